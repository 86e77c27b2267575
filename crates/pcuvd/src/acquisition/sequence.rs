//! Transmit sequences: which steered plane waves fire in each transmit event, with which polarity,
//! when, and with which pulse.

use crate::acquisition::hadamard::Hadamard;
use crate::core::error::{Result, invalid, require_positive, require_range};

/// How the angles of a compound frame are transmitted.
#[derive(Debug, Clone, PartialEq)]
pub enum Coding {
    /// Conventional: event i of a compound frame fires angle i alone.
    Conventional,
    /// Hadamard pulse coding: every event fires all n angles; slot k fires after `slot_delay`·k (s)
    /// with the polarity `H_n[i][k]` in event i of a compound frame.
    Hadamard {
        /// Delay Δτ between successive pulse slots in an event (s); the paper uses 1 µs.
        slot_delay: f64,
    },
    /// An explicit transmit code, as a scanner fires it: any invertible weight matrix with its rows
    /// in the scanner's order (a permuted or sign-flipped Hadamard matrix, say) and any slot starts
    /// (uneven slot delays). A recording manifest of version 2 says it.
    Matrix(TransmitCode),
    /// Coded when fired, stored decoded: the file holds one record per angle, already decoded
    /// from a coded sequence (a Hadamard-coded acquisition decoded by the scanner or a converter),
    /// so pcuvd decodes nothing. The angles of a compound frame share one time, the frame's
    /// decoding time, and the frame rate is the coded sequence's (event PRF / n, the event PRF
    /// being n × the frame rate). `polarity[k]` (±1) is the polarity angle k's record was stored
    /// with; pcuvd multiplies it back so that every angle compounds in phase.
    Decoded {
        /// The polarity (+1 or −1) of each angle's stored record, in angle order.
        polarity: Vec<f64>,
    },
}

/// An explicit transmit code: in event i of every compound frame, slot k (steering angle k) fires
/// with weight `weight(i, k)`, starting `slot_starts[k]` into the event.
#[derive(Debug, Clone, PartialEq)]
pub struct TransmitCode {
    /// Weights, row-major n × n: entry (i, k) is the weight of slot k in event i of a compound
    /// frame (±1 for a polarity code; 0 for a slot that does not fire in that event).
    pub weights: Vec<f64>,
    /// Start of each slot within its event (s, ≥ 0): when the first element of slot k fires,
    /// counted from the event's time origin (the origin of t0).
    pub slot_starts: Vec<f64>,
}

/// Largest condition number (largest / smallest singular value) of a transmit code pcuvd decodes:
/// decoding multiplies by the inverse, which amplifies noise in some direction by up to this
/// factor relative to the best; a Hadamard matrix has 1, and beyond 10³ the decoded angles are
/// mostly amplified noise (or the matrix was written wrongly).
pub const MAX_CODE_CONDITION: f64 = 1e3;

impl TransmitCode {
    /// The Hadamard code `h` with slot k starting at `slot_starts[k]` (s).
    pub fn hadamard(h: &Hadamard, slot_starts: Vec<f64>) -> Self {
        let n = h.order();
        TransmitCode {
            weights: (0..n * n).map(|j| h.get(j / n, j % n) as f64).collect(),
            slot_starts,
        }
    }

    /// One slot per event (event i fires slot i alone), slot k starting at `slot_starts[k]` (s).
    pub fn one_per_event(slot_starts: Vec<f64>) -> Self {
        let n = slot_starts.len();
        TransmitCode {
            weights: (0..n * n)
                .map(|j| if j / n == j % n { 1.0 } else { 0.0 })
                .collect(),
            slot_starts,
        }
    }

    /// Order n: slots (= angles) per event and events per compound frame.
    pub fn order(&self) -> usize {
        self.slot_starts.len()
    }

    /// Weight of slot `slot` in event `event` of a compound frame.
    pub fn weight(&self, event: usize, slot: usize) -> f64 {
        self.weights[event * self.order() + slot]
    }

    /// True when some event fires more than one slot at once (so decoding mixes events and the
    /// medium's motion between them matters).
    pub fn is_coded(&self) -> bool {
        let n = self.order();
        (0..n).any(|i| (0..n).filter(|&k| self.weight(i, k) != 0.0).count() > 1)
    }

