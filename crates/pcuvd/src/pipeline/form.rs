//! The linear part of the chain: decode, demodulate and beamform, in blocks of frames.

use std::time::Instant;

use ndarray::{Array3, ArrayViewMut3};

use super::blocks::Blocks;
use super::params::{ProcessParams, Stage, Timings};
use super::record::{angle_coverage, check_depth, recorded_depth_of};
use crate::acquisition::channel::{Acquisition, ChannelData};
use crate::acquisition::source::FrameSource;
use crate::core::error::{Error, Result, invalid};
use crate::form::beamform::{self};
use crate::form::decode;
use crate::form::images::AngleImages;
use crate::form::iq;
use num_complex::Complex32;

/// The linear part of the chain: decode, demodulate and beamform every angle. Returns the
/// per-angle IQ image series (nz, nx, frames) with their metadata and the stage timings. Because
/// every step is linear in the channel data, images of signal and of noise may be formed apart
/// and added later.
pub fn form_images(
    data: &ChannelData,
    params: &ProcessParams,
    progress: &dyn Fn(Stage, usize, usize),
) -> Result<(AngleImages, Timings)> {
    data.validate()?;
    form_images_in_blocks(data, params, Blocks::whole(data.n_frames()), progress)
}

/// As [`form_images`], a block of frames at a time from `source` ([`Blocks`]): the memory it
/// needs beyond the image series is one block's, not the recording's. Decoding, demodulation
/// and beamforming act on each frame alone, so blocks give the whole-recording images exactly,
/// except for coded recordings with mid-frame event alignment, whose resampling reaches
/// `blocks.margin` frames beyond each block (see [`Blocks::ALIGNMENT_MARGIN`]).
pub fn form_images_in_blocks(
    source: &dyn FrameSource,
    params: &ProcessParams,
    blocks: Blocks,
    progress: &dyn Fn(Stage, usize, usize),
) -> Result<(AngleImages, Timings)> {
    form_images_of(
        source,
        params,
        blocks,
        0..source.n_frames(),
        Vec::new(),
        &mut BlockBuffers::default(),
        progress,
    )
}

/// As [`form_images_in_blocks`], for the compound frames `frames` of `source` only (a segment of
/// a long recording): their images are those of the whole recording's path, the decoding
/// margins reaching into the frames around them. The series are formed in `spare`'s memory
/// where it has room (the previous segment's series, done with), and the events are read into
/// `buffers`' (the previous segment's, kept for the next).
pub fn form_images_of(
    source: &dyn FrameSource,
    params: &ProcessParams,
    blocks: Blocks,
    frames: std::ops::Range<usize>,
    mut spare: Vec<Array3<Complex32>>,
    buffers: &mut BlockBuffers,
    progress: &dyn Fn(Stage, usize, usize),
) -> Result<(AngleImages, Timings)> {
    let acq = source.acquisition();
    acq.validate()?;
    let (_, n_samples) = source.trace_shape();
    check_depth(recorded_depth_of(acq, n_samples), &params.grid)?;
    if frames.start >= frames.end || frames.end > source.n_frames() {
        return Err(invalid(
            "frames",
            format!(
                "{frames:?} is not a range of the recording's {} frames",
                source.n_frames()
            ),
        ));
    }
    let angles = &acq.sequence.angles;
    let n = angles.len();
    let first = frames.start;
    let (nz, nx) = params.grid.shape();
    // The beamformer writes every element of the series.
    spare.truncate(n);
    let mut series: Vec<Array3<Complex32>> = (0..n)
        .map(|_| crate::core::buffers::array_reusing(spare.pop(), (nz, nx, frames.len())))
        .collect();
    let ranges = blocks.ranges_in(frames, source.n_frames());
    let (mut decode_s, mut beamform_s) = (0.0, 0.0);
    let mut recorded = false;
    let largest = ranges.iter().map(|(_, decoded)| decoded.len()).max();
    buffers.make_room(acq, largest.unwrap_or(0) * n, source.trace_shape());
    for (b, (block, decoded)) in ranges.iter().enumerate() {
        let frames_of_block = ndarray::s![.., .., block.start - first..block.end - first];
        let formed = form_block_into(
            source,
            params,
            block.clone(),
            decoded.clone(),
            series
                .iter_mut()
                .map(|image| image.slice_mut(frames_of_block))
                .collect(),
            buffers,
            &|stage, k| {
                let (done, total) = match stage {
                    Stage::Decode => (b, ranges.len()),
                    _ => (b * n + k, ranges.len() * n),
                };
                progress(stage, done, total)
            },
        )?;
        decode_s += formed.decode_s;
        beamform_s += formed.beamform_s;
        recorded = recorded || formed.recorded;
    }
    // One angle's IQ is let go here: kept through the segment's analysis, it would raise the
    // run's peak above what [`memory_estimate`](super::memory_estimate) counts.
    buffers.iq.data = Array3::zeros((0, 0, 0));
    if !recorded {
        // Zeros beamform to zeros, and every map of them would be NaN or empty: a recording of
        // nothing (a scanner that did not record, a wrong variable) is refused.
        return Err(invalid(
            "samples",
            "every sample is zero: the recording holds no echo",
        ));
    }
    progress(Stage::Decode, ranges.len(), ranges.len());
    progress(Stage::Beamform, ranges.len() * n, ranges.len() * n);
    let images = AngleImages {
        grid: params.grid.clone(),
        angles: angles.clone(),
        frame_rate: acq.frame_rate(),
        sound_speed: acq.sound_speed,
        demodulation_frequency: acq.probe.center_frequency,
        coverage: Some(angle_coverage(acq, n_samples, &params.grid)),
        series,
    };
    Ok((
        images,
        vec![(Stage::Decode, decode_s), (Stage::Beamform, beamform_s)],
    ))
}

