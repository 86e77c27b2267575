//! Delay-and-sum beamforming of steered plane waves, in the IQ domain, batched over frames.
//!
//! For pixel (x, z), angle θ and element e the echo time is the shared convention
//! [`geometry::round_trip_delay`](crate::core::geometry::round_trip_delay); the baseband sample there
//! is linearly interpolated and rotated by exp(+2πi f_d τ) to restore the carrier phase. Receive
//! apodisation: elements within the aperture |x − x_e| ≤ z / (2 F#), weighted by a Hann (or flat)
//! window across it.
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
//!
//! Layout (private submodules): this file holds the public API; `taps` the delay and weight tables
//! the kernels read; `tiling` the blocked pixel loop that fills them; `kernel` the choice of accumulation kernel from the CPU's
//! features and the dispatch to it; `avx512`, `avx2` and `portable` one accumulation kernel each.

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx512;
mod kernel;
pub use kernel::KERNEL_VARIABLE;
mod portable;
mod taps;
mod tiling;

use std::borrow::Cow;

use ndarray::{Array3, ArrayView3, ArrayViewMut3, Axis};
use num_complex::Complex32;

use crate::acquisition::probe::Probe;
use crate::core::error::{Error, Result, invalid};
use crate::core::grid::Grid;
use crate::form::iq::IqChannels;
use kernel::Kernel;

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
    /// Default receive f-number (depth / active aperture width): 1.0, where the rat probe's
    /// (L22-14vX) elements hear −3 dB of their broadside sensitivity at the aperture's edge
    /// ([`crate::core::probe::Probe::directivity_f_number`]: 0.99). Wider apertures add
    /// elements that hear little; narrower ones (F# 1.5) average the velocity gradient of a
    /// vessel over a wider cell. Chosen with the partial-volume correction and the 5x1 kernel
    /// on held-out seeds of every study (docs/results/accuracy.md).
    pub const DEFAULT_F_NUMBER: f64 = 1.0;

    /// F# [`Self::DEFAULT_F_NUMBER`] with Hann apodisation at sound speed `c` (m/s).
    pub fn new(sound_speed: f64) -> Self {
        DasParams {
            f_number: Self::DEFAULT_F_NUMBER,
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
    tiling::beamform_with(Kernel::detect(), iq, probe, angle, grid, params)
}

/// As [`beamform`], into `image` (nz, nx, frames), e.g. a block's frames of a longer series:
/// no image is allocated when each pixel's frames lie contiguous in it.
pub fn beamform_into(
    iq: &IqChannels,
    probe: &Probe,
    angle: f64,
    grid: &Grid,
    params: &DasParams,
    image: ArrayViewMut3<Complex32>,
) -> Result<()> {
    tiling::beamform_into_with(Kernel::detect(), iq, probe, angle, grid, params, image)
}

/// The delay-and-sum accumulation kernel this CPU runs, for a speed report's arithmetic bound.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AccumulationKernel {
    /// "AVX-512", "AVX2" or "portable".
    pub name: &'static str,
    /// Width of its vectors (bits); `None` for the portable loop, vectorised as the compiler
    /// chooses.
    pub vector_bits: Option<usize>,
    /// Fused multiply-add instructions of that width per point (pixel × active element ×
    /// frame); `None` for the portable loop.
    pub fma_per_point: Option<f64>,
}

/// The accumulation kernel [`beamform`] runs on this CPU: the widest it supports, or the one
/// [`KERNEL_VARIABLE`] names.
pub fn accumulation_kernel() -> AccumulationKernel {
    Kernel::detect().describe()
}

/// Coherent compounding: the sum of per-angle images (nz, nx, frames).
pub fn compound(images: &[Array3<Complex32>]) -> Result<Array3<Complex32>> {
    let first = images
        .first()
        .ok_or_else(|| invalid("compounding", "no images to compound"))?;
    if images.iter().any(|img| img.dim() != first.dim()) {
        return Err(Error::Shape("per-angle images differ in shape".into()));
    }
    // On every core, the angles summed in their order: memory-bound, one thread held the other
    // idle for a tenth of the Doppler stage.
    let mut sum = crate::core::buffers::array_reusing(None, first.dim());
    ndarray::Zip::from(&mut sum)
        .and(first)
        .par_for_each(|s, &v| *s = v);
    for img in &images[1..] {
        ndarray::Zip::from(&mut sum)
            .and(img)
            .par_for_each(|s, &v| *s += v);
    }
    Ok(sum)
}

/// [`compound`], borrowing the one image of a single angle instead of copying it.
pub fn compounded(images: &[Array3<Complex32>]) -> Result<Cow<'_, Array3<Complex32>>> {
    match images {
        [only] => Ok(Cow::Borrowed(only)),
        _ => compound(images).map(Cow::Owned),
    }
}

