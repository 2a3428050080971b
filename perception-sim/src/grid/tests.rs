use super::*;
use proptest::prelude::*;

fn suite() -> Vec<GridTask> {
    GridSuite::paper(7, 20)
}

#[test]
fn the_suite_has_the_papers_shape() {
    let tasks = suite();
    assert_eq!(tasks.len(), 15);
    assert_eq!(tasks[0].n_states(), 900);
    for (i, t) in tasks.iter().enumerate() {
        assert!((20..=30).contains(&t.width()) && (20..=30).contains(&t.height()));
        assert_eq!(t.dynamics_set(), i % 3);
        assert_eq!(t.n_features(), 30);
        assert!((0..t.n_states()).any(|s| t.is_exit(s)));
    }
    let sets: Vec<usize> = tasks.iter().map(GridTask::dynamics_set).collect();
    for k in 0..3 {
        assert_eq!(sets.iter().filter(|&&s| s == k).count(), 5);
    }
}

#[test]
fn dynamics_sum_to_one_and_never_cross_walls() {
    for t in suite() {
        for s in 0..t.n_states() {
            for a in 0..4 {
                let p = t.true_effect_probs(s, a);
                assert!((p.iter().sum::<f64>() - 1.0).abs() < 1e-12);
                assert!(p.iter().all(|&v| (0.0..=1.0).contains(&v)));
                for d in Dir::ALL {
                    if t.has_wall(s, d) {
                        assert_eq!(p[d as usize], 0.0, "through-wall move has mass");
                        assert_eq!(t.apply_effect(s, d as usize), s);
                    } else {
                        let n = t.apply_effect(s, d as usize);
                        assert_ne!(n, s);
                        // Walls are symmetric.
                        assert!(!t.has_wall(n, d.opposite()));
                    }
                }
                assert_eq!(t.apply_effect(s, STAY), s);
            }
        }
    }
}

#[test]
fn surfaces_shape_the_dynamics_and_the_intended_move_usually_wins() {
    // On open sand in set 0 the intended move dominates; on water it is much less likely.
    let t = GridTask::from_map("....\n.~~.\n.~~.\n...E", 0, 0, 1).unwrap();
    let sand = t.true_effect_probs(5 - 4, 1); // (1,0) moving east
    let water = t.true_effect_probs(5, 1); // (1,1) moving east
    assert!(sand[1] > 0.6, "{sand:?}");
    assert!(water[1] < sand[1] - 0.2, "{water:?}");
    let sets: Vec<[f64; 5]> = (0..3)
        .map(|k| {
            GridTask::from_map("....\n.~~.\n.~~.\n...E", k, 0, 1)
                .unwrap()
                .true_effect_probs(5, 1)
        })
        .collect();
    assert_ne!(sets[0], sets[1]);
    assert_ne!(sets[1], sets[2]);
}

#[test]
fn same_seed_same_task_other_seed_other_task() {
    let a = GridSuite::paper(3, 10);
    let b = GridSuite::paper(3, 10);
    let c = GridSuite::paper(4, 10);
    assert_eq!(a, b);
    assert_ne!(a[0], c[0]);
    // The layout does not depend on the number of irrelevant features.
    let d = GridSuite::paper(3, 50);
    for s in 0..a[0].n_states() {
        assert_eq!(a[0].surface(s), d[0].surface(s));
        assert_eq!(a[0].true_effect_probs(s, 2), d[0].true_effect_probs(s, 2));
        let relevant = |t: &GridTask| -> Vec<u32> {
            t.features(s).iter().copied().filter(|&i| i < 10).collect()
        };
        assert_eq!(relevant(&a[0]), relevant(&d[0]));
    }
}

#[test]
fn every_non_terminal_cell_reaches_an_exit() {
    for t in suite() {
        let reached = reaching_cells(t.width, t.height, &t.surfaces, &t.walls, &t.exit);
        for s in 0..t.n_states() {
            assert!(t.is_terminal(s) || reached[s], "cell {s} is stranded");
        }
    }
}

