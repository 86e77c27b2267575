//! The paper's in vivo experiment (§4, Fig. 6–8) on the virtual rat brain, where every pixel's
//! true velocity, vessel class and RI are known: the brain simulated conventional and coded (once:
//! the recordings are cached, keyed by the scenario), each recording processed as `pcuvd process`
//! processes it (clutter filter on, dynamics stage on the recording's heartbeats), and the maps
//! scored against the truth.
//!
//! Which pixels are scored. The truth of a pixel is its voxel's view of the tree: its cell of
//! the plane (halfway to the neighbouring pixels), spread along the elevation by the beam's
//! two-way echo power; its velocity is the weighted mean over the blood the voxel holds, and
//! `blood_fraction` is the share of the voxel's weight that is blood. Near the probe the beam is
//! as tall as the element (1.5 mm), so a 40 µm penetrating arteriole fills a few % of its voxel,
//! and only the deep trunks near the lens focus fill a quarter: a threshold on the share would
//! score no cortex at all. The scores count the **lumen pixels**: those whose voxel holds blood,
//! most of it in a vessel at least [`LUMEN_MIN_DIAMETER_M`] wide, that is every arteriole, venule
//! and trunk, but not the capillary bed, whose echo (under 1 % of the voxel) no Doppler estimator
//! can be asked to read. A voxel counts however little of a vessel it holds: the wall's thin
//! slices of the wide vessels are lumen pixels too.
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use ndarray::{Array2, Zip};
use pcuvd::dynamics::{ARTERIOLE, BACKGROUND, RiMaps, Spectrogram, SpectrogramParams, VENULE};
use pcuvd::estimate::masks::VesselTests;
use pcuvd::estimate::vector::VectorField;
use pcuvd::pipeline::ProcessOutput;
use pcuvd::simulate::phantom::network::NetworkTruth;
use serde::Serialize;
use sha2::{Digest, Sha256};

use crate::progress::Progress;
use crate::run::{DynamicsOutcome, Plan, Processed};
use crate::scenario::{Scenario, Vessels};
use crate::settings::{DynamicsSettings, ProcessingSettings};
use crate::simulation::{SimulatedTruth, Simulation};
use crate::summary::CellRecord;
use pcuvd::study::Mode;

mod score;
use score::{ScoreContext, lumen_of, score};

/// The scenario the study simulates unless told otherwise (a shipped scenario's name).
pub const DEFAULT_SCENARIO: &str = "rat-brain";

pub use crate::simulation::{LUMEN_MIN_DIAMETER_M, TRUTH_TIMES};

/// Vessel diameter classes of the scores (m): [lower, upper) and a label.
pub const DIAMETER_CLASSES: [(f64, f64, &str); 3] = [
    (LUMEN_MIN_DIAMETER_M, 50e-6, "20–50 µm"),
    (50e-6, 80e-6, "50–80 µm"),
    (80e-6, f64::INFINITY, "≥ 80 µm"),
];

/// What the vector scores count.
pub const VECTOR_SCORE_DEFINITION: &str = "over the lumen pixels (the pixel's voxel holds \
    blood, most of it in a vessel at least `lumen_min_diameter_m` wide) of the band (thirds of the depth range \
    the lumen pixels span), diameter class, or both (`vector_deep_by_diameter`: the deepest \
    third by diameter class): `detected` is the \
    fraction the method's vessel mask (noise-floor margin and local peak, as `pcuvd process`) \
    holds; over the detected ones, RMSE of vx, of vz and of the in-plane vector error (mm/s) \
    against the truth (the mean velocity of the blood in the pixel's voxel: its cell of the \
    plane, weighted along the elevation by the beam's two-way echo power; averaged over the \
    recording at `TRUTH_TIMES` evenly spaced times), and the median angle between the \
    estimated and the true in-plane velocity (degrees)";

/// Mean of 1 − (r/R)² over a pixel's blood below which the pixel counts as near its vessel's
/// wall in the vector scores: the blood lies beyond about 0.8 R, where the laminar profile is
/// steepest and a resolution cell averages the most gradient. (A voxel that holds a vessel's
/// whole cross-section averages 1/2.)
pub const WALL_PROFILE: f64 = 1.0 / 3.0;

/// What the wall groups of the vector scores count.
pub const WALL_DEFINITION: &str = "the vector scores (as `vector_definition`) of the lumen \
    pixels near their vessel's wall (the truth's `axis_profile`, the mean of 1 − (r/R)² over the \
    pixel's blood, below `WALL_PROFILE` = 1/3: the blood lies beyond about 0.8 of the radius) \
    and toward its axis (the rest), over every lumen pixel and over the vessels at least one \
    wavelength wide";

/// What the RI scores count.
pub const BRAIN_RI_DEFINITION: &str = "over the lumen pixels of vessels at least one wavelength \
    wide (the resolution cell's size): median |RI_estimated − RI_true| (a pixel without an RI \
    counts 1), and the fraction classed as the right kind (arteriole or venule) by the dynamics \
    stage; `all_lumen` counts every lumen pixel whatever its vessel's width; the groups marked \
    \"one class in the beam\" keep the pixels where at least 90 % of the blood in the elevation \
    beam is of the class the truth names (the truth's RI is its main vessel's, while an estimate \
    reads the blood-weighted mix of every vessel in the beam); `arterioles` and `venules` split \
    the lumen pixels by the truth's class; the depth bands (the vector scores' thirds) hold every \
    lumen pixel of the band, then those of vessels at least a wavelength wide; the groups marked \
    \"against the beam's own RI\" score against the RI of the speed of the in-plane velocity the \
    pixel's beam holds over the recording (the truth's (max − min)/max over its averaged times; \
    classes by the dynamics stage's thresholds): what an estimate of the beam's mean velocity \
    without error would read, where an artery and a vein share it";

