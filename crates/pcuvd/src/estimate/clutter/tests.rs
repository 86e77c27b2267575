use super::*;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

/// Strong still tissue + weak moving blood: the filter removes the tissue and keeps the blood.
#[test]
fn removes_still_tissue_and_keeps_moving_blood() {
    let (nz, nx, nf) = (20, 20, 32);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let normal = Normal::new(0.0, 1.0).unwrap();
    let mut tissue = Array3::<Complex32>::zeros((nz, nx, nf));
    let mut blood = Array3::<Complex32>::zeros((nz, nx, nf));
    for z in 0..nz {
        for x in 0..nx {
            let t = Complex32::new(normal.sample(&mut rng), normal.sample(&mut rng)) * 100.0;
            let b = Complex32::new(normal.sample(&mut rng), normal.sample(&mut rng));
            for f in 0..nf {
                tissue[[z, x, f]] = t;
                if (8..12).contains(&x) {
                    // A whole number of cycles over the frames: orthogonal to the still tissue.
                    blood[[z, x, f]] = b * Complex32::from_polar(
                        1.0,
                        2.0 * std::f32::consts::PI * 4.0 * f as f32 / nf as f32,
                    );
                }
            }
        }
    }
    let mut series = &tissue + &blood;
    let report = svd_filter(&mut series, &ClutterParams::default()).unwrap();
    assert_eq!(report.low, 1, "one still component");
    // Tissue suppressed by more than 60 dB; blood kept (normalised correlation > 0.999).
    let rejection = residue_over_tissue(&series, &blood, &tissue);
    assert!(rejection < 1e-6, "tissue rejection {rejection}");
    let dot: Complex32 = series
        .iter()
        .zip(blood.iter())
        .map(|(a, b)| a * b.conj())
        .sum();
    let blood_energy: f32 = blood.iter().map(|v| v.norm_sqr()).sum();
    let kept: f32 = series.iter().map(|v| v.norm_sqr()).sum();
    let correlation = dot.norm() / (blood_energy * kept).sqrt();
    assert!(correlation > 0.999, "blood correlation {correlation}");
}

/// Tissue whose components span 80 dB of energy (amplitudes 1, 10⁻², 10⁻⁴: a bright layer, its
/// motion and the motion's next order, as a block of brain shows them) over blood 100 dB
/// down: cutting the three tissue components leaves the blood. The Gram matrix squares the
/// data's dynamic range, so single precision (about 10⁻⁷ of the strongest component's energy)
/// would lose the third component and leave it, 20 dB over the blood.
#[test]
fn tissue_spanning_eighty_decibels_is_cut_to_the_blood() {
    let shape = (40, 40, 64);
    let tissue = toned(shape, 11, |_, _| vec![(1.0, 0.0), (1e-2, 1.0), (1e-4, 2.0)]);
    let blood = toned(shape, 12, |_, _| vec![(1e-5, 9.0)]);
    for blocks in [None, Some((20, 20))] {
        let mut series = &tissue + &blood;
        let params = ClutterParams {
            low: RankCut::Fixed(3),
            blocks,
            ..ClutterParams::default()
        };
        svd_filter(&mut series, &params).unwrap();
        let left: f64 = (&series - &blood).iter().map(|v| v.norm_sqr() as f64).sum();
        let kept: f64 = blood.iter().map(|v| v.norm_sqr() as f64).sum();
        assert!(
            left < 0.01 * kept,
            "{blocks:?}: left {:.1} dB re the blood",
            10.0 * (left / kept).log10()
        );
    }
}

#[test]
fn no_tissue_means_no_cut() {
    let (nz, nx, nf) = (10, 10, 16);
    let mut series = Array3::from_shape_fn((nz, nx, nf), |(z, x, f)| {
        Complex32::from_polar(1.0, 0.9 * f as f32 + (z * 7 + x * 3) as f32)
    });
    let report = svd_filter(&mut series, &ClutterParams::default()).unwrap();
    assert_eq!(report.low, 0);
}

/// Both ways of applying the projection (through the kept or through the removed subspace)
/// equal S·V_keep·V_keepᴴ computed in f64 from an independent thin SVD of S.
#[test]
fn filtered_series_equal_the_projection_of_an_independent_svd() {
    let (nz, nx, nf) = (7, 9, 12);
    let mut state = 12345u64;
    let mut next = move || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1);
        ((state >> 40) as f32 / (1u64 << 24) as f32) - 0.5
    };
    // Rank-2 tissue (strong, slow), rank-3 blood (weaker, faster, a random amplitude per
    // pixel) and weak noise: the subspaces are well separated at ranks 2 and 5, where the
    // cut-offs below fall (between near-equal noise components the split itself is
    // ill-conditioned, and no two computations agree there).
    let series = Array3::from_shape_fn((nz, nx, nf), |(z, x, f)| {
        let (t, p) = (f as f32, (z * nx + x) as f32);
        let tissue = Complex32::new(30.0 * (0.1 * t).cos(), 20.0 * (0.05 * t + 0.01 * p).sin());
        let blood: Complex32 = (1..=3)
            .map(|k| {
                let phase = 0.7 * k as f32 * t + next() * 6.0;
                Complex32::from_polar(3.0 * (next() + 0.6), phase)
            })
            .sum();
        tissue + blood + Complex32::new(0.05 * next(), 0.05 * next())
    });
    let s = Mat::<c64>::from_fn(nz * nx, nf, |p, f| {
        let v = series[[p / nx, p % nx, f]];
        c64::new(v.re as f64, v.im as f64)
    });
    let svd = s.thin_svd().unwrap();
    for (low, high) in [(2, 12), (0, 5), (2, 5)] {
        let mut filtered = series.clone();
        let params = ClutterParams {
            low: RankCut::Fixed(low),
            high: RankCut::Fixed(high),
            tissue_frequency: 0.0,
            blocks: None,
        };
        svd_filter(&mut filtered, &params).unwrap();
        let v = svd.V();
        let mut worst: f64 = 0.0;
        let mut scale: f64 = 0.0;
        for p in 0..nz * nx {
            for f in 0..nf {
                let mut expected = c64::new(0.0, 0.0);
                for g in 0..nf {
                    let mut weight = c64::new(0.0, 0.0);
                    for k in low..high {
                        weight += v[(g, k)] * v[(f, k)].conj();
                    }
                    expected += s[(p, g)] * weight;
                }
                let got = filtered[[p / nx, p % nx, f]];
                let diff = c64::new(got.re as f64, got.im as f64) - expected;
                worst = worst.max(diff.norm());
                scale = scale.max(expected.norm());
            }
        }
        // −80 dB of the kept signal: the f32 series and the Gram matrix (which squares the
        // tissue-to-blood ratio) bound the agreement (measured 0.9–5.9·10⁻⁵ here, as with
        // the full frames × frames projection this replaced).
        assert!(
            worst < 1e-4 * scale,
            "cut-offs {low}..{high}: worst error {worst} of {scale}"
        );
    }
}

