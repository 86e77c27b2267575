//! Blood in a vascular tree in three dimensions: scatterers in every segment of a solved
//! [`VascularFlow`], moving along it with its laminar, pulsatile flow, and the truth the probe's
//! imaging plane sees of it.
//!
//! # Scatterers
//! Each segment holds scatterers uniformly in its cylinder, of Gaussian amplitude whose variance
//! gives the blood's backscattered power per unit volume ([`TreeSpec::power_density`]) whatever
//! their number: a segment gets its volume × [`TreeSpec::density`] scatterers, but never fewer
//! than [`TreeSpec::min_per_mm`] per mm of length, so that a 10 µm vessel still has speckle along
//! it. A scatterer at radius r moves along the axis by the centreline displacement × (1 − (r/R)²)
//! (the laminar profile, exact in closed form at any time) and re-enters at the segment's other
//! end when it leaves, as in the other phantoms: at the ends of the segments blood appears and
//! disappears, which decorrelates the signal over a scatterer spacing there.
//!
//! # Truth
//! A pixel (x, z) of the imaging plane sees the blood within the elevation beam. Its truth is the
//! mean over the elevation y of what lies at (x, y, z), weighted by the beam's two-way echo power
//! |G(y, z)|⁴ ([`crate::simulate::elevation`]): the velocity (vx, vy, vz) of the blood, averaged
//! over the blood only; the blood fraction (the blood's share of the pixel's weight, a partial
//! volume); and the segment holding most of the pixel's blood weight, which gives its id, class
//! and RI. PSV and EDV are that segment's, scaled by the mean laminar profile factor the pixel
//! sees. Without an elevation aperture (a two-dimensional simulation) the weight is 1 at y = 0
//! and 0 elsewhere: the plane's own cut through the tree.

use ndarray::Array2;
use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use super::network::NetworkTruth;
use super::{MAX_SCATTERERS, Phantom, Truth, rng};
use crate::core::error::{Result, invalid, require_positive};
use crate::core::vessel::BACKGROUND;
use crate::simulate::elevation::ElevationAperture;
use crate::simulate::vascular::{SegmentFlow, VascularFlow};

/// How blood fills a tree.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TreeSpec {
    /// Scatterers per m³ of lumen.
    pub density: f64,
    /// Fewest scatterers per mm of a segment's length.
    pub min_per_mm: f64,
    /// Backscattered power per unit volume of blood, ρ·E[a²] (amplitude² per m³): the reference
    /// of a tissue's echogenicity.
    pub power_density: f64,
}

impl TreeSpec {
    /// 10⁵ scatterers per mm³ of lumen (ten in a 40 µm vessel's 0.1 mm resolution cell), at least
    /// 40 per mm of length, unit power per mm³.
    pub fn default_blood() -> Self {
        TreeSpec {
            density: 1e14,
            min_per_mm: 40.0,
            power_density: 1e9,
        }
    }
}

/// Where a scatterer sits in its segment.
#[derive(Debug, Clone, Copy)]
struct Seat {
    segment: usize,
    /// Distance along the axis from the segment's start at t = 0 (m).
    along: f64,
    /// Offset across the axis: radius (m) and angle (rad) around it.
    radius: f64,
    angle: f64,
}

/// Blood in a solved vascular tree, as a phantom.
#[derive(Debug, Clone)]
pub struct TreePhantom {
    flow: VascularFlow,
    seats: Vec<Seat>,
    amplitudes: Vec<f64>,
    /// Per segment: its unit axis and two unit normals spanning the cross-section.
    frames: Vec<[[f64; 3]; 3]>,
}

