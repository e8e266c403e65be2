//! A function that makes several parallel passes, run as one job on
//! rayon's pool.
//!
//! Why: a parallel iterator started on a thread outside rayon's pool (a
//! library user's thread, a benchmark's) hands its work to the pool and
//! waits for it. The pool's threads go to sleep soon after their last job,
//! and waking one took 35–48 µs per call on this virtual machine (a local
//! probe: a parallel sum of 4,096 numbers in four chunks, called after
//! each 0.5 ms of other work, against 0.2 µs a call from a pool thread,
//! one pool thread, benches/ROUNDS.md, Thirty-third round). The weld
//! makes nine such calls and the topology six, so from outside the pool
//! each of them waited for a wake-up in every pass, and its data moved
//! between the caller's core and the pool's. Run as one job, a function's
//! passes start on the pool thread that runs it, and only the job itself
//! waits for a wake-up. Called from a pool thread, the function runs
//! there, as before (the command line's builds run on their batch's pool).
//!
//! On the dragon, one thread, from outside the pool (thirty-third round,
//! binaries alternated three times):
//! - weld + topology + bucket counts, memory recycled: 24.43–25.34 →
//!   24.01–24.16 ms at the fastest, 26.27–30.26 → 24.49–24.71 ms at the
//!   median (`RECYCLE=1 cargo run --release --example stage_probe --
//!   buckets target/dragon/dragon.glb`);
//! - one light's evaluation (`verify::evaluate_into`): 2.72–2.83 →
//!   2.42–2.65 ms at the fastest, 3.07–3.24 → 2.65–2.99 ms at the median
//!   (`cargo run --release --example stage_probe -- evaluate
//!   target/dragon/dragon.glb`, its `auto` row). The evaluate bench
//!   already ran its loops inside the pool, so its figures do not change.

/// Runs `f` on a thread of rayon's pool (the current one's, or the global
/// pool from any other thread) and returns its result; the caller waits.
/// Panics in `f` reach the caller.
pub(crate) fn one_job<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    // `scope` runs its body on the current pool thread, or from outside a
    // pool, injects it into the global pool as one job.
    rayon::scope(|_| f())
}

#[cfg(test)]
mod tests {
    use super::one_job;

    #[test]
    fn runs_on_a_pool_thread_from_outside_the_pool() {
        // The test harness's threads are not rayon's.
        assert_eq!(rayon::current_thread_index(), None);
        assert!(one_job(rayon::current_thread_index).is_some());
    }

    #[test]
    fn stays_on_the_calling_pool_thread() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        let (outer, inner) = pool.install(|| {
            let outer = std::thread::current().id();
            (outer, one_job(|| std::thread::current().id()))
        });
        assert_eq!(outer, inner);
    }
}
