//! Tissue: a region of fully developed speckle, many times brighter than blood, optional bright
//! layers (dura, skull edge) and anechoic regions, all moved by a smooth physiological
//! displacement field (heartbeat and breathing); and [`Moved`], which moves any phantom (its
//! vessels) with the same field, so that tissue and vessels move together.
//!
//! # Echogenicity
//! Tissue brightness is set relative to blood as a ratio of backscattered power per unit volume
//! (per unit area in a two-dimensional phantom): ρ·E[a²] for scatterers of density ρ and
//! amplitude a. Blood echoes some 20–60 dB below the tissue around it (as commonly quoted after
//! Jensen, *Estimation of Blood Velocities Using Ultrasound*, Cambridge University Press, 1996);
//! [`TissueSpec::DEFAULT_ECHOGENICITY_DB`] takes 40 dB, the middle of that range.
//!
//! # Speckle
//! Speckle is fully developed (Rayleigh-distributed envelope, mean/SD = 1.91) when every
//! resolution cell holds about ten or more scatterers of random amplitude. The resolution cell of
//! a 15.6 MHz plane-wave image is about λ axially (0.1 mm, two-cycle pulse) by 0.15 mm laterally
//! and, in elevation, the two-way beam width (0.4 mm at the L22-14vX's focus):
//! [`TissueSpec::DEFAULT_DENSITY_3D`] puts 10 scatterers in 0.1 × 0.15 × 0.4 mm³, and
//! [`TissueSpec::DEFAULT_DENSITY_2D`] 10 in 0.1 × 0.15 mm².
//!
//! # Motion
//! Each scatterer first at p₀ = (x, y, z) is displaced by
//!
//! d(p₀, t) = Σₖ (sin(ωₖ t + φₖ) − sin φₖ) · (1 + gₖ · (z₀ − z_ref)) · aₖ,
//!
//! one term per [`Oscillation`] (angular frequency ωₖ, phase φₖ, amplitude vector aₖ (m), depth
//! gradient gₖ (1/m), so that the field may grow or shrink with depth below `z_ref`): rigid when
//! every gₖ is 0, smooth (affine in depth) otherwise, exact in closed form at any t, and zero at
//! t = 0. Its velocity is ∂d/∂t. The displacement is a function of the starting position
//! (Lagrangian): for displacements of tens of µm over a field that varies over millimetres, the
//! difference from the field at the current position is below 10⁻³ of the motion.

use ndarray::Array2;
use rand::RngExt;

use super::{Phantom, Truth, require_finite, rng, scatterer_count};
use crate::core::error::{Result, invalid, require_positive};

/// One periodic physiological displacement (heartbeat or breathing) of the tissue.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Oscillation {
    /// Frequency (Hz): the rat's heart beats at about 5.5 Hz, it breathes at about 1 Hz.
    pub frequency_hz: f64,
    /// Displacement amplitude (m) along (x, y, z) at the reference depth.
    pub amplitude: [f64; 3],
    /// Phase at t = 0 (rad).
    pub phase_rad: f64,
    /// Relative change of the amplitude per metre of depth below the reference depth (1/m):
    /// 0 for a rigid motion.
    pub depth_gradient: f64,
}

impl Oscillation {
    fn omega(&self) -> f64 {
        2.0 * std::f64::consts::PI * self.frequency_hz
    }

    fn validate(&self, name: &str) -> Result<()> {
        require_positive(&format!("{name} frequency"), self.frequency_hz)?;
        for (axis, a) in ["x", "y", "z"].iter().zip(self.amplitude) {
            require_finite(&format!("{name} amplitude along {axis}"), a)?;
        }
        require_finite(&format!("{name} phase"), self.phase_rad)?;
        require_finite(&format!("{name} depth gradient"), self.depth_gradient)
    }
}

/// A smooth displacement field over slow time: the sum of its oscillations (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct TissueMotion {
    /// The oscillations, e.g. a cardiac and a respiratory one.
    pub oscillations: Vec<Oscillation>,
    /// Depth (m) at which every oscillation has its stated amplitude.
    pub reference_depth: f64,
}

