//! The studio window: it owns the [`Session`] (the state, which knows no window), the [`Canvas`], the
//! connection to the runtime and the dialogs, lays the panels out each frame, and carries out the
//! [`Command`]s the panels push once they are drawn.

use std::path::PathBuf;

use kairos_diagram::{ComponentInstance, LibraryInfo, Value};
use kairos_protocol::{LogLevel, RequestBody};

use crate::canvas::{Canvas, auto_layout, lay_out_if_stacked};
use crate::chooser::{self, Choice, FileChooser, Purpose};
use crate::client::RuntimeClient;
use crate::commands::{AfterDiscard, Command};
use crate::connection::Connection;
use crate::document::Document;
use crate::log_panel::{BottomPanel, bottom_panel_ui};
use crate::menus::{MenuContext, menu_bar_ui, shortcuts};
use crate::session::{Saved, Session};
use crate::settings::{RemoteAddress, Settings};
use crate::transport::Transport;

/// The dialogs, each while it is open.
#[derive(Debug, Default)]
struct Dialogs {
    /// The file chooser.
    chooser: Option<FileChooser>,
    /// The question about unsaved changes, and what to do after it.
    unsaved: Option<AfterDiscard>,
    /// The connect dialog.
    connect: Option<crate::dialogs::ConnectDialog>,
    /// The "New component…" dialog.
    new_component: Option<crate::wizard::NewComponentDialog>,
}

/// The studio.
#[derive(Debug)]
pub struct StudioApp {
    /// The state: document, library, runtime session, figures, viewers, log, settings.
    pub session: Session,
    /// The node editor.
    pub canvas: Canvas,
    connection: Connection,
    /// Recording and replay controls.
    transport: Transport,
    bottom: BottomPanel,
    /// The palette's search.
    search: String,
    dialogs: Dialogs,
    /// Components copied, to paste.
    clipboard: Vec<ComponentInstance>,
    /// What the panels asked for this frame.
    commands: Vec<Command>,
    quitting: bool,
    /// The example diagrams an empty canvas offers.
    examples: Vec<crate::examples::Example>,
    /// The diagrams the open one was entered from, outermost first (double-clicking a subgraph).
    breadcrumb: Vec<PathBuf>,
    /// The window title last sent: egui repaints after every viewport command, so sending the title each
    /// frame would keep the studio drawing for ever.
    window_title: String,
    /// With `KAIROS_STUDIO_TRACE_FRAMES` set, each frame drawn is said on standard error with its time since
    /// this instant: how the window tests (and anyone chasing a busy studio) count frames.
    frame_trace: Option<(std::time::Instant, u64)>,
}

/// Said when a diagram opened with every component at one place was laid out.
const STACKED_LAID_OUT: &str =
    "the diagram gives its components no positions: they are laid out in columns (save to keep them)";

impl StudioApp {
    /// A studio editing `document`, driving the runtime behind `client` (none: editing only, with
    /// `library` as the palette), named `runtime_label`; `local` is the runtime the studio started, kept
    /// running as long as the studio.
    pub fn new(
        document: Document,
        library: LibraryInfo,
        client: Option<RuntimeClient>,
        runtime_label: String,
        local: Option<crate::local::LocalRuntime>,
    ) -> Self {
        let (settings, settings_error) = Settings::load(crate::settings::default_folder());
        let mut session = Session::new(document, library, settings);
        session.restore_viewers();
        if lay_out_if_stacked(&mut session.document) {
            session.note(LogLevel::Info, STACKED_LAID_OUT.to_owned());
        }
        if let Some(error) = settings_error {
            session.note(LogLevel::Warn, error);
        }
        if let Some(client) = &client {
            session.connecting(runtime_label, client.url());
        }
        let mut canvas = Canvas::default();
        canvas.fit(&session.document, &session.library);
        StudioApp {
            session,
            canvas,
            connection: Connection::new(client, local),
            transport: Transport::default(),
            bottom: BottomPanel::default(),
            search: String::new(),
            dialogs: Dialogs::default(),
            clipboard: Vec::new(),
            commands: Vec::new(),
            quitting: false,
            breadcrumb: Vec::new(),
            examples: crate::examples::folder()
                .map(|folder| crate::examples::in_folder(&folder))
                .unwrap_or_default(),
            window_title: String::new(),
            frame_trace: std::env::var_os("KAIROS_STUDIO_TRACE_FRAMES")
                .map(|_| (std::time::Instant::now(), 0)),
        }
    }

