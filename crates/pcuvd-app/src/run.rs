//! `pcuvd process`: a recording in, maps, numbers and figures out.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;
use ndarray::Array1;
use pcuvd::ChannelData;
use pcuvd::dynamics::{self, DynamicsParams, PoolingSummary, RiMaps, VelocitySeries, VesselTests};
use pcuvd::pipeline::{self, ProcessOutput, ProcessParams};
use pcuvd::segments::Segments;
use pcuvd::source::FrameSource;
use serde_json::json;

use crate::figures;
use crate::options::{DynamicsChoice, DynamicsOptions, ProcessingOptions, Switch};
use crate::outputs;
use crate::progress::PipelineProgress;

/// Arguments of `pcuvd process`.
#[derive(Args, Debug)]
pub struct ProcessArgs {
    /// Recording: any format `pcuvd info` reads (MUST .mat v5/v7.3 or .npz, USTB .uff, zea .hdf5,
    /// a Verasonics workspace .mat, or a pcuvd recording manifest .toml); recognised by content.
    pub input: PathBuf,
    /// Output folder (created if needed; a folder that holds anything is refused unless --force).
    #[arg(long)]
    pub out: PathBuf,
    /// Reuse a non-empty output folder: pcuvd's own outputs of an earlier run there are removed
    /// first (no stale map beside the new summary.json); other files are never touched.
    #[arg(long)]
    pub force: bool,
    /// Memory processing may use (GB); default: what the machine has available now. Set it on a
    /// shared node whose job limit is below the machine's free memory (a Slurm --mem, say).
    #[arg(long)]
    pub max_memory_gb: Option<f64>,
    #[command(flatten)]
    pub acquisition: AcquisitionOverrides,
    #[command(flatten)]
    pub options: ProcessingOptions,
    #[command(flatten)]
    pub dynamics: DynamicsOptions,
}

/// Acquisition values that replace (or fill in) what the recording says, SI units; each is
/// recorded as given by the user in `pcuvd info` and summary.json.
#[derive(Args, Debug, Clone, Default)]
pub struct AcquisitionOverrides {
    /// Time of the first sample after the first element fires (s), e.g. --t0-s 9.95e-6.
    #[arg(long, allow_hyphen_values = true)]
    pub t0_s: Option<f64>,
    /// Speed of sound (m/s).
    #[arg(long)]
    pub sound_speed_m_s: Option<f64>,
    /// Transmit-event repetition frequency (Hz).
    #[arg(long)]
    pub event_prf_hz: Option<f64>,
    /// Sampling frequency of the traces (Hz).
    #[arg(long)]
    pub sampling_freq_hz: Option<f64>,
    /// Probe centre frequency (Hz).
    #[arg(long)]
    pub center_freq_hz: Option<f64>,
    /// Demodulation frequency of IQ samples (Hz).
    #[arg(long)]
    pub demod_freq_hz: Option<f64>,
}

impl AcquisitionOverrides {
    /// The overrides as the readers take them.
    pub fn to_overrides(&self) -> pcuvd_io::Overrides {
        pcuvd_io::Overrides {
            t0_s: self.t0_s,
            sound_speed_m_s: self.sound_speed_m_s,
            event_prf_hz: self.event_prf_hz,
            sampling_freq_hz: self.sampling_freq_hz,
            center_freq_hz: self.center_freq_hz,
            demod_freq_hz: self.demod_freq_hz,
            ..pcuvd_io::Overrides::default()
        }
    }
}

/// Reads a whole recording, any format (recognised from its content). Returns the data and every
/// file it was read from (a manifest and its samples, or the one file).
pub fn read_input(path: &Path) -> Result<(ChannelData, Vec<PathBuf>)> {
    let opened = open_input(path, &pcuvd_io::Overrides::default())?;
    let data = opened.read_all()?;
    Ok((data, opened.info.files))
}

/// Opens a recording for `process` and `info`, any format, with the user's overrides: its frames
/// are read a block at a time, and its [`pcuvd_io::SourceInfo`] says what was read, by which
/// reader, and where every acquisition parameter came from.
pub fn open_input(
    path: &Path,
    overrides: &pcuvd_io::Overrides,
) -> Result<pcuvd_io::OpenedRecording> {
    let opened = pcuvd_io::open_recording(path, overrides)?;
    check_recording(path, opened.source.as_ref())?;
    Ok(opened)
}

/// The warning for RF that is band-pass sampled (f_s below twice the band's top, the band whole in
/// one Nyquist zone: valid, and demodulated as such); `None` when f_s is above twice the band's top
/// or the band folds (an error the readers give).
pub fn band_pass_warning(acq: &pcuvd::Acquisition) -> Option<String> {
    match acq.rf_band_sampling() {
        Ok(pcuvd::BandSampling::BandPass { zone }) => {
            let probe = &acq.probe;
            let (low, high) = (
                probe.center_frequency * (1.0 - probe.bandwidth / 2.0),
                probe.center_frequency * (1.0 + probe.bandwidth / 2.0),
            );
            let half = acq.sampling_frequency / 2.0;
            Some(format!(
                "f_s {:.3} MHz is below twice the band's top ({:.3} MHz): the RF is band-pass \
                 sampled, its band {:.3}–{:.3} MHz lying in Nyquist zone {zone} ({:.3}–{:.3} MHz); \
                 pcuvd demodulates it as such, but a band wider than the probe's stated bandwidth \
                 would fold onto itself",
                acq.sampling_frequency * 1e-6,
                2.0 * high * 1e-6,
                low * 1e-6,
                high * 1e-6,
                zone as f64 * half * 1e-6,
                (zone + 1) as f64 * half * 1e-6
            ))
        }
        _ => None,
    }
}

/// [`band_pass_warning`] for a recording whose samples are RF (read from its first frame).
fn rf_band_pass_warning(data: &dyn FrameSource) -> Result<Option<String>> {
    if data.n_frames() == 0 {
        return Ok(None);
    }
    let first = data.read_frames(0..1)?;
    Ok(match first.samples {
        pcuvd::Samples::Rf(_) => band_pass_warning(data.acquisition()),
        pcuvd::Samples::Iq { .. } => None,
    })
}

