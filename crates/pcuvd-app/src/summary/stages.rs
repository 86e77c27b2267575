//! What each stage of a run did, as `summary.json` records it: the clutter filter, Doppler, the
//! vector fit, dealiasing, the dynamics, and how the frames were split (blocks, segments,
//! ensembles), with the rules they follow in words.

use pcuvd::dynamics::{self, PoolingSummary};
use pcuvd::estimate::clutter::{self, BlockLayout, ClutterReport};
use pcuvd::estimate::masks;
use pcuvd::estimate::partial_volume::CellCovariance;
use pcuvd::pipeline::{self, ProcessOutput, ProcessParams};
use serde::Serialize;

use crate::run::{DynamicsOutcome, Plan, Processed};

/// A clutter filter's cut-offs as `summary.json` writes them: singular components kept are
/// `low..high`; the blocks' ranges are left out for a whole-image filter (which the pipeline's own
/// [`clutter::CutOffs`], sent between processes in a format without field names, cannot do).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct CutOffs {
    /// Components removed from the top (tissue).
    pub low: usize,
    /// First component removed from the bottom (noise).
    pub high: usize,
    /// A block-wise filter: the least and the most components its blocks removed from the top
    /// (`low` and `high` are then the blocks' medians).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub block_low_range: Option<[usize; 2]>,
    /// A block-wise filter: the least and the most of its blocks' `high`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub block_high_range: Option<[usize; 2]>,
}

impl From<clutter::CutOffs> for CutOffs {
    fn from(c: clutter::CutOffs) -> CutOffs {
        CutOffs {
            low: c.low,
            high: c.high,
            block_low_range: c.block_low_range,
            block_high_range: c.block_high_range,
        }
    }
}

impl CutOffs {
    /// What one filter reported, with its blocks' ranges when it worked block-wise.
    pub(super) fn of(report: &ClutterReport) -> CutOffs {
        report.cut_offs().into()
    }
}

/// The SVD clutter filter's settings and the cut-offs it chose per angle.
#[derive(Debug, Clone, Serialize)]
pub struct ClutterRecord {
    /// The low (tissue) cut-off as set.
    pub low: String,
    /// The high (noise) cut-off as set.
    pub high: String,
    /// Tissue's largest Doppler frequency, as a fraction of the PRF.
    pub tissue_frequency_fraction: f64,
    /// Block-wise filtering: the blocks' size (rows, columns of pixels) as filtered, grown from
    /// `--svd-block-mm` where a block would hold fewer pixels than frames; absent for one filter
    /// over the whole image.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub block_pixels: Option<[usize; 2]>,
    /// Block-wise filtering: each row of blocks' first row and each column of blocks' first
    /// column (pixels), the blocks of `clutter_block_cut_offs.npy`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub block_starts_px: Option<BlockStarts>,
    /// The cut-offs each angle's filter used.
    pub cut_offs_per_angle: Vec<CutOffs>,
}

/// Where a block-wise filter's blocks start (pixels).
#[derive(Debug, Clone, Serialize)]
pub struct BlockStarts {
    /// Each row of blocks' first row.
    pub z: Vec<usize>,
    /// Each column of blocks' first column.
    pub x: Vec<usize>,
}

impl BlockStarts {
    /// Where the blocks of `layout` start.
    pub(super) fn of(layout: &BlockLayout) -> BlockStarts {
        BlockStarts {
            z: layout.z_starts.clone(),
            x: layout.x_starts.clone(),
        }
    }
}

/// Doppler estimation settings.
#[derive(Debug, Clone, Serialize)]
pub struct DopplerRecord {
    /// Averaging kernel (rows, columns of pixels).
    pub kernel: [usize; 2],
    /// The estimator's name.
    pub estimator: &'static str,
    /// What the estimator does.
    pub estimator_description: &'static str,
    /// Whether the partial-volume correction was on.
    pub partial_volume: bool,
    /// Each angle's intensity cell at one pixel (its speckle's) as the correction saw it; `None`
    /// where it could not be measured; absent (`null`) with the correction off or one angle (no
    /// vector fit for it to correct).
    pub partial_volume_cells: Option<Vec<Option<CellRecord>>>,
}

/// A resolution cell's intensity covariance (mm, mm²).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CellRecord {
    /// Lateral standard deviation (mm).
    pub sigma_x_mm: f64,
    /// Axial standard deviation (mm).
    pub sigma_z_mm: f64,
    /// Lateral-axial covariance (mm²).
    pub covariance_xz_mm2: f64,
}

