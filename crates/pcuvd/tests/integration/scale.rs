//! A recording's scale: every map but the power maps (the dynamics windows' too) is the same, bit
//! for bit, at any power-of-two scale within the range single-precision lag products hold (no absolute amplitude
//! threshold hides in the chain), and a recording outside that range is refused, where it would
//! have become noise (Field II's 10⁻²⁰-scale RF) or infinities.

use pcuvd_testing as common;

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

/// Whether two maps hold the same values bit for bit (NaN where the other has the same NaN).
fn same_bits<'a>(
    a: impl IntoIterator<Item = &'a f64>,
    b: impl IntoIterator<Item = &'a f64>,
) -> bool {
    let (a, b): (Vec<u64>, Vec<u64>) = (
        a.into_iter().map(|v| v.to_bits()).collect(),
        b.into_iter().map(|v| v.to_bits()).collect(),
    );
    a == b
}

fn assert_same_maps(out: &ProcessOutput, reference: &ProcessOutput, power_scale: f64, label: &str) {
    let (maps, expected) = (&out.maps, &reference.maps);
    let fields = |m: &pcuvd::pipeline::DopplerMaps| {
        let vectors =
            [&m.vector_ls, &m.vector_irls].map(|v| v.clone().expect("two angles or more"));
        [
            m.color_doppler.clone().into_raw_vec_and_offset().0,
            m.projections.clone().into_raw_vec_and_offset().0,
            vectors[0].vx.clone().into_raw_vec_and_offset().0,
            vectors[0].vz.clone().into_raw_vec_and_offset().0,
            vectors[1].vx.clone().into_raw_vec_and_offset().0,
            vectors[1].vz.clone().into_raw_vec_and_offset().0,
        ]
    };
    let names = [
        "colour Doppler",
        "projections",
        "LS vx",
        "LS vz",
        "IRLS vx",
        "IRLS vz",
    ];
    for ((name, got), want) in names.iter().zip(fields(maps)).zip(fields(expected)) {
        let worst = got
            .iter()
            .zip(&want)
            .filter(|(a, b)| a.to_bits() != b.to_bits())
            .map(|(a, b)| ((a - b) / b).abs())
            .fold(0.0f64, |w, e| if e.is_nan() || e > w { e } else { w });
        let count = got
            .iter()
            .zip(&want)
            .filter(|(a, b)| a.to_bits() != b.to_bits())
            .count();
        assert!(
            same_bits(&got, &want),
            "{label}: {name}: {count} values differ, worst {worst:e}"
        );
    }
    assert!(
        same_bits(&out.bmode_db, &reference.bmode_db),
        "{label}: B-mode"
    );
    let cut = |o: &ProcessOutput| o.clutter.iter().map(|c| c.low).collect::<Vec<_>>();
    assert_eq!(cut(out), cut(reference), "{label}: tissue cut-offs");
    assert!(
        same_bits(
            &maps.power_doppler,
            &expected.power_doppler.mapv(|p| p * power_scale)
        ),
        "{label}: power Doppler, scaled by the square of the samples' scale"
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
            assert!(same_bits(&got.vx, &want.vx), "{label}: windows' vx");
            assert!(same_bits(&got.vz, &want.vz), "{label}: windows' vz");
            let power = want.power.mapv(|p| p * 2f64.powi(2 * k));
            assert!(same_bits(&got.power, &power), "{label}: windows' power");
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
