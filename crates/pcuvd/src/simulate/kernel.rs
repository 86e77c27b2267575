//! The simulator's inner loops: one transmit event → one trace per channel.
//!
//! Per event, the transmit part (delay, polarity × transmit field × scatterer amplitude) is computed
//! once per scatterer and slot. Per channel, scatterers are processed in blocks: a branch-free,
//! vectorisable pass computes the receive delay and amplitude of every scatterer of the block (f64
//! delays, f32 amplitudes from polynomial approximations), then each echo is added as one scaled
//! vector add of two linearly interpolated rows of the waveform's polyphase table.

use ndarray::{ArrayViewMut2, Axis};
use rayon::prelude::*;

use super::SimParams;
use super::noise::NoiseGenerator;
use super::waveform::EchoWaveform;
use crate::error::Result;
use crate::geometry::transmit_delay;

/// One pulse slot of an event: steering angle (rad), polarity (±1) and start within the event (s).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Slot {
    pub(crate) angle: f64,
    pub(crate) polarity: f32,
    pub(crate) offset: f64,
}

/// Scatterers of one event that some slot insonifies, structure-of-arrays.
struct EventScatterers {
    xs: Vec<f64>,
    zs: Vec<f64>,
    /// Per slot and scatterer (slot-major): start of the echo row in the padded trace buffer
    /// (samples), before the receive delay.
    tx_pos: Vec<f64>,
    /// Per slot and scatterer (slot-major): scatterer amplitude × polarity × transmit field.
    tx_amp: Vec<f32>,
    slots: usize,
}

/// Scatterers per block of the per-channel loop.
const BLOCK: usize = 128;

/// Per-call constants of the simulator: waveform table, element positions, amplitude models.
pub(crate) struct Simulator {
    wf: EchoWaveform,
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
    sinc_coeffs: [f32; SINC_TERMS],
    /// Reference distance of the receive spreading (m): √(r_ref / r).
    r_ref: f64,
    /// Distance below which spreading is clamped (m).
    r_min: f64,
}

impl Simulator {
    pub(crate) fn new(params: &SimParams) -> Result<Self> {
        let probe = &params.probe;
        let wf = EchoWaveform::new(
            probe,
            params.sequence.pulse_cycles,
            params.sampling_frequency,
        )?;
        let c = params.sound_speed;
        let lambda = probe.wavelength(c);
        let kappa = params.attenuation_db_cm_mhz * (probe.center_frequency / 1e6) * 100.0
            / (20.0 * std::f64::consts::LOG10_E);
        let aperture = probe.aperture();
        Ok(Simulator {
            wf,
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
        })
    }

    /// Transmit field amplitude of a plane wave steered by `angle` at (x, z) (m): aperture shadow ×
    /// attenuation over the path z / cos θ.
    fn transmit_amplitude(&self, x: f64, z: f64, angle: f64) -> f64 {
        if z <= 0.0 {
            return 0.0;
        }
        let path = z / angle.cos();
        let start = x - z * angle.tan();
        let outside = (self.edges.0 - start).max(start - self.edges.1);
        let half_width = (0.5 * (self.lambda * path).sqrt()).max(0.5 * self.lambda);
        let shadow = if outside <= -half_width {
            1.0
        } else if outside >= half_width {
            0.0
        } else {
            0.5 * (1.0 - (0.5 * std::f64::consts::PI * outside / half_width).sin())
        };
        shadow * (-self.kappa * path).exp()
    }

