//! The [`Moments`] of many overlapping windows of one series, each frame's products formed once.
//!
//! Sliding windows overlap: 36-frame windows 9 frames apart hold every frame four times, and
//! forming each window's moments on its own forms every product four times, in sums so short that
//! the cost of starting each is much of the work. Here each pixel's frames are read once: the
//! products are summed in bins of g frames (g divides the window and the distance between window
//! starts), and each window's sums are the sums of its bins, with the frame pairs that straddle
//! the boundaries between its bins added. Each product is formed in f32 and summed in f64 as
//! [`conj_dot`] does; only the order of the sums differs from [`moments`] of the window.

use super::*;

/// What a window sums per pixel: power and lag-1 product of the pixel itself, and for each spatial
/// lag (axial, then lateral) its products at temporal lags +1 and −1 and within frames.
#[derive(Debug, Clone, Copy, Default)]
struct Sums {
    power: f64,
    r1: Complex64,
    /// Axial then lateral: [plus, minus, same].
    lags: [[Complex64; 3]; 2],
}

impl std::ops::AddAssign<&Sums> for Sums {
    fn add_assign(&mut self, other: &Sums) {
        self.power += other.power;
        self.r1 += other.r1;
        for (mine, theirs) in self.lags.iter_mut().zip(&other.lags) {
            for (m, t) in mine.iter_mut().zip(theirs) {
                *m += t;
            }
        }
    }
}

/// conj(x)·y, each product in f32 and their sums in f64, as [`conj_dot`] forms its terms.
#[inline(always)]
fn conj_product(x: Complex32, y: Complex32) -> Complex64 {
    Complex64::new(
        (x.re * y.re) as f64 + (x.im * y.im) as f64,
        (x.re * y.im) as f64 - (x.im * y.re) as f64,
    )
}

/// The most memory one window's [`Moments`] from [`window_moments`] take per pixel (bytes): the
/// power and seven complex products (lag 1, and the three of each spatial lag).
pub const WINDOW_MOMENT_BYTES_PER_PIXEL: usize =
    std::mem::size_of::<f64>() + 7 * std::mem::size_of::<Complex64>();

