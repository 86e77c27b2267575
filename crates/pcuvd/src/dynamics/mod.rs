//! Dynamics over the cardiac cycle (paper §2.2 eq. 16, §4 Fig. 8): sliding-window vector Doppler,
//! cardiac cycles, peak-systolic / end-diastolic velocities, resistivity-index (RI) maps,
//! arteriole/venule classes and compounded Doppler spectrograms.
//!
//! Data flow: the clutter-filtered per-angle IQ series (nz, nx, frames) are cut into windows of
//! `window` frames, `step` frames apart ([`sliding_vectors`]); each window gives per-angle lag-1
//! autocorrelations → projections V_θ → (Vx, Vz) (the same estimators as [`crate::estimate::vector`];
//! one angle gives its colour-Doppler velocity alone, and RI of its magnitude). The
//! spatial mean speed over vessel pixels gives the cardiac period and the cycles ([`find_cycles`]);
//! per pixel, PSV is the largest speed of each cycle and EDV the smallest (end-diastole: the
//! minimum just before the next systolic upstroke), both averaged over the complete cycles in the
//! recording; RI = (PSV − EDV)/PSV ([`resistivity_index`], eq. 16) classifies arterioles
//! (RI ≥ 0.55) and venules (RI ≤ 0.5) ([`ri_maps`]).
//!
//! A recording must hold at least one complete cardiac cycle (of window centres): a shorter one
//! is refused with an error that says how long it is and how long a cycle is, never answered with
//! a map of zeros. The cycles come from trigger times given with the recording (ECG R-waves), a
//! given heart rate, or the data ([`cardiac_cycles`]): beat to beat between systolic upstrokes on
//! long recordings, one period from the autocorrelation (≳ 1.5 cycles), or between the two
//! upstrokes of a recording a little longer than one cycle. The paper's 0.2 s rat recordings
//! (≈ 1.1 cycles) usually hold one upstroke: give the heart rate. Over several cycles, the spread
//! across cycles of PSV, EDV and RI is measured too.
//!
//! Files: `windows` (sliding-window vectors), `vessels` (whole-recording vessel tests), `pooling`
//! (vessel pooling), `harmonics` (cardiac-harmonic fit), `cycles` (heart rate, cycles, PSV/EDV),
//! `ri` (RI maps and classes), `spectrogram`; the settings live here.

use faer::Mat;
use ndarray::{Array2, Array3, Axis, s};
use num_complex::{Complex32, Complex64};
use pcuvd_fft::FftPlanner64;
use rayon::prelude::*;

use crate::core::error::{Error, Result, invalid, require_positive};
use crate::core::units::power_to_db;
use crate::estimate::dealias::{self, Dealias};
use crate::estimate::doppler;
use crate::estimate::vector::{self, Estimator, IrlsParams};
use crate::form::images::AngleImages;

// The class codes are shared with the phantoms' ground truth, which must not depend on this stage.
pub use crate::core::vessel::{ARTERIOLE, BACKGROUND, UNDETERMINED, VENULE};

mod cycles;
mod harmonics;
mod pooling;
mod ri;
mod spectrogram;
mod vessels;
mod windows;

pub use cycles::*;
pub use harmonics::*;
pub use pooling::*;
pub use ri::*;
pub use spectrogram::*;
pub use vessels::*;
pub use windows::*;

/// Spatial averaging (rows, cols pixels) of each window's autocorrelation for RI maps: 0.25 mm at
/// a 0.05 mm grid. A 20 ms window sees few speckle renewals, so per-pixel window speeds jitter
/// and the extremes of a jittery waveform inflate RI; a small box cuts the jitter at the cost of
/// resolution across thin vessels.
pub const RI_KERNEL: (usize, usize) = (5, 5);

/// Default of [`DynamicsParams::debias_harmonics`]. A slow vein (2–5 mm/s) crosses a resolution
/// cell in tens of milliseconds, so a 20 ms window sees little of its speckle renew and its speed
/// jitters from window to window (by 30–60 % on the virtual rat brain, with or without tissue); a
/// fit of two harmonics to one cardiac cycle of that jitter reads RI 0.2–0.6 where the vein is
/// steady. Debiased, its venules read 0.00 (truth 0.03–0.06) while the vessel network's pulsatile
/// veins and arterioles keep their RI.
pub const DEBIAS_HARMONICS: bool = true;

/// Default sliding-window length (s): 36 frames at the rat's 1.8 kHz ([`DynamicsParams::rat`]).
pub const DEFAULT_WINDOW_S: f64 = 20e-3;

/// Default time between window starts (s): a quarter window.
pub const DEFAULT_STEP_S: f64 = 5e-3;

