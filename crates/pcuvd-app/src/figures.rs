//! Figures of processed maps: what a person looks at (units: mm, mm/s, dB).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use ndarray::{Array2, Zip};
use pcuvd::core::grid::Grid;
use pcuvd::dynamics::{ARTERIOLE, BACKGROUND, DynamicsParams, RiMaps, VENULE, VelocitySeries};
use pcuvd::estimate::clutter::ClutterReport;
use pcuvd::estimate::masks;
use pcuvd::estimate::vector::VectorField;
use pcuvd::pipeline::ProcessOutput;
use pcuvd_render::{
    Colormap, Figure, ImagePanel, Marker, Panel, PlotPanel, Polyline, Series, SeriesStyle,
    VectorOverlay, render_png_bytes,
};
use rayon::prelude::*;

mod series;
pub use series::*;

pub use pcuvd::core::stats::{median, quantile};

/// A rendered figure: file name, caption, PNG bytes.
pub struct Rendered {
    /// File name inside the output folder.
    pub file: String,
    /// Caption for the report.
    pub caption: String,
    /// The PNG file's bytes.
    pub png: Vec<u8>,
}

/// Draws `fig` into `dir/file` and keeps its bytes for the report.
pub fn render(dir: &Path, file: &str, caption: &str, fig: Figure) -> Result<Rendered> {
    let png = render_png_bytes(&fig).with_context(|| format!("cannot draw {file}"))?;
    write_file(&dir.join(file), &png)?;
    Ok(Rendered {
        file: file.to_string(),
        caption: caption.to_string(),
        png,
    })
}

/// A line series of one colour.
pub fn line(
    label: &str,
    x: Vec<f64>,
    y: Vec<f64>,
    style: SeriesStyle,
    rgb: (u8, u8, u8),
) -> Series {
    Series {
        label: label.to_string(),
        x,
        y,
        y_err: None,
        style,
        rgb: Some(rgb),
    }
}

/// Colour of the ground truth in plots.
pub const TRUTH_RGB: (u8, u8, u8) = (31, 119, 180);
/// Colour of UVD (conventional) in plots.
pub const UVD_RGB: (u8, u8, u8) = (230, 159, 0);
/// Colour of PC-UVD (coded) in plots.
pub const PCUVD_RGB: (u8, u8, u8) = (214, 39, 40);

/// Colour of the lines drawn on maps where a profile figure takes its values (cyan: apart from
/// the hot and red-blue maps' colours).
pub const PROFILE_LINE_RGB: (u8, u8, u8) = (0, 220, 255);
/// Colour of the outlines drawn on maps around the regions another figure enlarges.
pub const ROI_BOX_RGB: (u8, u8, u8) = (120, 255, 120);

/// Colour-bar label of an axial velocity drawn positive toward the probe with
/// [`Colormap::RedBlue`]: red is flow toward the probe (up), in every figure, as in the paper.
/// The label names the sign, since the maps written beside the figure count + away (deeper).
pub const TOWARD_PROBE_LABEL: &str = "velocity toward the probe (mm/s): red = toward, blue = away";
/// Colour-bar label of Vz (positive deeper) drawn with [`Colormap::BlueRed`]: red = up.
pub const VZ_LABEL: &str = "Vz (mm/s, + = deeper): red = toward probe (up), blue = away";
/// Colour-bar label of Vx drawn with [`Colormap::RedBlue`].
pub const VX_LABEL: &str = "Vx (mm/s): red = toward +x (right), blue = toward −x";
/// Colour-bar label of a [`class_map`] of PSV.
pub const PSV_UP_LABEL: &str = "PSV (mm/s): red = flowing up (toward probe), blue = down";

/// A colour range (0, top) in dB shared by maps a reader compares, from their data: the top is
/// the largest 99.9th percentile of the maps, rounded up to 5 dB, so that no map saturates.
pub fn shared_db_range(maps: &[&Array2<f64>]) -> (f64, f64) {
    let top = maps
        .iter()
        .map(|m| quantile(m.iter().copied(), 0.999))
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max);
    (0.0, ((top / 5.0).ceil() * 5.0).max(5.0))
}

