//! Channel data: what the scanner records, one trace per element per transmit event.

use ndarray::{Array3, Array4};
use num_complex::Complex32;

use crate::error::{Error, Result, invalid, require_positive};
use crate::probe::Probe;
use crate::sequence::Sequence;

/// Everything needed to interpret a recording's samples.
#[derive(Debug, Clone, PartialEq)]
pub struct Acquisition {
    /// The probe that transmitted and received.
    pub probe: Probe,
    /// The transmit sequence (angles, event PRF, coding).
    pub sequence: Sequence,
    /// Sampling frequency of the traces (Hz).
    pub sampling_frequency: f64,
    /// Speed of sound assumed for the medium (m/s).
    pub sound_speed: f64,
    /// Time of the first sample after the first element of the event's first pulse slot fires (s).
    pub t0: f64,
}

impl Acquisition {
    /// Checks every parameter for physical sense (positive f_s, c, pitch...).
    pub fn validate(&self) -> Result<()> {
        self.probe.validate()?;
        self.sequence.validate()?;
        require_positive("sampling frequency", self.sampling_frequency)?;
        require_positive("speed of sound", self.sound_speed)?;
        if !self.t0.is_finite() {
            return Err(invalid("t0", format!("must be finite, got {}", self.t0)));
        }
        Ok(())
    }

    /// Slow-time sampling rate of each angle (Hz) = event PRF / number of angles.
    pub fn frame_rate(&self) -> f64 {
        self.sequence.frame_rate()
    }

    /// Largest unaliased projection velocity V_θ (m/s) ([`crate::doppler::nyquist_velocity`]).
    pub fn nyquist_velocity(&self) -> f64 {
        crate::doppler::nyquist_velocity(
            self.sound_speed,
            self.frame_rate(),
            self.probe.center_frequency,
        )
    }
}

/// Recorded samples, shape (events, channels, samples): RF, or IQ already demodulated.
#[derive(Debug, Clone, PartialEq)]
pub enum Samples {
    /// Real radio-frequency samples.
    Rf(Array3<f32>),
    /// Complex baseband samples, demodulated at `demod_frequency` (Hz) with time origin t0.
    Iq {
        /// The samples.
        data: Array3<Complex32>,
        /// Demodulation frequency (Hz).
        demod_frequency: f64,
    },
}

impl Samples {
    /// (events, channels, samples).
    pub fn dim(&self) -> (usize, usize, usize) {
        match self {
            Samples::Rf(a) => a.dim(),
            Samples::Iq { data, .. } => data.dim(),
        }
    }
}

/// A recording: acquisition parameters and the samples of every transmit event.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelData {
    /// How it was acquired.
    pub acquisition: Acquisition,
    /// Samples, shape (events, channels, samples).
    pub samples: Samples,
}

impl ChannelData {
    /// Checks parameters, shapes (channels = elements, whole compound frames) and finiteness.
    pub fn validate(&self) -> Result<()> {
        self.acquisition.validate()?;
        let (events, channels, samples) = self.samples.dim();
        let n = self.acquisition.sequence.n_angles();
        if channels != self.acquisition.probe.n_elements {
            return Err(Error::Shape(format!(
                "the data has {channels} channels but the probe has {} elements",
                self.acquisition.probe.n_elements
            )));
        }
        if samples < 2 {
            return Err(Error::Shape(format!(
                "each trace needs at least 2 samples, got {samples}"
            )));
        }
        if events < n || events % n != 0 {
            return Err(Error::Shape(format!(
                "{events} transmit events is not a whole number of compound frames of {n} events"
            )));
        }
        let finite = match &self.samples {
            Samples::Rf(a) => a.iter().all(|v| v.is_finite()),
            Samples::Iq { data, .. } => data.iter().all(|v| v.re.is_finite() && v.im.is_finite()),
        };
        if !finite {
            return Err(Error::NonFinite("the channel samples (NaN or Inf)".into()));
        }
        Ok(())
    }

    /// Number of compound frames (events / angles).
    pub fn n_frames(&self) -> usize {
        self.samples.dim().0 / self.acquisition.sequence.n_angles()
    }
}

/// Channel data separated per angle, shape (angles, frames, channels, samples); each angle's time
/// origin is t0 after its own slot fired.
#[derive(Debug, Clone, PartialEq)]
pub enum AngleSamples {
    /// Real RF.
    Rf(Array4<f32>),
    /// Complex baseband.
    Iq {
        /// The samples.
        data: Array4<Complex32>,
        /// Demodulation frequency (Hz).
        demod_frequency: f64,
    },
}

impl AngleSamples {
    /// The frames `frames` of every angle (a copy).
    pub fn frames(&self, frames: std::ops::Range<usize>) -> AngleSamples {
        match self {
            AngleSamples::Rf(a) => {
                AngleSamples::Rf(a.slice(ndarray::s![.., frames, .., ..]).to_owned())
            }
            AngleSamples::Iq {
                data,
                demod_frequency,
            } => AngleSamples::Iq {
                data: data.slice(ndarray::s![.., frames, .., ..]).to_owned(),
                demod_frequency: *demod_frequency,
            },
        }
    }

    /// (angles, frames, channels, samples).
    pub fn dim(&self) -> (usize, usize, usize, usize) {
        match self {
            AngleSamples::Rf(a) => a.dim(),
            AngleSamples::Iq { data, .. } => data.dim(),
        }
    }
}
