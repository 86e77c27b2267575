//! Line/scatter plot panels: axes, grid, series with error bars, legend,
//! annotations, markers and an optional y = x reference.

use crate::canvas::{Canvas, HAlign, Rect, VAlign};
use crate::placement::{ANNOTATION_ORDER, LEGEND_ORDER, Occupied, place};
use crate::style::{INK, Style, snap};
use crate::ticks::{Tick, linear_ticks, log_ticks};
use crate::{PlotPanel, RenderError, Series, SeriesStyle};

/// Default series colours: blue, orange, red, green, purple, brown, pink, grey, olive, cyan.
const PALETTE: [(u8, u8, u8); 10] = [
    (31, 119, 180),
    (255, 127, 14),
    (214, 39, 40),
    (44, 160, 44),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
];

const GRID: (u8, u8, u8) = (228, 228, 228);

/// Geometry of one laid-out plot panel (supersampled pixels).
pub(crate) struct PlotLayout {
    /// The grid cell this panel lives in.
    cell: Rect,
    plot: Rect,
    /// X limits (data units).
    xr: (f64, f64),
    /// Y limits in axis space (log10 of the value when log_y).
    yr: (f64, f64),
    log_y: bool,
    xt: Vec<Tick>,
    yt: Vec<Tick>,
    yt_w: f64,
}

impl PlotLayout {
    fn px_x(&self, x: f64) -> f64 {
        self.plot.x0 + (x - self.xr.0) / (self.xr.1 - self.xr.0) * self.plot.w()
    }
    /// Axis-space value of y (NaN if not drawable).
    fn ty(&self, y: f64) -> f64 {
        if self.log_y {
            if y > 0.0 { y.log10() } else { f64::NAN }
        } else {
            y
        }
    }
    fn px_y(&self, y: f64) -> f64 {
        let t = self.ty(y);
        self.plot.y1 - (t - self.yr.0) / (self.yr.1 - self.yr.0) * self.plot.h()
    }
    fn pt(&self, x: f64, y: f64) -> (f64, f64) {
        (self.px_x(x), self.px_y(y))
    }
}

fn series_color(s: &Series, i: usize) -> (u8, u8, u8) {
    s.rgb.unwrap_or(PALETTE[i % PALETTE.len()])
}

fn check_range(name: &str, r: (f64, f64), log: bool) -> Result<(), RenderError> {
    if !(r.0.is_finite() && r.1.is_finite() && r.0 < r.1) {
        return Err(RenderError::InvalidRange(format!(
            "{name} ({}, {}) must be finite and increasing",
            r.0, r.1
        )));
    }
    if log && r.0 <= 0.0 {
        return Err(RenderError::InvalidRange(format!(
            "{name} ({}, {}) must be positive on a log axis",
            r.0, r.1
        )));
    }
    Ok(())
}

fn validate(pp: &PlotPanel) -> Result<(), RenderError> {
    for (i, s) in pp.series.iter().enumerate() {
        if s.x.len() != s.y.len() {
            return Err(RenderError::ShapeMismatch(format!(
                "series {i} ('{}'): {} x values but {} y values",
                s.label,
                s.x.len(),
                s.y.len()
            )));
        }
        if let Some(e) = &s.y_err
            && e.len() != s.y.len()
        {
            return Err(RenderError::ShapeMismatch(format!(
                "series {i} ('{}'): {} y_err values but {} y values",
                s.label,
                e.len(),
                s.y.len()
            )));
        }
    }
    if let Some(r) = pp.x_range {
        check_range("x_range", r, false)?;
    }
    if let Some(r) = pp.y_range {
        check_range("y_range", r, pp.log_y)?;
    }
    Ok(())
}

/// Min/max accumulator over finite values.
#[derive(Clone, Copy)]
struct Span(f64, f64);
impl Span {
    fn new() -> Self {
        Span(f64::INFINITY, f64::NEG_INFINITY)
    }
    fn add(&mut self, v: f64) {
        if v.is_finite() {
            self.0 = self.0.min(v);
            self.1 = self.1.max(v);
        }
    }
    fn valid(&self) -> bool {
        self.0 <= self.1
    }
}

/// Pad a data span by `frac` on each side (in axis space) and widen degenerate spans.
fn padded(s: Span, frac: f64) -> (f64, f64) {
    let (mut lo, mut hi) = (s.0, s.1);
    if hi - lo <= 1e-12 * lo.abs().max(hi.abs()).max(1e-300) {
        let d = (lo.abs() * 0.1).max(1.0);
        lo -= d;
        hi += d;
        return (lo, hi);
    }
    let m = (hi - lo) * frac;
    (lo - m, hi + m)
}

