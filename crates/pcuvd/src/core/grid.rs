//! The pixel grid that images and maps live on, and rectangular regions of it.
//!
//! Rows are depths `z`, columns lateral positions `x`, both in metres and increasing; a map on a
//! grid has shape (nz, nx).

use std::ops::Range;

use ndarray::{Array2, s};

use crate::core::error::{Result, invalid, require_positive};

/// Most pixels a grid may hold.
pub const MAX_PIXELS: usize = 50_000_000;

/// A rectangular pixel grid: lateral positions `x` and depths `z` (m), both increasing.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Grid {
    /// Lateral pixel positions (m).
    pub x: Vec<f64>,
    /// Depth pixel positions (m).
    pub z: Vec<f64>,
}

impl Grid {
    /// A grid spanning [x_min, x_max] × [z_min, z_max] (m) with spacing `step` (m) on both axes.
    pub fn new(x_min: f64, x_max: f64, z_min: f64, z_max: f64, step: f64) -> Result<Grid> {
        require_positive("grid step", step)?;
        for (name, v) in [
            ("x_min", x_min),
            ("x_max", x_max),
            ("z_min", z_min),
            ("z_max", z_max),
        ] {
            if !v.is_finite() {
                return Err(invalid("grid", format!("{name} = {v} is not finite")));
            }
        }
        if x_max < x_min || z_max < z_min {
            return Err(invalid(
                "grid",
                format!("empty extent x [{x_min}, {x_max}] m, z [{z_min}, {z_max}] m"),
            ));
        }
        if z_min < 0.0 {
            return Err(invalid(
                "grid",
                format!("z_min = {z_min} m lies behind the probe face (z < 0)"),
            ));
        }
        // Counted in floating point and checked before any allocation: an extent of 1e300 m or a
        // step of 1e-300 m would overflow an integer count.
        let count = |lo: f64, hi: f64| ((hi - lo) / step + 1e-9).floor() + 1.0;
        let (nx, nz) = (count(x_min, x_max), count(z_min, z_max));
        if nx * nz > MAX_PIXELS as f64 {
            return Err(invalid(
                "grid",
                format!(
                    "{nz:.3e} × {nx:.3e} pixels is too many (at most {MAX_PIXELS}): check the extent \
                     and the step ({step:.3e} m)"
                ),
            ));
        }
        let axis = |lo: f64, n: f64| -> Vec<f64> {
            (0..n as usize).map(|i| lo + i as f64 * step).collect()
        };
        Ok(Grid {
            x: axis(x_min, nx),
            z: axis(z_min, nz),
        })
    }

    /// (nz, nx).
    pub fn shape(&self) -> (usize, usize) {
        (self.z.len(), self.x.len())
    }

    /// Pixel spacing (m): the lateral one, or the axial one when the grid is one column wide.
    pub fn step(&self) -> f64 {
        match (self.x.as_slice(), self.z.as_slice()) {
            ([x0, x1, ..], _) => x1 - x0,
            (_, [z0, z1, ..]) => z1 - z0,
            _ => f64::NAN,
        }
    }

    /// Axial pixel spacing (m): z[1] − z[0]; NaN for a one-row grid.
    pub fn axial_step(&self) -> f64 {
        match self.z.as_slice() {
            [z0, z1, ..] => z1 - z0,
            _ => f64::NAN,
        }
    }

    /// The (row, column) of the pixel nearest to (x, z) (m); a tie goes to the lower index,
    /// and an empty axis gives index 0.
    pub fn nearest_pixel(&self, x: f64, z: f64) -> (usize, usize) {
        let nearest = |axis: &[f64], v: f64| {
            axis.iter()
                .enumerate()
                .min_by(|a, b| (a.1 - v).abs().total_cmp(&(b.1 - v).abs()))
                .map_or(0, |(i, _)| i)
        };
        (nearest(&self.z, z), nearest(&self.x, x))
    }
}

/// The indices of the increasing `axis` (m) whose positions lie in [lo, hi] (m), ends included;
/// an empty range (at the first position ≥ lo) when none does.
pub fn index_range(axis: &[f64], lo: f64, hi: f64) -> Range<usize> {
    let start = axis.iter().position(|&v| v >= lo).unwrap_or(axis.len());
    let end = axis.iter().rposition(|&v| v <= hi).map_or(start, |e| e + 1);
    start..end.max(start)
}

/// A rectangular part of a grid, at least 2 × 2 pixels, and the cut of maps on the grid to it.
#[derive(Debug, Clone, PartialEq)]
pub struct Roi {
    /// The part's own grid: the pixels of the parent grid inside it.
    pub grid: Grid,
    /// The parent grid's rows (depth indices) inside the part.
    pub rows: Range<usize>,
    /// The parent grid's columns (lateral indices) inside the part.
    pub cols: Range<usize>,
}

