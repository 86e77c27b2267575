//! `pcuvd info`: what pcuvd understood of a recording, without processing it.

use std::ops::Range;
use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use pcuvd::Coding;
use serde_json::json;

use crate::process::AcquisitionOverrides;
use pcuvd_app::input::open_input;

/// What `directivity_f_number` in `pcuvd info --json` is.
const DIRECTIVITY_F_NUMBER_RULE: &str = "1 / (2 tan θ) where the element's directivity \
    sinc(π w sin θ / λ)·cos θ (soft baffle, centre frequency) falls to −3 dB: the receive \
    f-number whose aperture edge hears echoes at half power";

/// Arguments of `pcuvd info`.
#[derive(Args, Debug)]
pub struct InfoArgs {
    /// Recording: MUST .mat (v5 or v7.3) or .npz, USTB .uff, zea .hdf5, a Verasonics workspace
    /// .mat, URX .urx, or a pcuvd recording manifest .toml; recognised from its content. Or
    /// beamformed images formed elsewhere: an images manifest (.toml, format "pcuvd-images"), or
    /// ConfUSIus's Zarr store of IQ (a .zarr folder with an `iq` array).
    pub input: PathBuf,
    /// Acquisition values given on the command line.
    #[command(flatten)]
    pub acquisition: AcquisitionOverrides,
    /// Print JSON (for programs) instead of text.
    #[arg(long)]
    pub json: bool,
    /// Memory a run at the defaults is checked against (GB), as `process --max-memory-gb`
    /// checks it: a warning says when the run would be refused, or would go without its RI maps;
    /// default: what the machine and the process's limits leave now.
    #[arg(long)]
    pub max_memory_gb: Option<f64>,
}

/// Slowest blood speed (m/s) a recording is expected to measure without aliasing: below this
/// projection Nyquist velocity, arterioles and larger vessels alias.
const LOW_NYQUIST_M_S: f64 = 20e-3;

