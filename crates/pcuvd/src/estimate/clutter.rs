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
//! four to a block. Only the eigenvalues a block's rule reads (the leading ones and the median)
//! are found, by bisection, and the blend is summed over a band of a block's rows, each row going
//! back into the series once no block reads it again, rather than over a second whole series.

use faer::linalg::matmul::triangular::{self, BlockStructure};
use faer::{Mat, MatRef, Side, c32, c64};
use ndarray::{Array2, Array3};
use num_complex::Complex32;
use rayon::prelude::*;

use super::leading_eigen;
use crate::core::error::{Error, Result, invalid};

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
    match params.blocks {
        Some(size) => filter_blocks(series, params, size),
        None => filter_whole(series, params, Pass::Filter { low_cap: None }),
    }
}

/// What [`filter_whole`] does with the cut-offs it chooses.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Pass {
    /// Filter the series, removing at most `low_cap` leading components when given.
    Filter { low_cap: Option<usize> },
    /// Choose the cut-offs only, leaving the series as it is.
    CutOffsOnly,
}

/// Starts of the blocks of `size` that cover `n` pixels at half-block steps, the last one flush
/// with the end.
fn block_starts(n: usize, size: usize) -> Vec<usize> {
    let step = (size / 2).max(1);
    let mut starts: Vec<usize> = (0..n.saturating_sub(size)).step_by(step).collect();
    starts.push(n.saturating_sub(size));
    starts.dedup();
    starts
}

/// Tent weight of a block's pixel `i` of `size`: highest in the middle, never zero, so that the
/// image's edges (covered by one block) keep their own filtered values.
fn tent(i: usize, size: usize) -> f32 {
    (i + 1).min(size - i) as f32
}

/// Where a block-wise filter's blocks lie on an image: their size and their first rows and
/// columns (pixels), at half-block steps, the last ones flush with the image's edges.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct BlockLayout {
    /// A block's rows and columns of pixels.
    pub size: (usize, usize),
    /// Each row of blocks' first row (pixel).
    pub z_starts: Vec<usize>,
    /// Each column of blocks' first column (pixel).
    pub x_starts: Vec<usize>,
}

impl BlockLayout {
    /// The blocks of `size` (rows, columns; clamped to the image) over an image of `shape`
    /// (nz, nx) pixels.
    pub fn new((nz, nx): (usize, usize), (rows, cols): (usize, usize)) -> BlockLayout {
        let size = (rows.clamp(1, nz.max(1)), cols.clamp(1, nx.max(1)));
        BlockLayout {
            size,
            z_starts: block_starts(nz, size.0),
            x_starts: block_starts(nx, size.1),
        }
    }

    /// The image's shape (nz, nx): the last blocks end flush with its edges.
    pub fn shape(&self) -> (usize, usize) {
        let end = |starts: &[usize], size| starts.last().map_or(0, |&s| s + size);
        (
            end(&self.z_starts, self.size.0),
            end(&self.x_starts, self.size.1),
        )
    }

    /// Each block's (row, column) of pixels where it starts, block rows first: the order of a
    /// report's `block_cut_offs`.
    pub fn origins(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        (self.z_starts.iter()).flat_map(|&z| self.x_starts.iter().map(move |&x| (z, x)))
    }

    /// Per-block `values` (block rows first) blended onto the image's pixels as the filter blends
    /// the blocks' series: each pixel gets the tent-weighted mean over the blocks that hold it
    /// (for the blocks' cut-offs, how many components were cut there, in effect).
    pub fn blend(&self, values: &[f64]) -> Result<Array2<f64>> {
        let blocks = self.z_starts.len() * self.x_starts.len();
        if values.len() != blocks {
            return Err(Error::Shape(format!(
                "{} values for {blocks} blocks",
                values.len()
            )));
        }
        let (rows, cols) = self.size;
        let mut sums = Array2::<f64>::zeros(self.shape());
        let mut weights = Array2::<f64>::zeros(self.shape());
        for ((z0, x0), &value) in self.origins().zip(values) {
            for i in 0..rows {
                for j in 0..cols {
                    let w = f64::from(tent(i, rows) * tent(j, cols));
                    sums[[z0 + i, x0 + j]] += w * value;
                    weights[[z0 + i, x0 + j]] += w;
                }
            }
        }
        Ok(sums / weights)
    }
}

fn filter_blocks(
    series: &mut Array3<Complex32>,
    params: &ClutterParams,
    size: (usize, usize),
) -> Result<ClutterReport> {
    let (nz, nx, frames) = series.dim();
    let removes_nothing = params.low == RankCut::Off && params.high == RankCut::Off;
    if nz == 0 || nx == 0 || frames < 2 || removes_nothing {
        // The whole image's filter refuses what it cannot filter, and returns what needs none.
        return filter_whole(series, params, Pass::Filter { low_cap: None });
    }
    let layout = BlockLayout::new((nz, nx), holding_frames((nz, nx), size, frames));
    let (rows, cols) = layout.size;
    let whole = ClutterParams {
        blocks: None,
        ..*params
    };
    // A block's tissue is the whole image's seen on some of its pixels: its rank is at most the
    // whole's, so a block cuts at most the components the whole image's rule cuts. Without that
    // cap a block holding a wide, slow vessel cuts its blood as tissue (strong, slow and steep
    // within the block).
    let low_cap = match params.low {
        RankCut::Auto | RankCut::Similarity => {
            Some(filter_whole(series, &whole, Pass::CutOffsOnly)?.low)
        }
        RankCut::Off => Some(0),
        RankCut::Fixed(_) => None,
    };
    let blocks = layout.z_starts.len() * layout.x_starts.len();
    if low_cap == Some(0) && params.high == RankCut::Off {
        // Every block would keep all its components: the series stays as it is (bit for bit;
        // blending unchanged blocks would round it).
        return Ok(ClutterReport {
            low: 0,
            high: frames,
            singular_values: Vec::new(),
            block_cut_offs: vec![(0, frames); blocks],
            block_layout: Some(layout),
        });
    }
    // Blocks overlap by half: a block's Gram matrix is the sum of those of the cells the blocks'
    // edges cut the image into, each cell's summed once and shared by the (up to four) blocks
    // that hold it, rather than every pixel's four times.
    let z_cuts = cell_edges(&layout.z_starts, rows);
    let x_cuts = cell_edges(&layout.x_starts, cols);
    let cell_gram = |series: &Array3<Complex32>, za: usize, xa: usize| {
        let (x0, x1) = (x_cuts[xa], x_cuts[xa + 1]);
        let runs = (z_cuts[za]..z_cuts[za + 1]).map(|z| series.slice(ndarray::s![z, x0..x1, ..]));
        let mut pixels = Mat::<c64>::zeros(frames, (z_cuts[za + 1] - z_cuts[za]) * (x1 - x0));
        for (k, value) in runs.flat_map(|run| run.into_iter()).enumerate() {
            pixels[(k % frames, k / frames)] = c64::new(value.re as f64, value.im as f64);
        }
        lower_gram_of_columns(pixels.as_ref())
    };
    // Cell rows' Gram matrices, kept while a row of blocks still needs them.
    let mut cell_rows: std::collections::BTreeMap<usize, Vec<Mat<c64>>> = Default::default();
    // The blocks' tent-weighted sums over the rows that a row of blocks still to come may add
    // to, `blended.start..blended.start + rows`: the rows above a row of blocks are final, and go
    // back into the series before it is filtered, as no block reads them again.
    let mut blended = Blended {
        sums: vec![Complex32::new(0.0, 0.0); rows * nx * frames],
        weights: Array2::<f32>::zeros((nz, nx)),
        start: 0,
    };
    let mut block_cut_offs = Vec::with_capacity(blocks);
    // One row of blocks at a time: its blocks are filtered in parallel (each block's own filter
    // is one chunk of pixels, sequential), then blended in.
    for &z0 in &layout.z_starts {
        blended.settle(series, z0)?;
        cell_rows.retain(|&za, _| z_cuts[za] >= z0);
        let missing: Vec<(usize, usize)> = cells_within(&z_cuts, z0, rows)
            .filter(|za| !cell_rows.contains_key(za))
            .flat_map(|za| (0..x_cuts.len() - 1).map(move |xa| (za, xa)))
            .collect();
        let grams: Vec<Mat<c64>> = missing
            .par_iter()
            .map(|&(za, xa)| cell_gram(series, za, xa))
            .collect();
        for ((za, _), gram) in missing.into_iter().zip(grams) {
            cell_rows.entry(za).or_default().push(gram);
        }
        let filtered =
            layout
                .x_starts
                .par_iter()
                .map(|&x0| {
                    let mut gram = Mat::<c64>::zeros(frames, frames);
                    for za in cells_within(&z_cuts, z0, rows) {
                        for xa in cells_within(&x_cuts, x0, cols) {
                            add_lower(&mut gram, &cell_rows[&za][xa]);
                        }
                    }
                    // The block's pixels (rows × cols × frames), a pixel row's run at a time.
                    let mut block = Vec::with_capacity(rows * cols * frames);
                    for z in z0..z0 + rows {
                        let run = series.slice(ndarray::s![z, x0..x0 + cols, ..]);
                        block.extend_from_slice(run.as_slice().ok_or_else(|| {
                            Error::Shape("image series must be contiguous".into())
                        })?);
                    }
                    // A block's singular values are not reported: only those its rule reads.
                    filter_with_gram(
                        &mut block,
                        frames,
                        gram,
                        &whole,
                        Pass::Filter { low_cap },
                        false,
                    )
                    .map(|report| (x0, block, report))
                })
                .collect::<Result<Vec<_>>>()?;
        for (x0, block, report) in filtered {
            block_cut_offs.push((report.low, report.high));
            blended.add(&block, (z0, x0), (rows, cols), frames);
        }
    }
    blended.settle(series, nz)?;
    let median = |pick: fn(&(usize, usize)) -> usize| {
        let mut values: Vec<usize> = block_cut_offs.iter().map(pick).collect();
        values.sort_unstable();
        values[values.len() / 2]
    };
    Ok(ClutterReport {
        low: median(|c| c.0),
        high: median(|c| c.1),
        singular_values: Vec::new(),
        block_cut_offs,
        block_layout: Some(layout),
    })
}

