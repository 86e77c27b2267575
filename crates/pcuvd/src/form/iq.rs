//! IQ demodulation: RF traces to complex baseband, for every angle, batched over frames.
//!
//! Each trace is mixed with exp(−2πi f_d t), t = t0 + n/f_s being the absolute record time (so that
//! phases stay consistent with the beamformer's delays), then low-pass filtered with a zero-phase
//! windowed-sinc FIR of gain 2 (so that |IQ| is the RF envelope). Band-pass-sampled data (f_s below
//! 2 f_c) works unchanged: mixing at f_d aliases exactly like the signal does; the cut-off is placed
//! halfway between the baseband signal and the nearest alias of the −2 f_d image.

use ndarray::{Array3, Axis, s};
use num_complex::Complex32;
use rayon::prelude::*;

use crate::acquisition::channel::{AngleSamples, AngleSamplesView};
use crate::core::buffers::{complex_floats, complex_floats_mut, contiguous, padded_rows_reusing};
use crate::core::error::{Error, Result, invalid, require_positive};
use crate::core::rows::weighted_rows;

/// Baseband channel data of one angle, laid out (channels, samples, frames) so that the beamformer
/// applies each delay to a whole batch of frames at once.
#[derive(Debug, Clone, PartialEq)]
pub struct IqChannels {
    /// Complex baseband samples, shape (channels, samples, frames). Demodulation lays each row
    /// of frames on whole cache lines, padded, for the beamformer's vector loads: its output is
    /// in standard layout only where the frames fill whole lines (multiples of 8).
    pub data: Array3<Complex32>,
    /// Sampling frequency (Hz).
    pub sampling_frequency: f64,
    /// Time of the first sample (s), as in the recording.
    pub t0: f64,
    /// Demodulation frequency (Hz).
    pub demod_frequency: f64,
}

/// Lowest IQ low-pass cut-off accepted, as a fraction of the sampling frequency.
pub const MIN_CUTOFF_RATIO: f64 = 1e-4;

/// Default low-pass cut-off (Hz): halfway to the nearest alias of the −2 f_d image, never above f_d.
pub fn default_cutoff(demod_frequency: f64, sampling_frequency: f64) -> f64 {
    let fs = sampling_frequency;
    // Distance from 0 Hz to the nearest alias of −2 f_d on the circle of circumference f_s.
    let image = (2.0 * demod_frequency).rem_euclid(fs);
    let distance = image.min(fs - image);
    (0.5 * distance).min(demod_frequency)
}

/// Zero-phase low-pass FIR taps (odd length, Hamming-windowed sinc) with DC gain 2.
pub fn lowpass_taps(cutoff: f64, sampling_frequency: f64) -> Vec<f32> {
    let ratio = cutoff / sampling_frequency;
    let half = (3.0 / ratio).ceil() as isize / 2 + 2;
    let taps: Vec<f64> = (-half..=half)
        .map(|k| {
            let k = k as f64;
            let sinc = if k == 0.0 {
                2.0 * ratio
            } else {
                (2.0 * std::f64::consts::PI * ratio * k).sin() / (std::f64::consts::PI * k)
            };
            let window = 0.54 + 0.46 * (std::f64::consts::PI * k / (half as f64 + 1.0)).cos();
            sinc * window
        })
        .collect();
    let sum: f64 = taps.iter().sum();
    taps.iter().map(|t| (2.0 * t / sum) as f32).collect()
}

/// Demodulates angle `angle` of per-angle samples to baseband, shape (channels, samples, frames).
/// IQ input is only transposed. `cutoff` defaults to [`default_cutoff`].
pub fn demodulate(
    samples: &AngleSamples,
    angle: usize,
    t0: f64,
    sampling_frequency: f64,
    demod_frequency: f64,
    cutoff: Option<f64>,
) -> Result<IqChannels> {
    let mut out = IqChannels {
        data: Array3::zeros((0, 0, 0)),
        sampling_frequency,
        t0,
        demod_frequency,
    };
    demodulate_into(
        samples.view(),
        angle,
        t0,
        sampling_frequency,
        demod_frequency,
        cutoff,
        &mut out,
    )?;
    Ok(out)
}

