//! The one echo waveform of a point scatterer, finely tabulated for fast sub-sample placement.

use num_complex::Complex64;
use pcuvd_fft::FftPlanner64;

use crate::acquisition::probe::Probe;
use crate::acquisition::sequence::{Sequence, TransmitPulse};
use crate::core::error::{Result, invalid, require_positive};

/// The echo of a point scatterer as received on one element: the transmit pulse (`pulse_cycles`
/// cycles of f_c under a Hann window, cosine phase) filtered by the probe's two-way impulse response
/// (a zero-phase Gaussian band-pass centred on f_c whose −6 dB full width is the probe's fractional
/// bandwidth × f_c). Its span, ±[`EchoWaveform::half_duration`], ends where |w| last exceeds
/// 3·10⁻⁴ of its peak (−70 dB); the table rounds the span up to whole groups of 8 taps, so it may
/// hold a little more of the tails. The waveform is even about its time origin, which is the
/// centre of the pulse and the peak of its envelope: an echo "arriving at τ" is centred on τ.
/// Peak amplitude 1.
///
/// For placement at arbitrary sub-sample delays it is tabulated as a polyphase table of
/// [`EchoWaveform::PHASES`] + 1 rows (fractional delays p/PHASES of a sample) × `taps` samples;
/// a delay between two rows interpolates them linearly (error ≲ 3·10⁻⁵ of the peak at f_s/f_c ≈ 4).
/// The simulator uses its Farrow form instead: each tap as a degree-7 polynomial of the sub-sample
/// delay, fitted to the 65 finely sampled delays of the table (error ≲ 10⁻⁶ of the peak).
#[derive(Debug, Clone)]
pub struct EchoWaveform {
    fs: f64,
    /// Peak of the unattenuated waveform before normalisation (the scale of every table).
    peak: f64,
    /// Half-span in samples of the fine grid.
    half_fine: usize,
    taps: usize,
    half: usize,
    table: Vec<f32>,
    farrow: Vec<[f32; FARROW_TERMS]>,
    fine: Vec<f64>,
    fine_origin: usize,
    half_duration: f64,
    peak_offset: f64,
    truncation: f64,
}

/// Coefficients per tap of the Farrow (polynomial in the sub-sample delay) form: degree 7.
pub(crate) const FARROW_TERMS: usize = 8;

impl EchoWaveform {
    /// Default relative level (of the peak) below which the waveform's tails are left out of its
    /// span: 3·10⁻⁴, −70.5 dB. Why this level: it lies 60 dB below the presets' receiver noise
    /// (−10 dB at the quietest), and blood alone holds no echoes far brighter than itself that could
    /// lift the lost tails above it. A lower level costs taps (10⁻⁴ takes the paper's L22-14vX
    /// 2-cycle echo from 24 to 32 taps, a third more convolution work) and widens every receive
    /// window; with tissue far brighter than blood a scenario may ask for one
    /// ([`EchoWaveform::for_sequence_truncated`]).
    pub const DEFAULT_TRUNCATION: f64 = 3e-4;

    /// Sub-sample phases of the polyphase table (per sample period).
    pub const PHASES: usize = 64;

    /// The echo waveform of `probe` for a pulse of `pulse_cycles` cycles, sampled at `fs` (Hz).
    pub fn new(probe: &Probe, pulse_cycles: f64, fs: f64) -> Result<Self> {
        Self::build(probe, pulse_cycles, fs, 0.0, None, Self::DEFAULT_TRUNCATION)
    }

