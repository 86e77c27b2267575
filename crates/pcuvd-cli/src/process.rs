//! `pcuvd process`: a recording in, maps, numbers and figures out. The options are the
//! application layer's settings ([`pcuvd_app::settings`]); the run is [`pcuvd_app::run`].

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;
use pcuvd_app::input::{check_first_frame, open_images, open_input};
use pcuvd_app::memory::check_memory;
use pcuvd_app::outputs;
use pcuvd_app::run::{Plan, Processed};
use pcuvd_app::settings::{DynamicsSettings, ProcessingSettings};
use pcuvd_app::summary::{
    EarlierRun, Provenance, Record, checksum_for, earlier_run, provenance, save,
};

use crate::progress::Bars;

/// Arguments of `pcuvd process`.
#[derive(Args, Debug)]
pub struct ProcessArgs {
    /// Recording: any format `pcuvd info` reads (MUST .mat v5/v7.3 or .npz, USTB .uff, zea .hdf5,
    /// a Verasonics workspace .mat, URX .urx, or a pcuvd recording manifest .toml); recognised
    /// by content. Or beamformed IQ images formed elsewhere, described by an images manifest
    /// (.toml, format "pcuvd-images") or held in ConfUSIus's Zarr store (a .zarr folder with an
    /// `iq` array): decoding and beamforming are then skipped.
    pub input: PathBuf,
    /// Output folder (created if needed; a folder that holds anything is refused unless --force).
    #[arg(long)]
    pub out: PathBuf,
    /// Reuse a non-empty output folder: pcuvd's own outputs of an earlier run there are removed
    /// first (no stale map beside the new summary.json); other files are never touched.
    #[arg(long)]
    pub force: bool,
    /// Memory processing may use (GB); default: the tightest of what the machine has available
    /// now, the process's address-space and data limits (ulimit -v, -d) and its control group's
    /// memory.max. Set it on a shared node whose job limit none of these shows.
    #[arg(long)]
    pub max_memory_gb: Option<f64>,
    /// The checksum that identifies each input file in summary.json (and lets a re-run skip a
    /// folder processed from the same input): xxh128 (xxh128sum), blake3 (b3sum), or sha256
    /// (sha256sum). Default: the kind an earlier run in --out recorded, else xxh128.
    #[arg(long, value_enum)]
    pub checksum: Option<outputs::Checksum>,
    /// Also write the maps and the time series as NIfTI images (.nii.gz) with fUSI-BIDS (BEP040)
    /// JSON sidecars, named by map (power_doppler.nii.gz…), as nibabel and BIDS tools read them.
    #[arg(long)]
    pub nifti: bool,
    /// Also write the run as one Zarr v3 store (pcuvd.zarr): the maps (z, x), the time series
    /// (time, z, x) and the velocity windows, in metres and seconds, as zarr and
    /// xarray.open_zarr read it. The time series go to the store as the run goes, in it only.
    #[arg(long)]
    pub zarr: bool,
    /// BIDS subject label: name the NIfTI images by BIDS entities (sub-<label>[_ses-…][_task-…]
    /// [_desc-…]_pwd.nii.gz for the power maps); implies --nifti.
    #[arg(long)]
    pub bids_subject: Option<String>,
    /// BIDS session label (with --bids-subject).
    #[arg(long)]
    pub bids_session: Option<String>,
    /// BIDS task label (with --bids-subject).
    #[arg(long)]
    pub bids_task: Option<String>,
    /// Acquisition values given on the command line.
    #[command(flatten)]
    pub acquisition: AcquisitionOverrides,
    /// Processing settings.
    #[command(flatten)]
    pub options: ProcessingSettings,
    /// Dynamics-stage settings.
    #[command(flatten)]
    pub dynamics: DynamicsSettings,
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
    /// Probe's two-way −6 dB fractional bandwidth (0.6 = 60 %), for a file that does not state
    /// it (pcuvd then takes 67 %, or the widest band the sampling holds) or states it wrongly.
    #[arg(long)]
    pub bandwidth: Option<f64>,
    /// The track to read from a file of several: zea / OpenH-RF, its index N (tracks/track_N) or
    /// its label; URX, the recorded group's index or description; default the first with raw
    /// data (`pcuvd info` lists them).
    #[arg(long)]
    pub track: Option<String>,
}

impl ProcessArgs {
    /// The checksum to identify the input by: `--checksum`, else, unless forced, the kind an
    /// earlier run in the folder recorded (a re-run then recognises it), else the default.
    fn checksum_kind(&self) -> outputs::Checksum {
        match self.force {
            true => self.checksum.unwrap_or_default(),
            false => checksum_for(&self.out, self.checksum),
        }
    }

