//! Command-line options shared by the commands that process recordings.

use anyhow::{Context, Result, bail};
use clap::Args;
use pcuvd::beamform::{Apodization, DasParams};
use pcuvd::clutter::{ClutterParams, RankCut};
use pcuvd::dynamics::{self, DynamicsParams, VesselPooling, VesselTests};
use pcuvd::grid::Grid;
use pcuvd::pipeline::{self, ProcessParams};
use pcuvd::vector::{Estimator, IrlsParams};

/// Processing options (grid, beamforming, clutter filter, Doppler, IRLS).
#[derive(Args, Debug, Clone)]
pub struct ProcessingOptions {
    /// Imaging grid XMIN,XMAX,ZMIN,ZMAX,STEP in mm (e.g. --grid=-12.5,12.5,10,35,0.1); default: the
    /// array's width, from 1 mm to the recorded depth, half-wavelength step.
    #[arg(
        long,
        visible_alias = "grid-mm",
        allow_hyphen_values = true,
        value_name = "XMIN,XMAX,ZMIN,ZMAX,STEP"
    )]
    pub grid: Option<String>,
    /// Receive f-number (depth / active aperture width).
    #[arg(long, default_value_t = DasParams::DEFAULT_F_NUMBER)]
    pub f_number: f64,
    /// SVD clutter filter: tissue components removed: "auto", "off" or a number.
    #[arg(long, default_value = "auto")]
    pub svd_low: String,
    /// SVD clutter filter: first noise component removed: "off", "auto" or a number.
    #[arg(long, default_value = "off")]
    pub svd_high: String,
    /// Spatial averaging of the autocorrelation, ROWSxCOLS pixels (odd), e.g. 3x3.
    #[arg(long, default_value = "1x1")]
    pub doppler_kernel: String,
    /// Which frequency turns the Doppler phase into velocity: "loupas" (the mean RF frequency
    /// measured at every pixel: unbiased whatever the echo spectrum, depth or attenuation) or
    /// "kasai" (the nominal centre frequency, the paper's eq. 5: reads a few per cent low).
    #[arg(long, value_enum, default_value_t = DopplerEstimatorOption::from(pcuvd::doppler::DopplerEstimator::default()))]
    pub doppler_estimator: DopplerEstimatorOption,
    /// IRLS regularisation λ (mm/s) of the weights 1/(|residual| + λ).
    #[arg(long, default_value_t = IrlsParams::default().lambda_mm_s)]
    pub irls_lambda: f64,
    /// IRLS convergence threshold on the largest weight change.
    #[arg(long, default_value_t = IrlsParams::default().epsilon)]
    pub irls_epsilon: f64,
    /// IRLS iteration cap.
    #[arg(long, default_value_t = IrlsParams::default().max_iterations)]
    pub irls_max_iterations: usize,
    /// How coded (Hadamard) events are decoded: "mid-frame" (each event's slow-time series
    /// resampled to the frame's mid-event time first, so moving blood does not leak angles into
    /// each other) or "simultaneous" (the paper's decoding: the events of a frame taken as
    /// simultaneous). Conventional recordings are not affected.
    #[arg(long, value_enum, default_value_t = Alignment::from(pcuvd::decode::EventAlignment::default()))]
    pub event_alignment: Alignment,
    /// Vector dealiasing: "off", "auto" or K. A projection beyond the Nyquist velocity v_N wraps
    /// by 2·v_N; K unwraps up to ±K such intervals per angle (speeds up to (2K + 1)·v_N), choosing
    /// each pixel's alias pattern by the smallest residual of the vector fit and the common shift
    /// of all angles over each vessel (flow pixels only: power 3 dB above the noise floor and
    /// within 20 dB of the brightest pixel within 1 mm; dealias.png shows the counts): the
    /// shift at which its wall pixels read slowest, unless another makes the vessel's
    /// power-weighted residual below 0.8 times as large (flow fast up to the wall). "auto"
    /// picks the smallest K of 1–4 at which under 1 % of the unwrapped pixels reach ±K. Applies
    /// to the vector maps, the ensembles and the dynamics windows. Hadamard-coded recordings
    /// decode flow above v_N wrongly, which dealiasing cannot mend (a warning says so): it is for
    /// conventional recordings.
    #[arg(long, default_value = "off")]
    pub dealias: String,
    /// Partial-volume correction: "on" moves each angle's projection from its resolution cell's
    /// power centroid back to the pixel before the vector fit (the cell measured from that
    /// angle's speckle, the centroid from its power Doppler's gradient): the wall of a vessel and
    /// the speckle inside it no longer pull the velocity toward where the echoes are brighter.
    /// Applies to the vector maps and the ensembles' (the dynamics windows' with
    /// --dynamics-partial-volume on). Where
    /// flow exceeds the Nyquist velocity, use it with --dealias (it works on the unwrapped
    /// projections; across a wrap the gradient it needs is meaningless).
    #[arg(long, value_enum, default_value = "off")]
    pub partial_volume: Switch,
    /// Doppler time series: compound frames per ensemble; each ensemble gets its own clutter
    /// filter and its own power, colour and vector maps (ensemble_*.npy, ensembles.png). Default:
    /// none (the whole recording is one ensemble, as the other maps are).
    #[arg(long)]
    pub ensemble_frames: Option<usize>,
    /// Frames from one ensemble's start to the next's (default: --ensemble-frames, no overlap).
    #[arg(long, requires = "ensemble_frames")]
    pub ensemble_step: Option<usize>,
    /// Long recordings: compound frames per segment, each imaged, clutter-filtered and analysed
    /// on its own so that memory stays bounded (default: as many as fit in 1.25 GiB of image
    /// series; the whole recording in one when it fits, which gives the exact whole-recording
    /// maps).
    #[arg(long)]
    pub segment_frames: Option<usize>,
}

