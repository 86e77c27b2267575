//! The vessel graph: vertices, segments with a class, boundary conditions, and the checks that
//! a flow solve needs before it can be trusted.

use crate::core::error::{Result, invalid};
pub use crate::core::vessel::CAPILLARY;
use crate::core::vessel::{ARTERIOLE, VENULE};

/// Anatomical class of a segment: it sets the truth class code and the default compliance.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum VesselClass {
    /// Artery or arteriole (pial artery, penetrating arteriole and its branches).
    Arteriole,
    /// Capillary (the bed joining arterioles to venules).
    Capillary,
    /// Vein or venule (ascending venule, pial vein).
    Venule,
}

impl VesselClass {
    /// All classes, in the order of [`VesselClass::index`].
    pub const ALL: [VesselClass; 3] = [
        VesselClass::Arteriole,
        VesselClass::Capillary,
        VesselClass::Venule,
    ];

    /// Truth class code: [`ARTERIOLE`] (1), [`VENULE`] (2) or [`CAPILLARY`] (4).
    pub fn code(self) -> u8 {
        match self {
            VesselClass::Arteriole => ARTERIOLE,
            VesselClass::Capillary => CAPILLARY,
            VesselClass::Venule => VENULE,
        }
    }

    /// Position of the class in per-class parameter arrays (0 arteriole, 1 capillary, 2 venule).
    pub fn index(self) -> usize {
        match self {
            VesselClass::Arteriole => 0,
            VesselClass::Capillary => 1,
            VesselClass::Venule => 2,
        }
    }

    /// The name written in edge tables: `arteriole`, `capillary` or `venule`.
    pub fn name(self) -> &'static str {
        match self {
            VesselClass::Arteriole => "arteriole",
            VesselClass::Capillary => "capillary",
            VesselClass::Venule => "venule",
        }
    }

    /// The class named `s` (`arteriole`/`artery`, `capillary`, `venule`/`vein`, any case).
    pub fn from_name(s: &str) -> Option<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "arteriole" | "artery" => Some(VesselClass::Arteriole),
            "capillary" => Some(VesselClass::Capillary),
            "venule" | "vein" => Some(VesselClass::Venule),
            _ => None,
        }
    }
}

/// What a boundary condition fixes at its vertex.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BoundaryKind {
    /// The vertex's pressure (Pa).
    Pressure,
    /// The flow entering the network at the vertex (m³/s; negative leaves it).
    Inflow,
}

/// A boundary condition at one vertex: a mean value plus an optional cardiac pulse.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Boundary {
    /// Index of the vertex it applies to.
    pub vertex: usize,
    /// Pressure (Pa) or inflow (m³/s).
    pub kind: BoundaryKind,
    /// Mean over a beat (Pa or m³/s).
    pub value: f64,
    /// Peak-to-trough swing over a beat (Pa or m³/s) of the cardiac pulse shape; 0 is steady
    /// (e.g. a venous outlet).
    pub pulse: f64,
}

/// One straight vessel segment between two vertices.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Edge {
    /// Index of its first vertex; positive flow runs from `v1` to `v2`.
    pub v1: usize,
    /// Index of its second vertex.
    pub v2: usize,
    /// Lumen diameter (m).
    pub diameter: f64,
    /// Hydraulic length (m), e.g. of a tortuous vessel; `None` is the straight distance.
    pub length: Option<f64>,
    /// Anatomical class.
    pub class: VesselClass,
}

/// A vessel network: vertices (m), segments, boundary conditions.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct VesselGraph {
    /// Vertex positions (x lateral, y elevation out of the imaging plane, z depth into the
    /// tissue) (m).
    pub vertices: Vec<[f64; 3]>,
    /// Segments.
    pub edges: Vec<Edge>,
    /// Boundary conditions, at most one per vertex; every other vertex conserves flow.
    pub boundaries: Vec<Boundary>,
}

impl VesselGraph {
    /// One vessel of `diameter` (m) and `class` from `start` to `end` (m), driven by an inlet
    /// pressure at `start` of mean and peak-to-trough `inlet` = (mean, pulse) (Pa) into a steady
    /// `outlet` pressure (Pa) at `end`.
    pub fn single_vessel(
        start: [f64; 3],
        end: [f64; 3],
        diameter: f64,
        class: VesselClass,
        inlet: (f64, f64),
        outlet: f64,
    ) -> Self {
        let pressure = |vertex, value, pulse| Boundary {
            vertex,
            kind: BoundaryKind::Pressure,
            value,
            pulse,
        };
        VesselGraph {
            vertices: vec![start, end],
            edges: vec![Edge {
                v1: 0,
                v2: 1,
                diameter,
                length: None,
                class,
            }],
            boundaries: vec![pressure(0, inlet.0, inlet.1), pressure(1, outlet, 0.0)],
        }
    }

