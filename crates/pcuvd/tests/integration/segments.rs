//! A long recording processed in segments ([`pcuvd::pipeline::segments`]): one segment gives the
//! whole-recording path's maps; several stay within the estimator's own spread, and the time
//! series' ensembles, each filtered on its own, are the whole-recording path's exactly. Vector
//! dealiasing applies on both paths alike. Both Doppler estimators: Kasai (the lag-1 sums) and
//! Loupas (the lag-1 and the spatial lags within frames and at temporal lags ±1, summed per core
//! alike).

use ndarray::{Array2, Array3};
use pcuvd::dynamics::DynamicsParams;
use pcuvd::estimate::clutter::{ClutterParams, RankCut};
use pcuvd::estimate::dealias::Dealias;
use pcuvd::estimate::doppler::DopplerEstimator;
use pcuvd::form::decode::EventAlignment;
use pcuvd::pipeline::ensembles::{self, EnsembleSpec};
use pcuvd::pipeline::segments::{SegmentRun, SegmentSource, Segments, process_in_segments};
use pcuvd::pipeline::{self, ProcessParams, Stage};
use pcuvd::simulate::phantom::{Phantom, TubePhantom};
use pcuvd::simulate::{NoiseSpec, SimParams, simulate};
use pcuvd::{ChannelData, Coding, Probe, Samples, Sequence};
use pcuvd_testing::{same_bits, tube, tube_at};

const FRAMES: usize = 64;

fn quiet(_: Stage, _: usize, _: usize) {}

/// A 48-element, 5-angle conventional recording of a tube 6 mm deep flowing at 30 mm/s, noise
/// −20 dB: every frame's images stand alone, so segments image exactly what the whole path does.
fn recording() -> ChannelData {
    recording_of(&tube())
}

fn recording_of(phantom: &TubePhantom) -> ChannelData {
    simulate(phantom, &sim_params(), FRAMES, &|_, _| {}).unwrap()
}

/// The acquisition of [`recording_of`].
fn sim_params() -> SimParams {
    let probe = Probe {
        n_elements: 48,
        ..Probe::l22_14vx()
    };
    let sequence = Sequence {
        angles: Sequence::evenly_spaced_angles(5, 12f64.to_radians()),
        event_prf: 9e3,
        coding: Coding::Conventional,
        pulse_cycles: 2.0,
        pulse: None,
    };
    let mut params = SimParams::new(probe, sequence, 65e6, 1540.0, (4e-3, 8e-3)).unwrap();
    params.noise = Some(NoiseSpec::new(-20.0));
    params.seed = 5;
    params
}

fn params(data: &ChannelData) -> ProcessParams {
    params_with(data, DopplerEstimator::default())
}

/// The processing settings of these tests with the Doppler estimator `estimator` (0.05 mm grid:
/// fine enough for Loupas).
fn params_with(data: &ChannelData, estimator: DopplerEstimator) -> ProcessParams {
    let grid = pcuvd::core::grid::Grid::new(-1.5e-3, 1.5e-3, 5e-3, 7e-3, 0.05e-3).unwrap();
    ProcessParams {
        doppler_estimator: estimator,
        ..pcuvd::study::process_params(&grid, &data.acquisition, (1, 1), EventAlignment::MidFrame)
    }
}

/// Windows of 16 frames every 8, reading velocity with `estimator`.
fn windows_with(estimator: DopplerEstimator) -> DynamicsParams {
    DynamicsParams {
        doppler: estimator,
        ..windows()
    }
}

/// Windows of 16 frames every 8; no heart rate needed for the windows themselves.
fn windows() -> DynamicsParams {
    DynamicsParams {
        window: 16,
        step: 8,
        heart_rate_hz: None,
        ..DynamicsParams::rat()
    }
}

const ENSEMBLES: EnsembleSpec = EnsembleSpec {
    frames: 12,
    step: 6,
};