/// B-mode in dB mapped to [0, 1] grey over a 60 dB dynamic range, as a background.
pub fn bmode_background(bmode_db: &Array2<f64>) -> Array2<f64> {
    bmode_db.mapv(|v| ((v + 60.0) / 60.0).clamp(0.0, 1.0))
}

/// An image panel of `data` on `grid` with the usual axes in mm.
pub fn map_panel(
    title: &str,
    data: Array2<f64>,
    grid: &Grid,
    colormap: Colormap,
    range: (f64, f64),
    label: &str,
) -> ImagePanel {
    ImagePanel {
        title: title.to_string(),
        data,
        x_mm: (grid.x[0] * 1e3, grid.x[grid.x.len() - 1] * 1e3),
        z_mm: (grid.z[0] * 1e3, grid.z[grid.z.len() - 1] * 1e3),
        colormap,
        range,
        colorbar_label: label.to_string(),
        mask: None,
        background: None,
        arrows: None,
        lines: vec![],
        axes: None,
    }
}

/// The dashed outline of the region x ∈ `x`, z ∈ `z` (m), drawn where a figure enlarges it.
pub fn region_outline(x: (f64, f64), z: (f64, f64), label: &str) -> Polyline {
    let (x0, x1, z0, z1) = (x.0 * 1e3, x.1 * 1e3, z.0 * 1e3, z.1 * 1e3);
    Polyline {
        x_mm: vec![x0, x1, x1, x0, x0],
        z_mm: vec![z0, z0, z1, z1, z0],
        dashed: true,
        rgb: ROI_BOX_RGB,
        label: label.to_string(),
    }
}

/// Axial velocity `vz_m_s` (m/s, + = deeper) drawn red toward the probe on a ±`vmax_mm_s` scale
/// over `mask`, black elsewhere: colour Doppler, or the truth's axial velocity beside it.
pub fn axial_velocity_panel(
    title: &str,
    vz_m_s: &Array2<f64>,
    grid: &Grid,
    vmax_mm_s: f64,
    mask: &Array2<bool>,
) -> Panel {
    let mut panel = map_panel(
        title,
        vz_m_s.mapv(|v| -v * 1e3),
        grid,
        Colormap::RedBlue,
        (-vmax_mm_s, vmax_mm_s),
        TOWARD_PROBE_LABEL,
    );
    panel.mask = Some(mask.clone());
    panel.background = Some(Array2::zeros(mask.dim()));
    Panel::Image(panel)
}

/// Triangles along the flow, one per `stride` × `stride` block of pixels that holds `mask` pixels,
/// coloured by speed (mm/s). Each sits at the centroid of its block's flow pixels and carries
/// their component-wise median velocity: vessels narrower than a block would be missed by a
/// fixed lattice of sample points, and one noisy pixel would draw a full-length glyph.
pub fn vector_overlay(
    field: &VectorField,
    grid: &Grid,
    mask: &Array2<bool>,
    speed_max_mm_s: f64,
) -> VectorOverlay {
    let (nz, nx) = grid.shape();
    let stride = (nx.max(nz) / 22).max(1);
    let step_mm = (grid.x.get(1).copied().unwrap_or(grid.x[0]) - grid.x[0]).abs() * 1e3;
    let mut overlay = VectorOverlay {
        x_mm: vec![],
        z_mm: vec![],
        vx: vec![],
        vz: vec![],
        scale_mm: (stride as f64 * step_mm * 1.4).max(1e-3),
        colormap: Colormap::Viridis,
        speed_range: (0.0, speed_max_mm_s.max(1e-9)),
    };
    for z0 in (0..nz).step_by(stride) {
        for x0 in (0..nx).step_by(stride) {
            let (mut xs, mut zs, mut vxs, mut vzs) = (vec![], vec![], vec![], vec![]);
            for iz in z0..(z0 + stride).min(nz) {
                for ix in x0..(x0 + stride).min(nx) {
                    let (vx, vz) = (field.vx[[iz, ix]], field.vz[[iz, ix]]);
                    if mask[[iz, ix]] && vx.is_finite() && vz.is_finite() {
                        xs.push(grid.x[ix]);
                        zs.push(grid.z[iz]);
                        vxs.push(vx);
                        vzs.push(vz);
                    }
                }
            }
            // A block that only grazes a vessel edge gives an unrepresentative glyph.
            let block = (stride.min(nz) * stride.min(nx)).max(1);
            if xs.is_empty() || xs.len() * 16 < block {
                continue;
            }
            let n = xs.len() as f64;
            overlay.x_mm.push(xs.iter().sum::<f64>() / n * 1e3);
            overlay.z_mm.push(zs.iter().sum::<f64>() / n * 1e3);
            overlay.vx.push(median(vxs) * 1e3);
            overlay.vz.push(median(vzs) * 1e3);
        }
    }
    overlay
}

