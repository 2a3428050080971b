//! Every figure of every experiment, from tiny quick runs: one colour per method across all of
//! them, Table 2 drawn as categories, and no verdict on the paper's targets from a quick run.

use std::collections::BTreeMap;
use std::fs;
use std::path::Path;

use tes_experiments::grid::{self, GridConfig};
use tes_experiments::replot::replot;
use tes_experiments::robot::{self, RobotConfig};
use tes_experiments::svg::{colour_problems, drawn_series};
use tes_experiments::transfer::{self, TransferConfig};
use tes_experiments::verdict::{QUICK_RUN_NOTE, Verdict};

/// The three experiments, each on a tiny quick configuration, into `dir/{grid,transfer,robot}`.
fn run_all(dir: &Path) {
    let grid = GridConfig {
        runs: 1,
        episodes: 2,
        ..GridConfig::quick()
    };
    let report = grid::run(&grid, &dir.join("grid"), &|_, _| {}).unwrap();
    assert!(
        report
            .targets
            .iter()
            .all(|t| t.verdict == Verdict::QuickRun)
    );
    let transfer = TransferConfig {
        runs: 1,
        train_episodes: 2,
        test_episodes: 2,
        test_tasks: vec![1, 10],
        training_tasks: 1,
        ..TransferConfig::quick()
    };
    let report = transfer::run(&transfer, &dir.join("transfer"), &|_, _| {}).unwrap();
    assert!(
        report
            .targets
            .iter()
            .all(|t| t.verdict == Verdict::QuickRun)
    );
    let robot = RobotConfig {
        runs: 1,
        episodes: 2,
        train_episodes: 1,
        ..RobotConfig::quick()
    };
    let report = robot::run(&robot, &dir.join("robot"), &|_, _| {}).unwrap();
    assert!(
        report
            .targets
            .iter()
            .all(|t| t.verdict == Verdict::QuickRun)
    );
}

/// Every `.svg` under `dir`, by path relative to it.
fn figures(dir: &Path) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    for sub in ["grid", "transfer", "robot"] {
        for entry in fs::read_dir(dir.join(sub)).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "svg") {
                let name = format!("{sub}/{}", path.file_name().unwrap().to_string_lossy());
                out.insert(name, fs::read_to_string(&path).unwrap());
            }
        }
    }
    out
}

#[test]
fn quick_runs_draw_every_method_in_its_one_colour_and_give_no_verdicts() {
    let dir = tempfile::tempdir().unwrap();
    run_all(dir.path());
    let figures = figures(dir.path());
    for expected in [
        "grid/fig3a.svg",
        "grid/fig3b.svg",
        "grid/fig3c.svg",
        "transfer/table2.svg",
        "transfer/fig4b-task1.svg",
        "transfer/fig4b-task10.svg",
        "robot/fig8.svg",
        "robot/fig9.svg",
    ] {
        assert!(figures.contains_key(expected), "{expected} written");
    }

    // One colour per method across all figures; no two methods of a figure share one.
    let mut colour_of: BTreeMap<String, (String, String)> = BTreeMap::new();
    for (figure, svg) in &figures {
        let drawn = drawn_series(svg);
        assert!(drawn.len() >= 2, "{figure} draws its methods");
        assert_eq!(colour_problems(&drawn), Vec::<String>::new(), "{figure}");
        for d in &drawn {
            let (first_figure, colour) = colour_of
                .entry(d.name.clone())
                .or_insert_with(|| (figure.clone(), d.colour.clone()));
            assert_eq!(
                colour, &d.colour,
                "{} in {first_figure} and {figure}",
                d.name
            );
        }
    }
    // Methods drawn by more than one experiment: loreRL everywhere, fEpsG, LWT, TES, fRmax.
    for name in ["loreRL", "fEpsG", "fRmax", "LWT"] {
        let in_figures = figures
            .values()
            .filter(|svg| drawn_series(svg).iter().any(|d| d.name == name))
            .count();
        assert!(in_figures >= 2, "{name} drawn in {in_figures} figures");
    }

    // Table 2 plots tasks as categories: nothing joins them, unrun tasks are marked.
    let table2 = &figures["transfer/table2.svg"];
    for shape in ["<polyline", "<path", "<polygon"] {
        assert!(!table2.contains(shape), "table2.svg draws a {shape}");
    }
    assert_eq!(table2.matches("<g class=\"category\"").count(), 15);
    assert_eq!(table2.matches(">not run</text>").count(), 13);

    // Quick runs record that they are too small to judge, never that a target fails.
    for sub in ["grid", "transfer", "robot"] {
        let summary = fs::read_to_string(dir.path().join(sub).join("summary.json")).unwrap();
        assert!(!summary.contains("does not hold"), "{sub}");
        assert!(!summary.contains("\"holds\""), "{sub}");
        assert!(summary.contains(QUICK_RUN_NOTE), "{sub}");
    }
}

#[test]
fn replotting_a_run_redraws_its_summary_figures_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("transfer");
    let config = TransferConfig {
        runs: 2,
        train_episodes: 2,
        test_episodes: 2,
        test_tasks: vec![2],
        training_tasks: 1,
        ..TransferConfig::quick()
    };
    transfer::run(&config, &out, &|_, _| {}).unwrap();
    let drawn = fs::read_to_string(out.join("table2.svg")).unwrap();
    fs::remove_file(out.join("table2.svg")).unwrap();
    let done = replot(&out).unwrap();
    assert_eq!(done.written, vec![out.join("table2.svg")]);
    assert_eq!(fs::read_to_string(out.join("table2.svg")).unwrap(), drawn);

    let out = dir.path().join("grid");
    let config = GridConfig {
        runs: 2,
        episodes: 2,
        ..GridConfig::quick()
    };
    grid::run(&config, &out, &|_, _| {}).unwrap();
    let drawn = fs::read_to_string(out.join("fig3c.svg")).unwrap();
    replot(&out).unwrap();
    assert_eq!(fs::read_to_string(out.join("fig3c.svg")).unwrap(), drawn);
}
