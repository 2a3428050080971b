//! LSE-Rmax: R-max exploration while learning which features each action's effect depends
//! on — a baseline of the paper's §5.1 (Fig. 3a, Table 1; m = 10, σ = 0.99 as there).
//!
//! Chakraborty & Stone, "Structure learning in ergodic factored MDPs without knowledge of the
//! transition function's in-degree", ICML 2011. LSE-Rmax ("Learn Structure and Exploit with
//! Rmax") learns the parents of every factor of a factored MDP's transition function without
//! being told the in-degree, by comparing models of increasing in-degree with a statistical
//! test, and plans R-max style on the current structure.
//!
//! **What is reconstructed.** The original algorithm text was not available to us (only its
//! abstract and the description in Nguyen et al.), so this is a faithful reading of its core
//! idea on a CMDP, where each action has one factor to predict — its effect — and the
//! candidate parents are the state's binary features:
//!
//! * For every action and every *candidate parent set* `Q` of at most
//!   [`LseRmaxParams::max_in_degree`] features, the agent counts the effects observed in each
//!   of `Q`'s `2^|Q|` contexts (feature assignments). All sets are counted all the time, which
//!   is what makes the algorithm heavy (the paper's Table 1).
//! * A context with at least `m` samples is *known*.
//! * Structure selection, after every observation of the action: start from `P = ∅`; for
//!   `k = 1, 2, …, max_in_degree`, compare `P` with every size-`k` superset `Q ⊃ P`. `Q`
//!   refines `P` *significantly* when a likelihood-ratio (G) test of "the effect is independent
//!   of `Q`'s extra features given `P`'s context", pooled over `P`'s contexts and using only
//!   `Q`'s known contexts, rejects independence at confidence `σ`, Bonferroni-corrected over
//!   the `C(F, k)` sets of size `k`. The most significant refinement (largest ratio of the
//!   statistic to its critical value; lowest set on ties) becomes `P`. If none is significant
//!   at size `k`, `P` is kept and size `k + 1` is still tried, so a parent pair whose features
//!   matter only jointly (an XOR) can be found. A larger set is thus accepted only when it
//!   predicts significantly better.
//! * Acting: `P(e | x(s), a)` is the effect frequency in `s`'s context of the chosen `P`; a
//!   state whose context has fewer than `m` samples is unknown and valued at
//!   `R_max / (1 − γ)` by the shared planner (R-max optimism). When a larger `P` is accepted
//!   its contexts split and some become unknown again, which re-opens exploration there.
//!
//! Simplifications against the original: the in-degree is capped at `max_in_degree`
//! (default 2, at most 3) to keep the number of candidate sets polynomial; there are no
//! separate exploration and exploitation phases and no horizon `T` (the structure is
//! re-selected after every step and the planner always uses it); counts keep growing after a
//! context becomes known (unlike frozen R-max estimates), because the same samples feed the
//! structure tests; and the χ² critical values use the Wilson–Hilferty approximation.

use std::sync::Arc;

use super::{Agent, AgentError, check_step};
use crate::cmdp::{CmdpStructure, EffectTable};
use crate::plan::{Optimism, PlannedModel, PlannerParams, ValueIteration};

/// The largest in-degree [`LseRmaxParams::max_in_degree`] may ask for.
const MAX_IN_DEGREE: usize = 3;

/// At most this many counters (actions × candidate contexts × effects).
const MAX_COUNTERS: usize = 1 << 24;

/// LSE-Rmax's settings, checked by [`LseRmax::new`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LseRmaxParams {
    /// Value-iteration settings (paper: γ = 0.95).
    pub planner: PlannerParams,
    /// Samples before a context is known (≥ 1; paper: 10).
    pub m: u32,
    /// Confidence of the structure test, in (0, 1) (paper: 0.99).
    pub sigma: f64,
    /// Largest parent set considered (at most 3; clipped to the feature count).
    pub max_in_degree: usize,
}

