//! Pixels solved side by side: [`solve_rows`](super::solve_rows) for [`LANES`] pixels at once, a
//! pixel per lane of a vector register, each lane to the bit what the pixel gives alone.

use super::Estimator;

/// Pixels [`field`](super::field) solves side by side, one per lane of a vector register.
pub(super) const LANES: usize = 8;

/// A value per pixel of a [`PixelLanes`].
type Lanes = [f64; LANES];

/// LANES pixels' problems with the same axial weights (1 + cos θ per angle), and the working
/// arrays of their solve, kept from one group of pixels to the next. Solving them together does
/// the pixels' arithmetic in vector registers, a lane each, and each lane does [`solve_rows`](super::solve_rows)'s
/// operations in its order (no fused multiply-adds, the same sums in the same order), so a
/// pixel's vector is the same to the bit as solved alone, and its IRLS rounds stop where they
/// would alone. An angle a pixel has no projection for has weight zero in its lane: its terms
/// add zeros, which leave every sum as [`solve_rows`](super::solve_rows) leaves it without that angle.
pub(super) struct PixelLanes {
    /// Per angle: the shared axial weight.
    axial: Vec<f64>,
    /// Per angle: each pixel's lateral weight.
    lateral: Vec<Lanes>,
    /// Per angle: each pixel's projection (m/s; 0 where it has none).
    v_theta: Vec<Lanes>,
    /// Per angle: the lanes (bit l for lane l) that have its projection.
    present: Vec<u8>,
    /// Per angle: the weights of the current IRLS round and of the next.
    w: Vec<Lanes>,
    new_w: Vec<Lanes>,
}

impl PixelLanes {
    /// Lanes for problems whose model rows have the axial weights of `nominal` (lateral, axial).
    pub(super) fn new(nominal: &[(f64, f64)]) -> Self {
        let n = nominal.len();
        PixelLanes {
            axial: nominal.iter().map(|&(_, c)| c).collect(),
            lateral: vec![[0.0; LANES]; n],
            v_theta: vec![[0.0; LANES]; n],
            present: vec![0; n],
            w: vec![[0.0; LANES]; n],
            new_w: vec![[0.0; LANES]; n],
        }
    }

    /// Sets lane `l`'s problem: per angle, its (finite lateral weight, projection in m/s); a
    /// projection that is not finite is left out, as [`solve_rows`](super::solve_rows) leaves it out.
    pub(super) fn set(&mut self, l: usize, angles: impl Iterator<Item = (f64, f64)>) {
        for (k, (s, p)) in angles.enumerate() {
            self.lateral[k][l] = s;
            let finite = p.is_finite();
            self.v_theta[k][l] = if finite { p } else { 0.0 };
            self.present[k] = (self.present[k] & !(1 << l)) | (u8::from(finite) << l);
        }
    }

    /// Each lane's starting weights, 1/n over its n projections (0 where it has none), and the
    /// lanes that have at least two (the others have no vector).
    fn start(&mut self) -> u8 {
        let mut count = [0usize; LANES];
        for &present in &self.present {
            for (l, count) in count.iter_mut().enumerate() {
                *count += usize::from(present >> l & 1 == 1);
            }
        }
        for (w, &present) in self.w.iter_mut().zip(&self.present) {
            for (l, w) in w.iter_mut().enumerate() {
                *w = if present >> l & 1 == 1 {
                    1.0 / count[l] as f64
                } else {
                    0.0
                };
            }
        }
        (0..LANES).fold(0, |solvable, l| solvable | (u8::from(count[l] >= 2) << l))
    }

    /// Every lane's (Vx, Vz) in m/s, as [`solve_rows`](super::solve_rows) gives it: in AVX-512 registers where the
    /// CPU has them.
    pub(super) fn solve(&mut self, estimator: &Estimator) -> (Lanes, Lanes) {
        #[cfg(target_arch = "x86_64")]
        {
            if is_x86_feature_detected!("avx512f") {
                // SAFETY: AVX-512F was detected.
                return unsafe { self.solve_avx512(estimator) };
            }
            if is_x86_feature_detected!("avx2") {
                // SAFETY: AVX2 was detected.
                return unsafe { self.solve_avx2(estimator) };
            }
        }
        self.solve_portable(estimator)
    }

