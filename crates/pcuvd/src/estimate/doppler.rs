//! Autocorrelation Doppler (paper eq. 4–5): power, mean frequency, projection velocity.
//!
//! R = 1/(N−1) Σ_t S*(t)·S(t+1) over the frames of a (clutter-filtered) series. A scatterer moving
//! deeper lengthens the echo path, so the phase of R is negative; hence
//! V_θ = −c·f_frame/(4π f̄)·arg R, with f_frame = event PRF / n the per-angle frame rate and f̄ the
//! mean RF frequency of the echoes. V_θ is the projection of (Vx, Vz) on the angle's Doppler
//! direction: Vx·sin θ + Vz·(cos θ + 1) = 2 V_θ.
//!
//! # Which frequency (two estimators, [`DopplerEstimator`])
//! The lag-1 phase is 4π f̄ V_θ / (c f_frame), where f̄ is the power-weighted mean RF frequency of
//! the *image*, not the transmit's nominal f_0. [`DopplerEstimator::Kasai`] (the paper's eq. 5)
//! divides by f_0 (the demodulation frequency); [`DopplerEstimator::Loupas`] measures f̄ at every
//! pixel and divides by it (the 2-D autocorrelation of Loupas et al. 1995). Why it matters:
//! - In a 2-D image of diffuse scatterers each frequency f of the echo contributes in proportion
//!   to its lateral beam width, ∝ 1/f, so f̄ is the harmonic mean of the echo's power spectrum —
//!   0.969 f_0 for the L22-14vX 2-cycle echo (67 % bandwidth). Kasai reads projections 3 % low.
//! - f̄ varies from one speckle realisation to the next (±2–3 % over a few dozen speckle cells),
//!   differently at each angle, and an angle-dependent error of 2 % is several mm/s of Vx.
//! - Frequency-dependent attenuation lowers f̄ with depth (by 5–10 % at 1 cm in brain at 15 MHz),
//!   as do the transducer and the medium in real recordings.
//!
//! Loupas reads f̄ from the phase of the axial-lag autocorrelation (one pixel deeper). The plain
//! R(1, 0) = ⟨S*(z, t)·S(z + 1, t)⟩ also holds the receiver noise's own axial correlation, which
//! pulls f̄ toward the noise band's centre at low SNR; the axial lag paired with a temporal lag of
//! one frame, ⟨S*(z, t)·S(z + 1, t ± 1)⟩, where white noise does not correlate, with the Doppler
//! phase they carry removed by arg R ([`axial_autocorrelation_lag1`]), is immune to that but errs
//! as the square of the speed with a skewed spectrum. pcuvd mixes the two 2:1
//! ([`SAME_FRAME_WEIGHT`], which says why), the lateral lag alike. The mean frequency changes
//! slowly across the image, so it is averaged over the Doppler kernel widened by one pixel on
//! each side ([`mean_frequency_kernel`]).
//!
//! Its limit is the axial pixel step: the axial phase 2π f̄ (1 + cos θ) Δz / c is read modulo 2π
//! around the demodulation frequency, and with a wide echo spectrum its third cumulant (skew)
//! bends that phase away from 2π f̄ τ by ≈ (2π σ_f τ)³·skew/6: at Δz = λ/2 (τ ≈ 1/f_0) a speckle
//! region's realised skew gives errors of ±1 % per angle; at λ/4 about ±0.3 %. Grids coarser than
//! about a wavelength are refused ([`AxialSampling::new`]).
use ndarray::{Array2, ArrayView3, Axis, Zip, s};
use num_complex::{Complex32, Complex64};

use rayon::prelude::*;

use crate::core::error::{Error, Result, invalid, require_positive};

/// Power and lag-1 autocorrelation per pixel, shape (nz, nx).
#[derive(Debug, Clone, PartialEq)]
pub struct Autocorrelation {
    /// Mean |S|² over frames (power Doppler).
    pub power: Array2<f64>,
    /// Lag-1 autocorrelation R (eq. 4).
    pub r1: Array2<Complex64>,
}

/// Computes power and lag-1 autocorrelation of `series` (nz, nx, frames), each averaged over a
/// spatial box of `kernel` = (rows, cols) pixels (odd sizes; (1, 1) means no averaging).
pub fn autocorrelation(
    series: ArrayView3<Complex32>,
    kernel: (usize, usize),
) -> Result<Autocorrelation> {
    let (nz, nx, nf) = series.dim();
    if nf < 2 {
        return Err(invalid(
            "Doppler",
            format!("needs at least 2 frames, got {nf}"),
        ));
    }
    check_kernel(kernel)?;
    let mut power = Array2::<f64>::zeros((nz, nx));
    let mut r1 = Array2::<Complex64>::zeros((nz, nx));
    Zip::from(&mut power)
        .and(&mut r1)
        .and(series.lanes(Axis(2)))
        .par_for_each(|p, r, s| {
            let s = contiguous(&s);
            let mut acc_p = 0.0f64;
            let mut acc_r = Complex64::new(0.0, 0.0);
            for (t, x) in s.iter().enumerate() {
                acc_p += x.norm_sqr() as f64;
                if let Some(next) = s.get(t + 1) {
                    let v = x.conj() * next;
                    acc_r += Complex64::new(v.re as f64, v.im as f64);
                }
            }
            *p = acc_p / nf as f64;
            *r = acc_r / (nf - 1) as f64;
        });
    if kernel != (1, 1) {
        power = box_average(&power, kernel);
        r1 = box_average(&r1, kernel);
    }
    Ok(Autocorrelation { power, r1 })
}

/// A pixel's frames as a slice: borrowed where they lie contiguous (a formed series), else
/// copied.
fn contiguous<'a>(
    frames: &'a ndarray::ArrayView1<'_, Complex32>,
) -> std::borrow::Cow<'a, [Complex32]> {
    match frames.as_slice() {
        Some(slice) => std::borrow::Cow::Borrowed(slice),
        None => std::borrow::Cow::Owned(frames.to_vec()),
    }
}

/// Refuses an averaging box with an even size (it would have no centre pixel).
fn check_kernel(kernel: (usize, usize)) -> Result<()> {
    if kernel.0.is_multiple_of(2) || kernel.1.is_multiple_of(2) {
        return Err(invalid(
            "Doppler averaging kernel",
            format!("sizes must be odd, got {kernel:?}"),
        ));
    }
    Ok(())
}

