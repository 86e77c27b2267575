//! Renders a sample figure (image + colour bar + vector overlay, and a plot
//! with error bars) to the path given as the first argument
//! (default /tmp/render_example.png), plus an HTML report next to it.

use ndarray::Array2;
use pcuvd_render::*;
use std::path::PathBuf;

fn main() -> Result<(), RenderError> {
    let out = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/tmp/render_example.png"));

    // A vessel at depth 20 mm, 6 mm diameter, tilted flow, on a speckly background.
    let (nz, nx) = (160, 200);
    let (x0, x1, z0, z1) = (-10.0, 10.0, 10.0, 30.0);
    let xs = |j: usize| x0 + (x1 - x0) * j as f64 / (nx - 1) as f64;
    let zs = |i: usize| z0 + (z1 - z0) * i as f64 / (nz - 1) as f64;
    let radius = 3.0;
    let (tilt_x, tilt_z) = (0.9f64, 0.25f64);
    let norm = tilt_x.hypot(tilt_z);
    let (ax, az) = (tilt_x / norm, tilt_z / norm);
    let dist = |x: f64, z: f64| ((x * az - (z - 20.0) * ax).abs(), ());
    let vmax = 400.0;
    let mut vx = Array2::<f64>::zeros((nz, nx));
    let mut mask = Array2::from_elem((nz, nx), false);
    let mut bmode = Array2::<f64>::zeros((nz, nx));
    for i in 0..nz {
        for j in 0..nx {
            let (x, z) = (xs(j), zs(i));
            let d = dist(x, z).0;
            // Cheap deterministic speckle.
            let mut k = (i as u64) << 32 | j as u64;
            k = (k ^ (k >> 33)).wrapping_mul(0xff51_afd7_ed55_8ccd);
            k = (k ^ (k >> 33)).wrapping_mul(0xc4ce_b9fe_1a85_ec53);
            let h = ((k ^ (k >> 33)) % 1000) as f64 / 1000.0;
            bmode[(i, j)] = 0.15 + 0.35 * h * (-(d - radius).abs() / 4.0).exp() + 0.1 * h;
            if d < radius {
                let v = vmax * (1.0 - (d / radius).powi(2));
                vx[(i, j)] = v * ax;
                mask[(i, j)] = true;
            }
        }
    }
    vx[(80, 100)] = f64::NAN;
    let mut ov = VectorOverlay {
        scale_mm: 1.3,
        colormap: Colormap::Hot,
        speed_range: (0.0, vmax),
        ..Default::default()
    };
    for i in (4..nz).step_by(12) {
        for j in (4..nx).step_by(12) {
            if mask[(i, j)] {
                let (x, z) = (xs(j), zs(i));
                let d = dist(x, z).0;
                let v = vmax * (1.0 - (d / radius).powi(2));
                ov.x_mm.push(x);
                ov.z_mm.push(z);
                ov.vx.push(v * ax);
                ov.vz.push(v * az);
            }
        }
    }
    let image = ImagePanel {
        title: "Lateral velocity vx".into(),
        data: vx,
        x_mm: (x0, x1),
        z_mm: (z0, z1),
        colormap: Colormap::RedBlue,
        range: (-vmax, vmax),
        colorbar_label: "mm/s".into(),
        mask: Some(mask),
        background: Some(bmode),
        arrows: Some(ov),
        lines: vec![Polyline {
            x_mm: vec![-3.0 * az, 3.0 * az],
            z_mm: vec![20.0 + 3.0 * ax, 20.0 - 3.0 * ax],
            dashed: true,
            rgb: (0, 200, 0),
            label: String::new(),
        }],
        axes: None,
    };

    let r: Vec<f64> = (0..=20).map(|k| -3.0 + 0.3 * k as f64).collect();
    let truth: Vec<f64> = r
        .iter()
        .map(|&r| vmax * (1.0 - (r / 3.0).powi(2)))
        .collect();
    let est: Vec<f64> = r
        .iter()
        .enumerate()
        .map(|(k, &r)| vmax * (1.0 - (r / 3.0).powi(2)) * 0.93 + 8.0 * ((k as f64) * 1.7).sin())
        .collect();
    let err: Vec<f64> = r.iter().map(|&r| 15.0 + 10.0 * (r / 3.0).abs()).collect();
    let mut est_nan = est.clone();
    est_nan[10] = f64::NAN;
    let plot = PlotPanel {
        title: "Profile across the vessel".into(),
        x_label: "distance along profile (mm)".into(),
        y_label: "speed (mm/s)".into(),
        series: vec![
            Series {
                label: "true (Poiseuille)".into(),
                x: r.clone(),
                y: truth,
                style: SeriesStyle::DashedLine,
                rgb: Some((40, 40, 40)),
                ..Default::default()
            },
            Series {
                label: "estimate ± 1 SD".into(),
                x: r.clone(),
                y: est_nan,
                y_err: Some(err),
                style: SeriesStyle::LinePoints,
                ..Default::default()
            },
        ],
        annotations: vec!["RMSE 21.4 mm/s".into(), "bias −4.2 mm/s".into()],
        markers: vec![Marker {
            x: 0.0,
            y: 372.0,
            label: "peak".into(),
            rgb: (214, 39, 40),
        }],
        ..Default::default()
    };

    // Estimated vs true scatter with the y = x reference.
    let truth: Vec<f64> = (0..40).map(|k| -300.0 + 15.0 * k as f64).collect();
    let est: Vec<f64> = truth
        .iter()
        .enumerate()
        .map(|(k, &t)| 0.95 * t + 12.0 * ((k as f64) * 2.3).sin())
        .collect();
    let scatter = PlotPanel {
        title: "Estimated vs true vx".into(),
        x_label: "true vx (mm/s)".into(),
        y_label: "estimated vx (mm/s)".into(),
        series: vec![Series {
            label: "pixels".into(),
            x: truth,
            y: est,
            style: SeriesStyle::Points,
            ..Default::default()
        }],
        diagonal: true,
        annotations: vec!["slope 0.95".into(), "R² 0.998".into()],
        ..Default::default()
    };
    // Convergence on a log axis.
    let n: Vec<f64> = (1..=30).map(|k| k as f64).collect();
    let conv = PlotPanel {
        title: "Residual per iteration".into(),
        x_label: "iteration".into(),
        y_label: "relative residual".into(),
        series: vec![
            Series {
                label: "CG".into(),
                x: n.clone(),
                y: n.iter().map(|k| 0.6f64.powf(*k)).collect(),
                ..Default::default()
            },
            Series {
                label: "Jacobi".into(),
                x: n.clone(),
                y: n.iter().map(|k| 0.85f64.powf(*k)).collect(),
                style: SeriesStyle::DashedLine,
                ..Default::default()
            },
        ],
        log_y: true,
        markers: vec![Marker {
            x: 10.0,
            y: 0.6f64.powi(10),
            label: "tol".into(),
            rgb: (60, 60, 60),
        }],
        ..Default::default()
    };

    let fig = Figure {
        title: "Example: vector Doppler in a tilted vessel".into(),
        panels: vec![
            Panel::Image(image),
            Panel::Plot(plot),
            Panel::Plot(scatter),
            Panel::Plot(conv),
        ],
        ncols: 2,
        panel_size_px: (640, 500),
    };
    let t = std::time::Instant::now();
    render_png(&fig, &out)?;
    eprintln!("wrote {} in {:?}", out.display(), t.elapsed());

    let png = render_png_bytes(&fig)?;
    let mut rep = Report::new("Example report");
    rep.heading("Figure")
        .paragraph("Tilted vessel, 6 mm <diameter> & parabolic flow.")
        .image_png("Figure 1: velocity map and profile", &png)
        .table(
            &["metric", "value"],
            &[vec!["RMSE (mm/s)".into(), "21.4".into()]],
        )
        .preformatted("{\"f0_mhz\": 5.0}");
    rep.write(&out.with_extension("html"))?;
    Ok(())
}