/// B-mode image in dB (0 dB at the brightest pixel) of the mean envelope over frames of `image` (nz, nx, frames).
pub fn bmode_db(image: ArrayView3<Complex32>) -> ndarray::Array2<f64> {
    let (nz, nx, _) = image.dim();
    let mut env = ndarray::Array2::<f64>::zeros((nz, nx));
    ndarray::Zip::from(&mut env)
        .and(image.lanes(Axis(2)))
        .par_for_each(|e, v| *e = mean_envelope(v));
    bmode_db_of_envelope(env)
}

/// The mean |S| of a pixel's frames ([`envelope`] of each); frames in one run are summed as a
/// slice, which vectorises, and strided ones element by element.
fn mean_envelope(frames: ndarray::ArrayView1<Complex32>) -> f64 {
    let sum: f64 = match frames.as_slice() {
        Some(run) => run.iter().copied().map(envelope).sum(),
        None => frames.iter().copied().map(envelope).sum(),
    };
    sum / frames.len().max(1) as f64
}

/// A sample's envelope |S|, the B-mode's, in double precision, where the squares of its
/// single-precision parts are exact: a square root that vectorises, closer to the true modulus
/// than single-precision `hypot` rounded to 24 bits, and far cheaper (it is taken once a sample).
pub fn envelope(sample: Complex32) -> f64 {
    let (re, im) = (sample.re as f64, sample.im as f64);
    (re * re + im * im).sqrt()
}