impl ProcessingOptions {
    /// The dealiasing of `--dealias`.
    pub fn dealias(&self) -> Result<pcuvd::dealias::Dealias> {
        pcuvd::dealias::Dealias::parse(&self.dealias).context("--dealias")
    }

    /// The ensembles of `--ensemble-frames` / `--ensemble-step`, checked against a recording of
    /// `frames` frames; `None` when no time series was asked for.
    pub fn ensembles(&self, frames: usize) -> Result<Option<pcuvd::ensembles::EnsembleSpec>> {
        let Some(ensemble_frames) = self.ensemble_frames else {
            return Ok(None);
        };
        let spec = pcuvd::ensembles::EnsembleSpec {
            frames: ensemble_frames,
            step: self.ensemble_step.unwrap_or(ensemble_frames),
        };
        spec.starts(frames)
            .context("--ensemble-frames / --ensemble-step")?;
        Ok(Some(spec))
    }
}

/// Which frequency turns the Doppler phase into velocity ([`pcuvd::doppler::DopplerEstimator`]).
#[derive(Clone, Copy, PartialEq, Eq, Debug, clap::ValueEnum)]
pub enum DopplerEstimatorOption {
    /// The nominal centre frequency (Kasai; the paper's eq. 5).
    Kasai,
    /// The mean RF frequency measured at every pixel (2-D autocorrelation, Loupas).
    Loupas,
}

impl From<pcuvd::doppler::DopplerEstimator> for DopplerEstimatorOption {
    fn from(e: pcuvd::doppler::DopplerEstimator) -> Self {
        match e {
            pcuvd::doppler::DopplerEstimator::Kasai => Self::Kasai,
            pcuvd::doppler::DopplerEstimator::Loupas => Self::Loupas,
        }
    }
}

impl From<DopplerEstimatorOption> for pcuvd::doppler::DopplerEstimator {
    fn from(e: DopplerEstimatorOption) -> Self {
        match e {
            DopplerEstimatorOption::Kasai => Self::Kasai,
            DopplerEstimatorOption::Loupas => Self::Loupas,
        }
    }
}

