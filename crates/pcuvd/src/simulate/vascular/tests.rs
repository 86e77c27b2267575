//! Tests of the solver, tables and generator together.

use num_complex::Complex64;

use super::*;

const PI: f64 = std::f64::consts::PI;

fn pressure(vertex: usize, value: f64, pulse: f64) -> Boundary {
    Boundary {
        vertex,
        kind: BoundaryKind::Pressure,
        value,
        pulse,
    }
}

/// One straight tube along z from 1 mm to 1 + `length` mm, both ends at fixed pressures.
fn tube(d: f64, length: f64, p_in: f64, p_out: f64) -> VesselGraph {
    VesselGraph {
        vertices: vec![[0.0, 0.0, 1e-3], [0.0, 0.0, 1e-3 + length]],
        edges: vec![Edge {
            v1: 0,
            v2: 1,
            diameter: d,
            length: None,
            class: VesselClass::Arteriole,
        }],
        boundaries: vec![pressure(0, p_in, 0.0), pressure(1, p_out, 0.0)],
    }
}

/// Largest |net flow| (relative to the largest segment flow there) over every vertex without a
/// boundary condition and every harmonic.
fn worst_conservation(graph: &VesselGraph, flow: &VascularFlow) -> f64 {
    let boundary = graph.boundary_index();
    let n_k = flow.pressure[0].len();
    let mut worst: f64 = 0.0;
    for v in (0..graph.vertices.len()).filter(|&v| boundary[v].is_none()) {
        for k in 0..n_k {
            let scale = flow
                .segments
                .iter()
                .filter(|s| s.v1 == v || s.v2 == v)
                .map(|s| {
                    if k == 0 {
                        s.mean_flow.abs()
                    } else {
                        s.harmonics[k - 1].norm()
                    }
                })
                .fold(0.0, f64::max);
            if scale > 0.0 {
                worst = worst.max(flow.junction_residual(v, k).norm() / scale);
            }
        }
    }
    worst
}

fn small_cortex(seed: u64) -> CortexParams {
    CortexParams {
        width: 3e-3,
        seed,
        ..CortexParams::default()
    }
}

#[test]
fn single_tube_carries_the_poiseuille_flow() {
    let (d, l, dp) = (40e-6, 1.5e-3, 4000.0);
    let g = tube(d, l, 5000.0, 1000.0);
    let flow = solve(&g, &FlowParams::rat()).unwrap();
    let analytic = dp * PI * d.powi(4) / (128.0 * DEFAULT_VISCOSITY * l);
    let s = &flow.segments[0];
    assert!(
        (s.mean_flow / analytic - 1.0).abs() < 1e-12,
        "{}",
        s.mean_flow
    );
    // Steady boundaries: no pulse, centreline speed twice the mean.
    assert!(s.harmonics.iter().all(|q| q.norm() < 1e-30));
    let mean = analytic / (PI * d * d / 4.0);
    assert!((s.centreline_speed(0.03) - 2.0 * mean).abs() < 1e-12 * mean);
    assert_eq!(s.pulsatility.ri, 0.0);
}

#[test]
fn inflow_condition_sets_the_flow() {
    let mut g = tube(20e-6, 1e-3, 0.0, 1000.0);
    g.boundaries[0] = Boundary {
        vertex: 0,
        kind: BoundaryKind::Inflow,
        value: 2e-12,
        pulse: 1e-12,
    };
    let swing = |params: &FlowParams| {
        let flow = solve(&g, params).unwrap();
        let s = &flow.segments[0];
        assert!((s.mean_flow - 2e-12).abs() < 1e-24);
        let (lo, hi) = (0..2048)
            .map(|i| s.flow(i as f64 / 2048.0 / 5.5))
            .fold((f64::MAX, f64::MIN), |(a, b), q| (a.min(q), b.max(q)));
        hi - lo
    };
    assert!((swing(&FlowParams::rat().rigid()) - 1e-12).abs() < 1e-18);
    // The inlet vertex's compliance stores part of the pulse: the tube's swing is smaller.
    let mut params = FlowParams::rat();
    params.wave_speed = [0.7; 3];
    let s = swing(&params);
    assert!(s < 0.9e-12 && s > 0.1e-12, "{s}");
}

