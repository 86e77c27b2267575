//! Blood flow in a [`VesselGraph`]: steady Poiseuille flow plus the cardiac pulse through a 0-D
//! compliant network, solved per harmonic in the frequency domain (see the module docs of
//! [`super`] for the model and what it neglects).

use faer::Mat;
use faer::linalg::solvers::Solve;
use num_complex::Complex64;

use super::graph::{BoundaryKind, VesselClass, VesselGraph};
use crate::core::error::{Error, Result, invalid, require_positive, require_range};

/// Default blood viscosity (Pa·s): whole blood at high shear, haematocrit ≈ 0.45.
pub const DEFAULT_VISCOSITY: f64 = 3.5e-3;
/// Blood density (kg/m³).
pub const BLOOD_DENSITY: f64 = 1050.0;
/// Largest number of vertices without a pressure condition that [`solve`] accepts: it factors a
/// dense complex matrix of that order per harmonic (3000 → 144 MB and a few seconds each).
pub const MAX_UNKNOWNS: usize = 3000;
/// Samples per beat from which [`Pulsatility`] takes its extremes (relative error ~1e-6).
const BEAT_SAMPLES: usize = 2048;

/// How the blood viscosity depends on the segment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Viscosity {
    /// The same viscosity (Pa·s) in every segment (Newtonian blood).
    Constant(f64),
    /// Fåhraeus–Lindqvist effect: plasma viscosity (Pa·s) times the in-vitro relative viscosity
    /// of Pries, Neuhaus & Gaehtgens, "Blood viscosity in tube flow: dependence on diameter and
    /// hematocrit", Am. J. Physiol. 263 (1992) H1770–H1778, at a discharge haematocrit in [0, 0.9].
    PriesInVitro {
        /// Plasma viscosity (Pa·s), ≈ 1.2e-3 at 37 °C.
        plasma: f64,
        /// Discharge haematocrit, the same in every segment (no phase separation at junctions).
        hematocrit: f64,
    },
}

impl Viscosity {
    /// Apparent viscosity (Pa·s) in a segment of this diameter (m).
    pub fn at(&self, diameter: f64) -> f64 {
        match *self {
            Viscosity::Constant(mu) => mu,
            Viscosity::PriesInVitro { plasma, hematocrit } => {
                plasma * pries_relative_viscosity(diameter * 1e6, hematocrit)
            }
        }
    }

    fn validate(&self) -> Result<()> {
        match *self {
            Viscosity::Constant(mu) => require_positive("blood viscosity", mu),
            Viscosity::PriesInVitro { plasma, hematocrit } => {
                require_positive("plasma viscosity", plasma)?;
                require_range("discharge haematocrit", hematocrit, (0.0, 0.9), "")
            }
        }
    }
}

/// Relative apparent viscosity of blood in a glass tube of diameter `d_um` (µm) at discharge
/// haematocrit `h` (Pries et al. 1992, eqs. for μ_0.45 and C): 1 at h = 0, ≈ 3.2 in wide tubes
/// at h = 0.45, with its minimum (≈ 1.3) near 7 µm.
pub fn pries_relative_viscosity(d_um: f64, h: f64) -> f64 {
    let d = d_um;
    let mu45 = 220.0 * (-1.3 * d).exp() + 3.2 - 2.44 * (-0.06 * d.powf(0.645)).exp();
    let s = 1.0 / (1.0 + 1e-11 * d.powi(12));
    let c = (0.8 + (-0.075 * d).exp()) * (-1.0 + s) + s;
    1.0 + (mu45 - 1.0) * ((1.0 - h).powf(c) - 1.0) / ((1.0 - 0.45f64).powf(c) - 1.0)
}

/// The periodic shape that modulates every pulsatile boundary condition: a zero-mean Fourier
/// series at the heart rate, scaled to a peak-to-trough swing of 1.
#[derive(Debug, Clone, PartialEq)]
pub struct CardiacPulse {
    heart_rate_hz: f64,
    harmonics: Vec<Complex64>,
}

impl CardiacPulse {
    /// Heart rate of an anaesthetised rat (Hz), ≈ 330 beats/min.
    pub const RAT_HEART_RATE: f64 = 5.5;

