//! A second thread for fork–joins, shared by everything that forks in two: one half of a
//! join runs on it while the caller runs the other, and it spins between jobs, so a handoff
//! takes well under a microsecond where a thread pool's sleeping workers take tens (measured
//! on this project's 2-core VM: a pool's join around two 49 µs halves cost 38 µs, this one
//! under 1 µs; benches/README.md, session 16). It parks after `SPIN` without a job; a job it
//! has not started by the time the caller's half ends (it is waking, or its core is busy) is
//! taken back and run by the caller, so a late helper costs no more than one thread. One job
//! at a time holds it: a join while it is held (from another thread, or nested in a join's
//! half while the other half runs) runs both halves on its caller, as does every join in a
//! process forked from the one that started it (which has no such thread). Whichever way a
//! join runs, both halves run, so results cannot depend on it.

use std::panic::{AssertUnwindSafe, catch_unwind, resume_unwind};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, Weak};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How long the helper spins after a job before it parks.
const SPIN: Duration = Duration::from_millis(1);

/// A job the helper runs: a borrowed closure whose lifetime [`Helper::join`] guarantees.
type Job = &'static (dyn Fn() + Sync);

/// A job's panic, for the join that posted it.
type Panic = Box<dyn std::any::Any + Send>;

#[derive(Default)]
struct Shared {
    // The epoch of the last job posted (what wakes the helper) and of the last one it ran.
    posted: AtomicU64,
    finished: AtomicU64,
    // The job posted and not yet taken, with its epoch (a join takes back only its own).
    job: Mutex<Option<(u64, Job)>>,
    panics: Mutex<Vec<(u64, Panic)>>,
    parked: AtomicBool,
    stop: AtomicBool,
    // A job is posted and neither finished nor taken back (see `Helper::join`): only its
    // poster posts until it is let go, so epochs are posted, taken and finished in order.
    held: AtomicBool,
}

/// A helper thread (joined when dropped).
pub struct Helper {
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

/// The helper in use, if any (see [`Helper::shared`]).
static SHARED: Mutex<Weak<Helper>> = Mutex::new(Weak::new());

impl Helper {
    /// The helper the stages and solvers that fork in two share: the one in use if there is
    /// one, else a new one (its thread is joined when the last user drops it, so a library
    /// that is unloaded after its last simulation leaves no thread behind). `None` when the
    /// system refuses a thread (callers then run both halves themselves). One thread for all:
    /// two helpers would spin against each other on two cores.
    pub fn shared() -> Option<Arc<Helper>> {
        let mut shared = SHARED.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(helper) = shared.upgrade() {
            return Some(helper);
        }
        let helper = Arc::new(Helper::start()?);
        *shared = Arc::downgrade(&helper);
        Some(helper)
    }

