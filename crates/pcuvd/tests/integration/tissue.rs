//! The three-dimensional simulator and moving tissue, against theory: the elevation beam at the
//! focus, a rigid displacement against the echo's shift, tissue's brightness against blood's.

use ndarray::{Array2, s};
use pcuvd::simulate::keyframes::{TissueKeyframes, keyframe_interval, simulate_events_with_tissue};
use pcuvd::simulate::phantom::tissue::{Oscillation, TissueMotion, TissuePhantom, TissueSpec};
use pcuvd::simulate::phantom::{Phantom, Truth};
use pcuvd::simulate::{ElevationAperture, SimParams, simulate};
use pcuvd::{Coding, Probe, Samples, Sequence};

const C: f64 = 1540.0;

fn no_progress(_: usize, _: usize) {}

/// A 32-element L22-14vX, one 0° plane wave every 1/`prf` s, depths 1–10 mm.
fn params(prf: f64) -> SimParams {
    let probe = Probe {
        n_elements: 32,
        ..Probe::l22_14vx()
    };
    let sequence = Sequence {
        angles: vec![0.0],
        event_prf: prf,
        coding: Coding::Conventional,
        pulse_cycles: 2.0,
        pulse: None,
    };
    let mut p = SimParams::new(probe, sequence, 65e6, C, (1e-3, 10e-3)).unwrap();
    p.attenuation_db_cm_mhz = 0.0;
    p
}

fn traces(phantom: &dyn Phantom, params: &SimParams, frames: usize) -> ndarray::Array3<f32> {
    match simulate(phantom, params, frames, &no_progress)
        .unwrap()
        .samples
    {
        Samples::Rf(rf) => rf,
        _ => unreachable!("the simulator writes RF"),
    }
}

/// Points at (x, y, z) (m), still, amplitude 1.
struct Points(Vec<[f64; 3]>, Vec<f64>);

impl Phantom for Points {
    fn amplitudes(&self) -> &[f64] {
        &self.1
    }
    fn positions_at(&self, _t: f64, out: &mut Vec<[f64; 2]>) {
        out.clear();
        out.extend(self.0.iter().map(|p| [p[0], p[2]]));
    }
    fn elevations_at(&self, _t: f64, out: &mut Vec<f64>) {
        out.clear();
        out.extend(self.0.iter().map(|p| p[1]));
    }
    fn truth(&self, x: &[f64], z: &[f64], _t: f64) -> Truth {
        Truth::empty(z.len(), x.len())
    }
}

/// RMS of a trace: an echo's amplitude whatever its phase (its peak sample would depend on
/// where the carrier falls between samples).
fn rms(trace: ndarray::ArrayView1<f32>) -> f64 {
    (trace.iter().map(|&v| (v as f64).powi(2)).sum::<f64>() / trace.len() as f64).sqrt()
}

#[test]
fn a_point_at_the_focus_fades_out_of_the_plane_as_the_strips_fraunhofer_pattern() {
    // At the lens focus the two-way elevation factor is sinc²(h y / (λ F)): the echo of a point
    // moved y out of the plane scales by it, whatever the in-plane model does.
    let aperture = ElevationAperture::l22_14vx();
    let mut p = params(1e3);
    p.elevation = Some(aperture);
    let lambda = C / p.probe.center_frequency;
    let ys = [0.0, 0.1e-3, 0.2e-3, 0.3e-3];
    let echo = |y: f64| {
        let rf = traces(&Points(vec![[0.0, y, aperture.focus]], vec![1.0]), &p, 1);
        rms(rf.slice(s![0, 16, ..]))
    };
    let on_axis = echo(0.0);
    for &y in &ys[1..] {
        let u: f64 = aperture.height * y / (lambda * aperture.focus);
        let sinc = (std::f64::consts::PI * u).sin() / (std::f64::consts::PI * u);
        let ratio = echo(y) / on_axis;
        assert!(
            (ratio - sinc * sinc).abs() < 0.03,
            "y = {:.1} mm: echo ratio {ratio:.3}, sinc² {:.3}",
            y * 1e3,
            sinc * sinc
        );
    }
    // The same point with no elevation model: the two-dimensional simulator, unscaled.
    p.elevation = None;
    let flat = rms(traces(
        &Points(vec![[0.0, 0.3e-3, aperture.focus]], vec![1.0]),
        &p,
        1,
    )
    .slice(s![0, 16, ..]));
    let flat_on_axis = rms(
        traces(&Points(vec![[0.0, 0.0, aperture.focus]], vec![1.0]), &p, 1).slice(s![0, 16, ..]),
    );
    assert_eq!(flat, flat_on_axis);
}