    /// The same echo after frequency-dependent attenuation over a path whose attenuation is
    /// `tilt` (s) per Hz beyond f_c: its spectrum multiplied by exp(−tilt·(|f| − f_c)), so that
    /// the gain at f_c stays 1 (the simulator applies the attenuation at f_c apart). With linear
    /// attenuation α (Np/m/Hz) over a round-trip path L, tilt = α·L; a Gaussian echo spectrum of
    /// amplitude width σ then moves down by α·L·σ². Same time span, taps and scale as `self`, so
    /// that tables of several paths can be blended.
    /// `sequence` gives the transmit pulse, as for [`EchoWaveform::for_sequence`].
    pub fn attenuated(&self, probe: &Probe, sequence: &Sequence, tilt: f64) -> Result<Self> {
        if !(tilt.is_finite() && tilt >= 0.0) {
            return Err(invalid(
                "attenuation",
                format!("the spectral tilt must be finite and ≥ 0 s, got {tilt}"),
            ));
        }
        match &sequence.pulse {
            Some(pulse) => {
                Self::pulse_echo(probe, pulse, self.fs, tilt, Some(self), self.truncation)
            }
            None => Self::build(
                probe,
                sequence.pulse_cycles,
                self.fs,
                tilt,
                Some(self),
                self.truncation,
            ),
        }
    }

    fn build(
        probe: &Probe,
        pulse_cycles: f64,
        fs: f64,
        tilt: f64,
        like: Option<&EchoWaveform>,
        truncation: f64,
    ) -> Result<Self> {
        probe.validate()?;
        require_positive("pulse cycles", pulse_cycles)?;
        require_positive("sampling frequency", fs)?;
        let fc = probe.center_frequency;
        let p = Self::PHASES;
        let fine_rate = fs * p as f64;
        let burst = pulse_cycles / fc;
        let sigma_f = probe.bandwidth * fc / (2.0 * (2.0 * std::f64::consts::LN_2).sqrt());
        let sigma_t = 1.0 / (2.0 * std::f64::consts::PI * sigma_f);
        let half_est = 0.5 * burst + 8.0 * sigma_t;
        let len = (2.0 * (half_est * fine_rate).ceil() + 1.0).max(16.0);
        if len > (1 << 22) as f64 {
            return Err(invalid(
                "pulse",
                format!(
                    "a {pulse_cycles}-cycle pulse with {:.0} % bandwidth lasts too many samples at {:.1} MHz to tabulate",
                    probe.bandwidth * 100.0,
                    fs / 1e6
                ),
            ));
        }
        let n = 2 * (len as usize).next_power_of_two();
        let origin = n / 2;
        let mut spec: Vec<Complex64> = (0..n)
            .map(|i| {
                let t = (i as f64 - origin as f64) / fine_rate;
                let v = if t.abs() <= 0.5 * burst {
                    let hann = 0.5 * (1.0 + (2.0 * std::f64::consts::PI * t / burst).cos());
                    hann * (2.0 * std::f64::consts::PI * fc * t).cos()
                } else {
                    0.0
                };
                Complex64::new(v, 0.0)
            })
            .collect();
        let mut planner = FftPlanner64::new();
        planner.plan_fft_forward(n).process(&mut spec);
        let freq = |k: usize| {
            let k = if k <= n / 2 {
                k as f64
            } else {
                k as f64 - n as f64
            };
            k * fine_rate / n as f64
        };
        for (k, v) in spec.iter_mut().enumerate() {
            let d = (freq(k).abs() - fc) / sigma_f;
            *v *= (-0.5 * d * d).exp() / n as f64;
        }
        Self::from_spectrum(fs, spec, origin, &mut planner, (fc, tilt), like, truncation)
    }

    /// The echo waveform of `probe` for the transmit pulse of `sequence` (its sampled
    /// [`TransmitPulse`] when it has one, else a burst of `pulse_cycles` cycles), sampled at `fs`.
    pub fn for_sequence(probe: &Probe, sequence: &Sequence, fs: f64) -> Result<Self> {
        Self::for_sequence_truncated(probe, sequence, fs, Self::DEFAULT_TRUNCATION)
    }

