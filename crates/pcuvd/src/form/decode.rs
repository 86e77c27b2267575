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
use rayon::prelude::*;
use rustfft::{Fft, FftPlanner};

use crate::acquisition::channel::{AngleSamples, ChannelData, Samples};
use crate::acquisition::hadamard::Hadamard;
use crate::acquisition::sequence::{Coding, TransmitCode};
use crate::core::error::{Error, Result};

/// Advances traces of a fixed length by a (possibly fractional) number of samples: `y[t] = x[t + shift]`.
/// Samples shifted in from beyond the end are zero.
pub struct TraceShifter {
    len: usize,
    fft_len: usize,
    forward: Arc<dyn Fft<f32>>,
    inverse: Arc<dyn Fft<f32>>,
}

impl TraceShifter {
    /// A shifter for traces of `len` samples and advances of at most `max_shift` samples.
    pub fn new(len: usize, max_shift: f64) -> Self {
        // Odd length: no Nyquist bin, so a real trace stays real and shifts invert exactly.
        // The zero pad absorbs the wrap-around of the circular shift and the sinc tails.
        let mut fft_len = len + max_shift.abs().ceil() as usize + 64;
        if fft_len.is_multiple_of(2) {
            fft_len += 1;
        }
        let mut planner = FftPlanner::new();
        TraceShifter {
            len,
            fft_len,
            forward: planner.plan_fft_forward(fft_len),
            inverse: planner.plan_fft_inverse(fft_len),
        }
    }

    /// Advances `trace` in place by `shift` samples (negative delays it).
    pub fn shift_complex(&self, trace: &mut [Complex32], shift: f64) {
        assert_eq!(trace.len(), self.len);
        let rounded = shift.round();
        if (shift - rounded).abs() < 1e-9 {
            shift_integer(trace, rounded as isize, Complex32::new(0.0, 0.0));
            return;
        }
        let mut buf = vec![Complex32::new(0.0, 0.0); self.fft_len];
        buf[..self.len].copy_from_slice(trace);
        self.forward.process(&mut buf);
        let n = self.fft_len as f64;
        let half = (self.fft_len - 1) / 2;
        for (k, v) in buf.iter_mut().enumerate() {
            let freq = if k <= half { k as f64 } else { k as f64 - n };
            let phase = 2.0 * std::f64::consts::PI * freq * shift / n;
            *v *= Complex32::new(phase.cos() as f32, phase.sin() as f32) / self.fft_len as f32;
        }
        self.inverse.process(&mut buf);
        trace.copy_from_slice(&buf[..self.len]);
    }

    /// Advances a real trace in place by `shift` samples.
    pub fn shift_real(&self, trace: &mut [f32], shift: f64) {
        let rounded = shift.round();
        if (shift - rounded).abs() < 1e-9 {
            shift_integer(trace, rounded as isize, 0.0);
            return;
        }
        let mut c: Vec<Complex32> = trace.iter().map(|&v| Complex32::new(v, 0.0)).collect();
        self.shift_complex(&mut c, shift);
        for (t, v) in trace.iter_mut().zip(&c) {
            *t = v.re;
        }
    }
}

fn shift_integer<T: Copy>(trace: &mut [T], shift: isize, zero: T) {
    let n = trace.len() as isize;
    if shift >= 0 {
        let k = shift.min(n) as usize;
        trace.copy_within(k.., 0);
        let len = trace.len();
        trace[len - k..].fill(zero);
    } else {
        let k = (-shift).min(n) as usize;
        trace.copy_within(..trace.len() - k, k);
        trace[..k].fill(zero);
    }
}

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

/// Separates a recording into one record per angle: shape (angles, frames, channels, samples).
/// Coded frames are decoded as if their events were simultaneous ([`EventAlignment::Simultaneous`]).
pub fn decode(data: &ChannelData) -> Result<AngleSamples> {
    decode_aligned(data, EventAlignment::Simultaneous)
}

/// As [`decode`], with coded events aligned in slow time as `alignment` says (conventional
/// sequences are only split: each angle's record is already one event per frame).
pub fn decode_aligned(data: &ChannelData, alignment: EventAlignment) -> Result<AngleSamples> {
    decode_aligned_frames(data, alignment, 0..data.n_frames())
}

/// As [`decode_aligned`], keeping only compound frames `frames` of the recording (the others
/// are read only by the slow-time alignment): (angles, frames.len(), channels, samples).
pub fn decode_aligned_frames(
    data: &ChannelData,
    alignment: EventAlignment,
    frames: Range<usize>,
) -> Result<AngleSamples> {
    decode_reusing(data, alignment, frames, None)
}

/// As [`decode_aligned_frames`], into `out`: the memory of the records it holds (a previous
/// block's) is reused when they have the shape, rather than fresh pages faulted in and zeroed.
pub fn decode_aligned_frames_into(
    data: &ChannelData,
    alignment: EventAlignment,
    frames: Range<usize>,
    out: &mut Option<AngleSamples>,
) -> Result<()> {
    *out = Some(decode_reusing(data, alignment, frames, out.take())?);
    Ok(())
}

