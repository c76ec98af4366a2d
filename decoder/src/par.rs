//! The decode's parallel loops: rayon's, or plain loops on the calling thread inside
//! [`one_thread`]. A one-thread decode (`Decoder::set_threads(1)`) used to run on a pool of one
//! worker; handing the decode to that worker and waking the caller again took a fifth of a small
//! file's decode time (k7000 at λ 24, docs/decoder.md). Inside [`one_thread`] nothing is handed
//! to another thread.

use std::cell::Cell;

use rayon::prelude::*;

thread_local! {
    static ONE_THREAD: Cell<bool> = const { Cell::new(false) };
}

/// Runs `f` on this thread with every loop of this module inside it sequential.
pub(crate) fn one_thread<T>(f: impl FnOnce() -> T) -> T {
    /// Restores the flag as it was, also when `f` panics.
    struct Restore(bool);
    impl Drop for Restore {
        fn drop(&mut self) {
            ONE_THREAD.with(|c| c.set(self.0));
        }
    }
    let _restore = Restore(ONE_THREAD.with(|c| c.replace(true)));
    f()
}

/// Whether this thread is inside [`one_thread`], or the target has no threads to hand work to
/// (WebAssembly without atomics, where rayon would run every job here through its queues).
pub(crate) fn sequential() -> bool {
    cfg!(all(target_arch = "wasm32", not(target_feature = "atomics"))) || ONE_THREAD.with(Cell::get)
}

/// `rayon::join`, or `a` then `b` inside [`one_thread`].
pub(crate) fn join<A, B, RA, RB>(a: A, b: B) -> (RA, RB)
where
    A: FnOnce() -> RA + Send,
    B: FnOnce() -> RB + Send,
    RA: Send,
    RB: Send,
{
    if sequential() {
        (a(), b())
    } else {
        rayon::join(a, b)
    }
}

/// `f` of every item, in order, or an error of one of them (inside [`one_thread`]: the first).
pub(crate) fn try_map<T: Send, U: Send, E: Send>(items: Vec<T>, f: impl Fn(T) -> Result<U, E> + Sync + Send) -> Result<Vec<U>, E> {
    if sequential() {
        items.into_iter().map(f).collect()
    } else {
        items.into_par_iter().map(f).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::thread::{self, ThreadId};

    /// Inside `one_thread` every job runs on the calling thread, in order, and the flag is
    /// restored afterwards (also after a panic); outside it the jobs go to rayon's pool.
    #[test]
    fn one_thread_runs_every_job_on_the_calling_thread() {
        let me = thread::current().id();
        let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
        let ids = |items: Vec<usize>| -> (Vec<(usize, ThreadId)>, (ThreadId, ThreadId)) {
            let mapped = try_map(items, |i| Ok::<_, ()>((i, thread::current().id()))).unwrap();
            (mapped, join(|| thread::current().id(), || thread::current().id()))
        };
        let (mapped, joined) = one_thread(|| ids((0..64).collect()));
        assert_eq!(mapped, (0..64).map(|i| (i, me)).collect::<Vec<_>>());
        assert_eq!(joined, (me, me));
        assert!(!sequential(), "restored");
        // On a pool the jobs run on its workers, never on this thread.
        let (mapped, _) = pool.install(|| ids((0..64).collect()));
        assert!(mapped.iter().all(|&(_, id)| id != me));
        assert_eq!(mapped.iter().map(|m| m.0).collect::<Vec<_>>(), (0..64).collect::<Vec<_>>(), "in order");
        // A panic inside leaves the flag as it was.
        assert!(std::panic::catch_unwind(|| one_thread(|| panic!("inside"))).is_err());
        assert!(!sequential());
        // The first error in order inside `one_thread`.
        let first = one_thread(|| try_map((0..10).collect(), |i| if i >= 3 { Err(i) } else { Ok(i) }));
        assert_eq!(first, Err(3));
    }
}
