//! The non-linear part of the chain: clutter filter, Doppler, vector velocity, dealiasing,
//! partial-volume correction and the dynamics windows, on formed images.

use std::time::Instant;

use ndarray::{Array2, Array3, Axis};

use crate::acquisition::channel::Acquisition;

use super::params::{DealiasOutcome, DopplerMaps, ProcessOutput, ProcessParams, Stage};
use crate::core::error::{Error, Result, invalid};
use crate::core::grid::Grid;
use crate::dynamics::{self, DynamicsParams, RiMaps, VelocitySeries, VesselTests};
use crate::estimate::clutter::{self};
use crate::estimate::dealias::{self, Dealias};
use crate::estimate::doppler::{self, DopplerEstimator, DopplerGeometry, Moments};
use crate::estimate::partial_volume;
use crate::estimate::projections::Projections;
use crate::estimate::vector::{self, Estimator, VectorField};
use crate::form::beamform::{self};
use crate::form::images::AngleImages;

/// The non-linear part: B-mode, clutter filter, Doppler and vector solve from per-angle image
/// series (nz, nx, frames) on `params.grid`.
pub fn analyse(
    mut images: AngleImages,
    params: &ProcessParams,
    progress: &dyn Fn(Stage, usize, usize),
) -> Result<ProcessOutput> {
    images.validate()?;
    if images.grid != params.grid {
        return Err(invalid(
            "grid",
            "the images were formed on another grid than the processing settings'",
        ));
    }
    let angles = images.angles.clone();
    let n = angles.len();
    let mut timings = Vec::new();
    let bmode_db = beamform::bmode_db(beamform::compounded(&images.series)?.view());
    let clock = Instant::now();
    let reports = clutter::svd_filter_each(&mut images.series, &params.clutter, |k| {
        progress(Stage::Clutter, k, n)
    })?;
    progress(Stage::Clutter, n, n);
    timings.push((Stage::Clutter, clock.elapsed().as_secs_f64()));

    let clock = Instant::now();
    progress(Stage::Doppler, 0, 1);
    let (per_angle, compound) = moments(&images, params, None)?;
    let maps = doppler_maps(&per_angle, &compound, &images, params)?;
    progress(Stage::Doppler, 1, 1);
    timings.push((Stage::Doppler, clock.elapsed().as_secs_f64()));

    Ok(ProcessOutput::from_maps(
        maps,
        params.grid.clone(),
        bmode_db,
        reports,
        images,
        timings,
    ))
}

/// What turns angle `angle`'s series (`None`: the compound's) of `images` into velocity: the
/// sampling of `grid` and the echo path's weights, (sin θ, 1 + cos θ) for one angle and the
/// angles' means for their compound.
pub fn doppler_geometry(
    images: &AngleImages,
    grid: &Grid,
    angle: Option<usize>,
) -> DopplerGeometry {
    geometry_of(
        &images.angles,
        (
            images.sound_speed,
            images.frame_rate,
            images.demodulation_frequency,
        ),
        grid,
        angle,
    )
}

/// [`doppler_geometry`] from the angles (rad) and (speed of sound (m/s), frame rate (Hz),
/// demodulation frequency (Hz)).
fn geometry_of(
    angles: &[f64],
    (sound_speed, frame_rate, demodulation_frequency): (f64, f64, f64),
    grid: &Grid,
    angle: Option<usize>,
) -> DopplerGeometry {
    let n = angles.len().max(1) as f64;
    let (lateral_weight, axial_weight) = match angle {
        Some(k) => vector::projection_weights(angles[k]),
        None => (
            angles.iter().map(|a| a.sin()).sum::<f64>() / n,
            1.0 + angles.iter().map(|a| a.cos()).sum::<f64>() / n,
        ),
    };
    DopplerGeometry {
        sound_speed,
        frame_rate,
        demodulation_frequency,
        axial_step: grid.axial_step(),
        axial_weight,
        lateral_step: grid.step(),
        lateral_weight,
    }
}

/// Refuses, before any work, a Doppler estimator that `params.grid` cannot serve for the
/// recording `acq`: Loupas on an axial step too coarse to read the echo's mean frequency
/// ([`doppler::AxialSampling::with_weight`]), at any angle or their compound.
pub fn check_doppler_estimator(acq: &Acquisition, params: &ProcessParams) -> Result<()> {
    let angles = &acq.sequence.angles;
    let scales = (
        acq.sound_speed,
        acq.frame_rate(),
        acq.probe.center_frequency,
    );
    for angle in (0..angles.len()).map(Some).chain([None]) {
        params
            .doppler_estimator
            .check(&geometry_of(angles, scales, &params.grid, angle))?;
    }
    Ok(())
}

