//! Vector velocity in sliding windows over slow time.

use super::*;
use crate::core::buffers::complex_finite_on_every_core;
use crate::estimate::partial_volume::{CellCovariance, CellLags};
use crate::estimate::projections::Projections;

/// Vector velocity over time: one (Vx, Vz) map per sliding window, shapes (time, nz, nx); of a
/// recording of one steering angle, the colour-Doppler velocity alone ([`Self::axial_only`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct VelocitySeries {
    /// Window centres (s) from the first frame.
    pub times_s: Vec<f64>,
    /// Lateral velocity (m/s), positive toward +x; no window when [`Self::axial_only`].
    pub vx: Array3<f64>,
    /// Axial velocity (m/s), positive moving deeper (away from the probe).
    pub vz: Array3<f64>,
    /// Power Doppler per window, mean over angles (|IQ|² units).
    pub power: Array3<f64>,
    /// Duration of each window (s).
    pub window_s: f64,
    /// Time between consecutive windows (s).
    pub step_s: f64,
    /// True when one steering angle gave the series: `vz` is the colour-Doppler velocity (m/s,
    /// the angle's projection scaled to the axis, as `color_doppler.npy`), `vx` holds no window
    /// (shape (0, nz, nx): one projection cannot tell it, and a long recording's windows of NaN
    /// would take as much memory as `vz`'s), and [`Self::speed`] is |Vz|.
    #[serde(default)]
    pub axial_only: bool,
}

impl VelocitySeries {
    /// Speed |V| = √(Vx² + Vz²) (m/s), shape (time, nz, nx); |Vz| when [`Self::axial_only`].
    pub fn speed(&self) -> Array3<f64> {
        if self.axial_only {
            return self.vz.mapv(f64::abs);
        }
        ndarray::Zip::from(&self.vx)
            .and(&self.vz)
            .map_collect(|&x, &z| x.hypot(z))
    }

    /// Speed (m/s) of window `k` at every pixel, as [`Self::speed`] gives it, without the whole
    /// series' speeds.
    pub fn speed_at(&self, k: usize) -> Array2<f64> {
        let vz = self.vz.index_axis(Axis(0), k);
        if self.axial_only {
            return vz.mapv(f64::abs);
        }
        ndarray::Zip::from(self.vx.index_axis(Axis(0), k))
            .and(vz)
            .map_collect(|&x, &z| x.hypot(z))
    }

    /// Speed (m/s) of pixel (`iz`, `ix`) in every window, as [`Self::speed`] gives it.
    pub fn speed_lane(&self, iz: usize, ix: usize) -> Vec<f64> {
        let vz = self.vz.slice(ndarray::s![.., iz, ix]);
        if self.axial_only {
            return vz.iter().map(|v| v.abs()).collect();
        }
        self.vx
            .slice(ndarray::s![.., iz, ix])
            .iter()
            .zip(vz)
            .map(|(x, z)| x.hypot(*z))
            .collect()
    }

    /// Time-mean velocity (m/s) per pixel over the finite windows, (Vx, Vz) maps of shape (nz, nx);
    /// zero where no window is finite.
    pub fn mean_velocity(&self) -> (Array2<f64>, Array2<f64>) {
        let mean = |v: &Array3<f64>| {
            v.map_axis(Axis(0), |lane| {
                let (sum, count) = lane
                    .iter()
                    .filter(|x| x.is_finite())
                    .fold((0.0, 0usize), |(s, c), &x| (s + x, c + 1));
                if count > 0 { sum / count as f64 } else { 0.0 }
            })
        };
        (mean(&self.vx), mean(&self.vz))
    }

    /// Keeps the first `windows` windows (a segment's own, [`crate::pipeline::segments`]).
    pub fn truncate(&mut self, windows: usize) {
        let keep = windows.min(self.len());
        self.times_s.truncate(keep);
        for a in [&mut self.vx, &mut self.vz, &mut self.power] {
            // One angle's Vx holds no window.
            let kept = keep.min(a.dim().0);
            a.slice_collapse(ndarray::s![..kept, .., ..]);
        }
    }

    /// Moves every window `seconds` later (a segment's windows, timed from the recording's start).
    pub fn shift(&mut self, seconds: f64) {
        self.times_s.iter_mut().for_each(|t| *t += seconds);
    }

