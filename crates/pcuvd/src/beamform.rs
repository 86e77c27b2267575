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
//! one pixel stays in registers across the group (AVX-512 kernel, 8 frames per vector and up to
//! 104 frames in registers, the last vector masked; else AVX2 + FMA, 4 frames per vector and 20
//! in registers, leftover frames in plain Rust; two sums per vector so that the complex products
//! need no shuffle, software prefetch a few elements ahead), and the next pass's samples are
//! prefetched into L2 while one runs. The kernel is picked at run time from the CPU's features,
//! so one build runs everywhere. Delays and weights are computed by a
//! vectorised loop over the elements, into one flat table per tile and group.

use ndarray::{Array3, ArrayView3, Axis};
use num_complex::Complex32;
use rayon::prelude::*;

use crate::error::{Error, Result, invalid, require_positive};
use crate::geometry;
// The pixel grid has its own module; re-exported so that `beamform::Grid` paths keep working.
pub use crate::grid::Grid;
use crate::iq::IqChannels;
use crate::probe::Probe;

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
    beamform_with(Kernel::detect(), iq, probe, angle, grid, params)
}

/// [`beamform`] with a given accumulation kernel, so that tests can run each one this CPU
/// supports.
fn beamform_with(
    kernel: Kernel,
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
    // The kernel's tables index rows of frames (channel, sample) in 32 bits.
    if channels.saturating_mul(n_samples) > i32::MAX as usize {
        return Err(Error::Shape(format!(
            "{channels} channels × {n_samples} samples per channel"
        )));
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
        tiles.into_par_iter().for_each_init(
            || (Taps::default(), Vec::new()),
            |(taps, rows), mut pixels| {
                let extent = |f: fn(&(f64, f64, &mut [Complex32])) -> f64| {
                    let v = pixels.iter().map(f);
                    (
                        v.clone().fold(f64::INFINITY, f64::min),
                        v.fold(f64::NEG_INFINITY, f64::max),
                    )
                };
                setup.tile_rows(extent(|p| p.0), extent(|p| p.1), rows);
                // Within a tile, one group of elements and one run of frames at a time (a
                // pass): the samples they need (a few hundred KB) are reused from L2 by all
                // the pixels. While a pass runs, the next one's samples are prefetched a few
                // rows per pixel, so that they come from L2 rather than from memory.
                let passes: Vec<_> = (0..channels)
                    .step_by(GROUP)
                    .flat_map(|g| {
                        chunks
                            .iter()
                            .map(move |f| (g..(g + GROUP).min(channels), f.clone()))
                    })
                    .collect();
                for (i, (elements, frames)) in passes.iter().enumerate() {
                    if frames.start == 0 {
                        taps.clear();
                        for (x, z, _) in pixels.iter() {
                            setup.taps(*x, *z, elements.clone(), kernel, taps);
                        }
                        taps.finish();
                    }
                    let mut ahead = passes
                        .get(i + 1)
                        .map(|(e, f)| Ahead::new(e.clone(), f.clone(), rows))
                        .unwrap_or_default();
                    let quota = ahead.rows.div_ceil(pixels.len());
                    for p in 0..pixels.len() {
                        ahead.issue(quota, data, &setup, rows);
                        if taps.spans[p].len == 0 {
                            continue;
                        }
                        // The next pixel's sums are fetched while this one is summed.
                        let next = pixels[(p + 1).min(pixels.len() - 1)].2[frames.clone()].as_ptr();
                        kernel.accumulate(
                            &mut pixels[p].2[frames.clone()],
                            frames.start,
                            data,
                            &setup,
                            taps,
                            p,
                            next,
                        );
                    }
                }
            },
        );
    }
    Ok(image)
}

/// Depths per band and lateral positions per tile of the blocked pixel loop.
const TILE_Z: usize = 8;
const TILE_X: usize = 32;
/// Elements per pass over a tile.
const GROUP: usize = 16;