/// Largest |a − b| over the pixels where both are finite, relative to b's largest |value|; and
/// whether both are NaN at the same pixels.
fn relative_difference(a: &Array2<f64>, b: &Array2<f64>) -> (f64, bool) {
    let scale = b
        .iter()
        .filter(|v| v.is_finite())
        .fold(0.0f64, |m, v| m.max(v.abs()));
    let same_nan = a.iter().zip(b).all(|(x, y)| x.is_nan() == y.is_nan());
    let diff = a
        .iter()
        .zip(b)
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
    (diff / scale.max(f64::MIN_POSITIVE), same_nan)
}

fn per_angle(a: &Array3<f64>) -> Vec<Array2<f64>> {
    a.outer_iter().map(|m| m.to_owned()).collect()
}

#[test]
fn one_segment_gives_the_whole_recording_maps() {
    let data = recording();
    for estimator in DopplerEstimator::ALL {
        one_segment_is_the_whole_path(&data, estimator);
    }
}

fn one_segment_is_the_whole_path(data: &ChannelData, estimator: DopplerEstimator) {
    let params = params_with(data, estimator);
    let windows = || windows_with(estimator);
    let whole = pipeline::process(data, &params, &quiet).unwrap();
    let one = Segments {
        core: FRAMES,
        overlap: 0,
    };
    let done = process_in_segments(
        data,
        &params,
        &one,
        Some(&windows()),
        Some(ENSEMBLES),
        &quiet,
    )
    .unwrap();
    assert_eq!(done.ranges, vec![(0..FRAMES, 0..FRAMES)]);
    let out = &done.out;
    let mut maps = vec![
        ("B-mode", out.bmode_db.clone(), whole.bmode_db.clone()),
        (
            "power",
            out.maps.power_doppler.clone(),
            whole.maps.power_doppler.clone(),
        ),
        (
            "colour",
            out.maps.color_doppler.clone(),
            whole.maps.color_doppler.clone(),
        ),
    ];
    for (k, (a, b)) in per_angle(&out.maps.projections)
        .into_iter()
        .zip(per_angle(&whole.maps.projections))
        .enumerate()
    {
        maps.push((if k == 0 { "projection 0" } else { "projection" }, a, b));
    }
    let (irls, reference) = (
        out.maps.vector_irls.as_ref().unwrap(),
        whole.maps.vector_irls.as_ref().unwrap(),
    );
    maps.push(("Vx", irls.vx.clone(), reference.vx.clone()));
    maps.push(("Vz", irls.vz.clone(), reference.vz.clone()));
    for (name, a, b) in &maps {
        let (diff, same_nan) = relative_difference(a, b);
        assert!(same_nan, "{estimator:?} {name}: NaN at other pixels");
        assert!(
            diff < 1e-5,
            "{estimator:?} {name}: differs by {diff:.2e} of its peak"
        );
    }
    // The dynamics windows and ensembles of the one segment are the whole path's.
    let series = done.series.unwrap();
    let reference = pcuvd::dynamics::sliding_vectors(&whole.filtered, &windows()).unwrap();
    assert_eq!(series.times_s, reference.times_s);
    assert_eq!(series.vx, reference.vx);
    let (images, _) = pipeline::form_images(data, &params, &quiet).unwrap();
    let ensembles = ensembles::ensemble_maps(&images, &params, ENSEMBLES, &quiet).unwrap();
    assert_eq!(done.ensembles.unwrap(), ensembles);
}

#[test]
fn segments_stay_within_the_estimators_spread() {
    let data = recording();
    let mut read = Vec::new();
    for estimator in DopplerEstimator::ALL {
        read.push(segments_against_the_whole_path(&data, estimator));
    }
    // Loupas sums its own moments per core: its segmented projections are not Kasai's.
    assert!(
        (read[0] - read[1]).abs() > 1e-6,
        "Kasai and Loupas segments read alike: {read:?}"
    );
}

