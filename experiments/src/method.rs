//! Every method the experiments compare, in one place: its name in reports and files, its
//! colour in every figure, and its order.
//!
//! The name is what `summary.json`, `episodes.csv`, the job records, the figures' legends and
//! `report.md` call a method, so it never changes once results are written. The colour keeps a
//! method recognisable from figure to figure (Okabe–Ito's colour-blind-safe colours for the
//! methods drawn most often, Paul Tol's for the rest, a family of browns for the random view
//! combinations). The order is the declaration order ([`Ord`]): reports list methods in it,
//! and the grid experiment numbers its jobs by it, so reordering the variants would renumber
//! the jobs of result folders already written.
//!
//! ```
//! use tes_experiments::method::Method;
//!
//! assert_eq!(Method::TesWoRi.name(), "TES-woRi");
//! assert_eq!(Method::Rands(2).to_string(), "Rands 2");
//! assert_eq!(Method::from_name("RL-DT"), Some(Method::RlDt));
//! assert_eq!(Method::LoreRl.colour(), "#009E73");
//! assert!(Method::Tes < Method::LoreRl && Method::FEpsG < Method::Rands(1));
//! ```

use std::borrow::Cow;
use std::fmt;

use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// A method of the paper's experiments (§5.1 grid and transfer, §5.2 robot).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Method {
    /// TES: the view library's views scored and switched online (the robot study's TES has
    /// lived through Env 1 and Env 2 first).
    Tes,
    /// TES having lived through Env 2 only (the robot study).
    TesWoRi,
    /// LWT: the library's best-track-record view per action, frozen.
    Lwt,
    /// loreRL, no transfer.
    LoreRl,
    /// loreRL on the robot's 12 hand-picked features.
    ManLoreRl,
    /// loreRL without the regulariser (λ = 0).
    BloreRl,
    /// Tabular R-max.
    Rmax,
    /// Factored R-max with the true DBN structure.
    FRmax,
    /// Factored ε-greedy with the true DBN structure.
    FEpsG,
    /// RL-DT: decision-tree effect models, ε-greedy.
    RlDt,
    /// LSE-Rmax: R-max with learned parent sets.
    LseRmax,
    /// TES with a library of no practical bound (the lifelong benchmark).
    TesUnbounded,
    /// TES with no recency decay of the track record (`μ = 0`, the paper's setting; the
    /// lifelong benchmark's ablation).
    TesNoRecency,
    /// loreRL whose views are carried from task to task and never reset: one mDAGL model per
    /// action learning across the whole sequence (the lifelong benchmark's continual
    /// baseline).
    LoreRlContinual,
    /// The `i`-th random view combination (from 1): a random library view per action,
    /// learning, never switched (the transfer study's "Rands").
    Rands(usize),
}

impl Method {
    /// Every method without a parameter, in order; the random combinations
    /// ([`Rands`](Self::Rands)) come after them.
    pub const FIXED: [Method; 14] = [
        Method::Tes,
        Method::TesWoRi,
        Method::Lwt,
        Method::LoreRl,
        Method::ManLoreRl,
        Method::BloreRl,
        Method::Rmax,
        Method::FRmax,
        Method::FEpsG,
        Method::RlDt,
        Method::LseRmax,
        Method::TesUnbounded,
        Method::TesNoRecency,
        Method::LoreRlContinual,
    ];

    /// The name in reports, files and legends; borrowed for every method but the numbered
    /// random combinations.
    pub fn name(self) -> Cow<'static, str> {
        Cow::Borrowed(match self {
            Method::Tes => "TES",
            Method::TesWoRi => "TES-woRi",
            Method::Lwt => "LWT",
            Method::LoreRl => "loreRL",
            Method::ManLoreRl => "man-loreRL",
            Method::BloreRl => "bloreRL",
            Method::Rmax => "Rmax",
            Method::FRmax => "fRmax",
            Method::FEpsG => "fEpsG",
            Method::RlDt => "RL-DT",
            Method::LseRmax => "LSE-Rmax",
            Method::TesUnbounded => "TES-unbounded",
            Method::TesNoRecency => "TES-norecency",
            Method::LoreRlContinual => "loreRL-continual",
            Method::Rands(i) => return Cow::Owned(format!("Rands {i}")),
        })
    }

    /// The method called `name`: the inverse of [`name`](Self::name), exactly (so "Rands 07"
    /// is no method: its name would be "Rands 7").
    pub fn from_name(name: &str) -> Option<Self> {
        if let Some(&m) = Self::FIXED.iter().find(|m| m.name() == name) {
            return Some(m);
        }
        let digits = name.strip_prefix("Rands ")?;
        let i: usize = digits.parse().ok()?;
        (i.to_string() == digits).then_some(Method::Rands(i))
    }

    /// The colour the method is drawn in, in every figure of every experiment.
    pub fn colour(self) -> &'static str {
        match self {
            Method::Tes => "#0072B2",
            Method::TesWoRi => "#56B4E9",
            Method::Lwt => "#D55E00",
            Method::LoreRl => "#009E73",
            Method::ManLoreRl => "#117733",
            Method::BloreRl => "#999933",
            Method::Rmax => "#882255",
            Method::FRmax => "#E69F00",
            Method::FEpsG => "#CC79A7",
            Method::RlDt => "#000000",
            Method::LseRmax => "#332288",
            Method::TesUnbounded => "#AA3377",
            Method::TesNoRecency => "#BBCC33",
            Method::LoreRlContinual => "#EE8866",
            Method::Rands(1) => "#8C510A",
            Method::Rands(2) => "#BF812D",
            Method::Rands(3) => "#DDCC77",
            Method::Rands(4) => "#6E4B2A",
            Method::Rands(5) => "#C49A6C",
            // The paper compares five; a sixth and later are told apart by name.
            Method::Rands(_) => spare_colour(&self.name()),
        }
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name())
    }
}