    /// The NIfTI images asked for (`--nifti`, the BIDS labels), checked before any work.
    fn nifti_naming(&self) -> Result<Option<pcuvd_app::nifti::NiftiNaming>> {
        pcuvd_app::nifti::NiftiNaming::requested(
            self.nifti,
            self.bids_subject.clone(),
            self.bids_session.clone(),
            self.bids_task.clone(),
        )
    }

    /// The name the figures carry: the input file's.
    fn figure_name(&self) -> String {
        self.input
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    }
}

impl AcquisitionOverrides {
    /// Refuses overrides given for the images manifest at `input`: they set how channel data
    /// is read, and images come formed.
    pub fn refuse_for_images(&self, input: &std::path::Path) -> Result<()> {
        if !self.to_overrides().is_empty() {
            anyhow::bail!(
                "{}: the acquisition overrides (--t0-s, --event-prf-hz...) are not for beamformed \
                 images formed elsewhere: the images are formed",
                input.display()
            );
        }
        Ok(())
    }

    /// The overrides as the readers take them.
    pub fn to_overrides(&self) -> pcuvd_io::Overrides {
        pcuvd_io::Overrides {
            t0_s: self.t0_s,
            sound_speed_m_s: self.sound_speed_m_s,
            event_prf_hz: self.event_prf_hz,
            sampling_freq_hz: self.sampling_freq_hz,
            center_freq_hz: self.center_freq_hz,
            demod_freq_hz: self.demod_freq_hz,
            bandwidth: self.bandwidth,
            track: self.track.clone(),
            ..pcuvd_io::Overrides::default()
        }
    }
}

/// Runs `pcuvd process`.
pub fn run(args: &ProcessArgs) -> Result<()> {
    if pcuvd_io::open::is_images_input(&args.input) {
        return run_on_images(args);
    }
    let clock = std::time::Instant::now();
    // Checked before any work, like every other option.
    let nifti = args.nifti_naming()?;
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
    let band_warning = check_first_frame(data).with_context(|| args.input.display().to_string())?;
    check_memory(data, &mut plan, args.max_memory_gb)?;
    let checksum = args.checksum_kind();
    let provenance_of_run = {
        let (input, info) = (args.input.display().to_string(), opened.info.clone());
        let options_text = plan.options_text.clone();
        move |hashed: Vec<(std::path::PathBuf, pcuvd_io::Checksummed)>| {
            let clock = std::time::Instant::now();
            let command_line = std::env::args().collect();
            let source = provenance(
                &input,
                &info,
                &options_text,
                command_line,
                checksum,
                &hashed,
            );
            let hashing_s: f64 = hashed.iter().map(|(_, done)| done.seconds).sum();
            source.map(|source| (source, hashing_s + clock.elapsed().as_secs_f64()))
        }
    };
    // The checksums read the whole input (XXH3: about 0.2 s of a core for 2.8 GB, BLAKE3 with
    // SIMD 0.8 s, SHA-256 without SHA instructions 10 s). They are needed before any work only
    // to skip a folder processed before. Otherwise a reader that reads its samples file block by
    // block hashes it as it reads it (each run of a block while it is in cache), so that the
    // file is not read twice. Other inputs, and SHA-256 (without SHA instructions many times
    // the others' time, which the reader's pass would hold the other core idle for), are hashed
    // beside the processing, on a thread of their own that takes only the time the processing
    // leaves idle.
    let in_pass = opened
        .read_pass
        .clone()
        .filter(|_| checksum != outputs::Checksum::Sha256);
    let checksums = if !args.force && args.out.join("summary.json").is_file() {
        let (source, seconds) = provenance_of_run(vec![])?;
        if already_processed(&args.out, &source)? {
            return Ok(());
        }
        Checksums::Done(Box::new(source), seconds)
    } else if let Some(pass) = in_pass {
        pass.attach(Box::new(outputs::Digest::on_every_core(checksum)));
        Checksums::InPass(pass, Box::new(provenance_of_run))
    } else {
        Checksums::Running(std::thread::spawn(move || {
            lower_this_threads_priority();
            provenance_of_run(vec![])
        }))
    };
    let made_out = !args.out.exists();
    outputs::prepare(
        &args.out,
        outputs::PROCESS_OUTPUTS,
        &input_files,
        args.force,
    )?;
    let name = args.figure_name();
    // Said once the run is accepted (not before an error, which stays the only line).
    if let Some(warning) = band_warning {
        eprintln!("warning: {}: {warning}", args.input.display());
    }
    let mut zarr = match args.zarr {
        true => Some(pcuvd_app::zarr::ZarrStore::create(
            &args.out.join(pcuvd_app::zarr::STORE),
            pcuvd_app::summary::RunInput::Recording(data),
            &plan,
        )?),
        false => None,
    };
    let progress = Bars::new("");
    let sink = zarr
        .as_mut()
        .map(|z| z as &mut dyn pcuvd::pipeline::segments::EnsembleSink);
    let processed = pcuvd_app::run_into(data, &plan, &progress, sink)
        .inspect_err(|_| outputs::remove_if_empty(&args.out, made_out))
        .with_context(|| format!("{}: processing failed", args.input.display()))?;
    let coded = data.acquisition().sequence.is_coded();
    if let Some(warning) =
        pcuvd::pipeline::dealias_warning(plan.params.dealias, coded, &processed.out)
    {
        eprintln!("warning: {}: {warning}", args.input.display());
    }
    let (source, checksum_s) = match checksums {
        Checksums::Done(source, seconds) => (*source, seconds),
        Checksums::InPass(pass, provenance_of_run) => {
            let cannot = || format!("{}: cannot read for its checksum", pass.path().display());
            let done = pass.finish().with_context(cannot)?.with_context(cannot)?;
            provenance_of_run(vec![(pass.path().to_path_buf(), done)])?
        }
        Checksums::Running(thread) => thread
            .join()
            .map_err(|_| anyhow::anyhow!("the checksum thread failed"))??,
    };
    let extra_timings = [("read", read_s), ("checksum", checksum_s)];
    let record = Record {
        source,
        name: &name,
        extra_timings: &extra_timings,
        nifti: nifti.as_ref(),
        zarr,
        simulated_from: None,
    };
    let saved = save(
        &args.out,
        pcuvd_app::summary::RunInput::Recording(data),
        &plan,
        &processed,
        record,
        &progress,
    )?;
    let (angles, frames) = (data.acquisition().sequence.n_angles(), data.n_frames());
    println!(
        "{}: {angles} angle{}, {frames} frame{} at {:.1} Hz; Nyquist velocity {:.1} mm/s; grid {} x \
         {} pixels (depth x lateral)",
        args.input.display(),
        if angles == 1 { "" } else { "s" },
        if frames == 1 { "" } else { "s" },
        data.acquisition().frame_rate(),
        processed.out.maps.nyquist_velocity * 1e3,
        processed.out.grid.z.len(),
        processed.out.grid.x.len()
    );
    if let Some(scored) = &saved.against_truth {
        println!("{}", scored.line());
    }
    say_written(&args.out, saved.figures.len());
    failed_after_saving(&args.input, &args.out, &processed)
}

