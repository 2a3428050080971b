//! What an observer of the group costs it: the recorder (`tes bench latency --record`), the
//! live Foxglove server with a viewer reading every channel (`--foxglove`), the same server
//! followed by Rerun's own viewer (`--rerun`, [`crate::rerun_client`]), or the group's ROS 2
//! side publishing the run on DDS (`--ros2`; its subscribers are outside). The measured group
//! runs in blocks without and with it, alternating, each from the same starting library,
//! compared by the medians over the blocks of each kind.

use std::path::{Path, PathBuf};

use tes_launch::Event;
use tes_recorder::reader::Recording;

use crate::error::{BenchError, Result};
use crate::group::Group;
use crate::harness::{Harness, LatencySettings, Note};
pub use crate::harness::{RecorderBlock, RecorderComparison, Watcher};
use crate::rerun_client::RerunClient;
use crate::viewer_client::ViewerClient;

/// Runs `2 × record_blocks` blocks of `actions / record_blocks` measured actions each,
/// without and with `watcher` in turn ([`block_is_recorded`]), and compares them.
pub(crate) fn compare(
    group: &Group,
    settings: &LatencySettings,
    harness: &mut Harness<'_>,
    watcher: Watcher,
) -> Result<RecorderComparison> {
    let measured = (settings.actions() / settings.record_blocks.max(1)).max(1);
    let mut block_file = group.file.clone();
    block_file.perception.actions = measured + settings.warmup();
    let mcap = group.dir.join("bench.mcap");
    let kinds = 2 * settings.record_blocks;
    let mut blocks = Vec::new();
    for i in 0..kinds {
        let with = block_is_recorded(i);
        (harness.notes)(&Note::RecorderBlock {
            block: i + 1,
            of: kinds,
            recorded: with,
            watcher,
            measured,
        });
        let mut file = block_file.clone();
        match watcher {
            Watcher::Recorder => file.launch.record = with.then(|| mcap.clone()),
            Watcher::Ros2 => file.launch.ros2 = with,
            Watcher::Foxglove | Watcher::Rerun => {
                file.launch.foxglove = with.then(|| "127.0.0.1:0".to_owned());
            }
        }
        let viewer = match (watcher, &settings.rerun) {
            (Watcher::Rerun, Some(script)) => Viewer::Rerun {
                script,
                rrd: group.dir.join("bench.rrd"),
            },
            _ => Viewer::Bench,
        };
        let ((report, summary), viewer_messages) = run_watched(group, &file, harness, &viewer)?;
        if report.count < measured {
            return Err(BenchError::Run(format!(
                "block {}: the bridge saw {} measured commands, expected {measured}",
                i + 1,
                report.count
            )));
        }
        let (written, missed) = if with && watcher == Watcher::Recorder {
            let (written, missed) = what_was_recorded(&mcap, i + 1)?;
            (Some(written), Some(missed))
        } else {
            (None, None)
        };
        blocks.push(RecorderBlock {
            recorded: with,
            p50_us: report.p50_us,
            p99_us: report.p99_us,
            misses: report.misses,
            allocations: summary.allocations,
            written,
            missed,
            viewer_messages,
        });
    }
    Ok(comparison(watcher, blocks))
}

type Reports = (
    tes_runtime::latency::LatencyReport,
    tes_controller::process::ControllerSummary,
);

/// Who follows a launch that serves Foxglove.
enum Viewer<'a> {
    /// The bench's own client, reading every channel.
    Bench,
    /// `python3 script --live ADDR -o rrd` (`python/tes/rerun_view.py`).
    Rerun { script: &'a Path, rrd: PathBuf },
}

/// A viewer following a block.
enum Following {
    Bench(ViewerClient),
    Rerun(RerunClient),
}

impl Following {
    fn start(viewer: &Viewer<'_>, addr: std::net::SocketAddr) -> Result<Self> {
        match viewer {
            Viewer::Bench => ViewerClient::connect(addr).map(Self::Bench),
            Viewer::Rerun { script, rrd } => RerunClient::spawn(script, addr, rrd).map(Self::Rerun),
        }
    }

    /// Ends it; the messages it received (the bench's client) or drew (Rerun's).
    fn stop(self) -> Result<u64> {
        match self {
            Self::Bench(client) => Ok(client.stop()),
            Self::Rerun(client) => client.stop(),
        }
    }
}

/// Runs the group once; when its launch serves Foxglove, `viewer` follows it throughout and
/// the messages it received are returned too.
fn run_watched(
    group: &Group,
    file: &tes_launch::LaunchFile,
    harness: &mut Harness<'_>,
    viewer: &Viewer<'_>,
) -> Result<(Reports, Option<u64>)> {
    let mut following: Option<Following> = None;
    let mut failed = None;
    let inner = &mut *harness.observer;
    let mut watching = |e: &Event| {
        if let Event::Foxglove { addr, .. } = e {
            match Following::start(viewer, *addr) {
                Ok(f) => following = Some(f),
                Err(e) => failed = Some(e),
            }
        }
        inner.event(e);
    };
    let mut watched = Harness {
        programs: harness.programs.clone(),
        stop: harness.stop.clone(),
        observer: &mut watching,
        notes: &mut *harness.notes,
    };
    let ran = group.run(file, &mut watched);
    let received = following.map(Following::stop).transpose();
    if let Some(e) = failed {
        return Err(e);
    }
    let ran = ran?;
    Ok((ran, received?))
}