/// The [`Moments`] of the windows of `window` frames of `series` (nz, nx, frames) that start at
/// each of `starts` (frame indices, ascending), as [`moments`] of each window's frames would give
/// them (the same products; sums in another order, so equal to within rounding of the f64 sums).
/// Refuses windows shorter than 2 frames or past the series' end, and what [`moments`] refuses.
pub fn window_moments(
    series: ArrayView3<Complex32>,
    starts: &[usize],
    window: usize,
    estimator: DopplerEstimator,
    geometry: &DopplerGeometry,
) -> Result<Vec<Moments>> {
    let (nz, nx, nf) = series.dim();
    let (Some(&first), Some(&last)) = (starts.first(), starts.last()) else {
        return Ok(Vec::new());
    };
    if window < 2 {
        return Err(invalid(
            "Doppler",
            format!("needs at least 2 frames per window, got {window}"),
        ));
    }
    if starts.windows(2).any(|w| w[1] < w[0]) || last + window > nf {
        return Err(invalid(
            "Doppler windows",
            format!(
                "windows of {window} frames from frames {first}..={last} do not lie, in order, \
                 within the series' {nf} frames"
            ),
        ));
    }
    let lags = MeasuredLags::of(estimator, geometry, nx)?;
    if lags.axial && nz < 2 {
        return Err(invalid(
            "Doppler",
            format!("a spatial-lag autocorrelation needs at least 2 rows, got {nz}"),
        ));
    }
    // Bins of g frames from the first start: every window begins and ends on a bin boundary.
    let bin = starts
        .iter()
        .fold(window, |g, &s| num_integer::gcd(g, s - first));
    let span = last + window - first;
    let n_bins = span / bin;
    let n_windows = starts.len();
    let n_lags = lags.axial as usize + lags.lateral as usize;
    // Per window: r1, then [plus, minus, same] of each lag measured. Each map is allocated on its
    // own, small enough for the allocator to reuse from one call to the next.
    let planes = 1 + 3 * n_lags;
    let mut power: Vec<Array2<f64>> = (0..n_windows).map(|_| Array2::zeros((nz, nx))).collect();
    let mut products: Vec<Vec<Array2<Complex64>>> = (0..n_windows)
        .map(|_| (0..planes).map(|_| Array2::zeros((nz, nx))).collect())
        .collect();
    // Each depth row's slice of every map, so that rows fill in parallel.
    let mut rows: Vec<_> = (0..nz)
        .map(|_| {
            (
                Vec::with_capacity(n_windows),
                Vec::with_capacity(n_windows * planes),
            )
        })
        .collect();
    for map in &mut power {
        for (bundle, row) in rows.iter_mut().zip(map.outer_iter_mut()) {
            bundle.0.push(row);
        }
    }
    for map in products.iter_mut().flatten() {
        for (bundle, row) in rows.iter_mut().zip(map.outer_iter_mut()) {
            bundle.1.push(row);
        }
    }
    // A pixel's frames are contiguous in standard layout: each read as one slice.
    let series = series.as_standard_layout();
    let samples = series.as_slice().expect("standard layout");
    let frames = |z: usize, x: usize| -> &[Complex32] {
        let at = (z * nx + x) * nf + first;
        &samples[at..at + span]
    };
    rows.into_par_iter().enumerate().for_each_init(
        || (vec![Sums::default(); n_bins], vec![Sums::default(); n_bins]),
        |(bins, straddling), (iz, (mut power_rows, mut product_rows))| {
            for ix in 0..nx {
                // The pixel and its neighbour one step along each lag; the last one pairs with the
                // one before it, roles swapped, as [`spatial_lag_means`] pairs them.
                let pair = |i: usize, n: usize| if i + 1 < n { (i, i + 1) } else { (i - 1, i) };
                let axial = lags.axial.then(|| {
                    let (a, b) = pair(iz, nz);
                    (frames(a, ix), frames(b, ix))
                });
                let lateral = lags.lateral.then(|| {
                    let (a, b) = pair(ix, nx);
                    (frames(iz, a), frames(iz, b))
                });
                bin_sums(frames(iz, ix), [axial, lateral], bin, bins, straddling);
                let pairs = (window - 1) as f64;
                for ((&start, power), products) in starts
                    .iter()
                    .zip(power_rows.iter_mut())
                    .zip(product_rows.chunks_mut(planes))
                {
                    let (j0, j1) = ((start - first) / bin, (start - first + window) / bin);
                    let mut sums = bins[j0];
                    for j in j0 + 1..j1 {
                        sums += &bins[j];
                        sums += &straddling[j];
                    }
                    power[ix] = sums.power / window as f64;
                    products[0][ix] = sums.r1 / pairs;
                    for (lag, planes) in sums.lags.iter().zip(products[1..].chunks_mut(3)) {
                        planes[0][ix] = lag[0] / pairs;
                        planes[1][ix] = lag[1] / pairs;
                        planes[2][ix] = lag[2] / window as f64;
                    }
                }
            }
        },
    );
    Ok(power
        .into_iter()
        .zip(products)
        .map(|(power, planes)| {
            let mut planes = planes.into_iter();
            let r1 = planes.next().expect("the lag-1 map");
            let mut spatial = || {
                Some(SpatialLag {
                    plus: planes.next()?,
                    minus: planes.next()?,
                    same: planes.next()?,
                })
            };
            let axial = if lags.axial { spatial() } else { None };
            let lateral = if lags.lateral { spatial() } else { None };
            Moments {
                power,
                r1,
                axial,
                lateral,
                cell: None,
                frames: window,
                pairs: window - 1,
            }
        })
        .collect())
}

