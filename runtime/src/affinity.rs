//! CPU placement: pinning a thread to one CPU.
//!
//! A woken thread that may run anywhere pays for the scheduler's choice of CPU and, after a
//! sleep, for caches that other work on that CPU has filled. Pinning the controller's acting
//! thread to one CPU and its planner thread to another keeps the acting thread's memory warm
//! and its wake-up short (measured in `docs/performance.md`). Linux only; elsewhere pinning
//! is refused with [`AffinityError::Unsupported`].

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Deserializer, Serialize, Serializer};
use thiserror::Error;

/// Where a thread is to run: the value of a CPU-placement setting (the controller's
/// `acting_cpu` and `planner_cpu`, `tes bench latency --acting-cpu`). Written as a CPU number,
/// `"auto"` or `"none"`.
///
/// ```
/// use tes_runtime::affinity::Placement;
///
/// assert_eq!("3".parse(), Ok(Placement::Cpu(3)));
/// assert_eq!("none".parse(), Ok(Placement::Unpinned));
/// assert_eq!(Placement::default(), Placement::Auto);
/// assert!("fast".parse::<Placement>().is_err());
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Placement {
    /// The process chooses at start (what it chooses is documented with the setting).
    #[default]
    Auto,
    /// Wherever the scheduler puts it.
    Unpinned,
    /// This CPU only.
    Cpu(usize),
}

/// A placement that is neither a CPU number, `auto` nor `none`.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[error("{0:?} is not a placement: expected a CPU number, \"auto\" or \"none\"")]
pub struct BadPlacement(pub String);

impl FromStr for Placement {
    type Err = BadPlacement;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "auto" => Ok(Self::Auto),
            "none" => Ok(Self::Unpinned),
            _ => s
                .parse()
                .map(Self::Cpu)
                .map_err(|_| BadPlacement(s.to_owned())),
        }
    }
}

impl fmt::Display for Placement {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Auto => f.write_str("auto"),
            Self::Unpinned => f.write_str("none"),
            Self::Cpu(c) => write!(f, "{c}"),
        }
    }
}

impl Serialize for Placement {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        match self {
            Self::Cpu(c) => serializer.serialize_u64(*c as u64),
            other => serializer.serialize_str(&other.to_string()),
        }
    }
}

impl<'de> Deserialize<'de> for Placement {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Written {
            Cpu(usize),
            Word(String),
        }
        match Written::deserialize(deserializer) {
            Ok(Written::Cpu(c)) => Ok(Self::Cpu(c)),
            Ok(Written::Word(w)) => w.parse().map_err(serde::de::Error::custom),
            Err(_) => Err(serde::de::Error::custom(
                "expected a CPU number, \"auto\" or \"none\"",
            )),
        }
    }
}

/// The automatic placement of a real-time thread and its helper: the last allowed CPU for
/// the real-time thread and the first for the helper, or `None` with fewer than two allowed
/// CPUs (pinning both to the only one would only forbid what the scheduler does anyway).
///
/// The last, because CPU 0 is where Linux tends to put housekeeping and device interrupts.
pub fn auto_pair() -> Option<(usize, usize)> {
    let allowed = allowed_cpus();
    match (allowed.first(), allowed.last()) {
        (Some(&first), Some(&last)) if first != last => Some((last, first)),
        _ => None,
    }
}

/// For a process whose receivers anticipate its messages, or that anticipates them beside
/// the controller: pins the calling thread to the helper's CPU of [`auto_pair`] (the one the
/// controller's acting thread does not take by default), so that on two CPUs the acting
/// thread polls alone on its own. Returns the CPU, or `None` with fewer than two CPUs.
pub fn pin_off_the_acting_cpu() -> Result<Option<usize>, AffinityError> {
    let Some((_, other)) = auto_pair() else {
        return Ok(None);
    };
    pin_this_thread(other).map(|()| Some(other))
}

/// Pins the controller's acting thread (or the floor's hop) to `cpu` and says whether it has
/// that CPU to itself as far as TES goes: when it `anticipates` its messages, the chain around
/// it keeps off its CPU ([`place_beside_the_acting_thread`]); blocking, the chain shares it.
/// Judged from the CPUs the thread could run on *before* pinning: afterwards it sees only
/// `cpu`, and no CPU would look kept clear.
pub fn pin_acting_thread(cpu: usize, anticipates: bool) -> Result<bool, AffinityError> {
    let alone = anticipates && auto_pair().is_some_and(|(_, other)| other != cpu);
    pin_this_thread(cpu)?;
    Ok(alone)
}

