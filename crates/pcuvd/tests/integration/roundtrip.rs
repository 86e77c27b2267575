//! Simulator → pipeline round trips against the known truth: a point beamforms back to its position,
//! and a translating block gives back the projection velocities, with their signs, in all four
//! directions of motion.

use num_complex::Complex64;
use pcuvd::core::grid::Grid;
use pcuvd::estimate::doppler::{
    AxialSampling, autocorrelation, axial_autocorrelation, loupas_velocity, velocity_scale,
};
use pcuvd::form::beamform::{DasParams, beamform};
use pcuvd::form::decode::{Decoder, EventAlignment};
use pcuvd::form::iq;
use pcuvd::simulate::phantom::{BlockPhantom, BlockSpec, Phantom, PointPhantom};
use pcuvd::simulate::{SimParams, simulate};
use pcuvd::{Coding, Hadamard, Probe, Sequence, TransmitCode};

fn params(angles_deg: &[f64], coding: Coding, n_elements: usize) -> SimParams {
    let probe = Probe {
        n_elements,
        ..Probe::l22_14vx()
    };
    let sequence = Sequence {
        angles: angles_deg.iter().map(|a| a.to_radians()).collect(),
        event_prf: 10e3,
        coding,
        pulse_cycles: 2.0,
        pulse: None,
    };
    let mut p = SimParams::new(probe, sequence, 65e6, 1540.0, (3e-3, 9e-3)).unwrap();
    p.attenuation_db_cm_mhz = 0.0;
    p
}

/// Per-angle IQ image series of a simulated acquisition on `grid`.
fn images(
    phantom: &dyn Phantom,
    p: &SimParams,
    frames: usize,
    grid: &Grid,
    f_number: f64,
) -> Vec<ndarray::Array3<num_complex::Complex32>> {
    images_aligned(phantom, p, frames, grid, f_number, None)
}

/// As [`images`], decoded with `alignment` (`None`: [`decode`]).
fn images_aligned(
    phantom: &dyn Phantom,
    p: &SimParams,
    frames: usize,
    grid: &Grid,
    f_number: f64,
    alignment: Option<EventAlignment>,
) -> Vec<ndarray::Array3<num_complex::Complex32>> {
    let data = simulate(phantom, p, frames, &|_, _| {}).unwrap();
    let alignment = alignment.unwrap_or(EventAlignment::Simultaneous);
    let per_angle = (Decoder::new(&data, alignment).unwrap())
        .decode(&data.samples)
        .unwrap();
    let acq = &data.acquisition;
    acq.sequence
        .angles
        .iter()
        .enumerate()
        .map(|(k, &angle)| {
            let ch = iq::demodulate(
                &per_angle,
                k,
                acq.t0,
                acq.sampling_frequency,
                acq.probe.center_frequency,
                None,
            )
            .unwrap();
            beamform(
                &ch,
                &acq.probe,
                angle,
                grid,
                &DasParams {
                    f_number,
                    ..DasParams::new(acq.sound_speed)
                },
            )
            .unwrap()
        })
        .collect()
}

#[test]
fn simulated_point_beamforms_back_to_its_position() {
    let point = (0.7e-3, 6.1e-3);
    let phantom = PointPhantom::single(point.0, point.1).unwrap();
    for coding in [
        Coding::Conventional,
        Coding::Hadamard { slot_delay: 1e-6 },
        Coding::Matrix(scrambled_code()),
    ] {
        let p = params(&[-15.0, -5.0, 5.0, 15.0], coding.clone(), 64);
        let lambda = p.probe.wavelength(p.sound_speed);
        let grid = Grid::new(
            point.0 - 0.6e-3,
            point.0 + 0.6e-3,
            point.1 - 0.6e-3,
            point.1 + 0.6e-3,
            lambda / 16.0,
        )
        .unwrap();
        for (k, image) in images(&phantom, &p, 1, &grid, 1.5).iter().enumerate() {
            let (mut best, mut at) = (0.0f32, (0, 0));
            for ((iz, ix, _), v) in image.indexed_iter() {
                if v.norm() > best {
                    best = v.norm();
                    at = (iz, ix);
                }
            }
            let err = (grid.x[at.1] - point.0).hypot(grid.z[at.0] - point.1);
            assert!(
                err < lambda / 4.0,
                "{coding:?}, angle {k}: error {:.3} λ",
                err / lambda
            );
        }
    }
}

