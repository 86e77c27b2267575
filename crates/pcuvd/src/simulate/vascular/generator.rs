//! A rule-based vascular tree of a coronal slab of rat cortex: a pial artery and a pial vein on
//! the surface, penetrating arterioles and ascending venules leaving them at near-normal
//! incidence and branching by Murray's law, joined at depth by a coarse capillary bed; and,
//! optionally, the deep brain below it: a basal artery and vein whose larger branches rise into
//! the thalamus and hippocampus and meet in a capillary bed of their own.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::graph::{Boundary, BoundaryKind, Edge, VesselClass, VesselGraph, distance};
use crate::core::error::{Result, invalid, require_positive, require_range};

/// Thickest slab along the elevation (m): a rat brain's extent. A slab metres thick spread the
/// vessels out of the elevation beam, and its tissue took minutes to simulate into noise.
pub const MAX_SLAB_THICKNESS: f64 = 20e-3;

/// Geometry, sizes and boundary pressures of a generated cortical slab (SI units).
#[derive(Debug, Clone, PartialEq)]
pub struct CortexParams {
    /// Depth of the cortical surface below the probe (m).
    pub surface_depth: f64,
    /// Cortical thickness (m); penetrating vessels reach 50–90 % of it.
    pub thickness: f64,
    /// Slab width along x, centred on x = 0 (m).
    pub width: f64,
    /// Slab thickness along y (elevation), centred on y = 0 (m); every vertex stays within 90 %.
    pub slab_thickness: f64,
    /// Distance between neighbouring penetrating arterioles along x (m); an ascending venule
    /// sits halfway between each pair.
    pub spacing: f64,
    /// Range of penetrating-arteriole diameters where they leave the surface (m).
    pub arteriole_diameter: (f64, f64),
    /// Range of ascending-venule diameters where they join the surface (m).
    pub venule_diameter: (f64, f64),
    /// Capillary diameter (m).
    pub capillary_diameter: f64,
    /// Side branches along each penetrating trunk.
    pub branchings: usize,
    /// Share of the parent's d³ that a side branch takes (Murray: the trunk keeps the rest).
    pub side_share: f64,
    /// Largest tilt of a penetrating trunk from the normal, in x and in y (degrees).
    pub max_tilt_deg: f64,
    /// Capillary paths from each arteriole terminal to its nearest venule terminals.
    pub capillaries_per_terminal: usize,
    /// Segments per capillary path.
    pub capillary_segments: usize,
    /// Mean pressure of the arterial inlet (Pa).
    pub inlet_pressure: f64,
    /// Peak-to-trough cardiac swing of the inlet pressure (Pa).
    pub inlet_pulse: f64,
    /// Steady venous outlet pressure (Pa).
    pub outlet_pressure: f64,
    /// Arteriole–venule pairs rising from the basal vessels into the deep brain, `spacing` apart
    /// and centred on x = 0; 0: none.
    pub deep_pairs: usize,
    /// Depth of the basal artery and vein the deep pairs leave (m).
    pub deep_depth: f64,
    /// How far the deep trunks rise above the basal vessels (m); each reaches 50–90 % of it.
    pub deep_reach: f64,
    /// Range of deep-arteriole diameters where they leave the basal artery (m).
    pub deep_arteriole_diameter: (f64, f64),
    /// Range of deep-venule diameters where they join the basal vein (m).
    pub deep_venule_diameter: (f64, f64),
    /// Side branches along each deep trunk: a larger vessel feeds a larger bed.
    pub deep_branchings: usize,
    /// Seed of the tilts, depths, diameters and jitter.
    pub seed: u64,
}

