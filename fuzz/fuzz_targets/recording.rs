//! The reader of our recordings on arbitrary bytes: a recording or a clear error, never a
//! panic (a truncated or corrupted file, another program's MCAP, garbage).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = std::path::Path::new("fuzz.mcap");
    let _ = tes_recorder::reader::Recording::from_bytes(path, data);
    // A valid MCAP header in front makes the fuzzer reach the records.
    let mut framed = mcap::MAGIC.to_vec();
    framed.extend_from_slice(data);
    let _ = tes_recorder::reader::Recording::from_bytes(path, &framed);
});
