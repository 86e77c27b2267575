//! Dynamics stage against analytic truth: PSV/EDV/RI of known waveforms, cardiac-period detection,
//! sliding vector Doppler on synthetic pulsatile IQ series, the compounded spectrogram, and every
//! refusal of bad input.

use pcuvd_testing as common;

use std::f64::consts::PI;

use ndarray::{Array2, Array3, s};
use num_complex::Complex32;
use pcuvd::Error;
use pcuvd::core::grid::Grid;
use pcuvd::dynamics::{
    self, ARTERIOLE, BACKGROUND, CycleSource, DynamicsParams, SpectrogramParams, VENULE,
    VelocitySeries, VesselPooling, cardiac_cycles, estimate_heart_rate, find_cycles, psv_edv,
    resistivity_index, ri_maps, ri_maps_triggered, sliding_vectors, spectrogram,
    systolic_upstrokes,
};
use pcuvd::estimate::doppler::velocity_scale;
use pcuvd::form::images::AngleImages;
use pcuvd::simulate::phantom::network::CardiacWaveform;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

const C: f64 = 1540.0;
const FRAME_RATE: f64 = 1800.0;
const F0: f64 = 15.625e6;

/// The rat preset with the nominal-frequency (Kasai) Doppler: the synthetic series below are a
/// Doppler tone per pixel with no echo along depth (their mean frequency is the nominal one by
/// construction, and a 0.1 mm grid is too coarse to measure one at 15.6 MHz).
fn rat() -> DynamicsParams {
    DynamicsParams {
        doppler: pcuvd::estimate::doppler::DopplerEstimator::Kasai,
        ..DynamicsParams::rat()
    }
}

/// `iq` (per angle, (nz, nx, frames)) with the test's sound speed and centre frequency, at
/// `frame_rate` (Hz), on a 0.1 mm grid of its shape.
fn images(
    iq: &[Array3<Complex32>],
    angles: &[f64],
    frame_rate: f64,
    coverage: Option<Array3<bool>>,
) -> AngleImages {
    let (nz, nx, _) = iq.first().map_or((0, 0, 0), |s| s.dim());
    AngleImages {
        grid: Grid {
            x: (0..nx).map(|i| i as f64 * 1e-4).collect(),
            z: (0..nz).map(|i| 1e-3 + i as f64 * 1e-4).collect(),
        },
        angles: angles.to_vec(),
        frame_rate,
        sound_speed: C,
        demodulation_frequency: F0,
        coverage,
        series: iq.to_vec(),
    }
}

fn paper_angles() -> Vec<f64> {
    (0..8)
        .map(|i| (-15.0 + 30.0 * i as f64 / 7.0_f64).to_radians())
        .collect()
}

/// Pulsatile speed: EDV at end-diastole, PSV at systole, a raised cosine at `hr` Hz.
fn pulsatile(t: f64, hr: f64, psv: f64, edv: f64) -> f64 {
    edv + (psv - edv) * 0.5 * (1.0 - (2.0 * PI * hr * t).cos())
}

/// A vessel pixel: speed waveform (PSV, EDV, m/s) along a fixed unit direction (ux, uz).
struct Vessel {
    pixel: (usize, usize),
    psv: f64,
    edv: f64,
    dir: (f64, f64),
}

impl Vessel {
    fn velocity(&self, t: f64, hr: f64) -> (f64, f64) {
        let s = pulsatile(t, hr, self.psv, self.edv);
        (s * self.dir.0, s * self.dir.1)
    }
}

/// Per-angle IQ series (nz, nx, frames): unit-amplitude Doppler phase ramps at the vessel pixels
/// (phase step −V_θ/scale per frame, V_θ = (Vx sin θ + Vz (cos θ + 1))/2), complex white noise of
/// power `noise_power` everywhere.
fn synthetic_iq(
    vessels: &[Vessel],
    shape: (usize, usize),
    frames: usize,
    hr: f64,
    noise_power: f64,
    seed: u64,
) -> Vec<Array3<Complex32>> {
    synthetic_iq_at(
        &paper_angles(),
        vessels,
        shape,
        frames,
        hr,
        noise_power,
        seed,
    )
}

/// [`synthetic_iq`] at the steering `angles` given (rad).
fn synthetic_iq_at(
    angles: &[f64],
    vessels: &[Vessel],
    shape: (usize, usize),
    frames: usize,
    hr: f64,
    noise_power: f64,
    seed: u64,
) -> Vec<Array3<Complex32>> {
    let scale = velocity_scale(C, FRAME_RATE, F0).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let sigma = (noise_power / 2.0).sqrt();
    angles
        .iter()
        .map(|&theta| {
            let mut series = Array3::<Complex32>::zeros((shape.0, shape.1, frames));
            for v in series.iter_mut() {
                let re: f64 = StandardNormal.sample(&mut rng);
                let im: f64 = StandardNormal.sample(&mut rng);
                *v = Complex32::new((sigma * re) as f32, (sigma * im) as f32);
            }
            for vessel in vessels {
                let mut phase = 0.3 * theta;
                for t in 0..frames {
                    let (iz, ix) = vessel.pixel;
                    series[[iz, ix, t]] += Complex32::from_polar(1.0, phase as f32);
                    let (vx, vz) = vessel.velocity((t as f64 + 0.5) / FRAME_RATE, hr);
                    let v_theta = 0.5 * (vx * theta.sin() + vz * (theta.cos() + 1.0));
                    phase -= v_theta / scale;
                }
            }
            series
        })
        .collect()
}

fn unit(deg: f64, up: bool) -> (f64, f64) {
    let a = deg.to_radians();
    (a.sin(), if up { -a.cos() } else { a.cos() })
}

#[test]
fn rat_defaults_are_valid() {
    let p = DynamicsParams::rat();
    assert_eq!((p.window, p.step), (36, 9));
    assert_eq!(p, DynamicsParams::default());
    p.validate(FRAME_RATE).unwrap();
    assert_eq!(SpectrogramParams::default(), SpectrogramParams::rat());
}

#[test]
fn resistivity_index_exact_on_analytic_waveform() {
    // v(t) = EDV + (PSV − EDV)·max(0, sin 2πft)³, 200 samples per cycle: peaks and troughs sampled.
    let (f, fs, psv, edv) = (6.0, 1200.0, 0.021, 0.0065);
    let n = 680; // 3.4 cycles
    let times: Vec<f64> = (0..n).map(|i| i as f64 / fs).collect();
    let v: Vec<f64> = times
        .iter()
        .map(|&t| edv + (psv - edv) * (2.0 * PI * f * t).sin().max(0.0).powi(3))
        .collect();
    let truth = (psv - edv) / psv;
    assert!((resistivity_index(psv, edv) - truth).abs() < 1e-15);
    for hr in [Some(f), None] {
        let cycles = find_cycles(&v, &times, hr).unwrap();
        assert_eq!(cycles.len(), 3, "{hr:?}: {cycles:?}");
        assert!(cycles.iter().all(|&(a, b)| b - a == 200), "{cycles:?}");
        let (p, e) = psv_edv(&v, &cycles).unwrap();
        assert!(
            (p - psv).abs() < 1e-12 && (e - edv).abs() < 1e-12,
            "{p} {e}"
        );
        assert!((resistivity_index(p, e) - truth).abs() < 1e-9);
    }
    assert!(resistivity_index(0.0, 0.0).is_nan());
    assert!(resistivity_index(-1.0, 0.0).is_nan());
    assert!(resistivity_index(f64::NAN, 0.0).is_nan());
    assert!(psv_edv(&v, &[]).is_err());
    assert!(psv_edv(&v, &[(600, 700)]).is_err());
}

#[test]
fn cycle_detection_recovers_heart_rate() {
    // An arterial-like waveform (fast upstroke, slow decay) at 5.5 Hz on a drift, sampled every
    // 5 ms (the window series of the rat preset) over 0.65 s, with small deterministic noise.
    let (hr, dt) = (5.5, 0.005);
    let times: Vec<f64> = (0..130).map(|i| 0.01 + i as f64 * dt).collect();
    let v: Vec<f64> = times
        .iter()
        .enumerate()
        .map(|(i, &t)| {
            let phase = (hr * t + 0.9).fract();
            let w = if phase < 0.15 {
                phase / 0.15
            } else {
                (-(phase - 0.15) / 0.25).exp()
            };
            0.008 + 0.012 * w + 0.004 * t + 2e-4 * ((i * 7919) % 13) as f64 / 13.0
        })
        .collect();
    let est = estimate_heart_rate(&v, &times).unwrap();
    assert!((est - hr).abs() / hr < 0.03, "estimated {est} Hz");
    let cycles = find_cycles(&v, &times, None).unwrap();
    assert_eq!(cycles.len(), 3, "{cycles:?}");
    for &(a, b) in &cycles {
        assert!((b - a) as f64 * dt * hr > 0.97 && ((b - a) as f64 * dt * hr) < 1.03);
    }
    // Cycles start at systolic peaks: the first sample of each cycle is within 1 sample of its max.
    for &(a, b) in &cycles {
        let peak = (a..b).max_by(|&i, &j| v[i].total_cmp(&v[j])).unwrap();
        assert!(peak <= a + 1, "cycle [{a}, {b}) peaks at {peak}");
    }
}

