//! Which accumulation kernel runs: the fastest that the CPU supports, detected once at run time
//! (so that one build runs everywhere), and the dispatch of a pixel's run of frames to it.

use num_complex::Complex32;

#[cfg(target_arch = "x86_64")]
use super::avx2;
#[cfg(target_arch = "x86_64")]
use super::avx512;
use super::portable;
use super::taps::{PF, Setup, Span, Taps};
use crate::core::simd::Level;

/// The environment variable that picks a slower beamformer kernel than this CPU's fastest
/// ([`Kernel::detect`]); `pcuvd bench` names the kernel that ran.
pub const KERNEL_VARIABLE: &str = "PCUVD_BEAMFORM_KERNEL";

/// The accumulation kernel in use: chosen once per process from the running CPU.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Kernel {
    /// Explicit AVX-512 (F, DQ) on interleaved complex frames, eight frames per vector, the last
    /// vector of a run masked.
    #[cfg(target_arch = "x86_64")]
    Avx512,
    /// Explicit AVX2 + FMA on interleaved complex frames, four frames per vector, the last
    /// vector of a run masked.
    #[cfg(target_arch = "x86_64")]
    Avx2,
    /// Plain Rust, any target.
    Portable,
}

impl Kernel {
    /// The kernels this process runs (those of [`crate::core::simd::level`]), fastest first;
    /// the portable loop is always last.
    // Elsewhere than on x86_64 only the portable loop is pushed.
    #[cfg_attr(not(target_arch = "x86_64"), allow(clippy::vec_init_then_push))]
    fn supported() -> &'static [Kernel] {
        use std::sync::OnceLock;
        static SUPPORTED: OnceLock<Vec<Kernel>> = OnceLock::new();
        SUPPORTED.get_or_init(|| {
            let mut kernels = Vec::new();
            #[cfg(target_arch = "x86_64")]
            {
                if crate::core::simd::avx512() {
                    kernels.push(Kernel::Avx512);
                }
                if crate::core::simd::avx2() {
                    kernels.push(Kernel::Avx2);
                }
            }
            kernels.push(Kernel::Portable);
            kernels
        })
    }

    /// The fastest kernel this CPU runs, or the one that the environment variable
    /// [`KERNEL_VARIABLE`] names (`avx2`, `portable`) where this CPU runs it: a speed report of
    /// what a CPU without AVX-512 would spend in the beamformer, taken on one that has it.
    pub(super) fn detect() -> Kernel {
        use std::sync::OnceLock;
        static CHOSEN: OnceLock<Kernel> = OnceLock::new();
        *CHOSEN.get_or_init(|| {
            let named = std::env::var(KERNEL_VARIABLE).ok();
            Kernel::named(named.as_deref(), Kernel::supported())
        })
    }

    /// The kernel of `name` among `supported` (fastest first, every slower level's kernel after
    /// the first), else the first of them: a name this CPU cannot run, or no name, leaves the
    /// fastest. The names are [`Level::named`]'s, as `PCUVD_SIMD` takes them: `avx512`, `avx2`,
    /// `portable`.
    fn named(name: Option<&str>, supported: &[Kernel]) -> Kernel {
        Kernel::at(Level::capped(supported[0].level(), name))
    }

    /// The vector instructions the kernel uses.
    fn level(self) -> Level {
        match self {
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512 => Level::Avx512,
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => Level::Avx2,
            Kernel::Portable => Level::Portable,
        }
    }

    /// The kernel that uses `level`'s vector instructions.
    fn at(level: Level) -> Kernel {
        match level {
            #[cfg(target_arch = "x86_64")]
            Level::Avx512 => Kernel::Avx512,
            #[cfg(target_arch = "x86_64")]
            Level::Avx2 => Kernel::Avx2,
            // Elsewhere than on x86_64 no wider level is detected.
            _ => Kernel::Portable,
        }
    }

    /// What the kernel is, for a speed report (see [`super::AccumulationKernel`]).
    pub(super) fn describe(self) -> super::AccumulationKernel {
        let (name, vector_bits, fma_per_point) = match self {
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512 => ("AVX-512", Some(512), Some(avx512::FMA_PER_POINT)),
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => ("AVX2", Some(256), Some(avx2::FMA_PER_POINT)),
            Kernel::Portable => ("portable", None, None),
        };
        super::AccumulationKernel {
            name,
            vector_bits,
            fma_per_point,
        }
    }

    /// Adds to `out`, frames `f0..f0 + out.len()` of pixel `p`, Σ over its taps of c0·a + c1·b,
    /// a and b being the tap element's frames at samples i0 and i0 + 1; with `fresh`, writes
    /// that sum to `out`, bit for bit what adding it to zeros gives, without reading `out` (a
    /// pixel's first pass: its memory then needs no zeroing). `next` (the next pixel's sums) is
    /// only prefetched.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn accumulate(
        self,
        out: &mut [Complex32],
        f0: usize,
        data: &[Complex32],
        setup: &Setup,
        taps: &Taps,
        p: usize,
        next: *const Complex32,
        fresh: bool,
    ) {
        let (frames, n_samples, row) = (setup.frames, setup.n_samples, setup.row);
        let Span { start, len } = taps.spans[p];
        let end = start + len;
        // Rows of `row` samples, the last one's `frames` read: every frame of every row is in.
        let rows = setup.element_x.len() * n_samples;
        assert!(
            f0 + out.len() <= frames && frames <= row && data.len() >= (rows - 1) * row + frames
        );
        assert!(taps.rows.len() >= end + PF && taps.c1_im.len() >= end);
        #[cfg(target_arch = "x86_64")]
        if self == Kernel::Avx512 && !out.is_empty() && out.len() <= 8 * avx512::MAX_VECTORS {
            // SAFETY: AVX-512F/DQ, AVX2 and FMA were detected. Reads stay within `data` as for
            // AVX2 below; the masked last vector reads and writes only frames below
            // f0 + out.len().
            unsafe { avx512::pixel_chunk(out, next, data, f0, row, taps, start, len, fresh) };
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if self == Kernel::Avx2 && !out.is_empty() && out.len() <= 4 * avx2::MAX_VECTORS {
            // SAFETY: AVX2 and FMA were detected. Reads stay within `data`: each row index is
            // that of an element below the channel count and a sample i0 with
            // i0 + 1 < n_samples (the `Taps` invariant), frames below f0 + out.len() ≤ frames
            // (asserted above; the masked last vector reads and writes no frame beyond); the tap
            // arrays hold `end` entries and `rows` PF more (asserted above).
            unsafe { avx2::pixel_chunk(out, next, data, f0, row, taps, start, len, fresh) };
            return;
        }
        // Only the SIMD kernels prefetch.
        let _ = next;
        if fresh {
            out.fill(Complex32::new(0.0, 0.0));
        }
        portable::pixel_chunk(out, data, f0, row, taps, start, len);
    }
}

