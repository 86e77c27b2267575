//! A simulated recording's maps scored against its ground truth.
//!
//! `pcuvd simulate` writes the scenario it simulated (`scenario.toml`, every option applied)
//! beside its recordings. Where a processed recording has one beside it, the truth is computed
//! again from that scenario on the run's own grid (so any `--grid` is scored), its velocity
//! averaged over the recording as a whole-recording map averages the flow (a pulsing vessel's
//! velocity at one time is not what the map estimates), and the run's maps are scored against
//! it: summary.json's `against_truth`, and the figure [`FIGURE`]. The `truth_*.npy` files beside
//! the recording are the truth at the recording's start, on the default grid: the same as this
//! one for steady flow, not for a beating network.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use ndarray::{Array2, Zip};
use pcuvd::acquisition::source::FrameSource;
use pcuvd::core::grid::Grid;
use pcuvd::dynamics::BACKGROUND;
use pcuvd::estimate::vector::VectorField;
use pcuvd::evaluate::metrics::{self, RiScores, Rmse};
use pcuvd::simulate::phantom::Truth;
use pcuvd::simulate::phantom::network::NetworkTruth;
use pcuvd_render::{Colormap, Panel};
use serde::Serialize;

use crate::figures;
use crate::run::{DynamicsOutcome, Processed};
use crate::simulation::folder::{SCENARIO_FILE, SCENARIO_HEADER};
use crate::simulation::{Simulation, truth_times};

/// The figure of a run scored against its truth: the truth beside the estimate and their error.
pub const FIGURE: &str = "against_truth.png";

/// Which pixels are scored.
pub const PIXELS_DEFINITION: &str = "vessel pixels: those holding blood at the recording's start \
in the truth; for a vascular tree, those whose blood is mostly of a vessel at least 20 µm wide \
(its lumen, not the capillary bed), as `pcuvd paper --part brain` scores";

/// What the truth is.
pub const TRUTH_DEFINITION: &str = "the in-plane velocity the scenario beside the recording gives \
each pixel on the run's grid, averaged over 24 times evenly spread over the recording at the \
times the pixel holds blood, vessels carried with the tissue: what a whole-recording map \
estimates";

/// How the colour Doppler is scored.
pub const COLOR_DOPPLER_DEFINITION: &str = "RMSE (mm/s) of the colour Doppler against the true \
axial velocity Vz over the vessel pixels; a pixel without an estimate (NaN) counts as 0";

/// How the figures' flow pixels are scored.
pub const SHOWN_DEFINITION: &str = "shares of the vessel pixels and of the pixels without blood \
(none at the recording's start, a tree's capillaries counting as blood) that the colour-Doppler \
figure draws as flow (summary.json's figures.flow_rule at figures.colour_level_db)";

/// A run's scores against the truth of the simulation it processed, or why it has none.
#[derive(Debug, Clone, Serialize)]
#[serde(untagged)]
pub enum TruthRecord {
    /// The scores.
    Scored(Box<TruthScores>),
    /// Why the run could not be scored, with the scenario found beside the recording.
    NotScored {
        /// The scenario file beside the recording.
        scenario: String,
        /// Why it gave no truth for this run.
        not_scored: String,
    },
}

/// A run's maps scored against the simulation's truth.
#[derive(Debug, Clone, Serialize)]
pub struct TruthScores {
    /// The scenario file the truth was computed from (or how the scenario came with the
    /// recording: one simulated in memory carries its own).
    pub scenario: String,
    /// Vessel pixels scored ([`PIXELS_DEFINITION`]).
    pub vessel_pixels: usize,
    /// The fastest true speed over the vessel pixels (mm/s).
    pub peak_speed_mm_s: f64,
    /// RMSE of the colour Doppler against the true Vz (mm/s; [`COLOR_DOPPLER_DEFINITION`]).
    pub color_doppler_rmse_mm_s: f64,
    /// Vector RMSE per component (mm/s); absent with a single angle.
    pub vector_rmse_mm_s: Option<ByEstimator<Rmse>>,
    /// Share of the vessel pixels whose vector error is at most 10 % of the peak speed; absent
    /// with a single angle.
    pub vector_within_10_percent_of_peak: Option<ByEstimator<f64>>,
    /// Share of the vessel pixels the colour-Doppler figure draws as flow.
    pub vessel_pixels_shown: f64,
    /// Share of the pixels without blood the colour-Doppler figure draws as flow.
    pub blood_free_pixels_shown: f64,
    /// The RI maps against the cardiac cycle's truth (PC-UVD's RI maps: the IRLS vectors'), or
    /// why there is no score.
    pub ri: RiRecord,
    /// Every definition, in words.
    pub definitions: Definitions,
}

