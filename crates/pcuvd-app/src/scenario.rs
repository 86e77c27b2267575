//! Simulation scenarios: everything `pcuvd simulate` simulates — probe, sequence, medium, receive
//! window, noise, vessels, tissue and its motion — as one TOML file, and the scenarios pcuvd ships
//! (its presets).
//!
//! The keys follow the recording manifest's conventions: SI units throughout, each key carrying
//! its unit in its name, the same names where the two overlap (`[probe]`). Unknown keys are
//! errors, and [`Scenario::check`] refuses an out-of-range value by its key
//! (`[probe].pitch_m = -0.0001: must be a finite number > 0`). The schema, with an example per
//! section, is in `docs/guide/scenarios.md`; the shipped scenarios are in
//! `crates/pcuvd-app/scenarios/`.

use std::path::Path;

use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};

use crate::settings::TubeProfile;

/// The scenarios pcuvd ships, by name: the presets of `pcuvd simulate --preset`, and a small rat
/// brain for quick runs (`pcuvd paper --quick`).
pub const SHIPPED: [(&str, &str); 5] = [
    (
        "paper-spiral",
        include_str!("../scenarios/paper-spiral.toml"),
    ),
    ("tube", include_str!("../scenarios/tube.toml")),
    ("rat-network", include_str!("../scenarios/rat-network.toml")),
    ("rat-brain", include_str!("../scenarios/rat-brain.toml")),
    (
        "rat-brain-small",
        include_str!("../scenarios/rat-brain-small.toml"),
    ),
];

/// Which transmit modes to simulate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum ModeChoice {
    /// Hadamard-coded: every event fires all angles.
    Coded,
    /// Conventional: one angle per event.
    Conventional,
    /// Both, with the same scatterers, motion and noise statistics.
    Both,
}

/// How the tissue of `--tissue-db` moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum TissueMotionChoice {
    /// The anaesthetised rat's brain: heartbeat 5.5 Hz (3 µm axial, 1 µm lateral), breathing 1 Hz (20 µm axial, 5 µm lateral, growing 10 % per mm of depth).
    Rat,
    /// No motion.
    Still,
}

/// A simulation scenario as its TOML file reads.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// What the scenario is, in words.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub description: Option<String>,
    /// Seed of the scatterers, the noise and a generated vascular tree.
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// `[probe]`: the transducer.
    pub probe: ProbeSection,
    /// `[sequence]`: the transmit sequence and the recording's length.
    pub sequence: SequenceSection,
    /// `[medium]`: sound speed and attenuation.
    #[serde(default)]
    pub medium: MediumSection,
    /// `[receive]`: sampling and the receive window.
    pub receive: ReceiveSection,
    /// `[noise]`: receiver noise; absent for noiseless recordings.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise: Option<NoiseSection>,
    /// `[vessels]`: the flow phantom.
    pub vessels: Vessels,
    /// `[tissue]`: tissue around the vessels; absent for blood alone.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tissue: Option<TissueSection>,
}

fn default_seed() -> u64 {
    1
}

/// `[probe]`: a named probe (`preset`), its keys, or a preset whose keys the section overrides.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProbeSection {
    /// A built-in probe ("L22-14vX", "L11-5v") that gives every key not set here.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub preset: Option<String>,
    /// The probe's name in the recording.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// Number of elements.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub n_elements: Option<usize>,
    /// Centre-to-centre element spacing (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pitch_m: Option<f64>,
    /// Element width in the imaging plane (m), at most the pitch.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub element_width_m: Option<f64>,
    /// Centre frequency (Hz).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub center_frequency_hz: Option<f64>,
    /// Two-way −6 dB bandwidth, a fraction of the centre frequency.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bandwidth: Option<f64>,
    /// Element height (m) along the elevation y: with `elevation_focus_m`, the simulation is
    /// three-dimensional; without, every scatterer lies in the imaging plane.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub element_height_m: Option<f64>,
    /// Depth of the elevation lens's focus (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub elevation_focus_m: Option<f64>,
}

/// `[sequence]`: the transmit sequence and the recording's length.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SequenceSection {
    /// Which recordings to simulate: "coded" (Hadamard), "conventional" or "both" (the same
    /// scatterers, motion and noise statistics).
    #[serde(default = "both")]
    pub transmit: ModeChoice,
    /// Number of steering angles, evenly spaced over [−max_angle_deg, max_angle_deg] (coded: a
    /// Hadamard order, 1, 2, 4, 8, 12, 16, ...). Give this or `angles_deg`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub angles: Option<usize>,
    /// The largest steering angle of `angles` (degrees).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_angle_deg: Option<f64>,
    /// The steering angles themselves (degrees; θ > 0 tilts toward +x).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub angles_deg: Option<Vec<f64>>,
    /// Transmit-event repetition frequency (Hz); the compound frame rate is this over the angles.
    pub event_prf_hz: f64,
    /// Delay between the Hadamard slots of a coded event (s).
    pub slot_delay_s: f64,
    /// Transmit pulse length (cycles of the centre frequency, a Hann-windowed burst). With
    /// `[sequence.pulse]`, the recording's statement of that pulse's length; absent, its
    /// duration in cycles of the centre frequency.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pulse_cycles: Option<f64>,
    /// `[sequence.pulse]`: the transmit pulse as the scanner drives it, sampled, instead of a
    /// Hann burst; the simulator sends it through the probe's two-way response.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pulse: Option<PulseSection>,
    /// Compound frames per recording.
    pub frames: usize,
}

