//! The whole processing chain, stage by stage: decode → IQ → beamform → clutter filter →
//! Doppler → vector velocity. Front ends (the CLI, bindings) call [`process`].

use std::time::Instant;

use ndarray::{Array2, Array3, ArrayViewMut3, Axis};

use crate::beamform::{self, DasParams};
use crate::channel::{Acquisition, ChannelData};
use crate::clutter::{self, ClutterParams, ClutterReport};
use crate::dealias::{self, AliasCounts, Dealias};
use crate::decode;
use crate::doppler::{self, DopplerEstimator, DopplerGeometry, Moments};
use crate::dynamics::{self, DynamicsParams, RiMaps, VelocitySeries, VesselTests};
use crate::error::{Error, Result, invalid};
use crate::grid::Grid;
use crate::images::AngleImages;
use crate::iq;
use crate::partial_volume;
use crate::source::{Blocks, FrameSource};
use crate::vector::{self, Estimator, IrlsParams, VectorField};
use num_complex::Complex32;

/// Settings of every stage of [`process`].
#[derive(Debug, Clone, PartialEq)]
pub struct ProcessParams {
    /// Pixel grid (m).
    pub grid: Grid,
    /// Delay-and-sum settings.
    pub das: DasParams,
    /// SVD clutter filter, applied to each angle's series separately.
    pub clutter: ClutterParams,
    /// Spatial averaging box (rows, cols) of the autocorrelation; odd sizes.
    pub doppler_kernel: (usize, usize),
    /// Which frequency scales the Doppler phase (see [`doppler::DopplerEstimator`]).
    pub doppler_estimator: doppler::DopplerEstimator,
    /// IRLS settings of the PC-UVD estimator.
    pub irls: IrlsParams,
    /// IQ low-pass cut-off (Hz); `None` picks [`iq::default_cutoff`].
    pub iq_cutoff: Option<f64>,
    /// How coded events are aligned in slow time before decoding (see [`decode::EventAlignment`]).
    pub event_alignment: decode::EventAlignment,
    /// Vector dealiasing of both estimators ([`crate::dealias`]); off by default.
    pub dealias: Dealias,
    /// Move each projection from its resolution cell's power centroid back to its pixel before
    /// the vector fit ([`crate::partial_volume`]); off by default.
    pub partial_volume: bool,
}

/// Pipeline stages, in order, as reported to a progress callback.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// Hadamard decoding / angle separation.
    Decode,
    /// IQ demodulation and delay-and-sum, one step per angle.
    Beamform,
    /// SVD clutter filtering, one step per angle.
    Clutter,
    /// Autocorrelation Doppler and vector solve.
    Doppler,
    /// The Doppler time series: every ensemble's clutter filter, Doppler and vectors
    /// ([`crate::ensembles`]).
    Ensembles,
}

impl Stage {
    /// Name shown to people.
    pub fn label(self) -> &'static str {
        match self {
            Stage::Decode => "decode",
            Stage::Beamform => "demodulate + beamform",
            Stage::Clutter => "clutter filter",
            Stage::Doppler => "Doppler + vector",
            Stage::Ensembles => "ensembles (time series)",
        }
    }
}

