//! Figures of what varies over the recording: the dynamics stage's RI and class maps, the time
//! series' ensembles, and Doppler spectrograms.

use super::*;

/// `ri.png` (RI map, arteriole and venule maps) and `waveform.png` (mean vessel speed over time
/// with the cardiac cycles used) of the dynamics stage.
pub fn dynamics_figures(
    dir: &Path,
    maps: &RiMaps,
    series: &VelocitySeries,
    params: &DynamicsParams,
    grid: &Grid,
    name: &str,
) -> Result<Vec<PathBuf>> {
    let vessels = maps.vessel_class.mapv(|c| c != BACKGROUND);
    let vmax = quantile(maps.psv.iter().map(|v| v * 1e3), 0.95).max(1e-6);
    let panels = vec![
        finite_panel(
            "Resistivity index (PSV − EDV)/PSV",
            maps.ri.clone(),
            grid,
            Colormap::Viridis,
            (0.0, 1.0),
            "RI",
        ),
        finite_panel(
            &format!("Arterioles (RI ≥ {})", params.artery_ri_min),
            class_map(&maps.psv, &maps.vessel_class, &maps.flow_up, ARTERIOLE),
            grid,
            Colormap::RedBlue,
            (-vmax, vmax),
            PSV_UP_LABEL,
        ),
        finite_panel(
            &format!("Venules (RI ≤ {})", params.vein_ri_max),
            class_map(&maps.psv, &maps.vessel_class, &maps.flow_up, VENULE),
            grid,
            Colormap::RedBlue,
            (-vmax, vmax),
            PSV_UP_LABEL,
        ),
    ];
    let mut written = vec![save(
        &dir.join("ri.png"),
        &format!(
            "{name}: resistivity index{}, heart rate {:.2} Hz",
            if series.axial_only {
                " of the colour-Doppler speed (one angle)"
            } else {
                ""
            },
            maps.heart_rate_hz
        ),
        panels,
        3,
        pcuvd_render::fitted_panel_size(
            &map_panel(
                "",
                maps.ri.clone(),
                grid,
                Colormap::Viridis,
                (0.0, 1.0),
                "RI",
            ),
            PROCESS_PANEL_WIDTH_PX,
        )
        .context("cannot lay out the figures")?,
    )?];
    let mean: Vec<f64> = series
        .mean_speed(&vessels)?
        .iter()
        .map(|v| v * 1e3)
        .collect();
    let mut t_ms: Vec<f64> = series.times_s.iter().map(|t| t * 1e3).collect();
    let (windows, cycles) = waveform_span(&maps.cycles, t_ms.len());
    t_ms.truncate(windows);
    let mut mean = mean;
    mean.truncate(windows);
    let markers = maps.cycles[..cycles]
        .iter()
        .flat_map(|&(start, end)| [start, end - 1])
        .map(|k| Marker {
            x: t_ms[k],
            y: mean[k],
            label: String::new(),
            rgb: (214, 39, 40),
        })
        .collect();
    let speed = if series.axial_only {
        "colour-Doppler speed |Vz|"
    } else {
        "speed"
    };
    let shown = match cycles < maps.cycles.len() {
        true => format!(
            "; the first {cycles} of {} cycles (every window: speed_series.npy)",
            maps.cycles.len()
        ),
        false => String::new(),
    };
    // Windows a run spaced out for memory sample the beat more coarsely: the title says so.
    let ms = |seconds: f64| (seconds * 1e4).round() / 10.0;
    let plot = PlotPanel {
        title: format!(
            "Mean {speed} over vessel pixels (red marks: first and last window of each \
             cycle)\nwindows of {} ms every {} ms{shown}",
            ms(series.window_s),
            ms(series.step_s)
        ),
        x_label: "time (ms)".into(),
        y_label: format!("{speed} (mm/s)"),
        series: vec![Series {
            // One curve, named by the title and the axis: no legend box over the beats.
            label: String::new(),
            x: t_ms,
            y: mean,
            y_err: None,
            style: SeriesStyle::LinePoints,
            rgb: Some((31, 119, 180)),
        }],
        markers,
        ..Default::default()
    };
    written.push(save(
        &dir.join("waveform.png"),
        &format!("{name}: cardiac waveform"),
        vec![Panel::Plot(plot)],
        1,
        (PROCESS_PANEL_WIDTH_PX, 480),
    )?);
    Ok(written)
}

/// Cardiac cycles the waveform figure draws at most: a long recording's hundreds of cycles would
/// merge into a band on a plot one panel wide.
const WAVEFORM_CYCLES: usize = 6;

/// (windows, cycles) of `windows` velocity windows that the waveform figure draws: every one
/// while the recording's `cycles` (window index ranges) are at most [`WAVEFORM_CYCLES`], else
/// those up to the end of that many cycles.
fn waveform_span(cycles: &[(usize, usize)], windows: usize) -> (usize, usize) {
    match cycles.get(WAVEFORM_CYCLES - 1) {
        Some(&(_, end)) if cycles.len() > WAVEFORM_CYCLES => (end.min(windows), WAVEFORM_CYCLES),
        _ => (windows, cycles.len()),
    }
}

