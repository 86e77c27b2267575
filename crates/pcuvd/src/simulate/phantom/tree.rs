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
//! A pixel (x, z) of the imaging plane sees the blood within its voxel: the cell of the plane
//! nearer to its centre than to its neighbours', spread along the elevation y by the beam's
//! two-way echo power |G(y, z)|⁴ ([`crate::simulate::elevation`]). Its truth is the mean over
//! that voxel, weighted so: the velocity (vx, vy, vz) of the blood, averaged over the blood only
//! (what a mean-frequency Doppler estimate of the voxel's echoes reads); the blood fraction (the
//! blood's share of the voxel's weight, a partial volume); and the segment holding most of the
//! voxel's blood weight, which gives its id, class and RI. PSV and EDV are that segment's, scaled
//! by the mean laminar profile factor the voxel sees. The integral runs on a lattice a quarter of
//! each vessel's radius fine, so a vessel narrower than a pixel counts with its whole cross-section
//! (its mean speed, half the centreline's), not with the line through the pixel's centre.
//! Without an elevation aperture (a two-dimensional simulation) the weight is 1 at y = 0 and 0
//! elsewhere: the plane's own cut through the tree, averaged over each pixel's cell. An axis of
//! one position has no cell: there the truth is taken on its line.

use ndarray::Array2;
use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use super::network::{NetworkTruth, point_segment_distance};
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
    /// Distance from the axis (m).
    radius: f64,
    /// Offset from the axis (x, y, z) (m): `radius` along its angle around the axis, in the
    /// segment's cross-section. Fixed, so computed once rather than at every event.
    offset: [f64; 3],
}

/// Blood in a solved vascular tree, as a phantom.
#[derive(Debug, Clone)]
pub struct TreePhantom {
    flow: VascularFlow,
    seats: Vec<Seat>,
    amplitudes: Vec<f64>,
    /// Per segment: its unit axis, from its start to its end.
    axes: Vec<[f64; 3]>,
    /// Per segment: its chord (m), the length its blood wraps around.
    chords: Vec<f64>,
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
        let mut unit_axes = Vec::with_capacity(flow.segments.len());
        let mut chords = Vec::with_capacity(flow.segments.len());
        for (index, s) in flow.segments.iter().enumerate() {
            let [u, n1, n2] = axes(s.direction());
            unit_axes.push(u);
            let chord = s.chord();
            chords.push(chord);
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
                let along = rng.random_range(0.0..chord);
                let (sin, cos) = rng.random_range(0.0..std::f64::consts::TAU).sin_cos();
                seats.push(Seat {
                    segment: index,
                    along,
                    radius: r,
                    offset: std::array::from_fn(|k| r * (cos * n1[k] + sin * n2[k])),
                });
                let a: f64 = StandardNormal.sample(&mut rng);
                amplitudes.push(sigma * a);
            }
        }
        Ok(TreePhantom {
            flow,
            seats,
            amplitudes,
            axes: unit_axes,
            chords,
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
        let chord = self.chords[seat.segment];
        let along = (seat.along + travelled * self.profile(seat)).rem_euclid(chord);
        let u = self.axes[seat.segment];
        std::array::from_fn(|k| s.start[k] + along * u[k] + seat.offset[k])
    }

    /// The truth the imaging plane sees on the grid `x`, `z` (m) at time `t` (s), over each
    /// pixel's voxel weighted by `aperture`'s two-way echo power at wavelength `lambda` (m) along
    /// the elevation, or the plane itself when `aperture` is `None` (see the module docs).
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

    /// [`TreePhantom::plane_truth`] at each of `times` (s). How much of each segment's blood
    /// lies in each voxel, weighted by the beam, does not change with time and costs most of
    /// the work: it is integrated once, and each time only scales it by the segments' speeds.
    pub fn plane_truths(
        &self,
        x: &[f64],
        z: &[f64],
        times: &[f64],
        aperture: Option<(&ElevationAperture, f64)>,
    ) -> Vec<TreeTruth> {
        let beam = Beam::new(&self.flow.segments, z, aperture);
        let (xs, zs) = (Cells { centres: x }, Cells { centres: z });
        let shares: Vec<Vec<Share>> = self
            .flow
            .segments
            .par_iter()
            .enumerate()
            .map(|(id, s)| voxel_shares(id, s, (&xs, &zs), &beam))
            .collect();
        // The whole weight of each pixel's voxel: the blood fraction's denominator.
        let totals = Array2::from_shape_fn((z.len(), x.len()), |(iz, ix)| {
            xs.width(ix) * zs.width(iz) * beam.total(iz)
        });
        times
            .par_iter()
            .map(|&t| {
                let mut acc = Accumulator::new(z.len(), x.len(), &self.flow.segments);
                for (s, shares) in self.flow.segments.iter().zip(&shares) {
                    let speed = s.centreline_speed(t);
                    let u = s.direction();
                    for share in shares {
                        acc.add(share, u.map(|u| speed * u));
                    }
                }
                acc.finish(&self.flow.segments, &totals)
            })
            .collect()
    }
}

