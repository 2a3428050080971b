//! What a launch records in its run folder as it goes, and the pictures it draws at the end.
//!
//! Two children write the raw records: the controller prints one line per episode (reward,
//! steps, decision latency p50/p99/max, misses), perception writes `trajectory.csv` (one row
//! per action, the episode's end reason on its last row). The launcher joins them, by episode,
//! into `episodes.csv` as both are known, and at the end draws `rewards.svg`, `latency.svg` and
//! `arena.svg` from them. It reads the files and lines the children write anyway: nothing
//! here touches the acting path.

use std::collections::{BTreeMap, VecDeque};
use std::fs::File;
use std::io::{BufRead, BufReader, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use tes_controller::summary::EpisodeLine;
use tes_experiments::svg::{BandPoint, LineChart, Series};
use tes_perception_sim::arena::{Arena, ArenaId, DVec2, Path as ArenaPath};

use crate::IoError;
use crate::file::TRAJECTORY;

/// The episode table of a run folder.
pub const EPISODES: &str = "episodes.csv";

/// Its header row.
pub const EPISODES_HEADER: &str =
    "episode,reward,steps,end,decision_p50_us,decision_p99_us,decision_max_us,misses";

/// How many of the last episodes' paths `arena.svg` (and the live view) draw.
pub const PATHS_DRAWN: usize = 5;

/// The window of the moving mean in `rewards.svg`.
const MOVING_MEAN: usize = 5;

/// One row of `episodes.csv`.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeRow {
    /// The controller's line.
    pub line: EpisodeLine,
    /// Why it ended, from the trajectory (`None` if perception did not say).
    pub end: Option<String>,
}

impl EpisodeRow {
    fn csv(&self) -> String {
        let l = &self.line;
        format!(
            "{},{:.2},{},{},{},{},{},{}",
            l.episode,
            l.reward,
            l.steps,
            self.end.as_deref().unwrap_or(""),
            l.p50_us,
            l.p99_us,
            l.max_us,
            l.misses
        )
    }
}

/// Where the robot is, from the trajectory's last row.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobotAt {
    /// Episode.
    pub episode: u32,
    /// Actions taken in it.
    pub steps: u32,
    /// Cell column and row, `None` out of the arena.
    pub cell: Option<(u16, u16)>,
    /// Orientation, 0..8 (45° steps counter-clockwise from east).
    pub orientation: u16,
}

/// Follows a growing file line by line (whole lines only).
struct Tail {
    path: PathBuf,
    offset: u64,
    partial: String,
}

impl Tail {
    fn new(path: PathBuf) -> Self {
        Self {
            path,
            offset: 0,
            partial: String::new(),
        }
    }

    /// The whole lines added since the last call (none if the file is not there yet).
    fn new_lines(&mut self) -> Vec<String> {
        let Ok(mut file) = File::open(&self.path) else {
            return Vec::new();
        };
        if file.seek(SeekFrom::Start(self.offset)).is_err() {
            return Vec::new();
        }
        let mut reader = BufReader::new(file);
        let mut lines = Vec::new();
        loop {
            let mut line = String::new();
            match reader.read_line(&mut line) {
                Ok(0) | Err(_) => break,
                Ok(n) => {
                    self.offset += n as u64;
                    if line.ends_with('\n') {
                        let mut whole = std::mem::take(&mut self.partial);
                        whole.push_str(line.trim_end_matches(['\n', '\r']));
                        lines.push(whole);
                    } else {
                        self.partial.push_str(&line);
                    }
                }
            }
        }
        lines
    }
}

/// The run folder's records: episodes joined from the controller's lines and perception's
/// trajectory, the last episodes' paths and where the robot is.
pub struct RunRecord {
    dir: PathBuf,
    budget_us: u64,
    arena: Option<ArenaId>,
    lines: BTreeMap<u32, EpisodeLine>,
    ends: BTreeMap<u32, String>,
    /// Episodes written to `episodes.csv`, in order.
    rows: Vec<EpisodeRow>,
    csv: Option<File>,
    trajectory: Tail,
    /// Column indices of the trajectory's header.
    columns: Option<BTreeMap<String, usize>>,
    paths: VecDeque<(u32, Vec<DVec2>)>,
    robot: Option<RobotAt>,
}

