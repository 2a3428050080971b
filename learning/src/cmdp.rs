//! The situation-calculus MDP (CMDP) of the paper's §3.1, as the agent knows it.
//!
//! In a CMDP an action does not move the agent to a next state directly: it causes one of a few
//! discrete *effects* (a relative state change such as "moved north" or "stayed"), and the
//! effect's meaning is known. So
//!
//! `P(s' | s, a) = Σ_e P(s' | e, s) · P(e | x(s), a)`
//!
//! where `P(s' | e, s)` is 0 or 1 and known ([`CmdpStructure::next_state`]) — a move into a
//! wall or off the map is a known outcome (stay put) — and `P(e | x(s), a)` is what the agent
//! learns, one effect predictor (an mDAGL *view*) per action, from the state's features `x(s)`.
//!
//! [`CmdpStructure`] holds the known part: states, effect semantics, rewards, terminal states
//! and the features of every state. [`EffectTable`] caches the learned part, `P(e | x(s), a)`
//! for every state and action, and is refreshed one action at a time as views learn.

use std::ops::Range;

use thiserror::Error;

use crate::mdagl::{Features, Mdagl, MdaglError, softmax};

/// Why a [`CmdpStructure`] is malformed.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum CmdpError {
    /// No states, actions or effects.
    #[error("a CMDP needs at least one state, action and effect ({states}, {actions}, {effects})")]
    Empty {
        /// States given.
        states: usize,
        /// Actions given.
        actions: usize,
        /// Effects given.
        effects: usize,
    },
    /// A table has the wrong length.
    #[error("{table} has {got} entries, expected {expected}")]
    WrongLength {
        /// Which table.
        table: &'static str,
        /// Its length.
        got: usize,
        /// The length it should have.
        expected: usize,
    },
    /// An effect leads to a state that does not exist.
    #[error("effect {effect} in state {state} leads to state {next}, beyond the {states} states")]
    BadNextState {
        /// State.
        state: usize,
        /// Effect.
        effect: usize,
        /// The bad destination.
        next: u32,
        /// Number of states.
        states: usize,
    },
    /// A reward is NaN or infinite.
    #[error("the reward for entering state {0} is not finite")]
    BadReward(usize),
    /// A step's reward ([`CmdpStructure::with_step_rewards`]) is NaN or infinite.
    #[error("the reward of action {action} with effect {effect} in state {state} is not finite")]
    BadStepReward {
        /// State.
        state: usize,
        /// Action.
        action: usize,
        /// Effect.
        effect: usize,
    },
    /// A state's features are out of range or unsorted.
    #[error("state {state}: {source}")]
    BadFeatures {
        /// State.
        state: usize,
        /// What is wrong.
        source: MdaglError,
    },
}

/// The agent-known part of a CMDP: effect semantics, rewards, terminal states and features.
#[derive(Debug, Clone, PartialEq)]
pub struct CmdpStructure {
    n_states: usize,
    n_actions: usize,
    n_effects: usize,
    n_features: usize,
    /// `next[s * E + e]`: the state effect `e` leads to from `s`.
    next: Vec<u32>,
    /// Reward for entering each state.
    reward: Vec<f64>,
    terminal: Vec<bool>,
    /// Sparse binary features, CSR: state `s` has `indices[offsets[s]..offsets[s+1]]`.
    offsets: Vec<usize>,
    indices: Vec<u32>,
    /// The transpose, CSR: feature `i` is on in states `holders[holder_offsets[i]..holder_offsets[i+1]]`.
    holder_offsets: Vec<usize>,
    holders: Vec<u32>,
    /// The reverse of `next`, CSR: some effect leads from each of
    /// `preds[pred_offsets[s]..pred_offsets[s+1]]` to `s` (each such state once).
    pred_offsets: Vec<usize>,
    preds: Vec<u32>,
    /// `steps[s * E + e]`: where effect `e` leads from `s` with that state's reward and
    /// whether it is terminal, side by side for the planner's backups. With step rewards the
    /// reward here is 0 (the backups add each action's own from `step_rewards`).
    steps: Vec<Step>,
    /// `step_rewards[(s * A + a) * E + e]`: the reward of action `a` in `s` when it has
    /// effect `e`, if [`with_step_rewards`](Self::with_step_rewards) gave them.
    step_rewards: Option<Vec<f64>>,
}

/// One successor of a state as a backup reads it: `R(next) + (live ? γ V(next) : 0)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Step {
    /// `R(next)`.
    pub(crate) reward: f64,
    /// The successor, below the structure's state count.
    pub(crate) next: u32,
    /// Whether `next` is not terminal (its value counts).
    pub(crate) live: bool,
}