impl TissueMotion {
    /// No motion at all.
    pub fn still() -> Self {
        TissueMotion {
            oscillations: Vec::new(),
            reference_depth: 0.0,
        }
    }

    /// The anaesthetised rat's brain motion: a heartbeat at 5.5 Hz moving the tissue 3 µm
    /// axially (and 1 µm laterally) and breathing at 1 Hz moving it 20 µm axially and 5 µm
    /// laterally, both referred to 1 mm deep, breathing's growing by 10 % per mm deeper.
    pub fn rat() -> Self {
        TissueMotion {
            oscillations: vec![
                Oscillation {
                    frequency_hz: 5.5,
                    amplitude: [1e-6, 0.0, 3e-6],
                    phase_rad: 0.0,
                    depth_gradient: 0.0,
                },
                Oscillation {
                    frequency_hz: 1.0,
                    amplitude: [5e-6, 0.0, 20e-6],
                    phase_rad: 0.5,
                    depth_gradient: 100.0,
                },
            ],
            reference_depth: 1e-3,
        }
    }

    /// Checks every oscillation.
    pub fn validate(&self) -> Result<()> {
        require_finite("motion reference depth", self.reference_depth)?;
        for (i, o) in self.oscillations.iter().enumerate() {
            o.validate(&format!("motion oscillation {}", i + 1))?;
        }
        Ok(())
    }

    /// Fastest speed (m/s) of any point with depth in `depth` = (z_min, z_max) (m): a bound
    /// (every oscillation at its peak at once).
    pub fn max_speed(&self, depth: (f64, f64)) -> f64 {
        let farthest = (depth.0 - self.reference_depth)
            .abs()
            .max((depth.1 - self.reference_depth).abs());
        self.oscillations
            .iter()
            .map(|o| {
                let amplitude = o.amplitude.iter().map(|a| a * a).sum::<f64>().sqrt();
                o.omega() * amplitude * (1.0 + o.depth_gradient.abs() * farthest)
            })
            .sum()
    }

    /// Displacement (m) at time `t` (s) of the point first at `start` = (x, y, z) (m).
    pub fn displacement(&self, start: [f64; 3], t: f64) -> [f64; 3] {
        self.at(t).displacement(start)
    }

    /// The field at time `t` (s), for the displacements of many points: each oscillation's
    /// phase term is the same at every point, so it is computed once.
    pub fn at(&self, t: f64) -> MotionAt<'_> {
        MotionAt {
            motion: self,
            phases: self
                .oscillations
                .iter()
                .map(|o| (o.omega() * t + o.phase_rad).sin() - o.phase_rad.sin())
                .collect(),
        }
    }

    /// Velocity (m/s) at time `t` (s) of the point first at `start` = (x, y, z) (m).
    pub fn velocity(&self, start: [f64; 3], t: f64) -> [f64; 3] {
        let weights = self
            .oscillations
            .iter()
            .map(|o| o.omega() * (o.omega() * t + o.phase_rad).cos());
        self.sum(start, weights)
    }

    /// Adds to the flow `truth` on the grid `x`, `z` (m), inside its mask, the in-plane velocity
    /// of this motion at time `t` (s) (at y = 0): the truth of vessels that move with the tissue.
    pub fn carry(&self, truth: &mut Truth, x: &[f64], z: &[f64], t: f64) {
        for (iz, &zz) in z.iter().enumerate() {
            for (ix, &xx) in x.iter().enumerate() {
                if truth.mask[[iz, ix]] {
                    let v = self.velocity([xx, 0.0, zz], t);
                    truth.vx[[iz, ix]] += v[0];
                    truth.vz[[iz, ix]] += v[2];
                }
            }
        }
    }

    fn sum(&self, start: [f64; 3], weights: impl IntoIterator<Item = f64>) -> [f64; 3] {
        let mut total = [0.0; 3];
        for (o, weight) in self.oscillations.iter().zip(weights) {
            let scale = weight * (1.0 + o.depth_gradient * (start[2] - self.reference_depth));
            for (t, a) in total.iter_mut().zip(o.amplitude) {
                *t += scale * a;
            }
        }
        total
    }
}