/// As [`decode_aligned_frames`], in the memory of `data`'s samples rather than a new array:
/// afterwards event `f·n + k` of each compound frame f in `frames` holds angle k's record of
/// that frame, to the bit what [`decode_aligned_frames`] returns
/// ([`Samples::decoded_frames`] views them per angle); the other events are left as read. A
/// block of a long recording then needs half the memory, so it can hold twice the frames.
pub fn decode_in_place(
    data: &mut ChannelData,
    alignment: EventAlignment,
    frames: Range<usize>,
) -> Result<()> {
    data.validate()?;
    let acq = &data.acquisition;
    let n = acq.sequence.n_angles();
    check_frames(&data.samples, n)?;
    check_kept(&data.samples, n, &frames)?;
    let fs = acq.sampling_frequency;
    crate::core::error::require_positive("sampling frequency", fs)?;
    let plan = match &acq.sequence.coding {
        // Event f·n + k already is angle k's record of frame f.
        Coding::Conventional => return Ok(()),
        Coding::Hadamard { slot_delay } => hadamard_plan(n, checked_slot_shift(slot_delay * fs)?)?,
        Coding::Matrix(code) => code_plan(code, fs)?,
    };
    let (events, _, ns) = data.samples.dim();
    let aligner = checked_aligner(&plan, alignment, events, ns)?;
    let aligner = aligner.as_ref();
    match &mut data.samples {
        Samples::Rf(rf) => {
            if !rf.is_standard_layout() {
                *rf = rf.as_standard_layout().into_owned();
            }
            decode_events_in_place(rf.view_mut(), &plan, shift_rf, aligner, frames)
        }
        Samples::Iq {
            data: iq,
            demod_frequency,
        } => {
            if !iq.is_standard_layout() {
                *iq = iq.as_standard_layout().into_owned();
            }
            let shift = shift_iq(*demod_frequency, fs);
            decode_events_in_place(iq.view_mut(), &plan, shift, aligner, frames)
        }
    }
    Ok(())
}

fn decode_reusing(
    data: &ChannelData,
    alignment: EventAlignment,
    frames: Range<usize>,
    reuse: Option<AngleSamples>,
) -> Result<AngleSamples> {
    data.validate()?;
    let acq = &data.acquisition;
    match &acq.sequence.coding {
        Coding::Conventional => decode_samples_frames(
            &data.samples,
            acq.sequence.n_angles(),
            None,
            acq.sampling_frequency,
            alignment,
            frames,
            reuse,
        ),
        Coding::Hadamard { slot_delay } => decode_samples_frames(
            &data.samples,
            acq.sequence.n_angles(),
            Some(slot_delay * acq.sampling_frequency),
            acq.sampling_frequency,
            alignment,
            frames,
            reuse,
        ),
        Coding::Matrix(code) => decode_code_frames(
            &data.samples,
            code,
            acq.sampling_frequency,
            alignment,
            frames,
            reuse,
        ),
    }
}

/// As [`decode_aligned`], on bare samples (events, channels, samples) of `n` angles per compound
/// frame: Hadamard-coded with pulse slots `slot_shift` samples apart (`None`: conventional, only
/// split), sampled at `sampling_frequency` (Hz; it rotates the phase of shifted IQ).
pub fn decode_samples(
    samples: &Samples,
    n: usize,
    slot_shift: Option<f64>,
    sampling_frequency: f64,
    alignment: EventAlignment,
) -> Result<AngleSamples> {
    check_frames(samples, n)?;
    let frames = 0..samples.dim().0 / n;
    decode_samples_frames(
        samples,
        n,
        slot_shift,
        sampling_frequency,
        alignment,
        frames,
        None,
    )
}

/// [`decode_samples`], keeping compound frames `frames`, into `reuse`'s memory where it fits.
fn decode_samples_frames(
    samples: &Samples,
    n: usize,
    slot_shift: Option<f64>,
    sampling_frequency: f64,
    alignment: EventAlignment,
    frames: Range<usize>,
    reuse: Option<AngleSamples>,
) -> Result<AngleSamples> {
    check_frames(samples, n)?;
    check_kept(samples, n, &frames)?;
    let slot_shift = slot_shift.map(checked_slot_shift).transpose()?;
    crate::core::error::require_positive("sampling frequency", sampling_frequency)?;
    match slot_shift {
        None => {
            let events = s![frames.start * n..frames.end * n, .., ..];
            Ok(match samples {
                Samples::Rf(rf) => AngleSamples::Rf(split(rf.slice(events), n)),
                Samples::Iq {
                    data,
                    demod_frequency,
                } => AngleSamples::Iq {
                    data: split(data.slice(events), n),
                    demod_frequency: *demod_frequency,
                },
            })
        }
        Some(shift) => {
            let plan = hadamard_plan(n, shift)?;
            decode_with(samples, &plan, sampling_frequency, alignment, frames, reuse)
        }
    }
}

/// As [`decode_samples`], for samples (events, channels, samples) transmitted with the explicit
/// code `code`: slot k's record is Σ_i D[k][i]·event_i with D = [`TransmitCode::decoding_matrix`],
/// advanced by its start τ_k; events are aligned in slow time as `alignment` says when some event
/// fires several slots.
pub fn decode_code(
    samples: &Samples,
    code: &TransmitCode,
    sampling_frequency: f64,
    alignment: EventAlignment,
) -> Result<AngleSamples> {
    let n = code.order();
    check_frames(samples, n)?;
    let frames = 0..samples.dim().0 / n;
    decode_code_frames(samples, code, sampling_frequency, alignment, frames, None)
}

