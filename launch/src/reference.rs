//! The launch file's reference: every key of every table, with its unit or allowed values and
//! what it does.
//!
//! A key's words live in one place, the doc comment of its field in the config struct its
//! table is read into (`tes_launch::file::LaunchSection`, `tes_link::LinkSection`,
//! `tes_perception_sim::process::PerceptionConfig`, `tes_controller::config::ControllerConfig`,
//! `tes_bridge::config::BridgeSettings` and its nested tables): what the key does, then a
//! `Values:` line with its unit or allowed values (numeric limits as links to the constants
//! the structs' `check()` uses), and for a key unset by default an `Example:` line. This
//! crate's build script (build.rs) parses those files and generates [`KEYS`] from them. The
//! values come from the code too: the defaults are the config structs' own `Default`s,
//! serialised, and the keys the launcher fills in for the children are [`INHERITED`]; the
//! per-table prose is [`TABLES`], here. Two renderings are made from them: a launch file
//! with every key at its default, each commented (`tes launch --print-config`), and the
//! markdown page `docs/config.md` (`tes launch --print-config=markdown`). The tests derive
//! the key set from the config structs' parsers, so a field added without a doc or a
//! `Values:` line fails them with its name.

use std::fmt::Write as _;

use crate::file::{INHERITED, Inherited, LaunchFile, LaunchFileError, RESOLVED_LAUNCH_FILE};

/// The reference cannot be rendered: a table's values do not serialise (a bug in a config
/// struct), or the text cannot be written.
#[derive(Debug, thiserror::Error)]
pub enum ReferenceError {
    /// A table's values cannot be serialised to TOML.
    #[error("cannot serialise the [{table}] settings")]
    Serialise {
        /// The table.
        table: String,
        /// Why.
        #[source]
        source: toml::ser::Error,
    },
    /// Writing into the text failed.
    #[error("cannot write the reference")]
    Format(#[from] std::fmt::Error),
}

type Result<T, E = ReferenceError> = std::result::Result<T, E>;

/// Where the reference comes from and how to regenerate `docs/config.md`, as the printed
/// reference and its tests say.
pub const REGENERATE: &str = "tes launch --print-config=markdown > docs/config.md";

/// A table of the launch file, in the order the reference lists them.
#[derive(Debug, Clone, Copy)]
pub struct Table {
    /// Its dotted name (`bridge.watchdog`).
    pub name: &'static str,
    /// Whether it is an array of tables (`[[bridge.actions]]`).
    pub array: bool,
    /// What it is for.
    pub about: &'static str,
}

/// One key of the launch file, as the reference describes it (generated from its field's doc
/// comment: see the module docs).
#[derive(Debug, Clone, Copy)]
pub struct Key {
    /// The table it is in ([`Table::name`]).
    pub table: &'static str,
    /// Its name in the table.
    pub key: &'static str,
    /// Its unit, or the values it takes (its doc's `Values:` line).
    pub allowed: &'static str,
    /// What it does (its doc, without the `Values:` and `Example:` lines).
    pub meaning: &'static str,
    /// For a key that is unset by default (no TOML value can say "unset"): a value to show,
    /// commented out (its doc's `Example:` line).
    pub example: Option<&'static str>,
}

impl Key {
    /// Its dotted name from the top of the file (`bridge.watchdog.deadline_ms`).
    pub fn path(&self) -> String {
        format!("{}.{}", self.table, self.key)
    }

    /// For a key the launcher fills in for a child ([`INHERITED`]): the value it sets.
    pub fn inherited(&self) -> Option<&'static str> {
        inherited(self.table, self.key).map(|i| i.value)
    }
}

