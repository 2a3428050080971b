//! Experiments as lists of independent jobs: sharding, resuming, merging.
//!
//! Every experiment is an ordered list of independent jobs (grid: an algorithm at a feature
//! count and a run; transfer: a run, holding out each test task in turn; robot: a method and a
//! run), each with a stable index. A run writes into its result folder
//!
//! * `manifest.json` — the experiment, its settings (seeds included), the code version, the
//!   number of jobs and which share of them this folder holds ([`Shard`]);
//! * `jobs/NNNNN.json` — one record per finished job, written atomically (temporary file,
//!   then rename) as the job finishes.
//!
//! The summary, tables and figures are computed from the records read back from `jobs/`,
//! whether the folder was filled in one run, resumed after an interruption
//! ([`JobOptions::resume`]) or merged from shards ([`merge`]): one code path, so the three give
//! the same `summary.json` (timings aside). Floats survive the round trip exactly
//! (`serde_json`'s `float_roundtrip`).
//!
//! ```
//! use tes_experiments::jobs::Shard;
//!
//! let shard: Shard = "2/3".parse()?;
//! let mine: Vec<usize> = (0..7).filter(|&j| shard.owns(j)).collect();
//! assert_eq!(mine, [1, 4]);
//! assert!("0/3".parse::<Shard>().is_err() && "4/3".parse::<Shard>().is_err());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::collections::BTreeMap;
use std::fmt;
use std::fs;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::atomic::{AtomicU64, Ordering};

use anyhow::{Context, Result, bail};
use rayon::prelude::*;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::verdict::TIME_RATIO_TEST;

/// The version of the manifest and record format.
pub const FORMAT: u32 = 1;

/// The code a result folder was made with: the crate version and `git describe` of the tree
/// it was built from (`unknown` when built outside a git checkout).
pub fn code_version() -> String {
    format!(
        "{} ({})",
        env!("CARGO_PKG_VERSION"),
        option_env!("TES_GIT_DESCRIBE").unwrap_or("unknown")
    )
}

/// Share `index` of `count` (1-based: `1/3`, `2/3`, `3/3`): the jobs whose index modulo
/// `count` is `index − 1`. `1/1` is the whole experiment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    /// Which share, from 1.
    pub index: usize,
    /// How many shares.
    pub count: usize,
}

impl Shard {
    /// Every job: `1/1`.
    pub const ALL: Shard = Shard { index: 1, count: 1 };

    /// Whether job `job` belongs to this share.
    pub fn owns(&self, job: usize) -> bool {
        job % self.count == self.index - 1
    }

    /// Whether this is the whole experiment.
    pub fn is_all(&self) -> bool {
        self.count == 1
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// Why a `--shard` value was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("a shard is K/N with 1 <= K <= N (e.g. 2/3), not {0:?}")]
pub struct ShardParseError(String);

impl FromStr for Shard {
    type Err = ShardParseError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = || ShardParseError(s.to_owned());
        let (k, n) = s.split_once('/').ok_or_else(bad)?;
        let index: usize = k.trim().parse().map_err(|_| bad())?;
        let count: usize = n.trim().parse().map_err(|_| bad())?;
        if index == 0 || index > count {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }
}

/// What a result folder holds: written first, checked on resume and on merge.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// [`FORMAT`].
    pub format: u32,
    /// `grid`, `transfer` or `robot`.
    pub experiment: String,
    /// [`code_version`] of the binary that ran it.
    pub code_version: String,
    /// The experiment's settings, seeds included, as its `summary.json` records them.
    pub settings: serde_json::Value,
    /// Jobs in the whole experiment.
    pub jobs: usize,
    /// The share of them this folder holds.
    pub shard: Shard,
    /// The code version of every binary that ran jobs into, merged or re-summarised this
    /// folder, in the order they did (appended; `code_version` is the first's).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub written_by: Vec<String>,
    /// The machines its jobs ran on.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub machines: Vec<Machine>,
    /// Wall-clock seconds spent running its jobs, summed over every process (and shard) that
    /// ran some — the run's own time, where `summary.json`'s `wall_seconds` is the last
    /// summary's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub run_seconds: Option<f64>,
    /// The machine's load while its jobs ran: the lowest and highest 1-minute load average
    /// seen (at the start and end of each stretch of jobs and as each job finished), so that
    /// its times say what they were measured under. `None` in folders written before it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub load: Option<LoadRange>,
}

/// The lowest and highest 1-minute load average (`/proc/loadavg`) seen.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LoadRange {
    /// The lowest.
    pub lowest: f64,
    /// The highest.
    pub highest: f64,
}

