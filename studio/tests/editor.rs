//! The editor driven through its interface, as a user would: components dragged from the palette onto the
//! canvas, ports connected by dragging, a connection the input refuses, a property typed in, undo, save.
//! Widgets are found by their accessible labels.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

mod common;

use common::context_menu_entry;
use egui::accesskit::Role;
use egui::{Pos2, Vec2};
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable as _;
use kairos_diagram::{LibraryInfo, PortRef};
use kairos_studio::viewers::ViewerKind;
use kairos_studio::{Document, StudioApp};

fn library() -> LibraryInfo {
    kairos_studio::library_from_components_json(include_str!("library.json")).unwrap()
}

/// A studio on the diagram file at `path`, with no runtime, its window `size`.
fn studio_on(path: &std::path::Path, size: Vec2) -> Harness<'static, StudioApp> {
    studio_on_paced(path, size, None)
}

/// [`studio_on`] with frames at a desktop's pace: the two clicks of a double click come within its 0.3 s.
fn studio_on_at_desktop_pace(path: &std::path::Path, size: Vec2) -> Harness<'static, StudioApp> {
    studio_on_paced(path, size, Some(1.0 / 60.0))
}

fn studio_on_paced(path: &std::path::Path, size: Vec2, step: Option<f32>) -> Harness<'static, StudioApp> {
    let app = StudioApp::new(
        Document::open(path).unwrap(),
        library(),
        None,
        "no runtime (test)".to_owned(),
        None,
    );
    let mut builder = Harness::builder().with_size(size);
    if let Some(step) = step {
        builder = builder.with_step_dt(step);
    }
    builder.build_ui_state(|ui, app: &mut StudioApp| app.show(ui), app)
}

fn studio() -> Harness<'static, StudioApp> {
    studio_with(None)
}

/// The studio, remembering its settings in `config` when given (else nowhere).
fn studio_with(config: Option<&std::path::Path>) -> Harness<'static, StudioApp> {
    let mut app = StudioApp::new(
        Document::default(),
        library(),
        None,
        "no runtime (test)".to_owned(),
        None,
    );
    if let Some(config) = config {
        app = app.with_config_dir(config.to_owned());
    }
    let mut harness = Harness::new_ui_state(|ui, app: &mut StudioApp| app.show(ui), app);
    // Tall enough for the whole palette, the viewer entry at its end included.
    harness.set_size(Vec2::new(1280.0, 2400.0));
    harness.run_steps(2);
    harness
}

/// File → Connect to a runtime….
fn open_connect_dialog(harness: &mut Harness<'_, StudioApp>) {
    harness.get_by_label("File").click();
    harness.run_steps(2);
    harness.get_by_label("Connect to a runtime…").click();
    harness.run_steps(2);
}

/// Presses at `from`, moves in small steps to `to`, releases there.
fn drag(harness: &mut Harness<'_, StudioApp>, from: Pos2, to: Pos2) {
    harness.hover_at(from);
    harness.run_steps(1);
    harness.drag_at(from);
    harness.run_steps(1);
    for step in 1..=8 {
        let t = step as f32 / 8.0;
        harness.hover_at(from + (to - from) * t);
        harness.run_steps(1);
    }
    harness.drop_at(to);
    harness.run_steps(2);
}

fn center_of(harness: &Harness<'_, StudioApp>, label: &str) -> Pos2 {
    harness.get_by_label(label).rect().center()
}

/// Where a canvas widget is on the screen (accessible bounds inside the zoomable canvas are in canvas
/// coordinates).
fn on_canvas(harness: &Harness<'_, StudioApp>, label: &str) -> Pos2 {
    harness.state().canvas.to_screen(center_of(harness, label))
}

fn click_on_canvas(harness: &mut Harness<'_, StudioApp>, label: &str) {
    let at = on_canvas(harness, label);
    harness.hover_at(at);
    harness.run_steps(1);
    harness.drag_at(at);
    harness.run_steps(1);
    harness.event(egui::Event::PointerButton {
        pos: at,
        button: egui::PointerButton::Primary,
        pressed: false,
        modifiers: egui::Modifiers::NONE,
    });
    harness.run_steps(2);
}

/// Drags the palette's entry of `type_name` (shown by its readable name) onto the canvas at `at`.
fn add_from_palette(harness: &mut Harness<'_, StudioApp>, type_name: &str, at: Pos2) {
    let name = library().component(type_name).unwrap().display_name();
    let from = center_of(harness, &name);
    drag(harness, from, at);
}

/// File → Save as…, `path` typed, Save.
fn save_as(harness: &mut Harness<'_, StudioApp>, path: &std::path::Path) {
    harness.get_by_label("File").click();
    harness.run_steps(2);
    harness.get_by_label("Save as… Ctrl+Shift+S").click();
    harness.run_steps(2);
    harness.get_by_role_and_label(Role::TextInput, "File:").focus();
    harness.run_steps(1);
    harness.key_press_modifiers(egui::Modifiers::COMMAND, egui::Key::A);
    harness
        .get_by_role_and_label(Role::TextInput, "File:")
        .type_text(path.to_str().unwrap());
    harness.run_steps(1);
    harness.get_by_label("Save").click();
    harness.run_steps(2);
}

/// The open viewers: what each shows and how.
fn open_viewers(harness: &Harness<'_, StudioApp>) -> Vec<(String, ViewerKind)> {
    harness
        .state()
        .session
        .viewers
        .list
        .iter()
        .map(|v| (v.output.clone(), v.kind))
        .collect()
}

fn camera_image_viewer() -> (String, ViewerKind) {
    ("camera1.image".to_owned(), ViewerKind::Image)
}