/// Lag (samples) that best aligns `b` on `a`: the peak of their cross-correlation, refined by a
/// parabola through its three highest values.
fn lag(a: ndarray::ArrayView1<f32>, b: ndarray::ArrayView1<f32>) -> f64 {
    let xc = |k: i64| -> f64 {
        (0..a.len() as i64)
            .filter(|&i| (0..b.len() as i64).contains(&(i + k)))
            .map(|i| a[i as usize] as f64 * b[(i + k) as usize] as f64)
            .sum()
    };
    let (best, _) = (-20..=20)
        .map(|k| (k, xc(k)))
        .fold((0, f64::MIN), |m, v| if v.1 > m.1 { v } else { m });
    let (l, c, r) = (xc(best - 1), xc(best), xc(best + 1));
    best as f64 + 0.5 * (l - r) / (l - 2.0 * c + r)
}

fn tissue(motion: TissueMotion, echogenicity_db: f64, density: f64) -> TissuePhantom {
    let spec = TissueSpec {
        x_range: (-1.5e-3, 1.5e-3),
        z_range: (4e-3, 6e-3),
        half_thickness: 0.0,
        density,
        echogenicity_db,
        blood_power_density: 3e8,
        layers: Vec::new(),
        anechoic: Vec::new(),
        motion,
    };
    TissuePhantom::new(spec, 11, |_, _, _| false).unwrap()
}

#[test]
fn a_rigid_tissue_displacement_shifts_the_echo_by_its_round_trip() {
    // 20 µm deeper a quarter breathing period after t = 0 (phase 0): a 0° plane wave's echoes
    // arrive 2 · 20 µm / c later, 1.69 samples at 65 MHz, on every channel.
    let motion = TissueMotion {
        oscillations: vec![Oscillation {
            frequency_hz: 1.0,
            amplitude: [0.0, 0.0, 20e-6],
            phase_rad: 0.0,
            depth_gradient: 0.0,
        }],
        reference_depth: 0.0,
    };
    let phantom = tissue(motion, 40.0, TissueSpec::DEFAULT_DENSITY_2D);
    let rf = traces(&phantom, &params(4.0), 2);
    let expected = 2.0 * 20e-6 / C * 65e6;
    for channel in [4, 16, 27] {
        let shift = lag(rf.slice(s![0, channel, ..]), rf.slice(s![1, channel, ..]));
        assert!(
            (shift - expected).abs() < 0.05,
            "channel {channel}: echo shifted {shift:.3} samples, expected {expected:.3}"
        );
    }
}

#[test]
fn tissue_echoes_above_blood_by_its_echogenicity() {
    // Tissue-only and "blood-only" runs of the same region: blood at its own density (300/mm²)
    // and unit amplitudes; tissue at the speckle density, 35 dB brighter per unit area.
    let p = params(1e3);
    let power = |phantom: &dyn Phantom| {
        let rf = traces(phantom, &p, 1);
        rf.iter().map(|&v| (v as f64).powi(2)).sum::<f64>()
    };
    let tissue_power = power(&tissue(
        TissueMotion::still(),
        35.0,
        TissueSpec::DEFAULT_DENSITY_2D,
    ));
    let blood_power = power(&tissue(TissueMotion::still(), 0.0, 3e8));
    let measured = 10.0 * (tissue_power / blood_power).log10();
    // Two draws of ~4,000 and ~1,800 scatterers whose echoes overlap: a few tenths of a dB.
    assert!(
        (measured - 35.0).abs() < 1.0,
        "tissue {measured:.2} dB above blood"
    );
}

