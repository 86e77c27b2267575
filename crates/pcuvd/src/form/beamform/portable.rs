//! The portable accumulation kernel: plain Rust, for any CPU without AVX2 and FMA, and the
//! reference that the SIMD kernels are tested against.

use num_complex::Complex32;

use super::taps::Taps;

/// Adds to `acc`, frames `f0..f0 + acc.len()` of one pixel, Σ over taps `start..start + len` of
/// c0·a + c1·b, a and b being the tap element's frames at samples i0 and i0 + 1 (rows of `row`
/// frames in `data`).
#[inline]
pub(super) fn pixel_chunk(
    acc: &mut [Complex32],
    data: &[Complex32],
    f0: usize,
    row: usize,
    taps: &Taps,
    start: usize,
    len: usize,
) {
    let end = start + len;
    let n = acc.len();
    for k in start..end {
        let base = taps.rows[k] as usize * row + f0;
        accumulate(
            acc,
            Complex32::new(taps.c0_re[k], taps.c0_im[k]),
            &data[base..base + n],
            Complex32::new(taps.c1_re[k], taps.c1_im[k]),
            &data[base + row..base + row + n],
        );
    }
}

/// acc += c0·a + c1·b over a batch of frames: the beamformer's inner loop.
#[inline]
fn accumulate(
    acc: &mut [Complex32],
    c0: Complex32,
    a: &[Complex32],
    c1: Complex32,
    b: &[Complex32],
) {
    for ((o, &u), &v) in acc.iter_mut().zip(a).zip(b) {
        *o += c0 * u + c1 * v;
    }
}
