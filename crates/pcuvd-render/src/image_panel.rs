//! Image panels: letterboxed map in mm (or a filled/upward plot with custom axes),
//! colour bar, mask/underlay, vector glyphs, polylines.

use crate::canvas::{Canvas, HAlign, Rect, VAlign};
use crate::colormap::{Lut, colormap_rgb};
use crate::placement::{LEGEND_ORDER, Occupied, place};
use crate::style::{INK, MIN_HEIGHT_PER_480, SS, Style, snap};
use crate::ticks::{Tick, linear_ticks};
use crate::{ImagePanel, Polyline, RenderError, VectorOverlay};

/// Geometry of one laid-out image panel (supersampled pixels).
pub(crate) struct ImageLayout {
    /// The grid cell this panel lives in.
    cell: Rect,
    /// Plotting rectangle (the image itself), integer-aligned.
    plot: Rect,
    /// Colour-bar rectangle, integer-aligned.
    cbar: Rect,
    /// Image edges in mm: (x_lo, x_hi, z_lo, z_hi); z_lo is drawn at the top unless `y_up`.
    ext: (f64, f64, f64, f64),
    /// z_hi is drawn at the top (plot-style vertical axis).
    y_up: bool,
    xt: Vec<Tick>,
    zt: Vec<Tick>,
    ct: Vec<Tick>,
    /// Widest z tick label (px), for placing the rotated axis label.
    zt_w: f64,
    /// Height of the cell around the image area: title, labels and margins (px).
    margin_v: f64,
}

impl ImageLayout {
    fn px_x(&self, x_mm: f64) -> f64 {
        let (x0, x1, _, _) = self.ext;
        self.plot.x0 + (x_mm - x0) / (x1 - x0) * self.plot.w()
    }
    fn px_z(&self, z_mm: f64) -> f64 {
        let (_, _, z0, z1) = self.ext;
        if self.y_up {
            self.plot.y1 - (z_mm - z0) / (z1 - z0) * self.plot.h()
        } else {
            self.plot.y0 + (z_mm - z0) / (z1 - z0) * self.plot.h()
        }
    }
    /// Supersampled pixels per mm (horizontal units; equal on both axes unless filled).
    fn px_per_mm(&self) -> f64 {
        self.plot.w() / (self.ext.1 - self.ext.0)
    }
}

fn check_pair(name: &str, p: (f64, f64)) -> Result<(), RenderError> {
    if p.0.is_finite() && p.1.is_finite() {
        Ok(())
    } else {
        Err(RenderError::InvalidRange(format!(
            "{name} = ({}, {}) is not finite",
            p.0, p.1
        )))
    }
}

/// Centre spacing (signed) along one axis, given the first/last centre and count.
fn spacing(name: &str, ends: (f64, f64), n: usize, other: f64) -> Result<f64, RenderError> {
    if n > 1 {
        let d = (ends.1 - ends.0) / (n - 1) as f64;
        if d == 0.0 {
            return Err(RenderError::InvalidRange(format!(
                "{name} first and last centres are equal ({}) but there are {n} samples",
                ends.0
            )));
        }
        Ok(d)
    } else {
        // Single sample: borrow the other axis' spacing (or 1 mm).
        Ok(if other.is_finite() && other > 0.0 {
            other
        } else {
            1.0
        })
    }
}

