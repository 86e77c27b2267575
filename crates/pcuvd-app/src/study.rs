//! The settings of the paper's studies as `pcuvd paper` (and `pcuvd.study`) take them, each
//! read into the library's typed study settings ([`SpiralSettings`], [`NetworkSettings`],
//! [`DealiasSettings`]) with the command's checks and messages.

use anyhow::{Context, Result};
use pcuvd::study::Motion as StudyMotion;
use pcuvd::study::dealias::DealiasSettings;
use pcuvd::study::network::NetworkSettings;
use pcuvd::study::spiral::SpiralSettings;
use serde::{Deserialize, Serialize};

use crate::brain::BrainSettings;
use crate::settings::{
    Alignment, DopplerEstimatorOption, DynamicsSettings, ProcessingSettings, Switch, TubeProfile,
    kernel_text,
};

/// The studies' settings as options; every default is the library's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
#[serde(default, deny_unknown_fields)]
pub struct StudySettings {
    /// Compound frames per acquisition (the paper: 100).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().frames))]
    pub frames: usize,
    /// Seed of the scatterers and of the noise.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().seed))]
    pub seed: u64,
    /// Noise level of the main study, dB (see the noise definition in the report); the paper: −10.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().noise_db, allow_hyphen_values = true))]
    pub noise_db: f64,
    /// Noise levels (dB) of the RMSE sweep, comma-separated.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().sweep, allow_hyphen_values = true))]
    #[serde(deserialize_with = "crate::settings::text")]
    pub sweep: String,
    /// Scatterer motion: "per-event" (physical: blood moves between the events of a frame) or
    /// "per-frame" (held still within each compound frame, as the paper's simulation assumed).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = StudySettings::default().motion))]
    pub motion: Motion,
    /// How coded events are decoded: "mid-frame" (each event's slow-time series resampled to the
    /// frame's mid-event time first, so moving blood does not leak angles into each other) or
    /// "simultaneous" (the paper's decoding, which takes the events of a frame as simultaneous).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = StudySettings::default().event_alignment))]
    pub event_alignment: Alignment,
    /// Spatial averaging of the autocorrelation, ROWSxCOLS pixels (odd).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().doppler_kernel))]
    #[serde(deserialize_with = "crate::settings::text")]
    pub doppler_kernel: String,
    /// Pixel size of the imaging grid (mm).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().grid_step))]
    pub grid_step: f64,
    /// Which frequency turns the Doppler phase into velocity: "loupas" (the mean RF frequency
    /// measured at every pixel) or "kasai" (the nominal centre frequency, the paper's eq. 5).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = StudySettings::default().doppler_estimator))]
    pub doppler_estimator: DopplerEstimatorOption,
    /// Every study with the partial-volume correction (`process --partial-volume`): each
    /// angle's projection moved from its resolution cell's power centroid to its pixel, in the
    /// vector maps.
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = StudySettings::default().partial_volume))]
    pub partial_volume: Switch,
    /// The partial-volume correction in the dynamics windows too (`process
    /// --dynamics-partial-volume`), whose RI maps the network and the brain score.
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = StudySettings::default().dynamics_partial_volume))]
    pub dynamics_partial_volume: Switch,
    /// Receive f-number of the beamformer in every study (as `process --f-number`): the
    /// lateral size of each angle's resolution cell, which averages the velocity gradient
    /// inside it.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().f_number, allow_hyphen_values = true))]
    pub f_number: f64,
    /// Conventional UVD's Vx RMSE (mm/s) at which to calibrate one more noise level of the spiral
    /// study (the paper's baseline: 5.70), or "off".
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().calibrate_uvd_vx))]
    #[serde(deserialize_with = "crate::settings::text")]
    pub calibrate_uvd_vx: String,
    /// Spatial averaging kernels of the autocorrelation to score beside the main one (each
    /// without noise and at its own calibrated level, with its resolution cost),
    /// comma-separated ROWSxCOLS pixels, or "off".
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().averaging_kernels))]
    #[serde(deserialize_with = "crate::settings::text")]
    pub averaging_kernels: String,
    /// Compound frames of each vessel-network recording (the paper's rat: 360 = 0.2 s at 1.8 kHz).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().network_frames))]
    pub network_frames: usize,
    /// Noise level of the vessel-network recordings, dB (same definition as --noise-db); at +5 dB
    /// the conventional SNR falls from ≈ 18 dB at 2 mm to ≈ 3 dB at 12 mm, so coding matters.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().network_noise_db, allow_hyphen_values = true))]
    pub network_noise_db: f64,
    /// Heart rate of the vessel network (Hz); the RI analysis is given the same rate, since 0.2 s
    /// holds too few beats to measure it.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().heart_rate))]
    pub heart_rate: f64,
    /// Dealiasing study: the tube's peak speeds as multiples of the projection Nyquist velocity,
    /// comma-separated.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().dealias_multiples))]
    #[serde(deserialize_with = "crate::settings::text")]
    pub dealias_multiples: String,
    /// Dealiasing study: noise levels (dB, comma-separated; "off" for none).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().dealias_noise_db, allow_hyphen_values = true))]
    #[serde(deserialize_with = "crate::settings::text")]
    pub dealias_noise_db: String,
    /// Dealiasing study: seeds, comma-separated (each speed and seed is one simulation per mode).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().dealias_seeds))]
    #[serde(deserialize_with = "crate::settings::text")]
    pub dealias_seeds: String,
    /// Dealiasing study: the dealiasing compared with none, "auto" or K (see `process --dealias`).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().dealias))]
    #[serde(deserialize_with = "crate::settings::text")]
    pub dealias: String,
    /// Dealiasing study: flow direction of the tube, degrees below +x.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().dealias_tube_angle_deg))]
    pub dealias_tube_angle_deg: f64,
    /// Dealiasing study: the tube's flow profile. Plug flow has no gradient inside the
    /// resolution cell, which shows the estimator's accuracy apart from it, and is fast up to the
    /// wall, where dealiasing must settle its level by the vessel's residual.
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = StudySettings::default().dealias_tube_profile))]
    pub dealias_tube_profile: TubeProfile,
    /// Brain study: the scenario simulated (a shipped scenario's name or a TOML file with a
    /// vascular tree and both transmit modes).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().brain_scenario))]
    pub brain_scenario: String,
    /// Brain study: compound frames, overriding the scenario's (RI needs a whole cardiac cycle:
    /// 360 frames at 1.8 kHz hold one at 5.5 Hz).
    #[cfg_attr(feature = "clap", arg(long))]
    pub brain_frames: Option<usize>,
    /// Brain study: folder of cached simulations, one per scenario [default: OUT/cache; from
    /// Python, pcuvd-cache in the working folder].
    #[cfg_attr(feature = "clap", arg(long))]
    pub brain_cache: Option<std::path::PathBuf>,
    /// Brain study: SVD clutter filter's tissue cut-off (as `process --svd-low`).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().brain_svd_low))]
    pub brain_svd_low: String,
    /// Brain study: SVD clutter filter's noise cut-off (as `process --svd-high`).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = StudySettings::default().brain_svd_high))]
    pub brain_svd_high: String,
    /// Brain study: SVD clutter filter block-wise, blocks this wide (mm), or "whole" (as
    /// `process --svd-block-mm`).
    #[cfg_attr(feature = "clap", arg(long, value_name = "MM|whole", default_value_t = StudySettings::default().brain_svd_block_mm))]
    #[serde(deserialize_with = "crate::settings::text")]
    pub brain_svd_block_mm: String,
    /// A first look at every study in a few minutes: fewer frames, one noise level, no
    /// averaging kernels or calibration, a 90 µm grid, a fast heart for the network, one seed
    /// and two speeds for dealiasing, the small brain (`rat-brain-small`). An option given with
    /// a value other than its default keeps that value.
    #[cfg_attr(feature = "clap", arg(long))]
    pub quick: bool,
}

