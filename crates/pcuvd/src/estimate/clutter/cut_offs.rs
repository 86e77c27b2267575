//! The cut-offs' rules: the tissue rule (`auto`: strong, steep and slow leading components), the
//! noise rule (the Marchenko–Pastur edge) and the spatial-similarity fit of two squares.

use super::*;

/// The least ratio (2, 3 dB) of a tissue component's energy to the next component's.
pub(super) const TISSUE_STEP: f64 = 2.0;

/// The tissue rule's low cut-off among a spectrum's `components` (see the module
/// documentation), at most `limit`: the leading components that are strong, steep and slow.
pub(super) fn auto_low(
    spectrum: &Spectrum,
    components: usize,
    tissue_frequency: f64,
    limit: usize,
) -> usize {
    let vector = |k| spectrum.vectors.col(k);
    let candidates =
        strong_and_steep(&spectrum.eigenvalues, spectrum.median, components).min(limit);
    (0..candidates)
        .find(|&k| doppler_frequency(vector(k)) >= tissue_frequency)
        .unwrap_or(candidates)
}

/// How many leading components pass the tissue rule's energy tests, at most half of the
/// `components` and one fewer than the `leading` eigenvalues given (largest first): each at
/// least 10 dB above the `median` component (strong) and [`TISSUE_STEP`] above the next
/// (steep).
pub(super) fn strong_and_steep(leading: &[f64], median: f64, components: usize) -> usize {
    let median = median.max(f64::MIN_POSITIVE);
    (0..(components / 2).min(leading.len().saturating_sub(1)))
        .take_while(|&k| leading[k] >= 10.0 * median && leading[k] >= TISSUE_STEP * leading[k + 1])
        .count()
}

/// The median of `values` as the tissue rule reads it: the (n/2)-th smallest.
pub(super) fn median_of(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(|a, b| a.total_cmp(b));
    sorted[values.len() / 2]
}

/// A temporal singular vector's mean Doppler frequency, as a fraction of the frame rate (0 to
/// ½): the phase of its lag-one autocorrelation over 2π.
pub(super) fn doppler_frequency(v: faer::ColRef<'_, c64>) -> f64 {
    let mut r1 = c64::new(0.0, 0.0);
    for t in 0..v.nrows().saturating_sub(1) {
        r1 += v[t].conj() * v[t + 1];
    }
    r1.arg().abs() / (2.0 * std::f64::consts::PI)
}

/// A Gram matrix's eigenvalues (largest first, none below zero: all of them, or the leading
/// ones the tissue rule reads), their median, and the eigenvectors (columns, in the same order)
/// of as many leading components as the cut-offs can read.
pub(super) struct Spectrum {
    pub(super) eigenvalues: Vec<f64>,
    /// The eigenvalues' median; where only the leading ones were found by Krylov iteration, an
    /// upper bound of it that decides the tissue rule as the median does.
    pub(super) median: f64,
    pub(super) vectors: Mat<c64>,
}

impl Spectrum {
    /// The spectrum of `gram` (lower half) that `params` needs. The tissue cut-offs read few
    /// vectors (`Auto`: the components passing its energy tests, at most `low_cap`; `Fixed(k)`:
    /// k), so with no noise cut-off only those are computed ([`leading_eigen`]); the similarity
    /// rule and a noise cut-off read them all. Without `every_value` (a block's filter, whose
    /// singular values nobody reports) only the eigenvalues the tissue rule reads are found: the
    /// leading ones and the median, or an upper bound of it where that decides the rule
    /// ([`Spectrum::leading_by_krylov`]).
    pub(super) fn of(
        gram: &Mat<c64>,
        params: &ClutterParams,
        low_cap: Option<usize>,
        every_value: bool,
    ) -> Result<Spectrum> {
        Spectrum::found(gram, params, low_cap, every_value, true)
    }

