//! Dynamics over the cardiac cycle (paper §2.2 eq. 16, §4 Fig. 8): sliding-window vector Doppler,
//! cardiac cycles, peak-systolic / end-diastolic velocities, resistivity-index (RI) maps,
//! arteriole/venule classes and compounded Doppler spectrograms.
//!
//! Data flow: the clutter-filtered per-angle IQ series (nz, nx, frames) are cut into windows of
//! `window` frames, `step` frames apart ([`sliding_vectors`]); each window gives per-angle lag-1
//! autocorrelations → projections V_θ → (Vx, Vz) (the same estimators as [`crate::vector`]). The
//! spatial mean speed over vessel pixels gives the cardiac period and the cycles ([`find_cycles`]);
//! per pixel, PSV is the largest speed of each cycle and EDV the smallest (end-diastole: the
//! minimum just before the next systolic upstroke), both averaged over the complete cycles in the
//! recording; RI = (PSV − EDV)/PSV ([`resistivity_index`], eq. 16) classifies arterioles
//! (RI ≥ 0.55) and venules (RI ≤ 0.5) ([`ri_maps`]).
//!
//! A recording must hold at least one complete cardiac cycle (of window centres): a shorter one
//! is refused with an error that says how long it is and how long a cycle is, never answered with
//! a map of zeros. Measuring the heart rate from the data needs about 1.5 cycles or more; for the
//! paper's 0.2 s rat recordings (≈ 1.1 cycles) give the heart rate.

use faer::Mat;
use faer::linalg::solvers::SolveLstsq;
use ndarray::{Array2, Array3, ArrayView3, Axis, s};
use num_complex::{Complex32, Complex64};
use rayon::prelude::*;
use rustfft::FftPlanner;

use crate::doppler;
use crate::error::{Error, Result, invalid, require_positive};
use crate::vector::{self, Estimator, IrlsParams};

/// Vessel class code of a background pixel (power below `min_power_db`).
pub const BACKGROUND: u8 = 0;
/// Vessel class code of an arteriole (RI ≥ `artery_ri_min`).
pub const ARTERIOLE: u8 = 1;
/// Vessel class code of a venule (RI ≤ `vein_ri_max`).
pub const VENULE: u8 = 2;
/// Vessel class code of a vessel pixel whose RI is between the thresholds or undefined.
pub const UNDETERMINED: u8 = 3;

/// Default margin (dB) above the noise floor of the recording's power Doppler
/// ([`crate::doppler::above_noise_floor`]) of a vessel pixel for [`ri_maps_where`]. Why: the power
/// of a 20 ms window is too unsteady to tell noise from weak flow, so a window threshold alone lets
/// in many noise pixels around the lumens, and a noise pixel that joins a pool flattens its
/// waveform (lowers its RI). The recording's power Doppler averages over every frame, and a margin
/// above its noise floor removes those pixels. The margin is kept low because attenuation lowers
/// the echoes, not the noise, with depth: the deep vessels of a low-SNR recording stand only a few
/// dB above the noise floor, and a larger margin drops them first.
pub const VESSEL_MARGIN_DB: f64 = 3.0;

/// Default for [`VesselTests::local_db`]: a vessel pixel's power Doppler is within 20 dB of the
/// brightest pixel around it ([`crate::doppler::near_local_peak`]).
pub const VESSEL_LOCAL_DB: f64 = 20.0;

/// Default for [`VesselTests::local_radius_m`] (m): the half-width of the square searched for
/// the local peak, about the reach of a vessel's side-lobe haze in plane-wave images.
pub const VESSEL_LOCAL_RADIUS_M: f64 = 1.0e-3;

/// Whole-recording tests a pixel's power Doppler must pass to count as a vessel in the RI maps
/// (as well as each window's power test, [`DynamicsParams::min_power_db`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VesselTests {
    /// dB above the noise floor of its depth ([`crate::doppler::above_noise_floor`]); −∞: off.
    pub margin_db: f64,
    /// dB below the brightest pixel within `local_radius_m` at most
    /// ([`crate::doppler::near_local_peak`]), which drops the side-lobe haze around bright
    /// vessels in clean recordings; +∞: off.
    pub local_db: f64,
    /// Half-width (m) of the square around the pixel searched for its local peak.
    pub local_radius_m: f64,
}

impl Default for VesselTests {
    fn default() -> Self {
        VesselTests {
            margin_db: VESSEL_MARGIN_DB,
            local_db: VESSEL_LOCAL_DB,
            local_radius_m: VESSEL_LOCAL_RADIUS_M,
        }
    }
}

impl VesselTests {
    /// Refuses a NaN margin or local level, and a local radius that is negative or not finite.
    pub fn validate(&self) -> Result<()> {
        if self.margin_db.is_nan() {
            return Err(invalid("vessel margin", "must be a number of dB (or off)"));
        }
        if self.local_db.is_nan() || self.local_db < 0.0 {
            return Err(invalid(
                "vessel local level",
                format!("must be ≥ 0 dB (or off), got {}", self.local_db),
            ));
        }
        if !(self.local_radius_m.is_finite() && self.local_radius_m >= 0.0) {
            return Err(invalid(
                "vessel local radius",
                format!("must be ≥ 0 m, got {}", self.local_radius_m),
            ));
        }
        Ok(())
    }

    /// The pixels of `power` (nz, nx), a power-Doppler image on a grid of `grid_step_m` (m), that
    /// pass both tests: the `flow` mask of [`ri_maps_where`].
    pub fn flow_mask(&self, power: &Array2<f64>, grid_step_m: f64) -> Array2<bool> {
        let mut mask = doppler::above_noise_floor(power, self.margin_db);
        if self.local_db.is_finite() {
            // A radius beyond the image searches the whole image (and cannot overflow).
            let widest = power.nrows().max(power.ncols()) as f64;
            let radius = (self.local_radius_m / grid_step_m)
                .round()
                .clamp(0.0, widest) as usize;
            let local = doppler::near_local_peak(power, radius, self.local_db);
            mask.zip_mut_with(&local, |m, &l| *m &= l);
        }
        mask
    }
}

/// Lowest and highest heart rates (Hz) searched when the rate is measured from the data.
pub const HEART_RATE_SEARCH_HZ: (f64, f64) = (3.0, 15.0);

