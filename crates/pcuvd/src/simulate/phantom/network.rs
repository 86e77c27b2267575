//! A pulsatile vessel network with ground truth for PSV, EDV, RI and artery/vein class: the
//! in-vivo-like test bed of the dynamics stage (paper §4, Fig. 6–8), where the paper had no truth.
//!
//! Each vessel is a straight tube with a parabolic (laminar) profile whose centreline speed follows
//! a periodic cardiac waveform of known resistivity index:
//!
//! w(t) = (1 − RI) + RI · p(2π·f_h·(t − delay)),  p(θ) = ((1 + cos θ)/2)³,
//!
//! so the waveform peaks at 1 (PSV) once per beat and falls to 1 − RI (EDV) half a beat later, and
//! RI = (PSV − EDV)/PSV holds at every radius of the vessel (the profile scales PSV and EDV alike).
//! p is a three-harmonic Fourier series (5/16 + 15/32·cos θ + 3/16·cos 2θ + 1/32·cos 3θ), so the
//! displacement ∫w dt is exact in closed form and `positions_at(t)` does not depend on earlier calls.
//! Arterioles get RI ≈ 0.7 and a high PSV, venules RI ≈ 0.3 and a lower PSV (paper §4: arterioles
//! 0.55–0.9, venules < 0.5). Scatterers that leave a tube re-enter at its other end.

use ndarray::Array2;
use rand::RngExt;

use super::{Phantom, Truth, normal_amplitudes, parabolic, require_finite, rng, scatterer_count};
use crate::core::error::{Result, invalid, require_positive};
use crate::core::vessel::{ARTERIOLE, BACKGROUND, VENULE};

/// Fourier coefficients of the systolic pulse p(θ) = ((1 + cos θ)/2)³ (cos kθ, k = 0..3).
const PULSE_COS: [f64; 4] = [5.0 / 16.0, 15.0 / 32.0, 3.0 / 16.0, 1.0 / 32.0];

/// A periodic cardiac waveform, normalised so that its peak (systole) is 1 and its minimum
/// (end-diastole) is 1 − RI.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CardiacWaveform {
    /// Heart rate (Hz).
    pub heart_rate_hz: f64,
    /// Resistivity index (PSV − EDV)/PSV, in [0, 1].
    pub ri: f64,
    /// Time of the first systolic peak (s); the waveform repeats every 1/heart rate.
    pub delay_s: f64,
}

impl CardiacWaveform {
    fn omega(&self) -> f64 {
        2.0 * std::f64::consts::PI * self.heart_rate_hz
    }

    /// Relative speed at time `t` (s): 1 at peak systole, 1 − RI at end-diastole.
    pub fn value(&self, t: f64) -> f64 {
        let theta = self.omega() * (t - self.delay_s);
        let pulse: f64 = PULSE_COS
            .iter()
            .enumerate()
            .map(|(k, c)| c * (k as f64 * theta).cos())
            .sum();
        (1.0 - self.ri) + self.ri * pulse
    }

    /// ∫₀ᵗ w(t′) dt′ (s): the displacement of a unit-speed scatterer, exact.
    pub fn integral(&self, t: f64) -> f64 {
        let w = self.omega();
        let phase = |t: f64| w * (t - self.delay_s);
        let harmonics: f64 = PULSE_COS
            .iter()
            .enumerate()
            .skip(1)
            .map(|(k, c)| {
                let k = k as f64;
                c / (k * w) * ((k * phase(t)).sin() - (k * phase(0.0)).sin())
            })
            .sum();
        (1.0 - self.ri + self.ri * PULSE_COS[0]) * t + self.ri * harmonics
    }

    fn validate(&self, name: &str) -> Result<()> {
        require_positive(&format!("{name} heart rate"), self.heart_rate_hz)?;
        require_finite(&format!("{name} waveform delay"), self.delay_s)?;
        if !(0.0..=1.0).contains(&self.ri) {
            return Err(invalid(
                &format!("{name} resistivity index"),
                format!("must be in [0, 1], got {}", self.ri),
            ));
        }
        Ok(())
    }
}

/// Arteriole (pulsatile, high RI) or venule (steady, low RI).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VesselKind {
    /// A small artery: RI ≥ the arteriole threshold.
    Arteriole,
    /// A small vein: RI ≤ the venule threshold.
    Venule,
}

