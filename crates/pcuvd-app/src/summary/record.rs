//! What `summary.json` holds, as types: every parameter a run used, what each stage did, and where
//! its input came from. Serialised in field order; NaN and infinities are written as `null`.

use std::collections::BTreeMap;

use pcuvd::acquisition::source::FrameSource;
use pcuvd::dynamics::{self, PoolingSummary};
use pcuvd::pipeline::{self, ProcessOutput, ProcessParams};
use serde::{Deserialize, Serialize};

use crate::outputs::Checksum;
use crate::run::{DynamicsOutcome, Plan, Processed};

/// The whole of a `process` run's `summary.json`.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// The units every number is in, and the sign of axial velocities.
    pub units: &'static str,
    /// Where the input came from and the options it was processed with.
    pub source: Provenance,
    /// The probe.
    pub probe: ProbeRecord,
    /// Sampling, angles, coding and frames.
    pub acquisition: AcquisitionRecord,
    /// The image grid (m).
    pub grid: GridRecord,
    /// Delay-and-sum settings.
    pub beamforming: BeamformingRecord,
    /// The SVD clutter filter's settings and the cut-offs it chose.
    pub clutter_filter: ClutterRecord,
    /// Doppler estimation settings.
    pub doppler: DopplerRecord,
    /// The IRLS vector fit's settings.
    pub irls: IrlsRecord,
    /// The projections' Nyquist velocity (m/s).
    pub nyquist_velocity_m_s: f64,
    /// What dealiasing did.
    pub dealias: DealiasRecord,
    /// The dynamics stage (RI maps), or why it was skipped.
    pub dynamics: DynamicsRecord,
    /// How the frames were split into blocks for imaging.
    pub blocks: BlocksRecord,
    /// The segments of a recording too long to hold whole, or why there were none.
    pub segments: Described<SegmentsRecord>,
    /// The Doppler time series' ensembles, or why there were none.
    pub ensembles: Described<EnsemblesRecord>,
    /// The NIfTI images written beside the `.npy` maps (absent when none were asked for).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub nifti: Option<Vec<String>>,
    /// Wall-clock seconds by stage.
    pub timings_s: BTreeMap<String, f64>,
}

/// A section that is either a record or a sentence saying why there is none.
#[derive(Debug, Clone, Serialize)]
#[serde(untagged)]
pub enum Described<T> {
    /// There is one.
    Done(T),
    /// Why there is none.
    None(&'static str),
}

/// One input file: its path, size and checksum.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileRecord {
    /// The path as given.
    pub path: String,
    /// Its size (bytes).
    pub size_bytes: u64,
    /// Its BLAKE3 checksum (hex), when that was the kind asked for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub blake3: Option<String>,
    /// Its SHA-256 checksum (hex), when that was the kind asked for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sha256: Option<String>,
}

impl FileRecord {
    /// The record of a file of `size_bytes` whose `checksum` is `hex`.
    pub fn new(path: String, size_bytes: u64, checksum: Checksum, hex: String) -> Self {
        let (blake3, sha256) = match checksum {
            Checksum::Blake3 => (Some(hex), None),
            Checksum::Sha256 => (None, Some(hex)),
        };
        FileRecord {
            path,
            size_bytes,
            blake3,
            sha256,
        }
    }

    /// Whether it records a checksum (summaries of old versions may not).
    fn has_checksum(&self) -> bool {
        self.blake3.is_some() || self.sha256.is_some()
    }
}

/// Where the results came from: pcuvd's version, the command line, every input file with its size
/// and checksum, the format and the reader that read it, every acquisition parameter with its
/// source, the reader's warnings, and the options.
#[derive(Debug, Clone, Serialize)]
pub struct Provenance {
    /// The input as the user named it.
    pub input: String,
    /// The format, as the reader names it.
    pub format: String,
    /// The reader and how it read.
    pub reader: String,
    /// Every file read.
    pub files: Vec<FileRecord>,
    /// How the samples are stored in the file.
    pub stored_samples: Option<pcuvd_io::StoredSamples>,
    /// Every acquisition parameter with where it came from.
    pub parameters: Vec<pcuvd_io::Parameter>,
    /// The reader's warnings.
    pub reader_warnings: Vec<String>,
    /// pcuvd's version.
    pub pcuvd_version: String,
    /// The command (or Python call) that ran.
    pub command_line: Vec<String>,
    /// Every processing and dynamics setting, defaults included ([`crate::run::settings_text`]).
    pub options: String,
}

