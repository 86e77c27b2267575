//! The simulator's inner loops: one transmit event → one trace per channel.
//!
//! Per event, the transmit part (delay, polarity × transmit field × scatterer amplitude) is computed
//! once per scatterer and slot. Per channel, scatterers are processed in blocks: branch-free,
//! 8-wide f32 passes compute the receive delay and amplitude of every scatterer of the block
//! (polynomial approximations), then each echo (per slot) is *accumulated*, not drawn: an echo
//! whose row starts at sample n with sub-sample delay μ adds a·(μ − ½)^q, q = 0..7, to row n of an
//! 8-wide accumulator (one vector add per echo). One convolution of the accumulator with the
//! waveform's Farrow coefficients (each tap a degree-7 polynomial in μ − ½) then gives the trace:
//! O(1) work per echo and O(samples × taps) per channel, whatever the number of scatterers and
//! slots.
//!
//! One file of about 940 lines before its tests, kept whole on purpose: the block passes, the
//! accumulator's insertion (portable and AVX2) and the convolution share one data layout (the
//! block size, the 8-wide rows, the Farrow terms), and each loop's speed rests on assumptions the
//! others make.

use ndarray::{ArrayViewMut2, Axis};
use rayon::prelude::*;

use super::elevation::ElevationTable;
use super::noise::NoiseGenerator;
use super::waveform::{EchoWaveform, FARROW_TERMS};
use super::{SimParams, Snapshot};
use crate::core::error::{Result, invalid};
use crate::core::simd::Level;

/// CPUs (vendor, family, model) on which the render's AVX2 path is faster than its AVX-512 one,
/// as measured: Intel's Ice Lake server (family 6 model 106), the spiral's echoes 612–632 ns
/// each in AVX2 against 679–701 in AVX-512 (four alternating benches), its whole simulation 0.75–
/// 0.86 s against 0.83–0.93 s and 11 % less CPU. Both paths give the same samples to the bit, so
/// the choice changes only the time. (Other Intel server CPUs of its generation or the one before
/// may belong here; none was measured. Intel's family 6 model 167 ran AVX-512 faster.)
const AVX2_RENDER_CPUS: [(&[u8; 12], u32, u32); 1] = [(b"GenuineIntel", 6, 106)];

/// The vector instructions the simulator's render uses in this process: the kernels' level
/// ([`crate::core::simd::level`]), AVX2 instead of AVX-512 on the CPUs of [`AVX2_RENDER_CPUS`];
/// decided once, as the kernels' level is.
pub fn render_level() -> Level {
    static RENDER_LEVEL: std::sync::OnceLock<Level> = std::sync::OnceLock::new();
    *RENDER_LEVEL.get_or_init(|| {
        let level = crate::core::simd::level();
        let narrower_faster =
            crate::core::simd::cpu_identity().is_some_and(|(vendor, family, model)| {
                AVX2_RENDER_CPUS
                    .iter()
                    .any(|&(v, f, m)| *v == vendor && f == family && m == model)
            });
        if level == Level::Avx512 && narrower_faster {
            Level::Avx2
        } else {
            level
        }
    })
}

/// One pulse slot of an event: steering angle (rad), polarity (±1) and start within the event (s).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Slot {
    pub(crate) angle: f64,
    pub(crate) polarity: f32,
    pub(crate) offset: f64,
}

/// Scatterers of one event that some slot insonifies, structure-of-arrays.
pub(crate) struct EventScatterers {
    /// Lateral positions (m).
    xs: Vec<f32>,
    /// Depths (m).
    zs: Vec<f32>,
    /// Per slot and scatterer (slot-major): where the echo row starts in the padded trace buffer
    /// before the receive delay (samples), integer part.
    tx_int: Vec<i32>,
    /// Fractional part of the same, in [0, 1] (samples).
    tx_frac: Vec<f32>,
    /// Per slot and scatterer (slot-major): scatterer amplitude × polarity × transmit field.
    tx_amp: Vec<f32>,
    /// Per slot and scatterer (slot-major): transmit path z / cos θ (m), for the echo's spectrum.
    tx_path: Vec<f32>,
    slots: usize,
}

/// One channel task's working memory: the Farrow accumulators (one per spectral band, each
/// n_samples + taps + 1 rows), the rows each may hold, and one band's trace.
struct Scratch {
    impulses: Vec<[f32; FARROW_TERMS]>,
    written: Vec<std::ops::Range<usize>>,
    band_trace: Vec<f32>,
}

/// Rows beyond the record within which a scatterer's echo is still rendered (dropped beyond):
/// more than the receive path's f32 rounding and the row's rounding can move it.
const RECORD_MARGIN_ROWS: f64 = 4.0;

/// Scatterers per block of the per-channel loop.
const BLOCK: usize = 128;

/// The most spectral bands frequency-dependent attenuation may take over a record (one band per
/// eighth of the echo's bandwidth that its centre frequency falls): 0.5 dB/cm/MHz takes 8 over
/// 13 mm of depth at 15.6 MHz, and this allows some 90 dB/cm/MHz there.
const MAX_ATTENUATION_BANDS: usize = 1024;

/// Per-call constants of the simulator: waveform table, element positions, amplitude models.
pub(crate) struct Simulator {
    wf: EchoWaveform,
    /// The echo after frequency-dependent attenuation over round-trip paths 0, Δ, 2Δ, … (Δ =
    /// `band_step`); empty when attenuation only scales the amplitude, so one table (`wf`) serves.
    bands: Vec<EchoWaveform>,
    /// Path between consecutive `bands` tables (m).
    band_step: f64,
    element_x: Vec<f64>,
    aperture: (f64, f64),
    /// Outer edges of the array face (m).
    edges: (f64, f64),
    c: f64,
    fs: f64,
    t0: f64,
    n_samples: usize,
    lambda: f64,
    /// Attenuation (Np/m) at f_c.
    kappa: f64,
    /// Taylor coefficients of sinc(π w s / λ) in powers of s², highest first.
    sinc_coeffs: Vec<f32>,
    /// Reference distance of the receive spreading (m): √(r_ref / r).
    r_ref: f64,
    /// Distance below which spreading is clamped (m).
    r_min: f64,
    /// The two-way elevation factor, in a three-dimensional simulation.
    elevation: Option<std::sync::Arc<ElevationTable>>,
    /// The vector instructions of the render ([`render_level`]).
    render_level: Level,
    /// Working memory of finished channel tasks (zero, as each leaves it), for the next task:
    /// rayon starts several tasks per event, and allocating and zeroing each one's accumulators
    /// (half a megabyte with twelve bands) took a few per cent of a render's CPU.
    scratch_pool: std::sync::Mutex<Vec<Scratch>>,
}

