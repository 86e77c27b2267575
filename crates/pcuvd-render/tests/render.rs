//! End-to-end rendering tests: decode the PNG and inspect pixels.

use ndarray::Array2;
use pcuvd_render::*;

struct Img {
    w: usize,
    h: usize,
    rgb: Vec<u8>,
}

impl Img {
    fn px(&self, x: usize, y: usize) -> (u8, u8, u8) {
        let i = (y * self.w + x) * 3;
        (self.rgb[i], self.rgb[i + 1], self.rgb[i + 2])
    }
}

fn decode(png_bytes: &[u8]) -> Img {
    if let Ok(d) = std::env::var("RENDER_TEST_DUMP") {
        static N: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let k = N.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        let _ = std::fs::write(format!("{d}/dump_{k}.png"), png_bytes);
    }
    assert_eq!(&png_bytes[..8], b"\x89PNG\r\n\x1a\n", "not a PNG");
    let decoder = png::Decoder::new(std::io::Cursor::new(png_bytes));
    let mut reader = decoder.read_info().expect("png header");
    let mut buf = vec![0u8; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).expect("png frame");
    assert_eq!(info.color_type, png::ColorType::Rgb);
    assert_eq!(info.bit_depth, png::BitDepth::Eight);
    buf.truncate(info.buffer_size());
    Img {
        w: info.width as usize,
        h: info.height as usize,
        rgb: buf,
    }
}

fn image_panel(data: Array2<f64>, cmap: Colormap, range: (f64, f64)) -> ImagePanel {
    ImagePanel {
        title: "test".into(),
        data,
        x_mm: (-10.0, 10.0),
        z_mm: (0.0, 20.0),
        colormap: cmap,
        range,
        colorbar_label: "mm/s".into(),
        ..Default::default()
    }
}

fn figure(panels: Vec<Panel>, ncols: usize, title: &str) -> Figure {
    Figure {
        title: title.into(),
        panels,
        ncols,
        panel_size_px: (400, 360),
    }
}

/// Bounding box (x0, y0, x1, y1 inclusive) of the horizontal runs of at least
/// 20 pixels satisfying `f` (ignores text and the narrow colour bar).
fn bbox(img: &Img, f: impl Fn((u8, u8, u8)) -> bool) -> Option<(usize, usize, usize, usize)> {
    let mut b: Option<(usize, usize, usize, usize)> = None;
    for y in 0..img.h {
        let mut x = 0;
        while x < img.w {
            if !f(img.px(x, y)) {
                x += 1;
                continue;
            }
            let start = x;
            while x < img.w && f(img.px(x, y)) {
                x += 1;
            }
            if x - start >= 20 {
                let (a, c) = (start, x - 1);
                b = Some(match b {
                    None => (a, y, c, y),
                    Some((x0, y0, x1, y1)) => (x0.min(a), y0.min(y), x1.max(c), y1.max(y)),
                });
            }
        }
    }
    b
}

#[test]
fn left_dark_right_light_and_size() {
    let mut data = Array2::<f64>::zeros((50, 50));
    data.slice_mut(ndarray::s![.., 25..]).fill(1.0);
    let panels = vec![
        Panel::Image(image_panel(data, Colormap::Gray, (0.0, 1.0))),
        Panel::Empty,
        Panel::Empty,
    ];
    let fig = figure(panels, 2, "Pattern");
    let img = decode(&render_png_bytes(&fig).unwrap());
    // 3 panels in 2 columns -> 2 rows, plus the title band.
    assert_eq!(img.w, 2 * 400);
    assert_eq!(img.h, 2 * 360 + FIGURE_TITLE_BAND_PX as usize);

    // The black half of the image is the only pure-black region.
    let (x0, y0, x1, y1) = bbox(&img, |p| p == (0, 0, 0)).expect("no black pixels");
    let (bw, bh) = (x1 - x0 + 1, y1 - y0 + 1);
    // Square data extent (20 mm x 20 mm): the black half is half as wide as tall.
    assert!(bh > 100, "image too small: {bh}");
    let ratio = bw as f64 / bh as f64;
    assert!((ratio - 0.5).abs() < 0.03, "aspect ratio wrong: {bw}x{bh}");
    let ymid = (y0 + y1) / 2;
    // Left half dark, right half light (white), inside the plot area.
    let left = img.px(x0 + bw / 2, ymid);
    let right = img.px(x1 + bw / 2, ymid);
    assert_eq!(left, (0, 0, 0));
    assert!(right.0 > 240 && right.1 > 240 && right.2 > 240, "{right:?}");
    // The white half is as wide as the black one and is closed by the dark frame.
    // (At most one anti-aliased transition pixel at the data boundary.)
    let mut x = x1 + 1;
    if img.px(x, ymid).0 <= 240 {
        x += 1;
    }
    let start = x;
    while img.px(x, ymid).0 > 240 {
        x += 1;
    }
    assert!(
        (x - start).abs_diff(bw) <= 3,
        "white half {} px vs black {bw}",
        x - start
    );
    assert!(
        img.px(x, ymid).0 < 100,
        "expected frame at right edge, got {:?} at x={x} (row: {:?})",
        img.px(x, ymid),
        (x - 3..x + 4)
            .map(|x| img.px(x, ymid).0)
            .collect::<Vec<_>>()
    );
    // Frame is also just left of the black half.
    assert!(img.px(x0 - 1, ymid).0 < 100 && img.px(x0 - 1, ymid) != (0, 0, 0));
    // Everything is in the first cell (top-left), below the title band.
    assert!(y0 > FIGURE_TITLE_BAND_PX as usize && x1 + bw < 400 && y1 < 40 + 360);
}