fn validate(ip: &ImagePanel) -> Result<(), RenderError> {
    let (nz, nx) = ip.data.dim();
    if nz == 0 || nx == 0 {
        return Err(RenderError::EmptyData(format!(
            "image '{}' has shape ({nz}, {nx})",
            ip.title
        )));
    }
    if let Some(m) = &ip.mask
        && m.dim() != (nz, nx)
    {
        return Err(RenderError::ShapeMismatch(format!(
            "mask shape {:?} != data shape ({nz}, {nx})",
            m.dim()
        )));
    }
    if let Some(b) = &ip.background
        && b.dim() != (nz, nx)
    {
        return Err(RenderError::ShapeMismatch(format!(
            "background shape {:?} != data shape ({nz}, {nx})",
            b.dim()
        )));
    }
    check_pair("x_mm", ip.x_mm)?;
    check_pair("z_mm", ip.z_mm)?;
    check_pair("range", ip.range)?;
    if ip.range.0 >= ip.range.1 {
        return Err(RenderError::InvalidRange(format!(
            "colour range ({}, {}) must be increasing",
            ip.range.0, ip.range.1
        )));
    }
    for (i, l) in ip.lines.iter().enumerate() {
        if l.x_mm.len() != l.z_mm.len() {
            return Err(RenderError::ShapeMismatch(format!(
                "line {i}: {} x values but {} z values",
                l.x_mm.len(),
                l.z_mm.len()
            )));
        }
    }
    if let Some(v) = &ip.arrows {
        validate_overlay(v)?;
    }
    Ok(())
}

fn validate_overlay(v: &VectorOverlay) -> Result<(), RenderError> {
    let n = v.x_mm.len();
    if v.z_mm.len() != n || v.vx.len() != n || v.vz.len() != n {
        return Err(RenderError::ShapeMismatch(format!(
            "vector overlay lengths differ: x {}, z {}, vx {}, vz {}",
            n,
            v.z_mm.len(),
            v.vx.len(),
            v.vz.len()
        )));
    }
    if !(v.scale_mm.is_finite() && v.scale_mm > 0.0) {
        return Err(RenderError::InvalidRange(format!(
            "vector scale_mm must be finite and > 0, got {}",
            v.scale_mm
        )));
    }
    check_pair("speed_range", v.speed_range)?;
    if !(v.speed_range.1 > v.speed_range.0 && v.speed_range.1 > 0.0) {
        return Err(RenderError::InvalidRange(format!(
            "speed_range ({}, {}) must be increasing with a positive maximum",
            v.speed_range.0, v.speed_range.1
        )));
    }
    Ok(())
}

fn max_width(m: &Canvas, ticks: &[Tick], size: f64) -> f64 {
    ticks
        .iter()
        .map(|t| m.text_width(&t.label, size))
        .fold(0.0, f64::max)
}

