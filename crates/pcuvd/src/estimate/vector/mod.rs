//! Vector velocity from per-angle projections (paper eq. 6–15).
//!
//! Model: Vx·sin θ_i + Vz·(cos θ_i + 1) = 2·V_θi (transmit tilted by θ_i, receive straight), i.e.
//! A·v = 2·V_θ with A = [sin θ_i, cos θ_i + 1]. Least squares is the UVD baseline; PC-UVD solves
//! the weighted problem (eq. 9) with iteratively reweighted residuals: weights start at 1/n,
//! w_i = 1/(|r_i| + λ) with r_i in mm/s (eq. 11–12), normalised to sum 1, until max|Δw| < ε
//! (eq. 13) or an iteration cap.

use ndarray::{Array2, Array3, ArrayView3, Axis, Zip};
use rayon::prelude::*;

use crate::core::error::{Error, Result, invalid};

mod lanes;
use lanes::PixelLanes;

/// Iteratively reweighted least-squares settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IrlsParams {
    /// Regularisation λ of the weights 1/(|r| + λ), in mm/s (paper: 0.01).
    pub lambda_mm_s: f64,
    /// Convergence threshold ε on the largest weight change.
    pub epsilon: f64,
    /// Iteration cap.
    pub max_iterations: usize,
}

impl IrlsParams {
    /// Refuses a λ or ε that is not finite and positive, and an iteration cap of 0.
    pub fn validate(&self) -> Result<()> {
        for (name, value) in [("IRLS λ", self.lambda_mm_s), ("IRLS ε", self.epsilon)] {
            if !(value.is_finite() && value > 0.0) {
                return Err(invalid(
                    name,
                    format!("must be finite and > 0, got {value}"),
                ));
            }
        }
        if self.max_iterations == 0 {
            return Err(invalid("IRLS iteration cap", "must be at least 1"));
        }
        Ok(())
    }
}

impl Default for IrlsParams {
    fn default() -> Self {
        IrlsParams {
            lambda_mm_s: 0.01,
            epsilon: 1e-4,
            max_iterations: 50,
        }
    }
}

/// Which solver turns projections into a vector.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Estimator {
    /// Ordinary least squares (conventional UVD).
    LeastSquares,
    /// Iteratively reweighted weighted least squares (PC-UVD).
    Irls(IrlsParams),
}

/// A 2-D velocity field on the image grid, shape (nz, nx), m/s.
#[derive(Debug, Clone, PartialEq)]
pub struct VectorField {
    /// Lateral velocity (m/s), positive toward +x.
    pub vx: Array2<f64>,
    /// Axial velocity (m/s), positive moving deeper.
    pub vz: Array2<f64>,
}

impl VectorField {
    /// Speed |V| = √(Vx² + Vz²) (m/s), eq. 14.
    pub fn speed(&self) -> Array2<f64> {
        Zip::from(&self.vx)
            .and(&self.vz)
            .map_collect(|&x, &z| x.hypot(z))
    }

    /// Flow direction atan2(Vx, Vz) (rad): 0 = straight down (deeper), +π/2 = toward +x; eq. 15.
    pub fn direction(&self) -> Array2<f64> {
        Zip::from(&self.vx)
            .and(&self.vz)
            .map_collect(|&x, &z| x.atan2(z))
    }
}

/// The paper's projection geometry, the one place it is written: a plane wave steered by θ (rad)
/// and received straight sees V_θ = (Vx·sin θ + Vz·(1 + cos θ))/2. Returns (sin θ, 1 + cos θ).
pub fn projection_weights(theta: f64) -> (f64, f64) {
    (theta.sin(), theta.cos() + 1.0)
}

