//! `pcuvd paper`, in-vivo-like part (paper §4, Fig. 6–8): a pulsatile vessel network in the rat
//! setting, imaged conventionally (UVD) and with Hadamard coding (PC-UVD) over one cardiac cycle,
//! with ground truth for PSV, EDV, RI and artery/vein class that the paper's rat did not have.
//!
//! Per mode: echoes and noise are simulated and beamformed apart (for SNR by depth) and added; the
//! whole recording gives the power, colour and vector Doppler maps (Fig. 6–7); sliding windows give
//! the vector velocity over time, whose per-pixel PSV, EDV and RI are compared with the truth
//! (Fig. 8); compounded Doppler spectrograms are drawn at four pixels (Fig. 8b).

use std::time::Instant;

use anyhow::{Context, Result, bail};
use ndarray::{Array2, Axis, Zip, s};
use pcuvd::beamform::Grid;
use pcuvd::dynamics::{
    self, ARTERIOLE, BACKGROUND, DynamicsParams, RiMaps, Spectrogram, SpectrogramParams, VENULE,
    VelocitySeries, VesselPooling,
};
use pcuvd::network::{self, NetworkPhantom, NetworkSpec, NetworkTruth, VesselKind};
use pcuvd::phantom::Phantom;
use pcuvd::pipeline::{self, ProcessOutput};
use pcuvd::vector::{Estimator, IrlsParams, VectorField};
use pcuvd_render::{Colormap, Figure, ImageAxes, Panel, PlotPanel, Polyline, Report, SeriesStyle};
use serde_json::{Map, Value, json};

use crate::figures::{class_map, map_panel, median, vector_panel};
use crate::paper::{
    Mode, PaperArgs, Part, Rendered, TRUTH_RGB, UVD_RGB, line, mean_power, process_params, render,
    simulate_and_form, snr_by_depth,
};
use crate::process::pooling_summary;
use crate::progress::bar;

/// Field of view of the network study (m): the probe's aperture, 1–13 mm deep.
const FIELD: (f64, f64, f64, f64) = (-6.4e-3, 6.4e-3, 1.0e-3, 13.0e-3);

/// How the RI maps are scored against the truth.
pub const RI_SCORE_DEFINITION: &str = "over every vessel pixel of the ground truth (the lumen of \
every vessel on the grid): median_abs_error = median of |RI_estimated − RI_true|, where a pixel the \
estimator leaves without an RI (not a vessel pixel by its power thresholds) counts as an error of 1; \
classification_accuracy = fraction of vessel pixels classed as the right kind (arteriole or venule; \
undetermined or background count as wrong); coverage = fraction of vessel pixels with an RI";

/// What the network study hands back to `pcuvd paper`.
pub struct NetworkStudy {
    /// Keys merged into metrics.json (`ri`, `network`).
    pub metrics: Map<String, Value>,
    /// Figures, in report order.
    pub figs: Vec<Rendered>,
}

/// Refuses network settings that cannot work, before anything is simulated.
pub fn check_args(args: &PaperArgs) -> Result<()> {
    if args.part == Part::Spiral {
        return Ok(());
    }
    if !args.network_noise_db.is_finite() {
        bail!("--network-noise-db must be a finite number of dB");
    }
    if !(args.heart_rate.is_finite() && args.heart_rate > 0.0) {
        bail!(
            "--heart-rate {}: must be a positive number of Hz",
            args.heart_rate
        );
    }
    let frame_rate = frame_rate()?;
    let params = dynamics_params(args, Mode::Coded)?;
    params
        .validate(frame_rate)
        .with_context(|| format!("--heart-rate {} Hz", args.heart_rate))?;
    // The dynamics stage needs one cycle of window samples: round(period / step) windows.
    let period_frames = frame_rate / args.heart_rate;
    let cycle_windows = ((period_frames / params.step as f64).round() as usize).max(2);
    let needed = (cycle_windows - 1) * params.step + params.window;
    if args.network_frames < needed {
        bail!(
            "--network-frames {}: a cardiac cycle at {} Hz lasts {:.0} frames at {:.0} Hz, and RI \
             needs one whole cycle of {}-frame windows {} frames apart: at least {needed} frames",
            args.network_frames,
            args.heart_rate,
            period_frames,
            frame_rate,
            params.window,
            params.step
        );
    }
    Ok(())
}

fn frame_rate() -> Result<f64> {
    let params = network::rat_params(false)?;
    Ok(params.sequence.event_prf / params.sequence.n_angles() as f64)
}

/// Spatial averaging of the dynamics stage (pixels): as `pcuvd process --dynamics-kernel`, 0.25 mm
/// at the default 0.05 mm grid. Per-pixel window speeds jitter (a 20 ms window sees few speckle
/// renewals) and the extremes of a jittery waveform inflate RI; on this network, at noise +5 dB
/// and without pooling, the PC-UVD median RI error was 0.12 with 1 × 1, 0.097 with 3 × 3 and 0.078
/// with 5 × 5 (2 harmonics). With vessel pooling (a disc of radius 0.7 mm, seeds 1–3, before angle
/// coverage and the ellipse),
/// 5 × 5 gave 0.030–0.036 and 95.3–97.7 % rightly classed, 7 × 7 0.032–0.040 and 95.2–98.5 %.
const DYNAMICS_KERNEL: (usize, usize) = (5, 5);

