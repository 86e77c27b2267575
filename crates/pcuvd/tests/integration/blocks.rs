//! Forming images a block of frames at a time gives the whole-recording images: exactly for
//! conventional recordings and for the paper's (simultaneous) decoding, and for coded recordings
//! aligned at mid-frame when each block is decoded with the alignment's reach of margin.

use pcuvd_testing as common;

use ndarray::Array3;
use num_complex::Complex32;
use pcuvd::ChannelData;
use pcuvd::form::decode::EventAlignment;
use pcuvd::pipeline::blocks::Blocks;
use pcuvd::pipeline::{self, ProcessParams, Stage};

const FRAMES: usize = 48;

fn quiet(_: Stage, _: usize, _: usize) {}

fn recording(coded: bool) -> ChannelData {
    common::tube_recording(coded, FRAMES)
}

fn params(data: &ChannelData, alignment: EventAlignment) -> ProcessParams {
    let grid = pcuvd::core::grid::Grid::new(-1.5e-3, 1.5e-3, 5e-3, 7e-3, 0.05e-3).unwrap();
    pcuvd::study::process_params(&grid, &data.acquisition, (1, 1), alignment)
}

/// Largest difference between two image series, relative to the peak of `b`.
fn largest_difference(a: &[Array3<Complex32>], b: &[Array3<Complex32>]) -> f32 {
    let peak = b
        .iter()
        .flat_map(|s| s.iter())
        .map(|v| v.norm())
        .fold(0.0f32, f32::max);
    a.iter()
        .zip(b)
        .flat_map(|(x, y)| x.iter().zip(y.iter()).map(|(p, q)| (p - q).norm()))
        .fold(0.0f32, f32::max)
        / peak
}

fn series(data: &ChannelData, params: &ProcessParams, blocks: Blocks) -> Vec<Array3<Complex32>> {
    let (images, _) = pipeline::form_images_in_blocks(data, params, blocks, &quiet).unwrap();
    images.series
}

#[test]
#[ignore = "slow tier: cargo test -- --include-ignored"]
fn blocks_are_exact_where_every_frame_stands_alone() {
    for (coded, alignment) in [
        (false, EventAlignment::MidFrame),
        (true, EventAlignment::Simultaneous),
    ] {
        let data = recording(coded);
        let params = params(&data, alignment);
        let whole = series(&data, &params, Blocks::whole(FRAMES));
        let (reference, _) = pipeline::form_images(&data, &params, &quiet).unwrap();
        assert_eq!(whole, reference.series);
        for frames in [1, 7, 16] {
            let blocked = series(&data, &params, Blocks { frames, margin: 0 });
            assert_eq!(blocked, whole, "coded {coded}, blocks of {frames}");
        }
    }
}

#[test]
#[ignore = "slow tier: cargo test -- --include-ignored"]
fn coded_mid_frame_blocks_stay_within_the_estimators_spread() {
    let data = recording(true);
    let params = params(&data, EventAlignment::MidFrame);
    let whole = series(&data, &params, Blocks::whole(FRAMES));
    let projections = |images: Vec<Array3<Complex32>>| {
        let (template, _) = pipeline::form_images(&data, &params, &quiet).unwrap();
        let out = pipeline::analyse(template.with_series(images), &params, &quiet).unwrap();
        out.maps.projections
    };
    let reference = projections(whole.clone());
    // The estimator's own spread: the whole-recording projections against the truth.
    let truth = pcuvd::simulate::phantom::Phantom::truth(
        &common::tube(),
        &params.grid.x,
        &params.grid.z,
        0.0,
    );
    let mut own = Vec::new();
    for (k, &theta) in data.acquisition.sequence.angles.iter().enumerate() {
        let (s, c) = pcuvd::estimate::vector::projection_weights(theta);
        for ((iz, ix), &inside) in truth.mask.indexed_iter() {
            let v = reference[[k, iz, ix]];
            let expected = (truth.vx[[iz, ix]] * s + truth.vz[[iz, ix]] * c) / 2.0;
            if inside && v.is_finite() && expected.abs() > 5e-3 {
                own.push((v - expected).powi(2));
            }
        }
    }
    let spread = (own.iter().sum::<f64>() / own.len() as f64).sqrt();
    eprintln!(
        "estimator's own RMS error against the truth: {:.3} mm/s",
        spread * 1e3
    );
    let mut errors = Vec::new();
    for (frames, margin) in [
        (12, 0),
        (12, 8),
        (12, Blocks::ALIGNMENT_MARGIN),
        (24, 16),
        (24, 24),
        // The last block (42..48) decoded with 12 frames of margin would hold 18 frames, fewer
        // than the linear predictor past the recording's end is fitted on.
        (7, Blocks::ALIGNMENT_MARGIN),
    ] {
        let blocked = series(&data, &params, Blocks { frames, margin });
        let image_error = largest_difference(&blocked, &whole);
        let v = projections(blocked);
        // Inside the tube (noise-only pixels have no velocity to compare).
        let flow: Vec<(f64, f64)> = v
            .indexed_iter()
            .filter(|((_, iz, ix), a)| truth.mask[[*iz, *ix]] && a.is_finite())
            .map(|((k, iz, ix), &a)| (a, reference[[k, iz, ix]]))
            .filter(|(_, b)| b.is_finite())
            .collect();
        let rms =
            (flow.iter().map(|(a, b)| (a - b).powi(2)).sum::<f64>() / flow.len() as f64).sqrt();
        eprintln!(
            "blocks of {frames}, margin {margin:2}: largest image difference {image_error:.2e} of the peak; \
             projection RMS difference {:.3} µm/s over {} tube pixels",
            rms * 1e6,
            flow.len()
        );
        errors.push((image_error, rms));
    }
    // A shorter margin shrinks the images' difference (largest in a block's edge frames) and
    // keeps the velocities far inside the estimator's own error; the default margin, the
    // alignment's reach, gives the whole-recording images exactly, as does a longer one.
    assert!(errors[1].0 < 0.1 * errors[0].0, "{errors:?}");
    assert!(errors[1].1 < 0.01 * spread, "{errors:?} against {spread}");
    assert_eq!(errors[2], (0.0, 0.0), "default margin: {errors:?}");
    assert_eq!(errors[3], (0.0, 0.0), "a longer margin: {errors:?}");
    assert_eq!(
        errors[4],
        (0.0, 0.0),
        "a margin that reaches the ends is the whole path"
    );
    assert_eq!(
        errors[5],
        (0.0, 0.0),
        "short blocks at the recording's ends: {errors:?}"
    );
}
