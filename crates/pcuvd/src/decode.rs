//! Hadamard decoding: from coded transmit events back to one record per steering angle.
//!
//! In event i of a compound frame, slot k fired angle θ_k with polarity H[i][k] after τ_k = k·Δτ.
//! Decoding is RF = Hᵀ·M over the n events of the frame (eq. 2), then each slot k is advanced by
//! τ_k (eq. 3) so that every angle's record has the same time origin t0. When τ_k·f_s is not an
//! integer the advance is a band-limited fractional shift (FFT phase ramp). For a still medium
//! decode(encode(x)) = n·x; moving scatterers break the assumption (see DESIGN.md, "Coding and motion").
//! Conventional sequences are only split: event i of a frame is angle i.

use std::sync::Arc;

use ndarray::{Array3, Array4, ArrayView3, Axis, s};
use num_complex::Complex32;
use num_traits::Zero;
use rayon::prelude::*;
use rustfft::{Fft, FftPlanner};

use crate::channel::{AngleSamples, ChannelData, Samples};
use crate::error::{Error, Result};
use crate::hadamard::Hadamard;
use crate::sequence::Coding;

/// Advances traces of a fixed length by a (possibly fractional) number of samples: y[t] = x[t + shift].
/// Samples shifted in from beyond the end are zero.
pub struct TraceShifter {
    len: usize,
    fft_len: usize,
    forward: Arc<dyn Fft<f32>>,
    inverse: Arc<dyn Fft<f32>>,
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
        let mut planner = FftPlanner::new();
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

fn shift_integer<T: Copy>(trace: &mut [T], shift: isize, zero: T) {
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

/// Separates a recording into one record per angle: shape (angles, frames, channels, samples).
pub fn decode(data: &ChannelData) -> Result<AngleSamples> {
    data.validate()?;
    let acq = &data.acquisition;
    let n = acq.sequence.n_angles();
    let slot_shift = match acq.sequence.coding {
        Coding::Conventional => None,
        Coding::Hadamard { slot_delay } => Some(slot_delay * acq.sampling_frequency),
    };
    match &data.samples {
        Samples::Rf(rf) => {
            let out = match slot_shift {
                None => split(rf.view(), n),
                Some(shift) => {
                    decode_events(rf.view(), &Hadamard::new(n)?, shift, |shifter, tr, s| {
                        shifter.shift_real(tr, s)
                    })
                }
            };
            Ok(AngleSamples::Rf(out))
        }
        Samples::Iq {
            data: iq,
            demod_frequency,
        } => {
            let fd = *demod_frequency;
            let fs = acq.sampling_frequency;
            let out = match slot_shift {
                None => split(iq.view(), n),
                Some(shift) => {
                    decode_events(iq.view(), &Hadamard::new(n)?, shift, |shifter, tr, s| {
                        shifter.shift_complex(tr, s);
                        // Baseband of an advanced analytic signal: IQ(t + τ)·exp(+2πi f_d τ).
                        let phase = 2.0 * std::f64::consts::PI * fd * s / fs;
                        let rot = Complex32::new(phase.cos() as f32, phase.sin() as f32);
                        tr.iter_mut().for_each(|v| *v *= rot);
                    })
                }
            };
            Ok(AngleSamples::Iq {
                data: out,
                demod_frequency: fd,
            })
        }
    }
}

fn split<T: Copy + Send + Sync + Zero>(events: ArrayView3<T>, n: usize) -> Array4<T> {
    let (ne, nc, ns) = events.dim();
    let frames = ne / n;
    let mut out = Array4::<T>::from_elem((n, frames, nc, ns), T::zero());
    for k in 0..n {
        out.slice_mut(s![k, .., .., ..])
            .assign(&events.slice(s![k..;n, .., ..]));
    }
    out
}

/// Decodes coded events: for every frame, Hᵀ·M, then slot k advanced by k·`slot_shift` samples.
fn decode_events<T, F>(events: ArrayView3<T>, h: &Hadamard, slot_shift: f64, shift: F) -> Array4<T>
where
    T: Copy + Send + Sync + Zero + std::ops::Mul<f32, Output = T> + std::ops::AddAssign,
    F: Fn(&TraceShifter, &mut [T], f64) + Sync,
{
    let n = h.order();
    let (ne, nc, ns) = events.dim();
    let frames = ne / n;
    let shifter = TraceShifter::new(ns, slot_shift * (n - 1) as f64);
    let mut out = Array4::<T>::from_elem((n, frames, nc, ns), T::zero());
    out.axis_iter_mut(Axis(1))
        .into_par_iter()
        .enumerate()
        .for_each(|(f, mut frame_out)| {
            for k in 0..n {
                let mut acc = Array3::<T>::from_elem((1, nc, ns), T::zero());
                for i in 0..n {
                    let sign = h.get(i, k);
                    let ev = events.slice(s![f * n + i, .., ..]);
                    acc.slice_mut(s![0, .., ..])
                        .zip_mut_with(&ev, |a, &m| *a += m * sign);
                }
                let mut dest = frame_out.slice_mut(s![k, .., ..]);
                for (mut row, acc_row) in dest
                    .outer_iter_mut()
                    .zip(acc.slice(s![0, .., ..]).outer_iter())
                {
                    let mut trace = acc_row.to_vec();
                    shift(&shifter, &mut trace, k as f64 * slot_shift);
                    row.assign(&ndarray::ArrayView1::from(&trace));
                }
            }
        });
    out
}

/// Encodes per-angle records (angles, channels, samples) into the n events of one coded compound
/// frame (events, channels, samples): event i = Σ_k H[i][k]·x_k delayed by k·`slot_shift` samples.
/// The inverse of [`decode`] for a still medium, up to the factor n.
pub fn encode(per_angle: ArrayView3<f32>, h: &Hadamard, slot_shift: f64) -> Result<Array3<f32>> {
    let (n, nc, ns) = per_angle.dim();
    if n != h.order() {
        return Err(Error::Shape(format!(
            "{n} angles for a Hadamard matrix of order {}",
            h.order()
        )));
    }
    let shifter = TraceShifter::new(ns, slot_shift * (n - 1) as f64);
    let mut delayed = per_angle.to_owned();
    for (k, mut angle) in delayed.outer_iter_mut().enumerate() {
        for mut row in angle.outer_iter_mut() {
            let mut trace = row.to_vec();
            shifter.shift_real(&mut trace, -(k as f64) * slot_shift);
            row.assign(&ndarray::ArrayView1::from(&trace));
        }
    }
    let mut out = Array3::<f32>::zeros((n, nc, ns));
    for i in 0..n {
        for k in 0..n {
            let sign = h.get(i, k);
            out.slice_mut(s![i, .., ..])
                .zip_mut_with(&delayed.slice(s![k, .., ..]), |o, &x| *o += x * sign);
        }
    }
    Ok(out)
}
