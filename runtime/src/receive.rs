//! How a receiver waits for its next message: polls its source and, between polls, spins,
//! sleeps on its listener or (with `anticipate`) sleeps until shortly before the message is
//! due, as its [`WaitStrategy`] says. [`Inbox`](crate::channel::Inbox) and
//! [`LatestInbox`](crate::board::LatestInbox) both wait this way.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::prelude::*;
use iceoryx2::service::Service;

use crate::anticipate::{Anticipation, Step};
use crate::clock::monotonic_ns;
use crate::ipc::{IpcError, Listener, ipc_err};
use crate::wait::WaitStrategy;

/// Why [`Inbox::next`](crate::channel::Inbox::next) returned without a sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Idle {
    /// The timeout passed.
    Timeout,
    /// The stop flag was raised.
    Stopped,
}

/// How often a blocking wait looks at the stop flag.
const STOP_POLL: Duration = Duration::from_millis(50);

/// Polls `try_next` and waits between polls by `strategy` on `listener`, at most `timeout`,
/// calling `work` between polls while spinning; returns early when `stop` is raised.
/// Allocation-free in `spin`; `block` sleeps in the kernel; `anticipate` (with its
/// `anticipation`) sleeps until shortly before the next message is due.
pub(crate) fn wait_next<T, S: Service>(
    listener: &Listener<S>,
    strategy: WaitStrategy,
    anticipation: Option<&Anticipation<S>>,
    timeout: Duration,
    stop: &AtomicBool,
    mut try_next: impl FnMut() -> Result<Option<T>, IpcError>,
    mut work: impl FnMut() -> bool,
) -> Result<Result<T, Idle>, IpcError>
where
    Listener<S>: FileDescriptorBased,
{
    if let Some(a) = anticipation {
        return wait_anticipating(listener, a, timeout, stop, try_next, work);
    }
    let start = Instant::now();
    let spin_for = match strategy {
        WaitStrategy::Block | WaitStrategy::Anticipate | WaitStrategy::Auto => Duration::ZERO,
        WaitStrategy::Spin => timeout,
        WaitStrategy::SpinThenBlock(d) => d.min(timeout),
    };
    let mut polls: u32 = 0;
    loop {
        if let Some(v) = try_next()? {
            return Ok(Ok(v));
        }
        let waited = start.elapsed();
        if waited >= spin_for {
            break;
        }
        polls = polls.wrapping_add(1);
        if polls.is_multiple_of(1024) && stop.load(Ordering::Relaxed) {
            return Ok(Err(Idle::Stopped));
        }
        if !work() {
            std::hint::spin_loop();
        }
    }
    loop {
        if stop.load(Ordering::Relaxed) {
            return Ok(Err(Idle::Stopped));
        }
        let left = timeout.saturating_sub(start.elapsed());
        if left.is_zero() {
            return Ok(Err(Idle::Timeout));
        }
        // Sleep until the listener's socket is readable or the time is up, then drain
        // every pending notification and look again: a value sent between the last look
        // and the wait still wakes us, because its notification is pending.
        wait_readable(listener, left.min(STOP_POLL))?;
        drain(listener)?;
        if let Some(v) = try_next()? {
            return Ok(Ok(v));
        }
    }
}

/// How close to its poll window an anticipating receiver stops watching for messages and
/// sleeps by the timer alone: a message early by more than this still wakes it at once.
const FINAL_APPROACH: Duration = Duration::from_millis(2);

