//! `pcuvd paper`: the paper's spiral-flow study (§2.3, §3) end to end, with its figures and numbers.
//!
//! Conventional and Hadamard-coded acquisitions of the same spiral (same scatterers, same motion,
//! same noise statistics) are simulated, processed with no clutter filter (the phantom has no
//! tissue, as in the paper) and compared with the ground truth.
//!
//! Everything up to the Doppler autocorrelation (decoding, demodulation, beamforming) is linear in
//! the channel data, so the echoes and a unit noise field are beamformed apart, once per mode, and
//! combined as S + g·N for every noise level of the sweep: the sweep then costs only the Doppler and
//! vector stages, and every level sees the same scatterers and the same noise realisation.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Args;
use ndarray::{Array2, Array3, Zip};
use num_complex::Complex32;
use pcuvd::beamform::{DasParams, Grid};
use pcuvd::clutter::{ClutterParams, RankCut};
use pcuvd::decode::EventAlignment;
use pcuvd::phantom::{FrameHeld, Phantom, SpiralPhantom, Truth};
use pcuvd::pipeline::{self, ProcessOutput, ProcessParams};
use pcuvd::simulate::{self, NOISE_DEFINITION, NoiseSpec, SimParams};
use pcuvd::vector::{IrlsParams, VectorField};
use pcuvd_render::{
    Colormap, Figure, Marker, Panel, PlotPanel, Report, Series, SeriesStyle, render_png_bytes,
};
use serde_json::json;

use crate::figures::{self, map_panel, vector_overlay};
use crate::options::Alignment;
use crate::process::create_dir;
use crate::progress::{PipelineProgress, bar};

/// Arguments of `pcuvd paper`.
#[derive(Args, Debug)]
pub struct PaperArgs {
    /// Output folder (created if needed).
    #[arg(long)]
    pub out: PathBuf,
    /// Compound frames per acquisition (the paper: 100).
    #[arg(long, default_value_t = 100)]
    pub frames: usize,
    /// Seed of the scatterers and of the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Noise level of the main study, dB (see the noise definition in the report); the paper: −10.
    #[arg(long, default_value_t = -10.0, allow_hyphen_values = true)]
    pub noise_db: f64,
    /// Noise levels (dB) of the RMSE sweep, comma-separated.
    #[arg(
        long,
        default_value = "-30,-20,-10,0,5,10,15,20",
        allow_hyphen_values = true
    )]
    pub sweep: String,
    /// Scatterer motion: "per-event" (physical: blood moves between the events of a frame) or
    /// "per-frame" (held still within each compound frame, as the paper's simulation assumed).
    #[arg(long, value_enum, default_value = "per-event")]
    pub motion: Motion,
    /// How coded events are decoded: "mid-frame" (each event's slow-time series resampled to the
    /// frame's mid-event time first, so moving blood does not leak angles into each other) or
    /// "simultaneous" (the paper's decoding, which takes the events of a frame as simultaneous).
    #[arg(long, value_enum, default_value = "mid-frame")]
    pub event_alignment: Alignment,
    /// Spatial averaging of the autocorrelation, ROWSxCOLS pixels (odd).
    #[arg(long, default_value = "1x1")]
    pub doppler_kernel: String,
    /// Pixel size of the imaging grid (mm).
    #[arg(long, default_value_t = 0.05)]
    pub grid_step: f64,
    /// Which study to run: all, spiral (Fig. 2–5) or network (in-vivo-like, Fig. 6–8, RI maps).
    #[arg(long, value_enum, default_value = "all")]
    pub part: Part,
    /// Compound frames of each vessel-network recording (the paper's rat: 360 = 0.2 s at 1.8 kHz).
    #[arg(long, default_value_t = pcuvd::network::RAT_FRAMES)]
    pub network_frames: usize,
    /// Noise level of the vessel-network recordings, dB (same definition as --noise-db); at +5 dB
    /// the conventional SNR falls from ≈ 18 dB at 2 mm to ≈ 3 dB at 12 mm, so coding matters.
    #[arg(long, default_value_t = 5.0, allow_hyphen_values = true)]
    pub network_noise_db: f64,
    /// Heart rate of the vessel network (Hz); the RI analysis is given the same rate, since 0.2 s
    /// holds too few beats to measure it.
    #[arg(long, default_value_t = 5.5)]
    pub heart_rate: f64,
}

/// Which of the paper's studies `pcuvd paper` runs.
#[derive(Clone, Copy, PartialEq, Eq, Debug, clap::ValueEnum)]
pub enum Part {
    /// Both studies.
    All,
    /// The spiral-flow simulation (Fig. 2–5, noise sweep).
    Spiral,
    /// The in-vivo-like vessel network over a cardiac cycle (Fig. 6–8, RI maps).
    Network,
}

/// When scatterers move.
#[derive(Clone, Copy, PartialEq, Eq, Debug, clap::ValueEnum)]
pub enum Motion {
    /// At every transmit event (physical).
    PerEvent,
    /// Once per compound frame (the paper's simulation; Hadamard decoding then sees a still medium).
    PerFrame,
}

/// The two transmit modes compared.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub(crate) enum Mode {
    Conventional,
    Coded,
}

impl Mode {
    pub(crate) fn label(self) -> &'static str {
        match self {
            Mode::Conventional => "conventional",
            Mode::Coded => "coded",
        }
    }
}

