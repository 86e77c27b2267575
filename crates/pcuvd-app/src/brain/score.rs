//! The brain's maps scored against its truth: the lumen, vector errors by depth, diameter,
//! nearness to the wall and estimator, flow shown where there is no blood, and RI by class and
//! depth.

use super::*;

/// The diameter (m) of the vessel each pixel sees most of (NaN without blood), and the scored
/// pixels: blood in the beam from a vessel at least [`LUMEN_MIN_DIAMETER_M`] wide.
pub(super) fn lumen_of(
    simulation: &Simulation,
    truth: &SimulatedTruth,
) -> Result<(Array2<f64>, Array2<bool>)> {
    simulation
        .lumen(truth)
        .context("a tree scenario and its cycle truth")
}

pub(super) struct ScoreContext<'a> {
    pub(super) scenario: &'a str,
    pub(super) frames: usize,
    pub(super) noise_db: Option<f64>,
    pub(super) processing: &'a crate::settings::ProcessingSettings,
    /// The dynamics stage's least arteriole RI and largest venule RI.
    pub(super) class_thresholds: (f64, f64),
}

#[allow(clippy::too_many_arguments)]
pub(super) fn score(
    modes: &[BrainMode; 2],
    truth: &SimulatedTruth,
    diameter_m: &Array2<f64>,
    lumen: &Array2<bool>,
    wavelength: f64,
    context: ScoreContext<'_>,
    mut timing: Vec<(String, f64)>,
    clock: std::time::Instant,
) -> Result<BrainMetrics> {
    let (nz, nx) = lumen.dim();
    let z = &truth.z;
    let fields = [modes[0].field()?, modes[1].field()?];
    let group = |label: String, select: &dyn Fn(usize, usize) -> bool| {
        let scores =
            [0, 1].map(|m| vector_score(fields[m], &modes[m].detected, truth, lumen, select));
        GroupScores {
            group: label,
            improvement_pct: 100.0 * (1.0 - scores[1].rmse_mm_s / scores[0].rmse_mm_s),
            uvd: scores[0],
            pcuvd: scores[1],
        }
    };
    // The depth range the lumen spans: the default grid reaches as deep as the traces do (for
    // the brain, 22 mm under a 13 mm receive window), far below any vessel.
    let lumen_depths = lumen
        .indexed_iter()
        .filter(|(_, l)| **l)
        .map(|((iz, _), _)| z[iz]);
    let (top, bottom) = lumen_depths.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), d| {
        (a.min(d), b.max(d))
    });
    if !top.is_finite() {
        bail!("brain study: the truth holds no lumen pixel on the processing grid");
    }
    let third = (bottom - top) / 3.0;
    let bands: Vec<(String, f64, f64)> = (0..3)
        .map(|k| {
            let (from, to) = (top + k as f64 * third, top + (k + 1) as f64 * third);
            let label = format!("{:.1}–{:.1} mm", from * 1e3, to * 1e3);
            // The last band holds its lower edge and the bottom lumen row.
            (label, from, if k == 2 { f64::INFINITY } else { to })
        })
        .collect();
    // The groups' tests, shared by the vector and the RI scores.
    let in_band = |band: &(String, f64, f64), iz: usize| z[iz] >= band.1 && z[iz] < band.2;
    let in_class = |from: f64, to: f64, iz: usize, ix: usize| {
        let d = diameter_m[[iz, ix]];
        d >= from && d < to
    };
    let wide = |iz: usize, ix: usize| diameter_m[[iz, ix]] >= wavelength;
    let wide_label = format!("vessels ≥ {:.0} µm", wavelength * 1e6);
    let vector_by_depth = bands
        .iter()
        .map(|band| group(band.0.clone(), &|iz, _| in_band(band, iz)))
        .collect();
    let whole = ("all".to_string(), top, f64::INFINITY);
    let false_detections = bands
        .iter()
        .chain([&whole])
        .map(|(label, from, to)| {
            // The last band stops at the lumen's bottom row, as the whole range does.
            let in_band = |iz: usize| z[iz] >= *from && z[iz] < *to && z[iz] <= bottom;
            false_detections(label, modes, &truth.truth.mask, &in_band)
        })
        .collect();
    let vector_by_diameter = DIAMETER_CLASSES
        .iter()
        .map(|&(from, to, label)| group(label.to_string(), &|iz, ix| in_class(from, to, iz, ix)))
        .collect();
    let vector_all = group("all lumen pixels".into(), &|_, _| true);
    // Coding and IRLS apart: each recording read by each estimator, over the pixels both
    // recordings' vessel masks hold (each method's own mask would score different pixels).
    let detected_by_both = &modes[0].detected & &modes[1].detected;
    let by_estimator = |label: String, select: &dyn Fn(usize, usize) -> bool| {
        let read = |m: usize, irls: bool| -> Result<VectorScore> {
            let field = modes[m].field_of(irls)?;
            Ok(vector_score(field, &detected_by_both, truth, lumen, select))
        };
        Ok::<_, anyhow::Error>(EstimatorScores {
            group: label,
            conventional_ls: read(0, false)?,
            conventional_irls: read(0, true)?,
            coded_ls: read(1, false)?,
            coded_irls: read(1, true)?,
        })
    };
    let vector_by_estimator = vec![
        by_estimator("all lumen pixels".into(), &|_, _| true)?,
        by_estimator(bands[2].0.clone(), &|iz, _| in_band(&bands[2], iz))?,
    ];
    // The paper's "deep small vessels": the deepest third by diameter class.
    let deep = &bands[2];
    let vector_deep_by_diameter = DIAMETER_CLASSES
        .iter()
        .map(|&(from, to, label)| {
            group(format!("{}, {label}", deep.0), &|iz, ix| {
                in_band(deep, iz) && in_class(from, to, iz, ix)
            })
        })
        .collect();

    let cycle = truth.cycle.as_ref().context("the tree's cycle truth")?;
    let near_wall = |iz: usize, ix: usize| cycle.axis_profile[[iz, ix]] < WALL_PROFILE;
    let vector_by_wall = vec![
        group("near the wall".into(), &near_wall),
        group("toward the axis".into(), &|iz, ix| !near_wall(iz, ix)),
        group(format!("{wide_label}, near the wall"), &|iz, ix| {
            wide(iz, ix) && near_wall(iz, ix)
        }),
        group(format!("{wide_label}, toward the axis"), &|iz, ix| {
            wide(iz, ix) && !near_wall(iz, ix)
        }),
    ];
    let scored_against =
        |label: &str, truth: (&Array2<f64>, &Array2<u8>), select: &dyn Fn(usize, usize) -> bool| {
            RiGroupScores {
                group: label.to_string(),
                uvd: modes[0]
                    .ri
                    .as_ref()
                    .map(|ri| ri_score(ri, truth, lumen, select)),
                pcuvd: modes[1]
                    .ri
                    .as_ref()
                    .map(|ri| ri_score(ri, truth, lumen, select)),
            }
        };
    let ri_group = |label: &str, select: &dyn Fn(usize, usize) -> bool| {
        scored_against(label, (&cycle.ri, &cycle.vessel_class), select)
    };
    let mut ri = vec![
        ri_group(&format!("{wide_label} (a wavelength)"), &wide),
        ri_group("all lumen pixels", &|_, _| true),
    ];
    for &(from, to, label) in &DIAMETER_CLASSES {
        ri.push(ri_group(label, &|iz, ix| in_class(from, to, iz, ix)));
    }
    let one_class = |iz: usize, ix: usize| cycle.class_share[[iz, ix]] >= SINGLE_CLASS_SHARE;
    ri.push(ri_group(
        &format!("{wide_label}, one class in the beam"),
        &|iz, ix| wide(iz, ix) && one_class(iz, ix),
    ));
    ri.push(ri_group(
        "all lumen pixels, one class in the beam",
        &one_class,
    ));
    // What the beam's own mean velocity would give read without error: where an artery and a
    // vein share a beam (or a resolution cell), any first-moment estimate reads their mix.
    if let Some(beam_ri) = &truth.beam_ri {
        let (artery_ri_min, vein_ri_max) = context.class_thresholds;
        let beam_class = Zip::from(beam_ri)
            .and(&cycle.vessel_class)
            .map_collect(|&ri, &class| {
                if class == BACKGROUND || !ri.is_finite() {
                    BACKGROUND
                } else {
                    pcuvd::dynamics::vessel_class_of(ri, artery_ri_min, vein_ri_max)
                }
            });
        let beam = (beam_ri, &beam_class);
        ri.push(scored_against(
            &format!("{wide_label}, against the beam's own RI"),
            beam,
            &wide,
        ));
        ri.push(scored_against(
            "all lumen pixels, against the beam's own RI",
            beam,
            &|_, _| true,
        ));
    }
    // Veins are steady and slow, arteries pulsatile: the two kinds fail differently.
    for (class, label) in [(ARTERIOLE, "arterioles"), (VENULE, "venules")] {
        ri.push(ri_group(label, &|iz, ix| {
            cycle.vessel_class[[iz, ix]] == class
        }));
    }
    // Where in depth it fails: the vector scores' thirds, every lumen pixel and the wide ones
    // (a band without wide vessels has no such group).
    for band in &bands {
        let wide_in_band = |iz: usize, ix: usize| in_band(band, iz) && wide(iz, ix);
        ri.push(ri_group(&band.0, &|iz, _| in_band(band, iz)));
        if lumen
            .indexed_iter()
            .any(|((iz, ix), &l)| l && wide_in_band(iz, ix))
        {
            ri.push(ri_group(
                &format!("{}, {wide_label}", band.0),
                &wide_in_band,
            ));
        }
    }

    // Whole-millimetre bands over the lumen's depth.
    let band_m = 1e-3;
    let first = (top / band_m).floor() as usize;
    let last = (bottom / band_m).floor() as usize;
    let contrast_by_depth = (first..=last)
        .filter_map(|b| {
            let (from, to) = (b as f64 * band_m, (b + 1) as f64 * band_m);
            let rows: Vec<usize> = (0..nz).filter(|&iz| z[iz] >= from && z[iz] < to).collect();
            let lumen_pixels = rows
                .iter()
                .flat_map(|&iz| (0..nx).map(move |ix| (iz, ix)))
                .filter(|&p| lumen[p])
                .count();
            if lumen_pixels == 0 {
                return None;
            }
            let ratio = |m: usize| {
                let power = &modes[m].out.maps.power_doppler;
                let (mut vessel, mut background) = (Vec::new(), Vec::new());
                for &iz in &rows {
                    for ix in 0..nx {
                        if lumen[[iz, ix]] {
                            vessel.push(power[[iz, ix]]);
                        } else if !truth.truth.mask[[iz, ix]] {
                            background.push(power[[iz, ix]]);
                        }
                    }
                }
                let mean = vessel.iter().sum::<f64>() / vessel.len() as f64;
                10.0 * (mean / pcuvd::core::stats::median(background)).log10()
            };
            let (conventional_db, coded_db) = (ratio(0), ratio(1));
            Some(BandContrast {
                depth_mm: [from * 1e3, to * 1e3],
                lumen_pixels,
                conventional_db,
                coded_db,
                gain_db: coded_db - conventional_db,
            })
        })
        .collect();
    timing.push(("scoring_s".into(), clock.elapsed().as_secs_f64()));
    Ok(BrainMetrics {
        scenario: context.scenario.to_string(),
        frames: context.frames,
        noise_db: context.noise_db,
        lumen_min_diameter_m: LUMEN_MIN_DIAMETER_M,
        processing: context.processing.clone(),
        lumen_pixels: lumen.iter().filter(|&&l| l).count(),
        clutter_cut_offs: [0, 1].map(|m| {
            modes[m]
                .out
                .clutter
                .iter()
                .map(|r| (r.low, r.high))
                .collect()
        }),
        resolution_cells: [0, 1].map(|m| CellRecord::of_angles(&modes[m].out.maps.cells)),
        vector_by_depth,
        vector_by_diameter,
        vector_all,
        vector_definition: VECTOR_SCORE_DEFINITION,
        vector_deep_by_diameter,
        vector_by_estimator,
        vector_by_wall,
        wall_definition: WALL_DEFINITION,
        ri,
        ri_skipped: modes.iter().filter_map(|m| m.ri_skipped.clone()).collect(),
        ri_definition: BRAIN_RI_DEFINITION,
        contrast_by_depth,
        contrast_definition: CONTRAST_DEFINITION,
        false_detections,
        false_detection_definition: FALSE_DETECTION_DEFINITION,
        timing_s: timing,
    })
}

