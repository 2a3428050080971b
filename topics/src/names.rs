//! Readable names for what a [`WorldMap`] numbers: the robot arenas' features (by the
//! [`arena_features`](crate::arena_features) layout, which is the layout of every
//! [`Observation`](crate::Observation)'s feature bits) and the actions (by their wheel
//! targets, which the map carries).
//!
//! A saved view library stores one name per action and per feature, so that what a view
//! learned can be read without the code that built the world. The controller knows its world
//! only through the map, so the names come from here, where the layout is defined; perception
//! builds its features by the same constants and its tests check each named block against
//! what it sets.
//!
//! ```
//! use tes_topics::names::{arena_feature_name, wheel_action_name};
//!
//! assert_eq!(arena_feature_name(7).as_deref(), Some("green ring 7"));
//! assert_eq!(arena_feature_name(301).as_deref(), Some("facing NE"));
//! assert_eq!(arena_feature_name(312), None);
//! assert_eq!(wheel_action_name([90, -90]), "spin right (left 90°, right -90°)");
//! ```

use crate::WorldMap;
use crate::arena_features::{
    ARENA_FEATURES, BALL_RINGS, BLUE_IN_CELL, BLUE_RINGS, GREEN_IN_CELL, GREEN_RINGS,
    NO_BLUE_IN_CELL, NO_GREEN_IN_CELL, ORIENTATION_FEATURES, ORIENTATIONS,
};

/// Compass names of the orientation sectors: sector `k` covers the headings within ±22.5° of
/// `k · 45°`, counter-clockwise from east (`y` points north).
pub const HEADINGS: [&str; ORIENTATIONS] = ["E", "NE", "N", "NW", "W", "SW", "S", "SE"];

/// The name of arena feature `i`, or `None` past the last ([`ARENA_FEATURES`]):
///
/// * `green ring r`, `blue ring r`, `ball ring r` (r in 0..100): a green mark, a blue mark or
///   the ball lies `r` to `r + 1` distance units (the arena's width / 100) from the centre of
///   the robot's cell;
/// * `facing E`, `facing NE`, … `facing SE`: the robot's orientation sector;
/// * `green mark in cell`, `no green mark in cell`, `blue mark in cell`,
///   `no blue mark in cell`: whether the robot's cell holds a mark of that colour.
pub fn arena_feature_name(i: usize) -> Option<String> {
    Some(match i {
        _ if i < BLUE_RINGS => format!("green ring {}", i - GREEN_RINGS),
        _ if i < BALL_RINGS => format!("blue ring {}", i - BLUE_RINGS),
        _ if i < ORIENTATION_FEATURES => format!("ball ring {}", i - BALL_RINGS),
        _ if i < GREEN_IN_CELL => format!("facing {}", HEADINGS[i - ORIENTATION_FEATURES]),
        GREEN_IN_CELL => "green mark in cell".to_owned(),
        NO_GREEN_IN_CELL => "no green mark in cell".to_owned(),
        BLUE_IN_CELL => "blue mark in cell".to_owned(),
        NO_BLUE_IN_CELL => "no blue mark in cell".to_owned(),
        _ => return None,
    })
}

/// The names of all [`ARENA_FEATURES`] arena features, in feature order.
pub fn arena_feature_names() -> Vec<String> {
    (0..ARENA_FEATURES).filter_map(arena_feature_name).collect()
}

/// A name for the action that turns the left wheel by `left` and the right one by `right`
/// degrees: what the robot does (a differential drive turns towards the slower wheel), then
/// the wheel targets, e.g. `forward (both wheels 246°)`, `spin right (left 90°, right -90°)`,
/// `pivot right (left 90°, right 0°)`. The targets are part of the name because two
/// actions of the same kind differ only by them.
pub fn wheel_action_name([left, right]: [i32; 2]) -> String {
    let (l, r) = (i64::from(left), i64::from(right));
    let travel = if l + r < 0 { " backward" } else { "" };
    let side = if l > r { "right" } else { "left" };
    if l == r {
        let what = match l {
            0 => "stay",
            l if l > 0 => "forward",
            _ => "backward",
        };
        return format!("{what} (both wheels {left}°)");
    }
    let kind = if l + r == 0 {
        "spin"
    } else if l == 0 || r == 0 {
        "pivot"
    } else {
        "veer"
    };
    format!("{kind} {side}{travel} (left {left}°, right {right}°)")
}

