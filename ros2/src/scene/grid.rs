//! A world that is not one of the paper's arenas — a ROS 2 robot's grid of states — drawn
//! from its map alone: the cells (those that end an episode, by the sign of their reward),
//! the grid, and the robot at the cell and heading it was observed in.

use tes_perception_sim::arena::DVec2;
use tes_topics::{StateAttributes, WorldMap};
use tes_viewer::robot::FloorPose;

use super::{M_PER_CM, arena_marker, at, cm, robot_body};
use crate::msg::{ColorRgba, Header, Marker, MarkerArray, Point, Vector3, marker};

/// A cell's side as drawn: the map says nothing of scale.
const CELL_CM: f64 = 30.0;

/// What a cell is, as its map says it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Cell {
    /// Entering it goes on.
    Plain,
    /// Entering it ends an episode with a reward above 0 (an exit, a goal).
    Goal,
    /// Entering it ends an episode otherwise (fire, a collision).
    Hazard,
}

/// A grid world as drawn.
#[derive(Debug, Clone)]
pub(super) struct GridWorld {
    width: u16,
    height: u16,
    orientations: u16,
    cells: Vec<Cell>,
}

impl GridWorld {
    /// The drawing of `map`, if it is a grid (cells across and down).
    pub(super) fn from_map(map: &WorldMap) -> Option<Self> {
        if map.width == 0 || map.height == 0 || map.orientations == 0 {
            return None;
        }
        let cells = (0..map.height)
            .flat_map(|y| (0..map.width).map(move |x| (x, y)))
            .map(|(x, y)| {
                let s = map.state_index(StateAttributes::at(x, y, 0))?;
                let (terminal, reward) = (map.terminal[s] != 0, map.reward[s]);
                Some(match (terminal, reward > 0.0) {
                    (false, _) => Cell::Plain,
                    (true, true) => Cell::Goal,
                    (true, false) => Cell::Hazard,
                })
            })
            .collect::<Option<Vec<Cell>>>()?;
        Some(Self {
            width: map.width,
            height: map.height,
            orientations: map.orientations,
            cells,
        })
    }

    /// Where the robot is drawn in state `s`: its cell's centre, facing its orientation
    /// (orientation 0 east, counter-clockwise); `None` out of the area.
    pub(super) fn pose(&self, s: StateAttributes) -> Option<FloorPose> {
        if s.is_out() || s.x >= self.width || s.y >= self.height {
            return None;
        }
        Some(FloorPose {
            position: centre(s.x, s.y),
            heading: f64::from(s.orientation) * std::f64::consts::TAU
                / f64::from(self.orientations),
        })
    }

    /// The world's markers: the floor, the goal and hazard cells, the grid, the robot.
    pub(super) fn markers(&self, header: &Header) -> MarkerArray {
        let (w, h) = (f64::from(self.width), f64::from(self.height));
        let cell = CELL_CM * M_PER_CM;
        let floor = Marker {
            pose: at(w * cell / 2.0, h * cell / 2.0, -0.01),
            scale: Vector3 {
                x: w * cell,
                y: h * cell,
                z: 0.02,
            },
            color: rgba(0.82, 0.80, 0.74),
            ..arena_marker(header, 0, marker::CUBE)
        };
        MarkerArray {
            markers: vec![
                floor,
                self.cells_of(Cell::Goal, 1, rgba(0.20, 0.70, 0.30), header),
                self.cells_of(Cell::Hazard, 2, rgba(0.85, 0.20, 0.15), header),
                self.grid(header),
                robot_body(header),
            ],
        }
    }

    /// The cells of `kind`, as one list of tiles.
    fn cells_of(&self, kind: Cell, id: i32, color: ColorRgba, header: &Header) -> Marker {
        let cell = CELL_CM * M_PER_CM;
        let points = self
            .cells
            .iter()
            .enumerate()
            .filter(|(_, c)| **c == kind)
            .map(|(i, _)| {
                let (x, y) = (i % usize::from(self.width), i / usize::from(self.width));
                cm(centre(x as u16, y as u16), 0.002)
            })
            .collect();
        Marker {
            pose: at(0.0, 0.0, 0.0),
            scale: Vector3 {
                x: cell * 0.9,
                y: cell * 0.9,
                z: 0.004,
            },
            points,
            color,
            ..arena_marker(header, id, marker::CUBE_LIST)
        }
    }

