//! The levels over space, unwrapped as a phase map.
//!
//! # Levels over space ([`dealiased_vectors`])
//! Flow is continuous, so the levels are settled as a phase map is unwrapped: the coordinate of
//! each flow pixel's best candidate along the common-shift direction is a phase whose period is
//! the pixel's own spacing of levels (its v_N's; with Loupas that follows the echoes' mean
//! frequency, which falls with depth, so one spacing for the image would mis-round), and it is
//! unwrapped by Herráez et al.'s sorting by reliability (Appl.
//! Opt. 41, 7437, 2002), as scikit-image's `unwrap_phase` does. A pixel is reliable where its
//! second differences are small (inside smooth flow, even on a steep gradient; not on noise), and
//! the edges between neighbouring pixels are joined most reliable first, each join shifting the
//! smaller group by the whole levels that make the edge continuous. Blood is slow at a vessel's
//! wall, and whatever the flow mask lets in beyond it (noise, the blurred wall) reads within
//! ±v_N at level 0, so every pixel next to non-flow is also joined to a fixed node at speed 0
//! (pixels without candidates enclosed by flow are holes that the unwrapping goes around, not
//! wall: [`wall_pixels`]), after every join between flow pixels: the jump a fast vessel's blurred
//! wall leaves in the measured field is put where the data are least reliable, and the median of
//! all the vessel's wall pixels then sets its level. Joined as
//! reliably as any pixel instead, the wall would let a vessel that ends inside the image, or
//! leaves the plane, set its whole core by its fast end. Then a few passes move every pixel to
//! the level nearest its neighbours' median
//! (a pixel joined through a noisy neighbour), and where a jump of more than half a level still
//! cuts a part off a region, that part, if it reaches the wall, takes the level that makes its
//! wall slowest, and if it is enclosed, the level of fewest jumps to its surroundings. A region
//! not joined to the wall node takes the common offset that makes its edge slowest, or, without
//! an edge, the smallest summed score: the residual of a common shift adds
//! up over the region's pixels, its noise only as the square root of their number. Pixels outside
//! the flow mask, with fewer than 3 distinct angles, or in regions of fewer than
//! [`MIN_REGION_PIXELS`] pixels keep the plain fit.
//!
//! On the tube at 3× v_N this leaves under 1 % of the lumen's patterns wrong, and the vectors as
//! good as the true pattern makes them (`pcuvd paper --part dealias`'s "true pattern" column):
//! what still separates them from the truth is the estimator's error at that speed, not aliasing.
//!
//! The wall node is an assumption about the flow, not a measurement, so a region joined to it is
//! then checked against its residual: summed over the region, weighted by echo power (the haze a
//! flow mask lets in around a vessel, whose projections fit any level about equally, counts
//! little), a common offset whose score is below [`DECISIVE_SCORE_RATIO`] times the wall level's
//! replaces it. That sets flow that is fast up to the wall (a plug profile,
//! [`crate::simulate::phantom::FlowProfile::Plug`]), which the wall alone put a whole level too slow; on the
//! tube with the truth's patterns the true level's summed residual is 3.5–48 times smaller than
//! a level's off. Where the residual does not decide the wall's level stays; decoded coded data
//! beyond v_N, which fit no level, can go either way.

use super::*;

