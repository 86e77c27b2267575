//! The spiral study's figures: maps of each method beside the truth, profiles, error against
//! noise, and the spatial averaging's effect.

use super::*;
use pcuvd::core::grid::Grid;

pub(super) fn masked(values: &Array2<f64>, mask: &Array2<bool>, scale: f64) -> Array2<f64> {
    Zip::from(values)
        .and(mask)
        .map_collect(|&v, &m| if m { v * scale } else { f64::NAN })
}

pub(super) fn paper_figures(dir: &Path, study: &SpiralStudy) -> Result<Vec<Rendered>> {
    let mut out = Vec::new();
    let (conv, coded) = (&study.conventional, &study.coded);
    let (truth, grid, phantom, snr) = (&study.truth, &study.grid, &study.phantom, &study.snr);
    let noise_power = &study.noise_power;
    let sweep = &study.metrics.noise_sweep;

    // Fig. 4's profiles: across the vessel at a deep crossing (flow mostly lateral) and a side
    // crossing (flow mostly axial), at polar angle α0, over the offsets l of its bins.
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
    const PROFILE_HALF_WIDTH_M: f64 = 0.6e-3;
    let profile_lines: Vec<Polyline> = sections
        .iter()
        .map(|&(_, alpha0, _)| {
            let ends =
                [-PROFILE_HALF_WIDTH_M, PROFILE_HALF_WIDTH_M].map(|l| spec.position(alpha0, l));
            Polyline {
                x_mm: ends.iter().map(|p| p[0] * 1e3).collect(),
                z_mm: ends.iter().map(|p| p[1] * 1e3).collect(),
                dashed: false,
                rgb: PROFILE_LINE_RGB,
                label: "profiles of Fig. 4".into(),
            }
        })
        .collect();

    // Figure 2: PD and PC-PD, in dB above each image's own noise floor, and SNR versus depth.
    let mut panels = Vec::new();
    let pd_db = [
        masks::db_above_noise(&conv.maps.power_doppler, &noise_power[0]),
        masks::db_above_noise(&coded.maps.power_doppler, &noise_power[1]),
    ];
    // One range for both, from the data: neither map clips at its top.
    let pd_range = figures::shared_db_range(&[&pd_db[0], &pd_db[1]]);
    for (db, title) in pd_db
        .into_iter()
        .zip(["PD (conventional)", "PC-PD (Hadamard-coded)"])
    {
        let mut panel = map_panel(title, db, grid, Colormap::Hot, pd_range, "dB above noise");
        panel.lines = profile_lines.clone();
        panels.push(Panel::Image(panel));
    }
    let depth_mm = |rows: &[pcuvd::evaluate::metrics::DepthSnr]| {
        rows.iter().map(|r| r.depth_m * 1e3).collect::<Vec<_>>()
    };
    let snr_db = |rows: &[pcuvd::evaluate::metrics::DepthSnr], plus: f64| {
        rows.iter().map(|r| r.snr_db + plus).collect::<Vec<_>>()
    };
    let theory = study.metrics.snr_gain_theory_db;
    panels.push(Panel::Plot(PlotPanel {
        title: "SNR versus depth".into(),
        x_label: "depth (mm)".into(),
        y_label: "SNR (dB)".into(),
        series: vec![
            line(
                "PD",
                depth_mm(&snr[0]),
                snr_db(&snr[0], 0.0),
                SeriesStyle::LinePoints,
                UVD_RGB,
            ),
            line(
                "PC-PD",
                depth_mm(&snr[1]),
                snr_db(&snr[1], 0.0),
                SeriesStyle::LinePoints,
                TRUTH_RGB,
            ),
            line(
                &format!("PD + {theory:.2} dB (theory)"),
                depth_mm(&snr[0]),
                snr_db(&snr[0], theory),
                SeriesStyle::DashedLine,
                (120, 120, 120),
            ),
        ],
        annotations: vec!["SNR: echo power in vessel / noise power".into()],
        ..Default::default()
    }));
    out.push(render(dir, "fig2_power_doppler_snr.png", "Figure 2 analogue: conventional power Doppler (PD) and pulse-coded power Doppler (PC-PD), each in dB above its own noise floor (cyan: the lines across the vessel along which Fig. 4's profiles are taken), and SNR versus depth.", Figure { title: format!("Power Doppler, noise {} dB", study.settings.noise_db), panels, ncols: 3, panel_size_px: (520, 470) })?);

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
        ("UVD", conv.maps.vector_ls.clone().expect("8 angles")),
        ("PC-UVD", coded.maps.vector_irls.clone().expect("8 angles")),
    ];
    for (name, field) in &rows {
        let speed = field.speed();
        panels.push(vx_panel(name, field, truth, grid, vmax));
        // Vz is positive deeper: the reversed map keeps red = toward the probe (up), as in
        // every other figure and in the paper.
        panels.push(Panel::Image(map_panel(
            &format!("{name}: Vz"),
            masked(&field.vz, &truth.mask, 1e3),
            grid,
            Colormap::BlueRed,
            (-vmax, vmax),
            VZ_LABEL,
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
    out.push(render(dir, "fig3_vector_maps.png", "Figure 3 analogue: ground truth (top), conventional UVD with least squares (middle) and PC-UVD with IRLS-WLS (bottom): Vx (red = toward +x), Vz (red = toward the probe, up, as in every figure), speed and vector map inside the vessel.", Figure { title: format!("Spiral flow: vector velocity, noise {} dB", study.settings.noise_db), panels, ncols: 4, panel_size_px: (430, 400) })?);

    // Figure 4: the profiles (drawn as lines on Fig. 2).
    let mut panels = Vec::new();
    for (title, alpha0, component) in sections {
        let bins: Vec<f64> = (0..24)
            .map(|i| -PROFILE_HALF_WIDTH_M + (i as f64 + 0.5) * 0.05e-3)
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
                let b =
                    (((l + PROFILE_HALF_WIDTH_M) / 0.05e-3).floor() as usize).min(bins.len() - 1);
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
    out.push(render(dir, "fig4_profiles.png", "Figure 4 analogue: velocity profiles across the vessel versus distance from its centre (mean over a 0.2 rad stretch of the vessel, 0.05 mm bins).", Figure { title: format!("Velocity profiles, noise {} dB", study.settings.noise_db), panels, ncols: 2, panel_size_px: (560, 440) })?);

    // Figure 5: estimated versus true, binned per 1 mm/s, error bars = standard deviation.
    let mut panels = Vec::new();
    for (name, field) in [("UVD", &rows[1].1), ("PC-UVD", &rows[2].1)] {
        for component in [Component::Vx, Component::Vz] {
            panels.push(accuracy_panel(name, component, field, truth));
        }
    }
    out.push(render(dir, "fig5_accuracy.png", "Figure 5 analogue: estimated versus true velocity over all vessel pixels; points are means per 1 mm/s bin of the truth, bars one standard deviation; RMSE over all vessel pixels.", Figure { title: format!("Accuracy of Vx and Vz, noise {} dB", study.settings.noise_db), panels, ncols: 2, panel_size_px: (500, 460) })?);

    // Figures 3 and 5 again at the paper's own baseline, where pcuvd's main level leaves both
    // methods at their noise-free floor and the paper's contrast does not show.
    let baseline = dir.join(BASELINE_FIGURE);
    match (&study.at_baseline, &study.metrics.calibrated) {
        (Some(at), Some(calibrated)) => {
            let mut panels = Vec::new();
            for (name, field) in [("UVD", &at.uvd), ("PC-UVD", &at.pcuvd)] {
                panels.push(vx_panel(name, field, truth, grid, vmax));
                for component in [Component::Vx, Component::Vz] {
                    panels.push(accuracy_panel(name, component, field, truth));
                }
            }
            let title = format!(
                "At the paper's baseline: noise {:+.1} dB, where UVD's Vx RMSE is the paper's {:.2} mm/s",
                at.noise_db, calibrated.target_uvd_vx_mm_s
            );
            out.push(render(dir, BASELINE_FIGURE, "Figures 3 and 5 at the paper's own baseline (the noise level calibrated so that conventional UVD's Vx RMSE is the paper's, Fig. 5a): each method's Vx inside the vessel (the truth is Fig. 3's top row), and its estimated versus true velocity as in Fig. 5.", Figure { title, panels, ncols: 3, panel_size_px: (480, 440) })?);
        }
        // No level found, or none asked for: no figure, and none left from an earlier run.
        _ => remove_if_present(&baseline)?,
    }

    // Beyond the paper: RMSE versus noise level for four estimators.
    let levels: Vec<f64> = sweep.iter().map(|r| r.noise_db).collect();
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
                        let rmse = r.rmse.named()[k].1;
                        if component == "Vx" { rmse.vx } else { rmse.vz }
                    })
                    .collect();
                line(label, levels.clone(), y, style, rgb)
            })
            .collect();
        // The main study's level: a vertical dashed line over the plot's height (a marker at
        // RMSE 0 looked like a data point).
        let mut series: Vec<Series> = series;
        let top = series
            .iter()
            .flat_map(|s| s.y.iter().copied())
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max);
        let main = study.settings.noise_db;
        series.push(line(
            &format!("main study ({main} dB)"),
            vec![main, main],
            vec![0.0, top],
            SeriesStyle::DashedLine,
            (120, 120, 120),
        ));
        if let Some(at) = &study.at_baseline {
            series.push(line(
                &format!(
                    "paper's baseline ({:+.1} dB, {BASELINE_FIGURE})",
                    at.noise_db
                ),
                vec![at.noise_db, at.noise_db],
                vec![0.0, top],
                SeriesStyle::DashedLine,
                BASELINE_LINE_RGB,
            ));
        }
        panels.push(Panel::Plot(PlotPanel {
            title: format!("RMSE of {component} versus noise level"),
            x_label: "noise level (dB, see definition)".into(),
            y_label: format!("RMSE {component} (mm/s)"),
            series,
            ..Default::default()
        }));
    }
    out.push(render(dir, "fig_noise_sweep.png", "Beyond the paper: RMSE of Vx and Vz versus channel noise level for conventional and coded transmission, each with least squares and IRLS-WLS (same scatterers and noise realisation at every level); the dashed verticals mark the main study's level and the level calibrated to the paper's baseline.", Figure { title: "Noise sweep".into(), panels, ncols: 2, panel_size_px: (560, 440) })?);

    // The maps of each mode, as `pcuvd process` would draw them.
    for (o, mode) in [conv, coded].into_iter().zip(MODE_FOLDERS) {
        let sub = dir.join(mode);
        create_dir(&sub)?;
        figures::process_figures(&sub, o, &format!("spiral, {mode}"))?;
    }
    Ok(out)
}

