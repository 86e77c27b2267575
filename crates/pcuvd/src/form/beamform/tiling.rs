//! The blocked pixel loop of [`beamform`](super::beamform) and the tables it feeds the kernels:
//! pixels in tiles (a z band, the tiles of a band in parallel), within a tile a group of elements
//! and a run of frames at a time (a pass), whose samples stay in L2; per tile and group, the delays and rotated interpolation weights of every pixel's
//! elements in one flat table ([`Taps`]), filled by a loop over the elements that vectorises.

use ndarray::{Array3, ArrayViewMut3, Axis};
use num_complex::Complex32;
use rayon::prelude::*;

use super::kernel::{Kernel, frame_chunks};
use super::taps::{Setup, TAP_LANES, Taps};
use super::{Apodization, DasParams};
use crate::acquisition::probe::Probe;
use crate::core::error::{Error, Result, require_positive};
use crate::core::geometry;
use crate::core::grid::Grid;
use crate::form::iq::IqChannels;

/// [`beamform`](super::beamform) with a given accumulation kernel, so that tests can run each
/// one this CPU supports.
pub(super) fn beamform_with(
    kernel: Kernel,
    iq: &IqChannels,
    probe: &Probe,
    angle: f64,
    grid: &Grid,
    params: &DasParams,
) -> Result<Array3<Complex32>> {
    let (nz, nx) = grid.shape();
    let mut image = Array3::<Complex32>::zeros((nz, nx, iq.data.dim().2));
    beamform_into_with(kernel, iq, probe, angle, grid, params, image.view_mut())?;
    Ok(image)
}

