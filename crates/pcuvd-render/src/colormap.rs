//! Colour maps.

/// Colour maps for image panels and vector glyphs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Colormap {
    /// Black (0) to white (1).
    Gray,
    /// Black, red, yellow, white (matplotlib "hot").
    Hot,
    /// Perceptually uniform dark blue to yellow.
    #[default]
    Viridis,
    /// Diverging: blue for 0 (negative), white for 0.5 (zero), red for 1 (positive).
    RedBlue,
    /// Perceptually uniform black to light yellow via purple.
    Magma,
    /// Diverging, [`Colormap::RedBlue`] reversed: red for 0 (negative), white for 0.5 (zero),
    /// blue for 1 (positive); e.g. an axial velocity positive away from the probe, drawn with
    /// red = toward it.
    BlueRed,
}

/// Colour shown for NaN values (dark grey).
pub(crate) const NAN_RGB: (u8, u8, u8) = (64, 64, 64);

fn unit_to_u8(v: f64) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// sRGB colour of `cmap` at position `t` in [0, 1] (clamped); NaN gives dark grey.
pub fn colormap_rgb(cmap: Colormap, t: f64) -> (u8, u8, u8) {
    if t.is_nan() {
        return NAN_RGB;
    }
    let t = t.clamp(0.0, 1.0);
    match cmap {
        Colormap::Gray => {
            let g = unit_to_u8(t);
            (g, g, g)
        }
        Colormap::Hot => {
            // matplotlib "hot" segment data.
            let r = 0.0416 + (1.0 - 0.0416) * (t / 0.365_079).min(1.0);
            let g = ((t - 0.365_079) / (0.746_032 - 0.365_079)).clamp(0.0, 1.0);
            let b = ((t - 0.746_032) / (1.0 - 0.746_032)).clamp(0.0, 1.0);
            (unit_to_u8(r), unit_to_u8(g), unit_to_u8(b))
        }
        Colormap::Viridis => colorous::VIRIDIS.eval_continuous(t).as_tuple(),
        Colormap::Magma => colorous::MAGMA.eval_continuous(t).as_tuple(),
        // colorous RED_BLUE runs red (0) -> blue (1); flip so negative = blue.
        Colormap::RedBlue => colorous::RED_BLUE.eval_continuous(1.0 - t).as_tuple(),
        Colormap::BlueRed => colorous::RED_BLUE.eval_continuous(t).as_tuple(),
    }
}

/// Precomputed colour table for fast per-pixel lookups.
pub(crate) struct Lut {
    table: Vec<[u8; 3]>,
    lo: f64,
    inv_span: f64,
}

impl Lut {
    const N: usize = 1024;

    /// Table for values in `range` (lo < hi, both finite).
    pub(crate) fn new(cmap: Colormap, range: (f64, f64)) -> Self {
        let table = (0..Self::N)
            .map(|i| {
                let (r, g, b) = colormap_rgb(cmap, i as f64 / (Self::N - 1) as f64);
                [r, g, b]
            })
            .collect();
        Lut {
            table,
            lo: range.0,
            inv_span: 1.0 / (range.1 - range.0),
        }
    }

    /// Colour of data value `v` (clamped to the range; NaN = dark grey).
    #[inline]
    pub(crate) fn rgb(&self, v: f64) -> [u8; 3] {
        if v.is_nan() {
            return [NAN_RGB.0, NAN_RGB.1, NAN_RGB.2];
        }
        let t = ((v - self.lo) * self.inv_span).clamp(0.0, 1.0);
        // Rounded by adding ½ and truncating: the index is not negative, and `round` is a call
        // into libm on every pixel where the CPU baseline has no rounding instruction.
        self.table[(t * (Self::N - 1) as f64 + 0.5) as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn luminance((r, g, b): (u8, u8, u8)) -> f64 {
        0.2126 * r as f64 + 0.7152 * g as f64 + 0.0722 * b as f64
    }

    #[test]
    fn gray_endpoints_and_monotonic() {
        assert_eq!(colormap_rgb(Colormap::Gray, 0.0), (0, 0, 0));
        assert_eq!(colormap_rgb(Colormap::Gray, 1.0), (255, 255, 255));
        assert_eq!(colormap_rgb(Colormap::Gray, -3.0), (0, 0, 0));
        assert_eq!(colormap_rgb(Colormap::Gray, 7.0), (255, 255, 255));
        let mut prev = -1.0;
        for i in 0..=100 {
            let l = luminance(colormap_rgb(Colormap::Gray, i as f64 / 100.0));
            assert!(l > prev, "gray luminance not increasing at {i}");
            prev = l;
        }
    }

    #[test]
    fn viridis_endpoints_and_monotonic() {
        let (r0, g0, b0) = colormap_rgb(Colormap::Viridis, 0.0);
        assert!(b0 > r0 && b0 > g0, "viridis(0) should be dark purple-blue");
        let (r1, g1, b1) = colormap_rgb(Colormap::Viridis, 1.0);
        assert!(
            r1 > 200 && g1 > 200 && b1 < 80,
            "viridis(1) should be yellow"
        );
        let mut prev = -1.0;
        for i in 0..=50 {
            let l = luminance(colormap_rgb(Colormap::Viridis, i as f64 / 50.0));
            assert!(l >= prev, "viridis luminance not monotonic at {i}");
            prev = l;
        }
    }

    #[test]
    fn redblue_diverging() {
        let (r, g, b) = colormap_rgb(Colormap::RedBlue, 0.5);
        assert!(r > 230 && g > 230 && b > 230, "RedBlue(0.5) = {r},{g},{b}");
        let (r, _, b) = colormap_rgb(Colormap::RedBlue, 0.0);
        assert!(b > r + 40, "RedBlue(0) should be blue");
        let (r, _, b) = colormap_rgb(Colormap::RedBlue, 1.0);
        assert!(r > b + 40, "RedBlue(1) should be red");
        for t in [0.0, 0.3, 0.5, 0.8, 1.0] {
            assert_eq!(
                colormap_rgb(Colormap::BlueRed, t),
                colormap_rgb(Colormap::RedBlue, 1.0 - t)
            );
        }
    }

    #[test]
    fn nan_is_dark_grey() {
        for c in [
            Colormap::Gray,
            Colormap::Hot,
            Colormap::Viridis,
            Colormap::RedBlue,
            Colormap::Magma,
            Colormap::BlueRed,
        ] {
            assert_eq!(colormap_rgb(c, f64::NAN), NAN_RGB);
        }
    }

    #[test]
    fn hot_and_magma_endpoints() {
        let (r, g, b) = colormap_rgb(Colormap::Hot, 1.0);
        assert_eq!((r, g, b), (255, 255, 255));
        let (r, g, b) = colormap_rgb(Colormap::Hot, 0.0);
        assert!(r < 20 && g == 0 && b == 0);
        let l0 = luminance(colormap_rgb(Colormap::Magma, 0.0));
        let l1 = luminance(colormap_rgb(Colormap::Magma, 1.0));
        assert!(l0 < 10.0 && l1 > 200.0);
    }

    #[test]
    fn lut_matches_clamping() {
        let lut = Lut::new(Colormap::Gray, (10.0, 20.0));
        assert_eq!(lut.rgb(0.0), [0, 0, 0]);
        assert_eq!(lut.rgb(30.0), [255, 255, 255]);
        let m = lut.rgb(15.0);
        assert!((m[0] as i32 - 128).abs() <= 1);
        assert_eq!(lut.rgb(f64::NAN), [64, 64, 64]);
    }
}
