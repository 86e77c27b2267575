//! Simulates the small steered recording that `tests/fixtures/readers/make_reader_fixtures.py`
//! writes into each file format (MUST, UFF, zea): a rotating disk seen by a 32-element, 5 MHz
//! linear array with three conventional plane waves (−10°, 0°, +10°), 6 compound frames, no noise.
//!
//! `cargo run -p pcuvd-io --example steered_fixture -- OUT_DIR` writes `OUT_DIR/steered.toml` and
//! `OUT_DIR/steered.npy` (frames, angles, channels, samples), float32.
//!
//! Beside it, for the decoded-Hadamard zea fixtures, the same disk seen twice more:
//! `coded.{toml,npy}`, four plane waves (−9°, −3°, 3°, 9°) Hadamard-coded with 1 µs slots at an
//! 8 kHz event PRF, 12 frames; and `bmode.{toml,npy}`, one conventional 0° plane wave, 4 frames.

use std::path::PathBuf;

use pcuvd::simulate::phantom::rigid::{DiskPhantom, DiskSpec};
use pcuvd::simulate::{SimParams, simulate};
use pcuvd::{Coding, Probe, Sequence};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out: PathBuf = std::env::args_os()
        .nth(1)
        .ok_or("usage: steered_fixture OUT_DIR")?
        .into();
    let probe = Probe {
        name: "steered-fixture".into(),
        n_elements: 32,
        pitch: 3e-4,
        element_width: 2.5e-4,
        center_frequency: 5e6,
        bandwidth: 0.6,
    };
    let sequence = Sequence {
        angles: [-10.0f64, 0.0, 10.0]
            .iter()
            .map(|a| a.to_radians())
            .collect(),
        event_prf: 6000.0,
        coding: Coding::Conventional,
        pulse_cycles: 2.0,
        pulse: None,
    };
    let mut params = SimParams::new(probe.clone(), sequence, 20e6, 1540.0, (8e-3, 16e-3))?;
    params.seed = 7;
    let disk = DiskPhantom::new(
        DiskSpec {
            centre: [0.0, 12e-3],
            radius: 3e-3,
            angular_velocity: 20.0,
            density: 20e6,
        },
        7,
    )?;
    let data = simulate(&disk, &params, 6, &|_, _| {})?;
    let mut provenance = toml::Table::new();
    provenance.insert(
        "simulator".into(),
        "cargo run -p pcuvd-io --example steered_fixture".into(),
    );
    let path = pcuvd_io::write_recording(&out, "steered", &data, &provenance)?;
    println!("wrote {}", path.display());

    for (name, angles_deg, coding, event_prf, frames) in [
        (
            "coded",
            &[-9.0f64, -3.0, 3.0, 9.0][..],
            Coding::Hadamard { slot_delay: 1e-6 },
            8000.0,
            12,
        ),
        ("bmode", &[0.0][..], Coding::Conventional, 2000.0, 4),
    ] {
        let sequence = Sequence {
            angles: angles_deg.iter().map(|a| a.to_radians()).collect(),
            event_prf,
            coding,
            pulse_cycles: 2.0,
            pulse: None,
        };
        let mut params = SimParams::new(probe.clone(), sequence, 20e6, 1540.0, (8e-3, 16e-3))?;
        params.seed = 7;
        let data = simulate(&disk, &params, frames, &|_, _| {})?;
        let path = pcuvd_io::write_recording(&out, name, &data, &provenance)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