/// Least share of a pixel's blood (elevation-weighted) of the truth's class for the RI groups
/// scored on one class in the beam: where an artery and a vein share the beam (the pial and basal
/// pairs run one above the other in elevation), the truth names the vessel with more blood but an
/// estimate reads their mix.
pub const SINGLE_CLASS_SHARE: f64 = 0.9;

/// What the vessel-to-background ratio counts.
pub const CONTRAST_DEFINITION: &str = "per depth band: 10·log10 of the mean power Doppler over \
    the band's lumen pixels over the median power Doppler of its pixels with no blood in the \
    beam; `gain_db` is the coded recording's ratio minus the conventional one's (the SNR gain of \
    coding, as the paper's profiles read it: vessel against its surroundings)";

/// What the false-detection scores count.
pub const FALSE_DETECTION_DEFINITION: &str = "per depth band (the vector scores' thirds of the \
    lumen's depth range, then all of it): over the pixels with no blood in the elevation beam \
    (`blood_free_pixels`), the fraction the method's vessel mask holds (`in_vessel_mask`, as the \
    vector scores' mask) and the fraction given an RI (`with_ri`, the RI maps' vessels; absent \
    when the dynamics stage did not run): flow shown where there is none";

/// Settings of the brain study.
#[derive(Debug, Clone, Serialize)]
pub struct BrainSettings {
    /// The scenario: a shipped scenario's name or a TOML file; its vessels must be a tree and it
    /// must simulate both transmit modes.
    pub scenario: String,
    /// Compound frames, overriding the scenario's (a shorter, quicker run).
    pub frames: Option<usize>,
    /// Folder of cached simulations, one sub-folder per scenario.
    pub cache: PathBuf,
    /// How each recording is processed (as `pcuvd process`).
    pub processing: ProcessingSettings,
    /// The dynamics stage's settings (as `pcuvd process`).
    pub dynamics: DynamicsSettings,
}

impl BrainSettings {
    /// The scenario simulated, with the frame override applied, checked.
    pub fn scenario(&self) -> Result<Scenario> {
        let mut scenario = Scenario::load(&self.scenario)?;
        if let Some(frames) = self.frames {
            scenario.sequence.frames = frames;
        }
        scenario.check()?;
        if !matches!(scenario.vessels, Vessels::Tree(_)) {
            bail!(
                "brain study: the scenario {} has no vascular tree ([vessels] kind = \"tree\")",
                self.scenario
            );
        }
        Ok(scenario)
    }

    /// The folder the simulation of `scenario` is cached in: named by a hash of the scenario and
    /// of pcuvd's version (a new simulator may simulate the same scenario otherwise).
    pub fn cache_folder(&self, scenario: &Scenario) -> Result<PathBuf> {
        let mut hash = Sha256::new();
        hash.update(env!("CARGO_PKG_VERSION"));
        hash.update(scenario.to_toml()?);
        let key: String = hash.finalize()[..8]
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        Ok(self.cache.join(format!("brain-{key}")))
    }
}

/// One transmit mode, processed.
pub struct BrainMode {
    /// Conventional (UVD, least squares) or coded (PC-UVD, IRLS).
    pub mode: Mode,
    /// The maps (the filtered series dropped once processed, to bound memory).
    pub out: ProcessOutput,
    /// The RI maps, when the dynamics stage ran.
    pub ri: Option<RiMaps>,
    /// Why the dynamics stage did not run, when it did not.
    pub ri_skipped: Option<String>,
    /// The method's vessel mask (noise-floor margin and local peak).
    pub detected: Array2<bool>,
    /// Compounded Doppler spectrograms at the study's [`BrainSite`]s, in their order; `None`
    /// where the pixel's filtered series is zero (no Doppler signal to show).
    pub spectrograms: Vec<Option<Spectrogram>>,
}

impl BrainMode {
    /// "UVD" or "PC-UVD".
    pub fn method(&self) -> &'static str {
        self.mode.method()
    }

    /// The method's vector field: least squares for UVD, IRLS for PC-UVD.
    pub fn field(&self) -> Result<&VectorField> {
        self.field_of(self.mode == Mode::Coded)
    }

    /// The recording's vector field by IRLS (`irls` true) or by least squares.
    pub fn field_of(&self, irls: bool) -> Result<&VectorField> {
        let maps = &self.out.maps;
        if irls {
            maps.vector_irls.as_ref()
        } else {
            maps.vector_ls.as_ref()
        }
        .context("the recording gives no vector velocity (one steering angle)")
    }
}

/// Vector scores over one group of lumen pixels; see [`VECTOR_SCORE_DEFINITION`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct VectorScore {
    /// Lumen pixels in the group.
    pub pixels: usize,
    /// Fraction of them in the method's vessel mask.
    pub detected: f64,
    /// RMSE of vx (mm/s).
    pub rmse_vx_mm_s: f64,
    /// RMSE of vz (mm/s).
    pub rmse_vz_mm_s: f64,
    /// RMSE of the in-plane vector (mm/s).
    pub rmse_mm_s: f64,
    /// Median angle between estimated and true in-plane velocity (degrees).
    pub median_direction_error_deg: f64,
}