/// Every projection within 3 % with the Loupas 2-D autocorrelation, which divides the lag-1 phase by
/// the mean RF frequency measured on the image itself, on three consecutive seeds. Measured (F# 3,
/// no attenuation): ratios 0.974–1.017 over seeds 1–3, 0.974–1.020 over seeds 1–12.
#[test]
fn translating_block_projections_within_three_percent() {
    for seed in 1..=3 {
        block_projections(seed, Estimator::Loupas, 0.03);
    }
}

/// The lag-1 estimator scaled by f_0 reads low: in a 2-D image of diffuse scatterers each echo
/// frequency f counts in proportion to its lateral beam width (∝ 1/f), so the image's mean frequency
/// is the harmonic mean of the echo spectrum, 0.969 f_0 here, and it varies ±2–3 % with the speckle.
/// Measured ratios 0.94–1.02 (seeds 1–12). What holds: the right sign everywhere, within 7 %.
#[test]
fn translating_block_gives_projection_velocities_in_all_four_directions() {
    block_projections(5, Estimator::Lag1, 0.07);
}

#[derive(Debug, Clone, Copy)]
enum Estimator {
    /// arg R(0, 1) scaled by f_0 (Kasai).
    Lag1,
    /// arg R(0, 1) scaled by the mean frequency from R(1, 0) (Loupas).
    Loupas,
}

/// What a manifest of version 2 can say and version 1 cannot: H_4 with its rows in another order
/// and two of them sign-flipped, fired with uneven slot starts (0.3, 1.1, 2.45, 3.2 µs).
fn scrambled_code() -> TransmitCode {
    let h = Hadamard::new(4).unwrap();
    let (order, signs) = ([2usize, 3, 1, 0], [1.0, -1.0, -1.0, 1.0]);
    TransmitCode {
        weights: (0..16)
            .map(|j| signs[j / 4] * h.get(order[j / 4], j % 4) as f64)
            .collect(),
        slot_starts: vec![0.3e-6, 1.1e-6, 2.45e-6, 3.2e-6],
    }
}

/// The [`scrambled_code`] acquisition simulated moving and decoded with the code's own matrix
/// after mid-frame alignment: the same projections, within the same 3 % (Loupas), as conventional
/// transmission. Measured ratios 0.975–1.022 (seeds 1–3). (A wrong row order or sign would swap
/// or negate angles; a wrong slot start moves the image, which the point test below catches.)
#[test]
#[ignore = "slow tier: cargo test -- --include-ignored"]
fn explicit_code_with_uneven_slots_gives_the_projection_velocities() {
    let code = scrambled_code();
    for seed in 1..=3 {
        block_projections_with(
            seed,
            Estimator::Loupas,
            0.03,
            &[-12.0, -4.0, 4.0, 12.0],
            Coding::Matrix(code.clone()),
        );
    }
}

fn block_projections(seed: u64, estimator: Estimator, tolerance: f64) {
    block_projections_with(
        seed,
        estimator,
        tolerance,
        &[-12.0, 0.0, 12.0],
        Coding::Conventional,
    );
}