    /// Transmit part of one event, once per scatterer and slot; drops scatterers no slot reaches.
    fn prepare(
        &self,
        positions: &[[f64; 2]],
        amplitudes: &[f64],
        slots: &[Slot],
    ) -> EventScatterers {
        let nk = slots.len();
        let lead = (self.wf.taps() - self.wf.origin_tap()) as f64;
        let mut tx_pos = vec![0.0f64; positions.len() * nk];
        let mut tx_amp = vec![0.0f32; positions.len() * nk];
        tx_pos
            .par_chunks_mut(nk)
            .zip(tx_amp.par_chunks_mut(nk))
            .enumerate()
            .with_min_len(512)
            .for_each(|(i, (tp, ta))| {
                let [x, z] = positions[i];
                for (k, slot) in slots.iter().enumerate() {
                    let delay = slot.offset
                        + transmit_delay(x, z, slot.angle, self.aperture, self.c)
                        - self.t0;
                    tp[k] = delay * self.fs + lead;
                    ta[k] = (amplitudes[i]
                        * slot.polarity as f64
                        * self.transmit_amplitude(x, z, slot.angle))
                        as f32;
                }
            });
        let active: Vec<usize> = (0..positions.len())
            .filter(|&i| tx_amp[i * nk..(i + 1) * nk].iter().any(|&a| a != 0.0))
            .collect();
        // Slot-major (k, scatterer) so that the per-channel loops read them contiguously.
        EventScatterers {
            xs: active.iter().map(|&i| positions[i][0]).collect(),
            zs: active.iter().map(|&i| positions[i][1]).collect(),
            tx_pos: (0..nk)
                .flat_map(|k| active.iter().map(move |&i| (i, k)))
                .map(|(i, k)| tx_pos[i * nk + k])
                .collect(),
            tx_amp: (0..nk)
                .flat_map(|k| active.iter().map(move |&i| (i, k)))
                .map(|(i, k)| tx_amp[i * nk + k])
                .collect(),
            slots: nk,
        }
    }

    /// Renders one event into `out` (channels × samples): scatterers at `positions` with
    /// `amplitudes`, fired by `slots`; `noise` adds (generator, stream of channel 0 of this event).
    pub(crate) fn render_event(
        &self,
        positions: &[[f64; 2]],
        amplitudes: &[f64],
        slots: &[Slot],
        mut out: ArrayViewMut2<f32>,
        noise: Option<(&NoiseGenerator, u64)>,
    ) {
        let ev = self.prepare(positions, amplitudes, slots);
        let taps = self.wf.taps();
        let ns = self.n_samples;
        out.axis_iter_mut(Axis(0))
            .into_par_iter()
            .enumerate()
            .for_each(|(e, mut row)| {
                let mut buf = vec![0.0f32; ns + 2 * taps];
                self.render_channel(self.element_x[e], &ev, &mut buf);
                let trace = row.as_slice_mut().expect("rows of a standard-layout array");
                trace.copy_from_slice(&buf[taps..taps + ns]);
                if let Some((generator, first)) = noise {
                    generator.add(trace, first + e as u64);
                }
            });
    }

