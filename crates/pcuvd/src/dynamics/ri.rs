//! PSV, EDV, RI, vessel classes and flow directions per pixel.

use super::*;

/// Resistivity index RI = (PSV − EDV)/PSV (dimensionless, eq. 16); NaN when PSV ≤ 0 or not finite.
pub fn resistivity_index(psv: f64, edv: f64) -> f64 {
    if psv.is_finite() && edv.is_finite() && psv > 0.0 {
        (psv - edv) / psv
    } else {
        f64::NAN
    }
}

/// A vessel pixel's class from its RI: [`ARTERIOLE`] at or above `artery_ri_min`, [`VENULE`] at
/// or below `vein_ri_max`, [`UNDETERMINED`] between them or without an RI (NaN).
pub fn vessel_class_of(ri: f64, artery_ri_min: f64, vein_ri_max: f64) -> u8 {
    if ri >= artery_ri_min {
        ARTERIOLE
    } else if ri <= vein_ri_max {
        VENULE
    } else {
        UNDETERMINED
    }
}

/// Per-pixel cardiac-cycle maps, shape (nz, nx); background pixels hold NaN velocities and RI.
#[derive(Debug, Clone, PartialEq)]
pub struct RiMaps {
    /// Peak systolic speed (m/s), averaged over cycles.
    pub psv: Array2<f64>,
    /// End-diastolic speed (m/s), averaged over cycles.
    pub edv: Array2<f64>,
    /// Resistivity index (dimensionless, eq. 16).
    pub ri: Array2<f64>,
    /// [`BACKGROUND`], [`ARTERIOLE`], [`VENULE`] or [`UNDETERMINED`].
    pub vessel_class: Array2<u8>,
    /// True where the time-mean Vz < 0 (flow up, toward the probe); false on background.
    pub flow_up: Array2<bool>,
    /// Heart rate used (Hz): the given one or the one measured from the data.
    pub heart_rate_hz: f64,
    /// Cardiac cycles used, as [start, end) indices into the series' windows.
    pub cycles: Vec<(usize, usize)>,
    /// How the cycles were found (given rate, triggers, or measured, and how).
    pub cycle_source: CycleSource,
    /// Standard deviation across cycles of each cycle's PSV (m/s); NaN with fewer than 2 cycles.
    pub psv_spread: Array2<f64>,
    /// Standard deviation across cycles of each cycle's EDV (m/s); NaN with fewer than 2 cycles.
    pub edv_spread: Array2<f64>,
    /// Standard deviation across cycles of each cycle's RI (dimensionless); NaN with fewer than
    /// 2 cycles.
    pub ri_spread: Array2<f64>,
}

/// PSV, EDV, RI, vessel classes and flow directions from a [`VelocitySeries`]: vessel pixels are
/// those at or above `params.min_power_db`; the cycles come from their spatial mean speed.
pub fn ri_maps(series: &VelocitySeries, params: &DynamicsParams) -> Result<RiMaps> {
    ri_maps_where(series, params, None)
}

/// As [`ri_maps`], with vessel pixels restricted to where `flow` (nz, nx) holds as well: for
/// example the pixels of the whole recording's power Doppler above its noise floor
/// ([`crate::estimate::masks::above_noise_floor`]), a steadier test than the power of 20 ms windows.
pub fn ri_maps_where(
    series: &VelocitySeries,
    params: &DynamicsParams,
    flow: Option<&Array2<bool>>,
) -> Result<RiMaps> {
    ri_maps_triggered(series, params, flow, None)
}

