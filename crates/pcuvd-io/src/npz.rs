//! NumPy `.npy` files and `.npz` archives (plain or compressed) as [`StoredArray`]s: an `.npy`
//! and an uncompressed `.npz` member are read from the file a block at a time; a compressed
//! member is inflated once and kept as stored (int16 stays int16 until a block is converted).

use std::io::Read;
use std::path::Path;
use std::sync::Arc;

use ndarray_npy::npy::header::{Header, Layout};

use crate::array::{Backing, Dtype, StoredArray};
use crate::error::IoError;

/// Shape, element type, order and byte order of an `.npy` header; refuses types pcuvd cannot read.
fn parse_header(
    label: &Path,
    reader: &mut impl Read,
) -> Result<(Vec<usize>, Dtype, bool, bool, u64), IoError> {
    let mut counting = CountingReader {
        inner: reader,
        count: 0,
    };
    let header = Header::from_reader(&mut counting)
        .map_err(|e| IoError::malformed(label, format!("not a valid .npy array ({e})")))?;
    let descr = header
        .type_descriptor
        .as_string()
        .cloned()
        .unwrap_or_else(|| header.type_descriptor.to_string());
    let little = !descr.starts_with('>');
    let code = descr.trim_start_matches(['<', '>', '=', '|']);
    let dtype = Dtype::from_numpy(code)
        .ok_or_else(|| IoError::malformed(label, Dtype::unsupported(&descr)))?;
    Ok((
        header.shape,
        dtype,
        header.layout == Layout::Fortran,
        little,
        counting.count,
    ))
}

struct CountingReader<'a, R> {
    inner: &'a mut R,
    count: u64,
}

impl<R: Read> Read for CountingReader<'_, R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.count += n as u64;
        Ok(n)
    }
}

fn checked_bytes(label: &Path, shape: &[usize], dtype: Dtype) -> Result<u64, IoError> {
    crate::hdf5::element_count(shape)
        .and_then(|n| n.checked_mul(dtype.size()))
        .map(|b| b as u64)
        .ok_or_else(|| IoError::malformed(label, format!("the header's shape {shape:?} overflows")))
}

/// The `.npy` file at `path` as a stored array read from the file block by block.
pub fn open_npy(path: &Path) -> Result<StoredArray, IoError> {
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, "read", e))?;
    let len = file
        .metadata()
        .map_err(|e| IoError::io(path, "read", e))?
        .len();
    let mut reader = std::io::BufReader::new(file);
    let (shape, dtype, fortran, little, offset) = parse_header(path, &mut reader)?;
    let bytes = checked_bytes(path, &shape, dtype)?;
    if offset.checked_add(bytes) != Some(len) {
        return Err(IoError::malformed(
            path,
            format!(
                "the header announces shape {shape:?} of {} ({bytes} bytes) but the file holds {} data bytes",
                dtype.name(),
                len.saturating_sub(offset)
            ),
        ));
    }
    Ok(StoredArray {
        shape,
        dtype,
        fortran,
        backing: Backing::File {
            path: path.to_path_buf(),
            offset,
            little,
        },
        label: path.display().to_string(),
    })
}

/// The names of the arrays in the `.npz` archive at `path` (without `.npy`).
pub fn npz_members(path: &Path) -> Result<Vec<String>, IoError> {
    let archive = open_zip(path)?;
    Ok(archive
        .file_names()
        .map(|n| n.strip_suffix(".npy").unwrap_or(n).to_string())
        .collect())
}

fn open_zip(path: &Path) -> Result<zip::ZipArchive<std::fs::File>, IoError> {
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, "read", e))?;
    zip::ZipArchive::new(file)
        .map_err(|e| IoError::malformed(path, format!("not a readable .npz (zip) archive: {e}")))
}

