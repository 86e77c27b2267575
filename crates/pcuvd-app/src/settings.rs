//! The settings of a processing run, in the units people give them, shared by every front end:
//! the command line maps its options into them (with the `clap` feature they are its options),
//! Python maps keywords into them (a dict, through serde). `Default` is the command's defaults.
//!
//! Values that are a word or a number ("auto", "off", 3) are kept as the text the user gave and
//! read when the run is planned, so that every front end gets the same checks and messages.

use anyhow::{Context, Result, bail};
use pcuvd::core::grid::Grid;
use pcuvd::dynamics::{self, DynamicsParams, VesselPooling, VesselTests};
use pcuvd::estimate::clutter::{ClutterParams, RankCut};
use pcuvd::estimate::vector::{Estimator, IrlsParams};
use pcuvd::form::beamform::{Apodization, DasParams};
use pcuvd::form::images::AngleImages;
use pcuvd::pipeline::{self, ProcessParams};
use serde::{Deserialize, Deserializer, Serialize};

/// Processing options (grid, beamforming, clutter filter, Doppler, IRLS).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
#[serde(default, deny_unknown_fields)]
pub struct ProcessingSettings {
    /// Imaging grid XMIN,XMAX,ZMIN,ZMAX,STEP in mm (e.g. --grid=-12.5,12.5,10,35,0.1); default: the
    /// array's width, from 1 mm to the recorded depth, half-wavelength step.
    #[cfg_attr(
        feature = "clap",
        arg(
            long,
            visible_alias = "grid-mm",
            allow_hyphen_values = true,
            value_name = "XMIN,XMAX,ZMIN,ZMAX,STEP"
        )
    )]
    #[serde(alias = "grid_mm", deserialize_with = "optional_text")]
    pub grid: Option<String>,
    /// Receive f-number (depth / active aperture width).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = ProcessingSettings::default().f_number))]
    pub f_number: f64,
    /// SVD clutter filter: tissue components removed: "auto" (strong and slow), "similarity"
    /// (spatial similarity of the singular vectors), "off" or a number.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = ProcessingSettings::default().svd_low))]
    #[serde(deserialize_with = "text")]
    pub svd_low: String,
    /// SVD clutter filter: first noise component removed: "off", "auto" (Marchenko–Pastur edge),
    /// "similarity" or a number.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = ProcessingSettings::default().svd_high))]
    #[serde(deserialize_with = "text")]
    pub svd_high: String,
    /// SVD clutter filter block-wise: overlapping square blocks this wide (mm), each filtered
    /// with its own cut-offs by the rules above and blended back (Song et al. 2017), or "whole"
    /// for one filter of the whole image; a block smaller than the ensemble's frames grows until
    /// it holds as many pixels, and an odd side gains a pixel (summary.json gives the size
    /// filtered). A block cuts at most what the whole image's rule cuts, so where that cuts
    /// nothing the series is left as it is.
    #[cfg_attr(feature = "clap", arg(long, value_name = "MM|whole", default_value_t = ProcessingSettings::default().svd_block_mm))]
    #[serde(deserialize_with = "text")]
    pub svd_block_mm: String,
    /// Spatial averaging of the autocorrelation, ROWSxCOLS pixels (odd), e.g. 3x3.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = ProcessingSettings::default().doppler_kernel))]
    #[serde(deserialize_with = "text")]
    pub doppler_kernel: String,
    /// Which frequency turns the Doppler phase into velocity: "loupas" (the mean RF frequency
    /// measured at every pixel: unbiased whatever the echo spectrum, depth or attenuation) or
    /// "kasai" (the nominal centre frequency, the paper's eq. 5: reads a few per cent low).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = ProcessingSettings::default().doppler_estimator))]
    pub doppler_estimator: DopplerEstimatorOption,
    /// IRLS regularisation λ (mm/s) of the weights 1/(|residual| + λ).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = ProcessingSettings::default().irls_lambda))]
    pub irls_lambda: f64,
    /// IRLS convergence threshold on the largest weight change.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = ProcessingSettings::default().irls_epsilon))]
    pub irls_epsilon: f64,
    /// IRLS iteration cap.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = ProcessingSettings::default().irls_max_iterations))]
    pub irls_max_iterations: usize,
    /// How coded (Hadamard) events are decoded: "mid-frame" (each event's slow-time series
    /// resampled to the frame's mid-event time first, so moving blood does not leak angles into
    /// each other) or "simultaneous" (the paper's decoding: the events of a frame taken as
    /// simultaneous). Conventional recordings are not affected.
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = ProcessingSettings::default().event_alignment))]
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
    #[cfg_attr(feature = "clap", arg(long, default_value_t = ProcessingSettings::default().dealias))]
    #[serde(deserialize_with = "text")]
    pub dealias: String,
    /// Partial-volume correction: "on" moves each angle's projection from its resolution cell's
    /// power centroid back to the pixel before the vector fit (the cell measured from that
    /// angle's speckle, the centroid from its power Doppler's gradient): the wall of a vessel and
    /// the speckle inside it no longer pull the velocity toward where the echoes are brighter.
    /// Applies to the vector maps and the ensembles' (the dynamics windows' with
    /// --dynamics-partial-volume on). Where
    /// flow exceeds the Nyquist velocity, use it with --dealias (it works on the unwrapped
    /// projections; across a wrap the gradient it needs is meaningless).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = ProcessingSettings::default().partial_volume))]
    pub partial_volume: Switch,
    /// Doppler time series: compound frames per ensemble; each ensemble gets its own clutter
    /// filter and its own power, colour and vector maps (ensemble_*.npy, ensembles.png). Default:
    /// none (the whole recording is one ensemble, as the other maps are).
    #[cfg_attr(feature = "clap", arg(long))]
    pub ensemble_frames: Option<usize>,
    /// Frames from one ensemble's start to the next's (default: --ensemble-frames, no overlap).
    #[cfg_attr(feature = "clap", arg(long, requires = "ensemble_frames"))]
    pub ensemble_step: Option<usize>,
    /// Long recordings and images: compound frames per segment, each imaged (or read),
    /// clutter-filtered and analysed on its own so that memory and the clutter filter's cost stay
    /// bounded (default: as many as fit in 1.25 GiB of image series, at most 512; the whole
    /// recording in one when it fits, which gives the exact whole-recording maps).
    #[cfg_attr(feature = "clap", arg(long))]
    pub segment_frames: Option<usize>,
    /// Points (mm) at which to show the flow over time: each one's compounded Doppler
    /// spectrogram over the dynamics windows (--window-ms, --window-step-ms), read at the grid
    /// pixel nearest to it (sites.png, site_*.npy). X,Z pairs separated by ";" (or every number
    /// by ","), e.g. --sites=-1.5,8;2,10.
    #[cfg_attr(
        feature = "clap",
        arg(
            long,
            visible_alias = "sites-mm",
            allow_hyphen_values = true,
            value_name = "X,Z[;X,Z...]"
        )
    )]
    #[serde(alias = "sites_mm", deserialize_with = "optional_text")]
    pub sites: Option<String>,
    /// Radius (mm) of each site's sample volume, as a scanner's pulsed-wave gate: the
    /// spectrogram sums the power spectra of the grid pixels within it of the site's pixel, each
    /// with its echo power, which averages out one pixel's window-to-window speckle jitter.
    /// Default 0: the pixel alone; at most 2.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = ProcessingSettings::default().site_radius_mm))]
    pub site_radius_mm: f64,
}