    /// The shape s(t) = Σₖ Re(hₖ e^{ikωt}), k = 1, 2, …, `harmonics[k-1]` = hₖ, at `heart_rate_hz`
    /// (Hz), rescaled so that its peak-to-trough swing is 1. An empty list is a steady beat.
    pub fn new(heart_rate_hz: f64, harmonics: Vec<Complex64>) -> Result<Self> {
        require_positive("heart rate", heart_rate_hz)?;
        if harmonics
            .iter()
            .any(|h| !(h.re.is_finite() && h.im.is_finite()))
        {
            return Err(invalid("cardiac pulse", "its harmonics must be finite"));
        }
        let mut pulse = CardiacPulse {
            heart_rate_hz,
            harmonics,
        };
        if pulse.harmonics.iter().any(|h| h.norm() > 0.0) {
            let (lo, hi) = beat_extremes(|t| pulse.value(t), pulse.period());
            pulse.harmonics.iter_mut().for_each(|h| *h /= hi - lo);
        }
        Ok(pulse)
    }

    /// The house systolic pulse ((1 + cos θ)/2)³ minus its mean, at the rat heart rate: a sharp
    /// systole at t = 0 and a long diastole, three harmonics (the shape of the network phantom's
    /// `CardiacWaveform`).
    pub fn rat() -> Self {
        let h = [15.0 / 32.0, 3.0 / 16.0, 1.0 / 32.0];
        CardiacPulse::new(
            Self::RAT_HEART_RATE,
            h.iter().map(|&c| Complex64::new(c, 0.0)).collect(),
        )
        .expect("the rat pulse is valid")
    }

    /// Heart rate (Hz).
    pub fn heart_rate_hz(&self) -> f64 {
        self.heart_rate_hz
    }

    /// Beat period (s).
    pub fn period(&self) -> f64 {
        1.0 / self.heart_rate_hz
    }

    /// Fundamental angular frequency (rad/s).
    pub fn omega(&self) -> f64 {
        2.0 * std::f64::consts::PI * self.heart_rate_hz
    }

    /// Complex amplitudes hₖ, k = 1, 2, … (swing-normalised).
    pub fn harmonics(&self) -> &[Complex64] {
        &self.harmonics
    }

    /// The zero-mean shape at time `t` (s).
    pub fn value(&self, t: f64) -> f64 {
        fourier(0.0, &self.harmonics, self.omega(), t)
    }
}

/// Everything [`solve`] needs besides the graph: blood, vessel wall and heart.
#[derive(Debug, Clone, PartialEq)]
pub struct FlowParams {
    /// Blood viscosity model.
    pub viscosity: Viscosity,
    /// Blood density (kg/m³), for the compliance.
    pub density: f64,
    /// Pulse-wave speed (m/s) per class, indexed by [`VesselClass::index`] (arteriole, capillary,
    /// venule); `f64::INFINITY` makes that class rigid (no compliance).
    pub wave_speed: [f64; 3],
    /// Shape and rate of the cardiac pulse of the pulsatile boundary conditions.
    pub pulse: CardiacPulse,
}

impl FlowParams {
    /// Default pulse-wave speeds (m/s: arteriole, capillary, venule); see the module docs of
    /// [`super`] for how they were chosen.
    pub const DEFAULT_WAVE_SPEED: [f64; 3] = [20.0, 2.5, 0.25];

    /// Rat cortex defaults: 3.5 mPa·s Newtonian blood, 1050 kg/m³, the default wave speeds, the
    /// rat cardiac pulse at 5.5 Hz.
    pub fn rat() -> Self {
        FlowParams {
            viscosity: Viscosity::Constant(DEFAULT_VISCOSITY),
            density: BLOOD_DENSITY,
            wave_speed: Self::DEFAULT_WAVE_SPEED,
            pulse: CardiacPulse::rat(),
        }
    }

    /// The same parameters with rigid vessels: every segment carries the inlet's waveform.
    pub fn rigid(mut self) -> Self {
        self.wave_speed = [f64::INFINITY; 3];
        self
    }

    /// Poiseuille resistance 128 μ L / (π d⁴) (Pa·s/m³) of a segment of diameter `d` and length
    /// `length` (m).
    pub fn resistance(&self, d: f64, length: f64) -> f64 {
        128.0 * self.viscosity.at(d) * length / (std::f64::consts::PI * d.powi(4))
    }

