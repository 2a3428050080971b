//! The docs' generated tables say what their result folders hold: a number in
//! `docs/results.md` cannot drift from the committed `summary.json` it comes from.

use std::path::Path;

use tes_experiments::report;

#[test]
fn every_generated_block_of_the_results_page_holds() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let page = root.join("docs/results.md");
    let doc = std::fs::read_to_string(&page).unwrap();
    assert!(
        doc.contains(report::BEGIN),
        "the results page has generated blocks"
    );
    let stale = report::stale_blocks(&doc, &root).unwrap();
    assert!(
        stale.is_empty(),
        "run `tes experiment report --sync docs/results.md`: {stale:?}"
    );
}

/// docs/experiments.md is what `tes experiment settings` prints: the settings' table cannot
/// drift from the definitions the flags come from.
#[test]
fn the_settings_page_is_the_settings_definitions() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let page = std::fs::read_to_string(root.join("docs/experiments.md")).unwrap();
    assert_eq!(
        page,
        tes_experiments::study::settings_reference(),
        "run `tes experiment settings > docs/experiments.md`"
    );
}

/// Every target a committed folder judged is in the preregistration (`prereg.rs`): its current
/// form, an earlier form kept in its history, or the family entry of an experiment whose
/// targets the registry holds as one (Fig. 4, lifelong, the pooled transfer tests).
#[test]
fn every_committed_target_is_preregistered() {
    use tes_experiments::prereg::judged_by;
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/results");
    let mut checked = 0;
    for entry in std::fs::read_dir(&root).unwrap() {
        let dir = entry.unwrap().path();
        let summary = dir.join("summary.json");
        let Ok(text) = std::fs::read_to_string(&summary) else {
            continue;
        };
        let json: serde_json::Value = serde_json::from_str(&text).unwrap();
        let Some(targets) = json["targets"].as_array() else {
            continue;
        };
        let manifest: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap())
                .unwrap();
        let experiment = manifest["experiment"].as_str().unwrap();
        for t in targets {
            let words = t["target"].as_str().unwrap();
            assert!(
                judged_by(experiment, words).is_some(),
                "{}: {words:?} is not preregistered",
                summary.display()
            );
            checked += 1;
        }
    }
    assert!(checked >= 60, "only {checked} targets found");
}

/// The verdicts table of a folder beside its 100-run folder gives, row by row, the verdict
/// each folder's own `targets` and `claims` tables give: the page's overview of every claim
/// cannot say other than the folders' tables.
#[test]
fn the_verdicts_table_gives_each_folders_own_verdicts() {
    use tes_experiments::claims;
    use tes_experiments::report::{Request, Results};
    use tes_experiments::verdict::Verdict;
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/results");
    for name in ["grid", "transfer", "robot", "fig4"] {
        let (dir, other) = (root.join(name), root.join(format!("{name}-100")));
        let md = Request {
            dir: dir.clone(),
            table: Some("verdicts".into()),
            against: None,
            beside: Some(other.clone()),
        }
        .render(Path::new(""))
        .unwrap();
        assert!(md.contains("| target | 20 runs | 100 runs |"), "{md}");
        let rows: Vec<Vec<&str>> = md
            .lines()
            .filter(|l| l.starts_with("| ") && !l.starts_with("| target |"))
            .map(|l| l.trim_matches('|').split(" | ").map(str::trim).collect())
            .collect();
        let mut seen = 0;
        for (column, folder) in [dir, other].iter().enumerate() {
            let results = Results::read(folder).unwrap();
            let (own, claimed) = match &results {
                Results::Grid(g) => (g.targets.clone(), claims::grid(g)),
                Results::Transfer(t) => (t.targets.clone(), claims::transfer(t)),
                Results::Robot(r) => (r.targets.clone(), claims::robot(r)),
                Results::Fig4(f) => (f.targets.clone(), Vec::new()),
                Results::Lifelong(_) => unreachable!("{name} is not a lifelong folder"),
            };
            let judged =
                own.iter()
                    .map(|t| (t.target.clone(), t.verdict))
                    .chain(claimed.iter().map(|c| {
                        let label =
                            claims::label(Some(c.id), &c.check.target, c.stricter.as_deref());
                        (label, c.check.verdict)
                    }));
            for (target, verdict) in judged {
                let row = rows
                    .iter()
                    .find(|r| r[0] == target || r[0].ends_with(&format!(": {target}")))
                    .unwrap_or_else(|| panic!("{name}: no row for {target:?} in\n{md}"));
                let cell = row[1 + column];
                let expected = match verdict {
                    Verdict::NotRun => "—",
                    Verdict::Fails => "**fails**",
                    v => v.text(),
                };
                assert!(
                    cell.starts_with(expected),
                    "{name}, column {column}: {target:?} says {cell:?}, its folder {expected:?}"
                );
                seen += 1;
            }
        }
        assert!(seen >= 8, "{name}: only {seen} verdicts compared");
    }
}