/// Still tissue (one component, 40 dB above the blood) over slow blood of six vessels of
/// near-equal strength, each below the tissue frequency limit and far above the noise: the
/// blood forms a plateau of components, not tissue's steep fall, and only the tissue is cut.
#[test]
fn auto_low_keeps_a_plateau_of_strong_slow_blood() {
    let (nz, nx, nf) = (24, 24, 512);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    let normal = Normal::new(0.0, 1.0).unwrap();
    let echogenicity: Vec<f32> = (0..nz * nx).map(|_| normal.sample(&mut rng)).collect();
    let noise: Vec<Complex32> = (0..nz * nx * nf)
        .map(|_| Complex32::new(normal.sample(&mut rng), normal.sample(&mut rng)))
        .collect();
    let tau = 2.0 * std::f32::consts::PI;
    let mut series = Array3::from_shape_fn((nz, nx, nf), |(z, x, f)| {
        let tissue = 1000.0 * echogenicity[z * nx + x];
        // Vessel j: the column band x in [4j, 4j + 4), j + 1 cycles over the recording
        // (0.002–0.012 cycles per frame: whole cycles, so each its own component).
        let j = x / 4;
        let strength = 10.0 * 0.95f32.powi(j as i32);
        let cycles = (j + 1) as f32 / nf as f32;
        let blood = Complex32::from_polar(strength, tau * cycles * f as f32);
        tissue + blood + 0.1 * noise[(z * nx + x) * nf + f]
    });
    let report = svd_filter(&mut series, &ClutterParams::default()).unwrap();
    assert_eq!(report.low, 1, "{:?}", &report.singular_values[..8]);
    // Without the steepness test the slow blood passes for tissue: each of its six
    // components is slow and 10 dB above the median.
    let energies: Vec<f64> = report.singular_values.iter().map(|s| s * s).collect();
    let mut sorted = energies.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[nf / 2];
    assert!(energies[1..7].iter().all(|&e| e > 10.0 * median));
}

#[test]
fn fixed_cut_offs_are_projections() {
    let (nz, nx, nf) = (6, 5, 8);
    let mut series = Array3::from_shape_fn((nz, nx, nf), |(z, x, f)| {
        Complex32::new(
            ((z * 31 + x * 17 + f * 13) % 11) as f32,
            ((z + 2 * x + 3 * f) % 5) as f32,
        )
    });
    let params = ClutterParams {
        low: RankCut::Fixed(2),
        high: RankCut::Fixed(6),
        tissue_frequency: 0.0,
        blocks: None,
    };
    let mut twice = series.clone();
    svd_filter(&mut series, &params).unwrap();
    svd_filter(&mut twice, &params).unwrap();
    let report = svd_filter(
        &mut twice,
        &ClutterParams {
            low: RankCut::Fixed(0),
            high: RankCut::Fixed(4),
            tissue_frequency: 0.0,
            blocks: None,
        },
    )
    .unwrap();
    // After keeping components 2..6, exactly 4 non-zero singular values remain.
    assert!(report.singular_values[3] > 1e-2 * report.singular_values[0]);
    assert!(report.singular_values[4] < 1e-3 * report.singular_values[0]);
    assert!(
        svd_filter(
            &mut series,
            &ClutterParams {
                low: RankCut::Fixed(5),
                high: RankCut::Fixed(5),
                tissue_frequency: 0.0,
                blocks: None,
            }
        )
        .is_err()
    );
}

/// The similarity cut-offs on a case built to hold three subspaces, as the method assumes:
/// tissue of rank 3 whose components share one magnitude map (its echogenicity, varying
/// across the image), white noise whose level grows with depth (as a beamformed noise floor
/// does), and six vessels each lit by one Doppler tone of its own strength (equal ones would
/// mix in the singular vectors), placed where both maps are at their means, so that no vessel
/// map resembles the tissue's or the noise's (a weak vessel deep in the noise does, and the
/// fit then counts it as noise, as it should: nothing tells them apart). The fit finds the tissue's rank and the tissue-plus-blood
/// rank exactly; the energy-and-frequency rule sees only the still component.
#[test]
fn similarity_cut_offs_find_the_tissue_and_noise_subspaces() {
    let (nz, nx, nf) = (48, 32, 48);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let normal = Normal::new(0.0, 1.0).unwrap();
    let mut gaussian = || Complex32::new(normal.sample(&mut rng), normal.sample(&mut rng));
    let tau = 2.0 * std::f32::consts::PI;
    // Tissue: still, then one and two cycles of slow motion, weaker and weaker.
    let tissue_time = |k: usize, f: usize| -> Complex32 {
        let t = tau * f as f32 / nf as f32;
        match k {
            0 => Complex32::new(1.0, 0.0),
            1 => Complex32::from_polar(0.3, t),
            _ => Complex32::from_polar(0.1, 2.0 * t),
        }
    };
    let mut series = Array3::<Complex32>::zeros((nz, nx, nf));
    for z in 0..nz {
        for x in 0..nx {
            let echogenicity = 30.0 * (1.0 + 0.5 * (tau * x as f32 / nx as f32).cos());
            let phases: Vec<Complex32> = (0..3)
                .map(|_| Complex32::from_polar(1.0, gaussian().arg()))
                .collect();
            // Vessel j: 3 rows × 8 columns where both profiles are at their means, its tone
            // at 5 + j cycles.
            let vessel = (0..6).find(|j| {
                let (top, left) = (16 + 6 * (j / 2), 4 + 16 * (j % 2));
                (top..top + 3).contains(&z) && (left..left + 8).contains(&x)
            });
            let blood = vessel.map(|j| (j, Complex32::from_polar(1.0, gaussian().arg())));
            let noise_level = 0.05 + 0.15 * z as f32 / nz as f32;
            for f in 0..nf {
                let mut v: Complex32 = (0..3)
                    .map(|k| echogenicity * phases[k] * tissue_time(k, f))
                    .sum();
                if let Some((j, phase)) = blood {
                    let cycles = (5 + j) as f32;
                    // Distinct strengths, so that each component is one vessel.
                    let strength = 0.8f32.powi(j as i32);
                    v += phase
                        * Complex32::from_polar(strength, tau * cycles * f as f32 / nf as f32);
                }
                series[[z, x, f]] = v + noise_level * gaussian();
            }
        }
    }
    let similarity = ClutterParams {
        low: RankCut::Similarity,
        high: RankCut::Similarity,
        tissue_frequency: 0.02,
        blocks: None,
    };
    let report = svd_filter(&mut series.clone(), &similarity).unwrap();
    assert_eq!((report.low, report.high), (3, 9));
    let auto = svd_filter(&mut series.clone(), &ClutterParams::default()).unwrap();
    assert_eq!(
        auto.low, 1,
        "the moving tissue is faster than the auto rule's limit"
    );

    // Where a cut-off chosen from the data crosses one fixed, the chosen one gives way: the
    // filter is then the projection of the fixed cut-offs it comes to, to the bit.
    for (low, high, expected) in [
        (RankCut::Fixed(12), RankCut::Similarity, (12, 13)),
        (RankCut::Similarity, RankCut::Fixed(2), (1, 2)),
        (RankCut::Auto, RankCut::Fixed(1), (0, 1)),
        (RankCut::Fixed(40), RankCut::Auto, (40, 41)),
    ] {
        let crossing = ClutterParams {
            low,
            high,
            ..similarity
        };
        let mut given = series.clone();
        let report = svd_filter(&mut given, &crossing).unwrap();
        assert_eq!((report.low, report.high), expected, "{low:?} {high:?}");
        let fixed = ClutterParams {
            low: RankCut::Fixed(expected.0),
            high: RankCut::Fixed(expected.1),
            ..similarity
        };
        let mut projected = series.clone();
        svd_filter(&mut projected, &fixed).unwrap();
        assert!(given == projected, "{low:?} {high:?}");
    }
}

