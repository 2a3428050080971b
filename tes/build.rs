//! Tells the integration tests whether PyPI's `mcap` (the independent reader `tes launch
//! --record` is checked against), PyPI's Zenoh (the stranger the link's TLS keeps out) and the
//! viewers' clients (Rerun, Foxglove's Protobuf classes, a WebSocket client) can be imported
//! (see `tes_probe`: each test runs when its client can be, and always under CI).

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
}
