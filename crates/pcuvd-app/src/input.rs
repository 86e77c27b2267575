//! Opening a recording, any format, with the user's overrides, and the checks and warnings that
//! come before any work; what a run read ([`RunInput`]): a recording, or beamformed images
//! formed elsewhere.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use pcuvd::ChannelData;
use pcuvd::acquisition::source::FrameSource;
use pcuvd::pipeline;

/// Reads a whole recording, any format (recognised from its content). Returns the data and every
/// file it was read from (a manifest and its samples, or the one file).
pub fn read_input(path: &Path) -> Result<(ChannelData, Vec<PathBuf>)> {
    let opened = open_input(path, &pcuvd_io::Overrides::default())?;
    let data = opened.read_all()?;
    Ok((data, opened.info.files))
}

/// Opens a recording for `process` and `info`, any format, with the user's overrides: its frames
/// are read a block at a time, and its [`pcuvd_io::SourceInfo`] says what was read, by which
/// reader, and where every acquisition parameter came from.
pub fn open_input(
    path: &Path,
    overrides: &pcuvd_io::Overrides,
) -> Result<pcuvd_io::OpenedRecording> {
    let opened = pcuvd_io::open_recording(path, overrides)?;
    check_recording(path, opened.source.as_ref())?;
    Ok(opened)
}

/// The warning for RF that is band-pass sampled (f_s below twice the band's top, the band whole in
/// one Nyquist zone: valid, and demodulated as such); `None` when f_s is above twice the band's top
/// or the band folds (an error the readers give).
pub fn band_pass_warning(acq: &pcuvd::Acquisition) -> Option<String> {
    match acq.rf_band_sampling() {
        Ok(pcuvd::BandSampling::BandPass { zone }) => {
            let probe = &acq.probe;
            let (low, high) = (
                probe.center_frequency * (1.0 - probe.bandwidth / 2.0),
                probe.center_frequency * (1.0 + probe.bandwidth / 2.0),
            );
            let half = acq.sampling_frequency / 2.0;
            Some(format!(
                "f_s {:.3} MHz is below twice the band's top ({:.3} MHz): the RF is band-pass \
                 sampled, its band {:.3}–{:.3} MHz lying in Nyquist zone {zone} ({:.3}–{:.3} MHz); \
                 pcuvd demodulates it as such, but a band wider than the probe's stated bandwidth \
                 would fold onto itself",
                acq.sampling_frequency * 1e-6,
                2.0 * high * 1e-6,
                low * 1e-6,
                high * 1e-6,
                zone as f64 * half * 1e-6,
                (zone + 1) as f64 * half * 1e-6
            ))
        }
        _ => None,
    }
}

/// What frame 0 of a recording says before any work: samples at a scale that processing cannot
/// hold are refused here, before the output folder is made (a recording is scaled as a whole,
/// and `process` judges each block by its first frame, as it does here); for RF samples, the
/// [`band_pass_warning`] to print once the run is accepted.
pub fn check_first_frame(data: &dyn FrameSource) -> Result<Option<String>> {
    if data.n_frames() == 0 {
        return Ok(None);
    }
    let first = data.read_frames(0..1)?;
    let n_angles = data.acquisition().sequence.n_angles();
    pcuvd::core::lags::check_sample_peak(
        first.samples.peak_of_first_events(n_angles),
        "the samples of frame 0",
    )?;
    Ok(match first.samples {
        pcuvd::Samples::Rf(_) => band_pass_warning(data.acquisition()),
        pcuvd::Samples::Iq { .. } => None,
    })
}

/// Checks what a recording's acquisition says against its samples' shape before any work (every
/// pulse slot starts within the record), naming the file.
fn check_recording(path: &Path, data: &dyn FrameSource) -> Result<()> {
    pipeline::check_record(data.acquisition(), data.trace_shape().1)
        .with_context(|| path.display().to_string())
}

/// Creates `dir` (and parents), with a message naming it on failure.
pub fn create_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir)
        .with_context(|| format!("{}: cannot create the output folder", dir.display()))
}

/// Beamformed images formed elsewhere, opened and planned: what a run on them starts from.
pub struct OpenedImages {
    /// The images on file, which the run reads whole or a segment at a time.
    pub images: pcuvd_io::images::ImagesFile,
    /// The manifest and its images file, the format, every parameter with its source.
    pub info: pcuvd_io::SourceInfo,
    /// What summary.json, the NIfTI sidecars and the Zarr store record of them.
    pub record: ImagesRecord,
    /// The run's settings, checked against them.
    pub plan: crate::run::Plan,
    /// Bytes one frame of every series takes once read (complex64).
    pub frame_bytes: u64,
}