/// [`beamform_into`](super::beamform_into) with a given accumulation kernel.
pub(super) fn beamform_into_with(
    kernel: Kernel,
    iq: &IqChannels,
    probe: &Probe,
    angle: f64,
    grid: &Grid,
    params: &DasParams,
    mut image: ArrayViewMut3<Complex32>,
) -> Result<()> {
    require_positive("f-number", params.f_number)?;
    require_positive("speed of sound", params.sound_speed)?;
    let (channels, n_samples, frames) = iq.data.dim();
    if channels != probe.n_elements {
        return Err(Error::Shape(format!(
            "{channels} channels for a probe of {} elements",
            probe.n_elements
        )));
    }
    // The kernel's tables index rows of frames (channel, sample) in 32 bits.
    if channels.saturating_mul(n_samples) > i32::MAX as usize {
        return Err(Error::Shape(format!(
            "{channels} channels × {n_samples} samples per channel"
        )));
    }
    let (nz, nx) = grid.shape();
    if image.dim() != (nz, nx, frames) {
        return Err(Error::Shape(format!(
            "an image of {:?} (nz, nx, frames) for a grid of {nz} × {nx} and {frames} frames",
            image.dim()
        )));
    }
    if frames > 1 && image.stride_of(Axis(2)) != 1 {
        // The kernels write each pixel's frames as one run.
        let mut contiguous = Array3::<Complex32>::zeros((nz, nx, frames));
        beamform_into_with(
            kernel,
            iq,
            probe,
            angle,
            grid,
            params,
            contiguous.view_mut(),
        )?;
        image.assign(&contiguous);
        return Ok(());
    }
    // Interpolation needs two samples; with fewer, no pixel gets a contribution.
    if n_samples < 2 || frames == 0 || nz == 0 || nx == 0 || channels == 0 {
        image.fill(Complex32::new(0.0, 0.0));
        return Ok(());
    }
    let (data, row) = rows_of_frames(&iq.data);
    let data: &[Complex32] = &data;
    let setup = Setup::new(iq, row, probe, angle, params);
    let chunks = frame_chunks(frames, kernel);
    // z bands outermost, x tiles of a band in parallel: both threads then sweep the same band of
    // depths, so the channel samples it needs stay in L3 while they are in use.
    for (band, mut out_band) in image.axis_chunks_iter_mut(Axis(0), TILE_Z).enumerate() {
        let iz0 = band * TILE_Z;
        let mut tiles: Vec<Vec<(f64, f64, &mut [Complex32])>> = (0..nx.div_ceil(TILE_X))
            .map(|_| Vec::with_capacity(TILE_Z * TILE_X))
            .collect();
        // Lanes in (z, x) order; each pixel's frames are one run (checked above).
        for (i, pixel) in out_band.lanes_mut(Axis(2)).into_iter().enumerate() {
            let (iz, ix) = (i / nx, i % nx);
            let pixel = pixel.into_slice().expect("a pixel's frames are contiguous");
            tiles[ix / TILE_X].push((grid.x[ix], grid.z[iz0 + iz], pixel));
        }
        tiles
            .into_par_iter()
            .for_each_init(Taps::default, |taps, mut pixels| {
                // A pixel's first pass writes its sums (`fresh`) rather than adding them to
                // zeros: zeroing them beforehand was a pass over the whole series of its own.
                // Written by the thread that sums them, a fresh series is faulted in on every
                // core (zeroed whole by the calling thread, it kept the first block of a
                // 360-frame coded recording at 1.25 of 2 cores). `started[p·runs + r]`: pixel
                // p's run r of frames has been written.
                let mut started = vec![false; pixels.len() * chunks.len()];
                // Within a tile, one group of elements and one run of frames at a time (a
                // pass): the samples they need (a few hundred KB) are reused from L2 by all
                // the pixels. (Prefetching the next pass's samples into L2 while one ran cost
                // 12 % of the beamforming time on a 2 MB-L2 Xeon: the hardware prefetcher does
                // it.)
                let passes: Vec<_> = (0..channels)
                    .step_by(GROUP)
                    .flat_map(|g| {
                        chunks
                            .iter()
                            .enumerate()
                            .map(move |(r, f)| (g..(g + GROUP).min(channels), r, f.clone()))
                    })
                    .collect();
                // Every pixel's taps over its whole aperture at once, then each group's as a
                // sub-range: per group, the calls (and their aperture search and transmit delay)
                // cost more than the elements of a group did.
                taps.clear();
                taps.reserve(pixels.len(), channels);
                for (x, z, _) in pixels.iter() {
                    setup.taps(*x, *z, 0..channels, kernel, taps);
                }
                taps.finish();
                for (elements, run, frames) in &passes {
                    if frames.start == 0 {
                        taps.select(elements.clone());
                    }
                    for p in 0..pixels.len() {
                        if taps.spans[p].len == 0 {
                            continue;
                        }
                        // The next pixel's sums are fetched while this one is summed.
                        let next = pixels[(p + 1).min(pixels.len() - 1)].2[frames.clone()].as_ptr();
                        let fresh = !std::mem::replace(&mut started[p * chunks.len() + run], true);
                        kernel.accumulate(
                            &mut pixels[p].2[frames.clone()],
                            frames.start,
                            data,
                            &setup,
                            taps,
                            p,
                            next,
                            fresh,
                        );
                    }
                }
                // Runs that no element reached (outside every aperture) sum nothing.
                for (p, (_, _, pixel)) in pixels.iter_mut().enumerate() {
                    for (run, frames) in chunks.iter().enumerate() {
                        if !started[p * chunks.len() + run] {
                            pixel[frames.clone()].fill(Complex32::new(0.0, 0.0));
                        }
                    }
                }
            });
    }
    Ok(())
}