/// Runs the several-segment check with `estimator`; returns the segmented projections' RMS
/// error against the truth in the tube (m/s).
fn segments_against_the_whole_path(data: &ChannelData, estimator: DopplerEstimator) -> f64 {
    let params = params_with(data, estimator);
    let windows = || windows_with(estimator);
    let whole = pipeline::process(data, &params, &quiet).unwrap();
    // 24-frame cores (a multiple of both steps), each imaged with the 8 frames after it that the
    // last window starting in it (16 frames from 8 before its end) reaches.
    let segments = Segments::plan(FRAMES, 40, Some(&windows()), Some(ENSEMBLES))
        .unwrap()
        .unwrap();
    assert_eq!(
        segments,
        Segments {
            core: 24,
            overlap: 8
        }
    );
    let done = process_in_segments(
        data,
        &params,
        &segments,
        Some(&windows()),
        Some(ENSEMBLES),
        &quiet,
    )
    .unwrap();
    assert_eq!(
        done.ranges,
        vec![(0..24, 0..32), (24..48, 24..56), (48..64, 48..64)]
    );

    // The estimator's own spread: the whole-recording projections against the truth, in the tube.
    let truth = tube().truth(&params.grid.x, &params.grid.z, 0.0);
    let angles = &data.acquisition.sequence.angles;
    let rms_against = |projections: &Array3<f64>, reference: Option<&Array3<f64>>| {
        let mut squares = Vec::new();
        for (k, &theta) in angles.iter().enumerate() {
            let (s, c) = pcuvd::estimate::vector::projection_weights(theta);
            for ((iz, ix), &inside) in truth.mask.indexed_iter() {
                let v = projections[[k, iz, ix]];
                let expected = match reference {
                    Some(r) => r[[k, iz, ix]],
                    None => (truth.vx[[iz, ix]] * s + truth.vz[[iz, ix]] * c) / 2.0,
                };
                if inside && v.is_finite() && expected.is_finite() {
                    squares.push((v - expected).powi(2));
                }
            }
        }
        (squares.iter().sum::<f64>() / squares.len() as f64).sqrt()
    };
    let spread = rms_against(&whole.maps.projections, None);
    let segmented = rms_against(&done.out.maps.projections, None);
    let apart = rms_against(&done.out.maps.projections, Some(&whole.maps.projections));
    eprintln!(
        "{estimator:?} projections in the tube: whole path {:.3} mm/s RMS from the truth, \
         segments {:.3} mm/s; segments against the whole path {:.3} mm/s RMS",
        spread * 1e3,
        segmented * 1e3,
        apart * 1e3
    );
    assert!(apart < spread, "{apart} against the estimator's {spread}");
    assert!(segmented < 1.2 * spread, "{segmented} against {spread}");

    // The B-mode is unfiltered: its mean envelope summed over the segments is the whole path's.
    let (diff, _) = relative_difference(&done.out.bmode_db, &whole.bmode_db);
    assert!(diff < 1e-5, "B-mode differs by {diff:.2e}");

    // Every dynamics window and ensemble of the whole path, at the same times.
    let series = done.series.unwrap();
    let reference = pcuvd::dynamics::sliding_vectors(&whole.filtered, &windows()).unwrap();
    assert_eq!(series.len(), reference.len());
    for (a, b) in series.times_s.iter().zip(&reference.times_s) {
        assert!((a - b).abs() < 1e-12, "window at {a} s against {b} s");
    }
    let (images, _) = pipeline::form_images(data, &params, &quiet).unwrap();
    let ensembles = ensembles::ensemble_maps(&images, &params, ENSEMBLES, &quiet).unwrap();
    // Each ensemble is filtered on its own from the same images: the same maps.
    assert_eq!(done.ensembles.unwrap(), ensembles);
    segmented
}