/// An upward arteriole (RI 0.7) at pixel (0, 0) and a downward venule (RI 0.3) at (1, 2).
fn artery_and_vein() -> Vec<Vessel> {
    vec![
        Vessel {
            pixel: (0, 0),
            psv: 0.020,
            edv: 0.006,
            dir: unit(20.0, true),
        },
        Vessel {
            pixel: (1, 2),
            psv: 0.015,
            edv: 0.0105,
            dir: unit(-30.0, false),
        },
    ]
}

/// 2.5 cycles at 6 Hz and 1.8 kHz of [`artery_and_vein`].
fn pulsatile_case() -> (Vec<Array3<Complex32>>, Vec<Vessel>, f64) {
    let hr = 6.0;
    let frames = (2.5 * FRAME_RATE / hr) as usize; // 750
    let vessels = artery_and_vein();
    let iq = synthetic_iq(&vessels, (2, 3), frames, hr, 4e-4, 7);
    (iq, vessels, hr)
}

/// Settings that only the RI maps read leave the windows as they were, so a run's windows stand
/// for another's that differs in those alone; a window's own settings make other windows.
#[test]
fn ri_settings_form_the_same_windows_and_window_settings_do_not() {
    let (iq, _, hr) = pulsatile_case();
    let images = images(&iq, &paper_angles(), FRAME_RATE, None);
    let first = rat();
    let ri_only = DynamicsParams {
        heart_rate_hz: Some(hr),
        artery_ri_min: 0.7,
        vein_ri_max: 0.3,
        min_power_db: -20.0,
        harmonics: Some(3),
        debias_harmonics: !first.debias_harmonics,
        pooling: Some(VesselPooling {
            along: 4.0,
            across: 1.0,
            max_angle: 0.5,
        }),
        ..first
    };
    assert!(first.forms_the_same_windows(&ri_only));
    let windows = sliding_vectors(&images, &first).unwrap();
    assert_eq!(windows, sliding_vectors(&images, &ri_only).unwrap());
    for other in [
        DynamicsParams {
            kernel: (3, 3),
            ..first
        },
        DynamicsParams { step: 10, ..first },
        DynamicsParams {
            window: 30,
            ..first
        },
    ] {
        assert!(!first.forms_the_same_windows(&other), "{other:?}");
        assert_ne!(
            windows,
            sliding_vectors(&images, &other).unwrap(),
            "{other:?}"
        );
    }
}

#[test]
fn sliding_vectors_track_pulsatile_flow_and_classify_vessels() {
    let (iq, vessels, hr) = pulsatile_case();
    let angles = paper_angles();
    let mut params = rat();
    params.heart_rate_hz = None;
    let series = sliding_vectors(&images(&iq, &angles, FRAME_RATE, None), &params).unwrap();
    assert_eq!(series.len(), (750 - 36) / 9 + 1);
    assert_eq!(series.vx.dim(), (series.len(), 2, 3));
    let speed = series.speed();
    assert_eq!(series.speed_at(7), speed.index_axis(ndarray::Axis(0), 7));
    assert_eq!(series.speed_lane(0, 1), speed.slice(s![.., 0, 1]).to_vec());
    assert!((series.times_s[0] - 17.5 / FRAME_RATE).abs() < 1e-12);
    assert!((series.step_s - 0.005).abs() < 1e-12 && (series.window_s - 0.02).abs() < 1e-12);

    // The window estimates follow the window-averaged truth.
    for vessel in &vessels {
        let (iz, ix) = vessel.pixel;
        let mut sq = 0.0;
        for (k, &tc) in series.times_s.iter().enumerate() {
            let (mut tx, mut tz) = (0.0, 0.0);
            for j in 0..35 {
                let (x, z) = vessel.velocity(tc + (j as f64 - 17.0) / FRAME_RATE, hr);
                tx += x / 35.0;
                tz += z / 35.0;
            }
            sq += (series.vx[[k, iz, ix]] - tx).powi(2) + (series.vz[[k, iz, ix]] - tz).powi(2);
        }
        let rms = (sq / series.len() as f64).sqrt();
        assert!(rms < 5e-4, "pixel {:?}: RMS error {rms} m/s", vessel.pixel);
    }

    let maps = ri_maps(&series, &params).unwrap();
    assert!(
        (maps.heart_rate_hz - hr).abs() / hr < 0.03,
        "{}",
        maps.heart_rate_hz
    );
    assert_eq!(maps.cycles.len(), 2);
    for (vessel, class, up) in [(&vessels[0], ARTERIOLE, true), (&vessels[1], VENULE, false)] {
        let p = vessel.pixel;
        let ri = (vessel.psv - vessel.edv) / vessel.psv;
        let (psv, edv) = (maps.psv[p], maps.edv[p]);
        assert!((psv - vessel.psv).abs() < 0.03 * vessel.psv, "PSV {psv}");
        assert!((edv - vessel.edv).abs() < 0.03 * vessel.psv, "EDV {edv}");
        assert!((maps.ri[p] - ri).abs() < 0.03, "RI {} vs {ri}", maps.ri[p]);
        assert_eq!(maps.vessel_class[p], class);
        assert_eq!(maps.flow_up[p], up);
    }
    for p in [(0, 1), (0, 2), (1, 0), (1, 1)] {
        assert_eq!(maps.vessel_class[p], BACKGROUND);
        assert!(maps.ri[p].is_nan() && !maps.flow_up[p]);
    }

    // A given heart rate gives the same maps (to within the cycle placement).
    params.heart_rate_hz = Some(hr);
    let given = ri_maps(&series, &params).unwrap();
    assert_eq!(given.vessel_class, maps.vessel_class);
    assert!((given.ri[[0, 0]] - maps.ri[[0, 0]]).abs() < 0.02);

    // Deterministic: the same input gives bit-identical output.
    let again = sliding_vectors(&images(&iq, &angles, FRAME_RATE, None), &params).unwrap();
    assert_eq!(again, series);

    // The compounded spectrogram's mean velocity follows the vector Vz (paper Fig. 8b).
    let spec = spectrogram(
        &images(&iq, &angles, FRAME_RATE, None),
        (0, 0),
        &SpectrogramParams::rat(),
    )
    .unwrap();
    assert_eq!(spec.times_s, series.times_s);
    // With lateral flow the angles' Doppler lines differ and beat in the coherent sum, so the
    // colour estimate only follows the vector Vz in step (as in the paper), not to the sample.
    let colour = &spec.mean_velocity_m_s;
    let vector: Vec<f64> = (0..colour.len()).map(|k| series.vz[[k, 0, 0]]).collect();
    let n = colour.len() as f64;
    let (mc, mv) = (
        colour.iter().sum::<f64>() / n,
        vector.iter().sum::<f64>() / n,
    );
    let (mut cov, mut vc, mut vv, mut sq) = (0.0, 0.0, 0.0, 0.0);
    for (&a, &b) in colour.iter().zip(&vector) {
        cov += (a - mc) * (b - mv);
        vc += (a - mc).powi(2);
        vv += (b - mv).powi(2);
        sq += (a - b).powi(2);
    }
    let corr = cov / (vc * vv).sqrt();
    let rms = (sq / n).sqrt();
    assert!(
        corr > 0.98 && rms < 8e-4,
        "colour vs vector Vz: correlation {corr}, RMS {rms} m/s"
    );
}

