//! `tes link keygen DIR`: the keys of a group split across hosts.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use tes_link::keys::{self, DEFAULT_PORT, Host};

/// Arguments of `tes link`.
#[derive(Debug, Args)]
pub struct LinkArgs {
    #[command(subcommand)]
    which: Which,
}

#[derive(Debug, Subcommand)]
enum Which {
    /// Make the group's own certificate authority and a certificate and key per host, and
    /// print the `[launch.link]` lines each host's launch file needs.
    Keygen {
        /// The directory for the keys (created, readable only by you; an existing one must be
        /// yours and closed to others, else it is refused with the `chmod` that fixes it).
        /// Existing keys are never overwritten.
        dir: PathBuf,
        /// A host: `NAME=ROLE[,ROLE…][@ADDRESS]`, e.g.
        /// `robot=perception-sim,bridge@192.168.1.20`; the address is an IP address or a DNS
        /// name. The first listens; the others connect to it. [default: `robot=perception-sim,bridge` and `learner=controller`]
        #[arg(long = "host", value_name = "NAME=ROLES[@ADDRESS]")]
        hosts: Vec<Host>,
        /// The port the first host listens on.
        #[arg(long, default_value_t = DEFAULT_PORT)]
        port: u16,
    },
}

/// Runs `tes link`.
pub fn run(args: &LinkArgs) -> Result<()> {
    match &args.which {
        Which::Keygen { dir, hosts, port } => keygen(dir, hosts, *port),
    }
}

fn keygen(dir: &Path, hosts: &[Host], port: u16) -> Result<()> {
    let hosts = if hosts.is_empty() {
        keys::default_hosts()
    } else {
        hosts.to_vec()
    };
    let set = keys::keygen(dir, &hosts, port)
        .with_context(|| format!("cannot make the group's keys in {}", dir.display()))?;
    println!(
        "made the group's authority ({}; its signing key {} stays here) and a certificate and \
         key for {} — every file readable only by you, in a directory only you may open.\n",
        set.authority.display(),
        set.authority_key.display(),
        set.hosts
            .iter()
            .map(|h| h.host.name.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    );
    print!("{}", set.launch_lines());
    Ok(())
}