/// `[sequence.pulse]`: a sampled transmit pulse (as the recording manifest's `[acquisition.pulse]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PulseSection {
    /// Sampling rate of `samples` (Hz).
    pub sampling_frequency_hz: f64,
    /// The pulse, one value per sample (any unit: only its shape matters).
    pub samples: Vec<f64>,
}

fn both() -> ModeChoice {
    ModeChoice::Both
}

/// The steering angle limit of `[sequence].angles` when `max_angle_deg` is not given (degrees).
pub const DEFAULT_MAX_ANGLE_DEG: f64 = 15.0;

/// `[medium]`: the tissue's acoustics (soft tissue's by default).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MediumSection {
    /// Speed of sound (m/s).
    pub sound_speed_m_s: f64,
    /// Attenuation over the two-way path (dB/cm/MHz); 0 for none.
    pub attenuation_db_cm_mhz: f64,
    /// Whether attenuation also lowers each echo's spectrum along its path (true: as in
    /// tissue) or only scales its amplitude at the centre frequency.
    pub frequency_dependent_attenuation: bool,
}

impl Default for MediumSection {
    fn default() -> Self {
        MediumSection {
            sound_speed_m_s: 1540.0,
            attenuation_db_cm_mhz: pcuvd::simulate::SimParams::DEFAULT_ATTENUATION,
            frequency_dependent_attenuation: true,
        }
    }
}

/// `[receive]`: sampling and the receive window.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReceiveSection {
    /// Sampling frequency of the RF traces (Hz).
    pub sampling_frequency_hz: f64,
    /// Depths (m) whose whole echo every trace holds, for every angle, slot and element of the
    /// coded sequence: both transmit modes record the same window.
    pub depth_m: [f64; 2],
    /// Level (dB of its peak) below which the echo waveform's tails are left out, in (−120,
    /// −20]; absent: −70.5 dB. With tissue L dB brighter than blood, a level below −L dB keeps
    /// the tissue's lost tails under the blood's echo, at the cost of longer convolutions.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub waveform_truncation_db: Option<f64>,
}

/// `[noise]`: white receiver noise.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoiseSection {
    /// Noise level (dB) relative to the echo, as `pcuvd::simulate::NOISE_DEFINITION` defines it
    /// (with tissue: relative to the blood's echo alone).
    pub level_db: f64,
}

/// `[vessels]`: the flow phantom, by `kind`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Vessels {
    /// An Archimedean spiral vessel in the imaging plane (the paper's §2.3 phantom).
    Spiral(SpiralSection),
    /// A straight tube in the imaging plane.
    Tube(TubeSection),
    /// The eight straight pulsatile vessels of the in-vivo-like network (arterioles RI 0.7,
    /// venules RI 0.3, 5.5 Hz), in the imaging plane.
    RatNetwork(NetworkSection),
    /// A vascular tree in three dimensions, generated (a slab of rat cortex) or read from
    /// tables, with compliant pulsatile flow solved from its boundary conditions.
    Tree(TreeSection),
}

/// `kind = "spiral"`: the centreline r(α) = a + bα, α ∈ [0, 2π·turns], around `centre_m`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SpiralSection {
    /// Centre (x, z) (m).
    pub centre_m: [f64; 2],
    /// Radius a where the centreline starts (m).
    pub start_radius_m: f64,
    /// Growth b of the radius per radian (m/rad).
    pub turn_spacing_m_per_rad: f64,
    /// Turns of the centreline.
    pub turns: f64,
    /// Vessel radius (m).
    pub radius_m: f64,
    /// Centreline speed of the parabolic profile (m/s).
    pub peak_velocity_m_s: f64,
    /// Scatterers per m² of vessel (unit-variance amplitudes).
    pub density_per_m2: f64,
}

impl Default for SpiralSection {
    /// The paper's spiral.
    fn default() -> Self {
        let paper = pcuvd::simulate::phantom::SpiralSpec::paper();
        SpiralSection {
            centre_m: paper.centre,
            start_radius_m: paper.a,
            turn_spacing_m_per_rad: paper.b,
            turns: 2.1,
            radius_m: paper.radius,
            peak_velocity_m_s: paper.peak_speed,
            density_per_m2: paper.density,
        }
    }
}

/// `kind = "tube"`: a straight tube whose scatterers, leaving one end, re-enter at the other.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TubeSection {
    /// Centre (x, z) (m).
    pub centre_m: [f64; 2],
    /// Flow direction (degrees from +x toward +z: 90 flows straight down).
    pub angle_deg: f64,
    /// Length along the axis (m).
    pub length_m: f64,
    /// Radius (m).
    pub radius_m: f64,
    /// Peak speed (m/s): on the axis, or across the lumen for a plug profile.
    pub peak_velocity_m_s: f64,
    /// "parabolic" (laminar) or "plug".
    pub profile: TubeProfile,
    /// Scatterers per m² of vessel (unit-variance amplitudes).
    pub density_per_m2: f64,
}

