//! The in-vivo-like study (paper §4, Fig. 6–8): a pulsatile vessel network in the rat setting,
//! imaged conventionally (UVD) and with Hadamard coding (PC-UVD) over one cardiac cycle, with
//! ground truth for PSV, EDV, RI and artery/vein class that the paper's rat did not have.
//!
//! Per mode: echoes and noise are simulated and beamformed apart (for SNR by depth) and added;
//! the whole recording gives the power, colour and vector Doppler maps; sliding windows give the
//! vector velocity over time, whose per-pixel PSV, EDV and RI are scored against the truth;
//! compounded Doppler spectrograms are computed at four pixels (Fig. 8b).

use std::time::Instant;

use ndarray::Array2;
use serde::Serialize;

use super::spiral::{SnrByDepth, alignment_label};
use super::{
    Acquire, FormedSum, Mode, Motion, Progress, Timings, process_params, simulate_and_form_sum,
};
use crate::core::error::{Result, invalid};
use crate::core::grid::Grid;
use crate::dynamics::{
    self, DynamicsParams, PoolingSummary, RiMaps, Spectrogram, SpectrogramParams, VelocitySeries,
    VesselPooling, VesselTests,
};
use crate::estimate::doppler::DopplerEstimator;
use crate::estimate::vector::{Estimator, IrlsParams, VectorField};
use crate::evaluate::metrics::{self, DepthSnr, RI_SCORE_DEFINITION, RiScore, RiScores};
use crate::form::beamform::DasParams;
use crate::form::decode::EventAlignment;
use crate::pipeline::{self, ProcessOutput, ProcessParams};
use crate::simulate;
use crate::simulate::phantom::Phantom;
use crate::simulate::phantom::network::{NetworkPhantom, NetworkSpec, NetworkTruth, VesselKind};

/// Field of view of the network study (m): the probe's aperture, 1–13 mm deep.
pub const FIELD_M: (f64, f64, f64, f64) = (-6.4e-3, 6.4e-3, 1.0e-3, 13.0e-3);

/// Spatial averaging of the dynamics stage (pixels): as `pcuvd process --dynamics-kernel`.
pub const DYNAMICS_KERNEL: (usize, usize) = dynamics::RI_KERNEL;

/// Settings of the vessel-network study; `Default` is the paper's rat set-up.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NetworkSettings {
    /// Compound frames of each recording (the paper's rat: 360 = 0.2 s at 1.8 kHz).
    pub frames: usize,
    /// Seed of the scatterers and of the noise.
    pub seed: u64,
    /// Noise level (dB, [`crate::simulate::NOISE_DEFINITION`]); at +5 dB the conventional SNR
    /// falls from ≈ 18 dB at 2 mm to ≈ 3 dB at 12 mm, so coding matters.
    pub noise_db: f64,
    /// Heart rate of the network (Hz); the RI analysis is given the same rate, since 0.2 s holds
    /// too few beats to measure it.
    pub heart_rate_hz: f64,
    /// When scatterers move.
    pub motion: Motion,
    /// How coded events are decoded.
    #[serde(serialize_with = "alignment_label")]
    pub event_alignment: EventAlignment,
    /// Pixel size of the imaging grid (m).
    pub grid_step_m: f64,
    /// Which frequency scales the Doppler phase (whole-recording maps and windows alike).
    pub doppler_estimator: DopplerEstimator,
    /// Spatial averaging of the autocorrelation of the whole-recording maps (rows × columns of
    /// pixels, odd; `pcuvd process --doppler-kernel`). The dynamics windows keep their own
    /// [`DYNAMICS_KERNEL`].
    pub doppler_kernel: (usize, usize),
    /// The partial-volume correction ([`crate::estimate::partial_volume`]) of the whole-recording
    /// maps (`pcuvd process --partial-volume`).
    pub partial_volume: bool,
    /// The same correction in every dynamics window, whose RI is scored (`pcuvd process
    /// --dynamics-partial-volume`).
    pub dynamics_partial_volume: bool,
    /// Receive f-number of the beamformer (depth / aperture width; `pcuvd process --f-number`):
    /// the lateral size of each angle's resolution cell, over which a velocity gradient is
    /// averaged.
    pub f_number: f64,
}