    /// Remembers recent files and the last remote runtime in `folder` instead of the user's configuration.
    #[must_use]
    pub fn with_config_dir(mut self, folder: PathBuf) -> Self {
        let (settings, error) = Settings::load(Some(folder));
        self.session.settings = settings;
        if let Some(error) = error {
            self.session.note(LogLevel::Warn, error);
        }
        self
    }

    /// Offers the examples of `folder` on an empty canvas (instead of those `KAIROS_EXAMPLES` or the
    /// repository's `examples/` give).
    #[must_use]
    pub fn with_examples(mut self, folder: &std::path::Path) -> Self {
        self.examples = crate::examples::in_folder(folder);
        self
    }

    /// Uses this `kairos` program to generate components and to run the local runtime.
    #[must_use]
    pub fn with_kairos_binary(mut self, binary: PathBuf) -> Self {
        self.connection.kairos = Some(binary);
        self
    }

    /// Opens viewers on `outputs` (`component.port`) and, with `run`, deploys and starts the diagram, as soon
    /// as the runtime's library is known.
    #[must_use]
    pub fn with_startup(mut self, outputs: Vec<String>, run: bool) -> Self {
        self.session.set_startup(outputs, run);
        self
    }

    /// Reaches runtimes on other machines this way (the connect dialog's connections too).
    #[must_use]
    pub fn with_reach(mut self, reach: crate::connection::Reach) -> Self {
        self.connection.reach = reach;
        self
    }

    /// A component's state as the runtime last reported it.
    pub fn node_state(&self, id: &str) -> Option<&crate::session::NodeState> {
        self.session.node_state(id)
    }

    /// Whether the runtime accepted the session.
    pub fn is_connected(&self) -> bool {
        self.session.is_connected()
    }

    /// Whether viewer frames come through shared memory (a runtime on this machine) rather than the socket.
    pub fn uses_shared_memory(&self) -> bool {
        self.session.uses_shared_memory()
    }

    /// One frame of the whole window (also what the interface tests drive).
    pub fn show(&mut self, ui: &mut egui::Ui) {
        let ctx = ui.ctx().clone();
        self.connection.poll(&mut self.session);
        self.connection.poll_restart(&ctx, &mut self.session);
        self.session.describe_instances();
        self.session.describe_subgraphs();
        shortcuts(&ctx, &mut self.commands);
        crate::canvas::zoom_in_fine_steps(&ctx);
        if ctx.input(|i| i.viewport().close_requested()) && !self.quitting && self.session.document.is_dirty()
        {
            ctx.send_viewport_cmd(egui::ViewportCommand::CancelClose);
            self.dialogs.unsaved = Some(AfterDiscard::Quit);
        }
        if self.quitting {
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        }
        let title = self.title();
        if title != self.window_title {
            ctx.send_viewport_cmd(egui::ViewportCommand::Title(title.clone()));
            self.window_title = title;
        }
        self.panels_ui(ui);
        // The panels' commands first, so that a dialog they open shows in this frame already; then the
        // dialogs' own.
        self.run_commands(&ctx);
        self.dialogs_ui(&ctx);
        self.run_commands(&ctx);
        if self.session.viewers.take_changed() {
            self.session.subscribe_viewers();
        }
        self.connection.carry_out(&mut self.session);
    }

    fn title(&self) -> String {
        let document = &self.session.document;
        format!(
            "{}{} — Kairos studio",
            document
                .path()
                .map_or_else(|| "untitled".to_owned(), |p| p.display().to_string()),
            if document.is_dirty() { " •" } else { "" }
        )
    }