/// Places a process of the chain around the controller's acting thread — perception and the
/// bridge, and the floor's source and sink — on the CPUs of [`auto_pair`] (`who` names it in
/// the log; a refusal is logged and the process runs unpinned, not an error):
///
/// * `anticipating` (it announces its messages to receivers that poll for them, or polls
///   for its own): off the acting thread's CPU ([`pin_off_the_acting_cpu`]), so that
///   thread polls alone;
/// * otherwise, when every receiver blocks: on the acting thread's CPU. Each hand-over of the
///   chain is then a wake-up on the CPU its sender is about to leave, a few microseconds,
///   rather than a wake-up of the other CPU, which in a virtual machine is a halted virtual
///   CPU: about 40 µs on this project's test machine (`docs/performance.md`).
pub fn place_beside_the_acting_thread(anticipating: bool, who: &str) {
    let Some((acting, other)) = auto_pair() else {
        return;
    };
    let cpu = if anticipating { other } else { acting };
    if let Err(e) = pin_this_thread(cpu) {
        tracing::warn!(error = %e, "{who} runs unpinned");
    }
}

/// What every process of the chain does once its ports are open: takes its place beside the
/// acting thread ([`place_beside_the_acting_thread`]) and locks its pages
/// ([`crate::memory::keep_resident`]); `who` names it in what either says.
pub fn join_the_chain(anticipating: bool, who: &str) {
    place_beside_the_acting_thread(anticipating, who);
    crate::memory::keep_resident(who);
}

/// Makes the calling thread a background one (`who` names it in the log): the lowest priority
/// ([`lower_this_threads_priority`]) and off the acting thread's CPU
/// ([`pin_off_the_acting_cpu`]), so its wake-ups and work never sit between the acting thread
/// and its next observation. Best effort: a refusal is logged and the thread runs anyway.
pub fn make_this_a_background_thread(who: &str) {
    if !lower_this_threads_priority() {
        tracing::warn!("{who} runs at nice +19 or normal priority, not SCHED_IDLE");
    }
    if let Err(e) = pin_off_the_acting_cpu() {
        tracing::debug!("{who} stays unpinned: {e}");
    }
}

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

/// The real-time priority a receiver alone on its CPU polls its window at (`SCHED_FIFO`, the
/// lowest of the range): above every normal thread, the kernel's workers and page reclaim
/// included, and below any real-time thread the system runs.
const POLL_PRIORITY: i32 = 1;

/// Puts the calling thread under `SCHED_FIFO` at the lowest real-time priority (`true`), or
/// back under the normal policy (`false`). Refused without `CAP_SYS_NICE` or an
/// `RLIMIT_RTPRIO` of at least 1 (and everywhere but Linux).
pub fn set_this_thread_realtime(on: bool) -> std::io::Result<()> {
    #[cfg(target_os = "linux")]
    {
        let (policy, priority) = if on {
            (libc::SCHED_FIFO, POLL_PRIORITY)
        } else {
            (libc::SCHED_OTHER, 0)
        };
        let param = libc::sched_param {
            sched_priority: priority,
        };
        // SAFETY: pid 0 is the calling thread; `param` outlives the call.
        if unsafe { libc::sched_setscheduler(0, policy, &param) } == 0 {
            Ok(())
        } else {
            Err(std::io::Error::last_os_error())
        }
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = (on, POLL_PRIORITY);
        Err(std::io::Error::from(std::io::ErrorKind::Unsupported))
    }
}

