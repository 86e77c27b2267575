//! The vector instructions the kernels may use, and the register shuffles they share.
//!
//! Every kernel with vector paths asks [`level`] which to run: the widest this CPU has, detected
//! once at run time (so that one build runs everywhere), or a narrower one that the environment
//! variable [`SIMD_VARIABLE`] names. The cap is for speed reports: what a CPU without AVX-512
//! (or without AVX2) spends, timed on one that has it. The libraries pcuvd calls (faer's matrix
//! products, BLAKE3) choose their own instructions and are not capped.

/// The environment variable that caps the vector instructions pcuvd's kernels use: `avx2` or
/// `portable` (any case); another value, or one wider than this CPU has, leaves the widest.
pub const SIMD_VARIABLE: &str = "PCUVD_SIMD";

/// Vector instructions a kernel may use, narrowest first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Level {
    /// Plain Rust: whatever the compiler makes of it for the build's target.
    Portable,
    /// AVX2 with FMA: 256-bit vectors, 16 registers.
    Avx2,
    /// AVX-512 F and DQ, with AVX2 and FMA: 512-bit vectors, 32 registers, masked loads.
    Avx512,
}

impl Level {
    /// The level's name in a speed report and in [`SIMD_VARIABLE`]'s values.
    pub fn name(self) -> &'static str {
        match self {
            Level::Portable => "portable",
            Level::Avx2 => "AVX2",
            Level::Avx512 => "AVX-512",
        }
    }

    /// The widest level this CPU runs.
    pub fn detected() -> Level {
        #[cfg(target_arch = "x86_64")]
        {
            let avx2 = is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma");
            if avx2 && is_x86_feature_detected!("avx512f") && is_x86_feature_detected!("avx512dq") {
                return Level::Avx512;
            }
            if avx2 {
                return Level::Avx2;
            }
        }
        Level::Portable
    }

    /// The level `name` gives (`avx512`, `avx2`, `portable`, with or without a hyphen, any
    /// case), if any.
    pub fn named(name: &str) -> Option<Level> {
        let name = name.trim().replace('-', "").to_ascii_lowercase();
        [Level::Portable, Level::Avx2, Level::Avx512]
            .into_iter()
            .find(|level| level.name().replace('-', "").to_ascii_lowercase() == name)
    }

    /// `detected` capped at the level `name` gives ([`Level::named`]); no name, an unknown one
    /// or a wider level leaves `detected`.
    pub fn capped(detected: Level, name: Option<&str>) -> Level {
        name.and_then(Level::named)
            .map_or(detected, |wanted| wanted.min(detected))
    }
}

/// The vector instructions the kernels use in this process: [`Level::detected`], capped by
/// [`SIMD_VARIABLE`]; read once.
pub fn level() -> Level {
    use std::sync::OnceLock;
    static LEVEL: OnceLock<Level> = OnceLock::new();
    *LEVEL.get_or_init(|| {
        let name = std::env::var(SIMD_VARIABLE).ok();
        Level::capped(Level::detected(), name.as_deref())
    })
}

/// The x86-64 CPU's vendor (`GenuineIntel`, `AuthenticAMD`, …) and its family and model as
/// `/proc/cpuinfo` numbers them (CPUID leaves 0 and 1, the extended fields folded in); `None`
/// on other architectures. Kernels whose widest level is not their fastest on some CPUs ask it.
pub fn cpu_identity() -> Option<([u8; 12], u32, u32)> {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::__cpuid;
        // CPUID is always available on x86-64; the intrinsic is safe from Rust 1.89 on.
        #[allow(unused_unsafe)]
        let (vendor, signature) = unsafe { (__cpuid(0), __cpuid(1).eax) };
        let mut name = [0u8; 12];
        name[..4].copy_from_slice(&vendor.ebx.to_le_bytes());
        name[4..8].copy_from_slice(&vendor.edx.to_le_bytes());
        name[8..].copy_from_slice(&vendor.ecx.to_le_bytes());
        let base_family = (signature >> 8) & 0xf;
        let family = if base_family == 0xf {
            base_family + ((signature >> 20) & 0xff)
        } else {
            base_family
        };
        let model = if base_family == 0x6 || base_family == 0xf {
            ((signature >> 4) & 0xf) | (((signature >> 16) & 0xf) << 4)
        } else {
            (signature >> 4) & 0xf
        };
        Some((name, family, model))
    }
    #[cfg(not(target_arch = "x86_64"))]
    None
}

/// Whether the kernels may use AVX-512 (F, DQ) here, with AVX2 and FMA.
pub fn avx512() -> bool {
    level() >= Level::Avx512
}

/// Whether the kernels may use AVX2 and FMA here.
pub fn avx2() -> bool {
    level() >= Level::Avx2
}

