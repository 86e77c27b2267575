//! What to simulate: the options of `pcuvd simulate` (and `pcuvd.simulate`) as settings, each
//! overriding a value of the scenario they start from, and the shipped presets by name.

use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};

use crate::scenario::{
    LayerSection, MAX_ECHOGENICITY_DB, MotionSection, NoiseSection, Scenario, TissueSection,
    TubeSection, Vessels,
};
use crate::settings::parse_numbers;

use super::{ModeChoice, TissueMotionChoice};

/// Built-in simulation set-ups.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum Preset {
    /// The paper's spiral (§2.3): L22-14vX, 15.625 MHz, 2-cycle pulse, f_s 65 MHz, c 1540 m/s, 8 angles in [−15°, 15°], event PRF 14.4 kHz (1.8 kHz compound), Hadamard order 8 with 1 µs slots, 100 frames, noise −10 dB.
    PaperSpiral,
    /// A straight tube (radius 0.5 mm, 16 mm long, 25 mm/s peak unless --peak-velocity-mm-s, parabolic unless --tube-profile) at 30° below +x through (0, 8 mm) unless the --tube-* options place it, with the paper-spiral acquisition.
    Tube,
    /// The in-vivo-like pulsatile vessel network at 5.5 Hz (4 arterioles RI 0.7, 4 venules RI 0.3, flowing up and down, 1–13 mm deep) with the paper's rat acquisition (Table 1): as paper-spiral but 360 frames (0.2 s), receive window 0–13 mm; writes the RI truth too.
    RatNetwork,
    /// A first virtual rat brain, in three dimensions: the rat acquisition (Table 1) with the L22-14vX's elevation (1.5 mm elements, lens focus 8 mm); a 10 mm coronal slab of cortex 1–3 mm deep with a generated vascular tree (pial artery and vein, penetrating arterioles and ascending venules branching by Murray's law, a capillary bed; compliant pulsatile flow at 5.5 Hz: arterioles ~16 mm/s RI ~0.7, venules ~7 mm/s RI ~0.1) and four pairs of larger deep vessels rising from 9 mm toward 5 mm; tissue 40 dB above blood (--tissue-db) in a 1.2 mm slab under a dura-like layer, with the corpus callosum and lateral ventricles below the cortex, moving with the heartbeat and breathing (--tissue-motion) with the vessels; noise 0 dB re the blood's echo; 360 frames. Writes the RI truth and the out-of-plane velocity and blood fraction.
    RatBrain,
    /// The rat brain cut down for a first look in about a minute: the central 48 elements, a 3 mm slab of cortex with one deep pair rising from 6 mm, an 8 mm receive window, 48 frames (no whole cardiac cycle, so no RI maps); tissue, layers, motion and noise as the rat brain's.
    RatBrainSmall,
}

