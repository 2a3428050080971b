//! Stopping cleanly on SIGINT and SIGTERM.

use std::sync::atomic::AtomicBool;

/// Raises the returned flag on SIGINT or SIGTERM: every TES process stops its loop cleanly on
/// either (saving what it must) instead of dying mid-write.
pub fn stop_on_signals() -> std::io::Result<std::sync::Arc<AtomicBool>> {
    let stop = std::sync::Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, stop.clone())?;
    }
    Ok(stop)
}
