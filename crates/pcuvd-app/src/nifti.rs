//! The maps and the Doppler time series as NIfTI-1 images (`.nii.gz`) with fUSI-BIDS (BEP040)
//! JSON sidecars: the form functional-ultrasound tools (ConfUSIus, nibabel, BIDS datasets) share
//! derived maps in.
//!
//! Voxel axes: i = lateral x, j = elevation (one plane), k = depth z, and for a time series
//! l = the ensembles. The affine (sform, "scanner" code) maps them to millimetres with depth
//! downwards: x = x₀ + i·Δx, y = 0, z = −(z₀ + k·Δz), so that viewers that show the superior
//! direction up show the probe at the top. Times are in seconds (`xyzt_units` mm and s).

use std::path::{Path, PathBuf};

use crate::input::RunInput;
use anyhow::{Context, Result, bail};
use ndarray::{Array2, Array3};
use pcuvd::pipeline::ProcessOutput;
use serde::Serialize;

use crate::map_kinds::map_kind;
use crate::run::{DynamicsOutcome, Plan, Processed};

/// How the files are named: pcuvd's map names, or BIDS entities.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct NiftiNaming {
    /// BIDS subject label (`sub-<label>`); `None` names files by pcuvd's map names.
    pub subject: Option<String>,
    /// BIDS session label (`ses-<label>`).
    pub session: Option<String>,
    /// BIDS task label (`task-<label>`).
    pub task: Option<String>,
}

impl NiftiNaming {
    /// The naming a front end's options ask for (`--nifti` or any BIDS label), checked; `None`
    /// when they ask for no NIfTI images.
    pub fn requested(
        nifti: bool,
        subject: Option<String>,
        session: Option<String>,
        task: Option<String>,
    ) -> Result<Option<NiftiNaming>> {
        if !(nifti || subject.is_some() || session.is_some() || task.is_some()) {
            return Ok(None);
        }
        let naming = NiftiNaming {
            subject,
            session,
            task,
        };
        naming.validate()?;
        Ok(Some(naming))
    }

    /// Checks that every label is BIDS's alphanumeric form and that a session or task comes with
    /// a subject.
    pub fn validate(&self) -> Result<()> {
        for (entity, label) in [
            ("--bids-subject", &self.subject),
            ("--bids-session", &self.session),
            ("--bids-task", &self.task),
        ] {
            if let Some(label) = label
                && (label.is_empty() || !label.chars().all(|c| c.is_ascii_alphanumeric()))
            {
                bail!("{entity} {label:?}: a BIDS label is letters and digits only");
            }
        }
        if self.subject.is_none() && (self.session.is_some() || self.task.is_some()) {
            bail!("--bids-session and --bids-task need --bids-subject (BIDS names start with it)");
        }
        Ok(())
    }

    /// The file stem of map `map` ([`MAPS`]).
    fn stem(&self, map: &BidsName) -> String {
        let Some(subject) = &self.subject else {
            return map.name.to_string();
        };
        let mut stem = format!("sub-{subject}");
        if let Some(session) = &self.session {
            stem.push_str(&format!("_ses-{session}"));
        }
        if let Some(task) = &self.task {
            stem.push_str(&format!("_task-{task}"));
        }
        if let Some(desc) = map.bids_desc {
            stem.push_str(&format!("_desc-{desc}"));
        }
        format!("{stem}_{}", map.bids_suffix)
    }
}

/// A map's BIDS name parts: pcuvd's name, its BIDS `desc` and suffix (its unit and meaning are
/// [`map_kind`]'s).
struct BidsName {
    name: &'static str,
    bids_desc: Option<&'static str>,
    bids_suffix: &'static str,
}

const fn bids(
    name: &'static str,
    bids_desc: Option<&'static str>,
    bids_suffix: &'static str,
) -> BidsName {
    BidsName {
        name,
        bids_desc,
        bids_suffix,
    }
}