/// One score of each vector estimator.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ByEstimator<T> {
    /// IRLS, PC-UVD's estimator (vx.npy, vz.npy).
    pub irls: T,
    /// Least squares, UVD's (vx_ls.npy, vz_ls.npy).
    pub ls: T,
}

/// RI scores, or why there are none.
#[derive(Debug, Clone, Serialize)]
#[serde(untagged)]
pub enum RiRecord {
    /// Scored over the vessel pixels.
    Scored(RiScores),
    /// Why not.
    NotScored(&'static str),
}

/// The definitions of every score, written beside them.
#[derive(Debug, Clone, Serialize)]
pub struct Definitions {
    /// Which pixels are scored.
    pub pixels: &'static str,
    /// What the truth is.
    pub truth: &'static str,
    /// The vector RMSE.
    pub vector_rmse: &'static str,
    /// The share within 10 % of the peak.
    pub within_10_percent_of_peak: &'static str,
    /// The colour Doppler's RMSE.
    pub color_doppler_rmse: &'static str,
    /// The shares drawn as flow.
    pub shown: &'static str,
    /// The RI scores.
    pub ri: &'static str,
}

impl Default for Definitions {
    fn default() -> Self {
        Definitions {
            pixels: PIXELS_DEFINITION,
            truth: TRUTH_DEFINITION,
            vector_rmse: metrics::RMSE_DEFINITION,
            within_10_percent_of_peak: metrics::WITHIN_PEAK_DEFINITION,
            color_doppler_rmse: COLOR_DOPPLER_DEFINITION,
            shown: SHOWN_DEFINITION,
            ri: metrics::RI_SCORE_DEFINITION,
        }
    }
}

/// A run scored against its truth: the record for summary.json, and the truth it was scored
/// against, for the figure.
pub struct AgainstTruth {
    /// What summary.json records.
    pub record: TruthRecord,
    /// The truth on the run's grid and the scored pixels; `None` where not scored.
    truth: Option<ScoredTruth>,
}

/// The truth a run was scored against.
struct ScoredTruth {
    /// Velocity (m/s, averaged over the recording) and the scored pixels as its mask.
    flow: Truth,
    /// The pixels holding any blood at the recording's start (a tree's capillaries too).
    blood: Array2<bool>,
    /// The cardiac cycle's truth, with the pixels outside the scored ones as background.
    cycle: Option<NetworkTruth>,
}

/// The scenario file `pcuvd simulate` wrote beside the recording `input` (a path as the user
/// gave it), if there is one: the sign of a recording it simulated. A file of that name that
/// pcuvd did not write (a lab's own notes beside a measured recording) is not taken for one.
pub fn scenario_beside(input: &str) -> Option<PathBuf> {
    use std::io::BufRead;
    let input = Path::new(input);
    if !input.is_file() {
        return None;
    }
    let scenario = input.parent()?.join(SCENARIO_FILE);
    let mut first_line = String::new();
    std::io::BufReader::new(std::fs::File::open(&scenario).ok()?)
        .read_line(&mut first_line)
        .ok()?;
    first_line.starts_with(SCENARIO_HEADER).then_some(scenario)
}

/// The run on `data` scored against the truth of the simulation it came from: `simulated_from`,
/// the scenario (TOML) a recording simulated in memory carries, or else the scenario file beside
/// `input`, its file; `None` where there is neither (not a simulation).
pub fn score_run(
    input: &str,
    simulated_from: Option<&str>,
    data: &dyn FrameSource,
    processed: &Processed,
) -> Option<AgainstTruth> {
    if let Some(text) = simulated_from {
        return Some(score_scenario_text(text, SIMULATED_WITH, data, processed));
    }
    let path = scenario_beside(input)?;
    let named = path.display().to_string();
    Some(match crate::scenario::Scenario::load(&named) {
        Ok(scenario) => score_against(scenario, &named, data, processed),
        Err(e) => AgainstTruth::not_scored(named, format!("{e:#}")),
    })
}

/// How the record names the scenario a recording simulated in memory came with.
const SIMULATED_WITH: &str = "the scenario it was simulated with";

/// The run on `data` scored against the truth of the scenario `text` (TOML) describes, named
/// `named` in the record; a scenario that does not parse is recorded as not scored, with why.
fn score_scenario_text(
    text: &str,
    named: &str,
    data: &dyn FrameSource,
    processed: &Processed,
) -> AgainstTruth {
    match crate::scenario::Scenario::parse(text) {
        Ok(scenario) => score_against(scenario, named, data, processed),
        Err(e) => AgainstTruth::not_scored(named.to_string(), format!("{e:#}")),
    }
}

/// The run on `data` scored against the truth of `scenario` (named `named` in the record): a
/// recording simulated in memory, whose scenario came with it rather than beside a file.
pub fn score_against(
    scenario: crate::scenario::Scenario,
    named: &str,
    data: &dyn FrameSource,
    processed: &Processed,
) -> AgainstTruth {
    let named = named.to_string();
    let truth = match scored_truth(scenario, &named, data, &processed.out.grid) {
        Ok(truth) => truth,
        Err(e) => return AgainstTruth::not_scored(named, format!("{e:#}")),
    };
    match scores(&named, &truth, processed) {
        Ok(scores) => AgainstTruth {
            record: TruthRecord::Scored(Box::new(scores)),
            truth: Some(truth),
        },
        Err(why) => AgainstTruth::not_scored(named, why.to_string()),
    }
}

/// The truth of `scenario` (named `named`) on `grid`, averaged over the recording `data`, and
/// its scored pixels; an error where the scenario does not describe `data`.
fn scored_truth(
    scenario: crate::scenario::Scenario,
    named: &str,
    data: &dyn FrameSource,
    grid: &Grid,
) -> Result<ScoredTruth> {
    let simulation = Simulation::of(scenario, named.to_string()).context("the scenario")?;
    let acq = data.acquisition();
    let (angles, coded) = (acq.sequence.n_angles(), acq.sequence.is_coded());
    let same_rate = |rate: f64| (rate - acq.frame_rate()).abs() <= 1e-9 * acq.frame_rate();
    let described = simulation.modes.iter().any(|(_, params)| {
        let theirs = params.acquisition();
        theirs.sequence.n_angles() == angles
            && theirs.sequence.is_coded() == coded
            && same_rate(theirs.frame_rate())
    });
    if !described || simulation.frames != data.n_frames() {
        anyhow::bail!(
            "it describes other recordings ({} frames of {}) than this one ({} frames of {angles} \
             {} angles at {:.1} Hz): simulated again since?",
            simulation.frames,
            simulation
                .modes
                .iter()
                .map(|(name, params)| format!(
                    "{} {name} angles at {:.1} Hz",
                    params.sequence.n_angles(),
                    params.acquisition().frame_rate()
                ))
                .collect::<Vec<_>>()
                .join(" or "),
            data.n_frames(),
            if coded { "coded" } else { "conventional" },
            acq.frame_rate(),
        );
    }
    let duration_s = data.n_frames() as f64 / acq.frame_rate();
    let truth = simulation.truth_averaged_on(grid, &truth_times(duration_s));
    let scored = match simulation.lumen(&truth) {
        Some((_, lumen)) => lumen,
        None => truth.truth.mask.clone(),
    };
    let cycle = truth.cycle.map(|mut cycle| {
        Zip::from(&mut cycle.vessel_class)
            .and(&scored)
            .for_each(|class, &scored| {
                if !scored {
                    *class = BACKGROUND;
                }
            });
        cycle
    });
    Ok(ScoredTruth {
        flow: Truth {
            vx: truth.truth.vx,
            vz: truth.truth.vz,
            mask: scored,
        },
        blood: truth.truth.mask,
        cycle,
    })
}

/// The run's maps scored against `truth`; an error where the truth holds no vessel pixel.
fn scores(
    scenario: &str,
    truth: &ScoredTruth,
    processed: &Processed,
) -> Result<TruthScores, &'static str> {
    let out = &processed.out;
    let maps = &out.maps;
    let flow = &truth.flow;
    let vessel_pixels = flow.mask.iter().filter(|&&m| m).count();
    if vessel_pixels == 0 {
        return Err("the truth holds no vessel pixel on the run's grid");
    }
    let peak =
        Zip::from(&flow.vx)
            .and(&flow.vz)
            .and(&flow.mask)
            .fold(
                0.0_f64,
                |top, &vx, &vz, &m| if m { top.max(vx.hypot(vz)) } else { top },
            );
    let axial_only = Truth {
        vx: Array2::zeros(flow.mask.dim()),
        vz: flow.vz.clone(),
        mask: flow.mask.clone(),
    };
    let color = VectorField {
        vx: Array2::zeros(flow.mask.dim()),
        vz: maps.color_doppler.clone(),
    };
    let estimators = maps.vector_irls.as_ref().zip(maps.vector_ls.as_ref());
    let shown = figures::colour_flow_mask(out);
    let share = |select: &Array2<bool>, within: bool| {
        let (mut drawn, mut all) = (0usize, 0usize);
        Zip::from(&shown).and(select).for_each(|&s, &m| {
            if m == within {
                all += 1;
                drawn += usize::from(s);
            }
        });
        drawn as f64 / all.max(1) as f64
    };
    let ri = match (&truth.cycle, &processed.dynamics) {
        (None, _) => RiRecord::NotScored("the scenario's flow is steady: no cardiac cycle"),
        (Some(_), DynamicsOutcome::Skipped(_) | DynamicsOutcome::Failed(_)) => {
            RiRecord::NotScored("the run made no RI maps (summary.json's dynamics says why)")
        }
        (Some(cycle), DynamicsOutcome::Done { maps, .. }) => {
            RiRecord::Scored(metrics::score_ri(maps, cycle))
        }
    };
    Ok(TruthScores {
        scenario: scenario.to_string(),
        vessel_pixels,
        peak_speed_mm_s: peak * 1e3,
        color_doppler_rmse_mm_s: metrics::rmse(&color, &axial_only).vz,
        vector_rmse_mm_s: estimators.map(|(irls, ls)| ByEstimator {
            irls: metrics::rmse(irls, flow),
            ls: metrics::rmse(ls, flow),
        }),
        vector_within_10_percent_of_peak: estimators.map(|(irls, ls)| ByEstimator {
            irls: metrics::within_fraction_of_peak(irls, flow, peak, 0.1),
            ls: metrics::within_fraction_of_peak(ls, flow, peak, 0.1),
        }),
        vessel_pixels_shown: share(&flow.mask, true),
        blood_free_pixels_shown: share(&truth.blood, false),
        ri,
        definitions: Definitions::default(),
    })
}

