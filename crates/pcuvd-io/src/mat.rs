//! MATLAB v5 ("Level 5") MAT-files: a reader written by hand (structs, cells and compressed
//! variables included) and a small writer for numeric, logical, char, struct and cell values.
//!
//! Arrays are kept as MATLAB stores them: column-major, with MATLAB's dimensions
//! ([`MatValue::to_array_c_order`] turns them into a C-order `ndarray`). Objects, sparse matrices and
//! function handles are read as [`MatValue::Unsupported`] without failing the file. MATLAB v7.3
//! files (HDF5) are recognised and refused with a clear message.

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::path::Path;

use ndarray::{ArrayD, IxDyn};

use crate::error::IoError;

// Data types of the data elements (MATLAB "miXXX").
const MI_INT8: u32 = 1;
const MI_UINT8: u32 = 2;
const MI_INT16: u32 = 3;
const MI_UINT16: u32 = 4;
const MI_INT32: u32 = 5;
const MI_UINT32: u32 = 6;
const MI_SINGLE: u32 = 7;
const MI_DOUBLE: u32 = 9;
const MI_INT64: u32 = 12;
const MI_UINT64: u32 = 13;
const MI_MATRIX: u32 = 14;
const MI_COMPRESSED: u32 = 15;
const MI_UTF8: u32 = 16;
const MI_UTF16: u32 = 17;
const MI_UTF32: u32 = 18;

// Array classes ("mxXXX_CLASS").
const MX_CELL: u8 = 1;
const MX_STRUCT: u8 = 2;
const MX_OBJECT: u8 = 3;
const MX_CHAR: u8 = 4;
const MX_SPARSE: u8 = 5;
const MX_FUNCTION: u8 = 16;
const MX_OPAQUE: u8 = 17;

const FLAG_COMPLEX: u32 = 0x0800;
const FLAG_LOGICAL: u32 = 0x0200;

/// Deepest nesting of cells/structs accepted (guards the stack against hostile files).
const MAX_DEPTH: usize = 64;

/// The numeric class of a MATLAB array (what `class(x)` says in MATLAB).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NumericClass {
    /// 64-bit float (`double`).
    Double,
    /// 32-bit float (`single`).
    Single,
    /// Signed 8-bit integer.
    Int8,
    /// Unsigned 8-bit integer.
    UInt8,
    /// Signed 16-bit integer.
    Int16,
    /// Unsigned 16-bit integer.
    UInt16,
    /// Signed 32-bit integer.
    Int32,
    /// Unsigned 32-bit integer.
    UInt32,
    /// Signed 64-bit integer (values beyond 2⁵³ lose precision as f64).
    Int64,
    /// Unsigned 64-bit integer (values beyond 2⁵³ lose precision as f64).
    UInt64,
}

impl NumericClass {
    fn from_code(class: u8) -> Option<Self> {
        Some(match class {
            6 => NumericClass::Double,
            7 => NumericClass::Single,
            8 => NumericClass::Int8,
            9 => NumericClass::UInt8,
            10 => NumericClass::Int16,
            11 => NumericClass::UInt16,
            12 => NumericClass::Int32,
            13 => NumericClass::UInt32,
            14 => NumericClass::Int64,
            15 => NumericClass::UInt64,
            _ => return None,
        })
    }

    fn code(self) -> u8 {
        match self {
            NumericClass::Double => 6,
            NumericClass::Single => 7,
            NumericClass::Int8 => 8,
            NumericClass::UInt8 => 9,
            NumericClass::Int16 => 10,
            NumericClass::UInt16 => 11,
            NumericClass::Int32 => 12,
            NumericClass::UInt32 => 13,
            NumericClass::Int64 => 14,
            NumericClass::UInt64 => 15,
        }
    }

    /// The data type MATLAB uses to store this class.
    fn storage(self) -> u32 {
        match self {
            NumericClass::Double => MI_DOUBLE,
            NumericClass::Single => MI_SINGLE,
            NumericClass::Int8 => MI_INT8,
            NumericClass::UInt8 => MI_UINT8,
            NumericClass::Int16 => MI_INT16,
            NumericClass::UInt16 => MI_UINT16,
            NumericClass::Int32 => MI_INT32,
            NumericClass::UInt32 => MI_UINT32,
            NumericClass::Int64 => MI_INT64,
            NumericClass::UInt64 => MI_UINT64,
        }
    }

