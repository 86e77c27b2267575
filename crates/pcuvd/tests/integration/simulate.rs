//! Physics checks of the RF simulator and the phantoms, at reduced sizes.

use ndarray::{Array4, s};
use num_complex::Complex64;
use pcuvd::acquisition::channel::AngleSamples;
use pcuvd::form::decode::{Decoder, EventAlignment};
use pcuvd::simulate::phantom::{
    BlockPhantom, BlockSpec, DiskPhantom, DiskSpec, FlowProfile, Phantom, PointPhantom,
    SpiralPhantom, SpiralSpec, TubePhantom, TubeSpec,
};
use pcuvd::simulate::{
    EchoWaveform, NOISE_DEFINITION, NoiseSpec, SimParams, echo_time, paper_spiral_params, simulate,
};
use pcuvd::{ChannelData, Coding, Probe, Samples, Sequence};
use pcuvd_fft::FftPlanner64;

const FS: f64 = 65e6;
const C: f64 = 1540.0;

fn no_progress(_: usize, _: usize) {}

/// The L22-14vX cut down to `n` elements (same pitch, width, frequency, bandwidth).
fn probe(n: usize) -> Probe {
    Probe {
        n_elements: n,
        ..Probe::l22_14vx()
    }
}

fn sequence(angles_deg: &[f64], coding: Coding) -> Sequence {
    Sequence {
        angles: angles_deg.iter().map(|a| a.to_radians()).collect(),
        event_prf: 14.4e3,
        coding,
        pulse_cycles: 2.0,
        pulse: None,
    }
}

fn rf(data: &ChannelData) -> &ndarray::Array3<f32> {
    match &data.samples {
        Samples::Rf(a) => a,
        _ => panic!("the simulator returns RF"),
    }
}

fn per_angle(data: &ChannelData) -> Array4<f32> {
    let decoder = Decoder::new(data, EventAlignment::Simultaneous).expect("decoder");
    match decoder.decode(&data.samples).expect("decode") {
        AngleSamples::Rf(a) => a,
        _ => panic!("RF in, RF out"),
    }
}

/// Envelope (|analytic signal|) of a real trace.
fn envelope(trace: &[f32]) -> Vec<f64> {
    let n = trace.len();
    let mut planner = FftPlanner64::new();
    let mut buf: Vec<Complex64> = trace
        .iter()
        .map(|&v| Complex64::new(v as f64, 0.0))
        .collect();
    planner.plan_fft_forward(n).process(&mut buf);
    for (k, v) in buf.iter_mut().enumerate() {
        if k == 0 || (n.is_multiple_of(2) && k == n / 2) {
            continue;
        }
        *v *= if k < n.div_ceil(2) { 2.0 } else { 0.0 };
    }
    planner.plan_fft_inverse(n).process(&mut buf);
    buf.iter().map(|v| v.norm()).collect()
}

fn argmax(v: &[f64], range: std::ops::Range<usize>) -> usize {
    range
        .max_by(|&a, &b| v[a].total_cmp(&v[b]))
        .expect("non-empty range")
}

fn rel_l2(a: &[f32], b: &[f32]) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (x, y) in a.iter().zip(b) {
        num += (*x as f64 - *y as f64).powi(2);
        den += (*y as f64).powi(2);
    }
    (num / den).sqrt()
}

#[test]
fn noise_definition_is_one_sentence() {
    assert!(NOISE_DEFINITION.contains("0°"));
    assert!(NOISE_DEFINITION.contains("RMS"));
}

#[test]
fn echo_waveform_is_centred_and_band_limited() {
    let p = Probe::l22_14vx();
    let wf = EchoWaveform::new(&p, 2.0, FS).unwrap();
    assert!(wf.peak_offset().abs() < 1.0 / FS / 10.0);
    assert!((wf.value(0.0) - 1.0).abs() < 1e-9);
    assert!(
        wf.taps().is_multiple_of(8) && wf.taps() <= 32,
        "taps {}",
        wf.taps()
    );
    // Even about its origin, negligible beyond its half duration.
    for i in 1..40 {
        let t = i as f64 / (4.0 * FS);
        assert!((wf.value(t) - wf.value(-t)).abs() < 1e-9);
    }
    assert!(wf.value(wf.half_duration() + 2.0 / FS).abs() < 3e-4);
}

