//! Each pixel's alias patterns: enumerated from trial vectors, fitted, scored, grouped by level.
//!
//! # Candidates, per pixel ([`pixel_candidates`])
//! Patterns are enumerated from trial vectors rather than over all (2K + 1)^n combinations (for a
//! given vector the counts of neighbouring angles differ by at most one, so few combinations are
//! physical): every node t of a square grid of spacing min v_N over the disc |t| ≤ (2K + 1)·v_N +
//! spacing gives the pattern k_i(t) = round((a_i·t/2 − p_i)/(2 v_N)). The true vector lies within
//! 0.71·v_N of a node, and since |a_i|/2 ≤ 1 every node within v_N of it unwraps every angle
//! rightly: the true pattern is among the candidates while each projection's error stays below
//! 0.29·v_N. Patterns with an |k_i| > K, and fits faster than 1.1·(2K + 1)·v_N, are outside the
//! limit and dropped: K intervals reach speeds up to (2K + 1)·v_N.
//!
//! # Score
//! Each candidate is fitted with the estimator and scored by the objective that estimator
//! minimises, over all the pixel's reached angles, unweighted: the sum of squared residuals for
//! least squares (UVD), the sum of absolute residuals for IRLS (PC-UVD: weights 1/|r| make IRLS a
//! least-absolute-deviations fit). Every candidate fits the same two unknowns to the same angles, so
//! the scores compare directly. IRLS's own weighted residual would not: its weights are n more
//! free parameters with which any pattern explains away the angles that disagree with it (a wrong
//! alias count becomes "an outlier" of weight ≈ 0), so a wrong pattern would win by overfitting; the
//! unweighted objective charges it the full 2·v_N at each angle it gets wrong.
//!
//! # The common shift, which one pixel hardly settles
//! Adding the same count c to every angle moves every unwrapped projection by 2c·v_N. With transmit
//! angles within ±15° and straight receive every projection is nearly axial (1 + cos θ spans only
//! 1.966–2), so with one v_N for all angles the shift is almost exactly a change of Vz by
//! ≈ 2c·v_N, whose residual is only the 1.7 % spread of 1 + cos θ (0.5 mm/s per angle at the
//! paper's settings). With Loupas each angle unwraps by its own 2·v_N, from its own mean frequency,
//! and those differ by about 2 % between the angles at a pixel: a wrong level leaves about 2 mm/s
//! per angle, where the estimator scatters by about 0.5 mm/s without noise. Measured on the tube
//! with the truth's patterns, the true level has the smallest residual at only 80–94 % of the
//! lumen's pixels: one pixel's residual settles which angles are wrapped relative to the others
//! far better than how many times all of them are. The candidates are therefore grouped by level
//! ℓ = round(mean k) (a common shift moves the level by c), the best of each level is kept, and
//! the level is chosen over space.
//!
//! Within a level, a mixed pattern (some angles shifted more than others, as where a pixel's
//! projections straddle a wrap) is kept only where its summed squared residual is below
//! [`MIXED_PATTERN_RATIO`] times the level's common shift's; otherwise the common shift is. A truly
//! wrapped angle leaves about 2·v_N at the common shift (89 mm/s at the paper's settings; with
//! per-angle errors of 0.5–5 mm/s the ratio is about 3·10⁻⁴–3·10⁻²), but spare counts also fit
//! noise a little better than none: without the rule the haze a flow mask lets in around a vessel
//! took mixed patterns and read as flow of several v_N (a simulated tube at 25 mm/s, 100 frames,
//! `--dealias auto`: 125 of its 1,696 flow pixels, all outside the lumen, went from a median of
//! 41 to 187 mm/s; with it, 10 pixels, and the lumen of a tube at 2.5× v_N, 20 frames, is read
//! exactly as before).
//!
//! The common shift is that yardstick even when its own fit lies beyond the speed limit, and a
//! pixel without a candidate at level 0 (no pattern within the limit explains its projections
//! better than their plain fit) has none at all and keeps the plain fit, unless a candidate at
//! another level fits with under [`MIXED_PATTERN_RATIO`] times the plain fit's squared residual
//! (fast flow whose wrapped projections, through angles a few degrees apart and v_N a few % apart,
//! also fit far off sideways). Projections that no
//! vector explains (haze at a vessel's end whose angles disagree in sign) have a plain fit far
//! faster than any flow, and no pattern that fits them worse than none is kept.
//!

