//! The paper's three arenas as layouts: size, marks, ball, death spots and surfaces.

use super::*;

/// One of the paper's three arenas.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ArenaId {
    /// Environment 1: 6×6 ft, 10×10 cells, blue marks on beans.
    Env1,
    /// Environment 2: 5×5 ft, 8×8 cells, green marks on a slope.
    Env2,
    /// Environment 3: like Env 1's surfaces, with the ball, death spots and green marks moved.
    Env3,
}

impl ArenaId {
    /// All three, in order.
    pub const ALL: [ArenaId; 3] = [ArenaId::Env1, ArenaId::Env2, ArenaId::Env3];

    /// The paper's number, 1–3.
    pub fn number(self) -> u32 {
        match self {
            ArenaId::Env1 => 1,
            ArenaId::Env2 => 2,
            ArenaId::Env3 => 3,
        }
    }

    /// The arena with the paper's number `n` (1–3).
    pub fn from_number(n: u32) -> Result<Self, ArenaError> {
        match n {
            1 => Ok(ArenaId::Env1),
            2 => Ok(ArenaId::Env2),
            3 => Ok(ArenaId::Env3),
            other => Err(ArenaError::UnknownArena(other)),
        }
    }
}

impl fmt::Display for ArenaId {
    /// "Env 1", "Env 2" or "Env 3".
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Env {}", self.number())
    }
}

/// The colour of a mark drawn on the floor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MarkColour {
    /// Green.
    Green,
    /// Blue.
    Blue,
}

impl MarkColour {
    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            MarkColour::Green => "green",
            MarkColour::Blue => "blue",
        }
    }

    /// The other colour.
    pub fn other(self) -> MarkColour {
        match self {
            MarkColour::Green => MarkColour::Blue,
            MarkColour::Blue => MarkColour::Green,
        }
    }

    /// The feature "a mark of this colour is in the cell".
    pub fn in_cell_feature(self) -> usize {
        match self {
            MarkColour::Green => GREEN_IN_CELL,
            MarkColour::Blue => BLUE_IN_CELL,
        }
    }

    /// The feature "no mark of this colour is in the cell".
    pub fn not_in_cell_feature(self) -> usize {
        self.in_cell_feature() + 1
    }

    pub(super) fn flag(self) -> u8 {
        match self {
            MarkColour::Green => FLAG_GREEN,
            MarkColour::Blue => FLAG_BLUE,
        }
    }
}

/// Why an arena (or a request to one) is invalid.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ArenaError {
    /// No arena has this number.
    #[error("arena {0} does not exist (1, 2 or 3)")]
    UnknownArena(u32),
    /// No such action.
    #[error("action {0} does not exist (0, 1 or 2)")]
    BadAction(usize),
    /// No such state.
    #[error("state {state} does not exist ({states} states)")]
    BadState {
        /// The state given.
        state: usize,
        /// Number of states.
        states: usize,
    },
    /// The episode already ended.
    #[error("the episode is over")]
    EpisodeOver,
    /// Cells per side outside 2..=32.
    #[error("{0} cells per side is outside 2..=32")]
    BadSize(usize),
    /// The side length is not a positive finite number of cm.
    #[error("side length {0} cm is not positive and finite")]
    BadSide(f64),
    /// A mark or the ball lies outside the area (or is not finite).
    #[error("{what} at ({x}, {y}) cm lies outside the area")]
    OutsideArea {
        /// "green mark", "blue mark" or "ball".
        what: &'static str,
        /// East coordinate, cm.
        x: f64,
        /// North coordinate, cm.
        y: f64,
    },
    /// A death spot lies outside the grid.
    #[error("death spot ({x}, {y}) lies outside the grid")]
    DeathOutside {
        /// Column.
        x: usize,
        /// Row.
        y: usize,
    },
    /// The ball is on a death spot.
    #[error("the ball lies on a death spot")]
    BallOnDeath,
    /// Every cell is terminal: nowhere to start.
    #[error("every cell is a death spot or the ball: nowhere to start")]
    NoStartCell,
    /// A hand-drawn map is malformed.
    #[error("map: {0}")]
    BadMap(String),
}

/// The full description of an arena, from which [`Arena::from_layout`] derives everything.
#[derive(Debug, Clone, PartialEq)]
pub struct ArenaLayout {
    /// Cells per side (the grid is square), 2..=32.
    pub cells: usize,
    /// Side length, cm.
    pub side_cm: f64,
    /// The colour of the marks on the surface that changes the dynamics.
    pub governing: MarkColour,
    /// The surface under every governing-colour mark.
    pub governing_surface: Surface,
    /// The floor everywhere else (carpet unless set; paper board in the paper's Env 2).
    pub floor: Surface,
    /// Green mark positions, cm.
    pub green_marks: Vec<DVec2>,
    /// Blue mark positions, cm.
    pub blue_marks: Vec<DVec2>,
    /// Ball position, cm; its cell is the goal.
    pub ball: DVec2,
    /// Death spot cells `(x, y)`.
    pub death_cells: Vec<(usize, usize)>,
}

/// Env 1 (north row first): `b` blue mark, `g` green mark, `+` both, `O` ball, `X` death.
pub(super) const ENV1_MAP: &str = "
    . . . . . . . . . .
    . . . g . . . . O .
    . X . . . b b . . .
    . . . . b b b . X .
    . g . b b + . . . .
    . . . b b . . g . .
    . . . . . . X . . .
    . . g . . . . . . .
    . X . . . . . . g .
    . . . . . . . . . .
";

/// Env 2: the green marks lie on the slope, the blue ones are decoys.
pub(super) const ENV2_MAP: &str = "
    . . . . . . . .
    . b . . X . O .
    . . . g g g . .
    . X . g + g b .
    . . . g g . . .
    . b . . . . X .
    . . . . b . . .
    X . . . . . . .
