//! Vector dealiasing: projections beyond the Nyquist velocity unwrapped by the vector fit.
//!
//! Each angle's lag-1 Doppler reads its projection V_θ modulo 2·v_N (v_N = c·f_frame/(4 f_0), the
//! projection Nyquist velocity): a projection u beyond ±v_N is read as p = u − 2k·v_N with an
//! integer alias count k. The angles see one vector, so their alias counts are tied: for a true
//! vector v, u_i = a_i·v/2 (a_i = (sin θ_i, 1 + cos θ_i), [`projection_weights`]) and
//! k_i = round((u_i − p_i)/(2 v_N)). A pattern of alias counts turns the measured projections into
//! unwrapped ones, p_i + 2k_i·v_N, and a vector fit; a wrong pattern leaves a residual of the order
//! of 2 v_N at the angles it gets wrong (Ekroll et al.'s extended least squares).
//!
//! The steps, a module each:
//! - `candidates`: each pixel's alias patterns from trial vectors, fitted and scored by the
//!   estimator's own objective, the best of each level kept ([`pixel_candidates`]);
//! - `settle`: which pixels settle the levels (flow, angles that agree on v_N), and each
//!   estimator's pattern within its pixel's settled level;
//! - `levels`: the levels over space, unwrapped as a phase map with the wall at speed 0 and then
//!   checked against the summed residual;
//! - `regions`: neighbours, walls, holes, and the parts a jump of levels cuts off a region.
//!
//! [`dealiased_vectors`] runs them; [`Dealias`] is the setting.

use ndarray::{Array2, Array3, ArrayView2, ArrayView3};
use rayon::prelude::*;

use crate::core::error::{Error, Result, invalid};
use crate::estimate::projections::Projections;
use crate::estimate::vector::{self, Estimator, VectorField, projection_weights};

mod candidates;
mod levels;
mod regions;
mod settle;
#[cfg(test)]
mod tests;

use candidates::*;
pub use candidates::{Candidate, pixel_candidates, solve_pixel_dealiased};
use levels::*;
use regions::*;
use settle::*;

/// Smallest region (pixels) whose levels are chosen by its summed score; smaller ones keep the
/// plain fit (a few noise pixels above the flow threshold carry too little evidence).
pub const MIN_REGION_PIXELS: usize = 16;

/// A walled region leaves its wall's level only for one whose power-weighted summed score is below
/// this fraction of the wall level's ([`decisive_offset`]): between what the right level of flow
/// fast up to its wall scores against the wall's (about 0.4–0.7 on the plug tube at 3× v_N) and
/// what any other level of a vessel whose wall is right scores (above 1). Decoded coded data
/// beyond v_N fit no level and score near 1, on either side of it.
pub const DECISIVE_SCORE_RATIO: f64 = 0.8;

/// [`decisive_offset`] weighs an offset only where the pixels with a candidate at it (within ±K)
/// hold at least this share of the region's echo power.
pub const DECISIVE_POWER_SHARE: f64 = 0.9;

/// Within a level, a pattern that shifts some angles more than others is kept only where its
/// summed squared residual is below this fraction of the level's common shift's: a truly wrapped
/// angle leaves about 2·v_N at the common shift (a ratio of 10⁻⁴–10⁻²), while spare counts fitting
/// noise gain little; on the tube at 3× v_N it costs under 0.2 % of the lumen's right patterns.
pub const MIXED_PATTERN_RATIO: f64 = 0.3;

/// How many times [`unwrap_levels`] lets each pixel move to the level of its neighbours' median.
const CONSISTENCY_PASSES: usize = 4;

/// Largest K that [`Dealias::Auto`] tries: speeds up to 9·v_N (≈ 0.4 m/s at the paper's settings).
pub const MAX_AUTO_INTERVALS: u32 = 4;

/// [`Dealias::Auto`] stops at the first K at which fewer than this fraction of the unwrapped flow
/// pixels reach ±K at some angle.
pub const AUTO_LIMIT_FRACTION: f64 = 0.01;