/// The tables of a launch file, in order (a table comes before the tables nested in it).
pub const TABLES: &[Table] = &[
    Table {
        name: "launch",
        array: false,
        about: "Launch-wide settings: the run (episodes, arena, pace, seed), how every process \
                waits, and how the launcher supervises the group. Several of them are copied \
                into the children's tables (the inherited keys).",
    },
    Table {
        name: "launch.link",
        array: false,
        about: "How a launch that starts only some of the processes (`roles`) reaches the \
                others on other hosts: one Zenoh session (docs/multi-host.md). Unused without \
                `roles`.",
    },
    Table {
        name: "perception",
        array: false,
        about: "The perception-sim process: the simulated world, which publishes an \
                observation per step and moves the robot by the bridge's motion reports.",
    },
    Table {
        name: "controller",
        array: false,
        about: "The controller process: the acting loop (observation to command within the \
                budget), learning the views of the library, and planning.",
    },
    Table {
        name: "bridge",
        array: false,
        about: "The bridge process: turns the controller's commands into NXT motor telegrams \
                over the transport (the simulated brick, or a real NXT over Bluetooth) and \
                reports the motion. Its nested tables follow.",
    },
    Table {
        name: "bridge.link_delay",
        array: false,
        about: "A simulated Bluetooth delay on each reply of the `sim` transport (and of \
                `tes-bridge brick --pty`).",
    },
    Table {
        name: "bridge.serial",
        array: false,
        about: "The real links' settings: the timing keys apply to `usb`, `bluetooth:<address>` and `serial:<path>` alike; `baud_rate` and `exclusive` to a serial device only.",
    },
    Table {
        name: "bridge.watchdog",
        array: false,
        about: "The dead man's switch: the motors are braked when the commands stop.",
    },
    Table {
        name: "bridge.poll",
        array: false,
        about: "How the bridge polls the brick (periods in brick time: see \
                `[bridge.brick] time_scale`).",
    },
    Table {
        name: "bridge.ipc",
        array: false,
        about: "The bridge's side of iceoryx2: waiting for commands, and its latency figures.",
    },
    Table {
        name: "bridge.brick",
        array: false,
        about: "The simulated brick's physics and identity (`transport = \"sim\"`; a serial \
                transport ignores them).",
    },
    Table {
        name: "bridge.motors",
        array: false,
        about: "How the wheel motors are wired and driven.",
    },
    Table {
        name: "bridge.actions",
        array: true,
        about: "The action table: one entry per action id the controller may send, at least \
                one, ids unique. The default is the paper's three (section 5.2): forward, \
                turn left, turn right. Entries written in the file replace the whole table.",
    },
    Table {
        name: "ros2_world",
        array: false,
        about: "A ROS 2 robot as the world, in place of perception-sim and the bridge (a `tes` \
                built with `--features ros2`; docs/ros2.md): what its node sends (the counts \
                every map and step is checked against) and what each action does. Absent by \
                default: the world is the simulated arena.",
    },
    Table {
        name: "ros2_world.twist",
        array: true,
        about: "For a wheeled base: each action's velocity on `cmd_vel`, held for its time, \
                then a stop. Absent: actions go out by index only.",
    },
];

include!(concat!(env!("OUT_DIR"), "/keys.rs"));

/// The defaults of a launch file, one TOML table per process (`launch`, `perception`,
/// `controller`, `bridge`): the config structs' `Default`s, serialised. Keys that are unset
/// by default are absent (TOML has no "unset").
pub fn defaults() -> Result<toml::Table> {
    values_of(&LaunchFile::default())
}

/// The values of `file`, one TOML table per process, as [`defaults`] gives the defaults'.
fn values_of(file: &LaunchFile) -> Result<toml::Table> {
    let mut tables = toml::Table::new();
    let mut put = |name: &str, value: Result<toml::Value, toml::ser::Error>| -> Result<()> {
        let value = value.map_err(|source| ReferenceError::Serialise {
            table: name.to_owned(),
            source,
        })?;
        tables.insert(name.to_owned(), value);
        Ok(())
    };
    put("launch", toml::Value::try_from(&file.launch))?;
    put("perception", toml::Value::try_from(&file.perception))?;
    put("controller", toml::Value::try_from(&file.controller))?;
    put("bridge", toml::Value::try_from(&file.bridge))?;
    Ok(tables)
}

/// The value at the dotted `path` of `root`, if any.
pub fn lookup<'a>(root: &'a toml::Table, path: &str) -> Option<&'a toml::Value> {
    let mut parts = path.split('.');
    let mut value = root.get(parts.next()?)?;
    for part in parts {
        value = value.as_table()?.get(part)?;
    }
    Some(value)
}

/// Whether `value` is a table of its own in a TOML file: a table, or a non-empty array of
/// tables — not a key of the table holding it.
pub fn is_table(value: &toml::Value) -> bool {
    match value {
        toml::Value::Table(_) => true,
        toml::Value::Array(items) => !items.is_empty() && items.iter().all(|v| v.is_table()),
        _ => false,
    }
}

