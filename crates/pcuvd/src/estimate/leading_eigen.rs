//! Every eigenvalue of a Hermitian matrix and the eigenvectors of its largest few only.
//!
//! The clutter filter's tissue rule reads all the eigenvalues of a Gram matrix (their median and
//! steps) but the eigenvectors of the few leading components only (their Doppler frequency, and
//! the subspace it removes). A full Hermitian eigendecomposition spends most of its time on the
//! vectors: accumulating the tridiagonal solver's rotations and carrying all n vectors back
//! through the Householder reflections of the reduction. Here the matrix is reduced to real
//! tridiagonal form once (faer), its eigenvalues found without vectors (faer's tridiagonal QR),
//! and each wanted eigenvector found by inverse iteration on the tridiagonal at its eigenvalue
//! (O(n) per solve, LAPACK's `stein` in spirit), orthogonalised against those before it, then
//! carried back through the reflections: O(n²) per vector instead of O(n³) for all.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::evd::{self, ComputeEigenvectors, tridiag};
use faer::linalg::householder;
use faer::{Col, ColRef, Conj, Mat, MatRef, Par, c64};

/// A Hermitian matrix reduced to real symmetric tridiagonal form, T = Dᴴ Qᴴ A Q D (Q a product
/// of Householder reflections, D a diagonal of unit phases that makes the subdiagonal real).
pub(crate) struct Tridiagonal {
    /// The reduction's output: T's complex diagonals and the reflections' vectors below them.
    packed: Mat<c64>,
    /// The reflections' block coefficients.
    householder: Mat<c64>,
    /// T's diagonal (real).
    diagonal: Vec<f64>,
    /// T's subdiagonal, made real and non-negative by D.
    subdiagonal: Vec<f64>,
}

impl Tridiagonal {
    /// Reduces the Hermitian `matrix` (its lower half read) to tridiagonal form.
    pub(crate) fn new(matrix: MatRef<'_, c64>) -> Tridiagonal {
        let n = matrix.nrows();
        let mut packed = Mat::<c64>::zeros(n, n);
        packed.copy_from_triangular_lower(matrix);
        let block = faer::linalg::qr::no_pivoting::factor::recommended_block_size::<c64>(n, n);
        let mut householder = Mat::<c64>::zeros(block, n.saturating_sub(1));
        if n > 0 {
            let mut buffer = MemBuffer::new(tridiag::tridiag_in_place_scratch::<c64>(
                n,
                Par::Seq,
                Default::default(),
            ));
            tridiag::tridiag_in_place(
                packed.as_mut(),
                householder.as_mut(),
                Par::Seq,
                MemStack::new(&mut buffer),
                Default::default(),
            );
        }
        let diagonal = (0..n).map(|i| packed[(i, i)].re).collect();
        let subdiagonal = (1..n).map(|i| packed[(i, i - 1)].norm()).collect();
        Tridiagonal {
            packed,
            householder,
            diagonal,
            subdiagonal,
        }
    }

    /// Every eigenvalue, largest first.
    pub(crate) fn eigenvalues(&self) -> Result<Vec<f64>, evd::EvdError> {
        let n = self.diagonal.len();
        let mut values = Col::<f64>::zeros(n);
        if n > 0 {
            let mut subdiagonal = self.subdiagonal.clone();
            subdiagonal.push(0.0);
            let mut buffer = MemBuffer::new(evd::self_adjoint_evd_scratch::<f64>(
                n,
                ComputeEigenvectors::No,
                Par::Seq,
                Default::default(),
            ));
            evd::tridiagonal_self_adjoint_evd(
                ColRef::from_slice(&self.diagonal).as_diagonal(),
                ColRef::from_slice(&subdiagonal).as_diagonal(),
                values.as_diagonal_mut(),
                None,
                Par::Seq,
                MemStack::new(&mut buffer),
                Default::default(),
            )?;
        }
        // The solver returns them in nondecreasing order.
        Ok(values.iter().rev().copied().collect())
    }

