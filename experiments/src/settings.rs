//! Each experiment's settings, defined once: one [`Setting`] per flag, in the experiment's own
//! module (e.g. [`GridConfig`](crate::grid::GridConfig)'s [`Settings::SETTINGS`]), says the
//! flag, its meaning, and how a config shows and takes its value. From that one definition
//! come the command line's flags ([`SettingsArgs`], a `clap::Args` the `tes experiment`
//! sub-commands flatten), the defaults their help prints (the standard and `--quick`
//! configs' own values, shown), and the docs' table ([`markdown`], `tes experiment settings`,
//! docs/experiments.md). The manifest a run writes is the config itself, serialised.
//!
//! ```
//! use clap::Parser;
//! use tes_experiments::grid::GridConfig;
//! use tes_experiments::settings::SettingsArgs;
//!
//! #[derive(Parser)]
//! struct Cli {
//!     #[command(flatten)]
//!     settings: SettingsArgs<GridConfig>,
//! }
//!
//! let cli = Cli::try_parse_from(["grid", "--quick", "--episodes", "30"])?;
//! let config = cli.settings.config()?;
//! assert_eq!((config.runs, config.episodes), (GridConfig::quick().runs, 30));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::fmt::Write as _;
use std::marker::PhantomData;
use std::str::FromStr;

use clap::{Arg, ArgAction, ArgMatches, Args, Command, FromArgMatches};

/// Whether a flag takes a value or is a switch.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// `--flag VALUE`.
    Value,
    /// `--flag` alone: turns something on that both the standard and the quick settings
    /// leave off.
    Switch,
}

/// One setting of an experiment: its flag, what it means, and how a config of type `C`
/// shows and takes its value.
pub struct Setting<C> {
    /// The long flag, without its dashes (`runs` is `--runs`).
    pub flag: &'static str,
    /// The value's name in the help (`N`, `SEED`); unused for a switch.
    pub value_name: &'static str,
    /// What it sets, in one sentence.
    pub help: &'static str,
    /// A value or a switch.
    pub kind: Kind,
    /// The config's value, as the flag takes it (a switch: `on` or `off`).
    pub show: fn(&C) -> String,
    /// Sets the config's value from the flag's text (a switch: from the empty text).
    pub take: fn(&mut C, &str) -> Result<(), String>,
}

/// An experiment's settings: its standard and `--quick` configs and its flags.
pub trait Settings: Clone + Send + Sync + 'static {
    /// What `--quick` means for this experiment, in one sentence.
    const QUICK_HELP: &'static str;
    /// Every flag that sets part of the config, in the help's order.
    const SETTINGS: &'static [Setting<Self>];
    /// The settings without `--quick`.
    fn standard() -> Self;
    /// The settings with `--quick`.
    fn quick() -> Self;
}

/// A whole number (or any `FromStr` value), said as the standard library says why not.
pub fn number<T: FromStr>(text: &str) -> Result<T, String>
where
    T::Err: std::fmt::Display,
{
    text.parse().map_err(|e: T::Err| e.to_string())
}

/// A comma-separated list of whole numbers.
pub fn numbers(text: &str) -> Result<Vec<usize>, String> {
    text.split(',').map(|n| number(n.trim())).collect()
}

/// An exploration probability, in [0, 1].
pub fn probability(text: &str) -> Result<f64, String> {
    let e: f64 = text
        .parse()
        .map_err(|_| format!("{text:?} is not a number"))?;
    if (0.0..=1.0).contains(&e) {
        Ok(e)
    } else {
        Err(format!("{e} is not a probability in [0, 1]"))
    }
}

/// `on` or `off`, as a switch's value shows.
pub fn on_off(on: bool) -> String {
    if on { "on" } else { "off" }.to_owned()
}

/// A list shown as the flag takes it.
pub fn comma_separated<T: ToString>(items: &[T]) -> String {
    items
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join(",")
}

/// The help line of `setting`: its meaning and, for a value, the default and (where it
/// differs) the `--quick` value, both shown from the configs themselves.
pub fn help<C: Settings>(setting: &Setting<C>) -> String {
    match setting.kind {
        Kind::Switch => setting.help.to_owned(),
        Kind::Value => {
            let (standard, quick) = ((setting.show)(&C::standard()), (setting.show)(&C::quick()));
            if standard == quick {
                format!("{} [default: {standard}]", setting.help)
            } else {
                format!("{} [default: {standard}; --quick: {quick}]", setting.help)
            }
        }
    }
}

