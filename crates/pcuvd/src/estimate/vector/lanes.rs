//! Pixels solved side by side: [`solve_rows`](super::solve_rows) for [`LANES`] pixels at once, a
//! pixel per lane of a vector register, each lane to the bit what the pixel gives alone.

use super::Estimator;

/// Pixels [`field`](super::field) solves side by side, one per lane of a vector register.
pub(super) const LANES: usize = 8;

/// A value per pixel of a [`PixelLanes`].
type Lanes = [f64; LANES];

/// LANES pixels' problems with the same axial weights (1 + cos θ per angle), and the working
/// arrays of their solve, kept from one group of pixels to the next. Solving them together does
/// the pixels' arithmetic in vector registers, a lane each, and each lane does the operations of
/// [`solve_rows`](super::solve_rows) in their order (no fused multiply-adds, the same sums in the
/// same order), so a pixel's vector is the same to the bit as solved alone, and its IRLS rounds
/// stop where they would alone. An angle a pixel has no projection for has weight zero in its
/// lane: its terms add zeros, which leave every sum as it is without that angle.
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
    /// projection that is not finite is left out, as [`solve_rows`](super::solve_rows) leaves
    /// it out.
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

    /// Every lane's (Vx, Vz) in m/s, as [`solve_rows`](super::solve_rows) gives it: in pairs of
    /// AVX2 registers where the CPU has them. (No AVX-512 path: the divisions bound the solve,
    /// and one AVX-512 register per operation was no faster than two AVX2 ones; the speed page
    /// has the numbers.)
    pub(super) fn solve(&mut self, estimator: &Estimator) -> (Lanes, Lanes) {
        #[cfg(target_arch = "x86_64")]
        if is_x86_feature_detected!("avx2") {
            // SAFETY: AVX2 was detected.
            return unsafe { self.solve_avx2(estimator) };
        }
        self.solve_in::<Lanes>(estimator)
    }

    /// [`PixelLanes::solve_in`] in pairs of AVX2 registers.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn solve_avx2(&mut self, estimator: &Estimator) -> (Lanes, Lanes) {
        self.solve_in::<simd::Avx2Pair>(estimator)
    }

    /// [`solve_rows`](super::solve_rows) of every lane at once, in the registers of `V`: the same
    /// operations in the same order as one pixel alone, lanes that are done left as they are.
    #[inline(always)]
    fn solve_in<V: EightLanes>(&mut self, estimator: &Estimator) -> (Lanes, Lanes) {
        let solvable = self.start();
        let (vx, vz, solved) = self.weighted_solve_in::<V>();
        // A lane whose first solve fails, or that has fewer than two projections, has no vector.
        let solved = solved & solvable;
        let nan = V::splat(f64::NAN);
        let (mut vx, mut vz) = (V::select(solved, vx, nan), V::select(solved, vz, nan));
        let Estimator::Irls(p) = estimator else {
            return (vx.lanes(), vz.lanes());
        };
        let (two, thousand, one) = (V::splat(2.0), V::splat(1e3), V::splat(1.0));
        let (lambda, epsilon) = (V::splat(p.lambda_mm_s), V::splat(p.epsilon));
        let mut active = solved;
        for _ in 0..p.max_iterations {
            if active == 0 {
                break;
            }
            // The weights 1/(|r| + λ), r = (2·V_θ − Vz·c − Vx·s)·10³ in mm/s (0 where a lane has
            // no projection), and their sum in the angles' order.
            let mut total = V::splat(-0.0);
            for ((((next, lateral), &c), v), &present) in (self.new_w.iter_mut())
                .zip(&self.lateral)
                .zip(&self.axial)
                .zip(&self.v_theta)
                .zip(&self.present)
            {
                let fitted = two.mul(V::load(v)).sub(vz.mul(V::splat(c)));
                let residual_mm_s = fitted.sub(vx.mul(V::load(lateral))).mul(thousand);
                let weight = one
                    .div(residual_mm_s.abs().add(lambda))
                    .zero_unless(present);
                weight.store(next);
                total = total.add(weight);
            }
            // Normalised, and the largest change of a weight (a NaN change ignored, as f64::max
            // ignores it).
            let mut change = V::splat(0.0);
            for (next, w) in self.new_w.iter_mut().zip(&self.w) {
                let normalised = V::load(next).div(total);
                normalised.store(next);
                change = change.max_of(normalised.sub(V::load(w)).abs());
            }
            std::mem::swap(&mut self.w, &mut self.new_w);
            let (x, z, solved) = self.weighted_solve_in::<V>();
            let moved = active & solved;
            vx = V::select(moved, x, vx);
            vz = V::select(moved, z, vz);
            let converged = change.less_than(epsilon);
            active = moved & !converged;
        }
        (vx.lanes(), vz.lanes())
    }

    /// [`weighted_solve`](super::weighted_solve) of every lane with the weights `self.w`, in the
    /// registers of `V`: (Vx, Vz) and the lanes whose system could be solved.
    #[inline(always)]
    fn weighted_solve_in<V: EightLanes>(&self) -> (V, V, u8) {
        let zero = V::splat(0.0);
        let two = V::splat(2.0);
        let (mut a11, mut a12, mut a22, mut b1, mut b2) = (zero, zero, zero, zero, zero);
        for (((s, &c), v), w) in (self.lateral.iter())
            .zip(&self.axial)
            .zip(&self.v_theta)
            .zip(&self.w)
        {
            let (s, c, v, w) = (V::load(s), V::splat(c), V::load(v), V::load(w));
            // w·s·s, w·s·c, w·c·c, w·s·2·v, w·c·2·v, each multiplied from the left.
            let (ws, wc) = (w.mul(s), w.mul(c));
            a11 = a11.add(ws.mul(s));
            a12 = a12.add(ws.mul(c));
            a22 = a22.add(wc.mul(c));
            b1 = b1.add(ws.mul(two).mul(v));
            b2 = b2.add(wc.mul(two).mul(v));
        }
        let det = a11.mul(a22).sub(a12.mul(a12));
        let floor = V::splat(1e-12).mul(a11.mul(a22).abs().at_least(f64::MIN_POSITIVE));
        let singular = det.abs().at_most(floor);
        let vx = a22.mul(b1).sub(a12.mul(b2)).div(det);
        let vz = a11.mul(b2).sub(a12.mul(b1)).div(det);
        (vx, vz, !singular)
    }
}

