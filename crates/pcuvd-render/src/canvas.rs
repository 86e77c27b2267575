//! Thin pixel-space drawing layer over plotters' bitmap backend: text with
//! predictable anchoring, clipped (dashed) polylines and polygons.

use crate::RenderError;
use plotters::backend::BitMapBackend;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::FontTransform;
use std::sync::OnceLock;

/// Register the embedded DejaVu Sans as "sans-serif" once.
pub(crate) fn ensure_font() -> Result<(), RenderError> {
    static FONT: OnceLock<Result<(), String>> = OnceLock::new();
    FONT.get_or_init(|| {
        plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            include_bytes!("../assets/DejaVuSans.ttf"),
        )
        .map_err(|_| "embedded DejaVuSans.ttf could not be parsed".to_string())
    })
    .clone()
    .map_err(RenderError::Font)
}

/// Axis-aligned rectangle in pixel coordinates (x right, y down).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Rect {
    pub x0: f64,
    pub y0: f64,
    pub x1: f64,
    pub y1: f64,
}

impl Rect {
    pub(crate) fn new(x0: f64, y0: f64, w: f64, h: f64) -> Self {
        Rect {
            x0,
            y0,
            x1: x0 + w,
            y1: y0 + h,
        }
    }
    pub(crate) fn w(&self) -> f64 {
        self.x1 - self.x0
    }
    pub(crate) fn h(&self) -> f64 {
        self.y1 - self.y0
    }
}

/// Horizontal text anchor.
#[derive(Debug, Clone, Copy)]
pub(crate) enum HAlign {
    Left,
    Center,
    Right,
}

/// Vertical text anchor, relative to the capital letters' box.
#[derive(Debug, Clone, Copy)]
pub(crate) enum VAlign {
    Top,
    Center,
    Bottom,
}

// DejaVu Sans metrics at plotters' ab_glyph "size" (= ascent - descent in px):
// the baseline lies size/2 below the anchor (Top/Left anchor); capital letters
// are ~0.626*size tall.
const BASELINE: f64 = 0.5;
const CAP: f64 = 0.626;
/// Baseline-to-baseline distance of a title's lines, in font sizes.
pub(crate) const TITLE_LINE_STEP: f64 = 1.2;

/// Lines of a title (the text split at `\n`; one for an empty title).
pub(crate) fn title_lines(title: &str) -> usize {
    title.lines().count().max(1)
}

/// Height a title band of `lines` lines at font size `size` takes above the usual one-line
/// band.
pub(crate) fn extra_title_height(lines: usize, size: f64) -> f64 {
    lines.saturating_sub(1) as f64 * TITLE_LINE_STEP * size
}

fn rgb(c: (u8, u8, u8)) -> RGBColor {
    RGBColor(c.0, c.1, c.2)
}

fn draw_err<E: std::fmt::Display>(e: E) -> RenderError {
    RenderError::Draw(e.to_string())
}

/// A pixel-space drawing surface.
pub(crate) struct Canvas<'a> {
    root: DrawingArea<BitMapBackend<'a>, Shift>,
}

impl<'a> Canvas<'a> {
    /// Wrap an RGB buffer of size w*h*3.
    pub(crate) fn new(buf: &'a mut [u8], w: u32, h: u32) -> Result<Self, RenderError> {
        let backend = BitMapBackend::with_buffer_and_format(buf, (w, h)).map_err(draw_err)?;
        Ok(Canvas {
            root: backend.into_drawing_area(),
        })
    }

    pub(crate) fn finish(self) -> Result<(), RenderError> {
        self.root.present().map_err(draw_err)
    }

    /// Width in pixels of `s` at font size `size`.
    pub(crate) fn text_width(&self, s: &str, size: f64) -> f64 {
        if s.is_empty() {
            return 0.0;
        }
        let style = ("sans-serif", size).into_font();
        self.root
            .estimate_text_size(s, &style.into_text_style(&self.root))
            .map(|(w, _)| w as f64)
            .unwrap_or(0.6 * size * s.chars().count() as f64)
    }