/// One steering angle gives the colour-Doppler velocity alone, and RI from it: a ratio, blind to
/// the projection's scale, so an arteriole and a venule oblique to the beam read their own RI and
/// class, while a vessel across the beam (a projection of zero: the windows' noise) is left
/// undetermined rather than given the RI of noise.
#[test]
fn one_angle_reads_ri_from_the_colour_doppler_velocity() {
    let hr = 6.0;
    let frames = (2.5 * FRAME_RATE / hr) as usize;
    let mut vessels = artery_and_vein();
    vessels.push(Vessel {
        pixel: (1, 0),
        psv: 0.020,
        edv: 0.006,
        dir: (1.0, 0.0),
    });
    let mut params = rat();
    params.heart_rate_hz = None;
    let iq = synthetic_iq_at(&[0.0], &vessels, (2, 3), frames, hr, 4e-4, 11);
    let series = sliding_vectors(&images(&iq, &[0.0], FRAME_RATE, None), &params).unwrap();
    assert!(series.axial_only);
    // No Vx is held, not even NaN: a long single-angle recording's windows are two maps each.
    assert_eq!(series.vx.dim(), (0, 2, 3));
    assert_eq!(series.speed(), series.vz.mapv(f64::abs));
    for k in 0..series.len() {
        assert_eq!(
            series.speed_at(k),
            series.speed().index_axis(ndarray::Axis(0), k)
        );
    }
    assert_eq!(
        series.speed_lane(1, 2),
        series.speed().slice(s![.., 1, 2]).to_vec()
    );
    for vessel in &vessels[..2] {
        let (iz, ix) = vessel.pixel;
        let mut sq = 0.0;
        for (k, &tc) in series.times_s.iter().enumerate() {
            let tz = (0..35)
                .map(|j| vessel.velocity(tc + (j as f64 - 17.0) / FRAME_RATE, hr).1)
                .sum::<f64>()
                / 35.0;
            sq += (series.vz[[k, iz, ix]] - tz).powi(2);
        }
        let rms = (sq / series.len() as f64).sqrt();
        assert!(rms < 5e-4, "pixel {:?}: RMS error {rms} m/s", vessel.pixel);
    }
    // Pooling gathers neighbours along the flow's direction in the plane, which one angle does
    // not give: refused, not run along a guess.
    let pooled = DynamicsParams {
        pooling: Some(VesselPooling {
            along: 3.0,
            across: 1.0,
            max_angle: 0.5,
        }),
        ..params
    };
    is_invalid(ri_maps(&series, &pooled), "one steering angle");
    let maps = ri_maps(&series, &params).unwrap();
    assert!(
        (maps.heart_rate_hz - hr).abs() / hr < 0.03,
        "{}",
        maps.heart_rate_hz
    );
    for (vessel, class, up) in [(&vessels[0], ARTERIOLE, true), (&vessels[1], VENULE, false)] {
        let p = vessel.pixel;
        let ri = (vessel.psv - vessel.edv) / vessel.psv;
        let axial = vessel.dir.1.abs();
        let (psv, edv) = (maps.psv[p], maps.edv[p]);
        assert!(
            (psv - vessel.psv * axial).abs() < 0.03 * vessel.psv,
            "PSV {psv}"
        );
        assert!(
            (edv - vessel.edv * axial).abs() < 0.03 * vessel.psv,
            "EDV {edv}"
        );
        assert!((maps.ri[p] - ri).abs() < 0.03, "RI {} vs {ri}", maps.ri[p]);
        assert_eq!(maps.vessel_class[p], class);
        assert_eq!(maps.flow_up[p], up);
    }
    let across = vessels[2].pixel;
    let coherence = dynamics::axial_coherence(series.vz.slice(s![.., across.0, across.1]));
    assert!(coherence < dynamics::AXIAL_COHERENCE_MIN, "{coherence}");
    assert_eq!(maps.vessel_class[across], dynamics::UNDETERMINED);
    assert!(maps.ri[across].is_nan() && maps.psv[across].is_nan());

    // Steered, the one angle's projection (Vx sin θ + Vz (1 + cos θ))/2 reads as the colour
    // Doppler's Vz + Vx tan(θ/2): the vessel across the beam now shows, at a quarter of its
    // speed (θ = 30°), with its own RI.
    let theta = 30f64.to_radians();
    vessels[2].dir = (1.0, 0.0);
    let iq = synthetic_iq_at(&[theta], &vessels, (2, 3), frames, hr, 4e-4, 12);
    let series = sliding_vectors(&images(&iq, &[theta], FRAME_RATE, None), &params).unwrap();
    for vessel in &vessels {
        let (iz, ix) = vessel.pixel;
        let mut sq = 0.0;
        for (k, &tc) in series.times_s.iter().enumerate() {
            let read = (0..35)
                .map(|j| {
                    let (vx, vz) = vessel.velocity(tc + (j as f64 - 17.0) / FRAME_RATE, hr);
                    vz + vx * (theta / 2.0).tan()
                })
                .sum::<f64>()
                / 35.0;
            sq += (series.vz[[k, iz, ix]] - read).powi(2);
        }
        let rms = (sq / series.len() as f64).sqrt();
        assert!(rms < 5e-4, "pixel {:?}: RMS error {rms} m/s", vessel.pixel);
    }
    let maps = ri_maps(&series, &params).unwrap();
    let p = vessels[2].pixel;
    assert!(
        (maps.ri[p] - 0.7).abs() < 0.05,
        "RI across the beam, steered: {}",
        maps.ri[p]
    );
    assert_eq!(maps.vessel_class[p], ARTERIOLE);
}

#[test]
fn rat_preset_measures_one_cycle_in_a_fifth_of_a_second() {
    // The paper's recording: 360 frames (0.2 s) at 1.8 kHz, ≈ 1.1 cycles at 5.5 Hz.
    let vessel = Vessel {
        pixel: (0, 0),
        psv: 0.02,
        edv: 0.008,
        dir: unit(10.0, true),
    };
    let iq = synthetic_iq(&[vessel], (1, 2), 360, 5.5, 4e-4, 11);
    let params = rat();
    let series = sliding_vectors(&images(&iq, &paper_angles(), FRAME_RATE, None), &params).unwrap();
    assert_eq!(series.len(), 37);
    let maps = ri_maps(&series, &params).unwrap();
    assert_eq!(maps.cycles.len(), 1);
    assert!(
        (maps.ri[[0, 0]] - 0.6).abs() < 0.03,
        "RI {}",
        maps.ri[[0, 0]]
    );
    assert_eq!(maps.vessel_class[[0, 0]], ARTERIOLE);
    assert!(maps.flow_up[[0, 0]]);
    // Too short to measure the heart rate from the data, and shorter than a 5 Hz cycle.
    let measure = DynamicsParams {
        heart_rate_hz: None,
        ..params
    };
    is_invalid(ri_maps(&series, &measure), "give the heart rate");
    let slow = DynamicsParams {
        heart_rate_hz: Some(5.0),
        ..params
    };
    is_invalid(ri_maps(&series, &slow), "shorter than one cardiac cycle");
}

#[test]
fn spectrogram_of_uniform_axial_flow() {
    let v0 = 0.012; // m/s, moving deeper
    let vessel = Vessel {
        pixel: (0, 1),
        psv: v0,
        edv: v0,
        dir: (0.0, 1.0),
    };
    let iq = synthetic_iq(&[vessel], (1, 2), 300, 6.0, 1e-4, 3);
    let angles = paper_angles();
    let params = SpectrogramParams {
        window: 64,
        step: 16,
        nfft: 256,
    };
    let spec = spectrogram(&images(&iq, &angles, FRAME_RATE, None), (0, 1), &params).unwrap();
    let nv = spec.velocities_m_s.len();
    assert_eq!(nv, 256);
    assert_eq!(spec.power_db.dim(), (spec.times_s.len(), 256));
    assert!(spec.velocities_m_s.windows(2).all(|w| w[1] > w[0]));
    let dv = spec.velocities_m_s[1] - spec.velocities_m_s[0];
    assert!((spec.velocities_m_s[nv - 1] - spec.nyquist_m_s).abs() < 1e-12);
    assert!((spec.velocities_m_s[0] + spec.nyquist_m_s - dv).abs() < 1e-12);
    for (k, row) in spec.power_db.outer_iter().enumerate() {
        let peak = (0..nv).max_by(|&i, &j| row[i].total_cmp(&row[j])).unwrap();
        assert!(
            (spec.velocities_m_s[peak] - v0).abs() <= 1.5 * dv,
            "peak at {} m/s",
            spec.velocities_m_s[peak]
        );
        assert!((spec.mean_velocity_m_s[k] - v0).abs() < 0.02 * v0);
        assert!(row.iter().all(|&p| (-200.0..=1e-12).contains(&p)));
    }
    // Flow toward the probe lands on the negative side.
    let up = Vessel {
        pixel: (0, 0),
        psv: v0,
        edv: v0,
        dir: (0.0, -1.0),
    };
    let iq = synthetic_iq(&[up], (1, 1), 128, 6.0, 1e-4, 4);
    let spec = spectrogram(&images(&iq, &angles, FRAME_RATE, None), (0, 0), &params).unwrap();
    assert!(
        spec.mean_velocity_m_s
            .iter()
            .all(|&v| (v + v0).abs() < 0.02 * v0)
    );
}