/// The elevation beam's two-way echo power |G(y, z)|⁴ on each pixel row, tabulated every
/// [`Beam::STEP`] over the tree and the whole beam; or, in two dimensions, the plane alone.
struct Beam {
    /// Per row, the weight at y = (i − centre) · STEP; `None` in two dimensions.
    table: Option<(Vec<Vec<f64>>, usize)>,
}

impl Beam {
    /// Elevation step of the table (m): the beam varies over hundreds of µm.
    const STEP: f64 = 10e-6;

    fn new(
        segments: &[SegmentFlow],
        z: &[f64],
        aperture: Option<(&ElevationAperture, f64)>,
    ) -> Self {
        let Some((a, lambda)) = aperture else {
            return Beam { table: None };
        };
        let deepest = z.iter().cloned().fold(0.0, f64::max);
        let reach = segments
            .iter()
            .flat_map(|s| [s.start[1].abs(), s.end[1].abs()].map(|y| y + 0.5 * s.diameter))
            .fold(a.y_reach(lambda, deepest), f64::max);
        let n = (reach / Self::STEP).ceil() as usize + 1;
        let strip = a.strip(lambda);
        let rows = z
            .par_iter()
            .map(|&zz| {
                strip
                    .row(zz, -(n as f64) * Self::STEP, Self::STEP, 2 * n + 1)
                    .into_iter()
                    .map(|g| g.norm_sqr().powi(2))
                    .collect()
            })
            .collect();
        Beam {
            table: Some((rows, n)),
        }
    }

    /// The weight at elevation `y` (m) on row `iz`, linear between the table's samples.
    fn weight(&self, iz: usize, y: f64) -> f64 {
        let Some((rows, centre)) = &self.table else {
            return 1.0;
        };
        let row = &rows[iz];
        let at = y / Self::STEP + *centre as f64;
        if at.is_nan() || at < 0.0 || at >= (row.len() - 1) as f64 {
            return 0.0;
        }
        let i = at as usize;
        let f = at - i as f64;
        row[i] * (1.0 - f) + row[i + 1] * f
    }

    /// The weight's integral over the elevation on row `iz` (m; 1 in two dimensions).
    fn total(&self, iz: usize) -> f64 {
        match &self.table {
            None => 1.0,
            Some((rows, _)) => rows[iz].iter().sum::<f64>() * Self::STEP,
        }
    }

    /// Whether this is the plane alone (two dimensions).
    fn is_flat(&self) -> bool {
        self.table.is_none()
    }
}

/// Midpoints and width of the fewest equal cells no wider than `step` covering `lo..hi`.
fn cells(lo: f64, hi: f64, step: f64) -> Vec<(f64, f64)> {
    let n = ((hi - lo) / step).ceil().max(1.0) as usize;
    let width = (hi - lo) / n as f64;
    (0..n)
        .map(|k| (lo + (k as f64 + 0.5) * width, width))
        .collect()
}