/// The samples as one slice of rows of frames, and the stride from one row to the next
/// (complex samples): the array's own memory where its rows lie at one stride (standard layout,
/// or rows padded to cache lines as demodulation writes them), else a copy in standard layout.
pub(super) fn rows_of_frames(
    data: &Array3<Complex32>,
) -> (std::borrow::Cow<'_, [Complex32]>, usize) {
    let (channels, n_samples, frames) = data.dim();
    let rows = channels * n_samples;
    // (The stride of an axis of length 1 is never stepped, and may be anything.)
    let [plane, row, column] = [0, 1, 2].map(|axis| data.stride_of(Axis(axis)));
    let row = match (n_samples, channels) {
        (2.., _) => row,
        (_, 2..) => plane,
        _ => frames as isize,
    };
    let one_stride = rows > 0
        && (frames == 1 || column == 1)
        && row >= frames as isize
        && (channels == 1 || plane == row * n_samples as isize);
    if !one_stride {
        let copy: Vec<Complex32> = data.iter().copied().collect();
        return (copy.into(), frames);
    }
    let row = row as usize;
    // SAFETY: an owned array's elements lie in one vector of initialized values, and so does
    // everything between its first element and its last, row·(rows − 1) + frames − 1 elements
    // further on (the strides checked above).
    let span = unsafe { std::slice::from_raw_parts(data.as_ptr(), row * (rows - 1) + frames) };
    (span.into(), row)
}

/// Depths per band and lateral positions per tile of the blocked pixel loop.
const TILE_Z: usize = 8;
const TILE_X: usize = 32;
/// Elements per pass over a tile.
const GROUP: usize = 16;

/// One pixel's slices of the [`Taps`] arrays, for the delay loop to fill.
struct TapsMut<'a> {
    rows: &'a mut [u32],
    c0_re: &'a mut [f32],
    c0_im: &'a mut [f32],
    c1_re: &'a mut [f32],
    c1_im: &'a mut [f32],
}

impl Setup {
    fn new(iq: &IqChannels, row: usize, probe: &Probe, angle: f64, params: &DasParams) -> Setup {
        let element_x = probe.element_x();
        let sorted = element_x.windows(2).all(|w| w[0] <= w[1]);
        let last = element_x.last().copied().unwrap_or(0.0);
        let padded_x = element_x
            .iter()
            .copied()
            .chain(std::iter::repeat_n(last, TAP_LANES - 1))
            .collect();
        let (_, n_samples, frames) = iq.data.dim();
        Setup {
            element_x,
            padded_x,
            sorted,
            angle,
            aperture: probe.aperture(),
            c: params.sound_speed,
            fs: iq.sampling_frequency,
            t0: iq.t0,
            demod_frequency: iq.demod_frequency,
            f_number: params.f_number,
            apodization: params.apodization,
            n_samples,
            frames,
            row,
        }
    }

    /// Appends to `taps` a pixel (x, z) with those of `elements` in its aperture. Elements whose
    /// echo falls outside the record keep zero weights (and a valid sample index): they add
    /// nothing.
    fn taps(
        &self,
        x: f64,
        z: f64,
        elements: std::ops::Range<usize>,
        kernel: Kernel,
        taps: &mut Taps,
    ) {
        let half_aperture = z / (2.0 * self.f_number);
        let inside = |xe: f64| (x - xe).abs() <= half_aperture;
        let (first, end) = if self.sorted {
            // |x − x_e| is monotone on either side of x, so with sorted elements the aperture is
            // a contiguous range.
            let element_x = &self.element_x[elements.clone()];
            let first = element_x.partition_point(|&xe| xe < x && !inside(xe));
            let len = element_x[first..].partition_point(|&xe| inside(xe));
            (elements.start + first, elements.start + first + len)
        } else {
            (elements.start, elements.end)
        };
        let len = end - first;
        let padded = len.next_multiple_of(TAP_LANES);
        let start = taps.push(len, padded - len, first);
        let span = start..start + padded;
        let element_x = &self.padded_x[first..first + padded];
        let out = TapsMut {
            rows: &mut taps.rows[span.clone()],
            c0_re: &mut taps.c0_re[span.clone()],
            c0_im: &mut taps.c0_im[span.clone()],
            c1_re: &mut taps.c1_re[span.clone()],
            c1_im: &mut taps.c1_im[span.clone()],
        };
        match kernel {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Kernel::Avx512` is only constructed after detecting AVX-512F/DQ, AVX2
            // and FMA.
            Kernel::Avx512 => unsafe {
                self.taps_avx512(x, z, half_aperture, first, element_x, out)
            },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Kernel::Avx2` is only constructed after detecting AVX2 and FMA.
            Kernel::Avx2 => unsafe { self.taps_avx2(x, z, half_aperture, first, element_x, out) },
            Kernel::Portable => self.taps_portable(x, z, half_aperture, first, element_x, out),
        }
        taps.drop_scratch();
    }

