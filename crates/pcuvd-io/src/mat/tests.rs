use super::*;

fn sample_vars() -> Vec<(String, MatValue)> {
    let mut inner = BTreeMap::new();
    inner.insert("fs".to_string(), MatValue::scalar(6.5e7));
    inner.insert(
        "label".to_string(),
        MatValue::Char("probe Ω\nlinear".to_string()),
    );
    inner.insert(
        "list".to_string(),
        MatValue::Cell {
            dims: vec![1, 3],
            items: vec![
                MatValue::scalar(1.0),
                MatValue::Char("two".into()),
                MatValue::empty(),
            ],
        },
    );
    let mut param = BTreeMap::new();
    param.insert("inner".to_string(), MatValue::Struct(inner));
    param.insert("c".to_string(), MatValue::scalar(1540.0));
    param.insert(
        "TXdelay".to_string(),
        MatValue::double(vec![1, 4], vec![0.0, 1e-7, 2e-7, 3e-7]).unwrap(),
    );
    let elems: Vec<BTreeMap<String, MatValue>> = (0..3)
        .map(|i| {
            let mut m = BTreeMap::new();
            m.insert("k".to_string(), MatValue::scalar(i as f64));
            m
        })
        .collect();
    vec![
        (
            "RF".to_string(),
            MatValue::Numeric {
                class: NumericClass::Int16,
                dims: vec![3, 2, 2],
                real: (0..12).map(|v| v as f64 - 6.0).collect(),
                imag: None,
            },
        ),
        (
            "z".to_string(),
            MatValue::Numeric {
                class: NumericClass::Single,
                dims: vec![2, 1],
                real: vec![1.5, -2.0].into(),
                imag: Some(vec![0.25, 4.0].into()),
            },
        ),
        (
            "mask".to_string(),
            MatValue::Logical {
                dims: vec![1, 3],
                data: vec![true, false, true],
            },
        ),
        ("s".to_string(), MatValue::Char("hello".into())),
        ("param".to_string(), MatValue::Struct(param)),
        (
            "arr".to_string(),
            MatValue::StructArray {
                dims: vec![1, 3],
                fields: elems,
            },
        ),
        ("e".to_string(), MatValue::empty()),
    ]
}

fn refs(v: &[(String, MatValue)]) -> Vec<(&str, &MatValue)> {
    v.iter().map(|(n, v)| (n.as_str(), v)).collect()
}

#[test]
fn round_trip_every_kind_both_byte_orders_compressed_or_not() {
    let vars = sample_vars();
    for big in [false, true] {
        for compress in [false, true] {
            let bytes = encode_mat(&refs(&vars), big, compress).unwrap();
            if !compress {
                assert_eq!(bytes.len() % 8, 0);
            }
            let file = parse_mat(&bytes).unwrap();
            assert!(file.header.starts_with("MATLAB 5.0 MAT-file"));
            assert_eq!(file.variables.len(), vars.len(), "big={big} z={compress}");
            for (name, value) in &vars {
                assert_eq!(file.get(name), Some(value), "{name} big={big} z={compress}");
            }
        }
    }
}

#[test]
fn helpers() {
    let vars = sample_vars();
    let file = parse_mat(&encode_mat(&refs(&vars), false, true).unwrap()).unwrap();
    let param = file.get("param").unwrap();
    assert_eq!(param.field("c").unwrap().as_scalar(), Some(1540.0));
    assert_eq!(
        param
            .field("inner")
            .unwrap()
            .field("fs")
            .unwrap()
            .as_scalar(),
        Some(6.5e7)
    );
    assert!(param.field("nope").is_none());
    assert_eq!(file.get("mask").unwrap().as_scalar(), None);
    assert_eq!(file.get("s").unwrap().as_str(), Some("hello"));
    assert_eq!(file.get("z").unwrap().as_scalar(), None);
    // MATLAB (3, 2, 2) column-major → C order (2, 2, 3): a[k][j][i] = rf(i, j, k).
    let rf = file.get("RF").unwrap();
    assert_eq!(rf.describe(), "3×2×2 int16 array");
    let a = rf.to_array_c_order().unwrap();
    assert_eq!(a.shape(), &[2, 2, 3]);
    let real = match rf {
        MatValue::Numeric { real, .. } => real,
        _ => unreachable!(),
    };
    for i in 0..3 {
        for j in 0..2 {
            for k in 0..2 {
                assert_eq!(a[[k, j, i]], real.get(i + 3 * (j + 2 * k)).unwrap());
            }
        }
    }
    assert!(file.get("s").unwrap().to_array_c_order().is_none());
}

/// Hand-assembled little-endian bytes.
fn tag(out: &mut Vec<u8>, ty: u32, n: u32) {
    out.extend_from_slice(&ty.to_le_bytes());
    out.extend_from_slice(&n.to_le_bytes());
}