/// Weighted least-squares solution (Vx, Vz) of rows·v = 2·V_θ with weights `w`; each row is an
/// angle's (lateral, axial) weight, (sin θ, 1 + cos θ) in the paper's model.
fn weighted_solve(rows: &[(f64, f64)], v_theta: &[f64], w: &[f64]) -> Option<(f64, f64)> {
    let (mut a11, mut a12, mut a22, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for ((&(s, c), &v), &wi) in rows.iter().zip(v_theta).zip(w) {
        a11 += wi * s * s;
        a12 += wi * s * c;
        a22 += wi * c * c;
        b1 += wi * s * 2.0 * v;
        b2 += wi * c * 2.0 * v;
    }
    let det = a11 * a22 - a12 * a12;
    if det.abs() <= 1e-12 * (a11 * a22).abs().max(f64::MIN_POSITIVE) {
        return None;
    }
    Some(((a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det))
}

/// Solves one pixel: (Vx, Vz) in m/s from projections `v_theta` (m/s) at `angles` (rad).
pub fn solve_pixel(angles: &[f64], v_theta: &[f64], estimator: &Estimator) -> (f64, f64) {
    let rows: Vec<(f64, f64)> = angles.iter().map(|&a| projection_weights(a)).collect();
    solve_rows(&rows, v_theta, estimator)
}

/// Solves one pixel: (Vx, Vz) in m/s from projections `v_theta` (m/s) whose model rows are
/// `rows` = (lateral, axial) weights per angle: lateral·Vx + axial·Vz = 2·V_θ. A projection that
/// is not finite is left out; fewer than two left give NaN.
pub fn solve_rows(rows: &[(f64, f64)], v_theta: &[f64], estimator: &Estimator) -> (f64, f64) {
    if v_theta.iter().any(|v| !v.is_finite()) {
        let (kept_rows, kept): (Vec<(f64, f64)>, Vec<f64>) = rows
            .iter()
            .zip(v_theta)
            .filter(|(_, v)| v.is_finite())
            .map(|(&r, &v)| (r, v))
            .unzip();
        if kept.len() < 2 {
            return (f64::NAN, f64::NAN);
        }
        return solve_rows(&kept_rows, &kept, estimator);
    }
    let n = rows.len();
    let mut w = vec![1.0 / n as f64; n];
    let Some(mut v) = weighted_solve(rows, v_theta, &w) else {
        return (f64::NAN, f64::NAN);
    };
    let Estimator::Irls(p) = estimator else {
        return v;
    };
    // The weights of the next round are formed beside the current ones, then swapped in.
    let mut new_w = vec![0.0; n];
    for _ in 0..p.max_iterations {
        for ((next, &(s, c)), &vt) in new_w.iter_mut().zip(rows).zip(v_theta) {
            let residual_mm_s = (2.0 * vt - v.1 * c - v.0 * s) * 1e3;
            *next = 1.0 / (residual_mm_s.abs() + p.lambda_mm_s);
        }
        let total: f64 = new_w.iter().sum();
        new_w.iter_mut().for_each(|x| *x /= total);
        let change = new_w
            .iter()
            .zip(&w)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        std::mem::swap(&mut w, &mut new_w);
        match weighted_solve(rows, v_theta, &w) {
            Some(next) => v = next,
            None => break,
        }
        if change < p.epsilon {
            break;
        }
    }
    v
}

/// Marks as missing (NaN) the projections of `v_theta` (angles, nz, nx) whose angle does not
/// reach the pixel by `coverage` (same shape, true = reached); [`solve_pixel`] leaves them out.
pub fn drop_unreached(v_theta: &mut Array3<f64>, coverage: ArrayView3<bool>) {
    Zip::from(v_theta).and(coverage).for_each(|v, &reached| {
        if !reached {
            *v = f64::NAN;
        }
    });
}

/// Vector field from projection maps `v_theta` of shape (angles, nz, nx) (m/s) at `angles` (rad).
pub fn vector_velocity(
    angles: &[f64],
    v_theta: ArrayView3<f64>,
    estimator: &Estimator,
) -> Result<VectorField> {
    field(angles, v_theta, None, estimator)
}

/// As [`vector_velocity`], each projection with its own lateral weight `lateral` (angles, nz,
/// nx) in place of sin θ (the model row of angle k at a pixel is (lateral[k], 1 + cos θ_k)): the
/// weights [`crate::estimate::doppler::doppler_maps`] measures (Loupas), which follow the receive aperture
/// and the speckle. A weight that is not finite falls back to sin θ.
pub fn vector_velocity_measured(
    angles: &[f64],
    v_theta: ArrayView3<f64>,
    lateral: ArrayView3<f64>,
    estimator: &Estimator,
) -> Result<VectorField> {
    if lateral.dim() != v_theta.dim() {
        return Err(Error::Shape(format!(
            "lateral weights {:?} for projections {:?}",
            lateral.dim(),
            v_theta.dim()
        )));
    }
    field(angles, v_theta, Some(lateral), estimator)
}

/// [`vector_velocity_measured`] with the lateral weights `lateral` when given, else
/// [`vector_velocity`] (the model's sin θ).
pub fn vector_velocity_with(
    angles: &[f64],
    v_theta: ArrayView3<f64>,
    lateral: Option<ArrayView3<f64>>,
    estimator: &Estimator,
) -> Result<VectorField> {
    match lateral {
        Some(lateral) => vector_velocity_measured(angles, v_theta, lateral, estimator),
        None => vector_velocity(angles, v_theta, estimator),
    }
}

fn field(
    angles: &[f64],
    v_theta: ArrayView3<f64>,
    lateral: Option<ArrayView3<f64>>,
    estimator: &Estimator,
) -> Result<VectorField> {
    let (n, nz, nx) = v_theta.dim();
    if n != angles.len() {
        return Err(Error::Shape(format!(
            "{n} projection maps for {} angles",
            angles.len()
        )));
    }
    if n < 2 {
        return Err(invalid("angles", "vector Doppler needs at least 2 angles"));
    }
    if let Estimator::Irls(p) = estimator {
        p.validate()?;
    }
    let nominal: Vec<(f64, f64)> = angles.iter().map(|&a| projection_weights(a)).collect();
    let mut vx = Array2::<f64>::zeros((nz, nx));
    let mut vz = Array2::<f64>::zeros((nz, nx));
    // A row of pixels per task, its pixels through the lanes of one `PixelLanes`.
    vx.axis_iter_mut(Axis(0))
        .into_par_iter()
        .zip(vz.axis_iter_mut(Axis(0)))
        .enumerate()
        .for_each(|(iz, (mut vx_row, mut vz_row))| {
            let mut lanes = PixelLanes::new(&nominal);
            let load = &mut |ix: usize, l: usize, lanes: &mut PixelLanes| {
                let pixel = (nominal.iter().enumerate()).map(|(k, &(s, _))| {
                    // The measured lateral weight where it is finite, else sin θ.
                    let m = lateral.map_or(s, |lat| lat[[k, iz, ix]]);
                    (if m.is_finite() { m } else { s }, v_theta[[k, iz, ix]])
                });
                lanes.set(l, pixel);
            };
            let done = &mut |ix: usize, x: f64, z: f64| (vx_row[ix], vz_row[ix]) = (x, z);
            lanes.solve_each(estimator, nx, load, done);
        });
    Ok(VectorField { vx, vz })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The paper's 8 angles, −15° to 15° (rad).
    pub(super) fn paper_angles() -> Vec<f64> {
        (0..8)
            .map(|i| (-15.0 + 30.0 * i as f64 / 7.0_f64).to_radians())
            .collect()
    }

    fn projections(angles: &[f64], vx: f64, vz: f64) -> Vec<f64> {
        angles
            .iter()
            .map(|&t| {
                let (s, c) = projection_weights(t);
                0.5 * (vx * s + vz * c)
            })
            .collect()
    }

    #[test]
    fn exact_on_noiseless_projections() {
        let angles = paper_angles();
        for &(vx, vz) in &[(0.02, 0.0), (-0.013, 0.004), (0.0, -0.025), (0.007, 0.019)] {
            solves_exactly(&angles, &projections(&angles, vx, vz), (vx, vz));
        }
    }

    /// Both estimators give back (vx, vz) (m/s) from `p` within 1e-9 m/s.
    fn solves_exactly(angles: &[f64], p: &[f64], (vx, vz): (f64, f64)) {
        for est in [
            Estimator::LeastSquares,
            Estimator::Irls(IrlsParams::default()),
        ] {
            let (ex, ez) = solve_pixel(angles, p, &est);
            assert!(
                (ex - vx).abs() < 1e-9 && (ez - vz).abs() < 1e-9,
                "{est:?}: {ex} {ez}"
            );
        }
    }

    #[test]
    fn angles_without_a_projection_are_left_out() {
        // Projections that are NaN (the angle's plane wave misses the pixel) are dropped: the
        // rest still solve exactly; fewer than two left give no vector.
        let angles = paper_angles();
        let (vx, vz) = (-0.017, 0.009);
        let mut p = projections(&angles, vx, vz);
        p[0] = f64::NAN;
        p[1] = f64::NAN;
        solves_exactly(&angles, &p, (vx, vz));
        let mut lone = vec![f64::NAN; angles.len()];
        lone[3] = p[3];
        let (ex, ez) = solve_pixel(&angles, &lone, &Estimator::LeastSquares);
        assert!(ex.is_nan() && ez.is_nan());
    }

    #[test]
    fn irls_settings_must_be_finite_and_positive() {
        assert!(IrlsParams::default().validate().is_ok());
        for bad in [
            IrlsParams {
                lambda_mm_s: f64::INFINITY,
                ..Default::default()
            },
            IrlsParams {
                lambda_mm_s: -1.0,
                ..Default::default()
            },
            IrlsParams {
                epsilon: 0.0,
                ..Default::default()
            },
            IrlsParams {
                epsilon: f64::NAN,
                ..Default::default()
            },
            IrlsParams {
                max_iterations: 0,
                ..Default::default()
            },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }

    #[test]
    fn irls_rejects_one_corrupted_angle() {
        let angles = paper_angles();
        let (vx, vz) = (0.02, 0.01);
        let mut p = projections(&angles, vx, vz);
        p[2] += 0.02; // one angle off by 20 mm/s
        let truth = vx.hypot(vz);
        let (lx, lz) = solve_pixel(&angles, &p, &Estimator::LeastSquares);
        let (ix, iz) = solve_pixel(&angles, &p, &Estimator::Irls(IrlsParams::default()));
        let ls_err = (lx - vx).hypot(lz - vz) / truth;
        let irls_err = (ix - vx).hypot(iz - vz) / truth;
        assert!(irls_err < 0.05, "IRLS error {irls_err}");
        assert!(ls_err > 0.05, "LS error {ls_err} should exceed 5 %");
    }

    /// The field's pixels, solved side by side in lanes that take the next pixel as theirs
    /// finish, are each pixel's [`solve_rows`] to the bit: noisy projections (so IRLS takes a
    /// different number of rounds per pixel), rows whose width is not a multiple of eight,
    /// missing projections and lateral weights, a pixel whose system is singular, both
    /// estimators and iteration caps that stop rounds early.
    #[test]
    fn field_solves_each_pixel_as_alone_to_the_bit() {
        let angles = paper_angles();
        let (nz, nx) = (5, 19);
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let mut uniform = move || rng.random_range(0.0..1.0);
        let mut p = Array3::from_shape_fn((8, nz, nx), |_| 0.0);
        let mut lateral = Array3::from_shape_fn((8, nz, nx), |_| 0.0);
        for iz in 0..nz {
            for ix in 0..nx {
                let (vx, vz) = (0.04 * uniform() - 0.02, 0.04 * uniform() - 0.02);
                for (k, &t) in angles.iter().enumerate() {
                    let (s, c) = projection_weights(t);
                    let s = s * (0.8 + 0.4 * uniform());
                    lateral[[k, iz, ix]] = s;
                    p[[k, iz, ix]] = 0.5 * (vx * s + vz * c) + 0.004 * (uniform() - 0.5);
                }
            }
        }
        p[[2, 1, 3]] = f64::NAN;
        p[[0, 1, 3]] = f64::INFINITY;
        for k in 1..8 {
            p[[k, 2, 17]] = f64::NAN;
        }
        lateral[[4, 3, 9]] = f64::NAN;
        // Every lateral weight zero: Vx cannot be told, the system is singular.
        for k in 0..8 {
            lateral[[k, 4, 0]] = 0.0;
        }
        let irls = |max_iterations, epsilon| {
            Estimator::Irls(IrlsParams {
                max_iterations,
                epsilon,
                ..Default::default()
            })
        };
        for est in [
            Estimator::LeastSquares,
            irls(50, 1e-4),
            irls(3, 1e-4),
            irls(50, 1e-9),
        ] {
            for measured in [None, Some(lateral.view())] {
                let field = vector_velocity_with(&angles, p.view(), measured, &est).unwrap();
                for iz in 0..nz {
                    for ix in 0..nx {
                        let rows: Vec<(f64, f64)> = (angles.iter().enumerate())
                            .map(|(k, &t)| {
                                let (s, c) = projection_weights(t);
                                let m = measured.map_or(s, |l| l[[k, iz, ix]]);
                                (if m.is_finite() { m } else { s }, c)
                            })
                            .collect();
                        let alone: Vec<f64> = (0..8).map(|k| p[[k, iz, ix]]).collect();
                        let (x, z) = solve_rows(&rows, &alone, &est);
                        let got = (field.vx[[iz, ix]], field.vz[[iz, ix]]);
                        assert!(
                            x.to_bits() == got.0.to_bits() && z.to_bits() == got.1.to_bits(),
                            "{est:?}, measured {}: pixel ({iz}, {ix}) {got:?} against {:?}",
                            measured.is_some(),
                            (x, z)
                        );
                    }
                }
                assert!(field.vx[[4, 0]].is_nan() == measured.is_some());
                assert!(field.vx[[2, 17]].is_nan());
            }
        }
    }

    #[test]
    fn field_shapes_and_signs() {
        let angles = paper_angles();
        let p = projections(&angles, -0.01, 0.02);
        let maps = ndarray::Array3::from_shape_fn((8, 2, 3), |(a, _, _)| p[a]);
        let f = vector_velocity(&angles, maps.view(), &Estimator::LeastSquares).unwrap();
        assert!(f.vx.iter().all(|&v| (v + 0.01).abs() < 1e-12));
        assert!(f.vz.iter().all(|&v| (v - 0.02).abs() < 1e-12));
        assert!(f.direction().iter().all(|&d| d < 0.0));
        assert!(vector_velocity(&angles[..3], maps.view(), &Estimator::LeastSquares).is_err());
    }
}
