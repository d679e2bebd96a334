//! Helpers shared by the end-to-end tests: run the real `kairos` binary.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The repository root.
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .canonicalize()
        .expect("repository root")
}

/// The example diagram `name` (`hello`, `camera`, `fusion`).
#[allow(dead_code, reason = "not every test file uses every helper")]
pub fn example(name: &str) -> PathBuf {
    repo_root().join("examples").join(format!("{name}.ron"))
}

/// Runs `kairos` with `args` in `dir` and returns its output.
#[allow(dead_code, reason = "not every test file uses every helper")]
pub fn kairos(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kairos"))
        .args(args)
        .current_dir(dir)
        .env("RUST_LOG", "info")
        .output()
        .expect("running kairos")
}

/// Standard output and standard error as text.
pub fn text(output: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&output.stdout).into_owned(),
        String::from_utf8_lossy(&output.stderr).into_owned(),
    )
}

/// How many cycles `kairos run --stats` says component `id` ran, from the last table in `stderr`.
#[allow(dead_code, reason = "not every test file uses every helper")]
pub fn stats_cycles(stderr: &str, id: &str) -> u64 {
    let row = stderr
        .lines()
        .rev()
        .find(|l| l.split_whitespace().next() == Some(id))
        .unwrap_or_else(|| panic!("{id} in the stats: {stderr}"));
    row.split_whitespace()
        .nth(3)
        .and_then(|cycles| cycles.parse().ok())
        .unwrap_or_else(|| panic!("{id}'s cycles in: {row}"))
}