/// Beamformed echoes (S) and unit noise (N) per angle, for one mode.
pub(crate) struct Formed {
    pub(crate) acquisition: pcuvd::Acquisition,
    pub(crate) signal: Vec<Array3<Complex32>>,
    pub(crate) noise: Vec<Array3<Complex32>>,
}

impl Formed {
    /// Per-angle series at noise level `gain` × the simulated one.
    pub(crate) fn at_gain(&self, gain: f32) -> Vec<Array3<Complex32>> {
        self.signal
            .iter()
            .zip(&self.noise)
            .map(|(s, n)| {
                let mut out = s.clone();
                Zip::from(&mut out).and(n).for_each(|o, &v| *o += v * gain);
                out
            })
            .collect()
    }
}

/// RMSE (mm/s) of Vx and Vz over the vessel.
#[derive(Clone, Copy, Debug)]
struct Rmse {
    vx: f64,
    vz: f64,
}

fn rmse(field: &VectorField, truth: &Truth) -> Rmse {
    let (mut sx, mut sz, mut n) = (0.0, 0.0, 0.0);
    Zip::from(&field.vx)
        .and(&field.vz)
        .and(&truth.vx)
        .and(&truth.vz)
        .and(&truth.mask)
        .for_each(|&ex, &ez, &tx, &tz, &m| {
            if m {
                let (dx, dz) = (
                    if ex.is_finite() { ex - tx } else { tx },
                    if ez.is_finite() { ez - tz } else { tz },
                );
                sx += dx * dx;
                sz += dz * dz;
                n += 1.0;
            }
        });
    Rmse {
        vx: (sx / n).sqrt() * 1e3,
        vz: (sz / n).sqrt() * 1e3,
    }
}

fn parse_levels(text: &str) -> Result<Vec<f64>> {
    crate::options::parse_numbers(text)
        .with_context(|| format!("--sweep {text:?}: expected comma-separated noise levels in dB"))
}

