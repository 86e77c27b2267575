//! The MATLAB v5 reader against files written by an independent writer, scipy.io.savemat:
//! `tests/fixtures/make_mat_fixtures.py` wrote the `.mat` fixtures and `expected.json`, the
//! values it put in them (arrays column-major, as MATLAB and pcuvd's reader keep them).

use std::path::{Path, PathBuf};

use pcuvd::{Coding, Samples};
use pcuvd_io::array::Dtype;
use pcuvd_io::mat::Numbers;
use pcuvd_io::{MatValue, NumericClass, read_mat, read_must_mat};
use serde_json::Value;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

fn expected() -> Value {
    let text = std::fs::read_to_string(fixture("expected.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

fn numbers(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap_or_else(|| panic!("{v} is not an array"))
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

fn dims(v: &Value) -> Vec<usize> {
    numbers(v).into_iter().map(|d| d as usize).collect()
}

/// The numeric array `value`: (class, dims, real, imag), or a panic naming what it is instead.
fn numeric(value: &MatValue) -> (NumericClass, &[usize], Vec<f64>, Option<Vec<f64>>) {
    match value {
        MatValue::Numeric {
            class,
            dims,
            real,
            imag,
        } => (
            *class,
            dims,
            real.to_f64().into_owned(),
            imag.as_ref().map(|i| i.to_f64().into_owned()),
        ),
        other => panic!("expected a numeric array, found a {}", other.describe()),
    }
}

#[test]
fn must_style_int16_rf_and_param_struct() {
    let e = &expected()["must"];
    // The same variables, written plain and zlib-compressed (miCOMPRESSED): the same values.
    for name in ["must_int16.mat", "must_compressed.mat"] {
        let file = read_mat(&fixture(name)).unwrap();
        let (class, rf_dims, real, imag) = numeric(file.get("RF").unwrap());
        assert_eq!(class, NumericClass::Int16, "{name}");
        assert_eq!(rf_dims, dims(&e["rf_dims"]), "{name}");
        assert_eq!(real, numbers(&e["rf"]), "{name}");
        assert!(imag.is_none(), "{name}");
        // The samples stay two bytes each in memory, as the file stores them.
        let Some(MatValue::Numeric {
            real: Numbers::Stored { dtype, bytes, .. },
            ..
        }) = file.get("RF")
        else {
            panic!("{name}: RF not kept as stored")
        };
        assert_eq!(
            (*dtype, bytes.len()),
            (Dtype::I16, 2 * real.len()),
            "{name}"
        );
        let param = file.get("param").unwrap();
        for key in ["fs", "fc", "c", "pitch", "width", "t0", "PRF", "Nelements"] {
            assert_eq!(
                param.field(key).and_then(MatValue::as_scalar),
                e[key].as_f64(),
                "{name}: param.{key}"
            );
        }
        assert_eq!(
            param.field("bandwidth").and_then(MatValue::as_scalar),
            e["bandwidth_percent"].as_f64()
        );
        let (_, tx_dims, tx, _) = numeric(param.field("TXdelay").unwrap());
        assert_eq!((tx_dims, tx), (&[1, 4][..], vec![0.0; 4]), "{name}");
    }
    let bytes = |n| std::fs::metadata(fixture(n)).unwrap().len();
    assert!(
        bytes("must_compressed.mat") < bytes("must_int16.mat"),
        "the compressed fixture is not compressed"
    );
}

#[test]
fn must_style_files_read_as_channel_data() {
    let e = &expected()["must"];
    let rf = numbers(&e["rf"]);
    let (ns, ne, nt) = (24, 4, 3);
    assert_eq!(dims(&e["rf_dims"]), [ns, ne, nt]);
    let scale = e["double_rf_scale"].as_f64().unwrap();
    for (name, scale, steer_deg) in [
        ("must_int16.mat", 1.0, 0.0),
        ("must_compressed.mat", 1.0, 0.0),
        ("must_double.mat", scale, e["steer_deg"].as_f64().unwrap()),
    ] {
        let data = read_must_mat(&fixture(name)).unwrap();
        let Samples::Rf(samples) = &data.samples else {
            panic!("{name}: not RF");
        };
        // MATLAB RF(i, j, k) (samples × elements × transmits) is samples[[k, j, i]].
        assert_eq!(samples.dim(), (nt, ne, ns), "{name}");
        for ((k, j, i), &v) in samples.indexed_iter() {
            let want = rf[i + ns * (j + ne * k)] * scale;
            assert_eq!(
                v as f64,
                want,
                "{name}: RF({}, {}, {})",
                i + 1,
                j + 1,
                k + 1
            );
        }
        let a = &data.acquisition;
        assert_eq!(a.sampling_frequency, e["fs"].as_f64().unwrap());
        assert_eq!(a.sound_speed, e["c"].as_f64().unwrap());
        assert_eq!(a.t0, e["t0"].as_f64().unwrap());
        assert_eq!(a.sequence.event_prf, e["PRF"].as_f64().unwrap());
        assert_eq!(a.sequence.coding, Coding::Conventional);
        assert_eq!(a.probe.n_elements, ne);
        assert_eq!(a.probe.pitch, e["pitch"].as_f64().unwrap());
        assert_eq!(a.probe.element_width, e["width"].as_f64().unwrap());
        assert_eq!(a.probe.center_frequency, e["fc"].as_f64().unwrap());
        assert!((a.probe.bandwidth - 0.6).abs() < 1e-15, "{name}");
        // The steered file's TXdelay is an exact plane wave: its angle comes back to rounding.
        assert_eq!(a.sequence.angles.len(), 1);
        let angle_deg = a.sequence.angles[0].to_degrees();
        assert!(
            (angle_deg - steer_deg).abs() < 1e-9,
            "{name}: {angle_deg}° instead of {steer_deg}°"
        );
    }
    let file = read_mat(&fixture("must_double.mat")).unwrap();
    assert_eq!(numeric(file.get("RF").unwrap()).0, NumericClass::Double);
    let (_, _, tx, _) = numeric(file.get("param").unwrap().field("TXdelay").unwrap());
    // To one ulp: serde_json's default float parser is not correctly rounded, and it reads
    // one of these delays one ulp away from the double Python wrote.
    let want = numbers(&e["steered_tx_delay"]);
    assert_eq!(tx.len(), want.len());
    for (got, want) in tx.iter().zip(&want) {
        assert!(
            (got - want).abs() <= f64::EPSILON * want.abs(),
            "{got:e} vs {want:e}"
        );
    }
}

#[test]
fn nested_structs() {
    let e = &expected()["nested"];
    let file = read_mat(&fixture("nested_struct.mat")).unwrap();
    let cfg = file.get("cfg").unwrap();
    assert!(matches!(cfg, MatValue::Struct(_)), "{}", cfg.describe());
    assert_eq!(
        cfg.field("gain").and_then(MatValue::as_scalar),
        e["gain"].as_f64()
    );
    let inner = cfg.field("inner").unwrap();
    assert!(matches!(inner, MatValue::Struct(_)), "{}", inner.describe());
    let (class, d, depths, _) = numeric(inner.field("depths").unwrap());
    assert_eq!(class, NumericClass::Double);
    assert_eq!(d, dims(&e["depths_dims"]));
    assert_eq!(depths, numbers(&e["depths"]));
    assert_eq!(
        inner.field("label").and_then(MatValue::as_str),
        e["label"].as_str()
    );
    let count = inner.field("deeper").unwrap().field("count").unwrap();
    assert_eq!(numeric(count).0, NumericClass::Int32);
    assert_eq!(count.as_scalar(), e["count"].as_f64());
}

#[test]
fn complex_array() {
    let e = &expected()["complex"];
    let file = read_mat(&fixture("complex.mat")).unwrap();
    let (class, d, real, imag) = numeric(file.get("z").unwrap());
    assert_eq!(class, NumericClass::Double);
    assert_eq!(d, dims(&e["dims"]));
    assert_eq!(real, numbers(&e["real"]));
    assert_eq!(imag.expect("complex"), numbers(&e["imag"]));
}

#[test]
fn char_string_with_non_ascii_characters() {
    let text = expected()["char"]["text"].as_str().unwrap().to_string();
    let file = read_mat(&fixture("char.mat")).unwrap();
    let note = file.get("note").unwrap();
    assert_eq!(note.as_str(), Some(text.as_str()));
    // MATLAB counts characters, not UTF-8 bytes (scipy stores this string as miUTF8).
    assert_eq!(note.dims(), vec![1, text.chars().count()]);
}