impl CmdpStructure {
    /// Builds and checks a structure.
    ///
    /// * `next_state(s, e)` — where effect `e` takes the agent from state `s`;
    /// * `reward[s']` — the reward for entering `s'`;
    /// * `terminal[s]` — whether an episode ends on entering `s`;
    /// * `features(s)` — the sorted indices of the binary features on in `s`, below `n_features`.
    #[allow(clippy::too_many_arguments)]
    pub fn new<'a>(
        n_states: usize,
        n_actions: usize,
        n_effects: usize,
        n_features: usize,
        next_state: impl Fn(usize, usize) -> usize,
        reward: Vec<f64>,
        terminal: Vec<bool>,
        features: impl Fn(usize) -> &'a [u32],
    ) -> Result<Self, CmdpError> {
        if n_states == 0 || n_actions == 0 || n_effects == 0 {
            return Err(CmdpError::Empty {
                states: n_states,
                actions: n_actions,
                effects: n_effects,
            });
        }
        for (table, got) in [("reward", reward.len()), ("terminal", terminal.len())] {
            if got != n_states {
                return Err(CmdpError::WrongLength {
                    table,
                    got,
                    expected: n_states,
                });
            }
        }
        if let Some(s) = reward.iter().position(|r| !r.is_finite()) {
            return Err(CmdpError::BadReward(s));
        }
        let mut next = Vec::with_capacity(n_states * n_effects);
        for s in 0..n_states {
            for e in 0..n_effects {
                let to = next_state(s, e);
                let to32 = u32::try_from(to).unwrap_or(u32::MAX);
                if to >= n_states {
                    return Err(CmdpError::BadNextState {
                        state: s,
                        effect: e,
                        next: to32,
                        states: n_states,
                    });
                }
                next.push(to32);
            }
        }
        let mut offsets = Vec::with_capacity(n_states + 1);
        let mut indices = Vec::new();
        offsets.push(0);
        for s in 0..n_states {
            let x = features(s);
            Features::SparseBinary(x)
                .validate(n_features)
                .map_err(|source| CmdpError::BadFeatures { state: s, source })?;
            indices.extend_from_slice(x);
            offsets.push(indices.len());
        }
        let mut holder_offsets = vec![0usize; n_features + 1];
        for &i in &indices {
            holder_offsets[i as usize + 1] += 1;
        }
        for i in 0..n_features {
            holder_offsets[i + 1] += holder_offsets[i];
        }
        let mut fill = holder_offsets.clone();
        let mut holders = vec![0u32; indices.len()];
        for s in 0..n_states {
            for &i in &indices[offsets[s]..offsets[s + 1]] {
                holders[fill[i as usize]] = s as u32;
                fill[i as usize] += 1;
            }
        }
        let (pred_offsets, preds) = predecessors(n_states, n_effects, &next);
        let steps = next
            .iter()
            .map(|&to| Step {
                reward: reward[to as usize],
                next: to,
                live: !terminal[to as usize],
            })
            .collect();
        Ok(Self {
            n_states,
            n_actions,
            n_effects,
            n_features,
            next,
            reward,
            terminal,
            offsets,
            indices,
            holder_offsets,
            holders,
            pred_offsets,
            preds,
            steps,
            step_rewards: None,
        })
    }

    /// Every state's reward for entering it, by state.
    #[inline]
    pub(crate) fn rewards(&self) -> &[f64] {
        &self.reward
    }

    /// Whether each state is terminal, by state.
    #[inline]
    pub(crate) fn terminals(&self) -> &[bool] {
        &self.terminal
    }

    /// Every state's successors with their rewards and terminal flags: `steps()[s * E + e]`
    /// describes `next_state(s, e)`.
    #[inline]
    pub(crate) fn steps(&self) -> &[Step] {
        &self.steps
    }

    /// Number of states.
    pub fn n_states(&self) -> usize {
        self.n_states
    }

    /// Number of actions.
    pub fn n_actions(&self) -> usize {
        self.n_actions
    }

    /// Number of effects.
    pub fn n_effects(&self) -> usize {
        self.n_effects
    }

    /// Number of state features.
    pub fn n_features(&self) -> usize {
        self.n_features
    }

    /// The state effect `e` leads to from `s` (the known `P(s' | e, s)`).
    #[inline]
    pub fn next_state(&self, s: usize, e: usize) -> usize {
        self.next[s * self.n_effects + e] as usize
    }

    /// The states each effect leads to from `s`, by effect: `successors(s)[e] ==
    /// next_state(s, e)`.
    #[inline]
    pub fn successors(&self, s: usize) -> &[u32] {
        &self.next[s * self.n_effects..(s + 1) * self.n_effects]
    }

    /// Reward for entering state `s`.
    #[inline]
    pub fn reward(&self, s: usize) -> f64 {
        self.reward[s]
    }

    /// The reward of taking action `a` in `s` when it has effect `e` (and so leads to
    /// `next_state(s, e)`): the [`reward`](Self::reward) for entering where it leads, unless
    /// [`with_step_rewards`](Self::with_step_rewards) set it.
    #[inline]
    pub fn step_reward(&self, s: usize, a: usize, e: usize) -> f64 {
        match &self.step_rewards {
            Some(table) => table[(s * self.n_actions + a) * self.n_effects + e],
            None => self.steps[s * self.n_effects + e].reward,
        }
    }

    /// Whether [`with_step_rewards`](Self::with_step_rewards) gave the steps their rewards.
    #[inline]
    pub fn has_step_rewards(&self) -> bool {
        self.step_rewards.is_some()
    }

    /// The rewards of one state's steps, `[a * E + e]`, when the structure has step rewards.
    #[inline]
    pub(crate) fn step_rewards_of(&self, s: usize) -> Option<&[f64]> {
        let width = self.n_actions * self.n_effects;
        self.step_rewards
            .as_deref()
            .map(|table| &table[s * width..][..width])
    }

    /// The same structure with each step's reward decided by the state it starts in, the
    /// action taken and the effect it has, `reward(s, a, e)` — so by the state, the action
    /// and the next state, which `(s, e)` decides — instead of by the state it enters alone:
    /// a refused pick-up and a bump into a wall can stay put at different costs, and two
    /// actions with the same outcome can cost differently, with no copy of any state or
    /// effect. The planner backs up `Σ_e P(e | s, a) (reward(s, a, e) + γ V(next_state(s, e)))`;
    /// [`reward`](Self::reward) still reports the entering rewards the structure was built
    /// with. Kept as `S × A × E` floats (a Taxi of 500 states, 6 actions and 8 effects:
    /// 24 000), not `S × A × S`.
    pub fn with_step_rewards(
        mut self,
        reward: impl Fn(usize, usize, usize) -> f64,
    ) -> Result<Self, CmdpError> {
        let (n_states, n_actions, n_effects) = (self.n_states, self.n_actions, self.n_effects);
        let mut table = Vec::with_capacity(n_states * n_actions * n_effects);
        for state in 0..n_states {
            for action in 0..n_actions {
                for effect in 0..n_effects {
                    let r = reward(state, action, effect);
                    if !r.is_finite() {
                        return Err(CmdpError::BadStepReward {
                            state,
                            action,
                            effect,
                        });
                    }
                    table.push(r);
                }
            }
        }
        for step in &mut self.steps {
            step.reward = 0.0;
        }
        self.step_rewards = Some(table);
        Ok(self)
    }

    /// Whether an episode ends on entering `s`.
    #[inline]
    pub fn is_terminal(&self, s: usize) -> bool {
        self.terminal[s]
    }

    /// The binary features on in state `s`, sorted.
    #[inline]
    pub fn features(&self, s: usize) -> &[u32] {
        &self.indices[self.offsets[s]..self.offsets[s + 1]]
    }

    /// The states in which feature `i` is on, in increasing order.
    #[inline]
    pub fn states_with_feature(&self, i: usize) -> &[u32] {
        &self.holders[self.holder_offsets[i]..self.holder_offsets[i + 1]]
    }

    /// The states from which some effect leads to `s`, each once, in increasing order (the
    /// states whose backups read `V(s)`).
    #[inline]
    pub fn predecessors(&self, s: usize) -> &[u32] {
        &self.preds[self.pred_offsets[s]..self.pred_offsets[s + 1]]
    }

    /// Which effect leads from `s` to `next`, if one does (the lowest such effect id).
    ///
    /// Used where only states are observed; when several effects lead to the same state (a
    /// blocked move and "stay") the world should report the effect itself instead.
    pub fn effect_between(&self, s: usize, next: usize) -> Option<usize> {
        (0..self.n_effects).find(|&e| self.next_state(s, e) == next)
    }
}