    /// [`PixelLanes::solve_portable`] in AVX-512 registers, a lane per pixel, with the same
    /// operations in the same order (the compiler's own vectorisation of the portable loops
    /// mixed register widths and shuffles: a fifth faster than one pixel at a time, against
    /// twice as fast here).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn solve_avx512(&mut self, estimator: &Estimator) -> (Lanes, Lanes) {
        use std::arch::x86_64::*;
        let load = |a: &Lanes| unsafe { _mm512_loadu_pd(a.as_ptr()) };
        let store = |to: &mut Lanes, v: __m512d| unsafe { _mm512_storeu_pd(to.as_mut_ptr(), v) };
        let lanes = |v: __m512d| {
            let mut out = [0.0; LANES];
            store(&mut out, v);
            out
        };
        let solvable = self.start();
        let (vx, vz, solved) = self.weighted_solve_avx512();
        // A lane whose first solve fails, or that has fewer than two projections, has no vector.
        let solved = solved & solvable;
        let nan = _mm512_set1_pd(f64::NAN);
        let (mut vx, mut vz) = (
            _mm512_mask_blend_pd(solved, nan, vx),
            _mm512_mask_blend_pd(solved, nan, vz),
        );
        let Estimator::Irls(p) = estimator else {
            return (lanes(vx), lanes(vz));
        };
        let (two, thousand, one) = (
            _mm512_set1_pd(2.0),
            _mm512_set1_pd(1e3),
            _mm512_set1_pd(1.0),
        );
        let (lambda, epsilon) = (_mm512_set1_pd(p.lambda_mm_s), _mm512_set1_pd(p.epsilon));
        let mut active = solved;
        for _ in 0..p.max_iterations {
            if active == 0 {
                break;
            }
            // The weights 1/(|r| + λ), r = 2·V_θ − Vz·c − Vx·s in mm/s (0 where a lane has no
            // projection), and their sum in the angles' order.
            let mut total = _mm512_set1_pd(-0.0);
            for ((((next, lateral), &c), v), &present) in (self.new_w.iter_mut())
                .zip(&self.lateral)
                .zip(&self.axial)
                .zip(&self.v_theta)
                .zip(&self.present)
            {
                let fitted = _mm512_sub_pd(
                    _mm512_mul_pd(two, load(v)),
                    _mm512_mul_pd(vz, _mm512_set1_pd(c)),
                );
                let residual_mm_s = _mm512_mul_pd(
                    _mm512_sub_pd(fitted, _mm512_mul_pd(vx, load(lateral))),
                    thousand,
                );
                let weight = _mm512_maskz_div_pd(
                    present,
                    one,
                    _mm512_add_pd(_mm512_abs_pd(residual_mm_s), lambda),
                );
                store(next, weight);
                total = _mm512_add_pd(total, weight);
            }
            // Normalised, and the largest change of a weight (max ignores a NaN change, as
            // f64::max does: the second operand is what it returns when either is NaN).
            let mut change = _mm512_setzero_pd();
            for (next, w) in self.new_w.iter_mut().zip(&self.w) {
                let normalised = _mm512_div_pd(load(next), total);
                store(next, normalised);
                change = _mm512_max_pd(_mm512_abs_pd(_mm512_sub_pd(normalised, load(w))), change);
            }
            std::mem::swap(&mut self.w, &mut self.new_w);
            let (x, z, solved) = self.weighted_solve_avx512();
            let moved = active & solved;
            vx = _mm512_mask_blend_pd(moved, vx, x);
            vz = _mm512_mask_blend_pd(moved, vz, z);
            let converged = _mm512_cmp_pd_mask::<_CMP_LT_OQ>(change, epsilon);
            active = moved & !converged;
        }
        (lanes(vx), lanes(vz))
    }

    /// [`PixelLanes::weighted_solve`] in AVX-512 registers: (Vx, Vz) and the lanes solved.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    fn weighted_solve_avx512(
        &self,
    ) -> (
        std::arch::x86_64::__m512d,
        std::arch::x86_64::__m512d,
        std::arch::x86_64::__mmask8,
    ) {
        use std::arch::x86_64::*;
        let load = |a: &Lanes| unsafe { _mm512_loadu_pd(a.as_ptr()) };
        let zero = _mm512_setzero_pd();
        let two = _mm512_set1_pd(2.0);
        let (mut a11, mut a12, mut a22, mut b1, mut b2) = (zero, zero, zero, zero, zero);
        for (((s, &c), v), w) in (self.lateral.iter())
            .zip(&self.axial)
            .zip(&self.v_theta)
            .zip(&self.w)
        {
            let (s, c, v, w) = (load(s), _mm512_set1_pd(c), load(v), load(w));
            // w·s·s, w·s·c, w·c·c, w·s·2·v, w·c·2·v, each multiplied from the left.
            let (ws, wc) = (_mm512_mul_pd(w, s), _mm512_mul_pd(w, c));
            a11 = _mm512_add_pd(a11, _mm512_mul_pd(ws, s));
            a12 = _mm512_add_pd(a12, _mm512_mul_pd(ws, c));
            a22 = _mm512_add_pd(a22, _mm512_mul_pd(wc, c));
            b1 = _mm512_add_pd(b1, _mm512_mul_pd(_mm512_mul_pd(ws, two), v));
            b2 = _mm512_add_pd(b2, _mm512_mul_pd(_mm512_mul_pd(wc, two), v));
        }
        let det = _mm512_sub_pd(_mm512_mul_pd(a11, a22), _mm512_mul_pd(a12, a12));
        // max returns its second operand where the product is NaN, as f64::max does.
        let floor = _mm512_mul_pd(
            _mm512_set1_pd(1e-12),
            _mm512_max_pd(
                _mm512_abs_pd(_mm512_mul_pd(a11, a22)),
                _mm512_set1_pd(f64::MIN_POSITIVE),
            ),
        );
        let singular = _mm512_cmp_pd_mask::<_CMP_LE_OQ>(_mm512_abs_pd(det), floor);
        let vx = _mm512_div_pd(
            _mm512_sub_pd(_mm512_mul_pd(a22, b1), _mm512_mul_pd(a12, b2)),
            det,
        );
        let vz = _mm512_div_pd(
            _mm512_sub_pd(_mm512_mul_pd(a11, b2), _mm512_mul_pd(a12, b1)),
            det,
        );
        (vx, vz, !singular)
    }

    /// [`PixelLanes::solve_portable`] compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn solve_avx2(&mut self, estimator: &Estimator) -> (Lanes, Lanes) {
        self.solve_portable(estimator)
    }

    /// [`solve_rows`](super::solve_rows) lane by lane, written as loops over the lanes.
    #[inline(always)]
    fn solve_portable(&mut self, estimator: &Estimator) -> (Lanes, Lanes) {
        let solvable = self.start();
        let (mut vx, mut vz, first) = self.weighted_solve();
        // A lane whose first solve fails, or that has fewer than two projections, has no vector.
        let mut active = [false; LANES];
        for l in 0..LANES {
            active[l] = first[l] && solvable >> l & 1 == 1;
            if !active[l] {
                (vx[l], vz[l]) = (f64::NAN, f64::NAN);
            }
        }
        let Estimator::Irls(p) = estimator else {
            return (vx, vz);
        };
        for _ in 0..p.max_iterations {
            if !active.iter().any(|&a| a) {
                break;
            }
            for ((((next, lateral), &c), v), &present) in (self.new_w.iter_mut())
                .zip(&self.lateral)
                .zip(&self.axial)
                .zip(&self.v_theta)
                .zip(&self.present)
            {
                for l in 0..LANES {
                    let residual_mm_s = (2.0 * v[l] - vz[l] * c - vx[l] * lateral[l]) * 1e3;
                    next[l] = if present >> l & 1 == 1 {
                        1.0 / (residual_mm_s.abs() + p.lambda_mm_s)
                    } else {
                        0.0
                    };
                }
            }
            let mut total = [-0.0; LANES];
            for next in &self.new_w {
                for l in 0..LANES {
                    total[l] += next[l];
                }
            }
            let mut change = [0.0f64; LANES];
            for (next, w) in self.new_w.iter_mut().zip(&self.w) {
                for l in 0..LANES {
                    next[l] /= total[l];
                    change[l] = change[l].max((next[l] - w[l]).abs());
                }
            }
            std::mem::swap(&mut self.w, &mut self.new_w);
            let (x, z, solved) = self.weighted_solve();
            for l in 0..LANES {
                if active[l] && solved[l] {
                    (vx[l], vz[l]) = (x[l], z[l]);
                }
                let converged = change[l] < p.epsilon;
                active[l] = active[l] && solved[l] && !converged;
            }
        }
        (vx, vz)
    }

    /// [`weighted_solve`](super::weighted_solve) of every lane with the weights `self.w`: (Vx, Vz) and whether the
    /// lane's system could be solved.
    #[inline(always)]
    fn weighted_solve(&self) -> (Lanes, Lanes, [bool; LANES]) {
        let zero = [0.0f64; LANES];
        let (mut a11, mut a12, mut a22, mut b1, mut b2) = (zero, zero, zero, zero, zero);
        for (((s, &c), v), w) in (self.lateral.iter())
            .zip(&self.axial)
            .zip(&self.v_theta)
            .zip(&self.w)
        {
            for l in 0..LANES {
                a11[l] += w[l] * s[l] * s[l];
                a12[l] += w[l] * s[l] * c;
                a22[l] += w[l] * c * c;
                b1[l] += w[l] * s[l] * 2.0 * v[l];
                b2[l] += w[l] * c * 2.0 * v[l];
            }
        }
        let (mut vx, mut vz, mut solved) = (zero, zero, [false; LANES]);
        for l in 0..LANES {
            let det = a11[l] * a22[l] - a12[l] * a12[l];
            let singular = det.abs() <= 1e-12 * (a11[l] * a22[l]).abs().max(f64::MIN_POSITIVE);
            solved[l] = !singular;
            vx[l] = (a22[l] * b1[l] - a12[l] * b2[l]) / det;
            vz[l] = (a11[l] * b2[l] - a12[l] * b1[l]) / det;
        }
        (vx, vz, solved)
    }
}

