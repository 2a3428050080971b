//! The supervisor with a fake child: a shell script that plays each role as a scenario asks
//! (episode lines and a clean finish, a crash, silence), so that the sequence of events for
//! a clean run, a crash with a restart and a stall is checked without the real processes.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use tes_launch::event::{Event, ExitConsequence};
use tes_launch::{ChildCommand, LaunchFile, Options, Restart, Verdict};
use tes_topics::Role;

/// The fake child: `sh fake.sh SCENARIO ROLE --config FILE`. Every role but perception
/// waits to be stopped; perception finishes after a while (its episodes), unless the
/// scenario is a stall, where nobody does anything.
const FAKE_CHILD: &str = r#"
scenario="$1"; role="$2"; dir=$(dirname "$4")
trap 'exit 0' INT TERM
wait_for_stop() { while :; do sleep 0.05; done; }
case "$scenario:$role" in
  stall:*) wait_for_stop ;;
  crash:controller)
    if [ ! -e "$dir/crashed-once" ]; then
      touch "$dir/crashed-once"
      echo "error: the fake controller crashes once" >&2
      exit 3
    fi ;;
esac
case "$role" in
  controller)
    echo "episode 1: reward 0.50, 7 steps, decision latency p50 4 us p99 9 us max 31 us, 0 over budget"
    echo "episode 2: reward -1.00, 3 steps, decision latency p50 5 us p99 8 us max 12 us, 1 over budget"
    wait_for_stop ;;
  perception-sim) sleep 1.5; exit 0 ;;
  *) wait_for_stop ;;
esac
"#;

/// A launch in a fresh directory: its run folder and library there, `scenario` played by
/// the fake child; the events it emitted and its verdict.
fn launch(
    scenario: &str,
    configure: impl FnOnce(&mut LaunchFile),
    start_allowance: Duration,
) -> (Vec<Event>, Verdict) {
    let dir = tempfile::tempdir().expect("temp dir");
    let script = dir.path().join("fake.sh");
    std::fs::write(&script, FAKE_CHILD).expect("script");
    let mut file = LaunchFile::default();
    file.launch.run_dir = Some(dir.path().join("run"));
    file.controller.library = Some(dir.path().join("library.tesl"));
    configure(&mut file);
    let command = ChildCommand::new("sh").arg(&script).arg(scenario);
    let mut options = Options::new(command, Arc::new(AtomicBool::new(false)));
    options.start_allowance = start_allowance;
    let mut events: Vec<Event> = Vec::new();
    let verdict = tes_launch::run(&file, options, &mut events).expect("the launch runs");
    (events, verdict)
}

/// The events that tell the processes' lives, in order, without pids.
fn lives(events: &[Event]) -> Vec<String> {
    events
        .iter()
        .filter_map(|e| match e {
            Event::ProcessStarted { role, .. } => Some(format!("started {role}")),
            Event::ProcessExited {
                role, how, then, ..
            } => Some(format!("{role} {how}: {then:?}")),
            Event::ProcessRestarted { role, restart, max } => {
                Some(format!("restarted {role} {restart}/{max}"))
            }
            Event::Stalled { restarting, .. } => Some(format!("stalled, restarting: {restarting}")),
            Event::StopRequested => Some("stop requested".into()),
            Event::Verdict(v) => Some(format!("verdict: {} failures", v.failures.len())),
            _ => None,
        })
        .collect()
}

/// How many events say `text` (a log line, an exit's cause, a warning).
fn said_anywhere(events: &[Event], text: &str) -> usize {
    events
        .iter()
        .filter(|e| match e {
            Event::Log { text: t, .. } | Event::Warning(t) => t.contains(text),
            Event::ProcessExited { said, .. } => said.as_deref().is_some_and(|s| s.contains(text)),
            _ => false,
        })
        .count()
}

fn episodes(events: &[Event]) -> Vec<u32> {
    events
        .iter()
        .filter_map(|e| match e {
            Event::EpisodeEnded { line, .. } => Some(line.episode),
            _ => None,
        })
        .collect()
}

fn run_dir(events: &[Event]) -> PathBuf {
    events
        .iter()
        .find_map(|e| match e {
            Event::Planned { run_dir, .. } => Some(run_dir.clone()),
            _ => None,
        })
        .expect("the plan is said first")
}

fn position(events: &[Event], what: impl Fn(&Event) -> bool) -> usize {
    events.iter().position(what).expect("the event is there")
}

