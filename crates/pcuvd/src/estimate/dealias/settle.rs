//! Which pixels settle the levels, the settling at K intervals, and each estimator's alias
//! counts within its pixel's settled level.
//!
//! # Pixels whose angles disagree on the Nyquist velocity
//! With Loupas each angle's v_N = c·f_frame/(4 f̄) comes from its own echo's mean frequency f̄,
//! which the blood at one place shares between angles (within about 20 %) and haze and noise do
//! not (their f̄ scatter by a factor of up to 2.8). Such pixels (above [`NYQUIST_SPREAD_LIMIT`])
//! are set aside from the settling below and then take the level of the flow around them where
//! they lie inside it (a hole of the flow, [`wall_pixels`]); elsewhere they keep the plain fit.
//! Kasai's v_N is one for all angles, so nothing is set aside with it.
//!

use super::*;

/// Every flow pixel's least-squares candidates at K = `intervals` and the level each pixel of a
/// settled region takes ([`settle_levels`]).
pub(super) struct Settled {
    pub(super) intervals: u32,
    pub(super) least_squares: Vec<Vec<Candidate>>,
    pub(super) levels: Vec<Option<i32>>,
}

/// Flow pixels (row-major) whose angles' Nyquist velocities disagree: the largest over the
/// reached angles above [`NYQUIST_SPREAD_LIMIT`] times the smallest.
pub(super) fn nyquist_disagrees(v_theta: ArrayView3<f64>, nyquist: ArrayView3<f64>) -> Vec<bool> {
    let (_, nz, nx) = nyquist.dim();
    (0..nz * nx)
        .map(|p| {
            let (iz, ix) = (p / nx, p % nx);
            let (lo, hi) = nyquist
                .slice(ndarray::s![.., iz, ix])
                .iter()
                .zip(v_theta.slice(ndarray::s![.., iz, ix]))
                .filter(|(_, v)| v.is_finite())
                .fold((f64::INFINITY, 0.0f64), |(lo, hi), (&vn, _)| {
                    (lo.min(vn), hi.max(vn))
                });
            hi > NYQUIST_SPREAD_LIMIT * lo
        })
        .collect()
}

/// The levels of `v_theta`'s flow pixels at K = `intervals`, settled on least-squares candidates
/// whatever the estimator: their vectors vary smoothly over the vessel. IRLS's best candidate of a
/// level can switch between relative patterns near a wall (it discards the angles that
/// disagree), and the jumps this puts in its vectors made the unwrapping shift a whole vessel's
/// core by a level on one seed of five. IRLS still chooses, within each level, the pattern of
/// its smallest residual ([`counts_with`]).
pub(super) fn settle(
    projections: &Projections,
    intervals: u32,
    quality: ArrayView2<f64>,
    flow: ArrayView2<bool>,
) -> Result<Settled> {
    let Projections {
        angles,
        velocities: v_theta,
        nyquist,
        ..
    } = *projections;
    if let Some(bad) = nyquist.iter().find(|v| !(v.is_finite() && **v > 0.0)) {
        return Err(invalid(
            "Nyquist velocity",
            format!("must be finite and > 0 m/s, got {bad}"),
        ));
    }
    let n = v_theta.dim().0;
    if n != angles.len() {
        return Err(Error::Shape(format!(
            "{n} projection maps for {} angles",
            angles.len()
        )));
    }
    let mut least_squares = flow_candidates(projections, intervals, flow, &Estimator::LeastSquares);
    // Pixels whose angles disagree on v_N (with Loupas: on the echo's mean frequency, which blood
    // at one place shares) are haze or noise, or speckle of the lumen: they do not settle levels,
    // and take their neighbours' where they lie inside flow.
    let disagree = nyquist_disagrees(v_theta, nyquist);
    let set_aside: Vec<usize> = (0..least_squares.len())
        .filter(|&p| disagree[p] && !least_squares[p].is_empty())
        .collect();
    let aside: Vec<Vec<Candidate>> = set_aside
        .iter()
        .map(|&p| std::mem::take(&mut least_squares[p]))
        .collect();
    let outside = outside_of(&least_squares, flow);
    let shift = common_shift(angles, nyquist);
    let mut levels = settle_levels(
        projections,
        &least_squares,
        intervals,
        quality,
        &outside,
        shift,
    );
    for (&p, c) in set_aside.iter().zip(aside) {
        least_squares[p] = c;
    }
    let (unit, _) = shift;
    fill_holes(
        &mut levels,
        &least_squares,
        &set_aside,
        &disagree,
        &outside,
        &|c: &Candidate| c.vx * unit.0 + c.vz * unit.1,
        flow.dim(),
    );
    Ok(Settled {
        intervals,
        least_squares,
        levels,
    })
}

