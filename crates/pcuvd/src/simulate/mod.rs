//! RF channel-data simulator: plane-wave (conventional or Hadamard-coded) acquisitions of a
//! [`Phantom`], one transmit event at a time, with the medium moving between events.
//!
//! # Model
//! * **Echo shape**: every scatterer returns the same [`EchoWaveform`] (Hann-windowed N-cycle pulse,
//!   or the sequence's sampled [`TransmitPulse`](crate::TransmitPulse), through the probe's
//!   Gaussian two-way impulse response), centred on its round-trip time.
//! * **Timing**: the echo of a scatterer at (x, z) from pulse slot k (angle θ_k, slot start τ_k) on
//!   element e is centred at `τ_k + geometry::round_trip_delay(x, z, θ_k, x_e, aperture, c) − t0`
//!   after the record's first sample — the crate's one time-of-flight convention.
//! * **Transmit amplitude**: a plane wave has no spreading loss. The finite aperture is modelled as
//!   a geometric shadow: a point is insonified when the ray through it along (sin θ, cos θ) starts
//!   on the array face, with a raised-cosine edge of half-width ½√(λ·path) (amplitude ½ on the
//!   shadow line). Attenuation over the path z / cos θ.
//! * **Receive amplitude**: element directivity sinc(π w sin φ / λ)·cos φ (soft baffle), 2-D
//!   cylindrical spreading √(1 mm / r) (r ≥ λ/2), attenuation over r.
//! * **Elevation** (with [`SimParams::elevation`]): scatterers have an elevation y (the
//!   phantom's [`Phantom::elevations_at`]) and every echo is scaled and delayed by the two-way
//!   elevation factor of the elements' height and lens ([`elevation`]). Without it the model is
//!   two-dimensional: every scatterer in the plane, elements infinitely tall.
//! * **Attenuation**: α·f (dB/cm/MHz × MHz) over the two-way path L (transmit z / cos θ plus
//!   receive r). Its value at f_c scales each echo's amplitude; with
//!   `SimParams::frequency_dependent_attenuation` (the default) it also lowers the echo's
//!   spectrum, as tissue does: the spectrum is multiplied by exp(−α (|f| − f_c) L), which moves a
//!   Gaussian spectrum of amplitude width σ down by α·σ²·L — for the L22-14vX 2-cycle echo at
//!   0.5 dB/cm/MHz its mean frequency falls by about 1 % per mm of depth (12 % at 12 mm;
//!   `tests/integration/simulate.rs`). The
//!   echo table is tabulated at path lengths a few mm apart (each band shifts the spectrum by at
//!   most an eighth of its width) and each echo is blended linearly between the two tables
//!   around its path, so the spectrum changes smoothly with depth at twice the insertion work of
//!   a single table. A Doppler estimator that divides by the nominal f_c reads low in proportion;
//!   the mean-frequency (Loupas) estimator does not.
//! * **Coding**: a coded event superposes all n slots of `Sequence::event_pulses` with their
//!   polarity (or weight) and slot start; event i is simulated at its own time i / PRF.
//! * **Noise**: see [`NOISE_DEFINITION`]; added to every recorded event, before any decoding.
//!
//! # Speed and determinism
//! Transmit delay and amplitude are computed once per scatterer and slot; receive delay and
//! amplitude once per scatterer–element pair (shared by all slots), 8 wide in f32 (delays to
//! ~3·10⁻⁵ sample). Echoes are then *accumulated*, not drawn (a Farrow structure): the echo of a
//! scatterer whose row starts at sample n with sub-sample delay μ adds a·(μ − ½)^q, q = 0..7, to
//! row n of an 8-wide accumulator — one vector add per echo and slot — and one convolution per
//! channel with the waveform's Farrow coefficients (each tap a degree-7 polynomial of μ, within
//! 2·10⁻⁷ of the waveform) gives the trace. Channels run in parallel (rayon), each channel's trace
//! owned by one task, and the noise of (event, channel) comes from its own ChaCha8 stream: the
//! same seed gives bit-identical output whatever the number of threads.

