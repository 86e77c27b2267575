//! Channel data: what the scanner records, one trace per element per transmit event.

use ndarray::{Array3, Array4, ArrayView4};
use num_complex::Complex32;

use crate::acquisition::probe::Probe;
use crate::acquisition::sequence::Sequence;
use crate::core::buffers::{complex_finite_on_every_core, floats_finite_on_every_core};
use crate::core::error::{Error, Result, invalid, require_positive};

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
    /// Time of the first sample after the event's time origin (s): the instant the first element
    /// of the event's first pulse slot fires, unless an explicit code
    /// ([`Coding::Matrix`](crate::Coding::Matrix)) starts its slots later.
    pub t0: f64,
}

/// Range of speeds of sound pcuvd accepts (m/s): from below any gas-free tissue to above steel;
/// outside it the value is in another unit (mm/µs, say) or a mistake.
pub const SOUND_SPEED_RANGE: (f64, f64) = (300.0, 10_000.0);

impl Acquisition {
    /// Checks every parameter for physical sense and a plausible range (positive f_s up to
    /// 10 GHz, c within [`SOUND_SPEED_RANGE`], t0 within an event period, a sampled pulse that
    /// holds the probe's band ...).
    pub fn validate(&self) -> Result<()> {
        self.probe.validate()?;
        self.sequence.validate()?;
        require_positive("sampling frequency", self.sampling_frequency)?;
        crate::core::error::require_range(
            "sampling frequency",
            self.sampling_frequency,
            (1e3, crate::acquisition::sequence::MAX_SAMPLING_FREQUENCY),
            "Hz",
        )?;
        require_positive("speed of sound", self.sound_speed)?;
        crate::core::error::require_range(
            "speed of sound",
            self.sound_speed,
            SOUND_SPEED_RANGE,
            "m/s",
        )?;
        if !self.t0.is_finite() {
            return Err(invalid("t0", format!("must be finite, got {:?}", self.t0)));
        }
        // The first sample comes after the event fires and before the next one does.
        let period = 1.0 / self.sequence.event_prf;
        if self.t0.abs() >= period {
            return Err(invalid(
                "t0",
                format!(
                    "{:.3} µs is not within ± the event period ({:.3} µs at the event PRF): the \
                     first sample must be recorded within its own event (check the unit: s)",
                    self.t0 * 1e6,
                    period * 1e6
                ),
            ));
        }
        if let Some(pulse) = &self.sequence.pulse {
            let top = self.probe.center_frequency * (1.0 + self.probe.bandwidth / 2.0);
            if pulse.sampling_frequency <= 2.0 * top {
                return Err(invalid(
                    "pulse sampling frequency",
                    format!(
                        "{:.3} MHz must exceed twice the top of the probe's band ({:.3} MHz) for \
                         the sampled pulse to hold the band",
                        pulse.sampling_frequency * 1e-6,
                        2.0 * top * 1e-6
                    ),
                ));
            }
        }
        Ok(())
    }

    /// How RF sampled at the acquisition's f_s holds the probe's band [f_c(1 − B/2), f_c(1 + B/2)]
    /// (B the fractional bandwidth): whole below f_s/2, or band-pass sampled within one Nyquist
    /// zone [m·f_s/2, (m + 1)·f_s/2], m ≥ 1 (which demodulation handles), or an error when the
    /// band straddles a multiple of f_s/2 and so folds onto itself (its frequencies alias onto
    /// each other and no processing can separate them).
    pub fn rf_band_sampling(&self) -> Result<BandSampling> {
        let fs = self.sampling_frequency;
        let half = fs / 2.0;
        let (fc, b) = (self.probe.center_frequency, self.probe.bandwidth);
        let (low, high) = (fc * (1.0 - b / 2.0), fc * (1.0 + b / 2.0));
        let zone = (low / half).floor();
        // A band edge on a zone edge does not fold; rounding must not say it does.
        if high > (zone + 1.0) * half * (1.0 + 1e-12) {
            return Err(invalid(
                "sampling frequency",
                format!(
                    "{:.4} MHz folds the RF band {:.3}–{:.3} MHz (f_c {:.3} MHz, bandwidth {:.0} %) \
                     onto itself: the band straddles {:.4} MHz, a multiple of f_s/2, so its \
                     frequencies alias onto each other. Sample above {:.4} MHz (twice the band's \
                     top), or within a band-pass window that holds the whole band",
                    fs * 1e-6,
                    low * 1e-6,
                    high * 1e-6,
                    fc * 1e-6,
                    b * 100.0,
                    (zone + 1.0) * half * 1e-6,
                    2.0 * high * 1e-6
                ),
            ));
        }
        Ok(if zone >= 1.0 {
            BandSampling::BandPass {
                zone: zone as usize,
            }
        } else {
            BandSampling::Nyquist
        })
    }

    /// Slow-time sampling rate of each angle (Hz) = event PRF / number of angles.
    pub fn frame_rate(&self) -> f64 {
        self.sequence.frame_rate()
    }

    /// Largest unaliased projection velocity V_θ (m/s) ([`crate::estimate::doppler::nyquist_velocity`]).
    pub fn nyquist_velocity(&self) -> f64 {
        crate::estimate::doppler::nyquist_velocity(
            self.sound_speed,
            self.frame_rate(),
            self.probe.center_frequency,
        )
    }
}