/// As [`demodulate`], of records where they lie (an [`AngleSamples`]' or a block decoded in
/// place), into `out`, whose array is reused when it has the shape (an angle after another of
/// the same block).
#[allow(clippy::too_many_arguments)]
pub fn demodulate_into(
    samples: AngleSamplesView,
    angle: usize,
    t0: f64,
    sampling_frequency: f64,
    demod_frequency: f64,
    cutoff: Option<f64>,
    iq: &mut IqChannels,
) -> Result<()> {
    require_positive("sampling frequency", sampling_frequency)?;
    require_positive("demodulation frequency", demod_frequency)?;
    let (n_angles, frames, channels, n_samples) = samples.dim();
    if angle >= n_angles {
        return Err(Error::Shape(format!(
            "angle {angle} requested from data with {n_angles} angles"
        )));
    }
    iq.sampling_frequency = sampling_frequency;
    iq.t0 = t0;
    iq.demod_frequency = demod_frequency;
    let rf = match samples {
        AngleSamplesView::Iq {
            data,
            demod_frequency: fd,
        } => {
            iq.demod_frequency = fd;
            let mut whole = padded_channels(iq, (channels, n_samples, frames));
            let mut out = whole.slice_mut(s![.., .., ..frames]);
            out.assign(&data.slice(s![angle, .., .., ..]).permuted_axes([1, 2, 0]));
            iq.data = whole.slice_move(s![.., .., ..frames]);
            return Ok(());
        }
        AngleSamplesView::Rf(rf) => rf.slice_move(s![angle, .., .., ..]),
    };
    let cutoff = cutoff.unwrap_or_else(|| default_cutoff(demod_frequency, sampling_frequency));
    // The filter is about 3·f_s/cutoff taps long: a cut-off below 10⁻⁴·f_s (a demodulation
    // frequency of 10⁻³⁰⁰ Hz, an f_s of 10³⁰⁰ Hz) would ask for more taps than memory holds, and
    // never happens in an ultrasound recording.
    if cutoff.is_finite() && cutoff > 0.0 && cutoff < MIN_CUTOFF_RATIO * sampling_frequency {
        return Err(invalid(
            "IQ low-pass cut-off",
            format!(
                "{cutoff:.3e} Hz is below {MIN_CUTOFF_RATIO:e} × f_s ({sampling_frequency:.3e} Hz): \
                 check the sampling and demodulation (centre) frequencies"
            ),
        ));
    }
    if !(cutoff > 0.0 && cutoff < sampling_frequency / 2.0) {
        return Err(invalid(
            "IQ low-pass cut-off",
            format!(
                "{:.3} MHz is not within (0, f_s/2 = {:.3} MHz)",
                cutoff * 1e-6,
                sampling_frequency * 5e-7
            ),
        ));
    }
    let taps = lowpass_taps(cutoff, sampling_frequency);
    let mixer: Vec<Complex32> = (0..n_samples)
        .map(|n| {
            let t = t0 + n as f64 / sampling_frequency;
            let ph = -2.0 * std::f64::consts::PI * demod_frequency * t;
            Complex32::new(ph.cos() as f32, ph.sin() as f32)
        })
        .collect();
    // Every element, padding included, is written below.
    let mut whole = padded_channels(iq, (channels, n_samples, frames));
    // Mixed and filtered with the frames side by side, (samples, frames) as the output is laid
    // out: each tap then multiplies a whole row of frames, which vectorises, where one trace at
    // a time did not. Rows are padded to whole vectors (the output's cache lines); the mixed
    // rows' padding stays zero, and so does the output's: the filter's sums then run in whole
    // blocks, where a row's few last floats cost as much as the rest.
    let stride = whole.dim().2;
    whole
        .axis_iter_mut(Axis(0))
        .into_par_iter()
        .enumerate()
        .for_each_init(Vec::new, |mixed, (ch, mut dest)| {
            let half = taps.len() / 2;
            mixed.resize((BAND + 2 * half) * stride, Complex32::new(0.0, 0.0));
            // Each frame's trace as a slice, found once: a view sliced per band and frame cost
            // more than the samples it moved.
            let traces: Vec<std::borrow::Cow<[f32]>> = (0..frames)
                .map(|f| contiguous(rf.slice(s![f, ch, ..])))
                .collect();
            let dest = dest
                .as_slice_mut()
                .expect("a standard-layout (channels, samples, padded frames) array");
            // A band of output samples at a time, mixed with the filter's reach on either side
            // and filtered at once: the mixed rows stay in L2 between the two, where a channel's
            // whole mixed record (megabytes) went to memory and back. The traces are read a band
            // at a time, long enough for the prefetcher to follow each.
            for n0 in (0..n_samples).step_by(BAND) {
                let n1 = (n0 + BAND).min(n_samples);
                let rows = n0.saturating_sub(half)..(n1 + half).min(n_samples);
                let band = &mut mixed[..rows.len() * stride];
                let weights = &mixer[rows.clone()];
                for (f0, tile) in traces.chunks(MIX_FRAMES).enumerate() {
                    let tile: Vec<&[f32]> = tile.iter().map(|t| &t[rows.clone()]).collect();
                    mix_into_rows(band, stride, f0 * MIX_FRAMES, &tile, weights);
                }
                fir_same_rows(
                    band,
                    stride,
                    rows.start,
                    n_samples,
                    &taps,
                    &mut dest[n0 * stride..n1 * stride],
                    n0,
                );
            }
        });
    iq.data = whole.slice_move(s![.., .., ..frames]);
    Ok(())
}