/// What to simulate: every option of `pcuvd simulate` but the output folder. A scenario (a shipped
/// one, or a TOML file) describes the whole simulation; the other options override its values.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
#[serde(default, deny_unknown_fields)]
pub struct SimulationSettings {
    /// The scenario to simulate: a TOML file (see docs/guide/scenarios.md) or the name of a
    /// shipped one (paper-spiral, tube, rat-network, rat-brain, rat-brain-small: the presets). Default: paper-spiral.
    #[cfg_attr(feature = "clap", arg(long))]
    #[serde(deserialize_with = "crate::settings::optional_text")]
    pub scenario: Option<String>,
    /// A shipped scenario by name (the same as --scenario NAME).
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub preset: Option<Preset>,
    /// Transmit mode(s) (default: the scenario's; every preset: both).
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub mode: Option<ModeChoice>,
    /// Compound frames (default: the scenario's: 100, or 360 for rat-network and rat-brain).
    #[cfg_attr(feature = "clap", arg(long))]
    pub frames: Option<usize>,
    /// Noise level in dB (see the noise definition in `--help` of the report; default: the
    /// scenario's: −10 for every preset but rat-brain, 0); "off" for none.
    #[cfg_attr(feature = "clap", arg(long, allow_hyphen_values = true))]
    #[serde(deserialize_with = "crate::settings::optional_text")]
    pub noise_db: Option<String>,
    /// Seed of the scatterers, the noise and a generated tree (default: the scenario's, 1).
    #[cfg_attr(feature = "clap", arg(long))]
    pub seed: Option<u64>,
    /// Number of steering angles, evenly spaced over [−15°, 15°] (coded: a Hadamard order: 1, 2,
    /// 4, 8, 12, 16, ...; default: the scenario's, 8).
    #[cfg_attr(feature = "clap", arg(long))]
    pub angles: Option<usize>,
    /// Hadamard slot delay (µs; default: the scenario's, 1).
    #[cfg_attr(feature = "clap", arg(long))]
    pub slot_delay_us: Option<f64>,
    /// Peak flow speed (mm/s): the centreline speed of the tube and the spiral, the peak
    /// systolic speed of the network's fastest vessel (the others scaled alike). Default: the
    /// scenario's (25 mm/s; the network's fastest arteriole 30 mm/s). The projection Nyquist
    /// velocity of the 8-angle presets is about 44 mm/s: faster flow aliases (see `process
    /// --dealias`).
    #[cfg_attr(feature = "clap", arg(long))]
    pub peak_velocity_mm_s: Option<f64>,
    /// Flow profile of the tube preset: parabolic (laminar, zero at the wall) or plug (the peak
    /// speed across the lumen): fast up to the wall, where vector dealiasing settles its level
    /// by the vessel's residual rather than by slow flow at the wall.
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub tube_profile: Option<crate::settings::TubeProfile>,
    /// Flow direction of the tube preset (degrees from +x toward +z: 30 flows toward +x and
    /// deeper, 90 straight down; default 30).
    #[cfg_attr(feature = "clap", arg(long, allow_hyphen_values = true))]
    pub tube_angle_deg: Option<f64>,
    /// Centre of the tube preset "x,z" (mm; default 0,8).
    #[cfg_attr(feature = "clap", arg(long, allow_hyphen_values = true))]
    #[serde(deserialize_with = "crate::settings::optional_text")]
    pub tube_centre_mm: Option<String>,
    /// Length of the tube preset along its axis (mm; default 16): scatterers leaving one end
    /// re-enter at the other, so an end inside the image is a vessel that starts or stops there.
    #[cfg_attr(feature = "clap", arg(long, allow_hyphen_values = true))]
    pub tube_length_mm: Option<f64>,
    /// Radius of the tube preset (mm; default 0.5).
    #[cfg_attr(feature = "clap", arg(long, allow_hyphen_values = true))]
    pub tube_radius_mm: Option<f64>,
    /// Tissue this many dB brighter than blood per unit area or volume (in vivo 30–60; try 40;
    /// at most 150, its layers too).
    /// A scenario with tissue (rat-brain) shifts its tissue and layers by the difference. One
    /// without gets fully developed speckle in the imaging plane over the image, a bright 0.1 mm
    /// layer (+10 dB) at 0.5 mm like the dura, no tissue inside the vessels; vessels and tissue
    /// move together (--tissue-motion). The noise level is then relative to the blood's echo
    /// alone.
    #[cfg_attr(feature = "clap", arg(long, allow_hyphen_values = true))]
    pub tissue_db: Option<f64>,
    /// How the tissue (and the vessels in it) moves (default: the scenario's; with --tissue-db
    /// on a scenario without tissue, rat).
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub tissue_motion: Option<TissueMotionChoice>,
    /// The rat brain's vessels from a folder of three tables instead of its generated tree:
    /// vertices.csv (x, y, z; headers x_um,y_um,z_um or x_m,y_m,z_m; y out of the imaging plane,
    /// z depth), edges.csv (v1,v2,diameter,length,class: arteriole, capillary or venule; an
    /// empty length is the straight distance) and boundary.csv (vertex,type,value,pulse:
    /// pressure in Pa or flow in m³/s, mean and peak-to-trough cardiac swing). The flow is
    /// solved from the boundary conditions (Poiseuille and compliance).
    #[cfg_attr(feature = "clap", arg(long))]
    #[serde(deserialize_with = "crate::settings::optional_text")]
    pub vessel_tables: Option<String>,
}