impl Default for NetworkSettings {
    fn default() -> Self {
        NetworkSettings {
            frames: simulate::RAT_FRAMES,
            seed: 1,
            noise_db: 5.0,
            heart_rate_hz: 5.5,
            motion: Motion::PerEvent,
            event_alignment: EventAlignment::MidFrame,
            grid_step_m: 0.05e-3,
            doppler_estimator: DopplerEstimator::default(),
            doppler_kernel: crate::pipeline::params::DEFAULT_DOPPLER_KERNEL,
            partial_volume: crate::pipeline::params::DEFAULT_PARTIAL_VOLUME,
            dynamics_partial_volume: false,
            f_number: DasParams::DEFAULT_F_NUMBER,
        }
    }
}

/// Compound frame rate of the rat acquisition (Hz).
pub fn frame_rate() -> Result<f64> {
    let params = simulate::rat_params(false)?;
    Ok(params.sequence.event_prf / params.sequence.n_angles() as f64)
}

impl NetworkSettings {
    /// The imaging grid: [`FIELD_M`] at `grid_step_m`.
    pub fn grid(&self) -> Result<Grid> {
        Grid::new(FIELD_M.0, FIELD_M.1, FIELD_M.2, FIELD_M.3, self.grid_step_m)
    }

    /// Dynamics settings of `mode`: the rat preset with the study's heart rate, the mode's
    /// estimator (LS for UVD, IRLS-WLS for PC-UVD), [`DYNAMICS_KERNEL`] and the default vessel
    /// pooling of `pcuvd process`.
    pub fn dynamics_params(&self, mode: Mode) -> Result<DynamicsParams> {
        let pooling = VesselPooling::from_metres(
            VesselPooling::DEFAULT_ALONG_M,
            VesselPooling::DEFAULT_ACROSS_M,
            VesselPooling::DEFAULT_MAX_ANGLE_DEG,
            self.grid_step_m,
        )?;
        Ok(DynamicsParams {
            kernel: DYNAMICS_KERNEL,
            heart_rate_hz: Some(self.heart_rate_hz),
            estimator: match mode {
                Mode::Conventional => Estimator::LeastSquares,
                Mode::Coded => Estimator::Irls(IrlsParams::default()),
            },
            pooling,
            doppler: self.doppler_estimator,
            partial_volume: self.dynamics_partial_volume,
            ..DynamicsParams::rat()
        })
    }

    /// Refuses settings that cannot work, before anything is simulated.
    pub fn validate(&self) -> Result<()> {
        if !self.noise_db.is_finite() {
            return Err(invalid("noise level", "must be a finite number of dB"));
        }
        crate::core::error::require_positive("f-number", self.f_number)?;
        super::check_doppler_kernel(self.doppler_kernel)?;
        if !(self.heart_rate_hz.is_finite() && self.heart_rate_hz > 0.0) {
            return Err(invalid(
                "heart rate",
                format!("{}: must be a positive number of Hz", self.heart_rate_hz),
            ));
        }
        self.grid()?;
        let frame_rate = frame_rate()?;
        let params = self.dynamics_params(Mode::Coded)?;
        params.validate(frame_rate)?;
        // The dynamics stage needs one cycle of window samples: round(period / step) windows.
        let period_frames = frame_rate / self.heart_rate_hz;
        let cycle_windows = ((period_frames / params.step as f64).round() as usize).max(2);
        let needed = (cycle_windows - 1) * params.step + params.window;
        if self.frames < needed {
            return Err(invalid(
                "frames",
                format!(
                    "{}: a cardiac cycle at {} Hz lasts {:.0} frames at {:.0} Hz, and RI needs one \
                     whole cycle of {}-frame windows {} frames apart: at least {needed} frames",
                    self.frames,
                    self.heart_rate_hz,
                    period_frames,
                    frame_rate,
                    params.window,
                    params.step
                ),
            ));
        }
        Ok(())
    }
}

/// One transmit mode's results.
#[derive(Debug, Clone)]
pub struct ModeResult {
    /// Which mode.
    pub mode: Mode,
    /// The whole recording, processed; its filtered series (`out.filtered.series`) is dropped
    /// once the dynamics and spectrograms are computed, to bound the study's memory.
    pub out: ProcessOutput,
    /// Vector velocity in sliding windows.
    pub series: VelocitySeries,
    /// PSV, EDV, RI, classes.
    pub ri: RiMaps,
    /// Time-mean power of the compounded echo-only images.
    pub echo_power: Array2<f64>,
    /// Time-mean power of the compounded noise-only images.
    pub noise_power: Array2<f64>,
    /// Spectrograms at the study's [`Site`]s, in order.
    pub spectrograms: Vec<Spectrogram>,
}

