//! The flow over time at points the user names (`--sites`): each site's compounded Doppler
//! spectrogram (paper Fig. 8b, at any pixel), as arrays and as one figure beside a power Doppler
//! map that marks where the sites lie.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use ndarray::{Array1, Array2, Array3, ArrayD};
use pcuvd::dynamics::Spectrogram;
use pcuvd::estimate::masks;
use pcuvd_render::{Colormap, Panel, Polyline};
use serde::Serialize;

use crate::figures::{self, map_panel, mean_doppler_line, spectrogram_panel};
use crate::run::{DynamicsOutcome, Plan, Processed};
use crate::settings::Site;

/// The figure of the sites.
pub const FIGURE: &str = "sites.png";

/// Colour of the dynamics windows' Vz drawn over each spectrogram: cyan, as the network
/// study's vector speed.
const WINDOW_VZ_RGB: (u8, u8, u8) = (80, 220, 255);

/// Size of each panel of [`FIGURE`] (px).
const SPECTROGRAM_PANEL_PX: (u32, u32) = (600, 460);

/// The sites' time dimension, the windows' centres: the Zarr store's coordinate, which the
/// arrays along it name as their dimension so that xarray aligns them.
pub const TIME_COORDINATE: &str = "site_time";

/// Makes one of the sites' arrays from their spectrograms.
type MakeArray = fn(&SiteSpectrograms) -> ArrayD<f64>;

/// Each array the sites are written as: its name, its dimensions as the Zarr store and xarray
/// name them ([`TIME_COORDINATE`]: the windows' centres), and how it is made. The one list the
/// `.npy` files, the Zarr store and the Python result read.
const LAYOUT: [(&str, &[&str], MakeArray); 4] = [
    (
        "site_spectrograms",
        &["site", TIME_COORDINATE, "site_velocity_bin"],
        |sites| sites.power_db().into_dyn(),
    ),
    ("site_times", &[TIME_COORDINATE], |sites| {
        Array1::from(sites.times_s.clone()).into_dyn()
    }),
    ("site_velocities", &["site", "site_velocity_bin"], |sites| {
        sites.velocities().into_dyn()
    }),
    ("site_mean_velocity", &["site", TIME_COORDINATE], |sites| {
        sites.mean_velocity().into_dyn()
    }),
];

/// The arrays the sites are written as (`.npy` file stems).
pub const ARRAYS: [&str; 4] = [LAYOUT[0].0, LAYOUT[1].0, LAYOUT[2].0, LAYOUT[3].0];

/// One array of the sites: what [`ARRAYS`] names, with its dimensions and values.
pub struct SiteArray {
    /// Its name: the `.npy` file stem, the Python result's key.
    pub name: &'static str,
    /// Its dimensions' names, as the Zarr store writes them.
    pub dimensions: &'static [&'static str],
    /// Its values (dB, s or m/s, as [`SiteSpectrograms`]'s methods of the same meaning).
    pub values: ArrayD<f64>,
}

/// Each site's spectrogram, in the order the sites were given.
pub struct SiteSpectrograms {
    /// The sites.
    pub sites: Vec<Site>,
    /// Per site, the pixels of its sample volume (1: the pixel alone).
    pub gate_pixels: Vec<usize>,
    /// The sample volume's radius (m); 0: the pixel alone.
    pub radius_m: f64,
    /// Per site, its spectrogram, its velocities at the mean RF frequency the maps' estimator
    /// reads at its pixel; `None` where the pixel's filtered series is zero (no Doppler signal).
    pub spectrograms: Vec<Option<Spectrogram>>,
    /// Per site, the frequency (Hz) its Doppler shifts were turned into velocity with: the
    /// pixel's measured mean RF frequency (Loupas, the default estimator), else the
    /// demodulation frequency (Kasai).
    pub frequencies_hz: Vec<f64>,
    /// Window centres (s from the first frame), shared by every site.
    pub times_s: Vec<f64>,
    /// FFT points of each window: the spectrograms' velocity columns.
    pub columns: usize,
}

