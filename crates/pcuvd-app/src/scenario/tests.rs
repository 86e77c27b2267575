use super::*;

/// The shipped rat brain with `edit` applied to its text.
fn brain_with(edit: impl Fn(&str) -> String) -> Result<Scenario> {
    let (_, text) = SHIPPED.iter().find(|(n, _)| *n == "rat-brain").unwrap();
    Scenario::parse(&edit(text))
}

/// The error `text` gives, on one line with its causes.
fn refusal(text: &str) -> String {
    crate::one_line(&Scenario::parse(text).unwrap_err())
}

/// A small scenario: a tube, two angles, one frame, conventional, no noise.
pub(crate) const SMALL: &str = r#"
[probe]
preset = "L22-14vX"
[sequence]
transmit = "conventional"
angles = 2
event_prf_hz = 1e4
slot_delay_s = 1e-6
pulse_cycles = 2.0
frames = 1
[receive]
sampling_frequency_hz = 65e6
depth_m = [5e-3, 11e-3]
[vessels]
kind = "tube"
"#;

#[test]
fn every_shipped_scenario_reads_back_from_the_toml_it_writes() {
    for (name, _) in SHIPPED {
        let scenario = Scenario::shipped(name).unwrap();
        let text = scenario.to_toml().unwrap();
        assert_eq!(Scenario::parse(&text).unwrap(), scenario, "{name}:\n{text}");
    }
}

#[test]
fn a_section_left_out_takes_its_documented_defaults() {
    let scenario = Scenario::parse(SMALL).unwrap();
    assert_eq!(scenario.seed, 1);
    assert_eq!(scenario.medium, MediumSection::default());
    assert_eq!(scenario.vessels, Vessels::Tube(TubeSection::default()));
    assert!(scenario.noise.is_none() && scenario.tissue.is_none());
    // The evenly spaced angles span ±15° unless told otherwise.
    let angles = scenario.angles();
    assert_eq!(angles.len(), 2);
    assert!((angles[1] - 15f64.to_radians()).abs() < 1e-15);
}

#[test]
fn the_rat_brains_written_motion_is_the_rat_motion() {
    // The shipped file spells the rat's heartbeat and breathing out key by key; they must be
    // the motion `TissueMotion::rat()` defines, to the bit.
    let brain = Scenario::shipped("rat-brain").unwrap();
    let motion = brain.tissue.unwrap().motion.motion();
    assert_eq!(motion, pcuvd::simulate::phantom::TissueMotion::rat());
}

#[test]
fn unknown_keys_are_refused_by_name_in_every_section() {
    let cases = [
        ("seed = 1\n", "seeds = 1\n", "seeds"),
        (
            "preset = \"L22-14vX\"\n",
            "preset = \"L22-14vX\"\ncolour = 1\n",
            "colour",
        ),
        ("frames = 360\n", "frames = 360\nrepeats = 2\n", "repeats"),
        (
            "kind = \"tree\"",
            "kind = \"tree\"\nbranches = 4",
            "branches",
        ),
        (
            "top_m = 0.9e-3\n",
            "top_m = 0.9e-3\nbottom_m = 1e-3\n",
            "bottom_m",
        ),
        (
            "phase_rad = 0.5\n",
            "phase_rad = 0.5\nphase_deg = 30\n",
            "phase_deg",
        ),
    ];
    for (from, to, key) in cases {
        let error = crate::one_line(&brain_with(|t| t.replacen(from, to, 1)).unwrap_err());
        assert!(error.contains(key), "{key}: {error}");
    }
    let error = crate::one_line(&brain_with(|t| t.replace("\"tree\"", "\"forest\"")).unwrap_err());
    assert!(error.contains("forest"), "{error}");
}