impl LoadRange {
    /// The 1-minute load average now (`None` where `/proc/loadavg` cannot be read).
    pub fn now() -> Option<f64> {
        let text = fs::read_to_string("/proc/loadavg").ok()?;
        text.split_whitespace().next()?.parse().ok()
    }

    /// The range widened to hold `other`.
    pub fn with(self, other: LoadRange) -> LoadRange {
        LoadRange {
            lowest: self.lowest.min(other.lowest),
            highest: self.highest.max(other.highest),
        }
    }

    /// The range holding both (either, if only one is known).
    pub fn both(a: Option<LoadRange>, b: Option<LoadRange>) -> Option<LoadRange> {
        match (a, b) {
            (Some(a), Some(b)) => Some(a.with(b)),
            (a, b) => a.or(b),
        }
    }

    /// `range` widened to hold the load now (`range` as it was if it cannot be read).
    fn sampled(range: Option<LoadRange>) -> Option<LoadRange> {
        let Some(load) = Self::now() else {
            return range;
        };
        let here = LoadRange {
            lowest: load,
            highest: load,
        };
        Some(range.map_or(here, |r| r.with(here)))
    }
}

impl fmt::Display for LoadRange {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if (self.highest - self.lowest).abs() < 0.05 {
            write!(f, "{:.1}", self.lowest)
        } else {
            write!(f, "{:.1}–{:.1}", self.lowest, self.highest)
        }
    }
}

/// A machine jobs ran on, as Linux describes it (`unknown` and 0 elsewhere).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Machine {
    /// The CPU model (`/proc/cpuinfo`'s `model name`).
    pub cpu: String,
    /// Logical cores the process may use.
    pub cores: usize,
    /// Memory in MiB (`/proc/meminfo`'s `MemTotal`).
    pub memory_mib: u64,
}

impl Machine {
    /// This machine.
    pub fn this() -> Self {
        let cpuinfo = fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
        let meminfo = fs::read_to_string("/proc/meminfo").unwrap_or_default();
        Self {
            cpu: field(&cpuinfo, "model name").unwrap_or_else(|| "unknown".to_owned()),
            cores: std::thread::available_parallelism().map_or(0, usize::from),
            memory_mib: field(&meminfo, "MemTotal")
                .and_then(|v| v.trim_end_matches("kB").trim().parse::<u64>().ok())
                .map_or(0, |kib| kib / 1024),
        }
    }
}

impl fmt::Display for Machine {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}, {} cores, {} MiB",
            self.cpu, self.cores, self.memory_mib
        )
    }
}

/// The value of the first `key: value` line of a `/proc` file.
fn field(text: &str, key: &str) -> Option<String> {
    text.lines().find_map(|line| {
        let (k, v) = line.split_once(':')?;
        (k.trim() == key).then(|| v.trim().to_owned())
    })
}

/// Whether `version` (a [`code_version`]) was built from a tree with uncommitted changes.
pub fn is_dirty(version: &str) -> bool {
    version.contains("-dirty")
}

impl Manifest {
    /// The manifest of `experiment` with `settings` and `jobs` jobs, for `shard`.
    pub fn new(
        experiment: &str,
        settings: &impl Serialize,
        jobs: usize,
        shard: Shard,
    ) -> Result<Self> {
        Ok(Self {
            format: FORMAT,
            experiment: experiment.to_owned(),
            code_version: code_version(),
            settings: serde_json::to_value(settings).context("cannot encode the settings")?,
            jobs,
            shard,
            written_by: vec![code_version()],
            machines: Vec::new(),
            run_seconds: None,
            load: None,
        })
    }

    /// Whether any binary that wrote or re-summarised the folder was built from a modified
    /// tree.
    pub fn is_dirty(&self) -> bool {
        is_dirty(&self.code_version) || self.written_by.iter().any(|v| is_dirty(v))
    }

    /// Whether the run is a `--quick` one (its settings say so).
    fn is_quick(&self) -> bool {
        self.settings.get("quick") == Some(&Value::Bool(true))
    }

