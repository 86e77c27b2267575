//! The command's options over a scenario, and a scenario file simulated.

use super::*;
use crate::scenario::NoiseSection;
use crate::scenario::tests::SMALL;

#[test]
fn the_options_override_the_scenario() {
    let settings = |edit: fn(&mut SimulationSettings)| {
        let mut s = SimulationSettings {
            preset: Some(crate::simulation::Preset::RatBrain),
            ..SimulationSettings::default()
        };
        edit(&mut s);
        s.scenario()
    };
    // --tissue-db moves the parenchyma and keeps the layers' contrast to it.
    let brighter = settings(|s| s.tissue_db = Some(55.0)).unwrap();
    let tissue = brighter.tissue.unwrap();
    assert_eq!(tissue.echogenicity_db, 55.0);
    let layers: Vec<f64> = tissue.layers.iter().map(|l| l.echogenicity_db).collect();
    assert_eq!(layers, [65.0, 60.0]);
    let still = settings(|s| s.tissue_motion = Some(TissueMotionChoice::Still)).unwrap();
    assert!(
        still
            .tissue
            .unwrap()
            .motion
            .motion()
            .oscillations
            .is_empty()
    );
    let error = settings(|s| s.tube_radius_mm = Some(1.0))
        .unwrap_err()
        .to_string();
    assert!(error.contains("--tube-radius-mm"), "{error}");
    let error = settings(|s| s.scenario = Some("tube".into()))
        .unwrap_err()
        .to_string();
    assert!(error.contains("not both"), "{error}");
    // --angles replaces the scenario's angles whichever way they were given.
    let listed = Scenario::parse(&SMALL.replace("angles = 2", "angles_deg = [-5.0, 5.0]")).unwrap();
    let mut scenario = listed.clone();
    SimulationSettings {
        angles: Some(4),
        ..SimulationSettings::default()
    }
    .apply_to(&mut scenario)
    .unwrap();
    assert_eq!(
        (scenario.sequence.angles, scenario.sequence.angles_deg),
        (Some(4), None)
    );
}

#[test]
fn a_scenario_file_simulates_what_it_wrote_and_names_its_tables_from_its_folder() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("small.toml");
    std::fs::write(&path, SMALL).unwrap();
    let samples = |source: &str| {
        let simulation = Simulation::new(&SimulationSettings {
            scenario: Some(source.into()),
            ..SimulationSettings::default()
        })
        .unwrap();
        let data = simulation.recording(0, &|_, _| {}).unwrap();
        (simulation.scenario, data.samples)
    };
    let (scenario, first) = samples(path.to_str().unwrap());
    // The scenario a simulation reports, written and read back, simulates the same samples.
    let again = dir.path().join("again.toml");
    std::fs::write(&again, scenario.to_toml().unwrap()).unwrap();
    let (_, second) = samples(again.to_str().unwrap());
    assert!(
        first == second,
        "the written scenario simulates other samples"
    );
    let tree = "[vessels]\nkind = \"tree\"\ntables = \"vessels\"\n";
    let with_tree = SMALL.replace("[vessels]\nkind = \"tube\"\n", tree).replace(
        "preset = \"L22-14vX\"",
        "preset = \"L22-14vX\"\nelement_height_m = 1.5e-3\nelevation_focus_m = 8e-3",
    );
    let sub = dir.path().join("sub");
    std::fs::create_dir(&sub).unwrap();
    std::fs::write(sub.join("tree.toml"), with_tree).unwrap();
    let read = Scenario::read(&sub.join("tree.toml")).unwrap();
    let Vessels::Tree(tree) = &read.vessels else {
        panic!("a tree")
    };
    assert_eq!(
        std::path::Path::new(tree.tables.as_deref().unwrap()),
        sub.join("vessels")
    );
}