#[test]
fn a_segment_too_short_for_the_windows_is_refused_by_name() {
    let e = Segments::plan(FRAMES, 20, Some(&windows()), Some(ENSEMBLES))
        .unwrap_err()
        .to_string();
    // 8 frames of overlap and a core of one 24-frame alignment step.
    assert!(
        e.contains("segment frames") && e.contains("at least 32"),
        "{e}"
    );
    assert_eq!(Segments::shortest(Some(&windows()), Some(ENSEMBLES)), 32);
    assert_eq!(
        Segments::plan(FRAMES, FRAMES, Some(&windows()), None).unwrap(),
        None
    );
}

/// `--dealias auto` in segments: the maps from the totals, every ensemble and every dynamics
/// window are dealiased, as on the whole-recording path; one segment gives the whole path's
/// dealiased vectors, windows (at the K the maps chose) and ensembles.
/// A tube at 3.5 × the Nyquist velocity at f_0, and the settings that dealias it: the maps'
/// and the windows' dealiasing automatic.
///
/// With this 20° tube the largest projection (at +12°) is about 0.44 of the peak speed,
/// 1.5 v_N. Loupas (the default) scales by the echo's mean frequency, here about 9 % below f_0, so
/// its own Nyquist velocity is that much higher, and a tube at 2.5 × (1.1 v_N at f_0) would
/// barely wrap.
fn aliasing_tube() -> (ChannelData, ProcessParams, DynamicsParams) {
    let acquisition = sim_params().acquisition();
    let nyquist = pcuvd::estimate::doppler::nyquist_velocity(
        acquisition.sound_speed,
        acquisition.frame_rate(),
        acquisition.probe.center_frequency,
    );
    let data = recording_of(&tube_at(3.5 * nyquist));
    let params = ProcessParams {
        dealias: Dealias::Auto,
        ..params(&data)
    };
    let dynamics = DynamicsParams {
        dealias: Dealias::Auto,
        ..windows()
    };
    (data, params, dynamics)
}

#[test]
#[ignore = "slow tier: cargo test -- --include-ignored"]
fn segments_dealias_as_the_whole_path_does() {
    let (data, params, dynamics) = aliasing_tube();
    let whole = pipeline::process(&data, &params, &quiet).unwrap();
    let dealiased = whole
        .maps
        .dealias
        .clone()
        .expect("the whole path dealiases");
    assert!(
        dealiased.irls.unwrapped_pixels > 0,
        "the fast tube aliases: {dealiased:?}"
    );
    let at_k = DynamicsParams {
        dealias: Dealias::Intervals(dealiased.intervals),
        ..dynamics
    };
    let reference = pcuvd::dynamics::sliding_vectors(&whole.filtered, &at_k).unwrap();
    let plain = pcuvd::dynamics::sliding_vectors(
        &whole.filtered,
        &DynamicsParams {
            dealias: Dealias::Off,
            ..dynamics
        },
    )
    .unwrap();
    assert_ne!(reference.vx, plain.vx, "the windows need dealiasing");
    let (images, _) = pipeline::form_images(&data, &params, &quiet).unwrap();
    let ensembles = ensembles::ensemble_maps(&images, &params, ENSEMBLES, &quiet).unwrap();

    let one = Segments {
        core: FRAMES,
        overlap: 0,
    };
    let done = process_in_segments(
        &data,
        &params,
        &one,
        Some(&dynamics),
        Some(ENSEMBLES),
        &quiet,
    )
    .unwrap();
    let out_dealiased = done
        .out
        .maps
        .dealias
        .as_ref()
        .expect("the segments dealias");
    assert_eq!(out_dealiased.intervals, dealiased.intervals);
    assert_eq!(
        out_dealiased.irls.unwrapped_pixels,
        dealiased.irls.unwrapped_pixels
    );
    let (irls, reference_irls) = (
        done.out.maps.vector_irls.as_ref().unwrap(),
        whole.maps.vector_irls.as_ref().unwrap(),
    );
    for (name, a, b) in [
        ("Vx", &irls.vx, &reference_irls.vx),
        ("Vz", &irls.vz, &reference_irls.vz),
    ] {
        let (diff, same_nan) = relative_difference(a, b);
        assert!(same_nan, "{name}: NaN at other pixels");
        assert!(diff < 1e-5, "{name}: differs by {diff:.2e} of its peak");
    }
    let series = done.series.unwrap();
    assert_eq!(series.vx, reference.vx);
    assert_eq!(series.vz, reference.vz);
    assert_eq!(done.ensembles.unwrap(), ensembles);

    // Several segments: the maps from the totals are dealiased too, and every window.
    let segments = Segments::plan(FRAMES, 40, Some(&dynamics), Some(ENSEMBLES))
        .unwrap()
        .unwrap();
    let done = process_in_segments(
        &data,
        &params,
        &segments,
        Some(&dynamics),
        Some(ENSEMBLES),
        &quiet,
    )
    .unwrap();
    assert!(done.ranges.len() > 1);
    let out_dealiased = done
        .out
        .maps
        .dealias
        .as_ref()
        .expect("the segments dealias");
    assert!(out_dealiased.irls.unwrapped_pixels > 0, "{out_dealiased:?}");
    assert_eq!(done.series.unwrap().len(), reference.len());
    assert_eq!(done.ensembles.unwrap(), ensembles);
}