    /// Compliance V / (ρ c²) (m³/Pa) of a segment of diameter `d`, length `length` (m) and class
    /// `class`: the volume it stores per pascal; 0 for a rigid class.
    pub fn compliance(&self, d: f64, length: f64, class: VesselClass) -> f64 {
        let c = self.wave_speed[class.index()];
        if c.is_infinite() {
            0.0
        } else {
            std::f64::consts::PI * d * d / 4.0 * length / (self.density * c * c)
        }
    }

    /// Checks every parameter.
    pub fn validate(&self) -> Result<()> {
        self.viscosity.validate()?;
        require_positive("blood density", self.density)?;
        for class in VesselClass::ALL {
            let c = self.wave_speed[class.index()];
            if c.is_nan() || c <= 0.0 {
                return Err(invalid(
                    &format!("{} pulse-wave speed", class.name()),
                    format!("must be > 0 m/s (infinite for rigid), got {c}"),
                ));
            }
        }
        Ok(())
    }
}

/// Pulsatility of one segment over a beat, of its centreline speed along its mean flow.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pulsatility {
    /// Peak systolic centreline speed (m/s).
    pub psv: f64,
    /// End-diastolic (minimum) centreline speed (m/s); negative if the flow reverses.
    pub edv: f64,
    /// Resistivity index (PSV − EDV)/PSV; NaN when the segment carries no mean flow.
    pub ri: f64,
    /// Delay (s) of the flow's fundamental behind the inlet pulse's, in (−T/2, T/2]: the
    /// pulse-wave delay; NaN for a steady beat.
    pub delay_s: f64,
}

/// The flow in one segment: geometry, class, and its periodic flow waveform.
#[derive(Debug, Clone, PartialEq)]
pub struct SegmentFlow {
    /// Segment id: its index in the graph's edges.
    pub id: usize,
    /// First vertex index (positive flow leaves it).
    pub v1: usize,
    /// Second vertex index.
    pub v2: usize,
    /// Position of `v1` (m).
    pub start: [f64; 3],
    /// Position of `v2` (m).
    pub end: [f64; 3],
    /// Lumen diameter (m).
    pub diameter: f64,
    /// Hydraulic length (m).
    pub length: f64,
    /// Anatomical class.
    pub class: VesselClass,
    /// Poiseuille resistance (Pa·s/m³).
    pub resistance: f64,
    /// Compliance (m³/Pa), shared half and half by its two vertices.
    pub compliance: f64,
    /// Mean flow from `v1` to `v2` over a beat (m³/s).
    pub mean_flow: f64,
    /// Complex flow amplitudes Qₖ (m³/s), k = 1, 2, …: q(t) = Q₀ + Σ Re(Qₖ e^{ikωt}).
    pub harmonics: Vec<Complex64>,
    /// Fundamental angular frequency ω (rad/s).
    pub omega: f64,
    /// PSV, EDV, RI and pulse delay.
    pub pulsatility: Pulsatility,
}

impl SegmentFlow {
    /// Lumen cross-section (m²).
    pub fn area(&self) -> f64 {
        std::f64::consts::PI * self.diameter * self.diameter / 4.0
    }

    /// Volume flow from `v1` to `v2` at time `t` (m³/s).
    pub fn flow(&self, t: f64) -> f64 {
        fourier(self.mean_flow, &self.harmonics, self.omega, t)
    }

    /// Cross-section mean speed from `v1` to `v2` at time `t` (m/s).
    pub fn mean_speed(&self, t: f64) -> f64 {
        self.flow(t) / self.area()
    }

    /// Centreline (peak of the parabolic profile, twice the mean) speed from `v1` to `v2` at
    /// time `t` (m/s); negative when the flow runs from `v2` to `v1`.
    pub fn centreline_speed(&self, t: f64) -> f64 {
        2.0 * self.mean_speed(t)
    }

    /// A bound on the centreline's speed at any time (m/s): every harmonic at its peak at once,
    /// 2 (|Q₀| + Σ |Qₖ|) / A.
    pub fn max_centreline_speed(&self) -> f64 {
        let peak = self.mean_flow.abs() + self.harmonics.iter().map(|q| q.norm()).sum::<f64>();
        2.0 * peak / self.area()
    }

