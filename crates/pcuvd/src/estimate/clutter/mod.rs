//! SVD clutter filtering of an IQ image series.
//!
//! The series (nz, nx, frames) is the Casorati matrix S (pixels × frames). Its temporal singular
//! vectors come from the small Gram matrix G = Sᴴ·S (frames × frames), summed in double
//! precision, by a Hermitian eigendecomposition — never a full SVD of S. Components 0..low (the
//! strongest, slow ones: tissue) and high..frames (the weakest: noise) are removed:
//! S_f = S·V_keep·V_keepᴴ.
//!
//! Automatic low cut-off: the leading components are tissue while their temporal singular vector is
//! slow (mean Doppler frequency below `tissue_frequency` × frame rate), strong (energy at least
//! 10 dB above the median component) and steep (at least 3 dB above the next component); at most
//! half the components are removed. Data with no tissue (a simulation of blood alone, a rotating
//! disk) therefore keeps every component. Steep, because tissue's components fall off fast (each
//! order of its motion far weaker than the last) while blood's, many vessels of similar strength,
//! form a plateau: without that test, the better the blood's SNR, the more of its slow components
//! were strong enough to pass for tissue (on the virtual rat brain, 10–12 components of coded
//! recordings against 5 of conventional ones, which doubled the coded vectors' RMSE).
//! Automatic high cut-off: components whose energy falls below the Marchenko–Pastur edge of white
//! noise, the noise variance estimated from the median eigenvalue, are removed.
//!
//! Similarity cut-offs (Baranger et al., IEEE TMI 2018): tissue moves as a whole, so the spatial
//! singular vectors of its components have the same magnitude map (the tissue's echogenicity),
//! and so do those of noise (the noise floor's map); blood components each light their own
//! vessels. The spatial-similarity matrix, the correlation over pixels of |u_n| with |u_m|,
//! therefore shows two bright squares: tissue at the top-left, noise at the bottom-right. The
//! cut-offs split the components into tissue, blood and noise so that a constant per pair of
//! subspaces (the two squares among six blocks) fits its off-diagonal entries best (least
//! squares; the diagonal is 1 by definition and carries nothing), the tissue square being the
//! leading one: the tissue cut-off grows while the fit improves and stops at its first best, as a
//! vascular tree whose blood components light the same vessels forms a second square after the
//! tissue's, which the best fit overall would take as tissue too. The fit scores every pair of
//! cut-offs in O(1) from a summed-area table, O(N²) in all, as the follow-up (Baranger et al.,
//! IEEE TUFFC 2023) made it fast. A square needs two components: a still tissue of a single
//! component forms no square, and `Auto` is the cut-off that sees it.
//!
//! Block-wise filtering (Song et al., IEEE TMI 2017): the image is cut into overlapping blocks,
//! each block's Casorati matrix filtered on its own, with its own cut-offs by the same rule, and
//! the blocks blended back with tent weights (half-block overlap: every pixel lies in up to four
//! blocks). Tissue moves and echoes differently across a large field of view (a bright layer
//! under the probe, motion that grows with depth), so one global set of temporal vectors needs
//! more components to hold it than each block's local, nearly rigid, tissue does; a block's
//! filter can therefore cut fewer components, and less slow flow with them, where its tissue is
//! simple. Its SVD needs at least as many pixels as frames to see a noise floor: a smaller block
//! grows until it holds them. A block cuts at most the components the whole image's rule cuts
//! (the tissue seen on some pixels has at most the whole tissue's rank): within a small block a
//! wide, slow vessel is strong and steep enough to pass for tissue. A block's Gram matrix is the
//! sum of those of the cells the blocks' edges cut the image into, each summed once; a block's
//! sides are made even, so that the half-block steps cut the image into cells of half a block,
//! four to a block; the whole image's Gram matrix, which caps the blocks' cut-offs, is the sum
//! of the cells' too, and the cells that fit in the room the series' compound will take later
//! are kept for the blocks rather than summed again. Only the eigenpairs a block's rule reads
//! are found: capped by the whole image's cut-off, a block needs a few leading ones, which Krylov
//! iteration finds in O(n²) products where an upper bound of the median (the mean of the ranks
//! above it) decides the rule as the median would; elsewhere the leading eigenvalues and the
//! median by bisection after the O(n³) reduction to tridiagonal form. The blend is summed over
//! a band of a block's rows, each row going back into the series once no block reads it again,
//! rather than over a second whole series.

use faer::linalg::matmul::triangular::{self, BlockStructure};
use faer::{Mat, MatMut, MatRef, Side, c32, c64};
use ndarray::{Array2, Array3};
use num_complex::Complex32;
use rayon::prelude::*;