impl Roi {
    /// The pixels of `grid` with x in [x.0, x.1] and z in [z.0, z.1] (m); an error when that
    /// holds fewer than two rows or two columns.
    pub fn new(grid: &Grid, x: (f64, f64), z: (f64, f64)) -> Result<Roi> {
        let rows = index_range(&grid.z, z.0, z.1);
        let cols = index_range(&grid.x, x.0, x.1);
        if rows.len() < 2 || cols.len() < 2 {
            return Err(invalid(
                "region of interest",
                format!(
                    "x {x:?} m × z {z:?} m holds {} rows × {} columns of the grid, fewer than 2 × 2",
                    rows.len(),
                    cols.len()
                ),
            ));
        }
        let step = grid.step();
        let sub = Grid::new(
            grid.x[cols.start],
            grid.x[cols.end - 1],
            grid.z[rows.start],
            grid.z[rows.end - 1],
            step,
        )?;
        Ok(Roi {
            grid: sub,
            rows,
            cols,
        })
    }

    /// The part of map `a` (nz, nx) on the parent grid inside the region: shape (rows, cols).
    pub fn cut<T: Clone>(&self, a: &Array2<T>) -> Array2<T> {
        a.slice(s![self.rows.clone(), self.cols.clone()]).to_owned()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::error::Error;

    /// x = 0, 0.25, …, 1 and z = 0, 0.25, 0.5 (m): dyadic, so every position is exact.
    fn grid() -> Grid {
        Grid::new(0.0, 1.0, 0.0, 0.5, 0.25).unwrap()
    }

    #[test]
    fn grid_axes_and_shape() {
        let g = grid();
        assert_eq!(g.x, [0.0, 0.25, 0.5, 0.75, 1.0]);
        assert_eq!(g.z, [0.0, 0.25, 0.5]);
        assert_eq!(g.shape(), (3, 5));
        assert_eq!(g.step(), 0.25);
    }

    #[test]
    fn nearest_pixel_rounds_to_the_closest_position() {
        let g = grid();
        assert_eq!(g.nearest_pixel(0.3, 0.2), (1, 1));
        assert_eq!(g.nearest_pixel(0.9, 0.0), (0, 4));
        // Outside the grid: the edge pixel.
        assert_eq!(g.nearest_pixel(-5.0, 7.0), (2, 0));
        assert_eq!(g.nearest_pixel(2.0, -1.0), (0, 4));
        // Half-way between two positions: the lower index.
        assert_eq!(g.nearest_pixel(0.125, 0.375), (1, 0));
        assert_eq!(g.nearest_pixel(0.625, 0.125), (0, 2));
    }

    #[test]
    fn nearest_pixel_on_empty_axes_is_zero() {
        let g = Grid {
            x: vec![],
            z: vec![],
        };
        assert_eq!(g.nearest_pixel(0.1, 0.2), (0, 0));
    }

    #[test]
    fn index_range_keeps_positions_within_the_bounds() {
        let axis = [0.0, 1.0, 2.0, 3.0];
        assert_eq!(index_range(&axis, 0.5, 2.5), 1..3);
        // Both ends included.
        assert_eq!(index_range(&axis, 1.0, 2.0), 1..3);
        assert_eq!(index_range(&axis, -1.0, 10.0), 0..4);
        assert_eq!(index_range(&axis, 2.0, 2.0), 2..3);
        // Nothing inside: empty, at the first position ≥ lo.
        assert_eq!(index_range(&axis, 5.0, 6.0), 4..4);
        assert_eq!(index_range(&axis, 1.2, 1.8), 2..2);
        assert_eq!(index_range(&axis, 2.5, 0.5), 3..3);
        assert_eq!(index_range(&axis, -3.0, -2.0), 0..0);
        assert_eq!(index_range(&[], 0.0, 1.0), 0..0);
    }

    #[test]
    fn roi_selects_rows_columns_and_sub_grid() {
        let g = grid();
        let roi = Roi::new(&g, (0.2, 0.8), (0.25, 0.6)).unwrap();
        assert_eq!(roi.rows, 1..3);
        assert_eq!(roi.cols, 1..4);
        assert_eq!(roi.grid.x, [0.25, 0.5, 0.75]);
        assert_eq!(roi.grid.z, [0.25, 0.5]);
        let map = Array2::from_shape_fn((3, 5), |(r, c)| 10 * r + c);
        assert_eq!(roi.cut(&map), ndarray::array![[11, 12, 13], [21, 22, 23]]);
    }

    #[test]
    fn absurd_extents_and_steps_are_refused_before_allocating() {
        for (x0, x1, step) in [
            (-1e-3, 1e-3, 1e-300),
            (-1e300, 1e300, 1e-4),
            (-1e308, 1e308, 1e-4),
        ] {
            let err = Grid::new(x0, x1, 5e-3, 6e-3, step).unwrap_err();
            assert!(err.to_string().contains("too many"), "{err}");
        }
        // Exactly at the cap is allowed: 5000 × 10000 pixels.
        let g = Grid::new(0.0, 9999.0, 0.0, 4999.0, 1.0).unwrap();
        assert_eq!(g.shape(), (5000, 10000));
    }

    #[test]
    fn roi_needs_two_rows_and_two_columns() {
        let g = grid();
        for (x, z) in [
            ((0.3, 0.4), (0.0, 0.5)), // no column
            ((0.2, 0.3), (0.0, 0.5)), // one column
            ((0.0, 1.0), (0.1, 0.3)), // one row
            ((0.0, 1.0), (0.6, 0.9)), // below the grid
        ] {
            let err = Roi::new(&g, x, z).unwrap_err();
            assert!(
                matches!(&err, Error::InvalidParameter { name, .. } if name == "region of interest"),
                "{err}"
            );
        }
    }
}