#[test]
fn a_diagram_is_built_through_the_interface_and_saved() {
    let mut harness = studio();
    add_from_palette(&mut harness, "core.sine", Pos2::new(450.0, 250.0));
    add_from_palette(&mut harness, "core.console", Pos2::new(800.0, 250.0));
    let ids: Vec<String> = harness
        .state()
        .session
        .document
        .diagram()
        .components
        .iter()
        .map(|c| c.id.clone())
        .collect();
    assert_eq!(ids, ["sine1", "console1"]);

    let from = on_canvas(&harness, "output sine1.out (f64)");
    let to = on_canvas(&harness, "input console1.in (any)");
    drag(&mut harness, from, to);
    let connections = &harness.state().session.document.diagram().connections;
    assert_eq!(
        connections.len(),
        1,
        "the ports were connected: {:?}",
        harness.state().canvas.notice()
    );
    assert_eq!(connections[0].from, PortRef::new("sine1", "out"));

    // Select the console and type a prefix into its inspector.
    click_on_canvas(&mut harness, "component console1 (core.console)");
    let prefix = harness.get_by_role_and_label(Role::TextInput, "prefix");
    prefix.focus();
    harness.run_steps(1);
    harness
        .get_by_role_and_label(Role::TextInput, "prefix")
        .type_text("wave: ");
    harness.run_steps(2);
    let console = harness
        .state()
        .session
        .document
        .diagram()
        .component("console1")
        .unwrap()
        .clone();
    assert_eq!(
        console.properties["prefix"],
        kairos_diagram::Value::Text("wave: ".to_owned())
    );

    // Undo takes the typing back; the connection stays.
    harness.state_mut().session.document.undo();
    harness.run_steps(1);
    assert!(
        harness
            .state()
            .session
            .document
            .diagram()
            .component("console1")
            .unwrap()
            .properties
            .get("prefix")
            .is_none_or(|v| v != &kairos_diagram::Value::Text("wave: ".to_owned()))
    );
    assert_eq!(harness.state().session.document.diagram().connections.len(), 1);

    // File > Save as…, a typed path, Save.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("built.ron");
    save_as(&mut harness, &dir.path().join("built"));
    assert_eq!(
        harness.state().session.document.path(),
        Some(path.as_path()),
        "saved with .ron added"
    );
    assert!(!harness.state().session.document.is_dirty());
    let saved = kairos_diagram::load(&path).unwrap().1.diagram;
    assert_eq!(
        saved.to_ron(),
        harness.state().session.document.diagram().to_ron()
    );
    assert!(
        std::fs::read_to_string(&path)
            .unwrap()
            .contains("Connection(from: \"sine1.out\", to: \"console1.in\")")
    );
}

#[test]
fn a_connection_the_input_refuses_is_not_made_and_the_canvas_says_why() {
    let mut harness = studio();
    add_from_palette(&mut harness, "sensors.camera", Pos2::new(450.0, 250.0));
    add_from_palette(&mut harness, "core.gain", Pos2::new(800.0, 250.0));
    let from = on_canvas(&harness, "output camera1.image (image)");
    let to = on_canvas(&harness, "input gain1.in (f64 | i64 | bool)");
    drag(&mut harness, from, to);
    assert!(harness.state().session.document.diagram().connections.is_empty());
    let notice = harness.state().canvas.notice().unwrap_or_default().to_owned();
    assert_eq!(
        notice,
        "gain1.in needs a number, a whole number or a yes/no value, and camera1.image gives an image"
    );
    // Said in the log too, where it stays.
    assert!(
        harness
            .state()
            .session
            .log
            .lines()
            .any(|l| l.text == notice && l.level == kairos_protocol::LogLevel::Warn)
    );
}

#[test]
fn a_path_property_is_chosen_in_the_file_chooser() {
    let mut harness = studio();
    add_from_palette(&mut harness, "recording.recorder", Pos2::new(600.0, 300.0));
    click_on_canvas(&mut harness, "component recorder1 (recording.recorder)");
    harness.get_by_label("…").click();
    harness.run_steps(2);
    // Tests run in the package's folder, which holds Cargo.toml.
    harness.get_by_label("Cargo.toml").click();
    harness.run_steps(2);
    let recorder = harness
        .state()
        .session
        .document
        .diagram()
        .component("recorder1")
        .unwrap()
        .clone();
    assert_eq!(
        recorder.properties["path"],
        kairos_diagram::Value::Text("Cargo.toml".to_owned())
    );
}

#[test]
fn a_box_dragged_on_the_background_selects_what_it_touches() {
    let mut harness = studio();
    add_from_palette(&mut harness, "core.sine", Pos2::new(450.0, 250.0));
    add_from_palette(&mut harness, "core.gain", Pos2::new(800.0, 250.0));
    add_from_palette(&mut harness, "core.console", Pos2::new(800.0, 600.0));
    let before = harness.state().session.document.diagram().clone();
    let sine = on_canvas(&harness, "component sine1 (core.sine)");
    let gain = on_canvas(&harness, "component gain1 (core.gain)");
    // From empty canvas above and left of the sine to below the gain's middle: not the console.
    drag(
        &mut harness,
        sine - Vec2::new(130.0, 90.0),
        gain + Vec2::new(0.0, 20.0),
    );
    let selected: Vec<&str> = harness
        .state()
        .canvas
        .selected
        .iter()
        .map(String::as_str)
        .collect();
    assert_eq!(selected, ["gain1", "sine1"]);
    // Nothing moved: the drag selected instead of panning or dragging a node.
    assert_eq!(harness.state().session.document.diagram(), &before);
}

#[test]
fn a_viewer_dropped_on_an_output_opens_for_its_type() {
    let mut harness = studio();
    add_from_palette(&mut harness, "sensors.camera", Pos2::new(450.0, 250.0));
    let from = center_of(&harness, "Viewer");
    let to = on_canvas(&harness, "output camera1.image (image)");
    drag(&mut harness, from, to);
    assert_eq!(open_viewers(&harness), [camera_image_viewer()]);
    assert!(
        !harness.state().session.document.is_dirty() || harness.state().session.document.path().is_none(),
        "opening a viewer is not an edit to be asked about"
    );

    // Saved with the diagram and opened with it again, in a new studio.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("viewed.ron");
    save_as(&mut harness, &path);
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(
        text.contains(
            "viewers: [\n        Viewer(output: \"camera1.image\", kind: \"image\", area: 0, share: 1.0),"
        ),
        "{text}"
    );
    let app = StudioApp::new(
        Document::open(&path).unwrap(),
        library(),
        None,
        "no runtime (test)".to_owned(),
        None,
    );
    let reopened = Harness::new_ui_state(|ui, app: &mut StudioApp| app.show(ui), app);
    assert_eq!(open_viewers(&reopened), [camera_image_viewer()]);
    assert!(!reopened.state().session.document.is_dirty());
    // The diagram format reads the file as any other diagram.
    assert!(kairos_diagram::load(&path).is_ok());
}

