//! `pcuvd paper`, brain part (paper §4, Fig. 6–8 on the virtual rat brain): the figures and the
//! report section of [`pcuvd_app::brain`].

use std::path::Path;

use crate::numbers::rounded;
use anyhow::Result;
use ndarray::{Array2, Zip};
use pcuvd::core::grid::{Grid, Roi};
use pcuvd::dynamics::{ARTERIOLE, RiMaps, VENULE};
use pcuvd::estimate::vector::VectorField;
use pcuvd_app::Progress;
use pcuvd_app::brain::{BrainMetrics, BrainStudy, GroupScores, VectorScore};
use pcuvd_app::figures::{
    PCUVD_RGB, PROFILE_LINE_RGB, PSV_UP_LABEL, Rendered, TRUTH_RGB, UVD_RGB, axial_velocity_panel,
    class_map, line, map_panel, mean_doppler_line, region_outline, render, shared_db_range,
    spectrogram_panel, speed_scale, vector_panel,
};
use pcuvd_render::{Colormap, Figure, Panel, PlotPanel, Polyline, Report, SeriesStyle};

/// The figures the brain part writes into the output folder.
pub const BRAIN_FIGURES: [&str; 5] = [
    "fig6_brain_doppler.png",
    "fig6gh_brain_profiles.png",
    "fig7_brain_rois.png",
    "fig8_brain_ri.png",
    "fig8b_brain_spectrograms.png",
];

/// Depths (m) of the two horizontal profile lines of Fig. 6 g, h: the cortex and the deep vessels.
const PROFILE_DEPTHS_M: [f64; 2] = [2.0e-3, 7.0e-3];

/// Power Doppler in dB over the median of the pixels with no blood in the beam: the level a
/// vessel stands above its surroundings.
fn db_over_background(power: &Array2<f64>, blood: &Array2<bool>) -> Array2<f64> {
    let background: Vec<f64> = Zip::from(power)
        .and(blood)
        .fold(Vec::new(), |mut v, &p, &b| {
            if !b {
                v.push(p);
            }
            v
        });
    let floor = pcuvd::core::stats::median(background).max(f64::MIN_POSITIVE);
    power.mapv(|p| 10.0 * (p.max(f64::MIN_POSITIVE) / floor).log10())
}

/// Side of the square regions of Fig. 7 (m).
const REGION_SIDE_M: f64 = 2.4e-3;

/// Three square regions at increasing depth: the lumen pixels' depth range in thirds, each region
/// centred on the median position of its third's lumen pixels, kept inside the image. (x range,
/// z range) in m.
fn regions(lumen: &Array2<bool>, grid: &Grid) -> Vec<((f64, f64), (f64, f64))> {
    let lumen: Vec<(f64, f64)> = lumen
        .indexed_iter()
        .filter(|(_, l)| **l)
        .map(|((iz, ix), _)| (grid.x[ix], grid.z[iz]))
        .collect();
    let (top, bottom) = lumen
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &(_, z)| {
            (a.min(z), b.max(z))
        });
    let third = (bottom - top) / 3.0;
    let (x_lo, x_hi) = (grid.x[0], grid.x[grid.x.len() - 1]);
    let (z_lo, z_hi) = (grid.z[0], grid.z[grid.z.len() - 1]);
    (0..3)
        .filter_map(|k| {
            let (z0, z1) = (top + k as f64 * third, top + (k + 1) as f64 * third);
            let inside: Vec<(f64, f64)> = lumen
                .iter()
                .filter(|&&(_, z)| z >= z0 && z <= z1)
                .copied()
                .collect();
            if inside.is_empty() {
                return None;
            }
            let half = 0.5 * REGION_SIDE_M;
            let centre_of = |values: Vec<f64>, lo: f64, hi: f64| {
                pcuvd::core::stats::median(values).clamp(lo + half, (hi - half).max(lo + half))
            };
            let x = centre_of(inside.iter().map(|p| p.0).collect(), x_lo, x_hi);
            let z = centre_of(inside.iter().map(|p| p.1).collect(), z_lo, z_hi);
            Some(((x - half, x + half), (z - half, z + half)))
        })
        .collect()
}

