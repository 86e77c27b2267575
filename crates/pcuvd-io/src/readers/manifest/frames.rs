//! Recordings read from their file a block of frames at a time ([`pcuvd::acquisition::source::FrameSource`]),
//! so that processing a long recording never holds all of it in memory.

use std::io::Seek;
use std::ops::Range;
use std::path::{Path, PathBuf};

use ndarray::Array3;
use ndarray_npy::npy::header::{Header, Layout};
use num_complex::Complex32;
use pcuvd::acquisition::source::FrameSource;
use pcuvd::core::buffers::{array_reusing, floats_finite};
use pcuvd::{Acquisition, ChannelData, Samples};
use rayon::prelude::*;

/// Bytes a core reads from a samples file at a time, then tests and offers to the checksum while
/// they are still in L2 (positional reads from several cores: Unix's `read_exact_at`).
#[cfg(unix)]
const RUN_BYTES: usize = 256 << 10;

use crate::error::IoError;
use crate::manifest::{event_shape, kind_error, parse_manifest};

/// How one stored sample reads (little-endian).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stored {
    F4,
    F8,
    I2,
    I4,
    C8,
    C16,
}

impl Stored {
    fn bytes(self) -> usize {
        match self {
            Stored::I2 => 2,
            Stored::F4 | Stored::I4 => 4,
            Stored::F8 | Stored::C8 => 8,
            Stored::C16 => 16,
        }
    }

    fn complex(self) -> bool {
        matches!(self, Stored::C8 | Stored::C16)
    }
}

/// The samples of a pcuvd manifest whose `.npy` holds events in order (axes (frames, angles,
/// channels, samples) or (events, channels, samples), C order, little-endian), read a block of
/// frames at a time. int16 samples stay int16 on disk until their block is converted.
#[derive(Debug, Clone)]
pub struct ManifestFrames {
    acquisition: Acquisition,
    data_path: PathBuf,
    data_offset: u64,
    stored: Stored,
    demod: Option<f64>,
    /// (events, channels, samples).
    shape: (usize, usize, usize),
    /// Where the bytes read are offered to a checksum of the samples file.
    pass: crate::ReadPass,
}

impl ManifestFrames {
    /// Opens the manifest at `path` for block reading: its acquisition is read and checked and its
    /// samples file's header checked against it. `Ok(None)` when the samples are not stored in
    /// event order (another axis order, Fortran order, big-endian): read those whole.
    pub fn open(path: &Path) -> Result<Option<ManifestFrames>, IoError> {
        let parsed = parse_manifest(path)?;
        if parsed.data_member.is_some() || parsed.perm.iter().enumerate().any(|(i, &p)| i != p) {
            return Ok(None);
        }
        let data_path = parsed.data_path.clone();
        let file =
            std::fs::File::open(&data_path).map_err(|e| IoError::io(&data_path, "read", e))?;
        let file_len = file
            .metadata()
            .map_err(|e| IoError::io(&data_path, "read", e))?
            .len();
        let mut reader = std::io::BufReader::new(file);
        let header = Header::from_reader(&mut reader).map_err(|e| {
            IoError::malformed(
                &data_path,
                format!("not a valid .npy file ({})", crate::error::flat(e)),
            )
        })?;
        let data_offset = reader
            .stream_position()
            .map_err(|e| IoError::io(&data_path, "read", e))?;
        let descr = header
            .type_descriptor
            .as_string()
            .cloned()
            .unwrap_or_else(|| header.type_descriptor.to_string());
        let little = descr.starts_with('<') || descr.starts_with('|') || descr.starts_with('=');
        let stored = match descr.trim_start_matches(['<', '>', '=', '|']) {
            "f4" => Stored::F4,
            "f8" => Stored::F8,
            "i2" => Stored::I2,
            "i4" => Stored::I4,
            "c8" => Stored::C8,
            "c16" => Stored::C16,
            // Other dtypes get read_npy's own message when read whole.
            _ => return Ok(None),
        };
        if header.layout != Layout::Standard || !little || cfg!(target_endian = "big") {
            return Ok(None);
        }
        if stored.complex() != parsed.demod.is_some() {
            return Err(kind_error(path, &data_path, parsed.demod.is_some()));
        }

        let shape = event_shape(
            path,
            &parsed.acquisition,
            &data_path,
            &parsed.axes,
            &parsed.perm,
            &header.shape,
        )?;
        let expected =
            (shape.0 as u128) * (shape.1 as u128) * (shape.2 as u128) * stored.bytes() as u128;
        if data_offset as u128 + expected != file_len as u128 {
            return Err(IoError::malformed(
                &data_path,
                format!(
                    "the header announces shape {:?} of '{descr}' but the file holds {} data bytes",
                    header.shape,
                    file_len.saturating_sub(data_offset)
                ),
            ));
        }
        let n = parsed.acquisition.sequence.n_angles();
        if shape.0 == 0 || shape.0 % n != 0 {
            return Err(IoError::invalid(
                path,
                "[data]",
                format!(
                    "{} events is not a whole number of compound frames of {n}",
                    shape.0
                ),
            ));
        }
        Ok(Some(ManifestFrames {
            acquisition: parsed.acquisition,
            data_path: data_path.clone(),
            data_offset,
            stored,
            demod: parsed.demod,
            shape,
            pass: crate::ReadPass::new(&data_path),
        }))
    }