impl Provenance {
    /// True when `earlier` (an earlier run's summary.json) records the same input files (by size
    /// and checksum, of the same kind), options and pcuvd version.
    pub fn same_run_as(&self, earlier: &str) -> bool {
        #[derive(Deserialize)]
        struct Earlier {
            source: EarlierSource,
        }
        #[derive(Deserialize)]
        struct EarlierSource {
            files: Vec<FileRecord>,
            options: String,
            pcuvd_version: String,
        }
        let Ok(Earlier { source: earlier }) = serde_json::from_str::<Earlier>(earlier) else {
            return false;
        };
        let same_content = |a: &FileRecord, b: &FileRecord| {
            a.has_checksum()
                && (a.size_bytes, &a.blake3, &a.sha256) == (b.size_bytes, &b.blake3, &b.sha256)
        };
        earlier.files.len() == self.files.len()
            && earlier
                .files
                .iter()
                .zip(&self.files)
                .all(|(a, b)| same_content(a, b))
            && earlier.options == self.options
            && earlier.pcuvd_version == self.pcuvd_version
    }
}

/// The probe, as summary.json and `pcuvd info` record it.
#[derive(Debug, Clone, Serialize)]
pub struct ProbeRecord {
    /// Its name.
    pub name: String,
    /// Elements.
    pub n_elements: usize,
    /// Element pitch (m).
    pub pitch_m: f64,
    /// Element width (m).
    pub element_width_m: f64,
    /// Centre frequency (Hz).
    pub center_frequency_hz: f64,
    /// Fractional bandwidth (0.67 = 67 %).
    pub bandwidth: f64,
}

impl ProbeRecord {
    /// The record of `probe`.
    pub fn of(probe: &pcuvd::Probe) -> Self {
        ProbeRecord {
            name: probe.name.clone(),
            n_elements: probe.n_elements,
            pitch_m: probe.pitch,
            element_width_m: probe.element_width,
            center_frequency_hz: probe.center_frequency,
            bandwidth: probe.bandwidth,
        }
    }
}

/// The acquisition of a processed recording.
#[derive(Debug, Clone, Serialize)]
pub struct AcquisitionRecord {
    /// RF sampling rate (Hz).
    pub sampling_frequency_hz: f64,
    /// Speed of sound (m/s).
    pub sound_speed_m_s: f64,
    /// Time of the first sample after each transmit (s).
    pub t0_s: f64,
    /// Transmit events per second (Hz).
    pub event_prf_hz: f64,
    /// Plane-wave angles (degrees).
    pub angles_deg: Vec<f64>,
    /// How the angles were transmitted.
    pub coding: CodingRecord,
    /// Compound frames.
    pub frames: usize,
    /// Compound frames per second (Hz).
    pub frame_rate_hz: f64,
    /// Cycles of the transmit pulse.
    pub pulse_cycles: f64,
    /// The sampled transmit pulse, when the sequence has one.
    pub transmit_pulse: Option<PulseRecord>,
}

/// How the angles were transmitted: without coding, Hadamard-coded, or by a code matrix; for a
/// coded recording also how its events were aligned in time.
#[derive(Debug, Clone, Serialize)]
pub struct CodingRecord {
    /// The code.
    #[serde(flatten)]
    pub code: CodeRecord,
    /// How a coded recording's events were aligned in time (absent when not coded).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub event_alignment: Option<&'static str>,
}

