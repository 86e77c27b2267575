//! Lag products of complex slow-time series: Σ conj(a)·b, the sum every autocorrelation (the
//! Doppler's lag-1, the spatial lags, the resolution cell's) is made of.

use num_complex::{Complex32, Complex64};

use crate::core::error::{Result, invalid};

/// The peak sample magnitude a recording or an image series may have, in its own units: the
/// chain forms every lag product and power in single precision, whose normal range (2⁻¹²⁶ to
/// 2¹²⁸) holds the square of a beamformed sample only between about 2⁻⁶³ and 2⁶⁴. Below 2⁻⁵⁰
/// (about 9·10⁻¹⁶; Field II's RF is often 10⁻²⁰ and smaller) the weaker echoes' products fall
/// into subnormals and then to zero, and the maps become noise; above 2⁴⁸ (about 3·10¹⁴) a
/// beamformed sum over a large aperture (up to 2¹⁰ times a channel's) squares past the largest
/// f32, and the power becomes infinite. Within the range every map but the power maps is the same
/// at any scale: multiplying the samples by a power of two changes no bit of them, but where the
/// weakest pixels' products reach subnormals near the floor (a rounding's difference).
pub const SAMPLE_PEAK_RANGE: (f32, f32) = (1.0 / (1u64 << 50) as f32, (1u64 << 48) as f32);

/// The largest |value| of `values` (a slice, or a strided view's iterator; 0 for none). A NaN
/// reads as larger than any number, an infinity as larger than any finite one: compared as the
/// bits of their magnitudes, which order them so and vectorise.
pub fn peak_magnitude<'a>(values: impl IntoIterator<Item = &'a f32>) -> f32 {
    let bits = values
        .into_iter()
        .map(|&v| magnitude_bits(v))
        .fold(0, u32::max);
    f32::from_bits(bits)
}

/// [`peak_magnitude`] of complex samples' parts.
pub fn complex_peak_magnitude<'a>(samples: impl IntoIterator<Item = &'a Complex32>) -> f32 {
    let bits = samples
        .into_iter()
        .map(|v| magnitude_bits(v.re).max(magnitude_bits(v.im)))
        .fold(0, u32::max);
    f32::from_bits(bits)
}

/// A float's magnitude as bits that order as the magnitudes do (NaN above infinity).
fn magnitude_bits(value: f32) -> u32 {
    value.to_bits() & 0x7fff_ffff
}

/// Why samples whose peak magnitude is `peak` (in their own units) cannot be processed, naming
/// `what` they are: a peak outside [`SAMPLE_PEAK_RANGE`], or not finite (a NaN or an infinity
/// among them). All-zero samples (peak 0) have nothing to lose.
pub fn sample_peak_problem(peak: f32, what: &str) -> Option<String> {
    let (low, high) = SAMPLE_PEAK_RANGE;
    if peak == 0.0 || (low..=high).contains(&peak) {
        return None;
    }
    if !peak.is_finite() {
        return Some(format!(
            "{what} hold a value that is not finite (NaN or infinite)"
        ));
    }
    let direction = if peak < low { "below" } else { "above" };
    Some(format!(
        "{what} peak at {peak:.2e}, {direction} the {low:.0e} to {high:.0e} that pcuvd's \
         single-precision lag products and powers hold (beyond it the maps would be noise or \
         infinite); scale the samples into it, e.g. by {:.0e} (every map but the power maps is \
         the same at any scale)",
        1.0 / peak
    ))
}

/// Refuses samples whose peak magnitude lies outside [`SAMPLE_PEAK_RANGE`]
/// ([`sample_peak_problem`]).
pub fn check_sample_peak(peak: f32, what: &str) -> Result<()> {
    match sample_peak_problem(peak, what) {
        Some(reason) => Err(invalid("sample scale", reason)),
        None => Ok(()),
    }
}