    /// [`EchoWaveform::for_sequence`], its span holding every sample above `truncation` of its
    /// peak (a fraction in (10⁻⁶, 0.1]; [`Self::DEFAULT_TRUNCATION`] is −70.5 dB).
    pub fn for_sequence_truncated(
        probe: &Probe,
        sequence: &Sequence,
        fs: f64,
        truncation: f64,
    ) -> Result<Self> {
        if !(truncation > 1e-6 && truncation <= 0.1) {
            return Err(invalid(
                "waveform truncation",
                format!("{truncation:e} of the peak: must lie in (10⁻⁶, 0.1] (−120 to −20 dB)"),
            ));
        }
        match &sequence.pulse {
            Some(pulse) => Self::pulse_echo(probe, pulse, fs, 0.0, None, truncation),
            None => Self::build(probe, sequence.pulse_cycles, fs, 0.0, None, truncation),
        }
    }

    /// The echo waveform of `probe` for a sampled transmit pulse, sampled at `fs` (Hz): the pulse
    /// (band-limited to half its own sampling rate) through the probe's Gaussian two-way response,
    /// with its time origin moved to the envelope peak, so that an echo arriving at τ peaks at τ
    /// as the default pulse's does.
    pub fn from_pulse(probe: &Probe, pulse: &TransmitPulse, fs: f64) -> Result<Self> {
        Self::pulse_echo(probe, pulse, fs, 0.0, None, Self::DEFAULT_TRUNCATION)
    }