/// Settings of the dynamics stage (windows in frames at the compound frame rate).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DynamicsParams {
    /// Frames per sliding window (≥ 2; lag-1 pairs per window = window − 1).
    pub window: usize,
    /// Frames between consecutive window starts (≥ 1).
    pub step: usize,
    /// Heart rate (Hz) if known; `None` measures it from the data (needs ≳ 1.5 cycles).
    pub heart_rate_hz: Option<f64>,
    /// Vector estimator applied in every window (LS = UVD, IRLS = PC-UVD).
    pub estimator: Estimator,
    /// Spatial averaging box (rows, cols) of each window's autocorrelation; odd sizes.
    pub kernel: (usize, usize),
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
    /// Pools each pixel's normalised waveform with those of its same-vessel neighbours before PSV
    /// and EDV are read ([`VesselPooling`]); `None` reads every pixel alone.
    pub pooling: Option<VesselPooling>,
}

/// Which neighbours share a pixel's cardiac waveform: those within an ellipse centred on the pixel
/// and aligned with its time-mean flow direction (half-length `along` down the vessel, half-width
/// `across` it), whose own time-mean flow direction is within `max_angle` of the pixel's.
///
/// Why: RI = 1 − EDV/PSV does not change when a waveform is scaled, and across a vessel's lumen
/// the velocity profile scales the waveform without changing its shape, so every pixel of a
/// vessel segment carries the same normalised waveform. Along the vessel the waveform is the same
/// too: the pulse wave travels at metres per second, so over millimetres it arrives within
/// microseconds. Averaging the normalised waveform over N neighbours divides the window-to-window
/// jitter by about √N without biasing RI. The pooled waveform is the weighted sum of the
/// neighbours' speed series over the same weighted sum of their time means, with weights the
/// square of each pixel's time-mean Doppler power: pixels at the edge of the vessel mask that
/// hold mostly noise have a large mean |V| and a flat waveform, and with plain weights they would
/// flatten the pool (lower its RI), most of all in deep, low-SNR vessels.
///
/// The neighbourhood is long and narrow because a vessel is: a disc holds few pixels of a thin
/// vessel and many of whatever lies beside it. Down the vessel it gathers the pixels that share
/// the waveform, including those with a better view (near the lateral edges of the field some
/// steering angles miss the pixel, and its lateral velocity is noisier); across it stops within
/// a lumen and its blur, so a parallel vessel farther than `across` is never mixed in, even when
/// it flows the same way. Flow direction tells apart what the ellipse still reaches: an arteriole
/// and a venule side by side flow opposite ways (the common case in the cortex, penetrating
/// arterioles down and venules up), and vessels that cross meet at an angle.
///
/// Pooling averages speeds |V|, so it cuts the jitter but keeps the noise bias of |V| (the Rice
/// mean, about |V| + σ²/2|V| for errors σ per component), which raises EDV more than PSV and
/// lowers RI. Pooling the velocity vectors before |V| removes that bias, but on the
/// vessel-network phantom it classed fewer pixels rightly than pooling speeds (the slow, oblique
/// venules read a higher RI), so speeds are pooled.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VesselPooling {
    /// Half-length (pixels) of the neighbourhood along the pixel's time-mean flow direction.
    pub along: f64,
    /// Half-width (pixels) of the neighbourhood across the pixel's time-mean flow direction.
    pub across: f64,
    /// Largest angle (rad) between the time-mean flow directions of the pixel and a neighbour.
    pub max_angle: f64,
}

impl VesselPooling {
    /// Default half-length (m) along the flow: 2 mm, so a pool holds up to 4 mm of a vessel
    /// segment; bends sharper than `max_angle` over that length end the pool.
    pub const DEFAULT_ALONG_M: f64 = 2.0e-3;
    /// Default half-width (m) across the flow: 0.25 mm, a little more than the radius of the
    /// rat's small vessels (0.15–0.2 mm), so that the pool spans one lumen and its blur but not a
    /// parallel neighbour. Chosen on the vessel-network phantom against discs and other ellipses,
    /// and checked on a seed held out while choosing (the README's network study).
    pub const DEFAULT_ACROSS_M: f64 = 0.25e-3;
    /// Default largest flow-direction difference (degrees) between pooled pixels.
    pub const DEFAULT_MAX_ANGLE_DEG: f64 = 30.0;

    /// Pooling within an ellipse of half-length `along_m` (m) down the flow and half-width
    /// `across_m` (m) across it, on a grid of `grid_step_m` (m) pixels, among neighbours whose
    /// mean flow directions differ by at most `max_angle_deg` (degrees); `None` when both are
    /// below half a pixel (nothing to pool but the pixel itself).
    pub fn from_metres(
        along_m: f64,
        across_m: f64,
        max_angle_deg: f64,
        grid_step_m: f64,
    ) -> Result<Option<Self>> {
        require_positive("grid step", grid_step_m)?;
        for (name, length) in [("half-length", along_m), ("half-width", across_m)] {
            if !(length.is_finite() && length >= 0.0) {
                return Err(invalid(
                    "vessel pooling",
                    format!("the {name} must be a finite length ≥ 0, got {length} m"),
                ));
            }
        }
        let pooling = VesselPooling {
            along: along_m / grid_step_m,
            across: across_m / grid_step_m,
            max_angle: max_angle_deg.to_radians(),
        };
        pooling.check()?;
        Ok((pooling.along.max(pooling.across) >= 0.5).then_some(pooling))
    }

    /// Refuses negative or non-finite half-axes and a largest flow-direction difference outside
    /// 0–180° (or NaN).
    fn check(&self) -> Result<()> {
        if !(self.along.is_finite()
            && self.across.is_finite()
            && self.along >= 0.0
            && self.across >= 0.0)
        {
            return Err(invalid(
                "vessel pooling",
                format!(
                    "half-length and half-width must be finite and ≥ 0 pixels, got {} and {}",
                    self.along, self.across
                ),
            ));
        }
        if self.max_angle.is_finite() && (0.0..=std::f64::consts::PI).contains(&self.max_angle) {
            Ok(())
        } else {
            Err(invalid(
                "vessel pooling",
                format!(
                    "the largest flow-direction difference must be within 0–180°, got {}°",
                    self.max_angle.to_degrees()
                ),
            ))
        }
    }

