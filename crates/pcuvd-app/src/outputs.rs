//! Output folders that never lose data: no input is ever overwritten or deleted, a folder holding
//! other files is refused unless `--force`, and `--force` removes only pcuvd's own outputs of an
//! earlier run (so no stale map sits beside a new `summary.json`), never anything else.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

/// Every file `pcuvd process` may write into its output folder.
pub const PROCESS_OUTPUTS: &[&str] = &[
    "summary.json",
    "report.html",
    "x.npy",
    "z.npy",
    "bmode_db.npy",
    "power_doppler.npy",
    "color_doppler.npy",
    "signed_power_doppler.npy",
    "projections.npy",
    "projection_nyquist.npy",
    "vx.npy",
    "vz.npy",
    "speed.npy",
    "vx_ls.npy",
    "vz_ls.npy",
    "speed_ls.npy",
    "alias_counts.npy",
    "alias_counts_ls.npy",
    "ri.npy",
    "psv.npy",
    "edv.npy",
    "psv_spread.npy",
    "edv_spread.npy",
    "ri_spread.npy",
    "vessel_class.npy",
    "flow_up.npy",
    "speed_series.npy",
    "times.npy",
    "ensemble_power_doppler.npy",
    "ensemble_color_doppler.npy",
    "ensemble_signed_power_doppler.npy",
    "ensemble_vx.npy",
    "ensemble_vz.npy",
    "ensemble_speed.npy",
    "ensemble_times.npy",
    "clutter_block_cut_offs.npy",
    "site_spectrograms.npy",
    "site_times.npy",
    "site_velocities.npy",
    "site_mean_velocity.npy",
    "bmode.png",
    "power_doppler.png",
    "signed_power_doppler.png",
    "color_doppler.png",
    "vector.png",
    "dealias.png",
    "ri.png",
    "waveform.png",
    "ensembles.png",
    "clutter_blocks.png",
    "against_truth.png",
    "sites.png",
    // --nifti, named by map: the image and its sidecar.
    "power_doppler.nii.gz",
    "power_doppler.json",
    "signed_power_doppler.nii.gz",
    "signed_power_doppler.json",
    "color_doppler.nii.gz",
    "color_doppler.json",
    "vx.nii.gz",
    "vx.json",
    "vz.nii.gz",
    "vz.json",
    "speed.nii.gz",
    "speed.json",
    "ri.nii.gz",
    "ri.json",
    "vessel_class.nii.gz",
    "vessel_class.json",
    "ensemble_power_doppler.nii.gz",
    "ensemble_power_doppler.json",
    "ensemble_signed_power_doppler.nii.gz",
    "ensemble_signed_power_doppler.json",
    "ensemble_color_doppler.nii.gz",
    "ensemble_color_doppler.json",
    "ensemble_vx.nii.gz",
    "ensemble_vx.json",
    "ensemble_vz.nii.gz",
    "ensemble_vz.json",
    // --zarr: one store (a folder).
    crate::zarr::STORE,
];

/// The same file, whether or not either path exists yet: canonical when it exists, else the
/// canonical folder joined with the name.
fn resolved(path: &Path) -> PathBuf {
    if let Ok(p) = path.canonicalize() {
        return p;
    }
    match (path.parent(), path.file_name()) {
        (Some(dir), Some(name)) => dir
            .canonicalize()
            .map(|d| d.join(name))
            .unwrap_or_else(|_| path.to_path_buf()),
        _ => path.to_path_buf(),
    }
}

/// After a run that failed before writing anything, removes the output folder `dir` if this run
/// `made` it and it is still empty: a refused recording leaves no empty folder behind. A folder
/// that was there before, or that holds anything (a Zarr store begun as the run went), stays.
pub fn remove_if_empty(dir: &Path, made: bool) {
    if made {
        // Only an empty folder is removed; anything else makes this fail, which is the point.
        let _ = std::fs::remove_dir(dir);
    }
}

