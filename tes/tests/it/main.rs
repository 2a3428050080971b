//! Integration tests of the `tes` command line, run as a user runs it: the built binary with
//! its real child processes. One binary; run a file's tests with `cargo test -p tes --test it
//! launch::` (its module name), one test with `cargo test -p tes --test it launch::NAME`.
//!
//! Every test that launches a group gives it its own data directory and service prefix (or
//! iceoryx2 domain), and a guard ([`common::Group`], [`common::Killed`]) kills what it started
//! and removes dead processes' iceoryx2 resources even when the test fails. Groups never run
//! beside the tests that must have the machine to themselves (the experiments, which load
//! every core, and `tes status`, which opens every group's services): see [`common::Alone`].

mod bench;
mod cli;
mod common;
mod config_reference;
mod faults;
mod hostile_files;
mod launch;
mod library_facts;
mod live_view;
mod multi_host;
mod recording;
mod ros2;
mod run_folder;
mod shutdown;
mod status;
mod tui;
mod viewers;