/// A channel task's [`Scratch`], given back to the pool when the task ends, unless it ends by a
/// panic, which may leave the accumulators not zero.
struct PooledScratch<'a> {
    scratch: Option<Scratch>,
    pool: &'a std::sync::Mutex<Vec<Scratch>>,
}

impl Drop for PooledScratch<'_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            return;
        }
        if let (Some(scratch), Ok(mut pool)) = (self.scratch.take(), self.pool.lock()) {
            pool.push(scratch);
        }
    }
}

/// Transmit constants of one slot.
struct SlotGeometry {
    sin: f64,
    cos: f64,
    tan: f64,
    inv_cos: f64,
    /// x of the element that fires first (m), see [`crate::core::geometry`].
    x_ref: f64,
    /// Slot start − t0 (s).
    offset: f64,
    polarity: f64,
}

impl Simulator {
    pub(crate) fn new(params: &SimParams) -> Result<Self> {
        let probe = &params.probe;
        let wf = EchoWaveform::for_sequence_truncated(
            probe,
            &params.sequence,
            params.sampling_frequency,
            params.waveform_truncation,
        )?;
        let c = params.sound_speed;
        let lambda = probe.wavelength(c);
        let kappa = params.attenuation_db_cm_mhz * (probe.center_frequency / 1e6) * 100.0
            / (20.0 * std::f64::consts::LOG10_E);
        let aperture = probe.aperture();
        let (bands, band_step) = if params.frequency_dependent_attenuation && kappa > 0.0 {
            // α (Np/m per Hz); the Gaussian part's amplitude width σ. A band of path Δ moves the
            // spectrum by α·Δ·σ²: at most σ/8, so that blending two neighbours stays faithful.
            let fc = probe.center_frequency;
            let alpha = kappa / fc;
            let sigma = probe.bandwidth * fc / (2.0 * (2.0 * std::f64::consts::LN_2).sqrt());
            let step = 1.0 / (8.0 * alpha * sigma);
            // No recorded echo travels farther than sound does until the record ends.
            let longest = c * (params.t0 + params.window_duration()) + c * wf.half_duration();
            let count = (longest / step).ceil() + 2.0;
            // Each band is an accumulator per thread, and the band index lives in i32 lanes.
            if count.is_nan() || count > MAX_ATTENUATION_BANDS as f64 {
                return Err(invalid(
                    "attenuation",
                    format!(
                        "{} dB/cm/MHz lowers the echo's spectrum so steeply that the {:.1} mm of \
                         path recorded would take {count:.3e} spectral bands (at most \
                         {MAX_ATTENUATION_BANDS}): soft tissue's is 0.3–1.5; give a lower one, \
                         or attenuation that scales the amplitude only \
                         (frequency_dependent_attenuation = false)",
                        params.attenuation_db_cm_mhz,
                        longest * 1e3
                    ),
                ));
            }
            let count = count as usize;
            // Each table is a few FFTs of its own: built side by side, they are not the
            // start-up's serial part.
            let bands = (0..count)
                .into_par_iter()
                .map(|k| wf.attenuated(probe, &params.sequence, alpha * step * k as f64))
                .collect::<Result<Vec<_>>>()?;
            (bands, step)
        } else {
            (Vec::new(), f64::INFINITY)
        };
        // Deep enough for every recorded echo (as the attenuation bands).
        let z_max = 0.5 * c * (params.t0 + params.window_duration()) + c * wf.half_duration();
        let elevation = params
            .elevation
            .as_ref()
            .map(|aperture| ElevationTable::shared(aperture, lambda, probe.center_frequency, z_max))
            .transpose()?;
        Ok(Simulator {
            wf,
            bands,
            band_step,
            element_x: probe.element_x(),
            aperture,
            edges: (
                aperture.0 - 0.5 * probe.pitch,
                aperture.1 + 0.5 * probe.pitch,
            ),
            c,
            fs: params.sampling_frequency,
            t0: params.t0,
            n_samples: params.n_samples,
            lambda,
            kappa,
            sinc_coeffs: sinc_taylor(std::f64::consts::PI * probe.element_width / lambda),
            r_ref: 1e-3,
            r_min: 0.5 * lambda,
            elevation,
            render_level: render_level(),
            scratch_pool: std::sync::Mutex::new(Vec::new()),
        })
    }

