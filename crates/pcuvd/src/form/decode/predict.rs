//! Extending a slow-time series past the recording's ends by linear prediction, so that the
//! alignment's interpolation has samples to read at the first and last frames.

use super::*;

/// An end of a series of frames.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub(super) enum End {
    /// Before the first frame.
    Head,
    /// After the last frame.
    Tail,
}

/// Continues every series of `lanes` (consecutive runs of `frames` + 2·ALIGN_HALF, the frames at
/// ALIGN_HALF..ALIGN_HALF + frames) by ALIGN_HALF predicted frames beyond `end`: a linear
/// predictor fitted on the series' ALIGN_FIT_FRAMES frames nearest that end, pooled over the
/// lanes, with real coefficients when each lane carries two real series (`real`). The other end's
/// slots are left as they are: an end predictor sees only its own end's frames.
pub(super) fn extend(lanes: &mut [Complex32], frames: usize, real: bool, end: End) {
    let len = frames + 2 * ALIGN_HALF;
    let order = ALIGN_ORDER.min(frames.saturating_sub(2) / 2);
    let fit_frames = ALIGN_FIT_FRAMES.min(frames);
    let from = match end {
        End::Head => 0,
        End::Tail => frames - fit_frames,
    };
    let fitted = lanes
        .chunks_exact(len)
        .map(|series| &series[ALIGN_HALF + from..ALIGN_HALF + from + fit_frames]);
    let a = predictor(fitted, order, real);
    for series in lanes.chunks_exact_mut(len) {
        match end {
            // After the last frame: x[t] = Σ_j a_j x[t − j].
            End::Tail => {
                for t in ALIGN_HALF + frames..len {
                    let mut v = Complex64::new(0.0, 0.0);
                    for (j, a) in a.iter().enumerate() {
                        let x = series[t - 1 - j];
                        v += a * Complex64::new(x.re as f64, x.im as f64);
                    }
                    series[t] = Complex32::new(v.re as f32, v.im as f32);
                }
            }
            // Before the first: x[t] = Σ_j a_j* x[t + j].
            End::Head => {
                for t in (0..ALIGN_HALF).rev() {
                    let mut v = Complex64::new(0.0, 0.0);
                    for (j, a) in a.iter().enumerate() {
                        let x = series[t + 1 + j];
                        v += a.conj() * Complex64::new(x.re as f64, x.im as f64);
                    }
                    series[t] = Complex32::new(v.re as f32, v.im as f32);
                }
            }
        }
    }
}

/// Coefficients a_1..a_p of the forward–backward least-squares linear predictor of `series`
/// (x[t] ≈ Σ_j a_j x[t − j], and x[t] ≈ Σ_j a_j* x[t + j]), real when `real`. With fewer than
/// one equation per unknown, or a singular system, the predictor repeats the last value.
pub(super) fn predictor<'a>(
    series: impl Iterator<Item = &'a [Complex32]>,
    order: usize,
    real: bool,
) -> Vec<Complex64> {
    let hold = || {
        let mut a = vec![Complex64::new(0.0, 0.0); order.max(1)];
        a[0] = Complex64::new(1.0, 0.0);
        a
    };
    if order == 0 {
        return hold();
    }
    let p = order.min(ALIGN_ORDER);
    let (mut gram, rhs) = if real {
        real_normal_equations(series, p)
    } else {
        complex_normal_equations(series, p)
    };
    // A light ridge keeps the solve stable on series that are nearly constant or zero.
    let scale = (0..p).map(|j| gram[j][j].re).fold(0.0, f64::max);
    if !(scale > 0.0 && scale.is_finite()) {
        return hold();
    }
    for (j, row) in gram.iter_mut().enumerate() {
        row[j] += 1e-6 * scale;
    }
    solve_small(gram, rhs).unwrap_or_else(hold)
}