#[test]
fn tissue_motion_truth_is_the_field_on_the_grid() {
    let phantom = tissue(TissueMotion::rat(), 40.0, TissueSpec::DEFAULT_DENSITY_2D);
    let (x, z) = (vec![-1e-3, 0.0, 1e-3], vec![4e-3, 5e-3]);
    let truth = phantom.motion_truth(&x, &z, 0.05);
    let v: Array2<f64> = truth.velocity[2].clone();
    let expected = TissueMotion::rat().velocity([1e-3, 0.0, 5e-3], 0.05)[2];
    assert_eq!(v[[1, 2]], expected);
    assert!(v[[1, 2]] > v[[0, 2]], "breathing grows with depth");
}

/// The RMS of `got − want` over the RMS of `want`: how far a keyframed simulation is from the
/// direct one.
fn relative_rms(got: &ndarray::Array3<f32>, want: &ndarray::Array3<f32>) -> f64 {
    let energy = |a: ndarray::ArrayView3<f32>| a.iter().map(|&v| (v as f64).powi(2)).sum::<f64>();
    (energy((got - want).view()) / energy(want.view())).sqrt()
}

#[test]
fn tissue_at_keyframes_matches_the_direct_simulation() {
    // Tissue moving 100 µm at 5 Hz (3.2 mm/s at its fastest, ten times the rat's brain) through
    // a coded 2-angle recording: its keyframes, 0.73 ms apart (10.6 events), turn its echo by 0.3 rad; the
    // cubic interpolation between them errs by ~φ⁴/40 = 2·10⁻⁴ of the echo.
    let motion = TissueMotion {
        oscillations: vec![Oscillation {
            frequency_hz: 5.0,
            amplitude: [20e-6, 0.0, 100e-6],
            phase_rad: 0.3,
            depth_gradient: 0.0,
        }],
        reference_depth: 0.0,
    };
    let v_max = 2.0 * std::f64::consts::PI * 5.0 * 20e-6f64.hypot(100e-6);
    let moving = tissue(motion, 40.0, TissueSpec::DEFAULT_DENSITY_2D);
    let mut p = params(14.4e3);
    p.sequence.angles = vec![-5f64.to_radians(), 5f64.to_radians()];
    p.sequence.coding = Coding::Hadamard { slot_delay: 1e-6 };
    let no_blood =
        pcuvd::simulate::phantom::PointPhantom::new(Vec::new(), Vec::new(), [0.0; 2]).unwrap();
    let interval = keyframe_interval(v_max, C / p.probe.center_frequency);
    let frames = 60;
    let direct = traces(&moving, &p, frames);
    let events = 0..2 * frames;
    let keyed = simulate_events_with_tissue(
        &no_blood,
        &moving,
        &p,
        frames,
        events.clone(),
        interval,
        &no_progress,
    )
    .unwrap();
    let error = relative_rms(&keyed, &direct);
    assert!(error < 1e-3, "relative RMS error {error:.2e}");
    // A later block of the same recording gives the same events.
    let block = simulate_events_with_tissue(
        &no_blood,
        &moving,
        &p,
        frames,
        50..90,
        interval,
        &no_progress,
    )
    .unwrap();
    assert_eq!(block, keyed.slice(s![50..90, .., ..]));
    // A conventional recording of the same tissue first, through one shared set of keyframes:
    // the coded slots reuse its angles' keyframes shifted by their whole-sample starts (65 at
    // 1 µs and 65 MHz), and give the same events as their own keyframes did.
    let mut shared = TissueKeyframes::new(interval, p.sequence.last_slot_start());
    let mut conventional_params = p.clone();
    conventional_params.sequence.coding = Coding::Conventional;
    let mut conventional = ndarray::Array3::<f32>::zeros(keyed.dim());
    shared
        .add(
            &moving,
            &conventional_params,
            events.clone(),
            conventional.view_mut(),
        )
        .unwrap();
    let mut coded = ndarray::Array3::<f32>::zeros(keyed.dim());
    shared
        .add(&moving, &p, events.clone(), coded.view_mut())
        .unwrap();
    let error = relative_rms(&coded, &keyed);
    assert!(
        error < 1e-6,
        "shared keyframes: relative RMS error {error:.2e}"
    );
    let conventional_direct = traces(&moving, &conventional_params, frames);
    let error = relative_rms(&conventional, &conventional_direct);
    assert!(error < 1e-3, "conventional: relative RMS error {error:.2e}");
    // Tissue at 0.5 m/s (amplitude 100 µm at 800 Hz), whose keyframes would be 14 to an event:
    // one at each event instead, exact but for the f32 rounding of summing the slots apart
    // (interpolated between keyframes 0.3 rad apart it would err by ~2·10⁻⁴, as above).
    let fast = tissue(
        TissueMotion {
            oscillations: vec![Oscillation {
                frequency_hz: 800.0,
                amplitude: [0.0, 0.0, 100e-6],
                phase_rad: 0.3,
                depth_gradient: 0.0,
            }],
            reference_depth: 0.0,
        },
        40.0,
        TissueSpec::DEFAULT_DENSITY_2D,
    );
    let v_fast = 2.0 * std::f64::consts::PI * 800.0 * 100e-6;
    let fast_interval = keyframe_interval(v_fast, C / p.probe.center_frequency);
    assert!(
        fast_interval * p.sequence.event_prf < 0.1,
        "{fast_interval} s"
    );
    let direct = traces(&fast, &p, 4);
    let keyed =
        simulate_events_with_tissue(&no_blood, &fast, &p, 4, 0..8, fast_interval, &no_progress)
            .unwrap();
    let error = relative_rms(&keyed, &direct);
    assert!(error < 1e-6, "fast tissue: relative RMS error {error:.2e}");
    // Still tissue: one keyframe, exact but for the f32 rounding of summing the slots apart.
    let still = tissue(TissueMotion::still(), 40.0, TissueSpec::DEFAULT_DENSITY_2D);
    let exact = traces(&still, &p, 2);
    let once =
        simulate_events_with_tissue(&no_blood, &still, &p, 2, 0..4, f64::INFINITY, &no_progress)
            .unwrap();
    let error = relative_rms(&once, &exact);
    assert!(error < 1e-6, "relative RMS error {error:.2e}");
}