    /// A channel task's working memory: one a finished task left, or a new one.
    fn scratch(&self) -> PooledScratch<'_> {
        let reused = self
            .scratch_pool
            .lock()
            .ok()
            .and_then(|mut pool| pool.pop());
        PooledScratch {
            scratch: Some(reused.unwrap_or_else(|| self.new_scratch())),
            pool: &self.scratch_pool,
        }
    }

    /// New working memory for one channel task, its accumulators zero.
    fn new_scratch(&self) -> Scratch {
        let bands = self.bands.len().max(1);
        Scratch {
            impulses: vec![[0.0f32; FARROW_TERMS]; (self.n_samples + self.wf.taps() + 1) * bands],
            written: vec![0..0; bands],
            band_trace: vec![0.0; self.n_samples],
        }
    }

    fn slot_geometry(&self, slot: &Slot) -> SlotGeometry {
        let (sin, cos) = slot.angle.sin_cos();
        SlotGeometry {
            sin,
            cos,
            tan: sin / cos,
            inv_cos: 1.0 / cos,
            // As in `geometry::transmit_delay`.
            x_ref: if slot.angle >= 0.0 {
                self.aperture.0
            } else {
                self.aperture.1
            },
            offset: slot.offset - self.t0,
            polarity: slot.polarity as f64,
        }
    }

    /// Transmit delay (s) of `geometry::transmit_delay` with the slot's sine and cosine computed
    /// once: ((x − x_ref)·sin θ + z·cos θ) / c, the same operations in the same order.
    #[inline(always)]
    fn transmit_delay(&self, g: &SlotGeometry, x: f64, z: f64) -> f64 {
        ((x - g.x_ref) * g.sin + z * g.cos) / self.c
    }

    /// Transmit field amplitude of a plane wave (slot `g`) at (x, z) (m): aperture shadow ×
    /// attenuation over the path z / cos θ. Branch-free, so that loops over scatterers vectorise.
    #[inline(always)]
    fn transmit_amplitude(&self, g: &SlotGeometry, x: f64, z: f64) -> f64 {
        let path = z * g.inv_cos;
        let start = x - z * g.tan;
        let outside = (self.edges.0 - start).max(start - self.edges.1);
        let half_width = (0.5 * (self.lambda * path.max(0.0)).sqrt()).max(0.5 * self.lambda);
        // ½(1 − sin(π/2 · t)), t = outside / half-width clamped to [−1, 1]: 1 inside, 0 outside.
        let t = (outside / half_width).clamp(-1.0, 1.0);
        let shadow = 0.5 - 0.5 * sin_half_pi(t);
        let att = exp2_nonpositive((-self.kappa * std::f64::consts::LOG2_E * path) as f32) as f64;
        if z > 0.0 { shadow * att } else { 0.0 }
    }

    /// Transmit part of one event, once per scatterer and slot; drops scatterers no slot reaches.
    /// The two-way elevation factor, which does not depend on the element, joins it here.
    pub(crate) fn prepare(
        &self,
        scatterers: &Snapshot,
        amplitudes: &[f64],
        slots: &[Slot],
    ) -> EventScatterers {
        let positions = &scatterers.positions[..];
        let nk = slots.len();
        let n = positions.len();
        // (amplitude, delay (s)) of each scatterer's elevation factor.
        let elevation: Option<Vec<(f64, f64)>> = self.elevation.as_ref().map(|table| {
            let y = |i: usize| scatterers.elevations.get(i).copied().unwrap_or(0.0);
            positions
                .par_iter()
                .enumerate()
                .map(|(i, &[_, z])| table.two_way(y(i), z))
                .collect()
        });
        let geometry: Vec<SlotGeometry> = slots.iter().map(|s| self.slot_geometry(s)).collect();
        let lead = (self.wf.taps() - self.wf.origin_tap()) as f64;
        // Slot-major (k, scatterer), so that the per-channel loops read them contiguously.
        let mut tx_pos = vec![0.0f64; n * nk];
        let mut tx_amp = vec![0.0f32; n * nk];
        let tx_path: Vec<f32> = if self.bands.is_empty() {
            Vec::new()
        } else {
            geometry
                .iter()
                .flat_map(|g| positions.iter().map(|p| (p[1] * g.inv_cos).max(0.0) as f32))
                .collect()
        };
        const CHUNK: usize = 1024;
        for (g, (pos, amp)) in geometry
            .iter()
            .zip(tx_pos.chunks_mut(n.max(1)).zip(tx_amp.chunks_mut(n.max(1))))
        {
            pos.par_chunks_mut(CHUNK)
                .zip(amp.par_chunks_mut(CHUNK))
                .enumerate()
                .for_each(|(chunk, (pos, amp))| {
                    let base = chunk * CHUNK;
                    let pts = &positions[base..base + pos.len()];
                    let amps = &amplitudes[base..base + pos.len()];
                    for (i, (((p, a), &[x, z]), &s)) in pos
                        .iter_mut()
                        .zip(amp.iter_mut())
                        .zip(pts)
                        .zip(amps)
                        .enumerate()
                    {
                        let mut delay = g.offset + self.transmit_delay(g, x, z);
                        let mut gain = s * g.polarity * self.transmit_amplitude(g, x, z);
                        if let Some(elevation) = &elevation {
                            let (amplitude, extra) = elevation[base + i];
                            delay += extra;
                            gain *= amplitude;
                        }
                        // Far beyond any record: clamp so that the integer part fits an i32.
                        *p = (delay * self.fs + lead).clamp(-1e9, 1e9);
                        *a = gain as f32;
                    }
                });
        }
        // A scatterer whose echo starts before the record's first row or after its last on every
        // channel (by a margin beyond the f32 receive path's rounding) would only add zeros to
        // the accumulator (its amplitude is zeroed there): dropped here with those no slot
        // reaches, so that a phantom larger than the field (a long vessel) costs its part in the
        // field. The echoes kept are the same; where some were dropped, the blocks of the render
        // start at other scatterers, and an accumulator row then sums the same echoes in another
        // order (each block adds its upper bands' shares before its lower ones): a rounding's
        // difference.
        let (first_x, last_x) = self.aperture;
        let last_row = (self.n_samples + self.wf.taps()) as f64 + RECORD_MARGIN_ROWS;
        let rows_per_m = self.fs / self.c;
        // √(a² + z²) rather than `hypot`, whose guard against overflow costs a call per
        // scatterer: positions in metres are far from overflowing, and the margin absorbs an ulp.
        let distance = |a: f64, z: f64| (a * a + z * z).sqrt();
        let active: Vec<usize> = (0..n)
            .into_par_iter()
            .filter(|&i| {
                let [x, z] = positions[i];
                let nearest = distance((first_x - x).max(x - last_x).max(0.0), z) * rows_per_m;
                let farthest =
                    distance((x - first_x).abs().max((x - last_x).abs()), z) * rows_per_m;
                (0..nk).any(|k| {
                    let (start, gain) = (tx_pos[k * n + i], tx_amp[k * n + i]);
                    gain != 0.0
                        && start + farthest >= -RECORD_MARGIN_ROWS
                        && start + nearest <= last_row
                })
            })
            .collect();
        let slot_major = |k: usize| active.iter().map(move |&i| k * n + i);
        let split = |p: f64| {
            let whole = p.floor();
            (whole as i32, (p - whole) as f32)
        };
        EventScatterers {
            xs: active.iter().map(|&i| positions[i][0] as f32).collect(),
            zs: active.iter().map(|&i| positions[i][1] as f32).collect(),
            tx_int: (0..nk)
                .flat_map(slot_major)
                .map(|j| split(tx_pos[j]).0)
                .collect(),
            tx_frac: (0..nk)
                .flat_map(slot_major)
                .map(|j| split(tx_pos[j]).1)
                .collect(),
            tx_amp: (0..nk).flat_map(slot_major).map(|j| tx_amp[j]).collect(),
            tx_path: if self.bands.is_empty() {
                Vec::new()
            } else {
                (0..nk).flat_map(slot_major).map(|j| tx_path[j]).collect()
            },
            slots: nk,
        }
    }

    /// Renders one event into `out` (channels × samples): scatterers at `positions` with
    /// `amplitudes`, fired by `slots`; `noise` adds (generator, stream of channel 0 of this event).
    pub(crate) fn render_event(
        &self,
        scatterers: &Snapshot,
        amplitudes: &[f64],
        slots: &[Slot],
        out: ArrayViewMut2<f32>,
        noise: Option<(&NoiseGenerator, u64)>,
    ) {
        self.render_prepared(&self.prepare(scatterers, amplitudes, slots), out, noise);
    }

    /// Renders the event `ev` ([`Self::prepare`]) into `out` (channels × samples); `noise` adds
    /// (generator, stream of channel 0 of this event).
    pub(crate) fn render_prepared(
        &self,
        ev: &EventScatterers,
        mut out: ArrayViewMut2<f32>,
        noise: Option<(&NoiseGenerator, u64)>,
    ) {
        out.axis_iter_mut(Axis(0))
            .into_par_iter()
            .enumerate()
            .for_each_init(
                || self.scratch(),
                |pooled, (e, mut row)| {
                    let trace = row.as_slice_mut().expect("rows of a standard-layout array");
                    let scratch = pooled.scratch.as_mut().expect("taken only when dropped");
                    self.render_channel(self.element_x[e], ev, scratch, trace);
                    if let Some((generator, first)) = noise {
                        generator.add(trace, first + e as u64);
                    }
                },
            );
    }

    /// Writes into `trace` the echoes of every scatterer of `ev` received on the element at `xe`
    /// (m), using `scratch` (its accumulators zero, and left zero).
    fn render_channel(
        &self,
        xe: f64,
        ev: &EventScatterers,
        scratch: &mut Scratch,
        trace: &mut [f32],
    ) {
        match self.render_level {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `render_level` is at most the level the CPU runs ([`render_level`]):
            // AVX-512F, AVX-512DQ, AVX2 and FMA.
            Level::Avx512 => unsafe { self.render_channel_avx512(xe, ev, scratch, trace) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as above, AVX2 and FMA.
            Level::Avx2 => unsafe { self.render_channel_avx2(xe, ev, scratch, trace) },
            _ => self.render_with(Insert::Portable, xe, ev, scratch, trace),
        }
    }

    /// The echoes of `ev` on the element at `xe` (m) into `trace`, inserted by `insert`: the body
    /// that each compiled variant of [`Self::render_channel`] inlines.
    #[inline(always)]
    fn render_with(
        &self,
        insert: Insert,
        xe: f64,
        ev: &EventScatterers,
        scratch: &mut Scratch,
        trace: &mut [f32],
    ) {
        self.accumulate(xe, ev, &mut scratch.impulses, insert, &mut scratch.written);
        self.convolve_bands(scratch, trace);
    }

    /// The trace from every band's accumulator (each convolved with its own table, summed), then
    /// the accumulators cleared.
    #[inline(always)]
    fn convolve_bands(&self, scratch: &mut Scratch, trace: &mut [f32]) {
        let stride = self.n_samples + self.wf.taps() + 1;
        let Scratch {
            impulses,
            written,
            band_trace,
        } = scratch;
        if self.bands.is_empty() {
            let rows = written[0].clone();
            self.convolve(self.wf.farrow(), impulses, rows.clone(), trace);
            impulses[rows].fill([0.0; FARROW_TERMS]);
            return;
        }
        trace.fill(0.0);
        for (b, table) in self.bands.iter().enumerate() {
            let rows = written[b].clone();
            if rows.is_empty() {
                continue;
            }
            let band = &mut impulses[b * stride..(b + 1) * stride];
            self.convolve(table.farrow(), band, rows.clone(), band_trace);
            for (t, v) in trace.iter_mut().zip(band_trace.iter()) {
                *t += v;
            }
            band[rows].fill([0.0; FARROW_TERMS]);
        }
    }

    /// [`Self::render_channel`] compiled for AVX2 and FMA, with an explicit transpose in the
    /// insertion. Same IEEE operations in the same order (fused multiply-adds are written as
    /// `mul_add`, correctly rounded on every path), so the output is bit-identical to the portable
    /// path.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn render_channel_avx2(
        &self,
        xe: f64,
        ev: &EventScatterers,
        scratch: &mut Scratch,
        trace: &mut [f32],
    ) {
        self.render_with(Insert::Avx2, xe, ev, scratch, trace);
    }

    /// [`Self::render_channel_avx2`] compiled for AVX-512 as well, so that the stages over a
    /// block of scatterers run 16 wide (the insertion's rows stay 8 floats, one AVX2 add each).
    /// Lane by lane the same operations, so bit-identical to the portable path.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2,fma")]
    fn render_channel_avx512(
        &self,
        xe: f64,
        ev: &EventScatterers,
        scratch: &mut Scratch,
        trace: &mut [f32],
    ) {
        self.render_with(Insert::Avx2, xe, ev, scratch, trace);
    }

    /// Adds every echo of `ev` on the element at `xe` (m) to the Farrow accumulator: an echo whose
    /// row starts at buffer index n with sub-sample delay μ adds a·(μ − ½)^q to `impulses[n][q]`.
    /// Each stage is a branch-free loop over a block of scatterers in f32, so that it runs 8 wide.
    /// With spectral bands, `impulses` holds one accumulator per band (`stride` rows apart) and
    /// each echo is split between the two bands around its path. Fills `written` with the range
    /// of rows of each band's accumulator that may have been written.
    #[inline(always)]
    fn accumulate(
        &self,
        xe: f64,
        ev: &EventScatterers,
        impulses: &mut [[f32; FARROW_TERMS]],
        insert: Insert,
        written: &mut [std::ops::Range<usize>],
    ) {
        let stride = self.n_samples + self.wf.taps() + 1;
        let n_bands = self.bands.len();
        let mut bounds = vec![(i32::MAX, -1i32); written.len()];
        let inv_step = (1.0 / self.band_step) as f32;
        // Per echo with bands: its row before the band's offset, and the band each of its two
        // shares is added to (−1 for a share of zero amplitude, which no band's rows count).
        let mut row = [0i32; BLOCK];
        let mut band_lo = [0i32; BLOCK];
        let mut band_hi = [0i32; BLOCK];
        let mut start_hi = [0i32; BLOCK];
        let mut amp_hi = [0.0f32; BLOCK];
        let nk = ev.slots;
        let taps = self.wf.taps();
        // Largest row start whose row ends inside the padded trace.
        let max_start = (self.n_samples + taps) as i32;
        debug_assert_eq!(impulses.len(), stride * n_bands.max(1));
        let xe = xe as f32;
        let fs_over_c = (self.fs / self.c) as f32;
        let att = (self.kappa * std::f64::consts::LOG2_E) as f32;
        let r_ref = self.r_ref as f32;
        let inv_r_min = (1.0 / self.r_min) as f32;
        let coeffs = &self.sinc_coeffs[..];
        let n_active = ev.xs.len();

        let mut r = [0.0f32; BLOCK];
        let mut inv = [0.0f32; BLOCK];
        let mut u = [0.0f32; BLOCK];
        let mut d = [0.0f32; BLOCK];
        let mut rx = [0.0f32; BLOCK];
        let mut fac = [0.0f32; BLOCK];
        let mut start = [0i32; BLOCK];
        let mut mu = [0.0f32; BLOCK];
        let mut amp = [0.0f32; BLOCK];

        for (block, (bx, bz)) in ev.xs.chunks(BLOCK).zip(ev.zs.chunks(BLOCK)).enumerate() {
            let m = bx.len();
            // Receive geometry: distance r, 1/r, sin² φ.
            for ((((x, z), r), inv), u) in bx
                .iter()
                .zip(bz)
                .zip(&mut r[..m])
                .zip(&mut inv[..m])
                .zip(&mut u[..m])
            {
                let dx = x - xe;
                *r = (dx * dx + z * z).sqrt();
                *inv = 1.0 / *r;
                let s = dx * *inv;
                *u = s * s;
            }
            // Directivity sinc(π w sin φ / λ): Horner in sin² φ, one coefficient at a time.
            d[..m].fill(coeffs[0]);
            for &ck in &coeffs[1..] {
                for (d, u) in d[..m].iter_mut().zip(&u[..m]) {
                    *d = d.mul_add(*u, ck);
                }
            }
            // Receive delay (samples) and amplitude: directivity × obliquity cos φ × spreading
            // √(r_ref / r) × attenuation exp(−κ r).
            for (((((z, r), inv), d), rx), fac) in bz
                .iter()
                .zip(&r[..m])
                .zip(&inv[..m])
                .zip(&d[..m])
                .zip(&mut rx[..m])
                .zip(&mut fac[..m])
            {
                *rx = r * fs_over_c;
                let spread = (r_ref * inv.min(inv_r_min)).sqrt();
                *fac = d * (z * inv) * spread * exp2_nonpositive(-att * r);
            }
            let lo = block * BLOCK;
            for k in 0..nk {
                let range = k * n_active + lo..k * n_active + lo + m;
                let (ti, tf, ta) = (
                    &ev.tx_int[range.clone()],
                    &ev.tx_frac[range.clone()],
                    &ev.tx_amp[range],
                );
                // Branch-free: where the echo's row starts, its sub-sample delay, its amplitude.
                for ((((((ti, tf), ta), rx), f), st), (mu, a)) in ti
                    .iter()
                    .zip(tf)
                    .zip(ta)
                    .zip(&rx[..m])
                    .zip(&fac[..m])
                    .zip(&mut start[..m])
                    .zip(mu[..m].iter_mut().zip(&mut amp[..m]))
                {
                    // n0 = round(pos − ½) ∈ {⌊pos⌋, ⌊pos⌋ − 1 at exact integers}: the delay
                    // pos − n0 ∈ [0, 1] is exact for 0 ≤ pos < 2²² (farther echoes are dropped).
                    let pos = tf + rx;
                    let (n0f, n0) = round_f32(pos - 0.5);
                    let s = ti.wrapping_add(n0);
                    let inside = s >= 0 && s <= max_start && pos < 4_000_000.0;
                    *a = if inside { ta * f } else { 0.0 };
                    *st = if inside { s } else { 0 };
                    *mu = (pos - n0f) - 0.5;
                }
                if n_bands > 0 {
                    // The echo's round-trip path picks the two tables around it: band b and b + 1
                    // with weights 1 − β and β. Branch-free, in wrapping integer arithmetic (no
                    // value comes near i32's range: `max_start` and the band count are small), so
                    // that it runs 8 wide like the stages above.
                    let tp = &ev.tx_path[k * n_active + lo..k * n_active + lo + m];
                    let stride = stride as i32;
                    let (mut first_band, mut last_band) = (i32::MAX, i32::MIN);
                    for (((tp, r), (row, (b_lo, b_hi))), ((st, a), (sh, ah))) in tp
                        .iter()
                        .zip(&r[..m])
                        .zip(
                            row[..m]
                                .iter_mut()
                                .zip(band_lo[..m].iter_mut().zip(band_hi[..m].iter_mut())),
                        )
                        .zip(
                            start[..m]
                                .iter_mut()
                                .zip(amp[..m].iter_mut())
                                .zip(start_hi[..m].iter_mut().zip(amp_hi[..m].iter_mut())),
                        )
                    {
                        let position = (tp + r) * inv_step;
                        let whole = position.floor().clamp(0.0, (n_bands - 2) as f32);
                        let beta = (position - whole).clamp(0.0, 1.0);
                        // `whole` is a small whole number: rounding it is exact.
                        let b = round_f32(whole).1;
                        first_band = first_band.min(b);
                        last_band = last_band.max(b);
                        *ah = *a * beta;
                        *a *= 1.0 - beta;
                        *row = *st;
                        *b_lo = if *a != 0.0 { b } else { -1 };
                        *b_hi = if *ah != 0.0 { b.wrapping_add(1) } else { -1 };
                        *sh = st.wrapping_add(b.wrapping_add(1).wrapping_mul(stride));
                        *st = st.wrapping_add(b.wrapping_mul(stride));
                    }
                    // Each band's rows: the bands this block reaches, each a masked min/max over
                    // the block (a few passes 8 wide rather than one scattered update per echo).
                    for (target, bound) in bounds
                        .iter_mut()
                        .enumerate()
                        .take(last_band as usize + 2)
                        .skip(first_band as usize)
                    {
                        let target = target as i32;
                        let (mut low, mut high) = (i32::MAX, -1i32);
                        for ((b_lo, b_hi), row) in
                            band_lo[..m].iter().zip(&band_hi[..m]).zip(&row[..m])
                        {
                            let here = *b_lo == target || *b_hi == target;
                            low = low.min(if here { *row } else { i32::MAX });
                            high = high.max(if here { *row } else { -1 });
                        }
                        *bound = (bound.0.min(low), bound.1.max(high));
                    }
                    insert.run(impulses, &start_hi[..m], &amp_hi[..m], &mu[..m]);
                } else {
                    for (st, a) in start[..m].iter().zip(&amp[..m]) {
                        let used = *a != 0.0;
                        let bound = &mut bounds[0];
                        bound.0 = bound.0.min(if used { *st } else { i32::MAX });
                        bound.1 = bound.1.max(if used { *st } else { -1 });
                    }
                }
                insert.run(impulses, &start[..m], &amp[..m], &mu[..m]);
            }
        }
        for (range, &(first, last)) in written.iter_mut().zip(&bounds) {
            *range = if last < first {
                0..0
            } else {
                first as usize..last as usize + 1
            };
        }
    }

    /// The trace from the Farrow accumulator: trace[i] = Σ_j Σ_q c[j][q]·impulses[i + taps − j][q]
    /// (buffer index i + taps is sample i; the row of tap j starts j samples before it). Only
    /// `rows` may be non-zero: samples that read none of them are set to 0 without arithmetic.
    #[inline(always)]
    fn convolve(
        &self,
        coeffs: &[[f32; FARROW_TERMS]],
        impulses: &[[f32; FARROW_TERMS]],
        rows: std::ops::Range<usize>,
        trace: &mut [f32],
    ) {
        match coeffs.len() {
            16 => convolve_taps::<16>(coeffs, impulses, rows, trace),
            24 => convolve_taps::<24>(coeffs, impulses, rows, trace),
            32 => convolve_taps::<32>(coeffs, impulses, rows, trace),
            40 => convolve_taps::<40>(coeffs, impulses, rows, trace),
            48 => convolve_taps::<48>(coeffs, impulses, rows, trace),
            _ => convolve_taps::<0>(coeffs, impulses, rows, trace),
        }
    }
}