/// The forward–backward normal equations (Gram matrix, right-hand side) of the order-`p`
/// predictor of complex `series`.
fn complex_normal_equations<'a>(
    series: impl Iterator<Item = &'a [Complex32]>,
    p: usize,
) -> (Vec<Vec<Complex64>>, Vec<Complex64>) {
    const ZERO: Complex64 = Complex64::new(0.0, 0.0);
    // On the stack, and only the upper triangle: the Gram matrix is Hermitian, and the lower
    // triangle, conjugated from the upper, comes out bit for bit as summed term by term.
    let mut upper = [[ZERO; ALIGN_ORDER]; ALIGN_ORDER];
    let mut rhs = vec![ZERO; p];
    let mut add = |past: &[Complex64; ALIGN_ORDER], target: Complex64| {
        for j in 0..p {
            for k in j..p {
                upper[j][k] += past[j].conj() * past[k];
            }
            rhs[j] += past[j].conj() * target;
        }
    };
    let (mut past, mut future) = ([ZERO; ALIGN_ORDER], [ZERO; ALIGN_ORDER]);
    let mut widened = [ZERO; ALIGN_FIT_FRAMES];
    for narrow in series {
        // Series are at most ALIGN_FIT_FRAMES long (the frames a predictor is fitted on).
        let x = &mut widened[..narrow.len()];
        for (wide, v) in x.iter_mut().zip(narrow) {
            *wide = Complex64::new(v.re as f64, v.im as f64);
        }
        for t in p..x.len() {
            for j in 1..=p {
                // Forward: x[t] from x[t − 1], …, x[t − p].
                past[j - 1] = x[t - j];
                // Backward: x[t − p] from x[t − p + 1], …, x[t], conjugated so the same a_j
                // serve.
                future[j - 1] = x[t - p + j].conj();
            }
            add(&past, x[t]);
            add(&future, x[t - p].conj());
        }
    }
    let gram = (0..p)
        .map(|j| {
            (0..p)
                .map(|k| {
                    if k >= j {
                        upper[j][k]
                    } else {
                        upper[k][j].conj()
                    }
                })
                .collect()
        })
        .collect();
    (gram, rhs)
}

/// [`complex_normal_equations`] of lanes that each carry two real series (real and imaginary
/// parts), whose predictor is real: the real parts of that Gram matrix and right-hand side,
/// Re(conj(u)·v) = u_re·v_re + u_im·v_im, summed alone. Every entry is a sum of one lag's
/// products c_d[u] = x[u + d]·x[u] over a window of the series (the forward equations' and the
/// backward ones' windows offset from each other), so each lag's products are formed once and
/// summed cumulatively, and each entry is a difference of two cumulative sums: p + 1 products per
/// frame where the equations written term by term take p(p + 3), and the same sums to rounding.
fn real_normal_equations<'a>(
    series: impl Iterator<Item = &'a [Complex32]>,
    p: usize,
) -> (Vec<Vec<Complex64>>, Vec<Complex64>) {
    let mut upper = [[0.0f64; ALIGN_ORDER]; ALIGN_ORDER];
    let mut rhs = [0.0f64; ALIGN_ORDER];
    let mut widened = [[0.0f64; 2]; ALIGN_FIT_FRAMES];
    // cumulative[d][i] = Σ_{u < i} x[u + d]·x[u].
    let mut cumulative = [[0.0f64; ALIGN_FIT_FRAMES + 1]; ALIGN_ORDER + 1];
    for narrow in series {
        let n = narrow.len();
        // The equations run over frames p..n: a series no longer than the order adds none.
        if n <= p {
            continue;
        }
        let x = &mut widened[..n];
        for (wide, v) in x.iter_mut().zip(narrow) {
            *wide = [v.re as f64, v.im as f64];
        }
        for (d, sums) in cumulative.iter_mut().enumerate().take(p + 1) {
            let mut sum = 0.0;
            for u in 0..n - d {
                sum += x[u + d][0] * x[u][0] + x[u + d][1] * x[u][1];
                sums[u + 1] = sum;
            }
        }
        // Σ_{u = first}^{last} x[u + d]·x[u].
        let window =
            |d: usize, first: usize, last: usize| cumulative[d][last + 1] - cumulative[d][first];
        for (j, (row, b)) in upper.iter_mut().zip(&mut rhs).enumerate().take(p) {
            for (k, entry) in row.iter_mut().enumerate().take(p).skip(j) {
                // Forward: x[t − 1 − j]·x[t − 1 − k] for t in p..n; backward:
                // x[t − p + 1 + j]·x[t − p + 1 + k].
                *entry += window(k - j, p - 1 - k, n - 2 - k) + window(k - j, 1 + j, n - p + j);
            }
            // Forward: x[t − 1 − j]·x[t]; backward: x[t − p + 1 + j]·x[t − p].
            *b += window(j + 1, p - 1 - j, n - 2 - j) + window(j + 1, 0, n - 1 - p);
        }
    }
    let gram = (0..p)
        .map(|j| {
            (0..p)
                .map(|k| Complex64::new(if k >= j { upper[j][k] } else { upper[k][j] }, 0.0))
                .collect()
        })
        .collect();
    (
        gram,
        rhs[..p].iter().map(|&v| Complex64::new(v, 0.0)).collect(),
    )
}