/// Lowest and highest heart rates (Hz) searched when the rate is measured from the data.
pub const HEART_RATE_SEARCH_HZ: (f64, f64) = (3.0, 15.0);

/// Settings of the dynamics stage (windows in frames at the compound frame rate).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DynamicsParams {
    /// Frames per sliding window (≥ 2; lag-1 pairs per window = window − 1).
    pub window: usize,
    /// Frames between consecutive window starts (≥ 1).
    pub step: usize,
    /// Heart rate (Hz) if known; `None` measures it from the data ([`cardiac_cycles`]).
    pub heart_rate_hz: Option<f64>,
    /// Vector estimator applied in every window (LS = UVD, IRLS = PC-UVD).
    pub estimator: Estimator,
    /// Vector dealiasing of every window ([`crate::estimate::dealias`]; auto decides in each window);
    /// systole beyond the Nyquist velocity needs it for RI.
    pub dealias: Dealias,
    /// Spatial averaging box (rows, cols) of each window's autocorrelation; odd sizes.
    pub kernel: (usize, usize),
    /// Which frequency scales each window's Doppler phase ([`doppler::DopplerEstimator`]).
    pub doppler: doppler::DopplerEstimator,
    /// Smallest RI (dimensionless) of an arteriole (paper: arterioles 0.55–0.9).
    pub artery_ri_min: f64,
    /// Largest RI (dimensionless) of a venule (paper: venules < 0.5).
    pub vein_ri_max: f64,
    /// Vessel threshold (dB re. the brightest pixel's time-mean power); pixels below are background.
    pub min_power_db: f64,
    /// Cardiac harmonics of the Fourier series fitted (least squares) to each pixel's speed
    /// series before PSV and EDV are read from it: `Some(0)` reads the raw window samples, `None`
    /// picks [`auto_harmonics`]. The largest and smallest of noisy samples are biased outward
    /// (PSV up, EDV down), which inflates RI most where it is small (venules); the fit keeps the
    /// waveform and drops the window-to-window estimation noise.
    pub harmonics: Option<usize>,
    /// Debiases the fitted harmonics for the windows' estimation noise before PSV and EDV are read
    /// (see [`harmonics`]'s `debiased`): each harmonic's power less the noise's share, so that a
    /// steady vessel's jitter does not read as a pulse.
    pub debias_harmonics: bool,
    /// Pools each pixel's normalised waveform with those of its same-vessel neighbours before PSV
    /// and EDV are read ([`VesselPooling`]); `None` reads every pixel alone.
    pub pooling: Option<VesselPooling>,
    /// Moves each window's projections from their cells' power centroids back to their pixels
    /// before the vector fit ([`crate::estimate::partial_volume`]; each angle's cell measured once on the
    /// whole series; with a `kernel`, each window's reading is the power-weighted mean of its
    /// pixels' centroids).
    pub partial_volume: bool,
}

impl DynamicsParams {
    /// The paper's rat brain setting (1.8 kHz compound rate, 360 frames = 0.2 s, heart ≈ 5–6 Hz).
    ///
    /// - `window` = 36 frames (20 ms, ≈ 1/9 of a 5.5 Hz cycle): 35 lag-1 pairs keep the phase
    ///   standard deviation of R ≈ 1/√(35·SNR), a few hundredths of a radian at the SNR of
    ///   clutter-filtered small vessels, while a 20 ms boxcar attenuates the cardiac fundamental by
    ///   only sinc(5.5 Hz · 20 ms) ≈ 0.98, so systole is resolved.
    /// - `step` = 9 frames (5 ms): a quarter window (75 % overlap), ≈ 36 samples per cycle, enough
    ///   to place the systolic peak within ±2.5 ms (cos(2π·5.5·2.5 ms) ≈ 0.995 of its height).
    /// - `heart_rate_hz` = 5.5 Hz (≈ 330 bpm, anaesthetised rat): 0.2 s holds only ≈ 1.1 cycles,
    ///   too few to measure the period from the data, so the preset supplies it; set `None` for
    ///   recordings of two cycles or more.
    /// - `estimator` = IRLS with the paper's λ = 0.01 mm/s (PC-UVD), no dealiasing; `kernel` =
    ///   (1, 1) (no spatial averaging: small vessels are a few pixels wide); `doppler` = the
    ///   library's default Doppler estimator (Loupas: the measured mean frequency).
    /// - `artery_ri_min` = 0.55, `vein_ri_max` = 0.5 (paper §4 and its ref. 29).
    /// - `min_power_db` = −30 dB: about the displayed dynamic range of the paper's power Doppler
    ///   images (Fig. 6); below it the speed is mostly noise and its RI meaningless.
    /// - `harmonics` = automatic ([`auto_harmonics`]: 2 at 5.5 Hz with 20 ms windows), debiased
    ///   for the noise by default ([`DEBIAS_HARMONICS`]).
    pub fn rat() -> Self {
        DynamicsParams {
            window: 36,
            step: 9,
            heart_rate_hz: Some(5.5),
            estimator: Estimator::Irls(IrlsParams::default()),
            dealias: Dealias::Off,
            kernel: (1, 1),
            doppler: doppler::DopplerEstimator::default(),
            artery_ri_min: 0.55,
            vein_ri_max: 0.5,
            min_power_db: -30.0,
            harmonics: None,
            debias_harmonics: DEBIAS_HARMONICS,
            pooling: None,
            partial_volume: false,
        }
    }

