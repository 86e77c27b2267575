//! A simulation written as `pcuvd simulate` writes it: each mode's recording (manifest and
//! samples, a block of frames at a time), the ground truth on the default processing grid, and
//! the scenario simulated, last.

use std::path::Path;

use anyhow::{Context, Result};
use ndarray::Array1;

use super::Simulation;

/// Ground-truth files every preset writes (on the default processing grid).
const TRUTH_FILES: [&str; 5] = [
    "truth_x.npy",
    "truth_z.npy",
    "truth_vx.npy",
    "truth_vz.npy",
    "truth_mask.npy",
];
/// Ground-truth files of the tissue's motion (with tissue): velocity at t = 0 (m/s), and the
/// displacement from t = 0 (m) at each frame, (frames, depths, 3: x, y, z).
const TISSUE_TRUTH_FILES: [&str; 3] = [
    "truth_tissue_vx.npy",
    "truth_tissue_vz.npy",
    "truth_tissue_displacement.npy",
];
/// The scenario simulated, every option applied: `pcuvd simulate --scenario` of this file
/// simulates the same recordings again.
pub const SCENARIO_FILE: &str = "scenario.toml";
/// How [`SCENARIO_FILE`] begins: what tells it from a file of the same name that pcuvd did not
/// write.
pub const SCENARIO_HEADER: &str = "# The scenario `pcuvd simulate` simulated here";
/// Ground-truth files of a phantom in three dimensions: out-of-plane velocity (m/s) and the
/// blood's share of each pixel's elevation beam.
const ELEVATION_TRUTH_FILES: [&str; 2] = ["truth_vy.npy", "truth_blood_fraction.npy"];
/// Ground-truth files only the vessel networks write (their cardiac-cycle truth; the class share
/// says how much of each pixel's blood is of the class named, below 1 where an artery and a vein
/// share a pixel's elevation beam; the axis profile says where in its vessel each pixel's blood
/// lies, 1 on the axis, 0 at the wall).
const NETWORK_TRUTH_FILES: [&str; 7] = [
    "truth_ri.npy",
    "truth_psv.npy",
    "truth_edv.npy",
    "truth_vessel_class.npy",
    "truth_flow_up.npy",
    "truth_class_share.npy",
    "truth_axis_profile.npy",
];

/// The recording of each transmit mode: `NAME.toml` (manifest) and `NAME.npy` (samples).
const RECORDING_NAMES: [&str; 2] = ["coded", "conventional"];

/// Removes the files of `pcuvd simulate`'s own naming in `dir` that this run will not rewrite, so
/// that a folder reused for another preset or mode holds no stale truth or recording beside the new
/// ones (a `truth_ri.npy` of an earlier network run beside a tube would be read as the tube's truth).
/// Files of any other name are left alone.
fn remove_stale_outputs(
    dir: &Path,
    recordings: &[&str],
    network_truth: bool,
    tissue_truth: bool,
    elevation_truth: bool,
    say: &dyn Fn(&str),
) -> Result<()> {
    let stale_recordings = RECORDING_NAMES
        .iter()
        .filter(|name| !recordings.contains(name))
        .flat_map(|name| [format!("{name}.toml"), format!("{name}.npy")]);
    let stale_truth = NETWORK_TRUTH_FILES
        .iter()
        .filter(|_| !network_truth)
        .chain(TISSUE_TRUTH_FILES.iter().filter(|_| !tissue_truth))
        .chain(ELEVATION_TRUTH_FILES.iter().filter(|_| !elevation_truth))
        .map(|name| name.to_string());
    for name in stale_recordings.chain(stale_truth) {
        let path = dir.join(name);
        match std::fs::remove_file(&path) {
            Ok(()) => say(&format!(
                "removed {} (stale: this run does not write it)",
                path.display()
            )),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => {
                return Err(e).with_context(|| {
                    format!("{}: cannot remove this stale output", path.display())
                });
            }
        }
    }
    Ok(())
}

/// Refuses a simulation whose recordings would not fit on the disk that holds `out` (the
/// recordings it replaces there counted as free): a run of a billion frames would otherwise
/// write until the disk is full.
fn check_disk_space(simulation: &Simulation, out: &Path, recordings: &[&str]) -> Result<()> {
    let Some(free) = crate::memory::free_disk_space(out) else {
        return Ok(());
    };
    let replaced: u64 = recordings
        .iter()
        .filter_map(|name| std::fs::metadata(out.join(format!("{name}.npy"))).ok())
        .map(|file| file.len())
        .sum();
    let needed = simulation.samples_bytes();
    if needed > free.saturating_add(replaced) {
        anyhow::bail!(
            "{}: the recordings of {} frames need about {} of disk but {} are free there: \
             simulate fewer frames, or into a folder on a larger disk",
            out.display(),
            simulation.frames,
            crate::memory::gigabytes(needed as f64),
            crate::memory::gigabytes(free.saturating_add(replaced) as f64)
        );
    }
    Ok(())
}