/// [`check_doppler_estimator`] for image series formed elsewhere: the estimator checked at
/// each of `images`' angles and their compound, on `params.grid`.
pub fn check_doppler_estimator_on(images: &AngleImages, params: &ProcessParams) -> Result<()> {
    for angle in (0..images.n_angles()).map(Some).chain([None]) {
        params
            .doppler_estimator
            .check(&doppler_geometry(images, &params.grid, angle))?;
    }
    Ok(())
}

/// The Doppler moments ([`doppler::moments`]) of each angle's clutter-filtered series of
/// `images` (nz, nx, frames) and of their compound, for `params.doppler_estimator`; a range of
/// `frames` only, when given (a segment's own frames).
pub fn moments(
    images: &AngleImages,
    params: &ProcessParams,
    frames: Option<std::ops::Range<usize>>,
) -> Result<(Vec<Moments>, Moments)> {
    let range = frames.unwrap_or(0..images.n_frames());
    let per_angle = images
        .series
        .iter()
        .enumerate()
        .map(|(k, image)| {
            let series = image.slice(ndarray::s![.., .., range.clone()]);
            // The cell's lags, for the partial-volume correction, in the moments' own pass.
            let measure = if params.measures_cells(images.series.len()) {
                doppler::moments_with_cell
            } else {
                doppler::moments
            };
            measure(
                series,
                params.doppler_estimator,
                &doppler_geometry(images, &params.grid, Some(k)),
            )
        })
        .collect::<Result<Vec<_>>>()?;
    let compound = match per_angle.as_slice() {
        // One angle is its own compound: the sum of one series, measured with the same echo
        // path's weights.
        [only] => Moments {
            cell: None,
            ..only.clone()
        },
        _ => doppler::moments(
            beamform::compound(&images.series)?.slice(ndarray::s![.., .., range]),
            params.doppler_estimator,
            &doppler_geometry(images, &params.grid, None),
        )?,
    };
    Ok((per_angle, compound))
}

/// Refuses Doppler moments whose power overflowed single precision somewhere: a sample far beyond
/// [`crate::core::lags::SAMPLE_PEAK_RANGE`] in a frame the scale check did not read (it reads
/// each block's first frame, a recording being scaled as a whole) would otherwise give infinite
/// power and maps of noise around it, written as if they were the flow.
fn check_power_finite<'a>(moments: impl Iterator<Item = &'a Moments>) -> Result<()> {
    let overflowed = moments
        .map(|m| m.power.iter().filter(|p| p.is_infinite()).count())
        .max()
        .unwrap_or(0);
    if overflowed == 0 {
        return Ok(());
    }
    Err(invalid(
        "sample scale",
        format!(
            "the power Doppler is infinite at {overflowed} pixels: some samples lie far above the \
             {:.0e} that pcuvd's single-precision lag products hold (each block is judged by its \
             first frame: a corrupt or saturated frame later in it is not); repair or rescale \
             the recording",
            crate::core::lags::SAMPLE_PEAK_RANGE.1
        ),
    ))
}

