//! Lag-1 autocorrelations of the slow-time series: the temporal one (Kasai's), its box average
//! over a kernel, and the spatial lags (axial, lateral) that give each echo's mean frequency.

use super::lag_sums::{Wanted, lag_sums};
use super::*;

/// Power and lag-1 autocorrelation per pixel, shape (nz, nx).
#[derive(Debug, Clone, PartialEq)]
pub struct Autocorrelation {
    /// Mean |S|² over frames (power Doppler).
    pub power: Array2<f64>,
    /// Lag-1 autocorrelation R (eq. 4).
    pub r1: Array2<Complex64>,
}

/// Computes power and lag-1 autocorrelation of `series` (nz, nx, frames), each averaged over a
/// spatial box of `kernel` = (rows, cols) pixels (odd sizes; (1, 1) means no averaging).
pub fn autocorrelation(
    series: ArrayView3<Complex32>,
    kernel: (usize, usize),
) -> Result<Autocorrelation> {
    check_frames(series.dim().2)?;
    check_kernel(kernel)?;
    let wanted = Wanted {
        temporal: true,
        ..Wanted::default()
    };
    let Autocorrelation { mut power, mut r1 } = lag_sums(series, wanted)
        .temporal
        .expect("the temporal lags were asked for");
    if kernel != (1, 1) {
        power = box_average(&power, kernel);
        r1 = box_average(&r1, kernel);
    }
    Ok(Autocorrelation { power, r1 })
}

/// Refuses a series of fewer than 2 frames, which has no lag-1 product.
pub(super) fn check_frames(nf: usize) -> Result<()> {
    if nf < 2 {
        return Err(invalid(
            "Doppler",
            format!("needs at least 2 frames, got {nf}"),
        ));
    }
    Ok(())
}

/// Refuses an averaging box with an even size (it would have no centre pixel).
pub(super) fn check_kernel(kernel: (usize, usize)) -> Result<()> {
    if kernel.0.is_multiple_of(2) || kernel.1.is_multiple_of(2) {
        return Err(invalid(
            "Doppler averaging kernel",
            format!("sizes must be odd, got {kernel:?}"),
        ));
    }
    Ok(())
}

impl Autocorrelation {
    /// The same estimates averaged over a spatial box of `kernel` = (rows, cols) pixels (odd
    /// sizes), as [`autocorrelation`] averages them: for estimates summed over several segments of
    /// a recording before averaging (the average is linear, so the order does not matter).
    pub fn box_averaged(self, kernel: (usize, usize)) -> Result<Autocorrelation> {
        check_kernel(kernel)?;
        if kernel == (1, 1) {
            return Ok(self);
        }
        Ok(Autocorrelation {
            power: box_average(&self.power, kernel),
            r1: box_average(&self.r1, kernel),
        })
    }
}