#[test]
fn out_of_range_values_are_refused_by_their_key() {
    let cases = [
        (
            "preset = \"L22-14vX\"\n",
            "preset = \"L22-14vX\"\npitch_m = -1e-4\n",
            "[probe].pitch_m",
        ),
        (
            "preset = \"L22-14vX\"\n",
            "preset = \"L99\"\n",
            "[probe].preset",
        ),
        ("frames = 360", "frames = 0", "[sequence].frames"),
        (
            "event_prf_hz = 14.4e3",
            "event_prf_hz = -1.0",
            "[sequence].event_prf_hz",
        ),
        (
            "depth_m = [0.0, 13e-3]",
            "depth_m = [13e-3, 1e-3]",
            "[receive].depth_m",
        ),
        ("level_db = 0.0", "level_db = nan", "[noise].level_db"),
        (
            "max_angle_deg = 15.0",
            "max_angle_deg = 95.0",
            "[sequence].max_angle_deg",
        ),
        (
            "capillary_segments = 2",
            "capillary_segments = 0",
            "[vessels].capillary_segments",
        ),
        (
            "thickness_m = 0.1e-3",
            "thickness_m = 0.0",
            "[[tissue.layers]].thickness_m",
        ),
        ("frequency_hz = 5.5", "frequency_hz = -5.5", "frequency_hz"),
        (
            "radii_m = [0.7e-3, 0.15e-3]",
            "radii_m = [0.7e-3, 0.0]",
            "[[tissue.anechoic]].radii_m",
        ),
        (
            "sound_speed_m_s = 1540.0",
            "sound_speed_m_s = 0.0",
            "[medium].sound_speed_m_s",
        ),
        // Echoes `process` could not hold in single precision.
        (
            "echogenicity_db = 40.0",
            "echogenicity_db = 300.0",
            "[tissue].echogenicity_db = 300: must be a finite number of dB, at most 150 above",
        ),
        (
            "echogenicity_db = 50.0",
            "echogenicity_db = 151.0",
            "[[tissue.layers]].echogenicity_db = 151",
        ),
        // Vessels wholly below the record (which ends 13 mm deep), more than 1 mm.
        (
            "surface_depth_m = 1e-3",
            "surface_depth_m = 14e-3",
            "[vessels].surface_depth_m = 0.014: the cortex would start more than 1 mm below",
        ),
        (
            "deep_depth_m = 9e-3",
            "deep_depth_m = 9e9",
            "[vessels].deep_depth_m = 9000000000: the deep vessels would lie more than 1 mm",
        ),
        (
            "deep_depth_m = 9e-3",
            "deep_depth_m = 18e-3",
            "[vessels].deep_depth_m = 0.018: the deep vessels would lie more than 1 mm",
        ),
        // The record starting more than 1 mm below the deep vessels (9 mm).
        (
            "depth_m = [0.0, 13e-3]",
            "depth_m = [10e-3, 13e-3]",
            "[receive].depth_m = [0.01, 0.013]: the record would start more than 1 mm below the \
             vessel tree, which ends 0.009 m deep",
        ),
    ];
    for (from, to, key) in cases {
        let edited = brain_with(|t| {
            assert!(t.contains(from), "{from}");
            t.replacen(from, to, 1)
        });
        let error = crate::one_line(&edited.unwrap_err());
        assert!(error.contains(key), "{key}: {error}");
    }
}

/// Vessels within 1 mm of the record (their axes; their lumens may reach in) are simulated.
#[test]
fn vessels_within_a_millimetre_of_the_record_are_kept() {
    // (A cortex that deep leaves no room for the deep pairs below it.)
    let cases: [&[(&str, &str)]; 3] = [
        &[("deep_depth_m = 9e-3", "deep_depth_m = 17.9e-3")],
        &[
            ("surface_depth_m = 1e-3", "surface_depth_m = 13.9e-3"),
            ("deep_pairs = 4", "deep_pairs = 0"),
        ],
        &[("depth_m = [0.0, 13e-3]", "depth_m = [9.9e-3, 13e-3]")],
    ];
    for edits in cases {
        let scenario = brain_with(|t| {
            edits
                .iter()
                .fold(t.to_string(), |t, (from, to)| t.replacen(from, to, 1))
        });
        assert!(scenario.is_ok(), "{edits:?}: {:?}", scenario.err());
    }
}

#[test]
fn blood_at_a_tenth_of_the_sound_speed_or_faster_is_refused() {
    // A stenotic jet (6 m/s) is blood; 154 m/s is a unit slip, or a flow the stop-and-go model
    // cannot hold.
    let tube = |speed: &str| format!("{SMALL}peak_velocity_m_s = {speed}\n");
    assert!(Scenario::parse(&tube("6.0")).is_ok());
    let error = refusal(&tube("154.0"));
    assert!(
        error.contains("[vessels].peak_velocity_m_s = 154")
            && error.contains("below a tenth of the sound speed (154 m/s)"),
        "{error}"
    );
}

