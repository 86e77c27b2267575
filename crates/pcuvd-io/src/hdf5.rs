//! HDF5 files (MATLAB v7.3, USTB UFF, zea / OpenH-RF, URX, Verasonics workspaces), read without a
//! system libhdf5.
//!
//! The crate is `rust-hdf5` (pure Rust, MIT): of the three pure-Rust readers the ecosystem notes
//! measured (`hdf5-pure`, `hdf5-reader`, `rust-hdf5`), all read UFF and MATLAB v7.3 (user block,
//! structs, cells through object references, gzip + shuffle), but only `rust-hdf5` decodes zea's
//! default chunks, Blosc(zstd) with bit-shuffle, and it reads hyperslabs of chunked, compressed
//! datasets (`read_slice`), which a reader of a block of frames at a time needs. Here it reads
//! every fixture in `tests/fixtures/readers/` (h5py/libhdf5 2.0, hdf5storage, pyuff-ustb, zea).
//! Its datasets are not `Sync`, so a block reader keeps the path and reopens the file for each
//! block (a few metadata reads against a block of up to 1 GiB).

use std::path::Path;

use rust_hdf5::{DatatypeMessage, H5Dataset, H5File, H5Group, Reference};

use crate::error::IoError;

/// Bytes an HDF5 header may announce for one array pcuvd reads whole (parameters, not samples):
/// a corrupt header announcing more is refused before anything is allocated.
pub const MAX_PARAMETER_ELEMENTS: usize = 1 << 24;

/// An open HDF5 file and its path (for messages).
pub struct Hdf5 {
    /// The file.
    pub file: H5File,
    /// Its path, as given.
    pub path: std::path::PathBuf,
}

/// What a stored element is, as far as pcuvd reads it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum H5Kind {
    /// Signed or unsigned integer of `size` bytes.
    Int {
        /// Bytes per element.
        size: u32,
        /// Signed or not.
        signed: bool,
    },
    /// IEEE float of `size` bytes.
    Float {
        /// Bytes per element.
        size: u32,
    },
    /// A compound of two floats of `size` bytes each (MATLAB's and h5py's complex numbers).
    Complex {
        /// Bytes per part.
        size: u32,
    },
    /// An object reference (MATLAB cells and struct arrays).
    Reference,
    /// Anything else (strings, enums, opaque...).
    Other,
}

/// Classifies an HDF5 datatype.
pub fn kind_of(dt: &DatatypeMessage) -> H5Kind {
    match dt {
        DatatypeMessage::FixedPoint { size, signed, .. } => H5Kind::Int {
            size: *size,
            signed: *signed,
        },
        DatatypeMessage::FloatingPoint { size, .. } => H5Kind::Float { size: *size },
        DatatypeMessage::Compound { size, members } => {
            let floats = members.len() == 2
                && members.iter().all(|m| {
                    matches!(&m.datatype, DatatypeMessage::FloatingPoint { size: s, .. } if 2 * *s == *size)
                });
            if floats {
                H5Kind::Complex { size: size / 2 }
            } else {
                H5Kind::Other
            }
        }
        DatatypeMessage::Reference { .. } => H5Kind::Reference,
        _ => H5Kind::Other,
    }
}

fn h5_error(path: &Path, what: &str, e: impl std::fmt::Display) -> IoError {
    IoError::malformed(path, format!("{what}: {e}"))
}

impl Hdf5 {
    /// Opens `path` for reading (a MATLAB v7.3 file's 512-byte user block included).
    pub fn open(path: &Path) -> Result<Hdf5, IoError> {
        let file = guard(path, "cannot be opened as HDF5", || {
            rust_hdf5::H5File::options().no_locking().open(path)
        })?;
        Ok(Hdf5 {
            file,
            path: path.to_path_buf(),
        })
    }

    /// The names of the members (groups and datasets) of group `group` ("/" for the root).
    pub fn members(&self, group: &str) -> Result<Vec<String>, IoError> {
        let g = self.group(group)?;
        guard(
            &self.path,
            &format!("group {group} cannot be listed"),
            || g.link_names(),
        )
    }

