//! Deterministic parallel sums: fixed chunks, partial results added in chunk order.

use rayon::prelude::*;
use std::ops::Range;

/// Up to this many items, work runs on the calling thread: handing it to the rayon pool (a
/// wake-up and a wait) costs more than a few hundred points' worth of work, e.g. a 2D scan
/// (180–361 points: measured on Intel and LMS scans). Two chunks at most ([`chunk_len`]), so a
/// 3D cloud this small gives up at most a two-way split.
pub const SEQUENTIAL_MAX: usize = 512;

/// Parallel maps over points (batch queries, per-point keys) split into pieces of at least
/// this many items, so a batch the size of a 2D scan never leaves the calling thread: rayon
/// then folds it inline, where handing even three queries to the pool from a foreign thread
/// cost ~30 µs (against under 1 µs for the work). Maps only: their results do not depend on
/// the split.
pub const MIN_PAR_ITEMS: usize = 256;

/// Points per chunk for `n` points: about 64 chunks, each of 256 to 8192 points.
///
/// A function of `n` only, never of the thread count, so results stay thread-independent. Not
/// a fixed size: 2048 would split a typical downsampled scan (~6k points) into 3 full chunks
/// and a sliver, and on 2 threads one thread would do two thirds of every ICP iteration.
pub fn chunk_len(n: usize) -> usize {
    n.div_ceil(64).clamp(256, 8192)
}

/// Apply `partial` to consecutive index ranges of `0..n` in parallel and fold the results
/// in order with `combine`, starting from `identity`. The chunking does not depend on the
/// thread count, so neither does the floating-point result.
pub fn chunked_sum<A, F, C>(n: usize, identity: A, partial: F, combine: C) -> A
where
    A: Send,
    F: Fn(Range<usize>) -> A + Sync,
    C: Fn(A, A) -> A,
{
    let len = chunk_len(n);
    let chunks = n.div_ceil(len);
    let range = |c: usize| c * len..((c + 1) * len).min(n);
    if n <= SEQUENTIAL_MAX {
        // The same chunks in the same order, so the same result, without the pool.
        return (0..chunks)
            .map(|c| partial(range(c)))
            .fold(identity, combine);
    }
    let parts: Vec<A> = (0..chunks)
        .into_par_iter()
        .map(|c| partial(range(c)))
        .collect();
    parts.into_iter().fold(identity, combine)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sum_matches_sequential_and_is_thread_independent() {
        let values: Vec<f64> = (0..10_000).map(|i| (i as f64).sin() * 1e-3 + 1.0).collect();
        let run = || {
            chunked_sum(
                values.len(),
                0.0,
                |r| values[r].iter().sum::<f64>(),
                |a, b| a + b,
            )
        };
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(run);
        let many = rayon::ThreadPoolBuilder::new()
            .num_threads(4)
            .build()
            .unwrap()
            .install(run);
        assert_eq!(one.to_bits(), many.to_bits());
        let seq: f64 = values.iter().sum();
        assert!((one - seq).abs() < 1e-9);
    }

    #[test]
    fn empty_input_gives_identity() {
        assert_eq!(chunked_sum(0, 7.0, |_| 1.0, |a, b| a + b), 7.0);
    }
}
