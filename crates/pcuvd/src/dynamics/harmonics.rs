//! The cardiac-harmonic (Fourier) fit of each pixel's speed series.

use super::*;

/// Cardiac harmonics worth fitting with windows of `window_s` seconds at `heart_rate_hz`: those
/// the window's boxcar passes at ≥ 90 % (sinc(f·window) ≥ 0.9, i.e. f ≤ 0.25/window). Higher
/// harmonics are already blurred by the window, and fitting them mostly fits estimation noise: the
/// overlapping windows give only about one independent estimate per window length, and that noise
/// is concentrated at low frequencies, where the harmonics are. At least 1; 2 for the rat preset
/// (5.5 Hz, 20 ms windows: 11 Hz ≤ 12.5 Hz), where fitting a third harmonic (blurred by the
/// window to sinc(16.5 Hz · 20 ms) ≈ 0.83) gave larger RI errors on the vessel-network phantom.
pub fn auto_harmonics(heart_rate_hz: f64, window_s: f64) -> usize {
    let k = (0.25 / (window_s * heart_rate_hz)).floor();
    if k.is_finite() && k >= 1.0 {
        k as usize
    } else {
        1
    }
}

/// Least-squares fit of a mean plus the first harmonics of the heart rate to series sampled at
/// fixed times: the pseudo-inverse is computed once and applied to every pixel. Every part costs
/// in proportion to the samples (times × coefficients), none to their square: a long
/// recording's windows (4,800 in 24 s at a 5 ms step, 60,000 in five minutes) are fitted whole.
pub(super) struct HarmonicFit {
    /// Design matrix, (times × coefficients): 1, cos kωt, sin kωt.
    design: Mat<f64>,
    /// Its pseudo-inverse, (coefficients × times).
    pinv: Mat<f64>,
    /// Per harmonic, the noise power its (cos, sin) pair takes from window noise of unit
    /// variance ([`HarmonicFit::debiased`]).
    harmonic_noise: Vec<f64>,
    /// Orthonormal basis (times × columns) of a fit of more harmonics: what it leaves of a
    /// series is the noise, with little of the waveform's higher harmonics, which a sharp systole
    /// has.
    noise_basis: Mat<f64>,
    /// What it leaves of window noise of unit variance: the expected sum of squares.
    residual_noise: f64,
}

/// Harmonics fitted to measure the noise from what they leave: as many as a cardiac waveform
/// holds above the window's blur, at most a quarter of the samples' degrees of freedom.
const NOISE_FIT_HARMONICS: usize = 6;

/// The design matrix (times × `columns`) of a mean and harmonics of `heart_rate_hz` at `times`
/// (s): 1, cos kωt, sin kωt for k = 1, 2, …
fn harmonic_design(times: &[f64], heart_rate_hz: f64, columns: usize) -> Mat<f64> {
    let omega = 2.0 * std::f64::consts::PI * heart_rate_hz;
    Mat::<f64>::from_fn(times.len(), columns, |i, j| {
        let k = j.div_ceil(2) as f64;
        match j {
            0 => 1.0,
            _ if j % 2 == 1 => (k * omega * times[i]).cos(),
            _ => (k * omega * times[i]).sin(),
        }
    })
}

/// Correlation of the noise of two windows `lag` steps apart when each is `overlap` steps long:
/// white per frame, so two windows' means share 1 − |lag| / overlap of their frames.
fn window_correlation(lag: usize, overlap: f64) -> f64 {
    (1.0 - lag as f64 / overlap.max(1.0)).max(0.0)
}

/// Σ_ij a_i · C_ij · b_j for the windows' noise correlation C ([`window_correlation`]), which is
/// zero beyond `overlap` steps: the noise that the linear forms a and b share.
fn correlated(a: impl Fn(usize) -> f64, b: impl Fn(usize) -> f64, n: usize, overlap: f64) -> f64 {
    let reach = (overlap.max(1.0).ceil() as usize).min(n);
    (0..n)
        .map(|i| {
            let near = i.saturating_sub(reach - 1)..(i + reach).min(n);
            a(i) * near
                .map(|j| window_correlation(i.abs_diff(j), overlap) * b(j))
                .sum::<f64>()
        })
        .sum()
}