/// B-mode image in dB (0 dB at the brightest pixel) of a mean envelope map (nz, nx).
pub fn bmode_db_of_envelope(env: ndarray::Array2<f64>) -> ndarray::Array2<f64> {
    let max = env.iter().cloned().fold(f64::MIN_POSITIVE, f64::max);
    env.mapv(|v| 20.0 * (v.max(max * 1e-12) / max).log10())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::geometry;

    /// Deterministic values in [−1, 1) (also used by the kernel tests).
    pub(super) fn noise(seed: u64) -> impl FnMut() -> f32 {
        let mut state = seed;
        move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        }
    }

    /// The compound is each pixel's sum over the angles, added in the angles' order, to the bit,
    /// whatever the series' memory layouts; one angle is its own compound; none is refused.
    #[test]
    fn the_compound_is_the_sum_over_angles_in_their_order() {
        let mut value = noise(5);
        let mut series = |dim: (usize, usize, usize)| {
            Array3::from_shape_simple_fn(dim, || Complex32::new(value(), value() * 1e-3))
        };
        let dim = (9, 31, 40);
        let standard: Vec<Array3<Complex32>> = (0..5).map(|_| series(dim)).collect();
        let mut transposed = standard.clone();
        transposed[2] = series((40, 31, 9)).reversed_axes();
        for images in [&standard, &transposed] {
            let sum = compound(images).unwrap();
            for ((z, x, f), &got) in sum.indexed_iter() {
                let mut want = images[0][[z, x, f]];
                for img in &images[1..] {
                    want += img[[z, x, f]];
                }
                assert_eq!(
                    (got.re.to_bits(), got.im.to_bits()),
                    (want.re.to_bits(), want.im.to_bits())
                );
            }
        }
        assert_eq!(compound(&standard[..1]).unwrap(), standard[0]);
        assert!(compound(&[]).is_err());
    }

    /// The B-mode is 20·log10 of each pixel's mean modulus over the brightest's, the moduli
    /// of the samples as stored (f32 parts) taken exactly (f64 `hypot`), whether a pixel's frames
    /// are one run or strided.
    #[test]
    fn bmode_is_the_mean_modulus_in_db() {
        let (nz, nx, frames) = (5, 4, 9);
        let mut r = noise(11);
        let samples = Array3::from_shape_fn((nz, nx, frames), |(iz, ix, _)| {
            Complex32::from_polar(1.0 + iz as f32 + 2.0 * ix as f32, 3.2 * r())
        });
        let mean = samples.map_axis(Axis(2), |v| {
            v.iter()
                .map(|c| (c.re as f64).hypot(c.im as f64))
                .sum::<f64>()
                / frames as f64
        });
        let brightest = mean.iter().cloned().fold(0.0, f64::max);
        let db = bmode_db(samples.view());
        for (got, m) in db.iter().zip(&mean) {
            assert!(
                (got - 20.0 * (m / brightest).log10()).abs() < 1e-12,
                "{got} {m}"
            );
        }
        // Frames strided: the same series stored frame by frame.
        let by_frame = samples
            .view()
            .permuted_axes([2, 0, 1])
            .as_standard_layout()
            .into_owned();
        let strided = by_frame.view().permuted_axes([1, 2, 0]);
        assert!(
            strided
                .lanes(Axis(2))
                .into_iter()
                .next()
                .unwrap()
                .as_slice()
                .is_none()
        );
        assert_eq!(bmode_db(strided), db);
    }

    pub(super) fn random_iq(
        channels: usize,
        samples: usize,
        frames: usize,
        seed: u64,
    ) -> IqChannels {
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

    /// Pixels beside the probe, which only its last elements reach, and pixels beyond it, which
    /// no element reaches, are written over whatever the memory held: the first with the
    /// textbook loop's sums, the second with zeros, by every kernel this CPU runs, over several
    /// runs of frames.
    #[test]
    fn every_pixel_is_written_over_what_the_memory_held() {
        let probe = Probe::l22_14vx();
        // The elements span ±6.35 mm; at F# 1.5 and 2–3 mm deep the aperture is ±0.7–1 mm.
        let grid = Grid::new(5.5e-3, 8.5e-3, 2e-3, 3e-3, 0.1e-3).unwrap();
        let params = DasParams {
            f_number: 1.5,
            ..DasParams::new(1540.0)
        };
        let iq = random_iq(probe.n_elements, 400, 110, 9);
        let slow = reference(&iq, &probe, 0.05, &grid, &params);
        let scale = slow.iter().map(|v| v.norm()).fold(0.0f32, f32::max);
        #[cfg_attr(not(target_arch = "x86_64"), allow(unused_mut))]
        let mut kernels = vec![Kernel::detect(), Kernel::Portable];
        #[cfg(target_arch = "x86_64")]
        if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
            kernels.push(Kernel::Avx2);
        }
        for kernel in kernels {
            let marker = Complex32::new(f32::NAN, 7.0);
            let mut image = Array3::from_elem(slow.dim(), marker);
            tiling::beamform_into_with(kernel, &iq, &probe, 0.05, &grid, &params, image.view_mut())
                .unwrap();
            let (mut reached, mut beyond) = (0, 0);
            for (&x, (a, b)) in pixel_xs(&grid)
                .iter()
                .zip(image.lanes(Axis(2)).into_iter().zip(slow.lanes(Axis(2))))
            {
                if b.iter().all(|v| v.norm() == 0.0) {
                    beyond += 1;
                    assert!(
                        a.iter().all(|v| (v.re.to_bits(), v.im.to_bits()) == (0, 0)),
                        "{kernel:?} at x = {x}"
                    );
                } else {
                    reached += 1;
                    for (u, v) in a.iter().zip(b) {
                        assert!(
                            (u - v).norm() <= 1e-5 * scale,
                            "{kernel:?} at x = {x}: {u} vs {v}"
                        );
                    }
                }
            }
            assert!(
                reached > 0 && beyond > 0,
                "{reached} pixels reached, {beyond} beyond"
            );
        }
    }

    /// Each pixel's x (m), in the order of an image's pixels (z, then x).
    fn pixel_xs(grid: &Grid) -> Vec<f64> {
        grid.z.iter().flat_map(|_| grid.x.iter().copied()).collect()
    }

    /// Into the block's frames of a longer series (each pixel's frames contiguous but pixels a
    /// series apart) and into a view whose frames are not contiguous, the images are those
    /// `beamform` returns, and the frames around the block are left as they were.
    #[test]
    fn beamform_into_a_slice_of_a_series_writes_only_its_frames() {
        let probe = Probe::l22_14vx();
        let grid = Grid::new(-1e-3, 1e-3, 3e-3, 4e-3, 0.1e-3).unwrap();
        let params = DasParams::new(1540.0);
        let iq = random_iq(probe.n_elements, 400, 9, 3);
        let whole = beamform(&iq, &probe, 0.1, &grid, &params).unwrap();
        let (nz, nx) = grid.shape();
        let marker = Complex32::new(7.0, -7.0);
        let mut series = Array3::from_elem((nz, nx, 20), marker);
        beamform_into(
            &iq,
            &probe,
            0.1,
            &grid,
            &params,
            series.slice_mut(ndarray::s![.., .., 5..14]),
        )
        .unwrap();
        assert_eq!(series.slice(ndarray::s![.., .., 5..14]), whole);
        assert!(
            series
                .slice(ndarray::s![.., .., ..5])
                .iter()
                .all(|&v| v == marker)
        );
        assert!(
            series
                .slice(ndarray::s![.., .., 14..])
                .iter()
                .all(|&v| v == marker)
        );
        // Every other frame of a series: not contiguous.
        let mut strided = Array3::from_elem((nz, nx, 18), marker);
        beamform_into(
            &iq,
            &probe,
            0.1,
            &grid,
            &params,
            strided.slice_mut(ndarray::s![.., .., ..;2]),
        )
        .unwrap();
        assert_eq!(strided.slice(ndarray::s![.., .., ..;2]), whole);
        assert!(
            strided
                .slice(ndarray::s![.., .., 1..;2])
                .iter()
                .all(|&v| v == marker)
        );
        let err = beamform_into(&iq, &probe, 0.1, &grid, &params, series.view_mut()).unwrap_err();
        assert!(err.to_string().contains("frames"), "{err}");
    }
}