/// A tissue motion at one time ([`TissueMotion::at`]).
pub struct MotionAt<'a> {
    motion: &'a TissueMotion,
    /// Per oscillation: sin(ωt + φ) − sin φ, its displacement's share of its amplitude.
    phases: Vec<f64>,
}

impl MotionAt<'_> {
    /// Displacement (m) of the point first at `start` = (x, y, z) (m).
    pub fn displacement(&self, start: [f64; 3]) -> [f64; 3] {
        self.motion.sum(start, self.phases.iter().copied())
    }
}

/// A layer of tissue, brighter (or darker) than the rest, between two depths.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Layer {
    /// Depth of its top (m).
    pub top: f64,
    /// Thickness (m).
    pub thickness: f64,
    /// Its echogenicity relative to blood (dB, see the module docs).
    pub echogenicity_db: f64,
}

/// A region without scatterers: a cylinder along y (elevation) of elliptic cross-section.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Anechoic {
    /// Centre (x, z) (m).
    pub centre: [f64; 2],
    /// Half-axes along x and z (m).
    pub radii: [f64; 2],
}

impl Anechoic {
    fn contains(&self, x: f64, z: f64) -> bool {
        let u = (x - self.centre[0]) / self.radii[0];
        let v = (z - self.centre[1]) / self.radii[1];
        u * u + v * v <= 1.0
    }
}

/// The tissue of a phantom: where it is, how bright, what it leaves out, how it moves.
#[derive(Debug, Clone, PartialEq)]
pub struct TissueSpec {
    /// Lateral extent (x_min, x_max) (m).
    pub x_range: (f64, f64),
    /// Depth extent (z_min, z_max) (m).
    pub z_range: (f64, f64),
    /// Half-thickness of the slab along the elevation y (m): scatterers fill |y| ≤ it. 0 puts
    /// them in the imaging plane (a two-dimensional phantom).
    pub half_thickness: f64,
    /// Scatterers per m³ (per m² when `half_thickness` is 0).
    pub density: f64,
    /// Backscattered power of the tissue relative to blood (dB, see the module docs).
    pub echogenicity_db: f64,
    /// The blood's backscattered power per unit volume (per unit area in two dimensions), ρ·E[a²]
    /// in the units of the phantom's blood amplitudes: the reference of every echogenicity.
    pub blood_power_density: f64,
    /// Brighter layers (dura, skull edge), in order of precedence.
    pub layers: Vec<Layer>,
    /// Regions without tissue.
    pub anechoic: Vec<Anechoic>,
    /// How the tissue moves.
    pub motion: TissueMotion,
}

impl TissueSpec {
    /// Tissue 40 dB above blood (see the module docs).
    pub const DEFAULT_ECHOGENICITY_DB: f64 = 40.0;
    /// Ten scatterers per resolution cell of 0.1 × 0.15 × 0.4 mm³ (scatterers/m³).
    pub const DEFAULT_DENSITY_3D: f64 = 10.0 / (0.1e-3 * 0.15e-3 * 0.4e-3);
    /// Ten scatterers per resolution cell of 0.1 × 0.15 mm² (scatterers/m²).
    pub const DEFAULT_DENSITY_2D: f64 = 10.0 / (0.1e-3 * 0.15e-3);

