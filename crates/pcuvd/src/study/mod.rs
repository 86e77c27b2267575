//! The paper's studies as library functions: settings whose `Default` is the paper's set-up, a
//! `run` that simulates, processes and scores, and typed results. Every front end (the `pcuvd
//! paper` command, Python, a notebook) gets the same numbers from the same code.
//!
//! - [`spiral`]: the spiral-flow simulation (paper §2.3, §3, Fig. 2–5) with a noise sweep;
//! - [`network`]: the in-vivo-like pulsatile vessel network (paper §4, Fig. 6–8) with RI truth.
//!
//! Both form the echoes and the receiver noise apart: everything up to the Doppler
//! autocorrelation (decoding, demodulation, beamforming) is linear in the channel data, so the
//! echo images S and the images N of a unit noise field are formed once per mode and added as
//! S + g·N for any noise level g; SNR is then measured without either biasing the other.
//!
//! ```no_run
//! use pcuvd::study::{network, spiral};
//!
//! let quiet = |_: &str, _: usize, _: usize| {};
//! let study = spiral::run(&spiral::SpiralSettings { frames: 20, ..Default::default() }, &quiet)?;
//! println!("PC-UVD RMSE Vx {:.2} mm/s", study.metrics.rmse_mm_s.pcuvd_irls.vx);
//! let net = network::run(&network::NetworkSettings::default(), &quiet)?;
//! println!("PC-UVD median |ΔRI| {:.3}", net.metrics.ri.pcuvd.median_abs_error);
//! # Ok::<(), pcuvd::Error>(())
//! ```

pub mod network;
pub mod spiral;

use std::collections::BTreeMap;
use std::time::Instant;

use serde::Serialize;

use crate::beamform::DasParams;
use crate::channel::Acquisition;
use crate::clutter::{ClutterParams, RankCut};
use crate::decode::EventAlignment;
use crate::error::Result;
use crate::grid::Grid;
use crate::images::AngleImages;
use crate::phantom::{FrameHeld, Phantom};
use crate::pipeline::{self, ProcessParams};
use crate::simulate::{self, NoiseSpec, SimParams};
use crate::vector::IrlsParams;

/// A study's progress callback: (task, steps done, steps in the task). Tasks follow one another;
/// a new task label starts a new count.
pub type Progress<'a> = &'a (dyn Fn(&str, usize, usize) + Sync);

/// Wall-clock seconds of a study's steps, by step name.
pub type Timings = BTreeMap<String, f64>;

/// When the simulated scatterers move.
#[derive(Clone, Copy, PartialEq, Eq, Debug, Default, Serialize)]
pub enum Motion {
    /// At every transmit event (physical).
    #[default]
    PerEvent,
    /// Once per compound frame (the paper's simulation; Hadamard decoding then sees a still medium).
    PerFrame,
}

impl Motion {
    /// One sentence for reports.
    pub fn describe(self) -> &'static str {
        match self {
            Motion::PerEvent => "scatterers move at every transmit event (physical)",
            Motion::PerFrame => {
                "scatterers held still within each compound frame, as in the paper's simulation (Δt = frame period)"
            }
        }
    }
}

/// One sentence for reports on what the event alignment did to the coded recording.
pub fn describe_alignment(alignment: EventAlignment) -> &'static str {
    match alignment {
        EventAlignment::MidFrame => {
            "each coded event's slow-time series resampled (band-limited, over the frames) to its frame's mid-event time before Hadamard decoding (--event-alignment mid-frame), so that blood moving between the events of a frame does not leak the decoded angles into each other"
        }
        EventAlignment::Simultaneous => {
            "the paper's Hadamard decoding, which takes the events of a compound frame as simultaneous (--event-alignment simultaneous): blood moving between them leaks the decoded angles into each other"
        }
    }
}

/// The two transmit modes a study compares.
#[derive(Clone, Copy, PartialEq, Eq, Debug, Serialize)]
pub enum Mode {
    /// One plane wave per event (UVD).
    Conventional,
    /// Hadamard-coded events, every angle in every event (PC-UVD).
    Coded,
}

impl Mode {
    /// Both modes, in the order studies report them.
    pub const BOTH: [Mode; 2] = [Mode::Conventional, Mode::Coded];

    /// Lower-case name used in file and timing names.
    pub fn label(self) -> &'static str {
        match self {
            Mode::Conventional => "conventional",
            Mode::Coded => "coded",
        }
    }

    /// The method the study pairs with this mode: UVD (least squares) or PC-UVD (IRLS-WLS).
    pub fn method(self) -> &'static str {
        match self {
            Mode::Conventional => "UVD",
            Mode::Coded => "PC-UVD",
        }
    }
}