impl TreePhantom {
    /// Fills every segment of `flow` with blood as `spec` says, drawn with `seed`.
    pub fn new(flow: VascularFlow, spec: TreeSpec, seed: u64) -> Result<Self> {
        require_positive("blood scatterer density", spec.density)?;
        require_positive("blood power density", spec.power_density)?;
        if !(spec.min_per_mm.is_finite() && spec.min_per_mm >= 0.0) {
            return Err(invalid(
                "scatterers per mm",
                format!("must be finite and ≥ 0, got {}", spec.min_per_mm),
            ));
        }
        let mut rng = rng(seed);
        let mut seats = Vec::new();
        let mut amplitudes = Vec::new();
        let mut frames = Vec::with_capacity(flow.segments.len());
        for (index, s) in flow.segments.iter().enumerate() {
            frames.push(axes(s.direction()));
            let chord = s.chord();
            let volume = s.area() * chord;
            let n = (spec.density * volume)
                .max(spec.min_per_mm * chord * 1e3)
                .ceil();
            if seats.len() as f64 + n > MAX_SCATTERERS as f64 {
                return Err(invalid(
                    "blood scatterer density",
                    format!("the tree would hold more than {MAX_SCATTERERS} scatterers"),
                ));
            }
            let sigma = (spec.power_density * volume / n).sqrt();
            let radius = 0.5 * s.diameter;
            for _ in 0..n as usize {
                // Uniform over the disc: radius ∝ √u.
                let r = radius * rng.random_range(0.0f64..1.0).sqrt();
                seats.push(Seat {
                    segment: index,
                    along: rng.random_range(0.0..chord),
                    radius: r,
                    angle: rng.random_range(0.0..std::f64::consts::TAU),
                });
                let a: f64 = StandardNormal.sample(&mut rng);
                amplitudes.push(sigma * a);
            }
        }
        Ok(TreePhantom {
            flow,
            seats,
            amplitudes,
            frames,
        })
    }

    /// The tree's flow.
    pub fn flow(&self) -> &VascularFlow {
        &self.flow
    }

    /// A bound on each scatterer's speed at any time (m/s), in the order of its amplitudes: its
    /// segment's centreline bound ([`SegmentFlow::max_centreline_speed`]) scaled by the laminar
    /// profile at its radius.
    pub fn speed_bounds(&self) -> Vec<f64> {
        let segment: Vec<f64> = self
            .flow
            .segments
            .iter()
            .map(SegmentFlow::max_centreline_speed)
            .collect();
        self.seats
            .iter()
            .map(|seat| segment[seat.segment] * self.profile(seat))
            .collect()
    }

    /// The laminar profile's share of the centreline speed at `seat`'s radius: 1 − (r/R)².
    fn profile(&self, seat: &Seat) -> f64 {
        let rel = seat.radius / (0.5 * self.flow.segments[seat.segment].diameter);
        1.0 - rel * rel
    }