#[test]
fn no_title_band_without_title() {
    let data = Array2::<f64>::zeros((10, 10));
    let fig = figure(
        vec![Panel::Image(image_panel(
            data,
            Colormap::Viridis,
            (0.0, 1.0),
        ))],
        3,
        "",
    );
    let (w, h, rgb) = render_rgb(&fig).unwrap();
    // ncols larger than the panel count shrinks to the panel count.
    assert_eq!((w, h), (400, 360));
    assert_eq!(rgb.len(), 400 * 360 * 3);
}

#[test]
fn depth_increases_downward() {
    // Row 0 (shallow) = 0 -> black, last rows = 1 -> white: black must be on top.
    let mut data = Array2::<f64>::zeros((40, 40));
    data.slice_mut(ndarray::s![20.., ..]).fill(1.0);
    let fig = figure(
        vec![Panel::Image(image_panel(data, Colormap::Gray, (0.0, 1.0)))],
        1,
        "",
    );
    let img = decode(&render_png_bytes(&fig).unwrap());
    let (x0, y0, x1, y1) = bbox(&img, |p| p == (0, 0, 0)).unwrap();
    let below = img.px((x0 + x1) / 2, y1 + (y1 - y0) / 2);
    assert!(below.0 > 240, "white half should be below: {below:?}");
    assert!(
        (x1 - x0) > 2 * (y1 - y0) - 6,
        "black band should be the top half"
    );
}

fn find_color(img: &Img, target: (u8, u8, u8), tol: i32) -> Vec<(usize, usize)> {
    let mut v = Vec::new();
    for y in 0..img.h {
        for x in 0..img.w {
            let p = img.px(x, y);
            if (p.0 as i32 - target.0 as i32).abs() <= tol
                && (p.1 as i32 - target.1 as i32).abs() <= tol
                && (p.2 as i32 - target.2 as i32).abs() <= tol
            {
                v.push((x, y));
            }
        }
    }
    v
}

/// Render a black image with one glyph at its centre; return (image, centre px, glyph pixels).
fn one_glyph(vx: f64, vz: f64) -> (Img, (usize, usize), Vec<(usize, usize)>) {
    let data = Array2::<f64>::zeros((40, 40));
    let mut p = image_panel(data, Colormap::Gray, (0.0, 1.0));
    p.colorbar_label.clear();
    p.arrows = Some(VectorOverlay {
        x_mm: vec![0.0],
        z_mm: vec![10.0],
        vx: vec![vx],
        vz: vec![vz],
        scale_mm: 8.0,
        colormap: Colormap::Viridis,
        speed_range: (0.0, 1.0),
    });
    let fig = figure(vec![Panel::Image(p)], 1, "");
    let img = decode(&render_png_bytes(&fig).unwrap());
    let (x0, y0, x1, y1) = bbox(&img, |p| p == (0, 0, 0)).unwrap();
    let centre = ((x0 + x1).div_ceil(2), (y0 + y1).div_ceil(2));
    // Speed 1 at the top of the range -> viridis(1), yellow.
    let yellow = colormap_rgb(Colormap::Viridis, 1.0);
    let px = find_color(&img, yellow, 12);
    // The colour-bar top also uses viridis(1): keep only pixels inside the image.
    let px: Vec<_> = px
        .into_iter()
        .filter(|&(x, y)| x > x0 && x < x1 && y > y0 && y < y1)
        .collect();
    (img, centre, px)
}

