//! Every CPU kept out of its idle state while a floor runs: the floor's second measurement.
//!
//! A process group keeps its CPUs busier than a floor that does no work: perception integrates
//! the world, the bridge steps its brick, the launchers forward. On a virtual machine a CPU
//! with nothing to run halts, and the next message's receiver then waits for it to wake
//! (tens of µs on the project's VM). A floor without that help can be slower than the group it
//! is meant to bound. [`KeepAwake`] runs one spinning thread under `SCHED_IDLE` on each CPU:
//! it never delays a thread of normal priority, which preempts it at once, but the CPU never
//! halts — so a floor measured under it pays no wake-up, the least its transport costs on the
//! machine, at the price of every core fully busy.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::thread::JoinHandle;

use tes_runtime::affinity;

use crate::error::{BenchError, Result};

/// Spinning `SCHED_IDLE` threads, one per CPU, until dropped.
#[derive(Debug)]
pub struct KeepAwake {
    stop: Arc<AtomicBool>,
    spinners: Vec<JoinHandle<()>>,
}

impl KeepAwake {
    /// Starts a spinner on each of `cpus` and returns once every one is pinned and runs under
    /// `SCHED_IDLE`. Fails, stopping those already started, if a CPU refuses the pin or the
    /// kernel refuses `SCHED_IDLE` (a spinner at normal priority would take CPU time from
    /// what it is meant to help).
    pub fn start(cpus: &[usize]) -> Result<Self> {
        let mut awake = Self {
            stop: Arc::new(AtomicBool::new(false)),
            spinners: Vec::with_capacity(cpus.len()),
        };
        let (ready_tx, ready) = mpsc::channel();
        for &cpu in cpus {
            let stop = Arc::clone(&awake.stop);
            let ready_tx = ready_tx.clone();
            let spinner = std::thread::Builder::new()
                .name(format!("keep-awake-{cpu}"))
                .spawn(move || {
                    let placed = affinity::pin_this_thread(cpu)
                        .map_err(|e| format!("cannot pin a spinner to CPU {cpu}: {e}"))
                        .and_then(|()| {
                            if affinity::lower_this_threads_priority() {
                                Ok(())
                            } else {
                                Err("the kernel refused SCHED_IDLE for a spinner".to_owned())
                            }
                        });
                    let placed_ok = placed.is_ok();
                    // The receiver outlives every spinner's first message (start waits).
                    let _ = ready_tx.send(placed);
                    if placed_ok {
                        spin_until(&stop);
                    }
                })
                .map_err(BenchError::io("cannot start a spinner".into()))?;
            awake.spinners.push(spinner);
        }
        drop(ready_tx);
        for placed in ready.iter().take(cpus.len()) {
            placed.map_err(BenchError::Run)?;
        }
        Ok(awake)
    }
}

fn spin_until(stop: &AtomicBool) {
    while !stop.load(Ordering::Relaxed) {
        std::hint::spin_loop();
    }
}

impl Drop for KeepAwake {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for spinner in self.spinners.drain(..) {
            // A spinner only loops on the flag: it cannot panic.
            let _ = spinner.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spinners_start_on_every_allowed_cpu_and_stop_when_dropped() {
        let cpus = affinity::allowed_cpus();
        let awake = KeepAwake::start(&cpus).expect("spinners");
        assert_eq!(awake.spinners.len(), cpus.len());
        assert!(awake.spinners.iter().all(|s| !s.is_finished()));
        drop(awake);
    }

    #[test]
    fn a_cpu_that_does_not_exist_is_refused() {
        let err = KeepAwake::start(&[usize::MAX / 2]).expect_err("no such CPU");
        assert!(err.to_string().contains("cannot pin"), "{err}");
    }
}