impl RunRecord {
    /// The records of the run folder `dir`, for a controller with a `budget_us` decision
    /// budget on arena `arena` (1–3). Creates `episodes.csv`.
    pub fn create(dir: &Path, budget_us: u64, arena: u32) -> Result<Self, IoError> {
        let path = dir.join(EPISODES);
        let mut csv = File::create(&path)
            .map_err(IoError::with(format!("cannot create {}", path.display())))?;
        writeln!(csv, "{EPISODES_HEADER}")
            .map_err(IoError::with(format!("cannot write {}", path.display())))?;
        Ok(Self {
            dir: dir.to_owned(),
            budget_us,
            arena: ArenaId::from_number(arena).ok(),
            lines: BTreeMap::new(),
            ends: BTreeMap::new(),
            rows: Vec::new(),
            csv: Some(csv),
            trajectory: Tail::new(dir.join(TRAJECTORY)),
            columns: None,
            paths: VecDeque::new(),
            robot: None,
        })
    }

    /// Takes a line of the controller's standard output (episode lines; others are ignored).
    pub fn controller_line(&mut self, text: &str) {
        if let Some(line) = EpisodeLine::parse(text) {
            self.lines.insert(line.episode, line);
        }
    }

    /// Reads the trajectory's new rows and writes the episodes now complete.
    pub fn poll(&mut self) {
        for line in self.trajectory.new_lines() {
            self.take_trajectory_row(&line);
        }
        self.write_ready(false);
    }

    fn take_trajectory_row(&mut self, line: &str) {
        let fields: Vec<&str> = line.split(',').collect();
        let Some(columns) = &self.columns else {
            self.columns = Some(
                fields
                    .iter()
                    .enumerate()
                    .map(|(i, f)| ((*f).to_owned(), i))
                    .collect(),
            );
            return;
        };
        let get = |name: &str| columns.get(name).and_then(|&i| fields.get(i)).copied();
        let num = |name: &str| get(name).and_then(|v| v.parse::<f64>().ok());
        let (Some(episode), Some(step)) = (
            get("episode").and_then(|v| v.parse::<u32>().ok()),
            get("step").and_then(|v| v.parse::<u32>().ok()),
        ) else {
            return;
        };
        let point = |x: &str, y: &str| match (num(x), num(y)) {
            (Some(x), Some(y)) => Some(DVec2::new(x, y)),
            _ => None,
        };
        // An episode run again after perception restarted starts its path over.
        if step == 0
            && let Some((e, path)) = self.paths.back_mut()
            && *e == episode
        {
            path.clear();
            path.extend(point("x_cm", "y_cm"));
        }
        if self.paths.back().is_none_or(|(e, _)| *e != episode) {
            if self.paths.len() == PATHS_DRAWN {
                self.paths.pop_front();
            }
            let start = point("x_cm", "y_cm");
            self.paths.push_back((episode, start.into_iter().collect()));
        }
        if let (Some((_, path)), Some(p)) = (self.paths.back_mut(), point("next_x_cm", "next_y_cm"))
        {
            path.push(p);
        }
        let cell = match (num("next_x"), num("next_y")) {
            (Some(x), Some(y)) if x >= 0.0 && y >= 0.0 => Some((x as u16, y as u16)),
            _ => None,
        };
        self.robot = Some(RobotAt {
            episode,
            steps: step + 1,
            cell,
            orientation: num("next_orientation").map_or(0, |o| o.max(0.0) as u16),
        });
        if let Some(end) = get("end").filter(|e| !e.is_empty()) {
            self.ends.insert(episode, end.to_owned());
        }
    }