#[test]
fn glyph_points_down_for_positive_vz() {
    let (img, (cx, cy), px) = one_glyph(0.0, 1.0);
    assert!(px.len() > 50, "too few glyph pixels: {}", px.len());
    // 40 samples over 20 mm: the image spans 20 + 20/39 mm between pixel edges.
    let ppm = {
        let (x0, _, x1, _) = bbox(&img, |p| p == (0, 0, 0)).unwrap();
        (x1 - x0 + 1) as f64 / (20.0 + 20.0 / 39.0)
    };
    let half = 4.0 * ppm; // half of the 8 mm glyph
    let ymin = px.iter().map(|p| p.1).min().unwrap() as f64;
    let ymax = px.iter().map(|p| p.1).max().unwrap() as f64;
    // Glyph is centred on its position and 8 mm long along z.
    assert!(
        (ymax - (cy as f64 + half)).abs() < 5.0,
        "tip at {ymax}, centre {cy}"
    );
    assert!(
        (ymin - (cy as f64 - half)).abs() < 3.0,
        "base at {ymin}, centre {cy}"
    );
    // The tip (narrow end) is below the centre: rows below are narrower than rows above.
    let width_at = |y: usize| px.iter().filter(|p| p.1 == y).count();
    let d = (0.6 * half) as usize;
    assert!(
        width_at(cy + d) < width_at(cy - d),
        "glyph should narrow downward: below {} above {}",
        width_at(cy + d),
        width_at(cy - d)
    );
    // Coloured pixels below the centre reach further than the base's half-width sideways.
    let below: Vec<_> = px.iter().filter(|p| p.1 > cy + 2).collect();
    assert!(!below.is_empty());
    assert!(
        px.iter()
            .all(|p| (p.0 as i64 - cx as i64).abs() < (half * 0.5) as i64 + 2)
    );
}

#[test]
fn glyph_points_up_for_negative_vz_and_sideways_for_vx() {
    let (_, (_, cy), px) = one_glyph(0.0, -1.0);
    let half_rows = |pred: &dyn Fn(usize) -> bool| px.iter().filter(|p| pred(p.1)).count();
    // Base (wide end) now below the centre.
    assert!(half_rows(&|y| y > cy) > half_rows(&|y| y < cy));

    let (_, (cx, cy), px) = one_glyph(1.0, 0.0);
    let ys: Vec<_> = px.iter().map(|p| p.1 as i64 - cy as i64).collect();
    let xs: Vec<_> = px.iter().map(|p| p.0 as i64 - cx as i64).collect();
    let yspread = ys.iter().max().unwrap() - ys.iter().min().unwrap();
    let xspread = xs.iter().max().unwrap() - xs.iter().min().unwrap();
    assert!(
        xspread > 2 * yspread,
        "horizontal glyph: {xspread} vs {yspread}"
    );
    // Narrow end to the right.
    let w_at = |x: i64| xs.iter().filter(|&&v| v == x).count();
    let d = xspread / 3;
    assert!(w_at(d) < w_at(-d));
}

#[test]
fn zero_and_nan_vectors_are_skipped() {
    let data = Array2::<f64>::zeros((20, 20));
    let mut p = image_panel(data, Colormap::Gray, (0.0, 1.0));
    p.arrows = Some(VectorOverlay {
        x_mm: vec![0.0, 1.0, f64::NAN],
        z_mm: vec![10.0, 5.0, 5.0],
        vx: vec![0.0, f64::NAN, 1.0],
        vz: vec![0.0, 1.0, 1.0],
        scale_mm: 8.0,
        colormap: Colormap::Viridis,
        speed_range: (0.0, 1.0),
    });
    let img = decode(&render_png_bytes(&figure(vec![Panel::Image(p)], 1, "")).unwrap());
    let (x0, y0, x1, y1) = bbox(&img, |p| p == (0, 0, 0)).unwrap();
    // The image interior stays black.
    for y in y0 + 1..y1 {
        for x in x0 + 1..x1 {
            assert_eq!(img.px(x, y), (0, 0, 0), "pixel ({x},{y}) drawn");
        }
    }
}

#[test]
fn nan_is_dark_grey_and_mask_shows_background() {
    let mut data = Array2::from_elem((30, 30), f64::NAN);
    // Right half valid (1.0 -> white in Gray) but masked out over a 0.5 background.
    data.slice_mut(ndarray::s![.., 15..]).fill(1.0);
    let mut mask = Array2::from_elem((30, 30), true);
    mask.slice_mut(ndarray::s![.., 15..]).fill(false);
    let mut p = image_panel(data, Colormap::Gray, (0.0, 1.0));
    p.mask = Some(mask);
    p.background = Some(Array2::from_elem((30, 30), 0.5));
    let img = decode(&render_png_bytes(&figure(vec![Panel::Image(p)], 1, "")).unwrap());
    let (gx0, gy0, gx1, gy1) = bbox(&img, |p| p == (64, 64, 64)).expect("no NaN grey");
    let (bx0, by0, bx1, by1) = bbox(&img, |p| p == (128, 128, 128)).expect("no background");
    assert!(gx1 - gx0 > 50 && gy1 - gy0 > 100, "NaN region too small");
    assert!(
        bx1 - bx0 > 50 && by1 - by0 > 100,
        "background region too small"
    );
    assert!(gx1 < bx0, "NaN half must be left of the background half");
    assert!(gy0.abs_diff(by0) <= 1 && gy1.abs_diff(by1) <= 1);
}

