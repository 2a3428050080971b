//! How `tes experiment` shows a run going on: a line saying what runs, a progress bar on a
//! terminal (plain lines elsewhere), and what Ctrl-C keeps.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Once;

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use tes_experiments::experiment::Experiment;
use tes_experiments::jobs::{self, JobOptions};
use tes_experiments::progress::ProgressLines;

/// Runs (a share of) an experiment with a line saying what runs (`resuming`: an interrupted
/// run goes on) and a progress bar; `None` for a shard.
pub(super) fn with_progress<E: Experiment>(
    config: &E,
    out: &Path,
    options: JobOptions,
    resuming: bool,
) -> Result<Option<E::Report>> {
    eprintln!(
        "{} experiment: {}{} -> {}",
        E::NAME,
        config.describe(),
        shard_note(options, resuming),
        out.display()
    );
    let bar = progress_bar(E::NAME);
    let report = config.run_with(out, options, &bar.callback())?;
    bar.finish(out, E::NAME, options);
    Ok(report)
}

/// Ctrl-C or SIGTERM stops the run at once and says how to go on: every finished run is
/// already on disk in one of `folders` (its record is written whole or not at all), and
/// `tes experiment WHICH --resume OUT` runs the rest. Installed by the command itself, so a
/// run started with SIGINT ignored (a script's background job) still stops when told to.
pub(super) fn stop_on_interrupt(out: &Path, which: &str, folders: &[PathBuf]) -> Result<()> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM])
        .context("cannot install the signal handlers")?;
    let (out, which, folders) = (out.to_owned(), which.to_owned(), folders.to_owned());
    std::thread::Builder::new()
        .name("interrupt".into())
        .spawn(move || {
            let Some(signal) = signals.forever().next() else {
                return;
            };
            let kept: usize = folders
                .iter()
                .map(|f| jobs::recorded(f).map_or(0, |r| r.len()))
                .sum();
            eprintln!(
                "\nexperiment {which}: interrupted; the {kept} runs recorded in {} are kept; \
                 run the rest with `tes experiment {which} --resume {}`",
                out.display(),
                out.display()
            );
            std::process::exit(128 + signal);
        })
        .context("cannot start the signal thread")?;
    Ok(())
}

fn shard_note(options: JobOptions, resuming: bool) -> String {
    let mut note = String::new();
    if !options.shard.is_all() {
        note.push_str(&format!(", shard {}", options.shard));
    }
    if resuming {
        note.push_str(", resuming");
    }
    note
}

/// Progress on stderr: a bar (runs done, elapsed, the time left) on a terminal; elsewhere (a
/// batch job's log, `nohup`) a plain line at most every [`PROGRESS_LINE_EVERY`](tes_experiments::progress::PROGRESS_LINE_EVERY) and at the
/// end. The estimate is made from the runs finished in this invocation, not those found on
/// resume.
struct Progress {
    bar: ProgressBar,
    first: Once,
    plain: Option<std::sync::Mutex<ProgressLines>>,
}

impl Progress {
    /// The `progress(done, total)` callback the experiments call.
    fn callback(&self) -> impl Fn(u64, u64) + Sync + '_ {
        move |done, total| {
            self.bar.set_length(total);
            self.bar.set_position(done);
            // The first call reports the runs found on resume: the estimate starts after it.
            self.first.call_once(|| self.bar.reset_eta());
            if let Some(plain) = &self.plain
                && let Ok(mut plain) = plain.lock()
            {
                plain.update(done, total);
            }
        }
    }

    fn finish(&self, out: &Path, experiment: &str, options: JobOptions) {
        self.bar.finish_and_clear();
        if !options.shard.is_all() {
            println!(
                "shard {} of the {experiment} experiment written to {}; combine the shards with `tes experiment merge DIR... --out DIR`",
                options.shard,
                out.display()
            );
        }
    }
}

fn progress_bar(what: &str) -> Progress {
    if std::io::stderr().is_terminal() {
        let bar = ProgressBar::with_draw_target(Some(1), ProgressDrawTarget::stderr());
        if let Ok(style) = ProgressStyle::with_template(
            "{msg} [{bar:40}] {pos}/{len} runs ({elapsed} elapsed, ~{eta} left)",
        ) {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.set_message(what.to_owned());
        Progress {
            bar,
            first: Once::new(),
            plain: None,
        }
    } else {
        let now = std::time::Instant::now();
        Progress {
            bar: ProgressBar::hidden(),
            first: Once::new(),
            plain: Some(std::sync::Mutex::new(ProgressLines::new(
                format!("{what} experiment"),
                now,
            ))),
        }
    }
}
