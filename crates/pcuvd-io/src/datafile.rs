//! A manifest's `[data].file`: a samples file, optionally with the array inside it —
//! `"rec.npy"`, `"rec.npz:RF"` (an array of an archive), `"rec.h5:/path/to/dataset"` (an HDF5
//! dataset, or a group holding `real` and `imag` datasets as USTB stores complex data),
//! `"rec.mat:RF"` (a MATLAB v5 or v7.3 variable). The file is resolved against the manifest's
//! folder; its format is recognised from its content.

use std::path::{Path, PathBuf};

use crate::array::{Backing, Block, Dtype, StoredArray};
use crate::container::{Container, read_head, sniff};
use crate::error::IoError;
use crate::hdf5::H5Kind;
use crate::npy::NpyArray;

/// A samples file and the array in it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DataSpec {
    /// The file, resolved against the manifest's folder.
    pub path: PathBuf,
    /// The array inside it (`None` for an `.npy`).
    pub member: Option<String>,
}

/// Splits `[data].file` = `file` of the manifest at `manifest` into the file and the array in it:
/// the whole text when it names an existing file, else the text before the first ':' that names
/// one; errors name `[data].file`.
pub fn parse_data_file(manifest: &Path, file: &str) -> Result<DataSpec, IoError> {
    let dir = manifest.parent().unwrap_or_else(|| Path::new(""));
    let whole = dir.join(file);
    if whole.is_file() {
        return Ok(DataSpec {
            path: whole,
            member: None,
        });
    }
    for (i, _) in file.match_indices(':') {
        let candidate = dir.join(&file[..i]);
        if candidate.is_file() {
            let member = file[i + 1..].to_string();
            if member.is_empty() {
                return Err(IoError::invalid(
                    manifest,
                    "[data].file",
                    format!(
                        "is {file:?}: nothing follows the ':' (name the array inside the file)"
                    ),
                ));
            }
            return Ok(DataSpec {
                path: candidate,
                member: Some(member),
            });
        }
    }
    let what = if let Some(kind) = crate::paths::what_is(&whole) {
        format!("which is {kind}, not a file")
    } else if let Some((f, _)) = file.split_once(':') {
        format!(
            "but neither {} nor {} exists",
            whole.display(),
            dir.join(f).display()
        )
    } else {
        "which does not exist".to_string()
    };
    Err(IoError::invalid(
        manifest,
        "[data].file",
        format!("names {}, {what}", whole.display()),
    ))
}

/// Opens the array `spec` names, to be read a block at a time.
pub fn open_data_array(spec: &DataSpec) -> Result<StoredArray, IoError> {
    let path = &spec.path;
    let head = read_head(path, 8192)?;
    let member = spec.member.as_deref();
    match sniff(&head) {
        Some(Container::Npy) => {
            if let Some(m) = member {
                return Err(IoError::invalid(
                    path,
                    "the array name",
                    format!("{m:?} was given but a .npy file holds one array: drop ':{m}'"),
                ));
            }
            crate::npz::open_npy(path)
        }
        Some(Container::Zip) => match member {
            Some(m) => crate::npz::open_npz_member(path, m),
            None => {
                let names = crate::npz::npz_members(path)?;
                match names.as_slice() {
                    [only] => crate::npz::open_npz_member(path, only),
                    _ => Err(IoError::invalid(
                        path,
                        "the array name",
                        format!(
                            "is missing: the archive holds {}; write \"{}:NAME\"",
                            names.join(", "),
                            file_name(path)
                        ),
                    )),
                }
            }
        },
        Some(Container::Hdf5 { .. }) => {
            let m = member.ok_or_else(|| {
                IoError::invalid(
                    path,
                    "the dataset",
                    format!(
                        "is missing: an HDF5 file holds many; write \"{}:/path/to/dataset\"",
                        file_name(path)
                    ),
                )
            })?;
            open_hdf5_array(path, m)
        }
        Some(Container::MatV5) => {
            let m = member.ok_or_else(|| {
                IoError::invalid(
                    path,
                    "the variable",
                    format!("is missing: write \"{}:VARIABLE\"", file_name(path)),
                )
            })?;
            let mut file = crate::mat::read_mat(path)?;
            match file.variables.remove(m) {
                Some(crate::mat::MatValue::Numeric {
                    dims, real, imag, ..
                }) => Ok(crate::mat::stored_array(
                    dims,
                    real,
                    imag,
                    format!("{}:{m}", path.display()),
                )),
                Some(other) => Err(IoError::invalid(
                    path,
                    format!("variable '{m}'"),
                    format!("must be a numeric array, found a {}", other.describe()),
                )),
                None => Err(IoError::missing(
                    path,
                    "the file",
                    format!("variable '{m}'"),
                )),
            }
        }
        _ => Err(IoError::malformed(
            path,
            "is not a samples file pcuvd reads (.npy, .npz, HDF5 or MATLAB .mat)",
        )),
    }
}