/// Largest K accepted: beyond it the candidates become too many and too close to tell apart.
pub const MAX_INTERVALS: u32 = 8;

/// A flow pixel whose angles' Nyquist velocities (with Loupas, from their echoes' mean
/// frequencies) differ by more than this ratio does not settle levels: it takes the level of the
/// flow around it where it lies inside flow, else keeps the plain fit. Blood's angles agree within
/// about 1.2 (largest over smallest v_N of a pixel's angles, in tubes and a vessel network at 100
/// frames), haze and noise spread 1.3–2.8; shorter recordings spread more.
pub const NYQUIST_SPREAD_LIMIT: f64 = 1.25;

/// A pixel set aside by [`NYQUIST_SPREAD_LIMIT`] takes the level of the flow around it only with
/// at least this many settled 8-neighbours.
const FILL_NEIGHBOURS: usize = 3;

/// Fewest distinct steering angles with which alias patterns can be told apart.
pub const MIN_DISTINCT_ANGLES: usize = 3;

/// How many of `angles` (rad) differ from one another by more than 1e-9 rad.
pub fn distinct_angles(angles: &[f64]) -> usize {
    let mut distinct = angles.to_vec();
    distinct.sort_by(f64::total_cmp);
    distinct.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    distinct.len()
}

/// Fits faster than this times (2K + 1)·v_N are outside the limit.
const SPEED_MARGIN: f64 = 1.1;

/// How far the vector fit may unwrap aliased projections.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Dealias {
    /// No unwrapping: the paper's estimators, speeds within the Nyquist velocity.
    #[default]
    Off,
    /// K chosen from the data: the smallest K in 1..=[`MAX_AUTO_INTERVALS`] at which fewer than
    /// [`AUTO_LIMIT_FRACTION`] of the unwrapped flow pixels reach ±K at some angle (least squares
    /// decides, both estimators use it).
    Auto,
    /// Alias patterns up to ±K Nyquist intervals (2·v_N each) per angle: speeds up to (2K + 1)·v_N.
    Intervals(u32),
}

impl Dealias {
    /// The setting as written on the command line: "off", "auto" or K.
    pub fn label(&self) -> String {
        match self {
            Dealias::Off => "off".into(),
            Dealias::Auto => "auto".into(),
            Dealias::Intervals(k) => k.to_string(),
        }
    }

    /// Reads "off", "auto" or a whole number K (0 is off) of Nyquist intervals.
    pub fn parse(text: &str) -> Result<Self> {
        match text.trim().to_ascii_lowercase().as_str() {
            "off" | "none" | "0" => Ok(Dealias::Off),
            "auto" => Ok(Dealias::Auto),
            n => match n.parse::<u32>() {
                Ok(k) if k <= MAX_INTERVALS => Ok(Dealias::Intervals(k)),
                Ok(k) => Err(invalid(
                    "dealias",
                    format!("{k} Nyquist intervals is more than the {MAX_INTERVALS} supported"),
                )),
                Err(_) => Err(invalid(
                    "dealias",
                    format!(
                        "{text:?}: give \"off\", \"auto\" or a whole number of Nyquist intervals"
                    ),
                )),
            },
        }
    }

    /// Whether the setting unwraps anything: not [`Dealias::Off`], nor 0 intervals.
    pub fn is_on(&self) -> bool {
        !matches!(self, Dealias::Off | Dealias::Intervals(0))
    }

    /// Refuses more than [`MAX_INTERVALS`] intervals.
    pub fn validate(&self) -> Result<()> {
        match self {
            Dealias::Intervals(k) if *k > MAX_INTERVALS => Err(invalid(
                "dealias",
                format!("{k} Nyquist intervals is more than the {MAX_INTERVALS} supported"),
            )),
            _ => Ok(()),
        }
    }
}

/// Flow pixels, the only ones unwrapped, have a power Doppler at least this many dB above the
/// noise floor of its depth row ([`crate::estimate::masks::above_noise_floor`]). Elsewhere the projections
/// are noise, which unwrapping would only turn into large random speeds.
pub const FLOW_MARGIN_DB: f64 = 3.0;