impl Default for ProcessingSettings {
    fn default() -> Self {
        ProcessingSettings {
            grid: None,
            f_number: DasParams::DEFAULT_F_NUMBER,
            svd_low: "auto".into(),
            svd_high: "off".into(),
            svd_block_mm: DEFAULT_SVD_BLOCK_MM.into(),
            doppler_kernel: kernel_text(pcuvd::pipeline::params::DEFAULT_DOPPLER_KERNEL),
            doppler_estimator: pcuvd::estimate::doppler::DopplerEstimator::default().into(),
            irls_lambda: IrlsParams::default().lambda_mm_s,
            irls_epsilon: IrlsParams::default().epsilon,
            irls_max_iterations: IrlsParams::default().max_iterations,
            event_alignment: pcuvd::form::decode::EventAlignment::default().into(),
            dealias: "off".into(),
            partial_volume: Switch::from(pcuvd::pipeline::params::DEFAULT_PARTIAL_VOLUME),
            ensemble_frames: None,
            ensemble_step: None,
            segment_frames: None,
            sites: None,
            site_radius_mm: 0.0,
        }
    }
}

impl ProcessingSettings {
    /// The IRLS vector fit's settings, checked.
    pub fn irls(&self) -> Result<IrlsParams> {
        let irls = IrlsParams {
            lambda_mm_s: self.irls_lambda,
            epsilon: self.irls_epsilon,
            max_iterations: self.irls_max_iterations,
        };
        irls.validate()
            .context("--irls-lambda / --irls-epsilon / --irls-max-iterations")?;
        Ok(irls)
    }

    /// The dealiasing of `--dealias`.
    pub fn dealias(&self) -> Result<pcuvd::estimate::dealias::Dealias> {
        pcuvd::estimate::dealias::Dealias::parse(&self.dealias).context("--dealias")
    }

    /// The ensembles of `--ensemble-frames` / `--ensemble-step`, checked against a recording of
    /// `frames` frames; `None` when no time series was asked for.
    pub fn ensembles(
        &self,
        frames: usize,
    ) -> Result<Option<pcuvd::pipeline::ensembles::EnsembleSpec>> {
        let Some(ensemble_frames) = self.ensemble_frames else {
            return Ok(None);
        };
        let spec = pcuvd::pipeline::ensembles::EnsembleSpec {
            frames: ensemble_frames,
            step: self.ensemble_step.unwrap_or(ensemble_frames),
        };
        spec.starts(frames)
            .context("--ensemble-frames / --ensemble-step")?;
        Ok(Some(spec))
    }

