//! The moments the estimators sum (power, lag-1 autocorrelation, spatial lags) and the maps made
//! from them: power, colour and signed power Doppler, and each angle's projection velocity.

use super::lag_sums::{Wanted, lag_sums};
use super::*;

/// What [`doppler_maps`] derives every map from, per pixel (nz, nx), before any spatial
/// averaging: means over a series' frames (power) and frame pairs (the rest). Being means, those
/// of consecutive parts of a recording combine into the whole's ([`Moments::merge`]; the pairs
/// across a cut are not counted), which is how a long recording is processed in segments.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Moments {
    /// Mean |S|² over the frames (|IQ|² units).
    pub power: Array2<f64>,
    /// Mean S*(t)·S(t + 1) over the frame pairs (|IQ|² units).
    pub r1: Array2<Complex64>,
    /// The axial lags at temporal lags ±1 and within frames (Loupas only; `None` for Kasai).
    pub axial: Option<SpatialLag>,
    /// The lateral lags at temporal lags ±1 and within frames (Loupas on a grid that
    /// [`DopplerGeometry::measures_lateral`]; else `None`).
    pub lateral: Option<SpatialLag>,
    /// The spatial lags within frames, summed over the image: the resolution cell
    /// ([`crate::estimate::partial_volume`]); measured only when asked for ([`moments_with_cell`];
    /// `None` from [`moments`]).
    pub cell: Option<CellLags>,
    /// Frames the power is a mean over.
    pub frames: usize,
    /// Frame pairs the lag-1 products are means over.
    pub pairs: usize,
}

impl Moments {
    /// Combines `other`'s moments (other frames of the same pixels, measured alike) into these:
    /// each mean weighted by its frames or pairs. Refuses moments of another shape or estimator.
    pub fn merge(&mut self, other: &Moments) -> Result<()> {
        if self.power.dim() != other.power.dim()
            || self.axial.is_some() != other.axial.is_some()
            || self.lateral.is_some() != other.lateral.is_some()
        {
            return Err(Error::Shape(format!(
                "moments of {:?} pixels cannot combine with moments of {:?} measured otherwise",
                other.power.dim(),
                self.power.dim()
            )));
        }
        let (f0, f1) = (self.frames as f64, other.frames as f64);
        let (p0, p1) = (self.pairs as f64, other.pairs as f64);
        let (frames, pairs) = ((f0 + f1).max(1.0), (p0 + p1).max(1.0));
        Zip::from(&mut self.power)
            .and(&other.power)
            .for_each(|a, &b| *a = (*a * f0 + b * f1) / frames);
        let by_pairs = |a: &mut Array2<Complex64>, b: &Array2<Complex64>| {
            Zip::from(a)
                .and(b)
                .for_each(|a, &b| *a = (*a * p0 + b * p1) / pairs)
        };
        by_pairs(&mut self.r1, &other.r1);
        for (mine, theirs) in [
            (self.axial.as_mut(), other.axial.as_ref()),
            (self.lateral.as_mut(), other.lateral.as_ref()),
        ] {
            if let (Some(m), Some(t)) = (mine, theirs) {
                by_pairs(&mut m.plus, &t.plus);
                by_pairs(&mut m.minus, &t.minus);
                Zip::from(&mut m.same)
                    .and(&t.same)
                    .for_each(|a, &b| *a = (*a * f0 + b * f1) / frames);
            }
        }
        self.cell = match (&self.cell, &other.cell) {
            (Some(mine), Some(theirs)) => Some(mine.merged(self.frames, theirs, other.frames)),
            _ => None,
        };
        self.frames += other.frames;
        self.pairs += other.pairs;
        Ok(())
    }
}

/// Which spatial lags an estimator's [`Moments`] hold: the axial one (Loupas), and the lateral
/// one too where Loupas measures the lateral weight.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct MeasuredLags {
    /// The axial lag ([`Moments::axial`]).
    pub axial: bool,
    /// The lateral lag ([`Moments::lateral`]).
    pub lateral: bool,
}

