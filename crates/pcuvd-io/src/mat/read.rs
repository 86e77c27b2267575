//! Parsing a MAT v5 file: its tagged data elements (compressed ones inflated), matrices, cells,
//! structs and character arrays, nested at most [`MAX_DEPTH`] deep.

use super::*;

// ---------------------------------------------------------------------------------------------
// Reading

/// A data element: its type and its bytes.
pub(super) struct Element<'a> {
    pub(super) ty: u32,
    pub(super) data: &'a [u8],
    pub(super) offset: usize,
}

/// Walks the data elements of a byte buffer.
pub(super) struct Reader<'a> {
    pub(super) buf: &'a [u8],
    pub(super) pos: usize,
    pub(super) big: bool,
}

pub(super) fn u16_from(b: &[u8], big: bool) -> u16 {
    let a = [b[0], b[1]];
    if big {
        u16::from_be_bytes(a)
    } else {
        u16::from_le_bytes(a)
    }
}

pub(super) fn u32_from(b: &[u8], big: bool) -> u32 {
    let a = [b[0], b[1], b[2], b[3]];
    if big {
        u32::from_be_bytes(a)
    } else {
        u32::from_le_bytes(a)
    }
}

pub(super) fn u64_from(b: &[u8], big: bool) -> u64 {
    let a = [b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]];
    if big {
        u64::from_be_bytes(a)
    } else {
        u64::from_le_bytes(a)
    }
}

impl<'a> Reader<'a> {
    pub(super) fn new(buf: &'a [u8], big: bool) -> Self {
        Reader { buf, pos: 0, big }
    }

    pub(super) fn remaining(&self) -> usize {
        self.buf.len().saturating_sub(self.pos)
    }

    /// The next data element, `None` at the end of the buffer.
    pub(super) fn next(&mut self) -> Result<Option<Element<'a>>, String> {
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
    pub(super) fn expect(&mut self, what: &str) -> Result<Element<'a>, String> {
        self.next()?
            .ok_or_else(|| format!("the array ends before its {what}"))
    }
}

pub(super) fn parse_mat(bytes: &[u8]) -> Result<MatFile, String> {
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
                let inflated = inflate(el.data, big)
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

pub(super) fn inflate(data: &[u8], big: bool) -> Result<Vec<u8>, String> {
    let corrupt = |e: std::io::Error| format!("corrupt zlib data ({e})");
    // A MAT element cannot exceed 4 GiB + its tag: cap what a hostile stream can make us allocate.
    let mut stream = flate2::read::ZlibDecoder::new(data).take(u64::from(u32::MAX) + 16);
    // The inflated element starts with its tag, which says its size: the output is allocated
    // once, not grown by doubling (each doubling copies it and faults in new pages). The size
    // is trusted only as far as deflate can expand the input (at most 1032:1).
    let mut tag = [0u8; 8];
    let mut filled = 0;
    while filled < tag.len() {
        match stream.read(&mut tag[filled..]).map_err(corrupt)? {
            0 => break,
            n => filled += n,
        }
    }
    let declared = u32_from(&tag[4..], big) as usize;
    let capacity = (declared + 8).min(data.len().saturating_mul(1032) + 64);
    let mut out = Vec::with_capacity(capacity.max(filled));
    out.extend_from_slice(&tag[..filled]);
    stream.read_to_end(&mut out).map_err(corrupt)?;
    Ok(out)
}

/// Product of dimensions, `None` on overflow.
pub(super) fn checked_numel(dims: &[usize]) -> Option<usize> {
    dims.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d))
}

pub(super) fn element_size(ty: u32) -> Option<usize> {
    Some(match ty {
        MI_INT8 | MI_UINT8 | MI_UTF8 => 1,
        MI_INT16 | MI_UINT16 | MI_UTF16 => 2,
        MI_INT32 | MI_UINT32 | MI_SINGLE | MI_UTF32 => 4,
        MI_INT64 | MI_UINT64 | MI_DOUBLE => 8,
        _ => return None,
    })
}

/// The size of a numeric data element's values (bytes), refusing a type that is not numeric and
/// data that is not a whole number of values.
fn value_size(el: &Element) -> Result<usize, String> {
    let size = element_size(el.ty).ok_or_else(|| format!("data type {} is not numeric", el.ty))?;
    if !el.data.len().is_multiple_of(size) {
        return Err(format!(
            "{} bytes of data type {} is not a whole number of {size}-byte values",
            el.data.len(),
            el.ty
        ));
    }
    Ok(size)
}

/// Numbers of any storage type, as f64.
pub(super) fn numbers(el: &Element, big: bool) -> Result<Vec<f64>, String> {
    let size = value_size(el)?;
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

/// The values of a numeric array's data element, kept in the type the file stores them when
/// that type is exact in f64 and narrower (MATLAB's int16 samples stay two bytes each).
pub(super) fn stored_numbers(el: &Element, big: bool) -> Result<Numbers, String> {
    use crate::array::Dtype;
    let dtype = match el.ty {
        MI_INT8 => Dtype::I8,
        MI_UINT8 => Dtype::U8,
        MI_INT16 => Dtype::I16,
        MI_UINT16 => Dtype::U16,
        MI_INT32 => Dtype::I32,
        MI_SINGLE => Dtype::F32,
        _ => return numbers(el, big).map(Numbers::F64),
    };
    value_size(el)?;
    Ok(Numbers::Stored {
        dtype,
        little: !big,
        bytes: el.data.to_vec(),
    })
}

/// Integers of any storage type (dims, field-name length), refusing negatives and fractions.
pub(super) fn sizes(el: &Element, big: bool, what: &str) -> Result<Vec<usize>, String> {
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

pub(super) fn text(el: &Element) -> String {
    let end = el
        .data
        .iter()
        .position(|&b| b == 0)
        .unwrap_or(el.data.len());
    String::from_utf8_lossy(&el.data[..end]).into_owned()
}

/// Parses the contents of a miMATRIX element: (name, value).
pub(super) fn parse_matrix(
    data: &[u8],
    big: bool,
    depth: usize,
) -> Result<(String, MatValue), String> {
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
                    Some(el) => stored_numbers(&el, big).map_err(ctx)?,
                    None => Numbers::F64(vec![]),
                };
                if real.len() != numel {
                    return Err(ctx(format!(
                        "has dimensions {dims:?} ({numel} values) but stores {} values",
                        real.len()
                    )));
                }
                let imag = if flags & FLAG_COMPLEX != 0 {
                    let im = match r.next().map_err(ctx)? {
                        Some(el) => stored_numbers(&el, big).map_err(ctx)?,
                        None => Numbers::F64(vec![]),
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
                        data: real.to_f64().iter().map(|&v| v != 0.0).collect(),
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
pub(super) fn decode_chars(el: &Element, big: bool, dims: &[usize]) -> Result<String, String> {
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