/// Figures 6–8 of the brain study, drawn into `dir`.
pub fn brain_figures(
    dir: &Path,
    study: &BrainStudy,
    progress: &dyn Progress,
) -> Result<Vec<Rendered>> {
    let task = "brain figures";
    progress.update(task, 0, 5);
    let full = &study.modes[0].out.grid;
    // The maps end 1.5 mm below the deepest lumen pixel: the default grid reaches as deep as the
    // traces do, far below any vessel.
    let deepest = study
        .lumen
        .indexed_iter()
        .filter(|(_, l)| **l)
        .map(|((iz, _), _)| full.z[iz])
        .fold(full.z[0], f64::max);
    let view = Roi::new(
        full,
        (full.x[0], full.x[full.x.len() - 1]),
        (full.z[0], (deepest + 1.5e-3).min(full.z[full.z.len() - 1])),
    )?;
    let grid = &view.grid;
    let truth = &study.truth;
    let blood = &view.cut(&truth.truth.mask);
    let lumen = &view.cut(&study.lumen);
    let black = Array2::<f64>::zeros(grid.shape());
    let truth_field = VectorField {
        vx: view.cut(&truth.truth.vx),
        vz: view.cut(&truth.truth.vz),
    };
    let fields: Vec<VectorField> = study
        .modes
        .iter()
        .map(|m| {
            m.field().map(|f| VectorField {
                vx: view.cut(&f.vx),
                vz: view.cut(&f.vz),
            })
        })
        .collect::<Result<_>>()?;
    let detected: Vec<Array2<bool>> = study.modes.iter().map(|m| view.cut(&m.detected)).collect();
    let speed_max = speed_scale(&[
        (&fields[0], &detected[0]),
        (&fields[1], &detected[1]),
        (&truth_field, lumen),
    ]);
    let mut figs = Vec::new();

    // Figure 6: power, colour and vector Doppler, UVD, PC-UVD, truth.
    let pd_db: Vec<Array2<f64>> = study
        .modes
        .iter()
        .map(|m| db_over_background(&view.cut(&m.out.maps.power_doppler), blood))
        .collect();
    let pd_range = shared_db_range(&pd_db.iter().collect::<Vec<_>>());
    let x_ends = (grid.x[0] * 1e3, grid.x[grid.x.len() - 1] * 1e3);
    let rows: Vec<usize> = PROFILE_DEPTHS_M
        .iter()
        .map(|&z| grid.nearest_pixel(0.0, z).0)
        .collect();
    let rois = regions(lumen, grid);
    let mut guides: Vec<Polyline> = rows
        .iter()
        .map(|&row| Polyline {
            x_mm: vec![x_ends.0, x_ends.1],
            z_mm: vec![grid.z[row] * 1e3; 2],
            dashed: false,
            rgb: PROFILE_LINE_RGB,
            label: "profiles of Fig. 6 g, h".into(),
        })
        .collect();
    guides.extend(
        rois.iter()
            .map(|&(x, z)| region_outline(x, z, "regions of Fig. 7")),
    );
    let vmax = 20.0;
    let mut panels = Vec::new();
    for (((mode, db), field), detected) in
        study.modes.iter().zip(&pd_db).zip(&fields).zip(&detected)
    {
        let mut pd = map_panel(
            &format!("{}: power Doppler", mode.method()),
            db.clone(),
            grid,
            Colormap::Hot,
            pd_range,
            "dB over the median of blood-free pixels",
        );
        pd.lines = guides.clone();
        panels.push(Panel::Image(pd));
        panels.push(axial_velocity_panel(
            &format!("{}: colour Doppler", mode.method()),
            &view.cut(&mode.out.maps.color_doppler),
            grid,
            vmax,
            detected,
        ));
        panels.push(vector_panel(
            &format!("{}: vector Doppler", mode.method()),
            field,
            grid,
            detected,
            &black,
            speed_max,
        ));
    }
    let mut fraction = map_panel(
        "Truth: blood's share of each pixel's voxel",
        truth
            .elevation
            .as_ref()
            .map_or_else(|| black.clone(), |(_, f)| view.cut(f)),
        grid,
        Colormap::Hot,
        (0.0, 0.1),
        "blood's share of the voxel (saturates at 10 %)",
    );
    fraction.mask = Some(blood.clone());
    fraction.background = Some(black.clone());
    panels.push(Panel::Image(fraction));
    panels.push(axial_velocity_panel(
        "Truth: axial velocity (lumen)",
        &truth_field.vz,
        grid,
        vmax,
        lumen,
    ));
    panels.push(vector_panel(
        "Truth: vector velocity (lumen)",
        &truth_field,
        grid,
        lumen,
        &black,
        speed_max,
    ));
    figs.push(render(
        dir,
        BRAIN_FIGURES[0],
        "Figure 6 analogue on the virtual rat brain: power Doppler (dB over the median of the pixels with no blood in the elevation beam; cyan: the lines of Fig. 6 g, h; dashed green: the regions of Fig. 7), colour Doppler and vector Doppler after the SVD clutter filter; UVD (top), PC-UVD (middle), truth (bottom: the blood's share of each pixel's elevation beam, and the beam-weighted blood velocity over the lumen pixels the scores count). Flow maps show each method's vessel mask.",
        Figure {
            title: format!(
                "Virtual rat brain, {} frames: UVD, PC-UVD, truth",
                study.metrics.frames
            ),
            panels,
            ncols: 3,
            panel_size_px: (520, 500),
        },
    )?);
    progress.update(task, 1, 5);

    // Figure 6 (g, h): power Doppler along the two lines; vessel-to-background ratio by depth.
    let x_mm: Vec<f64> = grid.x.iter().map(|x| x * 1e3).collect();
    let mut panels: Vec<Panel> = rows
        .iter()
        .map(|&row| {
            let mut series: Vec<pcuvd_render::Series> = study
                .modes
                .iter()
                .zip(&pd_db)
                .zip([UVD_RGB, PCUVD_RGB])
                .map(|((mode, db), rgb)| {
                    line(
                        &format!("{} power Doppler", mode.method()),
                        x_mm.clone(),
                        db.row(row).to_vec(),
                        SeriesStyle::Line,
                        rgb,
                    )
                })
                .collect();
            // Where the truth has lumen on the line, at the plot's floor.
            let marks: Vec<(f64, f64)> = (0..grid.x.len())
                .filter(|&ix| lumen[[row, ix]])
                .map(|ix| (x_mm[ix], 0.0))
                .collect();
            series.push(line(
                "true lumen",
                marks.iter().map(|m| m.0).collect(),
                marks.iter().map(|m| m.1).collect(),
                SeriesStyle::Points,
                TRUTH_RGB,
            ));
            Panel::Plot(PlotPanel {
                title: format!("power Doppler along z = {:.1} mm", grid.z[row] * 1e3),
                x_label: "x (mm)".into(),
                y_label: "dB over blood-free median".into(),
                series,
                ..Default::default()
            })
        })
        .collect();
    let contrast = &study.metrics.contrast_by_depth;
    let depth: Vec<f64> = contrast
        .iter()
        .map(|b| 0.5 * (b.depth_mm[0] + b.depth_mm[1]))
        .collect();
    let theory_db = 10.0 * 8f64.log10();
    // Across the bands' depths (where there is one band, at it).
    let theory_x: Vec<f64> = match (depth.first(), depth.last()) {
        (Some(&first), Some(&last)) if last > first => vec![first, last],
        _ => depth.clone(),
    };
    let theory_points = theory_x.len();
    panels.push(Panel::Plot(PlotPanel {
        title: "vessel over background, by depth".into(),
        x_label: "depth (mm)".into(),
        y_label: "dB".into(),
        series: vec![
            line(
                "conventional",
                depth.clone(),
                contrast.iter().map(|b| b.conventional_db).collect(),
                SeriesStyle::LinePoints,
                UVD_RGB,
            ),
            line(
                "coded",
                depth.clone(),
                contrast.iter().map(|b| b.coded_db).collect(),
                SeriesStyle::LinePoints,
                PCUVD_RGB,
            ),
            line(
                "gain (coded − conventional)",
                depth.clone(),
                contrast.iter().map(|b| b.gain_db).collect(),
                SeriesStyle::LinePoints,
                TRUTH_RGB,
            ),
            // The gain's reference: coding 8 angles lowers the noise by 10·log10 8 against the
            // echoes; a background the noise does not set (tissue residue, the blood's own
            // side lobes) keeps the measured gain below it.
            line(
                &format!("theory for 8 angles ({theory_db:.2} dB)"),
                theory_x,
                vec![theory_db; theory_points],
                SeriesStyle::DashedLine,
                TRUTH_RGB,
            ),
        ],
        ..Default::default()
    }));
    figs.push(render(
        dir,
        BRAIN_FIGURES[1],
        "Figure 6 (g, h) analogue: power Doppler along a line through the cortex and one through the deep vessels (blue points: the true lumen pixels on the line), and the vessel-to-background ratio by 1 mm depth band (mean power over the lumen pixels over the median of the blood-free pixels) for both modes, with the gain of coding.",
        Figure {
            title: "Virtual rat brain: power Doppler profiles and the gain of coding".into(),
            panels,
            ncols: 3,
            panel_size_px: (520, 420),
        },
    )?);
    progress.update(task, 2, 5);

    // Figure 7: vector velocity in three regions, UVD, PC-UVD, truth.
    let mut panels = Vec::new();
    let rows_of_fig7: [(&str, &VectorField, &Array2<bool>); 3] = [
        (study.modes[0].method(), &fields[0], &detected[0]),
        (study.modes[1].method(), &fields[1], &detected[1]),
        ("Truth", &truth_field, lumen),
    ];
    for (name, field, mask) in rows_of_fig7 {
        for (k, &(x, z)) in rois.iter().enumerate() {
            let roi = Roi::new(grid, x, z)?;
            let cut = VectorField {
                vx: roi.cut(&field.vx),
                vz: roi.cut(&field.vz),
            };
            panels.push(vector_panel(
                &format!("{name}: region {}", k + 1),
                &cut,
                &roi.grid,
                &roi.cut(mask),
                &roi.cut(&black),
                speed_max,
            ));
        }
    }
    figs.push(render(
        dir,
        BRAIN_FIGURES[2],
        "Figure 7 analogue: vector velocity (triangles along the flow, colour = speed) in three regions at increasing depth; UVD (top), PC-UVD (middle), truth over the lumen pixels (bottom).",
        Figure {
            title: "Virtual rat brain: vector velocity in three regions".into(),
            panels,
            ncols: rois.len().max(1),
            panel_size_px: (460, 440),
        },
    )?);
    progress.update(task, 3, 5);

    // Figure 8: RI, arterioles and venules: truth, UVD, PC-UVD. A method without RI maps (a
    // recording too short to find the heartbeat in) keeps its column, empty, its titles saying
    // why, so that the figure never shows the truth alone as if it were the whole comparison.
    let cycle = truth.cycle.as_ref();
    let mut panels = Vec::new();
    let shown_where = |data: &Array2<f64>, shown: &Array2<bool>| {
        Zip::from(data)
            .and(shown)
            .map_collect(|v, &s| s && v.is_finite())
    };
    // (the method, its RI maps or why it has none, its vessel mask); a placeholder panel shows
    // nothing on black.
    let none = Array2::from_elem(grid.shape(), false);
    let columns: Vec<(&str, Result<&RiMaps, String>, &Array2<bool>)> = study
        .modes
        .iter()
        .zip(&detected)
        .map(|(m, detected)| {
            let maps =
                m.ri.as_ref()
                    .ok_or_else(|| no_ri_reason(m.ri_skipped.as_deref().unwrap_or("not computed")));
            (m.method(), maps, detected)
        })
        .collect();
    let ncols = usize::from(cycle.is_some()) + columns.len();
    // One row of the figure: the truth's map over the lumen, then each method's over its vessel
    // mask, or an empty panel whose title (`missing(why)`) says why it has none.
    let mut row = |what: &str,
                   truth_map: Option<Array2<f64>>,
                   method_map: &dyn Fn(&RiMaps) -> Array2<f64>,
                   missing: &dyn Fn(&str) -> String,
                   (colormap, range, label): (Colormap, (f64, f64), &str)| {
        let truth_entry = truth_map.map(|t| (format!("Truth: {what}"), t, lumen));
        let method_entries = columns.iter().map(|(name, maps, detected)| match maps {
            Ok(ri) => (format!("{name}: {what}"), method_map(ri), *detected),
            Err(why) => (format!("{name}: {}", missing(why)), black.clone(), &none),
        });
        for (title, data, shown) in truth_entry.into_iter().chain(method_entries) {
            let mask = shown_where(&data, shown);
            let mut p = map_panel(&title, data, grid, colormap, range, label);
            p.mask = Some(mask);
            p.background = Some(black.clone());
            panels.push(Panel::Image(p));
        }
    };
    row(
        "RI",
        cycle.map(|c| view.cut(&c.ri)),
        &|ri| view.cut(&ri.ri),
        &|why| format!("no RI:\n{why}"),
        (Colormap::Viridis, (0.0, 1.0), "RI"),
    );
    for (which, kind) in [(ARTERIOLE, "arterioles"), (VENULE, "venules")] {
        row(
            kind,
            cycle.map(|c| view.cut(&class_map(&c.psv, &c.vessel_class, &c.flow_up, which))),
            &|ri| view.cut(&class_map(&ri.psv, &ri.vessel_class, &ri.flow_up, which)),
            &|_| format!("no {kind} (no RI)"),
            (Colormap::RedBlue, (-vmax, vmax), PSV_UP_LABEL),
        );
    }
    figs.push(render(
        dir,
        BRAIN_FIGURES[3],
        "Figure 8 (a, c, d) analogue: resistivity index, arterioles and venules (PSV, red = flowing up, blue = down): truth over the lumen pixels, then UVD and PC-UVD over their vessel masks (empty, the title saying why, where a method has no RI maps). The scores count the lumen pixels.",
        Figure {
            title: "Virtual rat brain: resistivity index over the cardiac cycle".into(),
            panels,
            ncols: ncols.max(1),
            panel_size_px: (480, 470),
        },
    )?);
    progress.update(task, 4, 5);
    if study
        .modes
        .iter()
        .any(|m| m.spectrograms.iter().any(Option::is_some))
    {
        figs.push(spectrogram_figure(dir, study)?);
    }
    progress.update(task, 5, 5);
    Ok(figs)
}