/// Crossed cut-offs: the one chosen from the data gives way to a fixed one, the noise cut-off
/// where both were chosen (one component kept after the tissue cut-off, or before the noise
/// cut-off at the last frame); fixed ones stay crossed, for the error.
#[test]
fn a_cut_off_chosen_from_the_data_gives_way_where_they_cross() {
    use RankCut::{Auto, Fixed, Similarity};
    let frames = 50;
    for (low_cut, high_cut, (low, high), expected) in [
        (Auto, Auto, (4, 30), (4, 30)),
        (Similarity, Auto, (12, 7), (12, 13)),
        (Auto, Similarity, (9, 9), (9, 10)),
        (Similarity, Similarity, (6, 2), (6, 7)),
        (Fixed(20), Auto, (20, 15), (20, 21)),
        (Auto, Fixed(5), (8, 5), (4, 5)),
        (Similarity, Fixed(1), (3, 1), (0, 1)),
        (Fixed(8), Fixed(5), (8, 5), (8, 5)),
        // A noise cut-off chosen from the data gives way up to the last frame, no further: a
        // tissue cut-off at the last frame then gives way if it was chosen too.
        (Fixed(50), Auto, (50, 3), (50, 3)),
        (Auto, Similarity, (50, 3), (2, 3)),
    ] {
        let params = ClutterParams {
            low: low_cut,
            high: high_cut,
            ..ClutterParams::default()
        };
        assert_eq!(
            super::uncrossed(low, high, &params, frames),
            expected,
            "{low_cut:?} {high_cut:?} ({low}, {high})"
        );
    }
}

/// The summed-area fit equals the least-squares fit computed directly, block by block, on a
/// symmetric matrix with two noisy squares and anti-correlated corners.
#[test]
fn two_square_fit_equals_the_direct_least_squares_fit() {
    let n = 24;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(8);
    let normal = Normal::new(0.0, 0.2).unwrap();
    let mut m = Mat::<f64>::zeros(n, n);
    for i in 0..n {
        for j in 0..=i {
            let level = match (j < 5, i >= 17) {
                (true, true) => -0.5,
                (true, false) if i < 5 => 0.9,
                (false, true) if j >= 17 => 0.5,
                _ => 0.05,
            };
            let v = if i == j {
                1.0
            } else {
                level + normal.sample(&mut rng)
            };
            m[(i, j)] = v;
            m[(j, i)] = v;
        }
    }
    let direct_error = |low: usize, high: usize| {
        let part = |i: usize| (i >= low) as usize + (i >= high) as usize;
        let region = |i: usize, j: usize| 3 * part(i).min(part(j)) + part(i).max(part(j));
        let mut sums = [0.0; 9];
        let mut counts = [0.0f64; 9];
        for i in 0..n {
            for j in 0..n {
                if i != j {
                    sums[region(i, j)] += m[(i, j)];
                    counts[region(i, j)] += 1.0;
                }
            }
        }
        let mut error = 0.0;
        for i in 0..n {
            for j in 0..n {
                if i != j {
                    let r = region(i, j);
                    error += (m[(i, j)] - sums[r] / counts[r].max(1.0)).powi(2);
                }
            }
        }
        error
    };
    // Each tissue cut-off's best noise cut-off, and its error, by the direct fit.
    let best_by_low: Vec<(f64, usize)> = (0..=n / 2)
        .map(|low| {
            (low + 1..=n)
                .map(|high| (direct_error(low, high), high))
                .min_by(|a, b| a.0.total_cmp(&b.0))
                .unwrap()
        })
        .collect();
    for (low, &(score, high)) in two_square_fits(&m).iter().enumerate() {
        assert!(
            direct_error(low, high) <= best_by_low[low].0 + 1e-9,
            "low {low}: high {high} (score {score}) fits worse than {:?}",
            best_by_low[low]
        );
    }
    let fitted = fit_two_squares(&m, None);
    let first_local_best = (0..n / 2)
        .find(|&low| best_by_low[low + 1].0 >= best_by_low[low].0 - 1e-9)
        .unwrap_or(n / 2);
    assert_eq!(fitted.0, first_local_best);
    assert_eq!(fitted, (5, 17));
}

/// A block's noisy fit: its steps wiggle (here component 1 resembles the blood's maps, not
/// the tissue's), so the leading square stops at 2; with a cap (a block's: the whole image's
/// cut-off) the best fit overall is taken, held to the cap.
#[test]
fn with_a_cap_the_best_fit_overall_is_held_to_it() {
    let n = 40;
    let mut m = Mat::<f64>::zeros(n, n);
    for i in 0..n {
        for j in 0..n {
            let (a, b) = (i.min(j), i.max(j));
            m[(i, j)] = match (a, b) {
                _ if a == b => 1.0,
                (1, 5..20) => 0.5,
                (1, _) => 0.0,
                (_, 0..5) => 0.8,
                (5..20, 5..20) => 0.1,
                (30.., _) => 0.4,
                _ => 0.0,
            };
        }
    }
    assert_eq!(fit_two_squares(&m, None).0, 2, "the case wiggles");
    assert_eq!(fit_two_squares(&m, Some(7)), (5, 30));
    assert_eq!(fit_two_squares(&m, Some(4)).0, 4);
}

/// A tissue square followed by a blood square (a vascular tree whose blood components light
/// the same vessels): the best fit overall takes tissue and blood together as tissue; the
/// leading square is the tissue alone.
#[test]
fn similarity_cut_off_is_the_leading_square_not_tissue_and_blood_together() {
    let n = 60;
    let (tissue, blood, noise) = (0..4, 4..30, 40..60);
    let mut m = Mat::<f64>::zeros(n, n);
    for i in 0..n {
        for j in 0..n {
            let both = |r: &std::ops::Range<usize>| r.contains(&i) && r.contains(&j);
            let across = |a: &std::ops::Range<usize>, b: &std::ops::Range<usize>| {
                (a.contains(&i) && b.contains(&j)) || (b.contains(&i) && a.contains(&j))
            };
            m[(i, j)] = if i == j {
                1.0
            } else if both(&tissue) || both(&blood) {
                0.7
            } else if both(&noise) {
                0.4
            } else if across(&tissue, &blood) || across(&blood, &(30..40)) {
                0.3
            } else {
                0.0
            };
        }
    }
    let fits = two_square_fits(&m);
    let best_overall = (0..fits.len())
        .max_by(|&a, &b| fits[a].0.total_cmp(&fits[b].0))
        .unwrap();
    assert_eq!(best_overall, 30, "the case holds the two-squares trap");
    assert_eq!(fit_two_squares(&m, None), (4, 30));
    // With a cap, the best fit overall held to it.
    assert_eq!(fit_two_squares(&m, Some(31)).0, 30);
    assert_eq!(fit_two_squares(&m, Some(4)), (4, 30));
}

