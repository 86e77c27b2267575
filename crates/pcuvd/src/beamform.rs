//! Delay-and-sum beamforming of steered plane waves, in the IQ domain, batched over frames.
//!
//! For pixel (x, z), angle θ and element e the echo time is the shared convention
//! [`geometry::round_trip_delay`]; the baseband sample there is linearly interpolated and rotated by
//! exp(+2πi f_d τ) to restore the carrier phase. Receive apodisation: elements within the aperture
//! |x − x_e| ≤ z / (2 F#), weighted by a Hann (or flat) window across it.
//! Frames are the contiguous axis, so each delay and weight is computed once per pixel and element
//! and applied to the whole batch of frames.
//!
//! Speed: the sum over elements is memory-bound unless blocked. Pixels go in tiles (a z band,
//! tiles of a band in parallel); within a tile, a group of elements and a run of frames at a time,
//! so that the samples they need are reused from L2 by all the tile's pixels; the run of frames of
//! one pixel stays in registers across the group (AVX2 + FMA kernel, software prefetch a few
//! elements ahead). Delays and weights are computed by a vectorised loop over the elements.

use ndarray::{Array3, ArrayView3, Axis};
use num_complex::Complex32;
use rayon::prelude::*;

use crate::error::{Error, Result, invalid, require_positive};
use crate::geometry;
use crate::iq::IqChannels;
use crate::probe::Probe;

/// A rectangular pixel grid: lateral positions `x` and depths `z` (m), both increasing.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    /// Lateral pixel positions (m).
    pub x: Vec<f64>,
    /// Depth pixel positions (m).
    pub z: Vec<f64>,
}

impl Grid {
    /// A grid spanning [x_min, x_max] × [z_min, z_max] (m) with spacing `step` (m) on both axes.
    pub fn new(x_min: f64, x_max: f64, z_min: f64, z_max: f64, step: f64) -> Result<Grid> {
        require_positive("grid step", step)?;
        for (name, v) in [
            ("x_min", x_min),
            ("x_max", x_max),
            ("z_min", z_min),
            ("z_max", z_max),
        ] {
            if !v.is_finite() {
                return Err(invalid("grid", format!("{name} = {v} is not finite")));
            }
        }
        if x_max < x_min || z_max < z_min {
            return Err(invalid(
                "grid",
                format!("empty extent x [{x_min}, {x_max}] m, z [{z_min}, {z_max}] m"),
            ));
        }
        if z_min < 0.0 {
            return Err(invalid(
                "grid",
                format!("z_min = {z_min} m lies behind the probe face (z < 0)"),
            ));
        }
        let axis = |lo: f64, hi: f64| -> Vec<f64> {
            let n = ((hi - lo) / step + 1e-9).floor() as usize + 1;
            (0..n).map(|i| lo + i as f64 * step).collect()
        };
        let (x, z) = (axis(x_min, x_max), axis(z_min, z_max));
        if x.len() * z.len() > 50_000_000 {
            return Err(invalid(
                "grid",
                format!("{} × {} pixels is too many", z.len(), x.len()),
            ));
        }
        Ok(Grid { x, z })
    }

    /// (nz, nx).
    pub fn shape(&self) -> (usize, usize) {
        (self.z.len(), self.x.len())
    }
}

/// Receive apodisation window across the active aperture.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Apodization {
    /// Flat weights.
    Boxcar,
    /// Hann weights, zero at the aperture edge.
    Hann,
}

/// Delay-and-sum settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DasParams {
    /// Receive f-number F# = depth / aperture width.
    pub f_number: f64,
    /// Window across the receive aperture.
    pub apodization: Apodization,
    /// Speed of sound for the delays (m/s).
    pub sound_speed: f64,
}

impl DasParams {
    /// F# 1.5 with Hann apodisation at sound speed `c` (m/s).
    pub fn new(sound_speed: f64) -> Self {
        DasParams {
            f_number: 1.5,
            apodization: Apodization::Hann,
            sound_speed,
        }
    }
}

