//! Files a setting or a command names that are not what they should be — a FIFO no one
//! writes to, `/dev/zero`, a sparse file of gigabytes, a row a million columns wide, a
//! decompression bomb, a key anyone may read — each refused clearly by the built `tes`
//! binary, run under an address-space limit (`RLIMIT_AS`) so that reading one whole would
//! fail the test instead of the machine.

use std::fs;
use std::io::Write;
use std::os::unix::fs::PermissionsExt;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use crate::common::{Killed, tes_command, wait_exit};

/// The address space each `tes` here may use: far below what reading any of these files
/// whole would take (2 GiB and more), and room enough for a real fit ([`the_limit_leaves_room_for_a_real_fit`]).
const ADDRESS_SPACE: u64 = 1 << 30;

/// Generous: these refusals take milliseconds; a blocked open would take forever.
const EXIT_WITHIN: Duration = Duration::from_secs(120);

/// `tes ARGS` under [`ADDRESS_SPACE`], its standard input from `stdin` (or nothing), run to
/// its end within [`EXIT_WITHIN`].
fn tes_limited(args: &[&str], stdin: Option<Stdio>) -> Output {
    let mut command = tes_command();
    command
        .args(args)
        .stdin(stdin.unwrap_or_else(Stdio::null))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    limit_address_space(&mut command);
    finish(command, args)
}

/// Runs `command` to its end within [`EXIT_WITHIN`] (else the test fails, the process
/// killed); its output, read as it comes so a full pipe cannot stall it.
fn finish(mut command: Command, args: &[&str]) -> Output {
    use std::io::Read;
    let mut child = Killed(command.spawn().expect("tes runs"));
    let drain = |pipe: Option<Box<dyn Read + Send>>| {
        std::thread::spawn(move || {
            let mut bytes = Vec::new();
            if let Some(mut pipe) = pipe {
                let _ = pipe.read_to_end(&mut bytes);
            }
            bytes
        })
    };
    let stdout = drain(
        child
            .0
            .stdout
            .take()
            .map(|p| Box::new(p) as Box<dyn Read + Send>),
    );
    let stderr = drain(
        child
            .0
            .stderr
            .take()
            .map(|p| Box::new(p) as Box<dyn Read + Send>),
    );
    let status = wait_exit(
        &mut child.0,
        EXIT_WITHIN,
        &format!("tes {}", args.join(" ")),
    );
    Output {
        status,
        stdout: stdout.join().expect("read"),
        stderr: stderr.join().expect("read"),
    }
}

fn limit_address_space(command: &mut Command) {
    // SAFETY: setrlimit is async-signal-safe and touches only the child's own limits.
    unsafe {
        command.pre_exec(|| {
            nix::sys::resource::setrlimit(
                nix::sys::resource::Resource::RLIMIT_AS,
                ADDRESS_SPACE,
                ADDRESS_SPACE,
            )
            .map_err(std::io::Error::from)
        });
    }
}

/// Its standard error, after asserting it failed cleanly (status 1, not a signal or an
/// abort).
fn refused(out: &Output) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    stderr
}

fn fifo(dir: &Path, name: &str) -> PathBuf {
    let path = dir.join(name);
    nix::unistd::mkfifo(&path, nix::sys::stat::Mode::S_IRWXU).expect("mkfifo");
    path
}

fn sparse(dir: &Path, name: &str, start: &[u8]) -> PathBuf {
    let path = dir.join(name);
    let mut file = fs::File::create(&path).expect("create");
    file.write_all(start).expect("write");
    file.set_len(2 << 30).expect("a sparse 2 GiB file");
    path
}

fn text(path: &Path) -> &str {
    path.to_str().expect("UTF-8 path")
}