/// Compound frames of the spiral and dealiasing studies with `--quick`.
pub const QUICK_FRAMES: usize = 20;
/// Pixel size (mm) with `--quick`: as coarse as the Loupas estimator's axial lag allows at the
/// rat probe's 15.6 MHz (at most 98.7 µm).
pub const QUICK_GRID_STEP_MM: f64 = 0.09;

impl Default for StudySettings {
    fn default() -> Self {
        StudySettings {
            frames: SpiralSettings::default().frames,
            seed: SpiralSettings::default().seed,
            noise_db: SpiralSettings::default().noise_db,
            sweep: default_sweep(),
            motion: Motion::from(SpiralSettings::default().motion),
            event_alignment: Alignment::from(SpiralSettings::default().event_alignment),
            doppler_kernel: kernel_text(SpiralSettings::default().doppler_kernel),
            grid_step: SpiralSettings::default().grid_step_m * 1e3,
            doppler_estimator: DopplerEstimatorOption::from(
                SpiralSettings::default().doppler_estimator,
            ),
            partial_volume: Switch::from(SpiralSettings::default().partial_volume),
            dynamics_partial_volume: DynamicsSettings::default().dynamics_partial_volume,
            f_number: SpiralSettings::default().f_number,
            calibrate_uvd_vx: "5.7".into(),
            averaging_kernels: default_averaging(),
            network_frames: NetworkSettings::default().frames,
            network_noise_db: NetworkSettings::default().noise_db,
            heart_rate: NetworkSettings::default().heart_rate_hz,
            dealias_multiples: join(&DealiasSettings::default().multiples),
            dealias_noise_db: default_dealias_noise(),
            dealias_seeds: join(&DealiasSettings::default().seeds),
            dealias: DealiasSettings::default().dealias.label(),
            dealias_tube_angle_deg: DealiasSettings::default().tube_angle_deg,
            dealias_tube_profile: DealiasSettings::default().tube_profile.into(),
            brain_scenario: crate::brain::DEFAULT_SCENARIO.into(),
            brain_frames: None,
            brain_cache: None,
            brain_svd_low: ProcessingSettings::default().svd_low,
            brain_svd_high: ProcessingSettings::default().svd_high,
            brain_svd_block_mm: ProcessingSettings::default().svd_block_mm,
            quick: false,
        }
    }
}

