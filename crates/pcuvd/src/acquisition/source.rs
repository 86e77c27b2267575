//! Recordings read a block of frames at a time, so that the chain's memory is bounded by the
//! block, not by the recording's length.

use std::ops::Range;

use ndarray::s;

use crate::acquisition::channel::{Acquisition, ChannelData, Samples};
use crate::core::buffers::copy_reusing;
use crate::core::error::{Result, invalid};

/// A recording that hands out its compound frames in blocks: in memory ([`ChannelData`]) or read
/// from a file block by block.
pub trait FrameSource: Sync {
    /// How the recording was acquired.
    fn acquisition(&self) -> &Acquisition;
    /// Number of compound frames.
    fn n_frames(&self) -> usize;
    /// (channels, samples) of each event's trace.
    fn trace_shape(&self) -> (usize, usize);
    /// The events of compound frames `frames` (frames.len() × angles events), as a recording of
    /// their own with the same acquisition.
    fn read_frames(&self, frames: Range<usize>) -> Result<ChannelData>;
    /// As [`FrameSource::read_frames`], into `block`: a source may reuse the memory of the
    /// recording it holds (the previous block) rather than fault in and zero fresh pages.
    fn read_frames_into(
        &self,
        frames: Range<usize>,
        block: &mut Option<ChannelData>,
    ) -> Result<()> {
        *block = None;
        *block = Some(self.read_frames(frames)?);
        Ok(())
    }
    /// Bytes of samples the source holds in memory (0 for one that reads its file block by block).
    fn resident_bytes(&self) -> u64 {
        0
    }
}

impl FrameSource for ChannelData {
    fn acquisition(&self) -> &Acquisition {
        &self.acquisition
    }

    fn n_frames(&self) -> usize {
        ChannelData::n_frames(self)
    }

    fn trace_shape(&self) -> (usize, usize) {
        let (_, channels, samples) = self.samples.dim();
        (channels, samples)
    }

    fn resident_bytes(&self) -> u64 {
        let (events, channels, samples) = self.samples.dim();
        let item = match self.samples {
            Samples::Rf(_) => 4,
            Samples::Iq { .. } => 8,
        };
        (events * channels * samples) as u64 * item
    }

    fn read_frames(&self, frames: Range<usize>) -> Result<ChannelData> {
        let mut block = None;
        self.read_frames_into(frames, &mut block)?;
        Ok(block.expect("a block read"))
    }

    /// A copy of the frames' events in the previous block's memory: a recording in memory (read
    /// whole, simulated, built from arrays) is processed a block at a time as a file is.
    fn read_frames_into(
        &self,
        frames: Range<usize>,
        block: &mut Option<ChannelData>,
    ) -> Result<()> {
        let n = self.acquisition.sequence.n_angles();
        if frames.start >= frames.end || frames.end > ChannelData::n_frames(self) {
            return Err(invalid(
                "frames",
                format!(
                    "block {frames:?} is not within the recording's {} frames",
                    ChannelData::n_frames(self)
                ),
            ));
        }
        let events = frames.start * n..frames.end * n;
        let old = block.take().map(|block| block.samples);
        let samples = match &self.samples {
            Samples::Rf(a) => {
                let old = match old {
                    Some(Samples::Rf(old)) => Some(old),
                    _ => None,
                };
                Samples::Rf(copy_reusing(a.slice(s![events, .., ..]), old))
            }
            Samples::Iq {
                data,
                demod_frequency,
            } => {
                let old = match old {
                    Some(Samples::Iq { data, .. }) => Some(data),
                    _ => None,
                };
                Samples::Iq {
                    data: copy_reusing(data.slice(s![events, .., ..]), old),
                    demod_frequency: *demod_frequency,
                }
            }
        };
        *block = Some(ChannelData {
            acquisition: self.acquisition.clone(),
            samples,
        });
        Ok(())
    }
}
