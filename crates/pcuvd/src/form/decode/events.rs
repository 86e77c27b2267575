//! The decoding itself, per channel and tile of samples: each frame's events aligned, combined by
//! the plan's matrix and advanced by each slot's start, into new memory or the events' own.

use super::*;

pub(super) fn split<T: Copy + Send + Sync + Zero>(events: ArrayView3<T>, n: usize) -> Array4<T> {
    let (ne, nc, ns) = events.dim();
    let frames = ne / n;
    let mut out = Array4::<T>::from_elem((n, frames, nc, ns), T::zero());
    for k in 0..n {
        out.slice_mut(s![k, .., .., ..])
            .assign(&events.slice(s![k..;n, .., ..]));
    }
    out
}

/// A sample type the [`SlowTimeAligner`] resamples, carried in complex lanes.
pub(super) trait SlowTimeSample: Copy + bytemuck::Zeroable {
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
        crate::core::buffers::complex_floats(samples)
    }
    fn floats_mut(samples: &mut [Complex32]) -> &mut [f32] {
        crate::core::buffers::complex_floats_mut(samples)
    }
}

/// Series resampled together by [`SlowTimeAligner`] (and pooled to fit its predictor): neighbouring
/// samples of one channel, which share a Doppler spectrum; few enough that the buffer stays in
/// cache while it is transposed in and out.
pub(super) const TILE: usize = 16;

/// Decodes coded events: per channel, the events aligned by `aligner` if given, then for every
/// frame of `kept` slot k = Σ_i D[k][i]·event_i (D = `plan.matrix`), advanced by
/// `plan.shifts[k]` samples: (slots, kept frames, channels, samples).
pub(super) fn decode_events<T, F>(
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
pub(super) fn decode_events_in_place<T, F>(
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
    pub(super) fn shifter(&self, ns: usize) -> TraceShifter {
        let max_shift = self.shifts.iter().fold(0.0f64, |m, s| m.max(s.abs()));
        TraceShifter::new(ns, max_shift)
    }
}

/// One worker's buffers for decoding a channel: the kept frames' events (aligned or as recorded)
/// and the trace being decoded.
pub(super) struct ChannelScratch<T> {
    pub(super) align: AlignScratch<T>,
    /// Kept frames × events rows.
    pub(super) events: Vec<T>,
    pub(super) trace: Vec<T>,
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
    pub(super) fn align<'a>(
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
    pub(super) fn decode(
        &mut self,
        plan: &DecodePlan,
        shifter: &TraceShifter,
        shift: &impl Fn(&TraceShifter, &mut [T], f64),
        ns: usize,
        kept: usize,
        mut write: impl FnMut(usize, usize, &[T]),
    ) {
        let n = plan.shifts.len();
        self.trace.resize(SLOTS_AT_ONCE * ns, T::zero());
        let mut frame: Vec<&[f32]> = Vec::with_capacity(n);
        for kept_f in 0..kept {
            // SLOTS_AT_ONCE slots at a time from one pass over the frame's events, then any
            // slots left one at a time; a zero weight skips its event.
            frame.clear();
            frame.extend((0..n).map(|i| T::floats(&self.events[(kept_f * n + i) * ns..][..ns])));
            let mut k = 0;
            while k + SLOTS_AT_ONCE <= n {
                let mut traces = self.trace.chunks_exact_mut(ns);
                let mut dests: [&mut [f32]; SLOTS_AT_ONCE] = std::array::from_fn(|_| {
                    T::floats_mut(traces.next().expect("a trace per slot"))
                });
                let matrix = &plan.matrix[k * n..(k + SLOTS_AT_ONCE) * n];
                matrix_weighted_rows(&mut dests, &frame, matrix);
                for (j, trace) in self.trace.chunks_exact_mut(ns).enumerate() {
                    shift(shifter, trace, plan.shifts[k + j]);
                    write(k + j, kept_f, trace);
                }
                k += SLOTS_AT_ONCE;
            }
            let trace = &mut self.trace[..ns];
            for k in k..n {
                let matrix = &plan.matrix[k * n..(k + 1) * n];
                matrix_weighted_rows(&mut [T::floats_mut(trace)], &frame, matrix);
                shift(shifter, trace, plan.shifts[k]);
                write(k, kept_f, trace);
            }
        }
    }
}

/// Slots a coded frame's events are combined into at once ([`matrix_weighted_rows`]).
const SLOTS_AT_ONCE: usize = 4;