    /// A helper of its own (tests; callers share [`Helper::shared`]); `None` when the system
    /// refuses a thread.
    pub fn start() -> Option<Self> {
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

    /// [`join`](Self::join) for a second half called once, with its result: `a` here and `b`
    /// on the helper (or both here, as `join` decides); both results.
    pub fn join_once<A, B: Send>(
        &self,
        a: impl FnOnce() -> A,
        b: impl FnOnce() -> B + Send,
    ) -> (A, B) {
        let b = Mutex::new((Some(b), None));
        let a = self.join(a, &|| {
            let mut b = b.lock().unwrap_or_else(|e| e.into_inner());
            if let Some(f) = b.0.take() {
                b.1 = Some(f());
            }
        });
        let (_, b) = b.into_inner().unwrap_or_else(|e| e.into_inner());
        (a, b.expect("a join runs both halves"))
    }

    /// Whether a job holds the helper now (a join would run both halves on its caller).
    pub fn is_held(&self) -> bool {
        self.shared.held.load(Ordering::Acquire)
    }

    /// Runs `b` on the helper while `a` runs here; returns `a`'s result once both are done. A
    /// panic in either is resumed here, after both have stopped. The helper is held from the
    /// post of `b` until `b` is done (so a join nested in `a` finds it free again once `b` is):
    /// a join while it is held (another thread's, or one nested in `b`, or in `a` while `b`
    /// runs) or in a process forked from the one that started it runs `a` then `b` here.
    pub fn join<R>(&self, a: impl FnOnce() -> R, b: &(dyn Fn() + Sync)) -> R {
        if std::process::id() != self.process || self.shared.held.swap(true, Ordering::Acquire) {
            let r = a();
            b();
            return r;
        }
        let thread = self
            .thread
            .as_ref()
            .expect("running until dropped")
            .thread();
        // SAFETY: the helper calls the job only if it takes it from the slot, and this
        // function neither returns nor unwinds before it has either taken the job back itself
        // (then the helper never sees it) or seen `finished` reach its epoch (`Wait` below, in
        // its drop, so also when `a` panics), which the helper stores after the call: the
        // borrow outlives every use. The job is `Sync`, so calling it from the helper is sound.
        #[allow(unsafe_code)]
        let job: Job =
            unsafe { std::mem::transmute::<&(dyn Fn() + Sync), &'static (dyn Fn() + Sync)>(b) };
        // (Held: no other join posts until this job is done or taken back.)
        let epoch = self.shared.posted.load(Ordering::SeqCst) + 1;
        *self.shared.job.lock().unwrap_or_else(|e| e.into_inner()) = Some((epoch, job));
        self.shared.posted.store(epoch, Ordering::SeqCst);
        if self.shared.parked.load(Ordering::SeqCst) {
            thread.unpark();
        }
        struct Wait<'a> {
            shared: &'a Shared,
            epoch: u64,
            armed: bool,
        }
        impl Wait<'_> {
            /// This join's job, if the helper has not taken it (asleep, or its core busy); the
            /// helper is then free again.
            fn take_back(&mut self) -> Option<Job> {
                let mut slot = self.shared.job.lock().unwrap_or_else(|e| e.into_inner());
                let (_, job) = slot.take_if(|(epoch, _)| *epoch == self.epoch)?;
                self.armed = false;
                self.shared.held.store(false, Ordering::Release);
                Some(job)
            }

            /// The panic of this join's job on the helper, if it panicked.
            fn panic(&self) -> Option<Panic> {
                let mut panics = self.shared.panics.lock().unwrap_or_else(|e| e.into_inner());
                let at = panics.iter().position(|(epoch, _)| *epoch == self.epoch)?;
                Some(panics.swap_remove(at).1)
            }
        }
        impl Wait<'_> {
            /// Until the helper has run this join's job (unless taken back); then disarmed.
            fn wait_done(&mut self) {
                if !self.armed || self.take_back().is_some() {
                    return;
                }
                while self.shared.finished.load(Ordering::Acquire) < self.epoch {
                    std::hint::spin_loop();
                }
                self.armed = false;
            }
        }
        impl Drop for Wait<'_> {
            fn drop(&mut self) {
                if !self.armed {
                    return;
                }
                self.wait_done();
                // `a` panicked: its panic goes on; the helper's, if any, goes with this job.
                if std::thread::panicking() {
                    drop(self.panic());
                }
            }
        }
        let mut wait = Wait {
            shared: &self.shared,
            epoch,
            armed: true,
        };
        let r = a();
        // Not started by the helper while `a` ran: it runs here (a helper woken late costs
        // no more than running both halves here).
        if let Some(job) = wait.take_back() {
            job();
            return r;
        }
        wait.wait_done();
        if let Some(p) = wait.panic() {
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
        // (Empty when its poster took the job back.)
        let job = shared.job.lock().unwrap_or_else(|e| e.into_inner()).take();
        if let Some((epoch, job)) = job {
            if let Err(p) = catch_unwind(AssertUnwindSafe(job)) {
                let mut panics = shared.panics.lock().unwrap_or_else(|e| e.into_inner());
                panics.push((epoch, p));
            }
            shared.held.store(false, Ordering::Release);
            shared.finished.store(epoch, Ordering::Release);
        }
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
    fn the_shared_helper_is_one_while_in_use_and_gone_after() {
        let (a, b) = (
            Helper::shared().expect("a thread"),
            Helper::shared().expect("a thread"),
        );
        assert!(Arc::ptr_eq(&a, &b), "one helper for all its users");
        let ran = AtomicUsize::new(0);
        a.join(|| (), &|| {
            ran.fetch_add(1, Ordering::SeqCst);
        });
        assert_eq!(ran.load(Ordering::SeqCst), 1);
        let weak = Arc::downgrade(&a);
        drop((a, b));
        // Dropped with its last user (and its thread joined): a library unloaded after its
        // last simulation leaves no thread running its code.
        assert!(weak.upgrade().is_none());
    }

    #[test]
    fn a_job_the_parked_helper_has_not_started_runs_once_on_the_caller() {
        let helper = Helper::start().expect("a thread");
        let here = std::thread::current().id();
        let (runs, on_caller) = (AtomicUsize::new(0), AtomicUsize::new(0));
        for _ in 0..50 {
            // Long enough for the helper to park: waking it takes far longer than `a`.
            std::thread::sleep(SPIN * 2);
            helper.join(|| (), &|| {
                runs.fetch_add(1, Ordering::SeqCst);
                if std::thread::current().id() == here {
                    on_caller.fetch_add(1, Ordering::SeqCst);
                }
            });
        }
        // Each job once, whoever ran it, and the helper serves on after jobs taken back.
        assert_eq!(runs.load(Ordering::SeqCst), 50);
        assert!(on_caller.load(Ordering::SeqCst) > 0, "no job taken back");
        // (Its first half waits for the second: nothing is taken back.)
        let (ran, done) = (Mutex::new(None), AtomicBool::new(false));
        helper.join(
            || {
                while !done.load(Ordering::SeqCst) {
                    std::hint::spin_loop();
                }
            },
            &|| {
                *ran.lock().unwrap() = Some(std::thread::current().id());
                done.store(true, Ordering::SeqCst);
            },
        );
        assert_ne!(
            *ran.lock().unwrap(),
            Some(here),
            "the helper takes a job it has time for"
        );
    }

    #[test]
    fn a_join_while_the_helper_is_held_runs_both_halves_on_its_caller() {
        let helper = Helper::start().expect("a thread");
        let here = std::thread::current().id();
        let ran = Mutex::new(Vec::new());
        let record = |what: &'static str| {
            ran.lock()
                .unwrap()
                .push((what, std::thread::current().id()))
        };
        // A join nested in each half while the helper runs its own: each runs on the thread
        // that called it.
        let (started, nested_done) = (AtomicBool::new(false), AtomicBool::new(false));
        helper.join(
            || {
                while !started.load(Ordering::SeqCst) {
                    std::hint::spin_loop();
                }
                helper.join(|| record("a.a"), &|| record("a.b"));
                nested_done.store(true, Ordering::SeqCst);
            },
            &|| {
                started.store(true, Ordering::SeqCst);
                helper.join(|| record("b.a"), &|| record("b.b"));
                while !nested_done.load(Ordering::SeqCst) {
                    std::hint::spin_loop();
                }
            },
        );
        let ran = ran.into_inner().unwrap();
        assert_eq!(ran.len(), 4, "{ran:?}");
        let on = |what| ran.iter().find(|r| r.0 == what).expect("ran").1;
        assert_eq!((on("a.a"), on("a.b")), (here, here));
        assert_eq!(on("b.a"), on("b.b"));
        assert_ne!(on("b.a"), here);
        // Its job done, the helper takes the second half of a join nested in the first (whose
        // own first half waits for it: nothing is taken back).
        let (done, nested) = (AtomicBool::new(false), Mutex::new(None));
        helper.join(
            || {
                while !done.load(Ordering::SeqCst) {
                    std::hint::spin_loop();
                }
                // (The helper lets go just after its job returns.)
                std::thread::sleep(Duration::from_millis(1));
                let ran = AtomicBool::new(false);
                helper.join(
                    || {
                        let start = Instant::now();
                        while !ran.load(Ordering::SeqCst) && start.elapsed().as_secs() < 10 {
                            std::hint::spin_loop();
                        }
                    },
                    &|| {
                        *nested.lock().unwrap() = Some(std::thread::current().id());
                        ran.store(true, Ordering::SeqCst);
                    },
                );
            },
            &|| done.store(true, Ordering::SeqCst),
        );
        assert_eq!(*nested.lock().unwrap(), Some(on("b.a")));
    }