    /// The points of `--sites` on `grid`, each with its nearest pixel; empty when none were
    /// asked for. A point farther than half a pixel beyond the grid's edge is refused: it was not
    /// imaged.
    pub fn sites(&self, grid: &Grid) -> Result<Vec<Site>> {
        let radius = self.site_radius_mm;
        if !(radius.is_finite() && (0.0..=MAX_SITE_RADIUS_MM).contains(&radius)) {
            bail!(
                "--site-radius-mm {}: must be within [0, {MAX_SITE_RADIUS_MM}] mm (a wider gate \
                 mixes vessels)",
                shown("--site-radius-mm", radius)
            );
        }
        let Some(text) = &self.sites else {
            if radius > 0.0 {
                bail!("--site-radius-mm applies to the points of --sites: give them too");
            }
            return Ok(Vec::new());
        };
        let numbers = parse_numbers(&text.replace(';', ",")).with_context(|| {
            format!("--sites {text:?}: expected X,Z pairs in mm, e.g. --sites=-1.5,8;2,10")
        })?;
        if numbers.is_empty() || numbers.len() % 2 != 0 {
            bail!(
                "--sites {text:?}: expected X,Z pairs in mm (an even count of numbers), got {}",
                numbers.len()
            );
        }
        if numbers.len() / 2 > MAX_SITES {
            bail!(
                "--sites: {} points, at most {MAX_SITES} a run (a figure of more is unreadable): \
                 give the others in another run",
                numbers.len() / 2
            );
        }
        let span = |axis: &[f64]| (axis[0] * 1e3, axis[axis.len() - 1] * 1e3);
        numbers
            .chunks(2)
            .map(|pair| {
                let (x_m, z_m) = (pair[0] * 1e-3, pair[1] * 1e-3);
                match (nearest_on(&grid.x, x_m), nearest_on(&grid.z, z_m)) {
                    (Some(ix), Some(iz)) => Ok(Site {
                        x_m,
                        z_m,
                        pixel: (iz, ix),
                    }),
                    _ => {
                        let ((x0, x1), (z0, z1)) = (span(&grid.x), span(&grid.z));
                        bail!(
                            "--sites {text:?}: ({}, {}) mm lies outside the imaged grid (x from \
                             {x0:.2} to {x1:.2} mm, z from {z0:.2} to {z1:.2} mm)",
                            pair[0],
                            pair[1]
                        )
                    }
                }
            })
            .collect()
    }
}

/// The most points `--sites` takes in one run: eight rows of three spectrograms.
pub const MAX_SITES: usize = 24;

/// The widest sample volume `--site-radius-mm` takes (mm).
pub const MAX_SITE_RADIUS_MM: f64 = 2.0;

/// The pixels of `grid` within `radius_m` (m) of pixel `centre` (row, col), in row-major order;
/// the centre always among them.
pub fn gate_pixels(grid: &Grid, centre: (usize, usize), radius_m: f64) -> Vec<(usize, usize)> {
    let (cz, cx) = (grid.z[centre.0], grid.x[centre.1]);
    // A radius of whole steps takes the pixels on it, whatever the grid's rounding.
    let radius_m = radius_m * (1.0 + 1e-9);
    let rows = (0..grid.z.len()).filter(|&iz| (grid.z[iz] - cz).abs() <= radius_m);
    rows.flat_map(|iz| {
        (0..grid.x.len())
            .filter(move |&ix| (grid.z[iz] - cz).hypot(grid.x[ix] - cx) <= radius_m)
            .map(move |ix| (iz, ix))
    })
    .collect()
}

/// The index of the sample of `axis` (m, evenly spaced) nearest to `v` (m); `None` when `v` lies
/// more than half a step beyond either end.
fn nearest_on(axis: &[f64], v: f64) -> Option<usize> {
    let (first, last) = (*axis.first()?, *axis.last()?);
    let half_step = 0.5 * (last - first).abs() / (axis.len() - 1).max(1) as f64;
    if !(v >= first.min(last) - half_step && v <= first.max(last) + half_step) {
        return None;
    }
    (0..axis.len()).min_by(|&a, &b| (axis[a] - v).abs().total_cmp(&(axis[b] - v).abs()))
}

/// A point whose flow a run shows over time (`--sites`): where it was asked for and the grid
/// pixel nearest to it, whose spectrogram is read.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Site {
    /// Lateral position asked for (m).
    pub x_m: f64,
    /// Depth asked for (m).
    pub z_m: f64,
    /// The nearest pixel, (row, col).
    pub pixel: (usize, usize),
}

/// A setting that is a word or a number ("auto", "off", 3) or a list of numbers ("3x3", [3, 3]),
/// as the text the command line would hold: a list joins with ",", which every list-reading
/// setting accepts (a kernel reads "3,3" as "3x3"), and a list of points with ";" between them.
#[derive(Deserialize)]
#[serde(untagged)]
enum TextValue {
    Text(String),
    Whole(i64),
    Number(f64),
    List(Vec<TextValue>),
}

impl TextValue {
    fn into_text(self) -> String {
        match self {
            TextValue::Text(text) => text,
            TextValue::Whole(n) => n.to_string(),
            // As Python's repr writes a float: the shortest text that reads back the same.
            TextValue::Number(v) => format!("{v:?}"),
            TextValue::List(items) => {
                // A list of lists (points, [[x, z], ...]) joins its points with ";", as the
                // command line writes them.
                let nested = items.iter().any(|item| matches!(item, TextValue::List(_)));
                items
                    .into_iter()
                    .map(TextValue::into_text)
                    .collect::<Vec<_>>()
                    .join(if nested { ";" } else { "," })
            }
        }
    }
}