impl TruthRecord {
    /// One line for the user: the scores, or why there are none.
    pub fn line(&self) -> String {
        let scores = match self {
            TruthRecord::NotScored {
                scenario,
                not_scored,
            } => return format!("not scored against the truth of {scenario}: {not_scored}"),
            TruthRecord::Scored(scores) => scores,
        };
        let mut line = format!(
            "against the truth of {} ({} vessel pixels, peak {:.1} mm/s): ",
            scores.scenario, scores.vessel_pixels, scores.peak_speed_mm_s
        );
        match &scores.vector_rmse_mm_s {
            Some(rmse) => line.push_str(&format!(
                "vector RMSE Vx {:.2} / Vz {:.2} mm/s (IRLS; least squares {:.2} / {:.2})",
                rmse.irls.vx, rmse.irls.vz, rmse.ls.vx, rmse.ls.vz
            )),
            None => line.push_str(&format!(
                "colour Doppler RMSE {:.2} mm/s",
                scores.color_doppler_rmse_mm_s
            )),
        }
        line.push_str(&format!(
            ", {:.0} % of them drawn as flow ({:.1} % of the pixels without blood)",
            100.0 * scores.vessel_pixels_shown,
            100.0 * scores.blood_free_pixels_shown
        ));
        if let RiRecord::Scored(ri) = &scores.ri {
            line.push_str(&format!(
                "; RI median |ΔRI| {:.3}, {:.0} % classed right",
                ri.median_abs_error,
                100.0 * ri.classification_accuracy
            ));
        }
        line
    }
}

