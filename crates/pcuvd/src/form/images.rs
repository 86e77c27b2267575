//! Per-angle IQ image series with what downstream stages need to read them: the grid, the
//! steering angles, the slow-time rate, the sound speed and the demodulation frequency (as USTB's
//! beamformed data carry their scan and sequence), so that Doppler, dynamics and spectrograms take
//! one argument.

use ndarray::Array3;
use num_complex::Complex32;

use crate::core::error::{Error, Result, invalid};
use crate::core::grid::Grid;

/// Beamformed IQ image series, one per steering angle, each (nz, nx, frames) with frames
/// contiguous, and the acquisition facts that give them meaning.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct AngleImages {
    /// Pixel grid of every image (m).
    pub grid: Grid,
    /// Steering angle of each series (rad).
    pub angles: Vec<f64>,
    /// Slow-time sampling rate of each series: the compound frame rate (Hz).
    pub frame_rate: f64,
    /// Speed of sound (m/s).
    pub sound_speed: f64,
    /// Frequency the IQ data were demodulated at, which Doppler converts phase with (Hz).
    pub demodulation_frequency: f64,
    /// Per angle, the pixels its plane wave reaches (angles, nz, nx); `None`: every pixel.
    pub coverage: Option<Array3<bool>>,
    /// The image series, one per angle, each (nz, nx, frames).
    pub series: Vec<Array3<Complex32>>,
}

impl AngleImages {
    /// Number of steering angles.
    pub fn n_angles(&self) -> usize {
        self.angles.len()
    }

    /// Frames per series (0 when there is none).
    pub fn n_frames(&self) -> usize {
        self.series.first().map_or(0, |s| s.dim().2)
    }

    /// The same metadata around other series (e.g. echoes plus scaled noise).
    pub fn with_series(&self, series: Vec<Array3<Complex32>>) -> AngleImages {
        AngleImages {
            grid: self.grid.clone(),
            angles: self.angles.clone(),
            frame_rate: self.frame_rate,
            sound_speed: self.sound_speed,
            demodulation_frequency: self.demodulation_frequency,
            coverage: self.coverage.clone(),
            series,
        }
    }

    /// Checks that the series, angles, grid and coverage agree and the rates are positive.
    pub fn validate(&self) -> Result<()> {
        let n = self.angles.len();
        if self.series.len() != n {
            return Err(Error::Shape(format!(
                "{} image series for {n} angles",
                self.series.len()
            )));
        }
        let (nz, nx) = self.grid.shape();
        for (k, s) in self.series.iter().enumerate() {
            let (z, x, _) = s.dim();
            if (z, x) != (nz, nx) {
                return Err(Error::Shape(format!(
                    "image series {k} is {z} × {x} pixels; the grid is {nz} × {nx}"
                )));
            }
        }
        if let Some(c) = &self.coverage
            && c.dim() != (n, nz, nx)
        {
            return Err(Error::Shape(format!(
                "coverage is {:?}; expected (angles, nz, nx) = ({n}, {nz}, {nx})",
                c.dim()
            )));
        }
        for (name, value) in [
            ("frame rate", self.frame_rate),
            ("speed of sound", self.sound_speed),
            ("demodulation frequency", self.demodulation_frequency),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(invalid(name, format!("{value}: must be positive")));
            }
        }
        Ok(())
    }
}

/// The series of a few pixels of a run's clutter-filtered images over the recording, per angle:
/// what a spectrogram needs where a long recording's whole series is never held (a segmented
/// run keeps these from each segment's own frames).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PixelSeries {
    /// The pixels, (row, col) on the images' grid.
    pub pixels: Vec<(usize, usize)>,
    /// Per angle, (pixels, frames).
    pub series: Vec<ndarray::Array2<Complex32>>,
    /// Where the series joins frames that were clutter-filtered apart (a segmented run's cores),
    /// in frame order; empty for a series filtered as one.
    #[serde(default)]
    pub seams: Vec<Seam>,
}

/// A join in a [`PixelSeries`] between two separately filtered runs of frames, with the frames the
/// earlier run's filter gave after it. Each run has its own clutter subspace, so its tissue residue
/// steps at the join; a window that starts before the join reads these instead of the later run's,
/// and so sees one filter throughout, as the dynamics windows of a segmented run do.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Seam {
    /// First frame of the later run, in the series' frames.
    pub frame: usize,
    /// Per angle, (pixels, frames): the earlier run's filtered frames from `frame` on.
    pub tail: Vec<ndarray::Array2<Complex32>>,
}

