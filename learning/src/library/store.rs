//! Saving and loading a [`ViewLibrary`]: the agent's lifelong memory on disk.
//!
//! A library file is versioned, checksummed and written atomically: the whole file goes to a
//! temporary file in the same directory, is flushed to disk (`fsync`), and is renamed over the
//! old one, whose directory is then flushed too. A reader therefore sees either the previous
//! complete file or the new complete file, never a mix; a failed save leaves the previous
//! file untouched.
//!
//! # Format, versions 1 and 2
//!
//! All integers little-endian; `f64` as IEEE-754 bits.
//!
//! | bytes | field |
//! |---|---|
//! | 8 | magic `TESVLIB\0` |
//! | 4 | format version `u32` (= [`FORMAT_VERSION`]) |
//! | 8 | body length `u64` |
//! | 4 | CRC-32 (IEEE) of the body `u32` |
//! | body | see below |
//!
//! Body: `n_actions u32, n_effects u32, n_features u32`; the parameters `max_views u32,
//! growth_threshold f64, recency f64, lambda f64, alpha f64, intercept u8` and, in version 2
//! only, `pruning u8` (0 to the limit, 1 one view per task as Algorithm 2); `tasks_seen u32,
//! next_id u64`; the world name (`u32` length + UTF-8); the action names and the feature names
//! (each a `u32` count, then `u32` length + UTF-8 per name; count 0 = unnamed); `u32` view
//! count, then per view: `id u64, action u32, updates u64`, the gradient sums (`u32` count +
//! `f64` each), the tasks won (`u32` count + `u32` each), and the score history (`u32` count,
//! then `task u32, score f64, observations u64, won u8` each).
//!
//! A library that prunes to its limit (the default) is written as version 1, which older builds
//! read; only one that prunes a view per task needs version 2. A version 1 file reads as
//! pruning to the limit.
//!
//! Loading checks everything: magic, version, length, checksum, then that the body is
//! consistent (shapes, parameters, ids, histories) before anything is built. Every count is
//! checked against the bytes left before memory is reserved for it, and a view shape beyond
//! [`MAX_VIEW_WEIGHTS`] is refused before a model of that shape is allocated.
//!
//! # The file on disk
//!
//! [`load`] opens the path once as every TES file is opened ([`tes_files::open_regular`]),
//! without blocking (a FIFO must not hang the caller), and refuses anything that is not a
//! regular file — a FIFO, a device such as `/dev/zero`, a directory, a socket — before
//! reading a byte of it. It reads the header, refuses a body
//! length the file's size cannot hold, and then reads exactly that much, so no file can make
//! it allocate more than the file really holds. A symbolic link is followed; a dangling one
//! is an error naming the link and its missing target.
//!
//! [`save`] through a symbolic link writes the link's *target* (atomically, in the target's
//! directory) and leaves the link in place: whoever made the link meant the library to live
//! where it points, and renaming over the link itself would silently move the library away
//! from there. A save through a dangling link, or over something that is not a regular file,
//! is refused.
//!
//! A save killed mid-write leaves its temporary file `.<name>.tmp-<pid>` behind;
//! [`remove_stale_temp_files`] removes those whose process is gone.

use std::fs::{self, File};
use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};

use tes_files::{FileProblem, Opened};
use thiserror::Error;

use super::{LibraryParams, Pruning, TaskScore, View, ViewLibrary};
use crate::mdagl::{Mdagl, MdaglParams, MdaglStateError};

/// The file's magic bytes.
pub const MAGIC: [u8; 8] = *b"TESVLIB\0";
/// The newest format version this build writes and reads.
pub const FORMAT_VERSION: u32 = 2;
const HEADER_LEN: usize = 8 + 4 + 8 + 4;
/// The largest view a file may describe, in weights (effects × (features + intercept)):
/// 2^24, 128 MiB of gradient sums per view. The paper's robot needs 20 × 312.
pub const MAX_VIEW_WEIGHTS: u64 = crate::mdagl::MAX_WEIGHTS as u64;

/// A library with what names its actions and features, as stored.
#[derive(Debug, Clone, PartialEq)]
pub struct StoredLibrary {
    /// The views.
    pub library: ViewLibrary,
    /// Which world trained it (free text, e.g. "grid suite 2017" or "arena 3").
    pub world: String,
    /// One name per action, or empty.
    pub action_names: Vec<String>,
    /// One name per feature, or empty.
    pub feature_names: Vec<String>,
}