impl Default for CortexParams {
    /// A 10 mm × 0.5 mm slab of rat cortex 2 mm thick, 1 mm below the probe: arterioles every
    /// 0.6 mm (30–50 µm), venules (40–60 µm), 8 µm capillaries, three branchings, 5° tilt; inlet
    /// 35 mmHg mean with a 22 mmHg swing (a rigid tree would then carry RI 0.55 everywhere),
    /// outlet 10 mmHg: penetrating vessels stay below ~40 mm/s, under the rat sequence's
    /// Nyquist speed.
    fn default() -> Self {
        CortexParams {
            surface_depth: 1e-3,
            thickness: 2e-3,
            width: 10e-3,
            slab_thickness: 0.5e-3,
            spacing: 0.6e-3,
            arteriole_diameter: (30e-6, 50e-6),
            venule_diameter: (40e-6, 60e-6),
            capillary_diameter: 8e-6,
            branchings: 3,
            side_share: 0.3,
            max_tilt_deg: 5.0,
            capillaries_per_terminal: 2,
            capillary_segments: 3,
            inlet_pressure: 4666.0,
            inlet_pulse: 2950.0,
            outlet_pressure: 1333.0,
            deep_pairs: 0,
            deep_depth: 9e-3,
            deep_reach: 4e-3,
            deep_arteriole_diameter: (60e-6, 90e-6),
            deep_venule_diameter: (70e-6, 100e-6),
            deep_branchings: 8,
            seed: 0,
        }
    }
}

impl CortexParams {
    /// Checks every parameter.
    pub fn validate(&self) -> Result<()> {
        require_positive("cortical surface depth", self.surface_depth)?;
        require_positive("cortical thickness", self.thickness)?;
        require_positive("slab width", self.width)?;
        require_positive("slab thickness", self.slab_thickness)?;
        if self.slab_thickness > MAX_SLAB_THICKNESS {
            return Err(invalid(
                "slab thickness",
                format!(
                    "{:.1} mm: at most {:.0} mm, a rat brain's extent (the elevation beam sees a \
                     millimetre or two of it: vessels spread farther add time, not signal)",
                    self.slab_thickness * 1e3,
                    MAX_SLAB_THICKNESS * 1e3
                ),
            ));
        }
        require_positive("arteriole spacing", self.spacing)?;
        if self.width < 2.0 * self.spacing {
            return Err(invalid(
                "slab width",
                format!(
                    "{:.3} mm holds no arteriole–venule pair at a spacing of {:.3} mm",
                    self.width * 1e3,
                    self.spacing * 1e3
                ),
            ));
        }
        if self.width / self.spacing > 1000.0 {
            return Err(invalid(
                "arteriole spacing",
                "gives more than 1000 arterioles",
            ));
        }
        if self.deep_pairs > 0 {
            require_positive("deep reach", self.deep_reach)?;
            if self.deep_depth - self.deep_reach <= self.surface_depth + self.thickness {
                return Err(invalid(
                    "deep depth",
                    format!(
                        "deep trunks rising {:.2} mm from {:.2} mm would enter the cortex (down to {:.2} mm)",
                        self.deep_reach * 1e3,
                        self.deep_depth * 1e3,
                        (self.surface_depth + self.thickness) * 1e3
                    ),
                ));
            }
            if self.deep_pairs > 100 {
                return Err(invalid("deep pairs", "at most 100"));
            }
        }
        for (name, (lo, hi)) in [
            ("arteriole diameter", self.arteriole_diameter),
            ("venule diameter", self.venule_diameter),
            ("deep arteriole diameter", self.deep_arteriole_diameter),
            ("deep venule diameter", self.deep_venule_diameter),
        ] {
            require_positive(name, lo)?;
            require_range(name, hi, (lo, 1e-3), "m")?;
        }
        require_positive("capillary diameter", self.capillary_diameter)?;
        for (name, n) in [
            ("branchings", self.branchings),
            ("deep branchings", self.deep_branchings),
        ] {
            if n > 20 {
                return Err(invalid(name, format!("at most 20, got {n}")));
            }
        }
        require_range("side-branch share", self.side_share, (0.01, 0.99), "")?;
        require_range("tilt", self.max_tilt_deg, (0.0, 45.0), "°")?;
        if !(1..=8).contains(&self.capillaries_per_terminal) {
            return Err(invalid("capillaries per terminal", "must be 1 to 8"));
        }
        if !(1..=20).contains(&self.capillary_segments) {
            return Err(invalid("capillary segments", "must be 1 to 20"));
        }
        for (name, v) in [
            ("inlet pressure", self.inlet_pressure),
            ("inlet pulse", self.inlet_pulse),
            ("outlet pressure", self.outlet_pressure),
        ] {
            if !v.is_finite() {
                return Err(invalid(name, format!("must be finite, got {v}")));
            }
        }
        if self.inlet_pressure <= self.outlet_pressure {
            return Err(invalid(
                "inlet pressure",
                "must exceed the outlet pressure for blood to flow",
            ));
        }
        Ok(())
    }
}

