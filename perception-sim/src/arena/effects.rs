//! The 20 effects an action can have: a relative move and a turn.

use super::*;

/// How an effect moves the robot, relative to its orientation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Move {
    /// To the neighbouring cell straight ahead.
    Forward = 0,
    /// To the neighbouring cell 45° to the left of ahead.
    ForwardLeft = 1,
    /// To the neighbouring cell 45° to the right of ahead.
    ForwardRight = 2,
    /// Stays in the cell.
    Stay = 3,
}

impl Move {
    /// All moves, in effect order.
    pub const ALL: [Move; N_MOVES] = [
        Move::Forward,
        Move::ForwardLeft,
        Move::ForwardRight,
        Move::Stay,
    ];

    /// The orientation change (in 45° steps, left positive) of the direction moved, if any.
    pub(super) fn direction(self) -> Option<i32> {
        match self {
            Move::Forward => Some(0),
            Move::ForwardLeft => Some(1),
            Move::ForwardRight => Some(-1),
            Move::Stay => None,
        }
    }

    fn name(self) -> &'static str {
        match self {
            Move::Forward => "forward",
            Move::ForwardLeft => "forward-left",
            Move::ForwardRight => "forward-right",
            Move::Stay => "no move",
        }
    }
}

/// How an effect turns the robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Turn {
    /// Keeps its orientation.
    None = 0,
    /// To the next orientation on the left (+45°).
    Left = 1,
    /// Two orientations to the left (+90°).
    Left2 = 2,
    /// To the next orientation on the right (−45°).
    Right = 3,
    /// Two orientations to the right (−90°).
    Right2 = 4,
}

impl Turn {
    /// All turns, in effect order.
    pub const ALL: [Turn; N_TURNS] = [
        Turn::None,
        Turn::Left,
        Turn::Left2,
        Turn::Right,
        Turn::Right2,
    ];

    /// The orientation change in 45° steps, counter-clockwise (left) positive.
    pub fn delta(self) -> i32 {
        match self {
            Turn::None => 0,
            Turn::Left => 1,
            Turn::Left2 => 2,
            Turn::Right => -1,
            Turn::Right2 => -2,
        }
    }

    fn name(self) -> &'static str {
        match self {
            Turn::None => "no turn",
            Turn::Left => "1 left",
            Turn::Left2 => "2 left",
            Turn::Right => "1 right",
            Turn::Right2 => "2 right",
        }
    }
}

/// One of the 20 effects: a move and a turn, both relative to the robot's orientation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Effect {
    /// Where the robot went.
    pub movement: Move,
    /// How it turned.
    pub turn: Turn,
}

impl Effect {
    /// The effect with index `i` (< 20): move `i / 5`, turn `i % 5`.
    pub fn from_index(i: usize) -> Option<Effect> {
        Some(Effect {
            movement: *Move::ALL.get(i / N_TURNS)?,
            turn: Turn::ALL[i % N_TURNS],
        })
    }

    /// The effect's index, `move · 5 + turn`.
    pub fn index(self) -> usize {
        self.movement as usize * N_TURNS + self.turn as usize
    }
}

impl fmt::Display for Effect {
    /// E.g. "forward-left, 1 right".
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}, {}", self.movement.name(), self.turn.name())
    }
}
