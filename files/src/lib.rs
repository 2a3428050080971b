//! Opening the files TES settings and commands name, one way everywhere: a view library, a
//! launch file, a recording, `tes fit`'s rows, the link's keys and certificates.
//!
//! A path a person typed can name anything: a FIFO no one writes to (an `open` that never
//! returns), `/dev/zero` (a read that never ends), a directory, a sparse file of gigabytes
//! holding nothing, a symbolic link to any of those. So every file is opened here the same
//! way:
//!
//! - [`open_regular`] refuses what is visibly not a regular file before opening it (opening
//!   a device can do things: a serial port's control lines, a tape's rewind), opens with
//!   `O_NONBLOCK | O_NOCTTY` (a FIFO without a writer returns at once instead of waiting for
//!   one, a terminal does not become the controlling one), and checks the *opened* file with
//!   `fstat` — that check is the one that counts, since the path may change between the two.
//!   Nothing is read before it passes.
//! - [`read_capped`] and [`read_text`] decide the size from `fstat` before allocating,
//!   refuse a file over the caller's stated limit without reading it, and never read past
//!   the limit even if the file grows meanwhile.
//! - [`check_private_file`] and [`check_private_dir`] refuse a key file, or its directory,
//!   that anyone but its owner may open, naming the `chmod` command that fixes it.
//! - [`read_until_capped`] reads one line of a stream up to a stated length, and
//!   [`InflationGuard`] stops a decompressor whose output outgrows its input by more than a
//!   stated [`InflationBound`] (a "zip bomb").
//!
//! Every refusal is a [`FileProblem`]; [`FileError`] adds the path.
//!
//! ```
//! use tes_files::{FileProblem, read_capped};
//!
//! let err = read_capped(std::path::Path::new("/dev/zero"), 1 << 20).unwrap_err();
//! assert!(matches!(err, FileProblem::NotARegularFile { kind: "a character device" }));
//! assert_eq!(err.to_string(), "is a character device, not a regular file");
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::fs::{self, File, OpenOptions};
use std::io::{self, BufRead, Read};
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use thiserror::Error;

/// Why a file was refused or could not be read.
#[derive(Debug, Error)]
pub enum FileProblem {
    /// Opening or reading failed.
    #[error("{0}")]
    Io(#[from] io::Error),
    /// The path names something other than a regular file; nothing was read from it.
    #[error("is {kind}, not a regular file")]
    NotARegularFile {
        /// What it is, e.g. "a FIFO" or "a character device" ([`kind_of`]).
        kind: &'static str,
    },
    /// The path is a symbolic link whose target does not exist.
    #[error("is a symbolic link to {}, which does not exist", target.display())]
    DanglingSymlink {
        /// Where the link points.
        target: PathBuf,
    },
    /// Larger than the caller reads; nothing was read from it.
    #[error("is {size} bytes, more than the {limit} bytes read from such a file")]
    TooLarge {
        /// Its size (at least; it may have grown while read).
        size: u64,
        /// The largest size read.
        limit: u64,
    },
    /// Someone other than its owner may open it (a key), or change what it holds (a key's
    /// directory).
    #[error(
        "is {what} with mode {mode:04o}: {who} may {may} it; run `{fix}`",
        mode = mode & 0o7777
    )]
    TooOpen {
        /// "a key file" or "a key's directory", …
        what: &'static str,
        /// Its permission bits.
        mode: u32,
        /// "others", "its group" or "its group and others".
        who: &'static str,
        /// What they may do: "read", "replace files in", …
        may: &'static str,
        /// The command that fixes it.
        fix: String,
    },
}

/// A file could not be used; names the file.
#[derive(Debug, Error)]
#[error("{}: {problem}", path.display())]
pub struct FileError {
    /// The file.
    pub path: PathBuf,
    /// What is wrong.
    pub problem: FileProblem,
}

impl FileError {
    /// `problem` of the file at `path`.
    pub fn new(path: &Path, problem: impl Into<FileProblem>) -> Self {
        Self {
            path: path.to_owned(),
            problem: problem.into(),
        }
    }
}