impl SimulationSettings {
    /// Where the scenario comes from: the `--scenario` file or name, or the preset's name.
    pub fn scenario_source(&self) -> Result<String> {
        match (&self.scenario, self.preset) {
            (Some(_), Some(_)) => bail!("give --scenario or --preset, not both"),
            (Some(source), None) => Ok(source.clone()),
            (None, preset) => Ok(preset.unwrap_or(Preset::PaperSpiral).name().to_string()),
        }
    }

    /// The scenario to simulate: the one named, with these options' overrides, checked.
    pub fn scenario(&self) -> Result<Scenario> {
        let mut scenario = Scenario::load(&self.scenario_source()?)?;
        self.apply_to(&mut scenario)?;
        scenario
            .check()
            .context("the scenario with the options given")?;
        Ok(scenario)
    }

    /// Applies every option given to `scenario`.
    pub(crate) fn apply_to(&self, scenario: &mut Scenario) -> Result<()> {
        if let Some(mode) = self.mode {
            scenario.sequence.transmit = mode;
        }
        if let Some(frames) = self.frames {
            if frames == 0 {
                bail!("--frames must be at least 1");
            }
            scenario.sequence.frames = frames;
        }
        if let Some(text) = &self.noise_db {
            scenario.noise = match text.as_str() {
                "off" | "none" => None,
                text => Some(NoiseSection {
                    level_db: text
                        .parse::<f64>()
                        .ok()
                        .filter(|v| v.is_finite())
                        .with_context(|| {
                            format!("--noise-db {text:?}: expected a number of dB or \"off\"")
                        })?,
                }),
            };
        }
        if let Some(seed) = self.seed {
            scenario.seed = seed;
        }
        if let Some(angles) = self.angles {
            scenario.sequence.angles = Some(angles);
            scenario.sequence.angles_deg = None;
        }
        if let Some(us) = self.slot_delay_us {
            scenario.sequence.slot_delay_s = us * 1e-6;
        }
        let peak = match self.peak_velocity_mm_s {
            Some(v) if !(v.is_finite() && v > 0.0) => {
                bail!("--peak-velocity-mm-s {v}: must be a finite speed > 0 mm/s")
            }
            given => given.map(|v| v * 1e-3),
        };
        let tube_flags = [
            ("--tube-profile", self.tube_profile.is_some()),
            ("--tube-angle-deg", self.tube_angle_deg.is_some()),
            ("--tube-centre-mm", self.tube_centre_mm.is_some()),
            ("--tube-length-mm", self.tube_length_mm.is_some()),
            ("--tube-radius-mm", self.tube_radius_mm.is_some()),
        ];
        if !matches!(scenario.vessels, Vessels::Tube(_))
            && let Some((flag, _)) = tube_flags.iter().find(|(_, given)| *given)
        {
            bail!(
                "{flag} applies to --preset tube only (or a scenario of [vessels] kind \"tube\")"
            );
        }
        if !matches!(scenario.vessels, Vessels::Tree(_)) && self.vessel_tables.is_some() {
            bail!(
                "--vessel-tables applies to --preset rat-brain only (or a scenario of [vessels] kind \"tree\")"
            );
        }
        match &mut scenario.vessels {
            Vessels::Spiral(spiral) => {
                if let Some(peak) = peak {
                    spiral.peak_velocity_m_s = peak;
                }
            }
            Vessels::Tube(tube) => self.apply_to_tube(tube, peak)?,
            Vessels::RatNetwork(network) => {
                if peak.is_some() {
                    network.fastest_psv_m_s = peak;
                }
            }
            Vessels::Tree(tree) => {
                if peak.is_some() {
                    bail!(
                        "--peak-velocity-mm-s does not apply to a vascular tree (--preset rat-brain), whose speeds follow from its pressures"
                    );
                }
                if let Some(folder) = &self.vessel_tables {
                    tree.tables = Some(folder.clone());
                }
            }
        }
        match (&mut scenario.tissue, self.tissue_db) {
            (_, Some(db)) if !(db.is_finite() && db <= MAX_ECHOGENICITY_DB) => {
                bail!(
                    "--tissue-db {db}: must be a finite number of dB, at most {MAX_ECHOGENICITY_DB} above the \
                     blood's echo (in vivo tissue echoes 30–60 dB above it)"
                )
            }
            (Some(tissue), Some(db)) => {
                // The layers keep their contrast to the parenchyma.
                let shift = db - tissue.echogenicity_db;
                tissue.echogenicity_db = db;
                for layer in &mut tissue.layers {
                    layer.echogenicity_db += shift;
                }
            }
            (None, Some(db)) => {
                let [_, deepest] = scenario.receive.depth_m;
                scenario.tissue = Some(TissueSection {
                    echogenicity_db: db,
                    x_range_m: None,
                    depth_m: [0.5e-3, deepest + 0.5e-3],
                    half_thickness_m: 0.0,
                    density_per_m3: None,
                    density_per_m2: None,
                    layers: vec![LayerSection {
                        top_m: 0.5e-3,
                        thickness_m: 0.1e-3,
                        echogenicity_db: db + 10.0,
                    }],
                    anechoic: Vec::new(),
                    motion: MotionSection {
                        preset: Some(TissueMotionChoice::Rat),
                        ..MotionSection::default()
                    },
                });
            }
            (_, None) => {}
        }
        if let (Some(tissue), Some(db)) = (&scenario.tissue, self.tissue_db) {
            let brightest = tissue
                .layers
                .iter()
                .map(|l| l.echogenicity_db)
                .fold(db, f64::max);
            if brightest > MAX_ECHOGENICITY_DB {
                bail!(
                    "--tissue-db {db}: the scenario's brightest layer, {} dB above its tissue, \
                     would echo {brightest} dB above the blood, beyond {MAX_ECHOGENICITY_DB}",
                    brightest - db
                );
            }
        }
        if let Some(choice) = self.tissue_motion {
            let Some(tissue) = &mut scenario.tissue else {
                bail!("--tissue-motion moves tissue: add some with --tissue-db");
            };
            tissue.motion = MotionSection {
                preset: Some(choice),
                ..MotionSection::default()
            };
        }
        Ok(())
    }

