//! NumPy `.npy` and JSON files: thin writers for results, and a reader that accepts several dtypes.

use std::path::Path;

use ndarray::{ArrayBase, ArrayD, Data, Dimension};
use ndarray_npy::npy::header::Header;
use ndarray_npy::{ReadNpyExt, WritableElement, WriteNpyError};
use num_complex::{Complex32, Complex64};

use crate::array::Dtype;
use crate::error::IoError;

/// Writes `path` atomically: `write` fills a temporary file beside it (`.NAME.part`), which is
/// then renamed over `path`, so that an interrupted or failed write never leaves a truncated file
/// under the final name (a rename within one folder is atomic).
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), IoError>,
) -> Result<(), IoError> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .ok_or_else(|| IoError::malformed(path, "not a file path"))?;
    let partial = path.with_file_name(format!(".{name}.part"));
    in_progress().push(partial.clone());
    let result = write(&partial)
        .and_then(|()| std::fs::rename(&partial, path).map_err(|e| IoError::io(path, "write", e)));
    if result.is_err() {
        let _ = std::fs::remove_file(&partial);
    }
    in_progress().retain(|p| p != &partial);
    result
}

/// Temporary files of [`write_atomically`] being written now.
fn in_progress() -> std::sync::MutexGuard<'static, Vec<std::path::PathBuf>> {
    static PARTIAL: std::sync::Mutex<Vec<std::path::PathBuf>> = std::sync::Mutex::new(Vec::new());
    PARTIAL.lock().unwrap_or_else(|e| e.into_inner())
}

/// Records (`true`) or forgets (`false`) a temporary file written outside [`write_atomically`],
/// so that [`remove_partial_files`] removes it on an interrupt.
pub(crate) fn track_partial(partial: &Path, writing: bool) {
    let mut list = in_progress();
    list.retain(|p| p != partial);
    if writing {
        list.push(partial.to_path_buf());
    }
}

/// Removes the temporary files of writes still in progress: for an interrupt handler, just
/// before the process exits, so that an interrupted run leaves no `.NAME.part` behind.
pub fn remove_partial_files() {
    for partial in in_progress().drain(..) {
        let _ = std::fs::remove_file(partial);
    }
}

/// Writes an array to a `.npy` file (C order, the element's own dtype), atomically.
pub fn write_npy<A, S, D>(path: &Path, arr: &ArrayBase<S, D>) -> Result<(), IoError>
where
    A: WritableElement,
    S: Data<Elem = A>,
    D: Dimension,
{
    write_atomically(path, |partial| {
        ndarray_npy::write_npy(partial, arr).map_err(|e| match e {
            WriteNpyError::Io(source) => IoError::io(path, "write", source),
            other => IoError::malformed(path, format!("cannot write the array: {other}")),
        })
    })
}

/// Writes the header of a `.npy` of `T` of `shape` in C order to `file`, whose values are then
/// written after it, in that order, as `T`'s native bytes (which the header's type names);
/// `path` is the file the user will see, named by an error.
pub(crate) fn write_header<T: WritableElement>(
    file: &mut impl std::io::Write,
    shape: &[usize],
    path: &Path,
) -> Result<(), IoError> {
    Header {
        type_descriptor: T::type_descriptor(),
        layout: ndarray_npy::npy::header::Layout::Standard,
        shape: shape.to_vec(),
    }
    .write(file)
    .map_err(|e| IoError::malformed(path, format!("cannot write the header: {e}")))
}

/// Writes a `.npy` of f64 of `shape` (C order), atomically, one slice of its first axis at a
/// time: `slice(i)` gives slice `i`, of the other axes' shape. An array too large to hold twice
/// (a long recording's speed in every window) is written without a copy of it whole.
pub fn write_npy_by_slices(
    path: &Path,
    shape: &[usize],
    mut slice: impl FnMut(usize) -> ndarray::ArrayD<f64>,
) -> Result<(), IoError> {
    use std::io::Write;
    let (&first, rest) = shape
        .split_first()
        .ok_or_else(|| IoError::malformed(path, "an array without axes"))?;
    let rest = rest.to_vec();
    write_atomically(path, |partial| {
        let io = |e: std::io::Error| IoError::io(path, "write", e);
        let mut file = std::io::BufWriter::new(std::fs::File::create(partial).map_err(io)?);
        write_header::<f64>(&mut file, shape, path)?;
        for i in 0..first {
            let values = slice(i);
            if values.shape() != rest.as_slice() {
                return Err(IoError::malformed(
                    path,
                    format!("slice {i} has shape {:?}, not {rest:?}", values.shape()),
                ));
            }
            let standard = values.as_standard_layout();
            let floats = standard.as_slice().expect("standard layout is contiguous");
            file.write_all(bytemuck::cast_slice(floats)).map_err(io)?;
        }
        file.flush().map_err(io)
    })
}