    /// MATLAB's name of the class ("double", "int16", ...).
    pub fn name(self) -> &'static str {
        match self {
            NumericClass::Double => "double",
            NumericClass::Single => "single",
            NumericClass::Int8 => "int8",
            NumericClass::UInt8 => "uint8",
            NumericClass::Int16 => "int16",
            NumericClass::UInt16 => "uint16",
            NumericClass::Int32 => "int32",
            NumericClass::UInt32 => "uint32",
            NumericClass::Int64 => "int64",
            NumericClass::UInt64 => "uint64",
        }
    }
}

/// One MATLAB value, as stored in a MAT-file (arrays column-major, MATLAB's dimensions).
#[derive(Debug, Clone, PartialEq)]
pub enum MatValue {
    /// A numeric array; `real` (and `imag` when complex) hold `dims`' product values, column-major.
    Numeric {
        /// MATLAB class of the array.
        class: NumericClass,
        /// MATLAB dimensions (at least 2 as MATLAB writes them).
        dims: Vec<usize>,
        /// Real parts, column-major, converted to f64.
        real: Vec<f64>,
        /// Imaginary parts when the array is complex.
        imag: Option<Vec<f64>>,
    },
    /// A logical array, column-major.
    Logical {
        /// MATLAB dimensions.
        dims: Vec<usize>,
        /// The values, column-major.
        data: Vec<bool>,
    },
    /// A char array; a multi-row char matrix becomes its rows joined by '\n'.
    Char(String),
    /// A 1×1 struct: field name → value.
    Struct(BTreeMap<String, MatValue>),
    /// A struct array of any other size; `fields` holds one map per element, column-major.
    StructArray {
        /// MATLAB dimensions.
        dims: Vec<usize>,
        /// One field map per element, column-major.
        fields: Vec<BTreeMap<String, MatValue>>,
    },
    /// A cell array, column-major.
    Cell {
        /// MATLAB dimensions.
        dims: Vec<usize>,
        /// The cells, column-major.
        items: Vec<MatValue>,
    },
    /// A value this reader does not decode (object, sparse matrix, function handle...), described.
    Unsupported(String),
}

impl MatValue {
    /// An empty (0×0) double array, what MATLAB's `[]` is.
    pub fn empty() -> Self {
        MatValue::Numeric {
            class: NumericClass::Double,
            dims: vec![0, 0],
            real: vec![],
            imag: None,
        }
    }

    /// A real double array from MATLAB dimensions and column-major values (`None` if sizes disagree).
    pub fn double(dims: Vec<usize>, real: Vec<f64>) -> Option<Self> {
        (checked_numel(&dims) == Some(real.len())).then_some(MatValue::Numeric {
            class: NumericClass::Double,
            dims,
            real,
            imag: None,
        })
    }

    /// A 1×1 double.
    pub fn scalar(value: f64) -> Self {
        MatValue::Numeric {
            class: NumericClass::Double,
            dims: vec![1, 1],
            real: vec![value],
            imag: None,
        }
    }

    /// The value of a real numeric or logical array with exactly one element.
    pub fn as_scalar(&self) -> Option<f64> {
        match self {
            MatValue::Numeric { real, imag, .. } if real.len() == 1 => match imag {
                Some(im) if im.first().is_some_and(|v| *v != 0.0) => None,
                _ => Some(real[0]),
            },
            MatValue::Logical { data, .. } if data.len() == 1 => {
                Some(if data[0] { 1.0 } else { 0.0 })
            }
            _ => None,
        }
    }

    /// The string of a char array.
    pub fn as_str(&self) -> Option<&str> {
        match self {
            MatValue::Char(s) => Some(s),
            _ => None,
        }
    }

    /// MATLAB dimensions (1×1 for structs and chars of one row, `[]` for unsupported values).
    pub fn dims(&self) -> Vec<usize> {
        match self {
            MatValue::Numeric { dims, .. }
            | MatValue::Logical { dims, .. }
            | MatValue::StructArray { dims, .. }
            | MatValue::Cell { dims, .. } => dims.clone(),
            MatValue::Char(s) => {
                let rows: Vec<&str> = s.split('\n').collect();
                vec![rows.len(), rows.first().map_or(0, |r| r.chars().count())]
            }
            MatValue::Struct(_) => vec![1, 1],
            MatValue::Unsupported(_) => vec![],
        }
    }

