//! What a run leaves behind: the maps as `.npy` (SI units), its figures, and `summary.json`
//! (every parameter, what each stage did, the input's provenance), written last.

use std::path::{Path, PathBuf};

use anyhow::Result;
use ndarray::Array1;
use pcuvd::dynamics;
use pcuvd::estimate::clutter::ClutterReport;
use pcuvd::pipeline::ProcessOutput;

use crate::figures;
use crate::outputs;
use crate::progress::Progress;
use crate::run::{DynamicsOutcome, Plan, Processed};

mod record;
mod report;
mod stages;
pub use record::*;
pub use report::{REPORT, caption, write_report};
pub use stages::*;

/// What a saved run records beside its results.
pub struct Record<'a> {
    /// The input's provenance ([`provenance`]).
    pub source: Provenance,
    /// The name the figures carry (the input file's).
    pub name: &'a str,
    /// Seconds of work outside the run (reading, checksums), by name, for `timings_s`.
    pub extra_timings: &'a [(&'a str, f64)],
    /// NIfTI images with BEP040 sidecars besides the `.npy` maps, named so; `None` for none.
    pub nifti: Option<&'a crate::nifti::NiftiNaming>,
    /// The run's Zarr store, to finish with the maps; `None` for none.
    pub zarr: Option<crate::zarr::ZarrStore>,
    /// The scenario (TOML) of a recording simulated in memory, to score the run against its
    /// truth; `None` looks for the scenario file beside the input.
    pub simulated_from: Option<&'a str>,
}

/// What [`save`] wrote.
pub struct Saved {
    /// The figures.
    pub figures: Vec<PathBuf>,
    /// The run scored against the truth of the simulation it came from, when it came from one.
    pub against_truth: Option<crate::against_truth::TruthRecord>,
}

/// Writes every output of `process` on `input` into `dir` (already prepared by
/// [`outputs::prepare`]): maps, figures, dynamics maps, the scores against a simulation's truth
/// where a recording has one beside it or came with one, and `summary.json` last with
/// `record`'s provenance and timings; what was found is said to `progress`. Images formed
/// elsewhere get NIfTI sidecars and Zarr attributes of what they give (no probe or transmit
/// sequence).
pub fn save(
    dir: &Path,
    input: RunInput<'_>,
    plan: &Plan,
    processed: &Processed,
    record: Record<'_>,
    progress: &dyn Progress,
) -> Result<Saved> {
    let Record {
        source,
        name,
        extra_timings,
        nifti,
        zarr,
        simulated_from,
    } = record;
    let clock = std::time::Instant::now();
    let out = &processed.out;
    write_maps(dir, out)?;
    // A simulation's truth is computed while the figures are drawn: the two share the cores.
    let (pngs, against) = rayon::join(
        || figures::process_figures(dir, out, name),
        || match input {
            RunInput::Recording(data) => {
                crate::against_truth::score_run(&source.input, simulated_from, data, processed)
            }
            RunInput::Images(_) => None,
        },
    );
    let mut pngs = pngs?;
    let mut summary = Summary::of(input, plan, processed, source);
    summary.against_truth = against.as_ref().map(|scored| scored.record.clone());
    // The sites' spectrograms, made once for the summary, the arrays, the figure and the store.
    let sites = crate::sites::SiteSpectrograms::of(plan, processed)?;
    if let Some(sites) = &sites {
        summary.sites = Some(sites.records(&out.grid));
        sites.write(dir)?;
        pngs.push(sites.figure(dir, processed, name)?);
    }
    if let Some(scored) = &against {
        pngs.extend(scored.figure(dir, processed, name)?);
    }
    let clutter = clutter_by_segment(processed);
    if let Some(cut_offs) = block_cut_offs(&clutter)? {
        pcuvd_io::write_npy(&dir.join("clutter_block_cut_offs.npy"), &cut_offs)?;
        pngs.extend(figures::clutter_blocks_figure(dir, out, &clutter, name)?);
    }
    pngs.append(&mut write_dynamics(dir, plan, processed, name, progress)?);
    if let Some(maps) = &processed.ensembles
        && !processed.ensembles_in_store
    {
        write_ensembles(dir, maps)?;
        pngs.push(figures::ensemble_figure(dir, out, maps, name)?);
    }
    if let Some(naming) = nifti {
        let images = crate::nifti::write_nifti(dir, input, plan, processed, naming)?;
        let names: Vec<String> = images
            .iter()
            .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
            .collect();
        summary.nifti = Some(names);
    }
    if let Some(store) = zarr {
        let in_store_only = processed.ensembles_in_store;
        let path = store.finish(input, plan, processed, sites.as_ref())?;
        // Series that went to the store as the run went are drawn from it, a run at a time.
        if in_store_only && let Some(timeline) = &processed.ensembles {
            pngs.push(crate::zarr::draw_ensembles(
                &path, dir, out, timeline, name,
            )?);
        }
        summary.zarr = Some(ZarrRecord {
            store: path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            arrays: crate::zarr::arrays(&path)?,
            time_series_in_store_only: in_store_only,
        });
    }
    for (key, seconds) in extra_timings {
        summary.timings_s.insert(key.to_string(), *seconds);
    }
    summary.timings_s.insert(
        "maps_figures_and_dynamics".into(),
        processed.dynamics_s + clock.elapsed().as_secs_f64(),
    );
    summary.peak_resident_bytes = crate::memory::peak_resident_memory();
    write_report(dir, &summary, &pngs)?;
    // Written last: a folder without summary.json is visibly incomplete.
    pcuvd_io::write_json(&dir.join("summary.json"), &summary)?;
    Ok(Saved {
        figures: pngs,
        against_truth: summary.against_truth,
    })
}

