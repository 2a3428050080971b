//! `tes launch --record` and `tes replay` with the real process group: the file is valid for
//! an independent MCAP reader (PyPI's `mcap`, installed by `.ci/run`), holds every
//! observation and command the run reported, and replays identically with a planner thread
//! and with planning between polls; a changed observation is reported at its step; a run
//! stopped by Ctrl-C leaves a complete file and one whose launcher was killed a readable one.
//!
//! Every group runs under its own service prefix and data directory; the guard kills the
//! launcher (its children die with it) and removes stale iceoryx2 resources even when a test
//! fails.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use tes_recorder::reader::Recording;

use crate::common::*;

const LIMIT: Duration = Duration::from_secs(180);

/// Launches `episodes` episodes recorded to `dir/run.mcap`, with `extra` after the
/// `[launch]` table's first keys; returns the file and the launcher's stdout.
fn record(dir: &Path, extra: &str, episodes: u32) -> (PathBuf, Vec<String>) {
    let file = dir.join("run.mcap");
    let toml = launch_file(dir, &format!("record = \"{}\"\n{extra}", file.display()));
    let mut group = Group::start(dir, &toml, episodes);
    let (ok, out, err) = group.finish(LIMIT);
    assert!(ok, "the launch failed: {out:?} {err:?}");
    assert!(
        err.iter().any(|l| l.starts_with("launch: recorded ")),
        "{err:?}"
    );
    (file, out)
}

/// What PyPI's `mcap` reader sees: `topic schema-name schema-encoding message-encoding count`
/// per JSON channel (ours; the viewers' Protobuf ones are read in `viewers.rs`), then the
/// metadata records' names.
fn python_view(file: &Path) -> Vec<String> {
    let script = r#"
import json, sys
from mcap.reader import make_reader
with open(sys.argv[1], "rb") as f:
    reader = make_reader(f)
    summary = reader.get_summary()
    counts = summary.statistics.channel_message_counts
    ours = [c for c in summary.channels.values() if c.message_encoding == "json"]
    for channel in sorted(ours, key=lambda c: c.topic):
        schema = summary.schemas[channel.schema_id]
        json.loads(schema.data)
        print(channel.topic, schema.name, schema.encoding, channel.message_encoding,
              counts.get(channel.id, 0))
    for _, channel, message in reader.iter_messages():
        if channel.message_encoding == "json":
            json.loads(message.data)
    print("metadata", *sorted(m.name for m in reader.iter_metadata()))
"#;
    let out = Command::new("python3")
        .args(["-c", script])
        .arg(file)
        .output()
        .expect("python3 runs");
    assert!(
        out.status.success(),
        "the mcap package could not read {}: {}",
        file.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(str::to_owned)
        .collect()
}

/// PyPI's `mcap`, a reader we did not write, sees our channels, schemas and as many commands
/// as the run reported actions. Ignored, with its reason, where the reader cannot be imported;
/// under CI it always runs (see `build.rs`).
#[test]
#[cfg_attr(
    not(tes_mcap_reader),
    ignore = "PyPI's mcap is not installed: python3 -m pip install 'mcap==1.*'"
)]
fn an_independent_reader_sees_every_channel_and_message() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (file, out) = record(dir.path(), "[controller]\nplanning = \"thread\"\n", 4);
    let actions = reported_actions(&out);
    let recording = Recording::open(&file).expect("the recording reads");
    let expect = [
        format!("/tes/command tes.Command jsonschema json {actions}"),
        "/tes/keep-alive tes.Command jsonschema json 0".to_owned(),
        format!(
            "/tes/motor-state tes.MotorState jsonschema json {}",
            recording.motor_states.len()
        ),
        format!(
            "/tes/observation tes.Observation jsonschema json {}",
            recording.observations.len()
        ),
        "/tes/world-map tes.WorldMap jsonschema json 1".to_owned(),
        "metadata tes.recorder tes.run".to_owned(),
    ];
    assert_eq!(python_view(&file), expect);
}