/// Σ_t conj(a_t)·b_t over two series of equal length, each product in f32 (the series'
/// precision) and the sum in f64, so that long ensembles lose nothing to the sum.
pub fn conj_dot(a: &[Complex32], b: &[Complex32]) -> Complex64 {
    assert_eq!(a.len(), b.len(), "series of equal length");
    let (a, b) = (
        crate::core::buffers::complex_floats(a),
        crate::core::buffers::complex_floats(b),
    );
    #[cfg(target_arch = "x86_64")]
    {
        if crate::core::simd::avx512() {
            // SAFETY: AVX-512F and DQ were detected.
            return unsafe { conj_dot_avx512(a, b) };
        }
        if crate::core::simd::avx2() {
            // SAFETY: AVX2 was detected.
            return unsafe { conj_dot_avx2(a, b) };
        }
    }
    conj_dot_floats(a, b)
}

/// [`conj_dot`] in AVX-512 registers: 8 complex samples per step, each product in f32 and
/// widened to f64 in four sums (the real and the swapped products, low and high halves), the last
/// step masked to the samples there are. The compiler's own vectorisation of
/// [`conj_dot_floats`] spilled its 16 lanes across registers of three widths (about four times
/// the instructions per step), and its serial sum of the lanes cost as much as a short Doppler
/// ensemble's products. The lanes' sums are the same; they are added pairwise here, so the result
/// can differ from the portable loop's in the last bits.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq")]
unsafe fn conj_dot_avx512(a: &[f32], b: &[f32]) -> Complex64 {
    use std::arch::x86_64::*;
    let n = a.len().min(b.len());
    let (a, b) = (a.as_ptr(), b.as_ptr());
    let zero = _mm512_setzero_pd();
    let (mut same_lo, mut same_hi, mut swapped_lo, mut swapped_hi) = (zero, zero, zero, zero);
    let mut at = 0;
    while at < n {
        let left = n - at;
        let mask: __mmask16 = if left >= 16 {
            u16::MAX
        } else {
            (1u16 << left) - 1
        };
        // SAFETY: the masked loads read only the `left` floats from `at` on, within both slices.
        let (x, y) = unsafe {
            (
                _mm512_maskz_loadu_ps(mask, a.add(at)),
                _mm512_maskz_loadu_ps(mask, b.add(at)),
            )
        };
        // (re, im) pairs swapped: y_im, y_re.
        let y_swapped = _mm512_permute_ps::<0b1011_0001>(y);
        let same = _mm512_mul_ps(x, y);
        let swapped = _mm512_mul_ps(x, y_swapped);
        let low = |v: __m512| _mm512_cvtps_pd(_mm512_castps512_ps256(v));
        let high = |v: __m512| _mm512_cvtps_pd(_mm512_extractf32x8_ps::<1>(v));
        same_lo = _mm512_add_pd(same_lo, low(same));
        same_hi = _mm512_add_pd(same_hi, high(same));
        swapped_lo = _mm512_add_pd(swapped_lo, low(swapped));
        swapped_hi = _mm512_add_pd(swapped_hi, high(swapped));
        at += 16;
    }
    // Im: even floats' products added, odd ones' subtracted.
    let signs = _mm512_setr_pd(1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0);
    let re = _mm512_reduce_add_pd(_mm512_add_pd(same_lo, same_hi));
    let im = _mm512_reduce_add_pd(_mm512_mul_pd(_mm512_add_pd(swapped_lo, swapped_hi), signs));
    Complex64::new(re, im)
}

