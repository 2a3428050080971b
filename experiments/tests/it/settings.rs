//! Each experiment's settings are defined once: the flags, the defaults their help prints and
//! the configs all come from it, and agree.

use clap::{Args, Command, FromArgMatches};
use serde::Serialize;
use tes_experiments::fig4::Fig4Config;
use tes_experiments::grid::GridConfig;
use tes_experiments::lifelong::LifelongConfig;
use tes_experiments::robot::RobotConfig;
use tes_experiments::settings::{Kind, Settings, SettingsArgs};
use tes_experiments::transfer::TransferConfig;

/// The config `args` give, through clap as `tes experiment` parses them.
fn parse<C: Settings>(args: &[&str]) -> Result<C, String> {
    let command = SettingsArgs::<C>::augment_args(Command::new("experiment"));
    let matches = command
        .try_get_matches_from(std::iter::once("experiment").chain(args.iter().copied()))
        .map_err(|e| e.to_string())?;
    SettingsArgs::<C>::from_arg_matches(&matches)
        .map_err(|e| e.to_string())?
        .config()
}

fn json<C: Serialize>(config: &C) -> serde_json::Value {
    serde_json::to_value(config).expect("a config serialises")
}

/// The help's `[default: X; --quick: Y]` of every value, read back from the rendered help
/// and given as the flag, gives the default (and the quick) config again; no flag gives the
/// standard config, `--quick` the quick one.
fn the_help_says_the_defaults<C: Settings + Serialize>() {
    assert_eq!(json(&parse::<C>(&[]).unwrap()), json(&C::standard()));
    assert_eq!(json(&parse::<C>(&["--quick"]).unwrap()), json(&C::quick()));
    let mut command = SettingsArgs::<C>::augment_args(Command::new("experiment"));
    let help = command.render_help().to_string().replace('\n', " ");
    let help = help.split_whitespace().collect::<Vec<_>>().join(" ");
    for setting in C::SETTINGS.iter().filter(|s| s.kind == Kind::Value) {
        let flag = format!("--{} <{}>", setting.flag, setting.value_name);
        let after = &help[help
            .find(&flag)
            .unwrap_or_else(|| panic!("{flag} in {help}"))..];
        let said = after
            .split_once("[default: ")
            .and_then(|(_, rest)| rest.split_once(']'))
            .map(|(said, _)| said)
            .unwrap_or_else(|| panic!("{flag} says no default: {after}"));
        let (standard, quick) = said.split_once("; --quick: ").unwrap_or((said, said));
        let long = format!("--{}", setting.flag);
        assert_eq!(
            json(&parse::<C>(&[&long, standard]).unwrap()),
            json(&C::standard()),
            "{long}: the help's default {standard:?} is not the config's"
        );
        assert_eq!(
            json(&parse::<C>(&["--quick", &long, quick]).unwrap()),
            json(&C::quick()),
            "{long}: the help's --quick value {quick:?} is not the quick config's"
        );
    }
    assert_eq!(
        tes_experiments::settings::check::<C>(),
        Vec::<String>::new()
    );
}

#[test]
fn every_experiments_help_says_its_configs_defaults() {
    the_help_says_the_defaults::<GridConfig>();
    the_help_says_the_defaults::<TransferConfig>();
    the_help_says_the_defaults::<RobotConfig>();
    the_help_says_the_defaults::<Fig4Config>();
    the_help_says_the_defaults::<LifelongConfig>();
}

#[test]
fn a_given_setting_changes_its_field_and_a_bad_one_is_refused_naming_the_flag() {
    let grid: GridConfig =
        parse(&["--quick", "--episodes", "30", "--methods", "loreRL,fEpsG"]).unwrap();
    assert_eq!((grid.runs, grid.episodes), (GridConfig::quick().runs, 30));
    assert_eq!(grid.methods.map(|m| m.len()), Some(2));
    let transfer: TransferConfig =
        parse(&["--tasks", "1,4", "--converge-plans", "--prune-one-per-task"]).unwrap();
    assert_eq!(transfer.test_tasks, [1, 4]);
    assert!(!transfer.stop_at_drift && transfer.prune_one_per_task);
    for (args, says) in [
        (&["--runs", "many"][..], "--runs <RUNS>"),
        (&["--fepsg-epsilon", "1.5"], "not a probability"),
        (&["--methods", "loreRL,nothing"], "\"nothing\" is no method"),
    ] {
        let err = parse::<GridConfig>(args).unwrap_err();
        assert!(err.contains(says), "{args:?}: {err}");
    }
    let err = parse::<LifelongConfig>(&["--recency", "fast"]).unwrap_err();
    assert!(err.contains("--recency <RECENCY>"), "{err}");
}