impl ModeResult {
    /// The mode's vector field: LS for UVD (conventional), IRLS-WLS for PC-UVD (coded).
    pub fn field(&self) -> &VectorField {
        match self.mode {
            Mode::Conventional => self.out.maps.vector_ls.as_ref(),
            Mode::Coded => self.out.maps.vector_irls.as_ref(),
        }
        .expect("the rat sequence has 8 angles")
    }
}

/// A pixel where a spectrogram is computed, with what it shows.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Site {
    /// Vessel name, kind and direction, for figures.
    pub label: String,
    /// Index of the vessel in the network.
    pub vessel: usize,
    /// (row, col) of the pixel.
    pub pixel: (usize, usize),
}

/// Scores of one vessel, with its specification.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct VesselScores {
    /// Name (e.g. "A1").
    pub name: String,
    /// "arteriole" or "venule".
    pub kind: String,
    /// True when its flow goes toward the probe.
    pub flows_up: bool,
    /// Centre of its axis (x, z) (m).
    pub centre_m: [f64; 2],
    /// Flow direction (degrees from +x toward +z).
    pub angle_deg: f64,
    /// Length (m).
    pub length_m: f64,
    /// Radius (m).
    pub radius_m: f64,
    /// Centreline peak systolic speed (m/s).
    pub psv_m_s: f64,
    /// True RI.
    pub ri: f64,
    /// UVD's scores on it.
    pub uvd: RiScore,
    /// PC-UVD's scores on it.
    pub pcuvd: RiScore,
}

/// Network-wide RI scores of both methods.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RiSummary {
    /// UVD (conventional + LS).
    pub uvd: RiScores,
    /// PC-UVD (coded + IRLS-WLS).
    pub pcuvd: RiScores,
    /// How the scores count.
    pub definition: &'static str,
}

/// Settings of the dynamics stage, as reported.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DynamicsSummary {
    /// Frames per window.
    pub window_frames: usize,
    /// Frames between window starts.
    pub step_frames: usize,
    /// Smallest RI of an arteriole.
    pub artery_ri_min: f64,
    /// Largest RI of a venule.
    pub vein_ri_max: f64,
    /// Window-power vessel threshold (dB re. the brightest pixel).
    pub min_power_db: f64,
    /// Whole-recording noise-floor margin (dB).
    pub vessel_margin_db: f64,
    /// Local-peak level (dB).
    pub vessel_local_db: f64,
    /// Local-peak search half-width (m).
    pub vessel_local_radius_m: f64,
    /// Autocorrelation averaging (rows, cols).
    pub kernel: (usize, usize),
    /// Vessel pooling.
    pub vessel_pooling: PoolingSummary,
    /// Cardiac cycles used per mode, as [start, end) window indices.
    pub cycles_windows: Vec<Vec<(usize, usize)>>,
}

/// The network study's set-up and per-vessel scores, as `metrics.json` holds them.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NetworkInfo {
    /// Compound frames per recording.
    pub frames: usize,
    /// Compound frame rate (Hz).
    pub frame_rate_hz: f64,
    /// Noise level (dB).
    pub noise_db: f64,
    /// Heart rate (Hz).
    pub heart_rate_hz: f64,
    /// When scatterers moved.
    pub motion: Motion,
    /// How coded events were decoded.
    pub event_alignment: &'static str,
    /// Receive f-number of the beamformer.
    pub f_number: f64,
    /// Spatial averaging of the whole-recording maps' autocorrelation (rows × columns of pixels).
    pub doppler_kernel: (usize, usize),
    /// Whether the partial-volume correction ran on the whole-recording maps.
    pub partial_volume: bool,
    /// Whether it ran in the dynamics windows (the RI maps).
    pub dynamics_partial_volume: bool,
    /// Seed.
    pub seed: u64,
    /// Scatterers in the phantom.
    pub scatterers: usize,
    /// Pixels inside the true lumens.
    pub vessel_pixels: usize,
    /// Each vessel with both methods' scores.
    pub vessels: Vec<VesselScores>,
    /// SNR by depth of both modes.
    pub snr_db_by_depth: SnrByDepth,
    /// Settings of the dynamics stage.
    pub dynamics: DynamicsSummary,
    /// Wall-clock seconds per step.
    pub timing_s: Timings,
}

