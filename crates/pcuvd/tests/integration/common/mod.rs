//! Recordings shared by the integration tests.
// Each test crate that includes this module uses a part of it.
#![allow(dead_code)]

use pcuvd::simulate::phantom::{FlowProfile, TubePhantom, TubeSpec};
use pcuvd::simulate::{NoiseSpec, SimParams, rat_params, simulate};
use pcuvd::{ChannelData, Probe};

/// A 48-element, 8-angle recording of [`tube`] (6 mm deep, 30 mm/s: 0.7 of the projection Nyquist
/// velocity at 1.8 kHz), `frames` frames, conventional or coded, noise −20 dB, seed 3; its
/// receive window covers 4–8 mm straight down.
pub fn tube_recording(coded: bool, frames: usize) -> ChannelData {
    let probe = Probe {
        n_elements: 48,
        ..Probe::l22_14vx()
    };
    // The rat acquisition's sequence, on a smaller probe and receive window, without attenuation.
    let sequence = rat_params(coded).unwrap().sequence;
    let mut params = SimParams::new(probe, sequence, 65e6, 1540.0, (4e-3, 8e-3)).unwrap();
    params.noise = Some(NoiseSpec::new(-20.0));
    params.seed = 3;
    simulate(&tube(), &params, frames, &|_, _| {}).unwrap()
}

/// A parabolic tube of radius 0.5 mm centred 6 mm deep, 20° below +x, peak 30 mm/s.
pub fn tube() -> TubePhantom {
    tube_at(0.03)
}

/// [`tube`] with a peak speed of `peak_speed` (m/s).
pub fn tube_at(peak_speed: f64) -> TubePhantom {
    TubePhantom::new(
        TubeSpec {
            centre: [0.0, 6e-3],
            angle: 20f64.to_radians(),
            length: 6e-3,
            radius: 0.5e-3,
            peak_speed,
            density: 300e6,
            profile: FlowProfile::Parabolic,
        },
        3,
    )
    .unwrap()
}