/// The dock's areas: each one's viewers (outputs) and share of the height, top to bottom.
fn dock(harness: &mut Harness<'_, StudioApp>) -> Vec<(Vec<String>, f32)> {
    harness.state_mut().session.viewers.dock_areas()
}

#[test]
fn docked_viewers_share_an_area_as_tabs_resize_and_come_back_so() {
    let mut harness = studio();
    add_from_palette(&mut harness, "sensors.camera", Pos2::new(300.0, 250.0));
    add_from_palette(&mut harness, "core.sine", Pos2::new(300.0, 450.0));
    for (output, kind) in [
        ("camera1.image", ViewerKind::Image),
        ("sine1.out", ViewerKind::Plot),
        ("sine1.out", ViewerKind::Table),
    ] {
        harness
            .state_mut()
            .session
            .viewers
            .open_kind(output.to_owned(), kind);
    }
    harness.run_steps(3);
    let outputs = |areas: &[(Vec<String>, f32)]| -> Vec<Vec<String>> {
        areas.iter().map(|(viewers, _)| viewers.clone()).collect()
    };
    let owned = |names: &[&[&str]]| -> Vec<Vec<String>> {
        names
            .iter()
            .map(|area| area.iter().map(|&o| o.to_owned()).collect())
            .collect()
    };
    // Each opens in an area of its own, stacked.
    assert_eq!(
        outputs(&dock(&mut harness)),
        owned(&[&["camera1.image"], &["sine1.out"], &["sine1.out"]])
    );

    // The plot's tab dropped in the middle of the image's area: they share it as tabs.
    let image_tab = harness.get_by_label("camera1.image — image").rect();
    let plot_tab = harness.get_by_label("sine1.out — plot").rect();
    // The dock ends where its areas' Float buttons end.
    let dock_right = harness.get_all_by_label("Float").next().unwrap().rect().right();
    let middle = Pos2::new(
        f32::midpoint(image_tab.left(), dock_right),
        f32::midpoint(image_tab.bottom(), plot_tab.top()),
    );
    drag(&mut harness, plot_tab.center(), middle);
    assert_eq!(
        outputs(&dock(&mut harness)),
        owned(&[&["camera1.image", "sine1.out"], &["sine1.out"]])
    );
    // The tab clicked is the one drawn.
    harness.get_by_label("sine1.out — plot").click();
    harness.run_steps(2);
    let in_front = harness.state().session.viewers.docked_in_front();
    assert_eq!(in_front, ["sine1.out plot", "sine1.out table"]);
    harness.get_by_label("camera1.image — image").click();
    harness.run_steps(2);
    let in_front = harness.state().session.viewers.docked_in_front();
    assert_eq!(in_front, ["camera1.image image", "sine1.out table"]);

    // The border between the two areas dragged down: the top one takes more of the height.
    let table_tab = harness.get_by_label("sine1.out — latest samples").rect();
    let border = Pos2::new(table_tab.center().x + 60.0, table_tab.top() - 1.0);
    drag(&mut harness, border, border + Vec2::new(0.0, 500.0));
    let areas = dock(&mut harness);
    assert!(areas[0].1 > 1.3 && areas[1].1 < 0.7, "{areas:?}");

    // Saved with the diagram, and the same dock in a new studio.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("docked.ron");
    save_as(&mut harness, &path);
    let app = StudioApp::new(
        Document::open(&path).unwrap(),
        library(),
        None,
        "no runtime (test)".to_owned(),
        None,
    );
    let mut reopened = Harness::builder()
        .with_size(Vec2::new(1280.0, 2400.0))
        .build_ui_state(|ui, app: &mut StudioApp| app.show(ui), app);
    reopened.run_steps(2);
    assert_eq!(dock(&mut reopened), areas);

    // A tab's close button closes its viewer; the other tab stays in the area.
    assert_eq!(
        reopened.get_all_by_label("Close").count(),
        3,
        "a close button on each tab"
    );
    let plot_tab = reopened.get_by_label("sine1.out — plot").rect();
    let close = reopened
        .get_all_by_label("Close")
        .map(|node| node.rect().center())
        .find(|at| plot_tab.contains(*at))
        .expect("the plot's tab has a close button");
    reopened.hover_at(close);
    reopened.run_steps(2);
    for pressed in [true, false] {
        reopened.event(egui::Event::PointerButton {
            pos: close,
            button: egui::PointerButton::Primary,
            pressed,
            modifiers: egui::Modifiers::NONE,
        });
        reopened.run_steps(1);
    }
    reopened.run_steps(2);
    assert_eq!(
        outputs(&dock(&mut reopened)),
        owned(&[&["camera1.image"], &["sine1.out"]])
    );
}

#[test]
fn an_unreadable_token_file_is_said_in_the_log_and_the_dialog_stays() {
    let config = tempfile::tempdir().unwrap();
    let mut harness = studio_with(Some(config.path()));
    open_connect_dialog(&mut harness);
    let token_label = "File holding its token (empty when it needs none):";
    harness
        .get_by_role_and_label(Role::TextInput, token_label)
        .focus();
    harness.run_steps(1);
    let missing = config.path().join("no-such.token");
    harness
        .get_by_role_and_label(Role::TextInput, token_label)
        .type_text(missing.to_str().unwrap());
    harness.run_steps(1);
    harness.get_by_label("Connect").click();
    harness.run_steps(2);
    let said: Vec<String> = harness
        .state()
        .session
        .log
        .lines()
        .map(|l| l.text.clone())
        .collect();
    assert!(
        said.iter()
            .any(|l| l.starts_with("cannot read the token file") && l.contains("no-such.token")),
        "{said:?}"
    );
    assert!(!harness.state().is_connected());
    assert!(
        harness.query_by_label("Connect").is_some(),
        "the dialog stays open to correct the file"
    );
    for remembered in ["studio-remote.txt", "studio-remotes.txt"] {
        assert!(!config.path().join(remembered).exists(), "nothing is remembered");
    }
}