/// The images of one block of frames, per angle, and the seconds its decoding and its
/// demodulation + beamforming took.
pub struct BlockImages {
    /// Per angle, the block's image series (nz, nx, block frames).
    pub images: Vec<Array3<Complex32>>,
    /// Seconds spent reading and decoding.
    pub decode_s: f64,
    /// Seconds spent demodulating and beamforming.
    pub beamform_s: f64,
    /// True when some sample of the decoded frames is not zero.
    pub recorded: bool,
}

/// What forming one block into given images took: seconds reading and decoding, seconds
/// demodulating and beamforming, and whether any decoded sample was not zero.
#[derive(Debug, Clone, Copy)]
pub struct BlockFormed {
    /// Seconds spent reading and decoding.
    pub decode_s: f64,
    /// Seconds spent demodulating and beamforming.
    pub beamform_s: f64,
    /// True when some sample of the decoded frames is not zero.
    pub recorded: bool,
}

/// Forms the images of frames `block` of `source`, decoding frames `decoded` (which holds
/// `block`, plus the margin the event alignment needs): one step of [`form_images_in_blocks`],
/// for callers that combine blocks of several sources (echoes and noise, say) as they come.
/// `progress(stage, k)` is called before decoding (k = 0) and before each angle k is beamformed.
pub fn form_block(
    source: &dyn FrameSource,
    params: &ProcessParams,
    block: std::ops::Range<usize>,
    decoded: std::ops::Range<usize>,
    progress: &dyn Fn(Stage, usize),
) -> Result<BlockImages> {
    let (nz, nx) = params.grid.shape();
    let mut images: Vec<Array3<Complex32>> = (0..source.acquisition().sequence.n_angles())
        .map(|_| Array3::zeros((nz, nx, block.len())))
        .collect();
    let formed = form_block_into(
        source,
        params,
        block,
        decoded,
        images.iter_mut().map(|image| image.view_mut()).collect(),
        &mut BlockBuffers::default(),
        progress,
    )?;
    Ok(BlockImages {
        images,
        decode_s: formed.decode_s,
        beamform_s: formed.beamform_s,
        recorded: formed.recorded,
    })
}

/// The working arrays of [`form_block_into`], kept from one block to the next: the events read
/// (and decoded in place; kept from one segment to the next too) and one angle's IQ. Fresh arrays of that size (about 1 GB) cost more to
/// fault in and zero than decoding them takes.
pub struct BlockBuffers {
    read: Option<ChannelData>,
    iq: iq::IqChannels,
}

impl Default for BlockBuffers {
    fn default() -> Self {
        BlockBuffers {
            read: None,
            iq: iq::IqChannels {
                data: Array3::zeros((0, 0, 0)),
                sampling_frequency: 0.0,
                t0: 0.0,
                demod_frequency: 0.0,
            },
        }
    }
}

impl BlockBuffers {
    /// Makes the array of events read hold room for `events` events of `trace` (channels,
    /// samples) real samples from the start, in the memory it has where that is enough: a
    /// recording's first block is shorter than the next (it has no frames before it), and would
    /// otherwise leave an array too small for them; and a segment's blocks are read into the
    /// previous segment's memory, whose pages are already faulted in (on a virtual machine that
    /// hands freed memory back to its host, a fresh gigabyte can cost seconds of system time).
    /// The array holds whole events: the last block's, to be read over, or new room of zeros
    /// that the system maps in as samples are first read into it (zeroing it here was a pass
    /// over the whole block before the read wrote it again).
    fn make_room(&mut self, acquisition: &Acquisition, events: usize, trace: (usize, usize)) {
        let per_event = trace.0 * trace.1;
        let room = events * per_event;
        // Memory too small is dropped before new memory is reserved.
        let kept = match self.read.take().map(|block| block.samples) {
            Some(crate::acquisition::channel::Samples::Rf(array)) => {
                Some(array.into_raw_vec_and_offset().0).filter(|memory| memory.capacity() >= room)
            }
            _ => None,
        };
        let mut memory = kept.unwrap_or_else(|| bytemuck::zeroed_vec(room));
        let held = memory.len().checked_div(per_event).unwrap_or(0);
        memory.truncate(held * per_event);
        let array = Array3::from_shape_vec((held, trace.0, trace.1), memory)
            .expect("whole events of the trace's samples");
        self.read = Some(ChannelData {
            acquisition: acquisition.clone(),
            samples: crate::acquisition::channel::Samples::Rf(array),
        });
    }
}

