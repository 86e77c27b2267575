//! Stored sample arrays (an `.npy` file, an `.npz` member, an HDF5 dataset, a MATLAB variable)
//! read a hyperslab at a time, and the [`ArrayFrames`] that hands out a recording's compound frames
//! from one: whatever the axis order the file names, int16 stays int16 on disk or in memory until
//! a block is converted.

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use ndarray::{Array3, ArrayD, IxDyn};
use num_complex::Complex32;
use pcuvd::acquisition::source::FrameSource;
use pcuvd::{Acquisition, ChannelData, Samples};

use crate::error::IoError;

mod frames;

pub use frames::*;

/// The element type of stored samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dtype {
    /// Signed 8-bit integer.
    I8,
    /// Unsigned 8-bit integer.
    U8,
    /// Signed 16-bit integer (scanners' samples).
    I16,
    /// Unsigned 16-bit integer.
    U16,
    /// Signed 32-bit integer.
    I32,
    /// 32-bit float.
    F32,
    /// 64-bit float.
    F64,
    /// Complex of two 32-bit floats.
    C64,
    /// Complex of two 64-bit floats.
    C128,
}

impl Dtype {
    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            Dtype::I8 | Dtype::U8 => 1,
            Dtype::I16 | Dtype::U16 => 2,
            Dtype::I32 | Dtype::F32 => 4,
            Dtype::F64 | Dtype::C64 => 8,
            Dtype::C128 => 16,
        }
    }

    /// True for complex elements.
    pub fn is_complex(self) -> bool {
        matches!(self, Dtype::C64 | Dtype::C128)
    }

    /// NumPy's name of the type.
    pub fn name(self) -> &'static str {
        match self {
            Dtype::I8 => "int8",
            Dtype::U8 => "uint8",
            Dtype::I16 => "int16",
            Dtype::U16 => "uint16",
            Dtype::I32 => "int32",
            Dtype::F32 => "float32",
            Dtype::F64 => "float64",
            Dtype::C64 => "complex64",
            Dtype::C128 => "complex128",
        }
    }

    /// Every element type pcuvd reads samples of.
    pub const ALL: [Dtype; 9] = [
        Dtype::I8,
        Dtype::U8,
        Dtype::I16,
        Dtype::U16,
        Dtype::I32,
        Dtype::F32,
        Dtype::F64,
        Dtype::C64,
        Dtype::C128,
    ];

    /// The accepted element types by NumPy's names ("int8, uint8, …, complex64 or complex128"),
    /// for messages that refuse another.
    pub fn accepted() -> String {
        let names: Vec<&str> = Dtype::ALL.iter().map(|d| d.name()).collect();
        let (last, rest) = names.split_last().expect("ALL is not empty");
        format!("{} or {last}", rest.join(", "))
    }

    /// The refusal of NumPy type `descr` (as the file writes it), naming the accepted types.
    pub fn unsupported(descr: &str) -> String {
        format!(
            "dtype '{descr}' is not supported (use {})",
            Dtype::accepted()
        )
    }

    /// The type of a NumPy type code without its byte-order mark ("f4", "i2", "c8"...).
    pub fn from_numpy(code: &str) -> Option<Dtype> {
        Some(match code {
            "i1" => Dtype::I8,
            // Booleans ("b1") are masks, not samples: refused with the type named.
            "u1" => Dtype::U8,
            "i2" => Dtype::I16,
            "u2" => Dtype::U16,
            "i4" => Dtype::I32,
            "f4" => Dtype::F32,
            "f8" => Dtype::F64,
            "c8" => Dtype::C64,
            "c16" => Dtype::C128,
            _ => return None,
        })
    }

    /// Decodes a contiguous row of real elements onto `out`, the type matched once for the row
    /// so that the conversion vectorises; complex types go element by element.
    fn decode_real_row(self, bytes: &[u8], little: bool, out: &mut Vec<f32>) {
        macro_rules! row {
            ($t:ty, $to:expr) => {{
                const N: usize = std::mem::size_of::<$t>();
                let chunks = bytes.chunks_exact(N);
                let arr = |c: &[u8]| -> [u8; N] { c.try_into().unwrap_or([0; N]) };
                if little {
                    out.extend(chunks.map(|c| $to(<$t>::from_le_bytes(arr(c)))));
                } else {
                    out.extend(chunks.map(|c| $to(<$t>::from_be_bytes(arr(c)))));
                }
            }};
        }
        match self {
            Dtype::I8 => out.extend(bytes.iter().map(|&b| f32::from(b as i8))),
            Dtype::U8 => out.extend(bytes.iter().map(|&b| f32::from(b))),
            Dtype::I16 => row!(i16, f32::from),
            Dtype::U16 => row!(u16, f32::from),
            Dtype::I32 => row!(i32, |v: i32| v as f32),
            Dtype::F32 => row!(f32, |v: f32| v),
            Dtype::F64 => row!(f64, |v: f64| v as f32),
            Dtype::C64 | Dtype::C128 => out.extend(
                bytes
                    .chunks_exact(self.size())
                    .map(|c| self.decode(c, little).0),
            ),
        }
    }

    /// Decodes one element of a real type exactly, as f64 (the real part of a complex one).
    pub(crate) fn decode_f64(self, bytes: &[u8], little: bool) -> f64 {
        macro_rules! num {
            ($t:ty, $b:expr) => {{
                let arr: [u8; std::mem::size_of::<$t>()] =
                    $b.try_into().unwrap_or([0; std::mem::size_of::<$t>()]);
                if little {
                    <$t>::from_le_bytes(arr)
                } else {
                    <$t>::from_be_bytes(arr)
                }
            }};
        }
        match self {
            Dtype::I8 => f64::from(bytes[0] as i8),
            Dtype::U8 => f64::from(bytes[0]),
            Dtype::I16 => f64::from(num!(i16, &bytes[..2])),
            Dtype::U16 => f64::from(num!(u16, &bytes[..2])),
            Dtype::I32 => f64::from(num!(i32, &bytes[..4])),
            Dtype::F32 | Dtype::C64 => f64::from(num!(f32, &bytes[..4])),
            Dtype::F64 | Dtype::C128 => num!(f64, &bytes[..8]),
        }
    }

    /// Decodes element `i` of little- or big-endian bytes as (re, im) (im = 0 for real types).
    fn decode(self, bytes: &[u8], little: bool) -> (f32, f32) {
        // f64 holds every real type exactly, so one rounding to f32 follows.
        let re = self.decode_f64(bytes, little) as f32;
        match self {
            Dtype::C64 => (re, Dtype::F32.decode_f64(&bytes[4..8], little) as f32),
            Dtype::C128 => (re, Dtype::F64.decode_f64(&bytes[8..16], little) as f32),
            _ => (re, 0.0),
        }
    }
}

