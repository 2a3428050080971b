//! The `tes` command line, run as a user would.

use std::path::{Path, PathBuf};

use tes_experiments::jobs::summary_without_timings;

use crate::common::*;

fn demo_csv() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/fit-demo.csv")
}

fn write(dir: &tempfile::TempDir, name: &str, text: &str) -> String {
    let path = dir.path().join(name);
    std::fs::write(&path, text).expect("temp file");
    path.to_string_lossy().into_owned()
}

#[test]
fn fit_json_on_the_demo_stream_finds_its_relevant_columns() {
    let demo = demo_csv();
    let out = tes(&["fit", demo.to_str().expect("utf-8 path"), "--json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8(out.stdout).expect("utf-8");
    assert_eq!(stdout.trim().lines().count(), 1, "exactly one JSON line");
    let report: serde_json::Value = serde_json::from_str(&stdout).expect("one JSON object");
    for key in [
        "n",
        "mean_logloss",
        "accuracy",
        "selected",
        "updates_per_sec",
    ] {
        assert!(report.get(key).is_some(), "missing {key}");
    }
    assert_eq!(report["n"], 4000);
    // data/README.md: seed 2017 → bias column 0 and relevant columns 125, 174, 175.
    assert_eq!(report["selected"], serde_json::json!([0, 125, 174, 175]));
    let loss = report["mean_logloss"].as_f64().expect("number");
    assert!(
        loss > 0.0 && loss < 5f64.ln(),
        "better than uniform: {loss}"
    );
    assert!(report["updates_per_sec"].as_f64().expect("number") > 0.0);
}

/// `--lambda auto --alpha auto` races the grid on the demo stream: the text names the
/// choice and the runner-up, the JSON every setting's standing, and the winner keeps the
/// demo's relevant columns; a bad value is refused naming both forms.
#[test]
fn fit_auto_races_the_grid_and_says_what_won() {
    let demo = demo_csv();
    let demo = demo.to_str().expect("utf-8 path");
    let out = tes(&["fit", demo, "--lambda", "auto", "--alpha", "auto"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("lambda = auto (chose "), "{text}");
    assert!(text.contains("alpha = auto (chose "), "{text}");
    assert!(
        text.contains("raced 15 settings in one pass; the runner-up, lambda = "),
        "{text}"
    );
    let out = tes(&["fit", demo, "--lambda", "auto", "--json"]);
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON object");
    let standings = report["auto"]["standings"].as_array().expect("standings");
    assert_eq!(standings.len(), 5, "λ alone is raced: {report}");
    assert_eq!(report["auto"]["alpha"], "1.5");
    assert_eq!(report["lambda"], standings[0]["lambda"]);
    let selected = report["selected"].as_array().expect("selected");
    for column in [125, 174, 175] {
        assert!(selected.contains(&serde_json::json!(column)), "{report}");
    }
    // One thread or three: the same fit.
    let json = |threads: &str| {
        let out = tes(&[
            "fit",
            demo,
            "--lambda",
            "auto",
            "--json",
            "--threads",
            threads,
        ]);
        let mut report: serde_json::Value =
            serde_json::from_slice(&out.stdout).expect("one JSON object");
        report["updates_per_sec"] = serde_json::Value::Null;
        report
    };
    assert_eq!(json("1"), json("3"));
    let out = tes(&["fit", demo, "--lambda", "small"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("expected a number or `auto`"), "{err}");
    let out = tes(&["fit", demo, "--lambda", "auto", "--threads", "0"]);
    assert!(!out.status.success(), "no threads is refused");
}

#[test]
fn fit_text_report_names_what_it_found() {
    let dir = tempfile::tempdir().expect("temp dir");
    // Feature 1 decides the class; feature 0 is noise. Real values → dense path.
    let mut text = String::new();
    for t in 0..400 {
        let on = t % 2;
        text.push_str(&format!("{on},{}.5,{on}\n", t % 3));
    }
    let path = write(&dir, "tiny.csv", &text);
    let out = tes(&["fit", &path, "--lambda", "0.01", "--intercept"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("400 rows"), "{stdout}");
    assert!(stdout.contains("prequential accuracy"), "{stdout}");
    assert!(stdout.contains("dense path"), "{stdout}");
}

/// `tes fit` with JSON output over `input`, fed `stdin` (nothing when `None`); the report.
fn fit_json(input: &str, stdin: Option<&[u8]>) -> serde_json::Value {
    let mut command = tes_command();
    command.args(["fit", input, "--json"]);
    let out = run_with_stdin(command, stdin.unwrap_or_default());
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("one JSON object")
}

/// Runs `command` with `stdin` written to its standard input; its output.
fn run_with_stdin(mut command: std::process::Command, stdin: &[u8]) -> std::process::Output {
    use std::io::Write;
    use std::process::Stdio;
    let mut child = command
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the tes binary runs");
    let mut pipe = child.stdin.take().expect("stdin piped");
    let bytes = stdin.to_vec();
    // Written from another thread, so a child that stops reading early cannot block us.
    let writer = std::thread::spawn(move || pipe.write_all(&bytes));
    let out = child.wait_with_output().expect("tes ends");
    let _ = writer.join();
    out
}

/// The demo stream as sparse `label column:1 …` rows.
fn as_sparse_rows(csv: &str) -> String {
    csv.lines()
        .map(|line| {
            let mut fields = line.split(',');
            let label = fields.next().unwrap_or_default();
            let on: Vec<String> = fields
                .enumerate()
                .filter(|(_, v)| *v == "1")
                .map(|(c, _)| format!("{c}:1"))
                .collect();
            format!("{label} {}\n", on.join(" "))
        })
        .collect()
}

/// The demo stream as a user's files hold it: piped to standard input, under a header,
/// gzip-compressed, as libsvm rows, and as Vowpal Wabbit rows piped in compressed: every form
/// fits to the same figures, and the header's names are reported.
#[test]
fn fit_reads_stdin_headers_gzip_and_sparse_rows_alike() {
    use std::io::Write;
    let dir = tempfile::tempdir().expect("temp dir");
    let demo = std::fs::read_to_string(demo_csv()).expect("demo stream");
    let width = demo.lines().next().expect("a row").split(',').count();
    let names: Vec<String> = std::iter::once("effect".to_owned())
        .chain((0..width - 1).map(|c| format!("f{c}")))
        .collect();
    let with_header = write(&dir, "named.csv", &format!("{}\n{demo}", names.join(",")));
    let gzip = |text: &str| {
        let mut out = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        out.write_all(text.as_bytes()).expect("compressed");
        out.finish().expect("compressed")
    };
    let packed = dir.path().join("demo.csv.gz");
    std::fs::write(&packed, gzip(&demo)).expect("temp file");
    let sparse = as_sparse_rows(&demo);
    let libsvm = write(&dir, "demo.svm", &sparse);
    // Vowpal Wabbit style: a bare `|` before the features, and value-less columns.
    let vw: String = sparse
        .lines()
        .map(|row| format!("{}\n", row.replacen(' ', " | ", 1).replace(":1", "")))
        .collect();

    let plain = fit_json(demo_csv().to_str().expect("utf-8 path"), None);
    let forms = [
        ("stdin", fit_json("-", Some(demo.as_bytes()))),
        ("header", fit_json(&with_header, None)),
        ("gzip", fit_json(packed.to_str().expect("utf-8 path"), None)),
        ("libsvm", fit_json(&libsvm, None)),
        ("vw via gzipped stdin", fit_json("-", Some(&gzip(&vw)))),
    ];
    for (form, report) in &forms {
        for key in ["n", "selected", "mean_logloss", "classes"] {
            assert_eq!(report[key], plain[key], "{form}: {key}");
        }
    }
    assert_eq!(plain["format"], "csv");
    assert_eq!(forms[3].1["format"], "sparse");
    assert_eq!(plain["selected_names"], serde_json::Value::Null);
    assert_eq!(
        forms[1].1["selected_names"],
        serde_json::json!(["f0", "f125", "f174", "f175"])
    );

    let out = tes(&["fit", &with_header]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("(named by the header)") && text.contains("f0 f125 f174 f175"),
        "{text}"
    );
    let mut command = tes_command();
    command.args(["fit", "-"]);
    let out = run_with_stdin(command, demo.as_bytes());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.starts_with("standard input: 4000 rows"), "{text}");
}

/// Malformed sparse rows and headers, in a file or piped in, stop with the line and report
/// nothing.
#[test]
fn malformed_sparse_rows_and_headers_stop_with_the_line() {
    let dir = tempfile::tempdir().expect("temp dir");
    let cases = [
        (
            "1 3:1\n0 3:1 x:2\n",
            ":2:",
            r#"feature "x:2" is not `column:value`"#,
        ),
        ("1 3:1\n0 3:1 3:2\n", ":2:", "column 3 is given twice"),
        ("1 3:1\n0 99999999999:1\n", ":2:", "largest supported"),
        ("label,a,b\n1,0\n", ":2:", "the header names 3 columns"),
    ];
    for (i, (text, line, reason)) in cases.into_iter().enumerate() {
        let path = write(&dir, &format!("bad{i}.rows"), text);
        let out = tes(&["fit", &path, "--json"]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && out.stdout.is_empty(), "case {i}");
        assert!(
            stderr.contains(&format!("bad{i}.rows{line}")) && stderr.contains(reason),
            "case {i}: {stderr}"
        );
        let mut command = tes_command();
        command.args(["fit", "-", "--json"]);
        let out = run_with_stdin(command, text.as_bytes());
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && out.stdout.is_empty(),
            "stdin case {i}"
        );
        assert!(
            stderr.contains(&format!("standard input{line}")) && stderr.contains(reason),
            "stdin case {i}: {stderr}"
        );
    }
    let out = tes(&["fit", "-", "--format", "libsvm"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && stderr.contains("possible values: csv, sparse"),
        "{stderr}"
    );
}

#[test]
fn malformed_rows_stop_with_the_line_and_report_nothing() {
    let dir = tempfile::tempdir().expect("temp dir");
    let cases = [
        ("0,1,0\n1,0,1\n1,0,oops\n", ":3:", "not a number"),
        ("0,1,0\n\n1,0\n", ":3:", "expected 3 columns"),
        ("0,1,0\n-1,0,1\n", ":2:", "label"),
        ("0,1,0\n1,NaN,1\n", ":2:", "not a finite number"),
        ("", "", "no rows"),
    ];
    for (i, (text, line, reason)) in cases.into_iter().enumerate() {
        let path = write(&dir, &format!("bad{i}.csv"), text);
        let out = tes(&["fit", &path, "--json"]);
        assert!(!out.status.success(), "case {i} should fail");
        assert!(out.stdout.is_empty(), "case {i}: nothing half-reported");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            stderr.contains(&format!("bad{i}.csv{line}")) && stderr.contains(reason),
            "case {i}: {stderr}"
        );
    }
}

/// A CSV file that is not UTF-8 text stops `tes fit` at the first line that is not, naming
/// `FILE:LINE` and the byte, and nothing is reported: a row holding the bytes 0xFF 0xFE, a
/// UTF-16 file (which starts with them), and a file of random bytes.
#[test]
fn files_that_are_not_utf8_stop_with_the_line_and_report_nothing() {
    let dir = tempfile::tempdir().expect("temp dir");
    let utf16: Vec<u8> = [0xFF, 0xFE]
        .into_iter()
        .chain("0,1,0\n1,0,1\n".encode_utf16().flat_map(u16::to_le_bytes))
        .collect();
    // xorshift64: the same "random" bytes every run.
    let mut x = 0x9E37_79B9_7F4A_7C15u64;
    let random: Vec<u8> = (0..4096)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 32) as u8
        })
        .collect();
    let first_line = random.split(|&b| b == b'\n').next().unwrap_or(&[]);
    assert!(
        std::str::from_utf8(first_line).is_err(),
        "the random file's first line is not UTF-8"
    );
    let cases: [(&str, &[u8], &str); 3] = [
        (
            "latin.csv",
            b"0,1,0\n1,0,1\n1,\xff\xfe,0\n0,1,1\n",
            "latin.csv:3: malformed row: byte 0xFF at position 3 is not UTF-8 text",
        ),
        (
            "utf16.csv",
            &utf16,
            "utf16.csv:1: malformed row: byte 0xFF at position 1 is not UTF-8 text",
        ),
        (
            "random.bin",
            &random,
            "random.bin:1: malformed row: byte 0x",
        ),
    ];
    for (name, bytes, expected) in cases {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).expect("temp file");
        for json in [false, true] {
            let mut args = vec!["fit", path.to_str().expect("utf-8 path")];
            if json {
                args.push("--json");
            }
            let out = tes(&args);
            assert!(!out.status.success(), "{name} should fail");
            assert!(out.stdout.is_empty(), "{name}: nothing reported");
            let stderr = String::from_utf8_lossy(&out.stderr);
            assert!(
                stderr.contains(expected) && stderr.contains("not UTF-8 text"),
                "{name}: {stderr}"
            );
            assert!(!stderr.contains("panicked"), "{name}: {stderr}");
        }
    }
}

