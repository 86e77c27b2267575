//! pcuvd — pulse-coded ultrafast vector Doppler: the science.
//!
//! Folders in the order data flows through them:
//! - [`core`]: the error type, statistics, the one time-of-flight convention ([`core::geometry`]),
//!   the pixel [`core::grid`], vessel class codes;
//! - [`acquisition`]: the probe, the transmit sequence and its Hadamard code, channel data, and
//!   recordings read a block of frames at a time;
//! - [`simulate`]: RF channel data of flow phantoms ([`simulate::phantom`]) with ground truth;
//! - [`form`]: Hadamard decoding, IQ demodulation, delay-and-sum beamforming per angle, the
//!   per-angle image series;
//! - [`estimate`]: SVD clutter filtering, autocorrelation Doppler, flow masks, the vector solve
//!   (LS = UVD, IRLS = PC-UVD), vector dealiasing, the partial-volume correction;
//! - [`dynamics`]: velocities over the cardiac cycle (PSV, EDV, RI, artery/vein classes);
//! - [`pipeline`]: the chain in order, on a whole recording, in segments, or as ensembles;
//! - [`evaluate`]: scores against truth, each with its written definition;
//! - [`study`]: the paper's studies end to end, with settings and typed results.
//!
//! Units are SI throughout (m, s, Hz, m/s). No printing, no file formats, no plotting here.

#![warn(missing_docs)]

pub mod acquisition;
pub mod core;
pub mod dynamics;
pub mod estimate;
pub mod evaluate;
pub mod form;
pub mod pipeline;
pub mod simulate;
pub mod study;

pub use acquisition::channel::{
    Acquisition, AngleSamples, AngleSamplesView, BandSampling, ChannelData, Samples,
};
pub use acquisition::hadamard::Hadamard;
pub use acquisition::probe::Probe;
pub use acquisition::sequence::{Coding, Sequence, TransmitCode, TransmitPulse};
pub use core::error::{Error, Result};
