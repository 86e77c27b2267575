//! The run's settings, its stages and timings, and what it returns.

use ndarray::{Array2, Array3};

use crate::core::grid::Grid;
use crate::estimate::clutter::{ClutterParams, ClutterReport};
use crate::estimate::dealias::{self, AliasCounts, Dealias};
use crate::estimate::doppler::{self};
use crate::estimate::partial_volume;
use crate::estimate::vector::{IrlsParams, VectorField};
use crate::form::beamform::DasParams;
use crate::form::decode;
use crate::form::images::AngleImages;
/// Default spatial averaging of the autocorrelation (rows × columns of pixels): 5 rows, 2.5
/// wavelengths in depth at the default half-wavelength step, about one pulse length, so the
/// average spans the speckle of one resolution cell axially and keeps the lateral resolution
/// the vector fit needs at a vessel's wall. Chosen with [`DEFAULT_PARTIAL_VOLUME`] and
/// [`DasParams::DEFAULT_F_NUMBER`] on held-out seeds of every study (docs/results/accuracy.md).
pub const DEFAULT_DOPPLER_KERNEL: (usize, usize) = (5, 1);

/// Whether the partial-volume correction ([`crate::estimate::partial_volume`]) is on by
/// default: it is, since the wall of a vessel and the speckle inside it otherwise pull each
/// angle's projection toward where the echoes are brighter (the spiral's PC-UVD Vx falls from
/// 3.8 to 2.3 mm/s with it and the 5x1 kernel).
pub const DEFAULT_PARTIAL_VOLUME: bool = true;

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
    /// Vector dealiasing of both estimators ([`crate::estimate::dealias`]); off by default.
    pub dealias: Dealias,
    /// Move each projection from its resolution cell's power centroid back to its pixel before
    /// the vector fit ([`crate::estimate::partial_volume`]); default [`DEFAULT_PARTIAL_VOLUME`].
    pub partial_volume: bool,
}

impl ProcessParams {
    /// Whether a recording of `angles` steering angles has its resolution cells measured for the
    /// partial-volume correction: with the correction on and two angles or more (one angle gives
    /// no vector fit for the correction to correct).
    pub fn measures_cells(&self, angles: usize) -> bool {
        self.partial_volume && angles >= 2
    }
}

/// Pipeline stages, in order, as reported to a progress callback.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Stage {
    /// Reading images formed elsewhere from their file, a segment at a time.
    Read,
    /// Hadamard decoding / angle separation.
    Decode,
    /// IQ demodulation and delay-and-sum, one step per angle.
    Beamform,
    /// SVD clutter filtering, one step per angle.
    Clutter,
    /// Autocorrelation Doppler and vector solve.
    Doppler,
    /// The Doppler time series: every ensemble's clutter filter, Doppler and vectors
    /// ([`crate::pipeline::ensembles`]).
    Ensembles,
}

impl Stage {
    /// Name shown to people.
    pub fn label(self) -> &'static str {
        match self {
            Stage::Read => "read images",
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
    /// The Doppler and vector maps.
    pub maps: DopplerMaps,
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
    /// Signed power Doppler (|IQ|² units, the sign of the colour Doppler: positive = away from
    /// the probe); see [`doppler::signed_power`].
    pub fn signed_power_doppler(&self) -> Array2<f64> {
        doppler::signed_power(&self.maps.power_doppler, &self.maps.color_doppler)
    }

    /// The mean RF frequency (Hz) the Doppler maps turned phase into velocity with at `pixel`
    /// (row, col): each angle's from its Nyquist velocity there (v_N = c·f_frame / (4 f̄)),
    /// averaged over the angles whose plane wave reaches the pixel. Loupas measures it at each
    /// pixel; Kasai's is the demodulation frequency everywhere. `None` where no angle reaches it.
    pub fn mean_frequency_at(&self, (iz, ix): (usize, usize)) -> Option<f64> {
        let images = &self.filtered;
        let nyquist = self.maps.projection_nyquist.slice(ndarray::s![.., iz, ix]);
        let frequencies: Vec<f64> = nyquist
            .iter()
            .filter(|v| v.is_finite() && **v > 0.0)
            .map(|v| images.sound_speed * images.frame_rate / (4.0 * v))
            .collect();
        (!frequencies.is_empty())
            .then(|| frequencies.iter().sum::<f64>() / frequencies.len() as f64)
    }

    /// Gathers the Doppler maps ([`doppler_maps`]) with the rest of what the chain measured: the
    /// one place both the whole-recording path and the segmented one ([`crate::pipeline::segments`]) build
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
            maps,
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
    (coded && out.maps.dealias.is_some()).then(|| coded_dealias_message(out.maps.nyquist_velocity))
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

/// The Doppler and vector maps of a recording ([`ProcessOutput::maps`]), on the grid (nz, nx),
/// SI units.
#[derive(Debug, Clone)]
pub struct DopplerMaps {
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
    /// correction's; [`crate::estimate::partial_volume`]); `None` where not measurable or not measured
    /// (the correction off).
    pub cells: Vec<Option<partial_volume::CellCovariance>>,
}