/// The tube's flow profile ([`pcuvd::phantom::FlowProfile`]).
#[derive(Clone, Copy, PartialEq, Eq, Debug, clap::ValueEnum)]
pub enum TubeProfile {
    /// Laminar: peak·(1 − (l/R)²), zero at the wall.
    Parabolic,
    /// The peak speed across the whole lumen, a step at the wall.
    Plug,
}

impl From<pcuvd::phantom::FlowProfile> for TubeProfile {
    fn from(p: pcuvd::phantom::FlowProfile) -> Self {
        match p {
            pcuvd::phantom::FlowProfile::Parabolic => Self::Parabolic,
            pcuvd::phantom::FlowProfile::Plug => Self::Plug,
        }
    }
}

impl From<TubeProfile> for pcuvd::phantom::FlowProfile {
    fn from(p: TubeProfile) -> Self {
        match p {
            TubeProfile::Parabolic => Self::Parabolic,
            TubeProfile::Plug => Self::Plug,
        }
    }
}

/// How coded events are aligned in slow time before decoding ([`EventAlignment`]).
#[derive(Clone, Copy, PartialEq, Eq, Debug, clap::ValueEnum)]
pub enum Alignment {
    /// Each event resampled to the frame's mid-event time (exact for Doppler below half the
    /// frame rate).
    MidFrame,
    /// The events of a frame taken as simultaneous (the paper's decoding).
    Simultaneous,
}

impl Alignment {
    /// The option's value, as written on the command line and in reports.
    pub fn label(self) -> &'static str {
        pcuvd::decode::EventAlignment::from(self).label()
    }
}

impl From<pcuvd::decode::EventAlignment> for Alignment {
    fn from(a: pcuvd::decode::EventAlignment) -> Self {
        match a {
            pcuvd::decode::EventAlignment::MidFrame => Self::MidFrame,
            pcuvd::decode::EventAlignment::Simultaneous => Self::Simultaneous,
        }
    }
}

impl From<Alignment> for pcuvd::decode::EventAlignment {
    fn from(a: Alignment) -> Self {
        match a {
            Alignment::MidFrame => Self::MidFrame,
            Alignment::Simultaneous => Self::Simultaneous,
        }
    }
}

fn rank_cut(text: &str, option: &str) -> Result<RankCut> {
    match text {
        "auto" => Ok(RankCut::Auto),
        "off" | "none" => Ok(RankCut::Off),
        n => n.parse::<usize>().map(RankCut::Fixed).with_context(|| {
            format!("--{option} must be \"auto\", \"off\" or a whole number, got {n:?}")
        }),
    }
}

/// Parses "XMIN,XMAX,ZMIN,ZMAX,STEP" in mm into a grid in m.
pub fn parse_grid(text: &str) -> Result<Grid> {
    let values = parse_numbers(text).with_context(|| {
        format!("--grid {text:?}: expected five numbers in mm: XMIN,XMAX,ZMIN,ZMAX,STEP")
    })?;
    let [x0, x1, z0, z1, step] = values[..] else {
        bail!(
            "--grid {text:?}: expected five numbers in mm (XMIN,XMAX,ZMIN,ZMAX,STEP), got {}",
            values.len()
        );
    };
    Grid::new(x0 * 1e-3, x1 * 1e-3, z0 * 1e-3, z1 * 1e-3, step * 1e-3)
        .with_context(|| format!("--grid {text:?}"))
}

/// The text the user gave for option `flag` (e.g. "--window-ms") on this process's command line,
/// as written (`--flag VALUE` or `--flag=VALUE`, the last one given); `None` when it is not there
/// (a default, or a front end such as Python that passes its own arguments).
pub fn as_written(flag: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    let mut found = None;
    for (i, arg) in args.iter().enumerate() {
        if arg == flag {
            found = args.get(i + 1).cloned();
        } else if let Some(value) = arg.strip_prefix(flag).and_then(|r| r.strip_prefix('=')) {
            found = Some(value.to_string());
        }
    }
    found
}

