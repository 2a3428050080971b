//! The preregistration: every target of the study in one place — the paper's sentence it
//! tests, our target as worded in the verdict tables, the test that judges it and its
//! threshold — with its history. A target changed after results existed keeps each earlier
//! form ([`Revision`]) beside the current one, with the commit at which results existed, the
//! verdict it had then and why it changed. A world or default that changed after a result
//! ([`WorldChange`]) is recorded the same way, with the verdict the result had before.
//!
//! Each target's form and each world's definition have a fingerprint (FNV-1a over their
//! words and numbers, or over a world's layout and a seeded walk through it), and the registry
//! holds the ledger of fingerprints each has had. The tests below fail when a target's
//! threshold, test or words, or a world's definition, no longer match the ledger's last entry:
//! changing one means recording the change here (the earlier form, the commit, why), then
//! appending the new fingerprint.
//!
//! `registered` says whether a target was written before any result existed or with results
//! in hand — many were, and the report says so beside their verdicts
//! (`tes experiment report DIR --table claims` prints each folder's full set).

/// A target's threshold: what the test's outcome is compared with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Threshold {
    /// The test must decide for the claim (two-sided 5 %, Holm over the claim's comparisons).
    Decided,
    /// At least this many of the 15 tasks decided ahead.
    Count(usize),
    /// A's reward at least this share of B's (the test: A − share × B decided ahead).
    Share(f64),
    /// A ratio's 95 % interval at or below this.
    AtMost(f64),
    /// A ratio's 95 % interval at or above this.
    AtLeast(f64),
}

impl Threshold {
    /// The count of a [`Threshold::Count`] (0 for any other).
    pub const fn count(self) -> usize {
        match self {
            Threshold::Count(n) => n,
            _ => 0,
        }
    }

    /// The number of a share or bound (NaN for a count or a decided test).
    pub const fn value(self) -> f64 {
        match self {
            Threshold::Share(x) | Threshold::AtMost(x) | Threshold::AtLeast(x) => x,
            _ => f64::NAN,
        }
    }

    /// In words, e.g. "≥ 8 of 15", "≤ 2.5", "share 0.9".
    pub fn text(self) -> String {
        match self {
            Threshold::Decided => "decided for the claim at 5 %".to_owned(),
            Threshold::Count(n) => format!(">= {n} of 15 tasks"),
            Threshold::Share(x) => format!("share {x}"),
            Threshold::AtMost(x) => format!("<= {x}"),
            Threshold::AtLeast(x) => format!(">= {x}"),
        }
    }
}

/// When a target was written.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Registered {
    /// Before any full result it judges existed.
    BeforeData,
    /// With results in hand, at this commit: its threshold may have been chosen knowing the
    /// data, which the report says beside its verdict.
    WithData {
        /// The commit that wrote it.
        at: &'static str,
    },
}

/// An earlier form of a target, replaced after results existed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Revision {
    /// The target's earlier words.
    pub target: &'static str,
    /// Its earlier test.
    pub test: &'static str,
    /// Its earlier threshold.
    pub threshold: Threshold,
    /// The commit at which results judged by it existed.
    pub results_at: &'static str,
    /// The verdicts it had then.
    pub verdict_then: &'static str,
    /// Why it was changed.
    pub why: &'static str,
}

/// One target of the study.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Target {
    /// A stable name, e.g. "grid.fig3b.share-of-fepsg".
    pub id: &'static str,
    /// The experiment whose folders it judges ("grid", "transfer", "robot", "fig4",
    /// "lifelong").
    pub experiment: &'static str,
    /// The paper's sentence (or table) it tests, with where it stands; "ours" for a target
    /// beyond the paper.
    pub paper: &'static str,
    /// Our target, as worded in the verdict tables.
    pub target: &'static str,
    /// The test that judges it.
    pub test: &'static str,
    /// Its threshold.
    pub threshold: Threshold,
    /// When it was written.
    pub registered: Registered,
    /// Its earlier forms, oldest first.
    pub history: &'static [Revision],
    /// The ledger: the fingerprint of each earlier form in order, then the current one's.
    pub fingerprints: &'static [&'static str],
}

