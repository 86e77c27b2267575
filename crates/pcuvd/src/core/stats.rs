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

/// Median of `values` (the mean of the two middle values for an even count; NaNs sort last);
/// NaN when `values` is empty.
pub fn median(mut values: Vec<f64>) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(|a, b| a.total_cmp(b));
    let n = values.len();
    if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_of_odd_and_even_counts() {
        assert_eq!(median(vec![3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(vec![4.0, 1.0, 3.0, 2.0]), 2.5);
        assert!(median(vec![]).is_nan());
        // NaN sorts last: the median of (1, 2, NaN) is the middle finite value.
        assert_eq!(median(vec![f64::NAN, 2.0, 1.0]), 2.0);
    }

    #[test]
    fn quantile_takes_the_rounded_rank_of_finite_values() {
        let v = [5.0, 1.0, f64::NAN, 3.0, 2.0, 4.0];
        assert_eq!(quantile(v.iter().copied(), 0.0), 1.0);
        assert_eq!(quantile(v.iter().copied(), 1.0), 5.0);
        // rank round(4 × 0.3) = 1 of (1, 2, 3, 4, 5)
        assert_eq!(quantile(v.iter().copied(), 0.3), 2.0);
        assert!(quantile([f64::NAN].into_iter(), 0.5).is_nan());
    }
}
