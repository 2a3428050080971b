//! Every launch leaves a run folder to look at: `runs/<start time>/` in the data directory
//! with the resolved launch file, the episode table, the trajectory, the latency reports, the
//! logs and three pictures; `runs/latest` points at the newest, and `keep_runs` bounds how
//! many are kept.
//!
//! Each group runs under its own data directory and service prefix; a guard kills the
//! launcher (its children die with it) even when the test fails.

use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::common::*;

/// A launch file with its own service prefix, no fixed run folder, and `extra`.
fn launch_file_with_runs(extra: &str) -> String {
    format!(
        "[launch]\nservice_prefix = \"tes-test/{}/runs/\"\n{extra}",
        std::process::id()
    )
}

fn launch(dir: &Path, config: &Path, episodes: u32) -> Vec<String> {
    let mut group = Group::start_with(dir, config, episodes);
    let (ok, out, err) = group.finish(Duration::from_secs(120));
    assert!(ok, "stdout {out:?}\nstderr {err:?}");
    assert!(!group.children_alive());
    // iceoryx2 is given its configuration: its "no config file" warning never shows.
    assert!(
        !err.iter()
            .chain(&out)
            .any(|l| l.contains("No config file was loaded")),
        "{err:?}"
    );
    out
}

fn csv_rows(path: &Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.lines()
        .map(|l| l.split(',').map(str::to_owned).collect())
        .collect()
}

/// The run folder's episodes.csv has one row per episode, each with why it ended and its
/// decision latency, and trajectory.csv one row per action whose rewards add up to them.
fn episodes_and_trajectory_agree(last: &Path) {
    let episodes = csv_rows(&last.join("episodes.csv"));
    assert_eq!(
        episodes[0].join(","),
        "episode,reward,steps,end,decision_p50_us,decision_p99_us,decision_max_us,misses"
    );
    assert_eq!(episodes.len(), 4, "{episodes:?}");
    let ends = ["ball", "death-spot", "left-arena", "stuck", "step-cap"];
    let mut steps = 0;
    for (i, row) in episodes[1..].iter().enumerate() {
        assert_eq!(row[0], i.to_string());
        assert!(ends.contains(&row[3].as_str()), "{row:?}");
        let (p50, p99, max): (u64, u64, u64) = (
            row[4].parse().unwrap(),
            row[5].parse().unwrap(),
            row[6].parse().unwrap(),
        );
        assert!(p50 > 0 && p50 <= p99 && p99 <= max, "{row:?}");
        steps += row[2].parse::<usize>().unwrap();
    }
    // One row per action, and the episodes' rewards add up from them.
    let trajectory = csv_rows(&last.join("trajectory.csv"));
    assert_eq!(trajectory.len() - 1, steps);
    let reward_column = trajectory[0].iter().position(|c| c == "reward").unwrap();
    let action_column = trajectory[0].iter().position(|c| c == "action").unwrap();
    for (i, row) in episodes[1..].iter().enumerate() {
        let sum: f64 = trajectory[1..]
            .iter()
            .filter(|r| r[0] == i.to_string())
            .map(|r| r[reward_column].parse::<f64>().unwrap())
            .sum();
        let reported: f64 = row[1].parse().unwrap();
        assert!(
            (sum - reported).abs() < 0.006,
            "episode {i}: {sum} vs {reported}"
        );
    }
    assert!(
        trajectory[1..]
            .iter()
            .all(|r| ["0", "1", "2"].contains(&r[action_column].as_str())),
        "every action is one of the three"
    );
}

