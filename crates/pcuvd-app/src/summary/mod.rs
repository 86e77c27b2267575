//! What a run leaves behind: the maps as `.npy` (SI units), its figures, and `summary.json`
//! (every parameter, what each stage did, the input's provenance), written last.

use std::path::{Path, PathBuf};

use anyhow::Result;
use ndarray::Array1;
use pcuvd::acquisition::source::FrameSource;
use pcuvd::dynamics::{self, PoolingSummary};
use pcuvd::pipeline::{self, ProcessOutput, ProcessParams};
use serde_json::json;

use crate::figures;
use crate::outputs;
use crate::progress::Progress;
use crate::run::{DynamicsOutcome, Plan, Processed};

/// What a saved run records beside its results.
pub struct Record<'a> {
    /// The input's provenance ([`provenance`]).
    pub source: serde_json::Value,
    /// The name the figures carry (the input file's).
    pub name: &'a str,
    /// Seconds of work outside the run (reading, checksums), by name, for `timings_s`.
    pub extra_timings: &'a [(&'a str, f64)],
    /// NIfTI images with BEP040 sidecars besides the `.npy` maps, named so; `None` for none.
    pub nifti: Option<&'a crate::nifti::NiftiNaming>,
}

/// Writes every output of `process` into `dir` (already prepared by [`outputs::prepare`]): maps,
/// figures, dynamics maps, and `summary.json` last with `record`'s provenance and timings; what
/// was found is said to `progress`. Returns the figures.
pub fn save(
    dir: &Path,
    data: &dyn FrameSource,
    plan: &Plan,
    processed: &Processed,
    record: Record<'_>,
    progress: &dyn Progress,
) -> Result<Vec<PathBuf>> {
    let Record {
        source,
        name,
        extra_timings,
        nifti,
    } = record;
    let clock = std::time::Instant::now();
    let out = &processed.out;
    write_maps(dir, out)?;
    let mut summary = summary(data, plan, processed, source);
    let mut pngs = figures::process_figures(dir, out, name)?;
    pngs.append(&mut write_dynamics(dir, plan, processed, name, progress)?);
    if let Some(maps) = &processed.ensembles {
        write_ensembles(dir, maps)?;
        pngs.push(figures::ensemble_figure(dir, out, maps, name)?);
    }
    if let Some(naming) = nifti {
        let images = crate::nifti::write_nifti(dir, data, plan, processed, naming)?;
        let names: Vec<String> = images
            .iter()
            .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
            .collect();
        summary["nifti"] = json!(names);
    }
    for (key, seconds) in extra_timings {
        summary["timings_s"][*key] = json!(seconds);
    }
    summary["timings_s"]["maps_figures_and_dynamics"] =
        json!(processed.dynamics_s + clock.elapsed().as_secs_f64());
    // Written last: a folder without summary.json is visibly incomplete.
    pcuvd_io::write_json(&dir.join("summary.json"), &summary)?;
    Ok(pngs)
}