/// Option `flag`'s value for a message: as the user wrote it on the command line, else `value`
/// in its shortest exact form (1e-300, not three hundred zeros).
pub fn shown(flag: &str, value: f64) -> String {
    as_written(flag).unwrap_or_else(|| format!("{value:?}"))
}

/// Parses a comma-separated list of finite numbers.
pub fn parse_numbers(text: &str) -> Result<Vec<f64>> {
    let values: Vec<f64> = text
        .split(',')
        .map(|v| v.trim().parse::<f64>())
        .collect::<std::result::Result<_, _>>()?;
    if values.iter().any(|v| !v.is_finite()) {
        bail!("every number must be finite");
    }
    Ok(values)
}

/// Parses a level in dB, or "off" (`None`: the test it sets is dropped).
pub fn parse_db_or_off(text: &str) -> Result<Option<f64>> {
    if text.trim().eq_ignore_ascii_case("off") {
        return Ok(None);
    }
    match text.trim().parse::<f64>() {
        Ok(db) if db.is_finite() => Ok(Some(db)),
        _ => bail!("{text:?}: give a number of dB or \"off\""),
    }
}

/// Most frames a sliding window may span: 10⁹ (a day at 10 kHz); more is a unit mistake, and a
/// frame count that does not fit a machine word would wrap.
const MAX_WINDOW_FRAMES: f64 = 1e9;

/// Range of receive f-numbers accepted: below 0.1 the aperture would be ten times the depth, above
/// 100 a single element; outside it the value is a mistake.
const F_NUMBER_RANGE: (f64, f64) = (0.1, 100.0);

/// Default sliding-window length of `--window-ms` (ms).
const DEFAULT_WINDOW_MS: f64 = dynamics::DEFAULT_WINDOW_S * 1e3;

/// An averaging-kernel size as "ROWSxCOLS", the form [`parse_kernel`] reads.
pub fn kernel_text((rows, cols): (usize, usize)) -> String {
    format!("{rows}x{cols}")
}

/// Parses "ROWSxCOLS" (e.g. "3x3") into an averaging-kernel size.
pub fn parse_kernel(text: &str) -> Result<(usize, usize)> {
    let parts: Vec<&str> = text.split(['x', 'X', ',']).collect();
    let parsed = match parts[..] {
        [r, c] => (
            r.trim().parse::<usize>().ok(),
            c.trim().parse::<usize>().ok(),
        ),
        _ => (None, None),
    };
    let (Some(rows), Some(cols)) = parsed else {
        bail!("--doppler-kernel {text:?}: expected ROWSxCOLS, e.g. 3x3");
    };
    Ok((rows, cols))
}

/// An option that is on or off.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Switch {
    /// Off.
    Off,
    /// On.
    On,
}

/// Whether `pcuvd process` runs the dynamics stage (cardiac cycle, PSV/EDV/RI maps).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum DynamicsChoice {
    /// When the recording holds a cardiac cycle and several angles; otherwise skipped with a note.
    Auto,
    /// Always: a recording that cannot give RI maps is an error.
    On,
    /// Never.
    Off,
}