/// A given heart rate whose cycle is longer than a segment, but not than the recording: each
/// segment keeps its windows (the cycle is checked, and the RI maps made, on the joined windows),
/// and they are the whole path's.
#[test]
fn segments_shorter_than_a_cardiac_cycle_keep_their_windows() {
    let data = recording();
    let params = params(&data);
    // A cycle of 40 frames: 5 windows, more than a segment's 3 (32 frames imaged), fewer than
    // the recording's 7.
    let beating = DynamicsParams {
        heart_rate_hz: Some(data.acquisition.frame_rate() / 40.0),
        ..windows()
    };
    let segments = Segments {
        core: 24,
        overlap: 8,
    };
    let done =
        process_in_segments(&data, &params, &segments, Some(&beating), None, &quiet).unwrap();
    let whole = pipeline::process(&data, &params, &quiet).unwrap();
    let reference = pcuvd::dynamics::sliding_vectors(&whole.filtered, &beating).unwrap();
    let series = done.series.unwrap();
    assert_eq!(series.len(), reference.len());
    for (a, b) in series.times_s.iter().zip(&reference.times_s) {
        assert!((a - b).abs() < 1e-12, "window at {a} s against {b} s");
    }
    let maps = pcuvd::dynamics::ri_maps(&series, &beating).unwrap();
    assert_eq!(maps.ri.dim(), params.grid.shape());
}