/// Runs of frames that the kernel keeps in registers, of near-equal whole numbers of vectors and
/// at most its register budget each; then, for a kernel without masked loads, the frames left
/// over from whole vectors (summed by the portable loop). With masks, the last run ends in a
/// partial vector instead.
fn frame_chunks(frames: usize, kernel: Kernel) -> Vec<std::ops::Range<usize>> {
    let simd = match kernel {
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx512 => Some((8, avx512::MAX_VECTORS, true)),
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx2 => Some((4, MAX_VECTORS, false)),
        Kernel::Portable => None,
    };
    let Some((width, max, masked)) = simd else {
        // One run of all the frames (not a list of its frame indices).
        #[allow(clippy::single_range_in_vec_init)]
        return vec![0..frames];
    };
    let vectors = if masked {
        frames.div_ceil(width)
    } else {
        frames / width
    };
    let n = vectors.div_ceil(max);
    let mut chunks: Vec<_> = (0..n)
        .map(|i| width * (i * vectors / n)..(width * ((i + 1) * vectors / n)).min(frames))
        .collect();
    if width * vectors < frames {
        chunks.push(width * vectors..frames);
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

/// Delays and weights of the pixels of a tile for one group of elements, in flat arrays so that
/// the kernel runs from one pixel's taps into the next one's: pixel p's taps are
/// `spans[p].start..spans[p].start + spans[p].len`. Per tap: `rows`, the index
/// element · n_samples + i0 of its element's row of frames at sample i0, and the rotated
/// interpolation weights c0, c1 of samples i0 and i0 + 1.
/// Invariant (by construction where filled): 0 ≤ i0 and i0 + 1 < n_samples; `rows` has `PF`
/// more entries than there are taps (zeros), so that the kernel may read ahead to prefetch.
#[derive(Default)]
struct Taps {
    spans: Vec<Span>,
    /// 32 bits (the caller checks that every row index fits) so that the delay loop fills them
    /// vectorised, along with the weights.
    rows: Vec<u32>,
    c0_re: Vec<f32>,
    c0_im: Vec<f32>,
    c1_re: Vec<f32>,
    c1_im: Vec<f32>,
}

/// The lines of one pass (elements × their rows for a tile × a run of frames), prefetched a
/// few rows at a time while the previous pass runs.
#[derive(Default)]
struct Ahead {
    elements: std::ops::Range<usize>,
    frames: std::ops::Range<usize>,
    /// The next row to prefetch: element `e`, sample `r`.
    e: usize,
    r: usize,
    /// Rows in all.
    rows: usize,
}

impl Ahead {
    fn new(
        elements: std::ops::Range<usize>,
        frames: std::ops::Range<usize>,
        rows: &[(usize, usize)],
    ) -> Ahead {
        let total = rows[elements.clone()]
            .iter()
            .map(|&(lo, hi)| hi + 1 - lo)
            .sum();
        Ahead {
            e: elements.start,
            r: rows[elements.start].0,
            elements,
            frames,
            rows: total,
        }
    }

    /// Prefetches the next `n` rows' lines.
    fn issue(&mut self, n: usize, data: &[Complex32], setup: &Setup, rows: &[(usize, usize)]) {
        let row = setup.frames;
        for _ in 0..n {
            if self.e >= self.elements.end {
                return;
            }
            let start = (self.e * setup.n_samples + self.r) * row;
            let lines = data[start + self.frames.start..start + self.frames.end].as_ptr_range();
            let mut a = lines.start.cast::<u8>();
            while a < lines.end.cast() {
                prefetch_far(a);
                a = a.wrapping_add(64);
            }
            // The last line, when the run does not start on a line boundary.
            prefetch_far(lines.end.cast::<u8>().wrapping_sub(1));
            self.r += 1;
            if self.r > rows[self.e].1 {
                self.e += 1;
                if self.e < self.elements.end {
                    self.r = rows[self.e].0;
                }
            }
        }
    }
}

/// Asks for the line at `a` ahead of its use (a hint: never faults).
#[inline(always)]
fn prefetch_far(a: *const u8) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: prefetches never fault, whatever the address; SSE is part of x86_64.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T1 }>(a.cast());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = a;
}