#[test]
fn the_limit_leaves_room_for_a_real_fit() {
    let demo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/fit-demo.csv");
    let out = tes_limited(&["fit", text(&demo)], None);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn fit_refuses_devices_fifos_and_endless_lines() {
    let dir = tempfile::tempdir().expect("temp dir");
    let rows = fifo(dir.path(), "rows.csv");
    let err = refused(&tes_limited(&["fit", text(&rows)], None));
    assert!(err.contains("is a FIFO, not a regular file"), "{err}");
    let err = refused(&tes_limited(&["fit", "/dev/zero"], None));
    assert!(
        err.contains("is a character device, not a regular file"),
        "{err}"
    );
    // 2 GiB of zero bytes and no newline: refused at the line cap, never held whole.
    let zeros = sparse(dir.path(), "zeros.csv", b"");
    let err = refused(&tes_limited(&["fit", text(&zeros)], None));
    assert!(err.contains("a line longer than 67108864 bytes"), "{err}");
    // The same endless line on standard input.
    let zero = fs::File::open("/dev/zero").expect("/dev/zero");
    let err = refused(&tes_limited(&["fit", "-"], Some(Stdio::from(zero))));
    assert!(err.contains("a line longer than 67108864 bytes"), "{err}");
}

#[test]
fn fit_of_three_rows_a_million_columns_wide_sizes_its_buffers_by_the_rows() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("wide.csv");
    let mut file = std::io::BufWriter::new(fs::File::create(&path).expect("create"));
    for label in [0, 1, 0] {
        write!(file, "{label}").expect("write");
        for column in 0..1_000_000 {
            write!(file, ",{}", u8::from(column % 7 == label)).expect("write");
        }
        writeln!(file).expect("write");
    }
    drop(file);
    let out = tes_limited(&["fit", text(&path), "--json"], None);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert_eq!(
        (&report["n"], &report["features"]),
        (&serde_json::json!(3), &serde_json::json!(1_000_000))
    );
}

/// A gzip member of `block` repeated `times` times, as `MultiGzDecoder` reads them: many
/// inflated bytes from few compressed ones.
fn bomb(block: &[u8], times: usize) -> Vec<u8> {
    let mut encoder = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
    encoder.write_all(block).expect("compress");
    let member = encoder.finish().expect("compress");
    member.repeat(times)
}

#[test]
fn fit_refuses_decompression_bombs() {
    let dir = tempfile::tempdir().expect("temp dir");
    // Rows of zeros, 1 GiB inflated from about 1 MiB: past the inflation bound.
    let row = b"0,0,0,0,0,0,0,0,0,0,0,0,0,0,0\n";
    let block: Vec<u8> = row.repeat((64 << 20) / row.len());
    let rows = dir.path().join("rows.csv.gz");
    fs::write(&rows, bomb(&block, 16)).expect("write");
    let err = refused(&tes_limited(&["fit", text(&rows)], None));
    assert!(err.contains("decompression bomb"), "{err}");
    // One line of 256 MiB, no newline: refused at the line cap first.
    let line = dir.path().join("line.csv.gz");
    fs::write(&line, bomb(&vec![b'1'; 64 << 20], 4)).expect("write");
    let err = refused(&tes_limited(&["fit", text(&line)], None));
    assert!(err.contains("a line longer than 67108864 bytes"), "{err}");
    // The same bomb on standard input.
    let stdin = fs::File::open(&rows).expect("open");
    let err = refused(&tes_limited(&["fit", "-"], Some(Stdio::from(stdin))));
    assert!(err.contains("decompression bomb"), "{err}");
}

#[test]
fn replay_refuses_devices_fifos_and_huge_files_before_reading_them() {
    let dir = tempfile::tempdir().expect("temp dir");
    let link = dir.path().join("run.mcap");
    std::os::unix::fs::symlink("/dev/zero", &link).expect("symlink");
    let err = refused(&tes_limited(&["replay", text(&link)], None));
    assert!(
        err.contains("is a character device, not a regular file"),
        "{err}"
    );
    let pipe = fifo(dir.path(), "fifo.mcap");
    let err = refused(&tes_limited(&["replay", text(&pipe)], None));
    assert!(err.contains("is a FIFO, not a regular file"), "{err}");
    // 2 GiB of zeros: not an MCAP file, told from its first 8 bytes.
    let zeros = sparse(dir.path(), "zeros.mcap", b"");
    let err = refused(&tes_limited(&["replay", text(&zeros)], None));
    assert!(
        err.contains("does not start with the MCAP magic bytes"),
        "{err}"
    );
    // The magic, then 2 GiB: over the size a recording may have, refused unread.
    let huge = sparse(dir.path(), "huge.mcap", b"\x89MCAP0\r\n");
    let err = refused(&tes_limited(&["replay", text(&huge)], None));
    assert!(
        err.contains("is 2147483648 bytes, more than the 1073741824 bytes"),
        "{err}"
    );
}