    /// Draw a title centred near `cx` with its last line's baseline at `y`, its lines (split at
    /// `\n`) one above another, shrunk alike (down to 55 %) and shifted as needed to stay
    /// within [x0, x1].
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn title(
        &self,
        s: &str,
        cx: f64,
        y: f64,
        size: f64,
        x0: f64,
        x1: f64,
        c: (u8, u8, u8),
    ) -> Result<(), RenderError> {
        let avail = (x1 - x0).max(1.0);
        let widest = s
            .lines()
            .map(|line| self.text_width(line, size))
            .fold(0.0, f64::max);
        let size = if widest > avail {
            (size * avail / widest).max(size * 0.55)
        } else {
            size
        };
        let lines: Vec<&str> = s.lines().collect();
        for (i, line) in lines.iter().enumerate() {
            let w = self.text_width(line, size);
            let cx = if w >= avail {
                (x0 + x1) / 2.0
            } else {
                cx.min(x1 - w / 2.0).max(x0 + w / 2.0)
            };
            let above = (lines.len() - 1 - i) as f64 * TITLE_LINE_STEP * size;
            self.text(
                line,
                cx,
                y - above,
                size,
                HAlign::Center,
                VAlign::Bottom,
                c,
                false,
            )?;
        }
        Ok(())
    }

