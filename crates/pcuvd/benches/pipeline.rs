//! Throughput of the pipeline's heavy stages, in release builds on the machine at hand.
//!
//! DAS: 256 × 256 pixels, 128 channels, 100 frames, full receive aperture (every channel
//! contributes to every pixel, so every counted pixel·channel·frame point is real work); once
//! into a new image, as `beamform` returns it, and once into one image reused, as the pipeline's
//! blocks are: the difference is faulting in the new image's 52 MB, which on a virtual machine
//! whose balloon hands freed pages back to the host costs a tenth of the time.
//! Decoding: a coded RF recording of 8 angles × 100 frames, 128 channels, 1000 samples (65 MHz,
//! 1 µs slots: whole-sample slot shifts, as in the rat setting), with the
//! events taken as simultaneous and aligned to mid-frame (the extra slow-time resampling).
//! Dealiasing: a 256 × 256 map (0.05 mm grid) with two tubes 1 mm wide at 3× v_N, parabolic, 8
//! angles within ±15°, wrapped projections with 1 mm/s of deterministic scatter; flow pixels are
//! the tubes and a 0.1 mm rim; K = 2, each estimator alone and both at once (as `process` runs
//! them), against the plain fit of the whole map.
//! Demodulation: one angle of 90 RF frames, 128 channels, 1903 samples at 65 MHz (the rat
//! network's records), mixed to baseband and low-pass filtered into rows of frames.
//! Dynamics: the sliding windows of `process` (36 frames, 9 apart, Loupas, 5 × 5 kernel, IRLS)
//! over 90 frames of 8 angles, 192 × 128 pixels (0.05 mm grid) of random speckle: 7 windows,
//! each frame in four of them.
//! Clutter: a 256 × 256 × 100 series with 5 components cut over the whole image; a 256 × 128 ×
//! 180 series of slowly moving tissue cut by the auto rule block by block (37-pixel blocks, made
//! 38 so that half-block steps tile the image).

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ndarray::{Array2, Array3};
use num_complex::Complex32;
use pcuvd::acquisition::channel::{Acquisition, AngleSamples, ChannelData, Samples};
use pcuvd::core::grid::Grid;
use pcuvd::estimate::clutter::{ClutterParams, RankCut, svd_filter};
use pcuvd::estimate::dealias::{
    Dealias, auto_intervals, dealiased_vectors, dealiased_vectors_each, uniform,
};
use pcuvd::estimate::projections::Projections;
use pcuvd::estimate::vector::{Estimator, IrlsParams, projection_weights, vector_velocity};
use pcuvd::form::beamform::{Apodization, DasParams, beamform, beamform_into};
use pcuvd::form::decode::{Decoder, EventAlignment};
use pcuvd::form::iq::{IqChannels, demodulate_into};
use pcuvd::{Coding, Probe, Sequence};

fn das_input(probe: &Probe, frames: usize) -> IqChannels {
    let samples = 1500;
    let data = Array3::from_shape_fn((probe.n_elements, samples, frames), |(c, s, f)| {
        Complex32::from_polar(1.0, (c * 7 + s * 3 + f) as f32 * 0.1)
    });
    IqChannels {
        data,
        sampling_frequency: 65e6,
        t0: 0.0,
        demod_frequency: probe.center_frequency,
    }
}