impl VesselKind {
    /// The class code of [`crate::dynamics`] ([`ARTERIOLE`] or [`VENULE`]).
    pub fn class_code(self) -> u8 {
        match self {
            VesselKind::Arteriole => ARTERIOLE,
            VesselKind::Venule => VENULE,
        }
    }
}

/// One straight vessel of the network, SI units.
#[derive(Debug, Clone, PartialEq)]
pub struct VesselSpec {
    /// Short name shown in figures and tables (e.g. "A1").
    pub name: String,
    /// Arteriole or venule.
    pub kind: VesselKind,
    /// Centre of the vessel axis (x, z) (m).
    pub centre: [f64; 2],
    /// Flow direction (rad) from +x toward +z: 0 flows toward +x, π/2 flows deeper, −π/2 up.
    pub angle: f64,
    /// Length along the axis (m).
    pub length: f64,
    /// Radius (m).
    pub radius: f64,
    /// Centreline speed at peak systole (m/s), > 0.
    pub psv: f64,
    /// Resistivity index of its waveform, in [0, 1].
    pub ri: f64,
    /// Time of its first systolic peak (s).
    pub delay_s: f64,
}

impl VesselSpec {
    fn axes(&self) -> ([f64; 2], [f64; 2]) {
        let (s, c) = self.angle.sin_cos();
        ([c, s], [-s, c])
    }

    /// True when the flow goes toward the probe (Vz < 0).
    pub fn flows_up(&self) -> bool {
        self.angle.sin() < 0.0
    }

    /// The two ends of the axis (m).
    fn ends(&self) -> [[f64; 2]; 2] {
        let (d, _) = self.axes();
        let h = 0.5 * self.length;
        [
            [self.centre[0] - h * d[0], self.centre[1] - h * d[1]],
            [self.centre[0] + h * d[0], self.centre[1] + h * d[1]],
        ]
    }

    /// (axial, lateral) coordinates (m) of (x, z) when inside the vessel.
    fn local(&self, x: f64, z: f64) -> Option<(f64, f64)> {
        let (d, n) = self.axes();
        let (dx, dz) = (x - self.centre[0], z - self.centre[1]);
        let s = dx * d[0] + dz * d[1];
        let l = dx * n[0] + dz * n[1];
        (s.abs() <= 0.5 * self.length && l.abs() <= self.radius).then_some((s, l))
    }
}

/// Geometry and physiology of a vessel network.
#[derive(Debug, Clone, PartialEq)]
pub struct NetworkSpec {
    /// The vessels; they must not touch each other.
    pub vessels: Vec<VesselSpec>,
    /// Heart rate (Hz), shared by every vessel.
    pub heart_rate_hz: f64,
    /// Scatterer density (scatterers/m²).
    pub density: f64,
}

impl NetworkSpec {
    /// A rat-cortex-like network for the paper's in-vivo setting (L22-14vX, field 12.8 mm wide,
    /// 1–13 mm deep): four arterioles (RI 0.7, PSV 20–30 mm/s, radius 0.15 mm) and four venules
    /// (RI 0.3, PSV 10–14 mm/s, radius 0.2 mm, systole 30 ms after the arterioles'), penetrating
    /// (near-vertical) vessels flowing up and down, oblique and near-horizontal deep ones; heart rate
    /// 5.5 Hz (≈ 330 bpm, anaesthetised rat), 300 scatterers/mm² as in the spiral. Peak axial speeds
    /// stay below the per-angle Nyquist velocity of the rat sequence (≈ 44 mm/s).
    pub fn rat() -> Self {
        let deg = std::f64::consts::PI / 180.0;
        let mm = 1e-3;
        let vessel = |name: &str, kind, x, z, angle_deg: f64, length, psv| {
            let (radius, ri, delay_s) = match kind {
                VesselKind::Arteriole => (0.15 * mm, 0.7, 0.02),
                VesselKind::Venule => (0.2 * mm, 0.3, 0.05),
            };
            VesselSpec {
                name: name.to_string(),
                kind,
                centre: [x * mm, z * mm],
                angle: angle_deg * deg,
                length: length * mm,
                radius,
                psv: psv * mm,
                ri,
                delay_s,
            }
        };
        use VesselKind::{Arteriole as A, Venule as V};
        NetworkSpec {
            vessels: vec![
                vessel("A1", A, -4.5, 5.0, 75.0, 6.0, 30.0),
                vessel("V1", V, -2.5, 5.5, -100.0, 6.0, 12.0),
                vessel("A2", A, 0.5, 6.0, -80.0, 7.0, 25.0),
                vessel("V2", V, 2.5, 6.5, 105.0, 7.0, 14.0),
                vessel("A3", A, 5.0, 8.0, 60.0, 5.0, 25.0),
                vessel("V3", V, -2.0, 11.0, 190.0, 6.0, 10.0),
                vessel("A4", A, 3.5, 11.5, 10.0, 4.0, 20.0),
                vessel("V4", V, -5.0, 8.8, -60.0, 2.4, 10.0),
            ],
            heart_rate_hz: 5.5,
            density: 3e8,
        }
    }

