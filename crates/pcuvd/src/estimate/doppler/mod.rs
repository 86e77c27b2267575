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

mod autocorrelation;
mod lag_sums;
mod loupas;
mod maps;
mod sliding;

pub use autocorrelation::*;
pub use lag_sums::CellLags;
pub use loupas::*;
pub use maps::*;
pub use sliding::*;

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

/// Whether `r` has a magnitude, |r| > 0, decided without computing it: the same answer as
/// `r.norm() > 0.0` for every value (an infinite part gives +∞ even beside a NaN; else a NaN
/// part gives NaN; else a part that is not zero gives more than zero, subnormals too). Every
/// pixel of every Doppler map asks it of several autocorrelations, where a hypotenuse each was
/// a percent of a default run.
#[inline]
pub(crate) fn has_magnitude(r: Complex64) -> bool {
    if r.re.is_infinite() || r.im.is_infinite() {
        return true;
    }
    !r.re.is_nan() && !r.im.is_nan() && (r.re != 0.0 || r.im != 0.0)
}

/// Projection velocity V_θ (m/s) per pixel from R (eq. 5); positive means the echo path lengthens.
pub fn projection_velocity(
    r1: &Array2<Complex64>,
    sound_speed: f64,
    frame_rate: f64,
    center_frequency: f64,
) -> Result<Array2<f64>> {
    let scale = velocity_scale(sound_speed, frame_rate, center_frequency)?;
    Ok(r1.mapv(|r| lag_velocity(r, scale)))
}

/// The projection velocity (m/s) of one lag-1 autocorrelation `r`, −scale·arg R (`scale` from
/// [`velocity_scale`]); 0 where R has no magnitude (no echo, or no phase to read).
pub(crate) fn lag_velocity(r: Complex64, scale: f64) -> f64 {
    if has_magnitude(r) {
        -scale * r.arg()
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The magnitude test answers as the hypotenuse does, on every pairing of zeros of both
    /// signs, subnormals, ordinary and extreme values, infinities and NaNs.
    #[test]
    fn has_magnitude_answers_as_the_norm_does() {
        let parts = [
            0.0,
            -0.0,
            f64::from_bits(1),
            -f64::from_bits(1),
            f64::MIN_POSITIVE,
            1e-300,
            -2.5,
            1.0,
            1e300,
            f64::MAX,
            f64::MIN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            -f64::NAN,
        ];
        for &re in &parts {
            for &im in &parts {
                let r = Complex64::new(re, im);
                assert_eq!(has_magnitude(r), r.norm() > 0.0, "{re:?} + {im:?}i");
            }
        }
    }

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