/// Deserialises a word, number or list setting as its text ([`TextValue`]).
pub(crate) fn text<'de, D: Deserializer<'de>>(
    deserializer: D,
) -> std::result::Result<String, D::Error> {
    TextValue::deserialize(deserializer).map(TextValue::into_text)
}

/// As [`text`], for a setting that may be absent (null).
pub(crate) fn optional_text<'de, D: Deserializer<'de>>(
    deserializer: D,
) -> std::result::Result<Option<String>, D::Error> {
    Option::<TextValue>::deserialize(deserializer).map(|v| v.map(TextValue::into_text))
}

/// Which frequency turns the Doppler phase into velocity ([`pcuvd::estimate::doppler::DopplerEstimator`]).
#[derive(Clone, Copy, PartialEq, Eq, Debug, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum DopplerEstimatorOption {
    /// The nominal centre frequency (Kasai; the paper's eq. 5).
    Kasai,
    /// The mean RF frequency measured at every pixel (2-D autocorrelation, Loupas).
    Loupas,
}

impl From<pcuvd::estimate::doppler::DopplerEstimator> for DopplerEstimatorOption {
    fn from(e: pcuvd::estimate::doppler::DopplerEstimator) -> Self {
        match e {
            pcuvd::estimate::doppler::DopplerEstimator::Kasai => Self::Kasai,
            pcuvd::estimate::doppler::DopplerEstimator::Loupas => Self::Loupas,
        }
    }
}

impl From<DopplerEstimatorOption> for pcuvd::estimate::doppler::DopplerEstimator {
    fn from(e: DopplerEstimatorOption) -> Self {
        match e {
            DopplerEstimatorOption::Kasai => Self::Kasai,
            DopplerEstimatorOption::Loupas => Self::Loupas,
        }
    }
}

/// The tube's flow profile ([`pcuvd::simulate::phantom::FlowProfile`]).
#[derive(Clone, Copy, PartialEq, Eq, Debug, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum TubeProfile {
    /// Laminar: peak·(1 − (l/R)²), zero at the wall.
    Parabolic,
    /// The peak speed across the whole lumen, a step at the wall.
    Plug,
}

impl From<pcuvd::simulate::phantom::FlowProfile> for TubeProfile {
    fn from(p: pcuvd::simulate::phantom::FlowProfile) -> Self {
        match p {
            pcuvd::simulate::phantom::FlowProfile::Parabolic => Self::Parabolic,
            pcuvd::simulate::phantom::FlowProfile::Plug => Self::Plug,
        }
    }
}

impl From<TubeProfile> for pcuvd::simulate::phantom::FlowProfile {
    fn from(p: TubeProfile) -> Self {
        match p {
            TubeProfile::Parabolic => Self::Parabolic,
            TubeProfile::Plug => Self::Plug,
        }
    }
}

/// How coded events are aligned in slow time before decoding ([`EventAlignment`]).
#[derive(Clone, Copy, PartialEq, Eq, Debug, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
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
        pcuvd::form::decode::EventAlignment::from(self).label()
    }
}

impl From<pcuvd::form::decode::EventAlignment> for Alignment {
    fn from(a: pcuvd::form::decode::EventAlignment) -> Self {
        match a {
            pcuvd::form::decode::EventAlignment::MidFrame => Self::MidFrame,
            pcuvd::form::decode::EventAlignment::Simultaneous => Self::Simultaneous,
        }
    }
}

impl From<Alignment> for pcuvd::form::decode::EventAlignment {
    fn from(a: Alignment) -> Self {
        match a {
            Alignment::MidFrame => Self::MidFrame,
            Alignment::Simultaneous => Self::Simultaneous,
        }
    }
}

/// The clutter filter's default block width (mm): on the virtual rat brain, 2 mm blocks read
/// the vectors, RI and the gain of coding closer to the truth than one filter of the whole
/// image (docs/results/brain.md), and where the whole image holds no tissue to cut they leave
/// the series as the whole image's filter does.
pub const DEFAULT_SVD_BLOCK_MM: &str = "2";

/// The clutter filter's block width (mm) from `--OPTION`'s text; `None` for "whole".
fn block_width_mm(text: &str, option: &str) -> Result<Option<f64>> {
    let text = text.trim();
    if text.eq_ignore_ascii_case("whole") {
        return Ok(None);
    }
    let mm: f64 = text.parse().map_err(|_| {
        anyhow::anyhow!("--{option} {text:?}: expected a block width in mm or \"whole\"")
    })?;
    if !(mm.is_finite() && mm > 0.0) {
        bail!("--{option} {text}: must be a positive width (mm) or \"whole\"");
    }
    Ok(Some(mm))
}

/// Checks a clutter block width's text as `--OPTION` would read it.
pub fn check_block_width(text: &str, option: &str) -> Result<()> {
    block_width_mm(text, option).map(|_| ())
}

fn rank_cut(text: &str, option: &str) -> Result<RankCut> {
    text.parse().map_err(|e| anyhow::anyhow!("--{option} {e}"))
}