/// Checks what a recording's acquisition says against its samples' shape before any work (every
/// pulse slot starts within the record), naming the file.
fn check_recording(path: &Path, data: &dyn FrameSource) -> Result<()> {
    pipeline::check_record(data.acquisition(), data.trace_shape().1)
        .with_context(|| path.display().to_string())
}

/// Creates `dir` (and parents), with a message naming it on failure.
pub fn create_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir)
        .with_context(|| format!("{}: cannot create the output folder", dir.display()))
}

/// Runs `pcuvd process`.
pub fn run(args: &ProcessArgs) -> Result<()> {
    let clock = std::time::Instant::now();
    let opened = open_input(&args.input, &args.acquisition.to_overrides())?;
    let input_files = opened.info.files.clone();
    let data = opened.source.as_ref();
    let read_s = clock.elapsed().as_secs_f64();
    let mut plan = Plan::new(
        &args.options,
        &args.dynamics,
        data,
        opened.info.cardiac_triggers_s.as_deref(),
    )?;
    // Overrides change the results: a re-run with others is not the same run.
    if !args.acquisition.to_overrides().is_empty() {
        plan.options_text
            .push_str(&format!(" {:?}", args.acquisition));
    }
    let band_warning = rf_band_pass_warning(data)?;
    check_memory(data, &plan, args.max_memory_gb)?;
    let provenance_of_run = {
        let (input, info) = (args.input.display().to_string(), opened.info.clone());
        let options_text = plan.options_text.clone();
        move || {
            let clock = std::time::Instant::now();
            let source = provenance(&input, &info, &options_text, std::env::args().collect());
            source.map(|source| (source, clock.elapsed().as_secs_f64()))
        }
    };
    // The checksums read the whole input, on one core (3 s for 2.8 GB): they are needed before
    // any work only to skip a folder processed before; otherwise they are computed beside the
    // processing, on a thread of their own that takes only the time the processing leaves idle.
    let checksums = if !args.force && args.out.join("summary.json").is_file() {
        let (source, seconds) = provenance_of_run()?;
        if already_done(&args.out, &source) {
            println!(
                "{}: already processed from the same input (checksums) with the same options and \
                 pcuvd version (summary.json); skipped (--force redoes it)",
                args.out.display()
            );
            return Ok(());
        }
        Checksums::Done(source, seconds)
    } else {
        Checksums::Running(std::thread::spawn(move || {
            lower_this_threads_priority();
            provenance_of_run()
        }))
    };
    outputs::prepare(
        &args.out,
        outputs::PROCESS_OUTPUTS,
        &input_files,
        args.force,
    )?;
    let name = args
        .input
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    // Said once the run is accepted (not before an error, which stays the only line).
    if let Some(warning) = band_warning {
        eprintln!("warning: {}: {warning}", args.input.display());
    }
    let progress = PipelineProgress::new("");
    let processed = compute(data, &plan, &|s, d, t| progress.update(s, d, t))
        .with_context(|| format!("{}: processing failed", args.input.display()))?;
    let coded = data.acquisition().sequence.is_coded();
    if let Some(warning) =
        pcuvd::pipeline::dealias_warning(plan.params.dealias, coded, &processed.out)
    {
        eprintln!("warning: {}: {warning}", args.input.display());
    }
    let (source, checksum_s) = match checksums {
        Checksums::Done(source, seconds) => (source, seconds),
        Checksums::Running(thread) => thread
            .join()
            .map_err(|_| anyhow::anyhow!("the checksum thread failed"))??,
    };
    let extra_timings = [("read", read_s), ("checksum", checksum_s)];
    let pngs = save(
        &args.out,
        data,
        &plan,
        &processed,
        source,
        &name,
        &extra_timings,
    )?;
    println!(
        "{}: {} angle(s), {} frames at {:.1} Hz; Nyquist velocity {:.1} mm/s; grid {} x {} pixels",
        args.input.display(),
        data.acquisition().sequence.n_angles(),
        data.n_frames(),
        data.acquisition().frame_rate(),
        processed.out.nyquist_velocity * 1e3,
        processed.out.grid.z.len(),
        processed.out.grid.x.len()
    );
    println!(
        "wrote maps (.npy), summary.json and {} figures to {}",
        pngs.len(),
        args.out.display()
    );
    Ok(())
}

/// The input's provenance with its checksums, and the seconds they took: computed, or being
/// computed beside the processing.
enum Checksums {
    Done(serde_json::Value, f64),
    Running(std::thread::JoinHandle<Result<(serde_json::Value, f64)>>),
}

/// Every setting of a `process` run, read and checked before any work: the pipeline's, the
/// dynamics stage's, and the options as text (what summary.json records and a re-run compares).
#[derive(Debug, Clone)]
pub struct Plan {
    /// Settings of the decoding-to-vectors chain.
    pub params: ProcessParams,
    /// Settings of the dynamics stage; `None` with `--dynamics off`.
    pub dynamics: Option<DynamicsSettings>,
    /// True when a dynamics setting was given, so that a recording that cannot honour it is an
    /// error rather than a skipped stage.
    pub dynamics_required: bool,
    /// Every processing and dynamics option, defaults included, as one line of text.
    pub options_text: String,
    /// The Doppler time series' ensembles, when asked for.
    pub ensembles: Option<pcuvd::ensembles::EnsembleSpec>,
    /// How a recording too long to hold whole is cut; `None`: processed whole.
    pub segments: Option<Segments>,
}

