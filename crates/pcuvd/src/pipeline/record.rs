//! What a recording's samples reach: its recorded depth, the default grid, and each angle's
//! coverage of the grid.

use ndarray::Array3;

use crate::acquisition::channel::{Acquisition, ChannelData};

use crate::core::error::{Result, invalid};
use crate::core::grid::Grid;
/// Per steering angle, the pixels of `grid` that its plane wave reaches and whose echo a record of
/// `n_samples` samples holds (angles, nz, nx):
/// - the ray back along the steering direction lands on the array face
///   ([`geometry::insonified`](crate::core::geometry::insonified)). Near the lateral edges, deeper than
///   a few mm, the widest angles miss a pixel (|x| > half-aperture − z·tan θ_max); their Doppler
///   there is noise or edge-wave leakage, and fitting it biased the lateral velocity (the spiral's
///   UVD Vx RMSE was 13.6 mm/s with it, 4.1 without);
/// - the echo's shortest way back (to the element nearest the pixel) arrives before the record
///   ends. A steered wave reaches a pixel later than the unsteered one by (x − x_first)·sin θ / c,
///   so the deepest rows of a grid that reaches [`recorded_depth_of`] lie beyond the record for
///   the steep angles: their images there are exactly zero, and read as a projection of 0 m/s
///   (on the default grid of the `rat-network` preset, 3,903 pixels of the deepest 1.2 mm had
///   such angles in their vector fit). Decoding advances slot k's record by the slot's start
///   ([`slot_offset`](crate::acquisition::sequence::Sequence::slot_offset)) and fills its tail
///   with zeros, so angle k's record ends that much earlier: on a coded recording the later
///   slots lose the deepest rows (on the coded `rat-brain-small`, slots 4–7 read exactly 0 at
///   12 mm).
pub fn angle_coverage(acq: &Acquisition, n_samples: usize, grid: &Grid) -> Array3<bool> {
    let xs = acq.probe.element_x();
    let aperture = (
        xs.first().copied().unwrap_or(0.0),
        xs.last().copied().unwrap_or(0.0),
    );
    let c = acq.sound_speed;
    let record_end = acq.t0 + (n_samples as f64 - 1.0) / acq.sampling_frequency;
    let angles = &acq.sequence.angles;
    let (nz, nx) = grid.shape();
    Array3::from_shape_fn((angles.len(), nz, nx), |(k, iz, ix)| {
        let (x, z) = (grid.x[ix], grid.z[iz]);
        let nearest = x.clamp(aperture.0, aperture.1);
        let earliest =
            crate::core::geometry::round_trip_delay(x, z, angles[k], nearest, aperture, c);
        crate::core::geometry::insonified(x, z, angles[k], aperture)
            && earliest <= record_end - acq.sequence.slot_offset(k)
    })
}

/// Checks, before any work, that every pulse slot of `acq` starts within a record of `n_samples`
/// samples: decoding advances slot k's record by its start, so a slot that starts after the record
/// ends has no echo in it (and would ask for an FFT longer than the record).
pub fn check_record(acq: &Acquisition, n_samples: usize) -> Result<()> {
    let last = acq.sequence.last_slot_start();
    let record = n_samples as f64 / acq.sampling_frequency;
    if last >= record {
        return Err(invalid(
            "slot delays",
            format!(
                "the last pulse slot starts {:.3} µs into the event, after the {:.3} µs record \
                 ({n_samples} samples at {:.3} MHz) ends: its echoes are not in the recording",
                last * 1e6,
                record * 1e6,
                acq.sampling_frequency * 1e-6
            ),
        ));
    }
    Ok(())
}

/// Deepest depth (m) whose straight-down echo lies inside the record.
pub fn recorded_depth(data: &ChannelData) -> f64 {
    recorded_depth_of(&data.acquisition, data.samples.dim().2)
}

/// Deepest depth (m) whose straight-down echo lies inside a record of `n_samples` samples.
pub fn recorded_depth_of(acq: &Acquisition, n_samples: usize) -> f64 {
    let t_end = acq.t0 + (n_samples as f64 - 1.0) / acq.sampling_frequency;
    (0.5 * t_end * acq.sound_speed).max(0.0)
}

/// The default grid: the array's lateral extent, from just below the first recorded depth to the
/// last, with a step of half a wavelength (rounded to 0.01 mm), capped near 400 × 400 pixels.
pub fn default_grid(data: &ChannelData) -> Result<Grid> {
    default_grid_for(&data.acquisition, data.samples.dim().2)
}

/// [`default_grid`] of a recording acquired as `acq` with traces of `n_samples` samples.
pub fn default_grid_for(acq: &Acquisition, n_samples: usize) -> Result<Grid> {
    let (x0, x1) = acq.probe.aperture();
    let z_first = (0.5 * acq.t0 * acq.sound_speed).max(0.0);
    let z0 = z_first.max(1e-3);
    let z1 = recorded_depth_of(acq, n_samples);
    if z1 <= z0 {
        return Err(invalid(
            "grid",
            "the record is too short to cover any depth beyond 1 mm",
        ));
    }
    let mut step = (acq.probe.wavelength(acq.sound_speed) / 2.0 * 1e5).round() / 1e5;
    let extent = (x1 - x0).max(z1 - z0);
    step = step.max(extent / 400.0).max(1e-5);
    Grid::new(x0, x1, z0, z1, step)
}

/// The finest step, in wavelengths, of a grid that spans less than a wavelength each way: a
/// hundredth, 25 times finer than the quarter wavelength that samples the speckle. Such a grid
/// was given in metres where millimetres are asked for (a 12 mm image in 0.1 mm steps becomes
/// 12 µm in 0.1 µm steps); a fine grid over a real image, or a coarse one over a few pixels,
/// is kept.
pub const MIN_GRID_STEP_WAVELENGTHS: f64 = 0.01;

/// Checks, before any work, that `grid` starts above the deepest depth a record of `n_samples`
/// samples acquired as `acq` holds ([`recorded_depth_of`]), and that it is not a grid in
/// metres read as millimetres ([`MIN_GRID_STEP_WAVELENGTHS`]).
pub fn check_grid_depth(acq: &Acquisition, n_samples: usize, grid: &Grid) -> Result<()> {
    check_depth(recorded_depth_of(acq, n_samples), grid)?;
    let wavelength = acq.probe.wavelength(acq.sound_speed);
    let span = |axis: &[f64]| axis.first().zip(axis.last()).map_or(0.0, |(f, l)| l - f);
    let (width, depth) = (span(&grid.x), span(&grid.z));
    let step = grid.step().min(grid.axial_step());
    if width.max(depth) < wavelength && step < MIN_GRID_STEP_WAVELENGTHS * wavelength {
        return Err(invalid(
            "grid",
            format!(
                "it spans {:.3e} × {:.3e} mm in steps of {:.3e} mm, under a wavelength ({:.3} \
                 mm) in steps under a hundredth of one: give it in millimetres",
                width * 1e3,
                depth * 1e3,
                step * 1e3,
                wavelength * 1e3
            ),
        ));
    }
    Ok(())
}

/// A grid deeper than the record can say nothing: refuse it rather than return zeros.
pub(super) fn check_depth(deepest: f64, grid: &Grid) -> Result<()> {
    let z_min = grid.z.first().copied().unwrap_or(0.0);
    if z_min >= deepest {
        return Err(invalid(
            "grid",
            format!(
                "the grid starts at z = {:.2} mm, below the deepest recorded depth {:.2} mm",
                z_min * 1e3,
                deepest * 1e3
            ),
        ));
    }
    Ok(())
}