/// `iq`'s array taken for a (channels, samples, frames) output in its memory, each row of
/// frames padded to and starting on a cache line ([`padded_rows_reusing`]): the beamformer
/// reads every row as whole vectors.
fn padded_channels(iq: &mut IqChannels, shape: (usize, usize, usize)) -> Array3<Complex32> {
    let old = std::mem::replace(&mut iq.data, Array3::zeros((0, 0, 0)));
    padded_rows_reusing(Some(old), shape)
}

/// Frames mixed side by side into a band's rows at a time ([`mix_into_rows`]).
const MIX_FRAMES: usize = 8;

/// Row i of `band` (rows of `stride` samples), frames `f0..f0 + tile.len()`, set to
/// `weights[i]·tile[f][i]`: a tile of frames' traces mixed and laid side by side, a row's run
/// of frames written whole. One frame at a time wrote a float pair to every row's cache line;
/// eight frames of eight rows are turned in registers where AVX2 is there (each product the
/// same single rounding).
fn mix_into_rows(
    band: &mut [Complex32],
    stride: usize,
    f0: usize,
    tile: &[&[f32]],
    weights: &[Complex32],
) {
    let rows = weights.len();
    assert!(band.len() >= rows * stride && f0 + tile.len() <= stride);
    assert!(tile.iter().all(|trace| trace.len() >= rows));
    // Rows the AVX2 path mixes, eight at a time; the loop below takes the rest.
    #[cfg(target_arch = "x86_64")]
    let done = if tile.len() == 8 && crate::core::simd::avx2() {
        let done = rows / 8 * 8;
        // SAFETY: AVX2 was detected; the asserts above bound every row and trace read or written.
        unsafe { mix_eight_avx2(band, stride, f0, tile, &weights[..done]) };
        done
    } else {
        0
    };
    #[cfg(not(target_arch = "x86_64"))]
    let done = 0;
    for i in done..rows {
        let row = &mut band[i * stride + f0..i * stride + f0 + tile.len()];
        for (out, trace) in row.iter_mut().zip(tile) {
            *out = weights[i] * trace[i];
        }
    }
}