/// Data limits in axis space: (x range, y range).
/// (x limits, y limits in axis space).
type Ranges = ((f64, f64), (f64, f64));

fn data_ranges(pp: &PlotPanel) -> Result<Ranges, RenderError> {
    let log = pp.log_y;
    let ty = |y: f64| {
        if log {
            if y > 0.0 { y.log10() } else { f64::NAN }
        } else {
            y
        }
    };
    let (mut sx, mut sy) = (Span::new(), Span::new());
    for s in &pp.series {
        for i in 0..s.x.len() {
            let (x, y) = (s.x[i], s.y[i]);
            if !x.is_finite() || !ty(y).is_finite() {
                continue;
            }
            sx.add(x);
            sy.add(ty(y));
            if let Some(e) = s.y_err.as_ref().map(|e| e[i].abs())
                && e.is_finite()
            {
                sy.add(ty(y + e));
                sy.add(ty(y - e));
            }
        }
    }
    for m in &pp.markers {
        if m.x.is_finite() && ty(m.y).is_finite() {
            sx.add(m.x);
            sy.add(ty(m.y));
        }
    }
    let xr = match pp.x_range {
        Some(r) => r,
        None => {
            if !sx.valid() {
                return Err(RenderError::EmptyData(format!(
                    "plot '{}' has no finite points to set the x range",
                    pp.title
                )));
            }
            padded(sx, 0.03)
        }
    };
    let yr = match pp.y_range {
        Some(r) => (ty(r.0), ty(r.1)),
        None => {
            if !sy.valid() {
                return Err(RenderError::EmptyData(format!(
                    "plot '{}' has no finite{} points to set the y range",
                    pp.title,
                    if log { " positive" } else { "" }
                )));
            }
            padded(sy, 0.06)
        }
    };
    // Estimated-vs-true plots: share limits when both are automatic.
    if pp.diagonal && pp.x_range.is_none() && pp.y_range.is_none() && !log {
        let r = (xr.0.min(yr.0), xr.1.max(yr.1));
        return Ok((r, r));
    }
    Ok((xr, yr))
}

fn ticks_for(log: bool, yr: (f64, f64), n: usize) -> Vec<Tick> {
    if log {
        log_ticks(10f64.powf(yr.0), 10f64.powf(yr.1), n)
            .into_iter()
            .map(|t| Tick {
                value: t.value.log10(),
                label: t.label,
            })
            .collect()
    } else {
        linear_ticks(yr.0, yr.1, n)
    }
}

fn max_width(m: &Canvas, ticks: &[Tick], size: f64) -> f64 {
    ticks
        .iter()
        .map(|t| m.text_width(&t.label, size))
        .fold(0.0, f64::max)
}

/// Validate `pp` and place it inside `cell`, below a title band of `title_lines` lines (at
/// least its own title's: the most of its row's, so that a row's plots line up).
pub(crate) fn layout(
    pp: &PlotPanel,
    cell: Rect,
    st: &Style,
    m: &Canvas,
    title_lines: usize,
) -> Result<PlotLayout, RenderError> {
    validate(pp)?;
    let (xr, yr) = data_ranges(pp)?;
    let (ts, ls, tts) = (st.tick(), st.label(), st.title());
    let tick_len = st.px(4.0);
    let gap = st.px(3.0);

    let yt0 = ticks_for(pp.log_y, yr, 8);
    let yt_w0 = max_width(m, &yt0, ts);
    let xt0 = linear_ticks(xr.0, xr.1, 8);
    let last_x_w = xt0.last().map_or(0.0, |t| m.text_width(&t.label, ts));

    let lines = title_lines.max(crate::canvas::title_lines(&pp.title));
    let title_h = tts * 1.7 + crate::canvas::extra_title_height(lines, tts);
    let left = st.px(6.0)
        + if pp.y_label.is_empty() {
            0.0
        } else {
            ls * 1.2 + st.px(5.0)
        }
        + yt_w0
        + gap
        + tick_len;
    let bottom = tick_len
        + gap
        + ts * 0.8
        + st.px(8.0)
        + if pp.x_label.is_empty() {
            0.0
        } else {
            ls * 0.8 + st.px(8.0)
        }
        + st.px(2.0);
    let right = (last_x_w / 2.0 + st.px(4.0)).max(st.px(14.0));
    let top = title_h + ts * 0.6;
    let plot = Rect {
        x0: snap(cell.x0 + left),
        y0: snap(cell.y0 + top),
        x1: snap(cell.x1 - right),
        y1: snap(cell.y1 - bottom),
    };
    if plot.w() < st.px(30.0) || plot.h() < st.px(30.0) {
        return Err(RenderError::InvalidLayout(
            "panel too small for its labels".into(),
        ));
    }
    let xw = max_width(m, &xt0, ts).max(ts);
    let nx_ticks = ((plot.w() / (xw + ts * 1.5)) as usize + 1).clamp(2, 10);
    let ny_ticks = ((plot.h() / (ts * 2.8)) as usize).clamp(2, 10);
    let xt = linear_ticks(xr.0, xr.1, nx_ticks);
    let yt = ticks_for(pp.log_y, yr, ny_ticks);
    let yt_w = max_width(m, &yt, ts);
    Ok(PlotLayout {
        cell,
        plot,
        xr,
        yr,
        log_y: pp.log_y,
        xt,
        yt,
        yt_w,
    })
}