/// How the insertion stage adds each scatterer's row of powers.
#[derive(Clone, Copy)]
enum Insert {
    /// 8 × 8 register transpose, one 8-wide add per scatterer.
    #[cfg(target_arch = "x86_64")]
    Avx2,
    /// Plain Rust.
    Portable,
}

impl Insert {
    /// impulses[start[i]][q] += amp[i]·mu[i]^q for every scatterer i, in order.
    #[inline(always)]
    fn run(self, impulses: &mut [[f32; FARROW_TERMS]], start: &[i32], amp: &[f32], mu: &[f32]) {
        match self {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Insert::Avx2` is only passed from the AVX2-enabled path.
            Insert::Avx2 => unsafe { insert_avx2(impulses, start, amp, mu) },
            Insert::Portable => insert_portable(impulses, start, amp, mu, 0),
        }
    }
}

/// impulses[start[i]][q] += amp[i]·mu[i]^q (the power built by repeated multiplication) for
/// scatterers i from `from` on, in order.
#[inline(always)]
fn insert_portable(
    impulses: &mut [[f32; FARROW_TERMS]],
    start: &[i32],
    amp: &[f32],
    mu: &[f32],
    from: usize,
) {
    for ((&s, &a), &mu) in start.iter().zip(amp).zip(mu).skip(from) {
        let row = &mut impulses[s as usize];
        let mut p = a;
        for v in row.iter_mut() {
            *v += p;
            p *= mu;
        }
    }
}

/// [`insert_portable`] eight scatterers at a time: the eight power vectors a·μ^q are built in
/// registers (across scatterers), an 8 × 8 transpose turns them into one row per scatterer, added
/// with one 8-wide add. The same operations in the same order, so bit-identical to the portable loop.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn insert_avx2(
    impulses: &mut [[f32; FARROW_TERMS]],
    start: &[i32],
    amp: &[f32],
    mu: &[f32],
) {
    use std::arch::x86_64::*;
    let m = start.len().min(amp.len()).min(mu.len());
    let full = m / 8 * 8;
    let len = impulses.len();
    let base = impulses.as_mut_ptr() as *mut f32;
    for i in (0..full).step_by(8) {
        // SAFETY: i + 8 ≤ m, so each load reads 8 floats inside `amp` and `mu`.
        let (a, x) = unsafe {
            (
                _mm256_loadu_ps(amp.as_ptr().add(i)),
                _mm256_loadu_ps(mu.as_ptr().add(i)),
            )
        };
        let r1 = _mm256_mul_ps(a, x);
        let r2 = _mm256_mul_ps(r1, x);
        let r3 = _mm256_mul_ps(r2, x);
        let r4 = _mm256_mul_ps(r3, x);
        let r5 = _mm256_mul_ps(r4, x);
        let r6 = _mm256_mul_ps(r5, x);
        let r7 = _mm256_mul_ps(r6, x);
        let rows = crate::core::simd::transpose_8x8([a, r1, r2, r3, r4, r5, r6, r7]);
        for (o, row) in rows.into_iter().enumerate() {
            let s = start[i + o] as usize;
            assert!(s < len, "row start inside the accumulator");
            // SAFETY: s < len rows of FARROW_TERMS = 8 floats, checked just above.
            unsafe {
                let p = base.add(s * FARROW_TERMS);
                _mm256_storeu_ps(p, _mm256_add_ps(_mm256_loadu_ps(p), row));
            }
        }
    }
    insert_portable(impulses, &start[..m], &amp[..m], &mu[..m], full);
}

/// [`Simulator::convolve`] for `T` taps (`T` = 0: any count, known at run time): eight outputs at
/// a time, each an 8-wide fused multiply-add over the taps and a fixed-order horizontal sum.
#[inline(always)]
fn convolve_taps<const T: usize>(
    coeffs: &[[f32; FARROW_TERMS]],
    impulses: &[[f32; FARROW_TERMS]],
    rows: std::ops::Range<usize>,
    trace: &mut [f32],
) {
    let taps = if T == 0 { coeffs.len() } else { T };
    let coeffs = &coeffs[..taps];
    let ns = trace.len();
    assert!(impulses.len() > ns + taps, "accumulator covers the trace");
    let hsum = |a: [f32; FARROW_TERMS]| {
        let h = [a[0] + a[4], a[1] + a[5], a[2] + a[6], a[3] + a[7]];
        let h = [h[0] + h[2], h[1] + h[3]];
        h[0] + h[1]
    };
    // Sample i reads rows i + 1 ..= i + taps.
    let lo = rows.start.saturating_sub(taps).min(ns);
    let hi = rows.end.saturating_sub(1).clamp(lo, ns);
    trace[..lo].fill(0.0);
    trace[hi..].fill(0.0);
    let mut i = lo;
    while i + 8 <= hi {
        let mut acc = [[0.0f32; FARROW_TERMS]; 8];
        // Output i + o reads rows i + o + taps − j, j = 0..taps: rows i + 1 ..= i + taps + 7.
        let rows = &impulses[i + 1..i + taps + 8];
        for (j, c) in coeffs.iter().enumerate() {
            for (o, acc) in acc.iter_mut().enumerate() {
                let row = &rows[o + taps - 1 - j];
                for q in 0..FARROW_TERMS {
                    acc[q] = c[q].mul_add(row[q], acc[q]);
                }
            }
        }
        for (o, acc) in acc.into_iter().enumerate() {
            trace[i + o] = hsum(acc);
        }
        i += 8;
    }
    for (i, out) in trace.iter_mut().enumerate().take(hi).skip(i) {
        let mut acc = [0.0f32; FARROW_TERMS];
        for (j, c) in coeffs.iter().enumerate() {
            let row = &impulses[i + taps - j];
            for q in 0..FARROW_TERMS {
                acc[q] = c[q].mul_add(row[q], acc[q]);
            }
        }
        *out = hsum(acc);
    }
}

/// round(v) (ties to even) as f32 and as i32, for |v| < 2²², branch- and cast-free so that it
/// vectorises (adding 1.5·2²³ rounds to an integer in the low mantissa bits).
#[inline(always)]
fn round_f32(v: f32) -> (f32, i32) {
    const MAGIC: f32 = 12_582_912.0;
    let t = v + MAGIC;
    (t - MAGIC, t.to_bits().wrapping_sub(MAGIC.to_bits()) as i32)
}

/// sin(π t / 2) for t ∈ [−1, 1] (odd Taylor polynomial of degree 11, error < 10⁻⁹). Branch-free.
#[inline(always)]
fn sin_half_pi(t: f64) -> f64 {
    let x = std::f64::consts::FRAC_PI_2 * t;
    let x2 = x * x;
    x * (1.0
        + x2 * (-1.0 / 6.0
            + x2 * (1.0 / 120.0
                + x2 * (-1.0 / 5040.0 + x2 * (1.0 / 362_880.0 + x2 * (-1.0 / 39_916_800.0))))))
}

/// 2^y for y ≤ 0 (relative error < 3·10⁻⁷; flushes to 0 below 2⁻¹²⁶). Branch- and cast-free
/// (rounding by the 1.5·2²³ trick), so that it vectorises.
#[inline(always)]
fn exp2_nonpositive(y: f32) -> f32 {
    const MAGIC: f32 = 12_582_912.0; // 1.5·2²³: adding it rounds to an integer in the low bits
    // 2^f on [−½, ½]: the degree-5 polynomial of least relative error (Lawson's iteration on
    // Chebyshev nodes), 7.5·10⁻⁸ in exact arithmetic and 2.1·10⁻⁷ evaluated in f32: five fused
    // multiply-adds where a Taylor series in f·ln 2 needs degree 7.
    const C: [f32; 6] = [
        1.000_000_1,
        0.693_146_94,
        0.240_221_2,
        0.055_507_13,
        0.009_675_541,
        0.001_327_647_1,
    ];
    let y = y.clamp(-126.0, 0.0);
    let t = y + MAGIC;
    let n = t - MAGIC; // round(y)
    let f = y - n; // ∈ [−½, ½]
    let i = t.to_bits().wrapping_sub(MAGIC.to_bits()) as i32; // round(y) as an integer
    let p = C[5]
        .mul_add(f, C[4])
        .mul_add(f, C[3])
        .mul_add(f, C[2])
        .mul_add(f, C[1])
        .mul_add(f, C[0]);
    p * f32::from_bits((i.wrapping_add(127) as u32) << 23)
}

/// Taylor coefficients of sinc(x·s) = sin(x s)/(x s) in powers of u = s², highest power first,
/// as many as needed for a truncation error below 10⁻⁹ for |s| ≤ 1 (at most 24 terms).
fn sinc_taylor(x: f64) -> Vec<f32> {
    let mut coeffs = Vec::new();
    let mut c = 1.0f64; // (−1)^k x^(2k) / (2k+1)!
    for k in 0..24 {
        coeffs.push(c as f32);
        let k1 = (k + 1) as f64;
        c *= -x * x / (2.0 * k1 * (2.0 * k1 + 1.0));
        if c.abs() < 1e-9 {
            break;
        }
    }
    coeffs.reverse();
    coeffs
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_exp2_is_accurate() {
        // Every thousandth over the range not flushed, so every fraction of [−½, ½] many times.
        for i in 0..126_000 {
            let y = -(i as f32) * 1e-3;
            let exact = (y as f64).exp2();
            let rel = (exp2_nonpositive(y) as f64 - exact).abs() / exact;
            assert!(rel < 3e-7, "y = {y}: rel err {rel}");
        }
    }

    #[test]
    fn transmit_delay_and_shadow_follow_the_convention() {
        let params = super::super::paper_spiral_params(true).unwrap();
        let sim = Simulator::new(&params).unwrap();
        let aperture = params.probe.aperture();
        for &angle in &params.sequence.angles {
            let slot = Slot {
                angle,
                polarity: 1.0,
                offset: 0.0,
            };
            let g = sim.slot_geometry(&slot);
            for &(x, z) in &[(0.0, 5e-3), (-6e-3, 1e-3), (6.3e-3, 13e-3), (2e-3, 0.2e-3)] {
                let exact = crate::core::geometry::transmit_delay(
                    x,
                    z,
                    angle,
                    aperture,
                    params.sound_speed,
                );
                assert!((sim.transmit_delay(&g, x, z) - exact).abs() < 1e-18);
            }
            // The shadow's raised-cosine edge: ½ on the shadow line, 1 well inside, 0 well outside.
            let z = 8e-3;
            let on_edge = sim.edges.1 + z * angle.tan();
            let tx =
                |x: f64| sim.transmit_amplitude(&g, x, z) / (-sim.kappa * z / angle.cos()).exp();
            assert!((tx(on_edge) - 0.5).abs() < 1e-6);
            assert!((tx(on_edge - 1e-3) - 1.0).abs() < 1e-6);
            assert!(tx(on_edge + 1e-3).abs() < 1e-6);
            assert_eq!(sim.transmit_amplitude(&g, 0.0, -1e-3), 0.0);
        }
    }

    /// The traces of one coded event by the portable loops: [`Simulator::accumulate`] with
    /// [`Insert::Portable`], then the bands' convolution.
    fn portable_event(sim: &Simulator, ev: &EventScatterers) -> Vec<Vec<f32>> {
        let mut scratch = sim.new_scratch();
        sim.element_x
            .iter()
            .map(|&xe| {
                let mut trace = vec![0.0f32; sim.n_samples];
                sim.accumulate(
                    xe,
                    ev,
                    &mut scratch.impulses,
                    Insert::Portable,
                    &mut scratch.written,
                );
                sim.convolve_bands(&mut scratch, &mut trace);
                trace
            })
            .collect()
    }

    #[test]
    #[cfg_attr(
        all(windows, target_env = "gnu"),
        ignore = "MinGW-w64's fmaf is not correctly rounded, and the portable path's f32 mul_add calls it"
    )]
    fn every_path_renders_the_same_samples() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        // Scatterers over the whole window and beyond its edges, so that echoes reach every band,
        // start before the record and end after it.
        let n = 1000;
        let positions: Vec<[f64; 2]> = (0..n)
            .map(|_| {
                [
                    rng.random_range(-8e-3..8e-3),
                    rng.random_range(-1e-3..16e-3),
                ]
            })
            .collect();
        let amplitudes: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        for spectral_bands in [true, false] {
            let mut params = super::super::paper_spiral_params(true).unwrap();
            params.frequency_dependent_attenuation = spectral_bands;
            let mut sim = Simulator::new(&params).unwrap();
            assert_eq!(sim.bands.len() > 2, spectral_bands);
            let slots: Vec<Slot> = params
                .sequence
                .angles
                .iter()
                .enumerate()
                .map(|(k, &angle)| Slot {
                    angle,
                    polarity: if k % 3 == 0 { -1.0 } else { 1.0 },
                    offset: k as f64 * 1e-6,
                })
                .collect();
            let scatterers = Snapshot {
                positions: positions.clone(),
                elevations: Vec::new(),
            };
            let ev = sim.prepare(&scatterers, &amplitudes, &slots);
            let portable = portable_event(&sim, &ev);
            // Every level this CPU runs, whichever the render would pick here.
            let levels = [Level::Portable, Level::Avx2, Level::Avx512];
            for level in levels
                .into_iter()
                .filter(|&l| l <= crate::core::simd::level())
            {
                sim.render_level = level;
                let mut out = ndarray::Array2::<f32>::zeros((sim.element_x.len(), sim.n_samples));
                sim.render_event(&scatterers, &amplitudes, &slots, out.view_mut(), None);
                assert!(out.iter().any(|&v| v != 0.0));
                for (e, trace) in portable.iter().enumerate() {
                    let rendered = out.row(e);
                    let same = trace
                        .iter()
                        .zip(rendered.iter())
                        .all(|(a, b)| a.to_bits() == b.to_bits());
                    assert!(
                        same,
                        "channel {e} (spectral bands {spectral_bands}, {}) differs",
                        level.name()
                    );
                }
            }
        }
    }

    #[test]
    fn sinc_series_matches() {
        for &x in &[0.5f64, 2.55, 4.2, 6.0] {
            let c = sinc_taylor(x);
            for j in 0..=100 {
                let s = j as f64 / 100.0;
                let u = (s * s) as f32;
                let v = c[1..].iter().fold(c[0], |acc, &ck| acc * u + ck) as f64;
                let arg = x * s;
                let exact = if arg == 0.0 { 1.0 } else { arg.sin() / arg };
                let tol = if x > 5.0 { 2e-6 } else { 5e-7 };
                assert!((v - exact).abs() < tol, "x {x} s {s}: {v} vs {exact}");
            }
        }
    }
}
