//! The run of a recording: its [`Plan`] (every setting read and checked before work), then the
//! chain, the Doppler time series and the dynamics stage ([`run`]), whole or in segments.

use anyhow::{Context, Result, bail};
use pcuvd::acquisition::source::FrameSource;
use pcuvd::dynamics::{DynamicsParams, RiMaps, VelocitySeries, VesselTests};
use pcuvd::form::images::ImageFrames;
use pcuvd::pipeline::segments::{SegmentSource, Segments};
use pcuvd::pipeline::{self, ProcessOutput, ProcessParams};

use crate::progress::Progress;
use crate::settings::{DynamicsChoice, DynamicsSettings, ProcessingSettings, Site, Switch};

/// Every setting of a `process` run, read and checked before any work: the pipeline's, the
/// dynamics stage's, and the options as text (what summary.json records and a re-run compares).
#[derive(Debug, Clone)]
pub struct Plan {
    /// Settings of the decoding-to-vectors chain.
    pub params: ProcessParams,
    /// Settings of the dynamics stage; `None` with `--dynamics off`.
    pub dynamics: Option<DynamicsPlan>,
    /// True when a dynamics setting was given, so that a recording that cannot honour it is an
    /// error rather than a skipped stage.
    pub dynamics_required: bool,
    /// What the memory check ([`crate::memory::check_memory`]) did to the dynamics stage that
    /// `--dynamics auto` asked for, so that its windows fit: dropped it, or spaced its windows
    /// further apart; `None` when it left the stage as planned.
    pub dynamics_fit: Option<DynamicsFit>,
    /// Every processing and dynamics option, defaults included, as one line of text.
    pub options_text: String,
    /// The Doppler time series' ensembles, when asked for.
    pub ensembles: Option<pcuvd::pipeline::ensembles::EnsembleSpec>,
    /// How a recording too long to hold whole is cut; `None`: processed whole.
    pub segments: Option<Segments>,
    /// Pixels (row, col) whose clutter-filtered series the run keeps over the whole recording
    /// ([`Processed::kept`], for spectrograms); the sites' pixels, in their order, else empty.
    pub kept_pixels: Vec<(usize, usize)>,
    /// The points `--sites` asked to see the flow at over time, and their spectrograms' windows;
    /// `None` when none were asked for.
    pub sites: Option<SitePlan>,
}

/// The spectrogram sites of a run ([`ProcessingSettings::sites`]) and the windows their
/// spectrograms take (the dynamics stage's).
#[derive(Debug, Clone)]
pub struct SitePlan {
    /// The points, in the order given.
    pub sites: Vec<Site>,
    /// Each site's sample volume (`--site-radius-mm`): the pixels its spectrogram sums, its own
    /// first; the run keeps their series in this order, site after site.
    pub gates: Vec<Vec<(usize, usize)>>,
    /// The sample volume's radius (m); 0: each site's pixel alone.
    pub radius_m: f64,
    /// Each spectrogram's windows (frames at the compound frame rate).
    pub spectrogram: pcuvd::dynamics::SpectrogramParams,
}

impl SitePlan {
    /// The sites `options` asks for on `grid`, their windows those of `dynamics` at
    /// `frame_rate` (Hz) over `n_frames` frames; `None` when none were asked for.
    fn of(
        options: &ProcessingSettings,
        dynamics: &DynamicsSettings,
        grid: &pcuvd::core::grid::Grid,
        (frame_rate, n_frames): (f64, usize),
    ) -> Result<Option<SitePlan>> {
        let sites = options.sites(grid)?;
        if sites.is_empty() {
            return Ok(None);
        }
        let (window, step) = dynamics.window_frames(frame_rate)?;
        let spectrogram = pcuvd::dynamics::SpectrogramParams::for_windows(window, step, n_frames)
            .context("--sites")?;
        let radius_m = options.site_radius_mm * 1e-3;
        let gates = sites
            .iter()
            .map(|site| {
                let mut gate = crate::settings::gate_pixels(grid, site.pixel, radius_m);
                // The site's own pixel first: the one a gate of one pixel is.
                gate.retain(|&p| p != site.pixel);
                gate.insert(0, site.pixel);
                gate
            })
            .collect();
        Ok(Some(SitePlan {
            sites,
            gates,
            radius_m,
            spectrogram,
        }))
    }

    /// The pixels of every site's gate, site after site: the kept pixels.
    fn pixels(&self) -> Vec<(usize, usize)> {
        self.gates.concat()
    }

    /// Where each site's gate lies among the kept pixels: its indices there.
    pub fn gate_indices(&self) -> Vec<Vec<usize>> {
        let mut start = 0;
        self.gates
            .iter()
            .map(|gate| {
                let indices = (start..start + gate.len()).collect();
                start += gate.len();
                indices
            })
            .collect()
    }
}