impl Default for LseRmaxParams {
    /// The paper's §5.1 settings (m = 10, σ = 0.99, γ = 0.95) and in-degree at most 2.
    fn default() -> Self {
        Self {
            planner: PlannerParams::default(),
            m: 10,
            sigma: 0.99,
            max_in_degree: 2,
        }
    }
}

/// The LSE-Rmax agent (Chakraborty & Stone, ICML 2011), as reconstructed here: R-max
/// exploration on a model whose parent features, per action, are re-selected after every step
/// by testing candidate parent sets of growing size (at most
/// [`LseRmaxParams::max_in_degree`]) with a G test at confidence σ; a context is known after
/// `m` samples. The source's module docs say what is reconstructed and what is simplified.
#[derive(Debug, Clone)]
pub struct LseRmax {
    structure: Arc<CmdpStructure>,
    params: LseRmaxParams,
    /// `has[s * F + f]`: whether feature `f` is on in state `s`.
    has: Vec<bool>,
    /// Candidate set `i` is `cand_features[cand_offsets[i]..cand_offsets[i + 1]]`, sorted;
    /// sets are ordered by size, then lexicographically; set 0 is `∅`.
    cand_offsets: Vec<usize>,
    cand_features: Vec<u32>,
    /// Sets of size `k` are `size_start[k]..size_start[k + 1]`.
    size_start: Vec<usize>,
    /// Candidate `i`'s counts start at `count_start[i]` within an action's block.
    count_start: Vec<usize>,
    /// Counters per action.
    block: usize,
    /// `counts[a * block + count_start[i] + ctx * E + e]`.
    counts: Vec<u32>,
    /// Per `k`, the standard-normal quantile of the Bonferroni-corrected confidence.
    z: Vec<f64>,
    /// Per action, the chosen parent set (a candidate index).
    chosen: Vec<usize>,
    /// `unknown[a * S + s]`.
    unknown: Vec<bool>,
    optimistic_value: f64,
    model: PlannedModel,
    scratch: Vec<f64>,
}

/// `n choose k`, saturating.
fn binomial(n: usize, k: usize) -> usize {
    (0..k).fold(1usize, |acc, i| acc.saturating_mul(n - i) / (i + 1))
}

/// The standard-normal quantile (Acklam's rational approximation, relative error < 1.2·10⁻⁹).
fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969_683_028_665_376e1,
        2.209_460_984_245_205e2,
        -2.759_285_104_469_687e2,
        1.383_577_518_672_69e2,
        -3.066_479_806_614_716e1,
        2.506_628_277_459_239,
    ];
    const B: [f64; 5] = [
        -5.447_609_879_822_406e1,
        1.615_858_368_580_409e2,
        -1.556_989_798_598_866e2,
        6.680_131_188_771_972e1,
        -1.328_068_155_288_572e1,
    ];
    const C: [f64; 6] = [
        -7.784_894_002_430_293e-3,
        -3.223_964_580_411_365e-1,
        -2.400_758_277_161_838,
        -2.549_732_539_343_734,
        4.374_664_141_464_968,
        2.938_163_982_698_783,
    ];
    const D: [f64; 4] = [
        7.784_695_709_041_462e-3,
        3.224_671_290_700_398e-1,
        2.445_134_137_142_996,
        3.754_408_661_907_416,
    ];
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    const LOW: f64 = 0.02425;
    if p < LOW {
        tail((-2.0 * p.ln()).sqrt())
    } else if p <= 1.0 - LOW {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    } else {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    }
}

/// The χ² quantile with `df` degrees of freedom at the normal quantile `z` (Wilson–Hilferty).
fn chi2_quantile(z: f64, df: usize) -> f64 {
    let k = df as f64;
    let h = 2.0 / (9.0 * k);
    (k * (1.0 - h + z * h.sqrt()).powi(3)).max(0.0)
}