#[test]
fn features_follow_the_layout() {
    for t in suite() {
        for s in 0..t.n_states() {
            let f = t.features(s);
            assert!(f.windows(2).all(|w| w[0] < w[1]));
            assert!(f.iter().all(|&i| (i as usize) < t.n_features()));
            assert_eq!(f[0], 0, "bias always on");
            let surfaces: Vec<u32> = f.iter().copied().filter(|i| (1..=5).contains(i)).collect();
            assert_eq!(surfaces, vec![1 + t.surface(s).index() as u32]);
            for d in Dir::ALL {
                assert_eq!(f.contains(&(6 + d as u32)), t.has_wall(s, d));
            }
            assert!(t.oracle_context(s) < t.n_oracle_contexts());
        }
    }
    let t = &suite()[0];
    assert_eq!(t.feature_name(0), "bias");
    assert_eq!(t.feature_name(3), "surface=water");
    assert_eq!(t.feature_name(9), "wall=W");
    assert_eq!(t.feature_name(12), "irrelevant2");
    assert_eq!(t.relevant_features().len(), N_RELEVANT_FEATURES);
}

#[test]
fn irrelevant_features_are_fair_coins() {
    let t = &GridSuite::paper(5, 200)[0];
    let on: usize = (0..t.n_states())
        .map(|s| t.features(s).iter().filter(|&&i| i >= 10).count())
        .sum();
    let rate = on as f64 / (t.n_states() * 200) as f64;
    assert!((rate - 0.5).abs() < 0.01, "{rate}");
}

#[test]
fn sampled_effects_match_the_true_probabilities() {
    let t = &suite()[1];
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let s = t.random_start(&mut rng);
    let p = t.true_effect_probs(s, 2);
    let n = 40_000;
    let mut counts = [0usize; 5];
    for _ in 0..n {
        counts[t.sample_effect(s, 2, &mut rng)] += 1;
    }
    for e in 0..5 {
        let f = counts[e] as f64 / n as f64;
        assert!((f - p[e]).abs() < 0.015, "effect {e}: {f} vs {}", p[e]);
        if p[e] == 0.0 {
            assert_eq!(counts[e], 0);
        }
    }
}

#[test]
fn rewards_terminals_starts_and_cap() {
    let t = GridTask::from_map("EF\n..", 0, 0, 1).unwrap();
    assert_eq!(t.reward(0), EXIT_REWARD);
    assert_eq!(t.reward(1), FIRE_REWARD);
    assert_eq!(t.reward(2), STEP_REWARD);
    assert!(t.is_terminal(0) && t.is_terminal(1) && !t.is_terminal(3));
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    for _ in 0..50 {
        assert!(!t.is_terminal(t.random_start(&mut rng)));
    }
    assert_eq!(t.step_cap(), 16);
    let out = t.step(2, 0, &mut rng);
    assert_eq!(out.next_state, t.apply_effect(2, out.effect));
    assert_eq!(out.terminal, t.is_terminal(out.next_state));
    assert!(t.to_string().starts_with("E F"));
}

#[test]
fn invalid_settings_and_maps_are_refused() {
    let ok = GridParams::default();
    let bad = [
        GridParams { width: 1, ..ok },
        GridParams {
            dynamics_set: 3,
            ..ok
        },
        GridParams {
            wall_density: 0.9,
            ..ok
        },
        GridParams {
            fire_fraction: -0.1,
            ..ok
        },
        GridParams { exits: 0, ..ok },
        GridParams { patches: 0, ..ok },
        GridParams {
            surface_weights: [0.0; 4],
            ..ok
        },
        GridParams {
            surface_weights: [1.0, -1.0, 1.0, 1.0],
            ..ok
        },
        GridParams {
            surface_weights: [1.0, f64::NAN, 1.0, 1.0],
            ..ok
        },
    ];
    for p in bad {
        assert!(GridTask::generate(p, 1).is_err(), "{p:?}");
    }
    assert!(GridTask::generate(ok, 1).is_ok());
    assert!(matches!(
        GridTask::from_map("..\n.x", 0, 0, 0),
        Err(GridError::BadMap(_))
    ));
    assert!(matches!(
        GridTask::from_map("..\n..", 0, 0, 0),
        Err(GridError::BadExits { .. })
    ));
    assert!(matches!(
        GridTask::from_map("...\n.E", 0, 0, 0),
        Err(GridError::BadMap(_))
    ));
    assert!(matches!(
        GridTask::from_map_with_walls("..\n.E", &[(4, Dir::North)], 0, 0, 0),
        Err(GridError::BadMap(_))
    ));
    assert!(matches!(
        GridTask::from_map("..\n.E", 3, 0, 0),
        Err(GridError::BadDynamicsSet(3))
    ));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// Any valid settings give a task whose dynamics are distributions and whose open cells
    /// all reach an exit.
    #[test]
    fn generated_tasks_are_well_formed(
        w in 2usize..14, h in 2usize..14, set in 0usize..3, density in 0.0..0.5f64,
        fire in 0.0..0.3f64, seed in any::<u64>(),
        mix in proptest::array::uniform4(0.0..2.0f64),
    ) {
        let exits = 1.max((w * h) / 30);
        let surface_weights = [mix[0] + 0.01, mix[1], mix[2], mix[3]];
        let p = GridParams { width: w, height: h, dynamics_set: set, n_irrelevant: 3,
            wall_density: density, fire_fraction: fire, exits, patches: 3, surface_weights };
        let t = GridTask::generate(p, seed).unwrap();
        let reached = reaching_cells(w, h, &t.surfaces, &t.walls, &t.exit);
        for s in 0..t.n_states() {
            prop_assert!(t.is_terminal(s) || reached[s]);
            for a in 0..4 {
                let sum: f64 = t.true_effect_probs(s, a).iter().sum();
                prop_assert!((sum - 1.0).abs() < 1e-12);
            }
        }
    }
}

