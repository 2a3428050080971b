//! What a recording says about its run, from the file alone: its episodes as `tes launch`
//! printed them, the decision latencies, and per-topic CSV files.

use std::io::Write;
use std::path::{Path, PathBuf};
use tes_controller::summary::EpisodeLine;

use tes_runtime::latency::LatencyRecorder;
use tes_topics::observation_flags;

use crate::reader::Recording;
use crate::schema::Topic;

/// One episode of a recorded run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Episode {
    /// Its line as `tes launch` printed it: reward (of the moves learned from), steps
    /// (commands that answered its observations), decision latency (observation stamped →
    /// command stamped) and misses against `[controller] budget_us`.
    pub line: EpisodeLine,
    /// Whether it ended (a terminal or truncated observation is in the file).
    pub ended: bool,
}

/// A recorded run's summary.
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    /// Its episodes, in order.
    pub episodes: Vec<Episode>,
    /// Decisions.
    pub actions: u64,
    /// Decision latency over the run: p50, p90, p99, max, µs.
    pub latency_us: [u64; 4],
}

/// Summarises `recording`: the latencies go through the controller's own recorder
/// ([`LatencyRecorder`]), so the percentiles are the ones `tes launch` printed.
pub fn summarise(recording: &Recording) -> Summary {
    // The budget the controller counted misses against (its default if the file has none).
    let budget_us =
        tes_controller::config::ControllerConfig::from_toml(recording.run_value("controller_toml"))
            .map_or(1000, |c| c.budget_us);
    let mut episodes: Vec<Episode> = Vec::new();
    let mut episode_latency = LatencyRecorder::new(budget_us, 0);
    let mut all = LatencyRecorder::new(budget_us, 0);
    let mut actions = 0u64;
    let by_answer: std::collections::HashMap<u64, &tes_topics::Command> =
        recording.commands.iter().map(|c| (c.answers, c)).collect();
    let mut observations: Vec<_> = recording.observations.iter().collect();
    observations.sort_by_key(|o| o.seq);
    let close = |e: &mut Episode, l: &mut LatencyRecorder| {
        let line = &mut e.line;
        (line.p50_us, line.p99_us, line.max_us, line.misses) = (
            l.quantile_us(0.5),
            l.quantile_us(0.99),
            l.max_us(),
            l.misses(),
        );
        l.reset();
    };
    for o in observations {
        if episodes.last().is_none_or(|e| e.line.episode != o.episode) {
            if let Some(e) = episodes.last_mut() {
                close(e, &mut episode_latency);
            }
            episodes.push(Episode {
                line: EpisodeLine {
                    episode: o.episode,
                    reward: 0.0,
                    steps: 0,
                    p50_us: 0,
                    p99_us: 0,
                    max_us: 0,
                    misses: 0,
                },
                ended: false,
            });
        }
        let Some(e) = episodes.last_mut() else {
            continue;
        };
        if o.flags & (observation_flags::EPISODE_START | observation_flags::RESYNC) == 0 {
            e.line.reward += f64::from(o.reward);
        }
        if o.flags & (observation_flags::TERMINAL | observation_flags::TRUNCATED) != 0 {
            e.ended = true;
        }
        if let Some(c) = by_answer.get(&o.seq) {
            e.line.steps += 1;
            let ns = c.stamp_ns.saturating_sub(c.observed_ns);
            episode_latency.record_ns(ns);
            all.record_ns(ns);
            actions += 1;
        }
    }
    if let Some(e) = episodes.last_mut() {
        close(e, &mut episode_latency);
    }
    // The maximum from the same histogram as the quantiles (both the top of a bucket), and
    // the quantiles held to it: a p99 above the max would be a contradiction on the page.
    let max = all.max_us();
    Summary {
        episodes,
        actions,
        latency_us: [
            all.quantile_us(0.5).min(max),
            all.quantile_us(0.9).min(max),
            all.quantile_us(0.99).min(max),
            max,
        ],
    }
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for e in &self.episodes {
            writeln!(
                f,
                "{}{}",
                e.line,
                if e.ended { "" } else { " (did not end)" }
            )?;
        }
        let ended = self.episodes.iter().filter(|e| e.ended).count();
        let [p50, p90, p99, max] = self.latency_us;
        write!(
            f,
            "{}, {}; decision latency p50 {p50} us, p90 {p90} us, p99 {p99} us, max {max} us",
            tes_controller::summary::count(ended as u64, "episode"),
            tes_controller::summary::count(self.actions, "action"),
        )
    }
}

/// Why the CSV export failed.
#[derive(Debug, thiserror::Error)]
#[error("cannot write {}: {error}", path.display())]
pub struct ExportError {
    /// The file or directory.
    pub path: PathBuf,
    /// Why.
    pub error: std::io::Error,
}

/// Writes one CSV file per topic with messages into `dir` (created if missing): a header,
/// then a row per message; feature lists as space-separated indices. Returns the files.
pub fn export_csv(recording: &Recording, dir: &Path) -> Result<Vec<PathBuf>, ExportError> {
    std::fs::create_dir_all(dir).map_err(fail(dir))?;
    let mut written = Vec::new();
    let mut file = |topic: Topic, header: &str, rows: Vec<String>| -> Result<(), ExportError> {
        let path = dir.join(format!("{}.csv", topic.stem()));
        write_csv(&path, header, rows)?;
        written.push(path);
        Ok(())
    };
    file(
        Topic::Observation,
        OBSERVATION_HEADER,
        recording.observations.iter().map(observation_row).collect(),
    )?;
    file(
        Topic::Command,
        COMMAND_HEADER,
        recording.commands.iter().map(command_row).collect(),
    )?;
    file(
        Topic::KeepAlive,
        COMMAND_HEADER,
        recording.keepalives.iter().map(command_row).collect(),
    )?;
    file(
        Topic::MotorState,
        MOTOR_STATE_HEADER,
        recording.motor_states.iter().map(motor_state_row).collect(),
    )?;
    if let Some(map) = &recording.world_map {
        file(Topic::WorldMap, WORLD_MAP_HEADER, world_map_rows(map))?;
    }
    Ok(written)
}