fn is_invalid(r: Result<impl std::fmt::Debug, Error>, needle: &str) {
    match r {
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.contains(needle), "message {msg:?} lacks {needle:?}");
        }
        Ok(v) => panic!("expected an error containing {needle:?}, got {v:?}"),
    }
}

#[test]
fn angles_that_miss_a_pixel_are_left_out_of_its_vectors() {
    // The two widest negative angles see only noise at pixel (0, 0) (as near the lateral edge of
    // the field, where their plane waves do not reach): told so by the coverage map, the vectors
    // there follow the flow; not told, the noise drags them off.
    let (mut iq, vessels, hr) = pulsatile_case();
    let angles = paper_angles();
    let (iz, ix) = (0, 0);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for series in iq.iter_mut().take(2) {
        for v in series.slice_mut(ndarray::s![iz, ix, ..]) {
            let re: f64 = StandardNormal.sample(&mut rng);
            let im: f64 = StandardNormal.sample(&mut rng);
            *v = Complex32::new(re as f32, im as f32);
        }
    }
    let mut coverage = Array3::from_elem((angles.len(), 2, 3), true);
    coverage[[0, iz, ix]] = false;
    coverage[[1, iz, ix]] = false;
    let params = rat();
    let vessel = vessels.iter().find(|v| v.pixel == (iz, ix)).unwrap();
    let rms = |series: &VelocitySeries| {
        let sq: f64 = series
            .times_s
            .iter()
            .enumerate()
            .map(|(k, &tc)| {
                // The window-averaged truth.
                let (mut tx, mut tz) = (0.0, 0.0);
                for j in 0..35 {
                    let (x, z) = vessel.velocity(tc + (j as f64 - 17.0) / FRAME_RATE, hr);
                    tx += x / 35.0;
                    tz += z / 35.0;
                }
                (series.vx[[k, iz, ix]] - tx).powi(2) + (series.vz[[k, iz, ix]] - tz).powi(2)
            })
            .sum();
        (sq / series.len() as f64).sqrt()
    };
    let covered = sliding_vectors(
        &images(&iq, &angles, FRAME_RATE, Some(coverage.clone())),
        &params,
    )
    .unwrap();
    let blind = sliding_vectors(&images(&iq, &angles, FRAME_RATE, None), &params).unwrap();
    let (good, bad) = (rms(&covered), rms(&blind));
    assert!(good < 5e-4, "with coverage: RMS error {good} m/s");
    assert!(
        bad > 3.0 * good,
        "without coverage: RMS error {bad} m/s vs {good}"
    );
    // The other pixels are untouched.
    assert_eq!(covered.vx[[0, 1, 2]], blind.vx[[0, 1, 2]]);
    assert_eq!(covered.vz[[5, 1, 2]], blind.vz[[5, 1, 2]]);
    is_invalid(
        sliding_vectors(
            &images(
                &iq,
                &angles,
                FRAME_RATE,
                Some(coverage.slice(ndarray::s![..4, .., ..]).to_owned()),
            ),
            &params,
        ),
        "coverage",
    );
}

#[test]
fn bad_input_is_refused_with_clear_errors() {
    let angles = paper_angles();
    let iq = synthetic_iq(
        &[Vessel {
            pixel: (0, 0),
            psv: 0.02,
            edv: 0.006,
            dir: (0.0, 1.0),
        }],
        (1, 2),
        400,
        6.0,
        1e-4,
        1,
    );
    let run = |p: DynamicsParams| sliding_vectors(&images(&iq, &angles, FRAME_RATE, None), &p);
    let base = DynamicsParams {
        heart_rate_hz: None,
        ..rat()
    };
    is_invalid(
        run(DynamicsParams {
            window: 500,
            ..base
        }),
        "longer than the recording",
    );
    is_invalid(
        run(DynamicsParams { window: 1, ..base }),
        "at least 2 frames",
    );
    is_invalid(run(DynamicsParams { step: 0, ..base }), "step");
    is_invalid(
        run(DynamicsParams {
            kernel: (2, 1),
            ..base
        }),
        "odd",
    );
    is_invalid(
        run(DynamicsParams {
            vein_ri_max: 0.7,
            ..base
        }),
        "RI thresholds",
    );
    // 40 Hz: a 45-frame period is shorter than two 36-frame windows; no heart beats that fast,
    // so the rate is taken as beats per minute given as Hz. 20 Hz could be a heart's: the way
    // out is shorter windows.
    is_invalid(
        run(DynamicsParams {
            heart_rate_hz: Some(40.0),
            ..base
        }),
        "2 windows of 36 frames: each window would blur systole into diastole; the heart rate is \
         in Hz (40 beats per minute would be 0.67 Hz)",
    );
    is_invalid(
        run(DynamicsParams {
            heart_rate_hz: Some(20.0),
            window: 50,
            ..base
        }),
        "use a window of at most 45 frames",
    );
    // Above the Nyquist rate of windows 100 frames apart (9 Hz).
    is_invalid(
        run(DynamicsParams {
            heart_rate_hz: Some(10.0),
            window: 20,
            step: 100,
            ..base
        }),
        "Nyquist",
    );
    is_invalid(
        run(DynamicsParams {
            heart_rate_hz: Some(-5.0),
            ..base
        }),
        "heart rate",
    );
    // 400 frames = 0.22 s: less than one 3 Hz cycle.
    is_invalid(
        run(DynamicsParams {
            heart_rate_hz: Some(3.0),
            ..base
        }),
        "shorter than one cardiac cycle",
    );
    // Empty, mismatched and non-finite series.
    is_invalid(
        sliding_vectors(&images(&[], &[], FRAME_RATE, None), &base),
        "no angle series",
    );
    assert!(matches!(
        sliding_vectors(&images(&iq, &angles[..4], FRAME_RATE, None), &base),
        Err(Error::Shape(_))
    ));
    let mut odd = iq.clone();
    odd[3] = Array3::zeros((1, 2, 399));
    assert!(matches!(
        sliding_vectors(&images(&odd, &angles, FRAME_RATE, None), &base),
        Err(Error::Shape(_))
    ));
    let empty = vec![Array3::<Complex32>::zeros((0, 2, 400)); 8];
    is_invalid(
        sliding_vectors(&images(&empty, &angles, FRAME_RATE, None), &base),
        "empty",
    );
    let mut nan = iq.clone();
    nan[1][[0, 1, 5]] = Complex32::new(f32::NAN, 0.0);
    assert!(matches!(
        sliding_vectors(&images(&nan, &angles, FRAME_RATE, None), &base),
        Err(Error::NonFinite(_))
    ));
    is_invalid(
        sliding_vectors(&images(&iq, &angles, 0.0, None), &base),
        "frame rate",
    );

    // The cycle finder.
    let t: Vec<f64> = (0..30).map(|i| i as f64 * 0.005).collect();
    let v: Vec<f64> = t.iter().map(|&t| pulsatile(t, 6.0, 0.02, 0.01)).collect();
    is_invalid(
        find_cycles(&v, &t, Some(5.0)),
        "shorter than one cardiac cycle",
    );
    is_invalid(find_cycles(&v, &t, None), "too short");
    is_invalid(find_cycles(&v, &t, Some(150.0)), "Nyquist");
    assert!(matches!(
        find_cycles(&v, &t[..10], Some(6.0)),
        Err(Error::Shape(_))
    ));
    let mut uneven = t.clone();
    uneven[4] += 0.001;
    is_invalid(find_cycles(&v, &uneven, Some(6.0)), "uniformly spaced");
    let flat = vec![0.01; 120];
    let tf: Vec<f64> = (0..120).map(|i| i as f64 * 0.005).collect();
    is_invalid(estimate_heart_rate(&flat, &tf), "constant");

    // RI maps: a short series and a series without any vessel.
    let series = sliding_vectors(&images(&iq, &angles, FRAME_RATE, None), &base).unwrap();
    is_invalid(
        ri_maps(
            &series,
            &DynamicsParams {
                heart_rate_hz: Some(3.5),
                ..base
            },
        ),
        "shorter than one cardiac cycle",
    );
    let dark = VelocitySeries {
        power: series.power.mapv(|_| 0.0),
        ..series.clone()
    };
    is_invalid(ri_maps(&dark, &base), "no vessel");

    // The spectrogram.
    let sp = SpectrogramParams::rat();
    let spec = |p: &SpectrogramParams, px: (usize, usize)| {
        dynamics::spectrogram(&images(&iq, &angles, FRAME_RATE, None), px, p)
    };
    is_invalid(spec(&sp, (1, 0)), "outside");
    is_invalid(
        spec(&SpectrogramParams { nfft: 16, ..sp }, (0, 0)),
        "FFT length",
    );
    is_invalid(
        spec(&SpectrogramParams { window: 1000, ..sp }, (0, 0)),
        "longer than the recording",
    );
    is_invalid(spec(&SpectrogramParams { step: 0, ..sp }, (0, 0)), "step");
    let zeros = vec![Array3::<Complex32>::zeros((1, 1, 100)); 8];
    is_invalid(
        dynamics::spectrogram(&images(&zeros, &angles, FRAME_RATE, None), (0, 0), &sp),
        "no Doppler signal",
    );
}

