//! `tes launch --tui`: the group, live, in the terminal (ratatui).
//!
//! It shows each process (pid, state, restarts, CPU), the episodes and their reward curve,
//! the decision latency (p50/p99/max of the last episode, misses), the robot on the arena
//! map, and the last log lines. It reads only what the launcher has anyway — its children,
//! the controller's episode lines, perception's trajectory in the run folder, the children's
//! logs — so it never touches the acting path. `q`, Esc or Ctrl-C stops the group cleanly.

use std::io::Stdout;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use ratatui::Terminal;
use ratatui::backend::CrosstermBackend;
use ratatui::crossterm::event::{self, Event, KeyCode, KeyEventKind, KeyModifiers};
use ratatui::crossterm::execute;
use ratatui::crossterm::terminal::{
    EnterAlternateScreen, LeaveAlternateScreen, disable_raw_mode, enable_raw_mode,
};
use ratatui::layout::{Constraint, Direction, Layout, Rect};
use ratatui::style::{Color, Modifier, Style};
use ratatui::symbols::Marker;
use ratatui::text::{Line, Span};
use ratatui::widgets::{
    Axis, Block, Borders, Cell, Chart, Dataset, GraphType, Paragraph, Row, Table,
};
use tes_perception_sim::arena::{Arena, MarkColour};

use tes_launch::run_record::{EpisodeRow, RobotAt};
use tes_perception_sim::arena::ArenaId;

/// The window of the reward curve's moving mean, episodes.
const MOVING_MEAN: usize = 10;

/// How often the view is redrawn.
pub(crate) const FRAME: Duration = Duration::from_millis(200);

/// What the view shows of one process.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ProcessRow {
    /// Its role.
    pub(crate) role: &'static str,
    /// Its pid.
    pub(crate) pid: u32,
    /// `running`, or how it ended.
    pub(crate) state: String,
    /// Respawns so far.
    pub(crate) restarts: u32,
}

/// What the launcher tells the view each frame.
pub(crate) struct Frame<'a> {
    /// The header: arena, services, run folder.
    pub(crate) title: &'a str,
    /// Episodes to run.
    pub(crate) episodes_planned: u32,
    /// The decision budget, µs.
    pub(crate) budget_us: u64,
    /// The processes.
    pub(crate) processes: &'a [ProcessRow],
    /// The episodes recorded so far, in order.
    pub(crate) episodes: &'a [EpisodeRow],
    /// Where the robot is, if it has moved.
    pub(crate) robot: Option<RobotAt>,
    /// The arena, if it is one of the paper's.
    pub(crate) arena: Option<ArenaId>,
    /// The last log lines, oldest first.
    pub(crate) log: &'a [String],
    /// Shown at the bottom ("stopping…" once asked).
    pub(crate) status: &'a str,
}

/// The live view: owns the terminal (raw mode, alternate screen) until dropped.
pub(crate) struct LiveView {
    terminal: Terminal<CrosstermBackend<Stdout>>,
    cpu: CpuMeter,
    drawn: Option<Instant>,
    arena: Option<Arena>,
}

impl LiveView {
    /// Takes the terminal.
    pub(crate) fn open() -> Result<Self> {
        enable_raw_mode().context("cannot put the terminal in raw mode (is it a terminal?)")?;
        let mut stdout = std::io::stdout();
        if let Err(e) = execute!(stdout, EnterAlternateScreen) {
            let _ = disable_raw_mode();
            return Err(e).context("cannot open the terminal's alternate screen");
        }
        let terminal =
            Terminal::new(CrosstermBackend::new(stdout)).context("cannot draw on the terminal")?;
        Ok(Self {
            terminal,
            cpu: CpuMeter::default(),
            drawn: None,
            arena: None,
        })
    }

