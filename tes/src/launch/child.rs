//! This executable in one of the group's roles.

use super::*;

/// The child roles' entry points (`tes child ROLE --config FILE`).
pub fn run_child(role: &str, config: &Path) -> Result<()> {
    let text = std::fs::read_to_string(config)
        .with_context(|| format!("cannot read {}", config.display()))?;
    let origin = Origin::File(config.to_owned());
    match role {
        "controller" => {
            let cfg = ControllerConfig::from_toml_in(&text, origin)?;
            let stop = tes_runtime::signals::stop_on_signals()?;
            let summary = tes_controller::process::run_to_end(&cfg, &stop)?;
            if summary.failed_saves > 0 {
                bail!("{} library saves failed", summary.failed_saves);
            }
            Ok(())
        }
        "perception-sim" => {
            let cfg = PerceptionConfig::from_toml_in(&text, origin)?;
            let stop = tes_runtime::signals::stop_on_signals()?;
            tes_perception_sim::process::run(&cfg, &stop)?;
            Ok(())
        }
        "bridge" => {
            let cfg = BridgeConfig::from_toml_in(&text, origin)?;
            let stop = tes_runtime::signals::stop_on_signals()?;
            let opts = tes_bridge::ipc::RunOptions {
                handle_signals: false,
                stop: Some(stop),
            };
            match tes_bridge::process::run(&cfg, &opts) {
                Err(e @ tes_bridge::process::ProcessError::LinkDown { .. }) => {
                    // A distinct status: the launcher ends the launch instead of respawning.
                    eprintln!("error: {e}");
                    std::process::exit(tes_bridge::process::LINK_DOWN_EXIT_STATUS);
                }
                done => {
                    done?;
                    Ok(())
                }
            }
        }
        relay if tes_bench::relay::ROLES.contains(&relay) => {
            let cfg = tes_bench::relay::RelayConfig::from_toml_in(&text, origin)?;
            let stop = tes_runtime::signals::stop_on_signals()?;
            tes_bench::relay::run(relay, &cfg, &stop)?;
            Ok(())
        }
        other => bail!("unknown role {other:?} (expected one of {ROLES:?})"),
    }
}
