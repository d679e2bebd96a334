//! Helpers shared by the studio's tests that start a real runtime.

/// The `kairos` binary of this build (`cargo test` in the workspace builds it before running tests).
pub fn kairos_binary() -> std::path::PathBuf {
    let test = std::env::current_exe().expect("the test's own path");
    let binary = test
        .parent()
        .and_then(std::path::Path::parent)
        .expect("the test runs from target/PROFILE/deps")
        .join("kairos");
    assert!(
        binary.is_file(),
        "{} is missing: run the workspace's tests (cargo test), or `cargo build -p kairos` first",
        binary.display()
    );
    binary
}
