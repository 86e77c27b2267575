//! Every lag product a series' Doppler moments are made of, in one pass over its pixels: power
//! and the temporal lag-1 ([`autocorrelation`]), the axial and lateral lags ([`SpatialLag`]) and
//! the resolution cell's lags within frames ([`CellLags`]).
//!
//! Each is the same sum of the same [`conj_dot`]s as when it is measured alone, so the moments
//! are the same to the bit however many are measured together. Measured together, a pixel's
//! frames and its neighbours' are read once for all of them, and the cell's lags within frames
//! to the pixel below and to the right are the axial and lateral lags' own.

use super::*;
use crate::core::buffers::contiguous;
use crate::core::lags::conj_dot;

/// Products of each pixel of an image series with its neighbour one pixel step away, within
/// frames, summed over the image and averaged over the frames: the spatial autocorrelation of
/// the echoes, whose fall-off with the step measures the resolution cell
/// ([`crate::estimate::partial_volume::CellCovariance`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CellLags {
    /// Σ |S|² over the pixels (|IQ|² units).
    pub zero: f64,
    /// Σ S*(z, x)·S(z + 1, x): one step deeper.
    pub down: Complex64,
    /// Σ S*(z, x)·S(z, x + 1): one step toward +x.
    pub right: Complex64,
    /// Σ S*(z, x)·S(z + 1, x + 1).
    pub down_right: Complex64,
    /// Σ S*(z, x)·S(z + 1, x − 1).
    pub down_left: Complex64,
}

impl CellLags {
    /// The lags of `series` (nz, nx, frames), each pixel's frames contiguous or not.
    pub fn of(series: ArrayView3<Complex32>) -> CellLags {
        let wanted = Wanted {
            cell: true,
            ..Wanted::default()
        };
        lag_sums(series, wanted)
            .cell
            .expect("the cell's lags were asked for")
    }

    /// Combines the lags of two sets of frames of the same pixels, `frames` and `other_frames`
    /// of them: means weighted by their frames.
    pub fn merged(&self, frames: usize, other: &CellLags, other_frames: usize) -> CellLags {
        let (a, b) = (frames as f64, other_frames as f64);
        let total = (a + b).max(1.0);
        let mix = |x: Complex64, y: Complex64| (x * a + y * b) / total;
        CellLags {
            zero: (self.zero * a + other.zero * b) / total,
            down: mix(self.down, other.down),
            right: mix(self.right, other.right),
            down_right: mix(self.down_right, other.down_right),
            down_left: mix(self.down_left, other.down_left),
        }
    }

    /// The lags from each row's sums over its pixels (zero, down, right, down-right, down-left),
    /// added in the order of the rows, and the series' `frames`.
    fn of_row_sums(rows: impl Iterator<Item = [Complex64; 5]>, frames: usize) -> CellLags {
        let total = rows.fold([Complex64::new(0.0, 0.0); 5], |mut t, r| {
            t.iter_mut().zip(r).for_each(|(t, r)| *t += r);
            t
        });
        let frames = frames.max(1) as f64;
        CellLags {
            zero: total[0].re / frames,
            down: total[1] / frames,
            right: total[2] / frames,
            down_right: total[3] / frames,
            down_left: total[4] / frames,
        }
    }
}

/// Which lags [`lag_sums`] measures.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Wanted {
    /// Power and the lag-1 autocorrelation (needs ≥ 2 frames).
    pub temporal: bool,
    /// The axial [`SpatialLag`] (needs ≥ 2 rows and 2 frames).
    pub axial: bool,
    /// The lateral [`SpatialLag`] (needs ≥ 2 columns and 2 frames).
    pub lateral: bool,
    /// The resolution cell's [`CellLags`].
    pub cell: bool,
}

/// What [`lag_sums`] measured, each `None` unless asked for.
#[derive(Debug, Clone)]
pub(super) struct LagSums {
    /// Power and lag-1 autocorrelation per pixel, not averaged in space.
    pub temporal: Option<Autocorrelation>,
    /// The axial lags per pixel.
    pub axial: Option<SpatialLag>,
    /// The lateral lags per pixel.
    pub lateral: Option<SpatialLag>,
    /// The resolution cell's lags over the image.
    pub cell: Option<CellLags>,
}

