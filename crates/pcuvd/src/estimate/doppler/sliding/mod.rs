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

#[cfg(target_arch = "x86_64")]
mod lanes;

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
    let mut moments = Vec::new();
    window_moments_into(series, starts, window, estimator, geometry, &mut moments)?;
    Ok(moments)
}

/// [`window_moments`] into `moments`, whose maps (a previous call's) are written again where
/// they have the series' image size: the dynamics stage takes its windows a chunk at a time, and
/// maps freed and allocated again each chunk were faulted in and zeroed anew each time where
/// the allocator hands freed memory back to the system.
pub fn window_moments_into(
    series: ArrayView3<Complex32>,
    starts: &[usize],
    window: usize,
    estimator: DopplerEstimator,
    geometry: &DopplerGeometry,
    moments: &mut Vec<Moments>,
) -> Result<()> {
    let (nz, nx, nf) = series.dim();
    // Every element of every map is written below (each pixel's window sums), so the old maps'
    // values need no clearing.
    let (mut spare_power, mut spare_products) = spare_maps(std::mem::take(moments), (nz, nx));
    let (Some(&first), Some(&last)) = (starts.first(), starts.last()) else {
        return Ok(());
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
    let n_windows = starts.len();
    let n_lags = lags.axial as usize + lags.lateral as usize;
    // Per window: r1, then [plus, minus, same] of each lag measured. Each map is allocated on its
    // own, small enough for the allocator to reuse from one call to the next.
    let planes = 1 + 3 * n_lags;
    let windows = Windows::new(starts, window, planes);
    let (bin, n_bins) = (windows.bin, windows.n_bins);
    let span = bin * n_bins;
    let mut power: Vec<Array2<f64>> = (0..n_windows)
        .map(|_| spare_power.pop().unwrap_or_else(|| Array2::zeros((nz, nx))))
        .collect();
    let mut products: Vec<Vec<Array2<Complex64>>> = (0..n_windows)
        .map(|_| {
            (0..planes)
                .map(|_| {
                    spare_products
                        .pop()
                        .unwrap_or_else(|| Array2::zeros((nz, nx)))
                })
                .collect()
        })
        .collect();
    // Maps beyond this call's windows are let go before the sums.
    drop((spare_power, spare_products));
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
        || LaneScratch::new(n_bins),
        |scratch, (iz, (mut power_rows, mut product_rows))| {
            // The pixel and its neighbour one step along each lag; the last one pairs with the
            // one before it, roles swapped, as [`spatial_lag_means`] pairs them.
            let pair = |i: usize, n: usize| if i + 1 < n { (i, i + 1) } else { (i - 1, i) };
            let mut ix = 0;
            while ix < nx {
                // Pixels side by side where each has its right-hand neighbour; one at a time at
                // the row's end.
                if ix + LANES < nx {
                    let own: [&[Complex32]; LANES + 1] =
                        std::array::from_fn(|c| frames(iz, ix + c));
                    let axial = lags.axial.then(|| {
                        let (z, order) = if iz + 1 < nz {
                            (iz + 1, AxialPair::OwnThenOther)
                        } else {
                            (iz - 1, AxialPair::OtherThenOwn)
                        };
                        let other: [&[Complex32]; LANES] =
                            std::array::from_fn(|c| frames(z, ix + c));
                        (other, order)
                    });
                    let pixels = LanePixels {
                        own,
                        axial,
                        lateral: lags.lateral,
                    };
                    let mut out = WindowRows {
                        ix,
                        power: &mut power_rows,
                        products: &mut product_rows,
                    };
                    lane_window_sums(&pixels, &windows, &mut out, scratch);
                    ix += LANES;
                } else {
                    let axial = lags.axial.then(|| {
                        let (a, b) = pair(iz, nz);
                        (frames(a, ix), frames(b, ix))
                    });
                    let lateral = lags.lateral.then(|| {
                        let (a, b) = pair(ix, nx);
                        (frames(iz, a), frames(iz, b))
                    });
                    let mut out = WindowRows {
                        ix,
                        power: &mut power_rows,
                        products: &mut product_rows,
                    };
                    let lags = [axial, lateral];
                    pixel_window_sums(frames(iz, ix), lags, &windows, &mut out, scratch);
                    ix += 1;
                }
            }
        },
    );
    moments.extend(power.into_iter().zip(products).map(|(power, planes)| {
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
    }));
    Ok(())
}

