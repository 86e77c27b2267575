//! Cardiac period and cycles from a speed waveform; PSV and EDV over the complete cycles.

use super::*;

/// Checks `times` (s): as long as `signal`, ≥ 2 samples, uniformly spaced; returns the spacing (s).
fn check_times(signal: &[f64], times: &[f64]) -> Result<f64> {
    if signal.len() != times.len() {
        return Err(Error::Shape(format!(
            "{} signal samples for {} times",
            signal.len(),
            times.len()
        )));
    }
    if signal.len() < 2 {
        return Err(invalid(
            "waveform",
            format!("needs at least 2 samples, got {}", signal.len()),
        ));
    }
    if signal.iter().chain(times).any(|v| !v.is_finite()) {
        return Err(Error::NonFinite("waveform or its times".into()));
    }
    let dt = times[1] - times[0];
    if dt <= 0.0 {
        return Err(invalid("times", "must increase"));
    }
    for pair in times.windows(2) {
        if ((pair[1] - pair[0]) - dt).abs() > 1e-6 * dt {
            return Err(invalid(
                "times",
                format!(
                    "must be uniformly spaced (window centres), found steps {dt} s and {} s",
                    pair[1] - pair[0]
                ),
            ));
        }
    }
    Ok(dt)
}

/// Removes the least-squares straight line from `x`.
fn detrend(x: &[f64]) -> Vec<f64> {
    let n = x.len() as f64;
    let tm = (n - 1.0) / 2.0;
    let xm = x.iter().sum::<f64>() / n;
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (t, &v) in x.iter().enumerate() {
        let dt = t as f64 - tm;
        sxy += dt * (v - xm);
        sxx += dt * dt;
    }
    let slope = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    x.iter()
        .enumerate()
        .map(|(t, &v)| v - xm - slope * (t as f64 - tm))
        .collect()
}

/// Pearson correlation of x[0..n−lag] with x[lag..n].
fn lag_correlation(x: &[f64], lag: usize) -> f64 {
    let a = &x[..x.len() - lag];
    let b = &x[lag..];
    let m = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / m, b.iter().sum::<f64>() / m);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (&u, &v) in a.iter().zip(b) {
        sab += (u - ma) * (v - mb);
        saa += (u - ma) * (u - ma);
        sbb += (v - mb) * (v - mb);
    }
    if saa > 0.0 && sbb > 0.0 {
        sab / (saa * sbb).sqrt()
    } else {
        f64::NAN
    }
}

/// Heart rate (Hz) of a pulsatile waveform `signal` sampled at `times` (s): the first strong peak
/// of the autocorrelation of the detrended signal at a period within 3–15 Hz, refined to a
/// fraction of a sample by a parabola through the peak. Needs ≳ 1.5 cycles of data.
pub fn estimate_heart_rate(signal: &[f64], times: &[f64]) -> Result<f64> {
    let dt = check_times(signal, times)?;
    let n = signal.len();
    let x = detrend(signal);
    let (f_lo, f_hi) = HEART_RATE_SEARCH_HZ;
    let lag_min = ((1.0 / (f_hi * dt)).ceil() as usize).max(2);
    // Keep at least a third of the record overlapping at the longest lag.
    let lag_max = ((1.0 / (f_lo * dt)).floor() as usize).min(2 * n / 3);
    let too_short = || {
        invalid(
            "recording",
            format!(
                "{:.1} ms of waveform is too short to measure a heart rate between {f_lo} and \
                 {f_hi} Hz from the data (about 1.5 cycles are needed); give the heart rate",
                n as f64 * dt * 1e3
            ),
        )
    };
    if lag_max < lag_min + 1 || lag_max + 2 > n {
        return Err(too_short());
    }
    let r: Vec<f64> = (0..=lag_max + 1)
        .map(|lag| {
            if lag + 2 <= n {
                lag_correlation(&x, lag)
            } else {
                f64::NAN
            }
        })
        .collect();
    if r[lag_min..=lag_max].iter().all(|v| !v.is_finite()) {
        return Err(invalid(
            "waveform",
            "is constant: no cardiac pulsation to measure",
        ));
    }
    let peaks: Vec<usize> = (lag_min..=lag_max)
        .filter(|&l| r[l].is_finite() && r[l] >= r[l - 1] && r[l] > r[l + 1])
        .collect();
    let best = peaks
        .iter()
        .map(|&l| r[l])
        .fold(f64::NEG_INFINITY, f64::max);
    if peaks.is_empty() || best < 0.3 {
        if peaks.is_empty() && n as f64 * dt * f_lo < 2.0 {
            return Err(too_short());
        }
        return Err(invalid(
            "waveform",
            format!(
                "no clear cardiac period between {f_lo} and {f_hi} Hz (best autocorrelation \
                 {best:.2} < 0.3); give the heart rate"
            ),
        ));
    }
    // The first peak nearly as strong as the best: the fundamental, not a multiple of the period.
    let lag = peaks
        .iter()
        .copied()
        .find(|&l| r[l] >= 0.8 * best)
        .unwrap_or(peaks[0]);
    let (a, b, c) = (r[lag - 1], r[lag], r[lag + 1]);
    let curvature = a - 2.0 * b + c;
    let shift = if c.is_finite() && curvature < 0.0 {
        (0.5 * (a - c) / curvature).clamp(-0.5, 0.5)
    } else {
        0.0
    };
    Ok(1.0 / ((lag as f64 + shift) * dt))
}

