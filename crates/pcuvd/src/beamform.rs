//! Delay-and-sum beamforming of steered plane waves, in the IQ domain, batched over frames.
//!
//! For pixel (x, z), angle θ and element e the echo time is the shared convention
//! [`geometry::round_trip_delay`]; the baseband sample there is linearly interpolated and rotated by
//! exp(+2πi f_d τ) to restore the carrier phase. Receive apodisation: elements within the aperture
//! |x − x_e| ≤ z / (2 F#), weighted by a Hann (or flat) window across it.
//! Frames are the contiguous axis, so each delay and weight is computed once per pixel and element
//! and applied to the whole batch of frames.

use ndarray::{Array3, ArrayView3, Axis, s};
use num_complex::Complex32;
use rayon::prelude::*;

use crate::error::{Error, Result, invalid, require_positive};
use crate::geometry;
use crate::iq::IqChannels;
use crate::probe::Probe;

/// A rectangular pixel grid: lateral positions `x` and depths `z` (m), both increasing.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    /// Lateral pixel positions (m).
    pub x: Vec<f64>,
    /// Depth pixel positions (m).
    pub z: Vec<f64>,
}

impl Grid {
    /// A grid spanning [x_min, x_max] × [z_min, z_max] (m) with spacing `step` (m) on both axes.
    pub fn new(x_min: f64, x_max: f64, z_min: f64, z_max: f64, step: f64) -> Result<Grid> {
        require_positive("grid step", step)?;
        for (name, v) in [
            ("x_min", x_min),
            ("x_max", x_max),
            ("z_min", z_min),
            ("z_max", z_max),
        ] {
            if !v.is_finite() {
                return Err(invalid("grid", format!("{name} = {v} is not finite")));
            }
        }
        if x_max < x_min || z_max < z_min {
            return Err(invalid(
                "grid",
                format!("empty extent x [{x_min}, {x_max}] m, z [{z_min}, {z_max}] m"),
            ));
        }
        if z_min < 0.0 {
            return Err(invalid(
                "grid",
                format!("z_min = {z_min} m lies behind the probe face (z < 0)"),
            ));
        }
        let axis = |lo: f64, hi: f64| -> Vec<f64> {
            let n = ((hi - lo) / step + 1e-9).floor() as usize + 1;
            (0..n).map(|i| lo + i as f64 * step).collect()
        };
        let (x, z) = (axis(x_min, x_max), axis(z_min, z_max));
        if x.len() * z.len() > 50_000_000 {
            return Err(invalid(
                "grid",
                format!("{} × {} pixels is too many", z.len(), x.len()),
            ));
        }
        Ok(Grid { x, z })
    }

    /// (nz, nx).
    pub fn shape(&self) -> (usize, usize) {
        (self.z.len(), self.x.len())
    }
}

/// Receive apodisation window across the active aperture.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Apodization {
    /// Flat weights.
    Boxcar,
    /// Hann weights, zero at the aperture edge.
    Hann,
}

/// Delay-and-sum settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DasParams {
    /// Receive f-number F# = depth / aperture width.
    pub f_number: f64,
    /// Window across the receive aperture.
    pub apodization: Apodization,
    /// Speed of sound for the delays (m/s).
    pub sound_speed: f64,
}

impl DasParams {
    /// F# 1.5 with Hann apodisation at sound speed `c` (m/s).
    pub fn new(sound_speed: f64) -> Self {
        DasParams {
            f_number: 1.5,
            apodization: Apodization::Hann,
            sound_speed,
        }
    }
}