#[test]
fn a_runtime_connected_to_before_comes_back_with_its_own_token_file_and_certificate() {
    let config = tempfile::tempdir().unwrap();
    let file = |name: &str| config.path().join(name).to_str().unwrap().to_owned();
    std::fs::write(file("car.token"), "car-token\n").unwrap();
    std::fs::write(file("roadside.token"), "roadside-token\n").unwrap();
    std::fs::write(
        file("studio-remotes.txt"),
        format!(
            "wss://127.0.0.1:9\t{}\t{}\nwss://127.0.0.1:10\t{}\t{}\n",
            file("car.token"),
            file("car.pem"),
            file("roadside.token"),
            file("ca.pem")
        ),
    )
    .unwrap();
    let mut harness = studio_with(Some(config.path()));
    open_connect_dialog(&mut harness);
    // The runtimes connected to before are offered; the other one brings back its own files.
    harness.get_by_label("wss://127.0.0.1:10").click();
    harness.run_steps(2);
    harness.get_by_label("Connect").click();
    harness.run_steps(2);
    let remembered = std::fs::read_to_string(file("studio-remotes.txt")).unwrap();
    assert_eq!(
        remembered.lines().next().unwrap(),
        format!(
            "wss://127.0.0.1:10\t{}\t{}",
            file("roadside.token"),
            file("ca.pem")
        ),
        "the one connected to goes first, with its own certificate: {remembered}"
    );
    assert!(
        remembered.contains(&file("car.pem")),
        "the other keeps its own: {remembered}"
    );
    assert!(!remembered.contains("-token"), "never a token: {remembered}");
}

/// Types `text` into the number field labelled `label` and presses Enter.
fn type_number(harness: &mut Harness<'_, StudioApp>, label: &str, text: &str) {
    harness.get_by_label(label).focus();
    harness.run_steps(2);
    harness.key_press_modifiers(egui::Modifiers::COMMAND, egui::Key::A);
    harness.run_steps(1);
    harness.get_by_label(label).type_text(text);
    harness.run_steps(1);
    harness.key_press(egui::Key::Enter);
    harness.run_steps(2);
}

#[test]
fn a_number_refused_or_clamped_is_said_at_the_field_and_in_the_log() {
    let mut harness = studio();
    add_from_palette(&mut harness, "core.sine", Pos2::new(600.0, 300.0));
    click_on_canvas(&mut harness, "component sine1 (core.sine)");
    // The range and unit are shown beside the field.
    harness.get_by_label("Hz, 0.001 to 100000");
    let rate = |harness: &Harness<'_, StudioApp>| {
        harness
            .state()
            .session
            .document
            .diagram()
            .component("sine1")
            .unwrap()
            .properties
            .get("rate")
            .cloned()
    };

    type_number(&mut harness, "rate", "-5");
    assert_eq!(rate(&harness), Some(kairos_diagram::Value::F64(0.001)));
    let said = "-5 is below the least value, 0.001 Hz: set to 0.001";
    harness.get_by_label(said);
    assert!(
        harness
            .state()
            .session
            .log
            .lines()
            .any(|l| l.text == format!("sine1.rate: {said}"))
    );

    // Undone, the clamped value goes and what the field said with it.
    harness.get_by_label("Edit").click();
    harness.run_steps(2);
    harness.get_by_label("Undo Ctrl+Z").click();
    harness.run_steps(3);
    assert_ne!(rate(&harness), Some(kairos_diagram::Value::F64(0.001)), "undone");
    assert!(harness.query_by_label(said).is_none(), "no stale note after Undo");
    // Redone, the value is back and the field says nothing new: the note was about the typing.
    harness.get_by_label("Edit").click();
    harness.run_steps(2);
    harness.get_by_label("Redo Ctrl+Y").click();
    harness.run_steps(3);
    assert_eq!(rate(&harness), Some(kairos_diagram::Value::F64(0.001)));

    type_number(&mut harness, "rate", "abc");
    assert_eq!(rate(&harness), Some(kairos_diagram::Value::F64(0.001)), "kept");
    harness.get_by_label("\"abc\" is not a number: kept 0.001 Hz");

    // A valid value clears what the field said.
    type_number(&mut harness, "rate", "25");
    assert_eq!(rate(&harness), Some(kairos_diagram::Value::F64(25.0)));
    assert_eq!(
        harness.query_all_by_label_contains("is not a number").count(),
        1,
        "only the log's line is left: {:?}",
        harness
            .state()
            .session
            .log
            .lines()
            .map(|l| l.text.clone())
            .collect::<Vec<_>>()
    );
}

#[test]
fn the_log_panel_is_made_taller_by_dragging_its_edge() {
    let mut harness = studio();
    let tab =
        |harness: &Harness<'_, StudioApp>| harness.get_by_role_and_label(Role::Button, "Log").rect().top();
    let before = tab(&harness);
    // The panel's edge is a few points above its first row.
    let edge = Pos2::new(600.0, before - 8.0);
    drag(&mut harness, edge, edge - Vec2::new(0.0, 200.0));
    let after = tab(&harness);
    assert!(
        before - after > 150.0,
        "the log's tabs moved from {before} to {after}"
    );
}

#[test]
fn a_table_of_long_samples_keeps_the_dock_bounded_and_the_canvas_in_view() {
    let mut harness = studio();
    add_from_palette(&mut harness, "sensors.gnss", Pos2::new(500.0, 300.0));
    let inspector_before = harness.get_by_label("Inspector").rect().left();
    let viewers = &mut harness.state_mut().session.viewers;
    viewers.open_kind("gnss1.fix".to_owned(), ViewerKind::Table);
    let header = kairos_protocol::frame::SampleHeader {
        output: "gnss1.fix".to_owned(),
        data_type: "gnss_fix".to_owned(),
        timestamp_ns: 1,
        time_of_issue_ns: 2,
        sequence: 0,
        skipped: 0,
        value: Some(serde_json::json!({"note": "x".repeat(5000)})),
        image: None,
        intensity: false,
    };
    viewers.receive(&header, &[]);
    harness.run_steps(4);
    let dock_title = harness.get_by_label("gnss1.fix — latest samples").rect();
    let float = harness.get_by_label("Float").rect();
    let inspector_after = harness.get_by_label("Inspector").rect().left();
    assert!(
        (inspector_after - inspector_before).abs() < 0.5,
        "the inspector keeps its place: {inspector_before} then {inspector_after}"
    );
    assert!(
        float.right() <= inspector_before,
        "the dock ends before the inspector: {float:?}"
    );
    let dock_width = float.right() - dock_title.left();
    assert!(dock_width <= 900.0, "the dock is {dock_width} wide");
    // The canvas keeps room between the palette and the dock, and its node is drawn there.
    let node = on_canvas(&harness, "component gnss1 (sensors.gnss)");
    assert!(
        node.x < dock_title.left(),
        "{node:?} is under the dock at {dock_title:?}"
    );
}

