use std::fs::OpenOptions;
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};

use proptest::prelude::*;
use tes_files::FileProblem;

use super::*;
use crate::library::{ActionOutcome, Winner};
use crate::mdagl::Features;

/// A library grown over three tasks: fresh winners, an adjusted copy updating its original,
/// one recruited as a new view.
fn grown() -> StoredLibrary {
    let params = LibraryParams {
        max_views: 6,
        recency: 0.1,
        ..LibraryParams::default()
    };
    let mut lib = ViewLibrary::new(2, 3, 5, params).unwrap();
    let trained = |lib: &ViewLibrary, seed: u32, n: u32| {
        let mut m = lib.fresh_model();
        for i in 0..n {
            let x = [0, 1 + (i * seed) % 4];
            m.update(Features::SparseBinary(&x), ((i + seed) % 3) as usize)
                .unwrap();
        }
        m
    };
    let outcome = |action, winner, model, score| ActionOutcome {
        action,
        observations: 30,
        winner,
        model,
        score,
        library_scores: vec![],
    };
    let (a, b) = (trained(&lib, 1, 40), trained(&lib, 2, 40));
    lib.end_task(vec![
        outcome(0, Winner::Fresh, a, -20.0),
        outcome(1, Winner::Fresh, b, -25.0),
    ])
    .unwrap();
    let c = trained(&lib, 3, 60);
    let mut o = outcome(
        0,
        Winner::Adjusted {
            id: 0,
            original_score: -10.5,
        },
        c,
        -10.0,
    );
    o.library_scores = vec![(0, -10.0)];
    lib.end_task(vec![o]).unwrap();
    let d = trained(&lib, 5, 80);
    let mut o = outcome(
        1,
        Winner::Adjusted {
            id: 1,
            original_score: -40.0,
        },
        d,
        -12.0,
    );
    o.library_scores = vec![(1, -12.0)];
    lib.end_task(vec![o]).unwrap();
    assert_eq!(lib.len(), 3);
    StoredLibrary {
        library: lib,
        world: "test world".into(),
        action_names: vec!["left".into(), "right".into()],
        feature_names: (0..5).map(|i| format!("f{i}")).collect(),
    }
}

fn problem(bytes: &[u8]) -> StoreProblem {
    decode(bytes).expect_err("the bytes should be refused")
}

#[test]
fn a_saved_library_loads_back_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lib.tesl");
    let stored = grown();
    save(&path, &stored).unwrap();
    let loaded = load(&path).unwrap();
    assert_eq!(loaded, stored);
    assert_eq!(load_for(&path, 2, 3, 5).unwrap().library, stored.library);
    // No temporary file is left behind.
    let names: Vec<_> = fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(names.len(), 1);
    // Saving again over it works and is still exact.
    save(&path, &loaded).unwrap();
    assert_eq!(load(&path).unwrap(), stored);
}

#[test]
fn each_kind_of_bad_file_is_refused_with_the_file_named() {
    let dir = tempfile::tempdir().unwrap();
    let good = encode(&grown());
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        (
            "foreign",
            b"hello, this is not a library".to_vec(),
            "not a TES view library",
        ),
        ("empty", Vec::new(), "truncated"),
        ("header-cut", good[..10].to_vec(), "truncated"),
        ("body-cut", good[..good.len() - 7].to_vec(), "truncated"),
        (
            "trailing",
            [good.as_slice(), b"xx"].concat(),
            "unexpected bytes",
        ),
        (
            "corrupt",
            {
                let mut b = good.clone();
                let i = b.len() / 2;
                b[i] ^= 0x40;
                b
            },
            "corrupt: checksum",
        ),
        (
            "future",
            {
                let mut b = good.clone();
                b[8..12].copy_from_slice(&7u32.to_le_bytes());
                b
            },
            "written by a newer TES: format v7",
        ),
    ];
    for (name, bytes, expected) in cases {
        let path = dir.path().join(format!("{name}.tesl"));
        fs::write(&path, &bytes).unwrap();
        let err = load(&path).unwrap_err().to_string();
        assert!(err.contains(&path.display().to_string()), "{name}: {err}");
        assert!(err.contains(expected), "{name}: {err}");
    }
    let path = dir.path().join("shape.tesl");
    fs::write(&path, &good).unwrap();
    let err = load_for(&path, 4, 5, 210).unwrap_err();
    assert!(matches!(
        err.problem,
        StoreProblem::WrongShape {
            found_actions: 2,
            ..
        }
    ));
    assert!(
        err.to_string().contains("this world has 4, 5 and 210"),
        "{err}"
    );
    let err = load(&dir.path().join("missing.tesl")).unwrap_err();
    assert!(matches!(err.problem, StoreProblem::Io(_)));
}

