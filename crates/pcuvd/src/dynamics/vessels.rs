//! Which pixels of a recording are vessels for the RI maps: the whole-recording power tests.

use super::*;

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
                format!("must be ≥ 0 dB (or off), got {:?}", self.local_db),
            ));
        }
        if !(self.local_radius_m.is_finite() && self.local_radius_m >= 0.0) {
            return Err(invalid(
                "vessel local radius",
                format!("must be ≥ 0 m, got {:?}", self.local_radius_m),
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
