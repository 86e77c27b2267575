//! Compounded Doppler spectrograms at a pixel (paper Fig. 8b).

use super::*;

/// Settings of a compounded Doppler spectrogram (frames at the compound frame rate).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpectrogramParams {
    /// Frames per Hann-windowed FFT (≥ 2).
    pub window: usize,
    /// Frames between consecutive windows (≥ 1).
    pub step: usize,
    /// FFT length (≥ window; the window is zero-padded to it).
    pub nfft: usize,
}

impl SpectrogramParams {
    /// Matches [`DynamicsParams::rat`]: 36-frame (20 ms) windows every 9 frames (5 ms), so the
    /// spectrum and the vector velocity share a time axis; 128-point FFT (zero-padded ×3.6 for a
    /// smooth display; the resolution stays f_frame/36 = 50 Hz).
    pub fn rat() -> Self {
        SpectrogramParams {
            window: 36,
            step: 9,
            nfft: 128,
        }
    }

    /// Windows of `window_frames` frames every `step_frames` over a recording of `frames`
    /// frames, as the dynamics stage's windows, so that a spectrogram and the window speeds share
    /// a time axis. A recording shorter than four such windows takes windows of a quarter of its
    /// frames (at least 8, or all but one of them) every quarter window instead, so that a short
    /// recording still shows its flow over time. The FFT is twice the next power of two (at
    /// least 64 points): a smooth display, the resolution staying f_frame / window.
    pub fn for_windows(window_frames: usize, step_frames: usize, frames: usize) -> Result<Self> {
        if frames < 2 || window_frames < 2 {
            return Err(invalid(
                "spectrogram window",
                format!(
                    "{window_frames}-frame windows over {frames} frame(s): a Doppler spectrum \
                     needs at least 2 frames"
                ),
            ));
        }
        let (window, step) = if frames >= 4 * window_frames {
            (window_frames, step_frames.max(1))
        } else {
            let window = (frames / 4).max(8.min(frames - 1)).max(2);
            (window, (window / 4).max(1))
        };
        Ok(SpectrogramParams {
            window,
            step,
            nfft: (2 * window.next_power_of_two()).max(64),
        })
    }

    /// The centre (s from the first frame) of each window these settings take over `frames`
    /// frames at `frame_rate` (Hz); none when no window fits.
    pub fn window_centres(&self, frames: usize, frame_rate: f64) -> Vec<f64> {
        let windows = window_count(frames, self.window, self.step, frame_rate).unwrap_or(0);
        let half = (self.window - 1) as f64 / 2.0;
        (0..windows)
            .map(|k| ((k * self.step) as f64 + half) / frame_rate)
            .collect()
    }
}

impl Default for SpectrogramParams {
    /// [`SpectrogramParams::rat`].
    fn default() -> Self {
        Self::rat()
    }
}

/// A Doppler spectrogram at one pixel: power over (time, axial velocity).
#[derive(Debug, Clone, PartialEq)]
pub struct Spectrogram {
    /// Window centres (s) from the first frame.
    pub times_s: Vec<f64>,
    /// Axial velocity (m/s, positive = away from the probe) of each column, ascending, ≈ ±Nyquist.
    pub velocities_m_s: Vec<f64>,
    /// Power (dB re. the spectrogram's maximum, floored at −200 dB), shape (time, velocity).
    pub power_db: Array2<f64>,
    /// Mean axial velocity (m/s) of each window from its mean Doppler frequency (lag-1
    /// autocorrelation phase, Kasai): the colour-Doppler estimate.
    pub mean_velocity_m_s: Vec<f64>,
    /// Nyquist axial velocity (m/s) of the compounded series.
    pub nyquist_m_s: f64,
}

impl Spectrogram {
    /// This spectrogram with its velocities turned from Doppler frequency at `frequency_hz` (Hz;
    /// the pixel's mean RF frequency, as a Loupas estimate measures it:
    /// [`crate::pipeline::ProcessOutput::mean_frequency_at`]) instead of the demodulation
    /// frequency `demodulation_hz` (Hz) it was computed at: velocity goes as 1 / frequency. The
    /// nominal frequency reads the flow slow by f̄ / f_0 where attenuation has lowered the echo's
    /// spectrum.
    pub fn at_frequency(mut self, demodulation_hz: f64, frequency_hz: f64) -> Self {
        let scale = demodulation_hz / frequency_hz;
        self.velocities_m_s.iter_mut().for_each(|v| *v *= scale);
        self.mean_velocity_m_s.iter_mut().for_each(|v| *v *= scale);
        self.nyquist_m_s *= scale;
        self
    }
}

