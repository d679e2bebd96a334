//! The menu bar (File, Edit, the run controls, the connection's state) and the keyboard shortcuts. Both
//! only push [`Command`]s.

use std::path::PathBuf;

use egui::{Color32, RichText};
use kairos_protocol::{ClockState, RequestBody, RuntimeState};

use crate::commands::Command;
use crate::session::Session;

/// What the menus need to know beyond the session.
#[derive(Debug, Clone, Copy)]
pub struct MenuContext<'a> {
    /// The recent files, the latest first.
    pub recent: &'a [PathBuf],
    /// Whether the studio started a local runtime it can go back to.
    pub has_local_runtime: bool,
}

/// The menu bar.
pub fn menu_bar_ui(
    ui: &mut egui::Ui,
    session: &Session,
    menus: MenuContext<'_>,
    commands: &mut Vec<Command>,
) {
    egui::MenuBar::new().ui(ui, |ui| {
        ui.menu_button("File", |ui| file_menu_ui(ui, menus, commands));
        ui.menu_button("Edit", |ui| {
            menu_items(
                ui,
                commands,
                [
                    ("Undo", "Ctrl+Z", Command::Undo),
                    ("Redo", "Ctrl+Y", Command::Redo),
                    ("Copy", "Ctrl+C", Command::Copy),
                    ("Paste", "Ctrl+V", Command::Paste),
                    ("Duplicate", "Ctrl+D", Command::Duplicate),
                    ("Delete", "Del", Command::Delete),
                    ("Tidy the layout", "", Command::TidyLayout),
                    ("Make a subgraph…", "", Command::MakeSubgraphDialog),
                ],
            );
        });
        ui.menu_button("View", |ui| {
            menu_items(
                ui,
                commands,
                [
                    ("Fit the diagram", "Ctrl+0", Command::FitDiagram),
                    ("Zoom in", "Ctrl+=", Command::Zoom(ZOOM_STEP)),
                    ("Zoom out", "Ctrl+-", Command::Zoom(1.0 / ZOOM_STEP)),
                ],
            );
        });
        ui.separator();
        run_controls_ui(ui, session.run_state(), commands);
        if let Some(refusal) = session.unlocked_refusal() {
            start_anyway_ui(ui, refusal, commands);
        }
        ui.separator();
        connection_state_ui(ui, session);
        if !session.document.diagram().hosts.is_empty() {
            lock_bound_ui(ui, session.lock_bound(), commands);
        }
    });
}

/// One zoom step of the keyboard and the View menu: fine enough to land on a readable size.
pub const ZOOM_STEP: f32 = 1.1;

/// Menu entries, each with its shortcut shown beside it.
fn menu_items<const N: usize>(
    ui: &mut egui::Ui,
    commands: &mut Vec<Command>,
    items: [(&str, &str, Command); N],
) {
    for (label, shortcut, command) in items {
        if ui.add(egui::Button::new(label).shortcut_text(shortcut)).clicked() {
            commands.push(command);
            ui.close();
        }
    }
}

fn file_menu_ui(ui: &mut egui::Ui, menus: MenuContext<'_>, commands: &mut Vec<Command>) {
    menu_items(
        ui,
        commands,
        [
            ("New", "Ctrl+N", Command::NewDiagram),
            ("Open…", "Ctrl+O", Command::OpenDiagram),
            ("Save", "Ctrl+S", Command::Save),
            ("Save as…", "Ctrl+Shift+S", Command::SaveAs),
        ],
    );
    ui.menu_button("Recent", |ui| {
        for path in menus.recent {
            if ui.button(path.display().to_string()).clicked() {
                commands.push(Command::OpenFile(path.clone()));
            }
        }
    });
    ui.separator();
    if ui
        .button("New component…")
        .on_hover_text("Generate a component, build its pack and load it into the local runtime")
        .clicked()
    {
        commands.push(Command::NewComponentDialog);
    }
    ui.separator();
    if ui.button("Connect to a runtime…").clicked() {
        commands.push(Command::ConnectDialog);
    }
    if menus.has_local_runtime && ui.button("Use the local runtime").clicked() {
        commands.push(Command::UseLocalRuntime);
    }
    ui.separator();
    menu_items(ui, commands, [("Quit", "Ctrl+Q", Command::Quit)]);
}

