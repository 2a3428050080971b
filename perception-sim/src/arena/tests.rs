use super::*;
use proptest::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn at(arena: &Arena, x: u16, y: u16, orientation: u16) -> usize {
    arena
        .state_index(StateAttributes::at(x, y, orientation))
        .unwrap()
}

/// Empirical effect distribution of `action` from cell `(x, y)`, orientation `o`: poses drawn
/// uniformly within ±0.3 cells of the centre and ±20° of the sector's centre.
fn effect_histogram(
    arena: &Arena,
    x: usize,
    y: usize,
    o: u16,
    action: usize,
    n: usize,
    seed: u64,
) -> [f64; N_EFFECTS] {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let s = at(arena, x as u16, y as u16, o);
    let centre = arena.cell_centre(x, y);
    let mut counts = [0.0; N_EFFECTS];
    for _ in 0..n {
        let jitter = DVec2::new(rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5)
            * 0.6
            * arena.cell_cm();
        let heading = f64::from(o) * FRAC_PI_4 + (rng.random::<f64>() - 0.5) * 40f64.to_radians();
        let pose = Pose {
            position: centre + jitter,
            heading,
        };
        assert_eq!(arena.discretise(pose), s);
        let out = arena.step(pose, action, &mut rng).unwrap();
        counts[arena.effect_between(s, out.state)] += 1.0;
    }
    counts.map(|c| c / n as f64)
}

fn total_variation(p: &[f64; N_EFFECTS], q: &[f64; N_EFFECTS]) -> f64 {
    0.5 * p.iter().zip(q).map(|(a, b)| (a - b).abs()).sum::<f64>()
}

/// Non-terminal interior cells (not on the border) for which `pred(x, y)` holds.
fn interior_cells(arena: &Arena, pred: impl Fn(usize, usize) -> bool) -> Vec<(usize, usize)> {
    let n = arena.cells();
    let mut v = Vec::new();
    for y in 1..n - 1 {
        for x in 1..n - 1 {
            if !arena.is_death_cell(x, y) && !arena.is_ball_cell(x, y) && pred(x, y) {
                v.push((x, y));
            }
        }
    }
    v
}

#[test]
fn the_arenas_have_the_papers_shape() {
    for id in ArenaId::ALL {
        let a = Arena::new(id);
        assert_eq!(a.id(), Some(id));
        assert_eq!(ArenaId::from_number(id.number()), Ok(id));
        let (cells, feet) = if id == ArenaId::Env2 {
            (8, 5.0)
        } else {
            (10, 6.0)
        };
        assert_eq!(a.cells(), cells);
        assert!((a.side_cm() - feet * 30.48).abs() < 1e-9);
        assert_eq!(a.n_states(), cells * cells * 8 + 1);
        assert_eq!(a.out_state(), cells * cells * 8);
        assert_eq!((a.n_actions(), a.n_effects(), a.n_features()), (3, 20, 312));
        assert_eq!(a.rewards().len(), a.n_states());
        assert_eq!(a.terminals().len(), a.n_states());
        let governing = if id == ArenaId::Env2 {
            MarkColour::Green
        } else {
            MarkColour::Blue
        };
        assert_eq!(a.governing_colour(), governing);
        // Both colours, one ball, several death spots.
        assert!(a.marks(MarkColour::Green).len() >= 4);
        assert!(a.marks(MarkColour::Blue).len() >= 4);
        assert!(a.layout().death_cells.len() >= 3);
        assert_eq!(a.to_string().lines().count(), cells);
    }
    assert_eq!(ArenaId::from_number(4), Err(ArenaError::UnknownArena(4)));
    assert_eq!(ArenaId::Env3.to_string(), "Env 3");
    // Forward ≈ one cell in Env 1.
    let forward = 246.0 / 360.0 * PI * WHEEL_DIAMETER_CM;
    let cell = Arena::new(ArenaId::Env1).cell_cm();
    assert!((forward / cell - 1.0).abs() < 0.05, "{forward} vs {cell}");
}

#[test]
fn env1_and_env3_share_surfaces_but_not_ball_deaths_or_green_marks() {
    let (e1, e3) = (Arena::new(ArenaId::Env1), Arena::new(ArenaId::Env3));
    for y in 0..10 {
        for x in 0..10 {
            assert_eq!(e1.surface(x, y), e3.surface(x, y), "({x}, {y})");
        }
    }
    assert_eq!(e1.marks(MarkColour::Blue), e3.marks(MarkColour::Blue));
    assert_ne!(e1.marks(MarkColour::Green), e3.marks(MarkColour::Green));
    assert_ne!(e1.ball(), e3.ball());
    assert_ne!(e1.layout().death_cells, e3.layout().death_cells);
    let e2 = Arena::new(ArenaId::Env2);
    assert!((0..8).any(|y| (0..8).any(|x| e2.surface(x, y) == Surface::Slope)));
    assert!((0..10).any(|y| (0..10).any(|x| e1.surface(x, y) == Surface::Beans)));
}