/// A run of ensembles of a Doppler time series, as [`ensemble_figure_in_chunks`] reads them:
/// power Doppler and, with vectors, speed (m/s), each (ensembles, nz, nx).
pub type EnsembleChunk = (ndarray::Array3<f64>, Option<ndarray::Array3<f64>>);

/// The Doppler time series (`ensembles.png`): the mean power Doppler over ensembles, its
/// variation across ensembles (std / mean) in the flow pixels, and the flow region's median power
/// (dB re its time average) and, with vectors, median speed over time, ± their robust spread
/// across pixels.
pub fn ensemble_figure(
    dir: &Path,
    out: &ProcessOutput,
    maps: &pcuvd::pipeline::ensembles::EnsembleMaps,
    name: &str,
) -> Result<PathBuf> {
    let speed = maps.speed();
    ensemble_figure_in_chunks(dir, out, &maps.times_s, name, &mut |range| {
        Ok((
            maps.power_doppler
                .slice(ndarray::s![range.clone(), .., ..])
                .to_owned(),
            speed
                .as_ref()
                .map(|s| s.slice(ndarray::s![range, .., ..]).to_owned()),
        ))
    })
}

/// Ensembles [`ensemble_figure_in_chunks`] reads at a time: about 64 MiB of f64 power and speed
/// on the grid `(nz, nx)`.
fn figure_chunk(nz: usize, nx: usize) -> usize {
    ((64usize << 20) / (16 * nz * nx).max(1)).max(1)
}

/// [`ensemble_figure`] of the ensembles at `times_s`, read a run at a time by `read(range)`
/// (twice: the mean first, then each ensemble against it), so that a series held on disk (a Zarr
/// store) is drawn in bounded memory.
pub fn ensemble_figure_in_chunks(
    dir: &Path,
    out: &ProcessOutput,
    times_s: &[f64],
    name: &str,
    read: &mut dyn FnMut(std::ops::Range<usize>) -> Result<EnsembleChunk>,
) -> Result<PathBuf> {
    let grid = &out.grid;
    let n = times_s.len();
    anyhow::ensure!(n >= 1, "a time series of no ensembles has no figure");
    let count = n as f64;
    let (nz, nx) = (grid.z.len(), grid.x.len());
    let step = figure_chunk(nz, nx);
    let runs: Vec<std::ops::Range<usize>> =
        (0..n).step_by(step).map(|a| a..(a + step).min(n)).collect();
    let mut mean = Array2::<f64>::zeros((nz, nx));
    for range in &runs {
        let (power, _) = read(range.clone())?;
        for e in power.outer_iter() {
            mean += &e;
        }
    }
    mean /= count;
    let flow = masks::figure_flow_mask(&mean, masks::FLOW_FIGURE_DB, grid.axial_step());
    let flow_pixels: Vec<(usize, usize)> = flow
        .indexed_iter()
        .filter(|(_, f)| **f)
        .map(|(p, _)| p)
        .collect();
    // Per ensemble, over the flow pixels: the median and a robust spread (1.4826 × the median
    // absolute deviation, the standard deviation for Gaussian values) of the power (dB re the
    // pixel's own time average, so bright and faint vessels weigh alike) and of the speed. Robust
    // because a few ill-conditioned pixels (a vector fit at the noise floor) can read speeds
    // thousands of times the flow's, which a mean and standard deviation would plot instead.
    let robust = |v: Vec<f64>| -> (f64, f64) {
        let v: Vec<f64> = v.into_iter().filter(|v| v.is_finite()).collect();
        if v.is_empty() {
            return (f64::NAN, f64::NAN);
        }
        let m = pcuvd::core::stats::median(v.clone());
        let mad = pcuvd::core::stats::median(v.iter().map(|x| (x - m).abs()).collect());
        (m, 1.4826 * mad)
    };
    let mut squares = Array2::<f64>::zeros((nz, nx));
    let (mut power_db, mut power_spread) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let (mut speed_mm_s, mut speed_spread) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let mut vectors = false;
    for range in &runs {
        let (power, speed) = read(range.clone())?;
        vectors = speed.is_some();
        for (k, e) in power.outer_iter().enumerate() {
            Zip::from(&mut squares)
                .and(&e)
                .and(&mean)
                .for_each(|s, &p, &m| *s += (p - m) * (p - m));
            let (m, s) = robust(
                flow_pixels
                    .iter()
                    .map(|&(z, x)| 10.0 * (e[[z, x]] / mean[[z, x]]).log10())
                    .collect(),
            );
            power_db.push(m);
            power_spread.push(s);
            if let Some(speed) = &speed {
                let (m, s) = robust(
                    flow_pixels
                        .iter()
                        .map(|&(z, x)| speed[[k, z, x]] * 1e3)
                        .collect(),
                );
                speed_mm_s.push(m);
                speed_spread.push(s);
            }
        }
    }
    let std = squares.mapv(|s| (s / count).sqrt());
    let variation = Zip::from(&std)
        .and(&mean)
        .and(&flow)
        .map_collect(|&s, &m, &f| {
            if f && m > 0.0 {
                100.0 * s / m
            } else {
                f64::NAN
            }
        });
    let top = quantile(variation.iter().copied().filter(|v| v.is_finite()), 0.95).max(1.0);
    let mean_panel = map_panel(
        &format!("Power Doppler, mean of {count} ensembles"),
        masks::power_db_re_peak(&mean),
        grid,
        Colormap::Hot,
        (-40.0, 0.0),
        "dB",
    );
    let size = pcuvd_render::fitted_panel_size(&mean_panel, PROCESS_PANEL_WIDTH_PX)
        .context("cannot lay out the figures")?;
    let variation_panel = finite_panel(
        "Power Doppler variation across ensembles (flow pixels)",
        variation,
        grid,
        Colormap::Viridis,
        (0.0, top),
        "std / mean (%)",
    );
    let t_ms: Vec<f64> = times_s.iter().map(|t| t * 1e3).collect();
    let mut series = vec![Series {
        label: "power Doppler (dB re its mean), median ± robust spread over flow pixels".into(),
        x: t_ms.clone(),
        y: power_db,
        y_err: Some(power_spread),
        style: SeriesStyle::LinePoints,
        rgb: Some((214, 39, 40)),
    }];
    let mut y_label = "power (dB re time average)".to_string();
    if vectors {
        series.push(Series {
            label: "speed (mm/s), median ± robust spread over flow pixels".into(),
            x: t_ms,
            y: speed_mm_s,
            y_err: Some(speed_spread),
            style: SeriesStyle::LinePoints,
            rgb: Some((31, 119, 180)),
        });
        y_label = "power (dB) / speed (mm/s)".into();
    }
    // A grid that holds no flow (a region beside the vessels) has no time series to plot: the
    // figure keeps its maps and says so, where drawing an empty plot failed the whole run.
    let any_flow = series.iter().any(|s| s.y.iter().any(|v| v.is_finite()));
    let (plot, title) = if any_flow {
        let plot = PlotPanel {
            title: "Flow region over time (one point per ensemble)".into(),
            x_label: "ensemble centre time (ms)".into(),
            y_label,
            series,
            ..Default::default()
        };
        let title = format!("{name}: Doppler time series, {count} ensembles");
        (Panel::Plot(plot), title)
    } else {
        let title = format!(
            "{name}: Doppler time series, {count} ensembles; no flow pixel, so no flow region \
             over time"
        );
        (Panel::Empty, title)
    };
    save(
        &dir.join("ensembles.png"),
        &title,
        vec![Panel::Image(mean_panel), variation_panel, plot],
        3,
        size,
    )
}