impl Target {
    /// Whether it is judged on times, which move with the machine's load: a time ratio's
    /// interval (§5.1.2's ratio of mean times over the tasks among them).
    pub fn on_times(&self) -> bool {
        self.test == RATIO_TEST || self.id == TRANSFER_TIME.id
    }

    /// The fingerprint of the current form.
    pub fn fingerprint(&self) -> String {
        form_fingerprint(self.id, self.target, self.test, self.threshold)
    }
}

/// The fingerprint of one form of target `id`.
pub fn form_fingerprint(id: &str, target: &str, test: &str, threshold: Threshold) -> String {
    fingerprint(&format!("{id}\n{target}\n{test}\n{threshold:?}"))
}

/// FNV-1a (64 bits) of `text`, in hex: stable across builds and platforms, unlike the
/// standard library's hasher.
pub fn fingerprint(text: &str) -> String {
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for byte in text.bytes() {
        hash ^= u64::from(byte);
        hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{hash:016x}")
}

/// A change to a world or default made after a result existed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldChange {
    /// What changed, before → after.
    pub what: &'static str,
    /// The commit that changed it.
    pub changed_in: &'static str,
    /// The commit at which the earlier result existed.
    pub results_at: &'static str,
    /// The verdict the result had before the change.
    pub verdict_before: &'static str,
    /// The verdict after it.
    pub verdict_after: &'static str,
    /// Why it changed.
    pub why: &'static str,
    /// The world's fingerprint before the change, for a change made since the registry
    /// exists (`None` for one made before: its earlier definition cannot be rebuilt).
    pub fingerprint_before: Option<&'static str>,
}

/// A world or default whose definition the results depend on.
pub struct World {
    /// A stable name.
    pub id: &'static str,
    /// What it is.
    pub describes: &'static str,
    /// Its definition, as the text its fingerprint is taken over.
    pub definition: fn() -> String,
    /// Its changes after results existed, oldest first.
    pub changes: &'static [WorldChange],
    /// The ledger: each fingerprint it has had since registration, the current last.
    pub fingerprints: &'static [&'static str],
}

impl World {
    /// The fingerprint of the current definition.
    pub fn fingerprint(&self) -> String {
        fingerprint(&(self.definition)())
    }
}

const HOLM_TEST: &str =
    "paired t-tests over runs, Holm's correction over the comparisons, family-wise 5 %";
const RATIO_TEST: &str = crate::verdict::TIME_RATIO_TEST;
const COUNT_TEST: &str = crate::verdict::PER_TASK_TEST;
const POOLED_TEST: &str = "Wilcoxon signed-rank over the 15 tasks' mean differences, two-sided 5 % (tasks share training prefixes: a run-level sign-flip test is reported beside it)";
const TASK_TARGETS_AT: Registered = Registered::WithData { at: "3b00f99" };
const CLAIMS_AT: Registered = Registered::WithData {
    at: "registered from the committed folders of 1cde447",
};

/// Fig. 3b: loreRL does not lose much to fEpsG.
pub const GRID_SHARE_OF_FEPSG: Target = Target {
    id: "grid.fig3b.share-of-fepsg",
    experiment: "grid",
    paper: "§5.1.1, Fig. 3b–c: \"loreRL ... still gain nearly as high accumulated rewards as fEpsG\"; \"loreRL does not lose much to fEpsG either\"",
    target: "200 irrelevant features: loreRL's accumulated reward >= 90 % of fEpsG's",
    test: "paired t-test over runs of loreRL − 0.9 × fEpsG, two-sided 5 %",
    threshold: Threshold::Share(0.9),
    registered: Registered::BeforeData,
    history: &[],
    fingerprints: &["68fe0c661de34edc"],
};

/// Fig. 3b: loreRL outperforms bloreRL and fRmax.
pub const GRID_ABOVE_BLORE_FRMAX: Target = Target {
    id: "grid.fig3b.above-blorerl-frmax",
    experiment: "grid",
    paper: "§5.1.1: \"loreRL ... outperforms fRmax and bloreRL\"",
    target: "200 irrelevant features: loreRL's accumulated reward above bloreRL's and fRmax's",
    test: "paired t-tests over runs, Holm's correction over the two, family-wise 5 %",
    threshold: Threshold::Decided,
    registered: Registered::BeforeData,
    history: &[],
    fingerprints: &["ffaba68feabddce4"],
};