/// Where a stored array's values are.
#[derive(Debug, Clone)]
pub enum Backing {
    /// Raw bytes at `offset` in a file (a `.npy`, or an uncompressed `.npz` member).
    File {
        /// The file.
        path: PathBuf,
        /// Byte offset of the first element.
        offset: u64,
        /// Little-endian elements.
        little: bool,
    },
    /// Raw bytes held in memory (a compressed `.npz` member, a MATLAB v5 variable of a narrower
    /// type than double: int16 stays int16).
    Bytes {
        /// The elements.
        bytes: Arc<Vec<u8>>,
        /// Little-endian elements.
        little: bool,
    },
    /// Values already decoded (a MATLAB v5 variable stored as double, or complex: real and
    /// imaginary parts as f64).
    Values {
        /// Real parts.
        real: Arc<Vec<f64>>,
        /// Imaginary parts, for complex values.
        imag: Option<Arc<Vec<f64>>>,
    },
    /// An HDF5 dataset of `rows` × `columns` (or `rows` alone) whose values in C order are the
    /// array's in C order: a URX group's `raw_data`, one row per sample (two columns, the real and
    /// imaginary parts, for complex samples), its shape given by the group's events. A selection
    /// reads the rows between its first and last element.
    Hdf5Flat {
        /// The file.
        path: PathBuf,
        /// The dataset.
        dataset: String,
        /// Values per row of a 2-D dataset; `None` for a 1-D one.
        columns: Option<usize>,
    },
    /// An HDF5 dataset, or two (the real and imaginary parts, as USTB stores complex data).
    Hdf5 {
        /// The file.
        path: PathBuf,
        /// The dataset (of real parts, when `imag` is given).
        dataset: String,
        /// The dataset of imaginary parts.
        imag: Option<String>,
    },
}

/// An N-d array of samples as a file stores it: its shape, element type, memory order and where
/// its values are; read a hyperslab at a time.
#[derive(Debug, Clone)]
pub struct StoredArray {
    /// Shape, in the order the file gives it.
    pub shape: Vec<usize>,
    /// Element type as stored (the real part's, for two HDF5 datasets).
    pub dtype: Dtype,
    /// Column-major (MATLAB, Fortran-ordered NumPy) instead of row-major.
    pub fortran: bool,
    /// Where the values are.
    pub backing: Backing,
    /// How the array is named in messages (file and member).
    pub label: String,
}