impl Autocorrelation {
    /// The same estimates averaged over a spatial box of `kernel` = (rows, cols) pixels (odd
    /// sizes), as [`autocorrelation`] averages them: for estimates summed over several segments of
    /// a recording before averaging (the average is linear, so the order does not matter).
    pub fn box_averaged(self, kernel: (usize, usize)) -> Result<Autocorrelation> {
        check_kernel(kernel)?;
        if kernel == (1, 1) {
            return Ok(self);
        }
        Ok(Autocorrelation {
            power: box_average(&self.power, kernel),
            r1: box_average(&self.r1, kernel),
        })
    }
}

fn box_average<T>(map: &Array2<T>, kernel: (usize, usize)) -> Array2<T>
where
    T: Copy + Default + std::ops::AddAssign + std::ops::Div<f64, Output = T>,
{
    let (nz, nx) = map.dim();
    let (hz, hx) = (kernel.0 / 2, kernel.1 / 2);
    Array2::from_shape_fn((nz, nx), |(z, x)| {
        let (z0, z1) = (z.saturating_sub(hz), (z + hz + 1).min(nz));
        let (x0, x1) = (x.saturating_sub(hx), (x + hx + 1).min(nx));
        let mut acc = T::default();
        for zz in z0..z1 {
            for xx in x0..x1 {
                acc += map[[zz, xx]];
            }
        }
        acc / ((z1 - z0) * (x1 - x0)) as f64
    })
}

/// Axial-lag autocorrelation R(1, 0) per pixel, shape (nz, nx): the mean over frames of
/// S*(z)·S(z + 1 pixel) (the last row uses the pair above it), averaged over a spatial box of
/// `kernel` = (rows, cols) pixels like [`autocorrelation`]. `series` is (nz, nx, frames) with the
/// carrier phase restored (as [`crate::form::beamform::beamform`] gives it) and needs nz ≥ 2.
pub fn axial_autocorrelation(
    series: ArrayView3<Complex32>,
    kernel: (usize, usize),
) -> Result<Array2<Complex64>> {
    let (nz, nx, nf) = series.dim();
    if nz < 2 || nf < 1 {
        return Err(invalid(
            "Doppler",
            format!(
                "the axial autocorrelation needs at least 2 rows and 1 frame, got {nz} rows and {nf} frames"
            ),
        ));
    }
    check_kernel(kernel)?;
    let mut r = Array2::<Complex64>::zeros((nz, nx));
    r.axis_iter_mut(Axis(0))
        .into_par_iter()
        .enumerate()
        .for_each(|(iz, mut row)| {
            let z0 = iz.min(nz - 2);
            for (ix, out) in row.iter_mut().enumerate() {
                let (a, b) = (
                    series.slice(s![z0, ix, ..]),
                    series.slice(s![z0 + 1, ix, ..]),
                );
                let mut acc = Complex64::new(0.0, 0.0);
                for (u, v) in a.iter().zip(b.iter()) {
                    let p = u.conj() * v;
                    acc += Complex64::new(p.re as f64, p.im as f64);
                }
                *out = acc / nf as f64;
            }
        });
    if kernel != (1, 1) {
        r = box_average(&r, kernel);
    }
    Ok(r)
}

/// How an image series samples depth, which turns the phase of R(1, 0) into a frequency.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxialSampling {
    /// Round-trip delay added by one axial pixel step (s): (1 + cos θ)·Δz / c, the straight-receive
    /// model of the projection itself.
    pub step_delay: f64,
    /// Frequency around which the axial phase is unwrapped (Hz), usually f_0 or the demodulation
    /// frequency: mean frequencies are read within ± 1/(2·step_delay) of it.
    pub reference_frequency: f64,
}

impl AxialSampling {
    /// Axial sampling of an image of angle `angle` (rad) with pixel step `axial_step` (m) at sound
    /// speed `sound_speed` (m/s), unwrapped around `reference_frequency` (Hz). Refuses steps so
    /// coarse that frequencies within ± f_ref/4 of f_ref would be ambiguous (Δz above about λ).
    pub fn new(
        axial_step: f64,
        angle: f64,
        sound_speed: f64,
        reference_frequency: f64,
    ) -> Result<Self> {
        require_positive("axial pixel step", axial_step)?;
        require_positive("speed of sound", sound_speed)?;
        require_positive("reference frequency", reference_frequency)?;
        if !(angle.is_finite() && angle.abs() < std::f64::consts::FRAC_PI_2) {
            return Err(invalid(
                "angle",
                format!("{angle} rad is not within (−π/2, π/2)"),
            ));
        }
        Self::with_weight(
            axial_step,
            crate::estimate::vector::projection_weights(angle).1,
            sound_speed,
            reference_frequency,
        )
    }

    /// As [`AxialSampling::new`] for an image whose echo path lengthens by `axial_weight` × the
    /// depth change (1 + cos θ for one angle; 1 + the mean cos θ for a compounded image).
    pub fn with_weight(
        axial_step: f64,
        axial_weight: f64,
        sound_speed: f64,
        reference_frequency: f64,
    ) -> Result<Self> {
        require_positive("axial pixel step", axial_step)?;
        require_positive("axial weight", axial_weight)?;
        require_positive("speed of sound", sound_speed)?;
        require_positive("reference frequency", reference_frequency)?;
        let step_delay = axial_weight * axial_step / sound_speed;
        if 0.5 / step_delay < 0.25 * reference_frequency {
            return Err(invalid(
                "axial pixel step",
                format!(
                    "{:.1} µm is too coarse to measure the mean frequency (at most {:.1} µm at {:.2} MHz)",
                    axial_step * 1e6,
                    2.0 * sound_speed / (axial_weight * reference_frequency) * 1e6,
                    reference_frequency * 1e-6
                ),
            ));
        }
        Ok(AxialSampling {
            step_delay,
            reference_frequency,
        })
    }

    /// Mean RF frequency (Hz) from R(1, 0): f̄ = (arg R(1, 0)/2π + m) / step_delay, with m the
    /// integer that puts f̄ nearest the reference frequency.
    pub fn mean_frequency(&self, r_axial: Complex64) -> f64 {
        let cycles = r_axial.arg() / std::f64::consts::TAU;
        let m = (self.reference_frequency * self.step_delay - cycles).round();
        (cycles + m) / self.step_delay
    }
}