    /// The matrix's condition number: largest over smallest singular value (∞ when singular).
    pub fn condition_number(&self) -> f64 {
        let n = self.order();
        let m = faer::Mat::<f64>::from_fn(n, n, |i, k| self.weight(i, k));
        match m.singular_values() {
            Ok(s) if !s.is_empty() => {
                let max = s.iter().cloned().fold(0.0, f64::max);
                let min = s.iter().cloned().fold(f64::INFINITY, f64::min);
                if min > 0.0 { max / min } else { f64::INFINITY }
            }
            _ => f64::INFINITY,
        }
    }

    /// Decoding gain g = ‖A‖²_F / n (the mean squared weight per event): decoding gives g·x for
    /// every slot's record x, which is n·x for a ±1 (Hadamard) code and x for one slot per event.
    pub fn decoding_gain(&self) -> f64 {
        self.weights.iter().map(|w| w * w).sum::<f64>() / self.order() as f64
    }

    /// The decoding matrix D = g·A⁻¹ ([`decoding_gain`](Self::decoding_gain)), row-major
    /// (slot k, event i): slot k's record is Σ_i D[k][i]·event_i. A code with orthogonal rows of
    /// equal norm (A·Aᵀ = g·I: Hadamard in any row order and signs, one slot per event) gets Aᵀ
    /// exactly, so that decode(encode(x)) = g·x without rounding; any other invertible code its
    /// LU inverse.
    pub fn decoding_matrix(&self) -> Result<Vec<f64>> {
        self.validate()?;
        let n = self.order();
        let g = self.decoding_gain();
        let orthogonal = (0..n).all(|i| {
            (0..n).all(|j| {
                let dot: f64 = (0..n).map(|k| self.weight(i, k) * self.weight(j, k)).sum();
                dot == if i == j { g } else { 0.0 }
            })
        });
        if orthogonal {
            return Ok((0..n * n).map(|j| self.weight(j % n, j / n)).collect());
        }
        let a = faer::Mat::<f64>::from_fn(n, n, |i, k| self.weight(i, k));
        use faer::linalg::solvers::DenseSolveCore;
        let inverse = a.partial_piv_lu().inverse();
        Ok((0..n * n).map(|j| g * inverse[(j / n, j % n)]).collect())
    }

    /// Checks the shape (n × n weights, n slot starts), that every value is finite, the starts
    /// ≥ 0, and that the matrix is invertible and well conditioned ([`MAX_CODE_CONDITION`]).
    pub fn validate(&self) -> Result<()> {
        let n = self.order();
        if n == 0 {
            return Err(invalid("code matrix", "a code needs at least one slot"));
        }
        if self.weights.len() != n * n {
            return Err(invalid(
                "code matrix",
                format!(
                    "has {} weights; {n} slots need an {n} × {n} matrix ({} weights): one row per \
                     event of a compound frame, one column per slot",
                    self.weights.len(),
                    n * n
                ),
            ));
        }
        if let Some(j) = self.weights.iter().position(|w| !w.is_finite()) {
            return Err(invalid(
                "code matrix",
                format!(
                    "entry (event {}, slot {}) is {}; weights must be finite",
                    j / n,
                    j % n,
                    self.weights[j]
                ),
            ));
        }
        if let Some(k) = self
            .slot_starts
            .iter()
            .position(|t| !(t.is_finite() && *t >= 0.0))
        {
            return Err(invalid(
                "slot delays",
                format!(
                    "slot {k} starts at {} s; a slot's start within its event must be finite and ≥ 0",
                    self.slot_starts[k]
                ),
            ));
        }
        if let Some(k) = (0..n).find(|&k| (0..n).all(|i| self.weight(i, k) == 0.0)) {
            return Err(invalid(
                "code matrix",
                format!("singular: slot {k} fires in no event (its column is all zero)"),
            ));
        }
        let condition = self.condition_number();
        if condition.is_nan() || condition > MAX_CODE_CONDITION {
            // Beyond 10¹² the smallest singular value is rounding noise: the matrix is singular.
            let what = if condition <= 1e12 {
                format!("ill-conditioned (condition number {condition:.3e})")
            } else {
                "singular (a combination of its rows is zero, to rounding)".to_string()
            };
            return Err(invalid(
                "code matrix",
                format!(
                    "{what}: the angles cannot be separated (decoding would amplify noise by up \
                     to the condition number; at most {MAX_CODE_CONDITION:e} is accepted, a \
                     Hadamard matrix has 1)"
                ),
            ));
        }
        Ok(())
    }
}