    /// Records `version` among the binaries that wrote the folder, unless it is the last.
    fn written_by_too(&mut self, version: String) {
        if self.written_by.last() != Some(&version) {
            self.written_by.push(version);
        }
    }

    /// The settings, decoded.
    pub fn settings<C: DeserializeOwned>(&self) -> Result<C> {
        serde_json::from_value(self.settings.clone())
            .with_context(|| format!("the manifest's {} settings do not decode", self.experiment))
    }

    /// Reads `dir/manifest.json`.
    pub fn read(dir: &Path) -> Result<Self> {
        let path = dir.join(MANIFEST);
        let text = fs::read_to_string(&path)
            .with_context(|| format!("cannot read {} (not a result folder?)", path.display()))?;
        serde_json::from_str(&text).with_context(|| format!("{} is malformed", path.display()))
    }

    pub(crate) fn write(&self, dir: &Path) -> Result<()> {
        let json = serde_json::to_string_pretty(self).context("cannot encode the manifest")?;
        write_atomically(&dir.join(MANIFEST), json.as_bytes())
    }
}

const MANIFEST: &str = "manifest.json";
const JOBS: &str = "jobs";

/// One finished job as written to `jobs/NNNNN.json`.
#[derive(Debug, Serialize, Deserialize)]
struct Record<R> {
    index: usize,
    result: R,
}

fn record_path(dir: &Path, index: usize) -> PathBuf {
    dir.join(JOBS).join(format!("{index:05}.json"))
}

fn write_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = path.with_extension("json.tmp");
    fs::write(&tmp, bytes).with_context(|| format!("cannot write {}", tmp.display()))?;
    fs::rename(&tmp, path).with_context(|| format!("cannot rename {}", tmp.display()))
}

/// The job indices recorded in `dir/jobs` (none if it has no such folder), sorted.
pub fn recorded(dir: &Path) -> Result<Vec<usize>> {
    let jobs = dir.join(JOBS);
    if !jobs.is_dir() {
        return Ok(Vec::new());
    }
    let mut out = Vec::new();
    for entry in fs::read_dir(&jobs).with_context(|| format!("cannot list {}", jobs.display()))? {
        let entry = entry.with_context(|| format!("cannot list {}", jobs.display()))?;
        let name = entry.file_name();
        let Some(stem) = name.to_str().and_then(|n| n.strip_suffix(".json")) else {
            continue;
        };
        if let Ok(i) = stem.parse() {
            out.push(i);
        }
    }
    out.sort_unstable();
    Ok(out)
}

fn read_record<R: DeserializeOwned>(dir: &Path, index: usize) -> Result<R> {
    let path = record_path(dir, index);
    let text =
        fs::read_to_string(&path).with_context(|| format!("cannot read {}", path.display()))?;
    let record: Record<R> =
        serde_json::from_str(&text).with_context(|| format!("{} is malformed", path.display()))?;
    if record.index != index {
        anyhow::bail!("{} holds job {}", path.display(), record.index);
    }
    Ok(record.result)
}

/// How to run an experiment's jobs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct JobOptions {
    /// The share of the jobs to run.
    pub shard: Shard,
    /// Keep the records a folder already holds (from the same settings, code and shard) and
    /// run only the missing jobs; otherwise earlier records in the folder are removed first.
    pub resume: bool,
    /// Write a full (not `--quick`) run from a binary built from a modified tree; refused
    /// otherwise, since its results could not be traced to a commit.
    pub allow_dirty: bool,
}

impl Default for JobOptions {
    fn default() -> Self {
        Self {
            shard: Shard::ALL,
            resume: false,
            allow_dirty: false,
        }
    }
}

/// Why a run was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RunError {
    /// A full run from a binary built from a modified tree, not allowed.
    #[error(
        "refusing to write a full run from a binary built from a modified tree ({version}): \
         commit first, or pass --allow-dirty (the folder is then marked in every table)"
    )]
    DirtyTree {
        /// The binary's code version.
        version: String,
    },
}

/// Refuses a full run from a modified tree unless `options` allow it.
fn refuse_dirty(manifest: &Manifest, options: JobOptions) -> Result<()> {
    dirty_refusal(&code_version(), manifest, options).map_err(Into::into)
}