/// Loupas 2-D autocorrelation velocity (m/s) from one lag-1 value `r1` and one axial-lag value
/// `r_axial`: V = −c·f_frame·arg R(0, 1) / (4π f̄), f̄ = [`AxialSampling::mean_frequency`];
/// 0 where either is zero or f̄ is not positive.
pub fn loupas_velocity(
    r1: Complex64,
    r_axial: Complex64,
    sound_speed: f64,
    frame_rate: f64,
    axial: &AxialSampling,
) -> f64 {
    let f = axial.mean_frequency(r_axial);
    if r1.norm() > 0.0 && r_axial.norm() > 0.0 && f > 0.0 {
        -sound_speed * frame_rate * r1.arg() / (4.0 * std::f64::consts::PI * f)
    } else {
        0.0
    }
}

/// Projection velocity V_θ (m/s) per pixel by the Loupas 2-D autocorrelation: [`loupas_velocity`]
/// of each pixel's R(0, 1) (`r1`, from [`autocorrelation`]) and R(1, 0) (`r_axial`, from
/// [`axial_autocorrelation`]), both (nz, nx).
pub fn projection_velocity_loupas(
    r1: &Array2<Complex64>,
    r_axial: &Array2<Complex64>,
    sound_speed: f64,
    frame_rate: f64,
    axial: &AxialSampling,
) -> Result<Array2<f64>> {
    require_positive("speed of sound", sound_speed)?;
    require_positive("frame rate", frame_rate)?;
    if r1.dim() != r_axial.dim() {
        return Err(Error::Shape(format!(
            "lag-1 autocorrelation {:?} and axial autocorrelation {:?} differ in shape",
            r1.dim(),
            r_axial.dim()
        )));
    }
    Ok(Zip::from(r1)
        .and(r_axial)
        .map_collect(|&a, &b| loupas_velocity(a, b, sound_speed, frame_rate, axial)))
}

/// Which frequency turns the lag-1 phase into velocity (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DopplerEstimator {
    /// The nominal frequency: the demodulation (centre) frequency f_0 (Kasai et al. 1985; the
    /// paper's eq. 5). Reads low by the ratio of the image's mean frequency to f_0.
    Kasai,
    /// The mean RF frequency measured at every pixel from the axial lag at temporal lags ±1
    /// (2-D autocorrelation, Loupas et al. 1995): unbiased whatever the echo spectrum.
    #[default]
    Loupas,
}

impl DopplerEstimator {
    /// Every estimator, in the order of their option names.
    pub const ALL: [DopplerEstimator; 2] = [DopplerEstimator::Kasai, DopplerEstimator::Loupas];

    /// Its name in settings and reports: "kasai" or "loupas".
    pub fn label(self) -> &'static str {
        match self {
            DopplerEstimator::Kasai => "kasai",
            DopplerEstimator::Loupas => "loupas",
        }
    }

    /// Refuses a series this estimator cannot read on `geometry`: Loupas on an axial step too
    /// coarse for [`AxialSampling::with_weight`] (the error says what to do); Kasai reads any.
    pub fn check(self, geometry: &DopplerGeometry) -> Result<()> {
        match self {
            DopplerEstimator::Kasai => Ok(()),
            DopplerEstimator::Loupas => geometry.loupas_axial().map(|_| ()),
        }
    }

    /// One sentence for reports.
    pub fn describe(self) -> &'static str {
        match self {
            DopplerEstimator::Kasai => {
                "lag-1 autocorrelation phase scaled by the nominal centre frequency (Kasai; the paper's eq. 5)"
            }
            DopplerEstimator::Loupas => {
                "lag-1 autocorrelation phase scaled by the mean RF frequency measured at each pixel from the axial lags within frames and at temporal lags ±1, mixed 2:1 (2-D autocorrelation, Loupas), unbiased by the echo spectrum and attenuation, and by the speed of fast flow"
            }
        }
    }
}

/// What turns an image series' autocorrelations into velocity: its sampling and geometry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DopplerGeometry {
    /// Speed of sound (m/s).
    pub sound_speed: f64,
    /// Slow-time rate of the series (Hz).
    pub frame_rate: f64,
    /// Demodulation frequency of the IQ data (Hz): Kasai's frequency, and the frequency around
    /// which Loupas unwraps the axial phase.
    pub demodulation_frequency: f64,
    /// Axial pixel step of the image (m).
    pub axial_step: f64,
    /// How much the echo path lengthens per unit of depth: 1 + cos θ for one angle, 1 + the mean
    /// cos θ for a compounded image.
    pub axial_weight: f64,
    /// Lateral pixel step of the image (m).
    pub lateral_step: f64,
    /// The model's lateral weight: how much the echo path lengthens per unit of lateral motion,
    /// sin θ for one angle (the mean sin θ for a compounded image).
    pub lateral_weight: f64,
}

/// Doppler of one image series, every map (nz, nx).
#[derive(Debug, Clone, PartialEq)]
pub struct DopplerMaps {
    /// Mean |S|² over frames (power Doppler), averaged over the kernel.
    pub power: Array2<f64>,
    /// Lag-1 autocorrelation R(0, 1), averaged over the kernel.
    pub r1: Array2<Complex64>,
    /// Mean RF frequency the phase was scaled by (Hz): measured per pixel (Loupas) or the
    /// demodulation frequency (Kasai).
    pub mean_frequency: Array2<f64>,
    /// Velocity along the series' Doppler direction (m/s): V = −c·f_frame·arg R / (4π f̄);
    /// 0 where R is 0. For one angle this is the projection V_θ.
    pub velocity: Array2<f64>,
    /// The lateral weight of this series' projection at each pixel, in the model
    /// Vx·s + Vz·(1 + cos θ) = 2·V: the geometry's sin θ (Kasai), or measured (Loupas) as the
    /// mean lateral wavenumber over the mean wavenumber 2π f̄ / c of the image, which the finite
    /// receive aperture and the speckle make differ from sin θ by up to a few hundredths.
    pub lateral_weight: Array2<f64>,
}

/// Largest lateral step (in wavelengths at the demodulation frequency) at which Loupas measures
/// the lateral weight: the image's lateral wavenumbers reach k·(|sin θ| + sin φ_max), with
/// φ_max ≈ 27° at F# 1 and 18° at F# 1.5, and their phase over one step must stay within ±π.
/// Coarser grids keep the model's sin θ.
pub const LATERAL_STEP_MAX_WAVELENGTHS: f64 = 0.5;