/// The figure of Figs. 3 and 5 at the paper's calibrated baseline (absent without one).
pub(super) const BASELINE_FIGURE: &str = "fig5b_accuracy_at_baseline.png";

/// The noise sweep's mark of the calibrated baseline (a dark teal, apart from the methods' colours).
const BASELINE_LINE_RGB: (u8, u8, u8) = (0, 110, 110);

/// `name`'s Vx (mm/s) inside the true vessel, red toward +x, on ±`vmax` mm/s.
fn vx_panel(name: &str, field: &VectorField, truth: &Truth, grid: &Grid, vmax: f64) -> Panel {
    Panel::Image(map_panel(
        &format!("{name}: Vx"),
        masked(&field.vx, &truth.mask, 1e3),
        grid,
        Colormap::RedBlue,
        (-vmax, vmax),
        VX_LABEL,
    ))
}

/// A velocity component of a vector field.
#[derive(Clone, Copy)]
enum Component {
    Vx,
    Vz,
}

/// `name`'s estimated `component` against the truth over the vessel pixels, as the paper's Fig. 5:
/// means per 1 mm/s bin of the truth (bins of at least 5 pixels), one standard deviation as
/// bars, the RMSE over every vessel pixel.
fn accuracy_panel(name: &str, component: Component, field: &VectorField, truth: &Truth) -> Panel {
    let err = pcuvd::evaluate::metrics::rmse(field, truth);
    let (label, est, tru, value) = match component {
        Component::Vx => ("Vx", &field.vx, &truth.vx, err.vx),
        Component::Vz => ("Vz", &field.vz, &truth.vz, err.vz),
    };
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
    Panel::Plot(PlotPanel {
        title: format!("{name}: {label}"),
        x_label: format!("true {label} (mm/s)"),
        y_label: format!("estimated {label} (mm/s)"),
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
    })
}