/// The refusal of a full run of `manifest` by a binary of `version`, if it is one.
fn dirty_refusal(version: &str, manifest: &Manifest, options: JobOptions) -> Result<(), RunError> {
    if is_dirty(version) && !manifest.is_quick() && !options.allow_dirty {
        return Err(RunError::DirtyTree {
            version: version.to_owned(),
        });
    }
    Ok(())
}

/// Adds a finished stretch of jobs to `out`'s manifest: `seconds` of wall time under `load`,
/// this machine and this binary's code version.
fn record_run(out: &Path, seconds: f64, load: Option<LoadRange>) -> Result<()> {
    let mut manifest = Manifest::read(out)?;
    manifest.run_seconds = Some(manifest.run_seconds.unwrap_or(0.0) + seconds);
    manifest.load = LoadRange::both(manifest.load, load);
    let machine = Machine::this();
    if !manifest.machines.contains(&machine) {
        manifest.machines.push(machine);
    }
    manifest.written_by_too(code_version());
    manifest.write(out)
}

/// Records in `dir`'s manifest that this binary re-summarised it.
pub fn record_summariser(dir: &Path) -> Result<()> {
    let mut manifest = Manifest::read(dir)?;
    manifest.written_by_too(code_version());
    manifest.write(dir)
}

/// Runs the jobs on `threads` worker threads (`None`: one per core). Only the first call in
/// a process can size the pool; a later one keeps the pool as it is.
pub fn use_threads(threads: Option<usize>) -> Result<()> {
    if let Some(threads) = threads {
        if threads == 0 {
            bail!("--threads must be at least 1");
        }
        // A failure means the pool was already built, which is harmless.
        let _ = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build_global();
    }
    Ok(())
}

/// Starts a fresh run in `out`: removes the job records an earlier run left there and
/// writes `manifest`.
pub fn prepare(out: &Path, manifest: &Manifest) -> Result<()> {
    fs::create_dir_all(out.join(JOBS))
        .with_context(|| format!("cannot create {}", out.join(JOBS).display()))?;
    for i in recorded(out)? {
        let path = record_path(out, i);
        fs::remove_file(&path)
            .with_context(|| format!("cannot remove the earlier {}", path.display()))?;
    }
    manifest.write(out)
}

/// Every job record of the finished folder `out` (described by its `manifest`), by job
/// index; a missing record is an error naming it (nothing is run).
pub fn read_all<R>(out: &Path, manifest: &Manifest) -> Result<BTreeMap<usize, R>>
where
    R: Serialize + DeserializeOwned + Send,
{
    let total = manifest.jobs;
    run_jobs(
        out,
        manifest,
        JobOptions {
            shard: Shard::ALL,
            resume: true,
            allow_dirty: true,
        },
        &|_, _| {},
        |index| anyhow::bail!("job {index} of {total} is missing from {}", out.display()),
    )
}