    /// True when the offset (`dx`, `dz`) pixels lies in the ellipse of a pixel whose unit flow
    /// direction is `unit` = (ux, uz).
    fn reaches(&self, unit: [f64; 2], dx: f64, dz: f64) -> bool {
        let along = dx * unit[0] + dz * unit[1];
        let across = dz * unit[0] - dx * unit[1];
        // (along/a)² + (across/b)² ≤ 1, without dividing by a half-axis that may be 0.
        // A relative tolerance keeps the pixels on the rim that a half-axis converted from metres
        // (2.9999999 pixels for 3) would drop.
        let (a2, b2) = (self.along * self.along, self.across * self.across);
        along * along * b2 + across * across * a2 <= a2 * b2 * (1.0 + 1e-9)
    }
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
    /// - `estimator` = IRLS with the paper's λ = 0.01 mm/s (PC-UVD); `kernel` = (1, 1) (no
    ///   spatial averaging: small vessels are a few pixels wide).
    /// - `artery_ri_min` = 0.55, `vein_ri_max` = 0.5 (paper §4 and its ref. 29).
    /// - `min_power_db` = −30 dB: about the displayed dynamic range of the paper's power Doppler
    ///   images (Fig. 6); below it the speed is mostly noise and its RI meaningless.
    /// - `harmonics` = automatic ([`auto_harmonics`]: 2 at 5.5 Hz with 20 ms windows).
    pub fn rat() -> Self {
        DynamicsParams {
            window: 36,
            step: 9,
            heart_rate_hz: Some(5.5),
            estimator: Estimator::Irls(IrlsParams::default()),
            kernel: (1, 1),
            artery_ri_min: 0.55,
            vein_ri_max: 0.5,
            min_power_db: -30.0,
            harmonics: None,
            pooling: None,
        }
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
                    "must be finite and ≤ 0 dB (re. the brightest pixel), got {} dB",
                    self.min_power_db
                ),
            ));
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
        return Err(invalid(
            "heart rate",
            format!(
                "{hr} Hz has a period of {period_frames:.1} frames at {frame_rate} Hz, shorter than \
                 2 windows of {window} frames: each window would blur systole into diastole; \
                 use a window of at most {} frames",
                (period_frames / 2.0).floor()
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
                 window would blur systole into diastole; shorten the window",
                1e3 / hr,
                window_s * 1e3
            ),
        ));
    }
    Ok(())
}

/// Vector velocity over time: one (Vx, Vz) map per sliding window, shapes (time, nz, nx).
#[derive(Debug, Clone, PartialEq)]
pub struct VelocitySeries {
    /// Window centres (s) from the first frame.
    pub times_s: Vec<f64>,
    /// Lateral velocity (m/s), positive toward +x.
    pub vx: Array3<f64>,
    /// Axial velocity (m/s), positive moving deeper (away from the probe).
    pub vz: Array3<f64>,
    /// Power Doppler per window, mean over angles (|IQ|² units).
    pub power: Array3<f64>,
    /// Duration of each window (s).
    pub window_s: f64,
    /// Time between consecutive windows (s).
    pub step_s: f64,
}

impl VelocitySeries {
    /// Speed |V| = √(Vx² + Vz²) (m/s), shape (time, nz, nx).
    pub fn speed(&self) -> Array3<f64> {
        ndarray::Zip::from(&self.vx)
            .and(&self.vz)
            .map_collect(|&x, &z| x.hypot(z))
    }

    /// Time-mean velocity (m/s) per pixel over the finite windows, (Vx, Vz) maps of shape (nz, nx);
    /// zero where no window is finite.
    pub fn mean_velocity(&self) -> (Array2<f64>, Array2<f64>) {
        let mean = |v: &Array3<f64>| {
            v.map_axis(Axis(0), |lane| {
                let (sum, count) = lane
                    .iter()
                    .filter(|x| x.is_finite())
                    .fold((0.0, 0usize), |(s, c), &x| (s + x, c + 1));
                if count > 0 { sum / count as f64 } else { 0.0 }
            })
        };
        (mean(&self.vx), mean(&self.vz))
    }

    /// Number of windows (time samples).
    pub fn len(&self) -> usize {
        self.times_s.len()
    }

    /// True when there are no windows.
    pub fn is_empty(&self) -> bool {
        self.times_s.is_empty()
    }

    /// Time-mean power (dB re. the brightest pixel, 0 dB at the maximum), shape (nz, nx).
    pub fn mean_power_db(&self) -> Array2<f64> {
        let mean = self
            .power
            .mean_axis(Axis(0))
            .unwrap_or_else(|| Array2::zeros((self.power.dim().1, self.power.dim().2)));
        let peak = mean
            .iter()
            .copied()
            .filter(|p| p.is_finite())
            .fold(0.0, f64::max);
        mean.mapv(|p| {
            if peak > 0.0 && p > 0.0 {
                10.0 * (p / peak).log10()
            } else {
                f64::NEG_INFINITY
            }
        })
    }

    /// Vessel pixels: time-mean power at or above `min_power_db` (dB re. the brightest pixel).
    pub fn vessel_mask(&self, min_power_db: f64) -> Array2<bool> {
        self.mean_power_db().mapv(|p| p >= min_power_db)
    }

    /// Spatial mean speed (m/s) over the `mask` pixels at each time (finite values only).
    pub fn mean_speed(&self, mask: &Array2<bool>) -> Vec<f64> {
        let speed = self.speed();
        speed
            .outer_iter()
            .map(|frame| {
                let (mut sum, mut count) = (0.0, 0usize);
                for (&v, &m) in frame.iter().zip(mask.iter()) {
                    if m && v.is_finite() {
                        sum += v;
                        count += 1;
                    }
                }
                if count > 0 {
                    sum / count as f64
                } else {
                    f64::NAN
                }
            })
            .collect()
    }
}