    /// The samples file.
    pub fn data_path(&self) -> &Path {
        &self.data_path
    }

    /// The hook that feeds the samples file to a checksum as its blocks are read: the file is
    /// hashed in the reader's own pass over its bytes, not read a second time.
    pub fn read_pass(&self) -> &crate::ReadPass {
        &self.pass
    }

    /// The stored values of `events`, in the file's type: read straight into their array (no
    /// byte buffer to convert from), which for float32 recordings is the array processing uses.
    fn read_stored<T: bytemuck::Pod + Sync>(
        &self,
        events: Range<usize>,
    ) -> std::io::Result<Vec<T>> {
        let per_event = self.shape.1 * self.shape.2 * self.stored.bytes() / size_of::<T>();
        let mut values = vec![T::zeroed(); events.len() * per_event];
        self.read_stored_into(events, &mut values, |_| true)?;
        Ok(values)
    }

    /// [`Self::read_stored`] into `values`, which holds exactly their number; whether `test`
    /// held for every run of values it was given (each a run just read).
    fn read_stored_into<T: bytemuck::Pod + Sync>(
        &self,
        events: Range<usize>,
        values: &mut [T],
        test: impl Fn(&[T]) -> bool + Sync,
    ) -> std::io::Result<bool> {
        let event_bytes = self.shape.1 * self.shape.2 * self.stored.bytes();
        #[cfg_attr(unix, allow(unused_mut))]
        let mut file = std::fs::File::open(&self.data_path)?;
        let start = self.data_offset + (events.start * event_bytes) as u64;
        let bytes: &mut [u8] = bytemuck::cast_slice_mut(values);
        // The file is little-endian: values read on a big-endian machine are tested once
        // their bytes are turned, below.
        let little = cfg!(target_endian = "little");
        #[cfg(unix)]
        let passed = {
            use std::os::unix::fs::FileExt;
            use std::sync::atomic::{AtomicUsize, Ordering};
            use std::sync::{Mutex, OnceLock};
            // In runs on every core, each core taking the next run not yet read: one core
            // copying a block (about a gigabyte) out of the page cache held the other idle for a
            // second per block. Each run is tested as it is read, while it is in L2, and offered
            // to the checksum in the file's order as soon as the runs before it are: hashed in
            // cache, where a hash of the whole block after reading it read it from memory
            // again. (Runs are whole values: the run size is a multiple of every stored size.)
            let unread: Vec<Mutex<Option<&mut [u8]>>> = bytes
                .chunks_mut(RUN_BYTES)
                .map(|run| Mutex::new(Some(run)))
                .collect();
            let read: Vec<OnceLock<&[u8]>> = unread.iter().map(|_| OnceLock::new()).collect();
            let next_unread = AtomicUsize::new(0);
            // Runs offered so far, held by whoever offers: a core that finds it held goes on
            // reading, and the holder offers the run too if it is read before it lets go.
            let offered = Mutex::new(0usize);
            let offer_read = |offered: &mut usize| {
                while let Some(run) = read.get(*offered).and_then(OnceLock::get) {
                    self.pass.offer(start + (*offered * RUN_BYTES) as u64, run);
                    *offered += 1;
                }
            };
            let passed = (0..rayon::current_num_threads())
                .into_par_iter()
                .map(|_| {
                    let mut passed = true;
                    loop {
                        let i = next_unread.fetch_add(1, Ordering::Relaxed);
                        let Some(slot) = unread.get(i) else {
                            return Ok::<bool, std::io::Error>(passed);
                        };
                        let run = slot
                            .lock()
                            .unwrap_or_else(|e| e.into_inner())
                            .take()
                            .expect("each run is taken once");
                        file.read_exact_at(run, start + (i * RUN_BYTES) as u64)?;
                        let run: &[u8] = run;
                        passed &= !little || test(bytemuck::cast_slice(run));
                        read[i].get_or_init(|| run);
                        if let Ok(mut offered) = offered.try_lock() {
                            offer_read(&mut offered);
                        }
                    }
                })
                .try_reduce(|| true, |a, b| Ok(a && b))?;
            // The runs read while another core was offering, after it had looked for them.
            offer_read(&mut offered.lock().unwrap_or_else(|e| e.into_inner()));
            passed
        };
        #[cfg(not(unix))]
        let passed = {
            use std::io::{Read, SeekFrom};
            file.seek(SeekFrom::Start(start))?;
            file.read_exact(bytes)?;
            self.pass.offer(start, bytes);
            !little || test(bytemuck::cast_slice(bytes))
        };
        if !little {
            values
                .iter_mut()
                .for_each(|v| bytemuck::bytes_of_mut(v).reverse());
            return Ok(test(values));
        }
        Ok(passed)
    }

