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