/// Every map written, BIDS's `pwd` (power Doppler) suffix for the power maps; pcuvd's own
/// suffixes (`vel`, `ri`) and BIDS's `dseg` (a discrete segmentation) for the others.
const MAPS: [BidsName; 13] = [
    bids("power_doppler", None, "pwd"),
    bids("signed_power_doppler", Some("signed"), "pwd"),
    bids("color_doppler", Some("axial"), "vel"),
    bids("vx", Some("x"), "vel"),
    bids("vz", Some("z"), "vel"),
    bids("speed", Some("speed"), "vel"),
    bids("ri", None, "ri"),
    bids("vessel_class", Some("vessels"), "dseg"),
    bids("ensemble_power_doppler", Some("ensembles"), "pwd"),
    bids(
        "ensemble_signed_power_doppler",
        Some("ensemblesSigned"),
        "pwd",
    ),
    bids("ensemble_color_doppler", Some("ensemblesAxial"), "vel"),
    bids("ensemble_vx", Some("ensemblesX"), "vel"),
    bids("ensemble_vz", Some("ensemblesZ"), "vel"),
];

fn kind(name: &str) -> &'static BidsName {
    MAPS.iter()
        .find(|m| m.name == name)
        .expect("every written map is listed")
}

/// The NIfTI header every map shares: voxel sizes and the affine in mm, times in s.
fn header(out: &ProcessOutput, time_step_s: f64) -> nifti::NiftiHeader {
    let grid = &out.grid;
    let dx_mm = (grid.step() * 1e3) as f32;
    let dz_mm = (grid.axial_step() * 1e3) as f32;
    let x0_mm = (grid.x[0] * 1e3) as f32;
    let z0_mm = (grid.z[0] * 1e3) as f32;
    let mut header = nifti::NiftiHeader {
        pixdim: [1.0, dx_mm, 1.0, dz_mm, time_step_s as f32, 1.0, 1.0, 1.0],
        // NIFTI_UNITS_MM | NIFTI_UNITS_SEC.
        xyzt_units: 2 | 8,
        sform_code: 1,
        qform_code: 0,
        srow_x: [dx_mm, 0.0, 0.0, x0_mm],
        srow_y: [0.0, 1.0, 0.0, 0.0],
        srow_z: [0.0, 0.0, -dz_mm, -z0_mm],
        ..nifti::NiftiHeader::default()
    };
    header.descrip = format!("pcuvd {}", env!("CARGO_PKG_VERSION")).into_bytes();
    header
}

/// A (nz, nx) map as NIfTI's (i = x, j = 1, k = z) volume.
fn volume<A: Copy>(map: &Array2<A>) -> ndarray16::Array3<A> {
    let (nz, nx) = map.dim();
    ndarray16::Array3::from_shape_fn((nx, 1, nz), |(ix, _, iz)| map[[iz, ix]])
}

/// An (ensembles, nz, nx) series as NIfTI's (i = x, j = 1, k = z, l = time) volume.
fn series(maps: &Array3<f64>) -> ndarray16::Array4<f32> {
    let (nt, nz, nx) = maps.dim();
    ndarray16::Array4::from_shape_fn((nx, 1, nz, nt), |(ix, _, iz, it)| maps[[it, iz, ix]] as f32)
}

/// A BEP040 JSON sidecar: the fUSI-BIDS fields pcuvd knows of a run, in BEP040's units (MHz, mm,
/// Hz, degrees, ms, s), and what the image beside it holds.
#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "PascalCase")]
struct Sidecar {
    /// Probe centre frequency (MHz); the probe's fields are absent for images formed elsewhere.
    #[serde(skip_serializing_if = "Option::is_none")]
    probe_central_frequency: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    probe_number_of_elements: Option<usize>,
    /// Element pitch (mm).
    #[serde(skip_serializing_if = "Option::is_none")]
    probe_pitch: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    probe_type: Option<&'static str>,
    /// Depths of the first and last rows (mm).
    depth: [f64; 2],
    /// Transmit events per second (Hz); absent for images formed elsewhere.
    #[serde(skip_serializing_if = "Option::is_none")]
    ultrasound_pulse_repetition_frequency: Option<f64>,
    /// Plane-wave angles (degrees).
    plane_wave_angles: Vec<f64>,
    /// Compound frames per second (Hz).
    compound_sampling_frequency: f64,
    /// Frames one clutter filter saw (ms).
    clutter_filter_window_duration: f64,
    clutter_filters: Vec<ClutterFilter>,
    /// Frames one power Doppler map integrates (ms).
    power_doppler_integration_duration: f64,
    /// Speed of sound (m/s).
    sound_speed: f64,
    /// Absent for images formed elsewhere.
    #[serde(skip_serializing_if = "Option::is_none")]
    transmit_coding: Option<&'static str>,
    software_versions: String,
    /// A time series' step between images (s).
    #[serde(skip_serializing_if = "Option::is_none")]
    repetition_time: Option<f64>,
    /// A time series' clutter cut-offs, per ensemble and angle (low, high).
    #[serde(skip_serializing_if = "Option::is_none")]
    clutter_cutoffs_per_ensemble: Option<Vec<Vec<(usize, usize)>>>,
    /// When a time series' first image's centre lies after the recording's first frame (s).
    #[serde(skip_serializing_if = "Option::is_none")]
    delay_after_trigger: Option<f64>,
    units: &'static str,
    description: &'static str,
    sources: Vec<String>,
}