/// Dynamics settings: the rat preset with the study's heart rate, the mode's estimator and the
/// default vessel pooling of `pcuvd process` on a grid of `grid_step_mm` (mm).
fn dynamics_params(args: &PaperArgs, mode: Mode) -> Result<DynamicsParams> {
    let pooling = VesselPooling::from_metres(
        VesselPooling::DEFAULT_ALONG_M,
        VesselPooling::DEFAULT_ACROSS_M,
        VesselPooling::DEFAULT_MAX_ANGLE_DEG,
        args.grid_step * 1e-3,
    )
    .context("--grid-step")?;
    Ok(DynamicsParams {
        kernel: DYNAMICS_KERNEL,
        heart_rate_hz: Some(args.heart_rate),
        estimator: match mode {
            Mode::Conventional => Estimator::LeastSquares,
            Mode::Coded => Estimator::Irls(IrlsParams::default()),
        },
        pooling,
        ..DynamicsParams::rat()
    })
}

/// One transmit mode's results.
struct ModeResult {
    mode: Mode,
    out: ProcessOutput,
    series: VelocitySeries,
    ri: RiMaps,
    echo_power: Array2<f64>,
    noise_power: Array2<f64>,
    spectrograms: Vec<Spectrogram>,
}

impl ModeResult {
    fn estimator_name(&self) -> &'static str {
        match self.mode {
            Mode::Conventional => "UVD",
            Mode::Coded => "PC-UVD",
        }
    }

    fn field(&self) -> &VectorField {
        match self.mode {
            Mode::Conventional => self.out.vector_ls.as_ref(),
            Mode::Coded => self.out.vector_irls.as_ref(),
        }
        .expect("the rat sequence has 8 angles")
    }
}

/// A pixel where a spectrogram is drawn, with what it shows.
struct Site {
    label: String,
    vessel: usize,
    pixel: (usize, usize),
}

/// Runs the network study: simulation, processing, dynamics, scores and figures.
pub fn run(args: &PaperArgs) -> Result<NetworkStudy> {
    let started = Instant::now();
    let mut timing = Map::new();
    let spec = NetworkSpec {
        heart_rate_hz: args.heart_rate,
        ..NetworkSpec::rat()
    };
    let phantom = NetworkPhantom::new(spec, args.seed)?;
    let grid = Grid::new(FIELD.0, FIELD.1, FIELD.2, FIELD.3, args.grid_step * 1e-3)
        .context("--grid-step")?;
    let truth = phantom.cycle_truth(&grid.x, &grid.z);
    let motion_truth = phantom.truth(&grid.x, &grid.z, 0.0);
    let sites = spectrogram_pixels(&phantom, &truth, &grid);
    let frame_rate = frame_rate()?;

    let mut results = Vec::new();
    for mode in [Mode::Conventional, Mode::Coded] {
        let mut params = network::rat_params(mode == Mode::Coded)?;
        params.seed = args.seed;
        let label = format!("network_{}", mode.label());
        let formed = simulate_and_form(
            &phantom,
            params,
            args.network_frames,
            args.network_noise_db,
            args.motion,
            args.event_alignment.into(),
            &grid,
            &label,
            &mut timing,
        )?;
        let clock = Instant::now();
        let compound_power = |series: &[ndarray::Array3<num_complex::Complex32>]| {
            pcuvd::beamform::compound(series).map(|c| mean_power(&c))
        };
        let echo_power = compound_power(&formed.signal)?;
        let noise_power = compound_power(&formed.noise)?;
        let acquisition = formed.acquisition.clone();
        let images = formed.at_gain(1.0);
        drop(formed);
        let process = process_params(&grid, &acquisition, (1, 1), args.event_alignment.into());
        let out = pipeline::analyse(&acquisition, images, &process, &|_, _, _| {})?;
        let dparams = dynamics_params(args, mode)?;
        let (c, f0) = (acquisition.sound_speed, acquisition.probe.center_frequency);
        let angles = &acquisition.sequence.angles;
        let series = dynamics::sliding_vectors(
            &out.filtered,
            angles,
            Some(out.coverage.view()),
            frame_rate,
            c,
            f0,
            &dparams,
        )?;
        let flow = dynamics::VesselTests::default().flow_mask(&out.power_doppler, grid.step());
        let ri = dynamics::ri_maps_where(&series, &dparams, Some(&flow))?;
        let spectrograms = sites
            .iter()
            .map(|p| {
                dynamics::spectrogram(
                    &out.filtered,
                    angles,
                    p.pixel,
                    frame_rate,
                    c,
                    f0,
                    &SpectrogramParams::rat(),
                )
            })
            .collect::<pcuvd::Result<Vec<_>>>()?;
        timing.insert(
            format!("{label}_analysis_s"),
            json!(clock.elapsed().as_secs_f64()),
        );
        results.push(ModeResult {
            mode,
            out,
            series,
            ri,
            echo_power,
            noise_power,
            spectrograms,
        });
    }

    let scores: Vec<Scores> = results.iter().map(|r| score(&r.ri, &truth)).collect();
    let snr: Vec<Vec<(f64, f64)>> = results
        .iter()
        .map(|r| snr_by_depth(&r.echo_power, &r.noise_power, &motion_truth, &grid))
        .collect();
    let figure_bar = bar("network figures", 5);
    let figs = network_figures(
        args,
        &phantom,
        &truth,
        &grid,
        &results,
        &scores,
        &snr,
        &sites,
        &figure_bar,
    )?;
    figure_bar.finish();
    timing.insert(
        "network_total_s".into(),
        json!(started.elapsed().as_secs_f64()),
    );

    let (uvd, pc) = (&scores[0], &scores[1]);
    println!(
        "network: RI median |error| UVD {:.3}, PC-UVD {:.3}; artery/vein correct UVD {:.1} %, PC-UVD {:.1} % ({:.0} s)",
        uvd.median_abs_error,
        pc.median_abs_error,
        100.0 * uvd.classification_accuracy,
        100.0 * pc.classification_accuracy,
        started.elapsed().as_secs_f64()
    );
    let spec = phantom.spec();
    let mut metrics = Map::new();
    metrics.insert(
        "ri".into(),
        json!({
            "uvd": uvd.to_json(),
            "pcuvd": pc.to_json(),
            "definition": RI_SCORE_DEFINITION,
        }),
    );
    metrics.insert(
        "network".into(),
        json!({
            "frames": args.network_frames,
            "frame_rate_hz": frame_rate,
            "noise_db": args.network_noise_db,
            "heart_rate_hz": args.heart_rate,
            "motion": format!("{:?}", args.motion),
            "event_alignment": args.event_alignment.label(),
            "seed": args.seed,
            "scatterers": phantom.n_scatterers(),
            "vessel_pixels": truth.mask().iter().filter(|&&m| m).count(),
            "vessels": spec.vessels.iter().enumerate().map(|(i, v)| json!({
                "name": v.name,
                "kind": format!("{:?}", v.kind).to_lowercase(),
                "flows_up": v.flows_up(),
                "centre_m": v.centre,
                "angle_deg": v.angle.to_degrees(),
                "length_m": v.length,
                "radius_m": v.radius,
                "psv_m_s": v.psv,
                "ri": v.ri,
                "uvd": uvd.per_vessel[i].to_json(),
                "pcuvd": pc.per_vessel[i].to_json(),
            })).collect::<Vec<_>>(),
            "snr_db_by_depth": {
                "depth_m": snr[0].iter().map(|r| r.0).collect::<Vec<_>>(),
                "conventional": snr[0].iter().map(|r| r.1).collect::<Vec<_>>(),
                "coded": snr[1].iter().map(|r| r.1).collect::<Vec<_>>(),
            },
            "dynamics": {
                "window_frames": DynamicsParams::rat().window,
                "step_frames": DynamicsParams::rat().step,
                "artery_ri_min": DynamicsParams::rat().artery_ri_min,
                "vein_ri_max": DynamicsParams::rat().vein_ri_max,
                "min_power_db": DynamicsParams::rat().min_power_db,
                "vessel_margin_db": dynamics::VESSEL_MARGIN_DB,
                "vessel_local_db": dynamics::VESSEL_LOCAL_DB,
                "vessel_local_radius_m": dynamics::VESSEL_LOCAL_RADIUS_M,
                "kernel": [DYNAMICS_KERNEL.0, DYNAMICS_KERNEL.1],
                "vessel_pooling": pooling_summary(&dynamics_params(args, Mode::Coded)?, args.grid_step * 1e-3),
                "cycles_windows": results.iter().map(|r| r.ri.cycles.clone()).collect::<Vec<_>>(),
            },
            "timing_s": timing,
        }),
    );
    Ok(NetworkStudy { metrics, figs })
}