/// The reverse of the successor table `next` (`next[s * E + e]`), CSR: each state's
/// predecessors, each once, in increasing order.
fn predecessors(n_states: usize, n_effects: usize, next: &[u32]) -> (Vec<usize>, Vec<u32>) {
    // Each distinct (from, to) pair once: a state's effects may share a successor.
    let distinct = |s: usize| {
        let succ = &next[s * n_effects..(s + 1) * n_effects];
        succ.iter()
            .enumerate()
            .filter(move |&(e, t)| !succ[..e].contains(t))
            .map(|(_, &t)| t as usize)
    };
    let mut offsets = vec![0usize; n_states + 1];
    for s in 0..n_states {
        for t in distinct(s) {
            offsets[t + 1] += 1;
        }
    }
    for t in 0..n_states {
        offsets[t + 1] += offsets[t];
    }
    let mut fill = offsets.clone();
    let mut preds = vec![0u32; offsets[n_states]];
    for s in 0..n_states {
        for t in distinct(s) {
            preds[fill[t]] = s as u32;
            fill[t] += 1;
        }
    }
    (offsets, preds)
}

/// `P(e | x(s), a)` for every action, state and effect: the learned half of the transition
/// model, cached so planning does not call the views.
///
/// Two tables are equal when their shapes and probabilities are.
#[derive(Debug, Clone)]
pub struct EffectTable {
    n_states: usize,
    n_effects: usize,
    /// `probs[(a * S + s) * E + e]`.
    probs: Vec<f64>,
    /// The same probabilities by state, for models of at most [`LANES`] actions (else empty):
    /// `lanes[(s * E + e) * LANES + a]`, the lanes of actions the model lacks 0. The planner
    /// computes a state's Q-values of all actions side by side (one SIMD lane each).
    lanes: Vec<f64>,
    /// Per state: some action's row changed since the planner last backed the state up
    /// ([`EffectTable::parts`]).
    fresh: Vec<bool>,
    /// Working memory of [`EffectTable::refresh`].
    scratch: RefreshScratch,
}

impl PartialEq for EffectTable {
    fn eq(&self, other: &Self) -> bool {
        self.n_states == other.n_states
            && self.n_effects == other.n_effects
            && self.probs == other.probs
    }
}

/// Actions whose probabilities [`EffectTable`] also keeps side by side per state and effect.
pub(crate) const LANES: usize = 4;

/// What the planner reads of an [`EffectTable`] and the flags it clears ([`EffectTable::parts`]).
pub(crate) struct TableParts<'a> {
    /// `probs[(a * S + s) * E + e]`.
    pub(crate) probs: &'a [f64],
    /// `lanes[(s * E + e) * LANES + a]`, or empty.
    pub(crate) lanes: &'a [f64],
    /// Per state: some row changed since the planner last backed it up.
    pub(crate) fresh: &'a mut [bool],
}