impl AgainstTruth {
    /// A run the scenario named `scenario` gave no scores, and `why`.
    fn not_scored(scenario: String, why: String) -> Self {
        AgainstTruth {
            record: TruthRecord::NotScored {
                scenario,
                not_scored: why,
            },
            truth: None,
        }
    }

    /// Draws [`FIGURE`] into `dir`: the truth beside the estimate (the IRLS vectors, or the colour
    /// Doppler with a single angle) and their error over the vessel pixels, and the same for RI
    /// where it was scored. `None` where the run was not scored.
    pub fn figure(&self, dir: &Path, processed: &Processed, name: &str) -> Result<Option<PathBuf>> {
        let (Some(truth), TruthRecord::Scored(scores)) = (&self.truth, &self.record) else {
            return Ok(None);
        };
        let out = &processed.out;
        let grid = &out.grid;
        let flow = &truth.flow;
        let background = figures::bmode_background(&out.bmode_db);
        let masked = |data: Array2<f64>| {
            Zip::from(&data)
                .and(&flow.mask)
                .map_collect(|&v, &m| if m { v } else { f64::NAN })
        };
        // A map drawn over the B-mode at the pixels `shown`.
        let on_bmode = |title: &str,
                        data: Array2<f64>,
                        colormap: Colormap,
                        range: (f64, f64),
                        label: &str,
                        shown: Array2<bool>| {
            let mut panel = figures::map_panel(title, data, grid, colormap, range, label);
            panel.mask = Some(shown);
            panel.background = Some(background.clone());
            Panel::Image(panel)
        };
        // Errors over the vessel pixels that have one (NaN elsewhere).
        let error_panel = |title: &str, error: Array2<f64>, top: f64, label: &str| {
            let error = masked(error);
            let shown = error.mapv(|e| !e.is_nan());
            on_bmode(title, error, Colormap::Magma, (0.0, top), label, shown)
        };
        let mut panels = Vec::new();
        match &out.maps.vector_irls {
            Some(irls) => {
                let true_field = VectorField {
                    vx: flow.vx.clone(),
                    vz: flow.vz.clone(),
                };
                let vmax = figures::speed_scale(&[(&true_field, &flow.mask)]);
                // The speed of every vessel pixel, as the error panel beside it has them,
                // without triangles: over vessels a few pixels wide they hide the speed, and the
                // error panel holds the direction's error (vector.png the directions).
                let speed_panel = |title: &str, field: &VectorField| {
                    let speed = field.speed().mapv(|v| v * 1e3);
                    let range = (0.0, vmax);
                    on_bmode(
                        title,
                        speed,
                        Colormap::Viridis,
                        range,
                        "speed (mm/s)",
                        flow.mask.clone(),
                    )
                };
                panels.push(speed_panel(
                    "Truth: speed, averaged over the recording",
                    &true_field,
                ));
                panels.push(speed_panel("Speed, PC-UVD estimator (IRLS-WLS)", irls));
                let error = Zip::from(&irls.vx)
                    .and(&irls.vz)
                    .and(&flow.vx)
                    .and(&flow.vz)
                    .map_collect(|&ex, &ez, &tx, &tz| (ex - tx).hypot(ez - tz) * 1e3);
                panels.push(error_panel(
                    "Vector error |v − v_true|",
                    error,
                    vmax,
                    "mm/s",
                ));
            }
            None => {
                let vmax = scores.peak_speed_mm_s.max(1e-3);
                panels.push(figures::axial_velocity_panel(
                    "Truth: axial velocity",
                    &flow.vz,
                    grid,
                    vmax,
                    &flow.mask,
                ));
                panels.push(figures::axial_velocity_panel(
                    "Colour Doppler",
                    &out.maps.color_doppler,
                    grid,
                    vmax,
                    &flow.mask,
                ));
                let error = (&out.maps.color_doppler - &flow.vz).mapv(|e| e.abs() * 1e3);
                panels.push(error_panel("Axial error |v − v_true|", error, vmax, "mm/s"));
            }
        }
        if let (Some(cycle), RiRecord::Scored(_), DynamicsOutcome::Done { maps, .. }) =
            (&truth.cycle, &scores.ri, &processed.dynamics)
        {
            let ri_panel = |title: &str, ri: &Array2<f64>| {
                let ri = masked(ri.clone());
                on_bmode(
                    title,
                    ri,
                    Colormap::Viridis,
                    (0.0, 1.0),
                    "RI",
                    flow.mask.clone(),
                )
            };
            panels.push(ri_panel("Truth: RI", &cycle.ri));
            panels.push(ri_panel("RI (PC-UVD)", &maps.ri));
            let error = Zip::from(&maps.ri)
                .and(&cycle.ri)
                .map_collect(|&est, &truth| (est - truth).abs());
            panels.push(error_panel("RI error |RI − RI_true|", error, 1.0, "|ΔRI|"));
        }
        let title = format!(
            "{name}: against the simulation's truth ({})",
            scores.scenario
        );
        figures::save_figure(&dir.join(FIGURE), &title, panels, 3, out).map(Some)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulation::{Preset, SimulationSettings};

    /// A run on a grid of the user's is scored against the truth of its own pixels: on a grid cut
    /// from the default one, the pulsing network's averaged velocity, mask and cycle truth are the
    /// default grid's at the same pixels.
    #[test]
    fn the_truth_on_a_users_grid_is_the_default_grids_at_the_same_pixels() {
        let simulation = Simulation::new(&SimulationSettings {
            preset: Some(Preset::RatNetwork),
            ..SimulationSettings::default()
        })
        .unwrap();
        let params = &simulation.modes[0].1;
        let whole =
            pcuvd::pipeline::default_grid_for(&params.acquisition(), params.n_samples).unwrap();
        let (rows, cols) = (60..260, 20..120);
        let cut = Grid {
            x: whole.x[cols.clone()].to_vec(),
            z: whole.z[rows.clone()].to_vec(),
        };
        let times = truth_times(0.2);
        let on_whole = simulation.truth_averaged_on(&whole, &times);
        let on_cut = simulation.truth_averaged_on(&cut, &times);
        let block = ndarray::s![rows, cols];
        assert!(on_cut.truth.mask.iter().filter(|&&m| m).count() > 100);
        assert_eq!(on_cut.truth.mask, on_whole.truth.mask.slice(block));
        assert_eq!(on_cut.truth.vx, on_whole.truth.vx.slice(block));
        assert_eq!(on_cut.truth.vz, on_whole.truth.vz.slice(block));
        let (cycle_cut, cycle_whole) = (on_cut.cycle.unwrap(), on_whole.cycle.unwrap());
        // RI is NaN outside the vessels.
        let marked = |ri: ndarray::ArrayView2<f64>| ri.mapv(|r| if r.is_nan() { -1.0 } else { r });
        assert_eq!(
            marked(cycle_cut.ri.view()),
            marked(cycle_whole.ri.slice(block))
        );
        assert_eq!(
            cycle_cut.vessel_class,
            cycle_whole.vessel_class.slice(block)
        );
        // Averaged, not the start's: a pulsing vessel's mean differs from its speed at t = 0.
        let at_start = simulation.truth_averaged_on(&cut, &[]);
        let moved = Zip::from(&on_cut.truth.vx)
            .and(&at_start.truth.vx)
            .and(&on_cut.truth.mask)
            .fold(0.0_f64, |most, &mean, &start, &m| {
                if m {
                    most.max((mean - start).abs())
                } else {
                    most
                }
            });
        assert!(moved > 1e-4, "largest change {moved} m/s");
        // Each pixel's mean over the times it holds blood, from the truth at each time alone.
        let (mut sum, mut count) = (
            Array2::<f64>::zeros(cut.shape()),
            Array2::<f64>::zeros(cut.shape()),
        );
        for &t in &times {
            let at = simulation.truth_averaged_on(&cut, &[t]);
            Zip::from(&mut sum)
                .and(&mut count)
                .and(&at.truth.vx)
                .and(&at.truth.mask)
                .for_each(|s, n, &vx, &blood| {
                    if blood {
                        *s += vx;
                        *n += 1.0;
                    }
                });
        }
        Zip::from(&on_cut.truth.vx)
            .and(&sum)
            .and(&count)
            .for_each(|&mean, &s, &n| {
                let expected = if n > 0.0 { s / n } else { 0.0 };
                assert!(
                    (mean - expected).abs() <= 1e-12,
                    "{mean} against {expected}"
                );
            });
    }
}
