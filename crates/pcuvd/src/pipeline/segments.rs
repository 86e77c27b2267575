//! Long recordings in segments: memory bounded by a segment's image series, not by the recording.
//!
//! The whole-recording path holds every frame's per-angle images, because the SVD clutter filter
//! sees the whole ensemble at once: 2.2 GB for the paper's 0.2 s rat recording, 11 GB for 1 s. A
//! recording too long for that is cut into consecutive *cores* of frames; each core is imaged with
//! some following frames (the *overlap*, so that every dynamics window and time-series ensemble
//! starting in it lies inside one segment), clutter-filtered on its own, and then dropped. What
//! the maps need accumulates across segments:
//!
//! - the Doppler moments ([`crate::estimate::doppler::Moments`]: power, lag-1 autocorrelation and, for
//!   Loupas, the axial (and lateral) lags within frames and at temporal lags ±1) are means over
//!   frames and frame pairs, so each core's are combined ([`crate::estimate::doppler::Moments::merge`],
//!   before the spatial box average, which is linear) and the velocities taken from the totals:
//!   the maps are those of one long ensemble, except that each segment has its own clutter
//!   subspace and the pairs across a cut are not counted;
//! - the B-mode's mean envelope is summed over the cores the same way (unfiltered: exact);
//! - dynamics windows and ensembles start on the same frames as the whole-recording path's, each
//!   computed in the segment whose core holds its start;
//! - vector dealiasing ([`crate::estimate::dealias`]) applies where the whole-recording path applies it: to
//!   the maps from the totals (in [`pipeline::doppler_maps`]), to every ensemble, and to every
//!   dynamics window. Where the whole path's windows take an automatic K from the recording's
//!   maps, the segments' take it from the first segment's (the totals come too late).
//!
//! Where one segment holds the whole recording the results are the whole-recording path's.
//! Images formed elsewhere ([`SegmentSource::Images`]: a scanner's beamformed IQ) are read a
//! segment at a time where a recording's are formed, and processed alike from the clutter
//! filter on.

use std::ops::Range;

use std::io::{Read, Seek, SeekFrom, Write};

use ndarray::{Array2, Array3, Zip, s};
use num_complex::Complex32;
use serde::{Deserialize, Serialize};

use crate::acquisition::source::FrameSource;
use crate::core::error::{Error, Result, invalid};
use crate::dynamics::{self, DynamicsParams, VelocitySeries};
use crate::estimate::clutter::{self, ClutterReport};
use crate::estimate::dealias::Dealias;
use crate::estimate::doppler::Moments;
use crate::form::beamform;
use crate::form::images::{AngleImages, ImageFrames, PixelSeries};
use crate::pipeline::ensembles::{self, EnsembleMaps, EnsembleSpec};
pub use crate::pipeline::memory::{
    MAX_SEGMENT_FRAMES, SERIES_BYTES, default_segment_frames, frames_held,
};
use crate::pipeline::{self, ProcessOutput, ProcessParams, Stage, Timings};

/// How a long recording is cut: cores of `core` frames (the last one takes the rest), each imaged
/// with `overlap` frames after it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Segments {
    /// Compound frames of each core (a multiple of the dynamics and ensemble steps).
    pub core: usize,
    /// Frames imaged after each core, for the windows and ensembles starting near its end.
    pub overlap: usize,
}

impl Segments {
    /// Cuts a recording of `total` frames for processing in segments of at most `segment_frames`
    /// frames (core + overlap), or `None` when one segment holds it (the whole-recording path).
    /// `dynamics` and `ensembles`, when they run, set the overlap (their window) and the cores'
    /// alignment (their steps); a segment too short for them is refused, naming both.
    pub fn plan(
        total: usize,
        segment_frames: usize,
        dynamics: Option<&DynamicsParams>,
        ensembles: Option<EnsembleSpec>,
    ) -> Result<Option<Segments>> {
        if segment_frames >= total {
            return Ok(None);
        }
        let (overlap, align) = Self::reach(dynamics, ensembles);
        let longest = segment_frames.saturating_sub(overlap) / align * align;
        if longest < Self::shortest_core(align) {
            return Err(invalid(
                "segment frames",
                format!(
                    "{segment_frames} frames per segment leave {longest} for its own frames after \
                     the {overlap} that the dynamics windows or ensembles reach into: give a \
                     larger --segment-frames (at least {})",
                    Self::shortest(dynamics, ensembles)
                ),
            ));
        }
        // As few segments as fit, of even length: a short last segment would get a clutter
        // filter of few frames. The even share, rounded up to the steps, is at most `longest`.
        let count = total.div_ceil(longest);
        let core = total.div_ceil(count).div_ceil(align) * align;
        Ok(Some(Segments { core, overlap }))
    }

