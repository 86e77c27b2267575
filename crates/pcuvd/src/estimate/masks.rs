//! Which pixels hold flow: every rule pcuvd uses, each one named function with its definition.
//!
//! The rules differ on purpose: figures of a recording compare power with the image's own
//! brightest pixels (no noise image exists); the simulated studies know the noise power apart and
//! compare with it; the RI maps combine a per-depth noise floor and a local peak
//! ([`VesselTests::flow_mask`], [`above_noise_floor`],
//! [`crate::estimate::masks::near_local_peak`]) with a window-power threshold
//! ([`crate::dynamics::VelocitySeries::vessel_mask`]).

use ndarray::Array2;

use crate::core::error::{Result, invalid};
use crate::core::stats::quantile;
use crate::core::units::power_to_db;

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

/// Fraction of a depth row's pixels below the noise floor estimate ([`noise_floor_by_depth`]).
pub const NOISE_FLOOR_QUANTILE: f64 = 0.3;

/// Noise power of each depth row (row `iz` of `power`, same units): the 30th percentile of the
/// row's finite power-Doppler values.
///
/// Why a per-row low percentile: the noise power of a beamformed image changes with depth (the
/// receive aperture grows, time-gain compensation lifts deep rows, attenuation does not act on
/// noise), but along a row it is nearly flat, and vessels fill a minority of any row, so the lower
/// part of the row's distribution is noise. Where flow fills more than 70 % of a row (a dense
/// perfused cortex) the 30th percentile is a flow pixel, so it reads the perfusion level instead,
/// and a mask built on it keeps what stands out of the perfused tissue: the larger vessels.
pub fn noise_floor_by_depth(power: &Array2<f64>) -> Vec<f64> {
    power
        .outer_iter()
        .map(|row| quantile(row.iter().copied(), NOISE_FLOOR_QUANTILE))
        .collect()
}

/// Flow pixels of a power-Doppler image: power at least `margin_db` (dB) above the noise floor of
/// its depth row ([`noise_floor_by_depth`]), and above zero.
pub fn above_noise_floor(power: &Array2<f64>, margin_db: f64) -> Array2<bool> {
    let gain = 10f64.powf(margin_db / 10.0);
    let floor = noise_floor_by_depth(power);
    Array2::from_shape_fn(power.dim(), |(iz, ix)| {
        let p = power[[iz, ix]];
        p.is_finite() && p > 0.0 && p >= floor[iz] * gain
    })
}

/// Margin (dB) above the depth's noise floor ([`figure_flow_mask`]) from which a recording's
/// figures draw flow: power Doppler over N frames of noise stays within 10·log10(1 ± 2/√N) dB
/// of its mean at two standard deviations (+1.3 / −1.9 dB at 32 frames, +2.1 dB at 10), so 6 dB
/// keeps noise pixels out from about 10 frames on.
pub const FIGURE_ABOVE_FLOOR_DB: f64 = 6.0;

/// Half-height (m) of the depth window over which [`figure_flow_mask`] takes the median of the
/// rows' noise floors.
pub const FIGURE_FLOOR_REACH_M: f64 = 5.0e-3;

/// Definition of [`figure_flow_mask`].
pub const FIGURE_FLOW_DEFINITION: &str = "power Doppler at or above the level (dB) relative to \
the image's 99.9th-percentile power, and at least 6 dB above the noise floor of its depth (the \
median of the rows' 30th-percentile powers within 5 mm above and below)";