/// The segments of one run processed apart (as other processes would: no memory handed on, the
/// first segment's Nyquist intervals passed to the others) and joined in any order give the run
/// of one process bit for bit: maps, B-mode, velocity windows and ensembles. A set of parts that
/// is not the recording's is refused.
#[test]
fn segments_processed_apart_join_into_the_one_process_run() {
    let (data, params, dynamics) = aliasing_tube();
    let segments = Segments::plan(FRAMES, 40, Some(&dynamics), Some(ENSEMBLES))
        .unwrap()
        .unwrap();
    let one = process_in_segments(
        &data,
        &params,
        &segments,
        Some(&dynamics),
        Some(ENSEMBLES),
        &quiet,
    )
    .unwrap();
    let run = SegmentRun {
        params: &params,
        segments: &segments,
        dynamics: Some(&dynamics),
        ensembles: Some(ENSEMBLES),
        kept_pixels: &[],
    };
    let count = run.count(SegmentSource::Channels(&data));
    assert!(count >= 3, "{count} segments");
    assert!(run.first_settles_windows(SegmentSource::Channels(&data)));
    let first = run
        .segment(SegmentSource::Channels(&data), 0, None, &quiet)
        .unwrap();
    let intervals = first.window_intervals;
    assert!(intervals.is_some_and(|k| k > 0), "{intervals:?}");
    let mut parts: Vec<_> = (1..count)
        .rev()
        .map(|index| {
            run.segment(SegmentSource::Channels(&data), index, intervals, &quiet)
                .unwrap()
        })
        .collect();
    parts.push(first);
    let joined = run
        .join(SegmentSource::Channels(&data), parts.clone())
        .unwrap();
    assert_eq!(joined.out.bmode_db, one.out.bmode_db);
    assert_eq!(joined.out.maps.power_doppler, one.out.maps.power_doppler);
    let (a, b) = (
        joined.out.maps.vector_irls.as_ref().unwrap(),
        one.out.maps.vector_irls.as_ref().unwrap(),
    );
    assert!(same_bits(&a.vx, &b.vx) && same_bits(&a.vz, &b.vz));
    assert_eq!(joined.out.maps.dealias, one.out.maps.dealias);
    assert_eq!(joined.series, one.series);
    assert_eq!(joined.ensembles, one.ensembles);
    assert_eq!(joined.ranges, one.ranges);
    assert_eq!(joined.clutter, one.clutter);

    // Handed to a sink, the ensembles come in recording order, one part per segment, and make
    // the same series; the run keeps their times alone.
    struct Collect(Vec<ensembles::EnsembleMaps>);
    impl pcuvd::pipeline::segments::EnsembleSink for Collect {
        fn append(&mut self, part: &ensembles::EnsembleMaps) -> pcuvd::Result<()> {
            self.0.push(part.clone());
            Ok(())
        }
    }
    let mut sink = Collect(Vec::new());
    let sunk = run
        .join_into(
            SegmentSource::Channels(&data),
            parts.clone(),
            Some(&mut sink),
        )
        .unwrap();
    assert_eq!(sink.0.len(), count);
    let expected = one.ensembles.clone().unwrap();
    assert_eq!(
        ensembles::EnsembleMaps::concatenate(sink.0).unwrap(),
        expected
    );
    let kept = sunk.ensembles.unwrap();
    assert_eq!(
        (kept.times_s, kept.starts, kept.clutter),
        (expected.times_s, expected.starts, expected.clutter)
    );
    assert_eq!(kept.power_doppler.dim().0, 0);
    assert_eq!(sunk.out.maps.power_doppler, one.out.maps.power_doppler);

    parts.pop();
    let missing = run
        .join(SegmentSource::Channels(&data), parts)
        .unwrap_err()
        .to_string();
    assert!(missing.contains("do not make"), "{missing}");
}

/// Images formed elsewhere and read a segment at a time are processed as the channel data's own
/// segments: the recording's images handed over whole, and cut by the run, give its segmented
/// run bit for bit (every frame's images stand alone here): maps, B-mode, velocity windows,
/// ensembles and clutter cut-offs, read time in place of decoding and beamforming.
#[test]
fn images_read_in_segments_give_the_recordings_segmented_run() {
    let (data, params, dynamics) = aliasing_tube();
    let segments = Segments::plan(FRAMES, 40, Some(&dynamics), Some(ENSEMBLES))
        .unwrap()
        .unwrap();
    let run = SegmentRun {
        params: &params,
        segments: &segments,
        dynamics: Some(&dynamics),
        ensembles: Some(ENSEMBLES),
        kept_pixels: &[(20, 31)],
    };
    let (images, _) = pipeline::form_images(&data, &params, &quiet).unwrap();
    let from_data = run
        .process(SegmentSource::Channels(&data), None, &quiet)
        .unwrap();
    let from_images = run
        .process(SegmentSource::Images(&images), None, &quiet)
        .unwrap();
    assert!(from_images.ranges.len() >= 3, "{:?}", from_images.ranges);
    assert_eq!(from_images.ranges, from_data.ranges);
    assert_eq!(from_images.out.bmode_db, from_data.out.bmode_db);
    assert_eq!(
        from_images.out.maps.power_doppler,
        from_data.out.maps.power_doppler
    );
    let (a, b) = (
        from_images.out.maps.vector_irls.as_ref().unwrap(),
        from_data.out.maps.vector_irls.as_ref().unwrap(),
    );
    assert!(same_bits(&a.vx, &b.vx) && same_bits(&a.vz, &b.vz));
    assert_eq!(from_images.out.maps.dealias, from_data.out.maps.dealias);
    assert_eq!(from_images.series, from_data.series);
    assert_eq!(from_images.ensembles, from_data.ensembles);
    assert_eq!(from_images.clutter, from_data.clutter);
    assert_eq!(
        from_images.kept.unwrap().series,
        from_data.kept.unwrap().series
    );
    let stages: Vec<Stage> = from_images.out.timings.iter().map(|t| t.0).collect();
    assert!(stages.contains(&Stage::Read), "{stages:?}");
    assert!(!stages.contains(&Stage::Decode), "{stages:?}");
    // Images on another grid than the settings' are refused, naming it.
    let other = ProcessParams {
        grid: pcuvd::core::grid::Grid::new(-1e-3, 1e-3, 5e-3, 7e-3, 1e-4).unwrap(),
        ..params.clone()
    };
    let refused = SegmentRun {
        params: &other,
        ..run
    }
    .process(SegmentSource::Images(&images), None, &quiet)
    .unwrap_err()
    .to_string();
    assert!(refused.contains("grid"), "{refused}");
}