impl PixelSeries {
    /// `pixels` of `images` over its frames `frames`.
    pub fn of(
        images: &AngleImages,
        pixels: &[(usize, usize)],
        frames: std::ops::Range<usize>,
    ) -> Result<Self> {
        let (nz, nx) = images.grid.shape();
        if let Some(p) = pixels.iter().find(|&&(iz, ix)| iz >= nz || ix >= nx) {
            return Err(invalid(
                "kept pixels",
                format!("{p:?} is outside the {nz} × {nx} image"),
            ));
        }
        if frames.end > images.n_frames() || frames.start > frames.end {
            return Err(invalid(
                "kept frames",
                format!("{frames:?} is not within the {} frames", images.n_frames()),
            ));
        }
        let series = images
            .series
            .iter()
            .map(|s| {
                ndarray::Array2::from_shape_fn((pixels.len(), frames.len()), |(k, t)| {
                    let (iz, ix) = pixels[k];
                    s[[iz, ix, frames.start + t]]
                })
            })
            .collect();
        Ok(PixelSeries {
            pixels: pixels.to_vec(),
            series,
            seams: Vec::new(),
        })
    }

    /// `pixels` of `images` over its frames `core`, followed by a [`Seam`] holding the frames
    /// imaged after the core (a segment's overlap), when there are any: what a segment of a
    /// segmented run keeps, to be [`append`](Self::append)ed in order.
    pub fn of_core(
        images: &AngleImages,
        pixels: &[(usize, usize)],
        core: std::ops::Range<usize>,
    ) -> Result<Self> {
        let mut kept = Self::of(images, pixels, core.clone())?;
        if core.end < images.n_frames() {
            let after = Self::of(images, pixels, core.end..images.n_frames())?;
            kept.seams.push(Seam {
                frame: core.len(),
                tail: after.series,
            });
        }
        Ok(kept)
    }

    /// Frames in the series.
    pub fn n_frames(&self) -> usize {
        self.series.first().map_or(0, |s| s.ncols())
    }

    /// Appends `later`'s frames (the same pixels and angles) after these.
    pub fn append(&mut self, later: PixelSeries) -> Result<()> {
        if later.pixels != self.pixels || later.series.len() != self.series.len() {
            return Err(Error::Shape(
                "kept pixel series of other pixels or angles cannot be joined".into(),
            ));
        }
        let offset = self.n_frames();
        for (mine, theirs) in self.series.iter_mut().zip(later.series) {
            *mine = ndarray::concatenate(ndarray::Axis(1), &[mine.view(), theirs.view()])
                .map_err(|e| Error::Shape(format!("joining kept pixel series: {e}")))?;
        }
        self.seams.extend(later.seams.into_iter().map(|seam| Seam {
            frame: seam.frame + offset,
            ..seam
        }));
        Ok(())
    }

    /// Pixel `k`'s compounded series (the angles' summed), frame by frame.
    pub fn compound(&self, k: usize) -> Result<Vec<num_complex::Complex64>> {
        if k >= self.pixels.len() {
            return Err(invalid(
                "kept pixel",
                format!("{k} is not one of the {} kept", self.pixels.len()),
            ));
        }
        Ok((0..self.n_frames())
            .map(|t| compounded(&self.series, k, t))
            .collect())
    }

    /// Pixel `k`'s compounded frames `frames` as the filter of the run holding its first frame
    /// gave them: across the next [`Seam`], from its tail (as far as the tail reaches: past it,
    /// the later run's frames).
    pub fn compound_window(
        &self,
        k: usize,
        frames: std::ops::Range<usize>,
    ) -> Result<Vec<num_complex::Complex64>> {
        if k >= self.pixels.len() || frames.end > self.n_frames() || frames.start > frames.end {
            return Err(invalid(
                "kept window",
                format!(
                    "pixel {k} of {}, frames {frames:?} of {}",
                    self.pixels.len(),
                    self.n_frames()
                ),
            ));
        }
        let next_seam = self.seams.iter().find(|seam| seam.frame > frames.start);
        Ok(frames
            .map(|t| match next_seam {
                Some(seam) if t >= seam.frame && t - seam.frame < seam.tail_frames() => {
                    compounded(&seam.tail, k, t - seam.frame)
                }
                _ => compounded(&self.series, k, t),
            })
            .collect())
    }
}

/// Beamformed image series read a range of frames at a time: images formed elsewhere, too long
/// to hold whole, that a run processes in segments.
pub trait ImageFrames: Sync {
    /// The images' grid, steering angles, frame rate, speed of sound and demodulation frequency,
    /// without series.
    fn description(&self) -> AngleImages;
    /// Frames per series.
    fn n_frames(&self) -> usize;
    /// Frames `frames` of every series, each (nz, nx, frames.len()).
    fn read_frames(&self, frames: std::ops::Range<usize>) -> Result<AngleImages>;
}

impl ImageFrames for AngleImages {
    fn description(&self) -> AngleImages {
        self.with_series(Vec::new())
    }

    fn n_frames(&self) -> usize {
        AngleImages::n_frames(self)
    }

