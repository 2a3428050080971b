//! The printer's lines, event by event.

use std::time::Duration;

use tes_launch::event::Verdict;
use tes_topics::Role;

use super::*;

/// The launcher's lines are the events, said as `tes launch` always said them; without
/// echo only warnings, failures and the children's logs remain.
#[test]
fn events_are_said_as_the_launchers_lines() {
    let events = [
        Event::StopRequested,
        Event::ProcessExited {
            role: Role::Controller,
            how: "was killed by SIGKILL".into(),
            said: Some("boom".into()),
            then: ExitConsequence::StopGroup,
        },
        Event::ProcessExited {
            role: Role::Bridge,
            how: "exited with status 1".into(),
            said: None,
            then: ExitConsequence::Restart { restart: 2, max: 3 },
        },
        Event::Stalled {
            silent_for: Duration::from_millis(1500),
            holder: Role::Perception,
            why: "published no observation".into(),
            restarting: false,
        },
        Event::LinkUp {
            role: Role::Bridge,
            again: true,
        },
        Event::Verdict(Verdict {
            episodes: 4,
            unfinished_steps: 0,
            failures: vec!["controller was killed by SIGKILL".into()],
        }),
    ];
    let said =
        |echo| -> Vec<(To, String)> { events.iter().flat_map(|e| lines_of(e, echo)).collect() };
    let err = |l: &str| (To::Err, l.to_owned());
    let always = [
        err("launch: stop requested; stopping the group"),
        err("launch: controller was killed by SIGKILL (boom); stopping the others"),
        err("launch: bridge exited with status 1; respawning it (restart 2/3)"),
        err(
            "launch: the group made no progress for 1.5 s: perception-sim published no \
             observation; stopping the group",
        ),
    ];
    assert_eq!(said(false), always);
    let mut echoed = always.to_vec();
    echoed.push(err("launch: link: the bridge joined again"));
    echoed.push((
        To::Out,
        "launch: 4 episodes; failed: controller was killed by SIGKILL".into(),
    ));
    assert_eq!(said(true), echoed);
}

/// The live view's address is said; one beyond loopback is warned about even without echo.
#[test]
fn a_live_view_beyond_loopback_is_warned_about() {
    let at = |addr: &str, exposed| Event::Foxglove {
        addr: addr.parse().expect("an address"),
        exposed,
    };
    let quiet = lines_of(&at("127.0.0.1:8765", false), false);
    assert!(quiet.is_empty(), "{quiet:?}");
    let said = lines_of(&at("0.0.0.0:8765", true), false);
    assert_eq!(said.len(), 1);
    assert!(said[0].1.contains("ws://0.0.0.0:8765") && said[0].1.contains("WARNING"));
}

/// The plan says its settings as the launch file spells them, and counts in words.
#[test]
fn the_plan_is_said_in_the_files_words() {
    let planned = Event::Planned {
        world: "arena Env 3".into(),
        episodes: 1,
        real_time_factor: 0.0,
        wait: tes_launch::file::ChosenWait::new(
            tes_runtime::channel::WaitStrategy::default(),
            0.0,
            200,
            true,
        ),
        restart: tes_launch::file::Restart::Never,
        service_prefix: "tes-1-2/".into(),
        run_dir: "runs/x".into(),
    };
    let lines = lines_of(&planned, true);
    let line = &lines[0].1;
    assert!(
        line.starts_with("launch: arena Env 3, 1 episode, real-time factor 0,")
            && line.contains(", restart never,")
            && line.contains("wait auto: block (nothing is announced here"),
        "{line}"
    );
    let ended = Event::Verdict(Verdict {
        episodes: 1,
        unfinished_steps: 0,
        failures: Vec::new(),
    });
    assert_eq!(
        lines_of(&ended, true),
        [(
            To::Out,
            "launch: 1 episode; all processes stopped cleanly".into()
        )]
    );
    // Stopped mid-episode: the actions the library learned from beyond the last episode
    // are said, so the library's new task is accounted for.
    let interrupted = Event::Verdict(Verdict {
        episodes: 0,
        unfinished_steps: 3,
        failures: Vec::new(),
    });
    assert_eq!(
        lines_of(&interrupted, true),
        [(
            To::Out,
            "launch: 0 episodes and 3 actions of an unfinished one; all processes stopped \
             cleanly"
                .into()
        )]
    );
}

/// perception-sim ends before the controller has said its last episode: its "finished"
/// line waits until the group has stopped, so it comes after every episode line.
#[test]
fn the_finished_line_comes_after_the_last_episode() {
    let mut printer = Printer {
        echo: true,
        ..Printer::default()
    };
    printer.say.hold();
    for event in [
        Event::ProcessExited {
            role: Role::Perception,
            how: "exited with status 0".into(),
            said: None,
            then: ExitConsequence::Finished,
        },
        Event::Output {
            role: Role::Controller,
            text: "episode 19: reward 1.00".into(),
        },
        Event::Verdict(Verdict {
            episodes: 20,
            unfinished_steps: 0,
            failures: Vec::new(),
        }),
    ] {
        printer.event(&event);
    }
    assert_eq!(
        printer.say.held_lines(10),
        [
            "episode 19: reward 1.00",
            "launch: perception-sim finished its episodes; the group stopped",
            "launch: 20 episodes; all processes stopped cleanly",
        ]
    );
}
