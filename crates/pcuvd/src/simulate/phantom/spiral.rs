//! The paper's Archimedes-spiral vessel (eqs. 17–22).

use rand::RngExt;
use rayon::prelude::*;

use super::{Phantom, Truth, normal_amplitudes, parabolic, require_finite, rng, scatterer_count};
use crate::core::error::{Result, invalid, require_positive};

/// Geometry and flow of the paper's Archimedes-spiral vessel (eqs. 17–22), SI units.
#[derive(Debug, Clone, PartialEq)]
pub struct SpiralSpec {
    /// Initial radius a of the centreline r(α) = a + bα (m).
    pub a: f64,
    /// Turn spacing b (m/rad).
    pub b: f64,
    /// Largest polar angle α_max of the centreline (rad).
    pub alpha_max: f64,
    /// Vessel radius R (m).
    pub radius: f64,
    /// Centreline (peak) speed u_c of the parabolic profile (m/s).
    pub peak_speed: f64,
    /// Scatterer density over the vessel area (scatterers/m²).
    pub density: f64,
    /// Spiral centre (x_offset, z_offset) (m).
    pub centre: [f64; 2],
}

impl SpiralSpec {
    /// The paper's spiral: a = 1 mm, b = 0.28 mm/rad, α ∈ [0, 4.2π], R = 0.6 mm, u_c = 25 mm/s,
    /// 300 scatterers/mm², centre (0, 7 mm).
    pub fn paper() -> Self {
        SpiralSpec {
            a: 1e-3,
            b: 0.28e-3,
            alpha_max: 4.2 * std::f64::consts::PI,
            radius: 0.6e-3,
            peak_speed: 25e-3,
            density: 300e6,
            centre: [0.0, 7e-3],
        }
    }

    /// Vessel area (m²): ∫∫ r dα dl = 2R·(a·α_max + b·α_max²/2).
    pub fn area(&self) -> f64 {
        2.0 * self.radius * (self.a * self.alpha_max + 0.5 * self.b * self.alpha_max.powi(2))
    }

    fn validate(&self) -> Result<()> {
        require_positive("spiral a", self.a)?;
        require_positive("spiral b", self.b)?;
        require_positive("spiral α_max", self.alpha_max)?;
        require_positive("vessel radius", self.radius)?;
        require_finite("peak speed", self.peak_speed)?;
        require_finite("spiral centre x", self.centre[0])?;
        require_finite("spiral centre z", self.centre[1])?;
        if self.radius >= self.a {
            return Err(invalid(
                "vessel radius",
                format!(
                    "{:.3} mm must be smaller than the spiral's initial radius a = {:.3} mm",
                    self.radius * 1e3,
                    self.a * 1e3
                ),
            ));
        }
        if 2.0 * self.radius >= 2.0 * std::f64::consts::PI * self.b {
            return Err(invalid(
                "vessel radius",
                format!(
                    "a {:.3} mm wide vessel overlaps the next turn {:.3} mm away",
                    2e3 * self.radius,
                    2e3 * std::f64::consts::PI * self.b
                ),
            ));
        }
        Ok(())
    }

    /// Arc-length primitive along a streamline: S(ρ) with dS/dρ = √(ρ² + b²)/b, ρ = a + bα + l (m).
    #[inline]
    fn arc_primitive(&self, rho: f64) -> f64 {
        let b = self.b;
        // asinh(ρ/b) = ln((ρ + √(ρ² + b²))/b) for ρ > 0 (ρ ≥ a − R > 0 here).
        let root = (rho * rho + b * b).sqrt();
        (rho * root + b * b * ((rho + root) / b).ln()) / (2.0 * b)
    }

    /// Arc length (m) from α = 0 to `alpha` along the streamline at offset `l`.
    pub fn arc_length(&self, alpha: f64, l: f64) -> f64 {
        let rho0 = self.a + l;
        self.arc_primitive(rho0 + self.b * alpha) - self.arc_primitive(rho0)
    }