/// [`decode_code`], keeping compound frames `frames`, into `reuse`'s memory where it fits.
fn decode_code_frames(
    samples: &Samples,
    code: &TransmitCode,
    sampling_frequency: f64,
    alignment: EventAlignment,
    frames: Range<usize>,
    reuse: Option<AngleSamples>,
) -> Result<AngleSamples> {
    let n = code.order();
    check_frames(samples, n)?;
    check_kept(samples, n, &frames)?;
    crate::core::error::require_positive("sampling frequency", sampling_frequency)?;
    let plan = code_plan(code, sampling_frequency)?;
    decode_with(samples, &plan, sampling_frequency, alignment, frames, reuse)
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

/// Advances an RF trace by a slot's start.
fn shift_rf(shifter: &TraceShifter, trace: &mut [f32], shift: f64) {
    shifter.shift_real(trace, shift)
}

/// Advances an IQ trace demodulated at `fd` (Hz), sampled at `fs` (Hz), by a slot's start.
fn shift_iq(fd: f64, fs: f64) -> impl Fn(&TraceShifter, &mut [Complex32], f64) + Sync {
    move |shifter, trace, shift| {
        shifter.shift_complex(trace, shift);
        // Baseband of an advanced analytic signal: IQ(t + τ)·exp(+2πi f_d τ).
        let phase = 2.0 * std::f64::consts::PI * fd * shift / fs;
        let rot = Complex32::new(phase.cos() as f32, phase.sin() as f32);
        trace.iter_mut().for_each(|v| *v *= rot);
    }
}

fn split<T: Copy + Send + Sync + Zero>(events: ArrayView3<T>, n: usize) -> Array4<T> {
    let (ne, nc, ns) = events.dim();
    let frames = ne / n;
    let mut out = Array4::<T>::from_elem((n, frames, nc, ns), T::zero());
    for k in 0..n {
        out.slice_mut(s![k, .., .., ..])
            .assign(&events.slice(s![k..;n, .., ..]));
    }
    out
}

/// Resamples, per channel, the slow-time series of each event of a coded frame to the frame's
/// mid-event time: event i (of n) is advanced by ((n − 1)/2 − i)/n frame periods.
///
/// Band-limited interpolation by a finite windowed sinc: each output frame is a weighted sum of
/// the [`ALIGN_HALF`] frames on either side of it (a Kaiser-windowed sinc, weights summing to 1),
/// so a frame depends only on its neighbours and a block of frames decoded with that many frames
/// of margin gives the whole recording's values exactly (where the decoded frames reach an end
/// of the recording they must also hold the [`ALIGN_FIT_FRAMES`] the predictor below is fitted
/// on: [`crate::pipeline::blocks::Blocks::END_FRAMES`]). Beyond the first and last frames the
/// series is continued by linear prediction: an autoregressive model of order [`ALIGN_ORDER`],
/// fitted by forward–backward least squares on the [`ALIGN_FIT_FRAMES`] frames nearest that end,
/// pooled over the tile of neighbouring samples aligned together (they share a Doppler
/// spectrum), predicts the missing frames. A Doppler signal is a few steady tones, which such a
/// model continues well (the forward–backward fit assumes them steady, as stationary flow is);
/// the earlier mirror extension reversed a steady tone at the ends and read the first and last
/// frames 60 % off.
struct SlowTimeAligner {
    frames: usize,
    events_per_frame: usize,
    /// Per event of the frame: the interpolation weights of frames f − ALIGN_HALF ..= f + ALIGN_HALF.
    weights: Vec<[f32; 2 * ALIGN_HALF + 1]>,
}

/// Frames on either side of an output frame that the mid-frame interpolator reads.
pub const ALIGN_HALF: usize = 12;

/// Order of the linear predictor that continues a series beyond its ends.
pub const ALIGN_ORDER: usize = 4;

/// Frames at each end of a series the linear predictor is fitted on (all, when fewer).
pub const ALIGN_FIT_FRAMES: usize = 24;

/// Kaiser window parameter of the interpolator (β): side lobes near −60 dB.
const ALIGN_KAISER_BETA: f64 = 6.0;

impl SlowTimeAligner {
    /// An aligner for recordings of `frames` compound frames of `events_per_frame` events each.
    fn new(frames: usize, events_per_frame: usize) -> Self {
        let centre = (events_per_frame as f64 - 1.0) / 2.0;
        let weights = (0..events_per_frame)
            .map(|i| {
                let advance = (centre - i as f64) / events_per_frame as f64;
                interpolation_weights(advance)
            })
            .collect();
        SlowTimeAligner {
            frames,
            events_per_frame,
            weights,
        }
    }

    /// Aligned events of the frames `kept` of one channel, into `out` (kept frames × events
    /// rows of `ns` samples): each row the weighted sum of the event's rows of the
    /// 2·ALIGN_HALF + 1 frames around it. `row(i)` is event row i (frame · events + event) of the
    /// channel's recording. Frames beyond the recording's ends are predicted, and only where a
    /// kept frame's window reaches them (the first and last block): a block's margin frames are
    /// read, never aligned.
    fn align_kept<'a, T>(
        &self,
        row: impl Fn(usize) -> &'a [T],
        ns: usize,
        kept: Range<usize>,
        scratch: &mut AlignScratch<T>,
        out: &mut [T],
    ) where
        T: SlowTimeSample + Zero + std::ops::Mul<f32, Output = T> + std::ops::AddAssign + 'a,
    {
        let (n, f) = (self.events_per_frame, self.frames);
        let h = ALIGN_HALF;
        let need_head = kept.start < h;
        let need_tail = kept.end + h > f;
        if need_head || need_tail {
            scratch.head.resize(h * n * ns, T::zero());
            scratch.tail.resize(h * n * ns, T::zero());
            self.predict_ends(&row, ns, need_head, need_tail, scratch);
        }
        let (head, tail) = (&scratch.head, &scratch.tail);
        // Frame g (from −ALIGN_HALF to f + ALIGN_HALF), event e.
        let frame_row = |g: isize, e: usize| -> &[T] {
            if g < 0 {
                let t = (g + h as isize) as usize;
                &head[(t * n + e) * ns..(t * n + e + 1) * ns]
            } else if g as usize >= f {
                let t = g as usize - f;
                &tail[(t * n + e) * ns..(t * n + e + 1) * ns]
            } else {
                row(g as usize * n + e)
            }
        };
        // In runs of samples whose rows stay in L2 while every kept frame sums them; the
        // sum runs along each row, which vectorises.
        const RUN: usize = 512;
        for s0 in (0..ns).step_by(RUN) {
            let s1 = (s0 + RUN).min(ns);
            for e in 0..n {
                let w = &self.weights[e];
                for (kf, frame) in kept.clone().enumerate() {
                    let dest = &mut out[(kf * n + e) * ns + s0..(kf * n + e) * ns + s1];
                    let sources: [&[f32]; 2 * ALIGN_HALF + 1] = std::array::from_fn(|k| {
                        let g = frame as isize + k as isize - h as isize;
                        T::floats(&frame_row(g, e)[s0..s1])
                    });
                    weighted_rows(T::floats_mut(dest), &sources, w);
                }
            }
        }
    }

    /// The ALIGN_HALF frames predicted before the first frame (`scratch.head`, frame −ALIGN_HALF
    /// first) and after the last (`scratch.tail`), each (frames × events) rows, as [`extend`]
    /// continues a series: from the ALIGN_FIT_FRAMES frames at that end, pooled over tiles of
    /// neighbouring samples.
    fn predict_ends<'a, T: SlowTimeSample + 'a>(
        &self,
        row: &impl Fn(usize) -> &'a [T],
        ns: usize,
        head: bool,
        tail: bool,
        scratch: &mut AlignScratch<T>,
    ) {
        let (n, f, per, h) = (self.events_per_frame, self.frames, T::PER_LANE, ALIGN_HALF);
        // The predictors see only the frames they are fitted on: a series of those frames
        // alone continues as the whole series does.
        let fit = ALIGN_FIT_FRAMES.min(f);
        let len = fit + 2 * h;
        scratch.lanes.resize(TILE * len, Complex32::new(0.0, 0.0));
        for (is_tail, wanted) in [(false, head), (true, tail)] {
            if !wanted {
                continue;
            }
            let first = if is_tail { f - fit } else { 0 };
            for e in 0..n {
                for s0 in (0..ns).step_by(per * TILE) {
                    let samples = (per * TILE).min(ns - s0);
                    let count = samples.div_ceil(per);
                    let lanes = &mut scratch.lanes[..count * len];
                    for frame in 0..fit {
                        let source = &row((first + frame) * n + e)[s0..s0 + samples];
                        for (j, lane) in source.chunks(per).enumerate() {
                            lanes[j * len + h + frame] = T::pack(lane);
                        }
                    }
                    let end = if is_tail { End::Tail } else { End::Head };
                    extend(lanes, fit, T::REAL, end);
                    let (out, from) = if is_tail {
                        (&mut scratch.tail, h + fit)
                    } else {
                        (&mut scratch.head, 0)
                    };
                    for t in 0..h {
                        let dest = &mut out[(t * n + e) * ns + s0..(t * n + e) * ns + s0 + samples];
                        for (j, lane) in dest.chunks_mut(per).enumerate() {
                            T::unpack(lanes[j * len + from + t], lane);
                        }
                    }
                }
            }
        }
    }
}