/// Runs of frames that the kernel keeps in registers, of near-equal whole numbers of vectors and
/// at most its register budget each, the last run ending in a partial (masked) vector.
pub(super) fn frame_chunks(frames: usize, kernel: Kernel) -> Vec<std::ops::Range<usize>> {
    let simd = match kernel {
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx512 => Some((8, avx512::MAX_VECTORS)),
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx2 => Some((4, avx2::MAX_VECTORS)),
        Kernel::Portable => None,
    };
    let Some((width, max)) = simd else {
        // One run of all the frames (not a list of its frame indices).
        #[allow(clippy::single_range_in_vec_init)]
        return vec![0..frames];
    };
    let vectors = frames.div_ceil(width);
    let n = vectors.div_ceil(max);
    (0..n)
        .map(|i| width * (i * vectors / n)..(width * ((i + 1) * vectors / n)).min(frames))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::acquisition::probe::Probe;
    use crate::core::grid::Grid;
    use crate::form::beamform::tests::{noise, random_iq};
    use crate::form::beamform::tiling::{beamform_with, rows_of_frames};
    use crate::form::beamform::{Apodization, DasParams};

    /// Runs `kernel`'s accumulation against the portable loop's on random taps and data, over
    /// every run of frames it is given for several frame counts (whole vectors, partial last
    /// vectors, more than one run), and on a whole image. Both sum the same f32 products in a
    /// different order and with or without FMA, so they differ by rounding only: a few ulps of
    /// the largest partial sum (here |sum| ≲ 8·|terms|), hence a relative bound of 1e-5 of the
    /// sum's size, or of 1 where the sum nearly cancels. A fresh run writes, to the bit, what a
    /// run adds to zeros, whatever the memory held.
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    fn kernel_matches_portable_loop(kernel: Kernel) {
        for frames in [1, 3, 8, 37, 100, 104, 105, 230] {
            let (channels, samples) = (5, 40);
            let iq = random_iq(channels, samples, frames, 3);
            let data = iq.data.as_slice().unwrap();
            let setup = Setup {
                element_x: vec![0.0; channels],
                padded_x: vec![0.0; channels],
                sorted: true,
                angle: 0.0,
                aperture: (0.0, 0.0),
                c: 1540.0,
                fs: 1.0,
                t0: 0.0,
                demod_frequency: 1.0,
                f_number: 1.0,
                apodization: Apodization::Boxcar,
                n_samples: samples,
                frames,
                row: frames,
            };
            let mut r = noise(11);
            // Two pixels, with four and three taps, on elements 1..5; the first tap of the
            // second reads the last sample pair of its element.
            let mut taps = Taps::default();
            for (n, offset) in [(4, 3), (3, 38)] {
                let start = taps.push(n, 0, 1);
                for k in 0..n {
                    let i0 = (k * 9 + offset).min(samples - 2);
                    taps.rows[start + k] = ((1 + k) * samples + i0) as u32;
                    taps.c0_re[start + k] = r();
                    taps.c0_im[start + k] = r();
                    taps.c1_re[start + k] = r();
                    taps.c1_im[start + k] = r();
                }
            }
            taps.finish();
            let chunks = frame_chunks(frames, kernel);
            assert_eq!(chunks.first().map(|c| c.start), Some(0));
            assert_eq!(chunks.last().map(|c| c.end), Some(frames));
            assert!(chunks.windows(2).all(|w| w[0].end == w[1].start));
            for p in 0..2 {
                for range in chunks.clone() {
                    let mut r = noise(range.start as u64);
                    let start: Vec<Complex32> =
                        range.clone().map(|_| Complex32::new(r(), r())).collect();
                    let (mut fast, mut slow) = (start.clone(), start);
                    let next = data.as_ptr();
                    let run = |out: &mut [Complex32], kernel: Kernel, fresh: bool| {
                        kernel.accumulate(out, range.start, data, &setup, &taps, p, next, fresh)
                    };
                    run(&mut fast, kernel, false);
                    run(&mut slow, Kernel::Portable, false);
                    for (a, b) in fast.iter().zip(&slow) {
                        assert!(
                            (a - b).norm() <= 1e-5 * b.norm().max(1.0),
                            "{kernel:?}, {frames} frames: {a} vs {b}"
                        );
                    }
                    // A fresh run writes over whatever was there what a run adds to zeros.
                    let mut written = vec![Complex32::new(f32::NAN, f32::INFINITY); range.len()];
                    let mut added = vec![Complex32::new(0.0, 0.0); range.len()];
                    run(&mut written, kernel, true);
                    run(&mut added, kernel, false);
                    let bits = |v: &[Complex32]| -> Vec<(u32, u32)> {
                        v.iter().map(|c| (c.re.to_bits(), c.im.to_bits())).collect()
                    };
                    assert_eq!(bits(&written), bits(&added), "{kernel:?}, {frames} frames");
                }
            }
        }
        // A whole image, 21 frames (a partial last vector for either kernel), against the
        // portable kernel's.
        let probe = Probe::l22_14vx();
        let grid = Grid::new(-1e-3, 1e-3, 3e-3, 4e-3, 0.1e-3).unwrap();
        let iq = random_iq(probe.n_elements, 400, 21, 5);
        let params = DasParams::new(1540.0);
        let fast = beamform_with(kernel, &iq, &probe, 0.1, &grid, &params).unwrap();
        let slow = beamform_with(Kernel::Portable, &iq, &probe, 0.1, &grid, &params).unwrap();
        let scale = slow.iter().map(|v| v.norm()).fold(0.0f32, f32::max);
        assert!(scale > 1.0);
        for (a, b) in fast.iter().zip(slow.iter()) {
            assert!((a - b).norm() <= 1e-5 * scale, "{kernel:?}: {a} vs {b}");
        }
    }

    /// Samples whose rows of frames are padded to cache lines (as demodulation writes them),
    /// or lie at any other strides (a transposed array, copied), beamform to the bit as the
    /// same samples in standard layout, with every kernel this CPU runs, for frame counts that
    /// fill their vectors and that do not.
    #[test]
    fn padded_and_strided_samples_beamform_as_standard_ones() {
        let probe = Probe::l22_14vx();
        let grid = Grid::new(-1e-3, 1e-3, 3e-3, 3.6e-3, 0.1e-3).unwrap();
        let params = DasParams::new(1540.0);
        for frames in [1, 5, 8, 90, 105] {
            let iq = random_iq(probe.n_elements, 300, frames, frames as u64);
            let shape = iq.data.dim();
            let mut padded = iq.clone();
            let whole = crate::core::buffers::padded_rows_reusing(None, shape);
            padded.data = whole.slice_move(ndarray::s![.., .., ..frames]);
            padded.data.assign(&iq.data);
            assert!(frames % 8 == 0 || !padded.data.is_standard_layout());
            // Read where they lie, not copied.
            let (span, row) = rows_of_frames(&padded.data);
            assert!(
                matches!(span, std::borrow::Cow::Borrowed(_)),
                "{frames} frames"
            );
            assert_eq!(row, frames.next_multiple_of(8));
            let mut strided = iq.clone();
            let mut transposed = ndarray::Array3::zeros((frames, shape.1, shape.0));
            transposed.assign(&iq.data.view().permuted_axes([2, 1, 0]));
            strided.data = transposed.permuted_axes([2, 1, 0]);
            let bits = |image: &ndarray::Array3<Complex32>| {
                image
                    .iter()
                    .map(|v| (v.re.to_bits(), v.im.to_bits()))
                    .collect::<Vec<_>>()
            };
            for &kernel in Kernel::supported() {
                let standard = beamform_with(kernel, &iq, &probe, 0.1, &grid, &params).unwrap();
                assert!(standard.iter().any(|v| v.norm() > 0.0));
                for other in [&padded, &strided] {
                    let image = beamform_with(kernel, other, &probe, 0.1, &grid, &params).unwrap();
                    assert_eq!(bits(&image), bits(&standard), "{kernel:?}, {frames} frames");
                }
            }
        }
    }

    #[test]
    fn each_kernel_counts_its_fmas_per_point_from_its_frames_per_vector() {
        // Four FMAs per tap and vector (two sums, each of two samples): a 512-bit vector holds
        // 8 complex frames, a 256-bit one 4.
        for &kernel in Kernel::supported() {
            let d = kernel.describe();
            match (d.vector_bits, d.fma_per_point) {
                (Some(bits), Some(per_point)) => {
                    assert_eq!(per_point, 4.0 / (bits / 64) as f64, "{}", d.name)
                }
                (None, None) => assert_eq!(kernel, Kernel::Portable),
                other => panic!("{}: {other:?}", d.name),
            }
        }
        assert_eq!(
            super::super::accumulation_kernel(),
            Kernel::detect().describe()
        );
    }

    #[test]
    fn avx512_kernel_matches_portable_loop() {
        #[cfg(target_arch = "x86_64")]
        if Kernel::supported().contains(&Kernel::Avx512) {
            return kernel_matches_portable_loop(Kernel::Avx512);
        }
        eprintln!("skipped: this CPU has no AVX-512F/DQ (or no AVX2 + FMA)");
    }

    #[test]
    fn avx2_kernel_matches_portable_loop() {
        #[cfg(target_arch = "x86_64")]
        if Kernel::supported().contains(&Kernel::Avx2) {
            return kernel_matches_portable_loop(Kernel::Avx2);
        }
        eprintln!("skipped: this CPU has no AVX2 + FMA");
    }

    #[test]
    fn detect_picks_the_first_supported_kernel_unless_one_is_named() {
        let supported = Kernel::supported();
        let named = std::env::var(KERNEL_VARIABLE).ok();
        assert_eq!(Kernel::detect(), Kernel::named(named.as_deref(), supported));
        assert_eq!(Kernel::named(None, supported), supported[0]);
        assert_eq!(supported.last(), Some(&Kernel::Portable));
    }

    #[test]
    fn a_named_kernel_is_taken_only_where_the_cpu_runs_it() {
        let portable_only = [Kernel::Portable];
        assert_eq!(
            Kernel::named(Some("portable"), &portable_only),
            Kernel::Portable
        );
        #[cfg(target_arch = "x86_64")]
        {
            let all = [Kernel::Avx512, Kernel::Avx2, Kernel::Portable];
            assert_eq!(Kernel::named(Some("avx2"), &all), Kernel::Avx2);
            assert_eq!(Kernel::named(Some(" AVX2 "), &all), Kernel::Avx2);
            assert_eq!(Kernel::named(Some("portable"), &all), Kernel::Portable);
            assert_eq!(Kernel::named(Some("avx512"), &all), Kernel::Avx512);
            // Unknown, empty or unsupported names leave the fastest.
            assert_eq!(Kernel::named(Some("sse"), &all), Kernel::Avx512);
            assert_eq!(Kernel::named(Some(""), &all), Kernel::Avx512);
            let no_avx512 = [Kernel::Avx2, Kernel::Portable];
            assert_eq!(Kernel::named(Some("avx512"), &no_avx512), Kernel::Avx2);
            assert_eq!(
                Kernel::named(Some("avx2"), &portable_only),
                Kernel::Portable
            );
        }
    }
}