impl CellRecord {
    /// Each angle's cell (m², as the partial-volume correction measures it) in mm and mm²; `None`
    /// where it could not be measured.
    pub fn of_angles(cells: &[Option<CellCovariance>]) -> Vec<Option<CellRecord>> {
        cells
            .iter()
            .map(|cell| {
                cell.map(|c| CellRecord {
                    sigma_x_mm: c.xx.sqrt() * 1e3,
                    sigma_z_mm: c.zz.sqrt() * 1e3,
                    covariance_xz_mm2: c.xz * 1e6,
                })
            })
            .collect()
    }
}

/// The IRLS vector fit's settings.
#[derive(Debug, Clone, Serialize)]
pub struct IrlsRecord {
    /// Regularisation λ (mm/s).
    pub lambda_mm_s: f64,
    /// Convergence ε.
    pub epsilon: f64,
    /// Iterations at most.
    pub max_iterations: usize,
}

/// What dealiasing did, with the rule it follows.
#[derive(Debug, Clone, Serialize)]
pub struct DealiasRecord {
    /// The setting ("off", "auto", or K).
    pub setting: String,
    /// The warning for a coded recording or one of too few angles.
    pub warning: Option<String>,
    /// What it did, when it ran.
    #[serde(flatten)]
    pub done: Option<DealiasDone>,
}

/// What a dealiasing run did.
#[derive(Debug, Clone, Serialize)]
pub struct DealiasDone {
    /// Nyquist intervals K unwrapped per angle.
    pub intervals: u32,
    /// The fastest speed reached, (2K + 1) v_N (m/s).
    pub max_speed_m_s: f64,
    /// Flow pixels, the ones dealiased.
    pub flow_pixels: usize,
    /// PC-UVD's (IRLS) counts.
    pub pcuvd_irls: AliasRecord,
    /// UVD's (least squares) counts.
    pub uvd_ls: AliasRecord,
    /// The rule, in words.
    pub rule: String,
}

/// One estimator's dealiasing counts.
#[derive(Debug, Clone, Serialize)]
pub struct AliasRecord {
    /// Flow pixels whose fit changed.
    pub dealiased_pixels: usize,
    /// Flow pixels given a non-zero common shift.
    pub unwrapped_pixels: usize,
    /// Flow pixels at ±K.
    pub at_limit_pixels: usize,
}

/// The dynamics stage's record, or why it was skipped.
#[derive(Debug, Clone, Serialize)]
#[serde(untagged)]
pub enum DynamicsRecord {
    /// It ran.
    Done(Box<DynamicsDone>),
    /// It did not.
    Skipped {
        /// Why.
        skipped: String,
    },
    /// A dynamics setting asked for it and the recording could not give it (the run's other
    /// results are written; the command then ends in an error).
    Failed {
        /// Why.
        failed: String,
    },
}

