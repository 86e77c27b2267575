//! `pcuvd bench`: each stage's throughput on this machine beside the bound that limits it, for a
//! speed report that shows regressions. Run by hand on a quiet machine, in a release build (CI
//! keeps its time budget and never runs it).
//!
//! Bounds: reading and decoding move the recording's bytes, so their bound is the memory
//! bandwidth measured here (one core copying a buffer far larger than the caches, and all cores
//! at once); the beamformer's work is counted as other beamformers publish it, points = pixels ×
//! elements × frames (all elements, every angle's image), with the active aperture (the elements
//! within the receive f-number's reach of each pixel) beside it, and its arithmetic bound: the
//! fused multiply-adds per second measured here on every core, over those the accumulation
//! kernel issues per active point.
//!
//! `--scenario` times the simulator instead: a scenario's recordings simulated as `pcuvd
//! simulate` does, block by block, and thrown away; the report counts scatterers and echoes (a
//! scatterer's echo on every channel, once per slot of an event) and the time per echo.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Args;
use pcuvd::pipeline::Stage;
use pcuvd_app::input::open_input;
use pcuvd_app::progress::Silent;
use pcuvd_app::run::Plan;
use pcuvd_app::settings::{DynamicsChoice, DynamicsSettings, ProcessingSettings};
use serde_json::json;

/// Arguments of `pcuvd bench`.
#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Recording to time (any format `pcuvd info` reads), processed with the processing options
    /// given (as `pcuvd process` takes them; its defaults otherwise) and no dynamics stage.
    #[arg(required_unless_present = "scenario")]
    pub input: Option<PathBuf>,
    /// Time the simulation of this scenario (a shipped one's name or a .toml file) instead,
    /// once, the modes the scenario says (or --mode).
    #[arg(long, conflicts_with = "input")]
    pub scenario: Option<String>,
    /// With --scenario: compound frames to simulate (default: the scenario's).
    #[arg(long, requires = "scenario")]
    pub frames: Option<usize>,
    /// With --scenario: the transmit mode(s) to simulate (default: the scenario's).
    #[arg(long, value_enum, requires = "scenario")]
    pub mode: Option<pcuvd_app::scenario::ModeChoice>,
    /// Runs to time; each stage reports its median.
    #[arg(long, default_value_t = 5)]
    pub repeat: usize,
    /// Also write the report as JSON (machine, commit-independent numbers) to this file.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Processing options, for a recording: what a candidate setting costs.
    #[command(flatten)]
    pub options: ProcessingSettings,
}

/// The CPU's model name and the instruction sets that matter here, from /proc/cpuinfo.
fn cpu() -> (String, Vec<&'static str>, usize) {
    let text = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let field = |name: &str| {
        text.lines()
            .find(|l| l.split(':').next().map(str::trim) == Some(name))
            .and_then(|l| l.split(':').nth(1))
            .map(|v| v.trim().to_string())
    };
    // Virtual machines often report a generic name ("Intel(R) Xeon(R) Processor"): the family
    // and model numbers tell one generation from another.
    let model = match (field("model name"), field("cpu family"), field("model")) {
        (Some(name), Some(family), Some(model)) => {
            format!("{name}, family {family} model {model}")
        }
        (Some(name), _, _) => name,
        _ => "unknown".to_string(),
    };
    let flags: Vec<&str> = text
        .lines()
        .find(|l| l.starts_with("flags"))
        .map(|l| l.split_whitespace().collect())
        .unwrap_or_default();
    let features = ["avx2", "fma", "avx512f", "sha_ni"]
        .into_iter()
        .filter(|f| flags.contains(f))
        .collect();
    (model, features, rayon::current_num_threads())
}

/// The vector instructions pcuvd's kernels use in this run: the CPU's widest, or the narrower
/// level that `PCUVD_SIMD` names (said so).
fn kernels_in_use() -> String {
    use pcuvd::core::simd::{Level, SIMD_VARIABLE, level};
    if level() < Level::detected() {
        format!("{} ({SIMD_VARIABLE})", level().name())
    } else {
        level().name().to_string()
    }
}