#[cfg(test)]
mod tests {
    use super::super::{IrlsParams, projection_weights, solve_rows};
    use super::*;

    fn paper_angles() -> Vec<f64> {
        (0..8)
            .map(|i| (-15.0 + 30.0 * i as f64 / 7.0_f64).to_radians())
            .collect()
    }

    /// Every path of [`PixelLanes::solve`] the CPU can run (portable, AVX2, AVX-512) gives each
    /// lane [`solve_rows`]'s vector to the bit: lanes missing projections, a lane with one
    /// projection and a singular lane (both NaN) among them.
    #[test]
    fn every_lane_path_solves_as_solve_rows() {
        let angles = paper_angles();
        let nominal: Vec<(f64, f64)> = angles.iter().map(|&a| projection_weights(a)).collect();
        let mut seed = 11u64;
        let mut uniform = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for group in 0..20 {
            let mut lanes = PixelLanes::new(&nominal);
            let mut problems = Vec::new();
            for l in 0..LANES {
                let (vx, vz) = (0.04 * uniform() - 0.02, 0.04 * uniform() - 0.02);
                let singular = group % 5 == 0 && l == 3;
                // Some lanes miss two projections, one all but one.
                let missing = |k: usize| {
                    (group % 3 == 1 && (k == l || k == (l + 3) % 8))
                        || (group % 7 == 2 && l == 5 && k != 4)
                };
                let problem: Vec<(f64, f64)> = (nominal.iter().enumerate())
                    .map(|(k, &(s, c))| {
                        let s = if singular {
                            0.0
                        } else {
                            s * (0.8 + 0.4 * uniform())
                        };
                        let p = 0.5 * (vx * s + vz * c) + 0.006 * (uniform() - 0.5);
                        (s, if missing(k) { f64::NAN } else { p })
                    })
                    .collect();
                lanes.set(l, problem.iter().copied());
                problems.push(problem);
            }
            for est in [
                Estimator::LeastSquares,
                Estimator::Irls(IrlsParams::default()),
                Estimator::Irls(IrlsParams {
                    max_iterations: 2,
                    ..Default::default()
                }),
            ] {
                let mut paths = vec![("portable", lanes.solve_portable(&est))];
                #[cfg(target_arch = "x86_64")]
                {
                    if is_x86_feature_detected!("avx2") {
                        // SAFETY: AVX2 was detected.
                        paths.push(("AVX2", unsafe { lanes.solve_avx2(&est) }));
                    }
                    if is_x86_feature_detected!("avx512f") {
                        // SAFETY: AVX-512F was detected.
                        paths.push(("AVX-512", unsafe { lanes.solve_avx512(&est) }));
                    }
                }
                for (path, (x, z)) in paths {
                    for (l, problem) in problems.iter().enumerate() {
                        let rows: Vec<(f64, f64)> = problem
                            .iter()
                            .zip(&nominal)
                            .map(|(&(s, _), &(_, c))| (s, c))
                            .collect();
                        let v: Vec<f64> = problem.iter().map(|&(_, v)| v).collect();
                        let want = solve_rows(&rows, &v, &est);
                        assert!(
                            want.0.to_bits() == x[l].to_bits()
                                && want.1.to_bits() == z[l].to_bits(),
                            "{path}, {est:?}, group {group} lane {l}: {:?} against {want:?}",
                            (x[l], z[l])
                        );
                    }
                }
            }
        }
    }
}
