//! Simulated recordings of flow phantoms, conventional and Hadamard-coded, with ground truth:
//! the settings of `pcuvd simulate` (and `pcuvd.simulate`) and the [`Simulation`] they set up.

use anyhow::{Context, Result, bail};
use pcuvd::pipeline;
use pcuvd::simulate::ElevationAperture;
use pcuvd::simulate::keyframes::{TissueKeyframes, keyframe_interval};
use pcuvd::simulate::phantom::network::{NetworkPhantom, NetworkSpec};
use pcuvd::simulate::phantom::tissue::{Anechoic, Layer, MotionTruth};
use pcuvd::simulate::phantom::{
    Moved, Phantom, SpiralPhantom, SpiralSpec, TissueMotion, TissuePhantom, TissueSpec,
    TreePhantom, TreeSpec, TubePhantom, TubeSpec,
};
use pcuvd::simulate::vascular::{CortexParams, FlowParams, generate, solve};
use pcuvd::simulate::{self, NOISE_DEFINITION, NoiseSpec, SimParams};
use pcuvd::{Coding, Sequence};
use serde::{Deserialize, Serialize};

use crate::settings::parse_numbers;

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
    /// A first virtual rat brain, in three dimensions: the rat acquisition (Table 1) with the L22-14vX's elevation (1.5 mm elements, lens focus 8 mm); a 10 mm coronal slab of cortex 1–3 mm deep with a generated vascular tree (pial artery and vein, penetrating arterioles and ascending venules branching by Murray's law, a capillary bed; compliant pulsatile flow at 5.5 Hz: arterioles ~16 mm/s RI ~0.7, venules ~7 mm/s RI ~0.1); tissue 40 dB above blood (--tissue-db) in a 1.2 mm slab under a dura-like layer, with the corpus callosum and lateral ventricles below the cortex, moving with the heartbeat and breathing (--tissue-motion) with the vessels; 360 frames. Writes the RI truth and the out-of-plane velocity and blood fraction.
    RatBrain,
}

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

/// What to simulate: every option of `pcuvd simulate` but the output folder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
#[serde(default, deny_unknown_fields)]
pub struct SimulationSettings {
    /// The set-up to simulate.
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = SimulationSettings::default().preset))]
    pub preset: Preset,
    /// Transmit mode(s).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = SimulationSettings::default().mode))]
    pub mode: ModeChoice,
    /// Compound frames (default: the preset's: 100, or 360 for rat-network).
    #[cfg_attr(feature = "clap", arg(long))]
    pub frames: Option<usize>,
    /// Noise level in dB (see the noise definition in `--help` of the report; default −10); "off" for none.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = SimulationSettings::default().noise_db, allow_hyphen_values = true))]
    #[serde(deserialize_with = "crate::settings::text")]
    pub noise_db: String,
    /// Seed of the scatterers and the noise.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = SimulationSettings::default().seed))]
    pub seed: u64,
    /// Number of steering angles, evenly spaced over [−15°, 15°] (coded: a Hadamard order: 1, 2, 4, 8, 12, 16, ...).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = SimulationSettings::default().angles))]
    pub angles: usize,
    /// Hadamard slot delay (µs).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = SimulationSettings::default().slot_delay_us))]
    pub slot_delay_us: f64,
    /// Peak flow speed (mm/s): the centreline speed of the tube and the spiral, the peak
    /// systolic speed of the network's fastest vessel (the others scaled alike). Default: the
    /// preset's (25 mm/s; the network's fastest arteriole 30 mm/s). The projection Nyquist
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
    /// Add tissue around the vessels, this many dB brighter than blood per unit area (in vivo
    /// 30–60; try 40): fully developed speckle in the imaging plane over the image, a bright
    /// 0.1 mm layer (+10 dB) at 0.5 mm like the dura, no tissue inside the vessels; vessels and
    /// tissue move together (--tissue-motion). The noise level is then relative to the blood's
    /// echo alone. Default: no tissue.
    #[cfg_attr(feature = "clap", arg(long, allow_hyphen_values = true))]
    pub tissue_db: Option<f64>,
    /// How the tissue (and the vessels in it) moves, with --tissue-db.
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = SimulationSettings::default().tissue_motion))]
    pub tissue_motion: TissueMotionChoice,
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