use super::leading_eigen;
use crate::core::error::{Error, Result, invalid};

mod blocks;
mod cut_offs;

pub use blocks::BlockLayout;
use blocks::*;
use cut_offs::*;
pub use cut_offs::{fit_two_squares, spatial_similarity};

/// How a rank cut-off is chosen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RankCut {
    /// Remove nothing on this side.
    Off,
    /// A fixed number of components.
    Fixed(usize),
    /// Chosen from the data by energy and Doppler frequency (see the module documentation).
    Auto,
    /// Chosen from the spatial similarity of the singular vectors (see the module documentation).
    Similarity,
}

impl std::str::FromStr for RankCut {
    type Err = String;

    /// Parses "off" (or "none"), "auto", "similarity" or a number of components.
    fn from_str(text: &str) -> std::result::Result<Self, String> {
        match text {
            "off" | "none" => Ok(RankCut::Off),
            "auto" => Ok(RankCut::Auto),
            "similarity" => Ok(RankCut::Similarity),
            n => n.parse::<usize>().map(RankCut::Fixed).map_err(|_| {
                format!(
                    "{n:?}: expected \"auto\", \"similarity\", \"off\" or a number of components"
                )
            }),
        }
    }
}

/// SVD clutter-filter settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClutterParams {
    /// Number of leading (tissue) components to remove.
    pub low: RankCut,
    /// Index of the first trailing (noise) component to remove; `Off` keeps all.
    pub high: RankCut,
    /// Tissue frequency limit as a fraction of the frame rate (used by `low: Auto`).
    pub tissue_frequency: f64,
    /// Block-wise filtering: the blocks' size (rows, columns of pixels; grown, the shorter side
    /// first, until a block holds as many pixels as frames); `None` filters the whole image at
    /// once.
    pub blocks: Option<(usize, usize)>,
}

impl Default for ClutterParams {
    fn default() -> Self {
        ClutterParams {
            low: RankCut::Auto,
            high: RankCut::Off,
            tissue_frequency: 0.02,
            blocks: None,
        }
    }
}

impl ClutterParams {
    /// These settings with their blocks grown as a series of `frames` frames on an `(nz, nx)`
    /// image grows them: the blocks the segments of one run share, grown for its longest
    /// segment, so that a shorter one (the last) keeps the others' layout and its block
    /// cut-offs line up with theirs.
    pub fn with_blocks_for(&self, (nz, nx): (usize, usize), frames: usize) -> ClutterParams {
        ClutterParams {
            blocks: (self.blocks).map(|size| holding_frames((nz, nx), size, frames)),
            ..*self
        }
    }

    /// Refuses fixed cut-offs that would keep no component of a series of `frames` frames
    /// (the shortest series the filter will see), before any image is formed: the filter
    /// itself would refuse them only once it reached them.
    pub fn check_for(&self, frames: usize) -> Result<()> {
        let fixed = |cut: RankCut| match cut {
            RankCut::Fixed(k) => Some(k),
            _ => None,
        };
        let keeps_none = match (fixed(self.low), fixed(self.high)) {
            (Some(low), Some(high)) => low >= high || high > frames,
            (Some(low), None) => low >= frames,
            (None, Some(high)) => high == 0 || high > frames,
            (None, None) => false,
        };
        if keeps_none {
            let shown = |cut: RankCut| match cut {
                RankCut::Fixed(k) => k.to_string(),
                RankCut::Off => "off".into(),
                RankCut::Auto | RankCut::Similarity => "chosen from the data".into(),
            };
            return Err(invalid(
                "clutter filter",
                format!(
                    "cut-offs low = {}, high = {} keep no component of the {frames} frames it \
                     filters at a time (the low cut-off removes that many leading components, \
                     the high one every component from that index on)",
                    shown(self.low),
                    shown(self.high)
                ),
            ));
        }
        Ok(())
    }
}

/// What the filter did.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ClutterReport {
    /// Components removed from the top (tissue).
    pub low: usize,
    /// First component removed from the bottom (noise); = frames when none.
    pub high: usize,
    /// Singular values of S, descending (empty for a block-wise filter: each block has its own).
    pub singular_values: Vec<f64>,
    /// Block-wise filtering: each block's (low, high) cut-offs, block rows first (`low` and
    /// `high` above are then their medians); empty for a whole-image filter.
    #[serde(default)]
    pub block_cut_offs: Vec<(usize, usize)>,
    /// Block-wise filtering: where the blocks lie; `None` for a whole-image filter.
    #[serde(default)]
    pub block_layout: Option<BlockLayout>,
}