use super::*;

/// One alias pattern of a pixel, fitted and scored.
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    /// Alias count k_i of each angle (0 for angles that do not reach the pixel): the unwrapped
    /// projection is V_θi + 2·k_i·v_N.
    pub alias_counts: Vec<i8>,
    /// Lateral velocity of the fit (m/s).
    pub vx: f64,
    /// Axial velocity of the fit (m/s).
    pub vz: f64,
    /// The estimator's objective over the reached angles, residuals r_i = 2·u_i − a_i·v in m/s:
    /// Σ r_i² (m²/s²) for least squares, Σ |r_i| (m/s) for IRLS.
    pub score: f64,
    /// round(mean of the alias counts over the reached angles): a common shift of every count by
    /// c moves it by c.
    pub level: i32,
}

/// The square grid of trial vectors (m/s) of K intervals for per-angle Nyquist velocities
/// between `slowest` and `fastest` (m/s): spacing `slowest`, over the disc of radius
/// (2K + 1)·`fastest` + `slowest`.
pub(super) fn trial_vectors(intervals: u32, slowest: f64, fastest: f64) -> Vec<(f64, f64)> {
    let radius = (2 * intervals + 1) as f64 * fastest + slowest;
    let m = (radius / slowest).ceil() as i64;
    let mut trials = Vec::new();
    for iz in -m..=m {
        for ix in -m..=m {
            let t = (ix as f64 * slowest, iz as f64 * slowest);
            if t.0.hypot(t.1) <= radius * (1.0 + 1e-9) {
                trials.push(t);
            }
        }
    }
    trials
}

/// The reached angles of a pixel and the least-squares operator of their projection model.
pub(super) struct PixelModel {
    /// Indices of the reached (finite) angles.
    pub(super) index: Vec<usize>,
    /// (sin θ, 1 + cos θ) of each reached angle.
    pub(super) weights: Vec<(f64, f64)>,
    /// The measured projections of the reached angles (m/s).
    pub(super) p: Vec<f64>,
    /// The alias period 2·v_N of each reached angle (m/s).
    pub(super) period: Vec<f64>,
    /// Rows of M = 2·(AᵀA)⁻¹Aᵀ, so that the LS vector of projections u is (m_x·u, m_z·u).
    pub(super) m_x: Vec<f64>,
    pub(super) m_z: Vec<f64>,
}

impl PixelModel {
    /// `None` when fewer than [`MIN_DISTINCT_ANGLES`] distinct angles reach the pixel: a common
    /// shift of the alias counts is then a vector like any other (with 2 angles every pattern
    /// fits exactly).
    pub(super) fn new(angles: &[f64], v_theta: &[f64], nyquist: &[f64]) -> Option<Self> {
        let index: Vec<usize> = (0..angles.len())
            .filter(|&i| v_theta[i].is_finite())
            .collect();
        let reached: Vec<f64> = index.iter().map(|&i| angles[i]).collect();
        if distinct_angles(&reached) < MIN_DISTINCT_ANGLES {
            return None;
        }
        let weights: Vec<(f64, f64)> = index
            .iter()
            .map(|&i| projection_weights(angles[i]))
            .collect();
        let (mut a11, mut a12, mut a22) = (0.0, 0.0, 0.0);
        for &(s, c) in &weights {
            a11 += s * s;
            a12 += s * c;
            a22 += c * c;
        }
        let det = a11 * a22 - a12 * a12;
        if det.abs() <= 1e-12 * (a11 * a22).abs() {
            return None;
        }
        let m_x = weights
            .iter()
            .map(|&(s, c)| 2.0 * (a22 * s - a12 * c) / det)
            .collect();
        let m_z = weights
            .iter()
            .map(|&(s, c)| 2.0 * (a11 * c - a12 * s) / det)
            .collect();
        let p = index.iter().map(|&i| v_theta[i]).collect();
        let period = index.iter().map(|&i| 2.0 * nyquist[i]).collect();
        Some(PixelModel {
            index,
            weights,
            p,
            period,
            m_x,
            m_z,
        })
    }

    pub(super) fn ls(&self, u: &[f64]) -> (f64, f64) {
        let dot = |m: &[f64]| m.iter().zip(u).map(|(a, b)| a * b).sum::<f64>();
        (dot(&self.m_x), dot(&self.m_z))
    }