    /// The same network with every vessel's peak systolic speed scaled so that the fastest
    /// vessel's is `psv` (m/s, > 0): fast flow (an artery beyond the Nyquist velocity) with the
    /// network's geometry, waveforms and speed ratios.
    pub fn with_fastest_psv(mut self, psv: f64) -> Result<Self> {
        require_positive("peak systolic speed", psv)?;
        let fastest = self.vessels.iter().map(|v| v.psv).fold(0.0, f64::max);
        require_positive("fastest vessel's peak systolic speed", fastest)?;
        for v in &mut self.vessels {
            v.psv *= psv / fastest;
        }
        Ok(self)
    }

    /// The waveform of vessel `i`.
    pub fn waveform(&self, i: usize) -> CardiacWaveform {
        let v = &self.vessels[i];
        CardiacWaveform {
            heart_rate_hz: self.heart_rate_hz,
            ri: v.ri,
            delay_s: v.delay_s,
        }
    }

    /// Checks every vessel and that no two vessels touch.
    pub fn validate(&self) -> Result<()> {
        if self.vessels.is_empty() {
            return Err(invalid("vessel network", "needs at least one vessel"));
        }
        require_positive("heart rate", self.heart_rate_hz)?;
        for (i, v) in self.vessels.iter().enumerate() {
            let name = format!("vessel {}", v.name);
            require_finite(&format!("{name} centre x"), v.centre[0])?;
            require_finite(&format!("{name} centre z"), v.centre[1])?;
            require_finite(&format!("{name} angle"), v.angle)?;
            require_positive(&format!("{name} length"), v.length)?;
            require_positive(&format!("{name} radius"), v.radius)?;
            require_positive(&format!("{name} peak systolic speed"), v.psv)?;
            self.waveform(i).validate(&name)?;
        }
        for (i, a) in self.vessels.iter().enumerate() {
            for b in &self.vessels[i + 1..] {
                let [a0, a1] = a.ends();
                let [b0, b1] = b.ends();
                let gap = segment_distance(a0, a1, b0, b1) - a.radius - b.radius;
                if gap <= 0.0 {
                    return Err(invalid(
                        "vessel network",
                        format!("vessels {} and {} overlap", a.name, b.name),
                    ));
                }
            }
        }
        Ok(())
    }
}

/// Distance (m) from `p` to the segment from `a` to `b`, in the plane (x, z).
pub(super) fn point_segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (abx, abz) = (b[0] - a[0], b[1] - a[1]);
    let len2 = abx * abx + abz * abz;
    let t = if len2 > 0.0 {
        (((p[0] - a[0]) * abx + (p[1] - a[1]) * abz) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p[0] - a[0] - t * abx).hypot(p[1] - a[1] - t * abz)
}

/// Shortest distance (m) between segments a0–a1 and b0–b1 (0 when they cross).
fn segment_distance(a0: [f64; 2], a1: [f64; 2], b0: [f64; 2], b1: [f64; 2]) -> f64 {
    let cross = |o: [f64; 2], p: [f64; 2], q: [f64; 2]| {
        (p[0] - o[0]) * (q[1] - o[1]) - (p[1] - o[1]) * (q[0] - o[0])
    };
    let (d1, d2) = (cross(b0, b1, a0), cross(b0, b1, a1));
    let (d3, d4) = (cross(a0, a1, b0), cross(a0, a1, b1));
    if d1 * d2 < 0.0 && d3 * d4 < 0.0 {
        return 0.0;
    }
    point_segment_distance(a0, b0, b1)
        .min(point_segment_distance(a1, b0, b1))
        .min(point_segment_distance(b0, a0, a1))
        .min(point_segment_distance(b1, a0, a1))
}