/// A vessel-test level (dB), or "off".
#[derive(Debug, Clone, Copy, Serialize)]
#[serde(untagged)]
pub enum Level {
    /// The level (dB).
    Db(f64),
    /// No such test.
    Off(&'static str),
}

impl Level {
    /// `db` as set: "off" for the infinite level that stands for it.
    pub(super) fn of(db: f64) -> Self {
        if db.is_finite() {
            Level::Db(db)
        } else {
            Level::Off("off")
        }
    }
}

/// What the RI maps of a recording of one steering angle are read from.
fn axial_speed() -> String {
    format!(
        "|Vz| of the colour-Doppler velocity (one steering angle): RI is a ratio, so a vessel \
         that keeps its direction to the beam over the cycle reads its own RI at any angle but \
         across the beam; vessel pixels whose velocity does not keep its sign (|sum v| / sum |v| \
         over the windows below {}: a vessel near 90 degrees to the beam, or noise) are \
         undetermined, with NaN PSV, EDV and RI; speed_series.npy holds |Vz|",
        dynamics::AXIAL_COHERENCE_MIN
    )
}

/// What the dynamics stage did.
#[derive(Debug, Clone, Serialize)]
pub struct DynamicsDone {
    /// Heart rate (Hz).
    pub heart_rate_hz: f64,
    /// Whether it was given rather than measured.
    pub heart_rate_given: bool,
    /// Where the cardiac cycles came from.
    pub cycles_from: String,
    /// Where the triggers came from, when given.
    pub triggers_from: Option<String>,
    /// Complete cardiac cycles used.
    pub cycles_count: usize,
    /// What the spread maps hold.
    pub spread: &'static str,
    /// Frames per sliding window.
    pub window_frames: usize,
    /// Frames between windows.
    pub step_frames: usize,
    /// Window length (s).
    pub window_s: f64,
    /// Window step (s).
    pub step_s: f64,
    /// Why the windows start further apart than the default step, when the memory check
    /// spaced them so that the whole recording's fit.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub step_spaced_for_memory: Option<String>,
    /// Harmonics of the heart rate fitted.
    pub harmonics: usize,
    /// True when one steering angle gave the maps: PSV, EDV and RI of the colour-Doppler speed.
    pub axial_only: bool,
    /// The speed PSV, EDV and RI are read from: the vector's, or one angle's colour Doppler's.
    pub speed: String,
    /// The velocity estimator.
    pub estimator: &'static str,
    /// Doppler averaging kernel (rows, columns).
    pub kernel: [usize; 2],
    /// Whether the partial-volume correction was on.
    pub partial_volume: bool,
    /// Smallest RI called an arteriole.
    pub artery_ri_min: f64,
    /// Largest RI called a venule.
    pub vein_ri_max: f64,
    /// Power Doppler level of vessel pixels (dB).
    pub vessel_threshold_db: f64,
    /// Margin above the row's noise floor (dB), or "off".
    pub vessel_margin_db: Level,
    /// What the margin is measured from.
    pub vessel_margin_reference: &'static str,
    /// Level within the brightest pixel nearby (dB), or "off".
    pub vessel_local_db: Level,
    /// Radius of "nearby" (mm).
    pub vessel_local_radius_mm: f64,
    /// How vessel pixels were pooled.
    pub vessel_pooling: PoolingSummary,
    /// The cycles used, as [start, end) windows.
    pub cycles_windows: Vec<(usize, usize)>,
    /// Pixels of each class.
    pub pixels: ClassCounts,
    /// The codes of `vessel_class.npy`.
    pub class_codes: ClassCodes,
}

/// Pixels of each vessel class.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ClassCounts {
    /// Arteriole pixels.
    pub arteriole: usize,
    /// Venule pixels.
    pub venule: usize,
    /// Vessel pixels of neither kind.
    pub undetermined: usize,
}

/// The codes of `vessel_class.npy`.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ClassCodes {
    /// Not a vessel.
    pub background: u8,
    /// Arteriole.
    pub arteriole: u8,
    /// Venule.
    pub venule: u8,
    /// Vessel of neither kind.
    pub undetermined: u8,
}

/// How the frames were split into blocks for imaging.
#[derive(Debug, Clone, Serialize)]
pub struct BlocksRecord {
    /// Frames per block.
    pub frames: usize,
    /// Frames decoded on either side of a block.
    pub margin_frames: usize,
    /// The rule, in words.
    pub rule: String,
}

/// The segments of a recording too long to hold whole.
#[derive(Debug, Clone, Serialize)]
pub struct SegmentsRecord {
    /// Segments.
    pub count: usize,
    /// Each segment's own frames, [start, end).
    pub own_frames: Vec<[usize; 2]>,
    /// The frames each segment imaged, [start, end).
    pub imaged_frames: Vec<[usize; 2]>,
    /// Each segment's clutter cut-offs, per angle.
    pub clutter_cut_offs_per_angle: Vec<Vec<CutOffs>>,
    /// The rule, in words.
    pub rule: String,
}

/// The Doppler time series' ensembles.
#[derive(Debug, Clone, Serialize)]
pub struct EnsemblesRecord {
    /// Frames per ensemble.
    pub frames: usize,
    /// Frames between ensembles.
    pub step_frames: usize,
    /// Ensembles.
    pub count: usize,
    /// One ensemble's duration (s).
    pub duration_s: f64,
    /// Each ensemble's centre time (s).
    pub times_s: Vec<f64>,
    /// Each ensemble's first frame.
    pub start_frames: Vec<usize>,
    /// Each ensemble's clutter cut-offs, per angle.
    pub clutter_cut_offs_per_angle: Vec<Vec<CutOffs>>,
    /// The vector estimator.
    pub estimator: &'static str,
}

/// The rule `summary.json` states for the blocks.
/// Which pixels a recording's figures draw as flow (colour Doppler, vectors, ensembles); the
/// `.npy` maps are not masked.
#[derive(Debug, Clone, Serialize)]
pub struct FiguresRecord {
    /// The rule, in words ([`masks::FIGURE_FLOW_DEFINITION`]).
    pub flow_rule: &'static str,
    /// The colour Doppler's and ensembles' level (dB re the 99.9th-percentile power).
    pub colour_level_db: f64,
    /// The vector figure's level (dB re the 99.9th-percentile power).
    pub vector_level_db: f64,
    /// The margin above the noise floor of the pixel's depth (dB).
    pub above_floor_db: f64,
}