/// Beamforms one angle's baseband channel data (channels, samples, frames) onto `grid`:
/// complex image of shape (nz, nx, frames).
pub fn beamform(
    iq: &IqChannels,
    probe: &Probe,
    angle: f64,
    grid: &Grid,
    params: &DasParams,
) -> Result<Array3<Complex32>> {
    require_positive("f-number", params.f_number)?;
    require_positive("speed of sound", params.sound_speed)?;
    let (channels, n_samples, frames) = iq.data.dim();
    if channels != probe.n_elements {
        return Err(Error::Shape(format!(
            "{channels} channels for a probe of {} elements",
            probe.n_elements
        )));
    }
    if n_samples > i32::MAX as usize {
        return Err(Error::Shape(format!("{n_samples} samples per channel")));
    }
    let (nz, nx) = grid.shape();
    let mut image = Array3::<Complex32>::zeros((nz, nx, frames));
    // Interpolation needs two samples; with fewer, no pixel gets a contribution.
    if n_samples < 2 || frames == 0 || nz == 0 || nx == 0 || channels == 0 {
        return Ok(image);
    }
    let setup = Setup::new(iq, probe, angle, params);
    let data = iq.data.as_standard_layout();
    let data = data.as_slice().expect("standard layout");
    let kernel = Kernel::detect();
    let chunks = frame_chunks(frames, kernel);
    let out = image.as_slice_mut().expect("standard layout");
    // z bands outermost, x tiles of a band in parallel: both threads then sweep the same band of
    // depths, so the channel samples it needs stay in L3 while they are in use.
    for (band, out_band) in out.chunks_mut(TILE_Z * nx * frames).enumerate() {
        let iz0 = band * TILE_Z;
        let mut tiles: Vec<Vec<(f64, f64, &mut [Complex32])>> = (0..nx.div_ceil(TILE_X))
            .map(|_| Vec::with_capacity(TILE_Z * TILE_X))
            .collect();
        for (row, &z) in out_band.chunks_mut(nx * frames).zip(&grid.z[iz0..]) {
            for (ix, pixel) in row.chunks_mut(frames).enumerate() {
                tiles[ix / TILE_X].push((grid.x[ix], z, pixel));
            }
        }
        tiles
            .into_par_iter()
            .for_each_init(Vec::<Taps>::new, |taps, mut pixels| {
                taps.resize_with(pixels.len(), || Taps::new(GROUP));
                // Within a tile, one group of elements and one run of frames at a time: the
                // samples they need (a few hundred KB) are reused from L2 by all the pixels.
                for group in (0..channels).step_by(GROUP) {
                    let elements = group..(group + GROUP).min(channels);
                    for ((x, z, _), taps) in pixels.iter().zip(taps.iter_mut()) {
                        setup.taps(*x, *z, elements.clone(), kernel, taps);
                    }
                    for frames in &chunks {
                        for p in 0..pixels.len() {
                            // The next pixel's first samples are fetched while this one is summed.
                            let next = (p + 1).min(pixels.len() - 1);
                            kernel.accumulate(
                                &mut pixels[p].2[frames.clone()],
                                frames.start,
                                data,
                                &setup,
                                &taps[p],
                                &taps[next],
                            );
                        }
                    }
                }
            });
    }
    Ok(image)
}

/// Depths per band and lateral positions per tile of the blocked pixel loop.
const TILE_Z: usize = 8;
const TILE_X: usize = 32;
/// Elements per pass over a tile.
const GROUP: usize = 16;

/// Runs of frames that the kernel keeps in registers, of near-equal lengths, then the frames
/// left over from whole vectors.
fn frame_chunks(frames: usize, kernel: Kernel) -> Vec<std::ops::Range<usize>> {
    let vectors = match kernel {
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx2 => frames / 4,
        Kernel::Portable => 0,
    };
    let n = vectors.div_ceil(MAX_VECTORS);
    let mut chunks: Vec<_> = (0..n)
        .map(|i| 4 * (i * vectors / n)..4 * ((i + 1) * vectors / n))
        .collect();
    if 4 * vectors < frames {
        chunks.push(4 * vectors..frames);
    }
    chunks
}

