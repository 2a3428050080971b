//! The arena drawn to scale in metres, in frame [`ARENA_FRAME`] (x east, y north, z up, the
//! origin at its south-west corner): once as a Foxglove scene (floor and surfaces per cell,
//! grid lines, marks, the ball, death spots, the walls) and once as a coloured point cloud,
//! which Rerun also decodes (it has no decoder for Foxglove's scene entities).

use foxglove::messages::{
    Color, CubePrimitive, CylinderPrimitive, LinePrimitive, PackedElementField, Point3, PointCloud,
    Pose, Quaternion, SceneEntity, SceneUpdate, SpherePrimitive, Timestamp, Vector3,
    line_primitive, packed_element_field,
};
use tes_perception_sim::arena::{Arena, DVec2, MarkColour, Surface};

/// The frame the arena is drawn in.
pub const ARENA_FRAME: &str = "arena";

/// Metres per centimetre: the worlds are in centimetres, viewers in metres.
pub const M_PER_CM: f64 = 0.01;

/// Height of the arena's walls, m.
const WALL_HEIGHT_M: f64 = 0.08;
/// Thickness of the walls and of the floor, m.
pub(crate) const WALL_THICKNESS_M: f64 = 0.02;
/// Diameter of a mark (a sticker on the floor), m.
const MARK_DIAMETER_M: f64 = 0.06;
/// Diameter of the ball, m.
const BALL_DIAMETER_M: f64 = 0.07;

/// An opaque colour.
pub(crate) fn rgb(r: f64, g: f64, b: f64) -> Color {
    Color { r, g, b, a: 1.0 }
}

/// A surface's colour.
pub fn surface_colour(surface: Surface) -> Color {
    match surface {
        Surface::Carpet => rgb(0.60, 0.57, 0.52),
        Surface::Board => rgb(0.86, 0.80, 0.64),
        Surface::Beans => rgb(0.50, 0.32, 0.16),
        Surface::Slope => rgb(0.84, 0.74, 0.34),
    }
}

/// A mark's colour.
pub fn mark_colour(colour: MarkColour) -> Color {
    match colour {
        MarkColour::Blue => rgb(0.10, 0.35, 0.90),
        MarkColour::Green => rgb(0.12, 0.68, 0.25),
    }
}

/// The ball's colour (a blue ball).
pub const BALL: Color = Color {
    r: 0.0,
    g: 0.25,
    b: 1.0,
    a: 1.0,
};
/// A death spot's colour.
pub const DEATH: Color = Color {
    r: 0.85,
    g: 0.08,
    b: 0.08,
    a: 1.0,
};
pub(crate) const WALL: Color = Color {
    r: 0.25,
    g: 0.25,
    b: 0.28,
    a: 1.0,
};
const GRID: Color = Color {
    r: 0.15,
    g: 0.15,
    b: 0.15,
    a: 0.5,
};

/// A pose at `(x, y, z)` metres, not rotated.
pub(crate) fn at(x: f64, y: f64, z: f64) -> Pose {
    Pose {
        position: Some(Vector3 { x, y, z }),
        orientation: Some(Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }),
    }
}

pub(crate) fn size(x: f64, y: f64, z: f64) -> Option<Vector3> {
    Some(Vector3 { x, y, z })
}

fn metres(p: DVec2) -> (f64, f64) {
    (p.x * M_PER_CM, p.y * M_PER_CM)
}

fn flat_disc(centre: DVec2, diameter: f64, height: f64, color: Color) -> CylinderPrimitive {
    let (x, y) = metres(centre);
    // A cylinder's axis is its z axis: upright, a disc lying on the floor.
    CylinderPrimitive {
        pose: Some(at(x, y, height / 2.0)),
        size: size(diameter, diameter, height),
        bottom_scale: 1.0,
        top_scale: 1.0,
        color: Some(color),
    }
}