/// Table 1: loreRL / fEpsG.
pub const TABLE1_LORE_OVER_FEPSG: Target = Target {
    id: "grid.table1.lorerl-over-fepsg",
    experiment: "grid",
    paper: "Table 1 (fEpsG 0.25 s, loreRL 0.55 s: 2.2); §5.1.1 \"loreRL's running time is also not much longer than fRmax's or fEpsG's\"",
    target: "Table 1: loreRL / fEpsG time per episode <= 2.5 (paper: 2.2)",
    test: RATIO_TEST,
    threshold: Threshold::AtMost(2.5),
    registered: Registered::BeforeData,
    history: &[],
    fingerprints: &["04618cecb7aa5f9a"],
};

/// Table 1: RL-DT / loreRL.
pub const TABLE1_RLDT_OVER_LORE: Target = Target {
    id: "grid.table1.rldt-over-lorerl",
    experiment: "grid",
    paper: "Table 1 (RL-DT 9.09 s, loreRL 0.55 s: 16.5); §5.1.1 \"Other methods are too slow to run in this high-dimensional environment\"",
    target: "Table 1: RL-DT / loreRL time per episode >= 10 (paper: 16.5)",
    test: RATIO_TEST,
    threshold: Threshold::AtLeast(10.0),
    registered: Registered::BeforeData,
    history: &[],
    fingerprints: &["7a31ae2742d95cc3"],
};

/// Table 2: jumpstart against loreRL, per task.
pub const TABLE2_JUMPSTART_LORE: Target = Target {
    id: "transfer.table2.jumpstart-lorerl.count",
    experiment: "transfer",
    paper: "§5.1.3, Table 2: \"TES usually outperforms both the non-transfer and the LWT approach\" (TES above loreRL on 14 of 15 tasks)",
    target: "Table 2 (paper: 14 of 15): TES's jumpstart ahead of loreRL's on >= 12 of 15 tasks",
    test: COUNT_TEST,
    threshold: Threshold::Count(12),
    registered: Registered::BeforeData,
    history: &[],
    fingerprints: &["30ea01174568f64d"],
};

/// Table 2: jumpstart against LWT, per task.
pub const TABLE2_JUMPSTART_LWT: Target = Target {
    id: "transfer.table2.jumpstart-lwt.count",
    experiment: "transfer",
    paper: "§5.1.3, Table 2: \"TES usually outperforms both the non-transfer and the LWT approach\" (TES above LWT on 12 of 15 tasks)",
    target: "Table 2 (paper: 12 of 15): TES's jumpstart ahead of LWT's on >= 10 of 15 tasks",
    test: COUNT_TEST,
    threshold: Threshold::Count(10),
    registered: Registered::BeforeData,
    history: &[],
    fingerprints: &["6b05425347b83187"],
};

/// Fig. 4b: accumulated reward against loreRL, per task.
pub const FIG4B_ACCUMULATED_LORE: Target = Target {
    id: "transfer.fig4b.accumulated-lorerl.count",
    experiment: "transfer",
    paper: "§5.1.2, Fig. 4b: \"TES achieves higher accumulated rewards than loreRL and fEpsG\" (no count given)",
    target: "Fig. 4b, §5.1.2 (paper: no count): TES's accumulated reward ahead of loreRL's on >= 8 of 15 tasks",
    test: COUNT_TEST,
    threshold: Threshold::Count(8),
    registered: TASK_TARGETS_AT,
    history: &[],
    fingerprints: &["f15dd0ea4fb08901"],
};