    /// The windows of consecutive segments as one series, in order; refuses no parts or parts
    /// with other windows or map shapes.
    pub fn concatenate(parts: Vec<VelocitySeries>) -> Result<VelocitySeries> {
        let first = parts
            .first()
            .ok_or_else(|| invalid("velocity series", "no segment has a whole window"))?;
        if parts.iter().any(|p| {
            p.window_s != first.window_s
                || p.step_s != first.step_s
                || p.axial_only != first.axial_only
        }) {
            return Err(invalid("velocity series", "segments with other windows"));
        }
        let stack = |field: fn(&VelocitySeries) -> &Array3<f64>| {
            let views: Vec<_> = parts.iter().map(|p| field(p).view()).collect();
            ndarray::concatenate(Axis(0), &views)
                .map_err(|e| Error::Shape(format!("velocity series of segments: {e}")))
        };
        Ok(VelocitySeries {
            times_s: parts.iter().flat_map(|p| p.times_s.clone()).collect(),
            vx: stack(|p| &p.vx)?,
            vz: stack(|p| &p.vz)?,
            power: stack(|p| &p.power)?,
            window_s: first.window_s,
            step_s: first.step_s,
            axial_only: first.axial_only,
        })
    }

    /// Number of windows (time samples).
    pub fn len(&self) -> usize {
        self.times_s.len()
    }

    /// True when there are no windows.
    pub fn is_empty(&self) -> bool {
        self.times_s.is_empty()
    }

    /// Time-mean power (dB re. the brightest pixel, 0 dB at the maximum), shape (nz, nx).
    pub fn mean_power_db(&self) -> Array2<f64> {
        let mean = self
            .power
            .mean_axis(Axis(0))
            .unwrap_or_else(|| Array2::zeros((self.power.dim().1, self.power.dim().2)));
        let peak = mean
            .iter()
            .copied()
            .filter(|p| p.is_finite())
            .fold(0.0, f64::max);
        mean.mapv(|p| {
            if peak > 0.0 && p > 0.0 {
                power_to_db(p / peak)
            } else {
                f64::NEG_INFINITY
            }
        })
    }

    /// Vessel pixels: time-mean power at or above `min_power_db` (dB re. the brightest pixel).
    pub fn vessel_mask(&self, min_power_db: f64) -> Array2<bool> {
        self.mean_power_db().mapv(|p| p >= min_power_db)
    }

    /// Spatial mean speed (m/s) over the `mask` pixels at each time (finite values only). A
    /// window in which no masked pixel has a finite speed (noise alone, or too few angles reaching
    /// them) takes the value interpolated linearly between its nearest windows that have one (the
    /// nearest one's at either end), so that it cannot break the waveform the cycles are found on;
    /// [`Error::NoFlow`] when no window has one.
    pub fn mean_speed(&self, mask: &Array2<bool>) -> Result<Vec<f64>> {
        let means: Vec<Option<f64>> = (0..self.len())
            .map(|k| {
                let frame = self.speed_at(k);
                let (mut sum, mut count) = (0.0, 0usize);
                for (&v, &m) in frame.iter().zip(mask.iter()) {
                    if m && v.is_finite() {
                        sum += v;
                        count += 1;
                    }
                }
                (count > 0).then(|| sum / count as f64)
            })
            .collect();
        let known: Vec<(usize, f64)> = means
            .iter()
            .enumerate()
            .filter_map(|(k, m)| m.map(|v| (k, v)))
            .collect();
        if known.is_empty() {
            return Err(Error::NoFlow(
                "no vessel pixel has a finite speed in any window".into(),
            ));
        }
        Ok((0..means.len())
            .map(|k| {
                let after = known.partition_point(|&(j, _)| j < k);
                match (after.checked_sub(1).map(|i| known[i]), known.get(after)) {
                    (_, Some(&(j, v))) if j == k => v,
                    (Some((j0, v0)), Some(&(j1, v1))) => {
                        v0 + (v1 - v0) * (k - j0) as f64 / (j1 - j0) as f64
                    }
                    (Some((_, v)), None) | (None, Some(&(_, v))) => v,
                    (None, None) => unreachable!("known is not empty"),
                }
            })
            .collect())
    }
}

