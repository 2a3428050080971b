//! The processes' settings files: one error type, [`SettingError`], for a bad key of any
//! process — naming the file, the line, the table and key, and the reason — and the TOML
//! parsing every process shares (unknown keys refused).
//!
//! A process reads its own file with [`parse_in`]; `tes launch` reads the `[launch]`,
//! `[perception]`, `[controller]` and `[bridge]` tables of one launch file with
//! [`parse_tables`]. Either way a key the parser refuses (unknown, mistyped, repeated) is
//! reported at its line in the file the user wrote, and a value a process's `check()` refuses
//! afterwards is placed there too with [`SettingError::in_file`]:
//!
//! ```
//! use tes_runtime::settings::{self, Origin};
//!
//! #[derive(Debug, serde::Deserialize)]
//! #[serde(deny_unknown_fields)]
//! struct Demo {
//!     rate: u32,
//! }
//! let text = "# demo\nrat = 5\n";
//! let err = settings::parse_in::<Demo>("demo", text, Origin::File("demo.toml".into()))
//!     .unwrap_err();
//! assert_eq!((err.key.as_str(), err.line()), ("rat", Some(2)));
//! assert!(err.to_string().starts_with("demo.toml:2:1: rat: unknown field `rat`"));
//! ```

use std::fmt;
use std::path::PathBuf;

use serde::de::DeserializeOwned;
use toml::de::{DeTable, DeValue};

/// The key of an error about the document as a whole (text that is not TOML, or a problem
/// the parser could not place at a key).
pub const FILE_KEY: &str = "(file)";

/// Where settings came from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Origin {
    /// A file, by the path the user gave.
    File(PathBuf),
    /// Text handed over in code, not read from a file (shown as `<string>`).
    Text,
    /// No file at all: the built-in defaults (shown as `(embedded defaults)`).
    Defaults,
}

impl fmt::Display for Origin {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Origin::File(path) => write!(f, "{}", path.display()),
            Origin::Text => f.write_str("<string>"),
            Origin::Defaults => f.write_str("(embedded defaults)"),
        }
    }
}

/// A 1-based line and column (in characters) of a settings document.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Position {
    /// The line, from 1.
    pub line: usize,
    /// The column in characters, from 1.
    pub column: usize,
}

impl Position {
    /// The position of byte `at` of `text` (the end of `text` if `at` is beyond it or not on
    /// a character boundary).
    pub fn of_byte(text: &str, at: usize) -> Self {
        let before = text.get(..at).unwrap_or(text);
        Self {
            line: before.matches('\n').count() + 1,
            column: before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1,
        }
    }
}

/// Where a bad key is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    /// The file (or text, or defaults) the settings came from.
    pub origin: Origin,
    /// The table holding the process's keys in a launch file (`bridge` for `[bridge]`);
    /// `None` in a file of the process's own.
    pub table: Option<String>,
    /// Where the key (or the offending text) is in the file; `None` when the key is not in it:
    /// its value is a default, or one set by the launcher or on the command line.
    pub position: Option<Position>,
}

/// A setting that is unreadable, unknown or out of range: which process's, which key, why,
/// and — once known — where in the user's file.
#[derive(Debug, Clone, PartialEq)]
pub struct SettingError {
    /// Which process's settings ("controller", "perception", "bridge", "launch", "relay").
    pub process: &'static str,
    /// The key within the process's settings, dotted for nested tables and indexed for
    /// arrays of tables (`watchdog.deadline_ms`, `actions[1].id`); [`FILE_KEY`] when the
    /// problem is the document as a whole.
    pub key: String,
    /// What is wrong.
    pub reason: String,
    /// Where, when the error has been placed in a file ([`SettingError::in_file`]; the
    /// parsers place their own). Boxed, to keep the error small.
    pub location: Option<Box<Location>>,
}

impl fmt::Display for SettingError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let Some(at) = &self.location else {
            return write!(
                f,
                "{} setting `{}`: {}",
                self.process, self.key, self.reason
            );
        };
        write!(f, "{}", at.origin)?;
        if let Some(p) = at.position {
            write!(f, ":{}:{}", p.line, p.column)?;
        }
        if self.key == FILE_KEY {
            return write!(f, ": {}", self.reason);
        }
        match &at.table {
            Some(table) => write!(f, ": [{table}] {}", self.key)?,
            None => write!(f, ": {}", self.key)?,
        }
        if at.position.is_none() && at.origin != Origin::Defaults {
            f.write_str(match at.table {
                Some(_) => " (not in the file: a default or a launch-wide value)",
                None => " (not in the file: a default or a value given elsewhere)",
            })?;
        }
        write!(f, ": {}", self.reason)
    }
}