    /// Straight distance between the ends of edge `e` (m); NaN when an end index is dangling.
    pub fn chord(&self, e: &Edge) -> f64 {
        match (self.vertices.get(e.v1), self.vertices.get(e.v2)) {
            (Some(a), Some(b)) => distance(a, b),
            _ => f64::NAN,
        }
    }

    /// Hydraulic length of edge `e` (m): its given length, else the straight distance.
    pub fn length(&self, e: &Edge) -> f64 {
        e.length.unwrap_or_else(|| self.chord(e))
    }

    /// Per vertex, the index in [`VesselGraph::boundaries`] of its boundary condition, if any
    /// (a duplicate keeps the first; [`VesselGraph::validate`] refuses duplicates).
    pub fn boundary_index(&self) -> Vec<Option<usize>> {
        let mut out = vec![None; self.vertices.len()];
        for (i, b) in self.boundaries.iter().enumerate() {
            if let Some(slot) = out.get_mut(b.vertex) {
                slot.get_or_insert(i);
            }
        }
        out
    }

    /// Checks that a flow solve is well posed and names the first thing that is not: finite
    /// positions, valid edge ends and sizes, one boundary condition per vertex at most, no vertex
    /// without an edge, and a pressure condition in every connected part (else its pressure
    /// level is undefined).
    pub fn validate(&self) -> Result<()> {
        let n = self.vertices.len();
        if self.edges.is_empty() {
            return Err(invalid("vessel graph", "has no edge"));
        }
        for (i, p) in self.vertices.iter().enumerate() {
            if !p.iter().all(|v| v.is_finite()) {
                return Err(invalid(
                    "vessel graph",
                    format!("vertex {i} has a non-finite position {p:?} (m)"),
                ));
            }
        }
        let mut degree = vec![0usize; n];
        for (i, e) in self.edges.iter().enumerate() {
            for v in [e.v1, e.v2] {
                if v >= n {
                    return Err(invalid(
                        "vessel graph",
                        format!("edge {i} refers to vertex {v}, but there are {n} vertices"),
                    ));
                }
            }
            if e.v1 == e.v2 {
                return Err(invalid(
                    "vessel graph",
                    format!("edge {i} joins vertex {} to itself", e.v1),
                ));
            }
            if !(e.diameter.is_finite() && e.diameter > 0.0) {
                return Err(invalid(
                    "vessel graph",
                    format!(
                        "edge {i} has diameter {:e} m; it must be finite and > 0",
                        e.diameter
                    ),
                ));
            }
            // A segment needs a direction for its velocity vector, so its ends must differ even
            // when a hydraulic length is given.
            let chord = self.chord(e);
            if chord.is_nan() || chord <= 0.0 {
                return Err(invalid(
                    "vessel graph",
                    format!(
                        "edge {i}: vertices {} and {} are at the same place, so it has no direction",
                        e.v1, e.v2
                    ),
                ));
            }
            if let Some(l) = e.length
                && !(l.is_finite() && l > 0.0)
            {
                return Err(invalid(
                    "vessel graph",
                    format!("edge {i} has length {l:e} m; it must be finite and > 0"),
                ));
            }
            degree[e.v1] += 1;
            degree[e.v2] += 1;
        }
        let mut seen = vec![None; n];
        for (i, b) in self.boundaries.iter().enumerate() {
            if b.vertex >= n {
                return Err(invalid(
                    "boundary conditions",
                    format!(
                        "condition {i} refers to vertex {}, but there are {n} vertices",
                        b.vertex
                    ),
                ));
            }
            if !(b.value.is_finite() && b.pulse.is_finite()) {
                return Err(invalid(
                    "boundary conditions",
                    format!(
                        "condition {i} (vertex {}) has a non-finite value {} or pulse {}",
                        b.vertex, b.value, b.pulse
                    ),
                ));
            }
            if let Some(first) = seen[b.vertex].replace(i) {
                return Err(invalid(
                    "boundary conditions",
                    format!(
                        "vertex {} has two conditions ({first} and {i}); give it one",
                        b.vertex
                    ),
                ));
            }
        }
        if let Some(v) = degree.iter().position(|&d| d == 0) {
            return Err(invalid(
                "vessel graph",
                format!("vertex {v} belongs to no edge"),
            ));
        }
        let root = self.components();
        let mut has_pressure = vec![false; n];
        for b in &self.boundaries {
            if b.kind == BoundaryKind::Pressure {
                has_pressure[root[b.vertex]] = true;
            }
        }
        if let Some(v) = (0..n).find(|&v| !has_pressure[root[v]]) {
            let size = root.iter().filter(|&&r| r == root[v]).count();
            return Err(invalid(
                "boundary conditions",
                format!(
                    "the {size} connected vertices that include vertex {v} have no pressure \
                     condition, so their pressure is undefined; give one of them a pressure"
                ),
            ));
        }
        Ok(())
    }