    /// Whether the user asked to stop (`q`, Esc, Ctrl-C); reads the keys pressed so far.
    pub(crate) fn stop_asked(&mut self) -> bool {
        let mut asked = false;
        while event::poll(Duration::ZERO).unwrap_or(false) {
            match event::read() {
                Ok(Event::Key(key)) if key.kind == KeyEventKind::Press => {
                    let ctrl_c = key.modifiers.contains(KeyModifiers::CONTROL)
                        && key.code == KeyCode::Char('c');
                    asked |= ctrl_c || matches!(key.code, KeyCode::Char('q') | KeyCode::Esc);
                }
                Ok(_) => {}
                Err(_) => break,
            }
        }
        asked
    }

    /// Draws `frame` if a [`FRAME`] has passed since the last drawing.
    pub(crate) fn draw_due(&mut self, frame: &Frame<'_>) -> Result<()> {
        if self.drawn.is_some_and(|at| at.elapsed() < FRAME) {
            return Ok(());
        }
        self.drawn = Some(Instant::now());
        if self.arena.is_none() {
            self.arena = frame.arena.map(Arena::new);
        }
        let cpu: Vec<Option<f64>> = frame
            .processes
            .iter()
            .map(|p| self.cpu.percent(p.pid))
            .collect();
        let arena = self.arena.as_ref();
        self.terminal
            .draw(|f| render(f, frame, &cpu, arena))
            .context("cannot draw on the terminal")?;
        Ok(())
    }
}

impl Drop for LiveView {
    fn drop(&mut self) {
        let _ = disable_raw_mode();
        let _ = execute!(self.terminal.backend_mut(), LeaveAlternateScreen);
        let _ = self.terminal.show_cursor();
    }
}

/// CPU use of processes, from `/proc/PID/stat` between two readings.
#[derive(Default)]
struct CpuMeter {
    last: std::collections::BTreeMap<u32, (u64, Instant)>,
}

impl CpuMeter {
    /// The share of one CPU `pid` used since the last reading, %.
    fn percent(&mut self, pid: u32) -> Option<f64> {
        let ticks = cpu_ticks(pid)?;
        let now = Instant::now();
        let before = self.last.insert(pid, (ticks, now));
        let (t0, at) = before?;
        let seconds = now.duration_since(at).as_secs_f64();
        (seconds > 0.0)
            .then(|| (ticks.saturating_sub(t0) as f64 / TICKS_PER_SECOND) / seconds * 100.0)
    }
}

/// Linux's `USER_HZ`, the unit of `/proc/PID/stat`'s CPU times (100 on every architecture
/// Linux runs TES on).
const TICKS_PER_SECOND: f64 = 100.0;

/// User plus system CPU time of `pid`, in ticks.
fn cpu_ticks(pid: u32) -> Option<u64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The command name (field 2) may hold spaces: count from after its closing parenthesis.
    let rest = &stat[stat.rfind(')')? + 2..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // utime and stime are fields 14 and 15, the 12th and 13th after the name.
    let utime: u64 = fields.get(11)?.parse().ok()?;
    let stime: u64 = fields.get(12)?.parse().ok()?;
    Some(utime + stime)
}

fn block(title: &str) -> Block<'_> {
    Block::default().borders(Borders::ALL).title(Span::styled(
        title,
        Style::default().add_modifier(Modifier::BOLD),
    ))
}