impl Plan {
    /// Reads and checks the options against the recording `data`, before the long processing.
    /// `recorded_triggers`: cardiac cycle start times (s) recorded with the recording (a
    /// manifest's `[cardiac]`), used unless `--cardiac-triggers` or `--heart-rate` is given.
    pub fn new(
        options: &ProcessingSettings,
        dynamics: &DynamicsSettings,
        data: &dyn FrameSource,
        recorded_triggers: Option<&[f64]>,
    ) -> Result<Plan> {
        // Every map compares frames with one another (the lag-1 autocorrelation, the clutter
        // filter's temporal subspace): refused now, not after beamforming.
        if data.n_frames() < 2 {
            bail!(
                "the recording holds {} frame{}: Doppler needs at least 2 (each velocity is the \
                 phase change from one frame to the next)",
                data.n_frames(),
                if data.n_frames() == 1 { "" } else { "s" }
            );
        }
        let params = options.params(data)?;
        let acq = data.acquisition();
        let dynamics_settings = dynamics_plan(
            dynamics,
            &params,
            (acq.frame_rate(), data.n_frames(), acq.sequence.n_angles()),
            recorded_triggers,
        )?;
        let ensembles = options.ensembles(data.n_frames())?;
        let sites = SitePlan::of(
            options,
            dynamics,
            &params.grid,
            (acq.frame_rate(), data.n_frames()),
        )?;
        let segments = planned_cut(
            options,
            &params,
            dynamics_settings.as_ref(),
            ensembles,
            (data.n_frames(), acq.sequence.n_angles()),
        )?;
        Ok(Plan {
            ensembles,
            segments,
            params,
            dynamics: dynamics_settings,
            dynamics_required: dynamics.explicit(),
            dynamics_fit: None,
            options_text: settings_text(options, dynamics),
            kept_pixels: sites.as_ref().map(SitePlan::pixels).unwrap_or_default(),
            sites,
        })
    }

    /// The plan of a run on beamformed images formed elsewhere ([`run_images`]) of `n_frames`
    /// frames, described by `images` (their grid, angles and rates; no series needed): held
    /// whole, or cut into segments as a recording is. `recorded_triggers`: cardiac cycle start
    /// times (s) recorded with them (an images manifest's `[cardiac]`), used unless
    /// `--cardiac-triggers` or `--heart-rate` is given.
    pub fn for_images(
        options: &ProcessingSettings,
        dynamics: &DynamicsSettings,
        images: &pcuvd::form::images::AngleImages,
        n_frames: usize,
        recorded_triggers: Option<&[f64]>,
    ) -> Result<Plan> {
        let params = options.images_params(images)?;
        let dynamics_settings = dynamics_plan(
            dynamics,
            &params,
            (images.frame_rate, n_frames, images.n_angles()),
            recorded_triggers,
        )?;
        let ensembles = options.ensembles(n_frames)?;
        let sites = SitePlan::of(
            options,
            dynamics,
            &params.grid,
            (images.frame_rate, n_frames),
        )?;
        let segments = planned_cut(
            options,
            &params,
            dynamics_settings.as_ref(),
            ensembles,
            (n_frames, images.n_angles()),
        )?;
        Ok(Plan {
            ensembles,
            segments,
            params,
            dynamics: dynamics_settings,
            dynamics_required: dynamics.explicit(),
            dynamics_fit: None,
            options_text: settings_text(options, dynamics),
            kept_pixels: sites.as_ref().map(SitePlan::pixels).unwrap_or_default(),
            sites,
        })
    }

    /// Why the dynamics stage `--dynamics auto` asked for was dropped before the run (its
    /// windows would not fit in memory); `None` when it was not.
    pub fn dynamics_dropped(&self) -> Option<&str> {
        match &self.dynamics_fit {
            Some(DynamicsFit::Dropped(reason)) => Some(reason),
            _ => None,
        }
    }

    /// Applies `fit` to the dynamics stage that `--dynamics auto` asked for, in a plan of a
    /// recording of `n_frames` frames: drops the stage, or starts its windows `step` frames
    /// apart, the segments cut again for that step (the reason goes to the run's notes and
    /// summary.json). The options' text says so too: a re-run with the same options where the
    /// windows fit as planned is not the same run, and is not skipped as done.
    pub fn apply_fit(&mut self, fit: DynamicsFit, n_frames: usize) -> Result<()> {
        match &fit {
            DynamicsFit::Dropped(_) => {
                self.dynamics = None;
                self.options_text
                    .push_str(" (no dynamics stage: its windows would not fit in memory)");
            }
            DynamicsFit::Stepped { step, .. } => {
                let Some(dynamics) = self.dynamics.as_mut() else {
                    bail!("a window step for a dynamics stage that is off");
                };
                dynamics.params.step = *step;
                if let Some(segments) = self.segments {
                    self.segments = cut_and_check(
                        &self.params,
                        segments.core + segments.overlap,
                        Some(&dynamics.params),
                        self.ensembles,
                        n_frames,
                    )?;
                }
                self.options_text.push_str(&format!(
                    " (dynamics windows {step} frames apart: the default's would not fit in memory)"
                ));
            }
        }
        self.dynamics_fit = Some(fit);
        Ok(())
    }
}

/// What the memory check did to the dynamics stage that `--dynamics auto` asked for
/// ([`Plan::apply_fit`]); as JSON it travels to the processes of a run shared among workers,
/// so that each runs the one plan.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum DynamicsFit {
    /// No dynamics stage: its windows would not fit at any step up to their length; why.
    Dropped(String),
    /// The windows start `step` frames apart, more than the default, so that they fit; why.
    Stepped {
        /// Frames between window starts.
        step: usize,
        /// Why, and what the default would have needed.
        reason: String,
    },
}

