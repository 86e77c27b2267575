//! Weighted sums of rows of samples, the inner loop of decoding, slow-time alignment and IQ
//! filtering, vectorised to the widest registers the CPU has.

/// `dest` = Σ_k w[k]·sources[k], element by element, summed from zero in the order of k, with
/// the widest vectors the CPU has (the same sums in any width: no fused multiply-adds). Every
/// source is at least as long as `dest`.
pub fn weighted_rows(dest: &mut [f32], sources: &[&[f32]], w: &[f32]) {
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
    // A block of outputs at a time, summed over every source in registers: one pass over the
    // sources, where a pass per source reads and writes the whole row each time. Rows a few
    // blocks long (IQ filtering's rows of frames) end in a narrower block, then single floats.
    let done = weighted_blocks::<64>(dest, sources, w, 0);
    let done = weighted_blocks::<16>(dest, sources, w, done);
    let rest = &mut dest[done..];
    rest.fill(0.0);
    for (source, &wk) in sources.iter().zip(w) {
        for (a, &x) in rest.iter_mut().zip(&source[done..]) {
            *a += x * wk;
        }
    }
}

/// The whole blocks of `BLOCK` floats of `dest` from `start` on, as [`weighted_rows`] sums them;
/// returns where they end.
#[inline(always)]
fn weighted_blocks<const BLOCK: usize>(
    dest: &mut [f32],
    sources: &[&[f32]],
    w: &[f32],
    start: usize,
) -> usize {
    let end = start + (dest.len() - start) / BLOCK * BLOCK;
    for (b, out) in dest[start..end].chunks_exact_mut(BLOCK).enumerate() {
        let at = start + b * BLOCK;
        let mut sum = [0.0f32; BLOCK];
        for (source, &wk) in sources.iter().zip(w) {
            let source: &[f32; BLOCK] = source[at..at + BLOCK]
                .try_into()
                .expect("a block of the row");
            for (a, &x) in sum.iter_mut().zip(source) {
                *a += x * wk;
            }
        }
        out.copy_from_slice(&sum);
    }
    end
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every length, across the block widths, gives the sum written out term by term in the
    /// order of the sources, to the bit.
    #[test]
    fn weighted_rows_are_the_sums_in_order() {
        let sources: Vec<Vec<f32>> = (0..5)
            .map(|k| {
                (0..150)
                    .map(|i| ((i * 7 + k * 13) as f32 * 0.37).sin())
                    .collect()
            })
            .collect();
        let sources: Vec<&[f32]> = sources.iter().map(|s| s.as_slice()).collect();
        let w = [0.5f32, -1.25, 0.1, 3.0, -0.3];
        for len in [0usize, 1, 15, 16, 17, 63, 64, 65, 80, 81, 150] {
            let mut dest = vec![f32::NAN; len];
            weighted_rows(&mut dest, &sources, &w);
            for (i, &d) in dest.iter().enumerate() {
                let mut expected = 0.0f32;
                for (s, &wk) in sources.iter().zip(&w) {
                    expected += s[i] * wk;
                }
                assert_eq!(d.to_bits(), expected.to_bits(), "len {len}, element {i}");
            }
        }
    }
}
