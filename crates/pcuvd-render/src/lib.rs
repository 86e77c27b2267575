//! Figures for pcuvd: colour maps, image panels with colour bars and vector
//! overlays, line/scatter plots, and a self-contained HTML report.
//!
//! The crate knows nothing about ultrasound: it draws what it is handed.
//! Lengths are in millimetres and velocities in whatever unit the caller
//! already converted to (typically mm/s); labels are shown verbatim.
//!
//! Figures are rasterised with 2x supersampling and box-filtered down, so lines
//! and glyphs are anti-aliased. Output size: `ncols * panel_w` wide and
//! `nrows * panel_h` tall, plus [`FIGURE_TITLE_BAND_PX`] on top when the
//! figure title is non-empty.

#![warn(missing_docs)]

mod canvas;
mod colormap;
mod figure;
mod image_panel;
mod placement;
mod plot_panel;
mod report;
mod style;
mod ticks;

pub use colormap::{Colormap, colormap_rgb};
pub use figure::{FIGURE_TITLE_BAND_PX, render_png, render_png_bytes, render_rgb};
pub use report::Report;

/// Size (w, h) in output pixels of a figure cell `width_px` wide that fits `panel`'s image with
/// equal mm on both axes, plus its title, labels and margins: use it as
/// [`Figure::panel_size_px`] so that a wide, shallow region is not drawn in a tall, mostly empty
/// frame (nor a deep, narrow one in a wide frame). Errors as rendering the panel would.
pub fn fitted_panel_size(panel: &ImagePanel, width_px: u32) -> Result<(u32, u32), RenderError> {
    canvas::ensure_font()?;
    image_panel::fitted_size(panel, width_px)
}

use std::path::PathBuf;

/// Errors from building or writing a figure or report.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// Reading or writing a file failed.
    #[error("I/O error on {path}: {source}")]
    Io {
        /// The file that could not be written.
        path: PathBuf,
        /// The underlying OS error.
        #[source]
        source: std::io::Error,
    },
    /// An image, series or figure had nothing to draw.
    #[error("empty data: {0}")]
    EmptyData(String),
    /// Arrays that must have the same shape or length did not.
    #[error("shape mismatch: {0}")]
    ShapeMismatch(String),
    /// A range or extent was non-finite, empty or otherwise unusable.
    #[error("invalid range: {0}")]
    InvalidRange(String),
    /// Figure layout parameters (columns, panel size) were unusable.
    #[error("invalid layout: {0}")]
    InvalidLayout(String),
    /// The embedded font could not be loaded or used.
    #[error("font error: {0}")]
    Font(String),
    /// The rasteriser reported a failure.
    #[error("drawing failed: {0}")]
    Draw(String),
    /// PNG encoding failed.
    #[error("PNG encoding failed: {0}")]
    Encode(String),
}

/// One image panel: a 2-D map in mm with a colour bar, optional mask/underlay and overlays.
#[derive(Debug, Clone, Default)]
pub struct ImagePanel {
    /// Title drawn above the panel.
    pub title: String,
    /// Values, shape (nz, nx): row = depth index, column = lateral index.
    pub data: ndarray::Array2<f64>,
    /// Lateral positions (mm) of the first and last column centres (data units with `axes`).
    pub x_mm: (f64, f64),
    /// Depth positions (mm) of the first and last row centres; depth increases downward
    /// (data units with `axes`, drawn upward when `y_up`).
    pub z_mm: (f64, f64),
    /// Colour map used for `data`.
    pub colormap: Colormap,
    /// Colour limits (data units); values outside are clamped.
    pub range: (f64, f64),
    /// Colour-bar label, e.g. "mm/s" or "dB".
    pub colorbar_label: String,
    /// Where false, the pixel shows `background` instead of the data colour; shape (nz, nx).
    pub mask: Option<ndarray::Array2<bool>>,
    /// Grey underlay in [0, 1] (e.g. B-mode) shown where `mask` is false; black if None; shape (nz, nx).
    pub background: Option<ndarray::Array2<f64>>,
    /// Optional vector glyphs drawn over the image.
    pub arrows: Option<VectorOverlay>,
    /// Lines (in mm) drawn over the image, e.g. a profile line; labelled ones get a legend.
    pub lines: Vec<Polyline>,
    /// Non-spatial axes; None = a depth map in mm (x right, z down, equal aspect).
    pub axes: Option<ImageAxes>,
}

/// Axes of an image that is not a depth map (e.g. a spectrogram: time × velocity).
///
/// With `ImagePanel::axes = Some(..)`, the panel's `x_mm` / `z_mm` hold the
/// horizontal / vertical coordinates of the first and last column / row
/// centres in data units, and overlays (`lines`, `arrows`) use the same units.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ImageAxes {
    /// Label under the horizontal axis, e.g. "time (ms)".
    pub x_label: String,
    /// Label beside the vertical axis, e.g. "velocity (mm/s)".
    pub y_label: String,
    /// Larger vertical values drawn higher (plots), instead of lower (depth maps).
    pub y_up: bool,
    /// Stretch the image to fill the panel instead of keeping equal units on both axes.
    pub fill: bool,
}

