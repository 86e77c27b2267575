//! How close an estimate is to the truth, each measure with its written definition: RMSE of
//! vector velocity, SNR by depth, RI scores; one power-to-dB and one median for all of them.

use crate::core::units::power_to_db;
use ndarray::{Array2, Array3, Axis, Zip};
use num_complex::Complex32;
use serde::Serialize;

use crate::core::grid::Grid;
use crate::dynamics::{BACKGROUND, RiMaps};
use crate::estimate::vector::VectorField;
use crate::simulate::phantom::Truth;
use crate::simulate::phantom::network::NetworkTruth;

pub use crate::core::stats::median;

/// How [`rmse`] counts: the definition printed in every report.
pub const RMSE_DEFINITION: &str = "RMSE = √(mean over every pixel of the true vessel of \
(estimate − truth)²), per component (Vx, Vz), in mm/s; a pixel without an estimate (NaN: no \
angle reached it) counts as an estimate of 0, so missing pixels are not left out of the error";

/// How [`snr_by_depth`] measures SNR on power Doppler images.
pub const SNR_DEFINITION: &str = "SNR(z) = 10·log10(P_echo / P_noise) per 0.5 mm depth band, where P_echo is the mean \
power Doppler of the blood echoes over the vessel pixels (ground-truth mask) of the band and P_noise the mean power \
Doppler of the receiver noise over all pixels of the band; the simulation forms the echo and noise images apart (the \
chain is linear up to the Doppler estimate), so neither is biased by the other or by side lobes";

/// How [`score_ri`] scores RI maps against the truth.
pub const RI_SCORE_DEFINITION: &str = "over every vessel pixel of the ground truth (the lumen of \
every vessel on the grid): median_abs_error = median of |RI_estimated − RI_true|, where a pixel the \
estimator leaves without an RI (not a vessel pixel by its power thresholds) counts as an error of 1; \
classification_accuracy = fraction of vessel pixels classed as the right kind (arteriole or venule; \
undetermined or background count as wrong); coverage = fraction of vessel pixels with an RI";

/// Depth bands (m) over which [`snr_by_depth`] averages.
pub const SNR_BAND_M: f64 = 0.5e-3;

/// Vessel pixels a depth band needs before [`snr_by_depth`] reports it.
pub const SNR_MIN_VESSEL_PIXELS: usize = 10;

/// RMSE of the two velocity components, mm/s.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Rmse {
    /// RMSE of the lateral velocity Vx (mm/s).
    pub vx: f64,
    /// RMSE of the axial velocity Vz (mm/s).
    pub vz: f64,
}

/// RMSE (mm/s) of `field` against `truth` over the true vessel; see [`RMSE_DEFINITION`].
pub fn rmse(field: &VectorField, truth: &Truth) -> Rmse {
    let (mut sx, mut sz, mut n) = (0.0, 0.0, 0.0);
    Zip::from(&field.vx)
        .and(&field.vz)
        .and(&truth.vx)
        .and(&truth.vz)
        .and(&truth.mask)
        .for_each(|&ex, &ez, &tx, &tz, &m| {
            if m {
                let (dx, dz) = (
                    if ex.is_finite() { ex - tx } else { tx },
                    if ez.is_finite() { ez - tz } else { tz },
                );
                sx += dx * dx;
                sz += dz * dz;
                n += 1.0;
            }
        });
    Rmse {
        vx: (sx / n).sqrt() * 1e3,
        vz: (sz / n).sqrt() * 1e3,
    }
}

/// How [`within_fraction_of_peak`] counts: the definition printed in every report.
pub const WITHIN_PEAK_DEFINITION: &str = "fraction of the pixels of the true vessel whose vector \
error |v_estimate − v_true| is at most 10 % of the peak (centreline) speed: an error measure that \
stays meaningful near the wall, where the true speed tends to zero; a pixel without an estimate \
(NaN) counts as wrong";