/// Scores of one group (a depth band or a diameter class), both methods.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GroupScores {
    /// The band's depths (mm) or the class's label.
    pub group: String,
    /// Conventional, least squares.
    pub uvd: VectorScore,
    /// Coded, IRLS.
    pub pcuvd: VectorScore,
    /// PC-UVD's vector RMSE below UVD's (%).
    pub improvement_pct: f64,
}

/// Vector scores of one group with each recording read by each vector estimator, over the lumen
/// pixels both recordings' vessel masks hold: what coding and IRLS, the two halves of PC-UVD,
/// each do against UVD on the same pixels.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EstimatorScores {
    /// The group's label.
    pub group: String,
    /// Conventional, least squares (UVD).
    pub conventional_ls: VectorScore,
    /// Conventional, IRLS (IRLS without coding).
    pub conventional_irls: VectorScore,
    /// Coded, least squares (coding without IRLS).
    pub coded_ls: VectorScore,
    /// Coded, IRLS (PC-UVD).
    pub coded_irls: VectorScore,
}

/// RI scores of one method over a group of lumen pixels; see [`BRAIN_RI_DEFINITION`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RiGroupScore {
    /// Pixels scored.
    pub pixels: usize,
    /// Median |RI_estimated − RI_true|; NaN (null in metrics.json) when the group is empty.
    pub median_abs_error: f64,
    /// Fraction classed right; NaN (null in metrics.json) when the group is empty.
    pub class_accuracy: f64,
}

/// RI scores of both methods over one group.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RiGroupScores {
    /// The group.
    pub group: String,
    /// UVD's, `None` when its dynamics stage did not run.
    pub uvd: Option<RiGroupScore>,
    /// PC-UVD's.
    pub pcuvd: Option<RiGroupScore>,
}

/// One method's false detections in a group of blood-free pixels; see
/// [`FALSE_DETECTION_DEFINITION`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FalseDetectionScore {
    /// Fraction of the blood-free pixels in the vessel mask.
    pub in_vessel_mask: f64,
    /// Fraction of them given an RI; `None` when the dynamics stage did not run.
    pub with_ri: Option<f64>,
}

/// False detections of both methods in one depth band; see [`FALSE_DETECTION_DEFINITION`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FalseDetections {
    /// The band's depths (mm), or "all".
    pub group: String,
    /// Pixels of the band with no blood in the elevation beam.
    pub blood_free_pixels: usize,
    /// Conventional.
    pub uvd: FalseDetectionScore,
    /// Coded.
    pub pcuvd: FalseDetectionScore,
}

/// Vessel-to-background ratio of one depth band; see [`CONTRAST_DEFINITION`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BandContrast {
    /// The band's depths (mm).
    pub depth_mm: [f64; 2],
    /// Lumen pixels in the band.
    pub lumen_pixels: usize,
    /// Conventional (dB).
    pub conventional_db: f64,
    /// Coded (dB).
    pub coded_db: f64,
    /// Coded minus conventional (dB).
    pub gain_db: f64,
}

/// The brain study's numbers, as `metrics.json` holds them (key `brain`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BrainMetrics {
    /// Where the scenario came from.
    pub scenario: String,
    /// Compound frames per recording.
    pub frames: usize,
    /// The noise level of the scenario (dB re the blood's echo), fixed before any score.
    pub noise_db: Option<f64>,
    /// Narrowest vessel whose pixels are scored (m).
    pub lumen_min_diameter_m: f64,
    /// Lumen pixels scored.
    pub lumen_pixels: usize,
    /// Clutter cut-offs (low, high) per angle: conventional, coded.
    pub clutter_cut_offs: [Vec<(usize, usize)>; 2],
    /// Vector scores by depth band (thirds of the depth range the lumen pixels span).
    pub vector_by_depth: Vec<GroupScores>,
    /// Vector scores by vessel diameter class.
    pub vector_by_diameter: Vec<GroupScores>,
    /// Vector scores over every lumen pixel.
    pub vector_all: GroupScores,
    /// What the vector scores count.
    pub vector_definition: &'static str,
    /// Vector scores of the deepest third by vessel diameter class (the deep small vessels).
    pub vector_deep_by_diameter: Vec<GroupScores>,
    /// Vector scores of every lumen pixel and of the deepest third, each recording read by both
    /// vector estimators (coding and IRLS apart).
    pub vector_by_estimator: Vec<EstimatorScores>,
    /// Vector scores near the vessels' walls and toward their axes ([`WALL_DEFINITION`]).
    pub vector_by_wall: Vec<GroupScores>,
    /// What the wall groups count.
    pub wall_definition: &'static str,
    /// RI scores: vessels at least a wavelength wide, every lumen pixel, by diameter class, by
    /// class, and by depth third.
    pub ri: Vec<RiGroupScores>,
    /// Why a method has no RI scores, when it has none.
    pub ri_skipped: Vec<String>,
    /// What the RI scores count.
    pub ri_definition: &'static str,
    /// Vessel-to-background ratio by depth band (1 mm bands), both modes.
    pub contrast_by_depth: Vec<BandContrast>,
    /// What the ratio counts.
    pub contrast_definition: &'static str,
    /// False detections by depth band (the vector scores' thirds, then the whole range).
    pub false_detections: Vec<FalseDetections>,
    /// What they count.
    pub false_detection_definition: &'static str,
    /// Each angle's resolution cell as its speckle measured it (the partial-volume correction's;
    /// `None` where not measured, as with the correction off): conventional, coded. What the
    /// truth is blurred by before an estimate can read it (`scripts/brain-vectors`).
    pub resolution_cells: [Vec<Option<CellRecord>>; 2],
    /// The processing settings both recordings were processed with (f-number, Doppler kernel,
    /// partial-volume correction, clutter cut-offs...), as `pcuvd process` takes them.
    pub processing: ProcessingSettings,
    /// Wall-clock seconds: simulation (0 when cached), processing of each mode, scoring.
    pub timing_s: Vec<(String, f64)>,
}