    /// True when `other` forms the same velocity windows ([`sliding_vectors`]) as `self`: they
    /// differ at most in what the RI maps read from the windows (heart rate, RI thresholds,
    /// vessel threshold, harmonics, pooling), so the windows of one stand for the other's.
    pub fn forms_the_same_windows(&self, other: &Self) -> bool {
        // Every field not named here is compared: a setting added later counts as the windows'
        // until it is known not to be.
        let windows_only = |p: &Self| DynamicsParams {
            heart_rate_hz: None,
            artery_ri_min: 0.0,
            vein_ri_max: 0.0,
            min_power_db: 0.0,
            harmonics: None,
            debias_harmonics: false,
            pooling: None,
            ..*p
        };
        windows_only(self) == windows_only(other)
    }

    /// Checks every setting against the compound frame rate `frame_rate` (Hz).
    pub fn validate(&self, frame_rate: f64) -> Result<()> {
        require_positive("frame rate", frame_rate)?;
        check_window_step(self.window, self.step)?;
        if self.kernel.0 % 2 != 1 || self.kernel.1 % 2 != 1 {
            return Err(invalid(
                "Doppler averaging kernel",
                format!("sizes must be odd, got {:?}", self.kernel),
            ));
        }
        self.validate_thresholds()?;
        if let Some(hr) = self.heart_rate_hz {
            check_heart_rate(hr, frame_rate, self.window, self.step)?;
        }
        Ok(())
    }

    /// Checks the RI thresholds and the vessel power threshold (dB).
    pub fn validate_thresholds(&self) -> Result<()> {
        if !(self.artery_ri_min.is_finite()
            && self.vein_ri_max.is_finite()
            && self.vein_ri_max <= self.artery_ri_min)
        {
            return Err(invalid(
                "RI thresholds",
                format!(
                    "need finite vein_ri_max ≤ artery_ri_min, got vein_ri_max = {} and artery_ri_min = {}",
                    self.vein_ri_max, self.artery_ri_min
                ),
            ));
        }
        if let Some(pooling) = self.pooling {
            pooling.check()?;
        }
        if !(self.min_power_db.is_finite() && self.min_power_db <= 0.0) {
            return Err(invalid(
                "vessel power threshold",
                format!(
                    "must be finite and ≤ 0 dB (re. the brightest pixel), got {:?} dB",
                    self.min_power_db
                ),
            ));
        }
        Ok(())
    }

    /// Checks, before any processing, that a recording of `n_frames` frames at `frame_rate`
    /// (Hz) can give RI with these windows: at least 2 windows (the speed waveform RI is read
    /// from), and one cardiac cycle within them, of the given heart rate or, with neither a
    /// heart rate nor cycle start times (`cycles_given`), of the fastest rate the data are
    /// searched for ([`HEART_RATE_SEARCH_HZ`]; a slower heart needs a longer recording, which
    /// only the data can tell).
    pub fn check_recording(
        &self,
        n_frames: usize,
        frame_rate: f64,
        cycles_given: bool,
    ) -> Result<()> {
        require_positive("frame rate", frame_rate)?;
        let n_windows = window_count(n_frames, self.window, self.step, frame_rate)?;
        let ms = |frames: usize| frames as f64 / frame_rate * 1e3;
        if n_windows < 2 {
            return Err(invalid(
                "windows",
                format!(
                    "the recording's {n_frames} frames ({:.1} ms) hold 1 window of {} frames \
                     ({:.1} ms) at a step of {} frames ({:.1} ms); RI is read from a speed \
                     waveform of at least 2 windows: shorten the windows or their step, or record longer",
                    ms(n_frames),
                    self.window,
                    ms(self.window),
                    self.step,
                    ms(self.step),
                ),
            ));
        }
        let dt = self.step as f64 / frame_rate;
        if let Some(hr) = self.heart_rate_hz {
            cycle_length(n_windows, dt, hr)?;
        } else if !cycles_given {
            let fastest = HEART_RATE_SEARCH_HZ.1;
            // Two systolic upstrokes at least one fastest period apart: the least the data can
            // give a cycle from.
            let span = (n_windows - 1) as f64 * dt;
            if span < 1.0 / fastest {
                return Err(invalid(
                    "recording",
                    format!(
                        "its {n_windows} windows span {:.1} ms, shorter than one cardiac cycle \
                         at {fastest} Hz ({:.1} ms), the fastest heart rate measured from the \
                         data: give the heart rate, or record at least one whole cycle",
                        span * 1e3,
                        1e3 / fastest
                    ),
                ));
            }
        }
        Ok(())
    }
}