/// Validate `ip` and place it inside `cell`, below a title band of `title_lines` lines (at
/// least its own title's: the most of its row's, so that a row's plots line up).
pub(crate) fn layout(
    ip: &ImagePanel,
    cell: Rect,
    st: &Style,
    m: &Canvas,
    title_lines: usize,
) -> Result<ImageLayout, RenderError> {
    validate(ip)?;
    let (nz, nx) = ip.data.dim();
    let dx0 = if nx > 1 {
        ((ip.x_mm.1 - ip.x_mm.0) / (nx - 1) as f64).abs()
    } else {
        f64::NAN
    };
    let dz0 = if nz > 1 {
        ((ip.z_mm.1 - ip.z_mm.0) / (nz - 1) as f64).abs()
    } else {
        f64::NAN
    };
    let dx = spacing("x_mm", ip.x_mm, nx, dz0)?.abs();
    let dz = spacing("z_mm", ip.z_mm, nz, dx0)?.abs();
    let ext = (
        ip.x_mm.0.min(ip.x_mm.1) - dx / 2.0,
        ip.x_mm.0.max(ip.x_mm.1) + dx / 2.0,
        ip.z_mm.0.min(ip.z_mm.1) - dz / 2.0,
        ip.z_mm.0.max(ip.z_mm.1) + dz / 2.0,
    );
    let (w_mm, h_mm) = (ext.1 - ext.0, ext.3 - ext.2);
    if !(w_mm.is_finite() && h_mm.is_finite() && w_mm > 0.0 && h_mm > 0.0) {
        return Err(RenderError::InvalidRange(
            "image extent is degenerate".into(),
        ));
    }

    let (ts, ls, tts) = (st.tick(), st.label(), st.title());
    let tick_len = st.px(4.0);
    let gap = st.px(3.0);
    let zt0 = linear_ticks(ext.2, ext.3, 8);
    let ct0 = linear_ticks(ip.range.0, ip.range.1, 8);
    let zt_w0 = max_width(m, &zt0, ts);
    let ct_w0 = max_width(m, &ct0, ts);

    let lines = title_lines.max(crate::canvas::title_lines(&ip.title));
    let title_h = tts * 1.7 + crate::canvas::extra_title_height(lines, tts);
    let top_pad = ts * 1.9;
    let left = st.px(6.0) + ls * 1.2 + st.px(5.0) + zt_w0 + gap + tick_len;
    let bottom = tick_len + gap + ts * 0.8 + st.px(8.0) + ls * 0.8 + st.px(8.0);
    let (cb_gap, cb_w) = (st.px(12.0), st.px(14.0));
    let right = cb_gap + cb_w + tick_len + gap + ct_w0 + st.px(8.0);

    let ax0 = cell.x0 + left;
    let ax1 = cell.x1 - right;
    let ay0 = cell.y0 + title_h + top_pad;
    let ay1 = cell.y1 - bottom;
    let (aw, ah) = (ax1 - ax0, ay1 - ay0);
    if aw < st.px(20.0) || ah < st.px(20.0) {
        return Err(RenderError::InvalidLayout(
            "panel too small for its labels".into(),
        ));
    }
    let (y_up, fill) = ip
        .axes
        .as_ref()
        .map_or((false, false), |a| (a.y_up, a.fill));
    // Snap to whole output pixels so edges and frames stay crisp after downsampling.
    let (px0, py0, pw, ph) = if fill {
        let (px0, py0) = (snap(ax0), snap(ay0));
        (px0, py0, snap(ax1) - px0, snap(ay1) - py0)
    } else {
        let s = (aw / w_mm).min(ah / h_mm);
        let (pw, ph) = (snap((w_mm * s).max(2.0)), snap((h_mm * s).max(2.0)));
        let px0 = snap(ax0 + (aw - pw) / 2.0);
        let py0 = snap(ay0 + (ah - ph) / 2.0);
        (px0, py0, pw, ph)
    };
    let plot = Rect::new(px0, py0, pw, ph);
    // The colour bar spans the image height, but at least ~150 px (within the free area).
    let cb_h = snap(ph.max(st.px(150.0).min(ah)));
    let cb_y0 = snap(((py0 + ph / 2.0) - cb_h / 2.0).min(ay1 - cb_h).max(ay0));
    let cbar = Rect::new(snap(plot.x1 + cb_gap), cb_y0, snap(cb_w), cb_h);

    // Final tick counts from the actual pixel sizes.
    let xt_probe = linear_ticks(ext.0, ext.1, 8);
    let xw = max_width(m, &xt_probe, ts).max(ts);
    let nx_ticks = ((pw / (xw + ts * 1.5)) as usize + 1).clamp(2, 8);
    let nz_ticks = ((ph / (ts * 2.6)) as usize).clamp(1, 8);
    let nc_ticks = ((cb_h / (ts * 2.6)) as usize).clamp(2, 8);
    let xt = linear_ticks(ext.0, ext.1, nx_ticks);
    let zt = linear_ticks(ext.2, ext.3, nz_ticks);
    let ct = linear_ticks(ip.range.0, ip.range.1, nc_ticks);
    let zt_w = max_width(m, &zt, ts);
    Ok(ImageLayout {
        cell,
        plot,
        cbar,
        ext,
        y_up,
        xt,
        zt,
        ct,
        zt_w,
        margin_v: title_h + top_pad + bottom,
    })
}