pub mod elevation;
mod kernel;
pub mod keyframes;
mod noise;
pub mod phantom;
mod presets;
pub mod vascular;
mod waveform;

use ndarray::{Array3, Axis};
use rayon::prelude::*;

pub use self::elevation::ElevationAperture;
pub use self::kernel::render_level;
use self::kernel::{Simulator, Slot};
pub use self::presets::{PAPER_FRAMES, RAT_FRAMES, paper_spiral_params, rat_params};
pub use self::waveform::EchoWaveform;
use crate::acquisition::channel::{Acquisition, ChannelData, Samples};
use crate::acquisition::probe::Probe;
use crate::acquisition::sequence::{Coding, Sequence};
use crate::core::error::{Error, Result, invalid, require_positive};
use crate::core::geometry::round_trip_delay;
use crate::simulate::phantom::Phantom;

/// What a noise level in dB means, for code docs and reports.
pub const NOISE_DEFINITION: &str = "noise level D dB: band-limited white Gaussian noise whose RMS is \
10^(D/20) times the RMS of the noiseless, uncoded, single-plane-wave (0°) echo of the same phantom at \
t = 0, taken over all channels and the whole receive window; the same noise is added to every \
recorded event before any decoding.";

/// Receiver noise: band-limited white Gaussian noise at a level relative to the echo (see
/// [`NOISE_DEFINITION`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseSpec {
    /// Noise RMS relative to the reference echo RMS (dB); the paper uses −10.
    pub level_db: f64,
    /// Pass band (low, high) of the noise (Hz); the paper uses 1–22 MHz.
    pub band_hz: (f64, f64),
}

impl NoiseSpec {
    /// Noise at `level_db` (dB) in the paper's 1–22 MHz band.
    pub fn new(level_db: f64) -> Self {
        NoiseSpec {
            level_db,
            band_hz: (1e6, 22e6),
        }
    }
}

/// Everything the simulator needs besides the phantom: acquisition, physics and randomness.
#[derive(Debug, Clone, PartialEq)]
pub struct SimParams {
    /// The probe (elements, pitch, width, f_c, bandwidth).
    pub probe: Probe,
    /// Angles, event PRF (Hz), coding, pulse cycles.
    pub sequence: Sequence,
    /// Sampling frequency of the traces (Hz).
    pub sampling_frequency: f64,
    /// Speed of sound (m/s).
    pub sound_speed: f64,
    /// Attenuation (dB/cm/MHz) over the two-way path; 0 disables it.
    pub attenuation_db_cm_mhz: f64,
    /// Whether attenuation also lowers each echo's spectrum with its path (α·f, linear in
    /// frequency, as in tissue) or only scales its amplitude at f_c. See the module docs.
    pub frequency_dependent_attenuation: bool,
    /// Time of the first sample after the first element of the event's first slot fires (s).
    pub t0: f64,
    /// Samples per trace (the receive window).
    pub n_samples: usize,
    /// Receiver noise, or `None` for noiseless data.
    pub noise: Option<NoiseSpec>,
    /// Seed of the noise streams.
    pub seed: u64,
    /// The elements' elevation aperture (height and lens focus), which makes the simulation
    /// three-dimensional: a scatterer's elevation y sets its echo's amplitude and delay
    /// ([`elevation`]). `None`: the two-dimensional model, every scatterer in the imaging plane.
    pub elevation: Option<ElevationAperture>,
    /// Level (fraction of the peak) below which the echo waveform's tails are left out
    /// ([`EchoWaveform::DEFAULT_TRUNCATION`], −70.5 dB, unless a brighter medium asks for less).
    pub waveform_truncation: f64,
}

impl SimParams {
    /// Default attenuation (dB/cm/MHz).
    pub const DEFAULT_ATTENUATION: f64 = 0.5;

