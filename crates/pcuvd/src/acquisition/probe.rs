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

    /// Element's receive amplitude at angle `theta` (rad) from its normal, relative to on-axis,
    /// at the centre frequency and sound speed `c` (m/s): a strip element in a soft baffle,
    /// sinc(π w sin θ / λ)·cos θ, the model the simulator uses.
    pub fn element_directivity(&self, theta: f64, c: f64) -> f64 {
        let x = std::f64::consts::PI * self.element_width * theta.sin() / self.wavelength(c);
        let sinc = if x == 0.0 { 1.0 } else { x.sin() / x };
        sinc * theta.cos()
    }

    /// Receive f-number whose aperture edge sees each element at `level_db` (dB, negative) of
    /// its on-axis sensitivity: 1 / (2 tan θ) where the directivity falls to that level. A
    /// smaller f-number would sum echoes from elements that barely hear them (more noise than
    /// signal); a larger one discards elements that do.
    pub fn directivity_f_number(&self, level_db: f64, c: f64) -> f64 {
        let level = 10f64.powf(level_db / 20.0);
        // The directivity falls monotonically from 1 at θ = 0 to its first null (or to 0 at
        // 90° for elements narrower than λ): bisect on that interval.
        let null = (self.wavelength(c) / self.element_width).min(1.0).asin();
        let (mut inside, mut outside) = (0.0, null);
        for _ in 0..64 {
            let mid = 0.5 * (inside + outside);
            if self.element_directivity(mid, c) > level {
                inside = mid;
            } else {
                outside = mid;
            }
        }
        0.5 / (0.5 * (inside + outside)).tan()
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

    /// Without width the element hears as cos θ, which is −3 dB (1/√2) at 45°: F# 1/(2 tan 45°)
    /// = 0.5 exactly; at −6 dB (1/2) it is 60°, F# 1/(2√3).
    #[test]
    fn a_point_element_hears_as_the_cosine() {
        let mut p = Probe::l22_14vx();
        p.element_width = 1e-12;
        let half_power = -10.0 * 2f64.log10();
        assert!((p.directivity_f_number(half_power, 1540.0) - 0.5).abs() < 1e-9);
        let half_amplitude = -20.0 * 2f64.log10();
        let expected = 0.5 / 3f64.sqrt();
        assert!((p.directivity_f_number(half_amplitude, 1540.0) - expected).abs() < 1e-9);
    }

    /// The L22-14vX (0.08 mm elements, λ = 0.0986 mm): the f-number found puts the aperture's
    /// edge where the directivity is the level asked, and a dense scan of the angles finds the
    /// same crossing; a wider element (L11-5v: w/λ = 1.33 against 0.81) needs a larger f-number.
    #[test]
    fn the_f_number_puts_the_edge_at_the_level() {
        let p = Probe::l22_14vx();
        let c = 1540.0;
        let f_number = p.directivity_f_number(-3.0, c);
        let edge = (0.5 / f_number).atan();
        let level = 10f64.powf(-3.0 / 20.0);
        assert!((p.element_directivity(edge, c) - level).abs() < 1e-12);
        let scanned = (0..90_000)
            .map(|i| i as f64 * 1e-5)
            .find(|&theta| p.element_directivity(theta, c) <= level)
            .unwrap();
        assert!((scanned - edge).abs() < 2e-5, "{scanned} against {edge}");
        assert!((0.95..1.0).contains(&f_number), "{f_number}");
        assert!(Probe::l11_5v().directivity_f_number(-3.0, c) > 1.4);
    }

    #[test]
    fn presets_by_name() {
        assert_eq!(Probe::preset("l11-5v").unwrap().pitch, 0.3e-3);
        assert!(Probe::preset("nope").is_err());
    }
}