/// A note when `PCUVD_SIMD` (`value`) is set to a name of no level: the report would otherwise
/// time the CPU's widest kernels (`in_use`) where a narrower level was meant, and say so only
/// in its machine line.
fn unknown_simd_level(value: Option<&str>, in_use: pcuvd::core::simd::Level) -> Option<String> {
    use pcuvd::core::simd::{Level, SIMD_VARIABLE};
    let value = value?;
    Level::named(value).is_none().then(|| {
        format!(
            "note: {SIMD_VARIABLE}={value:?} names no level (avx512, avx2, portable): the kernels \
             use {}",
            in_use.name()
        )
    })
}

/// Memory bandwidth (bytes/s, read + written) of copying a 256 MiB buffer: one core, and every
/// core on its own share. The best of three.
fn memory_bandwidth() -> (f64, f64) {
    use rayon::prelude::*;
    let len = 256 << 20;
    let source = vec![1u8; len];
    let mut target = vec![0u8; len];
    let mut best = |parallel: bool| {
        (0..3)
            .map(|_| {
                let clock = Instant::now();
                if parallel {
                    let chunk = len / rayon::current_num_threads().max(1);
                    target
                        .par_chunks_mut(chunk)
                        .zip(source.par_chunks(chunk))
                        .for_each(|(t, s)| t.copy_from_slice(s));
                } else {
                    target.copy_from_slice(&source);
                }
                std::hint::black_box(&target);
                2.0 * len as f64 / clock.elapsed().as_secs_f64()
            })
            .fold(0.0, f64::max)
    };
    (best(false), best(true))
}

/// Bytes per second at which fresh memory is faulted in and cleared, on every core: 256 MiB
/// asked for anew and written once, less the time of writing it again. Measured before any
/// other buffer of the bench, as a run first touches its arrays. The copy bandwidth does not
/// show it, and it differs between machines more: on a virtual machine whose host takes freed
/// memory back, each page is backed again as it is touched.
fn fresh_memory_rate() -> f64 {
    use rayon::prelude::*;
    let len = 256 << 20;
    let chunk = len / rayon::current_num_threads().max(1);
    // Zeroed by the allocator: new pages, mapped as they are first written.
    let mut memory = vec![0u8; len];
    let mut fill = |value: u8| {
        let clock = Instant::now();
        memory.par_chunks_mut(chunk).for_each(|c| c.fill(value));
        std::hint::black_box(&memory);
        clock.elapsed().as_secs_f64()
    };
    let (first, again) = (fill(1), fill(2));
    len as f64 / (first - again).max(1e-9)
}

