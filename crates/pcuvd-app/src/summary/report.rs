//! `report.html`: a run of `process` on one self-contained page for a person: what was read and
//! how it was processed in a few lines, the scores against a simulation's truth, every figure
//! with what it shows, where the time went, and summary.json in full.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use pcuvd_render::Report;

use super::{CodeRecord, DynamicsRecord, Summary};

/// The report's file name.
pub const REPORT: &str = "report.html";

/// What a figure of `process` shows, by its file name; `None` for a name it does not write.
pub fn caption(file: &str) -> Option<&'static str> {
    Some(match file {
        "bmode.png" => {
            "B-mode of the compounded series before the clutter filter (dB re its brightest pixel)."
        }
        "power_doppler.png" => {
            "Power Doppler of the clutter-filtered series (dB re its 99.9th percentile)."
        }
        "signed_power_doppler.png" => {
            "Signed power Doppler: brightness is the power's level above −40 dB re peak, hue its axial direction (red toward the probe)."
        }
        "color_doppler.png" => {
            "Colour Doppler: the axial velocity, red toward the probe, drawn where the power shows flow (summary.json's figures.flow_rule); the .npy map counts + away."
        }
        "vector.png" => {
            "Vector Doppler: speed (colour) and direction (triangles) by least squares (UVD) and by IRLS (PC-UVD's estimator), where the power is within 15 dB of its peak."
        }
        "dealias.png" => {
            "Where dealiasing unwrapped: each pixel's alias count averaged over its angles, for UVD and PC-UVD."
        }
        "clutter_blocks.png" => {
            "The block-wise clutter filter: the B-mode beside the tissue components cut at each pixel."
        }
        "ri.png" => {
            "Resistivity index over the cardiac cycle, and the arterioles and venules it classes (PSV, signed by the flow's direction)."
        }
        "waveform.png" => {
            "Mean vessel speed over the recording, with the cardiac cycles the RI maps used."
        }
        "ensembles.png" => {
            "The Doppler time series: its mean, how much it varies, and its mean over the vessels, ensemble by ensemble."
        }
        crate::sites::FIGURE => {
            "The flow over time at the sites asked for (--sites): each one's compounded Doppler spectrogram (axial velocity, + = deeper, at the pixel's mean RF frequency as the colour Doppler reads it; grey, dB re its own maximum; its title gives the pixel's power Doppler re the map's peak and that frequency) with its mean Doppler velocity (dashed white) and, where the dynamics stage ran, the vector fit's axial velocity in each window (cyan); the power Doppler marks where each site lies."
        }
        crate::against_truth::FIGURE => {
            "Against the simulation's truth: the true speed averaged over the recording beside the estimate's, and the vector error over the vessel pixels (RI too when it was scored)."
        }
        _ => return None,
    })
}

/// Writes `report.html` into `dir` for the run that `summary` describes, with the `figures` it
/// drew (PNG files, embedded in the page).
pub fn write_report(dir: &Path, summary: &Summary, figures: &[PathBuf]) -> Result<PathBuf> {
    let name = Path::new(&summary.source.input)
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| summary.source.input.clone());
    let mut report = Report::new(&format!("{name}: pcuvd process"));
    report.paragraph(&recording_line(summary));
    report.paragraph(&processing_line(summary));
    if let DynamicsRecord::Done(done) = &summary.dynamics {
        report.paragraph(&format!(
            "RI maps{} over {} cardiac cycle{} at {:.2} Hz{}: {}.",
            if done.axial_only {
                " of the colour-Doppler speed (one steering angle: vessels across the beam are \
                 undetermined)"
            } else {
                ""
            },
            done.cycles_count,
            if done.cycles_count == 1 { "" } else { "s" },
            done.heart_rate_hz,
            if done.heart_rate_given {
                " (given)"
            } else {
                ""
            },
            done.cycles_from
        ));
    }
    if let DynamicsRecord::Failed { failed } = &summary.dynamics {
        report.paragraph(&format!(
            "No RI maps: the dynamics settings asked for them and the recording could not give \
             them ({failed}). The run ended in that error; its other maps are here."
        ));
    }
    if let Some(scored) = &summary.against_truth {
        report.heading("Against the simulation's truth");
        let line = scored.line();
        let mut letters = line.chars();
        let capitalised: String = (letters.next().map(|c| c.to_ascii_uppercase()).into_iter())
            .chain(letters)
            .collect();
        report.paragraph(&format!("{capitalised}."));
    }
    report.heading("Figures");
    for figure in figures {
        let file = figure
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let png = std::fs::read(figure)
            .with_context(|| format!("{}: cannot read it for the report", figure.display()))?;
        report.image_png(caption(&file).unwrap_or(&file), &png);
    }
    report.heading("Where the time went");
    let rows: Vec<Vec<String>> = summary
        .timings_s
        .iter()
        .map(|(stage, seconds)| vec![stage.replace('_', " "), format!("{seconds:.2}")])
        .collect();
    report.table(&["stage", "seconds"], &rows);
    report.heading("Every parameter and where it came from (summary.json)");
    report.preformatted(&serde_json::to_string_pretty(summary)?);
    let path = dir.join(REPORT);
    crate::figures::write_file(&path, report.to_html().as_bytes())?;
    Ok(path)
}