/// The arena as one scene entity `arena` in [`ARENA_FRAME`].
pub fn arena_scene(arena: &Arena, timestamp: Timestamp) -> SceneUpdate {
    let (cells, cell) = (arena.cells(), arena.cell_cm() * M_PER_CM);
    let side = arena.side_cm() * M_PER_CM;
    let mut entity = SceneEntity {
        timestamp: Some(timestamp),
        frame_id: ARENA_FRAME.into(),
        id: "arena".into(),
        ..SceneEntity::default()
    };
    entity.cubes.push(floor(side, arena.layout().floor));
    entity.cubes.extend(surface_cells(arena, cell));
    entity.cubes.extend(death_spots(arena, cell));
    entity.cubes.extend(walls(side));
    entity.lines.push(grid_lines(cells, cell, side));
    for colour in [MarkColour::Blue, MarkColour::Green] {
        let marks = arena.marks(colour).iter();
        entity
            .cylinders
            .extend(marks.map(|&m| flat_disc(m, MARK_DIAMETER_M, 0.004, mark_colour(colour))));
    }
    let (bx, by) = metres(arena.ball());
    entity.spheres.push(SpherePrimitive {
        pose: Some(at(bx, by, BALL_DIAMETER_M / 2.0)),
        size: size(BALL_DIAMETER_M, BALL_DIAMETER_M, BALL_DIAMETER_M),
        color: Some(BALL),
    });
    SceneUpdate {
        deletions: Vec::new(),
        entities: vec![entity],
    }
}

fn floor(side: f64, surface: Surface) -> CubePrimitive {
    CubePrimitive {
        pose: Some(at(side / 2.0, side / 2.0, -WALL_THICKNESS_M / 2.0)),
        size: size(side, side, WALL_THICKNESS_M),
        color: Some(surface_colour(surface)),
    }
}

/// Every cell whose surface is not the floor's (the beans, the slope), as a flat tile.
fn surface_cells(arena: &Arena, cell: f64) -> impl Iterator<Item = CubePrimitive> + '_ {
    let floor = arena.layout().floor;
    every_cell(arena)
        .filter(move |&(x, y)| arena.surface(x, y) != floor)
        .map(move |(x, y)| {
            let (cx, cy) = metres(arena.cell_centre(x, y));
            CubePrimitive {
                pose: Some(at(cx, cy, 0.001)),
                size: size(cell, cell, 0.002),
                color: Some(surface_colour(arena.surface(x, y))),
            }
        })
}

fn death_spots(arena: &Arena, cell: f64) -> impl Iterator<Item = CubePrimitive> + '_ {
    every_cell(arena)
        .filter(|&(x, y)| arena.is_death_cell(x, y))
        .map(move |(x, y)| {
            let (cx, cy) = metres(arena.cell_centre(x, y));
            CubePrimitive {
                pose: Some(at(cx, cy, 0.003)),
                size: size(cell * 0.8, cell * 0.8, 0.006),
                color: Some(DEATH),
            }
        })
}

fn every_cell(arena: &Arena) -> impl Iterator<Item = (usize, usize)> {
    let n = arena.cells();
    (0..n).flat_map(move |y| (0..n).map(move |x| (x, y)))
}

/// The four walls around the area, outside it.
fn walls(side: f64) -> [CubePrimitive; 4] {
    let (t, h) = (WALL_THICKNESS_M, WALL_HEIGHT_M);
    let wall = |x: f64, y: f64, sx: f64, sy: f64| CubePrimitive {
        pose: Some(at(x, y, h / 2.0)),
        size: size(sx, sy, h),
        color: Some(WALL),
    };
    [
        wall(side / 2.0, -t / 2.0, side + 2.0 * t, t),
        wall(side / 2.0, side + t / 2.0, side + 2.0 * t, t),
        wall(-t / 2.0, side / 2.0, t, side),
        wall(side + t / 2.0, side / 2.0, t, side),
    ]
}

/// The cell boundaries, as one line list.
fn grid_lines(cells: usize, cell: f64, side: f64) -> LinePrimitive {
    let mut points = Vec::with_capacity(4 * (cells + 1));
    for i in 0..=cells {
        let d = i as f64 * cell;
        let z = 0.0015;
        points.extend([
            Point3 { x: d, y: 0.0, z },
            Point3 { x: d, y: side, z },
            Point3 { x: 0.0, y: d, z },
            Point3 { x: side, y: d, z },
        ]);
    }
    LinePrimitive {
        r#type: line_primitive::Type::LineList as i32,
        pose: Some(at(0.0, 0.0, 0.0)),
        thickness: 1.0,
        scale_invariant: true,
        points,
        color: Some(GRID),
        ..LinePrimitive::default()
    }
}

/// Bytes per point of [`arena_points`]: x, y, z as 32-bit floats, then red, green, blue and
/// alpha as bytes.
const POINT_STRIDE: usize = 16;

