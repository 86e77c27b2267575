//! Encoding per-angle records into coded events: the inverse of decoding for a still medium, for
//! simulation and tests.

use super::*;

/// Encodes per-angle records (angles, channels, samples) into the n events of one coded compound
/// frame (events, channels, samples): event i = `Σ_k H[i][k]·x_k` delayed by k·`slot_shift` samples.
/// The inverse of [`Decoder::hadamard`]'s decoding for a still medium, up to the factor n.
pub fn encode(per_angle: ArrayView3<f32>, h: &Hadamard, slot_shift: f64) -> Result<Array3<f32>> {
    let n = per_angle.dim().0;
    if n != h.order() {
        return Err(Error::Shape(format!(
            "{n} angles for a Hadamard matrix of order {}",
            h.order()
        )));
    }
    let shifts: Vec<f64> = (0..n).map(|k| k as f64 * slot_shift).collect();
    Ok(encode_with(per_angle, |i, k| h.get(i, k), &shifts))
}

/// Encodes per-angle records (angles, channels, samples) sampled at `sampling_frequency` (Hz)
/// into the n events of one compound frame transmitted with `code`: event i =
/// `Σ_k A[i][k]·x_k` delayed by slot k's start. The inverse of [`Decoder::code`]'s decoding for a still medium,
/// up to the factor [`TransmitCode::decoding_gain`].
pub fn encode_code(
    per_angle: ArrayView3<f32>,
    code: &TransmitCode,
    sampling_frequency: f64,
) -> Result<Array3<f32>> {
    code.validate()?;
    let n = per_angle.dim().0;
    if n != code.order() {
        return Err(Error::Shape(format!(
            "{n} angles for a transmit code of order {}",
            code.order()
        )));
    }
    let shifts: Vec<f64> = code
        .slot_starts
        .iter()
        .map(|t| t * sampling_frequency)
        .collect();
    Ok(encode_with(
        per_angle,
        |i, k| code.weight(i, k) as f32,
        &shifts,
    ))
}

/// Event i = Σ_k weight(i, k)·x_k delayed by `shifts[k]` samples.
pub(super) fn encode_with(
    per_angle: ArrayView3<f32>,
    weight: impl Fn(usize, usize) -> f32,
    shifts: &[f64],
) -> Array3<f32> {
    let (n, nc, ns) = per_angle.dim();
    let max_shift = shifts.iter().fold(0.0f64, |m, s| m.max(s.abs()));
    let shifter = TraceShifter::new(ns, max_shift);
    let mut delayed = per_angle.to_owned();
    for (k, mut angle) in delayed.outer_iter_mut().enumerate() {
        for mut row in angle.outer_iter_mut() {
            let mut trace = row.to_vec();
            shifter.shift_real(&mut trace, -shifts[k]);
            row.assign(&ndarray::ArrayView1::from(&trace));
        }
    }
    let mut out = Array3::<f32>::zeros((n, nc, ns));
    for i in 0..n {
        for k in 0..n {
            let sign = weight(i, k);
            out.slice_mut(s![i, .., ..])
                .zip_mut_with(&delayed.slice(s![k, .., ..]), |o, &x| *o += x * sign);
        }
    }
    out
}