/// What is wrong with a library file (or its save).
#[derive(Debug, Error)]
pub enum StoreProblem {
    /// Reading or writing failed.
    #[error("{0}")]
    Io(#[from] io::Error),
    /// The path is not a regular file or is a dangling symbolic link
    /// ([`tes_files::open_regular`]); nothing was read from it. (A file that cannot be opened
    /// is [`StoreProblem::Io`].)
    #[error(transparent)]
    File(FileProblem),
    /// Not a TES view library.
    #[error("not a TES view library (bad magic bytes)")]
    NotALibrary,
    /// Written by a newer format.
    #[error("written by a newer TES: format v{0}, this build reads v{FORMAT_VERSION}")]
    FutureVersion(u32),
    /// Shorter than its header says.
    #[error("truncated: {needed} bytes needed, {got} present")]
    Truncated {
        /// Bytes the header or a count requires.
        needed: usize,
        /// Bytes there.
        got: usize,
    },
    /// Bytes after the body.
    #[error("{0} unexpected bytes after the library")]
    TrailingBytes(usize),
    /// The checksum does not match.
    #[error("corrupt: checksum {stored:08x} stored, {computed:08x} computed")]
    Corrupt {
        /// In the header.
        stored: u32,
        /// Of the body.
        computed: u32,
    },
    /// The body decodes but does not make a valid library.
    #[error("inconsistent: {0}")]
    Inconsistent(String),
    /// The views' shape is too large to load (more than [`MAX_VIEW_WEIGHTS`] weights).
    #[error(
        "views of {effects} effects and {features} features ({weights} weights) are larger \
         than the {MAX_VIEW_WEIGHTS} weights a view may have"
    )]
    TooLarge {
        /// The file's effects.
        effects: usize,
        /// The file's features.
        features: usize,
        /// `effects × (features + 1 if there is an intercept)`.
        weights: u64,
    },
    /// A view's model cannot be restored.
    #[error("view {id}: {source}")]
    BadView {
        /// The view's id.
        id: u64,
        /// Why.
        source: MdaglStateError,
    },
    /// The library is for another shape of world.
    #[error(
        "views of {found_actions} actions, {found_effects} effects and {found_features} \
         features; this world has {actions}, {effects} and {features}"
    )]
    WrongShape {
        /// The file's actions.
        found_actions: usize,
        /// The file's effects.
        found_effects: usize,
        /// The file's features.
        found_features: usize,
        /// The world's actions.
        actions: usize,
        /// The world's effects.
        effects: usize,
        /// The world's features.
        features: usize,
    },
}

impl From<FileProblem> for StoreProblem {
    fn from(problem: FileProblem) -> Self {
        match problem {
            FileProblem::Io(e) => StoreProblem::Io(e),
            refused => StoreProblem::File(refused),
        }
    }
}

/// A library file could not be loaded or saved; names the file.
#[derive(Debug, Error)]
#[error("view library {}: {problem}", path.display())]
pub struct StoreError {
    /// The file.
    pub path: PathBuf,
    /// What went wrong.
    pub problem: StoreProblem,
}

impl StoreError {
    fn new(path: &Path, problem: impl Into<StoreProblem>) -> Self {
        Self {
            path: path.to_owned(),
            problem: problem.into(),
        }
    }
}

/// Saves `stored` to `path` atomically (see the module docs). On error the previous file at
/// `path`, if any, is untouched, and no temporary file is left behind. If `path` is a
/// symbolic link, its target is written and the link stays; a dangling link, or a path that
/// names something other than a regular file, is refused.
pub fn save(path: &Path, stored: &StoredLibrary) -> Result<(), StoreError> {
    check_names(stored).map_err(|p| StoreError::new(path, p))?;
    let bytes = encode(stored);
    save_bytes(path, &bytes, |file, bytes| file.write_all(bytes))
}

