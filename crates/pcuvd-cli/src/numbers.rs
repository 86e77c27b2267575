//! Numbers as the reports show them: a dash where there is none.

/// `x` with `decimals` decimals, or "–" when it is not finite (a score with nothing to score).
pub fn finite(x: f64, decimals: usize) -> String {
    if x.is_finite() {
        rounded(x, decimals)
    } else {
        "–".into()
    }
}

/// `x` with `decimals` decimals, without the sign where it rounds to zero: an improvement of
/// −0.3 % reads "0", not "-0".
pub fn rounded(x: f64, decimals: usize) -> String {
    let text = format!("{x:.decimals$}");
    match text.strip_prefix('-') {
        Some(unsigned) if unsigned.chars().all(|c| c == '0' || c == '.') => unsigned.to_string(),
        _ => text,
    }
}

/// The fraction `x` as a percentage with one decimal, or "–" when it is not finite.
pub fn percent(x: f64) -> String {
    if x.is_finite() {
        format!("{} %", rounded(100.0 * x, 1))
    } else {
        "–".into()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn what_rounds_to_zero_reads_without_a_sign() {
        assert_eq!(rounded(-0.3, 0), "0");
        assert_eq!(rounded(-0.004, 2), "0.00");
        assert_eq!(rounded(-0.6, 0), "-1");
        assert_eq!(rounded(-0.006, 2), "-0.01");
        assert_eq!(rounded(-10.0, 0), "-10");
        assert_eq!(finite(-0.0, 1), "0.0");
        assert_eq!(percent(-0.0004), "0.0 %");
        assert_eq!(finite(f64::NAN, 1), "–");
    }
}