/// Re-checksums a body edited in place, so the consistency checks are what refuse it.
fn with_body(good: &[u8], edit: impl FnOnce(&mut Vec<u8>)) -> Vec<u8> {
    let mut body = good[HEADER_LEN..].to_vec();
    edit(&mut body);
    let mut out = good[..HEADER_LEN].to_vec();
    out[12..20].copy_from_slice(&(body.len() as u64).to_le_bytes());
    out[20..24].copy_from_slice(&crc32fast::hash(&body).to_le_bytes());
    out.extend_from_slice(&body);
    out
}

#[test]
fn well_checksummed_but_inconsistent_bodies_are_refused() {
    let good = encode(&grown());
    // n_actions = 0.
    let zero_actions = with_body(&good, |b| b[0..4].copy_from_slice(&0u32.to_le_bytes()));
    assert!(matches!(
        problem(&zero_actions),
        StoreProblem::Inconsistent(_)
    ));
    // max_views = 1 but 3 views.
    let small = with_body(&good, |b| b[12..16].copy_from_slice(&1u32.to_le_bytes()));
    assert!(
        problem(&small)
            .to_string()
            .contains("more than the library's limit")
    );
    // tasks_seen = 1, but views won tasks 1 and 2.
    let at = 12 + 4 + 8 * 4 + 1;
    let early = with_body(&good, |b| {
        b[at..at + 4].copy_from_slice(&1u32.to_le_bytes())
    });
    assert!(
        problem(&early)
            .to_string()
            .contains("only 1 tasks were seen")
    );
    // next_id = 0: every id is too big.
    let ids = with_body(&good, |b| {
        b[at + 4..at + 12].copy_from_slice(&0u64.to_le_bytes());
    });
    assert!(problem(&ids).to_string().contains("not below the next id"));
    // A huge name count cannot reserve memory.
    let world_len = at + 12;
    let huge = with_body(&good, |b| {
        b[world_len..world_len + 4].copy_from_slice(&u32::MAX.to_le_bytes());
    });
    assert!(problem(&huge).to_string().contains("does not fit"));
}

/// Views the file describes must be for a known action, have distinct ids and finite
/// gradient sums (well-checksummed files, so the consistency checks are what refuse them).
#[test]
fn views_of_unknown_actions_duplicate_ids_or_non_finite_sums_are_refused() {
    let mut unknown_action = grown();
    unknown_action.library.views[0].action = 2;
    let err = problem(&encode(&unknown_action));
    assert!(matches!(err, StoreProblem::Inconsistent(_)), "{err}");
    assert!(err.to_string().contains("is for action 2 of 2"), "{err}");

    let mut duplicate = grown();
    let first = duplicate.library.views[0].id;
    duplicate.library.views[1].id = first;
    let err = problem(&encode(&duplicate));
    assert!(
        err.to_string()
            .contains(&format!("two views with id {first}")),
        "{err}"
    );

    // The first view's first gradient sum: after the body up to the view count, the
    // view's id, action, update count and sum count.
    let mut no_views = grown();
    no_views.library.views.clear();
    let at = encode(&no_views).len() - HEADER_LEN + 8 + 4 + 8 + 4;
    let good = encode(&grown());
    for bad in [f64::NAN, f64::INFINITY, 1e200] {
        let file = with_body(&good, |b| b[at..at + 8].copy_from_slice(&bad.to_le_bytes()));
        match problem(&file) {
            StoreProblem::BadView {
                id,
                source: MdaglStateError::BadSum { index: 0, .. },
            } => assert_eq!(id, first),
            other => panic!("{bad}: expected a bad sum, got {other}"),
        }
    }
}

