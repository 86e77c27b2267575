//! Figure layout, rasterisation and PNG encoding.

use crate::canvas::{Canvas, Rect, ensure_font};
use crate::style::{INK, SS, Style};
use crate::{Figure, Panel, RenderError, image_panel, plot_panel};
use std::path::Path;

/// Height in output pixels of the figure-title band added on top when `Figure::title` is non-empty.
pub const FIGURE_TITLE_BAND_PX: u32 = 40;

/// Largest figure accepted, in output pixels.
const MAX_PIXELS: u64 = 60_000_000;

enum Layout {
    Image(image_panel::ImageLayout),
    Plot(plot_panel::PlotLayout),
    Empty,
}

/// Output size (w, h) in pixels of `fig`, after validating the layout parameters.
fn output_size(fig: &Figure) -> Result<(u32, u32, usize), RenderError> {
    if fig.panels.is_empty() {
        return Err(RenderError::EmptyData("figure has no panels".into()));
    }
    if fig.ncols == 0 {
        return Err(RenderError::InvalidLayout(
            "ncols must be at least 1".into(),
        ));
    }
    let (pw, ph) = fig.panel_size_px;
    if pw < 120 || ph < 100 {
        return Err(RenderError::InvalidLayout(format!(
            "panel size {pw}x{ph} px is too small (minimum 120x100)"
        )));
    }
    let ncols = fig.ncols.min(fig.panels.len());
    let nrows = fig.panels.len().div_ceil(ncols);
    let band = if fig.title.is_empty() {
        0
    } else {
        FIGURE_TITLE_BAND_PX as u64
    };
    let w = ncols as u64 * pw as u64;
    let h = nrows as u64 * ph as u64 + band;
    if w * h > MAX_PIXELS || w > 30_000 || h > 30_000 {
        return Err(RenderError::InvalidLayout(format!(
            "figure of {w}x{h} px is too large"
        )));
    }
    Ok((w as u32, h as u32, ncols))
}

/// Render `fig` to an RGB8 buffer; returns (width, height, row-major RGB bytes) in output pixels.
pub fn render_rgb(fig: &Figure) -> Result<(u32, u32, Vec<u8>), RenderError> {
    ensure_font()?;
    let (w, h, ncols) = output_size(fig)?;
    let (sw, sh) = (w * SS, h * SS);
    let (pw, ph) = fig.panel_size_px;
    let band = if fig.title.is_empty() {
        0
    } else {
        FIGURE_TITLE_BAND_PX
    };
    let style = Style::for_panel(pw, ph);

    // 1. Validate and lay out every panel (text measured on a scratch surface).
    let mut scratch = vec![0u8; 3];
    // Each row's panels leave room for its longest title, so that the row's plots line up.
    let title_of = |p: &Panel| match p {
        Panel::Image(ip) => crate::canvas::title_lines(&ip.title),
        Panel::Plot(pp) => crate::canvas::title_lines(&pp.title),
        Panel::Empty => 1,
    };
    let row_title_lines: Vec<usize> = fig
        .panels
        .chunks(ncols.max(1))
        .map(|row| row.iter().map(title_of).max().unwrap_or(1))
        .collect();
    let layouts: Vec<Layout> = {
        let measurer = Canvas::new(&mut scratch, 1, 1)?;
        fig.panels
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let (r, c) = (i / ncols, i % ncols);
                let cell = Rect::new(
                    (c as u32 * pw * SS) as f64,
                    ((band + r as u32 * ph) * SS) as f64,
                    (pw * SS) as f64,
                    (ph * SS) as f64,
                );
                let lines = row_title_lines[r];
                Ok(match p {
                    Panel::Image(ip) => {
                        Layout::Image(image_panel::layout(ip, cell, &style, &measurer, lines)?)
                    }
                    Panel::Plot(pp) => {
                        Layout::Plot(plot_panel::layout(pp, cell, &style, &measurer, lines)?)
                    }
                    Panel::Empty => Layout::Empty,
                })
            })
            .collect::<Result<_, RenderError>>()?
    };

    // 2. Raster fills (images, colour bars) straight into the buffer.
    let mut buf = vec![255u8; sw as usize * sh as usize * 3];
    for (p, l) in fig.panels.iter().zip(&layouts) {
        if let (Panel::Image(ip), Layout::Image(il)) = (p, l) {
            image_panel::fill(ip, il, &mut buf, sw as usize);
        }
    }

    // 3. Vector drawing on top.
    {
        let canvas = Canvas::new(&mut buf, sw, sh)?;
        if band > 0 {
            let fs = 20.0 * SS as f64;
            let margin = 8.0 * SS as f64;
            canvas.title(
                &fig.title,
                sw as f64 / 2.0,
                (band * SS) as f64 * 0.55 + fs * 0.313,
                fs,
                margin,
                sw as f64 - margin,
                INK,
            )?;
        }
        for (p, l) in fig.panels.iter().zip(&layouts) {
            match (p, l) {
                (Panel::Image(ip), Layout::Image(il)) => {
                    image_panel::draw(ip, il, &style, &canvas)?
                }
                (Panel::Plot(pp), Layout::Plot(pl)) => plot_panel::draw(pp, pl, &style, &canvas)?,
                _ => {}
            }
        }
        canvas.finish()?;
    }

    Ok((w, h, downsample(&buf, sw as usize, sh as usize)))
}

/// Box-filter an SS x SS supersampled RGB buffer down to output size.
fn downsample(buf: &[u8], sw: usize, sh: usize) -> Vec<u8> {
    let s = SS as usize;
    let (w, h) = (sw / s, sh / s);
    let mut out = vec![0u8; w * h * 3];
    let n = (s * s) as u32;
    for y in 0..h {
        for x in 0..w {
            for ch in 0..3 {
                let mut acc = 0u32;
                for dy in 0..s {
                    let row = (y * s + dy) * sw;
                    for dx in 0..s {
                        acc += buf[(row + x * s + dx) * 3 + ch] as u32;
                    }
                }
                out[(y * w + x) * 3 + ch] = ((acc + n / 2) / n) as u8;
            }
        }
    }
    out
}

/// Render `fig` and return the PNG-encoded bytes (for embedding in a report).
pub fn render_png_bytes(fig: &Figure) -> Result<Vec<u8>, RenderError> {
    let (w, h, rgb) = render_rgb(fig)?;
    encode_png(w, h, &rgb)
}

/// Render `fig` and write it as a PNG file at `path`.
pub fn render_png(fig: &Figure, path: &Path) -> Result<(), RenderError> {
    let bytes = render_png_bytes(fig)?;
    std::fs::write(path, bytes).map_err(|source| RenderError::Io {
        path: path.to_path_buf(),
        source,
    })
}

fn encode_png(w: u32, h: u32, rgb: &[u8]) -> Result<Vec<u8>, RenderError> {
    let enc = |e: png::EncodingError| RenderError::Encode(e.to_string());
    let mut out = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut out, w, h);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header().map_err(enc)?;
        writer.write_image_data(rgb).map_err(enc)?;
        writer.finish().map_err(enc)?;
    }
    Ok(out)
}
