//! [`RecordingWriter`]: a recording written a block of events at a time, its manifest last.

use std::path::{Path, PathBuf};

use pcuvd::Acquisition;

use super::write::{prepare_recording, recording_paths, write_manifest};
use crate::error::IoError;

/// A recording written a block of events at a time (RF, float32), so that a long simulation
/// never holds the whole recording: [`RecordingWriter::create`], then [`append`](Self::append)
/// every event in order, then [`finish`](Self::finish) writes the manifest. Until then the
/// samples sit under a temporary name and no manifest describes them.
pub struct RecordingWriter {
    manifest_path: PathBuf,
    npy_name: String,
    npy_path: PathBuf,
    partial: PathBuf,
    file: std::io::BufWriter<std::fs::File>,
    acquisition: Acquisition,
    provenance: toml::Table,
    /// Cardiac cycle start times (s from the first frame) for the manifest's `[cardiac]`.
    cardiac_triggers_s: Option<Vec<f64>>,
    /// (events, channels, samples) the recording will hold.
    shape: (usize, usize, usize),
    written: usize,
}

impl RecordingWriter {
    /// Starts recording `stem` in `dir` of `events` RF events of (channels, samples) each,
    /// acquired as `acquisition`.
    pub fn create(
        dir: &Path,
        stem: &str,
        acquisition: &Acquisition,
        shape: (usize, usize, usize),
        provenance: &toml::Table,
    ) -> Result<RecordingWriter, IoError> {
        let (manifest_path, npy_name, npy_path) = recording_paths(dir, stem)?;
        acquisition
            .validate()
            .map_err(|source| IoError::Recording {
                path: manifest_path.clone(),
                source,
            })?;
        let (events, channels, samples) = shape;
        let n = acquisition.sequence.n_angles();
        if events == 0 || events % n != 0 || channels != acquisition.probe.n_elements {
            return Err(IoError::invalid(
                &npy_path,
                "the samples",
                format!(
                    "{events} events of {channels} channels are not whole frames of {n} events \
                     from {} elements",
                    acquisition.probe.n_elements
                ),
            ));
        }
        prepare_recording(dir, &manifest_path)?;
        let partial = dir.join(format!(".{npy_name}.part"));
        crate::npy::track_partial(&partial, true);
        let file =
            std::fs::File::create(&partial).map_err(|e| IoError::io(&partial, "create", e))?;
        let mut file = std::io::BufWriter::new(file);
        crate::npy::write_header::<f32>(&mut file, &[events / n, n, channels, samples], &npy_path)?;
        Ok(RecordingWriter {
            manifest_path,
            npy_name,
            npy_path,
            partial,
            file,
            acquisition: acquisition.clone(),
            provenance: provenance.clone(),
            cardiac_triggers_s: None,
            shape,
            written: 0,
        })
    }

    /// The recording with the cardiac cycle start times `times` (s from the first frame) that
    /// were recorded beside it (an ECG's R-waves; a simulation's heartbeats), written as the
    /// manifest's `[cardiac].triggers_s`, which `pcuvd process` reads for its RI maps.
    pub fn with_cardiac_triggers(mut self, times: Vec<f64>) -> Self {
        self.cardiac_triggers_s = Some(times);
        self
    }

    /// Appends the next events, shape (events, channels, samples); refuses a wrong shape, more
    /// events than announced, and NaN or Inf samples.
    pub fn append(&mut self, events: ndarray::ArrayView3<f32>) -> Result<(), IoError> {
        use std::io::Write;
        let (count, channels, samples) = events.dim();
        if (channels, samples) != (self.shape.1, self.shape.2)
            || self.written + count > self.shape.0
        {
            return Err(IoError::invalid(
                &self.npy_path,
                "the samples",
                format!(
                    "a block of {:?} after {} events does not fit {:?}",
                    events.dim(),
                    self.written,
                    self.shape
                ),
            ));
        }
        // A contiguous block (what the simulator hands over) is checked and written as one slice:
        // value by value, the writes took the main thread a tenth of a second per 80 MB while the
        // other cores waited for the next block.
        let contiguous = events.as_slice().filter(|_| cfg!(target_endian = "little"));
        let finite = match contiguous {
            Some(values) => values.iter().all(|v| v.is_finite()),
            None => events.iter().all(|v| v.is_finite()),
        };
        if !finite {
            return Err(IoError::invalid(
                &self.npy_path,
                "the samples",
                "hold NaN or Inf",
            ));
        }
        let written = match contiguous {
            // Little-endian f32 in memory is the file's '<f4'.
            Some(values) => self.file.write_all(bytemuck::cast_slice(values)),
            None => events
                .iter()
                .try_for_each(|v| self.file.write_all(&v.to_le_bytes())),
        };
        written.map_err(|e| IoError::io(&self.partial, "write", e))?;
        self.written += count;
        Ok(())
    }

    /// Completes the samples file (renamed into place) and writes the manifest; returns the
    /// manifest's path. Refuses a recording with fewer events than announced.
    pub fn finish(mut self) -> Result<PathBuf, IoError> {
        use std::io::Write;
        if self.written != self.shape.0 {
            return Err(IoError::invalid(
                &self.npy_path,
                "the samples",
                format!(
                    "{} events written of the {} announced",
                    self.written, self.shape.0
                ),
            ));
        }
        self.file
            .flush()
            .and_then(|()| self.file.get_ref().sync_all())
            .map_err(|e| IoError::io(&self.partial, "write", e))?;
        std::fs::rename(&self.partial, &self.npy_path)
            .map_err(|e| IoError::io(&self.npy_path, "write", e))?;
        crate::npy::track_partial(&self.partial, false);
        write_manifest(
            &self.manifest_path,
            &self.acquisition,
            &self.npy_name,
            None,
            self.cardiac_triggers_s.as_deref(),
            &self.provenance,
        )?;
        Ok(self.manifest_path.clone())
    }
}

impl Drop for RecordingWriter {
    fn drop(&mut self) {
        // Abandoned before finish (an error, a panic): no half-written samples stay behind. After
        // finish the partial name no longer exists and this does nothing.
        let _ = std::fs::remove_file(&self.partial);
        crate::npy::track_partial(&self.partial, false);
    }
}