impl MeasuredLags {
    /// The lags `estimator` measures on `geometry` in an image `nx` pixels wide: none for Kasai;
    /// for Loupas the axial lag (an axial step too coarse for it is refused here, before the
    /// work) and the lateral one where [`DopplerGeometry::measures_lateral`] and nx ≥ 2.
    pub(super) fn of(
        estimator: DopplerEstimator,
        geometry: &DopplerGeometry,
        nx: usize,
    ) -> Result<MeasuredLags> {
        Ok(match estimator {
            DopplerEstimator::Kasai => MeasuredLags {
                axial: false,
                lateral: false,
            },
            DopplerEstimator::Loupas => {
                geometry.loupas_axial()?;
                MeasuredLags {
                    axial: true,
                    lateral: nx >= 2 && geometry.measures_lateral(),
                }
            }
        })
    }
}

/// The [`Moments`] of `series` (nz, nx, frames ≥ 2) that `estimator` needs on this `geometry`:
/// power and lag-1 for both, the axial lag for Loupas (which needs ≥ 2 rows and an axial step
/// fine enough for [`AxialSampling::with_weight`], refused here, before the work), the lateral
/// lag where Loupas measures the lateral weight.
pub fn moments(
    series: ArrayView3<Complex32>,
    estimator: DopplerEstimator,
    geometry: &DopplerGeometry,
) -> Result<Moments> {
    measure(series, estimator, geometry, false)
}

/// [`moments`] with the resolution cell's lags ([`Moments::cell`]) measured in the same pass,
/// for the partial-volume correction.
pub fn moments_with_cell(
    series: ArrayView3<Complex32>,
    estimator: DopplerEstimator,
    geometry: &DopplerGeometry,
) -> Result<Moments> {
    measure(series, estimator, geometry, true)
}

/// [`moments`], with the cell's lags when `cell`.
fn measure(
    series: ArrayView3<Complex32>,
    estimator: DopplerEstimator,
    geometry: &DopplerGeometry,
    cell: bool,
) -> Result<Moments> {
    let (_, nx, nf) = series.dim();
    let lags = MeasuredLags::of(estimator, geometry, nx)?;
    if lags.lateral {
        check_spatial_lag(series.dim(), Axis(1))?;
    }
    if lags.axial {
        check_spatial_lag(series.dim(), Axis(0))?;
    }
    check_frames(nf)?;
    let sums = lag_sums(
        series,
        Wanted {
            temporal: true,
            axial: lags.axial,
            lateral: lags.lateral,
            cell,
        },
    );
    let raw = sums.temporal.expect("the temporal lags were asked for");
    Ok(Moments {
        power: raw.power,
        r1: raw.r1,
        axial: sums.axial,
        lateral: sums.lateral,
        cell: sums.cell,
        frames: nf,
        pairs: nf - 1,
    })
}

/// Power, lag-1 autocorrelation, mean frequency and velocity of `series` (nz, nx, frames) with
/// `estimator`, the autocorrelations averaged over `kernel` (odd (rows, cols)); the mean frequency
/// over [`mean_frequency_kernel`]. Loupas needs ≥ 2 rows and an axial step fine enough for
/// [`AxialSampling::with_weight`]; a pixel whose axial autocorrelation is zero keeps the
/// demodulation frequency. The same as [`maps_of_moments`] of [`moments`].
pub fn doppler_maps(
    series: ArrayView3<Complex32>,
    kernel: (usize, usize),
    estimator: DopplerEstimator,
    geometry: &DopplerGeometry,
) -> Result<DopplerMaps> {
    check_kernel(kernel)?;
    maps_of_moments(
        &moments(series, estimator, geometry)?,
        kernel,
        estimator,
        geometry,
    )
}