/// Written as its [`name`](Method::name), so job records and maps keyed by method read as the
/// reports do.
impl Serialize for Method {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.name())
    }
}

impl<'de> Deserialize<'de> for Method {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        Method::from_name(&name)
            .ok_or_else(|| serde::de::Error::custom(format!("unknown method {name:?}")))
    }
}

/// The colour a series called `name` is drawn in: its method's [`colour`](Method::colour), or
/// for a name that is no method one of a few spare colours chosen by the name alone, so it too
/// stays the same from figure to figure.
pub fn colour_by_name(name: &str) -> &'static str {
    Method::from_name(name).map_or_else(|| spare_colour(name), Method::colour)
}

/// Colours no method has.
const SPARE_COLOURS: [&str; 5] = ["#44AA99", "#AA4499", "#88CCEE", "#661100", "#6699CC"];

/// One of [`SPARE_COLOURS`], picked by a hash of `name`.
fn spare_colour(name: &str) -> &'static str {
    // FNV-1a: stable across runs and platforms, unlike the standard library's hasher.
    let hash = name.bytes().fold(0xcbf2_9ce4_8422_2325_u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    });
    SPARE_COLOURS[(hash % SPARE_COLOURS.len() as u64) as usize]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The paper's five random combinations and every other method.
    fn drawn() -> Vec<Method> {
        Method::FIXED
            .into_iter()
            .chain((1..=5).map(Method::Rands))
            .collect()
    }

    #[test]
    fn every_method_has_a_colour_of_its_own() {
        let methods = drawn();
        for (i, m) in methods.iter().enumerate() {
            assert_eq!(colour_by_name(&m.name()), m.colour());
            assert!(!SPARE_COLOURS.contains(&m.colour()), "{m}");
            for other in &methods[i + 1..] {
                assert_ne!(m.name(), other.name());
                assert_ne!(m.colour(), other.colour(), "{m} and {other}");
            }
        }
        // A name that is no method gets a spare colour, the same every time.
        let spare = colour_by_name("some new method");
        assert_eq!(spare, colour_by_name("some new method"));
        assert!(SPARE_COLOURS.contains(&spare));
    }

    #[test]
    fn names_and_order_are_those_results_were_written_with() {
        // Result folders, job records and the grid's job numbers depend on these.
        let names: Vec<String> = drawn().iter().map(ToString::to_string).collect();
        assert_eq!(
            names,
            [
                "TES",
                "TES-woRi",
                "LWT",
                "loreRL",
                "man-loreRL",
                "bloreRL",
                "Rmax",
                "fRmax",
                "fEpsG",
                "RL-DT",
                "LSE-Rmax",
                "TES-unbounded",
                "TES-norecency",
                "loreRL-continual",
                "Rands 1",
                "Rands 2",
                "Rands 3",
                "Rands 4",
                "Rands 5"
            ]
        );
        let mut sorted = drawn();
        sorted.sort();
        assert_eq!(sorted, drawn());
        for m in drawn().into_iter().chain([Method::Rands(12)]) {
            assert_eq!(Method::from_name(&m.name()), Some(m));
            let json = serde_json::to_string(&m).unwrap();
            assert_eq!(serde_json::from_str::<Method>(&json).unwrap(), m);
        }
        for no in ["Rands", "Rands 07", "Rands -1", "tes", ""] {
            assert_eq!(Method::from_name(no), None, "{no}");
        }
    }
}