#[test]
fn point_echo_arrives_at_time_of_flight() {
    // Inside the insonified strip of every angle (the 64-element aperture spans ±3.2 mm).
    let (x, z) = (1.3e-3, 6e-3);
    let point = PointPhantom::single(x, z).unwrap();
    let n_el = 64;
    let elements = probe(n_el).element_x();
    // Uncoded, one angle at a time.
    for angle in [-15.0, 0.0, 15.0] {
        let params = SimParams::new(
            probe(n_el),
            sequence(&[angle], Coding::Conventional),
            FS,
            C,
            (2e-3, 10e-3),
        )
        .unwrap();
        let wf = EchoWaveform::new(&params.probe, 2.0, FS).unwrap();
        let data = simulate(&point, &params, 1, &no_progress).unwrap();
        let rf = rf(&data);
        for (e, &xe) in elements.iter().enumerate() {
            let env = envelope(rf.slice(s![0, e, ..]).as_slice().unwrap());
            let expected =
                (echo_time(&params, x, z, angle.to_radians(), 0.0, xe) + wf.peak_offset()) * FS;
            let got = argmax(&env, 0..env.len()) as f64;
            assert!(
                (got - expected).abs() <= 1.0,
                "angle {angle}°, element {e}: peak at {got}, expected {expected:.2}"
            );
        }
    }
    // Coded: all four slots in one event, each at its slot offset + time of flight.
    let angles = [-15.0, -5.0, 5.0, 15.0];
    let params = SimParams::new(
        probe(n_el),
        sequence(&angles, Coding::Hadamard { slot_delay: 1e-6 }),
        FS,
        C,
        (2e-3, 10e-3),
    )
    .unwrap();
    let data = simulate(&point, &params, 1, &no_progress).unwrap();
    let rf = rf(&data);
    for event in 0..4 {
        let pulses = params.sequence.event_pulses(event);
        for (e, &xe) in elements.iter().enumerate() {
            let trace = rf.slice(s![event, e, ..]);
            let env = envelope(trace.as_slice().unwrap());
            for &(k, polarity, offset) in &pulses {
                let expected = echo_time(&params, x, z, angles[k].to_radians(), offset, xe) * FS;
                let lo = (expected - 20.0).max(0.0) as usize;
                let hi = ((expected + 20.0) as usize).min(env.len());
                let got = argmax(&env, lo..hi);
                assert!(
                    (got as f64 - expected).abs() <= 1.0,
                    "event {event} slot {k} element {e}: peak at {got}, expected {expected:.2}"
                );
                // The echo carries the slot's polarity: the waveform is +1 at its centre.
                let centre = trace[expected.round() as usize];
                let neighbours = [trace[got.saturating_sub(1)], trace[got], trace[got + 1]];
                let peak = neighbours
                    .iter()
                    .copied()
                    .max_by(|a, b| a.abs().total_cmp(&b.abs()))
                    .unwrap();
                assert_eq!(
                    peak.signum(),
                    polarity,
                    "event {event} slot {k} element {e}"
                );
                assert!(centre.abs() > 0.0);
            }
        }
    }
}

/// (coded params, conventional params) sharing one receive window.
fn coded_and_conventional(n: usize, slot_delay: f64, n_el: usize) -> (SimParams, SimParams) {
    let angles = Sequence::evenly_spaced_angles(n, 15f64.to_radians());
    let deg: Vec<f64> = angles.iter().map(|a| a.to_degrees()).collect();
    let coded = SimParams::new(
        probe(n_el),
        sequence(&deg, Coding::Hadamard { slot_delay }),
        FS,
        C,
        (3e-3, 9e-3),
    )
    .unwrap();
    let mut conventional = coded.clone();
    conventional.sequence.coding = Coding::Conventional;
    (coded, conventional)
}

fn block(velocity: [f64; 2], density_per_mm2: f64, seed: u64) -> BlockPhantom {
    BlockPhantom::new(
        BlockSpec {
            x: (-1e-3, 1e-3),
            z: (5e-3, 7e-3),
            velocity,
            density: density_per_mm2 * 1e6,
        },
        seed,
    )
    .unwrap()
}

/// Relative L2 difference between decoded coded RF / n and conventional per-angle RF.
fn coded_vs_conventional(phantom: &dyn Phantom, n: usize, slot_delay: f64) -> f64 {
    let (coded, conventional) = coded_and_conventional(n, slot_delay, 24);
    let dc = per_angle(&simulate(phantom, &coded, 1, &no_progress).unwrap()) / n as f32;
    let du = per_angle(&simulate(phantom, &conventional, 1, &no_progress).unwrap());
    assert_eq!(dc.dim(), du.dim());
    rel_l2(dc.as_slice().unwrap(), du.as_slice().unwrap())
}

#[test]
fn decoded_still_medium_equals_n_times_conventional() {
    let still = block([0.0, 0.0], 100.0, 3);
    for n in [4, 8] {
        for slot_delay in [1e-6, 0.77e-6] {
            let err = coded_vs_conventional(&still, n, slot_delay);
            eprintln!("still medium, n = {n}, Δτ = {slot_delay:e} s: relative L2 {err:e}");
            assert!(
                err < 1e-4,
                "n = {n}, Δτ = {} µs: relative L2 {err:e}",
                slot_delay * 1e6
            );
        }
    }
}

#[test]
fn motion_breaks_hadamard_decoding() {
    let moving = block([0.0, 25e-3], 100.0, 3);
    let err = coded_vs_conventional(&moving, 8, 1e-6);
    eprintln!("25 mm/s block, n = 8: decoded vs conventional relative L2 {err:.3}");
    assert!(err > 0.01, "decoded vs conventional differ by only {err}");
}

/// A phantom whose scatterers stand still within each compound frame, where the moving phantom
/// is at the frame's mid-event time: what every event of a frame would see if they all fired at once.
struct HeldAtMidFrame<'a> {
    inner: &'a dyn Phantom,
    frame_period: f64,
    event_period: f64,
    events: usize,
}

impl Phantom for HeldAtMidFrame<'_> {
    fn amplitudes(&self) -> &[f64] {
        self.inner.amplitudes()
    }

    fn positions_at(&self, t: f64, out: &mut Vec<[f64; 2]>) {
        let frame = (t / self.frame_period + 1e-9).floor();
        let mid = frame * self.frame_period + (self.events as f64 - 1.0) / 2.0 * self.event_period;
        self.inner.positions_at(mid, out);
    }

    fn truth(&self, x: &[f64], z: &[f64], t: f64) -> pcuvd::simulate::phantom::Truth {
        self.inner.truth(x, z, t)
    }
}