/// The cells of one axis of the pixel grid: each position's the stretch nearer to it than to its
/// neighbours (an axis of one position has no width there: its cell is the position itself).
/// A pixel's voxel in the plane is its x cell by its z cell.
struct Cells<'a> {
    /// Pixel positions (m), ascending.
    centres: &'a [f64],
}

impl Cells<'_> {
    /// (lower edge, upper edge) (m) of cell `i`.
    fn edges(&self, i: usize) -> (f64, f64) {
        let v = self.centres;
        if v.len() < 2 {
            return (v[i], v[i]);
        }
        let lo = if i == 0 {
            v[0] - 0.5 * (v[1] - v[0])
        } else {
            0.5 * (v[i - 1] + v[i])
        };
        let hi = if i + 1 == v.len() {
            v[i] + 0.5 * (v[i] - v[i - 1])
        } else {
            0.5 * (v[i] + v[i + 1])
        };
        (lo, hi)
    }

    /// Length (m) of cell `i`: 0 on an axis of one position.
    fn extent(&self, i: usize) -> f64 {
        let (lo, hi) = self.edges(i);
        hi - lo
    }

    /// Width of cell `i` in the measure the truth integrates with: its length, or 1 on an axis
    /// of one position (a line, sampled once).
    fn width(&self, i: usize) -> f64 {
        if self.centres.len() < 2 {
            1.0
        } else {
            self.extent(i)
        }
    }

    /// Sample positions `(v, dv)` across cell `i`, no further apart than `step` (m).
    fn samples(&self, i: usize, step: f64) -> Vec<(f64, f64)> {
        if self.centres.len() < 2 {
            return vec![(self.centres[i], 1.0)];
        }
        let (lo, hi) = self.edges(i);
        cells(lo, hi, step)
    }

    /// The cells that reach into `lo..=hi` (m).
    fn meeting(&self, lo: f64, hi: f64) -> Vec<usize> {
        (0..self.centres.len())
            .filter(|&i| {
                let (a, b) = self.edges(i);
                b >= lo && a <= hi
            })
            .collect()
    }
}

/// One segment's blood in one pixel's voxel: its beam-weighted volume, and that volume's
/// weighted sum of the laminar profile 1 − (r/R)² (the share of the centreline speed).
#[derive(Debug, Clone, Copy)]
struct Share {
    iz: usize,
    ix: usize,
    segment: usize,
    blood: f64,
    profiled: f64,
}

/// The shares of segment `s`'s blood in every voxel it reaches. In the plane, by the midpoint
/// rule on a lattice a quarter of its radius fine (10 µm at most, 0.5 µm at least: a 10 µm
/// capillary is sampled across, and so is a trunk's velocity gradient); along the elevation,
/// over the chord each lattice line cuts through the cylinder, where the laminar profile is a
/// quadratic in y, by Gauss–Legendre rules on pieces short beside the beam's variation. The
/// chord shrinks to nothing at the wall, so the sum has no step there.
fn voxel_shares(
    segment: usize,
    s: &SegmentFlow,
    (xs, zs): (&Cells, &Cells),
    beam: &Beam,
) -> Vec<Share> {
    let radius = 0.5 * s.diameter;
    let step = (radius / 4.0).clamp(0.5e-6, 10e-6);
    let (lo, hi) = s.bounds();
    // A voxel meets the cylinder only if its centre lies within the radius and the voxel's
    // half-diagonal of the axis's projection on the plane (the cylinder's projection lies
    // within the radius of it).
    let (a, b) = ([s.start[0], s.start[2]], [s.end[0], s.end[2]]);
    let near = |x: f64, z: f64, reach: f64| point_segment_distance([x, z], a, b) <= radius + reach;
    let chords = Chords::of(s);
    let columns: Vec<(usize, Vec<(f64, f64)>)> = xs
        .meeting(lo[0], hi[0])
        .into_iter()
        .map(|ix| (ix, xs.samples(ix, step)))
        .collect();
    let mut shares = Vec::new();
    for iz in zs.meeting(lo[2], hi[2]) {
        let sub_z = zs.samples(iz, step);
        for (ix, sub_x) in &columns {
            let ix = *ix;
            let half_diagonal = 0.5 * xs.extent(ix).hypot(zs.extent(iz));
            if !near(xs.centres[ix], zs.centres[iz], half_diagonal) {
                continue;
            }
            let (mut blood, mut profiled) = (0.0, 0.0);
            for &(zz, dz) in &sub_z {
                for &(xx, dx) in sub_x {
                    let (w, p) = chords.along_y(xx, zz, |y| beam.weight(iz, y), beam.is_flat());
                    blood += w * dx * dz;
                    profiled += p * dx * dz;
                }
            }
            if blood > 0.0 {
                shares.push(Share {
                    iz,
                    ix,
                    segment,
                    blood,
                    profiled,
                });
            }
        }
    }
    shares
}