/// Fused multiply-add instructions per second on every core at once, `bits` wide (512: AVX-512,
/// 256: AVX2 + FMA), the best of three: twelve independent chains per thread, enough to keep
/// two FMA units busy through their latency. The beamformer's arithmetic bound is this rate
/// over its FMAs per point. `None` where the CPU lacks the width (or off x86-64).
fn fma_rate(bits: usize) -> Option<f64> {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        const CHAINS: usize = 12;
        const ROUNDS: usize = 2_000_000;

        #[target_feature(enable = "avx512f")]
        unsafe fn chains_512() -> f32 {
            let (x, y) = (_mm512_set1_ps(0.999_999), _mm512_set1_ps(1e-7));
            let mut acc = [_mm512_set1_ps(1.0); CHAINS];
            for _ in 0..ROUNDS {
                for a in acc.iter_mut() {
                    *a = _mm512_fmadd_ps(*a, x, y);
                }
            }
            acc.iter().map(|&a| _mm512_reduce_add_ps(a)).sum()
        }

        #[target_feature(enable = "avx2,fma")]
        unsafe fn chains_256() -> f32 {
            let (x, y) = (_mm256_set1_ps(0.999_999), _mm256_set1_ps(1e-7));
            let mut acc = [_mm256_set1_ps(1.0); CHAINS];
            for _ in 0..ROUNDS {
                for a in acc.iter_mut() {
                    *a = _mm256_fmadd_ps(*a, x, y);
                }
            }
            let mut lanes = [0.0f32; 8];
            acc.iter()
                .map(|&a| {
                    // SAFETY: `lanes` holds the 8 floats stored.
                    unsafe { _mm256_storeu_ps(lanes.as_mut_ptr(), a) };
                    lanes.iter().sum::<f32>()
                })
                .sum()
        }

        let chains: unsafe fn() -> f32 = match bits {
            512 if is_x86_feature_detected!("avx512f") => chains_512,
            256 if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") => {
                chains_256
            }
            _ => return None,
        };
        let best = (0..3)
            .map(|_| {
                let clock = Instant::now();
                // SAFETY: the instructions' features were detected above.
                let sums = rayon::broadcast(|_| unsafe { chains() });
                std::hint::black_box(sums);
                let fmas = (CHAINS * ROUNDS * rayon::current_num_threads()) as f64;
                fmas / clock.elapsed().as_secs_f64()
            })
            .fold(0.0, f64::max);
        Some(best)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = bits;
        None
    }
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied().unwrap_or(f64::NAN)
}

/// This process's CPU time so far (s): (user, system), from getrusage; NaN where there is none
/// (not Unix).
#[cfg(not(unix))]
fn cpu_times() -> (f64, f64) {
    (f64::NAN, f64::NAN)
}

/// This process's CPU time so far (s): (user, system), from getrusage.
#[cfg(unix)]
fn cpu_times() -> (f64, f64) {
    // SAFETY: getrusage writes one rusage into the zeroed struct it is given, nothing else.
    let usage = unsafe {
        let mut usage: libc::rusage = std::mem::zeroed();
        libc::getrusage(libc::RUSAGE_SELF, &mut usage);
        usage
    };
    let seconds = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    (seconds(usage.ru_utime), seconds(usage.ru_stime))
}

/// Times the simulation of `args.scenario`.
fn run_simulation(args: &BenchArgs, source: &str) -> Result<()> {
    use pcuvd::simulate::phantom::Phantom;
    use pcuvd_app::simulation::{Simulation, SimulationSettings};
    if args.options != ProcessingSettings::default() {
        bail!(
            "processing options time the processing of a recording; --scenario times a simulation"
        );
    }
    let (model, features, threads) = cpu();
    let settings = SimulationSettings {
        scenario: Some(source.to_string()),
        frames: args.frames,
        mode: args.mode,
        ..SimulationSettings::default()
    };
    let clock = Instant::now();
    let simulation = Simulation::new(&settings)?;
    let setup_s = clock.elapsed().as_secs_f64();
    let blood = simulation.phantom.n_scatterers();
    let tissue = simulation.tissue.as_ref().map_or(0, |t| t.n_scatterers());
    let mut echoes = 0.0;
    let mut events_total = 0;
    let clock = Instant::now();
    // In the blocks `pcuvd simulate` writes, thrown away.
    simulation.in_blocks(
        |index, events, samples| {
            let sequence = &simulation.modes[index].1.sequence;
            let slots = if sequence.is_coded() {
                sequence.n_angles()
            } else {
                1
            };
            echoes += ((blood + tissue) * slots * events.len()) as f64;
            events_total += events.len();
            std::hint::black_box(samples);
            Ok(())
        },
        &|_, _| {},
    )?;
    let simulate_s = clock.elapsed().as_secs_f64();
    let channels = simulation.modes[0].1.probe.n_elements;
    let (render, kernels) = (pcuvd::simulate::render_level(), pcuvd::core::simd::level());
    let report = json!({
        "scenario": source,
        "machine": { "cpu": model, "features": features, "threads": threads, "kernels": kernels_in_use() },
        "frames": simulation.frames,
        "modes": simulation.modes.iter().map(|(name, _)| *name).collect::<Vec<_>>(),
        "scatterers": { "blood": blood, "tissue": tissue },
        "events": events_total,
        "channels": channels,
        "echoes": echoes,
        "echoes_definition": "scatterers (blood and tissue) x events x slots per event (8 when \
            coded, 1 conventional): the echoes a direct simulation would render, each on every \
            channel; tissue is rendered at keyframes and interpolated, so it costs less",
        "setup_s": setup_s,
        "simulate_s": simulate_s,
        "ns_per_echo": simulate_s / echoes * 1e9,
        "render_kernels": render.name(),
        "peak_memory_bytes": pcuvd_app::memory::peak_resident_memory(),
    });
    println!(
        "pcuvd bench --scenario {source}: {} frames",
        simulation.frames
    );
    println!(
        "  machine      {model} ({}; {threads} threads; {} kernels)",
        features.join(", "),
        kernels_in_use()
    );
    if render != kernels {
        println!(
            "  render       {} kernels (measured faster than {} on this CPU, the same samples)",
            render.name(),
            kernels.name()
        );
    }
    println!("  scatterers   {blood} blood, {tissue} tissue");
    println!("  set-up       {setup_s:.1} s (tree, flow, scatterers, tissue)");
    println!(
        "  simulate     {simulate_s:.1} s: {events_total} events × {channels} channels, \
         {echoes:.3e} echoes, {:.2} ns per echo",
        simulate_s / echoes * 1e9
    );
    if let Some(bytes) = pcuvd_app::memory::peak_resident_memory() {
        println!("  memory       {:.0} MB at its peak", bytes as f64 / 1e6);
    }
    if let Some(path) = &args.json {
        pcuvd_io::write_json(path, &report)?;
    }
    Ok(())
}