    /// Writes the episodes whose line and end are both known, in order; `all` writes the
    /// rest too (the run is over).
    fn write_ready(&mut self, all: bool) {
        while let Some((&episode, _)) = self.lines.first_key_value() {
            let end = self.ends.remove(&episode);
            if end.is_none() && !all {
                break;
            }
            let Some(line) = self.lines.remove(&episode) else {
                break;
            };
            let row = EpisodeRow { line, end };
            if let Some(csv) = &mut self.csv
                && writeln!(csv, "{}", row.csv()).is_err()
            {
                self.csv = None;
            }
            self.rows.push(row);
        }
    }

    /// The episodes so far, in order.
    pub fn episodes(&self) -> &[EpisodeRow] {
        &self.rows
    }

    /// Where the robot is, if it has moved.
    pub fn robot(&self) -> Option<RobotAt> {
        self.robot
    }

    /// The last episodes' paths (oldest first), cm.
    #[cfg(test)]
    pub fn paths(&self) -> impl Iterator<Item = &(u32, Vec<DVec2>)> {
        self.paths.iter()
    }

    /// The arena, if it is one of the paper's.
    pub fn arena(&self) -> Option<ArenaId> {
        self.arena
    }

    /// Ends the record: the last rows, every episode written, and the pictures. Returns the
    /// files drawn.
    pub fn finish(&mut self) -> Result<Vec<PathBuf>, IoError> {
        self.poll();
        self.write_ready(true);
        if let Some(csv) = &mut self.csv {
            csv.flush()
                .map_err(IoError::with("cannot write episodes.csv".into()))?;
        }
        let mut drawn = Vec::new();
        let mut write = |name: &str, svg: String| -> Result<(), IoError> {
            let path = self.dir.join(name);
            std::fs::write(&path, svg)
                .map_err(IoError::with(format!("cannot write {}", path.display())))?;
            drawn.push(path);
            Ok(())
        };
        write("rewards.svg", rewards_chart(&self.rows).to_svg())?;
        write(
            "latency.svg",
            latency_chart(&self.rows, self.budget_us).to_svg(),
        )?;
        if let Some(id) = self.arena {
            let paths: Vec<ArenaPath> = self
                .paths
                .iter()
                .map(|(e, points)| ArenaPath {
                    label: format!("episode {e}"),
                    points: points.clone(),
                })
                .collect();
            let title = format!("{id}: the last {} episodes' paths", paths.len());
            write("arena.svg", Arena::new(id).to_svg(&title, &paths))?;
        }
        Ok(drawn)
    }
}

fn flat(x: f64, y: f64) -> BandPoint {
    BandPoint { x, y, lo: y, hi: y }
}

/// Reward per episode, with its moving mean.
pub fn rewards_chart(rows: &[EpisodeRow]) -> LineChart {
    let rewards: Vec<(f64, f64)> = rows
        .iter()
        .map(|r| (f64::from(r.line.episode), r.line.reward))
        .collect();
    let mean = rewards
        .iter()
        .enumerate()
        .map(|(i, &(x, _))| {
            let window = &rewards[i.saturating_sub(MOVING_MEAN - 1)..=i];
            flat(
                x,
                window.iter().map(|w| w.1).sum::<f64>() / window.len() as f64,
            )
        })
        .collect();
    LineChart {
        title: "Reward per episode".into(),
        x_label: "episode".into(),
        y_label: "reward".into(),
        series: vec![
            Series {
                name: "reward".into(),
                points: rewards.iter().map(|&(x, y)| flat(x, y)).collect(),
                colour: Some(0),
            },
            Series {
                name: format!("moving mean of {MOVING_MEAN}"),
                points: mean,
                colour: Some(1),
            },
        ],
        markers: rows.len() <= 60,
    }
}

