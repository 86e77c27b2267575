//! Order statistics shared by the science and the command line.

/// The `q`-quantile (0..1, clamped) of the finite values of `values`: the value at rank
/// round((n − 1)·q) of the sorted finite values (no interpolation); NaN when none is finite.
pub fn quantile(values: impl Iterator<Item = f64>, q: f64) -> f64 {
    let mut v: Vec<f64> = values.filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    v[((v.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize]
}
