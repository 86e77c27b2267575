//! Which angles reach which pixels: the coverage map that leaves unreached angles out of the
//! vector fit agrees with the images the beamformer actually forms.

use pcuvd_testing as common;

use ndarray::s;
use pcuvd::form::decode::EventAlignment;
use pcuvd::pipeline::{self, Stage};

fn quiet(_: Stage, _: usize, _: usize) {}

/// Per angle, the pixels whose plane wave reaches them but which coverage leaves out; panics if
/// coverage keeps a pixel whose image is exactly zero or leaves out one whose image holds an echo.
fn left_out_per_angle(coded: bool) -> Vec<usize> {
    let data = common::tube_recording(coded, 4);
    let acq = &data.acquisition;
    let grid = pipeline::default_grid(&data).unwrap();
    let process = pcuvd::study::process_params(&grid, acq, (1, 1), EventAlignment::MidFrame);
    let (images, _) = pipeline::form_images(&data, &process, &quiet).unwrap();
    let coverage = images.coverage.as_ref().unwrap();
    let (nz, nx) = grid.shape();
    let aperture = acq.probe.aperture();
    let fs = acq.sampling_frequency;
    let record_end = acq.t0 + (data.samples.dim().2 as f64 - 1.0) / fs;
    // A decoded slot's record ends in zeros inside the array, and the IQ low-pass filter carries
    // its last echoes that far into them (plus a sample of the beamformer's interpolation).
    let cutoff = pcuvd::form::iq::default_cutoff(images.demodulation_frequency, fs);
    let filter_reach = (pcuvd::form::iq::lowpass_taps(cutoff, fs).len() / 2 + 1) as f64 / fs;
    let mut left_out = vec![0; images.series.len()];
    for (k, series) in images.series.iter().enumerate() {
        for iz in 0..nz {
            for ix in 0..nx {
                let recorded = series
                    .slice(s![iz, ix, ..])
                    .iter()
                    .any(|v| v.norm_sqr() > 0.0);
                let (x, z, angle) = (grid.x[ix], grid.z[iz], images.angles[k]);
                let insonified = pcuvd::core::geometry::insonified(x, z, angle, aperture);
                let covered = coverage[[k, iz, ix]];
                assert!(
                    !covered || recorded,
                    "angle {k}, pixel ({iz}, {ix}) of {nz} × {nx}: covered but its image is zero"
                );
                let nearest = x.clamp(aperture.0, aperture.1);
                let earliest = pcuvd::core::geometry::round_trip_delay(
                    x,
                    z,
                    angle,
                    nearest,
                    aperture,
                    acq.sound_speed,
                );
                let slot_end = record_end - acq.sequence.slot_offset(k);
                assert!(
                    !(insonified && recorded && !covered) || earliest <= slot_end + filter_reach,
                    "angle {k}, pixel ({iz}, {ix}): its echo arrives {:.3} µs before its slot's \
                     record ends, yet it is left out",
                    (slot_end - earliest) * 1e6
                );
                left_out[k] += usize::from(insonified && !covered);
            }
        }
    }
    left_out
}

#[test]
fn the_deepest_rows_are_left_to_the_angles_whose_echo_the_record_holds() {
    // A steered wave reaches a deep pixel on its far side later than the record lasts: there its
    // image is exactly zero, and a projection of 0 m/s must not enter the vector fit.
    let left_out = left_out_per_angle(false);
    // The condition bites (the steep angles lose the deepest rows: 1,504 pixel-angles of this
    // 109 × 95 grid), and leaves out no pixel whose image holds an echo.
    assert!(left_out.iter().sum::<usize>() > 95, "{left_out:?}");
}

#[test]
fn a_coded_slot_loses_the_depth_its_start_takes_from_the_record() {
    // Decoding advances slot k's record by k·Δτ and fills its tail with zeros: the later the
    // slot, the more of the deepest rows its angle cannot see, whatever its steering.
    let left_out = left_out_per_angle(true);
    // The angles are steered symmetrically (−θ … +θ), so angle k and angle n−1−k lose the same
    // pixels to the array's edges: the later slot of each pair must lose more.
    let n = left_out.len();
    assert!(
        (0..n / 2).all(|k| left_out[n - 1 - k] > left_out[k] + 95),
        "{left_out:?}"
    );
}
