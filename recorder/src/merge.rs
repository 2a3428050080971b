//! The group's streams merged into one, in the order of their publish times.
//!
//! The recorder reads four streams: observations, commands, motor states and world poses,
//! each published by one process in the order of its stamps (one monotonic clock for the
//! host; the link restamps what it brings in). It reads them one after the other, so a
//! sample published while it reads one stream can be found in the next stream read before
//! an older one of the first: drawn in that order, the robot's belief goes back in time (a
//! motor report moves it, then the observation before that report arrives). Here every
//! sample waits until no stream can still bring an older one: each other stream has shown
//! a sample at least as new, or the sample is older than [`STRAGGLER_GRACE_NS`] before the
//! read began (a publisher stamps, then sends at once; only a process descheduled between
//! the two for that long could still bring an older one).

use std::collections::VecDeque;

use tes_topics::{Command, MotorState, Observation, WorldPose};

/// How long a sample waits for the streams that have shown nothing as new, ns: far longer
/// than a publisher is descheduled between stamping a sample and sending it on a loaded
/// machine, and short enough for a live view (it is the lag a silent stream adds, such as
/// world poses from a perception on another host).
pub(crate) const STRAGGLER_GRACE_NS: u64 = 250_000_000;

/// One sample of the group.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Sample {
    Observation(Observation),
    Command(Command),
    MotorState(MotorState),
    WorldPose(WorldPose),
}

impl Sample {
    fn stamp_ns(&self) -> u64 {
        match self {
            Sample::Observation(o) => o.stamp_ns,
            Sample::Command(c) => c.stamp_ns,
            Sample::MotorState(m) => m.stamp_ns,
            Sample::WorldPose(w) => w.stamp_ns,
        }
    }

    /// Its stream: also the order of samples with the same stamp (an observation before
    /// the command answering it, the motion's reports before the world's pose after it).
    fn stream(&self) -> usize {
        match self {
            Sample::Observation(_) => 0,
            Sample::Command(_) => 1,
            Sample::MotorState(_) => 2,
            Sample::WorldPose(_) => 3,
        }
    }
}

const STREAMS: usize = 4;

/// Samples taken but not yet handed on, by stream.
#[derive(Debug)]
pub(crate) struct Merge {
    waiting: [VecDeque<Sample>; STREAMS],
    /// The newest stamp each stream has shown.
    newest_ns: [Option<u64>; STREAMS],
}

impl Merge {
    /// Room for `capacity` waiting samples of each stream before it grows.
    pub(crate) fn with_capacity(capacity: usize) -> Self {
        Self {
            waiting: std::array::from_fn(|_| VecDeque::with_capacity(capacity)),
            newest_ns: [None; STREAMS],
        }
    }

    /// Takes a sample read from its stream.
    pub(crate) fn push(&mut self, sample: Sample) {
        let (stream, stamp) = (sample.stream(), sample.stamp_ns());
        self.newest_ns[stream] = Some(self.newest_ns[stream].map_or(stamp, |n| n.max(stamp)));
        self.waiting[stream].push_back(sample);
    }

    /// The oldest sample waiting, if no stream can still bring an older one: each other
    /// stream has shown one at least as new, or it is [`STRAGGLER_GRACE_NS`] older than
    /// `read_ns` (when the streams were last read, taken before reading them), or `all`
    /// (the run is over: nothing more comes).
    pub(crate) fn next_ready(&mut self, read_ns: u64, all: bool) -> Option<Sample> {
        let (stream, stamp) = self
            .waiting
            .iter()
            .enumerate()
            .filter_map(|(i, q)| q.front().map(|s| (i, s.stamp_ns())))
            .min_by_key(|&(i, stamp)| (stamp, i))?;
        let overdue = stamp.saturating_add(STRAGGLER_GRACE_NS) <= read_ns;
        let others_newer = self
            .newest_ns
            .iter()
            .enumerate()
            .all(|(i, newest)| i == stream || newest.is_some_and(|n| n >= stamp));
        if all || overdue || others_newer {
            self.waiting[stream].pop_front()
        } else {
            None
        }
    }

    /// The stamp of the oldest sample waiting.
    pub(crate) fn oldest_ns(&self) -> Option<u64> {
        self.waiting
            .iter()
            .filter_map(|q| q.front().map(Sample::stamp_ns))
            .min()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn observation(stamp_ns: u64) -> Sample {
        Sample::Observation(Observation {
            stamp_ns,
            ..Observation::default()
        })
    }

    fn motor(stamp_ns: u64) -> Sample {
        Sample::MotorState(MotorState {
            stamp_ns,
            ..MotorState::default()
        })
    }

    fn command(stamp_ns: u64) -> Sample {
        Sample::Command(Command {
            stamp_ns,
            ..Command::default()
        })
    }

    fn pose(stamp_ns: u64) -> Sample {
        Sample::WorldPose(WorldPose {
            stamp_ns,
            ..WorldPose::default()
        })
    }

    fn stamps(merge: &mut Merge, read_ns: u64, all: bool) -> Vec<u64> {
        std::iter::from_fn(|| merge.next_ready(read_ns, all))
            .map(|s| s.stamp_ns())
            .collect()
    }

    /// The race the merge exists for: the motor reports were read after an observation
    /// published between the two reads, so they hold reports newer than it.
    #[test]
    fn a_sample_read_late_from_one_stream_still_comes_out_in_time_order() {
        let mut merge = Merge::with_capacity(8);
        let read_ns = 1_000;
        merge.push(observation(100));
        merge.push(command(110));
        merge.push(pose(105));
        for t in [120, 130, 150, 160] {
            merge.push(motor(t));
        }
        // Observations have shown nothing newer than 100: an observation between 100 and
        // the pose at 105 may still be on its way, so only the observation goes out.
        assert_eq!(stamps(&mut merge, read_ns, false), vec![100]);
        merge.push(observation(140));
        merge.push(command(150));
        merge.push(pose(145));
        assert_eq!(
            stamps(&mut merge, read_ns, false),
            vec![105, 110, 120, 130, 140]
        );
        // At the end everything goes, in order.
        assert_eq!(stamps(&mut merge, read_ns, true), vec![145, 150, 150, 160]);
        assert_eq!(merge.oldest_ns(), None);
    }

    #[test]
    fn a_silent_stream_holds_samples_back_only_for_the_grace() {
        let mut merge = Merge::with_capacity(8);
        merge.push(observation(10));
        merge.push(command(20));
        merge.push(motor(30));
        // No world pose yet (a perception on another host sends none).
        assert_eq!(stamps(&mut merge, 1_000, false), Vec::<u64>::new());
        assert_eq!(merge.oldest_ns(), Some(10));
        assert_eq!(
            stamps(&mut merge, 20 + STRAGGLER_GRACE_NS, false),
            vec![10, 20]
        );
        assert_eq!(merge.oldest_ns(), Some(30));
    }

    #[test]
    fn equal_stamps_go_observation_command_motor_pose() {
        let mut merge = Merge::with_capacity(8);
        for s in [pose(5), motor(5), command(5), observation(5)] {
            merge.push(s);
        }
        let order: Vec<usize> = std::iter::from_fn(|| merge.next_ready(0, false))
            .map(|s| s.stream())
            .collect();
        assert_eq!(order, vec![0, 1, 2, 3]);
    }
}
