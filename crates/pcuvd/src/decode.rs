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

use ndarray::{Array2, Array3, Array4, ArrayView3, Axis, s};
use num_complex::Complex32;
use num_traits::Zero;
use rayon::prelude::*;
use rustfft::{Fft, FftPlanner};

use crate::channel::{AngleSamples, ChannelData, Samples};
use crate::error::{Error, Result};
use crate::hadamard::Hadamard;
use crate::sequence::{Coding, TransmitCode};

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
    if let Some(shift) = slot_shift
        && !(shift.is_finite() && shift >= 0.0)
    {
        return Err(crate::error::invalid(
            "slot delay",
            format!("must be finite and ≥ 0 samples, got {shift}"),
        ));
    }
    crate::error::require_positive("sampling frequency", sampling_frequency)?;
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
            let h = Hadamard::new(n)?;
            // Hᵀ: slot k gathers event i with the polarity H[i][k].
            let matrix = (0..n * n).map(|j| h.get(j % n, j / n)).collect::<Vec<_>>();
            let shifts = (0..n).map(|k| k as f64 * shift).collect::<Vec<_>>();
            let plan = DecodePlan {
                matrix,
                shifts,
                align: true,
            };
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
    crate::error::require_positive("sampling frequency", sampling_frequency)?;
    let plan = DecodePlan {
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
    };
    decode_with(samples, &plan, sampling_frequency, alignment, frames, reuse)
}

/// A whole number of compound frames of `n` events, or an error.
fn check_frames(samples: &Samples, n: usize) -> Result<()> {
    let (events, _, _) = samples.dim();
    if n == 0 || events < n || events % n != 0 {
        return Err(crate::error::Error::Shape(format!(
            "{events} transmit events is not a whole number of compound frames of {n} events"
        )));
    }
    Ok(())
}

