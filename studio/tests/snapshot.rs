//! The main window with an example diagram, rendered in software (wgpu on Mesa's lavapipe) and compared
//! with the stored picture in `tests/snapshots/` (`UPDATE_SNAPSHOTS=1` rewrites it after a deliberate
//! change of looks).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use egui::Vec2;
use egui_kittest::{Harness, SnapshotOptions};
use kairos_studio::{Document, StudioApp};

#[test]
fn the_main_window_with_the_fusion_example() {
    let library = kairos_studio::library_from_components_json(include_str!("library.json")).unwrap();
    let example = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/fusion.ron");
    let document = Document::open(&example).unwrap();
    let app = StudioApp::new(document, library, None, "no runtime".to_owned(), None);
    let mut harness = Harness::builder()
        .with_size(Vec2::new(1280.0, 800.0))
        .wgpu()
        .build_ui_state(|ui, app: &mut StudioApp| app.show(ui), app);
    harness.run_steps(4);
    // The comparison ignores pixels it classes as anti-aliasing, so it catches changes of layout, shapes and
    // colours (a node 20 px wider fails it by 15 000 pixels) rather than of single glyphs.
    let result = harness.try_snapshot_options("main_window", &SnapshotOptions::new().max_failed_pixels(20));
    if let Err(error) = result {
        panic!("{error}");
    }
}