/// Blood moving between the events of a frame (25 mm/s axially, ~0.2 rad of echo phase per
/// event): decoding the events as simultaneous leaks angles into each other; aligning each event
/// to the frame's mid-event time first gives what a medium held still at that time would give.
#[test]
fn mid_frame_alignment_decodes_moving_blood_as_if_still() {
    let (n, frames) = (8usize, 32usize);
    let (coded, _) = coded_and_conventional(n, 1e-6, 16);
    let moving = block([5e-3, 25e-3], 100.0, 3);
    let event_period = 1.0 / coded.sequence.event_prf;
    let held = HeldAtMidFrame {
        inner: &moving,
        frame_period: n as f64 * event_period,
        event_period,
        events: n,
    };
    let recorded = simulate(&moving, &coded, frames, &no_progress).unwrap();
    let reference = per_angle(&simulate(&held, &coded, frames, &no_progress).unwrap());
    let decode_with = |alignment| match (Decoder::new(&recorded, alignment))
        .and_then(|decoder| decoder.decode(&recorded.samples))
        .unwrap()
    {
        AngleSamples::Rf(a) => a,
        _ => unreachable!(),
    };
    // Away from the first and last frames, which the alignment can only extrapolate.
    let inner = |a: &Array4<f32>| a.slice(s![.., 4..frames - 4, .., ..]).to_owned();
    let reference = inner(&reference);
    let err = |a: Array4<f32>| {
        let a = inner(&a);
        rel_l2(a.as_slice().unwrap(), reference.as_slice().unwrap())
    };
    let leak = err(decode_with(EventAlignment::Simultaneous));
    let aligned = err(decode_with(EventAlignment::MidFrame));
    eprintln!(
        "moving block: decoded vs held at mid-frame, relative L2 {leak:.3} simultaneous, {aligned:.4} aligned"
    );
    assert!(leak > 0.1, "simultaneous decoding differs by only {leak}");
    assert!(
        aligned < 0.02,
        "aligned decoding differs by {aligned} (simultaneous {leak})"
    );
}

#[test]
fn coding_gain_is_ten_log_n() {
    let n = 8;
    let (mut coded, mut conventional) = coded_and_conventional(n, 1e-6, 32);
    let still = block([0.0, 0.0], 100.0, 5);
    let run = |params: &SimParams| per_angle(&simulate(&still, params, 1, &no_progress).unwrap());
    let clean_c = run(&coded);
    let clean_u = run(&conventional);
    coded.noise = Some(NoiseSpec::new(-10.0));
    conventional.noise = Some(NoiseSpec::new(-10.0));
    coded.seed = 11;
    conventional.seed = 12;
    let noisy_c = run(&coded);
    let noisy_u = run(&conventional);
    // Only samples every decoded slot still has (slot k loses its last k·Δτ·f_s samples).
    let valid = coded.n_samples - ((n - 1) as f64 * 1e-6 * FS).ceil() as usize;
    let snr = |clean: &Array4<f32>, noisy: &Array4<f32>| {
        let c = clean.slice(s![.., .., .., ..valid]);
        let d = noisy.slice(s![.., .., .., ..valid]);
        let ps: f64 = c.iter().map(|&v| (v as f64).powi(2)).sum();
        let pn: f64 = c
            .iter()
            .zip(d.iter())
            .map(|(&a, &b)| (b as f64 - a as f64).powi(2))
            .sum();
        10.0 * (ps / pn).log10()
    };
    let gain = snr(&clean_c, &noisy_c) - snr(&clean_u, &noisy_u);
    eprintln!("measured Hadamard coding gain (n = 8): {gain:.3} dB");
    assert!(
        (gain - 10.0 * 8f64.log10()).abs() < 0.3,
        "coding gain {gain:.3} dB, expected 9.03 dB"
    );
    // The noise level itself: −10 dB relative to the 0° echo over the whole window.
    let mut zero = conventional.clone();
    zero.sequence.angles = vec![0.0];
    zero.noise = None;
    let clean0 = simulate(&still, &zero, 1, &no_progress).unwrap();
    zero.noise = Some(NoiseSpec::new(-10.0));
    let noisy0 = simulate(&still, &zero, 1, &no_progress).unwrap();
    let rms =
        |a: &[f32]| (a.iter().map(|&v| (v as f64).powi(2)).sum::<f64>() / a.len() as f64).sqrt();
    let (c0, n0) = (
        rf(&clean0).as_slice().unwrap(),
        rf(&noisy0).as_slice().unwrap(),
    );
    let diff: Vec<f32> = n0.iter().zip(c0).map(|(a, b)| a - b).collect();
    let level = 20.0 * (rms(&diff) / rms(c0)).log10();
    assert!((level + 10.0).abs() < 0.2, "noise level {level:.2} dB");
}

#[test]
fn same_seed_same_bytes_whatever_the_threads() {
    let moving = block([5e-3, 10e-3], 60.0, 9);
    let (mut coded, _) = coded_and_conventional(4, 0.77e-6, 16);
    coded.noise = Some(NoiseSpec::new(-6.0));
    coded.seed = 42;
    let run = |threads: usize, params: &SimParams| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| simulate(&moving, params, 2, &no_progress).unwrap())
    };
    let one = run(1, &coded);
    let two = run(2, &coded);
    let bits = |d: &ChannelData| rf(d).iter().map(|v| v.to_bits()).collect::<Vec<u32>>();
    assert_eq!(bits(&one), bits(&two));
    coded.seed = 43;
    let other = run(2, &coded);
    let err = rel_l2(rf(&other).as_slice().unwrap(), rf(&one).as_slice().unwrap());
    assert!(err > 0.1, "a different seed changed the data by only {err}");
}