impl LseRmax {
    /// A fresh agent on `structure`. LSE-Rmax does not randomise, so `seed` is only recorded
    /// for the common constructor shape.
    pub fn new(
        structure: Arc<CmdpStructure>,
        params: LseRmaxParams,
        seed: u64,
    ) -> Result<Self, AgentError> {
        let _ = seed;
        if params.m == 0 {
            return Err(AgentError::Invalid {
                param: "m",
                requirement: "at least 1",
            });
        }
        if !(params.sigma > 0.0 && params.sigma < 1.0) {
            return Err(AgentError::Invalid {
                param: "sigma",
                requirement: "in (0, 1)",
            });
        }
        if params.max_in_degree > MAX_IN_DEGREE {
            return Err(AgentError::Invalid {
                param: "max_in_degree",
                requirement: "at most 3",
            });
        }
        let (n_s, n_a, n_e, n_f) = (
            structure.n_states(),
            structure.n_actions(),
            structure.n_effects(),
            structure.n_features(),
        );
        let max_k = params.max_in_degree.min(n_f);
        let counters = (0..=max_k)
            .map(|k| binomial(n_f, k).saturating_mul((1 << k) * n_e))
            .fold(0usize, usize::saturating_add)
            .saturating_mul(n_a);
        if counters > MAX_COUNTERS {
            return Err(AgentError::Invalid {
                param: "max_in_degree",
                requirement: "small enough for at most 2^24 counters at this feature count",
            });
        }
        let model = PlannedModel::new(structure.clone(), params.planner)?;

        let mut has = vec![false; n_s * n_f];
        for s in 0..n_s {
            for &f in structure.features(s) {
                has[s * n_f + f as usize] = true;
            }
        }
        // Enumerate every set of at most max_k features, by size then lexicographically.
        let mut cand_offsets = vec![0];
        let mut cand_features = Vec::new();
        let mut size_start = vec![0];
        let mut count_start = Vec::new();
        let mut block = 0;
        for k in 0..=max_k {
            let mut combo: Vec<u32> = (0..k as u32).collect();
            loop {
                cand_features.extend_from_slice(&combo);
                cand_offsets.push(cand_features.len());
                count_start.push(block);
                block += (1 << k) * n_e;
                // Next combination of k out of n_f.
                let Some(i) = (0..k).rev().find(|&i| (combo[i] as usize) < n_f - k + i) else {
                    break;
                };
                combo[i] += 1;
                for j in i + 1..k {
                    combo[j] = combo[j - 1] + 1;
                }
            }
            size_start.push(count_start.len());
        }
        let z = (0..=max_k)
            .map(|k| {
                let tests = binomial(n_f, k).max(1) as f64;
                normal_quantile(1.0 - (1.0 - params.sigma) / tests)
            })
            .collect();
        let r_max = (0..n_s).map(|i| structure.reward(i)).fold(0.0, f64::max);
        Ok(Self {
            has,
            cand_offsets,
            cand_features,
            size_start,
            count_start,
            counts: vec![0; n_a * block],
            block,
            z,
            chosen: vec![0; n_a],
            unknown: vec![true; n_a * n_s],
            optimistic_value: r_max / (1.0 - params.planner.gamma),
            model,
            scratch: vec![0.0; n_e],
            structure,
            params,
        })
    }

    /// The settings.
    pub fn params(&self) -> LseRmaxParams {
        self.params
    }

    /// The parent features currently chosen for `action`'s effect, sorted.
    pub fn parents(&self, action: usize) -> Option<&[u32]> {
        self.chosen.get(action).map(|&i| self.set(i))
    }

    /// Whether `(state, action)` is known (its context under the chosen parents has at least
    /// `m` samples).
    pub fn is_known(&self, state: usize, action: usize) -> bool {
        state < self.structure.n_states()
            && action < self.structure.n_actions()
            && !self.unknown[action * self.structure.n_states() + state]
    }

    /// The planner, with the values and policy of the last plan.
    pub fn planner(&self) -> &ValueIteration {
        self.model.planner()
    }

