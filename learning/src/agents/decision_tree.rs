//! A C4.5/ID3-style classification tree over sparse binary features, the model learner of
//! [`RlDt`](super::RlDt).
//!
//! The tree is induced top-down from weighted examples: at each node the binary feature with
//! the largest *information gain* (entropy of the node's class distribution minus the weighted
//! entropy of its two children, in bits) is chosen; ties go to the lowest feature id, so a fit
//! is deterministic. A node becomes a leaf when
//!
//! * it is pure (one class),
//! * no feature splits it with gain above [`TreeParams::min_gain`],
//! * every split would leave a child with less than [`TreeParams::min_leaf`] examples (C4.5's
//!   "minimum cases per branch"), or
//! * it lies at [`TreeParams::max_depth`].
//!
//! A leaf predicts the class frequencies of the examples that reached it. Unlike C4.5 there is
//! no gain ratio and no pruning (a simplification; the tree is re-induced online instead).
//!
//! Examples carry a weight so that `n` identical examples can be passed as one with weight
//! `n`; the fitted tree is exactly the tree of the expanded list.

use thiserror::Error;

use crate::mdagl::{Features, MdaglError};

/// Tree-induction settings, checked by [`DecisionTree::fit`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TreeParams {
    /// Each child of a split must hold at least this much example weight (≥ 1).
    pub min_leaf: u32,
    /// A split must gain more than this many bits (finite, ≥ 0).
    pub min_gain: f64,
    /// Nodes at this depth are leaves (the root is at depth 0).
    pub max_depth: usize,
}

impl Default for TreeParams {
    /// C4.5's two cases per branch, a 10⁻⁴-bit gain floor (only guards against rounding and
    /// negligible splits), no depth limit.
    fn default() -> Self {
        Self {
            min_leaf: 2,
            min_gain: 1e-4,
            max_depth: usize::MAX,
        }
    }
}

/// Why a tree could not be fitted.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
pub enum TreeError {
    /// Zero classes.
    #[error("a tree needs at least one class")]
    NoClasses,
    /// `min_leaf` is 0 or `min_gain` negative or not finite.
    #[error("tree settings: min_leaf must be >= 1 and min_gain finite and >= 0")]
    BadParams,
    /// An example's class is out of range.
    #[error("example {example} has class {class}, beyond the {classes} classes")]
    BadClass {
        /// Position of the example.
        example: usize,
        /// Its class.
        class: usize,
        /// Number of classes.
        classes: usize,
    },
    /// An example's features are out of range or unsorted.
    #[error("example {example}: {source}")]
    BadFeatures {
        /// Position of the example.
        example: usize,
        /// What is wrong.
        source: MdaglError,
    },
}

/// One training example: the sorted indices of the features that are on, the class, and how
/// many times it was seen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Example<'a> {
    /// Sorted indices of the binary features that are on.
    pub features: &'a [u32],
    /// The class (effect) observed.
    pub class: usize,
    /// How many identical examples this one stands for.
    pub weight: u32,
}

/// A leaf of a [`DecisionTree`], as returned by [`DecisionTree::leaf`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct LeafId(u32);

#[derive(Debug, Clone, PartialEq)]
enum Node {
    /// Class counts at `leaf_counts[slot * C..(slot + 1) * C]`.
    Leaf { slot: u32 },
    /// Examples with `feature` off go to `off`, with it on to `on`.
    Split { feature: u32, off: u32, on: u32 },
}

/// A classification tree over sparse binary features, induced top-down by information gain
/// (ID3/C4.5 style, binary splits, no pruning); a leaf predicts its examples' class
/// frequencies. See [`TreeParams`] for the stopping rules.
///
/// ```
/// use tes_learning::agents::{DecisionTree, Example, TreeParams};
///
/// // Class 1 exactly when feature 2 is on; feature 0 is a bias.
/// let on = [0u32, 2];
/// let off = [0u32];
/// let examples = [
///     Example { features: &on, class: 1, weight: 5 },
///     Example { features: &off, class: 0, weight: 5 },
/// ];
/// let tree = DecisionTree::fit(3, 2, &examples, TreeParams::default())?;
/// assert_eq!(tree.root_split(), Some(2));
/// let mut p = [0.0; 2];
/// tree.predict_into(&on, &mut p);
/// assert_eq!(p, [0.0, 1.0]);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct DecisionTree {
    n_features: usize,
    n_classes: usize,
    /// Node 0 is the root.
    nodes: Vec<Node>,
    leaf_counts: Vec<u64>,
}

/// Scratch space for one induction.
struct Builder<'e, 'a> {
    examples: &'e [Example<'a>],
    params: TreeParams,
    /// `on[f * C + c]`: weight of class `c` among the node's examples with feature `f` on.
    on: Vec<u64>,
    touched: Vec<u32>,
    is_touched: Vec<bool>,
}