#[test]
fn there_are_312_features_in_a_fixed_layout() {
    assert_eq!(ARENA_FEATURES, 312);
    assert_eq!(
        (GREEN_RINGS, BLUE_RINGS, BALL_RINGS, ORIENTATION_FEATURES),
        (0, 100, 200, 300)
    );
    assert_eq!(
        (
            GREEN_IN_CELL,
            NO_GREEN_IN_CELL,
            BLUE_IN_CELL,
            NO_BLUE_IN_CELL
        ),
        (308, 309, 310, 311)
    );
    assert_eq!(feature_name(12).as_deref(), Some("green ring 12"));
    assert_eq!(feature_name(100).as_deref(), Some("blue ring 0"));
    assert_eq!(feature_name(299).as_deref(), Some("ball ring 99"));
    assert_eq!(feature_name(303).as_deref(), Some("facing NW"));
    assert_eq!(feature_name(308).as_deref(), Some("green mark in cell"));
    assert_eq!(feature_name(309).as_deref(), Some("no green mark in cell"));
    assert_eq!(feature_name(310).as_deref(), Some("blue mark in cell"));
    assert_eq!(feature_name(311).as_deref(), Some("no blue mark in cell"));
    assert_eq!(feature_name(312), None);
    let names: std::collections::HashSet<String> = (0..312).filter_map(feature_name).collect();
    assert_eq!(names.len(), 312);
}

/// The names saved libraries give the features (`tes_topics::names`) say what perception's
/// extraction sets, block by block: in every in-area state of every arena, a "green ring r"
/// (blue, ball) is on exactly when a green mark (blue mark, the ball) lies r to r + 1 units
/// from the cell's centre; exactly one "facing H" is on, H the compass name of the state's
/// orientation (its cell step); "green mark in cell" (blue) is on exactly when the cell holds
/// one and "no green mark in cell" otherwise. The out state has no feature.
#[test]
fn each_named_feature_block_is_what_the_extraction_sets() {
    for id in ArenaId::ALL {
        let a = Arena::new(id);
        assert!(a.features(a.out_state()).is_empty());
        let unit = a.unit_cm();
        for s in 0..a.out_state() {
            let attr = a.attributes(s).unwrap();
            let (x, y) = (usize::from(attr.x), usize::from(attr.y));
            let centre = a.cell_centre(x, y);
            let names: std::collections::BTreeSet<String> = a
                .features(s)
                .iter()
                .map(|&i| feature_name(i as usize).unwrap())
                .collect();
            // What each named block should hold, from the arena's geometry.
            let mut expected = std::collections::BTreeSet::new();
            for (what, points) in [
                ("green", a.marks(MarkColour::Green)),
                ("blue", a.marks(MarkColour::Blue)),
                ("ball", std::slice::from_ref(&a.layout().ball)),
            ] {
                for p in points {
                    let ring = (p.distance(centre) / unit).floor();
                    if ring < RINGS as f64 {
                        expected.insert(format!("{what} ring {ring}"));
                    }
                }
            }
            let (dx, dy) = DIRS[usize::from(attr.orientation)];
            let heading: String = [(dy > 0, 'N'), (dy < 0, 'S'), (dx > 0, 'E'), (dx < 0, 'W')]
                .into_iter()
                .filter_map(|(on, c)| on.then_some(c))
                .collect();
            expected.insert(format!("facing {heading}"));
            for (colour, word) in [(MarkColour::Green, "green"), (MarkColour::Blue, "blue")] {
                expected.insert(if a.has_mark(colour, x, y) {
                    format!("{word} mark in cell")
                } else {
                    format!("no {word} mark in cell")
                });
            }
            assert_eq!(names, expected, "{id}, state {s} {attr:?}");
        }
    }
}