    /// The `rank`-th largest eigenvalue (0: the largest), by bisection on Sturm counts (the
    /// number of eigenvalues below a shift, the negative pivots of T − shift·I): O(n) a step and
    /// about a hundred steps to the rounding unit, so that a few eigenvalues cost far less than
    /// all of them do by the QR iteration. `None` when `rank` is not below the order.
    ///
    /// Each count is a serial recurrence (a division per row, on the pivot before it), so one
    /// count leaves the CPU waiting on its divider. One pass over T counts at every middle the
    /// next [`LEVELS`] steps may take, whichever halves they keep, and the steps then walk that
    /// tree: the same middles, counts and result as one step a pass, in a third of the passes.
    pub(crate) fn eigenvalue(&self, rank: usize) -> Option<f64> {
        let n = self.diagonal.len();
        let below_count = n.checked_sub(rank + 1)?;
        let squares: Vec<f64> = self.subdiagonal.iter().map(|e| e * e).collect();
        let pivot_floor = pivot_floor(&squares);
        let (mut low, mut high, norm_rounding) = self.bracket(pivot_floor);
        // Invariant: at most `below_count` eigenvalues lie below `low`, more below `high`.
        loop {
            // The tree of middles under (low, high): node k's interval splits at its middle
            // into nodes 2k + 1 (below) and 2k + 2 (above).
            let mut intervals = [(low, high); TREE];
            let mut shifts = [0.0; TREE];
            for k in 0..TREE {
                let (a, b) = intervals[k];
                shifts[k] = 0.5 * (a + b);
                if 2 * k + 2 < TREE {
                    intervals[2 * k + 1] = (a, shifts[k]);
                    intervals[2 * k + 2] = (shifts[k], b);
                }
            }
            let counts = counts_below(&self.diagonal, &squares, pivot_floor, &shifts);
            let mut node = 0;
            for _ in 0..LEVELS {
                let middle = shifts[node];
                let width = (2.0 * f64::EPSILON * low.abs().max(high.abs())).max(norm_rounding);
                if high - low <= width || middle <= low || middle >= high {
                    return Some(middle);
                }
                if counts[node] > below_count {
                    high = middle;
                    node = 2 * node + 1;
                } else {
                    low = middle;
                    node = 2 * node + 2;
                }
            }
        }
    }

    /// An interval holding every eigenvalue (Gershgorin's discs), widened by the rounding the
    /// reduction to T left in them, and that rounding: (low, high, rounding).
    fn bracket(&self, pivot_floor: f64) -> (f64, f64, f64) {
        let n = self.diagonal.len();
        let radius = |i: usize| {
            let left = if i == 0 { 0.0 } else { self.subdiagonal[i - 1] };
            let right = self.subdiagonal.get(i).copied().unwrap_or(0.0);
            left + right
        };
        let low = (0..n)
            .map(|i| self.diagonal[i] - radius(i))
            .fold(f64::MAX, f64::min);
        let high = (0..n)
            .map(|i| self.diagonal[i] + radius(i))
            .fold(f64::MIN, f64::max);
        // The reduction to T already moved every eigenvalue by up to about the rounding unit
        // times the matrix's norm: no point bisecting below that.
        let norm_rounding = f64::EPSILON * low.abs().max(high.abs()) + pivot_floor;
        (low - norm_rounding, high + norm_rounding, norm_rounding)
    }