/// Entropy in bits of a count vector with the given total.
fn entropy(counts: impl Iterator<Item = u64>, total: u64) -> f64 {
    if total == 0 {
        return 0.0;
    }
    let t = total as f64;
    counts
        .filter(|&c| c > 0)
        .map(|c| {
            let p = c as f64 / t;
            -p * p.log2()
        })
        .sum()
}

impl DecisionTree {
    /// A tree that has seen nothing: one empty leaf, predicting every class equally.
    pub fn empty(n_features: usize, n_classes: usize) -> Self {
        Self {
            n_features,
            n_classes,
            nodes: vec![Node::Leaf { slot: 0 }],
            leaf_counts: vec![0; n_classes],
        }
    }

    /// Induces a tree from `examples` (features below `n_features`, classes below `n_classes`).
    pub fn fit(
        n_features: usize,
        n_classes: usize,
        examples: &[Example<'_>],
        params: TreeParams,
    ) -> Result<Self, TreeError> {
        if n_classes == 0 {
            return Err(TreeError::NoClasses);
        }
        if params.min_leaf == 0 || !(params.min_gain.is_finite() && params.min_gain >= 0.0) {
            return Err(TreeError::BadParams);
        }
        for (example, x) in examples.iter().enumerate() {
            if x.class >= n_classes {
                return Err(TreeError::BadClass {
                    example,
                    class: x.class,
                    classes: n_classes,
                });
            }
            Features::SparseBinary(x.features)
                .validate(n_features)
                .map_err(|source| TreeError::BadFeatures { example, source })?;
        }
        Ok(Self::fit_unchecked(n_features, n_classes, examples, params))
    }

    /// [`fit`](Self::fit) for inputs the caller has already checked.
    pub(crate) fn fit_unchecked(
        n_features: usize,
        n_classes: usize,
        examples: &[Example<'_>],
        params: TreeParams,
    ) -> Self {
        let mut tree = Self {
            n_features,
            n_classes,
            nodes: Vec::new(),
            leaf_counts: Vec::new(),
        };
        let mut builder = Builder {
            examples,
            params,
            on: vec![0; n_features * n_classes],
            touched: Vec::new(),
            is_touched: vec![false; n_features],
        };
        let mut idx: Vec<u32> = (0..examples.len() as u32)
            .filter(|&i| examples[i as usize].weight > 0)
            .collect();
        tree.grow(&mut builder, &mut idx, 0);
        tree
    }

    /// Builds the subtree of the examples `idx` and returns its node id.
    fn grow(&mut self, b: &mut Builder<'_, '_>, idx: &mut [u32], depth: usize) -> u32 {
        let c = self.n_classes;
        let mut totals = vec![0u64; c];
        for &i in idx.iter() {
            let x = &b.examples[i as usize];
            totals[x.class] += u64::from(x.weight);
        }
        let n: u64 = totals.iter().sum();
        let pure = totals.iter().filter(|&&t| t > 0).count() <= 1;
        let split = if pure || depth >= b.params.max_depth {
            None
        } else {
            self.best_split(b, idx, &totals, n)
        };
        let id = self.nodes.len() as u32;
        match split {
            None => {
                let slot = (self.leaf_counts.len() / c) as u32;
                self.leaf_counts.extend_from_slice(&totals);
                self.nodes.push(Node::Leaf { slot });
            }
            Some(feature) => {
                self.nodes.push(Node::Split {
                    feature,
                    off: 0,
                    on: 0,
                });
                // Partition: examples with the feature off first.
                let mut k = 0;
                for j in 0..idx.len() {
                    let has = b.examples[idx[j] as usize]
                        .features
                        .binary_search(&feature)
                        .is_ok();
                    if !has {
                        idx.swap(j, k);
                        k += 1;
                    }
                }
                let (off_idx, on_idx) = idx.split_at_mut(k);
                let off = self.grow(b, off_idx, depth + 1);
                let on = self.grow(b, on_idx, depth + 1);
                self.nodes[id as usize] = Node::Split { feature, off, on };
            }
        }
        id
    }

    /// The feature with the largest information gain over the node's examples, if any split
    /// is allowed and gains more than `min_gain`.
    fn best_split(
        &self,
        b: &mut Builder<'_, '_>,
        idx: &[u32],
        totals: &[u64],
        n: u64,
    ) -> Option<u32> {
        let c = self.n_classes;
        for &i in idx {
            let x = &b.examples[i as usize];
            for &f in x.features {
                if !b.is_touched[f as usize] {
                    b.is_touched[f as usize] = true;
                    b.touched.push(f);
                }
                b.on[f as usize * c + x.class] += u64::from(x.weight);
            }
        }
        b.touched.sort_unstable();
        let h = entropy(totals.iter().copied(), n);
        let nf = n as f64;
        let min_leaf = u64::from(b.params.min_leaf);
        let mut best: Option<(u32, f64)> = None;
        for &f in &b.touched {
            let on = &b.on[f as usize * c..(f as usize + 1) * c];
            let n_on: u64 = on.iter().sum();
            let n_off = n - n_on;
            if n_on < min_leaf || n_off < min_leaf {
                continue;
            }
            let h_on = entropy(on.iter().copied(), n_on);
            let h_off = entropy(totals.iter().zip(on).map(|(t, o)| t - o), n_off);
            let gain = h - (n_on as f64 / nf) * h_on - (n_off as f64 / nf) * h_off;
            if gain > b.params.min_gain && best.is_none_or(|(_, g)| gain > g + 1e-12) {
                best = Some((f, gain));
            }
        }
        for &f in &b.touched {
            b.is_touched[f as usize] = false;
            b.on[f as usize * c..(f as usize + 1) * c].fill(0);
        }
        b.touched.clear();
        best.map(|(f, _)| f)
    }

    /// Number of features the tree reads.
    pub fn n_features(&self) -> usize {
        self.n_features
    }

    /// Number of classes it predicts.
    pub fn n_classes(&self) -> usize {
        self.n_classes
    }

    /// Number of nodes (splits and leaves).
    pub fn n_nodes(&self) -> usize {
        self.nodes.len()
    }

    /// Number of leaves.
    pub fn n_leaves(&self) -> usize {
        self.leaf_counts.len() / self.n_classes.max(1)
    }

    /// The feature the root splits on, or `None` if the tree is a single leaf.
    pub fn root_split(&self) -> Option<u32> {
        match self.nodes[0] {
            Node::Split { feature, .. } => Some(feature),
            Node::Leaf { .. } => None,
        }
    }

    /// Every feature some node splits on, sorted and without repeats.
    pub fn split_features(&self) -> Vec<u32> {
        let mut f: Vec<u32> = self
            .nodes
            .iter()
            .filter_map(|n| match *n {
                Node::Split { feature, .. } => Some(feature),
                Node::Leaf { .. } => None,
            })
            .collect();
        f.sort_unstable();
        f.dedup();
        f
    }

    /// The leaf that the sorted on-features `x` reach.
    pub fn leaf(&self, x: &[u32]) -> LeafId {
        let mut node = 0usize;
        loop {
            match self.nodes[node] {
                Node::Leaf { slot } => return LeafId(slot),
                Node::Split { feature, off, on } => {
                    node = if x.binary_search(&feature).is_ok() {
                        on as usize
                    } else {
                        off as usize
                    };
                }
            }
        }
    }

    /// The class weights of the examples in `leaf`.
    pub fn leaf_counts(&self, leaf: LeafId) -> &[u64] {
        let c = self.n_classes;
        &self.leaf_counts[leaf.0 as usize * c..(leaf.0 as usize + 1) * c]
    }

    /// The most frequent class in `leaf` (lowest id on ties), or `None` if it is empty.
    pub fn majority(&self, leaf: LeafId) -> Option<usize> {
        let counts = self.leaf_counts(leaf);
        let (class, &n) = counts
            .iter()
            .enumerate()
            .max_by(|(i, a), (j, b)| a.cmp(b).then(j.cmp(i)))?;
        (n > 0).then_some(class)
    }

    /// Adds one example of `class` to `leaf` without re-inducing the tree.
    pub(crate) fn add_to_leaf(&mut self, leaf: LeafId, class: usize) {
        self.leaf_counts[leaf.0 as usize * self.n_classes + class] += 1;
    }

    /// The class distribution for the sorted on-features `x`: the frequencies in its leaf, or
    /// uniform for an empty leaf. `out` must hold one value per class.
    pub fn predict_into(&self, x: &[u32], out: &mut [f64]) {
        let counts = self.leaf_counts(self.leaf(x));
        let total: u64 = counts.iter().sum();
        if total == 0 {
            out.fill(1.0 / self.n_classes as f64);
        } else {
            for (p, &n) in out.iter_mut().zip(counts) {
                *p = n as f64 / total as f64;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ex(features: &[u32], class: usize, weight: u32) -> Example<'_> {
        Example {
            features,
            class,
            weight,
        }
    }

    #[test]
    fn pure_data_is_a_single_leaf() {
        let a = [0u32, 3];
        let b = [1u32];
        let data = [ex(&a, 2, 4), ex(&b, 2, 7), ex(&[], 2, 1)];
        let tree = DecisionTree::fit(4, 3, &data, TreeParams::default()).unwrap();
        assert_eq!(tree.n_nodes(), 1);
        assert_eq!(tree.root_split(), None);
        let mut p = [0.0; 3];
        tree.predict_into(&b, &mut p);
        assert_eq!(p, [0.0, 0.0, 1.0]);
        assert_eq!(tree.majority(tree.leaf(&a)), Some(2));
    }

    #[test]
    fn a_one_feature_rule_splits_on_that_feature() {
        // Class = feature 2, with features 0 (bias), 1 and 3 (noise) mixed in.
        let rows: Vec<Vec<u32>> = (0..16u32)
            .map(|i| {
                let mut x = vec![0];
                for f in 1..4 {
                    if i >> (f - 1) & 1 == 1 {
                        x.push(f);
                    }
                }
                x
            })
            .collect();
        let data: Vec<Example<'_>> = rows
            .iter()
            .map(|x| ex(x, usize::from(x.contains(&2)), 3))
            .collect();
        let tree = DecisionTree::fit(4, 2, &data, TreeParams::default()).unwrap();
        assert_eq!(tree.root_split(), Some(2));
        assert_eq!(tree.split_features(), vec![2]);
        assert_eq!(tree.n_leaves(), 2);
        let mut p = [0.0; 2];
        tree.predict_into(&[0, 2], &mut p);
        assert_eq!(p, [0.0, 1.0]);
        tree.predict_into(&[0, 1, 3], &mut p);
        assert_eq!(p, [1.0, 0.0]);
    }

    #[test]
    fn noisy_rule_keeps_frequencies_and_stopping_rules_hold() {
        let on = [1u32];
        let off: [u32; 0] = [];
        // Feature 1 on: class 0 w.p. 0.75; off: class 1 always.
        let data = [ex(&on, 0, 3), ex(&on, 1, 1), ex(&off, 1, 4)];
        let tree = DecisionTree::fit(2, 2, &data, TreeParams::default()).unwrap();
        assert_eq!(tree.root_split(), Some(1));
        let mut p = [0.0; 2];
        tree.predict_into(&on, &mut p);
        assert_eq!(p, [0.75, 0.25]);
        // Too few examples per branch: no split.
        let strict = TreeParams {
            min_leaf: 5,
            ..TreeParams::default()
        };
        assert_eq!(DecisionTree::fit(2, 2, &data, strict).unwrap().n_nodes(), 1);
        let stump = TreeParams {
            max_depth: 0,
            ..TreeParams::default()
        };
        let leaf = DecisionTree::fit(2, 2, &data, stump).unwrap();
        leaf.predict_into(&on, &mut p);
        assert_eq!(p, [0.375, 0.625]);
    }

    #[test]
    fn weights_equal_repeated_examples_and_fits_are_deterministic() {
        let xs: [&[u32]; 4] = [&[0, 1], &[1], &[0], &[2]];
        let weighted = [
            ex(xs[0], 0, 3),
            ex(xs[1], 1, 2),
            ex(xs[2], 0, 1),
            ex(xs[3], 1, 2),
        ];
        let mut expanded = Vec::new();
        for e in &weighted {
            for _ in 0..e.weight {
                expanded.push(ex(e.features, e.class, 1));
            }
        }
        let a = DecisionTree::fit(3, 2, &weighted, TreeParams::default()).unwrap();
        let b = DecisionTree::fit(3, 2, &expanded, TreeParams::default()).unwrap();
        let c = DecisionTree::fit(3, 2, &weighted, TreeParams::default()).unwrap();
        assert_eq!(a, b);
        assert_eq!(a, c);
    }

    #[test]
    fn empty_trees_predict_uniformly_and_bad_input_is_refused() {
        let t = DecisionTree::empty(2, 4);
        let mut p = [0.0; 4];
        t.predict_into(&[1], &mut p);
        assert_eq!(p, [0.25; 4]);
        assert_eq!(t.majority(t.leaf(&[])), None);
        let x = [5u32];
        assert!(matches!(
            DecisionTree::fit(2, 2, &[ex(&x, 0, 1)], TreeParams::default()),
            Err(TreeError::BadFeatures { example: 0, .. })
        ));
        assert!(matches!(
            DecisionTree::fit(2, 2, &[ex(&[], 2, 1)], TreeParams::default()),
            Err(TreeError::BadClass { class: 2, .. })
        ));
        assert_eq!(
            DecisionTree::fit(2, 0, &[], TreeParams::default()),
            Err(TreeError::NoClasses)
        );
        let bad = TreeParams {
            min_gain: f64::NAN,
            ..TreeParams::default()
        };
        assert_eq!(DecisionTree::fit(2, 2, &[], bad), Err(TreeError::BadParams));
    }
}
