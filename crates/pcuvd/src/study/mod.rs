//! The paper's studies as library functions: settings whose `Default` is the paper's set-up, a
//! `run` that simulates, processes and scores, and typed results. Every front end (the `pcuvd
//! paper` command, Python, a notebook) gets the same numbers from the same code.
//!
//! - [`spiral`]: the spiral-flow simulation (paper §2.3, §3, Fig. 2–5) with a noise sweep;
//! - [`network`]: the in-vivo-like pulsatile vessel network (paper §4, Fig. 6–8) with RI truth;
//! - [`dealias`]: vector dealiasing on a tube at 1–3× the Nyquist velocity (beyond the paper).
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

pub mod dealias;
pub mod network;
pub mod spiral;

use std::collections::BTreeMap;
use std::time::Instant;

use ndarray::{Array3, s};
use num_complex::Complex32;
use serde::Serialize;

use crate::acquisition::channel::{Acquisition, ChannelData, Samples};
use crate::acquisition::source::FrameSource;
use crate::core::error::Result;
use crate::core::grid::Grid;
use crate::estimate::clutter::{ClutterParams, RankCut};
use crate::estimate::vector::IrlsParams;
use crate::form::beamform::DasParams;
use crate::form::decode::EventAlignment;
use crate::form::images::AngleImages;
use crate::pipeline::{self, ProcessParams};
use crate::simulate::phantom::{FrameHeld, Phantom};
use crate::simulate::{self, NoiseSpec, SimParams};

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
    crate::form::beamform::compound(&images.series)
        .map(|c| crate::evaluate::metrics::mean_power(&c))
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
        doppler_estimator: crate::estimate::doppler::DopplerEstimator::default(),
        irls: IrlsParams::default(),
        iq_cutoff: None,
        event_alignment,
        dealias: Default::default(),
        partial_volume: false,
    }
}

/// Refuses a Doppler averaging kernel (rows × columns of pixels) that is not odd in both sizes:
/// the autocorrelation is averaged around each pixel, centred on it.
pub fn check_doppler_kernel((rows, cols): (usize, usize)) -> Result<()> {
    if rows % 2 == 0 || cols % 2 == 0 {
        return Err(crate::core::error::invalid(
            "Doppler kernel",
            format!("{rows} × {cols}: both sizes must be odd"),
        ));
    }
    Ok(())
}

/// Refuses, before anything is simulated, a Doppler `estimator` that a study's `grid` cannot
/// serve for the acquisition `params` ([`crate::pipeline::check_doppler_estimator`]: Loupas on
/// an axial step too coarse for it).
pub fn check_estimator(
    params: &crate::simulate::SimParams,
    grid: &Grid,
    estimator: crate::estimate::doppler::DopplerEstimator,
) -> Result<()> {
    let acq = params.acquisition();
    crate::pipeline::check_doppler_estimator(
        &acq,
        &ProcessParams {
            doppler_estimator: estimator,
            ..process_params(grid, &acq, (1, 1), EventAlignment::MidFrame)
        },
    )
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
    /// Receive f-number of the beamformer.
    pub f_number: f64,
}

/// Simulates the echoes and the noise of `what` apart and beamforms both on `grid`; adds the
/// simulation and beamforming times to `timing`. The recordings are simulated and formed a block
/// of frames at a time ([`pipeline::blocks_for`]), so only their images are ever held whole.
pub fn simulate_and_form(
    what: Acquire<'_>,
    grid: &Grid,
    timing: &mut Timings,
    progress: Progress<'_>,
) -> Result<Formed> {
    let frames = what.frames;
    check_series_memory(&what, grid, 2)?;
    let mut signal: Vec<Array3<Complex32>> = Vec::new();
    let mut noise: Vec<Array3<Complex32>> = Vec::new();
    let (acquisition, metadata) = form_echo_and_noise(
        what,
        grid,
        timing,
        progress,
        &mut |block, echo, unit_noise| {
            if signal.is_empty() {
                let shape = |a: &Array3<Complex32>| (a.dim().0, a.dim().1, frames);
                signal = echo.iter().map(|a| Array3::zeros(shape(a))).collect();
                noise = echo.iter().map(|a| Array3::zeros(shape(a))).collect();
            }
            for (k, (e, n)) in echo.iter().zip(unit_noise).enumerate() {
                signal[k].slice_mut(s![.., .., block.clone()]).assign(e);
                noise[k].slice_mut(s![.., .., block.clone()]).assign(n);
            }
        },
    )?;
    Ok(Formed {
        acquisition,
        signal: metadata.with_series(signal),
        noise: metadata.with_series(noise),
    })
}