/// Runs this shard's jobs of an experiment into `out` (records as they finish, in parallel
/// on the rayon pool) and returns their results read back from disk, by job index.
///
/// `progress(done, total)` counts this shard's jobs, those found on resume included; it is
/// called once before any job runs and then from worker threads as jobs finish.
pub fn run_jobs<R, F>(
    out: &Path,
    manifest: &Manifest,
    options: JobOptions,
    progress: &(dyn Fn(u64, u64) + Sync),
    job: F,
) -> Result<BTreeMap<usize, R>>
where
    R: Serialize + DeserializeOwned + Send,
    F: Fn(usize) -> Result<R> + Sync,
{
    fs::create_dir_all(out.join(JOBS))
        .with_context(|| format!("cannot create {}", out.join(JOBS).display()))?;
    refuse_dirty(manifest, options)?;
    let mut have = Vec::new();
    if options.resume {
        let earlier = Manifest::read(out)?;
        if let Some(why) = mismatch(&earlier, manifest) {
            anyhow::bail!(
                "cannot resume {}: it holds another run ({why})",
                out.display()
            );
        }
        if earlier.shard != manifest.shard {
            anyhow::bail!(
                "cannot resume {}: it holds shard {}, not {}",
                out.display(),
                earlier.shard,
                manifest.shard
            );
        }
        have = recorded(out)?;
    } else {
        prepare(out, manifest)?;
    }
    let mine: Vec<usize> = (0..manifest.jobs)
        .filter(|&j| manifest.shard.owns(j))
        .collect();
    let todo: Vec<usize> = mine
        .iter()
        .copied()
        .filter(|j| have.binary_search(j).is_err())
        .collect();
    let total = mine.len() as u64;
    let done = AtomicU64::new(total - todo.len() as u64);
    progress(done.load(Ordering::Relaxed), total);
    let started = std::time::Instant::now();
    let load = std::sync::Mutex::new(LoadRange::sampled(None));
    let sample_load = || {
        if let Ok(mut range) = load.lock() {
            *range = LoadRange::sampled(*range);
        }
    };
    let ran = todo.par_iter().try_for_each(|&index| -> Result<()> {
        let result = job(index)?;
        let json = serde_json::to_vec(&Record { index, result })
            .with_context(|| format!("cannot encode job {index}"))?;
        write_atomically(&record_path(out, index), &json)?;
        sample_load();
        progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
        Ok(())
    });
    sample_load();
    // An interrupted stretch counts too (a resume adds the rest); reading a complete folder
    // back runs nothing and records nothing.
    if done.load(Ordering::Relaxed) > total - todo.len() as u64 {
        let load = load.into_inner().ok().flatten();
        record_run(out, started.elapsed().as_secs_f64(), load)?;
    }
    ran?;
    mine.into_iter()
        .map(|i| Ok((i, read_record(out, i)?)))
        .collect()
}

/// Why shard folders were not merged.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MergeError {
    /// No folder given.
    #[error("no shard folder given")]
    Nothing,
    /// Two folders come from different runs.
    #[error("{first} and {other} are not shards of the same run: {why}")]
    Mismatched {
        /// The first folder.
        first: String,
        /// The folder that differs.
        other: String,
        /// What differs.
        why: String,
    },
    /// A job is in more than one folder.
    #[error("the shards overlap: job {job} is in both {a} and {b}")]
    Overlapping {
        /// The job index.
        job: usize,
        /// One folder.
        a: String,
        /// Another.
        b: String,
    },
    /// A folder holds a job its shard does not own.
    #[error("{dir} (shard {shard}) holds job {job}, which is not its share")]
    Foreign {
        /// The folder.
        dir: String,
        /// Its shard.
        shard: Shard,
        /// The job.
        job: usize,
    },
    /// Jobs are in no folder.
    #[error("{} of {total} jobs are missing (first: {first:?}); run the missing shards (or resume them) and merge again", missing.len())]
    Missing {
        /// The missing job indices.
        missing: Vec<usize>,
        /// The first few of them, for the message.
        first: Vec<usize>,
        /// Jobs in the whole experiment.
        total: usize,
    },
}

/// What differs between two manifests, besides the shard: experiment, format, code version,
/// settings or job count.
fn mismatch(a: &Manifest, b: &Manifest) -> Option<String> {
    if a.experiment != b.experiment {
        return Some(format!(
            "experiment {} against {}",
            a.experiment, b.experiment
        ));
    }
    if a.format != b.format {
        return Some(format!("format {} against {}", a.format, b.format));
    }
    if a.code_version != b.code_version {
        return Some(format!(
            "code version {} against {}",
            a.code_version, b.code_version
        ));
    }
    if a.settings != b.settings {
        let (serde_json::Value::Object(x), serde_json::Value::Object(y)) =
            (&a.settings, &b.settings)
        else {
            return Some("other settings".into());
        };
        let differing: Vec<String> = x
            .keys()
            .chain(y.keys())
            .filter(|k| x.get(*k) != y.get(*k))
            .map(|k| {
                let show = |v: Option<&serde_json::Value>| v.map_or("-".into(), |v| v.to_string());
                format!("{k} {} against {}", show(x.get(k)), show(y.get(k)))
            })
            .collect();
        return Some(format!("other settings: {}", differing.join(", ")));
    }
    if a.jobs != b.jobs {
        return Some(format!("{} jobs against {}", a.jobs, b.jobs));
    }
    None
}