fn block_projections_with(
    seed: u64,
    estimator: Estimator,
    tolerance: f64,
    angles: &[f64],
    coding: Coding,
) {
    let coded = !matches!(coding, Coding::Conventional);
    let p = params(angles, coding, 64);
    let frames = if coded { 20 } else { 12 };
    let grid = Grid::new(-0.8e-3, 0.8e-3, 5.4e-3, 6.6e-3, 0.05e-3).unwrap();
    let (c, frame_rate, f0) = (
        p.sound_speed,
        p.sequence.frame_rate(),
        p.probe.center_frequency,
    );
    let scale = velocity_scale(c, frame_rate, f0).unwrap();
    for velocity in [
        [0.012, 0.008],
        [-0.012, 0.008],
        [0.012, -0.008],
        [-0.012, -0.008],
    ] {
        let block = BlockPhantom::new(
            BlockSpec {
                x: (-2e-3, 2e-3),
                z: (4.5e-3, 7.5e-3),
                velocity,
                density: 200e6,
            },
            seed,
        )
        .unwrap();
        // The model 2·V_θ = Vx·sin θ + Vz·(cos θ + 1) assumes a straight receive path; a receive
        // aperture of half-angle φ scales the receive part by the mean cos φ (≈ 0.98 at F# 1.5,
        // which alone takes 2 % off). F# 3 keeps the model error well inside the 3 % tolerance.
        let alignment = coded.then_some(EventAlignment::MidFrame);
        let series = images_aligned(&block, &p, frames, &grid, 3.0, alignment);
        for (k, image) in series.iter().enumerate() {
            // Aligned decoding extrapolates the first and last frames: left out.
            let image = if coded {
                image.slice(ndarray::s![.., .., 3..frames - 3]).to_owned()
            } else {
                image.clone()
            };
            // Autocorrelations summed over the block's interior: one robust phase per angle.
            let ac = autocorrelation(image.view(), (1, 1)).unwrap();
            let r: Complex64 = ac.r1.iter().sum();
            let theta = angles[k].to_radians();
            let measured = match estimator {
                Estimator::Lag1 => -scale * r.arg(),
                Estimator::Loupas => {
                    let ra: Complex64 = axial_autocorrelation(image.view(), (1, 1))
                        .unwrap()
                        .iter()
                        .sum();
                    let axial = AxialSampling::new(grid.z[1] - grid.z[0], theta, c, f0).unwrap();
                    loupas_velocity(r, ra, c, frame_rate, &axial)
                }
            };
            let expected = 0.5 * (velocity[0] * theta.sin() + velocity[1] * (theta.cos() + 1.0));
            assert!(
                (measured - expected).abs() < tolerance * expected.abs(),
                "seed {seed}, {estimator:?}, v = {velocity:?}, angle {}°: V_θ {measured:.5} m/s, \
                 expected {expected:.5} (ratio {:.4})",
                angles[k],
                measured / expected
            );
        }
    }
}

/// A probe, its receive aperture and the block of one round trip.
#[derive(Clone, Copy)]
struct BlockCase {
    depth: f64,
    speed: f64,
    /// Flow direction (degrees) from +z (deeper) toward +x.
    direction_deg: f64,
    /// Element pitch (m): the L22-14vX's 0.1 mm, or half of it.
    pitch: f64,
    /// Receive f-number of the beamformer (depth / aperture width).
    f_number: f64,
}

/// What the pipeline read from one translating block: per-angle projection error (region mean
/// minus truth, as a fraction of the speed) and the region-mean vector's speed error (fraction)
/// and direction error (degrees).
struct BlockReading {
    /// The image's mean RF frequency over f_c (median over the region, the angle nearest 0°).
    mean_frequency_ratio: f64,
    projection_errors: Vec<f64>,
    speed_error: f64,
    direction_error_deg: f64,
}

/// A noiseless block translating through the whole pipeline (simulate, IQ, beamform, Doppler,
/// least-squares vector), 8 angles in [−15°, 15°] at 14.4 kHz (the paper's sequence), 32 frames,
/// read on a λ/4 grid over a 4.0 × 1.6 mm region (lateral × depth) inside the block;
/// `attenuation` in dB/cm/MHz (0: none). The region is that large because a region mean is
/// still a speckle estimate: over 1.6 × 0.8 mm the per-angle errors of seeds 1–5 changed sign
/// from seed to seed by up to ±1.5 % of the speed (F# 1.0) and the direction by ±1.1° at 5 mm/s
/// (F# 1.5), which the bias targets would read as bias.
///
/// The recording does not depend on the case's f-number or on the estimator: it is simulated
/// once and read by as many processings as a test needs.
struct SimulatedBlock {
    params: SimParams,
    data: pcuvd::ChannelData,
    /// The true velocity (vx, vz), m/s.
    velocity: [f64; 2],
}

impl SimulatedBlock {
    /// The block of `case` (its f-number aside) with `attenuation` (dB/cm/MHz) and `seed`: 32
    /// conventional frames.
    fn new(case: &BlockCase, attenuation: f64, seed: u64) -> Self {
        Self::recorded(case, Coding::Conventional, 32, attenuation, seed)
    }

