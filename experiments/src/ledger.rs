//! The ledger of what the results depend on beside the targets: each world and default
//! setting, fingerprinted, with the changes made after results existed, and the check that the
//! registry ([`crate::prereg`]) and this ledger hold. Apart from the registry so the
//! experiments, which read their targets from it, are not named by it.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use tes_perception_sim::arena::{Arena, ArenaId, ArenaLayout};

use crate::prereg::{TARGETS, World, WorldChange, form_fingerprint};
use crate::settings::Settings;

/// Env 2's floor, changed after the first robot result.
const ENV2_FLOOR: WorldChange = WorldChange {
    what: "Env 2's floor: carpet (as Env 1 and Env 3) → smooth paper board",
    changed_in: "41e257d",
    results_at: "16e1e8d",
    verdict_before: "TES ≥ TES-woRi ≥ loreRL > LWT fails: LWT 38.33 [34.86, 41.80] above loreRL's 37.95 (20 runs); TES 43.24, TES-woRi 40.29",
    verdict_after: "holds at 20 runs: 40.8 ≥ 39.3 ≥ 38.0 > 29.2 (the target itself was later replaced, see robot.fig9.tes-ahead)",
    why: "the paper's Env 2 is \"very different from Environment 1 and Environment 3\" in materials, slopes and obstacles, not only under its marks; the board's slip was set once, not searched over",
    fingerprint_before: None,
};

/// RL-DT's example store, changed after the first grid result.
const RLDT_STORE: WorldChange = WorldChange {
    what: "RL-DT's default example store: per-state counts → a list of every example (re-induced from all of them), as Hester & Stone's C45Tree keeps it",
    changed_in: "b1fb586",
    results_at: "57fcfcd",
    verdict_before: "Table 1 RL-DT / loreRL >= 10 fails: 3.0 (0.0034 s against 0.0011 s)",
    verdict_after: "holds: 10.1 and 9.9 in the two runs of the change (on the line); the grid folder's Table 1 rows give it now",
    why: "the per-state counts are our shortcut (identical trees, time bounded by the 900 states); the list is how RL-DT's authors store examples; `--rl-dt-per-state-counts` keeps the shortcut",
    fingerprint_before: None,
};

/// The lifelong benchmark's worlds, drawn once for every run → per run.
const LIFELONG_PER_RUN: WorldChange = WorldChange {
    what: "the lifelong benchmark's worlds and their order: drawn once from world_seed for every run → drawn per run from world_seed and the run (`--same-worlds` keeps the first design); with it the methods TES-norecency and loreRL-continual joined",
    changed_in: "the commit that added LifelongConfig::same_worlds",
    results_at: "2896153",
    verdict_before: "20 runs of one sequence of 12 fixed worlds: TES above loreRL undecided (+53.8 [−1.1, +108.8], p = 0.055); TES above LWT holds; its lead larger on return visits holds; unbounded above M = 20 holds, also after long gaps; TES above loreRL on logistic worlds holds, on table worlds fails (−62.6); the bounded library cheaper holds (0.80)",
    verdict_after: "each run's own worlds: TES above loreRL holds at 20 runs (+201.6) and 100 (+148.8); unbounded above M = 20 undecided at 20, holds at 100 (+72.4); TES above loreRL on table worlds undecided at 20 (+8.3), fails at 100 (−18.1)",
    why: "with the worlds and order fixed, the runs varied only the agents' seeds, so every conclusion rested on one draw of 8 logistic and 4 table worlds",
    fingerprint_before: Some("40fd29c93070e306"),
};

/// The three arenas: each layout and a seeded walk of 400 steps through it (the cells it
/// visits), so a change to a map, a floor or a surface's slip changes the fingerprint.
fn arenas_definition() -> String {
    arenas_text([ArenaId::Env1, ArenaId::Env2, ArenaId::Env3].map(ArenaLayout::paper))
}