/// Draw a laid-out plot panel.
pub(crate) fn draw(
    pp: &PlotPanel,
    l: &PlotLayout,
    st: &Style,
    c: &Canvas,
) -> Result<(), RenderError> {
    let plot = l.plot;
    let (ts, ls, tts) = (st.tick(), st.label(), st.title());
    let tick_len = st.px(4.0);
    let gap = st.px(3.0);
    let lw = st.px(1.0);

    // Grid.
    for t in &l.xt {
        let x = l.px_x(t.value);
        c.polyline(&[(x, plot.y0), (x, plot.y1)], GRID, 1.0, lw)?;
    }
    for t in &l.yt {
        let y = plot.y1 - (t.value - l.yr.0) / (l.yr.1 - l.yr.0) * plot.h();
        c.polyline(&[(plot.x0, y), (plot.x1, y)], GRID, 1.0, lw)?;
    }

    // y = x reference.
    if pp.diagonal
        && let Some((lo, hi)) = diagonal_span(l)
    {
        {
            let n = if l.log_y { 200 } else { 2 };
            let pts: Vec<(f64, f64)> = (0..n)
                .map(|i| {
                    let v = lo + (hi - lo) * i as f64 / (n - 1) as f64;
                    l.pt(v, v)
                })
                .collect();
            c.polyline_clipped(
                &pts,
                plot,
                (110, 110, 110),
                st.px(1.2),
                Some((st.px(5.0), st.px(4.0))),
            )?;
        }
    }

    // Series.
    for (si, s) in pp.series.iter().enumerate() {
        let col = series_color(s, si);
        if let Some(err) = &s.y_err {
            let cap = st.px(3.0);
            for ((&x, &y), &e) in s.x.iter().zip(&s.y).zip(err) {
                let e = e.abs();
                if !(x.is_finite() && l.ty(y).is_finite() && e.is_finite()) {
                    continue;
                }
                let px = l.px_x(x);
                let y_top = l.px_y(y + e);
                let lo_v = y - e;
                let y_bot = if l.log_y && lo_v <= 0.0 {
                    plot.y1
                } else {
                    l.px_y(lo_v)
                };
                c.polyline_clipped(&[(px, y_bot), (px, y_top)], plot, col, lw, None)?;
                for yy in [y_top, y_bot] {
                    if yy > plot.y0 && yy < plot.y1 {
                        c.polyline_clipped(&[(px - cap, yy), (px + cap, yy)], plot, col, lw, None)?;
                    }
                }
            }
        }
        let pts = series_pixels(s, l);
        match s.style {
            SeriesStyle::Line | SeriesStyle::LinePoints => {
                c.polyline_clipped(&pts, plot, col, st.px(1.6), None)?
            }
            SeriesStyle::DashedLine => {
                c.polyline_clipped(&pts, plot, col, st.px(1.6), Some((st.px(6.0), st.px(4.0))))?
            }
            SeriesStyle::Points => {}
        }
        if matches!(s.style, SeriesStyle::Points | SeriesStyle::LinePoints) {
            for &(x, y) in &pts {
                if x.is_finite()
                    && y.is_finite()
                    && x >= plot.x0
                    && x <= plot.x1
                    && y >= plot.y0
                    && y <= plot.y1
                {
                    c.circle((x, y), st.px(3.0), col, true, 1.0)?;
                }
            }
        }
    }

    // Markers.
    for mk in &pp.markers {
        if !(mk.x.is_finite() && l.ty(mk.y).is_finite()) {
            continue;
        }
        let (x, y) = l.pt(mk.x, mk.y);
        if x < plot.x0 || x > plot.x1 || y < plot.y0 || y > plot.y1 {
            continue;
        }
        c.circle((x, y), st.px(4.5), mk.rgb, false, st.px(1.5))?;
        let (a0, a1) = (st.px(28.0), st.px(7.0));
        let above = y - a0 - ts * 1.2 > plot.y0;
        let dir = if above { -1.0 } else { 1.0 };
        let start = (x, y + dir * a0);
        let tip = (x, y + dir * a1);
        c.polyline(
            &[start, (x, y + dir * (a1 + st.px(5.0)))],
            mk.rgb,
            1.0,
            st.px(1.5),
        )?;
        let hw = st.px(4.0);
        let hb = y + dir * (a1 + st.px(8.0));
        c.polygon_clipped(&[tip, (x - hw, hb), (x + hw, hb)], plot, mk.rgb, 1.0)?;
        let w = c.text_width(&mk.label, ts);
        // Keep the label inside the plot (never panics: min/max, not clamp).
        let lx = x
            .min(plot.x1 - w / 2.0 - st.px(3.0))
            .max(plot.x0 + w / 2.0 + st.px(3.0));
        let ly = start.1 + dir * st.px(3.0);
        c.text(
            &mk.label,
            lx,
            ly,
            ts,
            HAlign::Center,
            if above { VAlign::Bottom } else { VAlign::Top },
            mk.rgb,
            false,
        )?;
    }

    // Frame and axes.
    c.stroke_rect(plot, INK, lw)?;
    for t in &l.xt {
        let x = l.px_x(t.value);
        c.polyline(&[(x, plot.y1), (x, plot.y1 + tick_len)], INK, 1.0, lw)?;
        c.text(
            &t.label,
            x,
            plot.y1 + tick_len + gap,
            ts,
            HAlign::Center,
            VAlign::Top,
            INK,
            false,
        )?;
    }
    for t in &l.yt {
        let y = plot.y1 - (t.value - l.yr.0) / (l.yr.1 - l.yr.0) * plot.h();
        c.polyline(&[(plot.x0 - tick_len, y), (plot.x0, y)], INK, 1.0, lw)?;
        c.text(
            &t.label,
            plot.x0 - tick_len - gap,
            y,
            ts,
            HAlign::Right,
            VAlign::Center,
            INK,
            false,
        )?;
    }
    c.text(
        &pp.x_label,
        (plot.x0 + plot.x1) / 2.0,
        plot.y1 + tick_len + gap + ts * 0.8 + st.px(8.0),
        ls,
        HAlign::Center,
        VAlign::Top,
        INK,
        false,
    )?;
    c.text(
        &pp.y_label,
        plot.x0 - tick_len - gap - l.yt_w - st.px(5.0) - ls * 0.4,
        (plot.y0 + plot.y1) / 2.0,
        ls,
        HAlign::Center,
        VAlign::Center,
        INK,
        true,
    )?;
    let margin = st.px(4.0);
    c.title(
        &pp.title,
        (plot.x0 + plot.x1) / 2.0,
        plot.y0 - ts * 0.6 - tts * 0.35,
        tts,
        l.cell.x0 + margin,
        l.cell.x1 - margin,
        INK,
    )?;

    // Legend and annotations on translucent boxes, each in the corner that hides the fewest
    // drawn points (legend preferably upper right, annotations upper left).
    let fs = ts;
    let row_h = fs * 1.5;
    let pad = st.px(6.0);
    let inset = st.px(8.0);
    let occupied = occupied(pp, l, st);
    let entries: Vec<(usize, &Series)> = pp
        .series
        .iter()
        .enumerate()
        .filter(|(_, s)| !s.label.is_empty())
        .collect();
    let mut taken = Vec::new();
    if !entries.is_empty() {
        let sample_w = st.px(26.0);
        let w = entries
            .iter()
            .map(|(_, s)| c.text_width(&s.label, fs))
            .fold(0.0, f64::max);
        let bw = sample_w + st.px(6.0) + w + 2.0 * pad;
        let bh = row_h * entries.len() as f64 + pad;
        let bx = place(
            plot,
            inset,
            (bw, bh),
            &LEGEND_ORDER,
            &occupied,
            &[],
            st.px(3.0),
        );
        taken.push(bx);
        c.fill_rect(bx, (255, 255, 255), 0.82)?;
        c.stroke_rect(bx, (190, 190, 190), lw)?;
        for (k, (si, s)) in entries.iter().enumerate() {
            let col = series_color(s, *si);
            let cy = bx.y0 + pad / 2.0 + row_h * (k as f64 + 0.5);
            let (sx0, sx1) = (bx.x0 + pad, bx.x0 + pad + sample_w);
            match s.style {
                SeriesStyle::Line | SeriesStyle::LinePoints => {
                    c.polyline(&[(sx0, cy), (sx1, cy)], col, 1.0, st.px(1.6))?
                }
                SeriesStyle::DashedLine => c.polyline_clipped(
                    &[(sx0, cy), (sx1, cy)],
                    bx,
                    col,
                    st.px(1.6),
                    Some((st.px(6.0), st.px(4.0))),
                )?,
                SeriesStyle::Points => {}
            }
            if matches!(s.style, SeriesStyle::Points | SeriesStyle::LinePoints) {
                c.circle(((sx0 + sx1) / 2.0, cy), st.px(3.0), col, true, 1.0)?;
            }
            c.text(
                &s.label,
                sx1 + st.px(6.0),
                cy,
                fs,
                HAlign::Left,
                VAlign::Center,
                INK,
                false,
            )?;
        }
    }
    if !pp.annotations.is_empty() {
        let w = pp
            .annotations
            .iter()
            .map(|a| c.text_width(a, fs))
            .fold(0.0, f64::max);
        let size = (w + 2.0 * pad, row_h * pp.annotations.len() as f64 + pad);
        let bx = place(
            plot,
            inset,
            size,
            &ANNOTATION_ORDER,
            &occupied,
            &taken,
            st.px(3.0),
        );
        c.fill_rect(bx, (255, 255, 255), 0.8)?;
        for (i, a) in pp.annotations.iter().enumerate() {
            let cy = bx.y0 + pad / 2.0 + row_h * (i as f64 + 0.5);
            c.text(
                a,
                bx.x0 + pad,
                cy,
                fs,
                HAlign::Left,
                VAlign::Center,
                INK,
                false,
            )?;
        }
    }
    Ok(())
}