/// The names saved libraries give the actions, from the wheel targets the world map carries,
/// are the arena's own short names with the targets, and the way each says the robot turns
/// is the way the simulated robot turns on carpet (clockwise is right).
#[test]
fn action_names_from_the_wheels_say_what_the_robot_does() {
    let arena = Arena::new(ArenaId::Env1);
    let (x, y) = (0..10)
        .flat_map(|y| (0..10).map(move |x| (x, y)))
        .find(|&(x, y)| {
            arena.surface(x, y) == Surface::Carpet
                && !arena.is_death_cell(x, y)
                && !arena.is_ball_cell(x, y)
        })
        .unwrap();
    let start = Pose {
        position: arena.cell_centre(x, y),
        heading: 0.0,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for (a, &(left, right)) in ACTIONS.iter().enumerate() {
        let wheels = [left.round() as i32, right.round() as i32];
        let name = tes_topics::names::wheel_action_name(wheels);
        assert!(name.starts_with(ACTION_NAMES[a]), "{a}: {name}");
        let moved = arena.move_robot(start, left, right, &mut rng);
        let turned = (moved.heading - start.heading + PI).rem_euclid(TAU) - PI;
        match name.split_whitespace().nth(1) {
            Some("right") => assert!(turned < -0.1, "{name}: turned {turned} rad"),
            Some("left") => assert!(turned > 0.1, "{name}: turned {turned} rad"),
            _ => assert!(turned.abs() < 0.1, "{name}: turned {turned} rad"),
        }
    }
}

#[test]
fn features_are_sorted_in_range_with_orientation_and_mark_bits() {
    for id in ArenaId::ALL {
        let a = Arena::new(id);
        for s in 0..a.out_state() {
            let f = a.features(s);
            assert!(f.windows(2).all(|w| w[0] < w[1]), "unsorted in {s}");
            assert!(f.iter().all(|&i| (i as usize) < ARENA_FEATURES));
            let attr = a.attributes(s).unwrap();
            let (x, y) = (usize::from(attr.x), usize::from(attr.y));
            let orientations: Vec<u32> = f
                .iter()
                .copied()
                .filter(|&i| (300..308).contains(&i))
                .collect();
            assert_eq!(orientations, vec![300 + u32::from(attr.orientation)]);
            let green = a.has_mark(MarkColour::Green, x, y);
            let blue = a.has_mark(MarkColour::Blue, x, y);
            assert_eq!(f.contains(&308), green);
            assert_eq!(f.contains(&309), !green);
            assert_eq!(f.contains(&310), blue);
            assert_eq!(f.contains(&311), !blue);
            // A mark in the cell is within half a cell's diagonal of its centre.
            let max_ring = (a.cell_cm() * 0.5 * 2f64.sqrt() / a.unit_cm()).floor() as u32;
            if green {
                assert!(f.iter().any(|&i| i <= max_ring));
            }
            if blue {
                assert!(f.iter().any(|&i| (100..=100 + max_ring).contains(&i)));
            }
            // Ball rings: exactly one (one ball), and ring 0 in the ball's cell.
            let ball: Vec<u32> = f
                .iter()
                .copied()
                .filter(|&i| (200..300).contains(&i))
                .collect();
            assert!(ball.len() <= 1);
            if a.is_ball_cell(x, y) {
                assert_eq!(ball, vec![200]);
            }
            // The same features for all orientations of a cell, but the orientation.
            let base = s - s % 8;
            let strip = |v: &[u32]| -> Vec<u32> {
                v.iter()
                    .copied()
                    .filter(|i| !(300..308).contains(i))
                    .collect()
            };
            assert_eq!(strip(f), strip(a.features(base)));
        }
        assert!(a.features(a.out_state()).is_empty());
    }
}

#[test]
fn ring_features_match_a_hand_placed_mark() {
    // 10 cells of 10 cm: a unit is 1 cm, cell (0, 0) has its centre at (5, 5).
    let layout = ArenaLayout {
        cells: 10,
        side_cm: 100.0,
        governing: MarkColour::Blue,
        governing_surface: Surface::Beans,
        floor: Surface::Carpet,
        green_marks: vec![DVec2::new(37.0, 52.0)],
        blue_marks: vec![DVec2::new(5.0, 5.0), DVec2::new(95.0, 95.0)],
        ball: DVec2::new(45.0, 45.0),
        death_cells: vec![(9, 0)],
    };
    let a = Arena::from_layout(layout).unwrap();
    assert!((a.unit_cm() - 1.0).abs() < 1e-12);
    let f = a.features(at(&a, 0, 0, 0));
    // Green: √(32² + 47²) = √3233 = 56.86 → ring 56.
    // Blue: the first mark is at the centre → ring 0; the second at √(90² + 90²) = 127.3 ≥ 100
    // → no ring. Ball: √(40² + 40²) = 56.57 → ring 56 (feature 256).
    assert_eq!(f, &[56, 100, 256, 300, 309, 310]);
    // Cell (3, 5), centre (35, 55): green at √(2² + 3²) = 3.61 → ring 3, and in the cell.
    // Blue from (35, 55): √(30² + 50²) = 58.31 → ring 58; √(60² + 40²) = 72.11 → ring 72.
    // Ball from (35, 55): √(10² + 10²) = 14.14 → ring 14. Orientation 6, no blue in the cell.
    assert_eq!(
        a.features(at(&a, 3, 5, 6)),
        &[3, 158, 172, 214, 306, 308, 311]
    );
}

#[test]
fn layouts_are_validated() {
    let good = ArenaLayout::paper(ArenaId::Env2);
    let mut bad = good.clone();
    bad.cells = 1;
    assert_eq!(Arena::from_layout(bad), Err(ArenaError::BadSize(1)));
    let mut bad = good.clone();
    bad.side_cm = f64::NAN;
    assert!(matches!(
        Arena::from_layout(bad),
        Err(ArenaError::BadSide(_))
    ));
    let mut bad = good.clone();
    bad.green_marks.push(DVec2::new(-1.0, 3.0));
    assert!(matches!(
        Arena::from_layout(bad),
        Err(ArenaError::OutsideArea {
            what: "green mark",
            ..
        })
    ));
    let mut bad = good.clone();
    bad.ball = DVec2::new(10.0, good.side_cm);
    assert!(matches!(
        Arena::from_layout(bad),
        Err(ArenaError::OutsideArea { what: "ball", .. })
    ));
    let mut bad = good.clone();
    bad.death_cells.push((8, 0));
    assert_eq!(
        Arena::from_layout(bad),
        Err(ArenaError::DeathOutside { x: 8, y: 0 })
    );
    let mut bad = good.clone();
    bad.death_cells.push((6, 6)); // the ball's cell
    assert_eq!(Arena::from_layout(bad), Err(ArenaError::BallOnDeath));
    let full = ArenaLayout::from_map("OX\nXX", 10.0, MarkColour::Blue, Surface::Beans).unwrap();
    assert_eq!(Arena::from_layout(full), Err(ArenaError::NoStartCell));
    assert!(matches!(
        ArenaLayout::from_map("..\n.", 10.0, MarkColour::Blue, Surface::Beans),
        Err(ArenaError::BadMap(_))
    ));
    assert!(matches!(
        ArenaLayout::from_map("..\n..", 10.0, MarkColour::Blue, Surface::Beans),
        Err(ArenaError::BadMap(_))
    ));
    assert!(matches!(
        ArenaLayout::from_map("O?\n..", 10.0, MarkColour::Blue, Surface::Beans),
        Err(ArenaError::BadMap(_))
    ));
}

#[test]
fn apply_then_derive_gives_the_effect_back() {
    for id in ArenaId::ALL {
        let a = Arena::new(id);
        for s in 0..a.out_state() {
            for e in 0..N_EFFECTS {
                let next = a.apply_effect(s, e);
                assert!(next < a.n_states());
                if next != a.out_state() {
                    assert_eq!(a.effect_between(s, next), e, "state {s}, effect {e}");
                }
            }
        }
        for e in 0..N_EFFECTS {
            assert_eq!(a.apply_effect(a.out_state(), e), a.out_state());
        }
    }
}

#[test]
fn effects_have_their_meaning() {
    let a = Arena::new(ArenaId::Env1);
    let s = at(&a, 5, 5, 0); // facing east
    let outcomes: std::collections::HashSet<usize> =
        (0..N_EFFECTS).map(|e| a.apply_effect(s, e)).collect();
    assert_eq!(outcomes.len(), 20);
    let effect = |m: Move, t: Turn| {
        Effect {
            movement: m,
            turn: t,
        }
        .index()
    };
    assert_eq!(
        a.apply_effect(s, effect(Move::Forward, Turn::None)),
        at(&a, 6, 5, 0)
    );
    assert_eq!(
        a.apply_effect(s, effect(Move::ForwardLeft, Turn::None)),
        at(&a, 6, 6, 0)
    );
    assert_eq!(
        a.apply_effect(s, effect(Move::ForwardRight, Turn::Left)),
        at(&a, 6, 4, 1)
    );
    assert_eq!(
        a.apply_effect(s, effect(Move::Stay, Turn::Right)),
        at(&a, 5, 5, 7)
    );
    assert_eq!(
        a.apply_effect(s, effect(Move::Stay, Turn::Right2)),
        at(&a, 5, 5, 6)
    );
    assert_eq!(
        a.apply_effect(s, effect(Move::Stay, Turn::Left2)),
        at(&a, 5, 5, 2)
    );
    // Facing north-west (3): forward is (−1, +1), forward-left is west, forward-right north.
    let s = at(&a, 5, 5, 3);
    assert_eq!(a.apply_effect(s, 0), at(&a, 4, 6, 3));
    assert_eq!(a.apply_effect(s, 5), at(&a, 4, 5, 3));
    assert_eq!(a.apply_effect(s, 10), at(&a, 5, 6, 3));
    for i in 0..N_EFFECTS {
        assert_eq!(Effect::from_index(i).unwrap().index(), i);
    }
    assert_eq!(Effect::from_index(20), None);
    assert_eq!(
        Effect::from_index(7).unwrap().to_string(),
        "forward-left, 2 left"
    );
}

#[test]
fn leaving_the_grid_goes_out_and_out_is_absorbing_and_terminal() {
    let a = Arena::new(ArenaId::Env1);
    let out = a.out_state();
    // In the south-west corner facing south-west, every move leaves; facing east, only
    // forward-right (south-east) does.
    let corner = at(&a, 0, 0, 5);
    for m in 0..3 {
        for t in 0..5 {
            assert_eq!(a.apply_effect(corner, m * 5 + t), out);
        }
    }
    assert_ne!(a.apply_effect(corner, 15), out);
    let east = at(&a, 0, 0, 0);
    assert_ne!(a.apply_effect(east, 0), out);
    assert_ne!(a.apply_effect(east, 5), out);
    assert_eq!(a.apply_effect(east, 10), out);
    assert_eq!(a.effect_between(east, out), 10);
    assert!(a.is_terminal(out));
    assert_eq!(a.reward(out), OUT_REWARD);
    assert_eq!(a.attributes(out), Some(StateAttributes::OUT));
    assert_eq!(a.state_index(StateAttributes::OUT), Some(out));
    assert_eq!(a.attributes(out + 1), None);
    assert_eq!(a.state_pose(out), None);
    // Physically: a pose beyond the border discretises to out and stays there.
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let p = Pose::new(-0.1, 50.0, 0.0);
    assert_eq!(a.discretise(p), out);
    assert_eq!(a.move_robot(p, 246.0, 246.0, &mut rng), p);
    assert_eq!(a.discretise(Pose::new(a.side_cm(), 5.0, 0.0)), out);
    // Driving west from the west column's centre leaves the area.
    let west = Pose::new(a.cell_cm() / 2.0, 95.0, PI);
    let mut left = 0;
    for _ in 0..100 {
        if a.step(west, 0, &mut rng).unwrap().state == out {
            left += 1;
        }
    }
    assert!(left > 80, "{left}");
}

#[test]
fn nearest_effect_when_the_robot_skips_cells() {
    let a = Arena::new(ArenaId::Env1);
    let s = at(&a, 5, 5, 0);
    // Two cells ahead: forward, forward-left and forward-right are all one cell off; the
    // lowest-numbered (forward, no turn) wins.
    assert_eq!(a.effect_between(s, at(&a, 7, 5, 0)), 0);
    // Two cells ahead and turned 1 left: forward, 1 left.
    assert_eq!(a.effect_between(s, at(&a, 7, 5, 1)), 1);
    // Turned 4 (half a turn) without moving: no move, and the nearest turns are 2 left / 2 right.
    assert_eq!(a.effect_between(s, at(&a, 5, 5, 4)), 17);
    // Two cells up-left: forward-left is nearest.
    assert_eq!(a.effect_between(s, at(&a, 6, 7, 0)), 5);
    // From the out state everything is "effect 0".
    assert_eq!(a.effect_between(a.out_state(), s), 0);
}

#[test]
fn rewards_and_terminals_follow_the_layout() {
    for id in ArenaId::ALL {
        let a = Arena::new(id);
        let mut balls = 0;
        for s in 0..a.out_state() {
            let attr = a.attributes(s).unwrap();
            let (x, y) = (usize::from(attr.x), usize::from(attr.y));
            let (r, t) = if a.is_ball_cell(x, y) {
                balls += 1;
                (BALL_REWARD, true)
            } else if a.is_death_cell(x, y) {
                (DEATH_REWARD, true)
            } else {
                (STEP_REWARD, false)
            };
            assert_eq!((a.reward(s), a.is_terminal(s)), (r, t), "{id} state {s}");
        }
        assert_eq!(balls, 8, "one ball cell × 8 orientations");
        let (bx, by) = a.cell_of(a.ball()).unwrap();
        assert!(a.is_ball_cell(bx, by));
    }
}

#[test]
fn random_starts_are_seeded_and_never_terminal() {
    let a = Arena::new(ArenaId::Env3);
    let mut r1 = ChaCha8Rng::seed_from_u64(42);
    let mut r2 = ChaCha8Rng::seed_from_u64(42);
    let mut seen = std::collections::HashSet::new();
    for _ in 0..2000 {
        let p = a.random_start(&mut r1);
        assert_eq!(p, a.random_start(&mut r2));
        let s = a.discretise(p);
        assert!(!a.is_terminal(s));
        let ideal = a.state_pose(s).unwrap();
        assert!((p.position - ideal.position).abs().max_element() <= START_JITTER_CM + 1e-9);
        let dh = (p.heading - ideal.heading + PI).rem_euclid(TAU) - PI;
        assert!(dh.abs() <= START_JITTER_DEG.to_radians() + 1e-9);
        seen.insert(s);
    }
    // Uniform over 90+ cells × 8 orientations: most states are seen in 2000 draws.
    assert!(seen.len() > 500, "{}", seen.len());
}

#[test]
fn moves_are_seeded_and_deterministic() {
    let a = Arena::new(ArenaId::Env2);
    let run = |seed: u64| -> Vec<StepOutcome> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut pose = a.random_start(&mut rng);
        let mut v = Vec::new();
        for k in 0..50 {
            let out = a.step(pose, k % 3, &mut rng).unwrap();
            pose = out.pose;
            v.push(out);
        }
        v
    };
    assert_eq!(run(5), run(5));
    assert_ne!(run(5), run(6));
    assert_eq!(
        a.step(
            Pose::new(50.0, 50.0, 0.0),
            3,
            &mut ChaCha8Rng::seed_from_u64(0)
        ),
        Err(ArenaError::BadAction(3))
    );
}