/// The transmit pulse as the scanner drives it, sampled: what the simulator sends through the
/// probe's two-way response in place of the default Hann-windowed burst of `pulse_cycles` cycles.
/// Its time origin is the envelope peak of its echo (as the default pulse's is its centre), so
/// that an echo arriving at τ peaks at τ, which is what the beamformer assumes.
#[derive(Debug, Clone, PartialEq)]
pub struct TransmitPulse {
    /// The waveform, one value per sample (any unit: only its shape matters).
    pub samples: Vec<f64>,
    /// Its sampling rate (Hz).
    pub sampling_frequency: f64,
}

/// Most samples a transmit pulse may have (a pulse is microseconds long; more is a mistake).
pub const MAX_PULSE_SAMPLES: usize = 1 << 16;

impl TransmitPulse {
    /// Duration (s): samples / sampling rate.
    pub fn duration(&self) -> f64 {
        self.samples.len() as f64 / self.sampling_frequency
    }

    /// Checks the samples (2 to [`MAX_PULSE_SAMPLES`], finite, not all zero) and the sampling rate.
    pub fn validate(&self) -> Result<()> {
        let n = self.samples.len();
        if !(2..=MAX_PULSE_SAMPLES).contains(&n) {
            return Err(invalid(
                "pulse samples",
                format!("a pulse needs 2 to {MAX_PULSE_SAMPLES} samples, got {n}"),
            ));
        }
        if let Some(j) = self.samples.iter().position(|v| !v.is_finite()) {
            return Err(invalid(
                "pulse samples",
                format!(
                    "sample {j} is {}; every sample must be finite",
                    self.samples[j]
                ),
            ));
        }
        if self.samples.iter().all(|&v| v == 0.0) {
            return Err(invalid("pulse samples", "are all zero: no pulse"));
        }
        require_range(
            "pulse sampling frequency",
            self.sampling_frequency,
            (1e3, MAX_SAMPLING_FREQUENCY),
            "Hz",
        )
    }
}

/// Highest sampling frequency pcuvd accepts (Hz): no ultrasound scanner samples faster than
/// 10 GHz, so a larger value is a unit mistake.
pub const MAX_SAMPLING_FREQUENCY: f64 = 1e10;

/// Highest event PRF pcuvd accepts (Hz): an echo needs microseconds to come back.
pub const MAX_EVENT_PRF: f64 = 1e7;

/// A plane-wave transmit sequence: n steering angles repeated in compound frames of n events.
#[derive(Debug, Clone, PartialEq)]
pub struct Sequence {
    /// Steering angle of each slot (rad); θ > 0 tilts toward +x.
    pub angles: Vec<f64>,
    /// Transmit-event repetition frequency (Hz).
    pub event_prf: f64,
    /// Conventional, Hadamard-coded or explicitly coded transmission.
    pub coding: Coding,
    /// Transmit pulse length (cycles of the centre frequency).
    pub pulse_cycles: f64,
    /// The transmit pulse as sampled, when known; `None`: a Hann-windowed burst of
    /// `pulse_cycles` cycles of the centre frequency.
    pub pulse: Option<TransmitPulse>,
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

    /// The Hadamard matrix of a Hadamard-coded sequence, `None` otherwise.
    pub fn hadamard(&self) -> Result<Option<Hadamard>> {
        match self.coding {
            Coding::Hadamard { .. } => Hadamard::new(self.n_angles()).map(Some),
            _ => Ok(None),
        }
    }

    /// The sequence's transmit code in its general form (weights and slot starts), whatever the
    /// coding: the identity with zero starts when conventional, H_n with starts k·Δτ when
    /// Hadamard-coded.
    pub fn transmit_code(&self) -> Result<TransmitCode> {
        let n = self.n_angles();
        let starts = (0..n).map(|k| self.slot_offset(k)).collect();
        match &self.coding {
            Coding::Conventional => Ok(TransmitCode::one_per_event(starts)),
            Coding::Hadamard { .. } => Ok(TransmitCode::hadamard(&Hadamard::new(n)?, starts)),
            Coding::Matrix(code) => Ok(code.clone()),
            Coding::Decoded { polarity } => Ok(TransmitCode {
                weights: (0..n * n)
                    .map(|j| if j / n == j % n { polarity[j % n] } else { 0.0 })
                    .collect(),
                slot_starts: starts,
            }),
        }
    }

    /// True when the angles were fired coded, several slots per event (Hadamard, an explicit
    /// code that mixes slots, or a coded acquisition the file holds decoded): then flow faster
    /// than the Nyquist velocity decodes wrongly whatever follows.
    pub fn is_coded(&self) -> bool {
        match &self.coding {
            Coding::Conventional => false,
            Coding::Hadamard { .. } | Coding::Decoded { .. } => true,
            Coding::Matrix(code) => code.is_coded(),
        }
    }