/// Writes a JSON value to a file, pretty-printed, with a final newline, atomically.
pub fn write_json<T: serde::Serialize + ?Sized>(path: &Path, value: &T) -> Result<(), IoError> {
    let mut text = serde_json::to_string_pretty(value)
        .map_err(|e| IoError::malformed(path, format!("cannot format JSON: {e}")))?;
    text.push('\n');
    write_atomically(path, |partial| {
        std::fs::write(partial, text).map_err(|e| IoError::io(path, "write", e))
    })
}

/// An array read from a `.npy` file: real values as f32, or complex values as complex64.
#[derive(Debug, Clone, PartialEq)]
pub enum NpyArray {
    /// float32, float64, int16 or int32 data, converted to f32.
    Real(ArrayD<f32>),
    /// complex64 or complex128 data, converted to complex64.
    Complex(ArrayD<Complex32>),
}

impl NpyArray {
    /// Shape of the array.
    pub fn shape(&self) -> &[usize] {
        match self {
            NpyArray::Real(a) => a.shape(),
            NpyArray::Complex(a) => a.shape(),
        }
    }
}

/// Reads a `.npy` file of any [`Dtype`]: real types (→ [`NpyArray::Real`]) or c8, c16
/// (→ [`NpyArray::Complex`]), either byte order, C or Fortran order.
pub fn read_npy(path: &Path) -> Result<NpyArray, IoError> {
    use std::io::{Seek, SeekFrom};
    // Read from the file, not from its bytes in memory: a long recording would otherwise be held
    // twice while it is read (the file's bytes and the array).
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, "read", e))?;
    let file_len = file
        .metadata()
        .map_err(|e| IoError::io(path, "read", e))?
        .len();
    let mut reader = std::io::BufReader::new(file);
    let header = Header::from_reader(&mut reader).map_err(|e| {
        IoError::malformed(
            path,
            format!("not a valid .npy file ({})", crate::error::flat(e)),
        )
    })?;
    let header_len = reader
        .stream_position()
        .map_err(|e| IoError::io(path, "read", e))?;
    let data_len = file_len.saturating_sub(header_len);
    let descr = header
        .type_descriptor
        .as_string()
        .cloned()
        .unwrap_or_else(|| header.type_descriptor.to_string());
    let code = descr.trim_start_matches(['<', '>', '=', '|']);
    let dtype = Dtype::from_numpy(code)
        .ok_or_else(|| IoError::malformed(path, Dtype::unsupported(&descr)))?;
    let item = dtype.size();
    let expected = header
        .shape
        .iter()
        .try_fold(item, |acc: usize, &d| acc.checked_mul(d));
    if expected.map(|e| e as u64) != Some(data_len) {
        return Err(IoError::malformed(
            path,
            format!(
                "the header announces shape {:?} of '{descr}' but the file holds {data_len} data bytes",
                header.shape,
            ),
        ));
    }
    let bad = |e: ndarray_npy::ReadNpyError| {
        IoError::malformed(path, format!("cannot read the array ({e})"))
    };
    reader
        .seek(SeekFrom::Start(0))
        .map_err(|e| IoError::io(path, "read", e))?;
    let r = reader;
    let real = |a: ArrayD<f32>| NpyArray::Real(a);
    Ok(match dtype {
        Dtype::F32 => real(ArrayD::<f32>::read_npy(r).map_err(bad)?),
        Dtype::F64 => real(ArrayD::<f64>::read_npy(r).map_err(bad)?.mapv(|v| v as f32)),
        Dtype::I8 => real(ArrayD::<i8>::read_npy(r).map_err(bad)?.mapv(f32::from)),
        Dtype::U8 => real(ArrayD::<u8>::read_npy(r).map_err(bad)?.mapv(f32::from)),
        Dtype::I16 => real(ArrayD::<i16>::read_npy(r).map_err(bad)?.mapv(f32::from)),
        Dtype::U16 => real(ArrayD::<u16>::read_npy(r).map_err(bad)?.mapv(f32::from)),
        Dtype::I32 => real(ArrayD::<i32>::read_npy(r).map_err(bad)?.mapv(|v| v as f32)),
        Dtype::C64 => NpyArray::Complex(ArrayD::<Complex32>::read_npy(r).map_err(bad)?),
        Dtype::C128 => NpyArray::Complex(
            ArrayD::<Complex64>::read_npy(r)
                .map_err(bad)?
                .mapv(|v| Complex32::new(v.re as f32, v.im as f32)),
        ),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::{Array2, array};

    /// Slice by slice is the same file as the array whole: header and values, byte for byte;
    /// a slice of another shape is refused and leaves no file.
    #[test]
    fn an_array_written_by_slices_is_the_array_written_whole() {
        let dir = tempfile::tempdir().unwrap();
        let whole = ndarray::Array3::from_shape_fn((5, 3, 4), |(k, i, j)| {
            (k * 100 + i * 10 + j) as f64 * 0.37 - 8.0
        });
        let (a, b) = (dir.path().join("whole.npy"), dir.path().join("slices.npy"));
        write_npy(&a, &whole).unwrap();
        write_npy_by_slices(&b, &[5, 3, 4], |k| {
            whole.index_axis(ndarray::Axis(0), k).to_owned().into_dyn()
        })
        .unwrap();
        assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
        let c = dir.path().join("wrong.npy");
        let refused = write_npy_by_slices(&c, &[5, 3, 4], |_| ndarray::ArrayD::zeros(vec![4, 3]));
        assert!(
            refused
                .unwrap_err()
                .to_string()
                .contains("slice 0 has shape [4, 3]")
        );
        assert!(!c.exists());
    }

    #[test]
    fn write_and_read_each_dtype() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.npy");
        let a: Array2<f64> = array![[1.0, 2.0], [3.0, 4.5]];
        write_npy(&p, &a).unwrap();
        assert_eq!(
            read_npy(&p).unwrap(),
            NpyArray::Real(a.mapv(|v| v as f32).into_dyn())
        );
        write_npy(&p, &a.t()).unwrap(); // not C-contiguous: still written in logical order
        assert_eq!(
            read_npy(&p).unwrap(),
            NpyArray::Real(a.t().mapv(|v| v as f32).into_dyn())
        );
        let i: Array2<i16> = array![[1, -2]];
        write_npy(&p, &i).unwrap();
        assert_eq!(read_npy(&p).unwrap().shape(), &[1, 2]);
        let c = array![Complex64::new(1.0, -1.0)];
        write_npy(&p, &c).unwrap();
        assert_eq!(
            read_npy(&p).unwrap(),
            NpyArray::Complex(array![Complex32::new(1.0, -1.0)].into_dyn())
        );
        // Every accepted type reads, as the streaming reader reads it.
        write_npy(&p, &array![1u8, 255]).unwrap();
        assert_eq!(
            read_npy(&p).unwrap(),
            NpyArray::Real(array![1.0f32, 255.0].into_dyn())
        );
        write_npy(&p, &array![-128i8, 7]).unwrap();
        assert_eq!(
            read_npy(&p).unwrap(),
            NpyArray::Real(array![-128.0f32, 7.0].into_dyn())
        );
        write_npy(&p, &array![65535u16, 3]).unwrap();
        assert_eq!(
            read_npy(&p).unwrap(),
            NpyArray::Real(array![65535.0f32, 3.0].into_dyn())
        );
        write_npy(&p, &array![true, false]).unwrap();
        let e = read_npy(&p).unwrap_err().to_string();
        assert!(e.contains(&crate::array::Dtype::unsupported("|b1")), "{e}");
        // Truncated data, bad header: errors, not panics.
        write_npy(&p, &a).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        for cut in 0..bytes.len() {
            std::fs::write(&p, &bytes[..cut]).unwrap();
            let e = read_npy(&p).unwrap_err().to_string();
            assert!(e.starts_with(&p.display().to_string()), "{e}");
        }
        let e = write_npy(&dir.path().join("no/such/dir.npy"), &a).unwrap_err();
        assert!(e.to_string().contains("cannot write"), "{e}");
    }

    #[test]
    fn json() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("r.json");
        write_json(&p, &serde_json::json!({"rmse_m_s": 0.01})).unwrap();
        let back: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
        assert_eq!(back["rmse_m_s"], 0.01);
    }
}
