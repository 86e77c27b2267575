//! [`lane_window_sums`](super::lane_window_sums) in vector registers: a group of frames of the
//! pixels loaded at a time and turned in registers so that each vector holds one frame of every
//! pixel, real and imaginary parts apart; each sum of [`Sums`](super::Sums) one register of f64
//! lanes, from the frames to the windows' maps. AVX-512 sums the eight pixels at once, AVX2 four
//! at a time (the f64 lanes of its registers).
//!
//! The register operations are the methods of [`Registers`], inlined into the `target_feature`
//! entry points [`sums_avx512`] and [`sums_avx2`], which run only where the CPU has the set:
//! that is what makes each `unsafe` intrinsic call in them sound.

use super::{AxialPair, Complex32, Complex64, LANES, LanePixels, WindowRows, Windows};
use std::arch::x86_64::*;

/// One vector instruction set's registers for pixels side by side, one pixel per f64 lane; each
/// lane's arithmetic is the one IEEE operation the scalar sums do (no fused multiply-adds).
pub(super) trait Registers: Copy {
    /// Pixels side by side, and frames turned at a time.
    const WIDTH: usize;
    /// One frame of the pixels, f32: real parts, imaginary parts.
    type Frame: Copy;
    /// An f64 per pixel.
    type Wide: Copy;
    /// `WIDTH` frames of the pixels, turned.
    type Group: AsRef<[Self::Frame]>;
    /// Every lane zero.
    fn nothing() -> Self::Frame;
    /// `WIDTH` frames of zeros.
    fn none() -> Self::Group;
    /// Every lane `v`.
    fn splat(v: f64) -> Self::Wide;
    /// a + b.
    fn add(a: Self::Wide, b: Self::Wide) -> Self::Wide;
    /// a / b.
    fn div(a: Self::Wide, b: Self::Wide) -> Self::Wide;
    /// re² + im² of each lane, each square in f32, widened and added in f64: the real part of
    /// conj(s)·s, whose imaginary part the compiler drops.
    #[inline(always)]
    fn power(s: Self::Frame) -> Self::Wide {
        Self::conj_product(s, s)[0]
    }
    /// conj(x)·y lane by lane (Re, Im), each product in f32 and widened to f64 as
    /// [`super::conj_product`] forms it.
    fn conj_product(x: Self::Frame, y: Self::Frame) -> [Self::Wide; 2];
    /// Frames `t .. t + count` (count ≤ `WIDTH`) of `WIDTH` series, turned: element k holds
    /// frame t + k of every series (zeros beyond `count`).
    ///
    /// # Safety
    /// `series` holds `WIDTH` series, and frames t .. t + count lie within every one.
    unsafe fn turned(series: &[&[Complex32]], t: usize, count: usize) -> Self::Group;
    /// Writes the lanes to `to[.. WIDTH]`.
    fn store(to: &mut [f64], v: Self::Wide);
    /// Writes lane l's (re, im) to `to[l]`, l < `WIDTH`.
    fn store_complex(to: &mut [Complex64], re: Self::Wide, im: Self::Wide);
}

/// [`Sums`](super::Sums) of the pixels, lane by lane.
struct LaneSums<R: Registers> {
    power: R::Wide,
    /// Re, Im.
    r1: [R::Wide; 2],
    /// Axial then lateral: [plus, minus, same], each Re, Im.
    lags: [[[R::Wide; 2]; 3]; 2],
}

impl<R: Registers> Clone for LaneSums<R> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<R: Registers> Copy for LaneSums<R> {}

impl<R: Registers> LaneSums<R> {
    #[inline(always)]
    fn zero() -> LaneSums<R> {
        let z = R::splat(0.0);
        LaneSums {
            power: z,
            r1: [z; 2],
            lags: [[[z; 2]; 3]; 2],
        }
    }