/// Options of the dynamics stage of `pcuvd process`.
#[derive(Args, Debug, Clone)]
pub struct DynamicsOptions {
    /// Sliding-window vector velocity, PSV/EDV/RI and artery/vein maps: "auto" (when the recording
    /// holds a cardiac cycle), "on" (required) or "off".
    #[arg(long, value_enum, default_value = "auto")]
    pub dynamics: DynamicsChoice,
    /// Heart rate (Hz); default: measured from the data — from its systolic upstrokes where two
    /// are recorded (about one cycle or more), else from its autocorrelation (about 1.5 cycles).
    #[arg(long, visible_alias = "heart-rate-hz")]
    pub heart_rate: Option<f64>,
    /// Cardiac cycle start times (s from the recording's first frame: ECG R-waves or scanner
    /// triggers), a 1-D .npy file or a text file of numbers: each cycle runs from one to the next.
    #[arg(long)]
    pub cardiac_triggers: Option<std::path::PathBuf>,
    /// Sliding-window length (ms); default 20 ms (36 frames at the rat's 1.8 kHz).
    #[arg(long)]
    pub window_ms: Option<f64>,
    /// Time between window starts (ms); default 5 ms.
    #[arg(long)]
    pub window_step_ms: Option<f64>,
    /// Smallest RI of an arteriole (paper: arterioles 0.55–0.9).
    #[arg(long, default_value_t = DynamicsParams::rat().artery_ri_min)]
    pub artery_ri_min: f64,
    /// Largest RI of a venule (paper: below 0.5).
    #[arg(long, default_value_t = DynamicsParams::rat().vein_ri_max)]
    pub vein_ri_max: f64,
    /// Vessel threshold for the RI maps (dB re. the brightest pixel's mean power).
    #[arg(long, default_value_t = DynamicsParams::rat().min_power_db, allow_hyphen_values = true)]
    pub vessel_threshold_db: f64,
    /// Vessel pixels of the RI maps must also have a whole-recording power Doppler at least this
    /// many dB above the noise floor of their depth (the 30th percentile of the row); "off" leaves
    /// only --vessel-threshold-db.
    #[arg(long, default_value_t = dynamics::VESSEL_MARGIN_DB.to_string(), allow_hyphen_values = true)]
    pub vessel_margin_db: String,
    /// Vessel pixels of the RI maps must also have a whole-recording power Doppler within this
    /// many dB of the brightest pixel within --vessel-local-radius-mm: drops the side-lobe haze
    /// that bright vessels cast over their surroundings in clean recordings; "off" drops the test.
    #[arg(long, default_value_t = dynamics::VESSEL_LOCAL_DB.to_string(), allow_hyphen_values = true)]
    pub vessel_local_db: String,
    /// Half-width (mm) of the square searched for the local peak of --vessel-local-db.
    #[arg(long, default_value_t = dynamics::VESSEL_LOCAL_RADIUS_M * 1e3)]
    pub vessel_local_radius_mm: f64,
    /// Spatial averaging of each window's autocorrelation for the RI maps, ROWSxCOLS pixels (odd):
    /// a 20 ms window sees only a few speckle renewals, so per-pixel speeds jitter and the extremes
    /// (PSV, EDV) of a jittery waveform inflate RI; 5x5 is 0.25 mm on a 0.05 mm grid.
    #[arg(long, default_value_t = kernel_text(dynamics::RI_KERNEL))]
    pub dynamics_kernel: String,
    /// The partial-volume correction (--partial-volume) in every dynamics window too: each
    /// angle's cell measured once on the whole recording, each window corrected with its own
    /// power Doppler. Off by default: on the rat-network preset it made the RI maps worse
    /// (median |ΔRI| 0.0145 → 0.0179, classes right 99.9 → 98.7 %), though it helped the vessel
    /// network study's (0.015 → 0.012); a 20 ms window's power is too speckled to place each
    /// cell's centroid reliably.
    #[arg(long, value_enum, default_value = "off")]
    pub dynamics_partial_volume: Switch,
    /// Vessel pooling for the RI maps, half-length (mm) along the flow: each pixel's waveform
    /// shape is averaged over same-direction neighbours in an ellipse aligned with its flow (RI
    /// does not change with the lumen's velocity profile nor along a vessel, only the jitter
    /// does); 0 with --pool-across-mm 0 turns it off.
    #[arg(long, default_value_t = VesselPooling::DEFAULT_ALONG_M * 1e3)]
    pub pool_along_mm: f64,
    /// Vessel pooling half-width (mm) across the flow: parallel vessels farther apart than this
    /// are never pooled together.
    #[arg(long, default_value_t = VesselPooling::DEFAULT_ACROSS_M * 1e3)]
    pub pool_across_mm: f64,
    /// Largest angle (degrees) between the mean flow directions of pooled pixels: keeps an
    /// arteriole and a venule side by side, flowing opposite ways, apart.
    #[arg(long, default_value_t = VesselPooling::DEFAULT_MAX_ANGLE_DEG)]
    pub pool_max_angle_deg: f64,
}