impl Default for FiguresRecord {
    fn default() -> FiguresRecord {
        FiguresRecord {
            flow_rule: masks::FIGURE_FLOW_DEFINITION,
            colour_level_db: masks::FLOW_FIGURE_DB,
            vector_level_db: masks::VECTOR_FIGURE_DB,
            above_floor_db: masks::FIGURE_ABOVE_FLOOR_DB,
        }
    }
}

pub(super) fn blocks_rule() -> String {
    format!(
        "images formed a block of frames at a time, decoded in the memory they are read into: at \
         most as many frames as fit in {} MiB with their margins and one angle's IQ (the whole \
         recording when it fits), the blocks of a segment sharing its frames evenly, with {} \
         frames decoded on either side of a block of a coded recording aligned at mid-frame",
        pipeline::BLOCK_BYTES >> 20,
        pipeline::blocks::Blocks::ALIGNMENT_MARGIN
    )
}

/// The rule `summary.json` states for the segments.
pub(super) fn segments_rule() -> String {
    format!(
        "too long to hold whole (--segment-frames, default: the frames whose image series fit in \
         {} MiB, at most {}): each segment imaged (or read, for images formed elsewhere) with \
         the frames its dynamics windows and ensembles reach into, clutter-filtered on its own; \
         power and lag-1 autocorrelation summed over the segments' own frames, velocities and \
         vectors from the sums; windows and ensembles from the segment their start is in",
        pipeline::segments::SERIES_BYTES >> 20,
        pipeline::segments::MAX_SEGMENT_FRAMES
    )
}

/// The rule `summary.json` states for dealiasing.
pub(super) fn dealias_rule() -> String {
    use pcuvd::estimate::dealias;
    format!(
        "alias patterns up to ±K Nyquist intervals (2 v_N) per angle, from trial vectors; scored \
         by the estimator's unweighted objective (LS: sum of squared residuals, IRLS: sum of \
         absolute residuals); within a level a mixed pattern kept only where its summed squared \
         residual is below {} times the level's common shift's (even where that shift's fit is \
         beyond the speed limit; a pixel left without a level-0 candidate keeps the plain fit \
         unless another level's fits it with under that ratio times the plain fit's squared \
         residual); the common shift of all angles settled over the flow pixels (power {} dB \
         above the row's noise floor and within {} dB of the brightest pixel within {} mm) by \
         unwrapping the levels as a phase map, most reliable joins first (Herraez et al. 2002), \
         pixels next to non-flow joined to speed 0 (blood is slow at a wall; pixels without \
         candidates enclosed by flow are holes, not wall; pixels whose angles' Nyquist \
         velocities differ by more than {}x take the level of the flow around them, or keep the \
         plain fit outside it), unless another common shift makes the vessel's power-weighted \
         summed residual less than {} times as large; regions under {} pixels and other pixels \
         keep the plain fit; auto: the smallest K of 1-{} at which under {} % of the unwrapped \
         pixels reach ±K; alias_counts.npy (PC-UVD) and alias_counts_ls.npy (UVD) hold the \
         counts (angles, nz, nx)",
        dealias::MIXED_PATTERN_RATIO,
        dealias::FLOW_MARGIN_DB,
        dynamics::VESSEL_LOCAL_DB,
        dynamics::VESSEL_LOCAL_RADIUS_M * 1e3,
        dealias::NYQUIST_SPREAD_LIMIT,
        dealias::DECISIVE_SCORE_RATIO,
        dealias::MIN_REGION_PIXELS,
        dealias::MAX_AUTO_INTERVALS,
        dealias::AUTO_LIMIT_FRACTION * 100.0
    )
}