    /// Adds the echoes of every scatterer of `ev` received on the element at `xe` (m) into `buf`
    /// (the trace, padded by `taps` zeros on each side).
    fn render_channel(&self, xe: f64, ev: &EventScatterers, buf: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above.
            unsafe { self.render_channel_avx2(xe, ev, buf) };
            return;
        }
        self.render_channel_impl(xe, ev, buf);
    }

    /// [`Self::render_channel_impl`] compiled for AVX2. Same IEEE operations (no FMA contraction),
    /// so the output is bit-identical to the baseline path.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn render_channel_avx2(&self, xe: f64, ev: &EventScatterers, buf: &mut [f32]) {
        self.render_channel_impl(xe, ev, buf);
    }

    #[inline(always)]
    fn render_channel_impl(&self, xe: f64, ev: &EventScatterers, buf: &mut [f32]) {
        match self.wf.taps() {
            8 => self.render_channel_taps::<8>(xe, ev, buf),
            16 => self.render_channel_taps::<16>(xe, ev, buf),
            24 => self.render_channel_taps::<24>(xe, ev, buf),
            32 => self.render_channel_taps::<32>(xe, ev, buf),
            40 => self.render_channel_taps::<40>(xe, ev, buf),
            48 => self.render_channel_taps::<48>(xe, ev, buf),
            _ => self.render_channel_taps::<0>(xe, ev, buf),
        }
    }

    /// The channel loop for waveform rows of `T` taps (`T` = 0: any multiple of 8, known at run time).
    #[inline(always)]
    fn render_channel_taps<const T: usize>(&self, xe: f64, ev: &EventScatterers, buf: &mut [f32]) {
        let nk = ev.slots;
        let taps = self.wf.taps();
        let table = self.wf.table();
        let phases = EchoWaveform::PHASES as f64;
        let hi = (self.n_samples + taps + 1) as f64;
        let fs_over_c = self.fs / self.c;
        let att = (self.kappa * std::f64::consts::LOG2_E) as f32;
        let r_ref = self.r_ref as f32;
        let inv_r_min = (1.0 / self.r_min) as f32;
        let coeffs = self.sinc_coeffs;
        let n_active = ev.xs.len();

        let mut rx = [0.0f64; BLOCK];
        let mut fac = [0.0f32; BLOCK];
        let mut start = [0i32; BLOCK];
        let mut row = [0i32; BLOCK];
        let mut w0 = [0.0f32; BLOCK];
        let mut w1 = [0.0f32; BLOCK];

        for (block, (bx, bz)) in ev.xs.chunks(BLOCK).zip(ev.zs.chunks(BLOCK)).enumerate() {
            let m = bx.len();
            // Receive delay (samples, f64) and amplitude (f32): directivity sinc(π w sin φ / λ)
            // × obliquity cos φ × spreading √(r_ref / r) × attenuation exp(−κ r). Branch-free.
            for (((x, z), rx), fac) in bx.iter().zip(bz).zip(&mut rx[..m]).zip(&mut fac[..m]) {
                let dx = x - xe;
                let r = (dx * dx + z * z).sqrt();
                *rx = r * fs_over_c;
                let rf = r as f32;
                let inv = 1.0 / rf;
                let s = dx as f32 * inv;
                let u = s * s;
                let d = coeffs[1..].iter().fold(coeffs[0], |d, &ck| d * u + ck);
                let spread = (r_ref * inv.min(inv_r_min)).sqrt();
                *fac = d * (*z as f32 * inv) * spread * exp2_nonpositive(-att * rf);
            }
            // Echoes: one interpolated table row pair per scatterer and slot.
            let base = block * BLOCK;
            for k in 0..nk {
                let tp = &ev.tx_pos[k * n_active + base..k * n_active + base + m];
                let ta = &ev.tx_amp[k * n_active + base..k * n_active + base + m];
                // Branch-free: where the echo lies, which table rows, with which weights.
                for ((((((tp, ta), rx), f), st), rw), (a0, a1)) in tp
                    .iter()
                    .zip(ta)
                    .zip(&rx[..m])
                    .zip(&fac[..m])
                    .zip(&mut start[..m])
                    .zip(&mut row[..m])
                    .zip(w0[..m].iter_mut().zip(&mut w1[..m]))
                {
                    let pos = tp + rx;
                    let inside = pos >= 0.0 && pos < hi;
                    let pos = if inside { pos } else { 0.0 };
                    // Integer and fractional parts without saturating casts (so it vectorises):
                    // n0 = round(pos − ½) ∈ {⌊pos⌋, ⌊pos⌋ − 1 at exact integers}, frac ∈ [0, 1].
                    let (n0, n0_int) = round_f64(pos - 0.5);
                    let q = (pos - n0) * phases;
                    let (p, p_int) = round_f64((q - 0.5).min(phases - 1.0));
                    let mu = (q - p) as f32;
                    let a = if inside { ta * f } else { 0.0 };
                    *st = n0_int;
                    *rw = p_int;
                    *a0 = a - a * mu;
                    *a1 = a * mu;
                }
                for i in 0..m {
                    if w0[i] == 0.0 && w1[i] == 0.0 {
                        continue;
                    }
                    let st = start[i] as usize;
                    let p = row[i] as usize;
                    // With T known at compile time the add is fully unrolled.
                    let n = if T == 0 { taps } else { T };
                    let rows = &table[p * n..(p + 2) * n];
                    add_pulse(&mut buf[st..st + n], &rows[..n], &rows[n..], w0[i], w1[i]);
                }
            }
        }
    }
}