/// The figures [`process_figures`] writes.
pub const PROCESS_FIGURES: [&str; 5] = [
    "bmode.png",
    "power_doppler.png",
    "signed_power_doppler.png",
    "color_doppler.png",
    "vector.png",
];

/// Width (px) of one map of `pcuvd process`'s figures.
const PROCESS_PANEL_WIDTH_PX: u32 = 560;

fn save(
    path: &Path,
    title: &str,
    panels: Vec<Panel>,
    ncols: usize,
    panel_size_px: (u32, u32),
) -> Result<PathBuf> {
    let fig = Figure {
        title: title.to_string(),
        panels,
        ncols,
        panel_size_px,
    };
    let png = render_png_bytes(&fig).with_context(|| format!("cannot draw {}", path.display()))?;
    write_file(path, &png)?;
    Ok(path.to_path_buf())
}

/// Writes `bytes` to `path` atomically (a temporary name, then a rename): an interrupted run
/// never leaves a truncated figure or report under its final name.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    pcuvd_io::write_atomically(path, |partial| {
        std::fs::write(partial, bytes).map_err(|e| pcuvd_io::IoError::io(path, "write", e))
    })?;
    Ok(())
}

/// The B-mode panel of a result and the size (px) of every map panel of its figures: each map has
/// the grid's extent, so one cell size fitted to its aspect ratio serves them all.
fn bmode_panel(out: &ProcessOutput) -> Result<(ImagePanel, (u32, u32))> {
    let bmode = map_panel(
        "B-mode",
        out.bmode_db.clone(),
        &out.grid,
        Colormap::Gray,
        (-60.0, 0.0),
        "dB",
    );
    let size = pcuvd_render::fitted_panel_size(&bmode, PROCESS_PANEL_WIDTH_PX)
        .context("cannot lay out the figures")?;
    Ok((bmode, size))
}

/// Writes the figure of `panels` (`ncols` a row) to `path`, its panels sized as those of the
/// other figures of `out`.
pub fn save_figure(
    path: &Path,
    title: &str,
    panels: Vec<Panel>,
    ncols: usize,
    out: &ProcessOutput,
) -> Result<PathBuf> {
    let (_, size) = bmode_panel(out)?;
    save(path, title, panels, ncols, size)
}

/// The pixels `color_doppler.png` draws as flow (`summary.json`'s `figures.flow_rule` at its
/// colour level).
pub fn colour_flow_mask(out: &ProcessOutput) -> Array2<bool> {
    masks::figure_flow_mask(
        &out.maps.power_doppler,
        masks::FLOW_FIGURE_DB,
        out.grid.axial_step(),
    )
}

