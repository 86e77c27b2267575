//! Slowly moving tissue simulated at keyframes: its echoes rendered once per keyframe and pulse
//! slot, then interpolated to every event's time.
//!
//! Tissue holds 10⁵–10⁶ scatterers, a hundred times the blood, but moves a thousand times slower
//! (tens of µm at 1–6 Hz: below 1 mm/s). Between two events 70 µs apart its echoes barely change,
//! so rendering them at every event wastes almost all the work. Instead, the echo of every pulse
//! slot (angle, start within the event) is rendered alone, with polarity +1, at keyframes Δ
//! apart; an event's tissue echo is then, for each of its slots, the cubic (four-point Lagrange)
//! interpolation of that slot's keyframes at the event's time, times the slot's polarity, summed.
//! The echoes are linear in the scatterers' amplitudes and in the slots, so this is exact but for
//! the interpolation.
//!
//! # Error
//! At a given sample, the echo of tissue moving at speed v along the beam turns in phase at
//! 2 k v rad/s. Cubic interpolation of a phasor turning by φ between keyframes errs by about
//! φ⁴ / 40 of its amplitude. [`keyframe_interval`] sets φ = 0.3 rad at the tissue's fastest
//! speed: an error near 2·10⁻⁴ (−74 dB) of the tissue echo, 34 dB below blood that is 40 dB
//! fainter than the tissue; the tests measure it against a direct simulation. Per recording of
//! n angles, F frames and K keyframes it renders n·K single slots where the direct simulation
//! renders n·F events of n slots each (coded) or F·n single slots (conventional).

use std::collections::HashMap;

use ndarray::{Array2, Array3, ArrayView2, ArrayViewMut3, Axis, Zip, s};
use rayon::prelude::*;

use super::kernel::{Simulator, Slot};
use super::phantom::Phantom;
use super::{SimParams, Snapshot, simulate_events};
use crate::core::error::{Result, invalid, require_positive};

/// Phase (rad) the fastest tissue echo may turn between keyframes.
const PHASE_PER_KEYFRAME: f64 = 0.3;

/// Interval (s) between keyframes for tissue moving at most `max_speed` (m/s) at wavelength
/// `wavelength` (m): the echo's phase turns by at most 0.3 rad between them (see the module
/// docs). Infinite for still tissue.
pub fn keyframe_interval(max_speed: f64, wavelength: f64) -> f64 {
    if max_speed <= 0.0 {
        // Also −0.0, the empty sum of a motion without oscillations.
        return f64::INFINITY;
    }
    let k = 2.0 * std::f64::consts::PI / wavelength;
    PHASE_PER_KEYFRAME / (2.0 * k * max_speed)
}