/// The Doppler kernel of the mean frequency: the lag-1 kernel widened by one pixel on each side.
/// Why: f̄ follows the echo spectrum and the depth, which change over many pixels, and averaging
/// it a little wider than the lag-1 phase steadies it where the phase is noisy (on the paper's
/// spiral, 3 × 3 for a 1 × 1 kernel took the no-noise Vx RMSE from 3.60 to 3.38 mm/s).
pub fn mean_frequency_kernel(kernel: (usize, usize)) -> (usize, usize) {
    (kernel.0 + 2, kernel.1 + 2)
}

/// Weight of the same-frame spatial lag in the spatial phase that turns a Doppler phase into
/// velocity (the mean frequency f̄, and the lateral wavenumber); the pair at temporal lags ±1
/// ([`axial_autocorrelation_lag1`]) takes the rest.
///
/// Why a mix: a speckle pattern that moves by a delay τ_d per frame has the spatio-temporal
/// autocorrelation C(τ − m·τ_d) at spatial lag τ and temporal lag m, with
/// arg C(τ) = 2π f̄ τ − a·τ³ + … (a ∝ the spectrum's third cumulant, its skew). The Doppler
/// phase is arg C(−τ_d), so the frequency that converts it exactly is the secant
/// f̄ − a·τ_d²/2π. Per unit lag Δ, the same-frame lag reads f̄ − a·Δ²/2π (short of the secant by
/// a·τ_d²/2π) and the pair at temporal lags ±1 reads f̄ − a·(Δ² + 3τ_d²)/2π (beyond it by twice
/// that): 2/3 and 1/3 of them leave only the a·Δ² of the grid step, whatever the speed, wrapped or
/// not. The pair alone was unbiased by white noise but its error grows as the square of the
/// speed: a plug-flow tube at 3× v_N (60°, 100 frames, no noise, 0.056 mm grid) read 71.6 % of
/// its lumen within 10 % of the peak, Vx RMSE 11.6 mm/s; the same-frame lag alone 93.9 %,
/// 7.1 mm/s; the mix 98.9 %, 4.7 mm/s (at 0 dB noise 65.7, 84.9 and 90.5 %). The same-frame lag
/// also holds the receiver noise's own spatial correlation, which pulls f̄ toward the noise band
/// at low SNR; the mix keeps a third of the noise-immune pair.
pub const SAME_FRAME_WEIGHT: f64 = 2.0 / 3.0;

/// The [`SAME_FRAME_WEIGHT`] mix of a same-frame and a temporal-lag-±1 reading of one quantity
/// (a frequency, or an unwrapped phase).
fn secant(same: f64, turned: f64) -> f64 {
    SAME_FRAME_WEIGHT * same + (1.0 - SAME_FRAME_WEIGHT) * turned
}

/// Noise-immune axial-lag autocorrelation per pixel, (nz, nx): with R(1, ±1) the means over
/// frames of S*(z, t)·S(z + 1, t + 1) and S*(z, t + 1)·S(z + 1, t) (the last row pairs with the
/// row above), each averaged over `kernel`, R(1, +1)·e^{−iφ} + R(1, −1)·e^{+iφ}, φ = arg `r1`
/// (the lag-1 autocorrelation, same shape). Both terms carry the axial phase ± the Doppler phase;
/// removing φ leaves the axial phase of [`axial_autocorrelation`] without the receiver noise's
/// own axial correlation (white noise does not correlate across frames). Needs nz ≥ 2 and ≥ 2
/// frames.
pub fn axial_autocorrelation_lag1(
    series: ArrayView3<Complex32>,
    r1: &Array2<Complex64>,
    kernel: (usize, usize),
) -> Result<Array2<Complex64>> {
    spatial_lag1(series, r1, kernel, Axis(0))
}

/// As [`axial_autocorrelation_lag1`], one pixel to the side (+x): its phase is the mean lateral
/// wavenumber times the lateral step. Needs nx ≥ 2 and ≥ 2 frames.
pub fn lateral_autocorrelation_lag1(
    series: ArrayView3<Complex32>,
    r1: &Array2<Complex64>,
    kernel: (usize, usize),
) -> Result<Array2<Complex64>> {
    spatial_lag1(series, r1, kernel, Axis(1))
}

/// The spatial lag of one pixel along `along` (Axis(0): depth, Axis(1): lateral) at temporal lags
/// ±1, with the Doppler phase of `r1` removed; see [`axial_autocorrelation_lag1`].
fn spatial_lag1(
    series: ArrayView3<Complex32>,
    r1: &Array2<Complex64>,
    kernel: (usize, usize),
    along: Axis,
) -> Result<Array2<Complex64>> {
    check_kernel(kernel)?;
    let (nz, nx, _) = series.dim();
    if r1.dim() != (nz, nx) {
        return Err(Error::Shape(format!(
            "lag-1 autocorrelation {:?} for a series of {nz} × {nx} pixels",
            r1.dim()
        )));
    }
    Ok(spatial_lag_means(series, along)?.rotated(r1, kernel))
}

/// The spatial-lag products of one pixel step at temporal lags ±1 and within frames, per pixel
/// (nz, nx), as means over the frame pairs (frames) and not yet averaged in space: the raw
/// material of [`axial_autocorrelation_lag1`], [`lateral_autocorrelation_lag1`] and of the
/// phase that scales Loupas's velocity ([`SAME_FRAME_WEIGHT`]). Means over different frames add
/// as any mean does ([`Moments::merge`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SpatialLag {
    /// Mean over frame pairs of S*(p, t)·S(p′, t + 1), p′ the pixel one step along the lag (the
    /// last pixel of a line pairs with the one before it, roles swapped).
    pub plus: Array2<Complex64>,
    /// Mean over frame pairs of S*(p, t + 1)·S(p′, t).
    pub minus: Array2<Complex64>,
    /// Mean over frames of S*(p, t)·S(p′, t): the same lag within each frame.
    pub same: Array2<Complex64>,
}