/// Checks the per-angle series: non-empty, one per angle, equal shapes, finite; returns (nz, nx, frames).
fn check_series(filtered: &[Array3<Complex32>], angles: &[f64]) -> Result<(usize, usize, usize)> {
    let Some(first) = filtered.first() else {
        return Err(invalid("filtered IQ series", "no angle series given"));
    };
    if filtered.len() != angles.len() {
        return Err(Error::Shape(format!(
            "{} filtered IQ series for {} angles",
            filtered.len(),
            angles.len()
        )));
    }
    let dim = first.dim();
    if dim.0 == 0 || dim.1 == 0 || dim.2 == 0 {
        return Err(invalid(
            "filtered IQ series",
            format!("empty series of shape {dim:?} (nz, nx, frames)"),
        ));
    }
    for (k, series) in filtered.iter().enumerate() {
        if series.dim() != dim {
            return Err(Error::Shape(format!(
                "angle {k} series has shape {:?}, angle 0 has {dim:?} (nz, nx, frames)",
                series.dim()
            )));
        }
        if series
            .iter()
            .any(|v| !(v.re.is_finite() && v.im.is_finite()))
        {
            return Err(Error::NonFinite(format!("filtered IQ series of angle {k}")));
        }
    }
    if angles.iter().any(|a| !a.is_finite()) {
        return Err(Error::NonFinite("steering angles".into()));
    }
    Ok(dim)
}

/// Number of windows of `window` frames, `step` apart, in `frames` frames; errors when none fits.
fn window_count(frames: usize, window: usize, step: usize, frame_rate: f64) -> Result<usize> {
    check_window_step(window, step)?;
    if window > frames {
        return Err(invalid(
            "window",
            format!(
                "{window} frames ({:.1} ms) is longer than the recording ({frames} frames, {:.1} ms)",
                window as f64 / frame_rate * 1e3,
                frames as f64 / frame_rate * 1e3
            ),
        ));
    }
    Ok((frames - window) / step + 1)
}

/// Samples per cardiac cycle in a series of `n` samples `dt` apart; errors when one cycle does not fit.
fn cycle_length(n: usize, dt: f64, hr: f64) -> Result<(f64, usize)> {
    let period = 1.0 / (hr * dt);
    let len = (period.round() as usize).max(2);
    if n < len {
        return Err(invalid(
            "recording",
            format!(
                "shorter than one cardiac cycle: its {n} windows span {:.1} ms, a cycle at {hr:.2} Hz \
                 spans {:.1} ms ({len} windows); record at least one full cycle — PSV, EDV and RI \
                 need one",
                n as f64 * dt * 1e3,
                1e3 / hr
            ),
        ));
    }
    Ok((period, len))
}

/// Vector velocity in sliding windows over slow time: per angle, the lag-1 autocorrelation of each
/// window's frames → projection V_θ (m/s) → (Vx, Vz) with `params.estimator`.
///
/// `filtered`: clutter-filtered IQ per angle, shape (nz, nx, frames); `angles` (rad); `coverage`:
/// per angle the pixels its plane wave reaches (angles, nz, nx), as
/// [`pipeline::angle_coverage`](crate::pipeline::angle_coverage) gives, or `None` to use every
/// angle everywhere; `frame_rate`: compound frame rate (Hz); `sound_speed` (m/s); `center_frequency` (Hz).
/// Windows run in parallel; each is computed independently, so the output does not depend on the
/// number of threads.
pub fn sliding_vectors(
    filtered: &[Array3<Complex32>],
    angles: &[f64],
    coverage: Option<ArrayView3<bool>>,
    frame_rate: f64,
    sound_speed: f64,
    center_frequency: f64,
    params: &DynamicsParams,
) -> Result<VelocitySeries> {
    require_positive("frame rate", frame_rate)?;
    require_positive("speed of sound", sound_speed)?;
    require_positive("centre frequency", center_frequency)?;
    let (nz, nx, frames) = check_series(filtered, angles)?;
    if angles.len() < 2 {
        return Err(invalid("angles", "vector Doppler needs at least 2 angles"));
    }
    if let Some(c) = coverage
        && c.dim() != (angles.len(), nz, nx)
    {
        return Err(Error::Shape(format!(
            "angle coverage {:?} for {} angles of {nz} × {nx} pixels",
            c.dim(),
            angles.len()
        )));
    }
    let n_windows = window_count(frames, params.window, params.step, frame_rate)?;
    params.validate(frame_rate)?;
    let dt = params.step as f64 / frame_rate;
    if let Some(hr) = params.heart_rate_hz {
        cycle_length(n_windows, dt, hr)?;
    }

    let n = angles.len();
    let maps = (0..n_windows)
        .into_par_iter()
        .map(|k| {
            let start = k * params.step;
            let mut projections = Array3::<f64>::zeros((n, nz, nx));
            let mut power = Array2::<f64>::zeros((nz, nx));
            for (a, series) in filtered.iter().enumerate() {
                let window = series.slice(s![.., .., start..start + params.window]);
                let ac = doppler::autocorrelation(window, params.kernel)?;
                projections
                    .index_axis_mut(Axis(0), a)
                    .assign(&doppler::projection_velocity(
                        &ac.r1,
                        sound_speed,
                        frame_rate,
                        center_frequency,
                    )?);
                power += &ac.power;
            }
            power /= n as f64;
            if let Some(c) = coverage {
                vector::drop_unreached(&mut projections, c);
            }
            let field = vector::vector_velocity(angles, projections.view(), &params.estimator)?;
            Ok((field.vx, field.vz, power))
        })
        .collect::<Result<Vec<_>>>()?;

    let mut vx = Array3::<f64>::zeros((n_windows, nz, nx));
    let mut vz = Array3::<f64>::zeros((n_windows, nz, nx));
    let mut power = Array3::<f64>::zeros((n_windows, nz, nx));
    for (k, (x, z, p)) in maps.into_iter().enumerate() {
        vx.index_axis_mut(Axis(0), k).assign(&x);
        vz.index_axis_mut(Axis(0), k).assign(&z);
        power.index_axis_mut(Axis(0), k).assign(&p);
    }
    let half = (params.window - 1) as f64 / 2.0;
    let times_s = (0..n_windows)
        .map(|k| ((k * params.step) as f64 + half) / frame_rate)
        .collect();
    Ok(VelocitySeries {
        times_s,
        vx,
        vz,
        power,
        window_s: params.window as f64 / frame_rate,
        step_s: dt,
    })
}

