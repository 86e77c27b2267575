use super::*;
use crate::mat::{NumericClass, write_mat};
use crate::open::read_must_mat;
use std::collections::BTreeMap;

fn param(n: usize) -> BTreeMap<String, MatValue> {
    let mut p = BTreeMap::new();
    for (k, v) in [
        ("fs", 2e7),
        ("fc", 5e6),
        ("c", 1500.0),
        ("pitch", 3e-4),
        ("width", 2.5e-4),
        ("t0", 1e-6),
        ("PRF", 5e3),
        ("Nelements", n as f64),
    ] {
        p.insert(k.to_string(), MatValue::scalar(v));
    }
    p.insert(
        "TXdelay".into(),
        MatValue::double(vec![1, n], vec![0.0; n]).unwrap(),
    );
    p
}

fn rf(dims: Vec<usize>) -> MatValue {
    let n: usize = dims.iter().product();
    MatValue::Numeric {
        class: NumericClass::Int16,
        dims,
        real: (0..n).map(|i| (i % 200) as f64 - 100.0).collect(),
        imag: None,
    }
}

fn write(dir: &Path, rf: &MatValue, p: &BTreeMap<String, MatValue>) -> std::path::PathBuf {
    let path = dir.join("rec.mat");
    let pv = MatValue::Struct(p.clone());
    write_mat(&path, &[("RF", rf), ("param", &pv)], true).unwrap();
    path
}

#[test]
fn reads_a_small_must_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), &rf(vec![10, 4, 3]), &param(4));
    let d = read_must_mat(&path).unwrap();
    let a = &d.acquisition;
    assert_eq!(a.probe.n_elements, 4);
    assert_eq!(a.probe.bandwidth, 0.75);
    assert_eq!(a.probe.name, "from MAT file");
    assert_eq!(a.sequence.angles, vec![0.0]);
    assert_eq!(a.sequence.pulse_cycles, 2.0);
    assert_eq!(a.sampling_frequency, 2e7);
    assert_eq!(a.t0, 1e-6);
    assert_eq!(d.samples.dim(), (3, 4, 10));
    // RF(s, e, t) lands at [t, e, s].
    if let pcuvd::Samples::Rf(x) = &d.samples {
        let s = 7;
        let e = 2;
        let t = 1;
        assert_eq!(
            x[[t, e, s]],
            (((s + 10 * (e + 4 * t)) % 200) as f32) - 100.0
        );
    }
    // 2-D RF is one transmit.
    let path = write(dir.path(), &rf(vec![10, 4]), &param(4));
    assert_eq!(read_must_mat(&path).unwrap().samples.dim(), (1, 4, 10));
}

#[test]
fn steered_transmits_cycle_through_the_angles_of_a_frame() {
    let dir = tempfile::tempdir().unwrap();
    let n = 8;
    let x = Probe {
        name: String::new(),
        n_elements: n,
        pitch: 3e-4,
        element_width: 2.5e-4,
        center_frequency: 5e6,
        bandwidth: 0.7,
    }
    .element_x();
    let c = 1500.0;
    // MUST's txdelay: x·sin θ / c shifted so that the first element fires at 0.
    let law = |deg: f64| -> Vec<f64> {
        let d: Vec<f64> = x.iter().map(|xi| xi * deg.to_radians().sin() / c).collect();
        let min = d.iter().copied().fold(f64::INFINITY, f64::min);
        d.iter().map(|v| v - min).collect()
    };
    let matrix = |rows: &[Vec<f64>]| {
        // MATLAB rows × elements, column-major.
        let r = rows.len();
        let mut v = vec![0.0; r * n];
        for (i, row) in rows.iter().enumerate() {
            for (j, d) in row.iter().enumerate() {
                v[i + r * j] = *d;
            }
        }
        MatValue::double(vec![r, n], v).unwrap()
    };
    let angles = [-5.0, 0.0, 5.0];
    // One row per angle, 6 transmits: two frames of three angles.
    let mut p = param(n);
    p.insert("c".into(), MatValue::scalar(c));
    p.insert("TXdelay".into(), matrix(&angles.map(law)));
    let d = read_must_mat(&write(dir.path(), &rf(vec![10, n, 6]), &p)).unwrap();
    let got: Vec<f64> = d
        .acquisition
        .sequence
        .angles
        .iter()
        .map(|a| a.to_degrees())
        .collect();
    assert_eq!(got.len(), 3);
    for (g, w) in got.iter().zip(angles) {
        assert!((g - w).abs() < 1e-9, "{got:?}");
    }
    assert_eq!(d.n_frames(), 2);
    // One row per transmit, the same cycle: the same frame.
    let rows: Vec<Vec<f64>> = (0..6).map(|i| law(angles[i % 3])).collect();
    p.insert("TXdelay".into(), matrix(&rows));
    let e = read_must_mat(&write(dir.path(), &rf(vec![10, n, 6]), &p)).unwrap();
    assert_eq!(e.acquisition.sequence.angles, d.acquisition.sequence.angles);
    // Transmits that do not cycle through distinct angles are refused.
    let rows: Vec<Vec<f64>> = [0.0, 0.0, 5.0, 5.0, 0.0, 0.0].map(law).to_vec();
    p.insert("TXdelay".into(), matrix(&rows));
    let err = read_must_mat(&write(dir.path(), &rf(vec![10, n, 6]), &p))
        .unwrap_err()
        .to_string();
    assert!(err.contains("same steering angle"), "{err}");
    // Rows that do not divide the transmits are refused with the counts.
    p.insert(
        "TXdelay".into(),
        matrix(&[law(0.0), law(5.0), law(-5.0), law(1.0)]),
    );
    let err = read_must_mat(&write(dir.path(), &rf(vec![10, n, 6]), &p))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("has 4 rows") && err.contains("6 transmits"),
        "{err}"
    );
}