/// The alias counts of `v_theta` under `estimator` at the `settled` levels: its own best pattern
/// within each pixel's level. `process` fits both UVD and PC-UVD on one settling, which saves the
/// least-squares candidates and the unwrapping a second time.
pub(super) fn counts_with(
    projections: &Projections,
    estimator: &Estimator,
    settled: &Settled,
    flow: ArrayView2<bool>,
) -> AliasCounts {
    let own_candidates;
    let own = match estimator {
        Estimator::LeastSquares => &settled.least_squares,
        _ => {
            own_candidates = flow_candidates(projections, settled.intervals, flow, estimator);
            &own_candidates
        }
    };
    counts_at_levels(own, &settled.levels, projections.dim(), settled.intervals)
}

/// Each flow pixel's candidates under `estimator` (row-major; none elsewhere).
pub(super) fn flow_candidates(
    projections: &Projections,
    intervals: u32,
    flow: ArrayView2<bool>,
    estimator: &Estimator,
) -> Vec<Vec<Candidate>> {
    let Projections {
        angles,
        velocities: v_theta,
        nyquist,
        ..
    } = *projections;
    let (_, nz, nx) = v_theta.dim();
    let lanes = v_theta.permuted_axes([1, 2, 0]);
    let nyquist_lanes = nyquist.permuted_axes([1, 2, 0]);
    let mut candidates: Vec<Vec<Candidate>> = vec![Vec::new(); nz * nx];
    candidates
        .par_iter_mut()
        .enumerate()
        .for_each(|(pixel, out)| {
            let (iz, ix) = (pixel / nx, pixel % nx);
            if flow[[iz, ix]] {
                let p: Vec<f64> = lanes.slice(ndarray::s![iz, ix, ..]).to_vec();
                let vn: Vec<f64> = nyquist_lanes.slice(ndarray::s![iz, ix, ..]).to_vec();
                *out = candidates_of(angles, &p, &vn, intervals, estimator);
            }
        });
    candidates
}

