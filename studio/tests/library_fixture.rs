//! `tests/library.json`, the component library the interface tests use without a runtime, is what the
//! `kairos` binary of this workspace prints with `kairos components --json`: generated, never edited by
//! hand. When a pack changes, this test fails and says how to regenerate it.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::path::{Path, PathBuf};
use std::process::Command;

/// The `kairos` binary: `KAIROS_BIN`, else this workspace's debug build, built here when it is missing.
fn kairos_binary() -> PathBuf {
    if let Some(binary) = std::env::var_os("KAIROS_BIN") {
        return PathBuf::from(binary);
    }
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let target =
        std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| manifest.join("../target"), PathBuf::from);
    let binary = target.join("debug/kairos");
    if !binary.is_file() {
        let built = Command::new(env!("CARGO"))
            .args(["build", "-p", "kairos"])
            .current_dir(manifest)
            .status()
            .unwrap();
        assert!(built.success(), "cargo build -p kairos failed");
    }
    binary
}

#[test]
fn the_library_fixture_is_what_the_kairos_binary_prints() {
    let binary = kairos_binary();
    let output = Command::new(&binary)
        .args(["components", "--json"])
        // Only the built-in packs: no pack path from the environment.
        .env_remove("KAIROS_PACK_PATH")
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", binary.display()));
    assert!(
        output.status.success(),
        "{} components --json failed: {}",
        binary.display(),
        String::from_utf8_lossy(&output.stderr)
    );
    let printed = String::from_utf8(output.stdout).unwrap();
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/library.json");
    let stored = std::fs::read_to_string(&fixture).unwrap();
    // Compared as JSON values, so the fixture's formatting does not matter.
    let parse = |text: &str| serde_json::from_str::<serde_json::Value>(text).unwrap();
    assert!(
        parse(&printed) == parse(&stored),
        "{} is not what `kairos components --json` prints; regenerate it with\n\
         \tcargo run -p kairos -- components --json > studio/tests/library.json",
        fixture.display()
    );
    // And the studio reads it.
    let library = kairos_studio::library_from_components_json(&stored).unwrap();
    assert!(library.component("sensors.lidar").is_some());
}