/// `dest` = Σ_k w[k]·sources[k], element by element, summed from zero in the order of k, with
/// the widest vectors the CPU has (the same sums in any width: no fused multiply-adds).
fn weighted_rows(dest: &mut [f32], sources: &[&[f32]], w: &[f32]) {
    #[cfg(target_arch = "x86_64")]
    {
        if is_x86_feature_detected!("avx512f") {
            // SAFETY: AVX-512F was detected.
            return unsafe { weighted_rows_avx512(dest, sources, w) };
        }
        if is_x86_feature_detected!("avx2") {
            // SAFETY: AVX2 was detected.
            return unsafe { weighted_rows_avx2(dest, sources, w) };
        }
    }
    weighted_rows_portable(dest, sources, w)
}

/// [`weighted_rows`] compiled for AVX-512.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn weighted_rows_avx512(dest: &mut [f32], sources: &[&[f32]], w: &[f32]) {
    weighted_rows_portable(dest, sources, w)
}

/// [`weighted_rows`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn weighted_rows_avx2(dest: &mut [f32], sources: &[&[f32]], w: &[f32]) {
    weighted_rows_portable(dest, sources, w)
}

#[inline(always)]
fn weighted_rows_portable(dest: &mut [f32], sources: &[&[f32]], w: &[f32]) {
    dest.fill(0.0);
    for (source, &wk) in sources.iter().zip(w) {
        for (a, &x) in dest.iter_mut().zip(source.iter()) {
            *a += x * wk;
        }
    }
}