    /// Adds `other`'s sums lane by lane, as [`super::Sums`] adds.
    #[inline(always)]
    fn add(&mut self, other: &LaneSums<R>) {
        // Indexed loops of constant bounds, which unroll into registers.
        self.power = R::add(self.power, other.power);
        for c in 0..2 {
            self.r1[c] = R::add(self.r1[c], other.r1[c]);
        }
        for k in 0..2 {
            for m in 0..3 {
                for c in 0..2 {
                    self.lags[k][m][c] = R::add(self.lags[k][m][c], other.lags[k][m][c]);
                }
            }
        }
    }

    /// Adds a frame's sums within it: the power and, of each spatial lag measured (`axial`
    /// with its pair's order, `lateral`), the product of the pair's two series.
    #[inline(always)]
    fn within(&mut self, now: &Frame<R::Frame>, axial: Option<AxialPair>, lateral: bool) {
        self.power = R::add(self.power, R::power(now.own));
        if let Some(order) = axial {
            let (a, b) = now.axial(order);
            Self::add_conj_product(&mut self.lags[0][2], a, b);
        }
        if lateral {
            Self::add_conj_product(&mut self.lags[1][2], now.own, now.right);
        }
    }

    /// Adds the products of the frame pair (`before`, `now`): lag 1 and, of each spatial lag
    /// measured, its products at temporal lags +1 and −1.
    #[inline(always)]
    fn across(
        &mut self,
        before: &Frame<R::Frame>,
        now: &Frame<R::Frame>,
        axial: Option<AxialPair>,
        lateral: bool,
    ) {
        Self::add_conj_product(&mut self.r1, before.own, now.own);
        if let Some(order) = axial {
            let ((a0, b0), (a1, b1)) = (before.axial(order), now.axial(order));
            Self::add_conj_product(&mut self.lags[0][0], a0, b1);
            Self::add_conj_product(&mut self.lags[0][1], a1, b0);
        }
        if lateral {
            Self::add_conj_product(&mut self.lags[1][0], before.own, now.right);
            Self::add_conj_product(&mut self.lags[1][1], now.own, before.right);
        }
    }

    /// Adds conj(x)·y to the sum (Re, Im) `at`.
    #[inline(always)]
    fn add_conj_product(at: &mut [R::Wide; 2], x: R::Frame, y: R::Frame) {
        let [re, im] = R::conj_product(x, y);
        at[0] = R::add(at[0], re);
        at[1] = R::add(at[1], im);
    }
}

/// The pixels' bins and straddling pairs ([`super::bin_sums`]), lane by lane.
pub(super) struct Bins<R: Registers> {
    bins: Vec<LaneSums<R>>,
    straddling: Vec<LaneSums<R>>,
}

impl<R: Registers> Bins<R> {
    /// Room for `n_bins` bins.
    pub(super) fn new(n_bins: usize) -> Bins<R> {
        // SAFETY: the lanes are vectors of f64, of which every bit pattern, zeros among them,
        // is one.
        let zero: LaneSums<R> = unsafe { std::mem::zeroed() };
        Bins {
            bins: vec![zero; n_bins],
            straddling: vec![zero; n_bins],
        }
    }
}

/// One frame of the pixels, of their right-hand neighbours, and of the other row of their
/// axial pair.
#[derive(Clone, Copy)]
struct Frame<F> {
    own: F,
    right: F,
    other: F,
}

impl<F: Copy> Frame<F> {
    /// The (first, second) series of the axial pair.
    #[inline(always)]
    fn axial(&self, order: AxialPair) -> (F, F) {
        match order {
            AxialPair::OwnThenOther => (self.own, self.other),
            AxialPair::OtherThenOwn => (self.other, self.own),
        }
    }
}

/// `R::WIDTH` pixels of a row: their frames, the right-hand neighbour's of the last, the other
/// row of their axial pair with the pair's order, and whether the lateral pair is measured.
#[derive(Clone, Copy)]
struct PixelGroup<'a> {
    own: &'a [&'a [Complex32]],
    axial: Option<(&'a [&'a [Complex32]], AxialPair)>,
    lateral: bool,
}

/// How many groups of frames ahead each series is fetched.
const PREFETCH_GROUPS: usize = 2;