    /// Draw text anchored at (x, y); `rotated` = reads bottom-to-top (for y-axis labels).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn text(
        &self,
        s: &str,
        x: f64,
        y: f64,
        size: f64,
        ha: HAlign,
        va: VAlign,
        c: (u8, u8, u8),
        rotated: bool,
    ) -> Result<(), RenderError> {
        if s.is_empty() {
            return Ok(());
        }
        let w = self.text_width(s, size);
        let along = match ha {
            HAlign::Left => 0.0,
            HAlign::Center => -w / 2.0,
            HAlign::Right => -w,
        };
        // Offset of the draw anchor from the requested point, perpendicular to the text.
        let across = match va {
            VAlign::Top => (CAP - BASELINE) * size,
            VAlign::Center => (CAP / 2.0 - BASELINE) * size,
            VAlign::Bottom => -BASELINE * size,
        };
        let color = rgb(c);
        let mut style = ("sans-serif", size).into_font().color(&color);
        let pos = if rotated {
            style = style.transform(FontTransform::Rotate270);
            (x + across, y - along)
        } else {
            (x + along, y + across)
        };
        self.root
            .draw_text(s, &style, (pos.0.round() as i32, pos.1.round() as i32))
            .map_err(draw_err)
    }

    /// Unclipped polyline.
    pub(crate) fn polyline(
        &self,
        pts: &[(f64, f64)],
        c: (u8, u8, u8),
        alpha: f64,
        width: f64,
    ) -> Result<(), RenderError> {
        if pts.len() < 2 {
            return Ok(());
        }
        let style = ShapeStyle {
            color: rgb(c).mix(alpha),
            filled: false,
            stroke_width: width.round().max(1.0) as u32,
        };
        let p: Vec<(i32, i32)> = pts
            .iter()
            .map(|&(x, y)| (x.round() as i32, y.round() as i32))
            .collect();
        self.root
            .draw(&PathElement::new(p, style))
            .map_err(draw_err)
    }

    /// Polyline clipped to `clip`, optionally dashed with (on, off) lengths in px.
    /// Non-finite vertices break the line.
    pub(crate) fn polyline_clipped(
        &self,
        pts: &[(f64, f64)],
        clip: Rect,
        c: (u8, u8, u8),
        width: f64,
        dash: Option<(f64, f64)>,
    ) -> Result<(), RenderError> {
        let mut runs: Vec<Vec<(f64, f64)>> = Vec::new();
        let mut cur: Vec<(f64, f64)> = Vec::new();
        // Dash state carried along the whole polyline: (drawing?, length left in this dash/gap).
        let mut dash_state = dash.map(|(on, _)| (true, on.max(0.5)));
        for w in pts.windows(2) {
            let (a, b) = (w[0], w[1]);
            let finite = a.0.is_finite() && a.1.is_finite() && b.0.is_finite() && b.1.is_finite();
            if !finite {
                if cur.len() >= 2 {
                    runs.push(std::mem::take(&mut cur));
                }
                cur.clear();
                continue;
            }
            // Split into dash pieces first (so the pattern does not depend on clipping).
            let pieces: Vec<((f64, f64), (f64, f64))> = match dash {
                None => vec![(a, b)],
                Some((on, off)) => {
                    let (on, off) = (on.max(0.5), off.max(0.5));
                    let mut out = Vec::new();
                    let len = ((b.0 - a.0).powi(2) + (b.1 - a.1).powi(2)).sqrt();
                    let (mut drawing, mut left) = dash_state.unwrap_or((true, on));
                    let mut s = 0.0;
                    while len - s > 1e-9 {
                        let step = left.min(len - s);
                        let e = s + step;
                        if drawing {
                            let (t0, t1) = (s / len, e / len);
                            out.push((
                                (a.0 + (b.0 - a.0) * t0, a.1 + (b.1 - a.1) * t0),
                                (a.0 + (b.0 - a.0) * t1, a.1 + (b.1 - a.1) * t1),
                            ));
                        }
                        s = e;
                        left -= step;
                        if left <= 1e-9 {
                            drawing = !drawing;
                            left = if drawing { on } else { off };
                        }
                    }
                    dash_state = Some((drawing, left));
                    out
                }
            };
            for (p, q) in pieces {
                match clip_segment(p, q, clip) {
                    Some((p2, q2)) => {
                        let joined = dash.is_none()
                            && cur.last().is_some_and(|l| {
                                (l.0 - p2.0).abs() < 1e-9 && (l.1 - p2.1).abs() < 1e-9
                            });
                        if !joined {
                            if cur.len() >= 2 {
                                runs.push(std::mem::take(&mut cur));
                            }
                            cur.clear();
                            cur.push(p2);
                        }
                        cur.push(q2);
                    }
                    None => {
                        if cur.len() >= 2 {
                            runs.push(std::mem::take(&mut cur));
                        }
                        cur.clear();
                    }
                }
            }
        }
        if cur.len() >= 2 {
            runs.push(cur);
        }
        for r in runs {
            self.polyline(&r, c, 1.0, width)?;
        }
        Ok(())
    }

    /// Filled polygon clipped to `clip`.
    pub(crate) fn polygon_clipped(
        &self,
        pts: &[(f64, f64)],
        clip: Rect,
        c: (u8, u8, u8),
        alpha: f64,
    ) -> Result<(), RenderError> {
        let poly = clip_polygon(pts, clip);
        if poly.len() < 3 {
            return Ok(());
        }
        let p: Vec<(i32, i32)> = poly
            .iter()
            .map(|&(x, y)| (x.round() as i32, y.round() as i32))
            .collect();
        self.root
            .draw(&Polygon::new(p, rgb(c).mix(alpha).filled()))
            .map_err(draw_err)
    }

    /// Filled rectangle.
    pub(crate) fn fill_rect(
        &self,
        r: Rect,
        c: (u8, u8, u8),
        alpha: f64,
    ) -> Result<(), RenderError> {
        self.root
            .draw(&Rectangle::new(
                [
                    (r.x0.round() as i32, r.y0.round() as i32),
                    // The bitmap backend's filled rectangles exclude the bottom-right edge.
                    (r.x1.round() as i32, r.y1.round() as i32),
                ],
                rgb(c).mix(alpha).filled(),
            ))
            .map_err(draw_err)
    }

    /// Rectangle outline whose stroke lies just inside/on the rectangle edge.
    pub(crate) fn stroke_rect(
        &self,
        r: Rect,
        c: (u8, u8, u8),
        width: f64,
    ) -> Result<(), RenderError> {
        let t = width.round().max(1.0);
        // Draw as four filled bars so the corners are exact.
        let (x0, y0, x1, y1) = (r.x0.round(), r.y0.round(), r.x1.round(), r.y1.round());
        self.fill_rect(
            Rect {
                x0,
                y0,
                x1,
                y1: y0 + t,
            },
            c,
            1.0,
        )?;
        self.fill_rect(
            Rect {
                x0,
                y0: y1 - t,
                x1,
                y1,
            },
            c,
            1.0,
        )?;
        self.fill_rect(
            Rect {
                x0,
                y0,
                x1: x0 + t,
                y1,
            },
            c,
            1.0,
        )?;
        self.fill_rect(
            Rect {
                x0: x1 - t,
                y0,
                x1,
                y1,
            },
            c,
            1.0,
        )
    }

    /// Circle (filled or outlined).
    pub(crate) fn circle(
        &self,
        center: (f64, f64),
        radius: f64,
        c: (u8, u8, u8),
        filled: bool,
        width: f64,
    ) -> Result<(), RenderError> {
        let style = ShapeStyle {
            color: rgb(c).to_rgba(),
            filled,
            stroke_width: width.round().max(1.0) as u32,
        };
        self.root
            .draw(&Circle::new(
                (center.0.round() as i32, center.1.round() as i32),
                radius.round().max(1.0) as i32,
                style,
            ))
            .map_err(draw_err)
    }
}

