//! Logging set-up shared by the TES binaries.

use std::io::IsTerminal;

/// Sends `tracing` events to stderr at the level `RUST_LOG` gives, or `default_level` (e.g.
/// `"info"`, `"warn"`) without it. Colours only when stderr is a terminal, so logs captured by
/// a launcher, a file or a test stay plain text.
pub fn init(default_level: &str) {
    tracing_subscriber::fmt()
        .with_env_filter(env_filter(default_level))
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .init();
}

/// As [`init`], with `extra` beside the log lines: a layer with its own filter (the link's
/// refusals layer in the launcher), which sees the events it asks for whatever level the log
/// lines show. `default_level` `"off"` shows no
/// log line without `RUST_LOG`.
pub fn init_with<L>(default_level: &str, extra: L)
where
    L: tracing_subscriber::Layer<tracing_subscriber::Registry> + Send + Sync + 'static,
{
    use tracing_subscriber::Layer as _;
    use tracing_subscriber::layer::SubscriberExt as _;
    use tracing_subscriber::util::SubscriberInitExt as _;
    let lines = tracing_subscriber::fmt::layer()
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .with_filter(env_filter(default_level));
    // A second subscriber (a test harness's) is left in place.
    let _ = tracing_subscriber::registry()
        .with(extra)
        .with(lines)
        .try_init();
}

/// The level `RUST_LOG` gives, or `default_level` without it.
fn env_filter(default_level: &str) -> tracing_subscriber::EnvFilter {
    tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_level))
}
