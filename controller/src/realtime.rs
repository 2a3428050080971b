//! The real-time split of acting and planning (Hester & Stone's RTMBA architecture): the
//! acting loop learns and acts on the last finished policy; value iteration runs on its own
//! thread and hands back a fresh policy when done, so a slow plan never delays an action.
//!
//! One job buffer travels between the two threads over crossbeam channels: the acting
//! side puts the model's changes into it ([`ModelChanges`]: the latest view of each action
//! that learned) and sends it; the planner recomputes those actions' rows of its own effect
//! table, plans if they moved enough (warm-started from its previous values) and writes the
//! values and policy back into it; the acting side adopts them and keeps the buffer for the
//! next round. At most one plan is in flight; the acting side never allocates after warm-up
//! and never touches the effect table, whose refresh (an `exp` per state and effect) is the
//! expensive part of learning. On Linux the planner thread runs under `SCHED_IDLE` (else at
//! nice +19): any other thread that wakes — the acting loop, the bridge, perception —
//! preempts it at once, so on a machine with few cores background planning never delays an
//! action. (A merely niced thread is let finish its time slice first, which delays the
//! action behind it.)
//!
//! An acting loop that spins instead of sleeping can do the same work itself, in slices
//! between its polls ([`SlicedPlanner`]; [`Planner`] is either): on two cores a spinning loop
//! leaves a planner thread almost no time.
//!
//! ```
//! use std::sync::Arc;
//! use tes_learning::cmdp::CmdpStructure;
//! use tes_learning::plan::{PlannedModel, PlannerParams};
//! use tes_controller::realtime::PlannerThread;
//!
//! let features: [&[u32]; 2] = [&[0], &[0]];
//! let structure = Arc::new(CmdpStructure::new(
//!     2, 2, 2, 1,
//!     |s, e| if e == 0 { 1 } else { s },
//!     vec![0.0, 1.0],
//!     vec![false, true],
//!     |s| features[s],
//! )?);
//! let mut model = PlannedModel::new(structure.clone(), PlannerParams::default())?;
//! model.plan_elsewhere();
//! model.set(0, 0, &[0.1, 0.9]);
//! model.set(1, 0, &[0.8, 0.2]);
//! let mut planner = PlannerThread::spawn(structure, PlannerParams::default())?;
//! assert!(planner.offer(&mut model)?);
//! let stats = planner.wait(&mut model, std::time::Duration::from_secs(5))?;
//! assert!(stats.is_some());
//! assert_eq!(model.action(0), 1);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use crossbeam::channel::{self, Receiver, RecvTimeoutError, Sender, TryRecvError};
use tes_runtime::affinity::{AffinityError, check_cpu, pin_this_thread};
use thiserror::Error;

use tes_runtime::background::Background;

use tes_learning::cmdp::{CmdpError, CmdpStructure};
use tes_learning::plan::{
    ChangeError, ModelChanges, Pieces, PlanError, PlanStats, PlannedModel, PlannerParams,
};

