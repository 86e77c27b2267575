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
/// (Hz) or, if `None`, from the data ([`cardiac_cycles`]). Errors when not one cycle fits.
pub fn find_cycles(
    signal: &[f64],
    times: &[f64],
    heart_rate_hz: Option<f64>,
) -> Result<Vec<(usize, usize)>> {
    Ok(cardiac_cycles(signal, times, heart_rate_hz, None)?.ranges)
}

/// How the cardiac cycles of a recording were found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CycleSource {
    /// From the heart rate given by the user: cycles one period long, aligned with the systolic
    /// peaks.
    GivenRate,
    /// From cycle start times given beside the recording (ECG R-waves or scanner triggers): one
    /// cycle from each to the next.
    Triggers,
    /// From the period of the triggers given beside the recording, when the waveform is too short
    /// to hold a cycle from one trigger to the next (a recording of about one beat): cycles one
    /// period long, aligned with the systolic peaks, as with a given heart rate.
    TriggerPeriod,
    /// Measured from the data: the systolic upstrokes (steepest rises) of the vessels' mean speed,
    /// one cycle from each to the next. Needs two upstrokes: about one cycle or more.
    Upstrokes,
    /// Measured from the data: the first strong peak of the waveform's autocorrelation; cycles
    /// one period long, aligned with the systolic peaks. Needs about 1.5 cycles.
    Autocorrelation,
}

impl CycleSource {
    /// One sentence for summaries and reports.
    pub fn describe(self) -> &'static str {
        match self {
            CycleSource::GivenRate => {
                "heart rate given (--heart-rate); cycles one period long, aligned with the systolic peaks"
            }
            CycleSource::Triggers => {
                "cardiac triggers given with the recording (ECG R-waves or trigger times); one cycle from each trigger to the next"
            }
            CycleSource::TriggerPeriod => {
                "heart rate from the period of the cardiac triggers given with the recording (the waveform holds no cycle from one trigger to the next); cycles one period long, aligned with the systolic peaks"
            }
            CycleSource::Upstrokes => {
                "measured from the data: systolic upstrokes (steepest rises) of the vessels' mean speed; one cycle from each upstroke to the next"
            }
            CycleSource::Autocorrelation => {
                "measured from the data: first strong peak of the autocorrelation of the vessels' mean speed; cycles one period long, aligned with the systolic peaks"
            }
        }
    }
}

/// Cardiac cycles of a waveform and how they were found.
#[derive(Debug, Clone, PartialEq)]
pub struct CardiacCycles {
    /// Complete cycles as half-open [start, end) index ranges of the waveform, in order.
    pub ranges: Vec<(usize, usize)>,
    /// Heart rate (Hz): the given one, or 1 / the median cycle duration.
    pub heart_rate_hz: f64,
    /// Where the cycles came from.
    pub source: CycleSource,
}

/// Complete cycles from which the measured cycles follow the beats (one from each systolic upstroke
/// to the next) rather than one fixed period: over many cycles the heart rate drifts, and a fixed
/// period slides off the beats; over a few, one period fitted to the whole waveform is steadier.
pub const BEAT_TO_BEAT_MIN_CYCLES: usize = 4;

/// Complete cardiac cycles of a waveform `signal` (the vessels' mean speed) sampled at uniform
/// `times` (s). In order of preference: cycle start times `triggers` (s, same clock as `times`:
/// ECG R-waves or scanner triggers), or their period when the waveform, which they overlap,
/// holds no cycle from one to the next; a given `heart_rate_hz` (Hz); measured from the data — beat
/// to beat between systolic upstrokes ([`systolic_upstrokes`]) when they delimit at least
/// [`BEAT_TO_BEAT_MIN_CYCLES`] cycles, else one period from the autocorrelation
/// ([`estimate_heart_rate`], ≳ 1.5 cycles), else between two upstrokes (about one cycle and a
/// bit: the recording must hold the same phase of two beats). Errors when not one cycle fits.
pub fn cardiac_cycles(
    signal: &[f64],
    times: &[f64],
    heart_rate_hz: Option<f64>,
    triggers: Option<&[f64]>,
) -> Result<CardiacCycles> {
    let dt = check_times(signal, times)?;
    let mut from_triggers = None;
    if let Some(triggers) = triggers {
        match trigger_cycles(times, dt, triggers) {
            Ok(cycles) => return Ok(cycles),
            // A waveform shorter than one trigger-to-trigger cycle still knows the period, when
            // the triggers are of its time (they overlap it; elsewhere their clock is suspect).
            Err(_)
                if triggers.len() >= 2
                    && triggers.windows(2).all(|w| w[1] > w[0])
                    && triggers[0] <= times[times.len() - 1]
                    && triggers[triggers.len() - 1] >= times[0] =>
            {
                let mut periods: Vec<f64> = triggers.windows(2).map(|w| w[1] - w[0]).collect();
                periods.sort_by(f64::total_cmp);
                from_triggers = Some(1.0 / periods[periods.len() / 2]);
            }
            Err(e) => return Err(e),
        }
    }
    let (hr, source) = match from_triggers.or(heart_rate_hz) {
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
            let source = match from_triggers {
                Some(_) => CycleSource::TriggerPeriod,
                None => CycleSource::GivenRate,
            };
            (hr, source)
        }
        None => {
            let upstrokes = systolic_upstrokes(signal, times)?;
            let beats = cycles_between(times, dt, &upstrokes, CycleSource::Upstrokes);
            match beats {
                Some(beats) if beats.ranges.len() >= BEAT_TO_BEAT_MIN_CYCLES => return Ok(beats),
                _ => {}
            }
            match estimate_heart_rate(signal, times) {
                Ok(hr) => (hr, CycleSource::Autocorrelation),
                Err(e) => match beats {
                    Some(beats) => return Ok(beats),
                    None => {
                        // The estimate's own reason, without its "invalid recording:" again.
                        let why = match e {
                            Error::InvalidParameter { reason, .. } => reason,
                            other => other.to_string(),
                        };
                        return Err(invalid(
                            "recording",
                            format!(
                                "{why} (systolic upstrokes found: {}; two are needed to measure \
                                 the period from about one cycle)",
                                upstrokes.len()
                            ),
                        ));
                    }
                },
            }
        }
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
    let ranges = (0..count)
        .map(|k| {
            let start = offset + start_of(k);
            (start, start + len)
        })
        .collect();
    Ok(CardiacCycles {
        ranges,
        heart_rate_hz: hr,
        source,
    })
}