/// Ground truth of the cardiac-cycle maps on a pixel grid, shape (nz, nx); NaN outside vessels.
#[derive(Debug, Clone, PartialEq)]
pub struct NetworkTruth {
    /// Peak systolic speed (m/s).
    pub psv: Array2<f64>,
    /// End-diastolic speed (m/s).
    pub edv: Array2<f64>,
    /// Resistivity index (PSV − EDV)/PSV.
    pub ri: Array2<f64>,
    /// Class code of [`crate::dynamics`]: background, arteriole or venule.
    pub vessel_class: Array2<u8>,
    /// True where the flow goes toward the probe.
    pub flow_up: Array2<bool>,
    /// Index of the vessel at each pixel (`usize::MAX` outside).
    pub vessel_index: Array2<usize>,
    /// Share (0–1) of the blood in the pixel's elevation beam that is of class `vessel_class`:
    /// below 1 where vessels of other classes share the beam, whose flow any estimate mixes
    /// in (1 in every vessel pixel of this network, whose truth is the plane's own cut; 0
    /// outside vessels).
    pub class_share: Array2<f64>,
    /// Where in its vessel the pixel's blood lies: the mean of 1 − (r/R)² over it (r from the
    /// axis of a vessel of radius R; over the elevation beam's blood, weighted as the beam sees
    /// it), 1 on the axis and 0 at the wall; 0 outside vessels. A Poiseuille profile's speed is
    /// this share of its peak.
    pub axis_profile: Array2<f64>,
}

impl NetworkTruth {
    /// True inside a vessel.
    pub fn mask(&self) -> Array2<bool> {
        self.vessel_class.mapv(|c| c != BACKGROUND)
    }
}

/// A vessel's axes and the distance a unit-speed scatterer has travelled at one time (m).
struct VesselFrame {
    d: [f64; 2],
    n: [f64; 2],
    travel: f64,
    centre: [f64; 2],
}

/// A pulsatile vessel network (see the module docs).
#[derive(Debug, Clone)]
pub struct NetworkPhantom {
    spec: NetworkSpec,
    amplitudes: Vec<f64>,
    /// Per scatterer: vessel index, axial coordinate at t = 0 in [−L/2, L/2) (m), lateral offset
    /// (m), centreline-relative peak speed (m/s).
    vessel: Vec<usize>,
    axial0: Vec<f64>,
    offset: Vec<f64>,
    peak: Vec<f64>,
}

impl NetworkPhantom {
    /// Draws the scatterers of `spec` with the random stream of `seed`.
    pub fn new(spec: NetworkSpec, seed: u64) -> Result<Self> {
        spec.validate()?;
        let mut rng = rng(seed);
        let (mut vessel, mut axial0, mut offset, mut peak) = (vec![], vec![], vec![], vec![]);
        for (i, v) in spec.vessels.iter().enumerate() {
            let n = scatterer_count(spec.density, v.length * 2.0 * v.radius)?;
            for _ in 0..n {
                let l = rng.random_range(-v.radius..v.radius);
                vessel.push(i);
                axial0.push(rng.random_range(-0.5 * v.length..0.5 * v.length));
                offset.push(l);
                peak.push(parabolic(v.psv, l, v.radius));
            }
        }
        let amplitudes = normal_amplitudes(&mut rng, vessel.len());
        Ok(NetworkPhantom {
            spec,
            amplitudes,
            vessel,
            axial0,
            offset,
            peak,
        })
    }

    /// The rat-cortex-like network [`NetworkSpec::rat`].
    pub fn rat(seed: u64) -> Result<Self> {
        Self::new(NetworkSpec::rat(), seed)
    }

    /// The geometry and physiology.
    pub fn spec(&self) -> &NetworkSpec {
        &self.spec
    }

    /// PSV, EDV, RI, class and direction of every pixel of the grid `x` × `z` (m).
    pub fn cycle_truth(&self, x: &[f64], z: &[f64]) -> NetworkTruth {
        let shape = (z.len(), x.len());
        let mut t = NetworkTruth {
            psv: Array2::from_elem(shape, f64::NAN),
            edv: Array2::from_elem(shape, f64::NAN),
            ri: Array2::from_elem(shape, f64::NAN),
            vessel_class: Array2::from_elem(shape, BACKGROUND),
            flow_up: Array2::from_elem(shape, false),
            vessel_index: Array2::from_elem(shape, usize::MAX),
            class_share: Array2::zeros(shape),
            axis_profile: Array2::zeros(shape),
        };
        for (iz, &zz) in z.iter().enumerate() {
            for (ix, &xx) in x.iter().enumerate() {
                let Some((i, v, (_, l))) = self.vessel_at(xx, zz) else {
                    continue;
                };
                let psv = parabolic(v.psv, l, v.radius);
                t.psv[[iz, ix]] = psv;
                t.edv[[iz, ix]] = psv * (1.0 - v.ri);
                t.ri[[iz, ix]] = v.ri;
                t.vessel_class[[iz, ix]] = v.kind.class_code();
                t.flow_up[[iz, ix]] = v.flows_up();
                t.vessel_index[[iz, ix]] = i;
                t.class_share[[iz, ix]] = 1.0;
                t.axis_profile[[iz, ix]] = 1.0 - (l / v.radius).powi(2);
            }
        }
        t
    }