    /// Distance travelled along the centreline from time 0 to `t` (m), from `v1` toward `v2`:
    /// exact (closed form per harmonic), so it does not depend on earlier calls.
    pub fn centreline_displacement(&self, t: f64) -> f64 {
        let mut volume = self.mean_flow * t;
        for (k, q) in self.harmonics.iter().enumerate() {
            let w = (k + 1) as f64 * self.omega;
            let e = Complex64::from_polar(1.0, w * t) - 1.0;
            volume += (q * e / Complex64::new(0.0, w)).re;
        }
        2.0 * volume / self.area()
    }

    /// Unit vector from `start` to `end`.
    pub fn direction(&self) -> [f64; 3] {
        let d = sub(&self.end, &self.start);
        let n = norm(&d);
        [d[0] / n, d[1] / n, d[2] / n]
    }

    /// Straight distance from `start` to `end` (m): the cylinder's axis, which its blood fills
    /// (the hydraulic `length` may be longer, for a tortuous vessel).
    pub fn chord(&self) -> f64 {
        norm(&sub(&self.end, &self.start))
    }

    /// Corners (min, max) (m) of a box that holds the segment's whole cylinder: its axis's box
    /// grown by the radius.
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        let r = 0.5 * self.diameter;
        (
            std::array::from_fn(|k| self.start[k].min(self.end[k]) - r),
            std::array::from_fn(|k| self.start[k].max(self.end[k]) + r),
        )
    }

    /// (axial distance from `start`, distance from the axis) (m) of `point` (m) when it lies
    /// inside the segment's cylinder.
    pub fn local(&self, point: &[f64; 3]) -> Option<(f64, f64)> {
        let u = self.direction();
        let p = sub(point, &self.start);
        let s = dot(&p, &u);
        let chord = self.chord();
        let r2 = (dot(&p, &p) - s * s).max(0.0);
        let radius = self.diameter / 2.0;
        (s >= 0.0 && s <= chord && r2 <= radius * radius).then(|| (s, r2.sqrt()))
    }

    /// Laminar (Poiseuille) velocity vector (m/s, x y z) at `point` (m) and time `t` (s):
    /// 2 ū(t) (1 − (r/R)²) along the axis; `None` outside the segment.
    pub fn velocity_at(&self, point: &[f64; 3], t: f64) -> Option<[f64; 3]> {
        let (_, r) = self.local(point)?;
        let rel = r / (self.diameter / 2.0);
        let u = self.centreline_speed(t) * (1.0 - rel * rel);
        let d = self.direction();
        Some([u * d[0], u * d[1], u * d[2]])
    }
}

/// The solved flow in a whole graph.
#[derive(Debug, Clone, PartialEq)]
pub struct VascularFlow {
    /// Fundamental angular frequency ω (rad/s) of the heart.
    pub omega: f64,
    /// Per vertex, its pressure harmonics (Pa): index 0 the mean (real), k ≥ 1 the complex
    /// amplitude Pₖ of p(t) = P₀ + Σ Re(Pₖ e^{ikωt}).
    pub pressure: Vec<Vec<Complex64>>,
    /// Per vertex, its compliance (m³/Pa): half of each of its segments'.
    pub node_compliance: Vec<f64>,
    /// Per segment (indexed like the graph's edges), its flow.
    pub segments: Vec<SegmentFlow>,
}

impl VascularFlow {
    /// The first segment whose cylinder holds `point` (m), with its laminar velocity (m/s) at
    /// time `t` (s); a linear search, meant for truth maps and tests.
    pub fn velocity_at(&self, point: &[f64; 3], t: f64) -> Option<(usize, [f64; 3])> {
        self.segments
            .iter()
            .find_map(|s| s.velocity_at(point, t).map(|v| (s.id, v)))
    }

    /// Net flow harmonic `k` (m³/s) into vertex `v` from its segments, minus what its compliance
    /// stores (i k ω C Pₖ): zero at every vertex without a boundary condition (conservation).
    pub fn junction_residual(&self, v: usize, k: usize) -> Complex64 {
        let mut sum = Complex64::new(0.0, 0.0);
        for s in &self.segments {
            let q = if k == 0 {
                Complex64::new(s.mean_flow, 0.0)
            } else {
                s.harmonics[k - 1]
            };
            if s.v2 == v {
                sum += q;
            }
            if s.v1 == v {
                sum -= q;
            }
        }
        let w = k as f64 * self.omega;
        sum - Complex64::new(0.0, w * self.node_compliance[v]) * self.pressure[v][k]
    }
}

