//! Architecture invariant: no GUI crate in the dependency tree of the SDK, the diagram format, the
//! runtime, the CLI or the packs.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::process::Command;

const GUI_CRATES: [&str; 5] = ["egui", "eframe", "wgpu", "winit", "glutin"];
const HEADLESS: [&str; 9] = [
    "kairos-sdk",
    "kairos-diagram",
    "kairos-runtime",
    "kairos-protocol",
    "kairos",
    "kairos-pack-core",
    "kairos-pack-sensors",
    "kairos-pack-recording",
    "kairos-pack-filters",
];

#[test]
fn headless_crates_depend_on_no_gui_crate() {
    for package in HEADLESS {
        let output = Command::new(env!("CARGO"))
            .args([
                "tree",
                "--offline",
                "-e",
                "normal,build",
                "--prefix",
                "none",
                "-p",
                package,
            ])
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .expect("running cargo tree");
        assert!(
            output.status.success(),
            "{}",
            String::from_utf8_lossy(&output.stderr)
        );
        let tree = String::from_utf8_lossy(&output.stdout);
        for line in tree.lines() {
            let name = line.split_whitespace().next().unwrap_or_default();
            assert!(
                !GUI_CRATES
                    .iter()
                    .any(|gui| name == *gui || name.starts_with(&format!("{gui}-"))),
                "{package} depends on the GUI crate {name}"
            );
        }
    }
}