/// Everything the per-pixel delay and weight computation needs, fixed for one call.
struct Setup {
    element_x: Vec<f64>,
    /// Whether element positions increase, so that each aperture is a contiguous element range.
    sorted: bool,
    angle: f64,
    aperture: (f64, f64),
    c: f64,
    fs: f64,
    t0: f64,
    demod_frequency: f64,
    f_number: f64,
    apodization: Apodization,
    n_samples: usize,
    frames: usize,
}

/// Delays and weights of one pixel for the elements `first..first + len`: sample index i0 and the
/// rotated interpolation weights c0, c1 of samples i0 and i0 + 1.
/// Invariant (checked where filled): 0 ≤ i0 and i0 + 1 < n_samples.
struct Taps {
    first: usize,
    len: usize,
    i0: Vec<i32>,
    c0_re: Vec<f32>,
    c0_im: Vec<f32>,
    c1_re: Vec<f32>,
    c1_im: Vec<f32>,
}

impl Taps {
    fn new(capacity: usize) -> Taps {
        Taps {
            first: 0,
            len: 0,
            i0: vec![0; capacity],
            c0_re: vec![0.0; capacity],
            c0_im: vec![0.0; capacity],
            c1_re: vec![0.0; capacity],
            c1_im: vec![0.0; capacity],
        }
    }
}

impl Setup {
    fn new(iq: &IqChannels, probe: &Probe, angle: f64, params: &DasParams) -> Setup {
        let element_x = probe.element_x();
        let sorted = element_x.windows(2).all(|w| w[0] <= w[1]);
        let (_, n_samples, frames) = iq.data.dim();
        Setup {
            element_x,
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
        }
    }