    /// [`Spectrum::of`], by Krylov iteration where it may (`krylov`) or never (what the tests
    /// compare it with).
    pub(super) fn found(
        gram: &Mat<c64>,
        params: &ClutterParams,
        low_cap: Option<usize>,
        every_value: bool,
        krylov: bool,
    ) -> Result<Spectrum> {
        let frames = gram.nrows();
        let failed = |e: faer::linalg::evd::EvdError| {
            invalid(
                "clutter filter",
                format!("eigendecomposition failed: {e:?}"),
            )
        };
        let few_vectors = params.high == RankCut::Off
            && match params.low {
                RankCut::Off | RankCut::Auto => true,
                RankCut::Fixed(k) => k <= frames / 2,
                RankCut::Similarity => false,
            };
        if !few_vectors {
            let eig = gram.self_adjoint_eigen(Side::Lower).map_err(failed)?;
            // faer's are in nondecreasing order.
            let eigenvalues: Vec<f64> = (0..frames)
                .map(|k| eig.S()[frames - 1 - k].re.max(0.0))
                .collect();
            return Ok(Spectrum {
                median: median_of(&eigenvalues),
                eigenvalues,
                vectors: Mat::from_fn(frames, frames, |i, k| eig.U()[(i, frames - 1 - k)]),
            });
        }
        if krylov
            && !every_value
            && params.low == RankCut::Auto
            && let Some(spectrum) = Spectrum::leading_by_krylov(gram, low_cap)
        {
            return Ok(spectrum);
        }
        let reduced = leading_eigen::Tridiagonal::new(gram.as_ref());
        let (exact, median) = if every_value || params.low != RankCut::Auto {
            let exact = reduced.eigenvalues().map_err(failed)?;
            let median = median_of(&exact).max(0.0);
            (exact, median)
        } else {
            // strong_and_steep reads the leading min(frames / 2, cap) + 1 and the median.
            let leading = (frames / 2).min(low_cap.unwrap_or(frames)) + 1;
            let value = |rank| {
                reduced.eigenvalue(rank).ok_or_else(|| {
                    invalid("clutter filter", format!("no eigenvalue of rank {rank}"))
                })
            };
            let exact = (0..leading.min(frames))
                .map(value)
                .collect::<Result<Vec<_>>>()?;
            (exact, value(frames - 1 - frames / 2)?.max(0.0))
        };
        let eigenvalues: Vec<f64> = exact.iter().map(|v| v.max(0.0)).collect();
        let count = match params.low {
            RankCut::Auto => {
                strong_and_steep(&eigenvalues, median, frames).min(low_cap.unwrap_or(frames))
            }
            RankCut::Fixed(k) => k,
            RankCut::Off | RankCut::Similarity => 0,
        };
        Ok(Spectrum {
            vectors: reduced.leading_vectors(&exact, count),
            eigenvalues,
            median,
        })
    }

    /// The tissue rule's spectrum without the reduction to tridiagonal form, where the leading
    /// eigenvalues decide it: the leading min(frames / 2, cap) + 1 eigenpairs by Krylov iteration
    /// ([`leading_eigen::leading_pairs`]), and in place of the median an upper bound of it, the
    /// mean of the eigenvalues between the leading ones and the median's rank (each at least
    /// the median): (trace − the leading ones' sum) over their count. Where every component the
    /// steepness test passes is also at least 10 dB above that bound, the rule counts what it
    /// would with the exact median (which is lower); elsewhere `None`, and the caller finds the
    /// median. A block filter cut by the whole image's rule needs two or three eigenpairs of
    /// hundreds, so this is the usual path of a long recording's blocks.
    pub(super) fn leading_by_krylov(gram: &Mat<c64>, low_cap: Option<usize>) -> Option<Spectrum> {
        let frames = gram.nrows();
        // The median's rank, largest first (as `median_of` reads it: the (n/2)-th smallest).
        let median_rank = frames.checked_sub(1 + frames / 2)?;
        let leading = (frames / 2).min(low_cap.unwrap_or(frames)) + 1;
        // Short series: the reduction costs little; and the bound needs ranks between.
        if frames < KRYLOV_MIN_FRAMES || leading > KRYLOV_MAX_PAIRS || leading >= median_rank {
            return None;
        }
        let (values, vectors) = leading_eigen::leading_pairs(gram.as_ref(), leading)?;
        let eigenvalues: Vec<f64> = values.iter().map(|v| v.max(0.0)).collect();
        let steep = strong_and_steep(&eigenvalues, 0.0, frames);
        let trace: f64 = (0..frames).map(|i| gram[(i, i)].re).sum();
        // Rounding in the trace and the sum moves the rest by up to ~n·ε of the trace: the
        // margin keeps the bound above the median whatever it leaves.
        let rest = (trace - eigenvalues.iter().sum::<f64>()).max(0.0) + 1e-10 * trace;
        let median_bound = rest / (median_rank + 1 - leading) as f64;
        if strong_and_steep(&eigenvalues, median_bound, frames) != steep {
            return None;
        }
        let count = steep.min(low_cap.unwrap_or(frames));
        Some(Spectrum {
            vectors: vectors.subcols(0, count).to_owned(),
            eigenvalues,
            median: median_bound,
        })
    }
}