/// The [`INHERITED`] entry of `[table] key`, if the launcher fills it in for a child.
fn inherited(table: &str, key: &str) -> Option<&'static Inherited> {
    // `bridge.ipc` + `wait` is INHERITED's `bridge` + `ipc.wait`.
    INHERITED.iter().find(|i| {
        i.path()
            .strip_prefix(table)
            .and_then(|rest| rest.strip_prefix('.'))
            == Some(key)
    })
}

/// Whether the launcher fills `[table] key` in for a child ([`INHERITED`]).
fn is_inherited(table: &str, key: &str) -> bool {
    inherited(table, key).is_some()
}

/// How the reference describes a key the defaults have but [`KEYS`] does not (printed all
/// the same; the tests refuse it).
const UNDESCRIBED: Key = Key {
    table: "",
    key: "",
    allowed: "?",
    meaning: "Not described yet: document its field (with a `Values:` line) in its config \
              struct.",
    example: None,
};

/// The keys of `table` in reference order, each with its description: the described ones,
/// then any key of its defaults `values` that is not described.
fn keys_of(table: &Table, values: Option<&toml::Table>) -> Vec<(String, Key)> {
    let mut keys: Vec<(String, Key)> = KEYS
        .iter()
        .filter(|k| k.table == table.name)
        .map(|k| (k.key.to_owned(), *k))
        .collect();
    for (name, value) in values.into_iter().flatten() {
        if !is_table(value) && !keys.iter().any(|(k, _)| k == name) {
            keys.push((name.clone(), UNDESCRIBED));
        }
    }
    keys
}

/// The launch file of the defaults: every key of every table, each with its meaning, unit or
/// allowed values, and default. Keys the launcher fills in for a child are commented out
/// (written in a child's table, even at its default, a key no longer follows `[launch]`), as
/// are keys unset by default (shown with an example value) — unless `set_all`, which writes
/// every one (for the tests: every key then reaches the parser).
pub fn render_toml(set_all: bool) -> Result<String> {
    let header = [
        "TES launch file: every key of every table, at its default.",
        "Printed by `tes launch --print-config`; read by `tes launch --config FILE`.",
        "Every key is optional: keep only those you change. Unknown keys are refused.",
        "Keys marked \"inherited\" are commented out: the launcher fills them in from [launch]",
        "unless the table sets them; uncomment one to give that process a value of its own.",
        "Keys unset by default are commented out with an example value.",
        "Reference: docs/config.md (tes launch --print-config=markdown).",
    ];
    render_values(&defaults()?, &header, set_all)
}

/// The launch file a run folder keeps: every key of `file` (the user's values, the defaults
/// for the rest), described as [`render_toml`] describes them, which `tes launch --config`
/// reads back as the same launch. The keys a child inherits from `[launch]` stay commented
/// out unless the file gave that child its own value.
pub fn render_resolved(file: &LaunchFile) -> Result<String> {
    let header = [
        "TES launch file of this run: every key, as the launch ran it (the file's values, the",
        "defaults for the rest). `tes launch --config THIS_FILE` runs it again (with a run",
        "folder of its own). What each child ran with, inherited keys filled in, is in",
        "ROLE.toml beside it.",
    ];
    let mut text = render_values(&values_of(file)?, &header, false)?;
    // A child's own value of an inherited key is part of the launch: write it out.
    for key in &file.own {
        // `bridge.ipc.wait` is the `wait` line of `[bridge.ipc]`.
        let Some((table, name)) = key.rsplit_once('.') else {
            continue;
        };
        let commented = format!("# {name} = ");
        if let Some(at) = find_in_table(&text, table, &commented) {
            text.replace_range(at..at + 2, "");
        }
    }
    Ok(text)
}

/// Writes [`render_resolved`] of `file` as given (a launch without a service prefix of its
/// own gets a new one when rerun) into the run folder `run_dir`, as [`RESOLVED_LAUNCH_FILE`].
pub fn write_resolved(file: &LaunchFile, run_dir: &std::path::Path) -> Result<(), LaunchFileError> {
    let resolved = render_resolved(file).map_err(|error| LaunchFileError::Write {
        origin: file.origin.clone(),
        what: "cannot write the resolved launch file".into(),
        error: error.into(),
    })?;
    let path = run_dir.join(RESOLVED_LAUNCH_FILE);
    std::fs::write(&path, resolved).map_err(|error| LaunchFileError::RunDir { path, error })
}

