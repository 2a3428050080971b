//! [`WorldMap`]: what the observatory (perception) tells the controller about the world once,
//! at start — every state's features, the effects' known meaning, rewards and terminal states —
//! so the controller can plan without knowing anything about arenas.

#[cfg(feature = "ipc")]
use iceoryx2::prelude::ZeroCopySend;

use crate::{FeatureBits, StateAttributes};

/// The most states a [`WorldMap`] holds (the largest arena: 10 × 10 cells × 8 orientations,
/// plus one "out of the area" state).
pub const MAX_STATES: usize = 1024;
/// The most effects (the arenas' 4 moves × 5 turns).
pub const MAX_EFFECTS: usize = 20;
/// The most actions.
pub const MAX_ACTIONS: usize = 4;

/// The agent-known structure of a world (its CMDP without the dynamics), published once with
/// history so a controller that starts later still receives it.
///
/// States are numbered `(y · width + x) · orientations + orientation`; one more state,
/// `width · height · orientations`, is "out of the area", reported in an
/// [`Observation`](crate::Observation) with `x = y = u16::MAX`.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("tes::WorldMap"))]
#[repr(C)]
pub struct WorldMap {
    /// Strictly increasing per publisher.
    pub seq: u64,
    /// Which world (arena number, 1–3).
    pub world: u32,
    /// States in use (≤ [`MAX_STATES`]).
    pub n_states: u32,
    /// Actions (≤ [`MAX_ACTIONS`]).
    pub n_actions: u32,
    /// Effects (≤ [`MAX_EFFECTS`]).
    pub n_effects: u32,
    /// Binary features per state.
    pub n_features: u32,
    /// Cells across.
    pub width: u16,
    /// Cells down.
    pub height: u16,
    /// Orientations per cell.
    pub orientations: u16,
    /// Padding; always 0.
    pub reserved: u16,
    /// Wheel targets (left, right; degrees) of each action.
    pub action_wheels: [[i32; 2]; MAX_ACTIONS],
    /// `next_state[s][e]`: where effect `e` takes the robot from state `s`.
    pub next_state: [[u16; MAX_EFFECTS]; MAX_STATES],
    /// Reward for entering each state.
    pub reward: [f32; MAX_STATES],
    /// 1 if an episode ends on entering the state.
    pub terminal: [u8; MAX_STATES],
    /// The binary features of every state.
    pub features: [FeatureBits; MAX_STATES],
}

impl WorldMap {
    /// An all-zero map (no states).
    pub const EMPTY: Self = Self {
        seq: 0,
        world: 0,
        n_states: 0,
        n_actions: 0,
        n_effects: 0,
        n_features: 0,
        width: 0,
        height: 0,
        orientations: 0,
        reserved: 0,
        action_wheels: [[0; 2]; MAX_ACTIONS],
        next_state: [[0; MAX_EFFECTS]; MAX_STATES],
        reward: [0.0; MAX_STATES],
        terminal: [0; MAX_STATES],
        features: [FeatureBits::EMPTY; MAX_STATES],
    };

    /// The "out of the area" state's index.
    pub fn out_state(&self) -> usize {
        usize::from(self.width) * usize::from(self.height) * usize::from(self.orientations)
    }

    /// The index of the state with these attributes, if it is one of the map's.
    pub fn state_index(&self, s: StateAttributes) -> Option<usize> {
        if s.is_out() {
            return Some(self.out_state()).filter(|&i| i < self.n_states as usize);
        }
        if s.x >= self.width || s.y >= self.height || s.orientation >= self.orientations {
            return None;
        }
        let cell = usize::from(s.y) * usize::from(self.width) + usize::from(s.x);
        Some(cell * usize::from(self.orientations) + usize::from(s.orientation))
    }