/// A recorded run with a planner thread: our reader sees as many commands as the run
/// reported actions; the replay makes every decision again; a changed observation is reported
/// at its step.
#[test]
fn a_recorded_run_is_valid_mcap_and_replays_identically_with_a_planner_thread() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (file, out) = record(dir.path(), "[controller]\nplanning = \"thread\"\n", 4);
    let actions = reported_actions(&out);
    let recording = Recording::open(&file).expect("the recording reads");
    assert_eq!(recording.truncated, None);
    assert_eq!(recording.commands.len() as u64, actions);
    assert!(recording.world_map.is_some());
    assert!(recording.observations.len() as u64 > actions);
    assert!(!recording.motor_states.is_empty());

    let (ok, stdout, stderr) = replay(&file, &[]);
    assert!(ok, "{stdout} {stderr}");
    assert_eq!(
        stdout.trim(),
        format!("replay: {actions} of {actions} commands identical")
    );

    // One observation in the middle changed to a cell off the map: the replay's controller
    // refuses it where the run answered it, and says so at that step.
    let mut changed = recording.clone();
    let k = recording.commands[recording.commands.len() / 2].answers;
    let obs = changed
        .observations
        .iter_mut()
        .find(|o| o.seq == k)
        .expect("the answered observation");
    let (episode, step) = (obs.episode, obs.step);
    obs.state.x = 200;
    let outcome = tes_recorder::replay::replay(&changed).expect("replays");
    let d = outcome.divergence.expect("a divergence");
    assert_eq!((d.seq, d.episode, d.step, d.got), (k, episode, step, None));
    assert!(d.expected.is_some());
    assert!(d.to_string().starts_with(&format!(
        "first divergence at step {step} of episode {episode} (observation {k}): expected action"
    )));

    // The summary from the file alone: the episodes the launch printed.
    let (ok, summary, _) = replay(&file, &["--summary"]);
    assert!(ok);
    for line in out.iter().filter(|l| l.starts_with("episode ")) {
        assert!(summary.contains(line.as_str()), "{line:?} not in {summary}");
    }
    let csv = dir.path().join("csv");
    let (ok, _, _) = replay(&file, &["--export-csv", csv.to_str().unwrap()]);
    assert!(ok);
    let commands = std::fs::read_to_string(csv.join("command.csv")).unwrap();
    assert_eq!(commands.lines().count() as u64, actions + 1);
}

/// With planning between polls (a spinning wait), the replay makes every decision again too.
#[test]
fn a_recorded_run_replays_identically_with_planning_between_polls() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (file, out) = record(
        dir.path(),
        "wait = \"spin-then-block:200\"\n[controller]\nplanning = \"between-polls\"\n",
        4,
    );
    let actions = reported_actions(&out);
    let (ok, stdout, stderr) = replay(&file, &[]);
    assert!(ok, "{stdout} {stderr}");
    assert_eq!(
        stdout.trim(),
        format!("replay: {actions} of {actions} commands identical")
    );
}

/// The same under full load (two busy processes per core at normal priority): the recorder,
/// a `SCHED_IDLE` thread such a machine starves, is raised before it falls behind, so it
/// misses nothing and the run replays identically. Before, it drained the services only once
/// the group had stopped, when the observations and the world map had gone with their
/// publishers: a file of commands alone, or missing observations that made the replay
/// diverge.
#[test]
fn a_recorded_run_replays_identically_under_full_load() {
    let _alone = alone_on_the_machine();
    let _hogs = CpuHogs::two_per_core();
    for round in 0..3 {
        let dir = tempfile::tempdir().expect("temp dir");
        let file = dir.path().join("run.mcap");
        let toml = launch_file(
            dir.path(),
            &format!(
                "record = \"{}\"\nwait = \"spin-then-block:200\"\n[controller]\n\
                 planning = \"between-polls\"\n",
                file.display()
            ),
        );
        let mut group = Group::start(dir.path(), &toml, 4);
        let (ok, out, err) = group.finish(Duration::from_secs(600));
        assert!(ok, "round {round}: the launch failed: {out:?} {err:?}");
        let recorded = err
            .iter()
            .find(|l| l.starts_with("launch: recorded "))
            .unwrap_or_else(|| panic!("round {round}: {err:?}"));
        assert!(!recorded.contains("missed"), "round {round}: {recorded}");
        let actions = reported_actions(&out);
        let (ok, stdout, stderr) = replay(&file, &[]);
        assert!(ok, "round {round}: {recorded}\n{stdout} {stderr}");
        assert_eq!(
            stdout.trim(),
            format!("replay: {actions} of {actions} commands identical"),
            "round {round}: {recorded}"
        );
    }
}