/// The per-pixel outputs of [`lag_sums`], in their order within a row's values.
const POWER: usize = 0;
const R1: usize = 1;
const AXIAL: usize = 2;
const LATERAL: usize = 5;
const PER_PIXEL: usize = 8;

/// One row's measurements: `PER_PIXEL` maps' values (each map's row after the other; those not
/// asked for left zero) and the cell's sums over the row's pixels.
struct RowSums {
    values: Vec<Complex64>,
    cell: [Complex64; 5],
}

/// The lags `wanted` of `series` (nz, nx, frames), in one pass over its rows (in parallel); the
/// caller has checked the sizes each needs.
pub(super) fn lag_sums(series: ArrayView3<Complex32>, wanted: Wanted) -> LagSums {
    let (nz, nx, nf) = series.dim();
    let frames = nf as f64;
    let pairs = nf.saturating_sub(1) as f64;
    // Products of a pixel pair (a, b) at temporal lags +1 and −1 and within frames, as means.
    let pair_means = |a: &[Complex32], b: &[Complex32]| {
        (
            conj_dot(&a[..nf - 1], &b[1..]) / pairs,
            conj_dot(&a[1..], &b[..nf - 1]) / pairs,
            conj_dot(a, b),
        )
    };
    let rows: Vec<RowSums> = (0..nz)
        .into_par_iter()
        .map(|iz| {
            let pixel = |iz: usize, ix: usize| contiguous(series.slice(s![iz, ix, ..]));
            // No maps when only the cell's sums over the image are asked for.
            let maps = if wanted.temporal || wanted.axial || wanted.lateral {
                PER_PIXEL * nx
            } else {
                0
            };
            let mut values = vec![Complex64::new(0.0, 0.0); maps];
            let mut cell = [Complex64::new(0.0, 0.0); 5];
            let below = iz + 1 < nz;
            for ix in 0..nx {
                let at = |map: usize| map * nx + ix;
                let right = ix + 1 < nx;
                let here = pixel(iz, ix);
                let under = below.then(|| pixel(iz + 1, ix));
                if wanted.temporal || wanted.cell {
                    let zero = conj_dot(&here, &here);
                    if wanted.temporal {
                        values[at(POWER)] = Complex64::new(zero.re / frames, 0.0);
                        values[at(R1)] = conj_dot(&here[..nf - 1], &here[1..]) / pairs;
                    }
                    cell[0] += zero;
                }
                // The within-frame product to the pixel below, when the axial lag has it.
                let mut down = None;
                if wanted.axial {
                    // The last row pairs with the one above it, roles swapped, so the phase
                    // keeps its sign.
                    let (p, m, q) = match &under {
                        Some(under) => pair_means(&here, under),
                        None => pair_means(&pixel(iz - 1, ix), &here),
                    };
                    down = under.is_some().then_some(q);
                    values[at(AXIAL)] = p;
                    values[at(AXIAL + 1)] = m;
                    values[at(AXIAL + 2)] = q / frames;
                }
                let mut across = None;
                if wanted.lateral {
                    let (p, m, q) = if right {
                        pair_means(&here, &pixel(iz, ix + 1))
                    } else {
                        pair_means(&pixel(iz, ix - 1), &here)
                    };
                    across = right.then_some(q);
                    values[at(LATERAL)] = p;
                    values[at(LATERAL + 1)] = m;
                    values[at(LATERAL + 2)] = q / frames;
                }
                if wanted.cell {
                    if let Some(under) = &under {
                        cell[1] += down.unwrap_or_else(|| conj_dot(&here, under));
                        if right {
                            cell[3] += conj_dot(&here, &pixel(iz + 1, ix + 1));
                        }
                        if ix > 0 {
                            cell[4] += conj_dot(&here, &pixel(iz + 1, ix - 1));
                        }
                    }
                    if right {
                        cell[2] += across.unwrap_or_else(|| conj_dot(&here, &pixel(iz, ix + 1)));
                    }
                }
            }
            RowSums { values, cell }
        })
        .collect();
    let map = |k: usize| Array2::from_shape_fn((nz, nx), |(iz, ix)| rows[iz].values[k * nx + ix]);
    let spatial = |first: usize| SpatialLag {
        plus: map(first),
        minus: map(first + 1),
        same: map(first + 2),
    };
    LagSums {
        temporal: wanted.temporal.then(|| Autocorrelation {
            power: map(POWER).mapv(|p| p.re),
            r1: map(R1),
        }),
        axial: wanted.axial.then(|| spatial(AXIAL)),
        lateral: wanted.lateral.then(|| spatial(LATERAL)),
        cell: wanted
            .cell
            .then(|| CellLags::of_row_sums(rows.iter().map(|r| r.cell), nf)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array3;
    use rand::{RngExt, SeedableRng};

    /// A random series (nz, nx, frames) whose pixels' frames are not contiguous in memory (a view
    /// of a (frames, nz, nx) array), as a caller's slice of another layout may be.
    fn scattered_series(nz: usize, nx: usize, frames: usize, seed: u64) -> Array3<Complex32> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut value = || rng.random::<f32>() * 2.0 - 1.0;
        Array3::from_shape_fn((frames, nz, nx), |_| Complex32::new(value(), value()))
    }

    /// Σ_t conj(a_{t + da})·b_{t + db} over the `n` pairs, each float's product in f32 and the
    /// sums in f64, term by term.
    fn sum_of_products(
        a: &[Complex32],
        b: &[Complex32],
        da: usize,
        db: usize,
        n: usize,
    ) -> Complex64 {
        (0..n)
            .map(|t| {
                let (x, y) = (a[t + da], b[t + db]);
                let re = (x.re * y.re) as f64 + (x.im * y.im) as f64;
                let im = (x.re * y.im) as f64 - (x.im * y.re) as f64;
                Complex64::new(re, im)
            })
            .sum()
    }

    fn close(got: Complex64, want: Complex64, scale: f64) -> bool {
        (got - want).norm() <= 1e-12 * scale
    }

    /// Every lag measured in one pass is its definition written out term by term (within the
    /// sums' rounding), on series one pixel wide or deep too.
    #[test]
    fn each_lag_is_its_sum_of_products() {
        for (nz, nx, nf) in [(5, 4, 7), (2, 1, 3), (1, 3, 2), (3, 2, 16)] {
            let stored = scattered_series(nz, nx, nf, (nz * 100 + nx * 10 + nf) as u64);
            let series = stored.view().permuted_axes([1, 2, 0]);
            let wanted = Wanted {
                temporal: true,
                axial: nz >= 2,
                lateral: nx >= 2,
                cell: true,
            };
            let sums = lag_sums(series, wanted);
            let px = |iz: usize, ix: usize| series.slice(s![iz, ix, ..]).to_vec();
            let (frames, pairs) = (nf as f64, (nf - 1) as f64);
            let scale = 2.0 * nf as f64;
            let temporal = sums.temporal.as_ref().unwrap();
            let mut cell = [Complex64::new(0.0, 0.0); 5];
            for iz in 0..nz {
                for ix in 0..nx {
                    let here = px(iz, ix);
                    let zero = sum_of_products(&here, &here, 0, 0, nf);
                    assert!(close(temporal.power[[iz, ix]].into(), zero / frames, scale));
                    let r1 = sum_of_products(&here, &here, 0, 1, nf - 1) / pairs;
                    assert!(close(temporal.r1[[iz, ix]], r1, scale));
                    cell[0] += zero;
                    // (a, b): the pixel and its neighbour along the lag, the last pixel of a line
                    // with the one before it.
                    let check = |lag: &SpatialLag, a: &[Complex32], b: &[Complex32]| {
                        let plus = sum_of_products(a, b, 0, 1, nf - 1) / pairs;
                        let minus = sum_of_products(a, b, 1, 0, nf - 1) / pairs;
                        let same = sum_of_products(a, b, 0, 0, nf) / frames;
                        assert!(close(lag.plus[[iz, ix]], plus, scale));
                        assert!(close(lag.minus[[iz, ix]], minus, scale));
                        assert!(close(lag.same[[iz, ix]], same, scale));
                    };
                    if let Some(axial) = &sums.axial {
                        let (a, b) = if iz + 1 < nz {
                            (iz, iz + 1)
                        } else {
                            (iz - 1, iz)
                        };
                        check(axial, &px(a, ix), &px(b, ix));
                    }
                    if let Some(lateral) = &sums.lateral {
                        let (a, b) = if ix + 1 < nx {
                            (ix, ix + 1)
                        } else {
                            (ix - 1, ix)
                        };
                        check(lateral, &px(iz, a), &px(iz, b));
                    }
                    let mut add = |k: usize, dz: usize, dx: isize| {
                        let (z, x) = (iz + dz, ix as isize + dx);
                        if z < nz && x >= 0 && (x as usize) < nx {
                            cell[k] += sum_of_products(&here, &px(z, x as usize), 0, 0, nf);
                        }
                    };
                    add(1, 1, 0);
                    add(2, 0, 1);
                    add(3, 1, 1);
                    add(4, 1, -1);
                }
            }
            let got = sums.cell.unwrap();
            let got = [
                got.zero.into(),
                got.down,
                got.right,
                got.down_right,
                got.down_left,
            ];
            for (got, want) in got.iter().zip(cell) {
                assert!(
                    close(*got, want / frames, scale * (nz * nx) as f64),
                    "{got} {want}"
                );
            }
        }
    }

    /// Measured together or alone, every lag is the same to the bit: the moments do not depend
    /// on which others a caller asked for.
    #[test]
    fn lags_measured_together_are_those_measured_alone() {
        let stored = scattered_series(6, 5, 9, 11);
        let series = stored.view().permuted_axes([1, 2, 0]);
        let all = Wanted {
            temporal: true,
            axial: true,
            lateral: true,
            cell: true,
        };
        let together = lag_sums(series, all);
        let alone = |wanted: Wanted| lag_sums(series, wanted);
        let bits = |m: &Array2<Complex64>| {
            m.iter()
                .flat_map(|v| [v.re.to_bits(), v.im.to_bits()])
                .collect::<Vec<_>>()
        };
        let same_lag = |a: &SpatialLag, b: &SpatialLag| {
            bits(&a.plus) == bits(&b.plus)
                && bits(&a.minus) == bits(&b.minus)
                && bits(&a.same) == bits(&b.same)
        };
        let none = Wanted::default();
        let temporal = alone(Wanted {
            temporal: true,
            ..none
        })
        .temporal
        .unwrap();
        let t = together.temporal.as_ref().unwrap();
        assert!(
            t.power
                .iter()
                .zip(&temporal.power)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
        assert_eq!(bits(&t.r1), bits(&temporal.r1));
        let axial = alone(Wanted {
            axial: true,
            ..none
        })
        .axial
        .unwrap();
        assert!(same_lag(together.axial.as_ref().unwrap(), &axial));
        let lateral = alone(Wanted {
            lateral: true,
            ..none
        })
        .lateral
        .unwrap();
        assert!(same_lag(together.lateral.as_ref().unwrap(), &lateral));
        let cell = alone(Wanted { cell: true, ..none }).cell.unwrap();
        let c = together.cell.unwrap();
        let cell_bits = |c: &CellLags| {
            [c.down, c.right, c.down_right, c.down_left]
                .iter()
                .flat_map(|v| [v.re.to_bits(), v.im.to_bits()])
                .chain([c.zero.to_bits()])
                .collect::<Vec<_>>()
        };
        assert_eq!(cell_bits(&c), cell_bits(&cell));
    }
}