/// Values as comma-separated text, as the list options take them.
fn join<T: ToString>(values: &[T]) -> String {
    values
        .iter()
        .map(|v| v.to_string())
        .collect::<Vec<_>>()
        .join(",")
}

/// The library's dealiasing noise levels, as the option's default text ("off" for none).
fn default_dealias_noise() -> String {
    let levels: Vec<String> = DealiasSettings::default()
        .noise_db
        .iter()
        .map(|v| v.map_or("off".into(), |db| db.to_string()))
        .collect();
    levels.join(",")
}

/// The library's averaging kernels, as the option's default text ("off" for none).
fn default_averaging() -> String {
    let kernels = SpiralSettings::default().averaging_kernels;
    if kernels.is_empty() {
        return "off".into();
    }
    let texts: Vec<String> = kernels.into_iter().map(kernel_text).collect();
    texts.join(",")
}

/// The library's sweep levels, as the option's default text.
fn default_sweep() -> String {
    let levels: Vec<String> = SpiralSettings::default()
        .sweep_db
        .iter()
        .map(|v| v.to_string())
        .collect();
    levels.join(",")
}

/// When scatterers move ([`pcuvd::study::Motion`]).
#[derive(Clone, Copy, PartialEq, Eq, Debug, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum Motion {
    /// At every transmit event (physical).
    PerEvent,
    /// Once per compound frame (the paper's simulation; Hadamard decoding then sees a still medium).
    PerFrame,
}

impl From<StudyMotion> for Motion {
    fn from(m: StudyMotion) -> Self {
        match m {
            StudyMotion::PerEvent => Motion::PerEvent,
            StudyMotion::PerFrame => Motion::PerFrame,
        }
    }
}