/// As [`ri_maps_where`], with the cardiac cycles delimited by `triggers` (s, on the series' time
/// axis: ECG R-waves or scanner triggers) when given ([`cardiac_cycles`]).
///
/// PSV and EDV are each cycle's largest and smallest speed, averaged over the complete cycles,
/// after a fit of the cardiac harmonics that drops the window-to-window estimation noise: with
/// cycles of one fixed period (a given or autocorrelation-measured heart rate) one Fourier series
/// is fitted to the whole series (the mean beat, steadiest); with cycles of their own durations
/// (triggers, upstrokes) each cycle gets its own fit at its own period. The spread maps are the
/// standard deviations across cycles of the per-cycle values, each cycle fitted on its own.
///
/// A series of one projection ([`VelocitySeries::axial_only`]) reads PSV and EDV of |Vz| (vessel
/// pooling, which needs the flow's direction in the plane, is refused); its vessel pixels whose
/// velocity does not keep its sign ([`AXIAL_COHERENCE_MIN`]) are undetermined, with NaN PSV, EDV
/// and RI.
pub fn ri_maps_triggered(
    series: &VelocitySeries,
    params: &DynamicsParams,
    flow: Option<&Array2<bool>>,
    triggers: Option<&[f64]>,
) -> Result<RiMaps> {
    if series.is_empty() {
        return Err(invalid("velocity series", "has no windows"));
    }
    let (nt, nz, nx) = series.vz.dim();
    let vx_windows = if series.axial_only { 0 } else { nt };
    if series.vx.dim() != (vx_windows, nz, nx)
        || series.power.dim() != (nt, nz, nx)
        || nt != series.len()
    {
        return Err(Error::Shape(format!(
            "velocity series: vx {:?}, vz {:?}, power {:?} for {} times",
            series.vx.dim(),
            series.vz.dim(),
            series.power.dim(),
            series.len()
        )));
    }
    if !(series.step_s > 0.0 && series.window_s > 0.0) {
        return Err(invalid(
            "velocity series",
            format!(
                "window ({} s) and step ({} s) must be > 0",
                series.window_s, series.step_s
            ),
        ));
    }
    params.validate_thresholds()?;
    if series.axial_only && params.pooling.is_some() {
        return Err(invalid(
            "vessel pooling",
            "pools along each pixel's flow direction in the image plane, which one steering \
             angle does not give: pool with two or more angles, or turn pooling off",
        ));
    }
    if let Some(hr) = params.heart_rate_hz {
        require_positive("heart rate", hr)?;
        check_period_vs_window(hr, series.window_s)?;
    }

    let mut mask = series.vessel_mask(params.min_power_db);
    if let Some(flow) = flow {
        if flow.dim() != (nz, nx) {
            return Err(Error::Shape(format!(
                "flow mask {:?} for velocity maps of {:?}",
                flow.dim(),
                (nz, nx)
            )));
        }
        mask.zip_mut_with(flow, |m, &f| *m &= f);
    }
    if !mask.iter().any(|&m| m) {
        return Err(Error::NoFlow(
            "no pixel has power (no vessel to analyse)".into(),
        ));
    }
    let waveform = series.mean_speed(&mask)?;
    let found = cardiac_cycles(&waveform, &series.times_s, params.heart_rate_hz, triggers)?;
    let hr = found.heart_rate_hz;
    check_period_vs_window(hr, series.window_s)?;
    let cycles = found.ranges.clone();

    // Pooling reads its neighbours' speeds, so it holds them once; without it each pixel's
    // speed is read lane by lane from the windows, and no map of them is held.
    let held_speed = params.pooling.map(|pooling| (series.speed(), pooling));
    let pools = held_speed.as_ref().map(|(speed, pooling)| {
        let mean_power = series
            .power
            .mean_axis(Axis(0))
            .unwrap_or_else(|| Array2::zeros((nz, nx)));
        let weight = mean_power.mapv(|p| p * p);
        let (mx, mz) = series.mean_velocity();
        PooledSpeeds::new(speed, &mask, (&mx, &mz), &weight, *pooling)
    });
    let harmonics_at = |rate: f64| {
        params
            .harmonics
            .unwrap_or_else(|| auto_harmonics(rate, series.window_s))
    };
    let overlap = series.window_s / series.step_s;
    let fit_of = |fit: &HarmonicFit, lane: &[f64]| {
        if params.debias_harmonics {
            fit.debiased(lane)
        } else {
            fit.smooth(lane)
        }
    };
    // Beat-to-beat cycles (triggers, upstrokes) have durations of their own: no one period fits.
    let per_cycle_means = matches!(found.source, CycleSource::Triggers | CycleSource::Upstrokes);
    let global_fit = (!per_cycle_means)
        .then(|| HarmonicFit::new(&series.times_s, hr, harmonics_at(hr), overlap))
        .flatten();
    // Each cycle fitted on its own, at its own period: for the spread across cycles, and for the
    // means when the cycles differ in duration.
    let cycle_fits: Vec<Option<HarmonicFit>> = cycles
        .iter()
        .map(|&(start, end)| {
            let rate = 1.0 / ((end - start) as f64 * series.step_s);
            HarmonicFit::new(
                &series.times_s[start..end],
                rate,
                harmonics_at(rate),
                overlap,
            )
        })
        .collect();
    let pixels: Vec<PixelCycles> = (0..nz * nx)
        .into_par_iter()
        .map(|p| {
            let (iz, ix) = (p / nx, p % nx);
            if !mask[[iz, ix]] {
                return PixelCycles::background();
            }
            if series.axial_only
                && axial_coherence(series.vz.slice(s![.., iz, ix])) < AXIAL_COHERENCE_MIN
            {
                return PixelCycles {
                    class: UNDETERMINED,
                    ..PixelCycles::background()
                };
            }
            let raw: Vec<f64> = match &pools {
                Some(pools) => pools.lane(iz, ix),
                None => series.speed_lane(iz, ix),
            };
            let per_cycle: Vec<(f64, f64)> = cycles
                .iter()
                .zip(&cycle_fits)
                .map(|(&(start, end), fit)| {
                    let lane = &raw[start..end];
                    let smooth = fit.as_ref().and_then(|f| fit_of(f, lane));
                    psv_edv_unchecked(smooth.as_deref().unwrap_or(lane), &[(0, end - start)])
                })
                .collect();
            let (psv, edv) = if per_cycle_means {
                mean_finite_pairs(&per_cycle)
            } else {
                let smooth = global_fit.as_ref().and_then(|f| fit_of(f, &raw));
                psv_edv_unchecked(smooth.as_deref().unwrap_or(&raw), &cycles)
            };
            let ri = resistivity_index(psv, edv);
            let class = vessel_class_of(ri, params.artery_ri_min, params.vein_ri_max);
            let (mut sum, mut count) = (0.0, 0usize);
            for &v in series.vz.slice(s![.., iz, ix]) {
                if v.is_finite() {
                    sum += v;
                    count += 1;
                }
            }
            let up = count > 0 && sum / (count as f64) < 0.0;
            let spread = |values: Vec<f64>| sample_std(&values);
            PixelCycles {
                psv,
                edv,
                ri,
                class,
                up,
                psv_spread: spread(per_cycle.iter().map(|c| c.0).collect()),
                edv_spread: spread(per_cycle.iter().map(|c| c.1).collect()),
                ri_spread: spread(
                    per_cycle
                        .iter()
                        .map(|&(p, e)| resistivity_index(p, e))
                        .collect(),
                ),
            }
        })
        .collect();
    let map = |value: fn(&PixelCycles) -> f64| {
        Array2::from_shape_fn((nz, nx), |(iz, ix)| value(&pixels[iz * nx + ix]))
    };
    Ok(RiMaps {
        psv: map(|p| p.psv),
        edv: map(|p| p.edv),
        ri: map(|p| p.ri),
        vessel_class: Array2::from_shape_fn((nz, nx), |(iz, ix)| pixels[iz * nx + ix].class),
        flow_up: Array2::from_shape_fn((nz, nx), |(iz, ix)| pixels[iz * nx + ix].up),
        psv_spread: map(|p| p.psv_spread),
        edv_spread: map(|p| p.edv_spread),
        ri_spread: map(|p| p.ri_spread),
        heart_rate_hz: hr,
        cycles,
        cycle_source: found.source,
    })
}

