//! Deterministic data parallelism for the solvers: fixed chunks, partial sums added in chunk
//! order, so that no result depends on the number of threads. In a process forked after the
//! pool started (whose threads stay in the parent) everything runs on the caller.

use moreau_core::Parallelism;
use rayon::prelude::*;

use crate::error::SolveError;

/// Items per chunk. Fixed, not derived from the thread count: sums are formed per chunk and
/// then added in chunk order, the same way on one thread or many.
const CHUNK: usize = 4096;

/// A thread pool of the requested size, or the calling thread alone.
pub(crate) struct Workers {
    pool: Option<rayon::ThreadPool>,
    // The process that built the pool: a child forked from it has none of the pool's
    // threads (a job sent there would wait forever), and runs everything on the caller.
    process: u32,
}

impl std::fmt::Debug for Workers {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.pool() {
            None => f.write_str("Workers(1)"),
            Some(p) => write!(f, "Workers({})", p.current_num_threads()),
        }
    }
}

impl Workers {
    /// Workers for `parallelism`.
    pub(crate) fn new(parallelism: Parallelism) -> Result<Self, SolveError> {
        let process = std::process::id();
        if parallelism.is_sequential() {
            return Ok(Self {
                pool: None,
                process,
            });
        }
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(parallelism.get())
            .build()
            .map_err(|_| SolveError::InvalidSetting {
                field: "parallelism",
                value: parallelism.get().to_string(),
                reason: "the thread pool could not be built",
            })?;
        Ok(Self {
            pool: Some(pool),
            process,
        })
    }

    /// The pool, unless there is none or this is a process forked from the one that built
    /// it.
    fn pool(&self) -> Option<&rayon::ThreadPool> {
        self.pool
            .as_ref()
            .filter(|_| std::process::id() == self.process)
    }

    /// The pool for a loop over `n` items: none when they fit in one chunk, which would run
    /// on one thread anyway (sending it to the pool cost a round trip between threads for
    /// every loop of every iteration: the paper's room on two threads took 5–30× the time of
    /// one), the same chunks and bits either way.
    fn pool_for(&self, n: usize) -> Option<&rayon::ThreadPool> {
        self.pool().filter(|_| n > CHUNK)
    }

    /// Whether the loops (and what runs in [`Self::install`]) run on the caller alone: no
    /// pool, or a forked child of the process that built it (where faer must not be asked to
    /// split either: rayon's global pool may be the parent's too).
    pub(crate) fn is_sequential(&self) -> bool {
        self.pool().is_none()
    }

    /// Runs `op` on the workers (faer's `Par::rayon` then splits over them, not over rayon's
    /// global pool).
    pub(crate) fn install<R: Send>(&self, op: impl FnOnce() -> R + Send) -> R {
        match self.pool() {
            None => op(),
            Some(pool) => pool.install(op),
        }
    }

    /// `out[i] = f(i, out[i])` for every `i`.
    pub(crate) fn map(&self, out: &mut [f64], f: impl Fn(usize, f64) -> f64 + Sync) {
        let body = |(c, chunk): (usize, &mut [f64])| {
            for (k, x) in chunk.iter_mut().enumerate() {
                *x = f(c * CHUNK + k, *x);
            }
        };
        match self.pool_for(out.len()) {
            None => out.chunks_mut(CHUNK).enumerate().for_each(body),
            Some(pool) => pool.install(|| out.par_chunks_mut(CHUNK).enumerate().for_each(body)),
        }
    }

    /// `Σ_{i < n} f(i)`, summed per chunk and then over chunks in order.
    pub(crate) fn sum(&self, n: usize, f: impl Fn(usize) -> f64 + Sync) -> f64 {
        let chunk = |c: usize| (c * CHUNK..((c + 1) * CHUNK).min(n)).map(&f).sum::<f64>();
        let chunks = n.div_ceil(CHUNK);
        match self.pool_for(n) {
            None => (0..chunks).map(chunk).sum(),
            Some(pool) => pool
                .install(|| (0..chunks).into_par_iter().map(chunk).collect::<Vec<f64>>())
                .into_iter()
                .sum(),
        }
    }

    /// `min_{i < n} f(i)` of each of the two components of `f`, in one pass.
    pub(crate) fn min_pair(&self, n: usize, f: impl Fn(usize) -> (f64, f64) + Sync) -> (f64, f64) {
        let both = |a: (f64, f64), b: (f64, f64)| (a.0.min(b.0), a.1.min(b.1));
        let none = (f64::INFINITY, f64::INFINITY);
        match self.pool_for(n) {
            None => (0..n).map(f).fold(none, both),
            Some(pool) => pool.install(|| {
                (0..n)
                    .into_par_iter()
                    .with_min_len(CHUNK)
                    .map(&f)
                    .reduce(|| none, both)
            }),
        }
    }

    /// `min_{i < n} f(i)` (order does not matter for a minimum).
    pub(crate) fn min(&self, n: usize, f: impl Fn(usize) -> f64 + Sync) -> f64 {
        match self.pool_for(n) {
            None => (0..n).map(f).fold(f64::INFINITY, f64::min),
            Some(pool) => pool.install(|| {
                (0..n)
                    .into_par_iter()
                    .with_min_len(CHUNK)
                    .map(&f)
                    .reduce(|| f64::INFINITY, f64::min)
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sums_do_not_depend_on_the_thread_count() {
        let n = 10 * CHUNK + 17;
        let f = |i: usize| ((i * 7919) % 1000) as f64 * 1e-3 + 1e-17 * i as f64;
        let one = Workers::new(Parallelism::SEQUENTIAL).unwrap();
        let two = Workers::new(Parallelism::threads(2)).unwrap();
        assert_eq!(one.sum(n, f).to_bits(), two.sum(n, f).to_bits());
        assert_eq!(one.min(n, f), two.min(n, f));
        let g = |i: usize| (f(i), f(n - 1 - i) - 1.0);
        assert_eq!(one.min_pair(n, g), two.min_pair(n, g));
        assert_eq!(one.min_pair(n, g), (one.min(n, f), one.min(n, f) - 1.0));
        let (mut a, mut b) = (vec![1.0; n], vec![1.0; n]);
        one.map(&mut a, |i, x| x + f(i));
        two.map(&mut b, |i, x| x + f(i));
        assert_eq!(a, b);
    }

    /// Regression: every loop went to the pool, a round trip between threads even for one
    /// chunk (the paper's room on two threads: 5–30× the time of one thread, 150,000 context
    /// switches in 3 s). A loop of one chunk runs on the caller; of two, on the pool.
    #[test]
    fn a_loop_of_one_chunk_went_to_the_pool() {
        let two = Workers::new(Parallelism::threads(2)).unwrap();
        let caller = |_: usize| f64::from(u8::from(rayon::current_thread_index().is_none()));
        for (n, on_caller) in [(1, true), (CHUNK, true), (CHUNK + 1, false)] {
            let expected = if on_caller { n as f64 } else { 0.0 };
            assert_eq!(two.sum(n, caller), expected, "sum of {n}");
            let mut x = vec![0.0; n];
            two.map(&mut x, |i, _| caller(i));
            assert_eq!(x.iter().sum::<f64>(), expected, "map of {n}");
            let once = f64::from(u8::from(on_caller));
            assert_eq!(two.min(n, caller), once, "min of {n}");
            assert_eq!(
                two.min_pair(n, |i| (caller(i), 0.0)).0,
                once,
                "min_pair of {n}"
            );
        }
    }
}