/// The level each pixel of a settled region takes (row-major; `None`: the pixel keeps the plain
/// fit), from the least-squares `candidates` of every flow pixel, the `outside` of the flow
/// ([`outside_of`]) and the angle set's common shift ([`common_shift`]).
pub(super) fn settle_levels(
    projections: &Projections,
    candidates: &[Vec<Candidate>],
    intervals: u32,
    quality: ArrayView2<f64>,
    outside: &[bool],
    (unit, spacing): ((f64, f64), f64),
) -> Vec<Option<i32>> {
    let Projections {
        angles,
        velocities: v_theta,
        nyquist,
        ..
    } = *projections;
    let (n, nz, nx) = nyquist.dim();
    let along = |c: &Candidate| c.vx * unit.0 + c.vz * unit.1;

    let at_wall = wall_pixels(candidates, outside, (nz, nx));
    // Each pixel's own spacing of levels: the along-shift change of its fit when each reached
    // angle's projection grows by its own 2·v_N.
    let spacing_at: Vec<f64> = (0..nz * nx)
        .into_par_iter()
        .map(|p| {
            if candidates[p].is_empty() {
                return spacing;
            }
            let (iz, ix) = (p / nx, p % nx);
            let v: Vec<f64> = (0..n).map(|a| v_theta[[a, iz, ix]]).collect();
            let vn: Vec<f64> = (0..n).map(|a| nyquist[[a, iz, ix]]).collect();
            PixelModel::new(angles, &v, &vn)
                .map(|m| {
                    let (sx, sz) = m.ls(&m.period);
                    sx * unit.0 + sz * unit.1
                })
                .filter(|s| s.is_finite() && *s > 0.0)
                .unwrap_or(spacing)
        })
        .collect();
    let (regions, choice) = unwrap_levels(candidates, &along, &spacing_at, quality, &at_wall);

    // Each region's common offset: none where the wall node settled the levels. Elsewhere, blood
    // being slow at a vessel's wall and noise reading within ±v_N, the offset that makes the
    // region's edge (its pixels next to pixels that are not flow; the grid's border is none)
    // slowest is the physical one; the summed score decides between offsets that leave the edge
    // alike, and for regions without an edge (a pixel's own residual hardly settles the common
    // shift: see the module docs).
    let mut levels = vec![None; nz * nx];
    let k_max = intervals as i32;
    let mut choice = choice;
    for (members, _) in &regions {
        if members.len() < MIN_REGION_PIXELS {
            continue;
        }
        settle_cut_parts(
            members,
            candidates,
            &mut choice,
            &along,
            spacing,
            k_max,
            (nz, nx),
            &at_wall,
        );
    }
    for (members, walled) in &regions {
        if members.len() < MIN_REGION_PIXELS {
            continue;
        }
        let at_level = |p: usize, offset: i32| at_level(&candidates[p], choice[p], offset);
        // (edge speed in levels, rounded so that noise within a level does not decide; members
        // without a candidate at the offset (beyond ±K, they keep the plain fit); summed score of
        // the others; offset)
        let mut best: Option<(i64, usize, f64, i32)> = None;
        let offsets = if *walled {
            0..=0
        } else {
            -2 * k_max..=2 * k_max
        };
        for offset in offsets {
            let chosen: Vec<Option<usize>> = members.iter().map(|&p| at_level(p, offset)).collect();
            let missing = chosen.iter().filter(|i| i.is_none()).count();
            if missing == members.len() {
                continue;
            }
            let present = || {
                members
                    .iter()
                    .zip(&chosen)
                    .filter_map(|(&p, i)| i.map(|i| (p, i)))
            };
            let total: f64 = present().map(|(p, i)| candidates[p][i].score).sum();
            let speeds: Vec<f64> = present()
                .filter(|&(p, _)| at_wall[p])
                .map(|(p, i)| along(&candidates[p][i]).abs())
                .collect();
            let edge_levels = if speeds.is_empty() {
                0
            } else {
                (crate::core::stats::median(speeds) / spacing).round() as i64
            };
            let key = (edge_levels, missing, total, offset);
            let better = match best {
                None => true,
                Some((e, m, t, o)) => {
                    (edge_levels, missing, total, offset.abs()) < (e, m, t, o.abs())
                }
            };
            if better {
                best = Some(key);
            }
        }
        let mut offset = best.map_or(0, |(_, _, _, o)| o);
        if *walled {
            offset = decisive_offset(members, candidates, &choice, quality).unwrap_or(offset);
        }

        for &p in members {
            levels[p] = at_level(p, offset).map(|i| candidates[p][i].level);
        }
    }
    levels
}

/// The alias counts (shape `dim`: angles, nz, nx) of every pixel that has a level in `levels`
/// (row-major): those of its candidate of that level in `own`; K = `intervals`.
pub(super) fn counts_at_levels(
    own: &[Vec<Candidate>],
    levels: &[Option<i32>],
    dim: (usize, usize, usize),
    intervals: u32,
) -> AliasCounts {
    let nx = dim.2;
    let mut alias_counts = Array3::<i8>::zeros(dim);
    let (mut dealiased, mut unwrapped, mut at_limit) = (0, 0, 0);
    let k_max = intervals as i32;
    for (p, level) in levels.iter().enumerate() {
        let Some(level) = *level else {
            continue;
        };
        let Some(c) = own[p].iter().find(|c| c.level == level) else {
            continue;
        };
        let (iz, ix) = (p / nx, p % nx);
        for (a, &k) in c.alias_counts.iter().enumerate() {
            alias_counts[[a, iz, ix]] = k;
        }
        dealiased += 1;
        unwrapped += usize::from(c.alias_counts.iter().any(|&k| k != 0));
        at_limit += usize::from(c.alias_counts.iter().any(|&k| i32::from(k).abs() == k_max));
    }
    AliasCounts {
        alias_counts,
        dealiased_pixels: dealiased,
        unwrapped_pixels: unwrapped,
        at_limit_pixels: at_limit,
    }
}