fn small(out: &mut Vec<u8>, ty: u32, data: &[u8]) {
    out.extend_from_slice(&(((data.len() as u32) << 16) | ty).to_le_bytes());
    let mut d = data.to_vec();
    d.resize(4, 0);
    out.extend_from_slice(&d);
}

fn header() -> Vec<u8> {
    let mut h = b"MATLAB 5.0 MAT-file, Platform: hand-made".to_vec();
    h.resize(116, b' ');
    h.extend_from_slice(&[0; 8]);
    h.extend_from_slice(&0x0100u16.to_le_bytes());
    h.extend_from_slice(b"IM");
    h
}

/// A double 2×3 array stored as miUINT8 (as MATLAB does when values fit), name "x" as a small
/// element, and a scalar stored as miINT16 in a small element.
fn hand_made() -> Vec<u8> {
    let mut body = Vec::new();
    tag(&mut body, MI_UINT32, 8);
    body.extend_from_slice(&6u32.to_le_bytes()); // mxDOUBLE_CLASS
    body.extend_from_slice(&0u32.to_le_bytes());
    tag(&mut body, MI_INT32, 8);
    body.extend_from_slice(&2i32.to_le_bytes());
    body.extend_from_slice(&3i32.to_le_bytes());
    small(&mut body, MI_INT8, b"x");
    tag(&mut body, MI_UINT8, 6);
    body.extend_from_slice(&[1, 2, 3, 4, 5, 250, 0, 0]);
    let mut file = header();
    tag(&mut file, MI_MATRIX, body.len() as u32);
    file.extend_from_slice(&body);

    let mut body = Vec::new();
    tag(&mut body, MI_UINT32, 8);
    body.extend_from_slice(&6u32.to_le_bytes());
    body.extend_from_slice(&0u32.to_le_bytes());
    tag(&mut body, MI_INT32, 8);
    body.extend_from_slice(&1i32.to_le_bytes());
    body.extend_from_slice(&1i32.to_le_bytes());
    small(&mut body, MI_INT8, b"nel");
    small(&mut body, MI_INT16, &(-128i16).to_le_bytes());
    tag(&mut file, MI_MATRIX, body.len() as u32);
    file.extend_from_slice(&body);
    file
}

#[test]
fn storage_types_and_small_elements() {
    let file = parse_mat(&hand_made()).unwrap();
    assert_eq!(
        file.get("x"),
        Some(&MatValue::Numeric {
            class: NumericClass::Double,
            dims: vec![2, 3],
            real: vec![1.0, 2.0, 3.0, 4.0, 5.0, 250.0].into(),
            imag: None,
        })
    );
    assert_eq!(file.get("nel").unwrap().as_scalar(), Some(-128.0));
}

#[test]
fn char_in_utf8_and_a_sparse_matrix_is_unsupported_not_fatal() {
    let mut file = header();
    let mut body = Vec::new();
    tag(&mut body, MI_UINT32, 8);
    body.extend_from_slice(&4u32.to_le_bytes()); // mxCHAR_CLASS
    body.extend_from_slice(&0u32.to_le_bytes());
    tag(&mut body, MI_INT32, 8);
    body.extend_from_slice(&1i32.to_le_bytes());
    body.extend_from_slice(&3i32.to_le_bytes());
    small(&mut body, MI_INT8, b"u");
    let text = "aΩb".as_bytes();
    tag(&mut body, MI_UTF8, text.len() as u32);
    body.extend_from_slice(text);
    body.resize(body.len().div_ceil(8) * 8, 0);
    tag(&mut file, MI_MATRIX, body.len() as u32);
    file.extend_from_slice(&body);

    let mut body = Vec::new();
    tag(&mut body, MI_UINT32, 8);
    body.extend_from_slice(&5u32.to_le_bytes()); // mxSPARSE_CLASS
    body.extend_from_slice(&0u32.to_le_bytes());
    tag(&mut body, MI_INT32, 8);
    body.extend_from_slice(&4i32.to_le_bytes());
    body.extend_from_slice(&4i32.to_le_bytes());
    small(&mut body, MI_INT8, b"sp");
    tag(&mut file, MI_MATRIX, body.len() as u32);
    file.extend_from_slice(&body);

    let f = parse_mat(&file).unwrap();
    assert_eq!(f.get("u").unwrap().as_str(), Some("aΩb"));
    assert!(matches!(f.get("sp"), Some(MatValue::Unsupported(_))));
}