/// [`mix_into_rows`] of 8 frames on a multiple of 8 rows: each 8 × 8 block of samples (frames
/// × rows) is transposed in registers, and each row's 8 samples are duplicated into (x, x)
/// pairs and multiplied by the row's weight's (re, im), two 32-byte stores per row.
///
/// # Safety
/// AVX2 must be available; `tile` holds 8 traces of `weights.len()` samples or more, a multiple
/// of 8, and `band` that many rows of `stride` with frames `f0..f0 + 8` within each.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn mix_eight_avx2(
    band: &mut [Complex32],
    stride: usize,
    f0: usize,
    tile: &[&[f32]],
    weights: &[Complex32],
) {
    use std::arch::x86_64::*;
    let out = band.as_mut_ptr().cast::<f32>();
    let low = _mm256_setr_epi32(0, 0, 1, 1, 2, 2, 3, 3);
    let high = _mm256_setr_epi32(4, 4, 5, 5, 6, 6, 7, 7);
    for i0 in (0..weights.len()).step_by(8) {
        // SAFETY: rows i0..i0 + 8 lie within every trace (the caller's bound).
        let r: [__m256; 8] =
            std::array::from_fn(|f| unsafe { _mm256_loadu_ps(tile[f].as_ptr().add(i0)) });
        // r[f][i] → t[i][f].
        let t = crate::core::simd::transpose_8x8(r);
        for (k, &x) in t.iter().enumerate() {
            let w = weights[i0 + k];
            let pair = _mm256_setr_ps(w.re, w.im, w.re, w.im, w.re, w.im, w.re, w.im);
            // SAFETY: row i0 + k's frames f0..f0 + 8, 16 floats, lie within `band`.
            unsafe {
                let dest = out.add(2 * ((i0 + k) * stride + f0));
                _mm256_storeu_ps(dest, _mm256_mul_ps(_mm256_permutevar8x32_ps(x, low), pair));
                _mm256_storeu_ps(
                    dest.add(8),
                    _mm256_mul_ps(_mm256_permutevar8x32_ps(x, high), pair),
                );
            }
        }
    }
}

/// Output samples per band of the IQ filter, which mixes and filters a band at once: its mixed
/// rows (with the filter's reach on either side, a few hundred kB of a 360-frame ensemble) stay
/// in L2, also where L2 is 1 MB.
const BAND: usize = 128;