impl SpatialLag {
    /// Both products averaged over `kernel` (odd sizes), then R(+1)·e^{−iφ} + R(−1)·e^{+iφ} with
    /// φ = arg `r1` (same shape): the spatial phase without the Doppler phase.
    fn rotated(&self, r1: &Array2<Complex64>, kernel: (usize, usize)) -> Array2<Complex64> {
        let (plus, minus) = if kernel == (1, 1) {
            (self.plus.clone(), self.minus.clone())
        } else {
            (
                box_average(&self.plus, kernel),
                box_average(&self.minus, kernel),
            )
        };
        Zip::from(&plus)
            .and(&minus)
            .and(r1)
            .map_collect(|&p, &m, &r| {
                let turn = if r.norm() > 0.0 {
                    r / r.norm()
                } else {
                    Complex64::new(1.0, 0.0)
                };
                p * turn.conj() + m * turn
            })
    }
}

/// [`SpatialLag`] of `series` (nz, nx, frames) one pixel along `along`.
fn spatial_lag_means(series: ArrayView3<Complex32>, along: Axis) -> Result<SpatialLag> {
    let (nz, nx, nf) = series.dim();
    let (n_along, what) = if along == Axis(0) {
        (nz, "rows")
    } else {
        (nx, "columns")
    };
    if n_along < 2 || nf < 2 {
        return Err(invalid(
            "Doppler",
            format!(
                "a spatial-lag autocorrelation needs at least 2 {what} and 2 frames, got {n_along} {what} and {nf} frames"
            ),
        ));
    }
    let mut plus = Array2::<Complex64>::zeros((nz, nx));
    let mut minus = Array2::<Complex64>::zeros((nz, nx));
    let mut same = Array2::<Complex64>::zeros((nz, nx));
    plus.axis_iter_mut(Axis(0))
        .into_par_iter()
        .zip(minus.axis_iter_mut(Axis(0)))
        .zip(same.axis_iter_mut(Axis(0)))
        .enumerate()
        .for_each(|(iz, ((mut p_row, mut m_row), mut q_row))| {
            for ix in 0..nx {
                // The pixel and its neighbour one step along `along`; the last one pairs with the
                // one before it, roles swapped, so the phase keeps its sign.
                let i = if along == Axis(0) { iz } else { ix };
                let (first, second) = if i + 1 < n_along {
                    (i, i + 1)
                } else {
                    (i - 1, i)
                };
                let at = |j: usize| {
                    if along == Axis(0) {
                        series.slice(s![j, ix, ..])
                    } else {
                        series.slice(s![iz, j, ..])
                    }
                };
                let (a, b) = (at(first), at(second));
                // A pixel's frames are contiguous in a formed series: summed as slices, without
                // an index computation per term.
                let (a, b) = (contiguous(&a), contiguous(&b));
                let (mut p, mut m) = (Complex64::new(0.0, 0.0), Complex64::new(0.0, 0.0));
                for ((a0, a1), (b0, b1)) in a.iter().zip(&a[1..]).zip(b.iter().zip(&b[1..])) {
                    let up = a0.conj() * b1;
                    let down = a1.conj() * b0;
                    p += Complex64::new(up.re as f64, up.im as f64);
                    m += Complex64::new(down.re as f64, down.im as f64);
                }
                let mut q = Complex64::new(0.0, 0.0);
                for (a0, b0) in a.iter().zip(b.iter()) {
                    let same = a0.conj() * b0;
                    q += Complex64::new(same.re as f64, same.im as f64);
                }
                let pairs = (nf - 1) as f64;
                p_row[ix] = p / pairs;
                m_row[ix] = m / pairs;
                q_row[ix] = q / nf as f64;
            }
        });
    Ok(SpatialLag { plus, minus, same })
}

impl DopplerGeometry {
    /// Whether Loupas measures the lateral weight on this grid: a lateral step within
    /// [`LATERAL_STEP_MAX_WAVELENGTHS`] wavelengths at the demodulation frequency (else the
    /// model's sin θ is kept).
    pub fn measures_lateral(&self) -> bool {
        let wavelength = self.sound_speed / self.demodulation_frequency;
        let step = self.lateral_step;
        step.is_finite() && step > 0.0 && step <= LATERAL_STEP_MAX_WAVELENGTHS * wavelength
    }

    /// The axial sampling Loupas reads the mean frequency with, or the error that says the grid
    /// is too coarse for it (and what to do).
    fn loupas_axial(&self) -> Result<AxialSampling> {
        AxialSampling::with_weight(
            self.axial_step,
            self.axial_weight,
            self.sound_speed,
            self.demodulation_frequency,
        )
        .map_err(|e| {
            invalid(
                "Doppler estimator",
                format!(
                    "loupas: {e}; use a finer grid, or the kasai estimator (which scales by the nominal frequency)"
                ),
            )
        })
    }
}

/// What [`doppler_maps`] derives every map from, per pixel (nz, nx), before any spatial
/// averaging: means over a series' frames (power) and frame pairs (the rest). Being means, those
/// of consecutive parts of a recording combine into the whole's ([`Moments::merge`]; the pairs
/// across a cut are not counted), which is how a long recording is processed in segments.
#[derive(Debug, Clone, PartialEq)]
pub struct Moments {
    /// Mean |S|² over the frames (|IQ|² units).
    pub power: Array2<f64>,
    /// Mean S*(t)·S(t + 1) over the frame pairs (|IQ|² units).
    pub r1: Array2<Complex64>,
    /// The axial lags at temporal lags ±1 and within frames (Loupas only; `None` for Kasai).
    pub axial: Option<SpatialLag>,
    /// The lateral lags at temporal lags ±1 and within frames (Loupas on a grid that
    /// [`DopplerGeometry::measures_lateral`]; else `None`).
    pub lateral: Option<SpatialLag>,
    /// The spatial lags within frames, summed over the image: the resolution cell
    /// ([`crate::estimate::partial_volume`]); measured only when asked for (`None` from [`moments`];
    /// [`crate::pipeline::moments`] with the partial-volume correction on).
    pub cell: Option<crate::estimate::partial_volume::CellLags>,
    /// Frames the power is a mean over.
    pub frames: usize,
    /// Frame pairs the lag-1 products are means over.
    pub pairs: usize,
}

