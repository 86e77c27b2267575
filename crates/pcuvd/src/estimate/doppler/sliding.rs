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
    let n_windows = starts.len();
    let n_lags = lags.axial as usize + lags.lateral as usize;
    // Per window: r1, then [plus, minus, same] of each lag measured. Each map is allocated on its
    // own, small enough for the allocator to reuse from one call to the next.
    let planes = 1 + 3 * n_lags;
    let windows = Windows::new(starts, window, planes);
    let (bin, n_bins) = (windows.bin, windows.n_bins);
    let span = bin * n_bins;
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

/// Pixels of a row summed side by side: the f64 lanes of an AVX-512 register.
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
    /// The bins and straddling pairs in registers' lanes.
    #[cfg(target_arch = "x86_64")]
    wide: Option<lanes_avx512::Bins>,
}

impl LaneScratch {
    /// Room for `n_bins` bins: one pixel's, and eight lanes' where the CPU has AVX-512.
    fn new(n_bins: usize) -> LaneScratch {
        LaneScratch {
            bins: vec![Sums::default(); n_bins],
            straddling: vec![Sums::default(); n_bins],
            #[cfg(target_arch = "x86_64")]
            wide: is_x86_feature_detected!("avx512f").then(|| lanes_avx512::Bins::new(n_bins)),
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
    #[cfg(target_arch = "x86_64")]
    {
        if let Some(wide) = scratch.wide.as_mut() {
            // SAFETY: `wide` is made only where AVX-512F was detected; every series holds the
            // frames the bins read, and every row the pixels written (the checks above).
            unsafe {
                lanes_avx512::bin_sums(pixels, windows.bin, wide);
                lanes_avx512::window_sums(wide, windows, out);
            }
            return;
        }
    }
    one_at_a_time(pixels, windows, out, scratch);
}

/// [`lane_window_sums`] a pixel at a time, where the CPU has no AVX-512.
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

/// [`lane_window_sums`] in AVX-512 registers: eight frames of eight pixels loaded at a time and
/// turned in registers so that each vector holds one frame of every pixel, real and imaginary
/// parts apart; each sum of [`Sums`] one register of eight f64 lanes, from the
/// frames to the windows' maps.
#[cfg(target_arch = "x86_64")]
mod lanes_avx512 {
    use super::{AxialPair, Complex32, Complex64, LANES, LanePixels, WindowRows, Windows};
    use std::arch::x86_64::*;

    /// One frame of the eight pixels: real parts, imaginary parts.
    #[derive(Clone, Copy)]
    struct Lanes {
        re: __m256,
        im: __m256,
    }

    /// One frame of the pixels, of their right-hand neighbours, and of the other row of their
    /// axial pair.
    #[derive(Clone, Copy)]
    struct Frame {
        own: Lanes,
        right: Lanes,
        other: Lanes,
    }

    impl Frame {
        /// The (first, second) series of the axial pair.
        #[inline(always)]
        fn axial(&self, order: AxialPair) -> (Lanes, Lanes) {
            match order {
                AxialPair::OwnThenOther => (self.own, self.other),
                AxialPair::OtherThenOwn => (self.other, self.own),
            }
        }
    }

    /// [`Sums`](super::Sums) of eight pixels, lane by lane.
    #[derive(Clone, Copy)]
    struct LaneSums {
        power: __m512d,
        /// Re, Im.
        r1: [__m512d; 2],
        /// Axial then lateral: [plus, minus, same], each Re, Im.
        lags: [[[__m512d; 2]; 3]; 2],
    }

    impl LaneSums {
        #[target_feature(enable = "avx512f")]
        #[inline]
        fn zero() -> LaneSums {
            let z = _mm512_setzero_pd();
            LaneSums {
                power: z,
                r1: [z; 2],
                lags: [[[z; 2]; 3]; 2],
            }
        }

        /// Adds `other`'s sums lane by lane, as [`super::Sums`] adds.
        #[target_feature(enable = "avx512f")]
        #[inline]
        fn add(&mut self, other: &LaneSums) {
            // Indexed loops of constant bounds, which unroll into registers.
            self.power = _mm512_add_pd(self.power, other.power);
            for c in 0..2 {
                self.r1[c] = _mm512_add_pd(self.r1[c], other.r1[c]);
            }
            for k in 0..2 {
                for m in 0..3 {
                    for c in 0..2 {
                        self.lags[k][m][c] = _mm512_add_pd(self.lags[k][m][c], other.lags[k][m][c]);
                    }
                }
            }
        }
    }

    /// Eight pixels' bins and straddling pairs ([`super::bin_sums`]), lane by lane.
    pub(super) struct Bins {
        bins: Vec<LaneSums>,
        straddling: Vec<LaneSums>,
    }

    impl Bins {
        /// Room for `n_bins` bins.
        pub(super) fn new(n_bins: usize) -> Bins {
            // SAFETY: every bit pattern, zeros among them, is a vector of eight f64.
            let zero: LaneSums = unsafe { std::mem::zeroed() };
            Bins {
                bins: vec![zero; n_bins],
                straddling: vec![zero; n_bins],
            }
        }
    }

    /// Adds conj(x)·y to `sum` (Re, Im) lane by lane, each product in f32 and widened to f64 as
    /// [`super::conj_product`] forms it.
    #[target_feature(enable = "avx512f")]
    #[inline]
    fn add_conj_product(sum: &mut [__m512d; 2], x: Lanes, y: Lanes) {
        let wide = |v: __m256| _mm512_cvtps_pd(v);
        let re = _mm512_add_pd(
            wide(_mm256_mul_ps(x.re, y.re)),
            wide(_mm256_mul_ps(x.im, y.im)),
        );
        let im = _mm512_sub_pd(
            wide(_mm256_mul_ps(x.re, y.im)),
            wide(_mm256_mul_ps(x.im, y.re)),
        );
        sum[0] = _mm512_add_pd(sum[0], re);
        sum[1] = _mm512_add_pd(sum[1], im);
    }

    /// Frames `t .. t + count` (count ≤ 8) of eight series, turned: element k holds frame t + k
    /// of every series.
    ///
    /// # Safety
    /// Frames t .. t + count must lie within every series.
    #[target_feature(enable = "avx512f")]
    #[inline]
    unsafe fn turned(series: [&[Complex32]; 8], t: usize, count: usize) -> [Lanes; 8] {
        let mask: __mmask8 = if count >= 8 { 0xff } else { (1u8 << count) - 1 };
        // Each complex sample is one 64-bit element: its real part in the low half.
        // SAFETY (of the loads): the mask reads only frames t .. t + count, within each series.
        let r: [__m512i; 8] = std::array::from_fn(|p| unsafe {
            _mm512_maskz_loadu_epi64(mask, series[p].as_ptr().add(t).cast::<i64>())
        });
        // The 8 × 8 transpose of 64-bit elements: pairs of rows interleaved, then pairs of
        // pairs, then halves.
        let lo = |a, b| _mm512_unpacklo_epi64(a, b);
        let hi = |a, b| _mm512_unpackhi_epi64(a, b);
        let (t0, t1, t2, t3) = (
            lo(r[0], r[1]),
            hi(r[0], r[1]),
            lo(r[2], r[3]),
            hi(r[2], r[3]),
        );
        let (t4, t5, t6, t7) = (
            lo(r[4], r[5]),
            hi(r[4], r[5]),
            lo(r[6], r[7]),
            hi(r[6], r[7]),
        );
        let pick = |a, idx: [i64; 8], b| {
            let idx = _mm512_setr_epi64(
                idx[0], idx[1], idx[2], idx[3], idx[4], idx[5], idx[6], idx[7],
            );
            _mm512_permutex2var_epi64(a, idx, b)
        };
        const EVEN: [i64; 8] = [0, 1, 8, 9, 4, 5, 12, 13];
        const ODD: [i64; 8] = [2, 3, 10, 11, 6, 7, 14, 15];
        // s0: frames 0 and 4 of rows 0–3; s1: 2 and 6; s2: 1 and 5; s3: 3 and 7; s4–s7 rows 4–7.
        let (s0, s1, s2, s3) = (
            pick(t0, EVEN, t2),
            pick(t0, ODD, t2),
            pick(t1, EVEN, t3),
            pick(t1, ODD, t3),
        );
        let (s4, s5, s6, s7) = (
            pick(t4, EVEN, t6),
            pick(t4, ODD, t6),
            pick(t5, EVEN, t7),
            pick(t5, ODD, t7),
        );
        const LOW: [i64; 8] = [0, 1, 2, 3, 8, 9, 10, 11];
        const HIGH: [i64; 8] = [4, 5, 6, 7, 12, 13, 14, 15];
        let frames = [
            pick(s0, LOW, s4),
            pick(s2, LOW, s6),
            pick(s1, LOW, s5),
            pick(s3, LOW, s7),
            pick(s0, HIGH, s4),
            pick(s2, HIGH, s6),
            pick(s1, HIGH, s5),
            pick(s3, HIGH, s7),
        ];
        let mut out = [Lanes {
            re: _mm256_setzero_ps(),
            im: _mm256_setzero_ps(),
        }; 8];
        for (lanes, f) in out.iter_mut().zip(frames) {
            lanes.re = _mm256_castsi256_ps(_mm512_cvtepi64_epi32(f));
            lanes.im = _mm256_castsi256_ps(_mm512_cvtepi64_epi32(_mm512_srli_epi64::<32>(f)));
        }
        out
    }

    /// How many groups of 8 frames ahead each series is fetched.
    const PREFETCH_GROUPS: usize = 2;

    /// The bins and straddling pairs of `pixels`' frames in bins of `bin` frames, as many bins as
    /// `out` holds. See [`super::lane_window_sums`], whose checks it relies on.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn bin_sums(pixels: &LanePixels, bin: usize, out: &mut Bins) {
        let (own, axial, lateral) = (&pixels.own, pixels.axial, pixels.lateral);
        let n_bins = out.bins.len();
        let frames = n_bins * bin;
        let pixels: [&[Complex32]; 8] = std::array::from_fn(|l| own[l]);
        let right: [&[Complex32]; 8] = std::array::from_fn(|l| own[l + 1]);
        let within = |sums: &mut LaneSums, now: &Frame| {
            let s = now.own;
            let power = _mm512_add_pd(
                _mm512_cvtps_pd(_mm256_mul_ps(s.re, s.re)),
                _mm512_cvtps_pd(_mm256_mul_ps(s.im, s.im)),
            );
            sums.power = _mm512_add_pd(sums.power, power);
            if let Some((_, order)) = axial {
                let (a, b) = now.axial(order);
                add_conj_product(&mut sums.lags[0][2], a, b);
            }
            if lateral {
                add_conj_product(&mut sums.lags[1][2], now.own, now.right);
            }
        };
        let across = |sums: &mut LaneSums, before: &Frame, now: &Frame| {
            add_conj_product(&mut sums.r1, before.own, now.own);
            if let Some((_, order)) = axial {
                let ((a0, b0), (a1, b1)) = (before.axial(order), now.axial(order));
                add_conj_product(&mut sums.lags[0][0], a0, b1);
                add_conj_product(&mut sums.lags[0][1], a1, b0);
            }
            if lateral {
                add_conj_product(&mut sums.lags[1][0], before.own, now.right);
                add_conj_product(&mut sums.lags[1][1], now.own, before.right);
            }
        };
        let nothing = [Lanes {
            re: _mm256_setzero_ps(),
            im: _mm256_setzero_ps(),
        }; 8];
        let mut sums = LaneSums::zero();
        let mut before = Frame {
            own: nothing[0],
            right: nothing[0],
            other: nothing[0],
        };
        let mut t0 = 0;
        while t0 < frames {
            let count = (frames - t0).min(8);
            // Every series is its own stream through memory, more than the hardware follows:
            // each is fetched a few groups ahead.
            let ahead = t0 + 8 * PREFETCH_GROUPS;
            if ahead < frames {
                let fetch = |s: &[Complex32]| {
                    _mm_prefetch::<_MM_HINT_T0>(s[ahead..].as_ptr().cast::<i8>());
                };
                own.iter().for_each(|s| fetch(s));
                if let Some((other, _)) = axial {
                    other.iter().for_each(|s| fetch(s));
                }
            }
            // SAFETY: frames t0 .. t0 + count lie within every series (the caller's checks).
            let (own_at, right_at, other_at) = unsafe {
                (
                    turned(pixels, t0, count),
                    if lateral {
                        turned(right, t0, count)
                    } else {
                        nothing
                    },
                    match axial {
                        Some((other, _)) => turned(other, t0, count),
                        None => nothing,
                    },
                )
            };
            for k in 0..count {
                let t = t0 + k;
                let now = Frame {
                    own: own_at[k],
                    right: right_at[k],
                    other: other_at[k],
                };
                if t % bin == 0 {
                    // A bin's first frame: the bin before is whole, and the pair across the
                    // boundary is the new bin's straddling pair (none before the first).
                    let j = t / bin;
                    if j > 0 {
                        out.bins[j - 1] = sums;
                        sums = LaneSums::zero();
                    }
                    let mut straddle = LaneSums::zero();
                    if j > 0 {
                        across(&mut straddle, &before, &now);
                    }
                    out.straddling[j] = straddle;
                    within(&mut sums, &now);
                } else {
                    within(&mut sums, &now);
                    across(&mut sums, &before, &now);
                }
                before = now;
            }
            t0 += count;
        }
        if n_bins > 0 {
            out.bins[n_bins - 1] = sums;
        }
    }

    /// Writes the eight pixels' window sums from `bins` into their places `out.ix ..` of every
    /// window's maps, as [`super::window_sums`] writes each. See [`super::lane_window_sums`],
    /// whose checks it relies on.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn window_sums(bins: &Bins, windows: &Windows, out: &mut WindowRows) {
        let ix = out.ix;
        let frames = _mm512_set1_pd(windows.window as f64);
        let pairs = _mm512_set1_pd((windows.window - 1) as f64);
        // Complex values are (Re, Im) after each other: the lanes' real and imaginary parts
        // interleaved, the first four pixels' then the last four's.
        let first_four = _mm512_setr_epi64(0, 1, 8, 9, 2, 3, 10, 11);
        let last_four = _mm512_setr_epi64(4, 5, 12, 13, 6, 7, 14, 15);
        let store_complex = |row: &mut ndarray::ArrayViewMut1<Complex64>, re, im| {
            let row = row
                .as_slice_mut()
                .expect("a row of a map in standard layout");
            let at = row[ix..ix + LANES].as_mut_ptr().cast::<f64>();
            let (even, odd) = (_mm512_unpacklo_pd(re, im), _mm512_unpackhi_pd(re, im));
            // SAFETY: the 16 f64 written are the 8 complex values of row[ix .. ix + 8].
            unsafe {
                _mm512_storeu_pd(at, _mm512_permutex2var_pd(even, first_four, odd));
                _mm512_storeu_pd(at.add(8), _mm512_permutex2var_pd(even, last_four, odd));
            }
        };
        for (((j0, j1), power), products) in windows
            .bins()
            .zip(out.power.iter_mut())
            .zip(out.products.chunks_mut(windows.planes))
        {
            let mut sums = bins.bins[j0];
            for j in j0 + 1..j1 {
                sums.add(&bins.bins[j]);
                sums.add(&bins.straddling[j]);
            }
            let row = power
                .as_slice_mut()
                .expect("a row of a map in standard layout");
            // SAFETY: the 8 f64 written are row[ix .. ix + 8].
            unsafe {
                _mm512_storeu_pd(
                    row[ix..ix + LANES].as_mut_ptr(),
                    _mm512_div_pd(sums.power, frames),
                )
            };
            let r1 = sums.r1;
            store_complex(
                &mut products[0],
                _mm512_div_pd(r1[0], pairs),
                _mm512_div_pd(r1[1], pairs),
            );
            for (lag, planes) in sums.lags.iter().zip(products[1..].chunks_mut(3)) {
                for (m, (plane, by)) in planes.iter_mut().zip([pairs, pairs, frames]).enumerate() {
                    store_complex(
                        plane,
                        _mm512_div_pd(lag[m][0], by),
                        _mm512_div_pd(lag[m][1], by),
                    );
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

    /// Pixels summed side by side write the windows' moments each writes summed alone, to the
    /// bit and in their own places: with and without each spatial lag, both orders of the axial
    /// pair, bins of one frame and of several, frames that fill the last group of eight and
    /// frames that do not, windows from a later first frame.
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
                let written = |side_by_side: bool| {
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
                    let mut scratch = LaneScratch::new(n_bins);
                    if side_by_side {
                        lane_window_sums(&pixels, &windows, &mut out, &mut scratch);
                    } else {
                        one_at_a_time(&pixels, &windows, &mut out, &mut scratch);
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
                let (lanes, alone) = (written(true), written(false));
                let what = format!(
                    "{starts:?} × {window}, axial {:?}, lateral {lateral}",
                    axial.map(|a| a.1)
                );
                assert_eq!(lanes, alone, "{what}");
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