    /// Checks every field.
    pub fn validate(&self) -> Result<()> {
        for (name, (lo, hi)) in [
            ("tissue lateral extent", self.x_range),
            ("tissue depth extent", self.z_range),
        ] {
            if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                return Err(invalid(
                    name,
                    format!("({lo}, {hi}) m must be finite with min < max"),
                ));
            }
        }
        if !(self.half_thickness.is_finite() && self.half_thickness >= 0.0) {
            return Err(invalid(
                "tissue half-thickness",
                format!("must be finite and ≥ 0 m, got {}", self.half_thickness),
            ));
        }
        require_positive("tissue scatterer density", self.density)?;
        require_finite("tissue echogenicity", self.echogenicity_db)?;
        require_positive("blood power density", self.blood_power_density)?;
        for (i, layer) in self.layers.iter().enumerate() {
            require_finite(&format!("layer {} top", i + 1), layer.top)?;
            require_positive(&format!("layer {} thickness", i + 1), layer.thickness)?;
            require_finite(
                &format!("layer {} echogenicity", i + 1),
                layer.echogenicity_db,
            )?;
        }
        for (i, region) in self.anechoic.iter().enumerate() {
            require_finite(
                &format!("anechoic region {} centre x", i + 1),
                region.centre[0],
            )?;
            require_finite(
                &format!("anechoic region {} centre z", i + 1),
                region.centre[1],
            )?;
            require_positive(
                &format!("anechoic region {} radius along x", i + 1),
                region.radii[0],
            )?;
            require_positive(
                &format!("anechoic region {} radius along z", i + 1),
                region.radii[1],
            )?;
        }
        self.motion.validate()
    }

    /// RMS scatterer amplitude that gives `echogenicity_db` relative to blood at this density.
    fn amplitude_rms(&self, echogenicity_db: f64) -> f64 {
        (10f64.powf(echogenicity_db / 10.0) * self.blood_power_density / self.density).sqrt()
    }

    /// Echogenicity (dB) at depth `z` (m): the first layer holding it, else the tissue's.
    fn echogenicity_at(&self, z: f64) -> f64 {
        self.layers
            .iter()
            .find(|l| z >= l.top && z < l.top + l.thickness)
            .map_or(self.echogenicity_db, |l| l.echogenicity_db)
    }
}

/// Moving tissue as a phantom: Gaussian-amplitude scatterers, uniformly placed.
#[derive(Debug, Clone)]
pub struct TissuePhantom {
    spec: TissueSpec,
    /// Positions (x, y, z) at t = 0 (m).
    start: Vec<[f64; 3]>,
    amplitudes: Vec<f64>,
}

impl TissuePhantom {
    /// Draws the tissue of `spec` with `seed`; `excluded(x, y, z)` (m) removes scatterers that
    /// would lie where something else is (the lumens of the vessels).
    pub fn new(
        spec: TissueSpec,
        seed: u64,
        excluded: impl Fn(f64, f64, f64) -> bool,
    ) -> Result<Self> {
        spec.validate()?;
        let (x0, x1) = spec.x_range;
        let (z0, z1) = spec.z_range;
        let depth = if spec.half_thickness > 0.0 {
            2.0 * spec.half_thickness
        } else {
            1.0
        };
        let n = scatterer_count(spec.density, (x1 - x0) * (z1 - z0) * depth)?;
        let mut rng = rng(seed);
        let normal = rand_distr::StandardNormal;
        let mut start = Vec::with_capacity(n);
        let mut amplitudes = Vec::with_capacity(n);
        for _ in 0..n {
            let x = rng.random_range(x0..x1);
            let z = rng.random_range(z0..z1);
            let y = if spec.half_thickness > 0.0 {
                rng.random_range(-spec.half_thickness..spec.half_thickness)
            } else {
                0.0
            };
            let a: f64 = rand_distr::Distribution::sample(&normal, &mut rng);
            if spec.anechoic.iter().any(|r| r.contains(x, z)) || excluded(x, y, z) {
                continue;
            }
            start.push([x, y, z]);
            amplitudes.push(a * spec.amplitude_rms(spec.echogenicity_at(z)));
        }
        Ok(TissuePhantom {
            spec,
            start,
            amplitudes,
        })
    }

    /// The tissue's description.
    pub fn spec(&self) -> &TissueSpec {
        &self.spec
    }

    /// Displacement and velocity of the tissue on the pixel grid (`x`, `z`, m) at time `t` (s),
    /// each of shape (z.len(), x.len()): (dx, dy, dz) (m) and (vx, vy, vz) (m/s) of the point
    /// of the imaging plane (y = 0) first at each pixel.
    pub fn motion_truth(&self, x: &[f64], z: &[f64], t: f64) -> MotionTruth {
        let field = |f: &dyn Fn([f64; 3]) -> [f64; 3]| {
            let mut out = [(); 3].map(|_| Array2::zeros((z.len(), x.len())));
            for (iz, &zz) in z.iter().enumerate() {
                for (ix, &xx) in x.iter().enumerate() {
                    let v = f([xx, 0.0, zz]);
                    for (o, v) in out.iter_mut().zip(v) {
                        o[[iz, ix]] = v;
                    }
                }
            }
            out
        };
        MotionTruth {
            displacement: field(&|p| self.spec.motion.displacement(p, t)),
            velocity: field(&|p| self.spec.motion.velocity(p, t)),
        }
    }
}