#[test]
fn progress_counts_every_event() {
    let still = block([0.0, 0.0], 20.0, 1);
    let (coded, _) = coded_and_conventional(4, 1e-6, 8);
    let count = std::sync::atomic::AtomicUsize::new(0);
    let data = simulate(&still, &coded, 3, &|done, total| {
        assert_eq!(total, 12);
        count.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        assert!(done <= total);
    })
    .unwrap();
    assert_eq!(count.into_inner(), 12);
    assert_eq!(data.samples.dim(), (12, 8, coded.n_samples));
    data.validate().unwrap();
    assert_eq!(data.acquisition, coded.acquisition());
}

#[test]
fn bad_parameters_are_errors() {
    let still = block([0.0, 0.0], 20.0, 1);
    let (coded, _) = coded_and_conventional(8, 1e-6, 8);
    assert!(simulate(&still, &coded, 0, &no_progress).is_err());
    let mut p = coded.clone();
    p.noise = Some(NoiseSpec::new(f64::NAN));
    assert!(simulate(&still, &p, 1, &no_progress).is_err());
    let mut p = coded.clone();
    p.noise = Some(NoiseSpec {
        level_db: -10.0,
        band_hz: (1e6, 40e6),
    });
    assert!(simulate(&still, &p, 1, &no_progress).is_err());
    // A band between two FFT bins of the noise would give noiseless data: refused, by both
    // simulate and simulate_noise (which used to panic on it).
    let mut p = coded.clone();
    let bin_hz = p.sampling_frequency / p.n_samples.next_power_of_two().max(64) as f64;
    p.noise = Some(NoiseSpec {
        level_db: -10.0,
        band_hz: (100.25 * bin_hz, 100.75 * bin_hz),
    });
    for err in [
        simulate(&still, &p, 1, &no_progress).unwrap_err(),
        pcuvd::simulate::simulate_noise(&still, &p, 1).unwrap_err(),
    ] {
        let err = err.to_string();
        assert!(
            err.contains("noise band") && err.contains("kHz apart"),
            "{err}"
        );
    }
    let mut p = coded.clone();
    p.sequence.coding = Coding::Hadamard { slot_delay: 9.9e-6 };
    let err = simulate(&still, &p, 1, &no_progress)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("slot delay makes pulses overlap the next event's receive window"),
        "{err}"
    );
    let mut p = coded.clone();
    p.n_samples = 10_000; // 154 µs, longer than the 69 µs event period
    assert!(simulate(&still, &p, 1, &no_progress).is_err());
    let mut p = coded.clone();
    p.sampling_frequency = 20e6;
    assert!(simulate(&still, &p, 1, &no_progress).is_err());
    let mut p = coded.clone();
    p.attenuation_db_cm_mhz = -1.0;
    assert!(simulate(&still, &p, 1, &no_progress).is_err());
    // Attenuation beyond any tissue's: refused, where the spectral bands it would take (one per
    // eighth of the band its spectrum falls) overflowed the band index or outgrew memory.
    for absurd in [1e3, 1e10, 1e300] {
        let mut p = coded.clone();
        p.attenuation_db_cm_mhz = absurd;
        let err = simulate(&still, &p, 1, &no_progress)
            .unwrap_err()
            .to_string();
        assert!(err.contains("spectral bands"), "{absurd}: {err}");
    }
    let mut p = coded;
    p.attenuation_db_cm_mhz = 20.0;
    simulate(&still, &p, 1, &no_progress).unwrap();
    assert!(
        SimParams::new(
            probe(8),
            sequence(&[0.0], Coding::Conventional),
            FS,
            C,
            (5e-3, 1e-3)
        )
        .is_err()
    );
}

#[test]
fn paper_presets() {
    let coded = paper_spiral_params(true).unwrap();
    let conventional = paper_spiral_params(false).unwrap();
    coded.validate().unwrap();
    conventional.validate().unwrap();
    assert_eq!(coded.n_samples, conventional.n_samples);
    assert_eq!(coded.t0, 0.0);
    assert_eq!(coded.sequence.n_angles(), 8);
    assert_eq!(coded.noise, Some(NoiseSpec::new(-10.0)));
    assert!(matches!(conventional.sequence.coding, Coding::Conventional));
    // The window holds a 14 mm deep echo of the last slot on the farthest element.
    let (x0, _) = coded.probe.aperture();
    let last = echo_time(&coded, -x0, 14e-3, coded.sequence.angles[7], 7e-6, x0);
    assert!(last * FS < coded.n_samples as f64);
}

// ----------------------------------------------------------------------------------------------
// Phantoms
// ----------------------------------------------------------------------------------------------