/// The network study's numbers, as `metrics.json` holds them (keys `ri` and `network`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NetworkMetrics {
    /// RI scores of both methods.
    pub ri: RiSummary,
    /// Set-up and per-vessel scores.
    pub network: NetworkInfo,
}

/// Everything the network study produced: its numbers and what its figures draw.
#[derive(Debug, Clone)]
pub struct NetworkStudy {
    /// The settings it ran with.
    pub settings: NetworkSettings,
    /// The numbers.
    pub metrics: NetworkMetrics,
    /// The phantom.
    pub phantom: NetworkPhantom,
    /// The imaging grid.
    pub grid: Grid,
    /// Ground truth over the cardiac cycle (PSV, EDV, RI, class, direction).
    pub truth: NetworkTruth,
    /// Conventional (UVD) then coded (PC-UVD).
    pub modes: [ModeResult; 2],
    /// Pixels of the spectrograms.
    pub sites: Vec<Site>,
    /// SNR by depth, conventional then coded.
    pub snr: [Vec<DepthSnr>; 2],
    /// RI scores, conventional then coded.
    pub scores: [RiScores; 2],
}

/// One pixel on the axis of the first vessel of each kind and direction (Fig. 8b's four panels).
pub fn spectrogram_sites(phantom: &NetworkPhantom, truth: &NetworkTruth, grid: &Grid) -> Vec<Site> {
    let mut sites = Vec::new();
    for (kind, up) in [
        (VesselKind::Arteriole, true),
        (VesselKind::Arteriole, false),
        (VesselKind::Venule, true),
        (VesselKind::Venule, false),
    ] {
        let found = phantom
            .spec()
            .vessels
            .iter()
            .enumerate()
            .find(|(_, v)| v.kind == kind && v.flows_up() == up);
        if let Some((i, v)) = found {
            let pixel = grid.nearest_pixel(v.centre[0], v.centre[1]);
            if truth.vessel_index[pixel] == i {
                sites.push(Site {
                    label: format!(
                        "{}: {}, flowing {}",
                        v.name,
                        match kind {
                            VesselKind::Arteriole => "arteriole",
                            VesselKind::Venule => "venule",
                        },
                        if up { "up" } else { "down" }
                    ),
                    vessel: i,
                    pixel,
                });
            }
        }
    }
    sites
}

