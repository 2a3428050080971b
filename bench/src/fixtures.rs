//! Inputs the latency harness and the benches share: a view library that has really learned
//! in the robot arenas, and arena-shaped CMDPs of any feature count for scaling sweeps.

use anyhow::{Context, Result};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tes_learning::cmdp::CmdpStructure;
use tes_learning::library::{ActionOutcome, LibraryParams, ViewLibrary, Winner};
use tes_learning::mdagl::{Features, Mdagl, MdaglParams};
use tes_perception_sim::arena::{Arena, ArenaId};

/// The paper's §5.2 view settings: λ = 0.05, α = 0.5.
pub const ARENA_MDAGL: MdaglParams = MdaglParams {
    lambda: 0.05,
    alpha: 0.5,
    intercept: false,
};

/// A library of `views` views (spread over the three actions) for the robot arenas, as an
/// agent would carry into Env 3: each task's views learned `steps` steps of a seeded random
/// policy in Env 1 or Env 2 (alternately), and entered the library as fresh winners.
pub fn arena_library(views: usize, steps: usize, seed: u64) -> Result<ViewLibrary> {
    let probe = Arena::new(ArenaId::Env3);
    let params = LibraryParams {
        max_views: views.max(LibraryParams::default().max_views),
        mdagl: ARENA_MDAGL,
        ..LibraryParams::default()
    };
    let mut library = ViewLibrary::new(
        probe.n_actions(),
        probe.n_effects(),
        probe.n_features(),
        params,
    )?;
    let mut task = 0u64;
    while library.len() < views {
        let arena = Arena::new([ArenaId::Env1, ArenaId::Env2][(task % 2) as usize]);
        let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_add(task));
        let mut models = (0..arena.n_actions())
            .map(|_| Mdagl::new(arena.n_effects(), arena.n_features(), ARENA_MDAGL))
            .collect::<Result<Vec<_>, _>>()?;
        let mut pose = arena.random_start(&mut rng);
        let mut state = arena.discretise(pose);
        for _ in 0..steps {
            let action = rng.random_range(0..arena.n_actions());
            let outcome = arena.step(pose, action, &mut rng)?;
            let effect = arena.effect_between(state, outcome.state);
            models[action].update(Features::SparseBinary(arena.features(state)), effect)?;
            (pose, state) = if outcome.terminal {
                let p = arena.random_start(&mut rng);
                (p, arena.discretise(p))
            } else {
                (outcome.pose, outcome.state)
            };
        }
        let missing = views - library.len();
        let outcomes = models
            .into_iter()
            .enumerate()
            .take(missing)
            .map(|(action, model)| ActionOutcome {
                action,
                observations: steps as u64,
                winner: Winner::Fresh,
                model,
                score: 0.0,
                library_scores: Vec::new(),
            })
            .collect();
        library
            .end_task(outcomes)
            .context("a trained view was refused by the library")?;
        task += 1;
    }
    Ok(library)
}

/// An arena-shaped CMDP with `features` binary features: a 10×10 grid × 8 headings, 3
/// actions, 20 effects (4 moves × 5 turns relative to the heading), about 15 features on per
/// state (the real arena's density) plus one heading bit, a ball (+2) and death spots. Seeded.
pub fn arena_like(features: usize, seed: u64) -> Result<CmdpStructure> {
    let (w, o) = (10i32, 8i32);
    let n = (w * w * o) as usize;
    let features = features.max(16);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let density = 14.0 / features as f64;
    let per_state: Vec<Vec<u32>> = (0..n)
        .map(|s| {
            let mut f: Vec<u32> = (0..features as u32 - 8)
                .filter(|_| rng.random::<f64>() < density)
                .collect();
            f.push((features - 8 + s % 8) as u32);
            f
        })
        .collect();
    let dirs = tes_perception_sim::arena::DIRS;
    let next = |s: usize, e: usize| -> usize {
        let s = s as i32;
        let (cell, h) = (s / o, s % o);
        let (x, y) = (cell % w, cell / w);
        let (m, t) = (e as i32 / 5, e as i32 % 5);
        let dir = match m {
            0 => Some(h),
            1 => Some((h + 1) % o),
            2 => Some((h + o - 1) % o),
            _ => None,
        };
        let (nx, ny) = dir.map_or((x, y), |d| (x + dirs[d as usize].0, y + dirs[d as usize].1));
        let nh = (h + [0, 1, 2, -1, -2][t as usize] + o) % o;
        if (0..w).contains(&nx) && (0..w).contains(&ny) {
            ((ny * w + nx) * o + nh) as usize
        } else {
            s as usize // pushed against the border: stays
        }
    };
    let mut reward = vec![-0.05; n];
    let mut terminal = vec![false; n];
    for cell in [55usize, 12, 87, 33] {
        for h in 0..8 {
            let s = cell * 8 + h;
            reward[s] = if cell == 55 { 2.0 } else { -1.0 };
            terminal[s] = true;
        }
    }
    Ok(CmdpStructure::new(
        n,
        3,
        20,
        features,
        next,
        reward,
        terminal,
        |s| &per_state[s],
    )?)
}