#[test]
fn spiral_matches_the_paper() {
    let spiral = SpiralPhantom::paper(7).unwrap();
    let spec = spiral.spec().clone();
    // ≈ 45 mm² of vessel at 300 scatterers/mm².
    let area_mm2 = spec.area() * 1e6;
    assert!((area_mm2 - 45.08).abs() < 0.05, "area {area_mm2}");
    let density = spiral.n_scatterers() as f64 / area_mm2;
    assert!((density - 300.0).abs() < 0.5, "density {density}/mm²");
    // Truth on the centreline: 25 mm/s along the tangent.
    for alpha in [0.3, 2.0, 7.5, 12.0] {
        let [x, z] = spec.position(alpha, 0.0);
        let truth = spiral.truth(&[x], &[z], 0.0);
        assert!(truth.mask[[0, 0]]);
        let v = [truth.vx[[0, 0]], truth.vz[[0, 0]]];
        assert!((v[0].hypot(v[1]) - 25e-3).abs() < 1e-12);
        // Moving along increasing α: the position a little further along.
        let [x2, z2] = spec.position(alpha + 1e-6, 0.0);
        let dot = v[0] * (x2 - x) + v[1] * (z2 - z);
        assert!(dot > 0.0);
        // Half a radius off the centreline: 3/4 of the peak.
        let [x3, z3] = spec.position(alpha, 0.3e-3);
        let t3 = spiral.truth(&[x3], &[z3], 0.0);
        assert!((t3.speed()[[0, 0]] - 0.75 * 25e-3).abs() < 1e-9);
    }
    // Outside the vessel: between turns and at the centre.
    let [x, z] = spec.position(5.0, 0.8e-3);
    assert!(!spiral.truth(&[x], &[z], 0.0).mask[[0, 0]]);
    assert!(!spiral.truth(&[spec.centre[0]], &[spec.centre[1]], 0.0).mask[[0, 0]]);
    // Scatterers stay inside the vessel, however long they flow.
    let mut pos = Vec::new();
    for t in [0.0, 1e-3, 0.37, 12.3] {
        spiral.positions_at(t, &mut pos);
        assert_eq!(pos.len(), spiral.n_scatterers());
        for p in &pos {
            let (_, l) = spec
                .vessel_coordinates(p[0], p[1])
                .unwrap_or_else(|| panic!("scatterer at {p:?} outside the vessel at t = {t}"));
            assert!(l.abs() <= spec.radius * (1.0 + 1e-9));
        }
    }
    // Speed: displacement over 1 ms matches u within 0.5 % (chord ≈ arc over 25 µm).
    let mut p0 = Vec::new();
    let mut p1 = Vec::new();
    spiral.positions_at(0.2, &mut p0);
    spiral.positions_at(0.201, &mut p1);
    let mut checked = 0;
    for i in 0..spiral.n_scatterers() {
        let u = spiral.speeds()[i];
        if u < 2e-3 || spiral.alpha_at(i, 0.201) < spiral.alpha_at(i, 0.2) {
            continue; // too slow to measure well, or restarted at α = 0
        }
        let d = (p1[i][0] - p0[i][0]).hypot(p1[i][1] - p0[i][1]) / 1e-3;
        assert!((d / u - 1.0).abs() < 5e-3, "scatterer {i}: {d} vs {u}");
        checked += 1;
    }
    assert!(checked > spiral.n_scatterers() / 2);
    // Integration is exact: arc length from α0 to α(t) is u·t.
    let l = spiral.offsets()[0];
    let (a0, a1) = (spiral.alpha_at(0, 0.0), spiral.alpha_at(0, 0.01));
    if a1 > a0 {
        let s = spec.arc_length(a1, l) - spec.arc_length(a0, l);
        assert!((s - spiral.speeds()[0] * 0.01).abs() < 1e-12);
    }
    // Same seed, same phantom; another seed, another one.
    let again = SpiralPhantom::paper(7).unwrap();
    assert_eq!(again.amplitudes(), spiral.amplitudes());
    assert_ne!(
        SpiralPhantom::paper(8).unwrap().amplitudes(),
        spiral.amplitudes()
    );
    assert!(
        SpiralPhantom::new(
            SpiralSpec {
                radius: 2e-3,
                ..SpiralSpec::paper()
            },
            1
        )
        .is_err()
    );
}

#[test]
fn tube_truth_and_wrap_around() {
    let angle = 30f64.to_radians();
    let spec = TubeSpec {
        centre: [0.5e-3, 6e-3],
        angle,
        length: 6e-3,
        radius: 0.5e-3,
        peak_speed: 20e-3,
        density: 200e6,
        profile: FlowProfile::Parabolic,
    };
    let tube = TubePhantom::new(spec.clone(), 4).unwrap();
    assert_eq!(tube.n_scatterers(), (200.0 * 6.0 * 1.0f64).round() as usize);
    let (d, nrm) = ([angle.cos(), angle.sin()], [-angle.sin(), angle.cos()]);
    let at = |s: f64, l: f64| {
        [
            spec.centre[0] + s * d[0] + l * nrm[0],
            spec.centre[1] + s * d[1] + l * nrm[1],
        ]
    };
    let [x0, z0] = at(1e-3, 0.0);
    let [x1, z1] = at(-2e-3, 0.25e-3);
    let [x2, z2] = at(0.0, 0.7e-3);
    let [x3, z3] = at(3.5e-3, 0.0);
    for ([x, z], expected) in [
        ([x0, z0], Some(20e-3)),
        ([x1, z1], Some(15e-3)),
        ([x2, z2], None),
        ([x3, z3], None),
    ] {
        let t = tube.truth(&[x], &[z], 0.0);
        match expected {
            Some(u) => {
                assert!(t.mask[[0, 0]]);
                assert!((t.vx[[0, 0]] - u * d[0]).abs() < 1e-12);
                assert!((t.vz[[0, 0]] - u * d[1]).abs() < 1e-12);
            }
            None => assert!(!t.mask[[0, 0]]),
        }
    }
    let mut pos = Vec::new();
    for t in [0.0, 0.1, 10.0] {
        tube.positions_at(t, &mut pos);
        assert_eq!(pos.len(), tube.n_scatterers());
        for p in &pos {
            let (dx, dz) = (p[0] - spec.centre[0], p[1] - spec.centre[1]);
            let s = dx * d[0] + dz * d[1];
            let l = dx * nrm[0] + dz * nrm[1];
            assert!(s.abs() <= 0.5 * spec.length + 1e-12 && l.abs() <= spec.radius + 1e-12);
        }
    }
}