fn das(c: &mut Criterion) {
    let probe = Probe::l22_14vx();
    let frames = 100;
    let iq = das_input(&probe, frames);
    let step = 12.8e-3 / 256.0;
    let grid = Grid::new(
        -6.4e-3,
        -6.4e-3 + 255.0 * step,
        2e-3,
        2e-3 + 255.0 * step,
        step,
    )
    .unwrap();
    assert_eq!(grid.shape(), (256, 256));
    let params = DasParams {
        f_number: 1e-3,
        apodization: Apodization::Boxcar,
        sound_speed: 1540.0,
    };
    let points = (256 * 256 * probe.n_elements * frames) as u64;
    let mut group = c.benchmark_group("das");
    group.sample_size(10);
    group.throughput(Throughput::Elements(points));
    group.bench_function("256x256px_128ch_100fr", |b| {
        b.iter(|| beamform(&iq, &probe, 0.1, &grid, &params).unwrap())
    });
    let mut image = Array3::<Complex32>::zeros((256, 256, frames));
    group.bench_function("into_256x256px_128ch_100fr", |b| {
        b.iter(|| beamform_into(&iq, &probe, 0.1, &grid, &params, image.view_mut()).unwrap())
    });
    group.finish();
}

fn demodulate(c: &mut Criterion) {
    let (frames, channels, samples) = (90, 128, 1903);
    let rf = AngleSamples::Rf(ndarray::Array4::from_shape_fn(
        (1, frames, channels, samples),
        |(_, f, ch, n)| (n as f32 * 1.51 + ch as f32 * 0.3 + f as f32 * 0.07).sin(),
    ));
    let mut out = IqChannels {
        data: Array3::zeros((0, 0, 0)),
        sampling_frequency: 65e6,
        t0: 0.0,
        demod_frequency: 15.625e6,
    };
    let mut group = c.benchmark_group("demodulate");
    group.sample_size(10);
    group.throughput(Throughput::Elements((frames * channels * samples) as u64));
    group.bench_function("90fr_128ch_1903s", |b| {
        b.iter(|| demodulate_into(rf.view(), 0, 0.0, 65e6, 15.625e6, None, &mut out).unwrap())
    });
    group.finish();
}

fn clutter(c: &mut Criterion) {
    let series = Array3::from_shape_fn((256, 256, 100), |(z, x, f)| {
        Complex32::from_polar(1.0 + (z % 7) as f32, (x * 3 + f * (z % 5)) as f32 * 0.2)
    });
    let params = ClutterParams {
        low: RankCut::Fixed(5),
        high: RankCut::Off,
        tissue_frequency: 0.02,
        blocks: None,
    };
    let mut group = c.benchmark_group("clutter");
    group.sample_size(10);
    group.bench_function("svd_256x256px_100fr", |b| {
        b.iter_batched(
            || series.clone(),
            |mut s| svd_filter(&mut s, &params).unwrap(),
            criterion::BatchSize::LargeInput,
        )
    });
    // Block-wise: tissue whose echo and slow motion vary with depth (three components falling
    // 30 dB each, the auto rule cutting them) over weak moving blood and noise, in 37-pixel
    // blocks (2 mm on the rat grid) over 180 frames, as on the virtual brain.
    let frames = 180;
    let tissue = Array3::from_shape_fn((256, 128, frames), |(z, x, f)| {
        let speckle = ((z * 7919 + x * 104_729) % 1000) as f32 * 1e-3;
        let t = f as f32 / frames as f32;
        let depth = z as f32 / 256.0;
        let drift = Complex32::from_polar(1.0, 6.3 * (0.5 + depth) * t);
        let blood = Complex32::from_polar(0.01, (z * x) as f32 * 0.37 + 2.0 * f as f32);
        let noise = Complex32::from_polar(0.003, (z * 31 + x * 17 + f * 13) as f32);
        Complex32::new(30.0 * (1.0 + speckle), 0.0) * (1.0 + drift * 0.03 + drift * drift * 1e-3)
            + blood
            + noise
    });
    let blocks = ClutterParams {
        low: RankCut::Auto,
        blocks: Some((37, 37)),
        ..params
    };
    group.bench_function("blocks_37px_256x128px_180fr", |b| {
        b.iter_batched(
            || tissue.clone(),
            |mut s| svd_filter(&mut s, &blocks).unwrap(),
            criterion::BatchSize::LargeInput,
        )
    });
    group.finish();
}