#[test]
fn harmonic_fit_removes_the_outward_bias_of_noisy_extremes() {
    // 40 pixels of one venule (RI 0.3) at an SNR of 10 dB per frame and angle: each window's speed
    // jitters by several per cent, and the raw max/min of 37 samples inflate RI.
    let hr = 5.5;
    let (psv, edv) = (0.012, 0.0084);
    let vessels: Vec<Vessel> = (0..40)
        .map(|ix| Vessel {
            pixel: (0, ix),
            psv,
            edv,
            dir: unit(30.0, true),
        })
        .collect();
    let iq = synthetic_iq(&vessels, (1, 40), 360, hr, 0.1, 11);
    let params = rat();
    let series = sliding_vectors(&images(&iq, &paper_angles(), FRAME_RATE, None), &params).unwrap();
    let median_ri = |harmonics| {
        let maps = ri_maps(
            &series,
            &DynamicsParams {
                harmonics,
                ..params
            },
        )
        .unwrap();
        let mut ri: Vec<f64> = maps.ri.iter().copied().collect();
        ri.sort_by(|a, b| a.total_cmp(b));
        ri[ri.len() / 2]
    };
    let raw = median_ri(Some(0));
    let fitted = median_ri(None);

    assert_eq!(dynamics::auto_harmonics(hr, series.window_s), 2);
    assert!(raw - 0.3 > 0.05, "raw extremes: RI {raw}");
    assert!((fitted - 0.3).abs() < 0.03, "harmonic fit: RI {fitted}");
}

#[test]
fn vessel_pooling_cuts_ri_jitter_without_mixing_opposite_flows() {
    // Window velocities of an arteriole (RI 0.7, flowing down at 20°) in rows 0–3 against a
    // venule (RI 0.3, flowing up at 20°) in rows 4–7, each row scaled by its own lumen-profile
    // factor, with independent Gaussian errors on Vx and Vz per pixel and window (σ = 1.5 mm/s,
    // as a 20 ms window gives at low SNR). Each pixel's RI jitters; the pool of a pixel's
    // same-direction neighbours (about 20 pixels within radius 3) should divide that spread by
    // about √20, and the two vessels, 140° apart in direction, must not leak into each other.
    let profile = [0.8, 0.9, 1.0, 0.85, 0.85, 0.95, 1.0, 0.8];
    let sigma = 3e-3;
    let rows: Vec<Row> = profile
        .iter()
        .enumerate()
        .map(|(iz, &scale)| {
            let artery = iz < 4;
            Row {
                psv: scale * if artery { 0.025 } else { 0.012 },
                edv: scale * if artery { 0.0075 } else { 0.0084 },
                dir: unit(20.0, !artery),
            }
        })
        .collect();
    let series = noisy_window_series(&rows, 24, sigma, 9);
    // The errors here are independent from window to window, which overlapping windows' are not:
    // the harmonics' noise debiasing, whose noise model is the windows' overlap, would take this
    // white noise for 4 times stronger at the harmonics and flatten the venule's weak pulse. This
    // test is the pooling's; the debiasing is tested on noise made as windows make it.
    let params = DynamicsParams {
        debias_harmonics: false,
        ..rat()
    };
    let maps = |pooling| ri_maps(&series, &DynamicsParams { pooling, ..params }).unwrap();
    let alone = maps(None);
    let pooling = VesselPooling::from_metres(0.15e-3, 0.15e-3, 30.0, 0.05e-3)
        .unwrap()
        .unwrap();
    assert!((pooling.along - 3.0).abs() < 1e-9 && (pooling.across - 3.0).abs() < 1e-9);
    let pooled = maps(Some(pooling));
    // Median and spread (median absolute deviation from the median) of a band's RI.
    let band_stats = |m: &dynamics::RiMaps, rows: std::ops::Range<usize>| {
        let mut ri: Vec<f64> = rows.flat_map(|iz| m.ri.row(iz).to_vec()).collect();
        ri.sort_by(|a, b| a.total_cmp(b));
        let median = ri[ri.len() / 2];
        let mut dev: Vec<f64> = ri.iter().map(|r| (r - median).abs()).collect();
        dev.sort_by(|a, b| a.total_cmp(b));
        (median, dev[dev.len() / 2])
    };
    // Pooling averages speeds, so it keeps the noise bias of |V|: the expected speed is the Rice
    // mean, and the RI it should read is that of the Rice means of PSV and EDV.
    let expected_ri = |iz: usize| {
        let (psv, edv) = if iz < 4 {
            (0.025, 0.0075)
        } else {
            (0.012, 0.0084)
        };
        1.0 - rice_mean(profile[iz] * edv, sigma) / rice_mean(profile[iz] * psv, sigma)
    };
    for (rows, truth) in [(0..4, 0.7), (4..8, 0.3)] {
        let mut expected: Vec<f64> = rows.clone().map(expected_ri).collect();
        expected.sort_by(|a, b| a.total_cmp(b));
        let expected = 0.5 * (expected[1] + expected[2]);
        assert!(
            (expected - truth).abs() < 0.05,
            "Rice bias {expected} vs {truth}"
        );
        let (median_alone, spread_alone) = band_stats(&alone, rows.clone());
        let (median_pooled, spread_pooled) = band_stats(&pooled, rows.clone());
        assert!(
            spread_alone > 0.02,
            "the case must be noisy: {spread_alone}"
        );
        assert!(
            spread_pooled < 0.4 * spread_alone,
            "rows {rows:?}: RI spread {spread_pooled} pooled vs {spread_alone} alone"
        );
        // Neighbouring pools overlap, so a band of 96 pixels holds about 5 independent pools: its
        // median RI is uncertain by about 0.01 at this noise.
        assert!(
            (median_pooled - expected).abs() < 0.03,
            "rows {rows:?}: median RI {median_pooled} (alone {median_alone}, Rice {expected})"
        );
    }
    for ((iz, ix), &class) in pooled.vessel_class.indexed_iter() {
        let want = if iz < 4 { ARTERIOLE } else { VENULE };
        assert_eq!(
            class,
            want,
            "pixel ({iz}, {ix}): RI {}",
            pooled.ri[[iz, ix]]
        );
    }
    // The rows that touch the other vessel read like the rows far from it: nothing leaks across.
    let row_median = |iz: usize| {
        let mut row: Vec<f64> = pooled.ri.row(iz).to_vec();
        row.sort_by(|a, b| a.total_cmp(b));
        row[row.len() / 2]
    };
    for (border, far) in [(3, 0), (4, 7)] {
        let (b, f) = (row_median(border), row_median(far));
        assert!(
            (b - f).abs() < 0.03,
            "border row {border}: median RI {b} vs {f} in row {far}"
        );
    }
    // PSV keeps each pixel's own scale: the pooled shape times the pixel's own mean speed.
    for iz in [0, 2, 5] {
        let psv = pooled.psv.row(iz).mean().unwrap();
        let want = rice_mean(profile[iz] * if iz < 4 { 0.025 } else { 0.012 }, sigma);
        assert!(
            (psv - want).abs() < 0.05 * want,
            "row {iz}: PSV {psv}, Rice {want}"
        );
    }

    // Bad settings are refused.
    let from_mm = |along: f64, across: f64, angle| {
        VesselPooling::from_metres(along * 1e-3, across * 1e-3, angle, 0.05e-3)
    };
    is_invalid(from_mm(-1.0, 0.3, 30.0), "half-length");
    is_invalid(from_mm(1.0, f64::NAN, 30.0), "half-width");
    is_invalid(from_mm(0.5, 0.3, 200.0), "0–180");
    assert_eq!(from_mm(0.01, 0.01, 30.0).unwrap(), None);
    let bad = |pooling| DynamicsParams {
        pooling: Some(pooling),
        ..params
    };
    let nan_angle = VesselPooling {
        along: 2.0,
        across: 2.0,
        max_angle: f64::NAN,
    };
    is_invalid(ri_maps(&series, &bad(nan_angle)), "vessel pooling");
    let negative = VesselPooling {
        along: -2.0,
        ..pooling
    };
    is_invalid(ri_maps(&series, &bad(negative)), "vessel pooling");
}