/// Asks for the cache line of `frames`' first into L1.
#[inline(always)]
fn prefetch(frames: &[Complex32]) {
    // SAFETY: a prefetch never faults; SSE is part of x86_64.
    unsafe { _mm_prefetch::<_MM_HINT_T0>(frames.as_ptr().cast::<i8>()) };
}

/// The bins and straddling pairs of `pixels`' frames in bins of `bin` frames, as many bins as
/// `out` holds. See [`super::lane_window_sums`], whose checks it relies on.
///
/// # Safety
/// The CPU runs `R`'s instructions; every series holds the frames of `out`'s bins.
#[inline(always)]
unsafe fn bin_sums<R: Registers>(pixels: PixelGroup, bin: usize, out: &mut Bins<R>) {
    let (axial, lateral) = (pixels.axial.map(|(_, order)| order), pixels.lateral);
    let n_bins = out.bins.len();
    let frames = n_bins * bin;
    let own = &pixels.own[..R::WIDTH];
    let right = &pixels.own[1..R::WIDTH + 1];
    let nothing = R::nothing();
    let mut sums = LaneSums::<R>::zero();
    let mut before = Frame {
        own: nothing,
        right: nothing,
        other: nothing,
    };
    let mut t0 = 0;
    while t0 < frames {
        let count = (frames - t0).min(R::WIDTH);
        // Every series is its own stream through memory, more than the hardware follows: each
        // is fetched a few groups ahead.
        let ahead = t0 + R::WIDTH * PREFETCH_GROUPS;
        if ahead < frames {
            for s in &pixels.own[..R::WIDTH + 1] {
                prefetch(&s[ahead..]);
            }
            if let Some((other, _)) = pixels.axial {
                for s in &other[..R::WIDTH] {
                    prefetch(&s[ahead..]);
                }
            }
        }
        // SAFETY: frames t0 .. t0 + count lie within every series (the caller's checks).
        let (own_at, right_at, other_at) = unsafe {
            (
                R::turned(own, t0, count),
                if lateral {
                    R::turned(right, t0, count)
                } else {
                    R::none()
                },
                match pixels.axial {
                    Some((other, _)) => R::turned(&other[..R::WIDTH], t0, count),
                    None => R::none(),
                },
            )
        };
        for k in 0..count {
            let t = t0 + k;
            let now = Frame {
                own: own_at.as_ref()[k],
                right: right_at.as_ref()[k],
                other: other_at.as_ref()[k],
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
                    straddle.across(&before, &now, axial, lateral);
                }
                out.straddling[j] = straddle;
                sums.within(&now, axial, lateral);
            } else {
                sums.within(&now, axial, lateral);
                sums.across(&before, &now, axial, lateral);
            }
            before = now;
        }
        t0 += count;
    }
    if n_bins > 0 {
        out.bins[n_bins - 1] = sums;
    }
}

/// Writes the pixels' window sums from `bins` into their places `out.ix ..` of every window's
/// maps, as [`super::window_sums`] writes each.
#[inline(always)]
fn window_sums<R: Registers>(bins: &Bins<R>, windows: &Windows, out: &mut WindowRows) {
    let ix = out.ix;
    let frames = R::splat(windows.window as f64);
    let pairs = R::splat((windows.window - 1) as f64);
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
        R::store(&mut row[ix..ix + R::WIDTH], R::div(sums.power, frames));
        store_complex::<R>(&mut products[0], ix, sums.r1, pairs);
        for (lag, planes) in sums.lags.iter().zip(products[1..].chunks_mut(3)) {
            for (m, (plane, by)) in planes.iter_mut().zip([pairs, pairs, frames]).enumerate() {
                store_complex::<R>(plane, ix, lag[m], by);
            }
        }
    }
}

/// Writes `sum` (Re, Im) / `by` of the pixels into their places `ix ..` of `row`.
#[inline(always)]
fn store_complex<R: Registers>(
    row: &mut ndarray::ArrayViewMut1<Complex64>,
    ix: usize,
    [re, im]: [R::Wide; 2],
    by: R::Wide,
) {
    let row = row
        .as_slice_mut()
        .expect("a row of a map in standard layout");
    R::store_complex(&mut row[ix..ix + R::WIDTH], R::div(re, by), R::div(im, by));
}