    /// The block of `case` (its f-number aside), `frames` frames transmitted with `coding`.
    fn recorded(
        case: &BlockCase,
        coding: Coding,
        frames: usize,
        attenuation: f64,
        seed: u64,
    ) -> Self {
        let BlockCase {
            depth,
            speed,
            direction_deg,
            pitch,
            f_number: _,
        } = *case;
        let direction = direction_deg.to_radians();
        let velocity = [speed * direction.sin(), speed * direction.cos()];
        let probe = Probe {
            n_elements: (12.8e-3 / pitch).round() as usize,
            pitch,
            element_width: 0.8 * pitch,
            ..Probe::l22_14vx()
        };
        let sequence = Sequence {
            angles: Sequence::evenly_spaced_angles(8, 15f64.to_radians()),
            event_prf: 14.4e3,
            coding,
            pulse_cycles: 2.0,
            pulse: None,
        };
        let mut params = SimParams::new(
            probe,
            sequence,
            65e6,
            1540.0,
            (depth - 1.5e-3, depth + 1.5e-3),
        )
        .unwrap();
        params.attenuation_db_cm_mhz = attenuation;
        let travel = speed * frames as f64 / params.sequence.frame_rate();
        let block = BlockPhantom::new(
            BlockSpec {
                x: (-2.5e-3 - travel, 2.5e-3 + travel),
                z: (depth - 1.2e-3 - travel, depth + 1.2e-3 + travel),
                velocity,
                density: 300e6,
            },
            seed,
        )
        .unwrap();
        let data = simulate(&block, &params, frames, &|_, _| {}).unwrap();
        SimulatedBlock {
            params,
            data,
            velocity,
        }
    }

    /// The recording processed at the case's depth and f-number with `estimator`: the grid and
    /// the pipeline's output.
    fn processed(
        &self,
        case: &BlockCase,
        estimator: pcuvd::estimate::doppler::DopplerEstimator,
    ) -> (Grid, pcuvd::pipeline::ProcessOutput) {
        use pcuvd::pipeline;
        let depth = case.depth;
        let grid = Grid::new(-2.0e-3, 2.0e-3, depth - 0.8e-3, depth + 0.8e-3, 25e-6).unwrap();
        let defaults = pcuvd::study::process_params(
            &grid,
            &self.data.acquisition,
            (1, 1),
            pcuvd::form::decode::EventAlignment::MidFrame,
        );
        let params = pipeline::ProcessParams {
            doppler_estimator: estimator,
            das: DasParams {
                f_number: case.f_number,
                ..defaults.das
            },
            ..defaults
        };
        let out = pipeline::process(&self.data, &params, &|_, _, _| {}).unwrap();
        (grid, out)
    }

    /// What the pipeline read, processed as [`Self::processed`].
    fn reading(
        &self,
        case: &BlockCase,
        estimator: pcuvd::estimate::doppler::DopplerEstimator,
    ) -> BlockReading {
        let (grid, out) = self.processed(case, estimator);
        let (p, velocity) = (&self.params, self.velocity);
        let speed = case.speed;
        let direction = case.direction_deg.to_radians();
        let mean = |m: ndarray::ArrayView2<f64>| m.iter().sum::<f64>() / m.len() as f64;
        let projection_errors = p
            .sequence
            .angles
            .iter()
            .enumerate()
            .map(|(k, &theta)| {
                let (s, c) = pcuvd::estimate::vector::projection_weights(theta);
                let truth = 0.5 * (velocity[0] * s + velocity[1] * c);
                (mean(out.maps.projections.index_axis(ndarray::Axis(0), k)) - truth) / speed
            })
            .collect();
        let k0 = p.sequence.angles.len() / 2;
        let fc = p.probe.center_frequency;
        let maps = pcuvd::estimate::doppler::doppler_maps(
            out.filtered.series[k0].view(),
            (1, 1),
            pcuvd::estimate::doppler::DopplerEstimator::Loupas,
            &angle_geometry(p, &grid, k0),
        )
        .unwrap();
        let mean_frequency_ratio =
            pcuvd::core::stats::median(maps.mean_frequency.iter().copied().collect()) / fc;
        let field = out.maps.vector_ls.unwrap();
        let (vx, vz) = (mean(field.vx.view()), mean(field.vz.view()));
        let turn = (vx.atan2(vz) - direction + std::f64::consts::PI)
            .rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        BlockReading {
            mean_frequency_ratio,
            projection_errors,
            speed_error: vx.hypot(vz) / speed - 1.0,
            direction_error_deg: turn.to_degrees(),
        }
    }
}