#[test]
fn ideal_motion_on_carpet() {
    // Env 1 cell (1, 1) is plain carpet: forward from the centre reaches the next cell, the
    // spin turns ≈ 65.6° clockwise in place, the pivot ≈ 32.8° clockwise.
    let a = Arena::new(ArenaId::Env1);
    assert_eq!(a.surface(1, 2), Surface::Carpet);
    let start = a.state_pose(at(&a, 1, 2, 0)).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let n = 400;
    let (mut ds, mut spin, mut pivot) = (0.0, 0.0, 0.0);
    for _ in 0..n {
        let p = a.move_robot(start, 246.0, 246.0, &mut rng);
        ds += (p.position - start.position).length();
        let p = a.move_robot(start, 90.0, -90.0, &mut rng);
        assert!((p.position - start.position).length() < 1.0);
        spin += (p.heading + PI).rem_euclid(TAU) - PI;
        let p = a.move_robot(start, 90.0, 0.0, &mut rng);
        pivot += (p.heading + PI).rem_euclid(TAU) - PI;
    }
    let forward = 246.0 / 360.0 * PI * WHEEL_DIAMETER_CM;
    assert!((ds / n as f64 - forward).abs() < 0.3, "{}", ds / n as f64);
    assert!((spin / n as f64 + 65.6f64.to_radians()).abs() < 0.03);
    assert!((pivot / n as f64 + 32.8f64.to_radians()).abs() < 0.03);
}

