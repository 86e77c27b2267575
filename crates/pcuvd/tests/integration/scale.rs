//! A recording's scale: every map but the power maps (the dynamics windows' too) is the same, bit
//! for bit, at any power-of-two scale within the range single-precision lag products hold (no
//! absolute amplitude threshold hides in the chain), and a recording outside that range is
//! refused, where it would have become noise (Field II's 10⁻²⁰-scale RF) or infinities.

use pcuvd_testing as common;

use ndarray::{Array, Dimension};

use pcuvd::acquisition::channel::Samples;
use pcuvd::core::lags::SAMPLE_PEAK_RANGE;
use pcuvd::dynamics::{DynamicsParams, sliding_vectors};
use pcuvd::estimate::clutter::RankCut;
use pcuvd::form::decode::EventAlignment;
use pcuvd::pipeline::{self, ProcessOutput, ProcessParams, Stage};
use pcuvd::{ChannelData, Error};

fn quiet(_: Stage, _: usize, _: usize) {}

/// The recording's samples multiplied by `factor`.
fn scaled(data: &ChannelData, factor: f32) -> ChannelData {
    let mut scaled = data.clone();
    match &mut scaled.samples {
        Samples::Rf(a) => a.mapv_inplace(|v| v * factor),
        Samples::Iq { data, .. } => data.mapv_inplace(|v| v * factor),
    }
    scaled
}

fn peak(data: &ChannelData) -> f32 {
    match &data.samples {
        Samples::Rf(a) => a.iter().fold(0.0f32, |p, v| p.max(v.abs())),
        Samples::Iq { data, .. } => data.iter().fold(0.0f32, |p, v| p.max(v.norm())),
    }
}

/// The defaults' processing that amplitudes could reach: the `auto` tissue cut-off, the
/// partial-volume correction and a 5x1 Doppler kernel.
fn params(data: &ChannelData) -> ProcessParams {
    let grid = pcuvd::core::grid::Grid::new(-1.5e-3, 1.5e-3, 5e-3, 7e-3, 0.05e-3).unwrap();
    let mut params =
        pcuvd::study::process_params(&grid, &data.acquisition, (5, 1), EventAlignment::MidFrame);
    params.clutter.low = RankCut::Auto;
    params.partial_volume = true;
    params
}

/// Sliding windows of 6 frames, 3 apart, at the dynamics' defaults otherwise (IRLS, the
/// partial-volume correction).
fn dynamics() -> DynamicsParams {
    DynamicsParams {
        window: 6,
        step: 3,
        heart_rate_hz: None,
        partial_volume: true,
        ..DynamicsParams::rat()
    }
}

/// Asserts [`common::same_bits`] of two maps, saying how many values differ and by how much.
fn assert_same<D: Dimension>(got: &Array<f64, D>, want: &Array<f64, D>, what: &str) {
    let differing = || {
        got.iter()
            .zip(want)
            .filter(|(a, b)| a.to_bits() != b.to_bits())
    };
    let worst = differing()
        .map(|(a, b)| ((a - b) / b).abs())
        .fold(0.0f64, |w, e| if e.is_nan() || e > w { e } else { w });
    assert!(
        common::same_bits(got, want),
        "{what}: {} values differ, worst {worst:e}",
        differing().count()
    );
}

fn assert_same_maps(out: &ProcessOutput, reference: &ProcessOutput, power_scale: f64, label: &str) {
    let (maps, expected) = (&out.maps, &reference.maps);
    let what = |name: &str| format!("{label}: {name}");
    assert_same(
        &maps.color_doppler,
        &expected.color_doppler,
        &what("colour Doppler"),
    );
    assert_same(
        &maps.projections,
        &expected.projections,
        &what("projections"),
    );
    for (name, got, want) in [
        ("LS", &maps.vector_ls, &expected.vector_ls),
        ("IRLS", &maps.vector_irls, &expected.vector_irls),
    ] {
        let (got, want) = (
            got.as_ref().expect("two angles"),
            want.as_ref().expect("two angles"),
        );
        assert_same(&got.vx, &want.vx, &what(&format!("{name} vx")));
        assert_same(&got.vz, &want.vz, &what(&format!("{name} vz")));
    }
    assert_same(&out.bmode_db, &reference.bmode_db, &what("B-mode"));
    let cut = |o: &ProcessOutput| o.clutter.iter().map(|c| c.low).collect::<Vec<_>>();
    assert_eq!(cut(out), cut(reference), "{label}: tissue cut-offs");
    assert_same(
        &maps.power_doppler,
        &expected.power_doppler.mapv(|p| p * power_scale),
        &what("power Doppler, scaled by the square of the samples' scale"),
    );
}