/// The Doppler geometry of angle `k`'s image on `grid`.
fn angle_geometry(
    p: &SimParams,
    grid: &Grid,
    k: usize,
) -> pcuvd::estimate::doppler::DopplerGeometry {
    let (lateral_weight, axial_weight) =
        pcuvd::estimate::vector::projection_weights(p.sequence.angles[k]);
    pcuvd::estimate::doppler::DopplerGeometry {
        sound_speed: p.sound_speed,
        frame_rate: p.sequence.frame_rate(),
        demodulation_frequency: p.probe.center_frequency,
        axial_step: grid.axial_step(),
        axial_weight,
        lateral_step: grid.step(),
        lateral_weight,
    }
}

/// Fast flow: a noiseless block at 3× the projection Nyquist velocity (133 mm/s, 30° from +z
/// toward +x, 7 mm deep, the L22-14vX, 8 angles, 32 frames, a λ/4 grid), its phase unwrapped with
/// the true alias count. The speckle moves 0.75 λ a frame, and the frequency that turns the
/// Doppler phase into velocity is the secant of the phase over that lag, not the spectrum's
/// centroid (`doppler::SAME_FRAME_WEIGHT`). Per angle, median over the pixels of the projection
/// error as a fraction of the speed, with the default mean frequency (the 2:1 mix), the axial lag
/// within each frame alone and the pair at temporal lags ±1 alone. Measured (seed 1, no
/// attenuation, F# 1.5): the mix within 0.36 % at every angle (the accuracy issue's 1 % target); within
/// frames alone up to 0.66 % off, the ±1 pair alone up to 0.97 %, the two on opposite sides of the
/// truth at 7 of the 8 angles (the skew's sign differs between angles).
#[test]
#[ignore = "slow tier: cargo test -- --include-ignored"]
fn fast_block_projections_need_the_mixed_spatial_lag() {
    use pcuvd::estimate::doppler::{
        DopplerEstimator, axial_autocorrelation_lag1, doppler_maps, mean_frequency_kernel,
    };
    let v_n = 1540.0 * 1800.0 / (4.0 * 15.625e6);
    let case = BlockCase {
        depth: 7e-3,
        speed: 3.0 * v_n,
        direction_deg: 30.0,
        pitch: 0.1e-3,
        // Where the figures above were measured: the wider default aperture averages each
        // pixel over more directions, and the two single lags' skews with it (at F# 1.0 the ±1
        // pair alone reads 1.9 times the mix's worst error instead of over 2).
        f_number: 1.5,
    };
    let block = SimulatedBlock::new(&case, 0.0, 1);
    let (grid, out) = block.processed(&case, DopplerEstimator::Loupas);
    let (p, velocity) = (&block.params, block.velocity);
    let (c, frame_rate) = (p.sound_speed, p.sequence.frame_rate());
    let mut worst = [0.0f64; 3];
    for (k, &theta) in p.sequence.angles.iter().enumerate() {
        let (s, cz) = pcuvd::estimate::vector::projection_weights(theta);
        let truth = 0.5 * (velocity[0] * s + velocity[1] * cz);
        let series = out.filtered.series[k].view();
        let geometry = angle_geometry(p, &grid, k);
        let maps = doppler_maps(series, (1, 1), DopplerEstimator::Loupas, &geometry).unwrap();
        let wide = mean_frequency_kernel((1, 1));
        let r1_wide = autocorrelation(series, wide).unwrap().r1;
        let same = axial_autocorrelation(series, wide).unwrap();
        let turned = axial_autocorrelation_lag1(series, &r1_wide, wide).unwrap();
        let axial =
            AxialSampling::new(grid.axial_step(), theta, c, geometry.demodulation_frequency)
                .unwrap();
        let error = |f: &dyn Fn((usize, usize)) -> f64| {
            let errors: Vec<f64> = maps
                .r1
                .indexed_iter()
                .map(|(px, r)| {
                    let scale = c * frame_rate / (4.0 * std::f64::consts::PI * f(px));
                    let turns = ((-truth / scale - r.arg()) / std::f64::consts::TAU).round();
                    (-scale * (r.arg() + turns * std::f64::consts::TAU) - truth) / case.speed
                })
                .collect();
            pcuvd::core::stats::median(errors)
        };
        let readings = [
            error(&|px| maps.mean_frequency[px]),
            error(&|px| axial.mean_frequency(same[px])),
            error(&|px| axial.mean_frequency(turned[px])),
        ];
        eprintln!(
            "angle {:+5.1}°: mix {:+.4}, within frames {:+.4}, ±1 {:+.4}",
            theta.to_degrees(),
            readings[0],
            readings[1],
            readings[2]
        );
        for (i, e) in readings.iter().enumerate() {
            worst[i] = worst[i].max(e.abs());
        }
    }
    assert!(worst[0] < 0.01, "mix: worst {:.4}", worst[0]);
    assert!(
        worst[1] > 1.5 * worst[0] && worst[2] > 2.0 * worst[0],
        "worst of the mix, within frames, ±1: {worst:?}"
    );
}