    /// [`EchoWaveform::from_pulse`], attenuated by `tilt` and tabulated like `like` as
    /// [`EchoWaveform::attenuated`] says.
    fn pulse_echo(
        probe: &Probe,
        pulse: &TransmitPulse,
        fs: f64,
        tilt: f64,
        like: Option<&EchoWaveform>,
        truncation: f64,
    ) -> Result<Self> {
        probe.validate()?;
        pulse.validate()?;
        require_positive("sampling frequency", fs)?;
        let fc = probe.center_frequency;
        let p = Self::PHASES;
        let fine_rate = fs * p as f64;
        let sigma_f = probe.bandwidth * fc / (2.0 * (2.0 * std::f64::consts::LN_2).sqrt());
        let sigma_t = 1.0 / (2.0 * std::f64::consts::PI * sigma_f);
        // The envelope peak may lie anywhere in the pulse: room for its whole length either side.
        let half_est = pulse.duration() + 8.0 * sigma_t;
        let len = (2.0 * (half_est * fine_rate).ceil() + 1.0).max(16.0);
        if len > (1 << 22) as f64 {
            return Err(invalid(
                "pulse samples",
                format!(
                    "a {:.3} µs pulse with {:.0} % bandwidth lasts too many samples at {:.1} MHz to \
                     tabulate",
                    pulse.duration() * 1e6,
                    probe.bandwidth * 100.0,
                    fs / 1e6
                ),
            ));
        }
        let n = 2 * (len as usize).next_power_of_two();
        let origin = n / 2;
        let freq = |k: usize| {
            let k = if k <= n / 2 {
                k as f64
            } else {
                k as f64 - n as f64
            };
            k * fine_rate / n as f64
        };
        // The pulse's spectrum (its samples as band-limited impulses, centred on the origin) where
        // the probe passes anything: the Gaussian response is below 10⁻²⁰ beyond 9.6 σ_f.
        let fp = pulse.sampling_frequency;
        let centre = 0.5 * (pulse.samples.len() as f64 - 1.0) / fp;
        let mut spec: Vec<Complex64> = (0..n)
            .map(|k| {
                let f = freq(k);
                let d = (f.abs() - fc) / sigma_f;
                if d.abs() > 9.6 || f.abs() >= 0.5 * fp {
                    return Complex64::new(0.0, 0.0);
                }
                let dtft: Complex64 = pulse
                    .samples
                    .iter()
                    .enumerate()
                    .map(|(j, &v)| {
                        let t = j as f64 / fp - centre;
                        Complex64::from_polar(v, -2.0 * std::f64::consts::PI * f * t)
                    })
                    .sum();
                dtft * (-0.5 * d * d).exp()
            })
            .collect();
        // Where the echo's envelope peaks: the origin moves there.
        let mut planner = FftPlanner64::new();
        let mut analytic: Vec<Complex64> = (0..n)
            .map(|k| {
                if k < n / 2 {
                    spec[k]
                } else {
                    Complex64::new(0.0, 0.0)
                }
            })
            .collect();
        planner.plan_fft_inverse(n).process(&mut analytic);
        let peak = analytic
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.norm().total_cmp(&b.1.norm()))
            .map_or(origin, |(i, _)| i);
        let t_peak = (peak as f64 - origin as f64) / fine_rate;
        for (k, v) in spec.iter_mut().enumerate() {
            *v *= Complex64::from_polar(
                1.0 / n as f64,
                2.0 * std::f64::consts::PI * freq(k) * t_peak,
            );
        }
        Self::from_spectrum(fs, spec, origin, &mut planner, (fc, tilt), like, truncation)
    }

    /// The tables from the echo's spectrum `spec` on the fine grid (PHASES·`fs`, its time origin
    /// at index `origin`), already filtered and scaled by 1/len, after the attenuation
    /// `(f_c, tilt)` (exp(−tilt·(|f| − f_c)); tilt 0 leaves it); `like` gives the scale, span and
    /// taps of an attenuated table ([`EchoWaveform::attenuated`]).
    fn from_spectrum(
        fs: f64,
        mut spec: Vec<Complex64>,
        origin: usize,
        planner: &mut FftPlanner64,
        (fc, tilt): (f64, f64),
        like: Option<&EchoWaveform>,
        truncation: f64,
    ) -> Result<Self> {
        let p = Self::PHASES;
        let fine_rate = fs * p as f64;
        let n = spec.len();
        if tilt > 0.0 {
            for (k, v) in spec.iter_mut().enumerate() {
                let f = if k <= n / 2 {
                    k as f64
                } else {
                    k as f64 - n as f64
                } * fine_rate
                    / n as f64;
                *v *= (-tilt * (f.abs() - fc)).exp();
            }
        }
        // Analytic signal for the envelope: keep positive frequencies, doubled.
        let mut analytic: Vec<Complex64> = spec
            .iter()
            .enumerate()
            .map(|(k, &v)| match k {
                0 => v,
                k if k < n / 2 => 2.0 * v,
                k if k == n / 2 => v,
                _ => Complex64::new(0.0, 0.0),
            })
            .collect();
        let inverse = planner.plan_fft_inverse(n);
        inverse.process(&mut spec);
        inverse.process(&mut analytic);
        let mut fine: Vec<f64> = spec.iter().map(|v| v.re).collect();
        // A blended table keeps the unattenuated echo's scale, span and taps.
        let peak = like.map_or_else(
            || fine.iter().fold(0.0f64, |m, v| m.max(v.abs())),
            |w| w.peak,
        );
        if !(peak > 0.0 && peak.is_finite()) {
            return Err(invalid(
                "pulse",
                "the transmit pulse has no energy in the probe's band",
            ));
        }
        fine.iter_mut().for_each(|v| *v /= peak);
        let env_peak = analytic
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.norm().total_cmp(&b.1.norm()))
            .map_or(origin, |(i, _)| i);
        let peak_offset = (env_peak as f64 - origin as f64) / fine_rate;
        let lo = fine.iter().position(|v| v.abs() > truncation).unwrap_or(0);
        let hi = fine
            .iter()
            .rposition(|v| v.abs() > truncation)
            .unwrap_or(n - 1);
        let half_fine = like.map_or((origin - lo).max(hi - origin), |w| w.half_fine);
        let half_duration = half_fine as f64 / fine_rate;
        // Row p covers (j − half − p/P) samples for j < taps: [−half, taps − half − 1] ⊇ [−H, H + 1].
        let half = half_fine.div_ceil(p);
        let taps = (half + (half_fine + p).div_ceil(p) + 1).div_ceil(8) * 8;
        let mut table = vec![0.0f32; (p + 1) * taps];
        for phase in 0..=p {
            for j in 0..taps {
                // Tap j of phase row `phase` is the waveform at (j − half − phase/P) samples.
                let idx = origin as i64 + (j as i64 - half as i64) * p as i64 - phase as i64;
                if (0..n as i64).contains(&idx) {
                    table[phase * taps + j] = fine[idx as usize] as f32;
                }
            }
        }
        // Farrow form: tap j at delay μ is w(j − half − μ) (samples); fit Σ_q c_q (μ − ½)^q by least
        // squares on μ = phase / P, in the Chebyshev basis T_q(2μ − 1) (well conditioned), then
        // converted to powers of m = μ − ½ (T_q(2m) = Σ_k t_qk 2^k m^k).
        let mono = chebyshev_to_monomial(FARROW_TERMS);
        let basis: Vec<[f64; FARROW_TERMS]> = (0..=p)
            .map(|phase| {
                let y = 2.0 * phase as f64 / p as f64 - 1.0;
                let mut t = [0.0f64; FARROW_TERMS];
                t[0] = 1.0;
                t[1] = y;
                for q in 2..FARROW_TERMS {
                    t[q] = 2.0 * y * t[q - 1] - t[q - 2];
                }
                t
            })
            .collect();
        let mut gram = [[0.0f64; FARROW_TERMS]; FARROW_TERMS];
        for t in &basis {
            for a in 0..FARROW_TERMS {
                for b in 0..FARROW_TERMS {
                    gram[a][b] += t[a] * t[b];
                }
            }
        }
        let farrow = (0..taps)
            .map(|j| {
                let mut rhs = [0.0f64; FARROW_TERMS];
                for (phase, t) in basis.iter().enumerate() {
                    let idx = origin as i64 + (j as i64 - half as i64) * p as i64 - phase as i64;
                    let v = if (0..n as i64).contains(&idx) {
                        fine[idx as usize]
                    } else {
                        0.0
                    };
                    for q in 0..FARROW_TERMS {
                        rhs[q] += t[q] * v;
                    }
                }
                let cheb = solve_spd(gram, rhs);
                let mut row = [0.0f32; FARROW_TERMS];
                for (k, r) in row.iter_mut().enumerate() {
                    let c: f64 = (0..FARROW_TERMS).map(|q| cheb[q] * mono[q][k]).sum();
                    *r = (c * 2f64.powi(k as i32)) as f32;
                }
                row
            })
            .collect();
        Ok(EchoWaveform {
            fs,
            peak,
            half_fine,
            taps,
            half,
            table,
            farrow,
            fine,
            fine_origin: origin,
            half_duration,
            peak_offset,
            truncation,
        })
    }

    /// The waveform at time `t` (s) from its origin (linear interpolation of a grid at PHASES·f_s).
    pub fn value(&self, t: f64) -> f64 {
        let u = t * self.fs * Self::PHASES as f64 + self.fine_origin as f64;
        if !(u >= 0.0 && u < (self.fine.len() - 1) as f64) {
            return 0.0;
        }
        let i = u as usize;
        let w = u - i as f64;
        self.fine[i] * (1.0 - w) + self.fine[i + 1] * w
    }

    /// Time (s) of the envelope peak relative to the waveform's origin (0 up to the fine grid).
    pub fn peak_offset(&self) -> f64 {
        self.peak_offset
    }

    /// Half the waveform's duration (s): beyond ±this, |w| ≤ 3·10⁻⁴ of its peak (−70 dB).
    pub fn half_duration(&self) -> f64 {
        self.half_duration
    }

    /// Samples per tabulated row (a multiple of 8).
    pub fn taps(&self) -> usize {
        self.taps
    }

    /// Tap index (samples) of the waveform's origin in a row of phase 0.
    pub fn origin_tap(&self) -> usize {
        self.half
    }

    /// The polyphase table, row-major ((PHASES + 1) × taps); row p holds the waveform at
    /// (j − origin_tap − p/PHASES) samples.
    pub fn table(&self) -> &[f32] {
        &self.table
    }

    /// Farrow coefficients, one row per tap: tap j of an echo starting `μ` ∈ [0, 1] samples after a
    /// row of phase 0 is Σ_q row[j][q]·(μ − ½)^q.
    pub(crate) fn farrow(&self) -> &[[f32; FARROW_TERMS]] {
        &self.farrow
    }

    /// Sampling frequency the table was built for (Hz).
    pub fn sampling_frequency(&self) -> f64 {
        self.fs
    }
}