/// The power maps and complex product maps of `moments` that have `dim`, to be written again.
fn spare_maps(
    moments: Vec<Moments>,
    dim: (usize, usize),
) -> (Vec<Array2<f64>>, Vec<Array2<Complex64>>) {
    let (mut power, mut products) = (Vec::new(), Vec::new());
    for m in moments {
        power.push(m.power);
        products.push(m.r1);
        for lag in [m.axial, m.lateral].into_iter().flatten() {
            products.extend([lag.plus, lag.minus, lag.same]);
        }
    }
    power.retain(|map| map.dim() == dim);
    products.retain(|map| map.dim() == dim);
    (power, products)
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

/// Where a row's windows lie in the bins of its pixels' frames.
struct Windows<'a> {
    /// Each window's first frame, ascending.
    starts: &'a [usize],
    /// The first window's first frame: the first bin's.
    first: usize,
    /// Frames per bin.
    bin: usize,
    /// Frames per window.
    window: usize,
    /// Bins per pixel.
    n_bins: usize,
    /// Product maps per window: lag 1, then [plus, minus, same] per spatial lag measured.
    planes: usize,
}

impl<'a> Windows<'a> {
    /// Windows of `window` frames from each of `starts` (not empty, ascending), with `planes`
    /// product maps each: in bins of g frames from the first start, g the largest that divides
    /// the window and every start's distance from the first, so that every window begins and
    /// ends on a bin boundary.
    fn new(starts: &'a [usize], window: usize, planes: usize) -> Windows<'a> {
        let first = starts[0];
        let bin = starts
            .iter()
            .fold(window, |g, &s| num_integer::gcd(g, s - first));
        let last = starts[starts.len() - 1];
        Windows {
            starts,
            first,
            bin,
            window,
            n_bins: (last + window - first) / bin,
            planes,
        }
    }

    /// Each window's first and last bin + 1.
    fn bins(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.starts.iter().map(|&start| {
            let from = start - self.first;
            (from / self.bin, (from + self.window) / self.bin)
        })
    }
}

/// A row's slice of every window's maps, and the pixel written next.
struct WindowRows<'r, 'm> {
    /// The pixel's place in the row.
    ix: usize,
    /// Per window, the power map's row.
    power: &'r mut [ndarray::ArrayViewMut1<'m, f64>],
    /// Per window, [`Windows::planes`] product maps' rows.
    products: &'r mut [ndarray::ArrayViewMut1<'m, Complex64>],
}

/// Writes one pixel's window sums into its place of every window's maps: each window's bins,
/// with the pairs straddling their boundaries, divided by the window's frames (power, the
/// products within frames) or pairs (the products across a frame).
fn window_sums(bins: &[Sums], straddling: &[Sums], windows: &Windows, out: &mut WindowRows) {
    let ix = out.ix;
    let (frames, pairs) = (windows.window as f64, (windows.window - 1) as f64);
    for (((j0, j1), power), products) in windows
        .bins()
        .zip(out.power.iter_mut())
        .zip(out.products.chunks_mut(windows.planes))
    {
        let mut sums = bins[j0];
        for j in j0 + 1..j1 {
            sums += &bins[j];
            sums += &straddling[j];
        }
        power[ix] = sums.power / frames;
        products[0][ix] = sums.r1 / pairs;
        for (lag, planes) in sums.lags.iter().zip(products[1..].chunks_mut(3)) {
            planes[0][ix] = lag[0] / pairs;
            planes[1][ix] = lag[1] / pairs;
            planes[2][ix] = lag[2] / frames;
        }
    }
}

/// Pixels of a row summed side by side: the f64 lanes of an AVX-512 register, or of two AVX2
/// registers in turn.
const LANES: usize = 8;