/// [`bin_sums`] and [`window_sums`] of the `R::WIDTH` pixels of `pixels` from `offset` on,
/// written into their places `out.ix + offset ..`.
///
/// # Safety
/// As [`bin_sums`].
#[inline(always)]
unsafe fn group_sums<R: Registers>(
    pixels: &LanePixels,
    offset: usize,
    windows: &Windows,
    out: &mut WindowRows,
    bins: &mut Bins<R>,
) {
    let group = PixelGroup {
        own: &pixels.own[offset..offset + R::WIDTH + 1],
        axial: pixels
            .axial
            .as_ref()
            .map(|(other, order)| (&other[offset..offset + R::WIDTH], *order)),
        lateral: pixels.lateral,
    };
    // SAFETY: forwarded from the caller.
    unsafe { bin_sums(group, windows.bin, bins) };
    let first = out.ix;
    out.ix = first + offset;
    window_sums(bins, windows, out);
    out.ix = first;
}

/// The eight pixels' window sums in AVX-512 registers.
///
/// # Safety
/// The CPU has AVX-512F; the checks of [`super::lane_window_sums`] hold.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn sums_avx512(
    pixels: &LanePixels,
    windows: &Windows,
    out: &mut WindowRows,
    bins: &mut Bins<Avx512>,
) {
    // SAFETY: forwarded from the caller.
    unsafe { group_sums(pixels, 0, windows, out, bins) }
}

/// The eight pixels' window sums in AVX2 registers, four at a time.
///
/// # Safety
/// The CPU has AVX2; the checks of [`super::lane_window_sums`] hold.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn sums_avx2(
    pixels: &LanePixels,
    windows: &Windows,
    out: &mut WindowRows,
    bins: &mut Bins<Avx2>,
) {
    for offset in (0..LANES).step_by(Avx2::WIDTH) {
        // SAFETY: forwarded from the caller.
        unsafe { group_sums(pixels, offset, windows, out, bins) }
    }
}

/// AVX-512: eight pixels, an f64 per lane of a 512-bit register, their f32 frames in 256 bits.
#[derive(Clone, Copy)]
pub(super) struct Avx512;

/// One frame of eight pixels: real parts, imaginary parts.
#[derive(Clone, Copy)]
pub(super) struct Frame8 {
    re: __m256,
    im: __m256,
}

/// Frames t .. t + 8 of `series` as eight 64-bit elements, those beyond `mask` zero.
///
/// # Safety
/// The frames `mask` picks lie within `series`.
#[inline(always)]
unsafe fn load8(series: &[Complex32], t: usize, mask: __mmask8) -> __m512i {
    // SAFETY: forwarded from the caller; only reached from code compiled for AVX-512F.
    unsafe { _mm512_maskz_loadu_epi64(mask, series.as_ptr().add(t).cast::<i64>()) }
}

/// Eight complex samples, one per 64-bit element, as their real and imaginary parts.
#[inline(always)]
fn split8(frame: __m512i) -> Frame8 {
    // SAFETY: only reached from code compiled for AVX-512F.
    unsafe {
        Frame8 {
            re: _mm256_castsi256_ps(_mm512_cvtepi64_epi32(frame)),
            im: _mm256_castsi256_ps(_mm512_cvtepi64_epi32(_mm512_srli_epi64::<32>(frame))),
        }
    }
}

// SAFETY (every intrinsic below): reached only from `sums_avx512`, compiled for AVX-512F and run
// where the CPU has it.
impl Registers for Avx512 {
    const WIDTH: usize = 8;
    type Frame = Frame8;
    type Wide = __m512d;
    type Group = [Frame8; 8];

