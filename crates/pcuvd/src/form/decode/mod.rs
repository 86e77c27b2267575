//! Hadamard decoding: from coded transmit events back to one record per steering angle.
//!
//! In event i of a compound frame, slot k fired angle θ_k with polarity `H[i][k]` after τ_k = k·Δτ.
//! Decoding is RF = Hᵀ·M over the n events of the frame (eq. 2), then each slot k is advanced by
//! τ_k (eq. 3) so that every angle's record has the same time origin t0. When τ_k·f_s is not an
//! integer the advance is a band-limited fractional shift (FFT phase ramp). For a still medium
//! decode(encode(x)) = n·x; moving scatterers break the assumption (see DESIGN.md, "Coding and motion").
//! Conventional sequences are only split: event i of a frame is angle i.
//!
//! An explicit code (weights A, any row order and signs, any slot starts τ_k; see
//! [`TransmitCode`]) is decoded the same way with the decoding matrix g·A⁻¹
//! ([`TransmitCode::decoding_matrix`]) in place of Hᵀ: decode(encode(x)) = g·x with g = ‖A‖²_F / n,
//! which is n·x for any ±1 code and x for one slot per event.
//!
//! Motion between the events: event i of every frame fires i event periods after the frame's first,
//! so moving blood has changed its echo phase from one event to the next and Hᵀ·M no longer
//! cancels the other angles (it leaks each into the others, in proportion to the speed). With
//! [`EventAlignment::MidFrame`] each event's slow-time series (one sample per frame, at the frame
//! rate) is first resampled, band-limited, to the frame's mid-event time. All n events then see
//! the medium at one instant and decoding is exact again for every echo whose Doppler frequency is
//! below half the frame rate, which is what Doppler needs anyway (the Nyquist velocity).

use std::ops::Range;
use std::sync::Arc;

use ndarray::{Array3, Array4, ArrayView3, ArrayViewMut3, Axis, s};
use num_complex::{Complex32, Complex64};
use num_traits::Zero;
use pcuvd_fft::{Fft, FftPlanner32};
use rayon::prelude::*;

use crate::acquisition::channel::{AngleSamples, ChannelData, Samples};
use crate::acquisition::hadamard::Hadamard;
use crate::acquisition::sequence::{Coding, TransmitCode};
use crate::core::error::{Error, Result};
use crate::core::rows::{matrix_weighted_rows, sliding_weighted_rows, weighted_rows};

mod align;
mod encode;
mod events;
mod predict;
mod shift;

use align::*;
pub use align::{ALIGN_FIT_FRAMES, ALIGN_HALF, ALIGN_ORDER};
pub use encode::{encode, encode_code};
use events::*;
use predict::*;
pub use shift::TraceShifter;
use shift::*;

/// How decoding treats blood that moves between the n events of a coded compound frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum EventAlignment {
    /// The paper's decoding (eq. 2): the n events of a frame are taken as simultaneous, so moving
    /// blood leaks each angle into the others.
    Simultaneous,
    /// Each event's slow-time series is first resampled (band-limited) to the frame's mid-event
    /// time, so that decoding is exact for echoes whose Doppler is below half the frame rate.
    #[default]
    MidFrame,
}

impl EventAlignment {
    /// Its name in settings and reports: "simultaneous" or "mid-frame".
    pub fn label(self) -> &'static str {
        match self {
            EventAlignment::Simultaneous => "simultaneous",
            EventAlignment::MidFrame => "mid-frame",
        }
    }
}

/// How a recording's transmit events become one record per steering angle: the decoding matrix
/// and each slot's advance (none for a conventional sequence, whose events are only split), the
/// sampling rate, and whether coded events are first aligned in slow time. Built once from the
/// sequence, it decodes any block of compound frames, into new memory, a previous block's, or the
/// samples' own.
pub struct Decoder {
    n: usize,
    /// `None`: conventional, event f·n + k is angle k's record of frame f.
    plan: Option<DecodePlan>,
    sampling_frequency: f64,
    alignment: EventAlignment,
}