#[test]
fn governing_marks_change_the_dynamics_and_decoys_do_not() {
    const N: usize = 4000;
    for id in ArenaId::ALL {
        let a = Arena::new(id);
        let gov = a.governing_colour();
        let decoy = gov.other();
        let governed = interior_cells(&a, |x, y| a.has_mark(gov, x, y));
        let decoys = interior_cells(&a, |x, y| a.has_mark(decoy, x, y) && !a.has_mark(gov, x, y));
        let plain = interior_cells(&a, |x, y| {
            !a.has_mark(gov, x, y) && !a.has_mark(decoy, x, y)
        });
        assert!(!governed.is_empty() && !decoys.is_empty() && !plain.is_empty());
        let (g, d, p) = (governed[0], decoys[0], plain[0]);
        let mut largest = 0.0f64;
        for action in 0..N_ACTIONS {
            for o in [0u16, 3] {
                let hg = effect_histogram(&a, g.0, g.1, o, action, N, 10 + action as u64);
                let hd = effect_histogram(&a, d.0, d.1, o, action, N, 20 + action as u64);
                let hp = effect_histogram(&a, p.0, p.1, o, action, N, 30 + action as u64);
                // The decoy colour sits on carpet: the same distribution up to sampling noise.
                let tv = total_variation(&hd, &hp);
                assert!(tv < 0.05, "{id} decoy changes action {action}: tv {tv}");
                largest = largest.max(total_variation(&hg, &hp));
            }
        }
        assert!(
            largest > 0.3,
            "{id}: governing marks change little ({largest})"
        );
    }
}