impl Plan {
    /// Reads and checks the options against the recording `data`, before the long processing.
    /// `recorded_triggers`: cardiac cycle start times (s) recorded with the recording (a
    /// manifest's `[cardiac]`), used unless `--cardiac-triggers` or `--heart-rate` is given.
    pub fn new(
        options: &ProcessingOptions,
        dynamics: &DynamicsOptions,
        data: &dyn FrameSource,
        recorded_triggers: Option<&[f64]>,
    ) -> Result<Plan> {
        let params = options.params(data)?;
        let dynamics_settings = if dynamics.dynamics == DynamicsChoice::Off {
            None
        } else {
            Some(DynamicsSettings {
                params: pcuvd::dynamics::DynamicsParams {
                    // The windows read velocity as the whole-recording maps do.
                    doppler: params.doppler_estimator,
                    partial_volume: dynamics.dynamics_partial_volume == Switch::On,
                    ..dynamics.params(
                        data.acquisition().frame_rate(),
                        params.irls,
                        params.dealias,
                        params.grid.step(),
                    )?
                },
                vessel: dynamics.vessel_tests()?,
                triggers: match (dynamics.triggers()?, recorded_triggers) {
                    (Some(given), _) => Some((given, "--cardiac-triggers".into())),
                    // The recording's own triggers, unless the user gave a heart rate.
                    (None, Some(recorded)) if dynamics.heart_rate.is_none() => Some((
                        recorded.to_vec(),
                        "the recording's manifest ([cardiac])".into(),
                    )),
                    (None, _) => None,
                },
            })
        };
        if dynamics.explicit()
            && let Some(settings) = &dynamics_settings
        {
            // Asked for: what the recording cannot give is refused now, not after processing.
            let acq = data.acquisition();
            if acq.sequence.n_angles() < 2 {
                bail!(
                    "the dynamics stage (asked for by --dynamics on or a dynamics option) needs two \
                     or more steering angles for vector velocity; the recording has one"
                );
            }
            settings
                .params
                .validate(acq.frame_rate())
                .context("dynamics options")?;
            let duration = data.n_frames() as f64 / acq.frame_rate();
            if let Some(hr) = settings.params.heart_rate_hz
                && 1.0 / hr > duration
            {
                bail!(
                    "--heart-rate {}: a cycle lasts {:.4} s but the recording holds {:.4} s \
                     ({} frames at {:.1} Hz); RI needs at least one whole cycle",
                    crate::options::shown("--heart-rate", hr),
                    1.0 / hr,
                    duration,
                    data.n_frames(),
                    acq.frame_rate()
                );
            }
            if settings.params.window > data.n_frames() {
                bail!(
                    "--window-ms: a window of {} frames is longer than the recording's {} frames",
                    settings.params.window,
                    data.n_frames()
                );
            }
        }
        let ensembles = options.ensembles(data.n_frames())?;
        let (nz, nx) = params.grid.shape();
        let windows = dynamics_settings
            .as_ref()
            .map(|d| &d.params)
            .filter(|_| data.acquisition().sequence.n_angles() >= 2);
        // By default as many frames as fit, but never too few for the windows and ensembles.
        let segment_frames = options.segment_frames.unwrap_or_else(|| {
            pcuvd::segments::frames_that_fit(nz * nx, data.acquisition().sequence.n_angles())
                .max(Segments::shortest(windows, ensembles))
        });
        let segments = Segments::plan(data.n_frames(), segment_frames, windows, ensembles)
            .context("--segment-frames")?;
        Ok(Plan {
            ensembles,
            segments,
            params,
            dynamics: dynamics_settings,
            dynamics_required: dynamics.explicit(),
            options_text: format!("{options:?} {dynamics:?}"),
        })
    }
}

/// What the dynamics stage gave: RI maps and the velocity series they came from, or why not.
#[derive(Debug, Clone)]
pub enum DynamicsOutcome {
    /// The stage ran.
    Done {
        /// Vector velocity in sliding windows.
        series: Box<VelocitySeries>,
        /// PSV, EDV, RI, classes and flow directions.
        maps: Box<RiMaps>,
    },
    /// The stage was skipped (off, or the recording cannot give RI maps); the reason.
    Skipped(String),
}

/// Everything `process` computed, before anything is written.
#[derive(Debug, Clone)]
pub struct Processed {
    /// The maps of the decoding-to-vectors chain (shared: a re-run of the dynamics stage with
    /// other settings keeps them, and the filtered series they hold can be large).
    pub out: std::sync::Arc<ProcessOutput>,
    /// The dynamics stage's result.
    pub dynamics: DynamicsOutcome,
    /// Wall-clock seconds the dynamics stage took.
    pub dynamics_s: f64,
    /// The Doppler time series, when asked for.
    pub ensembles: Option<pcuvd::ensembles::EnsembleMaps>,
    /// The blocks of frames the images were formed in.
    pub blocks: pcuvd::source::Blocks,
    /// Each segment's core and imaged frames, and its clutter cut-offs per angle, when the
    /// recording was processed in segments.
    pub segments: Option<SegmentsDone>,
}

/// What processing in segments did, for summary.json.
#[derive(Debug, Clone)]
pub struct SegmentsDone {
    /// Each segment's own frames and the frames imaged for it.
    pub ranges: Vec<(std::ops::Range<usize>, std::ops::Range<usize>)>,
    /// Each segment's clutter cut-offs (low, high), per angle.
    pub clutter: Vec<Vec<(usize, usize)>>,
}

/// Runs the chain and the dynamics stage on `data` as `plan` says. With `--dynamics auto` and no
/// dynamics setting given, a recording that cannot give RI maps (too short, one angle) skips the
/// stage with a note; otherwise that is an error.
pub fn compute(
    data: &dyn FrameSource,
    plan: &Plan,
    progress: &(dyn Fn(pipeline::Stage, usize, usize) + Sync),
) -> Result<Processed> {
    // Images are formed a block of frames at a time, so that decoding and IQ need one block's
    // memory; each ensemble of a time series is filtered on its own, from the unfiltered images.
    let blocks = pipeline::blocks_for(data, plan.params.event_alignment);
    if let Some(segments) = &plan.segments {
        return compute_in_segments(data, plan, segments, blocks, progress);
    }
    let (images, mut timings) =
        pipeline::form_images_in_blocks(data, &plan.params, blocks, progress)?;
    let ensembles = match plan.ensembles {
        None => None,
        Some(spec) => {
            let clock = std::time::Instant::now();
            let maps = pcuvd::ensembles::ensemble_maps(&images, &plan.params, spec, progress)?;
            timings.push((pipeline::Stage::Ensembles, clock.elapsed().as_secs_f64()));
            Some(maps)
        }
    };
    let mut out = pipeline::analyse(images, &plan.params, progress)?;
    timings.append(&mut out.timings);
    out.timings = timings;
    let clock = std::time::Instant::now();
    let dynamics = run_dynamics(&out, plan)?;
    Ok(Processed {
        out: std::sync::Arc::new(out),
        dynamics,
        dynamics_s: clock.elapsed().as_secs_f64(),
        ensembles,
        blocks,
        segments: None,
    })
}