impl Moments {
    /// Combines `other`'s moments (other frames of the same pixels, measured alike) into these:
    /// each mean weighted by its frames or pairs. Refuses moments of another shape or estimator.
    pub fn merge(&mut self, other: &Moments) -> Result<()> {
        if self.power.dim() != other.power.dim()
            || self.axial.is_some() != other.axial.is_some()
            || self.lateral.is_some() != other.lateral.is_some()
        {
            return Err(Error::Shape(format!(
                "moments of {:?} pixels cannot combine with moments of {:?} measured otherwise",
                other.power.dim(),
                self.power.dim()
            )));
        }
        let (f0, f1) = (self.frames as f64, other.frames as f64);
        let (p0, p1) = (self.pairs as f64, other.pairs as f64);
        let (frames, pairs) = ((f0 + f1).max(1.0), (p0 + p1).max(1.0));
        Zip::from(&mut self.power)
            .and(&other.power)
            .for_each(|a, &b| *a = (*a * f0 + b * f1) / frames);
        let by_pairs = |a: &mut Array2<Complex64>, b: &Array2<Complex64>| {
            Zip::from(a)
                .and(b)
                .for_each(|a, &b| *a = (*a * p0 + b * p1) / pairs)
        };
        by_pairs(&mut self.r1, &other.r1);
        for (mine, theirs) in [
            (self.axial.as_mut(), other.axial.as_ref()),
            (self.lateral.as_mut(), other.lateral.as_ref()),
        ] {
            if let (Some(m), Some(t)) = (mine, theirs) {
                by_pairs(&mut m.plus, &t.plus);
                by_pairs(&mut m.minus, &t.minus);
                Zip::from(&mut m.same)
                    .and(&t.same)
                    .for_each(|a, &b| *a = (*a * f0 + b * f1) / frames);
            }
        }
        self.cell = match (&self.cell, &other.cell) {
            (Some(mine), Some(theirs)) => Some(mine.merged(self.frames, theirs, other.frames)),
            _ => None,
        };
        self.frames += other.frames;
        self.pairs += other.pairs;
        Ok(())
    }
}

/// The [`Moments`] of `series` (nz, nx, frames ≥ 2) that `estimator` needs on this `geometry`:
/// power and lag-1 for both, the axial lag for Loupas (which needs ≥ 2 rows and an axial step
/// fine enough for [`AxialSampling::with_weight`], refused here, before the work), the lateral
/// lag where Loupas measures the lateral weight.
pub fn moments(
    series: ArrayView3<Complex32>,
    estimator: DopplerEstimator,
    geometry: &DopplerGeometry,
) -> Result<Moments> {
    let (_, nx, nf) = series.dim();
    let (axial, lateral) = match estimator {
        DopplerEstimator::Kasai => (None, None),
        DopplerEstimator::Loupas => {
            geometry.loupas_axial()?;
            let lateral = if nx >= 2 && geometry.measures_lateral() {
                Some(spatial_lag_means(series, Axis(1))?)
            } else {
                None
            };
            (Some(spatial_lag_means(series, Axis(0))?), lateral)
        }
    };
    let raw = autocorrelation(series, (1, 1))?;
    Ok(Moments {
        power: raw.power,
        r1: raw.r1,
        axial,
        lateral,
        cell: None,
        frames: nf,
        pairs: nf - 1,
    })
}

/// Power, lag-1 autocorrelation, mean frequency and velocity of `series` (nz, nx, frames) with
/// `estimator`, the autocorrelations averaged over `kernel` (odd (rows, cols)); the mean frequency
/// over [`mean_frequency_kernel`]. Loupas needs ≥ 2 rows and an axial step fine enough for
/// [`AxialSampling::with_weight`]; a pixel whose axial autocorrelation is zero keeps the
/// demodulation frequency. The same as [`maps_of_moments`] of [`moments`].
pub fn doppler_maps(
    series: ArrayView3<Complex32>,
    kernel: (usize, usize),
    estimator: DopplerEstimator,
    geometry: &DopplerGeometry,
) -> Result<DopplerMaps> {
    check_kernel(kernel)?;
    maps_of_moments(
        &moments(series, estimator, geometry)?,
        kernel,
        estimator,
        geometry,
    )
}

/// The maps of [`doppler_maps`] from a series' [`Moments`] (or several series' merged): every
/// product averaged over `kernel` (the mean frequency's over [`mean_frequency_kernel`]), then the
/// phases turned into frequency and velocity. Loupas needs moments measured for Loupas.
pub fn maps_of_moments(
    moments: &Moments,
    kernel: (usize, usize),
    estimator: DopplerEstimator,
    geometry: &DopplerGeometry,
) -> Result<DopplerMaps> {
    let DopplerGeometry {
        sound_speed,
        frame_rate,
        demodulation_frequency: f_demod,
        ..
    } = *geometry;
    require_positive("speed of sound", sound_speed)?;
    require_positive("frame rate", frame_rate)?;
    require_positive("demodulation frequency", f_demod)?;
    check_kernel(kernel)?;
    let averaged = |map: &Array2<Complex64>, k: (usize, usize)| {
        if k == (1, 1) {
            map.clone()
        } else {
            box_average(map, k)
        }
    };
    let r1 = averaged(&moments.r1, kernel);
    let power = if kernel == (1, 1) {
        moments.power.clone()
    } else {
        box_average(&moments.power, kernel)
    };
    let (mean_frequency, lateral_weight) = match estimator {
        DopplerEstimator::Kasai => (
            Array2::from_elem(r1.dim(), f_demod),
            Array2::from_elem(r1.dim(), geometry.lateral_weight),
        ),
        DopplerEstimator::Loupas => {
            let axial = geometry.loupas_axial()?;
            let Some(axial_lag) = &moments.axial else {
                return Err(invalid(
                    "Doppler estimator",
                    "loupas needs the axial-lag moments, which these moments were measured without",
                ));
            };
            let wide = mean_frequency_kernel(kernel);
            let r1_wide = averaged(&moments.r1, wide);
            let r_axial = axial_lag.rotated(&r1_wide, wide);
            let r_axial_same = averaged(&axial_lag.same, wide);
            let f_bar = Zip::from(&r_axial)
                .and(&r_axial_same)
                .map_collect(|&r, &q| {
                    let f = secant(axial.mean_frequency(q), axial.mean_frequency(r));
                    if r.norm() > 0.0 && q.norm() > 0.0 && f > 0.0 {
                        f
                    } else {
                        f_demod
                    }
                });
            let lateral = match &moments.lateral {
                Some(lateral_lag) if geometry.measures_lateral() => {
                    let r_lateral = lateral_lag.rotated(&r1_wide, wide);
                    let r_lateral_same = averaged(&lateral_lag.same, wide);
                    let step = geometry.lateral_step;
                    let wavelength = sound_speed / f_demod;
                    let tau = std::f64::consts::TAU;
                    let expected = tau * geometry.lateral_weight * step / wavelength;
                    let unwrapped =
                        |r: Complex64| r.arg() + tau * ((expected - r.arg()) / tau).round();
                    Zip::from(&r_lateral)
                        .and(&r_lateral_same)
                        .and(&f_bar)
                        .map_collect(|&r, &q, &f| {
                            if r.norm() > 0.0 && q.norm() > 0.0 {
                                let phase = secant(unwrapped(q), unwrapped(r));
                                // k̄x / k̄, k̄ = 2π f̄ / c.
                                phase / step * sound_speed / (tau * f)
                            } else {
                                geometry.lateral_weight
                            }
                        })
                }
                _ => Array2::from_elem(r1.dim(), geometry.lateral_weight),
            };
            (f_bar, lateral)
        }
    };
    // −scale·arg R with scale = c·f_frame/(4π f̄), in the order of [`projection_velocity`], so
    // that Kasai's maps are bit for bit those of the lag-1 stage functions.
    let velocity = Zip::from(&r1).and(&mean_frequency).map_collect(|&r, &f| {
        if r.norm() > 0.0 {
            -(sound_speed * frame_rate / (4.0 * std::f64::consts::PI * f)) * r.arg()
        } else {
            0.0
        }
    });
    Ok(DopplerMaps {
        power,
        r1,
        mean_frequency,
        velocity,
        lateral_weight,
    })
}