/// The mean of `map` over a box of `kernel` = (rows, cols) pixels centred on each pixel (odd
/// sizes), the box cut at the image's edges. Separable: each row's sums along x, then those
/// sums added down z, rows + cols terms per pixel instead of rows × cols. Every sum takes its
/// terms in order (of x, then of z) from zero; each is formed in registers from its terms'
/// rows ([`sum_of_rows`]), where adding one term to every sum at a time read and wrote each
/// sum once per term.
pub(super) fn box_average<T>(map: &Array2<T>, kernel: (usize, usize)) -> Array2<T>
where
    T: bytemuck::Pod + Default + Send + Sync + std::ops::AddAssign + std::ops::Div<f64, Output = T>,
{
    let (nz, nx) = map.dim();
    let (hz, hx) = (kernel.0 / 2, kernel.1 / 2);
    if nz == 0 || nx == 0 {
        return map.clone();
    }
    // The f64 parts of one value (1 for f64, 2 for complex): sums are part by part.
    let parts = std::mem::size_of::<T>() / std::mem::size_of::<f64>();
    let columns = |x: usize| (x.saturating_sub(hx), (x + hx + 1).min(nx));
    let map = map.as_standard_layout();
    let rows = map.as_slice().expect("standard layout");
    // A box one pixel wide (the default 5x1 kernel) needs no sums along x: each is the value
    // itself. (The sums down z start from +0, so a value of −0 adds as its one-term sum, +0,
    // would: the same to the bit.)
    let along_x: std::borrow::Cow<[T]> = if hx == 0 {
        std::borrow::Cow::Borrowed(rows)
    } else {
        let mut sums = vec![T::default(); nz * nx];
        sums.par_chunks_mut(nx)
            .zip(rows.par_chunks(nx))
            .for_each(|(sums, row)| {
                // Where the box lies whole within the row, the sums are those of the row
                // shifted by each of the box's columns; at the edges, each of its own terms.
                let inner = hx..nx.saturating_sub(hx).max(hx);
                if !inner.is_empty() {
                    let floats: &[f64] = bytemuck::cast_slice(row);
                    let shifted: Vec<&[f64]> = (0..2 * hx + 1)
                        .map(|k| &floats[k * parts..(k + inner.len()) * parts])
                        .collect();
                    sum_of_rows(bytemuck::cast_slice_mut(&mut sums[inner.clone()]), &shifted);
                }
                for x in (0..nx).filter(|x| !inner.contains(x)) {
                    let (x0, x1) = columns(x);
                    let mut sum = T::default();
                    for &v in &row[x0..x1] {
                        sum += v;
                    }
                    sums[x] = sum;
                }
            });
        std::borrow::Cow::Owned(sums)
    };
    let mut out = vec![T::default(); nz * nx];
    out.par_chunks_mut(nx).enumerate().for_each(|(z, row)| {
        let (z0, z1) = (z.saturating_sub(hz), (z + hz + 1).min(nz));
        let terms: Vec<&[f64]> = along_x[z0 * nx..z1 * nx]
            .chunks(nx)
            .map(bytemuck::cast_slice)
            .collect();
        sum_of_rows(bytemuck::cast_slice_mut(row), &terms);
        // Each run of pixels whose boxes hold as many pixels (all but the edges' hx on either
        // side) divided by one count: the loop then vectorises, where a count per pixel left
        // every division on its own.
        let width = |x: usize| {
            let (x0, x1) = columns(x);
            x1 - x0
        };
        let mut x = 0;
        while x < nx {
            let w = width(x);
            let end = (x + 1..nx).find(|&e| width(e) != w).unwrap_or(nx);
            let count = ((z1 - z0) * w) as f64;
            for out in &mut row[x..end] {
                *out = *out / count;
            }
            x = end;
        }
    });
    Array2::from_shape_vec((nz, nx), out).expect("nz × nx values")
}

/// `dest[i]` = Σ_k `terms[k][i]`, summed from +0 in the order of k (the same bits as adding
/// them one by one), in blocks of values whose sums stay in registers while every term's block
/// is added. Every term is at least as long as `dest`.
fn sum_of_rows(dest: &mut [f64], terms: &[&[f64]]) {
    const BLOCK: usize = 16;
    let len = dest.len();
    assert!(terms.iter().all(|t| t.len() >= len));
    let whole = len / BLOCK * BLOCK;
    for (at, out) in (0..whole).step_by(BLOCK).zip(dest.chunks_exact_mut(BLOCK)) {
        let mut sums = [0.0f64; BLOCK];
        for term in terms {
            let term: &[f64; BLOCK] = term[at..at + BLOCK].try_into().expect("a block");
            for (sum, &v) in sums.iter_mut().zip(term) {
                *sum += v;
            }
        }
        out.copy_from_slice(&sums);
    }
    for (i, out) in dest.iter_mut().enumerate().skip(whole) {
        let mut sum = 0.0;
        for term in terms {
            sum += term[i];
        }
        *out = sum;
    }
}

/// Axial-lag autocorrelation R(1, 0) per pixel, shape (nz, nx): the mean over frames of
/// S*(z)·S(z + 1 pixel) (the last row uses the pair above it), averaged over a spatial box of
/// `kernel` = (rows, cols) pixels like [`autocorrelation`]. `series` is (nz, nx, frames) with the
/// carrier phase restored (as [`crate::form::beamform::beamform`] gives it) and needs nz ≥ 2.
pub fn axial_autocorrelation(
    series: ArrayView3<Complex32>,
    kernel: (usize, usize),
) -> Result<Array2<Complex64>> {
    let (nz, nx, nf) = series.dim();
    if nz < 2 || nf < 1 {
        return Err(invalid(
            "Doppler",
            format!(
                "the axial autocorrelation needs at least 2 rows and 1 frame, got {nz} rows and {nf} frames"
            ),
        ));
    }
    check_kernel(kernel)?;
    let mut r = Array2::<Complex64>::zeros((nz, nx));
    r.axis_iter_mut(Axis(0))
        .into_par_iter()
        .enumerate()
        .for_each(|(iz, mut row)| {
            let z0 = iz.min(nz - 2);
            for (ix, out) in row.iter_mut().enumerate() {
                let (a, b) = (
                    series.slice(s![z0, ix, ..]),
                    series.slice(s![z0 + 1, ix, ..]),
                );
                let mut acc = Complex64::new(0.0, 0.0);
                for (u, v) in a.iter().zip(b.iter()) {
                    let p = u.conj() * v;
                    acc += Complex64::new(p.re as f64, p.im as f64);
                }
                *out = acc / nf as f64;
            }
        });
    if kernel != (1, 1) {
        r = box_average(&r, kernel);
    }
    Ok(r)
}