/// Working arrays of [`SlowTimeAligner::align_kept`] for one channel, kept by a worker from one
/// channel to the next.
struct AlignScratch<T> {
    head: Vec<T>,
    tail: Vec<T>,
    lanes: Vec<Complex32>,
}

impl<T> Default for AlignScratch<T> {
    fn default() -> Self {
        AlignScratch {
            head: Vec::new(),
            tail: Vec::new(),
            lanes: Vec::new(),
        }
    }
}

/// Weights of the Kaiser-windowed sinc that reads a series at `advance` (frames, |advance| < 1)
/// after each frame, for frames −ALIGN_HALF ..= ALIGN_HALF around it, normalised to sum 1 (a still
/// series is unchanged).
fn interpolation_weights(advance: f64) -> [f32; 2 * ALIGN_HALF + 1] {
    let reach = (ALIGN_HALF + 1) as f64;
    let bessel_i0 = |x: f64| {
        let (mut sum, mut term) = (1.0f64, 1.0f64);
        for k in 1..40 {
            term *= (x / (2.0 * k as f64)).powi(2);
            sum += term;
        }
        sum
    };
    let raw: Vec<f64> = (0..=2 * ALIGN_HALF)
        .map(|j| {
            let t = j as f64 - ALIGN_HALF as f64 - advance;
            let sinc = if t.abs() < 1e-12 {
                1.0
            } else {
                (std::f64::consts::PI * t).sin() / (std::f64::consts::PI * t)
            };
            let u = (t / reach).clamp(-1.0, 1.0);
            sinc * bessel_i0(ALIGN_KAISER_BETA * (1.0 - u * u).sqrt())
                / bessel_i0(ALIGN_KAISER_BETA)
        })
        .collect();
    let total: f64 = raw.iter().sum();
    let mut w = [0.0f32; 2 * ALIGN_HALF + 1];
    for (o, r) in w.iter_mut().zip(&raw) {
        *o = (r / total) as f32;
    }
    w
}

/// An end of a series of frames.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum End {
    /// Before the first frame.
    Head,
    /// After the last frame.
    Tail,
}

/// Continues every series of `lanes` (consecutive runs of `frames` + 2·ALIGN_HALF, the frames at
/// ALIGN_HALF..ALIGN_HALF + frames) by ALIGN_HALF predicted frames beyond `end`: a linear
/// predictor fitted on the series' ALIGN_FIT_FRAMES frames nearest that end, pooled over the
/// lanes, with real coefficients when each lane carries two real series (`real`). The other end's
/// slots are left as they are: an end predictor sees only its own end's frames.
fn extend(lanes: &mut [Complex32], frames: usize, real: bool, end: End) {
    let len = frames + 2 * ALIGN_HALF;
    let order = ALIGN_ORDER.min(frames.saturating_sub(2) / 2);
    let fit_frames = ALIGN_FIT_FRAMES.min(frames);
    let from = match end {
        End::Head => 0,
        End::Tail => frames - fit_frames,
    };
    let fitted = lanes
        .chunks_exact(len)
        .map(|series| &series[ALIGN_HALF + from..ALIGN_HALF + from + fit_frames]);
    let a = predictor(fitted, order, real);
    for series in lanes.chunks_exact_mut(len) {
        match end {
            // After the last frame: x[t] = Σ_j a_j x[t − j].
            End::Tail => {
                for t in ALIGN_HALF + frames..len {
                    let mut v = Complex64::new(0.0, 0.0);
                    for (j, a) in a.iter().enumerate() {
                        let x = series[t - 1 - j];
                        v += a * Complex64::new(x.re as f64, x.im as f64);
                    }
                    series[t] = Complex32::new(v.re as f32, v.im as f32);
                }
            }
            // Before the first: x[t] = Σ_j a_j* x[t + j].
            End::Head => {
                for t in (0..ALIGN_HALF).rev() {
                    let mut v = Complex64::new(0.0, 0.0);
                    for (j, a) in a.iter().enumerate() {
                        let x = series[t + 1 + j];
                        v += a.conj() * Complex64::new(x.re as f64, x.im as f64);
                    }
                    series[t] = Complex32::new(v.re as f32, v.im as f32);
                }
            }
        }
    }
}

