//! `pcuvd process`: a recording in, maps, numbers and figures out.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;
use ndarray::Array1;
use pcuvd::ChannelData;
use pcuvd::dynamics::{self, DynamicsParams, PoolingSummary, RiMaps, VelocitySeries, VesselTests};
use pcuvd::pipeline::{self, ProcessOutput, ProcessParams};
use pcuvd::source::FrameSource;
use serde_json::json;

use crate::figures;
use crate::options::{DynamicsChoice, DynamicsOptions, ProcessingOptions};
use crate::outputs;
use crate::progress::PipelineProgress;

/// Arguments of `pcuvd process`.
#[derive(Args, Debug)]
pub struct ProcessArgs {
    /// Recording: a MUST-style MATLAB v5 file (.mat, variables RF and param) or a pcuvd recording manifest (.toml).
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
    pub options: ProcessingOptions,
    #[command(flatten)]
    pub dynamics: DynamicsOptions,
}

/// Reads a recording by its extension: `.mat` (MUST style) or `.toml` (pcuvd manifest). Returns
/// the data and every file it was read from (the manifest and its samples).
pub fn read_input(path: &Path) -> Result<(ChannelData, Vec<PathBuf>)> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    let (data, files) = match ext.as_str() {
        "mat" => (pcuvd_io::read_must_mat(path)?, vec![path.to_path_buf()]),
        "toml" => {
            let recording = pcuvd_io::read_recording(path)?;
            (
                recording.data,
                vec![path.to_path_buf(), recording.data_path],
            )
        }
        _ => bail!(
            "{}: unknown recording type: expected a MUST-style .mat file or a pcuvd manifest .toml",
            path.display()
        ),
    };
    Ok((data, files))
}

/// Opens a recording for `process`: a pcuvd manifest whose samples are stored in event order is
/// read from its file a block of frames at a time (never whole in memory); anything else is read
/// whole ([`read_input`]). Returns the source and every file it reads.
pub fn open_input(path: &Path) -> Result<(Box<dyn FrameSource>, Vec<PathBuf>)> {
    let manifest = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("toml"));
    if manifest && let Some(frames) = pcuvd_io::ManifestFrames::open(path)? {
        let files = vec![path.to_path_buf(), frames.data_path().to_path_buf()];
        return Ok((Box::new(frames), files));
    }
    let (data, files) = read_input(path)?;
    Ok((Box::new(data), files))
}

/// Creates `dir` (and parents), with a message naming it on failure.
pub fn create_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir)
        .with_context(|| format!("{}: cannot create the output folder", dir.display()))
}

/// Runs `pcuvd process`.
pub fn run(args: &ProcessArgs) -> Result<()> {
    let clock = std::time::Instant::now();
    let (source, input_files) = open_input(&args.input)?;
    let data = source.as_ref();
    let read_s = clock.elapsed().as_secs_f64();
    let plan = Plan::new(&args.options, &args.dynamics, data)?;
    check_memory(data, &plan.params, args.max_memory_gb)?;
    let clock = std::time::Instant::now();
    let (format, reader) = match input_files.len() {
        1 => ("MUST-style MATLAB v5 (.mat)", "pcuvd_io::read_must_mat"),
        _ if data.resident_bytes() == 0 => (
            "pcuvd recording manifest (.toml) + NumPy .npy",
            "pcuvd_io::ManifestFrames (a block of frames at a time)",
        ),
        _ => (
            "pcuvd recording manifest (.toml) + NumPy .npy",
            "pcuvd_io::read_recording",
        ),
    };
    let source = provenance(
        &args.input.display().to_string(),
        &input_files,
        (format, reader),
        &plan.options_text,
        std::env::args().collect(),
    )?;
    let checksum_s = clock.elapsed().as_secs_f64();
    if !args.force && already_done(&args.out, &source) {
        println!(
            "{}: already processed from the same input (checksums) with the same options and \
             pcuvd version (summary.json); skipped (--force redoes it)",
            args.out.display()
        );
        return Ok(());
    }
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
    let progress = PipelineProgress::new("");
    let processed = compute(data, &plan, &|s, d, t| progress.update(s, d, t))
        .with_context(|| format!("{}: processing failed", args.input.display()))?;
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
}

