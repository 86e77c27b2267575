//! The tables a delay-and-sum kernel reads: each pixel's taps (sample rows and rotated
//! interpolation weights) and the fixed setup of one call, shared by the tiling that fills them
//! and the per-ISA kernels that sum them.

use super::Apodization;

/// Elements whose taps the delay loop computes at a time (f64 lanes of AVX-512, two AVX2
/// vectors): a pixel's taps are computed in a whole number of these, with scratch taps after its
/// last, so that no element runs in the scalar loop a compiler adds for a remainder (which took a
/// third of the loop's time on apertures of about 70 elements).
pub(super) const TAP_LANES: usize = 8;

/// Taps ahead whose samples the AVX2 kernel prefetches into L1. Six taps (about 250 cycles of
/// that kernel's work, an L3 or DRAM latency) rather than three: the criterion `das` bench ran
/// 5–11 % faster in four of five paired runs on a 2-core AMD EPYC (Zen 3, AVX2), the same in the
/// fifth; eight taps were no better than three.
pub(super) const PF: usize = 6;

/// Everything the per-pixel delay and weight computation needs, fixed for one call.
pub(super) struct Setup {
    pub(super) element_x: Vec<f64>,
    /// `element_x` and `TAP_LANES` − 1 more positions (the last element's), so that the delay
    /// loop can run over a whole number of vectors.
    pub(super) padded_x: Vec<f64>,
    /// Whether element positions increase, so that each aperture is a contiguous element range.
    pub(super) sorted: bool,
    pub(super) angle: f64,
    pub(super) aperture: (f64, f64),
    pub(super) c: f64,
    pub(super) fs: f64,
    pub(super) t0: f64,
    pub(super) demod_frequency: f64,
    pub(super) f_number: f64,
    pub(super) apodization: Apodization,
    pub(super) n_samples: usize,
    pub(super) frames: usize,
    /// Complex samples from one row of frames to the next in the samples read: the frames, or
    /// more where rows are padded to cache lines.
    pub(super) row: usize,
}

/// Delays and weights of the pixels of a tile for one group of elements, in flat arrays so that
/// the kernel runs from one pixel's taps into the next one's: pixel p's taps are
/// `spans[p].start..spans[p].start + spans[p].len`. Per tap: `rows`, the index
/// element · n_samples + i0 of its element's row of frames at sample i0, and the rotated
/// interpolation weights c0, c1 of samples i0 and i0 + 1.
/// Invariant (by construction where filled): 0 ≤ i0 and i0 + 1 < n_samples; `rows` has `PF`
/// more entries than there are taps (zeros), so that the kernel may read ahead to prefetch.
#[derive(Default)]
pub(super) struct Taps {
    /// Per pixel, the taps the kernel runs now: those of the selected group of elements.
    pub(super) spans: Vec<Span>,
    /// Per pixel, all its taps and the element of the first: (span, element).
    apertures: Vec<(Span, usize)>,
    /// 32 bits (the caller checks that every row index fits) so that the delay loop fills them
    /// vectorised, along with the weights.
    pub(super) rows: Vec<u32>,
    pub(super) c0_re: Vec<f32>,
    pub(super) c0_im: Vec<f32>,
    pub(super) c1_re: Vec<f32>,
    pub(super) c1_im: Vec<f32>,
}

/// Where one pixel's taps lie in the arrays of [`Taps`].
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Span {
    pub(super) start: usize,
    pub(super) len: usize,
}

impl Taps {
    /// The four interpolation-weight arrays, which every table operation treats alike.
    fn weights_mut(&mut self) -> [&mut Vec<f32>; 4] {
        [
            &mut self.c0_re,
            &mut self.c0_im,
            &mut self.c1_re,
            &mut self.c1_im,
        ]
    }

    /// Empties the tables, keeping their allocations for the next group.
    pub(super) fn clear(&mut self) {
        self.spans.clear();
        self.apertures.clear();
        self.rows.clear();
        for v in self.weights_mut() {
            v.clear();
        }
    }

    /// Room for `pixels` pixels of at most `elements` taps each, so that filling a tile's table
    /// grows no array: grown by doubling, each array is copied about a dozen times per tile.
    pub(super) fn reserve(&mut self, pixels: usize, elements: usize) {
        // A pixel's taps are padded to whole TAP_LANES, and `finish` adds PF.
        let taps = pixels * elements.next_multiple_of(TAP_LANES) + PF;
        self.spans.reserve(pixels);
        self.apertures.reserve(pixels);
        self.rows.reserve(taps.saturating_sub(self.rows.len()));
        for v in self.weights_mut() {
            v.reserve(taps.saturating_sub(v.len()));
        }
    }

    /// Room for `len` more taps of a new pixel, of elements from `first` on, and `scratch` more
    /// after them, until [`Taps::drop_scratch`]; returns where they start.
    pub(super) fn push(&mut self, len: usize, scratch: usize, first: usize) -> usize {
        let start = self.rows.len();
        self.spans.push(Span { start, len });
        self.apertures.push((Span { start, len }, first));
        let end = start + len + scratch;
        self.rows.resize(end, 0);
        for v in self.weights_mut() {
            v.resize(end, 0.0);
        }
        start
    }

    /// Drops the scratch taps after the last pixel's.
    pub(super) fn drop_scratch(&mut self) {
        let end = self.spans.last().map_or(0, |span| span.start + span.len);
        self.rows.truncate(end);
        for v in self.weights_mut() {
            v.truncate(end);
        }
    }

    /// Points every pixel's span at its taps of `elements` (an empty span where its aperture
    /// has none of them).
    pub(super) fn select(&mut self, elements: std::ops::Range<usize>) {
        for (span, &(all, first)) in self.spans.iter_mut().zip(&self.apertures) {
            let lo = elements.start.clamp(first, first + all.len);
            let hi = elements.end.clamp(lo, first + all.len);
            *span = Span {
                start: all.start + lo - first,
                len: hi - lo,
            };
        }
    }

    /// Pads `rows` for the kernel's look-ahead once all pixels are in.
    pub(super) fn finish(&mut self) {
        self.rows.extend([0; PF]);
    }
}

/// Asks for the cache lines of the `bytes` at `a` and, if `row` > 0, of the same span `row`
/// complex samples further, into L1: the two rows a tap interpolates between, for the SIMD kernels.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(super) fn prefetch_near(a: *const f32, bytes: usize, row: usize) {
    use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
    let a = a.cast::<i8>();
    let b = a.wrapping_add(8 * row);
    let mut l = 0;
    while l < bytes + 63 {
        // SAFETY: prefetches never fault, whatever the address; SSE is part of x86_64.
        unsafe {
            _mm_prefetch::<_MM_HINT_T0>(a.wrapping_add(l));
            if row > 0 {
                _mm_prefetch::<_MM_HINT_T0>(b.wrapping_add(l));
            }
        }
        l += 64;
    }
}
