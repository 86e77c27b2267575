//! Flow phantoms: point scatterers with amplitudes, exact motion, and ground-truth velocity maps.
//!
//! A phantom is a fixed list of scatterers (amplitude, arbitrary units) whose positions are known at
//! any time t (s): motion is integrated in closed form, so `positions_at(t)` does not depend on the
//! times asked before. Every random draw comes from a `ChaCha8Rng` seeded by the phantom's seed.
//! Ground truth is sampled on any pixel grid as a [`Truth`] (m/s, shape (nz, nx)).
//!
//! Coordinates follow the crate convention: x lateral, z depth (positive into the medium), m.
//! Scatterer densities are per unit area of the 2-D imaging plane (scatterers/m²; 300/mm² = 3e8/m²).

use ndarray::Array2;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use crate::error::{Result, invalid, require_positive};

/// Largest number of scatterers a phantom may draw (guards against absurd densities).
pub const MAX_SCATTERERS: usize = 20_000_000;

/// Ground-truth velocity on a pixel grid: `vx`, `vz` in m/s, shape (nz, nx); `mask` is true inside
/// the flow. Outside the mask both components are 0.
#[derive(Debug, Clone, PartialEq)]
pub struct Truth {
    /// Lateral velocity (m/s), > 0 toward +x.
    pub vx: Array2<f64>,
    /// Axial velocity (m/s), > 0 moving deeper.
    pub vz: Array2<f64>,
    /// True where the pixel lies inside the moving medium.
    pub mask: Array2<bool>,
}

impl Truth {
    /// An all-outside truth of shape (nz, nx).
    pub fn empty(nz: usize, nx: usize) -> Self {
        Truth {
            vx: Array2::zeros((nz, nx)),
            vz: Array2::zeros((nz, nx)),
            mask: Array2::from_elem((nz, nx), false),
        }
    }

    /// Fills a truth by evaluating `f(x, z)` (m) → `Some((vx, vz))` inside the flow, `None` outside.
    pub fn from_fn(x: &[f64], z: &[f64], f: impl Fn(f64, f64) -> Option<[f64; 2]>) -> Self {
        let mut t = Truth::empty(z.len(), x.len());
        for (iz, &zz) in z.iter().enumerate() {
            for (ix, &xx) in x.iter().enumerate() {
                if let Some([vx, vz]) = f(xx, zz) {
                    t.vx[[iz, ix]] = vx;
                    t.vz[[iz, ix]] = vz;
                    t.mask[[iz, ix]] = true;
                }
            }
        }
        t
    }

    /// Speed |v| (m/s) at every pixel.
    pub fn speed(&self) -> Array2<f64> {
        ndarray::Zip::from(&self.vx)
            .and(&self.vz)
            .map_collect(|a, b| a.hypot(*b))
    }
}

/// A moving scattering medium, as the simulator sees it.
pub trait Phantom: Sync {
    /// Reflection amplitude of each scatterer (arbitrary units), in a fixed order.
    fn amplitudes(&self) -> &[f64];

    /// Clears `out` and fills it with the (x, z) position (m) of every scatterer at time `t` (s),
    /// in the order of [`Phantom::amplitudes`].
    fn positions_at(&self, t: f64, out: &mut Vec<[f64; 2]>);

    /// Ground-truth velocity (m/s) at time `t` (s) on the grid of lateral positions `x` and depths
    /// `z` (m); arrays of shape (z.len(), x.len()).
    fn truth(&self, x: &[f64], z: &[f64], t: f64) -> Truth;

    /// Number of scatterers.
    fn n_scatterers(&self) -> usize {
        self.amplitudes().len()
    }
}

pub(crate) fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

pub(crate) fn normal_amplitudes(rng: &mut ChaCha8Rng, n: usize) -> Vec<f64> {
    (0..n).map(|_| StandardNormal.sample(rng)).collect()
}

pub(crate) fn require_finite(name: &str, v: f64) -> Result<()> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(invalid(name, format!("must be finite, got {v}")))
    }
}

/// Scatterer count for `density` (1/m²) over `area` (m²), checked against [`MAX_SCATTERERS`].
pub(crate) fn scatterer_count(density: f64, area: f64) -> Result<usize> {
    require_positive("scatterer density", density)?;
    let n = (density * area).round();
    if !n.is_finite() || n > MAX_SCATTERERS as f64 {
        return Err(invalid(
            "scatterer density",
            format!(
                "{density:e} /m² over {:.3} mm² gives {n:e} scatterers, more than {MAX_SCATTERERS}",
                area * 1e6
            ),
        ));
    }
    Ok(n as usize)
}