/// Everything the brain study produced.
pub struct BrainStudy {
    /// Its settings.
    pub settings: BrainSettings,
    /// The scenario simulated.
    pub scenario: Scenario,
    /// Where the simulation is (cached).
    pub folder: PathBuf,
    /// The truth on the processing grid, its velocity averaged over the recording (see
    /// [`TRUTH_TIMES`]); the mask, the cycle's truth and the elevation's at the start.
    pub truth: SimulatedTruth,
    /// Diameter (m) of the vessel each pixel sees most of; NaN without blood.
    pub diameter_m: Array2<f64>,
    /// The scored pixels.
    pub lumen: Array2<bool>,
    /// The pixels of the spectrograms (Fig. 8b), with their vessels' truth.
    pub sites: Vec<BrainSite>,
    /// Conventional (UVD), then coded (PC-UVD).
    pub modes: [BrainMode; 2],
    /// The numbers.
    pub metrics: BrainMetrics,
}

/// The folder, under the study's output folder, of the maps the scores are computed from.
pub const BRAIN_MAPS_DIR: &str = "brain_maps";

impl BrainStudy {
    /// Writes the maps the scores are computed from into `dir`, as `.npy` on the processing grid
    /// (nz, nx), so that other methods can be scored on the same pixels: `x.npy`, `z.npy` (m);
    /// the truth (`truth_vx`, `truth_vz` (m/s, averaged over the recording), `truth_ri`,
    /// `truth_psv`, `truth_edv` (m/s), `truth_vessel_class`, `truth_class_share`,
    /// `truth_axis_profile` (the wall scores' nearness to the axis, 1 on it, 0 at the wall),
    /// `truth_blood_fraction` (the share of the pixel's elevation beam, by its echo weight, that
    /// blood fills), `truth_beam_ri` (see [`SimulatedTruth::beam_ri`]), `blood`,
    /// `diameter_m`, `lumen`); and per method (`uvd_…`, `pcuvd_…`) `vx`, `vz` (m/s),
    /// `power_doppler`, `detected` and, when the dynamics stage ran, `ri`, `psv`, `edv` (m/s),
    /// `vessel_class`.
    pub fn write_maps(&self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let npy = |name: &str, values: &Array2<f64>| {
            pcuvd_io::write_npy(&dir.join(format!("{name}.npy")), values)
        };
        let flags = |name: &str, values: &Array2<bool>| {
            pcuvd_io::write_npy(&dir.join(format!("{name}.npy")), &values.mapv(u8::from))
        };
        pcuvd_io::write_npy(
            &dir.join("x.npy"),
            &ndarray::Array1::from(self.truth.x.clone()),
        )?;
        pcuvd_io::write_npy(
            &dir.join("z.npy"),
            &ndarray::Array1::from(self.truth.z.clone()),
        )?;
        npy("truth_vx", &self.truth.truth.vx)?;
        npy("truth_vz", &self.truth.truth.vz)?;
        flags("blood", &self.truth.truth.mask)?;
        npy("diameter_m", &self.diameter_m)?;
        flags("lumen", &self.lumen)?;
        if let Some(cycle) = &self.truth.cycle {
            npy("truth_ri", &cycle.ri)?;
            npy("truth_psv", &cycle.psv)?;
            npy("truth_edv", &cycle.edv)?;
            npy("truth_class_share", &cycle.class_share)?;
            npy("truth_axis_profile", &cycle.axis_profile)?;
            pcuvd_io::write_npy(&dir.join("truth_vessel_class.npy"), &cycle.vessel_class)?;
        }
        if let Some((_, blood_fraction)) = &self.truth.elevation {
            npy("truth_blood_fraction", blood_fraction)?;
        }
        if let Some(beam_ri) = &self.truth.beam_ri {
            npy("truth_beam_ri", beam_ri)?;
        }
        for mode in &self.modes {
            let prefix = match mode.mode {
                Mode::Conventional => "uvd",
                Mode::Coded => "pcuvd",
            };
            let field = mode.field()?;
            npy(&format!("{prefix}_vx"), &field.vx)?;
            npy(&format!("{prefix}_vz"), &field.vz)?;
            npy(
                &format!("{prefix}_power_doppler"),
                &mode.out.maps.power_doppler,
            )?;
            flags(&format!("{prefix}_detected"), &mode.detected)?;
            if let Some(ri) = &mode.ri {
                npy(&format!("{prefix}_ri"), &ri.ri)?;
                npy(&format!("{prefix}_psv"), &ri.psv)?;
                npy(&format!("{prefix}_edv"), &ri.edv)?;
                pcuvd_io::write_npy(
                    &dir.join(format!("{prefix}_vessel_class.npy")),
                    &ri.vessel_class,
                )?;
            }
        }
        Ok(())
    }
}

