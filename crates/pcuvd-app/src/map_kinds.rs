//! What each map and time series pcuvd writes holds, named as its `.npy` file: its unit and
//! meaning, written once for every format that describes its arrays (the NIfTI sidecars, the
//! Zarr store's attributes).

/// A map's name (its `.npy` file's stem), unit and meaning.
pub struct MapKind {
    /// The name, as the `.npy` file's stem.
    pub name: &'static str,
    /// Its unit (`1` for none).
    pub units: &'static str,
    /// What its values are, signs included.
    pub description: &'static str,
}

impl MapKind {
    /// A map kind from its parts.
    pub const fn new(name: &'static str, units: &'static str, description: &'static str) -> Self {
        MapKind {
            name,
            units,
            description,
        }
    }
}

/// Every map and series an output format describes.
pub const MAP_KINDS: [MapKind; 22] = [
    MapKind::new(
        "power_doppler",
        "|IQ|^2",
        "power Doppler of the compounded, clutter-filtered series",
    ),
    MapKind::new(
        "signed_power_doppler",
        "|IQ|^2",
        "power Doppler signed by the colour Doppler (> 0 moving away from the probe)",
    ),
    MapKind::new(
        "color_doppler",
        "m/s",
        "axial velocity (> 0 moving away from the probe)",
    ),
    MapKind::new(
        "vx",
        "m/s",
        "lateral velocity, PC-UVD IRLS-WLS (> 0 toward +x)",
    ),
    MapKind::new("vz", "m/s", "axial velocity, PC-UVD IRLS-WLS (> 0 deeper)"),
    MapKind::new("speed", "m/s", "speed, PC-UVD IRLS-WLS"),
    MapKind::new(
        "ri",
        "1",
        "resistivity index (PSV - EDV)/PSV, NaN outside vessels",
    ),
    MapKind::new(
        "vessel_class",
        "1",
        "0 background, 1 arteriole, 2 venule, 3 undetermined",
    ),
    MapKind::new(
        "ensemble_power_doppler",
        "|IQ|^2",
        "power Doppler of each ensemble",
    ),
    MapKind::new(
        "ensemble_signed_power_doppler",
        "|IQ|^2",
        "signed power Doppler of each ensemble (> 0 moving away from the probe)",
    ),
    MapKind::new(
        "ensemble_color_doppler",
        "m/s",
        "axial velocity of each ensemble",
    ),
    MapKind::new("ensemble_vx", "m/s", "lateral velocity of each ensemble"),
    MapKind::new(
        "ensemble_vz",
        "m/s",
        "axial vector velocity of each ensemble",
    ),
    MapKind::new("bmode_db", "dB", "B-mode, dB re its maximum"),
    MapKind::new("psv", "m/s", "peak systolic speed"),
    MapKind::new("edv", "m/s", "end-diastolic speed"),
    MapKind::new(
        "window_vx",
        "m/s",
        "lateral velocity of each window (> 0 toward +x)",
    ),
    MapKind::new(
        "window_vz",
        "m/s",
        "axial velocity of each window (> 0 deeper)",
    ),
    MapKind::new(
        "window_power",
        "|IQ|^2",
        "power Doppler of each window, mean over angles",
    ),
    MapKind::new(
        "site_spectrograms",
        "dB",
        "Doppler spectrogram at each site, dB re its maximum (NaN without signal)",
    ),
    MapKind::new(
        "site_velocities",
        "m/s",
        "axial velocity of each spectrogram bin at each site (> 0 deeper)",
    ),
    MapKind::new(
        "site_mean_velocity",
        "m/s",
        "mean Doppler velocity of each window at each site (> 0 deeper)",
    ),
];

/// The description of map `name`, one of [`MAP_KINDS`].
pub fn map_kind(name: &str) -> &'static MapKind {
    MAP_KINDS
        .iter()
        .find(|m| m.name == name)
        .expect("every written map is described")
}