/// Echo-plus-noise images of one mode at the simulated noise level, with the time-mean power of
/// the compounded echo and noise images apart (what SNR by depth compares).
#[derive(Debug, Clone)]
pub struct FormedSum {
    /// The simulated acquisition.
    pub acquisition: Acquisition,
    /// Beamformed echoes plus receiver noise, per angle.
    pub images: AngleImages,
    /// Time-mean power of the compounded echo images (nz, nx), |IQ|² units.
    pub echo_power: ndarray::Array2<f64>,
    /// Time-mean power of the compounded noise images (nz, nx), |IQ|² units.
    pub noise_power: ndarray::Array2<f64>,
}

/// Refuses `copies` image series of every angle of `what` on `grid` that the machine cannot
/// allocate: a study asked for a billion frames aborted on the failed allocation.
fn check_series_memory(what: &Acquire<'_>, grid: &Grid, copies: u128) -> Result<()> {
    let (nz, nx) = grid.shape();
    let angles = what.params.sequence.n_angles() as u128;
    let bytes = copies * angles * (nz * nx) as u128 * what.frames as u128 * 8;
    crate::core::buffers::check_allocatable(
        bytes,
        &format!(
            "{} frames of {} ({nz} x {nx} pixels)",
            what.frames, what.label
        ),
    )
}

/// As [`simulate_and_form`], holding only the sum of echoes and noise (the network study needs no
/// other noise level): half the memory of [`Formed`]. The compounded powers equal
/// [`compound_mean_power`] of the echo and noise images [`simulate_and_form`] gives.
pub fn simulate_and_form_sum(
    what: Acquire<'_>,
    grid: &Grid,
    timing: &mut Timings,
    progress: Progress<'_>,
) -> Result<FormedSum> {
    let frames = what.frames;
    check_series_memory(&what, grid, 1)?;
    let mut series: Vec<Array3<Complex32>> = Vec::new();
    let mut sums: [ndarray::Array2<f64>; 2] = Default::default();
    let (acquisition, metadata) = form_echo_and_noise(
        what,
        grid,
        timing,
        progress,
        &mut |block, echo, unit_noise| {
            if series.is_empty() {
                let (nz, nx, _) = echo[0].dim();
                series = echo
                    .iter()
                    .map(|_| Array3::zeros((nz, nx, frames)))
                    .collect();
                sums = [
                    ndarray::Array2::zeros((nz, nx)),
                    ndarray::Array2::zeros((nz, nx)),
                ];
            }
            for (sum, part) in sums.iter_mut().zip([echo, unit_noise]) {
                let compound = crate::form::beamform::compound(part).expect("one block per angle");
                ndarray::Zip::from(sum)
                    .and(compound.lanes(ndarray::Axis(2)))
                    .for_each(|s, lane| {
                        *s += lane.iter().map(|c| c.norm_sqr() as f64).sum::<f64>()
                    });
            }
            for (k, (e, n)) in echo.iter().zip(unit_noise).enumerate() {
                let mut out = series[k].slice_mut(s![.., .., block.clone()]);
                out.assign(e);
                out += n;
            }
        },
    )?;
    let [echo_power, noise_power] = sums.map(|sum| sum / frames as f64);
    Ok(FormedSum {
        acquisition,
        images: metadata.with_series(series),
        echo_power,
        noise_power,
    })
}

/// A phantom's echoes or its receiver noise, simulated on demand a block of frames at a time.
struct SimulatedFrames<'a> {
    phantom: &'a dyn Phantom,
    params: SimParams,
    acquisition: Acquisition,
    frames: usize,
    /// Echoes (noise-free) when false; the receiver noise alone when true.
    noise: bool,
    /// Seconds spent simulating, as f64 bits (read_frames takes `&self`).
    seconds: std::sync::atomic::AtomicU64,
}

impl<'a> SimulatedFrames<'a> {
    fn new(phantom: &'a dyn Phantom, params: SimParams, frames: usize, noise: bool) -> Self {
        SimulatedFrames {
            acquisition: params.acquisition(),
            phantom,
            params,
            frames,
            noise,
            seconds: std::sync::atomic::AtomicU64::new(0f64.to_bits()),
        }
    }