#[test]
fn a_tighter_waveform_truncation_adds_only_the_tails_below_the_default_level() {
    // The same tube at the default truncation (−70.5 dB) and at −110 dB: the tighter one holds
    // a longer echo (a wider receive window) whose extra tails are what the default neglects,
    // each scatterer's below 3·10⁻⁴ of its peak, so the recordings differ by less than that.
    let simulate = |level: Option<f64>| {
        let mut scenario = Scenario::parse(SMALL).unwrap();
        scenario.receive.waveform_truncation_db = level;
        let simulation = Simulation::of(scenario, "small".into()).unwrap();
        let params = simulation.modes[0].1.clone();
        let data = simulation.recording(0, &|_, _| {}).unwrap();
        let pcuvd::Samples::Rf(rf) = data.samples else {
            panic!("the simulator writes RF")
        };
        (params, rf)
    };
    let (default, a) = simulate(None);
    let (tight, b) = simulate(Some(-110.0));
    assert!(tight.n_samples > default.n_samples);
    let shift = ((default.t0 - tight.t0) * default.sampling_frequency).round() as usize;
    let n = default.n_samples;
    assert!(shift + n <= tight.n_samples);
    let aligned = b.slice(ndarray::s![.., .., shift..shift + n]);
    let power = |v: f32| f64::from(v) * f64::from(v);
    let signal: f64 = a.iter().map(|&v| power(v)).sum();
    let difference: f64 = a
        .iter()
        .zip(aligned.iter())
        .map(|(&x, &y)| power(x - y))
        .sum();
    let relative = (difference / signal).sqrt();
    assert!(relative > 0.0 && relative < 3e-4, "{relative:e}");
}

#[test]
fn the_tissues_echo_and_the_noise_re_the_whole_echo_are_measured() {
    // A tube in a sheet of tissue 35 dB brighter per unit area. Within the receive window's 5-11
    // mm the sheet spans 14.8 × 6 mm, the tube (1 mm wide at 30° to x) 12 mm of its length: the
    // tissue has some 7.4 times the blood's area, so its echo stands about 35 + 8.7 dB above
    // the blood's (attenuation and the window's edges weigh depths apart).
    let mut scenario = Scenario::parse(SMALL).unwrap();
    scenario.noise = Some(NoiseSection { level_db: -10.0 });
    SimulationSettings {
        tissue_db: Some(35.0),
        tissue_motion: Some(TissueMotionChoice::Still),
        ..SimulationSettings::default()
    }
    .apply_to(&mut scenario)
    .unwrap();
    let simulation = Simulation::of(scenario, "small".into()).unwrap();
    let levels = simulation.echo_levels().unwrap().unwrap();
    let ratio = levels.tissue_over_blood_db;
    assert!((41.5..46.0).contains(&ratio), "{ratio}");
    // Speckle and blood are independent: their powers add, so the whole echo is the blood's
    // times 1 + 10^(ratio/10), and the noise stands that much lower against it.
    let expected = -10.0 - 10.0 * (1.0 + 10f64.powf(ratio / 10.0)).log10();
    let whole = levels.noise_db_re_whole_echo.unwrap();
    assert!((whole - expected).abs() < 0.5, "{whole} against {expected}");
    let provenance = simulation.provenance(0, Some(levels));
    assert_eq!(
        provenance["tissue"]["echo_over_blood_db"].as_float(),
        Some(ratio)
    );
    assert_eq!(provenance["noise_db_re_whole_echo"].as_float(), Some(whole));
    assert_eq!(
        Simulation::of(Scenario::parse(SMALL).unwrap(), "small".into())
            .unwrap()
            .echo_levels()
            .unwrap(),
        None
    );
}