    /// The first vessel containing (x, z), with its local (axial, lateral) coordinates.
    fn vessel_at(&self, x: f64, z: f64) -> Option<(usize, &VesselSpec, (f64, f64))> {
        self.spec
            .vessels
            .iter()
            .enumerate()
            .find_map(|(i, v)| v.local(x, z).map(|sl| (i, v, sl)))
    }
}

impl Phantom for NetworkPhantom {
    fn amplitudes(&self) -> &[f64] {
        &self.amplitudes
    }

    fn positions_at(&self, t: f64, out: &mut Vec<[f64; 2]>) {
        // Per vessel: axis direction, normal, distance travelled by a unit-speed scatterer, centre.
        let frames: Vec<VesselFrame> = (0..self.spec.vessels.len())
            .map(|i| {
                let v = &self.spec.vessels[i];
                let (d, n) = v.axes();
                VesselFrame {
                    d,
                    n,
                    travel: self.spec.waveform(i).integral(t),
                    centre: v.centre,
                }
            })
            .collect();
        out.clear();
        out.extend((0..self.amplitudes.len()).map(|k| {
            let i = self.vessel[k];
            let f = &frames[i];
            let len = self.spec.vessels[i].length;
            let s =
                (self.axial0[k] + self.peak[k] * f.travel + 0.5 * len).rem_euclid(len) - 0.5 * len;
            let l = self.offset[k];
            [
                f.centre[0] + s * f.d[0] + l * f.n[0],
                f.centre[1] + s * f.d[1] + l * f.n[1],
            ]
        }));
    }

