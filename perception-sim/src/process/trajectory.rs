//! The run's trajectory as perception saw it: one CSV row per action (the state it was taken
//! in, the action, the effect, the reward, the pose before and after, and on an episode's
//! last row why it ended).
//!
//! Perception writes it after publishing each observation, while the controller decides, so
//! it is never on the observation-to-command path; rows are buffered and flushed at most every
//! [`FLUSH_EVERY`] and at each episode's end, so a reader following the file (`tes launch
//! --tui`) sees the robot move.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::arena::{Arena, EpisodeStatus, Pose};

/// The header row of `trajectory.csv`.
pub const HEADER: &str = "episode,step,x,y,orientation,action,effect,reward,next_x,next_y,\
                          next_orientation,x_cm,y_cm,heading_deg,next_x_cm,next_y_cm,\
                          next_heading_deg,end";

/// How often buffered rows reach the file at most.
pub const FLUSH_EVERY: Duration = Duration::from_millis(100);

/// Why an episode ended, as the trajectory's `end` column says it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EndReason {
    /// The robot reached the ball (+2).
    Ball,
    /// The robot entered a death spot (−1).
    DeathSpot,
    /// The robot left the arena (−1).
    LeftArena,
    /// The state did not change for four actions.
    Stuck,
    /// The episode reached its step cap.
    StepCap,
    /// The run's action limit (`actions`) was reached.
    ActionLimit,
}

impl EndReason {
    /// How the `end` column and the episode table name it.
    pub fn name(self) -> &'static str {
        match self {
            EndReason::Ball => "ball",
            EndReason::DeathSpot => "death-spot",
            EndReason::LeftArena => "left-arena",
            EndReason::Stuck => "stuck",
            EndReason::StepCap => "step-cap",
            EndReason::ActionLimit => "action-limit",
        }
    }

    /// Why an episode whose last action reached `state` with `status` ended, if it did.
    pub fn of(
        arena: &Arena,
        state: usize,
        status: EpisodeStatus,
        at_step_cap: bool,
        out_of_actions: bool,
    ) -> Option<Self> {
        match status {
            EpisodeStatus::Terminal => Some(match arena.attributes(state) {
                Some(a) if !a.is_out() => {
                    let (x, y) = (usize::from(a.x), usize::from(a.y));
                    if arena.is_ball_cell(x, y) {
                        EndReason::Ball
                    } else {
                        EndReason::DeathSpot
                    }
                }
                _ => EndReason::LeftArena,
            }),
            EpisodeStatus::Stuck => Some(EndReason::Stuck),
            EpisodeStatus::Continuing if out_of_actions => Some(EndReason::ActionLimit),
            EpisodeStatus::Continuing if at_step_cap => Some(EndReason::StepCap),
            EpisodeStatus::Continuing => None,
        }
    }
}

/// One action as the trajectory records it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrajectoryRow {
    /// Episode index.
    pub episode: u32,
    /// The action's index within the episode, from 0.
    pub step: u32,
    /// The state the action was taken in.
    pub from: usize,
    /// The action the bridge carried out (`None` if it did not say).
    pub action: Option<u16>,
    /// The state it led to.
    pub to: usize,
    /// The reward for entering `to`.
    pub reward: f64,
    /// The pose before the action.
    pub pose_before: Pose,
    /// The pose after it.
    pub pose_after: Pose,
    /// Why the episode ended with this action, if it did.
    pub end: Option<EndReason>,
}

/// Writes `trajectory.csv`.
pub struct TrajectoryLog {
    path: PathBuf,
    out: BufWriter<File>,
    flushed: Instant,
}

impl TrajectoryLog {
    /// Creates (or truncates) the file at `path` and writes its header.
    pub fn create(path: &Path) -> std::io::Result<Self> {
        let mut out = BufWriter::new(File::create(path)?);
        writeln!(out, "{HEADER}")?;
        out.flush()?;
        Ok(Self {
            path: path.to_owned(),
            out,
            flushed: Instant::now(),
        })
    }