/// Checks a clutter cut-off's text as `--OPTION` would read it.
pub fn check_rank_cut(text: &str, option: &str) -> Result<()> {
    rank_cut(text, option).map(|_| ())
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
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum Switch {
    /// Off.
    Off,
    /// On.
    On,
}

impl From<bool> for Switch {
    fn from(on: bool) -> Self {
        if on { Switch::On } else { Switch::Off }
    }
}

/// Whether `pcuvd process` runs the dynamics stage (cardiac cycle, PSV/EDV/RI maps).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum DynamicsChoice {
    /// When the recording holds a cardiac cycle (one angle: RI of the colour-Doppler speed);
    /// otherwise skipped with a note.
    Auto,
    /// Always: a recording that cannot give RI maps is an error (before the work where the options tell, else after the other outputs are written).
    On,
    /// Never.
    Off,
}

/// Options of the dynamics stage of `pcuvd process`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
#[serde(default, deny_unknown_fields)]
pub struct DynamicsSettings {
    /// Sliding-window vector velocity, PSV/EDV/RI and artery/vein maps: "auto" (when the recording
    /// holds a cardiac cycle), "on" (required) or "off".
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = DynamicsSettings::default().dynamics))]
    pub dynamics: DynamicsChoice,
    /// Heart rate (Hz); default: measured from the data — from its systolic upstrokes where two
    /// are recorded (about one cycle or more), else from its autocorrelation (about 1.5 cycles).
    #[cfg_attr(feature = "clap", arg(long, visible_alias = "heart-rate-hz"))]
    #[serde(alias = "heart_rate_hz")]
    pub heart_rate: Option<f64>,
    /// Cardiac cycle start times (s from the recording's first frame: ECG R-waves or scanner
    /// triggers), a 1-D .npy file or a text file of numbers: each cycle runs from one to the next.
    #[cfg_attr(feature = "clap", arg(long))]
    pub cardiac_triggers: Option<std::path::PathBuf>,
    /// Sliding-window length (ms); default 20 ms (36 frames at the rat's 1.8 kHz).
    #[cfg_attr(feature = "clap", arg(long))]
    pub window_ms: Option<f64>,
    /// Time between window starts (ms); default 5 ms.
    #[cfg_attr(feature = "clap", arg(long))]
    pub window_step_ms: Option<f64>,
    /// Smallest RI of an arteriole (paper: arterioles 0.55–0.9).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = DynamicsSettings::default().artery_ri_min))]
    pub artery_ri_min: f64,
    /// Largest RI of a venule (paper: below 0.5).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = DynamicsSettings::default().vein_ri_max))]
    pub vein_ri_max: f64,
    /// Vessel threshold for the RI maps (dB re. the brightest pixel's mean power).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = DynamicsSettings::default().vessel_threshold_db, allow_hyphen_values = true))]
    pub vessel_threshold_db: f64,
    /// Vessel pixels of the RI maps must also have a whole-recording power Doppler at least this
    /// many dB above the noise floor of their depth (the 30th percentile of the row); "off" leaves
    /// only --vessel-threshold-db.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = DynamicsSettings::default().vessel_margin_db, allow_hyphen_values = true))]
    #[serde(deserialize_with = "text")]
    pub vessel_margin_db: String,
    /// Vessel pixels of the RI maps must also have a whole-recording power Doppler within this
    /// many dB of the brightest pixel within --vessel-local-radius-mm: drops the side-lobe haze
    /// that bright vessels cast over their surroundings in clean recordings; "off" drops the test.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = DynamicsSettings::default().vessel_local_db, allow_hyphen_values = true))]
    #[serde(deserialize_with = "text")]
    pub vessel_local_db: String,
    /// Half-width (mm) of the square searched for the local peak of --vessel-local-db.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = DynamicsSettings::default().vessel_local_radius_mm))]
    pub vessel_local_radius_mm: f64,
    /// Spatial averaging of each window's autocorrelation for the RI maps, ROWSxCOLS pixels (odd):
    /// a 20 ms window sees only a few speckle renewals, so per-pixel speeds jitter and the extremes
    /// (PSV, EDV) of a jittery waveform inflate RI; 5x5 is 0.25 mm on a 0.05 mm grid.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = DynamicsSettings::default().dynamics_kernel))]
    #[serde(deserialize_with = "text")]
    pub dynamics_kernel: String,
    /// The partial-volume correction (--partial-volume) in every dynamics window too: each
    /// angle's cell measured once on the whole recording, each window corrected with its own
    /// power Doppler. Off by default: on the rat-network preset it made the RI maps worse
    /// (median |ΔRI| 0.0145 → 0.0179, classes right 99.9 → 98.7 %), though it helped the vessel
    /// network study's (0.015 → 0.012); a 20 ms window's power is too speckled to place each
    /// cell's centroid reliably.
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = DynamicsSettings::default().dynamics_partial_volume))]
    pub dynamics_partial_volume: Switch,
    /// Debias each pixel's fitted cardiac waveform for the windows' estimation noise before its
    /// PSV and EDV are read (each harmonic's power less the noise's share): a steady, slow vein's
    /// window-to-window jitter otherwise reads as a pulse and its RI as an arteriole's.
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = DynamicsSettings::default().ri_debias))]
    pub ri_debias: Switch,
    /// Vessel pooling for the RI maps, half-length (mm) along the flow: each pixel's waveform
    /// shape is averaged over same-direction neighbours in an ellipse aligned with its flow (RI
    /// does not change with the lumen's velocity profile nor along a vessel, only the jitter
    /// does); 0 with --pool-across-mm 0 turns it off. Off for a recording of one angle, which
    /// gives no flow direction in the plane.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = DynamicsSettings::default().pool_along_mm))]
    pub pool_along_mm: f64,
    /// Vessel pooling half-width (mm) across the flow: parallel vessels farther apart than this
    /// are never pooled together.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = DynamicsSettings::default().pool_across_mm))]
    pub pool_across_mm: f64,
    /// Largest angle (degrees) between the mean flow directions of pooled pixels: keeps an
    /// arteriole and a venule side by side, flowing opposite ways, apart.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = DynamicsSettings::default().pool_max_angle_deg))]
    pub pool_max_angle_deg: f64,
}