/// Runs `pcuvd paper`.
pub fn run(args: &PaperArgs) -> Result<()> {
    if args.frames < 2 {
        bail!(
            "--frames {}: the Doppler estimate needs at least 2 frames",
            args.frames
        );
    }
    if !args.noise_db.is_finite() {
        bail!("--noise-db must be a finite number of dB");
    }
    parse_levels(&args.sweep)?;
    crate::options::parse_kernel(&args.doppler_kernel)?;
    crate::network_study::check_args(args)?;
    create_dir(&args.out)?;
    let started = Instant::now();
    let mut metrics = serde_json::Map::new();
    let mut spiral_figs = Vec::new();
    if args.part != Part::Network {
        let (spiral_metrics, figs) = spiral_study(args)?;
        metrics.extend(spiral_metrics);
        spiral_figs = figs;
    }
    let mut network = None;
    if args.part != Part::Spiral {
        let study = crate::network_study::run(args)?;
        for (key, value) in &study.metrics {
            metrics.insert(key.clone(), value.clone());
        }
        network = Some(study);
    }
    metrics.insert("total_s".into(), json!(started.elapsed().as_secs_f64()));
    let metrics = serde_json::Value::Object(metrics);
    pcuvd_io::write_json(&args.out.join("metrics.json"), &metrics)?;
    write_report(&args.out, &metrics, &spiral_figs, network.as_ref(), args)?;
    let figure_count = spiral_figs.len() + network.as_ref().map_or(0, |n| n.figs.len());
    println!(
        "wrote metrics.json, report.html and {figure_count} figures to {} ({:.0} s)",
        args.out.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The spiral-flow study (Fig. 2–5 and the noise sweep): its metrics and figures.
fn spiral_study(
    args: &PaperArgs,
) -> Result<(serde_json::Map<String, serde_json::Value>, Vec<Rendered>)> {
    let sweep = parse_levels(&args.sweep)?;
    let kernel = crate::options::parse_kernel(&args.doppler_kernel)?;
    let started = Instant::now();
    let mut timing = serde_json::Map::new();

    let clock = Instant::now();
    let phantom = SpiralPhantom::paper(args.seed)?;
    let step = args.grid_step * 1e-3;
    let grid = Grid::new(-6.4e-3, 6.4e-3, 1.0e-3, 13.2e-3, step).context("--grid-step")?;
    let truth = phantom.truth(&grid.x, &grid.z, 0.0);
    timing.insert("phantom_s".into(), json!(clock.elapsed().as_secs_f64()));

    let mut formed = Vec::new();
    for mode in [Mode::Conventional, Mode::Coded] {
        let mut params = simulate::paper_spiral_params(mode == Mode::Coded)?;
        params.seed = args.seed;
        formed.push(simulate_and_form(
            &phantom,
            params,
            args.frames,
            args.noise_db,
            args.motion,
            args.event_alignment.into(),
            &grid,
            mode.label(),
            &mut timing,
        )?);
    }

    // Main study at the requested noise level.
    let clock = Instant::now();
    let params = process_params(
        &grid,
        &formed[0].acquisition,
        kernel,
        args.event_alignment.into(),
    );
    let quiet = |_: pipeline::Stage, _: usize, _: usize| {};
    let main: Vec<ProcessOutput> = formed
        .iter()
        .map(|f| pipeline::analyse(&f.acquisition, f.at_gain(1.0), &params, &quiet))
        .collect::<pcuvd::Result<_>>()?;
    let compound_power =
        |series: &[Array3<Complex32>]| pcuvd::beamform::compound(series).map(|c| mean_power(&c));
    let noise_power: Vec<Array2<f64>> = formed
        .iter()
        .map(|f| compound_power(&f.noise))
        .collect::<pcuvd::Result<_>>()?;
    let echo_power: Vec<Array2<f64>> = formed
        .iter()
        .map(|f| compound_power(&f.signal))
        .collect::<pcuvd::Result<_>>()?;

    // Noise sweep: four estimators at every level.
    let sweep_bar = bar("noise sweep", sweep.len() as u64);
    let mut sweep_rows = Vec::new();
    for &level in &sweep {
        let gain = 10f64.powf((level - args.noise_db) / 20.0) as f32;
        let mut row = vec![];
        for (f, main_out) in formed.iter().zip(&main) {
            // The main study's level is already analysed: reuse it.
            let analysed;
            let out = if level == args.noise_db {
                main_out
            } else {
                analysed = pipeline::analyse(&f.acquisition, f.at_gain(gain), &params, &quiet)?;
                &analysed
            };
            row.push(rmse(out.vector_ls.as_ref().expect("8 angles"), &truth));
            row.push(rmse(out.vector_irls.as_ref().expect("8 angles"), &truth));
        }
        sweep_rows.push((level, row));
        sweep_bar.inc(1);
    }
    sweep_bar.finish();
    timing.insert(
        "doppler_vector_and_sweep_s".into(),
        json!(clock.elapsed().as_secs_f64()),
    );

    // Numbers.
    let (conv, coded) = (&main[0], &main[1]);
    let n_angles = formed[1].acquisition.sequence.n_angles();
    let theory = 10.0 * (n_angles as f64).log10();
    let snr = [
        snr_by_depth(&echo_power[0], &noise_power[0], &truth, &grid),
        snr_by_depth(&echo_power[1], &noise_power[1], &truth, &grid),
    ];
    let depths: Vec<f64> = snr[0].iter().map(|r| r.0).collect();
    let gain_by_depth: Vec<f64> = snr[0].iter().zip(&snr[1]).map(|(a, b)| b.1 - a.1).collect();
    let gain_mean = gain_by_depth.iter().sum::<f64>() / gain_by_depth.len().max(1) as f64;
    let r = |o: &ProcessOutput, irls: bool| {
        rmse(
            if irls {
                o.vector_irls.as_ref()
            } else {
                o.vector_ls.as_ref()
            }
            .expect("8 angles"),
            &truth,
        )
    };
    let (uvd_ls, uvd_irls, pc_ls, pc_irls) = (
        r(conv, false),
        r(conv, true),
        r(coded, false),
        r(coded, true),
    );
    let improvement = |a: f64, b: f64| 100.0 * (a - b) / a;
    timing.insert("total_s".into(), json!(started.elapsed().as_secs_f64()));
    let metrics = json!({
        "snr_gain_db": gain_mean,
        "snr_gain_db_by_depth": { "depth_m": depths, "gain_db": gain_by_depth },
        "snr_db_by_depth": { "depth_m": depths, "conventional": snr[0].iter().map(|r| r.1).collect::<Vec<_>>(), "coded": snr[1].iter().map(|r| r.1).collect::<Vec<_>>() },
        "snr_gain_theory_db": theory,
        "snr_definition": SNR_DEFINITION,
        "rmse_mm_s": {
            "uvd_ls": { "vx": uvd_ls.vx, "vz": uvd_ls.vz },
            "uvd_irls": { "vx": uvd_irls.vx, "vz": uvd_irls.vz },
            "pcuvd_ls": { "vx": pc_ls.vx, "vz": pc_ls.vz },
            "pcuvd_irls": { "vx": pc_irls.vx, "vz": pc_irls.vz },
        },
        "improvement_pct": { "vx": improvement(uvd_ls.vx, pc_irls.vx), "vz": improvement(uvd_ls.vz, pc_irls.vz) },
        "noise_sweep": sweep_rows.iter().map(|(level, row)| json!({
            "noise_db": level,
            "uvd_ls": { "vx": row[0].vx, "vz": row[0].vz },
            "uvd_irls": { "vx": row[1].vx, "vz": row[1].vz },
            "pcuvd_ls": { "vx": row[2].vx, "vz": row[2].vz },
            "pcuvd_irls": { "vx": row[3].vx, "vz": row[3].vz },
        })).collect::<Vec<_>>(),
        "noise_db": args.noise_db,
        "noise_definition": NOISE_DEFINITION,
        "frames": args.frames,
        "motion": format!("{:?}", args.motion),
        "event_alignment": args.event_alignment.label(),
        "doppler_kernel": [kernel.0, kernel.1],
        "seed": args.seed,
        "nyquist_velocity_m_s": coded.nyquist_velocity,
        "vessel_pixels": truth.mask.iter().filter(|&&m| m).count(),
        "grid": { "x_m": [grid.x[0], grid.x[grid.x.len() - 1]], "z_m": [grid.z[0], grid.z[grid.z.len() - 1]], "step_m": step },
        "timing_s": timing,
    });

    // Figures.
    let figs = paper_figures(
        &args.out,
        &main,
        &truth,
        &grid,
        &phantom,
        &snr,
        &noise_power,
        &sweep_rows,
        args,
    )?;
    println!(
        "spiral: SNR gain {gain_mean:.2} dB (theory {theory:.2}); RMSE Vx/Vz mm/s: UVD {:.2}/{:.2}, PC-UVD {:.2}/{:.2} ({:.0} % / {:.0} % better); {:.0} s",
        uvd_ls.vx,
        uvd_ls.vz,
        pc_irls.vx,
        pc_irls.vz,
        improvement(uvd_ls.vx, pc_irls.vx),
        improvement(uvd_ls.vz, pc_irls.vz),
        started.elapsed().as_secs_f64()
    );
    Ok((metrics.as_object().cloned().unwrap_or_default(), figs))
}

/// How SNR is measured on power Doppler images.
pub const SNR_DEFINITION: &str = "SNR(z) = 10·log10(P_echo / P_noise) per 0.5 mm depth band, where P_echo is the mean \
power Doppler of the blood echoes over the vessel pixels (ground-truth mask) of the band and P_noise the mean power \
Doppler of the receiver noise over all pixels of the band; the simulation forms the echo and noise images apart (the \
chain is linear up to the Doppler estimate), so neither is biased by the other or by side lobes";

/// How the scatterers moved, for the reports.
pub(crate) fn motion_text(motion: Motion) -> &'static str {
    match motion {
        Motion::PerEvent => "scatterers move at every transmit event (physical)",
        Motion::PerFrame => {
            "scatterers held still within each compound frame, as in the paper's simulation (Δt = frame period)"
        }
    }
}

/// One sentence on what `--event-alignment` did to the coded recording, for the reports.
pub(crate) fn alignment_text(alignment: Alignment) -> &'static str {
    match alignment {
        Alignment::MidFrame => {
            "each coded event's slow-time series resampled (band-limited, over the frames) to its frame's mid-event time before Hadamard decoding (--event-alignment mid-frame), so that blood moving between the events of a frame does not leak the decoded angles into each other"
        }
        Alignment::Simultaneous => {
            "the paper's Hadamard decoding, which takes the events of a compound frame as simultaneous (--event-alignment simultaneous): blood moving between them leaks the decoded angles into each other"
        }
    }
}