/// Views that have learned `rows` steps of a seeded random policy in `structure`, with
/// effects that depend on each state's first feature.
pub fn trained_views(structure: &CmdpStructure, rows: usize, seed: u64) -> Result<Vec<Mdagl>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut views = (0..structure.n_actions())
        .map(|_| Mdagl::new(structure.n_effects(), structure.n_features(), ARENA_MDAGL))
        .collect::<Result<Vec<_>, _>>()?;
    for _ in 0..rows {
        let s = rng.random_range(0..structure.n_states());
        let a = rng.random_range(0..structure.n_actions());
        let first = structure.features(s).first().copied().unwrap_or(0) as usize;
        let e = (first + rng.random_range(0..3)) % structure.n_effects();
        views[a].update(Features::SparseBinary(structure.features(s)), e)?;
    }
    Ok(views)
}

/// A library of `n` views spread over the actions of `structure`, trained by
/// [`trained_views`] on different seeds.
pub fn library_for(structure: &CmdpStructure, n: usize, seed: u64) -> Result<ViewLibrary> {
    let params = LibraryParams {
        max_views: n.max(1),
        mdagl: ARENA_MDAGL,
        ..LibraryParams::default()
    };
    let mut library = ViewLibrary::new(
        structure.n_actions(),
        structure.n_effects(),
        structure.n_features(),
        params,
    )?;
    let mut task = 0;
    while library.len() < n {
        let outcomes = trained_views(structure, 500, seed + task)?
            .into_iter()
            .enumerate()
            .take(n - library.len())
            .map(|(action, model)| ActionOutcome {
                action,
                observations: 500,
                winner: Winner::Fresh,
                model,
                score: 0.0,
                library_scores: Vec::new(),
            })
            .collect();
        library.end_task(outcomes)?;
        task += 1;
    }
    Ok(library)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_arena_library_has_the_views_asked_for_and_they_learned() {
        let lib = arena_library(9, 400, 3).unwrap();
        assert_eq!(lib.len(), 9);
        assert_eq!(
            (lib.n_actions(), lib.n_effects(), lib.n_features()),
            (3, 20, 312)
        );
        for a in 0..3 {
            assert_eq!(lib.views_for(a).count(), 3, "action {a}");
            for v in lib.views_for(a) {
                assert!(v.model().n_updates() > 0);
            }
        }
        let again = arena_library(9, 400, 3).unwrap();
        let models = |l: &ViewLibrary| {
            (0..3)
                .flat_map(|a| {
                    l.views_for(a)
                        .map(|v| v.model().clone())
                        .collect::<Vec<_>>()
                })
                .collect::<Vec<_>>()
        };
        assert_eq!(models(&lib), models(&again), "seeded");
    }

    #[test]
    fn arena_like_structures_have_the_asked_feature_count() {
        for d in [52, 312, 1000, 5000] {
            let c = arena_like(d, 1).unwrap();
            assert_eq!((c.n_states(), c.n_features()), (800, d));
            let mean = (0..800).map(|s| c.features(s).len()).sum::<usize>() as f64 / 800.0;
            assert!((10.0..20.0).contains(&mean), "d = {d}: {mean} features on");
        }
        let lib = library_for(&arena_like(52, 1).unwrap(), 20, 1).unwrap();
        assert_eq!(lib.len(), 20);
    }
}