impl Decoder {
    /// The decoder of `data`'s sequence (its samples checked against its acquisition), aligning
    /// coded events as `alignment` says.
    pub fn new(data: &ChannelData, alignment: EventAlignment) -> Result<Self> {
        data.validate()?;
        let acq = &data.acquisition;
        let fs = acq.sampling_frequency;
        let n = acq.sequence.n_angles();
        match &acq.sequence.coding {
            Coding::Conventional => Decoder::hadamard(n, None, fs, alignment),
            Coding::Hadamard { slot_delay } => {
                Decoder::hadamard(n, Some(slot_delay * fs), fs, alignment)
            }
            Coding::Matrix(code) => Decoder::code(code, fs, alignment),
            // Already decoded: only the stored polarity is turned back, event by event.
            Coding::Decoded { polarity } if polarity.iter().all(|&p| p == 1.0) => {
                Decoder::hadamard(n, None, fs, alignment)
            }
            Coding::Decoded { .. } => Decoder::code(&acq.sequence.transmit_code()?, fs, alignment),
        }
    }

    /// The decoder of `n` angles per compound frame, Hadamard-coded with pulse slots
    /// `slot_shift` samples apart (`None`: conventional, only split), sampled at
    /// `sampling_frequency` (Hz; it rotates the phase of shifted IQ).
    pub fn hadamard(
        n: usize,
        slot_shift: Option<f64>,
        sampling_frequency: f64,
        alignment: EventAlignment,
    ) -> Result<Self> {
        crate::core::error::require_positive("sampling frequency", sampling_frequency)?;
        let plan = match slot_shift {
            None => None,
            Some(shift) => Some(hadamard_plan(n, checked_slot_shift(shift)?)?),
        };
        Ok(Decoder {
            n,
            plan,
            sampling_frequency,
            alignment,
        })
    }

    /// The decoder of an explicit code sampled at `sampling_frequency` (Hz): slot k's record is
    /// Σ_i D[k][i]·event_i with D = [`TransmitCode::decoding_matrix`], advanced by its start τ_k;
    /// events are aligned in slow time as `alignment` says when some event fires several slots.
    pub fn code(
        code: &TransmitCode,
        sampling_frequency: f64,
        alignment: EventAlignment,
    ) -> Result<Self> {
        crate::core::error::require_positive("sampling frequency", sampling_frequency)?;
        Ok(Decoder {
            n: code.order(),
            plan: Some(code_plan(code, sampling_frequency)?),
            sampling_frequency,
            alignment,
        })
    }

    /// Angles (events) per compound frame.
    pub fn n_angles(&self) -> usize {
        self.n
    }

    /// Every compound frame of `samples` (events, channels, samples), one record per angle:
    /// (angles, frames, channels, samples).
    pub fn decode(&self, samples: &Samples) -> Result<AngleSamples> {
        check_frames(samples, self.n)?;
        self.decode_frames(samples, 0..samples.dim().0 / self.n, None)
    }

    /// Compound frames `frames` of `samples` (the others are read only by the slow-time
    /// alignment): (angles, frames.len(), channels, samples), in `reuse`'s memory when its records
    /// have the shape (a previous block's), rather than fresh pages faulted in and zeroed.
    pub fn decode_frames(
        &self,
        samples: &Samples,
        frames: Range<usize>,
        reuse: Option<AngleSamples>,
    ) -> Result<AngleSamples> {
        check_frames(samples, self.n)?;
        check_kept(samples, self.n, &frames)?;
        let Some(plan) = &self.plan else {
            let events = s![frames.start * self.n..frames.end * self.n, .., ..];
            return Ok(match samples {
                Samples::Rf(rf) => AngleSamples::Rf(split(rf.slice(events), self.n)),
                Samples::Iq {
                    data,
                    demod_frequency,
                } => AngleSamples::Iq {
                    data: split(data.slice(events), self.n),
                    demod_frequency: *demod_frequency,
                },
            });
        };
        decode_with(
            samples,
            plan,
            self.sampling_frequency,
            self.alignment,
            frames,
            reuse,
        )
    }

