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

mod sections;
pub use sections::*;

/// How far outside the record (m) a generated vessel tree's axes may lie before the scenario is
/// refused: its largest vessels (the pial and basal ones) are a few hundred µm across, so a tree
/// this far outside has no lumen in the record.
const OUTSIDE_MARGIN_M: f64 = 1e-3;

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

/// The most a scenario's tissue may echo above the blood, in dB of echo power: in
/// vivo 30–60 dB, a bone or a specular wall some 80. Beyond about 250 dB the samples of the
/// tube preset's tissue outgrow the 3·10¹⁴ that processing holds in single precision, so that
/// `pcuvd simulate` would write a recording `pcuvd process` refuses; 150 leaves a wide margin
/// for denser and thicker tissue. Quieter tissue has no floor: −200 dB is a way to leave it out.
pub const MAX_ECHOGENICITY_DB: f64 = 150.0;

/// Checks a tissue echo power re the blood's (dB): finite and at most [`MAX_ECHOGENICITY_DB`].
fn echogenicity(key: &str, v: f64) -> Result<()> {
    if v.is_finite() && v <= MAX_ECHOGENICITY_DB {
        Ok(())
    } else {
        Err(refuse(
            key,
            v,
            &format!(
                "must be a finite number of dB, at most {MAX_ECHOGENICITY_DB} above the blood's echo (in \
                 vivo tissue echoes 30–60 dB above it)"
            ),
        ))
    }
}

/// The fastest a scenario's tissue may move (m/s), every oscillation at its peak at once.
const MAX_TISSUE_SPEED_M_S: f64 = 1.0;

/// The most steering angles a compound frame may have: compounding uses tens.
const MAX_ANGLES: usize = 1024;

/// The most transmit events (frames × angles) a scenario may record, some 10¹⁸ bytes of
/// samples (which the disk and memory checks refuse in turn, saying what they would need): more
/// would overflow the event counts and sizes the simulator computes.
const MAX_EVENTS: u128 = 1 << 40;