/// Parabolic (laminar) profile: peak·(1 − (l/R)²) for |l| ≤ R, 0 outside (m/s).
#[inline]
pub(crate) fn parabolic(peak: f64, l: f64, radius: f64) -> f64 {
    let q = l / radius;
    if q.abs() <= 1.0 {
        peak * (1.0 - q * q)
    } else {
        0.0
    }
}

// ---------------------------------------------------------------------------------------------
// Spiral
// ---------------------------------------------------------------------------------------------

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

// ---------------------------------------------------------------------------------------------
// Tube
// ---------------------------------------------------------------------------------------------

/// A straight tube with a parabolic (laminar) profile, SI units.
#[derive(Debug, Clone, PartialEq)]
pub struct TubeSpec {
    /// Centre of the tube (x, z) (m).
    pub centre: [f64; 2],
    /// Flow direction (rad), measured from +x toward +z (0: flow toward +x; π/2: flow deeper).
    pub angle: f64,
    /// Length along the axis (m).
    pub length: f64,
    /// Radius (m).
    pub radius: f64,
    /// Centreline speed (m/s); negative reverses the flow.
    pub peak_speed: f64,
    /// Scatterer density (scatterers/m²).
    pub density: f64,
}

/// A straight tube; scatterers that leave one end re-enter at the other, so the count is constant.
#[derive(Debug, Clone)]
pub struct TubePhantom {
    spec: TubeSpec,
    amplitudes: Vec<f64>,
    /// Per scatterer: axial coordinate at t = 0 in [−L/2, L/2) (m), lateral offset (m), speed (m/s).
    axial0: Vec<f64>,
    offset: Vec<f64>,
    speed: Vec<f64>,
}

impl TubePhantom {
    /// Draws the scatterers of `spec` with the random stream of `seed`.
    pub fn new(spec: TubeSpec, seed: u64) -> Result<Self> {
        require_finite("tube centre x", spec.centre[0])?;
        require_finite("tube centre z", spec.centre[1])?;
        require_finite("tube angle", spec.angle)?;
        require_positive("tube length", spec.length)?;
        require_positive("tube radius", spec.radius)?;
        require_finite("tube peak speed", spec.peak_speed)?;
        let n = scatterer_count(spec.density, spec.length * 2.0 * spec.radius)?;
        let mut rng = rng(seed);
        let mut axial0 = Vec::with_capacity(n);
        let mut offset = Vec::with_capacity(n);
        for _ in 0..n {
            axial0.push(rng.random_range(-0.5 * spec.length..0.5 * spec.length));
            offset.push(rng.random_range(-spec.radius..spec.radius));
        }
        let speed = offset
            .iter()
            .map(|&l| parabolic(spec.peak_speed, l, spec.radius))
            .collect();
        let amplitudes = normal_amplitudes(&mut rng, n);
        Ok(TubePhantom {
            spec,
            amplitudes,
            axial0,
            offset,
            speed,
        })
    }

    /// The geometry and flow parameters.
    pub fn spec(&self) -> &TubeSpec {
        &self.spec
    }

    fn axes(&self) -> ([f64; 2], [f64; 2]) {
        let (s, c) = self.spec.angle.sin_cos();
        ([c, s], [-s, c])
    }
}

impl Phantom for TubePhantom {
    fn amplitudes(&self) -> &[f64] {
        &self.amplitudes
    }

    fn positions_at(&self, t: f64, out: &mut Vec<[f64; 2]>) {
        let (d, n) = self.axes();
        let (len, c) = (self.spec.length, self.spec.centre);
        out.clear();
        out.extend((0..self.amplitudes.len()).map(|i| {
            let s = (self.axial0[i] + self.speed[i] * t + 0.5 * len).rem_euclid(len) - 0.5 * len;
            let l = self.offset[i];
            [c[0] + s * d[0] + l * n[0], c[1] + s * d[1] + l * n[1]]
        }));
    }

    fn truth(&self, x: &[f64], z: &[f64], _t: f64) -> Truth {
        let (d, n) = self.axes();
        let spec = &self.spec;
        Truth::from_fn(x, z, |x, z| {
            let (dx, dz) = (x - spec.centre[0], z - spec.centre[1]);
            let s = dx * d[0] + dz * d[1];
            let l = dx * n[0] + dz * n[1];
            (s.abs() <= 0.5 * spec.length && l.abs() <= spec.radius).then(|| {
                let u = parabolic(spec.peak_speed, l, spec.radius);
                [u * d[0], u * d[1]]
            })
        })
    }
}

// ---------------------------------------------------------------------------------------------
// Disk
// ---------------------------------------------------------------------------------------------

/// A rigidly rotating disk, SI units.
#[derive(Debug, Clone, PartialEq)]
pub struct DiskSpec {
    /// Centre (x, z) (m).
    pub centre: [f64; 2],
    /// Radius (m).
    pub radius: f64,
    /// Angular velocity (rad/s); > 0 turns +x toward +z.
    pub angular_velocity: f64,
    /// Scatterer density (scatterers/m²).
    pub density: f64,
}