/// How many of a view's feature columns [`EffectTable::refresh`] tracks as a per-state bit
/// pattern; a view using more is refreshed state by state.
const PATTERN_BITS: usize = 64;

/// What [`EffectTable::refresh`] works in, kept between calls so it allocates nothing.
#[derive(Debug, Clone)]
struct RefreshScratch {
    /// New rows, built before they are compared with the old ones: one per state (state
    /// refresh) or one per distinct pattern (pattern refresh).
    rows: Vec<f64>,
    /// Per state: bit `j` set when the view's `j`-th used feature column is on there.
    patterns: Vec<u64>,
    /// The weights of the view's used feature columns, `PATTERN_BITS × E`.
    columns: Vec<f64>,
    /// The intercept's weights (`E`; zero without one).
    intercept: Vec<f64>,
    /// Every feature column's weights, `n_features × E`, zero where the view uses none
    /// (state refresh).
    weights: Vec<f64>,
    /// Per state: the row of `rows` holding its pattern's probabilities (pattern refresh).
    slots: Vec<u32>,
    /// Open-addressing map from a pattern to its row of `rows`; an entry counts only if its
    /// stamp is the current refresh's.
    keys: Vec<u64>,
    slot: Vec<u32>,
    stamps: Vec<u32>,
    stamp: u32,
    /// Whether the refresh in progress goes by pattern (else state by state).
    by_pattern: bool,
    /// Distinct patterns met so far in the refresh in progress.
    distinct: usize,
}

impl RefreshScratch {
    fn new(n_states: usize, n_effects: usize, n_features: usize) -> Self {
        let slots = (2 * n_states).next_power_of_two().max(2);
        Self {
            rows: vec![0.0; n_states * n_effects],
            patterns: vec![0; n_states],
            columns: vec![0.0; PATTERN_BITS * n_effects],
            intercept: vec![0.0; n_effects],
            weights: vec![0.0; n_features * n_effects],
            slots: vec![0; n_states],
            keys: vec![0; slots],
            slot: vec![0; slots],
            stamps: vec![0; slots],
            stamp: 0,
            by_pattern: true,
            distinct: 0,
        }
    }

    /// Starts a new pattern map (no entry of an earlier refresh counts any more).
    fn clear_map(&mut self) {
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            // Wrapped: stamps from 2^32 refreshes ago could look current.
            self.stamps.fill(0);
            self.stamp = 1;
        }
    }

    /// The scratch row of `pattern`: the one recorded earlier in this refresh, or else
    /// `next`, now recorded as its row.
    fn slot_of(&mut self, pattern: u64, next: usize) -> usize {
        let mask = self.keys.len() - 1;
        // Fibonacci hashing: the high bits of the product mix every bit of the pattern.
        let mut i = (pattern.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 32) as usize & mask;
        loop {
            if self.stamps[i] != self.stamp {
                self.stamps[i] = self.stamp;
                self.keys[i] = pattern;
                self.slot[i] = next as u32;
                return next;
            }
            if self.keys[i] == pattern {
                return self.slot[i] as usize;
            }
            i = (i + 1) & mask;
        }
    }
}

impl EffectTable {
    /// A table with every effect equally likely everywhere (what a fresh view predicts).
    pub fn uniform(structure: &CmdpStructure) -> Self {
        let (s, a, e) = (
            structure.n_states(),
            structure.n_actions(),
            structure.n_effects(),
        );
        let mut lanes = Vec::new();
        if a <= LANES {
            lanes = vec![0.0; s * e * LANES];
            for lane in lanes.chunks_exact_mut(LANES) {
                lane[..a].fill(1.0 / e as f64);
            }
        }
        Self {
            n_states: s,
            n_effects: e,
            probs: vec![1.0 / e as f64; a * s * e],
            lanes,
            fresh: vec![true; s],
            scratch: RefreshScratch::new(s, e, structure.n_features()),
        }
    }

