//! The AVX2 + FMA accumulation kernel: a pixel's run of frames, 4 complex frames per 256-bit
//! vector and up to 20 frames, kept in registers across a group of elements, the last vector
//! masked.

use super::taps::prefetch_near;
use super::taps::{PF, Taps};
use num_complex::Complex32;
use std::arch::x86_64::*;

/// The most 4-frame vectors of one pixel whose sums stay in registers across the element loop:
/// two sums per vector (see [`run`]) and four weights leave no register to spare at 6.
pub(super) const MAX_VECTORS: usize = 5;

/// Fused multiply-adds per point (pixel × active element × frame): per tap, each 4-frame vector
/// takes four (two sums, each of two samples by a broadcast weight).
pub(super) const FMA_PER_POINT: f64 = 1.0;

/// Dispatches a run of 1..=4·MAX_VECTORS frames to its register-resident instance.
///
/// # Safety
/// AVX2 and FMA must be available; `acc` must not be empty; for every tap k in
/// `start..start + len`,
/// `(rows[k] + 1)·row + f0 + acc.len()` must lie within `data`; `taps.rows` must hold PF
/// entries beyond them.
#[allow(clippy::too_many_arguments)]
#[inline]
pub(super) unsafe fn pixel_chunk(
    acc: &mut [Complex32],
    next: *const Complex32,
    data: &[Complex32],
    f0: usize,
    row: usize,
    taps: &Taps,
    start: usize,
    len: usize,
    fresh: bool,
) {
    debug_assert!(!acc.is_empty() && acc.len().div_ceil(4) <= MAX_VECTORS);
    // SAFETY: forwarded from the caller.
    unsafe {
        // A run of whole vectors takes plain loads throughout; only a partial last vector is
        // masked (a masked load costs an extra micro-op on Intel cores).
        match (acc.len().div_ceil(4), acc.len().is_multiple_of(4)) {
            (1, true) => run::<1, false>(acc, next, data, f0, row, taps, start, len, fresh),
            (1, false) => run::<1, true>(acc, next, data, f0, row, taps, start, len, fresh),
            (2, true) => run::<2, false>(acc, next, data, f0, row, taps, start, len, fresh),
            (2, false) => run::<2, true>(acc, next, data, f0, row, taps, start, len, fresh),
            (3, true) => run::<3, false>(acc, next, data, f0, row, taps, start, len, fresh),
            (3, false) => run::<3, true>(acc, next, data, f0, row, taps, start, len, fresh),
            (4, true) => run::<4, false>(acc, next, data, f0, row, taps, start, len, fresh),
            (4, false) => run::<4, true>(acc, next, data, f0, row, taps, start, len, fresh),
            (5, true) => run::<5, false>(acc, next, data, f0, row, taps, start, len, fresh),
            (5, false) => run::<5, true>(acc, next, data, f0, row, taps, start, len, fresh),
            _ => {}
        }
    }
}

/// Asks for the lines of N 8-float vectors at `a` and, if `row` > 0, one row further into L1.
#[inline(always)]
fn prefetch<const N: usize>(a: *const f32, row: usize) {
    prefetch_near(a, 32 * N, row);
}

