//! Transmit sequences: which steered plane waves fire in each transmit event, with which polarity.

use crate::error::{Result, invalid, require_positive};
use crate::hadamard::Hadamard;

/// How the angles of a compound frame are transmitted.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Coding {
    /// Conventional: event i of a compound frame fires angle i alone.
    Conventional,
    /// Hadamard pulse coding: every event fires all n angles; slot k fires after `slot_delay`·k (s)
    /// with the polarity `H_n[i][k]` in event i of a compound frame.
    Hadamard {
        /// Delay Δτ between successive pulse slots in an event (s); the paper uses 1 µs.
        slot_delay: f64,
    },
}

/// A plane-wave transmit sequence: n steering angles repeated in compound frames of n events.
#[derive(Debug, Clone, PartialEq)]
pub struct Sequence {
    /// Steering angle of each slot (rad); θ > 0 tilts toward +x.
    pub angles: Vec<f64>,
    /// Transmit-event repetition frequency (Hz).
    pub event_prf: f64,
    /// Conventional or Hadamard-coded transmission.
    pub coding: Coding,
    /// Transmit pulse length (cycles of the centre frequency).
    pub pulse_cycles: f64,
}

impl Sequence {
    /// `n` angles evenly spaced over [−max, max] (rad); a single angle is 0.
    pub fn evenly_spaced_angles(n: usize, max: f64) -> Vec<f64> {
        match n {
            0 => vec![],
            1 => vec![0.0],
            _ => (0..n)
                .map(|i| -max + 2.0 * max * i as f64 / (n - 1) as f64)
                .collect(),
        }
    }

    /// Number of angles n (= events per compound frame).
    pub fn n_angles(&self) -> usize {
        self.angles.len()
    }

    /// Compound frame rate = slow-time sampling rate of each angle: event PRF / n (Hz).
    pub fn frame_rate(&self) -> f64 {
        self.event_prf / self.n_angles() as f64
    }

    /// The Hadamard matrix of a coded sequence, `None` for conventional.
    pub fn hadamard(&self) -> Result<Option<Hadamard>> {
        match self.coding {
            Coding::Conventional => Ok(None),
            Coding::Hadamard { .. } => Hadamard::new(self.n_angles()).map(Some),
        }
    }

    /// Start of pulse slot `k` within an event (s): k·Δτ when coded, 0 when conventional.
    pub fn slot_offset(&self, k: usize) -> f64 {
        match self.coding {
            Coding::Conventional => 0.0,
            Coding::Hadamard { slot_delay } => k as f64 * slot_delay,
        }
    }

    /// Pulses fired in event `event` (counted from the first event of the recording):
    /// (angle index, polarity ±1, slot start time within the event in s).
    pub fn event_pulses(&self, event: usize) -> Vec<(usize, f32, f64)> {
        let n = self.n_angles();
        let row = event % n;
        match self.coding {
            Coding::Conventional => vec![(row, 1.0, 0.0)],
            Coding::Hadamard { .. } => {
                let h = Hadamard::new(n).expect("validated sequence");
                (0..n)
                    .map(|k| (k, h.get(row, k), self.slot_offset(k)))
                    .collect()
            }
        }
    }

    /// Checks angles, PRF, pulse length and that a Hadamard order exists for the number of angles.
    pub fn validate(&self) -> Result<()> {
        if self.angles.is_empty() {
            return Err(invalid("angles", "a sequence needs at least one angle"));
        }
        if let Some(a) = self
            .angles
            .iter()
            .find(|a| !a.is_finite() || a.abs() >= std::f64::consts::FRAC_PI_2)
        {
            return Err(invalid(
                "angles",
                format!(
                    "steering angle {:.2}° is not within (−90°, 90°)",
                    a.to_degrees()
                ),
            ));
        }
        // A repeated angle adds no direction to the vector fit and, coded, would decode two slots
        // onto one record: in a recording it is a mistake in the angle list.
        for (k, a) in self.angles.iter().enumerate() {
            if let Some(j) = self.angles[..k].iter().position(|b| b == a) {
                return Err(invalid(
                    "angles",
                    format!(
                        "slots {j} and {k} have the same steering angle {:.4}°: each slot must \
                         fire a different angle",
                        a.to_degrees()
                    ),
                ));
            }
        }
        require_positive("event PRF", self.event_prf)?;
        require_positive("pulse cycles", self.pulse_cycles)?;
        if let Coding::Hadamard { slot_delay } = self.coding {
            require_positive("slot delay", slot_delay)?;
            Hadamard::new(self.n_angles())?;
            let span = slot_delay * (self.n_angles() - 1) as f64;
            if span >= 1.0 / self.event_prf {
                return Err(invalid(
                    "slot delay",
                    format!(
                        "{} slots × {:.3} µs span {:.1} µs, longer than the event period {:.1} µs",
                        self.n_angles(),
                        slot_delay * 1e6,
                        span * 1e6,
                        1e6 / self.event_prf
                    ),
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_sequence_rates() {
        let s = Sequence {
            angles: Sequence::evenly_spaced_angles(8, 15f64.to_radians()),
            event_prf: 14.4e3,
            coding: Coding::Hadamard { slot_delay: 1e-6 },
            pulse_cycles: 2.0,
        };
        s.validate().unwrap();
        assert!((s.frame_rate() - 1800.0).abs() < 1e-9);
        assert!((s.angles[0] + 15f64.to_radians()).abs() < 1e-12);
        assert!((s.angles[7] - 15f64.to_radians()).abs() < 1e-12);
        let pulses = s.event_pulses(9); // second frame, row 1
        assert_eq!(pulses.len(), 8);
        assert_eq!(pulses[1], (1, -1.0, 1e-6));
    }

    #[test]
    fn bad_sequences_are_rejected() {
        let mut s = Sequence {
            angles: vec![0.0, 0.1, 0.2],
            event_prf: 1e4,
            coding: Coding::Hadamard { slot_delay: 1e-6 },
            pulse_cycles: 2.0,
        };
        assert!(s.validate().is_err()); // no H_3
        s.coding = Coding::Conventional;
        s.validate().unwrap();
        s.event_prf = 0.0;
        assert!(s.validate().is_err());
    }
}