#[test]
fn an_empty_canvas_opens_at_full_size_so_the_first_node_reads_as_the_palette_does() {
    let mut harness = studio();
    assert!(
        (harness.state().canvas.zoom() - 1.0).abs() < 1e-3,
        "an empty canvas opened at zoom {}",
        harness.state().canvas.zoom()
    );
    add_from_palette(&mut harness, "core.sine", Pos2::new(500.0, 300.0));
    assert!((harness.state().canvas.zoom() - 1.0).abs() < 1e-3);
}

#[test]
fn docking_a_viewer_keeps_the_canvas_zoom() {
    let mut harness = studio();
    add_from_palette(&mut harness, "core.sine", Pos2::new(500.0, 300.0));
    harness.run_steps(4);
    let before = harness.state().canvas.zoom();
    harness
        .state_mut()
        .session
        .viewers
        .open("sine1.out".to_owned(), "f64");
    harness.run_steps(4);
    let after = harness.state().canvas.zoom();
    assert!(
        (after - before).abs() < 1e-3,
        "the zoom went from {before} to {after} when the dock opened"
    );
}

#[test]
fn components_pushed_out_of_sight_by_a_dock_are_counted_in_the_canvas_corner() {
    let mut harness = studio();
    add_from_palette(&mut harness, "core.sine", Pos2::new(400.0, 300.0));
    add_from_palette(&mut harness, "core.counter", Pos2::new(850.0, 300.0));
    harness.run_steps(4);
    assert_eq!(harness.state().canvas.outside_view(), 0, "both in view");
    harness
        .state_mut()
        .session
        .viewers
        .open("sine1.out".to_owned(), "f64");
    harness.run_steps(4);
    // The dock takes the right of the canvas at the same zoom: the counter is out of sight, and said so.
    assert_eq!(harness.state().canvas.outside_view(), 1);
}

#[test]
fn the_view_menu_zooms_in_fine_steps_and_fits_the_diagram() {
    let mut harness = studio();
    add_from_palette(&mut harness, "core.sine", Pos2::new(500.0, 300.0));
    harness.run_steps(4);
    let zoom = |harness: &Harness<'_, StudioApp>| harness.state().canvas.zoom();
    let before = zoom(&harness);
    harness.get_by_label("View").click();
    harness.run_steps(2);
    // Each entry shows its shortcut.
    harness.get_by_label("Zoom in Ctrl+=").click();
    harness.run_steps(2);
    let zoomed = zoom(&harness);
    assert!(
        (zoomed / before - 1.1).abs() < 0.01,
        "one step is 10 %: {before} to {zoomed}"
    );
    harness.get_by_label("View").click();
    harness.run_steps(2);
    harness.get_by_label("Fit the diagram Ctrl+0").click();
    harness.run_steps(4);
    let fitted = zoom(&harness);
    assert!(fitted > zoomed, "a lone node fitted fills the canvas: {fitted}");
    // The Edit menu copies, pastes and duplicates.
    harness.get_by_label("Edit").click();
    harness.run_steps(2);
    for entry in ["Copy Ctrl+C", "Paste Ctrl+V", "Duplicate Ctrl+D"] {
        harness.get_by_label(entry);
    }
}

#[test]
fn an_empty_canvas_says_what_to_do_and_opens_an_example() {
    let mut harness = studio();
    harness.get_by_label("An empty diagram");
    harness.get_by_label("Open an example").click();
    harness.run_steps(2);
    // Each example with its description, one button for both.
    harness
        .get_by_label_contains("Hello, Kairos: a sine wave, amplified, printed on the console.")
        .click();
    harness.run_steps(3);
    let ids: Vec<String> = harness
        .state()
        .session
        .document
        .diagram()
        .components
        .iter()
        .map(|c| c.id.clone())
        .collect();
    assert_eq!(ids.len(), 3, "hello.ron is open: {ids:?}");
    assert!(harness.query_by_label("An empty diagram").is_none());

    // The showcases in subfolders are offered too, under their folder's name.
    harness.get_by_label("File").click();
    harness.run_steps(2);
    harness.get_by_label("New Ctrl+N").click();
    harness.run_steps(3);
    harness.get_by_label("Open an example").click();
    harness.run_steps(2);
    harness.get_by_label("vision/");
    // Below the fold of the menu's list: scrolled to, as a user would.
    harness
        .get_by_label_contains("Lane markings on the simulated camera")
        .scroll_to_me();
    harness.run_steps(3);
    harness
        .get_by_label_contains("Lane markings on the simulated camera")
        .click();
    harness.run_steps(3);
    let path = harness
        .state()
        .session
        .document
        .path()
        .map(std::path::Path::to_path_buf);
    assert!(
        path.as_ref().is_some_and(|p| p.ends_with("vision/lanes.ron")),
        "{path:?}"
    );
}

#[test]
fn a_component_is_renamed_in_the_inspector_and_its_connections_follow() {
    let mut harness = studio();
    add_from_palette(&mut harness, "core.sine", Pos2::new(450.0, 250.0));
    add_from_palette(&mut harness, "core.console", Pos2::new(800.0, 250.0));
    let from = on_canvas(&harness, "output sine1.out (f64)");
    let to = on_canvas(&harness, "input console1.in (any)");
    drag(&mut harness, from, to);
    click_on_canvas(&mut harness, "component sine1 (core.sine)");
    let rename = |harness: &mut Harness<'_, StudioApp>, name: &str| {
        harness.get_by_role_and_label(Role::TextInput, "name").focus();
        harness.run_steps(1);
        harness.key_press_modifiers(egui::Modifiers::COMMAND, egui::Key::A);
        harness.run_steps(1);
        harness
            .get_by_role_and_label(Role::TextInput, "name")
            .type_text(name);
        harness.run_steps(1);
        harness.key_press(egui::Key::Enter);
        harness.run_steps(2);
    };
    rename(&mut harness, "wave");
    let diagram = harness.state().session.document.diagram().clone();
    assert!(diagram.component("wave").is_some() && diagram.component("sine1").is_none());
    assert_eq!(diagram.connections[0].from, PortRef::new("wave", "out"));
    // A name another component has is refused, said at the field.
    rename(&mut harness, "console1");
    assert!(
        harness
            .state()
            .session
            .document
            .diagram()
            .component("wave")
            .is_some()
    );
    harness.get_by_label("there is already a component named console1: choose another name");
    // So is a name that is no id, and the log says it too.
    rename(&mut harness, "my wave");
    let refusal = "\"my wave\" cannot name a component: use letters, digits, _ and - (for example wave_2)";
    harness.get_by_label(refusal);
    assert!(
        harness
            .state()
            .session
            .log
            .lines()
            .any(|l| l.text.ends_with(refusal)),
        "said in the log"
    );
    assert!(
        harness
            .state()
            .session
            .document
            .diagram()
            .component("wave")
            .is_some()
    );
    // One undo takes the rename back.
    harness.state_mut().session.document.undo();
    assert!(
        harness
            .state()
            .session
            .document
            .diagram()
            .component("sine1")
            .is_some()
    );
}