    /// The same code as [`Setup::taps_portable`], compiled for AVX2 so that the element loop is
    /// vectorised four wide in f64.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn taps_avx2(
        &self,
        x: f64,
        z: f64,
        half_aperture: f64,
        first: usize,
        element_x: &[f64],
        out: TapsMut,
    ) {
        self.taps_portable(x, z, half_aperture, first, element_x, out)
    }

    /// The same code as [`Setup::taps_portable`], compiled for AVX-512 so that the element loop
    /// is vectorised eight wide in f64.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512dq,avx2,fma")]
    unsafe fn taps_avx512(
        &self,
        x: f64,
        z: f64,
        half_aperture: f64,
        first: usize,
        element_x: &[f64],
        out: TapsMut,
    ) {
        self.taps_portable(x, z, half_aperture, first, element_x, out)
    }

    /// Branch-free over the elements so that it vectorises: no calls but sqrt and floor.
    /// `element_x` are the positions of elements `first..`.
    #[inline(always)]
    fn taps_portable(
        &self,
        x: f64,
        z: f64,
        half_aperture: f64,
        first: usize,
        element_x: &[f64],
        out: TapsMut,
    ) {
        let tx = geometry::transmit_delay(x, z, self.angle, self.aperture, self.c);
        let last = (self.n_samples - 1) as f64;
        let hann = self.apodization == Apodization::Hann;
        // Divisions by constants of the loop, made multiplications: a packed f64 division
        // issues once per several cycles, and the two per element cost about a tenth of the
        // loop's time.
        let slowness = 1.0 / self.c;
        let hann_cycles_per_m = 0.5 / half_aperture;
        let len = element_x.len();
        let rows = &mut out.rows[..len];
        // Row indices fit in u32 (checked by the caller).
        let (n_samples, first_row) = (self.n_samples as u32, (first * self.n_samples) as u32);
        let c0_re = &mut out.c0_re[..len];
        let c0_im = &mut out.c0_im[..len];
        let c1_re = &mut out.c1_re[..len];
        let c1_im = &mut out.c1_im[..len];
        for k in 0..len {
            let xe = element_x[k];
            let dx = (x - xe).abs();
            let tau = tx + geometry::receive_path(x, z, xe) * slowness;
            let pos = (tau - self.t0) * self.fs;
            let valid = dx <= half_aperture && pos >= 0.0 && pos < last;
            let pos = if valid { pos } else { 0.0 };
            // SAFETY: 0 ≤ pos < last < 2³¹ here, and NaN fails `valid`: the conversion is
            // exact truncation. (`as` saturates, which no x86 instruction does for packed
            // lanes: the loop took each lane out of its vector to convert it.)
            let i: i32 = unsafe { pos.to_int_unchecked() };
            let w = pos - i as f64;
            // A no-op, as 0 ≤ pos < last here, which makes the invariant of `Taps` hold by
            // construction whatever the inputs.
            let i = i.clamp(0, n_samples as i32 - 2) as u32;
            // Hann: ½(1 + cos(π dx / h)), i.e. the cosine of dx / 2h cycles.
            let apod = if hann {
                hann_weight(dx * hann_cycles_per_m)
            } else {
                1.0
            };
            let apod = if valid { apod } else { 0.0 };
            let (cos, sin) = cis_cycles(self.demod_frequency * tau);
            let (re, im) = (apod * cos, apod * sin);
            let (w0, w1) = ((1.0 - w) as f32, w as f32);
            // Wrapping: the scratch taps after a pixel's last may lie past the last row.
            rows[k] = first_row.wrapping_add((k as u32).wrapping_mul(n_samples).wrapping_add(i));
            c0_re[k] = re * w0;
            c0_im[k] = im * w0;
            c1_re[k] = re * w1;
            c1_im[k] = im * w1;
        }
    }
}