/// Velocities and vectors from Doppler moments ([`moments`], or those of several segments of a
/// long recording merged, [`doppler::Moments::merge`]) with `params`' kernel, estimator and
/// dealiasing: `images` gives the angles, frame rate, speed of sound, demodulation frequency and
/// coverage (its series are not read).
pub fn doppler_maps(
    per_angle: &[Moments],
    compound: &Moments,
    images: &AngleImages,
    params: &ProcessParams,
) -> Result<DopplerMaps> {
    let angles = &images.angles;
    let n = angles.len();
    if per_angle.len() != n {
        return Err(invalid(
            "Doppler moments",
            format!("{} for {n} angles", per_angle.len()),
        ));
    }
    check_power_finite(per_angle.iter().chain([compound]))?;
    let frame_rate = images.frame_rate;
    let (c, f0) = (images.sound_speed, images.demodulation_frequency);
    let (nz, nx) = params.grid.shape();
    let mut projections = Array3::<f64>::zeros((n, nz, nx));
    let mut power_per_angle = Array3::<f64>::zeros((n, nz, nx));
    let mut lateral_weights = Array3::<f64>::zeros((n, nz, nx));
    // Each pixel's projection Nyquist velocity, c·f_frame/(4 f̄): its own mean frequency's.
    let mut nyquist = Array3::<f64>::zeros((n, nz, nx));
    let mut only_angle = None;
    for (k, m) in per_angle.iter().enumerate() {
        let maps = doppler::maps_of_moments(
            m,
            params.doppler_kernel,
            params.doppler_estimator,
            &doppler_geometry(images, &params.grid, Some(k)),
        )?;
        projections
            .index_axis_mut(Axis(0), k)
            .assign(&maps.velocity);
        lateral_weights
            .index_axis_mut(Axis(0), k)
            .assign(&maps.lateral_weight);
        nyquist.index_axis_mut(Axis(0), k).assign(
            &maps
                .mean_frequency
                .mapv(|f| doppler::nyquist_velocity(c, frame_rate, f)),
        );
        power_per_angle.index_axis_mut(Axis(0), k).assign(&m.power);
        if n == 1 {
            only_angle = Some(maps);
        }
    }
    // The compounded echo path changes by Vz·(1 + mean cos θ) (+ Vx·mean sin θ, zero for symmetric
    // angle sets): rescale its velocity to the axial velocity.
    let mean_cos = angles.iter().map(|a| a.cos()).sum::<f64>() / n as f64;
    // One angle is its own compound: the same moments ([`moments`]) read with the same geometry
    // (the mean of one angle's weights is its weights, to the bit), so its maps are the angle's.
    let doppler::DopplerMaps {
        power, velocity, ..
    } = match only_angle {
        Some(maps) => maps,
        None => doppler::maps_of_moments(
            compound,
            params.doppler_kernel,
            params.doppler_estimator,
            &doppler_geometry(images, &params.grid, None),
        )?,
    };
    let axial = velocity.mapv(|v| 2.0 * v / (1.0 + mean_cos));
    let coverage = images
        .coverage
        .clone()
        .unwrap_or_else(|| Array3::from_elem((n, nz, nx), true));
    vector::drop_unreached(&mut projections, coverage.view());
    let nyquist_velocity = doppler::nyquist_velocity(c, frame_rate, f0);
    let cells: Vec<_> = per_angle
        .iter()
        .map(|m| {
            m.cell.as_ref().and_then(|lags| {
                partial_volume::CellCovariance::from_lags(lags, params.grid.step())
            })
        })
        .collect();
    // Kasai's rows are the model's; Loupas fits its measured lateral weights.
    let lateral =
        (params.doppler_estimator == DopplerEstimator::Loupas).then(|| lateral_weights.view());
    let (vector_ls, vector_irls, dealiased) = if n >= 2 {
        let flow = dealias::flow_mask(&power, params.grid.step());
        let maps = Projections::new(angles, projections.view(), lateral, nyquist.view())?;
        let [ls, irls]: [dealias::DealiasedField; 2] = dealias::dealiased_vectors_each(
            &maps,
            &[Estimator::LeastSquares, Estimator::Irls(params.irls)],
            params.dealias,
            power.view(),
            flow.view(),
        )?
        .try_into()
        .map_err(|_| Error::Shape("two estimators, two fields".into()))?;
        let (ls_field, irls_field) = if params.partial_volume {
            let [ls_field, irls_field]: [VectorField; 2] = partial_volume::corrected_fits(
                &maps,
                &[
                    (Estimator::LeastSquares, &ls),
                    (Estimator::Irls(params.irls), &irls),
                ],
                &partial_volume::AngleCells {
                    power: power_per_angle.view(),
                    cells: &cells,
                    kernel: params.doppler_kernel,
                },
                flow.view(),
                params.grid.step(),
            )?
            .try_into()
            .map_err(|_| Error::Shape("two estimators, two fields".into()))?;
            (ls_field, irls_field)
        } else {
            (ls.field, irls.field)
        };
        let outcome = (ls.intervals > 0).then(|| DealiasOutcome {
            intervals: ls.intervals,
            flow_pixels: flow.iter().filter(|&&f| f).count(),
            irls: irls.counts,
            ls: ls.counts,
        });
        (Some(ls_field), Some(irls_field), outcome)
    } else {
        (None, None, None)
    };
    Ok(DopplerMaps {
        power_doppler: power,
        color_doppler: axial,
        power_per_angle,
        projections,
        coverage,
        lateral_weights,
        vector_ls,
        vector_irls,
        dealias: dealiased,
        nyquist_velocity,
        projection_nyquist: nyquist,
        cells,
    })
}