/// A view whose gradient-sum count does not fit the shape is refused when the count is read,
/// before a model of the library's shape is built for it.
#[test]
fn a_view_with_the_wrong_number_of_sums_is_refused_before_its_model_is_built() {
    let mut no_views = grown();
    no_views.library.views.clear();
    // The first view's sum count: after its id, action and update count.
    let at = encode(&no_views).len() - HEADER_LEN + 8 + 4 + 8;
    let good = encode(&grown());
    let first = grown().library.views[0].id;
    let short = with_body(&good, |b| {
        b[at..at + 4].copy_from_slice(&14u32.to_le_bytes())
    });
    match problem(&short) {
        StoreProblem::BadView {
            id,
            source:
                MdaglStateError::WrongLength {
                    got: 14,
                    expected: 15,
                    ..
                },
        } => assert_eq!(id, first),
        other => panic!("expected a wrong sum count, got {other}"),
    }
}

/// A file of `body` behind a valid version 1 header (magic, version, length, checksum).
fn with_header(body: &[u8]) -> Vec<u8> {
    let mut out = MAGIC.to_vec();
    out.extend_from_slice(&1u32.to_le_bytes());
    out.extend_from_slice(&(body.len() as u64).to_le_bytes());
    out.extend_from_slice(&crc32fast::hash(body).to_le_bytes());
    out.extend_from_slice(body);
    out
}

/// Found by `cargo fuzz run library_load` (fuzz/fuzz_targets/library_load.rs): a
/// well-checksummed body of 843 404 369 effects × 620 756 992 features made loading allocate
/// a fresh model of 4.2 × 10^18 bytes (an abort, not an error). The shape is now bounded
/// before anything is built.
#[test]
fn a_huge_view_shape_is_refused_before_anything_is_allocated() {
    let body: [u8; 53] = [
        50, 255, 50, 10, 81, 84, 69, 50, 0, 0, 0, 37, 255, 255, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
        0, 0, 0, 0, 0, 0, 0, 255, 255, 255, 255, 255, 255, 0, 0, 0, 0, 255, 255, 255, 255, 0, 0,
        51, 10, 10, 96,
    ];
    match problem(&with_header(&body)) {
        StoreProblem::TooLarge {
            effects,
            features,
            weights,
        } => {
            assert_eq!((effects, features), (843_404_369, 620_756_992));
            assert_eq!(weights, 843_404_369 * 620_756_992);
        }
        other => panic!("expected TooLarge, got {other}"),
    }
    // A saved library with its feature count raised to u32::MAX: refused the same way, and
    // the message says what is too large.
    let good = encode(&grown());
    let wide = with_body(&good, |b| b[8..12].copy_from_slice(&u32::MAX.to_le_bytes()));
    let err = problem(&wide);
    assert!(
        matches!(err, StoreProblem::TooLarge { effects: 3, .. }),
        "{err}"
    );
    assert!(
        err.to_string()
            .contains("views of 3 effects and 4294967295 features"),
        "{err}"
    );
    // The intercept counts as a column: 2^12 effects × (2^12 features + intercept) is over.
    let mut body = 1u32.to_le_bytes().to_vec();
    body.extend_from_slice(&(1u32 << 12).to_le_bytes());
    body.extend_from_slice(&(1u32 << 12).to_le_bytes());
    body.extend_from_slice(&20u32.to_le_bytes());
    for v in [1.0f64, 0.1, 0.05, 1.5] {
        body.extend_from_slice(&v.to_le_bytes());
    }
    body.push(1);
    assert!(matches!(
        problem(&with_header(&body)),
        StoreProblem::TooLarge {
            weights: 16_781_312,
            ..
        }
    ));
}

#[test]
fn a_failed_save_leaves_the_previous_file_intact() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lib.tesl");
    let old = grown();
    save(&path, &old).unwrap();
    let mut new = old.clone();
    new.world = "another".into();
    let bytes = encode(&new);
    // The disk fills up half way through the write.
    let err = save_bytes(&path, &bytes, |file, bytes| {
        file.write_all(&bytes[..bytes.len() / 2])?;
        Err(io::Error::new(
            io::ErrorKind::StorageFull,
            "no space left on device",
        ))
    })
    .unwrap_err();
    assert!(err.to_string().contains("no space left"), "{err}");
    assert!(err.to_string().contains("lib.tesl"), "{err}");
    assert_eq!(load(&path).unwrap(), old, "the old library survives");
    let names: Vec<_> = fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(names.len(), 1, "no temporary file left");
    // Names of the wrong count are refused before anything is written.
    let mut bad = old.clone();
    bad.feature_names.pop();
    assert!(
        save(&path, &bad)
            .unwrap_err()
            .to_string()
            .contains("4 feature names")
    );
    assert_eq!(load(&path).unwrap(), old);
}