    /// The fewest frames a segment may have with these windows and ensembles.
    pub fn shortest(dynamics: Option<&DynamicsParams>, ensembles: Option<EnsembleSpec>) -> usize {
        let (overlap, align) = Self::reach(dynamics, ensembles);
        overlap + Self::shortest_core(align)
    }

    /// The clutter filter and the lag-1 autocorrelation need several frames per core, and cores
    /// start on the windows' and ensembles' steps.
    fn shortest_core(align: usize) -> usize {
        4usize.div_ceil(align) * align
    }

    /// (overlap, alignment): windows and ensembles start every `step` frames, so the last one
    /// starting in a core (a multiple of the steps long) starts `step` before its end and needs
    /// `frames − step` frames after it; cores start on a multiple of every step.
    fn reach(dynamics: Option<&DynamicsParams>, ensembles: Option<EnsembleSpec>) -> (usize, usize) {
        let overlap = dynamics
            .map_or(0, |d| d.window.saturating_sub(d.step))
            .max(ensembles.map_or(0, |e| e.frames.saturating_sub(e.step)));
        let align = num_integer::lcm(
            dynamics.map_or(1, |d| d.step.max(1)),
            ensembles.map_or(1, |e| e.step.max(1)),
        );
        (overlap, align)
    }

    /// Each segment's core and the frames imaged for it: (core, imaged), in order. The cores
    /// tile the recording; a remainder too short to filter joins the last core.
    pub fn ranges(&self, total: usize) -> Vec<(Range<usize>, Range<usize>)> {
        let core = self.core.max(1);
        let mut starts: Vec<usize> = (0..total).step_by(core).collect();
        if starts.len() > 1 && total - starts[starts.len() - 1] < 4 {
            starts.pop();
        }
        starts
            .iter()
            .enumerate()
            .map(|(k, &start)| {
                let end = starts.get(k + 1).copied().unwrap_or(total);
                (start..end, start..(end + self.overlap).min(total))
            })
            .collect()
    }
}

/// What [`process_in_segments`] gives: the maps, and the stages that run over time.
#[derive(Debug, Clone)]
pub struct Segmented {
    /// The maps from the sums over every core. Its `filtered` holds no series (they were dropped
    /// segment by segment) and its `clutter` is the first segment's.
    pub out: ProcessOutput,
    /// The dynamics stage's velocity series, when `dynamics` was given.
    pub series: Option<VelocitySeries>,
    /// The Doppler time series, when `ensembles` was given. Where an [`EnsembleSink`] took the
    /// maps, only their times, first frames and clutter cut-offs are here: the maps are
    /// (0, nz, nx).
    pub ensembles: Option<EnsembleMaps>,
    /// Each segment's core and imaged frames.
    pub ranges: Vec<(Range<usize>, Range<usize>)>,
    /// Each segment's clutter cut-offs, per angle.
    pub clutter: Vec<Vec<ClutterReport>>,
    /// The kept pixels' filtered series over the whole recording, when the run kept any.
    pub kept: Option<PixelSeries>,
}

/// Finished parts' maps set aside in a scratch file while later segments are processed, so that
/// the outputs that grow with the recording (dynamics windows, time-series ensembles: 3 or 4 maps
/// of 8 bytes per pixel per window) do not add to the segments' peak: 197 windows of the rat
/// grid are 0.45 GB. Each part gives the same fields (e.g. Vx, Vz, power), (samples, nz, nx) f64.
/// The file is anonymous: the system removes it however the process ends.
struct SetAside {
    file: Option<std::fs::File>,
    /// Time samples of each part, in order.
    lengths: Vec<usize>,
    fields: usize,
    map: (usize, usize),
}

fn scratch(e: std::io::Error) -> Error {
    Error::Scratch(e.to_string())
}

impl SetAside {
    fn new() -> Self {
        SetAside {
            file: None,
            lengths: Vec::new(),
            fields: 0,
            map: (0, 0),
        }
    }