    /// True when pcuvd's decoding combines events (Hadamard, or an explicit code that mixes
    /// slots), so that events are aligned in slow time first; false for angles a file holds
    /// already decoded.
    pub fn decodes_events(&self) -> bool {
        match &self.coding {
            Coding::Decoded { .. } => false,
            _ => self.is_coded(),
        }
    }

    /// Start of pulse slot `k` within an event (s): k·Δτ when Hadamard-coded, the code's own
    /// start when explicit, 0 when conventional or decoded in the file (whose records start at
    /// their own slot's firing).
    pub fn slot_offset(&self, k: usize) -> f64 {
        match &self.coding {
            Coding::Conventional | Coding::Decoded { .. } => 0.0,
            Coding::Hadamard { slot_delay } => k as f64 * slot_delay,
            Coding::Matrix(code) => code.slot_starts.get(k).copied().unwrap_or(0.0),
        }
    }

    /// Latest slot start within an event (s).
    pub fn last_slot_start(&self) -> f64 {
        (0..self.n_angles())
            .map(|k| self.slot_offset(k))
            .fold(0.0, f64::max)
    }

    /// Pulses fired in event `event` (counted from the first event of the recording):
    /// (angle index, polarity or weight, slot start time within the event in s).
    pub fn event_pulses(&self, event: usize) -> Vec<(usize, f32, f64)> {
        let n = self.n_angles();
        let row = event % n;
        match &self.coding {
            Coding::Conventional => vec![(row, 1.0, 0.0)],
            // What the file holds: event k of a frame is angle k's record, with its polarity.
            Coding::Decoded { polarity } => vec![(row, polarity[row] as f32, 0.0)],
            Coding::Hadamard { .. } => {
                let h = Hadamard::new(n).expect("validated sequence");
                (0..n)
                    .map(|k| (k, h.get(row, k), self.slot_offset(k)))
                    .collect()
            }
            Coding::Matrix(code) => (0..n)
                .filter(|&k| code.weight(row, k) != 0.0)
                .map(|k| (k, code.weight(row, k) as f32, code.slot_starts[k]))
                .collect(),
        }
    }