#[test]
fn a_read_only_directory_is_reported_and_changes_nothing() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lib.tesl");
    let old = grown();
    save(&path, &old).unwrap();
    fs::set_permissions(dir.path(), fs::Permissions::from_mode(0o555)).unwrap();
    let probe = dir.path().join("probe");
    let writable_anyway = File::create(&probe).is_ok(); // root ignores permissions
    let _ = fs::remove_file(&probe);
    let result = save(&path, &grown());
    fs::set_permissions(dir.path(), fs::Permissions::from_mode(0o755)).unwrap();
    if !writable_anyway {
        let err = result.unwrap_err();
        assert!(matches!(err.problem, StoreProblem::Io(_)), "{err}");
    }
    assert_eq!(load(&path).unwrap(), old);
}

/// Counts the bytes the current thread asks the allocator for while [`measure`] runs, so
/// tests can check that decoding and loading reserve no more than their input justifies.
mod alloc_track {
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::cell::Cell;

    struct Tracking;

    thread_local! {
        static ON: Cell<bool> = const { Cell::new(false) };
        static BYTES: Cell<usize> = const { Cell::new(0) };
    }

    fn note(size: usize) {
        // Const-initialised cells without destructors: no allocation, usable at any time.
        let _ = ON.try_with(|on| {
            if on.get() {
                let _ = BYTES.try_with(|b| b.set(b.get().saturating_add(size)));
            }
        });
    }

    // SAFETY: every call is forwarded unchanged to the system allocator; the bookkeeping
    // touches only thread-local counters and never allocates.
    unsafe impl GlobalAlloc for Tracking {
        unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
            note(layout.size());
            // SAFETY: the caller's contract for `alloc` is passed on as is.
            unsafe { System.alloc(layout) }
        }
        unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
            note(layout.size());
            // SAFETY: the caller's contract for `alloc_zeroed` is passed on as is.
            unsafe { System.alloc_zeroed(layout) }
        }
        unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
            note(new_size);
            // SAFETY: the caller's contract for `realloc` is passed on as is.
            unsafe { System.realloc(ptr, layout, new_size) }
        }
        unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
            // SAFETY: the caller's contract for `dealloc` is passed on as is.
            unsafe { System.dealloc(ptr, layout) }
        }
    }

    #[global_allocator]
    static ALLOCATOR: Tracking = Tracking;

    /// `f`'s result and the bytes this thread asked for while it ran (every allocation and
    /// every reallocation's new size, summed).
    pub fn measure<T>(f: impl FnOnce() -> T) -> (T, usize) {
        BYTES.with(|b| b.set(0));
        ON.with(|on| on.set(true));
        let out = f();
        ON.with(|on| on.set(false));
        (out, BYTES.with(Cell::get))
    }
}

use alloc_track::measure;

/// The bytes decoding may spend beyond its input: the one fresh model of the declared shape
/// that building the library makes (sums, column norms, scratch), if the shape is allowed.
fn fresh_model_bytes(file: &[u8]) -> usize {
    let body = file.get(HEADER_LEN..).unwrap_or(&[]);
    let u32_at = |at: usize| {
        body.get(at..at + 4)
            .map_or(0, |b| u32::from_le_bytes(b.try_into().unwrap()) as u64)
    };
    let (classes, features) = (u32_at(4), u32_at(8));
    let intercept = body.get(12 + 4 + 8 * 4).is_some_and(|&b| b == 1);
    let columns = features + u64::from(intercept);
    let weights = columns.saturating_mul(classes);
    if weights > MAX_VIEW_WEIGHTS {
        return 0;
    }
    (8 * (weights + columns + classes)) as usize
}

/// Decoding `file` asks for at most a small multiple of its length, plus the fresh model of
/// the shape it declares: no count or length in it can make the decoder reserve more.
fn assert_decode_allocation_bounded(file: &[u8]) {
    let (_, bytes) = measure(|| decode(file));
    let bound = 64 * file.len() + fresh_model_bytes(file) + 4096;
    assert!(
        bytes <= bound,
        "decoding {} bytes asked for {bytes} bytes (bound {bound})",
        file.len()
    );
}