fn file_name(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// The HDF5 dataset `name` of `path` (or a group of `real` and `imag` datasets) as an array.
pub fn open_hdf5_array(path: &Path, name: &str) -> Result<StoredArray, IoError> {
    let h5 = crate::hdf5::Hdf5::open(path)?;
    let name = name.trim_start_matches('/').to_string();
    let (dataset, imag) = if h5.is_dataset(&name) {
        (name.clone(), None)
    } else if h5.is_dataset(&format!("{name}/real")) && h5.is_dataset(&format!("{name}/imag")) {
        (format!("{name}/real"), Some(format!("{name}/imag")))
    } else {
        return Err(IoError::missing(
            path,
            "the HDF5 file",
            format!("dataset /{name} (nor a group /{name} of 'real' and 'imag' datasets)"),
        ));
    };
    let (shape, kind) = h5.describe(&dataset)?;
    if let Some(im) = &imag {
        let (s2, _) = h5.describe(im)?;
        if s2 != shape {
            return Err(IoError::invalid(
                path,
                format!("/{name}"),
                format!("has real part of shape {shape:?} but imaginary part of shape {s2:?}"),
            ));
        }
    }
    let dtype = match kind {
        H5Kind::Int { size: 1, signed } => {
            if signed {
                Dtype::I8
            } else {
                Dtype::U8
            }
        }
        H5Kind::Int { size: 2, signed } => {
            if signed {
                Dtype::I16
            } else {
                Dtype::U16
            }
        }
        H5Kind::Int { size: 4, .. } => Dtype::I32,
        H5Kind::Float { size: 4 } => Dtype::F32,
        H5Kind::Float { size: 8 } => Dtype::F64,
        H5Kind::Complex { size: 4 } => Dtype::C64,
        H5Kind::Complex { size: 8 } => Dtype::C128,
        other => {
            return Err(IoError::invalid(
                path,
                format!("/{dataset}"),
                format!("holds {other:?} values; expected numbers"),
            ));
        }
    };
    Ok(StoredArray {
        shape,
        dtype,
        fortran: false,
        backing: Backing::Hdf5 {
            path: path.to_path_buf(),
            dataset,
            imag,
        },
        label: format!("{}:/{name}", path.display()),
    })
}

/// Reads the whole array `spec` names (what [`crate::manifest::read_recording`] holds in memory).
pub fn read_whole(spec: &DataSpec) -> Result<NpyArray, IoError> {
    if spec.member.is_none() && sniff(&read_head(&spec.path, 16)?) == Some(Container::Npy) {
        return crate::npy::read_npy(&spec.path);
    }
    let array = open_data_array(spec)?;
    let ranges: Vec<_> = array.shape.iter().map(|&d| 0..d).collect();
    Ok(match array.read(&ranges)? {
        Block::Real(a) => NpyArray::Real(a),
        Block::Complex(a) => NpyArray::Complex(a),
    })
}