/// Decision latency percentiles per episode, against the budget.
pub fn latency_chart(rows: &[EpisodeRow], budget_us: u64) -> LineChart {
    let series = |name: &str, slot, value: fn(&EpisodeLine) -> u64| Series {
        name: name.into(),
        points: rows
            .iter()
            .map(|r| flat(f64::from(r.line.episode), value(&r.line) as f64))
            .collect(),
        colour: Some(slot),
    };
    let mut all = vec![
        series("p50", 2, |l| l.p50_us),
        series("p99", 3, |l| l.p99_us),
        series("max", 4, |l| l.max_us),
    ];
    all.push(Series {
        name: format!("budget ({budget_us} us)"),
        points: rows
            .iter()
            .map(|r| flat(f64::from(r.line.episode), budget_us as f64))
            .collect(),
        colour: Some(5),
    });
    LineChart {
        title: "Decision latency per episode".into(),
        x_label: "episode".into(),
        y_label: "observation to command, us".into(),
        series: all,
        markers: rows.len() <= 60,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(episode: u32, reward: f64) -> String {
        EpisodeLine {
            episode,
            reward,
            steps: 3,
            p50_us: 5,
            p99_us: 9,
            max_us: 40,
            misses: 0,
        }
        .to_string()
    }

    /// An episode is written once both its controller line and its end are known, whichever
    /// comes first; the trajectory is read as it grows, half-written lines waited for.
    #[test]
    fn episodes_join_the_controllers_lines_and_the_trajectorys_ends() {
        let dir = tempfile::tempdir().unwrap();
        let mut record = RunRecord::create(dir.path(), 1000, 3).unwrap();
        let trajectory = dir.path().join(TRAJECTORY);
        let header = tes_perception_sim::process::trajectory::HEADER;
        let row = |episode: u32, step: u32, end: &str| {
            format!("{episode},{step},1,2,0,0,0,-0.05,2,2,0,15.0,27.0,0.0,33.0,27.0,0.0,{end}\n")
        };
        std::fs::write(&trajectory, format!("{header}\n{}", row(0, 0, ""))).unwrap();
        record.controller_line("controller: warming up");
        record.controller_line(&line(0, 1.5));
        record.poll();
        assert!(record.episodes().is_empty(), "episode 0 has not ended yet");
        let mut file = std::fs::OpenOptions::new()
            .append(true)
            .open(&trajectory)
            .unwrap();
        let last = row(0, 1, "ball");
        let (a, b) = last.split_at(10);
        file.write_all(a.as_bytes()).unwrap();
        record.poll();
        assert!(record.episodes().is_empty(), "half a line is not a row");
        file.write_all(b.as_bytes()).unwrap();
        file.write_all(row(1, 0, "stuck").as_bytes()).unwrap();
        record.poll();
        assert_eq!(record.episodes().len(), 1);
        assert_eq!(record.episodes()[0].end.as_deref(), Some("ball"));
        let robot = record.robot().unwrap();
        assert_eq!(
            (robot.episode, robot.steps, robot.cell),
            (1, 1, Some((2, 2)))
        );
        record.controller_line(&line(1, -0.2));
        record.controller_line(&line(2, 0.1));
        let drawn = record.finish().unwrap();
        assert_eq!(drawn.len(), 3);
        let csv = std::fs::read_to_string(dir.path().join(EPISODES)).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(
            lines,
            [
                EPISODES_HEADER,
                "0,1.50,3,ball,5,9,40,0",
                "1,-0.20,3,stuck,5,9,40,0",
                "2,0.10,3,,5,9,40,0"
            ]
        );
        let paths: Vec<_> = record.paths().collect();
        assert_eq!(paths.len(), 2);
        assert_eq!(paths[0].1.len(), 3, "the start and two moves");
        let arena = std::fs::read_to_string(dir.path().join("arena.svg")).unwrap();
        assert_eq!(arena.matches(r#"class="path""#).count(), 2);
        let rewards = std::fs::read_to_string(dir.path().join("rewards.svg")).unwrap();
        assert!(rewards.contains("moving mean of 5"), "{rewards}");
        let latency = std::fs::read_to_string(dir.path().join("latency.svg")).unwrap();
        assert!(latency.contains("budget (1000 us)"));
    }
}