/// Signed power Doppler (|IQ|² units): each pixel's power Doppler carrying the sign of its colour
/// Doppler (axial velocity, positive = away from the probe), the direction-coded map that
/// functional-ultrasound work reads arteries and veins from first (flow towards and away from the
/// probe). Zero where the axial velocity is zero; NaN where either input is not finite.
pub fn signed_power<D: ndarray::Dimension>(
    power: &ndarray::Array<f64, D>,
    axial_velocity: &ndarray::Array<f64, D>,
) -> ndarray::Array<f64, D> {
    Zip::from(power).and(axial_velocity).map_collect(|&p, &v| {
        if !(p.is_finite() && v.is_finite()) {
            f64::NAN
        } else if v == 0.0 {
            0.0
        } else {
            p.copysign(v)
        }
    })
}

/// Velocity scale of the phase of R: V = −scale · arg R, scale = c·f_frame/(4π f_0) (m/s per rad).
pub fn velocity_scale(sound_speed: f64, frame_rate: f64, center_frequency: f64) -> Result<f64> {
    require_positive("speed of sound", sound_speed)?;
    require_positive("frame rate", frame_rate)?;
    require_positive("centre frequency", center_frequency)?;
    Ok(sound_speed * frame_rate / (4.0 * std::f64::consts::PI * center_frequency))
}

/// Nyquist velocity (m/s) of the projection V_θ: c·f_frame/(4 f_0).
pub fn nyquist_velocity(sound_speed: f64, frame_rate: f64, center_frequency: f64) -> f64 {
    sound_speed * frame_rate / (4.0 * center_frequency)
}