impl StudySettings {
    /// The spiral study's settings, checked.
    pub fn spiral_settings(&self) -> Result<SpiralSettings> {
        let sweep_db = crate::settings::parse_numbers(&self.sweep).with_context(|| {
            format!(
                "--sweep {:?}: expected comma-separated noise levels in dB",
                self.sweep
            )
        })?;
        let settings = SpiralSettings {
            frames: self.frames,
            seed: self.seed,
            noise_db: self.noise_db,
            sweep_db,
            motion: self.motion.into(),
            event_alignment: self.event_alignment.into(),
            doppler_kernel: crate::settings::parse_kernel(&self.doppler_kernel)?,
            doppler_estimator: self.doppler_estimator.into(),
            partial_volume: self.partial_volume == Switch::On,
            f_number: self.f_number,
            grid_step_m: self.grid_step * 1e-3,
            calibrate_uvd_vx_m_s: match self.calibrate_uvd_vx.trim() {
                "off" => None,
                text => Some(
                    text.parse::<f64>().with_context(|| {
                        format!("--calibrate-uvd-vx {text:?}: expected mm/s or \"off\"")
                    })? * 1e-3,
                ),
            },
            averaging_kernels: match self.averaging_kernels.trim() {
                "off" => Vec::new(),
                text => text
                    .split(',')
                    .map(|k| crate::settings::parse_kernel(k.trim()))
                    .collect::<Result<Vec<_>>>()
                    .with_context(|| format!("--averaging-kernels {text:?}"))?,
            },
        };
        settings.validate().context(
            "--frames / --noise-db / --sweep / --doppler-kernel / --averaging-kernels / --grid-step",
        )?;
        Ok(settings)
    }

    /// The dealiasing study's settings, checked (with `--frames`, `--motion`,
    /// `--event-alignment`, `--doppler-kernel` and `--grid-step` shared with the spiral study).
    pub fn dealias_settings(&self) -> Result<DealiasSettings> {
        let multiples = crate::settings::parse_numbers(&self.dealias_multiples)
            .with_context(|| format!("--dealias-multiples {:?}", self.dealias_multiples))?;
        let noise_db = self
            .dealias_noise_db
            .split(',')
            .map(crate::settings::parse_db_or_off)
            .collect::<Result<Vec<_>>>()
            .with_context(|| format!("--dealias-noise-db {:?}", self.dealias_noise_db))?;
        let seeds = self
            .dealias_seeds
            .split(',')
            .map(|t| t.trim().parse::<u64>())
            .collect::<std::result::Result<Vec<_>, _>>()
            .with_context(|| {
                format!(
                    "--dealias-seeds {:?}: expected comma-separated whole numbers",
                    self.dealias_seeds
                )
            })?;
        let settings = DealiasSettings {
            multiples,
            noise_db,
            seeds,
            frames: self.frames,
            tube_angle_deg: self.dealias_tube_angle_deg,
            tube_profile: self.dealias_tube_profile.into(),
            dealias: pcuvd::estimate::dealias::Dealias::parse(&self.dealias)
                .context("--dealias")?,
            motion: self.motion.into(),
            event_alignment: self.event_alignment.into(),
            doppler_kernel: crate::settings::parse_kernel(&self.doppler_kernel)?,
            grid_step_m: self.grid_step * 1e-3,
            partial_volume: self.partial_volume == Switch::On,
            f_number: self.f_number,
        };
        settings.validate().context(
            "--dealias-multiples / --dealias-noise-db / --dealias-seeds / --dealias / --frames / --doppler-kernel / --grid-step",
        )?;
        Ok(settings)
    }

    /// The network study's settings, checked.
    pub fn network_settings(&self) -> Result<NetworkSettings> {
        let settings = NetworkSettings {
            frames: self.network_frames,
            seed: self.seed,
            noise_db: self.network_noise_db,
            heart_rate_hz: self.heart_rate,
            motion: self.motion.into(),
            event_alignment: self.event_alignment.into(),
            grid_step_m: self.grid_step * 1e-3,
            doppler_estimator: self.doppler_estimator.into(),
            doppler_kernel: crate::settings::parse_kernel(&self.doppler_kernel)?,
            partial_volume: self.partial_volume == Switch::On,
            dynamics_partial_volume: self.dynamics_partial_volume == Switch::On,
            f_number: self.f_number,
        };
        settings.validate().with_context(|| {
            format!(
                "--network-frames {} / --network-noise-db / --heart-rate {} Hz / --grid-step",
                self.network_frames, self.heart_rate
            )
        })?;
        Ok(settings)
    }
}