/// What a file type is, in words: "a directory", "a FIFO", "a character device", …
pub fn kind_of(t: fs::FileType) -> &'static str {
    if t.is_dir() {
        "a directory"
    } else if t.is_fifo() {
        "a FIFO"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_socket() {
        "a socket"
    } else if t.is_symlink() {
        "a symbolic link"
    } else if t.is_file() {
        "a regular file"
    } else {
        "a file of unknown type"
    }
}

/// The problem for an open of `path` that failed with `NotFound`: a dangling link if `path`
/// is a symbolic link, else the plain error (no file there).
pub fn dangling(path: &Path, error: io::Error) -> FileProblem {
    match fs::read_link(path) {
        Ok(target) => FileProblem::DanglingSymlink { target },
        Err(_) => FileProblem::Io(error),
    }
}

/// A regular file, opened for reading, and its size when opened.
#[derive(Debug)]
pub struct Opened {
    /// The file (its `O_NONBLOCK` is harmless: regular files ignore it).
    pub file: File,
    /// Its size per `fstat` of the opened file.
    pub size: u64,
}

/// Opens the regular file at `path` for reading, following symbolic links, without blocking
/// and without reading a byte; anything else — a FIFO, a device, a directory, a socket — is
/// [`FileProblem::NotARegularFile`], and a dangling link [`FileProblem::DanglingSymlink`].
pub fn open_regular(path: &Path) -> Result<Opened, FileProblem> {
    if let Ok(meta) = fs::metadata(path)
        && !meta.is_file()
    {
        return Err(FileProblem::NotARegularFile {
            kind: kind_of(meta.file_type()),
        });
    }
    // O_NONBLOCK: opening a FIFO without a writer returns at once instead of waiting for one.
    let file = OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY)
        .open(path)
        .map_err(|e| match e.kind() {
            io::ErrorKind::NotFound => dangling(path, e),
            _ => FileProblem::Io(e),
        })?;
    let meta = file.metadata()?;
    if !meta.is_file() {
        return Err(FileProblem::NotARegularFile {
            kind: kind_of(meta.file_type()),
        });
    }
    Ok(Opened {
        file,
        size: meta.len(),
    })
}

/// The whole regular file at `path`, refused without reading it if it holds more than
/// `limit` bytes ([`FileProblem::TooLarge`]). Memory is reserved for its size as `fstat`
/// gives it, once; a file that grows while read is refused at `limit + 1` bytes.
pub fn read_capped(path: &Path, limit: u64) -> Result<Vec<u8>, FileProblem> {
    let Opened { file, size } = open_regular(path)?;
    if size > limit {
        return Err(FileProblem::TooLarge { size, limit });
    }
    let mut bytes = Vec::new();
    bytes
        .try_reserve_exact(usize::try_from(size).unwrap_or(usize::MAX))
        .map_err(|e| io::Error::new(io::ErrorKind::OutOfMemory, e))?;
    let read = file.take(limit.saturating_add(1)).read_to_end(&mut bytes)?;
    if read as u64 > limit {
        return Err(FileProblem::TooLarge {
            size: read as u64,
            limit,
        });
    }
    Ok(bytes)
}

/// [`read_capped`], as UTF-8 text (else an [`io::ErrorKind::InvalidData`] error saying so).
pub fn read_text(path: &Path, limit: u64) -> Result<String, FileProblem> {
    String::from_utf8(read_capped(path, limit)?).map_err(|e| {
        FileProblem::Io(io::Error::new(
            io::ErrorKind::InvalidData,
            format!(
                "is not UTF-8 text (byte {} is not)",
                e.utf8_error().valid_up_to()
            ),
        ))
    })
}

/// The directory `path` is in: its parent, or `.` for a bare name.
pub fn parent_dir(path: &Path) -> PathBuf {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_owned(),
        _ => PathBuf::from("."),
    }
}