/// Eight f64 lanes in registers and the operations [`PixelLanes`] solves with: each lane's result
/// is the one IEEE operation f64 does (no fused multiply-adds), so every path gives the same bits.
/// Masks are a bit per lane (bit l: lane l).
trait EightLanes: Copy {
    /// Every lane `v`.
    fn splat(v: f64) -> Self;
    /// The lanes of `a`.
    fn load(a: &Lanes) -> Self;
    /// Writes the lanes to `to`.
    fn store(self, to: &mut Lanes);
    /// The lanes, as an array.
    fn lanes(self) -> Lanes {
        let mut out = [0.0; LANES];
        self.store(&mut out);
        out
    }
    /// self + o.
    fn add(self, o: Self) -> Self;
    /// self − o.
    fn sub(self, o: Self) -> Self;
    /// self · o.
    fn mul(self, o: Self) -> Self;
    /// self / o.
    fn div(self, o: Self) -> Self;
    /// |self|.
    fn abs(self) -> Self;
    /// f64::max(self, o) where self is not NaN: self where o is NaN.
    fn max_of(self, o: Self) -> Self;
    /// f64::max(self, floor) for a floor that is not NaN: floor where self is NaN.
    fn at_least(self, floor: f64) -> Self;
    /// The lanes where self < o (false where either is NaN).
    fn less_than(self, o: Self) -> u8;
    /// The lanes where self ≤ o (false where either is NaN).
    fn at_most(self, o: Self) -> u8;
    /// `if_set`'s lanes where `mask` has them, `if_clear`'s elsewhere.
    fn select(mask: u8, if_set: Self, if_clear: Self) -> Self;
    /// These lanes where `mask` has them, +0 elsewhere.
    fn zero_unless(self, mask: u8) -> Self;
}