/// Fig. 8b analogue: each site's compounded Doppler spectrogram, UVD beside PC-UVD, with the
/// mean Doppler velocity and the vessel's true peak and end-diastolic speeds.
fn spectrogram_figure(dir: &Path, study: &BrainStudy) -> Result<Rendered> {
    let mut panels = Vec::new();
    for (k, site) in study.sites.iter().enumerate() {
        for mode in &study.modes {
            let Some(Some(spec)) = mode.spectrograms.get(k) else {
                continue;
            };
            let t = &spec.times_s;
            let span = (t[0] * 1e3, t[t.len() - 1] * 1e3);
            // pcuvd's axial velocity is positive moving deeper: upward flow reads negative.
            let sign = if site.flows_up { -1.0 } else { 1.0 };
            let level = |v: f64, dashed: bool, label: &str| Polyline {
                x_mm: vec![span.0, span.1],
                z_mm: vec![sign * v * 1e3; 2],
                dashed,
                rgb: TRUTH_RGB,
                label: label.into(),
            };
            let mut lines = vec![
                mean_doppler_line(spec),
                level(
                    site.true_psv_m_s,
                    false,
                    "true PSV (speed, sign of the flow)",
                ),
                level(site.true_edv_m_s, true, "true EDV"),
            ];
            // One legend for the figure (the first panel's).
            if !panels.is_empty() {
                lines.iter_mut().for_each(|l| l.label.clear());
            }
            let ri = mode
                .ri
                .as_ref()
                .map(|r| r.ri[site.pixel])
                .filter(|v| v.is_finite())
                .map_or_else(|| "no RI".to_string(), |v| format!("RI {v:.2}"));
            let title = format!(
                "{}: {} — {ri} (true {:.2})",
                mode.method(),
                site.label,
                site.true_ri
            );
            panels.push(Panel::Image(spectrogram_panel(title, spec, lines)));
        }
    }
    render(
        dir,
        BRAIN_FIGURES[4],
        "Figure 8 (b) analogue: compounded Doppler spectrograms (axial velocity, + = deeper) at one pixel on the axis of the widest arteriole and venule of each direction, UVD beside PC-UVD. Dashed white: the mean Doppler velocity (colour Doppler); blue: the vessel's true peak systolic (solid) and end-diastolic (dashed) speed, signed as its flow, which the axial velocity reaches only where the vessel runs along the beam. A long recording is processed in segments, each clutter-filtered on its own: a bright column where one segment meets the next is that seam, not flow.",
        Figure {
            title: "Virtual rat brain: spectrograms over the cardiac cycle".into(),
            panels,
            ncols: 2,
            panel_size_px: (620, 420),
        },
    )
}