/// Why the planner thread failed.
#[derive(Debug, Error)]
pub enum PlannerThreadError {
    /// Bad planner settings.
    #[error("planner settings: {0}")]
    Settings(#[from] PlanError),
    /// The model does not fit the planner's state space.
    #[error("model: {0}")]
    Shape(#[from] CmdpError),
    /// The planner could not apply the model's changes.
    #[error("planner: {0}")]
    Changes(#[from] ChangeError),
    /// The OS refused to start the thread.
    #[error("cannot start the planner thread: {0}")]
    Spawn(std::io::Error),
    /// The CPU asked for the planner thread cannot be used.
    #[error("planner thread: {0}")]
    Affinity(#[from] AffinityError),
    /// The planner thread is gone (it panicked).
    #[error("the planner thread stopped")]
    Gone,
}

/// The buffer a plan travels in.
#[derive(Debug)]
struct PlanJob {
    changes: ModelChanges,
    values: Vec<f64>,
    policy: Vec<u32>,
    stats: PlanStats,
    /// [`PlannedModel::plan_span`] of the planner's model after the plan.
    backup_span: f64,
    /// Set by the planner when the changes could not be applied.
    error: Option<ChangeError>,
}

/// How a [`PlannerThread`] runs ([`PlannerThread::spawn_with`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PlannerThreadOptions {
    /// The CPU it is pinned to (`None`: unpinned).
    pub cpu: Option<usize>,
    /// How long it polls for the next job after finishing a plan before it sleeps (zero:
    /// sleeps at once). Under `SCHED_IDLE` the poll takes only time nobody else wants, and it
    /// keeps its CPU out of the idle halt: a process woken meanwhile (the bridge, on a
    /// command) is put on that CPU and runs at once, where a halted virtual CPU takes tens
    /// of µs to come back. And the next hand-over wakes no sleeping thread.
    pub idle_spin: Duration,
}

/// The next job for the planner thread: polled for up to `spin`, then waited for.
fn next_job(
    jobs: &Receiver<Box<PlanJob>>,
    spin: Duration,
) -> Result<Box<PlanJob>, channel::RecvError> {
    if !spin.is_zero() {
        let start = std::time::Instant::now();
        loop {
            match jobs.try_recv() {
                Ok(job) => return Ok(job),
                Err(TryRecvError::Disconnected) => return Err(channel::RecvError),
                Err(TryRecvError::Empty) if start.elapsed() >= spin => break,
                Err(TryRecvError::Empty) => std::hint::spin_loop(),
            }
        }
    }
    jobs.recv()
}

/// Value iteration on its own thread.
#[derive(Debug)]
pub struct PlannerThread {
    to_planner: Option<Sender<Box<PlanJob>>>,
    from_planner: Receiver<Box<PlanJob>>,
    /// The job buffer while it is on this side (`None` while a plan is in flight).
    spare: Option<Box<PlanJob>>,
    /// A finished plan received by [`settle`](Self::settle), not yet adopted.
    ready: Option<Box<PlanJob>>,
    handle: Option<JoinHandle<()>>,
    /// The thread's priority, raised back to normal when it is dropped.
    priority: Arc<Background>,
    plans: u64,
}

impl PlannerThread {
    /// Starts the planner thread for `structure` with `params` (each plan runs until the
    /// tolerance or `params.max_sweeps`).
    pub fn spawn(
        structure: Arc<CmdpStructure>,
        params: PlannerParams,
    ) -> Result<Self, PlannerThreadError> {
        Self::spawn_on(structure, params, None)
    }

    /// [`spawn`](Self::spawn), the thread pinned to `cpu` if given (checked first: a CPU this
    /// process may not run on is refused). Pinning it away from the acting thread's CPU keeps
    /// planning from cooling that CPU's caches between actions.
    pub fn spawn_on(
        structure: Arc<CmdpStructure>,
        params: PlannerParams,
        cpu: Option<usize>,
    ) -> Result<Self, PlannerThreadError> {
        Self::spawn_with(
            structure,
            params,
            PlannerThreadOptions {
                cpu,
                idle_spin: Duration::ZERO,
            },
        )
    }

    /// [`spawn`](Self::spawn) with `options`: where the thread runs, and how long it polls
    /// for its next job after a plan before it sleeps.
    pub fn spawn_with(
        structure: Arc<CmdpStructure>,
        params: PlannerParams,
        options: PlannerThreadOptions,
    ) -> Result<Self, PlannerThreadError> {
        let PlannerThreadOptions { cpu, idle_spin } = options;
        if let Some(cpu) = cpu {
            check_cpu(cpu)?;
        }
        // The planner's own copy of the model: inline, so it refreshes rows and plans here.
        let mut model = PlannedModel::new(structure.clone(), params)?;
        let n = structure.n_states();
        let job = Box::new(PlanJob {
            changes: ModelChanges::new(&structure),
            values: vec![0.0; n],
            policy: vec![0; n],
            stats: model.last_plan(),
            backup_span: 0.0,
            error: None,
        });
        let (to_planner, jobs) = channel::bounded::<Box<PlanJob>>(1);
        let (done, from_planner) = channel::bounded::<Box<PlanJob>>(1);
        let priority = Arc::new(Background::new());
        let lowered = priority.clone();
        let handle = std::thread::Builder::new()
            .name("planner".into())
            .spawn(move || {
                if let Some(cpu) = cpu
                    && let Err(e) = pin_this_thread(cpu)
                {
                    tracing::warn!(error = %e, "the planner thread runs unpinned");
                }
                // Polling at a priority above SCHED_IDLE would take time from others.
                let idle_spin = if lowered.lower() {
                    idle_spin
                } else {
                    Duration::ZERO
                };
                // Ends when the acting side drops its sender.
                while let Ok(mut job) = next_job(&jobs, idle_spin) {
                    // In as few pieces as it takes; no plan when the changes moved no backup
                    // by the tolerance.
                    let mut pieces = model.begin_pieces(&job.changes);
                    job.error = loop {
                        match model.advance(&job.changes, &mut pieces, usize::MAX) {
                            Ok(false) => continue,
                            Ok(true) => break None,
                            Err(e) => break Some(e),
                        }
                    };
                    job.stats = model.last_plan();
                    job.backup_span = model.plan_span();
                    job.values.copy_from_slice(model.planner().values());
                    job.policy.copy_from_slice(model.planner().policy());
                    if done.send(job).is_err() {
                        break;
                    }
                }
            })
            .map_err(PlannerThreadError::Spawn)?;
        Ok(Self {
            to_planner: Some(to_planner),
            from_planner,
            spare: Some(job),
            ready: None,
            handle: Some(handle),
            priority,
            plans: 0,
        })
    }

    /// Whether a plan is being made.
    pub fn busy(&self) -> bool {
        self.spare.is_none()
    }

    /// Plans adopted so far.
    pub fn plans(&self) -> u64 {
        self.plans
    }

    /// Hands the planner a snapshot of `model` if the planner is idle and the model needs a
    /// plan; returns whether it did. Allocation-free.
    pub fn offer(&mut self, model: &mut PlannedModel) -> Result<bool, PlannerThreadError> {
        if !model.needs_plan() {
            return Ok(false);
        }
        let Some(mut job) = self.spare.take() else {
            return Ok(false);
        };
        if let Err(e) = model.snapshot_into(&mut job.changes) {
            self.spare = Some(job);
            return Err(e.into());
        }
        let sender = self.to_planner.as_ref().ok_or(PlannerThreadError::Gone)?;
        sender.send(job).map_err(|_| PlannerThreadError::Gone)?;
        Ok(true)
    }

    /// Adopts a finished plan into `model` if one is ready. Allocation-free.
    pub fn collect(
        &mut self,
        model: &mut PlannedModel,
    ) -> Result<Option<PlanStats>, PlannerThreadError> {
        if let Some(job) = self.ready.take() {
            return self.adopt(job, model).map(Some);
        }
        match self.from_planner.try_recv() {
            Ok(job) => self.adopt(job, model).map(Some),
            Err(TryRecvError::Empty) => Ok(None),
            Err(TryRecvError::Disconnected) => Err(PlannerThreadError::Gone),
        }
    }

    /// Waits up to `timeout` for the plan in flight and adopts it (for start-up and tests).
    pub fn wait(
        &mut self,
        model: &mut PlannedModel,
        timeout: Duration,
    ) -> Result<Option<PlanStats>, PlannerThreadError> {
        if !self.busy() {
            return Ok(None);
        }
        if let Some(job) = self.ready.take() {
            return self.adopt(job, model).map(Some);
        }
        match self.from_planner.recv_timeout(timeout) {
            Ok(job) => self.adopt(job, model).map(Some),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => Err(PlannerThreadError::Gone),
        }
    }

    /// Waits up to `timeout` for the plan in flight to finish, without adopting it: the next
    /// [`collect`](Self::collect) does. Returns whether no plan is left in the making. For
    /// tests and replays that need the plan adopted at a known observation.
    pub fn settle(&mut self, timeout: Duration) -> Result<bool, PlannerThreadError> {
        if !self.busy() || self.ready.is_some() {
            return Ok(true);
        }
        match self.from_planner.recv_timeout(timeout) {
            Ok(job) => {
                self.ready = Some(job);
                Ok(true)
            }
            Err(RecvTimeoutError::Timeout) => Ok(false),
            Err(RecvTimeoutError::Disconnected) => Err(PlannerThreadError::Gone),
        }
    }

    fn adopt(
        &mut self,
        mut job: Box<PlanJob>,
        model: &mut PlannedModel,
    ) -> Result<PlanStats, PlannerThreadError> {
        let stats = job.stats;
        if let Some(e) = job.error.take() {
            self.spare = Some(job);
            return Err(e.into());
        }
        // Swapped, not copied: the acting thread never reads the plan the other CPU wrote
        // until it acts on a state of it; the job takes the old buffers back, which the
        // planner overwrites.
        let adopted =
            model.adopt_swapping(&mut job.values, &mut job.policy, stats, job.backup_span);
        self.spare = Some(job);
        adopted?;
        self.plans += 1;
        Ok(stats)
    }
}

/// Value iteration on the acting thread, in slices between the polls of a spinning wait.
///
/// With `wait = "spin"` the acting thread polls for the next observation without sleeping,
/// and on two cores the busy-polling acting loop and bridge leave a planner thread that
/// yields to everything almost no time, so the policy lags far behind learning. Planning
/// between polls turns the spinning into the planning: each [`work`](Self::work) call does
/// about `slice` states' worth of it (a few microseconds), so an observation that arrives
/// mid-slice waits at most one slice. The work and its order are the planner thread's
/// ([`PlannedModel::advance`]), so the plans are the same, bit for bit; the protocol
/// ([`offer`](Self::offer), [`collect`](Self::collect)) is [`PlannerThread`]'s.
///
/// ```
/// use std::sync::Arc;
/// use tes_learning::cmdp::CmdpStructure;
/// use tes_learning::plan::{PlannedModel, PlannerParams};
/// use tes_controller::realtime::SlicedPlanner;
///
/// let features: [&[u32]; 2] = [&[0], &[0]];
/// let structure = Arc::new(CmdpStructure::new(
///     2, 2, 2, 1,
///     |s, e| if e == 0 { 1 } else { s },
///     vec![0.0, 1.0],
///     vec![false, true],
///     |s| features[s],
/// )?);
/// let mut model = PlannedModel::new(structure.clone(), PlannerParams::default())?;
/// model.plan_elsewhere();
/// model.set(0, 0, &[0.1, 0.9]);
/// model.set(1, 0, &[0.8, 0.2]);
/// let mut planner = SlicedPlanner::new(structure, PlannerParams::default(), 1)?;
/// assert!(planner.offer(&mut model)?);
/// while planner.work() {} // between polls, one slice at a time
/// assert!(planner.collect(&mut model)?.is_some());
/// assert_eq!(model.action(0), 1);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug)]
pub struct SlicedPlanner {
    /// The planner's own copy of the model, as on a planner thread.
    model: PlannedModel,
    changes: ModelChanges,
    /// Where the work offered last stands ([`Pieces::DONE`] when there is none).
    pieces: Pieces,
    /// Whether a plan was offered and not yet collected.
    busy: bool,
    /// Set when the changes could not be applied.
    error: Option<ChangeError>,
    /// Set when a plan adopted between polls could not be; reported by the next
    /// [`collect`](Self::collect).
    failed: Option<PlannerThreadError>,
    slice: usize,
    plans: u64,
    /// While set, a finished plan is not adopted ([`hold`](Self::hold)).
    held: bool,
}

impl SlicedPlanner {
    /// A planner for `structure` with `params`, doing about `slice` states' worth of work per
    /// [`work`](Self::work) call (at least 1).
    pub fn new(
        structure: Arc<CmdpStructure>,
        params: PlannerParams,
        slice: usize,
    ) -> Result<Self, PlannerThreadError> {
        Ok(Self {
            model: PlannedModel::new(structure.clone(), params)?,
            changes: ModelChanges::new(&structure),
            pieces: Pieces::DONE,
            busy: false,
            error: None,
            failed: None,
            slice: slice.max(1),
            plans: 0,
            held: false,
        })
    }

    /// Whether a plan is being made (or made and not yet collected).
    pub fn busy(&self) -> bool {
        self.busy
    }

    /// While `hold` is set, [`collect`](Self::collect) adopts nothing, finished or not: a
    /// replay adopts each plan at the observation the recorded run did.
    pub fn hold(&mut self, hold: bool) {
        self.held = hold;
    }

    /// Plans adopted so far.
    pub fn plans(&self) -> u64 {
        self.plans
    }

    /// Takes a snapshot of `model`'s changes if no plan is in progress and the model needs
    /// one; returns whether it did. Allocation-free.
    pub fn offer(&mut self, model: &mut PlannedModel) -> Result<bool, PlannerThreadError> {
        if self.busy || !model.needs_plan() {
            return Ok(false);
        }
        model.snapshot_into(&mut self.changes)?;
        self.pieces = self.model.begin_pieces(&self.changes);
        self.error = None;
        self.busy = true;
        Ok(true)
    }

    /// Does one slice of the plan in progress; returns whether work is left. Allocation-free.
    pub fn work(&mut self) -> bool {
        if self.pieces.done() {
            return false;
        }
        match self
            .model
            .advance(&self.changes, &mut self.pieces, self.slice)
        {
            Ok(done) => !done,
            Err(e) => {
                self.error = Some(e);
                self.pieces = Pieces::DONE;
                false
            }
        }
    }

    /// One slice of the plan in progress, or, once it is finished, its adoption into `model`
    /// (a copy of the values and policy: about a slice's time);
    /// returns whether work is left. Adopting here, while the acting loop waits, keeps it off
    /// the next decision. An adoption that fails is reported by the next
    /// [`collect`](Self::collect). Allocation-free.
    pub fn work_then_adopt(&mut self, model: &mut PlannedModel) -> bool {
        if self.work() {
            return true;
        }
        if let Err(e) = self.collect(model) {
            self.failed = Some(e);
        }
        false
    }

    /// Adopts the plan into `model` if it is finished (and reports a failed adoption of
    /// [`work_then_adopt`](Self::work_then_adopt)). Allocation-free.
    pub fn collect(
        &mut self,
        model: &mut PlannedModel,
    ) -> Result<Option<PlanStats>, PlannerThreadError> {
        if let Some(e) = self.failed.take() {
            return Err(e);
        }
        if self.held || !self.busy || !self.pieces.done() {
            return Ok(None);
        }
        self.busy = false;
        if let Some(e) = self.error.take() {
            return Err(e.into());
        }
        let stats = self.model.last_plan();
        model.adopt(
            self.model.planner().values(),
            self.model.planner().policy(),
            stats,
            self.model.plan_span(),
        )?;
        self.plans += 1;
        Ok(Some(stats))
    }

    /// Finishes the plan in progress on the calling thread, at most `timeout`, and adopts it
    /// (for start-up and tests).
    pub fn wait(
        &mut self,
        model: &mut PlannedModel,
        timeout: Duration,
    ) -> Result<Option<PlanStats>, PlannerThreadError> {
        let start = std::time::Instant::now();
        while self.work() {
            if start.elapsed() > timeout {
                return Ok(None);
            }
        }
        self.collect(model)
    }
}

/// Who plans for an acting loop: a [`PlannerThread`], the acting thread itself between
/// polls ([`SlicedPlanner`]), or the acting thread at each hand-over. The same protocol
/// either way.
#[derive(Debug)]
pub enum Planner {
    /// On its own thread.
    Thread(PlannerThread),
    /// On the acting thread, between polls.
    BetweenPolls(Box<SlicedPlanner>),
    /// On the acting thread, the whole plan at each hand-over ([`offer`](Self::offer)),
    /// adopted at the next [`collect`](Self::collect): every plan is adopted one observation
    /// after its hand-over, whatever the timing. For replays and tests, not for real time (a
    /// plan can take milliseconds).
    Inline(Box<SlicedPlanner>),
}

impl Planner {
    /// See [`PlannerThread::offer`] (inline: and makes the plan).
    pub fn offer(&mut self, model: &mut PlannedModel) -> Result<bool, PlannerThreadError> {
        match self {
            Self::Thread(p) => p.offer(model),
            Self::BetweenPolls(p) => p.offer(model),
            Self::Inline(p) => {
                let offered = p.offer(model)?;
                while p.work() {}
                Ok(offered)
            }
        }
    }

    /// Waits up to `timeout` for the plan in flight to finish without adopting it (between
    /// polls: does its slices); returns whether none is left in the making. See
    /// [`PlannerThread::settle`].
    pub fn settle(&mut self, timeout: Duration) -> Result<bool, PlannerThreadError> {
        match self {
            Self::Thread(p) => p.settle(timeout),
            Self::BetweenPolls(p) | Self::Inline(p) => {
                let start = std::time::Instant::now();
                while p.work() {
                    if start.elapsed() > timeout {
                        return Ok(false);
                    }
                }
                Ok(true)
            }
        }
    }

    /// See [`PlannerThread::collect`].
    pub fn collect(
        &mut self,
        model: &mut PlannedModel,
    ) -> Result<Option<PlanStats>, PlannerThreadError> {
        match self {
            Self::Thread(p) => p.collect(model),
            Self::BetweenPolls(p) | Self::Inline(p) => p.collect(model),
        }
    }

    /// See [`PlannerThread::wait`].
    pub fn wait(
        &mut self,
        model: &mut PlannedModel,
        timeout: Duration,
    ) -> Result<Option<PlanStats>, PlannerThreadError> {
        match self {
            Self::Thread(p) => p.wait(model, timeout),
            Self::BetweenPolls(p) | Self::Inline(p) => p.wait(model, timeout),
        }
    }

    /// One slice of planning, or the adoption of a finished plan into `model`, when planning
    /// happens between polls (see [`SlicedPlanner::work_then_adopt`]); returns whether work
    /// is left. A planner thread needs none, nor does an inline planner: `false`.
    pub fn work(&mut self, model: &mut PlannedModel) -> bool {
        match self {
            Self::Thread(_) | Self::Inline(_) => false,
            Self::BetweenPolls(p) => p.work_then_adopt(model),
        }
    }

    /// Plans adopted so far.
    pub fn plans(&self) -> u64 {
        match self {
            Self::Thread(p) => p.plans(),
            Self::BetweenPolls(p) | Self::Inline(p) => p.plans(),
        }
    }

    /// Holds back (or releases) the adoption of finished plans ([`SlicedPlanner::hold`]);
    /// returns whether this planner can (a planner thread cannot).
    pub fn hold(&mut self, hold: bool) -> bool {
        match self {
            Self::Thread(_) => false,
            Self::BetweenPolls(p) | Self::Inline(p) => {
                p.hold(hold);
                true
            }
        }
    }
}

impl Drop for PlannerThread {
    fn drop(&mut self) {
        // Closing the channel ends the thread after its current plan. Under SCHED_IDLE on a
        // busy machine that plan could take seconds, and the run's end (the final library
        // save) would wait for it: the thread is raised back to normal priority first, and
        // left to end on its own where it cannot be (its plan is no longer wanted).
        self.to_planner = None;
        let raised = self.priority.restore();
        if let Some(handle) = self.handle.take()
            && raised
        {
            let _ = handle.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tes_learning::cmdp::examples::corridor;

    /// Every way of planning elsewhere: the thread, and between polls in slices of 1 state
    /// (the finest cut), 7 (cuts falling anywhere) and more than a whole sweep.
    fn planners(c: &Arc<CmdpStructure>, params: PlannerParams) -> Vec<Planner> {
        let mut all = vec![Planner::Thread(
            PlannerThread::spawn(c.clone(), params).unwrap(),
        )];
        for slice in [1, 7, 1000] {
            all.push(Planner::BetweenPolls(Box::new(
                SlicedPlanner::new(c.clone(), params, slice).unwrap(),
            )));
        }
        all
    }

    /// Waits for `planner`'s plan (doing its slices, if it plans between polls; with slices
    /// of 7, as the acting loop does: adopting it as the last piece of work).
    fn finish(planner: &mut Planner, model: &mut PlannedModel) -> PlanStats {
        if let Planner::BetweenPolls(p) = planner {
            assert!(
                p.collect(model).unwrap().is_none(),
                "not finished before its slices"
            );
            if p.slice == 7 {
                while planner.work(model) {}
                assert!(planner.collect(model).unwrap().is_none(), "adopted already");
                return model.last_plan();
            }
        }
        planner
            .wait(model, Duration::from_secs(10))
            .unwrap()
            .expect("a plan within 10 s")
    }

    /// A planner thread that polls between jobs plans the same as one that sleeps, and ends
    /// when the acting side goes, polling or not.
    #[test]
    fn a_polling_planner_thread_plans_the_same_and_ends_with_its_owner() {
        let c = Arc::new(corridor(9, &[]));
        let params = PlannerParams::default();
        for idle_spin in [Duration::ZERO, Duration::from_millis(50)] {
            let mut planner = PlannerThread::spawn_with(
                c.clone(),
                params,
                PlannerThreadOptions {
                    cpu: None,
                    idle_spin,
                },
            )
            .unwrap();
            let mut offloaded = PlannedModel::new(c.clone(), params).unwrap();
            offloaded.plan_elsewhere();
            let mut inline = PlannedModel::new(c.clone(), params).unwrap();
            for round in 0..3 {
                let p = 0.6 + 0.1 * round as f64;
                for s in 0..9 {
                    for m in [&mut offloaded, &mut inline] {
                        m.set(0, s, &[p, 1.0 - p, 0.0]);
                    }
                }
                assert!(planner.offer(&mut offloaded).unwrap());
                assert!(planner.settle(Duration::from_secs(10)).unwrap());
                let stats = planner.collect(&mut offloaded).unwrap();
                assert_eq!(stats, inline.replan(), "{idle_spin:?}");
                assert_eq!(offloaded.planner().policy(), inline.planner().policy());
            }
            // Dropping joins the thread: it must see the closed channel while polling.
            let started = std::time::Instant::now();
            drop(planner);
            assert!(started.elapsed() < Duration::from_secs(5), "{idle_spin:?}");
        }
    }

    #[test]
    fn plans_made_elsewhere_equal_inline_plans() {
        let c = Arc::new(corridor(9, &[]));
        let params = PlannerParams {
            max_sweeps: 10_000,
            ..PlannerParams::default()
        };
        for mut planner in planners(&c, params) {
            let mut offloaded = PlannedModel::new(c.clone(), params).unwrap();
            offloaded.plan_elsewhere();
            let mut inline = PlannedModel::new(c.clone(), params).unwrap();
            for round in 0..5 {
                let p = 0.5 + 0.1 * round as f64;
                for s in 0..9 {
                    for m in [&mut offloaded, &mut inline] {
                        m.set(0, s, &[p, 1.0 - p, 0.0]);
                        m.set(1, s, &[1.0 - p, p, 0.0]);
                    }
                }
                assert!(offloaded.replan().is_none(), "not planned inline");
                assert!(planner.offer(&mut offloaded).unwrap());
                assert!(
                    !planner.offer(&mut offloaded).unwrap(),
                    "one plan in flight"
                );
                let stats = finish(&mut planner, &mut offloaded);
                assert!(stats.converged);
                assert_eq!(Some(stats), inline.replan());
                assert_eq!(offloaded.planner().values(), inline.planner().values());
                assert_eq!(offloaded.planner().policy(), inline.planner().policy());
            }
            assert_eq!(planner.plans(), 5);
            assert!(!offloaded.needs_plan());
            assert!(planner.collect(&mut offloaded).unwrap().is_none());
            assert!(!planner.work(&mut offloaded), "nothing left to do");
        }
    }

    #[test]
    fn views_refreshed_elsewhere_plan_like_views_refreshed_inline() {
        use tes_learning::cmdp::EffectTable;
        use tes_learning::mdagl::{Features, Mdagl, MdaglParams};
        let c = Arc::new(corridor(9, &[3, 4]));
        let params = PlannerParams {
            max_sweeps: 10_000,
            ..PlannerParams::default()
        };
        for mut planner in planners(&c, params) {
            let mut offloaded = PlannedModel::new(c.clone(), params).unwrap();
            offloaded.plan_elsewhere();
            let mut inline = PlannedModel::new(c.clone(), params).unwrap();
            let mut views = [0, 1].map(|_| Mdagl::new(3, 2, MdaglParams::default()).unwrap());
            for round in 0..6 {
                // Action 0 moves left, action 1 right, except on the slippery cells
                // (feature 1).
                let a = round % 2;
                for s in 1..8 {
                    let x = c.features(s);
                    let effect = if x.contains(&1) { 2 } else { a };
                    views[a].update(Features::SparseBinary(x), effect).unwrap();
                }
                for m in [&mut offloaded, &mut inline] {
                    m.refresh(a, &views[a]).unwrap();
                }
                assert_eq!(
                    offloaded.table(),
                    &EffectTable::uniform(&c),
                    "the acting side's table is left to the planner"
                );
                assert!(planner.offer(&mut offloaded).unwrap());
                let stats = finish(&mut planner, &mut offloaded);
                assert_eq!(Some(stats), inline.replan());
                assert_eq!(offloaded.planner().values(), inline.planner().values());
                assert_eq!(offloaded.planner().policy(), inline.planner().policy());
            }
            // Refused before anything is handed over: a view of another shape.
            let wrong = Mdagl::new(4, 2, MdaglParams::default()).unwrap();
            assert!(offloaded.refresh(0, &wrong).is_err());
            assert!(!offloaded.needs_plan());
        }
    }
}
