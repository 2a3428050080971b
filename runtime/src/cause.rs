//! Operating-system errors said as their cause, for messages a user acts on.

use std::io;

/// What `e` means for the user, after the system's own words: `No space left on device
/// (os error 28)` becomes `… : the disk is full`, and so on for a read-only file system, a
/// missing file or device, too many open files and permissions. Other errors are returned as
/// the system says them.
///
/// ```
/// let e = std::io::Error::from_raw_os_error(24);
/// assert!(tes_runtime::cause::explain(&e).ends_with("too many open files: raise the limit (ulimit -n)"));
/// ```
pub fn explain(e: &io::Error) -> String {
    use nix::errno::Errno;
    let hint = match e.raw_os_error().map(Errno::from_raw) {
        Some(Errno::ENOSPC | Errno::EDQUOT) => "the disk is full",
        Some(Errno::EROFS) => "the file system is read-only",
        Some(Errno::EMFILE | Errno::ENFILE) => "too many open files: raise the limit (ulimit -n)",
        Some(Errno::ENOENT) => "no such file or device",
        Some(Errno::ENODEV | Errno::ENXIO) => "no such device (is it connected and switched on?)",
        Some(Errno::EACCES | Errno::EPERM) => "permission denied",
        _ => return e.to_string(),
    };
    format!("{e}: {hint}")
}

/// Whether this process has (nearly) run out of file descriptors: it has fewer than 16 left
/// under its `RLIMIT_NOFILE`, or cannot open one more. For errors of libraries that do not
/// keep the `io::Error` (iceoryx2 says `InternalFailure`, and has closed what it opened by
/// the time it says so).
pub fn is_out_of_descriptors() -> bool {
    const MARGIN: u64 = 16;
    let open = std::fs::read_dir("/proc/self/fd").map(|d| d.count() as u64);
    let limit = nix::sys::resource::getrlimit(nix::sys::resource::Resource::RLIMIT_NOFILE)
        .map(|(soft, _)| soft);
    if let (Ok(open), Ok(limit)) = (open, limit)
        && open.saturating_add(MARGIN) >= limit
    {
        return true;
    }
    std::fs::File::open("/dev/null").is_err_and(|e| {
        matches!(
            e.raw_os_error().map(nix::errno::Errno::from_raw),
            Some(nix::errno::Errno::EMFILE | nix::errno::Errno::ENFILE)
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_cause_is_said() {
        for (code, said) in [
            (28, "the disk is full"),
            (30, "read-only"),
            (24, "too many open files"),
            (2, "no such file"),
            (19, "no such device"),
            (13, "permission denied"),
        ] {
            let shown = explain(&io::Error::from_raw_os_error(code));
            assert!(shown.contains(said), "{code}: {shown}");
        }
        assert_eq!(explain(&io::Error::other("odd")), "odd");
    }
}
