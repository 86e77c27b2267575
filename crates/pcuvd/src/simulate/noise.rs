//! Band-limited white Gaussian receiver noise, one independent random stream per (event, channel).

use std::sync::Arc;

use num_complex::Complex32;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rustfft::{Fft, FftPlanner};

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
    /// `None` when the band holds no FFT bin.
    pub(crate) fn new(len: usize, fs: f64, band: (f64, f64), rms: f64, seed: u64) -> Option<Self> {
        let n_fft = len.next_power_of_two().max(64);
        let df = fs / n_fft as f64;
        let lo = ((band.0 / df).ceil() as usize).max(1);
        let hi = ((band.1 / df).floor() as usize).min((n_fft - 1) / 2);
        if lo > hi {
            return None;
        }
        // Re(IFFT) of unit complex Gaussians on m bins has per-sample variance m.
        let m = (hi - lo + 1) as f64;
        Some(NoiseGenerator {
            fft: FftPlanner::new().plan_fft_inverse(n_fft),
            n_fft,
            bins: lo..=hi,
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
