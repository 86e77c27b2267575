//! Band-limited white Gaussian receiver noise, one independent random stream per (event, channel).

use std::sync::Arc;

use num_complex::Complex32;
use pcuvd_fft::{Fft, FftPlanner32};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::core::error::{Result, invalid};

/// FFT length of the noise of traces of `len` samples: a power of two, at least 64.
fn fft_len(len: usize) -> usize {
    len.next_power_of_two().max(64)
}

/// The FFT bins (of [`fft_len`]`(len)` points at `fs`, Hz) strictly inside the Nyquist range that
/// lie in `band` (low, high) (Hz). An error naming the band and the bin width when there is none:
/// such a band (narrower than one bin, or between two bins) would give noiseless data.
pub(crate) fn band_bins(
    len: usize,
    fs: f64,
    band: (f64, f64),
) -> Result<std::ops::RangeInclusive<usize>> {
    let n_fft = fft_len(len);
    let df = fs / n_fft as f64;
    // DC and the Nyquist bin are left out: their coefficients are real, which the variance
    // bookkeeping below (complex Gaussians, Re has variance 1 per bin) does not cover.
    let lo = ((band.0 / df).ceil() as usize).max(1);
    let hi = ((band.1 / df).floor() as usize).min((n_fft - 1) / 2);
    if lo > hi {
        return Err(invalid(
            "noise band",
            format!(
                "({:.6}, {:.6}) MHz holds no FFT bin of the noise: its bins are f_s / {n_fft} = \
                 {:.3} kHz apart (the receive window's {len} samples at {:.3} MHz, padded to a power \
                 of two), excluding DC and f_s/2; widen the band to at least one bin",
                band.0 / 1e6,
                band.1 / 1e6,
                df / 1e3,
                fs / 1e6
            ),
        ));
    }
    Ok(lo..=hi)
}

/// Generates stationary Gaussian noise whose spectrum is flat inside a band and zero outside:
/// independent complex Gaussian coefficients on the FFT bins of the band (positive frequencies),
/// an inverse FFT, the real part, scaled so that each sample has the requested RMS.
pub(crate) struct NoiseGenerator {
    fft: Arc<dyn Fft<f32>>,
    n_fft: usize,
    bins: std::ops::RangeInclusive<usize>,
    scale: f32,
    seed: u64,
}

impl NoiseGenerator {
    /// Noise for traces of `len` samples at `fs` (Hz), band `band` (Hz), per-sample RMS `rms`.
    /// An error when the band holds no FFT bin ([`band_bins`]).
    pub(crate) fn new(len: usize, fs: f64, band: (f64, f64), rms: f64, seed: u64) -> Result<Self> {
        let n_fft = fft_len(len);
        let bins = band_bins(len, fs, band)?;
        // Re(IFFT) of unit complex Gaussians on m bins has per-sample variance m.
        let m = bins.clone().count() as f64;
        Ok(NoiseGenerator {
            fft: FftPlanner32::new().plan_fft_inverse(n_fft),
            n_fft,
            bins,
            scale: (rms / m.sqrt()) as f32,
            seed,
        })
    }

    /// Adds this (seed, `stream`)'s noise to `trace`.
    pub(crate) fn add(&self, trace: &mut [f32], stream: u64) {
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        rng.set_stream(stream);
        let mut buf = vec![Complex32::new(0.0, 0.0); self.n_fft];
        for k in self.bins.clone() {
            let re: f32 = StandardNormal.sample(&mut rng);
            let im: f32 = StandardNormal.sample(&mut rng);
            // E|X|² = 2, so Re(x) has variance 1 per bin.
            buf[k] = Complex32::new(re, im);
        }
        self.fft.process(&mut buf);
        for (t, v) in trace.iter_mut().zip(&buf) {
            *t += v.re * self.scale;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 1000 samples at 65 MHz: a 1024-point FFT, bins 63.477 kHz apart.
    const LEN: usize = 1000;
    const FS: f64 = 65e6;
    const DF: f64 = FS / 1024.0;

    #[test]
    fn a_band_narrower_than_one_bin_between_two_bins_is_an_error() {
        // Strictly between bins 100 and 101, so it holds none.
        let band = (100.2 * DF, 100.8 * DF);
        let err = band_bins(LEN, FS, band).unwrap_err().to_string();
        assert!(err.contains("noise band"), "{err}");
        assert!(err.contains(&format!("{:.6}", band.0 / 1e6)), "{err}");
        assert!(err.contains(&format!("{:.6}", band.1 / 1e6)), "{err}");
        assert!(err.contains("63.477 kHz"), "{err}");
        assert!(NoiseGenerator::new(LEN, FS, band, 1.0, 0).is_err());
    }

    #[test]
    fn bins_are_those_inside_the_band() {
        // A band narrower than a bin that does hold one is fine: exactly that bin.
        assert_eq!(
            band_bins(LEN, FS, (99.9 * DF, 100.1 * DF)).unwrap(),
            100..=100
        );
        // Edges on bins are inclusive.
        assert_eq!(band_bins(LEN, FS, (10.0 * DF, 20.0 * DF)).unwrap(), 10..=20);
        // DC and the Nyquist bin (512) are excluded.
        assert_eq!(band_bins(LEN, FS, (0.0, FS / 2.0)).unwrap(), 1..=511);
        assert!(band_bins(LEN, FS, (0.0, 0.5 * DF)).is_err());
        assert!(band_bins(LEN, FS, (511.5 * DF, FS / 2.0)).is_err());
    }

    #[test]
    fn noise_has_the_requested_rms() {
        let generator = NoiseGenerator::new(LEN, FS, (1e6, 22e6), 0.5, 3).unwrap();
        let mut sum_sq = 0.0f64;
        let mut n = 0usize;
        for stream in 0..200 {
            let mut trace = vec![0.0f32; LEN];
            generator.add(&mut trace, stream);
            sum_sq += trace.iter().map(|&v| (v as f64).powi(2)).sum::<f64>();
            n += LEN;
        }
        let rms = (sum_sq / n as f64).sqrt();
        // 200 × 1000 samples but only 200 × 331 independent bins: relative s.d. of the
        // variance ≈ 1/√(66 200) ≈ 0.4 %, of the RMS half that; 2 % is > 5 s.d.
        assert!((rms / 0.5 - 1.0).abs() < 0.02, "RMS {rms}, expected 0.5");
    }
}
