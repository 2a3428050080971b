//! Integration tests of the bridge: the serial transport against the simulated brick served
//! on a pseudo-terminal, the Bluetooth and USB links' framings against the simulated brick
//! through in-memory pipes, an independent client (nxt-python) against that brick, and the
//! iceoryx2 bridge loop.

mod ipc;
mod links;
mod nxt_python;
mod scan;
mod serial;
mod time_scale;
mod util;