/// A hyperslab read and converted: real values as f32 or complex as complex64, C order.
#[derive(Debug, Clone, PartialEq)]
pub enum Block {
    /// Real values.
    Real(ArrayD<f32>),
    /// Complex values.
    Complex(ArrayD<Complex32>),
}

impl StoredArray {
    /// True for complex values.
    pub fn is_complex(&self) -> bool {
        self.dtype.is_complex()
            || matches!(
                &self.backing,
                Backing::Values { imag: Some(_), .. } | Backing::Hdf5 { imag: Some(_), .. }
            )
    }

    /// The element type as a person reads it ("int16", "complex (2 × float32)"...).
    pub fn dtype_name(&self) -> String {
        match &self.backing {
            Backing::Hdf5 { imag: Some(_), .. } => {
                format!(
                    "complex (real and imaginary {} datasets)",
                    self.dtype.name()
                )
            }
            Backing::Values { imag: Some(_), .. } => "complex (MATLAB)".to_string(),
            _ => self.dtype.name().to_string(),
        }
    }

    /// The file the values are read from, when not already in memory.
    pub fn file(&self) -> Option<&Path> {
        match &self.backing {
            Backing::File { path, .. }
            | Backing::Hdf5 { path, .. }
            | Backing::Hdf5Flat { path, .. } => Some(path),
            _ => None,
        }
    }

    /// Bytes of samples held in memory (0 when read from the file block by block).
    pub fn resident_bytes(&self) -> u64 {
        match &self.backing {
            Backing::Bytes { bytes, .. } => bytes.len() as u64,
            Backing::Values { real, imag } => {
                8 * (real.len() + imag.as_ref().map_or(0, |i| i.len())) as u64
            }
            _ => 0,
        }
    }

    /// Reads `ranges` (one per axis, in the stored order) as a C-ordered array of the ranges'
    /// lengths.
    pub fn read(&self, ranges: &[Range<usize>]) -> Result<Block, IoError> {
        let identity: Vec<usize> = (0..self.shape.len()).collect();
        self.read_ordered(ranges, &identity)
    }

    /// Reads `ranges` (one per axis, in the stored order) as a C-ordered array whose axes are the
    /// stored axes in `order` (a permutation): the block a reader wants, laid out as it wants it
    /// in one pass, rather than read in the stored order and copied again to permute it.
    pub fn read_ordered(&self, ranges: &[Range<usize>], order: &[usize]) -> Result<Block, IoError> {
        self.read_ordered_with(ranges, order, SPARSE_SPAN_BYTES)
    }