/// The note of a run that goes on without the RI maps a dynamics setting of `auto` would have
/// made, and why (`reason`).
pub fn no_ri_maps_note(reason: &str) -> String {
    format!("no RI maps: {reason} (--dynamics off silences this)")
}

impl DynamicsFit {
    /// What the run says of it before it starts.
    pub fn note(&self) -> String {
        match self {
            DynamicsFit::Dropped(reason) => no_ri_maps_note(reason),
            DynamicsFit::Stepped { reason, .. } => reason.clone(),
        }
    }
}

/// How a recording of `n_frames` frames of `n_angles` angles is cut (`None`: held whole):
/// `--segment-frames`, by default as many frames as fit but never too few for the dynamics
/// windows and ensembles; the clutter cut-offs checked against the shortest series filtered.
fn planned_cut(
    options: &ProcessingSettings,
    params: &ProcessParams,
    dynamics: Option<&DynamicsPlan>,
    ensembles: Option<pcuvd::pipeline::ensembles::EnsembleSpec>,
    (n_frames, n_angles): (usize, usize),
) -> Result<Option<Segments>> {
    let (nz, nx) = params.grid.shape();
    let windows = dynamics.map(|d| &d.params);
    let segment_frames = options.segment_frames.unwrap_or_else(|| {
        pcuvd::pipeline::segments::default_segment_frames(nz * nx, n_angles)
            .max(Segments::shortest(windows, ensembles))
    });
    cut_and_check(params, segment_frames, windows, ensembles, n_frames)
}

/// How a recording of `n_frames` frames is cut into segments of at most `segment_frames`
/// frames for these `windows` and `ensembles` ([`Segments::plan`]), the clutter cut-offs of
/// `params` checked against the shortest series filtered.
fn cut_and_check(
    params: &ProcessParams,
    segment_frames: usize,
    windows: Option<&DynamicsParams>,
    ensembles: Option<pcuvd::pipeline::ensembles::EnsembleSpec>,
    n_frames: usize,
) -> Result<Option<Segments>> {
    let segments =
        Segments::plan(n_frames, segment_frames, windows, ensembles).context("--segment-frames")?;
    let shortest_filtered = segments
        .iter()
        .flat_map(|s| s.ranges(n_frames))
        .map(|(_, imaged)| imaged.len())
        .chain(ensembles.map(|e| e.frames))
        .fold(n_frames, usize::min);
    params
        .clutter
        .check_for(shortest_filtered)
        .context("--svd-low / --svd-high")?;
    Ok(segments)
}

/// The dynamics stage's settings for a recording of `n_frames` frames of `n_angles` angles at
/// `frame_rate` (Hz), processed with `params`; `None` with `--dynamics off`. With a dynamics
/// setting given, what the recording cannot give is refused now, not after processing.
/// `recorded_triggers`: cardiac cycle start times (s) recorded with the recording.
fn dynamics_plan(
    dynamics: &DynamicsSettings,
    params: &ProcessParams,
    (frame_rate, n_frames, n_angles): (f64, usize, usize),
    recorded_triggers: Option<&[f64]>,
) -> Result<Option<DynamicsPlan>> {
    if dynamics.dynamics == DynamicsChoice::Off {
        return Ok(None);
    }
    let settings = DynamicsPlan {
        params: window_params(
            dynamics,
            frame_rate,
            params.grid.step(),
            n_angles,
            params.irls,
            params.dealias,
            params.doppler_estimator,
        )?,
        vessel: dynamics.vessel_tests()?,
        triggers: match (dynamics.triggers()?, recorded_triggers) {
            (Some(given), _) => Some((given, "--cardiac-triggers".into())),
            // The recording's own triggers, unless the user gave a heart rate.
            (None, Some(recorded)) if dynamics.heart_rate.is_none() => Some((
                recorded.to_vec(),
                "the recording's manifest ([cardiac])".into(),
            )),
            (None, _) => None,
        },
    };
    if dynamics.explicit() {
        settings
            .params
            .validate(frame_rate)
            .context("dynamics options")?;
        let duration = n_frames as f64 / frame_rate;
        if let Some(hr) = settings.params.heart_rate_hz
            && 1.0 / hr > duration
        {
            bail!(
                "--heart-rate {}: a cycle lasts {:.4} s but the recording holds {:.4} s \
                 ({n_frames} frames at {frame_rate:.1} Hz); RI needs at least one whole cycle",
                crate::settings::shown("--heart-rate", hr),
                1.0 / hr,
                duration,
            );
        }
        if settings.params.window > n_frames {
            bail!(
                "--window-ms: a window of {} frames is longer than the recording's {n_frames} \
                 frames",
                settings.params.window,
            );
        }
        settings
            .params
            .check_recording(n_frames, frame_rate, settings.triggers.is_some())
            .context("the RI maps asked for (--dynamics on, or a dynamics option given)")?;
    }
    Ok(Some(settings))
}

/// What the dynamics stage gave: RI maps and the velocity series they came from, or why not.
#[derive(Debug, Clone)]
pub enum DynamicsOutcome {
    /// The stage ran.
    Done {
        /// Vector velocity in sliding windows (shared: the RI maps made again with other
        /// settings read the same windows, a long recording's gigabytes).
        series: std::sync::Arc<VelocitySeries>,
        /// PSV, EDV, RI, classes and flow directions.
        maps: Box<RiMaps>,
    },
    /// The stage was skipped (off, or the recording cannot give RI maps); the reason.
    Skipped(String),
    /// The stage a dynamics setting asked for ([`Plan::dynamics_required`]) could not be made
    /// from this recording (no cardiac cycle in its vessels' speed, say); why. Only the data
    /// could tell, after the work: the run's other results stand, and a caller keeps them
    /// before it reports this as an error ([`Processed::dynamics_failure`]).
    Failed(String),
}