impl Default for DynamicsParams {
    /// The paper's rat setting, [`DynamicsParams::rat`].
    fn default() -> Self {
        Self::rat()
    }
}

fn check_window_step(window: usize, step: usize) -> Result<()> {
    if window < 2 {
        return Err(invalid(
            "window",
            format!("needs at least 2 frames for a lag-1 autocorrelation, got {window}"),
        ));
    }
    if step == 0 {
        return Err(invalid("step", "must be at least 1 frame, got 0"));
    }
    Ok(())
}

/// A heart rate fits when its period spans ≥ 2 windows (a window must not blur systole into
/// diastole) and ≥ 2 steps (below the Nyquist rate of the window series).
fn check_heart_rate(hr: f64, frame_rate: f64, window: usize, step: usize) -> Result<()> {
    require_positive("heart rate", hr)?;
    let period_frames = frame_rate / hr;
    if period_frames < 2.0 * window as f64 {
        let way_out = way_out_of_a_short_period(hr, || {
            format!(
                "use a window of at most {} frames",
                (period_frames / 2.0).floor()
            )
        });
        return Err(invalid(
            "heart rate",
            format!(
                "{hr} Hz has a period of {period_frames:.1} frames at {frame_rate} Hz, shorter than \
                 2 windows of {window} frames: each window would blur systole into diastole; \
                 {way_out}"
            ),
        ));
    }
    if period_frames < 2.0 * step as f64 {
        return Err(invalid(
            "heart rate",
            format!(
                "{hr} Hz is above the Nyquist rate {:.2} Hz of windows {step} frames apart at \
                 {frame_rate} Hz",
                frame_rate / (2.0 * step as f64)
            ),
        ));
    }
    Ok(())
}

/// A heart rate (Hz) fits windows of `window_s` seconds when its period spans at least 2 windows.
fn check_period_vs_window(hr: f64, window_s: f64) -> Result<()> {
    if 1.0 / hr < 2.0 * window_s {
        return Err(invalid(
            "heart rate",
            format!(
                "{hr:.2} Hz has a period of {:.1} ms, shorter than 2 windows of {:.1} ms: each \
                 window would blur systole into diastole; {}",
                1e3 / hr,
                window_s * 1e3,
                way_out_of_a_short_period(hr, || "shorten the window".into())
            ),
        ));
    }
    Ok(())
}

/// What to do about a heart rate `hr` (Hz) whose period is shorter than two windows: what
/// `shorter_windows` says, unless no heart beats that fast (above 25 Hz; a mouse's, the fastest
/// studied, beats 10–14 times a second), where the rate was given in beats per minute.
fn way_out_of_a_short_period(hr: f64, shorter_windows: impl FnOnce() -> String) -> String {
    if hr > 25.0 {
        format!(
            "the heart rate is in Hz ({hr} beats per minute would be {:.2} Hz)",
            hr / 60.0
        )
    } else {
        shorter_windows()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Both checks of a heart rate against the windows, in frames and in seconds, say that a
    /// rate above any heart's was given in beats per minute, and otherwise how to shorten the
    /// windows.
    #[test]
    fn a_heart_rate_above_any_hearts_is_taken_for_beats_per_minute() {
        let said = |r: Result<()>| r.unwrap_err().to_string();
        let bpm = "the heart rate is in Hz (330 beats per minute would be 5.50 Hz)";
        assert!(said(check_heart_rate(330.0, 1000.0, 20, 5)).ends_with(bpm));
        assert!(said(check_period_vs_window(330.0, 0.02)).ends_with(bpm));
        let fast = said(check_heart_rate(20.0, 1000.0, 30, 5));
        assert!(
            fast.ends_with("use a window of at most 25 frames"),
            "{fast}"
        );
        let fast = said(check_period_vs_window(20.0, 0.03));
        assert!(fast.ends_with("shorten the window"), "{fast}");
    }
}