/// The similarity matrix equals the correlation of |U|'s columns from an independent thin SVD
/// of S in f64.
#[test]
fn spatial_similarity_equals_the_correlation_of_an_independent_svd() {
    let (pixels, nf) = (300, 10);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
    let normal = Normal::new(0.0, 1.0).unwrap();
    let data: Vec<Complex32> = (0..pixels * nf)
        .map(|i| {
            let level = 1.0 + (i / nf) as f32 / 50.0 + 3.0 * ((i % nf) as f32 / nf as f32);
            level * Complex32::new(normal.sample(&mut rng), normal.sample(&mut rng))
        })
        .collect();
    let s = Mat::<c64>::from_fn(pixels, nf, |p, f| {
        let v = data[p * nf + f];
        c64::new(v.re as f64, v.im as f64)
    });
    let svd = s.thin_svd().unwrap();
    let v = Mat::<c32>::from_fn(nf, nf, |i, k| {
        let x = svd.V()[(i, k)];
        c32::new(x.re as f32, x.im as f32)
    });
    let got = spatial_similarity(&data, nf, v.as_ref());
    let magnitude =
        |k: usize| -> Vec<f64> { (0..pixels).map(|p| svd.U()[(p, k)].norm()).collect() };
    for a in 0..nf {
        for b in 0..nf {
            let (ua, ub) = (magnitude(a), magnitude(b));
            let mean = |u: &[f64]| u.iter().sum::<f64>() / pixels as f64;
            let (ma, mb) = (mean(&ua), mean(&ub));
            let cov: f64 = ua.iter().zip(&ub).map(|(x, y)| (x - ma) * (y - mb)).sum();
            let var = |u: &[f64], m: f64| u.iter().map(|x| (x - m).powi(2)).sum::<f64>();
            let expected = cov / (var(&ua, ma) * var(&ub, mb)).sqrt();
            assert!(
                (got[(a, b)] - expected).abs() < 1e-4,
                "C({a}, {b}) = {} vs {expected}",
                got[(a, b)]
            );
        }
    }
}

/// The automatic high cut-off on an analytic case. S (P pixels × N frames) is complex white
/// noise of variance σ² per sample plus rank-1 components u·vᴴ of energy ℓ·Pσ² (tissue: still;
/// blood: a Doppler tone, orthogonal to it). Without them the eigenvalues of SᴴS fill the
/// Marchenko–Pastur bulk, whose upper edge is Pσ²(1 + √y)², y = N/P. A component with ℓ > √y
/// stands out of the bulk at about Pσ²(ℓ + 1)(1 + y/ℓ); one with ℓ < √y stays inside it
/// (Baik–Ben Arous–Péché), where no filter can tell it from noise. So the cut-off must keep
/// exactly the tissue and the strong blood, and cut the weak blood with the noise.
#[test]
fn auto_high_cut_is_at_the_marchenko_pastur_edge() {
    let (nz, nx, nf) = (48, 48, 32);
    let pixels = nz * nx;
    let y = nf as f64 / pixels as f64;
    let sigma2 = 1.0f64;
    // (ℓ, cycles over the recording): tissue, strong blood, weak blood (ℓ < √y ≈ 0.118).
    let components = [(1000.0, 0.0), (3.0, 4.0), (0.05, 9.0)];
    assert!(components[2].0 < y.sqrt());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    // Complex Gaussian of variance v: real and imaginary parts of variance v/2 each.
    let mut gaussian = |variance: f64| {
        let normal = Normal::new(0.0, (variance / 2.0).sqrt()).unwrap();
        Complex32::new(
            normal.sample(&mut rng) as f32,
            normal.sample(&mut rng) as f32,
        )
    };
    let noise = Array3::from_shape_simple_fn((nz, nx, nf), || gaussian(sigma2));
    let mut signal = Array3::<Complex32>::zeros((nz, nx, nf));
    for &(ell, cycles) in &components {
        // Per-pixel amplitude of variance ℓσ²/N over N frames: energy ℓPσ² on average.
        for z in 0..nz {
            for x in 0..nx {
                let a = gaussian(ell * sigma2 / nf as f64);
                for f in 0..nf {
                    let phase = 2.0 * std::f32::consts::PI * cycles * f as f32 / nf as f32;
                    signal[[z, x, f]] += a * Complex32::from_polar(1.0, phase);
                }
            }
        }
    }
    let params = ClutterParams {
        low: RankCut::Off,
        high: RankCut::Auto,
        tissue_frequency: 0.0,
        blocks: None,
    };
    let bulk_edge = pixels as f64 * sigma2 * (1.0 + y.sqrt()).powi(2);

    let report = svd_filter(&mut (&noise + &signal), &params).unwrap();
    assert_eq!(report.high, 2, "tissue and strong blood kept, the rest cut");
    let eigenvalues: Vec<f64> = report.singular_values.iter().map(|s| s * s).collect();
    let spike = |ell: f64| pixels as f64 * sigma2 * (ell + 1.0) * (1.0 + y / ell);
    for (k, &(ell, _)) in components[..2].iter().enumerate() {
        let ratio = eigenvalues[k] / spike(ell);
        // The amplitudes are drawn, so each energy is ℓPσ² within a few 1/√P (2 %).
        assert!((ratio - 1.0).abs() < 0.1, "component {k}: {ratio}");
    }
    // Everything cut lies within the noise bulk of the true σ² (to the definition's 5 %).
    assert!(
        eigenvalues[2] < 1.05 * bulk_edge,
        "{} vs edge {bulk_edge}",
        eigenvalues[2]
    );

    // Noise alone: nothing stands out; the cut-off keeps its floor of one component.
    let report = svd_filter(&mut noise.clone(), &params).unwrap();
    assert_eq!(report.high, 1);
    let largest = report.singular_values[0].powi(2);
    assert!(largest < 1.05 * bulk_edge, "{largest} vs edge {bulk_edge}");
}

/// The energy of what a filter left beside the blood, over the tissue's energy.
fn residue_over_tissue(
    filtered: &Array3<Complex32>,
    blood: &Array3<Complex32>,
    tissue: &Array3<Complex32>,
) -> f32 {
    let residual: f32 = (filtered - blood).iter().map(|v| v.norm_sqr()).sum();
    residual / tissue.iter().map(|v| v.norm_sqr()).sum::<f32>()
}

