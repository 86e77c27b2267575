//! MUST/PyMUST-style recordings: a MAT-file with `RF` (samples × elements × transmits) and a
//! `param` struct (fs, fc, c, pitch, width, t0, PRF, TXdelay, Nelements, bandwidth).

use std::path::Path;

use ndarray::Array3;
use pcuvd::{Acquisition, ChannelData, Coding, Probe, Samples, Sequence};

use crate::error::IoError;
use crate::mat::{MatFile, MatValue, read_mat};

/// MUST's default fractional bandwidth when `param.bandwidth` is absent (%).
pub const DEFAULT_BANDWIDTH_PERCENT: f64 = 75.0;
/// MUST's default speed of sound when `param.c` is absent (m/s).
pub const DEFAULT_SOUND_SPEED: f64 = 1540.0;
/// Transmit pulse length assumed when `param.TXnow` is absent (cycles).
pub const DEFAULT_PULSE_CYCLES: f64 = 2.0;

/// Reads a MUST-style MAT-file into channel data: one plane-wave angle (from `param.TXdelay`),
/// every transmit an event, RF as f32 of shape (transmits, elements, samples).
pub fn read_must_mat(path: &Path) -> Result<ChannelData, IoError> {
    let file = read_mat(path)?;
    from_mat(path, &file)
}