    /// A short description for messages, e.g. "334×128×32 int16 array" or "struct".
    pub fn describe(&self) -> String {
        let d = |dims: &[usize]| {
            dims.iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join("×")
        };
        match self {
            MatValue::Numeric {
                class, dims, imag, ..
            } => format!(
                "{} {}{} array",
                d(dims),
                if imag.is_some() { "complex " } else { "" },
                class.name()
            ),
            MatValue::Logical { dims, .. } => format!("{} logical array", d(dims)),
            MatValue::Char(_) => "char array".into(),
            MatValue::Struct(_) => "struct".into(),
            MatValue::StructArray { dims, .. } => format!("{} struct array", d(dims)),
            MatValue::Cell { dims, .. } => format!("{} cell array", d(dims)),
            MatValue::Unsupported(what) => format!("unsupported value ({what})"),
        }
    }

    /// A field of a 1×1 struct (or of a struct array with a single element).
    pub fn field(&self, name: &str) -> Option<&MatValue> {
        match self {
            MatValue::Struct(f) => f.get(name),
            MatValue::StructArray { fields, .. } if fields.len() == 1 => fields[0].get(name),
            _ => None,
        }
    }

    /// Real values of a numeric or logical array in C order: MATLAB (a, b, c) becomes shape
    /// (c, b, a) with the same memory order; `None` for other values.
    pub fn to_array_c_order(&self) -> Option<ArrayD<f64>> {
        let (dims, values): (&[usize], Vec<f64>) = match self {
            MatValue::Numeric { dims, real, .. } => (dims, real.clone()),
            MatValue::Logical { dims, data } => {
                (dims, data.iter().map(|&b| f64::from(u8::from(b))).collect())
            }
            _ => return None,
        };
        let shape: Vec<usize> = dims.iter().rev().copied().collect();
        ArrayD::from_shape_vec(IxDyn(&shape), values).ok()
    }
}

/// The variables of a MAT-file, by name.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MatFile {
    /// The descriptive text of the 116-byte header ("MATLAB 5.0 MAT-file, Platform: ...").
    pub header: String,
    /// Every variable, by name (a later duplicate replaces an earlier one).
    pub variables: BTreeMap<String, MatValue>,
}

impl MatFile {
    /// The variable `name`, if present.
    pub fn get(&self, name: &str) -> Option<&MatValue> {
        self.variables.get(name)
    }
}

/// Reads a MATLAB v5 MAT-file (compressed or not, either byte order).
pub fn read_mat(path: &Path) -> Result<MatFile, IoError> {
    let bytes = std::fs::read(path).map_err(|e| IoError::io(path, "read", e))?;
    parse_mat(&bytes).map_err(|p| IoError::malformed(path, p))
}

/// Writes variables to a MATLAB v5 MAT-file (little-endian; zlib-compressed variables when
/// `compress`); `Unsupported` values are refused.
pub fn write_mat(
    path: &Path,
    variables: &[(&str, &MatValue)],
    compress: bool,
) -> Result<(), IoError> {
    let bytes = encode_mat(variables, false, compress).map_err(|p| IoError::Invalid {
        path: path.to_path_buf(),
        field: "the data to write".into(),
        problem: p,
    })?;
    std::fs::write(path, bytes).map_err(|e| IoError::io(path, "write", e))
}

// ---------------------------------------------------------------------------------------------
// Reading

/// A data element: its type and its bytes.
struct Element<'a> {
    ty: u32,
    data: &'a [u8],
    offset: usize,
}

/// Walks the data elements of a byte buffer.
struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
    big: bool,
}

fn u16_from(b: &[u8], big: bool) -> u16 {
    let a = [b[0], b[1]];
    if big {
        u16::from_be_bytes(a)
    } else {
        u16::from_le_bytes(a)
    }
}

fn u32_from(b: &[u8], big: bool) -> u32 {
    let a = [b[0], b[1], b[2], b[3]];
    if big {
        u32::from_be_bytes(a)
    } else {
        u32::from_le_bytes(a)
    }
}

fn u64_from(b: &[u8], big: bool) -> u64 {
    let a = [b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]];
    if big {
        u64::from_be_bytes(a)
    } else {
        u64::from_le_bytes(a)
    }
}

