//! Rendering speed: one 512 × 512 map with a colour bar, PNG-encoded.
//!
//! `cargo bench -p pcuvd-render`. Replaces a timed test: run it in release, on a quiet machine,
//! and compare figures taken in one session.

use criterion::{Criterion, criterion_group, criterion_main};
use ndarray::Array2;
use pcuvd_render::{Colormap, Figure, ImagePanel, Panel, render_png_bytes};

/// A 512 × 512 red-blue map, 38.4 mm square, in an 800 × 700 px panel.
fn large_map() -> Figure {
    let n = 512;
    let data = Array2::from_shape_fn((n, n), |(i, j)| {
        ((i as f64) * 0.05).sin() * ((j as f64) * 0.03).cos()
    });
    Figure {
        title: "timing".into(),
        panels: vec![Panel::Image(ImagePanel {
            title: "512 × 512".into(),
            data,
            x_mm: (-19.2, 19.2),
            z_mm: (0.0, 38.4),
            colormap: Colormap::RedBlue,
            range: (-1.0, 1.0),
            colorbar_label: "mm/s".into(),
            ..Default::default()
        })],
        ncols: 1,
        panel_size_px: (800, 700),
    }
}

fn bench(c: &mut Criterion) {
    let figure = large_map();
    let mut group = c.benchmark_group("render");
    group.sample_size(10);
    group.bench_function("map_512x512_png", |b| {
        b.iter(|| render_png_bytes(&figure).expect("render"))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
