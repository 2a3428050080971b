use std::io::{BufReader, Write};
use std::os::unix::fs::PermissionsExt;
use std::sync::mpsc;
use std::time::Duration;

use super::*;

/// Runs `read` on a thread and fails (after giving a blocked FIFO open its writer) if it
/// does not return within a generous time: a blocking open must fail the test, not hang it.
fn within_a_while<T: Send + 'static>(fifo: &Path, read: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = mpsc::channel();
    let reader = std::thread::spawn(move || {
        let _ = tx.send(read());
    });
    match rx.recv_timeout(Duration::from_secs(20)) {
        Ok(r) => {
            reader.join().expect("the reader ends");
            r
        }
        Err(_) => {
            let _ = OpenOptions::new()
                .write(true)
                .custom_flags(libc::O_NONBLOCK)
                .open(fifo);
            panic!("opening a FIFO blocked");
        }
    }
}

#[test]
fn a_fifo_is_refused_without_blocking() {
    let dir = tempfile::tempdir().expect("temp dir");
    let fifo = dir.path().join("key.pem");
    nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::S_IRWXU).expect("mkfifo");
    let path = fifo.clone();
    let err = within_a_while(&fifo, move || read_capped(&path, 1 << 20)).unwrap_err();
    assert!(
        matches!(err, FileProblem::NotARegularFile { kind: "a FIFO" }),
        "{err}"
    );
    // Behind a symbolic link too.
    let link = dir.path().join("link.pem");
    std::os::unix::fs::symlink(&fifo, &link).expect("symlink");
    let err = within_a_while(&fifo, move || read_text(&link, 1 << 20)).unwrap_err();
    assert_eq!(err.to_string(), "is a FIFO, not a regular file");
}

#[test]
fn devices_and_directories_are_refused_before_a_byte_is_read() {
    for (path, kind) in [
        ("/dev/zero", "a character device"),
        ("/dev/null", "a character device"),
        ("/", "a directory"),
    ] {
        let err = read_capped(Path::new(path), u64::MAX).unwrap_err();
        assert_eq!(err.to_string(), format!("is {kind}, not a regular file"));
    }
}

#[test]
fn a_sparse_file_over_the_limit_is_refused_without_reading_it() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("huge");
    File::create(&path)
        .and_then(|f| f.set_len(2 << 30))
        .expect("a sparse 2 GiB file");
    let err = read_capped(&path, 1 << 20).unwrap_err();
    assert!(
        matches!(
            err,
            FileProblem::TooLarge {
                size: 0x8000_0000,
                limit: 0x10_0000
            }
        ),
        "{err}"
    );
    assert_eq!(
        err.to_string(),
        "is 2147483648 bytes, more than the 1048576 bytes read from such a file"
    );
}

#[test]
fn a_regular_file_reads_whole_and_a_missing_or_dangling_one_says_so() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("a.toml");
    fs::write(&path, "x = 1\n").expect("write");
    assert_eq!(read_text(&path, 6).expect("fits"), "x = 1\n");
    assert!(matches!(
        read_text(&path, 5),
        Err(FileProblem::TooLarge { size: 6, limit: 5 })
    ));
    fs::write(&path, [0xff, 0xfe]).expect("write");
    let err = read_text(&path, 100).unwrap_err();
    assert!(err.to_string().contains("is not UTF-8 text"), "{err}");
    let missing = dir.path().join("missing");
    let err = read_capped(&missing, 100).unwrap_err();
    assert!(matches!(&err, FileProblem::Io(e) if e.kind() == io::ErrorKind::NotFound));
    let link = dir.path().join("link");
    std::os::unix::fs::symlink(&missing, &link).expect("symlink");
    let err = FileError::new(&link, read_capped(&link, 100).unwrap_err());
    assert!(matches!(&err.problem, FileProblem::DanglingSymlink { target } if target == &missing));
    assert!(err.to_string().contains("which does not exist"), "{err}");
}

