//! The controller's per-action latency measured against the raw transport's floor (`tes bench
//! latency`).
//!
//! [`run`] runs, one after the other:
//!
//! 1. **ours** — the real group (through [`tes_launch::run`]): perception-sim on arena Env 3
//!    at the fastest real-time factor, the controller with a view library trained in Env 1
//!    and 2, the bridge with the simulated brick; the bridge records each command's latency
//!    from the observation's stamp, on arrival. With [`Via::Zenoh`] the group is split in two
//!    launches linked by Zenoh on loopback TCP;
//! 2. **the floor** ([`crate::floor`]) — the loop's payloads relayed (Observation → Command →
//!    MotorState) with the same wait strategy, no work, and the same cadence (the mean time
//!    between our actions, mostly the simulated robot moving), measured where the bridge
//!    measures: by [`crate::relay`]'s three processes over iceoryx2, or by the same two hops
//!    over the split launch's Zenoh link; at the fastest pace it runs again with every CPU
//!    kept out of its idle state ([`crate::keep_awake`]), the help the group's busy
//!    processes give each other;
//! 3. with `record` and `foxglove`, what the recorder and the live Foxglove server (with a
//!    viewer) cost the group ([`crate::recorder_cost`]).
//!
//! Both leave out the same warm-up and count overruns of the same budget. `wait` applies to
//! the two measured receivers (controller and bridge, hop and sink); perception and the
//! floor's source wait for the robot's motion by blocking, since on 2 cores three
//! busy-polling processes starve each other.
//!
//! Every process the harness starts is a program of the caller's ([`Programs`]): the
//! command line passes its own executable in each role.

use std::path::Path;
use std::time::Instant;

use tes_learning::library::store::StoredLibrary;
use tes_runtime::affinity;

use crate::error::{BenchError, Result};
use crate::fixtures;
use crate::floor;
use crate::group::{Carrier, Group};
pub use crate::harness::{
    AwakeFloor, COMPARABLE_RATIO, CheckedLatency, Floor, Harness, LatencyResult, LatencySettings,
    Note, Pace, Programs, REAL_LINK_DELAY_MS, Via,
};
use crate::harness::{Ours, comparable, ratio};
use crate::keep_awake::KeepAwake;
use crate::recorder_cost::{self, RecorderComparison, Watcher};
/// Runs the group, then the floor, then (with `record`, `foxglove`) the observers'
/// comparisons; keeps the
/// run's files in `out` (else in a temporary directory).
pub fn run(latency: &CheckedLatency, harness: &mut Harness<'_>) -> Result<LatencyResult> {
    let s = &latency.settings;
    let temp;
    let dir: &Path = match &s.out {
        Some(d) => {
            std::fs::create_dir_all(d)
                .map_err(BenchError::io(format!("cannot create {}", d.display())))?;
            d
        }
        None => {
            temp = tempfile::tempdir()
                .map_err(BenchError::io("cannot create a temporary directory".into()))?;
            temp.path()
        }
    };
    let prefix = format!("tes-bench-{}/", std::process::id());
    (harness.notes)(&Note::Training { views: s.views });
    let library = fixtures::arena_library(s.views, 3000, s.seed).map_err(BenchError::fixture)?;
    let stored = StoredLibrary {
        library,
        world: "arena 1+2 (bench)".into(),
        action_names: Vec::new(),
        feature_names: Vec::new(),
    };
    let group = Group::new(dir, &prefix, latency, stored);
    let ours = measure_ours(latency, &group, harness)?;
    let floor = measure_floor(latency, dir, &prefix, ours.cycle_us, false, harness)?;
    // At the robot's pace both sides wake from the same idleness (that is what the pace
    // measures); back to back, the group's busy processes keep CPUs awake for each other,
    // which the bare floor lacks: it runs again with that help.
    let floor_awake = match s.pace {
        Pace::Fastest => Some(measure_floor(
            latency,
            dir,
            &prefix,
            ours.cycle_us,
            true,
            harness,
        )?),
        Pace::Real => None,
    };
    let recorder = if s.record {
        Some(recorder_cost::compare(
            &group,
            s,
            harness,
            Watcher::Recorder,
        )?)
    } else {
        None
    };
    let foxglove = if s.foxglove {
        Some(recorder_cost::compare(
            &group,
            s,
            harness,
            Watcher::Foxglove,
        )?)
    } else {
        None
    };
    let rerun = if s.rerun.is_some() {
        Some(recorder_cost::compare(&group, s, harness, Watcher::Rerun)?)
    } else {
        None
    };
    let ros2 = if s.ros2 {
        Some(recorder_cost::compare(&group, s, harness, Watcher::Ros2)?)
    } else {
        None
    };
    Ok(result(
        latency,
        ours,
        floor,
        floor_awake,
        [recorder, foxglove, rerun, ros2],
    ))
}