    /// The learned `P(e | x(s), a)` (rows of unknown pairs are not used by the planner).
    pub fn effect_table(&self) -> &EffectTable {
        self.model.table()
    }

    /// Re-plans, with R-max optimism for unknown pairs, if the model changed since the last
    /// plan.
    pub fn replan(&mut self) {
        let optimism = Optimism {
            unknown: &self.unknown,
            value: self.optimistic_value,
        };
        self.model.replan_optimistic(optimism);
    }

    fn set(&self, i: usize) -> &[u32] {
        &self.cand_features[self.cand_offsets[i]..self.cand_offsets[i + 1]]
    }

    /// Candidate `i`'s context in state `s`: bit `j` is its `j`-th feature.
    fn context(&self, i: usize, s: usize) -> usize {
        let n_f = self.structure.n_features();
        self.set(i)
            .iter()
            .enumerate()
            .map(|(j, &f)| usize::from(self.has[s * n_f + f as usize]) << j)
            .sum()
    }

    /// Candidate `i`'s effect counts in context `ctx` for `action`.
    fn counts(&self, action: usize, i: usize, ctx: usize) -> &[u32] {
        let n_e = self.structure.n_effects();
        let start = action * self.block + self.count_start[i] + ctx * n_e;
        &self.counts[start..start + n_e]
    }

    /// The G statistic and degrees of freedom for "`q` ⊃ `p` adds information about the
    /// effect", pooled over `p`'s contexts, from `q`'s contexts with at least `m` samples.
    fn refinement(&self, action: usize, p: usize, q: usize, col: &mut [f64]) -> (f64, usize) {
        let (ps, qs) = (self.set(p), self.set(q));
        // Where each of p's features sits in q.
        let mut pos = [0usize; MAX_IN_DEGREE];
        for (j, f) in ps.iter().enumerate() {
            pos[j] = qs.iter().position(|g| g == f).unwrap_or(0);
        }
        let m = u64::from(self.params.m);
        let (mut g, mut df) = (0.0, 0usize);
        for cp in 0..1usize << ps.len() {
            col.fill(0.0);
            let (mut rows, mut n) = (0usize, 0.0);
            let in_cp = |cq: usize| (0..ps.len()).all(|j| (cq >> pos[j]) & 1 == (cp >> j) & 1);
            for cq in (0..1usize << qs.len()).filter(|&cq| in_cp(cq)) {
                let row = self.counts(action, q, cq);
                let total: u64 = row.iter().map(|&c| u64::from(c)).sum();
                if total < m {
                    continue;
                }
                rows += 1;
                n += total as f64;
                for (c, &x) in col.iter_mut().zip(row) {
                    *c += f64::from(x);
                }
            }
            let cols = col.iter().filter(|&&c| c > 0.0).count();
            if rows < 2 || cols < 2 {
                continue;
            }
            df += (rows - 1) * (cols - 1);
            for cq in (0..1usize << qs.len()).filter(|&cq| in_cp(cq)) {
                let row = self.counts(action, q, cq);
                let total: u64 = row.iter().map(|&c| u64::from(c)).sum();
                if total < m {
                    continue;
                }
                for (&x, &c) in row.iter().zip(col.iter()) {
                    if x > 0 {
                        let x = f64::from(x);
                        g += 2.0 * x * (x * n / (total as f64 * c)).ln();
                    }
                }
            }
        }
        (g, df)
    }

    /// Re-selects `action`'s parent set from its counts.
    fn select_structure(&mut self, action: usize) {
        let mut col = std::mem::take(&mut self.scratch);
        let mut p = 0;
        for k in 1..self.size_start.len() - 1 {
            let mut best: Option<(usize, f64)> = None;
            for q in self.size_start[k]..self.size_start[k + 1] {
                let qs = self.set(q);
                if !self.set(p).iter().all(|f| qs.contains(f)) {
                    continue;
                }
                let (g, df) = self.refinement(action, p, q, &mut col);
                if df == 0 {
                    continue;
                }
                let ratio = g / chi2_quantile(self.z[k], df);
                if ratio > 1.0 && best.is_none_or(|(_, r)| ratio > r + 1e-12) {
                    best = Some((q, ratio));
                }
            }
            if let Some((q, _)) = best {
                p = q;
            }
        }
        self.scratch = col;
        self.chosen[action] = p;
    }