/// [`conj_dot`] in AVX2 registers, as [`conj_dot_avx512`] sums it: 4 complex samples per step,
/// each product in f32 and widened to f64 in four sums, the last step masked. The compiler's
/// own vectorisation of [`conj_dot_floats`] for AVX2 took half again the Doppler stage's time
/// on the 360 coded rat-network frames (measured on a Zen 4 EPYC with AVX-512 turned off).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn conj_dot_avx2(a: &[f32], b: &[f32]) -> Complex64 {
    use std::arch::x86_64::*;
    let n = a.len().min(b.len());
    let (a, b) = (a.as_ptr(), b.as_ptr());
    let zero = _mm256_setzero_pd();
    let (mut same_lo, mut same_hi, mut swapped_lo, mut swapped_hi) = (zero, zero, zero, zero);
    let lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    let mut at = 0;
    while at < n {
        let left = n - at;
        // SAFETY: whole steps read 8 floats from `at` on, within both slices; the last step's
        // masked loads read only the `left` floats there are.
        let (x, y) = unsafe {
            if left >= 8 {
                (_mm256_loadu_ps(a.add(at)), _mm256_loadu_ps(b.add(at)))
            } else {
                let mask = _mm256_cmpgt_epi32(_mm256_set1_epi32(left as i32), lanes);
                (
                    _mm256_maskload_ps(a.add(at), mask),
                    _mm256_maskload_ps(b.add(at), mask),
                )
            }
        };
        // (re, im) pairs swapped: y_im, y_re.
        let y_swapped = _mm256_permute_ps::<0b1011_0001>(y);
        let same = _mm256_mul_ps(x, y);
        let swapped = _mm256_mul_ps(x, y_swapped);
        let low = |v: __m256| _mm256_cvtps_pd(_mm256_castps256_ps128(v));
        let high = |v: __m256| _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(v));
        same_lo = _mm256_add_pd(same_lo, low(same));
        same_hi = _mm256_add_pd(same_hi, high(same));
        swapped_lo = _mm256_add_pd(swapped_lo, low(swapped));
        swapped_hi = _mm256_add_pd(swapped_hi, high(swapped));
        at += 8;
    }
    let mut same = [0.0f64; 4];
    let mut swapped = [0.0f64; 4];
    // SAFETY: each store writes 4 doubles into its array.
    unsafe {
        _mm256_storeu_pd(same.as_mut_ptr(), _mm256_add_pd(same_lo, same_hi));
        _mm256_storeu_pd(swapped.as_mut_ptr(), _mm256_add_pd(swapped_lo, swapped_hi));
    }
    // Im: even floats' products added, odd ones' subtracted.
    let re = (same[0] + same[1]) + (same[2] + same[3]);
    let im = (swapped[0] - swapped[1]) + (swapped[2] - swapped[3]);
    Complex64::new(re, im)
}