fn render(
    f: &mut ratatui::Frame<'_>,
    frame: &Frame<'_>,
    cpu: &[Option<f64>],
    arena: Option<&Arena>,
) {
    let rows = Layout::default()
        .direction(Direction::Vertical)
        .constraints([
            Constraint::Length(1),
            Constraint::Length(frame.processes.len() as u16 + 3),
            Constraint::Min(12),
            Constraint::Length(8),
            Constraint::Length(1),
        ])
        .split(f.area());
    f.render_widget(
        Paragraph::new(Line::from(Span::styled(
            frame.title,
            Style::default().add_modifier(Modifier::BOLD),
        ))),
        rows[0],
    );
    processes(f, rows[1], frame, cpu);
    let middle = Layout::default()
        .direction(Direction::Horizontal)
        .constraints([Constraint::Min(40), Constraint::Length(arena_width(arena))])
        .split(rows[2]);
    let left = Layout::default()
        .direction(Direction::Vertical)
        .constraints([Constraint::Length(6), Constraint::Min(6)])
        .split(middle[0]);
    episodes(f, left[0], frame);
    rewards(f, left[1], frame);
    map(f, middle[1], frame, arena);
    let log: Vec<Line<'_>> = frame
        .log
        .iter()
        .skip(
            frame
                .log
                .len()
                .saturating_sub(rows[3].height.saturating_sub(2) as usize),
        )
        .map(|l| Line::from(l.as_str()))
        .collect();
    f.render_widget(Paragraph::new(log).block(block("Log")), rows[3]);
    f.render_widget(
        Paragraph::new(Line::from(vec![
            Span::styled(" q ", Style::default().add_modifier(Modifier::REVERSED)),
            Span::raw(format!(" stop the group   {}", frame.status)),
        ])),
        rows[4],
    );
}

fn processes(f: &mut ratatui::Frame<'_>, area: Rect, frame: &Frame<'_>, cpu: &[Option<f64>]) {
    let header = Row::new(["process", "pid", "state", "restarts", "CPU"])
        .style(Style::default().add_modifier(Modifier::BOLD));
    let rows = frame.processes.iter().zip(cpu).map(|(p, cpu)| {
        let state = if p.state == "running" {
            Cell::from(p.state.clone()).style(Style::default().fg(Color::Green))
        } else {
            Cell::from(p.state.clone()).style(Style::default().fg(Color::Red))
        };
        Row::new(vec![
            Cell::from(p.role),
            Cell::from(p.pid.to_string()),
            state,
            Cell::from(p.restarts.to_string()),
            Cell::from(cpu.map_or("-".to_owned(), |c| format!("{c:.0} %"))),
        ])
    });
    let widths = [
        Constraint::Length(16),
        Constraint::Length(9),
        Constraint::Min(12),
        Constraint::Length(9),
        Constraint::Length(7),
    ];
    f.render_widget(
        Table::new(rows, widths)
            .header(header)
            .block(block("Processes")),
        area,
    );
}

fn episodes(f: &mut ratatui::Frame<'_>, area: Rect, frame: &Frame<'_>) {
    let done = frame.episodes;
    let mut lines = vec![Line::from(format!(
        "episodes {} of {}   total reward {:.2}",
        done.len(),
        frame.episodes_planned,
        done.iter().map(|e| e.line.reward).sum::<f64>()
    ))];
    match done.last() {
        Some(last) => {
            let l = &last.line;
            lines.push(Line::from(format!(
                "last: episode {}, reward {:.2}, {} steps, {}",
                l.episode,
                l.reward,
                l.steps,
                last.end.as_deref().unwrap_or("?")
            )));
            lines.push(Line::from(format!(
                "decision latency p50 {} us  p99 {} us  max {} us  (budget {} us)",
                l.p50_us, l.p99_us, l.max_us, frame.budget_us
            )));
        }
        None => lines.push(Line::from("waiting for the first episode to end")),
    }
    let misses: u64 = done.iter().map(|e| e.line.misses).sum();
    let slowest = done.iter().map(|e| e.line.max_us).max().unwrap_or(0);
    lines.push(Line::from(format!(
        "over budget: {misses} decisions; slowest so far {slowest} us"
    )));
    f.render_widget(Paragraph::new(lines).block(block("Episodes")), area);
}

