//! `pcuvd paper`: the paper's studies (`pcuvd::study`), drawn and written: figures,
//! `metrics.json` (the studies' typed results, serialised) and `report.html`.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use ndarray::{Array2, Zip};
use pcuvd::estimate::masks;
use pcuvd::estimate::vector::VectorField;
use pcuvd::simulate::phantom::Truth;
use pcuvd::study::dealias::DealiasMetrics;
use pcuvd::study::describe_alignment;
use pcuvd::study::network::{NetworkMetrics, NetworkSettings};
use pcuvd::study::spiral::{self, SpiralMetrics, SpiralSettings, SpiralStudy};
use pcuvd_render::{Colormap, Figure, Panel, PlotPanel, Polyline, Report, Series, SeriesStyle};
use serde::Serialize;

use crate::numbers::rounded;
use crate::progress::Bars;
use pcuvd_app::figures::{
    self, PCUVD_RGB, PROFILE_LINE_RGB, Rendered, TRUTH_RGB, UVD_RGB, VX_LABEL, VZ_LABEL, line,
    map_panel, render, vector_overlay,
};
use pcuvd_app::input::create_dir;
use pcuvd_app::settings::kernel_text;
use pcuvd_app::study::StudySettings;

mod brain;
mod report;
mod spiral_figures;

use report::*;
use spiral_figures::*;

/// Arguments of `pcuvd paper`; every default is the library's (`SpiralSettings::default()`,
/// `NetworkSettings::default()`).
#[derive(Args, Debug)]
pub struct PaperArgs {
    /// Output folder (created if needed).
    #[arg(long, required_unless_present = "print_settings")]
    pub out: Option<std::path::PathBuf>,
    /// Print the settings each study of this run would use (every default filled in, every
    /// check made), as JSON, and stop: a record of a run, or a check of what options do.
    #[arg(long)]
    pub print_settings: bool,
    /// Which study to run: all, spiral (Fig. 2–5), network (in-vivo-like, Fig. 6–8, RI maps),
    /// dealias (vector dealiasing of a tube at 1–3× the Nyquist velocity) or brain (Fig. 6–8 on
    /// the virtual rat brain, with tissue, motion and the clutter filter, scored against truth).
    #[arg(long, value_enum, default_value = "all")]
    pub part: Part,
    /// The studies' settings.
    #[command(flatten)]
    pub study: StudySettings,
}

/// Which of the paper's studies `pcuvd paper` runs.
#[derive(Clone, Copy, PartialEq, Eq, Debug, clap::ValueEnum)]
pub enum Part {
    /// Every study: the spiral, the network, the dealiasing tube and the brain.
    All,
    /// The spiral-flow simulation (Fig. 2–5, noise sweep).
    Spiral,
    /// The in-vivo-like vessel network over a cardiac cycle (Fig. 6–8, RI maps).
    Network,
    /// Vector dealiasing of a tube at 1–3× the projection Nyquist velocity (beyond the paper).
    Dealias,
    /// The in vivo experiment (Fig. 6–8) on the virtual rat brain, scored against its truth.
    Brain,
}

/// What `metrics.json` holds: the studies' typed results side by side.
#[derive(Serialize)]
struct PaperMetrics<'a> {
    #[serde(flatten)]
    spiral: Option<&'a SpiralMetrics>,
    #[serde(flatten)]
    network: Option<&'a NetworkMetrics>,
    #[serde(skip_serializing_if = "Option::is_none")]
    dealias: Option<&'a DealiasMetrics>,
    #[serde(skip_serializing_if = "Option::is_none")]
    brain: Option<&'a pcuvd_app::brain::BrainMetrics>,
    /// True for a `--quick` run: reduced settings, for a first look.
    quick: bool,
    total_s: f64,
}