    fn truth(&self, x: &[f64], z: &[f64], t: f64) -> Truth {
        Truth::from_fn(x, z, |x, z| {
            self.vessel_at(x, z).map(|(i, v, (_, l))| {
                let u = parabolic(v.psv, l, v.radius) * self.spec.waveform(i).value(t);
                let (d, _) = v.axes();
                [u * d[0], u * d[1]]
            })
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn waveform_peaks_at_one_and_bottoms_at_one_minus_ri() {
        let w = CardiacWaveform {
            heart_rate_hz: 5.5,
            ri: 0.7,
            delay_s: 0.013,
        };
        let period = 1.0 / 5.5;
        let samples: Vec<f64> = (0..10_000)
            .map(|i| w.value(i as f64 * period / 10_000.0))
            .collect();
        let max = samples.iter().cloned().fold(f64::MIN, f64::max);
        let min = samples.iter().cloned().fold(f64::MAX, f64::min);
        assert!((max - 1.0).abs() < 1e-6, "max {max}");
        assert!((min - 0.3).abs() < 1e-6, "min {min}");
        assert!((w.value(0.013) - 1.0).abs() < 1e-12);
        assert!((w.value(0.013 + 0.5 * period) - 0.3).abs() < 1e-12);
    }

    #[test]
    fn integral_matches_numerical_quadrature() {
        let w = CardiacWaveform {
            heart_rate_hz: 6.0,
            ri: 0.55,
            delay_s: -0.04,
        };
        let t_end = 0.37;
        let n = 200_000;
        let h = t_end / n as f64;
        // Simpson's rule, independent of the closed form.
        let mut sum = w.value(0.0) + w.value(t_end);
        for i in 1..n {
            sum += w.value(i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
        }
        let simpson = sum * h / 3.0;
        assert!(
            (w.integral(t_end) - simpson).abs() < 1e-12,
            "{}",
            w.integral(t_end) - simpson
        );
        assert_eq!(w.integral(0.0), 0.0);
    }

    #[test]
    fn rat_network_is_valid_and_has_both_kinds_both_directions() {
        let spec = NetworkSpec::rat();
        spec.validate().unwrap();
        for kind in [VesselKind::Arteriole, VesselKind::Venule] {
            for up in [true, false] {
                assert!(
                    spec.vessels
                        .iter()
                        .any(|v| v.kind == kind && v.flows_up() == up),
                    "{kind:?} up={up}"
                );
            }
        }
    }

    #[test]
    fn fastest_psv_scales_every_vessel_alike() {
        let spec = NetworkSpec::rat();
        let fast = spec.clone().with_fastest_psv(0.12).unwrap();
        // A1 is the fastest (30 mm/s): ×4 for every vessel, geometry and RI unchanged.
        assert_eq!(fast.vessels[0].psv, 0.12);
        for (a, b) in spec.vessels.iter().zip(&fast.vessels) {
            assert!((b.psv - 4.0 * a.psv).abs() < 1e-12, "{}", a.name);
            assert_eq!((a.centre, a.angle, a.ri), (b.centre, b.angle, b.ri));
        }
        assert!(spec.clone().with_fastest_psv(0.0).is_err());
        assert!(spec.with_fastest_psv(f64::NAN).is_err());
    }

    #[test]
    fn axis_profile_is_one_on_the_axis_and_falls_as_the_laminar_profile() {
        let phantom = NetworkPhantom::rat(3).unwrap();
        let v = &phantom.spec().vessels[0];
        let (_, n) = v.axes();
        let at = |l: f64| {
            let (x, z) = (v.centre[0] + l * n[0], v.centre[1] + l * n[1]);
            phantom.cycle_truth(&[x], &[z]).axis_profile[[0, 0]]
        };
        assert!((at(0.0) - 1.0).abs() < 1e-12);
        assert!((at(0.6 * v.radius) - 0.64).abs() < 1e-9);
        assert!((at(-0.6 * v.radius) - 0.64).abs() < 1e-9);
        assert_eq!(at(1.5 * v.radius), 0.0);
    }

    #[test]
    fn overlapping_vessels_are_refused() {
        let mut spec = NetworkSpec::rat();
        spec.vessels[1].centre = spec.vessels[0].centre;
        let err = spec.validate().unwrap_err().to_string();
        assert!(err.contains("A1") && err.contains("V1"), "{err}");
    }

    #[test]
    fn scatterers_move_with_the_waveform_speed() {
        let phantom = NetworkPhantom::rat(3).unwrap();
        let (mut p0, mut p1) = (vec![], vec![]);
        let (t, dt) = (0.061, 1e-6);
        // Central difference: its error (jerk·dt²/6) is far below the tolerance.
        phantom.positions_at(t - dt, &mut p0);
        phantom.positions_at(t + dt, &mut p1);
        for k in (0..phantom.n_scatterers()).step_by(97) {
            let i = phantom.vessel[k];
            let v = &phantom.spec.vessels[i];
            let speed = phantom.peak[k] * phantom.spec.waveform(i).value(t);
            let moved = (p1[k][0] - p0[k][0]).hypot(p1[k][1] - p0[k][1]) / (2.0 * dt);
            if moved < 1.0 {
                // (a scatterer wrapping round the tube's end jumps a vessel length)
                assert!(
                    (moved - speed).abs() < 1e-6 * v.psv.max(1e-3),
                    "{moved} vs {speed}"
                );
            }
        }
    }

    #[test]
    fn cycle_truth_marks_vessels_with_their_ri_and_class() {
        let phantom = NetworkPhantom::rat(1).unwrap();
        let x: Vec<f64> = (0..257).map(|i| -6.4e-3 + i as f64 * 0.05e-3).collect();
        let z: Vec<f64> = (0..241).map(|i| 1e-3 + i as f64 * 0.05e-3).collect();
        let truth = phantom.cycle_truth(&x, &z);
        let motion = phantom.truth(&x, &z, 0.0);
        assert_eq!(truth.mask(), motion.mask);
        for ((&ri, &class), &psv) in truth.ri.iter().zip(&truth.vessel_class).zip(&truth.psv) {
            match class {
                ARTERIOLE => assert_eq!(ri, 0.7),
                VENULE => assert_eq!(ri, 0.3),
                _ => assert!(ri.is_nan() && psv.is_nan()),
            }
        }
        for (i, v) in phantom.spec.vessels.iter().enumerate() {
            assert!(
                truth.vessel_index.iter().any(|&k| k == i),
                "vessel {} is off the grid",
                v.name
            );
        }
    }
}