impl<'a> Reader<'a> {
    fn new(buf: &'a [u8], big: bool) -> Self {
        Reader { buf, pos: 0, big }
    }

    fn remaining(&self) -> usize {
        self.buf.len().saturating_sub(self.pos)
    }

    /// The next data element, `None` at the end of the buffer.
    fn next(&mut self) -> Result<Option<Element<'a>>, String> {
        let rest = self.remaining();
        if rest == 0 {
            return Ok(None);
        }
        let offset = self.pos;
        if rest < 4 {
            return Err(format!(
                "truncated data element tag at byte {offset} ({rest} bytes left)"
            ));
        }
        let w0 = u32_from(&self.buf[offset..], self.big);
        if w0 >> 16 != 0 {
            // Small data element: byte count in the upper 16 bits, data in the next 4 bytes.
            let n = (w0 >> 16) as usize;
            let ty = w0 & 0xFFFF;
            if n > 4 {
                return Err(format!(
                    "data element at byte {offset} claims to be a small element of {n} bytes (at most 4)"
                ));
            }
            let data = self
                .buf
                .get(offset + 4..offset + 4 + n)
                .ok_or_else(|| format!("truncated small data element at byte {offset}"))?;
            self.pos = (offset + 8).min(self.buf.len());
            return Ok(Some(Element { ty, data, offset }));
        }
        if rest < 8 {
            return Err(format!(
                "truncated data element tag at byte {offset} ({rest} bytes left)"
            ));
        }
        let ty = w0;
        let n = u32_from(&self.buf[offset + 4..], self.big) as usize;
        let start = offset + 8;
        let end = start
            .checked_add(n)
            .filter(|&e| e <= self.buf.len())
            .ok_or_else(|| {
                format!(
                    "truncated: the data element at byte {offset} declares {n} bytes but only {} remain",
                    self.buf.len() - start
                )
            })?;
        let data = &self.buf[start..end];
        // Compressed elements are not padded; everything else is padded to 8 bytes.
        let next = if ty == MI_COMPRESSED {
            end
        } else {
            end.saturating_add((8 - n % 8) % 8)
        };
        self.pos = next.min(self.buf.len());
        Ok(Some(Element { ty, data, offset }))
    }

    /// The next element, which must exist.
    fn expect(&mut self, what: &str) -> Result<Element<'a>, String> {
        self.next()?
            .ok_or_else(|| format!("the array ends before its {what}"))
    }
}

fn parse_mat(bytes: &[u8]) -> Result<MatFile, String> {
    if bytes.len() < 128 {
        return Err(format!(
            "not a MATLAB v5 MAT-file: {} bytes is shorter than the 128-byte header",
            bytes.len()
        ));
    }
    let text_end = bytes[..116]
        .iter()
        .rposition(|&b| b != 0 && b != b' ')
        .map_or(0, |i| i + 1);
    let header = String::from_utf8_lossy(&bytes[..text_end]).into_owned();
    let big = match &bytes[126..128] {
        b"IM" => false,
        b"MI" => true,
        _ => {
            return Err(if header.contains("MATLAB 7.3") {
                "MATLAB v7.3 (HDF5) MAT-files are not supported; save with -v7 instead".into()
            } else {
                "not a MATLAB v5 MAT-file (no 'IM'/'MI' endian indicator at byte 126)".into()
            });
        }
    };
    let version = u16_from(&bytes[124..], big);
    if version == 0x0200 || header.contains("MATLAB 7.3") {
        return Err("MATLAB v7.3 (HDF5) MAT-files are not supported; save with -v7 instead".into());
    }
    let mut file = MatFile {
        header,
        variables: BTreeMap::new(),
    };
    let mut reader = Reader {
        buf: bytes,
        pos: 128,
        big,
    };
    while let Some(el) = reader.next()? {
        match el.ty {
            MI_MATRIX => {
                let (name, value) = parse_matrix(el.data, big, 0)
                    .map_err(|e| format!("variable at byte {}: {e}", el.offset))?;
                file.variables.insert(name, value);
            }
            MI_COMPRESSED => {
                let inflated = inflate(el.data)
                    .map_err(|e| format!("compressed variable at byte {}: {e}", el.offset))?;
                let mut inner = Reader::new(&inflated, big);
                while let Some(iel) = inner
                    .next()
                    .map_err(|e| format!("compressed variable at byte {}: {e}", el.offset))?
                {
                    if iel.ty != MI_MATRIX {
                        continue;
                    }
                    let (name, value) = parse_matrix(iel.data, big, 0)
                        .map_err(|e| format!("compressed variable at byte {}: {e}", el.offset))?;
                    file.variables.insert(name, value);
                }
            }
            _ => {} // Not a variable: nothing to keep.
        }
    }
    Ok(file)
}

