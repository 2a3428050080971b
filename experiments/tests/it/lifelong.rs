//! The lifelong benchmark end to end on its quick configuration.

use tes_experiments::lifelong::{self, LifelongConfig};
use tes_experiments::report::Results;

#[test]
fn a_quick_lifelong_run_lives_the_sequence_with_every_method() {
    let dir = tempfile::tempdir().unwrap();
    let config = LifelongConfig::quick();
    let report = lifelong::run(&config, dir.path(), &|_, _| {}).unwrap();
    let tasks = config.rounds * config.worlds();
    assert_eq!(report.tasks(), tasks);
    // Each run lives a sequence of its own.
    assert_eq!(report.sequences.len(), config.runs);
    let orders: Vec<Vec<usize>> = report
        .sequences
        .iter()
        .map(|s| s.iter().map(|t| t.world).collect())
        .collect();
    assert_ne!(orders[0], orders[1]);
    for sequence in &report.sequences {
        assert_eq!(sequence.len(), tasks);
        assert!(
            sequence.iter().any(|t| !t.logistic),
            "a world that is not logistic"
        );
        assert!(sequence.iter().any(|t| t.gap.is_some()), "a return visit");
    }
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
    // The bounded libraries (with and without recency) hold at most M on average over the
    // runs (the library's own tests check the bound itself); the unbounded one ends with more.
    for bounded in ["TES", "TES-norecency"] {
        let sizes = &report.library_views[bounded];
        assert_eq!(sizes.len(), tasks);
        assert!(
            sizes
                .iter()
                .all(|s| s.mean <= config.max_views as f64 + 1e-9),
            "{bounded}: {sizes:?}"
        );
    }
    let bounded = &report.library_views["TES"];
    let unbounded = &report.library_views["TES-unbounded"];
    assert!(unbounded.last().unwrap().mean > bounded.last().unwrap().mean);
    // The ablation and the continual baseline are judged with the rest.
    assert_eq!(report.targets.len(), 11);
    for words in [
        "with μ = 0",
        "than loreRL-continual",
        "loreRL-continual accumulates",
    ] {
        assert!(
            report.targets.iter().any(|t| t.target.contains(words)),
            "{words}"
        );
    }
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
    // Each row's counts are the runs' own: logistic worlds and return visits at the position.
    for (position, line) in sequence.lines().skip(2).enumerate() {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        let at = || report.sequences.iter().map(move |s| &s[position]);
        assert_eq!(cells[1], (position + 1).to_string(), "{line}");
        assert_eq!(
            cells[2],
            at().filter(|t| t.logistic).count().to_string(),
            "{line}"
        );
        assert_eq!(
            cells[3],
            at().filter(|t| t.gap.is_some()).count().to_string(),
            "{line}"
        );
        let tes = report.per_task["TES"][position].mean;
        assert_eq!(cells[5], format!("{tes:.1}"), "{line}");
    }
    assert!(
        sequence.starts_with(&format!(
            "| task | logistic world (of {} runs) |",
            config.runs
        )),
        "{sequence}"
    );
}