/// RI scores of one vessel or of the whole network.
#[derive(Clone, Copy, Debug, Default)]
struct Score {
    median_abs_error: f64,
    classification_accuracy: f64,
    coverage: f64,
    median_ri: f64,
    pixels: usize,
}

impl Score {
    fn to_json(self) -> Value {
        json!({
            "median_abs_error": self.median_abs_error,
            "classification_accuracy": self.classification_accuracy,
            "coverage": self.coverage,
            "median_ri": self.median_ri,
            "pixels": self.pixels,
        })
    }
}

/// Network-wide scores with a breakdown per vessel.
struct Scores {
    median_abs_error: f64,
    classification_accuracy: f64,
    coverage: f64,
    direction_accuracy: f64,
    per_vessel: Vec<Score>,
}

impl Scores {
    fn to_json(&self) -> Value {
        json!({
            "median_abs_error": self.median_abs_error,
            "classification_accuracy": self.classification_accuracy,
            "coverage": self.coverage,
            "direction_accuracy": self.direction_accuracy,
        })
    }
}

/// Scores over the pixels where `select(vessel index)` holds; see [`RI_SCORE_DEFINITION`].
fn score_where(est: &RiMaps, truth: &NetworkTruth, select: impl Fn(usize) -> bool) -> Score {
    let (mut errors, mut ris) = (vec![], vec![]);
    let (mut correct, mut covered) = (0usize, 0usize);
    Zip::from(&est.ri)
        .and(&est.vessel_class)
        .and(&truth.ri)
        .and(&truth.vessel_class)
        .and(&truth.vessel_index)
        .for_each(|&ri, &class, &true_ri, &true_class, &vessel| {
            if true_class == BACKGROUND || !select(vessel) {
                return;
            }
            if ri.is_finite() {
                errors.push((ri - true_ri).abs());
                ris.push(ri);
                covered += 1;
            } else {
                errors.push(1.0);
            }
            if class == true_class {
                correct += 1;
            }
        });
    let n = errors.len();
    Score {
        median_abs_error: median(errors),
        classification_accuracy: correct as f64 / n.max(1) as f64,
        coverage: covered as f64 / n.max(1) as f64,
        median_ri: median(ris),
        pixels: n,
    }
}

