//! `tes-bridge scan` as a user runs it: a line for USB and one for Bluetooth, each naming the
//! bricks found or why there are none, and JSON that says the same.

use std::process::Command;

#[test]
fn scan_says_what_each_link_offers_and_exits_1_without_a_brick() {
    let run = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_tes-bridge"))
            .arg("scan")
            .args(args)
            .env("RUST_LOG", "warn")
            .output()
            .expect("run tes-bridge scan")
    };
    let text = run(&[]);
    let said = String::from_utf8_lossy(&text.stdout);
    let json = run(&["--json"]);
    let found: serde_json::Value = serde_json::from_slice(&json.stdout).expect("JSON");
    let bricks = found["usb"].as_array().map_or(0, Vec::len)
        + found["bluetooth"]["bricks"].as_array().map_or(0, Vec::len);
    assert_eq!(
        text.status.code(),
        Some(if bricks == 0 { 1 } else { 0 }),
        "{said}"
    );
    assert_eq!(text.status.code(), json.status.code());
    let usb = said
        .lines()
        .find(|l| l.starts_with("USB: "))
        .expect("a USB line");
    let bluetooth = said
        .lines()
        .find(|l| l.starts_with("Bluetooth: "))
        .expect("a Bluetooth line");
    // Without bricks, each line says why (on the build machine: no USB bus, no Bluetooth).
    if found["usb"].as_array().is_some_and(Vec::is_empty) {
        assert!(
            usb.contains("no NXT plugged in") || usb.contains("cannot list USB devices"),
            "{usb}"
        );
    }
    if let Some(problem) = found["bluetooth"]["problem"].as_str() {
        assert!(bluetooth.contains(problem), "{bluetooth}");
    }
}