/// Runs `pcuvd paper`.
pub fn run(args: &PaperArgs) -> Result<()> {
    // Every setting is checked before the first study starts.
    let runs = |part: Part| args.part == Part::All || args.part == part;
    let study = args.study.quickened();
    let spiral_settings = runs(Part::Spiral)
        .then(|| study.spiral_settings())
        .transpose()?;
    let network_settings = runs(Part::Network)
        .then(|| study.network_settings())
        .transpose()?;
    let dealias_settings = runs(Part::Dealias)
        .then(|| study.dealias_settings())
        .transpose()?;
    let brain_settings = runs(Part::Brain)
        .then(|| study.brain_settings(args.out.as_deref()))
        .transpose()?;
    if args.print_settings {
        let settings = serde_json::json!({
            "spiral": spiral_settings,
            "network": network_settings,
            "dealias": dealias_settings,
            "brain": brain_settings,
        });
        println!("{}", serde_json::to_string_pretty(&settings)?);
        return Ok(());
    }
    let Some(out) = &args.out else {
        anyhow::bail!("--out: the output folder is required");
    };
    create_dir(out)?;
    remove_other_part(out, args.part)?;
    let started = Instant::now();
    let progress = Bars::new("");
    let report_progress = pcuvd_app::progress::tasks(&progress);

    // Each study's maps are dropped once drawn: only its numbers and settings stay for the report.
    let mut spiral_done = None;
    let mut spiral_figs = Vec::new();
    if let Some(settings) = &spiral_settings {
        let study = spiral::run(settings, &report_progress)?;
        let m = &study.metrics;
        let improvement = &m.improvement_pct;
        println!(
            "spiral: SNR gain {:.2} dB (theory {:.2}); RMSE Vx/Vz mm/s: UVD {:.2}/{:.2}, PC-UVD {:.2}/{:.2} ({} % / {} % better); {:.0} s",
            m.snr_gain_db,
            m.snr_gain_theory_db,
            m.rmse_mm_s.uvd_ls.vx,
            m.rmse_mm_s.uvd_ls.vz,
            m.rmse_mm_s.pcuvd_irls.vx,
            m.rmse_mm_s.pcuvd_irls.vz,
            rounded(improvement.vx, 0),
            rounded(improvement.vz, 0),
            m.timing_s.get("total_s").copied().unwrap_or(f64::NAN)
        );
        if let Some(c) = &m.calibrated {
            match (c.noise_db, &c.rmse_mm_s, &c.improvement_pct) {
                (Some(level), Some(r), Some(gain)) => println!(
                    "spiral at the paper's baseline (UVD Vx RMSE {:.2} mm/s at {level:.2} dB): RMSE Vx/Vz mm/s: UVD {:.2}/{:.2}, PC-UVD {:.2}/{:.2} ({} % / {} % better; paper {:.2}/{:.2}, {:.0} % / {:.0} %)",
                    c.target_uvd_vx_mm_s,
                    r.uvd_ls.vx,
                    r.uvd_ls.vz,
                    r.pcuvd_irls.vx,
                    r.pcuvd_irls.vz,
                    rounded(gain.vx, 0),
                    rounded(gain.vz, 0),
                    spiral::paper::PCUVD_RMSE_MM_S.0,
                    spiral::paper::PCUVD_RMSE_MM_S.1,
                    spiral::paper::IMPROVEMENT_PCT.0,
                    spiral::paper::IMPROVEMENT_PCT.1,
                ),
                _ => println!("spiral: no calibrated noise level: {}", c.note),
            }
        }
        for a in &m.averaging {
            let at_baseline = match a.calibrated.as_ref().and_then(|c| c.rmse_mm_s) {
                Some(r) => format!(
                    "; at the paper's baseline UVD {:.2}/{:.2}, PC-UVD {:.2}/{:.2}",
                    r.uvd_ls.vx, r.uvd_ls.vz, r.pcuvd_irls.vx, r.pcuvd_irls.vz
                ),
                None => String::new(),
            };
            println!(
                "spiral, autocorrelation averaged over {} ({:.2} × {:.2} mm): RMSE Vx/Vz mm/s without noise UVD {:.2}/{:.2}, PC-UVD {:.2}/{:.2}{at_baseline}; resolution cost {:.2}/{:.2}",
                kernel_text(a.kernel),
                a.extent_mm.0,
                a.extent_mm.1,
                a.floor_mm_s.uvd_ls.vx,
                a.floor_mm_s.uvd_ls.vz,
                a.floor_mm_s.pcuvd_irls.vx,
                a.floor_mm_s.pcuvd_irls.vz,
                a.blur_rmse_mm_s.vx,
                a.blur_rmse_mm_s.vz,
            );
        }
        spiral_figs = paper_figures(out, &study)?;
        spiral_done = Some((study.metrics, study.settings));
    }
    let mut network = None;
    let mut network_figs = Vec::new();
    if let Some(settings) = &network_settings {
        let clock = Instant::now();
        let study = pcuvd::study::network::run(settings, &report_progress)?;
        let (uvd, pc) = (&study.metrics.ri.uvd, &study.metrics.ri.pcuvd);
        println!(
            "network: RI median |error| UVD {:.3}, PC-UVD {:.3}; artery/vein correct UVD {:.1} %, PC-UVD {:.1} % ({:.0} s)",
            uvd.median_abs_error,
            pc.median_abs_error,
            100.0 * uvd.classification_accuracy,
            100.0 * pc.classification_accuracy,
            clock.elapsed().as_secs_f64()
        );
        network_figs = crate::network_study::network_figures(out, &study, &progress)?;
        network = Some((study.metrics, study.settings));
    }
    let mut dealias = None;
    let mut dealias_figs = Vec::new();
    if let Some(settings) = &dealias_settings {
        let study = pcuvd::study::dealias::run(settings, &report_progress)?;
        for t in &study.metrics.targets {
            println!(
                "dealias: {}: {:.4} ({})",
                t.target,
                t.measured,
                if t.holds { "holds" } else { "does not hold" }
            );
        }
        dealias_figs = crate::dealias_study::dealias_figures(out, &study)?;
        dealias = Some(study.metrics);
    }
    let mut brain = None;
    let mut brain_figs = Vec::new();
    if let Some(settings) = &brain_settings {
        let study = pcuvd_app::brain::run(settings, &progress)?;
        println!("{}", brain::summary_line(&study.metrics));
        brain_figs = brain::brain_figures(out, &study, &progress)?;
        study.write_maps(&out.join(pcuvd_app::brain::BRAIN_MAPS_DIR))?;
        brain = Some(study.metrics);
    }
    let metrics = PaperMetrics {
        spiral: spiral_done.as_ref().map(|s| &s.0),
        network: network.as_ref().map(|n| &n.0),
        dealias: dealias.as_ref(),
        brain: brain.as_ref(),
        quick: args.study.quick,
        total_s: started.elapsed().as_secs_f64(),
    };
    // Through a JSON value, whose keys are sorted: the file reads the same whatever the struct order.
    let value = serde_json::to_value(&metrics).context("metrics.json")?;
    pcuvd_io::write_json(&out.join("metrics.json"), &value)?;
    write_report(
        out,
        &value,
        args.study.quick,
        spiral_done
            .as_ref()
            .map(|(m, s)| (m, s, spiral_figs.as_slice())),
        network
            .as_ref()
            .map(|(m, s)| (m, s, network_figs.as_slice())),
        dealias.as_ref().map(|m| (m, dealias_figs.as_slice())),
        brain.as_ref().map(|m| (m, brain_figs.as_slice())),
    )?;
    println!(
        "wrote metrics.json, report.html and {} figures to {} ({:.0} s)",
        spiral_figs.len() + network_figs.len() + dealias_figs.len() + brain_figs.len(),
        out.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The figures the spiral part writes into the output folder.
pub const SPIRAL_FIGURES: [&str; 6] = [
    "fig2_power_doppler_snr.png",
    "fig3_vector_maps.png",
    "fig4_profiles.png",
    "fig5_accuracy.png",
    BASELINE_FIGURE,
    "fig_noise_sweep.png",
];

/// Removes the figure at `path` that an earlier run wrote, if there is one.
fn remove_if_present(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => {
            Err(e).with_context(|| format!("{}: cannot remove this earlier figure", path.display()))
        }
    }
}

/// The subfolders where the spiral part draws each mode's maps ([`figures::PROCESS_FIGURES`]).
const MODE_FOLDERS: [&str; 2] = ["conventional", "coded"];

/// Removes the figures that the parts not run now wrote into `dir` in an earlier run, so that the
/// folder holds no figure that its report.html leaves out. Only files of pcuvd's own naming go;
/// a mode subfolder goes only when nothing else is left in it.
fn remove_other_part(dir: &Path, part: Part) -> Result<()> {
    let mut stale: Vec<std::path::PathBuf> = Vec::new();
    let spiral_off = !matches!(part, Part::All | Part::Spiral);
    if spiral_off {
        stale.extend(SPIRAL_FIGURES.iter().map(|f| dir.join(f)));
        for folder in MODE_FOLDERS {
            stale.extend(
                figures::PROCESS_FIGURES
                    .iter()
                    .map(|f| dir.join(folder).join(f)),
            );
        }
    }
    if !matches!(part, Part::All | Part::Network) {
        stale.extend(
            crate::network_study::NETWORK_FIGURES
                .iter()
                .map(|f| dir.join(f)),
        );
    }
    if !matches!(part, Part::All | Part::Brain) {
        stale.extend(brain::BRAIN_FIGURES.iter().map(|f| dir.join(f)));
    }
    if !matches!(part, Part::All | Part::Dealias) {
        stale.extend(
            crate::dealias_study::DEALIAS_FIGURES
                .iter()
                .map(|f| dir.join(f)),
        );
    }
    for path in stale {
        remove_if_present(&path)?;
    }
    if spiral_off {
        for folder in MODE_FOLDERS {
            // Fails, and is meant to, where the folder holds anything else.
            let _ = std::fs::remove_dir(dir.join(folder));
        }
    }
    Ok(())
}