impl HarmonicFit {
    /// `None` when `harmonics` is 0 or the series is too short to fit that many.
    /// `overlap`: window length over the step between windows (the samples' noise correlation).
    pub(super) fn new(
        times: &[f64],
        heart_rate_hz: f64,
        harmonics: usize,
        overlap: f64,
    ) -> Option<HarmonicFit> {
        let columns = 2 * harmonics + 1;
        let n = times.len();
        if harmonics == 0 || n <= columns {
            return None;
        }
        let design_of = |columns: usize| harmonic_design(times, heart_rate_hz, columns);
        let design = design_of(columns);
        // D = QR, so D⁺ = R⁻¹Qᵀ.
        let qr = design.qr();
        let mut pinv = qr.compute_thin_Q().transpose().to_owned();
        qr.thin_R().solve_upper_triangular_in_place(&mut pinv);
        // Each coefficient's noise variance is (D⁺ C D⁺ᵀ)_kk.
        let coefficient_noise =
            |row: usize| correlated(|i| pinv[(row, i)], |j| pinv[(row, j)], n, overlap);
        let harmonic_noise = (1..=harmonics)
            .map(|k| coefficient_noise(2 * k - 1) + coefficient_noise(2 * k))
            .collect();
        let noise_harmonics = NOISE_FIT_HARMONICS
            .min((n / 4).saturating_sub(1) / 2)
            .max(harmonics);
        let noise_basis = design_of(2 * noise_harmonics + 1).qr().compute_thin_Q();
        // The residual's projector P = I − QQᵀ is symmetric and idempotent, so the noise it
        // leaves, trace(P C P), is trace(C) − trace(QᵀCQ).
        let kept: f64 = (0..noise_basis.ncols())
            .map(|k| correlated(|i| noise_basis[(i, k)], |j| noise_basis[(j, k)], n, overlap))
            .sum();
        let residual_noise = n as f64 * window_correlation(0, overlap) - kept;
        Some(HarmonicFit {
            design,
            pinv,
            harmonic_noise,
            noise_basis,
            residual_noise,
        })
    }

    /// As [`HarmonicFit::smooth`], each harmonic's amplitude debiased for the noise: the fitted
    /// (cos, sin) pair of a harmonic holds the waveform's power plus the noise's, so its power is
    /// reduced by the noise's expected share (estimated from what a fit of more harmonics leaves,
    /// whose noise correlates over overlapping windows) and its phase kept; a harmonic within the
    /// noise is dropped. Without it, a steady vein's jitter reads as a pulse, and its RI as an artery's.
    pub(super) fn debiased(&self, lane: &[f64]) -> Option<Vec<f64>> {
        let mut coefficients = self.coefficients(lane)?;
        let basis = &self.noise_basis;
        let projections: Vec<f64> = (0..basis.ncols())
            .map(|k| (0..lane.len()).map(|i| basis[(i, k)] * lane[i]).sum())
            .collect();
        let residual: f64 = (0..lane.len())
            .map(|i| {
                let fitted: f64 = projections
                    .iter()
                    .enumerate()
                    .map(|(k, p)| basis[(i, k)] * p)
                    .sum();
                (lane[i] - fitted).powi(2)
            })
            .sum();
        let variance = residual / self.residual_noise;
        for (k, noise) in self.harmonic_noise.iter().enumerate() {
            let (c, s) = (coefficients[2 * k + 1], coefficients[2 * k + 2]);
            let power = c * c + s * s;
            let gain = if power > 0.0 {
                (1.0 - variance * noise / power).max(0.0).sqrt()
            } else {
                0.0
            };
            coefficients[2 * k + 1] *= gain;
            coefficients[2 * k + 2] *= gain;
        }
        Some(self.curve(&coefficients))
    }

    /// The fitted curve at the sample times; `None` if `lane` has non-finite samples.
    pub(super) fn smooth(&self, lane: &[f64]) -> Option<Vec<f64>> {
        Some(self.curve(&self.coefficients(lane)?))
    }

    /// The least-squares coefficients of `lane`; `None` if it has non-finite samples.
    fn coefficients(&self, lane: &[f64]) -> Option<Vec<f64>> {
        if lane.iter().any(|v| !v.is_finite()) {
            return None;
        }
        Some(
            (0..self.pinv.nrows())
                .map(|j| (0..lane.len()).map(|i| self.pinv[(j, i)] * lane[i]).sum())
                .collect(),
        )
    }