/// Coefficients a_1..a_p of the forward–backward least-squares linear predictor of `series`
/// (x[t] ≈ Σ_j a_j x[t − j], and x[t] ≈ Σ_j a_j* x[t + j]), real when `real`. With fewer than
/// one equation per unknown, or a singular system, the predictor repeats the last value.
fn predictor<'a>(
    series: impl Iterator<Item = &'a [Complex32]>,
    order: usize,
    real: bool,
) -> Vec<Complex64> {
    let hold = || {
        let mut a = vec![Complex64::new(0.0, 0.0); order.max(1)];
        a[0] = Complex64::new(1.0, 0.0);
        a
    };
    if order == 0 {
        return hold();
    }
    let p = order.min(ALIGN_ORDER);
    const ZERO: Complex64 = Complex64::new(0.0, 0.0);
    // On the stack, and only the upper triangle: the Gram matrix is Hermitian, and the lower
    // triangle, conjugated from the upper, comes out bit for bit as summed term by term.
    let mut upper = [[ZERO; ALIGN_ORDER]; ALIGN_ORDER];
    let mut rhs = vec![ZERO; p];
    let mut add = |past: &[Complex64; ALIGN_ORDER], target: Complex64| {
        for j in 0..p {
            for k in j..p {
                upper[j][k] += past[j].conj() * past[k];
            }
            rhs[j] += past[j].conj() * target;
        }
    };
    let (mut past, mut future) = ([ZERO; ALIGN_ORDER], [ZERO; ALIGN_ORDER]);
    let mut widened = [ZERO; ALIGN_FIT_FRAMES];
    for narrow in series {
        // Series are at most ALIGN_FIT_FRAMES long (the frames a predictor is fitted on).
        let x = &mut widened[..narrow.len()];
        for (wide, v) in x.iter_mut().zip(narrow) {
            *wide = Complex64::new(v.re as f64, v.im as f64);
        }
        for t in p..x.len() {
            for j in 1..=p {
                // Forward: x[t] from x[t − 1], …, x[t − p].
                past[j - 1] = x[t - j];
                // Backward: x[t − p] from x[t − p + 1], …, x[t], conjugated so the same a_j
                // serve.
                future[j - 1] = x[t - p + j].conj();
            }
            add(&past, x[t]);
            add(&future, x[t - p].conj());
        }
    }
    let mut gram: Vec<Vec<Complex64>> = (0..p)
        .map(|j| {
            (0..p)
                .map(|k| {
                    if k >= j {
                        upper[j][k]
                    } else {
                        upper[k][j].conj()
                    }
                })
                .collect()
        })
        .collect();
    if real {
        for row in gram.iter_mut() {
            for v in row.iter_mut() {
                *v = Complex64::new(v.re, 0.0);
            }
        }
        for v in rhs.iter_mut() {
            *v = Complex64::new(v.re, 0.0);
        }
    }
    // A light ridge keeps the solve stable on series that are nearly constant or zero.
    let scale = (0..p).map(|j| gram[j][j].re).fold(0.0, f64::max);
    if !(scale > 0.0 && scale.is_finite()) {
        return hold();
    }
    for (j, row) in gram.iter_mut().enumerate() {
        row[j] += 1e-6 * scale;
    }
    solve_small(gram, rhs).unwrap_or_else(hold)
}