/// Compounded Doppler spectrogram at pixel `pixel` = (iz, ix) (paper Fig. 8b): the angles' series
/// are summed (coherent compounding), then Hann-windowed FFTs over slow time in sliding windows.
///
/// Doppler frequency f (Hz) maps to axial velocity Vz = −c·f/(f0·(1 + mean cos θ)) (m/s): the
/// compounded echo path changes by Vz·(1 + mean cos θ) (+ Vx·mean sin θ, zero for symmetric angle
/// sets), as in the pipeline's colour Doppler, with the images' sound speed and demodulation
/// frequency f0; the slow-time rate is their frame rate.
pub fn spectrogram(
    images: &AngleImages,
    pixel: (usize, usize),
    params: &SpectrogramParams,
) -> Result<Spectrogram> {
    check_rates(images)?;
    let (nz, nx, frames) = check_series(&images.series, &images.angles)?;
    let (iz, ix) = pixel;
    if iz >= nz || ix >= nx {
        return Err(invalid(
            "pixel",
            format!("({iz}, {ix}) is outside the {nz} × {nx} image"),
        ));
    }
    let kept = crate::form::images::PixelSeries::of(images, &[pixel], 0..frames)?;
    spectrogram_of_kept(&kept, 0, images, params)?.ok_or_else(|| {
        invalid(
            "pixel",
            format!("({iz}, {ix}) has no Doppler signal (its compounded series is zero)"),
        )
    })
}

/// The images' frame rate, sound speed and demodulation frequency, each positive.
fn check_rates(images: &AngleImages) -> Result<()> {
    require_positive("frame rate", images.frame_rate)?;
    require_positive("speed of sound", images.sound_speed)?;
    require_positive("centre frequency", images.demodulation_frequency)
}

/// [`spectrogram`] of pixel `k` of `kept` (the clutter-filtered series of a few pixels, as a
/// segmented run keeps them) of images described by `images` (their angles, frame rate, sound
/// speed and demodulation frequency; their own series may be gone); `None` when the pixel's
/// compounded series is zero (no Doppler signal to show). Each window reads the frames of the
/// segment whose core holds its start, across the seams of `kept` (see
/// [`crate::form::images::Seam`]), so that it sees one clutter filter.
pub fn spectrogram_of_kept(
    kept: &crate::form::images::PixelSeries,
    k: usize,
    images: &AngleImages,
    params: &SpectrogramParams,
) -> Result<Option<Spectrogram>> {
    spectrogram_of_gate(kept, &[k], images, params)
}