impl Default for DynamicsSettings {
    fn default() -> Self {
        let rat = DynamicsParams::rat();
        DynamicsSettings {
            dynamics: DynamicsChoice::Auto,
            heart_rate: None,
            cardiac_triggers: None,
            window_ms: None,
            window_step_ms: None,
            artery_ri_min: rat.artery_ri_min,
            vein_ri_max: rat.vein_ri_max,
            vessel_threshold_db: rat.min_power_db,
            vessel_margin_db: dynamics::VESSEL_MARGIN_DB.to_string(),
            vessel_local_db: dynamics::VESSEL_LOCAL_DB.to_string(),
            vessel_local_radius_mm: dynamics::VESSEL_LOCAL_RADIUS_M * 1e3,
            dynamics_kernel: kernel_text(dynamics::RI_KERNEL),
            dynamics_partial_volume: Switch::Off,
            ri_debias: Switch::from(rat.debias_harmonics),
            pool_along_mm: VesselPooling::DEFAULT_ALONG_M * 1e3,
            pool_across_mm: VesselPooling::DEFAULT_ACROSS_M * 1e3,
            pool_max_angle_deg: VesselPooling::DEFAULT_MAX_ANGLE_DEG,
        }
    }
}

impl DynamicsSettings {
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

    /// The sliding windows of `--window-ms` and `--window-step-ms` in frames at compound frame
    /// rate `frame_rate` (Hz): (window ≥ 2, step ≥ 1).
    pub fn window_frames(&self, frame_rate: f64) -> Result<(usize, usize)> {
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
        Ok((window, step))
    }

    /// Dynamics settings at compound frame rate `frame_rate` (Hz): windows converted from ms to
    /// frames, the PC-UVD estimator (IRLS-WLS) with `irls` and `dealias`, the averaging kernel of
    /// `--dynamics-kernel`, vessel pooling converted from mm to pixels of `grid_step_m` (m).
    pub fn params(
        &self,
        frame_rate: f64,
        irls: IrlsParams,
        dealias: pcuvd::estimate::dealias::Dealias,
        grid_step_m: f64,
    ) -> Result<DynamicsParams> {
        let kernel = parse_kernel(&self.dynamics_kernel)
            .map_err(|e| anyhow::anyhow!("{e}").context("--dynamics-kernel"))?;
        let (window, step) = self.window_frames(frame_rate)?;
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
            debias_harmonics: self.ri_debias == Switch::On,
            ..DynamicsParams::rat()
        };
        params
            .validate_thresholds()
            .context("--artery-ri-min / --vein-ri-max / --vessel-threshold-db")?;
        Ok(params)
    }
}

impl ProcessingSettings {
    /// The clutter filter's blocks (rows, columns of pixels) on `grid`, from `--svd-block-mm`.
    fn svd_blocks(&self, grid: &Grid) -> Result<Option<(usize, usize)>> {
        let Some(mm) = block_width_mm(&self.svd_block_mm, "svd-block-mm")? else {
            return Ok(None);
        };
        let pixels = |step: f64| ((mm * 1e-3 / step).round() as usize).max(1);
        let (nz, nx) = grid.shape();
        let rows = if nz > 1 { pixels(grid.axial_step()) } else { 1 };
        let cols = if nx > 1 { pixels(grid.step()) } else { 1 };
        Ok(Some((rows.min(nz), cols.min(nx))))
    }

    /// Stage settings for `data`.
    pub fn params(
        &self,
        data: &dyn pcuvd::acquisition::source::FrameSource,
    ) -> Result<ProcessParams> {
        let grid = match &self.grid {
            Some(text) => {
                let grid = parse_grid(text)?;
                pipeline::check_grid_depth(data.acquisition(), data.trace_shape().1, &grid)
                    .with_context(|| format!("--grid {text:?}"))?;
                grid
            }
            None => pipeline::default_grid_for(data.acquisition(), data.trace_shape().1)?,
        };
        let params = self.params_on(grid, data.acquisition().sound_speed)?;
        // Refused now, not after imaging: an estimator the grid cannot serve.
        pipeline::check_doppler_estimator(data.acquisition(), &params)
            .with_context(|| self.estimator_context(&params))?;
        Ok(params)
    }