/// Everything `process` computed, before anything is written.
#[derive(Debug, Clone)]
pub struct Processed {
    /// The maps of the decoding-to-vectors chain (shared: a re-run of the dynamics stage with
    /// other settings keeps them, and the filtered series they hold can be large).
    pub out: std::sync::Arc<ProcessOutput>,
    /// The dynamics stage's result.
    pub dynamics: DynamicsOutcome,
    /// Wall-clock seconds the dynamics stage took.
    pub dynamics_s: f64,
    /// The Doppler time series, when asked for. Where the run handed them to a store as it went
    /// ([`run_into`]), only their times, first frames and clutter cut-offs: the maps are
    /// (0, nz, nx) and `ensembles_in_store` is true.
    pub ensembles: Option<pcuvd::pipeline::ensembles::EnsembleMaps>,
    /// True when the ensembles' maps went to a store as the run went, not into `ensembles`.
    pub ensembles_in_store: bool,
    /// The blocks of frames the images were formed in.
    pub blocks: pcuvd::pipeline::blocks::Blocks,
    /// Each segment's core and imaged frames, and its clutter cut-offs per angle, when the
    /// recording was processed in segments.
    pub segments: Option<SegmentsDone>,
    /// The series of the plan's kept pixels, when it names any.
    pub kept: Option<pcuvd::form::images::PixelSeries>,
}

impl Processed {
    /// Why the RI maps a dynamics setting asked for could not be made from the recording: the
    /// error to report once the run's other results are kept.
    pub fn dynamics_failure(&self) -> Option<&str> {
        match &self.dynamics {
            DynamicsOutcome::Failed(reason) => Some(reason),
            _ => None,
        }
    }
}

/// What processing in segments did, for summary.json.
#[derive(Debug, Clone)]
pub struct SegmentsDone {
    /// Each segment's own frames and the frames imaged for it.
    pub ranges: Vec<(std::ops::Range<usize>, std::ops::Range<usize>)>,
    /// Each segment's clutter filter reports, per angle.
    pub clutter: Vec<Vec<pcuvd::estimate::clutter::ClutterReport>>,
}

/// Runs the chain, the time series and the dynamics stage on `data` as `plan` says, reporting
/// to `progress`. With `--dynamics auto` and no dynamics setting given, a recording that cannot
/// give RI maps (too short, one angle) skips the stage with a note; otherwise the stage is
/// [`DynamicsOutcome::Failed`], the other results returned for the caller to keep before it
/// reports the error.
pub fn run(data: &dyn FrameSource, plan: &Plan, progress: &dyn Progress) -> Result<Processed> {
    run_into(data, plan, progress, None)
}

/// [`run`], the Doppler time series handed to `sink` (when given) instead of kept: a segmented
/// run hands each segment's ensembles as the segment finishes, a whole one all of them at the
/// end, so that a long recording's series are never in memory whole. The result keeps the
/// ensembles' times only ([`Processed::ensembles_in_store`]).
pub fn run_into(
    data: &dyn FrameSource,
    plan: &Plan,
    progress: &dyn Progress,
    sink: Option<&mut dyn pcuvd::pipeline::segments::EnsembleSink>,
) -> Result<Processed> {
    said_before_the_run(plan, progress);
    let stages = crate::progress::stages(progress);
    let stages: &(dyn Fn(pipeline::Stage, usize, usize) + Sync) = &stages;
    // Images are formed a block of frames at a time, so that decoding and IQ need one block's
    // memory; each ensemble of a time series is filtered on its own, from the unfiltered images.
    if let Some(segments) = &plan.segments {
        return run_in_segments(data.into(), plan, segments, progress, sink);
    }
    let blocks = pipeline::blocks_for(data, plan.params.event_alignment);
    let (out, ensembles) =
        pipeline::process_source(data, &plan.params, blocks, plan.ensembles, stages)?;
    finish_whole(out, ensembles, blocks, plan, progress, sink)
}

/// Says, before a long run, what the plan changed that the user did not ask for: the dynamics
/// stage dropped, or its windows spaced further apart, for memory ([`Plan::dynamics_fit`]).
fn said_before_the_run(plan: &Plan, progress: &dyn Progress) {
    if let Some(fit) = &plan.dynamics_fit {
        progress.note(&fit.note());
    }
}

/// What a run held whole returns once the chain's maps `out` and the time series' `ensembles`
/// are made (from images formed in `blocks`): the ensembles handed to `sink` when given, the
/// dynamics stage run, the plan's kept pixels' series cut.
fn finish_whole(
    out: ProcessOutput,
    mut ensembles: Option<pcuvd::pipeline::ensembles::EnsembleMaps>,
    blocks: pcuvd::pipeline::blocks::Blocks,
    plan: &Plan,
    progress: &dyn Progress,
    mut sink: Option<&mut dyn pcuvd::pipeline::segments::EnsembleSink>,
) -> Result<Processed> {
    let ensembles_in_store = match (&mut sink, &mut ensembles) {
        (Some(sink), Some(maps)) => {
            sink.append(maps)?;
            maps.keep_times_only();
            true
        }
        _ => false,
    };
    let clock = std::time::Instant::now();
    let dynamics = run_dynamics(&out, plan, progress)?;
    let kept = kept_of(&out.filtered, &plan.kept_pixels)?;
    Ok(Processed {
        out: std::sync::Arc::new(out),
        dynamics,
        dynamics_s: clock.elapsed().as_secs_f64(),
        ensembles,
        ensembles_in_store,
        blocks,
        segments: None,
        kept,
    })
}