/// Checks `times` (s): as long as `signal`, ≥ 2 samples, uniformly spaced; returns the spacing (s).
fn check_times(signal: &[f64], times: &[f64]) -> Result<f64> {
    if signal.len() != times.len() {
        return Err(Error::Shape(format!(
            "{} signal samples for {} times",
            signal.len(),
            times.len()
        )));
    }
    if signal.len() < 2 {
        return Err(invalid(
            "waveform",
            format!("needs at least 2 samples, got {}", signal.len()),
        ));
    }
    if signal.iter().chain(times).any(|v| !v.is_finite()) {
        return Err(Error::NonFinite("waveform or its times".into()));
    }
    let dt = times[1] - times[0];
    if dt <= 0.0 {
        return Err(invalid("times", "must increase"));
    }
    for pair in times.windows(2) {
        if ((pair[1] - pair[0]) - dt).abs() > 1e-6 * dt {
            return Err(invalid(
                "times",
                format!(
                    "must be uniformly spaced (window centres), found steps {dt} s and {} s",
                    pair[1] - pair[0]
                ),
            ));
        }
    }
    Ok(dt)
}

/// Removes the least-squares straight line from `x`.
fn detrend(x: &[f64]) -> Vec<f64> {
    let n = x.len() as f64;
    let tm = (n - 1.0) / 2.0;
    let xm = x.iter().sum::<f64>() / n;
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (t, &v) in x.iter().enumerate() {
        let dt = t as f64 - tm;
        sxy += dt * (v - xm);
        sxx += dt * dt;
    }
    let slope = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    x.iter()
        .enumerate()
        .map(|(t, &v)| v - xm - slope * (t as f64 - tm))
        .collect()
}

/// Pearson correlation of x[0..n−lag] with x[lag..n].
fn lag_correlation(x: &[f64], lag: usize) -> f64 {
    let a = &x[..x.len() - lag];
    let b = &x[lag..];
    let m = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / m, b.iter().sum::<f64>() / m);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (&u, &v) in a.iter().zip(b) {
        sab += (u - ma) * (v - mb);
        saa += (u - ma) * (u - ma);
        sbb += (v - mb) * (v - mb);
    }
    if saa > 0.0 && sbb > 0.0 {
        sab / (saa * sbb).sqrt()
    } else {
        f64::NAN
    }
}

/// Heart rate (Hz) of a pulsatile waveform `signal` sampled at `times` (s): the first strong peak
/// of the autocorrelation of the detrended signal at a period within 3–15 Hz, refined to a
/// fraction of a sample by a parabola through the peak. Needs ≳ 1.5 cycles of data.
pub fn estimate_heart_rate(signal: &[f64], times: &[f64]) -> Result<f64> {
    let dt = check_times(signal, times)?;
    let n = signal.len();
    let x = detrend(signal);
    let (f_lo, f_hi) = HEART_RATE_SEARCH_HZ;
    let lag_min = ((1.0 / (f_hi * dt)).ceil() as usize).max(2);
    // Keep at least a third of the record overlapping at the longest lag.
    let lag_max = ((1.0 / (f_lo * dt)).floor() as usize).min(2 * n / 3);
    let too_short = || {
        invalid(
            "recording",
            format!(
                "{:.1} ms of waveform is too short to measure a heart rate between {f_lo} and \
                 {f_hi} Hz from the data (about 1.5 cycles are needed); give the heart rate",
                n as f64 * dt * 1e3
            ),
        )
    };
    if lag_max < lag_min + 1 || lag_max + 2 > n {
        return Err(too_short());
    }
    let r: Vec<f64> = (0..=lag_max + 1)
        .map(|lag| {
            if lag + 2 <= n {
                lag_correlation(&x, lag)
            } else {
                f64::NAN
            }
        })
        .collect();
    if r[lag_min..=lag_max].iter().all(|v| !v.is_finite()) {
        return Err(invalid(
            "waveform",
            "is constant: no cardiac pulsation to measure",
        ));
    }
    let peaks: Vec<usize> = (lag_min..=lag_max)
        .filter(|&l| r[l].is_finite() && r[l] >= r[l - 1] && r[l] > r[l + 1])
        .collect();
    let best = peaks
        .iter()
        .map(|&l| r[l])
        .fold(f64::NEG_INFINITY, f64::max);
    if peaks.is_empty() || best < 0.3 {
        if peaks.is_empty() && n as f64 * dt * f_lo < 2.0 {
            return Err(too_short());
        }
        return Err(invalid(
            "waveform",
            format!(
                "no clear cardiac period between {f_lo} and {f_hi} Hz (best autocorrelation \
                 {best:.2} < 0.3); give the heart rate"
            ),
        ));
    }
    // The first peak nearly as strong as the best: the fundamental, not a multiple of the period.
    let lag = peaks
        .iter()
        .copied()
        .find(|&l| r[l] >= 0.8 * best)
        .unwrap_or(peaks[0]);
    let (a, b, c) = (r[lag - 1], r[lag], r[lag + 1]);
    let curvature = a - 2.0 * b + c;
    let shift = if c.is_finite() && curvature < 0.0 {
        (0.5 * (a - c) / curvature).clamp(-0.5, 0.5)
    } else {
        0.0
    };
    Ok(1.0 / ((lag as f64 + shift) * dt))
}

/// Complete cardiac cycles in a waveform `signal` (e.g. the mean speed over vessel pixels) sampled
/// at uniform `times` (s): half-open index ranges [start, end) one period long, as many as fit,
/// started at systolic peaks where the recording allows. The period comes from `heart_rate_hz`
/// (Hz) or, if `None`, from [`estimate_heart_rate`]. Errors when not one cycle fits.
pub fn find_cycles(
    signal: &[f64],
    times: &[f64],
    heart_rate_hz: Option<f64>,
) -> Result<Vec<(usize, usize)>> {
    Ok(cycles_and_rate(signal, times, heart_rate_hz)?.0)
}