/// The `anticipate` wait ([`crate::anticipate`]): sleeps until the model's poll window (a
/// message or a heads-up wakes it earlier), polls through the window calling `work`, and
/// blocks once the window has passed.
fn wait_anticipating<T, S: Service>(
    listener: &Listener<S>,
    anticipation: &Anticipation<S>,
    timeout: Duration,
    stop: &AtomicBool,
    mut try_next: impl FnMut() -> Result<Option<T>, IpcError>,
    mut work: impl FnMut() -> bool,
) -> Result<Result<T, Idle>, IpcError>
where
    Listener<S>: FileDescriptorBased,
{
    let start = Instant::now();
    let heads_up = anticipation.heads_up_listener();
    let model = &anticipation.model;
    loop {
        if let Some(v) = try_next()? {
            model.borrow_mut().arrived(monotonic_ns(), false);
            return Ok(Ok(v));
        }
        if stop.load(Ordering::Relaxed) {
            return Ok(Err(Idle::Stopped));
        }
        let left = timeout.saturating_sub(start.elapsed());
        if left.is_zero() {
            return Ok(Err(Idle::Timeout));
        }
        anticipation.take_heads_ups()?;
        let now = monotonic_ns();
        let step = model.borrow_mut().step(now);
        match step {
            Step::SleepUntil(until) => {
                anticipation.lower_to_sleep();
                let nap = Duration::from_nanos(until - now);
                if nap <= FINAL_APPROACH && nap <= left {
                    // The last stretch by the timer alone: a wait on the listeners comes back
                    // hundreds of µs late here, when the message itself wakes it.
                    std::thread::sleep(nap);
                    model.borrow_mut().woke(until, monotonic_ns());
                } else {
                    let nap = nap.saturating_sub(FINAL_APPROACH);
                    wait_readable_any(listener, heads_up, nap.min(left).min(STOP_POLL))?;
                    drain(listener)?;
                }
            }
            Step::PollUntil(until) => {
                anticipation.raise_for_window();
                loop {
                    if let Some(v) = try_next()? {
                        model.borrow_mut().arrived(monotonic_ns(), true);
                        return Ok(Ok(v));
                    }
                    // Every look: a yield may give the CPU away for a while.
                    if monotonic_ns() >= until || stop.load(Ordering::Relaxed) {
                        break;
                    }
                    if work() {
                        continue;
                    }
                    if anticipation.alone {
                        std::hint::spin_loop();
                    } else {
                        // The window is shared with the sender, which must run to send: on
                        // a machine with fewer CPUs than busy threads, a poll that keeps
                        // its CPU would hold the message up.
                        std::thread::yield_now();
                    }
                }
            }
            Step::Block => {
                anticipation.lower_to_sleep();
                wait_readable_any(listener, heads_up, left.min(STOP_POLL))?;
                drain(listener)?;
            }
        }
    }
}

/// Takes every pending notification of `listener`.
fn drain<S: Service>(listener: &Listener<S>) -> Result<(), IpcError> {
    listener
        .try_wait(|_| {})
        .map(|_| ())
        .map_err(ipc_err("drain the listener"))
}

/// Blocks until the listener's socket is readable or `timeout` passes, by `ppoll(2)`:
/// timer-precise, unlike iceoryx2 0.10's `Listener::timed_wait` (a socket receive
/// timeout, which the kernel rounds up to its scheduler tick, milliseconds for any shorter
/// timeout). A signal ends the wait early (the caller looks at its stop flag).
pub(crate) fn wait_readable<S: Service>(
    listener: &Listener<S>,
    timeout: Duration,
) -> Result<(), IpcError>
where
    Listener<S>: FileDescriptorBased,
{
    wait_readable_any(listener, None, timeout).map(|_| ())
}

/// [`wait_readable`] on `listener` and, if given, a second listener (an anticipating
/// receiver's heads-up); returns whether either became readable.
fn wait_readable_any<S: Service>(
    listener: &Listener<S>,
    other: Option<&Listener<S>>,
    timeout: Duration,
) -> Result<bool, IpcError>
where
    Listener<S>: FileDescriptorBased,
{
    use nix::poll::{PollFd, PollFlags, ppoll};
    use std::os::fd::BorrowedFd;
    // SAFETY: the descriptors belong to the listeners, which outlive this call.
    let fd =
        |l: &Listener<S>| unsafe { BorrowedFd::borrow_raw(l.file_descriptor().native_handle()) };
    let mut fds = [
        PollFd::new(fd(listener), PollFlags::POLLIN),
        PollFd::new(fd(other.unwrap_or(listener)), PollFlags::POLLIN),
    ];
    let n = if other.is_some() { 2 } else { 1 };
    match ppoll(
        &mut fds[..n],
        Some(nix::sys::time::TimeSpec::from_duration(timeout)),
        None,
    ) {
        Ok(ready) => Ok(ready > 0),
        Err(nix::errno::Errno::EINTR) => Ok(true),
        Err(e) => Err(ipc_err("wait on the listener")(e)),
    }
}