impl std::error::Error for SettingError {}

impl SettingError {
    /// An error for `key` of `process`, not yet placed in a file.
    pub fn new(process: &'static str, key: impl Into<String>, reason: impl Into<String>) -> Self {
        Self {
            process,
            key: key.into(),
            reason: reason.into(),
            location: None,
        }
    }

    /// Places the error in the settings it is about: `origin`, in `table` of a launch file
    /// (`None` for a process's own file), at the line where `text` — the document as the user
    /// wrote it — sets the key (no line if it does not). An error already placed is returned
    /// as it is.
    #[must_use]
    pub fn in_file(mut self, origin: Origin, table: Option<&str>, text: Option<&str>) -> Self {
        if self.location.is_none() {
            let position = text.and_then(|text| position_of(text, table, &self.key));
            self.location = Some(Box::new(Location {
                origin,
                table: table.map(str::to_owned),
                position,
            }));
        }
        self
    }

    /// Why the value is refused, without the key and place.
    pub fn reason(&self) -> &str {
        &self.reason
    }

    /// The 1-based line of the key in the user's file, if the error is placed there.
    pub fn line(&self) -> Option<usize> {
        self.location.as_ref()?.position.map(|p| p.line)
    }
}

/// Parses a TOML document into `T` (whose serde attributes refuse unknown keys); an error
/// names the key and its line (the origin shown as `<string>`).
pub fn parse<T: DeserializeOwned>(process: &'static str, text: &str) -> Result<T, SettingError> {
    parse_in(process, text, Origin::Text)
}

/// Parses a TOML document from `origin` into `T` ([`parse_in`]) and checks it with `check`;
/// an error of either names the key and its line in `origin`. What every process's
/// `from_toml_in` does.
pub fn parse_checked<T: DeserializeOwned, C>(
    process: &'static str,
    text: &str,
    origin: Origin,
    check: impl FnOnce(&T) -> Result<C, SettingError>,
) -> Result<(T, C), SettingError> {
    let settings: T = parse_in(process, text, origin.clone())?;
    let checked = check(&settings).map_err(|e| e.in_file(origin, None, Some(text)))?;
    Ok((settings, checked))
}

/// [`parse`] for a document from `origin`, which the error names.
pub fn parse_in<T: DeserializeOwned>(
    process: &'static str,
    text: &str,
    origin: Origin,
) -> Result<T, SettingError> {
    toml::from_str(text).map_err(|e| {
        let (path, position, reason) = parse_problem(text, &e);
        SettingError {
            process,
            key: if path.is_empty() {
                FILE_KEY.to_owned()
            } else {
                path.join(".")
            },
            reason,
            location: Some(Box::new(Location {
                origin,
                table: None,
                position,
            })),
        }
    })
}

/// Parses a document of tables, one per process (a launch file), into `T`. An error in a
/// table that `process_of` names a process for (`bridge` → `"bridge"`) is that process's,
/// with its key relative to the table (`[bridge] watchdog.deadline_ms`); any other is
/// `top`'s, with its full key (an unknown table `[monitor]`: key `monitor`).
pub fn parse_tables<T: DeserializeOwned>(
    top: &'static str,
    text: &str,
    origin: Origin,
    process_of: impl Fn(&str) -> Option<&'static str>,
) -> Result<T, SettingError> {
    toml::from_str(text).map_err(|e| {
        let (path, position, reason) = parse_problem(text, &e);
        let (process, table, key) = match path.split_first() {
            Some((table, rest)) if !rest.is_empty() => match process_of(table) {
                Some(process) => (process, Some(table.clone()), rest.join(".")),
                None => (top, None, path.join(".")),
            },
            _ if path.is_empty() => (top, None, FILE_KEY.to_owned()),
            _ => (top, None, path.join(".")),
        };
        SettingError {
            process,
            key,
            reason,
            location: Some(Box::new(Location {
                origin,
                table,
                position,
            })),
        }
    })
}