impl Default for TubeSection {
    /// The `tube` preset's vessel.
    fn default() -> Self {
        let preset = pcuvd::simulate::phantom::TubeSpec::preset(25e-3);
        TubeSection {
            centre_m: preset.centre,
            angle_deg: 30.0,
            length_m: preset.length,
            radius_m: preset.radius,
            peak_velocity_m_s: preset.peak_speed,
            profile: preset.profile.into(),
            density_per_m2: preset.density,
        }
    }
}

/// `kind = "rat-network"`: the network's vessels as pcuvd defines them.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NetworkSection {
    /// Peak systolic speed of the fastest vessel (m/s; the others scaled alike); absent: 30 mm/s.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fastest_psv_m_s: Option<f64>,
}

/// `kind = "tree"`: a generated slab of rat cortex (the keys below), or a vessel graph read from
/// `tables`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TreeSection {
    /// A folder of three tables (vertices.csv, edges.csv, boundary.csv; see `pcuvd simulate
    /// --help`, `--vessel-tables`), relative to the scenario file: the tree instead of a
    /// generated one (the generator's keys are then not used).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tables: Option<String>,
    /// Depth of the cortical surface (m).
    pub surface_depth_m: f64,
    /// Cortical thickness (m); penetrating vessels reach 50–90 % of it.
    pub cortex_thickness_m: f64,
    /// Slab width along x, centred on x = 0 (m).
    pub width_m: f64,
    /// Slab thickness along the elevation y, centred on the imaging plane (m).
    pub slab_thickness_m: f64,
    /// Distance between neighbouring penetrating arterioles (m); a venule sits between each pair.
    pub spacing_m: f64,
    /// Range of penetrating-arteriole diameters at the surface (m).
    pub arteriole_diameter_m: [f64; 2],
    /// Range of ascending-venule diameters at the surface (m).
    pub venule_diameter_m: [f64; 2],
    /// Capillary diameter (m).
    pub capillary_diameter_m: f64,
    /// Side branches along each penetrating trunk.
    pub branchings: usize,
    /// Share of the parent's d³ a side branch takes (Murray's law: the trunk keeps the rest).
    pub side_share: f64,
    /// Largest tilt of a penetrating trunk from the normal, in x and in y (degrees).
    pub max_tilt_deg: f64,
    /// Capillary paths from each arteriole terminal to its nearest venule terminals.
    pub capillaries_per_terminal: usize,
    /// Segments per capillary path.
    pub capillary_segments: usize,
    /// Mean pressure of the arterial inlet (Pa).
    pub inlet_pressure_pa: f64,
    /// Peak-to-trough cardiac swing of the inlet pressure (Pa).
    pub inlet_pulse_pa: f64,
    /// Steady venous outlet pressure (Pa).
    pub outlet_pressure_pa: f64,
    /// Arteriole–venule pairs rising into the deep brain (thalamus, hippocampus) from a basal
    /// artery and vein, `spacing_m` apart and centred; 0: the cortex alone.
    pub deep_pairs: usize,
    /// Depth of the basal artery and vein (m).
    pub deep_depth_m: f64,
    /// How far the deep trunks rise above them (m); each reaches 50–90 % of it.
    pub deep_reach_m: f64,
    /// Range of deep-arteriole diameters where they leave the basal artery (m).
    pub deep_arteriole_diameter_m: [f64; 2],
    /// Range of deep-venule diameters where they join the basal vein (m).
    pub deep_venule_diameter_m: [f64; 2],
    /// Side branches along each deep trunk.
    pub deep_branchings: usize,
}

impl Default for TreeSection {
    /// The rat brain's cortex: the generator's slab with a capillary bed of eight 10 µm paths of
    /// two segments from each arteriole terminal, which carries the flow a real bed of many
    /// capillaries does (penetrating arterioles at a median PSV of 16 mm/s, RI 0.73; venules
    /// 7 mm/s, RI 0.08). The generator's own default bed, two paths of three 8 µm segments,
    /// starves them (4 and 2 mm/s). Below, four pairs of larger deep vessels (60–90 µm
    /// arterioles, 70–100 µm venules, eight branchings) rise from 9 mm toward 5 mm: arterioles
    /// at a median PSV of 16 mm/s and RI 0.78, venules 6 mm/s and RI 0.12.
    fn default() -> Self {
        let base = pcuvd::simulate::vascular::CortexParams::default();
        TreeSection {
            tables: None,
            surface_depth_m: base.surface_depth,
            cortex_thickness_m: base.thickness,
            width_m: base.width,
            slab_thickness_m: base.slab_thickness,
            spacing_m: base.spacing,
            arteriole_diameter_m: [base.arteriole_diameter.0, base.arteriole_diameter.1],
            venule_diameter_m: [base.venule_diameter.0, base.venule_diameter.1],
            capillary_diameter_m: 10e-6,
            branchings: base.branchings,
            side_share: base.side_share,
            max_tilt_deg: base.max_tilt_deg,
            capillaries_per_terminal: 8,
            capillary_segments: 2,
            inlet_pressure_pa: base.inlet_pressure,
            inlet_pulse_pa: base.inlet_pulse,
            outlet_pressure_pa: base.outlet_pressure,
            deep_pairs: 4,
            deep_depth_m: base.deep_depth,
            deep_reach_m: base.deep_reach,
            deep_arteriole_diameter_m: [
                base.deep_arteriole_diameter.0,
                base.deep_arteriole_diameter.1,
            ],
            deep_venule_diameter_m: [base.deep_venule_diameter.0, base.deep_venule_diameter.1],
            deep_branchings: base.deep_branchings,
        }
    }
}