#[test]
fn the_dynamics_table_in_the_docs_holds() {
    // P(intended, each side, backwards, stay) on an open cell, as documented on DYNAMICS_SETS.
    let table: [[[f64; 4]; 4]; 3] = [
        [
            [0.81, 0.05, 0.01, 0.07],
            [0.49, 0.15, 0.07, 0.15],
            [0.36, 0.25, 0.08, 0.06],
            [0.45, 0.07, 0.03, 0.39],
        ],
        [
            [0.44, 0.09, 0.03, 0.35],
            [0.83, 0.05, 0.02, 0.05],
            [0.22, 0.31, 0.10, 0.05],
            [0.70, 0.09, 0.02, 0.09],
        ],
        [
            [0.49, 0.15, 0.07, 0.15],
            [0.81, 0.05, 0.01, 0.07],
            [0.35, 0.14, 0.26, 0.11],
            [0.36, 0.12, 0.18, 0.22],
        ],
    ];
    for (set, rows) in table.iter().enumerate() {
        for (k, row) in rows.iter().enumerate() {
            let map = format!("...\n.{}.\n..E", Surface::ALL[k].letter());
            let t = GridTask::from_map(&map, set, 0, 1).unwrap();
            for a in 0..4 {
                let p = t.true_effect_probs(4, a);
                let got = [p[a], p[(a + 1) % 4], p[(a + 2) % 4], p[STAY]];
                assert!(
                    (p[(a + 1) % 4] - p[(a + 3) % 4]).abs() < 1e-12,
                    "sides differ"
                );
                for (g, want) in got.iter().zip(row) {
                    assert!((g - want).abs() < 0.006, "set {set} surface {k}: {got:?}");
                }
                let intended_wins = p.iter().all(|&v| v <= p[a]);
                let exception = set == 1 && Surface::ALL[k] == Surface::Water;
                assert_eq!(intended_wins, !exception, "set {set} surface {k}: {p:?}");
            }
        }
    }
}

#[test]
fn true_dynamics_are_a_masked_softmax_of_the_relevant_features() {
    use std::collections::HashMap;
    for t in suite() {
        let mut by_context: HashMap<(usize, usize), [f64; 5]> = HashMap::new();
        for s in 0..t.n_states() {
            for a in 0..4 {
                let w = t.true_weights(a).unwrap();
                let mut z = [0.0; 5];
                for &j in t.features(s).iter().filter(|&&j| j < 10) {
                    for e in 0..5 {
                        z[e] += w[e][j as usize];
                    }
                }
                let total: f64 = z.iter().map(|v| v.exp()).sum();
                let mut p = z.map(|v| v.exp() / total);
                let blocked: Vec<usize> = (0..4).filter(|&d| t.has_wall(s, Dir::ALL[d])).collect();
                let freed: f64 = blocked.iter().map(|&d| p[d]).sum();
                for e in 0..5 {
                    p[e] = if blocked.contains(&e) {
                        0.0
                    } else {
                        p[e] + freed / (5 - blocked.len()) as f64
                    };
                }
                let got = t.true_effect_probs(s, a);
                for e in 0..5 {
                    assert!((got[e] - p[e]).abs() < 1e-12, "state {s} action {a}");
                }
                // The oracle DBN structure is exact: same context, same dynamics.
                let seen = by_context.entry((t.oracle_context(s), a)).or_insert(got);
                assert_eq!(*seen, got, "state {s} action {a}");
            }
        }
    }
}