/// Turns an I/O error on `path` into an [`ExportError`] naming it.
fn fail(path: &Path) -> impl FnOnce(std::io::Error) -> ExportError {
    let path = path.to_owned();
    move |error| ExportError { path, error }
}

/// Writes `header` and then `rows`, a line each, to `path`.
fn write_csv(path: &Path, header: &str, rows: Vec<String>) -> Result<(), ExportError> {
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).map_err(fail(path))?);
    writeln!(out, "{header}").map_err(fail(path))?;
    for row in rows {
        writeln!(out, "{row}").map_err(fail(path))?;
    }
    out.flush().map_err(fail(path))
}

/// A feature list as space-separated indices.
fn features(f: &tes_topics::FeatureBits) -> String {
    f.iter_ones()
        .map(|i| i.to_string())
        .collect::<Vec<_>>()
        .join(" ")
}

const OBSERVATION_HEADER: &str =
    "seq,stamp_ns,after_command,episode,step,x,y,orientation,n_features,reward,flags,features";

fn observation_row(o: &tes_topics::Observation) -> String {
    format!(
        "{},{},{},{},{},{},{},{},{},{},{},{}",
        o.seq,
        o.stamp_ns,
        o.after_command,
        o.episode,
        o.step,
        o.state.x,
        o.state.y,
        o.state.orientation,
        o.n_features,
        o.reward,
        o.flags,
        features(&o.features)
    )
}

/// Commands and keep-alives alike.
const COMMAND_HEADER: &str =
    "seq,answers,stamp_ns,observed_ns,action,left_deg,right_deg,in_flight_action,plans";

fn command_row(c: &tes_topics::Command) -> String {
    format!(
        "{},{},{},{},{},{},{},{},{}",
        c.seq,
        c.answers,
        c.stamp_ns,
        c.observed_ns,
        c.action,
        c.left_deg,
        c.right_deg,
        c.in_flight_action,
        c.plans
    )
}

const MOTOR_STATE_HEADER: &str = "seq,after_command,stamp_ns,tacho_a,tacho_b,tacho_c,rotation_a,rotation_b,rotation_c,run_a,run_b,run_c,battery_mv,flags";

fn motor_state_row(m: &tes_topics::MotorState) -> String {
    format!(
        "{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
        m.seq,
        m.after_command,
        m.stamp_ns,
        m.tacho_count[0],
        m.tacho_count[1],
        m.tacho_count[2],
        m.rotation_count[0],
        m.rotation_count[1],
        m.rotation_count[2],
        m.run_state[0],
        m.run_state[1],
        m.run_state[2],
        m.battery_mv,
        m.flags
    )
}

const WORLD_MAP_HEADER: &str = "state,reward,terminal,next_state_per_effect,features";

/// A row per state: its reward, whether it is terminal, the state each effect leads to, and
/// its features.
fn world_map_rows(map: &tes_topics::WorldMap) -> Vec<String> {
    (0..map.n_states as usize)
        .map(|s| {
            let next = map.next_state[s][..map.n_effects as usize]
                .iter()
                .map(|n| n.to_string())
                .collect::<Vec<_>>()
                .join(" ");
            format!(
                "{s},{},{},{next},{}",
                map.reward[s],
                map.terminal[s],
                features(&map.features[s])
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use tes_topics::{Command, Observation};

    /// One episode of decisions taking `latencies_ns`, as a recording holds it.
    fn recording(latencies_ns: &[u64]) -> Recording {
        let mut observations = Vec::new();
        let mut commands = Vec::new();
        for (i, &ns) in latencies_ns.iter().enumerate() {
            let seq = i as u64 + 1;
            observations.push(Observation {
                seq,
                step: i as u32,
                flags: if i == 0 {
                    observation_flags::EPISODE_START
                } else {
                    0
                },
                ..Observation::default()
            });
            commands.push(Command {
                seq,
                answers: seq,
                observed_ns: 1_000_000,
                stamp_ns: 1_000_000 + ns,
                ..Command::default()
            });
        }
        Recording {
            path: PathBuf::from("run.mcap"),
            run: Default::default(),
            end: None,
            world_map: None,
            observations,
            commands,
            keepalives: Vec::new(),
            motor_states: Vec::new(),
            library: None,
            truncated: None,
        }
    }

    /// Latencies whose largest falls inside a histogram bucket: no quantile is printed above
    /// the maximum, and one action or episode is said in the singular.
    #[test]
    fn no_quantile_exceeds_the_maximum() {
        let mut latencies: Vec<u64> = (0..200).map(|i| 40_000 + i * 7).collect();
        latencies.push(2_049_001);
        let summary = summarise(&recording(&latencies));
        let [p50, p90, p99, max] = summary.latency_us;
        assert!(
            p50 <= p90 && p90 <= p99 && p99 <= max,
            "{p50} {p90} {p99} {max}"
        );
        let one = summarise(&recording(&[5_000])).to_string();
        assert!(
            one.ends_with(
                "0 episodes, 1 action; decision latency p50 5 us, p90 5 us, p99 5 us, max 5 us"
            ),
            "{one}"
        );
    }
}