/// Where a group of penetrating trunks starts and how it grows: the cortex's go down from the
/// surface, the deep brain's rise from the basal vessels.
struct Trunks {
    /// Full length of a trunk; each reaches 50–90 % of it.
    reach: f64,
    arteriole_diameter: (f64, f64),
    venule_diameter: (f64, f64),
    /// Side branches along a trunk.
    branchings: usize,
    /// +1: growing deeper; −1: rising.
    sense: f64,
}

/// A penetrating tree under construction: its vertices from its root on, and terminals.
struct Tree {
    top: usize,
    top_diameter: f64,
    terminals: Vec<usize>,
}

/// Builds graphs, adding vertices and edges.
struct Builder {
    graph: VesselGraph,
    half_y: f64,
}

impl Builder {
    fn vertex(&mut self, mut p: [f64; 3]) -> usize {
        p[1] = p[1].clamp(-self.half_y, self.half_y);
        self.graph.vertices.push(p);
        self.graph.vertices.len() - 1
    }

    fn edge(&mut self, v1: usize, v2: usize, diameter: f64, class: VesselClass) {
        self.graph.edges.push(Edge {
            v1,
            v2,
            diameter,
            length: None,
            class,
        });
    }

    /// A penetrating trunk from `top` (on the surface) with side branches; edges point down the
    /// tree for an arteriole (blood flows in) and up it for a venule (blood flows out), and every
    /// branching obeys Murray's law d³ = d_trunk³ + d_side³.
    fn penetrating(
        &mut self,
        rng: &mut ChaCha8Rng,
        p: &CortexParams,
        trunks: &Trunks,
        top: usize,
        class: VesselClass,
    ) -> Tree {
        let (lo, hi) = match class {
            VesselClass::Venule => trunks.venule_diameter,
            _ => trunks.arteriole_diameter,
        };
        let top_diameter = if hi > lo {
            rng.random_range(lo..hi)
        } else {
            lo
        };
        let tilt = p.max_tilt_deg.to_radians();
        let mut tx = 0.0;
        let mut ty = 0.0;
        if tilt > 0.0 {
            tx = rng.random_range(-tilt..tilt);
            ty = rng.random_range(-tilt..tilt);
        }
        let dir = {
            let v = [tx.tan(), ty.tan(), trunks.sense];
            let n = (v[0] * v[0] + v[1] * v[1] + 1.0).sqrt();
            [v[0] / n, v[1] / n, v[2] / n]
        };
        let depth = trunks.reach * rng.random_range(0.5..0.9);
        let n_seg = trunks.branchings + 1;
        let start = self.graph.vertices[top];
        let mut prev = top;
        let mut d = top_diameter;
        let mut terminals = vec![];
        let flow_in = class != VesselClass::Venule;
        let link = |b: &mut Builder, upper: usize, lower: usize, d: f64| {
            if flow_in {
                b.edge(upper, lower, d, class)
            } else {
                b.edge(lower, upper, d, class)
            }
        };
        for i in 1..=n_seg {
            let s = depth * i as f64 / n_seg as f64;
            let node = self.vertex([
                start[0] + s * dir[0],
                start[1] + s * dir[1],
                start[2] + s * dir[2],
            ]);
            link(self, prev, node, d);
            prev = node;
            if i < n_seg {
                let side = d * p.side_share.cbrt();
                d *= (1.0 - p.side_share).cbrt();
                let here = self.graph.vertices[node];
                let sx = if i % 2 == 1 { 1.0 } else { -1.0 };
                let reach = rng.random_range(0.1..0.2) * p.spacing / 0.6;
                let end = self.vertex([
                    here[0] + sx * reach,
                    here[1] + rng.random_range(-0.5..0.5) * reach,
                    here[2] + trunks.sense * rng.random_range(0.2..0.6) * reach,
                ]);
                link(self, node, end, side);
                terminals.push(end);
            }
        }
        terminals.push(prev);
        Tree {
            top,
            top_diameter,
            terminals,
        }
    }