/// The atomic write, with the byte writer injectable so tests can make it fail.
fn save_bytes(
    path: &Path,
    bytes: &[u8],
    write: impl FnOnce(&mut File, &[u8]) -> io::Result<()>,
) -> Result<(), StoreError> {
    let err = |e: io::Error| StoreError::new(path, e);
    let target = save_target(path).map_err(|p| StoreError::new(path, p))?;
    let (dir, name) = dir_and_name(&target).map_err(err)?;
    let tmp = dir.join(temp_name(&name, std::process::id()));
    let result = (|| {
        let mut file = File::create(&tmp)?;
        write(&mut file, bytes)?;
        file.sync_all()?;
        drop(file);
        fs::rename(&tmp, &target)?;
        // The rename is durable once the directory is.
        File::open(&dir)?.sync_all()
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result.map_err(err)
}

/// The file a save of `path` replaces: `path` itself, or the target of the symbolic link at
/// `path` (renaming over the link would replace the link, not the library it points to).
fn save_target(path: &Path) -> Result<PathBuf, StoreProblem> {
    let meta = match fs::symlink_metadata(path) {
        Ok(m) => m,
        // Nothing there yet (or the directory is unreadable, which the write reports).
        Err(_) => return Ok(path.to_owned()),
    };
    let target = if meta.file_type().is_symlink() {
        match fs::canonicalize(path) {
            Ok(t) => t,
            Err(e) if e.kind() == io::ErrorKind::NotFound => {
                return Err(tes_files::dangling(path, e).into());
            }
            Err(e) => return Err(e.into()),
        }
    } else {
        path.to_owned()
    };
    let meta = fs::metadata(&target)?;
    if !meta.is_file() {
        return Err(FileProblem::NotARegularFile {
            kind: tes_files::kind_of(meta.file_type()),
        }
        .into());
    }
    Ok(target)
}

/// The directory a file is in (`.` for a bare name) and its name.
fn dir_and_name(path: &Path) -> io::Result<(PathBuf, String)> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_owned(),
        _ => PathBuf::from("."),
    };
    let name = path
        .file_name()
        .ok_or_else(|| io::Error::other("the path names no file"))?;
    Ok((dir, name.to_string_lossy().into_owned()))
}

/// The temporary file process `pid` writes a save of the file `name` to.
fn temp_name(name: &str, pid: u32) -> String {
    format!("{}{pid}", temp_prefix(name))
}

/// What the temporary files of saves of the file `name` are called, up to the pid.
fn temp_prefix(name: &str) -> String {
    format!(".{name}.tmp-")
}

/// Loads the library at `path`. Refuses anything but a regular file without reading from it
/// (and without blocking on a FIFO), and never allocates more than the file holds.
pub fn load(path: &Path) -> Result<StoredLibrary, StoreError> {
    let bytes = read_library_file(path).map_err(|p| StoreError::new(path, p))?;
    decode(&bytes).map_err(|p| StoreError::new(path, p))
}

/// The bytes of the library file at `path`: its header and the body length the header
/// declares (plus one byte, so a file that grew since is refused as having trailing bytes).
fn read_library_file(path: &Path) -> Result<Vec<u8>, StoreProblem> {
    let Opened { mut file, size } = tes_files::open_regular(path)?;
    let mut bytes = Vec::with_capacity(HEADER_LEN);
    Read::by_ref(&mut file)
        .take(HEADER_LEN as u64)
        .read_to_end(&mut bytes)?;
    let header = parse_header(&bytes)?;
    // Refused before anything is reserved: the body must fit the file.
    check_body_len(header.len, size)?;
    let len = usize::try_from(header.len).map_err(|_| StoreProblem::Truncated {
        needed: usize::MAX,
        got: usize::try_from(size).unwrap_or(usize::MAX),
    })?;
    bytes
        .try_reserve_exact(len)
        .map_err(|e| io::Error::new(io::ErrorKind::OutOfMemory, e))?;
    file.take(header.len.saturating_add(1))
        .read_to_end(&mut bytes)?;
    Ok(bytes)
}

