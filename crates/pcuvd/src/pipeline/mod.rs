//! The processing chain in order: decode → IQ → beamform ([`form`]), then clutter filter →
//! Doppler → vector velocity → dynamics ([`analyse`]). [`process_source`] runs it on a recording
//! held whole (images formed a block at a time, with the time series when asked), [`process`]
//! on one in memory; [`segments`] runs it on a long recording a segment at a time with memory bounded by a
//! segment, and [`ensembles`] cuts the result into successive Doppler ensembles. [`memory`] sizes
//! the blocks and segments, [`record`] says what a recording's samples reach.

pub mod analyse;
pub mod blocks;
pub mod ensembles;
pub mod form;
pub mod memory;
pub mod params;
pub mod record;
pub mod segments;
pub mod whole;

pub use analyse::*;
pub use form::*;
pub use memory::*;
pub use params::*;
pub use record::*;
pub use whole::{process, process_source};