pub(crate) fn process_params(
    grid: &Grid,
    acq: &pcuvd::Acquisition,
    kernel: (usize, usize),
    event_alignment: EventAlignment,
) -> ProcessParams {
    ProcessParams {
        grid: grid.clone(),
        das: DasParams::new(acq.sound_speed),
        clutter: ClutterParams {
            low: RankCut::Off,
            high: RankCut::Off,
            ..ClutterParams::default()
        },
        doppler_kernel: kernel,
        irls: IrlsParams::default(),
        iq_cutoff: None,
        event_alignment,
    }
}

/// Simulates `frames` compound frames of `phantom` with `params` (echoes and noise at `noise_db`
/// apart) and beamforms both on `grid`; `label` names the progress bars and timing keys.
#[allow(clippy::too_many_arguments)]
pub(crate) fn simulate_and_form(
    phantom: &dyn Phantom,
    mut params: SimParams,
    frames: usize,
    noise_db: f64,
    motion: Motion,
    alignment: EventAlignment,
    grid: &Grid,
    label: &str,
    timing: &mut serde_json::Map<String, serde_json::Value>,
) -> Result<Formed> {
    params.noise = None;
    let events = frames * params.sequence.n_angles();
    let held = FrameHeld {
        inner: phantom,
        frame_period: params.sequence.n_angles() as f64 / params.sequence.event_prf,
    };
    let phantom: &dyn Phantom = match motion {
        Motion::PerEvent => phantom,
        Motion::PerFrame => &held,
    };
    let clock = Instant::now();
    let sim_bar = bar(&format!("simulate {label}"), events as u64);
    let signal = simulate::simulate(phantom, &params, frames, &|done, _| {
        sim_bar.set_position(done as u64)
    })?;
    sim_bar.finish();
    params.noise = Some(NoiseSpec::new(noise_db));
    let noise = simulate::simulate_noise(phantom, &params, frames)?;
    timing.insert(
        format!("simulate_{label}_s"),
        json!(clock.elapsed().as_secs_f64()),
    );

    let clock = Instant::now();
    let process = process_params(grid, &signal.acquisition, (1, 1), alignment);
    let progress = PipelineProgress::new(&format!("{label} echoes: "));
    let (signal_images, _) =
        pipeline::form_images(&signal, &process, &|s, d, t| progress.update(s, d, t))?;
    let progress = PipelineProgress::new(&format!("{label} noise: "));
    let (noise_images, _) =
        pipeline::form_images(&noise, &process, &|s, d, t| progress.update(s, d, t))?;
    timing.insert(
        format!("beamform_{label}_s"),
        json!(clock.elapsed().as_secs_f64()),
    );
    Ok(Formed {
        acquisition: signal.acquisition,
        signal: signal_images,
        noise: noise_images,
    })
}

pub(crate) fn mean_power(series: &Array3<Complex32>) -> Array2<f64> {
    series.map_axis(ndarray::Axis(2), |v| {
        v.iter().map(|c| c.norm_sqr() as f64).sum::<f64>() / v.len() as f64
    })
}

