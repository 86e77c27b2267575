//! Flow phantoms: point scatterers with amplitudes, exact motion, and ground-truth velocity maps.
//!
//! A phantom is a fixed list of scatterers (amplitude, arbitrary units) whose positions are known at
//! any time t (s): motion is integrated in closed form, so `positions_at(t)` does not depend on the
//! times asked before. Every random draw comes from a `ChaCha8Rng` seeded by the phantom's seed.
//! Ground truth is sampled on any pixel grid as a [`Truth`] (m/s, shape (nz, nx)).
//!
//! One file per phantom family: [`spiral`] (the paper's vessel), [`tube`], [`rigid`] (disk, block,
//! point targets for tests), [`network`] (the pulsatile vessel network with RI truth) and
//! [`tissue`] (moving speckle around the vessels, and the wrappers that move and combine them).
//!
//! Coordinates follow the crate convention: x lateral, z depth (positive into the medium), m.
//! Scatterer densities are per unit area of the 2-D imaging plane (scatterers/m²; 300/mm² = 3e8/m²).

use ndarray::Array2;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::core::error::{Result, invalid, require_positive};

pub mod network;
pub mod rigid;
pub mod spiral;
pub mod tissue;
pub mod tree;
pub mod tube;

pub use network::{NetworkPhantom, NetworkSpec, NetworkTruth};
pub use rigid::{BlockPhantom, BlockSpec, DiskPhantom, DiskSpec, PointPhantom};
pub use spiral::{SpiralPhantom, SpiralSpec};
pub use tissue::{Composite, Moved, TissueMotion, TissuePhantom, TissueSpec};
pub use tree::{TreePhantom, TreeSpec, TreeTruth};
pub use tube::{FlowProfile, TubePhantom, TubeSpec};

/// Largest number of scatterers a phantom may draw (guards against absurd densities).
pub const MAX_SCATTERERS: usize = 20_000_000;

/// Ground-truth velocity on a pixel grid: `vx`, `vz` in m/s, shape (nz, nx); `mask` is true inside
/// the flow. Outside the mask both components are 0.
#[derive(Debug, Clone, PartialEq)]
pub struct Truth {
    /// Lateral velocity (m/s), > 0 toward +x.
    pub vx: Array2<f64>,
    /// Axial velocity (m/s), > 0 moving deeper.
    pub vz: Array2<f64>,
    /// True where the pixel lies inside the moving medium.
    pub mask: Array2<bool>,
}

impl Truth {
    /// An all-outside truth of shape (nz, nx).
    pub fn empty(nz: usize, nx: usize) -> Self {
        Truth {
            vx: Array2::zeros((nz, nx)),
            vz: Array2::zeros((nz, nx)),
            mask: Array2::from_elem((nz, nx), false),
        }
    }

    /// Fills a truth by evaluating `f(x, z)` (m) → `Some((vx, vz))` inside the flow, `None` outside.
    pub fn from_fn(x: &[f64], z: &[f64], f: impl Fn(f64, f64) -> Option<[f64; 2]>) -> Self {
        let mut t = Truth::empty(z.len(), x.len());
        for (iz, &zz) in z.iter().enumerate() {
            for (ix, &xx) in x.iter().enumerate() {
                if let Some([vx, vz]) = f(xx, zz) {
                    t.vx[[iz, ix]] = vx;
                    t.vz[[iz, ix]] = vz;
                    t.mask[[iz, ix]] = true;
                }
            }
        }
        t
    }

    /// Speed |v| (m/s) at every pixel.
    pub fn speed(&self) -> Array2<f64> {
        ndarray::Zip::from(&self.vx)
            .and(&self.vz)
            .map_collect(|a, b| a.hypot(*b))
    }
}

/// A moving scattering medium, as the simulator sees it.
pub trait Phantom: Sync {
    /// Reflection amplitude of each scatterer (arbitrary units), in a fixed order.
    fn amplitudes(&self) -> &[f64];

    /// Clears `out` and fills it with the (x, z) position (m) of every scatterer at time `t` (s),
    /// in the order of [`Phantom::amplitudes`].
    fn positions_at(&self, t: f64, out: &mut Vec<[f64; 2]>);

    /// Clears `out` and, for a phantom in three dimensions, fills it with the elevation y (m,
    /// distance from the imaging plane) of every scatterer at time `t` (s), in the order of
    /// [`Phantom::amplitudes`]. Left empty (the default): every scatterer lies in the plane.
    fn elevations_at(&self, _t: f64, out: &mut Vec<f64>) {
        out.clear();
    }

    /// Ground-truth velocity (m/s) at time `t` (s) on the grid of lateral positions `x` and depths
    /// `z` (m); arrays of shape (z.len(), x.len()).
    fn truth(&self, x: &[f64], z: &[f64], t: f64) -> Truth;

    /// Number of scatterers.
    fn n_scatterers(&self) -> usize {
        self.amplitudes().len()
    }
}

pub(crate) fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

pub(crate) fn normal_amplitudes(rng: &mut ChaCha8Rng, n: usize) -> Vec<f64> {
    (0..n).map(|_| StandardNormal.sample(rng)).collect()
}

pub(crate) fn require_finite(name: &str, v: f64) -> Result<()> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(invalid(name, format!("must be finite, got {v}")))
    }
}

/// Scatterer count for `density` (1/m²) over `area` (m²), checked against [`MAX_SCATTERERS`].
pub(crate) fn scatterer_count(density: f64, area: f64) -> Result<usize> {
    require_positive("scatterer density", density)?;
    let n = (density * area).round();
    if !n.is_finite() || n > MAX_SCATTERERS as f64 {
        return Err(invalid(
            "scatterer density",
            format!(
                "{density:e} /m² over {:.3} mm² gives {n:e} scatterers, more than {MAX_SCATTERERS}",
                area * 1e6
            ),
        ));
    }
    Ok(n as usize)
}

/// Parabolic (laminar) profile: peak·(1 − (l/R)²) for |l| ≤ R, 0 outside (m/s).
#[inline]
pub(crate) fn parabolic(peak: f64, l: f64, radius: f64) -> f64 {
    let q = l / radius;
    if q.abs() <= 1.0 {
        peak * (1.0 - q * q)
    } else {
        0.0
    }
}

/// A phantom held still within each compound frame: the positions of `inner` sampled at the start of
/// the frame. This is the motion model of simulations that move scatterers once per frame (as the
/// PC-UVD paper's Field II study did, Δt = frame period); it hides the error Hadamard decoding makes
/// when blood moves between the events of a frame, and exists to measure that error.
pub struct FrameHeld<'a> {
    /// The moving phantom.
    pub inner: &'a dyn Phantom,
    /// Compound-frame period (s): n angles / event PRF.
    pub frame_period: f64,
}

impl FrameHeld<'_> {
    /// Start (s) of the compound frame that holds time `t` (s).
    fn frame_start(&self, t: f64) -> f64 {
        // Event times are i / PRF: the tiny margin keeps frame starts from rounding down a frame.
        (t / self.frame_period + 1e-9).floor() * self.frame_period
    }
}

impl Phantom for FrameHeld<'_> {
    fn amplitudes(&self) -> &[f64] {
        self.inner.amplitudes()
    }

    fn positions_at(&self, t: f64, out: &mut Vec<[f64; 2]>) {
        self.inner.positions_at(self.frame_start(t), out);
    }

    fn elevations_at(&self, t: f64, out: &mut Vec<f64>) {
        self.inner.elevations_at(self.frame_start(t), out);
    }

    fn truth(&self, x: &[f64], z: &[f64], t: f64) -> Truth {
        self.inner.truth(x, z, t)
    }
}