/// Pixels a recording's figures draw as flow: power at least `level_db` relative to the peak
/// ([`within_db_of_peak`]) and at least [`FIGURE_ABOVE_FLOOR_DB`] above the noise floor of its
/// depth: the median of [`noise_floor_by_depth`] over the rows within [`FIGURE_FLOOR_REACH_M`]
/// above and below (pixels `step` m apart; fewer near the image's top and bottom, as many on
/// each side). Why the floor: time-gain compensation lifts the deep noise of a real recording
/// to within 25 dB of the flow's peak (the disk recording's bottom rows), where a level relative
/// to the peak alone colours noise. Why the median over depth: a vessel that crosses the whole
/// width fills its rows, whose own 30th percentile is its flow; fewer than half the window's
/// rows, it leaves the median on the noise, and a symmetric window's median is the centre row's
/// floor wherever the floor rises steadily with depth.
pub fn figure_flow_mask(power: &Array2<f64>, level_db: f64, step: f64) -> Array2<bool> {
    let floors = noise_floor_by_depth(power);
    let reach = if step > 0.0 {
        (FIGURE_FLOOR_REACH_M / step).round() as usize
    } else {
        0
    };
    let n = floors.len();
    let smoothed: Vec<f64> = (0..n)
        .map(|iz| {
            let half = reach.min(iz).min(n - 1 - iz);
            let window: Vec<f64> = floors[iz - half..=iz + half]
                .iter()
                .copied()
                .filter(|f| f.is_finite())
                .collect();
            if window.is_empty() {
                f64::NAN
            } else {
                crate::core::stats::median(window)
            }
        })
        .collect();
    let gain = 10f64.powf(FIGURE_ABOVE_FLOOR_DB / 10.0);
    let mut mask = within_db_of_peak(power, level_db);
    mask.indexed_iter_mut().for_each(|((iz, ix), m)| {
        // A depth without a finite floor has no noise to stand above (an image of one row).
        let floor = if smoothed[iz].is_finite() {
            smoothed[iz]
        } else {
            0.0
        };
        *m &= power[[iz, ix]] >= floor * gain;
    });
    mask
}

/// Pixels whose power is within `within_db` (dB) of the strongest pixel in the square of
/// half-width `radius` pixels around them (NaN and non-positive power: never).
///
/// Why: a bright vessel is seen through the side lobes of plane-wave images tens of dB below
/// itself, over a millimetre or more around it, and that haze stands well above the noise floor
/// of a clean recording; a vessel's own lumen lies within a few dB of its brightest pixel, and a
/// weak vessel away from the bright one is its own local peak. A radius of about 1 mm spans a
/// small vessel's haze, and 20 dB keeps a lumen's edges (whose power is a few dB below its centre)
/// while dropping side lobes tens of dB down.
pub fn near_local_peak(power: &Array2<f64>, radius: usize, within_db: f64) -> Array2<bool> {
    let (nz, nx) = power.dim();
    // Non-finite power counts as none; the peak of a square is at least zero.
    let finite: Vec<f64> = power
        .iter()
        .map(|&p| if p.is_finite() { p.max(0.0) } else { 0.0 })
        .collect();
    // The square's maximum is the maximum along z of the maxima along x.
    let along_x = sliding_max(&finite, (nz, nx), false, radius);
    let peaks = sliding_max(&along_x, (nz, nx), true, radius);
    let gain = 10f64.powf(-within_db / 10.0);
    let mut mask = Array2::from_elem((nz, nx), false);
    for ((m, &p), &peak) in mask.iter_mut().zip(power.iter()).zip(&peaks) {
        *m = p.is_finite() && p > 0.0 && p >= peak * gain;
    }
    mask
}

/// The maximum of each value's neighbours up to `radius` steps away, cut at the edges, along one
/// axis of an (nz, nx) map in standard layout: along z where `along_z`, else along x.
///
/// Van Herk's running maxima: the axis is cut into blocks of 2·radius + 1 values, each value
/// takes the maximum from its block's start (forward) and to its block's end (backward), and a
/// neighbourhood, which spans at most two blocks, is the larger of the backward maximum at its
/// first value and the forward one at its last (a neighbourhood within one block, cut at an
/// edge, is one of them): three comparisons a value whatever the radius, where scanning each
/// neighbourhood took 2·radius + 1. A maximum is exact, so the result is the scan's.
fn sliding_max(values: &[f64], shape: (usize, usize), along_z: bool, radius: usize) -> Vec<f64> {
    let (nz, nx) = shape;
    let (lines, len) = if along_z { (nx, nz) } else { (nz, nx) };
    let block = 2 * radius + 1;
    let at = |line: usize, i: usize| {
        if along_z {
            i * nx + line
        } else {
            line * nx + i
        }
    };
    let (mut forward, mut backward) = (vec![0.0; values.len()], vec![0.0; values.len()]);
    let mut out = vec![0.0; values.len()];
    for line in 0..lines {
        for i in 0..len {
            let v = values[at(line, i)];
            forward[at(line, i)] = if i % block == 0 {
                v
            } else {
                v.max(forward[at(line, i - 1)])
            };
        }
        for i in (0..len).rev() {
            let v = values[at(line, i)];
            backward[at(line, i)] = if i % block == block - 1 || i + 1 == len {
                v
            } else {
                v.max(backward[at(line, i + 1)])
            };
        }
        for i in 0..len {
            let (lo, hi) = (i.saturating_sub(radius), (i + radius).min(len - 1));
            out[at(line, i)] = if lo / block != hi / block {
                backward[at(line, lo)].max(forward[at(line, hi)])
            } else if lo % block == 0 {
                // Within one block, cut at the axis' start or a whole block: from its start.
                forward[at(line, hi)]
            } else {
                // Within one block, cut at the axis' end: to its end.
                backward[at(line, lo)]
            };
        }
    }
    out
}