/// Builds channel data from an already-read MUST-style MAT-file (`path` only names it in errors).
pub fn from_mat(path: &Path, file: &MatFile) -> Result<ChannelData, IoError> {
    let rf = file
        .get("RF")
        .ok_or_else(|| IoError::missing(path, "the file", "variable 'RF'"))?;
    let param = file
        .get("param")
        .ok_or_else(|| IoError::missing(path, "the file", "variable 'param'"))?;
    if param.field("fs").is_none() && !matches!(param, MatValue::Struct(_)) {
        return Err(IoError::invalid(
            path,
            "variable 'param'",
            format!("must be a 1×1 struct, found a {}", param.describe()),
        ));
    }

    // RF: samples × elements × transmits, column-major = C-order (transmits, elements, samples).
    let (dims, real) = match rf {
        MatValue::Numeric {
            dims,
            real,
            imag: None,
            ..
        } => (dims, real),
        MatValue::Numeric { .. } => {
            return Err(IoError::invalid(
                path,
                "variable 'RF'",
                "is complex; expected real RF samples",
            ));
        }
        other => {
            return Err(IoError::invalid(
                path,
                "variable 'RF'",
                format!("must be a numeric array, found a {}", other.describe()),
            ));
        }
    };
    let extra_ok = dims.iter().skip(3).all(|&d| d == 1);
    let (n_samples, n_elements, n_transmits) = match dims.as_slice() {
        [s, e] => (*s, *e, 1),
        [s, e, t, ..] if extra_ok => (*s, *e, *t),
        _ => {
            return Err(IoError::invalid(
                path,
                "variable 'RF'",
                format!(
                    "must be samples × elements × transmits (3-D, or 2-D for one transmit), found a {}",
                    rf.describe()
                ),
            ));
        }
    };
    if n_samples == 0 || n_elements == 0 || n_transmits == 0 {
        return Err(IoError::invalid(
            path,
            "variable 'RF'",
            format!("is empty ({})", rf.describe()),
        ));
    }
    if let Some(i) = real.iter().position(|v| !v.is_finite()) {
        return Err(IoError::invalid(
            path,
            "variable 'RF'",
            format!(
                "holds a non-finite sample ({}) at linear index {i}",
                real[i]
            ),
        ));
    }
    let data: Vec<f32> = real.iter().map(|&v| v as f32).collect();
    let samples = Array3::from_shape_vec((n_transmits, n_elements, n_samples), data)
        .map_err(|e| IoError::invalid(path, "variable 'RF'", format!("has a bad shape ({e})")))?;

    // param fields.
    let scalar = |name: &str| -> Result<Option<f64>, IoError> {
        match param.field(name) {
            None => Ok(None),
            Some(v) => v.as_scalar().map(Some).ok_or_else(|| {
                IoError::invalid(
                    path,
                    format!("param.{name}"),
                    format!("must be a real scalar, found a {}", v.describe()),
                )
            }),
        }
    };
    let required = |name: &str| -> Result<f64, IoError> {
        scalar(name)?
            .ok_or_else(|| IoError::missing(path, "variable 'param'", format!("field '{name}'")))
    };
    let positive = |name: &str, v: f64| -> Result<f64, IoError> {
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err(IoError::invalid(
                path,
                format!("param.{name}"),
                format!("must be finite and > 0, got {v}"),
            ))
        }
    };
    let fs = positive("fs", required("fs")?)?;
    let fc = positive("fc", required("fc")?)?;
    let pitch = positive("pitch", required("pitch")?)?;
    let width = positive("width", required("width")?)?;
    let prf = positive("PRF", required("PRF")?)?;
    let c = positive("c", scalar("c")?.unwrap_or(DEFAULT_SOUND_SPEED))?;
    let bandwidth = positive(
        "bandwidth",
        scalar("bandwidth")?.unwrap_or(DEFAULT_BANDWIDTH_PERCENT),
    )?;
    let pulse_cycles = positive("TXnow", scalar("TXnow")?.unwrap_or(DEFAULT_PULSE_CYCLES))?;
    let t0 = scalar("t0")?.unwrap_or(0.0);
    if !t0.is_finite() {
        return Err(IoError::invalid(
            path,
            "param.t0",
            format!("must be finite, got {t0}"),
        ));
    }
    if let Some(ne) = scalar("Nelements")?
        && ne != n_elements as f64
    {
        return Err(IoError::invalid(
            path,
            "param.Nelements",
            format!("is {ne} but RF has {n_elements} elements (its second dimension)"),
        ));
    }

    let probe = Probe {
        name: "from MAT file".into(),
        n_elements,
        pitch,
        element_width: width,
        center_frequency: fc,
        bandwidth: bandwidth / 100.0,
    };
    let angle = match param.field("TXdelay") {
        None => 0.0,
        Some(v) => {
            let delays: Vec<f64> = match v {
                MatValue::Numeric {
                    real, imag: None, ..
                } => real.clone(),
                other => {
                    return Err(IoError::invalid(
                        path,
                        "param.TXdelay",
                        format!("must be a real vector, found a {}", other.describe()),
                    ));
                }
            };
            plane_wave_angle(&delays, &probe.element_x(), c)
                .map_err(|p| IoError::invalid(path, "param.TXdelay", p))?
        }
    };

    let data = ChannelData {
        acquisition: Acquisition {
            probe,
            sequence: Sequence {
                angles: vec![angle],
                event_prf: prf,
                coding: Coding::Conventional,
                pulse_cycles,
                pulse: None,
            },
            sampling_frequency: fs,
            sound_speed: c,
            t0,
        },
        samples: Samples::Rf(samples),
    };
    data.validate().map_err(|source| IoError::Recording {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(data)
}

/// Steering angle θ (rad) of a linear transmit-delay profile d_i = d_0 + x_i·sinθ/c; refuses
/// delays that are not linear in x (focused or diverging waves).
pub fn plane_wave_angle(delays: &[f64], element_x: &[f64], c: f64) -> Result<f64, String> {
    if delays.len() != element_x.len() {
        return Err(format!(
            "has {} delays but the probe has {} elements",
            delays.len(),
            element_x.len()
        ));
    }
    if let Some(d) = delays.iter().find(|d| !d.is_finite()) {
        return Err(format!("holds a non-finite delay ({d})"));
    }
    let n = delays.len() as f64;
    if delays.len() < 2 || delays.iter().all(|&d| d == delays[0]) {
        return Ok(0.0);
    }
    let mx = element_x.iter().sum::<f64>() / n;
    let md = delays.iter().sum::<f64>() / n;
    let sxx: f64 = element_x.iter().map(|x| (x - mx).powi(2)).sum();
    let sxd: f64 = element_x
        .iter()
        .zip(delays)
        .map(|(x, d)| (x - mx) * (d - md))
        .sum();
    if sxx <= 0.0 {
        return Err("cannot be fitted: the elements all share one position".into());
    }
    let slope = sxd / sxx;
    let (lo, hi) = delays
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &d| {
            (l.min(d), h.max(d))
        });
    let residual = element_x
        .iter()
        .zip(delays)
        .map(|(x, d)| (d - (md + slope * (x - mx))).abs())
        .fold(0.0, f64::max);
    // Delays quantised by a scanner's clock stay well inside 2 % of their span.
    if residual > 0.02 * (hi - lo) + 1e-12 {
        return Err(format!(
            "is not a plane-wave delay profile (not linear across the elements: the best linear fit \
             misses by up to {:.3} µs over a span of {:.3} µs; focused and diverging waves are not supported)",
            residual * 1e6,
            (hi - lo) * 1e6
        ));
    }
    let s = c * slope;
    if s.abs() >= 1.0 {
        return Err(format!(
            "implies sin θ = {s:.3} (|sin θ| must be < 1): delays too steep for c = {c} m/s"
        ));
    }
    Ok(s.asin())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mat::{NumericClass, write_mat};
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
        if let Samples::Rf(x) = &d.samples {
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
    fn steered_delays_give_the_angle() {
        let x = Probe {
            name: String::new(),
            n_elements: 64,
            pitch: 3e-4,
            element_width: 2.5e-4,
            center_frequency: 5e6,
            bandwidth: 0.7,
        }
        .element_x();
        let theta = 7f64.to_radians();
        let c = 1540.0;
        let x0 = x[0];
        let d: Vec<f64> = x.iter().map(|xi| (xi - x0) * theta.sin() / c).collect();
        assert!((plane_wave_angle(&d, &x, c).unwrap() - theta).abs() < 1e-12);
        let neg: Vec<f64> = d.iter().map(|v| d[63] - v).collect();
        assert!((plane_wave_angle(&neg, &x, c).unwrap() + theta).abs() < 1e-12);
        // Diverging wave: delays ∝ distance from a virtual source behind the array.
        let div: Vec<f64> = x
            .iter()
            .map(|xi| (xi * xi + 0.01f64.powi(2)).sqrt() / c)
            .collect();
        let e = plane_wave_angle(&div, &x, c).unwrap_err();
        assert!(e.contains("is not a plane-wave delay profile"), "{e}");
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
            real[5] = f64::NAN;
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
        let path = Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../../shared/data/PWI_disk.mat"
        ));
        // Beside the repository, not in it; missing, the test fails rather than passing unrun.
        assert!(
            path.exists(),
            "the real rotating-disk recording PWI_disk.mat is missing: expected at {} \
             (shared/data/ beside the repository)",
            path.display()
        );
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
}