impl Plan {
    /// Reads and checks the options against the recording `data`, before the long processing.
    pub fn new(
        options: &ProcessingOptions,
        dynamics: &DynamicsOptions,
        data: &dyn FrameSource,
    ) -> Result<Plan> {
        let params = options.params(data)?;
        let dynamics_settings = if dynamics.dynamics == DynamicsChoice::Off {
            None
        } else {
            Some(DynamicsSettings {
                params: pcuvd::dynamics::DynamicsParams {
                    // The windows read velocity as the whole-recording maps do.
                    doppler: params.doppler_estimator,
                    ..dynamics.params(
                        data.acquisition().frame_rate(),
                        params.irls,
                        params.grid.step(),
                    )?
                },
                vessel: dynamics.vessel_tests()?,
            })
        };
        Ok(Plan {
            ensembles: options.ensembles(data.n_frames())?,
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
    })
}

/// The dynamics stage on the chain's maps `out`, as `plan` says (see [`compute`]).
pub fn run_dynamics(out: &ProcessOutput, plan: &Plan) -> Result<DynamicsOutcome> {
    Ok(match &plan.dynamics {
        None => DynamicsOutcome::Skipped("--dynamics off".into()),
        Some(settings) => match pipeline::dynamics(out, &settings.params, &settings.vessel) {
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

/// Refuses, before any work, a recording and grid whose processing would need more memory than
/// the machine has available ([`pipeline::memory_estimate`]), instead of aborting on allocation.
pub fn check_memory(
    data: &dyn FrameSource,
    params: &ProcessParams,
    limit_gb: Option<f64>,
) -> Result<()> {
    let available = match limit_gb {
        Some(gb) if gb.is_finite() && gb > 0.0 => Some(gb * 1e9),
        Some(gb) => bail!("--max-memory-gb {gb}: must be a positive number of GB"),
        None => available_memory().map(|b| b as f64),
    };
    let needed = pipeline::memory_estimate(data, &params.grid) as f64;
    if let Some(available) = available
        && needed > available
    {
        bail!(
            "processing needs about {:.3} GB ({}) but {:.3} GB are available: use a coarser or \
             smaller --grid, or a shorter recording",
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
/// size and SHA-256, the format and the reader (`format_reader`) that read it, and the options.
pub fn provenance(
    input: &str,
    input_files: &[PathBuf],
    format_reader: (&str, &str),
    options_text: &str,
    command_line: Vec<String>,
) -> Result<serde_json::Value> {
    let files = input_files
        .iter()
        .map(|path| {
            let (size, sha256) = outputs::fingerprint(path)?;
            Ok(json!({ "path": path.display().to_string(), "size_bytes": size, "sha256": sha256 }))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(json!({
        "input": input,
        "format": format_reader.0,
        "reader": format_reader.1,
        "files": files,
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
            "images formed a block of frames at a time: as many frames as fit in {} MiB of \
             decoding and IQ (the whole recording when it fits), with {} frames decoded on either \
             side of a block of a coded recording aligned at mid-frame",
            pipeline::BLOCK_BYTES >> 20,
            pcuvd::source::Blocks::ALIGNMENT_MARGIN
        ),
    });
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
        "window_frames": dparams.window,
        "step_frames": dparams.step,
        "window_s": series.window_s,
        "step_s": series.step_s,
        "harmonics": dparams.harmonics.unwrap_or_else(|| dynamics::auto_harmonics(maps.heart_rate_hz, series.window_s)),
        "estimator": "IRLS-WLS (PC-UVD)",
        "kernel": [dparams.kernel.0, dparams.kernel.1],
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
        "RI maps: heart rate {:.2} Hz, {} cycle(s); {} arteriole, {} venule, {} undetermined pixels",
        maps.heart_rate_hz,
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
    if let (Some(ls), Some(irls)) = (&out.vector_ls, &out.vector_irls) {
        npy(dir, "vx.npy", &irls.vx)?;
        npy(dir, "vz.npy", &irls.vz)?;
        npy(dir, "speed.npy", &irls.speed())?;
        npy(dir, "vx_ls.npy", &ls.vx)?;
        npy(dir, "vz_ls.npy", &ls.vz)?;
        npy(dir, "speed_ls.npy", &ls.speed())?;
    }
    Ok(())
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
    let coding = match seq.coding {
        pcuvd::Coding::Conventional => json!({ "kind": "none" }),
        pcuvd::Coding::Hadamard { slot_delay } => json!({
            "kind": "hadamard", "order": seq.n_angles(), "slot_delay_s": slot_delay,
            "event_alignment": params.event_alignment.label(),
        }),
    };
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
        "doppler": { "kernel": [params.doppler_kernel.0, params.doppler_kernel.1] },
        "irls": { "lambda_mm_s": params.irls.lambda_mm_s, "epsilon": params.irls.epsilon, "max_iterations": params.irls.max_iterations },
        "nyquist_velocity_m_s": out.nyquist_velocity,
        "timings_s": timings,
    })
}