impl ClutterReport {
    /// The cut-offs as a run records them, with the blocks' ranges when it worked block-wise.
    pub fn cut_offs(&self) -> CutOffs {
        let range = |pick: fn(&(usize, usize)) -> usize| {
            let values = self.block_cut_offs.iter().map(pick);
            Some([values.clone().min()?, values.max()?])
        };
        CutOffs {
            low: self.low,
            high: self.high,
            block_low_range: range(|c| c.0),
            block_high_range: range(|c| c.1),
        }
    }
}

/// A filter's cut-offs in brief: components `low..high` kept and, block-wise, the least and the
/// most its blocks chose; what a time series keeps of each ensemble's [`ClutterReport`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct CutOffs {
    /// Components removed from the top (tissue); block-wise, the blocks' median.
    pub low: usize,
    /// First component removed from the bottom (noise); block-wise, the blocks' median.
    pub high: usize,
    /// Block-wise: the least and the most components a block removed from the top.
    pub block_low_range: Option<[usize; 2]>,
    /// Block-wise: the least and the most of the blocks' `high`.
    pub block_high_range: Option<[usize; 2]>,
}

const CHUNK: usize = 4096;
/// Pixels per double-precision copy the Gram matrix is summed from (a few MB per thread).
const GRAM_CHUNK: usize = 1024;

/// `samples` as faer's complex type, which is the same type.
fn as_faer(samples: &[Complex32]) -> &[c32] {
    // SAFETY: num_complex::Complex32 and faer's c32 are the same type.
    unsafe { std::slice::from_raw_parts(samples.as_ptr() as *const c32, samples.len()) }
}

/// Filters `series` (nz, nx, frames) in place and reports the cut-offs used.
pub fn svd_filter(series: &mut Array3<Complex32>, params: &ClutterParams) -> Result<ClutterReport> {
    svd_filter_reusing(series, params, &mut ClutterScratch::default())
}

/// Filters each of `series` (a recording's angles) in turn, as [`svd_filter`] does, calling
/// `before(k)` before series k: memory one filter asked for serves the next, and is given back
/// before this returns.
pub fn svd_filter_each(
    series: &mut [Array3<Complex32>],
    params: &ClutterParams,
    mut before: impl FnMut(usize),
) -> Result<Vec<ClutterReport>> {
    let mut scratch = ClutterScratch::default();
    (series.iter_mut().enumerate())
        .map(|(k, series)| {
            before(k);
            svd_filter_reusing(series, params, &mut scratch)
        })
        .collect()
}

/// [`svd_filter`], with memory kept in `scratch` from the series filtered before: the same
/// series and report.
fn svd_filter_reusing(
    series: &mut Array3<Complex32>,
    params: &ClutterParams,
    scratch: &mut ClutterScratch,
) -> Result<ClutterReport> {
    match params.blocks {
        Some(size) => filter_blocks(series, params, size, scratch),
        None => filter_whole(series, params),
    }
}

/// What [`filter_with_gram`] does with the cut-offs it chooses.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Pass {
    /// Filter the series, removing at most `low_cap` leading components when given.
    Filter { low_cap: Option<usize> },
    /// Choose the cut-offs only, leaving the series as it is.
    CutOffsOnly,
}

/// The whole image's filter: one SVD of its Casorati matrix.
fn filter_whole(series: &mut Array3<Complex32>, params: &ClutterParams) -> Result<ClutterReport> {
    let (nz, nx, frames) = series.dim();
    let pixels = nz * nx;
    if frames < 2 || pixels == 0 {
        return Err(invalid(
            "clutter filter",
            format!("needs ≥ 2 frames and pixels, got {frames} frames"),
        ));
    }
    if params.low == RankCut::Off && params.high == RankCut::Off {
        return Ok(ClutterReport {
            low: 0,
            high: frames,
            singular_values: vec![],
            block_cut_offs: Vec::new(),
            block_layout: None,
        });
    }
    let data = series
        .as_slice_mut()
        .ok_or_else(|| Error::Shape("image series must be contiguous".into()))?;

    let gram = gram_of(data, frames);
    filter_with_gram(
        data,
        frames,
        gram,
        params,
        Pass::Filter { low_cap: None },
        true,
    )
}

/// The whole image's cut-offs, given its Gram matrix `gram` (lower half), the series left as it
/// is.
fn cut_offs_with_gram(
    series: &mut Array3<Complex32>,
    params: &ClutterParams,
    gram: Mat<c64>,
) -> Result<ClutterReport> {
    let frames = series.dim().2;
    let data = series
        .as_slice_mut()
        .ok_or_else(|| Error::Shape("image series must be contiguous".into()))?;
    filter_with_gram(data, frames, gram, params, Pass::CutOffsOnly, true)
}

