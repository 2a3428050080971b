//! The transfer experiment end to end on a tiny configuration: it trains a library, runs every
//! method on the held-out task, and writes consistent files.

use tes_experiments::transfer::{self, TransferConfig};

#[test]
fn a_tiny_transfer_run_writes_a_consistent_summary() {
    let dir = tempfile::tempdir().unwrap();
    let config = TransferConfig {
        runs: 2,
        train_episodes: 4,
        test_episodes: 3,
        test_tasks: vec![1],
        training_tasks: 2,
        random_combinations: 2,
        quick: true,
        ..TransferConfig::paper()
    };
    let report = transfer::run(&config, dir.path(), &|_, _| {}).unwrap();
    assert_eq!(report.tasks.len(), 1);
    let task = &report.tasks[0];
    assert_eq!((task.task, task.size.as_str()), (1, "20x20"));
    for method in ["TES", "LWT", "loreRL", "fEpsG", "Rands 1", "Rands 2"] {
        let j = task.jumpstart[method];
        assert_eq!(j.n, 2, "{method}");
        assert!(j.mean.is_finite() && j.lo <= j.mean && j.mean <= j.hi);
        assert!(report.seconds_per_episode[method].mean >= 0.0);
    }
    assert!(!task.difference_to_tes.contains_key("TES"));
    // Two training tasks, each adding at most one view per action.
    assert!(task.library_views.mean >= 1.0 && task.library_views.mean <= 8.0);
    // Runs record their seeds and training orders, which never include the test task.
    assert_eq!(task.runs.len(), 2);
    for r in &task.runs {
        assert_eq!(r.training_order.len(), 2);
        assert!(!r.training_order.contains(&1));
        assert_eq!(r.seed, transfer::job_seed(&config, 1, r.run));
    }
    for file in [
        "summary.json",
        "episodes.csv",
        "table2.svg",
        "fig4b-task1.svg",
    ] {
        assert!(dir.path().join(file).is_file(), "{file} written");
    }
    let csv = std::fs::read_to_string(dir.path().join("episodes.csv")).unwrap();
    // Header + 2 runs × 6 methods × 3 episodes.
    assert_eq!(csv.lines().count(), 1 + 2 * 6 * 3);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(json["config"]["runs"], 2);
    // Every run keeps each method's first and accumulated reward and how each episode ended,
    // which the claims are decided from.
    let run = &json["tasks"][0]["runs"][0]["methods"]["TES"];
    assert!(run["first"].is_f64() && run["accumulated"].is_f64());
    let ends = run["ends"].as_str().unwrap();
    assert_eq!(ends.len(), 3);
    assert!(ends.chars().all(|c| "gdc".contains(c)), "{ends}");
    let claim = &json["claims"]["jumpstart: TES − loreRL"];
    assert!(claim["tasks"]["1"]["p_holm"].is_f64(), "{claim}");
    assert!(claim["pooled"]["p"].is_f64(), "{claim}");
    // A quick run states each target's test but judges none.
    let targets = json["targets"].as_array().unwrap();
    assert_eq!(targets.len(), 8);
    for t in targets {
        assert!(!t["test"].as_str().unwrap().is_empty(), "{t}");
        assert_eq!(
            t["verdict"],
            tes_experiments::verdict::QUICK_RUN_NOTE,
            "{t}"
        );
    }
}

#[test]
fn bad_settings_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let no_task = TransferConfig {
        test_tasks: vec![15],
        ..TransferConfig::quick()
    };
    let err = transfer::run(&no_task, dir.path(), &|_, _| {}).unwrap_err();
    assert!(
        err.to_string().contains("test task 15 does not exist"),
        "{err}"
    );
    let no_training = TransferConfig {
        training_tasks: 0,
        ..TransferConfig::quick()
    };
    assert!(transfer::run(&no_training, dir.path(), &|_, _| {}).is_err());
}
