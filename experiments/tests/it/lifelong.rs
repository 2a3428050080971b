//! The lifelong benchmark end to end on its quick configuration.

use tes_experiments::lifelong::{self, LifelongConfig};
use tes_experiments::report::Results;

#[test]
fn a_quick_lifelong_run_lives_the_sequence_with_every_method() {
    let dir = tempfile::tempdir().unwrap();
    let config = LifelongConfig::quick();
    let report = lifelong::run(&config, dir.path(), &|_, _| {}).unwrap();
    let tasks = config.rounds * config.worlds();
    assert_eq!(report.sequence.len(), tasks);
    assert!(
        report.sequence.iter().any(|t| !t.logistic),
        "a world that is not logistic"
    );
    assert!(
        report.sequence.iter().any(|t| t.gap.is_some()),
        "a return visit"
    );
    for m in lifelong::METHODS {
        let runs = &report.runs[&*m.name()];
        assert_eq!(runs.len(), config.runs, "{m}");
        assert!(runs.iter().all(|r| r.len() == tasks), "{m}");
        assert!(
            runs[0].iter().all(|o| o.ends.len() == config.episodes),
            "{m}"
        );
        assert_eq!(report.per_task[&*m.name()].len(), tasks);
    }
    // The bounded library never holds more than M; the unbounded one ends with more.
    let bounded = &report.library_views["TES"];
    let unbounded = &report.library_views["TES-unbounded"];
    assert!(
        bounded
            .iter()
            .all(|s| s.hi <= config.max_views as f64 + 1e-9)
    );
    assert!(unbounded.last().unwrap().mean > bounded.last().unwrap().mean);
    for file in [
        "summary.json",
        "lifelong-reward.svg",
        "lifelong-lead.svg",
        "lifelong-library.svg",
    ] {
        assert!(dir.path().join(file).is_file(), "{file}");
    }
    let read = Results::read(dir.path()).unwrap();
    let sequence = read.table("sequence").unwrap();
    assert_eq!(sequence.lines().count(), 2 + tasks, "{sequence}");
}
