//! Rigid media for tests: a rotating disk, a translating block, still point targets.

use rand::RngExt;

use super::{Phantom, Truth, normal_amplitudes, require_finite, rng, scatterer_count};
use crate::core::error::{Result, require_positive};

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
            return Err(crate::core::error::Error::Shape(format!(
                "{} positions but {} amplitudes",
                positions.len(),
                amplitudes.len()
            )));
        }
        if positions.iter().flatten().any(|v| !v.is_finite())
            || amplitudes.iter().any(|v| !v.is_finite())
            || velocity.iter().any(|v| !v.is_finite())
        {
            return Err(crate::core::error::Error::NonFinite(
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
