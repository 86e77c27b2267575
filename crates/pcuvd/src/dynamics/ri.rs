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
}

/// PSV, EDV, RI, vessel classes and flow directions from a [`VelocitySeries`]: vessel pixels are
/// those at or above `params.min_power_db`; the cycles come from their spatial mean speed.
pub fn ri_maps(series: &VelocitySeries, params: &DynamicsParams) -> Result<RiMaps> {
    ri_maps_where(series, params, None)
}

/// As [`ri_maps`], with vessel pixels restricted to where `flow` (nz, nx) holds as well: for
/// example the pixels of the whole recording's power Doppler above its noise floor
/// ([`crate::doppler::above_noise_floor`]), a steadier test than the power of 20 ms windows.
pub fn ri_maps_where(
    series: &VelocitySeries,
    params: &DynamicsParams,
    flow: Option<&Array2<bool>>,
) -> Result<RiMaps> {
    if series.is_empty() {
        return Err(invalid("velocity series", "has no windows"));
    }
    let (nt, nz, nx) = series.vx.dim();
    if series.vz.dim() != (nt, nz, nx) || series.power.dim() != (nt, nz, nx) || nt != series.len() {
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
        return Err(invalid(
            "velocity series",
            "no pixel has power (no vessel to analyse)",
        ));
    }
    let waveform = series.mean_speed(&mask);
    let (cycles, hr) = cycles_and_rate(&waveform, &series.times_s, params.heart_rate_hz)?;
    check_period_vs_window(hr, series.window_s)?;

    let mut speed = series.speed();
    if let Some(pooling) = params.pooling {
        let (mx, mz) = series.mean_velocity();
        let mean_power = series
            .power
            .mean_axis(Axis(0))
            .unwrap_or_else(|| Array2::zeros((nz, nx)));
        let weight = mean_power.mapv(|p| p * p);
        speed = pool_waveforms(&speed, &mask, &mx, &mz, &weight, &pooling);
    }
    let harmonics = params
        .harmonics
        .unwrap_or_else(|| auto_harmonics(hr, series.window_s));
    let fit = HarmonicFit::new(&series.times_s, hr, harmonics);
    let pixels: Vec<(f64, f64, f64, u8, bool)> = (0..nz * nx)
        .into_par_iter()
        .map(|p| {
            let (iz, ix) = (p / nx, p % nx);
            if !mask[[iz, ix]] {
                return (f64::NAN, f64::NAN, f64::NAN, BACKGROUND, false);
            }
            let mut lane: Vec<f64> = speed.slice(s![.., iz, ix]).to_vec();
            if let Some(smooth) = fit.as_ref().and_then(|f| f.smooth(&lane)) {
                lane = smooth;
            }
            let (psv, edv) = psv_edv_unchecked(&lane, &cycles);
            let ri = resistivity_index(psv, edv);
            let class = if ri >= params.artery_ri_min {
                ARTERIOLE
            } else if ri <= params.vein_ri_max {
                VENULE
            } else {
                UNDETERMINED
            };
            let (mut sum, mut count) = (0.0, 0usize);
            for &v in series.vz.slice(s![.., iz, ix]) {
                if v.is_finite() {
                    sum += v;
                    count += 1;
                }
            }
            let up = count > 0 && sum / (count as f64) < 0.0;
            (psv, edv, ri, class, up)
        })
        .collect();
    let at = |iz: usize, ix: usize| &pixels[iz * nx + ix];
    Ok(RiMaps {
        psv: Array2::from_shape_fn((nz, nx), |(iz, ix)| at(iz, ix).0),
        edv: Array2::from_shape_fn((nz, nx), |(iz, ix)| at(iz, ix).1),
        ri: Array2::from_shape_fn((nz, nx), |(iz, ix)| at(iz, ix).2),
        vessel_class: Array2::from_shape_fn((nz, nx), |(iz, ix)| at(iz, ix).3),
        flow_up: Array2::from_shape_fn((nz, nx), |(iz, ix)| at(iz, ix).4),
        heart_rate_hz: hr,
        cycles,
    })
}
