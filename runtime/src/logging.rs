//! Logging set-up shared by the TES binaries.

use std::io::IsTerminal;

/// Sends `tracing` events to stderr at the level `RUST_LOG` gives, or `default_level` (e.g.
/// `"info"`, `"warn"`) without it. Colours only when stderr is a terminal, so logs captured by
/// a launcher, a file or a test stay plain text.
pub fn init(default_level: &str) {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_level)),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .init();
}