/// Whether `text` sets `key` (dotted, as in [`SettingError::key`]) in `table` (or at the top
/// level); `false` for text that is not TOML.
pub fn is_set(text: &str, table: Option<&str>, key: &str) -> bool {
    position_of(text, table, key).is_some()
}

/// Where `text` sets `key` (dotted, as in [`SettingError::key`]) in `table` (or at the top
/// level): the position of the key's name, `None` if it is not set (or `text` is not TOML).
pub fn position_of(text: &str, table: Option<&str>, key: &str) -> Option<Position> {
    let doc = DeTable::parse(text).ok()?;
    let mut steps = Vec::new();
    steps.extend(table.map(Step::Key));
    for part in key.split('.') {
        let (name, indices) = part.split_once('[').map_or((part, ""), |(n, i)| (n, i));
        steps.push(Step::Key(name));
        for index in indices.split('[') {
            match index.strip_suffix(']').map(str::parse::<usize>) {
                Some(Ok(i)) => steps.push(Step::Index(i)),
                _ if index.is_empty() => {}
                _ => return None,
            }
        }
    }
    let at = span_of(doc.get_ref(), &steps)?;
    Some(Position::of_byte(text, at))
}

enum Step<'a> {
    Key(&'a str),
    Index(usize),
}

/// The start of the last step's key (or array element) along `steps` from `table`.
fn span_of(table: &DeTable<'_>, steps: &[Step<'_>]) -> Option<usize> {
    let (Step::Key(name), rest) = steps.split_first()? else {
        return None;
    };
    let (key, value) = table.get_key_value(*name)?;
    if rest.is_empty() {
        return Some(key.span().start);
    }
    span_in(value, rest)
}

fn span_in(value: &toml::Spanned<DeValue<'_>>, steps: &[Step<'_>]) -> Option<usize> {
    match (value.get_ref(), steps.first()?) {
        (DeValue::Table(inner), Step::Key(_)) => span_of(inner, steps),
        (DeValue::Array(items), Step::Index(i)) => {
            let item = items.get(*i)?;
            match &steps[1..] {
                [] => Some(item.span().start),
                rest => span_in(item, rest),
            }
        }
        _ => None,
    }
}

/// Which key the parser's `error` is about (its path, indexed for arrays: `actions[1]`,
/// empty when it is about no key), where in `text` it is, and the parser's reason.
fn parse_problem(text: &str, error: &toml::de::Error) -> (Vec<String>, Option<Position>, String) {
    let position = error.span().map(|s| Position::of_byte(text, s.start));
    let Ok(doc) = DeTable::parse(text) else {
        return (
            Vec::new(),
            position,
            format!("not valid TOML: {}", error.message()),
        );
    };
    let mut path = Vec::new();
    if let Some(span) = error.span()
        && !key_at(doc.get_ref(), span.start, &mut path)
    {
        path.clear();
    }
    (path, position, error.message().to_owned())
}

/// The path of the innermost key of `table` whose name or value holds byte `at`.
fn key_at(table: &DeTable<'_>, at: usize, path: &mut Vec<String>) -> bool {
    for (key, value) in table.iter() {
        path.push(key.get_ref().to_string());
        if value_at(value, at, path) || key.span().contains(&at) || value.span().contains(&at) {
            return true;
        }
        path.pop();
    }
    false
}

/// Whether a key inside `value` (a table, or the tables of an array) holds byte `at`; its
/// path is appended to `path`, with an array's index on the last element (`actions[1]`).
fn value_at(value: &toml::Spanned<DeValue<'_>>, at: usize, path: &mut Vec<String>) -> bool {
    match value.get_ref() {
        DeValue::Table(inner) => key_at(inner, at, path),
        DeValue::Array(items) => {
            for (i, item) in items.iter().enumerate() {
                let Some(last) = path.last_mut() else {
                    return false;
                };
                let name_len = last.len();
                last.push_str(&format!("[{i}]"));
                if value_at(item, at, path) || item.span().contains(&at) {
                    return true;
                }
                if let Some(last) = path.last_mut() {
                    last.truncate(name_len);
                }
            }
            false
        }
        _ => false,
    }
}