impl Default for SimulationSettings {
    fn default() -> Self {
        SimulationSettings {
            preset: Preset::PaperSpiral,
            mode: ModeChoice::Both,
            frames: None,
            noise_db: "-10".into(),
            seed: 1,
            angles: 8,
            slot_delay_us: 1.0,
            peak_velocity_mm_s: None,
            tube_profile: None,
            tube_angle_deg: None,
            tube_centre_mm: None,
            tube_length_mm: None,
            tube_radius_mm: None,
            tissue_db: None,
            tissue_motion: TissueMotionChoice::Rat,
            vessel_tables: None,
        }
    }
}

/// A simulation, set up and checked before anything is simulated: the phantom and each transmit
/// mode's settings.
pub struct Simulation {
    /// The options it was set up from.
    pub options: SimulationSettings,
    /// Compound frames per recording.
    pub frames: usize,
    /// Noise level (dB), `None` for none.
    pub noise_db: Option<f64>,
    /// The flow phantom.
    pub phantom: Box<dyn Phantom>,
    /// The vessel network, for its cardiac-cycle truth (the `rat-network` preset only).
    pub network: Option<NetworkPhantom>,
    /// The tube's geometry and flow (the `tube` preset only).
    pub tube: Option<TubeSpec>,
    /// Each recording to simulate: its name ("conventional", "coded") and settings.
    pub modes: Vec<(&'static str, SimParams)>,
    /// The tissue around the vessels and how it moves (with `--tissue-db`, or the rat brain).
    pub tissue: Option<TissuePhantom>,
    /// The vascular tree (the `rat-brain` preset only).
    pub tree: Option<TreePhantom>,
    /// The tissue's keyframes, shared by the blocks and modes simulated in turn.
    keyframes: std::sync::Mutex<TissueKeyframes>,
}

/// The ground truth of a simulation on the recording's default processing grid (m, m/s).
pub struct SimulatedTruth {
    /// Pixel columns (m).
    pub x: Vec<f64>,
    /// Pixel rows (m).
    pub z: Vec<f64>,
    /// Velocity and flow mask at t = 0, shape (nz, nx).
    pub truth: pcuvd::simulate::phantom::Truth,
    /// The vessel network's cardiac-cycle truth (RI, PSV, EDV, classes), when it is one.
    pub cycle: Option<pcuvd::simulate::phantom::network::NetworkTruth>,
    /// The tissue's velocity and displacement at t = 0, when there is tissue.
    pub tissue: Option<MotionTruth>,
    /// Out-of-plane velocity (m/s) and blood fraction of each pixel's elevation beam, for a
    /// phantom in three dimensions (the vascular tree).
    pub elevation: Option<(ndarray::Array2<f64>, ndarray::Array2<f64>)>,
}

impl Simulation {
    /// Sets up the simulation `options` describe; every mode's settings are checked, so that a
    /// refused request (`--mode both --angles 6`: no Hadamard order) fails before any work.
    pub fn new(options: &SimulationSettings) -> Result<Simulation> {
        let args = options;
        let frames = args.frames.unwrap_or(match args.preset {
            Preset::RatNetwork | Preset::RatBrain => simulate::RAT_FRAMES,
            _ => simulate::PAPER_FRAMES,
        });
        if frames == 0 {
            bail!("--frames must be at least 1");
        }
        let noise_db = match args.noise_db.as_str() {
            "off" | "none" => None,
            text => Some(
                text.parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .with_context(|| {
                        format!("--noise-db {text:?}: expected a number of dB or \"off\"")
                    })?,
            ),
        };
        let peak = match args.peak_velocity_mm_s {
            Some(v) if !(v.is_finite() && v > 0.0) => {
                bail!("--peak-velocity-mm-s {v}: must be a finite speed > 0 mm/s")
            }
            given => given.map(|v| v * 1e-3),
        };
        let tube = match args.preset {
            Preset::Tube => Some(tube_spec(args, peak.unwrap_or(25e-3))?),
            _ => {
                let tube_flags = [
                    ("--tube-profile", args.tube_profile.is_some()),
                    ("--tube-angle-deg", args.tube_angle_deg.is_some()),
                    ("--tube-centre-mm", args.tube_centre_mm.is_some()),
                    ("--tube-length-mm", args.tube_length_mm.is_some()),
                    ("--tube-radius-mm", args.tube_radius_mm.is_some()),
                ];
                if let Some((flag, _)) = tube_flags.iter().find(|(_, given)| *given) {
                    bail!("{flag} applies to --preset tube only");
                }
                None
            }
        };
        let network = match args.preset {
            Preset::RatNetwork => {
                let spec = NetworkSpec::rat();
                let spec = match peak {
                    Some(psv) => spec.with_fastest_psv(psv)?,
                    None => spec,
                };
                Some(NetworkPhantom::new(spec, args.seed)?)
            }
            _ => None,
        };
        let tree = match args.preset {
            Preset::RatBrain => {
                if peak.is_some() {
                    bail!(
                        "--peak-velocity-mm-s does not apply to --preset rat-brain, whose speeds follow from its tree's pressures"
                    );
                }
                let graph = match &args.vessel_tables {
                    None => generate(&brain_cortex(args.seed))
                        .context("the rat brain's vascular tree")?,
                    Some(folder) => read_vessel_tables(std::path::Path::new(folder))?,
                };
                let flow =
                    solve(&graph, &FlowParams::rat()).context("the rat brain's blood flow")?;
                Some(TreePhantom::new(
                    flow,
                    TreeSpec::default_blood(),
                    args.seed,
                )?)
            }
            _ => {
                if args.vessel_tables.is_some() {
                    bail!("--vessel-tables applies to --preset rat-brain only");
                }
                None
            }
        };
        let phantom: Box<dyn Phantom> = match (args.preset, &network) {
            (_, Some(network)) => Box::new(network.clone()),
            (Preset::RatBrain, None) => Box::new(tree.clone().context("the rat brain's tree")?),
            (Preset::PaperSpiral, None) => {
                let paper = SpiralSpec::paper();
                let spec = SpiralSpec {
                    peak_speed: peak.unwrap_or(paper.peak_speed),
                    ..paper
                };
                Box::new(SpiralPhantom::new(spec, args.seed)?)
            }
            (_, None) => Box::new(TubePhantom::new(
                tube.clone().context("the tube preset's vessel")?,
                args.seed,
            )?),
        };
        let coded_modes: Vec<bool> = match args.mode {
            ModeChoice::Coded => vec![true],
            ModeChoice::Conventional => vec![false],
            ModeChoice::Both => vec![false, true],
        };
        let modes = coded_modes
            .into_iter()
            .map(|coded| {
                let name = if coded { "coded" } else { "conventional" };
                Ok((name, mode_params(args, coded, noise_db)?))
            })
            .collect::<Result<Vec<_>>>()?;
        let tissue_db = match (args.preset, args.tissue_db) {
            (Preset::RatBrain, None) => Some(TissueSpec::DEFAULT_ECHOGENICITY_DB),
            (_, given) => given,
        };
        let tissue = match tissue_db {
            None => None,
            Some(db) if !db.is_finite() => bail!("--tissue-db {db}: must be a finite number of dB"),
            Some(db) => Some(tissue(
                args,
                db,
                phantom.as_ref(),
                tree.as_ref(),
                &modes[0].1,
            )?),
        };
        let interval = tissue.as_ref().map_or(f64::INFINITY, |tissue| {
            let params = &modes[0].1;
            keyframe_interval(
                tissue.spec().motion.max_speed(tissue.spec().z_range),
                params.probe.wavelength(params.sound_speed),
            )
        });
        let lead = modes
            .iter()
            .map(|(_, params)| params.sequence.last_slot_start())
            .fold(0.0, f64::max);
        Ok(Simulation {
            options: options.clone(),
            frames,
            noise_db,
            phantom,
            network,
            tube,
            modes,
            tissue,
            tree,
            keyframes: std::sync::Mutex::new(TissueKeyframes::new(interval, lead)),
        })
    }