/// `frames`, a non-empty range of the recording's compound frames of `n` events, or an error.
fn check_kept(samples: &Samples, n: usize, frames: &Range<usize>) -> Result<()> {
    let total = samples.dim().0 / n;
    if frames.start >= frames.end || frames.end > total {
        return Err(crate::error::invalid(
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
    let n = plan.shifts.len();
    let (events, _, ns) = samples.dim();
    let frames = events / n;
    if let Some(k) = plan.shifts.iter().position(|s| s.abs() >= ns as f64) {
        return Err(crate::error::invalid(
            "slot delays",
            format!(
                "slot {k} is shifted by {:.1} samples, more than its {ns}-sample record: its echoes \
                 are not in the recording",
                plan.shifts[k]
            ),
        ));
    }
    let aligner = match alignment {
        EventAlignment::MidFrame if plan.align && n > 1 && frames > 1 => {
            Some(SlowTimeAligner::new(frames, n))
        }
        _ => None,
    };
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
            |shifter, tr, s| shifter.shift_real(tr, s),
            aligner,
            kept,
            reuse_rf,
        ))),
        Samples::Iq {
            data: iq,
            demod_frequency,
        } => {
            let fd = *demod_frequency;
            let fs = sampling_frequency;
            let out = decode_events(
                iq.view(),
                plan,
                |shifter, tr, s| {
                    shifter.shift_complex(tr, s);
                    // Baseband of an advanced analytic signal: IQ(t + τ)·exp(+2πi f_d τ).
                    let phase = 2.0 * std::f64::consts::PI * fd * s / fs;
                    let rot = Complex32::new(phase.cos() as f32, phase.sin() as f32);
                    tr.iter_mut().for_each(|v| *v *= rot);
                },
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
/// Band-limited interpolation by an FFT phase ramp over the frames. The series is first extended
/// by its mirror image, so that its periodic continuation has no jump at the ends of the recording
/// (a jump would ring through the whole series). Near the ends the events are extrapolated as if
/// the signal were reflected there, which is poor for fast flow: a steady Doppler tone is not
/// mirror-symmetric, so the error is a large fraction of the echo on the last frame, falls by
/// several times each frame inward, and grows with the Doppler frequency; mid-recording the
/// alignment is close to exact. Discard the first and last few frames where they matter.
struct SlowTimeAligner {
    frames: usize,
    events_per_frame: usize,
    fft_len: usize,
    forward: Arc<dyn Fft<f32>>,
    inverse: Arc<dyn Fft<f32>>,
    /// Per event of the frame: the spectral factor of its advance, with the 1/L of the inverse FFT.
    factors: Vec<Vec<Complex32>>,
}

impl SlowTimeAligner {
    /// An aligner for recordings of `frames` compound frames of `events_per_frame` events each.
    fn new(frames: usize, events_per_frame: usize) -> Self {
        let fft_len = 2 * frames;
        let mut planner = FftPlanner::new();
        let centre = (events_per_frame as f64 - 1.0) / 2.0;
        let factors = (0..events_per_frame)
            .map(|i| {
                let advance = (centre - i as f64) / events_per_frame as f64;
                (0..fft_len)
                    .map(|m| {
                        let scale = 1.0 / fft_len as f64;
                        if 2 * m == fft_len {
                            // The Nyquist bin: a real factor keeps a real series real.
                            let c = (std::f64::consts::PI * advance).cos() * scale;
                            return Complex32::new(c as f32, 0.0);
                        }
                        let freq = if 2 * m < fft_len {
                            m as f64
                        } else {
                            m as f64 - fft_len as f64
                        };
                        let phase = 2.0 * std::f64::consts::PI * freq * advance / fft_len as f64;
                        Complex32::new((phase.cos() * scale) as f32, (phase.sin() * scale) as f32)
                    })
                    .collect()
            })
            .collect();
        SlowTimeAligner {
            frames,
            events_per_frame,
            fft_len,
            forward: planner.plan_fft_forward(fft_len),
            inverse: planner.plan_fft_inverse(fft_len),
            factors,
        }
    }

    /// Shifts every series of `buf` (consecutive runs of `fft_len`, the first `frames` samples
    /// filled) by event `event`'s advance, after mirroring each into its second half.
    fn shift_series(&self, buf: &mut [Complex32], scratch: &mut [Complex32], event: usize) {
        let (f, len) = (self.frames, self.fft_len);
        for series in buf.chunks_exact_mut(len) {
            for k in 0..f {
                series[len - 1 - k] = series[k];
            }
        }
        // With a scratch buffer of the caller's: `process` would allocate one per call, and short
        // series (a block of frames) make many calls.
        self.forward.process_with_scratch(buf, scratch);
        for series in buf.chunks_exact_mut(len) {
            series
                .iter_mut()
                .zip(&self.factors[event])
                .for_each(|(v, g)| *v *= g);
        }
        self.inverse.process_with_scratch(buf, scratch);
    }

    /// Aligns one channel's block, shape (events, samples), in place.
    fn align<T: SlowTimeSample>(&self, block: &mut Array2<T>) {
        let (n, f, len, per) = (
            self.events_per_frame,
            self.frames,
            self.fft_len,
            T::PER_LANE,
        );
        let ns = block.ncols();
        let data = block.as_slice_mut().expect("an owned array is contiguous");
        let mut buf = vec![Complex32::new(0.0, 0.0); TILE * len];
        let scratch_len = self
            .forward
            .get_inplace_scratch_len()
            .max(self.inverse.get_inplace_scratch_len());
        let mut scratch = vec![Complex32::new(0.0, 0.0); scratch_len];
        for event in 0..n {
            for s0 in (0..ns).step_by(per * TILE) {
                let samples = (per * TILE).min(ns - s0);
                let buf = &mut buf[..samples.div_ceil(per) * len];
                for frame in 0..f {
                    let start = (frame * n + event) * ns + s0;
                    let row = &data[start..start + samples];
                    for (j, lane) in row.chunks(per).enumerate() {
                        buf[j * len + frame] = T::pack(lane);
                    }
                }
                self.shift_series(buf, &mut scratch, event);
                for frame in 0..f {
                    let start = (frame * n + event) * ns + s0;
                    let row = &mut data[start..start + samples];
                    for (j, lane) in row.chunks_mut(per).enumerate() {
                        T::unpack(buf[j * len + frame], lane);
                    }
                }
            }
        }
    }
}

/// A sample type the [`SlowTimeAligner`] resamples, carried in the lanes of complex FFTs.
trait SlowTimeSample: Copy {
    /// Samples per complex lane: two real ones travel as the real and imaginary parts of one
    /// (the shift's impulse response is real, so they do not mix), a complex one alone.
    const PER_LANE: usize;
    /// Packs up to `PER_LANE` samples into a lane (a missing last one as zero).
    fn pack(samples: &[Self]) -> Complex32;
    /// Unpacks a lane into the samples it was packed from.
    fn unpack(lane: Complex32, samples: &mut [Self]);
}

impl SlowTimeSample for f32 {
    const PER_LANE: usize = 2;
    fn pack(samples: &[f32]) -> Complex32 {
        Complex32::new(samples[0], samples.get(1).copied().unwrap_or(0.0))
    }
    fn unpack(lane: Complex32, samples: &mut [f32]) {
        samples[0] = lane.re;
        if let Some(im) = samples.get_mut(1) {
            *im = lane.im;
        }
    }
}

impl SlowTimeSample for Complex32 {
    const PER_LANE: usize = 1;
    fn pack(samples: &[Complex32]) -> Complex32 {
        samples[0]
    }
    fn unpack(lane: Complex32, samples: &mut [Complex32]) {
        samples[0] = lane;
    }
}

/// Series resampled together by [`SlowTimeAligner`]: enough for the FFTs to run back to back, few
/// enough that the buffer stays in cache while it is transposed in and out.
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
    let (ne, nc, ns) = events.dim();
    let max_shift = plan.shifts.iter().fold(0.0f64, |m, s| m.max(s.abs()));
    let shifter = TraceShifter::new(ns, max_shift);
    // Every element is written below, so a reused array needs no clearing.
    let shape = (n, kept.len(), nc, ns);
    let reuse = reuse.filter(|array| array.dim() == shape && array.is_standard_layout());
    // (An array of another shape is dropped by now, before a new one is allocated.)
    let mut out = reuse.unwrap_or_else(|| Array4::<T>::from_elem(shape, T::zero()));
    out.axis_iter_mut(Axis(2))
        .into_par_iter()
        .enumerate()
        .for_each(|(c, mut channel_out)| {
            // Gathered and summed through plain slices: ndarray's strided copies and row
            // iterators made decoding 2.4 times slower.
            let mut block = Array2::from_elem((ne, ns), T::zero());
            for (e, mut row) in block.outer_iter_mut().enumerate() {
                let source = events.slice(s![e, c, ..]);
                match (row.as_slice_mut(), source.as_slice()) {
                    (Some(dst), Some(src)) => dst.copy_from_slice(src),
                    _ => row.assign(&source),
                }
            }
            if let Some(aligner) = aligner {
                aligner.align(&mut block);
            }
            let block = block.as_slice().expect("an owned array is contiguous");
            let mut trace = vec![T::zero(); ns];
            for (kept_f, f) in kept.clone().enumerate() {
                for k in 0..n {
                    trace.fill(T::zero());
                    for i in 0..n {
                        let weight = plan.matrix[k * n + i];
                        if weight == 0.0 {
                            continue;
                        }
                        let event = &block[(f * n + i) * ns..(f * n + i + 1) * ns];
                        for (a, &m) in trace.iter_mut().zip(event) {
                            *a += m * weight;
                        }
                    }
                    shift(&shifter, &mut trace, plan.shifts[k]);
                    let mut dest = channel_out.slice_mut(s![k, kept_f, ..]);
                    match dest.as_slice_mut() {
                        Some(dest) => dest.copy_from_slice(&trace),
                        None => dest.assign(&ndarray::ArrayView1::from(&trace)),
                    }
                }
            }
        });
    out
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
