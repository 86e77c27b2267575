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
/// fixed times: the pseudo-inverse is computed once and applied to every pixel.
pub(super) struct HarmonicFit {
    /// Design matrix, (times × coefficients): 1, cos kωt, sin kωt.
    design: Mat<f64>,
    /// Its pseudo-inverse, (coefficients × times).
    pinv: Mat<f64>,
}

impl HarmonicFit {
    /// `None` when `harmonics` is 0 or the series is too short to fit that many.
    pub(super) fn new(times: &[f64], heart_rate_hz: f64, harmonics: usize) -> Option<HarmonicFit> {
        let columns = 2 * harmonics + 1;
        if harmonics == 0 || times.len() <= columns {
            return None;
        }
        let omega = 2.0 * std::f64::consts::PI * heart_rate_hz;
        let design = Mat::<f64>::from_fn(times.len(), columns, |i, j| {
            let k = j.div_ceil(2) as f64;
            match j {
                0 => 1.0,
                _ if j % 2 == 1 => (k * omega * times[i]).cos(),
                _ => (k * omega * times[i]).sin(),
            }
        });
        let pinv = design
            .qr()
            .solve_lstsq(Mat::<f64>::identity(times.len(), times.len()));
        Some(HarmonicFit { design, pinv })
    }

    /// The fitted curve at the sample times; `None` if `lane` has non-finite samples.
    pub(super) fn smooth(&self, lane: &[f64]) -> Option<Vec<f64>> {
        if lane.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let coefficients: Vec<f64> = (0..self.pinv.nrows())
            .map(|j| (0..lane.len()).map(|i| self.pinv[(j, i)] * lane[i]).sum())
            .collect();
        Some(
            (0..lane.len())
                .map(|i| {
                    coefficients
                        .iter()
                        .enumerate()
                        .map(|(j, c)| self.design[(i, j)] * c)
                        .sum()
                })
                .collect(),
        )
    }
}
