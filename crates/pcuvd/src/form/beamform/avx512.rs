//! The AVX-512 (F, DQ) accumulation kernel: a pixel's run of frames, 8 complex frames per
//! 512-bit vector and up to 104 frames, kept in registers across a group of elements, the last
//! vector masked.

use super::taps::Taps;
use super::taps::prefetch_near;
use num_complex::Complex32;
use std::arch::x86_64::*;

/// The most 8-frame vectors of one pixel whose sums stay in registers across the element
/// loop: two sums per vector and four broadcast weights take 30 of the 32 registers at 13,
/// leaving two for the samples. 13 vectors hold 104 frames, so a typical 100-frame ensemble
/// is one run and each tap's rows are read once per pass.
pub(super) const MAX_VECTORS: usize = 13;

/// Fused multiply-adds per point (pixel × active element × frame): per tap, each 8-frame vector
/// takes four (two sums, each of two samples by a broadcast weight).
pub(super) const FMA_PER_POINT: f64 = 0.5;

/// Dispatches a run of 1..=8·MAX_VECTORS frames to its register-resident instance.
///
/// # Safety
/// AVX-512F, AVX-512DQ, AVX2 and FMA must be available; `acc` must not be empty; for every
/// tap k in `start..start + len`, `(rows[k] + 1)·row + f0 + acc.len()` must lie within
/// `data`; `taps.rows` must hold PF entries beyond them.
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
    debug_assert!(!acc.is_empty() && acc.len().div_ceil(8) <= MAX_VECTORS);
    // SAFETY: forwarded from the caller.
    unsafe {
        match acc.len().div_ceil(8) {
            1 => run::<1>(acc, next, data, f0, row, taps, start, len, fresh),
            2 => run::<2>(acc, next, data, f0, row, taps, start, len, fresh),
            3 => run::<3>(acc, next, data, f0, row, taps, start, len, fresh),
            4 => run::<4>(acc, next, data, f0, row, taps, start, len, fresh),
            5 => run::<5>(acc, next, data, f0, row, taps, start, len, fresh),
            6 => run::<6>(acc, next, data, f0, row, taps, start, len, fresh),
            7 => run::<7>(acc, next, data, f0, row, taps, start, len, fresh),
            8 => run::<8>(acc, next, data, f0, row, taps, start, len, fresh),
            9 => run::<9>(acc, next, data, f0, row, taps, start, len, fresh),
            10 => run::<10>(acc, next, data, f0, row, taps, start, len, fresh),
            11 => run::<11>(acc, next, data, f0, row, taps, start, len, fresh),
            12 => run::<12>(acc, next, data, f0, row, taps, start, len, fresh),
            13 => run::<13>(acc, next, data, f0, row, taps, start, len, fresh),
            _ => {}
        }
    }
}

/// Asks for the lines of N 16-float vectors at `a` and, if `row` > 0, one row further into L1.
#[inline(always)]
fn prefetch<const N: usize>(a: *const f32, row: usize) {
    prefetch_near(a, 64 * N, row);
}

/// acc += `Σ_k c0[k]·a_k + c1[k]·b_k` on interleaved (re, im) pairs (acc = the sum when
/// `fresh`), as [`super::avx2`]'s `run` (two sums per vector, the swap and sign applied once
/// after the loop), 16 floats per vector; the last vector is masked to the frames of `acc`, so
/// that no frame is left to a scalar tail and nothing beyond them is read or written.
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx512f,avx512dq,avx2,fma")]
unsafe fn run<const N: usize>(
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
    // Frames in the last vector, 1..=8, two floats each.
    let last = acc.len() - 8 * (N - 1);
    let tail: __mmask16 = if last == 8 {
        u16::MAX
    } else {
        (1 << (2 * last)) - 1
    };
    let out = acc.as_mut_ptr().cast::<f32>();
    // SAFETY: acc holds 8·(N − 1) + `last` complex values, and the last load is masked.
    let mut sp: [__m512; N] = std::array::from_fn(|j| unsafe {
        if fresh {
            _mm512_setzero_ps()
        } else if j + 1 < N {
            _mm512_loadu_ps(out.add(16 * j))
        } else {
            _mm512_maskz_loadu_ps(tail, out.add(16 * j))
        }
    });
    let mut sq: [__m512; N] = [_mm512_setzero_ps(); N];
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
            // No software prefetch of the taps ahead (as the AVX2 kernel has): on a Xeon with
            // 2 MB of L2 per core it cost 8 % of the delay-and-sum time (criterion `das`).
            let p0 = _mm512_set1_ps(*c0r.add(k));
            let q0 = _mm512_set1_ps(*c0i.add(k));
            let p1 = _mm512_set1_ps(*c1r.add(k));
            let q1 = _mm512_set1_ps(*c1i.add(k));
            for j in 0..N {
                // 16 floats = 8 frames, inside the run of frames (masked in the last).
                let (u, v) = if j + 1 < N {
                    (
                        _mm512_loadu_ps(a.add(16 * j)),
                        _mm512_loadu_ps(b.add(16 * j)),
                    )
                } else {
                    (
                        _mm512_maskz_loadu_ps(tail, a.add(16 * j)),
                        _mm512_maskz_loadu_ps(tail, b.add(16 * j)),
                    )
                };
                sp[j] = _mm512_fmadd_ps(u, p0, sp[j]);
                sq[j] = _mm512_fmadd_ps(u, q0, sq[j]);
                sp[j] = _mm512_fmadd_ps(v, p1, sp[j]);
                sq[j] = _mm512_fmadd_ps(v, q1, sq[j]);
            }
        }
    }
    let sign = _mm512_setr_ps(
        -0.0, 0.0, -0.0, 0.0, -0.0, 0.0, -0.0, 0.0, -0.0, 0.0, -0.0, 0.0, -0.0, 0.0, -0.0, 0.0,
    );
    for j in 0..N {
        // (q u, q v) → (−q v, q u).
        let t = _mm512_xor_ps(_mm512_permute_ps::<0b1011_0001>(sq[j]), sign);
        let sum = _mm512_add_ps(sp[j], t);
        let mask = if j + 1 < N { u16::MAX } else { tail };
        // SAFETY: acc holds 8·(N − 1) + `last` complex values; the store is masked to them.
        unsafe { _mm512_mask_storeu_ps(out.add(16 * j), mask, sum) };
    }
}
