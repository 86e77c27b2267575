//! MATLAB v7.3 MAT-files (HDF5 behind a 512-byte user block): small variables (structs, struct
//! arrays, cells through object references, chars, numbers) read into the same [`MatValue`] the
//! v5 reader gives; large arrays stay in the file ([`crate::array::StoredArray`]).
//!
//! Layout (what MATLAB's `save -v7.3` and hdf5storage's MATLAB mode write): each variable is a
//! dataset or group with attribute `MATLAB_class`; an array's HDF5 shape is its MATLAB dimensions
//! reversed (so its C order is MATLAB's column-major order); a 1×1 struct is a group of fields; a
//! struct array is a group whose fields are datasets of object references (one per element,
//! without `MATLAB_class`); a cell is a dataset of references with class `cell`; the referenced
//! values live in `/#refs#`; chars are uint16 code units.

use std::collections::BTreeMap;

use crate::error::IoError;
use crate::hdf5::{H5Kind, Hdf5};
use crate::mat::{MatValue, Numbers, NumericClass};

/// How deep structs and cells may nest before the file is taken as malformed.
const MAX_DEPTH: usize = 16;

/// The MATLAB class of the variable or field at `path` ("double", "struct", "cell"...).
pub fn class_of(h5: &Hdf5, path: &str) -> Option<String> {
    h5.attr_string(path, "MATLAB_class")
}

/// Reads the variable or field at `path` into a [`MatValue`] (numeric arrays as f64).
pub fn read_value(h5: &Hdf5, path: &str) -> Result<MatValue, IoError> {
    read_at(h5, path, 0)
}

fn numeric_class(name: &str) -> Option<NumericClass> {
    Some(match name {
        "double" => NumericClass::Double,
        "single" => NumericClass::Single,
        "int8" => NumericClass::Int8,
        "uint8" => NumericClass::UInt8,
        "int16" => NumericClass::Int16,
        "uint16" => NumericClass::UInt16,
        "int32" => NumericClass::Int32,
        "uint32" => NumericClass::UInt32,
        "int64" => NumericClass::Int64,
        "uint64" => NumericClass::UInt64,
        _ => return None,
    })
}

fn read_at(h5: &Hdf5, path: &str, depth: usize) -> Result<MatValue, IoError> {
    if depth > MAX_DEPTH {
        return Err(IoError::invalid(
            &h5.path,
            path,
            format!("nests more than {MAX_DEPTH} levels of structs or cells"),
        ));
    }
    let class = class_of(h5, path);
    if h5.is_group(path) {
        let members: Vec<String> = h5
            .members(path)?
            .into_iter()
            .filter(|m| !m.starts_with('#'))
            .collect();
        let child = |m: &str| format!("{}/{m}", path.trim_end_matches('/'));
        // A struct array's fields are reference datasets without a MATLAB class.
        let is_array = !members.is_empty()
            && members.iter().all(|m| {
                let p = child(m);
                h5.is_dataset(&p)
                    && class_of(h5, &p).is_none()
                    && h5.describe(&p).is_ok_and(|(_, k)| k == H5Kind::Reference)
            });
        if !is_array {
            let mut fields = BTreeMap::new();
            for m in &members {
                fields.insert(m.clone(), read_at(h5, &child(m), depth + 1)?);
            }
            return Ok(MatValue::Struct(fields));
        }
        let mut per_field = Vec::new();
        let mut dims = Vec::new();
        for m in &members {
            let (shape, _) = h5.describe(&child(m))?;
            let refs = h5.references(&child(m))?;
            dims = shape.iter().rev().copied().collect();
            per_field.push((m.clone(), refs));
        }
        let n = per_field.first().map_or(0, |(_, r)| r.len());
        if per_field.iter().any(|(_, r)| r.len() != n) {
            return Err(IoError::invalid(
                &h5.path,
                path,
                "is a struct array whose fields have different lengths",
            ));
        }
        let mut fields = vec![BTreeMap::new(); n];
        for (name, refs) in &per_field {
            for (i, target) in refs.iter().enumerate() {
                fields[i].insert(name.clone(), read_at(h5, target, depth + 1)?);
            }
        }
        return Ok(MatValue::StructArray { dims, fields });
    }
    let (shape, kind) = h5.describe(path)?;
    let dims: Vec<usize> = shape.iter().rev().copied().collect();
    if h5.attr_string(path, "MATLAB_empty").is_some()
        || class.as_deref() == Some("canonical empty")
        || matches!(
            h5.dataset(path).map(|d| d.attr("MATLAB_empty").is_ok()),
            Ok(true)
        )
    {
        return Ok(MatValue::empty());
    }
    match (class.as_deref(), kind) {
        (Some("cell"), _) | (None, H5Kind::Reference) => {
            let refs = h5.references(path)?;
            let items = refs
                .iter()
                .map(|r| read_at(h5, r, depth + 1))
                .collect::<Result<Vec<_>, _>>()?;
            Ok(MatValue::Cell { dims, items })
        }
        (Some("char"), _) => {
            let (_, units) = h5.read_f64(path)?;
            let code: Vec<u16> = units.iter().map(|&u| u as u16).collect();
            Ok(MatValue::Char(String::from_utf16_lossy(&code)))
        }
        (Some("logical"), _) => {
            let (_, v) = h5.read_f64(path)?;
            Ok(MatValue::Logical {
                dims,
                data: v.iter().map(|&x| x != 0.0).collect(),
            })
        }
        (c, H5Kind::Complex { .. }) => {
            let class = c.and_then(numeric_class).unwrap_or(NumericClass::Double);
            let ds = h5.dataset(path)?;
            let n = crate::hdf5::element_count(&shape)
                .filter(|&n| n <= crate::hdf5::MAX_PARAMETER_ELEMENTS)
                .ok_or_else(|| IoError::invalid(&h5.path, path, "is too large for a parameter"))?;
            let zeros = vec![0usize; shape.len()];
            let values = crate::hdf5::guard(&h5.path, path, || {
                ds.read_slice::<rust_hdf5::types::Complex64>(&zeros, &shape)
            })
            .or_else(|_| {
                crate::hdf5::guard(&h5.path, path, || {
                    ds.read_slice::<rust_hdf5::types::Complex32>(&zeros, &shape)
                })
                .map(|v| {
                    v.into_iter()
                        .map(|c| rust_hdf5::types::Complex64 {
                            re: f64::from(c.re),
                            im: f64::from(c.im),
                        })
                        .collect()
                })
            })?;
            debug_assert_eq!(values.len(), n);
            Ok(MatValue::Numeric {
                class,
                dims,
                real: Numbers::F64(values.iter().map(|c| c.re).collect()),
                imag: Some(Numbers::F64(values.iter().map(|c| c.im).collect())),
            })
        }
        (c, H5Kind::Int { .. } | H5Kind::Float { .. }) => {
            let (_, real) = h5.read_f64(path)?;
            Ok(MatValue::Numeric {
                class: c.and_then(numeric_class).unwrap_or(NumericClass::Double),
                dims,
                real: Numbers::F64(real),
                imag: None,
            })
        }
        (c, k) => Ok(MatValue::Unsupported(format!(
            "MATLAB class {}, HDF5 {k:?}",
            c.unwrap_or("none")
        ))),
    }
}