/// The stretch [lo, hi] of the y = x line inside both axis ranges (data units), if any.
fn diagonal_span(l: &PlotLayout) -> Option<(f64, f64)> {
    let y_range = |v: f64| if l.log_y { 10f64.powf(v) } else { v };
    let (lo, hi) = (l.xr.0.max(y_range(l.yr.0)), l.xr.1.min(y_range(l.yr.1)));
    (lo < hi).then_some((lo, hi))
}

/// A series' points in pixels; NaN where x is not finite (a gap in the line).
fn series_pixels(s: &Series, l: &PlotLayout) -> Vec<(f64, f64)> {
    s.x.iter()
        .zip(&s.y)
        .map(|(&x, &y)| {
            if x.is_finite() {
                l.pt(x, y)
            } else {
                (f64::NAN, f64::NAN)
            }
        })
        .collect()
}

/// Where the panel draws data (pixels): lines, points, error bars, the y = x line and markers.
fn occupied(pp: &PlotPanel, l: &PlotLayout, st: &Style) -> Occupied {
    let mut occ = Occupied::default();
    let step = st.px(3.0);
    for s in &pp.series {
        let pts = series_pixels(s, l);
        match s.style {
            SeriesStyle::Points => pts.iter().for_each(|&p| occ.point(p)),
            _ => occ.polyline(&pts, step),
        }
        if let Some(err) = &s.y_err {
            for ((&x, &y), &e) in s.x.iter().zip(&s.y).zip(err) {
                if x.is_finite() && e.is_finite() {
                    let (lo, hi) = (y - e.abs(), y + e.abs());
                    let lo = if l.log_y && lo <= 0.0 {
                        10f64.powf(l.yr.0)
                    } else {
                        lo
                    };
                    occ.polyline(&[l.pt(x, lo), l.pt(x, hi)], step);
                }
            }
        }
    }
    if pp.diagonal
        && let Some((lo, hi)) = diagonal_span(l)
    {
        {
            occ.polyline(&[l.pt(lo, lo), l.pt(hi, hi)], step);
        }
    }
    for mk in &pp.markers {
        let p = l.pt(mk.x, mk.y);
        // The marker's arrow and label reach up to ~40 px above or below it.
        occ.polyline(&[(p.0, p.1 - st.px(40.0)), (p.0, p.1 + st.px(40.0))], step);
    }
    occ
}
