//! Tells the integration tests whether PyPI's `mcap` (the independent reader `tes launch
//! --record` is checked against), PyPI's Zenoh (the stranger the link's TLS keeps out), the
//! viewers' clients (Rerun, Foxglove's Protobuf classes, a WebSocket client) and the ROS 2
//! peer (PyPI's `cyclonedds`, from the Python `tes_probe::ros2_peers_python` picks, which the
//! tests run it with: `TES_ROS2_PYTHON` at compile time) can be imported (see `tes_probe`:
//! each test runs when its client can be, and always under CI).

use std::path::PathBuf;

use tes_probe::Client;

fn main() {
    tes_probe::tell_tests(&[
        Client {
            cfg: "tes_mcap_reader",
            imports: "import mcap.reader",
        },
        Client {
            cfg: "tes_zenoh_client",
            imports: "import zenoh",
        },
        Client {
            cfg: "tes_viewer_clients",
            imports: "import rerun, foxglove_schemas_protobuf, mcap_protobuf, websockets.sync.client",
        },
    ]);
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap_or_default());
    let python = tes_probe::ros2_peers_python(&manifest);
    println!("cargo::rustc-env=TES_ROS2_PYTHON={python}");
    tes_probe::tell_tests_using(
        &python,
        &[Client {
            cfg: "tes_cyclonedds",
            imports: "import cyclonedds.domain",
        }],
    );
}