    /// The `--tube-*` options and the peak speed `peak` (m/s) applied to `tube`.
    fn apply_to_tube(&self, tube: &mut TubeSection, peak: Option<f64>) -> Result<()> {
        if let Some(text) = &self.tube_centre_mm {
            tube.centre_m = match parse_numbers(text).as_deref() {
                Ok(&[x, z]) => [x * 1e-3, z * 1e-3],
                _ => bail!("--tube-centre-mm {text:?}: expected two finite numbers \"x,z\" in mm"),
            };
        }
        let positive_mm = |flag: &str, value: Option<f64>, slot: &mut f64| match value {
            None => Ok(()),
            Some(v) if v.is_finite() && v > 0.0 => {
                *slot = v * 1e-3;
                Ok(())
            }
            Some(v) => bail!("{flag} {v}: must be a finite length > 0 mm"),
        };
        positive_mm("--tube-length-mm", self.tube_length_mm, &mut tube.length_m)?;
        positive_mm("--tube-radius-mm", self.tube_radius_mm, &mut tube.radius_m)?;
        if let Some(deg) = self.tube_angle_deg {
            if !deg.is_finite() {
                bail!("--tube-angle-deg {deg}: must be a finite number of degrees");
            }
            tube.angle_deg = deg;
        }
        if let Some(profile) = self.tube_profile {
            tube.profile = profile;
        }
        if let Some(peak) = peak {
            tube.peak_velocity_m_s = peak;
        }
        Ok(())
    }
}

impl Preset {
    /// The shipped scenario's name.
    pub fn name(self) -> &'static str {
        match self {
            Preset::PaperSpiral => "paper-spiral",
            Preset::Tube => "tube",
            Preset::RatNetwork => "rat-network",
            Preset::RatBrain => "rat-brain",
            Preset::RatBrainSmall => "rat-brain-small",
        }
    }
}
