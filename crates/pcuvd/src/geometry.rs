//! The time-of-flight convention, written once and shared by the simulator and the beamformer.
//!
//! Geometry: x lateral (increasing with element index), z depth (positive into the medium), origin at
//! the centre of the array face. A plane wave steered by θ travels along (sin θ, cos θ); θ > 0 tilts
//! toward +x. Time zero of a transmit is the instant its *first* element fires: for θ > 0 the element
//! at the smallest x, for θ < 0 the one at the largest x. Each element i then fires at
//! (x_i − x_ref)·sin θ / c ≥ 0. A record's time origin `t0` is the time of its first sample after
//! that instant (MUST's convention).

/// Time (s) from the firing of the first element of a plane wave steered by `angle` (rad), emitted
/// by an array spanning `aperture` = (x_min, x_max) (m), until its wavefront reaches (x, z) (m).
#[inline]
pub fn transmit_delay(x: f64, z: f64, angle: f64, aperture: (f64, f64), c: f64) -> f64 {
    let x_ref = if angle >= 0.0 { aperture.0 } else { aperture.1 };
    ((x - x_ref) * angle.sin() + z * angle.cos()) / c
}

/// Firing delay (s) of an element at lateral position `element_x` (m) for a plane wave steered by `angle`.
#[inline]
pub fn element_firing_delay(element_x: f64, angle: f64, aperture: (f64, f64), c: f64) -> f64 {
    transmit_delay(element_x, 0.0, angle, aperture, c)
}

/// True when (x, z) (m) lies in the geometric shadow-free beam of a plane wave steered by `angle`
/// (rad) from an array spanning `aperture` (m): the ray along (sin θ, cos θ) through (x, z) starts
/// on the array face. Outside it only the edge wave arrives, and that angle's Doppler there is
/// noise or leakage from elsewhere.
#[inline]
pub fn insonified(x: f64, z: f64, angle: f64, aperture: (f64, f64)) -> bool {
    let foot = x - z * angle.tan();
    foot >= aperture.0 && foot <= aperture.1
}

/// Time (s) for an echo to travel from (x, z) back to the element at `element_x` (m).
#[inline]
pub fn receive_delay(x: f64, z: f64, element_x: f64, c: f64) -> f64 {
    ((x - element_x).powi(2) + z * z).sqrt() / c
}

/// Round-trip time (s): transmit by a plane wave steered by `angle`, receive on the element at `element_x`.
#[inline]
pub fn round_trip_delay(
    x: f64,
    z: f64,
    angle: f64,
    element_x: f64,
    aperture: (f64, f64),
    c: f64,
) -> f64 {
    transmit_delay(x, z, angle, aperture, c) + receive_delay(x, z, element_x, c)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn firing_delays_are_non_negative_and_zero_at_first_element() {
        let ap = (-6.35e-3, 6.35e-3);
        for &a in &[-0.26, -0.1, 0.0, 0.1, 0.26] {
            let xs: Vec<f64> = (0..128).map(|i| ap.0 + i as f64 * 0.1e-3).collect();
            let d: Vec<f64> = xs
                .iter()
                .map(|&x| element_firing_delay(x, a, ap, 1540.0))
                .collect();
            let min = d.iter().cloned().fold(f64::INFINITY, f64::min);
            assert!(min.abs() < 1e-15, "angle {a}: min delay {min}");
            assert!(d.iter().all(|&v| v >= -1e-15));
        }
    }

    #[test]
    fn wavefront_is_plane_with_positive_tilt_toward_plus_x() {
        // Along the propagation direction (sin θ, cos θ), the delay grows by distance / c.
        let (a, c, ap) = (0.2_f64, 1540.0, (-5e-3, 5e-3));
        let t1 = transmit_delay(0.0, 10e-3, a, ap, c);
        let t2 = transmit_delay(1e-3 * a.sin(), 10e-3 + 1e-3 * a.cos(), a, ap, c);
        assert!((t2 - t1 - 1e-3 / c).abs() < 1e-15);
        // Across it, no change.
        let t3 = transmit_delay(1e-3 * a.cos(), 10e-3 - 1e-3 * a.sin(), a, ap, c);
        assert!((t3 - t1).abs() < 1e-15);
    }

    #[test]
    fn plane_wave_reaches_the_parallelogram_under_the_array() {
        let ap = (-6.35e-3, 6.35e-3);
        let a = 15f64.to_radians();
        // Straight down: the band under the array, at any depth.
        assert!(insonified(6.3e-3, 20e-3, 0.0, ap));
        assert!(!insonified(6.4e-3, 1e-3, 0.0, ap));
        // Tilted toward +x by 15°: at 8.5 mm depth the beam spans x ∈ [−6.35, 6.35] + 8.5·tan 15°
        // = [−4.07, 8.63] mm, so x = 5 mm is reached by +15° and missed by −15°.
        let shift = 8.5e-3 * a.tan();
        assert!(insonified(5e-3, 8.5e-3, a, ap));
        assert!(!insonified(5e-3, 8.5e-3, -a, ap));
        assert!(insonified(ap.1 - shift - 1e-6, 8.5e-3, -a, ap));
        assert!(!insonified(ap.1 - shift + 1e-6, 8.5e-3, -a, ap));
        assert!(!insonified(ap.0 + shift - 1e-6, 8.5e-3, a, ap));
    }
}