/// A series of random speckle per pixel times a temporal tone per region: `tone(z, x)` gives
/// each pixel's (amplitude, cycles over the frames) terms.
fn toned(
    (nz, nx, nf): (usize, usize, usize),
    seed: u64,
    tones: impl Fn(usize, usize) -> Vec<(f32, f32)>,
) -> Array3<Complex32> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let normal = Normal::new(0.0, 1.0).unwrap();
    let mut series = Array3::<Complex32>::zeros((nz, nx, nf));
    for z in 0..nz {
        for x in 0..nx {
            for (amplitude, cycles) in tones(z, x) {
                let speckle = Complex32::new(normal.sample(&mut rng), normal.sample(&mut rng));
                for f in 0..nf {
                    let phase = 2.0 * std::f32::consts::PI * cycles * f as f32 / nf as f32;
                    series[[z, x, f]] += speckle * amplitude * Complex32::from_polar(1.0, phase);
                }
            }
        }
    }
    series
}

/// Still tissue over the whole image, a slow echo that grows with depth and blood whose tone
/// changes across the columns: series whose blocks see different tissue and blood.
fn still_tissue_slow_layers_and_blood(shape: (usize, usize, usize)) -> Array3<Complex32> {
    toned(shape, 12, |z, x| {
        vec![
            (40.0, 0.0),
            (4.0 + z as f32 / 4.0, 0.5),
            (1.0, 3.0 + (x % 5) as f32),
        ]
    })
}

/// Blocks that remove nothing give the series back: the tent weights blend to one over every
/// pixel, the image's edges and an image that the half-block steps do not divide included.
#[test]
fn blocks_that_remove_nothing_blend_back_to_the_series() {
    let original = toned((23, 17, 8), 5, |_, _| vec![(1.0, 1.0), (0.5, 3.0)]);
    let mut series = original.clone();
    let params = ClutterParams {
        low: RankCut::Fixed(0),
        high: RankCut::Fixed(8),
        blocks: Some((6, 5)),
        ..ClutterParams::default()
    };
    let report = svd_filter(&mut series, &params).unwrap();
    // Rows start at 0, 3, …, 15, 17; columns (5 made 6) at 0, 3, 6, 9, 11.
    assert_eq!(report.block_cut_offs.len(), 7 * 5);
    for (a, b) in series.iter().zip(original.iter()) {
        assert!((a - b).norm() <= 1e-5 * b.norm().max(1.0), "{a} vs {b}");
    }
}

/// One block as large as the image is the whole-image filter.
#[test]
fn one_block_over_the_image_is_the_whole_filter() {
    let original = toned((12, 10, 16), 6, |_, x| {
        vec![(30.0, 0.0), (1.0, if x < 5 { 3.0 } else { -5.0 })]
    });
    let (mut whole, mut blocked) = (original.clone(), original.clone());
    let whole_report = svd_filter(&mut whole, &ClutterParams::default()).unwrap();
    let params = ClutterParams {
        blocks: Some((40, 40)),
        ..ClutterParams::default()
    };
    let report = svd_filter(&mut blocked, &params).unwrap();
    assert_eq!(
        report.block_cut_offs,
        vec![(whole_report.low, whole_report.high)]
    );
    assert_eq!((report.low, report.high), (1, 16));
    for (a, b) in blocked.iter().zip(whole.iter()) {
        assert!((a - b).norm() <= 1e-6 * original[[0, 0, 0]].norm().max(1.0));
    }
}

/// Tissue that moves differently in two halves of the image (still on the left, a slow tone
/// on the right) spans two components of the whole image but one of each half's blocks: the
/// block-wise filter cuts one where its blocks see one tissue and two where they straddle
/// both, and keeps the blood everywhere.
#[test]
fn blended_block_values_are_the_tent_weighted_means_by_hand() {
    // Rows: blocks of 4 at 0 and 2 (tents 1, 2, 2, 1); one column of blocks of 3.
    let layout = BlockLayout::new((6, 3), (4, 3));
    assert_eq!(layout.shape(), (6, 3));
    assert_eq!(layout.origins().collect::<Vec<_>>(), vec![(0, 0), (2, 0)]);
    let blended = layout.blend(&[1.0, 4.0]).unwrap();
    // Row 2: tent 2 in the first block, 1 in the second; row 3 the other way round.
    let by_row = [1.0, 1.0, (2.0 + 4.0) / 3.0, (1.0 + 8.0) / 3.0, 4.0, 4.0];
    for (z, expected) in by_row.into_iter().enumerate() {
        for x in 0..3 {
            assert!((blended[[z, x]] - expected).abs() < 1e-12, "({z}, {x})");
        }
    }
    assert!(layout.blend(&[1.0]).is_err());
    // Blocks larger than the image are clamped to it, as the filter clamps them.
    let one = BlockLayout::new((5, 7), (50, 50));
    assert_eq!((one.size, one.shape()), ((5, 7), (5, 7)));
}

#[test]
fn blocks_cut_the_tissue_each_block_holds() {
    let (nz, nx, nf) = (24, 48, 64);
    // Still and brighter on the left, so that the whole image's tissue components fall off
    // steeply, as `Auto` asks.
    let tissue = toned((nz, nx, nf), 7, |_, x| {
        vec![if x < nx / 2 {
            (100.0, 0.0)
        } else {
            (30.0, 1.0)
        }]
    });
    // Blood: a fast tone (8 cycles, orthogonal to both tissue tones) in every pixel.
    let blood = toned((nz, nx, nf), 8, |_, _| vec![(1.0, 8.0)]);
    let mut whole = &tissue + &blood;
    let mut blocked = whole.clone();
    let whole_report = svd_filter(&mut whole, &ClutterParams::default()).unwrap();
    assert_eq!(whole_report.low, 2);
    let params = ClutterParams {
        blocks: Some((24, 16)),
        ..ClutterParams::default()
    };
    let report = svd_filter(&mut blocked, &params).unwrap();
    // Columns start at 0, 8, 16, 24, 32: the block at 16 straddles the two halves.
    let lows: Vec<usize> = report.block_cut_offs.iter().map(|c| c.0).collect();
    assert_eq!(lows, vec![1, 1, 2, 1, 1]);
    // In brief: the blocks' medians, with the least and the most they chose.
    assert_eq!(
        report.cut_offs(),
        CutOffs {
            low: 1,
            high: nf,
            block_low_range: Some([1, 2]),
            block_high_range: Some([nf, nf]),
        }
    );
    assert_eq!(whole_report.cut_offs().block_low_range, None);
    // Where the blocks lie, one per cut-off; blended, the cuts are 1 where one tissue fills
    // the blocks and up to 2 where they straddle both.
    assert_eq!(whole_report.block_layout, None);
    let layout = report.block_layout.as_ref().unwrap();
    assert_eq!(layout.x_starts, vec![0, 8, 16, 24, 32]);
    let lows: Vec<f64> = lows.iter().map(|&l| l as f64).collect();
    let blended = layout.blend(&lows).unwrap();
    assert_eq!((blended[[0, 0]], blended[[0, nx - 1]]), (1.0, 1.0));
    let peak = blended.iter().copied().fold(0.0, f64::max);
    assert!(peak > 1.0 && peak < 2.0, "{peak}");
    // What is left beside the blood is the tissue's residue at single precision (as the
    // whole-image filter's: 60 dB down).
    let rejection = residue_over_tissue(&blocked, &blood, &tissue);
    assert!(rejection < 1e-6, "tissue rejection {rejection}");
}

