//! A straight tube with a parabolic (laminar) or plug profile.

use rand::RngExt;
use serde::Serialize;

use super::{Phantom, Truth, normal_amplitudes, parabolic, require_finite, rng, scatterer_count};
use crate::core::error::{Result, require_positive};

/// How the speed varies across a tube, from its axis to its wall.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FlowProfile {
    /// Laminar (Poiseuille): peak·(1 − (l/R)²) at distance l from the axis, zero at the wall.
    #[default]
    Parabolic,
    /// Plug: the peak speed across the whole lumen, no gradient inside it, a step at the wall
    /// (the blunt profile of large arteries in systole, taken to its limit).
    Plug,
}

impl FlowProfile {
    /// Speed (m/s) at distance `l` (m) from the axis of a tube of `radius` (m) whose centreline
    /// speed is `peak` (m/s); zero outside.
    pub fn speed(self, peak: f64, l: f64, radius: f64) -> f64 {
        match self {
            FlowProfile::Parabolic => parabolic(peak, l, radius),
            FlowProfile::Plug if l.abs() <= radius => peak,
            FlowProfile::Plug => 0.0,
        }
    }

    /// Lower-case name, as the command line takes it.
    pub fn label(self) -> &'static str {
        match self {
            FlowProfile::Parabolic => "parabolic",
            FlowProfile::Plug => "plug",
        }
    }
}

/// A straight tube with a parabolic or plug profile, SI units.
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
    /// How the speed falls from the centreline to the wall.
    pub profile: FlowProfile,
}

impl TubeSpec {
    /// The `tube` preset's vessel: radius 0.5 mm, 16 mm long, 300 scatterers/mm², centred at
    /// (0, 8 mm), flowing 30° below +x (toward +x and deeper), parabolic, at a peak speed of
    /// `peak_speed` (m/s; the preset's default is 25 mm/s).
    pub fn preset(peak_speed: f64) -> Self {
        TubeSpec {
            centre: [0.0, 8e-3],
            angle: 30f64.to_radians(),
            length: 16e-3,
            radius: 0.5e-3,
            peak_speed,
            density: 300e6,
            profile: FlowProfile::Parabolic,
        }
    }
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
            .map(|&l| spec.profile.speed(spec.peak_speed, l, spec.radius))
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
                let u = spec.profile.speed(spec.peak_speed, l, spec.radius);
                [u * d[0], u * d[1]]
            })
        })
    }
}