/// A pixel where the brain's spectrograms are computed (Fig. 8b), with its vessel's truth.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BrainSite {
    /// The vessel's kind, direction, width and depth, for figures.
    pub label: String,
    /// (row, col) of the pixel.
    pub pixel: (usize, usize),
    /// The pixel's true peak systolic speed (m/s).
    pub true_psv_m_s: f64,
    /// Its true end-diastolic speed (m/s).
    pub true_edv_m_s: f64,
    /// Its true resistivity index.
    pub true_ri: f64,
    /// True when its flow goes toward the probe.
    pub flows_up: bool,
}

/// One lumen pixel for each kind (arteriole, venule) and direction (up, down) the brain holds:
/// in the widest such vessel whose mean in-plane flow `velocity` ((vx, vz), m/s) runs within 45°
/// of the beam, the pixel of highest peak speed (its axis). A spectrogram is the axial Doppler
/// spectrum, so it shows the speed only where the flow runs along the beam (a lateral trunk's
/// reads about 0 whatever its speed); where a kind and direction has no such pixel, its widest
/// vessel at any angle. Kinds and directions the lumen lacks are left out.
pub fn spectrogram_sites(
    cycle: &NetworkTruth,
    lumen: &Array2<bool>,
    diameter_m: &Array2<f64>,
    velocity: (&Array2<f64>, &Array2<f64>),
    z: &[f64],
) -> Vec<BrainSite> {
    let (vx, vz) = velocity;
    let along_the_beam = |p: (usize, usize)| vz[p].abs() >= vx[p].abs();
    let mut sites = Vec::new();
    for (class, kind) in [(ARTERIOLE, "arteriole"), (VENULE, "venule")] {
        for up in [false, true] {
            let best = lumen
                .indexed_iter()
                .filter(|&(p, &l)| l && cycle.vessel_class[p] == class && cycle.flow_up[p] == up)
                .map(|(p, _)| p)
                .max_by(|&a, &b| {
                    along_the_beam(a)
                        .cmp(&along_the_beam(b))
                        .then(diameter_m[a].total_cmp(&diameter_m[b]))
                        .then(cycle.psv[a].total_cmp(&cycle.psv[b]))
                });
            if let Some(pixel) = best {
                sites.push(BrainSite {
                    label: format!(
                        "{kind} flowing {}, {:.0} µm, {:.1} mm deep",
                        if up { "up" } else { "down" },
                        diameter_m[pixel] * 1e6,
                        z[pixel.0] * 1e3
                    ),
                    pixel,
                    true_psv_m_s: cycle.psv[pixel],
                    true_edv_m_s: cycle.edv[pixel],
                    true_ri: cycle.ri[pixel],
                    flows_up: up,
                });
            }
        }
    }
    sites
}

/// The simulation of `scenario`, from the cache or simulated into it now. Returns its folder.
pub fn cached_simulation(
    settings: &BrainSettings,
    scenario: &Scenario,
    simulation: &Simulation,
    progress: &dyn Progress,
) -> Result<(PathBuf, bool)> {
    let folder = settings.cache_folder(scenario)?;
    let written = folder.join(crate::simulation::folder::SCENARIO_FILE);
    // The scenario file is written last: its presence says the simulation finished.
    if written.is_file() {
        let cached = Scenario::read(&written)?;
        if cached.to_toml()? == scenario.to_toml()? {
            progress.report(&format!(
                "brain: simulation cached in {} (delete it to simulate again)",
                folder.display()
            ));
            return Ok((folder, true));
        }
    }
    progress.report(&format!(
        "brain: simulating {} ({} frames, both modes) into {}, once: later runs reuse it",
        settings.scenario,
        scenario.sequence.frames,
        folder.display()
    ));
    let task = "simulate the brain";
    crate::simulation::folder::write(
        simulation,
        &folder,
        &|done, total| progress.update(task, done, total),
        &|line| progress.report(line),
    )?;
    Ok((folder, false))
}

/// A run's notes held back until it ends: the study says why a method has no RI maps in its
/// summary line, figures and report, so the run's own note of it (written for `pcuvd process`,
/// naming options the study does not take) is dropped; every other note is passed on, naming
/// the recording.
struct HeldNotes<'a> {
    progress: &'a dyn Progress,
    notes: std::sync::Mutex<Vec<String>>,
}

impl<'a> HeldNotes<'a> {
    fn new(progress: &'a dyn Progress) -> Self {
        HeldNotes {
            progress,
            notes: std::sync::Mutex::new(Vec::new()),
        }
    }

    /// Passes on the notes of the `recording`'s run, but that of its RI maps `skipped` (the
    /// dynamics stage's reason), if any.
    fn pass_on(self, recording: &str, skipped: Option<&str>) {
        let notes = self.notes.into_inner().unwrap_or_else(|e| e.into_inner());
        for note in notes {
            if skipped.is_some_and(|reason| note.contains(reason)) {
                continue;
            }
            self.progress
                .note(&format!("brain, {recording} recording: {note}"));
        }
    }
}

impl Progress for HeldNotes<'_> {
    fn update(&self, task: &str, done: usize, total: usize) {
        self.progress.update(task, done, total);
    }

    fn note(&self, text: &str) {
        self.notes
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(text.to_string());
    }

    fn report(&self, text: &str) {
        self.progress.report(text);
    }
}

