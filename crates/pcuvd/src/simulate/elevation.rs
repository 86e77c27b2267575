//! The elevation beam: how a scatterer's distance y from the imaging plane sets its echo's
//! amplitude and delay, for elements of finite height behind a cylindrical lens.
//!
//! # Model
//! Each element is a strip of height `h` (along y) focused in elevation by a lens at depth `F`.
//! Its one-way field in the elevation plane (y, z) is the exact 2-D diffraction integral of a
//! uniform strip with the lens's focusing delay, at the centre frequency:
//!
//! u(y, z) = ∫_{−h/2}^{h/2} (z / r) · e^{i k (r − (√(η² + F²) − F))} / √r dη,  r = √((y − η)² + z²),
//!
//! (the far-field form of the 2-D Green's function, valid for k r ≫ 1). The simulator's in-plane
//! model already holds everything an infinitely tall, unfocused element would do, so the elevation
//! factor is u relative to that element's field, √λ · e^{iπ/4} · e^{ikz}:
//!
//! G(y, z) = u(y, z) · e^{−ikz} · e^{−iπ/4} / √λ,
//!
//! which tends to 1 near the axis of a tall unfocused strip. Transmit and receive use the same
//! element (reciprocity), so an echo is scaled by G²: amplitude |G|², delay arg(G²) / ω_c. At the
//! focus |G|² is the strip's Fraunhofer pattern sinc²(h y / (λ F)); near the probe it has the
//! strip's near-field structure, which a Gaussian beam would not have (a Gaussian matched at the
//! focus is 60 % too wide at F/2 for the L22-14vX), hence the exact integral, tabulated; the
//! matched Gaussian beam lends only the smooth wavefront curvature of the echo delays.
//!
//! # What it neglects
//! * The elevation factor is a function of depth z, not of the steered path: the paraxial
//!   separation of the elevation plane from the imaging plane (angles ≤ 15° change the path by
//!   ≤ 3.5 %).
//! * It is evaluated at the centre frequency: the pulse's bandwidth would blur the side lobes.
//! * An echo is a delayed real waveform, so G² becomes a smooth delay and a signed amplitude
//!   (its projection on a smooth reference phase; see `ElevationTable`): what lies in quadrature
//!   with that reference is dropped, most of all ~3 mm deep where the strip's near field is
//!   least like a focused beam.
//! * Scatterers beyond the table's |y| range (the aperture plus twice the far-field main lobe at
//!   the deepest depth) echo nothing.

use num_complex::Complex64;
use rayon::prelude::*;

use crate::core::error::{Result, invalid, require_positive};

/// The elevation aperture of the probe's elements: height (m) and lens focus (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ElevationAperture {
    /// Element height along y (m); 1.5 mm for the L22-14vX.
    pub height: f64,
    /// Depth of the elevation lens's focus (m); 8 mm for the L22-14vX.
    pub focus: f64,
}

impl ElevationAperture {
    /// The L22-14vX's elevation: 1.5 mm aperture focused at 8 mm (the Verasonics probe
    /// description: `elevationApertureMm` 1.5, `elevationFocusMm` 8).
    pub fn l22_14vx() -> Self {
        ElevationAperture {
            height: 1.5e-3,
            focus: 8e-3,
        }
    }

    /// Checks that height and focus are finite and positive.
    pub fn validate(&self) -> Result<()> {
        require_positive("element height", self.height)?;
        require_positive("elevation focus", self.focus)
    }

    /// One-way elevation factor G(y, z) at wavelength `lambda` (m) for a point at elevation `y`
    /// and depth `z` (m): see the module docs. Computed by direct integration.
    pub fn one_way(&self, lambda: f64, y: f64, z: f64) -> Complex64 {
        self.strip(lambda).one_way(y, z)
    }

    /// The strip's integration points at wavelength `lambda` (m), for evaluating G at many
    /// points.
    pub(crate) fn strip(&self, lambda: f64) -> Strip {
        // λ/16 per sample holds the integrand's phase step below 0.4 rad wherever k r ≫ 1.
        self.strip_of(
            lambda,
            ((self.height / (lambda / 16.0)).ceil() as usize).max(16),
        )
    }