/// The portable path: each lane one f64 operation after another.
impl EightLanes for Lanes {
    #[inline(always)]
    fn splat(v: f64) -> Self {
        [v; LANES]
    }
    #[inline(always)]
    fn load(a: &Lanes) -> Self {
        *a
    }
    #[inline(always)]
    fn store(self, to: &mut Lanes) {
        *to = self;
    }
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        std::array::from_fn(|l| self[l] + o[l])
    }
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        std::array::from_fn(|l| self[l] - o[l])
    }
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        std::array::from_fn(|l| self[l] * o[l])
    }
    #[inline(always)]
    fn div(self, o: Self) -> Self {
        std::array::from_fn(|l| self[l] / o[l])
    }
    #[inline(always)]
    fn abs(self) -> Self {
        self.map(f64::abs)
    }
    #[inline(always)]
    fn max_of(self, o: Self) -> Self {
        std::array::from_fn(|l| self[l].max(o[l]))
    }
    #[inline(always)]
    fn at_least(self, floor: f64) -> Self {
        self.map(|v| v.max(floor))
    }
    #[inline(always)]
    fn less_than(self, o: Self) -> u8 {
        (0..LANES).fold(0, |m, l| m | (u8::from(self[l] < o[l]) << l))
    }
    #[inline(always)]
    fn at_most(self, o: Self) -> u8 {
        (0..LANES).fold(0, |m, l| m | (u8::from(self[l] <= o[l]) << l))
    }
    #[inline(always)]
    fn select(mask: u8, if_set: Self, if_clear: Self) -> Self {
        std::array::from_fn(|l| {
            if mask >> l & 1 == 1 {
                if_set[l]
            } else {
                if_clear[l]
            }
        })
    }
    #[inline(always)]
    fn zero_unless(self, mask: u8) -> Self {
        Self::select(mask, self, [0.0; LANES])
    }
}

/// The vector-register path. Its operations are inlined into [`PixelLanes::solve_avx2`], which
/// runs only where `solve` detected AVX2: that is what makes each `unsafe` intrinsic call below
/// sound.
#[cfg(target_arch = "x86_64")]
mod simd {
    use super::{EightLanes, LANES, Lanes};
    use std::arch::x86_64::*;

    /// Eight lanes in two AVX2 registers (lanes 0–3, 4–7).
    #[derive(Clone, Copy)]
    pub(super) struct Avx2Pair([__m256d; 2]);

    impl Avx2Pair {
        /// `f` on each register.
        #[inline(always)]
        fn each(self, f: impl Fn(__m256d) -> __m256d) -> Self {
            Avx2Pair([f(self.0[0]), f(self.0[1])])
        }
        /// `f` on each pair of registers.
        #[inline(always)]
        fn with(self, o: Self, f: impl Fn(__m256d, __m256d) -> __m256d) -> Self {
            Avx2Pair([f(self.0[0], o.0[0]), f(self.0[1], o.0[1])])
        }
        /// A lane mask as bit l of `mask` for lane l, from both registers' comparisons.
        #[inline(always)]
        fn bits(low: __m256d, high: __m256d) -> u8 {
            unsafe { (_mm256_movemask_pd(low) | _mm256_movemask_pd(high) << 4) as u8 }
        }
        /// Each register's lanes all ones where `mask` has them, zeros elsewhere.
        #[inline(always)]
        fn lane_masks(mask: u8) -> [__m256d; 2] {
            let lane = |l: usize| if mask >> l & 1 == 1 { -1i64 } else { 0 };
            unsafe {
                [
                    _mm256_castsi256_pd(_mm256_setr_epi64x(lane(0), lane(1), lane(2), lane(3))),
                    _mm256_castsi256_pd(_mm256_setr_epi64x(lane(4), lane(5), lane(6), lane(7))),
                ]
            }
        }
    }

