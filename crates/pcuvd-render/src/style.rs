//! The look shared by every part of a figure: supersampling, panel-scaled sizes of text and
//! spacing, pixel snapping and the ink colour. The figure layout and both kinds of panel import
//! it from here, and it imports nothing of theirs.

/// Supersampling factor (figures are drawn at SS x SS and box-filtered down).
pub(crate) const SS: u32 = 2;

/// Panel height (px) per 480 px of width below which text shrinks with the height.
pub(crate) const MIN_HEIGHT_PER_480: f64 = 240.0;

/// Size and spacing constants of one panel, in supersampled pixels.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Style {
    /// Supersampled pixels per logical unit (SS x panel scale).
    pub u: f64,
}

impl Style {
    /// The style of a panel of `w_px` × `h_px` output pixels: sizes scale with the panel's
    /// width, within 0.7 to 2.5 times those of a 480-pixel-wide panel, and with its height where
    /// it is less than half its width (a short panel keeps room for its image).
    pub(crate) fn for_panel(w_px: u32, h_px: u32) -> Self {
        let f = (w_px as f64 / 480.0)
            .min(h_px as f64 / MIN_HEIGHT_PER_480)
            .clamp(0.7, 2.5);
        Style { u: SS as f64 * f }
    }
    /// Panel-title font size (supersampled pixels).
    pub(crate) fn title(&self) -> f64 {
        15.0 * self.u
    }
    /// Axis-label font size (supersampled pixels).
    pub(crate) fn label(&self) -> f64 {
        13.0 * self.u
    }
    /// Tick-label font size (supersampled pixels).
    pub(crate) fn tick(&self) -> f64 {
        11.5 * self.u
    }
    /// `v` logical units in supersampled pixels.
    pub(crate) fn px(&self, v: f64) -> f64 {
        v * self.u
    }
}

/// Round a supersampled coordinate to a whole output pixel.
pub(crate) fn snap(v: f64) -> f64 {
    (v / SS as f64).round() * SS as f64
}

/// Colour of axes, frames and text.
pub(crate) const INK: (u8, u8, u8) = (30, 30, 30);