    /// The attributes of state `index` (`x = y = u16::MAX` for the out state).
    pub fn attributes(&self, index: usize) -> StateAttributes {
        let o = usize::from(self.orientations.max(1));
        if index >= self.out_state() {
            return StateAttributes::OUT;
        }
        let cell = index / o;
        let w = usize::from(self.width.max(1));
        StateAttributes {
            x: (cell % w) as u16,
            y: (cell / w) as u16,
            orientation: (index % o) as u16,
            reserved: 0,
        }
    }

    /// The effect that took the robot from state `from` to state `to`, by the rule of
    /// [`effect_between`](crate::effect_between) over this map's known outcomes.
    /// Allocation-free.
    pub fn effect_between(&self, from: usize, to: usize) -> usize {
        let row = self.next_state.get(from).map_or(&[][..], |r| &r[..]);
        let row = &row[..row.len().min(self.n_effects as usize)];
        // The common case, by index: the outcome whose state is `to` is the one whose pose is.
        if let Some(exact) = row.iter().position(|&next| usize::from(next) == to) {
            return exact;
        }
        let outcomes = row.iter().map(|&next| self.attributes(usize::from(next)));
        crate::effect_between(outcomes, self.attributes(to), self.orientations)
    }

    /// Whether the counts fit the fixed capacities and every next state exists.
    pub fn check(&self) -> Result<(), String> {
        let (s, a, e) = (
            self.n_states as usize,
            self.n_actions as usize,
            self.n_effects as usize,
        );
        if s == 0 || s > MAX_STATES || a == 0 || a > MAX_ACTIONS || e == 0 || e > MAX_EFFECTS {
            return Err(format!(
                "{s} states, {a} actions, {e} effects exceed the map's capacity ({MAX_STATES}, {MAX_ACTIONS}, {MAX_EFFECTS}) or are zero"
            ));
        }
        if self.n_features as usize > crate::FEATURE_CAPACITY {
            return Err(format!("{} features per state", self.n_features));
        }
        if self.out_state() >= s && self.width != 0 {
            return Err(format!(
                "{s} states cannot hold a {}x{}x{} grid and its out state",
                self.width, self.height, self.orientations
            ));
        }
        for (i, row) in self.next_state[..s].iter().enumerate() {
            if let Some(&bad) = row[..e].iter().find(|&&n| usize::from(n) >= s) {
                return Err(format!("state {i} has an effect leading to state {bad}"));
            }
        }
        if let Some(i) = self.reward[..s].iter().position(|r| !r.is_finite()) {
            return Err(format!("state {i} has a non-finite reward"));
        }
        if let Some(i) = self.features[..s]
            .iter()
            .position(|f| f.has_bits_beyond(self.n_features as usize))
        {
            return Err(format!("state {i} has features beyond {}", self.n_features));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small() -> WorldMap {
        let mut m = WorldMap::EMPTY;
        (m.width, m.height, m.orientations) = (3, 2, 8);
        m.n_states = 3 * 2 * 8 + 1;
        (m.n_actions, m.n_effects, m.n_features) = (3, 20, 312);
        m
    }

    #[test]
    fn state_indices_and_attributes_agree() {
        let m = small();
        for i in 0..m.n_states as usize {
            assert_eq!(m.state_index(m.attributes(i)), Some(i));
        }
        assert_eq!(m.out_state(), 48);
        let off = StateAttributes {
            x: 3,
            y: 0,
            orientation: 0,
            reserved: 0,
        };
        assert_eq!(m.state_index(off), None);
        assert!(m.check().is_ok());
    }

    #[test]
    fn bad_maps_are_refused() {
        let mut m = small();
        m.next_state[4][7] = 49;
        assert!(m.check().unwrap_err().contains("state 4"));
        let mut m = small();
        m.n_states = 40;
        assert!(m.check().is_err());
        let mut m = small();
        m.reward[2] = f32::NAN;
        assert!(m.check().unwrap_err().contains("reward"));
        let mut m = small();
        m.n_effects = 21;
        assert!(m.check().is_err());
    }
}
