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
    let hint = match e.raw_os_error() {
        Some(code) if code == libc_errno::ENOSPC || code == libc_errno::EDQUOT => {
            Some("the disk is full")
        }
        Some(code) if code == libc_errno::EROFS => Some("the file system is read-only"),
        Some(code) if code == libc_errno::EMFILE || code == libc_errno::ENFILE => {
            Some("too many open files: raise the limit (ulimit -n)")
        }
        Some(code) if code == libc_errno::ENOENT => Some("no such file or device"),
        Some(code) if code == libc_errno::ENODEV || code == libc_errno::ENXIO => {
            Some("no such device (is it connected and switched on?)")
        }
        Some(code) if code == libc_errno::EACCES || code == libc_errno::EPERM => {
            Some("permission denied")
        }
        _ => None,
    };
    match hint {
        Some(h) => format!("{e}: {h}"),
        None => e.to_string(),
    }
}

/// The error numbers `explain` knows, from `nix` (no `libc` dependency needed).
mod libc_errno {
    use nix::errno::Errno;
    pub const ENOSPC: i32 = Errno::ENOSPC as i32;
    pub const EDQUOT: i32 = Errno::EDQUOT as i32;
    pub const EROFS: i32 = Errno::EROFS as i32;
    pub const EMFILE: i32 = Errno::EMFILE as i32;
    pub const ENFILE: i32 = Errno::ENFILE as i32;
    pub const ENOENT: i32 = Errno::ENOENT as i32;
    pub const ENODEV: i32 = Errno::ENODEV as i32;
    pub const ENXIO: i32 = Errno::ENXIO as i32;
    pub const EACCES: i32 = Errno::EACCES as i32;
    pub const EPERM: i32 = Errno::EPERM as i32;
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
    match std::fs::File::open("/dev/null") {
        Ok(_) => false,
        Err(e) => {
            matches!(e.raw_os_error(), Some(c) if c == libc_errno::EMFILE || c == libc_errno::ENFILE)
        }
    }
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
