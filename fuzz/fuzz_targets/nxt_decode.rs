//! Feeds arbitrary bytes to every NXT decoder and to the simulated brick.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tes_bridge::brick::{SimBrick, SimBrickConfig};
use tes_bridge::nxt::frame::decode_frame;
use tes_bridge::nxt::{FrameDecoder, Reply, Request};

fuzz_target!(|data: &[u8]| {
    if let Ok((req, reply)) = Request::decode(data) {
        assert_eq!(req.encode(reply).as_bytes(), data);
    }
    if let Ok(r) = Reply::decode(data) {
        assert_eq!(r.encode().as_bytes(), data);
    }
    let _ = decode_frame(data);
    let mut d = FrameDecoder::new();
    if let Ok(mut brick) = SimBrick::new(SimBrickConfig::default(), 0) {
        for &b in data {
            if let Some(Ok(t)) = d.push(b) {
                brick.advance(std::time::Duration::from_millis(u64::from(b)));
                let _ = brick.handle(t.as_bytes());
            }
        }
    }
});