/// Size (w, h) in output pixels of a figure cell `width_px` wide in which `ip`'s image fills the
/// width: the height follows the image's aspect ratio (equal mm on both axes) plus the title,
/// labels and margins (at most twice the width), so that a wide, shallow region gets no tall
/// empty frame. Panels with `axes.fill` keep a 4:3 cell. Errors as rendering the panel would.
pub(crate) fn fitted_size(ip: &ImagePanel, width_px: u32) -> Result<(u32, u32), RenderError> {
    if ip.axes.as_ref().is_some_and(|a| a.fill) {
        return Ok((width_px, (width_px * 3 / 4).max(100)));
    }
    let mut scratch = vec![0u8; 3];
    let m = Canvas::new(&mut scratch, 1, 1)?;
    let mut h = width_px;
    // The text sizes scale with the cell, so iterate to a fixed point (a few steps suffice).
    for _ in 0..4 {
        let st = Style::for_panel(width_px, h);
        // A cell tall enough that the image is limited by its width.
        let cell = Rect::new(
            0.0,
            0.0,
            (width_px * SS) as f64,
            (width_px * SS * 64) as f64,
        );
        let l = layout(ip, cell, &st, &m, 1)?;
        let need = ((l.margin_v + l.plot.h()) / SS as f64).ceil() as u32;
        // Room for a readable colour bar, and at least the smallest panel accepted.
        // At least the height below which the text would shrink, and room for a readable
        // colour bar; at most twice the width.
        let text_min = (MIN_HEIGHT_PER_480 * width_px as f64 / 480.0).ceil() as u32;
        h = need
            .max(text_min)
            .max((st.px(190.0) / SS as f64) as u32)
            .clamp(100, 2 * width_px);
    }
    Ok((width_px, h))
}

/// Fill the image and colour-bar pixels of a laid-out panel into an RGB buffer `buf_w` wide.
pub(crate) fn fill(ip: &ImagePanel, l: &ImageLayout, buf: &mut [u8], buf_w: usize) {
    let (nz, nx) = ip.data.dim();
    let lut = Lut::new(ip.colormap, ip.range);
    let (x0, y0) = (l.plot.x0 as usize, l.plot.y0 as usize);
    let (pw, ph) = (l.plot.w() as usize, l.plot.h() as usize);
    // Nearest data index for every screen column / row.
    let index = |n: usize, ends: (f64, f64), lo: f64, hi: f64, count: usize| -> Vec<usize> {
        (0..count)
            .map(|i| {
                if n == 1 {
                    return 0;
                }
                let mm = lo + (i as f64 + 0.5) / count as f64 * (hi - lo);
                let f = (mm - ends.0) / (ends.1 - ends.0) * (n - 1) as f64;
                (f.round().max(0.0) as usize).min(n - 1)
            })
            .collect()
    };
    let cols = index(nx, ip.x_mm, l.ext.0, l.ext.1, pw);
    let mut rows = index(nz, ip.z_mm, l.ext.2, l.ext.3, ph);
    if l.y_up {
        // Screen row 0 shows the largest coordinate.
        rows.reverse();
    }
    let mut row_rgb = vec![0u8; pw * 3];
    for (py, &r) in rows.iter().enumerate() {
        for (px, &c) in cols.iter().enumerate() {
            let visible = ip.mask.as_ref().is_none_or(|m| m[(r, c)]);
            let rgb = if visible {
                lut.rgb(ip.data[(r, c)])
            } else {
                let g = ip.background.as_ref().map_or(0.0, |b| {
                    let v = b[(r, c)];
                    if v.is_finite() {
                        v.clamp(0.0, 1.0)
                    } else {
                        0.0
                    }
                });
                // As in the colour map: ½ added and truncated, not a libm call per pixel.
                let g = (g * 255.0 + 0.5) as u8;
                [g, g, g]
            };
            row_rgb[px * 3..px * 3 + 3].copy_from_slice(&rgb);
        }
        let start = ((y0 + py) * buf_w + x0) * 3;
        buf[start..start + pw * 3].copy_from_slice(&row_rgb);
    }
    // Colour bar: top = range max.
    let (cx0, cw) = (l.cbar.x0 as usize, l.cbar.w() as usize);
    let (cy0, ch) = (l.cbar.y0 as usize, l.cbar.h() as usize);
    let (lo, hi) = ip.range;
    for py in 0..ch {
        let v = hi - (py as f64 + 0.5) / ch as f64 * (hi - lo);
        let rgb = lut.rgb(v);
        let start = ((cy0 + py) * buf_w + cx0) * 3;
        for px in 0..cw {
            buf[start + px * 3..start + px * 3 + 3].copy_from_slice(&rgb);
        }
    }
}