    /// The strip sampled at `n` points.
    fn strip_of(&self, lambda: f64, n: usize) -> Strip {
        let step = self.height / n as f64;
        let f = self.focus;
        let eta: Vec<f64> = (0..n)
            .map(|i| -0.5 * self.height + (i as f64 + 0.5) * step)
            .collect();
        Strip {
            lens: eta.iter().map(|e| e.hypot(f) - f).collect(),
            eta,
            step,
            height: self.height,
            focus: f,
            k: 2.0 * std::f64::consts::PI / lambda,
            scale: Complex64::from_polar(1.0 / lambda.sqrt(), -std::f64::consts::FRAC_PI_4),
        }
    }

    /// Half-width (m) of the elevations the simulator tabulates for depths up to `z_max` (m):
    /// the aperture plus twice its far-field main lobe (λ z / h) there.
    pub fn y_reach(&self, lambda: f64, z_max: f64) -> f64 {
        self.height + 2.0 * lambda * z_max / self.height
    }
}

/// The points at which [`ElevationAperture::one_way`] samples the strip: their elevations η (m)
/// and the lens's focusing path √(η² + F²) − F (m) at each, which depend on the aperture and the
/// wavelength alone, so that a table of G computes them once.
pub(crate) struct Strip {
    eta: Vec<f64>,
    lens: Vec<f64>,
    /// Spacing of the points (m): at most λ/16 and a sixteenth of the strip.
    step: f64,
    /// The strip's height (m).
    height: f64,
    /// Depth of the lens's focus (m).
    focus: f64,
    /// Wavenumber (rad/m).
    k: f64,
    /// e^{−iπ/4} / √λ.
    scale: Complex64,
}

impl Strip {
    /// G(y, z) at elevation `y` and depth `z` (m).
    pub(crate) fn one_way(&self, y: f64, z: f64) -> Complex64 {
        let sum: Complex64 = self
            .eta
            .iter()
            .zip(&self.lens)
            .map(|(&eta, &lens)| {
                let r = (y - eta).hypot(z);
                Complex64::from_polar(z / r / r.sqrt(), self.k * (r - lens - z))
            })
            .sum();
        sum * self.step * self.scale
    }

    /// G at depth `z` (m) and elevations `y0 + i · y_step` (m), i < `count`: the integral of
    /// [`Strip::one_way`] on points spaced y_step / m (m the least integer that keeps them as
    /// close as the strip's own) and laid on the elevations' grid, so that every distance y − η
    /// between an elevation and a point is a whole number of spacings. The radial factor
    /// z / r^{3/2} · e^{ik(r − z)}, the integral's square root, sine and cosine, then depends on
    /// that number alone and is computed once per distance, not once per pair: the row is the
    /// correlation of the lens's weighted phase with it. The points' cells are clipped to the
    /// strip's edges and weighted by what remains of them. A strip with fewer points than an
    /// elevation step holds has no distance shared between elevations, so each is summed
    /// directly ([`Strip::one_way`]), with no more work than that and no table of distances.
    pub(crate) fn row(&self, z: f64, y0: f64, y_step: f64, count: usize) -> Vec<Complex64> {
        let per_step = (y_step / self.step).ceil().max(1.0) as usize;
        if per_step >= self.eta.len() {
            return (0..count)
                .map(|i| self.one_way(y0 + i as f64 * y_step, z))
                .collect();
        }
        let spacing = y_step / per_step as f64;
        let half = 0.5 * self.height;
        // Points η_q = y0 + q · spacing whose cells [η − spacing/2, η + spacing/2] meet the strip.
        let first = ((-half - y0) / spacing + 0.5).floor() as i64;
        let last = ((half - y0) / spacing - 0.5).ceil() as i64;
        let lens: Vec<(i64, Complex64)> = (first..=last)
            .filter_map(|q| {
                let eta = y0 + q as f64 * spacing;
                let weight = (eta + 0.5 * spacing).min(half) - (eta - 0.5 * spacing).max(-half);
                (weight > 0.0).then(|| {
                    let path = eta.hypot(self.focus) - self.focus;
                    (q, Complex64::from_polar(weight, -self.k * path))
                })
            })
            .collect();
        // Distances p · spacing, p = i · per_step − q; the factor is even in p.
        let reach = ((count.saturating_sub(1) * per_step) as i64 - first)
            .abs()
            .max(last.abs()) as usize;
        let radial: Vec<Complex64> = (0..=reach)
            .map(|p| {
                let r = (p as f64 * spacing).hypot(z);
                Complex64::from_polar(z / r / r.sqrt(), self.k * (r - z))
            })
            .collect();
        (0..count)
            .map(|i| {
                let at = (i * per_step) as i64;
                let sum: Complex64 = lens
                    .iter()
                    .map(|&(q, weight)| weight * radial[(at - q).unsigned_abs() as usize])
                    .sum();
                sum * self.scale
            })
            .collect()
    }
}