    /// The grid's lines.
    fn grid(&self, header: &Header) -> Marker {
        let cell = CELL_CM * M_PER_CM;
        let (w, h) = (f64::from(self.width) * cell, f64::from(self.height) * cell);
        let across = (0..=self.width).flat_map(|i| {
            let x = f64::from(i) * cell;
            [(x, 0.0), (x, h)]
        });
        let down = (0..=self.height).flat_map(|j| {
            let y = f64::from(j) * cell;
            [(0.0, y), (w, y)]
        });
        Marker {
            pose: at(0.0, 0.0, 0.0),
            scale: Vector3 {
                x: 0.003,
                ..Vector3::default()
            },
            points: across
                .chain(down)
                .map(|(x, y)| Point { x, y, z: 0.0015 })
                .collect(),
            color: ColorRgba {
                a: 0.5,
                ..rgba(0.15, 0.15, 0.15)
            },
            ..arena_marker(header, 3, marker::LINE_LIST)
        }
    }
}

/// The centre of cell `(x, y)`, cm from the grid's south-west corner.
fn centre(x: u16, y: u16) -> DVec2 {
    DVec2::new(
        (f64::from(x) + 0.5) * CELL_CM,
        (f64::from(y) + 0.5) * CELL_CM,
    )
}

fn rgba(r: f32, g: f32, b: f32) -> ColorRgba {
    ColorRgba { r, g, b, a: 1.0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 3 × 2 cells, 4 orientations (and the out state): cell (2, 1) a goal, (0, 1) a hazard.
    fn map() -> Box<WorldMap> {
        let mut map = Box::new(WorldMap::EMPTY);
        (map.width, map.height, map.orientations) = (3, 2, 4);
        map.n_states = 3 * 2 * 4 + 1;
        for o in 0..4 {
            let goal = map.state_index(StateAttributes::at(2, 1, o)).unwrap();
            (map.terminal[goal], map.reward[goal]) = (1, 1.0);
            let fire = map.state_index(StateAttributes::at(0, 1, o)).unwrap();
            (map.terminal[fire], map.reward[fire]) = (1, -1.0);
        }
        map
    }

    #[test]
    fn the_cells_are_drawn_by_what_entering_them_does() {
        let grid = GridWorld::from_map(&map()).expect("a grid");
        let markers = grid.markers(&Header::default()).markers;
        let (goal, hazard) = (&markers[1], &markers[2]);
        assert_eq!(goal.points.len(), 1);
        assert_eq!(hazard.points.len(), 1);
        // Cell (2, 1)'s centre: 2.5 and 1.5 cells of 0.3 m.
        assert!((goal.points[0].x - 0.75).abs() < 1e-9 && (goal.points[0].y - 0.45).abs() < 1e-9);
        assert!((hazard.points[0].x - 0.15).abs() < 1e-9);
        // 4 + 3 grid lines, two points each.
        assert_eq!(markers[3].points.len(), 2 * (4 + 3));
        assert_eq!(markers[4].header.frame_id, super::super::ROBOT_FRAME);
    }

    #[test]
    fn the_robot_is_at_its_cell_facing_its_orientation() {
        let grid = GridWorld::from_map(&map()).unwrap();
        let p = grid
            .pose(StateAttributes::at(1, 0, 1))
            .expect("in the grid");
        assert_eq!(p.position, DVec2::new(45.0, 15.0));
        assert!((p.heading - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!(grid.pose(StateAttributes::OUT).is_none());
        let mut no_grid = map();
        no_grid.width = 0;
        assert!(GridWorld::from_map(&no_grid).is_none());
    }
}