/// Fig. 4b: accumulated reward against fEpsG, per task.
pub const FIG4B_ACCUMULATED_FEPSG: Target = Target {
    id: "transfer.fig4b.accumulated-fepsg.count",
    experiment: "transfer",
    paper: "§5.1.2, Fig. 4b: \"TES achieves higher accumulated rewards than loreRL and fEpsG\" (no count given)",
    target: "Fig. 4b, §5.1.2 (paper: no count): TES's accumulated reward ahead of fEpsG's on >= 8 of 15 tasks",
    test: COUNT_TEST,
    threshold: Threshold::Count(8),
    registered: TASK_TARGETS_AT,
    history: &[],
    fingerprints: &["fc9f7d57ff8fe00d"],
};

/// The pooled form of the four transfer claims.
pub const TRANSFER_POOLED: Target = Target {
    id: "transfer.pooled",
    experiment: "transfer",
    paper: "Table 2 and Fig. 4b, as above, across tasks",
    target: "across tasks, TES's jumpstart (accumulated reward) beats loreRL's, LWT's (loreRL's, fEpsG's)",
    test: POOLED_TEST,
    threshold: Threshold::Decided,
    registered: TASK_TARGETS_AT,
    history: &[],
    fingerprints: &["a32e75095c5b890d"],
};

/// Fig. 9 and §5.2.3: the ordering of the transfer methods on Env 3.
pub const FIG9_TES_AHEAD: Target = Target {
    id: "robot.fig9.tes-ahead",
    experiment: "robot",
    paper: "§5.2.3, Fig. 9: TES accumulates more than TES-woRi, loreRL and LWT",
    target: "Fig. 9: TES accumulates more than TES-woRi, loreRL and LWT (every difference to TES below 0)",
    test: HOLM_TEST,
    threshold: Threshold::Decided,
    registered: TASK_TARGETS_AT,
    history: &[Revision {
        target: "robot, Fig. 8: TES ≥ TES-woRi ≥ loreRL > LWT",
        test: "the means' order, with each difference's 95 % interval",
        threshold: Threshold::Decided,
        results_at: "52af216",
        verdict_then: "20 runs: holds (40.8 ≥ 39.3 ≥ 38.0 > 29.2); 100 runs: fails (TES-woRi − loreRL −1.33 [−3.39, +0.73] on the means)",
        why: "it asked TES-woRi ≥ loreRL, which the paper does not claim (§5.2.3: \"TES-woRi loses to loreRL but not to a large extent\"); split into the four targets of §5.2.3 the paper states",
    }],
    fingerprints: &["96759ad9218b25ff", "4decc16f2fb45576"],
};

/// §5.2.3: LWT least.
pub const ROBOT_LWT_LEAST: Target = Target {
    id: "robot.lwt-least",
    experiment: "robot",
    paper: "§5.2.3: LWT, whose Env 2 views transfer negatively, accumulates least",
    target: "§5.2.3: LWT accumulates least (below loreRL and TES-woRi)",
    test: HOLM_TEST,
    threshold: Threshold::Decided,
    registered: TASK_TARGETS_AT,
    history: &[],
    fingerprints: &["a5d5767e181dca0e"],
};

/// §5.2.3: TES-woRi loses to loreRL.
pub const ROBOT_WORI_LOSES: Target = Target {
    id: "robot.wori-loses",
    experiment: "robot",
    paper: "§5.2.3: \"We see that TES-woRi loses to loreRL\"",
    target: "§5.2.3: TES-woRi loses to loreRL",
    test: "paired t-test over runs of loreRL − TES-woRi, two-sided 5 %",
    threshold: Threshold::Decided,
    registered: TASK_TARGETS_AT,
    history: &[],
    fingerprints: &["fd7462936abeec52"],
};

/// §5.2.3: ... but not by much.
pub const ROBOT_WORI_NOT_BY_MUCH: Target = Target {
    id: "robot.wori-not-by-much",
    experiment: "robot",
    paper: "§5.2.3: \"... but not to a large extent\"",
    target: "§5.2.3: ... but not to a large extent (ours: by less than 10 % of loreRL's accumulated reward)",
    test: "paired t-test over runs of TES-woRi − 0.9 × loreRL, two-sided 5 %",
    threshold: Threshold::Share(0.9),
    registered: TASK_TARGETS_AT,
    history: &[],
    fingerprints: &["91a2464b00c89db0"],
};

