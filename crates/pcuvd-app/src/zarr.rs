//! The run as one Zarr v3 store (`pcuvd.zarr`), the form functional-ultrasound tools (ConfUSIus,
//! xarray + Dask) keep long series in: chunked arrays with named dimensions, opened lazily by
//! `zarr` ≥ 3 and `xarray.open_zarr` without pcuvd installed.
//!
//! - Maps: `(z, x)`; the Doppler time series: `(time, z, x)`, one step per ensemble, `time` its
//!   centre; the dynamics stage's velocity windows: `(window_time, z, x)`. Coordinates `z`, `x`
//!   (m), `time`, `window_time` (s from the first frame) are arrays of the same names, so xarray
//!   indexes by them. The sites' spectrograms (`--sites`): `(site, site_time,
//!   site_velocity_bin)`, each site's velocity axis `(site, site_velocity_bin)` (each site has
//!   its own echo frequency), its mean velocity `(site, site_time)`, coordinate `site_time`.
//! - Values are float32 (seven significant digits, far finer than any estimate's spread: the
//!   `.npy` maps keep float64), gzip-compressed; vessel classes are uint8. Every array carries
//!   `units` and `long_name`; the store's attributes hold the acquisition under ConfUSIus's names
//!   where they exist (`compound_sampling_frequency`, `transmit_frequency`,
//!   `beamforming_sound_velocity`) and pcuvd's processing options.
//! - A segmented run appends each segment's ensembles as the segment finishes ([`EnsembleSink`]),
//!   so a long recording's series are never in memory whole. The metadata is consolidated into
//!   the root group last: a store without it is visibly incomplete.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::input::RunInput;
use anyhow::{Context, Result};
use ndarray::{Array2, Array3, ArrayView3};
use pcuvd::pipeline::ensembles::EnsembleMaps;
use pcuvd::pipeline::segments::EnsembleSink;
use serde_json::{Map, Value, json};
use zarrs::array::ArraySubset;
use zarrs::array::{Array, ArrayBuilder, DataType, data_type};
use zarrs::filesystem::FilesystemStore;
use zarrs::group::GroupBuilder;

use crate::map_kinds::{MapKind, map_kind};
use crate::run::{DynamicsOutcome, Plan, Processed};
use crate::sites::SiteSpectrograms;

/// The store's folder name in a run's output folder.
pub const STORE: &str = "pcuvd.zarr";

/// Bytes of one time-series chunk (about): large enough that a long series is not millions of
/// files, small enough that reading one ensemble reads little else.
const CHUNK_BYTES: usize = 4 << 20;

/// A run's Zarr store, open for writing: created before the run, fed the ensembles as they come,
/// finished with the maps.
pub struct ZarrStore {
    path: PathBuf,
    store: Arc<FilesystemStore>,
    /// Rows (z) and columns (x) of every map.
    grid: (usize, usize),
    /// The time series' arrays (the `time` coordinate first), made by the first ensembles.
    series: Vec<Array<FilesystemStore>>,
}

/// The time series' arrays after `time`, in [`series_views`]' order (Vx, Vz only with two or
/// more angles).
const SERIES: [&str; 5] = [
    "ensemble_power_doppler",
    "ensemble_signed_power_doppler",
    "ensemble_color_doppler",
    "ensemble_vx",
    "ensemble_vz",
];

/// An ensemble part's series in [`SERIES`] order, the signed power (computed) given apart.
fn series_views<'a>(part: &'a EnsembleMaps, signed: &'a Array3<f64>) -> Vec<ArrayView3<'a, f64>> {
    let mut views = vec![
        part.power_doppler.view(),
        signed.view(),
        part.color_doppler.view(),
    ];
    views.extend(part.vx.as_ref().map(|v| v.view()));
    views.extend(part.vz.as_ref().map(|v| v.view()));
    views
}

fn as_f32(values: impl IntoIterator<Item = f64>) -> Vec<f32> {
    values.into_iter().map(|v| v as f32).collect()
}

/// Row-major float32 values of a (t, z, x) block.
fn block_f32(values: ArrayView3<f64>) -> Vec<f32> {
    as_f32(values.as_standard_layout().iter().copied())
}