fn score(est: &RiMaps, truth: &NetworkTruth) -> Scores {
    let all = score_where(est, truth, |_| true);
    let vessels = truth
        .vessel_index
        .iter()
        .filter(|&&i| i != usize::MAX)
        .max()
        .map_or(0, |&m| m + 1);
    let (mut right, mut n) = (0usize, 0usize);
    Zip::from(&est.flow_up)
        .and(&est.vessel_class)
        .and(&truth.flow_up)
        .and(&truth.vessel_class)
        .for_each(|&up, &class, &true_up, &true_class| {
            if true_class != BACKGROUND && class != BACKGROUND {
                n += 1;
                right += usize::from(up == true_up);
            }
        });
    Scores {
        median_abs_error: all.median_abs_error,
        classification_accuracy: all.classification_accuracy,
        coverage: all.coverage,
        direction_accuracy: right as f64 / n.max(1) as f64,
        per_vessel: (0..vessels)
            .map(|v| score_where(est, truth, |i| i == v))
            .collect(),
    }
}

/// The grid pixel nearest to (x, z) (m).
fn nearest_pixel(grid: &Grid, x: f64, z: f64) -> (usize, usize) {
    let nearest = |axis: &[f64], v: f64| {
        axis.iter()
            .enumerate()
            .min_by(|a, b| (a.1 - v).abs().total_cmp(&(b.1 - v).abs()))
            .map_or(0, |(i, _)| i)
    };
    (nearest(&grid.z, z), nearest(&grid.x, x))
}

/// One pixel on the axis of the first vessel of each kind and direction (Fig. 8b's four panels).
fn spectrogram_pixels(phantom: &NetworkPhantom, truth: &NetworkTruth, grid: &Grid) -> Vec<Site> {
    let mut sites = Vec::new();
    for (kind, up) in [
        (VesselKind::Arteriole, true),
        (VesselKind::Arteriole, false),
        (VesselKind::Venule, true),
        (VesselKind::Venule, false),
    ] {
        let found = phantom
            .spec()
            .vessels
            .iter()
            .enumerate()
            .find(|(_, v)| v.kind == kind && v.flows_up() == up);
        if let Some((i, v)) = found {
            let pixel = nearest_pixel(grid, v.centre[0], v.centre[1]);
            if truth.vessel_index[pixel] == i {
                sites.push(Site {
                    label: format!(
                        "{}: {}, flowing {}",
                        v.name,
                        match kind {
                            VesselKind::Arteriole => "arteriole",
                            VesselKind::Venule => "venule",
                        },
                        if up { "up" } else { "down" }
                    ),
                    vessel: i,
                    pixel,
                });
            }
        }
    }
    sites
}

/// Rows/columns of `grid` inside [lo, hi] (m).
fn index_range(axis: &[f64], lo: f64, hi: f64) -> std::ops::Range<usize> {
    let start = axis.iter().position(|&v| v >= lo).unwrap_or(axis.len());
    let end = axis.iter().rposition(|&v| v <= hi).map_or(start, |e| e + 1);
    start..end.max(start)
}

/// A rectangular part of a grid and of the maps on it.
struct Roi {
    grid: Grid,
    rows: std::ops::Range<usize>,
    cols: std::ops::Range<usize>,
}

impl Roi {
    fn new(grid: &Grid, x: (f64, f64), z: (f64, f64)) -> Result<Roi> {
        let rows = index_range(&grid.z, z.0, z.1);
        let cols = index_range(&grid.x, x.0, x.1);
        if rows.len() < 2 || cols.len() < 2 {
            bail!("region of interest {x:?} × {z:?} m holds no pixels of the grid");
        }
        let step = grid.step();
        let sub = Grid::new(
            grid.x[cols.start],
            grid.x[cols.end - 1],
            grid.z[rows.start],
            grid.z[rows.end - 1],
            step,
        )?;
        Ok(Roi {
            grid: sub,
            rows,
            cols,
        })
    }

    fn cut<T: Clone>(&self, a: &Array2<T>) -> Array2<T> {
        a.slice(s![self.rows.clone(), self.cols.clone()]).to_owned()
    }
}

/// Flow pixels for display: power Doppler at least [`DISPLAY_FLOW_DB`] above the mode's own noise
/// floor. A threshold relative to the brightest pixel lets the receiver noise through at +5 dB
/// (then colour and vector maps show noise everywhere and the glyph scale follows it).
fn flow_above_noise(power: &Array2<f64>, noise: &Array2<f64>) -> Array2<bool> {
    db_above(power, noise).mapv(|d| d >= DISPLAY_FLOW_DB)
}

/// Display threshold of flow maps (dB above the noise floor).
const DISPLAY_FLOW_DB: f64 = 6.0;

fn db_above(power: &Array2<f64>, noise: &Array2<f64>) -> Array2<f64> {
    let floor = noise.mean().unwrap_or(1.0).max(f64::MIN_POSITIVE);
    power.mapv(|p| 10.0 * (p.max(floor * 1e-3) / floor).log10())
}

fn finite_mask(a: &Array2<f64>) -> Array2<bool> {
    a.mapv(f64::is_finite)
}

