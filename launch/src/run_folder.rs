//! A launch's run folder: `runs/<start time>/` in the data directory, one per launch, the
//! oldest removed beyond `[launch] keep_runs`, and `runs/latest` pointing at the newest.
//!
//! The launcher fills a run folder as the run goes (see [`super::run_record`]) and draws its
//! pictures at the end.

use std::path::{Path, PathBuf};
use std::time::SystemTime;

/// The folder of run folders in the data directory.
pub(crate) const RUNS: &str = "runs";

/// The link in the runs folder to the newest run.
pub(crate) const LATEST: &str = "latest";

/// The name of a run folder started at `at`: its UTC time to the second, as RFC 3339 with
/// `-` for `:` (file names with colons trouble other systems).
pub(crate) fn folder_name(at: SystemTime) -> String {
    humantime::format_rfc3339_seconds(at)
        .to_string()
        .replace(':', "-")
}

/// Whether `name` is a run folder's: a [`folder_name`], perhaps with `-N` after it.
pub(crate) fn is_run_folder_name(name: &str) -> bool {
    let Some(stamp) = name.get(..20) else {
        return false;
    };
    let rest = &name[20..];
    let stamp_ok = humantime::parse_rfc3339(&restore_colons(stamp)).is_ok();
    stamp_ok
        && (rest.is_empty()
            || rest
                .strip_prefix('-')
                .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit())))
}

/// `2026-12-02T19-05-33Z` back to `2026-12-02T19:05:33Z`.
fn restore_colons(stamp: &str) -> String {
    let mut s = stamp.to_owned();
    for i in [13, 16] {
        if s.get(i..=i) == Some("-") {
            s.replace_range(i..=i, ":");
        }
    }
    s
}

/// The order of run folders: by start time, then by the number after it.
fn sort_key(name: &str) -> (String, u32) {
    let (stamp, rest) = name.split_at(name.len().min(20));
    let n = rest
        .strip_prefix('-')
        .and_then(|n| n.parse().ok())
        .unwrap_or(0);
    (stamp.to_owned(), n)
}

/// Creates the run folder of a launch started at `at` in `runs`: [`folder_name`], or with
/// `-2`, `-3`, … after it when a launch of the same second has it.
pub(crate) fn create(runs: &Path, at: SystemTime) -> std::io::Result<PathBuf> {
    let name = folder_name(at);
    for n in 1u32.. {
        let path = if n == 1 {
            runs.join(&name)
        } else {
            runs.join(format!("{name}-{n}"))
        };
        match std::fs::create_dir(&path) {
            Ok(()) => return Ok(path),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e),
        }
    }
    Err(std::io::Error::other("no free run folder name"))
}

/// The run folders in `runs`, oldest first.
pub(crate) fn list(runs: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(runs) else {
        return Vec::new();
    };
    let mut folders: Vec<(String, u32, PathBuf)> = entries
        .filter_map(Result::ok)
        .filter(|e| e.file_type().is_ok_and(|t| t.is_dir()))
        .filter_map(|e| {
            let name = e.file_name().into_string().ok()?;
            is_run_folder_name(&name).then(|| {
                let (stamp, n) = sort_key(&name);
                (stamp, n, e.path())
            })
        })
        .collect();
    folders.sort();
    folders.into_iter().map(|(_, _, p)| p).collect()
}

/// The lock file a launch holds in its run folder while it runs (see [`prune`]).
pub(crate) const IN_USE: &str = "in-use.lock";

/// Removes the oldest run folders of `runs` beyond `keep` (0 keeps all), never `current` nor
/// one another launch of the data directory still runs in (its [`IN_USE`] lock held);
/// returns the folders removed. A folder that cannot be removed is left (and not counted).
pub(crate) fn prune(runs: &Path, keep: u32, current: &Path) -> Vec<PathBuf> {
    if keep == 0 {
        return Vec::new();
    }
    let folders = list(runs);
    let excess = folders.len().saturating_sub(keep as usize);
    folders
        .into_iter()
        .filter(|f| f != current)
        .take(excess)
        .filter(|f| !in_use(f) && std::fs::remove_dir_all(f).is_ok())
        .collect()
}

/// Whether a launch runs in `folder` (holds its [`IN_USE`] lock). A folder whose lock is
/// free is not: taking the lock tells, and letting it go removes the file.
fn in_use(folder: &Path) -> bool {
    let lock = folder.join(IN_USE);
    lock.exists()
        && matches!(
            tes_runtime::lock::Lock::acquire(&lock, "run folder"),
            Err(tes_runtime::lock::LockError::Held { .. })
        )
}

/// Points `runs/latest` at `dir` (best effort: a file system without symbolic links just
/// has no `latest`).
pub(crate) fn point_latest_at(runs: &Path, dir: &Path) {
    let link = runs.join(LATEST);
    let Some(name) = dir.file_name() else { return };
    let temp = runs.join(format!(".{LATEST}.{}", std::process::id()));
    let _ = std::fs::remove_file(&temp);
    if std::os::unix::fs::symlink(name, &temp).is_ok() && std::fs::rename(&temp, &link).is_err() {
        let _ = std::fs::remove_file(&temp);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, UNIX_EPOCH};

    #[test]
    fn run_folders_are_named_by_their_utc_start_time() {
        let at = UNIX_EPOCH + Duration::from_secs(1_796_000_000);
        let name = folder_name(at);
        assert_eq!(name, "2026-11-30T00-53-20Z");
        assert!(is_run_folder_name(&name));
        assert!(is_run_folder_name(&format!("{name}-12")));
        for not in [
            "latest",
            "launch.lock",
            "2026-11-30",
            &format!("{name}-"),
            &format!("{name}x"),
        ] {
            assert!(!is_run_folder_name(not), "{not}");
        }
    }

    #[test]
    fn launches_of_one_second_get_folders_of_their_own_and_the_oldest_go_first() {
        let runs = tempfile::tempdir().unwrap();
        let at = UNIX_EPOCH + Duration::from_secs(1_796_000_000);
        let made: Vec<PathBuf> = (0..12)
            .map(|_| create(runs.path(), at).unwrap())
            .chain([create(runs.path(), at + Duration::from_secs(1)).unwrap()])
            .collect();
        assert_eq!(made[1].file_name().unwrap(), "2026-11-30T00-53-20Z-2");
        // Listed in start order, -10 after -9.
        assert_eq!(list(runs.path()), made);
        std::fs::create_dir(runs.path().join("not-a-run")).unwrap();
        let newest = made.last().unwrap();
        let pruned = prune(runs.path(), 3, newest);
        assert_eq!(pruned, made[..10].to_vec());
        assert_eq!(list(runs.path()), made[10..].to_vec());
        assert!(
            runs.path().join("not-a-run").exists(),
            "only run folders are pruned"
        );
        assert!(prune(runs.path(), 0, newest).is_empty());
        // A folder another launch of the data directory runs in is kept, and pruned once
        // that launch has let it go.
        let running = &made[10];
        let held = tes_runtime::lock::Lock::acquire(&running.join(IN_USE), "run folder").unwrap();
        assert_eq!(prune(runs.path(), 1, newest), vec![made[11].clone()]);
        assert!(running.exists(), "a folder in use is kept");
        drop(held);
        assert_eq!(prune(runs.path(), 1, newest), vec![running.clone()]);
        point_latest_at(runs.path(), newest);
        point_latest_at(runs.path(), newest);
        assert_eq!(
            std::fs::read_link(runs.path().join(LATEST)).unwrap(),
            newest.file_name().unwrap()
        );
    }
}
