//! pcuvd — pulse-coded ultrafast vector Doppler: the science.
//!
//! One module per pipeline stage, in the order data flows through them:
//! [`probe`] and [`sequence`] describe an acquisition, [`hadamard`] its code, [`geometry`] the one
//! time-of-flight convention; [`channel`] holds recordings; [`decode`] separates angles; [`iq`]
//! demodulates; [`beamform`] forms per-angle IQ images on a [`grid`] of pixels; [`clutter`] removes
//! tissue; [`doppler`] measures power and projection velocity; [`vector`] solves for (Vx, Vz),
//! [`dealias`] unwraps projections beyond the Nyquist velocity, [`partial_volume`] moves them from
//! each resolution cell's power centroid back to its pixel;
//! [`dynamics`] follows it over the cardiac cycle (PSV, EDV, RI, [`vessel`] classes). [`images`]
//! carries per-angle image series with their metadata; [`pipeline`] runs the chain in order.
//!
//! [`phantom`] and [`simulate`] make recordings with ground truth; [`metrics`] and [`masks`] score
//! estimates against it, each measure with its written definition; [`study`] runs the paper's two
//! studies (spiral, vessel network) end to end with settings and typed results.
//!
//! Units are SI throughout (m, s, Hz, m/s). No printing, no file formats, no plotting here.

pub mod beamform;
pub mod channel;
pub mod clutter;
pub mod dealias;
pub mod decode;
pub mod doppler;
pub mod dynamics;
pub mod ensembles;
pub mod error;
pub mod geometry;
pub mod grid;
pub mod hadamard;
pub mod images;
pub mod iq;
pub mod masks;
pub mod metrics;
pub mod partial_volume;
pub mod phantom;
pub mod pipeline;
pub mod probe;
pub mod segments;
pub mod sequence;
pub mod simulate;
pub mod source;
pub mod stats;
pub mod study;
pub mod vector;
pub mod vessel;

pub use channel::{
    Acquisition, AngleSamples, AngleSamplesView, BandSampling, ChannelData, Samples,
};
pub use error::{Error, Result};
pub use hadamard::Hadamard;
pub use probe::Probe;
pub use sequence::{Coding, Sequence, TransmitCode, TransmitPulse};