#[test]
fn errors_name_file_field_and_problem() {
    let dir = tempfile::tempdir().unwrap();
    let check = |rf: &MatValue, p: &BTreeMap<String, MatValue>, want: &str| {
        let path = write(dir.path(), rf, p);
        let e = read_must_mat(&path).unwrap_err().to_string();
        assert!(e.starts_with(&path.display().to_string()), "{e}");
        assert!(e.contains(want), "{e} (wanted {want})");
    };
    let mut p = param(4);
    p.remove("fs");
    check(
        &rf(vec![10, 4, 3]),
        &p,
        "variable 'param' has no field 'fs'",
    );
    let mut p = param(4);
    p.insert("fs".into(), MatValue::scalar(-1.0));
    check(&rf(vec![10, 4, 3]), &p, "param.fs must be finite and > 0");
    let mut p = param(4);
    p.insert("pitch".into(), MatValue::scalar(0.0));
    check(&rf(vec![10, 4, 3]), &p, "param.pitch");
    check(
        &rf(vec![10, 5, 3]),
        &param(4),
        "param.Nelements is 4 but RF has 5",
    );
    check(
        &rf(vec![10, 4, 3, 2]),
        &param(4),
        "variable 'RF' must be samples",
    );
    let mut p = param(4);
    p.insert(
        "TXdelay".into(),
        MatValue::double(vec![1, 4], vec![1e-6, 0.0, 0.0, 1e-6]).unwrap(),
    );
    check(
        &rf(vec![10, 4, 3]),
        &p,
        "TXdelay is not a plane-wave delay profile",
    );
    let mut bad = rf(vec![10, 4, 3]);
    if let MatValue::Numeric { class, real, .. } = &mut bad {
        *class = NumericClass::Double;
        real.as_f64_mut()[5] = f64::NAN;
    }
    check(&bad, &param(4), "non-finite");
    check(&rf(vec![1, 4, 3]), &param(4), "at least 2 samples");

    let path = dir.path().join("norf.mat");
    let pv = MatValue::Struct(param(4));
    write_mat(&path, &[("param", &pv)], false).unwrap();
    let e = read_must_mat(&path).unwrap_err().to_string();
    assert!(e.contains("the file has no variable 'RF'"), "{e}");
}

#[test]
fn pwi_disk() {
    let path = pcuvd_testing::disk_recording();
    let path = path.as_path();
    let d = read_must_mat(path).unwrap();
    let a = &d.acquisition;
    println!("{a:#?}\nsamples dim {:?}", d.samples.dim());
    assert_eq!(d.samples.dim(), (32, 128, 334));
    assert_eq!(a.probe.n_elements, 128);
    assert!((a.probe.bandwidth - 0.15).abs() < 1e-12);
    assert_eq!(a.sequence.angles, vec![0.0]);
    assert_eq!(a.sequence.event_prf, 1e4);
    assert_eq!(a.sound_speed, 1480.0);
    assert_eq!(d.n_frames(), 32);
}
