//! Sharding, merging and resuming: three shards merged give the unsharded run's summary
//! (timings aside), a resumed run too, and shards that overlap, miss jobs or come from
//! another run are refused with the reason.

use std::path::{Path, PathBuf};

use serde_json::Value;
use tes_experiments::jobs::{self, JobOptions, MergeError, Shard};
use tes_experiments::robot::{self, RobotConfig};
use tes_experiments::transfer::{self, TransferConfig};

/// Four runs: four jobs (a transfer job is a run, holding out every test task).
fn tiny_transfer() -> TransferConfig {
    TransferConfig {
        runs: 4,
        train_episodes: 3,
        test_episodes: 3,
        test_tasks: vec![1, 10],
        training_tasks: 2,
        random_combinations: 1,
        quick: true,
        ..TransferConfig::paper()
    }
}

/// `summary.json` of `dir` without what depends on the clock.
fn summary_without_timings(dir: &Path) -> Value {
    let path = dir.join("summary.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    jobs::summary_without_timings(&serde_json::from_str(&text).expect("summary.json is JSON"))
}

fn shard(k: usize, n: usize) -> JobOptions {
    JobOptions {
        shard: Shard { index: k, count: n },
        resume: false,
        // A test's runs are not results: they may come from a modified tree.
        allow_dirty: true,
    }
}

fn merge_error(dirs: &[PathBuf], out: &Path) -> MergeError {
    let err = jobs::merge(dirs, out).unwrap_err();
    err.downcast_ref::<MergeError>()
        .unwrap_or_else(|| panic!("not a merge refusal: {err:#}"))
        .clone()
}

#[test]
fn three_merged_shards_give_the_unsharded_summary_and_bad_sets_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let config = tiny_transfer();
    let whole = tmp.path().join("whole");
    transfer::run(&config, &whole, &|_, _| {}).unwrap();

    let shards: Vec<PathBuf> = (1..=3)
        .map(|k| tmp.path().join(format!("shard{k}")))
        .collect();
    for (k, dir) in shards.iter().enumerate() {
        let report = transfer::run_with(&config, dir, shard(k + 1, 3), &|_, _| {}).unwrap();
        assert!(report.is_none(), "a shard writes no summary");
        assert!(!dir.join("summary.json").exists());
    }
    let merged = tmp.path().join("merged");
    let manifest = jobs::merge(&shards, &merged).unwrap();
    assert_eq!((manifest.jobs, manifest.shard), (4, Shard::ALL));
    transfer::summarise_dir(&merged).unwrap();
    assert_eq!(
        summary_without_timings(&merged),
        summary_without_timings(&whole)
    );
    // Run 0's trained libraries come along.
    for task in [1, 10] {
        assert!(merged.join(format!("library-task{task}.tesl")).is_file());
    }

    // Overlapping: a shard given twice.
    let twice = [shards[0].clone(), shards[0].clone(), shards[1].clone()];
    assert!(matches!(
        merge_error(&twice, &tmp.path().join("m1")),
        MergeError::Overlapping { job: 0, .. }
    ));
    // Missing: shard 3 of 3 left out (jobs 2 of the 4).
    let missing = merge_error(&shards[..2], &tmp.path().join("m2"));
    assert!(
        matches!(&missing, MergeError::Missing { missing, .. } if missing == &[2]),
        "{missing}"
    );
    // Mismatched: a shard run with other seeds, other settings, or other code.
    let other_seed = tmp.path().join("other-seed");
    let reseeded = TransferConfig {
        seed: 7,
        ..config.clone()
    };
    transfer::run_with(&reseeded, &other_seed, shard(3, 3), &|_, _| {}).unwrap();
    let err = merge_error(
        &[shards[0].clone(), shards[1].clone(), other_seed],
        &tmp.path().join("m3"),
    );
    assert!(
        matches!(&err, MergeError::Mismatched { why, .. } if why.contains("seed 1 against 7")),
        "{err}"
    );
    let other_code = tmp.path().join("other-code");
    std::fs::create_dir_all(other_code.join("jobs")).unwrap();
    for entry in std::fs::read_dir(shards[2].join("jobs")).unwrap() {
        let entry = entry.unwrap();
        std::fs::copy(
            entry.path(),
            other_code.join("jobs").join(entry.file_name()),
        )
        .unwrap();
    }
    let mut m: Value =
        serde_json::from_str(&std::fs::read_to_string(shards[2].join("manifest.json")).unwrap())
            .unwrap();
    m["code_version"] = Value::from("0.0.0 (elsewhere)");
    std::fs::write(other_code.join("manifest.json"), m.to_string()).unwrap();
    let err = merge_error(
        &[shards[0].clone(), shards[1].clone(), other_code],
        &tmp.path().join("m4"),
    );
    assert!(
        matches!(&err, MergeError::Mismatched { why, .. } if why.contains("code version")),
        "{err}"
    );
    // Split differently: 1/3 with 2/2.
    let halves = tmp.path().join("half2");
    transfer::run_with(&config, &halves, shard(2, 2), &|_, _| {}).unwrap();
    let err = merge_error(&[shards[0].clone(), halves], &tmp.path().join("m5"));
    assert!(
        matches!(&err, MergeError::Mismatched { why, .. } if why.contains("shards")),
        "{err}"
    );
    assert!(matches!(
        merge_error(&[], &tmp.path().join("m6")),
        MergeError::Nothing
    ));
}

#[test]
fn a_resumed_run_gives_the_same_summary() {
    let tmp = tempfile::tempdir().unwrap();
    let config = RobotConfig {
        runs: 2,
        episodes: 3,
        train_episodes: 2,
        ..RobotConfig::quick()
    };
    let whole = tmp.path().join("whole");
    robot::run(&config, &whole, &|_, _| {}).unwrap();
    let before = summary_without_timings(&whole);
    // As if interrupted: some records never written, the summary never computed.
    for job in [0, 5, 13] {
        std::fs::remove_file(whole.join(format!("jobs/{job:05}.json"))).unwrap();
    }
    std::fs::remove_file(whole.join("summary.json")).unwrap();
    let seen = std::sync::Mutex::new(Vec::new());
    let resume = JobOptions {
        shard: Shard::ALL,
        resume: true,
        allow_dirty: true,
    };
    robot::run_with(&config, &whole, resume, &|done, total| {
        seen.lock().unwrap().push((done, total));
    })
    .unwrap();
    assert_eq!(summary_without_timings(&whole), before);
    let seen = seen.into_inner().unwrap();
    assert_eq!(seen[0], (11, 14), "progress starts at the jobs found");
    assert_eq!(seen.len(), 4);
    // A resume with other settings is refused.
    let other = RobotConfig { seed: 9, ..config };
    let err = robot::run_with(&other, &whole, resume, &|_, _| {}).unwrap_err();
    assert!(err.to_string().contains("another run"), "{err}");
}
