//! Keeping a real-time process's memory resident: `mlockall(MCL_CURRENT | MCL_ONFAULT)`.
//!
//! At the robot's pace the acting path runs once every few hundred milliseconds, and between
//! two runs its code and data sit untouched. A kernel that reclaims cold pages proactively
//! (DAMON's `pageout`, or plain reclaim under memory pressure) drops the file-backed ones —
//! the binary's own code — and the next action faults them back in from disk, in the
//! decision's time. Locked, a page stays: every page mapped when the process is ready, and
//! every page of those mappings it touches later, is kept (`MCL_ONFAULT` locks pages as they
//! are first touched rather than reading the whole binary in, so the cost is the memory the
//! process really uses). Mappings made later (the heap growing, a new service) are left to
//! the kernel, so no allocation can fail for want of lockable memory.
//!
//! Refused without `CAP_IPC_LOCK` when the process maps more than `RLIMIT_MEMLOCK` allows
//! (a normal user's limit is a few MB): the process runs unlocked and says so once.

/// Whether a process's memory is kept resident, as it reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Residency {
    /// Every page it had mapped when ready, and each page of them it touched since, is locked.
    Locked,
    /// The system refused (no `CAP_IPC_LOCK` and a lower `RLIMIT_MEMLOCK`, or not Linux).
    Refused,
}

/// Locks the calling process's current mappings as they are touched
/// (`mlockall(MCL_CURRENT | MCL_ONFAULT)`); `who` names the process in the one line said
/// when the system refuses.
pub fn keep_resident(who: &str) -> Residency {
    match lock_current_mappings() {
        Ok(()) => Residency::Locked,
        Err(e) => {
            tracing::info!(
                error = %e,
                "{who}'s memory is not locked (needs CAP_IPC_LOCK or a higher RLIMIT_MEMLOCK): \
                 pages the kernel reclaims are read back in the actions' time"
            );
            Residency::Refused
        }
    }
}

fn lock_current_mappings() -> std::io::Result<()> {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: mlockall takes flags only and changes no memory the program sees.
        if unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_ONFAULT) } == 0 {
            Ok(())
        } else {
            Err(std::io::Error::last_os_error())
        }
    }
    #[cfg(not(target_os = "linux"))]
    {
        Err(std::io::Error::from(std::io::ErrorKind::Unsupported))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Locked, the process's locked memory (`VmLck`) covers its mappings; refused (for want
    /// of the right), none is locked. (The lock is process-wide: this test binary's other
    /// tests run with it, which changes nothing they see.)
    #[test]
    fn a_locked_process_counts_its_touched_pages_as_locked() {
        let residency = keep_resident("this test");
        let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
        let locked_kb: u64 = status
            .lines()
            .find_map(|l| l.strip_prefix("VmLck:"))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
            .unwrap_or(0);
        match residency {
            Residency::Locked => assert!(locked_kb > 0, "locked, yet VmLck is {locked_kb} kB"),
            Residency::Refused => assert_eq!(locked_kb, 0),
        }
    }
}