/// Blocks grow until they hold as many pixels as the series has frames; segments of a run image
/// different numbers of frames (the last, without an overlap after it, fewer), yet all share the
/// layout their longest one needs, so that their block cut-offs line up.
#[test]
fn segments_of_different_lengths_share_one_block_layout() {
    let data = recording();
    let params = ProcessParams {
        clutter: ClutterParams {
            low: RankCut::Fixed(1),
            blocks: Some((4, 4)),
            ..ClutterParams::default()
        },
        ..params(&data)
    };
    let segments = Segments {
        core: 24,
        overlap: 8,
    };
    let run = SegmentRun {
        params: &params,
        segments: &segments,
        dynamics: None,
        ensembles: None,
        kept_pixels: &[],
    };
    let done = run
        .process(SegmentSource::Channels(&data), None, &quiet)
        .unwrap();
    let imaged: Vec<usize> = done.ranges.iter().map(|(_, i)| i.len()).collect();
    assert_eq!(imaged, vec![32, 32, 16]);
    let layouts: Vec<_> = (done.clutter.iter().flatten())
        .map(|report| report.block_layout.clone().expect("block-wise"))
        .collect();
    // 4 × 4 pixels grown to hold the longest segment's 32 frames: 6 × 6 (even sides).
    assert_eq!(layouts[0].size, (6, 6));
    assert!(layouts.iter().all(|l| *l == layouts[0]), "{layouts:?}");
}

/// The pixels a segmented run keeps are the whole path's filtered series at those pixels, over
/// every frame, each segment giving its own (no clutter filter here, and every frame's images
/// stand alone, so exactly); their spectrogram is the whole path's.
#[test]
fn kept_pixels_are_the_whole_series_at_those_pixels() {
    let data = recording();
    let params = params(&data);
    let whole = pipeline::process(&data, &params, &quiet).unwrap();
    let pixels = [(10, 30), (20, 31), (0, 0)];
    let segments = Segments {
        core: 24,
        overlap: 4,
    };
    let run = SegmentRun {
        params: &params,
        segments: &segments,
        dynamics: None,
        ensembles: None,
        kept_pixels: &pixels,
    };
    let done = run
        .process(SegmentSource::Channels(&data), None, &quiet)
        .unwrap();
    assert!(done.ranges.len() >= 3, "{:?}", done.ranges);
    let kept = done.kept.expect("kept pixels");
    assert_eq!(kept.pixels, pixels);
    for (angle, series) in whole.filtered.series.iter().enumerate() {
        for (k, &(iz, ix)) in pixels.iter().enumerate() {
            let want: Vec<_> = (0..FRAMES).map(|t| series[[iz, ix, t]]).collect();
            let got: Vec<_> = kept.series[angle].row(k).to_vec();
            assert_eq!(got, want, "angle {angle}, pixel {:?}", (iz, ix));
        }
    }
    let f = &whole.filtered;
    let spectrogram = pcuvd::dynamics::SpectrogramParams {
        window: 16,
        step: 8,
        nfft: 32,
    };
    let from_kept = pcuvd::dynamics::spectrogram_of_kept(&kept, 1, f, &spectrogram)
        .unwrap()
        .expect("a pixel with signal");
    let from_images = pcuvd::dynamics::spectrogram(f, pixels[1], &spectrogram).unwrap();
    assert_eq!(from_kept.power_db, from_images.power_db);
    assert_eq!(from_kept.mean_velocity_m_s, from_images.mean_velocity_m_s);
}

