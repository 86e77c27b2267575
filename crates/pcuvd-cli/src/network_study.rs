//! `pcuvd paper`, in-vivo-like part (paper §4, Fig. 6–8): the figures and report section of the
//! vessel-network study ([`pcuvd::study::network`]).

use std::path::Path;

use anyhow::Result;
use ndarray::{Array2, Axis, Zip, s};
use pcuvd::core::grid::Roi;
use pcuvd::dynamics::{ARTERIOLE, BACKGROUND, Spectrogram, VENULE};
use pcuvd::estimate::masks;
use pcuvd::estimate::vector::VectorField;
use pcuvd::evaluate::metrics::DepthSnr;
use pcuvd::simulate::phantom::network::{NetworkPhantom, NetworkTruth};
use pcuvd::study::describe_alignment;
use pcuvd::study::network::{
    DYNAMICS_KERNEL, ModeResult, NetworkMetrics, NetworkSettings, NetworkStudy, Site,
};
use pcuvd_render::{Colormap, Figure, Panel, PlotPanel, Polyline, Report, SeriesStyle};

use pcuvd_app::Progress;
use pcuvd_app::figures::{
    PROFILE_LINE_RGB, PSV_UP_LABEL, Rendered, TRUTH_RGB, UVD_RGB, axial_velocity_panel, class_map,
    line, map_panel, region_outline, render, shared_db_range, vector_panel,
};

/// The figures the network part writes into the output folder.
pub const NETWORK_FIGURES: [&str; 5] = [
    "fig6_network_doppler.png",
    "fig6gh_network_profiles.png",
    "fig7_network_rois.png",
    "fig8_ri_maps.png",
    "fig8b_spectrograms.png",
];

fn finite_mask(a: &Array2<f64>) -> Array2<bool> {
    a.mapv(f64::is_finite)
}

