//! Register shuffles the vector kernels share.

/// The 8 × 8 transpose of eight AVX vectors of 8 floats: out[i][j] = rows[j][i]. Kernels that
/// compute across one axis and store along the other (the simulator's powers per scatterer, the
/// demodulator's frames per row) turn their vectors with it; the values move unchanged.
///
/// # Safety
/// AVX2 must be available: callable without `unsafe` only from functions compiled for it.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub fn transpose_8x8(rows: [std::arch::x86_64::__m256; 8]) -> [std::arch::x86_64::__m256; 8] {
    use std::arch::x86_64::*;
    let r = rows;
    let t0 = _mm256_unpacklo_ps(r[0], r[1]);
    let t1 = _mm256_unpackhi_ps(r[0], r[1]);
    let t2 = _mm256_unpacklo_ps(r[2], r[3]);
    let t3 = _mm256_unpackhi_ps(r[2], r[3]);
    let t4 = _mm256_unpacklo_ps(r[4], r[5]);
    let t5 = _mm256_unpackhi_ps(r[4], r[5]);
    let t6 = _mm256_unpacklo_ps(r[6], r[7]);
    let t7 = _mm256_unpackhi_ps(r[6], r[7]);
    let u0 = _mm256_shuffle_ps::<0x44>(t0, t2);
    let u1 = _mm256_shuffle_ps::<0xEE>(t0, t2);
    let u2 = _mm256_shuffle_ps::<0x44>(t1, t3);
    let u3 = _mm256_shuffle_ps::<0xEE>(t1, t3);
    let u4 = _mm256_shuffle_ps::<0x44>(t4, t6);
    let u5 = _mm256_shuffle_ps::<0xEE>(t4, t6);
    let u6 = _mm256_shuffle_ps::<0x44>(t5, t7);
    let u7 = _mm256_shuffle_ps::<0xEE>(t5, t7);
    [
        _mm256_permute2f128_ps::<0x20>(u0, u4),
        _mm256_permute2f128_ps::<0x20>(u1, u5),
        _mm256_permute2f128_ps::<0x20>(u2, u6),
        _mm256_permute2f128_ps::<0x20>(u3, u7),
        _mm256_permute2f128_ps::<0x31>(u0, u4),
        _mm256_permute2f128_ps::<0x31>(u1, u5),
        _mm256_permute2f128_ps::<0x31>(u2, u6),
        _mm256_permute2f128_ps::<0x31>(u3, u7),
    ]
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;
    use std::arch::x86_64::*;

    /// Every value lands at its transposed place.
    #[test]
    fn transposes_eight_by_eight() {
        if !is_x86_feature_detected!("avx2") {
            return;
        }
        let m: Vec<[f32; 8]> = (0..8)
            .map(|j| std::array::from_fn(|i| (10 * j + i) as f32))
            .collect();
        // SAFETY: AVX2 was detected; each load reads one row of 8 floats.
        let out = unsafe {
            let rows: [__m256; 8] = std::array::from_fn(|j| _mm256_loadu_ps(m[j].as_ptr()));
            transpose_8x8(rows)
        };
        for (i, v) in out.iter().enumerate() {
            let mut got = [0.0f32; 8];
            // SAFETY: AVX2 was detected; the store writes 8 floats into `got`.
            unsafe { _mm256_storeu_ps(got.as_mut_ptr(), *v) };
            let want: [f32; 8] = std::array::from_fn(|j| m[j][i]);
            assert_eq!(got, want, "row {i} of the transpose");
        }
    }
}