#[test]
fn vessel_pooling_follows_the_vessel_and_keeps_parallel_vessels_apart() {
    // An arteriole (RI 0.7, rows 0–2) and a venule (RI 0.3, rows 7–9), both flowing along +x
    // (the worst case for direction: same way, side by side), 4 rows of background between them,
    // with the window-velocity errors of the test above. An ellipse 8 pixels long down the flow
    // and 2 across pools each vessel over ~30 of its own pixels and never reaches the other one
    // (7 rows away); a disc of radius 8 reaches across and must mix them.
    let sigma = 3e-3;
    let artery = Row {
        psv: 0.025,
        edv: 0.0075,
        dir: unit(90.0, false),
    };
    let vein = Row {
        psv: 0.012,
        edv: 0.0084,
        dir: unit(90.0, false),
    };
    let still = Row {
        psv: 0.0,
        edv: 0.0,
        dir: unit(90.0, false),
    };
    let rows = [
        artery, artery, artery, still, still, still, still, vein, vein, vein,
    ];
    let mut series = noisy_window_series(&rows, 40, sigma, 21);
    for iz in 3..7 {
        series.power.slice_mut(ndarray::s![.., iz, ..]).fill(0.0);
    }
    let params = rat();
    let maps = |along, across| {
        let pooling = VesselPooling {
            along,
            across,
            max_angle: 30f64.to_radians(),
        };
        ri_maps(
            &series,
            &DynamicsParams {
                pooling: Some(pooling),
                ..params
            },
        )
        .unwrap()
    };
    let median_ri = |m: &dynamics::RiMaps, rows: std::ops::Range<usize>| {
        let mut ri: Vec<f64> = rows.flat_map(|iz| m.ri.row(iz).to_vec()).collect();
        ri.sort_by(|a, b| a.total_cmp(b));
        ri[ri.len() / 2]
    };
    let alone = ri_maps(&series, &params).unwrap();
    let ellipse = maps(8.0, 2.0);
    let disc = maps(8.0, 8.0);
    let rice_ri = |r: &Row| 1.0 - rice_mean(r.edv, sigma) / rice_mean(r.psv, sigma);
    for (rows, row, want) in [(0..3, artery, ARTERIOLE), (7..10, vein, VENULE)] {
        let expected = rice_ri(&row);
        let got = median_ri(&ellipse, rows.clone());
        assert!(
            (got - expected).abs() < 0.03,
            "rows {rows:?}: ellipse RI {got}, Rice {expected} (alone {})",
            median_ri(&alone, rows.clone())
        );
        for iz in rows.clone() {
            for ix in 0..40 {
                assert_eq!(ellipse.vessel_class[[iz, ix]], want, "pixel ({iz}, {ix})");
            }
        }
        let mixed = median_ri(&disc, rows.clone());
        assert!(
            (mixed - expected).abs() > 0.05,
            "rows {rows:?}: a disc should mix the two vessels, RI {mixed} vs {expected}"
        );
    }
}

/// One row of a synthetic vessel: peak and end-diastolic speeds (m/s) and the flow direction.
#[derive(Clone, Copy)]
struct Row {
    psv: f64,
    edv: f64,
    dir: (f64, f64),
}

/// Window velocities (37 windows of 36 frames, 9 apart, at 5.5 Hz) of `rows`, `nx` pixels each,
/// with independent Gaussian errors of `sigma` (m/s) on Vx and Vz per pixel and window, as a
/// 20 ms window gives at low SNR; unit power everywhere.
fn noisy_window_series(rows: &[Row], nx: usize, sigma: f64, seed: u64) -> VelocitySeries {
    let hr = 5.5;
    let (nz, nt) = (rows.len(), 37);
    let step_s = 9.0 / FRAME_RATE;
    let times_s: Vec<f64> = (0..nt).map(|i| (i as f64 + 2.0) * step_s).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut vx = Array3::<f64>::zeros((nt, nz, nx));
    let mut vz = Array3::<f64>::zeros((nt, nz, nx));
    for (((it, iz, _), x), z) in vx.indexed_iter_mut().zip(vz.iter_mut()) {
        let row = rows[iz];
        let vessel = Vessel {
            pixel: (iz, 0),
            psv: row.psv,
            edv: row.edv,
            dir: row.dir,
        };
        let (tx, tz) = vessel.velocity(times_s[it], hr);
        let ex: f64 = StandardNormal.sample(&mut rng);
        let ez: f64 = StandardNormal.sample(&mut rng);
        *x = tx + sigma * ex;
        *z = tz + sigma * ez;
    }
    VelocitySeries {
        times_s,
        vx,
        vz,
        power: Array3::from_elem((nt, nz, nx), 1.0),
        window_s: 36.0 / FRAME_RATE,
        step_s,
        axial_only: false,
    }
}

/// Mean of |v + n| (m/s) for a 2-D velocity v of magnitude `v` and Gaussian errors of standard
/// deviation `sigma` on each component (the Rice mean): σ√(π/2)·L½(−v²/2σ²).
fn rice_mean(v: f64, sigma: f64) -> f64 {
    // Modified Bessel functions I0, I1 by their power series (arguments here stay below 20).
    let bessel = |order: i32, x: f64| {
        let (mut term, mut sum) = (if order == 0 { 1.0 } else { x / 2.0 }, 0.0);
        for k in 0..200 {
            sum += term;
            let k = k as f64;
            term *= (x / 2.0).powi(2) / ((k + 1.0) * (k + 1.0 + order as f64));
        }
        sum
    };
    let x = -v * v / (2.0 * sigma * sigma);
    let laguerre_half =
        (x / 2.0).exp() * ((1.0 - x) * bessel(0, -x / 2.0) - x * bessel(1, -x / 2.0));
    sigma * (PI / 2.0).sqrt() * laguerre_half
}

/// The steepest rise (s) of one beat of `wave` before its systolic peak at `peak` (s): found on a
/// 1 µs grid of the analytic waveform, the truth the detected upstrokes are checked against.
fn analytic_upstroke(wave: &CardiacWaveform, peak: f64) -> f64 {
    let period = 1.0 / wave.heart_rate_hz;
    let h = 1e-6;
    (0..(period / 2.0 / h) as usize)
        .map(|i| peak - period / 2.0 + i as f64 * h)
        .max_by(|&a, &b| {
            let slope = |t: f64| wave.value(t + h) - wave.value(t - h);
            slope(a).total_cmp(&slope(b))
        })
        .unwrap()
}

#[test]
fn heart_rate_from_two_upstrokes_in_little_more_than_one_cycle() {
    // The network phantom's arteriolar waveform at 5.5 Hz, as the rat preset's 5 ms window series
    // sees it, over 1.3 cycles that hold two systolic upstrokes: too short for the
    // autocorrelation (≳ 1.5 cycles), long enough for the upstrokes.
    let wave = CardiacWaveform {
        heart_rate_hz: 5.5,
        ri: 0.65,
        delay_s: 0.06,
    };
    let dt = 0.005;
    let times: Vec<f64> = (0..48).map(|i| 0.01 + i as f64 * dt).collect();
    let v: Vec<f64> = times.iter().map(|&t| 0.02 * wave.value(t)).collect();
    assert!(estimate_heart_rate(&v, &times).is_err());
    let upstrokes = systolic_upstrokes(&v, &times).unwrap();
    assert_eq!(upstrokes.len(), 2, "{upstrokes:?}");
    for (k, &t) in upstrokes.iter().enumerate() {
        let truth = analytic_upstroke(&wave, wave.delay_s + k as f64 / wave.heart_rate_hz);
        assert!(
            (t - truth).abs() < 0.5e-3,
            "upstroke {t} s, truth {truth} s"
        );
    }
    let cycles = cardiac_cycles(&v, &times, None, None).unwrap();
    assert_eq!(cycles.source, CycleSource::Upstrokes);
    assert_eq!(cycles.ranges.len(), 1);
    assert!(
        (cycles.heart_rate_hz - 5.5).abs() / 5.5 < 0.01,
        "{} Hz",
        cycles.heart_rate_hz
    );
    // The same waveform over 1.1 cycles holds one upstroke: the error says so.
    let short = &v[..37];
    let message = cardiac_cycles(short, &times[..37], None, None)
        .unwrap_err()
        .to_string();
    assert!(
        message.contains("upstrokes found: 1") && message.contains("give the heart rate"),
        "{message}"
    );
    assert_eq!(message.matches("invalid recording").count(), 1, "{message}");
}