/// Removes the temporary files that interrupted saves of the library at `path` left behind
/// (`.<name>.tmp-<pid>` in its directory, or in its target's if `path` is a symbolic link)
/// whose process no longer exists, and returns them. A temporary file of a live process —
/// this one included, whose saver may be writing it — is kept: it may be a save under way
/// (a process's next save replaces its own leftover anyway). A missing directory holds
/// nothing to remove.
pub fn remove_stale_temp_files(path: &Path) -> Result<Vec<PathBuf>, StoreError> {
    let err = |e: io::Error| StoreError::new(path, e);
    // Saves through a link write next to its target; a dangling link has nothing to clean.
    let target = save_target(path).unwrap_or_else(|_| path.to_owned());
    let (dir, name) = dir_and_name(&target).map_err(err)?;
    let prefix = temp_prefix(&name);
    let entries = match fs::read_dir(&dir) {
        Ok(entries) => entries,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(err(e)),
    };
    let mut removed = Vec::new();
    for entry in entries {
        let entry = entry.map_err(err)?;
        let file_name = entry.file_name();
        let Some(pid) = file_name
            .to_string_lossy()
            .strip_prefix(prefix.as_str())
            .and_then(parse_pid)
        else {
            continue;
        };
        // Only regular files: never follow or remove anything else by that name.
        if !entry.file_type().is_ok_and(|t| t.is_file()) || process_exists(pid) {
            continue;
        }
        let tmp = entry.path();
        match fs::remove_file(&tmp) {
            Ok(()) => removed.push(tmp),
            // Another process cleaned it up first.
            Err(e) if e.kind() == io::ErrorKind::NotFound => {}
            Err(e) => return Err(StoreError::new(&tmp, e)),
        }
    }
    removed.sort();
    Ok(removed)
}

/// A temporary file's pid suffix: decimal digits only, a positive `pid_t`.
fn parse_pid(suffix: &str) -> Option<i32> {
    if suffix.is_empty() || !suffix.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    suffix.parse::<i32>().ok().filter(|&p| p > 0)
}

/// Whether process `pid` exists: `kill(pid, 0)` fails with `ESRCH` only when it does not
/// (`EPERM` means it exists under another user). Anything unexpected counts as alive, so a
/// file is never removed on doubt.
fn process_exists(pid: i32) -> bool {
    // SAFETY: kill with signal 0 sends nothing; it only checks that `pid` exists.
    let sent = unsafe { libc::kill(pid, 0) };
    sent == 0 || std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
}

/// Loads the library at `path` and checks it holds views for a world of this shape.
pub fn load_for(
    path: &Path,
    actions: usize,
    effects: usize,
    features: usize,
) -> Result<StoredLibrary, StoreError> {
    let stored = load(path)?;
    let l = &stored.library;
    if (l.n_actions, l.n_effects, l.n_features) != (actions, effects, features) {
        return Err(StoreError::new(
            path,
            StoreProblem::WrongShape {
                found_actions: l.n_actions,
                found_effects: l.n_effects,
                found_features: l.n_features,
                actions,
                effects,
                features,
            },
        ));
    }
    Ok(stored)
}

fn check_names(stored: &StoredLibrary) -> Result<(), StoreProblem> {
    let l = &stored.library;
    for (what, names, n) in [
        ("action", &stored.action_names, l.n_actions),
        ("feature", &stored.feature_names, l.n_features),
    ] {
        if !names.is_empty() && names.len() != n {
            return Err(StoreProblem::Inconsistent(format!(
                "{} {what} names for {n} {what}s",
                names.len()
            )));
        }
    }
    Ok(())
}

/// The whole file's bytes.
pub fn encode(stored: &StoredLibrary) -> Vec<u8> {
    let mut body = Writer(Vec::new());
    let l = &stored.library;
    body.u32(l.n_actions as u32);
    body.u32(l.n_effects as u32);
    body.u32(l.n_features as u32);
    body.u32(l.params.max_views as u32);
    body.f64(l.params.growth_threshold);
    body.f64(l.params.recency);
    body.f64(l.params.mdagl.lambda);
    body.f64(l.params.mdagl.alpha);
    body.0.push(u8::from(l.params.mdagl.intercept));
    let version = match l.params.pruning {
        Pruning::ToLimit => 1,
        Pruning::OnePerTask => {
            body.0.push(1);
            2
        }
    };
    body.u32(l.tasks_seen);
    body.u64(l.next_id);
    body.str(&stored.world);
    for names in [&stored.action_names, &stored.feature_names] {
        body.u32(names.len() as u32);
        names.iter().for_each(|n| body.str(n));
    }
    body.u32(l.views.len() as u32);
    for v in &l.views {
        body.u64(v.id);
        body.u32(v.action as u32);
        body.u64(v.model.n_updates());
        let sums = v.model.gradient_sums();
        body.u32(sums.len() as u32);
        sums.iter().for_each(|&s| body.f64(s));
        body.u32(v.wins.len() as u32);
        v.wins.iter().for_each(|&t| body.u32(t));
        body.u32(v.history.len() as u32);
        for h in &v.history {
            body.u32(h.task);
            body.f64(h.score);
            body.u64(h.observations);
            body.0.push(u8::from(h.won));
        }
    }
    let body = body.0;
    let mut out = Vec::with_capacity(HEADER_LEN + body.len());
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&u32::to_le_bytes(version));
    out.extend_from_slice(&(body.len() as u64).to_le_bytes());
    out.extend_from_slice(&crc32fast::hash(&body).to_le_bytes());
    out.extend_from_slice(&body);
    out
}