/// B-mode, power Doppler, colour Doppler and (with several angles) vector-map figures of one result.
pub fn process_figures(dir: &Path, out: &ProcessOutput, name: &str) -> Result<Vec<PathBuf>> {
    let grid = &out.grid;
    // Each figure is drawn and compressed on its own core: (file name, title, panels, columns).
    let mut figures: Vec<(&str, String, Vec<Panel>, usize)> = Vec::new();
    let (bmode, size) = bmode_panel(out)?;
    figures.push((
        "bmode.png",
        format!("{name}: B-mode"),
        vec![Panel::Image(bmode)],
        1,
    ));

    let pd = map_panel(
        "Power Doppler",
        masks::power_db_re_peak(&out.maps.power_doppler),
        grid,
        Colormap::Hot,
        (-40.0, 0.0),
        "dB",
    );
    figures.push((
        "power_doppler.png",
        format!("{name}: power Doppler"),
        vec![Panel::Image(pd)],
        1,
    ));

    // Signed power Doppler: the power's level above −40 dB re peak, signed by the flow's axial
    // direction (red toward the probe, as the colour Doppler), so that brightness is power and
    // hue is direction.
    let floor_db = 40.0;
    let toward_level = ndarray::Zip::from(&masks::power_db_re_peak(&out.maps.power_doppler))
        .and(&out.maps.color_doppler)
        .map_collect(|&db, &v| {
            let level = (db + floor_db).clamp(0.0, floor_db);
            if v < 0.0 {
                level
            } else if v > 0.0 {
                -level
            } else {
                0.0
            }
        });
    let spd = map_panel(
        "Signed power Doppler",
        toward_level,
        grid,
        Colormap::RedBlue,
        (-floor_db, floor_db),
        "dB above -40 dB re peak; red: toward the probe",
    );
    figures.push((
        "signed_power_doppler.png",
        format!("{name}: signed power Doppler"),
        vec![Panel::Image(spd)],
        1,
    ));

    let mask = colour_flow_mask(out);
    let background = bmode_background(&out.bmode_db);
    // Red = toward the probe (upward), as in the paper's colour maps.
    let upward_mm_s = out.maps.color_doppler.mapv(|v| -v * 1e3);
    let vmax = out.maps.nyquist_velocity * 1e3;
    let mut cd = map_panel(
        "Colour Doppler",
        upward_mm_s,
        grid,
        Colormap::RedBlue,
        (-vmax, vmax),
        TOWARD_PROBE_LABEL,
    );
    cd.mask = Some(mask.clone());
    cd.background = Some(background.clone());
    figures.push((
        "color_doppler.png",
        format!("{name}: colour Doppler"),
        vec![Panel::Image(cd)],
        1,
    ));

    if let (Some(ls), Some(irls)) = (&out.maps.vector_ls, &out.maps.vector_irls) {
        let mask = masks::figure_flow_mask(
            &out.maps.power_doppler,
            masks::VECTOR_FIGURE_DB,
            grid.axial_step(),
        );
        // One speed scale for both estimators, so that their colours compare.
        let vmax = speed_scale(&[(ls, &mask), (irls, &mask)]);
        let panels = [
            ("UVD (least squares)", ls),
            ("PC-UVD estimator (IRLS-WLS)", irls),
        ]
        .into_iter()
        .map(|(title, field)| vector_panel(title, field, grid, &mask, &background, vmax))
        .collect();
        figures.push(("vector.png", format!("{name}: vector Doppler"), panels, 2));
    }
    if let Some(done) = &out.maps.dealias {
        let title = format!(
            "{name}: dealiasing (K = {}, up to {:.0} mm/s): {} of {} flow pixels unwrapped (UVD), {} (PC-UVD)",
            done.intervals,
            (2 * done.intervals + 1) as f64 * out.maps.nyquist_velocity * 1e3,
            done.ls.unwrapped_pixels,
            done.flow_pixels,
            done.irls.unwrapped_pixels,
        );
        let panels = vec![
            alias_panel(
                "UVD (least squares)",
                &done.ls,
                done.intervals,
                out,
                &background,
            ),
            alias_panel(
                "PC-UVD estimator (IRLS-WLS)",
                &done.irls,
                done.intervals,
                out,
                &background,
            ),
        ];
        figures.push(("dealias.png", title, panels, 2));
    }
    figures
        .into_par_iter()
        .map(|(file, title, panels, ncols)| save(&dir.join(file), &title, panels, ncols, size))
        .collect()
}