#[test]
fn plug_tube_moves_its_whole_lumen_at_the_peak() {
    let angle = -40f64.to_radians();
    let spec = TubeSpec {
        centre: [0.0, 5e-3],
        angle,
        length: 8e-3,
        radius: 0.4e-3,
        peak_speed: 0.12,
        density: 200e6,
        profile: FlowProfile::Plug,
    };
    let tube = TubePhantom::new(spec.clone(), 2).unwrap();
    let (d, nrm) = ([angle.cos(), angle.sin()], [-angle.sin(), angle.cos()]);
    // Truth: the peak up to the wall, nothing beyond it.
    for (l, inside) in [
        (0.0, true),
        (0.39e-3, true),
        (-0.39e-3, true),
        (0.41e-3, false),
    ] {
        let (x, z) = (spec.centre[0] + l * nrm[0], spec.centre[1] + l * nrm[1]);
        let t = tube.truth(&[x], &[z], 0.0);
        assert_eq!(t.mask[[0, 0]], inside, "l = {l}");
        if inside {
            assert!((t.vx[[0, 0]] - 0.12 * d[0]).abs() < 1e-12);
            assert!((t.vz[[0, 0]] - 0.12 * d[1]).abs() < 1e-12);
        }
    }
    // Every scatterer, at the wall too, moves 0.12 m/s × 1 ms = 0.12 mm along the axis.
    let (mut p0, mut p1) = (Vec::new(), Vec::new());
    tube.positions_at(0.0, &mut p0);
    tube.positions_at(1e-3, &mut p1);
    let mut moved = 0;
    for (a, b) in p0.iter().zip(&p1) {
        let along = (b[0] - a[0]) * d[0] + (b[1] - a[1]) * d[1];
        let across = (b[0] - a[0]) * nrm[0] + (b[1] - a[1]) * nrm[1];
        assert!(across.abs() < 1e-12);
        // Those that wrapped round the tube's ends jump back by its length.
        let along = if along < 0.0 {
            along + spec.length
        } else {
            along
        };
        assert!((along - 0.12e-3).abs() < 1e-12, "moved {along}");
        moved += 1;
    }
    assert_eq!(moved, tube.n_scatterers());
}

#[test]
fn block_and_disk_truth() {
    let b = block([3e-3, -4e-3], 50.0, 2);
    let t = 0.5;
    let grid_x = [0.0, 1.2e-3, 2.4e-3];
    let grid_z = [3.5e-3, 5.5e-3];
    let truth = b.truth(&grid_x, &grid_z, t);
    // At t = 0.5 s the block spans x ∈ [0.5, 2.5] mm, z ∈ [3, 5] mm.
    assert_eq!(truth.mask.dim(), (2, 3));
    assert!(!truth.mask[[0, 0]] && truth.mask[[0, 1]] && truth.mask[[0, 2]]);
    assert!(!truth.mask[[1, 1]]);
    assert_eq!((truth.vx[[0, 1]], truth.vz[[0, 1]]), (3e-3, -4e-3));
    let mut p0 = Vec::new();
    let mut p1 = Vec::new();
    b.positions_at(0.0, &mut p0);
    b.positions_at(t, &mut p1);
    for (a, c) in p0.iter().zip(&p1) {
        assert!((c[0] - a[0] - 1.5e-3).abs() < 1e-15 && (c[1] - a[1] + 2e-3).abs() < 1e-15);
    }

    let disk = DiskPhantom::new(
        DiskSpec {
            centre: [0.0, 8e-3],
            radius: 2e-3,
            angular_velocity: 3.0,
            density: 100e6,
        },
        1,
    )
    .unwrap();
    let truth = disk.truth(&[1e-3, 0.0, 3e-3], &[8e-3, 9e-3], 0.0);
    assert!((truth.vz[[0, 0]] - 3e-3).abs() < 1e-15 && truth.vx[[0, 0]].abs() < 1e-15);
    assert!((truth.vx[[1, 1]] + 3e-3).abs() < 1e-15);
    assert!(!truth.mask[[0, 2]]);
    disk.positions_at(0.1, &mut p0);
    for p in &p0 {
        assert!(p[0].hypot(p[1] - 8e-3) <= 2e-3 + 1e-12);
    }
    assert!(PointPhantom::new(vec![[0.0, 1e-3]], vec![], [0.0, 0.0]).is_err());
    assert!(
        BlockPhantom::new(
            BlockSpec {
                x: (1.0, 0.0),
                z: (0.0, 1.0),
                velocity: [0.0, 0.0],
                density: 1.0
            },
            0
        )
        .is_err()
    );
}