/// Radius of a Gaussian aperture (1/e amplitude, m) whose focal two-way −6 dB width is the
/// strip's of height `height` (m): 2√(ln 2 / 2) h / (π · 2 · 0.4429), about 0.42 h.
fn matched_gaussian_radius(height: f64) -> f64 {
    2.0 * (std::f64::consts::LN_2 / 2.0).sqrt() * height
        / (std::f64::consts::PI * 2.0 * 0.442_946_5)
}

/// The two-way elevation factor G² tabulated for the simulator, as a smooth delay and a signed
/// amplitude.
///
/// An echo is a delayed real waveform, so G²'s phase has to become a delay. Its phase is not
/// smooth: at the nulls between the strip's lobes it jumps by π, and no unwrapping makes it
/// continuous (a phase singularity has no consistent branch), so a scatterer moving through a
/// null would have its echo jump by half a period — moving tissue, 40 dB brighter than blood,
/// would then light up the Doppler maps along the depths of the nulls. Instead the delay comes
/// from a smooth reference phase ψ(y, z) = ψ₀(z) + k y² / R(z) — the strip's own on-axis phase
/// (unwrapped in depth, smooth there) plus the two-way wavefront curvature of the Gaussian beam
/// matched to the strip at its focus — and the amplitude is G²'s projection on it,
/// Re(G² e^{−iψ}), signed: the side lobes keep their opposite sign, and both parts are continuous
/// everywhere. What the projection drops (G²'s part in quadrature with the reference) is measured
/// in the tests: over the L22-14vX's |y| ≤ 0.6 mm it keeps 86–100 % of the echo power at depths
/// 1–2 mm and 5–12 mm, and about half around 3 mm, where the strip's near-field phase is not
/// quadratic in y.
pub(crate) struct ElevationTable {
    /// Re(G² e^{−iψ}) on the grid, row-major (depth, elevation).
    signed: Vec<f64>,
    /// Per depth row: ψ₀, the on-axis phase of G² (rad), unwrapped in depth.
    axis_phase: Vec<f64>,
    /// Per depth row: 1/R, the Gaussian beam's wavefront curvature (1/m), > 0 past its waist.
    curvature: Vec<f64>,
    /// Wavenumber k (rad/m): the reference's two-way curvature phase is k y² / R, twice the
    /// one-way k y² / (2R).
    k: f64,
    y_step: f64,
    z_step: f64,
    ny: usize,
    nz: usize,
    y_max: f64,
    /// ω_c (rad/s), turning a phase into a delay.
    omega: f64,
}

/// The points an [`ElevationTable`] samples: |y| ≤ `y_max` in steps of `y_step` (`ny` of
/// them), depths 0, `z_step`, ... (`nz` of them), all in m.
#[derive(Debug, Clone, Copy, PartialEq)]
struct TableGrid {
    y_max: f64,
    y_step: f64,
    z_step: f64,
    ny: usize,
    nz: usize,
}