/// The text the arenas' fingerprint is taken over: each layout and its seeded walk.
fn arenas_text(layouts: [ArenaLayout; 3]) -> String {
    use std::fmt::Write;
    let mut text = String::new();
    for layout in layouts {
        let _ = writeln!(text, "{layout:?}");
        let arena = match Arena::from_layout(layout) {
            Ok(arena) => arena,
            Err(e) => return format!("{text}\nno arena: {e}"),
        };
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut pose = arena.random_start(&mut rng);
        for step in 0..400 {
            match arena.step(pose, step % 3, &mut rng) {
                Ok(outcome) => {
                    let _ = write!(text, "{} ", outcome.state);
                    pose = if outcome.terminal {
                        arena.random_start(&mut rng)
                    } else {
                        outcome.pose
                    };
                }
                Err(e) => return format!("{text}\nno step: {e}"),
            }
        }
        text.push('\n');
    }
    text
}

/// An experiment's default settings, as JSON.
fn defaults<C: Settings + serde::Serialize>() -> String {
    serde_json::to_string(&C::standard()).unwrap_or_else(|e| format!("unserialisable: {e}"))
}

/// Every world and default the results depend on.
pub fn worlds() -> [World; 6] {
    use crate::{
        fig4::Fig4Config, grid::GridConfig, lifelong::LifelongConfig, robot::RobotConfig,
        transfer::TransferConfig,
    };
    [
        World {
            id: "robot.arenas",
            describes: "the robot study's Env 1–3: maps, floors, surfaces' slip",
            definition: arenas_definition,
            changes: &[ENV2_FLOOR],
            fingerprints: &["2d9c48a299b631d0"],
        },
        World {
            id: "grid.defaults",
            describes: "the grid experiment's default settings (RL-DT's example store among them)",
            definition: defaults::<GridConfig>,
            changes: &[RLDT_STORE],
            fingerprints: &["15ad553422a27a65"],
        },
        World {
            id: "transfer.defaults",
            describes: "the transfer experiment's default settings (pruning down to M, not Algorithm 2's one removal per task)",
            definition: defaults::<TransferConfig>,
            changes: &[],
            fingerprints: &["1e69a814e0c9f853"],
        },
        World {
            id: "robot.defaults",
            describes: "the robot study's default settings",
            definition: defaults::<RobotConfig>,
            changes: &[],
            fingerprints: &["5d561072ae2b3a3a"],
        },
        World {
            id: "fig4.defaults",
            describes: "the Fig. 4a/4c experiment's default settings",
            definition: defaults::<Fig4Config>,
            changes: &[],
            fingerprints: &["915e9ae910908849"],
        },
        World {
            id: "lifelong.defaults",
            describes: "the lifelong benchmark's default settings (each run's worlds and order drawn from world_seed and the run)",
            definition: defaults::<LifelongConfig>,
            changes: &[LIFELONG_PER_RUN],
            fingerprints: &["40fd29c93070e306", "f51c31da6bbcff2d"],
        },
    ]
}

/// Every change made after a result existed, as a Markdown table: each target's earlier
/// forms (from the registry) and each world's or default's changes (from this ledger), with
/// the results they had, the verdict before and after, and why.
/// `tes experiment report --changes` prints it.
pub fn changes_table() -> String {
    let cell = |text: &str| text.replace('|', "\\|");
    let mut md = String::from(
        "| what changed | results at | verdict before | verdict after | why |\n|---|---|---|---|---|\n",
    );
    for target in TARGETS {
        for earlier in target.history {
            md.push_str(&format!(
                "| target `{}`: \"{}\" → \"{}\" | {} | {} | see its rows in the verdicts tables | {} |\n",
                target.id,
                cell(earlier.target),
                cell(target.target),
                earlier.results_at,
                cell(earlier.verdict_then),
                cell(earlier.why)
            ));
        }
    }
    for world in worlds() {
        for change in world.changes {
            md.push_str(&format!(
                "| {} (`{}`, changed in {}) | {} | {} | {} | {} |\n",
                cell(change.what),
                world.id,
                change.changed_in,
                change.results_at,
                cell(change.verdict_before),
                cell(change.verdict_after),
                cell(change.why)
            ));
        }
    }
    md
}