/// Solves a small complex linear system by Gaussian elimination with partial pivoting.
pub(super) fn solve_small(
    mut a: Vec<Vec<Complex64>>,
    mut b: Vec<Complex64>,
) -> Option<Vec<Complex64>> {
    let n = b.len();
    for col in 0..n {
        let pivot = (col..n).max_by(|&i, &j| a[i][col].norm().total_cmp(&a[j][col].norm()))?;
        if a[pivot][col].norm() == 0.0 {
            return None;
        }
        a.swap(col, pivot);
        b.swap(col, pivot);
        let (upper, lower) = a.split_at_mut(col + 1);
        let pivot_row = &upper[col];
        let pivot_b = b[col];
        for (row, rhs) in lower.iter_mut().zip(&mut b[col + 1..]) {
            let f = row[col] / pivot_row[col];
            for (v, p) in row[col..].iter_mut().zip(&pivot_row[col..]) {
                *v -= f * p;
            }
            *rhs -= f * pivot_b;
        }
    }
    let mut x = vec![Complex64::new(0.0, 0.0); n];
    for row in (0..n).rev() {
        let mut v = b[row];
        for k in row + 1..n {
            v -= a[row][k] * x[k];
        }
        x[row] = v / a[row][row];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The windowed lag sums give the forward–backward equations written term by term (the
    /// real parts of the complex equations), for every order and for series shorter than the
    /// fit, pooled over several lanes.
    #[test]
    fn real_equations_are_the_terms_summed() {
        let lanes: Vec<Vec<Complex32>> = (0..3)
            .map(|l| {
                (0..ALIGN_FIT_FRAMES - 2 * l)
                    .map(|t| {
                        let t = t as f32;
                        Complex32::new(
                            (0.7 * t + l as f32).sin() + 0.1 * (2.3 * t).cos(),
                            (1.9 * t - 0.4 * l as f32).cos(),
                        )
                    })
                    .collect()
            })
            .collect();
        for p in 1..=ALIGN_ORDER {
            let (gram, rhs) = real_normal_equations(lanes.iter().map(|l| l.as_slice()), p);
            let (want_gram, want_rhs) =
                complex_normal_equations(lanes.iter().map(|l| l.as_slice()), p);
            let scale = want_gram[0][0].re;
            for j in 0..p {
                for k in 0..p {
                    let (got, want) = (gram[j][k].re, want_gram[j][k].re);
                    assert!(
                        (got - want).abs() <= 1e-12 * scale,
                        "order {p}, G[{j}][{k}]: {got} against {want}"
                    );
                }
                let (got, want) = (rhs[j].re, want_rhs[j].re);
                assert!(
                    (got - want).abs() <= 1e-12 * scale,
                    "order {p}, b[{j}]: {got} against {want}"
                );
            }
        }
    }
}
