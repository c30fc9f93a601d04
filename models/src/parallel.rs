//! How many worker threads the math may use. The binary sets it once from
//! `FDMLAB_THREADS`; unset, every available core. Results never depend on it:
//! work is split into fixed items whose results are gathered in input order.

use std::sync::atomic::{AtomicUsize, Ordering};

/// 0 = not set (use every available core).
static THREADS: AtomicUsize = AtomicUsize::new(0);

/// Limit worker threads to `n` (≥ 1; 0 restores the default).
pub fn set_threads(n: usize) {
    THREADS.store(n, Ordering::Relaxed);
}

/// Worker threads to use: the value set by [`set_threads`], else the available cores.
pub fn threads() -> usize {
    match THREADS.load(Ordering::Relaxed) {
        0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
        n => n,
    }
}
