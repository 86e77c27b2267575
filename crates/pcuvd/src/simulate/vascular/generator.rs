//! A rule-based vascular tree of a coronal slab of rat cortex: a pial artery and a pial vein on
//! the surface, penetrating arterioles and ascending venules leaving them at near-normal
//! incidence and branching by Murray's law, joined at depth by a coarse capillary bed.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::graph::{Boundary, BoundaryKind, Edge, VesselClass, VesselGraph, distance};
use crate::core::error::{Result, invalid, require_positive, require_range};

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
        for (name, (lo, hi)) in [
            ("arteriole diameter", self.arteriole_diameter),
            ("venule diameter", self.venule_diameter),
        ] {
            require_positive(name, lo)?;
            require_range(name, hi, (lo, 1e-3), "m")?;
        }
        require_positive("capillary diameter", self.capillary_diameter)?;
        if self.branchings > 10 {
            return Err(invalid(
                "branchings",
                format!("at most 10, got {}", self.branchings),
            ));
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

/// A penetrating tree under construction: its vertices from the surface down, and terminals.
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
        top: usize,
        class: VesselClass,
    ) -> Tree {
        let (lo, hi) = match class {
            VesselClass::Venule => p.venule_diameter,
            _ => p.arteriole_diameter,
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
            let v = [tx.tan(), ty.tan(), 1.0];
            let n = (v[0] * v[0] + v[1] * v[1] + 1.0).sqrt();
            [v[0] / n, v[1] / n, v[2] / n]
        };
        let depth = p.thickness * rng.random_range(0.5..0.9);
        let n_seg = p.branchings + 1;
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
                    here[2] + rng.random_range(0.2..0.6) * reach,
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
/// nearest venule terminals through capillary paths. Surface vessels obey Murray's law too.
pub fn generate(params: &CortexParams) -> Result<VesselGraph> {
    params.validate()?;
    let p = params;
    let mut rng = ChaCha8Rng::seed_from_u64(p.seed);
    let mut b = Builder {
        graph: VesselGraph::default(),
        half_y: 0.45 * p.slab_thickness,
    };
    let x0 = -0.5 * p.width;
    let n_pairs = ((p.width - 0.5 * p.spacing) / p.spacing).floor() as usize;
    let (ya, yv) = (-0.2 * p.slab_thickness, 0.2 * p.slab_thickness);
    let z = p.surface_depth;

    let artery_inlet = b.vertex([x0, ya, z]);
    let vein_outlet = b.vertex([x0, yv, z]);
    let mut arterioles = vec![];
    let mut venules = vec![];
    for i in 0..n_pairs {
        let xa = x0 + (i as f64 + 0.5) * p.spacing;
        let top = b.vertex([xa, ya, z]);
        arterioles.push(b.penetrating(&mut rng, p, top, VesselClass::Arteriole));
        let top = b.vertex([xa + 0.5 * p.spacing, yv, z]);
        venules.push(b.penetrating(&mut rng, p, top, VesselClass::Venule));
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
                b.edge(prev, t.top, d3.cbrt(), class);
            } else {
                b.edge(t.top, prev, d3.cbrt(), class);
            }
            prev = t.top;
        }
    }

    let venule_terminals: Vec<usize> = venules.iter().flat_map(|t| t.terminals.clone()).collect();
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
        let order = nearest(&b, a, &venule_terminals);
        for &j in order.iter().take(p.capillaries_per_terminal) {
            b.capillary(&mut rng, p, a, venule_terminals[j]);
            drained[j] = true;
        }
    }
    // A venule terminal that no arteriole reached would be a stagnant dead end.
    for (j, &v) in venule_terminals.iter().enumerate() {
        if !drained[j] {
            let a = arteriole_terminals[nearest(&b, v, &arteriole_terminals)[0]];
            b.capillary(&mut rng, p, a, v);
        }
    }

    b.graph.boundaries = vec![
        Boundary {
            vertex: artery_inlet,
            kind: BoundaryKind::Pressure,
            value: p.inlet_pressure,
            pulse: p.inlet_pulse,
        },
        Boundary {
            vertex: vein_outlet,
            kind: BoundaryKind::Pressure,
            value: p.outlet_pressure,
            pulse: 0.0,
        },
    ];
    b.graph.validate()?;
    Ok(b.graph)
}
