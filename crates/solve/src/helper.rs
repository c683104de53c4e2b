//! A second thread that runs one half of a fork–join and spins between jobs: a handoff in
//! well under a microsecond where a thread pool's sleeping workers take tens (measured on
//! this project's 2-core VM: a pool's join around two 49 µs halves cost 38 µs, this one
//! under 1 µs; benches/README.md, session 16). It parks after `SPIN` without a job. In a
//! process forked from the one that started it (which has no such thread) both halves run on
//! the caller.

use std::panic::{AssertUnwindSafe, catch_unwind, resume_unwind};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How long the helper spins after a job before it parks.
const SPIN: Duration = Duration::from_millis(1);

/// A job the helper runs: a borrowed closure whose lifetime [`Helper::join`] guarantees.
type Job = &'static (dyn Fn() + Sync);

#[derive(Default)]
struct Shared {
    posted: AtomicU64,
    finished: AtomicU64,
    job: Mutex<Option<Job>>,
    panic: Mutex<Option<Box<dyn std::any::Any + Send>>>,
    parked: AtomicBool,
    stop: AtomicBool,
}

/// The helper thread (joined when dropped).
pub(crate) struct Helper {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
    // The process that started the thread: a child forked from it has no helper thread, and
    // there both halves run on the caller.
    process: u32,
}

impl std::fmt::Debug for Helper {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Helper")
    }
}

impl Helper {
    /// Starts the thread; `None` when the system refuses one (the caller then runs both halves
    /// itself).
    pub(crate) fn start() -> Option<Self> {
        let shared = Arc::new(Shared::default());
        let theirs = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("moreau-helper".into())
            .spawn(move || serve(&theirs))
            .ok()?;
        Some(Self {
            shared,
            thread: Some(thread),
            process: std::process::id(),
        })
    }

    /// Runs `b` on the helper while `a` runs here; returns `a`'s result once both are done. A
    /// panic in either is resumed here, after both have stopped. One caller at a time (its
    /// owner, the normal equations, calls it through `&mut self` paths): a second `join` while
    /// one runs would be counted as the same job.
    pub(crate) fn join<R>(&self, a: impl FnOnce() -> R, b: &(dyn Fn() + Sync)) -> R {
        if std::process::id() != self.process {
            let r = a();
            b();
            return r;
        }
        let thread = self
            .thread
            .as_ref()
            .expect("running until dropped")
            .thread();
        // SAFETY: the helper calls the job only between `posted` and `finished` of this
        // epoch, and this function neither returns nor unwinds before it has seen `finished`
        // reach the epoch (`Wait` below waits in its drop, so also when `a` panics): the
        // borrow outlives every use. The job is `Sync`, so calling it from the helper is sound.
        #[allow(unsafe_code)]
        let job: Job =
            unsafe { std::mem::transmute::<&(dyn Fn() + Sync), &'static (dyn Fn() + Sync)>(b) };
        *self.shared.job.lock().unwrap_or_else(|e| e.into_inner()) = Some(job);
        let epoch = self.shared.posted.fetch_add(1, Ordering::SeqCst) + 1;
        if self.shared.parked.load(Ordering::SeqCst) {
            thread.unpark();
        }
        struct Wait<'a>(&'a Shared, u64);
        impl Drop for Wait<'_> {
            fn drop(&mut self) {
                while self.0.finished.load(Ordering::Acquire) < self.1 {
                    std::hint::spin_loop();
                }
                // `a` panicked: its panic goes on; the helper's, if any, goes with this job
                // (not to the next one's caller).
                if std::thread::panicking() {
                    drop(
                        self.0
                            .panic
                            .lock()
                            .unwrap_or_else(|e| e.into_inner())
                            .take(),
                    );
                }
            }
        }
        let wait = Wait(&self.shared, epoch);
        let r = a();
        drop(wait);
        if let Some(p) = self
            .shared
            .panic
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take()
        {
            resume_unwind(p);
        }
        r
    }
}

impl Drop for Helper {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        if std::process::id() != self.process {
            // A forked child: the thread is its parent's; nothing to join here.
            std::mem::forget(self.thread.take());
            return;
        }
        if let Some(t) = self.thread.take() {
            t.thread().unpark();
            let _ = t.join();
        }
    }
}

/// The helper's loop: wait (spinning, then parked) for the next epoch, run its job, publish
/// `finished`.
fn serve(shared: &Shared) {
    let mut seen = 0;
    loop {
        let mut since = None;
        let mut spins = 0u32;
        loop {
            let posted = shared.posted.load(Ordering::SeqCst);
            if posted != seen {
                seen = posted;
                break;
            }
            if shared.stop.load(Ordering::SeqCst) {
                return;
            }
            spins = spins.wrapping_add(1);
            if !spins.is_multiple_of(256) {
                std::hint::spin_loop();
                continue;
            }
            let start = *since.get_or_insert_with(Instant::now);
            if start.elapsed() < SPIN {
                continue;
            }
            // No lost wake-up: `join` posts, then reads `parked`; here `parked` is set, then
            // `posted` read again (both sequentially consistent).
            shared.parked.store(true, Ordering::SeqCst);
            if shared.posted.load(Ordering::SeqCst) == seen && !shared.stop.load(Ordering::SeqCst) {
                std::thread::park();
            }
            shared.parked.store(false, Ordering::SeqCst);
            since = None;
        }
        let job = shared.job.lock().unwrap_or_else(|e| e.into_inner()).take();
        if let Some(job) = job
            && let Err(p) = catch_unwind(AssertUnwindSafe(job))
        {
            *shared.panic.lock().unwrap_or_else(|e| e.into_inner()) = Some(p);
        }
        shared.finished.store(seen, Ordering::Release);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicUsize;

    #[test]
    fn both_halves_run_every_time_also_after_the_helper_parked() {
        let helper = Helper::start().expect("a thread");
        let count = AtomicUsize::new(0);
        for round in 0..200 {
            if round % 50 == 49 {
                // Long enough for the helper to park.
                std::thread::sleep(SPIN * 3);
            }
            let mut mine = 0;
            let r = helper.join(
                || {
                    mine += 1;
                    round
                },
                &|| {
                    count.fetch_add(1, Ordering::SeqCst);
                },
            );
            assert_eq!((r, mine), (round, 1));
            assert_eq!(count.load(Ordering::SeqCst), round + 1);
        }
    }

    #[test]
    fn a_panic_on_the_helper_reaches_the_caller_and_the_helper_serves_on() {
        let helper = Helper::start().expect("a thread");
        let caught = catch_unwind(AssertUnwindSafe(|| {
            helper.join(|| (), &|| panic!("in the helper"));
        }));
        assert!(caught.is_err());
        let ran = AtomicBool::new(false);
        helper.join(|| (), &|| ran.store(true, Ordering::SeqCst));
        assert!(ran.load(Ordering::SeqCst));
        // Both halves panic: the caller's panic is the one raised, and the next join is clean.
        let caught = catch_unwind(AssertUnwindSafe(|| {
            helper.join(|| panic!("here"), &|| panic!("in the helper"));
        }));
        let message = caught.expect_err("a panic");
        assert_eq!(message.downcast_ref::<&str>(), Some(&"here"));
        let fine = catch_unwind(AssertUnwindSafe(|| helper.join(|| 7, &|| ())));
        assert_eq!(fine.ok(), Some(7));
    }
}