/// The experiment `name`'s settings as a Markdown table: flag, default, `--quick`, meaning.
pub fn markdown<C: Settings>(name: &str) -> String {
    let mut text = format!(
        "### `tes experiment {name}`\n\n| flag | default | `--quick` | what it sets |\n|---|---|---|---|\n| `--quick` | | | {} |\n",
        C::QUICK_HELP
    );
    for setting in C::SETTINGS {
        let (flag, standard, quick) = match setting.kind {
            Kind::Value => (
                format!("`--{} {}`", setting.flag, setting.value_name),
                (setting.show)(&C::standard()),
                (setting.show)(&C::quick()),
            ),
            Kind::Switch => (format!("`--{}`", setting.flag), "off".into(), "off".into()),
        };
        // A table cell holds no bare `|`.
        let meaning = setting.help.replace('|', "\\|");
        let _ = writeln!(text, "| {flag} | {standard} | {quick} | {meaning} |");
    }
    text
}

/// The settings flags of experiment `C` on a command line: `--quick` and every
/// [`Setting`] of [`Settings::SETTINGS`]. [`config`](Self::config) is the standard (or
/// quick) config with the given flags applied, in the order of the settings.
pub struct SettingsArgs<C> {
    quick: bool,
    /// The given flags' values (a switch's: empty), by the setting's index.
    given: Vec<(usize, String)>,
    config: PhantomData<fn() -> C>,
}

impl<C> std::fmt::Debug for SettingsArgs<C> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SettingsArgs")
            .field("quick", &self.quick)
            .field("given", &self.given)
            .finish()
    }
}

impl<C: Settings> SettingsArgs<C> {
    /// Whether `--quick` or any setting was given.
    pub fn any_given(&self) -> bool {
        self.quick || !self.given.is_empty()
    }

    /// The config: the standard or quick one, with each given flag applied.
    pub fn config(&self) -> Result<C, String> {
        let mut config = if self.quick {
            C::quick()
        } else {
            C::standard()
        };
        for (index, text) in &self.given {
            let setting = &C::SETTINGS[*index];
            (setting.take)(&mut config, text).map_err(|e| format!("--{}: {e}", setting.flag))?;
        }
        Ok(config)
    }
}

impl<C: Settings> FromArgMatches for SettingsArgs<C> {
    fn from_arg_matches(matches: &ArgMatches) -> Result<Self, clap::Error> {
        let mut args = Self {
            quick: false,
            given: Vec::new(),
            config: PhantomData,
        };
        args.update_from_arg_matches(matches)?;
        Ok(args)
    }

    fn update_from_arg_matches(&mut self, matches: &ArgMatches) -> Result<(), clap::Error> {
        self.quick |= matches.get_flag("quick");
        for (index, setting) in C::SETTINGS.iter().enumerate() {
            let given = match setting.kind {
                Kind::Value => matches.get_one::<String>(setting.flag).cloned(),
                Kind::Switch => matches.get_flag(setting.flag).then(String::new),
            };
            if let Some(text) = given {
                self.given.retain(|(i, _)| *i != index);
                self.given.push((index, text));
            }
        }
        Ok(())
    }
}

impl<C: Settings> Args for SettingsArgs<C> {
    fn augment_args(command: Command) -> Command {
        let command = command.arg(
            Arg::new("quick")
                .long("quick")
                .action(ArgAction::SetTrue)
                .help(C::QUICK_HELP),
        );
        C::SETTINGS.iter().fold(command, |command, setting| {
            let arg = Arg::new(setting.flag)
                .long(setting.flag)
                .help(help(setting));
            command.arg(match setting.kind {
                Kind::Switch => arg.action(ArgAction::SetTrue),
                Kind::Value => {
                    let take = setting.take;
                    // Checked as it is parsed, so a bad value is clap's usage error.
                    arg.value_name(setting.value_name)
                        .value_parser(move |text: &str| {
                            take(&mut C::standard(), text).map(|()| text.to_owned())
                        })
                }
            })
        })
    }

    fn augment_args_for_update(command: Command) -> Command {
        Self::augment_args(command)
    }
}

/// Checks every experiment's definition: each value's default, as its help prints it, is
/// taken back as that very default (and so for `--quick`); a switch is off in both configs.
/// Returns what does not hold, named.
pub fn check<C: Settings + serde::Serialize>() -> Vec<String> {
    let mut wrong = Vec::new();
    let json = |c: &C| serde_json::to_value(c).unwrap_or_default();
    for setting in C::SETTINGS {
        for (which, config) in [("default", C::standard()), ("--quick", C::quick())] {
            let shown = (setting.show)(&config);
            match setting.kind {
                Kind::Value => {
                    let mut back = config.clone();
                    let taken = (setting.take)(&mut back, &shown);
                    if taken.is_err() || json(&back) != json(&config) {
                        wrong.push(format!(
                            "--{}: the {which} shown as {shown:?} is not taken back as the {which} ({taken:?})",
                            setting.flag
                        ));
                    }
                }
                Kind::Switch if shown != "off" => wrong.push(format!(
                    "--{}: a switch, but on in the {which} settings",
                    setting.flag
                )),
                Kind::Switch => {}
            }
        }
    }
    wrong
}