/// `SCHED_IDLE` for the calling thread, or nice +19 if that is refused (Linux schedules
/// threads individually): for background work (planning, saving, recording) that must take
/// only time the acting path does not want. Under `SCHED_IDLE` a waking thread of normal
/// priority preempts it at once; a merely niced thread is let finish its slice first. Best
/// effort — the work still runs at normal priority if both are refused. Returns whether the
/// thread runs under `SCHED_IDLE`.
pub fn lower_this_threads_priority() -> bool {
    #[cfg(target_os = "linux")]
    {
        let param = libc::sched_param { sched_priority: 0 };
        // SAFETY: pid 0 is the calling thread; `param` outlives the call.
        let idle = unsafe { libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) };
        if idle == 0 {
            return true;
        }
        // SAFETY: plain syscalls on the calling thread's own id; no memory is shared.
        let nice = unsafe {
            let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
            libc::setpriority(libc::PRIO_PROCESS, tid, 19)
        };
        if nice != 0 {
            tracing::debug!(
                error = %std::io::Error::last_os_error(),
                "could not lower a background thread's priority"
            );
        }
    }
    false
}

#[cfg(test)]
mod placement_tests {
    use super::*;

    #[test]
    fn a_placement_reads_and_writes_as_a_number_or_a_word() {
        #[derive(Debug, PartialEq, Serialize, Deserialize)]
        struct Keys {
            a: Placement,
            b: Placement,
            c: Placement,
        }
        let keys: Keys = toml::from_str("a = 2\nb = \"auto\"\nc = \"none\"").unwrap();
        assert_eq!(
            keys,
            Keys {
                a: Placement::Cpu(2),
                b: Placement::Auto,
                c: Placement::Unpinned
            }
        );
        // A number in a string reads too (scripts write every value quoted).
        let quoted: Keys = toml::from_str("a = \"2\"\nb = \"auto\"\nc = \"none\"").unwrap();
        assert_eq!(quoted, keys);
        let written = toml::to_string(&keys).unwrap();
        assert_eq!(toml::from_str::<Keys>(&written).unwrap(), keys);
        for p in [Placement::Auto, Placement::Unpinned, Placement::Cpu(7)] {
            assert_eq!(p.to_string().parse(), Ok(p));
        }
        for bad in [
            "a = \"fast\"\nb = 1\nc = 1",
            "a = -1\nb = 1\nc = 1",
            "a = 1.5\nb = 1\nc = 1",
        ] {
            let err = toml::from_str::<Keys>(bad).expect_err(bad).to_string();
            assert!(err.contains("auto") && err.contains("none"), "{bad}: {err}");
        }
    }

    /// Anticipating, the acting CPU of the automatic pair is the pinned thread's alone; the
    /// helper's is not; blocking, neither is (the chain shares it); and the answer does not
    /// depend on the pinning it follows (which leaves the thread one CPU, where every CPU
    /// would look shared).
    #[test]
    fn a_thread_pinned_to_the_acting_cpu_knows_whether_it_is_alone() {
        let Some((acting, helper)) = auto_pair() else {
            return;
        };
        let on = |cpu, anticipates| {
            std::thread::spawn(move || {
                let alone = pin_acting_thread(cpu, anticipates).unwrap();
                (alone, allowed_cpus())
            })
            .join()
            .unwrap()
        };
        assert_eq!(on(acting, true), (true, vec![acting]));
        assert_eq!(on(helper, true), (false, vec![helper]));
        assert_eq!(on(acting, false), (false, vec![acting]));
    }

    /// A process of the chain anticipating keeps off the acting thread's CPU; blocking, it
    /// shares it; with fewer than two CPUs it stays where it was.
    #[test]
    fn the_chain_shares_the_acting_cpu_when_blocking_and_keeps_off_it_when_anticipating() {
        let placed = |anticipating| {
            std::thread::spawn(move || {
                place_beside_the_acting_thread(anticipating, "this test");
                allowed_cpus()
            })
            .join()
            .unwrap()
        };
        match auto_pair() {
            Some((acting, other)) => {
                assert_eq!(placed(false), vec![acting]);
                assert_eq!(placed(true), vec![other]);
            }
            None => assert_eq!(placed(false), allowed_cpus()),
        }
    }

    #[test]
    fn the_automatic_pair_is_two_different_allowed_cpus_or_none() {
        let allowed = allowed_cpus();
        match auto_pair() {
            Some((rt, helper)) => {
                assert_ne!(rt, helper);
                assert_eq!(Some(&rt), allowed.last());
                assert_eq!(Some(&helper), allowed.first());
            }
            None => assert!(allowed.len() < 2, "{allowed:?}"),
        }
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