fn cycles_and_rate(
    signal: &[f64],
    times: &[f64],
    heart_rate_hz: Option<f64>,
) -> Result<(Vec<(usize, usize)>, f64)> {
    let dt = check_times(signal, times)?;
    let hr = match heart_rate_hz {
        Some(hr) => {
            require_positive("heart rate", hr)?;
            if hr * dt > 0.5 {
                return Err(invalid(
                    "heart rate",
                    format!(
                        "{hr} Hz is above the Nyquist rate {:.2} Hz of a waveform sampled every {:.2} ms",
                        0.5 / dt,
                        dt * 1e3
                    ),
                ));
            }
            hr
        }
        None => estimate_heart_rate(signal, times)?,
    };
    let n = signal.len();
    let (period, len) = cycle_length(n, dt, hr)?;
    let start_of = |k: usize| (k as f64 * period).round() as usize;
    let mut count = ((n - len) as f64 / period).floor() as usize + 1;
    while count > 1 && start_of(count - 1) + len > n {
        count -= 1;
    }
    // Free play of the first start that keeps `count` cycles: align the starts with the peaks.
    let slack = n - len - start_of(count - 1);
    let offset = (0..=slack)
        .map(|o| {
            let score: f64 = (0..count).map(|k| signal[o + start_of(k)]).sum();
            (o, score)
        })
        .fold((0, f64::NEG_INFINITY), |best, cur| {
            if cur.1 > best.1 { cur } else { best }
        })
        .0;
    let cycles = (0..count)
        .map(|k| {
            let start = offset + start_of(k);
            (start, start + len)
        })
        .collect();
    Ok((cycles, hr))
}

/// PSV and EDV (units of `speed`) averaged over `cycles`: PSV the largest and EDV the smallest
/// finite value of each cycle (end-diastole is the minimum before the next upstroke). NaN when no
/// cycle has a finite value.
pub fn psv_edv(speed: &[f64], cycles: &[(usize, usize)]) -> Result<(f64, f64)> {
    if cycles.is_empty() {
        return Err(invalid("cardiac cycles", "none given"));
    }
    for &(start, end) in cycles {
        if start >= end || end > speed.len() {
            return Err(invalid(
                "cardiac cycles",
                format!(
                    "cycle [{start}, {end}) is empty or runs past the {} samples",
                    speed.len()
                ),
            ));
        }
    }
    Ok(psv_edv_unchecked(speed, cycles))
}

fn psv_edv_unchecked(speed: &[f64], cycles: &[(usize, usize)]) -> (f64, f64) {
    let (mut psv, mut edv, mut count) = (0.0, 0.0, 0usize);
    for &(start, end) in cycles {
        let finite = speed[start..end].iter().copied().filter(|v| v.is_finite());
        let (lo, hi) = finite.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
        if lo <= hi {
            psv += hi;
            edv += lo;
            count += 1;
        }
    }
    if count == 0 {
        (f64::NAN, f64::NAN)
    } else {
        (psv / count as f64, edv / count as f64)
    }
}

/// Cardiac harmonics worth fitting with windows of `window_s` seconds at `heart_rate_hz`: those
/// the window's boxcar passes at ≥ 90 % (sinc(f·window) ≥ 0.9, i.e. f ≤ 0.25/window). Higher
/// harmonics are already blurred by the window, and fitting them mostly fits estimation noise: the
/// overlapping windows give only about one independent estimate per window length, and that noise
/// is concentrated at low frequencies, where the harmonics are. At least 1; 2 for the rat preset
/// (5.5 Hz, 20 ms windows: 11 Hz ≤ 12.5 Hz), where fitting a third harmonic (blurred by the
/// window to sinc(16.5 Hz · 20 ms) ≈ 0.83) gave larger RI errors on the vessel-network phantom.
pub fn auto_harmonics(heart_rate_hz: f64, window_s: f64) -> usize {
    let k = (0.25 / (window_s * heart_rate_hz)).floor();
    if k.is_finite() && k >= 1.0 {
        k as usize
    } else {
        1
    }
}

/// Least-squares fit of a mean plus the first harmonics of the heart rate to series sampled at
/// fixed times: the pseudo-inverse is computed once and applied to every pixel.
struct HarmonicFit {
    /// Design matrix, (times × coefficients): 1, cos kωt, sin kωt.
    design: Mat<f64>,
    /// Its pseudo-inverse, (coefficients × times).
    pinv: Mat<f64>,
}

impl HarmonicFit {
    /// `None` when `harmonics` is 0 or the series is too short to fit that many.
    fn new(times: &[f64], heart_rate_hz: f64, harmonics: usize) -> Option<HarmonicFit> {
        let columns = 2 * harmonics + 1;
        if harmonics == 0 || times.len() <= columns {
            return None;
        }
        let omega = 2.0 * std::f64::consts::PI * heart_rate_hz;
        let design = Mat::<f64>::from_fn(times.len(), columns, |i, j| {
            let k = j.div_ceil(2) as f64;
            match j {
                0 => 1.0,
                _ if j % 2 == 1 => (k * omega * times[i]).cos(),
                _ => (k * omega * times[i]).sin(),
            }
        });
        let pinv = design
            .qr()
            .solve_lstsq(Mat::<f64>::identity(times.len(), times.len()));
        Some(HarmonicFit { design, pinv })
    }

    /// The fitted curve at the sample times; `None` if `lane` has non-finite samples.
    fn smooth(&self, lane: &[f64]) -> Option<Vec<f64>> {
        if lane.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let coefficients: Vec<f64> = (0..self.pinv.nrows())
            .map(|j| (0..lane.len()).map(|i| self.pinv[(j, i)] * lane[i]).sum())
            .collect();
        Some(
            (0..lane.len())
                .map(|i| {
                    coefficients
                        .iter()
                        .enumerate()
                        .map(|(j, c)| self.design[(i, j)] * c)
                        .sum()
                })
                .collect(),
        )
    }
}