impl ZarrStore {
    /// Creates the store at `path` (a folder that must not exist yet) for a run of `input` as
    /// `plan` says: the root group with the acquisition's attributes (what images formed
    /// elsewhere give of it) and the `z`, `x` coordinates.
    pub fn create(path: &Path, input: RunInput<'_>, plan: &Plan) -> Result<ZarrStore> {
        let context = || format!("{}: cannot create the Zarr store", path.display());
        if path.exists() {
            anyhow::bail!(
                "{}: already exists; the store is written new",
                path.display()
            );
        }
        std::fs::create_dir_all(path).with_context(context)?;
        let store = Arc::new(FilesystemStore::new(path).with_context(context)?);
        let grid = &plan.params.grid;
        let zarr = ZarrStore {
            path: path.to_path_buf(),
            store,
            grid: (grid.z.len(), grid.x.len()),
            series: Vec::new(),
        };
        zarr.write_group(attributes(input, plan), None)?;
        zarr.write_coordinate(&MapKind::new("z", "m", "depth below the probe"), &grid.z)?;
        zarr.write_coordinate(&MapKind::new("x", "m", "lateral position"), &grid.x)?;
        Ok(zarr)
    }

    fn write_group(
        &self,
        attributes: Map<String, Value>,
        consolidated: Option<
            zarrs::metadata_ext::group::consolidated_metadata::ConsolidatedMetadata,
        >,
    ) -> Result<()> {
        let mut group = GroupBuilder::new()
            .attributes(attributes)
            .build(self.store.clone(), "/")
            .context("the store's root group")?;
        group.set_consolidated_metadata(consolidated);
        group
            .store_metadata()
            .with_context(|| format!("{}: cannot write the store's metadata", self.path.display()))
    }

    /// A new array `what` of `shape`, chunked by `chunks`, with named `dimensions`.
    fn new_array(
        &self,
        what: &MapKind,
        shape: Vec<u64>,
        chunks: Vec<u64>,
        dimensions: &[&str],
        data_type: DataType,
        fill: impl Into<zarrs::array::builder::ArrayBuilderFillValue>,
    ) -> Result<Array<FilesystemStore>> {
        let mut attributes = Map::new();
        attributes.insert("units".into(), what.units.into());
        attributes.insert("long_name".into(), what.description.into());
        let gzip = zarrs::array::codec::GzipCodec::new(5).context("gzip level")?;
        let array = ArrayBuilder::new(shape, chunks, data_type, fill)
            .dimension_names(Some(dimensions.to_vec()))
            .bytes_to_bytes_codecs(vec![Arc::new(gzip)])
            .attributes(attributes)
            .build(self.store.clone(), &format!("/{}", what.name))
            .with_context(|| format!("the store's array {}", what.name))?;
        array
            .store_metadata()
            .with_context(|| format!("{}: cannot write {}", self.path.display(), what.name))?;
        Ok(array)
    }