/// Runs the chain from the clutter filter on, the Doppler time series and the dynamics stage
/// on beamformed `images` formed elsewhere (a scanner's compound IQ: nothing to decode or
/// beamform), read whole or a segment at a time as `plan` ([`Plan::for_images`]) says,
/// reporting to `progress`.
pub fn run_images(
    images: &dyn ImageFrames,
    plan: &Plan,
    progress: &dyn Progress,
) -> Result<Processed> {
    run_images_into(images, plan, progress, None)
}

/// [`run_images`], the Doppler time series handed to `sink` (when given) as [`run_into`] hands
/// a recording's.
pub fn run_images_into(
    images: &dyn ImageFrames,
    plan: &Plan,
    progress: &dyn Progress,
    sink: Option<&mut dyn pcuvd::pipeline::segments::EnsembleSink>,
) -> Result<Processed> {
    said_before_the_run(plan, progress);
    let n_frames = images.n_frames();
    if let Some(segments) = &plan.segments {
        return run_in_segments(
            SegmentSource::Images(images),
            plan,
            segments,
            progress,
            sink,
        );
    }
    let stages = crate::progress::stages(progress);
    let clock = std::time::Instant::now();
    let images = images.read_frames(0..n_frames)?;
    let read_s = clock.elapsed().as_secs_f64();
    let clock = std::time::Instant::now();
    let ensembles = plan
        .ensembles
        .map(|spec| pcuvd::pipeline::ensembles::ensemble_maps(&images, &plan.params, spec, &stages))
        .transpose()?;
    let ensembles_s = clock.elapsed().as_secs_f64();
    let mut out = pipeline::analyse(images, &plan.params, &stages)?;
    if ensembles.is_some() {
        out.timings
            .insert(0, (pipeline::Stage::Ensembles, ensembles_s));
    }
    out.timings.insert(0, (pipeline::Stage::Read, read_s));
    let blocks = pcuvd::pipeline::blocks::Blocks::whole(n_frames);
    finish_whole(out, ensembles, blocks, plan, progress, sink)
}

/// The segmented run `plan` makes of `data`: its settings, with the velocity windows only where
/// the recording can give them (a window that fits).
fn segment_run<'a>(
    data: SegmentSource,
    plan: &'a Plan,
    segments: &'a Segments,
) -> pcuvd::pipeline::segments::SegmentRun<'a> {
    let windows = plan
        .dynamics
        .as_ref()
        .filter(|d| d.params.validate(data.frame_rate()).is_ok());
    pcuvd::pipeline::segments::SegmentRun {
        params: &plan.params,
        segments,
        dynamics: windows.map(|d| &d.params),
        ensembles: plan.ensembles,
        kept_pixels: &plan.kept_pixels,
    }
}

/// The series of `pixels` in a whole run's filtered images; `None` when there are none to keep.
fn kept_of(
    filtered: &pcuvd::form::images::AngleImages,
    pixels: &[(usize, usize)],
) -> Result<Option<pcuvd::form::images::PixelSeries>> {
    if pixels.is_empty() {
        return Ok(None);
    }
    Ok(Some(pcuvd::form::images::PixelSeries::of(
        filtered,
        pixels,
        0..filtered.n_frames(),
    )?))
}

/// The plan's segments of `data`, or an error saying that one holds it whole.
fn planned_segments<'a>(data: SegmentSource, plan: &'a Plan) -> Result<&'a Segments> {
    plan.segments.as_ref().with_context(|| {
        format!(
            "the recording's {} frames are processed whole: there are no segments to share out \
             (give a smaller segment_frames to cut it)",
            data.n_frames()
        )
    })
}

/// How many segments `plan` cuts `data` into, and whether the later ones need the first's
/// [`pcuvd::pipeline::segments::SegmentPart::window_intervals`]; `None` when it is processed
/// whole.
pub fn segment_count(data: SegmentSource, plan: &Plan) -> Option<(usize, bool)> {
    plan.segments.as_ref().map(|segments| {
        let run = segment_run(data, plan, segments);
        (run.count(data), run.first_settles_windows(data))
    })
}

/// Segment `index` of a segmented run of `data` as `plan` says, on its own (e.g. in another
/// process): what [`join_segments`] adds up. `window_intervals`: the first segment's
/// [`pcuvd::pipeline::segments::SegmentPart::window_intervals`], for every later segment.
pub fn run_segment(
    data: SegmentSource,
    plan: &Plan,
    index: usize,
    window_intervals: Option<u32>,
    progress: &dyn Progress,
) -> Result<pcuvd::pipeline::segments::SegmentPart> {
    let segments = planned_segments(data, plan)?;
    let stages = crate::progress::stages(progress);
    Ok(segment_run(data, plan, segments).segment(data, index, window_intervals, &stages)?)
}

