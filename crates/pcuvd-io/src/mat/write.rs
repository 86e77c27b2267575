//! Writing a MAT v5 file: numeric matrices, character arrays and structs, each element padded to
//! 8 bytes, compressed.

use super::*;

// ---------------------------------------------------------------------------------------------
// Writing

pub(super) struct Writer {
    pub(super) out: Vec<u8>,
    pub(super) big: bool,
}

impl Writer {
    pub(super) fn u32(&mut self, v: u32) {
        if self.big {
            self.out.extend_from_slice(&v.to_be_bytes());
        } else {
            self.out.extend_from_slice(&v.to_le_bytes());
        }
    }

    pub(super) fn pad(&mut self) {
        while !self.out.len().is_multiple_of(8) {
            self.out.push(0);
        }
    }

    /// One data element, in the small format when it has 1 to 4 bytes.
    pub(super) fn element(&mut self, ty: u32, data: &[u8]) -> Result<(), String> {
        if (1..=4).contains(&data.len()) {
            self.u32(((data.len() as u32) << 16) | ty);
            self.out.extend_from_slice(data);
            self.out.resize(self.out.len() + 4 - data.len(), 0);
        } else {
            let n = u32::try_from(data.len())
                .map_err(|_| format!("{} bytes exceed a MAT-file element", data.len()))?;
            self.u32(ty);
            self.u32(n);
            self.out.extend_from_slice(data);
            self.pad();
        }
        Ok(())
    }
}

pub(super) fn number_bytes(values: &[f64], ty: u32, big: bool) -> Vec<u8> {
    let mut out = Vec::with_capacity(values.len() * element_size(ty).unwrap_or(8));
    macro_rules! put {
        ($t:ty) => {
            for &v in values {
                let x = v as $t;
                out.extend_from_slice(&if big {
                    x.to_be_bytes()
                } else {
                    x.to_le_bytes()
                });
            }
        };
    }
    match ty {
        MI_INT8 => put!(i8),
        MI_UINT8 => put!(u8),
        MI_INT16 => put!(i16),
        MI_UINT16 => put!(u16),
        MI_INT32 => put!(i32),
        MI_UINT32 => put!(u32),
        MI_SINGLE => put!(f32),
        MI_INT64 => put!(i64),
        MI_UINT64 => put!(u64),
        _ => put!(f64),
    }
    out
}

pub(super) fn dims_bytes(dims: &[usize], big: bool) -> Result<Vec<u8>, String> {
    let d: Vec<f64> = dims
        .iter()
        .map(|&d| {
            i32::try_from(d)
                .map(f64::from)
                .map_err(|_| format!("dimension {d} exceeds MATLAB's limit"))
        })
        .collect::<Result<_, _>>()?;
    let d = if d.len() < 2 {
        let mut v = d;
        v.resize(2, 1.0);
        v
    } else {
        d
    };
    Ok(number_bytes(&d, MI_INT32, big))
}

/// The contents (no tag) of a miMATRIX element for `value`.
pub(super) fn matrix_body(name: &str, value: &MatValue, big: bool) -> Result<Vec<u8>, String> {
    let mut w = Writer {
        out: Vec::new(),
        big,
    };
    let header = |w: &mut Writer, flags: u32, dims: &[usize]| -> Result<(), String> {
        w.element(
            MI_UINT32,
            &number_bytes(&[f64::from(flags), 0.0], MI_UINT32, big),
        )?;
        w.element(MI_INT32, &dims_bytes(dims, big)?)?;
        w.element(MI_INT8, name.as_bytes())
    };
    match value {
        MatValue::Numeric {
            class,
            dims,
            real,
            imag,
        } => {
            if checked_numel(dims) != Some(real.len())
                || imag.as_ref().is_some_and(|im| im.len() != real.len())
            {
                return Err(format!(
                    "'{name}' has dimensions {dims:?} but {} values",
                    real.len()
                ));
            }
            let complex = if imag.is_some() { FLAG_COMPLEX } else { 0 };
            header(&mut w, u32::from(class.code()) | complex, dims)?;
            w.element(
                class.storage(),
                &number_bytes(&real.to_f64(), class.storage(), big),
            )?;
            if let Some(im) = imag {
                w.element(
                    class.storage(),
                    &number_bytes(&im.to_f64(), class.storage(), big),
                )?;
            }
        }
        MatValue::Logical { dims, data } => {
            if checked_numel(dims) != Some(data.len()) {
                return Err(format!(
                    "'{name}' has dimensions {dims:?} but {} values",
                    data.len()
                ));
            }
            header(&mut w, 9 | FLAG_LOGICAL, dims)?;
            let bytes: Vec<u8> = data.iter().map(|&b| u8::from(b)).collect();
            w.element(MI_UINT8, &bytes)?;
        }
        MatValue::Char(s) => {
            let rows: Vec<Vec<u16>> = s.split('\n').map(|r| r.encode_utf16().collect()).collect();
            let cols = rows.first().map_or(0, Vec::len);
            let (rows, cols) = if rows.iter().all(|r| r.len() == cols) {
                (rows, cols)
            } else {
                (
                    vec![s.encode_utf16().collect::<Vec<u16>>()],
                    s.encode_utf16().count(),
                )
            };
            let n = rows.len();
            let mut units = Vec::with_capacity(n * cols);
            for j in 0..cols {
                for r in &rows {
                    units.push(f64::from(r[j]));
                }
            }
            let dims = if cols == 0 { vec![0, 0] } else { vec![n, cols] };
            header(&mut w, u32::from(MX_CHAR), &dims)?;
            w.element(MI_UINT16, &number_bytes(&units, MI_UINT16, big))?;
        }
        MatValue::Struct(fields) => {
            struct_body(&mut w, name, &[1, 1], std::slice::from_ref(fields), big)?;
        }
        MatValue::StructArray { dims, fields } => {
            if checked_numel(dims) != Some(fields.len()) {
                return Err(format!(
                    "'{name}' has dimensions {dims:?} but {} elements",
                    fields.len()
                ));
            }
            struct_body(&mut w, name, dims, fields, big)?;
        }
        MatValue::Cell { dims, items } => {
            if checked_numel(dims) != Some(items.len()) {
                return Err(format!(
                    "'{name}' has dimensions {dims:?} but {} cells",
                    items.len()
                ));
            }
            header(&mut w, u32::from(MX_CELL), dims)?;
            for item in items {
                let body = matrix_body("", item, big)?;
                w.element(MI_MATRIX, &body)?;
            }
        }
        MatValue::Unsupported(what) => {
            return Err(format!("'{name}' cannot be written ({what})"));
        }
    }
    Ok(w.out)
}