    fn store<'a>(
        &self,
        array: &Array<FilesystemStore>,
        ranges: &[std::ops::Range<u64>],
        values: impl zarrs::array::IntoArrayBytes<'a>,
    ) -> Result<()> {
        array
            .store_array_subset(&ArraySubset::new_with_ranges(ranges), values)
            .with_context(|| format!("{}: cannot write {}", self.path.display(), array.path()))
    }

    fn write_coordinate(&self, what: &MapKind, values: &[f64]) -> Result<()> {
        let n = values.len() as u64;
        let array = self.new_array(
            what,
            vec![n],
            vec![n.max(1)],
            &[what.name],
            data_type::float64(),
            0.0f64,
        )?;
        self.store(&array, std::slice::from_ref(&(0..n)), values)
    }

    /// Writes a (z, x) map as float32.
    fn write_map(&self, what: &MapKind, values: &Array2<f64>) -> Result<()> {
        self.write_whole(what, values.shape(), &["z", "x"], values.iter().copied())
    }

    /// Writes an array of float32 `values` (row-major, of `shape`) along `dimensions`, one chunk.
    fn write_whole(
        &self,
        what: &MapKind,
        shape: &[usize],
        dimensions: &[&str],
        values: impl Iterator<Item = f64>,
    ) -> Result<()> {
        let shape: Vec<u64> = shape.iter().map(|&n| n as u64).collect();
        let chunks = shape.iter().map(|&n| n.max(1)).collect();
        let array = self.new_array(
            what,
            shape.clone(),
            chunks,
            dimensions,
            data_type::float32(),
            f32::NAN,
        )?;
        let ranges: Vec<std::ops::Range<u64>> = shape.iter().map(|&n| 0..n).collect();
        self.store(&array, &ranges, as_f32(values))
    }

    /// Writes the sites' spectrograms, their velocity axes and mean velocities, on the
    /// [`crate::sites::TIME_COORDINATE`] coordinate (the windows' centres).
    fn write_sites(&self, sites: &SiteSpectrograms) -> Result<()> {
        let time = MapKind::new(
            crate::sites::TIME_COORDINATE,
            "s",
            "centre time of each spectrogram window from the first frame",
        );
        self.write_coordinate(&time, &sites.times_s)?;
        for array in sites.arrays(|name| name != "site_times") {
            self.write_whole(
                map_kind(array.name),
                array.values.shape(),
                array.dimensions,
                array.values.iter().copied(),
            )?;
        }
        Ok(())
    }

    /// Ensembles of one chunk: about [`CHUNK_BYTES`] of float32 maps.
    fn time_chunk(&self) -> u64 {
        let (nz, nx) = self.grid;
        (CHUNK_BYTES / (4 * nz * nx).max(1)).max(1) as u64
    }

    /// A time series of `count` steps along `time` (its coordinate first, then `arrays`), empty.
    fn new_series(
        &self,
        time: &MapKind,
        arrays: &[&MapKind],
    ) -> Result<Vec<Array<FilesystemStore>>> {
        let (nz, nx) = (self.grid.0 as u64, self.grid.1 as u64);
        let chunk = self.time_chunk();
        let mut made = vec![self.new_array(
            time,
            vec![0],
            vec![4096],
            &[time.name],
            data_type::float64(),
            0.0f64,
        )?];
        for what in arrays {
            made.push(self.new_array(
                what,
                vec![0, nz, nx],
                vec![chunk, nz.max(1), nx.max(1)],
                &[time.name, "z", "x"],
                data_type::float32(),
                f32::NAN,
            )?);
        }
        Ok(made)
    }

    /// Appends `times` (s) and one (t, z, x) block per array of `series` (its coordinate first).
    fn append_to(
        &self,
        series: &mut [Array<FilesystemStore>],
        start: u64,
        times: &[f64],
        blocks: &[ArrayView3<f64>],
    ) -> Result<()> {
        let count = times.len() as u64;
        let end = start + count;
        let (nz, nx) = (self.grid.0 as u64, self.grid.1 as u64);
        let (time, maps) = series
            .split_first_mut()
            .context("a series without its time")?;
        time.set_shape(vec![end]).context("growing the time axis")?;
        time.store_metadata().context("the time axis' metadata")?;
        self.store(time, std::slice::from_ref(&(start..end)), times)?;
        for (array, block) in maps.iter_mut().zip(blocks) {
            if block.dim() != (times.len(), self.grid.0, self.grid.1) {
                anyhow::bail!(
                    "{}: a block of {:?} for {} times",
                    array.path(),
                    block.dim(),
                    times.len()
                );
            }
            array
                .set_shape(vec![end, nz, nx])
                .context("growing a series")?;
            array.store_metadata().context("a series' metadata")?;
            self.store(array, &[start..end, 0..nz, 0..nx], block_f32(block.view()))?;
        }
        Ok(())
    }

    /// Appends the next ensembles of the run's Doppler time series (recording order).
    fn append_ensembles(&mut self, part: &EnsembleMaps) -> Result<()> {
        let signed = part.signed_power_doppler();
        let views = series_views(part, &signed);
        if self.series.is_empty() {
            let time = MapKind::new(
                "time",
                "s",
                "centre time of each ensemble from the first frame",
            );
            let arrays: Vec<&MapKind> = SERIES
                .iter()
                .take(views.len())
                .map(|n| map_kind(n))
                .collect();
            self.series = self.new_series(&time, &arrays)?;
        }
        if self.series.len() != views.len() + 1 {
            anyhow::bail!("ensembles with and without vector maps in one run");
        }
        // Ensembles written so far: the time axis' length.
        let written = self.series[0].shape()[0];
        let mut series = std::mem::take(&mut self.series);
        let done = self.append_to(&mut series, written, &part.times_s, &views);
        self.series = series;
        done
    }

    /// Writes the run's maps (those the stages made), its ensembles when they did not come as
    /// the run went, the dynamics stage's velocity windows and the `sites`' spectrograms; then
    /// consolidates the metadata.
    /// Returns the store's folder.
    pub fn finish(
        mut self,
        input: RunInput<'_>,
        plan: &Plan,
        processed: &Processed,
        sites: Option<&SiteSpectrograms>,
    ) -> Result<PathBuf> {
        let out = &processed.out;
        let maps = &out.maps;
        self.write_map(map_kind("bmode_db"), &out.bmode_db)?;
        self.write_map(map_kind("power_doppler"), &maps.power_doppler)?;
        self.write_map(
            map_kind("signed_power_doppler"),
            &out.signed_power_doppler(),
        )?;
        self.write_map(map_kind("color_doppler"), &maps.color_doppler)?;
        if let Some(irls) = &maps.vector_irls {
            self.write_map(map_kind("vx"), &irls.vx)?;
            self.write_map(map_kind("vz"), &irls.vz)?;
            self.write_map(map_kind("speed"), &irls.speed())?;
        }
        if let DynamicsOutcome::Done { series, maps: ri } = &processed.dynamics {
            self.write_map(map_kind("ri"), &ri.ri)?;
            self.write_map(map_kind("psv"), &ri.psv)?;
            self.write_map(map_kind("edv"), &ri.edv)?;
            let classes = map_kind("vessel_class");
            let (nz, nx) = (
                ri.vessel_class.nrows() as u64,
                ri.vessel_class.ncols() as u64,
            );
            let array = self.new_array(
                classes,
                vec![nz, nx],
                vec![nz.max(1), nx.max(1)],
                &["z", "x"],
                data_type::uint8(),
                0u8,
            )?;
            let values: Vec<u8> = ri.vessel_class.iter().copied().collect();
            self.store(&array, &[0..nz, 0..nx], values)?;
            let time = MapKind::new(
                "window_time",
                "s",
                "centre time of each velocity window from the first frame",
            );
            // One angle's windows hold no lateral velocity: no array of NaN stands for it.
            let vx = (!series.axial_only).then_some(("window_vx", series.vx.view()));
            let (names, views): (Vec<&str>, Vec<_>) = vx
                .into_iter()
                .chain([
                    ("window_vz", series.vz.view()),
                    ("window_power", series.power.view()),
                ])
                .unzip();
            let arrays: Vec<&MapKind> = names.iter().map(|n| map_kind(n)).collect();
            let mut windows = self.new_series(&time, &arrays)?;
            self.append_to(&mut windows, 0, &series.times_s, &views)?;
        }
        if !processed.ensembles_in_store
            && let Some(ensembles) = &processed.ensembles
        {
            self.append_ensembles(ensembles)?;
        }
        if let Some(sites) = sites {
            self.write_sites(sites)?;
        }
        let node = zarrs::node::Node::open(&self.store, "/").context("reading the store back")?;
        let consolidated = node.consolidate_metadata().map(|metadata| {
            zarrs::metadata_ext::group::consolidated_metadata::ConsolidatedMetadata {
                metadata,
                ..Default::default()
            }
        });
        self.write_group(attributes(input, plan), consolidated)?;
        Ok(self.path)
    }
}