/// Array `name` of the `.npz` archive at `path`.
pub fn open_npz_member(path: &Path, name: &str) -> Result<StoredArray, IoError> {
    let mut archive = open_zip(path)?;
    let entry = format!("{name}.npy");
    let label = format!("{}:{name}", path.display());
    let label_path = Path::new(&label).to_path_buf();
    if archive.index_for_name(&entry).is_none() {
        let names = npz_members(path)?;
        return Err(IoError::missing(
            path,
            "the archive",
            format!("array '{name}' (it holds: {})", names.join(", ")),
        ));
    }
    let mut member = archive
        .by_name(&entry)
        .map_err(|e| IoError::malformed(&label_path, format!("cannot be read: {e}")))?;
    let stored = member.compression() == zip::CompressionMethod::Stored;
    let data_start = member.data_start();
    let (shape, dtype, fortran, little, offset) = parse_header(&label_path, &mut member)?;
    let bytes = checked_bytes(&label_path, &shape, dtype)?;
    if member.size() != offset + bytes {
        return Err(IoError::malformed(
            &label_path,
            format!(
                "the header announces shape {shape:?} of {} but the member holds {} data bytes",
                dtype.name(),
                member.size().saturating_sub(offset)
            ),
        ));
    }
    let backing = if stored {
        Backing::File {
            path: path.to_path_buf(),
            offset: data_start + offset,
            little,
        }
    } else {
        // Inflated as it arrives (never allocated from the header's claim), at most the
        // announced size plus one byte to detect a member longer than its header says.
        let mut data = Vec::new();
        member
            .by_ref()
            .take(bytes + 1)
            .read_to_end(&mut data)
            .map_err(|e| IoError::malformed(&label_path, format!("cannot be inflated: {e}")))?;
        if data.len() as u64 != bytes {
            return Err(IoError::malformed(
                &label_path,
                format!(
                    "holds {} data bytes, not the {bytes} its header announces",
                    data.len()
                ),
            ));
        }
        Backing::Bytes {
            bytes: Arc::new(data),
            little,
        }
    };
    Ok(StoredArray {
        shape,
        dtype,
        fortran,
        backing,
        label,
    })
}

/// A small numeric array of the archive (a parameter), as f64 values in C order with its shape.
pub fn read_npz_values(path: &Path, name: &str) -> Result<(Vec<usize>, Vec<f64>), IoError> {
    let array = open_npz_member(path, name)?;
    let n = crate::hdf5::element_count(&array.shape).unwrap_or(usize::MAX);
    if n > crate::hdf5::MAX_PARAMETER_ELEMENTS || array.is_complex() {
        return Err(IoError::invalid(
            path,
            name,
            format!(
                "must be a small real array, found shape {:?} of {}",
                array.shape,
                array.dtype.name()
            ),
        ));
    }
    exact_f64(&array).map(|v| (array.shape.clone(), v))
}

/// Every value of a small stored array exactly as f64 (C order).
fn exact_f64(array: &StoredArray) -> Result<Vec<f64>, IoError> {
    let bytes: Arc<Vec<u8>> = match &array.backing {
        Backing::Bytes { bytes, .. } => bytes.clone(),
        Backing::File { path, offset, .. } => {
            use std::io::{Seek, SeekFrom};
            let n = checked_bytes(Path::new(&array.label), &array.shape, array.dtype)?;
            let mut f = std::fs::File::open(path).map_err(|e| IoError::io(path, "read", e))?;
            f.seek(SeekFrom::Start(*offset))
                .map_err(|e| IoError::io(path, "read", e))?;
            let mut b = vec![0u8; n as usize];
            f.read_exact(&mut b)
                .map_err(|e| IoError::io(path, "read", e))?;
            Arc::new(b)
        }
        _ => {
            return Err(IoError::malformed(
                Path::new(&array.label),
                "not a stored array",
            ));
        }
    };
    let little = matches!(
        array.backing,
        Backing::Bytes { little: true, .. } | Backing::File { little: true, .. }
    );
    let size = array.dtype.size();
    let n = bytes.len() / size;
    // Values in storage order; reorder Fortran to C.
    let decode = |i: usize| -> f64 {
        let b = &bytes[i * size..(i + 1) * size];
        macro_rules! num {
            ($t:ty) => {{
                let arr = b.try_into().unwrap_or([0; std::mem::size_of::<$t>()]);
                if little {
                    <$t>::from_le_bytes(arr)
                } else {
                    <$t>::from_be_bytes(arr)
                }
            }};
        }
        match array.dtype {
            Dtype::F64 => num!(f64),
            Dtype::F32 => f64::from(num!(f32)),
            Dtype::I16 => f64::from(num!(i16)),
            Dtype::U16 => f64::from(num!(u16)),
            Dtype::I32 => f64::from(num!(i32)),
            Dtype::I8 => f64::from(b[0] as i8),
            Dtype::U8 => f64::from(b[0]),
            Dtype::C64 | Dtype::C128 => f64::NAN,
        }
    };
    let storage: Vec<f64> = (0..n).map(decode).collect();
    if !array.fortran || array.shape.len() < 2 {
        return Ok(storage);
    }
    let mut out = Vec::with_capacity(n);
    let shape = &array.shape;
    let nd = shape.len();
    let mut idx = vec![0usize; nd];
    for _ in 0..n {
        let mut lin = 0;
        let mut stride = 1;
        for k in 0..nd {
            lin += idx[k] * stride;
            stride *= shape[k];
        }
        out.push(storage.get(lin).copied().unwrap_or(f64::NAN));
        for k in (0..nd).rev() {
            idx[k] += 1;
            if idx[k] < shape[k] {
                break;
            }
            idx[k] = 0;
        }
    }
    Ok(out)
}