fn rewards(f: &mut ratatui::Frame<'_>, area: Rect, frame: &Frame<'_>) {
    let points: Vec<(f64, f64)> = frame
        .episodes
        .iter()
        .map(|e| (f64::from(e.line.episode), e.line.reward))
        .collect();
    let (lo, hi) = points
        .iter()
        .fold((0.0f64, 0.0f64), |(lo, hi), &(_, y)| (lo.min(y), hi.max(y)));
    let last = points.last().map_or(1.0, |p| p.0.max(1.0));
    let mean: Vec<(f64, f64)> = points
        .iter()
        .enumerate()
        .map(|(i, &(x, _))| {
            let window = &points[i.saturating_sub(MOVING_MEAN - 1)..=i];
            (
                x,
                window.iter().map(|p| p.1).sum::<f64>() / window.len() as f64,
            )
        })
        .collect();
    let data = vec![
        Dataset::default()
            .marker(Marker::Braille)
            .graph_type(GraphType::Line)
            .style(Style::default().fg(Color::DarkGray))
            .data(&points),
        Dataset::default()
            .marker(Marker::Braille)
            .graph_type(GraphType::Line)
            .style(Style::default().fg(Color::Yellow))
            .data(&mean),
    ];
    let title = format!("Reward per episode (yellow: moving mean of {MOVING_MEAN})");
    let chart = Chart::new(data)
        .block(block(&title))
        .x_axis(
            Axis::default()
                .bounds([0.0, last])
                .labels([Line::from("0"), Line::from(format!("{last:.0}"))]),
        )
        .y_axis(Axis::default().bounds([lo - 0.1, hi + 0.1]).labels([
            Line::from(format!("{lo:.1}")),
            Line::from(format!("{hi:.1}")),
        ]));
    f.render_widget(chart, area);
}

fn arena_width(arena: Option<&Arena>) -> u16 {
    arena.map_or(20, |a| (a.cells() as u16) * 2 + 3).max(24)
}

/// The robot's heading as an arrow, by orientation (45° steps counter-clockwise from east).
const ARROWS: [char; 8] = ['→', '↗', '↑', '↖', '←', '↙', '↓', '↘'];

fn map(f: &mut ratatui::Frame<'_>, area: Rect, frame: &Frame<'_>, arena: Option<&Arena>) {
    let Some(arena) = arena else {
        f.render_widget(Paragraph::new("no map").block(block("Arena")), area);
        return;
    };
    let robot = frame.robot;
    let n = arena.cells();
    let mut lines = Vec::with_capacity(n + 2);
    for row in (0..n).rev() {
        let mut spans = Vec::with_capacity(n);
        for x in 0..n {
            let here = robot.and_then(|r| r.cell) == Some((x as u16, row as u16));
            let (text, style) = if here {
                let o = robot.map_or(0, |r| usize::from(r.orientation) % 8);
                (
                    format!("{} ", ARROWS[o]),
                    Style::default().fg(Color::Black).bg(Color::Yellow),
                )
            } else if arena.is_ball_cell(x, row) {
                ("O ".to_owned(), Style::default().fg(Color::LightBlue))
            } else if arena.is_death_cell(x, row) {
                ("X ".to_owned(), Style::default().fg(Color::Red))
            } else if arena.has_mark(MarkColour::Blue, x, row) {
                ("b ".to_owned(), Style::default().fg(Color::Blue))
            } else if arena.has_mark(MarkColour::Green, x, row) {
                ("g ".to_owned(), Style::default().fg(Color::Green))
            } else {
                (". ".to_owned(), Style::default().fg(Color::DarkGray))
            };
            spans.push(Span::styled(text, style));
        }
        lines.push(Line::from(spans));
    }
    lines.push(Line::from(match robot {
        Some(r) if r.cell.is_none() => format!("episode {}: left the arena", r.episode),
        Some(r) => format!("episode {}, step {}", r.episode, r.steps),
        None => "robot not moved yet".to_owned(),
    }));
    let title = frame.arena.map_or("Arena".to_owned(), |id| id.to_string());
    f.render_widget(Paragraph::new(lines).block(block(&title)), area);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_time_is_read_from_proc() {
        let ticks = cpu_ticks(std::process::id());
        assert!(ticks.is_some());
        assert_eq!(cpu_ticks(u32::MAX), None);
    }
}