/// Whether block `i` of the comparison runs with the recorder: without, with, with, without,
/// and again, so that a drift of the machine over the run weighs on both kinds alike.
pub fn block_is_recorded(i: u64) -> bool {
    matches!(i % 4, 1 | 2)
}

/// The observations, commands and motor states block `block`'s recording holds, and the
/// samples its recorder said it missed.
fn what_was_recorded(mcap: &Path, block: u64) -> Result<([u64; 3], u64)> {
    let recording = Recording::open(mcap)?;
    if let Some(why) = &recording.truncated {
        return Err(BenchError::Run(format!(
            "block {block}: the recording is incomplete: {why}"
        )));
    }
    let missed = recording.end.as_ref().map_or(0, |end| {
        [
            "missed_observations",
            "missed_commands",
            "missed_motor_states",
        ]
        .iter()
        .filter_map(|k| end.get(*k).and_then(|v| v.parse::<u64>().ok()))
        .sum()
    });
    let written = [
        recording.observations.len() as u64,
        recording.commands.len() as u64,
        recording.motor_states.len() as u64,
    ];
    Ok((written, missed))
}

/// The comparison of `blocks`: the medians of each kind and their change.
fn comparison(watcher: Watcher, blocks: Vec<RecorderBlock>) -> RecorderComparison {
    let of = |recorded: bool, pick: fn(&RecorderBlock) -> u64| {
        median(blocks.iter().filter(|b| b.recorded == recorded).map(pick))
    };
    let (without_p50_us, without_p99_us) = (of(false, |b| b.p50_us), of(false, |b| b.p99_us));
    let (with_p50_us, with_p99_us) = (of(true, |b| b.p50_us), of(true, |b| b.p99_us));
    let change = |with: f64, without: f64| with / without.max(1.0) - 1.0;
    let allocations_with = blocks
        .iter()
        .filter(|b| b.recorded)
        .map(|b| b.allocations)
        .try_fold(0, |most, n| n.map(|n| most.max(n)));
    RecorderComparison {
        watcher,
        change_p50: change(with_p50_us, without_p50_us),
        change_p99: change(with_p99_us, without_p99_us),
        blocks,
        without_p50_us,
        without_p99_us,
        with_p50_us,
        with_p99_us,
        allocations_with,
    }
}

/// The median of `values` (the mean of the middle two for an even count); 0 for none.
pub fn median(values: impl IntoIterator<Item = u64>) -> f64 {
    let mut v: Vec<u64> = values.into_iter().collect();
    v.sort_unstable();
    match v.len() {
        0 => 0.0,
        n if n % 2 == 1 => v[n / 2] as f64,
        n => (v[n / 2 - 1] + v[n / 2]) as f64 / 2.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn block(recorded: bool, p50_us: u64, allocations: Option<u64>) -> RecorderBlock {
        RecorderBlock {
            recorded,
            p50_us,
            p99_us: 2 * p50_us,
            misses: 0,
            allocations,
            written: None,
            missed: None,
            viewer_messages: None,
        }
    }

    #[test]
    fn blocks_alternate_so_a_drift_weighs_on_both_kinds() {
        let kinds: Vec<bool> = (0..8).map(block_is_recorded).collect();
        assert_eq!(kinds, [false, true, true, false, false, true, true, false]);
    }

    #[test]
    fn the_median_of_an_even_count_is_the_mean_of_the_middle_two() {
        assert_eq!(median([4, 1, 3, 2]), 2.5);
        assert_eq!(median([5, 1, 3]), 3.0);
        assert_eq!(median([]), 0.0);
    }

    #[test]
    fn the_comparison_is_of_the_medians_of_each_kind() {
        let c = comparison(
            Watcher::Recorder,
            vec![
                block(false, 100, Some(0)),
                block(true, 110, Some(0)),
                block(true, 130, Some(2)),
                block(false, 100, Some(0)),
            ],
        );
        assert_eq!(c.without_p50_us, 100.0);
        assert_eq!(c.with_p50_us, 120.0);
        assert!((c.change_p50 - 0.2).abs() < 1e-12);
        assert!((c.change_p99 - 0.2).abs() < 1e-12);
        assert_eq!(c.allocations_with, Some(2));
        let uncounted = comparison(
            Watcher::Foxglove,
            vec![block(true, 1, None), block(true, 1, Some(3))],
        );
        assert_eq!(uncounted.allocations_with, None);
    }
}