#[test]
fn suite_tasks_mix_surfaces_differently() {
    let tasks = suite();
    let mut dominant = Vec::new();
    for t in &tasks {
        let mut counts = [0usize; 5];
        for s in 0..t.n_states() {
            counts[t.surface(s).index()] += 1;
        }
        let fire = counts[Surface::Fire.index()] as f64 / t.n_states() as f64;
        assert!(fire > 0.0 && fire < 0.08, "fire fraction {fire}");
        let top = (0..4).max_by_key(|&k| counts[k]).unwrap();
        if !dominant.contains(&top) {
            dominant.push(top);
        }
    }
    assert!(dominant.len() >= 3, "most common surfaces: {dominant:?}");
}

#[test]
fn interior_walls_block_and_show() {
    let t = GridTask::from_map_with_walls(
        "...\n...\n..E",
        &[(4, Dir::North), (4, Dir::East), (0, Dir::West)],
        2,
        4,
        3,
    )
    .unwrap();
    assert!(t.has_wall(1, Dir::South) && t.has_wall(5, Dir::West));
    let f = t.features(4);
    assert!(f.contains(&6) && f.contains(&7) && !f.contains(&8) && !f.contains(&9));
    for a in 0..4 {
        let p = t.true_effect_probs(4, a);
        assert_eq!(p[Dir::North as usize], 0.0);
        assert_eq!(p[Dir::East as usize], 0.0);
        assert!((p.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }
    assert_eq!(t.apply_effect(4, Dir::North as usize), 4);
    assert_eq!(t.apply_effect(4, Dir::West as usize), 3);
    let map = t.to_string();
    assert_eq!(map.lines().nth(2), Some(". .|."), "{map}");
    assert_eq!(map.lines().nth(1), Some("  -"), "{map}");
}

#[test]
fn dynamics_of_ones_own_give_the_same_layout_and_their_own_probabilities() {
    use rand::SeedableRng;
    let params = GridParams {
        dynamics_set: 7,
        ..GridParams::default()
    };
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let table = Dynamics::random_table(&mut rng);
    let Dynamics::Table(rows) = &table else {
        panic!("a table")
    };
    for row in rows.probs.iter().flatten() {
        assert!((row.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }
    let logistic = Dynamics::random_logistic(&mut rng);
    assert!(logistic.is_logistic() && !table.is_logistic());
    let a = GridTask::generate_with(params, table.clone(), 11).unwrap();
    let b = GridTask::generate_with(params, logistic, 11).unwrap();
    let paper = GridTask::generate(
        GridParams {
            dynamics_set: 0,
            ..params
        },
        11,
    )
    .unwrap();
    // The layout and the features follow the seed alone.
    for s in 0..a.n_states() {
        assert_eq!(a.surface(s), paper.surface(s));
        assert_eq!(a.features(s), b.features(s));
    }
    assert_eq!(a.dynamics_set(), 7);
    assert!(a.true_weights(0).is_none() && b.true_weights(0).is_some());
    // On a cell with no wall the table's row for pattern 0 is the distribution, turned
    // with the move: relative effect k of action a is absolute effect (a + k) mod 4.
    let open = (0..a.n_states())
        .find(|&s| !a.is_terminal(s) && Dir::ALL.iter().all(|&d| !a.has_wall(s, d)))
        .expect("an open cell");
    let row = rows.probs[a.surface(open).index()][0];
    for action in 0..4 {
        let p = a.true_effect_probs(open, action);
        for k in 0..4 {
            assert!((p[(action + k) % 4] - row[k]).abs() < 1e-12);
        }
        assert!((p[STAY] - row[STAY]).abs() < 1e-12);
    }
}
