//! Doppler time series: power, colour and vector Doppler maps of successive ensembles of frames,
//! each with its own SVD clutter filter, as functional-ultrasound studies need.
//!
//! An ensemble is `frames` consecutive compound frames; ensembles start every `step` frames. Each
//! one runs the non-linear part of the chain ([`pipeline::analyse`]) on its own slice of the
//! per-angle image series, so its clutter filter adapts to the tissue motion of its own time,
//! and its maps are exactly what `process` gives for a recording of just those frames.

use ndarray::{Array3, Axis, s};

use crate::core::error::{Result, invalid};
use crate::estimate::clutter::{ClutterReport, CutOffs};
use crate::form::images::AngleImages;
use crate::pipeline::{self, ProcessParams, Stage};

/// How a recording is cut into ensembles of frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EnsembleSpec {
    /// Compound frames per ensemble (≥ 2: Doppler needs two).
    pub frames: usize,
    /// Frames from one ensemble's start to the next's (≥ 1; `frames` for no overlap).
    pub step: usize,
}

impl EnsembleSpec {
    /// Centre time (s from the first frame) of the ensemble starting at frame `start`.
    pub fn centre_time(&self, start: usize, frame_rate: f64) -> f64 {
        (start as f64 + (self.frames as f64 - 1.0) / 2.0) / frame_rate
    }

    /// The start frame of every ensemble that fits in a recording of `total` frames; refuses an
    /// ensemble shorter than 2 frames, longer than the recording, or a step of 0.
    pub fn starts(&self, total: usize) -> Result<Vec<usize>> {
        if self.frames < 2 {
            return Err(invalid(
                "ensemble frames",
                format!("{}: Doppler needs at least 2 frames", self.frames),
            ));
        }
        if self.step == 0 {
            return Err(invalid("ensemble step", "must be at least 1 frame"));
        }
        if self.frames > total {
            return Err(invalid(
                "ensemble frames",
                format!(
                    "{} frames per ensemble, but the recording has {total}",
                    self.frames
                ),
            ));
        }
        Ok((0..=total - self.frames).step_by(self.step).collect())
    }
}

/// Maps of every ensemble, shape (ensembles, nz, nx), SI units.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EnsembleMaps {
    /// Centre time of each ensemble (s) from the first frame: (start + (frames − 1)/2) / frame rate.
    pub times_s: Vec<f64>,
    /// First frame of each ensemble.
    pub starts: Vec<usize>,
    /// Power Doppler of each ensemble's compounded, filtered series (|IQ|² units).
    pub power_doppler: Array3<f64>,
    /// Axial velocity (m/s, positive = away from the probe).
    pub color_doppler: Array3<f64>,
    /// Vector velocity, PC-UVD estimator (IRLS-WLS), m/s; `None` with one angle.
    pub vx: Option<Array3<f64>>,
    /// Axial component of the vector velocity (m/s, positive deeper); `None` with one angle.
    pub vz: Option<Array3<f64>>,
    /// Clutter cut-offs of each ensemble, per angle.
    pub clutter: Vec<Vec<CutOffs>>,
}

impl EnsembleMaps {
    /// Signed power Doppler of each ensemble (|IQ|² units, the sign of its colour Doppler:
    /// positive = away from the probe); see [`crate::estimate::doppler::signed_power`].
    pub fn signed_power_doppler(&self) -> Array3<f64> {
        crate::estimate::doppler::signed_power(&self.power_doppler, &self.color_doppler)
    }

    /// Drops the maps (left (0, nz, nx)), keeping the times, first frames and clutter cut-offs:
    /// what a run keeps of ensembles a store holds.
    pub fn keep_times_only(&mut self) {
        let (_, nz, nx) = self.power_doppler.dim();
        let empty = || Array3::zeros((0, nz, nx));
        self.power_doppler = empty();
        self.color_doppler = empty();
        self.vx = self.vx.as_ref().map(|_| empty());
        self.vz = self.vz.as_ref().map(|_| empty());
    }

    /// Moves every ensemble of `spec` `frames` frames later (a segment's ensembles, counted from
    /// the recording's first frame), at `frame_rate` (Hz).
    pub fn shift(&mut self, frames: usize, spec: EnsembleSpec, frame_rate: f64) {
        self.starts.iter_mut().for_each(|s| *s += frames);
        self.times_s = self
            .starts
            .iter()
            .map(|&s| spec.centre_time(s, frame_rate))
            .collect();
    }