/// acc += `Σ_k c0[k]·a_k + c1[k]·b_k` on interleaved (re, im) pairs; with `fresh`, acc = the
/// sum, from sums started at +0 as a zeroed acc would start them (the same bits), without
/// reading acc. With c = (p, q) and a = (u, v), c·a = p·(u, v) + (−q v, q u): the loop sums
/// p·a and q·a in two registers per vector, and the swap and sign of the second are applied
/// once, after the loop, so that each tap costs four FMAs per vector and no shuffle. With
/// MASKED, the last vector is masked to the frames of `acc`: nothing beyond them is read or
/// written, and every frame is summed by the same FMAs wherever a run puts it, so that
/// processing a recording in blocks of frames gives its images bit for bit.
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx2,fma")]
unsafe fn run<const N: usize, const MASKED: bool>(
    acc: &mut [Complex32],
    next: *const Complex32,
    data: &[Complex32],
    f0: usize,
    row: usize,
    taps: &Taps,
    start: usize,
    len: usize,
    fresh: bool,
) {
    // Frames in the last vector, 1..=4, two floats each: the lanes below 2·last are read.
    let last = acc.len() - 4 * (N - 1);
    let tail = _mm256_cmpgt_epi32(
        _mm256_set1_epi32(2 * last as i32),
        _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
    );
    let out = acc.as_mut_ptr().cast::<f32>();
    // SAFETY: acc holds 4·(N − 1) + `last` complex values, and the last load is masked.
    let mut sp: [__m256; N] = std::array::from_fn(|j| unsafe {
        if fresh {
            _mm256_setzero_ps()
        } else if j + 1 < N || !MASKED {
            _mm256_loadu_ps(out.add(8 * j))
        } else {
            _mm256_maskload_ps(out.add(8 * j), tail)
        }
    });
    let mut sq: [__m256; N] = [_mm256_setzero_ps(); N];
    prefetch::<N>(next.cast::<f32>(), 0);
    // SAFETY (all pointer arithmetic below): the caller guarantees the tap arrays hold
    // start + len entries, `rows` PF more, and that every tap's rows lie within `data`;
    // the last vector's loads are masked to the frames of `acc`.
    let base = unsafe { data.as_ptr().add(f0).cast::<f32>() };
    let rows = unsafe { taps.rows.as_ptr().add(start) };
    let c0r = unsafe { taps.c0_re.as_ptr().add(start) };
    let c0i = unsafe { taps.c0_im.as_ptr().add(start) };
    let c1r = unsafe { taps.c1_re.as_ptr().add(start) };
    let c1i = unsafe { taps.c1_im.as_ptr().add(start) };
    for k in 0..len {
        unsafe {
            let a = base.add(2 * row * *rows.add(k) as usize);
            let b = a.add(2 * row);
            // Prefetch PF taps ahead, running on into the next pixel's.
            prefetch::<N>(base.wrapping_add(2 * row * *rows.add(k + PF) as usize), row);
            let p0 = _mm256_broadcast_ss(&*c0r.add(k));
            let q0 = _mm256_broadcast_ss(&*c0i.add(k));
            let p1 = _mm256_broadcast_ss(&*c1r.add(k));
            let q1 = _mm256_broadcast_ss(&*c1i.add(k));
            for j in 0..N {
                // 8 floats = 4 frames, inside the run of frames (masked in the last).
                let (u, v) = if j + 1 < N || !MASKED {
                    (_mm256_loadu_ps(a.add(8 * j)), _mm256_loadu_ps(b.add(8 * j)))
                } else {
                    (
                        _mm256_maskload_ps(a.add(8 * j), tail),
                        _mm256_maskload_ps(b.add(8 * j), tail),
                    )
                };
                sp[j] = _mm256_fmadd_ps(u, p0, sp[j]);
                sq[j] = _mm256_fmadd_ps(u, q0, sq[j]);
                sp[j] = _mm256_fmadd_ps(v, p1, sp[j]);
                sq[j] = _mm256_fmadd_ps(v, q1, sq[j]);
            }
        }
    }
    let sign = _mm256_setr_ps(-0.0, 0.0, -0.0, 0.0, -0.0, 0.0, -0.0, 0.0);
    for j in 0..N {
        // (q u, q v) → (−q v, q u).
        let t = _mm256_xor_ps(_mm256_permute_ps(sq[j], 0b1011_0001), sign);
        let sum = _mm256_add_ps(sp[j], t);
        // SAFETY: acc holds 4·(N − 1) + `last` complex values; the last store is masked to them.
        unsafe {
            if j + 1 < N || !MASKED {
                _mm256_storeu_ps(out.add(8 * j), sum);
            } else {
                _mm256_maskstore_ps(out.add(8 * j), tail, sum);
            }
        }
    }
}