/// A strong, slow vessel on a few pixels: within a block it stands above the block's noise as
/// tissue does (strong, slow and steep), over the whole image it does not. The blocks cut at
/// most what the whole image's rule cuts, so its blood is kept.
#[test]
fn blocks_cut_no_more_than_the_whole_image() {
    let (nz, nx, nf) = (40, 40, 64);
    let vessel = |z: usize, x: usize| (14..18).contains(&z) && (14..18).contains(&x);
    let tissue = toned((nz, nx, nf), 9, |_, _| vec![(100.0, 0.0)]);
    let blood = toned((nz, nx, nf), 10, |z, x| match vessel(z, x) {
        true => vec![(3.0, 1.0)],
        false => vec![],
    });
    let noise = toned((nz, nx, nf), 11, |_, _| {
        (0..nf)
            .map(|k| (1.0 / (nf as f32).sqrt(), k as f32))
            .collect()
    });
    let series = &(&tissue + &blood) + &noise;
    // The premise: alone, the block around the vessel cuts it with the tissue.
    let mut alone = series.slice(ndarray::s![10..30, 10..30, ..]).to_owned();
    assert_eq!(
        svd_filter(&mut alone, &ClutterParams::default())
            .unwrap()
            .low,
        2
    );
    let whole = svd_filter(&mut series.clone(), &ClutterParams::default()).unwrap();
    assert_eq!(whole.low, 1);
    let mut blocked = series.clone();
    let params = ClutterParams {
        blocks: Some((20, 20)),
        ..ClutterParams::default()
    };
    let report = svd_filter(&mut blocked, &params).unwrap();
    assert!(
        report.block_cut_offs.iter().all(|c| c.0 == 1),
        "{:?}",
        report.block_cut_offs
    );
    // The vessel's blood is kept: its pixels still correlate with it.
    let (mut dot, mut kept, mut energy) = (Complex32::new(0.0, 0.0), 0.0f32, 0.0f32);
    for ((z, x, f), b) in blood.indexed_iter() {
        if vessel(z, x) {
            dot += blocked[[z, x, f]] * b.conj();
            kept += blocked[[z, x, f]].norm_sqr();
            energy += b.norm_sqr();
        }
    }
    let correlation = dot.norm() / (kept * energy).sqrt();
    assert!(correlation > 0.9, "{correlation}");
}

#[test]
fn blocks_of_an_empty_image_are_refused_as_the_whole_filter_refuses_it() {
    let params = ClutterParams {
        blocks: Some((4, 4)),
        ..ClutterParams::default()
    };
    for shape in [(0, 5, 8), (5, 0, 8), (5, 5, 1)] {
        let mut series = Array3::<Complex32>::zeros(shape);
        let error = svd_filter(&mut series, &params).unwrap_err().to_string();
        assert!(
            error.contains("needs ≥ 2 frames and pixels"),
            "{shape:?}: {error}"
        );
    }
}

/// Blocks smaller than the frames grow, the shorter side first, until they hold as many
/// pixels as frames; on an image smaller than that, the one block is the image.
#[test]
fn blocks_smaller_than_the_frames_grow_to_hold_them() {
    let series = toned((10, 12, 32), 3, |_, _| vec![(10.0, 0.0), (1.0, 5.0)]);
    let params = ClutterParams {
        blocks: Some((4, 3)),
        ..ClutterParams::default()
    };
    let report = svd_filter(&mut series.clone(), &params).unwrap();
    assert_eq!(report.block_layout.unwrap().size, (6, 6));
    assert_eq!(holding_frames((10, 12), (8, 2), 32), (8, 4));
    // Grown to (3, 11), then the side shorter than the image made even.
    assert_eq!(holding_frames((3, 40), (2, 2), 32), (3, 12));
    // Even sides, so that half-block steps tile the image; the image's own side stays.
    assert_eq!(holding_frames((401, 236), (37, 37), 180), (38, 38));
    assert_eq!(holding_frames((401, 37), (37, 37), 180), (38, 37));

    let small = series.slice(ndarray::s![..5, ..5, ..]).to_owned();
    let mut blocked = small.clone();
    let report = svd_filter(&mut blocked, &params).unwrap();
    assert_eq!(report.block_layout.unwrap().size, (5, 5));
    let mut whole = small;
    svd_filter(&mut whole, &ClutterParams::default()).unwrap();
    for (a, b) in blocked.iter().zip(whole.iter()) {
        assert!((a - b).norm() <= 1e-5 * b.norm().max(1.0), "{a} vs {b}");
    }
}

/// The block-wise filter equals each block filtered on its own (its own Gram matrix, summed
/// over its own pixels) and tent-blended by hand: the cells' shared Gram matrices add up to
/// each block's, the last blocks (flush with the edges, off the half-block steps) included.
#[test]
fn block_filter_is_each_blocks_own_filter_blended() {
    let (nz, nx, nf) = (23, 19, 24);
    let series = still_tissue_slow_layers_and_blood((nz, nx, nf));
    let params = ClutterParams {
        low: RankCut::Fixed(2),
        blocks: Some((7, 6)),
        ..ClutterParams::default()
    };
    let mut blocked = series.clone();
    let report = svd_filter(&mut blocked, &params).unwrap();
    let layout = report.block_layout.unwrap();
    // Seven rows made eight, so that the half-block steps tile the rows.
    assert_eq!(layout.size, (8, 6));
    assert_eq!(layout.z_starts, vec![0, 4, 8, 12, 15]);
    assert_eq!(layout.x_starts, vec![0, 3, 6, 9, 12, 13]);
    let own = ClutterParams {
        blocks: None,
        ..params
    };
    assert_blended_by_hand(&blocked, &series, &layout, |block| {
        svd_filter(block, &own).unwrap();
    });
}

/// Asserts that `blocked` is, within 10⁻⁵ of the largest value of `series`, each block of
/// `layout` filtered by `filter` on its own and tent-blended by hand.
fn assert_blended_by_hand(
    blocked: &Array3<Complex32>,
    series: &Array3<Complex32>,
    layout: &BlockLayout,
    filter: impl Fn(&mut Array3<Complex32>),
) {
    let (nz, nx, nf) = series.dim();
    let (rows, cols) = layout.size;
    let mut sums = Array3::<Complex32>::zeros((nz, nx, nf));
    let mut weights = Array2::<f32>::zeros((nz, nx));
    for (z0, x0) in layout.origins() {
        let mut block = series
            .slice(ndarray::s![z0..z0 + rows, x0..x0 + cols, ..])
            .to_owned();
        filter(&mut block);
        for ((i, j, f), v) in block.indexed_iter() {
            let w = tent(i, rows) * tent(j, cols);
            sums[[z0 + i, x0 + j, f]] += v * w;
            if f == 0 {
                weights[[z0 + i, x0 + j]] += w;
            }
        }
    }
    let largest = series.iter().map(|v| v.norm()).fold(0.0, f32::max);
    for ((z, x, f), v) in blocked.indexed_iter() {
        let expected = sums[[z, x, f]] / weights[[z, x]];
        assert!(
            (v - expected).norm() <= 1e-5 * largest,
            "({z}, {x}, {f}): {v} vs {expected}"
        );
    }
}

