//! What `summary.json` holds, as types: every parameter a run used, what each stage did, and where
//! its input came from. Serialised in field order; NaN and infinities are written as `null`.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

pub use crate::input::{ImagesRecord, RunInput};
use crate::outputs::Checksum;
use crate::run::{Plan, Processed};

use super::stages::*;

/// The whole of a `process` run's `summary.json`.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// The units every number is in, and the sign of axial velocities.
    pub units: &'static str,
    /// Where the input came from and the options it was processed with.
    pub source: Provenance,
    /// The probe (absent for beamformed images formed elsewhere).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub probe: Option<ProbeRecord>,
    /// Sampling, angles, coding and frames (absent for beamformed images formed elsewhere).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub acquisition: Option<AcquisitionRecord>,
    /// The beamformed images the run read, formed elsewhere (absent for channel data).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub images: Option<ImagesRecord>,
    /// The image grid (m).
    pub grid: GridRecord,
    /// Delay-and-sum settings (absent for beamformed images formed elsewhere).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub beamforming: Option<BeamformingRecord>,
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
    /// How the frames were split into blocks for imaging (absent for beamformed images formed
    /// elsewhere).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub blocks: Option<BlocksRecord>,
    /// Which pixels the figures draw as flow.
    pub figures: FiguresRecord,
    /// The segments of a recording too long to hold whole, or why there were none.
    pub segments: Described<SegmentsRecord>,
    /// The Doppler time series' ensembles, or why there were none.
    pub ensembles: Described<EnsemblesRecord>,
    /// The NIfTI images written beside the `.npy` maps (absent when none were asked for).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub nifti: Option<Vec<String>>,
    /// The Zarr store written beside the `.npy` maps (absent when none was asked for); it holds
    /// the time series alone when they went to it as the run went.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub zarr: Option<ZarrRecord>,
    /// The maps scored against the truth of the simulation they came from, where the recording
    /// has the scenario `pcuvd simulate` wrote beside it (absent otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub against_truth: Option<crate::against_truth::TruthRecord>,
    /// The points whose spectrograms the run drew (`--sites`: sites.png, site_*.npy), with the
    /// pixels read (absent when none were asked for).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sites: Option<Vec<crate::sites::SiteRecord>>,
    /// Wall-clock seconds by stage.
    pub timings_s: BTreeMap<String, f64>,
    /// The process's peak resident memory (bytes) when the summary was written, all outputs but
    /// the summary written; `null` where the system does not say.
    pub peak_resident_bytes: Option<u64>,
}

/// The run's Zarr store.
#[derive(Debug, Clone, Serialize)]
pub struct ZarrRecord {
    /// The store's folder, in the output folder.
    pub store: String,
    /// Its arrays: maps (z, x), time series (time, z, x), velocity windows (window_time, z, x).
    pub arrays: Vec<String>,
    /// True when the Doppler time series are in the store only (no `ensemble_*.npy` or NIfTI
    /// series): they went to it as the run went, never all in memory.
    pub time_series_in_store_only: bool,
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
    /// Its XXH3-128 checksum (hex, as `xxh128sum` prints it), when that was the kind asked for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub xxh128: Option<String>,
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
        let (mut xxh128, mut blake3, mut sha256) = (None, None, None);
        *match checksum {
            Checksum::Xxh128 => &mut xxh128,
            Checksum::Blake3 => &mut blake3,
            Checksum::Sha256 => &mut sha256,
        } = Some(hex);
        FileRecord {
            path,
            size_bytes,
            xxh128,
            blake3,
            sha256,
        }
    }

    /// The kind of checksum it records (summaries of old versions may record none).
    fn checksum(&self) -> Option<Checksum> {
        match (&self.xxh128, &self.blake3, &self.sha256) {
            (Some(_), None, None) => Some(Checksum::Xxh128),
            (None, Some(_), None) => Some(Checksum::Blake3),
            (None, None, Some(_)) => Some(Checksum::Sha256),
            _ => None,
        }
    }

    /// The checksums it records, for comparing one file's content with another's.
    fn content(&self) -> (u64, &Option<String>, &Option<String>, &Option<String>) {
        (self.size_bytes, &self.xxh128, &self.blake3, &self.sha256)
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
    /// A recording simulated in memory: the simulator's record (scenario, seed, noise), as a
    /// simulated recording's manifest holds it in `[provenance]`; absent for every other input.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub simulation: Option<toml::Table>,
}