    /// The ensembles of consecutive segments as one series, in order.
    pub fn concatenate(parts: Vec<EnsembleMaps>) -> Result<EnsembleMaps> {
        let first = parts
            .first()
            .ok_or_else(|| invalid("ensembles", "no segment holds a whole ensemble"))?;
        let stack =
            |field: fn(&EnsembleMaps) -> Option<&Array3<f64>>| -> Result<Option<Array3<f64>>> {
                let views: Option<Vec<_>> =
                    parts.iter().map(|p| field(p).map(|a| a.view())).collect();
                views
                    .map(|v| {
                        ndarray::concatenate(Axis(0), &v)
                            .map_err(|e| invalid("ensembles", format!("segments' maps: {e}")))
                    })
                    .transpose()
            };
        let vectors = first.vx.is_some();
        Ok(EnsembleMaps {
            times_s: parts.iter().flat_map(|p| p.times_s.clone()).collect(),
            starts: parts.iter().flat_map(|p| p.starts.clone()).collect(),
            power_doppler: stack(|p| Some(&p.power_doppler))?.expect("every part has power"),
            color_doppler: stack(|p| Some(&p.color_doppler))?.expect("every part has colour"),
            vx: if vectors {
                stack(|p| p.vx.as_ref())?
            } else {
                None
            },
            vz: if vectors {
                stack(|p| p.vz.as_ref())?
            } else {
                None
            },
            clutter: parts.iter().flat_map(|p| p.clutter.clone()).collect(),
        })
    }

    /// Speed |V| (m/s) of each ensemble's vector map; `None` with one angle.
    pub fn speed(&self) -> Option<Array3<f64>> {
        match (&self.vx, &self.vz) {
            (Some(vx), Some(vz)) => Some(
                ndarray::Zip::from(vx)
                    .and(vz)
                    .map_collect(|&x, &z| x.hypot(z)),
            ),
            _ => None,
        }
    }
}

/// The maps of every ensemble of the unfiltered per-angle `images` (as [`pipeline::form_images`]
/// gives them), each analysed with `params`; `progress(stage, done, total)` counts ensembles.
pub fn ensemble_maps(
    images: &AngleImages,
    params: &ProcessParams,
    spec: EnsembleSpec,
    progress: &dyn Fn(Stage, usize, usize),
) -> Result<EnsembleMaps> {
    let starts = spec.starts(images.n_frames())?;
    ensemble_maps_at(images, params, spec, &starts, progress)
}