/// (depth (m), SNR (dB)) per 0.5 mm band that holds vessel pixels; see [`SNR_DEFINITION`].
pub(crate) fn snr_by_depth(
    echo: &Array2<f64>,
    noise: &Array2<f64>,
    truth: &Truth,
    grid: &Grid,
) -> Vec<(f64, f64)> {
    let band = 0.5e-3;
    let z0 = grid.z[0];
    let n_bands = ((grid.z[grid.z.len() - 1] - z0) / band).floor() as usize + 1;
    let mut sums = vec![[0.0f64; 4]; n_bands];
    for (iz, &z) in grid.z.iter().enumerate() {
        let b = (((z - z0) / band).floor() as usize).min(n_bands - 1);
        for ix in 0..grid.x.len() {
            if truth.mask[[iz, ix]] {
                sums[b][0] += echo[[iz, ix]];
                sums[b][1] += 1.0;
            }
            sums[b][2] += noise[[iz, ix]];
            sums[b][3] += 1.0;
        }
    }
    sums.iter()
        .enumerate()
        .filter(|(_, s)| s[1] >= 10.0 && s[2] > 0.0)
        .map(|(b, s)| {
            (
                z0 + (b as f64 + 0.5) * band,
                10.0 * ((s[0] / s[1]) / (s[2] / s[3])).log10(),
            )
        })
        .collect()
}

/// A rendered figure: file name, caption, PNG bytes.
pub(crate) struct Rendered {
    pub(crate) file: String,
    pub(crate) caption: String,
    pub(crate) png: Vec<u8>,
}

pub(crate) fn render(dir: &Path, file: &str, caption: &str, fig: Figure) -> Result<Rendered> {
    let png = render_png_bytes(&fig).with_context(|| format!("cannot draw {file}"))?;
    std::fs::write(dir.join(file), &png)
        .with_context(|| format!("{}: cannot write", dir.join(file).display()))?;
    Ok(Rendered {
        file: file.to_string(),
        caption: caption.to_string(),
        png,
    })
}

fn masked(values: &Array2<f64>, mask: &Array2<bool>, scale: f64) -> Array2<f64> {
    Zip::from(values)
        .and(mask)
        .map_collect(|&v, &m| if m { v * scale } else { f64::NAN })
}

pub(crate) fn line(
    label: &str,
    x: Vec<f64>,
    y: Vec<f64>,
    style: SeriesStyle,
    rgb: (u8, u8, u8),
) -> Series {
    Series {
        label: label.to_string(),
        x,
        y,
        y_err: None,
        style,
        rgb: Some(rgb),
    }
}

pub(crate) const TRUTH_RGB: (u8, u8, u8) = (31, 119, 180);
pub(crate) const UVD_RGB: (u8, u8, u8) = (230, 159, 0);
const PCUVD_RGB: (u8, u8, u8) = (214, 39, 40);