#[allow(clippy::too_many_arguments)]
fn network_figures(
    args: &PaperArgs,
    phantom: &NetworkPhantom,
    truth: &NetworkTruth,
    grid: &Grid,
    results: &[ModeResult],
    scores: &[Scores],
    snr: &[Vec<(f64, f64)>],
    sites: &[Site],
    progress: &indicatif::ProgressBar,
) -> Result<Vec<Rendered>> {
    let dir = &args.out;
    let mut figs = Vec::new();
    let black = Array2::<f64>::zeros(grid.shape());
    let vmax = 30.0;
    // Flow pixels of each mode, for every flow map below.
    let flows: Vec<Array2<bool>> = results
        .iter()
        .map(|r| flow_above_noise(&r.out.power_doppler, &r.noise_power))
        .collect();

    // Figure 6: PD, colour Doppler and vector maps, UVD above PC-UVD.
    let mut panels = Vec::new();
    for (r, flow) in results.iter().zip(&flows) {
        let name = r.estimator_name();
        panels.push(Panel::Image(map_panel(
            &format!("{name}: power Doppler"),
            db_above(&r.out.power_doppler, &r.noise_power),
            grid,
            Colormap::Hot,
            (0.0, 40.0),
            "dB above noise",
        )));
        let mut cd = map_panel(
            &format!("{name}: colour Doppler (red: up)"),
            r.out.color_doppler.mapv(|v| -v * 1e3),
            grid,
            Colormap::RedBlue,
            (-vmax, vmax),
            "axial velocity toward probe (mm/s)",
        );
        cd.mask = Some(flow.clone());
        cd.background = Some(black.clone());
        panels.push(Panel::Image(cd));
        panels.push(vector_panel(
            &format!("{name}: vector Doppler"),
            r.field(),
            grid,
            flow,
            &black,
        ));
    }
    figs.push(render(dir, "fig6_network_doppler.png", "Figure 6 analogue: power Doppler (dB above each mode's own noise floor), colour Doppler and vector Doppler of the vessel network over the whole recording; conventional UVD (top) and PC-UVD (bottom). Flow maps show pixels at least 6 dB above the noise floor.", Figure { title: format!("Vessel network, noise {} dB: UVD (top) and PC-UVD (bottom)", args.network_noise_db), panels, ncols: 3, panel_size_px: (520, 500) })?);
    progress.inc(1);

    // Figure 6 (g, h): PD profiles along a shallow horizontal line and a vertical line, SNR by depth.
    let (z_line, x_line) = (5.0e-3, 4.2e-3);
    let row = nearest_pixel(grid, 0.0, z_line).0;
    let col = nearest_pixel(grid, x_line, 0.0).1;
    let x_mm: Vec<f64> = grid.x.iter().map(|x| x * 1e3).collect();
    let z_mm: Vec<f64> = grid.z.iter().map(|z| z * 1e3).collect();
    let rgb = [UVD_RGB, TRUTH_RGB];
    let labels = ["PD (conventional)", "PC-PD (coded)"];
    let profile = |horizontal: bool| -> Vec<pcuvd_render::Series> {
        results
            .iter()
            .enumerate()
            .map(|(k, r)| {
                let db = db_above(&r.out.power_doppler, &r.noise_power);
                let (xs, ys) = if horizontal {
                    (x_mm.clone(), db.row(row).to_vec())
                } else {
                    (z_mm.clone(), db.column(col).to_vec())
                };
                line(labels[k], xs, ys, SeriesStyle::Line, rgb[k])
            })
            .collect()
    };
    let depth = |rows: &Vec<(f64, f64)>| rows.iter().map(|r| r.0 * 1e3).collect::<Vec<_>>();
    let panels = vec![
        Panel::Plot(PlotPanel {
            title: format!("PD along z = {:.1} mm", grid.z[row] * 1e3),
            x_label: "x (mm)".into(),
            y_label: "dB above noise".into(),
            series: profile(true),
            ..Default::default()
        }),
        Panel::Plot(PlotPanel {
            title: format!("PD along x = {:.1} mm", grid.x[col] * 1e3),
            x_label: "depth (mm)".into(),
            y_label: "dB above noise".into(),
            series: profile(false),
            ..Default::default()
        }),
        Panel::Plot(PlotPanel {
            title: "SNR versus depth".into(),
            x_label: "depth (mm)".into(),
            y_label: "SNR (dB)".into(),
            series: vec![
                line(
                    "PD",
                    depth(&snr[0]),
                    snr[0].iter().map(|r| r.1).collect(),
                    SeriesStyle::LinePoints,
                    UVD_RGB,
                ),
                line(
                    "PC-PD",
                    depth(&snr[1]),
                    snr[1].iter().map(|r| r.1).collect(),
                    SeriesStyle::LinePoints,
                    TRUTH_RGB,
                ),
            ],
            annotations: vec!["SNR: echo power in vessels / noise power".into()],
            ..Default::default()
        }),
    ];
    figs.push(render(dir, "fig6gh_network_profiles.png", "Figure 6 (g, h) analogue: power Doppler in dB above the noise floor along a horizontal line at 5 mm depth and a vertical line at x = 4.2 mm, and SNR versus depth (echo and noise images formed apart). The echoes weaken with depth (attenuation 0.5 dB/cm/MHz), so the deep vessels are where coding matters.", Figure { title: "Vessel network: signal and SNR".into(), panels, ncols: 3, panel_size_px: (520, 420) })?);
    progress.inc(1);

    // Figure 7: vector maps in three regions at increasing depth.
    let rois = [
        ((-5.8e-3, -1.6e-3), (2.0e-3, 5.0e-3)),
        ((3.4e-3, 6.4e-3), (5.8e-3, 9.4e-3)),
        ((-1.8e-3, 3.6e-3), (10.0e-3, 12.4e-3)),
    ];
    let mut panels = Vec::new();
    for (r, flow) in results.iter().zip(&flows) {
        for (k, &(x, z)) in rois.iter().enumerate() {
            let roi = Roi::new(grid, x, z)?;
            let field = VectorField {
                vx: roi.cut(&r.field().vx),
                vz: roi.cut(&r.field().vz),
            };
            panels.push(vector_panel(
                &format!("{}: ROI {}", r.estimator_name(), k + 1),
                &field,
                &roi.grid,
                &roi.cut(flow),
                &roi.cut(&black),
            ));
        }
    }
    figs.push(render(dir, "fig7_network_rois.png", "Figure 7 analogue: vector velocity (triangles point along the flow, colour = speed) in three regions at increasing depth; UVD (top) and PC-UVD (bottom).", Figure { title: "Vector velocity in three regions".into(), panels, ncols: 3, panel_size_px: (460, 440) })?);
    progress.inc(1);

    // Figure 8 (a, c, d): RI maps and arteriole / venule maps, shown where there is flow: the
    // RI stage's vessel mask (−30 dB re. the brightest pixel) lets noise through at +5 dB, and
    // pooled noise paints smooth blobs that look like vessels. Scores are over the true lumen.
    let shown = |values: &Array2<f64>, flow: &Array2<bool>| {
        Zip::from(values)
            .and(flow)
            .map_collect(|v, &f| f && v.is_finite())
    };
    let mut panels = vec![{
        let mut p = map_panel(
            "Truth: RI",
            truth.ri.clone(),
            grid,
            Colormap::Viridis,
            (0.0, 1.0),
            "RI",
        );
        p.mask = Some(finite_mask(&truth.ri));
        p.background = Some(black.clone());
        Panel::Image(p)
    }];
    for ((r, sc), flow) in results.iter().zip(scores).zip(&flows) {
        let mut p = map_panel(
            &format!(
                "{}: RI (median |error| {:.3})",
                r.estimator_name(),
                sc.median_abs_error
            ),
            r.ri.ri.clone(),
            grid,
            Colormap::Viridis,
            (0.0, 1.0),
            "RI",
        );
        p.mask = Some(shown(&r.ri.ri, flow));
        p.background = Some(black.clone());
        panels.push(Panel::Image(p));
    }
    let class_panel =
        |title: &str, psv: &Array2<f64>, class: &Array2<u8>, up: &Array2<bool>, which, flow| {
            let data = class_map(psv, class, up, which);
            let mut p = map_panel(
                title,
                data.clone(),
                grid,
                Colormap::RedBlue,
                (-vmax, vmax),
                "PSV (mm/s), red up, blue down",
            );
            p.mask = Some(match flow {
                Some(flow) => shown(&data, flow),
                None => finite_mask(&data),
            });
            p.background = Some(black.clone());
            Panel::Image(p)
        };
    for (r, flow) in results.iter().zip(&flows).rev() {
        let (name, ri) = (r.estimator_name(), &r.ri);
        panels.push(class_panel(
            &format!("{name}: arterioles (RI ≥ 0.55)"),
            &ri.psv,
            &ri.vessel_class,
            &ri.flow_up,
            ARTERIOLE,
            Some(flow),
        ));
        panels.push(class_panel(
            &format!("{name}: venules (RI ≤ 0.5)"),
            &ri.psv,
            &ri.vessel_class,
            &ri.flow_up,
            VENULE,
            Some(flow),
        ));
        panels.push(class_panel(
            &format!(
                "{name}: kind missed (correct on {:.1} %)",
                100.0 * scores[r.mode as usize].classification_accuracy
            ),
            &truth.psv,
            &Zip::from(&truth.vessel_class)
                .and(&ri.vessel_class)
                .map_collect(|&t, &e| if t != BACKGROUND && t != e { 9 } else { 0 }),
            &truth.flow_up,
            9,
            None,
        ));
    }
    figs.push(render(dir, "fig8_ri_maps.png", "Figure 8 (a, c, d) analogue: resistivity-index maps (truth, UVD, PC-UVD), then for PC-UVD and UVD the arteriole and venule maps (PSV, red = flowing up, blue = down) and the vessel pixels whose kind was missed (shown with their true PSV). Estimates are shown where power Doppler is at least 6 dB above the mode's noise floor; the scores count every pixel of the true lumen.", Figure { title: format!("Resistivity index over one cardiac cycle ({} Hz)", args.heart_rate), panels, ncols: 3, panel_size_px: (480, 470) })?);
    progress.inc(1);

    // Figure 8 (b): compounded Doppler spectrograms at four pixels, PC-UVD.
    let coded = &results[1];
    let mut panels = Vec::new();
    for (site, spec) in sites.iter().zip(&coded.spectrograms) {
        panels.push(Panel::Image(spectrogram_panel(
            site, spec, coded, phantom, truth,
        )));
    }
    figs.push(render(dir, "fig8b_spectrograms.png", "Figure 8 (b) analogue: PC-UVD compounded Doppler spectrograms (axial velocity, + = deeper) at one pixel on the axis of an arteriole and a venule flowing up and down. Dashed white: mean Doppler velocity (colour-Doppler estimate); solid cyan: vector speed with the sign of the flow's Vz; thin green: true speed; red and yellow ticks: the PSV and EDV the RI uses.", Figure { title: "PC-UVD spectrograms over the cardiac cycle".into(), panels, ncols: 2, panel_size_px: (620, 420) })?);
    progress.inc(1);
    Ok(figs)
}