/// Draw overlays, axes, colour bar annotations and title of a laid-out panel.
pub(crate) fn draw(
    ip: &ImagePanel,
    l: &ImageLayout,
    st: &Style,
    c: &Canvas,
) -> Result<(), RenderError> {
    let plot = l.plot;
    let (ts, ls, tts) = (st.tick(), st.label(), st.title());
    let tick_len = st.px(4.0);
    let gap = st.px(3.0);
    let lw = st.px(1.0);

    // Overlays, clipped to the image.
    for line in &ip.lines {
        let pts: Vec<(f64, f64)> = line
            .x_mm
            .iter()
            .zip(&line.z_mm)
            .map(|(&x, &z)| (l.px_x(x), l.px_z(z)))
            .collect();
        let dash = line.dashed.then(|| (st.px(6.0), st.px(4.0)));
        c.polyline_clipped(&pts, plot, line.rgb, st.px(1.6), dash)?;
    }
    if let Some(v) = &ip.arrows {
        draw_glyphs(v, l, st, c)?;
    }
    draw_legend(ip, l, st, c)?;

    // Frame, just outside the image so no data pixel is hidden.
    let t = snap(lw).max(SS as f64);
    let outside = |r: Rect| Rect {
        x0: r.x0 - t,
        y0: r.y0 - t,
        x1: r.x1 + t,
        y1: r.y1 + t,
    };
    c.stroke_rect(outside(plot), INK, t)?;

    // x axis.
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
    let (x_label, y_label) = ip.axes.as_ref().map_or(("x (mm)", "z (mm)"), |a| {
        (a.x_label.as_str(), a.y_label.as_str())
    });
    c.text(
        x_label,
        (plot.x0 + plot.x1) / 2.0,
        plot.y1 + tick_len + gap + ts * 0.8 + st.px(8.0),
        ls,
        HAlign::Center,
        VAlign::Top,
        INK,
        false,
    )?;

    // z axis (depth downward, or upward with `y_up`).
    for t in &l.zt {
        let y = l.px_z(t.value);
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
        y_label,
        plot.x0 - tick_len - gap - l.zt_w - st.px(5.0) - ls * 0.4,
        (plot.y0 + plot.y1) / 2.0,
        ls,
        HAlign::Center,
        VAlign::Center,
        INK,
        true,
    )?;

    // Colour bar.
    let cb = l.cbar;
    c.stroke_rect(outside(cb), INK, t)?;
    let (lo, hi) = ip.range;
    for t in &l.ct {
        let y = cb.y1 - (t.value - lo) / (hi - lo) * cb.h();
        c.polyline(&[(cb.x1, y), (cb.x1 + tick_len, y)], INK, 1.0, lw)?;
        c.text(
            &t.label,
            cb.x1 + tick_len + gap,
            y,
            ts,
            HAlign::Left,
            VAlign::Center,
            INK,
            false,
        )?;
    }
    // The cell's own margin: a label that reached the edge would touch the next panel's.
    let margin = st.px(8.0);
    if !ip.colorbar_label.is_empty() {
        // Centred over the bar where it fits; else shifted left, and shrunk if even the
        // cell is too narrow.
        c.title(
            &ip.colorbar_label,
            (cb.x0 + cb.x1) / 2.0,
            cb.y0 - ts * 0.6,
            ts,
            l.cell.x0 + margin,
            l.cell.x1 - margin,
            INK,
        )?;
    }

    // Title, centred over the image.
    c.title(
        &ip.title,
        (plot.x0 + plot.x1) / 2.0,
        plot.y0.min(l.cbar.y0) - ts * 1.9 - tts * 0.35,
        tts,
        l.cell.x0 + margin,
        l.cell.x1 - margin,
        INK,
    )?;
    Ok(())
}

