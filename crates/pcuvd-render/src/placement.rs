//! Where a box of text (a legend, annotations) goes inside a plot area: the candidate corner
//! that covers the fewest drawn points, so that text never hides data when there is room.

use crate::canvas::Rect;

/// Pixels a text box should not cover: points, and samples along polylines.
#[derive(Debug, Default)]
pub(crate) struct Occupied {
    pts: Vec<(f64, f64)>,
}

impl Occupied {
    /// One drawn point (ignored unless finite).
    pub(crate) fn point(&mut self, p: (f64, f64)) {
        if p.0.is_finite() && p.1.is_finite() {
            self.pts.push(p);
        }
    }

    /// Samples every `step` pixels along a polyline; a non-finite vertex breaks it.
    pub(crate) fn polyline(&mut self, pts: &[(f64, f64)], step: f64) {
        let step = step.max(1.0);
        for (i, &p) in pts.iter().enumerate() {
            self.point(p);
            let Some(&q) = pts.get(i + 1) else { break };
            if !(p.0.is_finite() && p.1.is_finite() && q.0.is_finite() && q.1.is_finite()) {
                continue;
            }
            let len = (q.0 - p.0).hypot(q.1 - p.1);
            // Far-outside segments (clipped away when drawn) need no samples.
            let n = ((len / step) as usize).min(4096);
            for k in 1..n {
                let t = k as f64 / n as f64;
                self.point((p.0 + t * (q.0 - p.0), p.1 + t * (q.1 - p.1)));
            }
        }
    }

    /// Points inside `r` grown by `margin`.
    fn count(&self, r: Rect, margin: f64) -> usize {
        self.pts
            .iter()
            .filter(|&&(x, y)| {
                x >= r.x0 - margin && x <= r.x1 + margin && y >= r.y0 - margin && y <= r.y1 + margin
            })
            .count()
    }
}

/// Where a box may sit inside the area.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Corner {
    TopRight,
    TopLeft,
    BottomRight,
    BottomLeft,
    TopCentre,
    BottomCentre,
}

/// Every corner, legends' order of preference (upper right first).
pub(crate) const LEGEND_ORDER: [Corner; 6] = [
    Corner::TopRight,
    Corner::TopLeft,
    Corner::BottomRight,
    Corner::BottomLeft,
    Corner::TopCentre,
    Corner::BottomCentre,
];

/// Every corner, annotations' order of preference (upper left first).
pub(crate) const ANNOTATION_ORDER: [Corner; 6] = [
    Corner::TopLeft,
    Corner::BottomLeft,
    Corner::TopRight,
    Corner::BottomRight,
    Corner::TopCentre,
    Corner::BottomCentre,
];

fn box_at(area: Rect, inset: f64, (w, h): (f64, f64), corner: Corner) -> Rect {
    let (left, right) = (area.x0 + inset, area.x1 - inset - w);
    let centre = (area.x0 + area.x1 - w) / 2.0;
    let (top, bottom) = (area.y0 + inset, area.y1 - inset - h);
    let (x, y) = match corner {
        Corner::TopRight => (right, top),
        Corner::TopLeft => (left, top),
        Corner::BottomRight => (right, bottom),
        Corner::BottomLeft => (left, bottom),
        Corner::TopCentre => (centre, top),
        Corner::BottomCentre => (centre, bottom),
    };
    Rect::new(x, y, w, h)
}

fn overlaps(a: Rect, b: Rect) -> bool {
    a.x0 < b.x1 && b.x0 < a.x1 && a.y0 < b.y1 && b.y0 < a.y1
}

/// A `size` box `inset` inside `area`, at the corner of `order` that covers the fewest occupied
/// points (within `margin`) and overlaps no box of `taken`; ties go to the earlier corner.
pub(crate) fn place(
    area: Rect,
    inset: f64,
    size: (f64, f64),
    order: &[Corner],
    occupied: &Occupied,
    taken: &[Rect],
    margin: f64,
) -> Rect {
    let boxes: Vec<Rect> = order
        .iter()
        .map(|&c| box_at(area, inset, size, c))
        .collect();
    let free: Vec<Rect> = boxes
        .iter()
        .copied()
        .filter(|b| !taken.iter().any(|t| overlaps(*b, *t)))
        .collect();
    let pool = if free.is_empty() { &boxes } else { &free };
    pool.iter()
        .copied()
        .min_by_key(|&b| occupied.count(b, margin))
        .unwrap_or_else(|| box_at(area, inset, size, Corner::TopRight))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_box_avoids_the_points() {
        let area = Rect::new(0.0, 0.0, 100.0, 100.0);
        let mut occ = Occupied::default();
        // A line along the top edge: the box goes to the bottom.
        occ.polyline(&[(0.0, 5.0), (100.0, 5.0)], 2.0);
        let b = place(area, 2.0, (30.0, 20.0), &LEGEND_ORDER, &occ, &[], 1.0);
        assert_eq!(b, box_at(area, 2.0, (30.0, 20.0), Corner::BottomRight));
        // The annotation then takes the other bottom corner, clear of the legend.
        let a = place(area, 2.0, (30.0, 20.0), &ANNOTATION_ORDER, &occ, &[b], 1.0);
        assert_eq!(a, box_at(area, 2.0, (30.0, 20.0), Corner::BottomLeft));
    }

    #[test]
    fn ties_keep_the_preferred_corner() {
        let area = Rect::new(0.0, 0.0, 100.0, 100.0);
        let b = place(
            area,
            2.0,
            (30.0, 20.0),
            &LEGEND_ORDER,
            &Occupied::default(),
            &[],
            1.0,
        );
        assert_eq!(b, box_at(area, 2.0, (30.0, 20.0), Corner::TopRight));
    }
}