/// A 512 × 512 map renders (its speed is measured by `cargo bench -p pcuvd-render`, not here:
/// a timed test fails on a busy machine and passes on a fast one whatever the code does).
#[test]
fn large_image_renders() {
    let n = 512;
    let data = Array2::from_shape_fn((n, n), |(i, j)| {
        ((i as f64) * 0.05).sin() * ((j as f64) * 0.03).cos()
    });
    let mut p = image_panel(data, Colormap::RedBlue, (-1.0, 1.0));
    p.x_mm = (-19.2, 19.2);
    p.z_mm = (0.0, 38.4);
    let fig = Figure {
        title: "timing".into(),
        panels: vec![Panel::Image(p)],
        ncols: 1,
        panel_size_px: (800, 700),
    };
    let img = decode(&render_png_bytes(&fig).unwrap());
    assert_eq!((img.w, img.h), (800, 700 + FIGURE_TITLE_BAND_PX as usize));
}

fn plot_panel() -> PlotPanel {
    PlotPanel {
        title: "plot".into(),
        x_label: "t (s)".into(),
        y_label: "v (mm/s)".into(),
        series: vec![
            Series {
                label: "a".into(),
                x: vec![0.0, 1.0, 2.0, 3.0],
                y: vec![1.0, f64::NAN, 3.0, 4.0],
                y_err: Some(vec![0.1, 0.1, 0.2, 0.3]),
                style: SeriesStyle::LinePoints,
                rgb: None,
            },
            Series {
                label: "b".into(),
                x: vec![0.0, 3.0],
                y: vec![0.5, 2.0],
                style: SeriesStyle::DashedLine,
                ..Default::default()
            },
        ],
        annotations: vec!["RMSE 3.2 mm/s".into()],
        diagonal: true,
        markers: vec![Marker {
            x: 3.0,
            y: 4.0,
            label: "PSV".into(),
            rgb: (200, 0, 0),
        }],
        ..Default::default()
    }
}

#[test]
fn plot_panel_uses_default_colours() {
    let fig = figure(vec![Panel::Plot(plot_panel())], 1, "Plot");
    let img = decode(&render_png_bytes(&fig).unwrap());
    assert_eq!((img.w, img.h), (400, 400));
    // Default first colour (blue) and second (orange) both appear.
    assert!(find_color(&img, (31, 119, 180), 3).len() > 30);
    assert!(find_color(&img, (255, 127, 14), 3).len() > 10);
}

#[test]
fn log_plot_renders() {
    let mut p = plot_panel();
    p.log_y = true;
    p.series[0].y = vec![1e-3, 1e-2, -1.0, 10.0];
    p.diagonal = false;
    let fig = figure(vec![Panel::Plot(p)], 1, "");
    assert!(render_png_bytes(&fig).is_ok());
}