    #[inline(always)]
    fn nothing() -> Frame8 {
        let z = unsafe { _mm256_setzero_ps() };
        Frame8 { re: z, im: z }
    }
    #[inline(always)]
    fn none() -> [Frame8; 8] {
        [Self::nothing(); 8]
    }
    #[inline(always)]
    fn splat(v: f64) -> __m512d {
        unsafe { _mm512_set1_pd(v) }
    }
    #[inline(always)]
    fn add(a: __m512d, b: __m512d) -> __m512d {
        unsafe { _mm512_add_pd(a, b) }
    }
    #[inline(always)]
    fn div(a: __m512d, b: __m512d) -> __m512d {
        unsafe { _mm512_div_pd(a, b) }
    }
    #[inline(always)]
    fn conj_product(x: Frame8, y: Frame8) -> [__m512d; 2] {
        unsafe {
            [
                _mm512_add_pd(
                    _mm512_cvtps_pd(_mm256_mul_ps(x.re, y.re)),
                    _mm512_cvtps_pd(_mm256_mul_ps(x.im, y.im)),
                ),
                _mm512_sub_pd(
                    _mm512_cvtps_pd(_mm256_mul_ps(x.re, y.im)),
                    _mm512_cvtps_pd(_mm256_mul_ps(x.im, y.re)),
                ),
            ]
        }
    }
    #[inline(always)]
    unsafe fn turned(series: &[&[Complex32]], t: usize, count: usize) -> [Frame8; 8] {
        let series: &[&[Complex32]; 8] = series.try_into().expect("eight series");
        let mask: __mmask8 = if count >= 8 { 0xff } else { (1u8 << count) - 1 };
        // Each complex sample is one 64-bit element: its real part in the low half. (No
        // closures here nor in the other methods: one would be compiled without AVX-512, its
        // intrinsics left as calls.)
        // SAFETY (of the loads): the mask reads only frames t .. t + count, within each series.
        let r = unsafe {
            [
                load8(series[0], t, mask),
                load8(series[1], t, mask),
                load8(series[2], t, mask),
                load8(series[3], t, mask),
                load8(series[4], t, mask),
                load8(series[5], t, mask),
                load8(series[6], t, mask),
                load8(series[7], t, mask),
            ]
        };
        unsafe {
            // The 8 × 8 transpose of 64-bit elements: pairs of rows interleaved, then pairs of
            // pairs, then halves.
            let (t0, t1, t2, t3) = (
                _mm512_unpacklo_epi64(r[0], r[1]),
                _mm512_unpackhi_epi64(r[0], r[1]),
                _mm512_unpacklo_epi64(r[2], r[3]),
                _mm512_unpackhi_epi64(r[2], r[3]),
            );
            let (t4, t5, t6, t7) = (
                _mm512_unpacklo_epi64(r[4], r[5]),
                _mm512_unpackhi_epi64(r[4], r[5]),
                _mm512_unpacklo_epi64(r[6], r[7]),
                _mm512_unpackhi_epi64(r[6], r[7]),
            );
            let even = _mm512_setr_epi64(0, 1, 8, 9, 4, 5, 12, 13);
            let odd = _mm512_setr_epi64(2, 3, 10, 11, 6, 7, 14, 15);
            // s0: frames 0 and 4 of rows 0–3; s1: 2 and 6; s2: 1 and 5; s3: 3 and 7; s4–s7
            // rows 4–7.
            let (s0, s1, s2, s3) = (
                _mm512_permutex2var_epi64(t0, even, t2),
                _mm512_permutex2var_epi64(t0, odd, t2),
                _mm512_permutex2var_epi64(t1, even, t3),
                _mm512_permutex2var_epi64(t1, odd, t3),
            );
            let (s4, s5, s6, s7) = (
                _mm512_permutex2var_epi64(t4, even, t6),
                _mm512_permutex2var_epi64(t4, odd, t6),
                _mm512_permutex2var_epi64(t5, even, t7),
                _mm512_permutex2var_epi64(t5, odd, t7),
            );
            let low = _mm512_setr_epi64(0, 1, 2, 3, 8, 9, 10, 11);
            let high = _mm512_setr_epi64(4, 5, 6, 7, 12, 13, 14, 15);
            [
                split8(_mm512_permutex2var_epi64(s0, low, s4)),
                split8(_mm512_permutex2var_epi64(s2, low, s6)),
                split8(_mm512_permutex2var_epi64(s1, low, s5)),
                split8(_mm512_permutex2var_epi64(s3, low, s7)),
                split8(_mm512_permutex2var_epi64(s0, high, s4)),
                split8(_mm512_permutex2var_epi64(s2, high, s6)),
                split8(_mm512_permutex2var_epi64(s1, high, s5)),
                split8(_mm512_permutex2var_epi64(s3, high, s7)),
            ]
        }
    }
    #[inline(always)]
    fn store(to: &mut [f64], v: __m512d) {
        let to = &mut to[..8];
        // SAFETY: the 8 f64 written are `to`'s.
        unsafe { _mm512_storeu_pd(to.as_mut_ptr(), v) }
    }
    #[inline(always)]
    fn store_complex(to: &mut [Complex64], re: __m512d, im: __m512d) {
        let at = to[..8].as_mut_ptr().cast::<f64>();
        // Complex values are (Re, Im) after each other: the lanes' real and imaginary parts
        // interleaved, the first four pixels' then the last four's.
        // SAFETY: the 16 f64 written are the 8 complex values of `to[.. 8]`.
        unsafe {
            let first_four = _mm512_setr_epi64(0, 1, 8, 9, 2, 3, 10, 11);
            let last_four = _mm512_setr_epi64(4, 5, 12, 13, 6, 7, 14, 15);
            let (even, odd) = (_mm512_unpacklo_pd(re, im), _mm512_unpackhi_pd(re, im));
            _mm512_storeu_pd(at, _mm512_permutex2var_pd(even, first_four, odd));
            _mm512_storeu_pd(at.add(8), _mm512_permutex2var_pd(even, last_four, odd));
        }
    }
}