impl StudySettings {
    /// These settings as `--quick` makes them (see [`StudySettings::quick`]): each setting still
    /// at its default takes its quick value; without `quick`, the settings unchanged.
    pub fn quickened(&self) -> StudySettings {
        if !self.quick {
            return self.clone();
        }
        let default = StudySettings::default();
        let mut quick = self.clone();
        let set = |field: &mut String, default: &str, value: &str| {
            if field == default {
                *field = value.to_string();
            }
        };
        set(&mut quick.sweep, &default.sweep, "-10");
        set(
            &mut quick.averaging_kernels,
            &default.averaging_kernels,
            "off",
        );
        set(
            &mut quick.calibrate_uvd_vx,
            &default.calibrate_uvd_vx,
            "off",
        );
        set(
            &mut quick.dealias_noise_db,
            &default.dealias_noise_db,
            "off",
        );
        set(
            &mut quick.dealias_multiples,
            &default.dealias_multiples,
            "1,3",
        );
        set(&mut quick.dealias_seeds, &default.dealias_seeds, "1");
        set(
            &mut quick.brain_scenario,
            &default.brain_scenario,
            "rat-brain-small",
        );
        if quick.frames == default.frames {
            quick.frames = QUICK_FRAMES;
        }
        if quick.grid_step == default.grid_step {
            quick.grid_step = QUICK_GRID_STEP_MM;
        }
        // One cardiac cycle at 25 Hz is 72 frames at 1.8 kHz: 100 frames hold one of windows.
        if quick.network_frames == default.network_frames && quick.heart_rate == default.heart_rate
        {
            quick.network_frames = 100;
            quick.heart_rate = 25.0;
        }
        quick
    }

    /// The brain study's settings; its cache under `out` (or `pcuvd-cache` in the working folder
    /// without one) unless `--brain-cache` says where. The
    /// recordings are processed as `pcuvd process` processes them, with the studies' receive
    /// f-number, Doppler kernel and estimator, partial-volume correction and decoding.
    pub fn brain_settings(&self, out: Option<&std::path::Path>) -> Result<BrainSettings> {
        let processing = ProcessingSettings {
            f_number: self.f_number,
            // As the option reads it: "3x1" from the command line and (3, 1) from Python alike.
            doppler_kernel: kernel_text(crate::settings::parse_kernel(&self.doppler_kernel)?),
            doppler_estimator: self.doppler_estimator,
            partial_volume: self.partial_volume,
            event_alignment: self.event_alignment,
            svd_low: self.brain_svd_low.clone(),
            svd_high: self.brain_svd_high.clone(),
            svd_block_mm: self.brain_svd_block_mm.clone(),
            ..ProcessingSettings::default()
        };
        let settings = BrainSettings {
            scenario: self.brain_scenario.clone(),
            frames: self.brain_frames,
            cache: match &self.brain_cache {
                Some(folder) => folder.clone(),
                None => crate::brain::default_cache(out),
            },
            processing,
            dynamics: DynamicsSettings {
                dynamics_partial_volume: self.dynamics_partial_volume,
                ..DynamicsSettings::default()
            },
        };
        // Checked now, not after a quarter of an hour of simulation.
        settings
            .scenario()
            .with_context(|| format!("--brain-scenario {}", self.brain_scenario))?;
        crate::settings::check_rank_cut(&settings.processing.svd_low, "brain-svd-low")?;
        crate::settings::check_rank_cut(&settings.processing.svd_high, "brain-svd-high")?;
        crate::settings::check_block_width(
            &settings.processing.svd_block_mm,
            "brain-svd-block-mm",
        )?;
        Ok(settings)
    }
}