    /// The polar angle α (rad) reached after arc length `s` (m) from α = 0 on the streamline at
    /// offset `l` (Newton's method on the closed-form arc length; exact to rounding).
    pub fn alpha_at_arc(&self, s: f64, l: f64) -> f64 {
        let b = self.b;
        let rho0 = self.a + l;
        let target = self.arc_primitive(rho0) + s;
        // S(ρ) ≥ ρ²/2b + const, so this guess lies right of the root of a convex increasing
        // function: Newton then converges monotonically.
        let mut rho = (rho0 * rho0 + 2.0 * b * s.max(0.0)).sqrt();
        for _ in 0..8 {
            let f = self.arc_primitive(rho) - target;
            let step = f * b / (rho * rho + b * b).sqrt();
            rho -= step;
            if step.abs() <= 1e-14 * rho {
                break;
            }
        }
        (rho - rho0) / b
    }

    /// Position (m) of the point at polar angle `alpha` and radial offset `l` from the centreline.
    #[inline]
    pub fn position(&self, alpha: f64, l: f64) -> [f64; 2] {
        let r = self.a + self.b * alpha + l;
        let (s, c) = alpha.sin_cos();
        [r * c + self.centre[0], r * s + self.centre[1]]
    }

    /// The vessel coordinates (α, l) of the point (x, z): the turn whose centreline is nearest in r.
    /// `None` when no turn with α ∈ [0, α_max] is within one vessel radius.
    pub fn vessel_coordinates(&self, x: f64, z: f64) -> Option<(f64, f64)> {
        let two_pi = 2.0 * std::f64::consts::PI;
        let (dx, dz) = (x - self.centre[0], z - self.centre[1]);
        let rho = dx.hypot(dz);
        let phi = dz.atan2(dx).rem_euclid(two_pi);
        let mut best: Option<(f64, f64)> = None;
        let mut k = 0.0;
        while phi + two_pi * k <= self.alpha_max {
            let alpha = phi + two_pi * k;
            let l = rho - (self.a + self.b * alpha);
            if best.is_none_or(|(_, bl)| l.abs() < bl.abs()) {
                best = Some((alpha, l));
            }
            k += 1.0;
        }
        best.filter(|&(_, l)| l.abs() <= self.radius)
    }

    /// Flow velocity (m/s) at vessel coordinates (α, l): the tangent of r(α) = a + bα + l, with the
    /// parabolic speed u(l).
    pub fn velocity(&self, alpha: f64, l: f64) -> [f64; 2] {
        let r = self.a + self.b * alpha + l;
        let (s, c) = alpha.sin_cos();
        let (tx, tz) = (self.b * c - r * s, self.b * s + r * c);
        let u = parabolic(self.peak_speed, l, self.radius) / tx.hypot(tz);
        [u * tx, u * tz]
    }
}

/// The paper's spiral flow phantom: scatterers flowing along an Archimedes-spiral vessel with a
/// parabolic profile, restarting at α = 0 when they pass α_max.
///
/// Each scatterer keeps its offset l from the centreline and advances along its streamline
/// r(α) = a + bα + l at its speed u(l), i.e. dα/dt = u/√(b² + (a + bα + l)²) (eq. 21), integrated
/// exactly through the closed-form arc length. Scatterers are drawn uniformly in arc length along
/// each streamline (α weighted by √(b² + r²)), the distribution this motion leaves unchanged; over
/// the area that is uniform to within 1 % where r > 2 mm and up to 20 % denser at the innermost wall.
/// The count is density × [`SpiralSpec::area`].
#[derive(Debug, Clone)]
pub struct SpiralPhantom {
    spec: SpiralSpec,
    amplitudes: Vec<f64>,
    /// Per scatterer: offset l (m), arc position at t = 0 (m), streamline length (m), speed (m/s).
    offset: Vec<f64>,
    arc0: Vec<f64>,
    length: Vec<f64>,
    speed: Vec<f64>,
}

