//! Which pixels hold flow: every rule pcuvd uses, each one named function with its definition.
//!
//! The rules differ on purpose: figures of a recording compare power with the image's own
//! brightest pixels (no noise image exists); the simulated studies know the noise power apart and
//! compare with it; the RI maps combine a per-depth noise floor and a local peak
//! ([`crate::dynamics::VesselTests::flow_mask`], [`crate::doppler::above_noise_floor`],
//! [`crate::doppler::near_local_peak`]) with a window-power threshold
//! ([`crate::dynamics::VelocitySeries::vessel_mask`]).

use ndarray::Array2;

use crate::metrics::power_to_db;
use crate::stats::quantile;

/// Level (dB re. [`power_db_re_peak`]'s reference) below which a pixel of a recording's figures
/// is drawn as B-mode, not flow.
pub const FLOW_FIGURE_DB: f64 = -25.0;

/// Level (dB re. [`power_db_re_peak`]'s reference) below which no vector glyph is drawn: vectors
/// from weak, noise-dominated pixels are random and would swamp the figure and its colour scale.
pub const VECTOR_FIGURE_DB: f64 = -15.0;

/// Level (dB above the noise image's mean power) from which the studies' figures show flow.
pub const FLOW_ABOVE_NOISE_DB: f64 = 6.0;

/// The reference of [`power_db_re_peak`]: a high percentile, robust to a few very bright pixels.
pub const PEAK_QUANTILE: f64 = 0.999;

/// Definition of [`within_db_of_peak`].
pub const WITHIN_DB_OF_PEAK_DEFINITION: &str = "power Doppler at or above the level (dB) relative \
to the image's 99.9th-percentile power";

/// Definition of [`above_noise_image`].
pub const ABOVE_NOISE_IMAGE_DEFINITION: &str = "power Doppler at or above the level (dB) relative \
to the mean power of the noise-only image (known in simulations, where echoes and noise are \
imaged apart)";

/// Power in dB relative to its [`PEAK_QUANTILE`] percentile, floored at −120 dB.
pub fn power_db_re_peak(power: &Array2<f64>) -> Array2<f64> {
    let reference = quantile(power.iter().copied(), PEAK_QUANTILE).max(f64::MIN_POSITIVE);
    power.mapv(|p| power_to_db(p.max(reference * 1e-12) / reference))
}

/// Pixels whose power is at least `level_db` relative to the peak; see
/// [`WITHIN_DB_OF_PEAK_DEFINITION`].
pub fn within_db_of_peak(power: &Array2<f64>, level_db: f64) -> Array2<bool> {
    power_db_re_peak(power).mapv(|v| v >= level_db)
}

/// Power in dB above the mean of the noise-only power image `noise`, floored at −30 dB.
pub fn db_above_noise(power: &Array2<f64>, noise: &Array2<f64>) -> Array2<f64> {
    let floor = noise.mean().unwrap_or(1.0).max(f64::MIN_POSITIVE);
    power.mapv(|p| power_to_db(p.max(floor * 1e-3) / floor))
}

/// Pixels whose power is at least `level_db` above the noise image's mean; see
/// [`ABOVE_NOISE_IMAGE_DEFINITION`].
pub fn above_noise_image(power: &Array2<f64>, noise: &Array2<f64>, level_db: f64) -> Array2<bool> {
    db_above_noise(power, noise).mapv(|d| d >= level_db)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::array;

    #[test]
    fn within_db_of_peak_by_hand() {
        // 1000 pixels: one at 1.0, the rest 0.01 (−20 dB) and 0.001 (−30 dB). The 99.9th
        // percentile (rank round(999 × 0.999) = 998) is 0.01 here, not the lone bright pixel.
        let mut power = Array2::from_elem((10, 100), 0.001);
        for ix in 0..100 {
            power[[0, ix]] = 0.01;
        }
        power[[5, 5]] = 1.0;
        let db = power_db_re_peak(&power);
        assert!((db[[0, 0]]).abs() < 1e-12);
        assert!((db[[5, 5]] - 20.0).abs() < 1e-9);
        assert!((db[[9, 9]] + 10.0).abs() < 1e-9);
        let mask = within_db_of_peak(&power, -5.0);
        assert_eq!(mask.iter().filter(|&&m| m).count(), 101);
        // Zero power is floored at −120 dB instead of −∞.
        power[[9, 9]] = 0.0;
        assert!((power_db_re_peak(&power)[[9, 9]] + 120.0).abs() < 1e-9);
    }

    #[test]
    fn above_noise_image_by_hand() {
        let noise = array![[1.0, 3.0]]; // mean 2
        let power = array![[8.0, 7.9], [0.0, 2.0]];
        let db = db_above_noise(&power, &noise);
        assert!((db[[0, 0]] - power_to_db(4.0)).abs() < 1e-12);
        assert!((db[[1, 0]] + 30.0).abs() < 1e-9, "floored at −30 dB");
        assert!(db[[1, 1]].abs() < 1e-12);
        // 6 dB is a power ratio of 3.98: 8 passes (6.02 dB), 7.9 does not (5.97 dB).
        let mask = above_noise_image(&power, &noise, FLOW_ABOVE_NOISE_DB);
        assert_eq!(mask, array![[true, false], [false, false]]);
    }
}