#[test]
fn a_sampled_transmit_pulse_is_simulated_and_recorded() {
    // The 2-cycle Hann burst at 15.625 MHz, sampled at 250 MHz: the same echo as `pulse_cycles =
    // 2` (the waveform's own tests compare the two), now from the scenario's samples.
    let (fc, fs) = (15.625e6, 250e6);
    let n = (2.0 / fc * fs) as usize;
    let samples: Vec<String> = (0..n)
        .map(|i| {
            let t = (i as f64 + 0.5) / fs - 1.0 / fc;
            let hann = 0.5 * (1.0 + (std::f64::consts::PI * t * fc).cos());
            format!("{:.6}", hann * (2.0 * std::f64::consts::PI * fc * t).cos())
        })
        .collect();
    let text = SMALL.replace(
        "pulse_cycles = 2.0\n",
        &format!(
            "[sequence.pulse]\nsampling_frequency_hz = {fs:e}\nsamples = [{}]\n",
            samples.join(", ")
        ),
    );
    // The pulse's table follows the rest of [sequence]: move the keys after it back above it.
    let text = text
        .replace("frames = 1\n", "")
        .replace("[sequence.pulse]", "frames = 1\n[sequence.pulse]");
    let scenario = Scenario::parse(&text).unwrap();
    assert!((scenario.pulse_cycles().unwrap() - n as f64 / fs * fc).abs() < 1e-12);
    let simulation = Simulation::of(scenario.clone(), "small".into()).unwrap();
    let data = simulation.recording(0, &|_, _| {}).unwrap();
    assert_eq!(
        data.acquisition.sequence.pulse,
        scenario.transmit_pulse(),
        "the recording says which pulse it was simulated with"
    );
    let pcuvd::Samples::Rf(rf) = &data.samples else {
        panic!("the simulator writes RF")
    };
    assert!(rf.iter().any(|&v| v != 0.0));
    let empty = text.replace(
        &format!("samples = [{}]", samples.join(", ")),
        "samples = []",
    );
    let error = crate::one_line(&Scenario::parse(&empty).unwrap_err());
    assert!(error.contains("[sequence.pulse].samples"), "{error}");
}

#[test]
fn pulsatile_phantoms_give_their_heartbeats_as_an_ecg_would() {
    // The rat network beats at 5.5 Hz: 360 frames at 1.8 kHz (0.2 s) hold two beats, the first
    // at the first frame. Set up only: nothing is simulated.
    let network = Simulation::of(
        Scenario::shipped("rat-network").unwrap(),
        "rat-network".into(),
    )
    .unwrap();
    assert_eq!(network.cardiac_triggers(), Some(vec![0.0, 1.0 / 5.5]));
    // The tree beats at its flow's heart rate, the rat's; steady flow has no beats, and a
    // recording shorter than one cycle too few to say one.
    let mut brain = Scenario::shipped("rat-brain").unwrap();
    brain.tissue = None;
    let tree = Simulation::of(brain.clone(), "rat-brain".into()).unwrap();
    let beats = tree.cardiac_triggers().unwrap();
    assert_eq!(beats.len(), 2);
    assert!((beats[1] - 1.0 / 5.5).abs() < 1e-12, "{beats:?}");
    brain.sequence.frames = 100;
    assert_eq!(
        Simulation::of(brain, "rat-brain".into())
            .unwrap()
            .cardiac_triggers(),
        None
    );
    let tube = Simulation::of(Scenario::parse(SMALL).unwrap(), "small".into()).unwrap();
    assert_eq!(tube.cardiac_triggers(), None);
}

/// Blocks handed to the writer thread one after another, in order, make the recording simulated
/// whole; a writer's error ends the simulation and is the one reported.
#[test]
fn blocks_written_beside_the_simulation_make_the_whole_recording() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nine.toml");
    std::fs::write(&path, SMALL.replace("frames = 1", "frames = 9")).unwrap();
    let simulation = Simulation::new(&SimulationSettings {
        scenario: Some(path.to_str().unwrap().into()),
        ..SimulationSettings::default()
    })
    .unwrap();
    let whole = simulation.recording(0, &|_, _| {}).unwrap();
    let pcuvd::Samples::Rf(whole) = whole.samples else {
        panic!("RF samples")
    };
    let mut blocks = Vec::new();
    simulation
        .in_blocks(
            |index, events, samples| {
                blocks.push((index, events, samples.to_owned()));
                Ok(())
            },
            &|_, _| {},
        )
        .unwrap();
    // Nine frames in blocks of three (a quarter, rounded up), each in order.
    let ranges: Vec<_> = blocks.iter().map(|(_, events, _)| events.clone()).collect();
    assert_eq!(ranges, [0..6, 6..12, 12..18]);
    let views: Vec<_> = blocks
        .iter()
        .map(|(_, _, samples)| samples.view())
        .collect();
    assert!(ndarray::concatenate(ndarray::Axis(0), &views).unwrap() == whole);

    let mut written = 0;
    let error = simulation
        .in_blocks(
            |_, _, _| {
                written += 1;
                if written == 2 {
                    anyhow::bail!("disk full")
                }
                Ok(())
            },
            &|_, _| {},
        )
        .unwrap_err();
    assert_eq!(error.to_string(), "disk full");
    assert_eq!(written, 2);
}