    /// Rewrites `action`'s rows of the model and its unknown flags from the chosen parents.
    fn refresh(&mut self, action: usize) {
        let (n_s, p) = (self.structure.n_states(), self.chosen[action]);
        let m = u64::from(self.params.m);
        let mut probs = std::mem::take(&mut self.scratch);
        for s in 0..n_s {
            let ctx = self.context(p, s);
            let row = self.counts(action, p, ctx);
            let total: u64 = row.iter().map(|&c| u64::from(c)).sum();
            let known = total >= m;
            if known {
                for (q, &c) in probs.iter_mut().zip(row) {
                    *q = f64::from(c) / total as f64;
                }
                self.model.set(action, s, &probs);
            }
            if self.unknown[action * n_s + s] == known {
                // Optimism appears or goes, which the model's drift cannot see.
                self.unknown[action * n_s + s] = !known;
                self.model.invalidate();
            }
        }
        self.scratch = probs;
    }
}

impl Agent for LseRmax {
    fn name(&self) -> &str {
        "LSE-Rmax"
    }

    fn act(&mut self, state: usize) -> Result<usize, AgentError> {
        check_step(&self.structure, state, 0, None)?;
        self.replan();
        Ok(self.model.action(state))
    }

    fn observe(&mut self, state: usize, action: usize, effect: usize) -> Result<(), AgentError> {
        check_step(&self.structure, state, action, Some(effect))?;
        let n_e = self.structure.n_effects();
        for i in 0..self.count_start.len() {
            let ctx = self.context(i, state);
            let at = action * self.block + self.count_start[i] + ctx * n_e + effect;
            self.counts[at] = self.counts[at].saturating_add(1);
        }
        self.select_structure(action);
        self.refresh(action);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::agents::rl_dt::tests::{icy_corridor, run};
    use crate::agents::tests::assert_refuses_bad_steps;
    use crate::cmdp::examples::corridor;

    #[test]
    fn statistics_helpers_match_tables() {
        assert!((normal_quantile(0.975) - 1.959_964).abs() < 1e-5);
        assert!((normal_quantile(0.99) - 2.326_348).abs() < 1e-5);
        assert!((normal_quantile(0.001) + 3.090_232).abs() < 1e-5);
        // χ²₀.₉₉: df 1 → 6.635, df 4 → 13.277, df 10 → 23.209 (Wilson–Hilferty is within 1%
        // from df 1 up and closer as df grows).
        let z = normal_quantile(0.99);
        for (df, exact) in [(1, 6.635), (4, 13.277), (10, 23.209)] {
            let rel: f64 = (chi2_quantile(z, df) - exact) / exact;
            assert!(rel.abs() < 0.01, "df {df}: {}", chi2_quantile(z, df));
        }
        assert_eq!(binomial(10, 2), 45);
        assert_eq!(binomial(4, 0), 1);
    }

    #[test]
    fn candidate_sets_are_every_small_subset() {
        let c = Arc::new(icy_corridor(6, &[2]));
        let agent = LseRmax::new(c, LseRmaxParams::default(), 0).unwrap();
        // 4 features: 1 + 4 + 6 sets.
        assert_eq!(agent.count_start.len(), 11);
        assert_eq!(agent.set(0), &[] as &[u32]);
        assert_eq!(agent.set(1), &[0]);
        assert_eq!(agent.set(5), &[0, 1]);
        assert_eq!(agent.set(10), &[2, 3]);
        assert_eq!(agent.context(10, 2), 0b10, "state 2 has feature 3, not 2");
        assert_eq!(agent.parents(0), Some(&[] as &[u32]));
    }

    #[test]
    fn learns_the_task_and_finds_the_relevant_parent() {
        let c = Arc::new(icy_corridor(10, &[3, 6]));
        let mut agent = LseRmax::new(c.clone(), LseRmaxParams::default(), 0).unwrap();
        let returns = run(&mut agent, &c, 5, 120, 11);
        let late = returns[90..].iter().sum::<f64>() / 30.0;
        let parents = agent.parents(1).unwrap();
        assert!(parents.contains(&3), "right's parents {parents:?}");
        let t = agent.effect_table();
        assert!(t.probs(1, 6)[0] > 0.6 && t.probs(1, 4)[0] < 0.1);
        assert!(agent.is_known(6, 1) && agent.is_known(4, 1));
        assert!(late > 0.5, "late mean return {late}");
    }

    #[test]
    fn a_pair_that_matters_only_jointly_is_found() {
        // Feed effects directly: the effect is feature 1 XOR feature 2 (feature 0 is noise).
        let feats: Vec<Vec<u32>> = (0..8u32)
            .map(|s| (0..3).filter(|f| s >> f & 1 == 1).collect())
            .collect();
        let c = Arc::new(
            CmdpStructure::new(
                8,
                1,
                2,
                3,
                |s, _| s,
                vec![0.0; 8],
                vec![false; 8],
                |s| &feats[s],
            )
            .unwrap(),
        );
        let mut agent = LseRmax::new(c, LseRmaxParams::default(), 0).unwrap();
        for round in 0..20 {
            for s in 0..8usize {
                let xor = usize::from((s >> 1 & 1) ^ (s >> 2 & 1) == 1);
                // A little noise so the statistics are not degenerate.
                let e = if (round + s) % 10 == 0 { 1 - xor } else { xor };
                agent.observe(s, 0, e).unwrap();
            }
        }
        assert_eq!(agent.parents(0), Some(&[1u32, 2][..]));
        assert!((0..8).all(|s| agent.is_known(s, 0)));
    }

    #[test]
    fn too_little_evidence_keeps_the_empty_parent_set() {
        let c = Arc::new(corridor(6, &[2]));
        let mut agent = LseRmax::new(c, LseRmaxParams::default(), 0).unwrap();
        for _ in 0..9 {
            agent.observe(2, 1, 0).unwrap();
            agent.observe(3, 1, 1).unwrap();
        }
        // Nine samples in each context: neither is known yet, so no test can run.
        assert_eq!(agent.parents(1), Some(&[] as &[u32]));
        assert!(
            agent.is_known(3, 1),
            "18 samples make the empty context known"
        );
        agent.observe(2, 1, 0).unwrap();
        agent.observe(3, 1, 1).unwrap();
        assert_eq!(agent.parents(1), Some(&[1u32][..]));
        assert_eq!(agent.effect_table().probs(1, 2), &[1.0, 0.0, 0.0]);
        assert_eq!(agent.effect_table().probs(1, 3), &[0.0, 1.0, 0.0]);
    }

    #[test]
    fn bad_steps_and_settings_are_refused() {
        let c = Arc::new(corridor(5, &[]));
        let mut agent = LseRmax::new(c.clone(), LseRmaxParams::default(), 1).unwrap();
        assert_refuses_bad_steps(&mut agent);
        assert!(agent.counts.iter().all(|&n| n == 0));
        let ok = LseRmaxParams::default();
        for bad in [
            LseRmaxParams { m: 0, ..ok },
            LseRmaxParams { sigma: 1.0, ..ok },
            LseRmaxParams { sigma: 0.0, ..ok },
            LseRmaxParams {
                max_in_degree: 4,
                ..ok
            },
        ] {
            assert!(matches!(
                LseRmax::new(c.clone(), bad, 0),
                Err(AgentError::Invalid { .. })
            ));
        }
        assert_eq!(agent.name(), "LSE-Rmax");
    }
}
