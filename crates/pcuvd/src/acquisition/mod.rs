//! What an acquisition is: the probe, the transmit sequence and its Hadamard code, the channel
//! data a scanner records, and recordings read a block of frames at a time.

pub mod channel;
pub mod hadamard;
pub mod probe;
pub mod sequence;
pub mod source;