    /// Opens the file at `path` that an earlier perception of the same run wrote, to go on
    /// from it: its rows are kept and new ones appended. Returns the log and the episode to
    /// go on with: the one after the last that ended there (an episode cut short by the
    /// restart is run again under its number; no episode line was given for it). A missing
    /// or empty file is [`create`](Self::create)d, starting at episode 0.
    pub fn resume(path: &Path) -> std::io::Result<(Self, u32)> {
        let text = match std::fs::read_to_string(path) {
            Ok(text) if !text.trim().is_empty() => text,
            Ok(_) => return Ok((Self::create(path)?, 0)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Ok((Self::create(path)?, 0));
            }
            Err(e) => return Err(e),
        };
        let next = next_episode(&text);
        let mut file = std::fs::OpenOptions::new().append(true).open(path)?;
        // A row the predecessor was killed in the middle of writing is ended, so the next
        // row starts on its own line.
        if !text.ends_with('\n') {
            writeln!(file)?;
        }
        let log = Self {
            path: path.to_owned(),
            out: BufWriter::new(file),
            flushed: Instant::now(),
        };
        Ok((log, next))
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Appends one action's row; flushes at an episode's end or when [`FLUSH_EVERY`] has
    /// passed.
    pub fn push(&mut self, arena: &Arena, row: &TrajectoryRow) -> std::io::Result<()> {
        let state = |s: usize| {
            arena
                .attributes(s)
                .filter(|a| !a.is_out())
                .map_or((-1, -1, -1), |a| {
                    (i32::from(a.x), i32::from(a.y), i32::from(a.orientation))
                })
        };
        let (x, y, o) = state(row.from);
        let (nx, ny, no) = state(row.to);
        let effect = arena.effect_between(row.from, row.to);
        let action = row.action.map_or(String::new(), |a| a.to_string());
        let (b, a) = (row.pose_before, row.pose_after);
        writeln!(
            self.out,
            "{},{},{x},{y},{o},{action},{effect},{},{nx},{ny},{no},{:.1},{:.1},{:.1},{:.1},{:.1},{:.1},{}",
            row.episode,
            row.step,
            row.reward,
            b.position.x,
            b.position.y,
            b.heading.to_degrees(),
            a.position.x,
            a.position.y,
            a.heading.to_degrees(),
            row.end.map_or("", EndReason::name),
        )?;
        if row.end.is_some() || self.flushed.elapsed() >= FLUSH_EVERY {
            self.out.flush()?;
            self.flushed = Instant::now();
        }
        Ok(())
    }

    /// Writes what is buffered.
    pub fn flush(&mut self) -> std::io::Result<()> {
        self.out.flush()
    }
}

/// The episode after the last one whose end a trajectory's `text` holds (0 if none ended).
fn next_episode(text: &str) -> u32 {
    let mut lines = text.lines();
    let columns: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let at = |name: &str| columns.iter().position(|c| *c == name);
    let (Some(episode_at), Some(end_at)) = (at("episode"), at("end")) else {
        return 0;
    };
    lines
        .filter_map(|line| {
            let fields: Vec<&str> = line.split(',').collect();
            // A row cut short by a kill has fewer fields than the header: not an end.
            if fields.len() != columns.len() || fields[end_at].is_empty() {
                return None;
            }
            fields[episode_at].parse::<u32>().ok()
        })
        .max()
        .map_or(0, |last| last.saturating_add(1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::arena::ArenaId;

    /// A respawned perception goes on after the last episode that ended, whatever rows of
    /// an interrupted one (or half a row) follow it; the kept rows stay and new ones append.
    #[test]
    fn a_resumed_trajectory_goes_on_after_its_last_ended_episode() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("trajectory.csv");
        let fields = HEADER.split(',').count();
        let row = |episode: u32, step: u32, end: &str| {
            let mut cells = vec![episode.to_string(), step.to_string()];
            cells.resize(fields - 1, "1".to_owned());
            cells.push(end.to_owned());
            cells.join(",")
        };
        let text = format!(
            "{HEADER}\n{}\n{}\n{}\n{}\n4,0,1,",
            row(3, 0, ""),
            row(3, 1, "ball"),
            row(4, 0, ""),
            row(4, 1, "")
        );
        std::fs::write(&path, &text).unwrap();
        let (mut log, next) = TrajectoryLog::resume(&path).unwrap();
        assert_eq!(next, 4, "episode 4 was cut short: it is run again");
        writeln!(log.out, "{}", row(4, 0, "")).unwrap();
        log.flush().unwrap();
        let after = std::fs::read_to_string(&path).unwrap();
        assert!(after.starts_with(&text), "the earlier rows are kept");
        assert!(after.ends_with(&format!("4,0,1,\n{}\n", row(4, 0, ""))));

        let fresh = dir.path().join("fresh.csv");
        let (_, next) = TrajectoryLog::resume(&fresh).unwrap();
        assert_eq!(next, 0);
        assert_eq!(
            std::fs::read_to_string(&fresh).unwrap(),
            format!("{HEADER}\n")
        );
    }

    #[test]
    fn the_end_column_names_why_an_episode_ended() {
        let arena = Arena::new(ArenaId::Env3);
        let out = arena.out_state();
        let ball = (0..out)
            .find(|&s| {
                let a = arena.attributes(s).unwrap();
                arena.is_ball_cell(usize::from(a.x), usize::from(a.y))
            })
            .expect("a ball cell");
        let death = (0..out)
            .find(|&s| {
                let a = arena.attributes(s).unwrap();
                arena.is_death_cell(usize::from(a.x), usize::from(a.y))
            })
            .expect("a death spot");
        let of = |s, status, cap, limit| EndReason::of(&arena, s, status, cap, limit);
        assert_eq!(
            of(ball, EpisodeStatus::Terminal, false, false),
            Some(EndReason::Ball)
        );
        assert_eq!(
            of(death, EpisodeStatus::Terminal, false, false),
            Some(EndReason::DeathSpot)
        );
        assert_eq!(
            of(out, EpisodeStatus::Terminal, false, false),
            Some(EndReason::LeftArena)
        );
        assert_eq!(
            of(0, EpisodeStatus::Stuck, true, true),
            Some(EndReason::Stuck)
        );
        assert_eq!(
            of(0, EpisodeStatus::Continuing, true, false),
            Some(EndReason::StepCap)
        );
        assert_eq!(
            of(0, EpisodeStatus::Continuing, true, true),
            Some(EndReason::ActionLimit)
        );
        assert_eq!(of(0, EpisodeStatus::Continuing, false, false), None);
    }

    #[test]
    fn a_row_has_every_column_of_the_header() {
        let arena = Arena::new(ArenaId::Env3);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("trajectory.csv");
        let mut log = TrajectoryLog::create(&path).unwrap();
        let from = (0..arena.out_state())
            .find(|&s| arena.apply_effect(s, 0) != arena.out_state())
            .unwrap();
        let to = arena.apply_effect(from, 0);
        let pose_before = arena.state_pose(from).unwrap();
        let pose_after = arena.state_pose(to).unwrap();
        log.push(
            &arena,
            &TrajectoryRow {
                episode: 2,
                step: 0,
                from,
                action: Some(1),
                to,
                reward: -0.05,
                pose_before,
                pose_after,
                end: Some(EndReason::StepCap),
            },
        )
        .unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines[0], HEADER);
        let row: Vec<&str> = lines[1].split(',').collect();
        assert_eq!(row.len(), HEADER.split(',').count());
        assert_eq!((row[0], row[1], row[5], row[6]), ("2", "0", "1", "0"));
        assert_eq!(row[7], "-0.05");
        assert_eq!(*row.last().unwrap(), "step-cap");
    }
}
