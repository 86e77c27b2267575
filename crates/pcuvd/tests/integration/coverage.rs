//! Which angles reach which pixels: the coverage map that leaves unreached angles out of the
//! vector fit agrees with the images the beamformer actually forms.

use pcuvd_testing as common;

use ndarray::s;
use pcuvd::form::decode::EventAlignment;
use pcuvd::pipeline::{self, Stage};

fn quiet(_: Stage, _: usize, _: usize) {}

#[test]
fn the_deepest_rows_are_left_to_the_angles_whose_echo_the_record_holds() {
    // A steered wave reaches a deep pixel on its far side later than the record lasts: there its
    // image is exactly zero, and a projection of 0 m/s must not enter the vector fit.
    let data = common::tube_recording(false, 4);
    let grid = pipeline::default_grid(&data).unwrap();
    let process =
        pcuvd::study::process_params(&grid, &data.acquisition, (1, 1), EventAlignment::MidFrame);
    let (images, _) = pipeline::form_images(&data, &process, &quiet).unwrap();
    let coverage = images.coverage.as_ref().unwrap();
    let (nz, nx) = grid.shape();
    let (mut beyond_the_record, mut recorded_but_left_out) = (0, 0);
    for (k, series) in images.series.iter().enumerate() {
        for iz in 0..nz {
            for ix in 0..nx {
                let recorded = series
                    .slice(s![iz, ix, ..])
                    .iter()
                    .any(|v| v.norm_sqr() > 0.0);
                let insonified = pcuvd::core::geometry::insonified(
                    grid.x[ix],
                    grid.z[iz],
                    images.angles[k],
                    data.acquisition.probe.aperture(),
                );
                let covered = coverage[[k, iz, ix]];
                assert!(
                    !covered || recorded,
                    "angle {k}, pixel ({iz}, {ix}) of {nz} × {nx}: covered but its image is zero"
                );
                beyond_the_record += usize::from(insonified && !covered);
                recorded_but_left_out += usize::from(insonified && recorded && !covered);
            }
        }
    }
    // The condition bites (the steep angles lose the deepest rows: 1,504 pixel-angles of this
    // 109 × 95 grid), and leaves out no pixel whose image holds an echo.
    assert!(beyond_the_record > nx, "{beyond_the_record}");
    assert_eq!(recorded_but_left_out, 0);
}