/// Solves a small complex linear system by Gaussian elimination with partial pivoting.
fn solve_small(mut a: Vec<Vec<Complex64>>, mut b: Vec<Complex64>) -> Option<Vec<Complex64>> {
    let n = b.len();
    for col in 0..n {
        let pivot = (col..n).max_by(|&i, &j| a[i][col].norm().total_cmp(&a[j][col].norm()))?;
        if a[pivot][col].norm() == 0.0 {
            return None;
        }
        a.swap(col, pivot);
        b.swap(col, pivot);
        let (upper, lower) = a.split_at_mut(col + 1);
        let pivot_row = &upper[col];
        let pivot_b = b[col];
        for (row, rhs) in lower.iter_mut().zip(&mut b[col + 1..]) {
            let f = row[col] / pivot_row[col];
            for (v, p) in row[col..].iter_mut().zip(&pivot_row[col..]) {
                *v -= f * p;
            }
            *rhs -= f * pivot_b;
        }
    }
    let mut x = vec![Complex64::new(0.0, 0.0); n];
    for row in (0..n).rev() {
        let mut v = b[row];
        for k in row + 1..n {
            v -= a[row][k] * x[k];
        }
        x[row] = v / a[row][row];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// A sample type the [`SlowTimeAligner`] resamples, carried in complex lanes.
trait SlowTimeSample: Copy {
    /// Samples per complex lane: two real ones travel as the real and imaginary parts of one
    /// (the interpolator's weights and a real series' predictor are real, so they do not mix), a
    /// complex one alone.
    const PER_LANE: usize;
    /// Whether each lane carries real series (their predictor must be real).
    const REAL: bool;
    /// Packs up to `PER_LANE` samples into a lane (a missing last one as zero).
    fn pack(samples: &[Self]) -> Complex32;
    /// Unpacks a lane into the samples it was packed from.
    fn unpack(lane: Complex32, samples: &mut [Self]);
    /// The samples as their floats (a complex one as its real and imaginary parts).
    fn floats(samples: &[Self]) -> &[f32];
    /// [`SlowTimeSample::floats`], writable.
    fn floats_mut(samples: &mut [Self]) -> &mut [f32];
}

impl SlowTimeSample for f32 {
    const PER_LANE: usize = 2;
    const REAL: bool = true;
    fn pack(samples: &[f32]) -> Complex32 {
        Complex32::new(samples[0], samples.get(1).copied().unwrap_or(0.0))
    }
    fn unpack(lane: Complex32, samples: &mut [f32]) {
        samples[0] = lane.re;
        if let Some(im) = samples.get_mut(1) {
            *im = lane.im;
        }
    }
    fn floats(samples: &[f32]) -> &[f32] {
        samples
    }
    fn floats_mut(samples: &mut [f32]) -> &mut [f32] {
        samples
    }
}

impl SlowTimeSample for Complex32 {
    const PER_LANE: usize = 1;
    const REAL: bool = false;
    fn pack(samples: &[Complex32]) -> Complex32 {
        samples[0]
    }
    fn unpack(lane: Complex32, samples: &mut [Complex32]) {
        samples[0] = lane;
    }
    fn floats(samples: &[Complex32]) -> &[f32] {
        crate::form::iq::complex_floats(samples)
    }
    fn floats_mut(samples: &mut [Complex32]) -> &mut [f32] {
        crate::form::iq::complex_floats_mut(samples)
    }
}

/// Series resampled together by [`SlowTimeAligner`] (and pooled to fit its predictor): neighbouring
/// samples of one channel, which share a Doppler spectrum; few enough that the buffer stays in
/// cache while it is transposed in and out.
const TILE: usize = 16;

/// Decodes coded events: per channel, the events aligned by `aligner` if given, then for every
/// frame of `kept` slot k = Σ_i D[k][i]·event_i (D = `plan.matrix`), advanced by
/// `plan.shifts[k]` samples: (slots, kept frames, channels, samples).
fn decode_events<T, F>(
    events: ArrayView3<T>,
    plan: &DecodePlan,
    shift: F,
    aligner: Option<&SlowTimeAligner>,
    kept: Range<usize>,
    reuse: Option<Array4<T>>,
) -> Array4<T>
where
    T: SlowTimeSample + Send + Sync + Zero + std::ops::Mul<f32, Output = T> + std::ops::AddAssign,
    F: Fn(&TraceShifter, &mut [T], f64) + Sync,
{
    let n = plan.shifts.len();
    let (_, nc, ns) = events.dim();
    let shifter = plan.shifter(ns);
    // Every element is written below, so a reused array needs no clearing.
    let mut out = crate::core::buffers::array_reusing(reuse, (n, kept.len(), nc, ns));
    // Rows of samples are read where they lie: event i of channel c is row i·nc + c.
    let events = events.as_standard_layout();
    let data = events.as_slice().expect("standard layout");
    let row = |c: usize| move |i: usize| &data[(i * nc + c) * ns..(i * nc + c + 1) * ns];
    out.axis_iter_mut(Axis(2))
        .into_par_iter()
        .enumerate()
        .for_each_init(ChannelScratch::default, |scratch, (c, mut channel_out)| {
            scratch.align(row(c), ns, n, aligner, kept.clone());
            scratch.decode(
                plan,
                &shifter,
                &shift,
                ns,
                kept.len(),
                |k, kept_f, trace| {
                    let mut dest = channel_out.slice_mut(s![k, kept_f, ..]);
                    match dest.as_slice_mut() {
                        Some(dest) => dest.copy_from_slice(trace),
                        None => dest.assign(&ndarray::ArrayView1::from(trace)),
                    }
                },
            );
        });
    out
}

/// As [`decode_events`], in `events`' own memory: after it, event `f·n + k` of every frame f in
/// `kept` holds slot k's record of that frame. Each channel's events are read (aligned) into a
/// scratch buffer before any of them is overwritten, so the result is [`decode_events`]'s to
/// the bit.
fn decode_events_in_place<T, F>(
    mut events: ArrayViewMut3<T>,
    plan: &DecodePlan,
    shift: F,
    aligner: Option<&SlowTimeAligner>,
    kept: Range<usize>,
) where
    T: SlowTimeSample + Send + Sync + Zero + std::ops::Mul<f32, Output = T> + std::ops::AddAssign,
    F: Fn(&TraceShifter, &mut [T], f64) + Sync,
{
    let n = plan.shifts.len();
    let ns = events.dim().2;
    let shifter = plan.shifter(ns);
    events.axis_iter_mut(Axis(1)).into_par_iter().for_each_init(
        ChannelScratch::default,
        |scratch, mut channel| {
            {
                let rows = channel.view();
                let row = |i: usize| {
                    rows.index_axis_move(Axis(0), i)
                        .to_slice()
                        .expect("a row of samples is contiguous")
                };
                scratch.align(row, ns, n, aligner, kept.clone());
            }
            scratch.decode(
                plan,
                &shifter,
                &shift,
                ns,
                kept.len(),
                |k, kept_f, trace| {
                    channel
                        .row_mut((kept.start + kept_f) * n + k)
                        .as_slice_mut()
                        .expect("a row of samples is contiguous")
                        .copy_from_slice(trace)
                },
            );
        },
    );
}

impl DecodePlan {
    /// The shifter of this plan's slot advances for records of `ns` samples.
    fn shifter(&self, ns: usize) -> TraceShifter {
        let max_shift = self.shifts.iter().fold(0.0f64, |m, s| m.max(s.abs()));
        TraceShifter::new(ns, max_shift)
    }
}

/// One worker's buffers for decoding a channel: the kept frames' events (aligned or as recorded)
/// and the trace being decoded.
struct ChannelScratch<T> {
    align: AlignScratch<T>,
    /// Kept frames × events rows.
    events: Vec<T>,
    trace: Vec<T>,
}

impl<T> Default for ChannelScratch<T> {
    fn default() -> Self {
        ChannelScratch {
            align: AlignScratch::default(),
            events: Vec::new(),
            trace: Vec::new(),
        }
    }
}

impl<T> ChannelScratch<T>
where
    T: SlowTimeSample + Zero + std::ops::Mul<f32, Output = T> + std::ops::AddAssign,
{
    /// The kept frames' events of one channel (`row(i)`: its event i), aligned by `aligner` if
    /// given, into `self.events`.
    fn align<'a>(
        &mut self,
        row: impl Fn(usize) -> &'a [T],
        ns: usize,
        n: usize,
        aligner: Option<&SlowTimeAligner>,
        kept: Range<usize>,
    ) where
        T: 'a,
    {
        match aligner {
            Some(aligner) => {
                self.events.resize(kept.len() * n * ns, T::zero());
                aligner.align_kept(row, ns, kept, &mut self.align, &mut self.events);
            }
            None => {
                self.events.clear();
                for i in kept.start * n..kept.end * n {
                    self.events.extend_from_slice(row(i));
                }
            }
        }
    }

    /// Per kept frame and slot k, Σ_i D[k][i]·event_i advanced by slot k's start, handed to
    /// `write(k, kept frame, trace)`.
    fn decode(
        &mut self,
        plan: &DecodePlan,
        shifter: &TraceShifter,
        shift: &impl Fn(&TraceShifter, &mut [T], f64),
        ns: usize,
        kept: usize,
        mut write: impl FnMut(usize, usize, &[T]),
    ) {
        let n = plan.shifts.len();
        self.trace.resize(ns, T::zero());
        let trace = &mut self.trace;
        for kept_f in 0..kept {
            for k in 0..n {
                trace.fill(T::zero());
                for i in 0..n {
                    let weight = plan.matrix[k * n + i];
                    if weight == 0.0 {
                        continue;
                    }
                    let event = &self.events[(kept_f * n + i) * ns..(kept_f * n + i + 1) * ns];
                    for (a, &m) in trace.iter_mut().zip(event) {
                        *a += m * weight;
                    }
                }
                shift(shifter, trace, plan.shifts[k]);
                write(k, kept_f, trace);
            }
        }
    }
}

/// Encodes per-angle records (angles, channels, samples) into the n events of one coded compound
/// frame (events, channels, samples): event i = `Σ_k H[i][k]·x_k` delayed by k·`slot_shift` samples.
/// The inverse of [`decode`] for a still medium, up to the factor n.
pub fn encode(per_angle: ArrayView3<f32>, h: &Hadamard, slot_shift: f64) -> Result<Array3<f32>> {
    let n = per_angle.dim().0;
    if n != h.order() {
        return Err(Error::Shape(format!(
            "{n} angles for a Hadamard matrix of order {}",
            h.order()
        )));
    }
    let shifts: Vec<f64> = (0..n).map(|k| k as f64 * slot_shift).collect();
    Ok(encode_with(per_angle, |i, k| h.get(i, k), &shifts))
}

/// Encodes per-angle records (angles, channels, samples) sampled at `sampling_frequency` (Hz)
/// into the n events of one compound frame transmitted with `code`: event i =
/// `Σ_k A[i][k]·x_k` delayed by slot k's start. The inverse of [`decode_code`] for a still medium,
/// up to the factor [`TransmitCode::decoding_gain`].
pub fn encode_code(
    per_angle: ArrayView3<f32>,
    code: &TransmitCode,
    sampling_frequency: f64,
) -> Result<Array3<f32>> {
    code.validate()?;
    let n = per_angle.dim().0;
    if n != code.order() {
        return Err(Error::Shape(format!(
            "{n} angles for a transmit code of order {}",
            code.order()
        )));
    }
    let shifts: Vec<f64> = code
        .slot_starts
        .iter()
        .map(|t| t * sampling_frequency)
        .collect();
    Ok(encode_with(
        per_angle,
        |i, k| code.weight(i, k) as f32,
        &shifts,
    ))
}

/// Event i = Σ_k weight(i, k)·x_k delayed by `shifts[k]` samples.
fn encode_with(
    per_angle: ArrayView3<f32>,
    weight: impl Fn(usize, usize) -> f32,
    shifts: &[f64],
) -> Array3<f32> {
    let (n, nc, ns) = per_angle.dim();
    let max_shift = shifts.iter().fold(0.0f64, |m, s| m.max(s.abs()));
    let shifter = TraceShifter::new(ns, max_shift);
    let mut delayed = per_angle.to_owned();
    for (k, mut angle) in delayed.outer_iter_mut().enumerate() {
        for mut row in angle.outer_iter_mut() {
            let mut trace = row.to_vec();
            shifter.shift_real(&mut trace, -shifts[k]);
            row.assign(&ndarray::ArrayView1::from(&trace));
        }
    }
    let mut out = Array3::<f32>::zeros((n, nc, ns));
    for i in 0..n {
        for k in 0..n {
            let sign = weight(i, k);
            out.slice_mut(s![i, .., ..])
                .zip_mut_with(&delayed.slice(s![k, .., ..]), |o, &x| *o += x * sign);
        }
    }
    out
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