    /// [`Decoder::decode_frames`] in the memory of `samples` rather than a new array: afterwards
    /// event `f·n + k` of each compound frame f in `frames` holds angle k's record of that frame,
    /// to the bit what [`Decoder::decode_frames`] returns ([`Samples::decoded_frames`] views them
    /// per angle); the other events are left as read. A block of a long recording then needs half
    /// the memory, so it can hold twice the frames.
    pub fn decode_in_place(&self, samples: &mut Samples, frames: Range<usize>) -> Result<()> {
        check_frames(samples, self.n)?;
        check_kept(samples, self.n, &frames)?;
        // Conventional: event f·n + k already is angle k's record of frame f.
        let Some(plan) = &self.plan else {
            return Ok(());
        };
        let (events, _, ns) = samples.dim();
        let aligner = checked_aligner(plan, self.alignment, events, ns)?;
        let aligner = aligner.as_ref();
        match samples {
            Samples::Rf(rf) => {
                if !rf.is_standard_layout() {
                    *rf = rf.as_standard_layout().into_owned();
                }
                decode_events_in_place(rf.view_mut(), plan, shift_rf, aligner, frames)
            }
            Samples::Iq {
                data: iq,
                demod_frequency,
            } => {
                if !iq.is_standard_layout() {
                    *iq = iq.as_standard_layout().into_owned();
                }
                let shift = shift_iq(*demod_frequency, self.sampling_frequency);
                decode_events_in_place(iq.view_mut(), plan, shift, aligner, frames)
            }
        }
        Ok(())
    }
}

/// `shift` (samples between pulse slots) if it is finite and ≥ 0, or an error.
fn checked_slot_shift(shift: f64) -> Result<f64> {
    if !(shift.is_finite() && shift >= 0.0) {
        return Err(crate::core::error::invalid(
            "slot delay",
            format!("must be finite and ≥ 0 samples, got {shift}"),
        ));
    }
    Ok(shift)
}

/// The plan of a Hadamard code of order `n` with slots `shift` samples apart: Hᵀ, slot k
/// gathering event i with the polarity H[i][k].
fn hadamard_plan(n: usize, shift: f64) -> Result<DecodePlan> {
    let h = Hadamard::new(n)?;
    Ok(DecodePlan {
        matrix: (0..n * n).map(|j| h.get(j % n, j / n)).collect(),
        shifts: (0..n).map(|k| k as f64 * shift).collect(),
        align: true,
    })
}

/// The plan of an explicit code sampled at `sampling_frequency` (Hz).
fn code_plan(code: &TransmitCode, sampling_frequency: f64) -> Result<DecodePlan> {
    Ok(DecodePlan {
        matrix: code
            .decoding_matrix()?
            .into_iter()
            .map(|v| v as f32)
            .collect(),
        shifts: code
            .slot_starts
            .iter()
            .map(|t| t * sampling_frequency)
            .collect(),
        align: code.is_coded(),
    })
}

/// A whole number of compound frames of `n` events, or an error.
fn check_frames(samples: &Samples, n: usize) -> Result<()> {
    let (events, _, _) = samples.dim();
    if n == 0 || events < n || events % n != 0 {
        return Err(crate::core::error::Error::Shape(format!(
            "{events} transmit events is not a whole number of compound frames of {n} events"
        )));
    }
    Ok(())
}

/// `frames`, a non-empty range of the recording's compound frames of `n` events, or an error.
fn check_kept(samples: &Samples, n: usize, frames: &Range<usize>) -> Result<()> {
    let total = samples.dim().0 / n;
    if frames.start >= frames.end || frames.end > total {
        return Err(crate::core::error::invalid(
            "frames",
            format!("{frames:?} is not a range of the recording's {total} frames"),
        ));
    }
    Ok(())
}

/// How to decode a frame: the decoding matrix (row-major (slot, event)), each slot's advance
/// (samples), and whether events mix slots (then slow-time alignment applies).
struct DecodePlan {
    matrix: Vec<f32>,
    shifts: Vec<f64>,
    align: bool,
}

