//! The real-time split of acting and planning (Hester & Stone's RTMBA architecture): the
//! acting loop learns and acts on the last finished policy; value iteration runs on its own
//! thread and hands back a fresh policy when done, so a slow plan never delays an action.
//!
//! One job buffer travels between the two threads over crossbeam channels: the acting
//! side copies its effect table into it and sends it; the planner plans (warm-started from its
//! previous values) and writes the values and policy back into it; the acting side adopts them
//! and keeps the buffer for the next round. At most one plan is in flight and the acting side
//! never allocates.
//!
//! ```
//! use std::sync::Arc;
//! use tes_controller::cmdp::CmdpStructure;
//! use tes_controller::plan::{PlannedModel, PlannerParams};
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
//! model.set_inline_planning(false);
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
use thiserror::Error;

use crate::cmdp::{CmdpError, CmdpStructure, EffectTable};
use crate::plan::{PlanError, PlanStats, PlannedModel, PlannerParams, ValueIteration};

/// Why the planner thread failed.
#[derive(Debug, Error)]
pub enum PlannerThreadError {
    /// Bad planner settings.
    #[error("planner settings: {0}")]
    Settings(#[from] PlanError),
    /// The model does not fit the planner's state space.
    #[error("model: {0}")]
    Shape(#[from] CmdpError),
    /// The OS refused to start the thread.
    #[error("cannot start the planner thread: {0}")]
    Spawn(std::io::Error),
    /// The planner thread is gone (it panicked).
    #[error("the planner thread stopped")]
    Gone,
}

/// The buffer a plan travels in.
#[derive(Debug)]
struct PlanJob {
    table: EffectTable,
    values: Vec<f64>,
    policy: Vec<u32>,
    stats: PlanStats,
}

/// Value iteration on its own thread.
#[derive(Debug)]
pub struct PlannerThread {
    to_planner: Option<Sender<Box<PlanJob>>>,
    from_planner: Receiver<Box<PlanJob>>,
    /// The job buffer while it is on this side (`None` while a plan is in flight).
    spare: Option<Box<PlanJob>>,
    handle: Option<JoinHandle<()>>,
    plans: u64,
}

impl PlannerThread {
    /// Starts the planner thread for `structure` with `params` (each plan runs until the
    /// tolerance or `params.max_sweeps`).
    pub fn spawn(
        structure: Arc<CmdpStructure>,
        params: PlannerParams,
    ) -> Result<Self, PlannerThreadError> {
        let mut planner = ValueIteration::new(&structure, params)?;
        let n = structure.n_states();
        let job = Box::new(PlanJob {
            table: EffectTable::uniform(&structure),
            values: vec![0.0; n],
            policy: vec![0; n],
            stats: PlanStats {
                sweeps: 0,
                residual: f64::INFINITY,
                converged: false,
            },
        });
        let (to_planner, jobs) = channel::bounded::<Box<PlanJob>>(1);
        let (done, from_planner) = channel::bounded::<Box<PlanJob>>(1);
        let handle = std::thread::Builder::new()
            .name("planner".into())
            .spawn(move || {
                // Ends when the acting side drops its sender.
                while let Ok(mut job) = jobs.recv() {
                    job.stats = planner.plan(&structure, &job.table);
                    job.values.copy_from_slice(planner.values());
                    job.policy.copy_from_slice(planner.policy());
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
            handle: Some(handle),
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
        if let Err(e) = model.snapshot_into(&mut job.table) {
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
        match self.from_planner.recv_timeout(timeout) {
            Ok(job) => self.adopt(job, model).map(Some),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => Err(PlannerThreadError::Gone),
        }
    }

    fn adopt(
        &mut self,
        job: Box<PlanJob>,
        model: &mut PlannedModel,
    ) -> Result<PlanStats, PlannerThreadError> {
        let stats = job.stats;
        let adopted = model.adopt(&job.values, &job.policy, stats);
        self.spare = Some(job);
        adopted?;
        self.plans += 1;
        Ok(stats)
    }
}

impl Drop for PlannerThread {
    fn drop(&mut self) {
        // Closing the channel ends the thread after its current plan.
        self.to_planner = None;
        if let Some(handle) = self.handle.take() {
            let _ = handle.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cmdp::tests::corridor;

    #[test]
    fn plans_made_on_the_thread_equal_inline_plans() {
        let c = Arc::new(corridor(9, &[]));
        let params = PlannerParams {
            max_sweeps: 10_000,
            ..PlannerParams::default()
        };
        let mut offloaded = PlannedModel::new(c.clone(), params).unwrap();
        offloaded.set_inline_planning(false);
        let mut inline = PlannedModel::new(c.clone(), params).unwrap();
        let mut thread = PlannerThread::spawn(c.clone(), params).unwrap();
        for round in 0..5 {
            let p = 0.5 + 0.1 * round as f64;
            for s in 0..9 {
                for m in [&mut offloaded, &mut inline] {
                    m.set(0, s, &[p, 1.0 - p, 0.0]);
                    m.set(1, s, &[1.0 - p, p, 0.0]);
                }
            }
            assert!(offloaded.replan().is_none(), "not planned inline");
            assert!(thread.offer(&mut offloaded).unwrap());
            assert!(thread.busy());
            assert!(!thread.offer(&mut offloaded).unwrap(), "one plan in flight");
            let stats = thread
                .wait(&mut offloaded, Duration::from_secs(10))
                .unwrap()
                .expect("a plan within 10 s");
            assert!(stats.converged);
            inline.replan();
            assert_eq!(offloaded.planner().values(), inline.planner().values());
            assert_eq!(offloaded.planner().policy(), inline.planner().policy());
        }
        assert_eq!(thread.plans(), 5);
        assert!(!offloaded.needs_plan());
        assert!(thread.collect(&mut offloaded).unwrap().is_none());
    }
}