/// Asks for the cache lines of the `bytes` at `a` and, if `row` > 0, of the same span `row`
/// complex samples further, into L1: the two rows a tap interpolates between, for the SIMD kernels.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn prefetch_near(a: *const f32, bytes: usize, row: usize) {
    use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
    let a = a.cast::<i8>();
    let b = a.wrapping_add(8 * row);
    let mut l = 0;
    while l < bytes + 63 {
        // SAFETY: prefetches never fault, whatever the address; SSE is part of x86_64.
        unsafe {
            _mm_prefetch::<_MM_HINT_T0>(a.wrapping_add(l));
            if row > 0 {
                _mm_prefetch::<_MM_HINT_T0>(b.wrapping_add(l));
            }
        }
        l += 64;
    }
}

/// Where one pixel's taps lie in the arrays of [`Taps`].
#[derive(Debug, Clone, Copy, Default)]
struct Span {
    start: usize,
    len: usize,
}

impl Taps {
    /// Empties the tables, keeping their allocations for the next group.
    fn clear(&mut self) {
        self.spans.clear();
        self.rows.clear();
        for v in [
            &mut self.c0_re,
            &mut self.c0_im,
            &mut self.c1_re,
            &mut self.c1_im,
        ] {
            v.clear();
        }
    }

    /// Room for `len` more taps of a new pixel; returns where they start.
    fn push(&mut self, len: usize) -> usize {
        let start = self.rows.len();
        self.spans.push(Span { start, len });
        let end = start + len;
        self.rows.resize(end, 0);
        for v in [
            &mut self.c0_re,
            &mut self.c0_im,
            &mut self.c1_re,
            &mut self.c1_im,
        ] {
            v.resize(end, 0.0);
        }
        start
    }

    /// Pads `rows` for the kernel's look-ahead once all pixels are in.
    fn finish(&mut self) {
        self.rows.extend([0; PF]);
    }
}
/// One pixel's slices of the [`Taps`] arrays, for the delay loop to fill.
struct TapsMut<'a> {
    rows: &'a mut [u32],
    c0_re: &'a mut [f32],
    c0_im: &'a mut [f32],
    c1_re: &'a mut [f32],
    c1_im: &'a mut [f32],
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

    /// Per element, the sample rows (first, last) that pixels in [x0, x1] × [z0, z1] may read,
    /// clamped to the record: a superset, used only for prefetching. The delay grows with depth
    /// and is convex in x, so its minimum is at z0 where its x derivative vanishes (or at the
    /// nearer edge) and its maximum at a corner of depth z1.
    fn tile_rows(
        &self,
        (x0, x1): (f64, f64),
        (z0, z1): (f64, f64),
        rows: &mut Vec<(usize, usize)>,
    ) {
        let delay = |x: f64, z: f64, xe: f64| {
            geometry::round_trip_delay(x, z, self.angle, xe, self.aperture, self.c)
        };
        let last = self.n_samples - 1;
        let sample = |tau: f64| ((tau - self.t0) * self.fs).floor().max(0.0) as usize;
        rows.clear();
        rows.extend(self.element_x.iter().map(|&xe| {
            let x_min = (xe - z0 * self.angle.tan()).clamp(x0, x1);
            let lo = sample(delay(x_min, z0, xe)).min(last - 1);
            let hi = sample(delay(x0, z1, xe).max(delay(x1, z1, xe))) + 1;
            (lo, hi.clamp(lo + 1, last))
        }));
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
        let start = taps.push(len);
        let span = start..start + len;
        let element_x = &self.element_x[first..end];
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
            let tau = tx + geometry::receive_delay(x, z, xe, self.c);
            let pos = (tau - self.t0) * self.fs;
            let valid = dx <= half_aperture && pos >= 0.0 && pos < last;
            let pos = if valid { pos } else { 0.0 };
            let i = pos as i32;
            let w = pos - i as f64;
            // A no-op, as 0 ≤ pos < last here (and NaN fails `valid`), which makes the
            // invariant of `Taps` hold by construction whatever the inputs.
            let i = i.clamp(0, n_samples as i32 - 2) as u32;
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
            rows[k] = first_row + k as u32 * n_samples + i;
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
    /// Explicit AVX-512 (F, DQ) on interleaved complex frames, eight frames per vector, the last
    /// vector of a run masked.
    #[cfg(target_arch = "x86_64")]
    Avx512,
    /// Explicit AVX2 + FMA on interleaved complex frames.
    #[cfg(target_arch = "x86_64")]
    Avx2,
    /// Plain Rust, any target.
    Portable,
}