#[test]
fn errors_not_panics() {
    // Empty data.
    let e = Array2::<f64>::zeros((0, 5));
    let fig = figure(
        vec![Panel::Image(image_panel(e, Colormap::Gray, (0.0, 1.0)))],
        1,
        "",
    );
    assert!(matches!(
        render_png_bytes(&fig),
        Err(RenderError::EmptyData(_))
    ));

    // Mask shape mismatch.
    let mut p = image_panel(Array2::zeros((4, 5)), Colormap::Gray, (0.0, 1.0));
    p.mask = Some(Array2::from_elem((5, 4), true));
    let fig = figure(vec![Panel::Image(p)], 1, "");
    assert!(matches!(
        render_png_bytes(&fig),
        Err(RenderError::ShapeMismatch(_))
    ));

    // Background shape mismatch.
    let mut p = image_panel(Array2::zeros((4, 5)), Colormap::Gray, (0.0, 1.0));
    p.background = Some(Array2::zeros((4, 6)));
    let fig = figure(vec![Panel::Image(p)], 1, "");
    assert!(matches!(
        render_png_bytes(&fig),
        Err(RenderError::ShapeMismatch(_))
    ));

    // Non-finite or empty colour range, degenerate extent.
    for range in [(0.0, f64::NAN), (1.0, 1.0), (f64::NEG_INFINITY, 0.0)] {
        let p = image_panel(Array2::zeros((4, 5)), Colormap::Gray, range);
        let fig = figure(vec![Panel::Image(p)], 1, "");
        assert!(matches!(
            render_png_bytes(&fig),
            Err(RenderError::InvalidRange(_))
        ));
    }
    let mut p = image_panel(Array2::zeros((4, 5)), Colormap::Gray, (0.0, 1.0));
    p.x_mm = (3.0, 3.0);
    let fig = figure(vec![Panel::Image(p)], 1, "");
    assert!(matches!(
        render_png_bytes(&fig),
        Err(RenderError::InvalidRange(_))
    ));

    // Overlay length mismatch and bad scale.
    let mut p = image_panel(Array2::zeros((4, 5)), Colormap::Gray, (0.0, 1.0));
    p.arrows = Some(VectorOverlay {
        x_mm: vec![0.0],
        z_mm: vec![],
        vx: vec![1.0],
        vz: vec![1.0],
        scale_mm: 1.0,
        colormap: Colormap::Hot,
        speed_range: (0.0, 1.0),
    });
    let fig = figure(vec![Panel::Image(p.clone())], 1, "");
    assert!(matches!(
        render_png_bytes(&fig),
        Err(RenderError::ShapeMismatch(_))
    ));
    if let Some(a) = p.arrows.as_mut() {
        a.z_mm = vec![1.0];
        a.scale_mm = f64::NAN;
    }
    let fig = figure(vec![Panel::Image(p)], 1, "");
    assert!(matches!(
        render_png_bytes(&fig),
        Err(RenderError::InvalidRange(_))
    ));

    // Polyline length mismatch.
    let mut p = image_panel(Array2::zeros((4, 5)), Colormap::Gray, (0.0, 1.0));
    p.lines.push(Polyline {
        x_mm: vec![0.0, 1.0],
        z_mm: vec![0.0],
        dashed: false,
        rgb: (0, 0, 0),
        label: String::new(),
    });
    let fig = figure(vec![Panel::Image(p)], 1, "");
    assert!(matches!(
        render_png_bytes(&fig),
        Err(RenderError::ShapeMismatch(_))
    ));

    // Series shape mismatch, bad ranges, nothing to plot.
    let mut pp = plot_panel();
    pp.series[0].y.pop();
    assert!(matches!(
        render_png_bytes(&figure(vec![Panel::Plot(pp)], 1, "")),
        Err(RenderError::ShapeMismatch(_))
    ));
    let mut pp = plot_panel();
    pp.series[0].y_err = Some(vec![1.0]);
    assert!(matches!(
        render_png_bytes(&figure(vec![Panel::Plot(pp)], 1, "")),
        Err(RenderError::ShapeMismatch(_))
    ));
    let mut pp = plot_panel();
    pp.y_range = Some((2.0, f64::INFINITY));
    assert!(matches!(
        render_png_bytes(&figure(vec![Panel::Plot(pp)], 1, "")),
        Err(RenderError::InvalidRange(_))
    ));
    let pp = PlotPanel {
        series: vec![Series {
            x: vec![1.0, 2.0],
            y: vec![f64::NAN, f64::NAN],
            ..Default::default()
        }],
        ..Default::default()
    };
    assert!(matches!(
        render_png_bytes(&figure(vec![Panel::Plot(pp)], 1, "")),
        Err(RenderError::EmptyData(_))
    ));

    // Layout problems.
    assert!(matches!(
        render_png_bytes(&figure(vec![], 1, "")),
        Err(RenderError::EmptyData(_))
    ));
    assert!(matches!(
        render_png_bytes(&figure(vec![Panel::Empty], 0, "")),
        Err(RenderError::InvalidLayout(_))
    ));
    let mut fig = figure(vec![Panel::Empty], 1, "");
    fig.panel_size_px = (10, 10);
    assert!(matches!(
        render_png_bytes(&fig),
        Err(RenderError::InvalidLayout(_))
    ));
    fig.panel_size_px = (u32::MAX, u32::MAX);
    assert!(matches!(
        render_png_bytes(&fig),
        Err(RenderError::InvalidLayout(_))
    ));
}

#[test]
fn unwritable_path_is_an_error() {
    let fig = figure(
        vec![Panel::Image(image_panel(
            Array2::zeros((4, 4)),
            Colormap::Magma,
            (0.0, 1.0),
        ))],
        1,
        "",
    );
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("missing").join("fig.png");
    assert!(matches!(
        render_png(&fig, &bad),
        Err(RenderError::Io { .. })
    ));
    let good = dir.path().join("fig.png");
    render_png(&fig, &good).unwrap();
    let bytes = std::fs::read(&good).unwrap();
    let img = decode(&bytes);
    assert_eq!((img.w, img.h), (400, 360));
}