/// The transmit code, by `kind`.
#[derive(Debug, Clone, Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum CodeRecord {
    /// One angle per event.
    None,
    /// A Hadamard code.
    Hadamard {
        /// Angles per event.
        order: usize,
        /// Delay between successive slots of an event (s).
        slot_delay_s: f64,
    },
    /// A code matrix.
    Matrix {
        /// Angles per event.
        order: usize,
        /// The code's weights, row (event) by row.
        code_matrix: Vec<Vec<f64>>,
        /// Each slot's start within its event (s).
        slot_starts_s: Vec<f64>,
        /// Whether an event fires several slots (a real code, not one angle per event).
        events_fire_several_slots: bool,
        /// The decoding gain g: decoded records are g × each angle's.
        decoding_gain: f64,
        /// The code's condition number.
        condition_number: f64,
    },
}

impl CodingRecord {
    /// The coding of `seq`, without an event alignment.
    pub fn of(seq: &pcuvd::Sequence) -> Self {
        let code = match &seq.coding {
            pcuvd::Coding::Conventional => CodeRecord::None,
            pcuvd::Coding::Hadamard { slot_delay } => CodeRecord::Hadamard {
                order: seq.n_angles(),
                slot_delay_s: *slot_delay,
            },
            pcuvd::Coding::Matrix(code) => CodeRecord::Matrix {
                order: code.order(),
                code_matrix: code
                    .weights
                    .chunks(code.order().max(1))
                    .map(<[f64]>::to_vec)
                    .collect(),
                slot_starts_s: code.slot_starts.clone(),
                events_fire_several_slots: code.is_coded(),
                decoding_gain: code.decoding_gain(),
                condition_number: code.condition_number(),
            },
        };
        CodingRecord {
            code,
            event_alignment: None,
        }
    }
}

/// The sampled transmit pulse: its sampling rate, length, and what pcuvd uses it for.
#[derive(Debug, Clone, Serialize)]
pub struct PulseRecord {
    /// Its sampling rate (Hz).
    pub sampling_frequency_hz: f64,
    /// Its samples.
    pub n_samples: usize,
    /// Its duration (s).
    pub duration_s: f64,
    /// What pcuvd uses it for.
    pub used_for: &'static str,
}

impl PulseRecord {
    /// The record of `seq`'s pulse (`None` when it has none).
    pub fn of(seq: &pcuvd::Sequence) -> Option<Self> {
        seq.pulse.as_ref().map(|p| PulseRecord {
            sampling_frequency_hz: p.sampling_frequency,
            n_samples: p.samples.len(),
            duration_s: p.duration(),
            used_for: "simulation (the echo waveform: the pulse through the probe's two-way \
                       response); processing does not need it",
        })
    }
}

/// The image grid's extent and step (m).
#[derive(Debug, Clone, Serialize)]
pub struct GridRecord {
    /// First column's lateral position (m).
    pub x_min_m: f64,
    /// Last column's lateral position (m).
    pub x_max_m: f64,
    /// First row's depth (m).
    pub z_min_m: f64,
    /// Last row's depth (m).
    pub z_max_m: f64,
    /// Pixel step (m).
    pub step_m: f64,
    /// Columns.
    pub nx: usize,
    /// Rows.
    pub nz: usize,
}

/// Delay-and-sum settings.
#[derive(Debug, Clone, Serialize)]
pub struct BeamformingRecord {
    /// Receive f-number.
    pub f_number: f64,
    /// Receive apodization window.
    pub apodization: String,
}

/// A clutter filter's cut-offs: singular components kept are `low..high`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct CutOffs {
    /// Components removed from the top (tissue).
    pub low: usize,
    /// First component removed from the bottom (noise).
    pub high: usize,
}