/// A rigidly rotating disk: v = ω × r, so the axial velocity is linear in x.
#[derive(Debug, Clone)]
pub struct DiskPhantom {
    spec: DiskSpec,
    amplitudes: Vec<f64>,
    /// Offsets from the centre at t = 0 (m).
    offsets: Vec<[f64; 2]>,
}

impl DiskPhantom {
    /// Draws the scatterers of `spec` uniformly over the disk with the random stream of `seed`.
    pub fn new(spec: DiskSpec, seed: u64) -> Result<Self> {
        require_finite("disk centre x", spec.centre[0])?;
        require_finite("disk centre z", spec.centre[1])?;
        require_positive("disk radius", spec.radius)?;
        require_finite("angular velocity", spec.angular_velocity)?;
        let r = spec.radius;
        let n = scatterer_count(spec.density, std::f64::consts::PI * r * r)?;
        let mut rng = rng(seed);
        let mut offsets = Vec::with_capacity(n);
        while offsets.len() < n {
            let p = [rng.random_range(-r..r), rng.random_range(-r..r)];
            if p[0].hypot(p[1]) <= r {
                offsets.push(p);
            }
        }
        let amplitudes = normal_amplitudes(&mut rng, n);
        Ok(DiskPhantom {
            spec,
            amplitudes,
            offsets,
        })
    }

    /// The geometry and rotation parameters.
    pub fn spec(&self) -> &DiskSpec {
        &self.spec
    }
}

impl Phantom for DiskPhantom {
    fn amplitudes(&self) -> &[f64] {
        &self.amplitudes
    }

    fn positions_at(&self, t: f64, out: &mut Vec<[f64; 2]>) {
        let (s, c) = (self.spec.angular_velocity * t).sin_cos();
        let o = self.spec.centre;
        out.clear();
        out.extend(
            self.offsets
                .iter()
                .map(|p| [o[0] + c * p[0] - s * p[1], o[1] + s * p[0] + c * p[1]]),
        );
    }

    fn truth(&self, x: &[f64], z: &[f64], _t: f64) -> Truth {
        let (o, w, r) = (
            self.spec.centre,
            self.spec.angular_velocity,
            self.spec.radius,
        );
        Truth::from_fn(x, z, |x, z| {
            let (dx, dz) = (x - o[0], z - o[1]);
            (dx.hypot(dz) <= r).then_some([-w * dz, w * dx])
        })
    }
}

// ---------------------------------------------------------------------------------------------
// Block
// ---------------------------------------------------------------------------------------------

/// A rectangle of scatterers translating uniformly, SI units.
#[derive(Debug, Clone, PartialEq)]
pub struct BlockSpec {
    /// Lateral extent at t = 0 (x_min, x_max) (m).
    pub x: (f64, f64),
    /// Depth extent at t = 0 (z_min, z_max) (m).
    pub z: (f64, f64),
    /// Velocity (vx, vz) (m/s).
    pub velocity: [f64; 2],
    /// Scatterer density (scatterers/m²).
    pub density: f64,
}

/// A block of scatterers in uniform translation (no wrap-around): the simplest moving medium.
#[derive(Debug, Clone)]
pub struct BlockPhantom {
    spec: BlockSpec,
    amplitudes: Vec<f64>,
    initial: Vec<[f64; 2]>,
}

impl BlockPhantom {
    /// Draws the scatterers of `spec` uniformly over the rectangle with the random stream of `seed`.
    pub fn new(spec: BlockSpec, seed: u64) -> Result<Self> {
        for (name, v) in [
            ("block x_min", spec.x.0),
            ("block x_max", spec.x.1),
            ("block z_min", spec.z.0),
            ("block z_max", spec.z.1),
            ("block vx", spec.velocity[0]),
            ("block vz", spec.velocity[1]),
        ] {
            require_finite(name, v)?;
        }
        require_positive("block width", spec.x.1 - spec.x.0)?;
        require_positive("block height", spec.z.1 - spec.z.0)?;
        let n = scatterer_count(spec.density, (spec.x.1 - spec.x.0) * (spec.z.1 - spec.z.0))?;
        let mut rng = rng(seed);
        let initial = (0..n)
            .map(|_| {
                [
                    rng.random_range(spec.x.0..spec.x.1),
                    rng.random_range(spec.z.0..spec.z.1),
                ]
            })
            .collect();
        let amplitudes = normal_amplitudes(&mut rng, n);
        Ok(BlockPhantom {
            spec,
            amplitudes,
            initial,
        })
    }

    /// The geometry and velocity.
    pub fn spec(&self) -> &BlockSpec {
        &self.spec
    }
}