    fn read_frames(&self, frames: std::ops::Range<usize>) -> Result<AngleImages> {
        let total = AngleImages::n_frames(self);
        if frames.start >= frames.end || frames.end > total {
            return Err(invalid(
                "frames",
                format!("{frames:?} is not a range of the images' {total} frames"),
            ));
        }
        Ok(self.with_series(
            self.series
                .iter()
                .map(|s| s.slice(ndarray::s![.., .., frames.clone()]).to_owned())
                .collect(),
        ))
    }
}

impl Seam {
    /// Frames in the tail.
    fn tail_frames(&self) -> usize {
        self.tail.first().map_or(0, |s| s.ncols())
    }
}

/// Frame `t` of pixel `k` of per-angle (pixels, frames) series, the angles summed.
fn compounded(series: &[ndarray::Array2<Complex32>], k: usize, t: usize) -> num_complex::Complex64 {
    series
        .iter()
        .fold(num_complex::Complex64::new(0.0, 0.0), |acc, s| {
            let v = s[[k, t]];
            acc + num_complex::Complex64::new(v.re as f64, v.im as f64)
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two angles on a 2 × 3 grid, 5 frames: sample (iz, ix, t) of angle a is a + 10·iz + ix + i·t.
    fn images() -> AngleImages {
        let series = (0..2)
            .map(|a| {
                Array3::from_shape_fn((2, 3, 5), |(iz, ix, t)| {
                    Complex32::new((a + 10 * iz + ix) as f32, t as f32)
                })
            })
            .collect();
        AngleImages {
            grid: Grid::new(0.0, 2e-4, 0.0, 1e-4, 1e-4).unwrap(),
            angles: vec![-0.1, 0.1],
            frame_rate: 1000.0,
            sound_speed: 1540.0,
            demodulation_frequency: 5e6,
            coverage: None,
            series,
        }
    }

    #[test]
    fn kept_pixels_join_in_frame_order_and_compound_over_angles() {
        let images = images();
        let pixels = [(1, 2), (0, 1)];
        let mut kept = PixelSeries::of(&images, &pixels, 0..2).unwrap();
        kept.append(PixelSeries::of(&images, &pixels, 2..5).unwrap())
            .unwrap();
        assert_eq!(kept.series[1][[0, 4]], Complex32::new(13.0, 4.0));
        // Pixel (0, 1): angles 0 and 1 give 1 + i·t and 2 + i·t.
        let compound = kept.compound(1).unwrap();
        assert_eq!(compound[3], num_complex::Complex64::new(3.0, 6.0));
        assert!(PixelSeries::of(&images, &[(2, 0)], 0..5).is_err());
        assert!(PixelSeries::of(&images, &pixels, 0..6).is_err());
        let other = PixelSeries::of(&images, &[(0, 0)], 0..1).unwrap();
        assert!(kept.append(other).is_err());
        assert!(kept.compound(2).is_err());
    }

    /// Two segments filtered apart, cores 0..3 and 3..5 with 2 frames imaged after the first:
    /// a window starting in the first core reads the first segment's frames across the seam,
    /// as far as they reach, and a window starting at the seam reads the second's.
    #[test]
    fn windows_read_the_segment_holding_their_start() {
        let first = images();
        let mut second = images();
        for s in &mut second.series {
            s.mapv_inplace(|v| v * 10.0);
        }
        let pixels = [(1, 2), (0, 1)];
        let mut kept = PixelSeries::of_core(&first, &pixels, 0..3).unwrap();
        assert_eq!(kept.seams.len(), 1);
        // The second segment holds frames 3..5 of the recording as its own frames 3..5.
        kept.append(PixelSeries::of(&second, &pixels, 3..5).unwrap())
            .unwrap();
        assert_eq!(kept.n_frames(), 5);
        assert_eq!(kept.seams[0].frame, 3);
        // Pixel (0, 1) compounds to 3 + 2i·t in the first segment, ten times that in the second.
        let first_value = |t: usize| num_complex::Complex64::new(3.0, 2.0 * t as f64);
        let across = kept.compound_window(1, 1..5).unwrap();
        assert_eq!(across, (1..5).map(first_value).collect::<Vec<_>>());
        let after = kept.compound_window(1, 3..5).unwrap();
        assert_eq!(after, kept.compound(1).unwrap()[3..5].to_vec());
        assert_eq!(after[0], first_value(3) * 10.0);
        // Past the tail (here the first segment's frames 3 and 4 only), the later frames.
        let mut short = PixelSeries::of_core(&first, &pixels, 0..4).unwrap();
        short.seams[0]
            .tail
            .iter_mut()
            .for_each(|t| *t = t.slice(ndarray::s![.., ..0]).to_owned());
        short
            .append(PixelSeries::of(&second, &pixels, 4..5).unwrap())
            .unwrap();
        assert_eq!(
            short.compound_window(1, 2..5).unwrap()[2],
            first_value(4) * 10.0
        );
        assert!(kept.compound_window(1, 3..6).is_err());
        assert!(kept.compound_window(2, 0..1).is_err());
    }
}