/// See [`VECTOR_SCORE_DEFINITION`].
pub(super) fn vector_score(
    field: &VectorField,
    detected: &Array2<bool>,
    truth: &SimulatedTruth,
    lumen: &Array2<bool>,
    select: impl Fn(usize, usize) -> bool,
) -> VectorScore {
    let (mut pixels, mut found) = (0usize, 0usize);
    let (mut sx, mut sz) = (0.0, 0.0);
    let mut angles = Vec::new();
    for ((iz, ix), &is_lumen) in lumen.indexed_iter() {
        if !is_lumen || !select(iz, ix) {
            continue;
        }
        pixels += 1;
        let (vx, vz) = (field.vx[[iz, ix]], field.vz[[iz, ix]]);
        if !detected[[iz, ix]] || !vx.is_finite() || !vz.is_finite() {
            continue;
        }
        found += 1;
        let (tx, tz) = (truth.truth.vx[[iz, ix]], truth.truth.vz[[iz, ix]]);
        sx += (vx - tx).powi(2);
        sz += (vz - tz).powi(2);
        let angle = (vz.atan2(vx) - tz.atan2(tx)).rem_euclid(std::f64::consts::TAU);
        angles.push(angle.min(std::f64::consts::TAU - angle).to_degrees());
    }
    let n = found.max(1) as f64;
    VectorScore {
        pixels,
        detected: found as f64 / pixels.max(1) as f64,
        rmse_vx_mm_s: 1e3 * (sx / n).sqrt(),
        rmse_vz_mm_s: 1e3 * (sz / n).sqrt(),
        rmse_mm_s: 1e3 * ((sx + sz) / n).sqrt(),
        median_direction_error_deg: pcuvd::core::stats::median(angles),
    }
}