pub(super) fn struct_body(
    w: &mut Writer,
    name: &str,
    dims: &[usize],
    elements: &[BTreeMap<String, MatValue>],
    big: bool,
) -> Result<(), String> {
    let mut names: Vec<&String> = elements.iter().flat_map(|m| m.keys()).collect();
    names.sort();
    names.dedup();
    let len = names.iter().map(|n| n.len() + 1).max().unwrap_or(1).max(32);
    w.element(
        MI_UINT32,
        &number_bytes(&[f64::from(MX_STRUCT), 0.0], MI_UINT32, big),
    )?;
    w.element(MI_INT32, &dims_bytes(dims, big)?)?;
    w.element(MI_INT8, name.as_bytes())?;
    w.element(MI_INT32, &number_bytes(&[len as f64], MI_INT32, big))?;
    let mut name_bytes = Vec::with_capacity(len * names.len());
    for n in &names {
        let mut b = n.as_bytes().to_vec();
        b.resize(len, 0);
        name_bytes.extend_from_slice(&b);
    }
    w.element(MI_INT8, &name_bytes)?;
    let empty = MatValue::empty();
    for el in elements {
        for n in &names {
            let body = matrix_body("", el.get(*n).unwrap_or(&empty), big)?;
            w.element(MI_MATRIX, &body)?;
        }
    }
    Ok(())
}

/// A whole MAT-file in memory.
pub(super) fn encode_mat(
    variables: &[(&str, &MatValue)],
    big: bool,
    compress: bool,
) -> Result<Vec<u8>, String> {
    let mut w = Writer {
        out: Vec::new(),
        big,
    };
    let mut text = b"MATLAB 5.0 MAT-file, written by pcuvd-io".to_vec();
    text.resize(116, b' ');
    w.out.extend_from_slice(&text);
    w.out.extend_from_slice(&[0; 8]);
    if big {
        w.out.extend_from_slice(&0x0100u16.to_be_bytes());
        w.out.extend_from_slice(b"MI");
    } else {
        w.out.extend_from_slice(&0x0100u16.to_le_bytes());
        w.out.extend_from_slice(b"IM");
    }
    for (name, value) in variables {
        let body = matrix_body(name, value, big)?;
        if compress {
            let mut m = Writer {
                out: Vec::new(),
                big,
            };
            m.element(MI_MATRIX, &body)?;
            let mut enc =
                flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
            enc.write_all(&m.out)
                .and_then(|_| enc.finish())
                .map_err(|e| format!("compression failed: {e}"))
                .and_then(|z| {
                    let n = u32::try_from(z.len())
                        .map_err(|_| "compressed variable exceeds 4 GiB".to_string())?;
                    w.u32(MI_COMPRESSED);
                    w.u32(n);
                    w.out.extend_from_slice(&z);
                    Ok(())
                })?;
        } else {
            w.element(MI_MATRIX, &body)?;
        }
    }
    Ok(w.out)
}
