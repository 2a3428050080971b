//! The process group: starting the children, relaying their lines, respawning or stopping
//! them.

use super::*;

/// The roles this executable plays as a child.
pub const ROLES: [&str; 3] = ["bridge", "controller", "perception-sim"];

/// One child's launch recipe.
#[derive(Debug)]
pub(crate) struct ChildSpec {
    pub(crate) role: &'static str,
    pub(crate) config: PathBuf,
}

/// A running (or finished) child.
pub(crate) struct Running {
    pub(crate) spec: ChildSpec,
    pub(crate) child: Child,
    pub(crate) restarts: u32,
    pub(crate) status: Option<ExitStatus>,
}

/// How a group run went.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct GroupOutcome {
    /// Episodes the controller reported.
    pub(crate) episodes: u32,
}

/// [`run_file`] with the children already prepared.
pub(crate) fn run_group(
    file: &LaunchFile,
    specs: Vec<ChildSpec>,
    echo: bool,
) -> Result<GroupOutcome> {
    let launch = &file.launch;
    let note = |text: String| {
        if echo {
            eprintln!("{text}");
        }
    };

    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, stop.clone())
            .context("cannot install the signal handlers")?;
    }
    match channel::clean_stale_resources() {
        Ok(0) => {}
        Ok(n) => note(format!(
            "launch: removed the stale iceoryx2 resources of {n} dead processes"
        )),
        Err(e) => eprintln!("launch: warning: {e}"),
    }
    note(format!(
        "launch: arena Env {}, {} episodes, real-time factor {}, wait {}, restart {:?}",
        launch.arena, launch.episodes, launch.real_time_factor, launch.wait, launch.restart
    ));
    let (lines_tx, lines) = mpsc::channel::<String>();
    let mut children = Vec::new();
    for spec in specs {
        let child = spawn(&spec, &lines_tx)?;
        children.push(Running {
            spec,
            child,
            restarts: 0,
            status: None,
        });
    }
    let grace = Duration::from_millis(launch.grace_ms);
    let mut failure: Option<String> = None;
    let mut episodes = 0u32;
    'supervise: loop {
        for line in lines.try_iter() {
            if line.starts_with("episode ") {
                episodes += 1;
            }
            if echo {
                println!("{line}");
            }
        }
        if stop.load(Ordering::Relaxed) {
            eprintln!("launch: stop requested; stopping the group");
            break;
        }
        for i in 0..children.len() {
            let Some(status) = children[i]
                .child
                .try_wait()
                .context("cannot poll a child")?
            else {
                continue;
            };
            let role = children[i].spec.role;
            if role == "perception-sim" && status.success() {
                note("launch: perception-sim finished its episodes; stopping the group".into());
                children[i].status = Some(status);
                break 'supervise;
            }
            let why = describe(status);
            let may_restart = launch.restart == Restart::OnFailure
                && !status.success()
                && children[i].restarts < launch.max_restarts;
            if !may_restart {
                eprintln!("launch: {role} {why}; stopping the others");
                children[i].status = Some(status);
                failure = Some(format!("{role} {why}"));
                break 'supervise;
            }
            children[i].restarts += 1;
            eprintln!(
                "launch: {role} {why}; respawning it (restart {}/{})",
                children[i].restarts, launch.max_restarts
            );
            if let Err(e) = channel::clean_stale_resources() {
                eprintln!("launch: warning: {e}");
            }
            children[i].child = spawn(&children[i].spec, &lines_tx)?;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    shutdown(&mut children, grace);
    // Every child has exited; take what they printed last (the controller reports its last
    // episode and its summary on the way out) until each one's output is closed, or 2 s.
    drop(lines_tx);
    let deadline = Instant::now() + Duration::from_secs(2);
    while let Ok(line) = lines.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
        if line.starts_with("episode ") {
            episodes += 1;
        }
        if echo {
            println!("{line}");
        }
    }
    let mut failed: Vec<String> = failure.into_iter().collect();
    for c in &children {
        match c.status {
            Some(s) if !s.success() && !stopped_by_us(s) => {
                failed.push(format!("{} {}", c.spec.role, describe(s)));
            }
            _ => {}
        }
    }
    failed.dedup();
    if echo {
        println!(
            "launch: {episodes} episodes; {}",
            if failed.is_empty() {
                "all processes stopped cleanly".to_owned()
            } else {
                format!("failed: {}", failed.join("; "))
            }
        );
    }
    if !failed.is_empty() {
        bail!("a process failed: {}", failed.join("; "));
    }
    Ok(GroupOutcome { episodes })
}