";

/// Env 3: Env 1's blue marks (and beans); ball, deaths and green marks elsewhere.
pub(super) const ENV3_MAP: &str = "
    . . . . . . . . . .
    . O . . . . g . . .
    . . . . . b b . X .
    . . X . b b b . . .
    . . . b b b . g . .
    g . . b b . . . . .
    . . . . . . . . X .
    . . . . g . X . . .
    . . . . . . . . . .
    . . . g . . . . . g
";

impl ArenaLayout {
    /// The paper's arena `id`, as reconstructed here (the maps, north row first; `b` blue,
    /// `g` green, `+` both, `O` ball, `X` death spot):
    ///
    /// ```text
    ///  Env 1 (6 ft, beans)    Env 2 (5 ft, slope)    Env 3 (6 ft, beans)
    ///  . . . . . . . . . .    . . . . . . . .        . . . . . . . . . .
    ///  . . . g . . . . O .    . b . . X . O .        . O . . . . g . . .
    ///  . X . . . b b . . .    . . . g g g . .        . . . . . b b . X .
    ///  . . . . b b b . X .    . X . g + g b .        . . X . b b b . . .
    ///  . g . b b + . . . .    . . . g g . . .        . . . b b b . g . .
    ///  . . . b b . . g . .    . b . . . . X .        g . . b b . . . . .
    ///  . . . . . . X . . .    . . . . b . . .        . . . . . . . . X .
    ///  . . g . . . . . . .    X . . . . . . .        . . . . g . X . . .
    ///  . X . . . . . . g .                           . . . . . . . . . .
    ///  . . . . . . . . . .                           . . . g . . . . . g
    /// ```
    ///
    /// The blue cells of Env 1 and Env 3 coincide (the same bean patch); green marks, ball and
    /// death spots differ. Env 1 and Env 3 have a carpet floor, Env 2 paper board. Marks sit at fixed offsets from their cell's centre (see
    /// [`ArenaLayout::from_map`]); the ball sits at its cell's centre.
    pub fn paper(id: ArenaId) -> Self {
        let (map, feet, governing, surface) = match id {
            ArenaId::Env1 => (ENV1_MAP, 6.0, MarkColour::Blue, Surface::Beans),
            ArenaId::Env2 => (ENV2_MAP, 5.0, MarkColour::Green, Surface::Slope),
            ArenaId::Env3 => (ENV3_MAP, 6.0, MarkColour::Blue, Surface::Beans),
        };
        let mut layout = Self::from_map(map, feet * FOOT_CM, governing, surface)
            .expect("the paper's maps are well-formed");
        if id == ArenaId::Env2 {
            layout.floor = Surface::Board;
        }
        layout
    }

    /// Parses a square map, north row first, one character per cell (whitespace ignored):
    /// `.` plain, `g` green mark, `b` blue mark, `+` both, `O` the ball (exactly one), `X` a
    /// death spot. A mark in cell `(x, y)` sits at the cell's centre shifted by a fixed
    /// offset, `(0, 0)`, `(0.2, −0.15)`, `(−0.2, 0.1)` or `(0.15, 0.2)` cells for
    /// `(x + 2y) % 4` = 0, 1, 2, 3; the ball at its cell's centre. The floor is carpet
    /// (set [`ArenaLayout::floor`] for another).
    pub fn from_map(
        map: &str,
        side_cm: f64,
        governing: MarkColour,
        governing_surface: Surface,
    ) -> Result<Self, ArenaError> {
        let rows: Vec<Vec<char>> = map
            .lines()
            .map(|l| {
                l.chars()
                    .filter(|c| !c.is_whitespace())
                    .collect::<Vec<char>>()
            })
            .filter(|r| !r.is_empty())
            .collect();
        let cells = rows.len();
        if !(2..=32).contains(&cells) {
            return Err(ArenaError::BadSize(cells));
        }
        if !(side_cm.is_finite() && side_cm > 0.0) {
            return Err(ArenaError::BadSide(side_cm));
        }
        let cell_cm = side_cm / cells as f64;
        let mut layout = Self {
            cells,
            side_cm,
            governing,
            governing_surface,
            floor: Surface::Carpet,
            green_marks: Vec::new(),
            blue_marks: Vec::new(),
            ball: DVec2::ZERO,
            death_cells: Vec::new(),
        };
        let mut balls = 0;
        for (row, line) in rows.iter().enumerate() {
            if line.len() != cells {
                return Err(ArenaError::BadMap(format!(
                    "row {row} has {} cells, the map has {cells} rows",
                    line.len()
                )));
            }
            let y = cells - 1 - row;
            for (x, &c) in line.iter().enumerate() {
                let centre = DVec2::new((x as f64 + 0.5) * cell_cm, (y as f64 + 0.5) * cell_cm);
                let (ox, oy) = MARK_OFFSETS[(x + 2 * y) % 4];
                let mark = centre + DVec2::new(ox, oy) * cell_cm;
                match c {
                    '.' => {}
                    'g' => layout.green_marks.push(mark),
                    'b' => layout.blue_marks.push(mark),
                    '+' => {
                        layout.green_marks.push(mark);
                        layout.blue_marks.push(mark);
                    }
                    'O' => {
                        layout.ball = centre;
                        balls += 1;
                    }
                    'X' => layout.death_cells.push((x, y)),
                    other => {
                        return Err(ArenaError::BadMap(format!(
                            "unknown cell {other:?} in row {row}"
                        )));
                    }
                }
            }
        }
        if balls != 1 {
            return Err(ArenaError::BadMap(format!("{balls} balls, expected one")));
        }
        Ok(layout)
    }
}