    /// A regression: a join took back whatever job was in the slot when its own half ended,
    /// also another thread's posted after its own job had run; that job then ran on the wrong
    /// thread and its own join could return before it had finished.
    #[test]
    fn a_join_takes_back_only_its_own_job() {
        let helper = Helper::start().expect("a thread");
        let x = std::thread::current().id();
        let spin_until = |flag: &AtomicBool| {
            while !flag.load(Ordering::SeqCst) {
                std::hint::spin_loop();
            }
        };
        // (Whether X's join would reach the slot before the helper wakes is a race: rounds.)
        for _ in 0..40 {
            let (x_job_done, y_posted, x_returned) = (
                AtomicBool::new(false),
                AtomicBool::new(false),
                AtomicBool::new(false),
            );
            let (y_ran_on, y_job_runs) = (Mutex::new(None), AtomicUsize::new(0));
            std::thread::scope(|scope| {
                scope.spawn(|| {
                    spin_until(&x_job_done);
                    // Long enough for the helper to park: Y's job then waits for it to wake.
                    std::thread::sleep(SPIN * 3);
                    helper.join(
                        || {
                            y_posted.store(true, Ordering::SeqCst);
                            spin_until(&x_returned);
                        },
                        &|| {
                            *y_ran_on.lock().unwrap() = Some(std::thread::current().id());
                            std::thread::sleep(Duration::from_millis(2));
                            y_job_runs.fetch_add(1, Ordering::SeqCst);
                        },
                    );
                    assert_eq!(
                        y_job_runs.load(Ordering::SeqCst),
                        1,
                        "Y's job done when it returns"
                    );
                });
                helper.join(|| spin_until(&y_posted), &|| {
                    x_job_done.store(true, Ordering::SeqCst)
                });
                x_returned.store(true, Ordering::SeqCst);
            });
            assert_eq!(y_job_runs.load(Ordering::SeqCst), 1);
            assert_ne!(*y_ran_on.lock().unwrap(), Some(x), "X ran Y's job");
        }
    }

    #[test]
    fn join_once_returns_both_halves_results() {
        let helper = Helper::start().expect("a thread");
        let owned = String::from("123");
        for round in 0..100 {
            let (a, b) = helper.join_once(|| round * 2, || owned.len() as i32 * 2 + round);
            assert_eq!((a, b), (round * 2, 6 + round));
        }
    }

    #[test]
    fn joins_from_many_threads_at_once_each_run_both_halves() {
        let helper = Helper::start().expect("a thread");
        let count = AtomicUsize::new(0);
        std::thread::scope(|scope| {
            for _ in 0..4 {
                scope.spawn(|| {
                    for round in 0..500 {
                        let r = helper.join(
                            || {
                                count.fetch_add(1, Ordering::SeqCst);
                                round
                            },
                            &|| {
                                count.fetch_add(1, Ordering::SeqCst);
                            },
                        );
                        assert_eq!(r, round);
                    }
                });
            }
        });
        assert_eq!(count.load(Ordering::SeqCst), 4 * 500 * 2);
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
