//! Unit conversions people read results in.

/// `ratio` (a power ratio) in dB: 10·log10(ratio).
pub fn power_to_db(ratio: f64) -> f64 {
    10.0 * ratio.log10()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn power_to_db_of_known_ratios() {
        assert_eq!(power_to_db(1.0), 0.0);
        assert!((power_to_db(100.0) - 20.0).abs() < 1e-12);
        assert!((power_to_db(0.5) + 3.010_299_956_639_812).abs() < 1e-12);
    }
}