/// One pixel's products over its frames, summed in bins of `bin` frames: `bins[j]` holds the
/// frames of bin j and the pairs within it, `straddling[j]` the pair of frames (j·bin − 1, j·bin)
/// across the boundary before bin j (nothing for j = 0). `lags` holds the frames of the pixel pair
/// (first, second) of each spatial lag measured, axial then lateral.
fn bin_sums(
    pixel: &[Complex32],
    lags: [Option<(&[Complex32], &[Complex32])>; 2],
    bin: usize,
    bins: &mut [Sums],
    straddling: &mut [Sums],
) {
    for (j, (sums, across)) in bins.iter_mut().zip(straddling.iter_mut()).enumerate() {
        let (from, to) = (j * bin, (j + 1) * bin);
        *sums = Sums::default();
        *across = Sums::default();
        for t in from..to {
            let s = pixel[t];
            sums.power += (s.re * s.re) as f64 + (s.im * s.im) as f64;
            for (l, lag) in lags.iter().enumerate() {
                if let Some((a, b)) = lag {
                    sums.lags[l][2] += conj_product(a[t], b[t]);
                }
            }
            if t == 0 {
                continue;
            }
            // The pair (t − 1, t): within the bin, or across the boundary at its first frame.
            let paired = if t == from { &mut *across } else { &mut *sums };
            paired.r1 += conj_product(pixel[t - 1], s);
            for (l, lag) in lags.iter().enumerate() {
                if let Some((a, b)) = lag {
                    paired.lags[l][0] += conj_product(a[t - 1], b[t]);
                    paired.lags[l][1] += conj_product(a[t], b[t - 1]);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array3;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};

    fn geometry(lateral_step: f64) -> DopplerGeometry {
        DopplerGeometry {
            sound_speed: 1540.0,
            frame_rate: 1800.0,
            demodulation_frequency: 15.625e6,
            axial_step: 25e-6,
            axial_weight: 2.0,
            lateral_step,
            lateral_weight: 0.1,
        }
    }

    /// Every window's moments are those of [`moments`] on the window's own frames, to the
    /// rounding of the f64 sums: windows whose starts share a bin of several frames, windows one
    /// frame apart (bins of one frame: every pair straddles), a lone window, both estimators, and
    /// a grid too coarse for the lateral lag.
    #[test]
    fn each_window_has_the_moments_of_its_own_frames() {
        let (nz, nx, nf) = (5, 4, 40);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut draw = || -> f32 { StandardNormal.sample(&mut rng) };
        let series = Array3::from_shape_fn((nz, nx, nf), |_| Complex32::new(draw(), draw()));
        let close = |a: &Array2<Complex64>, b: &Array2<Complex64>| {
            a.iter()
                .zip(b)
                .all(|(a, b)| (a - b).norm() <= 1e-13 * (1.0 + b.norm()))
        };
        let cases: [(&[usize], usize); 5] = [
            (&[0, 9, 18, 27], 12),
            (&[1, 4, 7, 10, 13], 6),
            (&[2, 7, 12], 5),
            (&[3], 37),
            (&[0, 2, 4], 2),
        ];
        for estimator in DopplerEstimator::ALL {
            for lateral_step in [40e-6, 1e-3] {
                let geometry = geometry(lateral_step);
                for (starts, window) in cases {
                    let all = window_moments(series.view(), starts, window, estimator, &geometry)
                        .unwrap();
                    assert_eq!(all.len(), starts.len());
                    for (got, &start) in all.iter().zip(starts) {
                        let want = moments(
                            series.slice(s![.., .., start..start + window]),
                            estimator,
                            &geometry,
                        )
                        .unwrap();
                        let what =
                            format!("{estimator:?}, {lateral_step} m, {starts:?} × {window}");
                        assert_eq!((got.frames, got.pairs), (want.frames, want.pairs), "{what}");
                        assert!(
                            got.power
                                .iter()
                                .zip(&want.power)
                                .all(|(a, b)| (a - b).abs() <= 1e-13 * b),
                            "{what}"
                        );
                        assert!(close(&got.r1, &want.r1), "{what}");
                        for (mine, theirs) in
                            [(&got.axial, &want.axial), (&got.lateral, &want.lateral)]
                        {
                            assert_eq!(mine.is_some(), theirs.is_some(), "{what}");
                            if let (Some(m), Some(t)) = (mine, theirs) {
                                assert!(close(&m.plus, &t.plus), "{what}");
                                assert!(close(&m.minus, &t.minus), "{what}");
                                assert!(close(&m.same, &t.same), "{what}");
                            }
                        }
                    }
                }
            }
        }
        // Windows out of order, past the end or of one frame are refused; none give none.
        let geometry = geometry(40e-6);
        let kasai = DopplerEstimator::Kasai;
        assert!(window_moments(series.view(), &[9, 0], 5, kasai, &geometry).is_err());
        assert!(window_moments(series.view(), &[0, 30], 11, kasai, &geometry).is_err());
        assert!(window_moments(series.view(), &[0, 1], 1, kasai, &geometry).is_err());
        assert!(
            window_moments(series.view(), &[], 5, kasai, &geometry)
                .unwrap()
                .is_empty()
        );
    }
}