#[test]
fn env1_and_env3_share_dynamics_and_env2_differs() {
    const N: usize = 4000;
    let (e1, e2, e3) = (
        Arena::new(ArenaId::Env1),
        Arena::new(ArenaId::Env2),
        Arena::new(ArenaId::Env3),
    );
    // Different cells under the same kind of mark: Env 1 (3, 4) and Env 3 (5, 6), both blue;
    // Env 2 (4, 4), green.
    assert!(e1.has_mark(MarkColour::Blue, 3, 4) && e3.has_mark(MarkColour::Blue, 5, 6));
    assert!(e2.has_mark(MarkColour::Green, 4, 4));
    let mut differs = 0.0f64;
    for action in 0..N_ACTIONS {
        for o in [1u16, 2, 6] {
            let h1 = effect_histogram(&e1, 3, 4, o, action, N, 100 + action as u64);
            let h3 = effect_histogram(&e3, 5, 6, o, action, N, 200 + action as u64);
            let h2 = effect_histogram(&e2, 4, 4, o, action, N, 300 + action as u64);
            let same = total_variation(&h1, &h3);
            assert!(
                same < 0.05,
                "Env 1 vs Env 3, action {action}, o {o}: {same}"
            );
            differs = differs.max(total_variation(&h1, &h2));
        }
    }
    assert!(differs > 0.3, "Env 2 too like Env 1: {differs}");
}

#[test]
fn env2s_board_floor_differs_from_the_carpet_of_env1_and_env3_everywhere() {
    // The paper's Env 2 is "very different" from Env 1 and Env 3, not only under its marks:
    // a plain cell of each, same orientation and action, gives different effects.
    const N: usize = 4000;
    let (e1, e2, e3) = (
        Arena::new(ArenaId::Env1),
        Arena::new(ArenaId::Env2),
        Arena::new(ArenaId::Env3),
    );
    assert_eq!(e2.surface(3, 1), Surface::Board);
    assert_eq!(e1.surface(3, 1), Surface::Carpet);
    assert_eq!(e3.surface(3, 1), Surface::Carpet);
    let mut differs = 0.0f64;
    for action in 0..N_ACTIONS {
        for o in [0u16, 3] {
            let h1 = effect_histogram(&e1, 3, 1, o, action, N, 400 + action as u64);
            let h3 = effect_histogram(&e3, 3, 1, o, action, N, 500 + action as u64);
            let h2 = effect_histogram(&e2, 3, 1, o, action, N, 600 + action as u64);
            let same = total_variation(&h1, &h3);
            assert!(
                same < 0.05,
                "Env 1 vs Env 3 carpet, action {action}: {same}"
            );
            differs = differs.max(total_variation(&h1, &h2));
        }
    }
    assert!(differs > 0.3, "Env 2's floor too like carpet: {differs}");
}