/// `clutter_blocks.png`, the block-wise clutter filter's cut-offs where they applied: the B-mode
/// beside the tissue components cut at each pixel (the blocks' cut-offs blended as their series
/// were, averaged over the angles and the segments; `clutter_block_cut_offs.npy` holds every
/// block's both cut-offs). `reports`: each segment's filter reports, per angle. `None` for a
/// whole-image filter, and where no block cut a tissue component (the whole image's rule cut
/// none: an empty map would say only what summary.json does).
pub fn clutter_blocks_figure(
    dir: &Path,
    out: &ProcessOutput,
    reports: &[&[ClutterReport]],
    name: &str,
) -> Result<Option<PathBuf>> {
    let reports: Vec<&ClutterReport> = reports.iter().copied().flatten().collect();
    let Some(layout) = reports.first().and_then(|c| c.block_layout.as_ref()) else {
        return Ok(None);
    };
    let most = (reports.iter().flat_map(|c| &c.block_cut_offs))
        .map(|c| c.0)
        .max()
        .unwrap_or(0);
    if most == 0 {
        return Ok(None);
    }
    let grid = &out.grid;
    if layout.shape() != grid.shape() {
        bail!("the clutter filter's blocks cover another image than the maps' grid");
    }
    let mut cut = Array2::<f64>::zeros(grid.shape());
    for report in &reports {
        let lows: Vec<f64> = report.block_cut_offs.iter().map(|c| c.0 as f64).collect();
        cut += &layout.blend(&lows)?;
    }
    cut /= reports.len() as f64;
    let (bmode, size) = bmode_panel(out)?;
    let cut = map_panel(
        "Tissue components cut",
        cut,
        grid,
        Colormap::Viridis,
        (0.0, most as f64),
        "components (mean over angles)",
    );
    let (rows, cols) = layout.size;
    let caption = format!(
        "{name}: block-wise clutter filter, blocks of {rows} × {cols} pixels \
         ({:.2} × {:.2} mm) at half-block steps",
        rows as f64 * grid.axial_step() * 1e3,
        cols as f64 * grid.step() * 1e3,
    );
    let panels = vec![Panel::Image(bmode), Panel::Image(cut)];
    save(&dir.join("clutter_blocks.png"), &caption, panels, 2, size).map(Some)
}

/// The top of a speed colour scale (mm/s) shared by several vector maps: the 95th percentile of
/// the speed over every map's flow pixels, so that one colour means one speed in all of them.
pub fn speed_scale(fields: &[(&VectorField, &Array2<bool>)]) -> f64 {
    let speeds = fields.iter().flat_map(|(field, mask)| {
        Zip::from(&field.vx)
            .and(&field.vz)
            .and(*mask)
            .map_collect(|&x, &z, &m| if m { x.hypot(z) * 1e3 } else { f64::NAN })
            .into_iter()
    });
    quantile(speeds, 0.95).max(1e-6)
}

/// Speed map under triangles pointing along the flow, masked to flow pixels, with the speed colour
/// scale 0..`vmax` mm/s (from [`speed_scale`], shared by the maps a reader compares).
pub fn vector_panel(
    title: &str,
    field: &VectorField,
    grid: &Grid,
    mask: &Array2<bool>,
    background: &Array2<f64>,
    vmax: f64,
) -> Panel {
    let speed_mm_s = Zip::from(&field.vx)
        .and(&field.vz)
        .map_collect(|&x, &z| x.hypot(z) * 1e3);
    let mut panel = map_panel(
        title,
        speed_mm_s,
        grid,
        Colormap::Viridis,
        (0.0, vmax),
        "speed (mm/s)",
    );
    panel.arrows = Some(vector_overlay(field, grid, mask, vmax));
    // B-mode under triangles coloured by speed: a speed-coloured underlay would hide them.
    panel.mask = Some(Array2::from_elem(mask.dim(), false));
    panel.background = Some(background.clone());
    Panel::Image(panel)
}

/// Where dealiasing unwrapped: each pixel's alias count averaged over the angles that reach it
/// (a whole number where every angle was shifted alike, the common level; in between where the
/// pattern is mixed) on a scale of ±`intervals` (K), over the B-mode where nothing was unwrapped.
fn alias_panel(
    title: &str,
    counts: &pcuvd::estimate::dealias::AliasCounts,
    intervals: u32,
    out: &ProcessOutput,
    background: &Array2<f64>,
) -> Panel {
    let k = &counts.alias_counts;
    let (_, nz, nx) = k.dim();
    let mean = Array2::from_shape_fn((nz, nx), |(iz, ix)| {
        let reached: Vec<f64> = (0..k.dim().0)
            .filter(|&a| out.maps.coverage[[a, iz, ix]])
            .map(|a| f64::from(k[[a, iz, ix]]))
            .collect();
        reached.iter().sum::<f64>() / reached.len().max(1) as f64
    });
    let limit = f64::from(intervals.max(1));
    let mut panel = map_panel(
        title,
        mean.clone(),
        &out.grid,
        Colormap::RedBlue,
        (-limit, limit),
        "alias count k, mean over the angles: V_θ + 2k·v_N",
    );
    panel.mask = Some(mean.mapv(|m| m != 0.0));
    panel.background = Some(background.clone());
    let unwrapped = Array2::from_shape_fn((nz, nx), |(iz, ix)| {
        (0..k.dim().0).any(|a| k[[a, iz, ix]] != 0)
    });
    panel.lines = small_spot_rings(&unwrapped, &out.grid);
    Panel::Image(panel)
}