/// Runs the brain study: simulation (or the cache), processing, scores.
pub fn run(settings: &BrainSettings, progress: &dyn Progress) -> Result<BrainStudy> {
    let scenario = settings.scenario()?;
    let started = std::time::Instant::now();
    let simulation = Simulation::of(scenario.clone(), settings.scenario.clone())?;
    if simulation.modes.len() != 2 {
        bail!(
            "brain study: the scenario must simulate both transmit modes ([sequence] transmit = \"both\")"
        );
    }
    let (folder, cached) = cached_simulation(settings, &scenario, &simulation, progress)?;
    let mut timing = vec![(
        "simulation_s".to_string(),
        if cached {
            0.0
        } else {
            started.elapsed().as_secs_f64()
        },
    )];
    let mut modes = Vec::new();
    let mut truth = None;
    let mut sites = Vec::new();
    let mut scored = None;
    for mode in Mode::BOTH {
        let (name, method) = (mode.label(), mode.method());
        let clock = std::time::Instant::now();
        let path = folder.join(format!("{name}.toml"));
        let opened = crate::input::open_input(&path, &pcuvd_io::Overrides::default())?;
        let source = opened.source.as_ref();
        let mut plan = Plan::new(
            &settings.processing,
            &settings.dynamics,
            source,
            opened.info.cardiac_triggers_s.as_deref(),
        )?;
        if truth.is_none() {
            let acq = source.acquisition();
            let n_samples = source.trace_shape().1;
            let duration = source.n_frames() as f64 / acq.frame_rate();
            let times = crate::simulation::truth_times(duration);
            let averaged = simulation.truth_averaged(acq, n_samples, &times)?;
            if averaged.truth.mask.dim() != plan.params.grid.shape() {
                bail!("brain study: the processing grid differs from the truth's (give no --grid)");
            }
            let (diameter, lumen) = lumen_of(&simulation, &averaged)?;
            let cycle = averaged.cycle.as_ref().context("the tree's cycle truth")?;
            let velocity = (&averaged.truth.vx, &averaged.truth.vz);
            sites = spectrogram_sites(cycle, &lumen, &diameter, velocity, &averaged.z);
            truth = Some(averaged);
            scored = Some((diameter, lumen));
        }
        plan.kept_pixels = sites.iter().map(|s| s.pixel).collect();
        let held = HeldNotes::new(progress);
        let Processed {
            out,
            dynamics,
            kept,
            ..
        } = crate::run::run(source, &plan, &held)
            .with_context(|| format!("brain study: processing {}", path.display()))?;
        let skipped = match &dynamics {
            DynamicsOutcome::Skipped(reason) | DynamicsOutcome::Failed(reason) => {
                Some(reason.as_str())
            }
            DynamicsOutcome::Done { .. } => None,
        };
        held.pass_on(name, skipped);
        // The run hands its maps over whole (shared only with a later re-run of its dynamics).
        let mut out = Arc::into_inner(out).context("the run's maps are shared")?;
        // The filtered series (the largest thing a mode holds) has given all it will.
        out.filtered.series = Vec::new();
        // A recording shorter than one spectrogram window has no spectrogram to show.
        let long_enough = source.n_frames() >= SpectrogramParams::rat().window;
        let spectrograms = match &kept {
            // Each at the frequency the maps read velocity with at its pixel.
            Some(kept) if long_enough => (0..sites.len())
                .map(|k| {
                    let params = SpectrogramParams::rat();
                    let demodulation = out.filtered.demodulation_frequency;
                    let frequency = out
                        .mean_frequency_at(sites[k].pixel)
                        .unwrap_or(demodulation);
                    pcuvd::dynamics::spectrogram_of_kept(kept, k, &out.filtered, &params)
                        .map(|spec| spec.map(|spec| spec.at_frequency(demodulation, frequency)))
                })
                .collect::<pcuvd::Result<Vec<_>>>()
                .context("brain study: spectrograms")?,
            _ => Vec::new(),
        };
        let (ri, ri_skipped) = match dynamics {
            DynamicsOutcome::Done { maps, .. } => (Some(*maps), None),
            DynamicsOutcome::Skipped(reason) | DynamicsOutcome::Failed(reason) => {
                (None, Some(format!("{method}: {reason}")))
            }
        };
        let detected = VesselTests::default().flow_mask(&out.maps.power_doppler, out.grid.step());
        timing.push((
            format!("{name}_processing_s"),
            clock.elapsed().as_secs_f64(),
        ));
        modes.push(BrainMode {
            mode,
            out,
            ri,
            ri_skipped,
            detected,
            spectrograms,
        });
    }
    let truth = truth.expect("two modes processed");
    // The truth's grid was checked against the processing grid before the first run.
    let (diameter_m, lumen) = scored.expect("two modes processed");
    let modes: [BrainMode; 2] = modes.try_into().map_err(|_| anyhow::anyhow!("two modes"))?;
    let clock = std::time::Instant::now();
    let params = &simulation.modes[0].1;
    let wavelength = params.probe.wavelength(params.sound_speed);
    let metrics = score(
        &modes,
        &truth,
        &diameter_m,
        &lumen,
        wavelength,
        ScoreContext {
            scenario: &settings.scenario,
            frames: scenario.sequence.frames,
            noise_db: simulation.noise_db,
            processing: &settings.processing,
            class_thresholds: (
                settings.dynamics.artery_ri_min,
                settings.dynamics.vein_ri_max,
            ),
        },
        timing,
        clock,
    )?;
    Ok(BrainStudy {
        settings: settings.clone(),
        scenario,
        folder,
        truth,
        diameter_m,
        lumen,
        sites,
        modes,
        metrics,
    })
}