impl DynamicsOptions {
    /// True when the user set any dynamics setting (then a recording that cannot honour it is an
    /// error even with `--dynamics auto`).
    pub fn explicit(&self) -> bool {
        self.dynamics == DynamicsChoice::On
            || self.heart_rate.is_some()
            || self.cardiac_triggers.is_some()
            || self.window_ms.is_some()
            || self.window_step_ms.is_some()
    }

    /// The cycle start times of `--cardiac-triggers` (s), read and checked; `None` without it.
    pub fn triggers(&self) -> Result<Option<Vec<f64>>> {
        if self.heart_rate.is_some() && self.cardiac_triggers.is_some() {
            bail!("--heart-rate and --cardiac-triggers: give one (triggers delimit the cycles)");
        }
        self.cardiac_triggers
            .as_deref()
            .map(|path| pcuvd_io::read_trigger_times(path).context("--cardiac-triggers"))
            .transpose()
    }

    /// The whole-recording vessel tests of `--vessel-margin-db`, `--vessel-local-db` and
    /// `--vessel-local-radius-mm`.
    pub fn vessel_tests(&self) -> Result<VesselTests> {
        // "off" is a margin every pixel clears, and a local level every pixel is within.
        let margin_db = parse_db_or_off(&self.vessel_margin_db)
            .context("--vessel-margin-db")?
            .unwrap_or(f64::NEG_INFINITY);
        let local_db = parse_db_or_off(&self.vessel_local_db)
            .context("--vessel-local-db")?
            .unwrap_or(f64::INFINITY);
        let tests = VesselTests {
            margin_db,
            local_db,
            local_radius_m: self.vessel_local_radius_mm * 1e-3,
        };
        tests
            .validate()
            .context("--vessel-local-db / --vessel-local-radius-mm")?;
        Ok(tests)
    }

    /// Dynamics settings at compound frame rate `frame_rate` (Hz): windows converted from ms to
    /// frames, the PC-UVD estimator (IRLS-WLS) with `irls` and `dealias`, the averaging kernel of
    /// `--dynamics-kernel`, vessel pooling converted from mm to pixels of `grid_step_m` (m).
    pub fn params(
        &self,
        frame_rate: f64,
        irls: IrlsParams,
        dealias: pcuvd::dealias::Dealias,
        grid_step_m: f64,
    ) -> Result<DynamicsParams> {
        let kernel = parse_kernel(&self.dynamics_kernel)
            .map_err(|e| anyhow::anyhow!("{e}").context("--dynamics-kernel"))?;
        let frames = |ms: f64, option: &str| -> Result<usize> {
            let flag = format!("--{option}");
            if !(ms.is_finite() && ms > 0.0) {
                bail!(
                    "{flag} {}: must be a positive number of ms",
                    shown(&flag, ms)
                );
            }
            let frames = (ms * 1e-3 * frame_rate).round();
            if frames > MAX_WINDOW_FRAMES {
                bail!(
                    "{flag} {}: {frames:.3e} frames at the compound rate {frame_rate:.0} Hz; \
                     longer than any recording",
                    shown(&flag, ms)
                );
            }
            Ok(frames as usize)
        };
        let window = frames(self.window_ms.unwrap_or(DEFAULT_WINDOW_MS), "window-ms")?;
        if window < 2 {
            bail!(
                "--window-ms {}: {window} frame(s) at the compound rate {frame_rate:.0} Hz; a window needs at least 2",
                shown("--window-ms", self.window_ms.unwrap_or(DEFAULT_WINDOW_MS))
            );
        }
        let step = frames(
            self.window_step_ms
                .unwrap_or(dynamics::DEFAULT_STEP_S * 1e3),
            "window-step-ms",
        )?
        .max(1);
        if let Some(hr) = self.heart_rate
            && !(hr.is_finite() && hr > 0.0 && hr <= frame_rate)
        {
            bail!(
                "--heart-rate {}: must be a positive number of Hz, at most the compound frame \
                 rate {frame_rate:.1} Hz",
                shown("--heart-rate", hr)
            );
        }
        let pooling = VesselPooling::from_metres(
            self.pool_along_mm * 1e-3,
            self.pool_across_mm * 1e-3,
            self.pool_max_angle_deg,
            grid_step_m,
        )
        .context("--pool-along-mm / --pool-across-mm / --pool-max-angle-deg")?;
        let params = DynamicsParams {
            window,
            step,
            heart_rate_hz: self.heart_rate,
            estimator: Estimator::Irls(irls),
            dealias,
            kernel,
            artery_ri_min: self.artery_ri_min,
            vein_ri_max: self.vein_ri_max,
            min_power_db: self.vessel_threshold_db,
            pooling,
            ..DynamicsParams::rat()
        };
        params
            .validate_thresholds()
            .context("--artery-ri-min / --vein-ri-max / --vessel-threshold-db")?;
        Ok(params)
    }
}

