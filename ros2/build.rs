//! Tells the integration tests whether the independent ROS 2 peers can be imported: PyPI's
//! `cyclonedds` (a ROS 2 middleware, Eclipse Cyclone DDS) and `rosbags` (a rosbag2 reader),
//! from the Python `tes_probe::ros2_peers_python` picks (`TES_ROS2_PYTHON`, else
//! `target/ros2-venv/bin/python`, where `.ci/run` installs them, else `python3`); the tests
//! run their peers with that same Python (`TES_ROS2_PYTHON` at compile time). Each test runs
//! when its peer can be imported and is reported ignored, with how to install it, when it
//! cannot; under CI they always run, so a missing peer fails them.

use std::path::PathBuf;

use tes_probe::Client;

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap_or_default());
    let python = tes_probe::ros2_peers_python(&manifest);
    println!("cargo::rustc-env=TES_ROS2_PYTHON={python}");
    tes_probe::tell_tests_using(
        &python,
        &[
            Client {
                cfg: "tes_cyclonedds",
                imports: "import cyclonedds.domain",
            },
            Client {
                cfg: "tes_rosbags",
                imports: "import rosbags.rosbag2",
            },
        ],
    );
}
