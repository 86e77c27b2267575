//! Per-angle IQ image series with what downstream stages need to read them: the grid, the
//! steering angles, the slow-time rate, the sound speed and the demodulation frequency (as USTB's
//! beamformed data carry their scan and sequence), so that Doppler, dynamics and spectrograms take
//! one argument.

use ndarray::Array3;
use num_complex::Complex32;

use crate::core::error::{Error, Result, invalid};
use crate::core::grid::Grid;

/// Beamformed IQ image series, one per steering angle, each (nz, nx, frames) with frames
/// contiguous, and the acquisition facts that give them meaning.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct AngleImages {
    /// Pixel grid of every image (m).
    pub grid: Grid,
    /// Steering angle of each series (rad).
    pub angles: Vec<f64>,
    /// Slow-time sampling rate of each series: the compound frame rate (Hz).
    pub frame_rate: f64,
    /// Speed of sound (m/s).
    pub sound_speed: f64,
    /// Frequency the IQ data were demodulated at, which Doppler converts phase with (Hz).
    pub demodulation_frequency: f64,
    /// Per angle, the pixels its plane wave reaches (angles, nz, nx); `None`: every pixel.
    pub coverage: Option<Array3<bool>>,
    /// The image series, one per angle, each (nz, nx, frames).
    pub series: Vec<Array3<Complex32>>,
}

impl AngleImages {
    /// Number of steering angles.
    pub fn n_angles(&self) -> usize {
        self.angles.len()
    }

    /// Frames per series (0 when there is none).
    pub fn n_frames(&self) -> usize {
        self.series.first().map_or(0, |s| s.dim().2)
    }

    /// The same metadata around other series (e.g. echoes plus scaled noise).
    pub fn with_series(&self, series: Vec<Array3<Complex32>>) -> AngleImages {
        AngleImages {
            grid: self.grid.clone(),
            angles: self.angles.clone(),
            frame_rate: self.frame_rate,
            sound_speed: self.sound_speed,
            demodulation_frequency: self.demodulation_frequency,
            coverage: self.coverage.clone(),
            series,
        }
    }

    /// Checks that the series, angles, grid and coverage agree and the rates are positive.
    pub fn validate(&self) -> Result<()> {
        let n = self.angles.len();
        if self.series.len() != n {
            return Err(Error::Shape(format!(
                "{} image series for {n} angles",
                self.series.len()
            )));
        }
        let (nz, nx) = self.grid.shape();
        for (k, s) in self.series.iter().enumerate() {
            let (z, x, _) = s.dim();
            if (z, x) != (nz, nx) {
                return Err(Error::Shape(format!(
                    "image series {k} is {z} × {x} pixels; the grid is {nz} × {nx}"
                )));
            }
        }
        if let Some(c) = &self.coverage
            && c.dim() != (n, nz, nx)
        {
            return Err(Error::Shape(format!(
                "coverage is {:?}; expected (angles, nz, nx) = ({n}, {nz}, {nx})",
                c.dim()
            )));
        }
        for (name, value) in [
            ("frame rate", self.frame_rate),
            ("speed of sound", self.sound_speed),
            ("demodulation frequency", self.demodulation_frequency),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(invalid(name, format!("{value}: must be positive")));
            }
        }
        Ok(())
    }
}