    /// The panels around the canvas, and the canvas.
    fn panels_ui(&mut self, ui: &mut egui::Ui) {
        let menus = MenuContext {
            recent: &self.session.settings.recent,
            has_local_runtime: self.connection.local_address().is_some(),
        };
        egui::Panel::top("menu").show(ui, |ui| menu_bar_ui(ui, &self.session, menus, &mut self.commands));
        egui::Panel::left("palette")
            .default_size(210.0)
            .size_range(160.0..=400.0)
            .show(ui, |ui| {
                crate::palette::palette_ui(ui, &self.session.library, &mut self.search);
            });
        // Bounded, so selecting a component whose properties are wide does not resize (and move) the canvas.
        egui::Panel::right("inspector")
            .default_size(300.0)
            .size_range(220.0..=520.0)
            .show(ui, |ui| {
                crate::inspector::inspector_ui(ui, &self.session, &self.canvas, &mut self.commands);
            });
        // Top and bottom panels are fixed unless asked: the log is the one people make taller.
        egui::Panel::bottom("log")
            .resizable(true)
            .default_size(150.0)
            .size_range(60.0..=500.0)
            .show(ui, |ui| {
                bottom_panel_ui(
                    ui,
                    &mut self.bottom,
                    &self.session.log,
                    &mut self.session.monitor,
                    &mut self.session.console,
                );
            });
        if crate::transport::has_controls(&self.session.monitor) {
            let (requests, replay) = egui::Panel::bottom("transport")
                .show(ui, |ui| self.transport.show(ui, &self.session.monitor))
                .inner;
            self.commands.extend(requests.into_iter().map(Command::Request));
            self.commands.extend(replay);
        }
        // After the log, so that the log spans under the canvas and the dock alike; bounded, so no
        // viewer's contents widen it over the canvas.
        if self.session.viewers.any_docked() {
            egui::Panel::right("viewers")
                .default_size(470.0)
                .size_range(300.0..=900.0)
                .show(ui, |ui| {
                    let choices = self.session.outputs_with_types();
                    self.session.viewers.show_docked(ui, &choices);
                });
        }
        let not_applied = self.session.not_applied();
        if !not_applied.is_empty() {
            egui::Panel::top("not applied").show(ui, |ui| {
                not_applied_ui(ui, &not_applied, &mut self.commands);
            });
        }
        // Inside a subgraph: the way back out, each diagram a link.
        if !self.breadcrumb.is_empty() {
            egui::Panel::top("breadcrumb").show(ui, |ui| {
                breadcrumb_ui(
                    ui,
                    &self.breadcrumb,
                    self.session.document.path(),
                    &mut self.commands,
                );
            });
        }
        // Problems in a strip over the canvas rather than on it: they never cover a node.
        if self.session.monitor.has_notices() {
            egui::Panel::top("notices").show(ui, |ui| self.session.monitor.show_notices(ui));
        }
        let session = &mut self.session;
        let canvas = &mut self.canvas;
        let examples = &self.examples;
        let commands = &mut self.commands;
        egui::CentralPanel::default().show(ui, |ui| {
            let empty = session.document.diagram().components.is_empty();
            let (document, shown) = session.canvas_view();
            canvas.show(ui, document, &shown);
            if empty {
                empty_canvas_ui(ui, examples, commands);
            }
            if let Some(refusal) = canvas.take_refusal() {
                session.note(LogLevel::Warn, refusal);
            }
            if let Some(request) = canvas.take_viewer_request() {
                session
                    .viewers
                    .open_kind(request.output.to_string(), request.kind);
            }
            if let Some((output, publish)) = canvas.take_foxglove_request() {
                session.publish_to_foxglove(&output.to_string(), publish);
            }
            if let Some(file) = canvas.take_file_request() {
                commands.push(Command::OpenFile(file));
            }
            if let Some((kind, inner, name)) = canvas.take_expose_request() {
                commands.push(Command::SetExposed { kind, inner, name });
            }
            if let Some(file) = canvas.take_subgraph_request() {
                commands.push(Command::OpenSubgraph(session.document_folder().join(file)));
            }
        });
        let choices = self.session.outputs_with_types();
        self.session.viewers.show_floating(ui.ctx(), &choices);
    }