#[test]
fn the_dynamics_are_not_a_function_of_the_features_alone() {
    // Beans in Env 1 (4, 5): deep in the middle of the cell the wheels spin far more often
    // than near its edge, though both poses have the same state and features.
    let a = Arena::new(ArenaId::Env1);
    assert_eq!(a.surface(4, 5), Surface::Beans);
    let centre = a.cell_centre(4, 5);
    let edge = centre - DVec2::new(0.42 * a.cell_cm(), 0.0);
    let s = at(&a, 4, 5, 0);
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let n = 4000;
    let stuck = |from: DVec2, rng: &mut ChaCha8Rng| {
        (0..n)
            .filter(|_| {
                let p = a.move_robot(
                    Pose {
                        position: from,
                        heading: 0.0,
                    },
                    246.0,
                    246.0,
                    rng,
                );
                (p.position - from).length() < 2.0
            })
            .count() as f64
            / n as f64
    };
    assert_eq!(
        a.discretise(Pose {
            position: edge,
            heading: 0.0
        }),
        s
    );
    let (deep, shallow) = (stuck(centre, &mut rng), stuck(edge, &mut rng));
    assert!(
        (deep - 0.4).abs() < 0.04 && (shallow - 0.12).abs() < 0.04,
        "{deep} {shallow}"
    );
}

#[test]
fn episodes_end_on_terminal_states_or_when_stuck() {
    let a = Arena::new(ArenaId::Env1);
    let s = at(&a, 2, 2, 0);
    let t = at(&a, 3, 2, 0);
    let mut ep = Episode::new(&a, s).unwrap();
    // Unchanged three times, then a move resets the streak.
    for k in 1..=3 {
        let step = ep.observe(&a, s).unwrap();
        assert_eq!(
            (step.reward, step.status),
            (STEP_REWARD, EpisodeStatus::Continuing)
        );
        assert_eq!(ep.unchanged_streak(), k);
    }
    ep.observe(&a, t).unwrap();
    assert_eq!(ep.unchanged_streak(), 0);
    for _ in 0..3 {
        assert_eq!(ep.observe(&a, t).unwrap().status, EpisodeStatus::Continuing);
    }
    assert_eq!(ep.observe(&a, t).unwrap().status, EpisodeStatus::Stuck);
    assert!(ep.is_over());
    assert_eq!(ep.actions(), 8);
    assert!((ep.total_reward() - 8.0 * STEP_REWARD).abs() < 1e-12);
    assert_eq!(ep.observe(&a, t), Err(ArenaError::EpisodeOver));
    // Terminal: the ball (Env 1's ball is in cell (8, 8)), a death spot, the out state.
    for (next, reward) in [
        (at(&a, 8, 8, 3), BALL_REWARD),
        (at(&a, 1, 7, 0), DEATH_REWARD),
        (a.out_state(), OUT_REWARD),
    ] {
        let mut ep = Episode::new(&a, s).unwrap();
        let step = ep.observe(&a, next).unwrap();
        assert_eq!(
            (step.reward, step.status),
            (reward, EpisodeStatus::Terminal)
        );
    }
    assert!(Episode::new(&a, a.out_state()).unwrap().is_over());
    assert!(matches!(
        Episode::new(&a, a.n_states()),
        Err(ArenaError::BadState { .. })
    ));
    let mut ep = Episode::new(&a, s).unwrap();
    assert!(matches!(
        ep.observe(&a, 10_000),
        Err(ArenaError::BadState { .. })
    ));
}