#[allow(clippy::too_many_arguments)]
fn paper_figures(
    dir: &Path,
    main: &[ProcessOutput],
    truth: &Truth,
    grid: &Grid,
    phantom: &SpiralPhantom,
    snr: &[Vec<(f64, f64)>; 2],
    noise_power: &[Array2<f64>],
    sweep: &[(f64, Vec<Rmse>)],
    args: &PaperArgs,
) -> Result<Vec<Rendered>> {
    let mut out = Vec::new();
    let (conv, coded) = (&main[0], &main[1]);

    // Figure 2: PD and PC-PD, in dB above each image's own noise floor, and SNR versus depth.
    let mut panels = Vec::new();
    for (o, noise, title) in [
        (conv, &noise_power[0], "PD (conventional)"),
        (coded, &noise_power[1], "PC-PD (Hadamard-coded)"),
    ] {
        let floor = noise.mean().unwrap_or(1.0).max(f64::MIN_POSITIVE);
        let db = o
            .power_doppler
            .mapv(|p| 10.0 * (p.max(floor * 1e-3) / floor).log10());
        panels.push(Panel::Image(map_panel(
            title,
            db,
            grid,
            Colormap::Hot,
            (0.0, 35.0),
            "dB above noise",
        )));
    }
    let depth_mm = |rows: &Vec<(f64, f64)>| rows.iter().map(|r| r.0 * 1e3).collect::<Vec<_>>();
    let theory = 10.0 * (coded.projections.dim().0 as f64).log10();
    panels.push(Panel::Plot(PlotPanel {
        title: "SNR versus depth".into(),
        x_label: "depth (mm)".into(),
        y_label: "SNR (dB)".into(),
        series: vec![
            line(
                "PD",
                depth_mm(&snr[0]),
                snr[0].iter().map(|r| r.1).collect(),
                SeriesStyle::LinePoints,
                UVD_RGB,
            ),
            line(
                "PC-PD",
                depth_mm(&snr[1]),
                snr[1].iter().map(|r| r.1).collect(),
                SeriesStyle::LinePoints,
                TRUTH_RGB,
            ),
            line(
                &format!("PD + {theory:.2} dB (theory)"),
                depth_mm(&snr[0]),
                snr[0].iter().map(|r| r.1 + theory).collect(),
                SeriesStyle::DashedLine,
                (120, 120, 120),
            ),
        ],
        annotations: vec!["SNR: echo power in vessel / noise power".into()],
        ..Default::default()
    }));
    out.push(render(dir, "fig2_power_doppler_snr.png", "Figure 2 analogue: conventional power Doppler (PD) and pulse-coded power Doppler (PC-PD), each in dB above its own noise floor, and SNR versus depth.", Figure { title: format!("Power Doppler, noise {} dB", args.noise_db), panels, ncols: 3, panel_size_px: (520, 470) })?);

    // Figure 3: truth / UVD / PC-UVD × Vx, Vz, speed, vector map.
    let vmax = 25.0;
    let mut panels = Vec::new();
    let rows: [(&str, VectorField); 3] = [
        (
            "Truth",
            VectorField {
                vx: truth.vx.clone(),
                vz: truth.vz.clone(),
            },
        ),
        ("UVD", conv.vector_ls.clone().expect("8 angles")),
        ("PC-UVD", coded.vector_irls.clone().expect("8 angles")),
    ];
    for (name, field) in &rows {
        let speed = field.speed();
        panels.push(Panel::Image(map_panel(
            &format!("{name}: Vx"),
            masked(&field.vx, &truth.mask, 1e3),
            grid,
            Colormap::RedBlue,
            (-vmax, vmax),
            "Vx (mm/s)",
        )));
        panels.push(Panel::Image(map_panel(
            &format!("{name}: Vz (+ = deeper)"),
            masked(&field.vz, &truth.mask, 1e3),
            grid,
            Colormap::RedBlue,
            (-vmax, vmax),
            "Vz (mm/s)",
        )));
        panels.push(Panel::Image(map_panel(
            &format!("{name}: speed"),
            masked(&speed, &truth.mask, 1e3),
            grid,
            Colormap::Viridis,
            (0.0, vmax),
            "|V| (mm/s)",
        )));
        let mut vec_panel = map_panel(
            &format!("{name}: vectors"),
            masked(&speed, &truth.mask, 1e3),
            grid,
            Colormap::Viridis,
            (0.0, vmax),
            "|V| (mm/s)",
        );
        vec_panel.arrows = Some(vector_overlay(field, grid, &truth.mask, vmax));
        // Triangles coloured by speed on black, as in the paper (a speed-coloured underlay would hide them).
        vec_panel.mask = Some(Array2::from_elem(truth.mask.dim(), false));
        panels.push(Panel::Image(vec_panel));
    }
    out.push(render(dir, "fig3_vector_maps.png", "Figure 3 analogue: ground truth (top), conventional UVD with least squares (middle) and PC-UVD with IRLS-WLS (bottom): Vx, Vz, speed and vector map inside the vessel.", Figure { title: "Spiral flow: vector velocity".into(), panels, ncols: 4, panel_size_px: (430, 400) })?);

    // Figure 4: profiles across the vessel at a deep crossing (flow mostly lateral) and a side crossing (flow mostly axial).
    let spec = phantom.spec();
    let sections = [
        (
            "Vx across the vessel at x ≈ 0, z ≈ 10 mm",
            2.5 * std::f64::consts::PI,
            0usize,
        ),
        (
            "Vz across the vessel at x ≈ 4.5 mm, z ≈ 7 mm",
            4.0 * std::f64::consts::PI,
            1usize,
        ),
    ];
    let mut panels = Vec::new();
    for (title, alpha0, component) in sections {
        let bins: Vec<f64> = (0..24)
            .map(|i| -0.6e-3 + (i as f64 + 0.5) * 0.05e-3)
            .collect();
        let mut sums = vec![[0.0f64; 4]; bins.len()];
        for (iz, &z) in grid.z.iter().enumerate() {
            for (ix, &x) in grid.x.iter().enumerate() {
                let Some((alpha, l)) = spec.vessel_coordinates(x, z) else {
                    continue;
                };
                if (alpha - alpha0).abs() > 0.1 || !truth.mask[[iz, ix]] {
                    continue;
                }
                let b = (((l + 0.6e-3) / 0.05e-3).floor() as usize).min(bins.len() - 1);
                let pick = |f: &VectorField| {
                    if component == 0 {
                        f.vx[[iz, ix]]
                    } else {
                        f.vz[[iz, ix]]
                    }
                };
                sums[b][0] += pick(&rows[0].1);
                sums[b][1] += pick(&rows[1].1);
                sums[b][2] += pick(&rows[2].1);
                sums[b][3] += 1.0;
            }
        }
        let keep: Vec<usize> = (0..bins.len()).filter(|&b| sums[b][3] > 0.0).collect();
        let xs: Vec<f64> = keep.iter().map(|&b| bins[b] * 1e3).collect();
        let col = |k: usize| {
            keep.iter()
                .map(|&b| sums[b][k] / sums[b][3] * 1e3)
                .collect::<Vec<_>>()
        };
        let label = if component == 0 {
            "Vx (mm/s)"
        } else {
            "Vz (mm/s)"
        };
        panels.push(Panel::Plot(PlotPanel {
            title: title.into(),
            x_label: "distance from the vessel centre (mm)".into(),
            y_label: label.into(),
            series: vec![
                line("truth", xs.clone(), col(0), SeriesStyle::Line, TRUTH_RGB),
                line("UVD", xs.clone(), col(1), SeriesStyle::LinePoints, UVD_RGB),
                line("PC-UVD", xs, col(2), SeriesStyle::LinePoints, PCUVD_RGB),
            ],
            ..Default::default()
        }));
    }
    out.push(render(dir, "fig4_profiles.png", "Figure 4 analogue: velocity profiles across the vessel versus distance from its centre (mean over a 0.2 rad stretch of the vessel, 0.05 mm bins).", Figure { title: "Velocity profiles".into(), panels, ncols: 2, panel_size_px: (560, 440) })?);

    // Figure 5: estimated versus true, binned per 1 mm/s, error bars = standard deviation.
    let mut panels = Vec::new();
    for (name, field) in [("UVD", &rows[1].1), ("PC-UVD", &rows[2].1)] {
        let err = rmse(field, truth);
        for (component, est, tru, value) in [
            ("Vx", &field.vx, &truth.vx, err.vx),
            ("Vz", &field.vz, &truth.vz, err.vz),
        ] {
            let mut bins: std::collections::BTreeMap<i64, Vec<f64>> = Default::default();
            Zip::from(est)
                .and(tru)
                .and(&truth.mask)
                .for_each(|&e, &t, &m| {
                    if m && e.is_finite() {
                        bins.entry((t * 1e3).round() as i64)
                            .or_default()
                            .push(e * 1e3);
                    }
                });
            let (mut x, mut y, mut s) = (vec![], vec![], vec![]);
            for (k, v) in bins {
                if v.len() < 5 {
                    continue;
                }
                let mean = v.iter().sum::<f64>() / v.len() as f64;
                let var = v.iter().map(|a| (a - mean).powi(2)).sum::<f64>() / v.len() as f64;
                x.push(k as f64);
                y.push(mean);
                s.push(var.sqrt());
            }
            panels.push(Panel::Plot(PlotPanel {
                title: format!("{name}: {component}"),
                x_label: format!("true {component} (mm/s)"),
                y_label: format!("estimated {component} (mm/s)"),
                series: vec![Series {
                    label: "mean ± SD per 1 mm/s".into(),
                    x,
                    y,
                    y_err: Some(s),
                    style: SeriesStyle::Points,
                    rgb: Some(if name == "UVD" { UVD_RGB } else { PCUVD_RGB }),
                }],
                x_range: Some((-28.0, 28.0)),
                y_range: Some((-28.0, 28.0)),
                annotations: vec![format!("RMSE {value:.2} mm/s")],
                diagonal: true,
                ..Default::default()
            }));
        }
    }
    out.push(render(dir, "fig5_accuracy.png", "Figure 5 analogue: estimated versus true velocity over all vessel pixels; points are means per 1 mm/s bin of the truth, bars one standard deviation; RMSE over all vessel pixels.", Figure { title: "Accuracy of Vx and Vz".into(), panels, ncols: 2, panel_size_px: (500, 460) })?);

    // Beyond the paper: RMSE versus noise level for four estimators.
    let levels: Vec<f64> = sweep.iter().map(|r| r.0).collect();
    let names = [
        ("conventional + LS (UVD)", UVD_RGB, SeriesStyle::LinePoints),
        ("conventional + IRLS", UVD_RGB, SeriesStyle::DashedLine),
        ("coded + LS", PCUVD_RGB, SeriesStyle::DashedLine),
        ("coded + IRLS (PC-UVD)", PCUVD_RGB, SeriesStyle::LinePoints),
    ];
    let mut panels = Vec::new();
    for component in ["Vx", "Vz"] {
        let series = names
            .iter()
            .enumerate()
            .map(|(k, &(label, rgb, style))| {
                let y = sweep
                    .iter()
                    .map(|r| {
                        if component == "Vx" {
                            r.1[k].vx
                        } else {
                            r.1[k].vz
                        }
                    })
                    .collect();
                line(label, levels.clone(), y, style, rgb)
            })
            .collect();
        panels.push(Panel::Plot(PlotPanel {
            title: format!("RMSE of {component} versus noise level"),
            x_label: "noise level (dB, see definition)".into(),
            y_label: format!("RMSE {component} (mm/s)"),
            series,
            markers: vec![Marker {
                x: args.noise_db,
                y: 0.0,
                label: "main study".into(),
                rgb: (90, 90, 90),
            }],
            ..Default::default()
        }));
    }
    out.push(render(dir, "fig_noise_sweep.png", "Beyond the paper: RMSE of Vx and Vz versus channel noise level for conventional and coded transmission, each with least squares and IRLS-WLS (same scatterers and noise realisation at every level).", Figure { title: "Noise sweep".into(), panels, ncols: 2, panel_size_px: (560, 440) })?);

    // The maps of each mode, as `pcuvd process` would draw them.
    for (o, mode) in [(conv, "conventional"), (coded, "coded")] {
        let sub = dir.join(mode);
        create_dir(&sub)?;
        figures::process_figures(&sub, o, &format!("spiral, {mode}"))?;
    }
    Ok(out)
}

