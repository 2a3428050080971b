//! Background threads: they take only the time the group's processes leave, until the run's
//! end or a busy machine needs them at normal priority again.
//!
//! The planner, the library saver, the recorder and the live servers run under `SCHED_IDLE`
//! so that they only take time the acting path does not want. On a busy machine such a
//! thread gets almost no CPU (a weight of 3 against 1024 for a normal thread): a shutdown
//! that waits for it (the final library save waits for a save in progress) could wait for
//! seconds past the launcher's grace, a recorder would fall so far behind that the
//! publishers it reads are gone, and a viewer's handshake would time out.
//! [`Background::restore`] moves every thread of a [`Background`] back to normal scheduling
//! by its thread id (`sched_setscheduler` on a tid). The owner calls it at shutdown; a
//! [`Watcher`] (a thread at normal priority) calls it once the threads' work, which marks its
//! progress with [`Background::beat`], has not moved for a limit: the machine has shown it
//! is busy, and the threads keep normal priority for the rest of the run.
//!
//! Linux lets a thread leave `SCHED_IDLE` only with `CAP_SYS_NICE` or an `RLIMIT_NICE` of 20:
//! [`can_restore`] finds out once, on a throwaway thread. Where it cannot be undone, a thread
//! whose work someone waits for ([`Background::lower_if_restorable`]) stays at normal
//! priority instead.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Duration;

/// The scheduling of a set of background threads, shared between the threads, their owner
/// and a [`Watcher`].
#[derive(Debug, Default)]
pub struct Background {
    state: Mutex<State>,
    /// Monotonic ns of the threads' last progress ([`beat`](Self::beat); 0: none yet).
    last_beat_ns: AtomicU64,
}

#[derive(Debug, Default)]
struct State {
    /// The ids of the threads that lowered their priority.
    lowered: Vec<libc::pid_t>,
    /// The owner restored the threads: none may lower itself now.
    restored: bool,
}

impl Background {
    /// Threads not yet lowered.
    pub fn new() -> Self {
        Self::default()
    }

    /// On a background thread: lowers its priority ([`crate::affinity::lower_this_threads_priority`])
    /// unless the owner already restored the set. Returns whether it runs under `SCHED_IDLE`.
    pub fn lower(&self) -> bool {
        let mut state = self.lock();
        if state.restored {
            return false;
        }
        let idle = crate::affinity::lower_this_threads_priority();
        state.lowered.push(this_tid());
        idle
    }

    /// [`lower`](Self::lower) where the lowering can be undone ([`can_restore`]); otherwise
    /// the thread keeps normal priority (said at debug level). For threads whose work a
    /// shutdown or a reader waits for.
    pub fn lower_if_restorable(&self) -> bool {
        if can_restore() {
            return self.lower();
        }
        tracing::debug!(
            "a background thread keeps normal priority: SCHED_IDLE could not be undone here \
             (no CAP_SYS_NICE, RLIMIT_NICE below 20)"
        );
        false
    }

    /// On the owner (or a [`Watcher`]): moves every lowered thread back to normal scheduling
    /// (`SCHED_OTHER`, nice 0), and keeps the set's threads from lowering themselves later.
    /// Returns whether they all now run at normal priority (false: one was lowered and could
    /// not be raised).
    pub fn restore(&self) -> bool {
        let mut state = self.lock();
        state.restored = true;
        state.lowered.retain(|&tid| !raise(tid));
        state.lowered.is_empty()
    }

    /// On a background thread: its work moved on (a [`Watcher`] raises the set when this is
    /// not said for its limit).
    pub fn beat(&self) {
        self.last_beat_ns
            .store(crate::clock::monotonic_ns(), Ordering::Relaxed);
    }

    /// How long since the last [`beat`](Self::beat) (or since `since_ns`, before the first).
    pub fn lag(&self, since_ns: u64) -> Duration {
        let last = self.last_beat_ns.load(Ordering::Relaxed).max(since_ns);
        Duration::from_nanos(crate::clock::monotonic_ns().saturating_sub(last))
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        // The state is two plain fields: a panic elsewhere cannot leave it inconsistent.
        self.state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

/// How long a set's work may go without a beat before a [`Watcher`] raises it: five times
/// the 20 ms the recorder and the ROS 2 side go at most between drains (and the live server
/// between beats), far more than an idle machine ever delays a `SCHED_IDLE` thread.
pub const LAG_LIMIT: Duration = Duration::from_millis(100);

/// How often a [`Watcher`] looks at its threads' last beat.
const WATCH_EVERY: Duration = Duration::from_millis(10);

/// A thread at normal priority that raises a [`Background`] set back to normal scheduling
/// ([`Background::restore`]) once its last [`beat`](Background::beat) is `limit` old, and ends
/// then, or when stopped (dropped).
#[derive(Debug)]
pub struct Watcher {
    stop: Arc<AtomicBool>,
    handle: Option<std::thread::JoinHandle<()>>,
}

impl Watcher {
    /// Starts watching `threads` (`who` names them in the log); the limit counts from now
    /// until their first beat.
    pub fn start(threads: Arc<Background>, limit: Duration, who: &str) -> std::io::Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let (flag, who) = (stop.clone(), who.to_owned());
        let handle = std::thread::Builder::new()
            .name("background-watch".into())
            .spawn(move || {
                let since_ns = crate::clock::monotonic_ns();
                while !flag.load(Ordering::SeqCst) {
                    std::thread::sleep(WATCH_EVERY);
                    if threads.lag(since_ns) >= limit {
                        let raised = threads.restore();
                        tracing::debug!(
                            raised,
                            "{who} made no progress for {limit:?} (a busy machine): normal \
                             priority from now on"
                        );
                        return;
                    }
                }
            })?;
        Ok(Self {
            stop,
            handle: Some(handle),
        })
    }

    /// Stops watching; returns once the watcher has ended.
    pub fn stop(mut self) {
        self.end();
    }

    fn end(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(handle) = self.handle.take() {
            let _ = handle.join();
        }
    }
}

impl Drop for Watcher {
    fn drop(&mut self) {
        self.end();
    }
}

/// The calling thread's id.
fn this_tid() -> libc::pid_t {
    // SAFETY: gettid has no arguments and cannot fail.
    unsafe { libc::syscall(libc::SYS_gettid) as libc::pid_t }
}

/// Moves thread `tid` to `SCHED_OTHER` at nice 0; whether both took.
fn raise(tid: libc::pid_t) -> bool {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: plain syscalls on a thread id of this process; `param` outlives the call.
    unsafe {
        libc::sched_setscheduler(tid, libc::SCHED_OTHER, &param) == 0
            && libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, 0) == 0
    }
}