#[test]
fn launch_files_that_are_fifos_or_devices_are_refused_at_once() {
    let dir = tempfile::tempdir().expect("temp dir");
    let config = fifo(dir.path(), "launch.toml");
    for path in [text(&config), "/dev/zero"] {
        let args = ["launch", "--config", path];
        let mut command = tes_command();
        command
            .args(args)
            .env("TES_DATA_DIR", dir.path().join("data"))
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        let err = refused(&finish(command, &args));
        assert!(err.contains("not a regular file"), "{err}");
        assert!(err.contains("nothing was started"), "{err}");
    }
    assert!(!dir.path().join("data").exists(), "nothing made");
}

/// A launch file playing the controller over QUIC with the group's keys (made by `tes link
/// keygen` in `keys`), with `tls_key` (and the others) as given.
fn tls_launch_file(dir: &Path, ca: &Path, cert: &Path, key: &Path) -> PathBuf {
    let path = dir.join("learner.toml");
    let toml = format!(
        "[launch]\nroles = [\"controller\"]\n[launch.link]\nconnect = [\"quic/192.0.2.1:7447\"]\n\
         tls_ca = {:?}\ntls_cert = {:?}\ntls_key = {:?}\n",
        text(ca),
        text(cert),
        text(key)
    );
    fs::write(&path, toml).expect("launch file");
    path
}

/// Runs `tes launch --config FILE` with its own data directory; its refusal, after checking
/// that nothing was made there (no run folder, no lock).
fn launch_refused(dir: &Path, config: &Path) -> String {
    let data = dir.join("data");
    let args = ["launch", "--config", text(config)];
    let mut command = tes_command();
    command
        .args(args)
        .env("TES_DATA_DIR", &data)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    let err = refused(&finish(command, &args));
    assert!(err.contains("nothing was started"), "{err}");
    assert!(!data.join("runs").exists(), "no run folder: {err}");
    assert!(!data.exists() || fs::read_dir(&data).expect("dir").count() == 0);
    err
}

#[test]
fn tls_files_are_checked_before_anything_is_made() {
    let dir = tempfile::tempdir().expect("temp dir");
    let keys = dir.path().join("keys");
    let out = tes_limited(&["link", "keygen", text(&keys)], None);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let (ca, cert, key) = (
        keys.join("ca.pem"),
        keys.join("learner.pem"),
        keys.join("learner.key"),
    );
    let stuck = fifo(&keys, "stuck.key");
    let err = launch_refused(dir.path(), &tls_launch_file(dir.path(), &ca, &cert, &stuck));
    assert!(err.contains("link.tls_key"), "{err}");
    assert!(err.contains("is a FIFO, not a regular file"), "{err}");
    let zero = Path::new("/dev/zero");
    let err = launch_refused(dir.path(), &tls_launch_file(dir.path(), zero, &cert, &key));
    assert!(err.contains("link.tls_ca"), "{err}");
    assert!(err.contains("is a character device"), "{err}");
    let host_as_ca = keys.join("robot.pem");
    let err = launch_refused(
        dir.path(),
        &tls_launch_file(dir.path(), &host_as_ca, &cert, &key),
    );
    assert!(
        err.contains("not an authority's certificate but a host's"),
        "{err}"
    );
    fs::set_permissions(&key, fs::Permissions::from_mode(0o644)).expect("chmod");
    let err = launch_refused(dir.path(), &tls_launch_file(dir.path(), &ca, &cert, &key));
    assert!(
        err.contains(&format!("chmod 600 {}", key.display())),
        "{err}"
    );
}

#[test]
fn keygen_refuses_an_open_directory_and_addresses_that_are_not_addresses() {
    let dir = tempfile::tempdir().expect("temp dir");
    let open = dir.path().join("open");
    fs::create_dir(&open).expect("dir");
    fs::set_permissions(&open, fs::Permissions::from_mode(0o777)).expect("chmod");
    let err = refused(&tes_limited(&["link", "keygen", text(&open)], None));
    assert!(
        err.contains(&format!("chmod 700 {}", open.display())),
        "{err}"
    );
    assert_eq!(
        fs::read_dir(&open).expect("dir").count(),
        0,
        "nothing written"
    );
    let injected = "robot=perception-sim,bridge@x\"]\ninsecure = true";
    let keys = dir.path().join("keys");
    let out = tes_limited(
        &[
            "link",
            "keygen",
            text(&keys),
            "--host",
            injected,
            "--host",
            "learner=controller",
        ],
        None,
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "a bad argument: {err}");
    assert!(err.contains("is not an address"), "{err}");
    assert!(!String::from_utf8_lossy(&out.stdout).contains("insecure"));
    assert!(!keys.exists(), "nothing written");
}