    /// Whichever dialogs are open.
    fn dialogs_ui(&mut self, ctx: &egui::Context) {
        if let Some(mut dialog) = self.dialogs.new_component.take() {
            match dialog.show(ctx, self.connection.kairos.as_deref()) {
                crate::wizard::Outcome::Open => self.dialogs.new_component = Some(dialog),
                crate::wizard::Outcome::Closed => {}
                crate::wizard::Outcome::Load(folder) => {
                    self.dialogs.new_component = Some(dialog);
                    self.connection.load_pack(ctx, &mut self.session, &folder);
                }
            }
            if matches!(
                self.dialogs.new_component.as_ref().map(|d| &d.stage),
                Some(crate::wizard::Stage::Building(_))
            ) {
                ctx.request_repaint_after(std::time::Duration::from_millis(200));
            }
        }
        if let Some(mut chooser) = self.dialogs.chooser.take() {
            match chooser.show(ctx) {
                Choice::Open => self.dialogs.chooser = Some(chooser),
                Choice::Cancelled => {}
                Choice::Chosen(path) => self.chosen(chooser.purpose, path),
            }
        }
        if let Some(mut remote) = self.dialogs.connect.take()
            && crate::dialogs::connect_window(ctx, &mut remote, &mut self.commands)
        {
            self.dialogs.connect = Some(remote);
        }
        if let Some(after) = self.dialogs.unsaved.take()
            && crate::dialogs::unsaved_window(ctx, &after, &mut self.commands)
        {
            self.dialogs.unsaved = Some(after);
        }
    }

    /// A file was chosen in the file chooser.
    fn chosen(&mut self, purpose: Purpose, path: PathBuf) {
        match purpose {
            Purpose::OpenDiagram => self.unless_unsaved(AfterDiscard::Open(path)),
            Purpose::SaveDiagram => self.session.save_as(&path),
            Purpose::MakeSubgraph(ids) => {
                if let Some(instance) = self.session.make_subgraph(&ids, &path) {
                    self.canvas.selected = std::collections::BTreeSet::from([instance]);
                }
            }
            Purpose::Property { component, property } => {
                let written = chooser::as_written(&path);
                self.session
                    .set_property(&component, &property, Value::Text(written));
            }
        }
    }

    fn run_commands(&mut self, ctx: &egui::Context) {
        for command in std::mem::take(&mut self.commands) {
            self.run(ctx, command);
        }
    }

