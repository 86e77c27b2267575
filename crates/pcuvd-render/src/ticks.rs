//! Axis tick placement and labelling.

/// A tick: value in data units (linear) and its label.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Tick {
    pub value: f64,
    pub label: String,
}

/// "Nice" linear ticks inside [lo, hi], at most `max_n` of them (at least 2 when possible).
pub(crate) fn linear_ticks(lo: f64, hi: f64, max_n: usize) -> Vec<Tick> {
    if !(lo.is_finite() && hi.is_finite()) {
        return Vec::new();
    }
    let (lo, hi) = if lo <= hi { (lo, hi) } else { (hi, lo) };
    if hi - lo <= f64::EPSILON * lo.abs().max(1.0) {
        return vec![Tick {
            value: lo,
            label: format_with_decimals(lo, 2),
        }];
    }
    let max_n = max_n.max(1);
    let span = hi - lo;
    let raw = span / (max_n.max(2) - 1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let mut chosen = None;
    for exp_shift in [0.0, 1.0, 2.0] {
        for m in [1.0, 2.0, 2.5, 5.0] {
            let step = m * mag * 10f64.powf(exp_shift);
            let first = (lo / step - 1e-9).ceil();
            let last = (hi / step + 1e-9).floor();
            let n = (last - first + 1.0).max(0.0) as usize;
            if n <= max_n {
                chosen = Some((step, m, first, last));
                break;
            }
        }
        if chosen.is_some() {
            break;
        }
    }
    let Some((step, m, first, last)) = chosen else {
        return Vec::new();
    };
    let e = (step.log10() + 1e-9).floor();
    let mut decimals = (-e).max(0.0) as usize;
    if m == 2.5 && e <= 0.0 {
        decimals += 1;
    }
    let big = lo.abs().max(hi.abs());
    let sci = big >= 1e5 || (step < 1e-4);
    let mut out = Vec::new();
    let mut k = first;
    while k <= last + 0.5 {
        let v = k * step;
        let v = if v.abs() < step * 1e-9 { 0.0 } else { v };
        let label = if sci {
            format_sci(v)
        } else {
            format_with_decimals(v, decimals)
        };
        out.push(Tick { value: v, label });
        k += 1.0;
    }
    out
}

/// Ticks for a log10 axis over [lo, hi] (both > 0); `value` is the linear value.
pub(crate) fn log_ticks(lo: f64, hi: f64, max_n: usize) -> Vec<Tick> {
    if !(lo > 0.0 && hi > lo && hi.is_finite()) {
        return Vec::new();
    }
    let (a, b) = (lo.log10(), hi.log10());
    let k0 = (a - 1e-9).ceil() as i32;
    let k1 = (b + 1e-9).floor() as i32;
    let n_dec = (k1 - k0 + 1).max(0) as usize;
    let mut vals: Vec<f64> = Vec::new();
    if n_dec >= 2 {
        // Decades, thinned if too many.
        let stride = n_dec.div_ceil(max_n.max(2)).max(1) as i32;
        let mut k = k0;
        while k <= k1 {
            vals.push(10f64.powi(k));
            k += stride;
        }
        if n_dec <= 2 {
            // Few decades: add 2x and 5x.
            for k in (k0 - 1)..=k1 {
                for m in [2.0, 5.0] {
                    let v = m * 10f64.powi(k);
                    if v >= lo * (1.0 - 1e-9) && v <= hi * (1.0 + 1e-9) {
                        vals.push(v);
                    }
                }
            }
        }
    } else {
        for k in (k0 - 2)..=(k1 + 1) {
            for m in [1.0, 2.0, 5.0] {
                let v = m * 10f64.powi(k);
                if v >= lo * (1.0 - 1e-9) && v <= hi * (1.0 + 1e-9) {
                    vals.push(v);
                }
            }
        }
        if vals.len() < 2 {
            return linear_ticks(lo, hi, max_n);
        }
    }
    vals.sort_by(|x, y| x.total_cmp(y));
    vals.dedup();
    // One notation for the whole axis: plain numbers only if all of them are short.
    let plain = vals
        .iter()
        .all(|v| (-3..=4).contains(&(v.abs().log10().floor() as i32)));
    vals.into_iter()
        .map(|v| Tick {
            value: v,
            label: if plain {
                format_plain(v)
            } else {
                format_sci(v)
            },
        })
        .collect()
}

fn trim_zeros(s: String) -> String {
    if s.contains('.') {
        let t = s.trim_end_matches('0').trim_end_matches('.');
        t.to_string()
    } else {
        s
    }
}

fn fix_negative_zero(s: String) -> String {
    if s.starts_with('-') && s[1..].chars().all(|c| c == '0' || c == '.') {
        s[1..].to_string()
    } else {
        s
    }
}

/// Fixed-point label with the given decimals; "-0" is shown as "0". Uses a true minus sign.
pub(crate) fn format_with_decimals(v: f64, decimals: usize) -> String {
    let s = fix_negative_zero(format!("{v:.decimals$}"));
    s.replacen('-', "\u{2212}", 1)
}

fn superscript(n: i32) -> String {
    n.to_string()
        .chars()
        .map(|c| match c {
            '-' => '\u{207B}',
            '0' => '\u{2070}',
            '1' => '\u{00B9}',
            '2' => '\u{00B2}',
            '3' => '\u{00B3}',
            d => char::from_u32(0x2070 + d.to_digit(10).unwrap_or(0)).unwrap_or(d),
        })
        .collect()
}

/// Scientific label "m×10ⁿ".
fn format_sci(v: f64) -> String {
    if v == 0.0 {
        return "0".into();
    }
    let e = v.abs().log10().floor() as i32;
    let m = v / 10f64.powi(e);
    let ms = trim_zeros(format!("{m:.2}"));
    let body = if ms == "1" {
        format!("10{}", superscript(e))
    } else if ms == "-1" {
        format!("-10{}", superscript(e))
    } else {
        format!("{ms}\u{00D7}10{}", superscript(e))
    };
    body.replacen('-', "\u{2212}", 1)
}

/// Plain decimal label with just enough decimals for a 1-significant-digit value.
fn format_plain(v: f64) -> String {
    let e = v.abs().log10().floor() as i32;
    let decimals = (-e).max(0) as usize;
    trim_zeros(format!("{v:.decimals$}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn labels(t: &[Tick]) -> Vec<&str> {
        t.iter().map(|t| t.label.as_str()).collect()
    }

    #[test]
    fn linear_basic() {
        let t = linear_ticks(0.0, 10.0, 6);
        assert_eq!(labels(&t), ["0", "2", "4", "6", "8", "10"]);
        let t = linear_ticks(-20.0, 20.0, 5);
        assert_eq!(labels(&t), ["\u{2212}20", "\u{2212}10", "0", "10", "20"]);
        let t = linear_ticks(0.0, 1.0, 6);
        assert_eq!(labels(&t), ["0.0", "0.2", "0.4", "0.6", "0.8", "1.0"]);
        assert!(t.len() <= 6);
        let t = linear_ticks(0.0, 100.0, 5);
        assert_eq!(labels(&t), ["0", "25", "50", "75", "100"]);
        let t = linear_ticks(0.0, 1.0, 5);
        assert_eq!(labels(&t), ["0.00", "0.25", "0.50", "0.75", "1.00"]);
        let t = linear_ticks(-0.3, 7.0, 1);
        assert_eq!(t.len(), 1);
        let t = linear_ticks(5.0, 5.0, 6);
        assert_eq!(t.len(), 1);
        assert!(linear_ticks(f64::NAN, 1.0, 5).is_empty());
    }

    #[test]
    fn linear_respects_max() {
        for &(lo, hi) in &[(0.0, 37.0), (-1e-3, 2e-3), (3.3, 3.31), (-1e7, 1e7)] {
            for n in 1..10 {
                let t = linear_ticks(lo, hi, n);
                assert!(!t.is_empty() && t.len() <= n, "{lo} {hi} {n}: {t:?}");
                assert!(
                    t.iter()
                        .all(|t| t.value >= lo - 1e-9 && t.value <= hi + 1e-9)
                );
            }
        }
    }

    #[test]
    fn log_basic() {
        let t = log_ticks(1e-3, 10.0, 8);
        assert_eq!(labels(&t), ["0.001", "0.01", "0.1", "1", "10"]);
        let t = log_ticks(1e-8, 1e-6, 8);
        assert!(labels(&t).contains(&"10\u{207B}\u{2077}"));
        // Mixed magnitudes use one notation.
        let t = log_ticks(1e-7, 1.0, 10);
        assert_eq!(labels(&t)[0], "10\u{207B}\u{2077}");
        assert_eq!(*labels(&t).last().unwrap(), "10\u{2070}");
        let t = log_ticks(2.0, 8.0, 5);
        assert!(t.len() >= 2);
    }
}