/// One site as summary.json records it.
#[derive(Debug, Clone, Serialize)]
pub struct SiteRecord {
    /// Lateral position asked for (mm).
    pub x_mm: f64,
    /// Depth asked for (mm).
    pub z_mm: f64,
    /// The pixel read, (row, col) of the maps.
    pub pixel: (usize, usize),
    /// The pixel's lateral position (mm).
    pub pixel_x_mm: f64,
    /// The pixel's depth (mm).
    pub pixel_z_mm: f64,
    /// Pixels of its sample volume (`--site-radius-mm`; 1: the pixel alone).
    pub gate_pixels: usize,
    /// False when the pixel's clutter-filtered series is zero: no spectrogram to show.
    pub has_signal: bool,
    /// The frequency (Hz) its Doppler shifts were turned into velocity with: the pixel's
    /// measured mean RF frequency (Loupas, the default), else the demodulation frequency.
    pub frequency_hz: f64,
}

impl SiteSpectrograms {
    /// The sites' spectrograms of a finished run; `None` when its plan names no sites.
    pub fn of(plan: &Plan, processed: &Processed) -> Result<Option<SiteSpectrograms>> {
        let (Some(site_plan), Some(kept)) = (&plan.sites, &processed.kept) else {
            return Ok(None);
        };
        let images = &processed.out.filtered;
        let spectrograms = site_plan
            .gate_indices()
            .iter()
            .map(|gate| {
                pcuvd::dynamics::spectrogram_of_gate(kept, gate, images, &site_plan.spectrogram)
            })
            .collect::<pcuvd::Result<Vec<_>>>()
            .context("--sites: the spectrograms")?;
        // Each spectrogram reads velocity at the frequency the maps read it with over its gate
        // (Loupas: the measured mean RF frequency; Kasai: the demodulation frequency).
        let demodulation = images.demodulation_frequency;
        let frequencies_hz: Vec<f64> = site_plan
            .gates
            .iter()
            .map(|gate| {
                let measured: Vec<f64> = gate
                    .iter()
                    .filter_map(|&p| processed.out.mean_frequency_at(p))
                    .collect();
                match measured.is_empty() {
                    true => demodulation,
                    false => measured.iter().sum::<f64>() / measured.len() as f64,
                }
            })
            .collect();
        let spectrograms: Vec<Option<Spectrogram>> = spectrograms
            .into_iter()
            .zip(&frequencies_hz)
            .map(|(spec, &f)| spec.map(|spec| spec.at_frequency(demodulation, f)))
            .collect();
        // Every spectrogram has the same windows, a site without signal too.
        let params = &site_plan.spectrogram;
        let times_s = params.window_centres(kept.n_frames(), images.frame_rate);
        Ok(Some(SiteSpectrograms {
            sites: site_plan.sites.clone(),
            gate_pixels: site_plan.gates.iter().map(Vec::len).collect(),
            radius_m: site_plan.radius_m,
            spectrograms,
            frequencies_hz,
            times_s,
            columns: params.nfft,
        }))
    }

    /// Power (dB re each spectrogram's maximum), (sites, windows, velocities); NaN for a site
    /// without signal.
    pub fn power_db(&self) -> Array3<f64> {
        let shape = (self.sites.len(), self.times_s.len(), self.columns);
        let mut power = Array3::from_elem(shape, f64::NAN);
        for (k, spec) in self.spectrograms.iter().enumerate() {
            if let Some(spec) = spec {
                power
                    .index_axis_mut(ndarray::Axis(0), k)
                    .assign(&spec.power_db);
            }
        }
        power
    }

    /// Axial velocity of each spectrogram column (m/s, + = deeper, ascending), (sites,
    /// velocities); NaN for a site without signal.
    pub fn velocities(&self) -> Array2<f64> {
        self.rows(self.columns, |spec| &spec.velocities_m_s)
    }

    /// Mean axial velocity of each window (m/s, the colour-Doppler estimate), (sites,
    /// windows); NaN for a site without signal.
    pub fn mean_velocity(&self) -> Array2<f64> {
        self.rows(self.times_s.len(), |spec| &spec.mean_velocity_m_s)
    }