/// Events `events` of a recording of `n_frames` frames of `blood` and `tissue` together:
/// the blood simulated at every event (with the noise of `params`, relative to the blood's own
/// echo), the tissue rendered at keyframes `interval` (s) apart and interpolated (see the module
/// docs). Shape (events, channels, samples). `progress(done, total)` counts the blood's events.
/// A fresh [`TissueKeyframes`]; keep one across calls to reuse its keyframes.
pub fn simulate_events_with_tissue(
    blood: &dyn Phantom,
    tissue: &dyn Phantom,
    params: &SimParams,
    n_frames: usize,
    events: std::ops::Range<usize>,
    interval: f64,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Array3<f32>> {
    let mut rf = simulate_events(blood, params, n_frames, events.clone(), progress)?;
    TissueKeyframes::new(interval, params.sequence.last_slot_start()).add(
        tissue,
        params,
        events,
        rf.view_mut(),
    )?;
    Ok(rf)
}

/// A slot's keyframe: rendered at slot start 0 and shifted by a whole number of samples when
/// its start is one (so that every slot of every mode that fires the same angle shares it), or
/// rendered at its own start.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
enum SlotKey {
    /// Angle index; the slot's start is a whole number of samples.
    Shifted(usize),
    /// Angle index and the bits of its start (s).
    At(usize, u64),
}

/// The tissue's keyframes, kept between calls: consecutive blocks of a recording, and the
/// conventional and coded recordings of the same tissue, render each keyframe once.
///
/// Keyframes are rendered over the receive window grown `lead` (s) earlier, so that a slot
/// starting up to `lead` into the event is its angle's echo shifted by whole samples, exactly.
/// Keyframes before those a call needs are dropped, so memory follows the block, not the
/// recording: simulate the modes block by block (the same events of each in turn).
pub struct TissueKeyframes {
    interval: f64,
    lead: f64,
    /// What the keyframes were rendered with: the recording's settings but for its coding (the
    /// slots' starts are part of each keyframe's key), noise and seed, which a keyframe does not
    /// depend on.
    rendered_for: Option<SimParams>,
    echoes: HashMap<(i64, SlotKey), Array2<f32>>,
}

impl TissueKeyframes {
    /// Keyframes `interval` (s) apart (infinite: still tissue, one keyframe) for slots starting
    /// up to `lead` (s) into their event (the latest slot start of every mode to be simulated).
    pub fn new(interval: f64, lead: f64) -> Self {
        TissueKeyframes {
            interval,
            lead: lead.max(0.0),
            rendered_for: None,
            echoes: HashMap::new(),
        }
    }

    /// Adds to `rf` (events × channels × samples) the echo of `tissue` for events `events` of
    /// the recording `params` describes.
    pub fn add(
        &mut self,
        tissue: &dyn Phantom,
        params: &SimParams,
        events: std::ops::Range<usize>,
        mut rf: ArrayViewMut3<f32>,
    ) -> Result<()> {
        if rf.dim().0 != events.len() {
            return Err(invalid(
                "events",
                format!("{} events for a block of {}", events.len(), rf.dim().0),
            ));
        }
        if events.is_empty() || tissue.n_scatterers() == 0 {
            return Ok(());
        }
        let interval = self.interval;
        // Still tissue (an infinite interval) needs one keyframe, at t = 0.
        let still = interval == f64::INFINITY;
        if !still {
            require_positive("keyframe interval", interval)?;
        }
        let fs = params.sampling_frequency;
        let lead_samples = (self.lead * fs).ceil() as usize;
        let mut rendering = params.clone();
        rendering.sequence.coding = crate::acquisition::sequence::Coding::Conventional;
        rendering.noise = None;
        rendering.seed = 0;
        if self.rendered_for.as_ref() != Some(&rendering) {
            self.echoes.clear();
            self.rendered_for = Some(rendering);
        }
        let prf = params.sequence.event_prf;
        // Keyframes closer together than the events (tissue faster than about 3 cm/s at 15.6
        // MHz and 14.4 kHz) are rendered one at each event's start instead: every event then
        // falls on a keyframe (weights 0, 1, 0, 0), and its echo is its own, as the blood's is.
        let interval = if !still && interval < 1.0 / prf {
            1.0 / prf
        } else {
            interval
        };
        let position = |event: usize| {
            if still {
                0.0
            } else {
                event as f64 / prf / interval
            }
        };
        // Keyframes j·Δ from one before the first event's to two after the last's.
        let (first, last) = if still {
            (0, 0)
        } else {
            (
                position(events.start).floor() as i64 - 1,
                position(events.end - 1).floor() as i64 + 2,
            )
        };
        if last - first > 1_000_000 {
            return Err(invalid(
                "keyframe interval",
                format!("{interval} s gives more than a million keyframes for these events"),
            ));
        }
        self.echoes.retain(|&(j, _), _| j >= first);
        // Where each slot's keyframe comes from, and by how many samples it is shifted.
        let key = |k: usize, offset: f64| -> (SlotKey, usize) {
            let n = (offset * fs).round();
            if (offset * fs - n).abs() < 1e-6 && n >= 0.0 && n as usize <= lead_samples {
                (SlotKey::Shifted(k), n as usize)
            } else {
                (SlotKey::At(k, offset.to_bits()), 0)
            }
        };
        let mut slots: Vec<SlotKey> = Vec::new();
        for event in events.clone() {
            for (k, _, offset) in params.sequence.event_pulses(event) {
                let (slot, _) = key(k, offset);
                if !slots.contains(&slot) {
                    slots.push(slot);
                }
            }
        }
        // Rendered over the window grown `lead_samples` earlier; an `At` slot's lead is unused.
        let mut grown = params.clone();
        grown.t0 -= lead_samples as f64 / fs;
        grown.n_samples += lead_samples;
        let mut sim: Option<Simulator> = None;
        let amplitudes = tissue.amplitudes();
        let shape = (params.probe.n_elements, grown.n_samples);
        let mut scatterers = Snapshot::default();
        for j in first..=last {
            let missing: Vec<SlotKey> = slots
                .iter()
                .copied()
                .filter(|&slot| !self.echoes.contains_key(&(j, slot)))
                .collect();
            if missing.is_empty() {
                continue;
            }
            let sim = match &mut sim {
                Some(sim) => sim,
                None => sim.insert(Simulator::new(&grown)?),
            };
            scatterers.load(tissue, if still { 0.0 } else { j as f64 * interval })?;
            for slot in missing {
                let (k, offset) = match slot {
                    SlotKey::Shifted(k) => (k, 0.0),
                    SlotKey::At(k, bits) => (k, f64::from_bits(bits)),
                };
                let pulse = Slot {
                    angle: params.sequence.angles[k],
                    polarity: 1.0,
                    offset,
                };
                let mut echo = Array2::<f32>::zeros(shape);
                sim.render_event(&scatterers, amplitudes, &[pulse], echo.view_mut(), None);
                self.echoes.insert((j, slot), echo);
            }
        }
        let ns = params.n_samples;
        for (event, mut out) in events.clone().zip(rf.axis_iter_mut(Axis(0))) {
            let u = position(event);
            let j = u.floor() as i64;
            let weights = lagrange_cubic(u - j as f64);
            // Every keyframe echo this event adds, with its weight, in the order they add.
            let mut terms: Vec<(ArrayView2<'_, f32>, f32)> = Vec::new();
            for (k, polarity, offset) in params.sequence.event_pulses(event) {
                let (slot, shift) = key(k, offset);
                // Sample i of the slot's echo is sample i + lead − shift of its keyframe (a
                // shifted slot), or sample i + lead of one rendered at its own start.
                let from = lead_samples - shift;
                // Nodes of weight 0 (all but one at a keyframe, or for still tissue) may not exist.
                for (node, w) in (-1..=2).zip(weights).filter(|&(_, w)| w != 0.0) {
                    let echo = &self.echoes[&(j + node, slot)];
                    terms.push((echo.slice(s![.., from..from + ns]), w as f32 * polarity));
                }
            }
            // A channel at a time, every term in turn while its trace is in cache: each sample
            // sums the same products in the same order as one pass per term would.
            out.axis_iter_mut(Axis(0))
                .into_par_iter()
                .enumerate()
                .for_each(|(channel, mut trace)| {
                    for (echo, scale) in &terms {
                        Zip::from(&mut trace)
                            .and(echo.row(channel))
                            .for_each(|o, &e| *o += scale * e);
                    }
                });
        }
        Ok(())
    }
}

/// Fewest events between two keyframes of blood rendered at keyframes: closer, they would hold
/// too many echoes in memory for what they save.
const MIN_EVENTS_PER_KEYFRAME: f64 = 2.0;

/// The fixed part of rendering one slot on one channel, per sample of the receive window, in
/// units of one scatterer's echo: the trace's convolution with the waveform and the event's
/// set-up. Measured on the L22-14vX (2-cycle pulse, 65 MHz, 1,297 samples): a render took
/// 7.8 ms plus 1.06 µs per scatterer, 7,400 scatterers' worth, about 6 per sample.
const RENDER_COST_PER_SAMPLE: f64 = 6.0;

/// Most bytes of keyframes [`KeyframedBlood::add`] holds at once, whatever the range it adds.
pub const KEYFRAME_BYTES: usize = 256 << 20;

/// Speed classes of blood: each spans a factor of two in speed, from the fastest scatterer's.
const MAX_SPEED_CLASSES: usize = 16;

/// Blood rendered at keyframes by speed class: the keyframing of [`TissueKeyframes`] applied to
/// blood, whose speeds span three decades (capillaries below 1 mm/s, arterioles tens of mm/s).
///
/// Scatterers are grouped by a bound on their speed into classes a factor of two apart. Runs of
/// neighbouring classes are then rendered together, at the keyframes of their fastest speed
/// (the interval [`keyframe_interval`] gives: the echo turns by at most 0.3 rad between them),
/// or at every event, whichever costs less: a keyframe renders every angle alone, so its fixed
/// cost (a convolution per channel) pays only for enough scatterers, and keyframes closer than
/// 2 events are not used. The cubic interpolation errs by about 2·10⁻⁴ of each keyframed
/// scatterer's echo (−74 dB; see the module docs), far below the receiver noise. What it
/// changes: a scatterer that leaves its segment re-enters at the other end (see
/// [`super::phantom::TreePhantom`]); rendered at every event it jumps between two events,
/// interpolated it fades from one end to the other over the four keyframes around the jump.
/// Either way blood appears and disappears there; the keyframes spread it over up to four
/// keyframe intervals of its class (2.6 % RMS of the small rat brain's blood echo).
pub struct KeyframedBlood {
    /// Scatterers rendered at every event.
    direct: Vec<usize>,
    /// Speed classes rendered at keyframes.
    classes: Vec<SpeedClass>,
    /// The fastest scatterer's speed bound (m/s).
    fastest: f64,
}

/// One speed class of [`KeyframedBlood`].
struct SpeedClass {
    /// Fastest speed of the class (m/s).
    bound: f64,
    scatterers: Vec<usize>,
    keyframes: TissueKeyframes,
}

/// What [`KeyframedBlood`] renders how: one entry per class, fastest first.
#[derive(Debug, Clone, PartialEq)]
pub struct BloodClass {
    /// Fastest speed of the class (m/s).
    pub max_speed_m_s: f64,
    /// Time between its keyframes (s); `None`: rendered at every event.
    pub keyframe_interval_s: Option<f64>,
    /// Scatterers in it.
    pub scatterers: usize,
}

impl KeyframedBlood {
    /// Classes for scatterers whose speeds never exceed `speed_bounds` (m/s, one per scatterer,
    /// in the phantom's order), for recordings of `n_frames` frames in each of `modes` (the same
    /// probe and window; their events set the costs, their slot starts the keyframes' lead).
    pub fn new(speed_bounds: &[f64], modes: &[&SimParams], n_frames: usize) -> Result<Self> {
        let Some(first) = modes.first() else {
            return Err(invalid("recordings", "keyframed blood needs at least one"));
        };
        if let Some(bad) = speed_bounds.iter().find(|v| !(v.is_finite() && **v >= 0.0)) {
            return Err(invalid(
                "blood speed bound",
                format!("must be finite and ≥ 0, got {bad}"),
            ));
        }
        let wavelength = first.probe.wavelength(first.sound_speed);
        let event_period = modes
            .iter()
            .map(|p| 1.0 / p.sequence.event_prf)
            .fold(f64::INFINITY, f64::min);
        let lead = modes
            .iter()
            .map(|p| p.sequence.last_slot_start())
            .fold(0.0, f64::max);
        let fastest = speed_bounds.iter().copied().fold(0.0, f64::max);
        // Class c holds speeds in (fastest / 2^(c+1), fastest / 2^c]; the last, everything slower.
        let class_of = |v: f64| -> usize {
            if v <= 0.0 || fastest <= 0.0 {
                return MAX_SPEED_CLASSES - 1;
            }
            ((fastest / v).log2().floor().max(0.0) as usize).min(MAX_SPEED_CLASSES - 1)
        };
        let mut members = vec![Vec::new(); MAX_SPEED_CLASSES];
        for (i, &v) in speed_bounds.iter().enumerate() {
            members[class_of(v)].push(i);
        }
        let bound = |c: usize| fastest / f64::powi(2.0, c as i32);
        // What each way costs, per channel, in single-slot echoes (see `RENDER_COST_PER_SAMPLE`).
        let duration = modes
            .iter()
            .map(|p| n_frames as f64 * p.sequence.n_angles() as f64 / p.sequence.event_prf)
            .fold(0.0, f64::max);
        let per_scatterer_direct: f64 = modes
            .iter()
            .map(|p| {
                let events = (n_frames * p.sequence.n_angles()) as f64;
                let slots = p.sequence.event_pulses(0).len() as f64;
                events * slots
            })
            .sum();
        let angles = modes
            .iter()
            .map(|p| p.sequence.n_angles())
            .max()
            .unwrap_or(1) as f64;
        let window = (first.n_samples as f64 + (lead * first.sampling_frequency).ceil()).max(1.0);
        let keyframed = |fastest_class: usize, scatterers: usize| -> Option<f64> {
            let interval = keyframe_interval(bound(fastest_class), wavelength);
            (interval >= MIN_EVENTS_PER_KEYFRAME * event_period).then(|| {
                let keyframes = (duration / interval).ceil() + 3.0;
                keyframes * angles * (scatterers as f64 + RENDER_COST_PER_SAMPLE * window)
            })
        };
        // The cheapest split of the classes (fastest first) into runs, each rendered at every
        // event or at the keyframes of its fastest class: cost[j] covers classes 0..j.
        let counts: Vec<usize> = members.iter().map(Vec::len).collect();
        let mut cost = [0.0f64; MAX_SPEED_CLASSES + 1];
        let mut choice = [None; MAX_SPEED_CLASSES + 1];
        for j in 1..=MAX_SPEED_CLASSES {
            cost[j] = cost[j - 1] + counts[j - 1] as f64 * per_scatterer_direct;
            for i in 0..j {
                let n: usize = counts[i..j].iter().sum();
                if n == 0 {
                    continue;
                }
                if let Some(c) = keyframed(i, n).map(|c| cost[i] + c)
                    && c < cost[j]
                {
                    cost[j] = c;
                    choice[j] = Some(i);
                }
            }
        }
        let mut direct = Vec::new();
        let mut classes = Vec::new();
        let mut j = MAX_SPEED_CLASSES;
        while j > 0 {
            match choice[j] {
                None => {
                    direct.extend_from_slice(&members[j - 1]);
                    j -= 1;
                }
                Some(i) => {
                    let mut scatterers: Vec<usize> =
                        members[i..j].iter().flatten().copied().collect();
                    scatterers.sort_unstable();
                    classes.push(SpeedClass {
                        bound: bound(i),
                        scatterers,
                        keyframes: TissueKeyframes::new(
                            keyframe_interval(bound(i), wavelength),
                            lead,
                        ),
                    });
                    j = i;
                }
            }
        }
        classes.reverse();
        direct.sort_unstable();
        Ok(KeyframedBlood {
            direct,
            classes,
            fastest,
        })
    }

    /// The classes, fastest first: those rendered at every event as one.
    pub fn classes(&self) -> Vec<BloodClass> {
        let mut out = Vec::new();
        if !self.direct.is_empty() {
            out.push(BloodClass {
                max_speed_m_s: self.fastest,
                keyframe_interval_s: None,
                scatterers: self.direct.len(),
            });
        }
        out.extend(self.classes.iter().map(|c| BloodClass {
            max_speed_m_s: c.bound,
            keyframe_interval_s: Some(c.keyframes.interval),
            scatterers: c.scatterers.len(),
        }));
        out
    }

    /// Bytes the keyframes hold while a block of `events` events of the recording `params`
    /// describes is simulated: each class's keyframes over the block and the four around it.
    pub fn keyframe_bytes(&self, params: &SimParams, events: usize) -> usize {
        let span = events as f64 / params.sequence.event_prf;
        let lead = self.classes.first().map_or(0.0, |c| c.keyframes.lead);
        let echo = params.probe.n_elements
            * (params.n_samples + (lead * params.sampling_frequency).ceil() as usize)
            * std::mem::size_of::<f32>();
        self.classes
            .iter()
            .map(|c| {
                let keyframes = (span / c.keyframes.interval).ceil() as usize + 4;
                keyframes * params.sequence.n_angles() * echo
            })
            .sum()
    }

    /// Adds to `rf` (events × channels × samples) the noiseless echo of `blood` (the phantom
    /// whose speed bounds made the classes) for events `events` of the recording of `n_frames`
    /// frames that `params` describes. Keyframes are kept for the next call, as
    /// [`TissueKeyframes::add`] keeps them: simulate the modes block by block.
    pub fn add(
        &mut self,
        blood: &dyn Phantom,
        params: &SimParams,
        n_frames: usize,
        events: std::ops::Range<usize>,
        mut rf: ArrayViewMut3<f32>,
    ) -> Result<()> {
        let n = blood.n_scatterers();
        let counted = self.direct.len()
            + self
                .classes
                .iter()
                .map(|c| c.scatterers.len())
                .sum::<usize>();
        if counted != n {
            return Err(invalid(
                "blood",
                format!("{n} scatterers, but the speed classes were made for {counted}"),
            ));
        }
        if !self.direct.is_empty() {
            let subset = Subset::new(blood, &self.direct);
            let mut noiseless = params.clone();
            noiseless.noise = None;
            let echoes =
                simulate_events(&subset, &noiseless, n_frames, events.clone(), &|_, _| {})?;
            rf += &echoes;
        }
        // A long range is added a part at a time, so that the keyframes held stay within
        // `KEYFRAME_BYTES` (blocks that fit keep every class's keyframes for the next mode).
        let mut part = events.len().max(1);
        while part > 1 && self.keyframe_bytes(params, part) > KEYFRAME_BYTES {
            part = part.div_ceil(2);
        }
        for class in &mut self.classes {
            let subset = Subset::new(blood, &class.scatterers);
            for start in events.clone().step_by(part) {
                let end = (start + part).min(events.end);
                let rows = start - events.start..end - events.start;
                class
                    .keyframes
                    .add(&subset, params, start..end, rf.slice_mut(s![rows, .., ..]))?;
            }
        }
        Ok(())
    }
}

/// Some of a phantom's scatterers, alone (in their order in `indices`).
struct Subset<'a> {
    inner: &'a dyn Phantom,
    indices: &'a [usize],
    amplitudes: Vec<f64>,
}

impl<'a> Subset<'a> {
    fn new(inner: &'a dyn Phantom, indices: &'a [usize]) -> Self {
        let all = inner.amplitudes();
        Subset {
            inner,
            indices,
            amplitudes: indices.iter().map(|&i| all[i]).collect(),
        }
    }
}

impl Phantom for Subset<'_> {
    fn amplitudes(&self) -> &[f64] {
        &self.amplitudes
    }

    fn positions_at(&self, t: f64, out: &mut Vec<[f64; 2]>) {
        let mut all = Vec::new();
        self.inner.positions_at(t, &mut all);
        out.clear();
        out.extend(self.indices.iter().map(|&i| all[i]));
    }

    fn elevations_at(&self, t: f64, out: &mut Vec<f64>) {
        let mut all = Vec::new();
        self.inner.elevations_at(t, &mut all);
        out.clear();
        if !all.is_empty() {
            out.extend(self.indices.iter().map(|&i| all[i]));
        }
    }

    /// The whole phantom's truth: a subset has no truth of its own.
    fn truth(&self, x: &[f64], z: &[f64], t: f64) -> crate::simulate::phantom::Truth {
        self.inner.truth(x, z, t)
    }
}