/// Merges shard folders of one run into `out`: checks that they come from the same
/// experiment, settings, seeds and code, that no job is in two of them and none is missing,
/// then copies their job records (and any other files the jobs wrote, such as trained
/// libraries) into `out` with a `1/1` manifest. Returns that manifest; the experiment's
/// summary is then computed from `out` as for an unsharded run.
pub fn merge(dirs: &[PathBuf], out: &Path) -> Result<Manifest> {
    let Some(first_dir) = dirs.first() else {
        return Err(MergeError::Nothing.into());
    };
    let manifests: Vec<Manifest> = dirs
        .iter()
        .map(|d| Manifest::read(d))
        .collect::<Result<_>>()?;
    let first = &manifests[0];
    let shown = |d: &Path| d.display().to_string();
    for (dir, m) in dirs.iter().zip(&manifests).skip(1) {
        let why = mismatch(first, m).or_else(|| {
            (m.shard.count != first.shard.count).then(|| {
                format!(
                    "split into {} shards against {}",
                    first.shard.count, m.shard.count
                )
            })
        });
        if let Some(why) = why {
            return Err(MergeError::Mismatched {
                first: shown(first_dir),
                other: shown(dir),
                why,
            }
            .into());
        }
    }
    let mut owner: BTreeMap<usize, usize> = BTreeMap::new();
    for (d, (dir, m)) in dirs.iter().zip(&manifests).enumerate() {
        for job in recorded(dir)? {
            if job >= m.jobs || !m.shard.owns(job) {
                return Err(MergeError::Foreign {
                    dir: shown(dir),
                    shard: m.shard,
                    job,
                }
                .into());
            }
            if let Some(&other) = owner.get(&job) {
                return Err(MergeError::Overlapping {
                    job,
                    a: shown(&dirs[other]),
                    b: shown(dir),
                }
                .into());
            }
            owner.insert(job, d);
        }
    }
    let missing: Vec<usize> = (0..first.jobs).filter(|j| !owner.contains_key(j)).collect();
    if !missing.is_empty() {
        return Err(MergeError::Missing {
            first: missing.iter().copied().take(8).collect(),
            missing,
            total: first.jobs,
        }
        .into());
    }
    fs::create_dir_all(out.join(JOBS))
        .with_context(|| format!("cannot create {}", out.join(JOBS).display()))?;
    for i in recorded(out)? {
        if !owner.contains_key(&i) {
            fs::remove_file(record_path(out, i)).with_context(|| {
                format!("cannot remove the earlier job {i} in {}", out.display())
            })?;
        }
    }
    for (&job, &d) in &owner {
        let (from, to) = (record_path(&dirs[d], job), record_path(out, job));
        if from != to {
            fs::copy(&from, &to)
                .with_context(|| format!("cannot copy {} to {}", from.display(), to.display()))?;
        }
    }
    // Files the jobs wrote beside their records (e.g. a trained library).
    for dir in dirs {
        for entry in fs::read_dir(dir).with_context(|| format!("cannot list {}", dir.display()))? {
            let entry = entry.with_context(|| format!("cannot list {}", dir.display()))?;
            let name = entry.file_name();
            let is_artefact = name.to_str().is_some_and(|n| n.ends_with(".tesl"));
            let to = out.join(&name);
            if is_artefact && entry.path() != to {
                fs::copy(entry.path(), &to).with_context(|| {
                    format!("cannot copy {} to {}", entry.path().display(), to.display())
                })?;
            }
        }
    }
    let merged = merged_manifest(&manifests);
    merged.write(out)?;
    Ok(merged)
}

/// The manifest of shards merged into one folder: the first's run, the whole experiment, and
/// every shard's writers, machines and run time, with this binary as the last writer.
fn merged_manifest(manifests: &[Manifest]) -> Manifest {
    let mut merged = Manifest {
        shard: Shard::ALL,
        written_by: Vec::new(),
        machines: Vec::new(),
        run_seconds: None,
        load: None,
        ..manifests[0].clone()
    };
    for m in manifests {
        for v in &m.written_by {
            if !merged.written_by.contains(v) {
                merged.written_by.push(v.clone());
            }
        }
        for machine in &m.machines {
            if !merged.machines.contains(machine) {
                merged.machines.push(machine.clone());
            }
        }
        merged.load = LoadRange::both(merged.load, m.load);
        if let Some(s) = m.run_seconds {
            merged.run_seconds = Some(merged.run_seconds.unwrap_or(0.0) + s);
        }
    }
    merged.written_by_too(code_version());
    merged
}