/// See [`FALSE_DETECTION_DEFINITION`]: both modes over the rows `in_band` selects.
pub(super) fn false_detections(
    group: &str,
    modes: &[BrainMode; 2],
    blood: &Array2<bool>,
    in_band: &dyn Fn(usize) -> bool,
) -> FalseDetections {
    let [uvd, pcuvd] = [0, 1].map(|m| {
        let ri = modes[m].ri.as_ref().map(|maps| &maps.ri);
        false_detection_score(&modes[m].detected, ri, blood, in_band)
    });
    FalseDetections {
        group: group.to_string(),
        blood_free_pixels: uvd.0,
        uvd: uvd.1,
        pcuvd: pcuvd.1,
    }
}

/// The pixels of the rows `in_band` selects with no blood in the beam (`blood` false), and the
/// fractions of them in the vessel mask `detected` and with a finite RI in `ri`.
pub(super) fn false_detection_score(
    detected: &Array2<bool>,
    ri: Option<&Array2<f64>>,
    blood: &Array2<bool>,
    in_band: &dyn Fn(usize) -> bool,
) -> (usize, FalseDetectionScore) {
    let free: Vec<(usize, usize)> = blood
        .indexed_iter()
        .filter(|&((iz, _), &b)| !b && in_band(iz))
        .map(|(p, _)| p)
        .collect();
    let share = |hit: &dyn Fn((usize, usize)) -> bool| {
        free.iter().filter(|&&p| hit(p)).count() as f64 / free.len().max(1) as f64
    };
    let score = FalseDetectionScore {
        in_vessel_mask: share(&|p| detected[p]),
        with_ri: ri.map(|ri| share(&|p| ri[p].is_finite())),
    };
    (free.len(), score)
}

