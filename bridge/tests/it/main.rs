//! Integration tests of the bridge: the serial transport against the simulated brick served
//! on a pseudo-terminal, an independent client (nxt-python) against that brick, and the
//! iceoryx2 bridge loop.

mod ipc;
mod nxt_python;
mod serial;
mod time_scale;
mod util;