/// Table 5: first-episode wins.
pub const TABLE5_FIRST_EPISODE: Target = Target {
    id: "robot.table5.first-episode",
    experiment: "robot",
    paper: "§5.2.3, Table 5: \"TES methods still perform better than the others in the majority of the runs\" (the paper: not significant over 10 repeats)",
    target: "Table 5: TES's first-episode reward beats loreRL's, LWT's and TES-woRi's",
    test: "sign test over runs (draws left out), Holm's correction over the three, family-wise 5 %",
    threshold: Threshold::Decided,
    registered: TASK_TARGETS_AT,
    history: &[],
    fingerprints: &["f2b6d61199286de7"],
};

/// Table 3: loreRL / man-loreRL time.
pub const TABLE3_LORE_OVER_MAN: Target = Target {
    id: "robot.table3.lorerl-over-man",
    experiment: "robot",
    paper: "§5.2.2, Table 3: loreRL's time per episode \"only slightly slower than man-loreRL\" (1.16)",
    target: "Table 3: loreRL's time per episode only slightly above man-loreRL's (ours: at most 1.5 times; paper 1.16)",
    test: RATIO_TEST,
    threshold: Threshold::AtMost(1.5),
    registered: Registered::BeforeData,
    history: &[],
    fingerprints: &["3fe0fbf9bbf74182"],
};

/// Fig. 4a and 4c: the four targets of the fig4 experiment (their tests in fig4.rs).
pub const FIG4_TARGETS: Target = Target {
    id: "fig4.targets",
    experiment: "fig4",
    paper: "§5.1.2 Fig. 4a (\"these oracle methods ... gain lower accumulated rewards than TES\"; \"loreRL and fEpsG are more effective than fRmax in early episodes\"), §5.1.4 Fig. 4c (TES ahead of fRmax and Rmax early; they catch up)",
    target: "Fig. 4a: TES above loreRL, fRmax, fEpsG over 50 episodes; loreRL and fEpsG above fRmax over the first 10; Fig. 4c: TES above fRmax and Rmax over the first 50; its lead over the last 100 of 500 smaller than over the first 50",
    test: HOLM_TEST,
    threshold: Threshold::Decided,
    registered: TASK_TARGETS_AT,
    history: &[],
    fingerprints: &["35fbbe1bc9df4cb2"],
};

/// The lifelong benchmark's targets (beyond the paper; their tests in lifelong.rs).
pub const LIFELONG_TARGETS: Target = Target {
    id: "lifelong.targets",
    experiment: "lifelong",
    paper: "ours (beyond the paper)",
    target: "TES above loreRL and LWT over the sequence; its lead larger on return visits; the unbounded library above M = 20, also after long gaps; TES above loreRL on logistic and on table worlds; the bounded library cheaper",
    test: "paired t-tests over runs, two-sided 5 %; the time ratio's 95 % interval <= 1",
    threshold: Threshold::AtMost(1.0),
    registered: Registered::BeforeData,
    history: &[],
    fingerprints: &["18bf98008b03e97c"],
};

/// The lifelong benchmark's ablation and continual baseline (beyond the paper; their tests
/// in lifelong.rs), written before any run of them.
pub const LIFELONG_ABLATIONS: Target = Target {
    id: "lifelong.ablations",
    experiment: "lifelong",
    paper: "ours (beyond the paper); §4.3's recency weight μ, which the paper's experiments set to 0",
    target: "TES with recency μ = 0.1 above μ = 0 over the sequence; TES above loreRL-continual (one mDAGL model per action learning through the whole sequence); loreRL-continual above a fresh loreRL on every task",
    test: "paired t-tests over runs, two-sided 5 %",
    threshold: Threshold::Decided,
    registered: Registered::BeforeData,
    history: &[],
    fingerprints: &["773b74f8228c6830"],
};

/// Fig. 3a: loreRL converges as fast as fEpsG and RL-DT.
pub const FIG3A_AS_FAST: Target = Target {
    id: "grid.fig3a.as-fast",
    experiment: "grid",
    paper: "§5.1.1, Fig. 3a: \"loreRL ... converges as fast as fEpsG, and RL-DT to near optimal policy\"",
    target: "Fig. 3a (10 features): loreRL's accumulated reward >= 95 % of fEpsG's and of RL-DT's (accumulated reward as the area under the learning curve)",
    test: "paired t-tests over runs of loreRL − 0.95 × X, Holm over the two, decided ahead",
    threshold: Threshold::Share(0.95),
    registered: CLAIMS_AT,
    history: &[],
    fingerprints: &["d68768b73b1d8475"],
};