/// [`spectrogram_of_kept`] over a sample volume, the pixels `gate` of `kept` (as a scanner's
/// pulsed-wave gate): each window's power spectra summed over them and its mean velocity read from
/// their summed lag-1 autocorrelation, so that each pixel counts with its echo power and the
/// speckle's window-to-window jitter averages out. One pixel is [`spectrogram_of_kept`]'s to
/// the bit. `None` when every pixel's compounded series is zero.
pub fn spectrogram_of_gate(
    kept: &crate::form::images::PixelSeries,
    gate: &[usize],
    images: &AngleImages,
    params: &SpectrogramParams,
) -> Result<Option<Spectrogram>> {
    check_rates(images)?;
    let Some(&first) = gate.first() else {
        return Err(invalid("gate", "a spectrogram needs at least one pixel"));
    };
    let angles = &images.angles;
    if angles.is_empty() {
        return Err(invalid("angles", "a spectrogram needs at least one angle"));
    }
    let (frame_rate, sound_speed) = (images.frame_rate, images.sound_speed);
    let frames = kept.compound(first)?.len();
    let n_windows = window_count(frames, params.window, params.step, frame_rate)?;
    if params.nfft < params.window {
        return Err(invalid(
            "FFT length",
            format!(
                "{} is shorter than the window of {} frames",
                params.nfft, params.window
            ),
        ));
    }
    let mut silent = true;
    for &k in gate {
        silent &= kept.compound(k)?.iter().all(|v| v.norm_sqr() == 0.0);
    }
    if silent {
        return Ok(None);
    }
    let center_frequency = images.demodulation_frequency;
    let mean_cos = angles.iter().map(|a| a.cos()).sum::<f64>() / angles.len() as f64;
    // Axial velocity per Hz of Doppler frequency.
    let per_hz = -sound_speed / (center_frequency * (1.0 + mean_cos));
    let scale = doppler::velocity_scale(sound_speed, frame_rate, center_frequency)?;
    let nfft = params.nfft;
    let hann: Vec<f64> = (0..params.window)
        .map(|t| {
            0.5 - 0.5 * (2.0 * std::f64::consts::PI * t as f64 / (params.window - 1) as f64).cos()
        })
        .collect();
    let fft = FftPlanner64::new().plan_fft_forward(nfft);

    let mut power = Array2::<f64>::zeros((n_windows, nfft));
    let mut mean_velocity = Vec::with_capacity(n_windows);
    let mut buffer = vec![Complex64::new(0.0, 0.0); nfft];
    for column in 0..n_windows {
        let start = column * params.step;
        let mut r1 = Complex64::new(0.0, 0.0);
        for &k in gate {
            let frames_k = &kept.compound_window(k, start..start + params.window)?;
            buffer.fill(Complex64::new(0.0, 0.0));
            for ((b, &x), &w) in buffer.iter_mut().zip(frames_k).zip(&hann) {
                *b = x * w;
            }
            fft.process(&mut buffer);
            // Bin j of the fftshifted spectrum has frequency (j − nfft/2)·f_frame/nfft; velocity
            // falls as frequency rises, so column c = nfft − 1 − j ascends in velocity.
            for j in 0..nfft {
                let bin = (j + nfft.div_ceil(2)) % nfft;
                power[[column, nfft - 1 - j]] += buffer[bin].norm_sqr();
            }
            r1 += frames_k
                .windows(2)
                .map(|p| p[0].conj() * p[1])
                .sum::<Complex64>();
        }
        let v_proj = doppler::lag_velocity(r1, scale);
        mean_velocity.push(2.0 * v_proj / (1.0 + mean_cos));
    }
    let velocities_m_s: Vec<f64> = (0..nfft)
        .map(|c| {
            let j = nfft - 1 - c;
            let f = (j as f64 - (nfft / 2) as f64) * frame_rate / nfft as f64;
            f * per_hz
        })
        .collect();
    let peak = power.iter().copied().fold(0.0, f64::max);
    let power_db = power.mapv(|p| power_to_db((p / peak).max(1e-20)));
    Ok(Some(Spectrogram {
        times_s: params.window_centres(frames, frame_rate),
        velocities_m_s,
        power_db,
        mean_velocity_m_s: mean_velocity,
        nyquist_m_s: 0.5 * frame_rate * per_hz.abs(),
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lower_frequency_reads_faster_by_the_ratio() {
        let spec = Spectrogram {
            times_s: vec![0.01],
            velocities_m_s: vec![-0.02, 0.0, 0.02],
            power_db: ndarray::array![[-10.0, 0.0, -10.0]],
            mean_velocity_m_s: vec![0.005],
            nyquist_m_s: 0.03,
        };
        let lower = spec.clone().at_frequency(15e6, 12e6);
        assert_eq!(lower.velocities_m_s, [-0.025, 0.0, 0.025]);
        assert_eq!(lower.mean_velocity_m_s, [0.00625]);
        assert!((lower.nyquist_m_s - 0.0375).abs() < 1e-15);
        assert_eq!(
            (lower.times_s, lower.power_db),
            (spec.times_s, spec.power_db)
        );
    }

    #[test]
    fn windows_of_the_rat_recording_are_the_rat_spectrogram() {
        // 20 ms and 5 ms at the rat's 1.8 kHz: 36 and 9 frames.
        assert_eq!(
            SpectrogramParams::for_windows(36, 9, 360).unwrap(),
            SpectrogramParams::rat()
        );
    }

    #[test]
    fn a_short_recording_takes_shorter_windows() {
        // The rotating disk: 32 frames at 10 kHz, where 20 ms would be 200 frames.
        let disk = SpectrogramParams::for_windows(200, 50, 32).unwrap();
        assert_eq!((disk.window, disk.step, disk.nfft), (8, 2, 64));
        // rat-brain-small: 48 frames at 1.8 kHz.
        let small = SpectrogramParams::for_windows(36, 9, 48).unwrap();
        assert_eq!((small.window, small.step), (12, 3));
        // Four windows fit: the dynamics windows as given (a zero step is one frame).
        let fits = SpectrogramParams::for_windows(100, 0, 400).unwrap();
        assert_eq!((fits.window, fits.step, fits.nfft), (100, 1, 256));
        // Two frames: one window of both.
        let two = SpectrogramParams::for_windows(36, 9, 2).unwrap();
        assert_eq!((two.window, two.step), (2, 1));
        let five = SpectrogramParams::for_windows(36, 9, 5).unwrap();
        assert_eq!((five.window, five.step), (4, 1));
        let error = SpectrogramParams::for_windows(36, 9, 1).unwrap_err();
        assert!(error.to_string().contains("at least 2 frames"), "{error}");
    }
}