impl TreeSection {
    /// The generator's parameters, with the tree's `seed`.
    pub fn cortex(&self, seed: u64) -> pcuvd::simulate::vascular::CortexParams {
        pcuvd::simulate::vascular::CortexParams {
            surface_depth: self.surface_depth_m,
            thickness: self.cortex_thickness_m,
            width: self.width_m,
            slab_thickness: self.slab_thickness_m,
            spacing: self.spacing_m,
            arteriole_diameter: (self.arteriole_diameter_m[0], self.arteriole_diameter_m[1]),
            venule_diameter: (self.venule_diameter_m[0], self.venule_diameter_m[1]),
            capillary_diameter: self.capillary_diameter_m,
            branchings: self.branchings,
            side_share: self.side_share,
            max_tilt_deg: self.max_tilt_deg,
            capillaries_per_terminal: self.capillaries_per_terminal,
            capillary_segments: self.capillary_segments,
            inlet_pressure: self.inlet_pressure_pa,
            inlet_pulse: self.inlet_pulse_pa,
            outlet_pressure: self.outlet_pressure_pa,
            deep_pairs: self.deep_pairs,
            deep_depth: self.deep_depth_m,
            deep_reach: self.deep_reach_m,
            deep_arteriole_diameter: (
                self.deep_arteriole_diameter_m[0],
                self.deep_arteriole_diameter_m[1],
            ),
            deep_venule_diameter: (
                self.deep_venule_diameter_m[0],
                self.deep_venule_diameter_m[1],
            ),
            deep_branchings: self.deep_branchings,
            seed,
        }
    }
}

/// `[tissue]`: fully developed speckle around the vessels (none inside them), with bright layers,
/// anechoic regions, and a motion that carries the vessels too.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TissueSection {
    /// Echo power per unit volume (per unit area in the plane) relative to the blood's (dB): in
    /// vivo 30–60 dB at these frequencies.
    pub echogenicity_db: f64,
    /// Lateral extent (x_min, x_max) (m); absent: the array's aperture and 1 mm beyond each end.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x_range_m: Option<[f64; 2]>,
    /// Depth extent (z_min, z_max) (m); tissue deeper than the receive window records is left out.
    pub depth_m: [f64; 2],
    /// Half the slab's thickness along the elevation y (m); 0: a sheet in the imaging plane.
    /// A slab needs the probe's `element_height_m` and `elevation_focus_m`.
    #[serde(default)]
    pub half_thickness_m: f64,
    /// Scatterers per m³ of a slab; absent: 10 per resolution cell (0.1 × 0.15 × 0.4 mm³).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub density_per_m3: Option<f64>,
    /// Scatterers per m² of a sheet; absent: 10 per resolution cell (0.1 × 0.15 mm²).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub density_per_m2: Option<f64>,
    /// `[[tissue.layers]]`: bright bands across the image (a dura, a skull edge).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub layers: Vec<LayerSection>,
    /// `[[tissue.anechoic]]`: regions without tissue (fluid: ventricles), elliptic cylinders
    /// along y.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub anechoic: Vec<AnechoicSection>,
    /// `[tissue.motion]`: how the tissue and its vessels move; absent: still.
    #[serde(default)]
    pub motion: MotionSection,
}

/// `[[tissue.layers]]`: a bright band of tissue across the image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LayerSection {
    /// Depth of its top (m).
    pub top_m: f64,
    /// Thickness (m).
    pub thickness_m: f64,
    /// Echo power relative to the blood's (dB), as `echogenicity_db`.
    pub echogenicity_db: f64,
}

/// `[[tissue.anechoic]]`: an elliptic region without tissue.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnechoicSection {
    /// Centre (x, z) (m).
    pub centre_m: [f64; 2],
    /// Semi-axes along x and z (m).
    pub radii_m: [f64; 2],
}

/// `[tissue.motion]`: a named motion, or oscillations of their own.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionSection {
    /// A named motion ("rat": heartbeat and breathing of the anaesthetised rat; "still"),
    /// instead of `oscillations`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub preset: Option<TissueMotionChoice>,
    /// Depth at which each oscillation has its stated amplitude (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_depth_m: Option<f64>,
    /// `[[tissue.motion.oscillations]]`: sinusoidal displacements that add up.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub oscillations: Vec<OscillationSection>,
}

/// `[[tissue.motion.oscillations]]`: displacement amplitude · sin(2π f t + phase), scaled by
/// 1 + depth_gradient_per_m · (z − reference depth).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OscillationSection {
    /// Frequency (Hz): the rat's heart beats at about 5.5 Hz, it breathes at about 1 Hz.
    pub frequency_hz: f64,
    /// Displacement amplitude along (x, y, z) at the reference depth (m).
    pub amplitude_m: [f64; 3],
    /// Phase at t = 0 (rad).
    #[serde(default)]
    pub phase_rad: f64,
    /// Relative change of the amplitude per metre below the reference depth (1/m); 0: rigid.
    #[serde(default)]
    pub depth_gradient_per_m: f64,
}

