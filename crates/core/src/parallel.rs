//! How many threads a stage may use, passed as a value (never read from environment variables
//! or a global pool).

use std::num::NonZeroUsize;

/// The number of threads a solver or stage may use.
///
/// Results must not depend on it beyond the certified tolerance: a parallel reduction may
/// sum in another order, nothing else changes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Parallelism {
    threads: NonZeroUsize,
}

impl Parallelism {
    /// One thread: the calling one.
    pub const SEQUENTIAL: Self = Self {
        threads: NonZeroUsize::MIN,
    };

    /// `threads` threads; `0` means every core the machine reports.
    pub fn threads(threads: usize) -> Self {
        let threads = NonZeroUsize::new(threads)
            .unwrap_or_else(|| std::thread::available_parallelism().unwrap_or(NonZeroUsize::MIN));
        Self { threads }
    }

    /// Every core the machine reports.
    pub fn available() -> Self {
        Self::threads(0)
    }

    /// The number of threads.
    pub fn get(self) -> usize {
        self.threads.get()
    }

    /// True for one thread.
    pub fn is_sequential(self) -> bool {
        self.threads.get() == 1
    }
}

impl Default for Parallelism {
    fn default() -> Self {
        Self::SEQUENTIAL
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_threads_means_all_cores_and_one_is_sequential() {
        assert!(Parallelism::SEQUENTIAL.is_sequential());
        assert_eq!(Parallelism::threads(3).get(), 3);
        assert!(Parallelism::threads(0).get() >= 1);
        assert_eq!(Parallelism::default(), Parallelism::SEQUENTIAL);
    }
}
