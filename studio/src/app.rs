//! The studio window: palette, canvas, inspector, log, files and run controls, around one [`Document`] and
//! one runtime connection.

use std::collections::{BTreeMap, VecDeque};
use std::path::PathBuf;

use egui::{Color32, RichText};
use kairos_diagram::{ComponentInstance, LibraryInfo, PropertyKind, ReaderPolicy, Value};
use kairos_protocol::{ComponentState, LogLevel, ProtocolError, ReplyBody, RequestBody, RuntimeState, Token};

use crate::canvas::{Canvas, NewComponent, NewViewer, NodeState, auto_layout};
use crate::chooser::{self, Choice, FileChooser, Purpose};
use crate::client::{Answer, ClientEvent, RuntimeClient};
use crate::document::Document;
use crate::monitor::Monitor;
use crate::transport::Transport;
use crate::viewers::Viewers;

/// What a request in flight was for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Pending {
    Library,
    /// A description of the instances whose ports depend on their properties.
    Describe,
    /// A subscription to the viewers' sample frames.
    Samples,
    /// A deploy of this text.
    Deploy,
    Other,
}

/// A question about unsaved changes, and what to do after it.
#[derive(Debug, Clone, PartialEq, Eq)]
enum AfterDiscard {
    New,
    Open(PathBuf),
    Quit,
}

/// The studio.
#[allow(
    clippy::struct_excessive_bools,
    reason = "independent facts of one session: connected, quitting, starting after a deploy, shared memory"
)]
pub struct StudioApp {
    /// The diagram being edited.
    pub document: Document,
    /// The connected runtime's component library.
    pub library: LibraryInfo,
    /// The node editor.
    pub canvas: Canvas,
    client: Option<RuntimeClient>,
    runtime_label: String,
    connected: bool,
    run_state: RuntimeState,
    states: BTreeMap<String, NodeState>,
    pending: BTreeMap<u64, Pending>,
    start_after_deploy: bool,
    /// The text of the last deploy, to place the runtime's diagnostics on the nodes they concern.
    deployed_text: String,
    log: VecDeque<LogLine>,
    /// The log panel's filters: the least level shown, and one component (all when `None`).
    log_level: LogLevel,
    log_component: Option<String>,
    bottom_tab: BottomTab,
    /// Live figures from telemetry.
    pub monitor: Monitor,
    /// The open data viewers.
    pub viewers: Viewers,
    /// Recording and replay controls.
    transport: Transport,
    /// Whether the runtime is on this machine and can hand viewer frames over in shared memory.
    shared_memory: bool,
    /// Whether, with shared memory, images come as references to the runtime's own pixel buffers, which
    /// this process may map: no copy at all on the runtime's side.
    shared_pixels: bool,
    /// The "New component…" dialog, while it is open.
    new_component: Option<crate::wizard::NewComponentDialog>,
    /// The `kairos` program, which generates components and runs the local runtime.
    kairos: Option<PathBuf>,
    /// Folders of pack libraries built from the studio, loaded into the local runtime.
    pack_paths: Vec<PathBuf>,
    /// The instances (id, type, properties) last sent to be described, and whether an answer is awaited.
    described: (InstanceKey, bool),
    /// Outputs to open viewers on, and whether to run, once the runtime's library is known (command line).
    startup: (Vec<String>, bool),
    search: String,
    confirm: Option<AfterDiscard>,
    recent: Vec<PathBuf>,
    clipboard: Vec<ComponentInstance>,
    quitting: bool,
    /// The connect dialog's address and token file, while it is open.
    connect_prompt: Option<(String, String)>,
    /// The local runtime's address and token, to go back to it.
    local_address: Option<(String, Token)>,
    /// Where recent files and the last remote runtime are remembered.
    config_dir: Option<PathBuf>,
    /// The file chooser, while it is open.
    chooser: Option<FileChooser>,
    /// Kept alive as long as the studio: dropping it stops the local runtime.
    local_runtime: Option<crate::local::LocalRuntime>,
}

impl std::fmt::Debug for StudioApp {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StudioApp")
            .field("runtime", &self.runtime_label)
            .finish_non_exhaustive()
    }
}

const LOG_LINES: usize = 2000;
/// Viewers get at most this many samples a second per output, always the latest.
const VIEWER_RATE_HZ: f64 = 30.0;
/// Wider images are sent scaled down by a whole factor.
const VIEWER_IMAGE_WIDTH: u32 = 1920;
const WARN_COLOR: Color32 = Color32::from_rgb(240, 170, 60);

/// What a description of instances depends on: each component's id, type and properties.
type InstanceKey = Vec<(String, String, BTreeMap<String, Value>)>;

/// One line of the log panel.
#[derive(Debug, Clone)]
struct LogLine {
    color: Color32,
    level: LogLevel,
    /// The component it concerns, for runtime records that name one.
    component: Option<String>,
    text: String,
}

/// Which view the bottom panel shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum BottomTab {
    Log,
    Monitor,
}

