//! Advancing a trace by a fractional number of samples: whole samples moved, the rest a
//! band-limited phase ramp (RF) or a phase rotation at the demodulation frequency (IQ).

use super::*;

/// Advances traces of a fixed length by a (possibly fractional) number of samples: `y[t] = x[t + shift]`.
/// Samples shifted in from beyond the end are zero.
pub struct TraceShifter {
    pub(super) len: usize,
    pub(super) fft_len: usize,
    pub(super) forward: Arc<dyn Fft<f32>>,
    pub(super) inverse: Arc<dyn Fft<f32>>,
}

impl TraceShifter {
    /// A shifter for traces of `len` samples and advances of at most `max_shift` samples.
    pub fn new(len: usize, max_shift: f64) -> Self {
        // Odd length: no Nyquist bin, so a real trace stays real and shifts invert exactly.
        // The zero pad absorbs the wrap-around of the circular shift and the sinc tails.
        let mut fft_len = len + max_shift.abs().ceil() as usize + 64;
        if fft_len.is_multiple_of(2) {
            fft_len += 1;
        }
        let mut planner = FftPlanner32::new();
        TraceShifter {
            len,
            fft_len,
            forward: planner.plan_fft_forward(fft_len),
            inverse: planner.plan_fft_inverse(fft_len),
        }
    }

    /// Advances `trace` in place by `shift` samples (negative delays it).
    pub fn shift_complex(&self, trace: &mut [Complex32], shift: f64) {
        assert_eq!(trace.len(), self.len);
        let rounded = shift.round();
        if (shift - rounded).abs() < 1e-9 {
            shift_integer(trace, rounded as isize, Complex32::new(0.0, 0.0));
            return;
        }
        let mut buf = vec![Complex32::new(0.0, 0.0); self.fft_len];
        buf[..self.len].copy_from_slice(trace);
        self.forward.process(&mut buf);
        let n = self.fft_len as f64;
        let half = (self.fft_len - 1) / 2;
        for (k, v) in buf.iter_mut().enumerate() {
            let freq = if k <= half { k as f64 } else { k as f64 - n };
            let phase = 2.0 * std::f64::consts::PI * freq * shift / n;
            *v *= Complex32::new(phase.cos() as f32, phase.sin() as f32) / self.fft_len as f32;
        }
        self.inverse.process(&mut buf);
        trace.copy_from_slice(&buf[..self.len]);
    }

    /// Advances a real trace in place by `shift` samples.
    pub fn shift_real(&self, trace: &mut [f32], shift: f64) {
        let rounded = shift.round();
        if (shift - rounded).abs() < 1e-9 {
            shift_integer(trace, rounded as isize, 0.0);
            return;
        }
        let mut c: Vec<Complex32> = trace.iter().map(|&v| Complex32::new(v, 0.0)).collect();
        self.shift_complex(&mut c, shift);
        for (t, v) in trace.iter_mut().zip(&c) {
            *t = v.re;
        }
    }
}

pub(super) fn shift_integer<T: Copy>(trace: &mut [T], shift: isize, zero: T) {
    let n = trace.len() as isize;
    if shift >= 0 {
        let k = shift.min(n) as usize;
        trace.copy_within(k.., 0);
        let len = trace.len();
        trace[len - k..].fill(zero);
    } else {
        let k = (-shift).min(n) as usize;
        trace.copy_within(..trace.len() - k, k);
        trace[..k].fill(zero);
    }
}

/// Advances an RF trace by a slot's start.
pub(super) fn shift_rf(shifter: &TraceShifter, trace: &mut [f32], shift: f64) {
    shifter.shift_real(trace, shift)
}

/// Advances an IQ trace demodulated at `fd` (Hz), sampled at `fs` (Hz), by a slot's start.
pub(super) fn shift_iq(fd: f64, fs: f64) -> impl Fn(&TraceShifter, &mut [Complex32], f64) + Sync {
    move |shifter, trace, shift| {
        shifter.shift_complex(trace, shift);
        // Baseband of an advanced analytic signal: IQ(t + τ)·exp(+2πi f_d τ).
        let phase = 2.0 * std::f64::consts::PI * fd * shift / fs;
        let rot = Complex32::new(phase.cos() as f32, phase.sin() as f32);
        trace.iter_mut().for_each(|v| *v *= rot);
    }
}
