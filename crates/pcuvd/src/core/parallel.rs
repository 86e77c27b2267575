//! Sums computed on every core whose value does not depend on the cores: the same data give the
//! same bits on one thread or many, run after run.

use rayon::prelude::*;

/// Runs of consecutive chunks that [`sum_of_chunks`] sums apart: a number fixed whatever the
/// cores (enough to keep 16 of them busy), so that the order of the additions is too.
pub const RUNS: usize = 16;

/// The sum over `data`'s chunks of `chunk_len` items of `part(chunk)`, in parallel: the chunks
/// fall into [`RUNS`] runs of consecutive chunks, each run summed in order on one thread from
/// `zero()`, then the runs' sums added in order. Floating-point addition is not associative, and
/// a parallel `reduce` adds its partial sums in a tree that work stealing builds anew each run:
/// here the tree is fixed by the data's length alone.
pub fn sum_of_chunks<T, S>(
    data: &[T],
    chunk_len: usize,
    zero: impl Fn() -> S + Sync,
    part: impl Fn(&[T]) -> S + Sync,
    add: impl Fn(&mut S, S) + Sync,
) -> S
where
    T: Sync,
    S: Send,
{
    let chunks: Vec<&[T]> = data.chunks(chunk_len.max(1)).collect();
    let per_run = chunks.len().div_ceil(RUNS).max(1);
    let runs: Vec<S> = chunks
        .par_chunks(per_run)
        .map(|run| {
            let mut sum = zero();
            for chunk in run {
                add(&mut sum, part(chunk));
            }
            sum
        })
        .collect();
    let mut total = zero();
    for run in runs {
        add(&mut total, run);
    }
    total
}

/// `work`'s result computed on a pool of `threads` threads, for tests that a result does not
/// depend on them.
#[cfg(test)]
pub(crate) fn on_threads<R: Send>(threads: usize, work: impl FnOnce() -> R + Send) -> R {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("a thread pool")
        .install(work)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sums of values spanning 40 orders of magnitude, where the order of the additions shows
    /// in the result: the same bits on 1 to 7 threads, and the sequential sum run by run.
    #[test]
    fn the_sum_is_the_same_on_any_number_of_threads() {
        let data: Vec<f64> = (0..10_007)
            .map(|i| {
                let i = i as f64;
                (i * 0.7).sin() * 10f64.powf((i * 1.3).sin() * 20.0)
            })
            .collect();
        let on = |threads: usize| {
            on_threads(threads, || {
                sum_of_chunks(
                    &data,
                    100,
                    || 0.0,
                    |chunk| chunk.iter().sum::<f64>(),
                    |sum, part| *sum += part,
                )
            })
        };
        let one = on(1);
        for threads in 2..=7 {
            assert_eq!(on(threads).to_bits(), one.to_bits(), "{threads} threads");
        }
        // By hand: 101 chunks of 100 (the last of 7) in 16 runs of 7 chunks (the last of 3).
        let chunks: Vec<f64> = data.chunks(100).map(|c| c.iter().sum()).collect();
        let by_hand = chunks
            .chunks(7)
            .map(|run| run.iter().fold(0.0, |s, c| s + c))
            .fold(0.0, |s, r| s + r);
        assert_eq!(one.to_bits(), by_hand.to_bits());
    }
}
