//! Which vessel holds a point, without testing every segment: a uniform grid of cells, each
//! listing the segments whose bounding boxes reach into it. Drawing millions of tissue
//! scatterers around a tree of thousands of segments tests each against the few near it.

use super::SegmentFlow;

/// The segments of a tree listed by the grid cells their bounding boxes overlap.
pub struct LumenLookup<'a> {
    segments: &'a [SegmentFlow],
    boxes: Vec<([f64; 3], [f64; 3])>,
    /// The lowest corner of every box (m).
    origin: [f64; 3],
    /// A cell's side (m).
    cell: f64,
    dims: [usize; 3],
    /// Per cell (x fastest, then y, then z), the segments whose boxes reach into it.
    cells: Vec<Vec<u32>>,
}

impl<'a> LumenLookup<'a> {
    /// About eight cells per segment over the boxes' extent.
    const CELLS_PER_SEGMENT: f64 = 8.0;
    /// The most cells per segment, whatever the boxes' shape.
    const MAX_CELLS_PER_SEGMENT: f64 = 64.0;

    /// The lookup of `segments`.
    pub fn new(segments: &'a [SegmentFlow]) -> Self {
        let boxes: Vec<([f64; 3], [f64; 3])> = segments.iter().map(|s| s.bounds()).collect();
        let (origin, end) = boxes.iter().fold(
            ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
            |(lo, hi), (a, b)| {
                (
                    std::array::from_fn(|k| lo[k].min(a[k])),
                    std::array::from_fn(|k| hi[k].max(b[k])),
                )
            },
        );
        let extent: [f64; 3] = std::array::from_fn(|k| (end[k] - origin[k]).max(0.0));
        let volume: f64 = extent.iter().map(|e| e.max(1e-6)).product();
        let cell = (volume / (Self::CELLS_PER_SEGMENT * segments.len().max(1) as f64))
            .cbrt()
            .max(1e-6);
        // (Boxes of finite corners may still span more than f64 holds.)
        let finite = boxes
            .iter()
            .all(|(a, b)| a.iter().chain(b).all(|v| v.is_finite()))
            && extent.iter().all(|e| e.is_finite());
        // Counted in f64, which no extent overflows.
        let cells_along =
            |cell: f64| -> [f64; 3] { std::array::from_fn(|k| (extent[k] / cell).floor() + 1.0) };
        let (cell, dims) = if segments.is_empty() || !finite {
            (cell, [0; 3])
        } else {
            // An axis shorter than a cell still takes one: a tree far longer along one axis than
            // across (a vessel placed metres or kilometres away) would get cells by the billion
            // along it. The cell grows until their count is within a few times the plan (at
            // worst to infinity, where every extent takes one cell).
            let budget = Self::MAX_CELLS_PER_SEGMENT * segments.len() as f64 + 64.0;
            let mut cell = cell;
            while cells_along(cell).iter().product::<f64>() > budget {
                cell *= 2.0;
            }
            (cell, cells_along(cell).map(|n| n as usize))
        };
        let mut lookup = LumenLookup {
            segments,
            boxes,
            origin,
            cell,
            dims,
            cells: vec![Vec::new(); dims.iter().product()],
        };
        if dims[0] == 0 {
            // Nothing to index: every lookup tests every segment.
            return lookup;
        }
        for (index, (lo, hi)) in lookup.boxes.iter().enumerate() {
            let first: [usize; 3] = std::array::from_fn(|k| lookup.axis_cell(k, lo[k]));
            let last: [usize; 3] = std::array::from_fn(|k| lookup.axis_cell(k, hi[k]));
            for z in first[2]..=last[2] {
                for y in first[1]..=last[1] {
                    for x in first[0]..=last[0] {
                        let at = (z * dims[1] + y) * dims[0] + x;
                        lookup.cells[at].push(index as u32);
                    }
                }
            }
        }
        lookup
    }

    /// Cells of the grid.
    #[cfg(test)]
    pub(super) fn cell_count(&self) -> usize {
        self.cells.len()
    }

    /// The cell along axis `k` of a coordinate `v` (m) within the boxes' extent. Rounding is
    /// monotonic, so a point inside a box falls in one of the cells its corners fall in.
    fn axis_cell(&self, k: usize, v: f64) -> usize {
        (((v - self.origin[k]) / self.cell).floor().max(0.0) as usize).min(self.dims[k] - 1)
    }

    /// Whether `point` (m) lies in some segment's cylinder (inside its bounding box and
    /// [`SegmentFlow::local`] to it).
    pub fn holds(&self, point: &[f64; 3]) -> bool {
        let inside = |index: usize| {
            let (lo, hi) = &self.boxes[index];
            (0..3).all(|k| point[k] >= lo[k] && point[k] <= hi[k])
                && self.segments[index].local(point).is_some()
        };
        if self.dims[0] == 0 {
            return (0..self.segments.len()).any(inside);
        }
        let within = (0..3).all(|k| {
            let offset = (point[k] - self.origin[k]) / self.cell;
            offset >= 0.0 && offset < self.dims[k] as f64
        });
        if !within {
            // Outside every box (or not a number).
            return false;
        }
        let [x, y, z]: [usize; 3] = std::array::from_fn(|k| self.axis_cell(k, point[k]));
        self.cells[(z * self.dims[1] + y) * self.dims[0] + x]
            .iter()
            .any(|&index| inside(index as usize))
    }
}