impl MotionSection {
    /// The motion this section describes.
    pub fn motion(&self) -> pcuvd::simulate::phantom::TissueMotion {
        use pcuvd::simulate::phantom::TissueMotion;
        match self.preset {
            Some(TissueMotionChoice::Rat) => TissueMotion::rat(),
            Some(TissueMotionChoice::Still) => TissueMotion::still(),
            None => TissueMotion {
                oscillations: self
                    .oscillations
                    .iter()
                    .map(|o| pcuvd::simulate::phantom::tissue::Oscillation {
                        frequency_hz: o.frequency_hz,
                        amplitude: o.amplitude_m,
                        phase_rad: o.phase_rad,
                        depth_gradient: o.depth_gradient_per_m,
                    })
                    .collect(),
                reference_depth: self.reference_depth_m.unwrap_or(0.0),
            },
        }
    }
}

/// A value refused by its key.
fn refuse(key: &str, value: impl std::fmt::Display, why: &str) -> anyhow::Error {
    anyhow::anyhow!("{key} = {value}: {why}")
}

fn positive(key: &str, v: f64) -> Result<()> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(refuse(key, v, "must be a finite number > 0"))
    }
}

fn finite(key: &str, v: f64) -> Result<()> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(refuse(key, v, "must be a finite number"))
    }
}

/// Checks that `range` is finite and increasing (`nonnegative`: from 0 up).
fn increasing(key: &str, range: [f64; 2], nonnegative: bool) -> Result<()> {
    let [a, b] = range;
    if a.is_finite() && b.is_finite() && a < b && (!nonnegative || a >= 0.0) {
        Ok(())
    } else {
        let floor = if nonnegative { "0 ≤ " } else { "" };
        Err(refuse(
            key,
            format!("[{a}, {b}]"),
            &format!("must be finite with {floor}first < second"),
        ))
    }
}

impl Scenario {
    /// The shipped scenario `name` (see [`SHIPPED`]).
    pub fn shipped(name: &str) -> Result<Scenario> {
        let Some((_, text)) = SHIPPED.iter().find(|(n, _)| *n == name) else {
            let names: Vec<&str> = SHIPPED.iter().map(|(n, _)| *n).collect();
            bail!(
                "no shipped scenario is called {name:?} (there are {}; or give a .toml file)",
                names.join(", ")
            );
        };
        Scenario::parse(text).with_context(|| format!("the shipped scenario {name}"))
    }

    /// The shipped scenario `source` names, or the scenario file at the path `source`; the
    /// `[vessels].tables` folder of a file is taken relative to the file.
    pub fn load(source: &str) -> Result<Scenario> {
        if SHIPPED.iter().any(|(name, _)| *name == source) {
            return Scenario::shipped(source);
        }
        let path = Path::new(source);
        if !path.is_file() && path.extension().is_none() {
            return Scenario::shipped(source);
        }
        Scenario::read(path)
    }

