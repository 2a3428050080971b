//! Bad files get a clear error naming the file and the problem, and a truncated recording is
//! read up to its last complete record; nothing panics.

use std::collections::BTreeMap;
use std::path::Path;

use tes_recorder::reader::{ReadError, Recording};
use tes_recorder::writer::{RecordCounts, RunInfo, RunWriter};
use tes_topics::{Command, Observation};

fn info() -> RunInfo {
    RunInfo {
        tes_version: "0.1.0".into(),
        seed: 7,
        controller_toml: "seed = 7\n".into(),
        ..RunInfo::default()
    }
}

/// A complete recording of `n` observations and commands.
fn recording(path: &Path, n: u64) -> RecordCounts {
    let mut w = RunWriter::create(path, &info()).unwrap();
    for seq in 1..=n {
        w.observation(&Observation {
            seq,
            stamp_ns: seq * 1000,
            reward: -0.05,
            ..Observation::default()
        })
        .unwrap();
        w.command(&Command {
            seq,
            answers: seq,
            stamp_ns: seq * 1000 + 40_000,
            observed_ns: seq * 1000,
            action: (seq % 3) as u32,
            ..Command::default()
        })
        .unwrap();
        if seq % 100 == 0 {
            w.flush().unwrap();
        }
    }
    w.finish(RecordCounts::default()).unwrap()
}

#[test]
fn a_complete_recording_reads_back_whole() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    let counts = recording(&path, 500);
    assert_eq!(counts.written[1], 500);
    let r = Recording::open(&path).unwrap();
    assert_eq!((r.observations.len(), r.commands.len()), (500, 500));
    assert_eq!(r.truncated, None);
    assert_eq!(r.run_value("seed"), "7");
    assert!(r.end.is_some());
    assert!(r.library.is_none());
}

#[test]
fn a_truncated_recording_is_read_up_to_its_last_complete_chunk() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    recording(&path, 2000);
    let bytes = std::fs::read(&path).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let r = Recording::open(&cut).unwrap();
    let why = r.truncated.as_deref().expect("said to be truncated");
    assert!(why.contains("records"), "{why}");
    assert!(
        r.observations.len() > 100 && r.observations.len() < 2000,
        "{}",
        r.observations.len()
    );
    assert!(r.end.is_none());
    // Every cut point is refused or read, never a panic.
    for len in (0..bytes.len()).step_by(997) {
        let _ = Recording::from_bytes(&cut, &bytes[..len]);
    }
}

#[test]
fn what_is_not_a_tes_recording_is_refused_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let text = dir.path().join("notes.mcap");
    std::fs::write(&text, "hello").unwrap();
    let e = Recording::open(&text).unwrap_err();
    assert!(matches!(e, ReadError::NotMcap { .. }), "{e}");
    assert!(e.to_string().contains("notes.mcap") && e.to_string().contains("not an MCAP file"));

    let empty = dir.path().join("empty.mcap");
    std::fs::write(&empty, "").unwrap();
    let e = Recording::open(&empty).unwrap_err();
    assert!(e.to_string().contains("empty"), "{e}");

    let missing = Recording::open(&dir.path().join("none.mcap")).unwrap_err();
    assert!(missing.to_string().contains("none.mcap"), "{missing}");

    // Another program's MCAP: a channel of its own, no TES metadata.
    let other = dir.path().join("other.mcap");
    {
        let mut w = mcap::Writer::new(std::io::BufWriter::new(
            std::fs::File::create(&other).unwrap(),
        ))
        .unwrap();
        let ch = w
            .add_channel(0, "/camera", "raw", &BTreeMap::new())
            .unwrap();
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: ch,
                sequence: 1,
                log_time: 1,
                publish_time: 1,
            },
            b"pixels",
        )
        .unwrap();
        w.finish().unwrap();
    }
    let e = Recording::open(&other).unwrap_err();
    assert!(matches!(e, ReadError::NotTes { .. }), "{e}");
    let shown = e.to_string();
    assert!(
        shown.contains("other.mcap")
            && shown.contains("not a TES recording")
            && shown.contains("/camera"),
        "{shown}"
    );
}

#[test]
fn a_recording_of_a_future_version_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let future = dir.path().join("future.mcap");
    {
        let mut w = mcap::Writer::new(std::io::BufWriter::new(
            std::fs::File::create(&future).unwrap(),
        ))
        .unwrap();
        w.write_metadata(&mcap::records::Metadata {
            name: "tes.run".into(),
            metadata: BTreeMap::from([("format_version".to_owned(), "2".to_owned())]),
        })
        .unwrap();
        w.finish().unwrap();
    }
    let e = Recording::open(&future).unwrap_err();
    assert!(matches!(e, ReadError::FutureVersion { .. }), "{e}");
    assert!(e.to_string().contains("format version 2"), "{e}");
}

#[test]
fn a_message_that_does_not_decode_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    recording(&path, 3);
    let mut bytes = std::fs::read(&path).unwrap();
    // Break the second observation's JSON: `"seq":2` becomes `"seq":x`.
    let at = bytes
        .windows(8)
        .position(|w| w == b"\"seq\":2,")
        .expect("the second observation");
    bytes[at + 6] = b'x';
    // Flipped alone it is corruption; with the checksums made again, the message is read.
    let e = Recording::from_bytes(&path, &bytes).unwrap_err();
    assert!(matches!(e, ReadError::Corrupt { .. }), "{e}");
    reseal(&mut bytes);
    let e = Recording::from_bytes(&path, &bytes).unwrap_err();
    let shown = e.to_string();
    assert!(
        shown.contains("run.mcap")
            && shown.contains("/tes/observation")
            && shown.contains("message 1"),
        "{shown}"
    );
}