fn inflate(data: &[u8]) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    // A MAT element cannot exceed 4 GiB + its tag: cap what a hostile stream can make us allocate.
    flate2::read::ZlibDecoder::new(data)
        .take(u64::from(u32::MAX) + 16)
        .read_to_end(&mut out)
        .map_err(|e| format!("corrupt zlib data ({e})"))?;
    Ok(out)
}

/// Product of dimensions, `None` on overflow.
fn checked_numel(dims: &[usize]) -> Option<usize> {
    dims.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d))
}

fn element_size(ty: u32) -> Option<usize> {
    Some(match ty {
        MI_INT8 | MI_UINT8 | MI_UTF8 => 1,
        MI_INT16 | MI_UINT16 | MI_UTF16 => 2,
        MI_INT32 | MI_UINT32 | MI_SINGLE | MI_UTF32 => 4,
        MI_INT64 | MI_UINT64 | MI_DOUBLE => 8,
        _ => return None,
    })
}

/// Numbers of any storage type, as f64.
fn numbers(el: &Element, big: bool) -> Result<Vec<f64>, String> {
    let size = element_size(el.ty).ok_or_else(|| format!("data type {} is not numeric", el.ty))?;
    if !el.data.len().is_multiple_of(size) {
        return Err(format!(
            "{} bytes of data type {} is not a whole number of {size}-byte values",
            el.data.len(),
            el.ty
        ));
    }
    let chunks = el.data.chunks_exact(size);
    Ok(match el.ty {
        MI_INT8 => el.data.iter().map(|&b| f64::from(b as i8)).collect(),
        MI_UINT8 | MI_UTF8 => el.data.iter().map(|&b| f64::from(b)).collect(),
        MI_INT16 => chunks.map(|c| f64::from(u16_from(c, big) as i16)).collect(),
        MI_UINT16 | MI_UTF16 => chunks.map(|c| f64::from(u16_from(c, big))).collect(),
        MI_INT32 => chunks.map(|c| f64::from(u32_from(c, big) as i32)).collect(),
        MI_UINT32 | MI_UTF32 => chunks.map(|c| f64::from(u32_from(c, big))).collect(),
        MI_SINGLE => chunks
            .map(|c| f64::from(f32::from_bits(u32_from(c, big))))
            .collect(),
        MI_INT64 => chunks.map(|c| u64_from(c, big) as i64 as f64).collect(),
        MI_UINT64 => chunks.map(|c| u64_from(c, big) as f64).collect(),
        _ => chunks.map(|c| f64::from_bits(u64_from(c, big))).collect(),
    })
}

/// Integers of any storage type (dims, field-name length), refusing negatives and fractions.
fn sizes(el: &Element, big: bool, what: &str) -> Result<Vec<usize>, String> {
    numbers(el, big)?
        .into_iter()
        .map(|v| {
            if v >= 0.0 && v.fract() == 0.0 && v <= u32::MAX as f64 {
                Ok(v as usize)
            } else {
                Err(format!("invalid {what} {v}"))
            }
        })
        .collect()
}

fn text(el: &Element) -> String {
    let end = el
        .data
        .iter()
        .position(|&b| b == 0)
        .unwrap_or(el.data.len());
    String::from_utf8_lossy(&el.data[..end]).into_owned()
}