#[test]
fn the_palette_shows_readable_names_without_doubled_headers_and_searches() {
    let mut harness = studio();
    // Readable names, each group once, its pack said only when it differs from the category.
    for label in [
        "Sine wave",
        "Moving average",
        "Simulated lidar",
        "Sensors",
        "Generators (core)",
    ] {
        harness.get_by_label(label);
    }
    assert!(harness.query_by_label("Sensors (sensors)").is_none());
    let search = |harness: &mut Harness<'_, StudioApp>, text: &str| {
        let field = harness.get_by_role(Role::TextInput);
        field.focus();
        harness.run_steps(1);
        harness.key_press_modifiers(egui::Modifiers::COMMAND, egui::Key::A);
        harness.get_by_role(Role::TextInput).type_text(text);
        harness.run_steps(2);
    };
    // A name, an id, a description.
    search(&mut harness, "moving");
    harness.get_by_label("Moving average");
    assert!(harness.query_by_label("Sine wave").is_none());
    search(&mut harness, "core.sine");
    harness.get_by_label("Sine wave");
    search(&mut harness, "mcap");
    harness.get_by_label("MCAP recorder");
    assert!(
        harness.query_by_label("Viewer").is_none(),
        "the viewer answers its own words only"
    );
    search(&mut harness, "viewer");
    harness.get_by_label("Viewer");
    assert!(harness.query_by_label("Sine wave").is_none());

    // The palette keeps its width whatever the results: the canvas beside it does not move.
    let palette_width =
        |harness: &Harness<'_, StudioApp>| harness.get_by_role(Role::TextInput).rect().width();
    search(&mut harness, "");
    let full = palette_width(&harness);
    for text in ["gain", "socketcan", "wgs84", "zzz"] {
        search(&mut harness, text);
        let width = palette_width(&harness);
        assert!(
            (width - full).abs() < 0.01,
            "searching {text}: {width} then {full}"
        );
    }
}

#[test]
fn what_a_console_prints_is_in_the_console_tab_with_its_component_and_time() {
    let mut harness = studio();
    add_from_palette(&mut harness, "core.console", Pos2::new(600.0, 300.0));
    let printed = |at_ns: i64, message: &str| {
        kairos_studio::client::ClientEvent::Log(kairos_protocol::LogRecord {
            at_ns,
            level: kairos_protocol::LogLevel::Info,
            component: Some("console1".to_owned()),
            message: message.to_owned(),
        })
    };
    harness.state_mut().session.handle(printed(
        1_795_557_290_476_402_148,
        "console1: t=1 seq=0 latency=3.0µs 0.5",
    ));
    harness.run_steps(1);
    harness.get_by_label("Console output").click();
    harness.run_steps(2);
    harness.get_by_label("t=1 seq=0 latency=3.0µs 0.5");
    harness.get_by_label("21:54:50.476");
    assert!(harness.get_all_by_label("console1").count() >= 1);
}

#[test]
fn a_selection_is_put_in_an_execution_group_from_the_inspector_and_the_diagram_made_sequential() {
    let mut harness = studio();
    add_from_palette(&mut harness, "core.sine", Pos2::new(450.0, 250.0));
    add_from_palette(&mut harness, "core.gain", Pos2::new(800.0, 250.0));
    let group_of = |harness: &Harness<'_, StudioApp>, id: &str| {
        harness
            .state()
            .session
            .document
            .diagram()
            .component(id)
            .unwrap()
            .group
            .clone()
    };
    // Both selected: one name puts them in one group, one undoable edit.
    click_on_canvas(&mut harness, "component sine1 (core.sine)");
    harness.state_mut().canvas.selected.insert("gain1".to_owned());
    harness.run_steps(1);
    harness.get_by_label("Execution").click();
    harness.run_steps(1);
    harness
        .get_by_role_and_label(Role::TextInput, "new group")
        .focus();
    harness.run_steps(1);
    harness
        .get_by_role_and_label(Role::TextInput, "new group")
        .type_text("chain");
    harness.run_steps(1);
    harness.get_by_label("Put in it").click();
    harness.run_steps(2);
    assert_eq!(group_of(&harness, "sine1").as_deref(), Some("chain"));
    assert_eq!(group_of(&harness, "gain1").as_deref(), Some("chain"));
    harness.state_mut().session.document.undo();
    harness.run_steps(1);
    assert_eq!(group_of(&harness, "sine1"), None, "one undo takes both back");
    assert_eq!(group_of(&harness, "gain1"), None);

    // The diagram-wide switch, beside the selection's execution.
    harness.get_by_label("Sequential (the whole diagram)").click();
    harness.run_steps(2);
    assert!(harness.state().session.document.diagram().sequential);
    assert!(harness.state().session.document.is_dirty());
}