/// Unwrapped spots of at most this many pixels get a ring in `dealias.png`: a lone pixel is a
/// dot a few screen pixels wide, and such spots are where dealiasing is least sure.
const SMALL_SPOT_PIXELS: usize = 8;

/// At most this many rings are drawn; beyond it they would hide the map.
const MAX_SPOT_RINGS: usize = 200;

/// Rings (mm) around the 8-connected spots of `spots` of at most [`SMALL_SPOT_PIXELS`] pixels, the
/// largest first, at most [`MAX_SPOT_RINGS`].
fn small_spot_rings(spots: &Array2<bool>, grid: &Grid) -> Vec<Polyline> {
    let (nz, nx) = spots.dim();
    let mut seen = Array2::from_elem((nz, nx), false);
    let mut small: Vec<Vec<(usize, usize)>> = Vec::new();
    for start in spots.indexed_iter().filter(|(_, s)| **s).map(|(i, _)| i) {
        if seen[start] {
            continue;
        }
        seen[start] = true;
        let (mut spot, mut stack) = (Vec::new(), vec![start]);
        while let Some((iz, ix)) = stack.pop() {
            spot.push((iz, ix));
            for z in iz.saturating_sub(1)..(iz + 2).min(nz) {
                for x in ix.saturating_sub(1)..(ix + 2).min(nx) {
                    if spots[[z, x]] && !seen[[z, x]] {
                        seen[[z, x]] = true;
                        stack.push((z, x));
                    }
                }
            }
        }
        if spot.len() <= SMALL_SPOT_PIXELS {
            small.push(spot);
        }
    }
    small.sort_by_key(|spot| std::cmp::Reverse(spot.len()));
    // A ring wide enough to find at a glance: 2 % of the field, at least 4 pixels.
    let width = grid.x.last().unwrap_or(&0.0) - grid.x.first().unwrap_or(&0.0);
    let radius_mm = (0.02 * width).max(4.0 * grid.step()) * 1e3;
    let label = format!("unwrapped spots of ≤ {SMALL_SPOT_PIXELS} pixels");
    small
        .iter()
        .take(MAX_SPOT_RINGS)
        .map(|spot| {
            let n = spot.len() as f64;
            let cx = spot.iter().map(|&(_, ix)| grid.x[ix]).sum::<f64>() / n * 1e3;
            let cz = spot.iter().map(|&(iz, _)| grid.z[iz]).sum::<f64>() / n * 1e3;
            let (x_mm, z_mm) = (0..=32)
                .map(|i| {
                    let t = std::f64::consts::TAU * i as f64 / 32.0;
                    (cx + radius_mm * t.cos(), cz + radius_mm * t.sin())
                })
                .unzip();
            Polyline {
                x_mm,
                z_mm,
                dashed: false,
                rgb: (0, 170, 0),
                label: label.clone(),
            }
        })
        .collect()
}

/// A class map for display: +PSV (mm/s) where the flow goes up, −PSV where it goes down, NaN
/// elsewhere (red up, blue down, as in the paper's Fig. 8c–d).
pub fn class_map(
    psv: &Array2<f64>,
    class: &Array2<u8>,
    up: &Array2<bool>,
    which: u8,
) -> Array2<f64> {
    Zip::from(psv).and(class).and(up).map_collect(|&p, &c, &u| {
        if c == which && p.is_finite() {
            if u { p * 1e3 } else { -p * 1e3 }
        } else {
            f64::NAN
        }
    })
}

/// A map panel showing `data` where it is finite, black elsewhere.
pub fn finite_panel(
    title: &str,
    data: Array2<f64>,
    grid: &Grid,
    colormap: Colormap,
    range: (f64, f64),
    label: &str,
) -> Panel {
    let mask = data.mapv(f64::is_finite);
    let mut panel = map_panel(title, data, grid, colormap, range, label);
    panel.mask = Some(mask);
    panel.background = Some(Array2::zeros(grid.shape()));
    Panel::Image(panel)
}