/// Blocks over a series with no tissue (the whole image's rule cuts nothing) leave it bit for
/// bit, each block reported as keeping every component.
#[test]
fn blocks_over_blood_alone_leave_the_series_bit_for_bit() {
    let series = toned((16, 14, 20), 4, |z, _| vec![(1.0, 3.0 + (z % 3) as f32)]);
    let mut blocked = series.clone();
    let params = ClutterParams {
        blocks: Some((6, 6)),
        ..ClutterParams::default()
    };
    let report = svd_filter(&mut blocked, &params).unwrap();
    assert_eq!(blocked, series);
    let layout = report.block_layout.unwrap();
    assert_eq!(
        report.block_cut_offs,
        vec![(0, 20); layout.z_starts.len() * layout.x_starts.len()]
    );
}

/// The Gram matrix is the same bit for bit on one core and on several, and equals the product
/// summed in double precision by hand: the chunks' sums are added in an order the data fix.
#[test]
fn gram_matrix_is_the_same_on_any_number_of_cores() {
    let (pixels, frames) = (GRAM_CHUNK * 37 + 123, 7);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let normal = Normal::new(0.0f32, 1.0).unwrap();
    let data: Vec<Complex32> = (0..pixels * frames)
        .map(|_| Complex32::new(normal.sample(&mut rng), normal.sample(&mut rng)) * 1e3)
        .collect();
    let on = |threads: usize| crate::core::parallel::on_threads(threads, || gram_of(&data, frames));
    let one = on(1);
    for threads in [2, 3, 5] {
        for _ in 0..3 {
            assert!(on(threads) == one, "{threads} threads");
        }
    }
    for i in 0..frames {
        for j in 0..=i {
            let by_hand: c64 = (0..pixels)
                .map(|p| {
                    let (a, b) = (data[p * frames + i], data[p * frames + j]);
                    c64::new(a.re as f64, -a.im as f64) * c64::new(b.re as f64, b.im as f64)
                })
                .sum();
            let got = one[(i, j)];
            assert!(
                (got - by_hand).norm() <= 1e-9 * by_hand.norm().max(1.0),
                "{i} {j}"
            );
        }
    }
}

/// The whole image's Gram matrix summed from the blocks' cells equals the one summed over its
/// pixels (within rounding), and the blocks' filter gives the same series bit for bit whether
/// it keeps every cell's Gram matrix from the whole image's cut-off to the blocks, some of them,
/// or none (summing each again for the blocks).
#[test]
fn cells_sum_to_the_whole_gram_and_kept_cells_filter_as_recomputed_ones() {
    let (nz, nx, nf) = (23, 19, 24);
    let series = still_tissue_slow_layers_and_blood((nz, nx, nf));
    let layout = BlockLayout::new((nz, nx), holding_frames((nz, nx), (7, 6), nf));
    let z_cuts = cell_edges(&layout.z_starts, layout.size.0);
    let x_cuts = cell_edges(&layout.x_starts, layout.size.1);
    let scratch = &mut ClutterScratch::default();
    let (of_cells, kept) = whole_gram_of_cells(&series, &z_cuts, &x_cuts, usize::MAX, scratch);
    assert_eq!(kept.len(), z_cuts.len() - 1, "every row of cells kept");
    let of_pixels = gram_of(series.as_slice().unwrap(), nf);
    let largest = of_pixels[(0, 0)].norm();
    for j in 0..nf {
        for i in j..nf {
            assert!(
                (of_cells[(i, j)] - of_pixels[(i, j)]).norm() <= 1e-12 * largest,
                "({i}, {j}): {} vs {}",
                of_cells[(i, j)],
                of_pixels[(i, j)]
            );
        }
    }
    let row_bytes = (x_cuts.len() - 1) * LowerHalf::bytes(nf);
    let (_, two_rows) = whole_gram_of_cells(&series, &z_cuts, &x_cuts, 2 * row_bytes + 1, scratch);
    assert_eq!(two_rows.keys().copied().collect::<Vec<_>>(), vec![0, 1]);

    let params = ClutterParams {
        blocks: Some((7, 6)),
        ..ClutterParams::default()
    };
    let filtered = |kept_bytes: usize, scratch: &mut ClutterScratch| {
        let mut blocked = series.clone();
        let report =
            filter_blocks_keeping(&mut blocked, &params, (7, 6), kept_bytes, scratch).unwrap();
        (blocked, report)
    };
    let (none, none_report) = filtered(0, &mut ClutterScratch::default());
    assert!(none_report.low > 0, "the tissue is cut");
    let cells = (z_cuts.len() - 1) * (x_cuts.len() - 1);
    // One scratch through every run, its buffers holding the runs before's matrices.
    let scratch = &mut ClutterScratch::default();
    for kept_bytes in [2 * row_bytes + 1, usize::MAX, 0, usize::MAX] {
        let (some, report) = filtered(kept_bytes, scratch);
        assert_eq!(report, none_report, "{kept_bytes} bytes kept");
        assert!(some == none, "{kept_bytes} bytes kept: the series differ");
        // Every buffer went back, and no more were made than the cells ask for at once.
        assert!(scratch.spare_buffers() > 0 && scratch.spare_buffers() <= cells);
    }
}

/// The clutter filter gives the same series and report with memory reused from a series
/// filtered before (another image, more frames) as with fresh memory, block-wise and whole.
#[test]
fn reused_scratch_filters_as_fresh_memory() {
    let before = toned((20, 15, 30), 3, |z, _| {
        vec![(50.0, 0.2), (1.0, 2.0 + z as f32)]
    });
    let series = still_tissue_slow_layers_and_blood((23, 19, 24));
    for blocks in [None, Some((7, 6))] {
        let params = ClutterParams {
            blocks,
            ..ClutterParams::default()
        };
        let mut fresh = series.clone();
        let fresh_report = svd_filter(&mut fresh, &params).unwrap();
        let scratch = &mut ClutterScratch::default();
        svd_filter_reusing(&mut before.clone(), &params, scratch).unwrap();
        let mut reused = series.clone();
        let report = svd_filter_reusing(&mut reused, &params, scratch).unwrap();
        assert_eq!(report, fresh_report, "{blocks:?}");
        assert!(reused == fresh, "{blocks:?}: the series differ");
    }
}