#[test]
fn labels_beyond_classes_and_bad_settings_are_refused() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = write(&dir, "k.csv", "0,1\n2,0\n");
    let out = tes(&["fit", &path, "--classes", "2"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("k.csv:2: label 2 is out of range"));
    let out = tes(&["fit", &path, "--lambda", "-1"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("lambda"));
    let out = tes(&["fit", &dir.path().join("missing.csv").to_string_lossy()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("cannot open"));
}

#[test]
fn experiment_grid_writes_its_summary_csv_and_plots() {
    let _alone = alone_on_the_machine();
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("grid");
    let out_s = out.to_string_lossy().into_owned();
    let run = tes(&[
        "experiment",
        "grid",
        "--quick",
        "--runs",
        "2",
        "--episodes",
        "3",
        "--out",
        &out_s,
        "--draw",
        &format!("{out_s}/run.mcap"),
        "--draw-episodes",
        "3",
    ]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stderr}");
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("summary.json")).expect("summary.json"),
    )
    .expect("valid JSON");
    assert_eq!(summary["config"]["runs"], 2);
    // The drawn run is the study's loreRL run 0 at 0 irrelevant features: the same rewards.
    let csv = std::fs::read_to_string(out.join("episodes.csv")).expect("episodes.csv");
    let studied: Vec<String> = csv
        .lines()
        .filter(|l| l.starts_with("loreRL,0,0,"))
        .map(|l| {
            let reward: f64 = l
                .split(',')
                .nth(5)
                .and_then(|r| r.parse().ok())
                .expect("a reward");
            format!("{reward:.2}")
        })
        .collect();
    assert_eq!(studied.len(), 3, "{csv}");
    let drew = stderr
        .lines()
        .find(|l| l.contains("grid experiment: drew 3 episodes of loreRL"))
        .unwrap_or_else(|| panic!("no drawing line in {stderr}"));
    assert!(
        drew.contains(&format!("rewards {})", studied.join(" "))),
        "{drew} against {studied:?}"
    );
    assert!(std::fs::metadata(out.join("run.mcap")).is_ok_and(|m| m.len() > 1000));
    assert_eq!(summary["config"]["seed"], 1, "seeds are recorded");
    for alg in ["loreRL", "fRmax", "fEpsG", "Rmax", "RL-DT", "LSE-Rmax"] {
        assert!(summary["fig3a_final"][alg]["mean"].is_number(), "{alg}");
    }
    assert!(summary["fig3c"]["bloreRL"]["200"]["mean"].is_number());
    assert!(summary["table1"]["loreRL"]["seconds_per_episode"]["mean"].is_number());
    let csv = std::fs::read_to_string(out.join("episodes.csv")).expect("episodes.csv");
    // Header + 12 cells × 2 runs × 3 episodes.
    assert_eq!(csv.lines().count(), 1 + 12 * 2 * 3);
    for svg in ["fig3a.svg", "fig3b.svg", "fig3c.svg"] {
        let text = std::fs::read_to_string(out.join(svg)).expect(svg);
        assert!(text.starts_with("<svg") && text.contains("loreRL"), "{svg}");
    }
}