/// Velocity vectors drawn as slender triangles pointing along (vx, vz), coloured by speed.
#[derive(Debug, Clone, Default)]
pub struct VectorOverlay {
    /// Lateral glyph centres (mm).
    pub x_mm: Vec<f64>,
    /// Depth glyph centres (mm).
    pub z_mm: Vec<f64>,
    /// Lateral velocity components (caller units, e.g. mm/s); positive points right.
    pub vx: Vec<f64>,
    /// Axial velocity components (caller units); positive points toward larger z
    /// (down, deeper; up when the panel's axes have `y_up`).
    pub vz: Vec<f64>,
    /// Glyph length in mm (horizontal-axis units) at speed == `speed_range.1` (longer speeds are clamped to it).
    pub scale_mm: f64,
    /// Colour map for speed.
    pub colormap: Colormap,
    /// Speed limits for colour (and the length scale's maximum), caller units.
    pub speed_range: (f64, f64),
}

/// A polyline in mm drawn over an image panel.
#[derive(Debug, Clone, Default)]
pub struct Polyline {
    /// Lateral vertex positions (mm).
    pub x_mm: Vec<f64>,
    /// Depth vertex positions (mm).
    pub z_mm: Vec<f64>,
    /// Draw dashed instead of solid.
    pub dashed: bool,
    /// Line colour (sRGB).
    pub rgb: (u8, u8, u8),
    /// Legend entry; empty = not in the legend. Lines of one label share one entry, and the
    /// panel's legend goes in the corner of the image that its lines and glyphs leave free.
    pub label: String,
}

/// One data series of a plot panel.
#[derive(Debug, Clone, Default)]
pub struct Series {
    /// Legend label; empty = not shown in the legend.
    pub label: String,
    /// X values (plot units).
    pub x: Vec<f64>,
    /// Y values (plot units); NaN breaks the line.
    pub y: Vec<f64>,
    /// Optional symmetric error bar half-lengths (same units as y).
    pub y_err: Option<Vec<f64>>,
    /// How the series is drawn.
    pub style: SeriesStyle,
    /// Colour (sRGB); None = next default colour (blue, orange, red, green, purple, ...).
    pub rgb: Option<(u8, u8, u8)>,
}

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SeriesStyle {
    /// Solid line.
    #[default]
    Line,
    /// Dashed line.
    DashedLine,
    /// Markers only.
    Points,
    /// Solid line with markers.
    LinePoints,
}

/// A line/scatter plot panel.
#[derive(Debug, Clone, Default)]
pub struct PlotPanel {
    /// Title drawn above the panel.
    pub title: String,
    /// X-axis label (include units, e.g. "time (s)").
    pub x_label: String,
    /// Y-axis label (include units, e.g. "velocity (mm/s)").
    pub y_label: String,
    /// Data series, drawn in order.
    pub series: Vec<Series>,
    /// X limits; None = from the data with a small margin.
    pub x_range: Option<(f64, f64)>,
    /// Y limits; None = from the data (including error bars) with a small margin.
    pub y_range: Option<(f64, f64)>,
    /// Logarithmic y axis (non-positive values are skipped).
    pub log_y: bool,
    /// Text lines drawn in the upper-left corner inside the plot, e.g. "RMSE 3.2 mm/s".
    pub annotations: Vec<String>,
    /// Draw the y = x reference line (estimated-vs-true plots).
    pub diagonal: bool,
    /// Labelled point markers with a small arrow, e.g. PSV and EDV on a time series.
    pub markers: Vec<Marker>,
}

/// A labelled point marker in plot units.
#[derive(Debug, Clone, Default)]
pub struct Marker {
    /// X position (plot units).
    pub x: f64,
    /// Y position (plot units).
    pub y: f64,
    /// Text shown next to the arrow.
    pub label: String,
    /// Colour (sRGB).
    pub rgb: (u8, u8, u8),
}

/// One cell of a figure grid.
// Variants hold the panels by value (the CLI builds them inline); the size
// difference is irrelevant for a handful of panels.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone)]
pub enum Panel {
    /// A 2-D map with colour bar.
    Image(ImagePanel),
    /// A line/scatter plot.
    Plot(PlotPanel),
    /// A blank cell.
    Empty,
}

/// A grid of panels filled row-major, with an optional title band on top.
#[derive(Debug, Clone)]
pub struct Figure {
    /// Figure title drawn in a band of [`FIGURE_TITLE_BAND_PX`] pixels on top (no band if empty).
    pub title: String,
    /// Panels, filled row-major.
    pub panels: Vec<Panel>,
    /// Number of grid columns (>= 1).
    pub ncols: usize,
    /// Size of one grid cell in output pixels (width, height).
    pub panel_size_px: (u32, u32),
}
