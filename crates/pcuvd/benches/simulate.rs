//! Simulator speed on the paper's spiral (≈13,500 scatterers, 128 channels, 0–14 mm window).
//!
//! `cargo bench -p pcuvd --bench simulate`. Besides criterion's wall-clock times, prints the CPU
//! time per event (from /proc/self/stat, Linux), which stays meaningful on a shared, busy machine,
//! and the projected wall time of the paper's study (800 conventional + 800 coded events).

use std::time::Instant;

use criterion::{Criterion, criterion_group, criterion_main};
use pcuvd::simulate::phantom::{Phantom, SpiralPhantom};
use pcuvd::simulate::{SimParams, paper_spiral_params, simulate};

/// Single-angle (0°), uncoded, noiseless variant of the paper's acquisition.
fn single_angle() -> SimParams {
    let mut p = paper_spiral_params(false).expect("params");
    p.sequence.angles = vec![0.0];
    p.noise = None;
    p
}

fn bench(c: &mut Criterion) {
    let spiral = SpiralPhantom::paper(1).expect("paper spiral");
    let mut group = c.benchmark_group("simulate");
    group.sample_size(10);

    let single = single_angle();
    group.bench_function("single_angle_event", |b| {
        b.iter(|| simulate(&spiral, &single, 1, &|_, _| {}).expect("simulate"))
    });

    let mut positions = Vec::new();
    group.bench_function("spiral_positions", |b| {
        b.iter(|| spiral.positions_at(0.37e-3, &mut positions))
    });

    // One coded compound frame: 8 events of 8 slots each, noise off (÷ 8 per event).
    let mut coded = paper_spiral_params(true).expect("params");
    coded.noise = None;
    group.bench_function("coded_frame_8_events", |b| {
        b.iter(|| simulate(&spiral, &coded, 1, &|_, _| {}).expect("simulate"))
    });
    group.finish();
}

/// Process CPU time (user + system, s), or `None` off Linux.
fn cpu_time() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
    let ticks: f64 = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// (wall, CPU) seconds per event of `frames` frames with `params`, over `reps` runs.
fn per_event(spiral: &SpiralPhantom, params: &SimParams, frames: usize, reps: usize) -> (f64, f64) {
    let events = (frames * params.sequence.n_angles() * reps) as f64;
    let (w0, c0) = (Instant::now(), cpu_time().unwrap_or(f64::NAN));
    for _ in 0..reps {
        simulate(spiral, params, frames, &|_, _| {}).expect("simulate");
    }
    let wall = w0.elapsed().as_secs_f64() / events;
    let cpu = (cpu_time().unwrap_or(f64::NAN) - c0) / events;
    (wall, cpu)
}

fn report(_: &mut Criterion) {
    let spiral = SpiralPhantom::paper(1).expect("paper spiral");
    let threads = rayon::current_num_threads() as f64;
    let (w, c) = per_event(&spiral, &single_angle(), 1, 40);
    eprintln!(
        "single-angle event: {:.2} ms wall, {:.2} ms CPU ({:.2} ms on {threads} idle cores)",
        w * 1e3,
        c * 1e3,
        c * 1e3 / threads
    );
    let conventional = paper_spiral_params(false).expect("params");
    let coded = paper_spiral_params(true).expect("params");
    let (wu, cu) = per_event(&spiral, &conventional, 2, 2);
    let (wc, cc) = per_event(&spiral, &coded, 2, 1);
    eprintln!(
        "paper conventional event (noise on): {:.2} ms wall, {:.2} ms CPU",
        wu * 1e3,
        cu * 1e3
    );
    eprintln!(
        "paper coded 8-slot event (noise on): {:.2} ms wall, {:.2} ms CPU",
        wc * 1e3,
        cc * 1e3
    );
    eprintln!(
        "paper study, 800 conventional + 800 coded events: {:.1} s wall as measured, {:.1} s on {threads} idle cores",
        800.0 * (wu + wc),
        800.0 * (cu + cc) / threads
    );
}

criterion_group!(benches, bench, report);
criterion_main!(benches);