/// The 8 × 8 transpose of eight AVX vectors of 8 floats: out[i][j] = rows[j][i]. Kernels that
/// compute across one axis and store along the other (the simulator's powers per scatterer, the
/// demodulator's frames per row) turn their vectors with it; the values move unchanged.
///
/// # Safety
/// AVX2 must be available: callable without `unsafe` only from functions compiled for it.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub fn transpose_8x8(rows: [std::arch::x86_64::__m256; 8]) -> [std::arch::x86_64::__m256; 8] {
    use std::arch::x86_64::*;
    let r = rows;
    let t0 = _mm256_unpacklo_ps(r[0], r[1]);
    let t1 = _mm256_unpackhi_ps(r[0], r[1]);
    let t2 = _mm256_unpacklo_ps(r[2], r[3]);
    let t3 = _mm256_unpackhi_ps(r[2], r[3]);
    let t4 = _mm256_unpacklo_ps(r[4], r[5]);
    let t5 = _mm256_unpackhi_ps(r[4], r[5]);
    let t6 = _mm256_unpacklo_ps(r[6], r[7]);
    let t7 = _mm256_unpackhi_ps(r[6], r[7]);
    let u0 = _mm256_shuffle_ps::<0x44>(t0, t2);
    let u1 = _mm256_shuffle_ps::<0xEE>(t0, t2);
    let u2 = _mm256_shuffle_ps::<0x44>(t1, t3);
    let u3 = _mm256_shuffle_ps::<0xEE>(t1, t3);
    let u4 = _mm256_shuffle_ps::<0x44>(t4, t6);
    let u5 = _mm256_shuffle_ps::<0xEE>(t4, t6);
    let u6 = _mm256_shuffle_ps::<0x44>(t5, t7);
    let u7 = _mm256_shuffle_ps::<0xEE>(t5, t7);
    [
        _mm256_permute2f128_ps::<0x20>(u0, u4),
        _mm256_permute2f128_ps::<0x20>(u1, u5),
        _mm256_permute2f128_ps::<0x20>(u2, u6),
        _mm256_permute2f128_ps::<0x20>(u3, u7),
        _mm256_permute2f128_ps::<0x31>(u0, u4),
        _mm256_permute2f128_ps::<0x31>(u1, u5),
        _mm256_permute2f128_ps::<0x31>(u2, u6),
        _mm256_permute2f128_ps::<0x31>(u3, u7),
    ]
}

#[cfg(test)]
mod level_tests {
    use super::*;

    /// CPUID's vendor, family and model are those the kernel reads and prints in /proc/cpuinfo.
    #[test]
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    fn cpu_identity_is_what_the_kernel_reports() {
        let text = std::fs::read_to_string("/proc/cpuinfo").expect("/proc/cpuinfo on Linux");
        let field = |name: &str| {
            text.lines()
                .find(|line| line.split(':').next().map(str::trim) == Some(name))
                .and_then(|line| line.split(':').nth(1))
                .map(|value| value.trim().to_string())
                .expect("field in /proc/cpuinfo")
        };
        let (vendor, family, model) = cpu_identity().expect("x86-64");
        assert_eq!(std::str::from_utf8(&vendor).unwrap(), field("vendor_id"));
        assert_eq!(family.to_string(), field("cpu family"));
        assert_eq!(model.to_string(), field("model"));
    }

    /// A name caps the level at its own, never above what the CPU has; no name, an unknown one
    /// or a wider one leaves the CPU's.
    #[test]
    fn a_named_level_caps_the_detected_one() {
        use Level::*;
        let cases = [
            (Avx512, None, Avx512),
            (Avx512, Some("avx2"), Avx2),
            (Avx512, Some(" AVX-2 "), Avx2),
            (Avx512, Some("Portable"), Portable),
            (Avx512, Some("avx-512"), Avx512),
            (Avx512, Some("sse4"), Avx512),
            (Avx512, Some(""), Avx512),
            (Avx2, Some("avx512"), Avx2),
            (Avx2, Some("portable"), Portable),
            (Portable, Some("avx2"), Portable),
        ];
        for (detected, name, want) in cases {
            assert_eq!(
                Level::capped(detected, name),
                want,
                "{detected:?} capped by {name:?}"
            );
        }
    }

    /// The process's level is one this CPU runs.
    #[test]
    fn the_level_in_use_is_within_the_cpus() {
        assert!(level() <= Level::detected());
        assert_eq!(avx512(), level() == Level::Avx512);
        assert_eq!(avx2(), level() >= Level::Avx2);
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;
    use std::arch::x86_64::*;

    /// Every value lands at its transposed place.
    #[test]
    fn transposes_eight_by_eight() {
        if !is_x86_feature_detected!("avx2") {
            return;
        }
        let m: Vec<[f32; 8]> = (0..8)
            .map(|j| std::array::from_fn(|i| (10 * j + i) as f32))
            .collect();
        // SAFETY: AVX2 was detected; each load reads one row of 8 floats.
        let out = unsafe {
            let rows: [__m256; 8] = std::array::from_fn(|j| _mm256_loadu_ps(m[j].as_ptr()));
            transpose_8x8(rows)
        };
        for (i, v) in out.iter().enumerate() {
            let mut got = [0.0f32; 8];
            // SAFETY: AVX2 was detected; the store writes 8 floats into `got`.
            unsafe { _mm256_storeu_ps(got.as_mut_ptr(), *v) };
            let want: [f32; 8] = std::array::from_fn(|j| m[j][i]);
            assert_eq!(got, want, "row {i} of the transpose");
        }
    }
}