#[test]
fn a_double_click_goes_inside_a_subgraph_and_the_breadcrumb_comes_back_out() {
    let dir = tempfile::tempdir().unwrap();
    let examples = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/subgraph");
    for file in ["two_cameras.ron", "lane_pipeline.ron"] {
        std::fs::copy(examples.join(file), dir.path().join(file)).unwrap();
    }
    let outer = dir.path().join("two_cameras.ron");
    let mut harness = studio_on_at_desktop_pace(&outer, Vec2::new(1280.0, 2400.0));
    harness.run_steps(3);
    // Described from its file: the instance has the ports its file exposes.
    assert!(harness.query_by_label("output front.out (image)").is_some());

    let at = on_canvas(&harness, "component front (lane_pipeline.ron)");
    harness.hover_at(at);
    harness.run_steps(1);
    for pressed in [true, false, true, false] {
        harness.event(egui::Event::PointerButton {
            pos: at,
            button: egui::PointerButton::Primary,
            pressed,
            modifiers: egui::Modifiers::NONE,
        });
    }
    harness.run_steps(3);
    let inside = harness
        .state()
        .session
        .document
        .path()
        .map(std::path::Path::to_owned);
    assert_eq!(inside, Some(dir.path().join("lane_pipeline.ron")));
    assert!(
        harness
            .state()
            .session
            .document
            .diagram()
            .component("edges")
            .is_some()
    );

    // The breadcrumb names the diagram it was entered from; a click goes back there.
    harness.get_by_label("two_cameras.ron").click();
    harness.run_steps(3);
    assert_eq!(harness.state().session.document.path(), Some(outer.as_path()));
    assert!(
        harness.query_by_label("two_cameras.ron").is_none(),
        "no breadcrumb at the top"
    );
}

#[test]
fn selected_components_made_into_a_subgraph_are_one_instance_wired_as_they_were_and_one_undo() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("chain.ron");
    std::fs::write(
        &path,
        r#"Diagram(format: 1,
    packs: [Pack(name: "core", version: "^0.1")],
    components: [
        Component(id: "sine1", type: "core.sine", position: (x: 40.0, y: 40.0)),
        Component(id: "gain1", type: "core.gain", position: (x: 300.0, y: 40.0), properties: {"gain": 2.0}),
        Component(id: "gain2", type: "core.gain", position: (x: 560.0, y: 40.0)),
        Component(id: "console1", type: "core.console", position: (x: 820.0, y: 40.0)),
    ],
    connections: [
        Connection(from: "sine1.out", to: "gain1.in"),
        Connection(from: "gain1.out", to: "gain2.in"),
        Connection(from: "gain2.out", to: "console1.in"),
    ],
)"#,
    )
    .unwrap();
    let mut harness = studio_on(&path, Vec2::new(1280.0, 2400.0));
    harness.run_steps(2);
    harness.state_mut().canvas.selected = ["gain1", "gain2"].map(str::to_owned).into();
    harness.get_by_label("Edit").click();
    harness.run_steps(2);
    harness.get_by_label_contains("Make a subgraph").click();
    harness.run_steps(2);
    harness.get_by_role_and_label(Role::TextInput, "File:").focus();
    harness.run_steps(1);
    harness.key_press_modifiers(egui::Modifiers::COMMAND, egui::Key::A);
    harness
        .get_by_role_and_label(Role::TextInput, "File:")
        .type_text("amplifier");
    harness.run_steps(1);
    harness.get_by_label("Write").click();
    harness.run_steps(3);

    // The file: the two gains, the link between them, what they expose.
    let written = kairos_diagram::load(&dir.path().join("amplifier.ron"))
        .unwrap()
        .1
        .diagram;
    let ids: Vec<&str> = written.components.iter().map(|c| c.id.as_str()).collect();
    assert_eq!(ids, ["gain1", "gain2"]);
    assert_eq!(
        written.exposes.as_ref().unwrap().inputs["in"],
        [PortRef::new("gain1", "in")]
    );
    // The diagram: one instance in their place, wired through its ports, which the canvas shows.
    let diagram = harness.state().session.document.diagram().clone();
    assert_eq!(
        diagram.component("amplifier1").unwrap().type_name,
        "amplifier.ron"
    );
    let links: Vec<String> = diagram
        .connections
        .iter()
        .map(|c| format!("{} -> {}", c.from, c.to))
        .collect();
    assert_eq!(
        links,
        ["sine1.out -> amplifier1.in", "amplifier1.out -> console1.in"]
    );
    harness.run_steps(2);
    assert!(harness.query_by_label("output amplifier1.out (f64)").is_some());
    assert!(harness.state().session.document.is_dirty());

    // One undo puts the components back; the file stays.
    harness.key_press_modifiers(egui::Modifiers::COMMAND, egui::Key::Z);
    harness.run_steps(2);
    let back = harness.state().session.document.diagram();
    assert!(back.component("gain1").is_some() && back.component("amplifier1").is_none());
    assert!(dir.path().join("amplifier.ron").is_file());
}