#[test]
fn decoding_a_saved_library_allocates_in_proportion_to_it() {
    // The tracker sees allocations at all.
    let (v, bytes) = measure(|| vec![1u8; 1000]);
    assert!(bytes >= v.len(), "{bytes}");
    let good = encode(&grown());
    assert_decode_allocation_bounded(&good);
    // An empty library of the robot's shape: the fresh model, next to nothing else.
    let mut empty = grown();
    empty.library.views.clear();
    assert_decode_allocation_bounded(&encode(&empty));
}

#[test]
fn a_fifo_is_refused_without_blocking() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lib.tesl");
    nix::unistd::mkfifo(&path, nix::sys::stat::Mode::S_IRWXU).unwrap();
    // On a thread, so a regression (a blocking open) fails the test instead of hanging it.
    let (tx, rx) = std::sync::mpsc::channel();
    let p = path.clone();
    let loader = std::thread::spawn(move || {
        let _ = tx.send(load(&p));
    });
    let result = match rx.recv_timeout(std::time::Duration::from_secs(10)) {
        Ok(r) => r,
        Err(_) => {
            // Give the blocked open its writer, so the thread ends, then fail.
            let _ = OpenOptions::new()
                .write(true)
                .custom_flags(libc::O_NONBLOCK)
                .open(&path);
            panic!("loading a FIFO blocked");
        }
    };
    loader.join().unwrap();
    let err = result.unwrap_err();
    assert!(
        matches!(
            err.problem,
            StoreProblem::File(FileProblem::NotARegularFile { kind: "a FIFO" })
        ),
        "{err}"
    );
    assert!(
        err.to_string().contains("is a FIFO, not a regular file"),
        "{err}"
    );
    assert!(err.to_string().contains("lib.tesl"), "{err}");
    // A save does not replace it either.
    let err = save(&path, &grown()).unwrap_err();
    assert!(
        matches!(
            err.problem,
            StoreProblem::File(FileProblem::NotARegularFile { .. })
        ),
        "{err}"
    );
    assert!(fs::symlink_metadata(&path).unwrap().file_type().is_fifo());
}

#[test]
fn dev_zero_behind_a_symlink_is_refused_before_anything_is_read() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lib.tesl");
    std::os::unix::fs::symlink("/dev/zero", &path).unwrap();
    let (result, bytes) = measure(|| load(&path));
    let err = result.unwrap_err();
    assert!(
        matches!(
            err.problem,
            StoreProblem::File(FileProblem::NotARegularFile {
                kind: "a character device"
            })
        ),
        "{err}"
    );
    assert!(
        err.to_string()
            .contains("is a character device, not a regular file"),
        "{err}"
    );
    assert!(bytes < 4096, "refusing /dev/zero asked for {bytes} bytes");
}

#[test]
fn a_directory_at_the_path_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lib.tesl");
    fs::create_dir(&path).unwrap();
    let err = load(&path).unwrap_err();
    assert!(
        err.to_string()
            .contains("is a directory, not a regular file"),
        "{err}"
    );
    let err = save(&path, &grown()).unwrap_err();
    assert!(
        err.to_string()
            .contains("is a directory, not a regular file"),
        "{err}"
    );
    assert!(path.is_dir());
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
}

#[test]
fn a_dangling_symlink_is_an_error_and_stays_in_place_after_a_save_attempt() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lib.tesl");
    let target = dir.path().join("gone").join("lib.tesl");
    std::os::unix::fs::symlink(&target, &path).unwrap();
    let err = load(&path).unwrap_err();
    match &err.problem {
        StoreProblem::File(FileProblem::DanglingSymlink { target: t }) => assert_eq!(t, &target),
        other => panic!("expected a dangling link, got {other}"),
    }
    let text = err.to_string();
    assert!(text.contains(&path.display().to_string()), "{text}");
    assert!(text.contains(&target.display().to_string()), "{text}");
    assert!(text.contains("which does not exist"), "{text}");
    let err = save(&path, &grown()).unwrap_err();
    assert!(
        matches!(
            err.problem,
            StoreProblem::File(FileProblem::DanglingSymlink { .. })
        ),
        "{err}"
    );
    assert!(
        fs::symlink_metadata(&path)
            .unwrap()
            .file_type()
            .is_symlink()
    );
    assert_eq!(fs::read_link(&path).unwrap(), target);
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1, "nothing else");
}