/// Flow pixels of a power-Doppler image `power` on a grid of `grid_step_m` (m), the only ones
/// dealiased: [`FLOW_MARGIN_DB`] above the noise floor of its row, and within
/// [`super::masks::VESSEL_LOCAL_DB`] of the brightest pixel within
/// [`super::masks::VESSEL_LOCAL_RADIUS_M`] (the RI maps' vessel tests). Why the second test: a
/// bright vessel's side-lobe haze stands well above the noise floor of a clean recording, and its
/// projections vary with the angle in ways no vector explains, so some alias pattern fits them
/// better than none: on a simulated tube at 3× v_N (`tube` preset, 100 frames, no noise) haze
/// 31–36 dB below the vessel was unwrapped into flow in the tissue beside it.
pub fn flow_mask(power: &Array2<f64>, grid_step_m: f64) -> Array2<bool> {
    super::masks::VesselTests {
        margin_db: FLOW_MARGIN_DB,
        ..Default::default()
    }
    .flow_mask(power, grid_step_m)
}

/// A dealiased vector field and what the dealiasing did.
#[derive(Debug, Clone, PartialEq)]
pub struct DealiasedField {
    /// The vectors (m/s), shape (nz, nx).
    pub field: VectorField,
    /// K used (0 when off).
    pub intervals: u32,
    /// The alias counts chosen and how many pixels were unwrapped.
    pub counts: AliasCounts,
}

/// The alias counts dealiasing chose, and how many pixels it unwrapped.
#[derive(Debug, Clone, PartialEq)]
pub struct AliasCounts {
    /// Alias count of each angle at each pixel, (angles, nz, nx): the unwrapped projection is
    /// V_θ + 2·k·v_N; 0 where nothing was unwrapped.
    pub alias_counts: Array3<i8>,
    /// Flow pixels whose levels were chosen (in regions of at least [`MIN_REGION_PIXELS`]).
    pub dealiased_pixels: usize,
    /// Of those, the pixels with a non-zero alias count at some angle.
    pub unwrapped_pixels: usize,
    /// Of those, the pixels with an alias count of ±K at some angle.
    pub at_limit_pixels: usize,
}

impl AliasCounts {
    /// Nothing unwrapped: every count 0 for projections of shape `dim` (angles, nz, nx).
    pub fn none(dim: (usize, usize, usize)) -> AliasCounts {
        AliasCounts {
            alias_counts: Array3::zeros(dim),
            dealiased_pixels: 0,
            unwrapped_pixels: 0,
            at_limit_pixels: 0,
        }
    }
}

/// Vector field from the projection maps `projections` (see [`Projections`]), dealiased as
/// `dealias` says (see the module docs): each projection unwrapped by its own Nyquist velocity
/// (broadcast one value with [`uniform`]); `quality` (nz, nx), e.g. power Doppler, breaks ties
/// between equally reliable joins (strongest first); only pixels of `flow` (nz, nx) are
/// unwrapped. With [`Dealias::Off`] it is [`vector::vector_velocity_with`].
///
/// With measured lateral weights the alias pattern is still chosen with the model's rows:
/// measured weights differ from sin θ by a few hundredths, which moves a projection by a
/// fraction of a mm/s at the paper's speeds, far less than the 2·v_N a wrong count costs. The
/// unwrapped projections V_θ + 2k·v_N are then fitted with the measured rows.
pub fn dealiased_vectors(
    projections: &Projections,
    estimator: &Estimator,
    dealias: Dealias,
    quality: ArrayView2<f64>,
    flow: ArrayView2<bool>,
) -> Result<DealiasedField> {
    let estimators = std::slice::from_ref(estimator);
    let mut out = dealiased_vectors_each(projections, estimators, dealias, quality, flow)?;
    Ok(out.remove(0))
}