/// The bias target of the accuracy issue: a noiseless uniform translation, depths 2–12 mm,
/// speeds 5–40 mm/s, every direction quadrant, read by the default estimator (Loupas with
/// measured lateral weights): every per-angle projection within 1 % (of the speed, so that
/// near-zero projections of flow across an angle's Doppler direction are held to the same
/// absolute standard) and the vector within 1 % in speed and 1° in direction; at the default
/// receive F# 1.5 and at F# 1.0, whose wider aperture spreads each angle's receive directions
/// more (its mean direction stays straight down, so the paper's projection model still holds).
///
/// Measured (seed 1): F# 1.5 per-angle errors ≤ 0.49 % of the speed, vectors within 0.28 % and
/// 0.28°; F# 1.0 ≤ 0.78 %, 0.38 % and 0.17°. Over seeds 1–5: F# 1.5 ≤ 0.49 %, 0.48 %, 0.44°;
/// F# 1.0 ≤ 0.78 %, 0.74 %, 0.35°, errors changing sign from seed to seed. Kasai (the nominal
/// frequency) on the same data reads every projection 2–6 % low and vectors up to 9 % and 3°
/// off. At 2 and 4 mm the cases use a probe of half the L22-14vX's pitch: the
/// real probe's pitch is about λ, so its receive grating lobes, 42–90° off each pixel, see the
/// block's scatterers that lie more than ~0.9 × the depth to the side, whose Doppler is that of
/// another direction. With the L22-14vX the 2 mm block reads 1.5 % low (axial flow) and the 4 mm
/// one 2.3 % fast (oblique flow); from 7 mm on the block lies inside the lobe-free cone.
#[test]
#[ignore = "slow tier: cargo test -- --include-ignored"]
fn translating_block_reads_projections_and_vector_within_one_percent() {
    use pcuvd::estimate::doppler::DopplerEstimator;
    let l22 = 0.1e-3;
    let cases = [
        BlockCase {
            depth: 2e-3,
            speed: 0.005,
            direction_deg: 0.0,
            pitch: 0.05e-3,
            f_number: DasParams::DEFAULT_F_NUMBER,
        },
        BlockCase {
            depth: 4e-3,
            speed: 0.02,
            direction_deg: 60.0,
            pitch: 0.05e-3,
            f_number: DasParams::DEFAULT_F_NUMBER,
        },
        BlockCase {
            depth: 7e-3,
            speed: 0.04,
            direction_deg: 45.0,
            pitch: l22,
            f_number: DasParams::DEFAULT_F_NUMBER,
        },
        BlockCase {
            depth: 7e-3,
            speed: 0.02,
            direction_deg: 135.0,
            pitch: l22,
            f_number: DasParams::DEFAULT_F_NUMBER,
        },
        BlockCase {
            depth: 12e-3,
            speed: 0.02,
            direction_deg: -80.0,
            pitch: l22,
            f_number: DasParams::DEFAULT_F_NUMBER,
        },
        BlockCase {
            depth: 12e-3,
            speed: 0.005,
            direction_deg: 180.0,
            pitch: l22,
            f_number: DasParams::DEFAULT_F_NUMBER,
        },
    ];
    let mut kasai_worst = 0.0f64;
    let wider = cases.map(|case| BlockCase {
        f_number: 1.0,
        ..case
    });
    // Each case's recording once, read at both f-numbers.
    let blocks = cases.map(|case| SimulatedBlock::new(&case, 0.0, 1));
    for (case, block) in cases.iter().chain(&wider).zip(blocks.iter().chain(&blocks)) {
        let r = block.reading(case, DopplerEstimator::Loupas);
        let worst = r
            .projection_errors
            .iter()
            .map(|e| e.abs())
            .fold(0.0, f64::max);
        eprintln!(
            "F# {:.1}, depth {:4.1} mm, {:4.1} mm/s at {:6.1}°: worst projection error {:5.2} % of the speed, speed {:+5.2} %, direction {:+5.2}°",
            case.f_number,
            case.depth * 1e3,
            case.speed * 1e3,
            case.direction_deg,
            worst * 100.0,
            r.speed_error * 100.0,
            r.direction_error_deg
        );
        assert!(
            worst < 0.01,
            "projection error {:.2} % of the speed",
            worst * 100.0
        );
        assert!(
            r.speed_error.abs() < 0.01,
            "speed error {:.2} %",
            r.speed_error * 100.0
        );
        assert!(
            r.direction_error_deg.abs() < 1.0,
            "direction error {:.2}°",
            r.direction_error_deg
        );
        if case.direction_deg == 0.0 && case.f_number == DasParams::DEFAULT_F_NUMBER {
            let k = block.reading(case, DopplerEstimator::Kasai);
            kasai_worst = k
                .projection_errors
                .iter()
                .map(|e| e.abs())
                .fold(0.0, f64::max);
        }
    }
    // The nominal frequency misses the same target: the image's mean frequency is ≈ 0.97 f_0.
    eprintln!(
        "Kasai, axial flow at 2 mm: worst projection error {:.2} % of the speed",
        kasai_worst * 100.0
    );
    assert!(
        kasai_worst > 0.02,
        "Kasai worst projection error {:.2} %",
        kasai_worst * 100.0
    );
}

