//! `tes launch --record` (the launcher's side of a recording) and `tes replay`.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;
use tes_recorder::live::Recorder;
use tes_recorder::reader::Recording;
use tes_recorder::writer::RunInfo;

use crate::launch::{ChildSpec, LaunchFile};

/// Starts the recorder of a launch if its file asks for one: subscribed to the group's
/// services before any child starts; the run's settings, seed and starting library go into
/// the file's metadata.
pub(crate) fn start(
    file: &LaunchFile,
    specs: &[ChildSpec],
    prefix: &str,
    library: &Path,
) -> Result<Option<Recorder>> {
    let Some(path) = &file.launch.record else {
        return Ok(None);
    };
    let controller_toml = match specs.iter().find(|s| s.role == "controller") {
        Some(spec) => std::fs::read_to_string(&spec.config).with_context(|| {
            format!(
                "cannot read the controller's settings {}",
                spec.config.display()
            )
        })?,
        None => String::new(),
    };
    let library_bytes = match std::fs::read(library) {
        Ok(bytes) => Some(bytes),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => bail!(
            "cannot read the view library {} to record it: {e}; nothing was started",
            library.display()
        ),
    };
    let launch_toml = toml::to_string(&file.launch).unwrap_or_default();
    let wall_ns = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i128);
    let info = RunInfo {
        tes_version: env!("CARGO_PKG_VERSION").to_owned(),
        seed: file.launch.seed,
        service_prefix: prefix.to_owned(),
        controller_toml,
        launch_toml,
        library_path: library.display().to_string(),
        library: library_bytes,
        wall_offset_ns: wall_ns - i128::from(tes_runtime::clock::monotonic_ns()),
    };
    let recorder = Recorder::start(path, prefix, info)
        .with_context(|| format!("cannot record to {}; nothing was started", path.display()))?;
    Ok(Some(recorder))
}

/// Finishes a launch's recording (the group has stopped); the line that says what it holds.
pub(crate) fn finish(recorder: Recorder) -> Result<String> {
    let path = recorder.path().to_owned();
    let counts = recorder
        .stop()
        .with_context(|| format!("the recording {} is incomplete", path.display()))?;
    let [maps, observations, commands, keepalives, motor] = counts.written;
    let _ = maps;
    let missed = counts.missed_observations + counts.missed_commands + counts.missed_motor_states;
    let mut line = format!(
        "launch: recorded {observations} observations, {commands} commands, {keepalives} \
         keep-alives and {motor} motor states to {}",
        path.display()
    );
    if missed > 0 {
        line.push_str(&format!(
            " (missed {} observations, {} commands, {} motor states)",
            counts.missed_observations, counts.missed_commands, counts.missed_motor_states
        ));
    }
    Ok(line)
}

/// Arguments of `tes replay`.
#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// A recording (`tes launch --record FILE.mcap`).
    file: PathBuf,
    /// Print the run as `tes launch` did (episodes, rewards, latency percentiles) from the
    /// file alone, without replaying.
    #[arg(long)]
    summary: bool,
    /// Write one CSV file per topic into DIR, without replaying.
    #[arg(long, value_name = "DIR")]
    export_csv: Option<PathBuf>,
}

/// Runs `tes replay`.
pub fn run(args: &ReplayArgs) -> Result<()> {
    let recording = Recording::open(&args.file)?;
    if let Some(why) = &recording.truncated {
        eprintln!(
            "replay: {} is incomplete: {why}; read {} observations and {} commands up to there",
            args.file.display(),
            recording.observations.len(),
            recording.commands.len()
        );
    }
    if let Some(dir) = &args.export_csv {
        for path in tes_recorder::summary::export_csv(&recording, dir)? {
            println!("replay: wrote {}", path.display());
        }
    }
    if args.summary {
        println!("{}", tes_recorder::summary::summarise(&recording));
    }
    if args.summary || args.export_csv.is_some() {
        return Ok(());
    }
    let missed = recording
        .end
        .as_ref()
        .and_then(|e| e.get("missed_commands"))
        .map_or("0", String::as_str);
    if missed != "0" {
        eprintln!("replay: the recorder missed {missed} commands; those steps cannot be compared");
    }
    let outcome = tes_recorder::replay::replay(&recording)
        .with_context(|| format!("cannot replay {}", args.file.display()))?;
    println!("replay: {outcome}");
    if outcome.divergence.is_some() {
        bail!("the replay diverged from the recording");
    }
    Ok(())
}