/// The run of `data` from the parts of all its segments ([`run_segment`]): the same result as
/// [`run`] gives in one process.
pub fn join_segments(
    data: SegmentSource,
    plan: &Plan,
    parts: Vec<pcuvd::pipeline::segments::SegmentPart>,
    progress: &dyn Progress,
) -> Result<Processed> {
    let segments = planned_segments(data, plan)?;
    let done = segment_run(data, plan, segments).join(data, parts)?;
    finish_segmented(data, plan, done, progress, false)
}

/// A segment's part as bytes, to send to the process that joins the run.
pub fn part_to_bytes(part: &pcuvd::pipeline::segments::SegmentPart) -> Result<Vec<u8>> {
    postcard::to_stdvec(part).context("encoding a segment's part")
}

/// A segment's part from [`part_to_bytes`]'s bytes.
pub fn part_from_bytes(bytes: &[u8]) -> Result<pcuvd::pipeline::segments::SegmentPart> {
    postcard::from_bytes(bytes).context("not a segment's part of a pcuvd run")
}

/// [`run`] for a recording too long to hold whole: segment by segment
/// ([`pcuvd::pipeline::segments`]), the dynamics stage's windows and the ensembles from the segments, the
/// RI maps from their series.
fn run_in_segments(
    data: SegmentSource,
    plan: &Plan,
    segments: &Segments,
    progress: &dyn Progress,
    sink: Option<&mut dyn pcuvd::pipeline::segments::EnsembleSink>,
) -> Result<Processed> {
    let stages = crate::progress::stages(progress);
    let in_store = sink.is_some();
    let done = segment_run(data, plan, segments).process(data, sink, &stages)?;
    finish_segmented(data, plan, done, progress, in_store)
}

/// The dynamics stage's RI maps from a segmented run's series, and what [`run`] returns: the
/// blocks of frames a recording's images were formed in (images read: each segment whole).
fn finish_segmented(
    data: SegmentSource,
    plan: &Plan,
    done: pcuvd::pipeline::segments::Segmented,
    progress: &dyn Progress,
    ensembles_in_store: bool,
) -> Result<Processed> {
    let blocks = match data {
        SegmentSource::Channels(source) => {
            pipeline::blocks_for(source, plan.params.event_alignment)
        }
        SegmentSource::Images(_) => {
            let longest = done.ranges.iter().map(|(_, imaged)| imaged.len()).max();
            pcuvd::pipeline::blocks::Blocks::whole(longest.unwrap_or(0))
        }
    };
    let clock = std::time::Instant::now();
    let dynamics = dynamics_outcome(plan, progress, || match (&plan.dynamics, done.series) {
        (Some(settings), Some(series)) => {
            let maps = pipeline::ri_maps_of(
                &series,
                &done.out.maps.power_doppler,
                &done.out.grid,
                &settings.params,
                &settings.vessel,
                settings.triggers.as_ref().map(|(t, _)| t.as_slice()),
            )?;
            Ok((series.into(), maps))
        }
        // The stage's own checks say why it cannot run (a window too long).
        (Some(settings), None) => {
            settings.params.validate(data.frame_rate())?;
            Err(pcuvd::core::error::invalid(
                "dynamics",
                "no segment gave a velocity window",
            ))
        }
        (None, _) => Err(pcuvd::core::error::invalid("dynamics", "the stage is off")),
    });
    Ok(Processed {
        out: std::sync::Arc::new(done.out),
        dynamics,
        dynamics_s: clock.elapsed().as_secs_f64(),
        ensembles_in_store: ensembles_in_store && done.ensembles.is_some(),
        ensembles: done.ensembles,
        blocks,
        kept: done.kept,
        segments: Some(SegmentsDone {
            ranges: done.ranges,
            clutter: done.clutter,
        }),
    })
}

/// The dynamics stage on the chain's maps `out`, as `plan` says (see [`run`]).
pub fn run_dynamics(
    out: &ProcessOutput,
    plan: &Plan,
    progress: &dyn Progress,
) -> Result<DynamicsOutcome> {
    Ok(dynamics_outcome(plan, progress, || {
        let settings = plan
            .dynamics
            .as_ref()
            .expect("asked only when the stage is on");
        pipeline::dynamics(
            out,
            &settings.params,
            &settings.vessel,
            settings.triggers.as_ref().map(|(t, _)| t.as_slice()),
        )
        .map(|(series, maps)| (series.into(), maps))
    }))
}