impl CutOffs {
    /// Each angle's cut-offs from (low, high) pairs.
    fn per_angle(pairs: &[(usize, usize)]) -> Vec<CutOffs> {
        pairs
            .iter()
            .map(|&(low, high)| CutOffs { low, high })
            .collect()
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
    /// The cut-offs each angle's filter used.
    pub cut_offs_per_angle: Vec<CutOffs>,
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
    /// where it could not be measured; absent (`null`) with the correction off.
    pub partial_volume_cells: Option<Vec<Option<CellRecord>>>,
}

/// A resolution cell's intensity covariance (mm, mm²).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct CellRecord {
    /// Lateral standard deviation (mm).
    pub sigma_x_mm: f64,
    /// Axial standard deviation (mm).
    pub sigma_z_mm: f64,
    /// Lateral-axial covariance (mm²).
    pub covariance_xz_mm2: f64,
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
    fn of(db: f64) -> Self {
        if db.is_finite() {
            Level::Db(db)
        } else {
            Level::Off("off")
        }
    }
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
    /// Harmonics of the heart rate fitted.
    pub harmonics: usize,
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
fn blocks_rule() -> String {
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
fn segments_rule() -> String {
    format!(
        "too long to hold whole (--segment-frames, default: the frames whose image series fit in \
         {} MiB): each segment imaged with the frames its dynamics windows and ensembles reach \
         into, clutter-filtered on its own; power and lag-1 autocorrelation summed over the \
         segments' own frames, velocities and vectors from the sums; windows and ensembles from \
         the segment their start is in",
        pipeline::segments::SERIES_BYTES >> 20
    )
}

/// The rule `summary.json` states for dealiasing.
fn dealias_rule() -> String {
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

impl Summary {
    /// The summary of a `process` run (without the writing timings): every parameter used, the
    /// Nyquist velocity, clutter cut-offs, per-stage timings, the dynamics stage, and `source`.
    pub fn of(
        data: &dyn FrameSource,
        plan: &Plan,
        processed: &Processed,
        source: Provenance,
    ) -> Self {
        let params = &plan.params;
        let out = &processed.out;
        let acq = data.acquisition();
        let seq = &acq.sequence;
        let mut coding = CodingRecord::of(seq);
        if seq.is_coded() {
            coding.event_alignment = Some(params.event_alignment.label());
        }
        let (x, z) = (&out.grid.x, &out.grid.z);
        Summary {
            units: "SI (m, s, Hz, m/s); colour Doppler and Vz positive = moving away from the \
                    probe (deeper)",
            source,
            probe: ProbeRecord::of(&acq.probe),
            acquisition: AcquisitionRecord {
                sampling_frequency_hz: acq.sampling_frequency,
                sound_speed_m_s: acq.sound_speed,
                t0_s: acq.t0,
                event_prf_hz: seq.event_prf,
                angles_deg: seq.angles.iter().map(|a| a.to_degrees()).collect(),
                coding,
                frames: data.n_frames(),
                frame_rate_hz: acq.frame_rate(),
                pulse_cycles: seq.pulse_cycles,
                transmit_pulse: PulseRecord::of(seq),
            },
            grid: GridRecord {
                x_min_m: x[0],
                x_max_m: x[x.len() - 1],
                z_min_m: z[0],
                z_max_m: z[z.len() - 1],
                step_m: out.grid.step(),
                nx: x.len(),
                nz: z.len(),
            },
            beamforming: BeamformingRecord {
                f_number: params.das.f_number,
                apodization: format!("{:?}", params.das.apodization),
            },
            clutter_filter: ClutterRecord {
                low: format!("{:?}", params.clutter.low),
                high: format!("{:?}", params.clutter.high),
                tissue_frequency_fraction: params.clutter.tissue_frequency,
                cut_offs_per_angle: out
                    .clutter
                    .iter()
                    .map(|r| CutOffs {
                        low: r.low,
                        high: r.high,
                    })
                    .collect(),
            },
            doppler: DopplerRecord {
                kernel: [params.doppler_kernel.0, params.doppler_kernel.1],
                estimator: params.doppler_estimator.label(),
                estimator_description: params.doppler_estimator.describe(),
                partial_volume: params.partial_volume,
                partial_volume_cells: params.partial_volume.then(|| {
                    out.cells
                        .iter()
                        .map(|cell| {
                            cell.map(|c| CellRecord {
                                sigma_x_mm: c.xx.sqrt() * 1e3,
                                sigma_z_mm: c.zz.sqrt() * 1e3,
                                covariance_xz_mm2: c.xz * 1e6,
                            })
                        })
                        .collect()
                }),
            },
            irls: IrlsRecord {
                lambda_mm_s: params.irls.lambda_mm_s,
                epsilon: params.irls.epsilon,
                max_iterations: params.irls.max_iterations,
            },
            nyquist_velocity_m_s: out.nyquist_velocity,
            dealias: DealiasRecord::of(params, out, seq.is_coded()),
            dynamics: DynamicsRecord::of(plan, processed),
            blocks: BlocksRecord {
                frames: processed.blocks.frames,
                margin_frames: processed.blocks.margin,
                rule: blocks_rule(),
            },
            segments: match &processed.segments {
                None => Described::None("none: the whole recording was held and processed at once"),
                Some(done) => Described::Done(SegmentsRecord {
                    count: done.ranges.len(),
                    own_frames: done
                        .ranges
                        .iter()
                        .map(|(own, _)| [own.start, own.end])
                        .collect(),
                    imaged_frames: (done.ranges.iter())
                        .map(|(_, imaged)| [imaged.start, imaged.end])
                        .collect(),
                    clutter_cut_offs_per_angle: (done.clutter.iter())
                        .map(|per_angle| CutOffs::per_angle(per_angle))
                        .collect(),
                    rule: segments_rule(),
                }),
            },
            ensembles: match (&plan.ensembles, &processed.ensembles) {
                (Some(spec), Some(maps)) => Described::Done(EnsemblesRecord {
                    frames: spec.frames,
                    step_frames: spec.step,
                    count: maps.starts.len(),
                    duration_s: spec.frames as f64 / acq.frame_rate(),
                    times_s: maps.times_s.clone(),
                    start_frames: maps.starts.clone(),
                    clutter_cut_offs_per_angle: (maps.clutter.iter())
                        .map(|per_angle| CutOffs::per_angle(per_angle))
                        .collect(),
                    estimator: "IRLS-WLS (PC-UVD)",
                }),
                _ => Described::None(
                    "none: the whole recording is one ensemble (--ensemble-frames for a time \
                     series)",
                ),
            },
            nifti: None,
            timings_s: (out.timings.iter())
                .map(|(stage, seconds)| (stage.label().to_string(), *seconds))
                .collect(),
        }
    }
}

impl DealiasRecord {
    /// The setting, the K used, the speeds it reaches, per estimator how many flow pixels were
    /// dealiased, unwrapped, and reached ±K, and the warning for a `coded` recording or one of too
    /// few angles ([`pipeline::dealias_warning`]).
    fn of(params: &ProcessParams, out: &ProcessOutput, coded: bool) -> Self {
        let counts = |c: &pcuvd::estimate::dealias::AliasCounts| AliasRecord {
            dealiased_pixels: c.dealiased_pixels,
            unwrapped_pixels: c.unwrapped_pixels,
            at_limit_pixels: c.at_limit_pixels,
        };
        DealiasRecord {
            setting: params.dealias.label(),
            warning: pipeline::dealias_warning(params.dealias, coded, out),
            done: out.dealias.as_ref().map(|done| DealiasDone {
                intervals: done.intervals,
                max_speed_m_s: (2 * done.intervals + 1) as f64 * out.nyquist_velocity,
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
    fn of(plan: &Plan, processed: &Processed) -> Self {
        let (settings, series, maps) = match (&plan.dynamics, &processed.dynamics) {
            (Some(settings), DynamicsOutcome::Done { series, maps }) => (settings, series, maps),
            (_, DynamicsOutcome::Skipped(reason)) => {
                return DynamicsRecord::Skipped {
                    skipped: reason.clone(),
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
            harmonics: dparams
                .harmonics
                .unwrap_or_else(|| dynamics::auto_harmonics(maps.heart_rate_hz, series.window_s)),
            estimator: "IRLS-WLS (PC-UVD)",
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
            vessel_pooling: PoolingSummary::new(dparams.pooling, processed.out.grid.step()),
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

#[cfg(test)]
mod tests {
    use super::*;

    fn provenance(files: Vec<FileRecord>) -> Provenance {
        Provenance {
            input: "in.mat".into(),
            format: "MUST".into(),
            reader: "test".into(),
            files,
            stored_samples: None,
            parameters: vec![],
            reader_warnings: vec![],
            pcuvd_version: env!("CARGO_PKG_VERSION").into(),
            command_line: vec!["pcuvd".into()],
            options: "{\"processing\":{}}".into(),
        }
    }

    fn summary_of(source: &Provenance) -> String {
        #[derive(Serialize)]
        struct Saved<'a> {
            source: &'a Provenance,
        }
        serde_json::to_string(&Saved { source }).unwrap()
    }

    fn file(size: u64, checksum: Checksum, hex: &str) -> FileRecord {
        FileRecord::new("in.mat".into(), size, checksum, hex.into())
    }

    #[test]
    fn a_run_is_the_same_only_with_the_same_content_options_and_version() {
        let run = provenance(vec![file(10, Checksum::Blake3, "ab")]);
        assert!(run.same_run_as(&summary_of(&run)));
        // A file moved elsewhere is the same content.
        let mut moved = run.clone();
        moved.files[0].path = "elsewhere/in.mat".into();
        assert!(run.same_run_as(&summary_of(&moved)));
        let differs = [
            provenance(vec![file(10, Checksum::Blake3, "ac")]),
            provenance(vec![file(11, Checksum::Blake3, "ab")]),
            // The same hex under another kind of checksum is not the same content.
            provenance(vec![file(10, Checksum::Sha256, "ab")]),
            provenance(vec![
                file(10, Checksum::Blake3, "ab"),
                file(1, Checksum::Blake3, "cd"),
            ]),
            Provenance {
                options: "{\"processing\":{\"svd_low\":4}}".into(),
                ..run.clone()
            },
            Provenance {
                pcuvd_version: "0.0.1".into(),
                ..run.clone()
            },
        ];
        for earlier in &differs {
            assert!(!run.same_run_as(&summary_of(earlier)), "{earlier:?}");
        }
        // Without checksums (or not a summary at all) nothing is known to be the same.
        let unchecked = r#"{"source": {"files": [{"path": "in.mat", "size_bytes": 10}],
            "options": "{\"processing\":{}}", "pcuvd_version": "0.1.0"}}"#;
        assert!(!run.same_run_as(unchecked));
        assert!(!run.same_run_as("not json"));
    }

    #[test]
    fn sections_serialise_as_summary_json_names_them() {
        fn value<T: Serialize>(v: &T) -> String {
            serde_json::to_string(v).unwrap()
        }
        assert_eq!(value(&Level::of(f64::INFINITY)), "\"off\"");
        assert_eq!(value(&Level::of(-3.0)), "-3.0");
        assert_eq!(
            value(&Described::<BlocksRecord>::None("none: why")),
            "\"none: why\""
        );
        let coding = CodingRecord {
            code: CodeRecord::Hadamard {
                order: 4,
                slot_delay_s: 1e-6,
            },
            event_alignment: Some("mid-frame"),
        };
        assert_eq!(
            value(&coding),
            r#"{"kind":"hadamard","order":4,"slot_delay_s":1e-6,"event_alignment":"mid-frame"}"#
        );
        let plain = CodingRecord {
            code: CodeRecord::None,
            event_alignment: None,
        };
        assert_eq!(value(&plain), r#"{"kind":"none"}"#);
        let skipped = DynamicsRecord::Skipped {
            skipped: "--dynamics off".into(),
        };
        assert_eq!(value(&skipped), r#"{"skipped":"--dynamics off"}"#);
        // Non-finite numbers elsewhere are null (serde_json's writing of them).
        assert_eq!(value(&[f64::NAN]), "[null]");
    }
}