impl EnsembleSink for ZarrStore {
    fn append(&mut self, part: &EnsembleMaps) -> pcuvd::core::error::Result<()> {
        self.append_ensembles(part)
            .map_err(|e| pcuvd::core::error::Error::Write(format!("{e:#}")))
    }
}

/// The store's attributes: the acquisition (ConfUSIus's names where they exist, SI units, the
/// unit of each in `units`) and pcuvd's processing.
fn attributes(input: RunInput<'_>, plan: &Plan) -> Map<String, Value> {
    let mut values = match input {
        RunInput::Recording(data) => {
            let acq = data.acquisition();
            let angles: Vec<f64> = acq.sequence.angles.iter().map(|a| a.to_degrees()).collect();
            json!({
                "compound_sampling_frequency": acq.frame_rate(),
                "transmit_frequency": acq.probe.center_frequency,
                "beamforming_sound_velocity": acq.sound_speed,
                "pulse_repetition_frequency": acq.sequence.event_prf,
                "plane_wave_angles": angles,
                "probe_number_of_elements": acq.probe.n_elements,
                "probe_pitch": acq.probe.pitch,
                "transmit_coding": if acq.sequence.is_coded() { "hadamard" } else { "none" },
                "frames": data.n_frames(),
                "units": {
                    "compound_sampling_frequency": "Hz",
                    "transmit_frequency": "Hz",
                    "beamforming_sound_velocity": "m/s",
                    "pulse_repetition_frequency": "Hz",
                    "plane_wave_angles": "degree",
                    "probe_pitch": "m",
                },
            })
        }
        // Images formed elsewhere give no probe or transmit sequence: only what they hold.
        RunInput::Images(images) => json!({
            "compound_sampling_frequency": images.frame_rate_hz,
            "demodulation_frequency": images.demod_frequency_hz,
            "beamforming_sound_velocity": images.sound_speed_m_s,
            "plane_wave_angles": images.angles_deg,
            "frames": images.frames,
            "formed": images.formed,
            "units": {
                "compound_sampling_frequency": "Hz",
                "demodulation_frequency": "Hz",
                "beamforming_sound_velocity": "m/s",
                "plane_wave_angles": "degree",
            },
        }),
    };
    values["processing_options"] = json!(plan.options_text);
    values["software"] = json!(format!("pcuvd {}", env!("CARGO_PKG_VERSION")));
    match values {
        Value::Object(map) => map,
        _ => unreachable!("a JSON object literal"),
    }
}