fn decode_with(
    samples: &Samples,
    plan: &DecodePlan,
    sampling_frequency: f64,
    alignment: EventAlignment,
    kept: Range<usize>,
    reuse: Option<AngleSamples>,
) -> Result<AngleSamples> {
    let (events, _, ns) = samples.dim();
    let aligner = checked_aligner(plan, alignment, events, ns)?;
    let aligner = aligner.as_ref();
    let (reuse_rf, reuse_iq) = match reuse {
        Some(AngleSamples::Rf(a)) => (Some(a), None),
        Some(AngleSamples::Iq { data, .. }) => (None, Some(data)),
        None => (None, None),
    };
    match samples {
        Samples::Rf(rf) => Ok(AngleSamples::Rf(decode_events(
            rf.view(),
            plan,
            shift_rf,
            aligner,
            kept,
            reuse_rf,
        ))),
        Samples::Iq {
            data: iq,
            demod_frequency,
        } => {
            let fd = *demod_frequency;
            let out = decode_events(
                iq.view(),
                plan,
                shift_iq(fd, sampling_frequency),
                aligner,
                kept,
                reuse_iq,
            );
            Ok(AngleSamples::Iq {
                data: out,
                demod_frequency: fd,
            })
        }
    }
}

/// Refuses slot shifts beyond a record of `ns` samples; the slow-time aligner of `events`
/// events when `alignment` asks for one and the plan's events mix slots.
fn checked_aligner(
    plan: &DecodePlan,
    alignment: EventAlignment,
    events: usize,
    ns: usize,
) -> Result<Option<SlowTimeAligner>> {
    let n = plan.shifts.len();
    if let Some(k) = plan.shifts.iter().position(|s| s.abs() >= ns as f64) {
        return Err(crate::core::error::invalid(
            "slot delays",
            format!(
                "slot {k} is shifted by {:.1} samples, more than its {ns}-sample record: its echoes \
                 are not in the recording",
                plan.shifts[k]
            ),
        ));
    }
    let frames = events / n.max(1);
    Ok(match alignment {
        EventAlignment::MidFrame if plan.align && n > 1 && frames > 1 => {
            Some(SlowTimeAligner::new(frames, n))
        }
        _ => None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two steady tones (a Doppler signal of two velocities) are an order-2 autoregression: the
    /// forward–backward predictor continues them, from the last frames onward and from the first
    /// frames backward, 12 frames deep.
    #[test]
    fn predictor_continues_steady_tones() {
        let tone = |t: f64| {
            let a = Complex64::from_polar(1.0, 0.7 * t);
            let b = Complex64::from_polar(0.5, -1.9 * t + 0.4);
            a + b
        };
        let frames = 20usize;
        let len = frames + 2 * ALIGN_HALF;
        let mut lanes: Vec<Complex32> = (0..len)
            .map(|i| {
                let v = tone(i as f64 - ALIGN_HALF as f64);
                Complex32::new(v.re as f32, v.im as f32)
            })
            .collect();
        let truth = lanes.clone();
        for v in lanes[..ALIGN_HALF].iter_mut() {
            *v = Complex32::new(9.0, 9.0);
        }
        for v in lanes[ALIGN_HALF + frames..].iter_mut() {
            *v = Complex32::new(9.0, 9.0);
        }
        extend(&mut lanes, frames, false, End::Tail);
        extend(&mut lanes, frames, false, End::Head);
        let worst = lanes
            .iter()
            .zip(&truth)
            .map(|(a, b)| (a - b).norm() / b.norm())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-3, "worst relative error {worst}");
    }

    /// The interpolator reads a tone at 0.3 of the frame rate half a frame later to its designed
    /// ripple (side lobes near −60 dB), and leaves a still series as it is.
    #[test]
    fn interpolation_weights_shift_a_tone() {
        let w = interpolation_weights(0.5);
        let f = 0.3 * std::f64::consts::TAU;
        let got: Complex64 = w
            .iter()
            .enumerate()
            .map(|(j, &wj)| Complex64::from_polar(wj as f64, f * (j as f64 - ALIGN_HALF as f64)))
            .sum();
        let want = Complex64::from_polar(1.0, f * 0.5);
        assert!((got - want).norm() < 2e-3, "{got} against {want}");
        assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
    }
}