/// Centred ("same"-length) convolution along the rows of a trace of `n` rows (samples) of
/// `stride` columns, row-major, with an odd, symmetric FIR; zero beyond the trace ends. `x` holds
/// rows `first..` of the trace, `y` output rows `out_first..`; `x` reaches every row their windows
/// need. Every column is filtered alike, with the terms summed in the same order as one trace at
/// a time.
fn fir_same_rows(
    x: &[Complex32],
    stride: usize,
    first: usize,
    n: usize,
    taps: &[f32],
    y: &mut [Complex32],
    out_first: usize,
) {
    // A real tap scales the real and imaginary parts alike.
    let (x, y) = (complex_floats(x), complex_floats_mut(y));
    let rows: Vec<&[f32]> = x.chunks_exact(2 * stride).collect();
    let half = taps.len() / 2;
    for (o, out) in y.chunks_exact_mut(2 * stride).enumerate() {
        let i = out_first + o;
        let lo = i.saturating_sub(half);
        let hi = (i + half + 1).min(n);
        weighted_rows(
            out,
            &rows[lo - first..hi - first],
            &taps[lo + half - i..hi + half - i],
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array4;

    /// Mixed rows are, to the bit, each weight times each trace's sample, on row counts around
    /// the 8-row blocks and tiles of 1 to 8 frames, with the frames of other tiles untouched.
    #[test]
    fn mixed_rows_are_each_weight_times_each_sample() {
        let stride = 24;
        for rows in [0usize, 1, 7, 8, 9, 16, 21] {
            for frames in 1..=8 {
                let traces: Vec<Vec<f32>> = (0..frames)
                    .map(|f| {
                        (0..rows + 3)
                            .map(|i| ((i * 7 + f * 3) as f32 * 0.37).sin() * 1e3)
                            .collect()
                    })
                    .collect();
                let tile: Vec<&[f32]> = traces.iter().map(|t| &t[..]).collect();
                let weights: Vec<Complex32> = (0..rows)
                    .map(|i| Complex32::from_polar(1.0, i as f32 * 0.61))
                    .collect();
                let f0 = 5;
                let sentinel = Complex32::new(f32::NAN, -1.0);
                let mut band = vec![sentinel; rows * stride];
                mix_into_rows(&mut band, stride, f0, &tile, &weights);
                for i in 0..rows {
                    for c in 0..stride {
                        let got = band[i * stride + c];
                        if (f0..f0 + frames).contains(&c) {
                            let want = weights[i] * traces[c - f0][i];
                            assert_eq!(
                                (got.re.to_bits(), got.im.to_bits()),
                                (want.re.to_bits(), want.im.to_bits()),
                                "{rows} rows, {frames} frames: row {i}, frame {}",
                                c - f0
                            );
                        } else {
                            assert!(
                                got.re.is_nan() && got.im == -1.0,
                                "column {c} of row {i} written"
                            );
                        }
                    }
                }
            }
        }
    }

    /// The filter of rows of frames is, to the bit, each column's "same" convolution summed term
    /// by term in the order of the window (from its first row in the trace), at the ends where
    /// the window is cut and in between, for row counts around the window's length, whole or
    /// a band of rows at a time.
    #[test]
    fn rows_are_filtered_as_each_column_term_by_term() {
        let taps = lowpass_taps(15.625e6, 65e6);
        let half = taps.len() / 2;
        let stride = 24;
        for n in [1, half, taps.len(), taps.len() + 3, 40] {
            let x: Vec<Complex32> = (0..n * stride)
                .map(|i| Complex32::new((i as f32 * 0.71).sin(), (i as f32 * 0.37).cos() * 3.0))
                .collect();
            // Whole, and in bands of 1, 5 and 7 output rows, each given the rows it reaches.
            let mut y = vec![Complex32::new(f32::NAN, f32::NAN); n * stride];
            fir_same_rows(&x, stride, 0, n, &taps, &mut y, 0);
            for band in [1, 5, 7] {
                let mut banded = vec![Complex32::new(f32::NAN, f32::NAN); n * stride];
                for n0 in (0..n).step_by(band) {
                    let n1 = (n0 + band).min(n);
                    let rows = n0.saturating_sub(half)..(n1 + half).min(n);
                    fir_same_rows(
                        &x[rows.start * stride..rows.end * stride],
                        stride,
                        rows.start,
                        n,
                        &taps,
                        &mut banded[n0 * stride..n1 * stride],
                        n0,
                    );
                }
                let bits = |v: &[Complex32]| {
                    v.iter()
                        .map(|c| (c.re.to_bits(), c.im.to_bits()))
                        .collect::<Vec<_>>()
                };
                assert_eq!(bits(&banded), bits(&y), "{n} rows in bands of {band}");
            }
            for i in 0..n {
                for c in 0..stride {
                    let mut expected = Complex32::new(0.0, 0.0);
                    for j in i.saturating_sub(half)..(i + half + 1).min(n) {
                        let t = taps[j + half - i];
                        let v = x[j * stride + c];
                        expected.re += v.re * t;
                        expected.im += v.im * t;
                    }
                    let got = y[i * stride + c];
                    assert_eq!(
                        (got.re.to_bits(), got.im.to_bits()),
                        (expected.re.to_bits(), expected.im.to_bits()),
                        "{n} rows, row {i}, column {c}"
                    );
                }
            }
        }
    }

    /// Absurd frequencies (which would ask for a filter of 10³⁰⁰ taps) are an error, not a crash.
    #[test]
    fn absurd_frequencies_are_refused_not_allocated() {
        let rf = AngleSamples::Rf(Array4::<f32>::zeros((1, 1, 1, 10)));
        for (fs, fd) in [(1e7, 1e-300), (1e300, 5e6)] {
            let err = demodulate(&rf, 0, 0.0, fs, fd, None).unwrap_err();
            assert!(err.to_string().contains("cut-off"), "{err}");
        }
    }

    /// Each frame is demodulated as if alone (to the bit), whatever the number of frames beside
    /// it and whether the output's memory is fresh or reused from a larger block; every row of
    /// frames starts on a cache line.
    #[test]
    fn frames_demodulate_alone_into_rows_on_cache_lines() {
        let (fs, fc, n) = (65e6, 15.625e6, 700);
        let record = |frames: usize| {
            Array4::<f32>::from_shape_fn((1, frames, 3, n), |(_, f, ch, i)| {
                ((i as f32 * 0.9 + f as f32 * 1.3 + ch as f32).sin() * (1.0 + f as f32)).sin()
            })
        };
        let mut reused = demodulate(&AngleSamples::Rf(record(20)), 0, 1e-6, fs, fc, None).unwrap();
        for frames in [1, 3, 9, 13] {
            let rf = AngleSamples::Rf(record(frames));
            let fresh = demodulate(&rf, 0, 1e-6, fs, fc, None).unwrap();
            demodulate_into(rf.view(), 0, 1e-6, fs, fc, None, &mut reused).unwrap();
            for iq in [&fresh, &reused] {
                assert_eq!(iq.data.dim(), (3, n, frames));
                for lane in iq.data.lanes(Axis(2)) {
                    assert_eq!(&lane[0] as *const Complex32 as usize % 64, 0);
                }
                for f in 0..frames {
                    let alone =
                        AngleSamples::Rf(record(f + 1).slice_move(s![.., f..f + 1, .., ..]));
                    let alone = demodulate(&alone, 0, 1e-6, fs, fc, None).unwrap();
                    let bits = |v: ndarray::ArrayView2<Complex32>| {
                        v.iter()
                            .map(|c| (c.re.to_bits(), c.im.to_bits()))
                            .collect::<Vec<_>>()
                    };
                    assert_eq!(
                        bits(iq.data.slice(s![.., .., f])),
                        bits(alone.data.slice(s![.., .., 0])),
                        "frame {f} of {frames}"
                    );
                }
            }
        }
    }

    /// A Gaussian-windowed tone demodulates to its envelope with the expected phase.
    fn check_tone(fs: f64, fc: f64) {
        let n = 400;
        let t0 = 3e-6;
        let (tc, sigma, phi) = (t0 + 200.0 / fs, 30.0 / fs, 0.7);
        let mut rf = Array4::<f32>::zeros((1, 1, 1, n));
        for i in 0..n {
            let t = t0 + i as f64 / fs;
            let env = (-(t - tc).powi(2) / (2.0 * sigma * sigma)).exp();
            rf[[0, 0, 0, i]] = (env * (2.0 * std::f64::consts::PI * fc * t + phi).cos()) as f32;
        }
        let iq = demodulate(&AngleSamples::Rf(rf), 0, t0, fs, fc, None).unwrap();
        for i in (150..250).step_by(5) {
            let t = t0 + i as f64 / fs;
            let env = (-(t - tc).powi(2) / (2.0 * sigma * sigma)).exp();
            let v = iq.data[[0, i, 0]];
            assert!(
                (v.norm() as f64 - env).abs() < 0.02,
                "fs {fs}: |iq| {} vs {env}",
                v.norm()
            );
            assert!(env > 0.2);
            assert!(
                ((v.arg() as f64 - phi + 3.0 * std::f64::consts::PI)
                    .rem_euclid(2.0 * std::f64::consts::PI)
                    - std::f64::consts::PI)
                    .abs()
                    < 0.03
            );
        }
    }

    #[test]
    fn demodulates_nyquist_sampled_rf() {
        check_tone(65e6, 15.625e6);
    }

    #[test]
    fn demodulates_band_pass_sampled_rf() {
        // As in the PWI_disk recording: 5 MHz sampled at 6.67 MHz.
        check_tone(5e6 * 4.0 / 3.0, 5e6);
    }
}