/// Frequency-dependent attenuation (the simulator's default, 0.5 dB/cm/MHz) lowers the echo
/// spectrum with depth: at 6 mm the received echo's mean frequency is 6.2 % below f_c
/// (`tests/integration/simulate.rs`) and the image's, where each frequency also counts by its beam width
/// (∝ 1/f), about 10 % below (median over the read region, 5.2–6.8 mm). The default estimator (Loupas) still reads every projection and the
/// vector within 1 % and 1°; the nominal frequency (Kasai) does not. Measured (seed 1): image
/// mean frequency 0.896 f_c; Loupas worst projection error 0.17 % of the speed, speed −0.28 %,
/// direction −0.30°; Kasai worst 9.6 %.
#[test]
#[ignore = "slow tier: cargo test -- --include-ignored"]
fn attenuated_block_reads_within_one_percent_where_the_spectrum_has_moved() {
    use pcuvd::estimate::doppler::DopplerEstimator;
    let case = BlockCase {
        depth: 6e-3,
        speed: 0.02,
        direction_deg: 30.0,
        pitch: 0.1e-3,
        f_number: DasParams::DEFAULT_F_NUMBER,
    };
    let attenuation = SimParams::DEFAULT_ATTENUATION;
    let block = SimulatedBlock::new(&case, attenuation, 1);
    let r = block.reading(&case, DopplerEstimator::Loupas);
    let worst = r
        .projection_errors
        .iter()
        .map(|e| e.abs())
        .fold(0.0, f64::max);
    eprintln!(
        "image mean frequency {:.3} f_c; Loupas: worst projection error {:.2} % of the speed, speed {:+.2} %, direction {:+.2}°",
        r.mean_frequency_ratio,
        worst * 100.0,
        r.speed_error * 100.0,
        r.direction_error_deg
    );
    // The premise: the image's spectrum has moved well below the nominal frequency.
    assert!(
        (0.80..0.92).contains(&r.mean_frequency_ratio),
        "image mean frequency {:.3} f_c",
        r.mean_frequency_ratio
    );
    assert!(
        worst < 0.01,
        "projection error {:.2} % of the speed",
        worst * 100.0
    );
    assert!(
        r.speed_error.abs() < 0.01,
        "speed error {:.2} %",
        r.speed_error * 100.0
    );
    assert!(
        r.direction_error_deg.abs() < 1.0,
        "direction error {:.2}°",
        r.direction_error_deg
    );
    let k = block.reading(&case, DopplerEstimator::Kasai);
    let kasai_worst = k
        .projection_errors
        .iter()
        .map(|e| e.abs())
        .fold(0.0, f64::max);
    eprintln!(
        "Kasai: worst projection error {:.2} % of the speed",
        kasai_worst * 100.0
    );
    assert!(
        kasai_worst > 0.05,
        "Kasai worst {:.2} %",
        kasai_worst * 100.0
    );
}