/// Checks that a blood speed (m/s) is positive and far below the sound speed `c` (m/s): the
/// simulator holds the scatterers still during each event (stop-and-go), which a flow at a
/// tenth of c already strains; a faster one is a unit slip, not blood.
fn blood_speed(key: &str, v: f64, c: f64) -> Result<()> {
    positive(key, v)?;
    if v < c / 10.0 {
        Ok(())
    } else {
        Err(refuse(
            key,
            v,
            &format!(
                "must be below a tenth of the sound speed ({} m/s): the simulator holds the \
                 scatterers still during each event",
                c / 10.0
            ),
        ))
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
            (Some(n), None) if n > MAX_ANGLES => {
                return Err(refuse(
                    "[sequence].angles",
                    n,
                    &format!("at most {MAX_ANGLES} steering angles a frame"),
                ));
            }
            (None, Some(list)) => {
                if list.is_empty() {
                    bail!("[sequence].angles_deg is empty");
                }
                if list.len() > MAX_ANGLES {
                    return Err(refuse(
                        "[sequence].angles_deg",
                        format!("[{} angles]", list.len()),
                        &format!("at most {MAX_ANGLES} steering angles a frame"),
                    ));
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
        let angles = s
            .angles_deg
            .as_ref()
            .map_or(s.angles.unwrap_or(1), Vec::len);
        let events = s.frames as u128 * angles as u128;
        if events > MAX_EVENTS {
            return Err(refuse(
                "[sequence].frames",
                s.frames,
                &format!(
                    "{events} transmit events at {angles} angles a frame, more than the \
                     {MAX_EVENTS} a recording may hold"
                ),
            ));
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
        let c = self.medium.sound_speed_m_s;
        match &self.vessels {
            Vessels::Spiral(v) => {
                finite("[vessels].centre_m", v.centre_m[0])?;
                finite("[vessels].centre_m", v.centre_m[1])?;
                positive("[vessels].start_radius_m", v.start_radius_m)?;
                positive("[vessels].turn_spacing_m_per_rad", v.turn_spacing_m_per_rad)?;
                positive("[vessels].turns", v.turns)?;
                positive("[vessels].radius_m", v.radius_m)?;
                blood_speed("[vessels].peak_velocity_m_s", v.peak_velocity_m_s, c)?;
                positive("[vessels].density_per_m2", v.density_per_m2)?;
            }
            Vessels::Tube(v) => {
                finite("[vessels].centre_m", v.centre_m[0])?;
                finite("[vessels].centre_m", v.centre_m[1])?;
                finite("[vessels].angle_deg", v.angle_deg)?;
                positive("[vessels].length_m", v.length_m)?;
                positive("[vessels].radius_m", v.radius_m)?;
                blood_speed("[vessels].peak_velocity_m_s", v.peak_velocity_m_s, c)?;
                positive("[vessels].density_per_m2", v.density_per_m2)?;
            }
            Vessels::RatNetwork(v) => {
                if let Some(psv) = v.fastest_psv_m_s {
                    blood_speed("[vessels].fastest_psv_m_s", psv, c)?;
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
                    // Vessels wholly outside the record would simulate a recording with no blood
                    // in it: a unit slip (millimetres written as metres) more likely than a wish.
                    // Depths here are the vessels' axes: a margin far wider than any lumen.
                    let record_end = self.receive.depth_m[1];
                    let cortex_floor = v.surface_depth_m + v.cortex_thickness_m;
                    if v.surface_depth_m >= record_end + OUTSIDE_MARGIN_M {
                        return Err(refuse(
                            "[vessels].surface_depth_m",
                            v.surface_depth_m,
                            &format!(
                                "the cortex would start more than 1 mm below the record, which \
                                 ends {record_end} m deep ([receive].depth_m)"
                            ),
                        ));
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
                        if v.deep_depth_m - v.deep_reach_m >= record_end + OUTSIDE_MARGIN_M {
                            return Err(refuse(
                                "[vessels].deep_depth_m",
                                v.deep_depth_m,
                                &format!(
                                    "the deep vessels would lie more than 1 mm below the \
                                     record, which ends {record_end} m deep ([receive].depth_m), \
                                     even where a trunk rises the whole deep_reach_m"
                                ),
                            ));
                        }
                    }
                    // And wholly above it, where a record starts deeper than the tree reaches.
                    let deepest = if v.deep_pairs > 0 {
                        v.deep_depth_m.max(cortex_floor)
                    } else {
                        cortex_floor
                    };
                    let record_start = self.receive.depth_m[0];
                    if deepest + OUTSIDE_MARGIN_M <= record_start {
                        return Err(refuse(
                            "[receive].depth_m",
                            format!("{:?}", self.receive.depth_m),
                            &format!(
                                "the record would start more than 1 mm below the vessel tree, \
                                 which ends \
                                 {deepest} m deep (surface_depth_m + cortex_thickness_m, or \
                                 deep_depth_m with deep_pairs)"
                            ),
                        ));
                    }
                }
            }
        }
        Ok(())
    }

    fn check_tissue(&self, t: &TissueSection) -> Result<()> {
        echogenicity("[tissue].echogenicity_db", t.echogenicity_db)?;
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
            echogenicity("[[tissue.layers]].echogenicity_db", layer.echogenicity_db)?;
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
        // A speed no tissue reaches is a slip in the numbers (a depth gradient in 1/mm, an
        // amplitude in µm): refused, as the blood's beyond c/10 is (`blood_speed`).
        let depths = (
            t.depth_m[0].min(self.receive.depth_m[0]),
            t.depth_m[1].max(self.receive.depth_m[1]),
        );
        let fastest = motion.motion().max_speed(depths);
        if fastest.is_nan() || fastest > MAX_TISSUE_SPEED_M_S {
            bail!(
                "{key}: the tissue would move at up to {fastest:.3e} m/s between {} and {} m deep \
                 (each amplitude × 2π frequency × (1 + |depth_gradient_per_m| × the distance \
                 from reference_depth_m)); at most {MAX_TISSUE_SPEED_M_S} m/s, faster than any \
                 tissue moves (a beating heart's wall: about 0.1 m/s)",
                depths.0,
                depths.1,
            );
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