/// Monomial coefficients of the Chebyshev polynomials: `t[q][k]` is the coefficient of y^k in T_q(y).
fn chebyshev_to_monomial(n: usize) -> Vec<Vec<f64>> {
    let mut t = vec![vec![0.0f64; n]; n];
    t[0][0] = 1.0;
    if n > 1 {
        t[1][1] = 1.0;
    }
    for q in 2..n {
        for k in 0..n {
            let up = if k > 0 { 2.0 * t[q - 1][k - 1] } else { 0.0 };
            t[q][k] = up - t[q - 2][k];
        }
    }
    t
}

/// Solves a small symmetric positive-definite system by Cholesky decomposition.
fn solve_spd<const N: usize>(a: [[f64; N]; N], b: [f64; N]) -> [f64; N] {
    let mut l = [[0.0f64; N]; N];
    for i in 0..N {
        for j in 0..=i {
            let s: f64 = (0..j).map(|k| l[i][k] * l[j][k]).sum();
            l[i][j] = if i == j {
                (a[i][i] - s).sqrt()
            } else {
                (a[i][j] - s) / l[j][j]
            };
        }
    }
    let mut y = [0.0f64; N];
    for i in 0..N {
        let s: f64 = (0..i).map(|k| l[i][k] * y[k]).sum();
        y[i] = (b[i] - s) / l[i][i];
    }
    let mut x = [0.0f64; N];
    for i in (0..N).rev() {
        let s: f64 = (i + 1..N).map(|k| l[k][i] * x[k]).sum();
        x[i] = (y[i] - s) / l[i][i];
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Farrow polynomials reproduce every row of the polyphase table.
    #[test]
    fn farrow_form_matches_the_table() {
        for (probe, fs) in [(Probe::l22_14vx(), 65e6), (Probe::l11_5v(), 31.25e6)] {
            let wf = EchoWaveform::new(&probe, 2.0, fs).unwrap();
            let p = EchoWaveform::PHASES;
            let mut worst = 0.0f64;
            for phase in 0..=p {
                let m = phase as f64 / p as f64 - 0.5;
                for (j, c) in wf.farrow().iter().enumerate() {
                    let v: f64 = c.iter().rev().fold(0.0, |acc, &ck| acc * m + ck as f64);
                    worst = worst.max((v - wf.table()[phase * wf.taps() + j] as f64).abs());
                }
            }
            assert!(worst < 2e-6, "{}: worst tap error {worst:e}", probe.name);
        }
    }

    /// The truncation level: `half_duration` is where |w| last exceeds the level of its peak, and
    /// the tabulated rows hold every sample above that level; at the default level and at a
    /// tighter one a scenario may ask for.
    #[test]
    fn truncated_at_the_level_asked_for() {
        // 3·10⁻⁴ of the peak is −70.5 dB (what the docs say).
        assert!((20.0 * EchoWaveform::DEFAULT_TRUNCATION.log10() + 70.46).abs() < 0.01);
        let sequence = |cycles| Sequence {
            angles: vec![0.0],
            event_prf: 1e4,
            coding: crate::acquisition::sequence::Coding::Conventional,
            pulse_cycles: cycles,
            pulse: None,
        };
        let mut spans = Vec::new();
        for level in [EchoWaveform::DEFAULT_TRUNCATION, 1e-5] {
            for (probe, fs, cycles) in [
                (Probe::l22_14vx(), 65e6, 2.0),
                (Probe::l11_5v(), 31.25e6, 2.0),
                (Probe::l22_14vx(), 65e6, 4.0),
            ] {
                let wf = EchoWaveform::for_sequence_truncated(&probe, &sequence(cycles), fs, level)
                    .unwrap();
                let fine_rate = fs * EchoWaveform::PHASES as f64;
                let edge = (wf.half_duration() * fine_rate).round() as usize;
                let (lo, hi) = (wf.fine_origin - edge, wf.fine_origin + edge);
                // Beyond ±half_duration the waveform never exceeds the level...
                let outside = wf.fine[..lo]
                    .iter()
                    .chain(&wf.fine[hi + 1..])
                    .fold(0.0f64, |m, v| m.max(v.abs()));
                assert!(outside <= level, "{}: {outside:e} outside", probe.name);
                // ... and at one of its ends it does: half_duration is no longer than needed.
                let at_edge = wf.fine[lo].abs().max(wf.fine[hi].abs());
                assert!(at_edge > level, "{}: {at_edge:e} at the edge", probe.name);
                // Every polyphase row spans [−half_duration, half_duration]: the first tap of
                // row 0 is at −origin_tap samples, the last tap of the last row (delay 1 sample)
                // at taps − 1 − origin_tap − 1 samples.
                let h = wf.half_duration() * fs;
                assert!(wf.origin_tap() as f64 >= h, "{}", probe.name);
                assert!(
                    (wf.taps() - 2 - wf.origin_tap()) as f64 >= h,
                    "{}",
                    probe.name
                );
                spans.push(wf.half_duration());
            }
        }
        // The tighter level keeps a longer echo of every pulse.
        assert!((0..3).all(|i| spans[i + 3] > spans[i]), "{spans:?}");
        let refused =
            EchoWaveform::for_sequence_truncated(&Probe::l22_14vx(), &sequence(2.0), 65e6, 0.5);
        assert!(refused.unwrap_err().to_string().contains("truncation"));
    }

    /// A sampled pulse that is the default Hann burst (sampled at 1 GHz) gives the default echo,
    /// and so does the same burst after 100 ns of silence: the origin is the envelope peak.
    #[test]
    fn sampled_pulse_gives_the_bursts_echo() {
        let probe = Probe::l22_14vx();
        let fs = 65e6;
        let fc = probe.center_frequency;
        let reference = EchoWaveform::new(&probe, 2.0, fs).unwrap();
        let rate = 1e9;
        let burst = 2.0 / fc;
        let m = (burst * rate).round() as usize;
        let samples: Vec<f64> = (0..=m)
            .map(|j| {
                let t = j as f64 / rate - 0.5 * burst;
                0.5 * (1.0 + (std::f64::consts::TAU * t / burst).cos())
                    * (std::f64::consts::TAU * fc * t).cos()
            })
            .collect();
        for lead in [0usize, 100] {
            let pulse = TransmitPulse {
                samples: std::iter::repeat_n(0.0, lead)
                    .chain(samples.iter().copied())
                    .collect(),
                sampling_frequency: rate,
            };
            let wf = EchoWaveform::from_pulse(&probe, &pulse, fs).unwrap();
            assert!(
                wf.peak_offset().abs() < 1.0 / (fs * 64.0),
                "{}",
                wf.peak_offset()
            );
            let worst = (-400..=400)
                .map(|i| {
                    let t = i as f64 * 1e-9;
                    (wf.value(t) - reference.value(t)).abs()
                })
                .fold(0.0f64, f64::max);
            assert!(worst < 2e-3, "lead {lead}: worst difference {worst:e}");
        }
        // A pulse sampled too slowly for the band is refused, naming it.
        let slow = TransmitPulse {
            samples: vec![1.0, -1.0, 1.0],
            sampling_frequency: 0.0,
        };
        let e = EchoWaveform::from_pulse(&probe, &slow, fs)
            .unwrap_err()
            .to_string();
        assert!(e.contains("pulse sampling frequency"), "{e}");
    }
}
