//! `tes launch --print-config`: the launch file of the defaults, every key commented, and the
//! reference page `docs/config.md`, both from launch/src/reference.rs. (The checks that
//! need the launcher's own types — the `[launch]` table, the keys unset by default — are the
//! unit tests beside that file.)

use std::path::{Path, PathBuf};
use std::time::Duration;

use tes_bridge::config::BridgeSettings;
use tes_controller::config::ControllerConfig;
use tes_perception_sim::process::PerceptionConfig;
use tes_runtime::settings::Origin;

use crate::common::{Group, tes};

/// How to bring docs/config.md up to date, as the failing test says.
const REGENERATE: &str = "cargo run -p tes -- launch --print-config=markdown > docs/config.md \
                          (or: TES_UPDATE_DOCS=1 cargo test -p tes --test it config_reference)";

/// What `tes launch <flag>` prints; it must exit 0 and say nothing on stderr.
fn printed(flag: &str) -> String {
    let out = tes(&["launch", flag]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{flag}: {:?}: {stderr}", out.status);
    assert!(stderr.is_empty(), "{flag}: {stderr}");
    String::from_utf8(out.stdout).expect("UTF-8")
}

/// The table `name` of a launch file, as a document of its own.
fn table(doc: &toml::Table, name: &str) -> String {
    let value = doc.get(name).unwrap_or_else(|| panic!("no [{name}] table"));
    toml::to_string(value).expect("serialises")
}

/// The printed file is TOML of the four tables, each child's table reading back as its
/// process's defaults.
#[test]
fn the_printed_file_is_toml_of_the_defaults() {
    let text = printed("--print-config");
    assert_eq!(text, printed("--print-config=toml"));
    let doc: toml::Table = toml::from_str(&text).unwrap_or_else(|e| panic!("{e}\n{text}"));
    let tables: Vec<&str> = doc.keys().map(String::as_str).collect();
    assert_eq!(tables, ["bridge", "controller", "launch", "perception"]);
    let perception = PerceptionConfig::from_toml(&table(&doc, "perception")).expect("reads");
    assert_eq!(perception, PerceptionConfig::default());
    let controller = ControllerConfig::from_toml(&table(&doc, "controller")).expect("reads");
    assert_eq!(controller, ControllerConfig::default());
    let bridge = BridgeSettings::from_toml_in(&table(&doc, "bridge"), Origin::Text);
    assert_eq!(bridge.expect("reads"), BridgeSettings::default());
}

/// The section of the reference page for `table`.
fn section<'a>(md: &'a str, table: &str) -> &'a str {
    let header = [
        format!("\n## `[{table}]`\n"),
        format!("\n## `[[{table}]]`\n"),
    ]
    .into_iter()
    .find_map(|h| md.find(&h))
    .unwrap_or_else(|| panic!("no section for [{table}]"));
    let rest = &md[header + 1..];
    let end = rest[1..].find("\n## ").map_or(rest.len(), |e| e + 1);
    &rest[..end]
}

/// The dotted tables and keys of a serialised default (`table` is where it is).
fn keys(table: &str, value: &toml::Value, out: &mut Vec<(String, String)>) {
    let entries: Vec<&toml::Table> = match value {
        toml::Value::Table(t) => vec![t],
        toml::Value::Array(items) => items.iter().filter_map(|v| v.as_table()).collect(),
        _ => Vec::new(),
    };
    for entry in entries {
        for (name, v) in entry {
            let nested = v.is_table()
                || v.as_array()
                    .is_some_and(|a| !a.is_empty() && a.iter().all(|i| i.is_table()));
            if nested {
                keys(&format!("{table}.{name}"), v, out);
            } else {
                out.push((table.to_owned(), name.clone()));
            }
        }
    }
}

/// Every key of the children's config structs (as their defaults serialise) has a row in its
/// table's section of the reference page, and a line in the printed file.
#[test]
fn every_key_of_the_childrens_settings_is_in_the_reference() {
    let md = printed("--print-config=markdown");
    let text = printed("--print-config");
    let mut all = Vec::new();
    let values = [
        (
            "perception",
            toml::Value::try_from(PerceptionConfig::default()),
        ),
        (
            "controller",
            toml::Value::try_from(ControllerConfig::default()),
        ),
        ("bridge", toml::Value::try_from(BridgeSettings::default())),
    ];
    for (table, value) in values {
        keys(table, &value.expect("serialises"), &mut all);
    }
    assert!(all.len() > 80, "{all:?}");
    let missing: Vec<String> = all
        .iter()
        .filter(|(table, key)| {
            let described = section(&md, table).contains(&format!("\n| `{key}` |"));
            let written = text.lines().any(|l| {
                l.starts_with(&format!("{key} = ")) || l.starts_with(&format!("# {key} = "))
            });
            !(described && written)
        })
        .map(|(table, key)| format!("[{table}] {key}"))
        .collect();
    assert!(
        missing.is_empty(),
        "not in the reference: {missing:?}; describe them in KEYS of \
         launch/src/reference.rs, then {REGENERATE}"
    );
    assert!(!md.contains("Not described yet"), "{REGENERATE}");
}

/// docs/config.md is what the code generates.
#[test]
fn docs_config_md_is_the_generated_reference() {
    let generated = printed("--print-config=markdown");
    let path: PathBuf = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/config.md");
    if std::env::var_os("TES_UPDATE_DOCS").is_some_and(|v| v == "1") {
        std::fs::write(&path, &generated).expect("docs/config.md written");
    }
    let on_disk = std::fs::read_to_string(&path).unwrap_or_default();
    if on_disk != generated {
        let line = on_disk
            .lines()
            .zip(generated.lines())
            .position(|(a, b)| a != b)
            .unwrap_or_else(|| on_disk.lines().count().min(generated.lines().count()));
        panic!(
            "docs/config.md is not the reference the code generates (first difference at line \
             {}: {:?}); regenerate it: {REGENERATE}",
            line + 1,
            generated.lines().nth(line)
        );
    }
}

/// A format it does not know, or `--print-config` with a launch file or episodes, is a usage
/// error that prints nothing on stdout.
#[test]
fn print_config_refuses_an_unknown_format_and_other_flags() {
    for args in [
        &["launch", "--print-config=yaml"][..],
        &["launch", "--print-config", "--config", "launch.toml"],
        &["launch", "--print-config", "--episodes", "2"],
    ] {
        let out = tes(args);
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        assert!(out.stdout.is_empty(), "{args:?}");
    }
    let out = tes(&["launch", "--print-config=yaml"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("toml") && stderr.contains("markdown"),
        "{stderr}"
    );
}

/// Fed back to `tes launch --config`, the printed file runs a group to the end.
#[test]
fn the_printed_file_launches_a_group() {
    let dir = tempfile::tempdir().expect("temp dir");
    let text = printed("--print-config");
    let mut group = Group::start(dir.path(), &text, 1);
    let (ok, out, err) = group.finish(Duration::from_secs(120));
    assert!(ok, "stdout: {out:?}\nstderr: {err:?}");
    assert!(out.iter().any(|l| l.starts_with("episode ")), "{out:?}");
}