/// One line of the brain's scores for the terminal.
pub fn summary_line(m: &BrainMetrics) -> String {
    let deep = m.vector_by_depth.last();
    let ri = m.ri.first();
    format!(
        "brain: vector RMSE UVD {:.2}, PC-UVD {:.2} mm/s ({} % lower){}{}; coding gain {} dB by 1 mm band",
        m.vector_all.uvd.rmse_mm_s,
        m.vector_all.pcuvd.rmse_mm_s,
        rounded(m.vector_all.improvement_pct, 0),
        deep.map_or(String::new(), |d| format!(
            "; deepest third {:.2} vs {:.2} ({} %)",
            d.uvd.rmse_mm_s,
            d.pcuvd.rmse_mm_s,
            rounded(d.improvement_pct, 0)
        )),
        ri.and_then(|r| r.pcuvd).map_or_else(
            || m.ri_skipped.first().map_or(String::new(), |skipped| {
                format!("; no RI maps: {}", refusal(skipped))
            }),
            |r| format!(
                "; PC-UVD RI median |error| {:.3}, class right {:.1} % ({} px)",
                r.median_abs_error,
                100.0 * r.class_accuracy,
                r.pixels
            )
        ),
        m.contrast_by_depth
            .iter()
            .map(|b| rounded(b.gain_db, 1))
            .collect::<Vec<_>>()
            .join("/"),
    )
}