#[test]
fn parallel_tubes_split_the_flow_as_one_over_r() {
    let mut g = tube(30e-6, 1e-3, 6000.0, 1500.0);
    g.edges.push(Edge {
        diameter: 18e-6,
        length: Some(1.7e-3),
        ..g.edges[0]
    });
    let params = FlowParams::rat();
    let flow = solve(&g, &params).unwrap();
    let (a, b) = (&flow.segments[0], &flow.segments[1]);
    let ratio = a.mean_flow / b.mean_flow;
    let expected = params.resistance(18e-6, 1.7e-3) / params.resistance(30e-6, 1e-3);
    assert!(
        (ratio / expected - 1.0).abs() < 1e-12,
        "{ratio} vs {expected}"
    );
    assert!((a.resistance - params.resistance(30e-6, 1e-3)).abs() < 1e-9 * a.resistance);
}

#[test]
fn a_single_rc_windkessel_matches_its_transfer_function() {
    // One resistor (the tube) and one capacitor to ground (its far, dead-end vertex holds half
    // the tube's compliance): P₁/P₀ = 1 / (1 + iωRC) at every harmonic.
    let mut g = tube(40e-6, 2e-3, 5000.0, 0.0);
    g.boundaries.truncate(1);
    g.boundaries[0].pulse = 3000.0;
    let mut params = FlowParams::rat();
    params.wave_speed = [0.05; 3];
    let flow = solve(&g, &params).unwrap();
    let s = &flow.segments[0];
    let (r, c) = (s.resistance, flow.node_compliance[1]);
    assert!((c - s.compliance / 2.0).abs() < 1e-30);
    for k in 1..=3 {
        let w = k as f64 * flow.omega;
        let h = flow.pressure[1][k] / flow.pressure[0][k];
        let analytic = 1.0 / (1.0 + (w * r * c).powi(2)).sqrt();
        assert!(
            (h.norm() - analytic).abs() < 1e-12,
            "k={k}: {} vs {analytic}",
            h.norm()
        );
        assert!((h.arg() + (w * r * c).atan()).abs() < 1e-12);
    }
    assert!(
        flow.omega * r * c > 0.3,
        "the test should probe the roll-off"
    );
    // A dead end carries no mean flow, and its RI is undefined.
    assert!(s.mean_flow.abs() < 1e-25);
    assert!(s.pulsatility.ri.is_nan());
}

#[test]
fn flow_is_conserved_at_every_junction() {
    let params = FlowParams::rat();
    for g in [
        example(),
        generate(&small_cortex(4)).unwrap(),
        generate(&small_brain(4)).unwrap(),
    ] {
        let flow = solve(&g, &params).unwrap();
        let worst = worst_conservation(&g, &flow);
        assert!(worst < 1e-9, "relative imbalance {worst:e}");
        // Steady: what enters the network leaves it.
        let boundary = g.boundary_index();
        let through: f64 = (0..g.vertices.len())
            .filter(|&v| boundary[v].is_some())
            .map(|v| flow.junction_residual(v, 0).re)
            .sum();
        let inflow = flow.segments[0].mean_flow.abs();
        assert!(through.abs() < 1e-9 * inflow, "{through:e}");
    }
}

#[test]
fn a_rigid_tree_carries_the_same_ri_everywhere() {
    let g = example();
    let flow = solve(&g, &FlowParams::rat().rigid()).unwrap();
    let ri0 = flow.segments[0].pulsatility.ri;
    assert!(ri0 > 0.3, "{ri0}");
    for s in &flow.segments {
        assert!(
            (s.pulsatility.ri - ri0).abs() < 1e-9,
            "segment {}: {}",
            s.id,
            s.pulsatility.ri
        );
        assert!(s.pulsatility.delay_s.abs() < 1e-12);
    }
}

#[test]
fn compliance_lowers_ri_from_arteriole_to_venule_with_a_delay() {
    let g = example();
    let flow = solve(&g, &FlowParams::rat()).unwrap();
    let seg = |v1, v2| {
        let s = flow
            .segments
            .iter()
            .find(|s| s.v1 == v1 && s.v2 == v2)
            .unwrap();
        s.pulsatility
    };
    let (inlet, capillary, outlet) = (seg(0, 1), seg(3, 5), seg(8, 9));
    assert!(
        (0.55..0.9).contains(&inlet.ri),
        "inlet arteriole RI {}",
        inlet.ri
    );
    assert!(inlet.ri > capillary.ri && capillary.ri > outlet.ri);
    assert!(outlet.ri < 0.5, "outlet venule RI {}", outlet.ri);
    assert!(outlet.delay_s > capillary.delay_s && capillary.delay_s > inlet.delay_s);
    assert!(
        outlet.delay_s - inlet.delay_s > 1e-3,
        "{outlet:?} {inlet:?}"
    );
}