/// Where the results came from: pcuvd's version, the command line, every input file with its
/// size and `checksum`, the format and the reader that read it (as the reader reports them), every
/// acquisition parameter with its source, the reader's warnings, and the options. Files in
/// `hashed` (by the reader, in its pass over them) keep that checksum; the others are read for it.
pub fn provenance(
    input: &str,
    info: &pcuvd_io::SourceInfo,
    options_text: &str,
    command_line: Vec<String>,
    checksum: outputs::Checksum,
    hashed: &[(std::path::PathBuf, pcuvd_io::Checksummed)],
) -> Result<Provenance> {
    let files = info
        .files
        .iter()
        .map(|path| {
            let (size, hex) = match hashed.iter().find(|(file, _)| file == path) {
                Some((_, done)) => (done.size_bytes, done.hex.clone()),
                None => outputs::fingerprint(path, checksum)?,
            };
            Ok(FileRecord::new(
                path.display().to_string(),
                size,
                checksum,
                hex,
            ))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(Provenance {
        input: input.to_string(),
        format: info.format.clone(),
        reader: info.reader.clone(),
        files,
        stored_samples: info.stored.clone(),
        parameters: info.parameters.clone(),
        reader_warnings: info.warnings.clone(),
        pcuvd_version: env!("CARGO_PKG_VERSION").to_string(),
        command_line,
        options: options_text.to_string(),
        simulation: None,
    })
}

/// What `out` holds of an earlier run of the same input files (by size and checksum, of the
/// same kind), options (every processing and dynamics setting, defaults included) and pcuvd
/// version as `source` describes, by its summary.json.
#[derive(Debug, Clone, PartialEq)]
pub enum EarlierRun {
    /// None: no summary.json, or another run's.
    None,
    /// A complete run: a batch re-run can skip it.
    Done,
    /// A run whose RI maps asked for could not be made, why: it wrote its other outputs and
    /// ended in that error, which a re-run ends in again without the work.
    DynamicsFailed(String),
}

/// The kind of checksum `checksum` asks for, or where none is asked for, the kind by which an
/// earlier run in `out` records its input (so that a re-run of a folder made before the default
/// changed still knows it), else the default.
pub fn checksum_for(out: &Path, checksum: Option<outputs::Checksum>) -> outputs::Checksum {
    checksum
        .or_else(|| {
            let text = std::fs::read_to_string(out.join("summary.json")).ok()?;
            Provenance::checksum_of(&text)
        })
        .unwrap_or_default()
}

/// The earlier run `out` holds of the run `source` describes ([`EarlierRun`]).
pub fn earlier_run(out: &Path, source: &Provenance) -> EarlierRun {
    let Ok(text) = std::fs::read_to_string(out.join("summary.json")) else {
        return EarlierRun::None;
    };
    if !source.same_run_as(&text) {
        return EarlierRun::None;
    }
    let failed = serde_json::from_str::<serde_json::Value>(&text)
        .ok()
        .and_then(|summary| Some(summary["dynamics"].get("failed")?.as_str()?.to_string()));
    failed.map_or(EarlierRun::Done, EarlierRun::DynamicsFailed)
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
    // Window by window: a long recording's speeds are never held whole beside its windows.
    let (windows, nz, nx) = series.vz.dim();
    pcuvd_io::write_npy_by_slices(&dir.join("speed_series.npy"), &[windows, nz, nx], |k| {
        series.speed_at(k).into_dyn()
    })?;
    pcuvd_io::write_npy(
        &dir.join("times.npy"),
        &Array1::from(series.times_s.clone()),
    )?;
    let pngs = figures::dynamics_figures(dir, maps, series, &dparams, &out.grid, name)?;
    let count = |code: u8| maps.vessel_class.iter().filter(|&&c| c == code).count();
    progress.report(&format!(
        "RI maps: heart rate {:.2} Hz ({}), {} cycle{}; {} arteriole, {} venule, {} undetermined pixels",
        maps.heart_rate_hz,
        match maps.cycle_source {
            dynamics::CycleSource::GivenRate => "given",
            dynamics::CycleSource::Triggers => "from the cardiac triggers",
            dynamics::CycleSource::TriggerPeriod => "from the cardiac triggers' period",
            dynamics::CycleSource::Upstrokes => "measured: systolic upstrokes",
            dynamics::CycleSource::Autocorrelation => "measured: autocorrelation",
        },
        maps.cycles.len(),
        if maps.cycles.len() == 1 { "" } else { "s" },
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

/// Each segment's clutter filter reports, per angle: one segment when the recording was processed
/// whole.
pub fn clutter_by_segment(processed: &Processed) -> Vec<&[ClutterReport]> {
    match &processed.segments {
        Some(done) => done.clutter.iter().map(Vec::as_slice).collect(),
        None => vec![processed.out.clutter.as_slice()],
    }
}

/// Every block's (low, high) clutter cut-offs when the filter worked block-wise, shape (segments,
/// angles, block rows, block columns, 2): `clutter_block_cut_offs.npy`. `clutter`: each segment's
/// reports, per angle ([`clutter_by_segment`]). `None` for a whole-image filter.
pub fn block_cut_offs(clutter: &[&[ClutterReport]]) -> Result<Option<ndarray::Array5<i64>>> {
    let Some(layout) = (clutter.iter().copied().flatten()).find_map(|c| c.block_layout.as_ref())
    else {
        return Ok(None);
    };
    let (rows, cols) = (layout.z_starts.len(), layout.x_starts.len());
    let angles = clutter.first().map_or(0, |per_angle| per_angle.len());
    let mut cut_offs = ndarray::Array5::<i64>::zeros((clutter.len(), angles, rows, cols, 2));
    for (s, per_angle) in clutter.iter().enumerate() {
        for (a, report) in per_angle.iter().enumerate() {
            if report.block_layout.as_ref() != Some(layout) || per_angle.len() != angles {
                anyhow::bail!("the segments' clutter filters used different blocks");
            }
            for (b, &(low, high)) in report.block_cut_offs.iter().enumerate() {
                cut_offs[[s, a, b / cols, b % cols, 0]] = low as i64;
                cut_offs[[s, a, b / cols, b % cols, 1]] = high as i64;
            }
        }
    }
    Ok(Some(cut_offs))
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
    npy(dir, "power_doppler.npy", &out.maps.power_doppler)?;
    npy(dir, "color_doppler.npy", &out.maps.color_doppler)?;
    npy(dir, "signed_power_doppler.npy", &out.signed_power_doppler())?;
    pcuvd_io::write_npy(&dir.join("projections.npy"), &out.maps.projections)?;
    pcuvd_io::write_npy(
        &dir.join("projection_nyquist.npy"),
        &out.maps.projection_nyquist,
    )?;
    if let (Some(ls), Some(irls)) = (&out.maps.vector_ls, &out.maps.vector_irls) {
        npy(dir, "vx.npy", &irls.vx)?;
        npy(dir, "vz.npy", &irls.vz)?;
        npy(dir, "speed.npy", &irls.speed())?;
        npy(dir, "vx_ls.npy", &ls.vx)?;
        npy(dir, "vz_ls.npy", &ls.vz)?;
        npy(dir, "speed_ls.npy", &ls.speed())?;
    }
    if let Some(done) = &out.maps.dealias {
        pcuvd_io::write_npy(&dir.join("alias_counts.npy"), &done.irls.alias_counts)?;
        pcuvd_io::write_npy(&dir.join("alias_counts_ls.npy"), &done.ls.alias_counts)?;
    }
    Ok(())
}