/// The brain part of report.html.
pub fn report_section(report: &mut Report, m: &BrainMetrics, figs: &[Rendered]) {
    let f = |x: f64| crate::numbers::finite(x, 2);
    let pct = crate::numbers::percent;
    report.heading("Virtual rat brain (paper §4, Fig. 6–8, with truth)");
    report.paragraph(&format!(
        "The scenario {} simulated conventional and Hadamard-coded ({} frames, noise {} dB re the blood's echo, fixed in the scenario before any score), each recording processed as `pcuvd process` processes it: SVD clutter filter on (cut-offs per angle, conventional: {:?}; coded: {:?}), the dynamics stage on the recording's heartbeats. UVD is the conventional recording with least squares, PC-UVD the coded one with IRLS.",
        m.scenario,
        m.frames,
        m.noise_db.map_or("none".into(), |d| format!("{d}")),
        m.clutter_cut_offs[0],
        m.clutter_cut_offs[1],
    ));
    report.paragraph(&format!("Vector scores: {}.", m.vector_definition));
    // RMSE (of Vx / Vz): every vector table's first number.
    let rmse = |s: &VectorScore| {
        format!(
            "{} ({} / {})",
            f(s.rmse_mm_s),
            f(s.rmse_vx_mm_s),
            f(s.rmse_vz_mm_s)
        )
    };
    let row = |g: &GroupScores| {
        let cell = |s: &VectorScore| {
            format!(
                "{}, {}°, {}",
                rmse(s),
                f(s.median_direction_error_deg),
                pct(s.detected)
            )
        };
        vec![
            g.group.clone(),
            g.uvd.pixels.to_string(),
            cell(&g.uvd),
            cell(&g.pcuvd),
            format!("{} %", rounded(g.improvement_pct, 0)),
        ]
    };
    let header = [
        "lumen pixels",
        "n",
        "UVD: RMSE (Vx / Vz) mm/s, direction, detected",
        "PC-UVD: the same",
        "PC-UVD below UVD",
    ];
    let rows: Vec<Vec<String>> = m
        .vector_by_depth
        .iter()
        .chain(&m.vector_by_diameter)
        .chain(std::iter::once(&m.vector_all))
        .chain(&m.vector_deep_by_diameter)
        .chain(&m.vector_by_wall)
        .map(row)
        .collect();
    report.table(&header, &rows);
    report.paragraph(&format!("Near the wall: {}.", m.wall_definition));
    report.paragraph(
        "Coding and IRLS apart: each recording read by each vector estimator, over the lumen pixels both recordings' vessel masks hold (vector RMSE, Vx / Vz, mm/s).",
    );
    let rows: Vec<Vec<String>> = m
        .vector_by_estimator
        .iter()
        .map(|g| {
            vec![
                g.group.clone(),
                g.conventional_ls.pixels.to_string(),
                rmse(&g.conventional_ls),
                rmse(&g.conventional_irls),
                rmse(&g.coded_ls),
                rmse(&g.coded_irls),
            ]
        })
        .collect();
    report.table(
        &[
            "lumen pixels",
            "n",
            "conventional + LS (UVD)",
            "conventional + IRLS",
            "coded + LS",
            "coded + IRLS (PC-UVD)",
        ],
        &rows,
    );
    report.paragraph(&format!("RI scores: {}.", m.ri_definition));
    let ri_cell = |s: Option<pcuvd_app::brain::RiGroupScore>| {
        s.map_or("–".into(), |s| {
            format!(
                "{}, {}",
                crate::numbers::finite(s.median_abs_error, 3),
                pct(s.class_accuracy)
            )
        })
    };
    let rows: Vec<Vec<String>> =
        m.ri.iter()
            .map(|g| {
                vec![
                    g.group.clone(),
                    g.pcuvd.or(g.uvd).map_or(0, |s| s.pixels).to_string(),
                    ri_cell(g.uvd),
                    ri_cell(g.pcuvd),
                ]
            })
            .collect();
    report.table(
        &[
            "lumen pixels",
            "n",
            "UVD: median |ΔRI|, class right",
            "PC-UVD: the same",
        ],
        &rows,
    );
    for skipped in &m.ri_skipped {
        report.paragraph(&format!("No RI maps: {skipped}."));
    }
    report.paragraph(&format!(
        "Vessel over background: {}.",
        m.contrast_definition
    ));
    let rows: Vec<Vec<String>> = m
        .contrast_by_depth
        .iter()
        .map(|b| {
            vec![
                format!("{:.0}–{:.0}", b.depth_mm[0], b.depth_mm[1]),
                b.lumen_pixels.to_string(),
                f(b.conventional_db),
                f(b.coded_db),
                f(b.gain_db),
            ]
        })
        .collect();
    report.table(
        &[
            "depth (mm)",
            "lumen pixels",
            "conventional (dB)",
            "coded (dB)",
            "gain (dB)",
        ],
        &rows,
    );
    for fig in figs {
        report.image_png(&format!("{} ({})", fig.caption, fig.file), &fig.png);
    }
}