/// As [`ensemble_maps`], for the ensembles starting at frames `starts` of `images` only (those of
/// a segment of a long recording, [`crate::pipeline::segments`]).
pub fn ensemble_maps_at(
    images: &AngleImages,
    params: &ProcessParams,
    spec: EnsembleSpec,
    starts: &[usize],
    progress: &dyn Fn(Stage, usize, usize),
) -> Result<EnsembleMaps> {
    images.validate()?;
    spec.starts(images.n_frames())?;
    if let Some(&last) = starts.iter().max()
        && last + spec.frames > images.n_frames()
    {
        return Err(invalid(
            "ensemble start",
            format!(
                "frame {last} + {} frames is past the {} frames imaged",
                spec.frames,
                images.n_frames()
            ),
        ));
    }
    let (nz, nx) = params.grid.shape();
    let count = starts.len();
    let vectors = images.n_angles() >= 2;
    let mut maps = EnsembleMaps {
        times_s: starts
            .iter()
            .map(|&s| spec.centre_time(s, images.frame_rate))
            .collect(),
        starts: starts.to_vec(),
        power_doppler: Array3::zeros((count, nz, nx)),
        color_doppler: Array3::zeros((count, nz, nx)),
        vx: vectors.then(|| Array3::zeros((count, nz, nx))),
        vz: vectors.then(|| Array3::zeros((count, nz, nx))),
        clutter: Vec::with_capacity(count),
    };
    let quiet = |_: Stage, _: usize, _: usize| {};
    for (e, &start) in starts.iter().enumerate() {
        progress(Stage::Ensembles, e, count);
        let slice = images.with_series(
            images
                .series
                .iter()
                .map(|series| {
                    series
                        .slice(s![.., .., start..start + spec.frames])
                        .to_owned()
                })
                .collect(),
        );
        let out = pipeline::analyse(slice, params, &quiet)?;
        maps.power_doppler
            .index_axis_mut(Axis(0), e)
            .assign(&out.maps.power_doppler);
        maps.color_doppler
            .index_axis_mut(Axis(0), e)
            .assign(&out.maps.color_doppler);
        if let (Some(vx), Some(vz), Some(field)) =
            (&mut maps.vx, &mut maps.vz, &out.maps.vector_irls)
        {
            vx.index_axis_mut(Axis(0), e).assign(&field.vx);
            vz.index_axis_mut(Axis(0), e).assign(&field.vz);
        }
        maps.clutter
            .push(out.clutter.iter().map(ClutterReport::cut_offs).collect());
    }
    progress(Stage::Ensembles, count, count);
    Ok(maps)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::grid::Grid;
    use crate::estimate::clutter::{ClutterParams, RankCut};
    use crate::estimate::vector::{IrlsParams, projection_weights};
    use crate::form::beamform::DasParams;
    use num_complex::Complex32;

    const FRAME_RATE: f64 = 1000.0;
    const C: f64 = 1540.0;
    const F0: f64 = 5e6;

    /// Two angles' series of a uniform translation (vx, vz) m/s: per pixel a Doppler tone of the
    /// projection's frequency, with a pixel-dependent phase; no clutter.
    fn translating(vx: f64, vz: f64, frames: usize) -> (AngleImages, ProcessParams) {
        let grid = Grid::new(-1e-3, 1e-3, 5e-3, 6e-3, 0.5e-3).unwrap();
        let (nz, nx) = grid.shape();
        let angles = vec![-0.15, 0.15];
        let series = angles
            .iter()
            .map(|&theta| {
                let (s, c) = projection_weights(theta);
                let v_theta = (vx * s + vz * c) / 2.0;
                // arg R(1) = −V_θ/scale, scale = c·f_frame/(4π f0): the phase step per frame.
                let step = -v_theta * 4.0 * std::f64::consts::PI * F0 / (C * FRAME_RATE);
                Array3::from_shape_fn((nz, nx, frames), |(z, x, n)| {
                    let phase = step * n as f64 + 0.37 * (z * nx + x) as f64;
                    Complex32::new(phase.cos() as f32, phase.sin() as f32)
                })
            })
            .collect();
        let images = AngleImages {
            grid: grid.clone(),
            angles,
            frame_rate: FRAME_RATE,
            sound_speed: C,
            demodulation_frequency: F0,
            coverage: None,
            series,
        };
        let params = ProcessParams {
            grid,
            das: DasParams::new(C),
            clutter: ClutterParams {
                low: RankCut::Off,
                high: RankCut::Off,
                ..ClutterParams::default()
            },
            doppler_kernel: (1, 1),
            // The synthetic tones carry no echo along depth (their frequency is the nominal one
            // by construction, and the 0.5 mm grid is far too coarse to measure one).
            doppler_estimator: crate::estimate::doppler::DopplerEstimator::Kasai,
            irls: IrlsParams::default(),
            iq_cutoff: None,
            event_alignment: Default::default(),
            dealias: Default::default(),
            partial_volume: false,
        };
        (images, params)
    }

    #[test]
    fn one_ensemble_of_the_whole_recording_is_the_whole_analysis() {
        let (images, params) = translating(0.01, -0.02, 16);
        let quiet = |_: Stage, _: usize, _: usize| {};
        let spec = EnsembleSpec {
            frames: 16,
            step: 5,
        };
        let maps = ensemble_maps(&images, &params, spec, &quiet).unwrap();
        let whole = pipeline::analyse(images, &params, &quiet).unwrap();
        assert_eq!(maps.starts, vec![0]);
        assert_eq!(maps.times_s, vec![7.5 / FRAME_RATE]);
        assert_eq!(
            maps.power_doppler.index_axis(Axis(0), 0),
            whole.maps.power_doppler
        );
        assert_eq!(
            maps.color_doppler.index_axis(Axis(0), 0),
            whole.maps.color_doppler
        );
        let field = whole.maps.vector_irls.unwrap();
        assert_eq!(maps.vx.unwrap().index_axis(Axis(0), 0), field.vx);
        assert_eq!(maps.vz.unwrap().index_axis(Axis(0), 0), field.vz);
    }

    #[test]
    fn every_ensemble_reads_the_translation() {
        let (vx, vz) = (0.012, -0.02);
        let (images, params) = translating(vx, vz, 40);
        let quiet = |_: Stage, _: usize, _: usize| {};
        let spec = EnsembleSpec { frames: 8, step: 8 };
        let maps = ensemble_maps(&images, &params, spec, &quiet).unwrap();
        assert_eq!(maps.starts, vec![0, 8, 16, 24, 32]);
        assert_eq!(maps.power_doppler.dim(), (5, 3, 5));
        for (&got_x, &got_z) in maps
            .vx
            .as_ref()
            .unwrap()
            .iter()
            .zip(maps.vz.as_ref().unwrap())
        {
            assert!(
                (got_x - vx).abs() < 1e-5 && (got_z - vz).abs() < 1e-5,
                "{got_x} {got_z}"
            );
        }
        for &p in &maps.power_doppler {
            // Two unit-amplitude angles compounded in phase or not: |sum|² ≤ 4.
            assert!(p > 0.0 && p <= 4.0 + 1e-5);
        }
        let speed = maps.speed().unwrap();
        assert!(speed.iter().all(|s| (s - vx.hypot(vz)).abs() < 1e-5));
    }

    #[test]
    fn starts_cover_the_recording_in_steps() {
        let spec = EnsembleSpec { frames: 4, step: 3 };
        assert_eq!(spec.starts(10).unwrap(), vec![0, 3, 6]);
        assert_eq!(
            EnsembleSpec {
                frames: 10,
                step: 1
            }
            .starts(10)
            .unwrap(),
            vec![0]
        );
        assert!(
            EnsembleSpec {
                frames: 11,
                step: 1
            }
            .starts(10)
            .is_err()
        );
        assert!(EnsembleSpec { frames: 1, step: 1 }.starts(10).is_err());
        assert!(EnsembleSpec { frames: 4, step: 0 }.starts(10).is_err());
    }
}