    /// Writes one part's maps, one array per field (same fields, in the same order, for every
    /// part), and leaves empty (0, nz, nx) arrays in their place.
    fn put(&mut self, maps: &mut [&mut Array3<f64>]) -> Result<()> {
        let Some(first) = maps.first() else {
            return Ok(());
        };
        let (samples, nz, nx) = first.dim();
        if maps.iter().any(|m| m.dim() != (samples, nz, nx))
            || (!self.lengths.is_empty() && (self.fields != maps.len() || self.map != (nz, nx)))
        {
            return Err(Error::Shape(
                "maps set aside between segments differ in shape".into(),
            ));
        }
        let file = match &mut self.file {
            Some(file) => file,
            None => self.file.insert(tempfile::tempfile().map_err(scratch)?),
        };
        for map in maps.iter_mut() {
            let taken = std::mem::replace(&mut **map, Array3::zeros((0, nz, nx)));
            let standard = taken.as_standard_layout();
            let values = standard.as_slice().expect("standard layout is contiguous");
            file.write_all(bytemuck::cast_slice(values))
                .map_err(scratch)?;
        }
        self.lengths.push(samples);
        self.fields = maps.len();
        self.map = (nz, nx);
        Ok(())
    }

    /// Every part read back: per field, the parts joined along time.
    fn take(self) -> Result<Vec<Array3<f64>>> {
        let total: usize = self.lengths.iter().sum();
        let mut joined: Vec<Array3<f64>> = (0..self.fields)
            .map(|_| Array3::zeros((total, self.map.0, self.map.1)))
            .collect();
        if let Some(mut file) = self.file {
            file.seek(SeekFrom::Start(0)).map_err(scratch)?;
            let mut start = 0;
            for &len in &self.lengths {
                for field in joined.iter_mut() {
                    let mut part = field.slice_mut(s![start..start + len, .., ..]);
                    let values = part
                        .as_slice_mut()
                        .expect("whole time samples of a standard array are contiguous");
                    file.read_exact(bytemuck::cast_slice_mut(values))
                        .map_err(scratch)?;
                }
                start += len;
            }
        }
        Ok(joined)
    }
}

/// The Doppler moments of the cores so far, merged ([`doppler::Moments::merge`]).
#[derive(Default)]
struct Sums(Option<Moments>);

impl Sums {
    /// Adds the moments of a core's frames.
    fn add(&mut self, moments: Moments) -> Result<()> {
        match &mut self.0 {
            None => self.0 = Some(moments),
            Some(total) => total.merge(&moments)?,
        }
        Ok(())
    }

    fn total(&self) -> Result<&Moments> {
        self.0
            .as_ref()
            .ok_or_else(|| invalid("frames", "the recording has no frames"))
    }
}

/// Adds to `envelope` (nz, nx) the sum over frames `own` of the compound (angle-summed) images'
/// magnitude, as [`beamform::compound`] would sum them, without forming the compound series.
fn add_envelope(envelope: &mut Array2<f64>, series: &[Array3<Complex32>], own: Range<usize>) {
    let frames = series.first().map_or(0, |s| s.dim().2);
    let lanes: Vec<&[Complex32]> = series
        .iter()
        .map(|s| s.as_slice().expect("formed series are contiguous"))
        .collect();
    let nx = envelope.dim().1;
    Zip::indexed(envelope).par_for_each(|(iz, ix), e| {
        let base = (iz * nx + ix) * frames;
        *e += own
            .clone()
            .map(|f| {
                let mut sum = lanes[0][base + f];
                for lane in &lanes[1..] {
                    sum += lane[base + f];
                }
                beamform::envelope(sum)
            })
            .sum::<f64>();
    });
}

/// An ensemble part's maps, in the order they are set aside: power, colour, and Vx, Vz where the
/// recording gives vectors.
fn ensemble_fields(maps: &mut EnsembleMaps) -> Vec<&mut Array3<f64>> {
    let mut fields = vec![&mut maps.power_doppler, &mut maps.color_doppler];
    fields.extend(maps.vx.as_mut());
    fields.extend(maps.vz.as_mut());
    fields
}