    pub(super) fn residuals<'a>(
        &'a self,
        u: &'a [f64],
        v: (f64, f64),
    ) -> impl Iterator<Item = f64> + 'a {
        self.weights
            .iter()
            .zip(u)
            .map(move |(&(s, c), &ui)| 2.0 * ui - v.0 * s - v.1 * c)
    }
}

/// Packs a pattern of alias counts (|k| ≤ 127) into one key; `None` beyond 16 angles.
pub(super) fn pattern_key(k: &[i8]) -> Option<u128> {
    (k.len() <= 16).then(|| {
        k.iter()
            .fold(0u128, |key, &ki| (key << 8) | u128::from(ki as u8))
    })
}

/// The best candidate of every level of one pixel, sorted by level: projections `v_theta` (m/s;
/// NaN for an angle that does not reach the pixel) at `angles` (rad), projection Nyquist velocity
/// `nyquist` of each angle (m/s; c·f_frame/(4 f) for the frequency f that turned its phase into
/// a velocity), alias counts up to ±`intervals`, fitted and scored with `estimator` (see the module
/// docs). Empty when fewer than 3 distinct angles reach the pixel; an error when the three slices
/// differ in length.
pub fn pixel_candidates(
    angles: &[f64],
    v_theta: &[f64],
    nyquist: &[f64],
    intervals: u32,
    estimator: &Estimator,
) -> Result<Vec<Candidate>> {
    if v_theta.len() != angles.len() || nyquist.len() != angles.len() {
        return Err(Error::Shape(format!(
            "{} projections and {} Nyquist velocities for {} angles",
            v_theta.len(),
            nyquist.len(),
            angles.len()
        )));
    }
    Ok(candidates_of(
        angles, v_theta, nyquist, intervals, estimator,
    ))
}