#[test]
fn moving_block_echo_phase_follows_motion() {
    // A scatterer moving away from the probe delays its echo by 2·vz·Δt/c per event (0° plane wave).
    let vz = 25e-3;
    let point = PointPhantom::new(vec![[0.0, 6e-3]], vec![1.0], [0.0, vz]).unwrap();
    let params = SimParams::new(
        probe(8),
        sequence(&[0.0], Coding::Conventional),
        FS,
        C,
        (3e-3, 9e-3),
    )
    .unwrap();
    let data = simulate(&point, &params, 40, &no_progress).unwrap();
    let rf = rf(&data);
    let centroid = |event: usize| {
        let env = envelope(rf.slice(s![event, 3, ..]).as_slice().unwrap());
        let (num, den) = env.iter().enumerate().fold((0.0, 0.0), |(n, d), (i, &e)| {
            (n + i as f64 * e * e, d + e * e)
        });
        num / den
    };
    let shift = (centroid(39) - centroid(0)) / FS;
    let elapsed = 39.0 / params.sequence.event_prf;
    let xe = probe(8).element_x()[3];
    let expected = echo_time(&params, 0.0, 6e-3 + vz * elapsed, 0.0, 0.0, xe)
        - echo_time(&params, 0.0, 6e-3, 0.0, 0.0, xe);
    assert!(
        (shift - expected).abs() < 0.02 * expected,
        "echo moved {shift:e} s, expected {expected:e} s"
    );
}

/// The noise alone equals what `simulate` adds: noisy − noiseless, to f32 rounding.
#[test]
fn noise_alone_is_what_simulate_adds() {
    let (mut coded, _) = coded_and_conventional(4, 1e-6, 16);
    let phantom = block([0.01, -0.005], 50.0, 3);
    let clean = simulate(&phantom, &coded, 2, &no_progress).unwrap();
    coded.noise = Some(pcuvd::simulate::NoiseSpec::new(-6.0));
    coded.seed = 11;
    let noisy = simulate(&phantom, &coded, 2, &no_progress).unwrap();
    let noise = pcuvd::simulate::simulate_noise(&phantom, &coded, 2).unwrap();
    let difference = rf(&noisy) - rf(&clean);
    let err = rel_l2(
        difference.as_slice().unwrap(),
        rf(&noise).as_slice().unwrap(),
    );
    assert!(err < 1e-5, "relative difference {err}");
    coded.noise = None;
    assert!(pcuvd::simulate::simulate_noise(&phantom, &coded, 2).is_err());
}

/// A recording simulated a block of events at a time (as `pcuvd simulate` writes it) is the
/// whole-recording simulation bit for bit, noise included; a range beyond the recording is refused.
#[test]
fn events_in_blocks_are_the_whole_simulation() {
    let (mut coded, _) = coded_and_conventional(4, 1e-6, 16);
    coded.noise = Some(pcuvd::simulate::NoiseSpec::new(-6.0));
    coded.seed = 5;
    let phantom = block([0.01, -0.005], 50.0, 3);
    let whole = simulate(&phantom, &coded, 3, &no_progress).unwrap();
    let mut pieces = Vec::new();
    for events in [0..4, 4..5, 5..12] {
        pieces.push(
            pcuvd::simulate::simulate_events(&phantom, &coded, 3, events, &no_progress).unwrap(),
        );
    }
    let views: Vec<_> = pieces.iter().map(|p| p.view()).collect();
    let joined = ndarray::concatenate(ndarray::Axis(0), &views).unwrap();
    assert_eq!(&joined, rf(&whole));
    assert!(pcuvd::simulate::simulate_events(&phantom, &coded, 3, 8..13, &no_progress).is_err());
}

/// Power-weighted mean frequency (Hz) of `samples` taken at `fs` (Hz), by direct DFT over
/// 0–2 f_c in 0.05 MHz steps.
fn mean_frequency(samples: &[f64], fs: f64, fc: f64) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for i in 1..=(2.0 * fc / 5e4) as usize {
        let f = i as f64 * 5e4;
        let s: Complex64 = samples
            .iter()
            .enumerate()
            .map(|(n, &v)| Complex64::from_polar(v, -std::f64::consts::TAU * f * n as f64 / fs))
            .sum();
        num += f * s.norm_sqr();
        den += s.norm_sqr();
    }
    num / den
}