#[test]
fn report_embeds_rendered_png() {
    let fig = figure(vec![Panel::Plot(plot_panel())], 1, "");
    let png = render_png_bytes(&fig).unwrap();
    let mut r = Report::new("Report");
    r.paragraph("x < y").image_png("Figure <1>", &png).table(
        &["a", "b"],
        &[vec!["1".into(), "2".into()], vec!["3".into(), "4".into()]],
    );
    let html = r.to_html();
    assert!(html.contains("<p>x &lt; y</p>"));
    assert!(html.contains("src=\"data:image/png;base64,iVBORw0KGgo"));
    assert!(html.contains("<figcaption>Figure &lt;1&gt;</figcaption>"));
    assert_eq!(html.matches("<tr><td>").count(), 2);
}

/// A spectrogram-like panel: 40 time columns (0..390 ms), 20 velocity rows
/// (-950..950 mm/s, i.e. edges at ±1000); the row with the largest velocity is
/// +1 (red), every other row -1 (blue).
fn spectrogram_panel(y_up: bool, fill: bool, lines: Vec<Polyline>) -> ImagePanel {
    let (nv, nt) = (20, 40);
    let mut data = Array2::<f64>::from_elem((nv, nt), -1.0);
    data.row_mut(nv - 1).fill(1.0);
    ImagePanel {
        title: "spectrogram".into(),
        data,
        x_mm: (0.0, 390.0),
        z_mm: (-950.0, 950.0),
        colormap: Colormap::RedBlue,
        range: (-1.0, 1.0),
        colorbar_label: "dB".into(),
        lines,
        axes: Some(ImageAxes {
            x_label: "time (ms)".into(),
            y_label: "velocity (mm/s)".into(),
            y_up,
            fill,
        }),
        ..Default::default()
    }
}

fn rgb_img(fig: &Figure) -> Img {
    let (w, h, rgb) = render_rgb(fig).unwrap();
    Img {
        w: w as usize,
        h: h as usize,
        rgb,
    }
}

/// Bounding boxes (inclusive, output pixels) of the red (top data row) and blue
/// (all other rows) regions of a rendered `spectrogram_panel`.
type Bbox = (usize, usize, usize, usize);
fn red_blue_boxes(img: &Img) -> (Bbox, Bbox) {
    let red = colormap_rgb(Colormap::RedBlue, 1.0);
    let blue = colormap_rgb(Colormap::RedBlue, 0.0);
    let r = bbox(img, |p| p == red).expect("no red row");
    let b = bbox(img, |p| p == blue).expect("no blue area");
    (r, b)
}

#[test]
fn spectrogram_y_up_puts_largest_velocity_on_top() {
    let img = rgb_img(&figure(
        vec![Panel::Image(spectrogram_panel(true, true, vec![]))],
        1,
        "",
    ));
    let ((rx0, ry0, rx1, ry1), (bx0, by0, bx1, by1)) = red_blue_boxes(&img);
    // The red row is directly above the blue area (at most one blended pixel row
    // between them), spanning the same columns.
    assert_eq!((rx0, rx1), (bx0, bx1), "red and blue columns differ");
    assert!(
        ry1 < by0 && by0 - ry1 <= 2,
        "red {ry0}..{ry1} not just above blue {by0}..{by1}"
    );
    // It is one of 20 rows: about a twentieth of the plot height, at its top.
    let plot_h = (by1 - ry0 + 1) as f64;
    let red_h = (ry1 - ry0 + 1) as f64;
    assert!(
        (red_h - plot_h / 20.0).abs() <= 1.5,
        "red row {red_h} px of {plot_h}"
    );

    // Without y_up the same row is drawn at the bottom (depth-map convention).
    let img = rgb_img(&figure(
        vec![Panel::Image(spectrogram_panel(false, true, vec![]))],
        1,
        "",
    ));
    let ((_, ry0, _, _), (_, _, _, by1)) = red_blue_boxes(&img);
    assert!(
        ry0 > by1,
        "without y_up the red row should be below the blue area"
    );
}