/// Fig. 3a: fRmax lower than loreRL.
pub const FIG3A_FRMAX_LOWER: Target = Target {
    id: "grid.fig3a.frmax-lower",
    experiment: "grid",
    paper: "§5.1.1, Fig. 3a: \"fRmax ... its accumulated rewards are lower due to aggressive exploration\"",
    target: "Fig. 3a (10 features): fRmax's accumulated reward below loreRL's",
    test: "paired t-test over runs of loreRL − fRmax, two-sided 5 %",
    threshold: Threshold::Decided,
    registered: CLAIMS_AT,
    history: &[],
    fingerprints: &["5ae2d6eca8160f39"],
};

/// Fig. 3a: LSE-Rmax below fRmax.
pub const FIG3A_LSE_BELOW_FRMAX: Target = Target {
    id: "grid.fig3a.lse-below-frmax",
    experiment: "grid",
    paper: "§5.1.1, Fig. 3a: \"[LSE-Rmax's] accumulated reward drops below fRmax after 150 episodes\"",
    target: "Fig. 3a (10 features): LSE-Rmax's accumulated reward after 800 episodes below fRmax's",
    test: "paired t-test over runs of fRmax − LSE-Rmax, two-sided 5 %",
    threshold: Threshold::Decided,
    registered: CLAIMS_AT,
    history: &[],
    fingerprints: &["c54dee4cdb9a195c"],
};

/// Fig. 3c: insensitive to irrelevant features, and above bloreRL at every level.
pub const FIG3C_INSENSITIVE: Target = Target {
    id: "grid.fig3c.insensitive",
    experiment: "grid",
    paper: "§5.1.1, Fig. 3c: \"Only minimally affected by the actual number of irrelevant features, loreRL can quickly select the relevant features and outperform bloreRL\"",
    target: "Fig. 3c: loreRL's accumulated reward with 200 irrelevant features >= 95 % of its reward with none, and above bloreRL's at 50, 100, 150 and 200",
    test: "paired t-tests over runs (run i of each level shares its seed), Holm over the five, family-wise 5 %",
    threshold: Threshold::Share(0.95),
    registered: CLAIMS_AT,
    history: &[],
    fingerprints: &["919b960785583133"],
};

/// Table 1: loreRL / fRmax.
pub const TABLE1_LORE_OVER_FRMAX: Target = Target {
    id: "grid.table1.lorerl-over-frmax",
    experiment: "grid",
    paper: "Table 1 (fRmax 0.26 s, loreRL 0.55 s: 2.1); \"loreRL's running time is also not much longer than fRmax's\"",
    target: "Table 1: loreRL / fRmax time per episode <= 2.5 (paper: 2.1)",
    test: RATIO_TEST,
    threshold: Threshold::AtMost(2.5),
    registered: CLAIMS_AT,
    history: &[],
    fingerprints: &["485daf78f6e4d553"],
};

/// Table 1: LSE-Rmax / loreRL.
pub const TABLE1_LSE_OVER_LORE: Target = Target {
    id: "grid.table1.lse-over-lorerl",
    experiment: "grid",
    paper: "Table 1 (LSE-Rmax 67.53 s, loreRL 0.55 s: 123); \"the algorithm is computationally very demanding\"",
    target: "Table 1: LSE-Rmax / loreRL time per episode >= 10 (paper: 123)",
    test: RATIO_TEST,
    threshold: Threshold::AtLeast(10.0),
    registered: CLAIMS_AT,
    history: &[],
    fingerprints: &["d64a376644f92b53"],
};

