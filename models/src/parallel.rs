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

/// Map `f` over `items` on [`threads`] threads, results in input order. Items
/// are handed out one at a time (uneven items keep every thread busy).
pub fn par_map<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let n = threads().min(items.len().max(1));
    if n <= 1 {
        return items.iter().map(&f).collect();
    }
    let next = AtomicUsize::new(0);
    let mut done: Vec<(usize, R)> = std::thread::scope(|scope| {
        let worker = || {
            let mut mine = vec![];
            loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(item) = items.get(i) else { return mine };
                mine.push((i, f(item)));
            }
        };
        let handles: Vec<_> = (0..n).map(|_| scope.spawn(worker)).collect();
        // A worker only panics if `f` does; re-raise it here rather than hide it.
        handles.into_iter().flat_map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e))).collect()
    });
    done.sort_unstable_by_key(|d| d.0);
    done.into_iter().map(|d| d.1).collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn par_map_keeps_order() {
        let v: Vec<usize> = (0..37).collect();
        assert_eq!(super::par_map(&v, |x| x * 2), v.iter().map(|x| x * 2).collect::<Vec<_>>());
    }
}