#[test]
fn experiment_report_prints_a_folders_tables_and_keeps_a_documents_blocks_true() {
    let dir = tempfile::tempdir().expect("temp dir");
    let robot = dir.path().join("robot");
    let robot_s = robot.to_string_lossy().into_owned();
    let run = tes(&["experiment", "robot", "--quick", "--out", &robot_s]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let text = |out: &std::process::Output| String::from_utf8_lossy(&out.stdout).into_owned();
    let targets = tes(&["experiment", "report", &robot_s, "--table", "targets"]);
    assert!(
        targets.status.success(),
        "{}",
        String::from_utf8_lossy(&targets.stderr)
    );
    // Notes come first, as in a document's block: one about the folder from a build of a
    // modified tree, and the machine and load of the times (Table 3's target is one).
    let printed = text(&targets);
    let mut table = printed.as_str();
    let mut notes = Vec::new();
    while let Some((note, rest)) = table.split_once("\n\n").filter(|(n, _)| n.starts_with('*')) {
        notes.push(note);
        table = rest;
    }
    assert!(
        notes
            .iter()
            .any(|n| n.starts_with("*Times are wall-clock seconds")),
        "{printed}"
    );
    assert!(
        table.starts_with("| target | test | measured | verdict |"),
        "{printed}"
    );
    let nothing = tes(&["experiment", "report", &robot_s, "--table", "fig3a"]);
    assert!(!nothing.status.success());
    assert!(
        String::from_utf8_lossy(&nothing.stderr).contains("no table \"fig3a\" in a robot folder")
    );
    // A document whose block says something else is stale until synced.
    let doc = dir.path().join("page.md");
    std::fs::write(
        &doc,
        "# Page\n<!-- generated by: tes experiment report robot --table table5 -->\nold numbers\n<!-- end of generated table -->\nafter\n",
    )
    .expect("write page");
    let root = dir.path().to_string_lossy().into_owned();
    let doc_s = doc.to_string_lossy().into_owned();
    let check = |expect: bool| {
        let out = tes(&["experiment", "report", "--check", &doc_s, "--root", &root]);
        assert_eq!(
            out.status.success(),
            expect,
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        out
    };
    let stale = check(false);
    assert!(String::from_utf8_lossy(&stale.stderr).contains("robot --table table5"));
    let sync = tes(&["experiment", "report", "--sync", &doc_s, "--root", &root]);
    assert!(
        sync.status.success(),
        "{}",
        String::from_utf8_lossy(&sync.stderr)
    );
    check(true);
    let page = std::fs::read_to_string(&doc).expect("page");
    assert!(
        page.contains("| repeat |") && !page.contains("old numbers") && page.ends_with("after\n"),
        "{page}"
    );
}

#[test]
fn experiment_rejects_zero_runs() {
    let run = tes(&["experiment", "grid", "--runs", "0", "--out", "/nonexistent"]);
    assert!(!run.status.success());
    assert!(String::from_utf8_lossy(&run.stderr).contains("--runs"));
}

#[test]
fn experiment_shards_and_resumes_are_checked_before_anything_runs() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().to_string_lossy().into_owned();
    for bad in ["0/3", "4/3", "3", "a/b"] {
        let run = tes(&["experiment", "robot", "--shard", bad, "--out", &out]);
        assert!(!run.status.success(), "{bad}");
        assert!(
            String::from_utf8_lossy(&run.stderr).contains("K/N"),
            "{bad}"
        );
    }
    let run = tes(&["experiment", "transfer", "--resume", &out]);
    assert!(!run.status.success());
    assert!(String::from_utf8_lossy(&run.stderr).contains("manifest.json"));
    let run = tes(&["experiment", "grid", "--resume", &out, "--runs", "3"]);
    assert!(!run.status.success());
    assert!(String::from_utf8_lossy(&run.stderr).contains("give no other setting"));
    let run = tes(&["experiment", "merge", &out, "--out", &out]);
    assert!(!run.status.success());
    assert!(String::from_utf8_lossy(&run.stderr).contains("manifest.json"));
}

/// A library grown by this test process over two tasks, saved with names.
fn saved_library(dir: &tempfile::TempDir) -> PathBuf {
    use tes_learning::library::store::{self, StoredLibrary};
    use tes_learning::library::{ActionOutcome, LibraryParams, ViewLibrary, Winner};
    use tes_learning::mdagl::Features;

    let mut lib = ViewLibrary::new(2, 3, 6, LibraryParams::default()).expect("valid settings");
    for task in 0..2 {
        let outcomes = (0..2)
            .map(|action| {
                let mut model = lib.fresh_model();
                // Feature 4 decides the effect; the others are noise.
                for i in 0..400u32 {
                    let on = i % 2 == 0;
                    let x: Vec<u32> = if on { vec![0, 4] } else { vec![0, 1 + i % 3] };
                    let effect = if on { 2 } else { (action + task) % 2 };
                    model
                        .update(Features::SparseBinary(&x), effect)
                        .expect("valid rows");
                }
                ActionOutcome {
                    action,
                    observations: 400,
                    winner: Winner::Fresh,
                    model,
                    score: -100.0 - action as f64,
                    library_scores: vec![],
                }
            })
            .collect();
        lib.end_task(outcomes).expect("valid outcomes");
    }
    let path = dir.path().join("lib.tesl");
    store::save(
        &path,
        &StoredLibrary {
            library: lib,
            world: "a test world".into(),
            action_names: vec!["push".into(), "pull".into()],
            feature_names: ["bias", "red", "green", "blue", "wet", "dry"]
                .map(String::from)
                .to_vec(),
        },
    )
    .expect("saved");
    path
}

#[test]
fn a_library_written_by_one_process_is_read_by_another() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = saved_library(&dir);
    let path = path.to_str().expect("utf-8 path");

    let out = tes(&["library", "export", path, "--json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON object");
    assert_eq!(json["world"], "a test world");
    assert_eq!(json["tasks_seen"], 2);
    let views = json["views"].as_array().expect("views");
    assert_eq!(views.len(), 4);
    assert_eq!(views[0]["action_name"], "push");
    assert_eq!(views[1]["action_name"], "pull");
    assert_eq!(views[2]["tasks_won"], serde_json::json!([1]));
    for v in views {
        let names = v["selected_feature_names"]
            .as_array()
            .expect("named features");
        assert!(names.contains(&serde_json::json!("wet")), "{v}");
        assert_eq!(v["scores"][0]["won"], true);
    }

    let out = tes(&["library", "show", path]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).expect("utf-8");
    assert!(text.contains("4 views"), "{text}");
    assert!(text.contains("action 1 (pull)"), "{text}");
    assert!(text.contains("wet"), "{text}");
}

#[test]
fn a_corrupt_library_is_refused_naming_the_file() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = saved_library(&dir);
    let mut bytes = std::fs::read(&path).expect("read");
    let n = bytes.len();
    bytes[n - 3] ^= 0xFF;
    std::fs::write(&path, &bytes).expect("write");
    let out = tes(&["library", "show", path.to_str().expect("utf-8 path")]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("lib.tesl") && stderr.contains("corrupt"),
        "{stderr}"
    );
}