/// Per-angle projections (m/s, region means) that the pipeline reads from one noiseless block
/// translating at 25 mm/s, 20° from +z, at 7 mm, recorded over `frames` frames with `coding`
/// (8 angles in [−15°, 15°] at 14.4 kHz, the same scatterers for every coding), the coded one
/// decoded with mid-frame event alignment.
fn block_projections_coded(frames: usize, coding: Coding, seed: u64) -> Vec<f64> {
    use pcuvd::pipeline;
    let case = BlockCase {
        depth: 7e-3,
        speed: 0.025,
        direction_deg: 20.0,
        pitch: 0.1e-3,
        f_number: DasParams::DEFAULT_F_NUMBER,
    };
    let depth = case.depth;
    let data = SimulatedBlock::recorded(&case, coding, frames, 0.0, seed).data;
    let grid = Grid::new(-0.8e-3, 0.8e-3, depth - 0.4e-3, depth + 0.4e-3, 25e-6).unwrap();
    let params = pcuvd::study::process_params(
        &grid,
        &data.acquisition,
        (1, 1),
        pcuvd::form::decode::EventAlignment::MidFrame,
    );
    let out = pipeline::process(&data, &params, &|_, _, _| {}).unwrap();
    out.maps
        .projections
        .outer_iter()
        .map(|m| m.iter().sum::<f64>() / m.len() as f64)
        .collect()
}

/// Decoded projections of a coded recording against the conventional recording of the same
/// scatterers: the mid-frame alignment interpolates each event's slow-time series over ±12
/// frames and continues it beyond the recording's ends by linear prediction (an order-4 model,
/// fewer on short series: order ⌊(frames − 2)/2⌋), so every angle's projection is within 1 % of
/// the conventional one from 4 frames on. With 3 frames or fewer no predictor can be fitted, the
/// series is held at its end values, and the projections are off by several percent.
///
/// Measured (seed 1, worst angle, decoded / conventional − 1): +13.5 %, +0.49 %, −0.44 %,
/// −0.14 % and −0.01 % at 3, 4, 6, 12 and 32 frames (the test prints them); the FFT over the
/// mirror-extended series used before read −3.3 % and −1.5 % at 6 and 12 frames.
#[test]
#[ignore = "slow tier: cargo test -- --include-ignored"]
fn decoded_projections_match_conventional_from_twelve_frames() {
    for frames in [3usize, 4, 6, 12, 32] {
        let coded = block_projections_coded(frames, Coding::Hadamard { slot_delay: 1e-6 }, 1);
        let conventional = block_projections_coded(frames, Coding::Conventional, 1);
        let worst = coded
            .iter()
            .zip(&conventional)
            .map(|(a, b)| a / b - 1.0)
            .fold(0.0f64, |w, e| if e.abs() > w.abs() { e } else { w });
        eprintln!(
            "{frames} frames: worst decoded / conventional − 1 = {:+.2} % (conventional {:?} mm/s)",
            worst * 100.0,
            conventional
                .iter()
                .map(|v| (v * 1e4).round() / 10.0)
                .collect::<Vec<_>>()
        );
        if frames >= 4 {
            assert!(
                worst.abs() < 0.01,
                "{frames} frames: decoded projections {:.2} % off the conventional ones",
                worst * 100.0
            );
        }
    }
}