/// Series shorter than this (frames) take the reduction to tridiagonal form, whose O(n³) is
/// then no dearer than faer's Krylov iteration, which builds a basis of at least 64 vectors of
/// n: on the Zen 4 EPYC, at 180 frames (six pairs) 2.4 ms against the reduction's 1.3; at 500
/// (two pairs) 9.3 ms against 23.5 (the means over a run's blocks, both cores busy).
const KRYLOV_MIN_FRAMES: usize = 320;

/// The most leading eigenpairs found by Krylov iteration ([`Spectrum::leading_by_krylov`]);
/// more, and the reduction to tridiagonal form is as quick.
const KRYLOV_MAX_PAIRS: usize = 16;

/// The spatial-similarity matrix of the components in `vectors`' columns (temporal singular
/// vectors, strongest first): C(n, m) = the correlation coefficient over pixels of |S·v_n| and
/// |S·v_m| (the spatial singular vectors' magnitudes, up to their singular values, which a
/// correlation ignores). Accumulated over pixel chunks in f64, added in an order the data fix;
/// |S·V| is never held whole.
pub fn spatial_similarity(data: &[Complex32], frames: usize, vectors: MatRef<'_, c32>) -> Mat<f64> {
    let n = vectors.ncols();
    let (products, sums) = crate::core::parallel::sum_of_chunks(
        data,
        CHUNK * frames,
        || (Mat::<f64>::zeros(n, n), vec![0.0; n]),
        |chunk| {
            let rows = chunk.len() / frames;
            let mut spatial = Mat::<c32>::zeros(rows, n);
            faer::linalg::matmul::matmul(
                spatial.as_mut(),
                faer::Accum::Replace,
                MatRef::from_row_major_slice(as_faer(chunk), rows, frames),
                vectors,
                c32::new(1.0, 0.0),
                faer::Par::Seq,
            );
            let magnitude = Mat::<f64>::from_fn(rows, n, |p, k| spatial[(p, k)].norm() as f64);
            let sums: Vec<f64> = (0..n).map(|k| magnitude.col(k).sum()).collect();
            (magnitude.transpose() * &magnitude, sums)
        },
        |(products, sums), (chunk_products, chunk_sums)| {
            *products += chunk_products;
            for (sum, part) in sums.iter_mut().zip(chunk_sums) {
                *sum += part;
            }
        },
    );
    let pixels = (data.len() / frames) as f64;
    let mean: Vec<f64> = sums.iter().map(|s| s / pixels).collect();
    let covariance = |i: usize, j: usize| products[(i, j)] / pixels - mean[i] * mean[j];
    let spread: Vec<f64> = (0..n).map(|k| covariance(k, k).max(0.0).sqrt()).collect();
    Mat::from_fn(n, n, |i, j| {
        let scale = spread[i] * spread[j];
        if scale > 0.0 {
            covariance(i, j) / scale
        } else {
            0.0
        }
    })
}

