//! Weighted sums of rows of samples, the inner loop of decoding, slow-time alignment and IQ
//! filtering, vectorised to the widest registers the CPU has: one sum at a time, or several
//! outputs (of a sliding window, of a matrix product) from one pass over their rows.

/// `dest` = Σ_k w[k]·sources[k], element by element, summed from zero in the order of k, with
/// the widest vectors the CPU has (the same sums in any width: no fused multiply-adds). Every
/// source is at least as long as `dest`.
pub fn weighted_rows(dest: &mut [f32], sources: &[&[f32]], w: &[f32]) {
    combined_rows(&mut [dest], sources, |_, k| w.get(k).copied())
}

/// Outputs a sliding window apart: `dests[j]` = Σ_k w[k]·`sources[j + k]` for j < M, each summed
/// as [`weighted_rows`] sums it (the same sums to the bit). Consecutive outputs of a window
/// (the frames of a slow-time interpolator) share all but one of their rows; here each of the
/// w.len() + M − 1 rows is read once for all M outputs, where [`weighted_rows`] reads it once
/// per output, from L2 when the window does not fit in L1. Every source is at least as long as
/// the destinations, which are all of one length.
pub fn sliding_weighted_rows<const M: usize>(
    dests: &mut [&mut [f32]; M],
    sources: &[&[f32]],
    w: &[f32],
) {
    assert_eq!(sources.len() + 1, w.len() + M, "rows of M outputs' windows");
    // Row s is tap s − j of output j.
    combined_rows(dests, sources, |j, s| {
        s.checked_sub(j).and_then(|k| w.get(k)).copied()
    })
}

/// Outputs of one matrix product: `dests[j]` = Σ_i m[j][i]·`sources[i]` over the nonzero
/// m[j][i] (`m` row-major, M × sources), each summed as [`weighted_rows`] sums the sources and
/// weights of its nonzero terms (the same sums to the bit), from one pass over the sources for
/// all M outputs (the slots of a coded frame, each a combination of the frame's events). Every
/// source is at least as long as the destinations, which are all of one length.
pub fn matrix_weighted_rows<const M: usize>(
    dests: &mut [&mut [f32]; M],
    sources: &[&[f32]],
    m: &[f32],
) {
    let n = sources.len();
    assert_eq!(m.len(), M * n, "an M × sources matrix");
    combined_rows(dests, sources, |j, i| {
        Some(m[j * n + i]).filter(|&v| v != 0.0)
    })
}

/// `dests[j]` = Σ_s weight(j, s)·`sources[s]` over the sources whose weight is given, in the
/// order of s, with the widest vectors the CPU has.
fn combined_rows<const M: usize>(
    dests: &mut [&mut [f32]; M],
    sources: &[&[f32]],
    weight: impl Fn(usize, usize) -> Option<f32> + Copy,
) {
    let len = dests.first().map_or(0, |d| d.len());
    assert!(dests.iter().all(|d| d.len() == len) && sources.iter().all(|s| s.len() >= len));
    #[cfg(target_arch = "x86_64")]
    {
        if crate::core::simd::avx512() {
            // SAFETY: AVX-512F was detected.
            return unsafe { combined_avx512(dests, sources, weight) };
        }
        if crate::core::simd::avx2() {
            // SAFETY: AVX2 was detected.
            return unsafe { combined_avx2(dests, sources, weight) };
        }
    }
    combined_narrow(dests, sources, weight)
}

/// [`combined_rows`] compiled for AVX-512.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn combined_avx512<const M: usize>(
    dests: &mut [&mut [f32]; M],
    sources: &[&[f32]],
    weight: impl Fn(usize, usize) -> Option<f32> + Copy,
) {
    // One output's sums of 64 floats take 4 of the 32 registers, four outputs' 16.
    combined_portable::<M, 64>(dests, sources, weight)
}