/// Each `mask` pixel's speed series replaced by its pooled waveform (see [`VesselPooling`]): the
/// sum of the series of its same-vessel neighbours (itself included) over the sum of their time
/// means, times its own time mean, so that its mean speed is kept and its shape is the pooled one.
/// `speed` is (time, nz, nx); `mean_vx`, `mean_vz` are the time-mean velocities (nz, nx) that give
/// each pixel's flow direction. Pixels without a finite series, or outside the mask, are kept as
/// they are and pooled by none.
fn pool_waveforms(
    speed: &Array3<f64>,
    mask: &Array2<bool>,
    mean_vx: &Array2<f64>,
    mean_vz: &Array2<f64>,
    weight: &Array2<f64>,
    pooling: &VesselPooling,
) -> Array3<f64> {
    let (nt, nz, nx) = speed.dim();
    let r = pooling.along.max(pooling.across).ceil() as isize;
    let min_cos = pooling.max_angle.cos();
    // Per pixel: the unit flow direction and the time mean, or None when it cannot take part.
    let members: Vec<Option<([f64; 2], f64, f64)>> = (0..nz * nx)
        .map(|p| {
            let (iz, ix) = (p / nx, p % nx);
            let lane = speed.slice(s![.., iz, ix]);
            let norm = mean_vx[[iz, ix]].hypot(mean_vz[[iz, ix]]);
            if !mask[[iz, ix]]
                || norm.is_nan()
                || norm <= 0.0
                || lane.iter().any(|v| !v.is_finite())
            {
                return None;
            }
            let unit = [mean_vx[[iz, ix]] / norm, mean_vz[[iz, ix]] / norm];
            Some((unit, lane.sum() / nt as f64, weight[[iz, ix]]))
        })
        .collect();
    let pooled: Vec<Option<Vec<f64>>> = (0..nz * nx)
        .into_par_iter()
        .map(|p| {
            let (unit, own_mean, _) = members[p]?;
            let (iz, ix) = ((p / nx) as isize, (p % nx) as isize);
            let mut sum = vec![0.0; nt];
            let mut mean_sum = 0.0;
            let offsets = (-r..=r)
                .flat_map(|dz| (-r..=r).map(move |dx| (dz, dx)))
                .filter(|&(dz, dx)| pooling.reaches(unit, dx as f64, dz as f64));
            for (dz, dx) in offsets {
                let (qz, qx) = (iz + dz, ix + dx);
                if qz < 0 || qx < 0 || qz >= nz as isize || qx >= nx as isize {
                    continue;
                }
                let q = qz as usize * nx + qx as usize;
                let Some((u, mean, w)) = members[q] else {
                    continue;
                };
                if u[0] * unit[0] + u[1] * unit[1] < min_cos {
                    continue;
                }
                for (acc, &v) in sum
                    .iter_mut()
                    .zip(speed.slice(s![.., qz as usize, qx as usize]))
                {
                    *acc += w * v;
                }
                mean_sum += w * mean;
            }
            (mean_sum > 0.0).then(|| sum.iter().map(|v| v / mean_sum * own_mean).collect())
        })
        .collect();
    let mut out = speed.clone();
    for (p, lane) in pooled.into_iter().enumerate() {
        if let Some(lane) = lane {
            out.slice_mut(s![.., p / nx, p % nx])
                .assign(&ndarray::Array1::from(lane));
        }
    }
    out
}

/// Resistivity index RI = (PSV − EDV)/PSV (dimensionless, eq. 16); NaN when PSV ≤ 0 or not finite.
pub fn resistivity_index(psv: f64, edv: f64) -> f64 {
    if psv.is_finite() && edv.is_finite() && psv > 0.0 {
        (psv - edv) / psv
    } else {
        f64::NAN
    }
}

/// Per-pixel cardiac-cycle maps, shape (nz, nx); background pixels hold NaN velocities and RI.
#[derive(Debug, Clone, PartialEq)]
pub struct RiMaps {
    /// Peak systolic speed (m/s), averaged over cycles.
    pub psv: Array2<f64>,
    /// End-diastolic speed (m/s), averaged over cycles.
    pub edv: Array2<f64>,
    /// Resistivity index (dimensionless, eq. 16).
    pub ri: Array2<f64>,
    /// [`BACKGROUND`], [`ARTERIOLE`], [`VENULE`] or [`UNDETERMINED`].
    pub vessel_class: Array2<u8>,
    /// True where the time-mean Vz < 0 (flow up, toward the probe); false on background.
    pub flow_up: Array2<bool>,
    /// Heart rate used (Hz): the given one or the one measured from the data.
    pub heart_rate_hz: f64,
    /// Cardiac cycles used, as [start, end) indices into the series' windows.
    pub cycles: Vec<(usize, usize)>,
}

/// PSV, EDV, RI, vessel classes and flow directions from a [`VelocitySeries`]: vessel pixels are
/// those at or above `params.min_power_db`; the cycles come from their spatial mean speed.
pub fn ri_maps(series: &VelocitySeries, params: &DynamicsParams) -> Result<RiMaps> {
    ri_maps_where(series, params, None)
}