/// [`conj_dot`] on the series' floats, (re, im) after each other. Re(conj(a)·b) = a_re·b_re +
/// a_im·b_im is the sum of the floats' products in place; Im = a_re·b_im − a_im·b_re, of the
/// products with each pair swapped, even floats added and odd ones subtracted. Kept in
/// independent lanes, the sums vectorise where one running complex sum would wait on itself.
#[inline(always)]
fn conj_dot_floats(a: &[f32], b: &[f32]) -> Complex64 {
    const LANES: usize = 16;
    let mut same = [0.0f64; LANES];
    let mut swapped = [0.0f64; LANES];
    let (a_chunks, b_chunks) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let (a_rest, b_rest) = (a_chunks.remainder(), b_chunks.remainder());
    for (x, y) in a_chunks.zip(b_chunks) {
        for k in 0..LANES {
            same[k] += (x[k] * y[k]) as f64;
            swapped[k] += (x[k] * y[k ^ 1]) as f64;
        }
    }
    // Whole complex samples remain, so each float's partner is among them.
    for k in 0..a_rest.len() {
        same[k] += (a_rest[k] * b_rest[k]) as f64;
        swapped[k] += (a_rest[k] * b_rest[k ^ 1]) as f64;
    }
    let re = same.iter().sum();
    let im = swapped.chunks_exact(2).map(|pair| pair[0] - pair[1]).sum();
    Complex64::new(re, im)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The peak magnitude is the largest |v|, whatever the signs, the lengths (past and short of
    /// a vector's lanes) and the extremes (subnormals, the largest float, signed zeros).
    #[test]
    fn peak_magnitude_is_the_largest_absolute_value() {
        for len in [0usize, 1, 7, 8, 9, 33, 1000] {
            let mut values: Vec<f32> = (0..len)
                .map(|i| ((i * 7919) % 1000) as f32 * if i % 3 == 0 { -1e-3 } else { 1e-3 })
                .collect();
            let expected = |v: &[f32]| v.iter().fold(0.0f32, |m, x| m.max(x.abs()));
            assert_eq!(peak_magnitude(&values), expected(&values), "{len}");
            if len > 0 {
                for extreme in [f32::MIN, f32::MAX, -1e-45, -0.0] {
                    let at = len / 2;
                    let old = std::mem::replace(&mut values[at], extreme);
                    assert_eq!(
                        peak_magnitude(&values),
                        expected(&values),
                        "{extreme} in {len}"
                    );
                    values[at] = old;
                }
            }
        }
        let complex = [Complex32::new(0.5, -3.0), Complex32::new(-2.0, 1.0)];
        assert_eq!(complex_peak_magnitude(&complex), 3.0);
    }

    /// Peaks at the range's ends pass and one step beyond them fails, naming the side and a factor
    /// that brings the peak to 1; zero (no sample recorded) passes.
    #[test]
    fn sample_peaks_outside_the_range_are_refused() {
        let (low, high) = SAMPLE_PEAK_RANGE;
        for ok in [0.0, low, 1.0, 32768.0, high] {
            assert!(check_sample_peak(ok, "the samples").is_ok(), "{ok:e}");
        }
        for bad in [f32::NAN, f32::INFINITY] {
            let error = check_sample_peak(bad, "the series")
                .unwrap_err()
                .to_string();
            assert!(
                error.contains("the series hold a value that is not finite"),
                "{error}"
            );
        }
        let beyond =
            |v: f32, up: bool| f32::from_bits(if up { v.to_bits() + 1 } else { v.to_bits() - 1 });
        for (peak, side, factor) in [
            (beyond(low, false), "below", "1e15"),
            (1e-22, "below", "1e22"),
            (beyond(high, true), "above", "4e-15"),
        ] {
            let error = check_sample_peak(peak, "the samples of frame 3")
                .unwrap_err()
                .to_string();
            for needle in [
                "sample scale",
                "the samples of frame 3 peak at",
                side,
                factor,
            ] {
                assert!(error.contains(needle), "{needle:?} missing from: {error}");
            }
        }
    }

    /// The lag sums against the sum written out in f64, for series shorter and longer than a
    /// vector's lanes and of odd lengths.
    #[test]
    fn conj_dot_is_the_sum_of_conjugate_products() {
        for len in [0usize, 1, 2, 7, 8, 9, 17, 100, 361] {
            let a: Vec<Complex32> = (0..len)
                .map(|t| Complex32::new((0.37 * t as f32).sin(), (1.3 + 0.11 * t as f32).cos()))
                .collect();
            let b: Vec<Complex32> = (0..len)
                .map(|t| Complex32::new(0.5 - (0.05 * t as f32).cos(), (0.21 * t as f32).sin()))
                .collect();
            let expected = a
                .iter()
                .zip(&b)
                .fold(Complex64::new(0.0, 0.0), |acc, (x, y)| {
                    let (x, y) = (
                        Complex64::new(x.re as f64, x.im as f64),
                        Complex64::new(y.re as f64, y.im as f64),
                    );
                    acc + x.conj() * y
                });
            // Each product is rounded in f32: a relative error of 2⁻²⁴ per term at most.
            let bound = 1e-7
                * a.iter()
                    .zip(&b)
                    .map(|(x, y)| (x.norm() * y.norm()) as f64)
                    .sum::<f64>();
            // The dispatched path, and each one this CPU can run besides it.
            let (fa, fb) = (
                crate::core::buffers::complex_floats(&a),
                crate::core::buffers::complex_floats(&b),
            );
            let mut paths = vec![("dispatched", conj_dot(&a, &b))];
            paths.push(("portable", conj_dot_floats(fa, fb)));
            #[cfg(target_arch = "x86_64")]
            {
                if is_x86_feature_detected!("avx512f") && is_x86_feature_detected!("avx512dq") {
                    // SAFETY: AVX-512F and DQ were detected.
                    paths.push(("avx512", unsafe { conj_dot_avx512(fa, fb) }));
                }
                if is_x86_feature_detected!("avx2") {
                    // SAFETY: AVX2 was detected.
                    paths.push(("avx2", unsafe { conj_dot_avx2(fa, fb) }));
                }
            }
            for (path, got) in paths {
                assert!(
                    (got - expected).norm() <= bound,
                    "{path}, len {len}: {got} vs {expected}"
                );
            }
        }
        let x = [Complex32::new(3.0, -4.0), Complex32::new(0.0, 2.0)];
        let y = [Complex32::new(1.0, 2.0), Complex32::new(5.0, 0.0)];
        // conj(3 − 4i)(1 + 2i) = −5 + 10i; conj(2i)·5 = −10i.
        assert_eq!(conj_dot(&x, &y), Complex64::new(-5.0, 0.0));
    }
}