/// The relative levels of the flow pixels, settled as a phase map is unwrapped (Herráez et al.,
/// "sorting by reliability following a noncontinuous path", Appl. Opt. 2002): the along-shift
/// coordinate of each pixel's best candidate, in units of that pixel's own spacing of levels
/// `spacing_at` (row-major, m/s), is a phase of period 1; each pixel's
/// reliability is the inverse of its second differences (small inside smooth flow, even on a
/// steep gradient; large on noise), and the edges between 8-neighbours are joined most reliable
/// first, each join shifting the smaller group by the whole levels that make the edge continuous.
/// Every pixel next to non-flow is then joined to a fixed node at speed 0 (blood is slow at a
/// wall): each group takes the level at which its wall pixels read slowest, by their median. Every connected group of flow pixels ends as one region: levels fixed
/// by the wall where it reaches one, else up to one common offset. Then a few passes move each
/// pixel to the level nearest its neighbours' median. `quality` breaks ties between equally
/// reliable edges. Returns the regions (pixel indices, row-major; whether the wall settled its
/// levels) and each pixel's chosen candidate.
pub(super) fn unwrap_levels(
    candidates: &[Vec<Candidate>],
    along: &(dyn Fn(&Candidate) -> f64 + Sync),
    spacing_at: &[f64],
    quality: ArrayView2<f64>,
    at_wall: &[bool],
) -> (Vec<(Vec<usize>, bool)>, Vec<usize>) {
    let (nz, nx) = quality.dim();
    // In levels: with Loupas each pixel's v_N follows its mean frequency, which falls with depth,
    // and one spacing for the whole image (from the median v_N) mis-rounded the joins. On the
    // vessel network at 80 mm/s the median v_N was 41 mm/s and a vessel's 54 mm/s, 25 % apart:
    // 13 of its pixels were put a level off, at −129 mm/s for −20.
    let in_levels = |p: usize, c: &Candidate| along(c) / spacing_at[p];
    let spacing = 1.0;
    let best = |p: usize| {
        candidates[p]
            .iter()
            .min_by(|a, b| a.score.total_cmp(&b.score))
            .map(|c| in_levels(p, c))
    };
    let phase: Vec<f64> = (0..nz * nx).map(|p| best(p).unwrap_or(f64::NAN)).collect();
    let wrap = |d: f64| d - spacing * (d / spacing).round();
    let at = |iz: i64, ix: i64| {
        (iz >= 0 && ix >= 0 && (iz as usize) < nz && (ix as usize) < nx)
            .then(|| iz as usize * nx + ix as usize)
            .filter(|&q| phase[q].is_finite())
    };
    let reliability: Vec<f64> = (0..nz * nx)
        .into_par_iter()
        .map(|p| {
            if !phase[p].is_finite() {
                return 0.0;
            }
            let (iz, ix) = ((p / nx) as i64, (p % nx) as i64);
            let (mut sum, mut pairs) = (0.0, 0usize);
            for (dz, dx) in [(0, 1), (1, 0), (1, 1), (1, -1)] {
                if let (Some(l), Some(r)) = (at(iz - dz, ix - dx), at(iz + dz, ix + dx)) {
                    let second = wrap(phase[l] - phase[p]) - wrap(phase[p] - phase[r]);
                    sum += second * second;
                    pairs += 1;
                }
            }
            if pairs == 0 {
                0.0
            } else {
                1.0 / ((sum * 4.0 / pairs as f64).sqrt() + 1e-9 * spacing)
            }
        })
        .collect();
    let mut edges: Vec<(f64, f64, usize, usize)> = Vec::new();
    for p in (0..nz * nx).filter(|&p| phase[p].is_finite()) {
        let (iz, ix) = ((p / nx) as i64, (p % nx) as i64);
        for q in [
            at(iz, ix + 1),
            at(iz + 1, ix),
            at(iz + 1, ix + 1),
            at(iz + 1, ix - 1),
        ]
        .into_iter()
        .flatten()
        {
            let strength = quality[[p / nx, p % nx]] + quality[[q / nx, q % nx]];
            edges.push((reliability[p] + reliability[q], strength, p, q));
        }
    }
    edges.sort_by(|a, b| {
        b.0.total_cmp(&a.0)
            .then(b.1.total_cmp(&a.1))
            .then((a.2, a.3).cmp(&(b.2, b.3)))
    });
    // The wall: every pixel next to non-flow joins a fixed node at speed 0 (blood is slow at a
    // wall), after every join between flow pixels, so that each vessel's relative levels are
    // its data's and the median of all its wall pixels sets its level. Joined as reliably as
    // the pixel itself, a vessel that ends in the image (or leaves the plane) met the node first
    // through its fast end, whose level then held the whole core: at 3× v_N the core is joined
    // along the flow long before across the blurred wall, where the lag-1 coherence collapses.
    let ground = nz * nx;
    edges.extend(
        (0..nz * nx)
            .filter(|&p| at_wall[p])
            .map(|p| (reliability[p], 0.0, p, ground)),
    );
    // Each pixel's group (the index of a pixel of it) and its whole-level shift.
    let mut group: Vec<usize> = (0..=nz * nx).collect();
    let mut members: Vec<Vec<usize>> = (0..=nz * nx)
        .map(|p| {
            if p == ground || phase[p].is_finite() {
                vec![p]
            } else {
                Vec::new()
            }
        })
        .collect();
    let mut shift = vec![0i64; nz * nx + 1];
    let unwrapped = |p: usize, shift: &[i64]| {
        if p == ground {
            0.0
        } else {
            phase[p] + shift[p] as f64 * spacing
        }
    };
    for &(_, _, p, q) in &edges {
        let (gp, gq) = (group[p], group[q]);
        if gp == gq {
            continue;
        }
        // Joining the wall, a group takes the level at which its pixels at the wall read
        // slowest, by their median: not one pixel's say.
        let levels = if q == ground {
            let at_the_wall: Vec<f64> = members[gp]
                .iter()
                .filter(|&&m| at_wall[m])
                .map(|&m| unwrapped(m, &shift))
                .collect();
            (crate::core::stats::median(at_the_wall) / spacing).round() as i64
        } else {
            ((unwrapped(p, &shift) - unwrapped(q, &shift)) / spacing).round() as i64
        };
        let grounded = group[ground];
        let (into, from, by) =
            if gp == grounded || (gq != grounded && members[gq].len() <= members[gp].len()) {
                (gp, gq, levels)
            } else {
                (gq, gp, -levels)
            };
        let moved = std::mem::take(&mut members[from]);
        for &m in &moved {
            shift[m] += by;
            group[m] = into;
        }
        members[into].extend(moved);
    }
    let nearest = |p: usize, target: f64| {
        (0..candidates[p].len())
            .min_by(|&a, &b| {
                (in_levels(p, &candidates[p][a]) - target)
                    .abs()
                    .total_cmp(&(in_levels(p, &candidates[p][b]) - target).abs())
            })
            .unwrap_or(0)
    };
    let mut choice: Vec<usize> = (0..nz * nx)
        .map(|p| {
            if phase[p].is_finite() {
                nearest(p, unwrapped(p, &shift))
            } else {
                0
            }
        })
        .collect();
    // A pixel joined through a noisy neighbour can sit one level off the flow around it, which
    // the unwrapping never revisits; each pixel takes the candidate nearest the median of its
    // neighbours in the group, a few times over.
    for _ in 0..CONSISTENCY_PASSES {
        let next: Vec<usize> = (0..nz * nx)
            .into_par_iter()
            .map(|p| {
                if !phase[p].is_finite() {
                    return choice[p];
                }
                let around: Vec<f64> = neighbours(p, (nz, nx))
                    .filter(|&q| phase[q].is_finite() && group[q] == group[p])
                    .map(|q| in_levels(q, &candidates[q][choice[q]]))
                    .collect();
                if around.len() < 3 {
                    return choice[p];
                }
                let target = crate::core::stats::median(around);
                nearest(p, target)
            })
            .collect();
        if next == choice {
            break;
        }
        choice = next;
    }
    let walled = group[ground];
    let regions = members
        .into_iter()
        .enumerate()
        .map(|(g, m)| {
            let pixels: Vec<usize> = m.into_iter().filter(|&p| p != ground).collect();
            (pixels, g == walled)
        })
        .filter(|(m, _)| !m.is_empty())
        .collect();
    (regions, choice)
}