/// Makes `dir` ready for a run that writes the files named `own`: refuses when one of them would
/// land on one of `inputs`; creates the folder; refuses a folder that holds anything unless
/// `force`, and with `force` removes the files of `own` left there by an earlier run (only those,
/// and a Zarr store folder among them).
pub fn prepare(dir: &Path, own: &[&str], inputs: &[PathBuf], force: bool) -> Result<()> {
    let inputs: Vec<PathBuf> = inputs.iter().map(|p| resolved(p)).collect();
    for name in own {
        let target = resolved(&dir.join(name));
        if inputs.contains(&target) {
            bail!(
                "{}: the output {name} would overwrite the input {}; choose another --out folder",
                dir.display(),
                target.display()
            );
        }
    }
    if dir.exists() && !dir.is_dir() {
        bail!("{}: --out is a file, not a folder", dir.display());
    }
    std::fs::create_dir_all(dir)
        .with_context(|| format!("{}: cannot create the output folder", dir.display()))?;
    let entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("{}: cannot read the output folder", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    if entries.is_empty() {
        return Ok(());
    }
    if !force {
        bail!(
            "{}: the output folder is not empty ({} entries); choose an empty or new folder, or \
             pass --force to replace pcuvd's own outputs of an earlier run there (other files are \
             never touched)",
            dir.display(),
            entries.len()
        );
    }
    for name in own {
        let path = dir.join(name);
        if path.is_file() {
            std::fs::remove_file(&path)
                .with_context(|| format!("{}: cannot remove the earlier output", path.display()))?;
        } else if path.is_dir() && name.ends_with(".zarr") {
            std::fs::remove_dir_all(&path)
                .with_context(|| format!("{}: cannot remove the earlier output", path.display()))?;
        }
    }
    Ok(())
}

/// The hash that identifies an input file in `summary.json`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Checksum {
    /// XXH3-128 (`xxh128sum`, `xxhsum -H2`): about 18 GB/s on one core, under 1 % of a run; it
    /// identifies a file (a changed byte changes it), but is not cryptographic.
    #[default]
    Xxh128,
    /// BLAKE3 (`b3sum`): cryptographic, about 3.6 GB/s on one core with SIMD, 2–3 % of a run.
    Blake3,
    /// SHA-256 (`sha256sum`): for those who check inputs with it; about 10 s of a core for 2.7 GB
    /// on CPUs without SHA instructions.
    Sha256,
}

/// A checksum being computed, fed a file's bytes in order (by [`fingerprint`], or by a reader in
/// its own pass over the file: [`pcuvd_io::ReadPass`]).
pub struct Digest {
    hasher: Hasher,
    /// Whether large pieces are hashed on every core (BLAKE3 hashes a file's parts apart and
    /// joins them): for a reader's pass, which the processing waits for; not on a thread beside
    /// the processing, which should take only what the processing leaves idle.
    on_every_core: bool,
}

enum Hasher {
    Xxh128(Box<twox_hash::xxhash3_128::Hasher>),
    Blake3(Box<blake3::Hasher>),
    Sha256(sha2::Sha256),
}

/// Pieces from this size (bytes) are worth hashing on every core.
const PARALLEL_HASH_BYTES: usize = 1 << 20;

impl Digest {
    /// A new checksum of the kind `checksum`, computed on the calling thread.
    pub fn new(checksum: Checksum) -> Digest {
        use sha2::Digest as _;
        let hasher = match checksum {
            Checksum::Xxh128 => Hasher::Xxh128(Box::default()),
            Checksum::Blake3 => Hasher::Blake3(Box::default()),
            Checksum::Sha256 => Hasher::Sha256(sha2::Sha256::new()),
        };
        Digest {
            hasher,
            on_every_core: false,
        }
    }

    /// A new checksum of the kind `checksum` that hashes large pieces on every core (BLAKE3;
    /// XXH3 and SHA-256 are sequential by construction).
    pub fn on_every_core(checksum: Checksum) -> Digest {
        Digest {
            on_every_core: true,
            ..Digest::new(checksum)
        }
    }
}

impl pcuvd_io::ChecksumSink for Digest {
    fn update(&mut self, bytes: &[u8]) {
        use sha2::Digest as _;
        match &mut self.hasher {
            Hasher::Xxh128(hasher) => hasher.write(bytes),
            Hasher::Blake3(hasher) if self.on_every_core && bytes.len() >= PARALLEL_HASH_BYTES => {
                hasher.update_rayon(bytes);
            }
            Hasher::Blake3(hasher) => {
                hasher.update(bytes);
            }
            Hasher::Sha256(hasher) => hasher.update(bytes),
        }
    }

    fn hex(self: Box<Self>) -> String {
        use sha2::Digest as _;
        match self.hasher {
            // The canonical form xxhsum prints: the 128 bits big-endian.
            Hasher::Xxh128(hasher) => format!("{:032x}", hasher.finish_128()),
            Hasher::Blake3(hasher) => hasher.finalize().to_hex().to_string(),
            Hasher::Sha256(hasher) => hasher
                .finalize()
                .iter()
                .map(|b| format!("{b:02x}"))
                .collect::<String>(),
        }
    }
}