    /// The probabilities (both layouts) and the per-state flags of rows changed since the
    /// planner last backed a state up, which it clears as it does.
    pub(crate) fn parts(&mut self) -> TableParts<'_> {
        TableParts {
            probs: &self.probs,
            lanes: &self.lanes,
            fresh: &mut self.fresh,
        }
    }

    /// The probabilities by action and, if kept, by state ([`TableParts`] without the flags).
    pub(crate) fn layouts(&self) -> (&[f64], &[f64]) {
        (&self.probs, &self.lanes)
    }

    /// Copies row `(a, s)` of `probs` into `lanes` and flags `s` when its bits changed.
    #[inline]
    fn mirror_row(&mut self, a: usize, s: usize, changed: bool) {
        if changed {
            self.fresh[s] = true;
        }
        if self.lanes.is_empty() {
            return;
        }
        let e = self.n_effects;
        let start = (a * self.n_states + s) * e;
        for (k, &p) in self.probs[start..start + e].iter().enumerate() {
            self.lanes[(s * e + k) * LANES + a] = p;
        }
    }

    /// Overwrites this table with `other`, which must have the same shape. Allocation-free
    /// (unlike `clone_from`, which reallocates).
    pub fn copy_from(&mut self, other: &EffectTable) -> Result<(), CmdpError> {
        self.copy_rows_from(other, 0..self.n_rows())
    }

    /// `P(· | x(s), a)` as a slice over effects.
    #[inline]
    pub fn probs(&self, a: usize, s: usize) -> &[f64] {
        let start = (a * self.n_states + s) * self.n_effects;
        &self.probs[start..start + self.n_effects]
    }

    /// Recomputes action `a`'s rows from its view, for every state, and returns how far the
    /// model moved: the largest L1 distance between a state's old and new effect distribution.
    /// Allocation-free.
    ///
    /// Equal to calling [`Mdagl::predict_into`] on every state, but it visits only the
    /// features the view uses (a sparse view over hundreds of features touches a handful),
    /// and computes the probabilities once per pattern of used features that are on, not
    /// once per state.
    /// The view must predict `n_effects` classes from `n_features` features.
    ///
    /// A planner between polls does the same work in bounded pieces, with the same bits
    /// (see [`PlannedModel::advance`](crate::plan::PlannedModel::advance)).
    pub fn refresh(
        &mut self,
        a: usize,
        view: &Mdagl,
        structure: &CmdpStructure,
    ) -> Result<f64, MdaglError> {
        self.begin_refresh(view, structure)?;
        let all = 0..self.n_states;
        self.refresh_rows(all.clone())?;
        Ok(self.refresh_write(a, all))
    }

    /// Starts a refresh from `view` (checked against the table's shape): takes the weights
    /// of the columns it uses, and, by pattern, each state's pattern of used columns that are
    /// on; by state (a view using more than [`PATTERN_BITS`] columns), every state's scores.
    /// Then [`refresh_rows`](Self::refresh_rows) builds the new rows over every state, in
    /// order, and [`refresh_write`](Self::refresh_write) compares and writes them. Nothing
    /// reaches the table before `refresh_write`, so a refresh that fails leaves it intact.
    pub(crate) fn begin_refresh(
        &mut self,
        view: &Mdagl,
        structure: &CmdpStructure,
    ) -> Result<(), MdaglError> {
        let e = self.n_effects;
        if view.n_classes() != e {
            return Err(MdaglError::WrongOutputLen {
                expected: view.n_classes(),
                got: e,
            });
        }
        if view.n_features() != structure.n_features() {
            return Err(MdaglError::WrongFeatureCount {
                expected: view.n_features(),
                got: structure.n_features(),
            });
        }
        let n_features = structure.n_features();
        let mut used = 0;
        view.for_each_weight_column(|col, _, _| used += usize::from(col < n_features));
        if used > PATTERN_BITS {
            self.begin_by_state(view, structure);
        } else {
            self.begin_by_pattern(view, structure);
        }
        Ok(())
    }

    /// By state: every state's scores, the sum of the weights of its features that are on.
    ///
    /// State by state, over the state's sorted feature list, with the view's weights laid out
    /// densely (zero for the columns it does not use) and the state's scores in registers:
    /// the same sums in the same order (features by increasing column, the intercept last;
    /// adding a zero leaves a score's bits alone, as no score is ever −0), so the same bits as
    /// scattering each column's weights into the states where it is on, at a fraction of the
    /// memory traffic — a dense view (bloreRL uses every column) sums ~100 weights per state.
    fn begin_by_state(&mut self, view: &Mdagl, structure: &CmdpStructure) {
        match self.n_effects {
            5 => self.by_state_of::<5>(view, structure),
            20 => self.by_state_of::<20>(view, structure),
            _ => self.by_state_of::<0>(view, structure),
        }
    }

    /// [`begin_by_state`](Self::begin_by_state) for `E` effects (0: any count).
    fn by_state_of<const E: usize>(&mut self, view: &Mdagl, structure: &CmdpStructure) {
        let e = if E == 0 { self.n_effects } else { E };
        let n_features = structure.n_features();
        let scratch = &mut self.scratch;
        scratch.by_pattern = false;
        let weights = &mut scratch.weights[..n_features * e];
        weights.fill(0.0);
        let intercept = &mut scratch.intercept[..e];
        intercept.fill(0.0);
        view.for_each_weight_column(|col, scale, sums| {
            let column = if col < n_features {
                &mut weights[col * e..(col + 1) * e]
            } else {
                &mut *intercept
            };
            for (w, &g) in column.iter_mut().zip(sums) {
                *w = scale * g;
            }
        });
        let (weights, intercept) = (&scratch.weights[..n_features * e], &scratch.intercept[..e]);
        let rows = scratch.rows[..structure.n_states() * e].chunks_exact_mut(e);
        for (s, row) in rows.enumerate() {
            if E == 0 {
                row.fill(0.0);
                for &j in structure.features(s) {
                    let w = &weights[j as usize * e..(j as usize + 1) * e];
                    for (score, &w) in row.iter_mut().zip(w) {
                        *score += w;
                    }
                }
                for (score, &w) in row.iter_mut().zip(intercept) {
                    *score += w;
                }
                continue;
            }
            let mut scores = [0.0f64; E];
            for &j in structure.features(s) {
                let w = &weights[j as usize * E..(j as usize + 1) * E];
                for k in 0..E {
                    scores[k] += w[k];
                }
            }
            for k in 0..E {
                scores[k] += intercept[k];
            }
            row.copy_from_slice(&scores);
        }
    }

    /// By pattern (a view using at most [`PATTERN_BITS`] feature columns): states on which
    /// the same used columns are on get the same row, and a sparse view leaves few such
    /// patterns (mDAGL keeps a handful of columns), so each pattern's scores and softmax are
    /// computed once (into the scratch, one row per pattern) and then compared with and
    /// copied into every state's row — the `exp` per state and effect dominated the refresh
    /// before. Scores are summed in the same order as by state, so both give the same bits.
    fn begin_by_pattern(&mut self, view: &Mdagl, structure: &CmdpStructure) {
        let e = self.n_effects;
        let n_features = structure.n_features();
        let scratch = &mut self.scratch;
        scratch.by_pattern = true;
        scratch.patterns.fill(0);
        scratch.intercept.fill(0.0);
        let mut used = 0;
        view.for_each_weight_column(|col, scale, sums| {
            if col < n_features {
                let column = &mut scratch.columns[used * e..(used + 1) * e];
                for (w, &g) in column.iter_mut().zip(sums) {
                    *w = scale * g;
                }
                for &s in structure.states_with_feature(col) {
                    scratch.patterns[s as usize] |= 1 << used;
                }
                used += 1;
            } else {
                for (w, &g) in scratch.intercept.iter_mut().zip(sums) {
                    *w = scale * g;
                }
            }
        });
        // Each distinct pattern gets the next row of the scratch; `slots[s]` is state `s`'s.
        scratch.clear_map();
        scratch.distinct = 0;
    }

    /// Builds the new rows of `states` (after [`begin_refresh`](Self::begin_refresh); call
    /// it over every state in order, in as many pieces as wanted).
    pub(crate) fn refresh_rows(&mut self, states: Range<usize>) -> Result<(), MdaglError> {
        // The grid tasks have 5 effects, the robot arenas 20: with the count a constant the
        // compiler unrolls the per-effect loops (same code, same bits).
        match self.n_effects {
            5 => self.rows_of::<5>(states),
            20 => self.rows_of::<20>(states),
            _ => self.rows_of::<0>(states),
        }
    }

    /// [`refresh_rows`](Self::refresh_rows) for `E` effects (0: any count).
    fn rows_of<const E: usize>(&mut self, states: Range<usize>) -> Result<(), MdaglError> {
        let e = if E == 0 { self.n_effects } else { E };
        let scratch = &mut self.scratch;
        if !scratch.by_pattern {
            return scratch.rows[states.start * e..states.end * e]
                .chunks_exact_mut(e)
                .try_for_each(|row| softmax(row).map(|_| ()));
        }
        for s in states {
            let pattern = scratch.patterns[s];
            let distinct = scratch.distinct;
            let slot = scratch.slot_of(pattern, distinct);
            scratch.slots[s] = slot as u32;
            if slot < distinct {
                continue;
            }
            scratch.distinct += 1;
            let row = &mut scratch.rows[slot * e..slot * e + e];
            row.fill(0.0);
            let mut bits = pattern;
            while bits != 0 {
                let j = bits.trailing_zeros() as usize;
                bits &= bits - 1;
                for (score, &w) in row.iter_mut().zip(&scratch.columns[j * e..j * e + e]) {
                    *score += w;
                }
            }
            for (score, &w) in row.iter_mut().zip(&scratch.intercept[..e]) {
                *score += w;
            }
            softmax(row)?;
        }
        Ok(())
    }

    /// Writes the new rows of `states` into action `a`'s rows (once
    /// [`refresh_rows`](Self::refresh_rows) has built every state's) and returns the
    /// largest L1 distance between a state's old and new row among them.
    pub(crate) fn refresh_write(&mut self, a: usize, states: Range<usize>) -> f64 {
        match self.n_effects {
            5 => self.write_of::<5>(a, states),
            20 => self.write_of::<20>(a, states),
            _ => self.write_of::<0>(a, states),
        }
    }

    /// [`refresh_write`](Self::refresh_write) for `E` effects (0: any count).
    fn write_of<const E: usize>(&mut self, a: usize, states: Range<usize>) -> f64 {
        let e = if E == 0 { self.n_effects } else { E };
        let scratch = &self.scratch;
        let base = a * self.n_states;
        let rows = &mut self.probs[(base + states.start) * e..(base + states.end) * e];
        let mut moved: f64 = 0.0;
        for (old, s) in rows.chunks_exact_mut(e).zip(states) {
            let slot = if scratch.by_pattern {
                scratch.slots[s] as usize
            } else {
                s
            };
            let new = &scratch.rows[slot * e..slot * e + e];
            moved = moved.max(l1_distance(&old[..e], new));
            if !same_bits(&old[..e], new) {
                old[..e].copy_from_slice(new);
                self.fresh[s] = true;
                if !self.lanes.is_empty() {
                    for (k, &p) in new.iter().enumerate() {
                        self.lanes[(s * e + k) * LANES + a] = p;
                    }
                }
            }
        }
        moved
    }

    /// Copies action rows `rows` (indices `a * n_states + s`) from `other`, of the same
    /// shape (a whole-table copy in pieces; see [`copy_from`](Self::copy_from)).
    pub(crate) fn copy_rows_from(
        &mut self,
        other: &EffectTable,
        rows: Range<usize>,
    ) -> Result<(), CmdpError> {
        if self.probs.len() != other.probs.len() || self.n_effects != other.n_effects {
            return Err(CmdpError::WrongLength {
                table: "effect table",
                got: other.probs.len(),
                expected: self.probs.len(),
            });
        }
        let e = self.n_effects;
        let span = rows.start * e..rows.end * e;
        self.probs[span.clone()].copy_from_slice(&other.probs[span]);
        for row in rows {
            let (a, s) = (row / self.n_states, row % self.n_states);
            self.mirror_row(a, s, true);
        }
        Ok(())
    }

    /// How many rows (state–action pairs) the table has.
    pub(crate) fn n_rows(&self) -> usize {
        self.probs.len() / self.n_effects.max(1)
    }

    /// Overwrites `P(· | s, a)` directly (for models that are not mDAGL views).
    ///
    /// `probs` must hold one value per effect. Returns the L1 distance between the old and
    /// the new distribution.
    pub fn set(&mut self, a: usize, s: usize, probs: &[f64]) -> f64 {
        let start = (a * self.n_states + s) * self.n_effects;
        let row = &mut self.probs[start..start + self.n_effects];
        let moved = l1_distance(row, probs);
        let changed = !same_bits(row, probs);
        row.copy_from_slice(probs);
        self.mirror_row(a, s, changed);
        moved
    }
}