/// Figures 6–8 of the network study, drawn into `dir`.
pub fn network_figures(
    dir: &Path,
    study: &NetworkStudy,
    progress: &dyn Progress,
) -> Result<Vec<Rendered>> {
    let (phantom, truth, grid) = (&study.phantom, &study.truth, &study.grid);
    let (results, scores, snr, sites) = (&study.modes, &study.scores, &study.snr, &study.sites);
    let settings = &study.settings;
    let task = "network figures";
    progress.update(task, 0, 5);
    let mut figs = Vec::new();
    let black = Array2::<f64>::zeros(grid.shape());
    let vmax = 30.0;
    // Flow pixels of each mode, for every flow map below.
    let flows: Vec<Array2<bool>> = results
        .iter()
        .map(|r| {
            masks::above_noise_image(
                &r.out.maps.power_doppler,
                &r.noise_power,
                masks::FLOW_ABOVE_NOISE_DB,
            )
        })
        .collect();

    // One speed scale for every vector map of Fig. 6 and 7 (both modes), so colours compare.
    let speed_max = pcuvd_app::figures::speed_scale(
        &results
            .iter()
            .zip(&flows)
            .map(|(r, flow)| (r.field(), flow))
            .collect::<Vec<_>>(),
    );

    // Fig. 6gh's profile lines (a horizontal and a vertical line) and Fig. 7's regions, drawn
    // on Fig. 6's power Doppler maps.
    let (z_line, x_line) = (5.0e-3, 4.2e-3);
    let row = grid.nearest_pixel(0.0, z_line).0;
    let col = grid.nearest_pixel(x_line, 0.0).1;
    let rois = [
        ((-5.8e-3, -1.6e-3), (2.0e-3, 5.0e-3)),
        ((3.4e-3, 6.4e-3), (5.8e-3, 9.4e-3)),
        ((-1.8e-3, 3.6e-3), (10.0e-3, 12.4e-3)),
    ];
    let (x_ends, z_ends) = (
        (grid.x[0] * 1e3, grid.x[grid.x.len() - 1] * 1e3),
        (grid.z[0] * 1e3, grid.z[grid.z.len() - 1] * 1e3),
    );
    let mut guides = vec![
        Polyline {
            x_mm: vec![x_ends.0, x_ends.1],
            z_mm: vec![grid.z[row] * 1e3; 2],
            dashed: false,
            rgb: PROFILE_LINE_RGB,
            label: "profiles of Fig. 6 g, h".into(),
        },
        Polyline {
            x_mm: vec![grid.x[col] * 1e3; 2],
            z_mm: vec![z_ends.0, z_ends.1],
            dashed: false,
            rgb: PROFILE_LINE_RGB,
            label: "profiles of Fig. 6 g, h".into(),
        },
    ];
    guides.extend(
        rois.iter()
            .map(|&(x, z)| region_outline(x, z, "regions of Fig. 7")),
    );

    // Figure 6: PD, colour Doppler and vector maps, UVD above PC-UVD; one PD range from the data.
    let pd_db: Vec<Array2<f64>> = results
        .iter()
        .map(|r| masks::db_above_noise(&r.out.maps.power_doppler, &r.noise_power))
        .collect();
    let pd_range = shared_db_range(&pd_db.iter().collect::<Vec<_>>());
    let mut panels = Vec::new();
    for ((r, flow), db) in results.iter().zip(&flows).zip(pd_db) {
        let name = r.mode.method();
        let mut pd = map_panel(
            &format!("{name}: power Doppler"),
            db,
            grid,
            Colormap::Hot,
            pd_range,
            "dB above noise",
        );
        pd.lines = guides.clone();
        panels.push(Panel::Image(pd));
        panels.push(axial_velocity_panel(
            &format!("{name}: colour Doppler"),
            &r.out.maps.color_doppler,
            grid,
            vmax,
            flow,
        ));
        panels.push(vector_panel(
            &format!("{name}: vector Doppler"),
            r.field(),
            grid,
            flow,
            &black,
            speed_max,
        ));
    }
    figs.push(render(dir, "fig6_network_doppler.png", "Figure 6 analogue: power Doppler (dB above each mode's own noise floor; cyan: the lines of Fig. 6 g, h's profiles; dashed green: the regions of Fig. 7, ROI 1 the shallowest, ROI 3 the deepest), colour Doppler and vector Doppler of the vessel network over the whole recording; conventional UVD (top) and PC-UVD (bottom). Flow maps show pixels at least 6 dB above the noise floor.", Figure { title: format!("Vessel network, noise {} dB: UVD (top) and PC-UVD (bottom)", settings.noise_db), panels, ncols: 3, panel_size_px: (520, 500) })?);
    progress.update(task, 1, 5);

    // Figure 6 (g, h): PD profiles along a shallow horizontal line and a vertical line, SNR by depth.
    let x_mm: Vec<f64> = grid.x.iter().map(|x| x * 1e3).collect();
    let z_mm: Vec<f64> = grid.z.iter().map(|z| z * 1e3).collect();
    let rgb = [UVD_RGB, TRUTH_RGB];
    let labels = ["PD (conventional)", "PC-PD (coded)"];
    let profile = |horizontal: bool| -> Vec<pcuvd_render::Series> {
        results
            .iter()
            .enumerate()
            .map(|(k, r)| {
                let db = masks::db_above_noise(&r.out.maps.power_doppler, &r.noise_power);
                let (xs, ys) = if horizontal {
                    (x_mm.clone(), db.row(row).to_vec())
                } else {
                    (z_mm.clone(), db.column(col).to_vec())
                };
                line(labels[k], xs, ys, SeriesStyle::Line, rgb[k])
            })
            .collect()
    };
    let depth = |rows: &[DepthSnr]| rows.iter().map(|r| r.depth_m * 1e3).collect::<Vec<_>>();
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
                    snr[0].iter().map(|r| r.snr_db).collect(),
                    SeriesStyle::LinePoints,
                    UVD_RGB,
                ),
                line(
                    "PC-PD",
                    depth(&snr[1]),
                    snr[1].iter().map(|r| r.snr_db).collect(),
                    SeriesStyle::LinePoints,
                    TRUTH_RGB,
                ),
            ],
            annotations: vec!["SNR: echo power in vessels / noise power".into()],
            ..Default::default()
        }),
    ];
    figs.push(render(dir, "fig6gh_network_profiles.png", "Figure 6 (g, h) analogue: power Doppler in dB above the noise floor along a horizontal line at 5 mm depth and a vertical line at x = 4.2 mm, and SNR versus depth (echo and noise images formed apart). The echoes weaken with depth (attenuation 0.5 dB/cm/MHz), so the deep vessels are where coding matters.", Figure { title: "Vessel network: signal and SNR".into(), panels, ncols: 3, panel_size_px: (520, 420) })?);
    progress.update(task, 2, 5);

    // Figure 7: vector maps in three regions at increasing depth.
    let mut panels = Vec::new();
    for (r, flow) in results.iter().zip(&flows) {
        for (k, &(x, z)) in rois.iter().enumerate() {
            let roi = Roi::new(grid, x, z)?;
            let field = VectorField {
                vx: roi.cut(&r.field().vx),
                vz: roi.cut(&r.field().vz),
            };
            panels.push(vector_panel(
                &format!("{}: ROI {}", r.mode.method(), k + 1),
                &field,
                &roi.grid,
                &roi.cut(flow),
                &roi.cut(&black),
                speed_max,
            ));
        }
    }
    figs.push(render(dir, "fig7_network_rois.png", "Figure 7 analogue: vector velocity (triangles point along the flow, colour = speed) in three regions at increasing depth; UVD (top) and PC-UVD (bottom).", Figure { title: "Vector velocity in three regions".into(), panels, ncols: 3, panel_size_px: (460, 440) })?);
    progress.update(task, 3, 5);

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
                r.mode.method(),
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
                PSV_UP_LABEL,
            );
            p.mask = Some(match flow {
                Some(flow) => shown(&data, flow),
                None => finite_mask(&data),
            });
            p.background = Some(black.clone());
            Panel::Image(p)
        };
    for (r, flow) in results.iter().zip(&flows).rev() {
        let (name, ri) = (r.mode.method(), &r.ri);
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
    figs.push(render(dir, "fig8_ri_maps.png", "Figure 8 (a, c, d) analogue: resistivity-index maps (truth, UVD, PC-UVD), then for PC-UVD and UVD the arteriole and venule maps (PSV, red = flowing up, blue = down) and the vessel pixels whose kind was missed (shown with their true PSV). Estimates are shown where power Doppler is at least 6 dB above the mode's noise floor; the scores count every pixel of the true lumen.", Figure { title: format!("Resistivity index over one cardiac cycle ({} Hz)", settings.heart_rate_hz), panels, ncols: 3, panel_size_px: (480, 470) })?);
    progress.update(task, 4, 5);

    // Figure 8 (b): compounded Doppler spectrograms at four pixels, PC-UVD.
    let coded = &results[1];
    let mut panels = Vec::new();
    for (k, (site, spec)) in sites.iter().zip(&coded.spectrograms).enumerate() {
        let mut panel = spectrogram_panel(site, spec, coded, phantom, truth);
        // One legend for the figure (the first panel's): the lines mean the same in every panel.
        if k > 0 {
            panel.lines.iter_mut().for_each(|l| l.label.clear());
        }
        panels.push(Panel::Image(panel));
    }
    figs.push(render(dir, "fig8b_spectrograms.png", "Figure 8 (b) analogue: PC-UVD compounded Doppler spectrograms (axial velocity, + = deeper) at one pixel on the axis of an arteriole and a venule flowing up and down. The legend (first panel) holds for every panel: dashed white, mean Doppler velocity (colour-Doppler estimate); cyan, vector speed with the sign of the flow's Vz; green, true speed; red and yellow ticks, the PSV and EDV the RI uses.", Figure { title: "PC-UVD spectrograms over the cardiac cycle".into(), panels, ncols: 2, panel_size_px: (620, 420) })?);
    progress.update(task, 5, 5);
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
        pcuvd_app::figures::mean_doppler_line(spec),
        Polyline {
            x_mm: series.times_s.iter().map(|t| t * 1e3).collect(),
            z_mm: true_speed,
            dashed: false,
            rgb: (60, 200, 90),
            label: "true speed".into(),
        },
        Polyline {
            x_mm: series.times_s.iter().map(|t| t * 1e3).collect(),
            z_mm: speed.clone(),
            dashed: false,
            rgb: (80, 220, 255),
            label: "vector speed, sign of the flow's Vz".into(),
        },
    ];
    // PSV (red) and EDV (yellow) of each cycle: a short vertical tick at the sample used.
    let tick = (v_last - v_first).abs() * 0.06;
    for &(start, end) in &result.ri.cycles {
        let lane = &speed[start..end.min(speed.len())];
        let abs_max = (0..lane.len()).max_by(|&a, &b| lane[a].abs().total_cmp(&lane[b].abs()));
        let abs_min = (0..lane.len()).min_by(|&a, &b| lane[a].abs().total_cmp(&lane[b].abs()));
        for (at, rgb, label) in [
            (abs_max, (230, 40, 40), "PSV (peak systolic) used for RI"),
            (abs_min, (250, 210, 40), "EDV (end diastolic) used for RI"),
        ] {
            if let Some(k) = at {
                let (t, v) = (series.times_s[start + k] * 1e3, lane[k]);
                lines.push(Polyline {
                    x_mm: vec![t, t],
                    z_mm: vec![v - tick, v + tick],
                    dashed: false,
                    rgb,
                    label: label.into(),
                });
            }
        }
    }
    let ri = result.ri.ri[[iz, ix]];
    let title = format!(
        "{} — RI {:.2} (true {:.2})",
        site.label,
        ri,
        truth.ri[[iz, ix]]
    );
    pcuvd_app::figures::spectrogram_panel(title, spec, lines)
}