/// The Hann weight ½(1 + cos(2π·`cycles`)) at `cycles` = |x − x_e| / 2h ∈ [0, ½] inside the
/// aperture: [`cis_cycles`]'s cosine, the same operations to the bit, without what only other
/// quarter turns (¾ and on, outside the aperture, where the weight is not used) or the sine need.
#[inline(always)]
fn hann_weight(cycles: f64) -> f32 {
    let (quarter, s, c) = octant(cycles);
    // Quarter turns 0, 1, 2: cos = c, −s, −c.
    let cos = if quarter == 1.0 {
        -s
    } else if quarter == 0.0 {
        c
    } else {
        -c
    };
    0.5 * (1.0 + cos)
}

/// The quarter turns nearest 2π·`cycles` (a whole number) and the sine and cosine of what remains,
/// t ∈ [−π/4, π/4]: the turn count is removed in f64, where it is exact to far below f32
/// resolution; t gets f32 Taylor polynomials (error < 1e-7).
#[inline(always)]
fn octant(cycles: f64) -> (f64, f32, f32) {
    let quarter = (4.0 * cycles + 0.5).floor();
    let t = ((cycles - 0.25 * quarter) * std::f64::consts::TAU) as f32;
    let t2 = t * t;
    let s = t
        * (1.0
            + t2 * (-1.0 / 6.0
                + t2 * (1.0 / 120.0 + t2 * (-1.0 / 5040.0 + t2 * (1.0 / 362880.0)))));
    let c = 1.0 + t2 * (-0.5 + t2 * (1.0 / 24.0 + t2 * (-1.0 / 720.0 + t2 * (1.0 / 40320.0))));
    (quarter, s, c)
}

/// (cos, sin) of 2π·`cycles`, from its [`octant`] turned back by the quarter turns removed.
#[inline(always)]
fn cis_cycles(cycles: f64) -> (f32, f32) {
    let (quarter, s, c) = octant(cycles);
    let q = quarter - 4.0 * (0.25 * quarter).floor();
    // Quarter turns q = 0, 1, 2, 3 map (c, s) to (c, s), (−s, c), (−c, −s), (s, −c).
    let odd = q == 1.0 || q == 3.0;
    let (cos, sin) = if odd { (s, c) } else { (c, s) };
    let cos = if q == 1.0 || q == 2.0 { -cos } else { cos };
    let sin = if q >= 2.0 { -sin } else { sin };
    (cos, sin)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hann_is_the_raised_cosine_across_the_aperture() {
        // Across the aperture, the bits of cis_cycles's cosine (the general path), and the raised
        // cosine to within f32's resolution.
        for i in 0..=10000 {
            let cycles = i as f64 / 20000.0;
            let weight = hann_weight(cycles);
            let full = 0.5 * (1.0 + cis_cycles(cycles).0);
            assert_eq!(weight.to_bits(), full.to_bits(), "{cycles}");
            let exact = 0.5 * (1.0 + (std::f64::consts::TAU * cycles).cos());
            assert!(
                (weight as f64 - exact).abs() < 2e-7,
                "{cycles}: {weight} vs {exact}"
            );
        }
    }

    #[test]
    fn cis_cycles_is_accurate() {
        for i in -20000..20000 {
            let cycles = i as f64 * 0.0137 + 0.001;
            let (c, s) = cis_cycles(cycles);
            let (s0, c0) = (std::f64::consts::TAU * cycles).sin_cos();
            assert!((c as f64 - c0).abs() < 3e-7 && (s as f64 - s0).abs() < 3e-7);
        }
    }
}