/// Whether `p` and `q` hold the same bits (unlike `==`, which holds `0.0 == -0.0`).
#[inline]
fn same_bits(p: &[f64], q: &[f64]) -> bool {
    p.len() == q.len() && p.iter().zip(q).all(|(a, b)| a.to_bits() == b.to_bits())
}

/// `Σ |p_i − q_i|`.
fn l1_distance(p: &[f64], q: &[f64]) -> f64 {
    p.iter().zip(q).map(|(a, b)| (a - b).abs()).sum()
}

/// Small example worlds, for documentation examples and tests.
pub mod examples {
    use super::CmdpStructure;

    /// Two states, two actions, two effects that both lead from state 0 to the terminal
    /// state 1, no features and no entering rewards.
    pub fn two_state_structure() -> CmdpStructure {
        let no_features: &[u32] = &[];
        CmdpStructure::new(
            2,
            2,
            2,
            0,
            |_, _| 1,
            vec![0.0, 0.0],
            vec![false, true],
            |_| no_features,
        )
        .unwrap()
    }

    /// A corridor of `n` cells, 2 actions (left, right), 3 effects (left, right, stay); the
    /// right end is a +1 terminal, the left end a −1 terminal; −0.01 elsewhere. Feature 0 is a
    /// bias, feature 1 marks "slippery" cells. Panics if `n < 2`.
    pub fn corridor(n: usize, slippery: &[usize]) -> CmdpStructure {
        let feats = (0..n)
            .map(|s| {
                if slippery.contains(&s) {
                    vec![0, 1]
                } else {
                    vec![0]
                }
            })
            .collect();
        corridor_with(feats, 2)
    }

