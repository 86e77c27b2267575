//! Slow-time alignment of coded events ([`EventAlignment::MidFrame`]): each event's series of one
//! sample per frame resampled, band-limited (Kaiser-windowed sinc), to the frame's mid-event time.

use super::*;

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
pub(super) struct SlowTimeAligner {
    pub(super) frames: usize,
    pub(super) events_per_frame: usize,
    /// Per event of the frame: the interpolation weights of frames f − ALIGN_HALF ..= f + ALIGN_HALF.
    pub(super) weights: Vec<[f32; 2 * ALIGN_HALF + 1]>,
}

/// Frames on either side of an output frame that the mid-frame interpolator reads.
pub const ALIGN_HALF: usize = 12;

/// Kept frames the interpolator sums at once ([`sliding_weighted_rows`]).
const ALIGN_AT_ONCE: usize = 4;

/// Order of the linear predictor that continues a series beyond its ends.
pub const ALIGN_ORDER: usize = 4;

/// Frames at each end of a series the linear predictor is fitted on (all, when fewer).
pub const ALIGN_FIT_FRAMES: usize = 24;

/// Kaiser window parameter of the interpolator (β): side lobes near −60 dB.
pub(super) const ALIGN_KAISER_BETA: f64 = 6.0;

impl SlowTimeAligner {
    /// An aligner for recordings of `frames` compound frames of `events_per_frame` events each.
    pub(super) fn new(frames: usize, events_per_frame: usize) -> Self {
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
    pub(super) fn align_kept<'a, T>(
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
        // Row k of the window of `frame` (its frame − ALIGN_HALF + k), samples s0..s1.
        let window_row = |frame: usize, k: usize, e: usize, samples: Range<usize>| {
            let g = frame as isize + k as isize - h as isize;
            T::floats(&frame_row(g, e)[samples])
        };
        // In runs of samples whose rows stay in L2 while every kept frame sums them; the
        // sum runs along each row, which vectorises.
        const RUN: usize = 512;
        for s0 in (0..ns).step_by(RUN) {
            let s1 = (s0 + RUN).min(ns);
            for e in 0..n {
                let w = &self.weights[e];
                let mut kf = 0;
                // ALIGN_AT_ONCE kept frames at a time, from the rows their windows share.
                while kf + ALIGN_AT_ONCE <= kept.len() {
                    let frame = kept.start + kf;
                    let sources: [&[f32]; 2 * ALIGN_HALF + ALIGN_AT_ONCE] =
                        std::array::from_fn(|k| window_row(frame, k, e, s0..s1));
                    // Event e of frames kf, kf + 1, …: rows n apart.
                    let mut frames = out[(kf * n + e) * ns..].chunks_mut(n * ns);
                    let mut dests: [&mut [f32]; ALIGN_AT_ONCE] = std::array::from_fn(|_| {
                        let rows = frames.next().expect("kept frames of the output");
                        T::floats_mut(&mut rows[s0..s1])
                    });
                    sliding_weighted_rows(&mut dests, &sources, w);
                    kf += ALIGN_AT_ONCE;
                }
                for (kf, frame) in kept.clone().enumerate().skip(kf) {
                    let dest = &mut out[(kf * n + e) * ns + s0..(kf * n + e) * ns + s1];
                    let sources: [&[f32]; 2 * ALIGN_HALF + 1] =
                        std::array::from_fn(|k| window_row(frame, k, e, s0..s1));
                    weighted_rows(T::floats_mut(dest), &sources, w);
                }
            }
        }
    }

    /// The ALIGN_HALF frames predicted before the first frame (`scratch.head`, frame −ALIGN_HALF
    /// first) and after the last (`scratch.tail`), each (frames × events) rows, as [`extend`]
    /// continues a series: from the ALIGN_FIT_FRAMES frames at that end, pooled over tiles of
    /// neighbouring samples.
    pub(super) fn predict_ends<'a, T: SlowTimeSample + 'a>(
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

/// Working arrays of [`SlowTimeAligner::align_kept`] for one channel, kept by a worker from one
/// channel to the next.
pub(super) struct AlignScratch<T> {
    pub(super) head: Vec<T>,
    pub(super) tail: Vec<T>,
    pub(super) lanes: Vec<Complex32>,
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
pub(super) fn interpolation_weights(advance: f64) -> [f32; 2 * ALIGN_HALF + 1] {
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