/// Ctrl-C mid-run leaves a complete file; a killed launcher (and recorder) leaves one that is
/// read up to its last flushed chunk, and `tes replay` says how far it got.
#[test]
fn a_stopped_or_killed_run_leaves_a_readable_recording() {
    let dir = tempfile::tempdir().expect("temp dir");
    let file = dir.path().join("run.mcap");
    let toml = launch_file(dir.path(), &format!("record = \"{}\"\n", file.display()));
    let mut group = Group::start(dir.path(), &toml, 1000);
    group.wait_for_episodes(2, LIMIT);
    kill(Pid::from_raw(group.launcher.id() as i32), Signal::SIGINT).expect("SIGINT");
    let (_, _, _) = group.finish(LIMIT);
    let stopped = Recording::open(&file).expect("readable after Ctrl-C");
    assert_eq!(stopped.truncated, None, "finalised on shutdown");
    assert!(stopped.commands.len() > 1);

    let killed_dir = dir.path().join("killed");
    std::fs::create_dir_all(&killed_dir).unwrap();
    let file = killed_dir.join("run.mcap");
    let toml = launch_file(&killed_dir, &format!("record = \"{}\"\n", file.display()));
    let mut group = Group::start(&killed_dir, &toml, 1000);
    group.wait_for_episodes(2, LIMIT);
    // Past the recorder's next flush.
    std::thread::sleep(Duration::from_millis(1500));
    kill(Pid::from_raw(group.launcher.id() as i32), Signal::SIGKILL).expect("SIGKILL");
    let _ = group.finish(LIMIT);
    let killed = Recording::open(&file).expect("readable after SIGKILL");
    assert!(killed.truncated.is_some(), "no footer after SIGKILL");
    assert!(!killed.commands.is_empty());
    let (ok, stdout, stderr) = replay(&file, &[]);
    assert!(stderr.contains("is incomplete"), "{stderr}");
    assert!(ok, "{stdout} {stderr}");
    assert!(stdout.contains("commands identical"), "{stdout}");
}

/// A child that crashes mid-run stops the group (`restart = "never"`, the default); the
/// launcher still finishes the recording: complete for the independent reader, with every
/// command the controller sent, and it replays identically up to where the run ended.
#[test]
fn a_run_stopped_by_a_crashed_child_leaves_a_complete_recording() {
    let dir = tempfile::tempdir().expect("temp dir");
    let file = dir.path().join("run.mcap");
    let toml = launch_file(dir.path(), &format!("record = \"{}\"\n", file.display()));
    let mut group = Group::start(dir.path(), &toml, 1000);
    group.wait_for_episodes(2, LIMIT);
    kill(group.child("bridge"), Signal::SIGKILL).expect("kill the bridge");
    let (ok, out, err) = group.finish(LIMIT);
    assert!(!ok, "a crashed child fails the launch: {out:?}");
    assert!(
        err.iter()
            .any(|l| l.contains("bridge was killed by SIGKILL")),
        "{err:?}"
    );
    assert!(
        err.iter().any(|l| l.starts_with("launch: recorded ")),
        "{err:?}"
    );

    let recording = Recording::open(&file).expect("readable after a crashed child");
    assert_eq!(recording.truncated, None, "finalised on shutdown");
    assert!(recording.commands.len() > 1);
    let n = recording.commands.len();
    let (ok, stdout, stderr) = replay(&file, &[]);
    assert!(ok, "{stdout} {stderr}");
    assert_eq!(
        stdout.trim(),
        format!("replay: {n} of {n} commands identical")
    );
}

/// `tes replay --summary` of a recording cut short before any of its run was written says
/// so and fails, rather than summarising zero episodes as if they were the run.
#[test]
fn a_summary_of_a_recording_with_nothing_readable_fails() {
    use tes_recorder::writer::{RecordCounts, RunInfo, RunWriter};
    let dir = tempfile::tempdir().expect("temp dir");
    let whole = dir.path().join("whole.mcap");
    let writer = RunWriter::create(&whole, &RunInfo::default()).expect("a recording");
    writer.finish(RecordCounts::default()).expect("finished");
    let bytes = std::fs::read(&whole).expect("read");
    // The shortest cut that still reads: its run metadata, and nothing after it.
    let cut = dir.path().join("cut.mcap");
    let len = (8..bytes.len())
        .find(|&n| Recording::from_bytes(&cut, &bytes[..n]).is_ok())
        .expect("a cut that reads");
    std::fs::write(&cut, &bytes[..len]).expect("write");
    let (ok, stdout, stderr) = replay(&cut, &["--summary"]);
    assert!(!ok, "{stdout}");
    assert!(
        stderr.contains("is incomplete") && stderr.contains("nothing of the run to summarise"),
        "{stderr}"
    );
}