/// A segment's cylinder cut by lines along the elevation y: on the line through (x, z), the
/// squared distance from the axis is r²(y) = A y² + B y + C and the position along the axis
/// s(y) = s₀ + y u_y.
struct Chords {
    start: [f64; 3],
    u: [f64; 3],
    chord: f64,
    radius: f64,
}

/// Pieces of a chord integrated by one Gauss–Legendre rule (m): the beam changes over a
/// hundred µm or more.
const CHORD_PIECE: f64 = 40e-6;

impl Chords {
    fn of(s: &SegmentFlow) -> Self {
        Chords {
            start: s.start,
            u: s.direction(),
            chord: s.chord(),
            radius: 0.5 * s.diameter,
        }
    }

    /// (∫ w(y) dy, ∫ w(y) (1 − r²(y)/R²) dy) over the line through (x, z) inside the cylinder,
    /// `weight` the beam's; where the beam `flat` (two dimensions), the plane y = 0 alone, with
    /// unit weight.
    fn along_y(&self, x: f64, z: f64, weight: impl Fn(f64) -> f64, flat: bool) -> (f64, f64) {
        let p = [x - self.start[0], -self.start[1], z - self.start[2]];
        let u = self.u;
        let s0 = p[0] * u[0] + p[1] * u[1] + p[2] * u[2];
        let p2 = p[0] * p[0] + p[1] * p[1] + p[2] * p[2];
        let (a, b, c) = (1.0 - u[1] * u[1], 2.0 * (p[1] - s0 * u[1]), p2 - s0 * s0);
        let r2 = |y: f64| ((a * y + b) * y + c).max(0.0);
        let profile = |y: f64| 1.0 - r2(y) / (self.radius * self.radius);
        if flat {
            let inside = r2(0.0) <= self.radius * self.radius && (0.0..=self.chord).contains(&s0);
            return if inside {
                (1.0, profile(0.0))
            } else {
                (0.0, 0.0)
            };
        }
        // Where the line is within the radius of the axis ...
        let (mut y0, mut y1) = if a > 1e-12 {
            let disc = b * b - 4.0 * a * (c - self.radius * self.radius);
            if disc <= 0.0 {
                return (0.0, 0.0);
            }
            let root = disc.sqrt();
            ((-b - root) / (2.0 * a), (-b + root) / (2.0 * a))
        } else if c <= self.radius * self.radius {
            (f64::NEG_INFINITY, f64::INFINITY)
        } else {
            return (0.0, 0.0);
        };
        // ... and between the segment's ends.
        if u[1].abs() > 1e-12 {
            let (e0, e1) = (-s0 / u[1], (self.chord - s0) / u[1]);
            y0 = y0.max(e0.min(e1));
            y1 = y1.min(e0.max(e1));
        } else if !(0.0..=self.chord).contains(&s0) {
            return (0.0, 0.0);
        }
        if y0.is_nan() || y1.is_nan() || y1 <= y0 {
            return (0.0, 0.0);
        }
        let pieces = ((y1 - y0) / CHORD_PIECE).ceil().max(1.0) as usize;
        let length = (y1 - y0) / pieces as f64;
        let (mut blood, mut profiled) = (0.0, 0.0);
        for k in 0..pieces {
            let middle = y0 + (k as f64 + 0.5) * length;
            for (node, gauss) in GAUSS_LEGENDRE_4 {
                let y = middle + 0.5 * length * node;
                let w = weight(y) * 0.5 * length * gauss;
                blood += w;
                profiled += w * profile(y);
            }
        }
        (blood, profiled)
    }
}

