//! Simulator → pipeline round trips against the known truth: a point beamforms back to its position,
//! and a translating block gives back the projection velocities, with their signs, in all four
//! directions of motion.

use num_complex::Complex64;
use pcuvd::beamform::{DasParams, beamform};
use pcuvd::decode::{EventAlignment, decode, decode_aligned};
use pcuvd::doppler::{
    AxialSampling, autocorrelation, axial_autocorrelation, loupas_velocity, velocity_scale,
};
use pcuvd::grid::Grid;
use pcuvd::phantom::{BlockPhantom, BlockSpec, Phantom, PointPhantom};
use pcuvd::simulate::{SimParams, simulate};
use pcuvd::{Coding, Hadamard, Probe, Sequence, TransmitCode, iq};

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
    let per_angle = match alignment {
        None => decode(&data).unwrap(),
        Some(alignment) => decode_aligned(&data, alignment).unwrap(),
    };
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