    /// The group at `path` ("/" or "" for the root).
    pub fn group(&self, path: &str) -> Result<H5Group, IoError> {
        let trimmed = path.trim_matches('/');
        if trimmed.is_empty() {
            return Ok(self.file.root_group());
        }
        guard(
            &self.path,
            &format!("{path} is not a readable group"),
            || self.file.root_group().group(trimmed),
        )
    }

    /// True when a group exists at `path`.
    pub fn is_group(&self, path: &str) -> bool {
        let trimmed = path.trim_matches('/');
        trimmed.is_empty()
            || std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                self.file.root_group().group(trimmed).is_ok()
            }))
            .unwrap_or(false)
    }

    /// True when a dataset exists at `path`.
    pub fn is_dataset(&self, path: &str) -> bool {
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            self.file.dataset(path.trim_start_matches('/')).is_ok()
        }))
        .unwrap_or(false)
    }

    /// True when a group or dataset exists at `path`.
    pub fn exists(&self, path: &str) -> bool {
        self.is_dataset(path) || self.is_group(path)
    }

    /// The dataset at `path`.
    pub fn dataset(&self, path: &str) -> Result<H5Dataset, IoError> {
        guard(
            &self.path,
            &format!("{path} is not a readable dataset"),
            || self.file.dataset(path.trim_start_matches('/')),
        )
    }

    /// Shape and element kind of the dataset at `path`.
    pub fn describe(&self, path: &str) -> Result<(Vec<usize>, H5Kind), IoError> {
        let ds = self.dataset(path)?;
        let dt = guard(&self.path, &format!("{path}: datatype"), || ds.datatype())?;
        Ok((ds.shape(), kind_of(&dt)))
    }

    /// A string attribute of the group or dataset at `object`, if present and a string.
    pub fn attr_string(&self, object: &str, name: &str) -> Option<String> {
        let trimmed = object.trim_matches('/');
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            if let Ok(ds) = self.file.dataset(trimmed) {
                return ds.attr(name).ok().and_then(|a| a.read_string().ok());
            }
            let group = if trimmed.is_empty() {
                Ok(self.file.root_group())
            } else {
                self.file.root_group().group(trimmed)
            };
            group.ok().and_then(|g| g.attr_string(name).ok())
        }))
        .ok()
        .flatten()
    }

    /// Every value of the numeric dataset at `path` as f64, in the file's (C) order, with its
    /// shape; refuses more than [`MAX_PARAMETER_ELEMENTS`] values.
    pub fn read_f64(&self, path: &str) -> Result<(Vec<usize>, Vec<f64>), IoError> {
        let ds = self.dataset(path)?;
        let shape = ds.shape();
        let n = element_count(&shape).filter(|&n| n <= MAX_PARAMETER_ELEMENTS);
        if n.is_none() {
            return Err(IoError::invalid(
                &self.path,
                path,
                format!("announces shape {shape:?}: too large for a parameter"),
            ));
        }
        let dt = guard(&self.path, &format!("{path}: datatype"), || ds.datatype())?;
        if shape.is_empty() {
            // A scalar dataspace (h5py's scalars): read whole, hyperslabs need an extent.
            let what = format!("{path}: read");
            let v: Vec<f64> = match kind_of(&dt) {
                H5Kind::Float { size: 8 } => guard(&self.path, &what, || ds.read_raw::<f64>())?,
                H5Kind::Float { size: 4 } => guard(&self.path, &what, || ds.read_raw::<f32>())?
                    .into_iter()
                    .map(f64::from)
                    .collect(),
                H5Kind::Int { .. } => guard(&self.path, &what, || ds.read_numeric_as::<i64>())?
                    .into_iter()
                    .map(|v| v as f64)
                    .collect(),
                other => {
                    return Err(IoError::invalid(
                        &self.path,
                        path,
                        format!("holds {other:?}; expected a number"),
                    ));
                }
            };
            return Ok((shape, v));
        }
        let all: Vec<usize> = vec![0; shape.len()];
        let values = read_slice_f64(&self.path, path, &ds, kind_of(&dt), &all, &shape)?;
        Ok((shape, values))
    }

    /// The object references stored in the dataset at `path` (MATLAB cells, struct arrays), as
    /// the paths they point to, in the file's order.
    pub fn references(&self, path: &str) -> Result<Vec<String>, IoError> {
        let ds = self.dataset(path)?;
        if element_count(&ds.shape()).is_none_or(|n| n > MAX_PARAMETER_ELEMENTS) {
            return Err(IoError::invalid(
                &self.path,
                path,
                "announces too many references",
            ));
        }
        let refs = guard(&self.path, &format!("{path}: references"), || {
            ds.read_references()
        })?;
        refs.iter()
            .map(|r| match r {
                Reference::Object {
                    path: Some(p),
                    file: None,
                    ..
                } => Ok(p.clone()),
                other => Err(IoError::invalid(
                    &self.path,
                    path,
                    format!("holds a reference pcuvd cannot follow ({other:?})"),
                )),
            })
            .collect()
    }
}