/// Where a segmented run puts each segment's Doppler time series as the segment joins the run
/// (e.g. a chunked store on disk), so that a long recording's ensembles are never all in memory.
pub trait EnsembleSink {
    /// Takes the next segment's ensembles, in recording order: their centre times (s from the
    /// first frame), first frames, clutter cut-offs and maps in SI units, (ensembles, nz, nx).
    fn append(&mut self, part: &EnsembleMaps) -> Result<()>;
}

/// One segment's share of a segmented run: its Doppler moments, B-mode envelope, clutter cut-offs,
/// velocity windows and ensembles, as [`SegmentRun::segment`] makes them and
/// [`SegmentRun::join`] adds them up. Serializable, so that the segments of one recording can be
/// processed in other processes or on other machines and joined where the run started.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SegmentPart {
    /// The segment's index, 0-based in recording order.
    pub index: usize,
    /// The Nyquist intervals K every later segment's velocity windows unwrap by, settled on the
    /// first segment's maps when the windows' dealiasing is automatic (`None` otherwise, and for
    /// every later segment).
    pub window_intervals: Option<u32>,
    per_angle: Vec<Moments>,
    compound: Moments,
    /// The compound envelope summed over the core's frames.
    envelope: Array2<f64>,
    clutter: Vec<ClutterReport>,
    windows: Option<VelocitySeries>,
    ensembles: Option<EnsembleMaps>,
    kept: Option<PixelSeries>,
    timings: Timings,
    /// The images' description; their series are dropped with the segment.
    images: AngleImages,
}

/// Where a segmented run's image series come from.
#[derive(Clone, Copy)]
pub enum SegmentSource<'a> {
    /// Channel data, decoded and beamformed a segment at a time.
    Channels(&'a dyn FrameSource),
    /// Images formed elsewhere (a scanner's beamformed IQ), read a segment at a time.
    Images(&'a dyn ImageFrames),
}

impl SegmentSource<'_> {
    /// Compound frames of the recording.
    pub fn n_frames(&self) -> usize {
        match self {
            SegmentSource::Channels(source) => source.n_frames(),
            SegmentSource::Images(images) => images.n_frames(),
        }
    }

    /// Steering angles: one image series each.
    pub fn n_angles(&self) -> usize {
        match self {
            SegmentSource::Channels(source) => source.acquisition().sequence.n_angles(),
            SegmentSource::Images(images) => images.description().n_angles(),
        }
    }

    /// The compound frame rate: the series' slow-time sampling rate (Hz).
    pub fn frame_rate(&self) -> f64 {
        match self {
            SegmentSource::Channels(source) => source.acquisition().frame_rate(),
            SegmentSource::Images(images) => images.description().frame_rate,
        }
    }

    /// The image series of frames `imaged`, formed (channel data: in `params`' blocks, in the
    /// memory of `spare` and `buffers`) or read, and the time each stage took.
    fn images_of(
        &self,
        params: &ProcessParams,
        imaged: Range<usize>,
        spare: Vec<Array3<Complex32>>,
        buffers: &mut pipeline::BlockBuffers,
        progress: &dyn Fn(Stage, usize, usize),
    ) -> Result<(AngleImages, Timings)> {
        match self {
            SegmentSource::Channels(source) => {
                let blocks = pipeline::blocks_for(*source, params.event_alignment);
                pipeline::form_images_of(*source, params, blocks, imaged, spare, buffers, progress)
            }
            SegmentSource::Images(images) => {
                // The previous segment's series go before this one's are read.
                drop(spare);
                let clock = std::time::Instant::now();
                let read = images.read_frames(imaged)?;
                read.validate()?;
                if read.grid != params.grid {
                    return Err(invalid(
                        "grid",
                        "the images are on another grid than the processing settings'",
                    ));
                }
                progress(Stage::Read, 1, 1);
                Ok((read, vec![(Stage::Read, clock.elapsed().as_secs_f64())]))
            }
        }
    }
}

impl<'a> From<&'a dyn FrameSource> for SegmentSource<'a> {
    fn from(source: &'a dyn FrameSource) -> Self {
        SegmentSource::Channels(source)
    }
}