    /// [`Self::read_ordered`], a file's selection read run by run where the span it covers is
    /// larger than `sparse_above` bytes and twice the selection.
    fn read_ordered_with(
        &self,
        ranges: &[Range<usize>],
        order: &[usize],
        sparse_above: u64,
    ) -> Result<Block, IoError> {
        let mut sorted = order.to_vec();
        sorted.sort_unstable();
        if sorted != (0..self.shape.len()).collect::<Vec<_>>() {
            return Err(IoError::malformed(
                Path::new(&self.label),
                format!("axis order {order:?} is not a permutation of the stored axes"),
            ));
        }
        let bad = || {
            IoError::invalid(
                Path::new(&self.label),
                "the samples",
                format!(
                    "a read of {ranges:?} does not fit the stored shape {:?}",
                    self.shape
                ),
            )
        };
        if ranges.len() != self.shape.len()
            || ranges
                .iter()
                .zip(&self.shape)
                .any(|(r, &n)| r.start > r.end || r.end > n)
        {
            return Err(bad());
        }
        let stored_counts: Vec<usize> = ranges.iter().map(|r| r.len()).collect();
        let counts: Vec<usize> = order.iter().map(|&k| stored_counts[k]).collect();
        let n = crate::hdf5::element_count(&counts).ok_or_else(bad)?;
        let complex = self.is_complex();
        match &self.backing {
            Backing::Hdf5 {
                path,
                dataset,
                imag,
            } => {
                let block = read_hdf5(
                    path,
                    dataset,
                    imag.as_deref(),
                    self.dtype,
                    ranges,
                    &stored_counts,
                )?;
                Ok(match block {
                    Block::Real(a) => Block::Real(standard(a.permuted_axes(order))),
                    Block::Complex(a) => Block::Complex(standard(a.permuted_axes(order))),
                })
            }
            Backing::Hdf5Flat {
                path,
                dataset,
                columns,
            } => {
                if n == 0 {
                    return finish(&counts, vec![], None);
                }
                let (mut lo, mut hi) = (usize::MAX, 0usize);
                for_each_index_bounds(&self.shape, false, ranges, &mut lo, &mut hi);
                let width = columns.unwrap_or(1);
                let rows = lo / width..hi / width + 1;
                let (slab, slab_counts) = match columns {
                    None => (vec![rows.clone()], vec![rows.len()]),
                    Some(k) => (vec![rows.clone(), 0..*k], vec![rows.len(), *k]),
                };
                let span = match read_hdf5(path, dataset, None, self.dtype, &slab, &slab_counts)? {
                    Block::Real(a) => a.into_raw_vec_and_offset().0,
                    Block::Complex(_) => {
                        return Err(IoError::malformed(path, "a flat dataset of complex values"));
                    }
                };
                let base = rows.start * width;
                let mut re = Vec::with_capacity(n);
                for_each_row(&self.shape, false, ranges, order, |first, stride, count| {
                    re.extend((0..count).map(|i| span[first - base + i * stride]));
                });
                finish(&counts, re, None)
            }
            Backing::Values { real, imag } => {
                let mut re = Vec::with_capacity(n);
                let mut im = Vec::with_capacity(if complex { n } else { 0 });
                // A row contiguous in storage (MATLAB's samples, the fastest axis) converts as a
                // slice, which vectorises; other rows element by element.
                let row_into = |out: &mut Vec<f32>, values: &[f64], first, stride, count| match (
                    stride,
                    values.get(first..first + count),
                ) {
                    (1, Some(row)) => out.extend(row.iter().map(|&v| v as f32)),
                    _ => out
                        .extend((0..count).map(|i| {
                            values.get(first + i * stride).copied().unwrap_or(0.0) as f32
                        })),
                };
                for_each_row(
                    &self.shape,
                    self.fortran,
                    ranges,
                    order,
                    |first, stride, count| {
                        row_into(&mut re, real, first, stride, count);
                        if let Some(imag) = imag {
                            row_into(&mut im, imag, first, stride, count);
                        }
                    },
                );
                finish(&counts, re, complex.then_some(im))
            }
            Backing::Bytes { bytes, little } => {
                let (re, im) = self.decode_selection(bytes, 0, *little, ranges, order, n)?;
                finish(&counts, re, im)
            }
            Backing::File {
                path,
                offset,
                little,
            } => {
                // Read only the span of the file the selection covers (one frame block of an
                // array stored with frames as the slowest axis is one contiguous range).
                let size = self.dtype.size();
                let (mut lo, mut hi) = (usize::MAX, 0usize);
                for_each_index_bounds(&self.shape, self.fortran, ranges, &mut lo, &mut hi);
                if n == 0 {
                    return finish(&counts, vec![], complex.then_some(vec![]));
                }
                let span_bytes = ((hi + 1 - lo) * size) as u64;
                if !ranges.is_empty()
                    && span_bytes > sparse_above
                    && span_bytes > 2 * (n * size) as u64
                {
                    // A few frames of an array stored with frames as its fastest axis span
                    // nearly the whole file: only the selection's own runs are read.
                    let bytes = self.read_runs(path, *offset, ranges)?;
                    let selection = StoredArray {
                        shape: stored_counts.clone(),
                        ..self.clone()
                    };
                    let all: Vec<Range<usize>> = stored_counts.iter().map(|&c| 0..c).collect();
                    let (re, im) =
                        selection.decode_selection(&bytes, 0, *little, &all, order, n)?;
                    return finish(&counts, re, im);
                }
                let span = read_span(path, *offset, lo * size, (hi + 1 - lo) * size)?;
                let (re, im) = self.decode_selection(&span, lo, *little, ranges, order, n)?;
                finish(&counts, re, im)
            }
        }
    }