/// Fraction of the true vessel's pixels whose vector error |v − v_true| is at most
/// `fraction` × `peak` (m/s); see [`WITHIN_PEAK_DEFINITION`] (there, `fraction` = 0.1).
pub fn within_fraction_of_peak(
    field: &VectorField,
    truth: &Truth,
    peak: f64,
    fraction: f64,
) -> f64 {
    let (mut good, mut total) = (0usize, 0usize);
    Zip::from(&field.vx)
        .and(&field.vz)
        .and(&truth.vx)
        .and(&truth.vz)
        .and(&truth.mask)
        .for_each(|&ex, &ez, &tx, &tz, &m| {
            if m {
                total += 1;
                good += usize::from((ex - tx).hypot(ez - tz) <= fraction * peak);
            }
        });
    good as f64 / total.max(1) as f64
}

/// How [`speed_within_fraction_of_peak`] counts (the wording, "speed error"; laxer than
/// [`WITHIN_PEAK_DEFINITION`]: a pixel of the right speed in the wrong direction counts as right).
pub const SPEED_WITHIN_PEAK_DEFINITION: &str = "fraction of the pixels of the true vessel whose \
speed error ||v_estimate| − |v_true|| is at most 10 % of the peak (centreline) speed; a pixel \
without an estimate (NaN) counts as wrong";

/// Fraction of the true vessel's pixels whose speed error ||v| − |v_true|| is at most
/// `fraction` × `peak` (m/s); see [`SPEED_WITHIN_PEAK_DEFINITION`].
pub fn speed_within_fraction_of_peak(
    field: &VectorField,
    truth: &Truth,
    peak: f64,
    fraction: f64,
) -> f64 {
    let (mut good, mut total) = (0usize, 0usize);
    Zip::from(&field.vx)
        .and(&field.vz)
        .and(&truth.vx)
        .and(&truth.vz)
        .and(&truth.mask)
        .for_each(|&ex, &ez, &tx, &tz, &m| {
            if m {
                total += 1;
                good += usize::from((ex.hypot(ez) - tx.hypot(tz)).abs() <= fraction * peak);
            }
        });
    good as f64 / total.max(1) as f64
}

/// How [`alias_patterns_right`] counts: the definition printed in every report.
pub const ALIAS_PATTERN_DEFINITION: &str = "fraction of the pixels of the true vessel where the \
alias count k chosen for every angle that reaches the pixel equals the true one, \
round((V_θ,true − V_θ,measured)/(2 v_N)), v_N the projection's Nyquist velocity at that pixel \
(c·f_frame/(4 f), f the frequency its phase was scaled by): the count that brings the measured \
projection nearest to the true one (without dealiasing every count is 0)";

/// Fraction of the true vessel's pixels whose alias counts `counts` (angles, nz, nx) are right
/// for every angle with a finite projection in `projections` (angles, nz, nx, m/s) at `angles`
/// (rad), projection Nyquist velocity `nyquist` (angles, nz, nx, m/s: each pixel's own, as
/// [`crate::pipeline::DopplerMaps::projection_nyquist`] gives it); see
/// [`ALIAS_PATTERN_DEFINITION`].
pub fn alias_patterns_right(
    projections: &Array3<f64>,
    counts: &Array3<i8>,
    angles: &[f64],
    nyquist: &Array3<f64>,
    truth: &Truth,
) -> f64 {
    let right_counts = true_alias_counts(projections, angles, nyquist, truth);
    let (mut good, mut total) = (0usize, 0usize);
    for ((iz, ix), &inside) in truth.mask.indexed_iter() {
        if !inside {
            continue;
        }
        total += 1;
        let right = (0..angles.len()).all(|a| {
            !projections[[a, iz, ix]].is_finite()
                || counts[[a, iz, ix]] == right_counts[[a, iz, ix]]
        });
        good += usize::from(right);
    }
    good as f64 / total.max(1) as f64
}