/// The dynamics stage run again on `processed` (done as `done` planned it) as `plan` says. Where
/// `plan` forms the windows `processed` already holds, only the RI maps are made again from them:
/// what a long recording processed in segments allows, since its filtered series were not kept,
/// and what spares any recording the windows' vector fits. New windows need the filtered series.
pub fn rerun_dynamics(
    processed: &Processed,
    done: &Plan,
    plan: &Plan,
    progress: &dyn Progress,
) -> Result<DynamicsOutcome> {
    let held = match (&processed.dynamics, &done.dynamics, &plan.dynamics) {
        (DynamicsOutcome::Done { series, .. }, Some(before), Some(now))
            if before.params.forms_the_same_windows(&now.params) =>
        {
            Some((series, now))
        }
        _ => None,
    };
    if let Some((series, settings)) = held {
        return Ok(dynamics_outcome(plan, progress, || {
            let maps = pipeline::ri_maps_of(
                series,
                &processed.out.maps.power_doppler,
                &processed.out.grid,
                &settings.params,
                &settings.vessel,
                settings.triggers.as_ref().map(|(t, _)| t.as_slice()),
            )?;
            Ok((std::sync::Arc::clone(series), maps))
        }));
    }
    if plan.dynamics.is_some() && processed.out.filtered.series.is_empty() {
        bail!(
            "the recording was processed in segments (too long to hold whole) and its filtered \
             series were not kept, so the dynamics stage can make its RI maps again only from the \
             velocity windows the run made: {}",
            match &processed.dynamics {
                DynamicsOutcome::Done { series, .. } => format!(
                    "give the run's window_ms ({} ms), window_step_ms ({} ms), dynamics_kernel \
                     and dynamics_partial_volume (the rest may change), or process again with \
                     the new windows",
                    milliseconds(series.window_s),
                    milliseconds(series.step_s)
                ),
                DynamicsOutcome::Skipped(why) | DynamicsOutcome::Failed(why) =>
                    format!("the run made none ({why}): process again with the dynamics settings"),
            }
        );
    }
    run_dynamics(&processed.out, plan, progress)
}

/// `seconds` in milliseconds as an option takes them: rounded to the nanosecond, so that a
/// step of 9 frames at 1.8 kHz reads 5, not 5.000000000000001.
fn milliseconds(seconds: f64) -> f64 {
    (seconds * 1e9).round() / 1e6
}

/// The dynamics windows' settings: `dynamics`' windows, thresholds and pooling at `frame_rate`
/// (Hz) on a grid of `grid_step` (m), the velocity read as the whole-recording maps read it
/// (`irls`, `dealias`, `doppler`). Pooling follows each pixel's flow direction in the plane,
/// which one angle's projection does not give: off below two angles (summary.json's dynamics
/// says so).
fn window_params(
    dynamics: &DynamicsSettings,
    frame_rate: f64,
    grid_step: f64,
    n_angles: usize,
    irls: pcuvd::estimate::vector::IrlsParams,
    dealias: pcuvd::estimate::dealias::Dealias,
    doppler: pcuvd::estimate::doppler::DopplerEstimator,
) -> Result<DynamicsParams> {
    let windows = dynamics.params(frame_rate, irls, dealias, grid_step)?;
    Ok(DynamicsParams {
        doppler,
        partial_volume: dynamics.dynamics_partial_volume == Switch::On,
        pooling: windows.pooling.filter(|_| n_angles >= 2),
        ..windows
    })
}

/// The dynamics stage on clutter-filtered images formed elsewhere (a scanner's beamformed IQ, or
/// the Python stages'), as `process` runs it: `images`' series per angle (one angle: RI of the
/// colour-Doppler speed); `dynamics`' windows, thresholds, vessel tests and cycles (its
/// `--cardiac-triggers` file, if any); `processing`'s Doppler estimator, IRLS settings and
/// dealiasing; the vessel mask on the compound's power Doppler averaged over `processing`'s
/// Doppler kernel, as `process`'s maps. Returns the windows' velocity series and the RI maps.
pub fn dynamics_of_images(
    images: &pcuvd::form::images::AngleImages,
    processing: &ProcessingSettings,
    dynamics: &DynamicsSettings,
) -> Result<(VelocitySeries, RiMaps)> {
    let params = window_params(
        dynamics,
        images.frame_rate,
        images.grid.step(),
        images.n_angles(),
        processing.irls()?,
        processing.dealias()?,
        processing.doppler_estimator.into(),
    )?;
    let series = pcuvd::dynamics::sliding_vectors(images, &params)?;
    let kernel =
        crate::settings::parse_kernel(&processing.doppler_kernel).context("--doppler-kernel")?;
    let compound = pcuvd::form::beamform::compounded(&images.series)?;
    let power = pcuvd::estimate::doppler::autocorrelation(compound.view(), kernel)?.power;
    let triggers = dynamics.triggers()?;
    let maps = pipeline::ri_maps_of(
        &series,
        &power,
        &images.grid,
        &params,
        &dynamics.vessel_tests()?,
        triggers.as_deref(),
    )?;
    Ok((series, maps))
}

/// The dynamics stage's outcome as `plan` says: off, done by `stage`, or, when the recording
/// cannot give RI maps, skipped with a note where no dynamics setting was given and failed
/// where one was.
fn dynamics_outcome(
    plan: &Plan,
    progress: &dyn Progress,
    stage: impl FnOnce() -> pcuvd::Result<(std::sync::Arc<VelocitySeries>, RiMaps)>,
) -> DynamicsOutcome {
    match &plan.dynamics {
        // Said when the run started (`said_before_the_run`).
        None => DynamicsOutcome::Skipped(
            plan.dynamics_dropped()
                .map_or_else(|| "--dynamics off".into(), str::to_string),
        ),
        Some(_) => match stage() {
            Ok((series, maps)) => DynamicsOutcome::Done {
                series,
                maps: Box::new(maps),
            },
            // Settings the user gave are errors when the recording cannot meet them; a
            // recording without flow (noise alone) is not: its other results stand.
            Err(e) if !plan.dynamics_required || matches!(e, pcuvd::Error::NoFlow(_)) => {
                let reason = format!("{e:#}");
                progress.note(&no_ri_maps_note(&reason));
                DynamicsOutcome::Skipped(reason)
            }
            Err(e) => DynamicsOutcome::Failed(format!("{e:#}")),
        },
    }
}

