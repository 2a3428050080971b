//! Fig. 4a and Fig. 4c end to end on their quick configuration.

use tes_experiments::fig4::{self, Fig4Config};
use tes_experiments::report::Results;
use tes_experiments::verdict::Verdict;

#[test]
fn a_quick_fig4_run_keeps_every_run_and_reads_back_as_its_report() {
    let dir = tempfile::tempdir().unwrap();
    let config = Fig4Config::quick();
    let report = fig4::run(&config, dir.path(), &|_, _| {}).unwrap();
    assert_eq!(report.same_dynamics.len(), config.pairs.len());
    let pair = &report.same_dynamics[0];
    assert_eq!(pair.trained_on, [config.pairs[0].0]);
    assert_eq!(
        pair.test_task % 3,
        pair.trained_on[0] % 3,
        "the same dynamics set"
    );
    for m in fig4::FIG4A_METHODS {
        let runs = &pair.runs[&*m.name()];
        assert_eq!(runs.len(), config.runs, "{m}");
        // Each episode's reward is kept: the early-episode claims are made from them.
        let rewards = runs[0].rewards.as_ref().expect("rewards kept");
        assert_eq!(rewards.len(), config.test_episodes);
        assert!((rewards.iter().sum::<f64>() - runs[0].accumulated).abs() < 1e-9);
    }
    for m in fig4::FIG4C_METHODS {
        let runs = &report.convergence.runs[&*m.name()];
        assert_eq!(runs[0].ends.len(), config.convergence_episodes, "{m}");
    }
    // TES's library in the long run came from the other tasks, never the test task.
    assert!(
        !report
            .convergence
            .trained_on
            .contains(&config.convergence_task)
    );
    assert_eq!(
        report.convergence.trained_on.len(),
        config.convergence_training_tasks
    );
    assert_eq!(report.targets.len(), 4);
    assert!(
        report
            .targets
            .iter()
            .all(|t| t.verdict == Verdict::QuickRun)
    );
    for file in [
        "summary.json",
        "episodes.csv",
        "fig4c.svg",
        "fig4a-task1.svg",
    ] {
        assert!(dir.path().join(file).is_file(), "{file}");
    }
    // The summary reads back, and its tables come from it.
    let read = Results::read(dir.path()).unwrap();
    for table in read.table_names() {
        assert!(!read.table(table).unwrap().is_empty(), "{table}");
    }
    // Summarising the records again gives the same numbers.
    let again = fig4::summarise_dir(dir.path()).unwrap();
    assert_eq!(
        serde_json::to_value(&again.targets).unwrap(),
        serde_json::to_value(&report.targets).unwrap()
    );
}