/// Size (bytes) and checksum (hex) of a file, read in 8 MiB blocks (a [`pcuvd_io::ReadPass`]
/// that no reader fed, finished): neither the memory nor the process's resident size grows with
/// the file (a file mapped into memory would count whole in the resident size that
/// `summary.json` and batch schedulers report).
pub fn fingerprint(path: &Path, checksum: Checksum) -> Result<(u64, String)> {
    let pass = pcuvd_io::ReadPass::new(path);
    pass.attach(Box::new(Digest::new(checksum)));
    let cannot = || format!("{}: cannot read for its checksum", path.display());
    let done = pass.finish().with_context(cannot)?.with_context(cannot)?;
    Ok((done.size_bytes, done.hex))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_a_used_folder_and_force_removes_only_own_files() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        prepare(&out, PROCESS_OUTPUTS, &[], false).unwrap();
        assert!(out.is_dir());
        std::fs::write(out.join("ri.npy"), "old").unwrap();
        std::fs::write(out.join("notes.txt"), "mine").unwrap();
        let refused = prepare(&out, PROCESS_OUTPUTS, &[], false).unwrap_err();
        assert!(format!("{refused:#}").contains("--force"), "{refused:#}");
        assert!(out.join("ri.npy").exists());
        std::fs::create_dir_all(out.join(crate::zarr::STORE).join("vx")).unwrap();
        std::fs::create_dir_all(out.join("mine.zarr")).unwrap();
        prepare(&out, PROCESS_OUTPUTS, &[], true).unwrap();
        assert!(!out.join("ri.npy").exists());
        assert!(!out.join(crate::zarr::STORE).exists());
        assert!(out.join("mine.zarr").is_dir());
        assert_eq!(
            std::fs::read_to_string(out.join("notes.txt")).unwrap(),
            "mine"
        );
    }

    #[test]
    fn fingerprints_are_the_published_digests_of_the_bytes() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("abc");
        std::fs::write(&path, "abc").unwrap();
        // FIPS 180-2, appendix B.1.
        assert_eq!(
            fingerprint(&path, Checksum::Sha256).unwrap(),
            (
                3,
                "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad".to_string()
            )
        );
        // XXH3-128 as `xxhsum -H2` (xxHash 0.8) prints it, of nothing and of "abc".
        std::fs::write(&path, "").unwrap();
        assert_eq!(
            fingerprint(&path, Checksum::Xxh128).unwrap(),
            (0, "99aa06d3014798d86001c324468d497f".to_string())
        );
        std::fs::write(&path, "abc").unwrap();
        assert_eq!(
            fingerprint(&path, Checksum::Xxh128).unwrap(),
            (3, "06b05ab6733a618578af5f94892f3950".to_string())
        );
        // BLAKE3's reference vectors (test_vectors.json of the BLAKE3 team's repository): input
        // bytes i mod 251, here of length 1023 (a whole chunk less one byte) and 1025 (two
        // chunks), written to a file larger than nothing else reads in one block.
        // The same bytes' XXH3-128 by `xxhsum -H2` (past 240 bytes, XXH3 hashes in stripes).
        for (len, hash, xxh128) in [
            (
                1023,
                "10108970eeda3eb932baac1428c7a2163b0e924c9a9e25b35bba72b28f70bd11",
                "4325711b0ed4d742d3d91d80ac495685",
            ),
            (
                1025,
                "d00278ae47eb27b34faecf67b4fe263f82d5412916c1ffd97c8cb7fb814b8444",
                "2882ebca04ec915ce95c42288f28186e",
            ),
        ] {
            let bytes: Vec<u8> = (0..len).map(|i| (i % 251) as u8).collect();
            std::fs::write(&path, &bytes).unwrap();
            assert_eq!(
                fingerprint(&path, Checksum::Blake3).unwrap(),
                (len as u64, hash.to_string())
            );
            assert_eq!(
                fingerprint(&path, Checksum::Xxh128).unwrap(),
                (len as u64, xxh128.to_string())
            );
        }
    }

    /// A file of several read blocks hashes as its bytes do in one piece.
    #[test]
    fn fingerprints_join_the_read_blocks() {
        use sha2::Digest;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("long");
        let len = 2 * (8 << 20) + 12_345;
        let bytes: Vec<u8> = (0..len)
            .map(|i: usize| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
            .collect();
        std::fs::write(&path, &bytes).unwrap();
        assert_eq!(
            fingerprint(&path, Checksum::Blake3).unwrap(),
            (len as u64, blake3::hash(&bytes).to_hex().to_string())
        );
        let sha: String = sha2::Sha256::digest(&bytes)
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        assert_eq!(
            fingerprint(&path, Checksum::Sha256).unwrap(),
            (len as u64, sha)
        );
        // These bytes' XXH3-128 by `xxhsum -H2`.
        assert_eq!(
            fingerprint(&path, Checksum::Xxh128).unwrap(),
            (len as u64, "d4426104854e72ad7638624faf38be20".to_string())
        );
    }

    #[test]
    fn never_writes_over_an_input() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("speed.npy");
        std::fs::write(&input, "samples").unwrap();
        for force in [false, true] {
            let err = prepare(
                dir.path(),
                PROCESS_OUTPUTS,
                std::slice::from_ref(&input),
                force,
            )
            .unwrap_err();
            assert!(
                format!("{err:#}").contains("would overwrite the input"),
                "{err:#}"
            );
        }
        assert_eq!(std::fs::read_to_string(&input).unwrap(), "samples");
    }
}