    /// One row of `len` values per site, each spectrogram's `row`; NaN for a site without
    /// signal.
    fn rows(&self, len: usize, row: impl Fn(&Spectrogram) -> &Vec<f64>) -> Array2<f64> {
        let mut rows = Array2::from_elem((self.sites.len(), len), f64::NAN);
        for (k, spec) in self.spectrograms.iter().enumerate() {
            if let Some(spec) = spec {
                rows.row_mut(k)
                    .assign(&ndarray::ArrayView1::from(row(spec)));
            }
        }
        rows
    }

    /// The sites as summary.json records them, with the pixels read on `grid`.
    pub fn records(&self, grid: &pcuvd::core::grid::Grid) -> Vec<SiteRecord> {
        self.sites
            .iter()
            .zip(&self.spectrograms)
            .zip(&self.frequencies_hz)
            .zip(&self.gate_pixels)
            .map(|(((site, spec), &frequency_hz), &gate_pixels)| SiteRecord {
                x_mm: site.x_m * 1e3,
                z_mm: site.z_m * 1e3,
                pixel: site.pixel,
                pixel_x_mm: grid.x[site.pixel.1] * 1e3,
                pixel_z_mm: grid.z[site.pixel.0] * 1e3,
                gate_pixels,
                has_signal: spec.is_some(),
                frequency_hz,
            })
            .collect()
    }

    /// The arrays of [`ARRAYS`] whose names `wanted` accepts, in that order.
    pub fn arrays(&self, wanted: impl Fn(&str) -> bool) -> Vec<SiteArray> {
        LAYOUT
            .iter()
            .filter(|(name, _, _)| wanted(name))
            .map(|&(name, dimensions, make)| SiteArray {
                name,
                dimensions,
                values: make(self),
            })
            .collect()
    }

    /// Writes the arrays ([`ARRAYS`]) into `dir`, each as `name.npy`.
    pub fn write(&self, dir: &Path) -> Result<()> {
        for array in self.arrays(|_| true) {
            pcuvd_io::write_npy(&dir.join(format!("{}.npy", array.name)), &array.values)?;
        }
        Ok(())
    }

    /// Draws [`FIGURE`] into `dir`: the power Doppler with each site marked, then each site's
    /// spectrogram with its mean Doppler velocity and, where the dynamics stage ran, the vector
    /// fit's axial velocity of each window at that pixel.
    pub fn figure(&self, dir: &Path, processed: &Processed, name: &str) -> Result<PathBuf> {
        let out = &processed.out;
        let grid = &out.grid;
        let power_db = masks::power_db_re_peak(&out.maps.power_doppler);
        let mut map = map_panel(
            "Power Doppler and the sites",
            power_db.clone(),
            grid,
            Colormap::Hot,
            (-40.0, 0.0),
            "dB",
        );
        // A square around each site's pixel and its whole sample volume, a 25th of the map's
        // width on a side at least (and two pixels), in the site's colour.
        let width_mm = (grid.x[grid.x.len() - 1] - grid.x[0]).abs() * 1e3;
        let half = (grid.step() * 1e3)
            .max(width_mm / 50.0)
            .max(self.radius_m * 1e3);
        for (k, site) in self.sites.iter().enumerate() {
            let (x, z) = (grid.x[site.pixel.1] * 1e3, grid.z[site.pixel.0] * 1e3);
            let signal = if self.spectrograms[k].is_some() {
                ""
            } else {
                " (no signal)"
            };
            map.lines.push(Polyline {
                x_mm: vec![x - half, x + half, x + half, x - half, x - half],
                z_mm: vec![z - half, z - half, z + half, z + half, z - half],
                dashed: false,
                rgb: site_colour(k),
                label: format!("{}: {x:.2}, {z:.2} mm{signal}", k + 1),
            });
        }
        let mut panels = vec![Panel::Image(map)];
        let window_vz = match &processed.dynamics {
            DynamicsOutcome::Done { series, .. } => Some(series),
            _ => None,
        };
        let sites = self
            .sites
            .iter()
            .zip(&self.spectrograms)
            .zip(&self.frequencies_hz);
        for (k, ((site, spec), frequency)) in sites.enumerate() {
            let Some(spec) = spec else { continue };
            let mut lines = vec![mean_doppler_line(spec)];
            if let Some(series) = window_vz {
                let (iz, ix) = site.pixel;
                lines.push(Polyline {
                    x_mm: series.times_s.iter().map(|t| t * 1e3).collect(),
                    z_mm: (0..series.times_s.len())
                        .map(|w| series.vz[[w, iz, ix]] * 1e3)
                        .collect(),
                    dashed: false,
                    rgb: WINDOW_VZ_RGB,
                    label: match series.axial_only {
                        true => "axial velocity of each window (one angle)".into(),
                        false => "Vz of the vector fit (each window)".into(),
                    },
                });
            }
            // Each spectrogram is scaled to its own peak: the pixel's power says how strong it is.
            let gate = match self.gate_pixels[k] {
                1 => String::new(),
                n => format!(", {n} px"),
            };
            let title = format!(
                "{}: x {:.2}, z {:.2} mm ({:.0} dB, echo {:.1} MHz{gate})",
                k + 1,
                grid.x[site.pixel.1] * 1e3,
                grid.z[site.pixel.0] * 1e3,
                power_db[site.pixel],
                frequency * 1e-6
            );
            panels.push(Panel::Image(spectrogram_panel(title, spec, lines)));
        }
        let columns = panels.len().min(3);
        // Spectrograms read best wide whatever the grid's shape; the map keeps its aspect
        // within its cell.
        let figure = pcuvd_render::Figure {
            title: format!("{name}: the flow at the sites over time"),
            panels,
            ncols: columns,
            panel_size_px: SPECTROGRAM_PANEL_PX,
        };
        figures::render(dir, FIGURE, "", figure)?;
        Ok(dir.join(FIGURE))
    }
}