/// AVX2: four pixels, an f64 per lane of a 256-bit register, their f32 frames in 128 bits.
#[derive(Clone, Copy)]
pub(super) struct Avx2;

/// One frame of four pixels: real parts, imaginary parts.
#[derive(Clone, Copy)]
pub(super) struct Frame4 {
    re: __m128,
    im: __m128,
}

/// Frames t .. t + 4 of `series` as four 64-bit elements.
///
/// # Safety
/// The frames lie within `series`.
#[inline(always)]
unsafe fn load4(series: &[Complex32], t: usize) -> __m256i {
    // SAFETY: forwarded from the caller; only reached from code compiled for AVX2.
    unsafe { _mm256_loadu_si256(series.as_ptr().add(t).cast::<__m256i>()) }
}

/// [`load4`] of the frames `mask` picks (the others zero).
///
/// # Safety
/// Those frames lie within `series`.
#[inline(always)]
unsafe fn load4_masked(series: &[Complex32], t: usize, mask: __m256i) -> __m256i {
    // SAFETY: forwarded from the caller; only reached from code compiled for AVX2.
    unsafe { _mm256_maskload_epi64(series.as_ptr().add(t).cast::<i64>(), mask) }
}

/// Four complex samples, one per 64-bit element, as their real and imaginary parts.
#[inline(always)]
fn split4(frame: __m256i) -> Frame4 {
    // SAFETY: only reached from code compiled for AVX2.
    unsafe {
        // Real parts (even floats) to the low half, imaginary parts to the high half.
        let parts = _mm256_setr_epi32(0, 2, 4, 6, 1, 3, 5, 7);
        let split = _mm256_permutevar8x32_ps(_mm256_castsi256_ps(frame), parts);
        Frame4 {
            re: _mm256_castps256_ps128(split),
            im: _mm256_extractf128_ps::<1>(split),
        }
    }
}

// SAFETY (every intrinsic below): reached only from `sums_avx2`, compiled for AVX2 and run
// where the CPU has it.
impl Registers for Avx2 {
    const WIDTH: usize = 4;
    type Frame = Frame4;
    type Wide = __m256d;
    type Group = [Frame4; 4];