    /// Checks angles, PRF, pulse, and the coding: that a Hadamard order exists for the number of
    /// angles, or that an explicit code is n × n, invertible and well conditioned; and that every
    /// slot starts within the event period.
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
        require_range("event PRF", self.event_prf, (1e-3, MAX_EVENT_PRF), "Hz")?;
        require_positive("pulse cycles", self.pulse_cycles)?;
        let period = 1.0 / self.event_prf;
        if let Some(pulse) = &self.pulse {
            pulse.validate()?;
            if pulse.duration() >= period {
                return Err(invalid(
                    "pulse samples",
                    format!(
                        "the pulse lasts {:.3} µs, longer than the event period {:.3} µs",
                        pulse.duration() * 1e6,
                        period * 1e6
                    ),
                ));
            }
        }
        match &self.coding {
            Coding::Conventional => {}
            Coding::Hadamard { slot_delay } => {
                require_positive("slot delay", *slot_delay)?;
                Hadamard::new(self.n_angles())?;
            }
            Coding::Matrix(code) => {
                if code.order() != self.n_angles() {
                    return Err(invalid(
                        "code matrix",
                        format!(
                            "has {} slots but the sequence has {} angles (one slot per angle)",
                            code.order(),
                            self.n_angles()
                        ),
                    ));
                }
                code.validate()?;
            }
            Coding::Decoded { polarity } => {
                if polarity.len() != self.n_angles() {
                    return Err(invalid(
                        "polarity",
                        format!(
                            "has {} values but the sequence has {} angles (one per angle)",
                            polarity.len(),
                            self.n_angles()
                        ),
                    ));
                }
                if let Some(k) = polarity.iter().position(|&p| p != 1.0 && p != -1.0) {
                    return Err(invalid(
                        "polarity",
                        format!(
                            "angle {k} has polarity {}; a decoded angle's polarity is +1 or −1",
                            polarity[k]
                        ),
                    ));
                }
            }
        }
        let last = self.last_slot_start();
        if last >= period {
            let name = match self.coding {
                Coding::Hadamard { .. } => "slot delay",
                _ => "slot delays",
            };
            return Err(invalid(
                name,
                format!(
                    "{} slots span {:.1} µs (the last starts then), longer than the event period \
                     {:.1} µs",
                    self.n_angles(),
                    last * 1e6,
                    1e6 / self.event_prf
                ),
            ));
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
            pulse: None,
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
            pulse: None,
        };
        assert!(s.validate().is_err()); // no H_3
        s.coding = Coding::Conventional;
        s.validate().unwrap();
        s.event_prf = 0.0;
        assert!(s.validate().is_err());
    }

    /// H_4 with its rows in another order and two rows sign-flipped.
    fn scrambled_hadamard() -> TransmitCode {
        let h = Hadamard::new(4).unwrap();
        let (order, signs) = ([2usize, 0, 3, 1], [1.0, -1.0, 1.0, -1.0]);
        TransmitCode {
            weights: (0..16)
                .map(|j| signs[j / 4] * h.get(order[j / 4], j % 4) as f64)
                .collect(),
            slot_starts: vec![0.0, 1.3e-6, 2.1e-6, 3.9e-6],
        }
    }

    #[test]
    fn decoding_matrix_inverts_the_code() {
        // A scrambled Hadamard code decodes with its exact transpose: g = 4.
        let code = scrambled_hadamard();
        code.validate().unwrap();
        assert!(code.is_coded());
        assert_eq!(code.decoding_gain(), 4.0);
        assert!((code.condition_number() - 1.0).abs() < 1e-12);
        let d = code.decoding_matrix().unwrap();
        for k in 0..4 {
            for i in 0..4 {
                assert_eq!(d[k * 4 + i], code.weight(i, k));
            }
        }
        // A code whose rows are not orthogonal decodes with g·A⁻¹: D·A = g·I.
        let code = TransmitCode {
            weights: vec![1.0, 1.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 1.0],
            slot_starts: vec![0.0, 1e-6, 2e-6],
        };
        code.validate().unwrap();
        let g = code.decoding_gain();
        assert_eq!(g, 2.0);
        let d = code.decoding_matrix().unwrap();
        for k in 0..3 {
            for j in 0..3 {
                let da: f64 = (0..3).map(|i| d[k * 3 + i] * code.weight(i, j)).sum();
                let expect = if k == j { g } else { 0.0 };
                assert!((da - expect).abs() < 1e-12, "({k}, {j}): {da}");
            }
        }
        // One slot per event: no mixing, decoding gain 1.
        let plain = TransmitCode::one_per_event(vec![0.0, 5e-7]);
        assert!(!plain.is_coded());
        assert_eq!(plain.decoding_gain(), 1.0);
    }

    #[test]
    fn bad_codes_are_refused_with_the_reason() {
        let reason = |code: TransmitCode| code.validate().unwrap_err().to_string();
        let singular = TransmitCode {
            weights: vec![1.0, 1.0, 1.0, 1.0],
            slot_starts: vec![0.0, 1e-6],
        };
        assert!(reason(singular).contains("singular"));
        let silent = TransmitCode {
            weights: vec![1.0, 0.0, 1.0, 0.0],
            slot_starts: vec![0.0, 1e-6],
        };
        assert!(reason(silent).contains("slot 1 fires in no event"));
        let ill = TransmitCode {
            weights: vec![1.0, 1.0, 1.0, 1.0 + 1e-5],
            slot_starts: vec![0.0, 1e-6],
        };
        assert!(reason(ill).contains("ill-conditioned"));
        let ragged = TransmitCode {
            weights: vec![1.0, 1.0, 1.0],
            slot_starts: vec![0.0, 1e-6],
        };
        assert!(reason(ragged).contains("2 × 2"));
        let early = TransmitCode {
            slot_starts: vec![0.0, -1e-6],
            ..TransmitCode::one_per_event(vec![0.0; 2])
        };
        assert!(reason(early).contains("slot 1 starts at"));
        // In a sequence: the order must match the angles, and the slots fit in the event period.
        let mut s = Sequence {
            angles: vec![-0.1, 0.0, 0.1, 0.2],
            event_prf: 1e4,
            coding: Coding::Matrix(scrambled_hadamard()),
            pulse_cycles: 2.0,
            pulse: None,
        };
        s.validate().unwrap();
        assert_eq!(s.last_slot_start(), 3.9e-6);
        assert_eq!(s.event_pulses(5)[1], (1, -1.0, 1.3e-6));
        s.event_prf = 3e5;
        assert!(
            s.validate()
                .unwrap_err()
                .to_string()
                .contains("longer than the event period")
        );
        s.event_prf = 1e4;
        s.angles.pop();
        assert!(
            s.validate()
                .unwrap_err()
                .to_string()
                .contains("4 slots but the sequence has 3")
        );
    }
}