impl SpiralPhantom {
    /// Draws the scatterers of `spec` with the random stream of `seed`.
    pub fn new(spec: SpiralSpec, seed: u64) -> Result<Self> {
        spec.validate()?;
        let n = scatterer_count(spec.density, spec.area())?;
        let mut rng = rng(seed);
        let r_max = spec.a + spec.b * spec.alpha_max + spec.radius;
        let w_max = (spec.b * spec.b + r_max * r_max).sqrt();
        let (mut offset, mut arc0, mut length, mut speed) = (
            Vec::with_capacity(n),
            Vec::with_capacity(n),
            Vec::with_capacity(n),
            Vec::with_capacity(n),
        );
        while offset.len() < n {
            let alpha = rng.random_range(0.0..spec.alpha_max);
            let l = rng.random_range(-spec.radius..spec.radius);
            let r = spec.a + spec.b * alpha + l;
            let w = (spec.b * spec.b + r * r).sqrt() / w_max;
            if rng.random::<f64>() < w {
                offset.push(l);
                arc0.push(spec.arc_length(alpha, l));
                length.push(spec.arc_length(spec.alpha_max, l));
                speed.push(parabolic(spec.peak_speed, l, spec.radius));
            }
        }
        let amplitudes = normal_amplitudes(&mut rng, n);
        Ok(SpiralPhantom {
            spec,
            amplitudes,
            offset,
            arc0,
            length,
            speed,
        })
    }

    /// The paper's spiral ([`SpiralSpec::paper`]) drawn with `seed`.
    pub fn paper(seed: u64) -> Result<Self> {
        Self::new(SpiralSpec::paper(), seed)
    }

    /// The geometry and flow parameters.
    pub fn spec(&self) -> &SpiralSpec {
        &self.spec
    }

    /// Speed of each scatterer along its streamline (m/s).
    pub fn speeds(&self) -> &[f64] {
        &self.speed
    }

    /// Offset l of each scatterer from the centreline (m).
    pub fn offsets(&self) -> &[f64] {
        &self.offset
    }

    /// Polar angle α (rad) of scatterer `i` at time `t` (s).
    pub fn alpha_at(&self, i: usize, t: f64) -> f64 {
        let s = (self.arc0[i] + self.speed[i] * t).rem_euclid(self.length[i]);
        self.spec.alpha_at_arc(s, self.offset[i])
    }
}

impl Phantom for SpiralPhantom {
    fn amplitudes(&self) -> &[f64] {
        &self.amplitudes
    }

    /// Batched form of [`SpiralPhantom::alpha_at`] + [`SpiralSpec::position`]: the arc-length
    /// inversion is a fixed number of Newton steps in branch-free loops over chunks of scatterers
    /// (with `ln_vectorisable`), so that it runs 4 wide; the result matches the scalar path to
    /// rounding (below 10⁻¹⁵ m).
    fn positions_at(&self, t: f64, out: &mut Vec<[f64; 2]>) {
        const CHUNK: usize = 512;
        let n = self.amplitudes.len();
        out.clear();
        out.resize(n, [0.0; 2]);
        let spec = &self.spec;
        let b = spec.b;
        out.par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(chunk, out)| {
                let lo = chunk * CHUNK;
                let m = out.len();
                let range = lo..lo + m;
                let (arc0, speed) = (&self.arc0[range.clone()], &self.speed[range.clone()]);
                let (length, offset) = (&self.length[range.clone()], &self.offset[range]);
                let mut rho = [0.0f64; CHUNK];
                let mut target = [0.0f64; CHUNK];
                // Arc position s ∈ [0, length) and Newton's start (see `alpha_at_arc`).
                for i in 0..m {
                    let x = arc0[i] + speed[i] * t;
                    let s = x - length[i] * (x / length[i]).floor();
                    let s = if s >= length[i] {
                        s - length[i]
                    } else {
                        s.max(0.0)
                    };
                    let rho0 = spec.a + offset[i];
                    target[i] = arc_primitive_fast(b, rho0) + s;
                    rho[i] = (rho0 * rho0 + 2.0 * b * s).sqrt();
                }
                let mut last_step = [0.0f64; CHUNK];
                for _ in 0..NEWTON_STEPS {
                    for i in 0..m {
                        let r = rho[i];
                        let f = arc_primitive_fast(b, r) - target[i];
                        let step = f * b / (r * r + b * b).sqrt();
                        rho[i] = r - step;
                        last_step[i] = step;
                    }
                }
                for (i, o) in out.iter_mut().enumerate() {
                    let rho0 = spec.a + offset[i];
                    // Not converged (a spiral much tighter than the paper's): the scalar path.
                    let alpha = if last_step[i].abs() <= 1e-13 * rho[i] {
                        (rho[i] - rho0) / b
                    } else {
                        self.alpha_at(lo + i, t)
                    };
                    *o = spec.position(alpha, offset[i]);
                }
            });
    }

    fn truth(&self, x: &[f64], z: &[f64], _t: f64) -> Truth {
        Truth::from_fn(x, z, |x, z| {
            self.spec
                .vessel_coordinates(x, z)
                .map(|(alpha, l)| self.spec.velocity(alpha, l))
        })
    }
}

