//! The latency run's results as `tes bench latency` prints them: the settings line, the
//! latency table against the floor, the ratios, each process's CPU, the observers' costs and
//! the planner's pace.

use std::fmt::Write as _;

use tes_runtime::latency::LatencyReport;

use crate::harness::{LatencyResult, RecorderComparison, Via, Watcher};

/// One row of the latency table.
fn row(out: &mut String, name: &str, r: &LatencyReport) {
    let _ = writeln!(
        out,
        "{:<34} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}",
        name, r.p50_us, r.p90_us, r.p99_us, r.p999_us, r.max_us, r.misses
    );
}

/// The latency run as a table: the floor, ours and the controller's parts, the ratios, the
/// recorder's cost, and the planner's work.
pub fn latency(result: &LatencyResult, warmup: u64) -> String {
    let mut out = String::new();
    heading(&mut out, result, warmup);
    floor_rows(&mut out, result);
    our_rows(&mut out, result);
    ratios(&mut out, result);
    p50_by_hop(&mut out, result);
    cpu(&mut out, result);
    result.observers().for_each(|r| observer_cost(&mut out, r));
    learning_and_planning(&mut out, result, warmup);
    out
}

/// What was run (pace, wait, order, counts, CPUs), then the columns' heading.
fn heading(out: &mut String, result: &LatencyResult, warmup: u64) {
    let on = |c: Option<usize>| c.map_or("unpinned".to_owned(), |c| format!("CPU {c}"));
    let _ = writeln!(
        out,
        "tes bench latency: pace {}, wait {}{}, {}, {} actions measured (+{warmup} warm-up), {} views, budget {} us, one action every {} us; \
         acting thread and floor hop {}, planner (and the floor's helper) {}, polling {} us after each plan",
        result.pace,
        result.wait,
        if result.wait == result.wait_chosen {
            String::new()
        } else {
            format!(" ({})", result.wait_chosen)
        },
        result.order,
        result.actions,
        result.views,
        result.budget_us,
        result.cycle_us,
        on(result.acting_cpu),
        on(result.planner_cpu),
        result.planner_idle_spin_us
    );
    let _ = writeln!(
        out,
        "{:<34} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}",
        "", "p50 us", "p90 us", "p99 us", "p99.9 us", "max us", "misses"
    );
}

/// The floor's round trip and hops, and the same kept awake where it was measured.
fn floor_rows(out: &mut String, result: &LatencyResult) {
    row(
        out,
        match result.via {
            Via::Shm => "floor (raw two-hop relay)",
            Via::Zenoh => "floor (two hops over Zenoh)",
            Via::ZenohTls => "floor (two hops over Zenoh, QUIC with TLS)",
        },
        &result.floor(),
    );
    row(out, "floor: first hop only", &result.floor_decision);
    if result.floor_second_hop.count > 0 {
        row(out, "floor: second hop only", &result.floor_second_hop);
    }
    if let Some(awake) = &result.floor_awake {
        row(out, "floor, every CPU kept awake", &awake.round_trip);
        row(out, "  its first hop only", &awake.first_hop);
        if awake.second_hop.count > 0 {
            row(out, "  its second hop only", &awake.second_hop);
        }
    }
}

/// The group's round trip, the controller's decision and its parts, the command's hop and
/// the learning after it.
fn our_rows(out: &mut String, result: &LatencyResult) {
    row(out, "ours: observation -> bridge", &result.ours());
    row(out, "ours: controller decision only", &result.decision);
    row(out, "  of which: stamp -> received", &result.wake);
    row(out, "  of which: received -> published", &result.compute);
    if result.command_hop.count > 0 {
        row(out, "ours: command -> bridge only", &result.command_hop);
    }
    if result.learn.count > 0 {
        row(out, "learning after the command", &result.learn);
    }
}

/// Ours over the floor (and over the floor kept awake), and the acting path's allocations.
fn ratios(out: &mut String, result: &LatencyResult) {
    let _ = writeln!(
        out,
        "ratio ours/floor: p50 {:.2}, p99 {:.2}{}; allocations on the acting path: {}",
        result.ratio_p50,
        result.ratio_p99,
        if result.floor_comparable {
            ""
        } else {
            " — floor not comparable (a ratio below 0.9: the group had a help the floor lacked)"
        },
        match (result.allocations, result.ipc_allocations) {
            (Some(n), Some(ipc)) => format!("{n} ({ipc} inside iceoryx2's send)"),
            _ => "not counted".to_owned(),
        }
    );
    if let Some(awake) = &result.floor_awake {
        let _ = writeln!(
            out,
            "ratio ours/floor with every CPU kept awake: p50 {:.2}, p99 {:.2}{}",
            awake.ratio_p50,
            awake.ratio_p99,
            if awake.comparable {
                ""
            } else {
                " — not comparable either"
            }
        );
    }
}