/// Noise-immune axial-lag autocorrelation per pixel, (nz, nx): with R(1, ±1) the means over
/// frames of S*(z, t)·S(z + 1, t + 1) and S*(z, t + 1)·S(z + 1, t) (the last row pairs with the
/// row above), each averaged over `kernel`, R(1, +1)·e^{−iφ} + R(1, −1)·e^{+iφ}, φ = arg `r1`
/// (the lag-1 autocorrelation, same shape). Both terms carry the axial phase ± the Doppler phase;
/// removing φ leaves the axial phase of [`axial_autocorrelation`] without the receiver noise's
/// own axial correlation (white noise does not correlate across frames). Needs nz ≥ 2 and ≥ 2
/// frames.
pub fn axial_autocorrelation_lag1(
    series: ArrayView3<Complex32>,
    r1: &Array2<Complex64>,
    kernel: (usize, usize),
) -> Result<Array2<Complex64>> {
    spatial_lag1(series, r1, kernel, Axis(0))
}

/// As [`axial_autocorrelation_lag1`], one pixel to the side (+x): its phase is the mean lateral
/// wavenumber times the lateral step. Needs nx ≥ 2 and ≥ 2 frames.
pub fn lateral_autocorrelation_lag1(
    series: ArrayView3<Complex32>,
    r1: &Array2<Complex64>,
    kernel: (usize, usize),
) -> Result<Array2<Complex64>> {
    spatial_lag1(series, r1, kernel, Axis(1))
}

/// The spatial lag of one pixel along `along` (Axis(0): depth, Axis(1): lateral) at temporal lags
/// ±1, with the Doppler phase of `r1` removed; see [`axial_autocorrelation_lag1`].
pub(super) fn spatial_lag1(
    series: ArrayView3<Complex32>,
    r1: &Array2<Complex64>,
    kernel: (usize, usize),
    along: Axis,
) -> Result<Array2<Complex64>> {
    check_kernel(kernel)?;
    let (nz, nx, _) = series.dim();
    if r1.dim() != (nz, nx) {
        return Err(Error::Shape(format!(
            "lag-1 autocorrelation {:?} for a series of {nz} × {nx} pixels",
            r1.dim()
        )));
    }
    Ok(spatial_lag_means(series, along)?.rotated(r1, kernel))
}

/// The spatial-lag products of one pixel step at temporal lags ±1 and within frames, per pixel
/// (nz, nx), as means over the frame pairs (frames) and not yet averaged in space: the raw
/// material of [`axial_autocorrelation_lag1`], [`lateral_autocorrelation_lag1`] and of the
/// phase that scales Loupas's velocity ([`SAME_FRAME_WEIGHT`]). Means over different frames add
/// as any mean does ([`Moments::merge`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SpatialLag {
    /// Mean over frame pairs of S*(p, t)·S(p′, t + 1), p′ the pixel one step along the lag (the
    /// last pixel of a line pairs with the one before it, roles swapped).
    pub plus: Array2<Complex64>,
    /// Mean over frame pairs of S*(p, t + 1)·S(p′, t).
    pub minus: Array2<Complex64>,
    /// Mean over frames of S*(p, t)·S(p′, t): the same lag within each frame.
    pub same: Array2<Complex64>,
}

impl SpatialLag {
    /// Both products averaged over `kernel` (odd sizes), then R(+1)·e^{−iφ} + R(−1)·e^{+iφ} with
    /// φ = arg `r1` (same shape): the spatial phase without the Doppler phase.
    pub(super) fn rotated(
        &self,
        r1: &Array2<Complex64>,
        kernel: (usize, usize),
    ) -> Array2<Complex64> {
        let (plus, minus) = if kernel == (1, 1) {
            (self.plus.clone(), self.minus.clone())
        } else {
            (
                box_average(&self.plus, kernel),
                box_average(&self.minus, kernel),
            )
        };
        Zip::from(&plus)
            .and(&minus)
            .and(r1)
            .map_collect(|&p, &m, &r| {
                let magnitude = r.norm();
                let turn = if magnitude > 0.0 {
                    r / magnitude
                } else {
                    Complex64::new(1.0, 0.0)
                };
                p * turn.conj() + m * turn
            })
    }
}