#[test]
fn damaged_files_are_errors_naming_the_file_never_panics() {
    let dir = tempfile::tempdir().unwrap();
    let vars = sample_vars();
    let good = encode_mat(&refs(&vars), false, false).unwrap();
    let path = dir.path().join("cut.mat");
    std::fs::write(&path, &good[..good.len() - 13]).unwrap();
    let err = read_mat(&path).unwrap_err().to_string();
    assert!(err.starts_with(&path.display().to_string()), "{err}");
    assert!(err.contains("truncated"), "{err}");

    let err = read_mat(&dir.path().join("absent.mat"))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("absent.mat") && err.contains("cannot read"),
        "{err}"
    );

    std::fs::write(&path, b"hello").unwrap();
    assert!(
        read_mat(&path)
            .unwrap_err()
            .to_string()
            .contains("128-byte header")
    );
    let mut h73 = b"MATLAB 7.3 MAT-file, Platform: GLNXA64".to_vec();
    h73.resize(512, 0);
    std::fs::write(&path, &h73).unwrap();
    assert!(read_mat(&path).unwrap_err().to_string().contains("v7.3"));

    // Every truncation and many byte corruptions of valid files: errors or values, no panic.
    for compress in [false, true] {
        let good = encode_mat(&refs(&vars), compress, compress).unwrap();
        for cut in 0..good.len() {
            let _ = parse_mat(&good[..cut]);
        }
        for i in 128..good.len() {
            for v in [0u8, 0xFF, 0x7F, 3] {
                let mut bad = good.clone();
                bad[i] = v;
                let _ = parse_mat(&bad);
            }
        }
    }
    let hm = hand_made();
    for cut in 0..hm.len() {
        let _ = parse_mat(&hm[..cut]);
    }
}

#[test]
fn absurd_dimensions_are_refused() {
    let mut body = Vec::new();
    tag(&mut body, MI_UINT32, 8);
    body.extend_from_slice(&1u32.to_le_bytes()); // cell
    body.extend_from_slice(&0u32.to_le_bytes());
    tag(&mut body, MI_INT32, 16);
    for d in [i32::MAX, i32::MAX, i32::MAX, i32::MAX] {
        body.extend_from_slice(&d.to_le_bytes());
    }
    small(&mut body, MI_INT8, b"c");
    let mut file = header();
    tag(&mut file, MI_MATRIX, body.len() as u32);
    file.extend_from_slice(&body);
    assert!(parse_mat(&file).is_err());
}

#[test]
fn write_mat_then_read_mat() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("v.mat");
    let vars = sample_vars();
    write_mat(&path, &refs(&vars), true).unwrap();
    let f = read_mat(&path).unwrap();
    assert_eq!(f.get("param"), Some(&vars[4].1));
    let bad = MatValue::Unsupported("x".into());
    assert!(write_mat(&path, &[("b", &bad)], false).is_err());
}

#[test]
fn pwi_disk_recording() {
    let path = pcuvd_testing::disk_recording();
    let path = path.as_path();
    let f = read_mat(path).unwrap();
    println!("header: {}", f.header);
    for (name, v) in &f.variables {
        println!("{name}: {}", v.describe());
    }
    let rf = f.get("RF").unwrap();
    match rf {
        MatValue::Numeric {
            class, dims, real, ..
        } => {
            // Class double, stored on disk as miINT16 (MATLAB's compact storage of integral values).
            assert_eq!(*class, NumericClass::Double);
            assert!(matches!(
                real,
                Numbers::Stored {
                    dtype: crate::array::Dtype::I16,
                    ..
                }
            ));
            assert!(real.to_f64().iter().all(|v| v.fract() == 0.0));
            assert_eq!(dims, &vec![334, 128, 32]);
            assert_eq!(real.len(), 334 * 128 * 32);
            let max = real.to_f64().iter().fold(0.0f64, |m, v| m.max(v.abs()));
            println!("RF max |value| = {max}");
            assert!(max > 0.0 && max <= 32768.0);
        }
        other => panic!("RF is {}", other.describe()),
    }
    let p = f.get("param").unwrap();
    if let MatValue::Struct(fields) = p {
        for (k, v) in fields {
            match v.as_scalar() {
                Some(s) => println!("param.{k} = {s}"),
                None => println!("param.{k}: {}", v.describe()),
            }
        }
    }
    let s = |k: &str| p.field(k).and_then(MatValue::as_scalar).unwrap();
    assert!((s("fs") - 6666666.67).abs() < 1.0);
    assert!((s("pitch") - 2.98e-4).abs() < 1e-9);
    assert_eq!(s("fc"), 5e6);
    assert_eq!(s("c"), 1480.0);
    assert!((s("t0") - 9.95e-6).abs() < 0.05e-6);
    assert_eq!(s("PRF"), 1e4);
    assert!((s("width") - 2.62e-4).abs() < 1e-9);
    assert_eq!(s("Nelements"), 128.0);
    assert_eq!(s("bandwidth"), 15.0);
    let tx = p.field("TXdelay").unwrap();
    assert_eq!(tx.dims().iter().product::<usize>(), 128);
    assert!(tx.to_array_c_order().unwrap().iter().all(|&v| v == 0.0));
}