    // SAFETY (every block below): reached only from code compiled for AVX2 after detection.
    impl EightLanes for Avx2Pair {
        #[inline(always)]
        fn splat(v: f64) -> Self {
            let v = unsafe { _mm256_set1_pd(v) };
            Avx2Pair([v, v])
        }
        #[inline(always)]
        fn load(a: &Lanes) -> Self {
            const HALF: usize = LANES / 2;
            unsafe {
                Avx2Pair([
                    _mm256_loadu_pd(a.as_ptr()),
                    _mm256_loadu_pd(a.as_ptr().add(HALF)),
                ])
            }
        }
        #[inline(always)]
        fn store(self, to: &mut Lanes) {
            const HALF: usize = LANES / 2;
            unsafe {
                _mm256_storeu_pd(to.as_mut_ptr(), self.0[0]);
                _mm256_storeu_pd(to.as_mut_ptr().add(HALF), self.0[1]);
            }
        }
        #[inline(always)]
        fn add(self, o: Self) -> Self {
            self.with(o, |a, b| unsafe { _mm256_add_pd(a, b) })
        }
        #[inline(always)]
        fn sub(self, o: Self) -> Self {
            self.with(o, |a, b| unsafe { _mm256_sub_pd(a, b) })
        }
        #[inline(always)]
        fn mul(self, o: Self) -> Self {
            self.with(o, |a, b| unsafe { _mm256_mul_pd(a, b) })
        }
        #[inline(always)]
        fn div(self, o: Self) -> Self {
            self.with(o, |a, b| unsafe { _mm256_div_pd(a, b) })
        }
        #[inline(always)]
        fn abs(self) -> Self {
            self.each(|a| unsafe { _mm256_andnot_pd(_mm256_set1_pd(-0.0), a) })
        }
        // max_pd returns its second operand where either is NaN.
        #[inline(always)]
        fn max_of(self, o: Self) -> Self {
            o.with(self, |a, b| unsafe { _mm256_max_pd(a, b) })
        }
        #[inline(always)]
        fn at_least(self, floor: f64) -> Self {
            self.each(|a| unsafe { _mm256_max_pd(a, _mm256_set1_pd(floor)) })
        }
        #[inline(always)]
        fn less_than(self, o: Self) -> u8 {
            let lt = |a, b| unsafe { _mm256_cmp_pd::<_CMP_LT_OQ>(a, b) };
            Self::bits(lt(self.0[0], o.0[0]), lt(self.0[1], o.0[1]))
        }
        #[inline(always)]
        fn at_most(self, o: Self) -> u8 {
            let le = |a, b| unsafe { _mm256_cmp_pd::<_CMP_LE_OQ>(a, b) };
            Self::bits(le(self.0[0], o.0[0]), le(self.0[1], o.0[1]))
        }
        #[inline(always)]
        fn select(mask: u8, if_set: Self, if_clear: Self) -> Self {
            let m = Self::lane_masks(mask);
            unsafe {
                Avx2Pair([
                    _mm256_blendv_pd(if_clear.0[0], if_set.0[0], m[0]),
                    _mm256_blendv_pd(if_clear.0[1], if_set.0[1], m[1]),
                ])
            }
        }
        #[inline(always)]
        fn zero_unless(self, mask: u8) -> Self {
            let m = Self::lane_masks(mask);
            unsafe {
                Avx2Pair([
                    _mm256_and_pd(self.0[0], m[0]),
                    _mm256_and_pd(self.0[1], m[1]),
                ])
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::paper_angles;
    use super::super::{IrlsParams, projection_weights, solve_rows};
    use super::*;

    /// Every path of [`PixelLanes::solve`] the CPU can run (portable, AVX2) gives each
    /// lane [`solve_rows`]'s vector to the bit: lanes missing projections, a lane with one
    /// projection and a singular lane (both NaN) among them.
    #[test]
    fn every_lane_path_solves_as_solve_rows() {
        let angles = paper_angles();
        let nominal: Vec<(f64, f64)> = angles.iter().map(|&a| projection_weights(a)).collect();
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        let mut uniform = move || rng.random_range(0.0..1.0);
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
                let mut paths = vec![("portable", lanes.solve_in::<Lanes>(&est))];
                #[cfg(target_arch = "x86_64")]
                {
                    if is_x86_feature_detected!("avx2") {
                        // SAFETY: AVX2 was detected.
                        paths.push(("AVX2", unsafe { lanes.solve_avx2(&est) }));
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