    /// The bytes of the selection `ranges` of the file at `path` (elements from byte `offset`),
    /// in the storage order of the selection as an array of its own: one read per run of
    /// elements contiguous in the file.
    fn read_runs(
        &self,
        path: &Path,
        offset: u64,
        ranges: &[Range<usize>],
    ) -> Result<Vec<u8>, IoError> {
        use std::io::{Read, Seek, SeekFrom};
        let size = self.dtype.size();
        // Axes from the slowest-varying in storage to the fastest, with their strides.
        let nd = self.shape.len();
        let axes: Vec<usize> = if self.fortran {
            (0..nd).rev().collect()
        } else {
            (0..nd).collect()
        };
        let mut strides = vec![1usize; nd];
        for w in (0..nd.saturating_sub(1)).rev() {
            strides[w] = strides[w + 1] * self.shape[axes[w + 1]];
        }
        // The run: the innermost axis not selected whole, and every faster axis.
        let mut k = nd.saturating_sub(1);
        while k > 0 && ranges[axes[k]] == (0..self.shape[axes[k]]) {
            k -= 1;
        }
        let run = ranges[axes[k]].len() * strides[k];
        let outer: Vec<Range<usize>> = axes[..k].iter().map(|&a| ranges[a].clone()).collect();
        let total: usize = outer.iter().map(|r| r.len()).product::<usize>() * run;
        let mut bytes = vec![0u8; total * size];
        let mut file = std::fs::File::open(path).map_err(|e| IoError::io(path, "read", e))?;
        let mut idx: Vec<usize> = outer.iter().map(|r| r.start).collect();
        for chunk in bytes.chunks_exact_mut(run * size) {
            let first: usize = idx.iter().zip(&strides).map(|(i, s)| i * s).sum::<usize>()
                + ranges[axes[k]].start * strides[k];
            file.seek(SeekFrom::Start(offset + (first * size) as u64))
                .and_then(|_| file.read_exact(chunk))
                .map_err(|e| IoError::io(path, "read", e))?;
            // The next outer index, the last axis fastest.
            for w in (0..k).rev() {
                idx[w] += 1;
                if idx[w] < outer[w].end {
                    break;
                }
                idx[w] = outer[w].start;
            }
        }
        Ok(bytes)
    }

    /// The selection decoded from `bytes`, which hold the stored elements from index `first_index`
    /// on: real parts, and imaginary parts for complex elements.
    fn decode_selection(
        &self,
        bytes: &[u8],
        first_index: usize,
        little: bool,
        ranges: &[Range<usize>],
        order: &[usize],
        n: usize,
    ) -> Result<(Vec<f32>, Option<Vec<f32>>), IoError> {
        let size = self.dtype.size();
        let complex = self.dtype.is_complex();
        let mut re = Vec::with_capacity(n);
        let mut im = Vec::with_capacity(if complex { n } else { 0 });
        let mut short = false;
        for_each_row(
            &self.shape,
            self.fortran,
            ranges,
            order,
            |first, stride, count| {
                let first = first - first_index;
                // A real row contiguous in storage (MATLAB's samples, the fastest axis) converts
                // as a slice; other rows element by element.
                let row = bytes.get(first * size..(first + count) * size);
                if let (1, false, Some(row)) = (stride, complex, row) {
                    self.dtype.decode_real_row(row, little, &mut re);
                    return;
                }
                for i in (0..count).map(|k| first + k * stride) {
                    let b = bytes.get(i * size..(i + 1) * size);
                    short |= b.is_none();
                    let (r, m) = b.map_or((0.0, 0.0), |b| self.dtype.decode(b, little));
                    re.push(r);
                    if complex {
                        im.push(m);
                    }
                }
            },
        );
        if short {
            return Err(IoError::malformed(
                Path::new(&self.label),
                "holds fewer bytes than its header announces",
            ));
        }
        Ok((re, complex.then_some(im)))
    }
}

/// Span of a file's selection (bytes) above which only the selection's runs are read, when they
/// are less than half of it: larger than a block of frames stored contiguously needs to be read
/// in one piece, so that ordinary blocks keep one read.
const SPARSE_SPAN_BYTES: u64 = 64 << 20;

fn read_span(path: &Path, offset: u64, start: usize, len: usize) -> Result<Vec<u8>, IoError> {
    use std::io::{Read, Seek, SeekFrom};
    let mut file = std::fs::File::open(path).map_err(|e| IoError::io(path, "read", e))?;
    file.seek(SeekFrom::Start(offset + start as u64))
        .map_err(|e| IoError::io(path, "read", e))?;
    let mut bytes = vec![0u8; len];
    file.read_exact(&mut bytes)
        .map_err(|e| IoError::io(path, "read", e))?;
    Ok(bytes)
}

fn finish(counts: &[usize], re: Vec<f32>, im: Option<Vec<f32>>) -> Result<Block, IoError> {
    let shape = IxDyn(counts);
    let err = |e: ndarray::ShapeError| IoError::malformed(Path::new(""), e.to_string());
    Ok(match im {
        None => Block::Real(ArrayD::from_shape_vec(shape, re).map_err(err)?),
        Some(im) => Block::Complex(
            ArrayD::from_shape_vec(
                shape,
                re.into_iter()
                    .zip(im)
                    .map(|(r, i)| Complex32::new(r, i))
                    .collect(),
            )
            .map_err(err)?,
        ),
    })
}

