//! Helpers shared by the studio's tests.

/// The `kairos` binary of this build (`cargo test` in the workspace builds it before running tests).
#[allow(dead_code, reason = "each test binary uses the helpers it needs")]
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

/// Clicks `menu_entry` in the context menu of the canvas widget labelled `widget` (a port).
#[allow(dead_code, reason = "each test binary uses the helpers it needs")]
pub fn context_menu_entry(
    harness: &mut egui_kittest::Harness<'_, kairos_studio::StudioApp>,
    widget: &str,
    menu_entry: &str,
) {
    use egui_kittest::kittest::Queryable as _;
    let on_canvas = harness.get_by_label(widget).rect().center();
    let at = harness.state().canvas.to_screen(on_canvas);
    harness.hover_at(at);
    harness.run_steps(1);
    for pressed in [true, false] {
        harness.event(egui::Event::PointerButton {
            pos: at,
            button: egui::PointerButton::Secondary,
            pressed,
            modifiers: egui::Modifiers::NONE,
        });
        harness.run_steps(1);
    }
    harness.run_steps(1);
    harness.get_by_label(menu_entry).click();
    harness.run_steps(2);
}