/// dst += a0·row0 + a1·row1, in blocks of 8 whose loads all precede their stores, so that the
/// compiler vectorises each block (the table and the trace could alias as far as it knows).
#[inline(always)]
fn add_pulse(dst: &mut [f32], row0: &[f32], row1: &[f32], a0: f32, a1: f32) {
    for ((d, r0), r1) in dst
        .chunks_exact_mut(8)
        .zip(row0.chunks_exact(8))
        .zip(row1.chunks_exact(8))
    {
        let x: [f32; 8] = r0.try_into().expect("blocks of 8");
        let y: [f32; 8] = r1.try_into().expect("blocks of 8");
        let mut o: [f32; 8] = (&*d).try_into().expect("blocks of 8");
        for j in 0..8 {
            o[j] += a0 * x[j] + a1 * y[j];
        }
        d.copy_from_slice(&o);
    }
}

/// round(v) (ties to even) as f64 and as i32, for |v| < 2³¹, branch- and cast-free so that it
/// vectorises (adding 1.5·2⁵² rounds to an integer in the low mantissa bits).
#[inline(always)]
fn round_f64(v: f64) -> (f64, i32) {
    const MAGIC: f64 = 6_755_399_441_055_744.0;
    let t = v + MAGIC;
    (t - MAGIC, t.to_bits().wrapping_sub(MAGIC.to_bits()) as i32)
}

/// 2^y for y ≤ 0 (relative error < 10⁻⁶; flushes to 0 below 2⁻¹²⁶). Branch- and cast-free
/// (rounding by the 1.5·2²³ trick), so that it vectorises.
#[inline(always)]
fn exp2_nonpositive(y: f32) -> f32 {
    const MAGIC: f32 = 12_582_912.0; // 1.5·2²³: adding it rounds to an integer in the low bits
    let y = y.clamp(-126.0, 0.0);
    let t = y + MAGIC;
    let n = t - MAGIC; // round(y)
    let f = y - n; // ∈ [−½, ½]
    let i = t.to_bits().wrapping_sub(MAGIC.to_bits()) as i32; // round(y) as an integer
    // Taylor series of e^(f ln 2), degree 7.
    const L: f32 = std::f32::consts::LN_2;
    let x = f * L;
    let p = 1.0
        + x * (1.0
            + x * (0.5
                + x * (1.0 / 6.0
                    + x * (1.0 / 24.0 + x * (1.0 / 120.0 + x * (1.0 / 720.0 + x / 5040.0))))));
    p * f32::from_bits((i.wrapping_add(127) as u32) << 23)
}

/// Terms of the directivity's Taylor series.
const SINC_TERMS: usize = 12;

/// Taylor coefficients of sinc(x·s) = sin(x s)/(x s) in powers of u = s², highest power first:
/// 12 terms, accurate to 10⁻⁸ for |x s| ≤ 4.2 (elements up to 1.3 λ wide) and 10⁻⁵ up to 2π.
fn sinc_taylor(x: f64) -> [f32; SINC_TERMS] {
    let mut coeffs = [0.0f32; SINC_TERMS];
    let mut c = 1.0f64; // (−1)^k x^(2k) / (2k+1)!
    for k in 0..SINC_TERMS {
        coeffs[SINC_TERMS - 1 - k] = c as f32;
        let k1 = (k + 1) as f64;
        c *= -x * x / (2.0 * k1 * (2.0 * k1 + 1.0));
    }
    coeffs
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_exp2_is_accurate() {
        for i in 0..2000 {
            let y = -(i as f32) * 0.01;
            let exact = (y as f64).exp2();
            let rel = (exp2_nonpositive(y) as f64 - exact).abs() / exact;
            assert!(rel < 1e-6, "y = {y}: rel err {rel}");
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
                let tol = if x > 5.0 { 2e-5 } else { 2e-6 };
                assert!((v - exact).abs() < tol, "x {x} s {s}: {v} vs {exact}");
            }
        }
    }
}