/// Where the line starting with `line` is in the `[table]` section of `text`.
fn find_in_table(text: &str, table: &str, line: &str) -> Option<usize> {
    let header = format!("\n[{table}]\n");
    let start = text.find(&header)? + header.len();
    let end = text[start..].find("\n[").map_or(text.len(), |e| start + e);
    let at = text[start..end].find(&format!("\n{line}"))?;
    Some(start + at + 1)
}

/// [`render_toml`] of the values `tables`, after the comment lines `header`.
fn render_values(tables: &toml::Table, header: &[&str], set_all: bool) -> Result<String> {
    let defaults = tables;
    let mut out = String::new();
    for line in header {
        comment(&mut out, line);
    }
    for table in TABLES {
        let value = lookup(defaults, table.name);
        out.push('\n');
        comment(&mut out, table.about);
        if value.is_none() && OPTIONAL_TABLES.contains(&table.name) {
            write_absent(&mut out, table, set_all)?;
        } else if table.array {
            let items = value.and_then(toml::Value::as_array);
            for (i, item) in items.into_iter().flatten().enumerate() {
                if i > 0 {
                    out.push('\n');
                }
                writeln!(out, "[[{}]]", table.name)?;
                let values = item.as_table();
                for (name, k) in keys_of(table, values) {
                    write_key(&mut out, table, &name, &k, values, i == 0, set_all)?;
                }
            }
        } else {
            writeln!(out, "[{}]", table.name)?;
            let values = value.and_then(toml::Value::as_table);
            for (name, k) in keys_of(table, values) {
                write_key(&mut out, table, &name, &k, values, true, set_all)?;
            }
        }
    }
    Ok(out)
}

/// The tables a launch file may add that its defaults do not have.
pub const OPTIONAL_TABLES: &[&str] = &["ros2_world", "ros2_world.twist"];

/// Writes an optional table the values do not have: commented out, each key with its
/// example — or, `set_all`, written out (one entry of an array of tables) for the parser.
fn write_absent(out: &mut String, table: &Table, set_all: bool) -> Result<()> {
    let mark = if set_all { "" } else { "# " };
    if table.array {
        writeln!(out, "{mark}[[{}]]", table.name)?;
    } else {
        writeln!(out, "{mark}[{}]", table.name)?;
    }
    for (name, k) in keys_of(table, None) {
        out.push('\n');
        comment(out, k.meaning);
        comment(out, &format!("{}.", k.allowed));
        if let Some(example) = k.example {
            writeln!(out, "{mark}{name} = {example}")?;
        }
    }
    Ok(())
}

/// Writes `name` of `table`, described by `k`, where the table's (or the array entry's)
/// default values are `values`: its comment (if `described`), then its line.
fn write_key(
    out: &mut String,
    table: &Table,
    name: &str,
    k: &Key,
    values: Option<&toml::Table>,
    described: bool,
    set_all: bool,
) -> Result<()> {
    let value = values.and_then(|v| v.get(name));
    let inherited = is_inherited(table.name, name);
    if described {
        out.push('\n');
        comment(out, k.meaning);
        match value {
            // An entry of an array of tables: its values are right below.
            _ if table.array => comment(out, &format!("{}.", k.allowed)),
            Some(v) => comment(out, &format!("{}. Default: {v}.", k.allowed)),
            None => comment(out, &format!("{}. Default: unset.", k.allowed)),
        }
        if inherited {
            let from = k.inherited().unwrap_or("the launch-wide value");
            comment(
                out,
                &format!("Inherited: unless this table sets it, a launch sets it to {from}."),
            );
        }
    }
    match (value, k.example) {
        (Some(v), _) if inherited && !set_all => writeln!(out, "# {name} = {v}")?,
        (Some(v), _) => writeln!(out, "{name} = {v}")?,
        (None, Some(example)) if set_all => writeln!(out, "{name} = {example}")?,
        (None, Some(example)) => writeln!(out, "# {name} = {example}")?,
        (None, None) => {}
    }
    Ok(())
}

/// Appends `text` as TOML comment lines of at most [`WIDTH`] characters.
fn comment(out: &mut String, text: &str) {
    for line in wrap(text, WIDTH - 2) {
        out.push_str("# ");
        out.push_str(&line);
        out.push('\n');
    }
}

/// The width the printed file's comments are wrapped to.
const WIDTH: usize = 92;