/// Liang-Barsky clip of segment p-q to rectangle r.
pub(crate) fn clip_segment(
    p: (f64, f64),
    q: (f64, f64),
    r: Rect,
) -> Option<((f64, f64), (f64, f64))> {
    let (dx, dy) = (q.0 - p.0, q.1 - p.1);
    let mut t0 = 0.0f64;
    let mut t1 = 1.0f64;
    for (pk, qk) in [
        (-dx, p.0 - r.x0),
        (dx, r.x1 - p.0),
        (-dy, p.1 - r.y0),
        (dy, r.y1 - p.1),
    ] {
        if pk == 0.0 {
            if qk < 0.0 {
                return None;
            }
        } else {
            let t = qk / pk;
            if pk < 0.0 {
                t0 = t0.max(t);
            } else {
                t1 = t1.min(t);
            }
        }
    }
    if t0 > t1 {
        return None;
    }
    Some((
        (p.0 + t0 * dx, p.1 + t0 * dy),
        (p.0 + t1 * dx, p.1 + t1 * dy),
    ))
}

/// Sutherland-Hodgman clip of a polygon to rectangle r.
pub(crate) fn clip_polygon(pts: &[(f64, f64)], r: Rect) -> Vec<(f64, f64)> {
    let mut poly: Vec<(f64, f64)> = pts.to_vec();
    // (inside test, intersection) for each of the four edges.
    type Inside = fn((f64, f64), Rect) -> bool;
    let edges: [(Inside, usize); 4] = [
        (|p, r| p.0 >= r.x0, 0),
        (|p, r| p.0 <= r.x1, 1),
        (|p, r| p.1 >= r.y0, 2),
        (|p, r| p.1 <= r.y1, 3),
    ];
    for (inside, which) in edges {
        if poly.is_empty() {
            break;
        }
        let input = std::mem::take(&mut poly);
        let n = input.len();
        for i in 0..n {
            let cur = input[i];
            let prev = input[(i + n - 1) % n];
            let (ci, pi) = (inside(cur, r), inside(prev, r));
            let cross = |a: (f64, f64), b: (f64, f64)| -> (f64, f64) {
                let bound = match which {
                    0 => r.x0,
                    1 => r.x1,
                    2 => r.y0,
                    _ => r.y1,
                };
                if which < 2 {
                    let t = (bound - a.0) / (b.0 - a.0);
                    (bound, a.1 + t * (b.1 - a.1))
                } else {
                    let t = (bound - a.1) / (b.1 - a.1);
                    (a.0 + t * (b.0 - a.0), bound)
                }
            };
            if ci {
                if !pi {
                    poly.push(cross(prev, cur));
                }
                poly.push(cur);
            } else if pi {
                poly.push(cross(prev, cur));
            }
        }
    }
    poly
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn segment_clipping() {
        let r = Rect::new(0.0, 0.0, 10.0, 10.0);
        assert_eq!(
            clip_segment((-5.0, 5.0), (15.0, 5.0), r),
            Some(((0.0, 5.0), (10.0, 5.0)))
        );
        assert_eq!(clip_segment((-5.0, -5.0), (-1.0, 20.0), r), None);
        assert_eq!(
            clip_segment((2.0, 2.0), (3.0, 3.0), r),
            Some(((2.0, 2.0), (3.0, 3.0)))
        );
    }

    #[test]
    fn polygon_clipping() {
        let r = Rect::new(0.0, 0.0, 10.0, 10.0);
        let tri = [(-5.0, 5.0), (5.0, -5.0), (5.0, 5.0)];
        let c = clip_polygon(&tri, r);
        assert!(c.len() >= 3);
        assert!(
            c.iter()
                .all(|p| p.0 >= 0.0 && p.1 >= 0.0 && p.0 <= 10.0 && p.1 <= 10.0)
        );
        let outside = [(-5.0, -5.0), (-1.0, -5.0), (-1.0, -1.0)];
        assert!(clip_polygon(&outside, r).is_empty());
    }
}