fn spectrogram_panel(
    site: &Site,
    spec: &Spectrogram,
    result: &ModeResult,
    phantom: &NetworkPhantom,
    truth: &NetworkTruth,
) -> pcuvd_render::ImagePanel {
    let (iz, ix) = site.pixel;
    let t_ms: Vec<f64> = spec.times_s.iter().map(|t| t * 1e3).collect();
    let v_first = spec.velocities_m_s[0] * 1e3;
    let v_last = spec.velocities_m_s[spec.velocities_m_s.len() - 1] * 1e3;
    let series = &result.series;
    let vz_lane = series.vz.slice(s![.., iz, ix]).to_vec();
    let sign = if vz_lane.iter().sum::<f64>() < 0.0 {
        -1.0
    } else {
        1.0
    };
    let speed: Vec<f64> = series
        .speed()
        .index_axis(Axis(2), ix)
        .index_axis(Axis(1), iz)
        .iter()
        .map(|v| sign * v * 1e3)
        .collect();
    let waveform = phantom.spec().waveform(site.vessel);
    let true_speed: Vec<f64> = series
        .times_s
        .iter()
        .map(|&t| sign * truth.psv[[iz, ix]] * waveform.value(t) * 1e3)
        .collect();
    let mut lines = vec![
        Polyline {
            x_mm: t_ms.clone(),
            z_mm: spec.mean_velocity_m_s.iter().map(|v| v * 1e3).collect(),
            dashed: true,
            rgb: (255, 255, 255),
        },
        Polyline {
            x_mm: series.times_s.iter().map(|t| t * 1e3).collect(),
            z_mm: true_speed,
            dashed: false,
            rgb: (60, 200, 90),
        },
        Polyline {
            x_mm: series.times_s.iter().map(|t| t * 1e3).collect(),
            z_mm: speed.clone(),
            dashed: false,
            rgb: (80, 220, 255),
        },
    ];
    // PSV (red) and EDV (yellow) of each cycle: a short vertical tick at the sample used.
    let tick = (v_last - v_first).abs() * 0.06;
    for &(start, end) in &result.ri.cycles {
        let lane = &speed[start..end.min(speed.len())];
        let abs_max = (0..lane.len()).max_by(|&a, &b| lane[a].abs().total_cmp(&lane[b].abs()));
        let abs_min = (0..lane.len()).min_by(|&a, &b| lane[a].abs().total_cmp(&lane[b].abs()));
        for (at, rgb) in [(abs_max, (230, 40, 40)), (abs_min, (250, 210, 40))] {
            if let Some(k) = at {
                let (t, v) = (series.times_s[start + k] * 1e3, lane[k]);
                lines.push(Polyline {
                    x_mm: vec![t, t],
                    z_mm: vec![v - tick, v + tick],
                    dashed: false,
                    rgb,
                });
            }
        }
    }
    let ri = result.ri.ri[[iz, ix]];
    pcuvd_render::ImagePanel {
        title: format!(
            "{} — RI {:.2} (true {:.2})",
            site.label,
            ri,
            truth.ri[[iz, ix]]
        ),
        data: spec.power_db.t().to_owned(),
        x_mm: (t_ms[0], t_ms[t_ms.len() - 1]),
        z_mm: (v_first, v_last),
        colormap: Colormap::Gray,
        range: (-40.0, 0.0),
        colorbar_label: "dB".into(),
        lines,
        axes: Some(ImageAxes {
            x_label: "time (ms)".into(),
            y_label: "Vz (mm/s, + = deeper)".into(),
            y_up: true,
            fill: true,
        }),
        ..Default::default()
    }
}