/// The settings every segment of one segmented run shares.
#[derive(Debug, Clone, Copy)]
pub struct SegmentRun<'a> {
    /// The chain's settings.
    pub params: &'a ProcessParams,
    /// How the recording is cut.
    pub segments: &'a Segments,
    /// The dynamics stage's velocity windows, when they run.
    pub dynamics: Option<&'a DynamicsParams>,
    /// The Doppler time series' ensembles, when asked for.
    pub ensembles: Option<EnsembleSpec>,
    /// Pixels (row, col) whose clutter-filtered series each segment keeps over its own frames,
    /// joined into [`Segmented::kept`] (for spectrograms); empty: none.
    pub kept_pixels: &'a [(usize, usize)],
}

impl SegmentRun<'_> {
    /// The checks made before any segment is processed.
    pub fn check(&self, source: SegmentSource) -> Result<()> {
        match source {
            SegmentSource::Channels(channels) => {
                pipeline::check_doppler_estimator(channels.acquisition(), self.params)?
            }
            SegmentSource::Images(images) => {
                pipeline::check_doppler_estimator_on(&images.description(), self.params)?
            }
        }
        if let Some(d) = self.dynamics {
            d.validate(source.frame_rate())?;
        }
        Ok(())
    }

    /// How many segments `source` is cut into.
    pub fn count(&self, source: SegmentSource) -> usize {
        self.segments.ranges(source.n_frames()).len()
    }

    /// Whether the first segment settles the Nyquist intervals K of every segment's velocity
    /// windows (their dealiasing automatic), so that the later segments need its
    /// [`SegmentPart::window_intervals`].
    pub fn first_settles_windows(&self, source: SegmentSource) -> bool {
        self.dynamics.is_some_and(|d| {
            d.dealias == Dealias::Auto
                && self.params.dealias != Dealias::Off
                && source.n_angles() >= 2
        })
    }

    /// Segment `index` of `source`: imaged, clutter-filtered, its moments, windows and ensembles.
    /// `window_intervals`: the first segment's [`SegmentPart::window_intervals`], required by
    /// every later segment when the windows' dealiasing is automatic (the windows of all segments
    /// unwrap by the K the first settled). `progress` sees this segment's work as its share of
    /// the recording's.
    pub fn segment(
        &self,
        source: SegmentSource,
        index: usize,
        window_intervals: Option<u32>,
        progress: &dyn Fn(Stage, usize, usize),
    ) -> Result<SegmentPart> {
        self.check(source)?;
        Ok(self
            .segment_in(
                source,
                index,
                window_intervals,
                Vec::new(),
                &mut pipeline::BlockBuffers::default(),
                progress,
            )?
            .0)
    }

    /// [`Self::segment`], its series formed in the memory of `spare` (a previous segment's),
    /// which it gives back for the next, its events read into `buffers` (kept for the next
    /// likewise).
    fn segment_in(
        &self,
        source: SegmentSource,
        index: usize,
        window_intervals: Option<u32>,
        spare: Vec<Array3<Complex32>>,
        buffers: &mut pipeline::BlockBuffers,
        progress: &dyn Fn(Stage, usize, usize),
    ) -> Result<(SegmentPart, Vec<Array3<Complex32>>)> {
        let params = self.params;
        let ranges = self.segments.ranges(source.n_frames());
        let count = ranges.len();
        let Some((core, imaged)) = ranges.get(index).cloned() else {
            return Err(invalid(
                "segment",
                format!("{index} is not a segment of this recording (it has {count})"),
            ));
        };
        let n = source.n_angles();
        let mut dynamics = self.dynamics.copied();
        let automatic_windows = self.first_settles_windows(source);
        if automatic_windows
            && index > 0
            && let (Some(k), Some(d)) = (window_intervals, dynamics.as_mut())
        {
            d.dealias = Dealias::Intervals(k);
        }
        let mut timings: Timings = Vec::new();
        let mut add_time =
            |stage: Stage, seconds: f64| match timings.iter_mut().find(|t| t.0 == stage) {
                Some(t) => t.1 += seconds,
                None => timings.push((stage, seconds)),
            };
        let k = index;
        let (mut images, formed) =
            source.images_of(params, imaged.clone(), spare, buffers, &|stage, d, t| {
                progress(stage, k * t + d, count * t)
            })?;
        for (stage, seconds) in formed {
            add_time(stage, seconds);
        }
        let own = 0..core.len();
        let clock = std::time::Instant::now();
        let mut ensemble_part = None;
        if let Some(spec) = self.ensembles {
            // Ensembles start every `step` frames from the recording's first; those starting in
            // this core are this segment's.
            let starts: Vec<usize> = (0..own.end)
                .step_by(spec.step.max(1))
                .filter(|&s| s + spec.frames <= images.n_frames())
                .collect();
            if !starts.is_empty() {
                let mut part =
                    ensembles::ensemble_maps_at(&images, params, spec, &starts, &|_, _, _| {})?;
                part.shift(core.start, spec, images.frame_rate);
                ensemble_part = Some(part);
            }
            progress(Stage::Ensembles, k + 1, count);
            add_time(Stage::Ensembles, clock.elapsed().as_secs_f64());
        }
        let mut envelope = Array2::<f64>::zeros(params.grid.shape());
        add_envelope(&mut envelope, &images.series, own.clone());

        let clock = std::time::Instant::now();
        // Every segment's blocks are those its longest one needs, so that all share one layout.
        let longest = ranges.iter().map(|(_, imaged)| imaged.len()).max();
        let shared = (params.clutter).with_blocks_for(params.grid.shape(), longest.unwrap_or(0));
        let clutter = clutter::svd_filter_each(&mut images.series, &shared, |a| {
            progress(Stage::Clutter, k * n + a, count * n)
        })?;
        add_time(Stage::Clutter, clock.elapsed().as_secs_f64());
        let kept = if self.kept_pixels.is_empty() {
            None
        } else {
            Some(PixelSeries::of_core(
                &images,
                self.kept_pixels,
                own.clone(),
            )?)
        };

        let clock = std::time::Instant::now();
        progress(Stage::Doppler, k, count);
        let (per_angle, compound) = pipeline::moments(&images, params, Some(own.clone()))?;
        let mut settled = None;
        if index == 0
            && automatic_windows
            && let Some(d) = dynamics.as_mut()
        {
            // As `pipeline::dynamics` does with the recording's maps: windows unwrap as far as
            // the maps needed, here the first segment's (one segment: the whole path's K).
            let first = pipeline::doppler_maps(&per_angle, &compound, &images, params)?;
            if let Some(done) = first.dealias {
                d.dealias = Dealias::Intervals(done.intervals);
                settled = Some(done.intervals);
            }
        }
        let mut windows = None;
        if let Some(d) = &dynamics
            && images.n_frames() >= d.window
        {
            // A segment may be shorter than a cardiac cycle: the joined windows are checked
            // against a given heart rate when the RI maps are made, not each segment's.
            let segment_windows = DynamicsParams {
                heart_rate_hz: None,
                ..*d
            };
            let mut part = dynamics::sliding_vectors(&images, &segment_windows)?;
            // Windows start every `step` frames; keep those starting in this core.
            let keep = own.end.div_ceil(d.step.max(1)).min(part.len());
            part.truncate(keep);
            part.shift(core.start as f64 / images.frame_rate);
            windows = Some(part);
        }
        add_time(Stage::Doppler, clock.elapsed().as_secs_f64());
        let series = std::mem::take(&mut images.series);
        Ok((
            SegmentPart {
                index,
                window_intervals: settled,
                per_angle,
                compound,
                envelope,
                clutter,
                windows,
                ensembles: ensemble_part,
                kept,
                timings,
                images,
            },
            series,
        ))
    }

    /// The run's result from every segment's part of `source`, added up in recording order
    /// (whatever order `parts` come in): the maps from the summed moments, the windows and
    /// ensembles joined along time. The same sums in the same order as one process would make.
    pub fn join(
        &self,
        source: SegmentSource,
        parts: impl IntoIterator<Item = SegmentPart>,
    ) -> Result<Segmented> {
        self.join_into(source, parts, None)
    }

    /// [`Self::join`], each part's ensembles handed to `sink` in recording order instead of
    /// being joined in memory (when a sink is given).
    pub fn join_into(
        &self,
        source: SegmentSource,
        parts: impl IntoIterator<Item = SegmentPart>,
        mut sink: Option<&mut dyn EnsembleSink>,
    ) -> Result<Segmented> {
        let mut parts: Vec<SegmentPart> = parts.into_iter().collect();
        parts.sort_by_key(|p| p.index);
        let count = self.count(source);
        if parts.len() != count || parts.iter().enumerate().any(|(k, p)| p.index != k) {
            return Err(invalid(
                "segments",
                format!(
                    "the parts of segments {:?} do not make the recording's {count}",
                    parts.iter().map(|p| p.index).collect::<Vec<_>>()
                ),
            ));
        }
        let mut joined = Joined::new(self.params, source);
        for part in parts {
            joined.add(part, sink.as_deref_mut())?;
        }
        joined.finish(self, source)
    }

    /// Every segment of `source` in turn, joined as they finish: [`process_in_segments`], each
    /// segment's ensembles handed to `sink` (when given) as the segment joins instead of being
    /// kept.
    pub fn process(
        &self,
        source: SegmentSource,
        mut sink: Option<&mut dyn EnsembleSink>,
        progress: &dyn Fn(Stage, usize, usize),
    ) -> Result<Segmented> {
        self.check(source)?;
        let count = self.count(source);
        let mut joined = Joined::new(self.params, source);
        // The previous segment's series and events read, whose memory the next one's use.
        let mut spare = Vec::new();
        let mut buffers = pipeline::BlockBuffers::default();
        let mut window_intervals = None;
        for index in 0..count {
            let (part, series) = self.segment_in(
                source,
                index,
                window_intervals,
                spare,
                &mut buffers,
                progress,
            )?;
            spare = series;
            if index == 0 {
                window_intervals = part.window_intervals;
            }
            joined.add(part, sink.as_deref_mut())?;
        }
        progress(Stage::Doppler, count, count);
        // The windows' maps come back once the last series is gone.
        drop(spare);
        drop(buffers);
        joined.finish(self, source)
    }
}