#[test]
fn open_key_files_and_directories_are_refused_with_the_chmod_to_run() {
    let dir = tempfile::tempdir().expect("temp dir");
    let key = dir.path().join("my key.pem");
    fs::write(&key, "secret").expect("write");
    let set = |path: &Path, mode| {
        fs::set_permissions(path, fs::Permissions::from_mode(mode)).expect("chmod");
    };
    set(&key, 0o644);
    let err = check_private_file(&key).unwrap_err();
    let text = err.to_string();
    assert!(
        text.starts_with("is a key file with mode 0644: its group and others may read it"),
        "{text}"
    );
    assert!(
        text.ends_with(&format!("run `chmod 600 '{}'`", key.display())),
        "{text}"
    );
    set(&key, 0o640);
    let err = check_private_file(&key).unwrap_err().to_string();
    assert!(err.contains("its group may read"), "{err}");
    set(&key, 0o600);
    check_private_file(&key).expect("owner-only");
    set(dir.path(), 0o777);
    let err = check_private_dir(dir.path()).unwrap_err().to_string();
    assert!(err.contains("mode 0777"), "{err}");
    assert!(
        err.contains(&format!("chmod 700 {}", dir.path().display())),
        "{err}"
    );
    let err = check_dir_not_writable_by_others(dir.path())
        .unwrap_err()
        .to_string();
    assert!(err.contains("chmod go-w"), "{err}");
    set(dir.path(), 0o755);
    check_dir_not_writable_by_others(dir.path()).expect("only its owner writes");
    assert!(check_private_dir(dir.path()).is_err());
    set(dir.path(), 0o700);
    check_private_dir(dir.path()).expect("owner-only");
}

#[test]
fn shell_words_quote_what_a_shell_would_split() {
    assert_eq!(shell_word(Path::new("/etc/tes/ca.pem")), "/etc/tes/ca.pem");
    assert_eq!(shell_word(Path::new("my keys")), "'my keys'");
    assert_eq!(shell_word(Path::new("it's")), r"'it'\''s'");
    assert_eq!(parent_dir(Path::new("robot.key")), Path::new("."));
    assert_eq!(parent_dir(Path::new("k/robot.key")), Path::new("k"));
}

#[test]
fn a_line_without_end_is_cut_at_the_limit() {
    let mut endless = BufReader::with_capacity(4096, io::repeat(b'0'));
    let mut line = Vec::new();
    let err = read_until_capped(&mut endless, &mut line, 1 << 16).unwrap_err();
    assert_eq!(err.kind(), io::ErrorKind::InvalidData);
    assert!(err.to_string().contains("longer than 65536 bytes"), "{err}");
    assert!(line.len() <= (1 << 16) + 1, "{}", line.len());
    let mut lines = &b"ab\ncd\nlast"[..];
    let mut line = Vec::new();
    assert_eq!(
        read_until_capped(&mut lines, &mut line, 3).expect("fits"),
        3
    );
    assert_eq!(line, b"ab\n");
    line.clear();
    assert_eq!(
        read_until_capped(&mut lines, &mut line, 3).expect("fits"),
        3
    );
    line.clear();
    assert_eq!(
        read_until_capped(&mut lines, &mut line, 4).expect("fits"),
        4
    );
    assert_eq!(line, b"last");
    line.clear();
    assert_eq!(read_until_capped(&mut lines, &mut line, 4).expect("end"), 0);
}

#[test]
fn inflation_within_the_bound_reads_whole_and_past_it_stops() {
    let bound = InflationBound {
        allowance: 100,
        ratio: 2,
    };
    // An identity "decompressor": 1 to 1, always within the bound.
    let data = vec![5u8; 10_000];
    let mut guarded = InflationGuard::new(&data[..], |c| c, bound);
    let mut out = Vec::new();
    guarded.read_to_end(&mut out).expect("within the bound");
    assert_eq!(out, data);
    // Ten bytes out of each byte in.
    let tenfold = |mut c: CountingReader<&[u8]>| {
        let mut inflated = Vec::new();
        let mut all = Vec::new();
        c.read_to_end(&mut all).expect("read");
        for b in all {
            inflated.write_all(&[b; 10]).expect("write");
        }
        io::Cursor::new(inflated)
    };
    let mut guarded = InflationGuard::new(&data[..], tenfold, bound);
    let err = io::copy(&mut guarded, &mut io::sink()).unwrap_err();
    let exceeded = err
        .get_ref()
        .and_then(|e| e.downcast_ref::<InflationExceeded>())
        .expect("the typed cause");
    assert_eq!(exceeded.compressed, 10_000);
    assert!(exceeded.inflated > bound.allowed(10_000));
}