/// `text` in lines of at most `width` characters, broken at spaces (a longer word gets a
/// line of its own).
fn wrap(text: &str, width: usize) -> Vec<String> {
    let mut lines = Vec::new();
    let mut line = String::new();
    for word in text.split_whitespace() {
        if !line.is_empty() && line.chars().count() + 1 + word.chars().count() > width {
            lines.push(std::mem::take(&mut line));
        }
        if !line.is_empty() {
            line.push(' ');
        }
        line.push_str(word);
    }
    if !line.is_empty() {
        lines.push(line);
    }
    lines
}

/// The reference page, `docs/config.md`: how the launch file is read, the inherited keys, and
/// per table a row per key (key, default, unit or allowed values, meaning).
pub fn render_markdown() -> Result<String> {
    let defaults = defaults()?;
    let mut out = String::new();
    out.push_str("# Launch file reference\n\n");
    writeln!(
        out,
        "<!-- Generated from the config structs' field docs (by launch/build.rs and \
         launch/src/reference.rs): `{REGENERATE}`; do not edit by hand. -->\n"
    )?;
    out.push_str(INTRO);
    out.push_str("\n## Inherited keys\n\n");
    out.push_str(INHERITANCE);
    out.push_str("\n| key | in a launch |\n|---|---|\n");
    for i in INHERITED {
        let path = i.path();
        let (table, key) = path.rsplit_once('.').unwrap_or((i.table, i.key));
        writeln!(out, "| `[{table}] {key}` | {} |", cell(i.value))?;
    }
    for table in TABLES {
        let header = if table.array {
            format!("[[{}]]", table.name)
        } else {
            format!("[{}]", table.name)
        };
        writeln!(out, "\n## `{header}`\n")?;
        writeln!(out, "{}\n", table.about)?;
        out.push_str("| key | default | unit / allowed | meaning |\n|---|---|---|---|\n");
        let value = lookup(&defaults, table.name);
        // An array of tables: each key's defaults, entry by entry.
        let rows: Vec<&toml::Table> = match value {
            Some(toml::Value::Array(items)) => items.iter().filter_map(|v| v.as_table()).collect(),
            Some(toml::Value::Table(t)) => vec![t],
            _ => Vec::new(),
        };
        let first = rows.first().copied();
        for (name, k) in keys_of(table, first) {
            let values: Vec<String> = rows
                .iter()
                .filter_map(|r| r.get(&name))
                .map(|v| format!("`{v}`"))
                .collect();
            let mut default = if values.is_empty() {
                "unset".to_owned()
            } else {
                values.join(", ")
            };
            if let Some(example) = k.example.filter(|_| values.is_empty()) {
                default = format!("unset (e.g. `{example}`)");
            }
            let mut meaning = k.meaning.to_owned();
            if is_inherited(table.name, &name) {
                let from = k.inherited().unwrap_or("the launch-wide value");
                default = format!("{default}; in a launch: {from}");
                meaning = format!("**Inherited.** {meaning}");
            }
            writeln!(
                out,
                "| `{name}` | {} | {} | {} |",
                cell(&default),
                cell(k.allowed),
                cell(&meaning)
            )?;
        }
    }
    Ok(out)
}

/// `text` made safe for a markdown table cell (`|` escaped, even inside code spans, as GitHub
/// wants).
fn cell(text: &str) -> String {
    text.replace('|', "\\|")
}

/// The reference page's introduction: how the launch file is read.
const INTRO: &str = "\
`tes launch --config FILE` reads one TOML file with a table per process of the group: \
`[launch]` for the launch-wide settings, then `[perception]`, `[controller]` and `[bridge]` \
(with the bridge's nested tables). This page lists every key: its default, its unit or the \
values it takes, and what it does. `tes launch --print-config` prints the same keys as a \
launch file, every one at its default and commented, ready to edit; fed back to \
`tes launch --config`, that file runs the defaults.

## How the launch file is read

- Every table and every key is optional: a key left out has its default, and no file at all \
is the same as an empty one.
- The file is read once, before anything starts, each table into the typed settings of its \
process. A key that is unknown (a typo), of the wrong type or repeated is refused, naming \
the file, the line, the table and the key (`launch.toml:7:1: [controller] budjet_us: unknown \
field ...`).
- The launcher then fills in the inherited keys (below) and checks every process's settings \
(ranges, and keys that contradict each other, such as a keep-alive too slow for the bridge's \
watchdog); the first bad key is reported the same way, and nothing is started.
- It writes each child's settings, as the child runs them, to the launch's run folder \
(in `[launch] runs_dir`, or `[launch] run_dir`): `perception-sim.toml`, `controller.toml`, \
`bridge.toml`.
- `--episodes N` overrides `[launch] episodes`.
";