/// The sums of the segments so far, their large outputs set aside.
struct Joined {
    per_angle: Vec<Sums>,
    compound: Sums,
    envelope: Array2<f64>,
    // Each part's times and settings; their maps wait in the scratch files.
    windows: Vec<VelocitySeries>,
    windows_aside: SetAside,
    ensemble_parts: Vec<EnsembleMaps>,
    ensembles_aside: SetAside,
    /// True once a sink has taken the ensembles' maps: they are not joined.
    ensembles_sunk: bool,
    clutter: Vec<Vec<ClutterReport>>,
    kept: Option<PixelSeries>,
    timings: Timings,
    images: Option<AngleImages>,
}

impl Joined {
    /// No segment yet; the stages timed are `source`'s.
    fn new(params: &ProcessParams, source: SegmentSource) -> Self {
        let forming = match source {
            SegmentSource::Channels(_) => vec![(Stage::Decode, 0.0), (Stage::Beamform, 0.0)],
            SegmentSource::Images(_) => vec![(Stage::Read, 0.0)],
        };
        Joined {
            per_angle: Vec::new(),
            compound: Sums::default(),
            envelope: Array2::zeros(params.grid.shape()),
            windows: Vec::new(),
            windows_aside: SetAside::new(),
            ensemble_parts: Vec::new(),
            ensembles_aside: SetAside::new(),
            ensembles_sunk: false,
            clutter: Vec::new(),
            kept: None,
            timings: forming
                .into_iter()
                .chain([(Stage::Clutter, 0.0), (Stage::Doppler, 0.0)])
                .collect(),
            images: None,
        }
    }