    /// Carries out one command.
    fn run(&mut self, ctx: &egui::Context, command: Command) {
        match command {
            Command::NewDiagram => self.unless_unsaved(AfterDiscard::New),
            Command::OpenDiagram => self.choose_file(Purpose::OpenDiagram),
            Command::OpenFile(path) => self.unless_unsaved(AfterDiscard::Open(path)),
            Command::OpenSubgraph(path) => self.unless_unsaved(AfterDiscard::Inside(path)),
            Command::BackTo(depth) => self.unless_unsaved(AfterDiscard::Back(depth)),
            Command::Save => self.save(),
            Command::SaveAs => self.choose_file(Purpose::SaveDiagram),
            Command::Quit => self.unless_unsaved(AfterDiscard::Quit),
            Command::SaveThen(after) => {
                self.save();
                if !self.session.document.is_dirty() {
                    self.proceed(after);
                }
            }
            Command::Discard(after) => self.proceed(after),
            Command::NewComponentDialog => {
                self.dialogs.new_component = Some(crate::wizard::NewComponentDialog::default());
            }
            Command::ConnectDialog => {
                let known = self
                    .session
                    .settings
                    .remembered_remotes()
                    .unwrap_or_else(|error| {
                        self.session.note(
                            LogLevel::Warn,
                            format!("the remote runtimes connected to before: {error}"),
                        );
                        Vec::new()
                    });
                self.dialogs.connect = Some(crate::dialogs::ConnectDialog {
                    remote: known.first().cloned().unwrap_or_default(),
                    known,
                });
            }
            Command::Connect(remote) => self.connect_remote(ctx, remote),
            Command::UseLocalRuntime => self.connection.use_local(ctx, &mut self.session),
            Command::Undo => {
                self.session.document.undo();
                self.session.edit_undone_or_redone();
            }
            Command::Redo => {
                self.session.document.redo();
                self.session.edit_undone_or_redone();
            }
            Command::Copy => self.copy(),
            Command::Paste => self.paste(),
            Command::Duplicate => {
                self.copy();
                self.paste();
            }
            Command::Delete => self.delete_selection(),
            Command::Rename { from, to } => {
                if self.session.rename_component(&from, &to) && self.canvas.selected.remove(&from) {
                    self.canvas.selected.insert(to.trim().to_owned());
                }
            }
            Command::FitDiagram => self.canvas.fit(&self.session.document, &self.session.library),
            Command::Zoom(factor) => self.canvas.zoom_by(factor),
            Command::MakeSubgraphDialog => {
                let ids: Vec<String> = self.canvas.selected.iter().cloned().collect();
                if ids.is_empty() {
                    self.session.note(
                        LogLevel::Warn,
                        "select the components to make a subgraph of (drag a box around them)".to_owned(),
                    );
                } else {
                    self.choose_file(Purpose::MakeSubgraph(ids));
                }
            }
            Command::TidyLayout => {
                auto_layout(&mut self.session.document);
                self.canvas.fit(&self.session.document, &self.session.library);
            }
            Command::Run => self.session.deploy_and_start(),
            Command::StartUnlocked => self.session.start_unlocked(),
            Command::SetLockBound(bound) => self.session.set_lock_bound(bound),
            Command::Request(body) => self.session.request(body),
            Command::OpenViewer { output, data_type } => self.session.viewers.open(output, &data_type),
            Command::Replay { recorder, file } => {
                let replay = self.session.replay_diagram(&recorder, &file);
                self.unless_unsaved(AfterDiscard::Unsaved(Box::new(replay)));
            }
            Command::SetProperty {
                component,
                property,
                value,
            } => self.session.set_property(&component, &property, value),
            Command::FieldRefused {
                component,
                property,
                why,
            } => self.session.field_refused(&component, &property, why),
            Command::SetReader { from, to, settings } => self.session.set_reader(&from, &to, settings),
            Command::RefreshDevices => self.session.refresh_devices(),
            Command::RefreshRos2Topics { router, domain } => self.session.refresh_ros2_topics(router, domain),
            Command::SetClockSource(source) => {
                self.session
                    .document
                    .edit(|diagram| diagram.clock_source = source);
            }
            Command::SetGroup { components, group } => {
                self.session.document.edit(|diagram| {
                    for id in &components {
                        if let Some(component) = diagram.component_mut(id) {
                            component.group.clone_from(&group);
                        }
                    }
                });
            }
            Command::SetExposed { kind, inner, name } => {
                self.session.set_exposed(kind, &inner, name.as_deref());
            }
            Command::SetSequential(sequential) => {
                self.session
                    .document
                    .edit(|diagram| diagram.sequential = sequential);
            }
            Command::TriggerAction { component, action } => {
                self.session
                    .request(RequestBody::TriggerAction { component, action });
            }
            Command::ChoosePath {
                component,
                property,
                current,
            } => {
                self.dialogs.chooser = Some(FileChooser::new(
                    Purpose::Property { component, property },
                    &current,
                ));
            }
        }
    }

    /// Connects to a remote runtime with the token in its token file, and remembers both (never the token).
    fn connect_remote(&mut self, ctx: &egui::Context, remote: RemoteAddress) {
        let token = if remote.token_file.is_empty() {
            None
        } else {
            match crate::settings::read_token(std::path::Path::new(&remote.token_file)) {
                Ok(token) => Some(token),
                Err(error) => {
                    self.session.note(LogLevel::Error, error.to_string());
                    self.dialogs.connect = Some(crate::dialogs::ConnectDialog {
                        known: self.session.settings.remembered_remotes().unwrap_or_default(),
                        remote,
                    });
                    return;
                }
            }
        };
        if let Err(error) = self.session.settings.remember_remote(&remote) {
            self.session.note(
                LogLevel::Warn,
                format!("the runtime's address is not remembered: {error}"),
            );
        }
        let label = format!("runtime {}", remote.url);
        let certificate = (!remote.certificate.is_empty()).then(|| PathBuf::from(&remote.certificate));
        self.connection
            .connect(ctx, &mut self.session, &remote.url, token, certificate, label);
    }

    /// Runs `after` now, or asks first when there are unsaved changes.
    fn unless_unsaved(&mut self, after: AfterDiscard) {
        if self.session.document.is_dirty() {
            self.dialogs.unsaved = Some(after);
        } else {
            self.proceed(after);
        }
    }