/// What was read: the input, its format, angles, frames and Nyquist velocity.
fn recording_line(summary: &Summary) -> String {
    let angles_span = |angles: &[f64]| {
        let span = match (angles.first(), angles.last()) {
            (Some(first), Some(last)) if angles.len() > 1 => {
                format!(" from {first:.1}° to {last:.1}°")
            }
            (Some(only), _) => format!(" at {only:.1}°"),
            _ => String::new(),
        };
        format!(
            "{} plane-wave angle{}{span}",
            angles.len(),
            if angles.len() == 1 { "" } else { "s" }
        )
    };
    let read = match (&summary.acquisition, &summary.probe, &summary.images) {
        (Some(acq), Some(probe), _) => format!(
            "{}, {}, {} compound frames at {:.1} Hz; probe {} ({} elements, {:.2} MHz)",
            angles_span(&acq.angles_deg),
            match &acq.coding.code {
                CodeRecord::None => "one angle per event",
                CodeRecord::Hadamard { .. } => "Hadamard-coded",
                CodeRecord::Matrix { .. } => "coded by a code matrix",
                CodeRecord::Decoded { .. } => "coded, stored decoded",
            },
            acq.frames,
            acq.frame_rate_hz,
            probe.name,
            probe.n_elements,
            probe.center_frequency_hz * 1e-6,
        ),
        (_, _, Some(images)) => format!(
            "beamformed images formed elsewhere, {}, {} frames at {:.1} Hz, IQ demodulated at \
             {:.2} MHz",
            angles_span(&images.angles_deg),
            images.frames,
            images.frame_rate_hz,
            images.demod_frequency_hz * 1e-6,
        ),
        _ => "no acquisition recorded".into(),
    };
    format!(
        "{} ({}): {read}; Nyquist velocity {:.1} mm/s.",
        summary.source.input,
        summary.source.format,
        summary.nyquist_velocity_m_s * 1e3,
    )
}

/// How it was processed: the grid, the receive f-number, the clutter filter's cut-offs.
fn processing_line(summary: &Summary) -> String {
    let grid = &summary.grid;
    let lows: Vec<usize> = (summary.clutter_filter.cut_offs_per_angle.iter())
        .map(|c| c.low)
        .collect();
    let cut = match lows.as_slice() {
        [] => "no tissue component".to_string(),
        [first, rest @ ..] if rest.iter().all(|low| low == first) => format!(
            "{first} tissue component{} at {}",
            if *first == 1 { "" } else { "s" },
            if rest.is_empty() {
                "its angle"
            } else {
                "every angle"
            }
        ),
        _ => format!(
            "{} tissue components at the angles in turn",
            lows.iter()
                .map(|low| low.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    format!(
        "Imaged on {} × {} pixels (depth × lateral) of {:.0} µm, x {:.2} to {:.2} mm, z {:.2} to \
         {:.2} mm, {}; the clutter filter cut {cut}; Doppler by {} over {}×{} pixels.",
        grid.nz,
        grid.nx,
        grid.step_m * 1e6,
        grid.x_min_m * 1e3,
        grid.x_max_m * 1e3,
        grid.z_min_m * 1e3,
        grid.z_max_m * 1e3,
        match &summary.beamforming {
            Some(das) => format!("receive F# {}", das.f_number),
            None => "beamformed elsewhere".into(),
        },
        summary.doppler.estimator,
        summary.doppler.kernel[0],
        summary.doppler.kernel[1],
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every figure `process` may write has its caption.
    #[test]
    fn every_figure_process_writes_has_a_caption() {
        let figures = crate::outputs::PROCESS_OUTPUTS
            .iter()
            .filter(|name| name.ends_with(".png"));
        let mut count = 0;
        for name in figures {
            assert!(caption(name).is_some(), "{name} has no caption");
            count += 1;
        }
        assert!(count >= 10, "{count} figures");
    }
}