#[test]
fn maps_are_the_same_at_any_power_of_two_scale_within_range() {
    for coded in [false, true] {
        let data = common::tube_recording(coded, 12);
        let params = params(&data);
        let reference = pipeline::process(&data, &params, &quiet).unwrap();
        let (low, high) = SAMPLE_PEAK_RANGE;
        let exponent = |target: f32| (target / peak(&data)).log2().round() as i32;
        // Powers of two that put the peak 2⁻³⁰ and 2⁴⁶: every value and product a normal float.
        for k in [exponent(low) + 20, exponent(high) - 2] {
            let out = pipeline::process(&scaled(&data, 2f32.powi(k)), &params, &quiet).unwrap();
            let label = format!("coded {coded}, scaled by 2^{k}");
            assert_same_maps(&out, &reference, 2f64.powi(2 * k), &label);
            // The dynamics windows (the RI maps' velocities), with their own correction.
            let windows = |o: &ProcessOutput| sliding_vectors(&o.filtered, &dynamics()).unwrap();
            let (got, want) = (windows(&out), windows(&reference));
            assert_same(&got.vx, &want.vx, &format!("{label}: windows' vx"));
            assert_same(&got.vz, &want.vz, &format!("{label}: windows' vz"));
            let power = want.power.mapv(|p| p * 2f64.powi(2 * k));
            assert_same(&got.power, &power, &format!("{label}: windows' power"));
        }
        // At the range's floor the weakest pixels' single-precision products reach subnormals
        // and lose their last bits: a rounding's difference, not noise.
        let k = exponent(low) + 1;
        let out = pipeline::process(&scaled(&data, 2f32.powi(k)), &params, &quiet).unwrap();
        let (got, want) = (&out.maps.projections, &reference.maps.projections);
        let largest = want
            .iter()
            .filter(|v| v.is_finite())
            .fold(0.0f64, |m, v| m.max(v.abs()));
        for (a, b) in got.iter().zip(want) {
            assert!(
                (a.is_nan() && b.is_nan()) || (a - b).abs() <= 1e-12 * largest,
                "coded {coded}, scaled by 2^{k}: projection {a} against {b}"
            );
        }
    }
}

/// Samples that peak outside the range are refused with the scale they have and a factor into
/// it, for a tiny recording (Field II's scale) and a huge one, before anything is formed.
#[test]
fn recordings_outside_the_sample_range_are_refused() {
    let data = common::tube_recording(false, 4);
    let params = params(&data);
    for target in [1e-22f32, 1e17] {
        let factor = target / peak(&data);
        let error = pipeline::process(&scaled(&data, factor), &params, &quiet).unwrap_err();
        let Error::InvalidParameter { name, reason } = &error else {
            panic!("{target:e}: {error}")
        };
        assert_eq!(name, "sample scale", "{error}");
        let side = if target < 1.0 { "below" } else { "above" };
        assert!(
            reason.contains(side) && reason.contains("scale the samples into it"),
            "{error}"
        );
    }
}

/// A frame beyond the range after the first one of its block (corrupt or saturated; the scale
/// check reads each block's first frame) overflows the power Doppler: refused, not written as
/// maps of infinities and noise around them.
#[test]
fn a_later_frame_beyond_the_range_is_refused_where_it_overflows() {
    let data = common::tube_recording(false, 4);
    let n_angles = data.acquisition.sequence.n_angles();
    let mut corrupt = data.clone();
    let Samples::Rf(samples) = &mut corrupt.samples else {
        panic!("the tube is RF")
    };
    // Every channel of frame 2's first event.
    samples
        .index_axis_mut(ndarray::Axis(0), 2 * n_angles)
        .fill(1e30);
    let params = params(&data);
    let error = pipeline::process(&corrupt, &params, &quiet).unwrap_err();
    let Error::InvalidParameter { name, reason } = &error else {
        panic!("{error}")
    };
    assert_eq!(name, "sample scale", "{error}");
    assert!(reason.contains("infinite"), "{error}");
    // The same recording without the corrupt frame processes.
    assert!(pipeline::process(&data, &params, &quiet).is_ok());
}