/// Run, Pause, Resume and Stop, each enabled when the runtime's state allows it.
pub fn run_controls_ui(ui: &mut egui::Ui, state: RuntimeState, commands: &mut Vec<Command>) {
    let running = state == RuntimeState::Running;
    let paused = state == RuntimeState::Paused;
    if ui
        .button("Run")
        .on_hover_text("Deploy this diagram to the runtime and start it")
        .clicked()
    {
        commands.push(Command::Run);
    }
    for (label, enabled, request) in [
        ("Pause", running, RequestBody::Pause),
        ("Resume", paused, RequestBody::Resume),
        ("Stop", running || paused, RequestBody::Stop { at_ns: None }),
    ] {
        if ui.add_enabled(enabled, egui::Button::new(label)).clicked() {
            commands.push(Command::Request(request));
        }
    }
}

/// The lock bound a start over hosts asks for, in milliseconds, shown while the diagram has hosts.
fn lock_bound_ui(ui: &mut egui::Ui, bound: Option<std::time::Duration>, commands: &mut Vec<Command>) {
    let mut ms = bound.map_or(1.0, |b| b.as_secs_f64() * 1e3);
    let field = egui::DragValue::new(&mut ms)
        .range(0.001..=10_000.0)
        .speed(0.01)
        .max_decimals(3)
        .prefix("lock bound ")
        .suffix(" ms");
    let changed = ui
        .add(field)
        .on_hover_text(
            "How close to its clock master every host's clock must be for Run to start the diagram over its \
             hosts (1 ms unless set). A host's clock shows \"locked\" once its last error is under 10 ms; \
             a start also needs it within this bound. Drag or type to change it.",
        )
        .changed();
    if changed {
        commands.push(Command::SetLockBound(std::time::Duration::from_secs_f64(
            ms * 1e-3,
        )));
    }
}

/// After a start refused for hosts' clocks not locked: the way to start regardless.
fn start_anyway_ui(ui: &mut egui::Ui, refusal: &str, commands: &mut Vec<Command>) {
    let button = egui::Button::new(RichText::new("Start anyway").color(Color32::from_rgb(0xff, 0xb0, 0x40)));
    if ui
        .add(button)
        .on_hover_text(format!(
            "{refusal}\n\nStarts now although those clocks are not locked: their samples' times may be off by \
             the error shown, and every recording this start begins says so. Or raise the lock bound beside \
             the clock and Run again."
        ))
        .clicked()
    {
        commands.push(Command::StartUnlocked);
    }
}

/// Whom the studio drives, whether it is connected, and the runtime's state.
fn connection_state_ui(ui: &mut egui::Ui, session: &Session) {
    let (text, color) = match session.runtime() {
        None => ("no runtime: editing only".to_owned(), Color32::GRAY),
        Some(runtime) if runtime.connected => {
            (format!("connected to {}", runtime.label), Color32::LIGHT_GREEN)
        }
        Some(runtime) => (format!("not connected to {}", runtime.label), Color32::LIGHT_RED),
    };
    ui.label(RichText::new(text).color(color));
    ui.label(format!("— {:?}", session.run_state()).to_lowercase());
    if let Some(clock) = session.clock() {
        let color = clock_color(clock.state);
        // The bound the master gives (half an exchange's round trip) where there is one.
        let within = clock.error_bound_ns.map_or_else(String::new, |bound| {
            format!(" ±{:.1} µs", bound.unsigned_abs() as f64 * 1e-3)
        });
        ui.label(RichText::new(format!("clock: {} {}{within}", clock.source, clock.state)).color(color))
            .on_hover_text(format!(
                "The runtime clock follows '{}': error {} at the last reference, set {:+.3} s from the \
                 machine's clock at start, {} references",
                clock.source,
                kairos_protocol::error_ms(clock.error_ns),
                clock.step_ns as f64 * 1e-9,
                clock.references
            ));
    }
    for host in session.hosts() {
        let (text, color) = host_words(host);
        ui.label(RichText::new(text).color(color));
    }
}

