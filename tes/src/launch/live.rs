//! `tes launch --tui`: the supervisor's events drawn in the live view instead of printed.

use anyhow::{Context, Result};
use tes_launch::event::{Event, Observer, Verdict};
use tes_launch::run_record::{EpisodeRow, RobotAt};
use tes_launch::{LaunchFile, Options, Step, Supervisor};
use tes_perception_sim::arena::ArenaId;

use super::Printer;
use super::tui::{Frame, LiveView, ProcessRow};

/// How many of the last lines the view shows.
const LOG_LINES: usize = 50;

/// The live view as an observer: what it shows, kept from the events.
struct Live {
    /// The lines the printer would print, held for the view's log pane.
    printer: Printer,
    view: Option<LiveView>,
    title: String,
    episodes_planned: u32,
    budget_us: u64,
    arena: Option<ArenaId>,
    processes: Vec<ProcessRow>,
    episodes: Vec<EpisodeRow>,
    robot: Option<RobotAt>,
}

impl Observer for Live {
    fn event(&mut self, event: &Event) {
        self.printer.event(event);
        match event {
            Event::Planned {
                world,
                service_prefix,
                run_dir,
                ..
            } => {
                self.title = format!(
                    "TES launch: {world}, services {service_prefix}*, run folder {}",
                    run_dir.display()
                );
            }
            Event::ProcessStarted { role, pid } => {
                let row = ProcessRow {
                    role: role.name(),
                    pid: *pid,
                    state: "running".into(),
                    restarts: 0,
                };
                match self.processes.iter_mut().find(|p| p.role == role.name()) {
                    Some(p) => (p.pid, p.state) = (row.pid, row.state),
                    None => self.processes.push(row),
                }
            }
            Event::ProcessRestarted { role, restart, .. } => {
                if let Some(p) = self.processes.iter_mut().find(|p| p.role == role.name()) {
                    p.restarts = *restart;
                }
            }
            Event::ProcessExited { role, how, .. } => {
                if let Some(p) = self.processes.iter_mut().find(|p| p.role == role.name()) {
                    p.state.clone_from(how);
                }
            }
            Event::EpisodeRecorded(row) => self.episodes.push(row.clone()),
            Event::RobotMoved(at) => self.robot = Some(*at),
            _ => {}
        }
    }
}

impl Live {
    /// Draws the view if a frame is due; a view that fails is closed, and the lines printed
    /// again.
    fn draw(&mut self) {
        let Some(view) = &mut self.view else { return };
        let log = self.printer.say.held_lines(LOG_LINES);
        let frame = Frame {
            title: &self.title,
            episodes_planned: self.episodes_planned,
            budget_us: self.budget_us,
            processes: &self.processes,
            episodes: &self.episodes,
            robot: self.robot,
            arena: self.arena,
            log: &log,
            status: "",
        };
        if let Err(e) = view.draw_due(&frame) {
            self.close();
            self.printer
                .say
                .err(&format!("launch: warning: the live view stopped: {e:#}"));
        }
    }

    /// Whether the user asked to stop (`q`, Esc, Ctrl-C in the view).
    fn stop_asked(&mut self) -> bool {
        self.view.as_mut().is_some_and(LiveView::stop_asked)
    }

    /// Gives the terminal back: the shutdown and the summary are printed.
    fn close(&mut self) {
        self.view = None;
        self.printer.say.release();
    }
}

/// Runs the launch `file` with the live view: opened before anything starts (a terminal
/// that cannot show it starts nothing), closed before the group's end is printed.
pub(crate) fn run(file: &LaunchFile, options: Options) -> Result<Verdict> {
    let view = LiveView::open().context("--tui: cannot show the live view; nothing was started")?;
    let mut live = Live {
        printer: Printer {
            echo: true,
            ..Printer::default()
        },
        view: Some(view),
        title: String::new(),
        episodes_planned: file.launch.episodes,
        budget_us: file.controller.budget_us,
        arena: ArenaId::from_number(file.arena()).ok(),
        processes: Vec::new(),
        episodes: Vec::new(),
        robot: None,
    };
    live.printer.say.hold();
    let started = Supervisor::start(file, options, &mut live);
    let mut supervisor = match started {
        Ok(s) => s,
        Err(e) => {
            live.close();
            return Err(e.into());
        }
    };
    loop {
        match supervisor.step(&mut live) {
            Ok(Step::Running) => {}
            Ok(Step::Stopping) => break,
            Err(e) => {
                live.close();
                let _ = supervisor.stop(&mut live);
                return Err(e.into());
            }
        }
        if live.stop_asked() {
            supervisor.request_stop();
        }
        live.draw();
        std::thread::sleep(tes_launch::supervisor::TICK);
    }
    live.close();
    Ok(supervisor.stop(&mut live))
}