#[test]
fn displacement_is_the_exact_integral_of_the_speed() {
    let flow = solve(&example(), &FlowParams::rat()).unwrap();
    let s = &flow.segments[1];
    let t_end = 0.29;
    let n = 20_000;
    let h = t_end / n as f64;
    // Simpson's rule, independent of the closed form.
    let mut sum = s.centreline_speed(0.0) + s.centreline_speed(t_end);
    for i in 1..n {
        sum += s.centreline_speed(i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
    }
    let simpson = sum * h / 3.0;
    let exact = s.centreline_displacement(t_end);
    assert!(
        (exact - simpson).abs() < 1e-12 * exact.abs(),
        "{exact} {simpson}"
    );
    assert_eq!(s.centreline_displacement(0.0), 0.0);
}

#[test]
fn velocity_is_laminar_along_the_segment() {
    let flow = solve(&example(), &FlowParams::rat()).unwrap();
    let s = &flow.segments[1]; // arteriole 1 → 2, running down and to −x
    let (a, b) = (s.start, s.end);
    let mid = [
        (a[0] + b[0]) / 2.0,
        (a[1] + b[1]) / 2.0,
        (a[2] + b[2]) / 2.0,
    ];
    let t = 0.05;
    let v = s.velocity_at(&mid, t).unwrap();
    let u = s.direction();
    let c = s.centreline_speed(t);
    for k in 0..3 {
        assert!((v[k] - c * u[k]).abs() < 1e-15);
    }
    assert!((v[0] < 0.0 && v[2] > 0.0) == (c > 0.0), "{v:?}");
    // Half a radius off the axis (along y, normal to this segment): 3/4 of the centreline.
    let off = [mid[0], mid[1] + s.diameter / 4.0, mid[2]];
    let v = s.velocity_at(&off, t).unwrap();
    let speed = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    assert!((speed - 0.75 * c).abs() < 1e-12 * c);
    assert!(
        s.velocity_at(&[mid[0], mid[1] + s.diameter, mid[2]], t)
            .is_none()
    );
    assert_eq!(flow.velocity_at(&mid, t).map(|(id, _)| id), Some(1));
    // A segment drawn against its flow reads negative speeds, but its RI is of the magnitude.
    let mut g = example();
    let e = &mut g.edges[0];
    (e.v1, e.v2) = (e.v2, e.v1);
    let reversed = solve(&g, &FlowParams::rat()).unwrap();
    let (fwd, rev) = (&flow.segments[0], &reversed.segments[0]);
    assert!(rev.centreline_speed(t) < 0.0);
    assert!((rev.centreline_speed(t) + fwd.centreline_speed(t)).abs() < 1e-12);
    assert!((rev.pulsatility.ri - fwd.pulsatility.ri).abs() < 1e-12);
    assert!((rev.centreline_displacement(t) + fwd.centreline_displacement(t)).abs() < 1e-15);
}

#[test]
fn pries_viscosity_law() {
    // At the reference haematocrit the law is μ_0.45 itself, e.g. 3.2 − 2.44 e^{−0.06·D^0.645}
    // + 220 e^{−1.3 D}: 1.328 at 10 µm, 2.20 at 50 µm, 3.18 in wide tubes.
    let mu45 = |d: f64| 220.0 * (-1.3 * d).exp() + 3.2 - 2.44 * (-0.06 * d.powf(0.645)).exp();
    for d in [5.0, 10.0, 50.0, 150.0, 1000.0] {
        assert!((pries_relative_viscosity(d, 0.45) - mu45(d)).abs() < 1e-12);
        assert!((pries_relative_viscosity(d, 0.0) - 1.0).abs() < 1e-12);
    }
    assert!((pries_relative_viscosity(10.0, 0.45) - 1.3285).abs() < 1e-3);
    assert!((pries_relative_viscosity(1000.0, 0.45) - 3.186).abs() < 2e-3);
    // Fåhraeus–Lindqvist: thinner (down to ~7 µm) is less viscous; more cells, more viscous.
    let mut last = f64::INFINITY;
    for d in [300.0, 150.0, 80.0, 40.0, 20.0, 10.0, 7.0] {
        let mu = pries_relative_viscosity(d, 0.45);
        assert!(mu < last, "{d} µm: {mu}");
        last = mu;
        assert!(pries_relative_viscosity(d, 0.3) < mu && pries_relative_viscosity(d, 0.6) > mu);
    }
    let v = Viscosity::PriesInVitro {
        plasma: 1.2e-3,
        hematocrit: 0.45,
    };
    assert!((v.at(10e-6) - 1.2e-3 * mu45(10.0)).abs() < 1e-15);
    let mut params = FlowParams::rat();
    params.viscosity = v;
    assert!(solve(&example(), &params).is_ok());
    params.viscosity = Viscosity::PriesInVitro {
        plasma: 1.2e-3,
        hematocrit: 1.2,
    };
    assert!(solve(&example(), &params).is_err());
}

#[test]
fn cardiac_pulse_is_swing_normalised() {
    let p = CardiacPulse::rat();
    let (lo, hi) = (0..4096)
        .map(|i| p.value(i as f64 * p.period() / 4096.0))
        .fold((f64::MAX, f64::MIN), |(a, b), v| (a.min(v), b.max(v)));
    assert!((hi - lo - 1.0).abs() < 1e-12, "{}", hi - lo);
    assert!((hi - 11.0 / 16.0).abs() < 1e-12);
    let q = CardiacPulse::new(6.0, vec![Complex64::new(0.0, 3.0)]).unwrap();
    assert!((q.harmonics()[0].norm() - 0.5).abs() < 1e-6);
    assert!(CardiacPulse::new(0.0, vec![]).is_err());
    assert!(CardiacPulse::new(5.0, vec![Complex64::new(f64::NAN, 0.0)]).is_err());
    let steady = FlowParams {
        pulse: CardiacPulse::new(5.5, vec![]).unwrap(),
        ..FlowParams::rat()
    };
    let flow = solve(&example(), &steady).unwrap();
    assert!(flow.segments.iter().all(|s| s.pulsatility.ri.abs() < 1e-12));
}

#[test]
fn the_example_parses_in_micrometres_and_solves() {
    let g = example();
    assert_eq!(
        (g.vertices.len(), g.edges.len(), g.boundaries.len()),
        (11, 13, 2)
    );
    assert_eq!(g.vertices[1], [0.0, 0.0, 1400e-6]);
    assert_eq!(g.edges[3].length, Some(260e-6));
    assert_eq!(g.edges[0].length, None);
    assert!((g.length(&g.edges[0]) - 400e-6).abs() < 1e-15);
    let flow = solve(&g, &FlowParams::rat()).unwrap();
    // Every segment carries blood from its v1 to its v2, as drawn, but for the anastomosis 4–10
    // between two capillary paths, where little flows either way.
    for s in &flow.segments {
        if s.id == 9 {
            assert!(s.mean_flow.abs() < 0.05 * flow.segments[3].mean_flow);
        } else {
            assert!(s.mean_flow > 0.0, "segment {} ({:?})", s.id, s.class);
        }
    }
}

#[test]
fn tables_round_trip_bit_for_bit() {
    let g = generate(&small_cortex(2)).unwrap();
    let t = write_tables(&g);
    let back = parse_tables(&t.vertices, &t.edges, &t.boundary).unwrap();
    assert_eq!(back, g);
    let mut e = example();
    e.boundaries[1].kind = BoundaryKind::Inflow;
    e.boundaries[1].value = -1e-13;
    e.boundaries.push(pressure(8, 1000.0, 0.0));
    let t = write_tables(&e);
    assert_eq!(parse_tables(&t.vertices, &t.edges, &t.boundary).unwrap(), e);
}

#[test]
fn bad_table_rows_are_named() {
    let t = example_tables();
    let err = |v: &str, e: &str, b: &str| parse_tables(v, e, b).unwrap_err().to_string();
    let vertices = t.vertices.replace("-80,0,1600", "-80,zero,1600");
    let e = err(&vertices, &t.edges, &t.boundary);
    assert!(
        e.contains("vertices.csv") && e.contains("line 7, column 2 (y_um)") && e.contains("zero"),
        "{e}"
    );
    let edges = t
        .edges
        .replace("1,3,23.81,,arteriole", "1,3,23.81,arteriole");
    let e = err(&t.vertices, &edges, &t.boundary);
    assert!(
        e.contains("edges.csv") && e.contains("line 6 has 4 cells"),
        "{e}"
    );
    let edges = t.edges.replace("1,3,23.81", "1,31,23.81");
    let e = err(&t.vertices, &edges, &t.boundary);
    assert!(
        e.contains("line 6, column 2 (v2)") && e.contains("11"),
        "{e}"
    );
    let edges = t.edges.replace("1,3,23.81", "1,3,-2");
    let e = err(&t.vertices, &edges, &t.boundary);
    assert!(
        e.contains("column 3 (diameter_um)") && e.contains("> 0"),
        "{e}"
    );
    let edges = t.edges.replace("0,1,30,,arteriole", "0,1,30,,aorta");
    let e = err(&t.vertices, &edges, &t.boundary);
    assert!(
        e.contains("line 4, column 5 (class)") && e.contains("aorta"),
        "{e}"
    );
    let e = err(
        &t.vertices,
        "v1,v2,diameter_um,class\n0,1,30,artery\n",
        &t.boundary,
    );
    assert!(e.contains("vertex 2 belongs to no edge"), "{e}");
    let e = err(
        &t.vertices,
        &t.edges.replace("diameter_um", "d"),
        &t.boundary,
    );
    assert!(e.contains("edges.csv") && e.contains("diameter_um"), "{e}");
    let boundary = t.boundary.replace("9,pressure", "9,suction");
    let e = err(&t.vertices, &t.edges, &boundary);
    assert!(
        e.contains("boundary.csv") && e.contains("column 2 (type)"),
        "{e}"
    );
    let e = err("", &t.edges, &t.boundary);
    assert!(e.contains("vertices.csv") && e.contains("header"), "{e}");
    let e = err(&t.vertices, &t.edges, "vertex,value\n0,6666\n");
    assert!(
        e.contains("boundary.csv") && e.contains("no column `type`"),
        "{e}"
    );
    let e = err(
        &t.vertices,
        &t.edges,
        "vertex,type,value\n0,pressure,6666\n0,flow,1e-12\n",
    );
    assert!(e.contains("vertex 0 has two conditions"), "{e}");
}

#[test]
fn generated_branchings_obey_murrays_law() {
    let g = generate(&small_brain(7)).unwrap();
    let mut checked = 0;
    for v in 0..g.vertices.len() {
        let incident: Vec<&Edge> = g.edges.iter().filter(|e| e.v1 == v || e.v2 == v).collect();
        // Branchings of the arteriole and venule trees; the capillary bed is a mesh, not a tree.
        if incident.len() < 3 || incident.iter().any(|e| e.class == VesselClass::Capillary) {
            continue;
        }
        let cubes: Vec<f64> = incident.iter().map(|e| e.diameter.powi(3)).collect();
        let parent = cubes.iter().cloned().fold(0.0, f64::max);
        let children: f64 = cubes.iter().sum::<f64>() - parent;
        assert!((parent - children).abs() < 1e-9 * parent, "vertex {v}");
        checked += 1;
    }
    assert!(checked >= 10, "{checked}");
    for e in &g.edges {
        let d = e.diameter * 1e6;
        match e.class {
            VesselClass::Capillary => assert_eq!(d, 8.0),
            _ => assert!((10.0..=150.0).contains(&d), "{d} µm"),
        }
    }
}

#[test]
fn the_generator_is_deterministic_and_penetrates_near_normally() {
    let p = small_cortex(11);
    let a = generate(&p).unwrap();
    assert_eq!(a, generate(&p).unwrap());
    assert_ne!(a, generate(&small_cortex(12)).unwrap());
    // Trunk segments (arteriole and venule edges that are mostly vertical) stay within the
    // drawn tilt (≤ 5° in x and in y, so ≤ 7.1° from the normal).
    let mut trunks = 0;
    for e in g_noncapillary(&a) {
        let (p1, p2) = (a.vertices[e.v1], a.vertices[e.v2]);
        let dz = (p2[2] - p1[2]).abs();
        if dz > 0.9 * a.chord(e) {
            assert!(dz >= a.chord(e) * 7.1f64.to_radians().cos(), "{e:?}");
            trunks += 1;
        }
    }
    assert!(trunks > 10);
    // Within the slab and the cortex.
    for v in &a.vertices {
        assert!(v[1].abs() <= 0.25e-3 && v[2] >= 1e-3 - 1e-12 && v[2] <= 3e-3);
    }
    assert!(
        generate(&CortexParams {
            width: 1e-3,
            ..p.clone()
        })
        .is_err()
    );
    assert!(
        generate(&CortexParams {
            inlet_pressure: 0.0,
            ..p.clone()
        })
        .is_err()
    );
    // A slab thicker than a rat brain (here metres) is refused, naming the key; the largest kept.
    let thick = generate(&CortexParams {
        slab_thickness: 3.0,
        ..p.clone()
    })
    .unwrap_err()
    .to_string();
    assert!(
        thick.contains("slab thickness") && thick.contains("3000.0 mm"),
        "{thick}"
    );
    assert!(
        CortexParams {
            slab_thickness: super::generator::MAX_SLAB_THICKNESS,
            ..p
        }
        .validate()
        .is_ok()
    );
}

fn g_noncapillary(g: &VesselGraph) -> impl Iterator<Item = &Edge> {
    g.edges.iter().filter(|e| e.class != VesselClass::Capillary)
}

#[test]
fn the_generated_cortex_has_arteriole_and_venule_pulsatility() {
    let g = generate(&small_cortex(3)).unwrap();
    let flow = solve(&g, &FlowParams::rat()).unwrap();
    let median = |class: VesselClass, f: &dyn Fn(&Pulsatility) -> f64| {
        let mut v: Vec<f64> = flow
            .segments
            .iter()
            .filter(|s| s.class == class)
            .map(|s| f(&s.pulsatility))
            .filter(|x| x.is_finite())
            .collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let ri = |p: &Pulsatility| p.ri;
    let delay = |p: &Pulsatility| p.delay_s;
    let (a, c, v) = (
        median(VesselClass::Arteriole, &ri),
        median(VesselClass::Capillary, &ri),
        median(VesselClass::Venule, &ri),
    );
    assert!(
        (0.55..0.9).contains(&a) && a > c && c > v && v < 0.5,
        "{a} {c} {v}"
    );
    assert!(median(VesselClass::Venule, &delay) > median(VesselClass::Arteriole, &delay));
    assert_flowing_under_nyquist(&flow.segments);
}

/// Every segment carries blood, and none faster than the rat sequence's Nyquist speed.
fn assert_flowing_under_nyquist(segments: &[crate::simulate::vascular::SegmentFlow]) {
    for s in segments {
        assert!(s.mean_flow.abs() > 0.0, "segment {}", s.id);
        assert!(
            s.pulsatility.psv < 0.044,
            "segment {}: {} m/s",
            s.id,
            s.pulsatility.psv
        );
    }
}

/// The small cortex with three deep pairs rising from basal vessels 6 mm deep.
fn small_brain(seed: u64) -> CortexParams {
    CortexParams {
        deep_pairs: 3,
        deep_depth: 6e-3,
        deep_reach: 2.5e-3,
        ..small_cortex(seed)
    }
}

#[test]
fn the_deep_brain_rises_from_its_basal_vessels_and_leaves_the_cortex_as_it_was() {
    let cortex = generate(&small_cortex(5)).unwrap();
    let brain = generate(&small_brain(5)).unwrap();
    // The cortex is drawn first, from the same random stream: the deep brain only adds to it.
    assert_eq!(brain.vertices[..cortex.vertices.len()], cortex.vertices[..]);
    assert_eq!(brain.edges[..cortex.edges.len()], cortex.edges[..]);
    assert_eq!(brain.boundaries.len(), 4);
    let deep = &brain.edges[cortex.edges.len()..];
    let mut rising = 0;
    for e in deep {
        let (p1, p2) = (brain.vertices[e.v1], brain.vertices[e.v2]);
        for p in [p1, p2] {
            // Between the basal vessels and their reach (side branches poke a little further).
            assert!(
                p[2] > 6e-3 - 2.5e-3 - 0.1e-3 && p[2] <= 6e-3 + 1e-12,
                "{p:?}"
            );
        }
        // Arteriole trunks carry blood up from the basal artery, venule trunks down to the vein.
        let dz = p2[2] - p1[2];
        if dz.abs() > 0.9 * brain.chord(e) {
            match e.class {
                VesselClass::Arteriole => assert!(dz < 0.0, "{e:?}"),
                VesselClass::Venule => assert!(dz > 0.0, "{e:?}"),
                VesselClass::Capillary => {}
            }
            rising += 1;
        }
    }
    assert!(rising >= 12, "{rising}");
    let flow = solve(&brain, &FlowParams::rat()).unwrap();
    let worst = worst_conservation(&brain, &flow);
    assert!(worst < 1e-9, "relative imbalance {worst:e}");
    // Its own pulsatility, falling from arterioles to venules, and its speeds under Nyquist.
    let deep_ri = |class: VesselClass| {
        let mut ri: Vec<f64> = flow.segments[cortex.edges.len()..]
            .iter()
            .filter(|s| s.class == class)
            .map(|s| s.pulsatility.ri)
            .collect();
        ri.sort_by(f64::total_cmp);
        ri[ri.len() / 2]
    };
    let (a, v) = (
        deep_ri(VesselClass::Arteriole),
        deep_ri(VesselClass::Venule),
    );
    assert!((0.55..0.9).contains(&a) && v < 0.5, "{a} {v}");
    assert_flowing_under_nyquist(&flow.segments[cortex.edges.len()..]);
    let entering = generate(&CortexParams {
        deep_depth: 4e-3,
        ..small_brain(5)
    });
    assert!(entering.unwrap_err().to_string().contains("cortex"));
}

#[test]
fn the_lumen_lookup_answers_as_testing_every_segment() {
    let flow = solve(&generate(&small_cortex(3)).unwrap(), &FlowParams::rat()).unwrap();
    lookup_answers_as_testing_every_segment(&flow.segments);
}

/// A tree with one segment reaching a hundred kilometres deep (a user's vessel table with one
/// far-off vertex): its lookup stays small and still answers right.
#[test]
fn a_lumen_lookup_over_a_far_reaching_segment_stays_small() {
    let flow = solve(&generate(&small_cortex(3)).unwrap(), &FlowParams::rat()).unwrap();
    let mut segments = flow.segments.clone();
    let last = segments.len() - 1;
    segments[last].end[2] = 1e5;
    let lookup = LumenLookup::new(&segments);
    assert!(
        lookup.cell_count() <= 64 * segments.len() + 64,
        "{} cells for {} segments",
        lookup.cell_count(),
        segments.len()
    );
    lookup_answers_as_testing_every_segment(&segments);
    // Reaching past what any grid could hold, and past what f64 spans: the same answers.
    for far in [1e300, f64::MAX] {
        segments[last].end[2] = far;
        segments[0].start[2] = -far;
        lookup_answers_as_testing_every_segment(&segments);
    }
}

fn lookup_answers_as_testing_every_segment(segments: &[crate::simulate::vascular::SegmentFlow]) {
    let lookup = LumenLookup::new(segments);
    let every = |p: &[f64; 3]| {
        segments.iter().any(|s| {
            let (lo, hi) = s.bounds();
            (0..3).all(|k| p[k] >= lo[k] && p[k] <= hi[k]) && s.local(p).is_some()
        })
    };
    // Points over the tree's extent and past it, and points on the segments' axes and box
    // corners (where rounding decides), every kind held and not held.
    let (lo, hi) = segments.iter().map(|s| s.bounds()).fold(
        ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
        |(lo, hi), (a, b)| {
            (
                std::array::from_fn(|k| lo[k].min(a[k])),
                std::array::from_fn(|k| hi[k].max(b[k])),
            )
        },
    );
    let mut points: Vec<[f64; 3]> = Vec::new();
    let n = 40;
    for i in 0..=n {
        for j in 0..=n / 4 {
            for l in 0..=n {
                let at = |k: usize, t: usize, m: usize| {
                    let span = hi[k] - lo[k];
                    lo[k] - 0.1 * span + 1.2 * span * t as f64 / m as f64
                };
                points.push([at(0, i, n), at(1, j, n / 4), at(2, l, n)]);
            }
        }
    }
    for s in segments {
        let (a, b) = s.bounds();
        let middle: [f64; 3] = std::array::from_fn(|k| 0.5 * (s.start[k] + s.end[k]));
        points.extend([s.start, s.end, middle, a, b]);
    }
    points.push([f64::NAN, 0.0, 1e-3]);
    let held = points.iter().filter(|p| every(p)).count();
    assert!(
        held > 100 && held < points.len() - 100,
        "{held} of {}",
        points.len()
    );
    for p in &points {
        assert_eq!(lookup.holds(p), every(p), "{p:?}");
    }
    assert!(!LumenLookup::new(&[]).holds(&[0.0; 3]));
}