/// The arena as coloured points in [`ARENA_FRAME`]: a point per cell centre in its surface's
/// colour (red on a death spot), a point per mark and the ball, and the four corners.
pub fn arena_points(arena: &Arena, timestamp: Timestamp) -> PointCloud {
    let mut points = Vec::new();
    let mut put = |p: DVec2, z: f64, c: Color| {
        let (x, y) = metres(p);
        points.push((x, y, z, c));
    };
    for (x, y) in every_cell(arena) {
        let colour = if arena.is_death_cell(x, y) {
            DEATH
        } else {
            surface_colour(arena.surface(x, y))
        };
        put(arena.cell_centre(x, y), 0.0, colour);
    }
    for colour in [MarkColour::Blue, MarkColour::Green] {
        for &m in arena.marks(colour) {
            put(m, 0.01, mark_colour(colour));
        }
    }
    put(arena.ball(), BALL_DIAMETER_M / 2.0, BALL);
    let side = arena.side_cm();
    for corner in [(0.0, 0.0), (side, 0.0), (0.0, side), (side, side)] {
        put(DVec2::new(corner.0, corner.1), 0.0, WALL);
    }
    coloured_points(&points, timestamp)
}

/// Points `(x, y, z, colour)` (m) as one cloud in [`ARENA_FRAME`]: x, y, z as 32-bit floats,
/// then red, green, blue and alpha as bytes ([`POINT_STRIDE`] bytes a point).
pub(crate) fn coloured_points(
    points: &[(f64, f64, f64, Color)],
    timestamp: Timestamp,
) -> PointCloud {
    let mut data = Vec::with_capacity(points.len() * POINT_STRIDE);
    for (x, y, z, c) in points {
        for v in [x, y, z] {
            data.extend_from_slice(&(*v as f32).to_le_bytes());
        }
        data.extend([c.r, c.g, c.b, c.a].map(|v| (v * 255.0).round() as u8));
    }
    let field =
        |name: &str, offset: u32, t: packed_element_field::NumericType| PackedElementField {
            name: name.into(),
            offset,
            r#type: t as i32,
        };
    use packed_element_field::NumericType::{Float32, Uint8};
    PointCloud {
        timestamp: Some(timestamp),
        frame_id: ARENA_FRAME.into(),
        pose: Some(at(0.0, 0.0, 0.0)),
        point_stride: POINT_STRIDE as u32,
        fields: vec![
            field("x", 0, Float32),
            field("y", 4, Float32),
            field("z", 8, Float32),
            field("red", 12, Uint8),
            field("green", 13, Uint8),
            field("blue", 14, Uint8),
            field("alpha", 15, Uint8),
        ],
        data: data.into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tes_perception_sim::arena::ArenaId;

    #[test]
    fn the_arena_is_drawn_to_scale_with_every_mark_the_ball_and_the_death_spots() {
        let arena = Arena::new(ArenaId::Env3);
        let scene = arena_scene(&arena, Timestamp::new(1, 0));
        let e = &scene.entities[0];
        assert_eq!(e.frame_id, ARENA_FRAME);
        let marks = arena.marks(MarkColour::Blue).len() + arena.marks(MarkColour::Green).len();
        assert_eq!(e.cylinders.len(), marks);
        assert_eq!(e.spheres.len(), 1);
        let deaths = every_cell(&arena)
            .filter(|&(x, y)| arena.is_death_cell(x, y))
            .count();
        assert!(deaths > 0);
        let floor = e.cubes[0].size.expect("sized");
        // Env 3 is 6 ft square.
        assert!((floor.x - 6.0 * 0.3048).abs() < 1e-9, "{floor:?}");
        // floor + beans + deaths + 4 walls
        let beans = every_cell(&arena)
            .filter(|&(x, y)| arena.surface(x, y) == Surface::Beans)
            .count();
        assert_eq!(e.cubes.len(), 1 + beans + deaths + 4);
        assert_eq!(e.lines[0].points.len(), 4 * (arena.cells() + 1));
    }

    #[test]
    fn the_point_cloud_has_a_point_per_cell_mark_ball_and_corner() {
        let arena = Arena::new(ArenaId::Env2);
        let cloud = arena_points(&arena, Timestamp::new(1, 0));
        let marks = arena.marks(MarkColour::Blue).len() + arena.marks(MarkColour::Green).len();
        let n = arena.cells() * arena.cells() + marks + 1 + 4;
        assert_eq!(cloud.data.len(), n * POINT_STRIDE);
        // The first point is cell (0, 0)'s centre.
        let x = f32::from_le_bytes(cloud.data[0..4].try_into().expect("4 bytes"));
        assert!((f64::from(x) - arena.cell_cm() * M_PER_CM / 2.0).abs() < 1e-6);
    }
}