/// Runs `pcuvd bench`.
pub fn run(args: &BenchArgs) -> Result<()> {
    if args.repeat == 0 {
        bail!("--repeat 0: time at least one run");
    }
    if cfg!(debug_assertions) {
        eprintln!(
            "note: this pcuvd is a debug build; time a release build (cargo build --release)"
        );
    }
    let simd = std::env::var(pcuvd::core::simd::SIMD_VARIABLE).ok();
    if let Some(note) = unknown_simd_level(simd.as_deref(), pcuvd::core::simd::level()) {
        eprintln!("{note}");
    }
    let input = match (&args.input, &args.scenario) {
        (_, Some(source)) => return run_simulation(args, source),
        (Some(input), None) => input,
        (None, None) => bail!("give a recording to time, or --scenario"),
    };
    let (model, features, threads) = cpu();
    let fresh = fresh_memory_rate();
    let (copy_one, copy_all) = memory_bandwidth();
    let kernel = pcuvd::form::beamform::accumulation_kernel();
    let fma_per_s = kernel.vector_bits.and_then(fma_rate);
    let mut stage_times: std::collections::BTreeMap<&'static str, Vec<f64>> = Default::default();
    let mut read_times = Vec::new();
    let mut total_times = Vec::new();
    // Per run, CPU seconds (user, system): the system's share is mostly pages faulted in, which
    // the first run pays for all the memory it touches and later runs partly reuse.
    let mut cpu_per_run = Vec::new();
    let dynamics = DynamicsSettings {
        dynamics: DynamicsChoice::Off,
        ..DynamicsSettings::default()
    };
    let mut shape = None;
    for _ in 0..args.repeat {
        let clock = Instant::now();
        let cpu_before = cpu_times();
        let opened = open_input(input, &pcuvd_io::Overrides::default())?;
        read_times.push(clock.elapsed().as_secs_f64());
        let data = opened.source.as_ref();
        let plan = Plan::new(&args.options, &dynamics, data, None)?;
        let processed = pcuvd_app::run(data, &plan, &Silent)
            .with_context(|| format!("{}: processing failed", input.display()))?;
        total_times.push(clock.elapsed().as_secs_f64());
        let cpu_after = cpu_times();
        cpu_per_run.push((cpu_after.0 - cpu_before.0, cpu_after.1 - cpu_before.1));
        for (stage, seconds) in &processed.out.timings {
            stage_times.entry(stage.label()).or_default().push(*seconds);
        }
        if shape.is_some() {
            continue;
        }
        // What the runs process, counted once (after the first run's timings are taken).
        let acq = data.acquisition();
        let grid = &plan.params.grid;
        let (nz, nx) = grid.shape();
        // Elements within each pixel's receive aperture, |x_e − x| ≤ z / (2 F#), summed.
        let element_x = acq.probe.element_x();
        let f_number = plan.params.das.f_number;
        let active: f64 = grid
            .z
            .iter()
            .map(|&z| {
                let half = z / (2.0 * f_number);
                grid.x
                    .iter()
                    .map(|&x| element_x.iter().filter(|&&e| (e - x).abs() <= half).count())
                    .sum::<usize>() as f64
            })
            .sum();
        let (channels, samples) = data.trace_shape();
        shape = Some((
            nz * nx,
            acq.probe.n_elements,
            data.n_frames() * acq.sequence.n_angles(),
            active / (nz * nx) as f64,
            data.n_frames() * acq.sequence.n_angles() * channels * samples * 4,
        ));
    }
    let (pixels, elements, images, mean_active, input_bytes) = shape.context("no run was timed")?;
    let stage = |s: Stage| median(stage_times.get(s.label()).cloned().unwrap_or_default());
    let beamform_s = stage(Stage::Beamform);
    let points = pixels as f64 * elements as f64 * images as f64;
    let decode_s = stage(Stage::Decode);
    let active_points_per_s = points * mean_active / elements as f64 / beamform_s;
    // Only active taps are summed: the bound is on active points.
    let arithmetic_bound = fma_per_s.zip(kernel.fma_per_point).map(|(r, k)| r / k);
    let cpu_median = (
        median(cpu_per_run.iter().map(|c| c.0).collect()),
        median(cpu_per_run.iter().map(|c| c.1).collect()),
    );
    let report = json!({
        "input": input.display().to_string(),
        "runs": args.repeat,
        "processing": &args.options,
        "machine": { "cpu": model, "features": features, "threads": threads, "kernels": kernels_in_use() },
        "memory_bandwidth_bytes_per_s": { "one_core": copy_one, "all_cores": copy_all },
        "fresh_memory_bytes_per_s": fresh,
        "recording": {
            "pixels": pixels, "elements": elements, "images": images,
            "samples_bytes_as_f32": input_bytes,
        },
        "median_s": {
            "read": median(read_times.clone()),
            "stages": stage_times.keys().map(|k| (k.to_string(), json!(median(stage_times[k].clone())))).collect::<serde_json::Map<_, _>>(),
            "total": median(total_times.clone()),
        },
        "throughput": {
            "decode_bytes_per_s": input_bytes as f64 / decode_s,
            "beamform_points_per_s": points / beamform_s,
            "beamform_active_points_per_s": active_points_per_s,
            "mean_active_aperture_elements": mean_active,
            "beamform_kernel": kernel.name,
            "beamform_fma_per_point": kernel.fma_per_point,
            "fma_per_s_all_cores": fma_per_s,
            "beamform_arithmetic_bound_active_points_per_s": arithmetic_bound,
        },
        "cpu_s": {
            "user_median": cpu_median.0,
            "system_median": cpu_median.1,
        },
        "first_run_s": {
            "total": total_times[0],
            "user": cpu_per_run[0].0,
            "system": cpu_per_run[0].1,
        },
        "peak_memory_bytes": pcuvd_app::memory::peak_resident_memory(),
    });
    println!(
        "pcuvd bench: {} ({} runs, medians)",
        input.display(),
        args.repeat
    );
    println!(
        "  machine      {model} ({}; {threads} threads; {} kernels)",
        features.join(", "),
        kernels_in_use()
    );
    println!(
        "  memory       copy {:.1} GB/s on one core, {:.1} GB/s on all (read + write); fresh \
         pages {:.1} GB/s on all (faulted in and cleared)",
        copy_one * 1e-9,
        copy_all * 1e-9,
        fresh * 1e-9
    );
    println!(
        "  read         {:.3} s (open and parse the file)",
        median(read_times)
    );
    println!(
        "  decode       {:.3} s: {:.2} GB/s of f32 samples ({:.0} % of one core's copy bandwidth)",
        decode_s,
        input_bytes as f64 / decode_s * 1e-9,
        100.0 * input_bytes as f64 / decode_s / copy_one
    );
    println!(
        "  beamform     {:.3} s: {:.2}e9 points/s ({pixels} pixels × {elements} elements × \
         {images} images), {:.2}e9 active points/s ({:.1} elements in each pixel's aperture)",
        beamform_s,
        points / beamform_s * 1e-9,
        active_points_per_s * 1e-9,
        mean_active
    );
    match (arithmetic_bound, fma_per_s, kernel.fma_per_point) {
        (Some(bound), Some(rate), Some(per_point)) => println!(
            "               arithmetic bound {:.1}e9 active points/s ({} kernel: {per_point} FMA \
             per point; {:.1}e9 FMA/s measured on all cores): at {:.0} % of it",
            bound * 1e-9,
            kernel.name,
            rate * 1e-9,
            100.0 * active_points_per_s / bound
        ),
        _ => println!(
            "               arithmetic bound not known ({} kernel)",
            kernel.name
        ),
    }
    for (label, times) in &stage_times {
        if *label != Stage::Decode.label() && *label != Stage::Beamform.label() {
            println!("  {label:<12} {:.3} s", median(times.clone()));
        }
    }
    println!(
        "  total        {:.3} s (read to vector maps, no figures); CPU {:.1} s user + {:.1} s \
         system",
        median(total_times.clone()),
        cpu_median.0,
        cpu_median.1,
    );
    if args.repeat > 1 {
        println!(
            "  first run    {:.3} s; CPU {:.1} s user + {:.1} s system (its memory faulted in \
             fresh, as one `pcuvd process` does)",
            total_times[0], cpu_per_run[0].0, cpu_per_run[0].1
        );
    }
    if let Some(path) = &args.json {
        pcuvd_io::write_json(path, &report)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::{fma_rate, unknown_simd_level};

    /// A name of no level is noted, naming the kernels used instead; a level's name, in any of
    /// its spellings, or no variable at all, is not.
    #[test]
    fn an_unknown_simd_level_is_noted() {
        use pcuvd::core::simd::Level;
        let note = unknown_simd_level(Some("sse4"), Level::Avx512).expect("a note");
        assert!(
            note.contains("\"sse4\" names no level") && note.ends_with("use AVX-512"),
            "{note}"
        );
        assert!(unknown_simd_level(Some(""), Level::Avx2).is_some());
        for known in ["avx2", "AVX-512", " portable "] {
            assert_eq!(
                unknown_simd_level(Some(known), Level::Avx2),
                None,
                "{known}"
            );
        }
        assert_eq!(unknown_simd_level(None, Level::Avx512), None);
    }

    #[test]
    fn the_fma_rate_is_measured_for_the_widths_this_cpu_has() {
        assert_eq!(fma_rate(128), None, "no kernel is 128 bits wide");
        #[cfg(target_arch = "x86_64")]
        {
            let avx2 = is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma");
            assert_eq!(fma_rate(256).is_some(), avx2);
            assert_eq!(fma_rate(512).is_some(), is_x86_feature_detected!("avx512f"));
            for rate in [fma_rate(256), fma_rate(512)].into_iter().flatten() {
                assert!(rate.is_finite() && rate > 0.0, "{rate}");
            }
        }
    }
}