/// Solves `graph` with `params`: nodal pressures from flow conservation at every vertex without a
/// boundary condition (mean flow: conductances only; each harmonic: conductances + iωC), then
/// every segment's flow waveform and pulsatility. Refuses an invalid graph or parameters, and
/// more than [`MAX_UNKNOWNS`] vertices without a pressure condition.
pub fn solve(graph: &VesselGraph, params: &FlowParams) -> Result<VascularFlow> {
    graph.validate()?;
    params.validate()?;
    let n = graph.vertices.len();
    let boundary = graph.boundary_index();
    let mut unknown = vec![usize::MAX; n];
    let mut n_unknown = 0;
    for v in 0..n {
        let pressure_set =
            boundary[v].is_some_and(|b| graph.boundaries[b].kind == BoundaryKind::Pressure);
        if !pressure_set {
            unknown[v] = n_unknown;
            n_unknown += 1;
        }
    }
    if n_unknown > MAX_UNKNOWNS {
        return Err(invalid(
            "vessel graph",
            format!(
                "{n_unknown} vertices without a pressure condition exceed the dense solver's \
                 limit of {MAX_UNKNOWNS}"
            ),
        ));
    }
    let lengths: Vec<f64> = graph.edges.iter().map(|e| graph.length(e)).collect();
    let conductance: Vec<f64> = graph
        .edges
        .iter()
        .zip(&lengths)
        .map(|(e, &l)| 1.0 / params.resistance(e.diameter, l))
        .collect();
    let mut node_compliance = vec![0.0; n];
    for (e, &l) in graph.edges.iter().zip(&lengths) {
        let c = params.compliance(e.diameter, l, e.class);
        node_compliance[e.v1] += c / 2.0;
        node_compliance[e.v2] += c / 2.0;
    }
    if conductance.iter().any(|g| !(g.is_finite() && *g > 0.0)) {
        return Err(invalid(
            "vessel graph",
            "a segment's resistance is not finite and positive (diameter or length out of range)",
        ));
    }

    let omega = params.pulse.omega();
    let n_harmonics = params.pulse.harmonics().len();
    // Per harmonic, the pressure at every vertex.
    let mut columns = Vec::with_capacity(n_harmonics + 1);
    for k in 0..=n_harmonics {
        let mut column = vec![Complex64::new(0.0, 0.0); n];
        // Boundary value of harmonic k: the mean for k = 0, the pulse swing times the shape's
        // k-th amplitude otherwise.
        let shape = if k == 0 {
            Complex64::new(0.0, 0.0)
        } else {
            params.pulse.harmonics()[k - 1]
        };
        let value = |b: usize| {
            let b = &graph.boundaries[b];
            if k == 0 {
                Complex64::new(b.value, 0.0)
            } else {
                shape * b.pulse
            }
        };
        let mut a = vec![Complex64::new(0.0, 0.0); n_unknown * n_unknown];
        let mut rhs = vec![Complex64::new(0.0, 0.0); n_unknown];
        for v in 0..n {
            match boundary[v] {
                Some(b) if graph.boundaries[b].kind == BoundaryKind::Pressure => {
                    column[v] = value(b);
                }
                Some(b) => rhs[unknown[v]] += value(b),
                None => {}
            }
            if unknown[v] != usize::MAX {
                let w = k as f64 * omega;
                a[unknown[v] * (n_unknown + 1)] += Complex64::new(0.0, w * node_compliance[v]);
            }
        }
        for (e, &g) in graph.edges.iter().zip(&conductance) {
            for (i, j) in [(e.v1, e.v2), (e.v2, e.v1)] {
                let ui = unknown[i];
                if ui == usize::MAX {
                    continue;
                }
                a[ui * (n_unknown + 1)] += g;
                match unknown[j] {
                    usize::MAX => rhs[ui] += g * column[j],
                    uj => a[ui * n_unknown + uj] -= g,
                }
            }
        }
        let x = solve_dense(n_unknown, &a, &rhs)?;
        for (p, &u) in column.iter_mut().zip(&unknown) {
            if u != usize::MAX {
                *p = x[u];
            }
        }
        columns.push(column);
    }
    let pressure: Vec<Vec<Complex64>> = (0..n)
        .map(|v| columns.iter().map(|c| c[v]).collect())
        .collect();

    let segments = graph
        .edges
        .iter()
        .enumerate()
        .map(|(id, e)| {
            let g = conductance[id];
            let q: Vec<Complex64> = (0..=n_harmonics)
                .map(|k| (pressure[e.v1][k] - pressure[e.v2][k]) * g)
                .collect();
            let mut s = SegmentFlow {
                id,
                v1: e.v1,
                v2: e.v2,
                start: graph.vertices[e.v1],
                end: graph.vertices[e.v2],
                diameter: e.diameter,
                length: lengths[id],
                class: e.class,
                resistance: 1.0 / g,
                compliance: params.compliance(e.diameter, lengths[id], e.class),
                mean_flow: q[0].re,
                harmonics: q[1..].to_vec(),
                omega,
                pulsatility: Pulsatility {
                    psv: f64::NAN,
                    edv: f64::NAN,
                    ri: f64::NAN,
                    delay_s: f64::NAN,
                },
            };
            s.pulsatility = pulsatility(&s, &params.pulse);
            s
        })
        .collect();
    Ok(VascularFlow {
        omega,
        pressure,
        node_compliance,
        segments,
    })
}