    /// A group of `n_pairs` penetrating arteriole–venule pairs `spacing` apart from x = `first`,
    /// rooted at depth `z` on an artery and a vein that run along +x from x = −width/2, joined
    /// by capillaries; returns the artery's inlet and the vein's outlet.
    fn group(
        &mut self,
        rng: &mut ChaCha8Rng,
        p: &CortexParams,
        trunks: &Trunks,
        z: f64,
        n_pairs: usize,
        (first, spacing): (f64, f64),
    ) -> (usize, usize) {
        let x0 = -0.5 * p.width;
        let (ya, yv) = (-0.2 * p.slab_thickness, 0.2 * p.slab_thickness);
        let artery_inlet = self.vertex([x0, ya, z]);
        let vein_outlet = self.vertex([x0, yv, z]);
        let mut arterioles = vec![];
        let mut venules = vec![];
        for i in 0..n_pairs {
            let xa = first + i as f64 * spacing;
            let top = self.vertex([xa, ya, z]);
            arterioles.push(self.penetrating(rng, p, trunks, top, VesselClass::Arteriole));
            let top = self.vertex([xa + 0.5 * spacing, yv, z]);
            venules.push(self.penetrating(rng, p, trunks, top, VesselClass::Venule));
        }
        // Surface vessels: the segment upstream of (artery) or downstream of (vein) penetrating
        // vessel i carries all of vessels i.. , so by Murray's law its d³ is their sum.
        for (trees, class, end) in [
            (&arterioles, VesselClass::Arteriole, artery_inlet),
            (&venules, VesselClass::Venule, vein_outlet),
        ] {
            let mut sum = 0.0;
            let mut cubes: Vec<f64> = trees
                .iter()
                .rev()
                .map(|t| {
                    sum += t.top_diameter.powi(3);
                    sum
                })
                .collect();
            cubes.reverse();
            let mut prev = end;
            for (t, d3) in trees.iter().zip(cubes) {
                if class == VesselClass::Arteriole {
                    self.edge(prev, t.top, d3.cbrt(), class);
                } else {
                    self.edge(t.top, prev, d3.cbrt(), class);
                }
                prev = t.top;
            }
        }

        let venule_terminals: Vec<usize> =
            venules.iter().flat_map(|t| t.terminals.clone()).collect();
        let arteriole_terminals: Vec<usize> = arterioles
            .iter()
            .flat_map(|t| t.terminals.clone())
            .collect();
        let mut drained = vec![false; venule_terminals.len()];
        let nearest = |b: &Builder, from: usize, among: &[usize]| {
            let p0 = b.graph.vertices[from];
            let mut order: Vec<usize> = (0..among.len()).collect();
            order.sort_by(|&i, &j| {
                let di = distance(&p0, &b.graph.vertices[among[i]]);
                let dj = distance(&p0, &b.graph.vertices[among[j]]);
                di.total_cmp(&dj)
            });
            order
        };
        for &a in &arteriole_terminals {
            let order = nearest(self, a, &venule_terminals);
            for &j in order.iter().take(p.capillaries_per_terminal) {
                self.capillary(rng, p, a, venule_terminals[j]);
                drained[j] = true;
            }
        }
        // A venule terminal that no arteriole reached would be a stagnant dead end.
        for (j, &v) in venule_terminals.iter().enumerate() {
            if !drained[j] {
                let a = arteriole_terminals[nearest(self, v, &arteriole_terminals)[0]];
                self.capillary(rng, p, a, v);
            }
        }
        (artery_inlet, vein_outlet)
    }