/// What the header says about the body.
struct Header {
    /// The format version.
    version: u32,
    /// The body's length.
    len: u64,
    /// The body's CRC-32.
    crc: u32,
}

/// Checks the header at the start of `bytes` (magic, version) and reads the body's length
/// and checksum.
fn parse_header(bytes: &[u8]) -> Result<Header, StoreProblem> {
    if bytes.len() < 8 || bytes[..8] != MAGIC {
        if bytes.len() < 8 && MAGIC.starts_with(bytes) {
            return Err(StoreProblem::Truncated {
                needed: HEADER_LEN,
                got: bytes.len(),
            });
        }
        return Err(StoreProblem::NotALibrary);
    }
    if bytes.len() < HEADER_LEN {
        return Err(StoreProblem::Truncated {
            needed: HEADER_LEN,
            got: bytes.len(),
        });
    }
    let mut header = Reader(&bytes[8..HEADER_LEN]);
    let version = header.u32()?;
    if version > FORMAT_VERSION {
        return Err(StoreProblem::FutureVersion(version));
    }
    if version == 0 {
        return Err(StoreProblem::Inconsistent("format version 0".into()));
    }
    Ok(Header {
        version,
        len: header.u64()?,
        crc: header.u32()?,
    })
}

/// Checks that a file of `size` bytes holds the header and a body of `len` bytes, no more.
fn check_body_len(len: u64, size: u64) -> Result<(), StoreProblem> {
    let to_usize = |n: u64| usize::try_from(n).unwrap_or(usize::MAX);
    let body = size.saturating_sub(HEADER_LEN as u64);
    if body < len {
        return Err(StoreProblem::Truncated {
            needed: HEADER_LEN.saturating_add(to_usize(len)),
            got: to_usize(size),
        });
    }
    if body > len {
        return Err(StoreProblem::TrailingBytes(to_usize(body - len)));
    }
    Ok(())
}

/// Decodes and checks a whole file's bytes.
pub fn decode(bytes: &[u8]) -> Result<StoredLibrary, StoreProblem> {
    let Header {
        version,
        len,
        crc: stored_crc,
    } = parse_header(bytes)?;
    check_body_len(len, bytes.len() as u64)?;
    let body = &bytes[HEADER_LEN..];
    let computed = crc32fast::hash(body);
    if computed != stored_crc {
        return Err(StoreProblem::Corrupt {
            stored: stored_crc,
            computed,
        });
    }
    decode_body(&mut Reader(body), version)
}

fn decode_body(r: &mut Reader<'_>, version: u32) -> Result<StoredLibrary, StoreProblem> {
    let shape = decode_shape(r, version)?;
    let mut library = ViewLibrary::new(
        shape.n_actions,
        shape.n_effects,
        shape.n_features,
        shape.params,
    )
    .map_err(|e| inconsistent(e.to_string()))?;
    library.tasks_seen = r.u32()?;
    library.next_id = r.u64()?;
    let world = r.str()?;
    let [action_names, feature_names] = decode_names(r)?;
    decode_views(r, &shape, &mut library)?;
    if !r.0.is_empty() {
        return Err(inconsistent(format!(
            "{} bytes left after the last view",
            r.0.len()
        )));
    }
    let stored = StoredLibrary {
        library,
        world,
        action_names,
        feature_names,
    };
    check_names(&stored)?;
    Ok(stored)
}

/// A file's inconsistency, said in `message`.
fn inconsistent(message: String) -> StoreProblem {
    StoreProblem::Inconsistent(message)
}