/// [`SpatialLag`] of `series` (nz, nx, frames) one pixel along `along`.
pub(super) fn spatial_lag_means(series: ArrayView3<Complex32>, along: Axis) -> Result<SpatialLag> {
    check_spatial_lag(series.dim(), along)?;
    let wanted = Wanted {
        axial: along == Axis(0),
        lateral: along == Axis(1),
        ..Wanted::default()
    };
    let sums = lag_sums(series, wanted);
    Ok(sums
        .axial
        .or(sums.lateral)
        .expect("the lag along `along` was asked for"))
}

/// Refuses a series of `dim` (nz, nx, frames) too small for a spatial lag along `along`: it
/// needs 2 pixels along it and 2 frames.
pub(super) fn check_spatial_lag(dim: (usize, usize, usize), along: Axis) -> Result<()> {
    let (nz, nx, nf) = dim;
    let (n_along, what) = if along == Axis(0) {
        (nz, "rows")
    } else {
        (nx, "columns")
    };
    if n_along < 2 || nf < 2 {
        return Err(invalid(
            "Doppler",
            format!(
                "a spatial-lag autocorrelation needs at least 2 {what} and 2 frames, got {n_along} {what} and {nf} frames"
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The separable box mean is the mean over each pixel's box written out term by term, the
    /// box cut at the edges, on maps narrower and shorter than the box too and on rows long
    /// enough for whole blocks of sums; to the bit, it is the row sums along x added down z,
    /// each from zero (values over twelve decades, whose sums depend on their order, and zeros
    /// of both signs); a real map's is the real part of the complex one's.
    #[test]
    fn box_average_is_the_mean_over_each_pixels_box() {
        for (nz, nx) in [(9, 11), (2, 3), (1, 6), (7, 45)] {
            let map = Array2::from_shape_fn((nz, nx), |(z, x)| {
                let scale = 10f64.powi((x * 5 + z) as i32 % 13 - 6);
                let re = ((z * 31 + x * 7) as f64 * 0.37).sin() * scale;
                let im = if (z + x) % 4 == 0 {
                    -0.0
                } else {
                    ((z * x) as f64 * 0.11).cos()
                };
                Complex64::new(re, im)
            });
            for kernel in [(1, 1), (3, 5), (7, 7), (5, 1), (5, 5), (1, 3)] {
                let averaged = box_average(&map, kernel);
                let real = box_average(&map.mapv(|v| v.re), kernel);
                assert!(
                    (real.iter().zip(&averaged)).all(|(r, c)| r.to_bits() == c.re.to_bits()),
                    "{kernel:?} on {nz} × {nx}: the real map's mean"
                );
                for ((z, x), &got) in averaged.indexed_iter() {
                    let (hz, hx) = (kernel.0 / 2, kernel.1 / 2);
                    let (mut sum, mut count, mut size) = (Complex64::new(0.0, 0.0), 0, 0.0);
                    for zz in z.saturating_sub(hz)..(z + hz + 1).min(nz) {
                        for xx in x.saturating_sub(hx)..(x + hx + 1).min(nx) {
                            sum += map[[zz, xx]];
                            size += map[[zz, xx]].norm();
                            count += 1;
                        }
                    }
                    let want = sum / count as f64;
                    // Within the rounding of sums over terms of this size.
                    assert!(
                        (got - want).norm() <= 1e-14 * size,
                        "{kernel:?} on {nz} × {nx} at ({z}, {x}): {got} against {want}"
                    );
                    // To the bit: each row's terms summed along x from zero, those sums added
                    // down z from zero, divided by the count.
                    let mut separable = Complex64::new(0.0, 0.0);
                    for zz in z.saturating_sub(hz)..(z + hz + 1).min(nz) {
                        let mut along_x = Complex64::new(0.0, 0.0);
                        for xx in x.saturating_sub(hx)..(x + hx + 1).min(nx) {
                            along_x += map[[zz, xx]];
                        }
                        separable += along_x;
                    }
                    let separable = separable / count as f64;
                    assert_eq!(
                        (got.re.to_bits(), got.im.to_bits()),
                        (separable.re.to_bits(), separable.im.to_bits()),
                        "{kernel:?} on {nz} × {nx} at ({z}, {x})"
                    );
                }
            }
        }
    }
}
