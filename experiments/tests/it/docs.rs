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
    use tes_experiments::prereg::{TARGETS, Target};
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/results");
    let family = |t: &Target| t.id.ends_with(".targets") || t.id == "transfer.pooled";
    let mut checked = 0;
    for entry in std::fs::read_dir(&root).unwrap() {
        let summary = entry.unwrap().path().join("summary.json");
        let Ok(text) = std::fs::read_to_string(&summary) else {
            continue;
        };
        let json: serde_json::Value = serde_json::from_str(&text).unwrap();
        let Some(targets) = json["targets"].as_array() else {
            continue;
        };
        for t in targets {
            let words = t["target"].as_str().unwrap();
            let experiment = summary
                .parent()
                .unwrap()
                .file_name()
                .unwrap()
                .to_string_lossy();
            let registered = TARGETS.iter().any(|r| {
                r.target == words
                    || r.history.iter().any(|h| h.target == words)
                    || (family(r)
                        && experiment.starts_with(r.experiment)
                        && (r.id != "transfer.pooled" || words.contains("across tasks")))
            });
            assert!(
                registered,
                "{}: {words:?} is not preregistered",
                summary.display()
            );
            checked += 1;
        }
    }
    assert!(checked >= 60, "only {checked} targets found");
}
