//! The block-wise filter: overlapping blocks of the image, each with its own Casorati matrix and
//! cut-offs, their Gram matrices summed from the cells the blocks' edges cut the image into, and
//! blended back with tent weights.

use super::*;

/// Starts of the blocks of `size` that cover `n` pixels at half-block steps, the last one flush
/// with the end.
pub(super) fn block_starts(n: usize, size: usize) -> Vec<usize> {
    let step = (size / 2).max(1);
    let mut starts: Vec<usize> = (0..n.saturating_sub(size)).step_by(step).collect();
    starts.push(n.saturating_sub(size));
    starts.dedup();
    starts
}

/// Tent weight of a block's pixel `i` of `size`: highest in the middle, never zero, so that the
/// image's edges (covered by one block) keep their own filtered values.
pub(super) fn tent(i: usize, size: usize) -> f32 {
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

pub(super) fn filter_blocks(
    series: &mut Array3<Complex32>,
    params: &ClutterParams,
    size: (usize, usize),
    scratch: &mut ClutterScratch,
) -> Result<ClutterReport> {
    // The room the memory estimate keeps for the series' compound, which is formed only after
    // the filter: one angle's series.
    let room = series.len() * std::mem::size_of::<Complex32>();
    filter_blocks_keeping(series, params, size, room, scratch)
}

/// [`filter_blocks`], keeping at most `kept_bytes` of the cells' Gram matrices from the whole
/// image's cut-off (summed from them) to the blocks' filters; the cells not kept are summed
/// again when a row of blocks needs them. The cells' buffers come from `scratch` and go back to
/// it.
pub(super) fn filter_blocks_keeping(
    series: &mut Array3<Complex32>,
    params: &ClutterParams,
    size: (usize, usize),
    kept_bytes: usize,
    scratch: &mut ClutterScratch,
) -> Result<ClutterReport> {
    let (nz, nx, frames) = series.dim();
    let removes_nothing = params.low == RankCut::Off && params.high == RankCut::Off;
    if nz == 0 || nx == 0 || frames < 2 || removes_nothing {
        // The whole image's filter refuses what it cannot filter, and returns what needs none.
        return filter_whole(series, params);
    }
    let layout = BlockLayout::new((nz, nx), holding_frames((nz, nx), size, frames));
    let (rows, cols) = layout.size;
    let whole = ClutterParams {
        blocks: None,
        ..*params
    };
    // Blocks overlap by half: a block's Gram matrix is the sum of those of the cells the blocks'
    // edges cut the image into, each cell's summed once and shared by the (up to four) blocks
    // that hold it, rather than every pixel's four times.
    let z_cuts = cell_edges(&layout.z_starts, rows);
    let x_cuts = cell_edges(&layout.x_starts, cols);
    // Cell rows' Gram matrices, kept while a row of blocks still needs them.
    let mut cell_rows: std::collections::BTreeMap<usize, Vec<LowerHalf>> = Default::default();
    // A block's tissue is the whole image's seen on some of its pixels: its rank is at most the
    // whole's, so a block cuts at most the components the whole image's rule cuts. Without that
    // cap a block holding a wide, slow vessel cuts its blood as tissue (strong, slow and steep
    // within the block). The cells tile the image, so the whole image's Gram matrix is their
    // sum: summed from them, it costs no second pass over the pixels, and the cells that fit in
    // `kept_bytes` wait for the blocks.
    let low_cap = match params.low {
        RankCut::Auto | RankCut::Similarity => {
            let (gram, kept) = whole_gram_of_cells(series, &z_cuts, &x_cuts, kept_bytes, scratch);
            cell_rows = kept;
            Some(cut_offs_with_gram(series, &whole, gram)?.low)
        }
        RankCut::Off => Some(0),
        RankCut::Fixed(_) => None,
    };
    let blocks = layout.z_starts.len() * layout.x_starts.len();
    if low_cap == Some(0) && params.high == RankCut::Off {
        // Every block would keep all its components: the series stays as it is (bit for bit;
        // blending unchanged blocks would round it).
        cell_rows.into_values().for_each(|row| scratch.recycle(row));
        return Ok(ClutterReport {
            low: 0,
            high: frames,
            singular_values: Vec::new(),
            block_cut_offs: vec![(0, frames); blocks],
            block_layout: Some(layout),
        });
    }
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
        let passed: Vec<usize> = (cell_rows.keys().copied())
            .filter(|&za| z_cuts[za] < z0)
            .collect();
        for za in passed {
            scratch.recycle(cell_rows.remove(&za).unwrap_or_default());
        }
        let missing: Vec<(usize, usize)> = cells_within(&z_cuts, z0, rows)
            .filter(|za| !cell_rows.contains_key(za))
            .flat_map(|za| (0..x_cuts.len() - 1).map(move |xa| (za, xa)))
            .collect();
        let grams = cell_grams(series, &z_cuts, &x_cuts, &missing, scratch);
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
                            cell_rows[&za][xa].add_to(&mut gram);
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
        let mut row_of_blocks = Vec::with_capacity(filtered.len());
        for (x0, block, report) in filtered {
            block_cut_offs.push((report.low, report.high));
            row_of_blocks.push((x0, block));
        }
        blended.add_row(&row_of_blocks, z0, (rows, cols), frames);
    }
    blended.settle(series, nz)?;
    cell_rows.into_values().for_each(|row| scratch.recycle(row));
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
pub(super) struct Blended {
    /// The sums over rows `start..start + rows` (row-major: rows × nx × frames).
    sums: Vec<Complex32>,
    /// Each pixel's sum of the weights of the blocks added over it.
    weights: Array2<f32>,
    /// The image row the band starts at.
    start: usize,
}

impl Blended {
    /// Adds a row of filtered blocks, each (x0, its rows × cols × frames, row-major) with its
    /// first pixel at (z0, x0), z0 a row within the band, each pixel weighted by its tents. The
    /// image's rows are summed in parallel, each pixel's blocks in their order in the row: the
    /// same sums as adding the blocks one after another.
    fn add_row(
        &mut self,
        blocks: &[(usize, Vec<Complex32>)],
        z0: usize,
        (rows, cols): (usize, usize),
        frames: usize,
    ) {
        let nx = self.weights.ncols();
        let row_len = nx * frames;
        let first = (z0 - self.start) * row_len;
        let sums = &mut self.sums[first..first + rows * row_len];
        let weights = self
            .weights
            .as_slice_mut()
            .expect("an owned array is contiguous");
        let weights = &mut weights[z0 * nx..(z0 + rows) * nx];
        (sums.par_chunks_mut(row_len))
            .zip(weights.par_chunks_mut(nx))
            .enumerate()
            .for_each(|(i, (sums, weights))| {
                for (x0, block) in blocks {
                    for j in 0..cols {
                        let w = tent(i, rows) * tent(j, cols);
                        weights[x0 + j] += w;
                        let at = (x0 + j) * frames;
                        let from = (i * cols + j) * frames;
                        for (sum, &v) in sums[at..at + frames]
                            .iter_mut()
                            .zip(&block[from..from + frames])
                        {
                            *sum += v * w;
                        }
                    }
                }
            });
    }

    /// Writes the band's rows above `until` into `series` (each pixel its sum over its weight:
    /// the blend) and moves the band down to start there.
    fn settle(&mut self, series: &mut Array3<Complex32>, until: usize) -> Result<()> {
        let (_, nx, frames) = series.dim();
        let row_len = nx * frames;
        let done = until - self.start;
        let mut rows = series.slice_mut(ndarray::s![self.start..until, .., ..]);
        let out = rows
            .as_slice_mut()
            .ok_or_else(|| Error::Shape("image series must be contiguous".into()))?;
        let weights = self
            .weights
            .as_slice()
            .expect("an owned array is contiguous");
        (out.par_chunks_mut(row_len))
            .zip(self.sums[..done * row_len].par_chunks(row_len))
            .zip(weights[self.start * nx..until * nx].par_chunks(nx))
            .for_each(|((out, sums), weights)| {
                for ((out, sums), &w) in
                    out.chunks_mut(frames).zip(sums.chunks(frames)).zip(weights)
                {
                    for (o, &s) in out.iter_mut().zip(sums) {
                        *o = s / w;
                    }
                }
            });
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
pub(super) fn holding_frames(
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

/// The lower half (the diagonal included) of a square matrix, column by column: all that the
/// eigensolver reads of a Hermitian one, in half the memory of the square.
pub(super) struct LowerHalf {
    order: usize,
    entries: Vec<c64>,
}

impl LowerHalf {
    /// Entries in the lower half of a square matrix of `order`.
    fn entries(order: usize) -> usize {
        order * (order + 1) / 2
    }

    /// Bytes the lower half of a square matrix of `order` takes.
    pub(super) fn bytes(order: usize) -> usize {
        Self::entries(order) * std::mem::size_of::<c64>()
    }

    /// The lower half of the square `matrix`, in `buffer`'s memory.
    pub(super) fn of(matrix: &Mat<c64>, buffer: Vec<c64>) -> LowerHalf {
        let order = matrix.nrows();
        let mut entries = buffer;
        entries.clear();
        entries.reserve(Self::entries(order));
        for j in 0..order {
            entries.extend((j..order).map(|i| matrix[(i, j)]));
        }
        LowerHalf { order, entries }
    }

    /// Its memory, for another matrix.
    pub(super) fn into_buffer(self) -> Vec<c64> {
        self.entries
    }

    /// Adds this lower half to `sum`'s, entry by entry (the upper half left as it is).
    pub(super) fn add_to(&self, sum: &mut Mat<c64>) {
        let n = self.order;
        assert!(sum.nrows() == n && sum.ncols() == n);
        let mut from = self.entries.as_slice();
        for j in 0..n {
            let (column, rest) = from.split_at(n - j);
            from = rest;
            let to = sum.col_mut(j).subrows_mut(j, n - j);
            let to = to
                .try_as_col_major_mut()
                .expect("an owned matrix's columns are contiguous");
            // SAFETY: c64 is two f64 (re, im), laid out as such; both slices cover n − j entries.
            let (to, column) = unsafe {
                (
                    std::slice::from_raw_parts_mut(to.as_ptr_mut() as *mut f64, 2 * (n - j)),
                    std::slice::from_raw_parts(column.as_ptr() as *const f64, 2 * (n - j)),
                )
            };
            for (t, f) in to.iter_mut().zip(column) {
                *t += f;
            }
        }
    }
}

/// The Gram matrix (lower half) of the cell (`za`, `xa`) that the edges `z_cuts` and `x_cuts`
/// cut `series` into, in `buffer`'s memory, computed in `work`'s.
fn cell_gram(
    series: &Array3<Complex32>,
    z_cuts: &[usize],
    x_cuts: &[usize],
    (za, xa): (usize, usize),
    buffer: Vec<c64>,
    work: &mut CellWork,
) -> LowerHalf {
    let frames = series.dim().2;
    let (z0, z1, x0, x1) = (z_cuts[za], z_cuts[za + 1], x_cuts[xa], x_cuts[xa + 1]);
    // Each pixel's series one column, each value written once: a matrix zeroed first and then
    // filled entry by entry, in fresh memory per cell, took a few percent of a run's CPU.
    let pixels = (z1 - z0) * (x1 - x0);
    let columns = &mut work.columns;
    columns.clear();
    columns.reserve(frames * pixels);
    let cell = series.slice(ndarray::s![z0..z1, x0..x1, ..]);
    for pixel in cell.lanes(ndarray::Axis(2)) {
        let pixel = crate::core::buffers::contiguous(pixel);
        columns.extend(pixel.iter().map(|v| c64::new(v.re as f64, v.im as f64)));
    }
    let columns = MatRef::from_column_major_slice(columns, frames, pixels);
    if work.gram.nrows() != frames {
        work.gram = Mat::zeros(frames, frames);
    }
    lower_gram_of_columns_into(work.gram.as_mut(), columns);
    LowerHalf::of(&work.gram, buffer)
}

/// A thread's memory for [`cell_gram`], kept from one cell to the next: a megabyte or so, which
/// asked for anew per cell came as fresh pages the system clears.
struct CellWork {
    /// The cell's pixels' series, one column each.
    columns: Vec<c64>,
    /// The cell's Gram matrix (its lower half written).
    gram: Mat<c64>,
}

impl Default for CellWork {
    fn default() -> CellWork {
        CellWork {
            columns: Vec::new(),
            gram: Mat::zeros(0, 0),
        }
    }
}

/// The Gram matrices of `cells`, in parallel, in buffers from `scratch`.
fn cell_grams(
    series: &Array3<Complex32>,
    z_cuts: &[usize],
    x_cuts: &[usize],
    cells: &[(usize, usize)],
    scratch: &mut ClutterScratch,
) -> Vec<LowerHalf> {
    (cells.par_iter())
        .zip(scratch.buffers(cells.len(), series.dim().2))
        .map_init(CellWork::default, |work, (&cell, buffer)| {
            cell_gram(series, z_cuts, x_cuts, cell, buffer, work)
        })
        .collect()
}

/// The whole image's Gram matrix (lower half), summed from the Gram matrices of the cells that
/// `z_cuts` and `x_cuts` tile it with (rows of cells in order), and the first rows of cells'
/// matrices, as many as fit in `kept_bytes`; the others' buffers go back to `scratch`.
pub(super) fn whole_gram_of_cells(
    series: &Array3<Complex32>,
    z_cuts: &[usize],
    x_cuts: &[usize],
    kept_bytes: usize,
    scratch: &mut ClutterScratch,
) -> (Mat<c64>, std::collections::BTreeMap<usize, Vec<LowerHalf>>) {
    let frames = series.dim().2;
    let per_row = x_cuts.len() - 1;
    let mut whole = Mat::<c64>::zeros(frames, frames);
    let mut kept = std::collections::BTreeMap::new();
    let mut room = Some(kept_bytes);
    // Rows of cells in groups of at least GROUP_CELLS cells, computed in parallel: a row alone
    // may hold fewer cells than twice the cores.
    let rows: Vec<usize> = (0..z_cuts.len() - 1).collect();
    for group in rows.chunks(GROUP_CELLS.div_ceil(per_row)) {
        let cells: Vec<(usize, usize)> = (group.iter())
            .flat_map(|&za| (0..per_row).map(move |xa| (za, xa)))
            .collect();
        let mut grams = cell_grams(series, z_cuts, x_cuts, &cells, scratch);
        for gram in &grams {
            gram.add_to(&mut whole);
        }
        for &za in group {
            let row: Vec<LowerHalf> = grams.drain(..per_row).collect();
            // Rows from the top only: the blocks take them first and drop them as they pass.
            room = room.and_then(|room| room.checked_sub(per_row * LowerHalf::bytes(frames)));
            if room.is_some() {
                kept.insert(za, row);
            } else {
                scratch.recycle(row);
            }
        }
    }
    (whole, kept)
}

/// The least number of cells whose Gram matrices [`whole_gram_of_cells`] computes at once.
const GROUP_CELLS: usize = 64;

/// The cells along one axis (indices into `edges`) that lie within `len` pixels from `start`.
pub(super) fn cells_within(
    edges: &[usize],
    start: usize,
    len: usize,
) -> impl Iterator<Item = usize> + '_ {
    (0..edges.len() - 1).filter(move |&c| edges[c] >= start && edges[c + 1] <= start + len)
}

/// The edges along one axis of the cells that blocks of `size` starting at `starts` cut it into:
/// every block's first and one-past-last pixel, in order.
pub(super) fn cell_edges(starts: &[usize], size: usize) -> Vec<usize> {
    let mut edges: Vec<usize> = starts.iter().flat_map(|&s| [s, s + size]).collect();
    edges.sort_unstable();
    edges.dedup();
    edges
}

/// Memory the block-wise filter reuses from one series to the next (the cells' Gram matrices'
/// buffers), so that filtering a recording's angles one after another asks the system for it
/// once: on a virtual machine, memory freed and asked for again can cost as much as summing
/// the matrices.
#[derive(Debug, Default)]
pub(super) struct ClutterScratch {
    /// Buffers no cell holds now.
    spare: Vec<Vec<c64>>,
}

impl ClutterScratch {
    /// `count` buffers for the lower halves of matrices of `order`, spare ones first. New ones
    /// are allocated here, on the calling thread, rather than by the pool's threads that fill
    /// them: memory a pool thread allocates stays in its own arena once freed, and the process
    /// would hold it through the stages after the filter.
    fn buffers(&mut self, count: usize, order: usize) -> Vec<Vec<c64>> {
        let entries = LowerHalf::entries(order);
        (0..count)
            .map(|_| (self.spare.pop()).unwrap_or_else(|| Vec::with_capacity(entries)))
            .collect()
    }

    /// Takes back the buffers of `cells`.
    fn recycle(&mut self, cells: Vec<LowerHalf>) {
        self.spare
            .extend(cells.into_iter().map(LowerHalf::into_buffer));
    }

    /// Buffers held for the next series.
    #[cfg(test)]
    pub(super) fn spare_buffers(&self) -> usize {
        self.spare.len()
    }
}