    /// The stored values of `events` converted by `f` into an array of `shape`, in `reuse`'s
    /// memory where it has room.
    fn read_converted<T: bytemuck::Pod + Sync, U: Clone + bytemuck::Zeroable + Send>(
        &self,
        events: Range<usize>,
        shape: (usize, usize, usize),
        reuse: Option<Array3<U>>,
        f: impl Fn(T) -> U + Sync + Send,
    ) -> pcuvd::Result<Array3<U>> {
        let stored = self
            .read_stored::<T>(events)
            .map_err(|e| self.read_error(e))?;
        let mut array = array_reusing(reuse, shape);
        array
            .as_slice_mut()
            .expect("a new array is contiguous")
            .par_iter_mut()
            .zip(stored.par_iter())
            .for_each(|(out, &v)| *out = f(v));
        Ok(array)
    }

    /// The error of a samples file that cannot be read, naming it.
    fn read_error(&self, e: std::io::Error) -> pcuvd::Error {
        pcuvd::Error::Read(format!("{}: cannot read: {e}", self.data_path.display()))
    }

    /// Frames `frames` as [`FrameSource::read_frames`] reads them, in `reuse`'s memory where
    /// it has room for them ([`array_reusing`]: a block after another).
    fn read_block(
        &self,
        frames: Range<usize>,
        reuse: Option<ChannelData>,
    ) -> pcuvd::Result<ChannelData> {
        let n = self.acquisition.sequence.n_angles();
        if frames.start >= frames.end || frames.end > FrameSource::n_frames(self) {
            return Err(pcuvd::core::error::invalid(
                "frames",
                format!(
                    "block {frames:?} is not within the recording's {} frames",
                    FrameSource::n_frames(self)
                ),
            ));
        }
        let events = frames.start * n..frames.end * n;
        let shape = (events.len(), self.shape.1, self.shape.2);
        let (reuse_rf, reuse_iq) = match reuse.map(|block| block.samples) {
            Some(Samples::Rf(array)) => (Some(array), None),
            Some(Samples::Iq { data, .. }) => (None, Some(data)),
            None => (None, None),
        };
        // Conversions run on every core: single-threaded, they held the other core idle for
        // about a tenth of a run.
        let samples = match self.stored {
            Stored::F4 => {
                let mut array = array_reusing(reuse_rf, shape);
                let values = array.as_slice_mut().expect("a new array is contiguous");
                let finite = self
                    .read_stored_into(events, values, floats_finite)
                    .map_err(|e| self.read_error(e))?;
                if !finite {
                    return Err(self.non_finite_error(&frames));
                }
                return Ok(self.block(Samples::Rf(array)));
            }
            // Integers are finite as f32.
            Stored::I2 => {
                let samples = self.read_converted(events, shape, reuse_rf, |v: i16| f32::from(v));
                return Ok(self.block(Samples::Rf(samples?)));
            }
            Stored::I4 => {
                let samples = self.read_converted(events, shape, reuse_rf, |v: i32| v as f32);
                return Ok(self.block(Samples::Rf(samples?)));
            }
            Stored::F8 => {
                Samples::Rf(self.read_converted(events, shape, reuse_rf, |v: f64| v as f32)?)
            }
            Stored::C8 => Samples::Iq {
                data: self.read_converted(events, shape, reuse_iq, |[re, im]: [f32; 2]| {
                    Complex32::new(re, im)
                })?,
                demod_frequency: self.demod.unwrap_or(0.0),
            },
            Stored::C16 => Samples::Iq {
                data: self.read_converted(events, shape, reuse_iq, |[re, im]: [f64; 2]| {
                    Complex32::new(re as f32, im as f32)
                })?,
                demod_frequency: self.demod.unwrap_or(0.0),
            },
        };
        // Doubles past f32's range become infinite here.
        if !samples.all_finite() {
            return Err(self.non_finite_error(&frames));
        }
        Ok(self.block(samples))
    }

    /// A block of this recording holding `samples`.
    fn block(&self, samples: Samples) -> ChannelData {
        ChannelData {
            acquisition: self.acquisition.clone(),
            samples,
        }
    }

    /// The error of samples that are not all finite in the block of `frames`.
    fn non_finite_error(&self, frames: &Range<usize>) -> pcuvd::Error {
        pcuvd::Error::Read(format!(
            "{}: the samples hold NaN or Inf values in frames {frames:?} (every sample must be \
             finite)",
            self.data_path.display()
        ))
    }
}
impl FrameSource for ManifestFrames {
    fn acquisition(&self) -> &Acquisition {
        &self.acquisition
    }

    fn n_frames(&self) -> usize {
        self.shape.0 / self.acquisition.sequence.n_angles()
    }

    fn trace_shape(&self) -> (usize, usize) {
        (self.shape.1, self.shape.2)
    }

    fn read_frames(&self, frames: Range<usize>) -> pcuvd::Result<ChannelData> {
        self.read_block(frames, None)
    }

    fn read_frames_into(
        &self,
        frames: Range<usize>,
        block: &mut Option<ChannelData>,
    ) -> pcuvd::Result<()> {
        *block = Some(self.read_block(frames, block.take())?);
        Ok(())
    }
}