    fn add_time(&mut self, stage: Stage, seconds: f64) {
        match self.timings.iter_mut().find(|t| t.0 == stage) {
            Some(t) => t.1 += seconds,
            None => self.timings.push((stage, seconds)),
        }
    }

    /// Adds the next segment's part (parts come in recording order); its ensembles go to `sink`
    /// when one is given.
    fn add(&mut self, part: SegmentPart, sink: Option<&mut (dyn EnsembleSink + '_)>) -> Result<()> {
        if self.per_angle.is_empty() {
            self.per_angle = (0..part.per_angle.len()).map(|_| Sums::default()).collect();
        }
        if self.per_angle.len() != part.per_angle.len()
            || self.envelope.dim() != part.envelope.dim()
        {
            return Err(Error::Shape(
                "segment parts of different angles or grids".into(),
            ));
        }
        for (sums, m) in self.per_angle.iter_mut().zip(part.per_angle) {
            sums.add(m)?;
        }
        self.compound.add(part.compound)?;
        self.envelope += &part.envelope;
        if let Some(mut windows) = part.windows {
            // One angle's windows hold no Vx (`VelocitySeries::axial_only`).
            match windows.axial_only {
                true => self
                    .windows_aside
                    .put(&mut [&mut windows.vz, &mut windows.power])?,
                false => self.windows_aside.put(&mut [
                    &mut windows.vx,
                    &mut windows.vz,
                    &mut windows.power,
                ])?,
            }
            self.windows.push(windows);
        }
        if let Some(mut ensembles) = part.ensembles {
            match sink {
                Some(sink) => {
                    sink.append(&ensembles)?;
                    self.ensembles_sunk = true;
                    ensembles.keep_times_only();
                }
                None => self
                    .ensembles_aside
                    .put(&mut ensemble_fields(&mut ensembles))?,
            }
            self.ensemble_parts.push(ensembles);
        }
        self.clutter.push(part.clutter);
        match (&mut self.kept, part.kept) {
            (Some(kept), Some(later)) => kept.append(later)?,
            (kept @ None, Some(first)) => *kept = Some(first),
            _ => {}
        }
        for (stage, seconds) in part.timings {
            self.add_time(stage, seconds);
        }
        self.images = Some(part.images);
        Ok(())
    }

    /// The maps from the totals, the windows and ensembles read back and joined.
    fn finish(mut self, run: &SegmentRun, source: SegmentSource) -> Result<Segmented> {
        let params = run.params;
        let total = source.n_frames();
        let images = self
            .images
            .take()
            .ok_or_else(|| invalid("frames", "the recording has no frames"))?;
        let per_angle = self
            .per_angle
            .iter()
            .map(|s| s.total().cloned())
            .collect::<Result<Vec<_>>>()?;
        let clock = std::time::Instant::now();
        let maps = pipeline::doppler_maps(&per_angle, self.compound.total()?, &images, params)?;
        self.add_time(Stage::Doppler, clock.elapsed().as_secs_f64());
        let bmode_db = beamform::bmode_db_of_envelope(self.envelope / total as f64);
        let series = match run.dynamics {
            Some(_) => {
                let mut series = VelocitySeries::concatenate(self.windows)?;
                let mut joined = self.windows_aside.take()?.into_iter();
                let mut next = || {
                    joined
                        .next()
                        .ok_or_else(|| Error::Shape("velocity windows set aside".into()))
                };
                if !series.axial_only {
                    series.vx = next()?;
                }
                (series.vz, series.power) = (next()?, next()?);
                Some(series)
            }
            None => None,
        };
        let ensembles = match run.ensembles {
            Some(_) if self.ensembles_sunk => Some(EnsembleMaps::concatenate(self.ensemble_parts)?),
            Some(_) => {
                let mut maps = EnsembleMaps::concatenate(self.ensemble_parts)?;
                let mut joined = self.ensembles_aside.take()?.into_iter();
                for field in ensemble_fields(&mut maps) {
                    *field = joined
                        .next()
                        .ok_or_else(|| Error::Shape("ensemble maps set aside".into()))?;
                }
                Some(maps)
            }
            None => None,
        };
        let first_clutter = self
            .clutter
            .first()
            .cloned()
            .ok_or_else(|| invalid("frames", "the recording has no frames"))?;
        Ok(Segmented {
            out: ProcessOutput::from_maps(
                maps,
                params.grid.clone(),
                bmode_db,
                first_clutter,
                images,
                self.timings,
            ),
            series,
            ensembles,
            ranges: run.segments.ranges(total),
            clutter: self.clutter,
            kept: self.kept,
        })
    }
}

/// Runs the chain on `source` segment by segment as `segments` cuts it: images, clutter filter,
/// Doppler sums, and, when given, the dynamics stage's velocity windows and the time series'
/// ensembles, each from the segment holding it. Peak memory: one segment's images and filtered
/// series, not the recording's. `progress` sees every stage's work over the whole recording.
/// [`SegmentRun::segment`] and [`SegmentRun::join`] are the same run, one segment at a time.
pub fn process_in_segments(
    source: &dyn FrameSource,
    params: &ProcessParams,
    segments: &Segments,
    dynamics: Option<&DynamicsParams>,
    ensemble_spec: Option<EnsembleSpec>,
    progress: &dyn Fn(Stage, usize, usize),
) -> Result<Segmented> {
    let run = SegmentRun {
        params,
        segments,
        dynamics,
        ensembles: ensemble_spec,
        kept_pixels: &[],
    };
    run.process(SegmentSource::Channels(source), None, progress)
}