/// The dynamics stage on a processed recording: vector velocity in sliding windows over the
/// clutter-filtered series (`params`), the whole-recording vessel mask of `vessel` on its power
/// Doppler, then PSV, EDV, RI, classes and flow directions of those pixels, over the cardiac
/// cycles that `triggers` (s from the first frame: ECG R-waves or scanner triggers) delimit when
/// given, else found as [`dynamics::cardiac_cycles`] says. `process`, the vessel-network study and
/// the tests all run it through here.
pub fn dynamics(
    out: &ProcessOutput,
    params: &DynamicsParams,
    vessel: &VesselTests,
    triggers: Option<&[f64]>,
) -> Result<(VelocitySeries, RiMaps)> {
    if out.filtered.series.is_empty() {
        return Err(invalid(
            "filtered series",
            "the recording was processed in segments (too long to hold whole) and its filtered \
             series were not kept: give the dynamics settings to process itself",
        ));
    }
    params.validate(out.filtered.frame_rate)?;
    // Windows unwrap as far as the whole recording needed (auto decides once, on the recording).
    let params = &DynamicsParams {
        dealias: match (params.dealias, &out.maps.dealias) {
            (Dealias::Auto, Some(done)) => Dealias::Intervals(done.intervals),
            (setting, _) => setting,
        },
        ..*params
    };
    let series = dynamics::sliding_vectors(&out.filtered, params)?;
    let maps = ri_maps_of(
        &series,
        &out.maps.power_doppler,
        &out.grid,
        params,
        vessel,
        triggers,
    )?;
    Ok((series, maps))
}

/// The RI half of [`dynamics`], on a velocity series already formed (by [`dynamics`] or segment by
/// segment, [`crate::pipeline::segments`]): the vessel mask of `vessel` on the whole-recording power Doppler,
/// then PSV, EDV, RI, classes and flow directions over the cardiac cycles.
pub fn ri_maps_of(
    series: &VelocitySeries,
    power_doppler: &Array2<f64>,
    grid: &Grid,
    params: &DynamicsParams,
    vessel: &VesselTests,
    triggers: Option<&[f64]>,
) -> Result<RiMaps> {
    let flow = vessel.flow_mask(power_doppler, grid.step());
    dynamics::ri_maps_triggered(series, params, Some(&flow), triggers)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::vector::IrlsParams;
    use crate::form::beamform::{Apodization, DasParams};
    use crate::form::decode::EventAlignment;
    use num_complex::Complex32;

    /// One angle is its own compound: its maps stand for the compound's, to the bit, as reading
    /// the compound's moments would give them, and no cell is measured (there is no vector fit
    /// for the correction to correct).
    #[test]
    fn one_angle_is_read_as_its_own_compound() {
        let (nz, nx, frames) = (24, 7, 16);
        let grid = Grid {
            x: (0..nx).map(|i| i as f64 * 5e-5).collect(),
            z: (0..nz).map(|i| 5e-3 + i as f64 * 2.5e-5).collect(),
        };
        // A speckle whose phase turns 0.4 rad a frame and a half-wavelength a row (Loupas reads
        // its mean frequency from the rows): every map is non-trivial.
        let mut state = 7u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 40) as f32 / (1u64 << 24) as f32 - 0.5
        };
        let speckle = Array2::from_shape_simple_fn((nz, nx), || Complex32::new(next(), next()));
        let series = Array3::from_shape_fn((nz, nx, frames), |(iz, ix, t)| {
            speckle[[iz, ix]] * Complex32::from_polar(1.0, 0.4 * t as f32 + 1.3 * iz as f32)
        });
        let images = AngleImages {
            grid: grid.clone(),
            angles: vec![0.1],
            frame_rate: 1000.0,
            sound_speed: 1540.0,
            demodulation_frequency: 15.625e6,
            coverage: None,
            series: vec![series],
        };
        let params = ProcessParams {
            grid: grid.clone(),
            das: DasParams {
                f_number: 1.0,
                apodization: Apodization::Hann,
                sound_speed: 1540.0,
            },
            clutter: clutter::ClutterParams::default(),
            doppler_kernel: (5, 1),
            doppler_estimator: DopplerEstimator::Loupas,
            irls: IrlsParams::default(),
            iq_cutoff: None,
            event_alignment: EventAlignment::MidFrame,
            dealias: Dealias::Off,
            partial_volume: true,
        };
        let (per_angle, compound) = moments(&images, &params, None).unwrap();
        assert!(per_angle[0].cell.is_none());
        let maps = doppler_maps(&per_angle, &compound, &images, &params).unwrap();
        let own = doppler::maps_of_moments(
            &compound,
            params.doppler_kernel,
            params.doppler_estimator,
            &doppler_geometry(&images, &grid, None),
        )
        .unwrap();
        assert_eq!(maps.power_doppler, own.power);
        let axial = own.velocity.mapv(|v| 2.0 * v / (1.0 + 0.1f64.cos()));
        assert_eq!(maps.color_doppler, axial);
        assert!(axial.iter().all(|v| v.abs() > 0.0 && v.is_finite()));
        assert!(maps.cells.iter().all(Option::is_none));
    }
}