/// The network part of report.html.
pub fn report_section(
    report: &mut Report,
    m: &NetworkMetrics,
    settings: &NetworkSettings,
    figs: &[Rendered],
) {
    let rat = pcuvd::dynamics::DynamicsParams::rat();
    let dynamics = &m.network.dynamics;
    let get = |x: f64| crate::numbers::finite(x, 3);
    let pct = crate::numbers::percent;
    let pooling_text = match settings
        .dynamics_params(pcuvd::study::Mode::Coded)
        .map(|p| p.pooling)
    {
        Ok(Some(p)) => format!(
            "an ellipse aligned with each pixel's mean flow, half-length {:.2} mm along it and half-width {:.2} mm across, flow directions within {:.0}°, weights the squared mean Doppler power, speeds |V| pooled and rescaled to each pixel's own mean",
            p.along * settings.grid_step_m * 1e3,
            p.across * settings.grid_step_m * 1e3,
            p.max_angle.to_degrees()
        ),
        _ => "off".into(),
    };
    report.heading("In-vivo-like vessel network over a cardiac cycle (paper §4, Fig. 6–8)");
    report.paragraph(&format!(
        "The paper's rat setting (L22-14vX at 15.625 MHz, 8 plane waves from −15° to 15°, Hadamard order 8 with 1 µs slots, event PRF 14.4 kHz, 1.8 kHz compound rate) over {} compound frames, on a phantom with ground truth: eight straight vessels 1–13 mm deep at several orientations, four arterioles (RI 0.7, peak 20–30 mm/s, radius 0.15 mm) and four venules (RI 0.3, peak 10–14 mm/s, radius 0.2 mm), flowing up and down, parabolic profiles, pulsatile waveform w(t) = (1 − RI) + RI·((1 + cos 2πf_h t)/2)³ at {} Hz, {}; decoding: {}; receive F# {}. Attenuation 0.5 dB/cm/MHz makes the echoes, and the SNR, fall with depth. Noise {} dB ({}). No clutter filter (no tissue). Seed {}.",
        settings.frames,
        settings.heart_rate_hz,
        settings.motion.describe(),
        describe_alignment(settings.event_alignment),
        settings.f_number,
        settings.noise_db,
        pcuvd::simulate::NOISE_DEFINITION,
        settings.seed
    ));
    report.paragraph(&format!(
        "Dynamics: vector velocity in {}-frame windows every {} frames, autocorrelation averaged over {} × {} pixels, each pixel's waveform shape pooled with its same-direction neighbours ({}; dynamics::VesselPooling), then fitted by a mean plus the first cardiac harmonics (dynamics::auto_harmonics) (UVD: least squares on the conventional recording; PC-UVD: IRLS-WLS on the coded one); PSV and EDV per pixel over the complete cardiac cycle (heart rate given: the recording holds about one beat); RI = (PSV − EDV)/PSV; arteriole if RI ≥ {}, venule if RI ≤ {}; vessel pixels: window power within {} dB of the strongest and whole-recording power Doppler at least {} dB above the noise floor of its depth (doppler::above_noise_floor) and within {} dB of the brightest pixel within {} mm (doppler::near_local_peak). Scores: {}.",
        dynamics.window_frames,
        dynamics.step_frames,
        DYNAMICS_KERNEL.0,
        DYNAMICS_KERNEL.1,
        pooling_text,
        rat.artery_ri_min,
        rat.vein_ri_max,
        -dynamics.min_power_db,
        dynamics.vessel_margin_db,
        dynamics.vessel_local_db,
        dynamics.vessel_local_radius_m * 1e3,
        m.ri.definition
    ));
    let (uvd, pc) = (&m.ri.uvd, &m.ri.pcuvd);
    let rows = vec![
        vec![
            "RI median |error| over vessel pixels".into(),
            get(uvd.median_abs_error),
            get(pc.median_abs_error),
            "≤ 0.05".into(),
        ],
        vec![
            "artery/vein classification correct".into(),
            pct(uvd.classification_accuracy),
            pct(pc.classification_accuracy),
            "≥ 95 %".into(),
        ],
        vec![
            "vessel pixels with an RI (coverage)".into(),
            pct(uvd.coverage),
            pct(pc.coverage),
            String::new(),
        ],
        vec![
            "flow direction correct (pixels with an RI)".into(),
            pct(uvd.direction_accuracy),
            pct(pc.direction_accuracy),
            String::new(),
        ],
    ];
    report.table(&["quantity", "UVD", "PC-UVD", "target"], &rows);
    let f = |x: f64| crate::numbers::finite(x, 2);
    let p = |x: f64| {
        if x.is_finite() {
            format!("{:.0} %", 100.0 * x)
        } else {
            "–".into()
        }
    };
    let per_vessel: Vec<Vec<String>> = m
        .network
        .vessels
        .iter()
        .map(|v| {
            vec![
                v.name.clone(),
                v.kind.clone(),
                if v.flows_up { "up" } else { "down" }.into(),
                format!("{:.1}", v.centre_m[1] * 1e3),
                f(v.ri),
                f(v.uvd.median_ri),
                f(v.pcuvd.median_ri),
                p(v.uvd.classification_accuracy),
                p(v.pcuvd.classification_accuracy),
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
    for fig in figs {
        report.image_png(&format!("{} ({})", fig.caption, fig.file), &fig.png);
    }
}