    fn proceed(&mut self, after: AfterDiscard) {
        match after {
            AfterDiscard::New => {
                self.breadcrumb.clear();
                self.session.document = Document::default();
                self.session.restore_viewers();
                self.session.document_replaced();
                self.canvas = Canvas::default();
            }
            AfterDiscard::Open(path) => {
                self.breadcrumb.clear();
                self.open(&path);
            }
            AfterDiscard::Inside(path) => {
                let outside = self.session.document.path().map(std::path::Path::to_owned);
                if self.open(&path)
                    && let Some(outside) = outside
                {
                    self.breadcrumb.push(outside);
                }
            }
            AfterDiscard::Back(depth) => {
                if let Some(path) = self.breadcrumb.get(depth).cloned()
                    && self.open(&path)
                {
                    self.breadcrumb.truncate(depth);
                }
            }
            AfterDiscard::Quit => self.quitting = true,
            AfterDiscard::Unsaved(diagram) => {
                self.breadcrumb.clear();
                self.session.document = Document::unsaved(*diagram);
                self.session.restore_viewers();
                self.session.document_replaced();
                self.canvas = Canvas::default();
                self.canvas.fit(&self.session.document, &self.session.library);
            }
        }
    }

    /// Opens the diagram at `path` in place of the open one; whether it opened.
    fn open(&mut self, path: &std::path::Path) -> bool {
        let opened = self.session.open(path);
        if opened {
            if lay_out_if_stacked(&mut self.session.document) {
                self.session.note(LogLevel::Info, STACKED_LAID_OUT.to_owned());
            }
            self.session.document_replaced();
            self.canvas = Canvas::default();
            self.canvas.fit(&self.session.document, &self.session.library);
        }
        opened
    }

    fn save(&mut self) {
        if self.session.save() == Saved::NeedsPath {
            self.choose_file(Purpose::SaveDiagram);
        }
    }

    /// Opens the file chooser for a diagram, in the folder of the current file (and on its name, to save).
    fn choose_file(&mut self, purpose: Purpose) {
        let current = match (self.session.document.path(), &purpose) {
            (Some(path), Purpose::SaveDiagram) => path.display().to_string(),
            (Some(path), Purpose::MakeSubgraph(_)) => {
                path.with_file_name("subgraph.ron").display().to_string()
            }
            (Some(path), _) => path.parent().map(|f| f.display().to_string()).unwrap_or_default(),
            (None, Purpose::SaveDiagram) => "diagram.ron".to_owned(),
            (None, Purpose::MakeSubgraph(_)) => "subgraph.ron".to_owned(),
            (None, _) => String::new(),
        };
        self.dialogs.chooser = Some(FileChooser::new(purpose, &current));
    }

    fn copy(&mut self) {
        self.clipboard = self
            .session
            .document
            .diagram()
            .components
            .iter()
            .filter(|c| self.canvas.selected.contains(&c.id))
            .cloned()
            .collect();
    }

    /// Pastes the clipboard's components beside the originals, with fresh ids, and selects them.
    fn paste(&mut self) {
        let copies = self.clipboard.clone();
        let mut pasted = Vec::new();
        self.session.document.edit(|diagram| {
            for mut component in copies {
                let base = component
                    .id
                    .trim_end_matches(|c: char| c.is_ascii_digit())
                    .to_owned();
                let id = crate::document::fresh_id(diagram, &base);
                component.id.clone_from(&id);
                component.position.x += 30.0;
                component.position.y += 30.0;
                diagram.components.push(component);
                pasted.push(id);
            }
        });
        if !pasted.is_empty() {
            self.canvas.selected = pasted.into_iter().collect();
        }
    }

    fn delete_selection(&mut self) {
        if let Some(connection) = self.canvas.selected_connection.take() {
            self.session
                .document
                .remove_connection(&connection.from, &connection.to);
        }
        let ids: Vec<String> = std::mem::take(&mut self.canvas.selected).into_iter().collect();
        if !ids.is_empty() {
            self.session.document.remove_components(&ids);
        }
    }
}