/// With the clutter filter on, each segment filters in its own subspace, so the kept series
/// steps where two cores meet. A spectrogram window that starts in a core reads that segment's
/// frames throughout, across the seam: every window is the one of its segment's imaged frames
/// processed alone, where the joined series would have mixed two filters.
#[test]
fn spectrogram_windows_read_one_clutter_filter_across_a_seam() {
    let data = recording();
    let params = ProcessParams {
        clutter: ClutterParams {
            low: RankCut::Fixed(1),
            ..ClutterParams::default()
        },
        ..params(&data)
    };
    let segments = Segments {
        core: 32,
        overlap: 16,
    };
    let pixel = (20, 31);
    let run = SegmentRun {
        params: &params,
        segments: &segments,
        dynamics: None,
        ensembles: None,
        kept_pixels: &[pixel],
    };
    let kept = run
        .process(SegmentSource::Channels(&data), None, &quiet)
        .unwrap()
        .kept
        .unwrap();
    assert_eq!(kept.seams.len(), 1);
    let window = pcuvd::dynamics::SpectrogramParams {
        window: 16,
        step: 8,
        nfft: 32,
    };
    // Each segment's imaged frames as a recording of their own.
    let alone = |frames: std::ops::Range<usize>| {
        let n = data.acquisition.sequence.n_angles();
        let Samples::Rf(rf) = &data.samples else {
            panic!("the simulation gives RF")
        };
        let part = ChannelData {
            acquisition: data.acquisition.clone(),
            samples: Samples::Rf(
                rf.slice(ndarray::s![frames.start * n..frames.end * n, .., ..])
                    .to_owned(),
            ),
        };
        let out = pipeline::process(&part, &params, &quiet).unwrap();
        pcuvd::dynamics::spectrogram(&out.filtered, pixel, &window).unwrap()
    };
    let (first, second) = (alone(0..48), alone(32..FRAMES));
    let whole = pipeline::process(&data, &params, &quiet).unwrap();
    let from_kept = pcuvd::dynamics::spectrogram_of_kept(&kept, 0, &whole.filtered, &window)
        .unwrap()
        .unwrap();
    // Windows start every 8 frames: 0–24 in the first core, 32–48 in the second.
    assert_eq!(from_kept.mean_velocity_m_s.len(), 7);
    assert_eq!(
        from_kept.mean_velocity_m_s[..4],
        first.mean_velocity_m_s[..4]
    );
    assert_eq!(
        from_kept.mean_velocity_m_s[4..],
        second.mean_velocity_m_s[..3]
    );
    // The window at frame 24 crosses the seam at 32: joined as one series, it reads otherwise.
    let joined = pcuvd::form::images::PixelSeries {
        seams: Vec::new(),
        ..kept.clone()
    };
    let mixed = pcuvd::dynamics::spectrogram_of_kept(&joined, 0, &whole.filtered, &window)
        .unwrap()
        .unwrap();
    assert_eq!(
        mixed.mean_velocity_m_s[..3],
        from_kept.mean_velocity_m_s[..3]
    );
    assert_ne!(mixed.mean_velocity_m_s[3], from_kept.mean_velocity_m_s[3]);
}