    #[inline(always)]
    fn nothing() -> Frame4 {
        let z = unsafe { _mm_setzero_ps() };
        Frame4 { re: z, im: z }
    }
    #[inline(always)]
    fn none() -> [Frame4; 4] {
        [Self::nothing(); 4]
    }
    #[inline(always)]
    fn splat(v: f64) -> __m256d {
        unsafe { _mm256_set1_pd(v) }
    }
    #[inline(always)]
    fn add(a: __m256d, b: __m256d) -> __m256d {
        unsafe { _mm256_add_pd(a, b) }
    }
    #[inline(always)]
    fn div(a: __m256d, b: __m256d) -> __m256d {
        unsafe { _mm256_div_pd(a, b) }
    }
    #[inline(always)]
    fn conj_product(x: Frame4, y: Frame4) -> [__m256d; 2] {
        unsafe {
            [
                _mm256_add_pd(
                    _mm256_cvtps_pd(_mm_mul_ps(x.re, y.re)),
                    _mm256_cvtps_pd(_mm_mul_ps(x.im, y.im)),
                ),
                _mm256_sub_pd(
                    _mm256_cvtps_pd(_mm_mul_ps(x.re, y.im)),
                    _mm256_cvtps_pd(_mm_mul_ps(x.im, y.re)),
                ),
            ]
        }
    }
    #[inline(always)]
    unsafe fn turned(series: &[&[Complex32]], t: usize, count: usize) -> [Frame4; 4] {
        let series: &[&[Complex32]; 4] = series.try_into().expect("four series");
        // Each complex sample is one 64-bit element: its real part in the low half.
        // SAFETY (of the loads): a whole group lies within each series; else the mask reads
        // only frames t .. t + count (masked-out elements do not fault).
        let r = unsafe {
            if count >= 4 {
                [
                    load4(series[0], t),
                    load4(series[1], t),
                    load4(series[2], t),
                    load4(series[3], t),
                ]
            } else {
                let mask = _mm256_setr_epi64x(
                    -i64::from(count > 0),
                    -i64::from(count > 1),
                    -i64::from(count > 2),
                    -i64::from(count > 3),
                );
                [
                    load4_masked(series[0], t, mask),
                    load4_masked(series[1], t, mask),
                    load4_masked(series[2], t, mask),
                    load4_masked(series[3], t, mask),
                ]
            }
        };
        unsafe {
            // The 4 × 4 transpose of 64-bit elements: pairs of rows interleaved, then halves.
            let t0 = _mm256_unpacklo_epi64(r[0], r[1]);
            let t1 = _mm256_unpackhi_epi64(r[0], r[1]);
            let t2 = _mm256_unpacklo_epi64(r[2], r[3]);
            let t3 = _mm256_unpackhi_epi64(r[2], r[3]);
            [
                split4(_mm256_permute2x128_si256::<0x20>(t0, t2)),
                split4(_mm256_permute2x128_si256::<0x20>(t1, t3)),
                split4(_mm256_permute2x128_si256::<0x31>(t0, t2)),
                split4(_mm256_permute2x128_si256::<0x31>(t1, t3)),
            ]
        }
    }
    #[inline(always)]
    fn store(to: &mut [f64], v: __m256d) {
        let to = &mut to[..4];
        // SAFETY: the 4 f64 written are `to`'s.
        unsafe { _mm256_storeu_pd(to.as_mut_ptr(), v) }
    }
    #[inline(always)]
    fn store_complex(to: &mut [Complex64], re: __m256d, im: __m256d) {
        let at = to[..4].as_mut_ptr().cast::<f64>();
        // SAFETY: the 8 f64 written are the 4 complex values of `to[.. 4]`.
        unsafe {
            // (re0, im0, re2, im2) and (re1, im1, re3, im3), then their halves in order.
            let (even, odd) = (_mm256_unpacklo_pd(re, im), _mm256_unpackhi_pd(re, im));
            _mm256_storeu_pd(at, _mm256_permute2f128_pd::<0x20>(even, odd));
            _mm256_storeu_pd(at.add(4), _mm256_permute2f128_pd::<0x31>(even, odd));
        }
    }
}