#[test]
fn a_clean_run_starts_every_child_relays_its_episodes_and_stops_when_perception_is_done() {
    let (events, verdict) = launch("clean", |_| {}, Duration::from_secs(20));
    // The plan is said before anything starts (a warning about another test's leftovers
    // may come first).
    let planned = position(&events, |e| matches!(e, Event::Planned { .. }));
    let started = position(&events, |e| matches!(e, Event::ProcessStarted { .. }));
    assert!(planned < started, "{events:?}");
    assert_eq!(
        lives(&events),
        [
            "started bridge",
            "started controller",
            "started perception-sim",
            "perception-sim exited with status 0: Finished",
            "verdict: 0 failures",
        ]
    );
    assert_eq!(episodes(&events), [1, 2]);
    assert_eq!(
        verdict,
        Verdict {
            episodes: 2,
            unfinished_steps: 0,
            failures: Vec::new()
        }
    );
    // The end comes in order: the run folder, the library, the verdict last.
    let folder = position(&events, |e| matches!(e, Event::RunFolder { .. }));
    let library = position(&events, |e| matches!(e, Event::LibraryAtEnd { .. }));
    assert!(
        folder < library && library == events.len() - 2,
        "{events:?}"
    );
    let drawn = events.iter().find_map(|e| match e {
        Event::RunFolder { dir, drawn } => Some((dir.clone(), drawn.clone())),
        _ => None,
    });
    let (dir, drawn) = drawn.expect("the run folder is told");
    assert_eq!(dir, run_dir(&events));
    assert_eq!(
        drawn.map(|d| d.len()),
        Ok(3),
        "rewards, latency and arena pictures"
    );
}

#[test]
fn a_crashed_child_is_restarted_when_the_launch_says_so() {
    let (events, verdict) = launch(
        "crash",
        |f| f.launch.restart = Restart::OnFailure,
        Duration::from_secs(20),
    );
    let lives = lives(&events);
    let restarted = [
        "controller exited with status 3: Restart { restart: 1, max: 3 }",
        "restarted controller 1/3",
        "started controller",
    ];
    let at = lives
        .iter()
        .position(|l| l == restarted[0])
        .unwrap_or_else(|| panic!("no restart in {lives:?}"));
    assert_eq!(lives[at..at + 3], restarted, "{lives:?}");
    assert_eq!(
        lives[lives.len() - 2..],
        [
            "perception-sim exited with status 0: Finished",
            "verdict: 0 failures"
        ]
    );
    // The restarted controller's episodes are relayed; the crash's last words are said once,
    // with its exit (not relayed as a line of its own before).
    assert_eq!(episodes(&events), [1, 2]);
    assert_eq!(said_anywhere(&events, "crashes once"), 1, "{events:?}");
    assert!(events.iter().any(|e| matches!(
        e,
        Event::ProcessExited { role: Role::Controller, said: Some(said), .. }
            if said.contains("crashes once")
    )));
    assert!(verdict.success(), "{verdict:?}");
}

#[test]
fn a_crashed_child_stops_the_group_without_restarts() {
    let (events, verdict) = launch("crash", |_| {}, Duration::from_secs(20));
    let exit = events.iter().find_map(|e| match e {
        Event::ProcessExited {
            role: Role::Controller,
            said,
            then,
            ..
        } => Some((said, then)),
        _ => None,
    });
    assert_eq!(
        exit,
        Some((
            &Some("the fake controller crashes once".to_owned()),
            &ExitConsequence::StopGroup
        ))
    );
    // The cause was said with the exit; the verdict names the failure without repeating it.
    assert_eq!(verdict.failures, ["controller exited with status 3"]);
    assert_eq!(said_anywhere(&events, "crashes once"), 1, "{events:?}");
}

#[test]
fn a_group_that_makes_no_progress_is_stalled_and_stopped() {
    let (events, verdict) = launch("stall", |f| f.launch.stall_timeout_ms = 500, Duration::ZERO);
    let lives = lives(&events);
    assert_eq!(
        lives,
        [
            "started bridge",
            "started controller",
            "started perception-sim",
            "stalled, restarting: false",
            "verdict: 1 failures",
        ]
    );
    let holder = events.iter().find_map(|e| match e {
        Event::Stalled {
            holder, silent_for, ..
        } => Some((*holder, *silent_for)),
        _ => None,
    });
    assert_eq!(holder.map(|h| h.1), Some(Duration::from_millis(500)));
    assert!(
        verdict.failures[0].starts_with("the group made no progress for 0.5 s"),
        "{verdict:?}"
    );
}

/// Nothing of a group is left: the script's processes are gone.
#[test]
fn no_fake_child_outlives_its_launch() {
    let (events, _) = launch("clean", |_| {}, Duration::from_secs(20));
    let pids: Vec<u32> = events
        .iter()
        .filter_map(|e| match e {
            Event::ProcessStarted { pid, .. } => Some(*pid),
            _ => None,
        })
        .collect();
    assert_eq!(pids.len(), 3);
    for pid in pids {
        assert!(
            !Path::new(&format!("/proc/{pid}")).exists(),
            "{pid} lives on"
        );
    }
}
