//! Lag-1 autocorrelation Doppler (paper eq. 4–5): power, mean frequency, projection velocity.
//!
//! R = 1/(N−1) Σ_t S*(t)·S(t+1) over the frames of a (clutter-filtered) series. A scatterer moving
//! deeper lengthens the echo path, so the phase of R is negative; hence
//! V_θ = −c·f_frame/(4π f_0)·arg R, with f_frame = event PRF / n the per-angle frame rate. V_θ is
//! the projection of (Vx, Vz) on the angle's Doppler direction: Vx·sin θ + Vz·(cos θ + 1) = 2 V_θ.

use ndarray::{Array2, ArrayView3, Axis, Zip};
use num_complex::{Complex32, Complex64};

use crate::error::{Result, invalid, require_positive};

/// Power and lag-1 autocorrelation per pixel, shape (nz, nx).
#[derive(Debug, Clone, PartialEq)]
pub struct Autocorrelation {
    /// Mean |S|² over frames (power Doppler).
    pub power: Array2<f64>,
    /// Lag-1 autocorrelation R (eq. 4).
    pub r1: Array2<Complex64>,
}

/// Computes power and lag-1 autocorrelation of `series` (nz, nx, frames), each averaged over a
/// spatial box of `kernel` = (rows, cols) pixels (odd sizes; (1, 1) means no averaging).
pub fn autocorrelation(
    series: ArrayView3<Complex32>,
    kernel: (usize, usize),
) -> Result<Autocorrelation> {
    let (nz, nx, nf) = series.dim();
    if nf < 2 {
        return Err(invalid(
            "Doppler",
            format!("needs at least 2 frames, got {nf}"),
        ));
    }
    if kernel.0.is_multiple_of(2) || kernel.1.is_multiple_of(2) {
        return Err(invalid(
            "Doppler averaging kernel",
            format!("sizes must be odd, got {kernel:?}"),
        ));
    }
    let mut power = Array2::<f64>::zeros((nz, nx));
    let mut r1 = Array2::<Complex64>::zeros((nz, nx));
    Zip::from(&mut power)
        .and(&mut r1)
        .and(series.lanes(Axis(2)))
        .par_for_each(|p, r, s| {
            let mut acc_p = 0.0f64;
            let mut acc_r = Complex64::new(0.0, 0.0);
            for t in 0..nf {
                acc_p += s[t].norm_sqr() as f64;
                if t + 1 < nf {
                    let v = s[t].conj() * s[t + 1];
                    acc_r += Complex64::new(v.re as f64, v.im as f64);
                }
            }
            *p = acc_p / nf as f64;
            *r = acc_r / (nf - 1) as f64;
        });
    if kernel != (1, 1) {
        power = box_average(&power, kernel);
        r1 = box_average(&r1, kernel);
    }
    Ok(Autocorrelation { power, r1 })
}

fn box_average<T>(map: &Array2<T>, kernel: (usize, usize)) -> Array2<T>
where
    T: Copy + Default + std::ops::AddAssign + std::ops::Div<f64, Output = T>,
{
    let (nz, nx) = map.dim();
    let (hz, hx) = (kernel.0 / 2, kernel.1 / 2);
    Array2::from_shape_fn((nz, nx), |(z, x)| {
        let (z0, z1) = (z.saturating_sub(hz), (z + hz + 1).min(nz));
        let (x0, x1) = (x.saturating_sub(hx), (x + hx + 1).min(nx));
        let mut acc = T::default();
        for zz in z0..z1 {
            for xx in x0..x1 {
                acc += map[[zz, xx]];
            }
        }
        acc / ((z1 - z0) * (x1 - x0)) as f64
    })
}

/// Velocity scale of the phase of R: V = −scale · arg R, scale = c·f_frame/(4π f_0) (m/s per rad).
pub fn velocity_scale(sound_speed: f64, frame_rate: f64, center_frequency: f64) -> Result<f64> {
    require_positive("speed of sound", sound_speed)?;
    require_positive("frame rate", frame_rate)?;
    require_positive("centre frequency", center_frequency)?;
    Ok(sound_speed * frame_rate / (4.0 * std::f64::consts::PI * center_frequency))
}

/// Nyquist velocity (m/s) of the projection V_θ: c·f_frame/(4 f_0).
pub fn nyquist_velocity(sound_speed: f64, frame_rate: f64, center_frequency: f64) -> f64 {
    sound_speed * frame_rate / (4.0 * center_frequency)
}

/// Projection velocity V_θ (m/s) per pixel from R (eq. 5); positive means the echo path lengthens.
pub fn projection_velocity(
    r1: &Array2<Complex64>,
    sound_speed: f64,
    frame_rate: f64,
    center_frequency: f64,
) -> Result<Array2<f64>> {
    let scale = velocity_scale(sound_speed, frame_rate, center_frequency)?;
    Ok(r1.mapv(|r| {
        if r.norm() > 0.0 {
            -scale * r.arg()
        } else {
            0.0
        }
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array3;

    #[test]
    fn phase_ramp_gives_known_velocity() {
        let (c, fr, f0) = (1540.0, 1800.0, 15.625e6);
        let v_true = 0.01; // m/s, path lengthening
        let dphi = -v_true / velocity_scale(c, fr, f0).unwrap();
        let series = Array3::from_shape_fn((3, 4, 50), |(_, _, t)| {
            Complex32::from_polar(2.0, (dphi * t as f64) as f32)
        });
        let ac = autocorrelation(series.view(), (1, 1)).unwrap();
        let v = projection_velocity(&ac.r1, c, fr, f0).unwrap();
        assert!(v.iter().all(|&x| (x - v_true).abs() < 1e-6), "{v:?}");
        assert!(ac.power.iter().all(|&p| (p - 4.0).abs() < 1e-5));
        assert!(v_true < nyquist_velocity(c, fr, f0));
    }

    #[test]
    fn even_kernel_is_rejected() {
        let series = Array3::<Complex32>::zeros((3, 3, 4));
        assert!(autocorrelation(series.view(), (2, 1)).is_err());
        assert!(autocorrelation(Array3::<Complex32>::zeros((3, 3, 1)).view(), (1, 1)).is_err());
    }
}