/// [`pixel_candidates`] of slices of one length.
pub(super) fn candidates_of(
    angles: &[f64],
    v_theta: &[f64],
    nyquist: &[f64],
    intervals: u32,
    estimator: &Estimator,
) -> Vec<Candidate> {
    let Some(model) = PixelModel::new(angles, v_theta, nyquist) else {
        return vec![];
    };
    let n = model.index.len();
    let slowest = 0.5 * model.period.iter().copied().fold(f64::INFINITY, f64::min);
    let fastest = 0.5 * model.period.iter().copied().fold(0.0, f64::max);
    if !(slowest.is_finite() && slowest > 0.0) {
        return vec![];
    }
    let trials = trial_vectors(intervals, slowest, fastest);
    let k_max = intervals as i64;
    // Every trial vector's pattern, deduplicated.
    let mut patterns: Vec<Vec<i8>> = Vec::new();
    let mut keys: Vec<u128> = Vec::new();
    let mut k = vec![0i8; n];
    'trials: for &(tx, tz) in &trials {
        for (j, ((&(s, c), &p), &period)) in model
            .weights
            .iter()
            .zip(&model.p)
            .zip(&model.period)
            .enumerate()
        {
            let count = ((0.5 * (tx * s + tz * c) - p) / period).round() as i64;
            if count.abs() > k_max {
                continue 'trials;
            }
            k[j] = count as i8;
        }
        match pattern_key(&k) {
            Some(key) => keys.push(key),
            None => patterns.push(k.clone()),
        }
    }
    if n <= 16 {
        keys.sort_unstable();
        keys.dedup();
        patterns = keys
            .iter()
            .map(|&key| {
                (0..n)
                    .map(|j| (key >> (8 * (n - 1 - j)) & 0xff) as u8 as i8)
                    .collect()
            })
            .collect();
    } else {
        patterns.sort_unstable();
        patterns.dedup();
    }
    // Least squares for every pattern; the best of each level is kept.
    let limit = SPEED_MARGIN * (2 * intervals + 1) as f64 * fastest;
    let levels = 2 * intervals as usize + 1;
    let mut best: Vec<Option<(f64, usize)>> = vec![None; levels];
    let mut u = vec![0.0; n];
    for (index, pattern) in patterns.iter().enumerate() {
        for j in 0..n {
            u[j] = model.p[j] + model.period[j] * f64::from(pattern[j]);
        }
        let v = model.ls(&u);
        if v.0.hypot(v.1) > limit {
            continue;
        }
        let ssr: f64 = model.residuals(&u, v).map(|r| r * r).sum();
        let level = level_of(pattern);
        let slot = &mut best[(level + intervals as i32) as usize];
        if slot.is_none_or(|(s, _)| ssr < s) {
            *slot = Some((ssr, index));
        }
    }
    // A level's mixed pattern must explain the data far better than the level's common shift:
    // a truly wrapped angle leaves 2·v_N at the common shift, noise only what spare counts fit.
    // The common shift's fit is the yardstick even beyond the speed limit: projections that fit
    // no vector (haze at a vessel's end) have a plain fit far faster than any flow, and without
    // the test a mixed pattern that fits them worse than none was kept, as fast flow.
    for (slot, level) in best.iter_mut().zip(-(intervals as i32)..) {
        let Some((ssr, index)) = *slot else { continue };
        let uniform = vec![level as i8; n];
        if patterns[index] == uniform {
            continue;
        }
        for ((uj, &p), &period) in u.iter_mut().zip(&model.p).zip(&model.period) {
            *uj = p + period * f64::from(level);
        }
        let v = model.ls(&u);
        let uniform_ssr: f64 = model.residuals(&u, v).map(|r| r * r).sum();
        if ssr >= MIXED_PATTERN_RATIO * uniform_ssr {
            *slot = (v.0.hypot(v.1) <= limit).then(|| {
                patterns.push(uniform);
                (uniform_ssr, patterns.len() - 1)
            });
        }
    }
    // Projections that no vector within the limit explains better than their plain fit does are
    // not flow that dealiasing can mend: without a level-0 candidate, and without one at another
    // level that explains them far better than the plain fit (by the mixed-pattern ratio), the
    // pixel has none at all, rather than ones at other levels that the spatial settling would
    // then prefer. The second condition keeps fast flow whose wrapped projections have a plain fit
    // beyond the limit: with angles a few degrees apart, the v_N of each angle 5 % apart shifts
    // the wrapped projections enough to put that fit far off sideways.
    if best[intervals as usize].is_none() {
        u.copy_from_slice(&model.p);
        let v = model.ls(&u);
        let plain_ssr: f64 = model.residuals(&u, v).map(|r| r * r).sum();
        let explained = best
            .iter()
            .flatten()
            .any(|&(ssr, _)| ssr < MIXED_PATTERN_RATIO * plain_ssr);
        if !explained {
            return vec![];
        }
    }
    let reached_angles: Vec<f64> = model.index.iter().map(|&i| angles[i]).collect();
    best.iter()
        .flatten()
        .map(|&(_, index)| {
            let pattern = &patterns[index];
            for j in 0..n {
                u[j] = model.p[j] + model.period[j] * f64::from(pattern[j]);
            }
            // The final fit is the estimator's own (for an all-zero pattern: the plain fit, to
            // the last bit); the precomputed LS operator only ranked the patterns.
            let v = vector::solve_pixel(&reached_angles, &u, estimator);
            let score = match estimator {
                Estimator::LeastSquares => model.residuals(&u, v).map(|r| r * r).sum(),
                Estimator::Irls(_) => model.residuals(&u, v).map(f64::abs).sum(),
            };
            let mut alias_counts = vec![0i8; angles.len()];
            for (j, &i) in model.index.iter().enumerate() {
                alias_counts[i] = pattern[j];
            }
            Candidate {
                alias_counts,
                vx: v.0,
                vz: v.1,
                score,
                level: level_of(pattern),
            }
        })
        .collect()
}

/// round(mean k) of a pattern, halves rounded up, so that adding c to every count adds c.
pub(super) fn level_of(pattern: &[i8]) -> i32 {
    let sum: i32 = pattern.iter().map(|&k| i32::from(k)).sum();
    let n = pattern.len() as i32;
    (2 * sum + n).div_euclid(2 * n)
}

/// One pixel dealiased on its own: the candidate of smallest score ([`pixel_candidates`]), or
/// `None` when fewer than 3 distinct angles reach it. Exact on noiseless projections of any vector
/// within the limit; on measured data prefer [`dealiased_vectors`], which settles the common shift
/// over space (see the module docs).
pub fn solve_pixel_dealiased(
    angles: &[f64],
    v_theta: &[f64],
    nyquist: &[f64],
    intervals: u32,
    estimator: &Estimator,
) -> Result<Option<Candidate>> {
    Ok(
        pixel_candidates(angles, v_theta, nyquist, intervals, estimator)?
            .into_iter()
            .min_by(|a, b| a.score.total_cmp(&b.score)),
    )
}