/// The names of the actions and the features of the world `map` describes, as a saved
/// library stores them: `(action_names, feature_names)`. Actions are always named, by their
/// wheel targets (the map carries them). Features are named only when the map uses the arena
/// layout — [`ARENA_FEATURES`] features over [`ORIENTATIONS`] orientations, as every map
/// perception publishes does; for any other map they are left unnamed (empty), since nothing
/// says what its features mean.
pub fn map_names(map: &WorldMap) -> (Vec<String>, Vec<String>) {
    let actions = (map.n_actions as usize).min(map.action_wheels.len());
    let action_names = map.action_wheels[..actions]
        .iter()
        .map(|&wheels| wheel_action_name(wheels))
        .collect();
    let arena_layout =
        map.n_features as usize == ARENA_FEATURES && usize::from(map.orientations) == ORIENTATIONS;
    let feature_names = if arena_layout {
        arena_feature_names()
    } else {
        Vec::new()
    };
    (action_names, feature_names)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_arena_feature_has_one_distinct_name_in_its_block() {
        let names = arena_feature_names();
        assert_eq!(names.len(), ARENA_FEATURES);
        let distinct: std::collections::HashSet<&String> = names.iter().collect();
        assert_eq!(distinct.len(), ARENA_FEATURES, "names are distinct");
        assert_eq!(names[GREEN_RINGS], "green ring 0");
        assert_eq!(names[BLUE_RINGS - 1], "green ring 99");
        assert_eq!(names[BLUE_RINGS + 12], "blue ring 12");
        assert_eq!(names[BALL_RINGS + 7], "ball ring 7");
        assert_eq!(names[ORIENTATION_FEATURES - 1], "ball ring 99");
        assert_eq!(names[ORIENTATION_FEATURES], "facing E");
        assert_eq!(names[ORIENTATION_FEATURES + 2], "facing N");
        assert_eq!(names[ORIENTATION_FEATURES + 7], "facing SE");
        assert_eq!(
            &names[GREEN_IN_CELL..],
            [
                "green mark in cell",
                "no green mark in cell",
                "blue mark in cell",
                "no blue mark in cell"
            ]
        );
        assert_eq!(arena_feature_name(ARENA_FEATURES), None);
        assert_eq!(arena_feature_name(usize::MAX), None);
    }

    #[test]
    fn actions_are_named_by_what_the_wheels_do() {
        assert_eq!(wheel_action_name([246, 246]), "forward (both wheels 246°)");
        assert_eq!(wheel_action_name([-30, -30]), "backward (both wheels -30°)");
        assert_eq!(wheel_action_name([0, 0]), "stay (both wheels 0°)");
        assert_eq!(
            wheel_action_name([90, -90]),
            "spin right (left 90°, right -90°)"
        );
        assert_eq!(
            wheel_action_name([-45, 45]),
            "spin left (left -45°, right 45°)"
        );
        assert_eq!(
            wheel_action_name([90, 0]),
            "pivot right (left 90°, right 0°)"
        );
        assert_eq!(
            wheel_action_name([0, 90]),
            "pivot left (left 0°, right 90°)"
        );
        assert_eq!(
            wheel_action_name([-90, 0]),
            "pivot left backward (left -90°, right 0°)"
        );
        assert_eq!(
            wheel_action_name([200, 100]),
            "veer right (left 200°, right 100°)"
        );
        // The extremes do not overflow.
        assert_eq!(
            wheel_action_name([i32::MIN, i32::MAX]),
            format!(
                "veer left backward (left {}°, right {}°)",
                i32::MIN,
                i32::MAX
            )
        );
    }

    #[test]
    fn a_map_of_the_arena_layout_names_its_features_and_another_only_its_actions() {
        let mut map = WorldMap::EMPTY;
        (map.n_actions, map.n_features, map.orientations) = (3, ARENA_FEATURES as u32, 8);
        map.action_wheels[..3].copy_from_slice(&[[246, 246], [90, -90], [90, 0]]);
        let (actions, features) = map_names(&map);
        assert_eq!(
            actions,
            [
                "forward (both wheels 246°)",
                "spin right (left 90°, right -90°)",
                "pivot right (left 90°, right 0°)"
            ]
        );
        assert_eq!(features, arena_feature_names());

        // Another feature count or orientation count: not the arena layout.
        for (features, orientations) in [(4, 8), (ARENA_FEATURES as u32, 4)] {
            (map.n_features, map.orientations) = (features, orientations);
            let (actions, names) = map_names(&map);
            assert_eq!(actions.len(), 3);
            assert!(
                names.is_empty(),
                "{features} features, {orientations} orientations"
            );
        }
        // A map claiming more actions than it can carry names those it carries.
        map.n_actions = 99;
        assert_eq!(map_names(&map).0.len(), crate::MAX_ACTIONS);
    }

    /// Every wheel pair gets a name that starts with what the robot does and holds both
    /// targets; mirrored wheels turn the other way.
    #[test]
    fn every_wheel_pair_is_named_and_mirrors_turn_the_other_way() {
        let values = [
            i32::MIN,
            -720,
            -246,
            -90,
            -1,
            0,
            1,
            45,
            90,
            246,
            720,
            i32::MAX,
        ];
        for left in values {
            for right in values {
                let name = wheel_action_name([left, right]);
                let mut words = name.split_whitespace();
                let kind = words.next().unwrap_or_default();
                assert!(
                    ["forward", "backward", "stay", "spin", "pivot", "veer"].contains(&kind),
                    "{name}"
                );
                assert!(name.contains(&format!("{left}°")), "{name}");
                assert!(name.contains(&format!("{right}°)")), "{name}");
                if left != right {
                    let mirrored = wheel_action_name([right, left]);
                    let side = |n: &str| n.split_whitespace().nth(1).map(str::to_owned);
                    let (a, b) = (side(&name), side(&mirrored));
                    assert!(
                        matches!(
                            (a.as_deref(), b.as_deref()),
                            (Some("right"), Some("left")) | (Some("left"), Some("right"))
                        ),
                        "{name} / {mirrored}"
                    );
                }
            }
        }
    }
}
