//! The end of a launch states the facts about the robot's view library — which file, what it
//! held before and after, whether it was saved, and how to look at it — and `tes library
//! show` with no path shows that library, its features and actions named.
//!
//! The group runs under its own iceoryx2 service prefix and data directory (`TES_DATA_DIR`),
//! and a guard kills the launcher (its children die with it) and cleans up even when the test
//! fails.

use std::path::Path;
use std::process::Output;
use std::time::Duration;

use crate::common::*;

/// `tes library ARGS` with the data directory `data`.
fn tes_library(data: &Path, args: &[&str]) -> Output {
    tes_command()
        .arg("library")
        .args(args)
        .env("TES_DATA_DIR", data)
        .output()
        .expect("tes library runs")
}

/// Runs a group of `episodes` to its end; returns its standard output, checked to end with
/// the library's line, the hint to see its views, and the clean stop.
fn launch(dir: &Path, episodes: u32) -> Vec<String> {
    let mut group = Group::start(dir, &launch_file(dir, ""), episodes);
    let (ok, out, err) = group.finish(Duration::from_secs(120));
    assert!(ok, "stdout {out:?}\nstderr {err:?}");
    let n = out.len();
    assert!(n >= 3, "{out:?}");
    assert!(
        out[n - 1].contains(&format!(
            "launch: {episodes} episodes; all processes stopped cleanly"
        )),
        "{out:?}"
    );
    assert_eq!(
        out[n - 2],
        "launch: see its views with `tes library show`",
        "{out:?}"
    );
    assert!(!group.children_alive());
    out
}

/// The line saying what the launch did to the library.
fn library_line(out: &[String]) -> &str {
    out.iter()
        .find(|l| l.starts_with("launch: library "))
        .unwrap_or_else(|| panic!("no library line in {out:?}"))
}

/// "N views, M tasks" (or "1 view, 1 task") → (N, M).
fn counts(text: &str) -> (usize, u32) {
    let numbers: Vec<u64> = text
        .split(|c: char| !c.is_ascii_digit())
        .filter_map(|w| w.parse().ok())
        .collect();
    assert_eq!(numbers.len(), 2, "{text:?}");
    (numbers[0] as usize, numbers[1] as u32)
}

/// No library yet: `show` and `export` without a path say so and fail.
fn no_library_yet_is_said(data: &Path, library: &Path) {
    for args in [&["show"][..], &["export", "--json"]] {
        let none = tes_library(data, args);
        let err = String::from_utf8_lossy(&none.stderr);
        assert!(!none.status.success(), "{args:?}: {err}");
        assert!(
            err.contains(&format!("no library at {} yet", library.display()))
                && err.contains("run `tes launch` first"),
            "{args:?}: {err}"
        );
        assert!(none.stdout.is_empty(), "{args:?}");
    }
}

/// The arena's actions, as `tes library show` names them.
const ACTIONS: [&str; 3] = [
    "forward (both wheels 246°)",
    "spin right (left 90°, right -90°)",
    "pivot right (left 90°, right 0°)",
];

/// Checks that `tes library show`'s `text` names every view's action and every selected
/// feature; returns the view lines.
fn views_and_names_shown(text: &str) -> Vec<&str> {
    let view_lines: Vec<&str> = text
        .lines()
        .filter(|l| {
            l.strip_prefix("view ")
                .is_some_and(|r| r.starts_with(|c: char| c.is_ascii_digit()))
        })
        .collect();
    assert!(!view_lines.is_empty(), "{text}");
    for line in &view_lines {
        assert!(
            ACTIONS
                .iter()
                .enumerate()
                .any(|(a, name)| line.contains(&format!("action {a} ({name})"))),
            "an unnamed action: {line}"
        );
    }
    // Every selected feature is shown by its name, none by its bare number.
    let features: Vec<&str> = text
        .lines()
        .filter_map(|l| l.trim().strip_prefix("selected features ("))
        .filter_map(|l| l.split_once("): ").map(|(_, names)| names))
        .filter(|names| *names != "none")
        .flat_map(|names| names.split(", "))
        .collect();
    assert!(!features.is_empty(), "no view selected a feature: {text}");
    for name in features {
        assert!(
            name.contains(" ring ") || name.starts_with("facing ") || name.ends_with("in cell"),
            "an unnamed feature {name:?}: {text}"
        );
    }

    view_lines
}

#[test]
fn a_launch_states_the_library_facts_and_tes_library_show_finds_the_library() {
    let dir = tempfile::tempdir().expect("temp dir");
    let data = dir.path().join("data");
    let library = data.join("library.tesl");

    no_library_yet_is_said(&data, &library);

    // The first launch starts empty and saves.
    let out = launch(dir.path(), 3);
    let first = library_line(&out);
    let start = format!(
        "launch: library {}: started empty (no library file yet) -> ",
        library.display()
    );
    assert!(
        first.starts_with(&start) && first.ends_with(" (saved)"),
        "{first}"
    );
    let after_first = counts(&first[start.len()..]);
    assert!(after_first.0 > 0, "{first}");
    assert_eq!(after_first.1, 1, "one task per run: {first}");

    // The second starts from what the first saved and adds its task.
    let out = launch(dir.path(), 3);
    let second = library_line(&out);
    let prefix = format!("launch: library {}: ", library.display());
    let (before, after) = second
        .strip_prefix(&prefix)
        .and_then(|rest| rest.strip_suffix(" (saved)"))
        .and_then(|rest| rest.split_once(" -> "))
        .unwrap_or_else(|| panic!("not `{prefix}BEFORE -> AFTER (saved)`: {second}"));
    assert_eq!(counts(before), after_first, "{second}");
    assert_eq!(counts(after).1, 2, "{second}");

    // `show` without a path shows that library, its actions and features named.
    let shown = tes_library(&data, &["show"]);
    let text = String::from_utf8_lossy(&shown.stdout);
    assert!(
        shown.status.success(),
        "{text}\n{}",
        String::from_utf8_lossy(&shown.stderr)
    );
    assert!(
        text.starts_with(&format!("view library {}", library.display())),
        "{text}"
    );
    assert!(
        text.contains("world: arena 3; 3 actions, 20 effects, 312 features"),
        "{text}"
    );
    assert!(
        text.contains(&format!("{} views", counts(after).0)),
        "{text}"
    );
    let view_lines = views_and_names_shown(&text);

    // `export` without a path: the same library, names included; JSON with or without the
    // flag.
    let exported = tes_library(&data, &["export"]);
    assert!(exported.status.success());
    assert_eq!(
        tes_library(&data, &["export", "--json"]).stdout,
        exported.stdout
    );
    let json: serde_json::Value = serde_json::from_slice(&exported.stdout).expect("JSON");
    assert_eq!(json["file"], library.display().to_string());
    let views = json["views"].as_array().expect("views");
    assert_eq!(views.len(), view_lines.len());
    assert!(
        views.iter().all(|v| v["action_name"]
            .as_str()
            .is_some_and(|n| ACTIONS.contains(&n))),
        "{json}"
    );
}