/// Beamforms one angle's baseband channel data (channels, samples, frames) onto `grid`:
/// complex image of shape (nz, nx, frames).
pub fn beamform(
    iq: &IqChannels,
    probe: &Probe,
    angle: f64,
    grid: &Grid,
    params: &DasParams,
) -> Result<Array3<Complex32>> {
    require_positive("f-number", params.f_number)?;
    require_positive("speed of sound", params.sound_speed)?;
    let (channels, n_samples, frames) = iq.data.dim();
    if channels != probe.n_elements {
        return Err(Error::Shape(format!(
            "{channels} channels for a probe of {} elements",
            probe.n_elements
        )));
    }
    let (nz, nx) = grid.shape();
    let mut image = Array3::<Complex32>::zeros((nx, nz, frames));
    let element_x = probe.element_x();
    let aperture = probe.aperture();
    let c = params.sound_speed;
    let fs = iq.sampling_frequency;
    let two_pi_fd = 2.0 * std::f64::consts::PI * iq.demod_frequency;
    let data = iq.data.view();
    image
        .axis_iter_mut(Axis(0))
        .into_par_iter()
        .zip(grid.x.par_iter())
        .for_each(|(mut column, &x)| {
            let column = column.as_slice_mut().expect("standard layout");
            let tx: Vec<f64> = grid
                .z
                .iter()
                .map(|&z| geometry::transmit_delay(x, z, angle, aperture, c))
                .collect();
            for (e, &xe) in element_x.iter().enumerate() {
                let channel = data.slice(s![e, .., ..]);
                let channel = channel.as_slice().expect("standard layout");
                for (iz, &z) in grid.z.iter().enumerate() {
                    let half_aperture = z / (2.0 * params.f_number);
                    let dx = (x - xe).abs();
                    if dx > half_aperture {
                        continue;
                    }
                    let apod = match params.apodization {
                        Apodization::Boxcar => 1.0,
                        Apodization::Hann => {
                            0.5 * (1.0 + (std::f64::consts::PI * dx / half_aperture).cos())
                        }
                    };
                    let tau = tx[iz] + geometry::receive_delay(x, z, xe, c);
                    let pos = (tau - iq.t0) * fs;
                    if !(pos >= 0.0 && pos < (n_samples - 1) as f64) {
                        continue;
                    }
                    let i0 = pos as usize;
                    let w = pos - i0 as f64;
                    let rot = Complex32::from_polar(apod as f32, (two_pi_fd * tau) as f32);
                    let c0 = rot * (1.0 - w) as f32;
                    let c1 = rot * w as f32;
                    let a = &channel[i0 * frames..(i0 + 1) * frames];
                    let b = &channel[(i0 + 1) * frames..(i0 + 2) * frames];
                    let acc = &mut column[iz * frames..(iz + 1) * frames];
                    accumulate(acc, c0, a, c1, b);
                }
            }
        });
    Ok(image
        .permuted_axes([1, 0, 2])
        .as_standard_layout()
        .to_owned())
}

/// acc += c0·a + c1·b over a batch of frames: the beamformer's inner loop.
#[inline]
fn accumulate(
    acc: &mut [Complex32],
    c0: Complex32,
    a: &[Complex32],
    c1: Complex32,
    b: &[Complex32],
) {
    for ((o, &u), &v) in acc.iter_mut().zip(a).zip(b) {
        *o += c0 * u + c1 * v;
    }
}

/// Coherent compounding: the sum of per-angle images (nz, nx, frames).
pub fn compound(images: &[Array3<Complex32>]) -> Result<Array3<Complex32>> {
    let first = images
        .first()
        .ok_or_else(|| invalid("compounding", "no images to compound"))?;
    let mut sum = first.clone();
    for img in &images[1..] {
        if img.dim() != sum.dim() {
            return Err(Error::Shape("per-angle images differ in shape".into()));
        }
        sum += img;
    }
    Ok(sum)
}

/// B-mode image in dB (0 dB at the brightest pixel) of the mean envelope over frames of `image` (nz, nx, frames).
pub fn bmode_db(image: ArrayView3<Complex32>) -> ndarray::Array2<f64> {
    let env = image.map_axis(Axis(2), |v| {
        v.iter().map(|c| c.norm() as f64).sum::<f64>() / v.len().max(1) as f64
    });
    let max = env.iter().cloned().fold(f64::MIN_POSITIVE, f64::max);
    env.mapv(|v| 20.0 * (v.max(max * 1e-12) / max).log10())
}
