//! How the linear part of the chain walks through a recording: blocks of frames with margins.

use std::ops::Range;

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
    /// alignment's reach ([`crate::form::decode::ALIGN_HALF`]). Each aligned frame is a weighted sum of
    /// that many frames on either side, so a block's frames come out as the whole recording's
    /// (`tests/integration/blocks.rs`); near the recording's own ends see [`Blocks::END_FRAMES`].
    pub const ALIGNMENT_MARGIN: usize = crate::form::decode::ALIGN_HALF;

    /// Frames a decoded range holds at least where it reaches an end of the recording (with a
    /// margin): those the alignment's linear predictor is fitted on
    /// ([`crate::form::decode::ALIGN_FIT_FRAMES`]), so that it predicts beyond the end as the whole
    /// recording's does.
    pub const END_FRAMES: usize = crate::form::decode::ALIGN_FIT_FRAMES;

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