/// The maps of [`doppler_maps`] from a series' [`Moments`] (or several series' merged): every
/// product averaged over `kernel` (the mean frequency's over [`mean_frequency_kernel`]), then the
/// phases turned into frequency and velocity. Loupas needs moments measured for Loupas.
pub fn maps_of_moments(
    moments: &Moments,
    kernel: (usize, usize),
    estimator: DopplerEstimator,
    geometry: &DopplerGeometry,
) -> Result<DopplerMaps> {
    let DopplerGeometry {
        sound_speed,
        frame_rate,
        demodulation_frequency: f_demod,
        ..
    } = *geometry;
    require_positive("speed of sound", sound_speed)?;
    require_positive("frame rate", frame_rate)?;
    require_positive("demodulation frequency", f_demod)?;
    check_kernel(kernel)?;
    let averaged = |map: &Array2<Complex64>, k: (usize, usize)| {
        if k == (1, 1) {
            map.clone()
        } else {
            box_average(map, k)
        }
    };
    let r1 = averaged(&moments.r1, kernel);
    let power = if kernel == (1, 1) {
        moments.power.clone()
    } else {
        box_average(&moments.power, kernel)
    };
    let (mean_frequency, lateral_weight) = match estimator {
        DopplerEstimator::Kasai => (
            Array2::from_elem(r1.dim(), f_demod),
            Array2::from_elem(r1.dim(), geometry.lateral_weight),
        ),
        DopplerEstimator::Loupas => {
            let axial = geometry.loupas_axial()?;
            let Some(axial_lag) = &moments.axial else {
                return Err(invalid(
                    "Doppler estimator",
                    "loupas needs the axial-lag moments, which these moments were measured without",
                ));
            };
            let wide = mean_frequency_kernel(kernel);
            let r1_wide = averaged(&moments.r1, wide);
            let r_axial = axial_lag.rotated(&r1_wide, wide);
            let r_axial_same = averaged(&axial_lag.same, wide);
            let f_bar = Zip::from(&r_axial)
                .and(&r_axial_same)
                .map_collect(|&r, &q| {
                    let f = secant(axial.mean_frequency(q), axial.mean_frequency(r));
                    if has_magnitude(r) && has_magnitude(q) && f > 0.0 {
                        f
                    } else {
                        f_demod
                    }
                });
            let lateral = match &moments.lateral {
                Some(lateral_lag) if geometry.measures_lateral() => {
                    let r_lateral = lateral_lag.rotated(&r1_wide, wide);
                    let r_lateral_same = averaged(&lateral_lag.same, wide);
                    let step = geometry.lateral_step;
                    let wavelength = sound_speed / f_demod;
                    let tau = std::f64::consts::TAU;
                    let expected = tau * geometry.lateral_weight * step / wavelength;
                    let unwrapped = |r: Complex64| {
                        let phase = r.arg();
                        phase + tau * ((expected - phase) / tau).round()
                    };
                    Zip::from(&r_lateral)
                        .and(&r_lateral_same)
                        .and(&f_bar)
                        .map_collect(|&r, &q, &f| {
                            if has_magnitude(r) && has_magnitude(q) {
                                let phase = secant(unwrapped(q), unwrapped(r));
                                // k̄x / k̄, k̄ = 2π f̄ / c.
                                phase / step * sound_speed / (tau * f)
                            } else {
                                geometry.lateral_weight
                            }
                        })
                }
                _ => Array2::from_elem(r1.dim(), geometry.lateral_weight),
            };
            (f_bar, lateral)
        }
    };
    // −scale·arg R with scale = c·f_frame/(4π f̄), in the order of [`projection_velocity`], so
    // that Kasai's maps are bit for bit those of the lag-1 stage functions.
    let velocity = Zip::from(&r1).and(&mean_frequency).map_collect(|&r, &f| {
        if has_magnitude(r) {
            -(sound_speed * frame_rate / (4.0 * std::f64::consts::PI * f)) * r.arg()
        } else {
            0.0
        }
    });
    Ok(DopplerMaps {
        power,
        r1,
        mean_frequency,
        velocity,
        lateral_weight,
    })
}

/// Signed power Doppler (|IQ|² units): each pixel's power Doppler carrying the sign of its colour
/// Doppler (axial velocity, positive = away from the probe), the direction-coded map that
/// functional-ultrasound work reads arteries and veins from first (flow towards and away from the
/// probe). Zero where the axial velocity is zero; NaN where either input is not finite.
pub fn signed_power<D: ndarray::Dimension>(
    power: &ndarray::Array<f64, D>,
    axial_velocity: &ndarray::Array<f64, D>,
) -> ndarray::Array<f64, D> {
    Zip::from(power).and(axial_velocity).map_collect(|&p, &v| {
        if !(p.is_finite() && v.is_finite()) {
            f64::NAN
        } else if v == 0.0 {
            0.0
        } else {
            p.copysign(v)
        }
    })
}