/// The network part of report.html.
pub fn report_section(report: &mut Report, study: &NetworkStudy, args: &PaperArgs) {
    let m = &study.metrics;
    let get = |path: &[&str]| -> String {
        let mut v = m.get(path[0]).unwrap_or(&Value::Null);
        for p in &path[1..] {
            v = &v[*p];
        }
        v.as_f64()
            .map(|x| format!("{x:.3}"))
            .unwrap_or_else(|| "–".into())
    };
    let pct = |path: &[&str]| -> String {
        let mut v = m.get(path[0]).unwrap_or(&Value::Null);
        for p in &path[1..] {
            v = &v[*p];
        }
        v.as_f64()
            .map(|x| format!("{:.1} %", 100.0 * x))
            .unwrap_or_else(|| "–".into())
    };
    let pooling_text = match dynamics_params(args, Mode::Coded).map(|p| p.pooling) {
        Ok(Some(p)) => format!(
            "an ellipse aligned with each pixel's mean flow, half-length {:.2} mm along it and half-width {:.2} mm across, flow directions within {:.0}°, weights the squared mean Doppler power, speeds |V| pooled and rescaled to each pixel's own mean",
            p.along * args.grid_step,
            p.across * args.grid_step,
            p.max_angle.to_degrees()
        ),
        _ => "off".into(),
    };
    report.heading("In-vivo-like vessel network over a cardiac cycle (paper §4, Fig. 6–8)");
    report.paragraph(&format!(
        "The paper's rat setting (L22-14vX at 15.625 MHz, 8 plane waves from −15° to 15°, Hadamard order 8 with 1 µs slots, event PRF 14.4 kHz, 1.8 kHz compound rate) over {} compound frames, on a phantom with ground truth: eight straight vessels 1–13 mm deep at several orientations, four arterioles (RI 0.7, peak 20–30 mm/s, radius 0.15 mm) and four venules (RI 0.3, peak 10–14 mm/s, radius 0.2 mm), flowing up and down, parabolic profiles, pulsatile waveform w(t) = (1 − RI) + RI·((1 + cos 2πf_h t)/2)³ at {} Hz, {}; decoding: {}. Attenuation 0.5 dB/cm/MHz makes the echoes, and the SNR, fall with depth. Noise {} dB ({}). No clutter filter (no tissue). Seed {}.",
        args.network_frames, args.heart_rate, crate::paper::motion_text(args.motion), crate::paper::alignment_text(args.event_alignment), args.network_noise_db, pcuvd::simulate::NOISE_DEFINITION, args.seed
    ));
    report.paragraph(&format!(
        "Dynamics: vector velocity in {}-frame windows every {} frames, autocorrelation averaged over {} × {} pixels, each pixel's waveform shape pooled with its same-direction neighbours ({}; dynamics::VesselPooling), then fitted by a mean plus the first cardiac harmonics (dynamics::auto_harmonics) (UVD: least squares on the conventional recording; PC-UVD: IRLS-WLS on the coded one); PSV and EDV per pixel over the complete cardiac cycle (heart rate given: the recording holds about one beat); RI = (PSV − EDV)/PSV; arteriole if RI ≥ 0.55, venule if RI ≤ 0.5; vessel pixels: window power within {} dB of the strongest and whole-recording power Doppler at least {} dB above the noise floor of its depth (doppler::above_noise_floor) and within {} dB of the brightest pixel within {} mm (doppler::near_local_peak). Scores: {RI_SCORE_DEFINITION}.",
        DynamicsParams::rat().window,
        DynamicsParams::rat().step,
        DYNAMICS_KERNEL.0,
        DYNAMICS_KERNEL.1,
        pooling_text,
        -DynamicsParams::rat().min_power_db,
        dynamics::VESSEL_MARGIN_DB,
        dynamics::VESSEL_LOCAL_DB,
        dynamics::VESSEL_LOCAL_RADIUS_M * 1e3
    ));
    let rows = vec![
        vec![
            "RI median |error| over vessel pixels".into(),
            get(&["ri", "uvd", "median_abs_error"]),
            get(&["ri", "pcuvd", "median_abs_error"]),
            "≤ 0.05".into(),
        ],
        vec![
            "artery/vein classification correct".into(),
            pct(&["ri", "uvd", "classification_accuracy"]),
            pct(&["ri", "pcuvd", "classification_accuracy"]),
            "≥ 95 %".into(),
        ],
        vec![
            "vessel pixels with an RI (coverage)".into(),
            pct(&["ri", "uvd", "coverage"]),
            pct(&["ri", "pcuvd", "coverage"]),
            String::new(),
        ],
        vec![
            "flow direction correct (pixels with an RI)".into(),
            pct(&["ri", "uvd", "direction_accuracy"]),
            pct(&["ri", "pcuvd", "direction_accuracy"]),
            String::new(),
        ],
    ];
    report.table(&["quantity", "UVD", "PC-UVD", "target"], &rows);
    let vessels = m
        .get("network")
        .and_then(|n| n["vessels"].as_array().cloned())
        .unwrap_or_default();
    let per_vessel: Vec<Vec<String>> = vessels
        .iter()
        .map(|v| {
            let f = |x: &Value| x.as_f64().map_or("–".into(), |x| format!("{x:.2}"));
            let p = |x: &Value| {
                x.as_f64()
                    .map_or("–".into(), |x| format!("{:.0} %", 100.0 * x))
            };
            vec![
                v["name"].as_str().unwrap_or("").to_string(),
                v["kind"].as_str().unwrap_or("").to_string(),
                if v["flows_up"].as_bool().unwrap_or(false) {
                    "up".into()
                } else {
                    "down".into()
                },
                format!("{:.1}", v["centre_m"][1].as_f64().unwrap_or(f64::NAN) * 1e3),
                f(&v["ri"]),
                f(&v["uvd"]["median_ri"]),
                f(&v["pcuvd"]["median_ri"]),
                p(&v["uvd"]["classification_accuracy"]),
                p(&v["pcuvd"]["classification_accuracy"]),
            ]
        })
        .collect();
    report.table(
        &[
            "vessel",
            "kind",
            "flow",
            "depth (mm)",
            "true RI",
            "UVD median RI",
            "PC-UVD median RI",
            "UVD kind correct",
            "PC-UVD kind correct",
        ],
        &per_vessel,
    );
    report.heading("Network: figures");
    for fig in &study.figs {
        report.image_png(&format!("{} ({})", fig.caption, fig.file), &fig.png);
    }
}