/// See [`BRAIN_RI_DEFINITION`]: against `truth_ri` and `truth_class` (nz, nx), lumen pixels of a
/// class other than background.
pub(super) fn ri_score(
    est: &RiMaps,
    (truth_ri, truth_class): (&Array2<f64>, &Array2<u8>),
    lumen: &Array2<bool>,
    select: &dyn Fn(usize, usize) -> bool,
) -> RiGroupScore {
    let (mut errors, mut right) = (Vec::new(), 0usize);
    for ((iz, ix), &is_lumen) in lumen.indexed_iter() {
        let true_class = truth_class[[iz, ix]];
        if !is_lumen || true_class == BACKGROUND || !select(iz, ix) {
            continue;
        }
        let ri = est.ri[[iz, ix]];
        errors.push(if ri.is_finite() {
            (ri - truth_ri[[iz, ix]]).abs()
        } else {
            1.0
        });
        right += usize::from(est.vessel_class[[iz, ix]] == true_class);
    }
    let pixels = errors.len();
    RiGroupScore {
        pixels,
        median_abs_error: pcuvd::core::stats::median(errors),
        // A group without pixels has no accuracy (NaN, null in metrics.json), not 0.
        class_accuracy: if pixels == 0 {
            f64::NAN
        } else {
            right as f64 / pixels as f64
        },
    }
}