/// The tissue's motion on a pixel grid: components along (x, y, z), each shape (nz, nx).
#[derive(Debug, Clone, PartialEq)]
pub struct MotionTruth {
    /// Displacement from t = 0 (m).
    pub displacement: [Array2<f64>; 3],
    /// Velocity (m/s).
    pub velocity: [Array2<f64>; 3],
}

impl Phantom for TissuePhantom {
    fn amplitudes(&self) -> &[f64] {
        &self.amplitudes
    }

    fn positions_at(&self, t: f64, out: &mut Vec<[f64; 2]>) {
        out.clear();
        let motion = self.spec.motion.at(t);
        out.extend(self.start.iter().map(|&p| {
            let d = motion.displacement(p);
            [p[0] + d[0], p[2] + d[2]]
        }));
    }

    fn elevations_at(&self, t: f64, out: &mut Vec<f64>) {
        out.clear();
        if self.spec.half_thickness > 0.0
            || self
                .spec
                .motion
                .oscillations
                .iter()
                .any(|o| o.amplitude[1] != 0.0)
        {
            let motion = self.spec.motion.at(t);
            out.extend(self.start.iter().map(|&p| p[1] + motion.displacement(p)[1]));
        }
    }

    /// Tissue carries no flow: an empty truth (its motion is in [`TissuePhantom::motion_truth`]).
    fn truth(&self, x: &[f64], z: &[f64], _t: f64) -> Truth {
        Truth::empty(z.len(), x.len())
    }
}

/// A phantom moved as a whole by a tissue motion field: vessels that move with the tissue around
/// them. Its truth adds the tissue's in-plane velocity to the flow's inside the flow.
pub struct Moved<'a> {
    /// The phantom to move.
    pub inner: &'a dyn Phantom,
    /// The displacement field.
    pub motion: &'a TissueMotion,
}

impl Phantom for Moved<'_> {
    fn amplitudes(&self) -> &[f64] {
        self.inner.amplitudes()
    }

    fn positions_at(&self, t: f64, out: &mut Vec<[f64; 2]>) {
        // Blood's own position at t, displaced by the field where the blood is now: the field
        // varies over millimetres, so where it started matters below 10⁻³ of the motion.
        self.inner.positions_at(t, out);
        let mut ys = Vec::new();
        self.inner.elevations_at(t, &mut ys);
        let motion = self.motion.at(t);
        for (i, p) in out.iter_mut().enumerate() {
            let y = ys.get(i).copied().unwrap_or(0.0);
            let d = motion.displacement([p[0], y, p[1]]);
            p[0] += d[0];
            p[1] += d[2];
        }
    }

    fn elevations_at(&self, t: f64, out: &mut Vec<f64>) {
        self.inner.elevations_at(t, out);
        if self
            .motion
            .oscillations
            .iter()
            .all(|o| o.amplitude[1] == 0.0)
        {
            return;
        }
        let mut positions = Vec::new();
        self.inner.positions_at(t, &mut positions);
        if out.is_empty() {
            out.resize(positions.len(), 0.0);
        }
        let motion = self.motion.at(t);
        for (y, p) in out.iter_mut().zip(&positions) {
            *y += motion.displacement([p[0], *y, p[1]])[1];
        }
    }

    fn truth(&self, x: &[f64], z: &[f64], t: f64) -> Truth {
        let mut truth = self.inner.truth(x, z, t);
        self.motion.carry(&mut truth, x, z, t);
        truth
    }
}

/// Several phantoms simulated together (tissue and vessels): scatterers in the order of the parts,
/// truth from the parts' truths (the first part whose mask holds a pixel gives its velocity).
pub struct Composite<'a> {
    parts: Vec<&'a dyn Phantom>,
    amplitudes: Vec<f64>,
}