/// The alias counts (angles, nz, nx) that unwrap the measured `projections` (m/s) nearest to the
/// true vessel's projections at `angles` (rad), each angle and pixel by its own Nyquist velocity
/// `nyquist` (m/s): k = round((V_true − V_measured)/(2 v_N)); 0 outside the vessel and where a
/// projection is not finite.
pub fn true_alias_counts(
    projections: &Array3<f64>,
    angles: &[f64],
    nyquist: &Array3<f64>,
    truth: &Truth,
) -> Array3<i8> {
    Array3::from_shape_fn(projections.dim(), |(a, iz, ix)| {
        let measured = projections[[a, iz, ix]];
        if !truth.mask[[iz, ix]] || !measured.is_finite() {
            return 0;
        }
        let (s, c) = crate::estimate::vector::projection_weights(angles[a]);
        let true_projection = 0.5 * (truth.vx[[iz, ix]] * s + truth.vz[[iz, ix]] * c);
        let k = ((true_projection - measured) / (2.0 * nyquist[[a, iz, ix]])).round();
        k.clamp(f64::from(i8::MIN), f64::from(i8::MAX)) as i8
    })
}

/// Time-mean power |IQ|² of an image series (nz, nx, frames): the power Doppler without any
/// spatial averaging, shape (nz, nx).
pub fn mean_power(series: &Array3<Complex32>) -> Array2<f64> {
    series.map_axis(Axis(2), |v| {
        v.iter().map(|c| c.norm_sqr() as f64).sum::<f64>() / v.len() as f64
    })
}

/// SNR of one depth band.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct DepthSnr {
    /// Centre of the band (m).
    pub depth_m: f64,
    /// SNR of the band (dB).
    pub snr_db: f64,
}

/// SNR per [`SNR_BAND_M`] depth band of `grid` that holds at least [`SNR_MIN_VESSEL_PIXELS`]
/// vessel pixels of `vessel`: `echo` and `noise` are the time-mean powers of the echo-only and
/// noise-only images; see [`SNR_DEFINITION`].
pub fn snr_by_depth(
    echo: &Array2<f64>,
    noise: &Array2<f64>,
    vessel: &Array2<bool>,
    grid: &Grid,
) -> Vec<DepthSnr> {
    let z0 = grid.z[0];
    let n_bands = ((grid.z[grid.z.len() - 1] - z0) / SNR_BAND_M).floor() as usize + 1;
    let mut sums = vec![[0.0f64; 4]; n_bands];
    for (iz, &z) in grid.z.iter().enumerate() {
        let b = (((z - z0) / SNR_BAND_M).floor() as usize).min(n_bands - 1);
        for ix in 0..grid.x.len() {
            if vessel[[iz, ix]] {
                sums[b][0] += echo[[iz, ix]];
                sums[b][1] += 1.0;
            }
            sums[b][2] += noise[[iz, ix]];
            sums[b][3] += 1.0;
        }
    }
    sums.iter()
        .enumerate()
        .filter(|(_, s)| s[1] >= SNR_MIN_VESSEL_PIXELS as f64 && s[2] > 0.0)
        .map(|(b, s)| DepthSnr {
            depth_m: z0 + (b as f64 + 0.5) * SNR_BAND_M,
            snr_db: power_to_db((s[0] / s[1]) / (s[2] / s[3])),
        })
        .collect()
}

/// RI scores of one vessel or of a whole network; see [`RI_SCORE_DEFINITION`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct RiScore {
    /// Median |RI_estimated − RI_true| (a pixel without an RI counts 1).
    pub median_abs_error: f64,
    /// Fraction of the vessel pixels classed as the right kind.
    pub classification_accuracy: f64,
    /// Fraction of the vessel pixels with an RI.
    pub coverage: f64,
    /// Median estimated RI over the pixels that have one.
    pub median_ri: f64,
    /// Vessel pixels scored.
    pub pixels: usize,
}

/// Network-wide RI scores with a breakdown per vessel.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RiScores {
    /// Median |RI_estimated − RI_true| over every vessel pixel.
    pub median_abs_error: f64,
    /// Fraction of the vessel pixels classed as the right kind.
    pub classification_accuracy: f64,
    /// Fraction of the vessel pixels with an RI.
    pub coverage: f64,
    /// Among vessel pixels the estimate classes as vessel, the fraction whose flow direction
    /// (toward or away from the probe) is right.
    pub direction_accuracy: f64,
    /// Scores of each vessel of the truth, by vessel index.
    #[serde(skip)]
    pub per_vessel: Vec<RiScore>,
}