/// As [`form_block`], into `images` (per angle, (nz, nx, block frames)): the block's frames of
/// the recording's series, written in place, with the working arrays of `buffers`.
pub fn form_block_into(
    source: &dyn FrameSource,
    params: &ProcessParams,
    block: std::ops::Range<usize>,
    decoded: std::ops::Range<usize>,
    mut images: Vec<ArrayViewMut3<Complex32>>,
    buffers: &mut BlockBuffers,
    progress: &dyn Fn(Stage, usize),
) -> Result<BlockFormed> {
    let acq = source.acquisition();
    let n_angles = acq.sequence.n_angles();
    if !(decoded.start <= block.start && block.end <= decoded.end && block.start < block.end) {
        return Err(invalid(
            "frames",
            format!("block {block:?} is not within the decoded frames {decoded:?}"),
        ));
    }
    if images.len() != n_angles {
        return Err(Error::Shape(format!(
            "{} image series for {n_angles} angles",
            images.len(),
        )));
    }
    let clock = Instant::now();
    progress(Stage::Decode, 0);
    source.read_frames_into(decoded.clone(), &mut buffers.read)?;
    let data = buffers.read.as_ref().expect("just read");
    // A recording is scaled as a whole: each block's first frame stands for it, at no cost
    // worth a pass over the block.
    crate::core::lags::check_sample_peak(
        data.samples.peak_of_first_events(n_angles),
        &format!("the samples of frame {}", decoded.start),
    )?;
    let recorded = data.samples.any_nonzero();
    let kept = block.start - decoded.start..block.end - decoded.start;
    let data = buffers.read.as_mut().expect("just read");
    decode::Decoder::new(data, params.event_alignment)?
        .decode_in_place(&mut data.samples, kept.clone())?;
    let per_angle = data.samples.decoded_frames(n_angles, kept)?;
    let decode_s = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    // One angle's IQ at a time, in one array.
    let channels = &mut buffers.iq;
    for (k, (&angle, image)) in acq.sequence.angles.iter().zip(&mut images).enumerate() {
        progress(Stage::Beamform, k);
        iq::demodulate_into(
            per_angle,
            k,
            acq.t0,
            acq.sampling_frequency,
            acq.probe.center_frequency,
            params.iq_cutoff,
            channels,
        )?;
        beamform::beamform_into(
            channels,
            &acq.probe,
            angle,
            &params.grid,
            &params.das,
            image.view_mut(),
        )?;
    }
    Ok(BlockFormed {
        decode_s,
        beamform_s: clock.elapsed().as_secs_f64(),
        recorded,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read_memory(buffers: &BlockBuffers) -> (*const f32, usize) {
        match &buffers.read.as_ref().expect("room made").samples {
            crate::acquisition::channel::Samples::Rf(array) => {
                let room = array.len_of(ndarray::Axis(0));
                (array.as_ptr(), room)
            }
            _ => panic!("the room is for real samples"),
        }
    }

    #[test]
    fn a_segment_reads_into_the_memory_the_one_before_left_when_it_is_large_enough() {
        let acq = crate::simulate::rat_params(true).unwrap().acquisition();
        let mut buffers = BlockBuffers::default();
        buffers.make_room(&acq, 64, (4, 16));
        let (first, events) = read_memory(&buffers);
        assert_eq!(events, 64, "new room is events of zeros");
        buffers.make_room(&acq, 48, (4, 16));
        assert_eq!(read_memory(&buffers), (first, 64));
        buffers.make_room(&acq, 64, (4, 16));
        assert_eq!(read_memory(&buffers), (first, 64));
        // Another trace shape: the memory's whole events of it.
        buffers.make_room(&acq, 40, (3, 16));
        assert_eq!(read_memory(&buffers), (first, 64 * 4 / 3));
        // More than it has: new room, enough for the events asked for.
        buffers.make_room(&acq, 4096, (4, 16));
        let Some(ChannelData {
            samples: crate::acquisition::channel::Samples::Rf(array),
            ..
        }) = buffers.read.take()
        else {
            panic!("room made")
        };
        assert!(array.into_raw_vec_and_offset().0.capacity() >= 4096 * 4 * 16);
    }
}
