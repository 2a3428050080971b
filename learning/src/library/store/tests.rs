use proptest::prelude::*;

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

/// A file of `body` behind a valid header (magic, version, length, checksum).
fn with_header(body: &[u8]) -> Vec<u8> {
    let mut out = MAGIC.to_vec();
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
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

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let _ = decode(&bytes);
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
