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
    receive_path(x, z, element_x) / c
}

/// Distance (m) from (x, z) back to the element at `element_x` (m): [`receive_delay`] times
/// the speed of sound, for loops that multiply by a slowness computed once.
#[inline]
pub fn receive_path(x: f64, z: f64, element_x: f64) -> f64 {
    ((x - element_x).powi(2) + z * z).sqrt()
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

/// A plane wave recognised in per-element transmit delays ([`plane_wave_from_delays`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneWave {
    /// Steering angle (rad).
    pub angle: f64,
    /// When its first element fires (s), on the clock of the delays: the slot's start.
    pub start: f64,
    /// Largest difference between a given delay and the plane wave's (s).
    pub misfit: f64,
}

/// Largest misfit of per-element delays to a plane wave, in periods of the centre frequency: a
/// tenth of a period (36° of phase) holds a scanner's clock quantisation (4 ns at 250 MHz is 1/16
/// of a 15.6 MHz period) and refuses focused and diverging waves, whose delays bow by many periods.
pub const PLANE_WAVE_TOLERANCE_PERIODS: f64 = 0.1;

/// The plane wave that fires the elements at `element_x` (m) at `delays` (s, one per element, on
/// any clock): the least-squares line through (x_i, d_i) gives sin θ = c·slope and, at the element
/// that fires first ([`element_firing_delay`] = 0 there), the start. An error says why when the
/// delays are not a plane wave within `tolerance` (s) or imply |sin θ| ≥ 1 for the sound speed
/// `c` (m/s) — pcuvd beamforms and fits vectors to plane waves only. The inverse of
/// `start + element_firing_delay(x_i, θ, aperture, c)`.
pub fn plane_wave_from_delays(
    delays: &[f64],
    element_x: &[f64],
    c: f64,
    tolerance: f64,
) -> Result<PlaneWave, String> {
    if delays.len() != element_x.len() {
        return Err(format!(
            "has {} delays but the probe has {} elements",
            delays.len(),
            element_x.len()
        ));
    }
    if let Some(i) = delays.iter().position(|d| !d.is_finite()) {
        return Err(format!(
            "element {i}'s delay is {}; every delay must be finite (s)",
            delays[i]
        ));
    }
    let n = delays.len() as f64;
    let mx = element_x.iter().sum::<f64>() / n;
    let md = delays.iter().sum::<f64>() / n;
    let sxx: f64 = element_x.iter().map(|x| (x - mx).powi(2)).sum();
    let sxd: f64 = element_x
        .iter()
        .zip(delays)
        .map(|(x, d)| (x - mx) * (d - md))
        .sum();
    let slope = if sxx > 0.0 { sxd / sxx } else { 0.0 };
    let line = |x: f64| md + slope * (x - mx);
    let misfit = element_x
        .iter()
        .zip(delays)
        .map(|(&x, d)| (d - line(x)).abs())
        .fold(0.0, f64::max);
    if misfit.is_nan() || misfit > tolerance {
        return Err(format!(
            "is not a plane wave: the best plane wave misses a delay by {:.4} µs (at most {:.4} µs \
             is accepted); focused and diverging waves are not supported",
            misfit * 1e6,
            tolerance * 1e6
        ));
    }
    let sin = c * slope;
    if sin.is_nan() || sin.abs() >= 1.0 {
        return Err(format!(
            "implies sin θ = {sin:.4} for c = {c} m/s: a plane wave needs |sin θ| < 1 (delays \
             too steep, or in another unit than s)"
        ));
    }
    let angle = sin.asin();
    let (lo, hi) = element_x
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &x| {
            (l.min(x), h.max(x))
        });
    let x_ref = if angle >= 0.0 { lo } else { hi };
    Ok(PlaneWave {
        angle,
        start: line(x_ref),
        misfit,
    })
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

    /// A steered plane wave given as per-element delays (on a clock that starts 3 µs before its
    /// first element fires) is recognised as exactly the angle and start it was made from, and its
    /// transmit time of flight is the angle's; a focused wave and a too-steep line are refused.
    #[test]
    fn plane_wave_delays_give_back_the_angle() {
        let xs: Vec<f64> = (0..128).map(|i| (i as f64 - 63.5) * 0.1e-3).collect();
        let ap = (xs[0], xs[127]);
        let c = 1540.0;
        for deg in [-15.0f64, -7.5, 0.0, 3.0, 15.0] {
            let angle = deg.to_radians();
            let start = 3e-6;
            let delays: Vec<f64> = xs
                .iter()
                .map(|&x| start + element_firing_delay(x, angle, ap, c))
                .collect();
            let wave = plane_wave_from_delays(&delays, &xs, c, 1e-9).unwrap();
            assert!((wave.angle - angle).abs() < 1e-12, "{deg}: {}", wave.angle);
            assert!((wave.start - start).abs() < 1e-17, "{deg}: {}", wave.start);
            assert!(wave.misfit < 1e-17);
            for (x, z) in [(0.0, 10e-3), (-5e-3, 3e-3), (6e-3, 30e-3)] {
                let by_angle = start + transmit_delay(x, z, angle, ap, c);
                let by_delays = wave.start + transmit_delay(x, z, wave.angle, ap, c);
                assert!((by_angle - by_delays).abs() < 1e-16, "{deg}");
            }
        }
        // Focused at 20 mm: the delays bow by (6.35 mm)² / (2 · 20 mm) / c ≈ 0.65 µs.
        let focused: Vec<f64> = xs
            .iter()
            .map(|&x| (20e-3 - (x * x + 4e-4f64).sqrt()) / c)
            .collect();
        let e = plane_wave_from_delays(&focused, &xs, c, 6.4e-9).unwrap_err();
        assert!(e.contains("not a plane wave"), "{e}");
        let steep: Vec<f64> = xs.iter().map(|&x| x / 1000.0).collect();
        let e = plane_wave_from_delays(&steep, &xs, c, 6.4e-9).unwrap_err();
        assert!(e.contains("sin θ"), "{e}");
        let e = plane_wave_from_delays(&[0.0; 3], &xs, c, 6.4e-9).unwrap_err();
        assert!(e.contains("3 delays"), "{e}");
    }
}