/// Whether learning kept up with the observations, and how often the planner's plans came.
fn learning_and_planning(out: &mut String, result: &LatencyResult, warmup: u64) {
    // A planner thread yields to everything: where the measured loops keep both CPUs busy
    // (spin on two cores) it barely runs, and the agent acts on an old policy.
    if result.learn.count > 0 {
        let _ = writeln!(
            out,
            "learning finished before the next observation in {:.3} % of actions ({} observations waited for it)",
            100.0 * (1.0 - result.learning_overran as f64 / result.actions.max(1) as f64),
            result.learning_overran
        );
    }
    let _ = writeln!(
        out,
        "planner ({}): {} plans finished and adopted, one per {:.0} actions",
        result.planning,
        result.plans,
        (result.actions + warmup) as f64 / result.plans.max(1) as f64
    );
}

/// Where ours and the floor differ at the median, hop by hop: each hop's wake-up (the first
/// hop's from the observation's stamp to the controller's receiving it, the floor's hop
/// doing no work), the controller's compute, and the second hop (the command's publication
/// to its receiver's having it), against the floor and the floor kept awake. Medians of the
/// parts do not add up exactly to the median of the whole: the rest is said.
fn p50_by_hop(out: &mut String, r: &LatencyResult) {
    if r.command_hop.count == 0 || r.floor_second_hop.count == 0 {
        return;
    }
    let signed = |a: u64, b: u64| a as i64 - b as i64;
    let mut against = |name: &str, round_trip: u64, first_hop: u64, second_hop: u64| {
        let total = signed(r.p50_us, round_trip);
        let wake = signed(r.wake.p50_us, first_hop);
        let compute = r.compute.p50_us as i64;
        let second = signed(r.command_hop.p50_us, second_hop);
        let _ = writeln!(
            out,
            "p50 ours - {name}: {total:+} us = first hop's wake-up {wake:+} ({} vs {first_hop}) \
             + compute {compute:+} + second hop's wake-up {second:+} ({} vs {second_hop}) \
             + {:+} (medians of parts do not add up exactly)",
            r.wake.p50_us,
            r.command_hop.p50_us,
            total - wake - compute - second
        );
    };
    against(
        "floor",
        r.floor_p50_us,
        r.floor_decision.p50_us,
        r.floor_second_hop.p50_us,
    );
    if let Some(awake) = &r.floor_awake {
        against(
            "floor kept awake",
            awake.round_trip.p50_us,
            awake.first_hop.p50_us,
            awake.second_hop.p50_us,
        );
    }
}

/// Each process's CPU, the group's then the floor's, and the anticipating receivers' catches.
fn cpu(out: &mut String, result: &LatencyResult) {
    let _ = writeln!(
        out,
        "{:<34} {:>12} {:>12}",
        "CPU over the measured actions", "core share", "us/action"
    );
    let rows = result
        .cpu
        .iter()
        .map(|(name, used)| (format!("ours: {name}"), used))
        .chain(
            result
                .floor_cpu
                .iter()
                .map(|(role, used)| (format!("floor: {role}"), used)),
        );
    for (name, used) in rows {
        let _ = writeln!(
            out,
            "{:<34} {:>11.2}% {:>12.1}",
            name,
            100.0 * used.core_share,
            used.us_per_action
        );
    }
    for (who, c) in &result.catches {
        let _ = writeln!(
            out,
            "anticipation ({who}): {} caught polling, {} woken (early, late or unannounced), {} windows passed empty, {} polled under SCHED_FIFO",
            c.polled, c.woken, c.missed_windows, c.realtime_windows
        );
    }
}

/// An observer comparison's blocks and medians, as a table.
fn observer_cost(out: &mut String, r: &RecorderComparison) {
    let name = r.watcher.name();
    let _ = writeln!(
        out,
        "the {name}'s cost (blocks in the order they ran; observation -> bridge):"
    );
    let what = match r.watcher {
        Watcher::Recorder => "written obs/cmd/motor",
        Watcher::Foxglove => "viewer received",
        Watcher::Rerun => "Rerun drew",
        Watcher::Ros2 => "-",
    };
    let _ = writeln!(
        out,
        "{:>5} {:>16} {:>8} {:>8} {:>7} {:>12} {:>24} {:>7}",
        "block", name, "p50 us", "p99 us", "misses", "allocations", what, "missed"
    );
    for (i, b) in r.blocks.iter().enumerate() {
        let count = match (b.written, b.viewer_messages) {
            (Some([o, c, m]), _) => format!("{o}/{c}/{m}"),
            (None, Some(n)) => n.to_string(),
            (None, None) => "-".to_owned(),
        };
        let _ = writeln!(
            out,
            "{:>5} {:>16} {:>8} {:>8} {:>7} {:>12} {:>24} {:>7}",
            i + 1,
            if b.recorded { "with" } else { "without" },
            b.p50_us,
            b.p99_us,
            b.misses,
            b.allocations.map_or("-".to_owned(), |n| n.to_string()),
            count,
            b.missed.map_or("-".to_owned(), |n| n.to_string()),
        );
    }
    let _ = writeln!(
        out,
        "medians: without p50 {:.1} us, p99 {:.1} us; with p50 {:.1} us ({:+.1} %), p99 {:.1} us ({:+.1} %); \
         allocations on the acting path with the {name}: {}",
        r.without_p50_us,
        r.without_p99_us,
        r.with_p50_us,
        100.0 * r.change_p50,
        r.with_p99_us,
        100.0 * r.change_p99,
        r.allocations_with
            .map_or("not counted".to_owned(), |n| n.to_string())
    );
}