/// `summary.json` of `dir`.
fn summary(dir: &Path) -> serde_json::Value {
    let path = dir.join("summary.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).expect("summary.json is JSON")
}

#[test]
fn experiment_all_gives_the_separate_commands_results_to_the_last_digit() {
    let _alone = alone_on_the_machine();
    let dir = tempfile::tempdir().expect("temp dir");
    let study = dir.path().join("study");
    let out = tes(&[
        "experiment",
        "all",
        "--quick",
        "--out",
        study.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(study.join("report.md").exists());
    for experiment in ["grid", "transfer", "robot", "fig4", "lifelong"] {
        let alone = dir.path().join(experiment);
        let out = tes(&[
            "experiment",
            experiment,
            "--quick",
            "--out",
            alone.to_str().unwrap(),
        ]);
        assert!(
            out.status.success(),
            "{experiment}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert_eq!(
            summary_without_timings(&summary(&study.join(experiment))),
            summary_without_timings(&summary(&alone)),
            "{experiment}: `tes experiment all` and the separate command differ"
        );
    }
}

/// `all --full` regenerates every result folder of `--from` from its manifest's settings, to
/// the last digit of its rewards; given the same `--out` again it keeps what it ran.
#[test]
fn experiment_all_full_regenerates_every_committed_folder_from_its_manifest() {
    let _alone = alone_on_the_machine();
    let dir = tempfile::tempdir().expect("temp dir");
    let committed = dir.path().join("committed");
    let robot = committed.join("robot-quick");
    let made = tes(&[
        "experiment",
        "robot",
        "--quick",
        "--runs",
        "2",
        "--out",
        robot.to_str().unwrap(),
    ]);
    assert!(
        made.status.success(),
        "{}",
        String::from_utf8_lossy(&made.stderr)
    );
    let again = dir.path().join("again");
    let full = |out: &Path| {
        tes(&[
            "experiment",
            "all",
            "--full",
            "--from",
            committed.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
    };
    let run = full(&again);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(String::from_utf8_lossy(&run.stderr).contains("[1/1] robot-quick"));
    assert_eq!(
        summary_without_timings(&summary(&again.join("robot-quick"))),
        summary_without_timings(&summary(&robot)),
        "the regenerated folder differs from the one it regenerates"
    );
    let records = job_records(&again.join("robot-quick"));
    let resumed = full(&again);
    assert!(
        resumed.status.success(),
        "{}",
        String::from_utf8_lossy(&resumed.stderr)
    );
    assert!(String::from_utf8_lossy(&resumed.stderr).contains("resuming"));
    assert_eq!(job_records(&again.join("robot-quick")), records);
    // `--resume OUT` alone, from any working directory, finds the folder OUT was regenerated
    // from (not docs/results of wherever it runs).
    let out = again.to_str().unwrap();
    let elsewhere = tes_command()
        .args(["experiment", "all", "--full", "--resume", out])
        .current_dir(dir.path())
        .output()
        .expect("tes runs");
    let said = String::from_utf8_lossy(&elsewhere.stderr);
    assert!(elsewhere.status.success(), "{said}");
    assert!(said.contains("[1/1] robot-quick"), "{said}");
    assert!(
        String::from_utf8_lossy(&elsewhere.stdout).contains("s of running in all"),
        "{}",
        String::from_utf8_lossy(&elsewhere.stdout)
    );
    assert_eq!(job_records(&again.join("robot-quick")), records);
    // Another source for the same OUT is refused, naming both.
    let other = tes(&[
        "experiment",
        "all",
        "--full",
        "--from",
        dir.path().to_str().unwrap(),
        "--out",
        out,
    ]);
    let said = String::from_utf8_lossy(&other.stderr);
    assert!(!other.status.success(), "{said}");
    assert!(
        said.contains("was regenerated from") && said.contains("committed"),
        "{said}"
    );
}

/// Job records (`jobs/NNNNN.json`, finished ones only) in a result folder.
fn job_records(dir: &Path) -> usize {
    std::fs::read_dir(dir.join("jobs")).map_or(0, |entries| {
        entries
            .filter_map(Result::ok)
            .filter(|e| e.path().extension().is_some_and(|x| x == "json"))
            .count()
    })
}

#[test]
fn an_experiment_stopped_with_ctrl_c_resumes_from_its_records_to_the_same_summary() {
    use nix::sys::signal::{Signal, kill};
    use nix::unistd::Pid;
    use std::time::{Duration, Instant};

    let _alone = alone_on_the_machine();
    let dir = tempfile::tempdir().expect("temp dir");
    let (cut, whole) = (dir.path().join("cut"), dir.path().join("whole"));
    let args = |out: &Path| -> Vec<String> {
        [
            "experiment",
            "transfer",
            "--quick",
            "--runs",
            "6",
            "--threads",
            "1",
            "--out",
        ]
        .iter()
        .map(ToString::to_string)
        .chain([out.to_string_lossy().into_owned()])
        .collect()
    };
    let log = dir.path().join("cut.log");
    let mut command = tes_command();
    command
        .args(args(&cut))
        .stdout(std::process::Stdio::null())
        .stderr(std::fs::File::create(&log).expect("log file"));
    // A child inherits an ignored SIGINT (std resets only SIGPIPE and the signal mask), as
    // a script's background job has it: the command installs its own handler, so it stops
    // all the same.
    // SAFETY: between fork and exec only `sigaction` runs, which is async-signal-safe.
    unsafe {
        std::os::unix::process::CommandExt::pre_exec(&mut command, || {
            nix::sys::signal::signal(Signal::SIGINT, nix::sys::signal::SigHandler::SigIgn)
                .map(drop)
                .map_err(std::io::Error::from)
        });
    }
    let mut child = command.spawn().expect("the tes binary runs");
    // Ctrl-C once the first of the six jobs is recorded, while the second runs. Six, not
    // three: on a loaded machine this thread can sleep through a short job or two, and the
    // run must still be going when the signal comes.
    let deadline = Instant::now() + Duration::from_secs(600);
    while job_records(&cut) == 0 {
        if let Some(status) = child.try_wait().expect("wait") {
            panic!("the run ended ({status}) before it could be interrupted");
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("no job recorded in 10 minutes");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let pid = Pid::from_raw(i32::try_from(child.id()).expect("pid fits"));
    kill(pid, Signal::SIGINT).expect("SIGINT");
    let status = child.wait().expect("wait");
    assert_eq!(
        status.code(),
        Some(130),
        "an interrupted run exits as Ctrl-C's (128 + SIGINT)"
    );
    let said = std::fs::read_to_string(&log).expect("log");
    assert!(
        said.contains("interrupted") && said.contains("--resume"),
        "the interruption says how to go on: {said}"
    );
    let kept = job_records(&cut);
    assert!(
        (1..6).contains(&kept),
        "{kept} of 6 jobs recorded at the interruption"
    );
    assert!(!cut.join("summary.json").exists());

    let resumed = tes(&["experiment", "transfer", "--resume", cut.to_str().unwrap()]);
    assert!(
        resumed.status.success(),
        "{}",
        String::from_utf8_lossy(&resumed.stderr)
    );
    let args = args(&whole);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let alone = tes(&args);
    assert!(
        alone.status.success(),
        "{}",
        String::from_utf8_lossy(&alone.stderr)
    );
    assert_eq!(
        summary_without_timings(&summary(&cut)),
        summary_without_timings(&summary(&whole)),
        "the resumed run's summary differs from the uninterrupted run's"
    );
}

/// Every executable the workspace builds is named `tes` or `tes-…`, so installing one never
/// shadows, or is shadowed by, a system command (iproute2 ships `bridge`).
#[test]
fn every_executable_is_named_after_tes() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let workspace: toml::Table = read_toml(&root.join("Cargo.toml"));
    let members = workspace["workspace"]["members"]
        .as_array()
        .expect("the workspace lists its members");
    let mut names = Vec::new();
    for member in members {
        let dir = root.join(member.as_str().expect("a member is a path"));
        let manifest = read_toml(&dir.join("Cargo.toml"));
        let package = manifest["package"]["name"].as_str().unwrap_or_default();
        let bins = manifest.get("bin").and_then(|b| b.as_array()).cloned();
        match bins {
            Some(bins) => names.extend(
                bins.iter()
                    .filter_map(|b| b.get("name").and_then(|n| n.as_str()).map(str::to_owned)),
            ),
            // Cargo's default binary takes the package's name.
            None if dir.join("src/main.rs").exists() => names.push(package.to_owned()),
            None => {}
        }
    }
    assert!(names.contains(&"tes-bridge".to_owned()), "{names:?}");
    for name in &names {
        assert!(
            name == "tes" || name.starts_with("tes-"),
            "the executable {name:?} is not named tes-…"
        );
    }
}

fn read_toml(path: &Path) -> toml::Table {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.parse()
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// `tes link keygen DIR` makes the authority and a key pair per host, readable only by their
/// owner, prints each host's `[launch.link]` lines (which a launch accepts), and never
/// overwrites keys.
#[test]
fn link_keygen_makes_private_keys_and_prints_the_launch_lines() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().expect("temp dir");
    let keys = dir.path().join("keys");
    let keys_arg = keys.to_str().expect("utf-8 path");
    let out = tes(&[
        "link",
        "keygen",
        keys_arg,
        "--host",
        "robot=perception-sim,bridge@192.168.1.20",
        "--host",
        "learner=controller",
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for file in [
        "ca.pem",
        "ca.key",
        "robot.pem",
        "robot.key",
        "learner.pem",
        "learner.key",
    ] {
        let mode = std::fs::metadata(keys.join(file))
            .expect(file)
            .permissions()
            .mode();
        assert_eq!(mode & 0o777, 0o600, "{file}");
    }
    assert!(
        text.contains("connect = [\"quic/192.168.1.20:7447\"]"),
        "{text}"
    );
    assert!(text.contains("listen = [\"quic/0.0.0.0:7447\"]"), "{text}");
    // The learner's lines, as printed, make a launch file that passes its checks.
    let learner = &text[text.find("# on learner").expect("the learner's lines")..];
    let launch = dir.path().join("learner.toml");
    std::fs::write(&launch, learner).expect("write");
    let file = tes_launch::file::read_launch_file(&launch).expect("the printed lines read");
    tes_launch::file::check_launch(&file.launch).expect("and pass the launch's checks");
    assert_eq!(file.launch.roles, [tes_topics::Role::Controller]);
    let again = tes(&["link", "keygen", keys_arg]);
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("never overwritten"));
}

/// `--foxglove` with something that is not an address is refused before anything starts.
#[test]
fn a_foxglove_address_that_is_not_one_is_refused_before_anything_starts() {
    let dir = tempfile::tempdir().expect("temp dir");
    let run = tes_command()
        .args(["launch", "--episodes", "1", "--foxglove", "not an address"])
        .env("TES_DATA_DIR", dir.path())
        .output()
        .expect("tes runs");
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success());
    assert!(
        stderr.contains("--foxglove: \"not an address\" is not an address to serve on")
            && stderr.contains("nothing was started"),
        "{stderr}"
    );
    assert!(
        !dir.path().join("runs").exists(),
        "nothing was started: {stderr}"
    );
}
