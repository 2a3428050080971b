//! One process of the group, run in this process: what a child started by the supervisor
//! does (`tes child ROLE --config FILE`).

use std::path::{Path, PathBuf};

use tes_bridge::config::BridgeConfig;
use tes_controller::config::ControllerConfig;
use tes_perception_sim::process::PerceptionConfig;
use tes_runtime::settings::Origin;
use tes_topics::Role;

/// Why a role's process ended in failure.
#[derive(Debug, thiserror::Error)]
pub enum RoleError {
    /// Its settings file cannot be read.
    #[error("cannot read {}", path.display())]
    Read {
        /// The settings file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// Its settings are refused (placed in the file).
    #[error(transparent)]
    Settings(Box<dyn std::error::Error + Send + Sync>),
    /// The signal handlers cannot be installed.
    #[error("cannot install the signal handlers")]
    Signals(#[source] std::io::Error),
    /// The process failed.
    #[error(transparent)]
    Failed(Box<dyn std::error::Error + Send + Sync>),
    /// The controller could not save the library after some episodes.
    #[error("{0} library saves failed")]
    SavesFailed(u64),
    /// The bridge's link to the brick is down and did not come back: respawning cannot
    /// bring it back, so the process exits with [`RoleError::exit_status`] and the
    /// supervisor ends the launch.
    #[error(transparent)]
    LinkDown(tes_bridge::process::ProcessError),
}

impl RoleError {
    /// The exit status the process ends with: the bridge's link-down status
    /// ([`tes_bridge::process::LINK_DOWN_EXIT_STATUS`]) tells the supervisor not to respawn.
    pub fn exit_status(&self) -> i32 {
        match self {
            RoleError::LinkDown(_) => tes_bridge::process::LINK_DOWN_EXIT_STATUS,
            _ => 1,
        }
    }
}

/// Runs `role` with the settings file `config` until its work is done or a signal stops it.
pub fn run_role(role: Role, config: &Path) -> Result<(), RoleError> {
    let text = std::fs::read_to_string(config).map_err(|source| RoleError::Read {
        path: config.to_owned(),
        source,
    })?;
    let origin = Origin::File(config.to_owned());
    let settings = |e: Box<dyn std::error::Error + Send + Sync>| RoleError::Settings(e);
    let stop = tes_runtime::signals::stop_on_signals().map_err(RoleError::Signals)?;
    match role {
        Role::Controller => {
            let cfg =
                ControllerConfig::from_toml_in(&text, origin).map_err(|e| settings(e.into()))?;
            let summary = tes_controller::process::run_to_end(&cfg, &stop)
                .map_err(|e| RoleError::Failed(e.into()))?;
            match summary.failed_saves {
                0 => Ok(()),
                n => Err(RoleError::SavesFailed(n)),
            }
        }
        Role::Perception if crate::world::is_world_file(&text) => {
            crate::world::run_world(&text, &stop).map_err(RoleError::Failed)
        }
        Role::Perception => {
            let cfg =
                PerceptionConfig::from_toml_in(&text, origin).map_err(|e| settings(e.into()))?;
            // A respawned perception goes on with the run's episodes.
            let resume = std::env::var_os(crate::children::RESUME_ENV).is_some_and(|v| v == "1");
            tes_perception_sim::process::run_resuming(&cfg, &stop, resume)
                .map(|_| ())
                .map_err(|e| RoleError::Failed(e.into()))
        }
        Role::Bridge => {
            let mut cfg =
                BridgeConfig::from_toml_in(&text, origin).map_err(|e| settings(e.into()))?;
            // The launcher writes the simulated brick's pace from the run's real-time factor
            // whatever the transport; a real brick runs in physical time, so the bridge need
            // not warn that the scale is ignored (the user never wrote it).
            if cfg.transport != tes_bridge::config::TransportKind::Sim {
                cfg.brick.time_scale = 1.0;
            }
            let opts = tes_bridge::ipc::RunOptions {
                handle_signals: false,
                stop: Some(stop),
            };
            match tes_bridge::process::run(&cfg, &opts) {
                Ok(_) => Ok(()),
                Err(e @ tes_bridge::process::ProcessError::LinkDown { .. }) => {
                    Err(RoleError::LinkDown(e))
                }
                Err(e) => Err(RoleError::Failed(e.into())),
            }
        }
    }
}