    /// Parameters with a receive window covering depths `depth` = (z_min, z_max) (m) for every
    /// angle, slot offset and element ([`receive_window`]), 0.5 dB/cm/MHz (frequency-dependent),
    /// no noise, seed 0.
    pub fn new(
        probe: Probe,
        sequence: Sequence,
        sampling_frequency: f64,
        sound_speed: f64,
        depth: (f64, f64),
    ) -> Result<Self> {
        Self::new_truncated(
            probe,
            sequence,
            sampling_frequency,
            sound_speed,
            depth,
            EchoWaveform::DEFAULT_TRUNCATION,
        )
    }

    /// [`SimParams::new`] with the echo waveform truncated at `truncation` of its peak (see
    /// [`EchoWaveform::for_sequence_truncated`]): the receive window holds the longer echo.
    pub fn new_truncated(
        probe: Probe,
        sequence: Sequence,
        sampling_frequency: f64,
        sound_speed: f64,
        depth: (f64, f64),
        truncation: f64,
    ) -> Result<Self> {
        let (t0, n_samples) = receive_window(
            &probe,
            &sequence,
            (sampling_frequency, truncation),
            sound_speed,
            depth,
        )?;
        Ok(SimParams {
            probe,
            sequence,
            sampling_frequency,
            sound_speed,
            attenuation_db_cm_mhz: Self::DEFAULT_ATTENUATION,
            frequency_dependent_attenuation: true,
            t0,
            n_samples,
            noise: None,
            seed: 0,
            elevation: None,
            waveform_truncation: truncation,
        })
    }

    /// The acquisition description the simulated [`ChannelData`] carries.
    pub fn acquisition(&self) -> Acquisition {
        Acquisition {
            probe: self.probe.clone(),
            sequence: self.sequence.clone(),
            sampling_frequency: self.sampling_frequency,
            sound_speed: self.sound_speed,
            t0: self.t0,
        }
    }

    /// Duration of the receive window (s).
    pub fn window_duration(&self) -> f64 {
        self.n_samples as f64 / self.sampling_frequency
    }

    /// Checks every parameter, including that the slots and receive window fit in the event period.
    pub fn validate(&self) -> Result<()> {
        self.acquisition().validate()?;
        let fs = self.sampling_frequency;
        let fc = self.probe.center_frequency;
        if fs <= 2.0 * fc {
            return Err(invalid(
                "sampling frequency",
                format!(
                    "{:.3} MHz must exceed twice the centre frequency ({:.3} MHz)",
                    fs / 1e6,
                    2.0 * fc / 1e6
                ),
            ));
        }
        if !(self.attenuation_db_cm_mhz.is_finite() && self.attenuation_db_cm_mhz >= 0.0) {
            return Err(invalid(
                "attenuation",
                format!(
                    "must be finite and ≥ 0 dB/cm/MHz, got {}",
                    self.attenuation_db_cm_mhz
                ),
            ));
        }
        if let Some(elevation) = &self.elevation {
            elevation.validate()?;
        }
        if self.n_samples < 2 {
            return Err(invalid(
                "number of samples",
                format!(
                    "the receive window needs at least 2 samples, got {}",
                    self.n_samples
                ),
            ));
        }
        if let Some(noise) = &self.noise {
            if !noise.level_db.is_finite() {
                return Err(invalid(
                    "noise level",
                    format!("must be finite (dB), got {}", noise.level_db),
                ));
            }
            let (lo, hi) = noise.band_hz;
            if !(lo.is_finite() && hi.is_finite() && lo >= 0.0 && lo < hi && hi <= fs / 2.0) {
                return Err(invalid(
                    "noise band",
                    format!(
                        "({:.3}, {:.3}) MHz must satisfy 0 ≤ low < high ≤ f_s/2 = {:.3} MHz",
                        lo / 1e6,
                        hi / 1e6,
                        fs / 2e6
                    ),
                ));
            }
            // A band holding no FFT bin of the noise would silently give noiseless data.
            noise::band_bins(self.n_samples, fs, noise.band_hz)?;
        }
        let period = 1.0 / self.sequence.event_prf;
        let last = self.sequence.last_slot_start();
        if last > 0.0 {
            // The last slot fires `last` into the event; its echoes are listened to for as long
            // as the receive window lasts, which must end before the next event fires.
            let n = self.sequence.n_angles();
            let last_end = last + self.t0 + self.window_duration();
            if last_end > period {
                let name = match self.sequence.coding {
                    Coding::Hadamard { .. } => "slot delay",
                    _ => "slot delays",
                };
                return Err(invalid(
                    name,
                    format!(
                        "slot delay makes pulses overlap the next event's receive window: the last of \
                         {n} slots fires {:.2} µs into the event and its {:.2} µs receive window \
                         (t0 {:.2} µs) ends at {:.2} µs, after the next event fires at {:.2} µs",
                        last * 1e6,
                        self.window_duration() * 1e6,
                        self.t0 * 1e6,
                        last_end * 1e6,
                        period * 1e6
                    ),
                ));
            }
        }
        let window_end = self.t0 + self.window_duration();
        if window_end > period {
            return Err(invalid(
                "receive window",
                format!(
                    "it ends {:.2} µs after the event starts, after the next event fires at {:.2} µs \
                     (lower the depth or the event PRF)",
                    window_end * 1e6,
                    period * 1e6
                ),
            ));
        }
        Ok(())
    }
}