impl From<Motion> for StudyMotion {
    fn from(m: Motion) -> Self {
        match m {
            Motion::PerEvent => StudyMotion::PerEvent,
            Motion::PerFrame => StudyMotion::PerFrame,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::settings::testing;

    #[cfg(feature = "clap")]
    #[test]
    fn the_command_line_defaults_are_the_settings_defaults() {
        testing::command_line_defaults_are_default::<StudySettings>();
    }

    #[test]
    fn settings_read_back_as_they_were_written() {
        testing::reads_back_and_refuses_unknown_keys(&StudySettings::default());
    }

    /// The options the studies share reach every study that processes a recording, so that a
    /// candidate default is scored everywhere with the same settings; an even kernel is refused
    /// by each.
    #[test]
    fn every_study_gets_the_shared_processing_options() {
        let given = StudySettings {
            doppler_kernel: "3x1".into(),
            partial_volume: Switch::Off,
            f_number: 0.75,
            ..StudySettings::default()
        };
        // Values other than the defaults, so that the test sees them travel.
        let default = StudySettings::default();
        assert_ne!(default.doppler_kernel, "3x1");
        assert_ne!(default.partial_volume, Switch::Off);
        assert_ne!(default.f_number, 0.75);
        let spiral = given.spiral_settings().unwrap();
        let network = given.network_settings().unwrap();
        let dealias = given.dealias_settings().unwrap();
        let brain = given.brain_settings(None).unwrap().processing;
        assert_eq!(
            [
                spiral.doppler_kernel,
                network.doppler_kernel,
                dealias.doppler_kernel
            ],
            [(3, 1); 3]
        );
        assert_eq!(
            [
                spiral.partial_volume,
                network.partial_volume,
                dealias.partial_volume
            ],
            [false; 3]
        );
        assert_eq!(
            [
                spiral.f_number,
                network.f_number,
                dealias.f_number,
                brain.f_number
            ],
            [0.75; 4]
        );
        assert_eq!(
            (brain.doppler_kernel.as_str(), brain.partial_volume),
            ("3x1", Switch::Off)
        );
        // The maps' correction leaves the RI windows as `process` leaves them; their own option
        // reaches both studies that score RI.
        assert!(!network.dynamics_partial_volume);
        let windows = StudySettings {
            dynamics_partial_volume: Switch::On,
            ..StudySettings::default()
        };
        assert!(windows.network_settings().unwrap().dynamics_partial_volume);
        let brain_windows = windows.brain_settings(None).unwrap().dynamics;
        assert_eq!(brain_windows.dynamics_partial_volume, Switch::On);
        let even = StudySettings {
            doppler_kernel: "4x1".into(),
            ..StudySettings::default()
        };
        assert!(even.spiral_settings().is_err());
        assert!(even.network_settings().is_err());
        assert!(even.dealias_settings().is_err());
    }

    /// `--quick` changes only what is still at its default, and every study it reduces still
    /// passes its checks (a network recording that holds a cardiac cycle, a grid fine enough
    /// for Loupas).
    #[test]
    fn quick_keeps_what_was_given_and_gives_valid_settings() {
        let plain = StudySettings::default();
        assert_eq!(plain.quickened(), plain);
        let quick = StudySettings {
            quick: true,
            seed: 4,
            dealias_seeds: "2,3".into(),
            ..StudySettings::default()
        }
        .quickened();
        assert_eq!((quick.seed, quick.dealias_seeds.as_str()), (4, "2,3"));
        assert_eq!(quick.frames, QUICK_FRAMES);
        assert_eq!(quick.brain_scenario, "rat-brain-small");
        assert!(quick.spiral_settings().is_ok());
        assert!(quick.network_settings().is_ok());
        assert!(quick.dealias_settings().is_ok());
        let brain = quick.brain_settings(None).unwrap();
        assert_eq!(brain.scenario().unwrap().sequence.frames, 48);
        // A frame count given stays, even with --quick.
        let given = StudySettings {
            quick: true,
            frames: 30,
            ..StudySettings::default()
        };
        assert_eq!(given.quickened().frames, 30);
    }
}