/// A compounded Doppler spectrogram as an image panel: time (ms) across, axial velocity (mm/s,
/// + = deeper) upward, power over the top 40 dB in grey, with `lines` drawn over it.
pub fn spectrogram_panel(
    title: String,
    spec: &pcuvd::dynamics::Spectrogram,
    lines: Vec<Polyline>,
) -> pcuvd_render::ImagePanel {
    let (t, v) = (&spec.times_s, &spec.velocities_m_s);
    // One window has no extent in time: drawn a millisecond wide around its centre.
    let (first, last) = (t[0] * 1e3, t[t.len() - 1] * 1e3);
    let time_span = if last > first {
        (first, last)
    } else {
        (first - 0.5, last + 0.5)
    };
    pcuvd_render::ImagePanel {
        title,
        data: spec.power_db.t().to_owned(),
        x_mm: time_span,
        z_mm: (v[0] * 1e3, v[v.len() - 1] * 1e3),
        colormap: Colormap::Gray,
        range: (-40.0, 0.0),
        colorbar_label: "dB".into(),
        lines,
        axes: Some(pcuvd_render::ImageAxes {
            x_label: "time (ms)".into(),
            y_label: "Vz (mm/s, + = deeper)".into(),
            y_up: true,
            fill: true,
        }),
        ..Default::default()
    }
}

/// The spectrogram's mean Doppler velocity over time (the colour-Doppler estimate), dashed white.
pub fn mean_doppler_line(spec: &pcuvd::dynamics::Spectrogram) -> Polyline {
    Polyline {
        x_mm: spec.times_s.iter().map(|t| t * 1e3).collect(),
        z_mm: spec.mean_velocity_m_s.iter().map(|v| v * 1e3).collect(),
        dashed: true,
        rgb: (255, 255, 255),
        label: "mean Doppler velocity (colour Doppler)".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A recording of a few cycles is drawn whole; a long one up to the end of its sixth cycle,
    /// the windows before the first cycle included.
    #[test]
    fn the_waveform_draws_six_cycles_of_a_long_recording() {
        let cycles: Vec<(usize, usize)> =
            (0..118).map(|k| (3 + 40 * k, 3 + 40 * (k + 1))).collect();
        assert_eq!(waveform_span(&cycles[..5], 300), (300, 5));
        assert_eq!(waveform_span(&cycles[..6], 300), (300, 6));
        assert_eq!(waveform_span(&cycles, 4800), (243, 6));
        assert_eq!(waveform_span(&[], 10), (10, 0));
    }
}