/// Echo images (S) and unit-noise images (N) of one mode, formed apart.
#[derive(Debug, Clone)]
pub struct Formed {
    /// The simulated acquisition.
    pub acquisition: Acquisition,
    /// Beamformed echoes, per angle.
    pub signal: AngleImages,
    /// Beamformed receiver noise at the simulated level, per angle.
    pub noise: AngleImages,
}

impl Formed {
    /// Per-angle series with noise at `gain` × the simulated level: S + gain·N.
    pub fn at_gain(&self, gain: f32) -> AngleImages {
        let series = self
            .signal
            .series
            .iter()
            .zip(&self.noise.series)
            .map(|(s, n)| {
                let mut out = s.clone();
                ndarray::Zip::from(&mut out)
                    .and(n)
                    .for_each(|o, &v| *o += v * gain);
                out
            })
            .collect();
        self.signal.with_series(series)
    }
}

/// Time-mean power of the compounded (angle-summed) image series, shape (nz, nx): the power
/// Doppler of echo-only or noise-only images that SNR by depth compares.
pub fn compound_mean_power(images: &AngleImages) -> Result<ndarray::Array2<f64>> {
    crate::beamform::compound(&images.series).map(|c| crate::metrics::mean_power(&c))
}

/// Processing settings of the studies: the pipeline's defaults on `grid` with no clutter filter
/// (the phantoms hold no tissue, as in the paper).
pub fn process_params(
    grid: &Grid,
    acq: &Acquisition,
    doppler_kernel: (usize, usize),
    event_alignment: EventAlignment,
) -> ProcessParams {
    ProcessParams {
        grid: grid.clone(),
        das: DasParams::new(acq.sound_speed),
        clutter: ClutterParams {
            low: RankCut::Off,
            high: RankCut::Off,
            ..ClutterParams::default()
        },
        doppler_kernel,
        doppler_estimator: crate::doppler::DopplerEstimator::default(),
        irls: IrlsParams::default(),
        iq_cutoff: None,
        event_alignment,
    }
}

/// What [`simulate_and_form`] simulates.
pub struct Acquire<'a> {
    /// The phantom.
    pub phantom: &'a dyn Phantom,
    /// Probe, sequence and seed (its noise setting is replaced by `noise_db`).
    pub params: SimParams,
    /// Compound frames.
    pub frames: usize,
    /// Noise level (dB, [`simulate::NOISE_DEFINITION`]).
    pub noise_db: f64,
    /// When scatterers move.
    pub motion: Motion,
    /// How coded events are decoded.
    pub alignment: EventAlignment,
    /// Name of the progress tasks and timing keys.
    pub label: &'a str,
}

/// Simulates the echoes and the noise of `what` apart and beamforms both on `grid`; adds the
/// simulation and beamforming times to `timing`.
pub fn simulate_and_form(
    what: Acquire<'_>,
    grid: &Grid,
    timing: &mut Timings,
    progress: Progress<'_>,
) -> Result<Formed> {
    let Acquire {
        phantom,
        mut params,
        frames,
        noise_db,
        motion,
        alignment,
        label,
    } = what;
    params.noise = None;
    let events = frames * params.sequence.n_angles();
    let held = FrameHeld {
        inner: phantom,
        frame_period: params.sequence.n_angles() as f64 / params.sequence.event_prf,
    };
    let phantom: &dyn Phantom = match motion {
        Motion::PerEvent => phantom,
        Motion::PerFrame => &held,
    };
    let clock = Instant::now();
    let task = format!("simulate {label}");
    let signal = simulate::simulate(phantom, &params, frames, &|done, _| {
        progress(&task, done, events)
    })?;
    params.noise = Some(NoiseSpec::new(noise_db));
    let noise = simulate::simulate_noise(phantom, &params, frames)?;
    timing.insert(format!("simulate_{label}_s"), clock.elapsed().as_secs_f64());

    let clock = Instant::now();
    let process = process_params(grid, &signal.acquisition, (1, 1), alignment);
    let (signal_images, _) = pipeline::form_images(&signal, &process, &|s, d, t| {
        progress(&format!("{label} echoes: {}", s.label()), d, t)
    })?;
    let (noise_images, _) = pipeline::form_images(&noise, &process, &|s, d, t| {
        progress(&format!("{label} noise: {}", s.label()), d, t)
    })?;
    timing.insert(format!("beamform_{label}_s"), clock.elapsed().as_secs_f64());
    Ok(Formed {
        acquisition: signal.acquisition,
        signal: signal_images,
        noise: noise_images,
    })
}