/// The study's folder of cached simulations: `out`'s `cache`, or `pcuvd-cache` in the working
/// folder when there is no output folder (a study run from Python).
pub fn default_cache(out: Option<&Path>) -> PathBuf {
    match out {
        Some(out) => out.join("cache"),
        None => PathBuf::from("pcuvd-cache"),
    }
}

#[cfg(test)]
mod tests {
    use super::score::*;
    use super::*;
    use pcuvd::dynamics::{ARTERIOLE, VENULE};
    use pcuvd::simulate::phantom::Truth;
    use pcuvd::simulate::phantom::network::NetworkTruth;

    /// Notes kept by a progress that records them.
    #[derive(Default)]
    struct Recorded(std::sync::Mutex<Vec<String>>);

    impl Progress for Recorded {
        fn update(&self, _task: &str, _done: usize, _total: usize) {}
        fn note(&self, text: &str) {
            self.0.lock().unwrap().push(text.to_string());
        }
        fn report(&self, _text: &str) {}
    }

    #[test]
    fn a_run_note_of_skipped_ri_maps_is_dropped_and_every_other_passed_on() {
        let reason = "invalid recording: 10.0 ms of waveform is too short";
        let recorded = Recorded::default();
        let held = HeldNotes::new(&recorded);
        held.note("the grid was clipped to the recorded depth");
        held.note(&crate::run::no_ri_maps_note(reason));
        assert!(
            recorded.0.lock().unwrap().is_empty(),
            "held until the run ends"
        );
        held.pass_on("coded", Some(reason));
        assert_eq!(
            *recorded.0.lock().unwrap(),
            ["brain, coded recording: the grid was clipped to the recorded depth"]
        );
        // Without a skipped stage nothing is dropped.
        let recorded = Recorded::default();
        let held = HeldNotes::new(&recorded);
        held.note("no RI maps: something else");
        held.pass_on("conventional", None);
        assert_eq!(recorded.0.lock().unwrap().len(), 1);
    }

    fn truth_with(vx: f64, vz: f64, (nz, nx): (usize, usize)) -> SimulatedTruth {
        let mut truth = Truth::empty(nz, nx);
        truth.vx.fill(vx);
        truth.vz.fill(vz);
        truth.mask.fill(true);
        SimulatedTruth {
            x: (0..nx).map(|i| i as f64 * 1e-4).collect(),
            z: (0..nz).map(|i| i as f64 * 1e-4).collect(),
            truth,
            start_velocity: None,
            cycle: None,
            tissue: None,
            elevation: None,
            beam_ri: None,
        }
    }

    /// A field off the truth by a known vector: the RMSEs are its components and its length, the
    /// direction error the angle between the two vectors; undetected pixels count only in
    /// `detected`, pixels outside the lumen or the selection not at all.
    #[test]
    fn vector_scores_are_the_known_error() {
        let shape = (4, 5);
        let truth = truth_with(0.010, 0.0, shape);
        let field = VectorField {
            vx: Array2::from_elem(shape, 0.013),
            vz: Array2::from_elem(shape, 0.004),
        };
        let mut lumen = Array2::from_elem(shape, true);
        lumen[[0, 0]] = false;
        let mut detected = Array2::from_elem(shape, true);
        detected[[3, 4]] = false;
        detected[[3, 3]] = false;
        let score = vector_score(&field, &detected, &truth, &lumen, |iz, _| iz >= 1);
        assert_eq!(score.pixels, 15);
        assert!((score.detected - 13.0 / 15.0).abs() < 1e-12);
        assert!((score.rmse_vx_mm_s - 3.0).abs() < 1e-9);
        assert!((score.rmse_vz_mm_s - 4.0).abs() < 1e-9);
        assert!((score.rmse_mm_s - 5.0).abs() < 1e-9);
        let expected = 0.004f64.atan2(0.013).to_degrees();
        assert!((score.median_direction_error_deg - expected).abs() < 1e-9);
        // A reversed flow is 180° off, whichever way round.
        let reversed = VectorField {
            vx: Array2::from_elem(shape, -0.010),
            vz: Array2::from_elem(shape, 1e-12),
        };
        let score = vector_score(&reversed, &detected, &truth, &lumen, |_, _| true);
        assert!((score.median_direction_error_deg - 180.0).abs() < 1e-6);
    }

    /// Blood-free pixels of the band only: a detection on blood, or outside the band, is not
    /// false; an RI map counts its finite pixels.
    #[test]
    fn false_detections_count_flow_where_there_is_no_blood() {
        let shape = (4, 5);
        let mut blood = Array2::from_elem(shape, false);
        blood[[1, 1]] = true;
        blood[[1, 2]] = true;
        let mut detected = Array2::from_elem(shape, false);
        detected[[1, 1]] = true; // on blood: not false
        detected[[2, 0]] = true; // false
        detected[[2, 4]] = true; // false
        detected[[3, 3]] = true; // outside the band
        let mut ri = Array2::from_elem(shape, f64::NAN);
        ri[[1, 0]] = 0.6;
        let (free, score) = false_detection_score(&detected, Some(&ri), &blood, &|iz| iz <= 2);
        assert_eq!(free, 13);
        assert!((score.in_vessel_mask - 2.0 / 13.0).abs() < 1e-12);
        assert!((score.with_ri.unwrap() - 1.0 / 13.0).abs() < 1e-12);
        let (_, without) = false_detection_score(&detected, None, &blood, &|_| true);
        assert!(without.with_ri.is_none());
        assert!((without.in_vessel_mask - 3.0 / 18.0).abs() < 1e-12);
    }