/// The window centres (s) and a pulsatile waveform at `heart_rate_hz` sampled at them, of the
/// windows of `window` frames `step` apart that `n_frames` frames at `frame_rate` (Hz) hold:
/// what the dynamics stage reads cycles from (counted here as windows fit, not by pcuvd).
fn windows_waveform(
    n_frames: usize,
    (window, step): (usize, usize),
    frame_rate: f64,
    heart_rate_hz: f64,
) -> (Vec<f64>, Vec<f64>) {
    let wave = CardiacWaveform {
        heart_rate_hz,
        ri: 0.65,
        delay_s: 0.01,
    };
    let times: Vec<f64> = (0..)
        .map(|k| k * step)
        .take_while(|start| start + window <= n_frames)
        .map(|start| (start as f64 + window as f64 / 2.0) / frame_rate)
        .collect();
    let v = times.iter().map(|&t| 0.02 * wave.value(t)).collect();
    (times, v)
}

#[test]
fn the_check_before_processing_refuses_what_the_stage_would() {
    // `check_recording` runs before a recording is processed; the cycles are found after. With
    // a heart rate given it must pass exactly the recordings whose windows hold a cycle.
    let frame_rate = 1000.0;
    let given = DynamicsParams {
        window: 20,
        step: 5,
        heart_rate_hz: Some(12.0),
        ..DynamicsParams::rat()
    };
    for n_frames in 20..260 {
        let (times, v) = windows_waveform(n_frames, (20, 5), frame_rate, 12.0);
        let stage = cardiac_cycles(&v, &times, Some(12.0), None);
        let check = given.check_recording(n_frames, frame_rate, false);
        assert_eq!(
            check.is_ok(),
            stage.is_ok(),
            "{n_frames} frames: check {check:?}, stage {:?}",
            stage.map(|c| c.ranges)
        );
    }
    // Without one, the heart rate comes from the data: the check must never refuse what the
    // data could give cycles from (a heart at the fastest rate searched, whose cycles fit the
    // shortest recordings), and refuses the recordings too short for any.
    let measured = DynamicsParams {
        heart_rate_hz: None,
        ..given
    };
    let fastest = dynamics::HEART_RATE_SEARCH_HZ.1;
    let (mut refused, mut first_found) = (0, None);
    for n_frames in 20..400 {
        let (times, v) = windows_waveform(n_frames, (20, 5), frame_rate, fastest);
        let stage = cardiac_cycles(&v, &times, None, None);
        let check = measured.check_recording(n_frames, frame_rate, false);
        if stage.is_ok() {
            first_found.get_or_insert(n_frames);
            assert!(check.is_ok(), "{n_frames} frames: {check:?}");
        }
        if let Err(e) = check {
            refused += 1;
            let reason = if times.len() < 2 {
                "at least 2 windows"
            } else {
                "give the heart rate"
            };
            assert!(e.to_string().contains(reason), "{n_frames} frames: {e}");
        }
    }
    // Refused: the recordings whose windows' centres span less than one 15 Hz cycle (66.7 ms:
    // up to 14 windows, 89 frames, here).
    assert_eq!(
        refused,
        90 - 20,
        "first cycles found at {first_found:?} frames"
    );
    // Cycle start times given: the waveform's own span is not the limit (their period may be).
    assert!(measured.check_recording(60, frame_rate, true).is_ok());
    let one_window = given.check_recording(24, frame_rate, false).unwrap_err();
    assert!(
        one_window.to_string().contains("at least 2 windows"),
        "{one_window}"
    );
}

/// A beat-to-beat waveform sampled at `times`: beat k starts at `starts[k]` (s) and lasts to the
/// next start, a raised cosine from `edv` up to `psvs[k]` at mid-beat and back (m/s).
fn beats(times: &[f64], starts: &[f64], psvs: &[f64], edv: f64) -> Vec<f64> {
    times
        .iter()
        .map(|&t| {
            let k = starts.windows(2).position(|w| w[0] <= t && t < w[1]);
            match k {
                Some(k) => {
                    let phase = (t - starts[k]) / (starts[k + 1] - starts[k]);
                    edv + (psvs[k] - edv) * 0.5 * (1.0 - (2.0 * PI * phase).cos())
                }
                None => edv,
            }
        })
        .collect()
}

#[test]
fn long_recordings_follow_the_beats_as_the_heart_rate_drifts() {
    // 2.4 s of a heart slowing from 6.4 to 4.8 Hz, sampled every 5 ms: one fixed period slides off
    // the beats; the upstrokes keep to them.
    let dt = 0.005;
    let times: Vec<f64> = (0..480).map(|i| i as f64 * dt).collect();
    let mut starts = vec![0.03];
    while *starts.last().unwrap() < 2.4 {
        let t = *starts.last().unwrap();
        let rate = 6.4 - 1.6 * t / 2.4;
        starts.push(t + (1.0 / rate / dt).round() * dt);
    }
    let psvs = vec![0.02; starts.len()];
    let v = beats(&times, &starts, &psvs, 0.008);
    let cycles = cardiac_cycles(&v, &times, None, None).unwrap();
    assert_eq!(cycles.source, CycleSource::Upstrokes);
    assert!(cycles.ranges.len() >= 10, "{:?}", cycles.ranges);
    for &(a, b) in &cycles.ranges {
        // Each cycle spans one beat: from just after a beat's start (the raised cosine rises
        // fastest a quarter beat in) to the same point of the next.
        let beat = starts.iter().rposition(|&s| s <= times[a]).unwrap();
        let quarter = |k: usize| starts[k] + 0.25 * (starts[k + 1] - starts[k]);
        assert!(
            (times[a] - quarter(beat)).abs() <= dt,
            "cycle starts at {} s",
            times[a]
        );
        assert!(
            (times[b] - quarter(beat + 1)).abs() <= dt,
            "cycle ends at {} s",
            times[b]
        );
    }
}

/// Windows in which no vessel pixel has a finite speed (noise alone, or too few angles reaching
/// the pixels) are bridged in the waveform the cycles are found on, so they cannot fail the RI
/// maps (they did: "non-finite value in waveform"); a series with no finite speed at all has no
/// flow to analyse, which a run notes rather than fails on.
#[test]
fn windows_without_a_finite_speed_cannot_fail_the_ri_maps() {
    let (f, step, psv, edv) = (6.0, 0.005, 0.021, 0.0065);
    let times: Vec<f64> = (0..120).map(|i| 0.01 + i as f64 * step).collect();
    let nt = times.len();
    let wave: Vec<f64> = times
        .iter()
        .map(|&t| edv + (psv - edv) * (2.0 * PI * f * t).sin().max(0.0).powi(3))
        .collect();
    let series = VelocitySeries {
        times_s: times.clone(),
        vx: Array3::zeros((nt, 1, 2)),
        vz: Array3::from_shape_fn((nt, 1, 2), |(k, _, _)| wave[k]),
        power: Array3::from_elem((nt, 1, 2), 1.0),
        window_s: 0.02,
        step_s: step,
        axial_only: false,
    };
    let params = DynamicsParams {
        heart_rate_hz: Some(f),
        ..DynamicsParams::rat()
    };
    let whole = ri_maps(&series, &params).unwrap();
    // Every pixel loses window 40 (mid-diastole), and one pixel windows 50–59 as well.
    let mut gaps = series.clone();
    gaps.vz.slice_mut(s![40, .., ..]).fill(f64::NAN);
    gaps.vz.slice_mut(s![50..60, .., 1]).fill(f64::NAN);
    let mask = Array2::from_elem((1, 2), true);
    let bridged = gaps.mean_speed(&mask).unwrap();
    assert!(
        (bridged[40] - (wave[39] + wave[41]) / 2.0).abs() < 1e-15,
        "{} vs the neighbours' {} {}",
        bridged[40],
        wave[39],
        wave[41]
    );
    assert_eq!(bridged[55], wave[55], "the other pixel's finite speed");
    let maps = ri_maps(&gaps, &params).unwrap();
    assert_eq!(maps.cycles, whole.cycles);
    // A pixel with a gap is read from its raw extremes (the harmonic fit needs every window),
    // without the fit's flattening of this spiky systole: both near the true RI.
    let truth = resistivity_index(psv, edv);
    for (name, ri) in [("whole", whole.ri[[0, 0]]), ("with gaps", maps.ri[[0, 0]])] {
        assert!((ri - truth).abs() < 0.07, "{name}: RI {ri}, true {truth}");
    }
    let none = VelocitySeries {
        vz: series.vz.mapv(|_| f64::NAN),
        ..series
    };
    assert!(matches!(ri_maps(&none, &params), Err(Error::NoFlow(_))));
}