#[test]
fn a_save_through_a_symlink_writes_its_target_and_keeps_the_link() {
    let dir = tempfile::tempdir().unwrap();
    let elsewhere = dir.path().join("elsewhere");
    fs::create_dir(&elsewhere).unwrap();
    let target = elsewhere.join("real.tesl");
    let path = dir.path().join("lib.tesl");
    let old = grown();
    save(&target, &old).unwrap();
    std::os::unix::fs::symlink(&target, &path).unwrap();
    assert_eq!(load(&path).unwrap(), old);
    let mut new = old.clone();
    new.world = "another".into();
    save(&path, &new).unwrap();
    assert!(
        fs::symlink_metadata(&path)
            .unwrap()
            .file_type()
            .is_symlink()
    );
    assert_eq!(load(&target).unwrap(), new);
    assert_eq!(load(&path).unwrap(), new);
    // No temporary file left in either directory.
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 2);
    assert_eq!(fs::read_dir(&elsewhere).unwrap().count(), 1);
}

#[test]
fn a_declared_body_longer_than_the_file_is_refused_before_allocation() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lib.tesl");
    for declared in [1u64 << 40, u64::MAX, 1000] {
        let mut file = MAGIC.to_vec();
        file.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
        file.extend_from_slice(&declared.to_le_bytes());
        file.extend_from_slice(&0u32.to_le_bytes());
        file.extend_from_slice(&[0; 100]);
        fs::write(&path, &file).unwrap();
        let (result, bytes) = measure(|| load(&path));
        let err = result.unwrap_err();
        match err.problem {
            StoreProblem::Truncated { got, .. } => assert_eq!(got, file.len()),
            other => panic!("{declared}: expected truncated, got {other}"),
        }
        assert!(bytes < 4096, "{declared}: asked for {bytes} bytes");
    }
    // A body shorter than the file: the extra bytes are refused without being read.
    let good = encode(&grown());
    let mut file = good.clone();
    file.extend_from_slice(&[7; 1000]);
    fs::write(&path, &file).unwrap();
    let (result, bytes) = measure(|| load(&path));
    assert!(matches!(
        result.unwrap_err().problem,
        StoreProblem::TrailingBytes(1000)
    ));
    assert!(bytes < 4096, "asked for {bytes} bytes");
}

/// A pid no process has: one above the kernel's limit, else that of a child that has
/// exited and been waited for.
fn dead_pids() -> Vec<u32> {
    let mut pids = Vec::new();
    if let Some(max) = fs::read_to_string("/proc/sys/kernel/pid_max")
        .ok()
        .and_then(|s| s.trim().parse::<u32>().ok())
        .filter(|&m| m < i32::MAX as u32)
    {
        pids.push(max);
    }
    let mut child = std::process::Command::new("true").spawn().unwrap();
    let pid = child.id();
    child.wait().unwrap();
    // Reused already (very unlikely): then it is not dead.
    if !process_exists(pid as i32) {
        pids.push(pid);
    }
    pids
}

#[test]
fn temp_files_of_dead_savers_are_removed_and_live_ones_kept() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lib.tesl");
    save(&path, &grown()).unwrap();
    let touch = |name: &str| {
        let p = dir.path().join(name);
        fs::write(&p, b"half a library").unwrap();
        p
    };
    let dead: Vec<PathBuf> = dead_pids()
        .into_iter()
        .map(|pid| touch(&format!(".lib.tesl.tmp-{pid}")))
        .collect();
    assert!(!dead.is_empty());
    let kept = [
        touch(&format!(".lib.tesl.tmp-{}", std::process::id())),
        touch(".lib.tesl.tmp-abc"),
        touch(".lib.tesl.tmp-"),
        touch(".lib.tesl.tmp-0"),
        touch(".lib.tesl.tmp--5"),
        touch(&format!(".other.tesl.tmp-{}", dead_pids()[0])),
    ];
    let mut expected = dead.clone();
    expected.sort();
    assert_eq!(remove_stale_temp_files(&path).unwrap(), expected);
    for p in &dead {
        assert!(!p.exists(), "{} should be gone", p.display());
    }
    for p in &kept {
        assert!(p.exists(), "{} should be kept", p.display());
    }
    assert!(path.exists());
    // Nothing left to remove; a missing directory holds nothing.
    assert_eq!(
        remove_stale_temp_files(&path).unwrap(),
        Vec::<PathBuf>::new()
    );
    let missing = dir.path().join("no-such-dir").join("lib.tesl");
    assert_eq!(
        remove_stale_temp_files(&missing).unwrap(),
        Vec::<PathBuf>::new()
    );
}

