//! The robot experiment end to end on a tiny configuration.

use tes_experiments::robot::{self, RobotConfig};

#[test]
fn a_tiny_robot_run_writes_every_method_and_file() {
    let dir = tempfile::tempdir().unwrap();
    let config = RobotConfig {
        runs: 2,
        episodes: 3,
        train_episodes: 2,
        quick: true,
        ..RobotConfig::paper()
    };
    let report = robot::run(&config, dir.path(), &|_, _| {}).unwrap();
    for m in [
        "TES",
        "TES-woRi",
        "LWT",
        "loreRL",
        "man-loreRL",
        "fRmax",
        "fEpsG",
    ] {
        let a = report.accumulated[m];
        assert_eq!(a.n, 2, "{m}");
        assert!(a.mean.is_finite());
        assert_eq!(report.first_episode[m].len(), 2);
    }
    assert!(!report.difference_to_tes.contains_key("TES"));
    for file in ["summary.json", "episodes.csv", "fig8.svg", "fig9.svg"] {
        assert!(dir.path().join(file).is_file(), "{file}");
    }
    let csv = std::fs::read_to_string(dir.path().join("episodes.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 7 * 2 * 3);
}
