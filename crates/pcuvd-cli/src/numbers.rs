//! Numbers as the reports show them: a dash where there is none.

/// `x` with `decimals` decimals, or "–" when it is not finite (a score with nothing to score).
pub fn finite(x: f64, decimals: usize) -> String {
    if x.is_finite() {
        format!("{x:.decimals$}")
    } else {
        "–".into()
    }
}

/// The fraction `x` as a percentage with one decimal, or "–" when it is not finite.
pub fn percent(x: f64) -> String {
    if x.is_finite() {
        format!("{:.1} %", 100.0 * x)
    } else {
        "–".into()
    }
}
