//! Recordings read a block of frames at a time, so that the chain's memory is bounded by the
//! block, not by the recording's length.

use std::ops::Range;

use ndarray::{Array, Dimension, IntoDimension, s};
use num_traits::Zero;

use crate::channel::{Acquisition, ChannelData, Samples};
use crate::error::{Result, invalid};

/// An array of `shape` in `old`'s memory where that has room for it, else a new one: blocks of
/// frames come one after another in sizes that differ a little (a recording's first and last),
/// and fresh pages cost more to fault in and zero than the work done on them. The elements'
/// values are unspecified (the old array's or zeros): callers write every one.
pub fn array_reusing<T: Clone + Zero, D: Dimension>(
    old: Option<Array<T, D>>,
    shape: impl IntoDimension<Dim = D>,
) -> Array<T, D> {
    let shape = shape.into_dimension();
    let len = shape.size();
    let memory = old
        .map(|array| array.into_raw_vec_and_offset().0)
        .filter(|memory| memory.capacity() >= len);
    // (Memory too small is dropped by now, before the new array is allocated.)
    let memory = match memory {
        Some(mut memory) => {
            memory.resize(len, T::zero());
            memory
        }
        None => vec![T::zero(); len],
    };
    Array::from_shape_vec(shape, memory).expect("exactly the shape's number of elements")
}

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
        let samples = match &self.samples {
            Samples::Rf(a) => Samples::Rf(a.slice(s![events, .., ..]).to_owned()),
            Samples::Iq {
                data,
                demod_frequency,
            } => Samples::Iq {
                data: data.slice(s![events, .., ..]).to_owned(),
                demod_frequency: *demod_frequency,
            },
        };
        Ok(ChannelData {
            acquisition: self.acquisition.clone(),
            samples,
        })
    }
}

/// How the linear part of the chain walks through a recording: blocks of `frames` compound frames,
/// each decoded with `margin` extra frames on either side (where the recording has them) so that
/// mid-frame event alignment, which resamples each event's slow-time series, sees the block's
/// neighbours; only the block's own frames are beamformed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Blocks {
    /// Compound frames per block at most (≥ 1); the blocks of a range share it evenly.
    pub frames: usize,
    /// Frames decoded on either side of a block and then dropped.
    pub margin: usize,
}

impl Blocks {
    /// Frames decoded beyond each side of a block of a coded, mid-frame-aligned recording: the
    /// alignment's reach ([`crate::decode::ALIGN_HALF`]). Each aligned frame is a weighted sum of
    /// that many frames on either side, so a block's frames come out as the whole recording's
    /// (`tests/blocks.rs`); near the recording's own ends see [`Blocks::END_FRAMES`].
    pub const ALIGNMENT_MARGIN: usize = crate::decode::ALIGN_HALF;

    /// Frames a decoded range holds at least where it reaches an end of the recording (with a
    /// margin): those the alignment's linear predictor is fitted on
    /// ([`crate::decode::ALIGN_FIT_FRAMES`]), so that it predicts beyond the end as the whole
    /// recording's does.
    pub const END_FRAMES: usize = crate::decode::ALIGN_FIT_FRAMES;

    /// The whole recording of `frames` frames as one block: the reference path.
    pub fn whole(frames: usize) -> Blocks {
        Blocks {
            frames: frames.max(1),
            margin: 0,
        }
    }

    /// Each block's frames and the frames decoded for it: (block, decoded), in order.
    pub fn ranges(&self, total: usize) -> Vec<(Range<usize>, Range<usize>)> {
        self.ranges_in(0..total, total)
    }

    /// As [`Blocks::ranges`], for the frames `frames` of a recording of `total` frames: the
    /// blocks tile `frames`, and their margins reach into the frames around it (a segment of a
    /// long recording decodes as the whole recording would). With a margin, a decoded range
    /// that reaches the recording's first or last frame holds at least [`Blocks::END_FRAMES`]
    /// frames (all, when fewer): beyond its ends the alignment continues the series by a
    /// predictor fitted on that many frames, which must be the whole recording's.
    pub fn ranges_in(
        &self,
        frames: Range<usize>,
        total: usize,
    ) -> Vec<(Range<usize>, Range<usize>)> {
        let step = self.frames.max(1);
        let end_of_frames = frames.end.min(total);
        let at_ends = if self.margin > 0 {
            Self::END_FRAMES.min(total)
        } else {
            0
        };
        // As few blocks as hold at most `step` frames each, sharing the frames evenly: a last
        // block of a few frames would cost a whole block's margins.
        let len = end_of_frames.saturating_sub(frames.start);
        let count = len.div_ceil(step);
        (0..count)
            .map(|i| {
                let start = frames.start + i * len / count;
                let end = frames.start + (i + 1) * len / count;
                let mut first = start.saturating_sub(self.margin);
                let mut last = (end + self.margin).min(total);
                if first == 0 {
                    last = last.max(at_ends);
                }
                if last == total {
                    first = first.min(total - at_ends);
                }
                (start..end, first..last)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An array takes the old one's memory where it has room (shorter, then as long again),
    /// and new memory where it has not; either way it has the asked-for shape, in standard
    /// layout.
    #[test]
    fn arrays_reuse_memory_with_room() {
        let old = ndarray::Array3::<f32>::from_elem((4, 3, 5), 1.5);
        let memory = old.as_ptr();
        let shorter = array_reusing(Some(old), (2, 3, 5));
        assert_eq!(shorter.dim(), (2, 3, 5));
        assert_eq!(shorter.as_ptr(), memory);
        let again = array_reusing(Some(shorter), (4, 3, 5));
        assert_eq!(again.as_ptr(), memory);
        assert!(again.is_standard_layout());
        let longer = array_reusing(Some(again), (5, 3, 5));
        assert_eq!(longer.dim(), (5, 3, 5));
        assert!(longer.is_standard_layout());
        let fresh = array_reusing::<f32, _>(None, (1, 2, 3));
        assert!(fresh.iter().all(|&v| v == 0.0));
    }

    #[test]
    fn blocks_tile_the_recording_and_margins_stay_inside_it() {
        let blocks = Blocks {
            frames: 4,
            margin: 2,
        };
        // Ranges that reach an end hold the predictor's END_FRAMES frames: here all 10.
        assert_eq!(
            blocks.ranges(10),
            vec![(0..3, 0..10), (3..6, 1..8), (6..10, 0..10)]
        );
        assert_eq!(Blocks::whole(10).ranges(10), vec![(0..10, 0..10)]);
        let blocks = Blocks {
            frames: 8,
            margin: 2,
        };
        let ranges = blocks.ranges(60);
        // Eight blocks of 7 or 8 frames, not seven of 8 and one of 4.
        assert_eq!(ranges.len(), 8);
        assert!(ranges.iter().all(|(b, _)| (7..=8).contains(&b.len())));
        assert_eq!(ranges[0], (0..7, 0..Blocks::END_FRAMES));
        assert_eq!(ranges[1], (7..15, 5..17));
        assert_eq!(ranges[6], (45..52, 43..54));
        assert_eq!(ranges[7], (52..60, 60 - Blocks::END_FRAMES..60));
        // Without a margin (nothing aligned) every block decodes only itself.
        let bare = Blocks {
            frames: 8,
            margin: 0,
        };
        assert!(bare.ranges(60).iter().all(|(b, d)| b == d));
    }
}