/// An array in standard (C) layout, copied only when its layout is another.
fn standard<A: Clone>(a: ArrayD<A>) -> ArrayD<A> {
    if a.is_standard_layout() {
        a
    } else {
        a.as_standard_layout().into_owned()
    }
}

/// Calls `f` with the linear storage index of every element of the selection, in C order of the
/// selection with its axes taken in `order` (a permutation of the stored axes).
fn for_each_index(
    shape: &[usize],
    fortran: bool,
    ranges: &[Range<usize>],
    order: &[usize],
    mut f: impl FnMut(usize),
) {
    for_each_row(shape, fortran, ranges, order, |first, stride, count| {
        for i in 0..count {
            f(first + i * stride);
        }
    });
}

/// [`for_each_index`] a row of the selection's innermost axis at a time: `f(first, stride,
/// count)` for the storage indices first, first + stride, … (`count` of them), so that a row
/// lying contiguous in storage can be converted as one slice.
fn for_each_row(
    shape: &[usize],
    fortran: bool,
    ranges: &[Range<usize>],
    order: &[usize],
    mut f: impl FnMut(usize, usize, usize),
) {
    let nd = shape.len();
    // Stride of each axis in storage.
    let mut strides = vec![1usize; nd];
    if fortran {
        for k in 1..nd {
            strides[k] = strides[k - 1] * shape[k - 1];
        }
    } else {
        for k in (0..nd.saturating_sub(1)).rev() {
            strides[k] = strides[k + 1] * shape[k + 1];
        }
    }
    if ranges.iter().any(|r| r.is_empty()) {
        return;
    }
    let strides: Vec<usize> = order.iter().map(|&k| strides[k]).collect();
    let ranges: Vec<Range<usize>> = order.iter().map(|&k| ranges[k].clone()).collect();
    let mut idx: Vec<usize> = ranges.iter().map(|r| r.start).collect();
    loop {
        let base: usize = idx.iter().zip(&strides).map(|(i, s)| i * s).sum();
        // Innermost axis in a tight loop.
        if nd == 0 {
            f(base, 1, 1);
            return;
        }
        let last = nd - 1;
        let row = base - idx[last] * strides[last];
        let inner = &ranges[last];
        f(
            row + inner.start * strides[last],
            strides[last],
            inner.len(),
        );
        // Advance the outer axes.
        let mut k = last;
        loop {
            if k == 0 {
                return;
            }
            k -= 1;
            idx[k] += 1;
            if idx[k] < ranges[k].end {
                break;
            }
            idx[k] = ranges[k].start;
        }
    }
}

fn for_each_index_bounds(
    shape: &[usize],
    fortran: bool,
    ranges: &[Range<usize>],
    lo: &mut usize,
    hi: &mut usize,
) {
    // The first and last selected elements bound every other one (strides are positive).
    let first: Vec<Range<usize>> = ranges.iter().map(|r| r.start..r.start + 1).collect();
    let last: Vec<Range<usize>> = ranges
        .iter()
        .map(|r| r.end.saturating_sub(1)..r.end)
        .collect();
    if ranges.iter().any(|r| r.is_empty()) {
        return;
    }
    let identity: Vec<usize> = (0..shape.len()).collect();
    for_each_index(shape, fortran, &first, &identity, |i| *lo = (*lo).min(i));
    for_each_index(shape, fortran, &last, &identity, |i| *hi = (*hi).max(i));
}