/// Which of a pixel's rows comes first in its axial pair: its own (the row below follows), or the
/// row above (the image's last row, paired with the one before it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum AxialPair {
    /// (own row, next row).
    OwnThenOther,
    /// (row before, own row).
    OtherThenOwn,
}

/// [`LANES`] pixels of a row side by side, with the frames their sums read.
struct LanePixels<'a> {
    /// The pixels' frames, and the right-hand neighbour's of the last.
    own: [&'a [Complex32]; LANES + 1],
    /// The same pixels' frames in the other row of their axial pair, and the pair's order.
    axial: Option<([&'a [Complex32]; LANES], AxialPair)>,
    /// Whether the lateral pair (pixel, right-hand neighbour) is measured.
    lateral: bool,
}

/// The working memory of [`lane_window_sums`], kept from one call to the next.
struct LaneScratch {
    /// One pixel's bins, where pixels are summed one at a time.
    bins: Vec<Sums>,
    /// One pixel's straddling pairs, alike.
    straddling: Vec<Sums>,
    /// The bins and straddling pairs in registers' lanes, where the CPU has the registers.
    wide: Wide,
}

/// The vector registers pixels are summed side by side in, and their bins.
enum Wide {
    /// AVX-512: the eight pixels at once.
    #[cfg(target_arch = "x86_64")]
    Avx512(lanes::Bins<lanes::Avx512>),
    /// AVX2: four pixels at a time.
    #[cfg(target_arch = "x86_64")]
    Avx2(lanes::Bins<lanes::Avx2>),
    /// None: a pixel at a time.
    Scalar,
}

/// The ways [`lane_window_sums`] can sum, widest first.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Path {
    #[cfg(target_arch = "x86_64")]
    Avx512,
    #[cfg(target_arch = "x86_64")]
    Avx2,
    Scalar,
}

impl Path {
    /// The paths this CPU runs, widest first; the scalar one is always last.
    // Elsewhere than on x86_64 only the scalar path is pushed.
    #[cfg_attr(not(target_arch = "x86_64"), allow(clippy::vec_init_then_push))]
    fn supported() -> Vec<Path> {
        let mut paths = Vec::new();
        #[cfg(target_arch = "x86_64")]
        {
            if crate::core::simd::avx512() {
                paths.push(Path::Avx512);
            }
            if crate::core::simd::avx2() {
                paths.push(Path::Avx2);
            }
        }
        paths.push(Path::Scalar);
        paths
    }
}

impl LaneScratch {
    /// Room for `n_bins` bins: one pixel's, and the lanes' of the widest registers the CPU has.
    fn new(n_bins: usize) -> LaneScratch {
        LaneScratch::on(Path::supported()[0], n_bins)
    }

    /// Room for `n_bins` bins, to sum on `path` (one the CPU runs: [`Path::supported`]).
    fn on(path: Path, n_bins: usize) -> LaneScratch {
        LaneScratch {
            bins: vec![Sums::default(); n_bins],
            straddling: vec![Sums::default(); n_bins],
            wide: match path {
                #[cfg(target_arch = "x86_64")]
                Path::Avx512 => Wide::Avx512(lanes::Bins::new(n_bins)),
                #[cfg(target_arch = "x86_64")]
                Path::Avx2 => Wide::Avx2(lanes::Bins::new(n_bins)),
                Path::Scalar => Wide::Scalar,
            },
        }
    }
}

/// [`bin_sums`] and [`window_sums`] of [`LANES`] pixels side by side, written into their places
/// `out.ix ..` of every window's maps. Each lane's sums are its pixel's alone, to the bit: the
/// same products, widened and added in the same order. Summed a pixel at a time, each frame's
/// seven products waited on the widening and sums of the one before.
fn lane_window_sums(
    pixels: &LanePixels,
    windows: &Windows,
    out: &mut WindowRows,
    scratch: &mut LaneScratch,
) {
    let frames = windows.n_bins * windows.bin;
    assert!(pixels.own.iter().all(|s| s.len() >= frames));
    assert!(
        pixels
            .axial
            .is_none_or(|(other, _)| other.iter().all(|s| s.len() >= frames))
    );
    assert!(out.power.iter().all(|row| row.len() >= out.ix + LANES));
    assert!(out.products.iter().all(|row| row.len() >= out.ix + LANES));
    // SAFETY (both): the registers' bins are made only on a path the CPU runs; every series
    // holds the frames the bins read, and every row the pixels written (the checks above).
    match &mut scratch.wide {
        #[cfg(target_arch = "x86_64")]
        Wide::Avx512(bins) => unsafe { lanes::sums_avx512(pixels, windows, out, bins) },
        #[cfg(target_arch = "x86_64")]
        Wide::Avx2(bins) => unsafe { lanes::sums_avx2(pixels, windows, out, bins) },
        Wide::Scalar => one_at_a_time(pixels, windows, out, scratch),
    }
}

/// [`lane_window_sums`] a pixel at a time, where the CPU has neither AVX-512 nor AVX2.
fn one_at_a_time(
    pixels: &LanePixels,
    windows: &Windows,
    out: &mut WindowRows,
    scratch: &mut LaneScratch,
) {
    let first = out.ix;
    for l in 0..LANES {
        let own = &pixels.own;
        let lags = [
            pixels.axial.map(|(other, order)| match order {
                AxialPair::OwnThenOther => (own[l], other[l]),
                AxialPair::OtherThenOwn => (other[l], own[l]),
            }),
            pixels.lateral.then(|| (own[l], own[l + 1])),
        ];
        out.ix = first + l;
        pixel_window_sums(own[l], lags, windows, out, scratch);
    }
    out.ix = first;
}

/// [`bin_sums`] and [`window_sums`] of one pixel, written into its place `out.ix` of every
/// window's maps; `lags` as [`bin_sums`] takes them.
fn pixel_window_sums(
    pixel: &[Complex32],
    lags: [Option<(&[Complex32], &[Complex32])>; 2],
    windows: &Windows,
    out: &mut WindowRows,
    scratch: &mut LaneScratch,
) {
    let (bins, straddling) = (&mut scratch.bins, &mut scratch.straddling);
    bin_sums(pixel, lags, windows.bin, bins, straddling);
    window_sums(bins, straddling, windows, out);
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

    /// Pixels summed side by side, on every path the CPU runs (AVX-512, AVX2, scalar), write
    /// the windows' moments each writes summed alone, to the bit and in their own places: with
    /// and without each spatial lag, both orders of the axial pair, bins of one frame and of
    /// several, frames that fill the last group of eight (and of four) and frames that do not,
    /// windows from a later first frame.
    #[test]
    fn pixels_side_by_side_sum_as_each_alone() {
        let span = 61;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut draw = || -> f32 { StandardNormal.sample(&mut rng) };
        let series: Vec<Vec<Complex32>> = (0..2 * LANES + 1)
            .map(|_| (0..span).map(|_| Complex32::new(draw(), draw())).collect())
            .collect();
        let cases: [(&[usize], usize); 6] = [
            (&[0, 9, 18, 27], 27),
            (&[0, 1, 2, 3], 2),
            (&[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13], 16),
            (&[2, 7, 12, 47], 10),
            (&[3], 58),
            (&[0, 4], 8),
        ];
        let ix = 2;
        for (starts, window) in cases {
            let first = starts[0];
            let frames = |c: usize| &series[c][first..];
            let own: [&[Complex32]; LANES + 1] = std::array::from_fn(frames);
            let other: [&[Complex32]; LANES] = std::array::from_fn(|c| frames(LANES + 1 + c));
            for (axial, lateral) in [
                (None, false),
                (Some((other, AxialPair::OwnThenOther)), false),
                (Some((other, AxialPair::OtherThenOwn)), true),
                (Some((other, AxialPair::OwnThenOther)), true),
            ] {
                let planes = 1 + 3 * (axial.is_some() as usize + lateral as usize);
                let windows = Windows::new(starts, window, planes);
                let n_bins = windows.n_bins;
                let pixels = LanePixels {
                    own,
                    axial,
                    lateral,
                };
                // Each way writes into maps of NaN two pixels wider than the lanes.
                let written = |side_by_side: Option<Path>| {
                    let width = ix + LANES + 2;
                    let mut power = vec![ndarray::Array1::from_elem(width, f64::NAN); starts.len()];
                    let nan = Complex64::new(f64::NAN, f64::NAN);
                    let mut products =
                        vec![ndarray::Array1::from_elem(width, nan); starts.len() * planes];
                    let mut power_rows: Vec<_> = power.iter_mut().map(|r| r.view_mut()).collect();
                    let mut product_rows: Vec<_> =
                        products.iter_mut().map(|r| r.view_mut()).collect();
                    let mut out = WindowRows {
                        ix,
                        power: &mut power_rows,
                        products: &mut product_rows,
                    };
                    match side_by_side {
                        Some(path) => {
                            let mut scratch = LaneScratch::on(path, n_bins);
                            lane_window_sums(&pixels, &windows, &mut out, &mut scratch);
                        }
                        None => {
                            let mut scratch = LaneScratch::new(n_bins);
                            one_at_a_time(&pixels, &windows, &mut out, &mut scratch);
                        }
                    }
                    let mut bits: Vec<u64> = power.iter().flatten().map(|v| v.to_bits()).collect();
                    bits.extend(
                        products
                            .iter()
                            .flatten()
                            .flat_map(|c| [c.re.to_bits(), c.im.to_bits()]),
                    );
                    bits
                };
                let alone = written(None);
                let what = format!(
                    "{starts:?} × {window}, axial {:?}, lateral {lateral}",
                    axial.map(|a| a.1)
                );
                for path in Path::supported() {
                    assert_eq!(written(Some(path)), alone, "{path:?}: {what}");
                }
                // Each pixel's place and only those are written.
                let power_row = &alone[..ix + LANES + 2];
                assert!(
                    power_row[ix..ix + LANES]
                        .iter()
                        .all(|&b| f64::from_bits(b).is_finite())
                );
                assert!(
                    power_row[..ix].iter().all(|&b| f64::from_bits(b).is_nan()),
                    "{what}"
                );
                assert!(
                    power_row[ix + LANES..]
                        .iter()
                        .all(|&b| f64::from_bits(b).is_nan())
                );
            }
        }
    }

    /// Every window's moments are those of [`moments`] on the window's own frames, to the
    /// rounding of the f64 sums: windows whose starts share a bin of several frames, windows one
    /// frame apart (bins of one frame: every pair straddles), a lone window, both estimators, and
    /// a grid too coarse for the lateral lag.
    #[test]
    fn each_window_has_the_moments_of_its_own_frames() {
        // Rows wide enough for pixels side by side and for the row's end one at a time.
        let (nz, nx, nf) = (5, 19, 40);
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
        // One set of moments written again case after case (other windows, planes, lags), and
        // once for a smaller image: each the same as fresh, in the old maps' memory where they
        // have the image's size.
        let mut reused = Vec::new();
        for estimator in DopplerEstimator::ALL {
            for lateral_step in [40e-6, 1e-3] {
                let geometry = geometry(lateral_step);
                for (starts, window) in cases {
                    let all = window_moments(series.view(), starts, window, estimator, &geometry)
                        .unwrap();
                    assert_eq!(all.len(), starts.len());
                    let old: Vec<_> = reused.iter().map(|m: &Moments| m.power.as_ptr()).collect();
                    window_moments_into(
                        series.view(),
                        starts,
                        window,
                        estimator,
                        &geometry,
                        &mut reused,
                    )
                    .unwrap();
                    assert_eq!(reused, all);
                    if !old.is_empty() {
                        assert!(reused.iter().any(|m| old.contains(&m.power.as_ptr())));
                    }
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
        let geometry = geometry(40e-6);
        let kasai = DopplerEstimator::Kasai;
        let smaller = series.slice(s![..4, .., ..]);
        window_moments_into(smaller, &[0, 5], 8, kasai, &geometry, &mut reused).unwrap();
        assert_eq!(
            reused,
            window_moments(smaller, &[0, 5], 8, kasai, &geometry).unwrap()
        );
        // Windows out of order, past the end or of one frame are refused; none give none.
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