    /// A capillary path of `n` segments from `a` to `b`, its inner vertices jittered.
    fn capillary(&mut self, rng: &mut ChaCha8Rng, p: &CortexParams, a: usize, b: usize) {
        let (pa, pb) = (self.graph.vertices[a], self.graph.vertices[b]);
        let jitter = 0.1 * distance(&pa, &pb);
        let mut prev = a;
        for i in 1..p.capillary_segments {
            let f = i as f64 / p.capillary_segments as f64;
            let mut q = [0.0; 3];
            for (k, q) in q.iter_mut().enumerate() {
                *q = pa[k] + f * (pb[k] - pa[k]) + rng.random_range(-1.0..1.0) * jitter;
            }
            let node = self.vertex(q);
            self.edge(prev, node, p.capillary_diameter, VesselClass::Capillary);
            prev = node;
        }
        self.edge(prev, b, p.capillary_diameter, VesselClass::Capillary);
    }
}

/// A cortical vascular tree from `params`, the same for the same parameters and seed: the pial
/// artery enters at x = −width/2 (pulsatile inlet pressure) and runs along +x on the surface,
/// the pial vein drains toward x = −width/2 (steady outlet pressure); each penetrating vessel is
/// tilted a few degrees, branches `branchings` times, and each arteriole terminal drains into its
/// nearest venule terminals through capillary paths. Surface vessels obey Murray's law too. With
/// `deep_pairs`, a basal artery and vein at `deep_depth` do the same for the deep brain, their
/// trunks rising toward the cortex, at the same inlet and outlet pressures.
pub fn generate(params: &CortexParams) -> Result<VesselGraph> {
    params.validate()?;
    let p = params;
    let mut rng = ChaCha8Rng::seed_from_u64(p.seed);
    let mut b = Builder {
        graph: VesselGraph::default(),
        half_y: 0.45 * p.slab_thickness,
    };
    let n_pairs = ((p.width - 0.5 * p.spacing) / p.spacing).floor() as usize;
    let z = p.surface_depth;

    let cortex = Trunks {
        reach: p.thickness,
        arteriole_diameter: p.arteriole_diameter,
        venule_diameter: p.venule_diameter,
        branchings: p.branchings,
        sense: 1.0,
    };
    let first = -0.5 * p.width + 0.5 * p.spacing;
    let (artery_inlet, vein_outlet) = b.group(&mut rng, p, &cortex, z, n_pairs, (first, p.spacing));
    let mut boundaries = vec![(artery_inlet, vein_outlet)];
    if p.deep_pairs > 0 {
        let deep = Trunks {
            reach: p.deep_reach,
            arteriole_diameter: p.deep_arteriole_diameter,
            venule_diameter: p.deep_venule_diameter,
            branchings: p.deep_branchings,
            sense: -1.0,
        };
        // As closely spaced as the cortex's, so that their capillaries are as short; centred.
        let first = -0.5 * p.deep_pairs as f64 * p.spacing;
        let ends = b.group(
            &mut rng,
            p,
            &deep,
            p.deep_depth,
            p.deep_pairs,
            (first, p.spacing),
        );
        boundaries.push(ends);
    }
    // Every inlet at the same arterial pressure, every outlet at the same venous one.
    b.graph.boundaries = boundaries
        .into_iter()
        .flat_map(|(inlet, outlet)| {
            [
                Boundary {
                    vertex: inlet,
                    kind: BoundaryKind::Pressure,
                    value: p.inlet_pressure,
                    pulse: p.inlet_pulse,
                },
                Boundary {
                    vertex: outlet,
                    kind: BoundaryKind::Pressure,
                    value: p.outlet_pressure,
                    pulse: 0.0,
                },
            ]
        })
        .collect();
    b.graph.validate()?;
    Ok(b.graph)
}