/// `pcuvd process` on an images manifest: beamformed images formed elsewhere, read whole or a
/// segment at a time, their
/// chain from the clutter filter on (nothing to decode or beamform), with the maps, figures,
/// RI maps, report and summary.json a recording's run writes.
fn run_on_images(args: &ProcessArgs) -> Result<()> {
    let clock = std::time::Instant::now();
    args.acquisition.refuse_for_images(&args.input)?;
    let nifti = args.nifti_naming()?;
    let mut opened = open_images(&args.input, &args.options, &args.dynamics)?;
    opened
        .check_memory(args.max_memory_gb)
        .with_context(|| args.input.display().to_string())?;
    let read_s = clock.elapsed().as_secs_f64();
    let plan = opened.plan;
    let (input, info) = (args.input.display().to_string(), opened.info.clone());
    let (options_text, checksum) = (plan.options_text.clone(), args.checksum_kind());
    let provenance_of_run = move || {
        let clock = std::time::Instant::now();
        let command_line = std::env::args().collect();
        let source = provenance(&input, &info, &options_text, command_line, checksum, &[]);
        source.map(|source| (source, clock.elapsed().as_secs_f64()))
    };
    let checksums = if !args.force && args.out.join("summary.json").is_file() {
        let (source, seconds) = provenance_of_run()?;
        if already_processed(&args.out, &source)? {
            return Ok(());
        }
        Checksums::Done(Box::new(source), seconds)
    } else {
        Checksums::Running(std::thread::spawn(move || {
            lower_this_threads_priority();
            provenance_of_run()
        }))
    };
    let made_out = !args.out.exists();
    outputs::prepare(
        &args.out,
        outputs::PROCESS_OUTPUTS,
        &opened.info.files,
        args.force,
    )?;
    let record_of_images = opened.record;
    let mut zarr = match args.zarr {
        true => Some(pcuvd_app::zarr::ZarrStore::create(
            &args.out.join(pcuvd_app::zarr::STORE),
            pcuvd_app::summary::RunInput::Images(&record_of_images),
            &plan,
        )?),
        false => None,
    };
    let progress = Bars::new("");
    let sink = zarr
        .as_mut()
        .map(|z| z as &mut dyn pcuvd::pipeline::segments::EnsembleSink);
    let processed = pcuvd_app::run::run_images_into(&opened.images, &plan, &progress, sink)
        .inspect_err(|_| outputs::remove_if_empty(&args.out, made_out))
        .with_context(|| format!("{}: processing failed", args.input.display()))?;
    if let Some(warning) =
        pcuvd::pipeline::dealias_warning(plan.params.dealias, false, &processed.out)
    {
        eprintln!("warning: {}: {warning}", args.input.display());
    }
    let (source, checksum_s) = match checksums {
        Checksums::Done(source, seconds) => (*source, seconds),
        Checksums::Running(thread) => thread
            .join()
            .map_err(|_| anyhow::anyhow!("the checksum thread failed"))??,
        Checksums::InPass(..) => unreachable!("images are hashed apart, not in a reader's pass"),
    };
    let name = args.figure_name();
    let extra_timings = [("read", read_s), ("checksum", checksum_s)];
    let record = Record {
        source,
        name: &name,
        extra_timings: &extra_timings,
        nifti: nifti.as_ref(),
        zarr,
        simulated_from: None,
    };
    let saved = pcuvd_app::summary::save(
        &args.out,
        pcuvd_app::summary::RunInput::Images(&record_of_images),
        &plan,
        &processed,
        record,
        &progress,
    )?;
    let angles = record_of_images.angles_deg.len();
    println!(
        "{}: beamformed images, {angles} angle{}, {} frames at {:.1} Hz; Nyquist velocity {:.1} \
         mm/s; grid {} x {} pixels (depth x lateral)",
        args.input.display(),
        if angles == 1 { "" } else { "s" },
        record_of_images.frames,
        record_of_images.frame_rate_hz,
        processed.out.maps.nyquist_velocity * 1e3,
        processed.out.grid.z.len(),
        processed.out.grid.x.len()
    );
    say_written(&args.out, saved.figures.len());
    failed_after_saving(&args.input, &args.out, &processed)
}