#[test]
fn spectrogram_fill_uses_the_whole_axes_area() {
    let plot_box = |fill: bool| {
        let img = rgb_img(&figure(
            vec![Panel::Image(spectrogram_panel(true, fill, vec![]))],
            1,
            "",
        ));
        let ((rx0, ry0, rx1, _), (bx0, _, bx1, by1)) = red_blue_boxes(&img);
        assert_eq!((rx0, rx1), (bx0, bx1));
        ((bx1 - bx0 + 1) as f64, (by1 - ry0 + 1) as f64)
    };
    // Extent 400 ms x 2000 mm/s: at equal aspect the image is 5x taller than wide.
    let (ew, eh) = plot_box(false);
    assert!((eh / ew - 5.0).abs() < 0.2, "equal aspect {ew}x{eh}");
    let (fw, fh) = plot_box(true);
    assert!(
        fh >= eh - 1.0,
        "filled height {fh} < equal-aspect height {eh}"
    );
    assert!(
        fw > 3.0 * ew,
        "filled width {fw} not much wider than equal-aspect {ew}"
    );
    // Filled: wider than tall in a 400x360 cell, and most of the cell.
    assert!(fw > fh && fw > 0.6 * 400.0 && fh > 0.6 * 360.0, "{fw}x{fh}");
}

#[test]
fn spectrogram_polyline_follows_the_upward_axis() {
    // A horizontal line at +500 mm/s: a quarter of the way down from the top
    // edge (+1000) to the bottom edge (-1000).
    let line = Polyline {
        x_mm: vec![-100.0, 500.0],
        z_mm: vec![500.0, 500.0],
        dashed: false,
        rgb: (0, 255, 0),
        label: String::new(),
    };
    let img = rgb_img(&figure(
        vec![Panel::Image(spectrogram_panel(true, true, vec![line]))],
        1,
        "",
    ));
    let ((_, ry0, _, _), (bx0, _, bx1, by1)) = red_blue_boxes(&img);
    let (top, bottom) = (ry0 as f64, (by1 + 1) as f64);
    let expected = top + 0.25 * (bottom - top);
    let x = (bx0 + bx1) / 2;
    // Green-weighted centroid of the line in the middle column.
    let (mut acc, mut wsum) = (0.0, 0.0);
    for y in ry0..=by1 {
        let p = img.px(x, y);
        let w = (p.1 as f64 - p.0.max(p.2) as f64).max(0.0);
        acc += w * (y as f64 + 0.5);
        wsum += w;
    }
    assert!(wsum > 100.0, "no green line found in column {x}");
    let got = acc / wsum;
    assert!(
        (got - expected).abs() < 1.0,
        "line at row {got:.2}, expected {expected:.2} (plot {top}..{bottom})"
    );
}

#[test]
fn fitted_panel_size_follows_the_image_aspect() {
    // 40 mm wide, 10 mm deep: a short cell, not a tall, mostly empty one.
    let mut wide = image_panel(Array2::zeros((11, 41)), Colormap::Gray, (0.0, 1.0));
    wide.x_mm = (-20.0, 20.0);
    wide.z_mm = (0.0, 10.0);
    let (w, h) = fitted_panel_size(&wide, 560).unwrap();
    assert_eq!(w, 560);
    assert!((250..400).contains(&h), "wide: {h} px tall");
    // 10 mm wide, 30 mm deep: taller than wide, at most twice the width.
    let mut deep = image_panel(Array2::zeros((31, 11)), Colormap::Gray, (0.0, 1.0));
    deep.x_mm = (-5.0, 5.0);
    deep.z_mm = (0.0, 30.0);
    let (_, h_deep) = fitted_panel_size(&deep, 560).unwrap();
    assert!(h_deep > 560 && h_deep <= 1120, "deep: {h_deep} px tall");
    // The image then fills the width: few white columns inside the image row.
    let fig = Figure {
        title: String::new(),
        panels: vec![Panel::Image(wide)],
        ncols: 1,
        panel_size_px: (w, h),
    };
    let img = decode(&render_png_bytes(&fig).unwrap());
    assert_eq!((img.w, img.h), (w as usize, h as usize));
    let black = bbox(&img, |p| p == (0, 0, 0)).expect("image drawn");
    assert!(
        black.2 - black.0 > w as usize / 2,
        "image too narrow: {black:?}"
    );
}

#[test]
fn labelled_lines_get_a_legend_clear_of_them() {
    // A line along the top of the image: the legend goes to a lower corner.
    let mut p = image_panel(Array2::from_elem((20, 20), 1.0), Colormap::Gray, (0.0, 1.0));
    p.lines.push(Polyline {
        x_mm: vec![-10.0, 10.0],
        z_mm: vec![1.0, 1.0],
        dashed: false,
        rgb: (0, 255, 0),
        label: "green line".into(),
    });
    let img = decode(&render_png_bytes(&figure(vec![Panel::Image(p)], 1, "")).unwrap());
    // The legend's dark box on the white image, below the line.
    let dark = bbox(&img, |(r, g, b)| r < 120 && g < 120 && b < 120 && r > 60).expect("legend");
    let line = bbox(&img, |(r, g, b)| g > 200 && r < 80 && b < 80).expect("line");
    // (The legend's own green sample may extend the line's box downward; its top is the line.)
    assert!(
        dark.1 > line.1 + 5,
        "legend {dark:?} overlaps the line {line:?}"
    );
}