    /// Events `events` of recording `index`: the phantom alone, or with the tissue (rendered at
    /// keyframes, the vessels moving with it). Keyframes are kept for the next call: simulate
    /// the modes block by block (the same events of each in turn) so that they render once.
    fn simulate_block(
        &self,
        index: usize,
        events: std::ops::Range<usize>,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<ndarray::Array3<f32>> {
        let params = &self.modes[index].1;
        let phantom = self.phantom.as_ref();
        Ok(match &self.tissue {
            None => simulate::simulate_events(phantom, params, self.frames, events, progress)?,
            Some(tissue) => {
                let moved = Moved {
                    inner: phantom,
                    motion: &tissue.spec().motion,
                };
                let mut rf = simulate::simulate_events(
                    &moved,
                    params,
                    self.frames,
                    events.clone(),
                    progress,
                )?;
                self.keyframes
                    .lock()
                    .map_err(|_| {
                        anyhow::anyhow!("the tissue's keyframes: another simulation thread failed")
                    })?
                    .add(tissue, params, events, rf.view_mut())?;
                rf
            }
        })
    }

    /// Simulates recording `index` of [`Self::modes`]; `progress(events done, events)`.
    pub fn recording(
        &self,
        index: usize,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<pcuvd::ChannelData> {
        let params = &self.modes[index].1;
        let events = self.frames * params.sequence.n_angles();
        Ok(pcuvd::ChannelData {
            acquisition: params.acquisition(),
            samples: pcuvd::Samples::Rf(self.simulate_block(index, 0..events, progress)?),
        })
    }

    /// Events `events` of recording `index` of [`Self::modes`] (see
    /// [`simulate::simulate_events`]), shape (events, channels, samples).
    pub fn events(
        &self,
        index: usize,
        events: std::ops::Range<usize>,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<ndarray::Array3<f32>> {
        self.simulate_block(index, events, progress)
    }

    /// The `[provenance]` a recording of mode `index` carries: simulator, preset, seed, noise.
    pub fn provenance(&self, index: usize) -> toml::Table {
        let params = &self.modes[index].1;
        let mut provenance = toml::Table::new();
        provenance.insert("simulator".into(), "pcuvd simulate".into());
        provenance.insert("preset".into(), format!("{:?}", self.options.preset).into());
        provenance.insert("seed".into(), (self.options.seed as i64).into());
        provenance.insert(
            "blood_scatterers".into(),
            (self.phantom.n_scatterers() as i64).into(),
        );
        provenance.insert(
            "noise_db".into(),
            self.noise_db
                .map_or(toml::Value::from("off"), toml::Value::from),
        );
        provenance.insert("noise_definition".into(), NOISE_DEFINITION.into());
        provenance.insert(
            "attenuation_db_cm_mhz".into(),
            params.attenuation_db_cm_mhz.into(),
        );
        if let Some(folder) = &self.options.vessel_tables {
            provenance.insert("vessel_tables".into(), folder.clone().into());
        }
        if let Some(tissue) = &self.tissue {
            let spec = tissue.spec();
            let mut table = toml::Table::new();
            table.insert("echogenicity_db".into(), spec.echogenicity_db.into());
            table.insert("scatterers".into(), (tissue.n_scatterers() as i64).into());
            table.insert(
                "motion".into(),
                match self.options.tissue_motion {
                    TissueMotionChoice::Rat => "rat",
                    TissueMotionChoice::Still => "still",
                }
                .into(),
            );
            provenance.insert("tissue".into(), table.into());
        }
        if let Some(tube) = &self.tube {
            let mm = |v: f64| toml::Value::from(v * 1e3);
            let mut vessel = toml::Table::new();
            vessel.insert(
                "centre_mm".into(),
                toml::Value::Array(tube.centre.iter().map(|&v| mm(v)).collect()),
            );
            // Rounded to 1e-9° so that the 60 given reads back as 60, not 59.99999999999999.
            let degrees = (tube.angle.to_degrees() * 1e9).round() / 1e9;
            vessel.insert("angle_deg".into(), degrees.into());
            vessel.insert("length_mm".into(), mm(tube.length));
            vessel.insert("radius_mm".into(), mm(tube.radius));
            vessel.insert("peak_velocity_mm_s".into(), mm(tube.peak_speed));
            vessel.insert("profile".into(), tube.profile.label().into());
            provenance.insert("tube".into(), vessel.into());
        }
        provenance
    }

    /// The ground truth on `data`'s default processing grid (the same for every mode).
    pub fn truth(&self, data: &pcuvd::ChannelData) -> Result<SimulatedTruth> {
        self.truth_for(&data.acquisition, data.samples.dim().2)
    }

    /// The ground truth on the default processing grid of a recording acquired as `acq` with
    /// traces of `n_samples` samples.
    pub fn truth_for(&self, acq: &pcuvd::Acquisition, n_samples: usize) -> Result<SimulatedTruth> {
        let grid = pipeline::default_grid_for(acq, n_samples)?;
        // The tree's truth is the elevation beam's view of it, not the plane's cut.
        let params = &self.modes[0].1;
        let lambda = params.probe.wavelength(params.sound_speed);
        let aperture = params.elevation.as_ref().map(|a| (a, lambda));
        let (mut truth, elevation, cycle) = match &self.tree {
            Some(tree) => {
                let seen = tree.plane_truth(&grid.x, &grid.z, 0.0, aperture);
                (
                    seen.truth,
                    Some((seen.vy, seen.blood_fraction)),
                    Some(seen.cycle),
                )
            }
            None => (
                self.phantom.truth(&grid.x, &grid.z, 0.0),
                None,
                self.network
                    .as_ref()
                    .map(|network| network.cycle_truth(&grid.x, &grid.z)),
            ),
        };
        // The vessels move with the tissue.
        if let Some(tissue) = &self.tissue {
            tissue
                .spec()
                .motion
                .carry(&mut truth, &grid.x, &grid.z, 0.0);
        }
        Ok(SimulatedTruth {
            truth,
            elevation,
            tissue: self
                .tissue
                .as_ref()
                .map(|tissue| tissue.motion_truth(&grid.x, &grid.z, 0.0)),
            cycle,
            x: grid.x,
            z: grid.z,
        })
    }
}

/// The vessel graph in `folder`'s three tables (see `--vessel-tables`).
fn read_vessel_tables(folder: &std::path::Path) -> Result<pcuvd::simulate::vascular::VesselGraph> {
    let read = |name: &str| {
        let path = folder.join(name);
        std::fs::read_to_string(&path)
            .with_context(|| format!("--vessel-tables: cannot read {}", path.display()))
    };
    let (vertices, edges, boundary) = (
        read("vertices.csv")?,
        read("edges.csv")?,
        read("boundary.csv")?,
    );
    pcuvd::simulate::vascular::parse_tables(&vertices, &edges, &boundary)
        .with_context(|| format!("--vessel-tables {}", folder.display()))
}

/// The rat brain's cortex: the generator's slab with a denser capillary bed (eight 10 µm paths of
/// two segments from each arteriole terminal), which carries the flow that a real bed of many
/// capillaries does: penetrating arterioles then run at a median PSV of 16 mm/s (90th percentile
/// 27), capillaries 8, venules 7, with RI medians 0.73, 0.60 and 0.08 (the generator's default
/// bed, two paths of three 8 µm segments, starves them: 4, 14 and 2 mm/s).
fn brain_cortex(seed: u64) -> CortexParams {
    CortexParams {
        capillaries_per_terminal: 8,
        capillary_segments: 2,
        capillary_diameter: 10e-6,
        seed,
        ..CortexParams::default()
    }
}

/// The tissue of `--tissue-db` `db` around `phantom`'s vessels, over the image of `params`: a
/// sheet in the imaging plane, or for the rat brain (`tree`) a slab under a dura-like layer.
fn tissue(
    args: &SimulationSettings,
    db: f64,
    phantom: &dyn Phantom,
    tree: Option<&TreePhantom>,
    params: &SimParams,
) -> Result<TissuePhantom> {
    let (x0, x1) = params.probe.aperture();
    // Tissue below the preset's imaging depth would only cost time.
    let window = 0.5 * params.sound_speed * (params.t0 + params.window_duration());
    let preset_depth: f64 = match args.preset {
        Preset::RatNetwork | Preset::RatBrain => 13.5e-3,
        _ => 14.5e-3,
    };
    let depth = preset_depth.min(window);
    let motion = match args.tissue_motion {
        TissueMotionChoice::Rat => TissueMotion::rat(),
        TissueMotionChoice::Still => TissueMotion::still(),
    };
    // The brain's surface: the dura sits on the cortex, gel (anechoic) above it.
    let top = match tree {
        Some(_) => brain_cortex(0).surface_depth - 0.1e-3,
        None => 0.5e-3,
    };
    let (half_thickness, density, blood_power_density) = match tree {
        // The slab covers the elevation beam: the 1.5 mm strip's near field, 0.4 mm at its focus.
        Some(_) => (
            0.6e-3,
            TissueSpec::DEFAULT_DENSITY_3D,
            TreeSpec::default_blood().power_density,
        ),
        // Every two-dimensional phantom draws unit-variance amplitudes at 300 per mm².
        None => (0.0, TissueSpec::DEFAULT_DENSITY_2D, 3e8),
    };
    let dura = Layer {
        top,
        thickness: 0.1e-3,
        echogenicity_db: db + 10.0,
    };
    let (layers, anechoic) = match tree {
        None => (vec![dura], Vec::new()),
        // Below the cortex, a coronal section crosses the white matter (the corpus callosum,
        // brighter) and the lateral ventricles (fluid: no echo).
        Some(_) => {
            let below = brain_cortex(0).surface_depth + brain_cortex(0).thickness;
            let callosum = Layer {
                top: below + 0.1e-3,
                thickness: 0.2e-3,
                echogenicity_db: db + 5.0,
            };
            let ventricle = |x: f64| Anechoic {
                centre: [x, below + 0.6e-3],
                radii: [0.7e-3, 0.15e-3],
            };
            (
                vec![dura, callosum],
                vec![ventricle(-1.6e-3), ventricle(1.6e-3)],
            )
        }
    };
    let spec = TissueSpec {
        x_range: (x0 - 1e-3, x1 + 1e-3),
        z_range: (top, depth),
        half_thickness,
        density,
        echogenicity_db: db,
        blood_power_density,
        layers,
        anechoic,
        motion,
    };
    // A stream of its own: drawn from the vessels' seed itself, the tissue's positions would
    // repeat theirs.
    let seed = args.seed ^ 0x7155_0e5e_ed00_0000;
    let drawn = match tree {
        // No tissue inside the vessels at t = 0 (they move with the tissue from there).
        None => TissuePhantom::new(spec, seed, |x, _, z| {
            phantom.truth(&[x], &[z], 0.0).mask[[0, 0]]
        }),
        Some(tree) => {
            let segments = &tree.flow().segments;
            let boxes: Vec<([f64; 3], [f64; 3])> = segments.iter().map(|s| s.bounds()).collect();
            TissuePhantom::new(spec, seed, |x, y, z| {
                let p = [x, y, z];
                boxes.iter().zip(segments).any(|((lo, hi), s)| {
                    (0..3).all(|k| p[k] >= lo[k] && p[k] <= hi[k]) && s.local(&p).is_some()
                })
            })
        }
    };
    drawn.context("--tissue-db")
}

/// The `tube` preset's vessel with the `--tube-*` options applied, peak speed `peak` (m/s).
fn tube_spec(args: &SimulationSettings, peak: f64) -> Result<TubeSpec> {
    let preset = TubeSpec::preset(peak);
    let centre = match &args.tube_centre_mm {
        None => preset.centre,
        Some(text) => match parse_numbers(text).as_deref() {
            Ok(&[x, z]) => [x * 1e-3, z * 1e-3],
            _ => bail!("--tube-centre-mm {text:?}: expected two finite numbers \"x,z\" in mm"),
        },
    };
    let positive_mm = |flag: &str, value: Option<f64>, default: f64| match value {
        None => Ok(default),
        Some(v) if v.is_finite() && v > 0.0 => Ok(v * 1e-3),
        Some(v) => bail!("{flag} {v}: must be a finite length > 0 mm"),
    };
    let angle = match args.tube_angle_deg {
        None => preset.angle,
        Some(deg) if deg.is_finite() => deg.to_radians(),
        Some(deg) => bail!("--tube-angle-deg {deg}: must be a finite number of degrees"),
    };
    Ok(TubeSpec {
        centre,
        angle,
        length: positive_mm("--tube-length-mm", args.tube_length_mm, preset.length)?,
        radius: positive_mm("--tube-radius-mm", args.tube_radius_mm, preset.radius)?,
        profile: args.tube_profile.map_or(preset.profile, Into::into),
        ..preset
    })
}

/// The simulation settings of one transmit mode (Hadamard-coded when `coded`), checked.
fn mode_params(args: &SimulationSettings, coded: bool, noise_db: Option<f64>) -> Result<SimParams> {
    let mut params: SimParams = match args.preset {
        Preset::RatNetwork | Preset::RatBrain => simulate::rat_params(true)?,
        _ => simulate::paper_spiral_params(true)?,
    };
    if args.preset == Preset::RatBrain {
        params.elevation = Some(ElevationAperture::l22_14vx());
    }
    params.sequence = Sequence {
        angles: Sequence::evenly_spaced_angles(args.angles, 15f64.to_radians()),
        coding: if coded {
            Coding::Hadamard {
                slot_delay: args.slot_delay_us * 1e-6,
            }
        } else {
            Coding::Conventional
        },
        ..params.sequence
    };
    params
        .sequence
        .validate()
        .context("--angles / --slot-delay-us")?;
    params.seed = args.seed;
    params.noise = noise_db.map(NoiseSpec::new);
    params.validate().context("--slot-delay-us")?;
    Ok(params)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::settings::testing;

    #[cfg(feature = "clap")]
    #[test]
    fn the_command_line_defaults_are_the_settings_defaults() {
        testing::command_line_defaults_are_default::<SimulationSettings>();
    }

    #[test]
    fn settings_read_back_as_they_were_written() {
        testing::reads_back_and_refuses_unknown_keys(&SimulationSettings::default());
    }

    #[test]
    fn every_preset_gives_the_samples_it_gave_before_tissue_and_elevation() {
        // SHA-256 of the little-endian f32 samples of two frames of each preset, conventional
        // then coded, as pcuvd simulated them before the third dimension, tissue and keyframes
        // existed (commit ead5e0c): the presets keep their two-dimensional model bit for bit.
        // (The simulator is bit-identical whatever the thread count; these values assume an
        // x86-64 CPU with AVX2 and FMA, as every machine that runs the tests has.)
        use sha2::Digest;
        let expected = [
            (
                Preset::PaperSpiral,
                "1617f8ca0016cebff6dc6cb8a185f383aed0bd31d4832429fb384a5ed444c9ec",
                "fbec0abde3eea959763e64a6c7db8139269bf78584db2ad4488107b04567bc0d",
            ),
            (
                Preset::Tube,
                "2bed9f91a1a88cc328cf0998cc6be424f1dba683aad3f86b98c2db4b71715413",
                "74a51a45d5f11d89b5bb6d43aaad4a77889fe7905fa60223dc64c088327fdfc4",
            ),
            (
                Preset::RatNetwork,
                "8d83212b875d232e80f659e2dbfeb8aee00320ec419eb98ceac25a44221cd913",
                "6b1fce39e40c497aa5a66ec2ca962f1c5ed9dd69303bbc18171dbf22ec17a925",
            ),
        ];
        for (preset, conventional, coded) in expected {
            let simulation = Simulation::new(&SimulationSettings {
                preset,
                frames: Some(2),
                ..SimulationSettings::default()
            })
            .unwrap();
            for (index, expected) in [conventional, coded].into_iter().enumerate() {
                let data = simulation.recording(index, &|_, _| {}).unwrap();
                let pcuvd::Samples::Rf(rf) = &data.samples else {
                    panic!("the simulator writes RF");
                };
                let mut hasher = sha2::Sha256::new();
                for v in rf.iter() {
                    hasher.update(v.to_le_bytes());
                }
                let digest: String = hasher
                    .finalize()
                    .iter()
                    .map(|b| format!("{b:02x}"))
                    .collect();
                assert_eq!(
                    digest, expected,
                    "{preset:?}, {}",
                    simulation.modes[index].0
                );
            }
        }
    }
}