    /// Per vertex, a representative of its connected part (union–find over valid edges).
    fn components(&self) -> Vec<usize> {
        let n = self.vertices.len();
        let mut parent: Vec<usize> = (0..n).collect();
        fn find(parent: &mut [usize], mut v: usize) -> usize {
            while parent[v] != v {
                parent[v] = parent[parent[v]];
                v = parent[v];
            }
            v
        }
        for e in &self.edges {
            if e.v1 < n && e.v2 < n {
                let (a, b) = (find(&mut parent, e.v1), find(&mut parent, e.v2));
                parent[a] = b;
            }
        }
        (0..n).map(|v| find(&mut parent, v)).collect()
    }
}

/// Euclidean distance between two points (m).
pub(crate) fn distance(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    let d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tube() -> VesselGraph {
        VesselGraph {
            vertices: vec![[0.0, 0.0, 1e-3], [0.0, 0.0, 2e-3]],
            edges: vec![Edge {
                v1: 0,
                v2: 1,
                diameter: 20e-6,
                length: None,
                class: VesselClass::Arteriole,
            }],
            boundaries: vec![
                Boundary {
                    vertex: 0,
                    kind: BoundaryKind::Pressure,
                    value: 5000.0,
                    pulse: 0.0,
                },
                Boundary {
                    vertex: 1,
                    kind: BoundaryKind::Pressure,
                    value: 1000.0,
                    pulse: 0.0,
                },
            ],
        }
    }

    fn error(g: &VesselGraph) -> String {
        g.validate().unwrap_err().to_string()
    }

    #[test]
    fn length_defaults_to_the_distance() {
        let g = tube();
        g.validate().unwrap();
        assert!((g.length(&g.edges[0]) - 1e-3).abs() < 1e-18);
        let mut g = g;
        g.edges[0].length = Some(3e-3);
        assert_eq!(g.length(&g.edges[0]), 3e-3);
    }

    #[test]
    fn bad_graphs_are_refused_with_what_is_wrong() {
        let mut g = tube();
        g.edges[0].v2 = 7;
        assert!(error(&g).contains("vertex 7"), "{}", error(&g));
        let mut g = tube();
        g.edges[0].diameter = 0.0;
        assert!(error(&g).contains("diameter"), "{}", error(&g));
        let mut g = tube();
        g.edges[0].diameter = f64::NAN;
        assert!(error(&g).contains("diameter"), "{}", error(&g));
        let mut g = tube();
        g.edges[0].length = Some(-1.0);
        assert!(error(&g).contains("length"), "{}", error(&g));
        let mut g = tube();
        g.vertices[1] = g.vertices[0];
        assert!(error(&g).contains("same place"), "{}", error(&g));
        let mut g = tube();
        g.boundaries[1].vertex = 0;
        assert!(error(&g).contains("two conditions"), "{}", error(&g));
        let mut g = tube();
        g.boundaries[1].vertex = 9;
        assert!(error(&g).contains("vertex 9"), "{}", error(&g));
        let mut g = tube();
        g.vertices.push([1e-3, 0.0, 0.0]);
        assert!(
            error(&g).contains("vertex 2 belongs to no edge"),
            "{}",
            error(&g)
        );
        // A second tube with only inflow conditions: its pressure level is undefined.
        let mut g = tube();
        g.vertices.extend([[1e-3, 0.0, 1e-3], [1e-3, 0.0, 2e-3]]);
        g.edges.push(Edge {
            v1: 2,
            v2: 3,
            ..g.edges[0]
        });
        g.boundaries.push(Boundary {
            vertex: 2,
            kind: BoundaryKind::Inflow,
            value: 1e-12,
            pulse: 0.0,
        });
        let e = error(&g);
        assert!(e.contains("vertex 2") && e.contains("no pressure"), "{e}");
        assert!(VesselGraph::default().validate().is_err());
    }

    #[test]
    fn class_names_and_codes() {
        for c in VesselClass::ALL {
            assert_eq!(VesselClass::from_name(c.name()), Some(c));
        }
        assert_eq!(VesselClass::Arteriole.code(), ARTERIOLE);
        assert_eq!(VesselClass::Venule.code(), VENULE);
        assert_eq!(VesselClass::from_name(" Vein "), Some(VesselClass::Venule));
        assert_eq!(VesselClass::from_name("lymph"), None);
    }
}