/// Table 1: bloreRL / loreRL.
pub const TABLE1_BLORE_OVER_LORE: Target = Target {
    id: "grid.table1.blorerl-over-lorerl",
    experiment: "grid",
    paper: "Table 1 (bloreRL 4.3 s, loreRL 0.55 s: 7.8); \"loreRL, through selecting a small set of features, runs much faster than bloreRL\"",
    target: "Table 1: bloreRL / loreRL time per episode >= 2 (paper: 7.8)",
    test: RATIO_TEST,
    threshold: Threshold::AtLeast(2.0),
    registered: CLAIMS_AT,
    history: &[],
    fingerprints: &["03e35b720bc0fdeb"],
};

/// Fig. 4b: Rands.
pub const FIG4B_RANDS: Target = Target {
    id: "transfer.fig4b.rands",
    experiment: "transfer",
    paper: "§5.1.2, Fig. 4b: \"our view selection criterion outperforms random selection\"",
    target: "Fig. 4b: across tasks, TES's accumulated reward beats each of the 5 random view combinations' (Rands)",
    test: "per Rands, the pooled Wilcoxon over the tasks' mean differences, Holm over the five, family-wise 5 %",
    threshold: Threshold::Decided,
    registered: CLAIMS_AT,
    history: &[],
    fingerprints: &["6b5244414135258c"],
};

/// Fig. 4b: TES above LWT, LWT below loreRL.
pub const FIG4B_LWT: Target = Target {
    id: "transfer.fig4b.lwt",
    experiment: "transfer",
    paper: "§5.1.2, Fig. 4b: \"TES outperforms LWT which, due to differences in the tasks, also performs worse than loreRL\"",
    target: "Fig. 4b: across tasks, TES's accumulated reward beats LWT's, and LWT's is below loreRL's",
    test: "the pooled Wilcoxon over the tasks' mean differences, Holm over the two, family-wise 5 %",
    threshold: Threshold::Decided,
    registered: CLAIMS_AT,
    history: &[],
    fingerprints: &["bd54e39d6c4f5c80"],
};

/// §5.1.2: TES's time only slightly above LWT's and loreRL's.
pub const TRANSFER_TIME: Target = Target {
    id: "transfer.time",
    experiment: "transfer",
    paper: "§5.1.2: \"TES running time is just slightly longer than LWT's and loreRL's\"",
    target: "§5.1.2: TES's time per test episode <= 1.5 × loreRL's and <= 1.5 × LWT's",
    test: "the per-run ratio of mean times over the tasks, its 95 % interval against the bound",
    threshold: Threshold::AtMost(1.5),
    registered: CLAIMS_AT,
    history: &[],
    fingerprints: &["367e47b065b692ca"],
};

/// Fig. 8: loreRL outperforms the other single-environment learners.
pub const FIG8_LORE_AHEAD: Target = Target {
    id: "robot.fig8.lorerl-ahead",
    experiment: "robot",
    paper: "§5.2.2, Fig. 8: \"loreRL appears to quickly capture the environment dynamics and outperform the other methods\"",
    target: "Fig. 8: loreRL accumulates more than fRmax, fEpsG and man-loreRL over 50 episodes",
    test: HOLM_TEST,
    threshold: Threshold::Decided,
    registered: CLAIMS_AT,
    history: &[],
    fingerprints: &["5797dfd1614a5d37"],
};

/// Fig. 8: man-loreRL faster early, behind in the end.
pub const FIG8_MAN_LORE: Target = Target {
    id: "robot.fig8.man-lorerl",
    experiment: "robot",
    paper: "§5.2.2, Fig. 8: \"man-loreRL gains the rewards a bit faster, but in the end it loses to loreRL slightly\"",
    target: "Fig. 8: man-loreRL accumulates more than loreRL over the first 10 episodes, and less over all 50",
    test: HOLM_TEST,
    threshold: Threshold::Decided,
    registered: CLAIMS_AT,
    history: &[],
    fingerprints: &["f4a3ca37e10976bf"],
};