/// Everything the pipeline measured, on the grid, shape (nz, nx) for maps; SI units.
#[derive(Debug, Clone)]
pub struct ProcessOutput {
    /// The grid of every map.
    pub grid: Grid,
    /// B-mode of the compounded, unfiltered series (dB, 0 at the brightest pixel).
    pub bmode_db: Array2<f64>,
    /// Power Doppler of the compounded, clutter-filtered series (linear, |IQ|² units).
    pub power_doppler: Array2<f64>,
    /// Colour Doppler: axial velocity from the compounded series (m/s, positive = away from the probe).
    pub color_doppler: Array2<f64>,
    /// Per-angle power Doppler (angles, nz, nx), each pixel's own (not averaged over the
    /// Doppler kernel).
    pub power_per_angle: Array3<f64>,
    /// Per-angle projection velocities V_θ (angles, nz, nx), m/s; NaN where the angle's plane
    /// wave does not reach the pixel (see [`angle_coverage`]).
    pub projections: Array3<f64>,
    /// Per angle, the pixels its plane wave reaches (angles, nz, nx); see [`angle_coverage`].
    pub coverage: Array3<bool>,
    /// Per-angle lateral weight of each projection in the vector model (angles, nz, nx):
    /// sin θ (Kasai) or measured from the images (Loupas); see
    /// [`doppler::DopplerMaps::lateral_weight`].
    pub lateral_weights: Array3<f64>,
    /// Vector field by least squares (UVD); `None` with a single angle.
    pub vector_ls: Option<VectorField>,
    /// Vector field by IRLS-WLS (PC-UVD); `None` with a single angle.
    pub vector_irls: Option<VectorField>,
    /// What vector dealiasing did; `None` when it is off or with a single angle.
    pub dealias: Option<DealiasOutcome>,
    /// Nyquist velocity of each projection at the demodulation frequency (m/s): Kasai's.
    pub nyquist_velocity: f64,
    /// Nyquist velocity of each projection at each pixel (angles, nz, nx), m/s: c·f_frame/(4 f̄),
    /// f̄ the frequency its phase was scaled by (Loupas: the pixel's measured mean frequency,
    /// Kasai: the demodulation frequency everywhere). Dealiasing unwraps with these.
    pub projection_nyquist: Array3<f64>,
    /// Each angle's resolution cell at one pixel, as its speckle measures it (the partial-volume
    /// correction's; [`crate::partial_volume`]); `None` where not measurable or not measured
    /// (the correction off).
    pub cells: Vec<Option<partial_volume::CellCovariance>>,
    /// Clutter-filter cut-offs per angle.
    pub clutter: Vec<ClutterReport>,
    /// Clutter-filtered per-angle IQ series, each (nz, nx, frames), with their metadata; kept
    /// for the dynamics stage and spectrograms.
    pub filtered: AngleImages,
    /// Wall-clock seconds per stage.
    pub timings: Timings,
}

/// Wall-clock seconds per stage.
pub type Timings = Vec<(Stage, f64)>;

impl ProcessOutput {
    /// Gathers the Doppler maps ([`doppler_maps`]) with the rest of what the chain measured: the
    /// one place both the whole-recording path and the segmented one ([`crate::segments`]) build
    /// their output.
    pub fn from_maps(
        maps: DopplerMaps,
        grid: Grid,
        bmode_db: Array2<f64>,
        clutter: Vec<ClutterReport>,
        filtered: AngleImages,
        timings: Timings,
    ) -> ProcessOutput {
        ProcessOutput {
            grid,
            bmode_db,
            power_doppler: maps.power_doppler,
            color_doppler: maps.color_doppler,
            power_per_angle: maps.power_per_angle,
            projections: maps.projections,
            coverage: maps.coverage,
            lateral_weights: maps.lateral_weights,
            vector_ls: maps.vector_ls,
            vector_irls: maps.vector_irls,
            dealias: maps.dealias,
            nyquist_velocity: maps.nyquist_velocity,
            projection_nyquist: maps.projection_nyquist,
            cells: maps.cells,
            clutter,
            filtered,
            timings,
        }
    }
}

/// What vector dealiasing did to a recording's maps.
#[derive(Debug, Clone, PartialEq)]
pub struct DealiasOutcome {
    /// Nyquist intervals K unwrapped per angle (as set, or as [`Dealias::Auto`] chose).
    pub intervals: u32,
    /// Flow pixels, the ones dealiased ([`dealias::flow_mask`]).
    pub flow_pixels: usize,
    /// The alias counts of the PC-UVD (IRLS) vectors.
    pub irls: AliasCounts,
    /// The alias counts of the UVD (least-squares) vectors.
    pub ls: AliasCounts,
}

/// The warning for maps `out` of a recording processed with dealiasing `setting`; `None` where
/// dealiasing is off or did what it was asked. Two cases:
/// - fewer than 3 steering angles: the vector fit leaves nothing to tell alias patterns apart
///   (with 2 angles every pattern fits exactly, with 1 there is no vector), so nothing was
///   unwrapped, and a user who asked for it should not have to find that out from the maps;
/// - a Hadamard-`coded` recording: decoding needs every projection within ±v_N (blood moves
///   between the events of a frame), so coded flow beyond v_N decodes wrongly, fits no alias
///   pattern, and is left as garbage with or without dealiasing (on a simulated tube at 2.5× v_N
///   dealiasing unwrapped none of its lumen), and the maps do not flag it.
pub fn dealias_warning(setting: Dealias, coded: bool, out: &ProcessOutput) -> Option<String> {
    let angles = dealias::distinct_angles(&out.filtered.angles);
    if setting.is_on() && angles < dealias::MIN_DISTINCT_ANGLES {
        return Some(format!(
            "vector dealiasing needs {} or more distinct steering angles and \
             the recording has {angles}: nothing was unwrapped (--dealias {} had no effect)",
            dealias::MIN_DISTINCT_ANGLES,
            setting.label()
        ));
    }
    (coded && out.dealias.is_some()).then(|| coded_dealias_message(out.nyquist_velocity))
}