/// One clutter filter of a BEP040 sidecar: SVD, with its cut-offs when they are one pair.
#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "PascalCase")]
struct ClutterFilter {
    filter_type: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    low_threshold: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    high_threshold: Option<usize>,
}

/// The sidecar fields of a run whose clutter filter saw `integration_frames` frames, with the
/// whole recording's clutter filter (its first angle's cut-offs).
fn acquisition_fields(
    input: RunInput<'_>,
    out: &ProcessOutput,
    integration_frames: usize,
) -> Sidecar {
    let frame_rate = input.frame_rate();
    let window_ms = integration_frames as f64 / frame_rate * 1e3;
    let (probe, sequence, sound_speed, angles) = match input {
        RunInput::Recording(data) => {
            let acq = data.acquisition();
            (
                Some(&acq.probe),
                Some(&acq.sequence),
                acq.sound_speed,
                acq.sequence.angles.clone(),
            )
        }
        RunInput::Images(images) => (
            None,
            None,
            images.sound_speed_m_s,
            images.angles_deg.iter().map(|a| a.to_radians()).collect(),
        ),
    };
    Sidecar {
        probe_central_frequency: probe.map(|p| p.center_frequency * 1e-6),
        probe_number_of_elements: probe.map(|p| p.n_elements),
        probe_pitch: probe.map(|p| p.pitch * 1e3),
        probe_type: probe.map(|_| "linear"),
        depth: [out.grid.z[0] * 1e3, out.grid.z[out.grid.z.len() - 1] * 1e3],
        ultrasound_pulse_repetition_frequency: sequence.map(|seq| seq.event_prf),
        plane_wave_angles: angles.iter().map(|a| a.to_degrees()).collect(),
        compound_sampling_frequency: frame_rate,
        clutter_filter_window_duration: window_ms,
        // A block-wise filter's thresholds differ from block to block: summary.json lists them.
        clutter_filters: (out.clutter.first().iter())
            .map(|c| match c.block_cut_offs.is_empty() {
                true => ClutterFilter {
                    filter_type: "Index-based SVD",
                    low_threshold: Some(c.low),
                    high_threshold: Some(c.high),
                },
                false => ClutterFilter {
                    filter_type: "Index-based SVD, block-wise",
                    low_threshold: None,
                    high_threshold: None,
                },
            })
            .collect(),
        power_doppler_integration_duration: window_ms,
        sound_speed,
        transmit_coding: sequence.map(|seq| if seq.is_coded() { "hadamard" } else { "none" }),
        software_versions: format!("pcuvd {}", env!("CARGO_PKG_VERSION")),
        repetition_time: None,
        clutter_cutoffs_per_ensemble: None,
        delay_after_trigger: None,
        units: "",
        description: "",
        sources: vec![],
    }
}

/// Writes one image and its sidecar; returns the image's path.
fn write_one<A, D>(
    dir: &Path,
    naming: &NiftiNaming,
    map: &BidsName,
    image: &ndarray16::Array<A, D>,
    header: &nifti::NiftiHeader,
    mut sidecar: Sidecar,
) -> Result<PathBuf>
where
    A: nifti::DataElement + bytemuck::Pod,
    D: ndarray16::Dimension + ndarray16::RemoveAxis,
{
    let stem = naming.stem(map);
    let path = dir.join(format!("{stem}.nii.gz"));
    nifti::writer::WriterOptions::new(&path)
        .reference_header(header)
        .write_nifti(image)
        .with_context(|| format!("{}: cannot write the NIfTI image", path.display()))?;
    let described = map_kind(map.name);
    sidecar.units = described.units;
    sidecar.description = described.description;
    sidecar.sources = vec![format!("pcuvd:{}", map.name)];
    pcuvd_io::write_json(&dir.join(format!("{stem}.json")), &sidecar)?;
    Ok(path)
}