/// A clock state's colour: green when it agrees with its reference, red when lost or in alarm, yellow on
/// the way.
fn clock_color(state: ClockState) -> Color32 {
    match state {
        ClockState::Locked | ClockState::Master => Color32::LIGHT_GREEN,
        ClockState::Lost | ClockState::Alarm => Color32::LIGHT_RED,
        ClockState::Acquiring | ClockState::Slewing | ClockState::Holdover | ClockState::Unknown => {
            Color32::YELLOW
        }
    }
}

/// A host of a spread diagram in the top bar: `car: locked ±4.2 µs`, `car: lost`.
fn host_words(host: &kairos_protocol::HostTelemetry) -> (String, Color32) {
    let name = &host.name;
    if !host.answering {
        return (format!("{name}: lost"), Color32::LIGHT_RED);
    }
    let Some(clock) = &host.clock else {
        return (format!("{name}: own clock"), Color32::GRAY);
    };
    let color = clock_color(clock.state);
    let error_ns = clock.error_bound_ns.unwrap_or(clock.error_ns);
    // A master has no error, and a clock still acquiring has no measurement to show yet.
    let within = if clock.state.has_error() {
        format!(" ±{:.1} µs", error_ns.unsigned_abs() as f64 * 1e-3)
    } else {
        String::new()
    };
    (format!("{name}: {}{within}", clock.state), color)
}

/// The keyboard shortcuts; Save works while typing, the others only when no text field has the keyboard.
pub fn shortcuts(ctx: &egui::Context, commands: &mut Vec<Command>) {
    use egui::{Key, KeyboardShortcut, Modifiers};
    let typing = ctx.egui_wants_keyboard_input();
    let pressed =
        |modifiers, key| ctx.input_mut(|i| i.consume_shortcut(&KeyboardShortcut::new(modifiers, key)));
    if pressed(Modifiers::COMMAND | Modifiers::SHIFT, Key::S) {
        commands.push(Command::SaveAs);
    }
    if pressed(Modifiers::COMMAND, Key::S) {
        commands.push(Command::Save);
    }
    if pressed(Modifiers::COMMAND, Key::O) {
        commands.push(Command::OpenDiagram);
    }
    if pressed(Modifiers::COMMAND, Key::N) {
        commands.push(Command::NewDiagram);
    }
    if pressed(Modifiers::COMMAND, Key::Q) {
        commands.push(Command::Quit);
    }
    if typing {
        return;
    }
    if pressed(Modifiers::COMMAND, Key::Num0) {
        commands.push(Command::FitDiagram);
    }
    if pressed(Modifiers::COMMAND, Key::Equals) || pressed(Modifiers::COMMAND, Key::Plus) {
        commands.push(Command::Zoom(ZOOM_STEP));
    }
    if pressed(Modifiers::COMMAND, Key::Minus) {
        commands.push(Command::Zoom(1.0 / ZOOM_STEP));
    }
    if pressed(Modifiers::COMMAND | Modifiers::SHIFT, Key::Z) || pressed(Modifiers::COMMAND, Key::Y) {
        commands.push(Command::Redo);
    }
    if pressed(Modifiers::COMMAND, Key::Z) {
        commands.push(Command::Undo);
    }
    if pressed(Modifiers::COMMAND, Key::C) {
        commands.push(Command::Copy);
    }
    if pressed(Modifiers::COMMAND, Key::V) {
        commands.push(Command::Paste);
    }
    if pressed(Modifiers::COMMAND, Key::D) {
        commands.push(Command::Duplicate);
    }
    if pressed(Modifiers::NONE, Key::Delete) || pressed(Modifiers::NONE, Key::Backspace) {
        commands.push(Command::Delete);
    }
}