/// Parses the contents of a miMATRIX element: (name, value).
fn parse_matrix(data: &[u8], big: bool, depth: usize) -> Result<(String, MatValue), String> {
    if depth > MAX_DEPTH {
        return Err(format!(
            "cells/structs nested deeper than {MAX_DEPTH} levels"
        ));
    }
    if data.is_empty() {
        // MATLAB writes empty arrays inside cells and structs as an empty miMATRIX.
        return Ok((String::new(), MatValue::empty()));
    }
    let mut r = Reader::new(data, big);
    let flags_el = r.expect("array flags")?;
    if flags_el.data.len() < 4 {
        return Err("array flags subelement is shorter than 4 bytes".into());
    }
    let flags = u32_from(flags_el.data, big);
    let class = (flags & 0xFF) as u8;
    if class == MX_OPAQUE {
        // Opaque objects (strings, tables, classdef objects) have a different layout: name first.
        let name = r
            .next()
            .ok()
            .flatten()
            .map(|e| text(&e))
            .unwrap_or_default();
        return Ok((name, MatValue::Unsupported("MATLAB opaque object".into())));
    }
    let dims_el = r.expect("dimensions")?;
    let dims = sizes(&dims_el, big, "dimension")?;
    let name_el = r.expect("name")?;
    let name = text(&name_el);
    let ctx = |e: String| {
        if name.is_empty() {
            e
        } else {
            format!("'{name}': {e}")
        }
    };
    let numel = checked_numel(&dims).ok_or_else(|| ctx(format!("dimensions {dims:?} overflow")))?;
    let value = match class {
        MX_CELL => {
            if numel > r.remaining() / 8 {
                return Err(ctx(format!(
                    "a cell array of {numel} cells cannot fit in {} bytes",
                    r.remaining()
                )));
            }
            let mut items = Vec::with_capacity(numel);
            for i in 0..numel {
                let el = r.expect(&format!("cell {}", i + 1)).map_err(ctx)?;
                if el.ty != MI_MATRIX {
                    return Err(ctx(format!(
                        "cell {} is not an array (type {})",
                        i + 1,
                        el.ty
                    )));
                }
                items.push(parse_matrix(el.data, big, depth + 1).map_err(ctx)?.1);
            }
            MatValue::Cell { dims, items }
        }
        MX_STRUCT => {
            let len_el = r.expect("field name length").map_err(ctx)?;
            let len = sizes(&len_el, big, "field name length")
                .map_err(ctx)?
                .first()
                .copied()
                .unwrap_or(0);
            let names_el = r.expect("field names").map_err(ctx)?;
            let names: Vec<String> = if names_el.data.is_empty() {
                vec![]
            } else if len == 0 {
                return Err(ctx("field name length is 0 but field names follow".into()));
            } else {
                names_el
                    .data
                    .chunks(len)
                    .map(|c| {
                        text(&Element {
                            ty: MI_INT8,
                            data: c,
                            offset: 0,
                        })
                    })
                    .collect()
            };
            // Each field of each element is an array of at least 8 bytes; a struct array without
            // fields stores nothing per element, so cap its size instead.
            const MAX_FIELDLESS: usize = 1 << 20;
            let fits = if names.is_empty() {
                numel <= MAX_FIELDLESS
            } else {
                numel.saturating_mul(names.len()) <= r.remaining() / 8
            };
            if !fits {
                return Err(ctx(format!(
                    "a struct array of {numel} elements × {} fields cannot fit in {} bytes",
                    names.len(),
                    r.remaining()
                )));
            }
            let mut elements = Vec::with_capacity(numel);
            for i in 0..numel {
                let mut map = BTreeMap::new();
                for f in &names {
                    let el = r.expect(&format!("field '{f}'")).map_err(ctx)?;
                    if el.ty != MI_MATRIX {
                        return Err(ctx(format!(
                            "field '{f}' of element {} is not an array (type {})",
                            i + 1,
                            el.ty
                        )));
                    }
                    let v = parse_matrix(el.data, big, depth + 1)
                        .map_err(|e| ctx(format!("field '{f}': {e}")))?
                        .1;
                    map.insert(f.clone(), v);
                }
                elements.push(map);
            }
            if numel == 1 {
                MatValue::Struct(elements.pop().unwrap_or_default())
            } else {
                MatValue::StructArray {
                    dims,
                    fields: elements,
                }
            }
        }
        MX_OBJECT => {
            let cls = r
                .next()
                .ok()
                .flatten()
                .map(|e| text(&e))
                .unwrap_or_default();
            MatValue::Unsupported(format!("MATLAB object of class '{cls}'"))
        }
        MX_CHAR => match r.next().map_err(ctx)? {
            None => MatValue::Char(String::new()),
            Some(el) => MatValue::Char(decode_chars(&el, big, &dims).map_err(ctx)?),
        },
        MX_SPARSE => MatValue::Unsupported("sparse matrix".into()),
        MX_FUNCTION => MatValue::Unsupported("function handle".into()),
        c => match NumericClass::from_code(c) {
            None => MatValue::Unsupported(format!("MATLAB array class {c}")),
            Some(class) => {
                let real = match r.next().map_err(ctx)? {
                    Some(el) => numbers(&el, big).map_err(ctx)?,
                    None => vec![],
                };
                if real.len() != numel {
                    return Err(ctx(format!(
                        "has dimensions {dims:?} ({numel} values) but stores {} values",
                        real.len()
                    )));
                }
                let imag = if flags & FLAG_COMPLEX != 0 {
                    let im = match r.next().map_err(ctx)? {
                        Some(el) => numbers(&el, big).map_err(ctx)?,
                        None => vec![],
                    };
                    if im.len() != numel {
                        return Err(ctx(format!(
                            "has {numel} real values but {} imaginary values",
                            im.len()
                        )));
                    }
                    Some(im)
                } else {
                    None
                };
                if flags & FLAG_LOGICAL != 0 {
                    MatValue::Logical {
                        dims,
                        data: real.iter().map(|&v| v != 0.0).collect(),
                    }
                } else {
                    MatValue::Numeric {
                        class,
                        dims,
                        real,
                        imag,
                    }
                }
            }
        },
    };
    Ok((name, value))
}