    /// The scenario in the TOML file `path`, checked; `[vessels].tables` relative to its folder.
    pub fn read(path: &Path) -> Result<Scenario> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("scenario {}: cannot read it", path.display()))?;
        let mut scenario =
            Scenario::parse(&text).with_context(|| format!("scenario {}", path.display()))?;
        if let Vessels::Tree(TreeSection {
            tables: Some(tables),
            ..
        }) = &mut scenario.vessels
        {
            let folder = path.parent().unwrap_or(Path::new(""));
            *tables = folder.join(&*tables).to_string_lossy().into_owned();
        }
        Ok(scenario)
    }

    /// The scenario a TOML text describes, checked.
    pub fn parse(text: &str) -> Result<Scenario> {
        let scenario: Scenario = toml::from_str(text).map_err(|e| {
            // One line: toml's message quotes the offending line under a caret.
            anyhow::anyhow!("{}", e.to_string().trim_end().replace('\n', " "))
        })?;
        scenario.check()?;
        Ok(scenario)
    }

    /// The scenario as TOML (which [`Scenario::parse`] reads back to the same scenario).
    pub fn to_toml(&self) -> Result<String> {
        toml::to_string(self).context("the scenario as TOML")
    }

    /// Checks every value against its range; an error names its key.
    pub fn check(&self) -> Result<()> {
        let p = &self.probe;
        if let Some(name) = &p.preset {
            pcuvd::Probe::preset(name)
                .map_err(|e| refuse("[probe].preset", format!("{name:?}"), &e.to_string()))?;
        } else {
            for (key, given) in [
                ("n_elements", p.n_elements.is_some()),
                ("pitch_m", p.pitch_m.is_some()),
                ("element_width_m", p.element_width_m.is_some()),
                ("center_frequency_hz", p.center_frequency_hz.is_some()),
                ("bandwidth", p.bandwidth.is_some()),
            ] {
                if !given {
                    bail!("[probe].{key} is missing (or name a probe with [probe].preset)");
                }
            }
        }
        if p.n_elements == Some(0) {
            bail!("[probe].n_elements = 0: must be at least 1");
        }
        for (key, value) in [
            ("[probe].pitch_m", p.pitch_m),
            ("[probe].element_width_m", p.element_width_m),
            ("[probe].center_frequency_hz", p.center_frequency_hz),
            ("[probe].bandwidth", p.bandwidth),
            ("[probe].element_height_m", p.element_height_m),
            ("[probe].elevation_focus_m", p.elevation_focus_m),
        ] {
            if let Some(v) = value {
                positive(key, v)?;
            }
        }
        let probe = self.probe()?;
        if probe.element_width > probe.pitch {
            bail!(
                "[probe].element_width_m = {}: must not exceed the pitch ({} m)",
                probe.element_width,
                probe.pitch
            );
        }
        if p.element_height_m.is_some() != p.elevation_focus_m.is_some() {
            bail!(
                "[probe].element_height_m and [probe].elevation_focus_m go together: give both \
                 (a simulation in three dimensions) or neither (in the imaging plane)"
            );
        }
        let s = &self.sequence;
        match (s.angles, &s.angles_deg) {
            (Some(_), Some(_)) => bail!("[sequence]: give angles or angles_deg, not both"),
            (None, None) => bail!("[sequence].angles (a count) or angles_deg is missing"),
            (Some(0), None) => bail!("[sequence].angles = 0: must be at least 1"),
            (None, Some(list)) => {
                if list.is_empty() {
                    bail!("[sequence].angles_deg is empty");
                }
                if s.max_angle_deg.is_some() {
                    bail!("[sequence].max_angle_deg goes with angles (a count), not angles_deg");
                }
                for &a in list {
                    if !(a.is_finite() && a.abs() < 90.0) {
                        return Err(refuse(
                            "[sequence].angles_deg",
                            a,
                            "every angle must lie strictly between −90 and 90",
                        ));
                    }
                }
            }
            (Some(_), None) => {}
        }
        if let Some(max) = s.max_angle_deg
            && !(max.is_finite() && (0.0..90.0).contains(&max))
        {
            return Err(refuse(
                "[sequence].max_angle_deg",
                max,
                "must lie in [0, 90)",
            ));
        }
        positive("[sequence].event_prf_hz", s.event_prf_hz)?;
        positive("[sequence].slot_delay_s", s.slot_delay_s)?;
        match (s.pulse_cycles, &s.pulse) {
            (None, None) => bail!("[sequence].pulse_cycles (or a [sequence.pulse]) is missing"),
            (Some(cycles), _) => positive("[sequence].pulse_cycles", cycles)?,
            (None, Some(_)) => {}
        }
        if let Some(pulse) = &s.pulse {
            positive(
                "[sequence.pulse].sampling_frequency_hz",
                pulse.sampling_frequency_hz,
            )?;
            if let Some(pulse) = self.transmit_pulse() {
                pulse.validate().context("[sequence.pulse].samples")?;
            }
        }
        if s.frames == 0 {
            bail!("[sequence].frames = 0: must be at least 1");
        }
        let m = &self.medium;
        positive("[medium].sound_speed_m_s", m.sound_speed_m_s)?;
        if !(m.attenuation_db_cm_mhz.is_finite() && m.attenuation_db_cm_mhz >= 0.0) {
            return Err(refuse(
                "[medium].attenuation_db_cm_mhz",
                m.attenuation_db_cm_mhz,
                "must be a finite number ≥ 0",
            ));
        }
        positive(
            "[receive].sampling_frequency_hz",
            self.receive.sampling_frequency_hz,
        )?;
        increasing("[receive].depth_m", self.receive.depth_m, true)?;
        if let Some(db) = self.receive.waveform_truncation_db
            && !(db.is_finite() && db > -120.0 && db <= -20.0)
        {
            return Err(refuse(
                "[receive].waveform_truncation_db",
                db,
                "must lie in (-120, -20] dB",
            ));
        }
        if let Some(noise) = &self.noise {
            finite("[noise].level_db", noise.level_db)?;
        }
        self.check_vessels()?;
        if let Some(tissue) = &self.tissue {
            self.check_tissue(tissue)?;
        }
        Ok(())
    }

    fn check_vessels(&self) -> Result<()> {
        match &self.vessels {
            Vessels::Spiral(v) => {
                finite("[vessels].centre_m", v.centre_m[0])?;
                finite("[vessels].centre_m", v.centre_m[1])?;
                positive("[vessels].start_radius_m", v.start_radius_m)?;
                positive("[vessels].turn_spacing_m_per_rad", v.turn_spacing_m_per_rad)?;
                positive("[vessels].turns", v.turns)?;
                positive("[vessels].radius_m", v.radius_m)?;
                positive("[vessels].peak_velocity_m_s", v.peak_velocity_m_s)?;
                positive("[vessels].density_per_m2", v.density_per_m2)?;
            }
            Vessels::Tube(v) => {
                finite("[vessels].centre_m", v.centre_m[0])?;
                finite("[vessels].centre_m", v.centre_m[1])?;
                finite("[vessels].angle_deg", v.angle_deg)?;
                positive("[vessels].length_m", v.length_m)?;
                positive("[vessels].radius_m", v.radius_m)?;
                positive("[vessels].peak_velocity_m_s", v.peak_velocity_m_s)?;
                positive("[vessels].density_per_m2", v.density_per_m2)?;
            }
            Vessels::RatNetwork(v) => {
                if let Some(psv) = v.fastest_psv_m_s {
                    positive("[vessels].fastest_psv_m_s", psv)?;
                }
            }
            Vessels::Tree(v) => {
                if self.probe.element_height_m.is_none() {
                    bail!(
                        "[vessels] kind = \"tree\" lies in three dimensions: give the probe's \
                         [probe].element_height_m and elevation_focus_m"
                    );
                }
                if v.tables.is_none() {
                    for (key, value) in [
                        ("surface_depth_m", v.surface_depth_m),
                        ("cortex_thickness_m", v.cortex_thickness_m),
                        ("width_m", v.width_m),
                        ("slab_thickness_m", v.slab_thickness_m),
                        ("spacing_m", v.spacing_m),
                        ("capillary_diameter_m", v.capillary_diameter_m),
                        ("side_share", v.side_share),
                        ("inlet_pressure_pa", v.inlet_pressure_pa),
                        ("outlet_pressure_pa", v.outlet_pressure_pa),
                    ] {
                        positive(&format!("[vessels].{key}"), value)?;
                    }
                    increasing(
                        "[vessels].arteriole_diameter_m",
                        v.arteriole_diameter_m,
                        true,
                    )?;
                    increasing("[vessels].venule_diameter_m", v.venule_diameter_m, true)?;
                    if v.side_share >= 1.0 {
                        return Err(refuse(
                            "[vessels].side_share",
                            v.side_share,
                            "must be below 1",
                        ));
                    }
                    if !(v.inlet_pulse_pa.is_finite() && v.inlet_pulse_pa >= 0.0) {
                        return Err(refuse(
                            "[vessels].inlet_pulse_pa",
                            v.inlet_pulse_pa,
                            "must be a finite number ≥ 0",
                        ));
                    }
                    if v.inlet_pressure_pa <= v.outlet_pressure_pa {
                        return Err(refuse(
                            "[vessels].inlet_pressure_pa",
                            v.inlet_pressure_pa,
                            "must exceed outlet_pressure_pa, or no blood flows",
                        ));
                    }
                    if !(v.max_tilt_deg.is_finite() && (0.0..90.0).contains(&v.max_tilt_deg)) {
                        return Err(refuse(
                            "[vessels].max_tilt_deg",
                            v.max_tilt_deg,
                            "must lie in [0, 90)",
                        ));
                    }
                    for (key, value) in [
                        ("capillaries_per_terminal", v.capillaries_per_terminal),
                        ("capillary_segments", v.capillary_segments),
                    ] {
                        if value == 0 {
                            bail!("[vessels].{key} = 0: must be at least 1");
                        }
                    }
                    if v.deep_pairs > 0 {
                        positive("[vessels].deep_depth_m", v.deep_depth_m)?;
                        positive("[vessels].deep_reach_m", v.deep_reach_m)?;
                        increasing(
                            "[vessels].deep_arteriole_diameter_m",
                            v.deep_arteriole_diameter_m,
                            true,
                        )?;
                        increasing(
                            "[vessels].deep_venule_diameter_m",
                            v.deep_venule_diameter_m,
                            true,
                        )?;
                        let cortex_floor = v.surface_depth_m + v.cortex_thickness_m;
                        if v.deep_depth_m - v.deep_reach_m <= cortex_floor {
                            return Err(refuse(
                                "[vessels].deep_reach_m",
                                v.deep_reach_m,
                                &format!(
                                    "the deep trunks would rise from deep_depth_m into the cortex \
                                     (which ends {cortex_floor} m deep)"
                                ),
                            ));
                        }
                    }
                }
            }
        }
        Ok(())
    }

    fn check_tissue(&self, t: &TissueSection) -> Result<()> {
        finite("[tissue].echogenicity_db", t.echogenicity_db)?;
        if let Some(range) = t.x_range_m {
            increasing("[tissue].x_range_m", range, false)?;
        }
        increasing("[tissue].depth_m", t.depth_m, true)?;
        if !(t.half_thickness_m.is_finite() && t.half_thickness_m >= 0.0) {
            return Err(refuse(
                "[tissue].half_thickness_m",
                t.half_thickness_m,
                "must be a finite number ≥ 0",
            ));
        }
        let slab = t.half_thickness_m > 0.0;
        if slab && self.probe.element_height_m.is_none() {
            bail!(
                "[tissue].half_thickness_m = {}: a slab needs the probe's element_height_m and \
                 elevation_focus_m (or 0: a sheet in the imaging plane)",
                t.half_thickness_m
            );
        }
        match (slab, t.density_per_m3, t.density_per_m2) {
            (true, _, Some(_)) => {
                bail!("[tissue].density_per_m2 is a sheet's: a slab takes density_per_m3")
            }
            (false, Some(_), _) => {
                bail!("[tissue].density_per_m3 is a slab's: a sheet takes density_per_m2")
            }
            (_, Some(d), _) => positive("[tissue].density_per_m3", d)?,
            (_, _, Some(d)) => positive("[tissue].density_per_m2", d)?,
            _ => {}
        }
        for layer in &t.layers {
            finite("[[tissue.layers]].top_m", layer.top_m)?;
            positive("[[tissue.layers]].thickness_m", layer.thickness_m)?;
            finite("[[tissue.layers]].echogenicity_db", layer.echogenicity_db)?;
        }
        for region in &t.anechoic {
            finite("[[tissue.anechoic]].centre_m", region.centre_m[0])?;
            finite("[[tissue.anechoic]].centre_m", region.centre_m[1])?;
            positive("[[tissue.anechoic]].radii_m", region.radii_m[0])?;
            positive("[[tissue.anechoic]].radii_m", region.radii_m[1])?;
        }
        let motion = &t.motion;
        if motion.preset.is_some()
            && (!motion.oscillations.is_empty() || motion.reference_depth_m.is_some())
        {
            bail!(
                "[tissue.motion]: give a preset or oscillations (and reference_depth_m), not both"
            );
        }
        if let Some(depth) = motion.reference_depth_m {
            finite("[tissue.motion].reference_depth_m", depth)?;
        }
        let key = "[[tissue.motion.oscillations]]";
        for o in &motion.oscillations {
            positive(&format!("{key}.frequency_hz"), o.frequency_hz)?;
            for a in o.amplitude_m {
                finite(&format!("{key}.amplitude_m"), a)?;
            }
            finite(&format!("{key}.phase_rad"), o.phase_rad)?;
            finite(
                &format!("{key}.depth_gradient_per_m"),
                o.depth_gradient_per_m,
            )?;
        }
        Ok(())
    }

    /// The probe `[probe]` describes (its preset's keys where it gives none).
    pub fn probe(&self) -> Result<pcuvd::Probe> {
        let p = &self.probe;
        let preset = p.preset.as_deref().map(pcuvd::Probe::preset).transpose()?;
        let pick = |value: Option<f64>, key: &str, of: fn(&pcuvd::Probe) -> f64| {
            value
                .or(preset.as_ref().map(of))
                .with_context(|| format!("[probe].{key} is missing"))
        };
        Ok(pcuvd::Probe {
            name: p
                .name
                .clone()
                .or(preset.as_ref().map(|probe| probe.name.clone()))
                .unwrap_or_else(|| "custom".into()),
            n_elements: p
                .n_elements
                .or(preset.as_ref().map(|probe| probe.n_elements))
                .context("[probe].n_elements is missing")?,
            pitch: pick(p.pitch_m, "pitch_m", |probe| probe.pitch)?,
            element_width: pick(p.element_width_m, "element_width_m", |probe| {
                probe.element_width
            })?,
            center_frequency: pick(p.center_frequency_hz, "center_frequency_hz", |probe| {
                probe.center_frequency
            })?,
            bandwidth: pick(p.bandwidth, "bandwidth", |probe| probe.bandwidth)?,
        })
    }

    /// The level (fraction of its peak) at which the echo waveform is truncated.
    pub fn waveform_truncation(&self) -> f64 {
        self.receive
            .waveform_truncation_db
            .map_or(pcuvd::simulate::EchoWaveform::DEFAULT_TRUNCATION, |db| {
                10f64.powf(db / 20.0)
            })
    }

    /// The sampled transmit pulse of `[sequence.pulse]`, if any.
    pub fn transmit_pulse(&self) -> Option<pcuvd::TransmitPulse> {
        self.sequence.pulse.as_ref().map(|p| pcuvd::TransmitPulse {
            samples: p.samples.clone(),
            sampling_frequency: p.sampling_frequency_hz,
        })
    }

    /// The transmit pulse's length in cycles of the centre frequency: `pulse_cycles`, else the
    /// sampled pulse's duration.
    pub fn pulse_cycles(&self) -> Result<f64> {
        let s = &self.sequence;
        match (s.pulse_cycles, &s.pulse) {
            (Some(cycles), _) => Ok(cycles),
            (None, Some(p)) => {
                Ok(p.samples.len() as f64 / p.sampling_frequency_hz
                    * self.probe()?.center_frequency)
            }
            (None, None) => bail!("[sequence].pulse_cycles is missing"),
        }
    }

    /// The elevation aperture, when the probe has one.
    pub fn elevation(&self) -> Option<pcuvd::simulate::ElevationAperture> {
        match (self.probe.element_height_m, self.probe.elevation_focus_m) {
            (Some(height), Some(focus)) => {
                Some(pcuvd::simulate::ElevationAperture { height, focus })
            }
            _ => None,
        }
    }

    /// The steering angles (rad).
    pub fn angles(&self) -> Vec<f64> {
        let s = &self.sequence;
        match (&s.angles_deg, s.angles) {
            (Some(list), _) => list.iter().map(|a| a.to_radians()).collect(),
            (None, n) => pcuvd::Sequence::evenly_spaced_angles(
                n.unwrap_or(0),
                s.max_angle_deg
                    .unwrap_or(DEFAULT_MAX_ANGLE_DEG)
                    .to_radians(),
            ),
        }
    }
}

#[cfg(test)]
pub(crate) mod tests;