#[test]
fn a_launch_leaves_a_run_folder_with_tables_reports_logs_and_pictures() {
    let dir = tempfile::tempdir().expect("temp dir");
    let runs = dir.path().join("data/runs");
    let config = dir.path().join("launch.toml");
    std::fs::write(&config, launch_file_with_runs("keep_runs = 2\n")).expect("launch file");

    let mut folders: Vec<PathBuf> = Vec::new();
    for round in 0..3 {
        let out = launch(dir.path(), &config, 3);
        let said = out
            .iter()
            .find_map(|l| l.strip_prefix("launch: run folder "))
            .unwrap_or_else(|| panic!("no run folder line: {out:?}"));
        let folder = PathBuf::from(said);
        assert_eq!(folder.parent(), Some(runs.as_path()), "{out:?}");
        assert!(
            out.iter()
                .any(|l| l.contains("rewards.svg, latency.svg, arena.svg")),
            "{out:?}"
        );
        assert_eq!(
            std::fs::read_link(runs.join("latest")).expect("latest"),
            folder.file_name().expect("named")
        );
        folders.push(folder);
        let kept = std::fs::read_dir(&runs)
            .expect("runs")
            .filter_map(Result::ok)
            .filter(|e| e.file_type().is_ok_and(|t| t.is_dir()))
            .count();
        assert_eq!(kept, (round + 1).min(2), "keep_runs = 2");
    }
    assert!(!folders[0].exists(), "the oldest run folder was removed");
    assert!(folders[1].exists() && folders[2].exists());

    let last = &folders[2];
    for file in [
        "launch.toml",
        "controller.toml",
        "bridge.toml",
        "perception-sim.toml",
        "controller.out",
        "controller.log",
        "bridge.log",
        "perception-sim.log",
        "controller-report.json",
        "bridge-report.json",
    ] {
        assert!(last.join(file).is_file(), "{file} in {}", last.display());
    }

    episodes_and_trajectory_agree(last);

    // The pictures: the arena with the episodes' paths, rewards and latency per episode.
    let arena = std::fs::read_to_string(last.join("arena.svg")).expect("arena.svg");
    assert_eq!(arena.matches(r#"class="path""#).count(), 3);
    assert!(arena.contains(r#"class="ball""#) && arena.contains(r#"class="death""#));
    for picture in ["rewards.svg", "latency.svg"] {
        let svg = std::fs::read_to_string(last.join(picture)).expect(picture);
        assert!(
            svg.starts_with("<svg") && svg.contains("episode"),
            "{picture}"
        );
    }

    // The resolved launch file runs the same launch again.
    let resolved = std::fs::read_to_string(last.join("launch.toml")).expect("launch.toml");
    assert!(resolved.contains("keep_runs = 2"), "{resolved}");
    let again = launch(dir.path(), &last.join("launch.toml"), 2);
    assert!(
        again
            .iter()
            .any(|l| l.ends_with("2 episodes; all processes stopped cleanly")),
        "{again:?}"
    );
}

/// What a refused launch must leave as it was: the data directory's entries, the run folders
/// and where `runs/latest` points.
fn data_dir_state(data: &Path) -> (Vec<String>, Vec<String>, Option<PathBuf>) {
    let names = |dir: &Path| -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .map(|entries| {
                entries
                    .filter_map(Result::ok)
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .collect()
            })
            .unwrap_or_default();
        names.sort();
        names
    };
    let runs = data.join("runs");
    (
        names(data),
        names(&runs),
        std::fs::read_link(runs.join("latest")).ok(),
    )
}

/// A launch file with a service prefix of its own (the other tests of this file run beside
/// it with theirs), no fixed run folder, and `extra`.
fn refused_file(extra: &str) -> String {
    format!(
        "[launch]\nservice_prefix = \"tes-test/{}/refused/\"\n{extra}",
        std::process::id()
    )
}

/// Every refusal before the group runs — the live view without a terminal, a bad key, a brick
/// that is not there, a data directory in use — leaves the data directory, its run folders and
/// `runs/latest` exactly as they were, and says that nothing was started.
#[test]
fn a_refused_launch_leaves_the_data_directory_as_it_was() {
    let dir = tempfile::tempdir().expect("temp dir");
    let config = dir.path().join("launch.toml");
    std::fs::write(&config, refused_file("")).expect("launch file");
    launch(dir.path(), &config, 1);
    let data = dir.path().join("data");
    let before = data_dir_state(&data);
    assert_eq!(
        before.1.len(),
        2,
        "one run folder and latest (a clean exit leaves no lock): {before:?}"
    );

    let refused = |args: &[&str], file: &str| {
        let path = dir.path().join("refused.toml");
        std::fs::write(&path, refused_file(file)).expect("launch file");
        let out = tes_command()
            .arg("launch")
            .arg("--config")
            .arg(&path)
            .args(args)
            .env("TES_DATA_DIR", &data)
            .stdin(std::process::Stdio::null())
            .output()
            .expect("tes launch runs");
        let err = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(
            !out.status.success(),
            "{args:?} {file:?} was not refused: {err}"
        );
        assert!(
            err.contains("nothing was started"),
            "{args:?} {file:?}: {err}"
        );
        assert_eq!(data_dir_state(&data), before, "{args:?} {file:?}: {err}");
    };
    refused(&["--tui"], "");
    refused(&[], "[controller]\nbudget_us = \"soon\"\n");
    refused(
        &[],
        "[bridge]\ntransport = \"serial:/dev/no-such-nxt-brick\"\n",
    );
    // In use: a group of this data directory runs meanwhile.
    let running = Group::start_with(dir.path(), &config, 1000);
    // Once an episode has ended every process of the group holds what it holds for the run
    // (its role locks, the controller's library lock, the run folder): before that, the
    // snapshot could miss a file the group was about to make.
    running.wait_for_episodes(1, Duration::from_secs(60));
    let during = data_dir_state(&data);
    assert_ne!(
        during, before,
        "the running group shows in the data directory"
    );
    let path = dir.path().join("second.toml");
    std::fs::write(&path, refused_file("")).expect("launch file");
    let out = tes_command()
        .args(["launch", "--config"])
        .arg(&path)
        .env("TES_DATA_DIR", &data)
        .output()
        .expect("tes launch runs");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("in use"), "{err}");
    assert_eq!(data_dir_state(&data), during, "{err}");
    drop(running);
}