/// Refuses a key file that its group or others may read or write: its mode must have no
/// bits for them (`chmod 600`). Symbolic links are followed.
pub fn check_private_file(path: &Path) -> Result<(), FileProblem> {
    let mode = fs::metadata(path)?.permissions().mode();
    check_mode(mode, 0o077, "a key file", "read", || {
        format!("chmod 600 {}", shell_word(path))
    })
}

/// Refuses a directory holding keys that its group or others may enter or change (anyone who
/// may write to it may replace the files in it): its mode must have no bits for them
/// (`chmod 700`).
pub fn check_private_dir(dir: &Path) -> Result<(), FileProblem> {
    let mode = fs::metadata(dir)?.permissions().mode();
    check_mode(
        mode,
        0o077,
        "a key's directory",
        "open or replace files in",
        || format!("chmod 700 {}", shell_word(dir)),
    )
}

/// Refuses a directory whose group or others may write to it, so may replace the files in it
/// (a certificate authority, which need not be secret but must be the right one).
pub fn check_dir_not_writable_by_others(dir: &Path) -> Result<(), FileProblem> {
    let mode = fs::metadata(dir)?.permissions().mode();
    check_mode(
        mode,
        0o022,
        "a certificate's directory",
        "replace files in",
        || format!("chmod go-w {}", shell_word(dir)),
    )
}

fn check_mode(
    mode: u32,
    forbidden: u32,
    what: &'static str,
    may: &'static str,
    fix: impl FnOnce() -> String,
) -> Result<(), FileProblem> {
    let open = mode & forbidden;
    if open == 0 {
        return Ok(());
    }
    let who = match (open & 0o070 != 0, open & 0o007 != 0) {
        (true, true) => "its group and others",
        (true, false) => "its group",
        _ => "others",
    };
    Err(FileProblem::TooOpen {
        what,
        mode,
        who,
        may,
        fix: fix(),
    })
}

/// Whether the file `meta` describes belongs to the user this process runs as (its
/// effective user id).
pub fn owned_by_this_user(meta: &fs::Metadata) -> bool {
    use std::os::unix::fs::MetadataExt;
    // SAFETY: geteuid has no preconditions and cannot fail.
    meta.uid() == unsafe { libc::geteuid() }
}

/// `path` as one word of a POSIX shell command: as is when it needs no quoting, else in
/// single quotes.
pub fn shell_word(path: &Path) -> String {
    let text = path.to_string_lossy();
    let plain = !text.is_empty()
        && text
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b"/._-+,:@%".contains(&b));
    if plain {
        text.into_owned()
    } else {
        format!("'{}'", text.replace('\'', r"'\''"))
    }
}

/// Why a line of a stream was not read whole.
#[derive(Debug, Error)]
#[error("a line longer than {limit} bytes (no newline within them)")]
pub struct LineTooLong {
    /// The longest line read.
    pub limit: usize,
}

/// Reads bytes up to and including `b'\n'` into `line` (appended), as
/// [`BufRead::read_until`] does, but refuses a line longer than `limit` bytes with an
/// [`io::ErrorKind::InvalidData`] error holding [`LineTooLong`]: a stream with no newline
/// (`/dev/zero`, a sparse file, a bomb inflated to one line) never makes `line` larger
/// than `limit` plus one buffer. Returns the bytes read, 0 at the end of the stream.
pub fn read_until_capped(
    reader: &mut impl BufRead,
    line: &mut Vec<u8>,
    limit: usize,
) -> io::Result<usize> {
    let mut read = 0;
    loop {
        let available = match reader.fill_buf() {
            Ok(b) => b,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        };
        let (used, done) = match available.iter().position(|&b| b == b'\n') {
            Some(i) => (i + 1, true),
            None => (available.len(), available.is_empty()),
        };
        if read + used > limit.saturating_add(1) {
            return Err(io::Error::new(
                io::ErrorKind::InvalidData,
                LineTooLong { limit },
            ));
        }
        line.extend_from_slice(&available[..used]);
        reader.consume(used);
        read += used;
        if done {
            return Ok(read);
        }
    }
}