/// The reference page's paragraph on the keys the children inherit.
const INHERITANCE: &str = "\
Some keys of the children's tables are one setting for the whole group: the seed, how the \
processes wait, the service prefix, the arena and the pace. The launcher fills them in from \
`[launch]` for each child whose table does not set the key itself; a table that sets one \
keeps its own value, even when it equals the default. So `[launch] wait = \"spin\"` makes \
every process spin, and adding `[perception] wait = \"block\"` leaves perception blocking. \
The printed launch file therefore has these keys commented out: uncommenting one takes that \
process off the launch-wide value.
";

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;

    use serde::de::{DeserializeOwned, Visitor};
    use tes_bridge::actions::{ActionSpec, MotorsConfig};
    use tes_bridge::brick::SimBrickConfig;
    use tes_bridge::config::{
        IpcConfig, LinkDelayConfig, PollConfig, SerialSection, WatchdogSection,
    };
    use tes_runtime::settings::Origin;

    use super::*;
    use crate::file::LaunchSection;
    use tes_bridge::config::BridgeSettings;
    use tes_controller::config::ControllerConfig;
    use tes_perception_sim::process::PerceptionConfig;

    /// Stops a [`FieldNames`] probe once it has seen the struct's fields.
    #[derive(Debug)]
    struct Seen;

    impl std::fmt::Display for Seen {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str("field names seen")
        }
    }

    impl std::error::Error for Seen {}

    impl serde::de::Error for Seen {
        fn custom<T: std::fmt::Display>(_: T) -> Self {
            Seen
        }
    }

    /// A deserializer that reads nothing: it records the field names a derived
    /// `Deserialize` of a struct asks for — every field, `Option`s included, which a
    /// serialised default leaves out.
    struct FieldNames<'a>(&'a mut &'static [&'static str]);

    impl<'de> serde::Deserializer<'de> for FieldNames<'_> {
        type Error = Seen;

        fn deserialize_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Seen> {
            Err(Seen)
        }

        fn deserialize_struct<V: Visitor<'de>>(
            self,
            _: &'static str,
            fields: &'static [&'static str],
            _: V,
        ) -> Result<V::Value, Seen> {
            *self.0 = fields;
            Err(Seen)
        }

        serde::forward_to_deserialize_any! {
            bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string bytes
            byte_buf option unit unit_struct newtype_struct seq tuple tuple_struct map enum
            identifier ignored_any
        }
    }

    /// The field names of the struct `T`, as its `Deserialize` knows them.
    fn fields_of<T: DeserializeOwned>() -> &'static [&'static str] {
        let mut fields: &'static [&'static str] = &[];
        assert!(T::deserialize(FieldNames(&mut fields)).is_err());
        assert!(
            !fields.is_empty(),
            "{} is not a struct",
            std::any::type_name::<T>()
        );
        fields
    }

    /// Every table of the launch file and the struct it is read into, as the parser's field
    /// names.
    fn struct_fields() -> Vec<(&'static str, &'static [&'static str])> {
        vec![
            ("launch", fields_of::<LaunchSection>()),
            ("launch.link", fields_of::<tes_link::LinkSection>()),
            ("perception", fields_of::<PerceptionConfig>()),
            ("controller", fields_of::<ControllerConfig>()),
            ("bridge", fields_of::<BridgeSettings>()),
            ("bridge.link_delay", fields_of::<LinkDelayConfig>()),
            ("bridge.serial", fields_of::<SerialSection>()),
            ("bridge.watchdog", fields_of::<WatchdogSection>()),
            ("bridge.poll", fields_of::<PollConfig>()),
            ("bridge.ipc", fields_of::<IpcConfig>()),
            ("bridge.brick", fields_of::<SimBrickConfig>()),
            ("bridge.motors", fields_of::<MotorsConfig>()),
            ("bridge.actions", fields_of::<ActionSpec>()),
        ]
    }

    /// The tables a launch file may add that its defaults do not have, as the parser's
    /// field names: a build without ROS 2 reads `[ros2_world]` as any table (and refuses
    /// it), so only a build with it knows the keys.
    fn optional_struct_fields() -> Vec<(&'static str, &'static [&'static str])> {
        #[cfg(feature = "ros2")]
        {
            vec![
                ("ros2_world", fields_of::<tes_ros2::world::WorldSettings>()),
                (
                    "ros2_world.twist",
                    fields_of::<tes_ros2::world::TwistAction>(),
                ),
            ]
        }
        #[cfg(not(feature = "ros2"))]
        {
            Vec::new()
        }
    }

    /// The dotted tables and keys of `value` (a table at `path`), into `tables` and `keys`.
    fn walk(
        path: &str,
        value: &toml::Value,
        tables: &mut BTreeSet<String>,
        keys: &mut BTreeSet<String>,
    ) {
        tables.insert(path.to_owned());
        let entries: Vec<&toml::Table> = match value {
            toml::Value::Table(t) => vec![t],
            toml::Value::Array(items) => items.iter().filter_map(|v| v.as_table()).collect(),
            _ => Vec::new(),
        };
        for table in entries {
            for (name, v) in table {
                let at = format!("{path}.{name}");
                if is_table(v) {
                    walk(&at, v, tables, keys);
                } else {
                    keys.insert(at);
                }
            }
        }
    }

    /// The keys the config structs know, dotted from the top of the file: every key of the
    /// serialised defaults, and every field name of each table's struct that is not itself a
    /// table (the fields unset by default, which serialising leaves out).
    fn struct_keys() -> BTreeSet<String> {
        let defaults = defaults().expect("defaults serialise");
        let (mut tables, mut keys) = (BTreeSet::new(), BTreeSet::new());
        for (name, value) in &defaults {
            walk(name, value, &mut tables, &mut keys);
        }
        let typed = struct_fields();
        let typed_tables: BTreeSet<String> = typed.iter().map(|(t, _)| t.to_string()).collect();
        assert_eq!(
            tables, typed_tables,
            "a table of the launch file has no struct in struct_fields() (or one is gone): \
             add it there and to TABLES in launch/src/reference.rs"
        );
        tables.extend(OPTIONAL_TABLES.iter().map(ToString::to_string));
        for (table, fields) in typed.into_iter().chain(optional_struct_fields()) {
            for field in fields {
                let at = format!("{table}.{field}");
                if !tables.contains(&at) {
                    keys.insert(at);
                }
            }
        }
        keys
    }

    fn reference_keys() -> BTreeSet<String> {
        let known_to_this_build =
            |k: &&Key| cfg!(feature = "ros2") || !k.table.starts_with("ros2_world");
        KEYS.iter()
            .filter(known_to_this_build)
            .map(Key::path)
            .collect()
    }

    /// Adding a field to any config struct without describing it fails here, naming it.
    #[test]
    fn every_key_of_every_config_struct_is_in_the_reference() {
        let missing: Vec<String> = struct_keys()
            .difference(&reference_keys())
            .cloned()
            .collect();
        assert!(
            missing.is_empty(),
            "keys the config structs know but the launch file reference does not describe: \
             {missing:?}; is its struct's source file in SOURCES of launch/build.rs? Then \
             regenerate the docs: {REGENERATE}"
        );
    }

    #[test]
    fn every_key_in_the_reference_is_known_to_the_parser() {
        let unknown: Vec<String> = reference_keys()
            .difference(&struct_keys())
            .cloned()
            .collect();
        assert!(
            unknown.is_empty(),
            "keys in the reference (launch/build.rs) that no config struct's parser knows: \
             {unknown:?}"
        );
        let described: BTreeSet<String> = KEYS.iter().map(Key::path).collect();
        assert_eq!(described.len(), KEYS.len(), "a key is described twice");
        for table in KEYS.iter().map(|k| k.table) {
            assert!(TABLES.iter().any(|t| t.name == table), "no table {table}");
        }
        // Every key written, the ones commented out by default included: the parser (which
        // refuses unknown keys) takes them all, and the children's tables then set every
        // inherited key themselves.
        let every = render_toml(true).expect("renders");
        let file =
            LaunchFile::from_toml(&every, Origin::Text).unwrap_or_else(|e| panic!("{e}\n{every}"));
        let own: BTreeSet<String> = INHERITED.iter().map(Inherited::path).collect();
        assert_eq!(file.own, own);
    }

    /// The printed file is the defaults: each table reads back as its default, no child table
    /// sets an inherited key, and the children's settings are those of no file at all.
    #[test]
    fn the_printed_file_reads_back_as_the_defaults() {
        let text = render_toml(false).expect("renders");
        let file =
            LaunchFile::from_toml(&text, Origin::Text).unwrap_or_else(|e| panic!("{e}\n{text}"));
        let defaults = LaunchFile::default();
        assert_eq!(
            format!("{:?}", file.launch),
            format!("{:?}", defaults.launch)
        );
        assert_eq!(file.perception, defaults.perception);
        assert_eq!(file.controller, defaults.controller);
        assert_eq!(file.bridge, defaults.bridge);
        assert!(file.own.is_empty(), "{:?}", file.own);
        assert_eq!(
            file.children().expect("valid"),
            defaults.children().expect("valid")
        );
    }

    /// Every key of the reference is inherited exactly when [`INHERITED`] lists it.
    #[test]
    fn the_inherited_keys_are_the_launchers() {
        for i in INHERITED {
            let path = i.path();
            let row = KEYS.iter().find(|k| k.path() == path);
            assert!(
                row.is_some_and(|k| k.inherited() == Some(i.value)),
                "{path} is inherited but has no key of the reference"
            );
        }
        let marked = KEYS.iter().filter(|k| k.inherited().is_some()).count();
        assert_eq!(marked, INHERITED.len());
        assert!(!is_inherited("bridge", "wait"));
        assert!(!is_inherited("bridge.i", "pc.wait"));
    }

    /// Each field of a config struct says what it does and, on a `Values:` line, its unit or
    /// values: the build script makes the reference from them.
    #[test]
    fn every_key_has_a_doc_and_a_values_line() {
        let lacking: Vec<String> = KEYS
            .iter()
            .filter_map(|k| match (k.meaning.is_empty(), k.allowed.is_empty()) {
                (true, _) => Some(format!("{}: no doc comment", k.path())),
                (false, true) => Some(format!("{}: no `Values:` line in its doc", k.path())),
                (false, false) => None,
            })
            .collect();
        assert!(
            lacking.is_empty(),
            "fields of the config structs without their reference text: {lacking:?}; document \
             each (what it does, then a paragraph `Values: <unit or values>.`), then \
             regenerate the docs: {REGENERATE}"
        );
        // A link to a constant is its value; a doc link of another kind is code.
        for k in KEYS {
            for text in [k.meaning, k.allowed] {
                assert!(
                    !text.contains("[`"),
                    "{}: unresolved link in {text:?}",
                    k.path()
                );
            }
        }
        let prefix = KEYS
            .iter()
            .find(|k| k.path() == "controller.service_prefix");
        assert_eq!(
            prefix.map(|k| k.allowed),
            Some("text, at most 64 bytes"),
            "SERVICE_PREFIX_MAX resolved"
        );
        // A range, of floats, defined in another file than the field that links it.
        let scale = KEYS.iter().find(|k| k.path() == "bridge.brick.time_scale");
        assert_eq!(
            scale.map(|k| k.allowed),
            Some("factor, 0.001 to 10000"),
            "TIME_SCALE_RANGE resolved"
        );
    }

    #[test]
    fn the_markdown_has_a_row_per_key_and_escapes_pipes() {
        let md = render_markdown().expect("renders");
        for table in TABLES {
            let header = if table.array {
                format!("## `[[{}]]`", table.name)
            } else {
                format!("## `[{}]`", table.name)
            };
            assert!(md.contains(&header), "{header}");
        }
        for k in KEYS {
            assert!(md.contains(&format!("\n| `{}` |", k.key)), "{}", k.path());
        }
        // Every row of a key table has its four cells.
        for line in md
            .lines()
            .filter(|l| l.starts_with("| `") && !l.starts_with("| `["))
        {
            let cells = line.replace("\\|", "").matches('|').count();
            assert_eq!(cells, 5, "{line}");
        }
    }

    #[test]
    fn comments_are_wrapped_without_losing_a_word() {
        let text = "a few words, and one-very-long-word-that-does-not-fit, then more";
        for width in [1, 5, 12, 40, 200] {
            let lines = wrap(text, width);
            assert_eq!(lines.join(" "), text, "{width}");
            for line in &lines {
                assert!(
                    line.chars().count() <= width || !line.contains(' '),
                    "{width}: {line:?}"
                );
            }
        }
        assert!(wrap("", 10).is_empty());
        let printed = render_toml(false).expect("renders");
        for line in printed.lines().filter(|l| l.starts_with("# ")) {
            assert!(
                line.chars().count() <= WIDTH || !line[2..].contains(' '),
                "{line}"
            );
        }
    }
}