/// Where the studio keeps what it remembers between launches: `$XDG_CONFIG_HOME/kairos` or
/// `~/.config/kairos`.
fn default_config_dir() -> Option<PathBuf> {
    let base = std::env::var_os("XDG_CONFIG_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".config")))?;
    Some(base.join("kairos"))
}

/// The last remote runtime connected to: its address and token file (never the token itself).
fn remembered_remote(config: Option<&std::path::Path>) -> (String, String) {
    let text = config
        .map(|c| c.join("studio-remote.txt"))
        .and_then(|f| std::fs::read_to_string(f).ok())
        .unwrap_or_default();
    let mut lines = text.lines();
    (
        lines.next().unwrap_or("ws://HOST:7400").to_owned(),
        lines.next().unwrap_or("").to_owned(),
    )
}

fn remember_remote(config: Option<&std::path::Path>, url: &str, token_file: &str) {
    if let Some(folder) = config {
        let _ = std::fs::create_dir_all(folder);
        let _ = std::fs::write(folder.join("studio-remote.txt"), format!("{url}\n{token_file}\n"));
    }
}

impl StudioApp {
    /// A studio editing `document`, driving the runtime behind `client` (none: editing only, with
    /// `library` as the palette).
    pub fn new(
        document: Document,
        library: LibraryInfo,
        client: Option<RuntimeClient>,
        runtime_label: String,
        local: Option<crate::local::LocalRuntime>,
    ) -> Self {
        let config_dir = default_config_dir();
        let recent = config_dir
            .as_ref()
            .and_then(|c| std::fs::read_to_string(c.join("studio-recent.txt")).ok())
            .map(|text| text.lines().map(PathBuf::from).collect())
            .unwrap_or_default();
        let mut app = StudioApp {
            document,
            library,
            canvas: Canvas::default(),
            client,
            runtime_label,
            connected: false,
            run_state: RuntimeState::Empty,
            states: BTreeMap::new(),
            pending: BTreeMap::new(),
            start_after_deploy: false,
            deployed_text: String::new(),
            log: VecDeque::new(),
            log_level: LogLevel::Info,
            log_component: None,
            bottom_tab: BottomTab::Log,
            monitor: Monitor::default(),
            viewers: Viewers::default(),
            transport: Transport::default(),
            shared_memory: false,
            shared_pixels: false,
            new_component: None,
            kairos: crate::local::kairos_binary(),
            pack_paths: Vec::new(),
            described: (Vec::new(), false),
            startup: (Vec::new(), false),
            search: String::new(),
            confirm: None,
            recent,
            clipboard: Vec::new(),
            quitting: false,
            connect_prompt: None,
            local_address: local.as_ref().map(|l| (l.url.clone(), l.token.clone())),
            config_dir,
            chooser: None,
            local_runtime: local,
        };
        let library = app.library.clone();
        app.canvas.fit(&app.document, &library);
        app
    }

    /// A line of the studio's own in the log panel; its level follows from its colour.
    fn note(&mut self, color: Color32, text: impl Into<String>) {
        let level = if color == Color32::LIGHT_RED {
            LogLevel::Error
        } else if color == WARN_COLOR {
            LogLevel::Warn
        } else {
            LogLevel::Info
        };
        self.log_line(LogLine {
            color,
            level,
            component: None,
            text: text.into(),
        });
    }

    fn log_line(&mut self, line: LogLine) {
        self.log.push_back(line);
        while self.log.len() > LOG_LINES {
            self.log.pop_front();
        }
    }

    fn request(&mut self, body: RequestBody, pending: Pending) {
        if let Some(client) = &mut self.client {
            let id = client.request(body);
            self.pending.insert(id, pending);
        } else {
            self.note(Color32::LIGHT_RED, "no runtime connected");
        }
    }

    fn remember_recent(&mut self, path: PathBuf) {
        self.recent.retain(|p| p != &path);
        self.recent.insert(0, path);
        self.recent.truncate(10);
        if let Some(folder) = &self.config_dir {
            let _ = std::fs::create_dir_all(folder);
            let text: Vec<String> = self.recent.iter().map(|p| p.display().to_string()).collect();
            let _ = std::fs::write(folder.join("studio-recent.txt"), text.join("\n"));
        }
    }

    fn poll_runtime(&mut self) {
        let Some(client) = &self.client else { return };
        for event in client.poll() {
            match event {
                ClientEvent::Connected(welcome) => {
                    self.connected = true;
                    self.shared_memory = welcome.shared_memory_host.is_some()
                        && welcome.shared_memory_host == kairos_protocol::this_host();
                    self.shared_pixels = self.shared_memory
                        && welcome
                            .pid
                            .is_some_and(kairos_protocol::shared_pixels::can_map_buffers_of);
                    self.note(
                        Color32::LIGHT_GREEN,
                        format!("connected to {} ({:?})", welcome.server, welcome.role),
                    );
                    self.request(RequestBody::Library, Pending::Library);
                    self.request(
                        RequestBody::SubscribeTelemetry { interval_ms: 250 },
                        Pending::Other,
                    );
                    self.request(
                        RequestBody::SubscribeLog {
                            level: LogLevel::Info,
                        },
                        Pending::Other,
                    );
                }
                ClientEvent::Reply(answer) => self.take_reply(answer),
                ClientEvent::Telemetry(telemetry) => self.take_telemetry(&telemetry),
                ClientEvent::Log(record) => {
                    let color = match record.level {
                        LogLevel::Error => Color32::LIGHT_RED,
                        LogLevel::Warn => WARN_COLOR,
                        _ => Color32::GRAY,
                    };
                    let who = record
                        .component
                        .as_ref()
                        .map_or_else(String::new, |c| format!("{c}: "));
                    self.log_line(LogLine {
                        color,
                        level: record.level,
                        component: record.component,
                        text: format!("{who}{}", record.message),
                    });
                }
                ClientEvent::Sample(header, payload) => self.viewers.receive(&header, &payload),
                ClientEvent::Disconnected(reason) => {
                    self.connected = false;
                    self.note(Color32::LIGHT_RED, reason);
                }
            }
        }
    }

    /// The answer to one of our requests.
    fn take_reply(&mut self, answer: Answer) {
        let what = answer.id.and_then(|id| self.pending.remove(&id));
        match answer.outcome {
            Ok(result) => self.take_result(what, result),
            Err(error) => self.take_error(what, error),
        }
    }

    /// A request of ours that failed.
    fn take_error(&mut self, what: Option<Pending>, error: ProtocolError) {
        if what == Some(Pending::Deploy) && !error.diagnostics.is_empty() {
            let by_component =
                crate::document::diagnostics_by_component(&self.deployed_text, &error.diagnostics);
            for (id, problems) in by_component {
                self.states.insert(id, NodeState::Invalid(problems.join("\n")));
            }
            self.canvas.port_problems =
                crate::document::diagnostics_by_port(&self.deployed_text, &error.diagnostics)
                    .into_iter()
                    .map(|(port, problems)| (port, problems.join("\n")))
                    .collect();
        }
        if what == Some(Pending::Samples) && self.shared_memory {
            self.note(
                WARN_COLOR,
                format!("{}; viewers use the socket instead", error.message),
            );
            self.shared_memory = false;
            self.subscribe_viewers();
            return;
        }
        if what == Some(Pending::Describe) {
            // A diagram the runtime cannot parse yet: the editor keeps the type's ports.
            self.described.1 = false;
            self.start_up();
            return;
        }
        self.note(Color32::LIGHT_RED, error.message);
        self.start_after_deploy = false;
    }

    /// The result of a request of ours, of that request's type.
    fn take_result(&mut self, what: Option<Pending>, result: ReplyBody) {
        match (what, result) {
            (Some(Pending::Library), ReplyBody::Library(library)) => {
                self.library = library;
                self.described = (Vec::new(), false);
                self.describe_instances();
                if !self.described.1 {
                    self.start_up();
                }
            }
            (Some(Pending::Samples), ReplyBody::SubscribeSamples(subscribed)) => {
                self.samples_subscribed(subscribed.services);
            }
            (Some(Pending::Describe), ReplyBody::DescribeInstances(described)) => {
                self.described.1 = false;
                self.library.instances = described.instances;
                for (id, problem) in described.problems {
                    self.note(Color32::LIGHT_RED, format!("{id}: {}", problem.message));
                }
                self.start_up();
            }
            (Some(Pending::Deploy), ReplyBody::Deploy(_)) => {
                self.states.clear();
                self.monitor.clear();
                self.run_state = RuntimeState::Ready;
                self.subscribe_viewers();
                self.canvas.port_problems.clear();
                self.note(Color32::LIGHT_GREEN, "deployed");
                if std::mem::take(&mut self.start_after_deploy) {
                    self.request(RequestBody::Start, Pending::Other);
                }
            }
            _ => {}
        }
    }

    /// Node states and live figures from one telemetry event.
    fn take_telemetry(&mut self, telemetry: &kairos_protocol::Telemetry) {
        self.run_state = telemetry.state;
        // A refused deploy's marks stay until the next deploy, whatever runs meanwhile.
        let refused: Vec<(String, NodeState)> = self
            .states
            .iter()
            .filter(|(_, s)| matches!(s, NodeState::Invalid(_)))
            .map(|(id, s)| (id.clone(), s.clone()))
            .collect();
        self.states = telemetry
            .components
            .iter()
            .cloned()
            .map(|c| {
                let state = match (c.state, c.error) {
                    (ComponentState::Running, _) => NodeState::Running,
                    (ComponentState::Finished, _) => NodeState::Finished,
                    (_, Some(error)) => NodeState::Failed(error),
                    (other, None) => NodeState::Waiting(other.word().to_owned()),
                };
                (c.id, state)
            })
            .collect();
        self.states.extend(refused);
        for notice in self.monitor.update(telemetry) {
            self.note(WARN_COLOR, notice);
        }
    }

    /// Drops the current connection and connects to `url`.
    fn connect(&mut self, ctx: &egui::Context, url: &str, token: Option<Token>, label: String) {
        let waker = ctx.clone();
        self.client = Some(RuntimeClient::connect(url, token, move || {
            waker.request_repaint();
        }));
        self.runtime_label = label;
        self.connected = false;
        self.pending.clear();
        self.states.clear();
        self.run_state = RuntimeState::Empty;
        self.note(Color32::GRAY, format!("connecting to {url}"));
    }

    fn deploy_and_start(&mut self) {
        self.start_after_deploy = true;
        self.deployed_text = self.document.diagram().to_ron();
        self.request(
            RequestBody::Deploy {
                diagram: self.deployed_text.clone(),
            },
            Pending::Deploy,
        );
    }

    fn open(&mut self, path: PathBuf) {
        match Document::open(&path) {
            Ok(document) => {
                self.document = document;
                self.canvas = Canvas::default();
                self.canvas.fit(&self.document, &self.library);
                self.note(Color32::GRAY, format!("opened {}", path.display()));
                self.remember_recent(path);
            }
            Err(error) => self.note(Color32::LIGHT_RED, error),
        }
    }

    /// Runs `after` now, or asks first when there are unsaved changes.
    fn unless_unsaved(&mut self, after: AfterDiscard) {
        if self.document.is_dirty() {
            self.confirm = Some(after);
        } else {
            self.proceed(after);
        }
    }

    fn proceed(&mut self, after: AfterDiscard) {
        match after {
            AfterDiscard::New => {
                self.document = Document::default();
                self.canvas = Canvas::default();
            }
            AfterDiscard::Open(path) => self.open(path),
            AfterDiscard::Quit => self.quitting = true,
        }
    }

    fn save(&mut self) {
        if self.document.path().is_none() {
            self.choose_file(Purpose::SaveDiagram);
            return;
        }
        match self.document.save() {
            Ok(()) => {
                let path = self.document.path().map(std::path::Path::to_path_buf);
                self.note(
                    Color32::GRAY,
                    format!(
                        "saved {}",
                        path.as_deref()
                            .map(|p| p.display().to_string())
                            .unwrap_or_default()
                    ),
                );
                if let Some(path) = path {
                    self.remember_recent(path);
                }
            }
            Err(error) => self.note(Color32::LIGHT_RED, error),
        }
    }

    fn shortcuts(&mut self, ctx: &egui::Context) {
        use egui::{Key, KeyboardShortcut, Modifiers};
        let typing = ctx.egui_wants_keyboard_input();
        let pressed =
            |modifiers, key| ctx.input_mut(|i| i.consume_shortcut(&KeyboardShortcut::new(modifiers, key)));
        if pressed(Modifiers::COMMAND, Key::S) {
            self.save();
        }
        if typing {
            return;
        }
        if pressed(Modifiers::COMMAND | Modifiers::SHIFT, Key::Z) || pressed(Modifiers::COMMAND, Key::Y) {
            self.document.redo();
        }
        if pressed(Modifiers::COMMAND, Key::Z) {
            self.document.undo();
        }
        if pressed(Modifiers::COMMAND, Key::C) {
            self.copy();
        }
        if pressed(Modifiers::COMMAND, Key::V) {
            self.paste();
        }
        if pressed(Modifiers::COMMAND, Key::D) {
            self.copy();
            self.paste();
        }
        if pressed(Modifiers::NONE, Key::Delete) || pressed(Modifiers::NONE, Key::Backspace) {
            self.delete_selection();
        }
    }

    fn copy(&mut self) {
        self.clipboard = self
            .document
            .diagram()
            .components
            .iter()
            .filter(|c| self.canvas.selected.contains(&c.id))
            .cloned()
            .collect();
    }

    fn paste(&mut self) {
        let copies = self.clipboard.clone();
        let mut pasted = Vec::new();
        self.document.edit(|diagram| {
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
        if let Some((from, to)) = self.canvas.selected_connection.take() {
            self.document.remove_connection(&from, &to);
        }
        let ids: Vec<String> = std::mem::take(&mut self.canvas.selected).into_iter().collect();
        if !ids.is_empty() {
            self.document.remove_components(&ids);
        }
    }

    /// Opens the file chooser for a diagram, in the folder of the current file (and on its name, to save).
    fn choose_file(&mut self, purpose: Purpose) {
        let current = match (self.document.path(), &purpose) {
            (Some(path), Purpose::SaveDiagram) => path.display().to_string(),
            (Some(path), _) => path.parent().map(|f| f.display().to_string()).unwrap_or_default(),
            (None, Purpose::SaveDiagram) => "diagram.ron".to_owned(),
            (None, _) => String::new(),
        };
        self.chooser = Some(FileChooser::new(purpose, &current));
    }

    fn file_menu(&mut self, ui: &mut egui::Ui) {
        if ui.button("New").clicked() {
            self.unless_unsaved(AfterDiscard::New);
        }
        if ui.button("Open…").clicked() {
            self.choose_file(Purpose::OpenDiagram);
        }
        if ui.button("Save").clicked() {
            self.save();
        }
        if ui.button("Save as…").clicked() {
            self.choose_file(Purpose::SaveDiagram);
        }
        ui.menu_button("Recent", |ui| {
            for path in self.recent.clone() {
                if ui.button(path.display().to_string()).clicked() {
                    self.unless_unsaved(AfterDiscard::Open(path));
                }
            }
        });
        ui.separator();
        if ui
            .button("New component…")
            .on_hover_text("Generate a component, build its pack and load it into the local runtime")
            .clicked()
        {
            self.new_component = Some(crate::wizard::NewComponentDialog::default());
        }
        ui.separator();
        if ui.button("Connect to a runtime…").clicked() {
            self.connect_prompt = Some(remembered_remote(self.config_dir.as_deref()));
        }
        if let Some((url, token)) = self.local_address.clone()
            && ui.button("Use the local runtime").clicked()
        {
            let ctx = ui.ctx().clone();
            self.connect(&ctx, &url, Some(token), format!("local runtime {url}"));
        }
        ui.separator();
        if ui.button("Quit").clicked() {
            self.unless_unsaved(AfterDiscard::Quit);
        }
    }

    fn menu_bar(&mut self, ui: &mut egui::Ui) {
        egui::MenuBar::new().ui(ui, |ui| {
            ui.menu_button("File", |ui| self.file_menu(ui));
            ui.menu_button("Edit", |ui| {
                if ui.button("Undo").clicked() {
                    self.document.undo();
                }
                if ui.button("Redo").clicked() {
                    self.document.redo();
                }
                if ui.button("Delete").clicked() {
                    self.delete_selection();
                }
                if ui.button("Tidy the layout").clicked() {
                    auto_layout(&mut self.document);
                    self.canvas.fit(&self.document, &self.library);
                }
            });
            ui.separator();
            let running = matches!(self.run_state, RuntimeState::Running);
            if ui
                .button("Run")
                .on_hover_text("Deploy this diagram to the runtime and start it")
                .clicked()
            {
                self.deploy_and_start();
            }
            if ui.add_enabled(running, egui::Button::new("Pause")).clicked() {
                self.request(RequestBody::Pause, Pending::Other);
            }
            if ui
                .add_enabled(
                    matches!(self.run_state, RuntimeState::Paused),
                    egui::Button::new("Resume"),
                )
                .clicked()
            {
                self.request(RequestBody::Resume, Pending::Other);
            }
            if ui
                .add_enabled(
                    running || matches!(self.run_state, RuntimeState::Paused),
                    egui::Button::new("Stop"),
                )
                .clicked()
            {
                self.request(RequestBody::Stop, Pending::Other);
            }
            ui.separator();
            let (text, color) = match (&self.client, self.connected) {
                (None, _) => ("no runtime: editing only".to_owned(), Color32::GRAY),
                (Some(_), true) => (
                    format!("connected to {}", self.runtime_label),
                    Color32::LIGHT_GREEN,
                ),
                (Some(_), false) => (
                    format!("not connected to {}", self.runtime_label),
                    Color32::LIGHT_RED,
                ),
            };
            ui.label(RichText::new(text).color(color));
            ui.label(format!("— {:?}", self.run_state).to_lowercase());
        });
    }

    fn palette(&mut self, ui: &mut egui::Ui) {
        ui.heading("Components");
        ui.add(egui::TextEdit::singleline(&mut self.search).hint_text("search"));
        let needle = self.search.to_lowercase();
        let mut groups: BTreeMap<(String, String), Vec<&kairos_diagram::ComponentInfo>> = BTreeMap::new();
        for info in self.library.components.values() {
            let matches = needle.is_empty()
                || info.type_name.to_lowercase().contains(&needle)
                || info.doc.to_lowercase().contains(&needle);
            if matches {
                groups
                    .entry((info.pack.clone(), info.category.clone()))
                    .or_default()
                    .push(info);
            }
        }
        egui::ScrollArea::vertical().show(ui, |ui| {
            for ((pack, category), entries) in groups {
                egui::CollapsingHeader::new(format!("{pack} / {category}"))
                    .default_open(true)
                    .show(ui, |ui| {
                        for info in entries {
                            let id = ui.make_persistent_id(("palette", &info.type_name));
                            let response = ui
                                .dnd_drag_source(id, NewComponent(info.type_name.clone()), |ui| {
                                    ui.label(&info.type_name);
                                })
                                .response;
                            response.on_hover_text(&info.doc);
                        }
                    });
            }
            egui::CollapsingHeader::new("studio / viewers")
                .default_open(true)
                .show(ui, |ui| {
                    let id = ui.make_persistent_id("palette viewer");
                    ui.dnd_drag_source(id, NewViewer, |ui| {
                        ui.label("viewer");
                    })
                    .response
                    .on_hover_text(
                        "Drop on an output to watch its samples: images, plots, a GNSS track or a table, \
                         by the output's type",
                    );
                });
        });
    }

    #[allow(clippy::too_many_lines, reason = "one widget per property kind")]
    fn inspector(&mut self, ui: &mut egui::Ui) {
        ui.heading("Inspector");
        if let Some((from, to)) = self.canvas.selected_connection.clone() {
            ui.label(format!("{from} → {to}"));
            let Some(connection) = self
                .document
                .diagram()
                .connections
                .iter()
                .find(|c| c.from == from && c.to == to)
                .cloned()
            else {
                return;
            };
            let mut policy = connection.policy;
            egui::ComboBox::from_label("reader policy")
                .selected_text(policy.map_or("input's default", ReaderPolicy::name))
                .show_ui(ui, |ui| {
                    ui.selectable_value(&mut policy, None, "input's default");
                    for choice in [
                        ReaderPolicy::Fifo,
                        ReaderPolicy::LastOrNext,
                        ReaderPolicy::WaitForNext,
                        ReaderPolicy::Sampling,
                        ReaderPolicy::NeverSkipping,
                    ] {
                        ui.selectable_value(&mut policy, Some(choice), choice.name());
                    }
                });
            let mut buffer = connection.buffer_size.unwrap_or(0);
            ui.horizontal(|ui| {
                ui.label("buffer size (0: the output's)");
                ui.add(egui::DragValue::new(&mut buffer).range(0..=kairos_diagram::MAX_BUFFER_SIZE));
            });
            let mut subsampling = connection.subsampling.unwrap_or(1);
            ui.horizontal(|ui| {
                ui.label("keep one sample in");
                ui.add(egui::DragValue::new(&mut subsampling).range(1..=1_000_000));
            });
            if policy != connection.policy
                || buffer != connection.buffer_size.unwrap_or(0)
                || subsampling != connection.subsampling.unwrap_or(1)
            {
                self.document.edit(|d| {
                    if let Some(c) = d.connections.iter_mut().find(|c| c.from == from && c.to == to) {
                        c.policy = policy;
                        c.buffer_size = (buffer > 0).then_some(buffer);
                        c.subsampling = (subsampling > 1).then_some(subsampling);
                    }
                });
            }
            return;
        }
        let selected: Vec<String> = self.canvas.selected.iter().cloned().collect();
        let [id] = selected.as_slice() else {
            ui.label("Select a component or a connection.");
            return;
        };
        let id = id.clone();
        let Some(instance) = self.document.diagram().component(&id).cloned() else {
            return;
        };
        ui.label(RichText::new(&instance.id).strong());
        let Some(info) = self.library.component_of(&instance).cloned() else {
            ui.colored_label(Color32::LIGHT_RED, format!("unknown type {}", instance.type_name));
            return;
        };
        ui.label(RichText::new(&info.type_name).weak());
        ui.label(&info.doc);
        ui.separator();
        let running = matches!(self.run_state, RuntimeState::Running | RuntimeState::Paused);
        let mut browse = None;
        for property in &info.properties {
            let current = instance
                .properties
                .get(&property.name)
                .cloned()
                .unwrap_or_else(|| property.default.clone());
            let mut edited = current.clone();
            ui.horizontal(|ui| {
                let name_label = ui.label(&property.name).on_hover_text(&property.doc).id;
                match (&property.kind, &mut edited) {
                    (PropertyKind::F64 { min, max }, value) => {
                        let mut number = value.as_f64().unwrap_or(0.0);
                        let mut drag = egui::DragValue::new(&mut number).speed(0.1);
                        if let (Some(min), Some(max)) = (min, max) {
                            drag = drag.range(*min..=*max);
                        }
                        if ui.add(drag).labelled_by(name_label).changed() {
                            *value = Value::F64(number);
                        }
                    }
                    (PropertyKind::I64 { min, max }, value) => {
                        let mut number = value.as_i64().unwrap_or(0);
                        let mut drag = egui::DragValue::new(&mut number);
                        if let (Some(min), Some(max)) = (min, max) {
                            drag = drag.range(*min..=*max);
                        }
                        if ui.add(drag).labelled_by(name_label).changed() {
                            *value = Value::I64(number);
                        }
                    }
                    (PropertyKind::Bool, value) => {
                        let mut flag = value.as_bool().unwrap_or(false);
                        if ui.checkbox(&mut flag, "").labelled_by(name_label).changed() {
                            *value = Value::Bool(flag);
                        }
                    }
                    (PropertyKind::Choice(choices), value) => {
                        let mut chosen = value.as_text().unwrap_or("").to_owned();
                        egui::ComboBox::from_id_salt(("choice", &property.name))
                            .selected_text(&chosen)
                            .show_ui(ui, |ui| {
                                for choice in choices {
                                    ui.selectable_value(&mut chosen, choice.clone(), choice);
                                }
                            });
                        if Some(chosen.as_str()) != value.as_text() {
                            *value = Value::Text(chosen);
                        }
                    }
                    (kind @ (PropertyKind::Text | PropertyKind::Path), value) => {
                        let mut text = value.as_text().unwrap_or("").to_owned();
                        let edit = egui::TextEdit::singleline(&mut text).desired_width(160.0);
                        if ui.add(edit).labelled_by(name_label).changed() {
                            *value = Value::Text(text.clone());
                        }
                        if *kind == PropertyKind::Path
                            && ui.button("…").on_hover_text("Choose a file").clicked()
                        {
                            browse = Some(FileChooser::new(
                                Purpose::Property {
                                    component: id.clone(),
                                    property: property.name.clone(),
                                },
                                &text,
                            ));
                        }
                    }
                }
                if property.live {
                    ui.label(RichText::new("live").small().weak())
                        .on_hover_text("changes apply at once while the diagram runs");
                }
            });
            if let Err(error) = property.kind.check(&edited) {
                ui.colored_label(Color32::LIGHT_RED, error.to_string());
            }
            if edited != current {
                let name = property.name.clone();
                let value = edited.clone();
                self.document.edit(|d| {
                    if let Some(c) = d.component_mut(&id) {
                        c.properties.insert(name, value);
                    }
                });
                if running && property.live && property.kind.check(&edited).is_ok() {
                    self.request(
                        RequestBody::SetProperty {
                            component: id.clone(),
                            property: property.name.clone(),
                            value: edited,
                        },
                        Pending::Other,
                    );
                }
            }
        }
        if browse.is_some() {
            self.chooser = browse;
        }
        if !info.actions.is_empty() {
            ui.separator();
            for action in &info.actions {
                if ui.button(&action.name).on_hover_text(&action.doc).clicked() {
                    self.request(
                        RequestBody::TriggerAction {
                            component: id.clone(),
                            action: action.name.clone(),
                        },
                        Pending::Other,
                    );
                }
            }
        }
        if let Some(NodeState::Failed(error)) = self.states.get(&id) {
            ui.separator();
            ui.colored_label(Color32::LIGHT_RED, format!("failed: {error}"));
        }
    }

    fn connect_dialog(&mut self, ctx: &egui::Context) {
        let Some((mut url, mut token_file)) = self.connect_prompt.take() else {
            return;
        };
        let mut open = true;
        let mut go = false;
        egui::Window::new("Connect to a runtime")
            .collapsible(false)
            .open(&mut open)
            .show(ctx, |ui| {
                let address = ui.label("Address of a `kairos serve` (ws://HOST:PORT):").id;
                ui.text_edit_singleline(&mut url).labelled_by(address);
                let token = ui.label("File holding its token (empty when it needs none):").id;
                ui.text_edit_singleline(&mut token_file).labelled_by(token);
                go = ui.button("Connect").clicked();
            });
        if go {
            let token = if token_file.trim().is_empty() {
                Ok(None)
            } else {
                std::fs::read_to_string(token_file.trim())
                    .map(|t| Some(Token::new(t.lines().next().unwrap_or("").trim())))
                    .map_err(|e| format!("cannot read the token file {}: {e}", token_file.trim()))
            };
            match token {
                Ok(token) => {
                    remember_remote(self.config_dir.as_deref(), url.trim(), token_file.trim());
                    let url = url.trim().to_owned();
                    self.connect(ctx, &url, token, format!("runtime {url}"));
                }
                Err(error) => {
                    self.note(Color32::LIGHT_RED, error);
                    self.connect_prompt = Some((url, token_file));
                }
            }
        } else if open {
            self.connect_prompt = Some((url, token_file));
        }
    }

    /// The file chooser, for whichever purpose it is open.
    fn chooser_dialog(&mut self, ctx: &egui::Context) {
        let Some(mut chooser) = self.chooser.take() else {
            return;
        };
        let path = match chooser.show(ctx) {
            Choice::Open => {
                self.chooser = Some(chooser);
                return;
            }
            Choice::Cancelled => return,
            Choice::Chosen(path) => path,
        };
        match chooser.purpose {
            Purpose::OpenDiagram => self.unless_unsaved(AfterDiscard::Open(path)),
            Purpose::SaveDiagram => match self.document.save_as(&path) {
                Ok(()) => {
                    self.note(Color32::GRAY, format!("saved {}", path.display()));
                    self.remember_recent(path);
                }
                Err(error) => self.note(Color32::LIGHT_RED, error),
            },
            Purpose::Property { component, property } => {
                let written = chooser::as_written(&path);
                self.document.edit(|d| {
                    if let Some(c) = d.component_mut(&component) {
                        c.properties.insert(property, Value::Text(written));
                    }
                });
            }
        }
    }

    fn dialogs(&mut self, ctx: &egui::Context) {
        self.new_component_dialog(ctx);
        self.chooser_dialog(ctx);
        self.connect_dialog(ctx);
        if let Some(after) = self.confirm.clone() {
            egui::Window::new("Unsaved changes")
                .collapsible(false)
                .show(ctx, |ui| {
                    ui.label("The diagram has changes that are not saved.");
                    ui.horizontal(|ui| {
                        if ui.button("Save").clicked() {
                            self.save();
                            self.confirm = None;
                            if !self.document.is_dirty() {
                                self.proceed(after.clone());
                            }
                        }
                        if ui.button("Discard").clicked() {
                            self.confirm = None;
                            self.proceed(after.clone());
                        }
                        if ui.button("Cancel").clicked() {
                            self.confirm = None;
                        }
                    });
                });
        }
    }

    /// Remembers recent files and the last remote runtime in `folder` instead of the user's configuration.
    #[must_use]
    pub fn with_config_dir(mut self, folder: PathBuf) -> Self {
        self.config_dir = Some(folder);
        self
    }

    /// A component's state as the runtime last reported it.
    pub fn node_state(&self, id: &str) -> Option<&NodeState> {
        self.states.get(id)
    }

    /// Whether the runtime accepted the session.
    pub fn is_connected(&self) -> bool {
        self.connected
    }

    /// Asks the runtime to describe the instances whose ports depend on their properties (a player's
    /// outputs), whenever components or their properties changed since the last answer.
    fn describe_instances(&mut self) {
        if !self.connected || self.described.1 {
            return;
        }
        let key: InstanceKey = self
            .document
            .diagram()
            .components
            .iter()
            .map(|c| (c.id.clone(), c.type_name.clone(), c.properties.clone()))
            .collect();
        if key == self.described.0 {
            return;
        }
        self.described = (key, true);
        self.request(
            RequestBody::DescribeInstances {
                diagram: self.document.diagram().to_ron(),
            },
            Pending::Describe,
        );
    }

    /// Uses this `kairos` program to generate components and to run the local runtime.
    #[must_use]
    pub fn with_kairos_binary(mut self, binary: PathBuf) -> Self {
        self.kairos = Some(binary);
        self
    }

    /// The "New component…" dialog; a built pack is loaded by restarting the local runtime with it.
    fn new_component_dialog(&mut self, ctx: &egui::Context) {
        let Some(mut dialog) = self.new_component.take() else {
            return;
        };
        match dialog.show(ctx, self.kairos.as_deref()) {
            crate::wizard::Outcome::Open => self.new_component = Some(dialog),
            crate::wizard::Outcome::Closed => {}
            crate::wizard::Outcome::Load(folder) => {
                self.new_component = Some(dialog);
                self.load_pack(ctx, &folder);
            }
        }
        if matches!(
            self.new_component.as_ref().map(|d| &d.stage),
            Some(crate::wizard::Stage::Building(_))
        ) {
            ctx.request_repaint_after(std::time::Duration::from_millis(200));
        }
    }

    /// Restarts the local runtime with the pack libraries in `folder` too, and reconnects to it.
    fn load_pack(&mut self, ctx: &egui::Context, folder: &std::path::Path) {
        if self.local_address.is_none() {
            self.note(
                WARN_COLOR,
                format!(
                    "built {}; the studio drives a remote runtime: copy the library to that machine's pack path",
                    folder.display()
                ),
            );
            return;
        }
        let Some(binary) = self.kairos.clone() else { return };
        if !self.pack_paths.iter().any(|p| p == folder) {
            self.pack_paths.push(folder.to_path_buf());
        }
        match crate::local::LocalRuntime::start_with_packs(&binary, &self.pack_paths) {
            Ok(local) => {
                let (url, token) = (local.url.clone(), local.token.clone());
                self.local_address = Some((url.clone(), token.clone()));
                self.local_runtime = Some(local);
                self.connect(ctx, &url, Some(token), format!("local runtime {url}"));
                self.note(
                    Color32::LIGHT_GREEN,
                    format!("loaded the packs in {}", folder.display()),
                );
            }
            Err(error) => self.note(Color32::LIGHT_RED, error),
        }
    }

    /// Opens viewers on `outputs` (`component.port`) and, with `run`, deploys and starts the diagram, as soon
    /// as the runtime's library is known.
    #[must_use]
    pub fn with_startup(mut self, outputs: Vec<String>, run: bool) -> Self {
        self.startup = (outputs, run);
        self
    }

    fn start_up(&mut self) {
        let (outputs, run) = std::mem::take(&mut self.startup);
        for output in outputs {
            let port = kairos_diagram::PortRef::parse(&output);
            match port.and_then(|p| self.document.output_type(&p, &self.library)) {
                Some(data_type) => self.viewers.open(output, data_type.name()),
                None => self.note(
                    Color32::LIGHT_RED,
                    format!(
                        "--view {output}: no such output in the diagram (outputs are named component.port)"
                    ),
                ),
            }
        }
        if run {
            self.deploy_and_start();
        }
    }

    /// Asks the runtime for the samples of every output a viewer shows (and no others). Before a deployment
    /// there is nothing to subscribe to; deploying subscribes again.
    fn subscribe_viewers(&mut self) {
        if !self.connected || self.run_state == RuntimeState::Empty {
            return;
        }
        self.request(
            RequestBody::UnsubscribeSamples { outputs: Vec::new() },
            Pending::Other,
        );
        let outputs = self.viewers.outputs();
        if outputs.is_empty() {
            if let Some(client) = &mut self.client {
                let _ = client.receive_shared(BTreeMap::new());
            }
            return;
        }
        let transport = if self.shared_memory {
            kairos_protocol::SampleTransport::SharedMemory
        } else {
            kairos_protocol::SampleTransport::Socket
        };
        self.request(
            RequestBody::SubscribeSamples {
                outputs,
                max_rate_hz: VIEWER_RATE_HZ,
                max_image_width: Some(VIEWER_IMAGE_WIDTH),
                transport,
                shared_pixels: self.shared_memory && self.shared_pixels,
            },
            Pending::Samples,
        );
    }

    /// A subscription was accepted: with shared memory, start reading its services (or fall back to the
    /// socket when they cannot be read).
    fn samples_subscribed(&mut self, services: Option<BTreeMap<String, String>>) {
        let Some(services) = services else {
            return;
        };
        let Some(client) = &mut self.client else { return };
        if let Err(error) = client.receive_shared(services) {
            self.note(WARN_COLOR, format!("{error}; viewers use the socket instead"));
            self.shared_memory = false;
            self.subscribe_viewers();
        }
    }

    /// Whether viewer frames come through shared memory (a runtime on this machine) rather than the socket.
    pub fn uses_shared_memory(&self) -> bool {
        self.shared_memory
    }

    /// The log (filterable by level and component) or the monitoring panel.
    fn bottom_panel(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            ui.selectable_value(&mut self.bottom_tab, BottomTab::Log, "Log");
            ui.selectable_value(&mut self.bottom_tab, BottomTab::Monitor, "Monitor");
            if self.bottom_tab == BottomTab::Log {
                ui.separator();
                egui::ComboBox::from_id_salt("log level")
                    .selected_text(format!("{:?} and above", self.log_level))
                    .show_ui(ui, |ui| {
                        for level in [LogLevel::Debug, LogLevel::Info, LogLevel::Warn, LogLevel::Error] {
                            ui.selectable_value(&mut self.log_level, level, format!("{level:?} and above"));
                        }
                    });
                let mut components: Vec<String> =
                    self.log.iter().filter_map(|l| l.component.clone()).collect();
                components.sort();
                components.dedup();
                egui::ComboBox::from_id_salt("log component")
                    .selected_text(self.log_component.as_deref().unwrap_or("all components"))
                    .show_ui(ui, |ui| {
                        ui.selectable_value(&mut self.log_component, None, "all components");
                        for component in components {
                            let label = component.clone();
                            ui.selectable_value(&mut self.log_component, Some(component), label);
                        }
                    });
            }
        });
        match self.bottom_tab {
            BottomTab::Log => {
                egui::ScrollArea::vertical().stick_to_bottom(true).show(ui, |ui| {
                    for line in self.log.iter().filter(|l| {
                        l.level >= self.log_level
                            && self
                                .log_component
                                .as_ref()
                                .is_none_or(|c| l.component.as_ref() == Some(c))
                    }) {
                        ui.colored_label(line.color, &line.text);
                    }
                });
            }
            BottomTab::Monitor => self.monitor.panel(ui),
        }
    }

    /// One frame of the whole window (also what the interface tests drive).
    pub fn show(&mut self, ui: &mut egui::Ui) {
        let ctx = ui.ctx().clone();
        self.poll_runtime();
        self.describe_instances();
        self.shortcuts(&ctx);
        if ctx.input(|i| i.viewport().close_requested()) && !self.quitting && self.document.is_dirty() {
            ctx.send_viewport_cmd(egui::ViewportCommand::CancelClose);
            self.confirm = Some(AfterDiscard::Quit);
        }
        if self.quitting {
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        }
        let title = format!(
            "{}{} — Kairos studio",
            self.document
                .path()
                .map_or_else(|| "untitled".to_owned(), |p| p.display().to_string()),
            if self.document.is_dirty() { " •" } else { "" }
        );
        ctx.send_viewport_cmd(egui::ViewportCommand::Title(title));
        egui::Panel::top("menu").show(ui, |ui| self.menu_bar(ui));
        egui::Panel::left("palette")
            .default_size(210.0)
            .size_range(160.0..=400.0)
            .show(ui, |ui| self.palette(ui));
        // Bounded, so selecting a component whose properties are wide does not resize (and move) the canvas.
        egui::Panel::right("inspector")
            .default_size(300.0)
            .size_range(220.0..=520.0)
            .show(ui, |ui| self.inspector(ui));
        if self.viewers.any_docked() {
            egui::Panel::right("viewers")
                .default_size(470.0)
                .size_range(300.0..=900.0)
                .show(ui, |ui| self.viewers.show_docked(ui));
        }
        egui::Panel::bottom("log")
            .default_size(150.0)
            .size_range(60.0..=500.0)
            .show(ui, |ui| self.bottom_panel(ui));
        if crate::transport::has_controls(&self.monitor) {
            let requests = egui::Panel::bottom("transport")
                .show(ui, |ui| self.transport.show(ui, &self.monitor))
                .inner;
            for request in requests {
                self.request(request, Pending::Other);
            }
        }
        let canvas_rect = egui::CentralPanel::default()
            .show(ui, |ui| {
                self.canvas
                    .show(ui, &mut self.document, &self.library, &self.states, &self.monitor);
                if let Some((port, kind)) = self.canvas.take_viewer_request() {
                    self.viewers.open_kind(port.to_string(), kind);
                }
            })
            .response
            .rect;
        self.monitor.show_notices(&ctx, canvas_rect);
        self.viewers.show_floating(&ctx);
        if self.viewers.take_changed() {
            self.subscribe_viewers();
        }
        self.dialogs(&ctx);
    }
}

impl eframe::App for StudioApp {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        self.show(ui);
    }
}
