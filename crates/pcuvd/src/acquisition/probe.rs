//! Linear-array probes.

use crate::core::error::{Result, invalid, require_positive, require_range};

/// Most elements a probe may have (more is a mistake, not a probe).
pub const MAX_ELEMENTS: usize = 65_536;

/// Range of element pitches accepted (m): 1 µm to 50 mm.
pub const PITCH_RANGE: (f64, f64) = (1e-6, 50e-3);

/// Range of centre frequencies accepted (Hz): 20 kHz to 1 GHz.
pub const CENTER_FREQUENCY_RANGE: (f64, f64) = (20e3, 1e9);

/// A linear-array ultrasound probe. All lengths in m, frequencies in Hz.
#[derive(Debug, Clone, PartialEq)]
pub struct Probe {
    /// Model name, e.g. "L22-14vX".
    pub name: String,
    /// Number of elements.
    pub n_elements: usize,
    /// Centre-to-centre element spacing (m).
    pub pitch: f64,
    /// Element width in the imaging plane (m); sets the element directivity.
    pub element_width: f64,
    /// Centre frequency (Hz).
    pub center_frequency: f64,
    /// Two-way −6 dB fractional bandwidth (0.67 means 67 % of the centre frequency).
    pub bandwidth: f64,
}

impl Probe {
    /// Vermon L22-14vX, the probe of the PC-UVD paper (128 elements, 0.1 mm pitch, 15.625 MHz).
    pub fn l22_14vx() -> Self {
        Probe {
            name: "L22-14vX".into(),
            n_elements: 128,
            pitch: 0.1e-3,
            element_width: 0.08e-3,
            center_frequency: 15.625e6,
            bandwidth: 0.67,
        }
    }

    /// Verasonics/ATL L11-5v (128 elements, 0.3 mm pitch, 7.6 MHz).
    pub fn l11_5v() -> Self {
        Probe {
            name: "L11-5v".into(),
            n_elements: 128,
            pitch: 0.3e-3,
            element_width: 0.27e-3,
            center_frequency: 7.6e6,
            bandwidth: 0.77,
        }
    }

    /// Names of the built-in probe presets.
    pub const PRESETS: [&'static str; 2] = ["L22-14vX", "L11-5v"];

    /// A probe preset by name (case-insensitive).
    pub fn preset(name: &str) -> Result<Self> {
        match name.to_ascii_lowercase().as_str() {
            "l22-14vx" => Ok(Self::l22_14vx()),
            "l11-5v" => Ok(Self::l11_5v()),
            _ => Err(invalid(
                "probe",
                format!(
                    "unknown preset {name:?}; known: {}",
                    Self::PRESETS.join(", ")
                ),
            )),
        }
    }

    /// Checks that every field is physically meaningful.
    pub fn validate(&self) -> Result<()> {
        if self.n_elements == 0 {
            return Err(invalid("number of elements", "must be at least 1"));
        }
        if self.n_elements > MAX_ELEMENTS {
            return Err(invalid(
                "number of elements",
                format!(
                    "{} is more than any probe has (at most {MAX_ELEMENTS})",
                    self.n_elements
                ),
            ));
        }
        require_positive("pitch", self.pitch)?;
        require_range("pitch", self.pitch, PITCH_RANGE, "m")?;
        require_positive("element width", self.element_width)?;
        if self.element_width > self.pitch {
            return Err(invalid(
                "element width",
                format!(
                    "{:.4} mm is wider than the pitch {:.4} mm: elements of a linear array cannot \
                     overlap",
                    self.element_width * 1e3,
                    self.pitch * 1e3
                ),
            ));
        }
        require_positive("centre frequency", self.center_frequency)?;
        if !(CENTER_FREQUENCY_RANGE.0..=CENTER_FREQUENCY_RANGE.1).contains(&self.center_frequency) {
            return Err(invalid(
                "centre frequency",
                format!(
                    "{:e} Hz is not an ultrasound frequency (expected {:e} to {:e} Hz; the unit is \
                     Hz: 5 MHz is 5e6)",
                    self.center_frequency, CENTER_FREQUENCY_RANGE.0, CENTER_FREQUENCY_RANGE.1
                ),
            ));
        }
        require_positive("bandwidth", self.bandwidth)?;
        // A fraction of the centre frequency: at 2 (200 %) the band already reaches 0 Hz, so a
        // larger value is a percentage given where a fraction is meant (67 for 0.67).
        if self.bandwidth >= 2.0 {
            return Err(invalid(
                "bandwidth",
                format!(
                    "{} is a fraction of the centre frequency and must be below 2 (200 %); \
                     did you mean {}?",
                    self.bandwidth,
                    self.bandwidth / 100.0
                ),
            ));
        }
        Ok(())
    }

    /// Lateral position of each element centre (m), origin at the array centre, increasing with index.
    pub fn element_x(&self) -> Vec<f64> {
        let mid = (self.n_elements as f64 - 1.0) / 2.0;
        (0..self.n_elements)
            .map(|i| (i as f64 - mid) * self.pitch)
            .collect()
    }

    /// Lateral extent of the array (m): (first element centre, last element centre).
    pub fn aperture(&self) -> (f64, f64) {
        let half = (self.n_elements as f64 - 1.0) / 2.0 * self.pitch;
        (-half, half)
    }

    /// Wavelength at the centre frequency (m) for a sound speed `c` (m/s).
    pub fn wavelength(&self, c: f64) -> f64 {
        c / self.center_frequency
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn elements_are_centred_and_ordered() {
        let p = Probe::l22_14vx();
        let x = p.element_x();
        assert_eq!(x.len(), 128);
        assert!((x[0] + x[127]).abs() < 1e-15);
        assert!((x[1] - x[0] - 0.1e-3).abs() < 1e-15);
        assert_eq!(p.aperture(), (x[0], x[127]));
    }

    #[test]
    fn presets_by_name() {
        assert_eq!(Probe::preset("l11-5v").unwrap().pitch, 0.3e-3);
        assert!(Probe::preset("nope").is_err());
    }
}