impl DealiasRecord {
    /// The setting, the K used, the speeds it reaches, per estimator how many flow pixels were
    /// dealiased, unwrapped, and reached ±K, and the warning for a `coded` recording or one of too
    /// few angles ([`pipeline::dealias_warning`]).
    pub(super) fn of(params: &ProcessParams, out: &ProcessOutput, coded: bool) -> Self {
        let counts = |c: &pcuvd::estimate::dealias::AliasCounts| AliasRecord {
            dealiased_pixels: c.dealiased_pixels,
            unwrapped_pixels: c.unwrapped_pixels,
            at_limit_pixels: c.at_limit_pixels,
        };
        DealiasRecord {
            setting: params.dealias.label(),
            warning: pipeline::dealias_warning(params.dealias, coded, out),
            done: out.maps.dealias.as_ref().map(|done| DealiasDone {
                intervals: done.intervals,
                max_speed_m_s: (2 * done.intervals + 1) as f64 * out.maps.nyquist_velocity,
                flow_pixels: done.flow_pixels,
                pcuvd_irls: counts(&done.irls),
                uvd_ls: counts(&done.ls),
                rule: dealias_rule(),
            }),
        }
    }
}

impl DynamicsRecord {
    /// The dynamics stage's record.
    pub(super) fn of(plan: &Plan, processed: &Processed) -> Self {
        let (settings, series, maps) = match (&plan.dynamics, &processed.dynamics) {
            (Some(settings), DynamicsOutcome::Done { series, maps }) => (settings, series, maps),
            (_, DynamicsOutcome::Skipped(reason)) => {
                return DynamicsRecord::Skipped {
                    skipped: reason.clone(),
                };
            }
            (_, DynamicsOutcome::Failed(reason)) => {
                return DynamicsRecord::Failed {
                    failed: reason.clone(),
                };
            }
            (None, DynamicsOutcome::Done { .. }) => {
                return DynamicsRecord::Skipped {
                    skipped: "--dynamics off".into(),
                };
            }
        };
        let (dparams, vessel) = (settings.params, settings.vessel);
        let count = |code: u8| maps.vessel_class.iter().filter(|&&c| c == code).count();
        DynamicsRecord::Done(Box::new(DynamicsDone {
            heart_rate_hz: maps.heart_rate_hz,
            heart_rate_given: dparams.heart_rate_hz.is_some(),
            cycles_from: maps.cycle_source.describe().to_string(),
            triggers_from: settings.triggers.as_ref().map(|(_, from)| from.clone()),
            cycles_count: maps.cycles.len(),
            spread: "psv_spread.npy, edv_spread.npy, ri_spread.npy: standard deviation across \
                     the complete cycles of each cycle's PSV (m/s), EDV (m/s) and RI, each \
                     cycle's speed fitted on its own; NaN with one cycle",
            window_frames: dparams.window,
            step_frames: dparams.step,
            window_s: series.window_s,
            step_s: series.step_s,
            step_spaced_for_memory: match &plan.dynamics_fit {
                Some(crate::run::DynamicsFit::Stepped { reason, .. }) => Some(reason.clone()),
                _ => None,
            },
            harmonics: dparams
                .harmonics
                .unwrap_or_else(|| dynamics::auto_harmonics(maps.heart_rate_hz, series.window_s)),
            axial_only: series.axial_only,
            speed: if series.axial_only {
                axial_speed()
            } else {
                "|V| of the in-plane velocity vector".into()
            },
            estimator: if series.axial_only {
                "none: one steering angle gives one projection, not a vector"
            } else {
                "IRLS-WLS (PC-UVD)"
            },
            kernel: [dparams.kernel.0, dparams.kernel.1],
            partial_volume: dparams.partial_volume,
            artery_ri_min: dparams.artery_ri_min,
            vein_ri_max: dparams.vein_ri_max,
            vessel_threshold_db: dparams.min_power_db,
            vessel_margin_db: Level::of(vessel.margin_db),
            vessel_margin_reference: "noise floor of each depth row of the power Doppler: its \
                                      30th percentile (masks::noise_floor_by_depth)",
            vessel_local_db: Level::of(vessel.local_db),
            vessel_local_radius_mm: vessel.local_radius_m * 1e3,
            vessel_pooling: if series.axial_only {
                PoolingSummary::Off(
                    "off: it follows each pixel's flow direction in the image plane, which one \
                     steering angle does not give",
                )
            } else {
                PoolingSummary::new(dparams.pooling, processed.out.grid.step())
            },
            cycles_windows: maps.cycles.clone(),
            pixels: ClassCounts {
                arteriole: count(dynamics::ARTERIOLE),
                venule: count(dynamics::VENULE),
                undetermined: count(dynamics::UNDETERMINED),
            },
            class_codes: ClassCodes {
                background: dynamics::BACKGROUND,
                arteriole: dynamics::ARTERIOLE,
                venule: dynamics::VENULE,
                undetermined: dynamics::UNDETERMINED,
            },
        }))
    }
}