/// The first clause of why a method has no RI maps (what the dynamics stage refused), without
/// the error's kind.
fn refusal(skipped: &str) -> &str {
    let reason = skipped
        .rsplit("invalid recording: ")
        .next()
        .unwrap_or(skipped);
    reason.split([';', '(']).next().unwrap_or(reason).trim()
}

/// Why a method has no RI maps, for a panel's title: the reason's first clause (what the
/// dynamics stage refused), without the error's kind, in lines of at most [`TITLE_LINE_CHARS`].
fn no_ri_reason(skipped: &str) -> String {
    textwrap::wrap(refusal(skipped), TITLE_LINE_CHARS).join("\n")
}

/// Characters in a line of a panel's title that the figures' three columns show unshrunk.
const TITLE_LINE_CHARS: usize = 40;

#[cfg(test)]
mod tests {
    use super::no_ri_reason;

    #[test]
    fn a_refusal_becomes_a_title_of_short_lines() {
        let skipped = "invalid recording: 10.0 ms of waveform is too short to measure a heart \
                       rate between 3 and 15 Hz from the data (about 1.5 cycles are needed)";
        let title = no_ri_reason(skipped);
        assert_eq!(
            title,
            "10.0 ms of waveform is too short to\nmeasure a heart rate between 3 and 15 Hz\nfrom \
             the data"
        );
        assert!(title.lines().all(|line| line.chars().count() <= 40));
        assert_eq!(no_ri_reason("no heart rate given"), "no heart rate given");
    }
}