    fn seconds(&self) -> f64 {
        f64::from_bits(self.seconds.load(std::sync::atomic::Ordering::Relaxed))
    }
}

impl FrameSource for SimulatedFrames<'_> {
    fn acquisition(&self) -> &Acquisition {
        &self.acquisition
    }

    fn n_frames(&self) -> usize {
        self.frames
    }

    fn trace_shape(&self) -> (usize, usize) {
        (self.params.probe.n_elements, self.params.n_samples)
    }

    fn read_frames(&self, frames: std::ops::Range<usize>) -> Result<ChannelData> {
        let clock = Instant::now();
        let n = self.params.sequence.n_angles();
        let events = frames.start * n..frames.end * n;
        let rf = if self.noise {
            simulate::simulate_noise_events(self.phantom, &self.params, self.frames, events)?
        } else {
            simulate::simulate_events(self.phantom, &self.params, self.frames, events, &|_, _| {})?
        };
        let spent = self.seconds() + clock.elapsed().as_secs_f64();
        self.seconds
            .store(spent.to_bits(), std::sync::atomic::Ordering::Relaxed);
        Ok(ChannelData {
            acquisition: self.acquisition.clone(),
            samples: Samples::Rf(rf),
        })
    }
}

/// Receives each block of [`form_echo_and_noise`]: its frames, then per angle the echo images and
/// the noise images (nz, nx, block frames).
type BlockSink<'a> =
    dyn FnMut(std::ops::Range<usize>, &[Array3<Complex32>], &[Array3<Complex32>]) + 'a;

/// Simulates and forms the echoes and the unit-level noise of `what`, a block of frames at a time,
/// handing each block's per-angle images (echo, noise) to `sink(block frames, echo, noise)`.
/// Returns the acquisition and the image metadata (an [`AngleImages`] without series).
fn form_echo_and_noise(
    what: Acquire<'_>,
    grid: &Grid,
    timing: &mut Timings,
    progress: Progress<'_>,
    sink: &mut BlockSink<'_>,
) -> Result<(Acquisition, AngleImages)> {
    let Acquire {
        phantom,
        mut params,
        frames,
        noise_db,
        motion,
        alignment,
        label,
        f_number,
    } = what;
    params.noise = None;
    let held = FrameHeld {
        inner: phantom,
        frame_period: params.sequence.n_angles() as f64 / params.sequence.event_prf,
    };
    let phantom: &dyn Phantom = match motion {
        Motion::PerEvent => phantom,
        Motion::PerFrame => &held,
    };
    let echoes = SimulatedFrames::new(phantom, params.clone(), frames, false);
    params.noise = Some(NoiseSpec::new(noise_db));
    let noise = SimulatedFrames::new(phantom, params, frames, true);
    let acquisition = echoes.acquisition.clone();
    let mut process = process_params(grid, &acquisition, (1, 1), alignment);
    process.das.f_number = f_number;
    let blocks = pipeline::blocks_for(&echoes, alignment);
    let ranges = blocks.ranges(frames);
    let task = format!("simulate + beamform {label}");
    let clock = Instant::now();
    for (b, (block, decoded)) in ranges.iter().enumerate() {
        progress(&task, 2 * b, 2 * ranges.len());
        let quiet = |_: pipeline::Stage, _: usize| {};
        let echo = pipeline::form_block(&echoes, &process, block.clone(), decoded.clone(), &quiet)?;
        progress(&task, 2 * b + 1, 2 * ranges.len());
        let unit = pipeline::form_block(&noise, &process, block.clone(), decoded.clone(), &quiet)?;
        sink(block.clone(), &echo.images, &unit.images);
    }
    progress(&task, 2 * ranges.len(), 2 * ranges.len());
    let simulate_s = echoes.seconds() + noise.seconds();
    timing.insert(format!("simulate_{label}_s"), simulate_s);
    timing.insert(
        format!("beamform_{label}_s"),
        clock.elapsed().as_secs_f64() - simulate_s,
    );
    let metadata = AngleImages {
        grid: grid.clone(),
        angles: acquisition.sequence.angles.clone(),
        frame_rate: acquisition.frame_rate(),
        sound_speed: acquisition.sound_speed,
        demodulation_frequency: acquisition.probe.center_frequency,
        coverage: Some(pipeline::angle_coverage(
            &acquisition,
            echoes.trace_shape().1,
            grid,
        )),
        series: Vec::new(),
    };
    Ok((acquisition, metadata))
}