/// [`compute`] for a recording too long to hold whole: segment by segment
/// ([`pcuvd::segments`]), the dynamics stage's windows and the ensembles from the segments, the
/// RI maps from their series.
fn compute_in_segments(
    data: &dyn FrameSource,
    plan: &Plan,
    segments: &Segments,
    blocks: pcuvd::source::Blocks,
    progress: &(dyn Fn(pipeline::Stage, usize, usize) + Sync),
) -> Result<Processed> {
    let vectors = data.acquisition().sequence.n_angles() >= 2;
    let windows = plan
        .dynamics
        .as_ref()
        .filter(|d| vectors && d.params.validate(data.acquisition().frame_rate()).is_ok());
    let done = pcuvd::segments::process_in_segments(
        data,
        &plan.params,
        segments,
        windows.map(|d| &d.params),
        plan.ensembles,
        progress,
    )?;
    let clock = std::time::Instant::now();
    let dynamics = dynamics_outcome(plan, || match (&plan.dynamics, done.series) {
        (Some(settings), Some(series)) => {
            let maps = pipeline::ri_maps_of(
                &series,
                &done.out.power_doppler,
                &done.out.grid,
                &settings.params,
                &settings.vessel,
                settings.triggers.as_ref().map(|(t, _)| t.as_slice()),
            )?;
            Ok((series, maps))
        }
        // The stage's own checks say why it cannot run (one angle, a window too long).
        (Some(settings), None) => {
            if !vectors {
                return Err(pcuvd::error::invalid(
                    "angles",
                    "vector velocity needs two or more steering angles; the recording has one",
                ));
            }
            settings.params.validate(data.acquisition().frame_rate())?;
            Err(pcuvd::error::invalid(
                "dynamics",
                "no segment gave a velocity window",
            ))
        }
        (None, _) => Err(pcuvd::error::invalid("dynamics", "the stage is off")),
    })?;
    Ok(Processed {
        out: std::sync::Arc::new(done.out),
        dynamics,
        dynamics_s: clock.elapsed().as_secs_f64(),
        ensembles: done.ensembles,
        blocks,
        segments: Some(SegmentsDone {
            ranges: done.ranges,
            clutter: done
                .clutter
                .iter()
                .map(|per_angle| per_angle.iter().map(|r| (r.low, r.high)).collect())
                .collect(),
        }),
    })
}

/// The dynamics stage on the chain's maps `out`, as `plan` says (see [`compute`]).
pub fn run_dynamics(out: &ProcessOutput, plan: &Plan) -> Result<DynamicsOutcome> {
    dynamics_outcome(plan, || {
        let settings = plan
            .dynamics
            .as_ref()
            .expect("asked only when the stage is on");
        pipeline::dynamics(
            out,
            &settings.params,
            &settings.vessel,
            settings.triggers.as_ref().map(|(t, _)| t.as_slice()),
        )
    })
}

/// The dynamics stage's outcome as `plan` says: off, done by `stage`, or skipped with a note when
/// the recording cannot give RI maps and no dynamics setting was given (else an error).
fn dynamics_outcome(
    plan: &Plan,
    stage: impl FnOnce() -> pcuvd::Result<(VelocitySeries, RiMaps)>,
) -> Result<DynamicsOutcome> {
    Ok(match &plan.dynamics {
        None => DynamicsOutcome::Skipped("--dynamics off".into()),
        Some(_) => match stage() {
            Ok((series, maps)) => DynamicsOutcome::Done {
                series: Box::new(series),
                maps: Box::new(maps),
            },
            Err(e) if !plan.dynamics_required => {
                let reason = format!("{e:#}");
                eprintln!("note: no RI maps: {reason} (use --dynamics off to silence this)");
                DynamicsOutcome::Skipped(reason)
            }
            Err(e) => return Err(anyhow::Error::from(e).context("dynamics (RI maps)")),
        },
    })
}

/// Writes every output of `process` into `dir` (already prepared by [`outputs::prepare`]): maps,
/// figures, dynamics maps, and `summary.json` last with `source` as its provenance and
/// `extra_timings` (seconds) beside the stages'. `name` labels the figures. Returns the figures.
pub fn save(
    dir: &Path,
    data: &dyn FrameSource,
    plan: &Plan,
    processed: &Processed,
    source: serde_json::Value,
    name: &str,
    extra_timings: &[(&str, f64)],
) -> Result<Vec<PathBuf>> {
    let clock = std::time::Instant::now();
    let out = &processed.out;
    write_maps(dir, out)?;
    let mut summary = summary(data, plan, processed, source);
    let mut pngs = figures::process_figures(dir, out, name)?;
    pngs.append(&mut write_dynamics(dir, plan, processed, name)?);
    if let Some(maps) = &processed.ensembles {
        write_ensembles(dir, maps)?;
        pngs.push(figures::ensemble_figure(dir, out, maps, name)?);
    }
    for (key, seconds) in extra_timings {
        summary["timings_s"][*key] = json!(seconds);
    }
    summary["timings_s"]["maps_figures_and_dynamics"] =
        json!(processed.dynamics_s + clock.elapsed().as_secs_f64());
    // Written last: a folder without summary.json is visibly incomplete.
    pcuvd_io::write_json(&dir.join("summary.json"), &summary)?;
    Ok(pngs)
}

/// How [`check_memory`] counts beyond [`pipeline::MEMORY_ESTIMATE_RULE`].
pub const STAGE_MEMORY_RULE: &str = "+ dynamics: 5 × windows × pixels × 8 bytes (vx, vz, power, \
speed and the pooled speed per window) + time series: ensembles × pixels × 6 × 8 bytes (five \
maps and a filtered copy of one ensemble's frames per angle counted once more)";