/// Checks the per-angle series: non-empty, one per angle, equal shapes, finite; returns (nz, nx, frames).
pub(super) fn check_series(
    filtered: &[Array3<Complex32>],
    angles: &[f64],
) -> Result<(usize, usize, usize)> {
    let Some(first) = filtered.first() else {
        return Err(invalid("filtered IQ series", "no angle series given"));
    };
    if filtered.len() != angles.len() {
        return Err(Error::Shape(format!(
            "{} filtered IQ series for {} angles",
            filtered.len(),
            angles.len()
        )));
    }
    let dim = first.dim();
    if dim.0 == 0 || dim.1 == 0 || dim.2 == 0 {
        return Err(invalid(
            "filtered IQ series",
            format!("empty series of shape {dim:?} (nz, nx, frames)"),
        ));
    }
    for (k, series) in filtered.iter().enumerate() {
        if series.dim() != dim {
            return Err(Error::Shape(format!(
                "angle {k} series has shape {:?}, angle 0 has {dim:?} (nz, nx, frames)",
                series.dim()
            )));
        }
        // On every core (2 GB for 360 frames of 8 angles: a value at a time on one core took
        // most of a second).
        if !complex_finite_on_every_core(series.view()) {
            return Err(Error::NonFinite(format!("filtered IQ series of angle {k}")));
        }
    }
    if angles.iter().any(|a| !a.is_finite()) {
        return Err(Error::NonFinite("steering angles".into()));
    }
    Ok(dim)
}

/// Number of windows of `window` frames, `step` apart, in `frames` frames; errors when none fits.
pub(super) fn window_count(
    frames: usize,
    window: usize,
    step: usize,
    frame_rate: f64,
) -> Result<usize> {
    check_window_step(window, step)?;
    if window > frames {
        return Err(invalid(
            "window",
            format!(
                "{window} frames ({:.1} ms) is longer than the recording ({frames} frames, {:.1} ms)",
                window as f64 / frame_rate * 1e3,
                frames as f64 / frame_rate * 1e3
            ),
        ));
    }
    Ok((frames - window) / step + 1)
}

/// Samples per cardiac cycle in a series of `n` samples `dt` apart; errors when one cycle does not fit.
pub(super) fn cycle_length(n: usize, dt: f64, hr: f64) -> Result<(f64, usize)> {
    let period = 1.0 / (hr * dt);
    let len = (period.round() as usize).max(2);
    if n < len {
        return Err(invalid(
            "recording",
            format!(
                "shorter than one cardiac cycle: its {n} windows span {:.1} ms, a cycle at {hr:.2} Hz \
                 spans {:.1} ms ({len} windows); record at least one full cycle — PSV, EDV and RI \
                 need one",
                n as f64 * dt * 1e3,
                1e3 / hr
            ),
        ));
    }
    Ok((period, len))
}