#[test]
fn oracle_and_man_features() {
    for id in ArenaId::ALL {
        let a = Arena::new(id);
        let dyn_features = a.dynamics_features();
        for s in 0..a.out_state() {
            let attr = a.attributes(s).unwrap();
            let (x, y) = (usize::from(attr.x), usize::from(attr.y));
            let o = u32::from(attr.orientation);
            let gov = a.has_mark(a.governing_colour(), x, y);
            let oracle = a.oracle_features(s);
            assert_eq!(oracle.len(), 2);
            assert!(oracle.windows(2).all(|w| w[0] < w[1]));
            assert!(oracle.iter().all(|i| a.features(s).contains(i)));
            assert!(oracle.iter().all(|i| dyn_features.contains(i)));
            assert_eq!(oracle[0], 300 + o);
            assert_eq!(a.oracle_context(s), Some(usize::from(gov) * 8 + o as usize));
            let man = a.man_features(s);
            assert_eq!(man.len(), 3);
            assert!(man.windows(2).all(|w| w[0] < w[1]) && man.iter().all(|&i| i < 12));
            // Mapped back to the 312, they are exactly the state's man-features.
            let back: Vec<u32> = man.iter().map(|&i| MAN_FEATURES[i as usize]).collect();
            let expected: Vec<u32> = a
                .features(s)
                .iter()
                .copied()
                .filter(|i| MAN_FEATURES.contains(i))
                .collect();
            assert_eq!(back, expected);
        }
        assert!(a.oracle_features(a.out_state()).is_empty());
        assert!(a.man_features(a.out_state()).is_empty());
        assert_eq!(a.oracle_context(a.out_state()), None);
        assert_eq!(a.n_oracle_contexts(), 16);
    }
    assert_eq!(
        Arena::new(ArenaId::Env2).dynamics_features()[8..],
        [GREEN_IN_CELL as u32, NO_GREEN_IN_CELL as u32]
    );
    assert_eq!(
        Arena::new(ArenaId::Env1).dynamics_features()[8..],
        [BLUE_IN_CELL as u32, NO_BLUE_IN_CELL as u32]
    );
}

#[test]
fn orientation_sectors() {
    assert_eq!(Arena::orientation_of(0.0), 0);
    assert_eq!(Arena::orientation_of(22.4f64.to_radians()), 0);
    assert_eq!(Arena::orientation_of(22.6f64.to_radians()), 1);
    assert_eq!(Arena::orientation_of(-22.6f64.to_radians()), 7);
    assert_eq!(Arena::orientation_of(PI / 2.0), 2);
    assert_eq!(Arena::orientation_of(TAU - 1e-12), 0);
    assert_eq!(Arena::orientation_of(f64::NAN), 0);
    assert_eq!(Arena::orientation_of(7.0 * TAU + PI), 4);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// Moving never produces NaN, and any resulting pose discretises to a valid state.
    #[test]
    fn moves_stay_finite_and_discretise_validly(
        arena in 0usize..3, x in -20.0..200.0f64, y in -20.0..200.0f64,
        heading in -20.0..20.0f64, left in -5000.0..5000.0f64, right in -5000.0..5000.0f64,
        seed in any::<u64>(), steps in 1usize..20,
    ) {
        let a = Arena::new(ArenaId::ALL[arena]);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut pose = Pose::new(x, y, heading);
        for _ in 0..steps {
            pose = a.move_robot(pose, left, right, &mut rng);
            prop_assert!(pose.position.is_finite() && pose.heading.is_finite());
            let s = a.discretise(pose);
            prop_assert!(s < a.n_states());
            let attr = a.discretise_attributes(pose);
            prop_assert_eq!(a.state_index(attr), Some(s));
            prop_assert!(a.effect_between(s, s) < N_EFFECTS);
        }
    }

    /// Non-finite wheel rotations count as no rotation.
    #[test]
    fn non_finite_rotations_are_harmless(seed in any::<u64>(), which in 0usize..3) {
        let a = Arena::new(ArenaId::Env1);
        let bad = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY][which];
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let p = a.move_robot(Pose::new(90.0, 90.0, 1.0), bad, bad, &mut rng);
        prop_assert!(p.position.is_finite() && p.heading.is_finite());
        prop_assert!((p.position - DVec2::new(90.0, 90.0)).length() < 1e-9);
    }
}

#[test]
fn the_printed_maps_are_the_documented_ones() {
    for (id, map) in [
        (ArenaId::Env1, ENV1_MAP),
        (ArenaId::Env2, ENV2_MAP),
        (ArenaId::Env3, ENV3_MAP),
    ] {
        let expected: Vec<&str> = map
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty())
            .collect();
        let shown = Arena::new(id).to_string();
        assert_eq!(shown.lines().collect::<Vec<_>>(), expected, "{id}");
    }
}

#[test]
fn the_ball_is_reachable_from_every_start_by_ideal_moves() {
    // Ideal carpet moves: forward (effect 0), turn 1 or 2 right in place (18, 19).
    for id in ArenaId::ALL {
        let a = Arena::new(id);
        let n = a.n_states();
        let mut reaches = vec![false; n];
        let mut changed = true;
        while changed {
            changed = false;
            for s in 0..a.out_state() {
                if reaches[s] || a.is_terminal(s) {
                    continue;
                }
                let good = [0, 18, 19].iter().any(|&e| {
                    let t = a.apply_effect(s, e);
                    reaches[t] || (a.is_terminal(t) && a.reward(t) == BALL_REWARD)
                });
                if good {
                    reaches[s] = true;
                    changed = true;
                }
            }
        }
        for s in 0..a.out_state() {
            assert!(
                a.is_terminal(s) || reaches[s],
                "{id}: state {s} cannot reach the ball"
            );
        }
    }
}