    /// Stage settings for beamformed `images` formed elsewhere, on their own grid: the
    /// imaging options (`--grid`, `--f-number`, `--event-alignment`) are refused, since the
    /// images are already formed.
    pub fn images_params(&self, images: &AngleImages) -> Result<ProcessParams> {
        let defaults = ProcessingSettings::default();
        for (given, option) in [
            (
                self.grid.is_some(),
                "--grid (the images' pixels are the manifest's x_m and z_m)",
            ),
            (self.f_number != defaults.f_number, "--f-number"),
            (
                self.event_alignment != defaults.event_alignment,
                "--event-alignment",
            ),
        ] {
            if given {
                bail!("{option}: the images are already formed; the option sets their forming");
            }
        }
        let params = self.params_on(images.grid.clone(), images.sound_speed)?;
        pipeline::check_doppler_estimator_on(images, &params)
            .with_context(|| self.estimator_context(&params))?;
        Ok(params)
    }

    /// The stage settings on `grid` (m) at `sound_speed` (m/s), checked against it.
    fn params_on(&self, grid: Grid, sound_speed: f64) -> Result<ProcessParams> {
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
        let irls = self.irls()?;
        let blocks = self.svd_blocks(&grid)?;
        Ok(ProcessParams {
            grid,
            das: DasParams {
                f_number: self.f_number,
                apodization: Apodization::Hann,
                sound_speed,
            },
            clutter: ClutterParams {
                low: rank_cut(&self.svd_low, "svd-low")?,
                high: rank_cut(&self.svd_high, "svd-high")?,
                blocks,
                ..ClutterParams::default()
            },
            doppler_kernel: (rows, cols),
            doppler_estimator: self.doppler_estimator.into(),
            irls,
            iq_cutoff: None,
            event_alignment: self.event_alignment.into(),
            dealias: self.dealias()?,
            partial_volume: self.partial_volume == Switch::On,
        })
    }

    /// What an estimator refusal is about: the option and the axial step it was refused on.
    fn estimator_context(&self, params: &ProcessParams) -> String {
        format!(
            "--doppler-estimator {} on a {:.1} µm axial grid step",
            params.doppler_estimator.label(),
            params.grid.axial_step() * 1e6
        )
    }
}

/// Checks every settings type passes, for the settings modules' tests.
#[cfg(test)]
pub(crate) mod testing {
    use std::fmt::Debug;

    use serde::Serialize;
    use serde::de::DeserializeOwned;

    /// The command line's defaults of `T` are its `Default`, read back through the text clap
    /// shows in `--help` (so no default loses digits on the way).
    #[cfg(feature = "clap")]
    pub fn command_line_defaults_are_default<T: clap::Args + Default + PartialEq + Debug>() {
        let command = T::augment_args(clap::Command::new("pcuvd"));
        let matches = command.try_get_matches_from(["pcuvd"]).unwrap();
        let parsed = <T as clap::FromArgMatches>::from_arg_matches(&matches).unwrap();
        assert_eq!(parsed, T::default());
    }