fn read_hdf5(
    path: &Path,
    dataset: &str,
    imag: Option<&str>,
    dtype: Dtype,
    ranges: &[Range<usize>],
    counts: &[usize],
) -> Result<Block, IoError> {
    use crate::hdf5::guard;
    let file = crate::hdf5::Hdf5::open(path)?;
    let starts: Vec<usize> = ranges.iter().map(|r| r.start).collect();
    let what = format!("{dataset}: read");
    let real = |name: &str| -> Result<Vec<f32>, IoError> {
        let ds = file.dataset(name)?;
        Ok(match dtype {
            Dtype::F32 => guard(path, &what, || ds.read_slice::<f32>(&starts, counts))?,
            Dtype::I16 => guard(path, &what, || ds.read_slice::<i16>(&starts, counts))?
                .into_iter()
                .map(f32::from)
                .collect(),
            _ => {
                let kind = crate::hdf5::kind_of(&guard(path, &what, || ds.datatype())?);
                crate::hdf5::read_slice_f64(path, name, &ds, kind, &starts, counts)?
                    .into_iter()
                    .map(|v| v as f32)
                    .collect()
            }
        })
    };
    match (dtype, imag) {
        (Dtype::C64 | Dtype::C128, _) => {
            let ds = file.dataset(dataset)?;
            let values: Vec<Complex32> = if dtype == Dtype::C64 {
                guard(path, &what, || {
                    ds.read_slice::<rust_hdf5::types::Complex32>(&starts, counts)
                })?
                .into_iter()
                .map(|c| Complex32::new(c.re, c.im))
                .collect()
            } else {
                guard(path, &what, || {
                    ds.read_slice::<rust_hdf5::types::Complex64>(&starts, counts)
                })?
                .into_iter()
                .map(|c| Complex32::new(c.re as f32, c.im as f32))
                .collect()
            };
            Ok(Block::Complex(
                ArrayD::from_shape_vec(IxDyn(counts), values)
                    .map_err(|e| IoError::malformed(path, e.to_string()))?,
            ))
        }
        (_, Some(imag)) => finish(counts, real(dataset)?, Some(real(imag)?)),
        (_, None) => finish(counts, real(dataset)?, None),
    }
}

/// The most one compound frame may hold (bytes as complex64): a header announcing more is taken
/// as corrupt rather than allocated (a real frame holds megabytes).
pub const MAX_FRAME_BYTES: u64 = 4 << 30;