/// A recording cut anywhere says it was cut, never that it is another program's file or that
/// its run never started: cut before its run metadata it is refused as cut short; cut later it
/// reads as truncated, and a replay of one cut before its world map says so.
#[test]
fn a_cut_recording_is_said_to_be_cut_wherever_it_breaks() {
    use tes_recorder::replay::{ReplayError, replay};
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    recording(&path, 50);
    let bytes = std::fs::read(&path).unwrap();
    let (mut refused, mut read) = (0, 0);
    for len in (8..bytes.len()).step_by(31) {
        match Recording::from_bytes(&path, &bytes[..len]) {
            Err(e @ ReadError::CutBeforeRun { .. }) => {
                assert!(e.to_string().contains("cut short"), "{e}");
                refused += 1;
            }
            Err(e) => panic!("cut at {len} of {}: {e}", bytes.len()),
            Ok(r) => {
                assert!(r.truncated.is_some(), "cut at {len} read as complete");
                // This run has no world map: cut, it is not "a run that never started".
                let e = replay(&r).unwrap_err();
                assert!(matches!(e, ReplayError::CutBeforeMap(_)), "{e}");
                read += 1;
            }
        }
    }
    assert!(refused > 0 && read > 0, "{refused} refused, {read} read");
    // Whole and without a world map, the run did not start.
    let whole = Recording::open(&path).unwrap();
    assert!(matches!(replay(&whole).unwrap_err(), ReplayError::NoMap));
}

/// Recomputes the checksums of a recording's chunks and data section, as if its bytes had
/// been written as they are now.
fn reseal(bytes: &mut [u8]) {
    let mut at = 8;
    while at + 9 <= bytes.len() {
        let opcode = bytes[at];
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
        let body = at + 9;
        match opcode {
            0x06 => {
                let name_len =
                    u32::from_le_bytes(bytes[body + 28..body + 32].try_into().unwrap()) as usize;
                let records = body + 32 + name_len + 8;
                let crc = crc32fast::hash(&bytes[records..body + len]);
                bytes[body + 24..body + 28].copy_from_slice(&crc.to_le_bytes());
            }
            0x0F => {
                let crc = crc32fast::hash(&bytes[..at]);
                bytes[body..body + 4].copy_from_slice(&crc.to_le_bytes());
                return;
            }
            _ => {}
        }
        at = body + len;
    }
}

/// Every single flipped byte of a complete recording's data section (header, chunks,
/// metadata, attachments, the data end) makes it corrupt — never read as if whole, never
/// said to be cut short — and so does one in its summary.
#[test]
fn a_flipped_byte_is_corruption_not_a_cut() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    recording(&path, 5);
    let bytes = std::fs::read(&path).unwrap();
    let data_end = bytes
        .windows(9)
        .rposition(|w| w[0] == 0x0F && w[1..] == 4u64.to_le_bytes())
        .expect("a data end record");
    let mut flipped = bytes.clone();
    for at in (8..data_end + 13).chain([data_end + 20, bytes.len() - 40, bytes.len() - 3]) {
        flipped[at] ^= 0x10;
        match Recording::from_bytes(&path, &flipped) {
            Err(ReadError::Corrupt { why, .. }) => assert!(!why.is_empty()),
            Err(e) => panic!("byte {at} flipped: {e}"),
            Ok(r) => panic!("byte {at} flipped read as {:?}", r.truncated),
        }
        flipped[at] = bytes[at];
    }
    let e = Recording::from_bytes(&path, &{
        let mut b = bytes.clone();
        b[200] ^= 1;
        b
    })
    .unwrap_err();
    assert!(e.to_string().contains("is corrupt"), "{e}");
}

/// `Recording::open` reads a regular file only, checks its magic before reading on, and
/// refuses one over `MAX_RECORDING_BYTES` unread.
#[test]
fn open_refuses_what_is_not_a_recording_file_before_reading_it() {
    let dir = tempfile::tempdir().unwrap();
    let e = Recording::open(Path::new("/dev/zero")).unwrap_err();
    assert!(
        e.to_string()
            .contains("is a character device, not a regular file"),
        "{e}"
    );
    let fifo = dir.path().join("fifo.mcap");
    nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::S_IRWXU).unwrap();
    let e = Recording::open(&fifo).unwrap_err();
    assert!(
        e.to_string().contains("is a FIFO, not a regular file"),
        "{e}"
    );
    let sparse = |name: &str, start: &[u8]| {
        let path = dir.path().join(name);
        std::fs::write(&path, start).unwrap();
        std::fs::OpenOptions::new()
            .write(true)
            .open(&path)
            .and_then(|f| f.set_len(2 << 30))
            .unwrap();
        path
    };
    let e = Recording::open(&sparse("zeros.mcap", b"")).unwrap_err();
    assert!(matches!(e, ReadError::NotMcap { .. }), "{e}");
    let e = Recording::open(&sparse("huge.mcap", mcap::MAGIC)).unwrap_err();
    assert!(
        e.to_string().contains(&format!(
            "more than the {} bytes",
            tes_recorder::reader::MAX_RECORDING_BYTES
        )),
        "{e}"
    );
}