/// Slender isosceles triangles centred at each (x, z), pointing along (vx, vz).
fn draw_glyphs(
    v: &VectorOverlay,
    l: &ImageLayout,
    st: &Style,
    c: &Canvas,
) -> Result<(), RenderError> {
    let (s_lo, s_hi) = v.speed_range;
    let ppm = l.px_per_mm();
    for i in 0..v.x_mm.len() {
        let (x, z, vx, vz) = (v.x_mm[i], v.z_mm[i], v.vx[i], v.vz[i]);
        if !(x.is_finite() && z.is_finite() && vx.is_finite() && vz.is_finite()) {
            continue;
        }
        let speed = vx.hypot(vz);
        if speed <= 0.0 {
            continue;
        }
        let len = v.scale_mm * (speed / s_hi).min(1.0) * ppm;
        if len < st.px(0.5) {
            continue;
        }
        let (ux, uz) = (vx / speed, vz / speed);
        let uz = if l.y_up { -uz } else { uz };
        let (nx, nz) = (-uz, ux);
        let half_w = (0.17 * len).max(st.px(0.9));
        let (cx, cz) = (l.px_x(x), l.px_z(z));
        let tip = (cx + ux * len / 2.0, cz + uz * len / 2.0);
        let base = (cx - ux * len / 2.0, cz - uz * len / 2.0);
        let tri = [
            tip,
            (base.0 + nx * half_w, base.1 + nz * half_w),
            (base.0 - nx * half_w, base.1 - nz * half_w),
        ];
        let rgb = colormap_rgb(v.colormap, (speed - s_lo) / (s_hi - s_lo));
        c.polygon_clipped(&tri, l.plot, rgb, 1.0)?;
    }
    Ok(())
}

/// A legend of the labelled lines (one entry per label) on a dark translucent box, in the corner
/// of the image that the lines and glyphs leave free.
fn draw_legend(
    ip: &ImagePanel,
    l: &ImageLayout,
    st: &Style,
    c: &Canvas,
) -> Result<(), RenderError> {
    let mut entries: Vec<&Polyline> = Vec::new();
    for line in &ip.lines {
        if !line.label.is_empty() && !entries.iter().any(|e| e.label == line.label) {
            entries.push(line);
        }
    }
    if entries.is_empty() {
        return Ok(());
    }
    let mut occupied = Occupied::default();
    for line in &ip.lines {
        let pts: Vec<(f64, f64)> = line
            .x_mm
            .iter()
            .zip(&line.z_mm)
            .map(|(&x, &z)| (l.px_x(x), l.px_z(z)))
            .collect();
        occupied.polyline(&pts, st.px(3.0));
    }
    if let Some(v) = &ip.arrows {
        for (&x, &z) in v.x_mm.iter().zip(&v.z_mm) {
            occupied.point((l.px_x(x), l.px_z(z)));
        }
    }
    let fs = st.tick();
    let row_h = fs * 1.5;
    let pad = st.px(5.0);
    let sample_w = st.px(24.0);
    let text_w = entries
        .iter()
        .map(|e| c.text_width(&e.label, fs))
        .fold(0.0, f64::max);
    let size = (
        sample_w + st.px(6.0) + text_w + 2.0 * pad,
        row_h * entries.len() as f64 + pad,
    );
    let bx = place(
        l.plot,
        st.px(6.0),
        size,
        &LEGEND_ORDER,
        &occupied,
        &[],
        st.px(3.0),
    );
    c.fill_rect(bx, (0, 0, 0), 0.6)?;
    c.stroke_rect(bx, (150, 150, 150), st.px(1.0))?;
    for (k, e) in entries.iter().enumerate() {
        let cy = bx.y0 + pad / 2.0 + row_h * (k as f64 + 0.5);
        let (sx0, sx1) = (bx.x0 + pad, bx.x0 + pad + sample_w);
        let dash = e.dashed.then(|| (st.px(6.0), st.px(4.0)));
        c.polyline_clipped(&[(sx0, cy), (sx1, cy)], bx, e.rgb, st.px(1.8), dash)?;
        c.text(
            &e.label,
            sx1 + st.px(6.0),
            cy,
            fs,
            HAlign::Left,
            VAlign::Center,
            (240, 240, 240),
            false,
        )?;
    }
    Ok(())
}