#[test]
fn ports_and_properties_are_exposed_from_the_canvas_and_inspector_renamed_joined_and_followed() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("pair.ron");
    std::fs::write(
        &path,
        r#"Diagram(format: 1,
    packs: [Pack(name: "core", version: "^0.1")],
    components: [
        Component(id: "left", type: "core.gain", position: (x: 40.0, y: 40.0)),
        Component(id: "right", type: "core.gain", position: (x: 40.0, y: 240.0)),
    ],
    connections: [],
)"#,
    )
    .unwrap();
    let mut harness = studio_on(&path, Vec2::new(1280.0, 1400.0));
    harness.run_steps(2);
    let exposes = |harness: &Harness<'_, StudioApp>| {
        harness
            .state()
            .session
            .document
            .diagram()
            .exposes
            .clone()
            .unwrap_or_default()
    };

    // From the canvas: both outputs, the second under a name of its own.
    context_menu_entry(
        &mut harness,
        "output left.out (f64)",
        "Expose as the subgraph's output",
    );
    context_menu_entry(
        &mut harness,
        "output right.out (f64)",
        "Expose as the subgraph's output",
    );
    assert_eq!(exposes(&harness).outputs["out"], PortRef::new("left", "out"));
    assert_eq!(
        exposes(&harness).outputs["right_out"],
        PortRef::new("right", "out")
    );
    context_menu_entry(
        &mut harness,
        "input left.in (f64 | i64 | bool)",
        "Expose as the subgraph's input",
    );
    assert_eq!(exposes(&harness).inputs["in"], [PortRef::new("left", "in")]);

    // From the inspector: both gains exposed, then given one name, which sets them together.
    for id in ["left", "right"] {
        click_on_canvas(&mut harness, &format!("component {id} (core.gain)"));
        if harness.query_by_label("property gain").is_none() {
            harness.get_by_label("Exposed as a subgraph").click();
            harness.run_steps(1);
        }
        harness.get_by_label("property gain").click();
        harness.run_steps(2);
    }
    assert_eq!(
        exposes(&harness).properties["gain"],
        [PortRef::new("left", "gain")]
    );
    assert_eq!(
        exposes(&harness).properties["right_gain"],
        [PortRef::new("right", "gain")]
    );
    harness
        .get_by_role_and_label(Role::TextInput, "property gain")
        .focus();
    harness.run_steps(1);
    harness.key_press_modifiers(egui::Modifiers::COMMAND, egui::Key::A);
    harness.run_steps(1);
    harness
        .get_by_role_and_label(Role::TextInput, "property gain")
        .type_text("gain");
    harness.run_steps(1);
    harness.key_press(egui::Key::Enter);
    harness.run_steps(2);
    assert_eq!(
        exposes(&harness).properties["gain"],
        [PortRef::new("left", "gain"), PortRef::new("right", "gain")]
    );
    assert!(!exposes(&harness).properties.contains_key("right_gain"));

    // A name another output has is refused at its field (right is selected), and nothing changes.
    harness.state_mut().session.set_exposed(
        kairos_diagram::ExposedKind::Output,
        &PortRef::new("right", "out"),
        Some("out"),
    );
    harness.run_steps(2);
    assert_eq!(
        harness
            .query_all_by_label_contains("already shows left.out")
            .count(),
        2,
        "said at the field and in the log"
    );
    assert_eq!(
        exposes(&harness).outputs["right_out"],
        PortRef::new("right", "out")
    );

    // A renamed component's exposures follow it, and the saved file is a subgraph that loads.
    harness.state_mut().session.rename_component("right", "second");
    harness.run_steps(1);
    assert_eq!(
        exposes(&harness).outputs["right_out"],
        PortRef::new("second", "out")
    );
    harness.state_mut().session.document.save().unwrap();
    let saved = kairos_diagram::load(&path).unwrap().1.diagram;
    assert_eq!(saved.exposes.as_ref(), Some(&exposes(&harness)));

    // Nothing selected: the overview lists every exposure; its remove stops one.
    harness.state_mut().canvas.selected.clear();
    harness.run_steps(2);
    // Inputs come first.
    harness.get_all_by_label("remove").next().unwrap().click();
    harness.run_steps(2);
    assert!(exposes(&harness).inputs.is_empty());
    // And the canvas's menu says what an exposed port is exposed as, and takes it back.
    context_menu_entry(&mut harness, "output left.out (f64)", "Stop exposing (as 'out')");
    assert!(!exposes(&harness).outputs.contains_key("out"));
}

#[test]
fn a_subgraph_file_edited_elsewhere_shows_its_new_ports_on_its_instances() {
    let dir = tempfile::tempdir().unwrap();
    let examples = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/subgraph");
    for file in ["two_cameras.ron", "lane_pipeline.ron"] {
        std::fs::copy(examples.join(file), dir.path().join(file)).unwrap();
    }
    let mut harness = studio_on(&dir.path().join("two_cameras.ron"), Vec2::new(1280.0, 1400.0));
    harness.run_steps(2);
    assert!(harness.query_by_label("output front.out (image)").is_some());

    // Another editor renames the exposed output.
    let inner = dir.path().join("lane_pipeline.ron");
    let text = std::fs::read_to_string(&inner).unwrap();
    std::thread::sleep(std::time::Duration::from_millis(20));
    std::fs::write(
        &inner,
        text.replace(r#""out": "overlay.out""#, r#""annotated": "overlay.out""#),
    )
    .unwrap();
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
    while harness.query_by_label("output front.annotated (image)").is_none() {
        assert!(std::time::Instant::now() < deadline, "the edit was never seen");
        std::thread::sleep(std::time::Duration::from_millis(100));
        harness.run_steps(1);
    }
    assert!(harness.query_by_label("output rear.annotated (image)").is_some());
    assert!(harness.query_by_label("output front.out (image)").is_none());
}

/// A file dropped from the desktop, as the window hands it over.
#[derive(Debug)]
struct Dropped(std::path::PathBuf);

impl egui::DroppedFile for Dropped {
    fn path(&self) -> &std::path::Path {
        &self.0
    }

    fn bytes(&self) -> Result<Vec<u8>, String> {
        std::fs::read(&self.0).map_err(|e| e.to_string())
    }
}

fn drop_file(harness: &mut Harness<'_, StudioApp>, path: &std::path::Path) {
    harness
        .input_mut()
        .dropped_files
        .push(std::sync::Arc::new(Dropped(path.to_owned())));
    harness.run_steps(2);
}

#[test]
fn a_recording_dropped_on_the_canvas_becomes_a_player_on_it_and_a_diagram_opens() {
    let dir = tempfile::tempdir().unwrap();
    let mut harness = studio();
    // A rosbag2 folder (its metadata.yaml beside its MCAP file) and an MCAP file.
    let bag = dir.path().join("drive_bag");
    std::fs::create_dir(&bag).unwrap();
    std::fs::write(bag.join("metadata.yaml"), "rosbag2_bagfile_information: {}\n").unwrap();
    drop_file(&mut harness, &bag);
    let file = dir.path().join("drive.mcap");
    std::fs::write(&file, b"").unwrap();
    drop_file(&mut harness, &file);
    let players: Vec<(String, String)> = harness
        .state()
        .session
        .document
        .diagram()
        .components
        .iter()
        .filter(|c| c.type_name == "recording.player")
        .map(|c| (c.id.clone(), c.properties["path"].as_text().unwrap().to_owned()))
        .collect();
    assert_eq!(
        players,
        [
            ("player1".to_owned(), bag.display().to_string()),
            ("player2".to_owned(), file.display().to_string())
        ]
    );
    // Placed and pointed at its file in one step: one undo takes the last player away whole.
    harness.state_mut().session.document.undo();
    assert_eq!(harness.state().session.document.diagram().components.len(), 1);

    // Something else is said, not taken.
    drop_file(&mut harness, &dir.path().join("notes.txt"));
    assert!(harness.query_by_label_contains("notes.txt was dropped").is_some());

    // A diagram opens (the unsaved players are asked about first).
    let diagram = dir.path().join("other.ron");
    std::fs::copy(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/hello.ron"),
        &diagram,
    )
    .unwrap();
    drop_file(&mut harness, &diagram);
    harness.get_by_label("Discard").click();
    harness.run_steps(3);
    assert_eq!(harness.state().session.document.path(), Some(diagram.as_path()));
}