impl Kernel {
    /// The kernels this CPU runs, fastest first; the portable loop is always last.
    fn supported() -> &'static [Kernel] {
        use std::sync::OnceLock;
        static SUPPORTED: OnceLock<Vec<Kernel>> = OnceLock::new();
        SUPPORTED.get_or_init(|| {
            let mut kernels = Vec::new();
            #[cfg(target_arch = "x86_64")]
            {
                let avx2 = is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma");
                if avx2
                    && is_x86_feature_detected!("avx512f")
                    && is_x86_feature_detected!("avx512dq")
                {
                    kernels.push(Kernel::Avx512);
                }
                if avx2 {
                    kernels.push(Kernel::Avx2);
                }
            }
            kernels.push(Kernel::Portable);
            kernels
        })
    }

    /// The fastest kernel this CPU runs.
    fn detect() -> Kernel {
        Kernel::supported()[0]
    }

    /// Adds to `out`, frames `f0..f0 + out.len()` of pixel `p`, Σ over its taps of c0·a + c1·b,
    /// a and b being the tap element's frames at samples i0 and i0 + 1. `next` (the next
    /// pixel's sums) is only prefetched.
    #[allow(clippy::too_many_arguments)]
    fn accumulate(
        self,
        out: &mut [Complex32],
        f0: usize,
        data: &[Complex32],
        setup: &Setup,
        taps: &Taps,
        p: usize,
        next: *const Complex32,
    ) {
        let (frames, n_samples) = (setup.frames, setup.n_samples);
        let row = frames;
        let Span { start, len } = taps.spans[p];
        let end = start + len;
        assert!(f0 + out.len() <= frames && data.len() >= setup.element_x.len() * n_samples * row);
        assert!(taps.rows.len() >= end + PF && taps.c1_im.len() >= end);
        #[cfg(target_arch = "x86_64")]
        if self == Kernel::Avx512 && !out.is_empty() && out.len() <= 8 * avx512::MAX_VECTORS {
            // SAFETY: AVX-512F/DQ, AVX2 and FMA were detected. Reads stay within `data` as for
            // AVX2 below; the masked last vector reads and writes only frames below
            // f0 + out.len().
            unsafe { avx512::pixel_chunk(out, next, data, f0, row, taps, start, len) };
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if self == Kernel::Avx2 && out.len().is_multiple_of(4) && out.len() <= 4 * MAX_VECTORS {
            // SAFETY: AVX2 and FMA were detected. Reads stay within `data`: each row index is
            // that of an element below the channel count and a sample i0 with
            // i0 + 1 < n_samples (the `Taps` invariant), frames below f0 + out.len() ≤ frames
            // (asserted above); the tap arrays hold `end` entries and `rows` PF more (asserted
            // above).
            unsafe { avx2::pixel_chunk(out, next, data, f0, row, taps, start, len) };
            return;
        }
        let n = out.len();
        for k in start..end {
            let base = taps.rows[k] as usize * row + f0;
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

/// The most 4-frame vectors of one pixel whose sums stay in registers across the element loop:
/// two sums per vector (see [`avx2::run`]) and four weights leave no register to spare at 6.
const MAX_VECTORS: usize = 5;
/// Taps ahead whose samples are prefetched.
const PF: usize = 3;

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{MAX_VECTORS, PF, Taps};
    use num_complex::Complex32;
    use std::arch::x86_64::*;

    /// Dispatches a run of 1..=MAX_VECTORS vectors to its register-resident instance.
    ///
    /// # Safety
    /// AVX2 and FMA must be available; for every tap k in `start..start + len`,
    /// `(rows[k] + 1)·row + f0 + acc.len()` must lie within `data`; `taps.rows` must hold PF
    /// entries beyond them.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    pub(super) unsafe fn pixel_chunk(
        acc: &mut [Complex32],
        next: *const Complex32,
        data: &[Complex32],
        f0: usize,
        row: usize,
        taps: &Taps,
        start: usize,
        len: usize,
    ) {
        debug_assert!(acc.len().is_multiple_of(4) && acc.len() / 4 <= MAX_VECTORS);
        // SAFETY: forwarded from the caller.
        unsafe {
            match acc.len() / 4 {
                1 => run::<1>(acc, next, data, f0, row, taps, start, len),
                2 => run::<2>(acc, next, data, f0, row, taps, start, len),
                3 => run::<3>(acc, next, data, f0, row, taps, start, len),
                4 => run::<4>(acc, next, data, f0, row, taps, start, len),
                5 => run::<5>(acc, next, data, f0, row, taps, start, len),
                _ => {}
            }
        }
    }

    /// Asks for the lines of N 8-float vectors at `a` and, if `row` > 0, one row further into L1.
    #[inline(always)]
    fn prefetch<const N: usize>(a: *const f32, row: usize) {
        super::prefetch_near(a, 32 * N, row);
    }

    /// acc += Σ_k c0[k]·a_k + c1[k]·b_k on interleaved (re, im) pairs. With c = (p, q) and
    /// a = (u, v), c·a = p·(u, v) + (−q v, q u): the loop sums p·a and q·a in two registers
    /// per vector, and the swap and sign of the second are applied once, after the loop, so
    /// that each tap costs four FMAs per vector and no shuffle.
    #[allow(clippy::too_many_arguments)]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn run<const N: usize>(
        acc: &mut [Complex32],
        next: *const Complex32,
        data: &[Complex32],
        f0: usize,
        row: usize,
        taps: &Taps,
        start: usize,
        len: usize,
    ) {
        let out = acc.as_mut_ptr().cast::<f32>();
        // SAFETY: acc holds 4·N complex values.
        let mut sp: [__m256; N] =
            std::array::from_fn(|j| unsafe { _mm256_loadu_ps(out.add(8 * j)) });
        let mut sq: [__m256; N] = [_mm256_setzero_ps(); N];
        prefetch::<N>(next.cast::<f32>(), 0);
        // SAFETY (all pointer arithmetic below): the caller guarantees the tap arrays hold
        // start + len entries, `rows` PF more, and that every tap's rows lie within `data`.
        let base = unsafe { data.as_ptr().add(f0).cast::<f32>() };
        let rows = unsafe { taps.rows.as_ptr().add(start) };
        let c0r = unsafe { taps.c0_re.as_ptr().add(start) };
        let c0i = unsafe { taps.c0_im.as_ptr().add(start) };
        let c1r = unsafe { taps.c1_re.as_ptr().add(start) };
        let c1i = unsafe { taps.c1_im.as_ptr().add(start) };
        for k in 0..len {
            unsafe {
                let a = base.add(2 * row * *rows.add(k) as usize);
                let b = a.add(2 * row);
                // Prefetch PF taps ahead, running on into the next pixel's.
                prefetch::<N>(base.wrapping_add(2 * row * *rows.add(k + PF) as usize), row);
                let p0 = _mm256_broadcast_ss(&*c0r.add(k));
                let q0 = _mm256_broadcast_ss(&*c0i.add(k));
                let p1 = _mm256_broadcast_ss(&*c1r.add(k));
                let q1 = _mm256_broadcast_ss(&*c1i.add(k));
                for j in 0..N {
                    // 8 floats = 4 frames, inside the run of frames.
                    let u = _mm256_loadu_ps(a.add(8 * j));
                    let v = _mm256_loadu_ps(b.add(8 * j));
                    sp[j] = _mm256_fmadd_ps(u, p0, sp[j]);
                    sq[j] = _mm256_fmadd_ps(u, q0, sq[j]);
                    sp[j] = _mm256_fmadd_ps(v, p1, sp[j]);
                    sq[j] = _mm256_fmadd_ps(v, q1, sq[j]);
                }
            }
        }
        let sign = _mm256_setr_ps(-0.0, 0.0, -0.0, 0.0, -0.0, 0.0, -0.0, 0.0);
        for j in 0..N {
            // (q u, q v) → (−q v, q u).
            let t = _mm256_xor_ps(_mm256_permute_ps(sq[j], 0b1011_0001), sign);
            // SAFETY: acc holds 4·N complex values.
            unsafe { _mm256_storeu_ps(out.add(8 * j), _mm256_add_ps(sp[j], t)) };
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx512 {
    use super::{PF, Taps};
    use num_complex::Complex32;
    use std::arch::x86_64::*;

    /// The most 8-frame vectors of one pixel whose sums stay in registers across the element
    /// loop: two sums per vector and four broadcast weights take 30 of the 32 registers at 13,
    /// leaving two for the samples. 13 vectors hold 104 frames, so a typical 100-frame ensemble
    /// is one run and each tap's rows are read once per pass.
    pub(super) const MAX_VECTORS: usize = 13;

    /// Dispatches a run of 1..=8·MAX_VECTORS frames to its register-resident instance.
    ///
    /// # Safety
    /// AVX-512F, AVX-512DQ, AVX2 and FMA must be available; `acc` must not be empty; for every
    /// tap k in `start..start + len`, (rows[k] + 1)·row + f0 + acc.len() must lie within
    /// `data`; `taps.rows` must hold PF entries beyond them.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    pub(super) unsafe fn pixel_chunk(
        acc: &mut [Complex32],
        next: *const Complex32,
        data: &[Complex32],
        f0: usize,
        row: usize,
        taps: &Taps,
        start: usize,
        len: usize,
    ) {
        debug_assert!(!acc.is_empty() && acc.len().div_ceil(8) <= MAX_VECTORS);
        // SAFETY: forwarded from the caller.
        unsafe {
            match acc.len().div_ceil(8) {
                1 => run::<1>(acc, next, data, f0, row, taps, start, len),
                2 => run::<2>(acc, next, data, f0, row, taps, start, len),
                3 => run::<3>(acc, next, data, f0, row, taps, start, len),
                4 => run::<4>(acc, next, data, f0, row, taps, start, len),
                5 => run::<5>(acc, next, data, f0, row, taps, start, len),
                6 => run::<6>(acc, next, data, f0, row, taps, start, len),
                7 => run::<7>(acc, next, data, f0, row, taps, start, len),
                8 => run::<8>(acc, next, data, f0, row, taps, start, len),
                9 => run::<9>(acc, next, data, f0, row, taps, start, len),
                10 => run::<10>(acc, next, data, f0, row, taps, start, len),
                11 => run::<11>(acc, next, data, f0, row, taps, start, len),
                12 => run::<12>(acc, next, data, f0, row, taps, start, len),
                13 => run::<13>(acc, next, data, f0, row, taps, start, len),
                _ => {}
            }
        }
    }

    /// Asks for the lines of N 16-float vectors at `a` and, if `row` > 0, one row further into L1.
    #[inline(always)]
    fn prefetch<const N: usize>(a: *const f32, row: usize) {
        super::prefetch_near(a, 64 * N, row);
    }

    /// acc += `Σ_k c0[k]·a_k + c1[k]·b_k` on interleaved (re, im) pairs, as [`super::avx2`]'s
    /// `run` (two sums per vector, the swap and sign applied once after the loop), 16 floats
    /// per vector; the last vector is masked to the frames of `acc`, so that no frame is left
    /// to a scalar tail and nothing beyond them is read or written.
    #[allow(clippy::too_many_arguments)]
    #[target_feature(enable = "avx512f,avx512dq,avx2,fma")]
    unsafe fn run<const N: usize>(
        acc: &mut [Complex32],
        next: *const Complex32,
        data: &[Complex32],
        f0: usize,
        row: usize,
        taps: &Taps,
        start: usize,
        len: usize,
    ) {
        // Frames in the last vector, 1..=8, two floats each.
        let last = acc.len() - 8 * (N - 1);
        let tail: __mmask16 = if last == 8 {
            u16::MAX
        } else {
            (1 << (2 * last)) - 1
        };
        let out = acc.as_mut_ptr().cast::<f32>();
        // SAFETY: acc holds 8·(N − 1) + `last` complex values, and the last load is masked.
        let mut sp: [__m512; N] = std::array::from_fn(|j| unsafe {
            if j + 1 < N {
                _mm512_loadu_ps(out.add(16 * j))
            } else {
                _mm512_maskz_loadu_ps(tail, out.add(16 * j))
            }
        });
        let mut sq: [__m512; N] = [_mm512_setzero_ps(); N];
        prefetch::<N>(next.cast::<f32>(), 0);
        // SAFETY (all pointer arithmetic below): the caller guarantees the tap arrays hold
        // start + len entries, `rows` PF more, and that every tap's rows lie within `data`;
        // the last vector's loads are masked to the frames of `acc`.
        let base = unsafe { data.as_ptr().add(f0).cast::<f32>() };
        let rows = unsafe { taps.rows.as_ptr().add(start) };
        let c0r = unsafe { taps.c0_re.as_ptr().add(start) };
        let c0i = unsafe { taps.c0_im.as_ptr().add(start) };
        let c1r = unsafe { taps.c1_re.as_ptr().add(start) };
        let c1i = unsafe { taps.c1_im.as_ptr().add(start) };
        for k in 0..len {
            unsafe {
                let a = base.add(2 * row * *rows.add(k) as usize);
                let b = a.add(2 * row);
                // Prefetch PF taps ahead, running on into the next pixel's.
                prefetch::<N>(base.wrapping_add(2 * row * *rows.add(k + PF) as usize), row);
                let p0 = _mm512_set1_ps(*c0r.add(k));
                let q0 = _mm512_set1_ps(*c0i.add(k));
                let p1 = _mm512_set1_ps(*c1r.add(k));
                let q1 = _mm512_set1_ps(*c1i.add(k));
                for j in 0..N {
                    // 16 floats = 8 frames, inside the run of frames (masked in the last).
                    let (u, v) = if j + 1 < N {
                        (
                            _mm512_loadu_ps(a.add(16 * j)),
                            _mm512_loadu_ps(b.add(16 * j)),
                        )
                    } else {
                        (
                            _mm512_maskz_loadu_ps(tail, a.add(16 * j)),
                            _mm512_maskz_loadu_ps(tail, b.add(16 * j)),
                        )
                    };
                    sp[j] = _mm512_fmadd_ps(u, p0, sp[j]);
                    sq[j] = _mm512_fmadd_ps(u, q0, sq[j]);
                    sp[j] = _mm512_fmadd_ps(v, p1, sp[j]);
                    sq[j] = _mm512_fmadd_ps(v, q1, sq[j]);
                }
            }
        }
        let sign = _mm512_setr_ps(
            -0.0, 0.0, -0.0, 0.0, -0.0, 0.0, -0.0, 0.0, -0.0, 0.0, -0.0, 0.0, -0.0, 0.0, -0.0, 0.0,
        );
        for j in 0..N {
            // (q u, q v) → (−q v, q u).
            let t = _mm512_xor_ps(_mm512_permute_ps::<0b1011_0001>(sq[j]), sign);
            let sum = _mm512_add_ps(sp[j], t);
            let mask = if j + 1 < N { u16::MAX } else { tail };
            // SAFETY: acc holds 8·(N − 1) + `last` complex values; the store is masked to them.
            unsafe { _mm512_mask_storeu_ps(out.add(16 * j), mask, sum) };
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

    /// Runs `kernel`'s accumulation against the portable loop's on random taps and data, over
    /// every run of frames it is given for several frame counts (whole vectors, partial last
    /// vectors, more than one run), and on a whole image. Both sum the same f32 products in a
    /// different order and with or without FMA, so they differ by rounding only: a few ulps of
    /// the largest partial sum (here |sum| ≲ 8·|terms|), hence a relative bound of 1e-5 of the
    /// sum's size, or of 1 where the sum nearly cancels.
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    fn kernel_matches_portable_loop(kernel: Kernel) {
        for frames in [1, 3, 8, 37, 100, 104, 105, 230] {
            let (channels, samples) = (5, 40);
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
            // Two pixels, with four and three taps, on elements 1..5; the first tap of the
            // second reads the last sample pair of its element.
            let mut taps = Taps::default();
            for (n, offset) in [(4, 3), (3, 38)] {
                let start = taps.push(n);
                for k in 0..n {
                    let i0 = (k * 9 + offset).min(samples - 2);
                    taps.rows[start + k] = ((1 + k) * samples + i0) as u32;
                    taps.c0_re[start + k] = r();
                    taps.c0_im[start + k] = r();
                    taps.c1_re[start + k] = r();
                    taps.c1_im[start + k] = r();
                }
            }
            taps.finish();
            let chunks = frame_chunks(frames, kernel);
            assert_eq!(chunks.first().map(|c| c.start), Some(0));
            assert_eq!(chunks.last().map(|c| c.end), Some(frames));
            assert!(chunks.windows(2).all(|w| w[0].end == w[1].start));
            for p in 0..2 {
                for range in chunks.clone() {
                    let mut r = noise(range.start as u64);
                    let start: Vec<Complex32> =
                        range.clone().map(|_| Complex32::new(r(), r())).collect();
                    let (mut fast, mut slow) = (start.clone(), start);
                    let next = data.as_ptr();
                    kernel.accumulate(&mut fast, range.start, data, &setup, &taps, p, next);
                    Kernel::Portable.accumulate(
                        &mut slow,
                        range.start,
                        data,
                        &setup,
                        &taps,
                        p,
                        next,
                    );
                    for (a, b) in fast.iter().zip(&slow) {
                        assert!(
                            (a - b).norm() <= 1e-5 * b.norm().max(1.0),
                            "{kernel:?}, {frames} frames: {a} vs {b}"
                        );
                    }
                }
            }
        }
        // A whole image, 21 frames (a partial last vector for either kernel), against the
        // portable kernel's.
        let probe = Probe::l22_14vx();
        let grid = Grid::new(-1e-3, 1e-3, 3e-3, 4e-3, 0.1e-3).unwrap();
        let iq = random_iq(probe.n_elements, 400, 21, 5);
        let params = DasParams::new(1540.0);
        let fast = beamform_with(kernel, &iq, &probe, 0.1, &grid, &params).unwrap();
        let slow = beamform_with(Kernel::Portable, &iq, &probe, 0.1, &grid, &params).unwrap();
        let scale = slow.iter().map(|v| v.norm()).fold(0.0f32, f32::max);
        assert!(scale > 1.0);
        for (a, b) in fast.iter().zip(slow.iter()) {
            assert!((a - b).norm() <= 1e-5 * scale, "{kernel:?}: {a} vs {b}");
        }
    }

    #[test]
    fn avx512_kernel_matches_portable_loop() {
        #[cfg(target_arch = "x86_64")]
        if Kernel::supported().contains(&Kernel::Avx512) {
            return kernel_matches_portable_loop(Kernel::Avx512);
        }
        eprintln!("skipped: this CPU has no AVX-512F/DQ (or no AVX2 + FMA)");
    }

    #[test]
    fn avx2_kernel_matches_portable_loop() {
        #[cfg(target_arch = "x86_64")]
        if Kernel::supported().contains(&Kernel::Avx2) {
            return kernel_matches_portable_loop(Kernel::Avx2);
        }
        eprintln!("skipped: this CPU has no AVX2 + FMA");
    }

    #[test]
    fn detect_picks_the_first_supported_kernel() {
        let supported = Kernel::supported();
        assert_eq!(Kernel::detect(), supported[0]);
        assert_eq!(supported.last(), Some(&Kernel::Portable));
    }
}