    /// The unit eigenvectors (columns) of the matrix for `eigenvalues[..count]`, which must be
    /// [`Tridiagonal::eigenvalues`]' own, largest first. Each is orthogonal to those before it, so
    /// that a repeated eigenvalue gets a basis of its eigenspace.
    pub(crate) fn leading_vectors(&self, eigenvalues: &[f64], count: usize) -> Mat<c64> {
        let n = self.diagonal.len();
        let count = count.min(n);
        let mut real = Mat::<f64>::zeros(n, count);
        for k in 0..count {
            // A start with a part along every eigenvector (whole-number hash, no zero entry).
            let mut x: Vec<f64> = (0..n)
                .map(|i| 1.0 + ((i * 7919 + k * 104_729) % 1000) as f64 * 1e-3)
                .collect();
            // With the shift at the eigenvalue one solve grows its eigenvector by 1/(rounding)
            // over the others; a second and third make it certain (LAPACK's stein iterates up
            // to five times on a growth test).
            for _ in 0..3 {
                solve_shifted(&self.diagonal, &self.subdiagonal, eigenvalues[k], &mut x);
                for _ in 0..2 {
                    for j in 0..k {
                        let along: f64 = (0..n).map(|i| real[(i, j)] * x[i]).sum();
                        for (i, value) in x.iter_mut().enumerate() {
                            *value -= along * real[(i, j)];
                        }
                    }
                }
                let norm = x.iter().map(|v| v * v).sum::<f64>().sqrt();
                let norm = if norm > 0.0 { norm } else { 1.0 };
                x.iter_mut().for_each(|v| *v /= norm);
            }
            for (i, value) in x.into_iter().enumerate() {
                real[(i, k)] = value;
            }
        }
        // Back through D (the phases that made the subdiagonal real) and Q.
        let mut phase = c64::new(1.0, 0.0);
        let mut phases = vec![phase; n];
        for (i, slot) in phases.iter_mut().enumerate().skip(1) {
            let turned = self.packed[(i, i - 1)] * phase;
            let norm = turned.norm();
            phase = if norm > 0.0 {
                turned / norm
            } else {
                c64::new(1.0, 0.0)
            };
            *slot = phase;
        }
        let mut vectors = Mat::<c64>::from_fn(n, count, |i, k| phases[i] * real[(i, k)]);
        if n > 1 && count > 0 {
            let block = self.householder.nrows();
            let mut buffer = MemBuffer::new(
                householder::apply_block_householder_sequence_on_the_left_in_place_scratch::<c64>(
                    n - 1,
                    block,
                    count,
                ),
            );
            householder::apply_block_householder_sequence_on_the_left_in_place_with_conj(
                self.packed.as_ref().submatrix(1, 0, n - 1, n - 1),
                self.householder.as_ref(),
                Conj::No,
                vectors.as_mut().subrows_mut(1, n - 1),
                Par::Seq,
                MemStack::new(&mut buffer),
            );
        }
        vectors
    }
}

/// Bisection steps [`Tridiagonal::eigenvalue`] takes from one pass over T.
const LEVELS: usize = 3;

/// Middles one pass counts at: a full binary tree of [`LEVELS`] levels.
const TREE: usize = (1 << LEVELS) - 1;

/// The least pivot a Sturm count allows (LAPACK's pivmin), given T's squared subdiagonal: a
/// pivot closer to zero is taken as that much below it, so that every count is of a matrix
/// within rounding of T's.
fn pivot_floor(squares: &[f64]) -> f64 {
    f64::MIN_POSITIVE * squares.iter().copied().fold(1.0, f64::max)
}

/// The number of eigenvalues of T (its `diagonal` and squared subdiagonal `squares`) below
/// each of `shifts`: the negative pivots of T − shift·I, the shifts' recurrences side by side.
fn counts_below(
    diagonal: &[f64],
    squares: &[f64],
    pivot_floor: f64,
    shifts: &[f64; TREE],
) -> [usize; TREE] {
    let mut counts = [0; TREE];
    let mut pivots = [1.0; TREE];
    for (i, &d) in diagonal.iter().enumerate() {
        let square = if i == 0 { 0.0 } else { squares[i - 1] };
        for ((pivot, count), &shift) in pivots.iter_mut().zip(&mut counts).zip(shifts) {
            let coupling = if i == 0 { 0.0 } else { square / *pivot };
            *pivot = d - shift - coupling;
            if pivot.abs() < pivot_floor {
                *pivot = -pivot_floor;
            }
            *count += usize::from(*pivot < 0.0);
        }
    }
    counts
}