/// `summary` (the `summary.json` of any experiment) without what depends on the clock: wall
/// and agent seconds (`wall_seconds`, keys ending in `seconds_per_episode`), time ratios
/// (keys ending in `_time`), and the measured figure and verdict of the targets on times
/// (those judged by [`TIME_RATIO_TEST`]). What
/// is left is the same for every run of the same settings and code: one run, a resumed one,
/// merged shards, `tes experiment all` or the separate commands.
///
/// ```
/// use serde_json::json;
/// use tes_experiments::jobs::summary_without_timings;
/// use tes_experiments::verdict::TIME_RATIO_TEST;
///
/// let summary = json!({
///     "wall_seconds": 12.5,
///     "lore_over_fepsg_time": 2.1,
///     "table1": {"loreRL": {"features": 210, "seconds_per_episode": {"mean": 0.1}}},
///     "targets": [
///         {"target": "Table 1: loreRL / fEpsG ...", "test": TIME_RATIO_TEST,
///          "measured": "2.10", "verdict": "holds"},
///         {"target": "Fig. 8: ...", "measured": "TES 3.0", "verdict": "holds"},
///     ],
/// });
/// assert_eq!(
///     summary_without_timings(&summary),
///     json!({
///         "table1": {"loreRL": {"features": 210}},
///         "targets": [
///             {"target": "Table 1: loreRL / fEpsG ...", "test": TIME_RATIO_TEST},
///             {"target": "Fig. 8: ...", "measured": "TES 3.0", "verdict": "holds"},
///         ],
///     })
/// );
/// ```
pub fn summary_without_timings(summary: &Value) -> Value {
    fn strip(v: &mut Value) {
        match v {
            Value::Object(map) => {
                let timed = map
                    .get("test")
                    .and_then(Value::as_str)
                    .is_some_and(|t| t == TIME_RATIO_TEST);
                if timed {
                    map.remove("measured");
                    map.remove("verdict");
                }
                map.retain(|key, _| {
                    key != "wall_seconds"
                        && !key.ends_with("seconds_per_episode")
                        && !key.ends_with("_time")
                });
                map.values_mut().for_each(strip);
            }
            Value::Array(items) => items.iter_mut().for_each(strip),
            _ => {}
        }
    }
    let mut v = summary.clone();
    strip(&mut v);
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_split_the_jobs_into_disjoint_complete_shares() {
        for n in 1..6 {
            let shards: Vec<Shard> = (1..=n)
                .map(|k| format!("{k}/{n}").parse().unwrap())
                .collect();
            for job in 0..40 {
                assert_eq!(shards.iter().filter(|s| s.owns(job)).count(), 1);
            }
        }
        for bad in ["", "1", "0/2", "3/2", "a/b", "1/0", "-1/2"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
        assert_eq!(
            " 2 / 3 ".trim().parse::<Shard>().unwrap().to_string(),
            "2/3"
        );
    }

    #[test]
    fn a_full_run_from_a_modified_tree_is_refused_unless_allowed() {
        let full =
            Manifest::new("test", &serde_json::json!({"quick": false}), 1, Shard::ALL).unwrap();
        let quick =
            Manifest::new("test", &serde_json::json!({"quick": true}), 1, Shard::ALL).unwrap();
        let dirty = "0.1.0 (5d359f9-dirty)";
        let refused = dirty_refusal(dirty, &full, JobOptions::default());
        assert!(
            matches!(refused, Err(RunError::DirtyTree { .. })),
            "{refused:?}"
        );
        let allowed = JobOptions {
            allow_dirty: true,
            ..JobOptions::default()
        };
        assert_eq!(dirty_refusal(dirty, &full, allowed), Ok(()));
        assert_eq!(dirty_refusal(dirty, &quick, JobOptions::default()), Ok(()));
        assert_eq!(
            dirty_refusal("0.1.0 (5d359f9)", &full, JobOptions::default()),
            Ok(())
        );
        // As written by a clean binary (this test's own build may be dirty).
        let mut written = Manifest {
            code_version: "0.1.0 (5d359f9)".to_owned(),
            written_by: vec!["0.1.0 (5d359f9)".to_owned()],
            ..full.clone()
        };
        assert!(!written.is_dirty());
        written.written_by_too(dirty.to_owned());
        assert!(written.is_dirty(), "a dirty re-summariser marks the folder");
    }

    #[test]
    fn a_run_records_its_time_machine_and_writer_and_a_merge_keeps_them() {
        let dirs = [tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap()];
        let options = |k| JobOptions {
            shard: Shard { index: k, count: 2 },
            resume: false,
            allow_dirty: true,
        };
        for (k, dir) in dirs.iter().enumerate() {
            let manifest = Manifest::new(
                "test",
                &serde_json::json!({"x": 1}),
                4,
                options(k + 1).shard,
            )
            .unwrap();
            run_jobs(dir.path(), &manifest, options(k + 1), &|_, _| {}, |i| {
                Ok(i as f64)
            })
            .unwrap();
            let written = Manifest::read(dir.path()).unwrap();
            assert!(written.run_seconds.is_some_and(|s| s >= 0.0));
            assert_eq!(written.machines, [Machine::this()]);
            // The load it ran under, from /proc/loadavg.
            let load = written.load.expect("the load recorded");
            assert!(
                load.lowest <= load.highest && load.lowest >= 0.0,
                "{load:?}"
            );
            assert_eq!(written.written_by, [code_version()]);
        }
        let out = tempfile::tempdir().unwrap();
        let shards: Vec<PathBuf> = dirs.iter().map(|d| d.path().to_owned()).collect();
        let merged = merge(&shards, out.path()).unwrap();
        let each: Vec<f64> = dirs
            .iter()
            .map(|d| Manifest::read(d.path()).unwrap().run_seconds.unwrap())
            .collect();
        assert_eq!(
            merged.run_seconds,
            Some(each[0] + each[1]),
            "the shards' times summed"
        );
        assert_eq!(merged.machines.len(), 1);
        // Reading a complete folder back runs nothing and records nothing new.
        read_all::<f64>(out.path(), &merged).unwrap();
        assert_eq!(Manifest::read(out.path()).unwrap(), merged);
        record_summariser(out.path()).unwrap();
        assert_eq!(
            Manifest::read(out.path()).unwrap().written_by,
            [code_version()]
        );
    }

    #[test]
    fn a_resumed_run_runs_only_the_missing_jobs() {
        let dir = tempfile::tempdir().unwrap();
        let manifest = Manifest::new("test", &serde_json::json!({"x": 1}), 5, Shard::ALL).unwrap();
        let job = |i: usize| {
            if i == 3 {
                anyhow::bail!("interrupted");
            }
            Ok(i as f64 * 0.1)
        };
        let first = run_jobs(
            dir.path(),
            &manifest,
            JobOptions {
                allow_dirty: true,
                ..JobOptions::default()
            },
            &|_, _| {},
            job,
        );
        assert!(first.is_err());
        assert!(!recorded(dir.path()).unwrap().contains(&3));
        let resume = JobOptions {
            resume: true,
            allow_dirty: true,
            ..JobOptions::default()
        };
        let all = run_jobs(dir.path(), &manifest, resume, &|_, _| {}, |i| {
            Ok(i as f64 * 0.1)
        })
        .unwrap();
        assert_eq!(all.len(), 5);
        assert_eq!(all[&3], 0.30000000000000004);
        // Another run's settings cannot resume this folder.
        let other = Manifest::new("test", &serde_json::json!({"x": 2}), 5, Shard::ALL).unwrap();
        let err = run_jobs(dir.path(), &other, resume, &|_, _| {}, |_| Ok(0.0)).unwrap_err();
        assert!(err.to_string().contains("x 1 against 2"), "{err}");
    }

    #[test]
    fn a_load_range_widens_to_hold_both_and_says_itself() {
        let a = LoadRange {
            lowest: 0.5,
            highest: 1.25,
        };
        let b = LoadRange {
            lowest: 0.75,
            highest: 2.0,
        };
        let both = LoadRange::both(Some(a), Some(b)).unwrap();
        assert_eq!((both.lowest, both.highest), (0.5, 2.0));
        assert_eq!(LoadRange::both(None, Some(b)), Some(b));
        assert_eq!(LoadRange::both(None, None), None);
        assert_eq!(both.to_string(), "0.5–2.0");
        let flat = LoadRange {
            lowest: 1.02,
            highest: 1.04,
        };
        assert_eq!(flat.to_string(), "1.0");
    }
}