/// Bytes the stages after image formation hold beyond the chain's image series
/// ([`STAGE_MEMORY_RULE`]): the dynamics stage's window series and a time series' maps.
fn stage_memory(data: &dyn FrameSource, plan: &Plan) -> u128 {
    let (nz, nx) = plan.params.grid.shape();
    let pixels = (nz * nx) as u128;
    let frames = data.n_frames();
    // The stage runs only with two angles or more and a window the recording holds.
    let vectors = data.acquisition().sequence.n_angles() >= 2;
    let dynamics = plan.dynamics.as_ref().map_or(0, |d| {
        if !vectors || d.params.window > frames {
            return 0;
        }
        let windows = (frames - d.params.window) / d.params.step.max(1) + 1;
        5 * windows as u128 * pixels * 8
    });
    let ensembles = plan.ensembles.map_or(0, |e| {
        let count = frames.saturating_sub(e.frames) / e.step.max(1) + 1;
        let angles = data.acquisition().sequence.n_angles() as u128;
        count as u128 * pixels * 6 * 8 + e.frames as u128 * pixels * angles * 8
    });
    dynamics + ensembles
}

/// Refuses, before any work, a recording, grid and stages whose processing would need more memory
/// than the machine has available ([`pipeline::memory_estimate`] + [`STAGE_MEMORY_RULE`]),
/// instead of aborting on allocation.
pub fn check_memory(data: &dyn FrameSource, plan: &Plan, limit_gb: Option<f64>) -> Result<()> {
    let params = &plan.params;
    let available = match limit_gb {
        Some(gb) if gb.is_finite() && gb > 0.0 => Some(gb * 1e9),
        Some(gb) => bail!(
            "--max-memory-gb {}: must be a positive number of GB",
            crate::options::shown("--max-memory-gb", gb)
        ),
        None => available_memory().map(|b| b as f64),
    };
    let needed = (pipeline::memory_estimate(data, &params.grid) + stage_memory(data, plan)) as f64;
    if let Some(available) = available
        && needed > available
    {
        let what = match limit_gb {
            Some(gb) => format!(
                "--max-memory-gb {}",
                crate::options::shown("--max-memory-gb", gb)
            ),
            None => "the machine".to_string(),
        };
        bail!(
            "processing needs about {:.3} GB ({} {STAGE_MEMORY_RULE}) but {:.3} GB are \
             available ({what}): use a coarser or smaller --grid, or a shorter recording",
            needed / 1e9,
            pipeline::MEMORY_ESTIMATE_RULE,
            available / 1e9
        );
    }
    Ok(())
}