/// The number of elements of `shape`, `None` on overflow.
pub fn element_count(shape: &[usize]) -> Option<usize> {
    shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d))
}

/// Runs a call into the HDF5 crate, turning its errors and any panic it raises on a malformed
/// file into one message naming the file (a reader must never crash on a bad input).
pub fn guard<T, E: std::fmt::Display>(
    path: &Path,
    what: &str,
    f: impl FnOnce() -> Result<T, E>,
) -> Result<T, IoError> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)) {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(h5_error(path, what, e)),
        Err(_) => Err(IoError::malformed(
            path,
            format!("{what}: the HDF5 structure is corrupt"),
        )),
    }
}

/// A hyperslab `starts`/`counts` of a numeric dataset of kind `kind`, as f64 (complex refused).
pub fn read_slice_f64(
    file: &Path,
    name: &str,
    ds: &H5Dataset,
    kind: H5Kind,
    starts: &[usize],
    counts: &[usize],
) -> Result<Vec<f64>, IoError> {
    let what = format!("{name}: read");
    Ok(match kind {
        H5Kind::Float { size: 8 } => guard(file, &what, || ds.read_slice::<f64>(starts, counts))?,
        H5Kind::Float { size: 4 } => guard(file, &what, || ds.read_slice::<f32>(starts, counts))?
            .into_iter()
            .map(f64::from)
            .collect(),
        H5Kind::Int { size: 1, signed } => {
            let v = guard(file, &what, || ds.read_slice::<u8>(starts, counts))?;
            v.into_iter()
                .map(|b| {
                    if signed {
                        f64::from(b as i8)
                    } else {
                        f64::from(b)
                    }
                })
                .collect()
        }
        H5Kind::Int { size: 2, signed } => {
            let v = guard(file, &what, || ds.read_slice::<u16>(starts, counts))?;
            v.into_iter()
                .map(|b| {
                    if signed {
                        f64::from(b as i16)
                    } else {
                        f64::from(b)
                    }
                })
                .collect()
        }
        H5Kind::Int { size: 4, signed } => {
            let v = guard(file, &what, || ds.read_slice::<u32>(starts, counts))?;
            v.into_iter()
                .map(|b| {
                    if signed {
                        f64::from(b as i32)
                    } else {
                        f64::from(b)
                    }
                })
                .collect()
        }
        H5Kind::Int { size: 8, signed } => {
            let v = guard(file, &what, || ds.read_slice::<u64>(starts, counts))?;
            v.into_iter()
                .map(|b| if signed { b as i64 as f64 } else { b as f64 })
                .collect()
        }
        other => {
            return Err(IoError::invalid(
                file,
                name,
                format!("holds {other:?} values; expected real numbers"),
            ));
        }
    })
}