impl<'a> Composite<'a> {
    /// The phantoms `parts` as one.
    pub fn new(parts: Vec<&'a dyn Phantom>) -> Self {
        let amplitudes = parts
            .iter()
            .flat_map(|p| p.amplitudes().iter().copied())
            .collect();
        Composite { parts, amplitudes }
    }
}

impl Phantom for Composite<'_> {
    fn amplitudes(&self) -> &[f64] {
        &self.amplitudes
    }

    fn positions_at(&self, t: f64, out: &mut Vec<[f64; 2]>) {
        out.clear();
        let mut part = Vec::new();
        for p in &self.parts {
            p.positions_at(t, &mut part);
            out.extend_from_slice(&part);
        }
    }

    fn elevations_at(&self, t: f64, out: &mut Vec<f64>) {
        out.clear();
        let mut part = Vec::new();
        let mut any = false;
        for p in &self.parts {
            p.elevations_at(t, &mut part);
            if part.is_empty() {
                out.extend(std::iter::repeat_n(0.0, p.n_scatterers()));
            } else {
                any = true;
                out.extend_from_slice(&part);
            }
        }
        if !any {
            out.clear();
        }
    }

    fn truth(&self, x: &[f64], z: &[f64], t: f64) -> Truth {
        let mut truth = Truth::empty(z.len(), x.len());
        for p in self.parts.iter().rev() {
            let part = p.truth(x, z, t);
            ndarray::Zip::from(&mut truth.vx)
                .and(&mut truth.vz)
                .and(&mut truth.mask)
                .and(&part.vx)
                .and(&part.vz)
                .and(&part.mask)
                .for_each(|vx, vz, m, &pvx, &pvz, &pm| {
                    if pm {
                        (*vx, *vz, *m) = (pvx, pvz, true);
                    }
                });
        }
        truth
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn velocity_is_the_time_derivative_of_displacement() {
        let motion = TissueMotion::rat();
        let p = [0.4e-3, 0.1e-3, 3.2e-3];
        for t in [0.0, 0.013, 0.21, 0.77] {
            let h = 1e-6;
            let (a, b) = (motion.displacement(p, t - h), motion.displacement(p, t + h));
            let v = motion.velocity(p, t);
            for i in 0..3 {
                let numeric = (b[i] - a[i]) / (2.0 * h);
                assert!(
                    (numeric - v[i]).abs() <= 1e-6 * v[i].abs().max(1e-6),
                    "{i}: {numeric} vs {}",
                    v[i]
                );
            }
        }
        assert_eq!(motion.displacement(p, 0.0), [0.0; 3]);
        // Breathing's amplitude grows by 10 % per mm: 2.2 mm below the reference depth it is
        // 1.22 × 20 µm axially at its peak (quarter period after its zero phase).
        let breathing = TissueMotion {
            oscillations: vec![Oscillation {
                phase_rad: 0.0,
                ..TissueMotion::rat().oscillations[1]
            }],
            ..TissueMotion::rat()
        };
        let d = breathing.displacement(p, 0.25);
        assert!((d[2] - 1.22 * 20e-6).abs() < 1e-12, "{}", d[2]);
    }

    fn patch(echogenicity_db: f64) -> TissueSpec {
        TissueSpec {
            x_range: (-1e-3, 1e-3),
            z_range: (2e-3, 4e-3),
            half_thickness: 0.0,
            density: TissueSpec::DEFAULT_DENSITY_2D,
            echogenicity_db,
            blood_power_density: 3e8,
            layers: vec![Layer {
                top: 3e-3,
                thickness: 0.5e-3,
                echogenicity_db: echogenicity_db + 10.0,
            }],
            anechoic: vec![Anechoic {
                centre: [0.0, 2.5e-3],
                radii: [0.3e-3, 0.3e-3],
            }],
            motion: TissueMotion::still(),
        }
    }

    #[test]
    fn tissue_has_its_density_power_layers_and_holes() {
        let tissue = TissuePhantom::new(patch(40.0), 7, |_, _, z| z > 3.9e-3).unwrap();
        let mut pos = Vec::new();
        tissue.positions_at(0.0, &mut pos);
        // Scatterers avoid the anechoic disk and the excluded band.
        assert!(
            pos.iter()
                .all(|p| p[0].hypot(p[1] - 2.5e-3) > 0.3e-3 && p[1] <= 3.9e-3)
        );
        let area = 2e-3 * 1.9e-3 - std::f64::consts::PI * 0.09e-6;
        let expected = TissueSpec::DEFAULT_DENSITY_2D * area;
        assert!(
            (pos.len() as f64 / expected - 1.0).abs() < 0.02,
            "{} of {expected}",
            pos.len()
        );
        // Power per unit area ρ·E[a²] is 10^(E/10) × the blood's, in the tissue and the layer.
        let power = |keep: &dyn Fn(f64) -> bool, area: f64| {
            let s: f64 = pos
                .iter()
                .zip(tissue.amplitudes())
                .filter(|(p, _)| keep(p[1]))
                .map(|(_, a)| a * a)
                .sum();
            s / area / 3e8
        };
        let bulk = power(&|z| !(3e-3..3.5e-3).contains(&z), area - 2e-3 * 0.5e-3);
        let layer = power(&|z| (3e-3..3.5e-3).contains(&z), 2e-3 * 0.5e-3);
        // Sums of ~1,700 and ~670 squared Gaussians: relative SD √(2/N), 0.15 and 0.24 dB; 4 SD.
        assert!(
            (10.0 * bulk.log10() - 40.0).abs() < 0.6,
            "{}",
            10.0 * bulk.log10()
        );
        assert!(
            (10.0 * layer.log10() - 50.0).abs() < 1.0,
            "{}",
            10.0 * layer.log10()
        );
        // In the plane and still: no elevations, no motion.
        let mut ys = Vec::new();
        tissue.elevations_at(0.1, &mut ys);
        assert!(ys.is_empty());
    }

    #[test]
    fn bad_tissue_is_refused_by_name() {
        let mut spec = patch(40.0);
        spec.motion.oscillations.push(Oscillation {
            frequency_hz: -1.0,
            amplitude: [0.0; 3],
            phase_rad: 0.0,
            depth_gradient: 0.0,
        });
        let err = TissuePhantom::new(spec, 1, |_, _, _| false).unwrap_err();
        assert!(
            err.to_string().contains("motion oscillation 1 frequency"),
            "{err}"
        );
        let mut spec = patch(40.0);
        spec.layers[0].thickness = 0.0;
        let err = TissuePhantom::new(spec, 1, |_, _, _| false).unwrap_err();
        assert!(err.to_string().contains("layer 1 thickness"), "{err}");
    }

    #[test]
    fn composites_and_moved_phantoms_keep_every_scatterer_in_order() {
        let a = TissuePhantom::new(patch(40.0), 1, |_, _, _| false).unwrap();
        let mut thick = patch(0.0);
        thick.half_thickness = 0.2e-3;
        thick.density = TissueSpec::DEFAULT_DENSITY_3D;
        thick.x_range = (0.0, 0.2e-3);
        let b = TissuePhantom::new(thick, 2, |_, _, _| false).unwrap();
        let both = Composite::new(vec![&a, &b]);
        assert_eq!(both.n_scatterers(), a.n_scatterers() + b.n_scatterers());
        let mut ys = Vec::new();
        both.elevations_at(0.0, &mut ys);
        assert_eq!(ys.len(), both.n_scatterers());
        assert!(ys[..a.n_scatterers()].iter().all(|&y| y == 0.0));
        assert!(ys[a.n_scatterers()..].iter().all(|&y| y.abs() <= 0.2e-3));
        assert!(ys[a.n_scatterers()..].iter().any(|&y| y != 0.0));
        let motion = TissueMotion::rat();
        let moved = Moved {
            inner: &both,
            motion: &motion,
        };
        let (mut still, mut now) = (Vec::new(), Vec::new());
        both.positions_at(0.1, &mut still);
        moved.positions_at(0.1, &mut now);
        for (s, n) in still.iter().zip(&now) {
            let d = motion.displacement([s[0], 0.0, s[1]], 0.1);
            assert!((n[1] - s[1] - d[2]).abs() < 1e-12);
        }
    }
}