/// As [`ri_maps`], with vessel pixels restricted to where `flow` (nz, nx) holds as well: for
/// example the pixels of the whole recording's power Doppler above its noise floor
/// ([`crate::doppler::above_noise_floor`]), a steadier test than the power of 20 ms windows.
pub fn ri_maps_where(
    series: &VelocitySeries,
    params: &DynamicsParams,
    flow: Option<&Array2<bool>>,
) -> Result<RiMaps> {
    if series.is_empty() {
        return Err(invalid("velocity series", "has no windows"));
    }
    let (nt, nz, nx) = series.vx.dim();
    if series.vz.dim() != (nt, nz, nx) || series.power.dim() != (nt, nz, nx) || nt != series.len() {
        return Err(Error::Shape(format!(
            "velocity series: vx {:?}, vz {:?}, power {:?} for {} times",
            series.vx.dim(),
            series.vz.dim(),
            series.power.dim(),
            series.len()
        )));
    }
    if !(series.step_s > 0.0 && series.window_s > 0.0) {
        return Err(invalid(
            "velocity series",
            format!(
                "window ({} s) and step ({} s) must be > 0",
                series.window_s, series.step_s
            ),
        ));
    }
    params.validate_thresholds()?;
    if let Some(hr) = params.heart_rate_hz {
        require_positive("heart rate", hr)?;
        check_period_vs_window(hr, series.window_s)?;
    }

    let mut mask = series.vessel_mask(params.min_power_db);
    if let Some(flow) = flow {
        if flow.dim() != (nz, nx) {
            return Err(Error::Shape(format!(
                "flow mask {:?} for velocity maps of {:?}",
                flow.dim(),
                (nz, nx)
            )));
        }
        mask.zip_mut_with(flow, |m, &f| *m &= f);
    }
    if !mask.iter().any(|&m| m) {
        return Err(invalid(
            "velocity series",
            "no pixel has power (no vessel to analyse)",
        ));
    }
    let waveform = series.mean_speed(&mask);
    let (cycles, hr) = cycles_and_rate(&waveform, &series.times_s, params.heart_rate_hz)?;
    check_period_vs_window(hr, series.window_s)?;

    let mut speed = series.speed();
    if let Some(pooling) = params.pooling {
        let (mx, mz) = series.mean_velocity();
        let mean_power = series
            .power
            .mean_axis(Axis(0))
            .unwrap_or_else(|| Array2::zeros((nz, nx)));
        let weight = mean_power.mapv(|p| p * p);
        speed = pool_waveforms(&speed, &mask, &mx, &mz, &weight, &pooling);
    }
    let harmonics = params
        .harmonics
        .unwrap_or_else(|| auto_harmonics(hr, series.window_s));
    let fit = HarmonicFit::new(&series.times_s, hr, harmonics);
    let pixels: Vec<(f64, f64, f64, u8, bool)> = (0..nz * nx)
        .into_par_iter()
        .map(|p| {
            let (iz, ix) = (p / nx, p % nx);
            if !mask[[iz, ix]] {
                return (f64::NAN, f64::NAN, f64::NAN, BACKGROUND, false);
            }
            let mut lane: Vec<f64> = speed.slice(s![.., iz, ix]).to_vec();
            if let Some(smooth) = fit.as_ref().and_then(|f| f.smooth(&lane)) {
                lane = smooth;
            }
            let (psv, edv) = psv_edv_unchecked(&lane, &cycles);
            let ri = resistivity_index(psv, edv);
            let class = if ri >= params.artery_ri_min {
                ARTERIOLE
            } else if ri <= params.vein_ri_max {
                VENULE
            } else {
                UNDETERMINED
            };
            let (mut sum, mut count) = (0.0, 0usize);
            for &v in series.vz.slice(s![.., iz, ix]) {
                if v.is_finite() {
                    sum += v;
                    count += 1;
                }
            }
            let up = count > 0 && sum / (count as f64) < 0.0;
            (psv, edv, ri, class, up)
        })
        .collect();
    let at = |iz: usize, ix: usize| &pixels[iz * nx + ix];
    Ok(RiMaps {
        psv: Array2::from_shape_fn((nz, nx), |(iz, ix)| at(iz, ix).0),
        edv: Array2::from_shape_fn((nz, nx), |(iz, ix)| at(iz, ix).1),
        ri: Array2::from_shape_fn((nz, nx), |(iz, ix)| at(iz, ix).2),
        vessel_class: Array2::from_shape_fn((nz, nx), |(iz, ix)| at(iz, ix).3),
        flow_up: Array2::from_shape_fn((nz, nx), |(iz, ix)| at(iz, ix).4),
        heart_rate_hz: hr,
        cycles,
    })
}

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

/// Compounded Doppler spectrogram at pixel `pixel` = (iz, ix) (paper Fig. 8b): the angles' series
/// are summed (coherent compounding), then Hann-windowed FFTs over slow time in sliding windows.
///
/// Doppler frequency f (Hz) maps to axial velocity Vz = −c·f/(f0·(1 + mean cos θ)) (m/s): the
/// compounded echo path changes by Vz·(1 + mean cos θ) (+ Vx·mean sin θ, zero for symmetric angle
/// sets), as in the pipeline's colour Doppler. `frame_rate` (Hz), `sound_speed` (m/s),
/// `center_frequency` (Hz), `angles` (rad).
pub fn spectrogram(
    filtered: &[Array3<Complex32>],
    angles: &[f64],
    pixel: (usize, usize),
    frame_rate: f64,
    sound_speed: f64,
    center_frequency: f64,
    params: &SpectrogramParams,
) -> Result<Spectrogram> {
    require_positive("frame rate", frame_rate)?;
    require_positive("speed of sound", sound_speed)?;
    require_positive("centre frequency", center_frequency)?;
    let (nz, nx, frames) = check_series(filtered, angles)?;
    let (iz, ix) = pixel;
    if iz >= nz || ix >= nx {
        return Err(invalid(
            "pixel",
            format!("({iz}, {ix}) is outside the {nz} × {nx} image"),
        ));
    }
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
    let compound: Vec<Complex64> = (0..frames)
        .map(|t| {
            filtered.iter().fold(Complex64::new(0.0, 0.0), |acc, s| {
                let v = s[[iz, ix, t]];
                acc + Complex64::new(v.re as f64, v.im as f64)
            })
        })
        .collect();
    if compound.iter().all(|v| v.norm_sqr() == 0.0) {
        return Err(invalid(
            "pixel",
            format!("({iz}, {ix}) has no Doppler signal (its compounded series is zero)"),
        ));
    }
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
    let fft = FftPlanner::<f64>::new().plan_fft_forward(nfft);

    let mut power = Array2::<f64>::zeros((n_windows, nfft));
    let mut mean_velocity = Vec::with_capacity(n_windows);
    let mut buffer = vec![Complex64::new(0.0, 0.0); nfft];
    for k in 0..n_windows {
        let frames_k = &compound[k * params.step..k * params.step + params.window];
        buffer.fill(Complex64::new(0.0, 0.0));
        for ((b, &x), &w) in buffer.iter_mut().zip(frames_k).zip(&hann) {
            *b = x * w;
        }
        fft.process(&mut buffer);
        // Bin j of the fftshifted spectrum has frequency (j − nfft/2)·f_frame/nfft; velocity
        // falls as frequency rises, so column c = nfft − 1 − j ascends in velocity.
        for j in 0..nfft {
            let bin = (j + nfft.div_ceil(2)) % nfft;
            power[[k, nfft - 1 - j]] = buffer[bin].norm_sqr();
        }
        let r1: Complex64 = frames_k.windows(2).map(|p| p[0].conj() * p[1]).sum();
        let v_proj = if r1.norm() > 0.0 {
            -scale * r1.arg()
        } else {
            0.0
        };
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
    let power_db = power.mapv(|p| 10.0 * (p / peak).max(1e-20).log10());
    let half = (params.window - 1) as f64 / 2.0;
    Ok(Spectrogram {
        times_s: (0..n_windows)
            .map(|k| ((k * params.step) as f64 + half) / frame_rate)
            .collect(),
        velocities_m_s,
        power_db,
        mean_velocity_m_s: mean_velocity,
        nyquist_m_s: 0.5 * frame_rate * per_hz.abs(),
    })
}