/// Weights of the four-point Lagrange interpolation at nodes −1, 0, 1, 2 for a point `u` ∈ [0, 1).
fn lagrange_cubic(u: f64) -> [f64; 4] {
    [
        -u * (u - 1.0) * (u - 2.0) / 6.0,
        (u + 1.0) * (u - 1.0) * (u - 2.0) / 2.0,
        -(u + 1.0) * u * (u - 2.0) / 2.0,
        (u + 1.0) * u * (u - 1.0) / 6.0,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cubic_weights_reproduce_cubics() {
        for u in [0.0, 0.25, 0.6, 0.99] {
            let w = lagrange_cubic(u);
            let poly = |x: f64| 2.0 - x + 0.5 * x * x - 0.3 * x * x * x;
            let interpolated: f64 = (-1..=2).zip(w).map(|(n, w)| w * poly(n as f64)).sum();
            assert!((interpolated - poly(u)).abs() < 1e-12);
        }
        assert_eq!(lagrange_cubic(0.0), [0.0, 1.0, 0.0, 0.0]);
    }

    #[test]
    fn the_interval_turns_the_fastest_echo_by_a_third_of_a_radian() {
        let wavelength = 1540.0 / 15.625e6;
        let interval = keyframe_interval(0.4e-3, wavelength);
        let phase = 2.0 * (2.0 * std::f64::consts::PI / wavelength) * 0.4e-3 * interval;
        assert!((phase - 0.3).abs() < 1e-12);
        assert_eq!(keyframe_interval(0.0, wavelength), f64::INFINITY);
        assert_eq!(keyframe_interval(-0.0, wavelength), f64::INFINITY);
    }
}