/// Vector velocity in sliding windows over slow time: per angle, the autocorrelations of each
/// window's frames → projection V_θ (m/s, with `params.doppler`) → (Vx, Vz) with
/// `params.estimator`, dealiased as `params.dealias` says (each window's mean power orders and
/// masks its flow pixels; Loupas unwraps each pixel with its own Nyquist velocity).
///
/// `images`: clutter-filtered IQ per angle, each (nz, nx, frames), with their angles, compound
/// frame rate, sound speed and demodulation frequency; an angle is used only where its
/// `coverage` says its plane wave reaches the pixel (every angle everywhere without coverage).
/// Windows run in parallel; each is computed independently, so the output does not depend on the
/// number of threads. One angle gives its colour-Doppler velocity alone
/// ([`VelocitySeries::axial_only`]), whose RI is the vessel's wherever the vessel keeps its
/// direction over the cycle ([`ri_maps_triggered`]).
pub fn sliding_vectors(images: &AngleImages, params: &DynamicsParams) -> Result<VelocitySeries> {
    let (filtered, angles) = (&images.series[..], &images.angles[..]);
    let coverage = images.coverage.as_ref().map(|c| c.view());
    let (frame_rate, sound_speed, center_frequency) = (
        images.frame_rate,
        images.sound_speed,
        images.demodulation_frequency,
    );
    require_positive("frame rate", frame_rate)?;
    require_positive("speed of sound", sound_speed)?;
    require_positive("centre frequency", center_frequency)?;
    let (nz, nx, frames) = check_series(filtered, angles)?;
    if let Some(c) = coverage
        && c.dim() != (angles.len(), nz, nx)
    {
        return Err(Error::Shape(format!(
            "angle coverage {:?} for {} angles of {nz} × {nx} pixels",
            c.dim(),
            angles.len()
        )));
    }
    let n_windows = window_count(frames, params.window, params.step, frame_rate)?;
    params.validate(frame_rate)?;
    let dt = params.step as f64 / frame_rate;
    if let Some(hr) = params.heart_rate_hz {
        cycle_length(n_windows, dt, hr)?;
    }

    let n = angles.len();
    let grid_step = images.grid.step();
    // A cell is the beamformer's and the speckle's, not the window's: measured once, on every
    // frame.
    let axial_only = n == 1;
    let cells: Vec<_> = if params.partial_volume && !axial_only {
        filtered
            .par_iter()
            .map(|series| CellCovariance::from_lags(&CellLags::of(series.view()), grid_step))
            .collect()
    } else {
        Vec::new()
    };
    let geometries: Vec<_> = angles
        .iter()
        .map(|&angle| {
            let (lateral_weight, axial_weight) = vector::projection_weights(angle);
            doppler::DopplerGeometry {
                sound_speed,
                frame_rate,
                demodulation_frequency: center_frequency,
                axial_step: images.grid.axial_step(),
                axial_weight,
                lateral_step: grid_step,
                lateral_weight,
            }
        })
        .collect();
    let fit = WindowFit {
        angles,
        coverage,
        params,
        cells: &cells,
        grid_step,
    };
    let mut vx = Array3::<f64>::zeros((if axial_only { 0 } else { n_windows }, nz, nx));
    let mut vz = Array3::<f64>::zeros((n_windows, nz, nx));
    let mut power = Array3::<f64>::zeros((n_windows, nz, nx));
    // Windows are taken a chunk at a time, each angle's moments of the whole chunk from one pass
    // over its frames; the chunk bounds the memory of the moments and of the angles' maps.
    let per_window_bytes =
        nz * nx * (n * AngleMaps::BYTES_PER_PIXEL + doppler::WINDOW_MOMENT_BYTES_PER_PIXEL);
    let chunk = (CHUNK_BYTES / per_window_bytes.max(1)).clamp(1, n_windows);
    // Every window's maps are written whole: the chunk's are reused from one chunk to the next.
    let mut chunk_maps: Vec<AngleMaps> = (0..chunk).map(|_| AngleMaps::zeros(n, nz, nx)).collect();
    // Likewise each angle's moments of the chunk.
    let mut moments = Vec::new();
    for first in (0..n_windows).step_by(chunk) {
        let ks = first..(first + chunk).min(n_windows);
        let starts: Vec<usize> = ks.clone().map(|k| k * params.step).collect();
        let chunk_maps = &mut chunk_maps[..ks.len()];
        for (a, (series, geometry)) in filtered.iter().zip(&geometries).enumerate() {
            doppler::window_moments_into(
                series.view(),
                &starts,
                params.window,
                params.doppler,
                geometry,
                &mut moments,
            )?;
            chunk_maps
                .par_iter_mut()
                .zip(moments.par_iter())
                .try_for_each(|(maps, moments)| {
                    let doppler =
                        doppler::maps_of_moments(moments, params.kernel, params.doppler, geometry)?;
                    maps.assign(a, &doppler, sound_speed, frame_rate);
                    Ok::<_, Error>(())
                })?;
        }
        let fields = chunk_maps
            .par_iter_mut()
            .map(|maps| {
                if axial_only {
                    Ok(fit.axial(maps))
                } else {
                    fit.vectors(maps)
                }
            })
            .collect::<Result<Vec<_>>>()?;
        for (k, (x, z, p)) in ks.zip(fields) {
            if !axial_only {
                vx.index_axis_mut(Axis(0), k).assign(&x);
            }
            vz.index_axis_mut(Axis(0), k).assign(&z);
            power.index_axis_mut(Axis(0), k).assign(&p);
        }
    }
    let half = (params.window - 1) as f64 / 2.0;
    let times_s = (0..n_windows)
        .map(|k| ((k * params.step) as f64 + half) / frame_rate)
        .collect();
    Ok(VelocitySeries {
        times_s,
        vx,
        vz,
        power,
        window_s: params.window as f64 / frame_rate,
        step_s: dt,
        axial_only,
    })
}

/// Memory of the windows taken at a time (bytes): their moments and their angles' maps.
const CHUNK_BYTES: usize = 256 << 20;

/// One window's Doppler maps of every angle, each (angles, nz, nx).
struct AngleMaps {
    /// Projection velocity V_θ (m/s).
    projections: Array3<f64>,
    /// Lateral weight of each projection (the model's or measured).
    lateral: Array3<f64>,
    /// Nyquist velocity of each projection (m/s) at its mean frequency.
    nyquist: Array3<f64>,
    /// Power Doppler (|IQ|² units).
    power: Array3<f64>,
}

impl AngleMaps {
    /// Bytes per pixel per angle.
    const BYTES_PER_PIXEL: usize = 4 * 8;

