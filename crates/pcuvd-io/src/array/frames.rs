//! [`ArrayFrames`]: a recording's compound frames handed out from one stored array, whatever the
//! axis order the file names, a block of frames read and converted at a time.

use super::*;

/// What one axis of a stored array is, in pcuvd's terms.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Axis {
    /// Compound frames.
    Frames,
    /// The transmits (angles) of a compound frame.
    Angles,
    /// Transmit events in time order (frames × angles).
    Events,
    /// Receive channels (elements).
    Channels,
    /// Fast-time samples.
    Samples,
    /// Two values, real and imaginary parts (zea's IQ `n_ch` = 2).
    ReIm,
    /// An axis of length 1 (zea's RF `n_ch` = 1, MATLAB's trailing singletons).
    Unit,
}

impl Axis {
    /// The axis name a manifest or message uses.
    pub fn name(self) -> &'static str {
        match self {
            Axis::Frames => "frames",
            Axis::Angles => "angles",
            Axis::Events => "events",
            Axis::Channels => "channels",
            Axis::Samples => "samples",
            Axis::ReIm => "re_im",
            Axis::Unit => "unit",
        }
    }
}

/// A recording read from a [`StoredArray`] a block of frames at a time: the array's axes are named
/// ([`Axis`]), any order; blocks come out as (events, channels, samples).
#[derive(Debug, Clone)]
pub struct ArrayFrames {
    pub(super) acquisition: Acquisition,
    pub(super) array: StoredArray,
    pub(super) axes: Vec<Axis>,
    /// Demodulation frequency of IQ samples (Hz); `None` for RF.
    pub(super) demod: Option<f64>,
    /// (events, channels, samples).
    pub(super) shape: (usize, usize, usize),
}

impl ArrayFrames {
    /// Checks `axes` against `array` and `acquisition` (channels = elements, angles, whole frames,
    /// IQ ⇔ `demod`) and returns the source. `file` names the recording in messages.
    pub fn new(
        file: &Path,
        acquisition: Acquisition,
        array: StoredArray,
        axes: Vec<Axis>,
        demod: Option<f64>,
    ) -> Result<ArrayFrames, IoError> {
        let field = "the samples";
        let fail = |p: String| IoError::invalid(file, field, p);
        if axes.len() != array.shape.len() {
            return Err(fail(format!(
                "{} has {} axes (shape {:?}) but {} are named",
                array.label,
                array.shape.len(),
                array.shape,
                axes.len()
            )));
        }
        let size = |a: Axis| axes.iter().position(|&b| b == a).map(|i| array.shape[i]);
        for a in [
            Axis::Frames,
            Axis::Angles,
            Axis::Events,
            Axis::Channels,
            Axis::Samples,
            Axis::ReIm,
        ] {
            if axes.iter().filter(|&&b| b == a).count() > 1 {
                return Err(fail(format!("axis '{}' is named twice", a.name())));
            }
        }
        if let Some(i) = axes
            .iter()
            .zip(&array.shape)
            .position(|(&a, &n)| a == Axis::Unit && n != 1)
        {
            return Err(fail(format!(
                "axis {i} of {} has length {} but must be 1 (shape {:?})",
                array.label, array.shape[i], array.shape
            )));
        }
        let n = acquisition.sequence.n_angles();
        let events = match (size(Axis::Frames), size(Axis::Angles), size(Axis::Events)) {
            (Some(f), Some(a), None) => {
                if a != n {
                    return Err(fail(format!(
                        "the acquisition has {n} angles but the 'angles' axis of {} has {a} (shape {:?})",
                        array.label, array.shape
                    )));
                }
                f.checked_mul(a)
                    .ok_or_else(|| fail("too many events".into()))?
            }
            (Some(f), None, None) if n == 1 => f,
            (None, None, Some(e)) => e,
            _ => {
                return Err(fail(format!(
                    "the axes of {} must include 'frames' and 'angles', or 'events' (named: {})",
                    array.label,
                    axes.iter().map(|a| a.name()).collect::<Vec<_>>().join(", ")
                )));
            }
        };
        let channels = size(Axis::Channels)
            .ok_or_else(|| fail(format!("no axis of {} is 'channels'", array.label)))?;
        let samples = size(Axis::Samples)
            .ok_or_else(|| fail(format!("no axis of {} is 'samples'", array.label)))?;
        let re_im = size(Axis::ReIm);
        if let Some(k) = re_im
            && (k != 2 || array.is_complex())
        {
            return Err(fail(format!(
                "its real/imaginary axis has length {k} (must be 2, on real values)"
            )));
        }
        let iq = array.is_complex() || re_im.is_some();
        match (iq, demod) {
            (true, None) => {
                return Err(fail(format!(
                    "{} holds IQ (complex) values but no demodulation frequency is known",
                    array.label
                )));
            }
            (false, Some(_)) => {
                return Err(fail(format!(
                    "{} holds real (RF) values but a demodulation frequency was given",
                    array.label
                )));
            }
            _ => {}
        }
        if channels != acquisition.probe.n_elements {
            return Err(fail(format!(
                "do not match the probe: it has {} elements ([probe].n_elements in a manifest) \
                 but the 'channels' axis of {} has {channels} (shape {:?})",
                acquisition.probe.n_elements, array.label, array.shape
            )));
        }
        if events == 0 || events % n != 0 {
            return Err(fail(format!(
                "{events} transmit events is not a whole number of compound frames of {n}"
            )));
        }
        if samples < 2 {
            return Err(fail(format!(
                "each trace needs at least 2 samples, got {samples}"
            )));
        }
        check_frame_size(file, n, channels, samples)?;
        Ok(ArrayFrames {
            acquisition,
            array,
            axes,
            demod,
            shape: (events, channels, samples),
        })
    }

