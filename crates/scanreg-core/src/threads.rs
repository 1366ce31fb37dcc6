//! The process-wide thread budget: the size of rayon's global pool, which every parallel loop
//! without a pool of its own ([`in_pool`]) runs on.
//!
//! A batch worker given one CPU must not start one thread per core: it fixes the size once,
//! before any parallel work. Results do not depend on it (fixed chunks, ordered sums).

use crate::{Error, Result};
use rayon::ThreadPool;
use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

/// Build the global pool with `n` threads. Succeeds when the pool already has `n` threads;
/// fails when it was built with another size (rayon builds it once per process, at the first
/// parallel call, from `RAYON_NUM_THREADS` or the number of CPUs).
pub fn set_num_threads(n: usize) -> Result<()> {
    if n == 0 {
        return Err(Error::invalid("num_threads", "must be >= 1"));
    }
    match rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build_global()
    {
        Ok(()) => Ok(()),
        Err(_) if rayon::current_num_threads() == n => Ok(()),
        Err(_) => Err(Error::invalid(
            "num_threads",
            format!(
                "the thread pool already runs {} threads (it is sized once per process, at the \
                 first parallel call): set it before any other scanreg call, or set \
                 RAYON_NUM_THREADS={n} in the environment",
                rayon::current_num_threads()
            ),
        )),
    }
}

/// Threads of the global pool (builds it with its default size if no call has yet).
pub fn num_threads() -> usize {
    rayon::current_num_threads()
}

/// Run `f` on a rayon pool of `num_threads` threads (pools are built once per size and kept),
/// or on the global pool when `None`.
pub fn in_pool<T: Send>(num_threads: Option<usize>, f: impl FnOnce() -> T + Send) -> Result<T> {
    let Some(n) = num_threads else {
        return Ok(f());
    };
    if n == 0 {
        return Err(Error::invalid("num_threads", "must be >= 1"));
    }
    static POOLS: OnceLock<Mutex<HashMap<usize, Arc<ThreadPool>>>> = OnceLock::new();
    let pool = {
        let mut pools = POOLS
            .get_or_init(Default::default)
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        match pools.get(&n) {
            Some(p) => p.clone(),
            None => {
                let p = Arc::new(
                    rayon::ThreadPoolBuilder::new()
                        .num_threads(n)
                        .build()
                        .map_err(|e| Error::invalid("num_threads", e.to_string()))?,
                );
                pools.insert(n, p.clone());
                p
            }
        }
    };
    Ok(pool.install(f))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_is_refused_and_a_second_size_names_the_first() {
        assert!(set_num_threads(0).is_err());
        // The test binary's global pool: whatever size it has, asking for it again succeeds
        // and asking for another one fails with a message naming both.
        let n = num_threads();
        assert!(set_num_threads(n).is_ok());
        let err = set_num_threads(n + 1).unwrap_err().to_string();
        assert!(err.contains(&format!("already runs {n} threads")), "{err}");
    }
}