    /// Every scatterer's position (x, y, z) (m) at time `t` (s).
    fn positions(&self, t: f64) -> impl Iterator<Item = [f64; 3]> + '_ {
        let travelled: Vec<f64> = self
            .flow
            .segments
            .iter()
            .map(|s| s.centreline_displacement(t))
            .collect();
        self.seats
            .iter()
            .map(move |seat| self.position(seat, travelled[seat.segment]))
    }

    /// Position (x, y, z) (m) of the scatterer at `seat` once its segment's centreline has moved
    /// `travelled` (m).
    fn position(&self, seat: &Seat, travelled: f64) -> [f64; 3] {
        let s = &self.flow.segments[seat.segment];
        let chord = s.chord();
        let along = (seat.along + travelled * self.profile(seat)).rem_euclid(chord);
        let [u, n1, n2] = self.frames[seat.segment];
        let (sin, cos) = seat.angle.sin_cos();
        std::array::from_fn(|k| {
            s.start[k] + along * u[k] + seat.radius * (cos * n1[k] + sin * n2[k])
        })
    }

    /// The truth the imaging plane sees on the grid `x`, `z` (m) at time `t` (s), weighted over
    /// the elevation by `aperture`'s two-way echo power at wavelength `lambda` (m), or the plane
    /// itself when `aperture` is `None` (see the module docs).
    pub fn plane_truth(
        &self,
        x: &[f64],
        z: &[f64],
        t: f64,
        aperture: Option<(&ElevationAperture, f64)>,
    ) -> TreeTruth {
        self.plane_truths(x, z, &[t], aperture)
            .pop()
            .expect("one time, one truth")
    }

    /// [`TreePhantom::plane_truth`] at each of `times` (s): the elevation beam's weights, which
    /// do not change with time and cost most of the work, are computed once.
    pub fn plane_truths(
        &self,
        x: &[f64],
        z: &[f64],
        times: &[f64],
        aperture: Option<(&ElevationAperture, f64)>,
    ) -> Vec<TreeTruth> {
        // Elevations sampled every 10 µm over the tree and the whole beam (one sample, y = 0, in
        // two dimensions): the beam's weight outside the tree counts toward the pixel's total.
        let ys: Vec<f64> = match aperture {
            None => vec![0.0],
            Some((a, lambda)) => {
                let deepest = z.iter().cloned().fold(0.0, f64::max);
                let reach = self
                    .flow
                    .segments
                    .iter()
                    .flat_map(|s| [s.start[1].abs(), s.end[1].abs()].map(|y| y + 0.5 * s.diameter))
                    .fold(a.y_reach(lambda, deepest), f64::max);
                let n = (reach / 10e-6).ceil() as i64;
                (-n..=n).map(|i| i as f64 * 10e-6).collect()
            }
        };
        // Two-way echo power |G|⁴ at each (row, elevation), and its sum over the elevations.
        let weight: Vec<Vec<f64>> = z
            .par_iter()
            .map(|&zz| match aperture {
                None => vec![1.0],
                Some((a, lambda)) => ys
                    .iter()
                    .map(|&y| a.one_way(lambda, y, zz).norm_sqr().powi(2))
                    .collect(),
            })
            .collect();
        let totals: Vec<f64> = weight.iter().map(|w| w.iter().sum()).collect();
        times
            .par_iter()
            .map(|&t| self.accumulate(x, z, t, &ys, &weight, &totals))
            .collect()
    }

    /// The plane's truth at time `t` (s) from the elevations `ys` (m, ascending) and each
    /// row's beam `weight` over them (and its sum, `totals`).
    fn accumulate(
        &self,
        x: &[f64],
        z: &[f64],
        t: f64,
        ys: &[f64],
        weight: &[Vec<f64>],
        totals: &[f64],
    ) -> TreeTruth {
        let (nz, nx) = (z.len(), x.len());
        let mut acc = Accumulator::new(nz, nx, &self.flow.segments);
        for (id, s) in self.flow.segments.iter().enumerate() {
            let radius = 0.5 * s.diameter;
            let (lo, hi) = s.bounds();
            let columns = x
                .iter()
                .enumerate()
                .filter(|&(_, &v)| v >= lo[0] && v <= hi[0]);
            let columns: Vec<(usize, f64)> = columns.map(|(i, &v)| (i, v)).collect();
            // The elevations within the segment's reach (`ys` ascends): a capillary spans a few
            // of the hundreds the beam needs.
            let elevations =
                ys.partition_point(|&y| y < lo[1])..ys.partition_point(|&y| y <= hi[1]);
            for (iz, &zz) in z
                .iter()
                .enumerate()
                .filter(|&(_, &v)| v >= lo[2] && v <= hi[2])
            {
                for &(ix, xx) in &columns {
                    for iy in elevations.clone() {
                        let y = ys[iy];
                        let p = [xx, y, zz];
                        if let Some((_, r)) = s.local(&p) {
                            let w = weight[iz][iy];
                            let profile = 1.0 - (r / radius).powi(2);
                            let v = s.velocity_at(&p, t).expect("inside the segment");
                            acc.add(iz, ix, id, w, v, profile);
                        }
                    }
                }
            }
        }
        acc.finish(&self.flow.segments, totals)
    }
}

/// The truth of a tree on a pixel grid, each array of shape (nz, nx).
#[derive(Debug, Clone, PartialEq)]
pub struct TreeTruth {
    /// In-plane velocity and the flow mask (any blood in the pixel's beam).
    pub truth: Truth,
    /// Out-of-plane velocity (m/s), > 0 toward +y.
    pub vy: Array2<f64>,
    /// Share of the pixel's elevation weight that is blood, in [0, 1].
    pub blood_fraction: Array2<f64>,
    /// PSV, EDV, RI, class and segment of the blood each pixel sees most of.
    pub cycle: NetworkTruth,
}