/// How much a decompressed stream may hold: at most `allowance` bytes plus `ratio` times
/// the compressed bytes read so far. Ordinary data compresses far less than `ratio` to 1;
/// a bomb (a few kilobytes that inflate to gigabytes) is stopped once its output passes
/// the bound, after reading a bounded amount of it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InflationBound {
    /// Bytes any stream may inflate to, whatever its compressed size.
    pub allowance: u64,
    /// Inflated bytes allowed per compressed byte beyond the allowance.
    pub ratio: u64,
}

impl InflationBound {
    /// The inflated bytes allowed after `compressed` compressed bytes.
    pub fn allowed(&self, compressed: u64) -> u64 {
        self.allowance
            .saturating_add(self.ratio.saturating_mul(compressed))
    }
}

/// Why an inflated stream was stopped.
#[derive(Debug, Error)]
#[error(
    "the compressed stream inflates past {inflated} bytes from {compressed} (at most {} plus \
     {} per compressed byte are read: a decompression bomb?)",
    bound.allowance,
    bound.ratio
)]
pub struct InflationExceeded {
    /// Inflated bytes read when stopped.
    pub inflated: u64,
    /// Compressed bytes read by then.
    pub compressed: u64,
    /// The bound passed.
    pub bound: InflationBound,
}

/// Counts the bytes read through it, for an [`InflationGuard`] downstream.
#[derive(Debug)]
pub struct CountingReader<R> {
    inner: R,
    count: Arc<AtomicU64>,
}

impl<R: Read> Read for CountingReader<R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.count.fetch_add(n as u64, Ordering::Relaxed);
        Ok(n)
    }
}

/// A decompressor's output, stopped with an [`io::ErrorKind::InvalidData`] error holding
/// [`InflationExceeded`] once it holds more than its [`InflationBound`] allows for the
/// compressed bytes read.
///
/// ```
/// use std::io::Read;
/// use tes_files::{InflationBound, InflationGuard};
///
/// // A "decompressor" that makes 1000 bytes of each byte it reads.
/// struct Repeat<R>(R);
/// impl<R: Read> Read for Repeat<R> {
///     fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
///         let mut one = [0u8];
///         if self.0.read(&mut one)? == 0 { return Ok(0); }
///         let n = buf.len().min(1000);
///         buf[..n].fill(one[0]);
///         Ok(n)
///     }
/// }
/// let bound = InflationBound { allowance: 4096, ratio: 10 };
/// let mut guarded = InflationGuard::new(&[7u8; 100][..], Repeat, bound);
/// let err = std::io::copy(&mut guarded, &mut std::io::sink()).unwrap_err();
/// assert!(err.to_string().contains("decompression bomb"), "{err}");
/// ```
#[derive(Debug)]
pub struct InflationGuard<D> {
    decoder: D,
    compressed: Arc<AtomicU64>,
    inflated: u64,
    bound: InflationBound,
}

impl<D: Read> InflationGuard<D> {
    /// `decoder` made over `compressed` (counted), bounded by `bound`.
    pub fn new<C: Read>(
        compressed: C,
        decoder: impl FnOnce(CountingReader<C>) -> D,
        bound: InflationBound,
    ) -> Self {
        let count = Arc::new(AtomicU64::new(0));
        let counting = CountingReader {
            inner: compressed,
            count: Arc::clone(&count),
        };
        Self {
            decoder: decoder(counting),
            compressed: count,
            inflated: 0,
            bound,
        }
    }
}

impl<D: Read> Read for InflationGuard<D> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let n = self.decoder.read(buf)?;
        self.inflated += n as u64;
        let compressed = self.compressed.load(Ordering::Relaxed);
        if self.inflated > self.bound.allowed(compressed) {
            return Err(io::Error::new(
                io::ErrorKind::InvalidData,
                InflationExceeded {
                    inflated: self.inflated,
                    compressed,
                    bound: self.bound,
                },
            ));
        }
        Ok(n)
    }
}

#[cfg(test)]
mod tests;