/// Default margin (dB) above the noise floor of the recording's power Doppler
/// ([`above_noise_floor`]) of a vessel pixel for [`crate::dynamics::ri_maps_where`]. Why: the power
/// of a 20 ms window is too unsteady to tell noise from weak flow, so a window threshold alone lets
/// in many noise pixels around the lumens, and a noise pixel that joins a pool flattens its
/// waveform (lowers its RI). The recording's power Doppler averages over every frame, and a margin
/// above its noise floor removes those pixels. The margin is kept low because attenuation lowers
/// the echoes, not the noise, with depth: the deep vessels of a low-SNR recording stand only a few
/// dB above the noise floor, and a larger margin drops them first.
pub const VESSEL_MARGIN_DB: f64 = 3.0;

/// Default for [`VesselTests::local_db`]: a vessel pixel's power Doppler is within 20 dB of the
/// brightest pixel around it ([`near_local_peak`]).
pub const VESSEL_LOCAL_DB: f64 = 20.0;

/// Default for [`VesselTests::local_radius_m`] (m): the half-width of the square searched for
/// the local peak, about the reach of a vessel's side-lobe haze in plane-wave images.
pub const VESSEL_LOCAL_RADIUS_M: f64 = 1.0e-3;

/// Whole-recording tests a pixel's power Doppler must pass to count as a vessel in the RI maps
/// (as well as each window's power test, [`crate::dynamics::DynamicsParams::min_power_db`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VesselTests {
    /// dB above the noise floor of its depth ([`above_noise_floor`]); −∞: off.
    pub margin_db: f64,
    /// dB below the brightest pixel within `local_radius_m` at most
    /// ([`near_local_peak`]), which drops the side-lobe haze around bright
    /// vessels in clean recordings; +∞: off.
    pub local_db: f64,
    /// Half-width (m) of the square around the pixel searched for its local peak.
    pub local_radius_m: f64,
}

impl Default for VesselTests {
    fn default() -> Self {
        VesselTests {
            margin_db: VESSEL_MARGIN_DB,
            local_db: VESSEL_LOCAL_DB,
            local_radius_m: VESSEL_LOCAL_RADIUS_M,
        }
    }
}

impl VesselTests {
    /// Refuses a NaN margin or local level, and a local radius that is negative or not finite.
    pub fn validate(&self) -> Result<()> {
        if self.margin_db.is_nan() {
            return Err(invalid("vessel margin", "must be a number of dB (or off)"));
        }
        if self.local_db.is_nan() || self.local_db < 0.0 {
            return Err(invalid(
                "vessel local level",
                format!("must be ≥ 0 dB (or off), got {:?}", self.local_db),
            ));
        }
        if !(self.local_radius_m.is_finite() && self.local_radius_m >= 0.0) {
            return Err(invalid(
                "vessel local radius",
                format!("must be ≥ 0 m, got {:?}", self.local_radius_m),
            ));
        }
        Ok(())
    }

    /// The pixels of `power` (nz, nx), a power-Doppler image on a grid of `grid_step_m` (m), that
    /// pass both tests: the `flow` mask of [`crate::dynamics::ri_maps_where`].
    pub fn flow_mask(&self, power: &Array2<f64>, grid_step_m: f64) -> Array2<bool> {
        let mut mask = above_noise_floor(power, self.margin_db);
        if self.local_db.is_finite() {
            // A radius beyond the image searches the whole image (and cannot overflow).
            let widest = power.nrows().max(power.ncols()) as f64;
            let radius = (self.local_radius_m / grid_step_m)
                .round()
                .clamp(0.0, widest) as usize;
            let local = near_local_peak(power, radius, self.local_db);
            mask.zip_mut_with(&local, |m, &l| *m &= l);
        }
        mask
    }
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