/// Sums over the elevation samples of each pixel.
struct Accumulator {
    blood: Array2<f64>,
    velocity: [Array2<f64>; 3],
    profile: Array2<f64>,
    /// Blood weight per class ([`crate::simulate::vascular::VesselClass::index`]).
    class_blood: [Array2<f64>; 3],
    /// Each segment's class index.
    classes: Vec<usize>,
    /// Per pixel, the segment holding most weight and that weight, as segments are visited.
    best: Array2<(usize, f64)>,
    /// Per pixel, the weight of the segment being visited (segments are visited one at a time).
    current: Array2<(usize, f64)>,
}

impl Accumulator {
    fn new(nz: usize, nx: usize, segments: &[SegmentFlow]) -> Self {
        let zeros = || Array2::<f64>::zeros((nz, nx));
        Accumulator {
            blood: zeros(),
            velocity: [zeros(), zeros(), zeros()],
            profile: zeros(),
            class_blood: [zeros(), zeros(), zeros()],
            classes: segments.iter().map(|s| s.class.index()).collect(),
            best: Array2::from_elem((nz, nx), (usize::MAX, 0.0)),
            current: Array2::from_elem((nz, nx), (usize::MAX, 0.0)),
        }
    }

    fn add(&mut self, iz: usize, ix: usize, id: usize, w: f64, v: [f64; 3], profile: f64) {
        self.blood[[iz, ix]] += w;
        self.class_blood[self.classes[id]][[iz, ix]] += w;
        for (acc, v) in self.velocity.iter_mut().zip(v) {
            acc[[iz, ix]] += w * v;
        }
        self.profile[[iz, ix]] += w * profile;
        let current = &mut self.current[[iz, ix]];
        if current.0 != id {
            *current = (id, 0.0);
        }
        current.1 += w;
        let best = &mut self.best[[iz, ix]];
        if current.1 > best.1 {
            *best = *current;
        }
    }

    fn finish(self, segments: &[SegmentFlow], totals: &[f64]) -> TreeTruth {
        let (nz, nx) = self.blood.dim();
        let mut truth = Truth::empty(nz, nx);
        let mut vy = Array2::zeros((nz, nx));
        let mut fraction = Array2::zeros((nz, nx));
        let mut cycle = NetworkTruth {
            psv: Array2::zeros((nz, nx)),
            edv: Array2::zeros((nz, nx)),
            ri: Array2::zeros((nz, nx)),
            vessel_class: Array2::from_elem((nz, nx), BACKGROUND),
            flow_up: Array2::from_elem((nz, nx), false),
            vessel_index: Array2::from_elem((nz, nx), usize::MAX),
            class_share: Array2::zeros((nz, nx)),
            axis_profile: Array2::zeros((nz, nx)),
        };
        for ((iz, ix), &blood) in self.blood.indexed_iter() {
            if blood <= 0.0 {
                continue;
            }
            truth.mask[[iz, ix]] = true;
            truth.vx[[iz, ix]] = self.velocity[0][[iz, ix]] / blood;
            vy[[iz, ix]] = self.velocity[1][[iz, ix]] / blood;
            truth.vz[[iz, ix]] = self.velocity[2][[iz, ix]] / blood;
            fraction[[iz, ix]] = (blood / totals[iz]).min(1.0);
            let (id, _) = self.best[[iz, ix]];
            let s = &segments[id];
            let profile = self.profile[[iz, ix]] / blood;
            cycle.psv[[iz, ix]] = s.pulsatility.psv * profile;
            cycle.edv[[iz, ix]] = s.pulsatility.edv * profile;
            cycle.ri[[iz, ix]] = s.pulsatility.ri;
            cycle.vessel_class[[iz, ix]] = s.class.code();
            // Toward the probe: the mean flow runs to smaller depths.
            let dz = s.end[2] - s.start[2];
            cycle.flow_up[[iz, ix]] = s.mean_flow * dz < 0.0;
            cycle.vessel_index[[iz, ix]] = id;
            cycle.class_share[[iz, ix]] = self.class_blood[self.classes[id]][[iz, ix]] / blood;
            cycle.axis_profile[[iz, ix]] = profile;
        }
        TreeTruth {
            truth,
            vy,
            blood_fraction: fraction,
            cycle,
        }
    }
}