/// Runs the network study: simulation, processing, dynamics and scores.
pub fn run(settings: &NetworkSettings, progress: Progress<'_>) -> Result<NetworkStudy> {
    settings.validate()?;
    let started = Instant::now();
    let mut timing = Timings::new();
    let spec = NetworkSpec {
        heart_rate_hz: settings.heart_rate_hz,
        ..NetworkSpec::rat()
    };
    let phantom = NetworkPhantom::new(spec, settings.seed)?;
    let grid = settings.grid()?;
    super::check_estimator(
        &simulate::rat_params(true)?,
        &grid,
        settings.doppler_estimator,
    )?;
    let truth = phantom.cycle_truth(&grid.x, &grid.z);
    let motion_truth = phantom.truth(&grid.x, &grid.z, 0.0);
    let sites = spectrogram_sites(&phantom, &truth, &grid);
    let vessel_tests = VesselTests::default();

    let mut results = Vec::new();
    for mode in Mode::BOTH {
        let mut params = simulate::rat_params(mode == Mode::Coded)?;
        params.seed = settings.seed;
        let label = format!("network_{}", mode.label());
        let formed = simulate_and_form_sum(
            Acquire {
                phantom: &phantom,
                params,
                frames: settings.frames,
                noise_db: settings.noise_db,
                motion: settings.motion,
                alignment: settings.event_alignment,
                label: &label,
                f_number: settings.f_number,
            },
            &grid,
            &mut timing,
            progress,
        )?;
        let clock = Instant::now();
        let FormedSum {
            acquisition,
            images,
            echo_power,
            noise_power,
        } = formed;
        let process = ProcessParams {
            doppler_estimator: settings.doppler_estimator,
            partial_volume: settings.partial_volume,
            ..process_params(
                &grid,
                &acquisition,
                settings.doppler_kernel,
                settings.event_alignment,
            )
        };
        let mut out = pipeline::analyse(images, &process, &|_, _, _| {})?;
        let dparams = settings.dynamics_params(mode)?;
        let (series, ri) = pipeline::dynamics(&out, &dparams, &vessel_tests, None)?;
        // Each at the frequency the maps read velocity with at its pixel, as the colour and
        // vector maps beside it.
        let demodulation = out.filtered.demodulation_frequency;
        let spectrograms = sites
            .iter()
            .map(|p| {
                let spec =
                    dynamics::spectrogram(&out.filtered, p.pixel, &SpectrogramParams::rat())?;
                let frequency = out.mean_frequency_at(p.pixel).unwrap_or(demodulation);
                Ok(spec.at_frequency(demodulation, frequency))
            })
            .collect::<Result<Vec<_>>>()?;
        // The filtered series (the largest thing a mode holds) has given all it will: drop it
        // so that the other mode is simulated and processed in its place.
        out.filtered.series = Vec::new();
        timing.insert(format!("{label}_analysis_s"), clock.elapsed().as_secs_f64());
        results.push(ModeResult {
            mode,
            out,
            series,
            ri,
            echo_power,
            noise_power,
            spectrograms,
        });
    }
    let modes: [ModeResult; 2] = results.try_into().expect("two modes");
    let scores = [
        metrics::score_ri(&modes[0].ri, &truth),
        metrics::score_ri(&modes[1].ri, &truth),
    ];
    let snr = [
        metrics::snr_by_depth(
            &modes[0].echo_power,
            &modes[0].noise_power,
            &motion_truth.mask,
            &grid,
        ),
        metrics::snr_by_depth(
            &modes[1].echo_power,
            &modes[1].noise_power,
            &motion_truth.mask,
            &grid,
        ),
    ];
    timing.insert("network_total_s".into(), started.elapsed().as_secs_f64());

    let rat = DynamicsParams::rat();
    let spec = phantom.spec();
    let (uvd, pc) = (&scores[0], &scores[1]);
    let metrics = NetworkMetrics {
        ri: RiSummary {
            uvd: uvd.clone(),
            pcuvd: pc.clone(),
            definition: RI_SCORE_DEFINITION,
        },
        network: NetworkInfo {
            frames: settings.frames,
            frame_rate_hz: frame_rate()?,
            noise_db: settings.noise_db,
            heart_rate_hz: settings.heart_rate_hz,
            motion: settings.motion,
            event_alignment: settings.event_alignment.label(),
            f_number: settings.f_number,
            doppler_kernel: settings.doppler_kernel,
            partial_volume: settings.partial_volume,
            dynamics_partial_volume: settings.dynamics_partial_volume,
            seed: settings.seed,
            scatterers: phantom.n_scatterers(),
            vessel_pixels: truth.mask().iter().filter(|&&m| m).count(),
            vessels: spec
                .vessels
                .iter()
                .enumerate()
                .map(|(i, v)| VesselScores {
                    name: v.name.clone(),
                    kind: format!("{:?}", v.kind).to_lowercase(),
                    flows_up: v.flows_up(),
                    centre_m: v.centre,
                    angle_deg: v.angle.to_degrees(),
                    length_m: v.length,
                    radius_m: v.radius,
                    psv_m_s: v.psv,
                    ri: v.ri,
                    uvd: uvd.per_vessel[i],
                    pcuvd: pc.per_vessel[i],
                })
                .collect(),
            snr_db_by_depth: SnrByDepth::new(&snr[0], &snr[1]),
            dynamics: DynamicsSummary {
                window_frames: rat.window,
                step_frames: rat.step,
                artery_ri_min: rat.artery_ri_min,
                vein_ri_max: rat.vein_ri_max,
                min_power_db: rat.min_power_db,
                vessel_margin_db: vessel_tests.margin_db,
                vessel_local_db: vessel_tests.local_db,
                vessel_local_radius_m: vessel_tests.local_radius_m,
                kernel: DYNAMICS_KERNEL,
                vessel_pooling: PoolingSummary::new(
                    settings.dynamics_params(Mode::Coded)?.pooling,
                    settings.grid_step_m,
                ),
                cycles_windows: modes.iter().map(|r| r.ri.cycles.clone()).collect(),
            },
            timing_s: timing,
        },
    };
    Ok(NetworkStudy {
        settings: settings.clone(),
        metrics,
        phantom,
        grid,
        truth,
        modes,
        sites,
        snr,
        scores,
    })
}