/// The colour of site `k` on the map: distinct on the power Doppler's hot scale.
fn site_colour(k: usize) -> (u8, u8, u8) {
    const COLOURS: [(u8, u8, u8); 6] = [
        (0, 220, 255),
        (120, 255, 120),
        (255, 80, 255),
        (80, 140, 255),
        (255, 255, 255),
        (180, 120, 255),
    ];
    COLOURS[k % COLOURS.len()]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A site without signal keeps its place in every array, as NaN, and says so.
    #[test]
    fn a_site_without_signal_is_nan_in_its_rows_and_marked() {
        let spec = Spectrogram {
            times_s: vec![0.5e-3, 1.5e-3],
            velocities_m_s: vec![-0.1, 0.0, 0.1],
            power_db: ndarray::array![[-3.0, 0.0, -20.0], [-1.0, -2.0, -30.0]],
            mean_velocity_m_s: vec![0.01, 0.02],
            nyquist_m_s: 0.15,
        };
        let site = |x_m, pixel| Site {
            x_m,
            z_m: 2e-3,
            pixel,
        };
        let sites = SiteSpectrograms {
            sites: vec![site(0.0, (1, 0)), site(1e-3, (1, 1))],
            gate_pixels: vec![1, 1],
            radius_m: 0.0,
            spectrograms: vec![None, Some(spec.clone())],
            frequencies_hz: vec![15e6, 14e6],
            times_s: spec.times_s.clone(),
            columns: 3,
        };
        let power = sites.power_db();
        assert_eq!(power.dim(), (2, 2, 3));
        assert!(
            power
                .index_axis(ndarray::Axis(0), 0)
                .iter()
                .all(|v| v.is_nan())
        );
        assert_eq!(power.index_axis(ndarray::Axis(0), 1), spec.power_db);
        let velocities = sites.velocities();
        assert!(velocities.row(0).iter().all(|v| v.is_nan()));
        assert_eq!(velocities.row(1).to_vec(), spec.velocities_m_s);
        let mean = sites.mean_velocity();
        assert!(mean.row(0).iter().all(|v| v.is_nan()));
        assert_eq!(mean.row(1).to_vec(), spec.mean_velocity_m_s);
        let grid = pcuvd::core::grid::Grid::new(0.0, 1e-3, 1e-3, 2e-3, 1e-3).unwrap();
        let records = sites.records(&grid);
        assert_eq!(
            records.iter().map(|r| r.has_signal).collect::<Vec<_>>(),
            [false, true]
        );
        assert_eq!((records[1].pixel_x_mm, records[1].pixel_z_mm), (1.0, 2.0));
        assert_eq!(records[1].frequency_hz, 14e6);
    }
}
