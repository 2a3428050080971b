//! Feeds arbitrary bytes to the view-library decoder: as a whole file, and as a body behind
//! a valid header of each format version (magic, version, length and checksum), so the fuzzer reaches the
//! body's consistency checks without having to forge a CRC-32. Whatever decodes must
//! re-encode to exactly the same bytes, and its views must predict without panicking.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tes_learning::library::store::{FORMAT_VERSION, MAGIC, decode, encode};
use tes_learning::mdagl::Features;

fuzz_target!(|data: &[u8]| {
    check(data);
    for version in 1..=FORMAT_VERSION {
        let mut file = Vec::with_capacity(24 + data.len());
        file.extend_from_slice(&MAGIC);
        file.extend_from_slice(&version.to_le_bytes());
        file.extend_from_slice(&(data.len() as u64).to_le_bytes());
        file.extend_from_slice(&crc32fast::hash(data).to_le_bytes());
        file.extend_from_slice(data);
        check(&file);
    }
});

fn check(bytes: &[u8]) {
    let Ok(stored) = decode(bytes) else {
        return;
    };
    // The format is canonical: an accepted file is exactly what saving its library writes.
    let again = encode(&stored);
    assert_eq!(
        again, bytes,
        "an accepted library re-encodes to other bytes"
    );
    let library = &stored.library;
    for view in library.views() {
        assert!(view.action() < library.n_actions());
        let _ = library.track_record(view);
        let mut model = view.model().clone();
        let x: &[u32] = if library.n_features() > 0 { &[0] } else { &[] };
        if let Ok(p) = model.predict(Features::SparseBinary(x)) {
            let total: f64 = p.iter().sum();
            assert!(p.iter().all(|v| v.is_finite() && *v >= 0.0), "{p:?}");
            assert!((total - 1.0).abs() < 1e-9, "probabilities sum to {total}");
        }
    }
    let _ = library.fresh_model();
}
