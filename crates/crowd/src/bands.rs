//! The crowd's loops over people in bands on threads: how many bands, and running them (the
//! second band on the helper thread the solver shares, the others on threads of their own).

use std::sync::Arc;

use moreau_core::{Helper, Parallelism};

/// With threads, the crowd's loops over people (desired velocities, the grid's cells, the
/// contact rows) run in bands, one a thread, from this many people (or disks, or pairs) on
/// (measured on whole evacuations, benches/README.md, session 17: 10,000 beats 20,000 at
/// 10,000 people); from [`HELPER_FROM`] on in two, the second on the helper thread.
pub(crate) const PARALLEL_FROM: usize = 10_000;

/// From this many items on, a loop runs in two bands with threads, the second on the
/// shared helper thread ([`moreau_core::Helper`]): a handoff costs under a microsecond
/// there, where starting a thread costs tens (measured on cromosim's scene, benches/README.md,
/// session 18).
pub(crate) const HELPER_FROM: usize = 1_000;

/// The bands a loop over `count` items runs in on `threads` threads (see [`PARALLEL_FROM`]).
pub(crate) fn count(threads: usize, count: usize) -> usize {
    if threads < 2 || count < HELPER_FROM {
        1
    } else if count < PARALLEL_FROM {
        2
    } else {
        threads.min(count)
    }
}

/// The helper thread for loops on `parallelism` (with threads; see [`run`]).
pub(crate) fn helper_for(parallelism: Parallelism) -> Option<Arc<Helper>> {
    (!parallelism.is_sequential())
        .then(Helper::shared)
        .flatten()
}

/// Runs `first` on the caller and each of `others` on a thread, all to the end: the first
/// of `others` on `helper` (a handoff under a microsecond; without one, a thread of its own),
/// the rest on threads of their own.
pub(crate) fn run<F: FnOnce() + Send>(
    helper: Option<&Helper>,
    first: impl FnOnce(),
    others: impl IntoIterator<Item = F>,
) {
    let mut others = others.into_iter();
    let Some(second) = others.next() else {
        first();
        return;
    };
    std::thread::scope(|scope| {
        for band in others {
            scope.spawn(band);
        }
        match helper {
            Some(helper) => {
                helper.join_once(first, second);
            }
            None => {
                scope.spawn(second);
                first();
            }
        }
    });
}