/// `outer.ron › inner.ron`: the diagrams a subgraph was entered from, each a link back to it.
fn breadcrumb_ui(
    ui: &mut egui::Ui,
    breadcrumb: &[PathBuf],
    here: Option<&std::path::Path>,
    commands: &mut Vec<Command>,
) {
    let name = |path: &std::path::Path| {
        path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        )
    };
    ui.horizontal(|ui| {
        ui.weak("inside a subgraph:");
        for (depth, outside) in breadcrumb.iter().enumerate() {
            if ui
                .link(name(outside))
                .on_hover_text(format!("back to {}", outside.display()))
                .clicked()
            {
                commands.push(Command::BackTo(depth));
            }
            ui.weak("›");
        }
        if let Some(here) = here {
            ui.strong(name(here));
        }
    });
}

/// What an empty canvas says: how to begin, and the examples to open.
fn empty_canvas_ui(ui: &mut egui::Ui, examples: &[crate::examples::Example], commands: &mut Vec<Command>) {
    let rect = ui.max_rect();
    egui::Area::new(egui::Id::unique("empty canvas"))
        .order(egui::Order::Middle)
        // Top left, leaving the middle of the canvas free for what is dropped there.
        .fixed_pos(rect.left_top() + egui::vec2(24.0, 24.0))
        .constrain_to(rect)
        .show(ui.ctx(), |ui| {
            ui.set_max_width(440.0);
            ui.heading("An empty diagram");
            ui.label(
                "Drag components from the palette on the left onto this canvas, then drag from an \
                 output (right side of a node) to an input (left side) to connect them. Select a node \
                 to set its properties on the right, and press Run.",
            );
            if examples.is_empty() {
                return;
            }
            ui.add_space(8.0);
            ui.menu_button("Open an example", |ui| {
                ui.set_max_width(520.0);
                // Every example, grouped by folder: more than a window's height, so it scrolls.
                let height = ui.ctx().content_rect().height() * 0.8;
                egui::ScrollArea::vertical().max_height(height).show(ui, |ui| {
                    let mut group = "";
                    for example in examples {
                        if example.group != group {
                            group = &example.group;
                            ui.separator();
                            ui.label(egui::RichText::new(format!("{group}/")).strong());
                        }
                        // One button for the name and the description, so either opens it.
                        if ui.add(example_button(ui, example)).clicked() {
                            commands.push(Command::OpenFile(example.path.clone()));
                            ui.close();
                        }
                    }
                });
            });
        });
}

/// An example's entry: its name, and under it what it shows.
fn example_button(ui: &egui::Ui, example: &crate::examples::Example) -> egui::Button<'static> {
    let style = ui.style();
    let mut job = egui::text::LayoutJob::default();
    egui::RichText::new(&example.name).strong().append_to(
        &mut job,
        style,
        egui::FontSelection::Default,
        egui::Align::LEFT,
    );
    if !example.description.is_empty() {
        egui::RichText::new(format!("\n{}", example.description))
            .weak()
            .append_to(&mut job, style, egui::FontSelection::Default, egui::Align::LEFT);
    }
    job.wrap.max_width = 500.0;
    egui::Button::new(job).frame_when_inactive(false)
}

/// The bar over the canvas while the running diagram lacks some edits: which, and Restart.
fn not_applied_ui(ui: &mut egui::Ui, edits: &[String], commands: &mut Vec<Command>) {
    ui.horizontal_wrapped(|ui| {
        if ui
            .button("Restart now")
            .on_hover_text("Deploy the edited diagram and start it again")
            .clicked()
        {
            commands.push(Command::Run);
        }
        let shown: Vec<&str> = edits.iter().take(4).map(String::as_str).collect();
        let more = edits.len().saturating_sub(shown.len());
        let text = if more > 0 {
            format!("Applies at the next run: {} and {more} more", shown.join("; "))
        } else {
            format!("Applies at the next run: {}", shown.join("; "))
        };
        ui.label(egui::RichText::new(text).color(crate::log_panel::WARN_COLOR))
            .on_hover_text(edits.join("\n"));
    });
}

impl eframe::App for StudioApp {
    fn ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        if let Some((since, frames)) = &mut self.frame_trace {
            *frames += 1;
            eprintln!(
                "studio frame {frames} at {} ms ({:?})",
                since.elapsed().as_millis(),
                ui.ctx().repaint_causes()
            );
        }
        self.show(ui);
        if let Some(render_state) = frame.wgpu_render_state() {
            crate::cloud3d::forget(render_state, &self.session.viewers.take_closed_on_gpu());
        }
    }
}