    /// The stored array.
    pub fn array(&self) -> &StoredArray {
        &self.array
    }

    /// The named axes, in the stored order.
    pub fn axes(&self) -> &[Axis] {
        &self.axes
    }

    /// Reads every frame (for readers that hand back the whole recording).
    pub fn read_all(&self) -> Result<ChannelData, IoError> {
        let n = FrameSource::n_frames(self);
        self.read_frames(0..n).map_err(|e| IoError::Recording {
            path: PathBuf::from(&self.array.label),
            source: e,
        })
    }
}

impl FrameSource for ArrayFrames {
    fn acquisition(&self) -> &Acquisition {
        &self.acquisition
    }

    fn n_frames(&self) -> usize {
        self.shape.0 / self.acquisition.sequence.n_angles()
    }

    fn trace_shape(&self) -> (usize, usize) {
        (self.shape.1, self.shape.2)
    }

    fn resident_bytes(&self) -> u64 {
        self.array.resident_bytes()
    }

    fn read_frames(&self, frames: Range<usize>) -> pcuvd::Result<ChannelData> {
        let n = self.acquisition.sequence.n_angles();
        let total = FrameSource::n_frames(self);
        if frames.start >= frames.end || frames.end > total {
            return Err(pcuvd::core::error::invalid(
                "frames",
                format!("block {frames:?} is not within the recording's {total} frames"),
            ));
        }
        let events = frames.start * n..frames.end * n;
        let ranges: Vec<Range<usize>> = self
            .axes
            .iter()
            .zip(&self.array.shape)
            .map(|(a, &len)| match a {
                Axis::Frames => frames.clone(),
                Axis::Events => events.clone(),
                _ => 0..len,
            })
            .collect();
        // Read as (frames, angles | events, channels, samples[, re_im]), then merge.
        let order: Vec<usize> = [
            Axis::Frames,
            Axis::Angles,
            Axis::Events,
            Axis::Channels,
            Axis::Samples,
            Axis::ReIm,
        ]
        .iter()
        .filter_map(|a| self.axes.iter().position(|b| b == a))
        .chain(
            self.axes
                .iter()
                .enumerate()
                .filter(|(_, a)| **a == Axis::Unit)
                .map(|(i, _)| i),
        )
        .collect();
        let block = self
            .array
            .read_ordered(&ranges, &order)
            .map_err(|e| pcuvd::Error::Read(e.to_string()))?;
        let shape = (events.len(), self.shape.1, self.shape.2);
        let shape_error = |e: ndarray::ShapeError| pcuvd::Error::Shape(e.to_string());
        let samples = match block {
            Block::Real(a) if self.axes.contains(&Axis::ReIm) => {
                let pairs: Vec<Complex32> = a
                    .as_slice()
                    .unwrap_or_default()
                    .chunks_exact(2)
                    .map(|c| Complex32::new(c[0], c[1]))
                    .collect();
                Samples::Iq {
                    data: Array3::from_shape_vec(shape, pairs).map_err(shape_error)?,
                    demod_frequency: self.demod.unwrap_or(0.0),
                }
            }
            Block::Real(a) => Samples::Rf(a.into_shape_with_order(shape).map_err(shape_error)?),
            Block::Complex(a) => Samples::Iq {
                data: a.into_shape_with_order(shape).map_err(shape_error)?,
                demod_frequency: self.demod.unwrap_or(0.0),
            },
        };
        let data = ChannelData {
            acquisition: self.acquisition.clone(),
            samples,
        };
        if !data.samples.all_finite() {
            return Err(pcuvd::Error::NonFinite(format!(
                "the samples of {} (NaN or Inf in frames {frames:?})",
                self.array.label
            )));
        }
        Ok(data)
    }
}