impl Phantom for BlockPhantom {
    fn amplitudes(&self) -> &[f64] {
        &self.amplitudes
    }

    fn positions_at(&self, t: f64, out: &mut Vec<[f64; 2]>) {
        let v = self.spec.velocity;
        out.clear();
        out.extend(
            self.initial
                .iter()
                .map(|p| [p[0] + v[0] * t, p[1] + v[1] * t]),
        );
    }

    fn truth(&self, x: &[f64], z: &[f64], t: f64) -> Truth {
        let s = &self.spec;
        let (ox, oz) = (s.velocity[0] * t, s.velocity[1] * t);
        Truth::from_fn(x, z, |x, z| {
            let inside =
                (s.x.0 + ox..=s.x.1 + ox).contains(&x) && (s.z.0 + oz..=s.z.1 + oz).contains(&z);
            inside.then_some(s.velocity)
        })
    }
}

// ---------------------------------------------------------------------------------------------
// Explicit points
// ---------------------------------------------------------------------------------------------

/// Explicit point scatterers sharing one constant velocity: for impulse-response and geometry tests.
#[derive(Debug, Clone)]
pub struct PointPhantom {
    amplitudes: Vec<f64>,
    initial: Vec<[f64; 2]>,
    velocity: [f64; 2],
}

impl PointPhantom {
    /// Points at `positions` (m) at t = 0 with `amplitudes`, all moving at `velocity` (m/s).
    pub fn new(positions: Vec<[f64; 2]>, amplitudes: Vec<f64>, velocity: [f64; 2]) -> Result<Self> {
        if positions.len() != amplitudes.len() {
            return Err(crate::error::Error::Shape(format!(
                "{} positions but {} amplitudes",
                positions.len(),
                amplitudes.len()
            )));
        }
        if positions.iter().flatten().any(|v| !v.is_finite())
            || amplitudes.iter().any(|v| !v.is_finite())
            || velocity.iter().any(|v| !v.is_finite())
        {
            return Err(crate::error::Error::NonFinite(
                "point phantom positions, amplitudes or velocity".into(),
            ));
        }
        Ok(PointPhantom {
            amplitudes,
            initial: positions,
            velocity,
        })
    }

    /// One still point of amplitude 1 at (x, z) (m).
    pub fn single(x: f64, z: f64) -> Result<Self> {
        Self::new(vec![[x, z]], vec![1.0], [0.0, 0.0])
    }
}

impl Phantom for PointPhantom {
    fn amplitudes(&self) -> &[f64] {
        &self.amplitudes
    }

    fn positions_at(&self, t: f64, out: &mut Vec<[f64; 2]>) {
        let v = self.velocity;
        out.clear();
        out.extend(
            self.initial
                .iter()
                .map(|p| [p[0] + v[0] * t, p[1] + v[1] * t]),
        );
    }

    /// The pixel nearest to each point (within the grid) is marked, with the common velocity.
    fn truth(&self, x: &[f64], z: &[f64], t: f64) -> Truth {
        let mut truth = Truth::empty(z.len(), x.len());
        let nearest = |grid: &[f64], v: f64| {
            grid.iter()
                .enumerate()
                .min_by(|a, b| (a.1 - v).abs().total_cmp(&(b.1 - v).abs()))
                .map(|(i, _)| i)
        };
        let mut pos = Vec::new();
        self.positions_at(t, &mut pos);
        for p in pos {
            if let (Some(ix), Some(iz)) = (nearest(x, p[0]), nearest(z, p[1])) {
                truth.vx[[iz, ix]] = self.velocity[0];
                truth.vz[[iz, ix]] = self.velocity[1];
                truth.mask[[iz, ix]] = true;
            }
        }
        truth
    }
}

/// A phantom held still within each compound frame: the positions of `inner` sampled at the start of
/// the frame. This is the motion model of simulations that move scatterers once per frame (as the
/// PC-UVD paper's Field II study did, Δt = frame period); it hides the error Hadamard decoding makes
/// when blood moves between the events of a frame, and exists to measure that error.
pub struct FrameHeld<'a> {
    /// The moving phantom.
    pub inner: &'a dyn Phantom,
    /// Compound-frame period (s): n angles / event PRF.
    pub frame_period: f64,
}

impl Phantom for FrameHeld<'_> {
    fn amplitudes(&self) -> &[f64] {
        self.inner.amplitudes()
    }

    fn positions_at(&self, t: f64, out: &mut Vec<[f64; 2]>) {
        // Event times are i / PRF: the tiny margin keeps frame starts from rounding down a frame.
        let frame = (t / self.frame_period + 1e-9).floor();
        self.inner.positions_at(frame * self.frame_period, out);
    }

    fn truth(&self, x: &[f64], z: &[f64], t: f64) -> Truth {
        self.inner.truth(x, z, t)
    }
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
