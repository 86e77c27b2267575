//! The scenario file's schema: one type per TOML section, each with its keys in SI units and
//! its defaults; [`super::Scenario::check`] checks their values.

use serde::{Deserialize, Serialize};

use crate::settings::TubeProfile;

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
    /// Slab thickness along the elevation y, centred on the imaging plane (m; at most 20 mm).
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
    /// Blood rendered at keyframes by speed class and interpolated between them, instead of at
    /// every event (`pcuvd::simulate::keyframes::KeyframedBlood`), in a fraction of the time:
    /// moving blood's echoes agree within about 2·10⁻⁴ (−74 dB); blood re-entering a segment at
    /// its other end fades in over a few keyframes instead of jumping (2.6 % RMS of the small rat
    /// brain's blood echo).
    pub blood_keyframes: bool,
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
            blood_keyframes: true,
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