/// Steering angles past 1,024 a frame, and frames past 2⁴⁰ transmit events, are refused by key
/// (2⁶³ angles panicked building their list, and 2⁶³ frames wrapped the sizes the disk check
/// computes to nothing, which it let through); the bounds themselves pass.
#[test]
fn angles_and_events_past_what_a_recording_holds_are_refused_by_key() {
    let with = |angles: &str, frames: u64| {
        SMALL
            .replacen("angles = 2", &format!("angles = {angles}"), 1)
            .replacen("frames = 1", &format!("frames = {frames}"), 1)
    };
    Scenario::parse(&with("1024", 1)).unwrap();
    for angles in ["1025", "9223372036854775808"] {
        let error = refusal(&with(angles, 1));
        assert!(
            error.starts_with(&format!("[sequence].angles = {angles}: at most 1024")),
            "{error}"
        );
    }
    Scenario::parse(&with("2", 1 << 39)).unwrap();
    let error = refusal(&with("2", (1 << 39) + 1));
    assert!(
        error.starts_with("[sequence].frames = 549755813889: 1099511627778 transmit events"),
        "{error}"
    );
    let error = refusal(&with("2", 1 << 63));
    assert!(
        error.starts_with("[sequence].frames = 9223372036854775808"),
        "{error}"
    );
}

#[test]
fn tissue_faster_than_a_metre_a_second_is_refused() {
    // The brain's breathing, its depth gradient raised until the tissue farthest from the
    // reference depth (of the tissue's and the record's depths) moves at 1 m/s with every
    // oscillation at its peak at once: the bound, worked out here from the scenario's numbers.
    let brain = brain_with(str::to_string).unwrap();
    let tissue = brain.tissue.as_ref().unwrap();
    let reference = tissue.motion.reference_depth_m.unwrap();
    let farthest = [tissue.depth_m, brain.receive.depth_m]
        .iter()
        .flatten()
        .map(|z| (z - reference).abs())
        .fold(0.0, f64::max);
    let peak_speed = |o: &OscillationSection, gradient: f64| {
        let amplitude = o.amplitude_m.iter().map(|a| a * a).sum::<f64>().sqrt();
        2.0 * std::f64::consts::PI * o.frequency_hz * amplitude * (1.0 + gradient * farthest)
    };
    let [heart, breath] = &tissue.motion.oscillations[..] else {
        panic!("the brain's motion is a heartbeat and breathing");
    };
    assert_eq!(heart.depth_gradient_per_m, 0.0);
    let gradient = ((1.0 - peak_speed(heart, 0.0)) / peak_speed(breath, 0.0) - 1.0) / farthest;
    let with = |g: f64| {
        brain_with(|text| {
            text.replacen(
                "depth_gradient_per_m = 100.0",
                &format!("depth_gradient_per_m = {g:e}"),
                1,
            )
        })
    };
    with(0.99 * gradient).unwrap();
    let error = crate::one_line(&with(1.01 * gradient).unwrap_err());
    assert!(
        error.contains("[[tissue.motion.oscillations]]") && error.contains("at most 1 m/s"),
        "{error}"
    );
}

#[test]
fn what_goes_together_is_refused_apart() {
    // A tree or a slab of tissue lies in three dimensions: without the elevation it cannot.
    let flat = |t: &str| t.replace("element_height_m = 1.5e-3", "");
    let error = crate::one_line(&brain_with(flat).unwrap_err());
    assert!(error.contains("elevation_focus_m"), "{error}");
    let no_elevation = |t: &str| {
        t.replace("element_height_m = 1.5e-3", "")
            .replace("elevation_focus_m = 8e-3", "")
    };
    let error = crate::one_line(&brain_with(no_elevation).unwrap_err());
    assert!(error.contains("three dimensions"), "{error}");
    let both_angles = SMALL.replace("angles = 2", "angles = 2\nangles_deg = [0.0]");
    assert!(refusal(&both_angles).contains("angles_deg"));
    let sheet_density = SMALL.to_string()
        + "[tissue]\nechogenicity_db = 40.0\ndepth_m = [1e-3, 9e-3]\ndensity_per_m3 = 1e12\n";
    assert!(refusal(&sheet_density).contains("density_per_m3"));
    let missing = SMALL.replace("preset = \"L22-14vX\"", "n_elements = 16");
    assert!(refusal(&missing).contains("[probe].pitch_m is missing"));
}

#[test]
fn an_unknown_scenario_name_lists_the_shipped_ones() {
    let error = Scenario::load("rat-heart").unwrap_err().to_string();
    assert!(
        error.contains("rat-brain") && error.contains("paper-spiral"),
        "{error}"
    );
}