/// Runs `pcuvd info`.
pub fn run(args: &InfoArgs) -> Result<()> {
    if pcuvd_io::open::is_images_input(&args.input) {
        return images_info(args);
    }
    let opened = open_input(&args.input, &args.acquisition.to_overrides())?;
    let source = opened.source.as_ref();
    let info = &opened.info;
    let files = &info.files;
    let acq = source.acquisition();
    let (probe, seq) = (&acq.probe, &acq.sequence);
    let frames = source.n_frames();
    let n_angles = seq.n_angles();
    let events = frames * n_angles;
    let (channels, samples) = source.trace_shape();
    let iq = info.stored.as_ref().is_some_and(|s| s.kind == "iq");
    let demod = info
        .parameter("demod_frequency_hz")
        .and_then(|p| p.value.as_f64());
    let (kind, bytes_per_sample) = if iq {
        ("IQ (complex)", 8usize)
    } else {
        ("RF (real)", 4usize)
    };
    let depth = pcuvd::pipeline::recorded_depth_of(acq, samples);
    let grid = pcuvd::pipeline::default_grid_for(acq, samples).ok();
    let (nz, nx) = grid.as_ref().map_or((0, 0), |g| g.shape());
    let input_bytes = events * channels * samples * bytes_per_sample;
    let memory_bytes = grid.as_ref().map_or(0, |g| {
        usize::try_from(pcuvd::pipeline::memory_estimate(source, g)).unwrap_or(usize::MAX)
    });
    let plan = pcuvd_app::run::Plan::new(
        &Default::default(),
        &Default::default(),
        source,
        info.cardiac_triggers_s.as_deref(),
    )
    .ok();
    let mut warnings = info.warnings.clone();
    // Counted after the memory check, which may space the windows or drop the stage: what the
    // run would hold.
    let mut cut = None;
    let stage_bytes = plan.map(|mut plan| {
        let checked = pcuvd_app::memory::check_memory(source, &mut plan, args.max_memory_gb);
        warnings.extend(memory_warning(checked, &plan));
        cut = Some(segment_cut(&plan, frames));
        pcuvd_app::memory::stage_memory_of(&plan, frames, seq.n_angles()) as u64
    });
    if demod.is_none()
        && let Some(warning) = pcuvd_app::input::band_pass_warning(acq)
    {
        warnings.push(warning);
    }
    if acq.nyquist_velocity() < LOW_NYQUIST_M_S {
        warnings.push(format!(
            "the projection Nyquist velocity is {:.1} mm/s: faster blood aliases (raise the PRF or \
             use fewer angles)",
            acq.nyquist_velocity() * 1e3
        ));
    }
    if frames < 2 {
        warnings.push("fewer than 2 frames: no Doppler estimate is possible".into());
    }
    // The first frame's peak, which `process` checks before it forms anything: a recording at a
    // scale single precision cannot hold is refused there, and said here.
    let peak = match (frames > 0).then(|| source.read_frames(0..1)) {
        Some(Ok(first)) => Some(first.samples.peak_of_first_events(n_angles)),
        Some(Err(error)) => {
            warnings.push(format!("the first frame could not be read: {error}"));
            None
        }
        None => None,
    };
    if let Some(reason) =
        peak.and_then(|p| pcuvd::core::lags::sample_peak_problem(p, "the samples of frame 0"))
    {
        warnings.push(format!("process would refuse it: {reason}"));
    }
    let coding = pcuvd_app::summary::CodingRecord::of(seq);
    let simulated = pcuvd_app::against_truth::scenario_beside(&args.input.to_string_lossy());
    let directivity_f_number = probe.directivity_f_number(-3.0, acq.sound_speed);
    let report = json!({
        "input": args.input.display().to_string(),
        "files": files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>(),
        "format": info.format,
        "reader": info.reader,
        "stored_samples": info.stored,
        "parameters": info.parameters,
        "samples": {
            "kind": kind,
            "shape_events_channels_samples": [events, channels, samples],
            "bytes_in_memory": input_bytes,
            "demodulation_frequency_hz": demod,
            "peak_of_first_frame": peak,
        },
        "probe": pcuvd_app::summary::ProbeRecord::of(probe),
        "acquisition": {
            "sampling_frequency_hz": acq.sampling_frequency,
            "sound_speed_m_s": acq.sound_speed,
            "t0_s": acq.t0,
            "angles_deg": seq.angles.iter().map(|a| a.to_degrees()).collect::<Vec<_>>(),
            "coding": coding,
            "pulse_cycles": seq.pulse_cycles,
            "transmit_pulse": pcuvd_app::summary::PulseRecord::of(seq),
            "event_prf_hz": seq.event_prf,
            "frames": frames,
            "frame_rate_hz": acq.frame_rate(),
            "duration_s": frames as f64 / acq.frame_rate(),
            "nyquist_velocity_m_s": acq.nyquist_velocity(),
            "recorded_depth_m": depth,
            "cardiac_triggers_s": info.cardiac_triggers_s,
        },
        "processing": {
            "default_grid_nz_nx": [nz, nx],
            "segments": cut.map(|(count, _, _)| count),
            "segment_frames": cut.map(|(_, imaged, _)| imaged),
            "directivity_f_number": directivity_f_number,
            "directivity_f_number_rule": DIRECTIVITY_F_NUMBER_RULE,
            "memory_estimate_bytes": memory_bytes,
            "memory_estimate_rule": pcuvd::pipeline::MEMORY_ESTIMATE_RULE,
            "stage_memory_estimate_bytes": stage_bytes,
            "stage_memory_estimate_rule": STAGE_MEMORY_AT_DEFAULTS,
        },
        "simulated_scenario": simulated.as_ref().map(|path| path.display().to_string()),
        "warnings": warnings,
    });
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    print_what_was_read(&args.input, info);
    println!(
        "  samples      {kind}, {events} events × {channels} channels × {samples} samples ({} as float){}{}",
        size(input_bytes),
        demod.map_or(String::new(), |f| format!(
            ", demodulated at {:.3} MHz",
            f * 1e-6
        )),
        peak.map_or(String::new(), |p| format!(", peak {p:.3e} in frame 0"))
    );
    println!(
        "  probe        {} ({} elements, pitch {:.3} mm, f_c {:.3} MHz, bandwidth {:.0} %)",
        probe.name,
        probe.n_elements,
        probe.pitch * 1e3,
        probe.center_frequency * 1e-6,
        probe.bandwidth * 100.0
    );
    println!(
        "  sampling     f_s {:.3} MHz, c {:.1} m/s, t0 {:.3} µs",
        acq.sampling_frequency * 1e-6,
        acq.sound_speed,
        acq.t0 * 1e6
    );
    let angles: Vec<String> = seq
        .angles
        .iter()
        .map(|a| format!("{:.2}", a.to_degrees()))
        .collect();
    println!("  angles (°)   {}", angles.join(", "));
    println!(
        "  coding       {}",
        match &seq.coding {
            Coding::Conventional => "none (one angle per event)".to_string(),
            Coding::Hadamard { slot_delay } => format!(
                "Hadamard order {n_angles}, slot delay {:.3} µs",
                slot_delay * 1e6
            ),
            Coding::Matrix(code) => format!(
                "explicit code matrix of order {n_angles}{} (decoded records are {:.0} × each \
                 angle's; condition number {:.3}), slot starts {} µs",
                if code.is_coded() {
                    ""
                } else {
                    " (one slot per event)"
                },
                code.decoding_gain(),
                code.condition_number(),
                code.slot_starts
                    .iter()
                    .map(|t| format!("{:.3}", t * 1e6))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            Coding::Decoded { polarity } => format!(
                "coded when fired, decoded in the file ({n_angles} angles per frame, all at the \
                 frame's decoding time; not decoded again), stored polarity {}",
                polarity
                    .iter()
                    .map(|&p| if p < 0.0 { "−" } else { "+" })
                    .collect::<String>()
            ),
        }
    );
    println!(
        "  timing       event PRF {:.1} Hz, {frames} frame{} at {:.1} Hz ({:.3} s)",
        seq.event_prf,
        if frames == 1 { "" } else { "s" },
        acq.frame_rate(),
        frames as f64 / acq.frame_rate()
    );
    println!(
        "  Doppler      projection Nyquist velocity {:.1} mm/s; recorded depth {:.2} mm",
        acq.nyquist_velocity() * 1e3,
        depth * 1e3
    );
    let segmented = match cut {
        Some(cut) if cut.0 > 1 => format!(", {}", segments_text(cut)),
        _ => String::new(),
    };
    println!(
        "  processing   default grid {nz} × {nx} pixels{segmented}; about {} of memory{}; the \
         element's −3 dB directivity edge is at F# {directivity_f_number:.2} (--f-number)",
        size(memory_bytes),
        stage_memory_text(stage_bytes)
    );
    if let Some(scenario) = &simulated {
        println!(
            "  simulation   the scenario `pcuvd simulate` wrote beside it, {}: `pcuvd process` \
             scores its maps against that truth",
            scenario.display()
        );
    }
    if let Some(times) = &info.cardiac_triggers_s {
        println!(
            "  cardiac      {} recorded triggers ([cardiac]): {} cycle{} from {:.3} to {:.3} s, used by the dynamics stage",
            times.len(),
            times.len() - 1,
            if times.len() == 2 { "" } else { "s" },
            times[0],
            times[times.len() - 1]
        );
    }
    print_parameters_and_warnings(info, &warnings);
    Ok(())
}

/// `b` bytes as `info` prints them: MB, or GB from a gigabyte on.
fn size(b: usize) -> String {
    if b >= 1_000_000_000 {
        format!("{:.2} GB", b as f64 / 1e9)
    } else {
        format!("{:.1} MB", b as f64 / 1e6)
    }
}

/// What the memory check of a run at the defaults (`checked`, leaving `plan` as it planned it)
/// means for the user, when it is not that the run fits.
fn memory_warning(checked: Result<()>, plan: &pcuvd_app::run::Plan) -> Option<String> {
    use pcuvd_app::run::DynamicsFit;
    match (checked, &plan.dynamics_fit) {
        (Err(e), _) => Some(format!(
            "at the defaults `pcuvd process` would refuse: {e:#}"
        )),
        (Ok(()), Some(DynamicsFit::Dropped(reason))) => Some(format!(
            "at the defaults `pcuvd process` would run without RI maps: {reason}"
        )),
        (Ok(()), Some(DynamicsFit::Stepped { reason, .. })) => Some(format!(
            "at the defaults `pcuvd process` would make its {reason}"
        )),
        (Ok(()), None) => None,
    }
}

/// What `info`'s stage memory estimate counts.
const STAGE_MEMORY_AT_DEFAULTS: &str = "the dynamics windows and time series of a run at the \
default settings (pcuvd_app::memory::STAGE_MEMORY_RULE), beside the memory estimate, as the \
memory check leaves the run (under --dynamics auto its windows spaced further apart, or none, \
where those of the default step would not fit: the warnings say so); null where the defaults \
cannot plan the run";

/// The stage memory estimate as `info` prints it after the images' memory, "" when there is none.
fn stage_memory_text(bytes: Option<u64>) -> String {
    match bytes {
        Some(bytes) if bytes > 0 => format!(
            " + {} for the dynamics windows at the defaults",
            size(bytes as usize)
        ),
        _ => String::new(),
    }
}

/// How a run planned by `plan` cuts a recording of `frames` frames: the segments' count, and the
/// frames imaged and of its own of the longest (all of them, in one, where it is held whole).
fn segment_cut(plan: &pcuvd_app::run::Plan, frames: usize) -> (usize, usize, usize) {
    let Some(planned) = plan.segments else {
        return (1, frames, frames);
    };
    let ranges = planned.ranges(frames);
    let longest =
        |len: fn(&(Range<usize>, Range<usize>)) -> usize| ranges.iter().map(len).max().unwrap_or(0);
    (
        ranges.len(),
        longest(|(_, imaged)| imaged.len()),
        longest(|(own, _)| own.len()),
    )
}

/// A run's segments as `info` prints them ([`segment_cut`]'s count, imaged and own frames).
fn segments_text((segments, imaged, own): (usize, usize, usize)) -> String {
    if own == imaged {
        format!("in {segments} segments of up to {imaged} frames")
    } else {
        format!(
            "in {segments} segments of up to {imaged} frames ({own} of their own, the rest \
             shared with the next for the windows that reach into it)"
        )
    }
}

/// `pcuvd info` on an images manifest: what pcuvd understood of beamformed images formed
/// elsewhere, from the manifest and the images file's header (the images are not read).
fn images_info(args: &InfoArgs) -> Result<()> {
    args.acquisition.refuse_for_images(&args.input)?;
    let header = pcuvd_io::open::read_images_header(&args.input)?;
    let info = &header.info;
    let (nz, nx) = header.grid.shape();
    let (x, z) = (&header.grid.x, &header.grid.z);
    // As a recording's: the projection's, whatever the angles.
    let nyquist = pcuvd::estimate::doppler::nyquist_velocity(
        header.sound_speed,
        header.frame_rate,
        header.demodulation_frequency,
    );
    // As `process` holds them by default: whole, or a segment at a time.
    let held = pcuvd::pipeline::segments::frames_held(header.frames, nz * nx, header.angles.len());
    let memory_bytes = 3 * header.bytes_of_frames(held);
    let opened =
        pcuvd_app::input::plan_images(header.clone(), &Default::default(), &Default::default())
            .ok();
    let mut warnings = info.warnings.clone();
    // The segments as the run cuts them (their own frames a multiple of the windows' step, and
    // the frames the windows reach past them): (count, frames imaged, own frames) of the
    // longest; as `frames_held` shares the recording where the defaults cannot plan the run.
    let mut cut = (header.frames.div_ceil(held.max(1)), held, held);
    // Counted after the memory check, as for a recording.
    let stage_bytes = opened.map(|mut opened| {
        let checked = opened.check_memory(args.max_memory_gb);
        warnings.extend(memory_warning(checked, &opened.plan));
        cut = segment_cut(&opened.plan, header.frames);
        pcuvd_app::memory::stage_memory_of(&opened.plan, header.frames, header.angles.len()) as u64
    });
    let (segments, imaged, own) = cut;
    if nyquist < LOW_NYQUIST_M_S {
        warnings.push(format!(
            "the projection Nyquist velocity is {:.1} mm/s: faster blood aliases",
            nyquist * 1e3
        ));
    }
    let angles_deg: Vec<f64> = header.angles.iter().map(|a| a.to_degrees()).collect();
    let duration = header.frames as f64 / header.frame_rate;
    let report = json!({
        "input": args.input.display().to_string(),
        "files": info.files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>(),
        "format": info.format,
        "reader": info.reader,
        "stored_samples": info.stored,
        "parameters": info.parameters,
        "images": {
            "angles_deg": angles_deg,
            "frames": header.frames,
            "frame_rate_hz": header.frame_rate,
            "duration_s": duration,
            "demodulation_frequency_hz": header.demodulation_frequency,
            "sound_speed_m_s": header.sound_speed,
            "grid_nz_nx": [nz, nx],
            "x_m": [x[0], x[nx - 1]],
            "z_m": [z[0], z[nz - 1]],
            "nyquist_velocity_m_s": nyquist,
            "cardiac_triggers_s": info.cardiac_triggers_s,
        },
        "processing": {
            "segments": segments,
            "segment_frames": imaged,
            "frames_held": held,
            "memory_estimate_bytes": memory_bytes,
            "memory_estimate_rule": pcuvd_app::memory::IMAGES_MEMORY_RULE,
            "stage_memory_estimate_bytes": stage_bytes,
            "stage_memory_estimate_rule": STAGE_MEMORY_AT_DEFAULTS,
        },
        "warnings": warnings,
    });
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    print_what_was_read(&args.input, info);
    let angles: Vec<String> = angles_deg.iter().map(|a| format!("{a:.2}")).collect();
    println!(
        "  images       beamformed elsewhere: {} series at {}°, {nz} × {nx} pixels (z {:.2} to \
         {:.2} mm, x {:.2} to {:.2} mm)",
        header.angles.len(),
        angles.join(", "),
        z[0] * 1e3,
        z[nz - 1] * 1e3,
        x[0] * 1e3,
        x[nx - 1] * 1e3
    );
    println!(
        "  timing       {} frames at {:.1} Hz ({duration:.3} s); IQ demodulated at {:.3} MHz, \
         c {:.1} m/s",
        header.frames,
        header.frame_rate,
        header.demodulation_frequency * 1e-6,
        header.sound_speed
    );
    println!(
        "  Doppler      projection Nyquist velocity {:.1} mm/s",
        nyquist * 1e3
    );
    let cut = match segments {
        1 => "held whole".to_string(),
        _ => segments_text((segments, imaged, own)),
    };
    println!(
        "  processing   {cut}, about {} of memory{} ({})",
        size(memory_bytes as usize),
        stage_memory_text(stage_bytes),
        pcuvd_app::memory::IMAGES_MEMORY_RULE
    );
    if let Some(times) = &info.cardiac_triggers_s {
        println!(
            "  cardiac      {} recorded triggers ([cardiac]), used by the dynamics stage",
            times.len()
        );
    }
    print_parameters_and_warnings(info, &warnings);
    Ok(())
}

/// The first lines of `info`'s text: the input, its format, reader and stored array.
fn print_what_was_read(input: &std::path::Path, info: &pcuvd_io::SourceInfo) {
    println!("{}", input.display());
    println!("  format       {}", info.format);
    println!("  reader       {}", info.reader);
    if let Some(st) = &info.stored {
        println!(
            "  stored       {} {:?} ({}) in {}",
            st.dtype,
            st.shape,
            st.axes.join(", "),
            st.array
        );
    }
}

/// The last lines of `info`'s text: every parameter with where it came from, then `warnings`.
fn print_parameters_and_warnings(info: &pcuvd_io::SourceInfo, warnings: &[String]) {
    println!("  parameters   (value: where it came from)");
    for p in &info.parameters {
        println!("    {:<24} {}: {}", p.name, p.value, p.source);
    }
    for w in warnings {
        println!("  warning: {w}");
    }
}