/// A walled region's level settled by its residual rather than its wall: the common offset whose
/// candidates' scores, summed over the region weighted by echo power (so that the haze a flow mask
/// lets in around a vessel counts little), are below [`DECISIVE_SCORE_RATIO`] times those of the
/// wall's level over the same pixels (those with a candidate at that offset, at least
/// [`DECISIVE_POWER_SHARE`] of the region's power). `None` keeps the wall's level.
///
/// With Loupas each angle unwraps by its own 2·v_N (its own mean frequency, ~2 % apart between
/// angles at a pixel), so a wrong level leaves residuals of about 2 mm/s per angle and the sum
/// over a vessel tells levels apart. This is what sets flow that is fast up to the wall (plug
/// flow) right; the wall's level stays where the residuals do not decide. Decoded coded data
/// beyond v_N fit no level and can go either way.
pub(super) fn decisive_offset(
    members: &[usize],
    candidates: &[Vec<Candidate>],
    choice: &[usize],
    quality: ArrayView2<f64>,
) -> Option<i32> {
    let nx = quality.dim().1;
    let power = |p: usize| quality[[p / nx, p % nx]];
    let whole: f64 = members.iter().map(|&p| power(p)).sum();
    // (summed score at `offset`, at the wall's level, over the members with a candidate at
    // `offset`), when those hold at least [`DECISIVE_POWER_SHARE`] of the region's echo power.
    let totals = |offset: i32| -> Option<(f64, f64)> {
        let (mut at_offset, mut at_wall, mut covered) = (0.0, 0.0, 0.0);
        for &p in members {
            if let Some(i) = at_level(&candidates[p], choice[p], offset) {
                at_offset += power(p) * candidates[p][i].score;
                at_wall += power(p) * candidates[p][choice[p]].score;
                covered += power(p);
            }
        }
        (covered >= DECISIVE_POWER_SHARE * whole && at_wall > 0.0).then_some((at_offset, at_wall))
    };
    let levels = members.iter().flat_map(|&p| {
        candidates[p]
            .iter()
            .map(move |c| c.level - candidates[p][choice[p]].level)
    });
    let (lowest, highest) = levels.fold((0, 0), |(lo, hi), o| (lo.min(o), hi.max(o)));
    (lowest..=highest)
        .filter(|&o| o != 0)
        .filter_map(|o| totals(o).map(|(t, w)| (t / w, o)))
        .filter(|&(ratio, _)| ratio < DECISIVE_SCORE_RATIO)
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, o)| o)
}

/// The common-shift direction of the whole angle set: the change of the LS vector when every
/// projection grows by 2·v_N (the median v_N of `nyquist`), as a unit vector and its length (the
/// spacing of levels, m/s).
pub(super) fn common_shift(angles: &[f64], nyquist: ArrayView3<f64>) -> ((f64, f64), f64) {
    let n = angles.len();
    let typical = crate::core::stats::median(nyquist.iter().copied().collect());
    let shift = PixelModel::new(angles, &vec![0.0; n], &vec![typical; n]).map(|m| {
        let u = vec![2.0 * typical; n];
        m.ls(&u)
    });
    match shift {
        Some((sx, sz)) => {
            let len = sx.hypot(sz);
            ((sx / len, sz / len), len)
        }
        None => ((0.0, 1.0), 2.0 * typical),
    }
}