#[test]
fn a_long_colour_bar_label_keeps_clear_of_the_cell_edges() {
    // As long as the velocity labels the command draws, in two 400-px columns.
    // Wider than deep, so that the image, and the colour bar beside it, reach the right margin.
    let render = |label: &str| {
        let mut panel = image_panel(Array2::zeros((6, 20)), Colormap::BlueRed, (-600.0, 600.0));
        panel.z_mm = (0.0, 5.0);
        panel.colorbar_label = label.into();
        let fig = figure(
            vec![Panel::Image(panel.clone()), Panel::Image(panel)],
            2,
            "",
        );
        decode(&render_png_bytes(&fig).unwrap())
    };
    let img = render("PSV (mm/s): red = flowing up (toward probe), blue = down");
    let bare = render("");
    assert_eq!(img.w, 800);
    let inked = |x: usize| (0..img.h).any(|y| img.px(x, y) != (255, 255, 255));
    // Five output pixels inside each cell's right edge stay blank: nothing touches the
    // neighbouring panel or the figure's edge.
    for edge in [400, 800] {
        let touching: Vec<usize> = (edge - 5..edge).filter(|&x| inked(x)).collect();
        assert!(touching.is_empty(), "ink at columns {touching:?}");
    }
    // The label is drawn, above what the unlabelled panel draws over the bar's columns.
    let first_ink = |img: &Img| {
        (0..img.h)
            .find(|&y| (300..400).any(|x| img.px(x, y) != (255, 255, 255)))
            .unwrap()
    };
    let (labelled, unlabelled) = (first_ink(&img), first_ink(&bare));
    assert!(
        labelled + 5 < unlabelled,
        "no label above the bar: first ink at row {labelled}, {unlabelled} without the label"
    );
}

#[test]
fn a_title_of_two_lines_gets_room_for_both_above_the_image() {
    let render = |title: &str| {
        let mut panel = image_panel(Array2::zeros((40, 40)), Colormap::Gray, (0.0, 1.0));
        panel.title = title.into();
        decode(&render_png_bytes(&figure(vec![Panel::Image(panel)], 1, "")).unwrap())
    };
    let one = render("PC-UVD: no RI:");
    let two = render("PC-UVD: no RI:\nthe waveform is too short");
    let black = |p: (u8, u8, u8)| p == (0, 0, 0);
    let (_, top_one, _, _) = bbox(&one, black).unwrap();
    let (_, top_two, _, _) = bbox(&two, black).unwrap();
    // The rows above the image (but for its anti-aliased edge), over its columns, that hold
    // ink: one band of text per line.
    let bands = |img: &Img, top: usize| {
        let (x0, _, x1, _) = bbox(img, black).unwrap();
        let inked: Vec<bool> = (0..top - 2)
            .map(|y| (x0..=x1).any(|x| img.px(x, y) != (255, 255, 255)))
            .collect();
        inked.windows(2).filter(|w| !w[0] && w[1]).count() + usize::from(inked[0])
    };
    assert_eq!(bands(&one, top_one), 1);
    assert_eq!(bands(&two, top_two), 2);
    // The second line pushes the image down rather than drawing over it.
    assert!(
        top_two > top_one + 8,
        "image top at row {top_two} with two lines, {top_one} with one"
    );
}

#[test]
fn a_rows_images_line_up_under_titles_of_different_lengths() {
    let panel = |title: &str| {
        let mut p = image_panel(Array2::zeros((40, 40)), Colormap::Gray, (0.0, 1.0));
        p.title = title.into();
        Panel::Image(p)
    };
    let fig = figure(
        vec![
            panel("Truth: RI"),
            panel("PC-UVD: no RI:\nthe waveform\nis too short"),
        ],
        2,
        "",
    );
    let img = decode(&render_png_bytes(&fig).unwrap());
    let black = |p: (u8, u8, u8)| p == (0, 0, 0);
    let top_in = |x0: usize, x1: usize| {
        (0..img.h)
            .find(|&y| (x0..x1).filter(|&x| black(img.px(x, y))).count() >= 20)
            .unwrap()
    };
    let (left, right) = (top_in(0, img.w / 2), top_in(img.w / 2, img.w));
    assert_eq!(left, right, "image tops at rows {left} and {right}");
}