/// The dynamics stage's settings as read from the options.
#[derive(Debug, Clone)]
pub struct DynamicsPlan {
    /// Sliding windows, heart rate, RI thresholds, pooling.
    pub params: DynamicsParams,
    /// Whole-recording vessel tests (noise-floor margin, local peak).
    pub vessel: VesselTests,
    /// Cardiac cycle start times (s from the first frame), when given, and where they came from
    /// (the option or the recording's manifest).
    pub triggers: Option<(Vec<f64>, String)>,
}

/// Every processing and dynamics setting, defaults included, as one line of text (JSON): what
/// summary.json records and a re-run compares, the same whichever front end gave them.
pub fn settings_text(options: &ProcessingSettings, dynamics: &DynamicsSettings) -> String {
    #[derive(serde::Serialize)]
    struct Settings<'a> {
        processing: &'a ProcessingSettings,
        dynamics: &'a DynamicsSettings,
    }
    // Through a `Value`, whose keys are sorted: the text does not change when fields move. (It
    // cannot fail: the settings are numbers, words and lists, with no map keyed otherwise.)
    serde_json::to_value(Settings {
        processing: options,
        dynamics,
    })
    .map(|settings| settings.to_string())
    .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;
    use pcuvd::simulate::phantom::network::{NetworkPhantom, NetworkSpec, VesselKind, VesselSpec};
    use pcuvd::simulate::{self, SimParams};
    use pcuvd::{Coding, Probe, Sequence};

    /// `dynamics_of_images`, the stage on images formed elsewhere, is the run's own dynamics
    /// stage: fed a one-angle run's filtered images with the same settings, it gives the run's
    /// RI maps to the bit (the same windows, vessel mask and cycles).
    #[test]
    fn the_stage_on_given_images_is_the_runs_own() {
        let vessel = |name: &str, kind, x: f64, angle_deg: f64, psv, ri| VesselSpec {
            name: name.into(),
            kind,
            centre: [x, 6.5e-3],
            angle: f64::to_radians(angle_deg),
            length: 2.5e-3,
            radius: 0.25e-3,
            psv,
            ri,
            delay_s: 0.01,
        };
        let spec = NetworkSpec {
            vessels: vec![
                vessel("A", VesselKind::Arteriole, -0.6e-3, 70.0, 25e-3, 0.7),
                vessel("V", VesselKind::Venule, 0.6e-3, -110.0, 12e-3, 0.3),
            ],
            heart_rate_hz: 12.0,
            density: 3e8,
        };
        let phantom = NetworkPhantom::new(spec, 2).unwrap();
        let mut probe = Probe::l22_14vx();
        probe.n_elements = 32;
        let sequence = Sequence {
            angles: vec![0.0],
            event_prf: 1.8e3,
            coding: Coding::Conventional,
            pulse_cycles: 2.0,
            pulse: None,
        };
        let params = SimParams::new(probe, sequence, 65e6, 1540.0, (5.0e-3, 8.0e-3)).unwrap();
        let data = simulate::simulate(&phantom, &params, 240, &|_, _| {}).unwrap();
        let options = ProcessingSettings {
            grid: Some("-0.8,0.8,5.5,7.5,0.1".into()),
            svd_low: "off".into(),
            doppler_estimator: crate::settings::DopplerEstimatorOption::Kasai,
            ..ProcessingSettings::default()
        };
        let dynamics = DynamicsSettings {
            heart_rate: Some(12.0),
            ..DynamicsSettings::default()
        };
        let plan = Plan::new(&options, &dynamics, &data, None).unwrap();
        let processed = run(&data, &plan, &crate::progress::Silent).unwrap();
        let DynamicsOutcome::Done { series, maps } = &processed.dynamics else {
            panic!("no RI maps: {:?}", processed.dynamics);
        };
        assert!(series.axial_only);
        assert!(
            maps.vessel_class
                .iter()
                .any(|&c| c == pcuvd::dynamics::ARTERIOLE)
        );
        let (given_series, given) =
            dynamics_of_images(&processed.out.filtered, &options, &dynamics).unwrap();
        // NaN (the unknown Vx, the background's RI) compared by its bits.
        let same_bits = |a: ndarray::ArrayViewD<f64>, b: ndarray::ArrayViewD<f64>| {
            a.shape() == b.shape() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
        };
        assert_eq!(given_series.times_s, series.times_s);
        assert_eq!(given.vessel_class, maps.vessel_class);
        for (a, b) in [
            (
                given_series.vx.view().into_dyn(),
                series.vx.view().into_dyn(),
            ),
            (
                given_series.vz.view().into_dyn(),
                series.vz.view().into_dyn(),
            ),
            (
                given_series.power.view().into_dyn(),
                series.power.view().into_dyn(),
            ),
            (given.ri.view().into_dyn(), maps.ri.view().into_dyn()),
            (given.psv.view().into_dyn(), maps.psv.view().into_dyn()),
            (given.edv.view().into_dyn(), maps.edv.view().into_dyn()),
        ] {
            assert!(same_bits(a, b));
        }
    }
}