impl Phantom for TreePhantom {
    fn amplitudes(&self) -> &[f64] {
        &self.amplitudes
    }

    fn positions_at(&self, t: f64, out: &mut Vec<[f64; 2]>) {
        out.clear();
        out.extend(self.positions(t).map(|p| [p[0], p[2]]));
    }

    fn elevations_at(&self, t: f64, out: &mut Vec<f64>) {
        out.clear();
        out.extend(self.positions(t).map(|p| p[1]));
    }

    /// The imaging plane's own cut through the tree (y = 0); [`TreePhantom::plane_truth`] gives
    /// the elevation-weighted truth.
    fn truth(&self, x: &[f64], z: &[f64], t: f64) -> Truth {
        self.plane_truth(x, z, t, None).truth
    }
}

/// The unit axis `u` and two unit normals completing a right-handed frame.
fn axes(u: [f64; 3]) -> [[f64; 3]; 3] {
    // Cross with the coordinate axis least aligned with u: never near-parallel.
    let pick = if u[0].abs() <= u[1].abs() && u[0].abs() <= u[2].abs() {
        [1.0, 0.0, 0.0]
    } else if u[1].abs() <= u[2].abs() {
        [0.0, 1.0, 0.0]
    } else {
        [0.0, 0.0, 1.0]
    };
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let n1 = cross(u, pick);
    let len = (n1[0] * n1[0] + n1[1] * n1[1] + n1[2] * n1[2]).sqrt();
    let n1 = n1.map(|v| v / len);
    [u, n1, cross(u, n1)]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate::vascular::{
        Boundary, BoundaryKind, Edge, FlowParams, VesselClass, VesselGraph, solve,
    };

    /// One 60 µm arteriole from `a` to `b` (m), driven by a pulsatile pressure drop.
    fn vessel(a: [f64; 3], b: [f64; 3]) -> VascularFlow {
        let graph = VesselGraph::single_vessel(
            a,
            b,
            60e-6,
            VesselClass::Arteriole,
            (1500.0, 800.0),
            1400.0,
        );
        solve(&graph, &FlowParams::rat()).unwrap()
    }

    #[test]
    fn scatterers_move_with_the_laminar_flow_and_carry_the_bloods_power() {
        let flow = vessel([-1e-3, 0.1e-3, 3e-3], [1e-3, -0.1e-3, 4e-3]);
        let tree = TreePhantom::new(flow, TreeSpec::default_blood(), 3).unwrap();
        let s = &tree.flow().segments[0];
        let volume = s.area() * s.chord();
        // 10⁵/mm³ over 6.4·10⁻³ mm³: 636 scatterers, more than the 40 per mm floor (89).
        assert_eq!(tree.n_scatterers(), (1e14 * volume).ceil() as usize);
        let power: f64 = tree.amplitudes().iter().map(|a| a * a).sum::<f64>() / volume;
        // A sum of 636 squared Gaussians: relative SD √(2/636) = 5.6 %; 4 SD.
        assert!((power / 1e9 - 1.0).abs() < 0.23, "{power:e}");
        // Each scatterer moves at the laminar velocity where it is (away from the ends, where
        // it wraps around).
        let (t, h) = (0.031, 1e-6);
        let before: Vec<[f64; 3]> = tree.positions(t - h).collect();
        let after: Vec<[f64; 3]> = tree.positions(t + h).collect();
        let mut checked = 0;
        for (p0, p1) in before.iter().zip(&after) {
            let mid: [f64; 3] = std::array::from_fn(|k| 0.5 * (p0[k] + p1[k]));
            let moved: f64 = (0..3).map(|k| (p1[k] - p0[k]).powi(2)).sum::<f64>().sqrt();
            if moved > 1e-6 {
                continue; // wrapped around an end
            }
            let v = s.velocity_at(&mid, t).expect("inside");
            for k in 0..3 {
                let numeric = (p1[k] - p0[k]) / (2.0 * h);
                assert!((numeric - v[k]).abs() < 1e-6 * s.pulsatility.psv.max(1e-3));
            }
            checked += 1;
        }
        assert!(checked > 600);
    }

    #[test]
    fn a_vessel_crossing_the_plane_shows_its_speed_out_of_the_plane() {
        // Straight along y through (0.2 mm, 5 mm): the plane sees only vy, the centreline speed
        // at its centre (r = 0 all along y); its 1 mm holds nearly all the beam's two-way echo
        // power (|G|⁴ falls fast off the axis) but not its tails.
        let flow = vessel([0.2e-3, -0.5e-3, 5e-3], [0.2e-3, 0.5e-3, 5e-3]);
        let tree = TreePhantom::new(flow, TreeSpec::default_blood(), 1).unwrap();
        let x = [0.2e-3, 0.22e-3, 0.5e-3];
        let z = [5e-3];
        let aperture = ElevationAperture::l22_14vx();
        let t = 0.05;
        let truth = tree.plane_truth(&x, &z, t, Some((&aperture, 1540.0 / 15.625e6)));
        let s = &tree.flow().segments[0];
        assert!(truth.truth.mask[[0, 0]] && truth.truth.mask[[0, 1]] && !truth.truth.mask[[0, 2]]);
        assert!(
            (truth.vy[[0, 0]] - s.centreline_speed(t)).abs() < 1e-9 * s.centreline_speed(t).abs()
        );
        assert_eq!(truth.truth.vx[[0, 0]], 0.0);
        assert_eq!(truth.truth.vz[[0, 0]], 0.0);
        // 20 µm off the axis of a 30 µm-radius vessel: (1 − (2/3)²) of the centreline speed.
        let expected = s.centreline_speed(t) * (1.0 - (20.0f64 / 30.0).powi(2));
        assert!((truth.vy[[0, 1]] - expected).abs() < 1e-6 * expected.abs());
        let f = truth.blood_fraction[[0, 0]];
        assert!(f > 0.95 && f < 1.0, "blood fraction {f}");
        assert_eq!(truth.cycle.vessel_index[[0, 0]], 0);
        assert_eq!(
            truth.cycle.vessel_class[[0, 0]],
            crate::core::vessel::ARTERIOLE
        );
        assert_eq!(truth.cycle.ri[[0, 0]], s.pulsatility.ri);
        // In two dimensions the plane cuts the vessel at y = 0: the same centre pixel.
        let flat = tree.plane_truth(&x, &z, t, None);
        assert!(flat.truth.mask[[0, 0]]);
        assert_eq!(flat.blood_fraction[[0, 0]], 1.0);
    }

    #[test]
    fn an_artery_and_a_vein_in_one_beam_share_its_blood_by_the_beams_weight_on_each() {
        // A 60 µm artery and an 80 µm vein along x at one depth, 0.105 mm either side of the
        // plane in elevation, as the pial and basal pairs run: every pixel on their axis holds
        // both, and each holds the beam's two-way power over its lumen's chord in y (no
        // elevation sample falls on a wall).
        let (z, y) = (4e-3, 0.105e-3);
        let pressure = |vertex, value, pulse| Boundary {
            vertex,
            kind: BoundaryKind::Pressure,
            value,
            pulse,
        };
        let edge = |v1, v2, diameter, class| Edge {
            v1,
            v2,
            diameter,
            length: None,
            class,
        };
        let graph = VesselGraph {
            vertices: vec![[-1e-3, -y, z], [1e-3, -y, z], [-1e-3, y, z], [1e-3, y, z]],
            edges: vec![
                edge(0, 1, 60e-6, VesselClass::Arteriole),
                edge(3, 2, 80e-6, VesselClass::Venule),
            ],
            boundaries: vec![
                pressure(0, 1500.0, 800.0),
                pressure(1, 1400.0, 0.0),
                pressure(3, 1450.0, 0.0),
                pressure(2, 1400.0, 0.0),
            ],
        };
        let flow = solve(&graph, &FlowParams::rat()).unwrap();
        let tree = TreePhantom::new(flow, TreeSpec::default_blood(), 1).unwrap();
        let aperture = ElevationAperture::l22_14vx();
        let seen = tree.plane_truth(&[0.0], &[z], 0.0, Some((&aperture, 1540.0 / 15.625e6)));
        assert_eq!(seen.cycle.vessel_class[[0, 0]], crate::core::vessel::VENULE);
        // The beam's weight on the 10 µm elevation samples within each lumen.
        let lambda = 1540.0 / 15.625e6;
        let within = |centre: f64, radius: f64| -> f64 {
            (-40..=40)
                .map(|i| i as f64 * 10e-6)
                .filter(|yy| (yy - centre).abs() <= radius)
                .map(|yy| aperture.one_way(lambda, yy, z).norm_sqr().powi(2))
                .sum()
        };
        let (vein, artery) = (within(y, 40e-6), within(-y, 30e-6));
        let share = seen.cycle.class_share[[0, 0]];
        let expected = vein / (vein + artery);
        assert!(
            (share - expected).abs() < 1e-9,
            "vein's share {share}, not {expected}"
        );
        // The truth names the vessel holding most of the blood: the share is a majority.
        assert!(share > 0.5 && share < 1.0, "{share}");
        // Off both vessels: no blood, no share.
        let away = tree.plane_truth(
            &[0.0],
            &[z + 1e-3],
            0.0,
            Some((&aperture, 1540.0 / 15.625e6)),
        );
        assert_eq!(away.cycle.class_share[[0, 0]], 0.0);
    }

    #[test]
    fn a_vessel_in_the_plane_has_its_in_plane_velocity() {
        let flow = vessel([-1e-3, 0.0, 4e-3], [1e-3, 0.0, 5e-3]);
        let tree = TreePhantom::new(flow, TreeSpec::default_blood(), 1).unwrap();
        let s = &tree.flow().segments[0];
        let t = 0.02;
        let truth = tree.plane_truth(&[0.0], &[4.5e-3], t, None);
        let speed = s.centreline_speed(t);
        let u = s.direction();
        // On the axis, and half a radius across it in the plane: 1 − (r/R)².
        assert!((truth.cycle.axis_profile[[0, 0]] - 1.0).abs() < 1e-12);
        let across = 0.25 * s.diameter;
        let off = tree.plane_truth(&[-across * u[2]], &[4.5e-3 + across * u[0]], t, None);
        assert!(
            (off.cycle.axis_profile[[0, 0]] - 0.75).abs() < 1e-9,
            "{}",
            off.cycle.axis_profile[[0, 0]]
        );
        assert!((truth.truth.vx[[0, 0]] - speed * u[0]).abs() < 1e-9 * speed.abs());
        assert!((truth.truth.vz[[0, 0]] - speed * u[2]).abs() < 1e-9 * speed.abs());
        assert_eq!(truth.vy[[0, 0]], 0.0);
        // Seen through the beam, the 60 µm lumen is a small share of the pixel's elevation
        // weight, and its velocity the cross-section's beam-weighted mean: below the
        // centreline speed, above the cross-section mean (the beam favours the middle).
        let aperture = ElevationAperture::l22_14vx();
        let seen = tree.plane_truth(&[0.0], &[4.5e-3], t, Some((&aperture, 1540.0 / 15.625e6)));
        let f = seen.blood_fraction[[0, 0]];
        assert!(f > 0.01 && f < 0.3, "blood fraction {f}");
        let along = seen.truth.vx[[0, 0]] / u[0];
        assert!(
            along.abs() < speed.abs() && along.abs() > 0.5 * speed.abs(),
            "{along} of {speed}"
        );
    }
}