    /// The curve of `coefficients` at the sample times.
    fn curve(&self, coefficients: &[f64]) -> Vec<f64> {
        (0..self.design.nrows())
            .map(|i| {
                coefficients
                    .iter()
                    .enumerate()
                    .map(|(j, c)| self.design[(i, j)] * c)
                    .sum()
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};

    /// One 5.5 Hz cycle sampled every 5 ms by 20 ms windows (the rat preset), and window noise of
    /// standard deviation `sigma` made as the windows make it: white per 5 ms step, each sample
    /// the mean of the four steps its window spans.
    fn cycle_with_noise(
        waveform: impl Fn(f64) -> f64,
        sigma: f64,
        seed: u64,
    ) -> (Vec<f64>, Vec<f64>) {
        let times: Vec<f64> = (0..36).map(|i| 0.01 + 0.005 * i as f64).collect();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let steps: Vec<f64> = (0..times.len() + 3)
            .map(|_| {
                let z: f64 = StandardNormal.sample(&mut rng);
                2.0 * sigma * z
            })
            .collect();
        let lane = times
            .iter()
            .enumerate()
            .map(|(i, &t)| waveform(t) + steps[i..i + 4].iter().sum::<f64>() / 4.0)
            .collect();
        (times, lane)
    }

    fn ri(curve: &[f64]) -> f64 {
        let max = curve.iter().cloned().fold(f64::MIN, f64::max);
        let min = curve.iter().cloned().fold(f64::MAX, f64::min);
        (max - min) / max
    }

    #[test]
    fn a_steady_flows_jitter_is_dropped_as_often_as_the_noise_model_says() {
        // 3 mm/s, jittering by 1 mm/s per window. The plain fit reads a pulse. Debiased, a
        // harmonic is dropped when its fitted power is below the noise's expected share: for
        // noise alone, a (cos, sin) pair's power is that share times χ²₂/2, at most it with
        // probability 1 − 1/e (0.63; a little less with the share estimated from the residual),
        // so both harmonics are dropped, the fit flat, in about 0.63² = 0.40 of the seeds.
        let seeds = 400;
        let (mut plain, mut flat) = (Vec::new(), 0);
        for seed in 0..seeds {
            let (times, lane) = cycle_with_noise(|_| 3.0, 1.0, seed);
            let fit = HarmonicFit::new(&times, 5.5, 2, 4.0).unwrap();
            plain.push(ri(&fit.smooth(&lane).unwrap()));
            flat += usize::from(ri(&fit.debiased(&lane).unwrap()) < 1e-12);
        }
        plain.sort_by(f64::total_cmp);
        let median = plain[seeds as usize / 2];
        assert!(median > 0.3, "plain fit's median RI {median}");
        let share = flat as f64 / seeds as f64;
        // Binomial spread over 400 seeds: 0.025; ±3 of it around 0.35–0.40.
        assert!(
            (0.28..=0.47).contains(&share),
            "flat in {share} of the seeds"
        );
    }

    #[test]
    fn a_pulse_well_above_the_noise_keeps_its_shape() {
        // A pulse of two harmonics (RI 0.7) with 3 % jitter: the debiasing takes a little of each
        // harmonic's power, as much as the noise put in.
        let omega = 2.0 * std::f64::consts::PI * 5.5;
        let pulse = |t: f64| 10.0 + 3.5 * (omega * t).cos() + 1.5 * (2.0 * omega * t).sin();
        let truth: Vec<f64> = (0..2000).map(|i| pulse(i as f64 / 2000.0 / 5.5)).collect();
        let (times, lane) = cycle_with_noise(pulse, 0.3, 7);
        let fit = HarmonicFit::new(&times, 5.5, 2, 4.0).unwrap();
        let (plain, debiased) = (
            ri(&fit.smooth(&lane).unwrap()),
            ri(&fit.debiased(&lane).unwrap()),
        );
        assert!(
            (debiased - ri(&truth)).abs() < 0.03,
            "{debiased} against {}",
            ri(&truth)
        );
        assert!(debiased <= plain, "{debiased} > {plain}");
    }

    #[test]
    fn without_noise_the_debiased_fit_is_the_fit() {
        let omega = 2.0 * std::f64::consts::PI * 5.5;
        let times: Vec<f64> = (0..36).map(|i| 0.01 + 0.005 * i as f64).collect();
        let lane: Vec<f64> = times.iter().map(|t| 4.0 + (omega * t).sin()).collect();
        let fit = HarmonicFit::new(&times, 5.5, 2, 4.0).unwrap();
        let (plain, debiased) = (fit.smooth(&lane).unwrap(), fit.debiased(&lane).unwrap());
        for (a, b) in plain.iter().zip(&debiased) {
            assert!((a - b).abs() < 1e-9, "{a} against {b}");
        }
    }

    /// The fit, its noise shares and what it leaves, computed with dense matrices as their
    /// definitions write them (the pseudo-inverse by least squares on the identity, the noise
    /// correlation C and the projector P = I − N N⁺ whole), against the fit's band-wise forms:
    /// equal to rounding, on a fractional overlap and on samples that do not span whole cycles.
    #[test]
    fn the_fit_equals_its_dense_definition() {
        use faer::linalg::solvers::SolveLstsq;
        let (n, rate, harmonics, overlap) = (150, 5.3, 2, 3.5);
        let times: Vec<f64> = (0..n).map(|i| 0.012 + 0.005 * i as f64).collect();
        let omega = 2.0 * std::f64::consts::PI * rate;
        let design_of = |columns: usize| harmonic_design(&times, rate, columns);
        let pinv_of = |d: &Mat<f64>| d.qr().solve_lstsq(Mat::<f64>::identity(n, n));
        let correlation = Mat::<f64>::from_fn(n, n, |i, j| {
            (1.0 - (i as f64 - j as f64).abs() / overlap).max(0.0)
        });
        let pinv = pinv_of(&design_of(5));
        let coefficient_noise = &pinv * &correlation * pinv.transpose();
        let noise_design = design_of(2 * NOISE_FIT_HARMONICS + 1);
        let projector = Mat::<f64>::identity(n, n) - &noise_design * pinv_of(&noise_design);
        let residual_noise = (&projector * &correlation * projector.transpose())
            .diagonal()
            .column_vector()
            .sum();

        let fit = HarmonicFit::new(&times, rate, harmonics, overlap).unwrap();
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-10 * b.abs().max(1.0);
        for k in 1..=harmonics {
            let dense =
                coefficient_noise[(2 * k - 1, 2 * k - 1)] + coefficient_noise[(2 * k, 2 * k)];
            assert!(close(fit.harmonic_noise[k - 1], dense), "harmonic {k}");
        }
        assert!(
            close(fit.residual_noise, residual_noise),
            "{} against {residual_noise}",
            fit.residual_noise
        );
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let lane: Vec<f64> = times
            .iter()
            .map(|t| {
                let z: f64 = StandardNormal.sample(&mut rng);
                5.0 + 2.0 * (omega * t).cos() + 0.7 * (3.0 * omega * t).sin() + 0.3 * z
            })
            .collect();
        let coefficients: Vec<f64> = (0..5)
            .map(|j| (0..n).map(|i| pinv[(j, i)] * lane[i]).sum())
            .collect();
        let residual: f64 = (0..n)
            .map(|i| {
                (0..n)
                    .map(|j| projector[(i, j)] * lane[j])
                    .sum::<f64>()
                    .powi(2)
            })
            .sum();
        let variance = residual / residual_noise;
        let mut debiased = coefficients.clone();
        for k in 0..harmonics {
            let noise = coefficient_noise[(2 * k + 1, 2 * k + 1)]
                + coefficient_noise[(2 * k + 2, 2 * k + 2)];
            let power = debiased[2 * k + 1].powi(2) + debiased[2 * k + 2].powi(2);
            let gain = (1.0 - variance * noise / power).max(0.0).sqrt();
            debiased[2 * k + 1] *= gain;
            debiased[2 * k + 2] *= gain;
        }
        let design = design_of(5);
        let curve = |c: &[f64]| -> Vec<f64> {
            (0..n)
                .map(|i| (0..5).map(|j| design[(i, j)] * c[j]).sum())
                .collect()
        };
        for (got, want) in [
            (fit.smooth(&lane).unwrap(), curve(&coefficients)),
            (fit.debiased(&lane).unwrap(), curve(&debiased)),
        ] {
            for (a, b) in got.iter().zip(&want) {
                assert!(close(*a, *b), "{a} against {b}");
            }
        }
    }
}