/// Projection velocity V_θ (m/s) per pixel from R (eq. 5); positive means the echo path lengthens.
pub fn projection_velocity(
    r1: &Array2<Complex64>,
    sound_speed: f64,
    frame_rate: f64,
    center_frequency: f64,
) -> Result<Array2<f64>> {
    let scale = velocity_scale(sound_speed, frame_rate, center_frequency)?;
    Ok(r1.mapv(|r| {
        if r.norm() > 0.0 {
            -scale * r.arg()
        } else {
            0.0
        }
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn signed_power_is_the_power_with_the_flow_direction() {
        let power = ndarray::array![[2.0, 3.0, 5.0], [7.0, f64::NAN, 1.0]];
        let axial = ndarray::array![[0.01, -0.002, 0.0], [f64::INFINITY, 0.1, -1e-300]];
        let signed = signed_power(&power, &axial);
        assert_eq!(signed.row(0).to_vec(), vec![2.0, -3.0, 0.0]);
        assert!(signed[[1, 0]].is_nan() && signed[[1, 1]].is_nan());
        assert_eq!(signed[[1, 2]], -1.0);
    }
    use ndarray::Array3;

    #[test]
    fn phase_ramp_gives_known_velocity() {
        let (c, fr, f0) = (1540.0, 1800.0, 15.625e6);
        let v_true = 0.01; // m/s, path lengthening
        let dphi = -v_true / velocity_scale(c, fr, f0).unwrap();
        let series = Array3::from_shape_fn((3, 4, 50), |(_, _, t)| {
            Complex32::from_polar(2.0, (dphi * t as f64) as f32)
        });
        let ac = autocorrelation(series.view(), (1, 1)).unwrap();
        let v = projection_velocity(&ac.r1, c, fr, f0).unwrap();
        assert!(v.iter().all(|&x| (x - v_true).abs() < 1e-6), "{v:?}");
        assert!(ac.power.iter().all(|&p| (p - 4.0).abs() < 1e-5));
        assert!(v_true < nyquist_velocity(c, fr, f0));
        // Kasai's maps are the lag-1 stage's velocity bit for bit (Python's `kasai` stage
        // function and `process` must agree exactly).
        let geometry = DopplerGeometry {
            sound_speed: c,
            frame_rate: fr,
            demodulation_frequency: f0,
            axial_step: 50e-6,
            axial_weight: 2.0,
            lateral_step: 50e-6,
            lateral_weight: 0.0,
        };
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut draw = || -> f32 { StandardNormal.sample(&mut rng) };
        let speckle = Array3::from_shape_fn((6, 5, 9), |_| Complex32::new(draw(), draw()));
        let maps =
            doppler_maps(speckle.view(), (1, 1), DopplerEstimator::Kasai, &geometry).unwrap();
        let lag1 = autocorrelation(speckle.view(), (1, 1)).unwrap();
        assert_eq!(
            maps.velocity,
            projection_velocity(&lag1.r1, c, fr, f0).unwrap()
        );
    }

    /// A pulse moving axially through depth: the axial lag gives its frequency (not f_0), and the
    /// Loupas velocity is right where the lag-1 one, scaled by f_0, is off by f/f_0.
    #[test]
    fn loupas_measures_the_mean_frequency() {
        let (c, fr, f0) = (1540.0, 2000.0, 15e6);
        let (f, angle, dz) = (13.5e6, 0.2f64, 40e-6);
        let v_true = 0.012; // projection velocity (m/s)
        let axial = AxialSampling::new(dz, angle, c, f0).unwrap();
        // Phase at depth row iz and frame t of an echo of frequency f whose path lengthens by
        // 2 v / f_frame per frame: 2π f·(step_delay·iz − 2 v t / (c f_frame)).
        let series = Array3::from_shape_fn((6, 3, 20), |(iz, _, t)| {
            let tau = axial.step_delay * iz as f64 - 2.0 * v_true * t as f64 / (c * fr);
            Complex32::from_polar(1.0, (std::f64::consts::TAU * f * tau) as f32)
        });
        let ac = autocorrelation(series.view(), (1, 1)).unwrap();
        let ra = axial_autocorrelation(series.view(), (3, 1)).unwrap();
        assert!(
            ra.iter()
                .all(|&r| (axial.mean_frequency(r) - f).abs() < 1e3)
        );
        let v = projection_velocity_loupas(&ac.r1, &ra, c, fr, &axial).unwrap();
        assert!(v.iter().all(|&x| (x - v_true).abs() < 1e-6), "{v:?}");
        let lag1 = projection_velocity(&ac.r1, c, fr, f0).unwrap();
        assert!(lag1.iter().all(|&x| (x - v_true * f / f0).abs() < 1e-6));
        // Too coarse a grid is refused; mismatched shapes too.
        assert!(AxialSampling::new(0.2e-3, 0.0, c, f0).is_err());
        let other = Array2::<Complex64>::zeros((2, 2));
        assert!(projection_velocity_loupas(&ac.r1, &other, c, fr, &axial).is_err());
    }

    /// Moments of two consecutive parts of a series, merged, are the moments of the whole less
    /// the one frame pair across the cut: checked against sums written out pixel by pixel, and
    /// the maps of the merge are the maps of those sums.
    #[test]
    fn merged_moments_are_the_sums_over_both_parts() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let (nz, nx, nf, cut) = (5, 4, 17, 7);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut draw = || -> f32 { StandardNormal.sample(&mut rng) };
        let series = Array3::from_shape_fn((nz, nx, nf), |_| Complex32::new(draw(), draw()));
        let geometry = DopplerGeometry {
            sound_speed: 1540.0,
            frame_rate: 1800.0,
            demodulation_frequency: 15.625e6,
            axial_step: 25e-6,
            axial_weight: 2.0,
            lateral_step: 40e-6,
            lateral_weight: 0.1,
        };
        let of = |range: std::ops::Range<usize>| {
            moments(
                series.slice(s![.., .., range]),
                DopplerEstimator::Loupas,
                &geometry,
            )
            .unwrap()
        };
        let mut merged = of(0..cut);
        merged.merge(&of(cut..nf)).unwrap();
        assert_eq!((merged.frames, merged.pairs), (nf, nf - 2));
        let c64 = |v: Complex32| Complex64::new(v.re as f64, v.im as f64);
        let pairs: Vec<usize> = (0..nf - 1).filter(|&t| t + 1 != cut).collect();
        // The products are formed in f32 (as the estimators form them) and summed in f64.
        let close = |a: Complex64, b: Complex64| (a - b).norm() < 1e-6 * (1.0 + b.norm());
        for iz in 0..nz {
            for ix in 0..nx {
                let at = |z: usize, x: usize, t: usize| c64(series[[z, x, t]]);
                let power = (0..nf).map(|t| at(iz, ix, t).norm_sqr()).sum::<f64>() / nf as f64;
                assert!((merged.power[[iz, ix]] - power).abs() < 1e-6 * power);
                let mean = |f: &dyn Fn(usize) -> Complex64| {
                    pairs.iter().map(|&t| f(t)).sum::<Complex64>() / pairs.len() as f64
                };
                let r1 = mean(&|t| at(iz, ix, t).conj() * at(iz, ix, t + 1));
                assert!(close(merged.r1[[iz, ix]], r1));
                // The axial neighbour one row deeper (the last row pairs with the one above).
                let (a, b) = if iz + 1 < nz {
                    (iz, iz + 1)
                } else {
                    (iz - 1, iz)
                };
                let axial = merged.axial.as_ref().unwrap();
                let plus = mean(&|t| at(a, ix, t).conj() * at(b, ix, t + 1));
                let minus = mean(&|t| at(a, ix, t + 1).conj() * at(b, ix, t));
                assert!(close(axial.plus[[iz, ix]], plus));
                assert!(close(axial.minus[[iz, ix]], minus));
                let (a, b) = if ix + 1 < nx {
                    (ix, ix + 1)
                } else {
                    (ix - 1, ix)
                };
                let lateral = merged.lateral.as_ref().unwrap();
                assert!(close(
                    lateral.plus[[iz, ix]],
                    mean(&|t| at(iz, a, t).conj() * at(iz, b, t + 1))
                ));
            }
        }
        // Kasai's moments lack the spatial lags: they neither merge with Loupas's nor give its maps.
        let kasai = moments(series.view(), DopplerEstimator::Kasai, &geometry).unwrap();
        assert!(kasai.axial.is_none() && kasai.lateral.is_none());
        assert!(merged.clone().merge(&kasai).is_err());
        assert!(maps_of_moments(&kasai, (1, 1), DopplerEstimator::Loupas, &geometry).is_err());
        // One part alone gives doppler_maps of that part.
        let whole =
            doppler_maps(series.view(), (3, 1), DopplerEstimator::Loupas, &geometry).unwrap();
        let again =
            maps_of_moments(&of(0..nf), (3, 1), DopplerEstimator::Loupas, &geometry).unwrap();
        assert_eq!(whole, again);
    }

    #[test]
    fn even_kernel_is_rejected() {
        let series = Array3::<Complex32>::zeros((3, 3, 4));
        assert!(autocorrelation(series.view(), (2, 1)).is_err());
        assert!(autocorrelation(Array3::<Complex32>::zeros((3, 3, 1)).view(), (1, 1)).is_err());
        assert!(axial_autocorrelation(series.view(), (1, 2)).is_err());
        assert!(
            axial_autocorrelation(Array3::<Complex32>::zeros((1, 3, 4)).view(), (1, 1)).is_err()
        );
    }
}