/// The cut-offs (low, high) that split the components into tissue [0, low), blood [low, high) and
/// noise [high, N) such that a constant per pair of subspaces fits `similarity`'s off-diagonal
/// entries best (least squares). The tissue and noise squares are two of the six blocks; the
/// others let the tissue and the noise maps anti-correlate (echoes fade with depth while the
/// noise floor grows) without bending the squares. Candidates: low ≤ N/2 (at most half the
/// components are tissue, as for `Auto`), low < high ≤ N.
///
/// The tissue square is the leading one: `low` grows from 0 while taking the next component into
/// the tissue fits better (each with its best `high`), and stops at the first cut-off that does
/// not, even where a larger one fits better still. A vascular tree whose blood components all
/// light the same vessels forms a square of its own after the tissue's; the best fit overall may
/// then take tissue and blood together as "tissue" (on the virtual rat brain, 28–33 components
/// where the tissue holds 4–5) and the filter would remove the blood.
///
/// With `max_low` (a block of a block-wise filter: the whole image's cut-off), the best fit
/// overall, held to `max_low`. A block's few pixels make its fit noisy: on the brain's 1 mm
/// blocks its first best was often a wiggle (1–2 components where the tissue holds 4–5), and so
/// was its best below the cap (that run showed 36 % of the blood-free pixels as flow, against
/// 13 % with `Auto`); its best overall lies at or past the tissue (often the blood's square), so
/// the cap holds it to the whole image's tissue, and a block without tissue cuts less.
pub fn fit_two_squares(similarity: &Mat<f64>, max_low: Option<usize>) -> (usize, usize) {
    let fits = two_square_fits(similarity);
    let better = |a: usize, b: usize| fits[a].0 > fits[b].0 + 1e-12 * fits[b].0.abs();
    let low = match max_low {
        Some(max_low) => {
            let best =
                (0..fits.len()).fold(0, |best, low| if better(low, best) { low } else { best });
            best.min(max_low)
        }
        None => {
            let mut low = 0;
            while low + 1 < fits.len() && better(low + 1, low) {
                low += 1;
            }
            low
        }
    };
    (low, fits[low].1)
}

/// For each tissue cut-off `low` in 0..=N/2: the best fit's score (the larger, the smaller its
/// squared error; the errors of two cut-offs differ by minus the difference of their scores) and
/// its noise cut-off `high` (the largest among equal fits: the fewest components cut).
pub(super) fn two_square_fits(similarity: &Mat<f64>) -> Vec<(f64, usize)> {
    let n = similarity.nrows();
    // table[(i, j)] = Σ of the off-diagonal entries of rows < i and columns < j.
    let mut table = Mat::<f64>::zeros(n + 1, n + 1);
    for i in 0..n {
        for j in 0..n {
            let entry = if i == j { 0.0 } else { similarity[(i, j)] };
            table[(i + 1, j + 1)] = entry + table[(i, j + 1)] + table[(i + 1, j)] - table[(i, j)];
        }
    }
    let block_sum = |rows: (usize, usize), columns: (usize, usize)| {
        table[(rows.1, columns.1)] - table[(rows.0, columns.1)] - table[(rows.1, columns.0)]
            + table[(rows.0, columns.0)]
    };
    let block_entries = |rows: (usize, usize), columns: (usize, usize)| {
        let (r, c) = (rows.1 - rows.0, columns.1 - columns.0);
        if rows == columns {
            r * r.saturating_sub(1)
        } else {
            r * c
        }
    };
    // Minimising the squared error of a constant per block maximises Σ (block sum)² / entries.
    let explained = |rows: (usize, usize), columns: (usize, usize)| {
        let count = block_entries(rows, columns);
        match count {
            0 => 0.0,
            _ => block_sum(rows, columns).powi(2) / count as f64,
        }
    };
    (0..=n / 2)
        .map(|low| {
            let mut best = (f64::NEG_INFINITY, n);
            for high in (low + 1..=n).rev() {
                let parts = [(0, low), (low, high), (high, n)];
                let mut score = 0.0;
                for (i, &rows) in parts.iter().enumerate() {
                    score += explained(rows, rows);
                    for &columns in &parts[i + 1..] {
                        // The block and its transpose hold the same entries.
                        score += 2.0 * explained(rows, columns);
                    }
                }
                if score > best.0 + 1e-12 * score.abs() {
                    best = (score, high);
                }
            }
            best
        })
        .collect()
}

/// The noise cut-off: the components above the Marchenko–Pastur edge of white noise whose
/// variance the `median` of the (all) `eigenvalues` gives, at least one.
pub(super) fn auto_high(eigenvalues: &[f64], median: f64, pixels: usize) -> usize {
    let n = eigenvalues.len();
    // For white noise of variance σ², eigenvalues of SᴴS spread over P σ² (1 ± √(N/P))².
    let ratio = (n as f64 / pixels as f64).sqrt();
    let sigma2_p = median / (1.0 + ratio * ratio).max(1.0);
    let edge = sigma2_p * (1.0 + ratio).powi(2) * 1.05;
    let signal = eigenvalues.iter().take_while(|&&v| v > edge).count();
    signal.max(1)
}
