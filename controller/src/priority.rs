//! Background threads whose low priority can be taken back at shutdown.
//!
//! The planner and the library saver run under `SCHED_IDLE` so that they only take time the
//! acting path does not want. On a busy machine such a thread gets almost no CPU (a weight of
//! 3 against 1024 for a normal thread), so a shutdown that waits for it — the final library
//! save waits for a save in progress — could wait for seconds, past the launcher's grace.
//! [`Background::restore`] moves the thread back to normal scheduling by its thread id
//! (`sched_setscheduler` on a tid) so that it finishes promptly.
//!
//! Linux lets a thread leave `SCHED_IDLE` only with `CAP_SYS_NICE` or an `RLIMIT_NICE` of 20:
//! [`can_restore`] finds out once, on a throwaway thread. Where it cannot be undone, a thread
//! whose work the shutdown needs ([`Background::lower_if_restorable`]) stays at normal
//! priority instead.

use std::sync::{Mutex, OnceLock};

/// A background thread's scheduling, shared between the thread and its owner.
#[derive(Debug, Default)]
pub struct Background {
    state: Mutex<State>,
}

#[derive(Debug, Default)]
struct State {
    /// The thread's id once it lowered its priority.
    lowered: Option<libc::pid_t>,
    /// The owner restored (or is about to wait for) the thread: it must not lower itself now.
    restored: bool,
}

impl Background {
    /// A thread not yet lowered.
    pub fn new() -> Self {
        Self::default()
    }

    /// On the background thread: lowers its priority ([`tes_runtime::affinity::lower_this_threads_priority`])
    /// unless the owner already restored it. Returns whether it runs under `SCHED_IDLE`.
    pub fn lower(&self) -> bool {
        let mut state = self.lock();
        if state.restored {
            return false;
        }
        let idle = tes_runtime::affinity::lower_this_threads_priority();
        state.lowered = Some(this_tid());
        idle
    }

    /// [`lower`](Self::lower) where the lowering can be undone ([`can_restore`]); otherwise
    /// the thread keeps normal priority (said at debug level). For threads whose work a
    /// shutdown waits for.
    pub fn lower_if_restorable(&self) -> bool {
        if can_restore() {
            return self.lower();
        }
        tracing::debug!(
            "a background thread keeps normal priority: SCHED_IDLE could not be undone at \
             shutdown here (no CAP_SYS_NICE, RLIMIT_NICE below 20)"
        );
        false
    }

    /// On the owner: moves the thread back to normal scheduling (`SCHED_OTHER`, nice 0) if
    /// it lowered itself, and keeps it from lowering itself later. Returns whether the
    /// thread now runs at normal priority (false: it was lowered and could not be raised).
    pub fn restore(&self) -> bool {
        let mut state = self.lock();
        state.restored = true;
        match state.lowered.take() {
            None => true,
            Some(tid) => {
                let raised = raise(tid);
                if !raised {
                    state.lowered = Some(tid);
                }
                raised
            }
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        // The state is two plain fields: a panic elsewhere cannot leave it inconsistent.
        self.state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
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
}
