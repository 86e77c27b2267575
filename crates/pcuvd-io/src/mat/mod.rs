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

mod numbers;
mod read;
mod write;

pub use numbers::{Numbers, stored_array};

use read::*;
use write::*;

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
        /// Real parts, column-major, in the type the file stores them.
        real: Numbers,
        /// Imaginary parts when the array is complex.
        imag: Option<Numbers>,
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
            real: Numbers::F64(vec![]),
            imag: None,
        }
    }

    /// A real double array from MATLAB dimensions and column-major values (`None` if sizes disagree).
    pub fn double(dims: Vec<usize>, real: Vec<f64>) -> Option<Self> {
        (checked_numel(&dims) == Some(real.len())).then_some(MatValue::Numeric {
            class: NumericClass::Double,
            dims,
            real: real.into(),
            imag: None,
        })
    }

    /// A 1×1 double.
    pub fn scalar(value: f64) -> Self {
        MatValue::Numeric {
            class: NumericClass::Double,
            dims: vec![1, 1],
            real: Numbers::F64(vec![value]),
            imag: None,
        }
    }

    /// The value of a real numeric or logical array with exactly one element.
    pub fn as_scalar(&self) -> Option<f64> {
        match self {
            MatValue::Numeric { real, imag, .. } if real.len() == 1 => match imag {
                Some(im) if im.get(0).is_some_and(|v| v != 0.0) => None,
                _ => real.get(0),
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
            MatValue::Numeric { dims, real, .. } => (dims, real.to_f64().into_owned()),
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

#[cfg(test)]
mod tests;