/// Receive window (t0 (s), samples) that holds, for every angle, slot offset and element, the
/// whole echo (down to `truncation` of its peak) of any point with depth in `depth` = (z_min,
/// z_max) (m) and lateral position within the array's aperture, sampled at `sampling_frequency`
/// (Hz). t0 is on the sample grid and never negative.
pub fn receive_window(
    probe: &Probe,
    sequence: &Sequence,
    (sampling_frequency, truncation): (f64, f64),
    sound_speed: f64,
    depth: (f64, f64),
) -> Result<(f64, usize)> {
    sequence.validate()?;
    require_positive("sampling frequency", sampling_frequency)?;
    require_positive("speed of sound", sound_speed)?;
    let (z0, z1) = depth;
    if !(z0.is_finite() && z1.is_finite() && z0 >= 0.0 && z0 < z1) {
        return Err(invalid(
            "depth range",
            format!(
                "({:.3}, {:.3}) mm must satisfy 0 ≤ z_min < z_max",
                z0 * 1e3,
                z1 * 1e3
            ),
        ));
    }
    let half =
        EchoWaveform::for_sequence_truncated(probe, sequence, sampling_frequency, truncation)?
            .half_duration();
    let c = sound_speed;
    let (x0, x1) = probe.aperture();
    let width = x1 - x0;
    let max_offset = sequence.last_slot_start();
    let min_cos = sequence
        .angles
        .iter()
        .map(|a| a.cos())
        .fold(f64::INFINITY, f64::min);
    let t_min = (z0 * min_cos + z0) / c - half;
    let tx_max = sequence
        .angles
        .iter()
        .map(|a| (width * a.sin().abs() + z1 * a.cos()) / c)
        .fold(0.0, f64::max);
    let t_max = max_offset + tx_max + width.hypot(z1) / c + half;
    let fs = sampling_frequency;
    let t0 = ((t_min * fs).floor() / fs).max(0.0);
    let samples = ((t_max - t0) * fs).ceil() as usize + 1;
    Ok((t0, samples))
}