fn write_report(
    dir: &Path,
    metrics: &serde_json::Value,
    figs: &[Rendered],
    network: Option<&crate::network_study::NetworkStudy>,
    args: &PaperArgs,
) -> Result<()> {
    let mut report =
        Report::new("pcuvd: pulse-coded ultrafast vector Doppler, the paper's studies");
    if args.part != Part::Network {
        spiral_report(&mut report, metrics, figs, args);
    }
    if let Some(study) = network {
        crate::network_study::report_section(&mut report, study, args);
    }
    report.heading("Every number and parameter (metrics.json)");
    report.preformatted(&serde_json::to_string_pretty(metrics).unwrap_or_default());
    report
        .write(&dir.join("report.html"))
        .with_context(|| format!("{}: cannot write", dir.join("report.html").display()))?;
    Ok(())
}

fn spiral_report(
    report: &mut Report,
    metrics: &serde_json::Value,
    figs: &[Rendered],
    args: &PaperArgs,
) {
    let m = metrics;
    let f = |path: &[&str]| -> String {
        let mut v = m;
        for p in path {
            v = &v[*p];
        }
        v.as_f64()
            .map(|x| format!("{x:.2}"))
            .unwrap_or_else(|| "–".into())
    };
    report.heading("Spiral-flow simulation (paper §2.3, §3, Fig. 2–5)");
    report.paragraph(&format!(
        "Reproduction of the simulation study of Yan et al. (PC-UVD): an Archimedes-spiral vessel (a = 1 mm, b = 0.28 mm/rad, α up to 4.2π, R = 0.6 mm, 300 scatterers/mm², parabolic flow with 25 mm/s peak, centre at z = 7 mm) imaged by an L22-14vX probe at 15.625 MHz (f_s 65 MHz, 2-cycle pulse, c 1540 m/s), 8 plane waves from −15° to 15° at an event PRF of 14.4 kHz (1.8 kHz compound rate), {} compound frames, conventionally and with Hadamard coding of order 8 (1 µs slot delay). No clutter filter (the phantom has no tissue). Seed {}.",
        args.frames, args.seed
    ));
    report.paragraph(&format!(
        "Noise: {NOISE_DEFINITION} Main study at {} dB.",
        args.noise_db
    ));
    report.paragraph(&format!(
        "Motion: {}. Decoding: {}. Doppler autocorrelation averaged over {} pixels.",
        motion_text(args.motion),
        alignment_text(args.event_alignment),
        args.doppler_kernel
    ));
    report.paragraph(&format!("{SNR_DEFINITION}."));
    report.heading("Numbers: pcuvd and the paper");
    let rows = vec![
        vec![
            "SNR gain, coded over conventional (dB)".into(),
            f(&["snr_gain_db"]),
            "8.7".into(),
            format!("theory {}", f(&["snr_gain_theory_db"])),
        ],
        vec![
            "RMSE Vx, UVD (mm/s)".into(),
            f(&["rmse_mm_s", "uvd_ls", "vx"]),
            "5.70".into(),
            "conventional + LS".into(),
        ],
        vec![
            "RMSE Vz, UVD (mm/s)".into(),
            f(&["rmse_mm_s", "uvd_ls", "vz"]),
            "2.28".into(),
            "conventional + LS".into(),
        ],
        vec![
            "RMSE Vx, PC-UVD (mm/s)".into(),
            f(&["rmse_mm_s", "pcuvd_irls", "vx"]),
            "3.22".into(),
            "coded + IRLS-WLS".into(),
        ],
        vec![
            "RMSE Vz, PC-UVD (mm/s)".into(),
            f(&["rmse_mm_s", "pcuvd_irls", "vz"]),
            "1.59".into(),
            "coded + IRLS-WLS".into(),
        ],
        vec![
            "Improvement Vx (%)".into(),
            f(&["improvement_pct", "vx"]),
            "43.51".into(),
            String::new(),
        ],
        vec![
            "Improvement Vz (%)".into(),
            f(&["improvement_pct", "vz"]),
            "30.26".into(),
            String::new(),
        ],
        vec![
            "RMSE Vx / Vz, conventional + IRLS (mm/s)".into(),
            format!(
                "{} / {}",
                f(&["rmse_mm_s", "uvd_irls", "vx"]),
                f(&["rmse_mm_s", "uvd_irls", "vz"])
            ),
            "–".into(),
            "beyond the paper".into(),
        ],
        vec![
            "RMSE Vx / Vz, coded + LS (mm/s)".into(),
            format!(
                "{} / {}",
                f(&["rmse_mm_s", "pcuvd_ls", "vx"]),
                f(&["rmse_mm_s", "pcuvd_ls", "vz"])
            ),
            "–".into(),
            "beyond the paper".into(),
        ],
    ];
    report.table(&["quantity", "pcuvd", "paper", "note"], &rows);
    report.paragraph(
        "Reading the numbers: blood at 25 mm/s moves its echo phase by about 0.2 rad per event, so the paper's decoding, which takes the n events of a compound frame as simultaneous (--event-alignment simultaneous), leaks the decoded angles into each other: a haze around the vessel in PC-PD, and a coded Vx worse than the conventional one when noise is weak. pcuvd resamples each event to the frame's mid-event time before decoding (the default, --event-alignment mid-frame), which makes decoding exact again for Doppler below half the frame rate; with the scatterers held still within frames (--motion per-frame, the paper's simulation) there is nothing to leak. Where the sweep is flat, errors are not noise-limited and the estimator (LS or IRLS), not coding, makes the difference; coding wins as noise grows.",
    );
    report.heading("Spiral: figures");
    for fig in figs {
        report.image_png(&format!("{} ({})", fig.caption, fig.file), &fig.png);
    }
}