/// Decodes a char array's data (UTF-16 code units, UTF-8 or 8-bit) into rows joined by '\n'.
fn decode_chars(el: &Element, big: bool, dims: &[usize]) -> Result<String, String> {
    // Code units: UTF-16 units, or Unicode scalar values for UTF-8/UTF-32/8-bit text.
    let utf16 = matches!(el.ty, MI_UINT16 | MI_UTF16 | MI_INT16);
    let units: Vec<u32> = match el.ty {
        MI_UTF8 => String::from_utf8_lossy(el.data)
            .chars()
            .map(u32::from)
            .collect(),
        _ => numbers(el, big)?.into_iter().map(|v| v as u32).collect(),
    };
    let to_string = |u: &[u32]| -> String {
        if utf16 {
            let u16s: Vec<u16> = u.iter().map(|&c| c as u16).collect();
            char::decode_utf16(u16s)
                .map(|c| c.unwrap_or(char::REPLACEMENT_CHARACTER))
                .collect()
        } else {
            u.iter()
                .map(|&c| char::from_u32(c).unwrap_or(char::REPLACEMENT_CHARACTER))
                .collect()
        }
    };
    let rows = dims.first().copied().unwrap_or(1);
    if dims.len() != 2 || rows <= 1 || checked_numel(dims) != Some(units.len()) {
        return Ok(to_string(&units));
    }
    let cols = units.len() / rows;
    let lines: Vec<String> = (0..rows)
        .map(|i| {
            let row: Vec<u32> = (0..cols).map(|j| units[i + rows * j]).collect();
            to_string(&row)
        })
        .collect();
    Ok(lines.join("\n"))
}

// ---------------------------------------------------------------------------------------------
// Writing

struct Writer {
    out: Vec<u8>,
    big: bool,
}

impl Writer {
    fn u32(&mut self, v: u32) {
        if self.big {
            self.out.extend_from_slice(&v.to_be_bytes());
        } else {
            self.out.extend_from_slice(&v.to_le_bytes());
        }
    }

    fn pad(&mut self) {
        while !self.out.len().is_multiple_of(8) {
            self.out.push(0);
        }
    }

    /// One data element, in the small format when it has 1 to 4 bytes.
    fn element(&mut self, ty: u32, data: &[u8]) -> Result<(), String> {
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

fn number_bytes(values: &[f64], ty: u32, big: bool) -> Vec<u8> {
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

fn dims_bytes(dims: &[usize], big: bool) -> Result<Vec<u8>, String> {
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
fn matrix_body(name: &str, value: &MatValue, big: bool) -> Result<Vec<u8>, String> {
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
            w.element(class.storage(), &number_bytes(real, class.storage(), big))?;
            if let Some(im) = imag {
                w.element(class.storage(), &number_bytes(im, class.storage(), big))?;
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

fn struct_body(
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
fn encode_mat(
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

#[cfg(test)]
mod tests;