    fn zeros(angles: usize, nz: usize, nx: usize) -> AngleMaps {
        let zeros = || Array3::<f64>::zeros((angles, nz, nx));
        AngleMaps {
            projections: zeros(),
            lateral: zeros(),
            nyquist: zeros(),
            power: zeros(),
        }
    }

    /// Takes angle `a`'s maps from its Doppler.
    fn assign(&mut self, a: usize, maps: &doppler::DopplerMaps, sound_speed: f64, frame_rate: f64) {
        self.projections
            .index_axis_mut(Axis(0), a)
            .assign(&maps.velocity);
        self.lateral
            .index_axis_mut(Axis(0), a)
            .assign(&maps.lateral_weight);
        ndarray::Zip::from(self.nyquist.index_axis_mut(Axis(0), a))
            .and(&maps.mean_frequency)
            .for_each(|nyquist, &f| {
                *nyquist = doppler::nyquist_velocity(sound_speed, frame_rate, f);
            });
        self.power.index_axis_mut(Axis(0), a).assign(&maps.power);
    }
}

/// What turns a window's angle maps into its vectors: the same for every window.
struct WindowFit<'a> {
    angles: &'a [f64],
    coverage: Option<ndarray::ArrayView3<'a, bool>>,
    params: &'a DynamicsParams,
    cells: &'a [Option<CellCovariance>],
    grid_step: f64,
}

impl WindowFit<'_> {
    /// The window's maps of its one angle: NaN Vx, the colour-Doppler velocity as Vz (the
    /// projection V_θ along (sin θ, 1 + cos θ)/2 read as 2·V_θ/(1 + cos θ), as the whole
    /// recording's `color_doppler` is; NaN where the plane wave misses the pixel), and its power.
    /// Neither dealiasing nor the partial-volume correction applies: both rest on a vector fit.
    fn axial(&self, maps: &mut AngleMaps) -> (Array2<f64>, Array2<f64>, Array2<f64>) {
        if let Some(c) = self.coverage {
            vector::drop_unreached(&mut maps.projections, c);
        }
        let scale = 2.0 / (1.0 + self.angles[0].cos());
        let vz = maps.projections.index_axis(Axis(0), 0).mapv(|v| v * scale);
        let power = maps.power.index_axis(Axis(0), 0).to_owned();
        (Array2::from_elem(vz.dim(), f64::NAN), vz, power)
    }

    /// The window's (Vx, Vz) maps (m/s) and its power Doppler averaged over the angles; `maps`
    /// keep their projections only where the angle reaches the pixel.
    fn vectors(&self, maps: &mut AngleMaps) -> Result<(Array2<f64>, Array2<f64>, Array2<f64>)> {
        let AngleMaps {
            projections,
            lateral,
            nyquist,
            power: power_per_angle,
        } = maps;
        let (params, grid_step) = (self.params, self.grid_step);
        let n = self.angles.len();
        let (_, nz, nx) = projections.dim();
        let mut power = Array2::<f64>::zeros((nz, nx));
        for angle_power in power_per_angle.outer_iter() {
            power += &angle_power;
        }
        power /= n as f64;
        if let Some(c) = self.coverage {
            vector::drop_unreached(projections, c);
        }
        // Kasai's rows are the model's; Loupas fits its measured lateral weights.
        let measured =
            (params.doppler == doppler::DopplerEstimator::Loupas).then(|| lateral.view());
        let flow = dealias::flow_mask(&power, grid_step);
        // The correction's shifts rest on a least-squares fit; the window's estimator fits
        // the corrected projections.
        let estimators = if params.partial_volume && params.estimator != Estimator::LeastSquares {
            vec![Estimator::LeastSquares, params.estimator]
        } else {
            vec![params.estimator]
        };
        let maps = Projections::new(self.angles, projections.view(), measured, nyquist.view())?;
        let fits = dealias::dealiased_vectors_each(
            &maps,
            &estimators,
            params.dealias,
            power.view(),
            flow.view(),
        )?;
        let field = if params.partial_volume {
            let pairs: Vec<_> = estimators.iter().copied().zip(&fits).collect();
            crate::estimate::partial_volume::corrected_fits(
                &maps,
                &pairs,
                &crate::estimate::partial_volume::AngleCells {
                    power: power_per_angle.view(),
                    cells: self.cells,
                    kernel: params.kernel,
                },
                flow.view(),
                grid_step,
            )?
            .pop()
        } else {
            fits.into_iter().next().map(|f| f.field)
        }
        .ok_or_else(|| Error::Shape("one vector field per estimator".into()))?;
        Ok((field.vx, field.vz, power))
    }
}