/// [`combined_rows`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn combined_avx2<const M: usize>(
    dests: &mut [&mut [f32]; M],
    sources: &[&[f32]],
    weight: impl Fn(usize, usize) -> Option<f32> + Copy,
) {
    combined_narrow(dests, sources, weight)
}

/// [`combined_portable`] in blocks that 16 registers of 8 floats hold: one output's sums of 64
/// floats take 8 of them, four outputs' sums of 16 floats 8 too.
#[inline(always)]
fn combined_narrow<const M: usize>(
    dests: &mut [&mut [f32]; M],
    sources: &[&[f32]],
    weight: impl Fn(usize, usize) -> Option<f32> + Copy,
) {
    if M == 1 {
        combined_portable::<M, 64>(dests, sources, weight)
    } else {
        combined_portable::<M, 16>(dests, sources, weight)
    }
}

/// Blocks of `BLOCK` floats, then of 16 (where `BLOCK` is more), then single floats: all M sums
/// of a block stay in registers, which bounds `BLOCK` by the register file (M·BLOCK floats).
#[inline(always)]
fn combined_portable<const M: usize, const BLOCK: usize>(
    dests: &mut [&mut [f32]; M],
    sources: &[&[f32]],
    weight: impl Fn(usize, usize) -> Option<f32> + Copy,
) {
    let done = combined_blocks::<BLOCK, M>(dests, sources, weight, 0);
    let done = combined_blocks::<16, M>(dests, sources, weight, done);
    combined_blocks::<1, M>(dests, sources, weight, done);
}