/// Solves (T − shift·I) x = b in place for the symmetric tridiagonal T (`diagonal`,
/// `subdiagonal`), by Gaussian elimination with partial pivoting (rows may swap, which puts a
/// second superdiagonal in the factor). A pivot that vanishes (the shift is an eigenvalue) is
/// replaced by the matrix's scale times the rounding unit, as inverse iteration wants.
fn solve_shifted(diagonal: &[f64], subdiagonal: &[f64], shift: f64, b: &mut [f64]) {
    let n = diagonal.len();
    if n == 0 {
        return;
    }
    let scale = diagonal
        .iter()
        .map(|d| (d - shift).abs())
        .chain(subdiagonal.iter().map(|e| e.abs()))
        .fold(0.0, f64::max);
    let tiny = (scale * f64::EPSILON).max(f64::MIN_POSITIVE);
    let safe = |pivot: f64| {
        if pivot.abs() < tiny {
            tiny.copysign(pivot)
        } else {
            pivot
        }
    };
    // The factor's rows: its diagonal, first and second superdiagonals.
    let mut factor = vec![[0.0f64; 3]; n];
    // Row i as the elimination reaches it: its entries in columns i and i + 1 (never i + 2).
    let (mut head, mut next) = (
        diagonal[0] - shift,
        subdiagonal.first().copied().unwrap_or(0.0),
    );
    for i in 0..n - 1 {
        let below = subdiagonal[i];
        let below_diagonal = diagonal[i + 1] - shift;
        let below_next = subdiagonal.get(i + 1).copied().unwrap_or(0.0);
        if head.abs() >= below.abs() {
            let pivot = safe(head);
            let m = below / pivot;
            factor[i] = [pivot, next, 0.0];
            b[i + 1] -= m * b[i];
            (head, next) = (below_diagonal - m * next, below_next);
        } else {
            let m = head / below;
            factor[i] = [below, below_diagonal, below_next];
            b.swap(i, i + 1);
            b[i + 1] -= m * b[i];
            (head, next) = (next - m * below_diagonal, -m * below_next);
        }
    }
    factor[n - 1] = [safe(head), 0.0, 0.0];
    for i in (0..n).rev() {
        let mut value = b[i];
        if i + 1 < n {
            value -= factor[i][1] * b[i + 1];
        }
        if i + 2 < n {
            value -= factor[i][2] * b[i + 2];
        }
        b[i] = value / factor[i][0];
    }
}