/// The error a run ends in once its results are written, when the RI maps a dynamics setting
/// asked for could not be made from the recording (only the data could tell, after the work).
fn failed_after_saving(
    input: &std::path::Path,
    out: &std::path::Path,
    processed: &Processed,
) -> Result<()> {
    match processed.dynamics_failure() {
        Some(reason) => bail!(
            "{}: the RI maps asked for (--dynamics on, or a dynamics option given) could not be \
             made: {reason}; the run's other maps, figures and summary.json are written to {}",
            input.display(),
            out.display()
        ),
        None => Ok(()),
    }
}

/// True, and said, when `out` holds an earlier run of the same input (checksums), options and
/// pcuvd version: a batch re-run skips it. Where that run's RI maps could not be made, the
/// error it ended in.
fn already_processed(out: &std::path::Path, source: &Provenance) -> Result<bool> {
    match earlier_run(out, source) {
        EarlierRun::None => Ok(false),
        EarlierRun::Done => {
            println!(
                "{}: already processed from the same input (checksums) with the same options and \
                 pcuvd version (summary.json); skipped (--force redoes it)",
                out.display()
            );
            Ok(true)
        }
        EarlierRun::DynamicsFailed(reason) => bail!(
            "{}: an earlier run of the same input (checksums), options and pcuvd version wrote its \
             other outputs here, and the RI maps asked for (--dynamics on, or a dynamics option \
             given) could not be made: {reason} (--force runs it again)",
            out.display()
        ),
    }
}

/// Says what a run wrote into `out`.
fn say_written(out: &std::path::Path, figures: usize) {
    println!(
        "wrote maps (.npy), summary.json, {} and {figures} figures to {}",
        pcuvd_app::summary::REPORT,
        out.display()
    );
}

/// What makes the input's provenance from the checksums the reader computed in its pass.
type ProvenanceOfRun =
    dyn FnOnce(Vec<(std::path::PathBuf, pcuvd_io::Checksummed)>) -> Result<(Provenance, f64)>;

/// The input's provenance with its checksums, and the seconds they took: computed, being computed
/// by the reader as it reads the samples file (the other files hashed at the end), or being
/// computed beside the processing.
enum Checksums {
    Done(Box<Provenance>, f64),
    InPass(pcuvd_io::ReadPass, Box<ProvenanceOfRun>),
    Running(std::thread::JoinHandle<Result<(Provenance, f64)>>),
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