impl TableGrid {
    /// Steps λ/4 in y and λ/8 in z over depths 0..`z_max` (m) and |y| ≤
    /// [`ElevationAperture::y_reach`] at wavelength `lambda` (m).
    fn new(aperture: &ElevationAperture, lambda: f64, z_max: f64) -> TableGrid {
        let y_max = aperture.y_reach(lambda, z_max);
        let (y_step, z_step) = (lambda / 4.0, lambda / 8.0);
        TableGrid {
            y_max,
            y_step,
            z_step,
            // Saturating: an aperture too tall for any table (a height of 10³⁰⁰ m converts to
            // usize::MAX) must count as too many entries, not wrap around to none.
            ny: ((2.0 * y_max / y_step).ceil() as usize).saturating_add(1),
            nz: ((z_max / z_step).ceil() as usize).saturating_add(2),
        }
    }
}

/// What an [`ElevationTable`]'s every entry follows from: aperture, wavelength (m), f_c (Hz)
/// and the grid. Not the depth asked for: the blood's simulators and the tissue keyframes' ask
/// for receive windows that end at the same time but may round to depths a bit apart, whose
/// grids are the same.
type TableKey = (ElevationAperture, f64, f64, TableGrid);

/// The last tables built, newest last: a long recording is simulated a block at a time, each
/// block with its own simulators, and every block and transmit mode asks for the same few
/// tables, each seconds of integrals to build.
static RECENT_TABLES: std::sync::Mutex<Vec<(TableKey, std::sync::Arc<ElevationTable>)>> =
    std::sync::Mutex::new(Vec::new());

/// How many recent tables are kept (a few MB each).
const RECENT: usize = 4;