/// Least [`axial_coherence`] of a vessel pixel whose RI is read from one projection
/// ([`VelocitySeries::axial_only`]). RI = 1 − EDV/PSV is blind to a waveform's scale, so the
/// projection |V|·|cos φ| of a vessel that keeps its direction φ to the beam gives the vessel's
/// RI, as spectral Doppler's RI does; but across a vessel near 90° to the beam the projection is
/// the windows' estimation noise, whose extremes read any RI. A window speed v ± σ (Gaussian
/// jitter σ) has coherence v / E|v ± σ|: 0.86 at v = σ, 0.56 at v = σ/2, so 0.8 keeps the
/// pixels whose time-mean speed is above about 0.85 σ; the others are undetermined.
pub const AXIAL_COHERENCE_MIN: f64 = 0.8;

/// How steadily a pixel's velocity series keeps one sign: |Σ v| / Σ |v| over its finite windows
/// (1 for a flow that never reverses, near 0 for noise about zero); 0 without a finite window.
pub fn axial_coherence(vz: ndarray::ArrayView1<f64>) -> f64 {
    let (sum, magnitude) = vz
        .iter()
        .filter(|v| v.is_finite())
        .fold((0.0, 0.0), |(s, m), &v| (s + v, m + v.abs()));
    if magnitude > 0.0 {
        sum.abs() / magnitude
    } else {
        0.0
    }
}

/// One pixel's cycle values: means over cycles, class, direction, and spreads across cycles.
struct PixelCycles {
    psv: f64,
    edv: f64,
    ri: f64,
    class: u8,
    up: bool,
    psv_spread: f64,
    edv_spread: f64,
    ri_spread: f64,
}

impl PixelCycles {
    fn background() -> Self {
        PixelCycles {
            psv: f64::NAN,
            edv: f64::NAN,
            ri: f64::NAN,
            class: BACKGROUND,
            up: false,
            psv_spread: f64::NAN,
            edv_spread: f64::NAN,
            ri_spread: f64::NAN,
        }
    }
}

/// Means of the finite (PSV, EDV) pairs; NaN when there is none.
fn mean_finite_pairs(pairs: &[(f64, f64)]) -> (f64, f64) {
    let finite: Vec<&(f64, f64)> = pairs
        .iter()
        .filter(|(p, e)| p.is_finite() && e.is_finite())
        .collect();
    if finite.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let n = finite.len() as f64;
    (
        finite.iter().map(|c| c.0).sum::<f64>() / n,
        finite.iter().map(|c| c.1).sum::<f64>() / n,
    )
}

/// Sample standard deviation (n − 1) of the finite values; NaN with fewer than two.
fn sample_std(values: &[f64]) -> f64 {
    let finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if finite.len() < 2 {
        return f64::NAN;
    }
    let n = finite.len() as f64;
    let mean = finite.iter().sum::<f64>() / n;
    (finite.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
}
