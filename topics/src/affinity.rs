//! CPU placement: pinning a thread to one CPU.
//!
//! A woken thread that may run anywhere pays for the scheduler's choice of CPU and, after a
//! sleep, for caches that other work on that CPU has filled. Pinning the controller's acting
//! thread to one CPU and its planner thread to another keeps the acting thread's memory warm
//! and its wake-up short (measured in `docs/performance.md`). Linux only; elsewhere pinning
//! is refused with [`AffinityError::Unsupported`].

use thiserror::Error;

/// Why a thread could not be pinned.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum AffinityError {
    /// The CPU is not one this process may run on.
    #[error("CPU {cpu} is not one this process may run on (allowed: {allowed:?})")]
    NotAllowed {
        /// The CPU asked for.
        cpu: usize,
        /// The CPUs this process may use.
        allowed: Vec<usize>,
    },
    /// The operating system refused.
    #[error("pinning to CPU {cpu} failed: {reason}")]
    Refused {
        /// The CPU asked for.
        cpu: usize,
        /// The system's reason.
        reason: String,
    },
    /// Not supported on this platform.
    #[error("pinning threads to CPUs is supported on Linux only")]
    Unsupported,
}

/// The CPUs the calling thread may run on, ascending (empty where this cannot be known).
pub fn allowed_cpus() -> Vec<usize> {
    #[cfg(target_os = "linux")]
    {
        use nix::sched::{CpuSet, sched_getaffinity};
        use nix::unistd::Pid;
        match sched_getaffinity(Pid::from_raw(0)) {
            Ok(set) => (0..CpuSet::count())
                .filter(|&c| set.is_set(c).unwrap_or(false))
                .collect(),
            Err(_) => Vec::new(),
        }
    }
    #[cfg(not(target_os = "linux"))]
    {
        Vec::new()
    }
}

/// Checks that `cpu` is one of [`allowed_cpus`].
pub fn check_cpu(cpu: usize) -> Result<(), AffinityError> {
    if !cfg!(target_os = "linux") {
        return Err(AffinityError::Unsupported);
    }
    let allowed = allowed_cpus();
    if allowed.contains(&cpu) {
        Ok(())
    } else {
        Err(AffinityError::NotAllowed { cpu, allowed })
    }
}

/// Pins the calling thread to `cpu` (it runs there only, from now on).
pub fn pin_this_thread(cpu: usize) -> Result<(), AffinityError> {
    check_cpu(cpu)?;
    #[cfg(target_os = "linux")]
    {
        use nix::sched::{CpuSet, sched_setaffinity};
        use nix::unistd::Pid;
        let mut set = CpuSet::new();
        set.set(cpu).map_err(|e| AffinityError::Refused {
            cpu,
            reason: e.to_string(),
        })?;
        // Pid 0 is the calling thread (Linux sets affinity per thread).
        sched_setaffinity(Pid::from_raw(0), &set).map_err(|e| AffinityError::Refused {
            cpu,
            reason: e.to_string(),
        })
    }
    #[cfg(not(target_os = "linux"))]
    {
        Err(AffinityError::Unsupported)
    }
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    #[test]
    fn a_thread_pinned_to_an_allowed_cpu_runs_there_only() {
        let allowed = allowed_cpus();
        assert!(!allowed.is_empty());
        let cpu = *allowed.last().expect("at least one CPU");
        let seen = std::thread::spawn(move || pin_this_thread(cpu).map(|()| allowed_cpus()))
            .join()
            .expect("the thread ran");
        assert_eq!(seen, Ok(vec![cpu]));
        // The pin was the other thread's only.
        assert_eq!(allowed_cpus(), allowed);
    }

    #[test]
    fn a_cpu_outside_the_allowed_set_is_refused_naming_the_allowed_ones() {
        let allowed = allowed_cpus();
        let beyond = allowed.iter().max().copied().unwrap_or(0) + 1;
        let err = std::thread::spawn(move || pin_this_thread(beyond))
            .join()
            .expect("the thread ran")
            .expect_err("no such CPU");
        assert_eq!(
            err,
            AffinityError::NotAllowed {
                cpu: beyond,
                allowed
            }
        );
        assert!(err.to_string().contains(&format!("CPU {beyond}")));
    }
}