impl ElevationTable {
    /// The table of [`ElevationTable::new`], built once for the same aperture, wavelength,
    /// frequency and grid (depths a rounding apart share one) while it is among the few most
    /// recently asked for.
    pub(crate) fn shared(
        aperture: &ElevationAperture,
        lambda: f64,
        fc: f64,
        z_max: f64,
    ) -> Result<std::sync::Arc<Self>> {
        aperture.validate()?;
        require_positive("depth of the receive window", z_max)?;
        let key = (
            *aperture,
            lambda,
            fc,
            TableGrid::new(aperture, lambda, z_max),
        );
        // A poisoned lock only means another thread panicked while building: the list is whole.
        let mut recent = RECENT_TABLES.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, table)) = recent.iter().find(|(built, _)| *built == key) {
            return Ok(table.clone());
        }
        let table = std::sync::Arc::new(Self::on(aperture, lambda, fc, key.3)?);
        if recent.len() == RECENT {
            recent.remove(0);
        }
        recent.push((key, table.clone()));
        Ok(table)
    }

    /// G² for depths 0..`z_max` (m) and |y| ≤ [`ElevationAperture::y_reach`], at wavelength
    /// `lambda` (m) and centre frequency `fc` (Hz): steps λ/4 in y, λ/8 in z.
    #[cfg(test)]
    pub(crate) fn new(
        aperture: &ElevationAperture,
        lambda: f64,
        fc: f64,
        z_max: f64,
    ) -> Result<Self> {
        aperture.validate()?;
        require_positive("depth of the receive window", z_max)?;
        Self::on(
            aperture,
            lambda,
            fc,
            TableGrid::new(aperture, lambda, z_max),
        )
    }

    /// G² on `grid` (see [`ElevationTable::new`]).
    fn on(aperture: &ElevationAperture, lambda: f64, fc: f64, grid: TableGrid) -> Result<Self> {
        let TableGrid {
            y_max,
            y_step,
            z_step,
            ny,
            nz,
        } = grid;
        if ny.saturating_mul(nz) > 50_000_000 {
            return Err(invalid(
                "element height",
                format!(
                    "a {:.2} mm aperture over {:.1} mm of depth needs a {ny} × {nz} elevation table; \
                     the simulator holds at most 5·10⁷ entries",
                    aperture.height * 1e3,
                    (nz - 2) as f64 * z_step * 1e3
                ),
            ));
        }
        // The integral is singular at z = 0; the first row is never reached by a scatterer
        // (positions ≤ 0 receive no transmit field) but keeps interpolation defined next to it.
        let depth = |iz: usize| (iz as f64 * z_step).max(z_step);
        let strip = aperture.strip(lambda);
        let strip = &strip;
        let values: Vec<Complex64> = (0..nz)
            .into_par_iter()
            .flat_map_iter(|iz| {
                strip
                    .row(depth(iz), -y_max, y_step, ny)
                    .into_iter()
                    .map(|g| g * g)
            })
            .collect();
        let mut axis_phase: Vec<f64> = (0..nz)
            .map(|iz| strip.one_way(0.0, depth(iz)).powi(2).arg())
            .collect();
        for iz in 1..nz {
            let previous = axis_phase[iz - 1];
            axis_phase[iz] = previous
                + (axis_phase[iz] - previous + std::f64::consts::PI)
                    .rem_euclid(std::f64::consts::TAU)
                - std::f64::consts::PI;
        }
        // The matched Gaussian beam: q(z) = q(0) + z, 1/q(0) = −1/F − iλ/(π a²); 1/R = Re(1/q).
        let a = matched_gaussian_radius(aperture.height);
        let q0 = Complex64::new(
            -1.0 / aperture.focus,
            -lambda / (std::f64::consts::PI * a * a),
        )
        .inv();
        let curvature: Vec<f64> = (0..nz).map(|iz| (q0 + depth(iz)).inv().re).collect();
        let k = 2.0 * std::f64::consts::PI / lambda;
        let signed = values
            .iter()
            .enumerate()
            .map(|(i, g2)| {
                let (iz, iy) = (i / ny, i % ny);
                let y = -y_max + iy as f64 * y_step;
                let reference = axis_phase[iz] + k * y * y * curvature[iz];
                (g2 * Complex64::from_polar(1.0, -reference)).re
            })
            .collect();
        Ok(ElevationTable {
            signed,
            axis_phase,
            curvature,
            k,
            y_step,
            z_step,
            ny,
            nz,
            y_max,
            omega: 2.0 * std::f64::consts::PI * fc,
        })
    }

    /// (signed amplitude, delay (s)) of the two-way elevation factor at elevation `y` and depth
    /// `z` (m), interpolated bilinearly; (0, 0) outside the table.
    pub(crate) fn two_way(&self, y: f64, z: f64) -> (f64, f64) {
        let fy = (y + self.y_max) / self.y_step;
        let fz = z / self.z_step;
        if !(fy >= 0.0 && fz >= 0.0) || fy >= (self.ny - 1) as f64 || fz >= (self.nz - 1) as f64 {
            return (0.0, 0.0);
        }
        let (iy, iz) = (fy as usize, fz as usize);
        let (ty, tz) = (fy - iy as f64, fz - iz as f64);
        let at = |z: usize, y: usize| self.signed[z * self.ny + y];
        let row = |z: usize| at(z, iy) * (1.0 - ty) + at(z, iy + 1) * ty;
        let amplitude = row(iz) * (1.0 - tz) + row(iz + 1) * tz;
        let lerp = |v: &[f64]| v[iz] * (1.0 - tz) + v[iz + 1] * tz;
        let phase = lerp(&self.axis_phase) + self.k * y * y * lerp(&self.curvature);
        (amplitude, phase / self.omega)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LAMBDA: f64 = 1540.0 / 15.625e6;

    /// Two-way −6 dB full width (m) of |G(y, z)|² over y, found on a fine grid.
    fn two_way_width(aperture: &ElevationAperture, z: f64) -> f64 {
        let ys: Vec<f64> = (0..=1200).map(|i| -1.5e-3 + i as f64 * 2.5e-6).collect();
        let p: Vec<f64> = ys
            .iter()
            .map(|&y| aperture.one_way(LAMBDA, y, z).norm_sqr())
            .collect();
        let peak = p.iter().cloned().fold(0.0, f64::max);
        let inside: Vec<f64> = ys
            .iter()
            .zip(&p)
            .filter(|&(_, &v)| v >= 0.5 * peak)
            .map(|(&y, _)| y)
            .collect();
        inside.last().unwrap() - inside.first().unwrap()
    }

    #[test]
    fn the_focal_profile_is_the_strips_fraunhofer_pattern() {
        // At the focus the lens cancels the quadratic phase: |G|² ∝ sinc²(h y / (λ F)), whose
        // two-way −6 dB width is 2 · 0.4429 · λ F / h (sinc(u) = 1/√2 at u = 0.4429).
        let a = ElevationAperture::l22_14vx();
        let width = two_way_width(&a, a.focus);
        let theory = 2.0 * 0.442_946_5 * LAMBDA * a.focus / a.height;
        assert!(
            (width / theory - 1.0).abs() < 0.02,
            "focal width {:.4} mm, Fraunhofer {:.4} mm",
            width * 1e3,
            theory * 1e3
        );
        // Its first null at y = λ F / h.
        let null = LAMBDA * a.focus / a.height;
        let on_axis = a.one_way(LAMBDA, 0.0, a.focus).norm();
        assert!(a.one_way(LAMBDA, null, a.focus).norm() < 0.02 * on_axis);
        // Past the focus the beam widens. (Before it, it need not: with a Fresnel number
        // h² / (4 λ F) of 0.7 the narrowest point moves toward the probe, the known focal shift
        // of weakly focused apertures.)
        assert!(two_way_width(&a, 1.5 * a.focus) > 1.3 * width);
    }

    #[test]
    fn a_tall_unfocused_strip_is_the_in_plane_model() {
        // A 20 mm strip with its focus far away: 4 mm from the probe, near the axis, the field is
        // the infinitely tall element's (|G| = 1, no extra phase) up to the edge waves' ripple.
        let a = ElevationAperture {
            height: 20e-3,
            focus: 1e3,
        };
        for y in [0.0, 0.3e-3, 1e-3] {
            let g = a.one_way(LAMBDA, y, 4e-3);
            assert!(
                (g.norm() - 1.0).abs() < 0.1,
                "|G| = {} at y = {y}",
                g.norm()
            );
            assert!(g.arg().abs() < 0.1, "arg G = {} at y = {y}", g.arg());
        }
    }

    #[test]
    fn a_row_of_the_field_is_as_close_to_the_integral_as_the_direct_sum() {
        // The row's points lie on the elevations' grid, the direct sum's on the strip's own: two
        // midpoint rules of one integral at the same density, each held against the integral
        // converged (the strip sampled 32 times finer), from the near field to past the focus,
        // on the table's grid (λ/4 from −y_max) and the truth's (10 µm, centred).
        let a = ElevationAperture::l22_14vx();
        let strip = a.strip(LAMBDA);
        let converged = a.strip_of(LAMBDA, 32 * strip.eta.len());
        let y_max = a.y_reach(LAMBDA, 13e-3);
        for (y0, y_step, count) in [
            (
                -y_max,
                LAMBDA / 4.0,
                (2.0 * y_max / (LAMBDA / 4.0)).ceil() as usize + 1,
            ),
            (-300.0 * 10e-6, 10e-6, 601),
        ] {
            for z in [0.5e-3, 1e-3, 3e-3, 5e-3, 8e-3, 12e-3] {
                let row = strip.row(z, y0, y_step, count);
                let (mut peak, mut off_row, mut off_direct) = (0.0f64, 0.0f64, 0.0f64);
                for (i, g) in row.iter().enumerate() {
                    let y = y0 + i as f64 * y_step;
                    let exact = converged.one_way(y, z);
                    peak = peak.max(exact.norm());
                    off_row = off_row.max((g - exact).norm());
                    off_direct = off_direct.max((strip.one_way(y, z) - exact).norm());
                }
                // Both within 3·10⁻⁴ of the peak here (the edge cells, clipped, weigh the row's
                // a little more); the row as close as the direct sum, to half as much again.
                assert!(
                    off_row < 5e-4 * peak && off_row < 1.5 * off_direct,
                    "z = {z}, step {y_step}: row {off_row:.2e}, direct sum {off_direct:.2e}, \
                     peak {peak:.2e}"
                );
            }
        }
    }

    #[test]
    fn a_strip_narrower_than_the_rows_step_is_summed_directly() {
        // 16 points over 20 µm, a step of λ/4 holds 79 of their spacings: no distance is shared.
        let narrow = ElevationAperture {
            height: 20e-6,
            focus: 8e-3,
        };
        let strip = narrow.strip(LAMBDA);
        let row = strip.row(5e-3, -1e-3, LAMBDA / 4.0, 81);
        for (i, g) in row.iter().enumerate() {
            assert_eq!(*g, strip.one_way(-1e-3 + i as f64 * LAMBDA / 4.0, 5e-3));
        }
    }

    #[test]
    fn the_table_keeps_the_beam_and_moves_echoes_smoothly() {
        let a = ElevationAperture::l22_14vx();
        let fc = 15.625e6;
        let table = ElevationTable::new(&a, LAMBDA, fc, 13e-3).unwrap();
        // In the main lobe the signed amplitude is |G²| (the reference follows the phase), to
        // 3 % from the focus on and 10 % in the near field.
        for (y, z, tolerance) in [
            (0.0, 8e-3, 0.03),
            (0.1e-3, 8e-3, 0.03),
            (0.0, 10.3e-3, 0.03),
            (0.0, 5e-3, 0.03),
            (0.1e-3, 1.5e-3, 0.1),
        ] {
            let exact = a.one_way(LAMBDA, y, z).powi(2).norm();
            let (amplitude, _) = table.two_way(y, z);
            assert!(
                (amplitude - exact).abs() < tolerance * exact,
                "({y}, {z}): table {amplitude}, |G²| {exact}"
            );
        }
        // The echo power kept by the projection, weighted by the echo power itself, over the
        // slab |y| ≤ 0.6 mm: most of it but near 3 mm deep (see the type's docs).
        let kept = |z: f64| {
            let ys = (0..=240).map(|i| -0.6e-3 + i as f64 * 5e-6);
            let (mut kept, mut all) = (0.0, 0.0);
            for y in ys {
                let exact = a.one_way(LAMBDA, y, z).powi(2).norm_sqr();
                kept += table.two_way(y, z).0.powi(2);
                all += exact;
            }
            kept / all
        };
        for (z, least) in [
            (1e-3, 0.85),
            (2e-3, 0.8),
            (5e-3, 0.95),
            (8e-3, 0.97),
            (12e-3, 0.95),
        ] {
            let k = kept(z);
            assert!(k > least && k < 1.03, "z = {z}: kept {k:.3}");
        }
        assert!(kept(3e-3) > 0.4);
        // Delay and amplitude are continuous: across the focal null (y = λF/h = 0.53 mm) and in
        // depth, no step of a period (64 ns) or of the amplitude anywhere in the slab.
        let period = 1.0 / fc;
        for z in [3e-3, 7.7e-3, 8e-3] {
            let along: Vec<(f64, f64)> = (0..1200)
                .map(|i| table.two_way(i as f64 * 0.5e-6, z))
                .collect();
            for w in along.windows(2) {
                assert!(
                    (w[1].1 - w[0].1).abs() < 0.01 * period,
                    "delay step at z = {z}"
                );
                assert!((w[1].0 - w[0].0).abs() < 0.02, "amplitude step at z = {z}");
            }
        }
        for y in [0.0, 0.3e-3, 0.53e-3] {
            let down: Vec<(f64, f64)> = (0..2400)
                .map(|i| table.two_way(y, 0.5e-3 + i as f64 * 5e-6))
                .collect();
            for w in down.windows(2) {
                assert!(
                    (w[1].1 - w[0].1).abs() < 0.01 * period,
                    "delay step at y = {y}"
                );
            }
        }
        assert_eq!(table.two_way(5e-3, 8e-3), (0.0, 0.0));
        assert_eq!(table.two_way(0.0, 20e-3), (0.0, 0.0));
    }

    #[test]
    fn depths_on_the_same_grid_share_one_table() {
        // A wavelength no other test asks for, so that no other table is shared by mistake.
        // Elements tall against the main lobe's growth over the depths, as the L22-14vX's are:
        // then y_max, as the depth, often rounds to the same value.
        let a = ElevationAperture {
            height: 1.5e-3,
            focus: 2e-3,
        };
        let lambda = 1540.0 / 14.5e6;
        let z_max = 1.7e-3;
        let grid = TableGrid::new(&a, lambda, z_max);
        // The next depth up whose grid is the same (one or a few ulps deeper: y_max rounds too).
        let rounded_depth = std::iter::successors(Some(z_max.next_up()), |z| Some(z.next_up()))
            .take(64)
            .find(|&z| TableGrid::new(&a, lambda, z) == grid)
            .unwrap();
        let table = ElevationTable::shared(&a, lambda, 14.5e6, z_max).unwrap();
        let rounded = ElevationTable::shared(&a, lambda, 14.5e6, rounded_depth).unwrap();
        assert!(std::sync::Arc::ptr_eq(&table, &rounded));
        // What sharing hands out is what the depth asked for would have built.
        let own = ElevationTable::new(&a, lambda, 14.5e6, rounded_depth).unwrap();
        assert_eq!(own.signed, rounded.signed);
        assert_eq!(own.axis_phase, rounded.axis_phase);
        assert_eq!(
            (own.ny, own.nz, own.y_max),
            (rounded.ny, rounded.nz, rounded.y_max)
        );
        // A step deeper is another grid.
        let deeper = ElevationTable::shared(&a, lambda, 14.5e6, z_max + lambda / 8.0).unwrap();
        assert!(!std::sync::Arc::ptr_eq(&table, &deeper));
        assert_eq!(deeper.nz, table.nz + 1);
    }

    #[test]
    fn beyond_the_focus_off_axis_echoes_come_later() {
        // The wavefront diverges past the focus (off-axis points are reached late) and converges
        // before it (early): the extra two-way delay is ≈ y² / (R c) with R the wavefront radius.
        let a = ElevationAperture::l22_14vx();
        let table = ElevationTable::new(&a, LAMBDA, 15.625e6, 14e-3).unwrap();
        let (_, on_axis_deep) = table.two_way(0.0, 12e-3);
        let (_, off_axis_deep) = table.two_way(0.15e-3, 12e-3);
        assert!(off_axis_deep > on_axis_deep);
        let (_, on_axis_shallow) = table.two_way(0.0, 5e-3);
        let (_, off_axis_shallow) = table.two_way(0.15e-3, 5e-3);
        assert!(off_axis_shallow < on_axis_shallow);
    }

    #[test]
    fn bad_apertures_are_refused_by_name() {
        let bad = ElevationAperture {
            height: 0.0,
            focus: 8e-3,
        };
        let err = ElevationTable::new(&bad, LAMBDA, 15.625e6, 10e-3)
            .err()
            .unwrap();
        assert!(err.to_string().contains("element height"), "{err}");
        // Too tall for any table, up to past what a count of entries holds: refused, not built.
        for height in [1.0, 1e9, 1e300, f64::MAX] {
            let tall = ElevationAperture {
                height,
                focus: 8e-3,
            };
            let err = ElevationTable::new(&tall, LAMBDA, 15.625e6, 10e-3)
                .err()
                .unwrap();
            assert!(
                err.to_string().contains("at most 5·10⁷ entries"),
                "{height}: {err}"
            );
        }
    }
}