/// The tent-weighted sums of filtered blocks over a band of image rows, and every pixel's sum of
/// weights.
struct Blended {
    /// The sums over rows `start..start + rows` (row-major: rows × nx × frames).
    sums: Vec<Complex32>,
    /// Each pixel's sum of the weights of the blocks added over it.
    weights: Array2<f32>,
    /// The image row the band starts at.
    start: usize,
}

impl Blended {
    /// Adds the filtered `block` (rows × cols × frames, row-major) whose first pixel is at
    /// (z0, x0), a row within the band, each pixel weighted by its tents.
    fn add(
        &mut self,
        block: &[Complex32],
        (z0, x0): (usize, usize),
        (rows, cols): (usize, usize),
        frames: usize,
    ) {
        let row_len = self.weights.ncols() * frames;
        for i in 0..rows {
            let band_row = (z0 + i - self.start) * row_len;
            for j in 0..cols {
                let w = tent(i, rows) * tent(j, cols);
                self.weights[[z0 + i, x0 + j]] += w;
                let at = band_row + (x0 + j) * frames;
                let from = (i * cols + j) * frames;
                for (sum, &v) in self.sums[at..at + frames]
                    .iter_mut()
                    .zip(&block[from..from + frames])
                {
                    *sum += v * w;
                }
            }
        }
    }

    /// Writes the band's rows above `until` into `series` (each pixel its sum over its weight:
    /// the blend) and moves the band down to start there.
    fn settle(&mut self, series: &mut Array3<Complex32>, until: usize) -> Result<()> {
        let (_, nx, frames) = series.dim();
        let row_len = nx * frames;
        let done = until - self.start;
        for r in 0..done {
            let z = self.start + r;
            let mut row = series.slice_mut(ndarray::s![z, .., ..]);
            let out = row
                .as_slice_mut()
                .ok_or_else(|| Error::Shape("image series must be contiguous".into()))?;
            let sums = &self.sums[r * row_len..(r + 1) * row_len];
            for ((out, sums), &w) in out
                .chunks_mut(frames)
                .zip(sums.chunks(frames))
                .zip(self.weights.row(z))
            {
                for (o, &s) in out.iter_mut().zip(sums) {
                    *o = s / w;
                }
            }
        }
        let moved = (done * row_len).min(self.sums.len());
        self.sums.copy_within(moved.., 0);
        let kept = self.sums.len() - moved;
        self.sums[kept..].fill(Complex32::new(0.0, 0.0));
        self.start = until;
        Ok(())
    }
}

/// The block size (rows, columns) on an image of `shape`: `size` clamped to the image, grown a
/// row or a column at a time (the shorter side first) until a block holds at least `frames`
/// pixels, as a block's SVD needs to see a noise floor (the whole image where it holds fewer),
/// then each side shorter than the image made even (a pixel more where it is odd). Blocks of
/// an even side at half-block steps cut the image into cells of half a block, four to a block;
/// an odd side's half-steps leave one-pixel cells between the others, up to five a side, and a
/// block sums up to 25 cells' Gram matrices instead of four.
fn holding_frames(
    (nz, nx): (usize, usize),
    (rows, cols): (usize, usize),
    frames: usize,
) -> (usize, usize) {
    let (mut rows, mut cols) = (rows.clamp(1, nz), cols.clamp(1, nx));
    while rows * cols < frames && (rows < nz || cols < nx) {
        if cols == nx || (rows <= cols && rows < nz) {
            rows += 1;
        } else {
            cols += 1;
        }
    }
    let even = |side: usize, image: usize| (side + side % 2).min(image);
    (even(rows, nz), even(cols, nx))
}

/// Adds the lower half (the diagonal included) of the square `term` to `sum`'s: all that the
/// eigensolver reads, at half the work of adding whole matrices.
fn add_lower(sum: &mut Mat<c64>, term: &Mat<c64>) {
    let n = sum.nrows();
    for j in 0..n {
        let to = sum.col_mut(j).subrows_mut(j, n - j);
        let from = term.col(j).subrows(j, n - j);
        let (to, from) = (
            to.try_as_col_major_mut()
                .expect("an owned matrix's columns are contiguous"),
            from.try_as_col_major()
                .expect("an owned matrix's columns are contiguous"),
        );
        // SAFETY: c64 is two f64 (re, im), laid out as such; the slices cover the same entries.
        let (to, from) = unsafe {
            (
                std::slice::from_raw_parts_mut(to.as_ptr_mut() as *mut f64, 2 * to.nrows()),
                std::slice::from_raw_parts(from.as_ptr() as *const f64, 2 * from.nrows()),
            )
        };
        for (t, f) in to.iter_mut().zip(from) {
            *t += f;
        }
    }
}

/// The cells along one axis (indices into `edges`) that lie within `len` pixels from `start`.
fn cells_within(edges: &[usize], start: usize, len: usize) -> impl Iterator<Item = usize> + '_ {
    (0..edges.len() - 1).filter(move |&c| edges[c] >= start && edges[c + 1] <= start + len)
}

/// The edges along one axis of the cells that blocks of `size` starting at `starts` cut it into:
/// every block's first and one-past-last pixel, in order.
fn cell_edges(starts: &[usize], size: usize) -> Vec<usize> {
    let mut edges: Vec<usize> = starts.iter().flat_map(|&s| [s, s + size]).collect();
    edges.sort_unstable();
    edges.dedup();
    edges
}