fn decode(c: &mut Criterion) {
    let (n, frames, samples) = (8usize, 100usize, 1000usize);
    let probe = Probe::l22_14vx();
    let events = Array3::from_shape_fn((n * frames, probe.n_elements, samples), |(e, c, s)| {
        ((e * 13 + c * 7 + s * 3) as f32 * 0.1).sin()
    });
    let data = ChannelData {
        acquisition: Acquisition {
            probe,
            sequence: Sequence {
                angles: Sequence::evenly_spaced_angles(n, 15f64.to_radians()),
                event_prf: 14.4e3,
                coding: Coding::Hadamard { slot_delay: 1e-6 },
                pulse_cycles: 2.0,
                pulse: None,
            },
            sampling_frequency: 65e6,
            sound_speed: 1540.0,
            t0: 0.0,
        },
        samples: Samples::Rf(events),
    };
    let mut group = c.benchmark_group("decode");
    group.sample_size(10);
    group.throughput(Throughput::Elements((n * frames * samples * 128) as u64));
    for (name, alignment) in [
        (
            "simultaneous_8x100fr_128ch_1000s",
            EventAlignment::Simultaneous,
        ),
        ("mid_frame_8x100fr_128ch_1000s", EventAlignment::MidFrame),
    ] {
        let decoder = Decoder::new(&data, alignment).unwrap();
        group.bench_function(name, |b| b.iter(|| decoder.decode(&data.samples).unwrap()));
    }
    group.finish();
}

fn dealias(c: &mut Criterion) {
    let (n, nz, nx, step) = (8usize, 256usize, 256usize, 0.05e-3);
    let vn = 1540.0 * 1800.0 / (4.0 * 15.625e6);
    let angles = Sequence::evenly_spaced_angles(n, 15f64.to_radians());
    let (radius, peak) = (0.5e-3, 3.0 * vn);
    // (direction below +x, a point on the axis (x, z) in m) of each tube.
    let tubes = [
        (30f64.to_radians(), (0.0, 4e-3)),
        (-60f64.to_radians(), (2e-3, 8e-3)),
    ];
    let mut truth = Array2::from_elem((nz, nx), (0.0, 0.0));
    let mut flow = Array2::from_elem((nz, nx), false);
    for iz in 0..nz {
        for ix in 0..nx {
            let (x, z) = ((ix as f64 - 128.0) * step, iz as f64 * step);
            for &(dir, (x0, z0)) in &tubes {
                let l = -(x - x0) * dir.sin() + (z - z0) * dir.cos();
                flow[[iz, ix]] |= l.abs() <= radius + 2.0 * step;
                if l.abs() <= radius {
                    let u = peak * (1.0 - (l / radius).powi(2));
                    truth[[iz, ix]] = (u * dir.cos(), u * dir.sin());
                }
            }
        }
    }
    let v_theta = Array3::from_shape_fn((n, nz, nx), |(a, iz, ix)| {
        let (s, c) = projection_weights(angles[a]);
        let (vx, vz) = truth[[iz, ix]];
        let scatter = 1e-3 * ((a * 7919 + iz * 104_729 + ix * 1_299_709) as f64).sin();
        (0.5 * (vx * s + vz * c) + scatter + vn).rem_euclid(2.0 * vn) - vn
    });
    let power = flow.mapv(|f| if f { 1.0 } else { 1e-3 });
    let nyquist = uniform(vn, (n, nz, nx));
    let projections = Projections::new(&angles, v_theta.view(), None, nyquist.view()).unwrap();
    let run = |estimator: &Estimator| {
        dealiased_vectors(
            &projections,
            estimator,
            Dealias::Intervals(2),
            power.view(),
            flow.view(),
        )
        .unwrap()
    };
    // The work measured is the real one: the tubes come out unwrapped.
    let done = run(&Estimator::LeastSquares);
    let lumen: Vec<(usize, usize)> = truth
        .indexed_iter()
        .filter(|(_, t)| t.0 != 0.0 || t.1 != 0.0)
        .map(|(i, _)| i)
        .collect();
    let within = lumen
        .iter()
        .filter(|&&(iz, ix)| {
            let (tx, tz) = truth[[iz, ix]];
            (done.field.vx[[iz, ix]] - tx).hypot(done.field.vz[[iz, ix]] - tz) <= 0.1 * peak
        })
        .count();
    assert!(
        within * 10 >= lumen.len() * 9,
        "{within} of {}",
        lumen.len()
    );
    let mut group = c.benchmark_group("dealias");
    group.sample_size(10);
    for (name, estimator) in [
        ("ls_k2_256x256px_8angles", Estimator::LeastSquares),
        (
            "irls_k2_256x256px_8angles",
            Estimator::Irls(IrlsParams::default()),
        ),
    ] {
        group.bench_function(name, |b| b.iter(|| run(&estimator)));
    }
    // What `process` runs: both estimators, the levels settled once.
    let both = [
        Estimator::LeastSquares,
        Estimator::Irls(IrlsParams::default()),
    ];
    let each = |dealias: Dealias| {
        dealiased_vectors_each(&projections, &both, dealias, power.view(), flow.view()).unwrap()
    };
    group.bench_function("ls_and_irls_k2_256x256px_8angles", |b| {
        b.iter(|| each(Dealias::Intervals(2)))
    });
    // Auto: K is searched from 1 (this map settles at 2), and the levels of the K found serve
    // the fits; before, the fits settled them again after the search.
    group.bench_function("ls_and_irls_auto_256x256px_8angles", |b| {
        b.iter(|| each(Dealias::Auto))
    });
    group.bench_function("auto_search_256x256px_8angles", |b| {
        b.iter(|| auto_intervals(&projections, power.view(), flow.view()))
    });
    group.bench_function("plain_ls_256x256px_8angles", |b| {
        b.iter(|| vector_velocity(&angles, v_theta.view(), &Estimator::LeastSquares).unwrap())
    });
    group.bench_function("plain_irls_256x256px_8angles", |b| {
        let irls = Estimator::Irls(IrlsParams::default());
        b.iter(|| vector_velocity(&angles, v_theta.view(), &irls).unwrap())
    });
    group.finish();
}