/// Writes the maps (power, signed power, colour, the vector components, RI and vessel classes
/// when the stages made them) and the ensembles' time series as NIfTI images with BEP040
/// sidecars into `dir`. Returns the images written.
pub fn write_nifti(
    dir: &Path,
    input: RunInput<'_>,
    plan: &Plan,
    processed: &Processed,
    naming: &NiftiNaming,
) -> Result<Vec<PathBuf>> {
    naming.validate()?;
    let out = &processed.out;
    let frame_rate = input.frame_rate();
    let still = header(out, 0.0);
    let fields = acquisition_fields(input, out, input.n_frames());
    let mut written = Vec::new();
    let mut maps: Vec<(&str, Array2<f64>)> = vec![
        ("power_doppler", out.maps.power_doppler.clone()),
        ("signed_power_doppler", out.signed_power_doppler()),
        ("color_doppler", out.maps.color_doppler.clone()),
    ];
    if let Some(irls) = &out.maps.vector_irls {
        maps.push(("vx", irls.vx.clone()));
        maps.push(("vz", irls.vz.clone()));
        maps.push(("speed", irls.speed()));
    }
    if let DynamicsOutcome::Done { maps: ri, .. } = &processed.dynamics {
        maps.push(("ri", ri.ri.clone()));
        let classes = volume(&ri.vessel_class);
        written.push(write_one(
            dir,
            naming,
            kind("vessel_class"),
            &classes,
            &still,
            fields.clone(),
        )?);
    }
    for (name, values) in maps {
        let image = volume(&values.mapv(|v| v as f32));
        written.push(write_one(
            dir,
            naming,
            kind(name),
            &image,
            &still,
            fields.clone(),
        )?);
    }
    // Ensembles that went to a Zarr store as the run went are there only.
    if let (Some(ensembles), Some(spec), false) = (
        &processed.ensembles,
        plan.ensembles,
        processed.ensembles_in_store,
    ) {
        let step_s = spec.step as f64 / frame_rate;
        let timed = header(out, step_s);
        let mut fields = acquisition_fields(input, out, spec.frames);
        // Ensembles are evenly spaced: RepetitionTime says when each starts after the first,
        // DelayAfterTrigger when the first one's centre lies after the recording's first frame.
        fields.repetition_time = Some(step_s);
        // Each ensemble has its own SVD cut-offs (one pair per angle; a block-wise filter's are
        // its blocks' medians).
        let block_wise = (ensembles.clutter.iter().flatten()).any(|c| c.block_low_range.is_some());
        fields.clutter_filters = vec![ClutterFilter {
            filter_type: if block_wise {
                "Index-based SVD, block-wise, per ensemble"
            } else {
                "Index-based SVD, per ensemble"
            },
            low_threshold: None,
            high_threshold: None,
        }];
        fields.clutter_cutoffs_per_ensemble = Some(
            (ensembles.clutter.iter())
                .map(|per_angle| per_angle.iter().map(|c| (c.low, c.high)).collect())
                .collect(),
        );
        fields.delay_after_trigger = Some(ensembles.times_s.first().copied().unwrap_or(0.0));
        let mut series_maps: Vec<(&str, Array3<f64>)> = vec![
            ("ensemble_power_doppler", ensembles.power_doppler.clone()),
            (
                "ensemble_signed_power_doppler",
                ensembles.signed_power_doppler(),
            ),
            ("ensemble_color_doppler", ensembles.color_doppler.clone()),
        ];
        if let (Some(vx), Some(vz)) = (&ensembles.vx, &ensembles.vz) {
            series_maps.push(("ensemble_vx", vx.clone()));
            series_maps.push(("ensemble_vz", vz.clone()));
        }
        for (name, values) in series_maps {
            let image = series(&values);
            written.push(write_one(
                dir,
                naming,
                kind(name),
                &image,
                &timed,
                fields.clone(),
            )?);
        }
    }
    Ok(written)
}