fn coded_dealias_message(nyquist_velocity: f64) -> String {
    format!(
        "dealiasing cannot recover flow faster than the Nyquist velocity ({:.1} mm/s) in a \
         Hadamard-coded recording: decoding needs every projection within it, so such flow \
         decodes wrongly whatever the dealiasing; dealias conventional recordings (or record at \
         a higher PRF)",
        nyquist_velocity * 1e3
    )
}

/// Runs the pipeline on a recording. `progress(stage, done, total)` is called as work completes.
pub fn process(
    data: &ChannelData,
    params: &ProcessParams,
    progress: &dyn Fn(Stage, usize, usize),
) -> Result<ProcessOutput> {
    check_doppler_estimator(&data.acquisition, params)?;
    let (images, mut timings) = form_images(data, params, progress)?;
    let mut out = analyse(images, params, progress)?;
    timings.append(&mut out.timings);
    out.timings = timings;
    Ok(out)
}

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
        progress,
    )
}

/// As [`form_images_in_blocks`], for the compound frames `frames` of `source` only (a segment of
/// a long recording): their images are those of the whole recording's path, the decoding
/// margins reaching into the frames around them. The series are formed in `spare`'s memory
/// where it has room (the previous segment's series, done with).
pub fn form_images_of(
    source: &dyn FrameSource,
    params: &ProcessParams,
    blocks: Blocks,
    frames: std::ops::Range<usize>,
    mut spare: Vec<Array3<Complex32>>,
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
        .map(|_| crate::source::array_reusing(spare.pop(), (nz, nx, frames.len())))
        .collect();
    let ranges = blocks.ranges_in(frames, source.n_frames());
    let (mut decode_s, mut beamform_s) = (0.0, 0.0);
    let mut recorded = false;
    let largest = ranges.iter().map(|(_, decoded)| decoded.len()).max();
    let mut buffers = BlockBuffers::with_room(acq, largest.unwrap_or(0) * n, source.trace_shape());
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
            &mut buffers,
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
/// (and decoded in place) and one angle's IQ. Fresh arrays of that size (about 1 GB) cost more to
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
    /// Buffers whose array of events read has room for `events` events of `trace` (channels,
    /// samples) real samples from the start: a recording's first block is shorter than the
    /// next (it has no frames before it), and would otherwise leave an array too small for them.
    /// The room is reserved, not touched: pages are faulted in as samples are read into them.
    fn with_room(acquisition: &Acquisition, events: usize, trace: (usize, usize)) -> Self {
        let room = Vec::with_capacity(events * trace.0 * trace.1);
        let empty =
            Array3::from_shape_vec((0, trace.0, trace.1), room).expect("no events, no samples");
        BlockBuffers {
            read: Some(ChannelData {
                acquisition: acquisition.clone(),
                samples: crate::channel::Samples::Rf(empty),
            }),
            ..BlockBuffers::default()
        }
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
    if !(decoded.start <= block.start && block.end <= decoded.end && block.start < block.end) {
        return Err(invalid(
            "frames",
            format!("block {block:?} is not within the decoded frames {decoded:?}"),
        ));
    }
    if images.len() != acq.sequence.n_angles() {
        return Err(Error::Shape(format!(
            "{} image series for {} angles",
            images.len(),
            acq.sequence.n_angles()
        )));
    }
    let clock = Instant::now();
    progress(Stage::Decode, 0);
    source.read_frames_into(decoded.clone(), &mut buffers.read)?;
    let data = buffers.read.as_ref().expect("just read");
    let recorded = data.samples.any_nonzero();
    let kept = block.start - decoded.start..block.end - decoded.start;
    let data = buffers.read.as_mut().expect("just read");
    decode::decode_in_place(data, params.event_alignment, kept.clone())?;
    let per_angle = data.samples.decoded_frames(acq.sequence.n_angles(), kept)?;
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

/// The non-linear part: B-mode, clutter filter, Doppler and vector solve from per-angle image
/// series (nz, nx, frames) on `params.grid`.
pub fn analyse(
    mut images: AngleImages,
    params: &ProcessParams,
    progress: &dyn Fn(Stage, usize, usize),
) -> Result<ProcessOutput> {
    images.validate()?;
    if images.grid != params.grid {
        return Err(invalid(
            "grid",
            "the images were formed on another grid than the processing settings'",
        ));
    }
    let angles = images.angles.clone();
    let n = angles.len();
    let mut timings = Vec::new();
    let bmode_db = beamform::bmode_db(beamform::compound(&images.series)?.view());
    let clock = Instant::now();
    let mut reports = Vec::with_capacity(n);
    for (k, image) in images.series.iter_mut().enumerate() {
        progress(Stage::Clutter, k, n);
        reports.push(clutter::svd_filter(image, &params.clutter)?);
    }
    progress(Stage::Clutter, n, n);
    timings.push((Stage::Clutter, clock.elapsed().as_secs_f64()));

    let clock = Instant::now();
    progress(Stage::Doppler, 0, 1);
    let (per_angle, compound) = moments(&images, params, None)?;
    let maps = doppler_maps(&per_angle, &compound, &images, params)?;
    progress(Stage::Doppler, 1, 1);
    timings.push((Stage::Doppler, clock.elapsed().as_secs_f64()));

    Ok(ProcessOutput::from_maps(
        maps,
        params.grid.clone(),
        bmode_db,
        reports,
        images,
        timings,
    ))
}

/// What turns angle `angle`'s series (`None`: the compound's) of `images` into velocity: the
/// sampling of `grid` and the echo path's weights, (sin θ, 1 + cos θ) for one angle and the
/// angles' means for their compound.
pub fn doppler_geometry(
    images: &AngleImages,
    grid: &Grid,
    angle: Option<usize>,
) -> DopplerGeometry {
    geometry_of(
        &images.angles,
        (
            images.sound_speed,
            images.frame_rate,
            images.demodulation_frequency,
        ),
        grid,
        angle,
    )
}

/// [`doppler_geometry`] from the angles (rad) and (speed of sound (m/s), frame rate (Hz),
/// demodulation frequency (Hz)).
fn geometry_of(
    angles: &[f64],
    (sound_speed, frame_rate, demodulation_frequency): (f64, f64, f64),
    grid: &Grid,
    angle: Option<usize>,
) -> DopplerGeometry {
    let n = angles.len().max(1) as f64;
    let (lateral_weight, axial_weight) = match angle {
        Some(k) => vector::projection_weights(angles[k]),
        None => (
            angles.iter().map(|a| a.sin()).sum::<f64>() / n,
            1.0 + angles.iter().map(|a| a.cos()).sum::<f64>() / n,
        ),
    };
    DopplerGeometry {
        sound_speed,
        frame_rate,
        demodulation_frequency,
        axial_step: grid.axial_step(),
        axial_weight,
        lateral_step: grid.step(),
        lateral_weight,
    }
}

/// Refuses, before any work, a Doppler estimator that `params.grid` cannot serve for the
/// recording `acq`: Loupas on an axial step too coarse to read the echo's mean frequency
/// ([`doppler::AxialSampling::with_weight`]), at any angle or their compound.
pub fn check_doppler_estimator(acq: &Acquisition, params: &ProcessParams) -> Result<()> {
    let angles = &acq.sequence.angles;
    let scales = (
        acq.sound_speed,
        acq.frame_rate(),
        acq.probe.center_frequency,
    );
    for angle in (0..angles.len()).map(Some).chain([None]) {
        params
            .doppler_estimator
            .check(&geometry_of(angles, scales, &params.grid, angle))?;
    }
    Ok(())
}

/// The Doppler moments ([`doppler::moments`]) of each angle's clutter-filtered series of
/// `images` (nz, nx, frames) and of their compound, for `params.doppler_estimator`; a range of
/// `frames` only, when given (a segment's own frames).
pub fn moments(
    images: &AngleImages,
    params: &ProcessParams,
    frames: Option<std::ops::Range<usize>>,
) -> Result<(Vec<Moments>, Moments)> {
    let range = frames.unwrap_or(0..images.n_frames());
    let per_angle = images
        .series
        .iter()
        .enumerate()
        .map(|(k, image)| {
            let series = image.slice(ndarray::s![.., .., range.clone()]);
            let mut m = doppler::moments(
                series,
                params.doppler_estimator,
                &doppler_geometry(images, &params.grid, Some(k)),
            )?;
            if params.partial_volume {
                m.cell = Some(partial_volume::CellLags::of(series));
            }
            Ok(m)
        })
        .collect::<Result<Vec<_>>>()?;
    let compound = beamform::compound(&images.series)?;
    let compound = doppler::moments(
        compound.slice(ndarray::s![.., .., range]),
        params.doppler_estimator,
        &doppler_geometry(images, &params.grid, None),
    )?;
    Ok((per_angle, compound))
}

/// The Doppler maps of [`ProcessOutput`], on the grid (nz, nx), SI units.
#[derive(Debug, Clone)]
pub struct DopplerMaps {
    /// Power Doppler of the compounded series (|IQ|² units).
    pub power_doppler: Array2<f64>,
    /// Axial velocity from the compounded series (m/s, positive = away from the probe).
    pub color_doppler: Array2<f64>,
    /// Per-angle power Doppler (angles, nz, nx), each pixel's own (not averaged over the
    /// Doppler kernel).
    pub power_per_angle: Array3<f64>,
    /// Per-angle projection velocities (angles, nz, nx), m/s; NaN where the angle does not reach.
    pub projections: Array3<f64>,
    /// Per angle, the pixels its plane wave reaches (angles, nz, nx).
    pub coverage: Array3<bool>,
    /// Per-angle lateral weight of each projection in the vector model (angles, nz, nx): sin θ
    /// (Kasai) or measured (Loupas); see [`doppler::DopplerMaps::lateral_weight`].
    pub lateral_weights: Array3<f64>,
    /// Vector field by least squares (UVD); `None` with a single angle.
    pub vector_ls: Option<VectorField>,
    /// Vector field by IRLS-WLS (PC-UVD); `None` with a single angle.
    pub vector_irls: Option<VectorField>,
    /// What vector dealiasing did; `None` when it is off or with a single angle.
    pub dealias: Option<DealiasOutcome>,
    /// Nyquist velocity of each projection at the demodulation frequency (m/s); Loupas unwraps
    /// each pixel with its own, c·f_frame/(4 f̄).
    pub nyquist_velocity: f64,
    /// Each projection's Nyquist velocity at each pixel (angles, nz, nx), m/s; see
    /// [`ProcessOutput::projection_nyquist`].
    pub projection_nyquist: Array3<f64>,
    /// Each angle's resolution cell as the partial-volume correction sees it; see
    /// [`ProcessOutput::cells`].
    pub cells: Vec<Option<partial_volume::CellCovariance>>,
}

/// Velocities and vectors from Doppler moments ([`moments`], or those of several segments of a
/// long recording merged, [`doppler::Moments::merge`]) with `params`' kernel, estimator and
/// dealiasing: `images` gives the angles, frame rate, speed of sound, demodulation frequency and
/// coverage (its series are not read).
pub fn doppler_maps(
    per_angle: &[Moments],
    compound: &Moments,
    images: &AngleImages,
    params: &ProcessParams,
) -> Result<DopplerMaps> {
    let angles = &images.angles;
    let n = angles.len();
    if per_angle.len() != n {
        return Err(invalid(
            "Doppler moments",
            format!("{} for {n} angles", per_angle.len()),
        ));
    }
    let frame_rate = images.frame_rate;
    let (c, f0) = (images.sound_speed, images.demodulation_frequency);
    let (nz, nx) = params.grid.shape();
    let mut projections = Array3::<f64>::zeros((n, nz, nx));
    let mut power_per_angle = Array3::<f64>::zeros((n, nz, nx));
    let mut lateral_weights = Array3::<f64>::zeros((n, nz, nx));
    // Each pixel's projection Nyquist velocity, c·f_frame/(4 f̄): its own mean frequency's.
    let mut nyquist = Array3::<f64>::zeros((n, nz, nx));
    for (k, m) in per_angle.iter().enumerate() {
        let maps = doppler::maps_of_moments(
            m,
            params.doppler_kernel,
            params.doppler_estimator,
            &doppler_geometry(images, &params.grid, Some(k)),
        )?;
        projections
            .index_axis_mut(Axis(0), k)
            .assign(&maps.velocity);
        lateral_weights
            .index_axis_mut(Axis(0), k)
            .assign(&maps.lateral_weight);
        nyquist.index_axis_mut(Axis(0), k).assign(
            &maps
                .mean_frequency
                .mapv(|f| doppler::nyquist_velocity(c, frame_rate, f)),
        );
        power_per_angle.index_axis_mut(Axis(0), k).assign(&m.power);
    }
    // The compounded echo path changes by Vz·(1 + mean cos θ) (+ Vx·mean sin θ, zero for symmetric
    // angle sets): rescale its velocity to the axial velocity.
    let mean_cos = angles.iter().map(|a| a.cos()).sum::<f64>() / n as f64;
    let doppler::DopplerMaps {
        power, velocity, ..
    } = doppler::maps_of_moments(
        compound,
        params.doppler_kernel,
        params.doppler_estimator,
        &doppler_geometry(images, &params.grid, None),
    )?;
    let axial = velocity.mapv(|v| 2.0 * v / (1.0 + mean_cos));
    let coverage = images
        .coverage
        .clone()
        .unwrap_or_else(|| Array3::from_elem((n, nz, nx), true));
    vector::drop_unreached(&mut projections, coverage.view());
    let nyquist_velocity = doppler::nyquist_velocity(c, frame_rate, f0);
    let cells: Vec<_> = per_angle
        .iter()
        .map(|m| {
            m.cell.as_ref().and_then(|lags| {
                partial_volume::CellCovariance::from_lags(lags, params.grid.step())
            })
        })
        .collect();
    // Kasai's rows are the model's; Loupas fits its measured lateral weights.
    let lateral =
        (params.doppler_estimator == DopplerEstimator::Loupas).then(|| lateral_weights.view());
    let (vector_ls, vector_irls, dealiased) = if n >= 2 {
        let flow = dealias::flow_mask(&power, params.grid.step());
        let [ls, irls]: [dealias::DealiasedField; 2] = dealias::dealiased_vectors_each(
            angles,
            projections.view(),
            lateral,
            nyquist.view(),
            &[Estimator::LeastSquares, Estimator::Irls(params.irls)],
            params.dealias,
            power.view(),
            flow.view(),
        )?
        .try_into()
        .map_err(|_| Error::Shape("two estimators, two fields".into()))?;
        let (ls_field, irls_field) = if params.partial_volume {
            let [ls_field, irls_field]: [VectorField; 2] = partial_volume::corrected_fits(
                angles,
                projections.view(),
                nyquist.view(),
                lateral,
                &[
                    (Estimator::LeastSquares, &ls),
                    (Estimator::Irls(params.irls), &irls),
                ],
                &partial_volume::AngleCells {
                    power: power_per_angle.view(),
                    cells: &cells,
                    kernel: params.doppler_kernel,
                },
                flow.view(),
                params.grid.step(),
            )?
            .try_into()
            .map_err(|_| Error::Shape("two estimators, two fields".into()))?;
            (ls_field, irls_field)
        } else {
            (ls.field, irls.field)
        };
        let outcome = (ls.intervals > 0).then(|| DealiasOutcome {
            intervals: ls.intervals,
            flow_pixels: flow.iter().filter(|&&f| f).count(),
            irls: irls.counts,
            ls: ls.counts,
        });
        (Some(ls_field), Some(irls_field), outcome)
    } else {
        (None, None, None)
    };
    Ok(DopplerMaps {
        power_doppler: power,
        color_doppler: axial,
        power_per_angle,
        projections,
        coverage,
        lateral_weights,
        vector_ls,
        vector_irls,
        dealias: dealiased,
        nyquist_velocity,
        projection_nyquist: nyquist,
        cells,
    })
}

/// The dynamics stage on a processed recording: vector velocity in sliding windows over the
/// clutter-filtered series (`params`), the whole-recording vessel mask of `vessel` on its power
/// Doppler, then PSV, EDV, RI, classes and flow directions of those pixels, over the cardiac
/// cycles that `triggers` (s from the first frame: ECG R-waves or scanner triggers) delimit when
/// given, else found as [`dynamics::cardiac_cycles`] says. `process`, the vessel-network study and
/// the tests all run it through here.
pub fn dynamics(
    out: &ProcessOutput,
    params: &DynamicsParams,
    vessel: &VesselTests,
    triggers: Option<&[f64]>,
) -> Result<(VelocitySeries, RiMaps)> {
    if out.filtered.n_angles() < 2 {
        return Err(invalid(
            "angles",
            "vector velocity needs two or more steering angles; the recording has one",
        ));
    }
    if out.filtered.series.is_empty() {
        return Err(invalid(
            "filtered series",
            "the recording was processed in segments (too long to hold whole) and its filtered \
             series were not kept: give the dynamics settings to process itself",
        ));
    }
    params.validate(out.filtered.frame_rate)?;
    // Windows unwrap as far as the whole recording needed (auto decides once, on the recording).
    let params = &DynamicsParams {
        dealias: match (params.dealias, &out.dealias) {
            (Dealias::Auto, Some(done)) => Dealias::Intervals(done.intervals),
            (setting, _) => setting,
        },
        ..*params
    };
    let series = dynamics::sliding_vectors(&out.filtered, params)?;
    let maps = ri_maps_of(
        &series,
        &out.power_doppler,
        &out.grid,
        params,
        vessel,
        triggers,
    )?;
    Ok((series, maps))
}

/// The RI half of [`dynamics`], on a velocity series already formed (by [`dynamics`] or segment by
/// segment, [`crate::segments`]): the vessel mask of `vessel` on the whole-recording power Doppler,
/// then PSV, EDV, RI, classes and flow directions over the cardiac cycles.
pub fn ri_maps_of(
    series: &VelocitySeries,
    power_doppler: &Array2<f64>,
    grid: &Grid,
    params: &DynamicsParams,
    vessel: &VesselTests,
    triggers: Option<&[f64]>,
) -> Result<RiMaps> {
    let flow = vessel.flow_mask(power_doppler, grid.step());
    dynamics::ri_maps_triggered(series, params, Some(&flow), triggers)
}

/// Per steering angle, the pixels of `grid` that its plane wave reaches and whose echo a record of
/// `n_samples` samples holds (angles, nz, nx):
/// - the ray back along the steering direction lands on the array face
///   ([`geometry::insonified`](crate::geometry::insonified)). Near the lateral edges, deeper than
///   a few mm, the widest angles miss a pixel (|x| > half-aperture − z·tan θ_max); their Doppler
///   there is noise or edge-wave leakage, and fitting it biased the lateral velocity (the spiral's
///   UVD Vx RMSE was 13.6 mm/s with it, 4.1 without);
/// - the echo's shortest way back (to the element nearest the pixel) arrives before the record
///   ends. A steered wave reaches a pixel later than the unsteered one by (x − x_first)·sin θ / c,
///   so the deepest rows of a grid that reaches [`recorded_depth_of`] lie beyond the record for
///   the steep angles: their images there are exactly zero, and read as a projection of 0 m/s
///   (on the default grid of the `rat-network` preset, 3,903 pixels of the deepest 1.2 mm had
///   such angles in their vector fit).
pub fn angle_coverage(acq: &Acquisition, n_samples: usize, grid: &Grid) -> Array3<bool> {
    let xs = acq.probe.element_x();
    let aperture = (
        xs.first().copied().unwrap_or(0.0),
        xs.last().copied().unwrap_or(0.0),
    );
    let c = acq.sound_speed;
    let record_end = acq.t0 + (n_samples as f64 - 1.0) / acq.sampling_frequency;
    let angles = &acq.sequence.angles;
    let (nz, nx) = grid.shape();
    Array3::from_shape_fn((angles.len(), nz, nx), |(k, iz, ix)| {
        let (x, z) = (grid.x[ix], grid.z[iz]);
        let nearest = x.clamp(aperture.0, aperture.1);
        let earliest = crate::geometry::round_trip_delay(x, z, angles[k], nearest, aperture, c);
        crate::geometry::insonified(x, z, angles[k], aperture) && earliest <= record_end
    })
}

/// How [`memory_estimate`] counts.
pub const MEMORY_ESTIMATE_RULE: &str = "the input's samples held in memory (none when they are \
read from the file a block at a time) + one \
block's working memory (BLOCK_BYTES, or the whole recording's decoding and IQ when it is \
smaller) + (1 + 1/angles) × pixels × frames × angles × 8 bytes (the image series, complex64, \
filtered in place, and a compound of it; frames: the recording's, or one segment's when it is \
processed in segments: as few segments of even length as fit in segments::SERIES_BYTES, before \
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
    let coded = source.acquisition().sequence.is_coded();
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
    // A recording longer than one segment holds one segment's images at a time, and segments
    // share the recording evenly.
    let total = source.n_frames();
    let fit = crate::segments::frames_that_fit(nz * nx, angles).max(1);
    let frames = total.div_ceil(total.div_ceil(fit).max(1)) as u128;
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

/// Checks, before any work, that every pulse slot of `acq` starts within a record of `n_samples`
/// samples: decoding advances slot k's record by its start, so a slot that starts after the record
/// ends has no echo in it (and would ask for an FFT longer than the record).
pub fn check_record(acq: &Acquisition, n_samples: usize) -> Result<()> {
    let last = acq.sequence.last_slot_start();
    let record = n_samples as f64 / acq.sampling_frequency;
    if last >= record {
        return Err(invalid(
            "slot delays",
            format!(
                "the last pulse slot starts {:.3} µs into the event, after the {:.3} µs record \
                 ({n_samples} samples at {:.3} MHz) ends: its echoes are not in the recording",
                last * 1e6,
                record * 1e6,
                acq.sampling_frequency * 1e-6
            ),
        ));
    }
    Ok(())
}

/// Deepest depth (m) whose straight-down echo lies inside the record.
pub fn recorded_depth(data: &ChannelData) -> f64 {
    recorded_depth_of(&data.acquisition, data.samples.dim().2)
}

/// Deepest depth (m) whose straight-down echo lies inside a record of `n_samples` samples.
pub fn recorded_depth_of(acq: &Acquisition, n_samples: usize) -> f64 {
    let t_end = acq.t0 + (n_samples as f64 - 1.0) / acq.sampling_frequency;
    (0.5 * t_end * acq.sound_speed).max(0.0)
}

/// The default grid: the array's lateral extent, from just below the first recorded depth to the
/// last, with a step of half a wavelength (rounded to 0.01 mm), capped near 400 × 400 pixels.
pub fn default_grid(data: &ChannelData) -> Result<Grid> {
    default_grid_for(&data.acquisition, data.samples.dim().2)
}

/// [`default_grid`] of a recording acquired as `acq` with traces of `n_samples` samples.
pub fn default_grid_for(acq: &Acquisition, n_samples: usize) -> Result<Grid> {
    let (x0, x1) = acq.probe.aperture();
    let z_first = (0.5 * acq.t0 * acq.sound_speed).max(0.0);
    let z0 = z_first.max(1e-3);
    let z1 = recorded_depth_of(acq, n_samples);
    if z1 <= z0 {
        return Err(invalid(
            "grid",
            "the record is too short to cover any depth beyond 1 mm",
        ));
    }
    let mut step = (acq.probe.wavelength(acq.sound_speed) / 2.0 * 1e5).round() / 1e5;
    let extent = (x1 - x0).max(z1 - z0);
    step = step.max(extent / 400.0).max(1e-5);
    Grid::new(x0, x1, z0, z1, step)
}

/// Checks, before any work, that `grid` starts above the deepest depth a record of `n_samples`
/// samples acquired as `acq` holds ([`recorded_depth_of`]).
pub fn check_grid_depth(acq: &Acquisition, n_samples: usize, grid: &Grid) -> Result<()> {
    check_depth(recorded_depth_of(acq, n_samples), grid)
}

/// A grid deeper than the record can say nothing: refuse it rather than return zeros.
fn check_depth(deepest: f64, grid: &Grid) -> Result<()> {
    let z_min = grid.z.first().copied().unwrap_or(0.0);
    if z_min >= deepest {
        return Err(invalid(
            "grid",
            format!(
                "the grid starts at z = {:.2} mm, below the deepest recorded depth {:.2} mm",
                z_min * 1e3,
                deepest * 1e3
            ),
        ));
    }
    Ok(())
}