/// Simulates `n_frames` compound frames (n_frames × n_angles transmit events) of `phantom` with
/// `params`: RF channel data, shape (events, channels, samples). Event i is simulated with the
/// scatterers at time i / event PRF (s). `progress(done_events, total_events)` is called after
/// each event. Same parameters and seed → bit-identical output, whatever the thread count.
pub fn simulate(
    phantom: &dyn Phantom,
    params: &SimParams,
    n_frames: usize,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<ChannelData> {
    let n_events = n_frames.saturating_mul(params.sequence.n_angles());
    Ok(ChannelData {
        acquisition: params.acquisition(),
        samples: Samples::Rf(simulate_events(
            phantom,
            params,
            n_frames,
            0..n_events,
            progress,
        )?),
    })
}

/// Events `events` (a range of transmit-event indices) of the recording of `n_frames` frames that
/// [`simulate`] makes, shape (events, channels, samples): the same samples, bit for bit, so that a
/// long recording can be simulated and written a block at a time. `progress(event index + 1,
/// events of the whole recording)` after each event.
pub fn simulate_events(
    phantom: &dyn Phantom,
    params: &SimParams,
    n_frames: usize,
    events: std::ops::Range<usize>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Array3<f32>> {
    simulate_events_reusing(phantom, params, n_frames, events, progress, None)
}

/// [`simulate_events`], made in `memory`'s memory where it has room (a block already written).
pub fn simulate_events_reusing(
    phantom: &dyn Phantom,
    params: &SimParams,
    n_frames: usize,
    events: std::ops::Range<usize>,
    progress: &(dyn Fn(usize, usize) + Sync),
    memory: Option<Array3<f32>>,
) -> Result<Array3<f32>> {
    params.validate()?;
    if n_frames == 0 {
        return Err(invalid("number of frames", "must be at least 1"));
    }
    let n = params.sequence.n_angles();
    let n_channels = params.probe.n_elements;
    let ns = params.n_samples;
    let n_events = n_frames
        .checked_mul(n)
        .filter(|e| e.checked_mul(n_channels * ns).is_some_and(|v| v <= isize::MAX as usize / 4))
        .ok_or_else(|| {
            invalid(
                "number of frames",
                format!("{n_frames} frames × {n} angles × {n_channels} channels × {ns} samples is too large"),
            )
        })?;
    if phantom.amplitudes().iter().any(|a| !a.is_finite()) {
        return Err(Error::NonFinite(
            "the phantom's scatterer amplitudes".into(),
        ));
    }
    let sim = Simulator::new(params)?;
    let mut scatterers = Snapshot::default();
    let load = |t: f64, out: &mut Snapshot| -> Result<()> {
        out.load(phantom, t)?;
        let n = phantom.n_scatterers();
        if out.positions.len() != n || !(out.elevations.is_empty() || out.elevations.len() == n) {
            return Err(Error::Shape(format!(
                "the phantom gave {} positions and {} elevations for {n} scatterers",
                out.positions.len(),
                out.elevations.len(),
            )));
        }
        if out
            .positions
            .iter()
            .flatten()
            .chain(&out.elevations)
            .any(|v| !v.is_finite())
        {
            return Err(Error::NonFinite(format!(
                "the phantom's scatterer positions at t = {t} s"
            )));
        }
        Ok(())
    };

    let noise = noise_generator(phantom, params, &sim, &mut scatterers, &load)?;

    if events.start > events.end || events.end > n_events {
        return Err(invalid(
            "events",
            format!("{events:?} is not within the recording's {n_events} events"),
        ));
    }
    let mut rf: Array3<f32> =
        crate::core::buffers::zeros_reusing(memory, (events.len(), n_channels, ns));
    let prepare = |event: usize, scatterers: &mut Snapshot| -> Result<kernel::EventScatterers> {
        load(event as f64 / params.sequence.event_prf, scatterers)?;
        let slots: Vec<Slot> = params
            .sequence
            .event_pulses(event)
            .into_iter()
            .map(|(k, polarity, offset)| Slot {
                angle: params.sequence.angles[k],
                polarity,
                offset,
            })
            .collect();
        Ok(sim.prepare(scatterers, phantom.amplitudes(), &slots))
    };
    // An event's scatterers are moved and their transmit part computed (mostly one thread's work,
    // a tenth of a single-angle event's time) while the event before renders on the other
    // threads, so that no core waits for it; the traces are the same whatever the order.
    let mut next = match events.clone().next() {
        Some(first) => Some(prepare(first, &mut scatterers)?),
        None => None,
    };
    for (event, out) in events.clone().zip(rf.axis_iter_mut(Axis(0))) {
        let ev = next
            .take()
            .expect("each event is prepared before it renders");
        let streams = noise
            .as_ref()
            .map(|g| (g, event as u64 * n_channels as u64));
        let ((), following) = rayon::join(
            || sim.render_prepared(&ev, out, streams),
            || {
                (event + 1 < events.end)
                    .then(|| prepare(event + 1, &mut scatterers))
                    .transpose()
            },
        );
        next = following?;
        progress(event + 1, n_events);
    }
    Ok(rf)
}

/// The scatterers of a phantom at one time: in-plane positions (x, z) and, for a phantom in
/// three dimensions, elevations y (m; empty when every scatterer lies in the plane).
#[derive(Debug, Default)]
pub(crate) struct Snapshot {
    pub(crate) positions: Vec<[f64; 2]>,
    pub(crate) elevations: Vec<f64>,
}

impl Snapshot {
    pub(crate) fn load(&mut self, phantom: &dyn Phantom, t: f64) -> Result<()> {
        phantom.positions_at(t, &mut self.positions);
        phantom.elevations_at(t, &mut self.elevations);
        Ok(())
    }
}

/// Fills the scatterers at a time (s), checking them.
type PositionLoader<'a> = dyn Fn(f64, &mut Snapshot) -> Result<()> + 'a;

/// The RMS of the noiseless, uncoded 0° echo of `phantom` at t = 0 over all channels and the
/// receive window of `params`: the reference of the noise level ([`NOISE_DEFINITION`]). For
/// another phantom (tissue beside blood, say), it says how their echoes compare.
pub fn reference_echo_rms(phantom: &dyn Phantom, params: &SimParams) -> Result<f64> {
    let sim = Simulator::new(params)?;
    let mut scatterers = Snapshot::default();
    scatterers.load(phantom, 0.0)?;
    Ok(zero_degree_rms(phantom, params, &sim, &scatterers))
}

/// The RMS of the 0° echo of `scatterers` (with `phantom`'s amplitudes) through `sim`.
fn zero_degree_rms(
    phantom: &dyn Phantom,
    params: &SimParams,
    sim: &Simulator,
    scatterers: &Snapshot,
) -> f64 {
    let mut reference = ndarray::Array2::<f32>::zeros((params.probe.n_elements, params.n_samples));
    let slot = Slot {
        angle: 0.0,
        polarity: 1.0,
        offset: 0.0,
    };
    sim.render_event(
        scatterers,
        phantom.amplitudes(),
        &[slot],
        reference.view_mut(),
        None,
    );
    let power = reference.iter().map(|&v| (v as f64).powi(2)).sum::<f64>() / reference.len() as f64;
    power.sqrt()
}

/// The noise source of `params` (see [`NOISE_DEFINITION`]): its RMS is set from the noiseless,
/// uncoded 0° echo of `phantom` at t = 0. `None` when `params.noise` is `None`.
fn noise_generator(
    phantom: &dyn Phantom,
    params: &SimParams,
    sim: &Simulator,
    scatterers: &mut Snapshot,
    load: &PositionLoader,
) -> Result<Option<noise::NoiseGenerator>> {
    let ns = params.n_samples;
    Ok(match &params.noise {
        None => None,
        Some(spec) => {
            load(0.0, scatterers)?;
            let rms = zero_degree_rms(phantom, params, sim, scatterers);
            if !(rms > 0.0 && rms.is_finite()) {
                return Err(invalid(
                    "noise level",
                    "the phantom's noiseless 0° echo is zero in the receive window (do its \
                     scatterers lie within the receive depths?), so a noise level relative to it \
                     is undefined",
                ));
            }
            let noise_rms = rms * 10f64.powf(spec.level_db / 20.0);
            // The samples are single precision: noise whose peaks (a few RMS) overflow it would
            // write infinities.
            if noise_rms.is_nan() || noise_rms * 10.0 >= f32::MAX as f64 {
                return Err(invalid(
                    "noise level",
                    format!(
                        "{} dB re the echo gives noise of RMS {noise_rms:.3e}, beyond the single \
                         precision of the samples",
                        spec.level_db
                    ),
                ));
            }
            Some(noise::NoiseGenerator::new(
                ns,
                params.sampling_frequency,
                spec.band_hz,
                noise_rms,
                params.seed,
            )?)
        }
    })
}

/// The receiver noise alone that [`simulate`] adds to each event with the same `params` (same
/// seed, same streams, same level relative to the phantom's echo), shape (events, channels,
/// samples). Since every processing step up to the Doppler estimate is linear, echoes and noise
/// can be processed apart and added at any scale, e.g. for a sweep of noise levels.
pub fn simulate_noise(
    phantom: &dyn Phantom,
    params: &SimParams,
    n_frames: usize,
) -> Result<ChannelData> {
    let n_events = n_frames.saturating_mul(params.sequence.n_angles());
    Ok(ChannelData {
        acquisition: params.acquisition(),
        samples: Samples::Rf(simulate_noise_events(
            phantom,
            params,
            n_frames,
            0..n_events,
        )?),
    })
}

/// Events `events` of the noise [`simulate_noise`] makes for a recording of `n_frames` frames,
/// shape (events, channels, samples): the same samples, bit for bit, a block at a time.
pub fn simulate_noise_events(
    phantom: &dyn Phantom,
    params: &SimParams,
    n_frames: usize,
    events: std::ops::Range<usize>,
) -> Result<Array3<f32>> {
    simulate_noise_events_reusing(phantom, params, n_frames, events, None)
}

/// [`simulate_noise_events`], made in `memory`'s memory where it has room.
pub fn simulate_noise_events_reusing(
    phantom: &dyn Phantom,
    params: &SimParams,
    n_frames: usize,
    events: std::ops::Range<usize>,
    memory: Option<Array3<f32>>,
) -> Result<Array3<f32>> {
    params.validate()?;
    if n_frames == 0 {
        return Err(invalid("number of frames", "must be at least 1"));
    }
    if params.noise.is_none() {
        return Err(invalid(
            "noise level",
            "simulate_noise needs a noise specification",
        ));
    }
    let (n_channels, ns) = (params.probe.n_elements, params.n_samples);
    let n_events = n_frames.saturating_mul(params.sequence.n_angles());
    if events.start > events.end || events.end > n_events {
        return Err(invalid(
            "events",
            format!("{events:?} is not within the recording's {n_events} events"),
        ));
    }
    let sim = Simulator::new(params)?;
    let mut scatterers = Snapshot::default();
    let load = |t: f64, out: &mut Snapshot| out.load(phantom, t);
    let generator = noise_generator(phantom, params, &sim, &mut scatterers, &load)?
        .expect("noise is specified");
    let first = events.start;
    let mut rf: Array3<f32> =
        crate::core::buffers::zeros_reusing(memory, (events.len(), n_channels, ns));
    rf.axis_iter_mut(Axis(0))
        .into_par_iter()
        .enumerate()
        .for_each(|(i, mut out)| {
            let event = first + i;
            for (channel, mut trace) in out.axis_iter_mut(Axis(0)).enumerate() {
                let trace = trace.as_slice_mut().expect("standard layout");
                generator.add(trace, (event * n_channels + channel) as u64);
            }
        });
    Ok(rf)
}

/// Echo arrival time (s, relative to the record's first sample) of a scatterer at (x, z) (m) for a
/// pulse steered by `angle` fired `slot_offset` (s) into the event, on the element at `element_x`:
/// the centre of its [`EchoWaveform`].
pub fn echo_time(
    params: &SimParams,
    x: f64,
    z: f64,
    angle: f64,
    slot_offset: f64,
    element_x: f64,
) -> f64 {
    let aperture = params.probe.aperture();
    slot_offset + round_trip_delay(x, z, angle, element_x, aperture, params.sound_speed) - params.t0
}
