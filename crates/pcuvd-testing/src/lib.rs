//! The scenarios the workspace's tests share, written once: a small simulated tube recording
//! and the real rotating-disk recording that lives beside the repository; and what "the same
//! map" means where NaN marks pixels without a value. A dev-dependency only
//! (a crate of its own rather than a feature of `pcuvd`, so that the library the tests, the
//! command and the Python wheel link is built once with one set of features).
#![warn(missing_docs)]

use std::path::PathBuf;

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

/// The real rotating-disk recording (`PWI_disk.mat`: Verasonics, 32 unsteered plane waves),
/// which lives beside the repository (`shared/data/`), not in it. Missing, the calling test
/// fails: a real-data test that passes without its data would hide that it never ran.
pub fn disk_recording() -> PathBuf {
    let path = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/PWI_disk.mat"
    ));
    assert!(
        path.exists(),
        "the real rotating-disk recording PWI_disk.mat is missing: expected at {} \
         (shared/data/ beside the repository; see shared/data/README.md for its source)",
        path.display()
    );
    path
}

/// Whether two maps are the same bit for bit: the same shape, and each value's bits (a NaN where
/// the other has the same NaN, which `==` would call different).
pub fn same_bits<D: ndarray::Dimension>(
    a: &ndarray::Array<f64, D>,
    b: &ndarray::Array<f64, D>,
) -> bool {
    a.shape() == b.shape() && a.iter().zip(b).all(|(p, q)| p.to_bits() == q.to_bits())
}