    /// `settings` read back from JSON as they were written, and an unknown key is refused by
    /// name.
    pub fn reads_back_and_refuses_unknown_keys<T>(settings: &T)
    where
        T: Serialize + DeserializeOwned + PartialEq + Debug,
    {
        let text = serde_json::to_string(settings).unwrap();
        assert_eq!(&serde_json::from_str::<T>(&text).unwrap(), settings);
        let error = serde_json::from_str::<T>(r#"{"no_such_setting": 1}"#)
            .unwrap_err()
            .to_string();
        assert!(error.contains("no_such_setting"), "{error}");
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

    #[test]
    fn unknown_keys_are_refused_by_name() {
        let error = serde_json::from_str::<ProcessingSettings>(r#"{"svd_lo": "auto"}"#)
            .unwrap_err()
            .to_string();
        assert!(error.contains("svd_lo"), "{error}");
        let error = serde_json::from_str::<DynamicsSettings>(r#"{"window_ms": "long"}"#)
            .unwrap_err()
            .to_string();
        assert!(error.contains("long"), "{error}");
    }

    #[test]
    fn sites_are_points_in_mm_read_at_their_nearest_pixel() {
        // x from −2 to 2 mm, z from 6 to 10 mm, 0.1 mm steps.
        let grid = parse_grid("-2,2,6,10,0.1").unwrap();
        let from_python: ProcessingSettings =
            serde_json::from_str(r#"{"sites_mm": [[0, 8], [-1.96, 6.04]]}"#).unwrap();
        assert_eq!(from_python.sites.as_deref(), Some("0,8;-1.96,6.04"));
        let sites = from_python.sites(&grid).unwrap();
        assert_eq!(sites.len(), 2);
        assert_eq!(sites[0].pixel, (20, 20));
        assert_eq!(sites[1].pixel, (0, 0));
        assert!((sites[1].x_m + 1.96e-3).abs() < 1e-12 && (sites[1].z_m - 6.04e-3).abs() < 1e-12);
        // Every number by "," reads the same; half a step beyond the edge is still the edge.
        let flat = ProcessingSettings {
            sites: Some("0,8,2.04,10.04".into()),
            ..ProcessingSettings::default()
        };
        let pixels: Vec<_> = flat.sites(&grid).unwrap().iter().map(|s| s.pixel).collect();
        assert_eq!(pixels, [(20, 20), (40, 40)]);
        assert!(
            ProcessingSettings::default()
                .sites(&grid)
                .unwrap()
                .is_empty()
        );
        let many = ["0,8"; 25].join(";");
        for (text, expected) in [
            ("0,8;2.1,8", "(2.1, 8) mm lies outside the imaged grid"),
            ("0,5.9", "(0, 5.9) mm lies outside the imaged grid"),
            ("0,8;1", "an even count of numbers"),
            ("", "expected X,Z pairs"),
            ("0,eight", "expected X,Z pairs"),
            ("0,NaN", "expected X,Z pairs"),
            (many.as_str(), "25 points, at most 24 a run"),
        ] {
            let settings = ProcessingSettings {
                sites: Some(text.into()),
                ..ProcessingSettings::default()
            };
            let error = format!("{:#}", settings.sites(&grid).unwrap_err());
            assert!(
                error.contains("--sites") && error.contains(expected),
                "{text}: {error}"
            );
        }
    }

    #[test]
    fn a_sample_volume_is_the_pixels_within_its_radius() {
        let grid = parse_grid("-2,2,6,10,0.1").unwrap();
        // A cross of five at one step (the diagonals lie √2 steps away); three at a corner.
        assert_eq!(
            gate_pixels(&grid, (20, 20), 0.1e-3),
            [(19, 20), (20, 19), (20, 20), (20, 21), (21, 20)]
        );
        assert_eq!(gate_pixels(&grid, (0, 0), 0.1e-3), [(0, 0), (0, 1), (1, 0)]);
        assert_eq!(gate_pixels(&grid, (20, 20), 0.0), [(20, 20)]);
        for (radius, sites, expected) in [
            (
                3.0,
                Some("0,8"),
                "--site-radius-mm 3.0: must be within [0, 2] mm",
            ),
            (-0.1, Some("0,8"), "must be within [0, 2] mm"),
            (f64::NAN, Some("0,8"), "must be within [0, 2] mm"),
            (
                0.1,
                None,
                "--site-radius-mm applies to the points of --sites",
            ),
        ] {
            let settings = ProcessingSettings {
                sites: sites.map(str::to_string),
                site_radius_mm: radius,
                ..ProcessingSettings::default()
            };
            let error = format!("{:#}", settings.sites(&grid).unwrap_err());
            assert!(error.contains(expected), "{radius}: {error}");
        }
    }

    #[test]
    fn words_numbers_and_lists_read_as_the_command_line_would_hold_them() {
        let settings: ProcessingSettings = serde_json::from_str(
            r#"{"svd_low": 4, "doppler_kernel": [3, 1], "grid_mm": [-5, 5, 200, 210, 0.1],
                "dealias": "auto", "f_number": 2}"#,
        )
        .unwrap();
        assert_eq!(settings.svd_low, "4");
        assert_eq!(parse_kernel(&settings.doppler_kernel).unwrap(), (3, 1));
        assert_eq!(settings.grid.as_deref(), Some("-5,5,200,210,0.1"));
        assert_eq!(settings.dealias, "auto");
        assert_eq!(settings.f_number, 2.0);
        // What is not given keeps its default.
        assert_eq!(settings.svd_high, ProcessingSettings::default().svd_high);
        let dynamics: DynamicsSettings =
            serde_json::from_str(r#"{"heart_rate_hz": 5.5, "vessel_margin_db": "off"}"#).unwrap();
        assert_eq!(dynamics.heart_rate, Some(5.5));
        assert_eq!(parse_db_or_off(&dynamics.vessel_margin_db).unwrap(), None);
    }

    #[test]
    fn clutter_blocks_are_two_millimetres_unless_the_whole_image_is_asked_for() {
        // 0.1 mm pixels.
        let grid = Grid::new(-5e-3, 5e-3, 1e-3, 9e-3, 1e-4).unwrap();
        let default = ProcessingSettings::default();
        assert_eq!(default.svd_blocks(&grid).unwrap(), Some((20, 20)));
        let whole = ProcessingSettings {
            svd_block_mm: "whole".into(),
            ..default.clone()
        };
        assert_eq!(whole.svd_blocks(&grid).unwrap(), None);
        // Python and settings files give a number.
        let read: ProcessingSettings = serde_json::from_str(r#"{"svd_block_mm": 1.5}"#).unwrap();
        assert_eq!(read.svd_blocks(&grid).unwrap(), Some((15, 15)));
        for bad in ["0", "-2", "inf", "blocks", ""] {
            let settings = ProcessingSettings {
                svd_block_mm: bad.into(),
                ..default.clone()
            };
            let error = format!("{:#}", settings.svd_blocks(&grid).unwrap_err());
            assert!(
                error.contains("--svd-block-mm") && error.contains("whole"),
                "{error}"
            );
        }
    }

    #[test]
    fn settings_read_back_as_they_were_written() {
        let settings = ProcessingSettings {
            grid: Some("-6,6,2,14,0.05".into()),
            partial_volume: Switch::On,
            event_alignment: Alignment::Simultaneous,
            ..ProcessingSettings::default()
        };
        testing::reads_back_and_refuses_unknown_keys(&settings);
        testing::reads_back_and_refuses_unknown_keys(&DynamicsSettings::default());
    }

    #[cfg(feature = "clap")]
    #[test]
    fn the_command_line_defaults_are_the_settings_defaults() {
        testing::command_line_defaults_are_default::<ProcessingSettings>();
        testing::command_line_defaults_are_default::<DynamicsSettings>();
    }
}