/// Nodes on [−1, 1] and weights of the four-point Gauss–Legendre rule (exact for cubics).
const GAUSS_LEGENDRE_4: [(f64, f64); 4] = [
    (-0.861_136_311_594_052_6, 0.347_854_845_137_453_9),
    (-0.339_981_043_584_856_3, 0.652_145_154_862_546_1),
    (0.339_981_043_584_856_3, 0.652_145_154_862_546_1),
    (0.861_136_311_594_052_6, 0.347_854_845_137_453_9),
];

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

/// Sums over the segments' shares of each voxel.
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

    /// Adds one segment's share of a voxel, its blood moving at `centreline` (m/s, x y z) on
    /// the axis. Shares come a segment at a time.
    fn add(&mut self, share: &Share, centreline: [f64; 3]) {
        let (iz, ix, id, w) = (share.iz, share.ix, share.segment, share.blood);
        self.blood[[iz, ix]] += w;
        self.class_blood[self.classes[id]][[iz, ix]] += w;
        for (acc, v) in self.velocity.iter_mut().zip(centreline) {
            acc[[iz, ix]] += share.profiled * v;
        }
        self.profile[[iz, ix]] += share.profiled;
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

    fn finish(self, segments: &[SegmentFlow], totals: &Array2<f64>) -> TreeTruth {
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
            fraction[[iz, ix]] = (blood / totals[[iz, ix]]).min(1.0);
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

    /// The mean of the laminar profile 1 − (r/R)² over the positions r (m) of `lo..hi` inside
    /// the radius `radius`, by a fine midpoint sum: the truth of a pixel whose cell crosses a
    /// vessel along y, taken apart from the phantom's lattice.
    fn mean_profile(lo: f64, hi: f64, radius: f64) -> f64 {
        let n = 100_000;
        let (mut sum, mut count) = (0.0, 0);
        for k in 0..n {
            let r = lo + (k as f64 + 0.5) * (hi - lo) / n as f64;
            if r.abs() <= radius {
                sum += 1.0 - (r / radius).powi(2);
                count += 1;
            }
        }
        sum / count as f64
    }

    #[test]
    fn a_vessel_crossing_the_plane_shows_its_speed_out_of_the_plane() {
        // Straight along y through (0.2 mm, 5 mm): the plane sees only vy, the laminar profile
        // averaged over each pixel's cell in x (cells reach halfway to the neighbours: 0.19–0.215,
        // 0.215–0.365 and 0.365–0.635 mm); its 1 mm holds nearly all the beam's two-way echo
        // power (|G|⁴ falls fast off the axis) but not its tails.
        let flow = vessel([0.2e-3, -0.5e-3, 5e-3], [0.2e-3, 0.5e-3, 5e-3]);
        let tree = TreePhantom::new(flow, TreeSpec::default_blood(), 1).unwrap();
        let x = [0.2e-3, 0.23e-3, 0.5e-3];
        let z = [5e-3];
        let aperture = ElevationAperture::l22_14vx();
        let t = 0.05;
        let truth = tree.plane_truth(&x, &z, t, Some((&aperture, 1540.0 / 15.625e6)));
        let s = &tree.flow().segments[0];
        let speed = s.centreline_speed(t);
        assert!(truth.truth.mask[[0, 0]] && truth.truth.mask[[0, 1]] && !truth.truth.mask[[0, 2]]);
        assert_eq!(truth.truth.vx[[0, 0]], 0.0);
        assert_eq!(truth.truth.vz[[0, 0]], 0.0);
        // The centre pixel's cell, −10 to 15 µm about the axis of a 30 µm-radius vessel, and
        // the next one's, from 15 µm off the axis to the wall at 30 µm (and beyond, bloodless).
        // The phantom's lattice, a quarter of the radius fine, reads the continuous mean within
        // 2 %. (Along y the chord does not shrink at the wall, so a wall inside a lattice cell
        // would err by up to a cell; here it falls on an edge.)
        let radius = 30e-6;
        for (ix, (lo, hi)) in [(0, (-10e-6, 15e-6)), (1, (15e-6, 165e-6))] {
            let expected = speed * mean_profile(lo, hi, radius);
            let got = truth.vy[[0, ix]];
            assert!(
                (got - expected).abs() < 0.02 * expected.abs(),
                "pixel {ix}: {got} against {expected}"
            );
        }
        let f = truth.blood_fraction[[0, 0]];
        assert!(f > 0.95 && f < 1.0, "blood fraction {f}");
        // The next cell is blood over 15 of its 150 µm.
        let f = truth.blood_fraction[[0, 1]];
        assert!((f / (15.0 / 150.0) - 1.0).abs() < 0.1, "blood fraction {f}");
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

    /// A vessel narrower than a pixel counts with its whole cross-section: its truth is the
    /// cross-section's mean speed, half the centreline's (Poiseuille), wherever it lies in the
    /// pixel, and not the speed on the line through the pixel's centre.
    #[test]
    fn a_vessel_narrower_than_a_pixel_reads_its_mean_speed() {
        let aperture = ElevationAperture::l22_14vx();
        let lambda = 1540.0 / 15.625e6;
        // 50 µm pixels laterally, 25 µm in depth; a 20 µm vessel along z, in the plane, at
        // 0 and at 12 µm off the centre of the middle column (its cell reaches 25 µm).
        let x: Vec<f64> = (-2..=2).map(|i| i as f64 * 50e-6).collect();
        let z: Vec<f64> = (0..9).map(|i| 4.4e-3 + i as f64 * 25e-6).collect();
        for offset in [0.0, 12e-6] {
            let graph = VesselGraph::single_vessel(
                [offset, 0.0, 4e-3],
                [offset, 0.0, 5e-3],
                20e-6,
                VesselClass::Arteriole,
                (1500.0, 0.0),
                1400.0,
            );
            let flow = solve(&graph, &FlowParams::rat()).unwrap();
            let tree = TreePhantom::new(flow, TreeSpec::default_blood(), 1).unwrap();
            let s = &tree.flow().segments[0];
            let mean = s.mean_speed(0.0);
            let truth = tree.plane_truth(&x, &z, 0.0, Some((&aperture, lambda)));
            for iz in 0..z.len() {
                // Only the middle column holds blood, all of the vessel's cross-section.
                for ix in 0..x.len() {
                    assert_eq!(truth.truth.mask[[iz, ix]], ix == 2, "row {iz}, column {ix}");
                }
                let vz = truth.truth.vz[[iz, 2]];
                assert!(
                    (vz / mean - 1.0).abs() < 0.03,
                    "offset {offset}: {vz} against the mean speed {mean}"
                );
            }
        }
    }

    #[test]
    fn an_artery_and_a_vein_in_one_beam_share_its_blood_by_the_beams_weight_on_each() {
        // A 60 µm artery and an 80 µm vein along x at one depth, 0.105 mm either side of the
        // plane in elevation, as the pial and basal pairs run: every pixel on their axis holds
        // both, and each holds the beam's two-way power over its lumen's chord in y.
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
        // The beam's weight integrated over each lumen's chord in y (0.5 µm midpoints, the
        // beam computed exactly; the phantom interpolates it between 10 µm samples).
        let lambda = 1540.0 / 15.625e6;
        let within = |centre: f64, radius: f64| -> f64 {
            let n = (2.0 * radius / 0.5e-6).round() as usize;
            (0..n)
                .map(|k| centre - radius + (k as f64 + 0.5) * 0.5e-6)
                .map(|yy| aperture.one_way(lambda, yy, z).norm_sqr().powi(2))
                .sum()
        };
        let (vein, artery) = (within(y, 40e-6), within(-y, 30e-6));
        let share = seen.cycle.class_share[[0, 0]];
        let expected = vein / (vein + artery);
        assert!(
            (share - expected).abs() < 1e-3,
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
