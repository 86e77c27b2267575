//! How much memory a run needs, and how the chain's blocks and segments are sized to bound it.

use super::blocks::Blocks;
use crate::acquisition::source::FrameSource;
use crate::core::grid::Grid;
use crate::form::decode;

/// How [`memory_estimate`] counts.
pub const MEMORY_ESTIMATE_RULE: &str = "the input's samples held in memory (none when they are \
read from the file a block at a time) + one \
block's working memory (BLOCK_BYTES, or the whole recording's decoding and IQ when it is \
smaller) + (1 + 1/angles) × pixels × frames × angles × 8 bytes (the image series, complex64, \
filtered in place, and a compound of it, formed after the clutter filter, whose block-wise \
filter keeps its cells' Gram matrices in that room first); frames: the recording's, or one segment's when it is \
processed in segments: as few segments of even length as fit in segments::SERIES_BYTES and hold \
at most segments::MAX_SEGMENT_FRAMES frames, before \
the frames that dynamics windows and ensembles reach past a segment). FFT and filter lengths are \
bounded by the data: a slot shift by less than a record \
(check_record), an IQ filter of at most 3·10⁴ taps (iq::MIN_CUTOFF_RATIO), a slow-time FFT of \
twice the frames of a block";

/// Working memory a block of frames may take while it is decoded, demodulated and beamformed
/// (bytes): [`blocks_for`] sizes blocks to it.
pub const BLOCK_BYTES: u64 = 1 << 30;

/// Bytes one compound frame takes while its block is formed into images: (events read and
/// decoded in place (f32), one angle's IQ (complex64)). Margin frames are only read.
fn block_bytes_per_frame(source: &dyn FrameSource) -> (u64, u64) {
    let (channels, samples) = source.trace_shape();
    let trace = (channels * samples) as u64;
    let angles = source.acquisition().sequence.n_angles() as u64;
    (angles * trace * 4, trace * 8)
}

/// Bytes a block of `frames` frames and `margin` frames on either side takes while it is
/// formed into images.
fn block_bytes(source: &dyn FrameSource, frames: usize, margin: usize) -> u64 {
    let (read, iq) = block_bytes_per_frame(source);
    (frames + 2 * margin) as u64 * read + frames as u64 * iq
}

/// The blocks `process` forms images in: as many frames as fit in [`BLOCK_BYTES`] with their
/// margins (the whole recording when it fits), with [`Blocks::ALIGNMENT_MARGIN`] frames on
/// either side for coded recordings aligned at mid-frame.
pub fn blocks_for(source: &dyn FrameSource, alignment: decode::EventAlignment) -> Blocks {
    let frames = source.n_frames();
    if block_bytes(source, frames, 0) <= BLOCK_BYTES {
        return Blocks::whole(frames);
    }
    let coded = source.acquisition().sequence.decodes_events();
    let margin = if coded && alignment == decode::EventAlignment::MidFrame {
        Blocks::ALIGNMENT_MARGIN
    } else {
        0
    };
    let (read, iq) = block_bytes_per_frame(source);
    let room = BLOCK_BYTES.saturating_sub(2 * margin as u64 * read);
    // At least a margin's worth of frames, or the margins would be most of the work.
    let fit = ((room / (read + iq).max(1)) as usize).max(margin).max(1);
    Blocks {
        frames: fit,
        margin,
    }
}

/// Bytes `process` needs for `source` on `grid`, formed in [`blocks_for`] blocks, by
/// [`MEMORY_ESTIMATE_RULE`]: a rule of thumb from the buffers it holds at its peak.
pub fn memory_estimate(source: &dyn FrameSource, grid: &Grid) -> u128 {
    let (nz, nx) = grid.shape();
    let angles = source.acquisition().sequence.n_angles();
    let total = source.n_frames();
    let frames = frames_held(total, nz * nx, angles) as u128;
    let angles = angles as u128;
    let blocks = blocks_for(source, decode::EventAlignment::MidFrame);
    let block = block_bytes(
        source,
        blocks.frames.min(total),
        blocks.margin.min(total.saturating_sub(blocks.frames) / 2),
    ) as u128;
    let series = (nz * nx) as u128 * frames * angles * 8;
    source.resident_bytes() as u128 + block + series + series / angles.max(1)
}

/// Bytes of per-angle image series (complex64) one segment may hold: 1.25 GiB. With a block's
/// working memory (up to 1 GiB) and the series' compound, a segmented run peaks near 2.6 GB
/// whatever the recording's length. A smaller budget means more, shorter segments, each with
/// its own clutter filter and its overlap imaged twice; at 1.25 GiB the rat grid's segments
/// hold 180–221 frames (0.1 s or more), and the paper's 360-frame recording, like a five times
/// longer one, is cut into segments of about 200 frames, so both peak alike.
pub const SERIES_BYTES: u64 = 5 << 28;

/// Frames one segment holds at most by default, whatever the memory allows. The clutter filter's
/// temporal Gram matrix grows as frames², its cost per frame as pixels × frames, and each
/// block's eigendecomposition as frames³: on a small grid (functional ultrasound's 128 × 128
/// images) segments as long as memory allows (10,000 frames and more) would each need
/// gigabytes and many minutes. 6,000 such frames took 41 s of clutter filter in segments of
/// 1,000 frames, 10 s in segments of 512 and 4 s of 256, with the same maps. 512 frames
/// (0.25–1 s at 500–2,000 Hz) are longer than the 200–400-frame ensembles functional
/// ultrasound filters, and than every shipped scenario.
pub const MAX_SEGMENT_FRAMES: usize = 512;

/// Frames of per-angle images of `angles` angles on `pixels` pixels that a run of `total` frames
/// holds at once by default: all of them, or, for a recording longer than one segment, one
/// segment's, segments sharing the recording evenly (before the frames that dynamics windows
/// and ensembles reach past a segment).
pub fn frames_held(total: usize, pixels: usize, angles: usize) -> usize {
    let fit = default_segment_frames(pixels, angles).max(1);
    total.div_ceil(total.div_ceil(fit).max(1))
}

/// Frames of a segment by default: those of per-angle images of `angles` angles on `pixels`
/// pixels that fit in [`SERIES_BYTES`], at most [`MAX_SEGMENT_FRAMES`].
pub fn default_segment_frames(pixels: usize, angles: usize) -> usize {
    let fit = SERIES_BYTES / (pixels.max(1) * angles.max(1) * 8) as u64;
    (fit as usize).min(MAX_SEGMENT_FRAMES)
}