/// The arrays of the store at `path`, by name, sorted.
pub fn arrays(path: &Path) -> Result<Vec<String>> {
    let mut names: Vec<String> = std::fs::read_dir(path)
        .with_context(|| format!("{}: cannot list the store", path.display()))?
        .filter_map(|e| e.ok())
        .filter(|e| e.path().join("zarr.json").is_file())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    Ok(names)
}

/// Draws `ensembles.png` into `dir` from the Doppler time series the store at `path` holds (at
/// `timeline`'s times), reading a run of ensembles at a time: a long series is drawn in bounded
/// memory, as it was written.
pub fn draw_ensembles(
    path: &Path,
    dir: &Path,
    out: &pcuvd::pipeline::ProcessOutput,
    timeline: &EnsembleMaps,
    name: &str,
) -> Result<PathBuf> {
    let (_, nz, nx) = timeline.power_doppler.dim();
    let count = timeline.times_s.len();
    let store = Arc::new(
        FilesystemStore::new(path)
            .with_context(|| format!("{}: cannot open the Zarr store", path.display()))?,
    );
    let open = |name: &str| -> Result<Array<FilesystemStore>> {
        let array = Array::open(store.clone(), &format!("/{name}"))
            .with_context(|| format!("{}: no array {name}", path.display()))?;
        if array.shape() != [count as u64, nz as u64, nx as u64] {
            anyhow::bail!(
                "{}: {name} is {:?}, not ({count}, {nz}, {nx})",
                path.display(),
                array.shape()
            );
        }
        Ok(array)
    };
    let power = open("ensemble_power_doppler")?;
    let vectors = match timeline.vx.is_some() {
        true => Some((open("ensemble_vx")?, open("ensemble_vz")?)),
        false => None,
    };
    let read =
        |array: &Array<FilesystemStore>, range: &std::ops::Range<usize>| -> Result<Array3<f64>> {
            let subset = ArraySubset::new_with_ranges(&[
                range.start as u64..range.end as u64,
                0..nz as u64,
                0..nx as u64,
            ]);
            let values: Vec<f32> = array
                .retrieve_array_subset(&subset)
                .with_context(|| format!("{}: cannot read {}", path.display(), array.path()))?;
            Ok(Array3::from_shape_vec((range.len(), nz, nx), values)?.mapv(f64::from))
        };
    crate::figures::ensemble_figure_in_chunks(dir, out, &timeline.times_s, name, &mut |range| {
        let speed = match &vectors {
            Some((vx, vz)) => {
                let (vx, vz) = (read(vx, &range)?, read(vz, &range)?);
                Some(
                    ndarray::Zip::from(&vx)
                        .and(&vz)
                        .map_collect(|&x, &z| x.hypot(z)),
                )
            }
            None => None,
        };
        Ok((read(&power, &range)?, speed))
    })
}