/// The whole blocks of `BLOCK` floats of the destinations from `start` on, as
/// [`combined_rows`] sums them; returns where they end.
#[inline(always)]
fn combined_blocks<const BLOCK: usize, const M: usize>(
    dests: &mut [&mut [f32]; M],
    sources: &[&[f32]],
    weight: impl Fn(usize, usize) -> Option<f32>,
    start: usize,
) -> usize {
    let len = dests.first().map_or(0, |d| d.len());
    let end = start + (len - start) / BLOCK * BLOCK;
    for at in (start..end).step_by(BLOCK) {
        let mut sums = [[0.0f32; BLOCK]; M];
        for (s, source) in sources.iter().enumerate() {
            let source: &[f32; BLOCK] = source[at..at + BLOCK]
                .try_into()
                .expect("a block of the row");
            for (j, sum) in sums.iter_mut().enumerate() {
                if let Some(wk) = weight(j, s) {
                    for (a, &x) in sum.iter_mut().zip(source) {
                        *a += x * wk;
                    }
                }
            }
        }
        for (dest, sum) in dests.iter_mut().zip(&sums) {
            dest[at..at + BLOCK].copy_from_slice(sum);
        }
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

    /// Each output of a sliding window is [`weighted_rows`]' sum of its own rows, to the bit, for
    /// every length across the block widths and for 1, 2 and 4 outputs at once, by the
    /// dispatched, the portable and every vector variant this CPU runs.
    #[test]
    fn sliding_outputs_are_each_windows_weighted_rows() {
        type Variant<const M: usize> = fn(&mut [&mut [f32]; M], &[&[f32]], &[f32]);
        fn check<const M: usize>(rows: &[Vec<f32>], w: &[f32]) {
            #[cfg_attr(not(target_arch = "x86_64"), allow(unused_mut))]
            let mut variants: Vec<(&str, Variant<M>)> = vec![
                ("dispatched", sliding_weighted_rows::<M>),
                ("portable", |d, s, w| {
                    combined_portable::<M, 16>(d, s, |j, s| {
                        s.checked_sub(j).and_then(|k| w.get(k)).copied()
                    })
                }),
            ];
            #[cfg(target_arch = "x86_64")]
            {
                if is_x86_feature_detected!("avx512f") {
                    // SAFETY: AVX-512F was detected.
                    variants.push(("AVX-512", |d, s, w| unsafe {
                        combined_avx512(d, s, |j, s| {
                            s.checked_sub(j).and_then(|k| w.get(k)).copied()
                        })
                    }));
                }
                if is_x86_feature_detected!("avx2") {
                    // SAFETY: AVX2 was detected.
                    variants.push(("AVX2", |d, s, w| unsafe {
                        combined_avx2(d, s, |j, s| {
                            s.checked_sub(j).and_then(|k| w.get(k)).copied()
                        })
                    }));
                }
            }
            for len in [0usize, 1, 15, 16, 17, 63, 64, 65, 80, 81, 150] {
                let sources: Vec<&[f32]> = rows[..w.len() + M - 1].iter().map(|r| &r[..]).collect();
                for &(name, variant) in &variants {
                    let mut out = vec![vec![f32::NAN; len]; M];
                    let mut dests: [&mut [f32]; M] = {
                        let mut it = out.iter_mut();
                        std::array::from_fn(|_| it.next().unwrap().as_mut_slice())
                    };
                    variant(&mut dests, &sources, w);
                    for (j, got) in out.iter().enumerate() {
                        let mut expected = vec![0.0f32; len];
                        weighted_rows(&mut expected, &sources[j..j + w.len()], w);
                        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                        assert_eq!(
                            bits(got),
                            bits(&expected),
                            "{name}: {M} outputs, length {len}, output {j}"
                        );
                    }
                }
            }
        }
        let rows: Vec<Vec<f32>> = (0..30)
            .map(|k| {
                (0..150)
                    .map(|i| {
                        ((i * 7 + k * 13) as f32 * 0.37).sin() * 1e3f32.powf((k % 3) as f32 - 1.0)
                    })
                    .collect()
            })
            .collect();
        let w: Vec<f32> = (0..25)
            .map(|k| ((k as f32 - 12.0) * 0.3).cos() - 0.4)
            .collect();
        check::<1>(&rows, &w);
        check::<2>(&rows, &w);
        check::<4>(&rows, &w);
        check::<4>(&rows, &w[..3]);
    }

    /// Each output of a block of a matrix product is [`weighted_rows`]' sum of the sources and
    /// weights of its nonzero terms, to the bit: ±1 (a Hadamard matrix's rows), zeros skipped
    /// (a partial code), fractions, over every length across the block widths.
    #[test]
    fn matrix_outputs_are_each_rows_weighted_rows_of_its_nonzero_terms() {
        let rows: Vec<Vec<f32>> = (0..8)
            .map(|k| {
                (0..150)
                    .map(|i| ((i * 5 + k * 11) as f32 * 0.41).cos() * (k + 1) as f32)
                    .collect()
            })
            .collect();
        let m: Vec<f32> = (0..4 * 8)
            .map(|e| match e % 7 {
                0 | 3 => 0.0,
                1 | 4 => -1.0,
                2 => 0.3,
                _ => 1.0,
            })
            .collect();
        for len in [0usize, 1, 15, 16, 17, 63, 64, 65, 80, 81, 150] {
            let sources: Vec<&[f32]> = rows.iter().map(|r| &r[..]).collect();
            let mut out = vec![vec![f32::NAN; len]; 4];
            let mut dests: [&mut [f32]; 4] = {
                let mut it = out.iter_mut();
                std::array::from_fn(|_| it.next().unwrap().as_mut_slice())
            };
            matrix_weighted_rows(&mut dests, &sources, &m);
            for (j, got) in out.iter().enumerate() {
                let (terms, weights): (Vec<&[f32]>, Vec<f32>) = (0..8)
                    .filter(|&i| m[j * 8 + i] != 0.0)
                    .map(|i| (sources[i], m[j * 8 + i]))
                    .unzip();
                let mut expected = vec![0.0f32; len];
                weighted_rows(&mut expected, &terms, &weights);
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(got), bits(&expected), "length {len}, output {j}");
            }
        }
    }
}