/// Table 6: TES and TES-woRi faster than loreRL; LWT fastest.
pub const TABLE6_TIMES: Target = Target {
    id: "robot.table6.times",
    experiment: "robot",
    paper: "§5.2.3, Table 6: TES and TES-woRi are \"not much slower than LWT, and even faster than loreRL\"; LWT has the shortest running time",
    target: "Table 6: TES / loreRL and TES-woRi / loreRL time per episode <= 1, and LWT / TES <= 1",
    test: RATIO_TEST,
    threshold: Threshold::AtMost(1.0),
    registered: CLAIMS_AT,
    history: &[],
    fingerprints: &["d19628b4966e96f2"],
};

/// Every target, in the order the results page lists them.
pub const TARGETS: [&Target; 31] = [
    &GRID_SHARE_OF_FEPSG,
    &GRID_ABOVE_BLORE_FRMAX,
    &TABLE1_LORE_OVER_FEPSG,
    &TABLE1_RLDT_OVER_LORE,
    &FIG3A_AS_FAST,
    &FIG3A_FRMAX_LOWER,
    &FIG3A_LSE_BELOW_FRMAX,
    &FIG3C_INSENSITIVE,
    &TABLE1_LORE_OVER_FRMAX,
    &TABLE1_LSE_OVER_LORE,
    &TABLE1_BLORE_OVER_LORE,
    &TABLE2_JUMPSTART_LORE,
    &TABLE2_JUMPSTART_LWT,
    &FIG4B_ACCUMULATED_LORE,
    &FIG4B_ACCUMULATED_FEPSG,
    &TRANSFER_POOLED,
    &FIG4B_RANDS,
    &FIG4B_LWT,
    &TRANSFER_TIME,
    &FIG4_TARGETS,
    &FIG9_TES_AHEAD,
    &ROBOT_LWT_LEAST,
    &ROBOT_WORI_LOSES,
    &ROBOT_WORI_NOT_BY_MUCH,
    &TABLE5_FIRST_EPISODE,
    &TABLE3_LORE_OVER_MAN,
    &FIG8_LORE_AHEAD,
    &FIG8_MAN_LORE,
    &TABLE6_TIMES,
    &LIFELONG_TARGETS,
    &LIFELONG_ABLATIONS,
];

/// Looks a target up by its id.
pub fn target(id: &str) -> Option<&'static Target> {
    TARGETS.iter().copied().find(|t| t.id == id)
}

/// The registered target that a verdict of an `experiment` folder judges, from the words its
/// `summary.json` records: the target with those words (now or in an earlier form), else the
/// experiment's family whose checks carry words of their own (`fig4.targets`,
/// `lifelong.targets`, and `transfer.pooled` for the "across tasks" checks).
pub fn judged_by(experiment: &str, words: &str) -> Option<&'static Target> {
    let worded = |t: &&Target| t.target == words || t.history.iter().any(|h| h.target == words);
    let family = |t: &&Target| {
        let pooled = t.id == TRANSFER_POOLED.id;
        t.experiment == experiment
            && (t.id.ends_with(".targets") || pooled)
            && (!pooled || words.contains("across tasks"))
    };
    let targets = || TARGETS.iter().copied();
    targets().find(worded).or_else(|| targets().find(family))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_changed_threshold_without_a_revision_is_caught() {
        let mut changed = ROBOT_WORI_NOT_BY_MUCH;
        changed.threshold = Threshold::Share(0.95);
        assert_ne!(
            changed.fingerprint(),
            *ROBOT_WORI_NOT_BY_MUCH.fingerprints.last().unwrap_or(&"")
        );
        let mut reworded = ROBOT_WORI_NOT_BY_MUCH;
        reworded.target = "§5.2.3: ... but not to a large extent";
        assert_ne!(reworded.fingerprint(), changed.fingerprint());
    }

    #[test]
    fn a_revised_target_keeps_its_earlier_form() {
        let fig9 = target("robot.fig9.tes-ahead").expect("registered");
        assert_eq!(fig9.history.len(), 1);
        assert!(fig9.history[0].verdict_then.contains("fails"));
        assert_eq!(fig9.fingerprints.len(), 2);
    }

    #[test]
    fn fnv_is_the_published_function() {
        // FNV-1a 64 of "" and "a" (the reference values).
        assert_eq!(fingerprint(""), "cbf29ce484222325");
        assert_eq!(fingerprint("a"), "af63dc4c8601ec8c");
    }
}