/// The whole image's filter: one SVD of its Casorati matrix.
fn filter_whole(
    series: &mut Array3<Complex32>,
    params: &ClutterParams,
    pass: Pass,
) -> Result<ClutterReport> {
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
    filter_with_gram(data, frames, gram, params, pass, true)
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
    let through_cut = cut.len() < keep.len();
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
fn gram_of(data: &[Complex32], frames: usize) -> Mat<c64> {
    data.par_chunks(GRAM_CHUNK * frames)
        .map(|chunk| {
            let rows = chunk.len() / frames;
            lower_gram(rows, frames, |i, j| chunk[i * frames + j])
        })
        .reduce(|| Mat::<c64>::zeros(frames, frames), |a, b| a + b)
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
/// G = conj(Sᵀ)·(Sᵀ)ᵀ.
fn lower_gram_of_columns(pixels: MatRef<'_, c64>) -> Mat<c64> {
    lower_conj_product(pixels, pixels.transpose())
}

/// The lower half (the diagonal included) of the square product conj(`left`)·`right`.
fn lower_conj_product(left: MatRef<'_, c64>, right: MatRef<'_, c64>) -> Mat<c64> {
    let mut g = Mat::<c64>::zeros(left.nrows(), right.ncols());
    triangular::matmul_with_conj(
        g.as_mut(),
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
    g
}

/// The least ratio (2, 3 dB) of a tissue component's energy to the next component's.
const TISSUE_STEP: f64 = 2.0;

/// The tissue rule's low cut-off among a spectrum's `components` (see the module
/// documentation), at most `limit`: the leading components that are strong, steep and slow.
fn auto_low(spectrum: &Spectrum, components: usize, tissue_frequency: f64, limit: usize) -> usize {
    let vector = |k| spectrum.vectors.col(k);
    let candidates =
        strong_and_steep(&spectrum.eigenvalues, spectrum.median, components).min(limit);
    (0..candidates)
        .find(|&k| doppler_frequency(vector(k)) >= tissue_frequency)
        .unwrap_or(candidates)
}

/// How many leading components pass the tissue rule's energy tests, at most half of the
/// `components` and one fewer than the `leading` eigenvalues given (largest first): each at
/// least 10 dB above the `median` component (strong) and [`TISSUE_STEP`] above the next
/// (steep).
fn strong_and_steep(leading: &[f64], median: f64, components: usize) -> usize {
    let median = median.max(f64::MIN_POSITIVE);
    (0..(components / 2).min(leading.len().saturating_sub(1)))
        .take_while(|&k| leading[k] >= 10.0 * median && leading[k] >= TISSUE_STEP * leading[k + 1])
        .count()
}

/// The median of `values` as the tissue rule reads it: the (n/2)-th smallest.
fn median_of(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(|a, b| a.total_cmp(b));
    sorted[values.len() / 2]
}

/// A temporal singular vector's mean Doppler frequency, as a fraction of the frame rate (0 to
/// ½): the phase of its lag-one autocorrelation over 2π.
fn doppler_frequency(v: faer::ColRef<'_, c64>) -> f64 {
    let mut r1 = c64::new(0.0, 0.0);
    for t in 0..v.nrows().saturating_sub(1) {
        r1 += v[t].conj() * v[t + 1];
    }
    r1.arg().abs() / (2.0 * std::f64::consts::PI)
}

/// A Gram matrix's eigenvalues (largest first, none below zero: all of them, or the leading
/// ones the tissue rule reads), their median, and the eigenvectors (columns, in the same order)
/// of as many leading components as the cut-offs can read.
struct Spectrum {
    eigenvalues: Vec<f64>,
    median: f64,
    vectors: Mat<c64>,
}

impl Spectrum {
    /// The spectrum of `gram` (lower half) that `params` needs. The tissue cut-offs read few
    /// vectors (`Auto`: the components passing its energy tests, at most `low_cap`; `Fixed(k)`:
    /// k), so with no noise cut-off only those are computed ([`leading_eigen`]); the similarity
    /// rule and a noise cut-off read them all. Without `every_value` (a block's filter, whose
    /// singular values nobody reports) only the eigenvalues the tissue rule reads are found: the
    /// leading ones and the median.
    fn of(
        gram: &Mat<c64>,
        params: &ClutterParams,
        low_cap: Option<usize>,
        every_value: bool,
    ) -> Result<Spectrum> {
        let frames = gram.nrows();
        let failed = |e: faer::linalg::evd::EvdError| {
            invalid(
                "clutter filter",
                format!("eigendecomposition failed: {e:?}"),
            )
        };
        let few_vectors = params.high == RankCut::Off
            && match params.low {
                RankCut::Off | RankCut::Auto => true,
                RankCut::Fixed(k) => k <= frames / 2,
                RankCut::Similarity => false,
            };
        if !few_vectors {
            let eig = gram.self_adjoint_eigen(Side::Lower).map_err(failed)?;
            // faer's are in nondecreasing order.
            let eigenvalues: Vec<f64> = (0..frames)
                .map(|k| eig.S()[frames - 1 - k].re.max(0.0))
                .collect();
            return Ok(Spectrum {
                median: median_of(&eigenvalues),
                eigenvalues,
                vectors: Mat::from_fn(frames, frames, |i, k| eig.U()[(i, frames - 1 - k)]),
            });
        }
        let reduced = leading_eigen::Tridiagonal::new(gram.as_ref());
        let (exact, median) = if every_value || params.low != RankCut::Auto {
            let exact = reduced.eigenvalues().map_err(failed)?;
            let median = median_of(&exact).max(0.0);
            (exact, median)
        } else {
            // strong_and_steep reads the leading min(frames / 2, cap) + 1 and the median.
            let leading = (frames / 2).min(low_cap.unwrap_or(frames)) + 1;
            let value = |rank| {
                reduced.eigenvalue(rank).ok_or_else(|| {
                    invalid("clutter filter", format!("no eigenvalue of rank {rank}"))
                })
            };
            let exact = (0..leading.min(frames))
                .map(value)
                .collect::<Result<Vec<_>>>()?;
            (exact, value(frames - 1 - frames / 2)?.max(0.0))
        };
        let eigenvalues: Vec<f64> = exact.iter().map(|v| v.max(0.0)).collect();
        let count = match params.low {
            RankCut::Auto => {
                strong_and_steep(&eigenvalues, median, frames).min(low_cap.unwrap_or(frames))
            }
            RankCut::Fixed(k) => k,
            RankCut::Off | RankCut::Similarity => 0,
        };
        Ok(Spectrum {
            vectors: reduced.leading_vectors(&exact, count),
            eigenvalues,
            median,
        })
    }
}

/// The spatial-similarity matrix of the components in `vectors`' columns (temporal singular
/// vectors, strongest first): C(n, m) = the correlation coefficient over pixels of |S·v_n| and
/// |S·v_m| (the spatial singular vectors' magnitudes, up to their singular values, which a
/// correlation ignores). Accumulated over pixel chunks in f64; |S·V| is never held whole.
pub fn spatial_similarity(data: &[Complex32], frames: usize, vectors: MatRef<'_, c32>) -> Mat<f64> {
    let n = vectors.ncols();
    let (products, sums) = data
        .par_chunks(CHUNK * frames)
        .map(|chunk| {
            let rows = chunk.len() / frames;
            let mut spatial = Mat::<c32>::zeros(rows, n);
            faer::linalg::matmul::matmul(
                spatial.as_mut(),
                faer::Accum::Replace,
                MatRef::from_row_major_slice(as_faer(chunk), rows, frames),
                vectors,
                c32::new(1.0, 0.0),
                faer::Par::Seq,
            );
            let magnitude = Mat::<f64>::from_fn(rows, n, |p, k| spatial[(p, k)].norm() as f64);
            let sums: Vec<f64> = (0..n).map(|k| magnitude.col(k).sum()).collect();
            (magnitude.transpose() * &magnitude, sums)
        })
        .reduce(
            || (Mat::<f64>::zeros(n, n), vec![0.0; n]),
            |(pa, sa), (pb, sb)| (pa + pb, sa.iter().zip(&sb).map(|(a, b)| a + b).collect()),
        );
    let pixels = (data.len() / frames) as f64;
    let mean: Vec<f64> = sums.iter().map(|s| s / pixels).collect();
    let covariance = |i: usize, j: usize| products[(i, j)] / pixels - mean[i] * mean[j];
    let spread: Vec<f64> = (0..n).map(|k| covariance(k, k).max(0.0).sqrt()).collect();
    Mat::from_fn(n, n, |i, j| {
        let scale = spread[i] * spread[j];
        if scale > 0.0 {
            covariance(i, j) / scale
        } else {
            0.0
        }
    })
}

/// The cut-offs (low, high) that split the components into tissue [0, low), blood [low, high) and
/// noise [high, N) such that a constant per pair of subspaces fits `similarity`'s off-diagonal
/// entries best (least squares). The tissue and noise squares are two of the six blocks; the
/// others let the tissue and the noise maps anti-correlate (echoes fade with depth while the
/// noise floor grows) without bending the squares. Candidates: low ≤ N/2 (at most half the
/// components are tissue, as for `Auto`), low < high ≤ N.
///
/// The tissue square is the leading one: `low` grows from 0 while taking the next component into
/// the tissue fits better (each with its best `high`), and stops at the first cut-off that does
/// not, even where a larger one fits better still. A vascular tree whose blood components all
/// light the same vessels forms a square of its own after the tissue's; the best fit overall may
/// then take tissue and blood together as "tissue" (on the virtual rat brain, 28–33 components
/// where the tissue holds 4–5) and the filter would remove the blood.
///
/// With `max_low` (a block of a block-wise filter: the whole image's cut-off), the best fit
/// overall, held to `max_low`. A block's few pixels make its fit noisy: on the brain's 1 mm
/// blocks its first best was often a wiggle (1–2 components where the tissue holds 4–5), and so
/// was its best below the cap (that run showed 36 % of the blood-free pixels as flow, against
/// 13 % with `Auto`); its best overall lies at or past the tissue (often the blood's square), so
/// the cap holds it to the whole image's tissue, and a block without tissue cuts less.
pub fn fit_two_squares(similarity: &Mat<f64>, max_low: Option<usize>) -> (usize, usize) {
    let fits = two_square_fits(similarity);
    let better = |a: usize, b: usize| fits[a].0 > fits[b].0 + 1e-12 * fits[b].0.abs();
    let low = match max_low {
        Some(max_low) => {
            let best =
                (0..fits.len()).fold(0, |best, low| if better(low, best) { low } else { best });
            best.min(max_low)
        }
        None => {
            let mut low = 0;
            while low + 1 < fits.len() && better(low + 1, low) {
                low += 1;
            }
            low
        }
    };
    (low, fits[low].1)
}

/// For each tissue cut-off `low` in 0..=N/2: the best fit's score (the larger, the smaller its
/// squared error; the errors of two cut-offs differ by minus the difference of their scores) and
/// its noise cut-off `high` (the largest among equal fits: the fewest components cut).
fn two_square_fits(similarity: &Mat<f64>) -> Vec<(f64, usize)> {
    let n = similarity.nrows();
    // table[(i, j)] = Σ of the off-diagonal entries of rows < i and columns < j.
    let mut table = Mat::<f64>::zeros(n + 1, n + 1);
    for i in 0..n {
        for j in 0..n {
            let entry = if i == j { 0.0 } else { similarity[(i, j)] };
            table[(i + 1, j + 1)] = entry + table[(i, j + 1)] + table[(i + 1, j)] - table[(i, j)];
        }
    }
    let block_sum = |rows: (usize, usize), columns: (usize, usize)| {
        table[(rows.1, columns.1)] - table[(rows.0, columns.1)] - table[(rows.1, columns.0)]
            + table[(rows.0, columns.0)]
    };
    let block_entries = |rows: (usize, usize), columns: (usize, usize)| {
        let (r, c) = (rows.1 - rows.0, columns.1 - columns.0);
        if rows == columns {
            r * r.saturating_sub(1)
        } else {
            r * c
        }
    };
    // Minimising the squared error of a constant per block maximises Σ (block sum)² / entries.
    let explained = |rows: (usize, usize), columns: (usize, usize)| {
        let count = block_entries(rows, columns);
        match count {
            0 => 0.0,
            _ => block_sum(rows, columns).powi(2) / count as f64,
        }
    };
    (0..=n / 2)
        .map(|low| {
            let mut best = (f64::NEG_INFINITY, n);
            for high in (low + 1..=n).rev() {
                let parts = [(0, low), (low, high), (high, n)];
                let mut score = 0.0;
                for (i, &rows) in parts.iter().enumerate() {
                    score += explained(rows, rows);
                    for &columns in &parts[i + 1..] {
                        // The block and its transpose hold the same entries.
                        score += 2.0 * explained(rows, columns);
                    }
                }
                if score > best.0 + 1e-12 * score.abs() {
                    best = (score, high);
                }
            }
            best
        })
        .collect()
}

/// The noise cut-off: the components above the Marchenko–Pastur edge of white noise whose
/// variance the `median` of the (all) `eigenvalues` gives, at least one.
fn auto_high(eigenvalues: &[f64], median: f64, pixels: usize) -> usize {
    let n = eigenvalues.len();
    // For white noise of variance σ², eigenvalues of SᴴS spread over P σ² (1 ± √(N/P))².
    let ratio = (n as f64 / pixels as f64).sqrt();
    let sigma2_p = median / (1.0 + ratio * ratio).max(1.0);
    let edge = sigma2_p * (1.0 + ratio).powi(2) * 1.05;
    let signal = eigenvalues.iter().take_while(|&&v| v > edge).count();
    signal.max(1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// Strong still tissue + weak moving blood: the filter removes the tissue and keeps the blood.
    #[test]
    fn removes_still_tissue_and_keeps_moving_blood() {
        let (nz, nx, nf) = (20, 20, 32);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let mut tissue = Array3::<Complex32>::zeros((nz, nx, nf));
        let mut blood = Array3::<Complex32>::zeros((nz, nx, nf));
        for z in 0..nz {
            for x in 0..nx {
                let t = Complex32::new(normal.sample(&mut rng), normal.sample(&mut rng)) * 100.0;
                let b = Complex32::new(normal.sample(&mut rng), normal.sample(&mut rng));
                for f in 0..nf {
                    tissue[[z, x, f]] = t;
                    if (8..12).contains(&x) {
                        // A whole number of cycles over the frames: orthogonal to the still tissue.
                        blood[[z, x, f]] = b * Complex32::from_polar(
                            1.0,
                            2.0 * std::f32::consts::PI * 4.0 * f as f32 / nf as f32,
                        );
                    }
                }
            }
        }
        let mut series = &tissue + &blood;
        let report = svd_filter(&mut series, &ClutterParams::default()).unwrap();
        assert_eq!(report.low, 1, "one still component");
        // Tissue suppressed by more than 60 dB; blood kept (normalised correlation > 0.999).
        let rejection = residue_over_tissue(&series, &blood, &tissue);
        assert!(rejection < 1e-6, "tissue rejection {rejection}");
        let dot: Complex32 = series
            .iter()
            .zip(blood.iter())
            .map(|(a, b)| a * b.conj())
            .sum();
        let blood_energy: f32 = blood.iter().map(|v| v.norm_sqr()).sum();
        let kept: f32 = series.iter().map(|v| v.norm_sqr()).sum();
        let correlation = dot.norm() / (blood_energy * kept).sqrt();
        assert!(correlation > 0.999, "blood correlation {correlation}");
    }

    /// Tissue whose components span 80 dB of energy (amplitudes 1, 10⁻², 10⁻⁴: a bright layer, its
    /// motion and the motion's next order, as a block of brain shows them) over blood 100 dB
    /// down: cutting the three tissue components leaves the blood. The Gram matrix squares the
    /// data's dynamic range, so single precision (about 10⁻⁷ of the strongest component's energy)
    /// would lose the third component and leave it, 20 dB over the blood.
    #[test]
    fn tissue_spanning_eighty_decibels_is_cut_to_the_blood() {
        let shape = (40, 40, 64);
        let tissue = toned(shape, 11, |_, _| vec![(1.0, 0.0), (1e-2, 1.0), (1e-4, 2.0)]);
        let blood = toned(shape, 12, |_, _| vec![(1e-5, 9.0)]);
        for blocks in [None, Some((20, 20))] {
            let mut series = &tissue + &blood;
            let params = ClutterParams {
                low: RankCut::Fixed(3),
                blocks,
                ..ClutterParams::default()
            };
            svd_filter(&mut series, &params).unwrap();
            let left: f64 = (&series - &blood).iter().map(|v| v.norm_sqr() as f64).sum();
            let kept: f64 = blood.iter().map(|v| v.norm_sqr() as f64).sum();
            assert!(
                left < 0.01 * kept,
                "{blocks:?}: left {:.1} dB re the blood",
                10.0 * (left / kept).log10()
            );
        }
    }

    #[test]
    fn no_tissue_means_no_cut() {
        let (nz, nx, nf) = (10, 10, 16);
        let mut series = Array3::from_shape_fn((nz, nx, nf), |(z, x, f)| {
            Complex32::from_polar(1.0, 0.9 * f as f32 + (z * 7 + x * 3) as f32)
        });
        let report = svd_filter(&mut series, &ClutterParams::default()).unwrap();
        assert_eq!(report.low, 0);
    }

    /// Both ways of applying the projection (through the kept or through the removed subspace)
    /// equal S·V_keep·V_keepᴴ computed in f64 from an independent thin SVD of S.
    #[test]
    fn filtered_series_equal_the_projection_of_an_independent_svd() {
        let (nz, nx, nf) = (7, 9, 12);
        let mut state = 12345u64;
        let mut next = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1);
            ((state >> 40) as f32 / (1u64 << 24) as f32) - 0.5
        };
        // Rank-2 tissue (strong, slow), rank-3 blood (weaker, faster, a random amplitude per
        // pixel) and weak noise: the subspaces are well separated at ranks 2 and 5, where the
        // cut-offs below fall (between near-equal noise components the split itself is
        // ill-conditioned, and no two computations agree there).
        let series = Array3::from_shape_fn((nz, nx, nf), |(z, x, f)| {
            let (t, p) = (f as f32, (z * nx + x) as f32);
            let tissue = Complex32::new(30.0 * (0.1 * t).cos(), 20.0 * (0.05 * t + 0.01 * p).sin());
            let blood: Complex32 = (1..=3)
                .map(|k| {
                    let phase = 0.7 * k as f32 * t + next() * 6.0;
                    Complex32::from_polar(3.0 * (next() + 0.6), phase)
                })
                .sum();
            tissue + blood + Complex32::new(0.05 * next(), 0.05 * next())
        });
        let s = Mat::<c64>::from_fn(nz * nx, nf, |p, f| {
            let v = series[[p / nx, p % nx, f]];
            c64::new(v.re as f64, v.im as f64)
        });
        let svd = s.thin_svd().unwrap();
        for (low, high) in [(2, 12), (0, 5), (2, 5)] {
            let mut filtered = series.clone();
            let params = ClutterParams {
                low: RankCut::Fixed(low),
                high: RankCut::Fixed(high),
                tissue_frequency: 0.0,
                blocks: None,
            };
            svd_filter(&mut filtered, &params).unwrap();
            let v = svd.V();
            let mut worst: f64 = 0.0;
            let mut scale: f64 = 0.0;
            for p in 0..nz * nx {
                for f in 0..nf {
                    let mut expected = c64::new(0.0, 0.0);
                    for g in 0..nf {
                        let mut weight = c64::new(0.0, 0.0);
                        for k in low..high {
                            weight += v[(g, k)] * v[(f, k)].conj();
                        }
                        expected += s[(p, g)] * weight;
                    }
                    let got = filtered[[p / nx, p % nx, f]];
                    let diff = c64::new(got.re as f64, got.im as f64) - expected;
                    worst = worst.max(diff.norm());
                    scale = scale.max(expected.norm());
                }
            }
            // −80 dB of the kept signal: the f32 series and the Gram matrix (which squares the
            // tissue-to-blood ratio) bound the agreement (measured 0.9–5.9·10⁻⁵ here, as with
            // the full frames × frames projection this replaced).
            assert!(
                worst < 1e-4 * scale,
                "cut-offs {low}..{high}: worst error {worst} of {scale}"
            );
        }
    }

    /// Still tissue (one component, 40 dB above the blood) over slow blood of six vessels of
    /// near-equal strength, each below the tissue frequency limit and far above the noise: the
    /// blood forms a plateau of components, not tissue's steep fall, and only the tissue is cut.
    #[test]
    fn auto_low_keeps_a_plateau_of_strong_slow_blood() {
        let (nz, nx, nf) = (24, 24, 512);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let echogenicity: Vec<f32> = (0..nz * nx).map(|_| normal.sample(&mut rng)).collect();
        let noise: Vec<Complex32> = (0..nz * nx * nf)
            .map(|_| Complex32::new(normal.sample(&mut rng), normal.sample(&mut rng)))
            .collect();
        let tau = 2.0 * std::f32::consts::PI;
        let mut series = Array3::from_shape_fn((nz, nx, nf), |(z, x, f)| {
            let tissue = 1000.0 * echogenicity[z * nx + x];
            // Vessel j: the column band x in [4j, 4j + 4), j + 1 cycles over the recording
            // (0.002–0.012 cycles per frame: whole cycles, so each its own component).
            let j = x / 4;
            let strength = 10.0 * 0.95f32.powi(j as i32);
            let cycles = (j + 1) as f32 / nf as f32;
            let blood = Complex32::from_polar(strength, tau * cycles * f as f32);
            tissue + blood + 0.1 * noise[(z * nx + x) * nf + f]
        });
        let report = svd_filter(&mut series, &ClutterParams::default()).unwrap();
        assert_eq!(report.low, 1, "{:?}", &report.singular_values[..8]);
        // Without the steepness test the slow blood passes for tissue: each of its six
        // components is slow and 10 dB above the median.
        let energies: Vec<f64> = report.singular_values.iter().map(|s| s * s).collect();
        let mut sorted = energies.clone();
        sorted.sort_by(f64::total_cmp);
        let median = sorted[nf / 2];
        assert!(energies[1..7].iter().all(|&e| e > 10.0 * median));
    }

    #[test]
    fn fixed_cut_offs_are_projections() {
        let (nz, nx, nf) = (6, 5, 8);
        let mut series = Array3::from_shape_fn((nz, nx, nf), |(z, x, f)| {
            Complex32::new(
                ((z * 31 + x * 17 + f * 13) % 11) as f32,
                ((z + 2 * x + 3 * f) % 5) as f32,
            )
        });
        let params = ClutterParams {
            low: RankCut::Fixed(2),
            high: RankCut::Fixed(6),
            tissue_frequency: 0.0,
            blocks: None,
        };
        let mut twice = series.clone();
        svd_filter(&mut series, &params).unwrap();
        svd_filter(&mut twice, &params).unwrap();
        let report = svd_filter(
            &mut twice,
            &ClutterParams {
                low: RankCut::Fixed(0),
                high: RankCut::Fixed(4),
                tissue_frequency: 0.0,
                blocks: None,
            },
        )
        .unwrap();
        // After keeping components 2..6, exactly 4 non-zero singular values remain.
        assert!(report.singular_values[3] > 1e-2 * report.singular_values[0]);
        assert!(report.singular_values[4] < 1e-3 * report.singular_values[0]);
        assert!(
            svd_filter(
                &mut series,
                &ClutterParams {
                    low: RankCut::Fixed(5),
                    high: RankCut::Fixed(5),
                    tissue_frequency: 0.0,
                    blocks: None,
                }
            )
            .is_err()
        );
    }

    /// The similarity cut-offs on a case built to hold three subspaces, as the method assumes:
    /// tissue of rank 3 whose components share one magnitude map (its echogenicity, varying
    /// across the image), white noise whose level grows with depth (as a beamformed noise floor
    /// does), and six vessels each lit by one Doppler tone of its own strength (equal ones would
    /// mix in the singular vectors), placed where both maps are at their means, so that no vessel
    /// map resembles the tissue's or the noise's (a weak vessel deep in the noise does, and the
    /// fit then counts it as noise, as it should: nothing tells them apart). The fit finds the tissue's rank and the tissue-plus-blood
    /// rank exactly; the energy-and-frequency rule sees only the still component.
    #[test]
    fn similarity_cut_offs_find_the_tissue_and_noise_subspaces() {
        let (nz, nx, nf) = (48, 32, 48);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let mut gaussian = || Complex32::new(normal.sample(&mut rng), normal.sample(&mut rng));
        let tau = 2.0 * std::f32::consts::PI;
        // Tissue: still, then one and two cycles of slow motion, weaker and weaker.
        let tissue_time = |k: usize, f: usize| -> Complex32 {
            let t = tau * f as f32 / nf as f32;
            match k {
                0 => Complex32::new(1.0, 0.0),
                1 => Complex32::from_polar(0.3, t),
                _ => Complex32::from_polar(0.1, 2.0 * t),
            }
        };
        let mut series = Array3::<Complex32>::zeros((nz, nx, nf));
        for z in 0..nz {
            for x in 0..nx {
                let echogenicity = 30.0 * (1.0 + 0.5 * (tau * x as f32 / nx as f32).cos());
                let phases: Vec<Complex32> = (0..3)
                    .map(|_| Complex32::from_polar(1.0, gaussian().arg()))
                    .collect();
                // Vessel j: 3 rows × 8 columns where both profiles are at their means, its tone
                // at 5 + j cycles.
                let vessel = (0..6).find(|j| {
                    let (top, left) = (16 + 6 * (j / 2), 4 + 16 * (j % 2));
                    (top..top + 3).contains(&z) && (left..left + 8).contains(&x)
                });
                let blood = vessel.map(|j| (j, Complex32::from_polar(1.0, gaussian().arg())));
                let noise_level = 0.05 + 0.15 * z as f32 / nz as f32;
                for f in 0..nf {
                    let mut v: Complex32 = (0..3)
                        .map(|k| echogenicity * phases[k] * tissue_time(k, f))
                        .sum();
                    if let Some((j, phase)) = blood {
                        let cycles = (5 + j) as f32;
                        // Distinct strengths, so that each component is one vessel.
                        let strength = 0.8f32.powi(j as i32);
                        v += phase
                            * Complex32::from_polar(strength, tau * cycles * f as f32 / nf as f32);
                    }
                    series[[z, x, f]] = v + noise_level * gaussian();
                }
            }
        }
        let similarity = ClutterParams {
            low: RankCut::Similarity,
            high: RankCut::Similarity,
            tissue_frequency: 0.02,
            blocks: None,
        };
        let report = svd_filter(&mut series.clone(), &similarity).unwrap();
        assert_eq!((report.low, report.high), (3, 9));
        let auto = svd_filter(&mut series, &ClutterParams::default()).unwrap();
        assert_eq!(
            auto.low, 1,
            "the moving tissue is faster than the auto rule's limit"
        );
    }

    /// The summed-area fit equals the least-squares fit computed directly, block by block, on a
    /// symmetric matrix with two noisy squares and anti-correlated corners.
    #[test]
    fn two_square_fit_equals_the_direct_least_squares_fit() {
        let n = 24;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(8);
        let normal = Normal::new(0.0, 0.2).unwrap();
        let mut m = Mat::<f64>::zeros(n, n);
        for i in 0..n {
            for j in 0..=i {
                let level = match (j < 5, i >= 17) {
                    (true, true) => -0.5,
                    (true, false) if i < 5 => 0.9,
                    (false, true) if j >= 17 => 0.5,
                    _ => 0.05,
                };
                let v = if i == j {
                    1.0
                } else {
                    level + normal.sample(&mut rng)
                };
                m[(i, j)] = v;
                m[(j, i)] = v;
            }
        }
        let direct_error = |low: usize, high: usize| {
            let part = |i: usize| (i >= low) as usize + (i >= high) as usize;
            let region = |i: usize, j: usize| 3 * part(i).min(part(j)) + part(i).max(part(j));
            let mut sums = [0.0; 9];
            let mut counts = [0.0f64; 9];
            for i in 0..n {
                for j in 0..n {
                    if i != j {
                        sums[region(i, j)] += m[(i, j)];
                        counts[region(i, j)] += 1.0;
                    }
                }
            }
            let mut error = 0.0;
            for i in 0..n {
                for j in 0..n {
                    if i != j {
                        let r = region(i, j);
                        error += (m[(i, j)] - sums[r] / counts[r].max(1.0)).powi(2);
                    }
                }
            }
            error
        };
        // Each tissue cut-off's best noise cut-off, and its error, by the direct fit.
        let best_by_low: Vec<(f64, usize)> = (0..=n / 2)
            .map(|low| {
                (low + 1..=n)
                    .map(|high| (direct_error(low, high), high))
                    .min_by(|a, b| a.0.total_cmp(&b.0))
                    .unwrap()
            })
            .collect();
        for (low, &(score, high)) in two_square_fits(&m).iter().enumerate() {
            assert!(
                direct_error(low, high) <= best_by_low[low].0 + 1e-9,
                "low {low}: high {high} (score {score}) fits worse than {:?}",
                best_by_low[low]
            );
        }
        let fitted = fit_two_squares(&m, None);
        let first_local_best = (0..n / 2)
            .find(|&low| best_by_low[low + 1].0 >= best_by_low[low].0 - 1e-9)
            .unwrap_or(n / 2);
        assert_eq!(fitted.0, first_local_best);
        assert_eq!(fitted, (5, 17));
    }

    /// A block's noisy fit: its steps wiggle (here component 1 resembles the blood's maps, not
    /// the tissue's), so the leading square stops at 2; with a cap (a block's: the whole image's
    /// cut-off) the best fit overall is taken, held to the cap.
    #[test]
    fn with_a_cap_the_best_fit_overall_is_held_to_it() {
        let n = 40;
        let mut m = Mat::<f64>::zeros(n, n);
        for i in 0..n {
            for j in 0..n {
                let (a, b) = (i.min(j), i.max(j));
                m[(i, j)] = match (a, b) {
                    _ if a == b => 1.0,
                    (1, 5..20) => 0.5,
                    (1, _) => 0.0,
                    (_, 0..5) => 0.8,
                    (5..20, 5..20) => 0.1,
                    (30.., _) => 0.4,
                    _ => 0.0,
                };
            }
        }
        assert_eq!(fit_two_squares(&m, None).0, 2, "the case wiggles");
        assert_eq!(fit_two_squares(&m, Some(7)), (5, 30));
        assert_eq!(fit_two_squares(&m, Some(4)).0, 4);
    }

    /// A tissue square followed by a blood square (a vascular tree whose blood components light
    /// the same vessels): the best fit overall takes tissue and blood together as tissue; the
    /// leading square is the tissue alone.
    #[test]
    fn similarity_cut_off_is_the_leading_square_not_tissue_and_blood_together() {
        let n = 60;
        let (tissue, blood, noise) = (0..4, 4..30, 40..60);
        let mut m = Mat::<f64>::zeros(n, n);
        for i in 0..n {
            for j in 0..n {
                let both = |r: &std::ops::Range<usize>| r.contains(&i) && r.contains(&j);
                let across = |a: &std::ops::Range<usize>, b: &std::ops::Range<usize>| {
                    (a.contains(&i) && b.contains(&j)) || (b.contains(&i) && a.contains(&j))
                };
                m[(i, j)] = if i == j {
                    1.0
                } else if both(&tissue) || both(&blood) {
                    0.7
                } else if both(&noise) {
                    0.4
                } else if across(&tissue, &blood) || across(&blood, &(30..40)) {
                    0.3
                } else {
                    0.0
                };
            }
        }
        let fits = two_square_fits(&m);
        let best_overall = (0..fits.len())
            .max_by(|&a, &b| fits[a].0.total_cmp(&fits[b].0))
            .unwrap();
        assert_eq!(best_overall, 30, "the case holds the two-squares trap");
        assert_eq!(fit_two_squares(&m, None), (4, 30));
        // With a cap, the best fit overall held to it.
        assert_eq!(fit_two_squares(&m, Some(31)).0, 30);
        assert_eq!(fit_two_squares(&m, Some(4)), (4, 30));
    }

    /// The similarity matrix equals the correlation of |U|'s columns from an independent thin SVD
    /// of S in f64.
    #[test]
    fn spatial_similarity_equals_the_correlation_of_an_independent_svd() {
        let (pixels, nf) = (300, 10);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let data: Vec<Complex32> = (0..pixels * nf)
            .map(|i| {
                let level = 1.0 + (i / nf) as f32 / 50.0 + 3.0 * ((i % nf) as f32 / nf as f32);
                level * Complex32::new(normal.sample(&mut rng), normal.sample(&mut rng))
            })
            .collect();
        let s = Mat::<c64>::from_fn(pixels, nf, |p, f| {
            let v = data[p * nf + f];
            c64::new(v.re as f64, v.im as f64)
        });
        let svd = s.thin_svd().unwrap();
        let v = Mat::<c32>::from_fn(nf, nf, |i, k| {
            let x = svd.V()[(i, k)];
            c32::new(x.re as f32, x.im as f32)
        });
        let got = spatial_similarity(&data, nf, v.as_ref());
        let magnitude =
            |k: usize| -> Vec<f64> { (0..pixels).map(|p| svd.U()[(p, k)].norm()).collect() };
        for a in 0..nf {
            for b in 0..nf {
                let (ua, ub) = (magnitude(a), magnitude(b));
                let mean = |u: &[f64]| u.iter().sum::<f64>() / pixels as f64;
                let (ma, mb) = (mean(&ua), mean(&ub));
                let cov: f64 = ua.iter().zip(&ub).map(|(x, y)| (x - ma) * (y - mb)).sum();
                let var = |u: &[f64], m: f64| u.iter().map(|x| (x - m).powi(2)).sum::<f64>();
                let expected = cov / (var(&ua, ma) * var(&ub, mb)).sqrt();
                assert!(
                    (got[(a, b)] - expected).abs() < 1e-4,
                    "C({a}, {b}) = {} vs {expected}",
                    got[(a, b)]
                );
            }
        }
    }

    /// The automatic high cut-off on an analytic case. S (P pixels × N frames) is complex white
    /// noise of variance σ² per sample plus rank-1 components u·vᴴ of energy ℓ·Pσ² (tissue: still;
    /// blood: a Doppler tone, orthogonal to it). Without them the eigenvalues of SᴴS fill the
    /// Marchenko–Pastur bulk, whose upper edge is Pσ²(1 + √y)², y = N/P. A component with ℓ > √y
    /// stands out of the bulk at about Pσ²(ℓ + 1)(1 + y/ℓ); one with ℓ < √y stays inside it
    /// (Baik–Ben Arous–Péché), where no filter can tell it from noise. So the cut-off must keep
    /// exactly the tissue and the strong blood, and cut the weak blood with the noise.
    #[test]
    fn auto_high_cut_is_at_the_marchenko_pastur_edge() {
        let (nz, nx, nf) = (48, 48, 32);
        let pixels = nz * nx;
        let y = nf as f64 / pixels as f64;
        let sigma2 = 1.0f64;
        // (ℓ, cycles over the recording): tissue, strong blood, weak blood (ℓ < √y ≈ 0.118).
        let components = [(1000.0, 0.0), (3.0, 4.0), (0.05, 9.0)];
        assert!(components[2].0 < y.sqrt());
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        // Complex Gaussian of variance v: real and imaginary parts of variance v/2 each.
        let mut gaussian = |variance: f64| {
            let normal = Normal::new(0.0, (variance / 2.0).sqrt()).unwrap();
            Complex32::new(
                normal.sample(&mut rng) as f32,
                normal.sample(&mut rng) as f32,
            )
        };
        let noise = Array3::from_shape_simple_fn((nz, nx, nf), || gaussian(sigma2));
        let mut signal = Array3::<Complex32>::zeros((nz, nx, nf));
        for &(ell, cycles) in &components {
            // Per-pixel amplitude of variance ℓσ²/N over N frames: energy ℓPσ² on average.
            for z in 0..nz {
                for x in 0..nx {
                    let a = gaussian(ell * sigma2 / nf as f64);
                    for f in 0..nf {
                        let phase = 2.0 * std::f32::consts::PI * cycles * f as f32 / nf as f32;
                        signal[[z, x, f]] += a * Complex32::from_polar(1.0, phase);
                    }
                }
            }
        }
        let params = ClutterParams {
            low: RankCut::Off,
            high: RankCut::Auto,
            tissue_frequency: 0.0,
            blocks: None,
        };
        let bulk_edge = pixels as f64 * sigma2 * (1.0 + y.sqrt()).powi(2);

        let report = svd_filter(&mut (&noise + &signal), &params).unwrap();
        assert_eq!(report.high, 2, "tissue and strong blood kept, the rest cut");
        let eigenvalues: Vec<f64> = report.singular_values.iter().map(|s| s * s).collect();
        let spike = |ell: f64| pixels as f64 * sigma2 * (ell + 1.0) * (1.0 + y / ell);
        for (k, &(ell, _)) in components[..2].iter().enumerate() {
            let ratio = eigenvalues[k] / spike(ell);
            // The amplitudes are drawn, so each energy is ℓPσ² within a few 1/√P (2 %).
            assert!((ratio - 1.0).abs() < 0.1, "component {k}: {ratio}");
        }
        // Everything cut lies within the noise bulk of the true σ² (to the definition's 5 %).
        assert!(
            eigenvalues[2] < 1.05 * bulk_edge,
            "{} vs edge {bulk_edge}",
            eigenvalues[2]
        );

        // Noise alone: nothing stands out; the cut-off keeps its floor of one component.
        let report = svd_filter(&mut noise.clone(), &params).unwrap();
        assert_eq!(report.high, 1);
        let largest = report.singular_values[0].powi(2);
        assert!(largest < 1.05 * bulk_edge, "{largest} vs edge {bulk_edge}");
    }

    /// The energy of what a filter left beside the blood, over the tissue's energy.
    fn residue_over_tissue(
        filtered: &Array3<Complex32>,
        blood: &Array3<Complex32>,
        tissue: &Array3<Complex32>,
    ) -> f32 {
        let residual: f32 = (filtered - blood).iter().map(|v| v.norm_sqr()).sum();
        residual / tissue.iter().map(|v| v.norm_sqr()).sum::<f32>()
    }

    /// A series of random speckle per pixel times a temporal tone per region: `tone(z, x)` gives
    /// each pixel's (amplitude, cycles over the frames) terms.
    fn toned(
        (nz, nx, nf): (usize, usize, usize),
        seed: u64,
        tones: impl Fn(usize, usize) -> Vec<(f32, f32)>,
    ) -> Array3<Complex32> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let mut series = Array3::<Complex32>::zeros((nz, nx, nf));
        for z in 0..nz {
            for x in 0..nx {
                for (amplitude, cycles) in tones(z, x) {
                    let speckle = Complex32::new(normal.sample(&mut rng), normal.sample(&mut rng));
                    for f in 0..nf {
                        let phase = 2.0 * std::f32::consts::PI * cycles * f as f32 / nf as f32;
                        series[[z, x, f]] +=
                            speckle * amplitude * Complex32::from_polar(1.0, phase);
                    }
                }
            }
        }
        series
    }

    /// Blocks that remove nothing give the series back: the tent weights blend to one over every
    /// pixel, the image's edges and an image that the half-block steps do not divide included.
    #[test]
    fn blocks_that_remove_nothing_blend_back_to_the_series() {
        let original = toned((23, 17, 8), 5, |_, _| vec![(1.0, 1.0), (0.5, 3.0)]);
        let mut series = original.clone();
        let params = ClutterParams {
            low: RankCut::Fixed(0),
            high: RankCut::Fixed(8),
            blocks: Some((6, 5)),
            ..ClutterParams::default()
        };
        let report = svd_filter(&mut series, &params).unwrap();
        // Rows start at 0, 3, …, 15, 17; columns (5 made 6) at 0, 3, 6, 9, 11.
        assert_eq!(report.block_cut_offs.len(), 7 * 5);
        for (a, b) in series.iter().zip(original.iter()) {
            assert!((a - b).norm() <= 1e-5 * b.norm().max(1.0), "{a} vs {b}");
        }
    }

    /// One block as large as the image is the whole-image filter.
    #[test]
    fn one_block_over_the_image_is_the_whole_filter() {
        let original = toned((12, 10, 16), 6, |_, x| {
            vec![(30.0, 0.0), (1.0, if x < 5 { 3.0 } else { -5.0 })]
        });
        let (mut whole, mut blocked) = (original.clone(), original.clone());
        let whole_report = svd_filter(&mut whole, &ClutterParams::default()).unwrap();
        let params = ClutterParams {
            blocks: Some((40, 40)),
            ..ClutterParams::default()
        };
        let report = svd_filter(&mut blocked, &params).unwrap();
        assert_eq!(
            report.block_cut_offs,
            vec![(whole_report.low, whole_report.high)]
        );
        assert_eq!((report.low, report.high), (1, 16));
        for (a, b) in blocked.iter().zip(whole.iter()) {
            assert!((a - b).norm() <= 1e-6 * original[[0, 0, 0]].norm().max(1.0));
        }
    }

    /// Tissue that moves differently in two halves of the image (still on the left, a slow tone
    /// on the right) spans two components of the whole image but one of each half's blocks: the
    /// block-wise filter cuts one where its blocks see one tissue and two where they straddle
    /// both, and keeps the blood everywhere.
    #[test]
    fn blended_block_values_are_the_tent_weighted_means_by_hand() {
        // Rows: blocks of 4 at 0 and 2 (tents 1, 2, 2, 1); one column of blocks of 3.
        let layout = BlockLayout::new((6, 3), (4, 3));
        assert_eq!(layout.shape(), (6, 3));
        assert_eq!(layout.origins().collect::<Vec<_>>(), vec![(0, 0), (2, 0)]);
        let blended = layout.blend(&[1.0, 4.0]).unwrap();
        // Row 2: tent 2 in the first block, 1 in the second; row 3 the other way round.
        let by_row = [1.0, 1.0, (2.0 + 4.0) / 3.0, (1.0 + 8.0) / 3.0, 4.0, 4.0];
        for (z, expected) in by_row.into_iter().enumerate() {
            for x in 0..3 {
                assert!((blended[[z, x]] - expected).abs() < 1e-12, "({z}, {x})");
            }
        }
        assert!(layout.blend(&[1.0]).is_err());
        // Blocks larger than the image are clamped to it, as the filter clamps them.
        let one = BlockLayout::new((5, 7), (50, 50));
        assert_eq!((one.size, one.shape()), ((5, 7), (5, 7)));
    }

    #[test]
    fn blocks_cut_the_tissue_each_block_holds() {
        let (nz, nx, nf) = (24, 48, 64);
        // Still and brighter on the left, so that the whole image's tissue components fall off
        // steeply, as `Auto` asks.
        let tissue = toned((nz, nx, nf), 7, |_, x| {
            vec![if x < nx / 2 {
                (100.0, 0.0)
            } else {
                (30.0, 1.0)
            }]
        });
        // Blood: a fast tone (8 cycles, orthogonal to both tissue tones) in every pixel.
        let blood = toned((nz, nx, nf), 8, |_, _| vec![(1.0, 8.0)]);
        let mut whole = &tissue + &blood;
        let mut blocked = whole.clone();
        let whole_report = svd_filter(&mut whole, &ClutterParams::default()).unwrap();
        assert_eq!(whole_report.low, 2);
        let params = ClutterParams {
            blocks: Some((24, 16)),
            ..ClutterParams::default()
        };
        let report = svd_filter(&mut blocked, &params).unwrap();
        // Columns start at 0, 8, 16, 24, 32: the block at 16 straddles the two halves.
        let lows: Vec<usize> = report.block_cut_offs.iter().map(|c| c.0).collect();
        assert_eq!(lows, vec![1, 1, 2, 1, 1]);
        // In brief: the blocks' medians, with the least and the most they chose.
        assert_eq!(
            report.cut_offs(),
            CutOffs {
                low: 1,
                high: nf,
                block_low_range: Some([1, 2]),
                block_high_range: Some([nf, nf]),
            }
        );
        assert_eq!(whole_report.cut_offs().block_low_range, None);
        // Where the blocks lie, one per cut-off; blended, the cuts are 1 where one tissue fills
        // the blocks and up to 2 where they straddle both.
        assert_eq!(whole_report.block_layout, None);
        let layout = report.block_layout.as_ref().unwrap();
        assert_eq!(layout.x_starts, vec![0, 8, 16, 24, 32]);
        let lows: Vec<f64> = lows.iter().map(|&l| l as f64).collect();
        let blended = layout.blend(&lows).unwrap();
        assert_eq!((blended[[0, 0]], blended[[0, nx - 1]]), (1.0, 1.0));
        let peak = blended.iter().copied().fold(0.0, f64::max);
        assert!(peak > 1.0 && peak < 2.0, "{peak}");
        // What is left beside the blood is the tissue's residue at single precision (as the
        // whole-image filter's: 60 dB down).
        let rejection = residue_over_tissue(&blocked, &blood, &tissue);
        assert!(rejection < 1e-6, "tissue rejection {rejection}");
    }

    /// A strong, slow vessel on a few pixels: within a block it stands above the block's noise as
    /// tissue does (strong, slow and steep), over the whole image it does not. The blocks cut at
    /// most what the whole image's rule cuts, so its blood is kept.
    #[test]
    fn blocks_cut_no_more_than_the_whole_image() {
        let (nz, nx, nf) = (40, 40, 64);
        let vessel = |z: usize, x: usize| (14..18).contains(&z) && (14..18).contains(&x);
        let tissue = toned((nz, nx, nf), 9, |_, _| vec![(100.0, 0.0)]);
        let blood = toned((nz, nx, nf), 10, |z, x| match vessel(z, x) {
            true => vec![(3.0, 1.0)],
            false => vec![],
        });
        let noise = toned((nz, nx, nf), 11, |_, _| {
            (0..nf)
                .map(|k| (1.0 / (nf as f32).sqrt(), k as f32))
                .collect()
        });
        let series = &(&tissue + &blood) + &noise;
        // The premise: alone, the block around the vessel cuts it with the tissue.
        let mut alone = series.slice(ndarray::s![10..30, 10..30, ..]).to_owned();
        assert_eq!(
            svd_filter(&mut alone, &ClutterParams::default())
                .unwrap()
                .low,
            2
        );
        let whole = svd_filter(&mut series.clone(), &ClutterParams::default()).unwrap();
        assert_eq!(whole.low, 1);
        let mut blocked = series.clone();
        let params = ClutterParams {
            blocks: Some((20, 20)),
            ..ClutterParams::default()
        };
        let report = svd_filter(&mut blocked, &params).unwrap();
        assert!(
            report.block_cut_offs.iter().all(|c| c.0 == 1),
            "{:?}",
            report.block_cut_offs
        );
        // The vessel's blood is kept: its pixels still correlate with it.
        let (mut dot, mut kept, mut energy) = (Complex32::new(0.0, 0.0), 0.0f32, 0.0f32);
        for ((z, x, f), b) in blood.indexed_iter() {
            if vessel(z, x) {
                dot += blocked[[z, x, f]] * b.conj();
                kept += blocked[[z, x, f]].norm_sqr();
                energy += b.norm_sqr();
            }
        }
        let correlation = dot.norm() / (kept * energy).sqrt();
        assert!(correlation > 0.9, "{correlation}");
    }

    #[test]
    fn blocks_of_an_empty_image_are_refused_as_the_whole_filter_refuses_it() {
        let params = ClutterParams {
            blocks: Some((4, 4)),
            ..ClutterParams::default()
        };
        for shape in [(0, 5, 8), (5, 0, 8), (5, 5, 1)] {
            let mut series = Array3::<Complex32>::zeros(shape);
            let error = svd_filter(&mut series, &params).unwrap_err().to_string();
            assert!(
                error.contains("needs ≥ 2 frames and pixels"),
                "{shape:?}: {error}"
            );
        }
    }

    /// Blocks smaller than the frames grow, the shorter side first, until they hold as many
    /// pixels as frames; on an image smaller than that, the one block is the image.
    #[test]
    fn blocks_smaller_than_the_frames_grow_to_hold_them() {
        let series = toned((10, 12, 32), 3, |_, _| vec![(10.0, 0.0), (1.0, 5.0)]);
        let params = ClutterParams {
            blocks: Some((4, 3)),
            ..ClutterParams::default()
        };
        let report = svd_filter(&mut series.clone(), &params).unwrap();
        assert_eq!(report.block_layout.unwrap().size, (6, 6));
        assert_eq!(holding_frames((10, 12), (8, 2), 32), (8, 4));
        // Grown to (3, 11), then the side shorter than the image made even.
        assert_eq!(holding_frames((3, 40), (2, 2), 32), (3, 12));
        // Even sides, so that half-block steps tile the image; the image's own side stays.
        assert_eq!(holding_frames((401, 236), (37, 37), 180), (38, 38));
        assert_eq!(holding_frames((401, 37), (37, 37), 180), (38, 37));

        let small = series.slice(ndarray::s![..5, ..5, ..]).to_owned();
        let mut blocked = small.clone();
        let report = svd_filter(&mut blocked, &params).unwrap();
        assert_eq!(report.block_layout.unwrap().size, (5, 5));
        let mut whole = small;
        svd_filter(&mut whole, &ClutterParams::default()).unwrap();
        for (a, b) in blocked.iter().zip(whole.iter()) {
            assert!((a - b).norm() <= 1e-5 * b.norm().max(1.0), "{a} vs {b}");
        }
    }

    /// The block-wise filter equals each block filtered on its own (its own Gram matrix, summed
    /// over its own pixels) and tent-blended by hand: the cells' shared Gram matrices add up to
    /// each block's, the last blocks (flush with the edges, off the half-block steps) included.
    #[test]
    fn block_filter_is_each_blocks_own_filter_blended() {
        let (nz, nx, nf) = (23, 19, 24);
        let series = toned((nz, nx, nf), 12, |z, x| {
            vec![
                (40.0, 0.0),
                (4.0 + z as f32 / 4.0, 0.5),
                (1.0, 3.0 + (x % 5) as f32),
            ]
        });
        let params = ClutterParams {
            low: RankCut::Fixed(2),
            blocks: Some((7, 6)),
            ..ClutterParams::default()
        };
        let mut blocked = series.clone();
        let report = svd_filter(&mut blocked, &params).unwrap();
        let layout = report.block_layout.unwrap();
        // Seven rows made eight, so that the half-block steps tile the rows.
        assert_eq!(layout.size, (8, 6));
        assert_eq!(layout.z_starts, vec![0, 4, 8, 12, 15]);
        assert_eq!(layout.x_starts, vec![0, 3, 6, 9, 12, 13]);
        let own = ClutterParams {
            blocks: None,
            ..params
        };
        let mut sums = Array3::<Complex32>::zeros((nz, nx, nf));
        let mut weights = Array2::<f32>::zeros((nz, nx));
        for (z0, x0) in layout.origins() {
            let mut block = series
                .slice(ndarray::s![z0..z0 + 8, x0..x0 + 6, ..])
                .to_owned();
            svd_filter(&mut block, &own).unwrap();
            for ((i, j, f), v) in block.indexed_iter() {
                let w = tent(i, 8) * tent(j, 6);
                sums[[z0 + i, x0 + j, f]] += v * w;
                if f == 0 {
                    weights[[z0 + i, x0 + j]] += w;
                }
            }
        }
        let largest = series.iter().map(|v| v.norm()).fold(0.0, f32::max);
        for ((z, x, f), v) in blocked.indexed_iter() {
            let expected = sums[[z, x, f]] / weights[[z, x]];
            assert!(
                (v - expected).norm() <= 1e-5 * largest,
                "({z}, {x}, {f}): {v} vs {expected}"
            );
        }
    }

    /// Blocks over a series with no tissue (the whole image's rule cuts nothing) leave it bit for
    /// bit, each block reported as keeping every component.
    #[test]
    fn blocks_over_blood_alone_leave_the_series_bit_for_bit() {
        let series = toned((16, 14, 20), 4, |z, _| vec![(1.0, 3.0 + (z % 3) as f32)]);
        let mut blocked = series.clone();
        let params = ClutterParams {
            blocks: Some((6, 6)),
            ..ClutterParams::default()
        };
        let report = svd_filter(&mut blocked, &params).unwrap();
        assert_eq!(blocked, series);
        let layout = report.block_layout.unwrap();
        assert_eq!(
            report.block_cut_offs,
            vec![(0, 20); layout.z_starts.len() * layout.x_starts.len()]
        );
    }
}