impl ProcessingOptions {
    /// Stage settings for `data`.
    pub fn params(&self, data: &dyn pcuvd::source::FrameSource) -> Result<ProcessParams> {
        let grid = match &self.grid {
            Some(text) => {
                let grid = parse_grid(text)?;
                pipeline::check_grid_depth(data.acquisition(), data.trace_shape().1, &grid)
                    .with_context(|| format!("--grid {text:?}"))?;
                grid
            }
            None => pipeline::default_grid_for(data.acquisition(), data.trace_shape().1)?,
        };
        let (rows, cols) = parse_kernel(&self.doppler_kernel)?;
        let (nz, nx) = grid.shape();
        if rows % 2 == 0 || cols % 2 == 0 || rows > nz || cols > nx {
            bail!(
                "--doppler-kernel {:?}: sizes must be odd and at most the grid's {nz} × {nx} pixels",
                self.doppler_kernel
            );
        }
        if !(self.f_number >= F_NUMBER_RANGE.0 && self.f_number <= F_NUMBER_RANGE.1) {
            bail!(
                "--f-number {}: must be within [{}, {}] (depth / receive aperture width)",
                shown("--f-number", self.f_number),
                F_NUMBER_RANGE.0,
                F_NUMBER_RANGE.1
            );
        }
        let irls = IrlsParams {
            lambda_mm_s: self.irls_lambda,
            epsilon: self.irls_epsilon,
            max_iterations: self.irls_max_iterations,
        };
        irls.validate()
            .context("--irls-lambda / --irls-epsilon / --irls-max-iterations")?;
        let params = ProcessParams {
            grid,
            das: DasParams {
                f_number: self.f_number,
                apodization: Apodization::Hann,
                sound_speed: data.acquisition().sound_speed,
            },
            clutter: ClutterParams {
                low: rank_cut(&self.svd_low, "svd-low")?,
                high: rank_cut(&self.svd_high, "svd-high")?,
                ..ClutterParams::default()
            },
            doppler_kernel: (rows, cols),
            doppler_estimator: self.doppler_estimator.into(),
            irls,
            iq_cutoff: None,
            event_alignment: self.event_alignment.into(),
            dealias: self.dealias()?,
            partial_volume: self.partial_volume == Switch::On,
        };
        // Refused now, not after imaging: an estimator the grid cannot serve.
        pipeline::check_doppler_estimator(data.acquisition(), &params).with_context(|| {
            format!(
                "--doppler-estimator {} on a {:.1} µm axial grid step",
                params.doppler_estimator.label(),
                params.grid.axial_step() * 1e6
            )
        })?;
        Ok(params)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_accepts_negative_mm() {
        let g = parse_grid("-12.5,12.5,10,35,0.1").unwrap();
        assert_eq!(g.shape(), (251, 251));
        assert!((g.x[0] + 12.5e-3).abs() < 1e-12);
        assert!(parse_grid("1,2,3").is_err());
        assert!(parse_grid("a,2,3,4,5").is_err());
        assert!(parse_grid("0,1,1,2,-0.1").is_err());
    }
}