/// What the body says of its library's shape, before any view.
struct Shape {
    n_actions: usize,
    n_effects: usize,
    n_features: usize,
    params: LibraryParams,
    /// A view's model's columns: the features, and the intercept if any.
    columns: u64,
    /// A view's model's weights: `columns` per effect.
    weights: u64,
}

/// Reads the library's shape and parameters, and refuses a shape whose views are too large
/// to build: building the library builds a fresh model of this shape.
fn decode_shape(r: &mut Reader<'_>, version: u32) -> Result<Shape, StoreProblem> {
    let n_actions = r.u32()? as usize;
    let n_effects = r.u32()? as usize;
    let n_features = r.u32()? as usize;
    let mut params = LibraryParams {
        max_views: r.u32()? as usize,
        growth_threshold: r.f64()?,
        recency: r.f64()?,
        mdagl: MdaglParams {
            lambda: r.f64()?,
            alpha: r.f64()?,
            intercept: match r.u8()? {
                0 => false,
                1 => true,
                b => return Err(inconsistent(format!("intercept flag {b}"))),
            },
        },
        pruning: Pruning::ToLimit,
    };
    if version >= 2 {
        // Version 2 exists for the one pruning version 1 cannot say: a library pruned to its
        // limit is written as version 1, so each library has exactly one encoding.
        params.pruning = match r.u8()? {
            1 => Pruning::OnePerTask,
            b => return Err(inconsistent(format!("pruning {b} in a version 2 file"))),
        };
    }
    let columns = n_features as u64 + u64::from(params.mdagl.intercept);
    let weights = columns.saturating_mul(n_effects as u64);
    if weights > MAX_VIEW_WEIGHTS {
        return Err(StoreProblem::TooLarge {
            effects: n_effects,
            features: n_features,
            weights,
        });
    }
    Ok(Shape {
        n_actions,
        n_effects,
        n_features,
        params,
        columns,
        weights,
    })
}

/// Reads the action names, then the feature names.
fn decode_names(r: &mut Reader<'_>) -> Result<[Vec<String>; 2], StoreProblem> {
    let mut names = [Vec::new(), Vec::new()];
    for list in &mut names {
        let n = r.count(4)?;
        for _ in 0..n {
            list.push(r.str()?);
        }
    }
    Ok(names)
}

/// Reads the views into `library`, each checked against the library and the views before it.
fn decode_views(
    r: &mut Reader<'_>,
    shape: &Shape,
    library: &mut ViewLibrary,
) -> Result<(), StoreProblem> {
    let n_views = r.count(8 + 4 + 8 + 4 + 4 + 4)?;
    if library.params.pruning == Pruning::ToLimit && n_views > library.params.max_views {
        return Err(inconsistent(format!(
            "{n_views} views, more than the library's limit of {}",
            library.params.max_views
        )));
    }
    for _ in 0..n_views {
        let fields = ViewFields::decode(r, shape)?;
        fields.check(shape, library)?;
        let ViewFields {
            id,
            action,
            updates,
            sums,
            wins,
            history,
        } = fields;
        let model = Mdagl::from_state(
            shape.n_effects,
            shape.n_features,
            shape.params.mdagl,
            updates,
            sums,
        )
        .map_err(|source| StoreProblem::BadView { id, source })?;
        library.views.push(View {
            id,
            action,
            model,
            wins,
            history,
        });
    }
    Ok(())
}

/// One view as the file stores it, before its model is restored.
struct ViewFields {
    id: u64,
    action: usize,
    updates: u64,
    sums: Vec<f64>,
    wins: Vec<u32>,
    history: Vec<TaskScore>,
}