#[test]
fn a_directory_named_like_a_dead_savers_temp_file_is_kept() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lib.tesl");
    let pid = dead_pids()[0];
    let sub = dir.path().join(format!(".lib.tesl.tmp-{pid}"));
    fs::create_dir(&sub).unwrap();
    assert_eq!(
        remove_stale_temp_files(&path).unwrap(),
        Vec::<PathBuf>::new()
    );
    assert!(sub.is_dir());
}

#[test]
fn temp_files_of_a_symlinked_library_are_cleaned_next_to_its_target() {
    let dir = tempfile::tempdir().unwrap();
    let elsewhere = dir.path().join("elsewhere");
    fs::create_dir(&elsewhere).unwrap();
    let target = elsewhere.join("real.tesl");
    save(&target, &grown()).unwrap();
    let path = dir.path().join("lib.tesl");
    std::os::unix::fs::symlink(&target, &path).unwrap();
    let pid = dead_pids()[0];
    let stale = elsewhere.join(format!(".real.tesl.tmp-{pid}"));
    fs::write(&stale, b"x").unwrap();
    let removed = remove_stale_temp_files(&path).unwrap();
    assert_eq!(removed.len(), 1);
    assert!(!stale.exists());
}

/// Bodies near a real library's: a saved body with bytes overwritten, cut or appended, behind
/// a valid header, so decoding gets past the checksum into the body's counts and lengths.
fn mutated_file() -> impl Strategy<Value = Vec<u8>> {
    let body = encode(&grown())[HEADER_LEN..].to_vec();
    let n = body.len();
    (
        proptest::collection::vec((0..n, any::<u8>()), 1..8),
        0..=n,
        proptest::collection::vec(any::<u8>(), 0..16),
    )
        .prop_map(move |(edits, keep, tail)| {
            let mut b = body.clone();
            for (at, v) in edits {
                b[at] = v;
            }
            b.truncate(keep);
            b.extend_from_slice(&tail);
            with_header(&b)
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        assert_decode_allocation_bounded(&bytes);
        // Behind a valid header too, so the body's parser sees them.
        assert_decode_allocation_bounded(&with_header(&bytes));
    }

    #[test]
    fn mutated_bodies_never_panic_nor_over_allocate(file in mutated_file()) {
        assert_decode_allocation_bounded(&file);
    }

    #[test]
    fn any_single_corruption_or_truncation_is_refused(
        at in any::<prop::sample::Index>(),
        flip in 1u8..=255,
        cut in any::<prop::sample::Index>(),
    ) {
        let good = encode(&grown());
        let mut corrupt = good.clone();
        let i = at.index(good.len());
        corrupt[i] ^= flip;
        prop_assert!(decode(&corrupt).is_err());
        let n = cut.index(good.len());
        prop_assert!(decode(&good[..n]).is_err());
        prop_assert!(decode(&good).is_ok());
    }
}

#[test]
fn a_library_pruned_one_view_per_task_round_trips_as_version_2() {
    let mut stored = grown();
    let bytes_v1 = encode(&stored);
    assert_eq!(
        bytes_v1[8..12],
        1u32.to_le_bytes(),
        "pruning to the limit stays version 1"
    );
    assert_eq!(
        decode(&bytes_v1).unwrap().library.params().pruning,
        Pruning::ToLimit
    );
    stored.library.params.pruning = Pruning::OnePerTask;
    let bytes = encode(&stored);
    assert_eq!(bytes[8..12], 2u32.to_le_bytes());
    let back = decode(&bytes).unwrap();
    assert_eq!(back, stored);
    assert_eq!(encode(&back), bytes);
    // A version 2 file saying "to the limit" is not canonical, and refused.
    let mut body = bytes[HEADER_LEN..].to_vec();
    let flag = 4 * 3 + 4 + 8 * 4 + 1; // shape, max_views, four f64, intercept
    assert_eq!(body[flag], 1);
    body[flag] = 0;
    let mut file = MAGIC.to_vec();
    file.extend_from_slice(&2u32.to_le_bytes());
    file.extend_from_slice(&(body.len() as u64).to_le_bytes());
    file.extend_from_slice(&crc32fast::hash(&body).to_le_bytes());
    file.extend_from_slice(&body);
    let err = decode(&file).unwrap_err();
    assert!(
        err.to_string().contains("pruning 0 in a version 2 file"),
        "{err}"
    );
}