/// The cut-offs `low` and `high` of `frames` components, uncrossed where `params` chose one
/// from the data: it gives way to one the user fixed (the noise cut-off to a fixed tissue one:
/// the series keeps the one component after it), and of two chosen from the data the noise
/// cut-off gives way. The data can say they cross only once the images are formed, and the
/// run's work is kept. Fixed cut-offs that cross are left so: they were refused before any
/// work (`check_for`).
fn uncrossed(low: usize, high: usize, params: &ClutterParams, frames: usize) -> (usize, usize) {
    let chosen = |cut: RankCut| matches!(cut, RankCut::Auto | RankCut::Similarity);
    if low < high {
        (low, high)
    } else if chosen(params.high) && low < frames {
        (low, low + 1)
    } else if chosen(params.low) && high > 0 {
        (high - 1, high)
    } else {
        (low, high)
    }
}

/// The filter of `data` (pixels × frames, row-major) given its Gram matrix `gram` (lower half);
/// the report's singular values are all of them with `every_value`, else those the rule read.
fn filter_with_gram(
    data: &mut [Complex32],
    frames: usize,
    gram: Mat<c64>,
    params: &ClutterParams,
    pass: Pass,
    every_value: bool,
) -> Result<ClutterReport> {
    let pixels = data.len() / frames;
    let low_cap = match pass {
        Pass::Filter { low_cap } => low_cap,
        Pass::CutOffsOnly => None,
    };
    let spectrum = Spectrum::of(&gram, params, low_cap, every_value)?;
    let (eigenvalues, vectors) = (&spectrum.eigenvalues, &spectrum.vectors);

    let similar =
        (params.low == RankCut::Similarity || params.high == RankCut::Similarity).then(|| {
            let descending = Mat::<c32>::from_fn(frames, frames, |i, k| {
                let v = vectors[(i, k)];
                c32::new(v.re as f32, v.im as f32)
            });
            fit_two_squares(
                &spatial_similarity(data, frames, descending.as_ref()),
                low_cap,
            )
        });
    let low = match params.low {
        RankCut::Off => 0,
        RankCut::Fixed(k) => k,
        RankCut::Auto => auto_low(
            &spectrum,
            frames,
            params.tissue_frequency,
            low_cap.unwrap_or(frames),
        ),
        RankCut::Similarity => similar.map_or(0, |(low, _)| low),
    };
    let low = low.min(low_cap.unwrap_or(low));
    let high = match params.high {
        RankCut::Off => frames,
        RankCut::Fixed(k) => k,
        RankCut::Auto => auto_high(eigenvalues, spectrum.median, pixels),
        RankCut::Similarity => similar.map_or(frames, |(_, high)| high),
    };
    let (low, high) = uncrossed(low, high, params, frames);
    if low >= high || high > frames {
        return Err(invalid(
            "clutter filter",
            format!("cut-offs low = {low}, high = {high} keep no component of {frames} frames"),
        ));
    }
    let singular_values = eigenvalues.iter().map(|v| v.sqrt()).collect();
    if (low == 0 && high == frames) || pass == Pass::CutOffsOnly {
        return Ok(ClutterReport {
            low,
            high,
            singular_values,
            block_cut_offs: Vec::new(),
            block_layout: None,
        });
    }

    // Projection onto the kept temporal subspace, S_f = S·V_keep·V_keepᴴ, or, the same, S minus
    // its part in the removed subspace, S_f = S − S·V_cut·V_cutᴴ (the eigenvectors are
    // orthonormal): applied through whichever subspace is smaller, two thin products of
    // pixels × frames × rank instead of one of pixels × frames² (tissue and noise cut-offs
    // remove a few components of hundreds).
    let keep: Vec<usize> = (low..high).collect();
    let cut: Vec<usize> = (0..low).chain(high..frames).collect();
    // A spectrum of only the leading vectors (no noise cut-off) holds the cut ones and no
    // others, even where the cut is not the smaller side (half the frames).
    let through_cut = cut.len() < keep.len() || vectors.ncols() < frames;
    debug_assert!(
        vectors.ncols() == frames || (through_cut && high == frames && low <= vectors.ncols()),
        "the spectrum holds the vectors the projection reads"
    );
    let basis_of = |columns: &[usize]| {
        Mat::<c32>::from_fn(frames, columns.len(), |i, k| {
            let v = vectors[(i, columns[k])];
            c32::new(v.re as f32, v.im as f32)
        })
    };
    let basis = basis_of(if through_cut { &cut } else { &keep });
    data.par_chunks_mut(CHUNK * frames).for_each(|chunk| {
        let rows = chunk.len() / frames;
        let mut coefficients = Mat::<c32>::zeros(rows, basis.ncols());
        faer::linalg::matmul::matmul(
            coefficients.as_mut(),
            faer::Accum::Replace,
            MatRef::from_row_major_slice(as_faer(chunk), rows, frames),
            basis.as_ref(),
            c32::new(1.0, 0.0),
            faer::Par::Seq,
        );
        // SAFETY: num_complex::Complex32 and faer's c32 are the same type.
        let out =
            unsafe { std::slice::from_raw_parts_mut(chunk.as_mut_ptr() as *mut c32, chunk.len()) };
        let out = faer::MatMut::from_row_major_slice_mut(out, rows, frames);
        let (accum, alpha) = if through_cut {
            (faer::Accum::Add, c32::new(-1.0, 0.0))
        } else {
            (faer::Accum::Replace, c32::new(1.0, 0.0))
        };
        faer::linalg::matmul::matmul(
            out,
            accum,
            coefficients.as_ref(),
            basis.adjoint(),
            alpha,
            faer::Par::Seq,
        );
    });
    Ok(ClutterReport {
        low,
        high,
        singular_values,
        block_cut_offs: Vec::new(),
        block_layout: None,
    })
}