/// What does not hold of the registry: a target or world whose definition no longer matches
/// its ledger, or whose ledger and history disagree. Empty when all is recorded.
pub fn problems() -> Vec<String> {
    let mut problems = Vec::new();
    for t in TARGETS {
        let mut expected: Vec<String> = t
            .history
            .iter()
            .map(|r| form_fingerprint(t.id, r.target, r.test, r.threshold))
            .collect();
        expected.push(t.fingerprint());
        if expected
            .iter()
            .map(String::as_str)
            .ne(t.fingerprints.iter().copied())
        {
            problems.push(format!(
                "target {}: its ledger {:?} does not match its forms {:?}; a change to a target \
                 keeps its earlier form as a Revision (with the commit where results existed and \
                 why) and appends the new fingerprint",
                t.id, t.fingerprints, expected
            ));
        }
    }
    for w in worlds() {
        let now = w.fingerprint();
        if w.fingerprints.last() != Some(&now.as_str()) {
            problems.push(format!(
                "world {}: its definition's fingerprint is {now}, the ledger's last {:?}; record \
                 the change as a WorldChange (with the verdict before it) and append {now}",
                w.id,
                w.fingerprints.last()
            ));
        }
        for pair in w.fingerprints.windows(2) {
            if !w
                .changes
                .iter()
                .any(|c| c.fingerprint_before == Some(pair[0]))
            {
                problems.push(format!(
                    "world {}: it changed from {} to {} with no WorldChange recording it",
                    w.id, pair[0], pair[1]
                ));
            }
        }
    }
    let mut ids: Vec<&str> = TARGETS.iter().map(|t| t.id).collect();
    ids.sort_unstable();
    ids.dedup();
    if ids.len() != TARGETS.len() {
        problems.push("two targets share an id".to_owned());
    }
    problems
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::prereg::fingerprint;

    #[test]
    fn the_changes_table_has_a_row_for_every_recorded_change() {
        let md = changes_table();
        let rows: Vec<&str> = md.lines().skip(2).collect();
        let revisions: usize = TARGETS.iter().map(|t| t.history.len()).sum();
        let changed: usize = worlds().iter().map(|w| w.changes.len()).sum();
        assert_eq!(rows.len(), revisions + changed, "{md}");
        for world in worlds() {
            for change in world.changes {
                let row = rows
                    .iter()
                    .find(|r| {
                        r.contains(&format!(
                            "(`{}`, changed in {})",
                            world.id, change.changed_in
                        ))
                    })
                    .unwrap_or_else(|| panic!("no row for {}: {md}", world.id));
                assert!(row.contains(&format!("| {} |", change.results_at)), "{row}");
            }
        }
        // Five cells a row, whatever the words hold.
        for row in rows {
            assert_eq!(row.replace("\\|", "").matches('|').count(), 6, "{row}");
        }
    }

    #[test]
    fn every_target_and_world_matches_its_recorded_ledger() {
        let problems = problems();
        assert!(problems.is_empty(), "{}", problems.join("\n"));
    }

    #[test]
    fn a_changed_world_is_caught() {
        let board = fingerprint(&arenas_definition());
        let mut layouts = [ArenaId::Env1, ArenaId::Env2, ArenaId::Env3].map(ArenaLayout::paper);
        layouts[1].floor = tes_perception_sim::arena::Surface::Carpet;
        assert_ne!(
            board,
            fingerprint(&arenas_text(layouts)),
            "Env 2 on carpet (its form before the change) must not fingerprint as on board"
        );
        assert_eq!(board, fingerprint(&arenas_definition()), "deterministic");
    }
}