/// Complete cardiac cycles in a waveform `signal` (e.g. the mean speed over vessel pixels) sampled
/// at uniform `times` (s): half-open index ranges [start, end) one period long, as many as fit,
/// started at systolic peaks where the recording allows. The period comes from `heart_rate_hz`
/// (Hz) or, if `None`, from [`estimate_heart_rate`]. Errors when not one cycle fits.
pub fn find_cycles(
    signal: &[f64],
    times: &[f64],
    heart_rate_hz: Option<f64>,
) -> Result<Vec<(usize, usize)>> {
    Ok(cycles_and_rate(signal, times, heart_rate_hz)?.0)
}

pub(super) fn cycles_and_rate(
    signal: &[f64],
    times: &[f64],
    heart_rate_hz: Option<f64>,
) -> Result<(Vec<(usize, usize)>, f64)> {
    let dt = check_times(signal, times)?;
    let hr = match heart_rate_hz {
        Some(hr) => {
            require_positive("heart rate", hr)?;
            if hr * dt > 0.5 {
                return Err(invalid(
                    "heart rate",
                    format!(
                        "{hr} Hz is above the Nyquist rate {:.2} Hz of a waveform sampled every {:.2} ms",
                        0.5 / dt,
                        dt * 1e3
                    ),
                ));
            }
            hr
        }
        None => estimate_heart_rate(signal, times)?,
    };
    let n = signal.len();
    let (period, len) = cycle_length(n, dt, hr)?;
    let start_of = |k: usize| (k as f64 * period).round() as usize;
    let mut count = ((n - len) as f64 / period).floor() as usize + 1;
    while count > 1 && start_of(count - 1) + len > n {
        count -= 1;
    }
    // Free play of the first start that keeps `count` cycles: align the starts with the peaks.
    let slack = n - len - start_of(count - 1);
    let offset = (0..=slack)
        .map(|o| {
            let score: f64 = (0..count).map(|k| signal[o + start_of(k)]).sum();
            (o, score)
        })
        .fold((0, f64::NEG_INFINITY), |best, cur| {
            if cur.1 > best.1 { cur } else { best }
        })
        .0;
    let cycles = (0..count)
        .map(|k| {
            let start = offset + start_of(k);
            (start, start + len)
        })
        .collect();
    Ok((cycles, hr))
}

/// PSV and EDV (units of `speed`) averaged over `cycles`: PSV the largest and EDV the smallest
/// finite value of each cycle (end-diastole is the minimum before the next upstroke). NaN when no
/// cycle has a finite value.
pub fn psv_edv(speed: &[f64], cycles: &[(usize, usize)]) -> Result<(f64, f64)> {
    if cycles.is_empty() {
        return Err(invalid("cardiac cycles", "none given"));
    }
    for &(start, end) in cycles {
        if start >= end || end > speed.len() {
            return Err(invalid(
                "cardiac cycles",
                format!(
                    "cycle [{start}, {end}) is empty or runs past the {} samples",
                    speed.len()
                ),
            ));
        }
    }
    Ok(psv_edv_unchecked(speed, cycles))
}

pub(super) fn psv_edv_unchecked(speed: &[f64], cycles: &[(usize, usize)]) -> (f64, f64) {
    let (mut psv, mut edv, mut count) = (0.0, 0.0, 0usize);
    for &(start, end) in cycles {
        let finite = speed[start..end].iter().copied().filter(|v| v.is_finite());
        let (lo, hi) = finite.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
        if lo <= hi {
            psv += hi;
            edv += lo;
            count += 1;
        }
    }
    if count == 0 {
        (f64::NAN, f64::NAN)
    } else {
        (psv / count as f64, edv / count as f64)
    }
}