/// Runs our group (shared memory or split) and checks it measured what was asked.
fn measure_ours(
    latency: &CheckedLatency,
    group: &Group,
    harness: &mut Harness<'_>,
) -> Result<Ours> {
    let s = &latency.settings;
    let total = latency.total();
    (harness.notes)(&Note::Ours {
        total,
        pace: s.pace,
        wait: s.chosen_wait(),
    });
    let started = Instant::now();
    let (report, controller) = match s.via {
        Via::Shm => group.run(&group.file, harness)?,
        Via::Zenoh | Via::ZenohTls => {
            group.run_split(&Carrier::for_via(s.via, &group.dir)?, harness)?
        }
    };
    let (cpu, catches, command_hop) = group.bridge_and_perception(&controller)?;
    let elapsed = started.elapsed();
    if report.count < s.actions() {
        return Err(BenchError::Run(format!(
            "the bridge saw {} measured commands, expected {} (see the run's files with --out)",
            report.count,
            s.actions()
        )));
    }
    if controller.placement != latency.placement {
        return Err(BenchError::Run(format!(
            "the controller placed its threads at {:?}, not at {:?} as asked: the floor's hop would not match",
            controller.placement, latency.placement
        )));
    }
    let cycle_us = (elapsed.as_micros() / u128::from(total)) as u64;
    Ok(Ours {
        report,
        controller,
        cpu,
        catches,
        command_hop,
        cycle_us,
    })
}

/// Runs the floor of `via` at our cadence (with `awake`, every CPU kept out of its idle
/// state, in a folder and service names of its own): its round trip, and its first hop alone.
fn measure_floor(
    latency: &CheckedLatency,
    dir: &Path,
    prefix: &str,
    cycle_us: u64,
    awake: bool,
    harness: &mut Harness<'_>,
) -> Result<Floor> {
    let s = &latency.settings;
    (harness.notes)(&Note::Floor {
        via: s.via,
        total: latency.total(),
        wait: s.acting_wait(),
        cycle_us,
        awake,
    });
    if !awake {
        return floor_of_via(latency, dir, prefix, cycle_us, harness);
    }
    let dir = dir.join("floor-awake");
    std::fs::create_dir_all(&dir)
        .map_err(BenchError::io(format!("cannot create {}", dir.display())))?;
    let _awake = KeepAwake::start(&affinity::allowed_cpus())?;
    floor_of_via(latency, &dir, &format!("{prefix}awake-"), cycle_us, harness)
}

/// The floor of `via`: a raw relay over shared memory, or the link's two hops.
fn floor_of_via(
    latency: &CheckedLatency,
    dir: &Path,
    prefix: &str,
    cycle_us: u64,
    harness: &mut Harness<'_>,
) -> Result<Floor> {
    let s = &latency.settings;
    let hop_cpu = latency.placement.acting;
    match s.via {
        Via::Shm => {
            let helps = floor::Helps {
                hop_cpu,
                helper_cpu: latency.placement.planner,
                helper_idle_spin_us: latency.planner_idle_spin_us(),
            };
            floor::relay_floor(dir, prefix, cycle_us, s, helps, &harness.programs.relay)
        }
        Via::Zenoh | Via::ZenohTls => {
            let carrier = Carrier::for_via(s.via, &dir.join("floor"))?;
            let (round_trip, first_hop) = floor::zenoh_floor(
                dir,
                cycle_us,
                s,
                hop_cpu,
                &harness.programs.floor_hop,
                &carrier,
            )?;
            Ok(Floor {
                round_trip,
                first_hop,
                // The link's two hops are timed on its two sides: only the whole is measured.
                second_hop: Default::default(),
                cpu: Default::default(),
                hop_catches: None,
            })
        }
    }
}

/// The run's result from its parts.
fn result(
    latency: &CheckedLatency,
    ours: Ours,
    floor: Floor,
    floor_awake: Option<Floor>,
    [recorder, foxglove, rerun, ros2]: [Option<RecorderComparison>; 4],
) -> LatencyResult {
    let s = &latency.settings;
    let Ours {
        report,
        controller,
        cpu,
        catches,
        command_hop,
        cycle_us,
    } = ours;
    let Floor {
        round_trip: floor,
        first_hop: floor_decision,
        second_hop: floor_second_hop,
        cpu: floor_cpu,
        hop_catches,
    } = floor;
    let mut catches = catches;
    if let Some(hop) = hop_catches {
        catches.insert("floor hop".to_owned(), hop);
    }
    let (ratio_p50, ratio_p99) = (
        ratio(report.p50_us, floor.p50_us),
        ratio(report.p99_us, floor.p99_us),
    );
    let floor_awake = floor_awake.map(|f| AwakeFloor::against(&report, f));
    LatencyResult {
        via: s.via,
        wait: s.wait.to_string(),
        wait_chosen: s.acting_wait().to_string(),
        actions: report.count,
        budget_us: s.budget_us,
        views: s.views,
        p50_us: report.p50_us,
        p90_us: report.p90_us,
        p99_us: report.p99_us,
        p999_us: report.p999_us,
        max_us: report.max_us,
        misses: report.misses,
        allocations: controller.allocations,
        ipc_allocations: controller.ipc_allocations,
        decision: controller.latency,
        wake: controller.wake,
        compute: controller.compute,
        order: controller.order,
        learn: controller.learn,
        learning_overran: controller.learning_overran,
        floor_p50_us: floor.p50_us,
        floor_p90_us: floor.p90_us,
        floor_p99_us: floor.p99_us,
        floor_p999_us: floor.p999_us,
        floor_max_us: floor.max_us,
        floor_misses: floor.misses,
        floor_decision,
        command_hop,
        floor_second_hop,
        ratio_p50,
        ratio_p99,
        floor_comparable: comparable(ratio_p50, ratio_p99),
        floor_awake,
        pace: s.pace,
        cpu,
        floor_cpu,
        catches,
        planner_idle_spin_us: latency.planner_idle_spin_us(),
        cycle_us,
        seed: s.seed,
        acting_cpu: latency.placement.acting,
        planner_cpu: latency.placement.planner,
        plans: controller.plans,
        planning: controller.planning,
        recorder,
        foxglove,
        rerun,
        ros2,
    }
}