/// Writes `simulation` into the folder `out` (created if needed): removes what an earlier run of
/// another preset left there, then writes the recordings, the truth and `scenario.toml` (last, so
/// that an interrupted run leaves none). `progress(events done, events in all)`; `say` takes a
/// line for the user per file written.
pub fn write(
    simulation: &Simulation,
    out: &Path,
    progress: &(dyn Fn(usize, usize) + Sync),
    say: &dyn Fn(&str),
) -> Result<()> {
    crate::input::create_dir(out)?;
    let recordings: Vec<&str> = simulation.modes.iter().map(|(name, _)| *name).collect();
    check_disk_space(simulation, out, &recordings)?;
    // Once every setting is checked: a refused run deletes nothing.
    remove_stale_outputs(
        out,
        &recordings,
        simulation.network.is_some() || simulation.tree.is_some(),
        simulation.tissue.is_some(),
        simulation.tree.is_some(),
        say,
    )?;
    // Written last, so that an interrupted run leaves no scenario beside half-written recordings.
    let scenario = out.join(SCENARIO_FILE);
    match std::fs::remove_file(&scenario) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(e).with_context(|| format!("{}: cannot remove it", scenario.display()));
        }
        _ => {}
    }
    let events_of =
        |params: &pcuvd::simulate::SimParams| simulation.frames * params.sequence.n_angles();
    let levels = simulation.echo_levels()?;
    if let Some(levels) = levels {
        say(&format!(
            "tissue echo {:.1} dB above the blood's (0° plane wave){}",
            levels.tissue_over_blood_db,
            levels
                .noise_db_re_whole_echo
                .map_or_else(String::new, |level| format!(
                    "; noise {level:.1} dB re the whole echo"
                ))
        ));
    }
    let mut writers = simulation
        .modes
        .iter()
        .enumerate()
        .map(|(index, (name, params))| {
            let shape = (events_of(params), params.probe.n_elements, params.n_samples);
            let writer = pcuvd_io::RecordingWriter::create(
                out,
                name,
                &params.acquisition(),
                shape,
                &simulation.provenance(index, levels),
            )?;
            Ok::<_, pcuvd_io::IoError>(match simulation.cardiac_triggers() {
                Some(times) => writer.with_cardiac_triggers(times),
                None => writer,
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    // Written a block of frames at a time, as they are simulated: memory stays bounded.
    simulation.in_blocks(
        |index, _, samples| Ok(writers[index].append(samples.view())?),
        progress,
    )?;
    // The truth is the same for every mode (same phantom, same default grid): computed once, on
    // a thread while the recordings are flushed to disk (where `finish` waits on the disk, not
    // the CPU), and written whatever an earlier run left in the folder.
    let (_, first) = simulation
        .modes
        .first()
        .context("a simulation without a transmit mode")?;
    let truth = std::thread::scope(|scope| -> Result<_> {
        let truth = scope.spawn(|| simulation.truth_for(&first.acquisition(), first.n_samples));
        for ((_, params), writer) in simulation.modes.iter().zip(writers) {
            let manifest = writer.finish()?;
            say(&format!(
                "wrote {} ({} events of {} channels × {} samples)",
                manifest.display(),
                events_of(params),
                params.probe.n_elements,
                params.n_samples
            ));
        }
        truth
            .join()
            .map_err(|_| anyhow::anyhow!("the thread computing the ground truth failed"))?
    })?;
    let [x, z, vx, vz, mask] = TRUTH_FILES.map(|name| out.join(name));
    pcuvd_io::write_npy(&x, &Array1::from(truth.x.clone()))?;
    pcuvd_io::write_npy(&z, &Array1::from(truth.z.clone()))?;
    pcuvd_io::write_npy(&vx, &truth.truth.vx)?;
    pcuvd_io::write_npy(&vz, &truth.truth.vz)?;
    pcuvd_io::write_npy(&mask, &truth.truth.mask.mapv(u8::from))?;
    if let Some(cycle) = &truth.cycle {
        let [
            ri,
            psv,
            edv,
            vessel_class,
            flow_up,
            class_share,
            axis_profile,
        ] = NETWORK_TRUTH_FILES.map(|name| out.join(name));
        pcuvd_io::write_npy(&ri, &cycle.ri)?;
        pcuvd_io::write_npy(&psv, &cycle.psv)?;
        pcuvd_io::write_npy(&edv, &cycle.edv)?;
        pcuvd_io::write_npy(&vessel_class, &cycle.vessel_class)?;
        pcuvd_io::write_npy(&flow_up, &cycle.flow_up.mapv(u8::from))?;
        pcuvd_io::write_npy(&class_share, &cycle.class_share)?;
        pcuvd_io::write_npy(&axis_profile, &cycle.axis_profile)?;
    }
    if let Some((vy, fraction)) = &truth.elevation {
        let [vy_path, fraction_path] = ELEVATION_TRUTH_FILES.map(|name| out.join(name));
        pcuvd_io::write_npy(&vy_path, vy)?;
        pcuvd_io::write_npy(&fraction_path, fraction)?;
    }
    if let Some(tissue) = &truth.tissue {
        let [vx, vz, displacement] = TISSUE_TRUTH_FILES.map(|name| out.join(name));
        pcuvd_io::write_npy(&vx, &tissue.velocity[0])?;
        pcuvd_io::write_npy(&vz, &tissue.velocity[2])?;
        if let Some(moved) = simulation.tissue_displacement(&truth.z) {
            pcuvd_io::write_npy(&displacement, &moved)?;
        }
    }
    say(&format!(
        "wrote the ground truth (truth_*.npy, m/s, on the default processing grid) to {}",
        out.display()
    ));
    let text = format!(
        "{SCENARIO_HEADER} (from {}, every option applied):\n\
         # `pcuvd simulate --scenario {SCENARIO_FILE}` simulates the same recordings again.\n\n{}",
        simulation.source,
        simulation.scenario.to_toml()?
    );
    std::fs::write(&scenario, text)
        .with_context(|| format!("{}: cannot write the scenario", scenario.display()))?;
    say(&format!(
        "wrote {} (the scenario simulated)",
        scenario.display()
    ));
    Ok(())
}
