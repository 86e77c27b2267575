//! The per-angle maps that the vector stage reads together: each angle's projection velocity,
//! the lateral weight its row of the vector model takes, and its Nyquist velocity. Three arrays
//! of one shape and one unit that would otherwise travel as interchangeable arguments.

use ndarray::ArrayView3;

use crate::core::error::{Error, Result};

/// Per-angle projection maps (each angles × nz × nx) with the steering angles they belong to.
#[derive(Debug, Clone, Copy)]
pub struct Projections<'a> {
    /// Steering angles (rad), one per map.
    pub angles: &'a [f64],
    /// Projection velocities V_θ (m/s); NaN where an angle's plane wave does not reach a pixel.
    pub velocities: ArrayView3<'a, f64>,
    /// Measured lateral weights of each projection in the vector model (Loupas), or `None`
    /// for the model's sin θ (Kasai); see [`crate::estimate::vector::vector_velocity_measured`].
    pub lateral: Option<ArrayView3<'a, f64>>,
    /// Each projection's Nyquist velocity at each pixel (m/s): the interval dealiasing unwraps by.
    pub nyquist: ArrayView3<'a, f64>,
}

impl<'a> Projections<'a> {
    /// The maps of `angles`, checked to share one shape (angles × nz × nx).
    pub fn new(
        angles: &'a [f64],
        velocities: ArrayView3<'a, f64>,
        lateral: Option<ArrayView3<'a, f64>>,
        nyquist: ArrayView3<'a, f64>,
    ) -> Result<Self> {
        let dim = velocities.dim();
        if angles.len() != dim.0 {
            return Err(Error::Shape(format!(
                "{} angles for projections {dim:?}",
                angles.len()
            )));
        }
        if nyquist.dim() != dim {
            return Err(Error::Shape(format!(
                "Nyquist velocities {:?} for projections {dim:?}",
                nyquist.dim()
            )));
        }
        if let Some(lateral) = lateral
            && lateral.dim() != dim
        {
            return Err(Error::Shape(format!(
                "lateral weights {:?} for projections {dim:?}",
                lateral.dim()
            )));
        }
        Ok(Projections {
            angles,
            velocities,
            lateral,
            nyquist,
        })
    }

    /// (angles, nz, nx).
    pub fn dim(&self) -> (usize, usize, usize) {
        self.velocities.dim()
    }
}