/// Where the results came from: pcuvd's version, the command line, every input file with its
/// size and `checksum` (keyed by its name: "blake3" or "sha256"), the format and the reader that
/// read it (as the reader reports them), every acquisition parameter with its source, the
/// reader's warnings, and the options.
pub fn provenance(
    input: &str,
    info: &pcuvd_io::SourceInfo,
    options_text: &str,
    command_line: Vec<String>,
    checksum: outputs::Checksum,
) -> Result<serde_json::Value> {
    let files = info
        .files
        .iter()
        .map(|path| {
            let (size, hex) = outputs::fingerprint(path, checksum)?;
            let mut file = json!({ "path": path.display().to_string(), "size_bytes": size });
            file[checksum.key()] = json!(hex);
            Ok(file)
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(json!({
        "input": input,
        "format": info.format,
        "reader": info.reader,
        "files": files,
        "stored_samples": info.stored,
        "parameters": info.parameters,
        "reader_warnings": info.warnings,
        "pcuvd_version": env!("CARGO_PKG_VERSION"),
        "command_line": command_line,
        "options": options_text,
    }))
}

/// True when `out` holds a complete earlier run (its summary.json) of the same input files (by
/// size and checksum, of the same kind), options (every processing and dynamics setting, defaults included) and
/// pcuvd version as `source` describes: a batch re-run can skip it.
pub fn already_done(out: &Path, source: &serde_json::Value) -> bool {
    let Ok(text) = std::fs::read_to_string(out.join("summary.json")) else {
        return false;
    };
    let Ok(summary) = serde_json::from_str::<serde_json::Value>(&text) else {
        return false;
    };
    let earlier = &summary["source"];
    let fingerprints = |s: &serde_json::Value| -> Option<Vec<(u64, &'static str, String)>> {
        s["files"]
            .as_array()?
            .iter()
            .map(|f| {
                let key = outputs::Checksum::ALL
                    .map(outputs::Checksum::key)
                    .into_iter()
                    .find(|k| f[*k].is_string())?;
                Some((f["size_bytes"].as_u64()?, key, f[key].as_str()?.to_string()))
            })
            .collect()
    };
    fingerprints(earlier).is_some()
        && fingerprints(earlier) == fingerprints(source)
        && earlier["options"] == source["options"]
        && earlier["pcuvd_version"] == source["pcuvd_version"]
}

/// The summary.json of a `process` run (without the writing timings): every parameter used, the
/// Nyquist velocity, clutter cut-offs, per-stage timings, the dynamics stage, and `source`.
pub fn summary(
    data: &dyn FrameSource,
    plan: &Plan,
    processed: &Processed,
    source: serde_json::Value,
) -> serde_json::Value {
    let mut summary = summary_json(data, &plan.params, &processed.out, source);
    summary["dynamics"] = dynamics_summary(plan, processed);
    summary["blocks"] = json!({
        "frames": processed.blocks.frames,
        "margin_frames": processed.blocks.margin,
        "rule": format!(
            "images formed a block of frames at a time, decoded in the memory they are read \
             into: at most as many frames as fit in {} MiB with their margins and one angle's IQ \
             (the whole recording when it fits), the blocks of a segment sharing its frames \
             evenly, with {} frames decoded on either side of a block of a coded recording \
             aligned at mid-frame",
            pipeline::BLOCK_BYTES >> 20,
            pcuvd::pipeline::blocks::Blocks::ALIGNMENT_MARGIN
        ),
    });
    summary["segments"] = match &processed.segments {
        None => json!("none: the whole recording was held and processed at once"),
        Some(done) => json!({
            "count": done.ranges.len(),
            "own_frames": done.ranges.iter().map(|(core, _)| [core.start, core.end]).collect::<Vec<_>>(),
            "imaged_frames": done.ranges.iter().map(|(_, imaged)| [imaged.start, imaged.end]).collect::<Vec<_>>(),
            "clutter_cut_offs_per_angle": done.clutter.iter().map(|per_angle| {
                per_angle.iter().map(|(low, high)| json!({"low": low, "high": high})).collect::<Vec<_>>()
            }).collect::<Vec<_>>(),
            "rule": format!(
                "too long to hold whole (--segment-frames, default: the frames whose image series \
                 fit in {} MiB): each segment imaged with the frames its dynamics windows and \
                 ensembles reach into, clutter-filtered on its own; power and lag-1 \
                 autocorrelation summed over the segments' own frames, velocities and vectors \
                 from the sums; windows and ensembles from the segment their start is in",
                pcuvd::pipeline::segments::SERIES_BYTES >> 20
            ),
        }),
    };
    summary["ensembles"] = match (&plan.ensembles, &processed.ensembles) {
        (Some(spec), Some(maps)) => json!({
            "frames": spec.frames,
            "step_frames": spec.step,
            "count": maps.starts.len(),
            "duration_s": spec.frames as f64 / data.acquisition().frame_rate(),
            "times_s": maps.times_s,
            "start_frames": maps.starts,
            "clutter_cut_offs_per_angle": maps.clutter.iter().map(|per_angle| {
                per_angle.iter().map(|(low, high)| json!({"low": low, "high": high})).collect::<Vec<_>>()
            }).collect::<Vec<_>>(),
            "estimator": "IRLS-WLS (PC-UVD)",
        }),
        _ => {
            json!("none: the whole recording is one ensemble (--ensemble-frames for a time series)")
        }
    };
    summary
}

/// The dynamics stage's entry of summary.json.
fn dynamics_summary(plan: &Plan, processed: &Processed) -> serde_json::Value {
    let out = &processed.out;
    let (settings, series, maps) = match (&plan.dynamics, &processed.dynamics) {
        (Some(settings), DynamicsOutcome::Done { series, maps }) => (settings, series, maps),
        (_, DynamicsOutcome::Skipped(reason)) => return json!({ "skipped": reason }),
        (None, DynamicsOutcome::Done { .. }) => {
            return json!({ "skipped": "--dynamics off" });
        }
    };
    let (dparams, vessel) = (settings.params, settings.vessel);
    let count = |code: u8| maps.vessel_class.iter().filter(|&&c| c == code).count();
    json!({
        "heart_rate_hz": maps.heart_rate_hz,
        "heart_rate_given": dparams.heart_rate_hz.is_some(),
        "cycles_from": maps.cycle_source.describe(),
        "triggers_from": settings.triggers.as_ref().map(|(_, from)| from.as_str()),
        "cycles_count": maps.cycles.len(),
        "spread": "psv_spread.npy, edv_spread.npy, ri_spread.npy: standard deviation across the complete cycles of each cycle's PSV (m/s), EDV (m/s) and RI, each cycle's speed fitted on its own; NaN with one cycle",
        "window_frames": dparams.window,
        "step_frames": dparams.step,
        "window_s": series.window_s,
        "step_s": series.step_s,
        "harmonics": dparams.harmonics.unwrap_or_else(|| dynamics::auto_harmonics(maps.heart_rate_hz, series.window_s)),
        "estimator": "IRLS-WLS (PC-UVD)",
        "kernel": [dparams.kernel.0, dparams.kernel.1],
        "partial_volume": dparams.partial_volume,
        "artery_ri_min": dparams.artery_ri_min,
        "vein_ri_max": dparams.vein_ri_max,
        "vessel_threshold_db": dparams.min_power_db,
        "vessel_margin_db": db_or_off(vessel.margin_db),
        "vessel_margin_reference": "noise floor of each depth row of the power Doppler: its 30th percentile (masks::noise_floor_by_depth)",
        "vessel_local_db": db_or_off(vessel.local_db),
        "vessel_local_radius_mm": vessel.local_radius_m * 1e3,
        "vessel_pooling": PoolingSummary::new(dparams.pooling, out.grid.step()),
        "cycles_windows": maps.cycles,
        "pixels": {
            "arteriole": count(dynamics::ARTERIOLE),
            "venule": count(dynamics::VENULE),
            "undetermined": count(dynamics::UNDETERMINED),
        },
        "class_codes": { "background": dynamics::BACKGROUND, "arteriole": dynamics::ARTERIOLE, "venule": dynamics::VENULE, "undetermined": dynamics::UNDETERMINED },
    })
}

/// Writes the dynamics stage's maps and figures into `dir` (nothing when it was skipped);
/// returns the figures written.
fn write_dynamics(
    dir: &Path,
    plan: &Plan,
    processed: &Processed,
    name: &str,
    progress: &dyn Progress,
) -> Result<Vec<PathBuf>> {
    let (Some(settings), DynamicsOutcome::Done { series, maps }) =
        (&plan.dynamics, &processed.dynamics)
    else {
        return Ok(vec![]);
    };
    let out = &processed.out;
    let dparams = settings.params;
    npy(dir, "ri.npy", &maps.ri)?;
    npy(dir, "psv.npy", &maps.psv)?;
    npy(dir, "edv.npy", &maps.edv)?;
    npy(dir, "psv_spread.npy", &maps.psv_spread)?;
    npy(dir, "edv_spread.npy", &maps.edv_spread)?;
    npy(dir, "ri_spread.npy", &maps.ri_spread)?;
    pcuvd_io::write_npy(&dir.join("vessel_class.npy"), &maps.vessel_class)?;
    pcuvd_io::write_npy(&dir.join("flow_up.npy"), &maps.flow_up.mapv(u8::from))?;
    pcuvd_io::write_npy(&dir.join("speed_series.npy"), &series.speed())?;
    pcuvd_io::write_npy(
        &dir.join("times.npy"),
        &Array1::from(series.times_s.clone()),
    )?;
    let pngs = figures::dynamics_figures(dir, maps, series, &dparams, &out.grid, name)?;
    let count = |code: u8| maps.vessel_class.iter().filter(|&&c| c == code).count();
    progress.report(&format!(
        "RI maps: heart rate {:.2} Hz ({}), {} cycle(s); {} arteriole, {} venule, {} undetermined pixels",
        maps.heart_rate_hz,
        match maps.cycle_source {
            dynamics::CycleSource::GivenRate => "given",
            dynamics::CycleSource::Triggers => "from the cardiac triggers",
            dynamics::CycleSource::Upstrokes => "measured: systolic upstrokes",
            dynamics::CycleSource::Autocorrelation => "measured: autocorrelation",
        },
        maps.cycles.len(),
        count(dynamics::ARTERIOLE),
        count(dynamics::VENULE),
        count(dynamics::UNDETERMINED)
    ));
    Ok(pngs)
}

/// Writes the Doppler time series: (ensembles, nz, nx) maps in SI units and their centre times.
fn write_ensembles(dir: &Path, maps: &pcuvd::pipeline::ensembles::EnsembleMaps) -> Result<()> {
    pcuvd_io::write_npy(&dir.join("ensemble_power_doppler.npy"), &maps.power_doppler)?;
    pcuvd_io::write_npy(&dir.join("ensemble_color_doppler.npy"), &maps.color_doppler)?;
    pcuvd_io::write_npy(
        &dir.join("ensemble_signed_power_doppler.npy"),
        &maps.signed_power_doppler(),
    )?;
    if let (Some(vx), Some(vz), Some(speed)) = (&maps.vx, &maps.vz, maps.speed()) {
        pcuvd_io::write_npy(&dir.join("ensemble_vx.npy"), vx)?;
        pcuvd_io::write_npy(&dir.join("ensemble_vz.npy"), vz)?;
        pcuvd_io::write_npy(&dir.join("ensemble_speed.npy"), &speed)?;
    }
    pcuvd_io::write_npy(
        &dir.join("ensemble_times.npy"),
        &Array1::from(maps.times_s.clone()),
    )?;
    Ok(())
}

/// A vessel-test level (dB) as set: "off" for the infinite level that stands for it.
fn db_or_off(db: f64) -> serde_json::Value {
    if db.is_finite() {
        json!(db)
    } else {
        json!("off")
    }
}

fn npy(dir: &Path, name: &str, arr: &ndarray::Array2<f64>) -> Result<()> {
    pcuvd_io::write_npy(&dir.join(name), arr)?;
    Ok(())
}

/// Writes the maps as .npy (SI units).
pub fn write_maps(dir: &Path, out: &ProcessOutput) -> Result<()> {
    pcuvd_io::write_npy(&dir.join("x.npy"), &Array1::from(out.grid.x.clone()))?;
    pcuvd_io::write_npy(&dir.join("z.npy"), &Array1::from(out.grid.z.clone()))?;
    npy(dir, "bmode_db.npy", &out.bmode_db)?;
    npy(dir, "power_doppler.npy", &out.power_doppler)?;
    npy(dir, "color_doppler.npy", &out.color_doppler)?;
    npy(dir, "signed_power_doppler.npy", &out.signed_power_doppler())?;
    pcuvd_io::write_npy(&dir.join("projections.npy"), &out.projections)?;
    pcuvd_io::write_npy(&dir.join("projection_nyquist.npy"), &out.projection_nyquist)?;
    if let (Some(ls), Some(irls)) = (&out.vector_ls, &out.vector_irls) {
        npy(dir, "vx.npy", &irls.vx)?;
        npy(dir, "vz.npy", &irls.vz)?;
        npy(dir, "speed.npy", &irls.speed())?;
        npy(dir, "vx_ls.npy", &ls.vx)?;
        npy(dir, "vz_ls.npy", &ls.vz)?;
        npy(dir, "speed_ls.npy", &ls.speed())?;
    }
    if let Some(done) = &out.dealias {
        pcuvd_io::write_npy(&dir.join("alias_counts.npy"), &done.irls.alias_counts)?;
        pcuvd_io::write_npy(&dir.join("alias_counts_ls.npy"), &done.ls.alias_counts)?;
    }
    Ok(())
}

/// The `dealias` entry of summary.json: the setting, the K used, the speeds it reaches, per
/// estimator how many flow pixels were dealiased, unwrapped, and reached ±K, and the warning for a
/// `coded` recording or one of too few angles ([`pcuvd::pipeline::dealias_warning`]; null
/// otherwise).
fn dealias_summary(params: &ProcessParams, out: &ProcessOutput, coded: bool) -> serde_json::Value {
    let warning = pcuvd::pipeline::dealias_warning(params.dealias, coded, out);
    let Some(done) = &out.dealias else {
        return json!({ "setting": params.dealias.label(), "warning": warning });
    };
    let counts = |c: &pcuvd::estimate::dealias::AliasCounts| {
        json!({
            "dealiased_pixels": c.dealiased_pixels,
            "unwrapped_pixels": c.unwrapped_pixels,
            "at_limit_pixels": c.at_limit_pixels,
        })
    };
    json!({
        "setting": params.dealias.label(),
        "intervals": done.intervals,
        "max_speed_m_s": (2 * done.intervals + 1) as f64 * out.nyquist_velocity,
        "flow_pixels": done.flow_pixels,
        "pcuvd_irls": counts(&done.irls),
        "uvd_ls": counts(&done.ls),
        "warning": warning,
        "rule": format!(
            "alias patterns up to ±K Nyquist intervals (2 v_N) per angle, from trial vectors; \
             scored by the estimator's unweighted objective (LS: sum of squared residuals, IRLS: \
             sum of absolute residuals); within a level a mixed pattern kept only where its \
             summed squared residual is below {} times the level's common shift's (even where \
             that shift's fit is beyond the speed limit; a pixel left without a level-0 \
             candidate keeps the plain fit unless another level's fits it with under that ratio \
             times the plain fit's squared residual); the common shift of all angles settled over the flow \
             pixels (power {} dB above the row's noise floor and within {} dB of the \
             brightest pixel within {} mm) by unwrapping the levels as a \
             phase map, most reliable joins first (Herraez et al. 2002), pixels next to non-flow \
             joined to speed 0 (blood is slow at a wall; pixels without candidates enclosed by \
             flow are holes, not wall; pixels whose angles' Nyquist velocities differ by more \
             than {}x take the level of the flow around them, or keep the plain fit outside \
             it), unless another common shift makes the \
             vessel's power-weighted summed residual less than {} times as large; regions under \
             {} pixels and other \
             pixels keep the plain fit; auto: the smallest K of 1-{} at which under {} % of the \
             unwrapped pixels reach ±K; alias_counts.npy (PC-UVD) and alias_counts_ls.npy (UVD) \
             hold the counts (angles, nz, nx)",
            pcuvd::estimate::dealias::MIXED_PATTERN_RATIO,
            pcuvd::estimate::dealias::FLOW_MARGIN_DB,
            pcuvd::dynamics::VESSEL_LOCAL_DB,
            pcuvd::dynamics::VESSEL_LOCAL_RADIUS_M * 1e3,
            pcuvd::estimate::dealias::NYQUIST_SPREAD_LIMIT,
            pcuvd::estimate::dealias::DECISIVE_SCORE_RATIO,
            pcuvd::estimate::dealias::MIN_REGION_PIXELS,
            pcuvd::estimate::dealias::MAX_AUTO_INTERVALS,
            pcuvd::estimate::dealias::AUTO_LIMIT_FRACTION * 100.0
        ),
    })
}

/// How the angles were transmitted, for summary.json and `pcuvd info`: `kind` "none",
/// "hadamard" (order, even slot delay) or "matrix" (the code's weights row by row, each slot's
/// start, the decoding gain g — decoded records are g × each angle's — and the condition number).
pub fn coding_json(seq: &pcuvd::Sequence) -> serde_json::Value {
    match &seq.coding {
        pcuvd::Coding::Conventional => json!({ "kind": "none" }),
        pcuvd::Coding::Hadamard { slot_delay } => json!({
            "kind": "hadamard", "order": seq.n_angles(), "slot_delay_s": slot_delay,
        }),
        pcuvd::Coding::Matrix(code) => json!({
            "kind": "matrix",
            "order": code.order(),
            "code_matrix": code.weights.chunks(code.order().max(1)).collect::<Vec<_>>(),
            "slot_starts_s": code.slot_starts,
            "events_fire_several_slots": code.is_coded(),
            "decoding_gain": code.decoding_gain(),
            "condition_number": code.condition_number(),
        }),
    }
}

/// The sampled transmit pulse for summary.json and `pcuvd info` (null when the sequence has
/// none): its sampling rate, length, and what pcuvd uses it for.
pub fn pulse_json(seq: &pcuvd::Sequence) -> serde_json::Value {
    match &seq.pulse {
        None => serde_json::Value::Null,
        Some(p) => json!({
            "sampling_frequency_hz": p.sampling_frequency,
            "n_samples": p.samples.len(),
            "duration_s": p.duration(),
            "used_for": "simulation (the echo waveform: the pulse through the probe's two-way response); processing does not need it",
        }),
    }
}

/// Every parameter used, the Nyquist velocity, clutter cut-offs and per-stage timings.
pub fn summary_json(
    data: &dyn FrameSource,
    params: &ProcessParams,
    out: &ProcessOutput,
    extra: serde_json::Value,
) -> serde_json::Value {
    let acq = data.acquisition();
    let probe = &acq.probe;
    let seq = &acq.sequence;
    let mut coding = coding_json(seq);
    if seq.is_coded() {
        coding["event_alignment"] = json!(params.event_alignment.label());
    }
    let timings: serde_json::Map<String, serde_json::Value> = out
        .timings
        .iter()
        .map(|(s, t)| (s.label().to_string(), json!(t)))
        .collect();
    json!({
        "units": "SI (m, s, Hz, m/s); colour Doppler and Vz positive = moving away from the probe (deeper)",
        "source": extra,
        "probe": {
            "name": probe.name, "n_elements": probe.n_elements, "pitch_m": probe.pitch,
            "element_width_m": probe.element_width, "center_frequency_hz": probe.center_frequency,
            "bandwidth": probe.bandwidth,
        },
        "acquisition": {
            "sampling_frequency_hz": acq.sampling_frequency, "sound_speed_m_s": acq.sound_speed,
            "t0_s": acq.t0, "event_prf_hz": seq.event_prf,
            "angles_deg": seq.angles.iter().map(|a| a.to_degrees()).collect::<Vec<_>>(),
            "coding": coding, "frames": data.n_frames(), "frame_rate_hz": acq.frame_rate(),
            "pulse_cycles": seq.pulse_cycles, "transmit_pulse": pulse_json(seq),
        },
        "grid": {
            "x_min_m": out.grid.x[0], "x_max_m": out.grid.x[out.grid.x.len() - 1],
            "z_min_m": out.grid.z[0], "z_max_m": out.grid.z[out.grid.z.len() - 1],
            "step_m": out.grid.step(),
            "nx": out.grid.x.len(), "nz": out.grid.z.len(),
        },
        "beamforming": { "f_number": params.das.f_number, "apodization": format!("{:?}", params.das.apodization) },
        "clutter_filter": {
            "low": format!("{:?}", params.clutter.low), "high": format!("{:?}", params.clutter.high),
            "tissue_frequency_fraction": params.clutter.tissue_frequency,
            "cut_offs_per_angle": out.clutter.iter().map(|r| json!({"low": r.low, "high": r.high})).collect::<Vec<_>>(),
        },
        "doppler": {
            "kernel": [params.doppler_kernel.0, params.doppler_kernel.1],
            "estimator": params.doppler_estimator.label(),
            "estimator_description": params.doppler_estimator.describe(),
            "partial_volume": params.partial_volume,
            // Each angle's intensity cell at one pixel (its speckle's) as the correction saw
            // it; null where it could not be measured.
            "partial_volume_cells": params.partial_volume.then(|| out.cells.iter().map(|c| c.map(|c| json!({
                "sigma_x_mm": c.xx.sqrt() * 1e3,
                "sigma_z_mm": c.zz.sqrt() * 1e3,
                "covariance_xz_mm2": c.xz * 1e6,
            }))).collect::<Vec<_>>()),
        },
        "irls": { "lambda_mm_s": params.irls.lambda_mm_s, "epsilon": params.irls.epsilon, "max_iterations": params.irls.max_iterations },
        "nyquist_velocity_m_s": out.nyquist_velocity,
        "dealias": dealias_summary(params, out, seq.is_coded()),
        "timings_s": timings,
    })
}