/// Times (s) of the systolic upstrokes of a pulsatile waveform `signal` sampled at uniform `times`:
/// the local maxima of its slope (central difference) that reach half the steepest slope, at
/// least one period of the fastest searched heart rate ([`HEART_RATE_SEARCH_HZ`]) apart, each
/// placed to a fraction of a sample by a parabola through the slope's peak. A rise cut by either
/// end of the recording is not counted (its steepest point may lie outside).
pub fn systolic_upstrokes(signal: &[f64], times: &[f64]) -> Result<Vec<f64>> {
    let dt = check_times(signal, times)?;
    let n = signal.len();
    if n < 5 {
        return Ok(Vec::new());
    }
    let slope: Vec<f64> = (1..n - 1)
        .map(|i| 0.5 * (signal[i + 1] - signal[i - 1]))
        .collect();
    let steepest = slope.iter().copied().fold(0.0, f64::max);
    if steepest <= 0.0 {
        return Ok(Vec::new());
    }
    // slope[j] is the slope at sample j + 1; a peak needs both neighbours inside the record.
    let mut peaks: Vec<usize> = (1..slope.len() - 1)
        .filter(|&j| {
            slope[j] >= 0.5 * steepest && slope[j] >= slope[j - 1] && slope[j] > slope[j + 1]
        })
        .collect();
    // Keep the steepest of peaks closer than the shortest searched period.
    let min_gap = 1.0 / (HEART_RATE_SEARCH_HZ.1 * dt);
    peaks.sort_by(|&a, &b| slope[b].total_cmp(&slope[a]));
    let mut kept: Vec<usize> = Vec::new();
    for j in peaks {
        if kept.iter().all(|&k| (k as f64 - j as f64).abs() >= min_gap) {
            kept.push(j);
        }
    }
    kept.sort_unstable();
    Ok(kept
        .into_iter()
        .map(|j| {
            let (a, b, c) = (slope[j - 1], slope[j], slope[j + 1]);
            let curvature = a - 2.0 * b + c;
            let shift = if curvature < 0.0 {
                (0.5 * (a - c) / curvature).clamp(-0.5, 0.5)
            } else {
                0.0
            };
            times[0] + (j as f64 + 1.0 + shift) * dt
        })
        .collect())
}

/// Cycles from each of `starts` (s) to the next, as index ranges of `times` (`dt` apart), keeping
/// those whose duration lies within ±35 % of the median and within the searched heart rates;
/// `None` when not one cycle remains.
fn cycles_between(
    times: &[f64],
    dt: f64,
    starts: &[f64],
    source: CycleSource,
) -> Option<CardiacCycles> {
    let durations: Vec<f64> = starts.windows(2).map(|w| w[1] - w[0]).collect();
    if durations.is_empty() {
        return None;
    }
    let median = crate::core::stats::median(durations.clone());
    let (f_lo, f_hi) = HEART_RATE_SEARCH_HZ;
    let plausible = |d: f64| (0.65 * median..=1.35 * median).contains(&d);
    if source == CycleSource::Upstrokes && !(1.0 / f_hi..=1.0 / f_lo).contains(&median) {
        return None;
    }
    let index = |t: f64| ((t - times[0]) / dt).round();
    let n = times.len() as f64;
    let ranges: Vec<(usize, usize)> = starts
        .windows(2)
        .filter(|w| plausible(w[1] - w[0]))
        .map(|w| (index(w[0]), index(w[1])))
        .filter(|&(a, b)| a >= 0.0 && b <= n && b - a >= 2.0)
        .map(|(a, b)| (a as usize, b as usize))
        .collect();
    if ranges.is_empty() {
        return None;
    }
    Some(CardiacCycles {
        ranges,
        heart_rate_hz: 1.0 / median,
        source,
    })
}

/// Cycles between given trigger times (s); errors when the triggers are not finite and increasing
/// or when no complete cycle lies within the waveform's times.
fn trigger_cycles(times: &[f64], dt: f64, triggers: &[f64]) -> Result<CardiacCycles> {
    if triggers.iter().any(|t| !t.is_finite()) || triggers.windows(2).any(|w| w[1] <= w[0]) {
        return Err(invalid(
            "cardiac triggers",
            "must be finite times (s) in increasing order",
        ));
    }
    let (first, last) = (times[0], times[times.len() - 1]);
    let inside: Vec<f64> = triggers
        .iter()
        .copied()
        .filter(|&t| t >= first - 0.5 * dt && t <= last + 0.5 * dt)
        .collect();
    cycles_between(times, dt, &inside, CycleSource::Triggers).ok_or_else(|| {
        invalid(
            "cardiac triggers",
            format!(
                "{} of the {} triggers fall within the waveform's {:.1}–{:.1} ms: at least two are \
                 needed for one complete cycle",
                inside.len(),
                triggers.len(),
                first * 1e3,
                last * 1e3
            ),
        )
    })
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