#[test]
fn triggers_delimit_the_cycles_and_the_spread_measures_beat_to_beat_change() {
    // One vessel pixel whose systolic peak changes from beat to beat (PSV 20, 23, 18, 21 mm/s,
    // EDV 8 mm/s), beats of 36–40 windows (5.6–5.0 Hz) given as trigger times: per-cycle values
    // are exact for raised-cosine beats, so the means and spreads are those of the beats.
    let step = 0.005;
    let durations = [36.0, 40.0, 38.0, 36.0];
    let mut starts = vec![0.02];
    for d in durations {
        starts.push(starts.last().unwrap() + d * step);
    }
    let times: Vec<f64> = (0..170).map(|i| 0.01 + i as f64 * step).collect();
    let psvs = [0.020, 0.023, 0.018, 0.021];
    let speed = beats(&times, &starts, &psvs, 0.008);
    let nt = times.len();
    let series = VelocitySeries {
        times_s: times.clone(),
        vx: Array3::zeros((nt, 1, 1)),
        vz: Array3::from_shape_vec((nt, 1, 1), speed).unwrap(),
        power: Array3::from_elem((nt, 1, 1), 1.0),
        window_s: 0.02,
        step_s: step,
        axial_only: false,
    };
    let params = DynamicsParams {
        heart_rate_hz: None,
        ..DynamicsParams::rat()
    };
    let maps = ri_maps_triggered(&series, &params, None, Some(&starts)).unwrap();
    assert_eq!(maps.cycle_source, CycleSource::Triggers);
    assert_eq!(maps.cycles.len(), 4);
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let std = |v: &[f64]| {
        let m = mean(v);
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
    };
    let ris: Vec<f64> = psvs.iter().map(|p| resistivity_index(*p, 0.008)).collect();
    for (name, got, want) in [
        ("PSV", maps.psv[[0, 0]], mean(&psvs)),
        ("EDV", maps.edv[[0, 0]], 0.008),
        ("PSV spread", maps.psv_spread[[0, 0]], std(&psvs)),
        ("EDV spread", maps.edv_spread[[0, 0]], 0.0),
        ("RI spread", maps.ri_spread[[0, 0]], std(&ris)),
    ] {
        assert!((got - want).abs() < 1e-9, "{name}: {got}, expected {want}");
    }
    assert!((maps.heart_rate_hz - 1.0 / (37.0 * step)).abs() < 1e-9);
    // One cycle: no spread.
    let one = ri_maps_triggered(&series, &params, None, Some(&starts[..2])).unwrap();
    assert!(one.ri_spread[[0, 0]].is_nan());
    // Triggers that hold no complete cycle within the series, or run backwards, are refused.
    is_invalid(
        ri_maps_triggered(&series, &params, None, Some(&[5.0, 5.2])),
        "at least two are needed",
    );
    is_invalid(
        ri_maps_triggered(&series, &params, None, Some(&[0.3, 0.1])),
        "increasing order",
    );
}

/// The partial-volume correction reaches the dynamics windows: on a parabolic tube (0.7 v_N,
/// −20 dB, 8 angles), each window's vectors move from their cells' power centroids back to their
/// pixels, and their RMSE against the truth falls as the whole-recording maps' does (measured,
/// mean over the 32-frame windows: Vx 5.51 → 5.02, Vz 0.67 → 0.55 mm/s; the maps 4.24 → 3.69
/// and 0.59 → 0.48).
#[test]
fn partial_volume_correction_reaches_the_dynamics_windows() {
    use pcuvd::estimate::vector::{Estimator, VectorField};
    use pcuvd::evaluate::metrics;
    use pcuvd::form::decode::EventAlignment;
    use pcuvd::pipeline::{self, ProcessParams};
    use pcuvd::simulate::phantom::Phantom;

    let data = common::tube_recording(false, 64);
    let grid = Grid::new(-1.5e-3, 1.5e-3, 5e-3, 7e-3, 0.05e-3).unwrap();
    let processed = |partial_volume| {
        let params = ProcessParams {
            partial_volume,
            ..pcuvd::study::process_params(
                &grid,
                &data.acquisition,
                (1, 1),
                EventAlignment::MidFrame,
            )
        };
        pipeline::process(&data, &params, &|_, _, _| {}).unwrap()
    };
    let truth = common::tube().truth(&grid.x, &grid.z, 0.0);
    let out = processed(false);
    // Each window's RMSE, averaged over the windows (mm/s).
    let windows_error = |partial_volume| {
        let params = DynamicsParams {
            window: 32,
            step: 16,
            heart_rate_hz: None,
            estimator: Estimator::LeastSquares,
            kernel: (1, 1),
            partial_volume,
            ..DynamicsParams::rat()
        };
        let series = sliding_vectors(&out.filtered, &params).unwrap();
        let each: Vec<metrics::Rmse> = series
            .vx
            .outer_iter()
            .zip(series.vz.outer_iter())
            .map(|(vx, vz)| {
                let field = VectorField {
                    vx: vx.to_owned(),
                    vz: vz.to_owned(),
                };
                metrics::rmse(&field, &truth)
            })
            .collect();
        let mean =
            |f: fn(&metrics::Rmse) -> f64| each.iter().map(f).sum::<f64>() / each.len() as f64;
        (mean(|r| r.vx), mean(|r| r.vz))
    };
    let (plain, corrected) = (windows_error(false), windows_error(true));
    let maps =
        |out: &pipeline::ProcessOutput| metrics::rmse(out.maps.vector_ls.as_ref().unwrap(), &truth);
    let (maps_plain, maps_corrected) = (maps(&out), maps(&processed(true)));
    eprintln!(
        "windows Vx {:.2} -> {:.2}, Vz {:.2} -> {:.2} mm/s; whole-recording maps Vx {:.2} -> {:.2}, \
         Vz {:.2} -> {:.2} mm/s",
        plain.0,
        corrected.0,
        plain.1,
        corrected.1,
        maps_plain.vx,
        maps_corrected.vx,
        maps_plain.vz,
        maps_corrected.vz
    );
    assert!(
        corrected.0 < 0.95 * plain.0,
        "windows' Vx {plain:?} -> {corrected:?}"
    );
    assert!(
        corrected.1 < 0.9 * plain.1,
        "windows' Vz {plain:?} -> {corrected:?}"
    );
    assert!(maps_corrected.vz < 0.9 * maps_plain.vz);
}

/// A recording of about one beat holds no cycle from one trigger to the next (its windows start
/// after the first trigger): the triggers' period then sets the cycle, as a given heart rate
/// would, and the cycle found is that period long.
#[test]
fn triggers_too_far_apart_for_the_waveform_give_their_period() {
    let hr = 5.5;
    let dt = 0.002;
    // The windows of a 0.2 s recording: 9.7 to 189.7 ms.
    let times: Vec<f64> = (0..91).map(|i| 0.0097 + i as f64 * dt).collect();
    let signal: Vec<f64> = times
        .iter()
        .map(|t| 1.0 + 0.7 * (2.0 * PI * hr * (t - 0.05)).cos())
        .collect();
    let beats = [0.0, 1.0 / hr];
    let found = pcuvd::dynamics::cardiac_cycles(&signal, &times, None, Some(&beats)).unwrap();
    assert_eq!(found.source, CycleSource::TriggerPeriod);
    assert!((found.heart_rate_hz - hr).abs() < 1e-12);
    assert_eq!(found.ranges.len(), 1);
    let (start, end) = found.ranges[0];
    assert!(
        ((end - start) as f64 * dt - 1.0 / hr).abs() <= dt,
        "{:?}",
        found.ranges
    );
    // Triggers of another clock (none near the waveform) or one trigger say no period: still an
    // error that says why.
    let elsewhere = [5.0, 5.0 + 1.0 / hr];
    let far = pcuvd::dynamics::cardiac_cycles(&signal, &times, None, Some(&elsewhere));
    assert!(
        far.unwrap_err()
            .to_string()
            .contains("at least two are needed")
    );
    let one = pcuvd::dynamics::cardiac_cycles(&signal, &times, None, Some(&beats[..1]));
    assert!(one.unwrap_err().to_string().contains("trigger"));
}
