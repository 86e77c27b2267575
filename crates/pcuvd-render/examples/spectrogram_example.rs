//! Renders a synthetic Doppler spectrogram (time × velocity, velocity upward,
//! panel filled) next to a depth map, to the path given as the first argument
//! (default /tmp/spectrogram_example.png).

use ndarray::Array2;
use pcuvd_render::*;
use std::path::PathBuf;

fn main() -> Result<(), RenderError> {
    let out = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/tmp/spectrogram_example.png"));

    // 2 s of a pulsatile flow, 3 beats; velocity axis ±600 mm/s (Nyquist).
    let (nv, nt) = (96, 250);
    let (t_end, v_nyq) = (2000.0, 600.0);
    let dt = t_end / nt as f64;
    let dv = 2.0 * v_nyq / nv as f64;
    let ts = |j: usize| (j as f64 + 0.5) * dt;
    let vs = |i: usize| -v_nyq + (i as f64 + 0.5) * dv;
    let v_peak = |t: f64| {
        let p = t % 700.0;
        120.0 + 380.0 * (-((p - 120.0) / 60.0).powi(2) / 2.0).exp()
    };
    let mut db = Array2::<f64>::zeros((nv, nt));
    for i in 0..nv {
        for j in 0..nt {
            let (t, v) = (ts(j), vs(i));
            let vp = v_peak(t);
            // Flow band between 0.2 vp and vp with soft edges, on a noise floor.
            let edge = |x: f64| 1.0 / (1.0 + (-x / 6.0).exp());
            let band = edge(v - 0.2 * vp) * edge(vp - v);
            let noise = 0.5 + 0.5 * ((i * 7919 + j * 104_729) as f64 * 0.618).sin();
            let p = band + 1e-4 * (0.3 + noise);
            db[(i, j)] = 10.0 * p.log10();
        }
    }
    let trace_t: Vec<f64> = (0..nt).map(ts).collect();
    let trace_v: Vec<f64> = trace_t.iter().map(|&t| v_peak(t)).collect();
    let spectrogram = ImagePanel {
        title: "Doppler spectrogram at the vessel centre".into(),
        data: db,
        x_mm: (ts(0), ts(nt - 1)),
        z_mm: (vs(0), vs(nv - 1)),
        colormap: Colormap::Gray,
        range: (-40.0, 0.0),
        colorbar_label: "dB".into(),
        lines: vec![
            Polyline {
                x_mm: trace_t,
                z_mm: trace_v,
                dashed: true,
                rgb: (230, 60, 40),
                label: String::new(),
            },
            Polyline {
                x_mm: vec![0.0, t_end],
                z_mm: vec![0.0, 0.0],
                dashed: false,
                rgb: (80, 160, 255),
                label: String::new(),
            },
        ],
        axes: Some(ImageAxes {
            x_label: "time (ms)".into(),
            y_label: "velocity (mm/s)".into(),
            y_up: true,
            fill: true,
        }),
        ..Default::default()
    };

    // A depth map alongside, to check that both kinds sit well in one figure.
    let (nz, nx) = (80, 100);
    let depth = Array2::from_shape_fn((nz, nx), |(i, j)| {
        let (x, z) = (-10.0 + 0.2 * j as f64, 10.0 + 0.25 * i as f64);
        let r = x.hypot(z - 20.0);
        if r < 3.0 {
            400.0 * (1.0 - (r / 3.0).powi(2))
        } else {
            0.0
        }
    });
    let map = ImagePanel {
        title: "Velocity map".into(),
        data: depth,
        x_mm: (-10.0, 9.8),
        z_mm: (10.0, 29.75),
        colormap: Colormap::Hot,
        range: (0.0, 400.0),
        colorbar_label: "mm/s".into(),
        ..Default::default()
    };

    let fig = Figure {
        title: "Example: spectrogram (y up, filled) and depth map".into(),
        panels: vec![Panel::Image(spectrogram), Panel::Image(map)],
        ncols: 2,
        panel_size_px: (640, 420),
    };
    render_png(&fig, &out)?;
    eprintln!("wrote {}", out.display());
    Ok(())
}