/// What a re-run compares of an earlier run's summary.json.
#[derive(Deserialize)]
struct Earlier {
    source: EarlierSource,
}

/// The `source` section of an earlier run's summary.json, as far as a re-run compares it.
#[derive(Deserialize)]
struct EarlierSource {
    files: Vec<FileRecord>,
    options: String,
    pcuvd_version: String,
}

impl Provenance {
    /// The kind of checksum by which `earlier` (an earlier run's summary.json) records its input
    /// files, where it records them all by one: a re-run hashes its input with it, whatever
    /// today's default, to know whether that run was of the same files.
    pub fn checksum_of(earlier: &str) -> Option<Checksum> {
        let Earlier { source } = serde_json::from_str::<Earlier>(earlier).ok()?;
        let mut kinds = source.files.iter().map(FileRecord::checksum);
        let first = kinds.next()??;
        kinds.all(|kind| kind == Some(first)).then_some(first)
    }

    /// True when `earlier` (an earlier run's summary.json) records the same input files (by size
    /// and checksum, of the same kind), options and pcuvd version.
    pub fn same_run_as(&self, earlier: &str) -> bool {
        let Ok(Earlier { source: earlier }) = serde_json::from_str::<Earlier>(earlier) else {
            return false;
        };
        let same_content =
            |a: &FileRecord, b: &FileRecord| a.checksum().is_some() && a.content() == b.content();
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
    /// Coded when fired, stored decoded: one record per angle, nothing decoded again.
    Decoded {
        /// Angles per frame.
        order: usize,
        /// The polarity (±1) each angle's record was stored with, turned back by pcuvd.
        polarity: Vec<f64>,
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
            pcuvd::Coding::Decoded { polarity } => CodeRecord::Decoded {
                order: seq.n_angles(),
                polarity: polarity.clone(),
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

impl Summary {
    /// The summary of a `process` run on `input` (without the writing timings): every parameter
    /// used, the Nyquist velocity, clutter cut-offs, per-stage timings, the dynamics stage, and
    /// `source`.
    pub fn of(input: RunInput<'_>, plan: &Plan, processed: &Processed, source: Provenance) -> Self {
        let params = &plan.params;
        let out = &processed.out;
        let (x, z) = (&out.grid.x, &out.grid.z);
        let block_layout = (out.clutter.first()).and_then(|report| report.block_layout.as_ref());
        let frame_rate = input.frame_rate();
        let (probe, acquisition, images, coded) = match input {
            RunInput::Recording(data) => {
                let acq = data.acquisition();
                let seq = &acq.sequence;
                let mut coding = CodingRecord::of(seq);
                if seq.decodes_events() {
                    coding.event_alignment = Some(params.event_alignment.label());
                }
                let acquisition = AcquisitionRecord {
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
                };
                let probe = ProbeRecord::of(&acq.probe);
                (Some(probe), Some(acquisition), None, seq.is_coded())
            }
            RunInput::Images(images) => (None, None, Some(images.clone()), false),
        };
        let formed_here = acquisition.is_some();
        Summary {
            units: "SI (m, s, Hz, m/s); colour Doppler and Vz positive = moving away from the \
                    probe (deeper)",
            source,
            probe,
            acquisition,
            images,
            grid: GridRecord {
                x_min_m: x[0],
                x_max_m: x[x.len() - 1],
                z_min_m: z[0],
                z_max_m: z[z.len() - 1],
                step_m: out.grid.step(),
                nx: x.len(),
                nz: z.len(),
            },
            beamforming: formed_here.then(|| BeamformingRecord {
                f_number: params.das.f_number,
                apodization: format!("{:?}", params.das.apodization),
            }),
            clutter_filter: ClutterRecord {
                low: format!("{:?}", params.clutter.low),
                high: format!("{:?}", params.clutter.high),
                tissue_frequency_fraction: params.clutter.tissue_frequency,
                block_pixels: block_layout.map(|layout| [layout.size.0, layout.size.1]),
                block_starts_px: block_layout.map(BlockStarts::of),
                cut_offs_per_angle: out.clutter.iter().map(CutOffs::of).collect(),
            },
            doppler: DopplerRecord {
                kernel: [params.doppler_kernel.0, params.doppler_kernel.1],
                estimator: params.doppler_estimator.label(),
                estimator_description: params.doppler_estimator.describe(),
                partial_volume: params.partial_volume,
                partial_volume_cells: params
                    .measures_cells(out.maps.cells.len())
                    .then(|| CellRecord::of_angles(&out.maps.cells)),
            },
            irls: IrlsRecord {
                lambda_mm_s: params.irls.lambda_mm_s,
                epsilon: params.irls.epsilon,
                max_iterations: params.irls.max_iterations,
            },
            nyquist_velocity_m_s: out.maps.nyquist_velocity,
            dealias: DealiasRecord::of(params, out, coded),
            dynamics: DynamicsRecord::of(plan, processed),
            blocks: formed_here.then(|| BlocksRecord {
                frames: processed.blocks.frames,
                margin_frames: processed.blocks.margin,
                rule: blocks_rule(),
            }),
            figures: FiguresRecord::default(),
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
                        .map(|per_angle| per_angle.iter().map(CutOffs::of).collect())
                        .collect(),
                    rule: segments_rule(),
                }),
            },
            ensembles: match (&plan.ensembles, &processed.ensembles) {
                (Some(spec), Some(maps)) => Described::Done(EnsemblesRecord {
                    frames: spec.frames,
                    step_frames: spec.step,
                    count: maps.starts.len(),
                    duration_s: spec.frames as f64 / frame_rate,
                    times_s: maps.times_s.clone(),
                    start_frames: maps.starts.clone(),
                    clutter_cut_offs_per_angle: (maps.clutter.iter())
                        .map(|per_angle| per_angle.iter().map(|&c| CutOffs::from(c)).collect())
                        .collect(),
                    estimator: "IRLS-WLS (PC-UVD)",
                }),
                _ => Described::None(
                    "none: the whole recording is one ensemble (--ensemble-frames for a time \
                     series)",
                ),
            },
            nifti: None,
            zarr: None,
            against_truth: None,
            sites: None,
            timings_s: (out.timings.iter())
                .map(|(stage, seconds)| (stage.label().to_string(), *seconds))
                .collect(),
            peak_resident_bytes: None,
        }
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
            simulation: None,
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
            provenance(vec![file(10, Checksum::Xxh128, "ab")]),
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
    fn an_earlier_run_names_the_one_kind_of_checksum_it_recorded() {
        for kind in [Checksum::Xxh128, Checksum::Blake3, Checksum::Sha256] {
            let run = provenance(vec![file(10, kind, "ab"), file(3, kind, "cd")]);
            assert_eq!(Provenance::checksum_of(&summary_of(&run)), Some(kind));
        }
        let mixed = provenance(vec![
            file(10, Checksum::Blake3, "ab"),
            file(3, Checksum::Xxh128, "cd"),
        ]);
        assert_eq!(Provenance::checksum_of(&summary_of(&mixed)), None);
        let unchecked = r#"{"source": {"files": [{"path": "in.mat", "size_bytes": 10}],
            "options": "{\"processing\":{}}", "pcuvd_version": "0.1.0"}}"#;
        assert_eq!(Provenance::checksum_of(unchecked), None);
        assert_eq!(Provenance::checksum_of("not json"), None);
        assert_eq!(
            Provenance::checksum_of(&summary_of(&provenance(vec![]))),
            None
        );
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