/// Points drifting at constant in-plane velocities (m/s) from their starts (m), each at its
/// elevation (m), amplitude 1.
struct Drifting {
    starts: Vec<[f64; 2]>,
    velocities: Vec<[f64; 2]>,
    elevations: Vec<f64>,
    amplitudes: Vec<f64>,
}

impl Phantom for Drifting {
    fn amplitudes(&self) -> &[f64] {
        &self.amplitudes
    }
    fn positions_at(&self, t: f64, out: &mut Vec<[f64; 2]>) {
        out.clear();
        out.extend(
            self.starts
                .iter()
                .zip(&self.velocities)
                .map(|(p, v)| [p[0] + v[0] * t, p[1] + v[1] * t]),
        );
    }
    fn elevations_at(&self, _t: f64, out: &mut Vec<f64>) {
        out.clear();
        out.extend(&self.elevations);
    }
    fn truth(&self, x: &[f64], z: &[f64], _t: f64) -> Truth {
        Truth::empty(z.len(), x.len())
    }
}

#[test]
#[ignore = "slow tier: cargo test -- --include-ignored"]
fn blood_at_keyframes_by_speed_matches_the_direct_simulation() {
    use pcuvd::simulate::keyframes::KeyframedBlood;
    // 7,000 scatterers from 0.3 to 40 mm/s, in every direction, through a coded 2-angle
    // recording and a conventional one, each 200 frames. Classes halve from 40 mm/s; runs of
    // them are rendered at every event or at the keyframes of their fastest speed, whichever
    // costs less. The fastest would need keyframes closer than 2 events (59 µs against 139 µs).
    let speeds = [40e-3, 25e-3, 12e-3, 7e-3, 3e-3, 1e-3, 0.3e-3];
    let n = 7000;
    let mut drifting = Drifting {
        starts: Vec::new(),
        velocities: Vec::new(),
        elevations: Vec::new(),
        amplitudes: Vec::new(),
    };
    for (i, &speed) in speeds.iter().cycle().take(n).enumerate() {
        let angle = i as f64 * 2.4;
        let start = [
            -1.5e-3 + 3e-3 * (i as f64 / n as f64),
            3e-3 + 4e-3 * ((i * 37 % n) as f64 / n as f64),
        ];
        drifting.starts.push(start);
        drifting
            .velocities
            .push([speed * angle.cos(), speed * angle.sin()]);
        drifting.elevations.push(0.3e-3 * angle.sin());
        drifting.amplitudes.push(1.0);
    }
    let bounds: Vec<f64> = speeds.iter().cycle().take(n).copied().collect();
    // In three dimensions, with the echo's spectrum lowered by attenuation along its path.
    let mut coded = params(14.4e3);
    coded.elevation = Some(ElevationAperture::l22_14vx());
    coded.attenuation_db_cm_mhz = 0.5;
    coded.sequence.angles = vec![-5f64.to_radians(), 5f64.to_radians()];
    coded.sequence.coding = Coding::Hadamard { slot_delay: 1e-6 };
    let mut conventional = coded.clone();
    conventional.sequence.coding = Coding::Conventional;
    let frames = 200;
    let mut blood = KeyframedBlood::new(&bounds, &[&conventional, &coded], frames).unwrap();
    let classes = blood.classes();
    assert_eq!(classes[0].keyframe_interval_s, None, "{classes:?}");
    assert!(classes.len() >= 2, "some blood at keyframes: {classes:?}");
    let event = 1.0 / 14.4e3;
    for class in &classes[1..] {
        let interval = class.keyframe_interval_s.unwrap();
        assert!(interval >= 2.0 * event, "{class:?}");
        let phase = 2.0 * 2.0 * std::f64::consts::PI / (C / coded.probe.center_frequency)
            * class.max_speed_m_s
            * interval;
        assert!((phase - 0.3).abs() < 1e-9, "{class:?}");
    }
    assert_eq!(classes.iter().map(|c| c.scatterers).sum::<usize>(), n);

    let mut first = ndarray::Array3::<f32>::zeros((2 * frames, 32, conventional.n_samples));
    blood
        .add(
            &drifting,
            &conventional,
            frames,
            0..2 * frames,
            first.view_mut(),
        )
        .unwrap();
    let mut keyed = ndarray::Array3::<f32>::zeros(first.dim());
    blood
        .add(&drifting, &coded, frames, 0..2 * frames, keyed.view_mut())
        .unwrap();
    for (keyed, p) in [(&first, &conventional), (&keyed, &coded)] {
        let direct = traces(&drifting, p, frames);
        let error = relative_rms(keyed, &direct);
        assert!(
            error < 1e-3,
            "{:?}: relative RMS error {error:.2e}",
            p.sequence.coding
        );
    }
    // A later block of the same recording, through fresh classes, gives the same events.
    let mut fresh = KeyframedBlood::new(&bounds, &[&conventional, &coded], frames).unwrap();
    let mut block = ndarray::Array3::<f32>::zeros((30, 32, coded.n_samples));
    fresh
        .add(&drifting, &coded, frames, 40..70, block.view_mut())
        .unwrap();
    assert_eq!(block, keyed.slice(s![40..70, .., ..]));
    // The classes were made for 7,000 scatterers.
    let fewer = Drifting {
        starts: drifting.starts[..10].to_vec(),
        velocities: drifting.velocities[..10].to_vec(),
        elevations: drifting.elevations[..10].to_vec(),
        amplitudes: drifting.amplitudes[..10].to_vec(),
    };
    assert!(
        blood
            .add(
                &fewer,
                &coded,
                frames,
                0..2,
                keyed.slice_mut(s![0..2, .., ..])
            )
            .is_err()
    );
}