/// Refuses a compound frame of `events` × `channels` × `samples` beyond [`MAX_FRAME_BYTES`].
pub fn check_frame_size(
    file: &Path,
    events: usize,
    channels: usize,
    samples: usize,
) -> Result<(), IoError> {
    let bytes = (events as u128) * (channels as u128) * (samples as u128) * 8;
    if bytes > u128::from(MAX_FRAME_BYTES) {
        return Err(IoError::invalid(
            file,
            "the samples",
            format!(
                "announce compound frames of {events} events × {channels} channels × {samples} \
                 samples ({:.1} GB each as complex64): more than {} GB per frame, taken as a \
                 corrupt header",
                bytes as f64 / 1e9,
                MAX_FRAME_BYTES >> 30
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selections_follow_either_memory_order() {
        // A 2 × 3 × 4 array, values = C-order linear index; the same values column-major.
        let shape = [2usize, 3, 4];
        let c: Vec<f64> = (0..24).map(f64::from).collect();
        let mut f = vec![0.0; 24];
        for i in 0..2 {
            for j in 0..3 {
                for k in 0..4 {
                    f[i + 2 * (j + 3 * k)] = c[(i * 3 + j) * 4 + k];
                }
            }
        }
        for (values, fortran) in [(c.clone(), false), (f, true)] {
            let a = StoredArray {
                shape: shape.to_vec(),
                dtype: Dtype::F64,
                fortran,
                backing: Backing::Values {
                    real: Arc::new(values),
                    imag: None,
                },
                label: "test".into(),
            };
            let Block::Real(b) = a.read(&[1..2, 0..3, 1..3]).unwrap() else {
                panic!()
            };
            assert_eq!(b.shape(), &[1, 3, 2]);
            assert_eq!(
                b.iter().copied().collect::<Vec<_>>(),
                vec![13.0, 14.0, 17.0, 18.0, 21.0, 22.0]
            );
            assert!(a.read(&[0..3, 0..3, 0..4]).is_err());
            // Axes in another order, laid out as asked: element [k, i, j] = stored [i, j, k].
            let Block::Real(p) = a.read_ordered(&[1..2, 0..3, 1..3], &[2, 0, 1]).unwrap() else {
                panic!()
            };
            assert_eq!(p.shape(), &[2, 1, 3]);
            assert!(p.is_standard_layout());
            assert_eq!(
                p.iter().copied().collect::<Vec<_>>(),
                vec![13.0, 17.0, 21.0, 14.0, 18.0, 22.0]
            );
            assert!(a.read_ordered(&[1..2, 0..3, 1..3], &[0, 0, 1]).is_err());
        }
    }

    #[test]
    fn every_real_type_converts_a_row_as_its_elements_one_by_one() {
        // Values each type holds exactly (negative ones where signed), in either byte order:
        // the row conversion (one match per row) and the element decoder (one per element)
        // give the same floats, and those are the values.
        for dtype in Dtype::ALL.into_iter().filter(|d| !d.is_complex()) {
            // Each type's extremes: an unsigned value read as signed, or a byte order swapped,
            // reads otherwise.
            let vals: [f64; 5] = match dtype {
                Dtype::I8 => [-128.0, -3.0, 0.0, 5.0, 127.0],
                Dtype::U8 => [0.0, 1.0, 128.0, 200.0, 255.0],
                Dtype::I16 => [-32768.0, -3.0, 0.0, 300.0, 32767.0],
                Dtype::U16 => [0.0, 1.0, 255.0, 40000.0, 65535.0],
                Dtype::I32 => [-2147483648.0, -3.0, 0.0, 70000.0, 2147483647.0],
                _ => [-1.5, 0.0, 3.25, 1e30, -7.0],
            };
            for little in [true, false] {
                let bytes: Vec<u8> = vals
                    .iter()
                    .flat_map(|&v| {
                        let b: Vec<u8> = match dtype {
                            Dtype::I8 => vec![v as i8 as u8],
                            Dtype::U8 => vec![v as u8],
                            Dtype::I16 => (v as i16).to_le_bytes().to_vec(),
                            Dtype::U16 => (v as u16).to_le_bytes().to_vec(),
                            Dtype::I32 => (v as i32).to_le_bytes().to_vec(),
                            Dtype::F32 => (v as f32).to_le_bytes().to_vec(),
                            Dtype::F64 => v.to_le_bytes().to_vec(),
                            Dtype::C64 | Dtype::C128 => unreachable!("real types only"),
                        };
                        if little {
                            b
                        } else {
                            b.into_iter().rev().collect()
                        }
                    })
                    .collect();
                let mut row = Vec::new();
                dtype.decode_real_row(&bytes, little, &mut row);
                let one_by_one: Vec<f32> = bytes
                    .chunks_exact(dtype.size())
                    .map(|b| dtype.decode(b, little).0)
                    .collect();
                let expected: Vec<f32> = vals.iter().map(|&v| v as f32).collect();
                assert_eq!(row, expected, "{dtype:?}, little {little}");
                assert_eq!(one_by_one, expected, "{dtype:?}, little {little}");
            }
        }
    }

    #[test]
    fn stored_bytes_read_as_their_values_in_every_order() {
        // int16 values (negative ones too) as bytes of either byte order and memory order read
        // as the same values held decoded, whatever rows the selection makes contiguous.
        let shape = [5usize, 3, 4];
        let values: Vec<i16> = (0..60)
            .map(|v| (v * 997 % 65_536 - 32_768) as i16)
            .collect();
        for fortran in [false, true] {
            let decoded = StoredArray {
                shape: shape.to_vec(),
                dtype: Dtype::F64,
                fortran,
                backing: Backing::Values {
                    real: Arc::new(values.iter().map(|&v| f64::from(v)).collect()),
                    imag: None,
                },
                label: "decoded".into(),
            };
            for little in [true, false] {
                let bytes = values
                    .iter()
                    .flat_map(|v| {
                        if little {
                            v.to_le_bytes()
                        } else {
                            v.to_be_bytes()
                        }
                    })
                    .collect();
                let stored = StoredArray {
                    dtype: Dtype::I16,
                    backing: Backing::Bytes {
                        bytes: Arc::new(bytes),
                        little,
                    },
                    ..decoded.clone()
                };
                // The same bytes after a 7-byte header in a file, read a span at a time.
                let dir = tempfile::tempdir().unwrap();
                let path = dir.path().join("samples.bin");
                let Backing::Bytes { bytes, .. } = &stored.backing else {
                    unreachable!()
                };
                std::fs::write(&path, [&[9u8; 7][..], bytes].concat()).unwrap();
                let in_file = StoredArray {
                    backing: Backing::File {
                        path,
                        offset: 7,
                        little,
                    },
                    ..stored.clone()
                };
                for (ranges, order) in [
                    ([0..5, 0..3, 0..4], [0, 1, 2]),
                    ([1..4, 1..3, 2..4], [2, 1, 0]),
                    ([0..5, 2..3, 0..4], [1, 2, 0]),
                    ([2..5, 1..2, 1..3], [0, 1, 2]),
                ] {
                    let expected = decoded.read_ordered(&ranges, &order).unwrap();
                    for array in [&stored, &in_file] {
                        assert_eq!(
                            array.read_ordered(&ranges, &order).unwrap(),
                            expected,
                            "fortran {fortran}, little {little}, {ranges:?} in {order:?}"
                        );
                    }
                    // The file read run by run, as a selection far smaller than its span is.
                    assert_eq!(
                        in_file.read_ordered_with(&ranges, &order, 0).unwrap(),
                        expected,
                        "run by run: fortran {fortran}, little {little}, {ranges:?} in {order:?}"
                    );
                }
            }
        }
    }
}