/// [`dealiased_vectors`] for each of `estimators`, in order, at the cost of little more
/// than the most expensive one: the levels are settled once, on least-squares candidates, for
/// all of them (as each alone would).
pub fn dealiased_vectors_each(
    projections: &Projections,
    estimators: &[Estimator],
    dealias: Dealias,
    quality: ArrayView2<f64>,
    flow: ArrayView2<bool>,
) -> Result<Vec<DealiasedField>> {
    dealias.validate()?;
    let (n, nz, nx) = projections.dim();
    if quality.dim() != (nz, nx) || flow.dim() != (nz, nx) {
        return Err(Error::Shape(format!(
            "quality {:?} and flow mask {:?} for projections of {nz} × {nx} pixels",
            quality.dim(),
            flow.dim()
        )));
    }
    let Projections {
        angles,
        velocities: v_theta,
        lateral,
        nyquist,
    } = *projections;
    let fit = |projections: ArrayView3<f64>, estimator: &Estimator| {
        vector::vector_velocity_with(angles, projections, lateral, estimator)
    };
    let settled = match dealias {
        Dealias::Off | Dealias::Intervals(0) => {
            return estimators
                .iter()
                .map(|estimator| {
                    Ok(DealiasedField {
                        field: fit(v_theta, estimator)?,
                        intervals: 0,
                        counts: AliasCounts::none((n, nz, nx)),
                    })
                })
                .collect();
        }
        Dealias::Intervals(k) => settle(projections, k, quality, flow)?,
        Dealias::Auto => auto_settle(projections, quality, flow)?,
    };
    // Each estimator's own pattern within each pixel's level, then its fit of the projections
    // those counts unwrap (the plain fit where nothing is unwrapped).
    estimators
        .iter()
        .map(|estimator| {
            let counts = counts_with(projections, estimator, &settled, flow);
            let unwrapped = unwrap(v_theta, counts.alias_counts.view(), nyquist);
            Ok(DealiasedField {
                field: fit(unwrapped.view(), estimator)?,
                intervals: settled.intervals,
                counts,
            })
        })
        .collect()
}

/// Projections `v_theta` (angles, nz, nx; m/s) unwrapped by alias counts `counts`: V_θ + 2k·v_N,
/// with each projection's Nyquist velocity `nyquist` (m/s); all three of one shape.
pub fn unwrap(
    v_theta: ArrayView3<f64>,
    counts: ArrayView3<i8>,
    nyquist: ArrayView3<f64>,
) -> Array3<f64> {
    let mut unwrapped = v_theta.to_owned();
    ndarray::Zip::from(&mut unwrapped)
        .and(counts)
        .and(nyquist)
        .for_each(|u, &k, &vn| *u += 2.0 * f64::from(k) * vn);
    unwrapped
}

/// The K that [`Dealias::Auto`] picks for these projections (see there).
pub fn auto_intervals(
    projections: &Projections,
    quality: ArrayView2<f64>,
    flow: ArrayView2<bool>,
) -> Result<u32> {
    Ok(auto_settle(projections, quality, flow)?.intervals)
}

/// [`Dealias::Auto`]'s K and the levels settled at it: the search settles every K it tries, and
/// the last is the one dealiasing needs.
fn auto_settle(
    projections: &Projections,
    quality: ArrayView2<f64>,
    flow: ArrayView2<bool>,
) -> Result<Settled> {
    for k in 1..MAX_AUTO_INTERVALS {
        let settled = settle(projections, k, quality, flow)?;
        let counts = counts_at_levels(
            &settled.least_squares,
            &settled.levels,
            projections.dim(),
            k,
        );
        if (counts.at_limit_pixels as f64) < AUTO_LIMIT_FRACTION * counts.dealiased_pixels as f64 {
            return Ok(settled);
        }
    }
    settle(projections, MAX_AUTO_INTERVALS, quality, flow)
}

/// One Nyquist velocity (m/s) for every angle and pixel of projections of shape `dim`
/// (angles, nz, nx), as [`dealiased_vectors`] takes it.
pub fn uniform(nyquist: f64, dim: (usize, usize, usize)) -> Array3<f64> {
    Array3::from_elem(dim, nyquist)
}