/// Opens the images manifest at `path` for `process`, as [`open_input`] opens a recording: the
/// run planned with `options` and `dynamics` from the manifest and the file's header (held
/// whole, or in segments of `--segment-frames` or as many frames as fit); nothing is read yet,
/// and [`OpenedImages::check_memory`] says whether the run fits.
pub fn open_images(
    path: &Path,
    options: &crate::settings::ProcessingSettings,
    dynamics: &crate::settings::DynamicsSettings,
) -> Result<OpenedImages> {
    plan_images(pcuvd_io::open::read_images_header(path)?, options, dynamics)
}

/// [`open_images`] from the images' `header`, already read.
pub fn plan_images(
    header: pcuvd_io::images::ImagesHeader,
    options: &crate::settings::ProcessingSettings,
    dynamics: &crate::settings::DynamicsSettings,
) -> Result<OpenedImages> {
    use pcuvd::form::images::ImageFrames;
    let images = header.images_file()?;
    let description = images.description();
    let frames = images.n_frames();
    let plan = crate::run::Plan::for_images(
        options,
        dynamics,
        &description,
        frames,
        header.info.cardiac_triggers_s.as_deref(),
    )?;
    Ok(OpenedImages {
        record: ImagesRecord::of(&description, frames),
        images,
        frame_bytes: header.bytes_of_frames(1),
        info: header.info,
        plan,
    })
}

impl OpenedImages {
    /// Refuses, before the images are read, a run that would not fit within `limit_gb` (else
    /// what the machine leaves), or spaces its dynamics windows further apart or drops the
    /// stage where only they do not fit and `--dynamics auto` asked for it
    /// ([`crate::memory::check_images_memory`]).
    pub fn check_memory(&mut self, limit_gb: Option<f64>) -> Result<()> {
        use pcuvd::form::images::ImageFrames;
        let frames = self.images.n_frames();
        // A segment's frames are held at once, its overlap included; else the whole series.
        let held = self
            .plan
            .segments
            .map_or(frames, |s| (s.core + s.overlap).min(frames));
        let description = self.images.description();
        let shape = (
            self.frame_bytes * held as u64,
            frames,
            description.n_angles(),
            description.frame_rate,
        );
        crate::memory::check_images_memory(&mut self.plan, shape, limit_gb)
    }
}

/// Beamformed images formed elsewhere, as the run read them.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ImagesRecord {
    /// Frames of each series.
    pub frames: usize,
    /// Compound frame rate: the images' slow-time sampling rate (Hz).
    pub frame_rate_hz: f64,
    /// The frequency their IQ was demodulated at, which turns phase into velocity (Hz).
    pub demod_frequency_hz: f64,
    /// Speed of sound (m/s).
    pub sound_speed_m_s: f64,
    /// Steering angle of each series (degrees).
    pub angles_deg: Vec<f64>,
    /// What the run did not do to them.
    pub formed: &'static str,
}

impl ImagesRecord {
    /// The record of `frames` frames of images described by `images` (grid, angles, rates).
    pub fn of(images: &pcuvd::form::images::AngleImages, frames: usize) -> Self {
        ImagesRecord {
            frames,
            frame_rate_hz: images.frame_rate,
            demod_frequency_hz: images.demodulation_frequency,
            sound_speed_m_s: images.sound_speed,
            angles_deg: images.angles.iter().map(|a| a.to_degrees()).collect(),
            formed: "formed elsewhere and read as given: no decoding, demodulation or \
                     beamforming (the series' Doppler starts at the clutter filter)",
        }
    }
}

/// What a run read: a recording of channel data, or beamformed images formed elsewhere.
#[derive(Clone, Copy)]
pub enum RunInput<'a> {
    /// Channel data that the run decoded, demodulated and beamformed.
    Recording(&'a dyn FrameSource),
    /// Images formed elsewhere.
    Images(&'a ImagesRecord),
}

impl RunInput<'_> {
    /// The compound frame rate (Hz).
    pub fn frame_rate(&self) -> f64 {
        match self {
            RunInput::Recording(data) => data.acquisition().frame_rate(),
            RunInput::Images(images) => images.frame_rate_hz,
        }
    }

    /// Frames of the recording.
    pub fn n_frames(&self) -> usize {
        match self {
            RunInput::Recording(data) => data.n_frames(),
            RunInput::Images(images) => images.frames,
        }
    }
}