/// The cut-offs refused before imaging are exactly those the filter refuses: every fixed or
/// open pair on a series of 6 frames, checked both ways.
#[test]
fn cut_offs_refused_up_front_are_those_the_filter_refuses() {
    let (nz, nx, nf) = (4, 4, 6);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let normal = Normal::new(0.0f32, 1.0).unwrap();
    let series = Array3::from_shape_simple_fn((nz, nx, nf), || {
        Complex32::new(normal.sample(&mut rng), normal.sample(&mut rng))
    });
    let cuts = std::iter::once(RankCut::Off).chain((0..=nf + 1).map(RankCut::Fixed));
    let mut refused = 0;
    for low in cuts.clone() {
        for high in cuts.clone() {
            let params = ClutterParams {
                low,
                high,
                ..ClutterParams::default()
            };
            let up_front = params.check_for(nf);
            let filtered = svd_filter(&mut series.clone(), &params);
            assert_eq!(
                up_front.is_err(),
                filtered.is_err(),
                "{low:?} {high:?}: {up_front:?} / {filtered:?}"
            );
            refused += usize::from(up_front.is_err());
        }
    }
    assert!(refused > 10, "{refused}");
    // Half the frames cut with no noise cut-off reads only the leading vectors; cut with the
    // noise cut-off at the last frame (the same projection) it reads the whole spectrum.
    let filtered = |high| {
        let mut s = series.clone();
        let params = ClutterParams {
            low: RankCut::Fixed(nf / 2),
            high,
            ..ClutterParams::default()
        };
        svd_filter(&mut s, &params).unwrap();
        s
    };
    let (leading, whole) = (filtered(RankCut::Off), filtered(RankCut::Fixed(nf)));
    let scale = whole.iter().fold(0.0f32, |m, v| m.max(v.norm()));
    let worst = leading
        .iter()
        .zip(&whole)
        .fold(0.0f32, |m, (a, b)| m.max((a - b).norm()));
    assert!(worst <= 1e-5 * scale, "{worst} of {scale}");
}

/// A Hermitian positive semi-definite matrix with the given eigenvalues (largest first) in a
/// random orthonormal basis: Q·diag(values)·Qᴴ.
fn with_eigenvalues(values: &[f64], seed: u64) -> Mat<c64> {
    let n = values.len();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let normal = Normal::new(0.0, 1.0).unwrap();
    let random = Mat::<c64>::from_fn(n, n, |_, _| {
        c64::new(normal.sample(&mut rng), normal.sample(&mut rng))
    });
    let q = random.qr().compute_Q();
    let scaled = Mat::<c64>::from_fn(n, n, |i, k| q[(i, k)] * values[k]);
    &scaled * q.adjoint()
}

/// Where the leading eigenpairs decide the tissue rule, Krylov iteration gives the spectrum the
/// reduction to tridiagonal form gives: the same leading eigenvalues (to 10⁻¹² of the largest),
/// the same count of tissue components and the same subspace (projectors to 10⁻⁹), for a
/// block's cap of one, of three and none; on the Gram matrix of a series of 400 frames of still
/// tissue, slow layers and blood.
#[test]
fn krylov_spectrum_decides_the_tissue_rule_as_the_reduction_does() {
    let series = still_tissue_slow_layers_and_blood((12, 14, 400));
    let gram = gram_of(series.as_slice().unwrap(), 400);
    let params = ClutterParams::default();
    for cap in [Some(1), Some(3), None] {
        let Some(krylov) = Spectrum::leading_by_krylov(&gram, cap) else {
            assert_eq!(cap, None, "the bound decides with a cap of {cap:?}");
            continue;
        };
        let reduced = Spectrum::found(&gram, &params, cap, false, false).unwrap();
        let largest = reduced.eigenvalues[0];
        for (k, (a, b)) in krylov
            .eigenvalues
            .iter()
            .zip(&reduced.eigenvalues)
            .enumerate()
        {
            assert!(
                (a - b).abs() <= 1e-12 * largest,
                "eigenvalue {k}: {a} vs {b}"
            );
        }
        let count =
            |s: &Spectrum| strong_and_steep(&s.eigenvalues, s.median, 400).min(cap.unwrap_or(400));
        assert_eq!(count(&krylov), count(&reduced), "cap {cap:?}");
        assert!(count(&krylov) >= 1, "the still tissue is cut");
        assert!(
            krylov.median >= reduced.median,
            "the bound is above the median"
        );
        let projector = |v: &Mat<c64>| v * v.adjoint();
        let difference = (projector(&krylov.vectors) - projector(&reduced.vectors)).norm_max();
        assert!(
            difference < 1e-9,
            "cap {cap:?}: projectors differ by {difference}"
        );
    }
}

/// Where the bound of the median does not decide, Krylov iteration gives way to the reduction:
/// a first component more than twice the next (steep) and 100 times the median (strong), over a
/// plateau of 99 components 30 times the median that lifts the mean of the ranks above the
/// median to 15 times it.
#[test]
fn krylov_gives_way_where_the_bound_of_the_median_does_not_decide() {
    let values: Vec<f64> = (0..400)
        .map(|k| match k {
            0 => 100.0,
            1 => 40.0,
            2..=100 => 30.0,
            _ => 1.0,
        })
        .collect();
    let gram = with_eigenvalues(&values, 9);
    assert!(Spectrum::leading_by_krylov(&gram, Some(1)).is_none());
    let spectrum = Spectrum::of(&gram, &ClutterParams::default(), Some(1), false).unwrap();
    assert!((spectrum.median - 1.0).abs() < 1e-9, "{}", spectrum.median);
    assert_eq!(
        strong_and_steep(&spectrum.eigenvalues, spectrum.median, 400),
        1
    );
    // Without the plateau the bound decides, and says the same.
    let flat: Vec<f64> = (0..400).map(|k| if k == 0 { 100.0 } else { 1.0 }).collect();
    let krylov = Spectrum::leading_by_krylov(&with_eigenvalues(&flat, 9), Some(1)).unwrap();
    assert_eq!(strong_and_steep(&krylov.eigenvalues, krylov.median, 400), 1);
}

/// Blocks of a long series (400 frames, where each block's tissue rule reads its leading
/// eigenpairs by Krylov iteration) filter as each block's own whole filter (every eigenvalue,
/// the full decomposition) blended by hand: the same cut-off in every block, the series within
/// 10⁻⁵ of its largest value.
#[test]
fn blocks_of_a_long_series_filter_as_each_blocks_own_whole_filter() {
    let (nz, nx, nf) = (40, 40, 400);
    let series = toned((nz, nx, nf), 21, |z, x| {
        vec![(40.0, 0.0), (1.0, 40.0 + (x % 5) as f32 + z as f32 / 8.0)]
    });
    let params = ClutterParams {
        blocks: Some((20, 20)),
        ..ClutterParams::default()
    };
    let mut blocked = series.clone();
    let report = svd_filter(&mut blocked, &params).unwrap();
    let layout = report.block_layout.clone().unwrap();
    assert_eq!(layout.size, (20, 20));
    assert!(
        report.block_cut_offs.iter().all(|&(low, _)| low == 1),
        "{report:?}"
    );
    let own = ClutterParams {
        blocks: None,
        ..params
    };
    assert_blended_by_hand(&blocked, &series, &layout, |block| {
        assert_eq!(svd_filter(block, &own).unwrap().low, 1);
    });
}