/// How RF samples hold the probe's band ([`Acquisition::rf_band_sampling`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BandSampling {
    /// f_s is at least twice the band's top.
    Nyquist,
    /// The band lies whole in Nyquist zone `zone` ≥ 1, [zone·f_s/2, (zone + 1)·f_s/2]: valid,
    /// and demodulated as such, but a band edge set too optimistically would fold.
    BandPass {
        /// The Nyquist zone that holds the band.
        zone: usize,
    },
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
    /// The largest magnitude of the first `events` events' samples (of an IQ sample's parts),
    /// in the samples' units: what [`crate::core::lags::check_sample_peak`] tests.
    pub fn peak_of_first_events(&self, events: usize) -> f32 {
        use crate::core::lags::{complex_peak_magnitude, peak_magnitude};
        let head = |n: usize| ndarray::s![..events.min(n), .., ..];
        match self {
            Samples::Rf(a) => peak_magnitude(a.slice(head(a.dim().0))),
            Samples::Iq { data, .. } => complex_peak_magnitude(data.slice(head(data.dim().0))),
        }
    }

    /// True when some sample is not zero.
    pub fn any_nonzero(&self) -> bool {
        match self {
            Samples::Rf(a) => a.iter().any(|&v| v != 0.0),
            Samples::Iq { data, .. } => data.iter().any(|v| v.re != 0.0 || v.im != 0.0),
        }
    }

    /// The records of compound frames `frames` of `n` events as [`Decoder::decode_in_place`]
    /// leaves them (event f·n + k: angle k's record of frame f), viewed per angle: (angles,
    /// frames, channels, samples). Samples in standard layout (as read, and as decoding in
    /// place leaves them), or an error.
    ///
    /// [`Decoder::decode_in_place`]: crate::form::decode::Decoder::decode_in_place
    pub fn decoded_frames(
        &self,
        n: usize,
        frames: std::ops::Range<usize>,
    ) -> Result<AngleSamplesView<'_>> {
        fn per_angle<T>(
            events: &Array3<T>,
            n: usize,
            frames: std::ops::Range<usize>,
        ) -> Result<ArrayView4<'_, T>> {
            let (total, channels, samples) = events.dim();
            if n == 0 || frames.start > frames.end || frames.end * n > total {
                return Err(Error::Shape(format!(
                    "frames {frames:?} of {n} events from {total} events"
                )));
            }
            let kept = events.slice(ndarray::s![frames.start * n..frames.end * n, .., ..]);
            let by_frame = kept
                .into_shape_with_order((frames.len(), n, channels, samples))
                .map_err(|e| Error::Shape(format!("decoded frames not in standard layout: {e}")))?;
            Ok(by_frame.permuted_axes([1, 0, 2, 3]))
        }
        Ok(match self {
            Samples::Rf(a) => AngleSamplesView::Rf(per_angle(a, n, frames)?),
            Samples::Iq {
                data,
                demod_frequency,
            } => AngleSamplesView::Iq {
                data: per_angle(data, n, frames)?,
                demod_frequency: *demod_frequency,
            },
        })
    }

    /// Whether every sample is finite (no NaN or Inf), checked on every core.
    pub fn all_finite(&self) -> bool {
        match self {
            Samples::Rf(a) => match a.as_slice_memory_order() {
                Some(values) => floats_finite_on_every_core(values),
                None => a.iter().all(|v| v.is_finite()),
            },
            Samples::Iq { data, .. } => complex_finite_on_every_core(data.view()),
        }
    }

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
    /// Checks parameters, shapes (channels = elements, whole compound frames), that RF samples
    /// do not fold the probe's band ([`Acquisition::rf_band_sampling`]) and finiteness.
    pub fn validate(&self) -> Result<()> {
        self.acquisition.validate()?;
        if let Samples::Rf(_) = self.samples {
            self.acquisition.rf_band_sampling()?;
        }
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
        // On every core: a block of a recording is about a gigabyte, which one core takes a
        // noticeable share of a run to scan.
        if !self.samples.all_finite() {
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

/// Per-angle records borrowed where they lie, (angles, frames, channels, samples): an
/// [`AngleSamples`] or a block decoded in place ([`Samples::decoded_frames`]).
#[derive(Debug, Clone, Copy)]
pub enum AngleSamplesView<'a> {
    /// Real RF.
    Rf(ArrayView4<'a, f32>),
    /// Complex baseband.
    Iq {
        /// The samples.
        data: ArrayView4<'a, Complex32>,
        /// Demodulation frequency (Hz).
        demod_frequency: f64,
    },
}

impl AngleSamplesView<'_> {
    /// (angles, frames, channels, samples).
    pub fn dim(&self) -> (usize, usize, usize, usize) {
        match self {
            AngleSamplesView::Rf(a) => a.dim(),
            AngleSamplesView::Iq { data, .. } => data.dim(),
        }
    }
}

impl AngleSamples {
    /// The records, borrowed.
    pub fn view(&self) -> AngleSamplesView<'_> {
        match self {
            AngleSamples::Rf(a) => AngleSamplesView::Rf(a.view()),
            AngleSamples::Iq {
                data,
                demod_frequency,
            } => AngleSamplesView::Iq {
                data: data.view(),
                demod_frequency: *demod_frequency,
            },
        }
    }

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