impl ViewFields {
    /// Reads one view. Restoring a model builds one of the full shape first: so its sums are
    /// read only if they fit that shape, and each view's model is paid for by bytes of the
    /// file.
    fn decode(r: &mut Reader<'_>, shape: &Shape) -> Result<Self, StoreProblem> {
        let id = r.u64()?;
        let action = r.u32()? as usize;
        let updates = r.u64()?;
        let n_sums = r.count(8)?;
        let expected = usize::try_from(shape.weights).unwrap_or(usize::MAX);
        if n_sums != expected {
            return Err(StoreProblem::BadView {
                id,
                source: MdaglStateError::WrongLength {
                    got: n_sums,
                    expected,
                    classes: shape.n_effects,
                    columns: usize::try_from(shape.columns).unwrap_or(usize::MAX),
                },
            });
        }
        let mut sums = Vec::with_capacity(n_sums);
        for _ in 0..n_sums {
            sums.push(r.f64()?);
        }
        let n_wins = r.count(4)?;
        let mut wins = Vec::with_capacity(n_wins);
        for _ in 0..n_wins {
            wins.push(r.u32()?);
        }
        let n_history = r.count(4 + 8 + 8 + 1)?;
        let mut history = Vec::with_capacity(n_history);
        for _ in 0..n_history {
            history.push(TaskScore {
                task: r.u32()?,
                score: r.f64()?,
                observations: r.u64()?,
                won: match r.u8()? {
                    0 => false,
                    1 => true,
                    b => return Err(inconsistent(format!("view {id}: won flag {b}"))),
                },
            });
        }
        Ok(Self {
            id,
            action,
            updates,
            sums,
            wins,
            history,
        })
    }

    /// Checks the view against the library: an action it has, an id it has handed out and
    /// no other view has, tasks it has seen.
    fn check(&self, shape: &Shape, library: &ViewLibrary) -> Result<(), StoreProblem> {
        let (id, action, n_actions) = (self.id, self.action, shape.n_actions);
        if action >= n_actions {
            return Err(inconsistent(format!(
                "view {id} is for action {action} of {n_actions}"
            )));
        }
        if id >= library.next_id {
            return Err(inconsistent(format!(
                "view id {id} is not below the next id {}",
                library.next_id
            )));
        }
        if library.views.iter().any(|v| v.id == id) {
            return Err(inconsistent(format!("two views with id {id}")));
        }
        if let Some(t) = self
            .wins
            .iter()
            .chain(self.history.iter().map(|h| &h.task))
            .find(|&&t| t >= library.tasks_seen)
        {
            return Err(inconsistent(format!(
                "view {id} records task {t}, but only {} tasks were seen",
                library.tasks_seen
            )));
        }
        Ok(())
    }
}

struct Writer(Vec<u8>);

impl Writer {
    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.0.extend_from_slice(&v.to_bits().to_le_bytes());
    }
    fn str(&mut self, s: &str) {
        self.u32(s.len() as u32);
        self.0.extend_from_slice(s.as_bytes());
    }
}

struct Reader<'a>(&'a [u8]);

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> Result<[u8; N], StoreProblem> {
        if self.0.len() < N {
            return Err(StoreProblem::Inconsistent(format!(
                "the body ends {} bytes early",
                N - self.0.len()
            )));
        }
        let (head, rest) = self.0.split_at(N);
        self.0 = rest;
        let mut out = [0; N];
        out.copy_from_slice(head);
        Ok(out)
    }
    fn u8(&mut self) -> Result<u8, StoreProblem> {
        Ok(self.take::<1>()?[0])
    }
    fn u32(&mut self) -> Result<u32, StoreProblem> {
        Ok(u32::from_le_bytes(self.take()?))
    }
    fn u64(&mut self) -> Result<u64, StoreProblem> {
        Ok(u64::from_le_bytes(self.take()?))
    }
    fn f64(&mut self) -> Result<f64, StoreProblem> {
        Ok(f64::from_bits(self.u64()?))
    }
    /// A `u32` count of items of at least `item_len` bytes each, refused if the bytes left
    /// cannot hold that many (so a corrupt count never reserves memory).
    fn count(&mut self, item_len: usize) -> Result<usize, StoreProblem> {
        let n = self.u32()? as usize;
        if n.saturating_mul(item_len) > self.0.len() {
            return Err(StoreProblem::Inconsistent(format!(
                "a count of {n} items does not fit the {} bytes left",
                self.0.len()
            )));
        }
        Ok(n)
    }
    fn str(&mut self) -> Result<String, StoreProblem> {
        let n = self.count(1)?;
        let (s, rest) = self.0.split_at(n);
        self.0 = rest;
        String::from_utf8(s.to_vec())
            .map_err(|_| StoreProblem::Inconsistent("a name is not UTF-8".into()))
    }
}

#[cfg(test)]
mod tests;