    /// A spectrogram site is on the widest vessel whose flow runs within 45° of the beam, not on
    /// a wider lateral trunk whose axial spectrum would read about 0; a kind with only lateral
    /// vessels still gets its widest one.
    #[test]
    fn spectrogram_sites_prefer_flow_along_the_beam() {
        let shape = (1, 4);
        let cycle = NetworkTruth {
            psv: Array2::from_shape_vec(shape, vec![0.006, 0.004, 0.03, 0.02]).unwrap(),
            edv: Array2::from_elem(shape, 0.002),
            ri: Array2::from_elem(shape, 0.5),
            vessel_class: Array2::from_shape_vec(shape, vec![VENULE, VENULE, ARTERIOLE, ARTERIOLE])
                .unwrap(),
            flow_up: Array2::from_elem(shape, false),
            vessel_index: Array2::from_shape_vec(shape, vec![0, 1, 2, 3]).unwrap(),
            class_share: Array2::from_elem(shape, 1.0),
            axis_profile: Array2::from_elem(shape, 1.0),
        };
        // The venules: a 140 µm lateral trunk and a 60 µm descending venule; the arterioles
        // both lateral, 100 and 50 µm.
        let diameter = Array2::from_shape_vec(shape, vec![140e-6, 60e-6, 100e-6, 50e-6]).unwrap();
        let vx = Array2::from_shape_vec(shape, vec![0.004, 0.001, 0.01, 0.01]).unwrap();
        let vz = Array2::from_shape_vec(shape, vec![0.0003, 0.003, 0.001, 0.002]).unwrap();
        let lumen = Array2::from_elem(shape, true);
        let sites = spectrogram_sites(&cycle, &lumen, &diameter, (&vx, &vz), &[1e-3]);
        let pixels: Vec<_> = sites.iter().map(|s| s.pixel).collect();
        assert_eq!(pixels, [(0, 2), (0, 1)], "{sites:?}");
        assert!(
            sites[1].label.starts_with("venule flowing down, 60 µm"),
            "{sites:?}"
        );
    }

    /// RI scores count the lumen pixels of the selection: a pixel without an RI counts an error
    /// of 1, and the class is right or wrong per pixel.
    #[test]
    fn ri_scores_count_misses_as_full_errors() {
        let shape = (1, 4);
        let cycle = NetworkTruth {
            psv: Array2::from_elem(shape, 0.02),
            edv: Array2::from_elem(shape, 0.006),
            ri: Array2::from_shape_vec(shape, vec![0.7, 0.7, 0.3, 0.3]).unwrap(),
            vessel_class: Array2::from_shape_vec(shape, vec![ARTERIOLE, ARTERIOLE, VENULE, VENULE])
                .unwrap(),
            flow_up: Array2::from_elem(shape, true),
            vessel_index: Array2::from_elem(shape, 0),
            class_share: Array2::from_elem(shape, 1.0),
            axis_profile: Array2::from_elem(shape, 1.0),
        };
        let est = RiMaps {
            ri: Array2::from_shape_vec(shape, vec![0.72, f64::NAN, 0.2, 0.6]).unwrap(),
            vessel_class: Array2::from_shape_vec(
                shape,
                vec![ARTERIOLE, BACKGROUND, VENULE, ARTERIOLE],
            )
            .unwrap(),
            psv: Array2::from_elem(shape, 0.02),
            edv: Array2::from_elem(shape, 0.01),
            flow_up: Array2::from_elem(shape, true),
            heart_rate_hz: 5.5,
            cycles: vec![],
            cycle_source: pcuvd::dynamics::CycleSource::GivenRate,
            psv_spread: Array2::from_elem(shape, f64::NAN),
            edv_spread: Array2::from_elem(shape, f64::NAN),
            ri_spread: Array2::from_elem(shape, f64::NAN),
        };
        let lumen = Array2::from_elem(shape, true);
        let score = ri_score(&est, (&cycle.ri, &cycle.vessel_class), &lumen, &|_, _| true);
        assert_eq!(score.pixels, 4);
        // Errors 0.02, 1 (no RI), 0.1, 0.3: the median is 0.2.
        assert!((score.median_abs_error - 0.2).abs() < 1e-12);
        assert!((score.class_accuracy - 0.5).abs() < 1e-12);
        let venules = ri_score(&est, (&cycle.ri, &cycle.vessel_class), &lumen, &|_, ix| {
            ix >= 2
        });
        assert_eq!(venules.pixels, 2);
        assert!((venules.median_abs_error - 0.2).abs() < 1e-12);
        // A group without pixels has no score, not a perfect or a null one.
        let none = ri_score(&est, (&cycle.ri, &cycle.vessel_class), &lumen, &|_, _| {
            false
        });
        assert_eq!(none.pixels, 0);
        assert!(none.median_abs_error.is_nan() && none.class_accuracy.is_nan());
    }
}