/// Scores over the true vessel pixels where `select(vessel index)` holds.
fn score_where(est: &RiMaps, truth: &NetworkTruth, select: impl Fn(usize) -> bool) -> RiScore {
    let (mut errors, mut ris) = (vec![], vec![]);
    let (mut correct, mut covered) = (0usize, 0usize);
    Zip::from(&est.ri)
        .and(&est.vessel_class)
        .and(&truth.ri)
        .and(&truth.vessel_class)
        .and(&truth.vessel_index)
        .for_each(|&ri, &class, &true_ri, &true_class, &vessel| {
            if true_class == BACKGROUND || !select(vessel) {
                return;
            }
            if ri.is_finite() {
                errors.push((ri - true_ri).abs());
                ris.push(ri);
                covered += 1;
            } else {
                errors.push(1.0);
            }
            if class == true_class {
                correct += 1;
            }
        });
    let n = errors.len();
    RiScore {
        median_abs_error: median(errors),
        classification_accuracy: correct as f64 / n.max(1) as f64,
        coverage: covered as f64 / n.max(1) as f64,
        median_ri: median(ris),
        pixels: n,
    }
}

/// Scores the RI maps `est` against `truth`, network-wide and per vessel; see
/// [`RI_SCORE_DEFINITION`].
pub fn score_ri(est: &RiMaps, truth: &NetworkTruth) -> RiScores {
    let all = score_where(est, truth, |_| true);
    let vessels = truth
        .vessel_index
        .iter()
        .filter(|&&i| i != usize::MAX)
        .max()
        .map_or(0, |&m| m + 1);
    let (mut right, mut n) = (0usize, 0usize);
    Zip::from(&est.flow_up)
        .and(&est.vessel_class)
        .and(&truth.flow_up)
        .and(&truth.vessel_class)
        .for_each(|&up, &class, &true_up, &true_class| {
            if true_class != BACKGROUND && class != BACKGROUND {
                n += 1;
                right += usize::from(up == true_up);
            }
        });
    RiScores {
        median_abs_error: all.median_abs_error,
        classification_accuracy: all.classification_accuracy,
        coverage: all.coverage,
        direction_accuracy: right as f64 / n.max(1) as f64,
        per_vessel: (0..vessels)
            .map(|v| score_where(est, truth, |i| i == v))
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamics::{ARTERIOLE, UNDETERMINED, VENULE};
    use ndarray::array;

    #[test]
    fn rmse_by_hand_and_missing_estimates_count_as_zero() {
        // Three vessel pixels, one outside (ignored whatever its error).
        let truth = Truth {
            vx: array![[1.0e-3, 2.0e-3], [3.0e-3, 100.0]],
            vz: array![[0.0, 0.0], [-2.0e-3, 100.0]],
            mask: array![[true, true], [true, false]],
        };
        let field = VectorField {
            vx: array![[2.0e-3, 2.0e-3], [f64::NAN, 0.0]],
            vz: array![[1.0e-3, -1.0e-3], [-2.0e-3, 0.0]],
        };
        let r = rmse(&field, &truth);
        // Vx errors 1, 0 and (missing) 3 mm/s: √((1 + 0 + 9)/3); Vz errors 1, 1, 0: √(2/3).
        assert!((r.vx - (10.0f64 / 3.0).sqrt()).abs() < 1e-12, "{r:?}");
        assert!((r.vz - (2.0f64 / 3.0).sqrt()).abs() < 1e-12, "{r:?}");
    }

    #[test]
    fn mean_power_over_frames() {
        let mut s = Array3::<Complex32>::zeros((1, 2, 2));
        s[[0, 0, 0]] = Complex32::new(3.0, 4.0); // |.|² = 25
        s[[0, 1, 1]] = Complex32::new(0.0, 2.0); // 4
        assert_eq!(mean_power(&s), array![[12.5, 2.0]]);
    }

    #[test]
    fn snr_by_depth_by_hand() {
        // Two 0.5 mm bands of 10 rows each, 2 columns; vessel in column 0 of every row.
        let grid = Grid::new(0.0, 0.1e-3, 1.0e-3, 1.95e-3, 0.05e-3).unwrap();
        let (nz, nx) = grid.shape();
        assert_eq!((nz, nx), (20, 3));
        let vessel = Array2::from_shape_fn((nz, nx), |(_, ix)| ix == 0);
        // Echo power 100 in the vessel of band 0, 10 in band 1; noise 1 everywhere in band 0, 2 in band 1.
        let echo = Array2::from_shape_fn((nz, nx), |(iz, ix)| match (iz < 10, ix) {
            (true, 0) => 100.0,
            (false, 0) => 10.0,
            _ => 7.0, // outside the vessel: not echo power
        });
        let noise = Array2::from_shape_fn((nz, nx), |(iz, _)| if iz < 10 { 1.0 } else { 2.0 });
        let snr = snr_by_depth(&echo, &noise, &vessel, &grid);
        assert_eq!(snr.len(), 2);
        assert!((snr[0].depth_m - 1.25e-3).abs() < 1e-12);
        assert!((snr[0].snr_db - 20.0).abs() < 1e-9);
        assert!((snr[1].depth_m - 1.75e-3).abs() < 1e-12);
        assert!((snr[1].snr_db - power_to_db(5.0)).abs() < 1e-9);
        // A band with fewer than 10 vessel pixels is not reported.
        let sparse = Array2::from_shape_fn((nz, nx), |(iz, ix)| ix == 0 && iz % 2 == 0);
        assert!(snr_by_depth(&echo, &noise, &sparse, &grid).is_empty());
    }

    #[test]
    fn ri_scores_by_hand() {
        // Vessel 0: two arteriole pixels (RI 0.7), vessel 1: two venule pixels (RI 0.3); one background.
        let truth = NetworkTruth {
            psv: Array2::zeros((1, 5)),
            edv: Array2::zeros((1, 5)),
            ri: array![[0.7, 0.7, 0.3, 0.3, f64::NAN]],
            vessel_class: array![[ARTERIOLE, ARTERIOLE, VENULE, VENULE, BACKGROUND]],
            flow_up: array![[true, true, false, false, false]],
            vessel_index: array![[0, 0, 1, 1, usize::MAX]],
            class_share: array![[1.0, 1.0, 1.0, 1.0, 0.0]],
            axis_profile: array![[1.0, 1.0, 1.0, 1.0, 0.0]],
        };
        let est = RiMaps {
            ri: array![[0.8, 0.5, 0.3, f64::NAN, 0.9]],
            vessel_class: array![[ARTERIOLE, UNDETERMINED, VENULE, BACKGROUND, ARTERIOLE]],
            flow_up: array![[true, false, false, false, true]],
            psv: Array2::zeros((1, 5)),
            edv: Array2::zeros((1, 5)),
            psv_spread: Array2::zeros((1, 5)),
            edv_spread: Array2::zeros((1, 5)),
            ri_spread: Array2::zeros((1, 5)),
            heart_rate_hz: 5.5,
            cycles: vec![],
            cycle_source: crate::dynamics::CycleSource::GivenRate,
        };
        let s = score_ri(&est, &truth);
        // Errors 0.1, 0.2, 0.0 and 1 (missing): median 0.15.
        assert!((s.median_abs_error - 0.15).abs() < 1e-12, "{s:?}");
        assert_eq!(s.classification_accuracy, 0.5);
        assert_eq!(s.coverage, 0.75);
        // Pixels classed vessel by both: 0, 1, 2; directions right at 0 and 2.
        assert!((s.direction_accuracy - 2.0 / 3.0).abs() < 1e-12);
        assert_eq!(s.per_vessel.len(), 2);
        assert!((s.per_vessel[0].median_abs_error - 0.15).abs() < 1e-12);
        assert!((s.per_vessel[0].median_ri - 0.65).abs() < 1e-12);
        assert_eq!(s.per_vessel[1].median_abs_error, 0.5);
        assert_eq!(s.per_vessel[1].pixels, 2);
        assert_eq!(s.per_vessel[1].coverage, 0.5);
    }
}