/// Checks a CPU-placement key (`acting_cpu`, …): unset, or a CPU this process may run on.
pub fn cpu(
    process: &'static str,
    key: &'static str,
    cpu: Option<usize>,
) -> Result<(), SettingError> {
    match cpu {
        None => Ok(()),
        Some(c) => crate::affinity::check_cpu(c)
            .map_err(|e| SettingError::new(process, key, e.to_string())),
    }
}

/// The longest service prefix a group may have, in bytes: every process's `service_prefix`
/// (the bridge's `[ipc] service_prefix`, the launch's `[launch] service_prefix`) is held to it
/// by [`service_prefix`].
pub const SERVICE_PREFIX_MAX: usize = 64;

/// The decision budget, µs: the default per-action latency budget, observation to command
/// (the controller's `budget_us`, the bridge's `[ipc] budget_us`).
pub const DEFAULT_BUDGET_US: u64 = 1000;

/// The least per-action latency budget a process takes, µs.
pub const MIN_BUDGET_US: u64 = 1;

/// Checks a `service_prefix` key of `process`: at most [`SERVICE_PREFIX_MAX`] bytes.
pub fn service_prefix(
    process: &'static str,
    key: &'static str,
    prefix: &str,
) -> Result<(), SettingError> {
    if prefix.len() > SERVICE_PREFIX_MAX {
        return Err(SettingError::new(
            process,
            key,
            format!("must be at most {SERVICE_PREFIX_MAX} bytes"),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_service_prefix_is_held_to_its_limit() {
        let at_most = "x".repeat(SERVICE_PREFIX_MAX);
        assert!(service_prefix("demo", "service_prefix", &at_most).is_ok());
        let e = service_prefix("demo", "service_prefix", &format!("{at_most}x")).unwrap_err();
        assert_eq!((e.process, e.key.as_str()), ("demo", "service_prefix"));
        assert_eq!(e.reason, "must be at most 64 bytes");
    }

    #[derive(Debug, PartialEq, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Demo {
        rate: u32,
    }

    #[test]
    fn a_bad_document_names_the_key_and_its_line() {
        assert_eq!(parse::<Demo>("demo", "rate = 5"), Ok(Demo { rate: 5 }));
        for (text, key, line, reason) in [
            ("rate = 5\nrat = 6", "rat", Some(2), "unknown field `rat`"),
            ("rate = \"fast\"", "rate", Some(1), "invalid type"),
            ("rate = 5\nrate = 6", FILE_KEY, Some(2), "duplicate key"),
            ("rate = ", FILE_KEY, Some(1), "not valid TOML"),
            ("\n\n", FILE_KEY, Some(1), "missing field `rate`"),
        ] {
            let err = parse::<Demo>("demo", text).expect_err(text);
            assert_eq!((err.process, err.key.as_str()), ("demo", key), "{text}");
            assert_eq!(err.line(), line, "{text}");
            assert!(err.reason.contains(reason), "{text}: {err}");
            assert!(!err.reason.contains('\n'), "one line: {err}");
            assert!(err.to_string().starts_with("<string>:"), "{err}");
        }
        let origin = Origin::File("/etc/demo.toml".into());
        let err = parse_in::<Demo>("demo", "rate = 5\n\nrat = 6", origin.clone()).unwrap_err();
        assert_eq!(
            err.to_string(),
            "/etc/demo.toml:3:1: rat: unknown field `rat`, expected `rate`"
        );
        assert_eq!(err.location.map(|l| l.origin), Some(origin));
    }

    #[derive(Debug, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Launch {
        #[serde(default)]
        top: Option<Demo>,
        #[serde(default)]
        child: Option<Child>,
    }

    #[derive(Debug, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Child {
        #[serde(default)]
        inner: Option<Demo>,
        #[serde(default)]
        items: Vec<Demo>,
    }

    fn tables(text: &str) -> SettingError {
        let process = |t: &str| (t == "child").then_some("child");
        parse_tables::<Launch>("top", text, Origin::File("l.toml".into()), process).expect_err(text)
    }

    #[test]
    fn a_bad_key_of_a_table_is_its_process_key_at_its_line() {
        let err = tables("[top]\nrate = 1\n[child.inner]\nrate = 1\nrat = 2\n");
        assert_eq!((err.process, err.key.as_str()), ("child", "inner.rat"));
        assert_eq!(err.line(), Some(5));
        assert_eq!(
            err.to_string(),
            "l.toml:5:1: [child] inner.rat: unknown field `rat`, expected `rate`"
        );
        let err = tables("[child]\n[[child.items]]\nrate = 1\n[[child.items]]\nrate = -1\n");
        assert_eq!((err.process, err.key.as_str()), ("child", "items[1].rate"));
        assert_eq!(err.line(), Some(5));
        // Not a process's table: the launcher's own key.
        let err = tables("[top]\nrate = 1\n[monitor]\nrate = 5\n");
        assert_eq!((err.process, err.key.as_str()), ("top", "monitor"));
        assert!(
            err.to_string()
                .starts_with("l.toml:3:2: monitor: unknown field")
        );
        let err = tables("[top]\nrat = 1\n");
        assert_eq!((err.process, err.key.as_str()), ("top", "top.rat"));
        let err = tables("this is { not toml\n");
        assert_eq!((err.process, err.key.as_str()), ("top", FILE_KEY));
        assert!(
            err.to_string().starts_with("l.toml:1:6: not valid TOML: "),
            "{err}"
        );
    }

    #[test]
    fn a_checked_value_is_placed_at_its_key_or_said_to_be_absent() {
        let text = "[launch]\nx = 1\n[bridge]\nseed = 1\n[bridge.watchdog]\ndeadline_ms = 10\n\
                    [[bridge.actions]]\nid = 0\n[[bridge.actions]]\n  id = 0\n";
        assert_eq!(
            position_of(text, Some("bridge"), "watchdog.deadline_ms"),
            Some(Position { line: 6, column: 1 })
        );
        assert_eq!(
            position_of(text, Some("bridge"), "actions[1].id"),
            Some(Position {
                line: 10,
                column: 3
            })
        );
        assert!(is_set(text, Some("bridge"), "seed"));
        assert!(!is_set(text, Some("bridge"), "ipc.wait"));
        assert!(!is_set(text, Some("controller"), "seed"));
        assert!(!is_set(text, None, "seed"));
        assert!(!is_set(text, Some("bridge"), "actions[2].id"));
        assert!(!is_set("not toml {", None, "x"));

        let origin = Origin::File("launch.toml".into());
        let bad = SettingError::new("bridge", "watchdog.deadline_ms", "must be at least 50");
        let placed = bad
            .clone()
            .in_file(origin.clone(), Some("bridge"), Some(text));
        assert_eq!(placed.line(), Some(6));
        assert_eq!(
            placed.to_string(),
            "launch.toml:6:1: [bridge] watchdog.deadline_ms: must be at least 50"
        );
        // Placed once: a second placement changes nothing.
        assert_eq!(placed.clone().in_file(Origin::Text, None, Some("")), placed);
        let injected = SettingError::new("bridge", "ipc.wait", "no").in_file(
            origin.clone(),
            Some("bridge"),
            Some(text),
        );
        assert_eq!(injected.line(), None);
        assert_eq!(
            injected.to_string(),
            "launch.toml: [bridge] ipc.wait (not in the file: a default or a launch-wide value): no"
        );
        let default = SettingError::new("launch", "episodes", "must be at least 1").in_file(
            Origin::Defaults,
            Some("launch"),
            None,
        );
        assert_eq!(
            default.to_string(),
            "(embedded defaults): [launch] episodes: must be at least 1"
        );
        // Not placed: the process and key.
        assert_eq!(
            bad.to_string(),
            "bridge setting `watchdog.deadline_ms`: must be at least 50"
        );
    }

    #[test]
    fn a_cpu_key_is_unset_or_an_allowed_cpu() {
        assert_eq!(cpu("demo", "acting_cpu", None), Ok(()));
        let allowed = crate::affinity::allowed_cpus();
        if let Some(&c) = allowed.first() {
            assert_eq!(cpu("demo", "acting_cpu", Some(c)), Ok(()));
        }
        let err = cpu("demo", "acting_cpu", Some(100_000)).expect_err("no such CPU");
        assert_eq!((err.process, err.key.as_str()), ("demo", "acting_cpu"));
        assert!(err.reason.contains("100000"), "{err}");
    }
}
