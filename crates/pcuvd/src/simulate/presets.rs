//! The acquisitions of the paper's two studies, in one place: the spiral simulation (§2.3) and the
//! rat set-up of the vessel network (Table 1).

use super::{NoiseSpec, SimParams};
use crate::acquisition::probe::Probe;
use crate::acquisition::sequence::{Coding, Sequence};
use crate::core::error::Result;

/// Frames of the paper's spiral simulation.
pub const PAPER_FRAMES: usize = 100;

/// The paper's spiral acquisition (section 2.3): L22-14vX, 15.625 MHz, 2-cycle pulse, f_s 65 MHz,
/// c 1540 m/s, 8 angles evenly spaced in [−15°, 15°], event PRF 14.4 kHz, noise −10 dB (1–22 MHz),
/// Hadamard coding with 1 µs slot delay when `coded`, else conventional. Both variants share the
/// coded receive window (z ∈ [0, 14 mm] for every slot), so that the noise level — relative to the
/// echo RMS over that window — is the same. Simulate [`PAPER_FRAMES`] frames.
pub fn paper_spiral_params(coded: bool) -> Result<SimParams> {
    let probe = Probe::l22_14vx();
    let mut sequence = Sequence {
        angles: Sequence::evenly_spaced_angles(8, 15f64.to_radians()),
        event_prf: 14.4e3,
        coding: Coding::Hadamard { slot_delay: 1e-6 },
        pulse_cycles: 2.0,
        pulse: None,
    };
    let mut params = SimParams::new(probe, sequence.clone(), 65e6, 1540.0, (0.0, 14e-3))?;
    if !coded {
        sequence.coding = Coding::Conventional;
        params.sequence = sequence;
    }
    params.noise = Some(NoiseSpec::new(-10.0));
    Ok(params)
}

/// The paper's rat acquisition (Table 1): L22-14vX, f_c 15.625 MHz, 2-cycle pulse, f_s 65 MHz,
/// c 1540 m/s, 8 angles in [−15°, 15°], event PRF 14.4 kHz (1.8 kHz compound), Hadamard order 8
/// with 1 µs slot delay when `coded`, receive window 0–13 mm, attenuation 0.5 dB/cm/MHz (so the
/// echoes, and the SNR, fall with depth), noise −10 dB.
pub fn rat_params(coded: bool) -> Result<SimParams> {
    let sequence = Sequence {
        angles: Sequence::evenly_spaced_angles(8, 15f64.to_radians()),
        event_prf: 14.4e3,
        coding: if coded {
            Coding::Hadamard { slot_delay: 1e-6 }
        } else {
            Coding::Conventional
        },
        pulse_cycles: 2.0,
        pulse: None,
    };
    let mut params = SimParams::new(Probe::l22_14vx(), sequence, 65e6, 1540.0, (0.0, 13e-3))?;
    params.noise = Some(NoiseSpec::new(-10.0));
    Ok(params)
}

/// Compound frames of the paper's rat recordings (0.2 s at 1.8 kHz).
pub const RAT_FRAMES: usize = 360;
