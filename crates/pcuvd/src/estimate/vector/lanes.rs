//! Pixels solved side by side: [`solve_rows`](super::solve_rows) for [`LANES`] pixels at once, a
//! pixel per lane of a vector register, each lane to the bit what the pixel gives alone, and
//! taking the next pixel as soon as its own is done.

use super::Estimator;

/// Pixels [`field`](super::field) solves side by side, one per lane of a vector register.
const LANES: usize = 8;

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

    /// Lane `l`'s starting weights, 1/n over its n projections (0 where it has none), and
    /// whether it has at least two (with fewer it has no vector).
    fn start(&mut self, l: usize) -> bool {
        let count = (self.present.iter())
            .filter(|&&present| present >> l & 1 == 1)
            .count();
        for (w, &present) in self.w.iter_mut().zip(&self.present) {
            w[l] = if present >> l & 1 == 1 {
                1.0 / count as f64
            } else {
                0.0
            };
        }
        count >= 2
    }

    /// Solves pixels `0..count` each as [`solve_rows`](super::solve_rows) solves it alone:
    /// `load(i, l, lanes)` sets pixel i's problem into lane l ([`PixelLanes::set`]) and
    /// `done(i, vx, vz)` takes its vector (m/s). A lane takes the next pixel as soon as its own
    /// pixel is done, so that lanes whose IRLS rounds stop early do not wait, idle, on the
    /// slowest pixel of a group. In pairs of AVX2 registers where the CPU has them. (No
    /// AVX-512 path: the divisions bound the solve, and one AVX-512 register per operation was
    /// no faster than two AVX2 ones; the speed page has the numbers.)
    pub(super) fn solve_each(
        &mut self,
        estimator: &Estimator,
        count: usize,
        load: &mut dyn FnMut(usize, usize, &mut PixelLanes),
        done: &mut dyn FnMut(usize, f64, f64),
    ) {
        #[cfg(target_arch = "x86_64")]
        if crate::core::simd::avx2() {
            // SAFETY: AVX2 was detected.
            return unsafe { self.solve_each_avx2(estimator, count, load, done) };
        }
        self.solve_each_in::<Lanes>(estimator, count, load, done)
    }

    /// [`PixelLanes::solve_each_in`] in pairs of AVX2 registers.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn solve_each_avx2(
        &mut self,
        estimator: &Estimator,
        count: usize,
        load: &mut dyn FnMut(usize, usize, &mut PixelLanes),
        done: &mut dyn FnMut(usize, f64, f64),
    ) {
        self.solve_each_in::<simd::Avx2Pair>(estimator, count, load, done)
    }

    /// [`PixelLanes::solve_each`] in the registers of `V`. Each step solves every lane once: a
    /// lane that has just taken a pixel solves it with its starting weights (the least-squares
    /// start), a lane in IRLS rounds first reweighs from its last vector; each lane does the
    /// operations of [`solve_rows`](super::solve_rows) in their order, whatever the others do.
    #[inline(always)]
    fn solve_each_in<V: EightLanes>(
        &mut self,
        estimator: &Estimator,
        count: usize,
        load: &mut dyn FnMut(usize, usize, &mut PixelLanes),
        done: &mut dyn FnMut(usize, f64, f64),
    ) {
        let irls = match estimator {
            Estimator::Irls(p) => Some(*p),
            Estimator::LeastSquares => None,
        };
        let max_rounds = irls.map_or(0, |p| p.max_iterations);
        let (two, thousand, one) = (V::splat(2.0), V::splat(1e3), V::splat(1.0));
        let (lambda, epsilon) = irls.map_or((one, one), |p| {
            (V::splat(p.lambda_mm_s), V::splat(p.epsilon))
        });
        let nan = V::splat(f64::NAN);
        let (mut vx, mut vz) = (nan, nan);
        // Per lane: its pixel, and the IRLS rounds it has done.
        let mut pixel: [Option<usize>; LANES] = [None; LANES];
        let mut rounds = [0usize; LANES];
        // Lanes whose pixel waits for its first solve, lanes in IRLS rounds, and lanes whose
        // pixel has at least two projections.
        let (mut fresh, mut iterating, mut solvable) = (0u8, 0u8, 0u8);
        let mut next = 0;
        loop {
            for (l, lane_pixel) in pixel.iter_mut().enumerate() {
                if lane_pixel.is_none() && next < count {
                    load(next, l, self);
                    *lane_pixel = Some(next);
                    next += 1;
                    let bit = 1 << l;
                    solvable = (solvable & !bit) | if self.start(l) { bit } else { 0 };
                    fresh |= bit;
                }
            }
            if fresh | iterating == 0 {
                break;
            }
            // The iterating lanes' weights 1/(|r| + λ), r = (2·V_θ − Vz·c − Vx·s)·10³ in mm/s
            // (0 where a lane has no projection), normalised by their sum in the angles' order,
            // and the largest change of a weight (a NaN change ignored, as f64::max ignores it);
            // the fresh lanes keep their starting weights.
            let mut change = V::splat(0.0);
            if iterating != 0 {
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
                for (next, w) in self.new_w.iter().zip(self.w.iter_mut()) {
                    let (normalised, old) = (V::load(next).div(total), V::load(w));
                    change = change.max_of(normalised.sub(old).abs());
                    V::select(iterating, normalised, old).store(w);
                }
            }
            let (x, z, solved) = self.weighted_solve_in::<V>();
            // A fresh lane whose first solve fails, or that has fewer than two projections, has
            // no vector; an iterating lane keeps its last vector where a round's solve fails.
            let started = solved & solvable & fresh;
            let moved = solved & iterating;
            vx = V::select(moved, x, V::select(fresh, V::select(started, x, nan), vx));
            vz = V::select(moved, z, V::select(fresh, V::select(started, z, nan), vz));
            let going_on = moved & !change.less_than(epsilon);
            let mut finished = 0u8;
            for (l, rounds) in rounds.iter_mut().enumerate() {
                let bit = 1 << l;
                if iterating & bit != 0 {
                    *rounds += 1;
                    if going_on & bit == 0 || *rounds == max_rounds {
                        finished |= bit;
                    }
                } else if fresh & bit != 0 {
                    *rounds = 0;
                    if started & bit == 0 || max_rounds == 0 {
                        finished |= bit;
                    }
                }
            }
            iterating = (iterating | fresh) & !finished;
            fresh = 0;
            if finished != 0 {
                let (x, z) = (vx.lanes(), vz.lanes());
                for (l, lane_pixel) in pixel.iter_mut().enumerate() {
                    if finished >> l & 1 == 1
                        && let Some(i) = lane_pixel.take()
                    {
                        done(i, x[l], z[l]);
                    }
                }
            }
        }
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

/// The vector-register path. Its operations are inlined into [`PixelLanes::solve_each_avx2`],
/// which runs only where `solve_each` detected AVX2: that is what makes each `unsafe` intrinsic call below
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

    /// Every path of [`PixelLanes::solve_each`] the CPU can run (portable, AVX2) gives each
    /// pixel [`solve_rows`]'s vector to the bit, lanes taking new pixels as theirs finish:
    /// pixels missing projections, one with a single projection and singular ones (both NaN)
    /// among them, with least squares, IRLS to convergence and IRLS cut short.
    #[test]
    fn every_lane_path_solves_as_solve_rows() {
        let angles = paper_angles();
        let nominal: Vec<(f64, f64)> = angles.iter().map(|&a| projection_weights(a)).collect();
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        let mut uniform = move || rng.random_range(0.0..1.0);
        let mut problems: Vec<Vec<(f64, f64)>> = Vec::new();
        for i in 0..163 {
            let (group, l) = (i / LANES, i % LANES);
            let (vx, vz) = (0.04 * uniform() - 0.02, 0.04 * uniform() - 0.02);
            let singular = group % 5 == 0 && l == 3;
            // Some pixels miss two projections, one all but one.
            let missing = |k: usize| {
                (group % 3 == 1 && (k == l || k == (l + 3) % 8))
                    || (group % 7 == 2 && l == 5 && k != 4)
            };
            // Noise from none to a lot, so that IRLS takes from a few rounds to all of them.
            let noise = 0.012 * (i % 4) as f64;
            let problem: Vec<(f64, f64)> = (nominal.iter().enumerate())
                .map(|(k, &(s, c))| {
                    let s = if singular {
                        0.0
                    } else {
                        s * (0.8 + 0.4 * uniform())
                    };
                    let p = 0.5 * (vx * s + vz * c) + noise * (uniform() - 0.5);
                    (s, if missing(k) { f64::NAN } else { p })
                })
                .collect();
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
            let solved = |path: &str| {
                let mut lanes = PixelLanes::new(&nominal);
                let mut out = vec![(f64::NAN, 0.0); problems.len()];
                let mut rounds_done = vec![0; problems.len()];
                let load = &mut |i: usize, l: usize, lanes: &mut PixelLanes| {
                    lanes.set(l, problems[i].iter().copied())
                };
                let done = &mut |i: usize, x: f64, z: f64| {
                    out[i] = (x, z);
                    rounds_done[i] += 1;
                };
                match path {
                    "portable" => lanes.solve_each_in::<Lanes>(&est, problems.len(), load, done),
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: called only where AVX2 was detected (below).
                    "AVX2" => unsafe { lanes.solve_each_avx2(&est, problems.len(), load, done) },
                    _ => unreachable!(),
                }
                assert!(
                    rounds_done.iter().all(|&n| n == 1),
                    "{path}: each pixel done once"
                );
                out
            };
            #[cfg_attr(not(target_arch = "x86_64"), allow(unused_mut))]
            let mut paths = vec!["portable"];
            #[cfg(target_arch = "x86_64")]
            {
                if is_x86_feature_detected!("avx2") {
                    paths.push("AVX2");
                }
            }
            for path in paths {
                for (i, ((x, z), problem)) in solved(path).into_iter().zip(&problems).enumerate() {
                    let rows: Vec<(f64, f64)> = problem
                        .iter()
                        .zip(&nominal)
                        .map(|(&(s, _), &(_, c))| (s, c))
                        .collect();
                    let v: Vec<f64> = problem.iter().map(|&(_, v)| v).collect();
                    let want = solve_rows(&rows, &v, &est);
                    assert!(
                        want.0.to_bits() == x.to_bits() && want.1.to_bits() == z.to_bits(),
                        "{path}, {est:?}, pixel {i}: {:?} against {want:?}",
                        (x, z)
                    );
                }
            }
        }
    }
}