    #[test]
    fn noise_floor_follows_depth_and_the_mask_keeps_vessels_only() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Gamma};
        // Power Doppler averaged over 60 independent frames (gamma-distributed, shape 60) on a
        // noise floor rising 20 dB from the top row to the bottom one; every fifth column a
        // vessel 10 dB above its row's floor.
        let (nz, nx, frames) = (40, 200, 60.0);
        let floor = |iz: usize| 1e-3 * 10f64.powf(2.0 * iz as f64 / (nz - 1) as f64);
        let vessel = |ix: usize| ix.is_multiple_of(5);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let speckle = Gamma::new(frames, 1.0 / frames).unwrap();
        let power = Array2::from_shape_fn((nz, nx), |(iz, ix)| {
            let signal = if vessel(ix) { 10.0 * floor(iz) } else { 0.0 };
            (signal + floor(iz)) * speckle.sample(&mut rng)
        });
        // The 30th percentile of the noise alone sits 0.5 dB below its mean (gamma, shape 60).
        for (iz, &estimate) in noise_floor_by_depth(&power).iter().enumerate() {
            let error_db = power_to_db(estimate / floor(iz));
            assert!(error_db.abs() < 1.0, "row {iz}: floor off by {error_db} dB");
        }
        let mask = above_noise_floor(&power, 6.0);
        let (mut missed, mut false_alarms) = (0, 0);
        for ((_, ix), &m) in mask.indexed_iter() {
            missed += usize::from(vessel(ix) && !m);
            false_alarms += usize::from(!vessel(ix) && m);
        }
        assert_eq!(missed, 0);
        assert!(
            false_alarms < nz * nx / 200,
            "{false_alarms} noise pixels in the mask"
        );
        // A fixed threshold re. the brightest pixel cannot do this: −25 dB from the deep vessels'
        // power lets in the noise of every row deeper than the first quarter.
        let brightest = power.iter().copied().fold(0.0, f64::max);
        let fixed = power
            .iter()
            .filter(|&&p| p >= brightest * 10f64.powf(-2.5))
            .count();
        assert!(fixed > nz * nx / 2, "{fixed}");
        // Rows without finite power have no floor and no flow.
        let blank = Array2::from_elem((2, 3), f64::NAN);
        assert!(noise_floor_by_depth(&blank).iter().all(|f| f.is_nan()));
        assert!(!above_noise_floor(&blank, 0.0).iter().any(|&m| m));
    }

    #[test]
    fn figure_flow_definition_states_the_constants() {
        for part in [
            format!("{} dB above", FIGURE_ABOVE_FLOOR_DB),
            format!("{}th-percentile powers", NOISE_FLOOR_QUANTILE * 100.0),
            format!("within {} mm", FIGURE_FLOOR_REACH_M * 1e3),
            format!("{}th-percentile power,", PEAK_QUANTILE * 100.0),
        ] {
            assert!(FIGURE_FLOW_DEFINITION.contains(&part), "{part}");
        }
    }

    #[test]
    fn figure_mask_drops_lifted_noise_and_keeps_a_vessel_filling_its_rows() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Gamma};
        // 100 µm pixels, 32 frames of noise whose floor rises 30 dB with depth (time-gain
        // compensation), to within 20 dB of the flow's peak in the deepest rows. Flow: a vessel
        // 4 mm wide crossing the whole width at 4–8 mm, 40 dB above the shallow floor, and a
        // small vessel 10 dB above the deep floor.
        let (nz, nx, step, frames) = (160, 80, 1e-4, 32.0);
        let floor = |iz: usize| 1e-4 * 10f64.powf(3.0 * iz as f64 / (nz - 1) as f64);
        let band = |iz: usize| (40..80).contains(&iz);
        let deep_vessel = |iz: usize, ix: usize| iz >= 140 && (38..42).contains(&ix);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let speckle = Gamma::new(frames, 1.0 / frames).unwrap();
        let power = Array2::from_shape_fn((nz, nx), |(iz, ix)| {
            let flow = if band(iz) {
                1.0
            } else if deep_vessel(iz, ix) {
                10.0 * floor(iz)
            } else {
                0.0
            };
            (flow + floor(iz)) * speckle.sample(&mut rng)
        });
        let mask = figure_flow_mask(&power, FLOW_FIGURE_DB, step);
        let count = |test: &dyn Fn(usize, usize) -> bool| {
            mask.indexed_iter()
                .filter(|&((iz, ix), &m)| m && test(iz, ix))
                .count()
        };
        assert_eq!(count(&|iz, _| band(iz)), 40 * nx, "the band is drawn whole");
        assert_eq!(
            count(&deep_vessel),
            20 * 4,
            "the deep vessel is drawn whole"
        );
        let noise = count(&|iz, ix| !band(iz) && !deep_vessel(iz, ix));
        assert!(noise < nz * nx / 1000, "{noise} noise pixels drawn");
        // The level re. the peak alone draws the deep noise: the rows within 25 dB of the band.
        let peak_only = within_db_of_peak(&power, FLOW_FIGURE_DB);
        let lifted = peak_only
            .indexed_iter()
            .filter(|&((iz, ix), &m)| m && !band(iz) && !deep_vessel(iz, ix))
            .count();
        assert!(lifted > 10 * nx, "{lifted}");
    }

    /// The running maxima give each pixel the peak of its own square, scanned value by value:
    /// on maps narrower and shorter than the square, with NaN, negative and zero power, radius 0.
    #[test]
    fn near_local_peak_tests_each_pixel_against_its_own_square() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for (nz, nx) in [(17, 23), (1, 9), (8, 1), (40, 6)] {
            let power = Array2::from_shape_fn((nz, nx), |_| match rng.random_range(0..10) {
                0 => f64::NAN,
                1 => -1.0,
                2 => 0.0,
                _ => 10f64.powf(rng.random_range(-4.0..0.0)),
            });
            for radius in [0, 1, 2, 5, 30] {
                for within_db in [3.0, 20.0] {
                    let got = near_local_peak(&power, radius, within_db);
                    let gain = 10f64.powf(-within_db / 10.0);
                    for ((iz, ix), &m) in got.indexed_iter() {
                        let mut peak = 0.0f64;
                        for z in iz.saturating_sub(radius)..=(iz + radius).min(nz - 1) {
                            for x in ix.saturating_sub(radius)..=(ix + radius).min(nx - 1) {
                                let p = power[[z, x]];
                                if p.is_finite() {
                                    peak = peak.max(p);
                                }
                            }
                        }
                        let p = power[[iz, ix]];
                        let want = p.is_finite() && p > 0.0 && p >= peak * gain;
                        assert_eq!(m, want, "{nz} × {nx}, radius {radius}, at ({iz}, {ix})");
                    }
                }
            }
        }
    }

    /// A bright vessel with a side-lobe haze 25 dB below it on either side, and a vessel 35–38 dB
    /// weaker than the bright one farther away: the haze goes, both vessels (edges included) stay.
    #[test]
    fn local_peak_test_drops_side_lobes_and_keeps_weak_vessels() {
        let (nz, nx) = (30, 120);
        let db = |d: f64| 10f64.powf(d / 10.0);
        let power = Array2::from_shape_fn((nz, nx), |(iz, ix)| match ix {
            20..=24 => db(if ix == 20 || ix == 24 { -3.0 } else { 0.0 }),
            10..=19 | 25..=34 => db(-25.0),
            90..=93 => db(-35.0 - 0.1 * iz as f64),
            _ if iz == 0 && ix == 60 => f64::NAN,
            _ => db(-60.0),
        });
        let mask = near_local_peak(&power, 10, 20.0);
        // Around the bright vessel, and around the weak one (whose surroundings, noise 22–25 dB
        // below it, go too); noise far from any vessel is its own local peak and is left to the
        // noise-floor test.
        for iz in 0..nz {
            for ix in (10..=34).chain(80..=103) {
                let vessel = (20..=24).contains(&ix) || (90..=93).contains(&ix);
                assert_eq!(mask[[iz, ix]], vessel, "pixel ({iz}, {ix})");
            }
        }
        assert!(!mask[[0, 60]], "a NaN pixel is no vessel");
        // The haze is within 30 dB of the vessel: a looser test keeps it.
        assert!(near_local_peak(&power, 10, 30.0)[[5, 12]]);
        // Nothing beyond the radius counts: with a radius of 3 the haze 9 columns away is its
        // own peak.
        assert!(near_local_peak(&power, 3, 20.0)[[5, 11]]);
    }
}
