//! Image formation: Hadamard decoding of coded events, IQ demodulation, delay-and-sum
//! beamforming per angle, and the per-angle image series that carries the result downstream.

pub mod beamform;
pub mod decode;
pub mod images;
pub mod iq;