/// The lower half of the Gram matrix G = Sᴴ S of `data` (pixels × frames, row-major), summed in
/// double precision.
///
/// G squares the series' dynamic range (tissue components 80 dB apart in energy, as a brain's
/// are within a few millimetres, are 10⁻⁸ apart in G), and a single-precision product resolves
/// only about 10⁻⁷ of its largest entry, so the weaker tissue components' vectors would come out
/// as rounding noise and their tissue stay in the filtered series. G is Hermitian and the
/// eigensolver reads its lower half only: computing that half alone halves the largest product
/// of the filter.
///
/// The chunks' products are added in an order the data fix
/// ([`sum_of_chunks`](crate::core::parallel::sum_of_chunks)): the same matrix on any number of
/// cores.
fn gram_of(data: &[Complex32], frames: usize) -> Mat<c64> {
    crate::core::parallel::sum_of_chunks(
        data,
        GRAM_CHUNK * frames,
        || Mat::<c64>::zeros(frames, frames),
        |chunk| lower_gram(chunk.len() / frames, frames, |i, j| chunk[i * frames + j]),
        |sum, part| *sum += part,
    )
}

/// The lower half of the Gram matrix of the `rows` × `frames` matrix whose entries `entry` gives.
fn lower_gram(rows: usize, frames: usize, entry: impl Fn(usize, usize) -> Complex32) -> Mat<c64> {
    let s = Mat::<c64>::from_fn(rows, frames, |i, j| {
        let v = entry(i, j);
        c64::new(v.re as f64, v.im as f64)
    });
    lower_conj_product(s.transpose(), s.as_ref())
}

/// The lower half of the Gram matrix G = SᴴS of the pixels × frames matrix S whose transpose
/// `pixels` holds (frames × pixels: each pixel's time series one column, contiguous):
/// G = conj(Sᵀ)·(Sᵀ)ᵀ, written into the lower half of `gram` (frames × frames; its upper half
/// left as it was).
fn lower_gram_of_columns_into(gram: MatMut<'_, c64>, pixels: MatRef<'_, c64>) {
    lower_conj_product_into(gram, pixels, pixels.transpose())
}

/// The lower half (the diagonal included) of the square product conj(`left`)·`right`.
fn lower_conj_product(left: MatRef<'_, c64>, right: MatRef<'_, c64>) -> Mat<c64> {
    let mut g = Mat::<c64>::zeros(left.nrows(), right.ncols());
    lower_conj_product_into(g.as_mut(), left, right);
    g
}

/// [`lower_conj_product`] written into the lower half of `g`, its upper half left as it was.
fn lower_conj_product_into(g: MatMut<'_, c64>, left: MatRef<'_, c64>, right: MatRef<'_, c64>) {
    triangular::matmul_with_conj(
        g,
        BlockStructure::TriangularLower,
        faer::Accum::Replace,
        left,
        BlockStructure::Rectangular,
        faer::Conj::Yes,
        right,
        BlockStructure::Rectangular,
        faer::Conj::No,
        c64::new(1.0, 0.0),
        faer::Par::Seq,
    );
}

#[cfg(test)]
mod tests;