/// The `count` largest eigenvalues (largest first) and their unit eigenvectors (columns) of the
/// Hermitian positive semi-definite `matrix` (its lower half read), by faer's Krylov–Schur
/// iteration (Lanczos with thick restarts): each a few dozen products with the matrix, O(n²)
/// each, against the O(n³) reduction to tridiagonal form. Each pair's residual
/// ‖A·v − λ·v‖ is at most 10⁻¹² of the matrix's trace (which bounds its largest eigenvalue), as
/// [`Tridiagonal`]'s are. `None` when the iteration does not converge within its restarts.
pub(crate) fn leading_pairs(matrix: MatRef<'_, c64>, count: usize) -> Option<(Vec<f64>, Mat<c64>)> {
    use faer::matrix_free::eigen::{
        PartialEigenParams, partial_self_adjoint_eigen, partial_self_adjoint_eigen_scratch,
    };
    let n = matrix.nrows();
    if count == 0 || count > n {
        return None;
    }
    let full = Mat::<c64>::from_fn(n, n, |i, j| {
        if i >= j {
            matrix[(i, j)]
        } else {
            matrix[(j, i)].conj()
        }
    });
    let trace: f64 = (0..n).map(|i| matrix[(i, i)].re).sum();
    if !(trace.is_finite() && trace > 0.0) {
        return None;
    }
    // A fixed start with a part along every eigenvector, so that a run is reproducible.
    let start = Col::<c64>::from_fn(n, |i| {
        c64::new(1.0 + ((i * 7919) % 1000) as f64 * 1e-3, 0.0)
    });
    let start = &start * faer::Scale(c64::new(1.0 / start.norm_l2(), 0.0));
    let params = PartialEigenParams {
        max_restarts: 64,
        ..Default::default()
    };
    let mut buffer = MemBuffer::new(partial_self_adjoint_eigen_scratch::<c64>(
        &full.as_ref(),
        count,
        Par::Seq,
        params,
    ));
    let mut vectors = Mat::<c64>::zeros(n, count);
    let mut values = vec![c64::new(0.0, 0.0); count];
    let info = partial_self_adjoint_eigen(
        vectors.as_mut(),
        &mut values,
        &full.as_ref(),
        start.as_ref(),
        1e-12 * trace,
        Par::Seq,
        MemStack::new(&mut buffer),
        params,
    );
    if info.n_converged_eigen < count {
        return None;
    }
    // The largest magnitudes of a positive semi-definite matrix are its largest eigenvalues.
    Some((values.iter().map(|v| v.re).collect(), vectors))
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::Side;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A Gram matrix SᴴS of frames whose components span `decades` of energy, as a tissue's do,
    /// over white noise.
    fn gram(frames: usize, pixels: usize, decades: &[f64], seed: u64) -> Mat<c64> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let mut gaussian = || c64::new(normal.sample(&mut rng), normal.sample(&mut rng));
        let tones: Vec<(f64, f64)> = decades
            .iter()
            .enumerate()
            .map(|(k, &d)| (10f64.powf(d / 2.0), 0.003 * k as f64))
            .collect();
        let s = Mat::<c64>::from_fn(pixels, frames, |_, _| gaussian());
        let mut s = s;
        for p in 0..pixels {
            for &(amplitude, cycles) in &tones {
                let speckle = gaussian() * amplitude;
                for f in 0..frames {
                    let phase = 2.0 * std::f64::consts::PI * cycles * f as f64;
                    s[(p, f)] += speckle * c64::new(phase.cos(), phase.sin());
                }
            }
        }
        s.adjoint() * &s
    }

    /// Eigenvalues and leading eigenvectors equal faer's full decomposition's: the values to
    /// 10⁻¹² of the largest, each vector to 10⁻⁹ (up to its phase), and each an eigenvector to
    /// 10⁻¹² of the largest eigenvalue (its residual).
    #[test]
    fn leading_eigenpairs_equal_the_full_decomposition() {
        for (frames, seed) in [(48, 1), (97, 2)] {
            let g = gram(frames, 400, &[8.0, 6.5, 5.0, 3.0], seed);
            let full = g.self_adjoint_eigen(Side::Lower).unwrap();
            let reduced = Tridiagonal::new(g.as_ref());
            let values = reduced.eigenvalues().unwrap();
            let largest = values[0];
            for (k, value) in values.iter().enumerate() {
                let expected = full.S()[frames - 1 - k].re;
                assert!(
                    (value - expected).abs() <= 1e-12 * largest,
                    "eigenvalue {k}: {value} vs {expected}"
                );
            }
            let vectors = reduced.leading_vectors(&values, 6);
            for k in 0..6 {
                let expected = full.U().col(frames - 1 - k);
                let overlap: c64 = (0..frames)
                    .map(|i| expected[i].conj() * vectors[(i, k)])
                    .sum();
                assert!(
                    (overlap.norm() - 1.0).abs() < 1e-9,
                    "vector {k}: overlap {}",
                    overlap.norm()
                );
                let v = vectors.col(k);
                let residual = (&g * v - v * faer::Scale(c64::new(values[k], 0.0))).norm_l2();
                assert!(
                    residual <= 1e-12 * largest,
                    "vector {k}: residual {residual}"
                );
            }
        }
    }

    /// Krylov iteration's leading eigenpairs are the full decomposition's: the values to 10⁻¹² of
    /// the largest, each vector to 10⁻⁹ (up to its phase), each residual within 10⁻¹² of the
    /// trace; in the order of the values.
    #[test]
    fn krylov_leading_pairs_equal_the_full_decomposition() {
        for (frames, count, seed) in [(160, 2, 3), (300, 6, 4)] {
            let g = gram(frames, 500, &[8.0, 6.5, 5.0, 3.0, 2.0], seed);
            let full = g.self_adjoint_eigen(Side::Lower).unwrap();
            let largest = full.S()[frames - 1].re;
            let trace: f64 = (0..frames).map(|i| g[(i, i)].re).sum();
            let (values, vectors) = leading_pairs(g.as_ref(), count).unwrap();
            assert!(values.is_sorted_by(|a, b| a >= b), "{values:?}");
            for k in 0..count {
                let expected = full.S()[frames - 1 - k].re;
                assert!(
                    (values[k] - expected).abs() <= 1e-12 * largest,
                    "eigenvalue {k}: {} vs {expected}",
                    values[k]
                );
                let overlap: c64 = (0..frames)
                    .map(|i| full.U()[(i, frames - 1 - k)].conj() * vectors[(i, k)])
                    .sum();
                assert!((overlap.norm() - 1.0).abs() < 1e-9, "vector {k}: {overlap}");
                let v = vectors.col(k);
                let residual = (&g * v - v * faer::Scale(c64::new(values[k], 0.0))).norm_l2();
                assert!(residual <= 1e-12 * trace, "vector {k}: residual {residual}");
            }
        }
        // Nothing to find, or more than the order.
        let g = gram(8, 20, &[2.0], 5);
        assert!(leading_pairs(g.as_ref(), 0).is_none() && leading_pairs(g.as_ref(), 9).is_none());
    }

    /// Bisection finds what the QR iteration finds, to 10⁻¹³ of the largest eigenvalue, every
    /// rank of Gram matrices spanning eight decades; and the eigenvalues of the tridiagonal
    /// (…, 1, 2, 1, …), 2 + 2 cos(kπ/(n + 1)), to 10⁻¹⁴.
    #[test]
    fn bisected_eigenvalues_equal_the_qr_iterations() {
        for (frames, seed) in [(48, 3), (97, 4)] {
            let g = gram(frames, 400, &[8.0, 6.5, 5.0, 3.0], seed);
            let reduced = Tridiagonal::new(g.as_ref());
            let values = reduced.eigenvalues().unwrap();
            for (rank, value) in values.iter().enumerate() {
                let bisected = reduced.eigenvalue(rank).unwrap();
                assert!(
                    (bisected - value).abs() <= 1e-13 * values[0],
                    "rank {rank}: {bisected} vs {value}"
                );
            }
            assert_eq!(reduced.eigenvalue(frames), None);
        }
        let n = 31;
        let toeplitz = Tridiagonal {
            packed: Mat::zeros(0, 0),
            householder: Mat::zeros(0, 0),
            diagonal: vec![2.0; n],
            subdiagonal: vec![1.0; n - 1],
        };
        for rank in 0..n {
            let k = (rank + 1) as f64;
            let exact = 2.0 + 2.0 * (k * std::f64::consts::PI / (n + 1) as f64).cos();
            let bisected = toeplitz.eigenvalue(rank).unwrap();
            assert!(
                (bisected - exact).abs() < 1e-14,
                "rank {rank}: {bisected} vs {exact}"
            );
        }
    }

    /// One bisection step a pass, as the steps were taken before a pass counted at the next
    /// levels' middles too.
    fn eigenvalue_a_step_a_pass(t: &Tridiagonal, rank: usize) -> Option<f64> {
        let n = t.diagonal.len();
        let below_count = n.checked_sub(rank + 1)?;
        let squares: Vec<f64> = t.subdiagonal.iter().map(|e| e * e).collect();
        let floor = pivot_floor(&squares);
        let below = |shift: f64| {
            let mut count = 0;
            let mut pivot = 1.0;
            for (i, &d) in t.diagonal.iter().enumerate() {
                let coupling = if i == 0 { 0.0 } else { squares[i - 1] / pivot };
                pivot = d - shift - coupling;
                if pivot.abs() < floor {
                    pivot = -floor;
                }
                count += usize::from(pivot < 0.0);
            }
            count
        };
        let (mut low, mut high, norm_rounding) = t.bracket(floor);
        loop {
            let middle = 0.5 * (low + high);
            let width = (2.0 * f64::EPSILON * low.abs().max(high.abs())).max(norm_rounding);
            if high - low <= width || middle <= low || middle >= high {
                return Some(middle);
            }
            if below(middle) > below_count {
                high = middle;
            } else {
                low = middle;
            }
        }
    }

    /// Counting at the next levels' middles in one pass finds every eigenvalue bit for bit as
    /// one step a pass does: Gram matrices spanning eight decades, a repeated eigenvalue, and a
    /// tridiagonal of zeros (every count at the floor).
    #[test]
    fn a_pass_over_three_levels_bisects_as_one_step_a_pass() {
        let mut cases: Vec<Tridiagonal> = [(48, 5), (97, 6), (180, 7)]
            .into_iter()
            .map(|(frames, seed)| {
                Tridiagonal::new(gram(frames, 400, &[8.0, 6.5, 5.0, 3.0], seed).as_ref())
            })
            .collect();
        let rank_two = Mat::<c64>::from_fn(12, 12, |i, j| {
            c64::new(((i % 3) * (j % 3)) as f64 + ((i % 2) * (j % 2)) as f64, 0.0)
        });
        cases.push(Tridiagonal::new(rank_two.as_ref()));
        cases.push(Tridiagonal::new(Mat::<c64>::zeros(5, 5).as_ref()));
        for (c, t) in cases.iter().enumerate() {
            for rank in 0..=t.diagonal.len() {
                let (new, old) = (t.eigenvalue(rank), eigenvalue_a_step_a_pass(t, rank));
                assert_eq!(
                    new.map(f64::to_bits),
                    old.map(f64::to_bits),
                    "case {c}, rank {rank}: {new:?} vs {old:?}"
                );
            }
        }
    }

    /// A repeated eigenvalue (a rank-2 matrix's zero, many times over) gets orthonormal vectors
    /// that are eigenvectors.
    #[test]
    fn a_repeated_eigenvalue_gets_an_orthonormal_basis() {
        let n = 12;
        let a = Mat::<c64>::from_fn(n, 2, |i, j| c64::new((i + j) as f64, (i * j) as f64 * 0.5));
        let g = &a * a.adjoint();
        let reduced = Tridiagonal::new(g.as_ref());
        let values = reduced.eigenvalues().unwrap();
        let vectors = reduced.leading_vectors(&values, 5);
        let gram_of_vectors = vectors.adjoint() * &vectors;
        for i in 0..5 {
            for j in 0..5 {
                let expected = if i == j { 1.0 } else { 0.0 };
                assert!((gram_of_vectors[(i, j)] - c64::new(expected, 0.0)).norm() < 1e-9);
            }
            let v = vectors.col(i);
            let residual = (&g * v - v * faer::Scale(c64::new(values[i], 0.0))).norm_l2();
            assert!(
                residual <= 1e-10 * values[0],
                "vector {i}: residual {residual}"
            );
        }
    }

    /// Partial pivoting: a shifted tridiagonal whose first pivot vanishes is solved exactly.
    #[test]
    fn shifted_solve_equals_the_dense_solution() {
        let diagonal = [1.0, 4.0, -2.0, 3.0, 0.5];
        let subdiagonal = [2.0, 1.0, 5.0, 0.25];
        let shift = 1.0;
        let x_true = [1.0, -2.0, 0.5, 3.0, -1.0];
        let t = |i: usize, j: usize| match i.abs_diff(j) {
            0 => diagonal[i] - shift,
            1 => subdiagonal[i.min(j)],
            _ => 0.0,
        };
        let mut b: Vec<f64> = (0..5)
            .map(|i| (0..5).map(|j| t(i, j) * x_true[j]).sum())
            .collect();
        solve_shifted(&diagonal, &subdiagonal, shift, &mut b);
        for (got, want) in b.iter().zip(x_true) {
            assert!((got - want).abs() < 1e-12, "{got} vs {want}");
        }
    }
}