/// Newton steps of the batched arc-length inversion: from the start guess, 3 reach rounding on
/// the paper's spiral (ρ ≥ 1.4 b); the 4th checks it, and scatterers whose last step still moved
/// them by more than 10⁻¹³ ρ are redone by the scalar path.
const NEWTON_STEPS: usize = 4;

/// [`SpiralSpec::arc_primitive`] with [`ln_vectorisable`] for the logarithm.
#[inline(always)]
fn arc_primitive_fast(b: f64, rho: f64) -> f64 {
    let root = (rho * rho + b * b).sqrt();
    (rho * root + b * b * ln_vectorisable((rho + root) / b)) / (2.0 * b)
}

/// ln x for finite x > 0 (relative error below 3·10⁻¹⁶), branch- and call-free so that loops over
/// it vectorise: x = 2^e·m with m ∈ [√½, √2), ln m = 2 atanh((m − 1)/(m + 1)) by its series.
#[inline(always)]
fn ln_vectorisable(x: f64) -> f64 {
    let bits = x.to_bits();
    let e = ((bits >> 52) & 0x7ff) as i64 - 1023;
    let m = f64::from_bits((bits & 0x000f_ffff_ffff_ffff) | 0x3ff0_0000_0000_0000); // [1, 2)
    let big = m > std::f64::consts::SQRT_2;
    let m = if big { 0.5 * m } else { m };
    let e = (e + big as i64) as f64;
    let s = (m - 1.0) / (m + 1.0); // |s| ≤ 0.1716
    let s2 = s * s;
    let mut p = 1.0 / 23.0;
    for k in (0..11).rev() {
        p = p * s2 + 1.0 / (2 * k + 1) as f64;
    }
    e * std::f64::consts::LN_2 + 2.0 * s * p
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vectorisable_ln_is_accurate() {
        for &x in &[
            1e-300,
            1e-9,
            0.3,
            std::f64::consts::FRAC_1_SQRT_2,
            1.0,
            std::f64::consts::SQRT_2 * (1.0 - 1e-15),
            std::f64::consts::SQRT_2 * (1.0 + 1e-15),
            1.5,
            2.0,
            3.7,
            1e4,
            1e300,
        ] {
            let (fast, exact) = (ln_vectorisable(x), x.ln());
            assert!(
                (fast - exact).abs() <= 4e-16 * exact.abs().max(1.0),
                "ln {x}: {fast} vs {exact}"
            );
        }
    }

    /// The batched positions agree with the scalar arc-length inversion to rounding.
    #[test]
    fn batched_spiral_positions_match_the_scalar_path() {
        let spiral = SpiralPhantom::paper(3).unwrap();
        let mut out = Vec::new();
        for &t in &[0.0, 0.37e-3, 0.05, 2.3] {
            spiral.positions_at(t, &mut out);
            assert_eq!(out.len(), spiral.n_scatterers());
            for (i, p) in out.iter().enumerate() {
                let q = spiral
                    .spec
                    .position(spiral.alpha_at(i, t), spiral.offset[i]);
                let err = (p[0] - q[0]).hypot(p[1] - q[1]);
                assert!(err < 1e-15, "t {t}, scatterer {i}: {err:e} m");
            }
        }
    }
}