/// Solves the n × n system `a` (row-major) x = `rhs` by LU with partial pivoting.
fn solve_dense(n: usize, a: &[Complex64], rhs: &[Complex64]) -> Result<Vec<Complex64>> {
    if n == 0 {
        return Ok(vec![]);
    }
    let m = Mat::<Complex64>::from_fn(n, n, |i, j| a[i * n + j]);
    let b = Mat::<Complex64>::from_fn(n, 1, |i, _| rhs[i]);
    let x = m.partial_piv_lu().solve(&b);
    let out: Vec<Complex64> = (0..n).map(|i| x[(i, 0)]).collect();
    if out.iter().any(|v| !(v.re.is_finite() && v.im.is_finite())) {
        return Err(Error::NonFinite(
            "the nodal pressures (the network's system is singular)".into(),
        ));
    }
    Ok(out)
}

/// PSV, EDV, RI and pulse delay of a segment (see [`Pulsatility`]).
fn pulsatility(s: &SegmentFlow, pulse: &CardiacPulse) -> Pulsatility {
    let sign = if s.mean_flow < 0.0 { -1.0 } else { 1.0 };
    let (edv, psv) = beat_extremes(|t| sign * s.centreline_speed(t), pulse.period());
    let ri = if s.mean_flow != 0.0 && psv > 0.0 {
        (psv - edv) / psv
    } else {
        f64::NAN
    };
    let delay_s = match (s.harmonics.first(), pulse.harmonics().first()) {
        (Some(q), Some(h)) if q.norm() > 0.0 && h.norm() > 0.0 => {
            let lag = -((q * sign) / h).arg(); // in [−π, π]
            let lag = if lag <= -std::f64::consts::PI {
                lag + 2.0 * std::f64::consts::PI
            } else {
                lag
            };
            lag / s.omega
        }
        _ => f64::NAN,
    };
    Pulsatility {
        psv,
        edv,
        ri,
        delay_s,
    }
}

/// (min, max) of `f` over one period, sampled.
fn beat_extremes(f: impl Fn(f64) -> f64, period: f64) -> (f64, f64) {
    (0..BEAT_SAMPLES)
        .map(|i| f(i as f64 * period / BEAT_SAMPLES as f64))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        })
}

/// c₀ + Σₖ Re(cₖ e^{ikωt}), k = 1, 2, …
fn fourier(mean: f64, harmonics: &[Complex64], omega: f64, t: f64) -> f64 {
    mean + harmonics
        .iter()
        .enumerate()
        .map(|(k, c)| (c * Complex64::from_polar(1.0, (k + 1) as f64 * omega * t)).re)
        .sum::<f64>()
}

fn sub(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn norm(a: &[f64; 3]) -> f64 {
    dot(a, a).sqrt()
}