/// Memory available to a new process (bytes): `MemAvailable` of /proc/meminfo, where there is one.
pub fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Where the results came from: pcuvd's version, the command line, every input file with its
/// size and SHA-256, the format and the reader that read it (as the reader reports them), every
/// acquisition parameter with its source, the reader's warnings, and the options.
pub fn provenance(
    input: &str,
    info: &pcuvd_io::SourceInfo,
    options_text: &str,
    command_line: Vec<String>,
) -> Result<serde_json::Value> {
    let files = info
        .files
        .iter()
        .map(|path| {
            let (size, sha256) = outputs::fingerprint(path)?;
            Ok(json!({ "path": path.display().to_string(), "size_bytes": size, "sha256": sha256 }))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(json!({
        "input": input,
        "format": info.format,
        "reader": info.reader,
        "files": files,
        "stored_samples": info.stored,
        "parameters": info.parameters,
        "reader_warnings": info.warnings,
        "pcuvd_version": env!("CARGO_PKG_VERSION"),
        "command_line": command_line,
        "options": options_text,
    }))
}

/// True when `out` holds a complete earlier run (its summary.json) of the same input files (by
/// size and SHA-256), options (every processing and dynamics setting, defaults included) and
/// pcuvd version as `source` describes: a batch re-run can skip it.
fn already_done(out: &Path, source: &serde_json::Value) -> bool {
    let Ok(text) = std::fs::read_to_string(out.join("summary.json")) else {
        return false;
    };
    let Ok(summary) = serde_json::from_str::<serde_json::Value>(&text) else {
        return false;
    };
    let earlier = &summary["source"];
    let fingerprints = |s: &serde_json::Value| -> Option<Vec<(u64, String)>> {
        s["files"]
            .as_array()?
            .iter()
            .map(|f| Some((f["size_bytes"].as_u64()?, f["sha256"].as_str()?.to_string())))
            .collect()
    };
    fingerprints(earlier).is_some()
        && fingerprints(earlier) == fingerprints(source)
        && earlier["options"] == source["options"]
        && earlier["pcuvd_version"] == source["pcuvd_version"]
}

/// The dynamics stage's settings as read from the options.
#[derive(Debug, Clone)]
pub struct DynamicsSettings {
    /// Sliding windows, heart rate, RI thresholds, pooling.
    pub params: DynamicsParams,
    /// Whole-recording vessel tests (noise-floor margin, local peak).
    pub vessel: VesselTests,
    /// Cardiac cycle start times (s from the first frame), when given, and where they came from
    /// (the option or the recording's manifest).
    pub triggers: Option<(Vec<f64>, String)>,
}

/// The summary.json of a `process` run (without the writing timings): every parameter used, the
/// Nyquist velocity, clutter cut-offs, per-stage timings, the dynamics stage, and `source`.
pub fn summary(
    data: &dyn FrameSource,
    plan: &Plan,
    processed: &Processed,
    source: serde_json::Value,
) -> serde_json::Value {
    let mut summary = summary_json(data, &plan.params, &processed.out, source);
    summary["dynamics"] = dynamics_summary(plan, processed);
    summary["blocks"] = json!({
        "frames": processed.blocks.frames,
        "margin_frames": processed.blocks.margin,
        "rule": format!(
            "images formed a block of frames at a time, decoded in the memory they are read \
             into: at most as many frames as fit in {} MiB with their margins and one angle's IQ \
             (the whole recording when it fits), the blocks of a segment sharing its frames \
             evenly, with {} frames decoded on either side of a block of a coded recording \
             aligned at mid-frame",
            pipeline::BLOCK_BYTES >> 20,
            pcuvd::source::Blocks::ALIGNMENT_MARGIN
        ),
    });
    summary["segments"] = match &processed.segments {
        None => json!("none: the whole recording was held and processed at once"),
        Some(done) => json!({
            "count": done.ranges.len(),
            "own_frames": done.ranges.iter().map(|(core, _)| [core.start, core.end]).collect::<Vec<_>>(),
            "imaged_frames": done.ranges.iter().map(|(_, imaged)| [imaged.start, imaged.end]).collect::<Vec<_>>(),
            "clutter_cut_offs_per_angle": done.clutter.iter().map(|per_angle| {
                per_angle.iter().map(|(low, high)| json!({"low": low, "high": high})).collect::<Vec<_>>()
            }).collect::<Vec<_>>(),
            "rule": format!(
                "too long to hold whole (--segment-frames, default: the frames whose image series \
                 fit in {} MiB): each segment imaged with the frames its dynamics windows and \
                 ensembles reach into, clutter-filtered on its own; power and lag-1 \
                 autocorrelation summed over the segments' own frames, velocities and vectors \
                 from the sums; windows and ensembles from the segment their start is in",
                pcuvd::segments::SERIES_BYTES >> 20
            ),
        }),
    };
    summary["ensembles"] = match (&plan.ensembles, &processed.ensembles) {
        (Some(spec), Some(maps)) => json!({
            "frames": spec.frames,
            "step_frames": spec.step,
            "count": maps.starts.len(),
            "duration_s": spec.frames as f64 / data.acquisition().frame_rate(),
            "times_s": maps.times_s,
            "start_frames": maps.starts,
            "clutter_cut_offs_per_angle": maps.clutter.iter().map(|per_angle| {
                per_angle.iter().map(|(low, high)| json!({"low": low, "high": high})).collect::<Vec<_>>()
            }).collect::<Vec<_>>(),
            "estimator": "IRLS-WLS (PC-UVD)",
        }),
        _ => {
            json!("none: the whole recording is one ensemble (--ensemble-frames for a time series)")
        }
    };
    summary
}

/// The dynamics stage's entry of summary.json.
fn dynamics_summary(plan: &Plan, processed: &Processed) -> serde_json::Value {
    let out = &processed.out;
    let (settings, series, maps) = match (&plan.dynamics, &processed.dynamics) {
        (Some(settings), DynamicsOutcome::Done { series, maps }) => (settings, series, maps),
        (_, DynamicsOutcome::Skipped(reason)) => return json!({ "skipped": reason }),
        (None, DynamicsOutcome::Done { .. }) => {
            return json!({ "skipped": "--dynamics off" });
        }
    };
    let (dparams, vessel) = (settings.params, settings.vessel);
    let count = |code: u8| maps.vessel_class.iter().filter(|&&c| c == code).count();
    json!({
        "heart_rate_hz": maps.heart_rate_hz,
        "heart_rate_given": dparams.heart_rate_hz.is_some(),
        "cycles_from": maps.cycle_source.describe(),
        "triggers_from": settings.triggers.as_ref().map(|(_, from)| from.as_str()),
        "cycles_count": maps.cycles.len(),
        "spread": "psv_spread.npy, edv_spread.npy, ri_spread.npy: standard deviation across the complete cycles of each cycle's PSV (m/s), EDV (m/s) and RI, each cycle's speed fitted on its own; NaN with one cycle",
        "window_frames": dparams.window,
        "step_frames": dparams.step,
        "window_s": series.window_s,
        "step_s": series.step_s,
        "harmonics": dparams.harmonics.unwrap_or_else(|| dynamics::auto_harmonics(maps.heart_rate_hz, series.window_s)),
        "estimator": "IRLS-WLS (PC-UVD)",
        "kernel": [dparams.kernel.0, dparams.kernel.1],
        "partial_volume": dparams.partial_volume,
        "artery_ri_min": dparams.artery_ri_min,
        "vein_ri_max": dparams.vein_ri_max,
        "vessel_threshold_db": dparams.min_power_db,
        "vessel_margin_db": db_or_off(vessel.margin_db),
        "vessel_margin_reference": "noise floor of each depth row of the power Doppler: its 30th percentile (doppler::noise_floor_by_depth)",
        "vessel_local_db": db_or_off(vessel.local_db),
        "vessel_local_radius_mm": vessel.local_radius_m * 1e3,
        "vessel_pooling": PoolingSummary::new(dparams.pooling, out.grid.step()),
        "cycles_windows": maps.cycles,
        "pixels": {
            "arteriole": count(dynamics::ARTERIOLE),
            "venule": count(dynamics::VENULE),
            "undetermined": count(dynamics::UNDETERMINED),
        },
        "class_codes": { "background": dynamics::BACKGROUND, "arteriole": dynamics::ARTERIOLE, "venule": dynamics::VENULE, "undetermined": dynamics::UNDETERMINED },
    })
}

/// Writes the dynamics stage's maps and figures into `dir` (nothing when it was skipped);
/// returns the figures written.
fn write_dynamics(
    dir: &Path,
    plan: &Plan,
    processed: &Processed,
    name: &str,
) -> Result<Vec<PathBuf>> {
    let (Some(settings), DynamicsOutcome::Done { series, maps }) =
        (&plan.dynamics, &processed.dynamics)
    else {
        return Ok(vec![]);
    };
    let out = &processed.out;
    let dparams = settings.params;
    npy(dir, "ri.npy", &maps.ri)?;
    npy(dir, "psv.npy", &maps.psv)?;
    npy(dir, "edv.npy", &maps.edv)?;
    npy(dir, "psv_spread.npy", &maps.psv_spread)?;
    npy(dir, "edv_spread.npy", &maps.edv_spread)?;
    npy(dir, "ri_spread.npy", &maps.ri_spread)?;
    pcuvd_io::write_npy(&dir.join("vessel_class.npy"), &maps.vessel_class)?;
    pcuvd_io::write_npy(&dir.join("flow_up.npy"), &maps.flow_up.mapv(u8::from))?;
    pcuvd_io::write_npy(&dir.join("speed_series.npy"), &series.speed())?;
    pcuvd_io::write_npy(
        &dir.join("times.npy"),
        &Array1::from(series.times_s.clone()),
    )?;
    let pngs = figures::dynamics_figures(dir, maps, series, &dparams, &out.grid, name)?;
    let count = |code: u8| maps.vessel_class.iter().filter(|&&c| c == code).count();
    println!(
        "RI maps: heart rate {:.2} Hz ({}), {} cycle(s); {} arteriole, {} venule, {} undetermined pixels",
        maps.heart_rate_hz,
        match maps.cycle_source {
            dynamics::CycleSource::GivenRate => "given",
            dynamics::CycleSource::Triggers => "from the cardiac triggers",
            dynamics::CycleSource::Upstrokes => "measured: systolic upstrokes",
            dynamics::CycleSource::Autocorrelation => "measured: autocorrelation",
        },
        maps.cycles.len(),
        count(dynamics::ARTERIOLE),
        count(dynamics::VENULE),
        count(dynamics::UNDETERMINED)
    );
    Ok(pngs)
}

/// Writes the Doppler time series: (ensembles, nz, nx) maps in SI units and their centre times.
fn write_ensembles(dir: &Path, maps: &pcuvd::ensembles::EnsembleMaps) -> Result<()> {
    pcuvd_io::write_npy(&dir.join("ensemble_power_doppler.npy"), &maps.power_doppler)?;
    pcuvd_io::write_npy(&dir.join("ensemble_color_doppler.npy"), &maps.color_doppler)?;
    if let (Some(vx), Some(vz), Some(speed)) = (&maps.vx, &maps.vz, maps.speed()) {
        pcuvd_io::write_npy(&dir.join("ensemble_vx.npy"), vx)?;
        pcuvd_io::write_npy(&dir.join("ensemble_vz.npy"), vz)?;
        pcuvd_io::write_npy(&dir.join("ensemble_speed.npy"), &speed)?;
    }
    pcuvd_io::write_npy(
        &dir.join("ensemble_times.npy"),
        &Array1::from(maps.times_s.clone()),
    )?;
    Ok(())
}

/// A vessel-test level (dB) as set: "off" for the infinite level that stands for it.
fn db_or_off(db: f64) -> serde_json::Value {
    if db.is_finite() {
        json!(db)
    } else {
        json!("off")
    }
}

fn npy(dir: &Path, name: &str, arr: &ndarray::Array2<f64>) -> Result<()> {
    pcuvd_io::write_npy(&dir.join(name), arr)?;
    Ok(())
}

/// Writes the maps as .npy (SI units).
pub fn write_maps(dir: &Path, out: &ProcessOutput) -> Result<()> {
    pcuvd_io::write_npy(&dir.join("x.npy"), &Array1::from(out.grid.x.clone()))?;
    pcuvd_io::write_npy(&dir.join("z.npy"), &Array1::from(out.grid.z.clone()))?;
    npy(dir, "bmode_db.npy", &out.bmode_db)?;
    npy(dir, "power_doppler.npy", &out.power_doppler)?;
    npy(dir, "color_doppler.npy", &out.color_doppler)?;
    pcuvd_io::write_npy(&dir.join("projections.npy"), &out.projections)?;
    pcuvd_io::write_npy(&dir.join("projection_nyquist.npy"), &out.projection_nyquist)?;
    if let (Some(ls), Some(irls)) = (&out.vector_ls, &out.vector_irls) {
        npy(dir, "vx.npy", &irls.vx)?;
        npy(dir, "vz.npy", &irls.vz)?;
        npy(dir, "speed.npy", &irls.speed())?;
        npy(dir, "vx_ls.npy", &ls.vx)?;
        npy(dir, "vz_ls.npy", &ls.vz)?;
        npy(dir, "speed_ls.npy", &ls.speed())?;
    }
    if let Some(done) = &out.dealias {
        pcuvd_io::write_npy(&dir.join("alias_counts.npy"), &done.irls.alias_counts)?;
        pcuvd_io::write_npy(&dir.join("alias_counts_ls.npy"), &done.ls.alias_counts)?;
    }
    Ok(())
}

/// The `dealias` entry of summary.json: the setting, the K used, the speeds it reaches, per
/// estimator how many flow pixels were dealiased, unwrapped, and reached ±K, and the warning for a
/// `coded` recording or one of too few angles ([`pcuvd::pipeline::dealias_warning`]; null
/// otherwise).
fn dealias_summary(params: &ProcessParams, out: &ProcessOutput, coded: bool) -> serde_json::Value {
    let warning = pcuvd::pipeline::dealias_warning(params.dealias, coded, out);
    let Some(done) = &out.dealias else {
        return json!({ "setting": params.dealias.label(), "warning": warning });
    };
    let counts = |c: &pcuvd::dealias::AliasCounts| {
        json!({
            "dealiased_pixels": c.dealiased_pixels,
            "unwrapped_pixels": c.unwrapped_pixels,
            "at_limit_pixels": c.at_limit_pixels,
        })
    };
    json!({
        "setting": params.dealias.label(),
        "intervals": done.intervals,
        "max_speed_m_s": (2 * done.intervals + 1) as f64 * out.nyquist_velocity,
        "flow_pixels": done.flow_pixels,
        "pcuvd_irls": counts(&done.irls),
        "uvd_ls": counts(&done.ls),
        "warning": warning,
        "rule": format!(
            "alias patterns up to ±K Nyquist intervals (2 v_N) per angle, from trial vectors; \
             scored by the estimator's unweighted objective (LS: sum of squared residuals, IRLS: \
             sum of absolute residuals); within a level a mixed pattern kept only where its \
             summed squared residual is below {} times the level's common shift's (even where \
             that shift's fit is beyond the speed limit; a pixel left without a level-0 \
             candidate keeps the plain fit unless another level's fits it with under that ratio \
             times the plain fit's squared residual); the common shift of all angles settled over the flow \
             pixels (power {} dB above the row's noise floor and within {} dB of the \
             brightest pixel within {} mm) by unwrapping the levels as a \
             phase map, most reliable joins first (Herraez et al. 2002), pixels next to non-flow \
             joined to speed 0 (blood is slow at a wall; pixels without candidates enclosed by \
             flow are holes, not wall; pixels whose angles' Nyquist velocities differ by more \
             than {}x take the level of the flow around them, or keep the plain fit outside \
             it), unless another common shift makes the \
             vessel's power-weighted summed residual less than {} times as large; regions under \
             {} pixels and other \
             pixels keep the plain fit; auto: the smallest K of 1-{} at which under {} % of the \
             unwrapped pixels reach ±K; alias_counts.npy (PC-UVD) and alias_counts_ls.npy (UVD) \
             hold the counts (angles, nz, nx)",
            pcuvd::dealias::MIXED_PATTERN_RATIO,
            pcuvd::dealias::FLOW_MARGIN_DB,
            pcuvd::dynamics::VESSEL_LOCAL_DB,
            pcuvd::dynamics::VESSEL_LOCAL_RADIUS_M * 1e3,
            pcuvd::dealias::NYQUIST_SPREAD_LIMIT,
            pcuvd::dealias::DECISIVE_SCORE_RATIO,
            pcuvd::dealias::MIN_REGION_PIXELS,
            pcuvd::dealias::MAX_AUTO_INTERVALS,
            pcuvd::dealias::AUTO_LIMIT_FRACTION * 100.0
        ),
    })
}

/// How the angles were transmitted, for summary.json and `pcuvd info`: `kind` "none",
/// "hadamard" (order, even slot delay) or "matrix" (the code's weights row by row, each slot's
/// start, the decoding gain g — decoded records are g × each angle's — and the condition number).
pub fn coding_json(seq: &pcuvd::Sequence) -> serde_json::Value {
    match &seq.coding {
        pcuvd::Coding::Conventional => json!({ "kind": "none" }),
        pcuvd::Coding::Hadamard { slot_delay } => json!({
            "kind": "hadamard", "order": seq.n_angles(), "slot_delay_s": slot_delay,
        }),
        pcuvd::Coding::Matrix(code) => json!({
            "kind": "matrix",
            "order": code.order(),
            "code_matrix": code.weights.chunks(code.order().max(1)).collect::<Vec<_>>(),
            "slot_starts_s": code.slot_starts,
            "events_fire_several_slots": code.is_coded(),
            "decoding_gain": code.decoding_gain(),
            "condition_number": code.condition_number(),
        }),
    }
}

/// The sampled transmit pulse for summary.json and `pcuvd info` (null when the sequence has
/// none): its sampling rate, length, and what pcuvd uses it for.
pub fn pulse_json(seq: &pcuvd::Sequence) -> serde_json::Value {
    match &seq.pulse {
        None => serde_json::Value::Null,
        Some(p) => json!({
            "sampling_frequency_hz": p.sampling_frequency,
            "n_samples": p.samples.len(),
            "duration_s": p.duration(),
            "used_for": "simulation (the echo waveform: the pulse through the probe's two-way response); processing does not need it",
        }),
    }
}

/// Every parameter used, the Nyquist velocity, clutter cut-offs and per-stage timings.
pub fn summary_json(
    data: &dyn FrameSource,
    params: &ProcessParams,
    out: &ProcessOutput,
    extra: serde_json::Value,
) -> serde_json::Value {
    let acq = data.acquisition();
    let probe = &acq.probe;
    let seq = &acq.sequence;
    let mut coding = coding_json(seq);
    if seq.is_coded() {
        coding["event_alignment"] = json!(params.event_alignment.label());
    }
    let timings: serde_json::Map<String, serde_json::Value> = out
        .timings
        .iter()
        .map(|(s, t)| (s.label().to_string(), json!(t)))
        .collect();
    json!({
        "units": "SI (m, s, Hz, m/s); colour Doppler and Vz positive = moving away from the probe (deeper)",
        "source": extra,
        "probe": {
            "name": probe.name, "n_elements": probe.n_elements, "pitch_m": probe.pitch,
            "element_width_m": probe.element_width, "center_frequency_hz": probe.center_frequency,
            "bandwidth": probe.bandwidth,
        },
        "acquisition": {
            "sampling_frequency_hz": acq.sampling_frequency, "sound_speed_m_s": acq.sound_speed,
            "t0_s": acq.t0, "event_prf_hz": seq.event_prf,
            "angles_deg": seq.angles.iter().map(|a| a.to_degrees()).collect::<Vec<_>>(),
            "coding": coding, "frames": data.n_frames(), "frame_rate_hz": acq.frame_rate(),
            "pulse_cycles": seq.pulse_cycles, "transmit_pulse": pulse_json(seq),
        },
        "grid": {
            "x_min_m": out.grid.x[0], "x_max_m": out.grid.x[out.grid.x.len() - 1],
            "z_min_m": out.grid.z[0], "z_max_m": out.grid.z[out.grid.z.len() - 1],
            "step_m": out.grid.step(),
            "nx": out.grid.x.len(), "nz": out.grid.z.len(),
        },
        "beamforming": { "f_number": params.das.f_number, "apodization": format!("{:?}", params.das.apodization) },
        "clutter_filter": {
            "low": format!("{:?}", params.clutter.low), "high": format!("{:?}", params.clutter.high),
            "tissue_frequency_fraction": params.clutter.tissue_frequency,
            "cut_offs_per_angle": out.clutter.iter().map(|r| json!({"low": r.low, "high": r.high})).collect::<Vec<_>>(),
        },
        "doppler": {
            "kernel": [params.doppler_kernel.0, params.doppler_kernel.1],
            "estimator": params.doppler_estimator.label(),
            "estimator_description": params.doppler_estimator.describe(),
            "partial_volume": params.partial_volume,
            // Each angle's intensity cell at one pixel (its speckle's) as the correction saw
            // it; null where it could not be measured.
            "partial_volume_cells": params.partial_volume.then(|| out.cells.iter().map(|c| c.map(|c| json!({
                "sigma_x_mm": c.xx.sqrt() * 1e3,
                "sigma_z_mm": c.zz.sqrt() * 1e3,
                "covariance_xz_mm2": c.xz * 1e6,
            }))).collect::<Vec<_>>()),
        },
        "irls": { "lambda_mm_s": params.irls.lambda_mm_s, "epsilon": params.irls.epsilon, "max_iterations": params.irls.max_iterations },
        "nyquist_velocity_m_s": out.nyquist_velocity,
        "dealias": dealias_summary(params, out, seq.is_coded()),
        "timings_s": timings,
    })
}

/// Gives the calling thread the lowest priority (nice 19), so that work beside the processing
/// runs on what the processing leaves idle (its serial stretches) instead of taking a core from
/// it. On Linux the nice value is per thread.
fn lower_this_threads_priority() {
    #[cfg(target_os = "linux")]
    // SAFETY: plain system calls on the calling thread's own id; a failure only leaves the
    // priority as it was.
    unsafe {
        libc::setpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t, 19);
    }
}