/// Whether this process may move a thread out of `SCHED_IDLE` (or nice +19) again: tried
/// once on a throwaway thread, remembered.
pub fn can_restore() -> bool {
    static CAN: OnceLock<bool> = OnceLock::new();
    *CAN.get_or_init(|| {
        std::thread::Builder::new()
            .name("priority-probe".into())
            .spawn(|| {
                let background = Background::new();
                background.lower();
                background.restore()
            })
            .ok()
            .and_then(|h| h.join().ok())
            .unwrap_or(false)
    })
}

/// The calling thread's scheduling policy (for tests).
#[cfg(test)]
fn policy_of(tid: libc::pid_t) -> i32 {
    // SAFETY: a query on a thread id of this process.
    unsafe { libc::sched_getscheduler(tid) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    /// A lowered thread is moved back to normal scheduling by its owner, while it runs,
    /// wherever this process may do so; elsewhere `restore` says it could not.
    #[test]
    fn a_lowered_thread_is_raised_back_by_its_owner() {
        let background = Arc::new(Background::new());
        let (lowered_tx, lowered_rx) = std::sync::mpsc::channel();
        let (check_tx, check_rx) = std::sync::mpsc::channel::<()>();
        let thread = {
            let background = background.clone();
            std::thread::spawn(move || {
                let idle = background.lower();
                let tid = this_tid();
                lowered_tx.send((idle, tid, policy_of(0))).unwrap();
                check_rx.recv().unwrap();
                policy_of(0)
            })
        };
        let (idle, _tid, policy_while_lowered) = lowered_rx.recv().unwrap();
        if idle {
            assert_eq!(policy_while_lowered, libc::SCHED_IDLE);
        }
        let raised = background.restore();
        check_tx.send(()).unwrap();
        let policy_after = thread.join().unwrap();
        assert_eq!(raised, can_restore() || !idle);
        if raised {
            assert_eq!(policy_after, libc::SCHED_OTHER);
        }
    }

    /// A thread its owner restored before it got to lower itself stays at normal priority.
    #[test]
    fn a_thread_restored_before_it_lowers_itself_stays_normal() {
        let background = Background::new();
        assert!(background.restore());
        let policy = std::thread::scope(|s| {
            s.spawn(|| {
                assert!(!background.lower());
                policy_of(0)
            })
            .join()
            .unwrap()
        });
        assert_eq!(policy, libc::SCHED_OTHER);
    }

    /// Two threads that lowered themselves and never beat are both raised by a watcher once
    /// its limit passes, where this process may raise them; one that beats is left lowered.
    #[test]
    fn a_watcher_raises_every_thread_of_a_set_that_makes_no_progress() {
        let stalled = Arc::new(Background::new());
        let busy = Arc::new(Background::new());
        let (policies_tx, policies) = std::sync::mpsc::channel();
        let (lowered_tx, lowered) = std::sync::mpsc::channel();
        let done = Arc::new(AtomicBool::new(false));
        let threads: Vec<_> = [stalled.clone(), stalled.clone(), busy.clone()]
            .into_iter()
            .enumerate()
            .map(|(i, set)| {
                let (policies_tx, lowered_tx, done) =
                    (policies_tx.clone(), lowered_tx.clone(), done.clone());
                std::thread::spawn(move || {
                    let idle = set.lower();
                    lowered_tx.send(()).unwrap();
                    while !done.load(Ordering::SeqCst) {
                        if i == 2 {
                            set.beat();
                        }
                        std::thread::sleep(Duration::from_millis(2));
                    }
                    policies_tx.send((i, idle, policy_of(0))).unwrap();
                })
            })
            .collect();
        for _ in 0..3 {
            lowered.recv().unwrap();
        }
        let watch_stalled =
            Watcher::start(stalled.clone(), Duration::from_millis(50), "stalled").unwrap();
        let watch_busy = Watcher::start(busy.clone(), Duration::from_millis(50), "busy").unwrap();
        std::thread::sleep(Duration::from_millis(300));
        watch_busy.stop();
        done.store(true, Ordering::SeqCst);
        threads.into_iter().for_each(|t| t.join().unwrap());
        drop(watch_stalled);
        let policies: Vec<_> = policies.try_iter().collect();
        assert_eq!(policies.len(), 3);
        for (i, idle, policy) in policies {
            match (i, idle) {
                // Lowered and never beating: raised wherever raising is allowed.
                (0 | 1, true) if can_restore() => {
                    assert_eq!(policy, libc::SCHED_OTHER, "thread {i}")
                }
                // Beating: still lowered.
                (2, true) => assert_eq!(policy, libc::SCHED_IDLE),
                _ => {}
            }
        }
        // The stalled set is restored: a thread that would join it now stays normal.
        assert!(!stalled.lower());
    }
}