    /// Fills `taps` for pixel (x, z) and those of `elements` in its aperture. Elements whose echo
    /// falls outside the record keep zero weights (and a valid sample index): they add nothing.
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
        taps.first = first;
        taps.len = end - first;
        match kernel {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Kernel::Avx2` is only constructed after detecting AVX2 and FMA.
            Kernel::Avx2 => unsafe { self.taps_avx2(x, z, half_aperture, taps) },
            Kernel::Portable => self.taps_portable(x, z, half_aperture, taps),
        }
        let last = self.n_samples - 1;
        let in_record = taps.i0[..taps.len]
            .iter()
            .fold(true, |ok, &i| ok & (i >= 0) & ((i as usize) < last));
        assert!(in_record, "sample index outside the record");
    }

    /// The same code as [`Setup::taps_portable`], compiled for AVX2 so that the element loop is
    /// vectorised four wide in f64.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn taps_avx2(&self, x: f64, z: f64, half_aperture: f64, taps: &mut Taps) {
        self.taps_portable(x, z, half_aperture, taps)
    }

    /// Branch-free over the elements so that it vectorises: no calls but sqrt and floor.
    #[inline(always)]
    fn taps_portable(&self, x: f64, z: f64, half_aperture: f64, taps: &mut Taps) {
        let tx = geometry::transmit_delay(x, z, self.angle, self.aperture, self.c);
        let last = (self.n_samples - 1) as f64;
        let hann = self.apodization == Apodization::Hann;
        let (first, len) = (taps.first, taps.len);
        let element_x = &self.element_x[first..first + len];
        let i0 = &mut taps.i0[..len];
        let c0_re = &mut taps.c0_re[..len];
        let c0_im = &mut taps.c0_im[..len];
        let c1_re = &mut taps.c1_re[..len];
        let c1_im = &mut taps.c1_im[..len];
        for k in 0..len {
            let xe = element_x[k];
            let dx = (x - xe).abs();
            let tau = tx + geometry::receive_delay(x, z, xe, self.c);
            let pos = (tau - self.t0) * self.fs;
            let valid = dx <= half_aperture && pos >= 0.0 && pos < last;
            let pos = if valid { pos } else { 0.0 };
            let i = pos as i32;
            let w = pos - i as f64;
            // Hann: ½(1 + cos(π dx / h)), i.e. the cosine of dx / 2h cycles.
            let apod = if hann {
                0.5 * (1.0 + cis_cycles(0.5 * dx / half_aperture).0)
            } else {
                1.0
            };
            let apod = if valid { apod } else { 0.0 };
            let (cos, sin) = cis_cycles(self.demod_frequency * tau);
            let (re, im) = (apod * cos, apod * sin);
            let (w0, w1) = ((1.0 - w) as f32, w as f32);
            i0[k] = i;
            c0_re[k] = re * w0;
            c0_im[k] = im * w0;
            c1_re[k] = re * w1;
            c1_im[k] = im * w1;
        }
    }
}

/// (cos, sin) of 2π·`cycles`. The turn count is removed in f64, where it is exact to far below
/// f32 resolution; the remaining octant [−π/4, π/4] gets f32 Taylor polynomials (error < 1e-7).
#[inline(always)]
fn cis_cycles(cycles: f64) -> (f32, f32) {
    let quarter = (4.0 * cycles + 0.5).floor();
    let t = ((cycles - 0.25 * quarter) * std::f64::consts::TAU) as f32;
    let t2 = t * t;
    let s = t
        * (1.0
            + t2 * (-1.0 / 6.0
                + t2 * (1.0 / 120.0 + t2 * (-1.0 / 5040.0 + t2 * (1.0 / 362880.0)))));
    let c = 1.0 + t2 * (-0.5 + t2 * (1.0 / 24.0 + t2 * (-1.0 / 720.0 + t2 * (1.0 / 40320.0))));
    let q = quarter - 4.0 * (0.25 * quarter).floor();
    // Quarter turns q = 0, 1, 2, 3 map (c, s) to (c, s), (−s, c), (−c, −s), (s, −c).
    let odd = q == 1.0 || q == 3.0;
    let (cos, sin) = if odd { (s, c) } else { (c, s) };
    let cos = if q == 1.0 || q == 2.0 { -cos } else { cos };
    let sin = if q >= 2.0 { -sin } else { sin };
    (cos, sin)
}

/// The accumulation kernel in use: chosen once per call from the running CPU.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kernel {
    /// Explicit AVX2 + FMA on interleaved complex frames.
    #[cfg(target_arch = "x86_64")]
    Avx2,
    /// Plain Rust, any target.
    Portable,
}

impl Kernel {
    fn detect() -> Kernel {
        #[cfg(target_arch = "x86_64")]
        {
            use std::sync::OnceLock;
            static AVX2: OnceLock<bool> = OnceLock::new();
            let avx2 = *AVX2.get_or_init(|| {
                is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
            });
            if avx2 {
                return Kernel::Avx2;
            }
        }
        Kernel::Portable
    }

    /// Adds to `out`, frames `f0..f0 + out.len()` of one pixel, Σ over the taps' elements of
    /// c0·a + c1·b, a and b being the element's frames at samples i0 and i0 + 1.
    fn accumulate(
        self,
        out: &mut [Complex32],
        f0: usize,
        data: &[Complex32],
        setup: &Setup,
        taps: &Taps,
        next: &Taps,
    ) {
        let (frames, n_samples) = (setup.frames, setup.n_samples);
        let (row, chan) = (frames, n_samples * frames);
        assert!(f0 + out.len() <= frames && data.len() >= (taps.first + taps.len) * chan);
        #[cfg(target_arch = "x86_64")]
        if self == Kernel::Avx2 && out.len().is_multiple_of(4) && out.len() <= 4 * MAX_VECTORS {
            // SAFETY: AVX2 and FMA were detected. Reads stay within `data`: elements below
            // first + len (asserted above), rows i0 + 1 < n_samples (the `Taps` invariant),
            // frames below f0 + out.len() ≤ frames (asserted above).
            unsafe { avx2::pixel_chunk(out, data, f0, chan, row, taps, next) };
            return;
        }
        let n = out.len();
        for k in 0..taps.len {
            let base = (taps.first + k) * chan + taps.i0[k] as usize * row + f0;
            accumulate(
                out,
                Complex32::new(taps.c0_re[k], taps.c0_im[k]),
                &data[base..base + n],
                Complex32::new(taps.c1_re[k], taps.c1_im[k]),
                &data[base + row..base + row + n],
            );
        }
    }
}

/// The most 4-frame vectors of one pixel whose sums stay in registers across the element loop.
const MAX_VECTORS: usize = 8;
const PF: usize = 3;

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{MAX_VECTORS, PF, Taps};
    use num_complex::Complex32;
    use std::arch::x86_64::*;

    /// Dispatches a run of 1..=MAX_VECTORS vectors to its register-resident instance.
    ///
    /// # Safety
    /// AVX2 and FMA must be available; for every tap k, elements first + k, rows i0[k] and
    /// i0[k] + 1, frames f0..f0 + acc.len() must lie within `data` (strides `chan`, `row`).
    #[inline]
    pub(super) unsafe fn pixel_chunk(
        acc: &mut [Complex32],
        data: &[Complex32],
        f0: usize,
        chan: usize,
        row: usize,
        taps: &Taps,
        next: &Taps,
    ) {
        debug_assert!(acc.len().is_multiple_of(4) && acc.len() / 4 <= MAX_VECTORS);
        // SAFETY: forwarded from the caller.
        unsafe {
            match acc.len() / 4 {
                1 => run::<1>(acc, data, f0, chan, row, taps, next),
                2 => run::<2>(acc, data, f0, chan, row, taps, next),
                3 => run::<3>(acc, data, f0, chan, row, taps, next),
                4 => run::<4>(acc, data, f0, chan, row, taps, next),
                5 => run::<5>(acc, data, f0, chan, row, taps, next),
                6 => run::<6>(acc, data, f0, chan, row, taps, next),
                7 => run::<7>(acc, data, f0, chan, row, taps, next),
                8 => run::<8>(acc, data, f0, chan, row, taps, next),
                _ => {}
            }
        }
    }

    /// Asks for the lines of N vectors at `a` and one row further into L1.
    #[inline(always)]
    fn prefetch<const N: usize>(a: *const f32, row: usize) {
        let a = a.cast::<i8>();
        let b = a.wrapping_add(8 * row);
        let mut l = 0;
        while l < 32 * N + 63 {
            // SAFETY: prefetches never fault, whatever the address.
            unsafe {
                _mm_prefetch::<_MM_HINT_T0>(a.wrapping_add(l));
                _mm_prefetch::<_MM_HINT_T0>(b.wrapping_add(l));
            }
            l += 64;
        }
    }

    /// acc += Σ_k c0[k]·a_k + c1[k]·b_k on interleaved (re, im) pairs: with c = (p, q) and
    /// a = (u, v), c·a = (p u − q v, p v + q u) = p·(u, v) + (−q, q)·(v, u).
    #[target_feature(enable = "avx2,fma")]
    unsafe fn run<const N: usize>(
        acc: &mut [Complex32],
        data: &[Complex32],
        f0: usize,
        chan: usize,
        row: usize,
        taps: &Taps,
        next: &Taps,
    ) {
        let out = acc.as_mut_ptr().cast::<f32>();
        // SAFETY: acc holds 4·N complex values.
        let mut sum: [__m256; N] =
            std::array::from_fn(|j| unsafe { _mm256_loadu_ps(out.add(8 * j)) });
        let sign = _mm256_setr_ps(-0.0, 0.0, -0.0, 0.0, -0.0, 0.0, -0.0, 0.0);
        let base = data.as_ptr().cast::<f32>();
        for k in 0..taps.len {
            let offset = (taps.first + k) * chan + taps.i0[k] as usize * row + f0;
            // SAFETY: within `data` by the caller's contract; Complex32 is two packed f32.
            let a = unsafe { base.add(2 * offset) };
            let b = unsafe { a.add(2 * row) };
            // Prefetch PF elements ahead, running on into the next pixel.
            let (t, kk) = if k + PF < taps.len {
                (taps, k + PF)
            } else {
                (next, k + PF - taps.len)
            };
            if kk < t.len {
                let o = (t.first + kk) * chan + t.i0[kk] as usize * row + f0;
                prefetch::<N>(base.wrapping_add(2 * o), row);
            }
            let c0r = _mm256_set1_ps(taps.c0_re[k]);
            let c0i = _mm256_xor_ps(_mm256_set1_ps(taps.c0_im[k]), sign);
            let c1r = _mm256_set1_ps(taps.c1_re[k]);
            let c1i = _mm256_xor_ps(_mm256_set1_ps(taps.c1_im[k]), sign);
            for (j, s) in sum.iter_mut().enumerate() {
                // SAFETY: 8 floats = 4 frames, inside the run of frames.
                let (u, v) =
                    unsafe { (_mm256_loadu_ps(a.add(8 * j)), _mm256_loadu_ps(b.add(8 * j))) };
                let mut t = _mm256_fmadd_ps(u, c0r, *s);
                t = _mm256_fmadd_ps(_mm256_permute_ps(u, 0b1011_0001), c0i, t);
                t = _mm256_fmadd_ps(v, c1r, t);
                *s = _mm256_fmadd_ps(_mm256_permute_ps(v, 0b1011_0001), c1i, t);
            }
        }
        for (j, s) in sum.iter().enumerate() {
            // SAFETY: acc holds 4·N complex values.
            unsafe { _mm256_storeu_ps(out.add(8 * j), *s) };
        }
    }
}

/// acc += c0·a + c1·b over a batch of frames: the beamformer's inner loop.
#[inline]
fn accumulate(
    acc: &mut [Complex32],
    c0: Complex32,
    a: &[Complex32],
    c1: Complex32,
    b: &[Complex32],
) {
    for ((o, &u), &v) in acc.iter_mut().zip(a).zip(b) {
        *o += c0 * u + c1 * v;
    }
}

/// Coherent compounding: the sum of per-angle images (nz, nx, frames).
pub fn compound(images: &[Array3<Complex32>]) -> Result<Array3<Complex32>> {
    let first = images
        .first()
        .ok_or_else(|| invalid("compounding", "no images to compound"))?;
    let mut sum = first.clone();
    for img in &images[1..] {
        if img.dim() != sum.dim() {
            return Err(Error::Shape("per-angle images differ in shape".into()));
        }
        sum += img;
    }
    Ok(sum)
}

/// B-mode image in dB (0 dB at the brightest pixel) of the mean envelope over frames of `image` (nz, nx, frames).
pub fn bmode_db(image: ArrayView3<Complex32>) -> ndarray::Array2<f64> {
    let env = image.map_axis(Axis(2), |v| {
        v.iter().map(|c| c.norm() as f64).sum::<f64>() / v.len().max(1) as f64
    });
    let max = env.iter().cloned().fold(f64::MIN_POSITIVE, f64::max);
    env.mapv(|v| 20.0 * (v.max(max * 1e-12) / max).log10())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic values in [−1, 1).
    fn noise(seed: u64) -> impl FnMut() -> f32 {
        let mut state = seed;
        move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        }
    }

    fn random_iq(channels: usize, samples: usize, frames: usize, seed: u64) -> IqChannels {
        let mut r = noise(seed);
        IqChannels {
            data: Array3::from_shape_simple_fn((channels, samples, frames), || {
                Complex32::new(r(), r())
            }),
            sampling_frequency: 62.5e6,
            t0: 1e-6,
            demod_frequency: 15.625e6,
        }
    }

    /// The textbook loop, in f64, with the library's geometry.
    fn reference(
        iq: &IqChannels,
        probe: &Probe,
        angle: f64,
        grid: &Grid,
        p: &DasParams,
    ) -> Array3<Complex32> {
        let (_, n_samples, frames) = iq.data.dim();
        let (nz, nx) = grid.shape();
        let mut image = Array3::<Complex32>::zeros((nz, nx, frames));
        for (iz, &z) in grid.z.iter().enumerate() {
            for (ix, &x) in grid.x.iter().enumerate() {
                for (e, &xe) in probe.element_x().iter().enumerate() {
                    let h = z / (2.0 * p.f_number);
                    let dx = (x - xe).abs();
                    if dx > h {
                        continue;
                    }
                    let apod = match p.apodization {
                        Apodization::Boxcar => 1.0,
                        Apodization::Hann => 0.5 * (1.0 + (std::f64::consts::PI * dx / h).cos()),
                    };
                    let tau = geometry::round_trip_delay(
                        x,
                        z,
                        angle,
                        xe,
                        probe.aperture(),
                        p.sound_speed,
                    );
                    let pos = (tau - iq.t0) * iq.sampling_frequency;
                    if !(pos >= 0.0 && pos < (n_samples - 1) as f64) {
                        continue;
                    }
                    let (i, w) = (pos.floor() as usize, pos - pos.floor());
                    let phase = std::f64::consts::TAU * iq.demod_frequency * tau;
                    let (s, c) = phase.sin_cos();
                    for f in 0..frames {
                        let (a, b) = (iq.data[[e, i, f]], iq.data[[e, i + 1, f]]);
                        let re = (1.0 - w) * a.re as f64 + w * b.re as f64;
                        let im = (1.0 - w) * a.im as f64 + w * b.im as f64;
                        let v = Complex32::new(
                            (apod * (re * c - im * s)) as f32,
                            (apod * (re * s + im * c)) as f32,
                        );
                        image[[iz, ix, f]] += v;
                    }
                }
            }
        }
        image
    }

    #[test]
    fn beamform_matches_reference_loop() {
        let probe = Probe::l22_14vx();
        let lambda = probe.wavelength(1540.0);
        let grid = Grid::new(-2e-3, 1.5e-3, 3e-3, 5e-3, lambda / 3.0).unwrap();
        // 11 frames: two register runs of 4-frame vectors and a scalar tail of 3.
        let iq = random_iq(probe.n_elements, 700, 11, 7);
        for (angle, apodization) in [(0.12, Apodization::Hann), (-0.2, Apodization::Boxcar)] {
            let params = DasParams {
                f_number: 1.5,
                apodization,
                sound_speed: 1540.0,
            };
            let fast = beamform(&iq, &probe, angle, &grid, &params).unwrap();
            let slow = reference(&iq, &probe, angle, &grid, &params);
            assert_eq!(fast.dim(), slow.dim());
            let scale = slow.iter().map(|v| v.norm()).fold(0.0f32, f32::max);
            assert!(scale > 1.0);
            for (a, b) in fast.iter().zip(slow.iter()) {
                assert!((a - b).norm() <= 1e-5 * scale, "{a} vs {b} (scale {scale})");
            }
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

    #[test]
    fn fast_kernel_matches_portable_loop() {
        if Kernel::detect() == Kernel::Portable {
            return;
        }
        let (channels, samples, frames) = (5, 40, 37);
        let iq = random_iq(channels, samples, frames, 3);
        let data = iq.data.as_slice().unwrap();
        let setup = Setup {
            element_x: vec![0.0; channels],
            sorted: true,
            angle: 0.0,
            aperture: (0.0, 0.0),
            c: 1540.0,
            fs: 1.0,
            t0: 0.0,
            demod_frequency: 1.0,
            f_number: 1.0,
            apodization: Apodization::Boxcar,
            n_samples: samples,
            frames,
        };
        let mut r = noise(11);
        let mut taps = Taps::new(4);
        taps.first = 1;
        taps.len = 4;
        for k in 0..4 {
            taps.i0[k] = (k * 9 + 3) as i32;
            taps.c0_re[k] = r();
            taps.c0_im[k] = r();
            taps.c1_re[k] = r();
            taps.c1_im[k] = r();
        }
        for range in frame_chunks(frames, Kernel::detect()) {
            let mut r = noise(range.start as u64);
            let start: Vec<Complex32> = range.clone().map(|_| Complex32::new(r(), r())).collect();
            let (mut fast, mut slow) = (start.clone(), start);
            Kernel::detect().accumulate(&mut fast, range.start, data, &setup, &taps, &taps);
            Kernel::Portable.accumulate(&mut slow, range.start, data, &setup, &taps, &taps);
            for (a, b) in fast.iter().zip(&slow) {
                assert!((a - b).norm() <= 1e-5 * b.norm().max(1.0), "{a} vs {b}");
            }
        }
    }
}