/// Frequency-dependent attenuation lowers the echo's spectrum with its path as exp(−α (f − f_c) L)
/// predicts: a point straight below the centre element, its echo on that element, against the
/// unattenuated echo waveform's spectrum times that factor (computed here from
/// `EchoWaveform::value`). Measured (0.5 dB/cm/MHz): the mean falls from 0.9986 f_c to 0.968,
/// 0.938 and 0.878 f_c at 3, 6 and 12 mm (about 1 % per mm of depth), within 0.02 % of the
/// prediction (the tables are blended between paths a few mm apart); with attenuation at f_c
/// only, the spectrum does not move.
#[test]
fn attenuation_lowers_the_echo_spectrum_with_depth() {
    let p = probe(2);
    let fc = p.center_frequency;
    let wf = EchoWaveform::new(&p, 2.0, FS).unwrap();
    let alpha = SimParams::DEFAULT_ATTENUATION * 100.0 / (20.0 * std::f64::consts::LOG10_E) / 1e6;
    let half = (wf.half_duration() * FS).ceil() as i64;
    for depth in [3e-3, 6e-3, 12e-3] {
        let point = PointPhantom::single(p.element_x()[1], depth).unwrap();
        let mut mean = [0.0; 2];
        for (i, spectral) in [false, true].into_iter().enumerate() {
            let mut params = SimParams::new(
                p.clone(),
                sequence(&[0.0], Coding::Conventional),
                FS,
                C,
                (depth - 1e-3, depth + 1e-3),
            )
            .unwrap();
            params.frequency_dependent_attenuation = spectral;
            let data = simulate(&point, &params, 1, &no_progress).unwrap();
            let trace = rf(&data).slice(s![0, 1, ..]).to_vec();
            let centre = ((2.0 * depth / C - params.t0) * FS).round() as i64;
            let window: Vec<f64> = (centre - half..=centre + half)
                .map(|n| trace[n as usize] as f64)
                .collect();
            mean[i] = mean_frequency(&window, FS, fc);
        }
        // The prediction: the unattenuated echo's spectrum × exp(−α (f − f_c)·2·depth).
        let (mut num, mut den) = (0.0, 0.0);
        for i in 1..=(2.0 * fc / 5e4) as usize {
            let f = i as f64 * 5e4;
            let s: Complex64 = (-half..=half)
                .map(|n| {
                    let t = n as f64 / FS;
                    Complex64::from_polar(wf.value(t), -std::f64::consts::TAU * f * t)
                })
                .sum();
            let w = s.norm_sqr() * (-2.0 * alpha * (f - fc) * 2.0 * depth).exp();
            num += f * w;
            den += w;
        }
        let predicted = num / den;
        let unattenuated = mean_frequency(
            &(-half..=half)
                .map(|n| wf.value(n as f64 / FS))
                .collect::<Vec<_>>(),
            FS,
            fc,
        );
        eprintln!(
            "depth {:4.1} mm: mean frequency {:.4} f_c (predicted {:.4}; attenuation at f_c only {:.4}; no attenuation {:.4})",
            depth * 1e3,
            mean[1] / fc,
            predicted / fc,
            mean[0] / fc,
            unattenuated / fc
        );
        assert!(
            (mean[1] / predicted - 1.0).abs() < 1e-3,
            "{:.4} vs {:.4}",
            mean[1] / fc,
            predicted / fc
        );
        assert!((mean[0] / unattenuated - 1.0).abs() < 1e-3);
    }
}

/// Scatterers whose echoes fall outside the record on every channel (deeper than the receive
/// window, or far beside the array) change nothing: the recording with them equals the one
/// without, both modes, to rounding (the render's blocks of scatterers then start elsewhere, and
/// an accumulator row may sum the same echoes in another order).
#[test]
fn scatterers_beyond_the_record_change_nothing() {
    let (coded, conventional) = coded_and_conventional(4, 1e-6, 16);
    let mut positions = Vec::new();
    block([0.0, 0.0], 100.0, 7).positions_at(0.0, &mut positions);
    let inside =
        PointPhantom::new(positions.clone(), vec![1.0; positions.len()], [0.0; 2]).unwrap();
    // Beyond the 9 mm window's depths, and beside the array at the window's own depths.
    for k in 0..2000 {
        let f = k as f64 / 2000.0;
        positions.push(if k % 2 == 0 {
            [-4e-3 + 8e-3 * f, 20e-3 + 40e-3 * f]
        } else {
            [0.1 + 0.2 * f, 4e-3 + 4e-3 * f]
        });
    }
    let with_far =
        PointPhantom::new(positions.clone(), vec![1.0; positions.len()], [0.0; 2]).unwrap();
    for params in [&coded, &conventional] {
        let alone = simulate(&inside, params, 2, &no_progress).unwrap();
        let beside = simulate(&with_far, params, 2, &no_progress).unwrap();
        let peak = rf(&alone).iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let difference = (rf(&alone) - rf(&beside))
            .iter()
            .fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(
            peak > 0.0 && difference <= 1e-6 * peak,
            "{difference} of {peak}"
        );
    }
}

/// A point's echo leaves the end of the record a sample at a time as the point moves deeper: the
/// scatterers dropped before rendering (echoes beyond the record on every channel) are only those
/// whose echo no sample holds.
#[test]
fn an_echo_at_the_end_of_the_record_is_rendered_until_it_leaves() {
    let (_, conventional) = coded_and_conventional(1, 1e-6, 16);
    let ns = conventional.n_samples;
    // Half a sample of depth (c / (4 fs)) a step, over the last rows of the record and beyond.
    let step = C / (4.0 * FS);
    let mut held = Vec::new();
    for k in 0..160 {
        let z = 8.6e-3 + k as f64 * step;
        let point = PointPhantom::new(vec![[0.0, z]], vec![1.0], [0.0; 2]).unwrap();
        let data = simulate(&point, &conventional, 1, &no_progress).unwrap();
        let trace = rf(&data).slice(ndarray::s![0, 8, ..]).to_owned();
        held.push(trace.iter().rev().take(64).filter(|v| **v != 0.0).count());
    }
    // The echo (some 24 samples long) lies whole in the last 64 at first, and beyond them last.
    assert!(
        held[0] >= 16 && held[159] == 0,
        "{held:?} (of the last 64 of {ns} samples)"
    );
    for pair in held.windows(2) {
        assert!(
            pair[1] + 2 >= pair[0],
            "the echo left the record at once: {held:?}"
        );
    }
}
