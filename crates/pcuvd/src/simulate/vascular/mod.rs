//! A vascular tree and the blood flow in it: the physics core of a virtual rat-brain phantom.
//!
//! A [`VesselGraph`] holds vertices (m; x lateral, y elevation out of the imaging plane, z depth
//! into the tissue), straight segments (diameter, hydraulic length, class: arteriole, capillary,
//! venule) and boundary conditions (pressure or inflow, each a mean plus a cardiac pulse). It is
//! built by the rule-based cortical [`generate`] or read from the three tables of network
//! blood-flow solvers ([`parse_tables`]; a small example in [`example`]). [`solve`] gives each
//! segment its periodic flow, from which a phantom moves scatterers ([`SegmentFlow`]).
//!
//! # Model
//! * **Resistance** (Poiseuille): R = 128 μ L / (π d⁴) per segment, with a constant viscosity
//!   (Newtonian blood, 3.5 mPa·s) or the Fåhraeus–Lindqvist in-vitro law of Pries et al. (1992)
//!   ([`Viscosity`]), which lowers the apparent viscosity in vessels below ~300 µm.
//! * **Compliance**: each segment stores C = V / (ρ c²) (m³/Pa) per pascal — V its lumen
//!   volume, c a pulse-wave speed per class — half at each end vertex (a 0-D lumped model). A
//!   purely resistive network is linear and memoryless: every pressure and flow is an affine
//!   function of the one inlet pressure, so every segment carries the inlet's waveform shape and
//!   the same RI (tested). The compliances make the network a low-pass filter: the pulse falls
//!   and lags from arterioles through capillaries to venules, as measured in vivo.
//! * **Solve**: nodal pressures from conservation at every vertex without a boundary condition,
//!   once for the mean (conductances only) and once per cardiac harmonic k (admittance
//!   G + i k ω C), each a dense LU ([`MAX_UNKNOWNS`]). Boundary pressures and inflows are
//!   `value + pulse · s(t)`, s the swing-normalised [`CardiacPulse`] (three harmonics for the rat
//!   default), so the solution is exact for that band-limited beat.
//! * **Per segment**: flow q(t) = Q₀ + Σ Re(Qₖ e^{ikωt}), mean speed q / (π d²/4), a parabolic
//!   (laminar) profile whose centreline speed is twice the mean, and its closed-form integral for
//!   exact scatterer displacements. PSV, EDV and RI are the max and min over a beat of the
//!   centreline speed along the mean flow; the pulse delay is the lag of the flow's fundamental
//!   behind the inlet pulse's.
//!
//! # Default compliance, and why
//! In this model pulsatility can only fall downstream where volume is stored, and a compliant
//! segment also draws a capacitive current through everything upstream of it (its inflow is
//! *more* pulsatile). The rat default ([`FlowParams::rat`]) therefore puts the compliance where
//! it filters without making arterioles reverse: c = 20 m/s in arterioles (nearly rigid — the
//! arterial tree's compliance lies upstream, in the large arteries, and is already in the inlet
//! waveform), 2.5 m/s in capillaries (the coarse bed holds a small fraction of the real
//! capillary volume, so each of its segments stands for many and stores accordingly) and
//! 0.25 m/s in venules (veins are the most distensible vessels). These are tuned, not measured.
//! With the [`generate`] defaults (10 mm slab, 524 vertices; inlet swing set for a rigid-tree RI
//! of 0.55) they give RI (10th/50th/90th percentile) 0.62/0.69/0.83 in arterioles,
//! 0.55/0.57/0.63 in capillaries and 0.00/0.11/0.48 in venules — the paper's ranges (arterioles
//! 0.55–0.9, venules < 0.5) — with median pulse delays of −13 ms (arterioles lead the inlet
//! pressure: their flow feeds the downstream compliance), +4 ms (capillaries) and +33 ms
//! (venules).
//!
//! # Known limits of the coarse bed
//! Each generated capillary edge carries the flow of many real capillaries, so its speed
//! (median PSV ≈ 14 mm/s) is about ten times a real capillary's while the penetrating vessels'
//! (a few mm/s) are on the low side; a few arteriole segments near a strongly compliant bed may
//! reach RI ≈ 1.05 (flow briefly stopping or reversing in diastole).
//!
//! # Neglected
//! Blood inertia (no inductance: the Womersley number is ≪ 1 in vessels below 150 µm at 5.5 Hz,
//! so the profile stays parabolic at every instant), wave propagation and reflection (a segment
//! is much shorter than a pulse wavelength), the nonlinearity of the wall (C does not depend on
//! pressure), phase separation of red cells at junctions (one haematocrit everywhere), profile
//! blunting by red cells, and any active regulation of the diameters.

mod flow;
mod generator;
mod graph;
mod lookup;
mod tables;

pub use self::flow::{
    BLOOD_DENSITY, CardiacPulse, DEFAULT_VISCOSITY, FlowParams, MAX_UNKNOWNS, Pulsatility,
    SegmentFlow, VascularFlow, Viscosity, pries_relative_viscosity, solve,
};
pub use self::generator::{CortexParams, generate};
pub use self::graph::{Boundary, BoundaryKind, CAPILLARY, Edge, VesselClass, VesselGraph};
pub use self::lookup::LumenLookup;
pub use self::tables::{Tables, parse_tables, write_tables};

/// The shipped example's three tables (an arteriole splitting in two, a capillary mesh, a venule;
/// positions in µm, pressures in Pa).
pub fn example_tables() -> Tables {
    Tables {
        vertices: include_str!("example/vertices.csv").to_string(),
        edges: include_str!("example/edges.csv").to_string(),
        boundary: include_str!("example/boundary.csv").to_string(),
    }
}

/// The shipped example as a vessel graph (see [`example_tables`]).
pub fn example() -> VesselGraph {
    let t = example_tables();
    parse_tables(&t.vertices, &t.edges, &t.boundary).expect("the shipped example is valid")
}

#[cfg(test)]
mod tests;