    /// The same corridor (one cell per entry of `feats`) with any sparse features.
    pub fn corridor_with(feats: Vec<Vec<u32>>, n_features: usize) -> CmdpStructure {
        let n = feats.len();
        let mut reward = vec![-0.01; n];
        reward[0] = -1.0;
        reward[n - 1] = 1.0;
        let mut terminal = vec![false; n];
        terminal[0] = true;
        terminal[n - 1] = true;
        CmdpStructure::new(
            n,
            2,
            3,
            n_features,
            |s, e| match e {
                0 => s.saturating_sub(1),
                1 => (s + 1).min(n - 1),
                _ => s,
            },
            reward,
            terminal,
            |s| &feats[s],
        )
        .expect("a corridor of two or more cells is a valid CMDP")
    }
}

#[cfg(test)]
mod tests {
    use super::examples::corridor;
    use super::*;

    #[test]
    fn structure_answers_what_it_was_given() {
        let c = corridor(5, &[2]);
        assert_eq!((c.n_states(), c.n_actions(), c.n_effects()), (5, 2, 3));
        assert_eq!(c.next_state(0, 0), 0);
        assert_eq!(c.next_state(2, 1), 3);
        assert_eq!(c.features(2), &[0, 1]);
        assert_eq!(c.features(3), &[0]);
        assert!(c.is_terminal(4) && !c.is_terminal(2));
        assert_eq!(c.effect_between(2, 1), Some(0));
        assert_eq!(c.effect_between(2, 2), Some(2));
        assert_eq!(c.effect_between(2, 4), None);
        // The planner's successor table says the same.
        for s in 0..c.n_states() {
            for e in 0..c.n_effects() {
                let step = c.steps()[s * c.n_effects() + e];
                let next = c.next_state(s, e);
                assert_eq!(step.next as usize, next);
                assert_eq!(step.reward.to_bits(), c.reward(next).to_bits());
                assert_eq!(step.live, !c.is_terminal(next));
            }
        }
    }

    #[test]
    fn malformed_structures_are_refused() {
        let f = [0u32];
        let ok = |s: usize| -> &[u32] {
            let _ = s;
            &f
        };
        assert!(matches!(
            CmdpStructure::new(0, 1, 1, 1, |s, _| s, vec![], vec![], ok),
            Err(CmdpError::Empty { .. })
        ));
        assert!(matches!(
            CmdpStructure::new(2, 1, 1, 1, |_, _| 2, vec![0.0; 2], vec![false; 2], ok),
            Err(CmdpError::BadNextState { next: 2, .. })
        ));
        assert!(matches!(
            CmdpStructure::new(2, 1, 1, 1, |s, _| s, vec![0.0; 3], vec![false; 2], ok),
            Err(CmdpError::WrongLength {
                table: "reward",
                ..
            })
        ));
        assert!(matches!(
            CmdpStructure::new(
                2,
                1,
                1,
                1,
                |s, _| s,
                vec![f64::NAN, 0.0],
                vec![false; 2],
                ok
            ),
            Err(CmdpError::BadReward(0))
        ));
        let bad = [3u32];
        assert!(matches!(
            CmdpStructure::new(2, 1, 1, 1, |s, _| s, vec![0.0; 2], vec![false; 2], |_| &bad),
            Err(CmdpError::BadFeatures { state: 0, .. })
        ));
    }