fn dynamics(c: &mut Criterion) {
    use pcuvd::dynamics::{DynamicsParams, sliding_vectors};
    use pcuvd::form::images::AngleImages;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    let (nz, nx, frames, step) = (192, 128, 90, 5e-5);
    let angles: Vec<f64> = (0..8)
        .map(|i| (-15.0 + 30.0 * i as f64 / 7.0_f64).to_radians())
        .collect();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let mut draw = || -> f32 { StandardNormal.sample(&mut rng) };
    let series = angles
        .iter()
        .map(|_| Array3::from_shape_fn((nz, nx, frames), |_| Complex32::new(draw(), draw())))
        .collect();
    let images = AngleImages {
        grid: Grid {
            x: (0..nx).map(|i| i as f64 * step).collect(),
            z: (0..nz).map(|i| 2e-3 + i as f64 * step).collect(),
        },
        angles,
        frame_rate: 1800.0,
        sound_speed: 1540.0,
        demodulation_frequency: 15.625e6,
        coverage: None,
        series,
    };
    let params = DynamicsParams {
        kernel: (5, 5),
        heart_rate_hz: None,
        ..DynamicsParams::rat()
    };
    let mut group = c.benchmark_group("dynamics");
    group.sample_size(10);
    group.throughput(Throughput::Elements((nz * nx * 7 * 8) as u64));
    group.bench_function("windows_36fr_step9_192x128px_8angles_90fr", |b| {
        b.iter(|| sliding_vectors(&images, &params).unwrap())
    });
    group.finish();
}

criterion_group!(benches, das, demodulate, clutter, decode, dealias, dynamics);
criterion_main!(benches);