/// Starts one child: this executable in the child's role, dying with the launcher.
pub(crate) fn spawn(spec: &ChildSpec, lines: &mpsc::Sender<String>) -> Result<Child> {
    let exe = std::env::current_exe().context("cannot find the tes executable")?;
    let mut cmd = Command::new(exe);
    cmd.arg("child")
        .arg(spec.role)
        .arg("--config")
        .arg(&spec.config)
        .stdin(Stdio::null())
        .stdout(Stdio::piped());
    // SAFETY: `pre_exec` runs in the forked child before exec; prctl(PR_SET_PDEATHSIG) is
    // async-signal-safe and touches no memory of the parent.
    unsafe {
        cmd.pre_exec(|| {
            nix::sys::prctl::set_pdeathsig(Signal::SIGTERM).map_err(std::io::Error::from)
        });
    }
    let mut child = cmd
        .spawn()
        .with_context(|| format!("cannot start {}", spec.role))?;
    if let Some(out) = child.stdout.take() {
        relay(out, lines.clone());
    }
    Ok(child)
}

/// Forwards a child's stdout, line by line, to the launcher.
pub(crate) fn relay(out: ChildStdout, lines: mpsc::Sender<String>) {
    std::thread::spawn(move || {
        for line in BufReader::new(out).lines() {
            let Ok(line) = line else { break };
            if lines.send(line).is_err() {
                break;
            }
        }
    });
}

/// SIGINT, then SIGTERM after `grace`, then SIGKILL after `grace`; waits for every child.
pub(crate) fn shutdown(children: &mut [Running], grace: Duration) {
    for signal in [Signal::SIGINT, Signal::SIGTERM, Signal::SIGKILL] {
        let mut any = false;
        for c in children.iter_mut() {
            if c.status.is_none() {
                if let Ok(Some(s)) = c.child.try_wait() {
                    c.status = Some(s);
                    continue;
                }
                let pid = Pid::from_raw(c.child.id() as i32);
                if kill(pid, signal).is_ok() {
                    any = true;
                }
            }
        }
        if !any {
            break;
        }
        let deadline = Instant::now() + grace;
        while Instant::now() < deadline {
            let mut alive = false;
            for c in children.iter_mut() {
                if c.status.is_none() {
                    match c.child.try_wait() {
                        Ok(Some(s)) => c.status = Some(s),
                        _ => alive = true,
                    }
                }
            }
            if !alive {
                return;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        for c in children.iter() {
            if c.status.is_none() && signal != Signal::SIGKILL {
                eprintln!(
                    "launch: {} did not stop within {grace:?} of {signal}; escalating",
                    c.spec.role
                );
            }
        }
    }
    for c in children.iter_mut() {
        if c.status.is_none() {
            c.status = c.child.wait().ok();
        }
    }
}

/// Whether `status` is an exit the shutdown itself caused (SIGINT/SIGTERM handled by a
/// child that then exited by that signal).
pub(crate) fn stopped_by_us(status: ExitStatus) -> bool {
    use std::os::unix::process::ExitStatusExt;
    matches!(status.signal(), Some(s) if s == Signal::SIGINT as i32 || s == Signal::SIGTERM as i32)
}

/// "exited with status 3" / "was killed by SIGKILL".
pub(crate) fn describe(status: ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (status.code(), status.signal()) {
        (Some(code), _) => format!("exited with status {code}"),
        (None, Some(sig)) => match Signal::try_from(sig) {
            Ok(s) => format!("was killed by {s}"),
            Err(_) => format!("was killed by signal {sig}"),
        },
        _ => "ended".to_owned(),
    }
}