    proptest::proptest! {
        /// The column-wise refresh equals predicting every state one by one, whether it goes
        /// by pattern (views using up to 64 feature columns; specialised for 5 and 20
        /// effects) or state by state, whole or in pieces; where several apply they give the
        /// same bits and report the same move.
        #[test]
        fn refresh_equals_per_state_prediction(
            seed in 0u64..1000,
            features in 1usize..100,
            effects in proptest::sample::select(vec![4usize, 5, 20]),
            intercept in proptest::bool::ANY,
            lambda in 0.0..0.1f64,
            piece in 1usize..40,
        ) {
            use rand::{RngExt, SeedableRng};
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let n = 30;
            let feats: Vec<Vec<u32>> = (0..n)
                .map(|_| (0..features as u32).filter(|_| rng.random::<f64>() < 0.3).collect())
                .collect();
            let c = CmdpStructure::new(
                n, 2, effects, features, |s, _| s, vec![0.0; n], vec![false; n], |s| &feats[s],
            ).unwrap();
            let params = crate::mdagl::MdaglParams { lambda, alpha: 0.5, intercept };
            let mut view = Mdagl::new(effects, features, params).unwrap();
            let mut table = EffectTable::uniform(&c);
            for t in 0..200 {
                let s = rng.random_range(0..n);
                view.update(Features::SparseBinary(&feats[s]), (s + t % 2) % effects).unwrap();
                if t == 100 {
                    // A refresh over an earlier one, so the move is between two views.
                    table.refresh(1, &view, &c).unwrap();
                }
            }
            let before = table.clone();
            table.refresh(1, &view, &c).unwrap();
            let mut p = vec![0.0; effects];
            for (s, f) in feats.iter().enumerate() {
                view.predict_into(Features::SparseBinary(f), &mut p).unwrap();
                for (a, b) in p.iter().zip(table.probs(1, s)) {
                    proptest::prop_assert!((a - b).abs() < 1e-12);
                }
            }
            // In pieces of any size, with the generic code or the specialised, by pattern
            // or by state: the same bits and the same move.
            let whole = table;
            let moved_whole = before.clone().refresh(1, &view, &c).unwrap();
            let mut used = 0;
            view.for_each_weight_column(|col, _, _| used += usize::from(col < features));
            let modes: &[bool] = if used <= PATTERN_BITS { &[true, false] } else { &[false] };
            for &by_pattern in modes {
                for generic in [false, true] {
                    let mut t = before.clone();
                    let moved = refresh_in_pieces(&mut t, 1, &view, &c, by_pattern, generic, piece);
                    proptest::prop_assert_eq!(&t.probs, &whole.probs);
                    proptest::prop_assert_eq!(moved.to_bits(), moved_whole.to_bits());
                }
            }
        }
    }

    /// A refresh of action `a` made `piece` states at a time, forced by pattern or by state,
    /// with the code specialised for the effect count or the generic code.
    fn refresh_in_pieces(
        table: &mut EffectTable,
        a: usize,
        view: &Mdagl,
        c: &CmdpStructure,
        by_pattern: bool,
        generic: bool,
        piece: usize,
    ) -> f64 {
        if by_pattern {
            table.begin_by_pattern(view, c);
        } else {
            table.begin_by_state(view, c);
        }
        let n = c.n_states();
        let pieces = || (0..n).step_by(piece).map(move |s| s..(s + piece).min(n));
        for range in pieces() {
            if generic {
                table.rows_of::<0>(range).unwrap();
            } else {
                table.refresh_rows(range).unwrap();
            }
        }
        let mut moved: f64 = 0.0;
        for range in pieces() {
            moved = moved.max(if generic {
                table.write_of::<0>(a, range)
            } else {
                table.refresh_write(a, range)
            });
        }
        moved
    }

    #[test]
    fn effect_table_follows_the_view() {
        let c = corridor(5, &[2]);
        let mut table = EffectTable::uniform(&c);
        assert!(
            table
                .probs(1, 3)
                .iter()
                .all(|&p| (p - 1.0 / 3.0).abs() < 1e-15)
        );
        let mut view = Mdagl::new(3, 2, crate::mdagl::MdaglParams::default()).unwrap();
        for _ in 0..200 {
            view.update(Features::SparseBinary(&[0]), 1).unwrap();
        }
        table.refresh(1, &view, &c).unwrap();
        assert!(table.probs(1, 3)[1] > 0.6);
        // Action 0's rows are untouched.
        assert!((table.probs(0, 3)[1] - 1.0 / 3.0).abs() < 1e-15);
        // The fast refresh equals per-state prediction.
        let mut p = [0.0; 3];
        for s in 0..5 {
            view.predict_into(Features::SparseBinary(c.features(s)), &mut p)
                .unwrap();
            for (a, b) in p.iter().zip(table.probs(1, s)) {
                assert!((a - b).abs() < 1e-12);
            }
        }
        assert_eq!(c.states_with_feature(1), &[2]);
        assert_eq!(c.states_with_feature(0), &[0, 1, 2, 3, 4]);
        table.set(0, 1, &[0.0, 0.0, 1.0]);
        assert_eq!(table.probs(0, 1), &[0.0, 0.0, 1.0]);
    }
}
