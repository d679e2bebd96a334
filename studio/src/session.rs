//! The studio's state without a window: the edited document, the runtime's library, the session with the
//! runtime (connection, run state, each component's state, requests in flight, deploy bookkeeping), live
//! figures, viewers' data, the log and the remembered settings. Its methods take the runtime's events and
//! the user's commands and update the state; what must go to the runtime comes out as [`Effect`]s, which
//! the app hands to the connection (and tests read). Nothing here draws, so all of it is tested without a
//! window.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use kairos_diagram::{LibraryInfo, PortRef, ReaderPolicy, Value};
use kairos_protocol::{
    ComponentState, ComponentTelemetry, ErrorCode, LogLevel, ProtocolError, ReplyBody, Request, RequestBody,
    RuntimeState, SampleTransport, Telemetry, Welcome,
};

use crate::client::{Answer, ClientEvent, DroppedEvents};
use crate::document::Document;
use crate::log::{Log, Tone};
use crate::monitor::Monitor;
use crate::settings::Settings;
use crate::viewers::Viewers;

/// Subgraph instances as the studio described them from their files, and what from: the document's
/// folder, each instance's id and type, and how many component types the library had.
#[derive(Debug, Default)]
struct Subgraphs {
    key: (PathBuf, Vec<(String, String)>, usize),
    /// When each diagram file beside the document and each used subgraph file was last modified, as of
    /// the last look: a file edited elsewhere is described again.
    stamps: Vec<(PathBuf, Option<std::time::SystemTime>)>,
    /// When the files were last looked at (at most once a second).
    looked: Option<Instant>,
    infos: BTreeMap<String, kairos_diagram::ComponentInfo>,
    /// Each exposed output (`front.out`) → the inner output it is in the flat diagram the runtime runs
    /// (`front/overlay.out`): viewers subscribe to the one and show the other.
    outputs: BTreeMap<String, String>,
    /// Each exposed property (`front.edge_low`) → the inner properties it sets in the flat diagram
    /// (`front/edges`, `low`): a live change is sent to each.
    properties: BTreeMap<String, Vec<(String, String)>>,
    /// Each instance's inner components, their outputs and actions, ids inside it.
    inside: BTreeMap<String, Vec<kairos_diagram::subgraph::InnerPart>>,
}

/// How often the studio looks whether a subgraph file changed on disk.
const FILES_LOOKED_AT: Duration = Duration::from_secs(1);

/// When each diagram file in `folder` and each file `instances` use was last modified, sorted.
fn subgraph_stamps(
    folder: &Path,
    instances: &[(String, String)],
) -> Vec<(PathBuf, Option<std::time::SystemTime>)> {
    let beside = std::fs::read_dir(folder)
        .into_iter()
        .flatten()
        .map_while(Result::ok)
        .map(|entry| entry.path())
        .filter(|path| path.extension().is_some_and(|e| e == "ron"));
    let used = instances
        .iter()
        .filter(|(_, type_name)| kairos_diagram::is_subgraph_type(type_name))
        .map(|(_, type_name)| folder.join(type_name));
    let mut stamps: Vec<_> = beside
        .chain(used)
        .map(|path| {
            let modified = std::fs::metadata(&path).and_then(|m| m.modified()).ok();
            (path, modified)
        })
        .collect();
    stamps.sort();
    stamps.dedup();
    stamps
}

/// The diagram files in `folder` that expose something (subgraphs), but `document` itself: their
/// types (file names) and paths, by name.
fn subgraph_files(folder: &Path, document: Option<&Path>) -> Vec<(String, PathBuf)> {
    let document = document.and_then(|d| d.file_name()).map(|name| folder.join(name));
    let Ok(entries) = std::fs::read_dir(folder) else {
        return Vec::new();
    };
    let mut found: Vec<(String, PathBuf)> = entries
        .map_while(Result::ok)
        .map(|entry| entry.path())
        .filter(|path| path.extension().is_some_and(|e| e == "ron") && Some(path) != document.as_ref())
        .filter(|path| {
            // A quick look before parsing: only subgraphs have an `exposes` section.
            std::fs::read_to_string(path).is_ok_and(|text| {
                text.contains("exposes")
                    && kairos_diagram::parse(&text).is_ok_and(|p| p.diagram.exposes.is_some())
            })
        })
        .filter_map(|path| Some((path.file_name()?.to_str()?.to_owned(), path)))
        .collect();
    found.sort();
    found
}

/// The player of a diagram made to replay a recording.
const REPLAY_PLAYER: &str = "player";

/// Viewers get at most this many samples a second per output, always the latest.
const VIEWER_RATE_HZ: f64 = 30.0;
/// Wider images are sent scaled down by a whole factor.
const VIEWER_IMAGE_WIDTH: u32 = 1920;
/// The console sink, whose printed lines the Console tab shows.
const CONSOLE_TYPE: &str = "core.console";
/// How often telemetry comes (4 Hz).
const TELEMETRY_INTERVAL_MS: u64 = 250;
/// The first id of the session's requests; 1 is the connection's `hello`.
const FIRST_REQUEST_ID: u64 = 2;

/// How a component is doing, as the runtime reports it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum NodeState {
    /// Running its cycles.
    Running,
    /// Waiting (paused, idle, not started, stopped): the runtime's word for it.
    Waiting(String),
    /// Its stream ended.
    Finished,
    /// Failed, with the error.
    Failed(String),
    /// The runtime refused the diagram because of this component; the problems, one per line.
    Invalid(String),
}

impl NodeState {
    /// The state one telemetry entry reports.
    fn of(component: &ComponentTelemetry) -> NodeState {
        match (component.state, &component.error) {
            (ComponentState::Running, _) => NodeState::Running,
            (ComponentState::Finished, _) => NodeState::Finished,
            (_, Some(error)) => NodeState::Failed(error.clone()),
            (other, None) => NodeState::Waiting(other.word().to_owned()),
        }
    }
}

/// The topics of a ROS 2 graph as the runtime reached it through `router`, in `domain`.
#[derive(Debug)]
struct Ros2Graph {
    router: String,
    domain: i64,
    listing: Ros2Listing,
}

/// What the runtime said of a ROS 2 graph.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Ros2Listing {
    /// Its topics and services, by name.
    Graph(kairos_protocol::Ros2TopicList),
    /// Why it could not list them (the router out of reach), as it said it.
    Refused(String),
}

/// What a request in flight was for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Pending {
    /// The runtime's component library.
    Library,
    /// A description of the instances whose ports depend on their properties.
    Describe,
    /// A subscription to the viewers' sample frames.
    Samples,
    /// A deploy (of the text kept in `Deploy`).
    Deploy,
    /// The devices of the runtime's machine.
    Devices,
    /// The topics of a ROS 2 graph, as the runtime reaches it.
    Ros2Topics,
    /// A start: refused while some hosts' clocks are not locked, it may be asked again anyway.
    Start,
    /// What the runtime publishes to Foxglove (asked, or changed).
    Foxglove,
    /// Anything whose answer only matters when it is an error.
    Other,
}

/// What the session asks of the connection to the runtime.
#[derive(Debug, Clone, PartialEq)]
pub enum Effect {
    /// Send this request.
    Send(Request),
    /// Read viewer frames from these shared-memory services (output → service), in place of any read
    /// before; none: stop reading.
    ReadShared(BTreeMap<String, String>),
}

/// The runtime the session drives.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RuntimeLink {
    /// How the studio names it (`local runtime ws://127.0.0.1:PORT`).
    pub label: String,
    /// Whether it accepted the session.
    pub connected: bool,
}

/// How viewer frames come from the runtime.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum FramePath {
    /// Through the socket (a remote runtime, or shared memory failed).
    Socket,
    /// In shared memory: the runtime is on this machine.
    SharedMemory,
    /// In shared memory, images as references to the runtime's own pixel buffers, which this process may
    /// map: no copy at all on the runtime's side.
    SharedPixels,
}

/// The last deploy.
#[derive(Debug, Clone, Default)]
struct Deploy {
    /// The text deployed, to place the runtime's diagnostics on the nodes they concern.
    text: String,
    /// Whether to start once the deploy is accepted.
    start_after: bool,
}

/// One instance as its description depends on it.
#[derive(Debug, Clone, PartialEq)]
struct InstanceKey {
    id: String,
    type_name: String,
    properties: BTreeMap<String, Value>,
}

/// The instances last sent to be described, and whether the answer is awaited.
#[derive(Debug, Clone, Default)]
struct Described {
    instances: Vec<InstanceKey>,
    awaiting: bool,
}

/// What the command line asked for once the runtime's library is known.
#[derive(Debug, Clone, Default)]
struct Startup {
    /// Outputs (`component.port`) to open viewers on.
    views: Vec<String>,
    /// Whether to deploy and start the diagram.
    run: bool,
}

/// A connection's reader settings as the inspector edits them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReaderSettings {
    /// Its policy; `None`: the input's default.
    pub policy: Option<ReaderPolicy>,
    /// Its share of the output's buffer; `None`: the output's.
    pub buffer_size: Option<usize>,
    /// Keeps one sample in this many; `None`: every sample.
    pub subsampling: Option<u32>,
}

/// What a save did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Saved {
    /// Written (or failed, which the log says).
    Done,
    /// The document has no file yet: ask for one.
    NeedsPath,
}

/// The studio's state; see the module's documentation.
#[derive(Debug)]
pub struct Session {
    /// The diagram being edited.
    pub document: Document,
    /// The connected runtime's component library (the palette).
    pub library: LibraryInfo,
    /// Live figures from telemetry.
    pub monitor: Monitor,
    /// The open data viewers.
    pub viewers: Viewers,
    /// The log panel's lines.
    pub log: Log,
    /// What the diagram's console components printed.
    pub console: crate::console::Console,
    /// What is remembered between launches.
    pub settings: Settings,
    /// Problems the runtime found with ports (a refused deploy), shown on them until the next deploy.
    pub port_problems: BTreeMap<PortRef, String>,
    /// What the inspector says under a property's field (a value typed and refused or clamped), by
    /// component and property, until the property is set again.
    field_notes: BTreeMap<(String, String), String>,
    runtime: Option<RuntimeLink>,
    run_state: RuntimeState,
    /// The runtime clock, when a component disciplines it.
    clock: Option<kairos_protocol::ClockTelemetry>,
    /// With a diagram spread over hosts: each host's state and clock.
    hosts: Vec<kairos_protocol::HostTelemetry>,
    /// The devices of the runtime's machine, once asked (`None`: never asked, or asked of another
    /// runtime); `devices_asked` while a request is out.
    devices: Option<Vec<kairos_protocol::DeviceInfo>>,
    devices_asked: bool,
    /// The topics of the ROS 2 graph last asked for (its router and domain, and what the runtime said),
    /// and the one being asked for.
    ros2_graph: Option<Ros2Graph>,
    ros2_asking: Option<(String, i64)>,
    states: BTreeMap<String, NodeState>,
    next_request: u64,
    pending: BTreeMap<u64, Pending>,
    deploy: Deploy,
    /// The diagram the runtime holds, as deployed and changed live since.
    deployed: Option<kairos_diagram::Diagram>,
    described: Described,
    /// The subgraph instances described from their files, and what that description was made from.
    subgraphs: Subgraphs,
    startup: Startup,
    frames: FramePath,
    effects: Vec<Effect>,
    /// Dropped events as last reported.
    dropped: DroppedEvents,
    /// Why the last start was refused, when it was for hosts' clocks not locked: "Start anyway" offers
    /// to start regardless.
    unlocked_refusal: Option<String>,
    /// How close to their master the hosts' clocks must be for a start of a diagram spread over hosts to
    /// go ahead; `None`: the runtime's default (1 ms).
    lock_bound: Option<Duration>,
    /// What the runtime publishes to Foxglove, as it last said.
    foxglove: kairos_protocol::FoxgloveState,
    /// The runtime's host as its address names it (`robot`), when it runs on another machine.
    remote_host: Option<String>,
}

/// What the runtime's refusal says when hosts' clocks are not locked (`deploy::check_clocks`).
const CLOCKS_NOT_LOCKED: &str = "clock is locked to its master";

/// The host of a runtime's address (`ws://robot:7400` gives `robot`).
fn host_of(url: &str) -> Option<String> {
    let rest = url.split_once("://").map_or(url, |(_, rest)| rest);
    let authority = rest.split('/').next()?;
    let host = match authority.rsplit_once(':') {
        Some((host, port)) if port.chars().all(|c| c.is_ascii_digit()) => host,
        _ => authority,
    };
    (!host.is_empty()).then(|| host.trim_matches(['[', ']']).to_owned())
}

fn join(outputs: &[&String]) -> String {
    outputs.iter().map(|o| o.as_str()).collect::<Vec<_>>().join(", ")
}

/// Whether a count going from `before` to `now` passed 1, 2, 4, 8 ...: when a growing count is worth a
/// line in the log.
fn passed_power_of_two(before: u64, now: u64) -> bool {
    now > before && (before == 0 || now.ilog2() > before.ilog2())
}

impl Session {
    /// A session editing `document`, with `library` as the palette until a runtime sends its own; no
    /// runtime yet.
    pub fn new(document: Document, library: LibraryInfo, settings: Settings) -> Session {
        Session {
            document,
            library,
            monitor: Monitor::default(),
            viewers: Viewers::default(),
            log: Log::default(),
            console: crate::console::Console::default(),
            settings,
            port_problems: BTreeMap::new(),
            field_notes: BTreeMap::new(),
            unlocked_refusal: None,
            lock_bound: None,
            foxglove: kairos_protocol::FoxgloveState::default(),
            remote_host: None,
            runtime: None,
            run_state: RuntimeState::Empty,
            clock: None,
            hosts: Vec::new(),
            devices: None,
            devices_asked: false,
            ros2_graph: None,
            ros2_asking: None,
            states: BTreeMap::new(),
            next_request: FIRST_REQUEST_ID,
            pending: BTreeMap::new(),
            deploy: Deploy::default(),
            deployed: None,
            described: Described::default(),
            subgraphs: Subgraphs::default(),
            startup: Startup::default(),
            frames: FramePath::Socket,
            effects: Vec::new(),
            dropped: DroppedEvents::default(),
        }
    }

    /// A line of the studio's own in the log.
    pub fn note(&mut self, level: LogLevel, text: impl Into<String>) {
        self.log.studio(level, Tone::Plain, text);
    }

    /// A success of the studio's own in the log.
    pub fn succeeded(&mut self, text: impl Into<String>) {
        self.log.studio(LogLevel::Info, Tone::Success, text);
    }

    /// The runtime the session drives, if any.
    pub fn runtime(&self) -> Option<&RuntimeLink> {
        self.runtime.as_ref()
    }

    /// Whether the runtime accepted the session.
    pub fn is_connected(&self) -> bool {
        self.runtime.as_ref().is_some_and(|r| r.connected)
    }

    /// Where the runtime is, as its telemetry last said.
    pub fn run_state(&self) -> RuntimeState {
        self.run_state
    }

    /// The devices of the runtime's machine, once the runtime has said.
    pub fn devices(&self) -> Option<&[kairos_protocol::DeviceInfo]> {
        self.devices.as_deref()
    }

    /// Asks the runtime for its devices (again); one request at a time.
    pub fn refresh_devices(&mut self) {
        if !self.devices_asked {
            self.devices_asked = true;
            self.request_for(RequestBody::Devices, Pending::Devices);
        }
    }

    /// The topics of the ROS 2 graph reached through `router` in `domain`, once the runtime has said.
    pub fn ros2_topics(&self, router: &str, domain: i64) -> Option<&Ros2Listing> {
        self.ros2_graph
            .as_ref()
            .filter(|graph| graph.router == router && graph.domain == domain)
            .map(|graph| &graph.listing)
    }

    /// Asks the runtime for the topics of the ROS 2 graph reached through `router` in `domain` (again);
    /// one request at a time.
    pub fn refresh_ros2_topics(&mut self, router: String, domain: i64) {
        if self.ros2_asking.is_none() {
            self.ros2_asking = Some((router.clone(), domain));
            self.request_for(
                RequestBody::Ros2Topics {
                    router,
                    domain_id: domain,
                },
                Pending::Ros2Topics,
            );
        }
    }

    /// The runtime clock, when a component of the running diagram disciplines it.
    pub fn clock(&self) -> Option<&kairos_protocol::ClockTelemetry> {
        self.clock.as_ref()
    }

    /// The hosts of the running spread diagram, with their state and clock.
    pub fn hosts(&self) -> &[kairos_protocol::HostTelemetry] {
        &self.hosts
    }

    /// A component's state as the runtime last reported it.
    pub fn node_state(&self, id: &str) -> Option<&NodeState> {
        self.states.get(id)
    }

    /// Every component's state as the runtime last reported it.
    pub fn node_states(&self) -> &BTreeMap<String, NodeState> {
        &self.states
    }

    /// The document for the canvas to edit, and what the canvas shows besides it.
    pub fn canvas_view(&mut self) -> (&mut Document, crate::canvas::Shown<'_>) {
        (
            &mut self.document,
            crate::canvas::Shown {
                library: &self.library,
                states: &self.states,
                monitor: &self.monitor,
                port_problems: &self.port_problems,
                foxglove: &self.foxglove,
            },
        )
    }

    /// Whether viewer frames come through shared memory (a runtime on this machine) rather than the socket.
    pub fn uses_shared_memory(&self) -> bool {
        self.frames != FramePath::Socket
    }

    /// What the connection must do, in order, since the last call.
    pub fn take_effects(&mut self) -> Vec<Effect> {
        std::mem::take(&mut self.effects)
    }

    /// A new connection to the runtime `label` at `url` is being made: everything known of the previous
    /// one is forgotten.
    pub fn connecting(&mut self, label: String, url: &str) {
        self.runtime = Some(RuntimeLink {
            label,
            connected: false,
        });
        self.pending.clear();
        self.states.clear();
        self.run_state = RuntimeState::Empty;
        self.frames = FramePath::Socket;
        self.dropped = DroppedEvents::default();
        self.foxglove = kairos_protocol::FoxgloveState::default();
        self.remote_host = host_of(url);
        self.note(LogLevel::Info, format!("connecting to {url}"));
    }

    /// Opens viewers on `views` (`component.port`) and, with `run`, deploys and starts the diagram, as soon
    /// as the runtime's library is known.
    pub fn set_startup(&mut self, views: Vec<String>, run: bool) {
        self.startup = Startup { views, run };
    }

    /// Sends a request whose answer matters only when it is an error.
    pub fn request(&mut self, body: RequestBody) {
        self.request_for(body, Pending::Other);
    }

    fn request_for(&mut self, body: RequestBody, pending: Pending) {
        if self.runtime.is_none() {
            self.note(LogLevel::Error, "no runtime connected");
            return;
        }
        let id = self.next_request;
        self.next_request += 1;
        self.pending.insert(id, pending);
        self.effects.push(Effect::Send(Request { id, body }));
    }

    /// Takes in one event of the connection.
    pub fn handle(&mut self, event: ClientEvent) {
        match event {
            ClientEvent::Connected(welcome) => self.connected(&welcome),
            ClientEvent::Reply(reply) => self.take_reply(reply),
            ClientEvent::Telemetry(telemetry) => self.take_telemetry(&telemetry),
            ClientEvent::Log(record) => self.take_log(record),
            ClientEvent::Sample(mut header, payload) => {
                // A subgraph's exposed output, as its viewers name it.
                if let Some((exposed, _)) = self
                    .subgraphs
                    .outputs
                    .iter()
                    .find(|(_, inner)| **inner == header.output)
                {
                    header.output.clone_from(exposed);
                }
                self.viewers.receive(&header, &payload);
            }
            ClientEvent::SharedMemory(Ok(())) => {}
            ClientEvent::SharedMemory(Err(error)) => self.socket_instead(&error.to_string()),
            ClientEvent::Disconnected(reason) => {
                if let Some(runtime) = &mut self.runtime {
                    runtime.connected = false;
                }
                self.note(LogLevel::Error, reason);
            }
        }
    }

    /// A log record: a console component's printed line goes to the Console, anything else to the log.
    fn take_log(&mut self, record: kairos_protocol::LogRecord) {
        let from_console = record.component.as_deref().is_some_and(|id| {
            self.document
                .diagram()
                .component(id)
                .is_some_and(|c| c.type_name == CONSOLE_TYPE)
        });
        match record.component {
            Some(component) if from_console && record.level == LogLevel::Info => {
                self.console.push(crate::console::ConsoleLine {
                    at_ns: record.at_ns,
                    component,
                    text: record.message,
                });
            }
            component => self
                .log
                .record(kairos_protocol::LogRecord { component, ..record }),
        }
    }

    /// Says in the log when the connection dropped events because the studio fell behind: each time log
    /// records were lost, and at the 1st, 2nd, 4th ... lost sample frame or telemetry event.
    pub fn report_dropped(&mut self, now: DroppedEvents) {
        let before = std::mem::replace(&mut self.dropped, now);
        if now.log > before.log {
            self.note(
                LogLevel::Warn,
                format!(
                    "the studio fell behind: {} of the runtime's log records were dropped",
                    now.log - before.log
                ),
            );
        }
        if passed_power_of_two(before.samples, now.samples) {
            self.note(
                LogLevel::Debug,
                format!(
                    "the studio fell behind: {} sample frames were dropped so far (viewers show the next)",
                    now.samples
                ),
            );
        }
        if passed_power_of_two(before.telemetry, now.telemetry) {
            self.note(
                LogLevel::Debug,
                format!(
                    "the studio fell behind: {} telemetry events were dropped so far",
                    now.telemetry
                ),
            );
        }
    }

    fn connected(&mut self, welcome: &Welcome) {
        if let Some(runtime) = &mut self.runtime {
            runtime.connected = true;
        }
        let same_host = welcome.shared_memory_host.is_some()
            && welcome.shared_memory_host == kairos_protocol::this_host();
        let pixels = welcome
            .pid
            .is_some_and(kairos_protocol::shared_pixels::can_map_buffers_of);
        if same_host {
            self.remote_host = None;
        }
        self.frames = match (same_host, pixels) {
            (false, _) => FramePath::Socket,
            (true, false) => FramePath::SharedMemory,
            (true, true) => FramePath::SharedPixels,
        };
        self.succeeded(format!("connected to {} ({:?})", welcome.server, welcome.role));
        self.request_for(RequestBody::Library, Pending::Library);
        // Another runtime, maybe another machine: its devices are asked for when a picker needs them.
        self.devices = None;
        self.devices_asked = false;
        self.ros2_graph = None;
        self.ros2_asking = None;
        self.request(RequestBody::SubscribeTelemetry {
            interval_ms: TELEMETRY_INTERVAL_MS,
        });
        self.request(RequestBody::SubscribeLog {
            level: LogLevel::Info,
        });
        self.request_for(RequestBody::Foxglove, Pending::Foxglove);
    }

    /// What the runtime publishes to Foxglove.
    pub fn foxglove(&self) -> &kairos_protocol::FoxgloveState {
        &self.foxglove
    }

    /// Publishes `output` live to Foxglove, or stops (the runtime starts its Foxglove server on loopback
    /// the first time).
    pub fn publish_to_foxglove(&mut self, output: &str, publish: bool) {
        self.request_for(
            RequestBody::FoxglovePublish {
                outputs: vec![output.to_owned()],
                publish,
            },
            Pending::Foxglove,
        );
    }

    /// The runtime's answer about Foxglove: the log says what changed, and where to connect.
    fn foxglove_changed(&mut self, now: kairos_protocol::FoxgloveState) {
        let before = std::mem::replace(&mut self.foxglove, now);
        let address = self.foxglove.address.clone().unwrap_or_default();
        let added: Vec<&String> = self
            .foxglove
            .outputs
            .iter()
            .filter(|o| !before.outputs.contains(o))
            .collect();
        let removed: Vec<&String> = before
            .outputs
            .iter()
            .filter(|o| !self.foxglove.outputs.contains(o))
            .collect();
        let mut lines = Vec::new();
        if !added.is_empty() {
            let port = address.rsplit(':').next().unwrap_or("8765");
            let reach = match &self.remote_host {
                // The runtime's loopback is not this machine's.
                Some(host) if address.starts_with("ws://127.") => format!(
                    " It listens on the runtime's machine, on loopback: forward it first (ssh -L \
                     {port}:127.0.0.1:{port} {host}), then open ws://127.0.0.1:{port} in Foxglove."
                ),
                _ => " In Foxglove, open a connection (Foxglove WebSocket) to that address.".to_owned(),
            };
            lines.push(format!(
                "Foxglove: publishing {} on {address}.{reach}",
                join(&added)
            ));
        }
        if !removed.is_empty() {
            lines.push(format!("Foxglove: no longer publishing {}", join(&removed)));
        }
        for line in lines {
            self.succeeded(line);
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
        match what {
            Some(Pending::Deploy) if !error.diagnostics.is_empty() => {
                let by_component =
                    crate::document::diagnostics_by_component(&self.deploy.text, &error.diagnostics);
                for (id, problems) in by_component {
                    self.states.insert(id, NodeState::Invalid(problems.join("\n")));
                }
                self.port_problems =
                    crate::document::diagnostics_by_port(&self.deploy.text, &error.diagnostics)
                        .into_iter()
                        .map(|(port, problems)| (port, problems.join("\n")))
                        .collect();
            }
            // An output the runtime does not have is not a failure of shared memory.
            Some(Pending::Samples) if error.code == ErrorCode::NotFound => {
                self.note(
                    LogLevel::Warn,
                    format!(
                        "{}; its viewer shows it once a diagram that has it runs",
                        error.message
                    ),
                );
                return;
            }
            Some(Pending::Samples) if self.uses_shared_memory() => {
                self.socket_instead(&error.message);
                return;
            }
            Some(Pending::Devices) => {
                // A runtime that cannot list its devices: the pickers say there are none.
                self.devices_asked = false;
                self.devices = Some(Vec::new());
            }
            Some(Pending::Ros2Topics) => {
                // Said beside the picker, and in the log.
                if let Some((router, domain)) = self.ros2_asking.take() {
                    self.ros2_graph = Some(Ros2Graph {
                        router,
                        domain,
                        listing: Ros2Listing::Refused(error.message.clone()),
                    });
                }
            }
            Some(Pending::Start) if error.message.contains(CLOCKS_NOT_LOCKED) => {
                self.unlocked_refusal = Some(error.message.clone());
            }
            Some(Pending::Describe) => {
                // A diagram the runtime cannot parse yet: the editor keeps the type's ports.
                self.described.awaiting = false;
                self.start_up();
                return;
            }
            _ => {}
        }
        self.note(LogLevel::Error, error.message);
        self.deploy.start_after = false;
    }

    /// The result of a request of ours, of that request's type.
    fn take_result(&mut self, what: Option<Pending>, result: ReplyBody) {
        match (what, result) {
            (Some(Pending::Library), ReplyBody::Library(library)) => {
                self.library = library;
                self.described = Described::default();
                self.describe_instances();
                if !self.described.awaiting {
                    self.start_up();
                }
            }
            (Some(Pending::Samples), ReplyBody::SubscribeSamples(subscribed)) => {
                // A subscription through the socket names no services.
                if let Some(services) = subscribed.services {
                    self.effects.push(Effect::ReadShared(services));
                }
            }
            (Some(Pending::Foxglove), ReplyBody::FoxglovePublish(state) | ReplyBody::Foxglove(state)) => {
                self.foxglove_changed(state);
            }
            (Some(Pending::Devices), ReplyBody::Devices(list)) => {
                self.devices_asked = false;
                self.devices = Some(list.devices);
            }
            (Some(Pending::Ros2Topics), ReplyBody::Ros2Topics(list)) => {
                if let Some((router, domain)) = self.ros2_asking.take() {
                    self.ros2_graph = Some(Ros2Graph {
                        router,
                        domain,
                        listing: Ros2Listing::Graph(list),
                    });
                }
            }
            (Some(Pending::Describe), ReplyBody::DescribeInstances(described)) => {
                self.described.awaiting = false;
                self.library.instances = described.instances;
                // The runtime does not read subgraph files: the studio's descriptions of them stay.
                self.library.instances.extend(self.subgraphs.infos.clone());
                for (id, problem) in described.problems {
                    self.note(LogLevel::Error, format!("{id}: {}", problem.message));
                }
                self.start_up();
            }
            (Some(Pending::Deploy), ReplyBody::Deploy(_)) => {
                self.deployed = kairos_diagram::parse(&self.deploy.text).ok().map(|p| p.diagram);
                self.states.clear();
                self.monitor.clear();
                self.run_state = RuntimeState::Ready;
                self.subscribe_viewers();
                self.port_problems.clear();
                self.succeeded("deployed");
                self.unlocked_refusal = None;
                if std::mem::take(&mut self.deploy.start_after) {
                    self.request_for(
                        RequestBody::Start {
                            at_ns: None,
                            forced: None,
                            start_unlocked: false,
                            lock_bound_ns: self.lock_bound_ns(),
                        },
                        Pending::Start,
                    );
                }
            }
            _ => {}
        }
    }

    /// Node states and live figures from one telemetry event.
    fn take_telemetry(&mut self, telemetry: &Telemetry) {
        self.run_state = telemetry.state;
        self.clock.clone_from(&telemetry.clock);
        self.hosts.clone_from(&telemetry.hosts);
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
            .map(|c| (c.id.clone(), NodeState::of(c)))
            .collect();
        self.states.extend(refused);
        for (level, notice) in self.monitor.update(telemetry) {
            self.note(level, notice);
        }
        // A subgraph instance shows the state of its parts.
        for (id, rolled) in &self.monitor.subgraphs {
            self.states
                .entry(id.clone())
                .or_insert_with(|| NodeState::of(rolled));
        }
    }

    /// How close to their master hosts' clocks must be for a start to go ahead; `None`: the runtime's
    /// default (1 ms).
    pub fn lock_bound(&self) -> Option<Duration> {
        self.lock_bound
    }

    /// Sets the lock bound the next starts ask for.
    pub fn set_lock_bound(&mut self, bound: Duration) {
        self.lock_bound = Some(bound);
    }

    fn lock_bound_ns(&self) -> Option<u64> {
        self.lock_bound
            .map(|bound| u64::try_from(bound.as_nanos()).unwrap_or(u64::MAX))
    }

    /// Why the last start was refused when some hosts' clocks were not locked: the studio then offers
    /// to start anyway.
    pub fn unlocked_refusal(&self) -> Option<&str> {
        self.unlocked_refusal.as_deref()
    }

    /// Starts the deployed diagram although some hosts' clocks are not locked (every recording says so).
    pub fn start_unlocked(&mut self) {
        if self.unlocked_refusal.take().is_some() {
            self.note(
                LogLevel::Warn,
                "starting with hosts' clocks not locked, as asked: the recordings say so".to_owned(),
            );
            self.request_for(
                RequestBody::Start {
                    at_ns: None,
                    forced: None,
                    start_unlocked: true,
                    lock_bound_ns: self.lock_bound_ns(),
                },
                Pending::Start,
            );
        }
    }

    /// Deploys the document and starts it once the runtime accepts it.
    pub fn deploy_and_start(&mut self) {
        // Token files, certificates and subgraph files beside the diagram, when the runtime sees this
        // machine's files.
        let folder = (self.frames != FramePath::Socket)
            .then(|| self.document.path().and_then(Path::parent))
            .flatten()
            .map(Path::to_owned);
        let mut text = self.document.diagram().to_ron();
        // A runtime that cannot read the subgraph files (on another machine) is sent the diagram flat.
        let shipped = &self.library.subgraphs;
        let uses_subgraphs =
            (self.document.diagram().components.iter()).any(|c| self.library.names_subgraph(&c.type_name));
        if folder.is_none() && uses_subgraphs {
            let file = self
                .document
                .path()
                .map_or_else(|| PathBuf::from("untitled.ron"), Path::to_owned);
            let parsed = kairos_diagram::parse(&text)
                .map_err(|problems| problems.iter().map(ToString::to_string).collect::<Vec<_>>());
            let flat = parsed.and_then(|parsed| {
                let mut read =
                    kairos_diagram::subgraph::from_files(kairos_diagram::subgraph::MAX_SUBGRAPH_READS);
                let mut sources = kairos_diagram::Sources {
                    read: &mut read,
                    shipped,
                };
                kairos_diagram::flatten_from(parsed, &file, &mut sources)
                    .map_err(|problems| problems.iter().map(ToString::to_string).collect())
            });
            match flat {
                Ok(flat) => text = flat.parsed.diagram.to_ron(),
                Err(problems) => {
                    for problem in problems {
                        self.note(LogLevel::Error, problem);
                    }
                    return;
                }
            }
        }
        self.deploy = Deploy {
            text,
            start_after: true,
        };
        self.request_for(
            RequestBody::Deploy {
                diagram: self.deploy.text.clone(),
                network: None,
                folder: folder.map(|folder| folder.display().to_string()),
            },
            Pending::Deploy,
        );
    }

    /// Asks the runtime to describe the instances whose ports depend on their properties (a player's
    /// outputs), whenever components or their properties changed since the last answer.
    pub fn describe_instances(&mut self) {
        if !self.is_connected() || self.described.awaiting {
            return;
        }
        let instances: Vec<InstanceKey> = self
            .document
            .diagram()
            .components
            .iter()
            .map(|c| InstanceKey {
                id: c.id.clone(),
                type_name: c.type_name.clone(),
                properties: c.properties.clone(),
            })
            .collect();
        if instances == self.described.instances {
            return;
        }
        self.described = Described {
            instances,
            awaiting: true,
        };
        self.request_for(
            RequestBody::DescribeInstances {
                diagram: self.document.diagram().to_ron(),
            },
            Pending::Describe,
        );
    }

    /// The folder of the document's file, where its subgraph files are: the working folder for a
    /// document not saved yet or opened by a bare file name.
    pub fn document_folder(&self) -> PathBuf {
        self.document
            .path()
            .and_then(Path::parent)
            .filter(|folder| !folder.as_os_str().is_empty())
            .map_or_else(|| PathBuf::from("."), Path::to_owned)
    }

    /// Describes each subgraph instance (a component whose type is a diagram file) from its file, read
    /// beside the document, whenever the instances, the document's file or the library changed: the
    /// canvas then shows its exposed ports and the inspector its exposed properties. A subgraph that
    /// cannot be described is said in the log once.
    pub fn describe_subgraphs(&mut self) {
        if self.library.components.is_empty() {
            return;
        }
        let folder = self.document_folder();
        let instances: Vec<(String, String)> = self
            .document
            .diagram()
            .components
            .iter()
            .filter(|c| self.library.names_subgraph(&c.type_name))
            .map(|c| (c.id.clone(), c.type_name.clone()))
            .collect();
        let packs_components = self
            .library
            .components
            .keys()
            .filter(|t| !self.library.names_subgraph(t))
            .count();
        let key = (folder.clone(), instances, packs_components);
        if key == self.subgraphs.key {
            if self
                .subgraphs
                .looked
                .is_some_and(|at| at.elapsed() < FILES_LOOKED_AT)
            {
                return;
            }
            self.subgraphs.looked = Some(Instant::now());
            if subgraph_stamps(&folder, &key.1) == self.subgraphs.stamps {
                return;
            }
        }
        let stamps = subgraph_stamps(&folder, &key.1);
        for id in self.subgraphs.infos.keys() {
            self.library.instances.remove(id);
        }
        let subgraphs = &self.library.subgraphs;
        self.library.components.retain(|type_name, _| {
            !kairos_diagram::is_subgraph_type(type_name) && !subgraphs.contains_key(type_name)
        });
        // Each subgraph described once, whether the palette offers it, instances use it, or both.
        let mut described: BTreeMap<
            String,
            Result<kairos_diagram::subgraph::Described, kairos_diagram::subgraph::DescribeSubgraphError>,
        > = BTreeMap::new();
        let mut describe = |type_name: &str, path: &Path, library: &LibraryInfo| {
            described
                .entry(type_name.to_owned())
                .or_insert_with(|| kairos_diagram::subgraph::describe(path, type_name, library))
                .clone()
        };
        // The palette offers the subgraphs beside the diagram (files there that expose something) and
        // those the packs ship.
        let mut offered = subgraph_files(&folder, self.document.path());
        offered.extend(self.library.subgraphs.keys().map(|t| (t.clone(), PathBuf::new())));
        for (type_name, path) in offered {
            if let Ok(described) = describe(&type_name, &path, &self.library) {
                let mut info = described.info;
                if let Some((pack, _)) = type_name.split_once('.').filter(|_| path.as_os_str().is_empty()) {
                    pack.clone_into(&mut info.pack);
                }
                self.library.components.insert(type_name, info);
            }
        }
        let mut infos = BTreeMap::new();
        let mut outputs = BTreeMap::new();
        let mut properties = BTreeMap::new();
        let mut inside = BTreeMap::new();
        let mut problems = Vec::new();
        for (id, type_name) in &key.1 {
            match describe(type_name, &folder.join(type_name), &self.library) {
                Ok(described) => {
                    let exposes = described.exposes;
                    infos.insert(id.clone(), described.info);
                    inside.insert(id.clone(), described.inside);
                    for (name, inner) in exposes.outputs {
                        outputs.insert(
                            format!("{id}.{name}"),
                            format!("{id}/{}.{}", inner.component, inner.port),
                        );
                    }
                    for (name, targets) in exposes.properties {
                        let flat = targets
                            .into_iter()
                            .map(|t| (format!("{id}/{}", t.component), t.port))
                            .collect();
                        properties.insert(format!("{id}.{name}"), flat);
                    }
                }
                Err(why) => problems.push(format!("{id}: subgraph {type_name}: {why}")),
            }
        }
        self.library.instances.extend(infos.clone());
        self.subgraphs = Subgraphs {
            key,
            stamps,
            looked: Some(Instant::now()),
            infos,
            outputs,
            properties,
            inside,
        };
        for problem in problems {
            self.note(LogLevel::Warn, problem);
        }
    }

    /// The components inside the subgraph instance `id` (their ids inside it), with their outputs'
    /// types and their actions: what the inspector offers to view and trigger inside.
    pub fn inside_subgraph(&self, id: &str) -> &[kairos_diagram::subgraph::InnerPart] {
        self.subgraphs.inside.get(id).map_or(&[], Vec::as_slice)
    }

    /// Writes the components `ids` to a new subgraph file at `path` and puts one instance of it in their
    /// place, the links that crossed rewired to its exposed ports: one edit, undone as one (the file
    /// stays). Returns the instance's id; a refusal is said in the log.
    pub fn make_subgraph(&mut self, ids: &[String], path: &Path) -> Option<String> {
        let stem = path
            .file_stem()
            .map(|s| {
                s.to_string_lossy()
                    .replace(|c: char| !c.is_ascii_alphanumeric() && c != '_', "_")
            })
            .filter(|s| !s.is_empty())
            .unwrap_or_else(|| "subgraph".to_owned());
        let instance = crate::document::fresh_id(self.document.diagram(), &stem);
        // Named from the diagram's folder, as a subgraph's type is; a file elsewhere by its full path.
        let folder = self
            .document
            .path()
            .and_then(Path::parent)
            .unwrap_or_else(|| Path::new(""));
        let type_name = path
            .strip_prefix(folder)
            .ok()
            .filter(|_| !folder.as_os_str().is_empty())
            .unwrap_or(path)
            .display()
            .to_string();
        let made = kairos_diagram::subgraph::extract(self.document.diagram(), ids, &instance, &type_name);
        let (subgraph, outer) = match made {
            Ok(made) => made,
            Err(why) => {
                self.note(LogLevel::Warn, format!("no subgraph made: {why}"));
                return None;
            }
        };
        if let Err(error) = std::fs::write(path, subgraph.to_ron()) {
            self.note(
                LogLevel::Error,
                format!("cannot write {}: {error}", path.display()),
            );
            return None;
        }
        self.document.edit(|diagram| *diagram = outer);
        self.note(
            LogLevel::Info,
            format!(
                "{} components are now subgraph {} ('{instance}'); double-click it to go inside; Undo puts \
                 them back (the file stays)",
                ids.len(),
                path.display()
            ),
        );
        Some(instance)
    }

    /// A diagram replaying `file`, which `recorder` wrote: a player on it, held at its end so that it
    /// can be sought back, and each open viewer of an output the recorder took, on the player's output
    /// for it.
    pub fn replay_diagram(&mut self, recorder: &str, file: &str) -> kairos_diagram::Diagram {
        let diagram = self.document.diagram();
        let inputs: Vec<String> = diagram
            .connections
            .iter()
            .filter(|c| c.to.component == recorder)
            .map(|c| c.from.to_string())
            .collect();
        let on_player =
            |output: &String| format!("{REPLAY_PLAYER}.{}", kairos_diagram::port_name_for_topic(output));
        let taken = |output: &String| inputs.contains(output);
        let viewers = self
            .viewers
            .specs()
            .into_iter()
            .filter(|v| taken(&v.output))
            .map(|mut viewer| {
                viewer.output = on_player(&viewer.output);
                viewer.also = viewer.also.iter().filter(|o| taken(o)).map(on_player).collect();
                viewer
            })
            .collect();
        let mut player = kairos_diagram::ComponentInstance::new(REPLAY_PLAYER, "recording.player");
        player.position = kairos_diagram::Position { x: 40.0, y: 40.0 };
        player.properties = BTreeMap::from([
            ("path".to_owned(), Value::Text(file.to_owned())),
            ("at_end".to_owned(), Value::Text("hold".to_owned())),
        ]);
        let packs = diagram
            .packs
            .iter()
            .filter(|p| p.name == "recording")
            .cloned()
            .collect();
        kairos_diagram::Diagram {
            packs,
            components: vec![player],
            viewers,
            ..kairos_diagram::Diagram::default()
        }
    }

    /// Every output of the diagram with the name of its type (`camera.image`, `image`), in diagram order.
    pub fn outputs_with_types(&self) -> Vec<(String, String)> {
        let diagram = self.document.diagram();
        diagram
            .components
            .iter()
            .filter_map(|c| self.library.component_of(c).map(|info| (c, info)))
            .flat_map(|(c, info)| {
                info.outputs.iter().filter_map(|o| {
                    let port = PortRef {
                        component: c.id.clone(),
                        port: o.name.clone(),
                    };
                    let data_type = self.document.output_type(&port, &self.library)?;
                    Some((format!("{}.{}", c.id, o.name), data_type.name().to_owned()))
                })
            })
            .collect()
    }

    /// The type of the output named `component.port`, when the diagram has it.
    fn output_type_named(&self, output: &str) -> Option<kairos_diagram::DataType> {
        PortRef::parse(output).and_then(|p| self.document.output_type(&p, &self.library))
    }

    /// What the command line asked for, once the library is known: viewers (`a.out+b.out` draws `b.out`
    /// over `a.out`'s viewer), and a run.
    fn start_up(&mut self) {
        // Subgraphs' exposed outputs are outputs to view too.
        self.describe_subgraphs();
        let Startup { views, run } = std::mem::take(&mut self.startup);
        for view in views {
            let mut outputs = view.split('+').map(str::to_owned);
            let Some(output) = outputs.next() else { continue };
            let Some(data_type) = self.output_type_named(&output) else {
                self.note(
                    LogLevel::Error,
                    format!(
                        "--view {output}: no such output in the diagram (outputs are named component.port)"
                    ),
                );
                continue;
            };
            // A viewer the diagram file reopened already shows it: in front, should it be a tab behind.
            let kind = crate::viewers::ViewerKind::for_type(data_type.name());
            if self.viewers.shows(&output, kind) {
                self.viewers.bring_to_front(&output, kind);
                continue;
            }
            self.viewers.open(output.clone(), data_type.name());
            let index = self.viewers.list.len() - 1;
            for over in outputs {
                let over_type = self.output_type_named(&over);
                let added =
                    over_type.is_some_and(|t| self.viewers.add_overlay(index, over.clone(), t.name()));
                if !added {
                    self.note(
                        LogLevel::Error,
                        format!(
                            "--view {view}: {over} cannot be drawn over {output} (a GNSS track takes more GNSS fixes, a 3D view boxes as a matrix of 6 columns)"
                        ),
                    );
                }
            }
        }
        if run {
            self.deploy_and_start();
        }
    }

    /// Asks the runtime for the samples of every output a viewer shows (and no others). Before a deployment
    /// there is nothing to subscribe to; deploying subscribes again.
    pub fn subscribe_viewers(&mut self) {
        if !self.is_connected() || self.run_state == RuntimeState::Empty {
            return;
        }
        self.request(RequestBody::UnsubscribeSamples { outputs: Vec::new() });
        // Only what the runtime runs: a viewer of a diagram not deployed yet (opened, or made to replay
        // a recording, while the last one is still deployed) subscribes once its diagram is.
        let deployed = self.deployed.as_ref();
        let flat = &self.subgraphs.outputs;
        let outputs: Vec<String> = self
            .viewers
            .outputs()
            .into_iter()
            .map(|output| flat.get(&output).cloned().unwrap_or(output))
            .filter(|output| {
                deployed.is_none_or(|diagram| {
                    // An inner output of a subgraph (`front/edges.out`) runs when its instance does.
                    PortRef::parse(output).is_some_and(|port| {
                        let instance = port.component.split('/').next().unwrap_or_default();
                        diagram.component(&port.component).is_some() || diagram.component(instance).is_some()
                    })
                })
            })
            .collect();
        if outputs.is_empty() {
            self.effects.push(Effect::ReadShared(BTreeMap::new()));
            return;
        }
        let transport = match self.frames {
            FramePath::Socket => SampleTransport::Socket,
            FramePath::SharedMemory | FramePath::SharedPixels => SampleTransport::SharedMemory,
        };
        self.request_for(
            RequestBody::SubscribeSamples {
                outputs,
                max_rate_hz: VIEWER_RATE_HZ,
                max_image_width: Some(VIEWER_IMAGE_WIDTH),
                transport,
                shared_pixels: self.frames == FramePath::SharedPixels,
            },
            Pending::Samples,
        );
    }

    /// Shared memory failed (`why`): viewers subscribe through the socket from now on.
    fn socket_instead(&mut self, why: &str) {
        if self.frames == FramePath::Socket {
            return;
        }
        self.note(LogLevel::Warn, format!("{why}; viewers use the socket instead"));
        self.frames = FramePath::Socket;
        self.subscribe_viewers();
    }

    /// Sets a component's property (one undoable edit); while the diagram runs, a live property whose value
    /// is valid changes in the runtime at once too.
    pub fn set_property(&mut self, component: &str, property: &str, value: Value) {
        self.field_notes
            .remove(&(component.to_owned(), property.to_owned()));
        self.document.edit(|d| {
            if let Some(c) = d.component_mut(component) {
                c.properties.insert(property.to_owned(), value.clone());
            }
        });
        let running = matches!(self.run_state, RuntimeState::Running | RuntimeState::Paused);
        let live = self
            .document
            .diagram()
            .component(component)
            .and_then(|c| self.library.component_of(c))
            .and_then(|info| info.properties.iter().find(|p| p.name == property))
            .is_some_and(|p| p.live && p.kind.check(&value).is_ok());
        if running && live {
            if let Some(c) = self.deployed.as_mut().and_then(|d| d.component_mut(component)) {
                c.properties.insert(property.to_owned(), value.clone());
            }
            // A subgraph's exposed property is each inner property it feeds, in the flat diagram run.
            let targets = self
                .subgraphs
                .properties
                .get(&format!("{component}.{property}"))
                .cloned()
                .unwrap_or_else(|| vec![(component.to_owned(), property.to_owned())]);
            let values = vec![value; targets.len()];
            for ((component, property), value) in targets.into_iter().zip(values) {
                self.request(RequestBody::SetProperty {
                    component,
                    property,
                    value,
                });
            }
        } else if running {
            self.note(
                LogLevel::Info,
                format!(
                    "{component}.{property} applies at the next run: it is not a live property \
                     (Restart applies it now)"
                ),
            );
        }
    }

    /// Renames a component (its connections follow, one undoable edit) and says so in the log; a name that
    /// is taken or no valid id is refused, said at the inspector's name field and in the log. What the
    /// fields said about the component moves to its new name.
    pub fn rename_component(&mut self, from: &str, to: &str) -> bool {
        match self.document.rename_component(from, to) {
            Ok(()) => {
                let to = to.trim();
                let notes = std::mem::take(&mut self.field_notes);
                self.field_notes = notes
                    .into_iter()
                    .filter(|((component, field), _)| !(component == from && field == "name"))
                    .map(|((component, field), note)| {
                        let component = if component == from {
                            to.to_owned()
                        } else {
                            component
                        };
                        ((component, field), note)
                    })
                    .collect();
                if from != to {
                    self.succeeded(format!("renamed {from} to {to}"));
                }
                true
            }
            Err(why) => {
                self.field_refused(from, "name", why.to_string());
                false
            }
        }
    }

    /// Exposes an inner port or property under `name` (or stops exposing it), one undoable edit; a
    /// refused name is said at its field in the inspector and in the log.
    pub fn set_exposed(&mut self, kind: kairos_diagram::ExposedKind, inner: &PortRef, name: Option<&str>) {
        let field = exposed_field(kind, &inner.port);
        match self.document.set_exposed(kind, inner, name) {
            Ok(()) => {
                self.field_notes.remove(&(inner.component.clone(), field));
                let said = match name {
                    Some(name) => format!("{} {inner} is exposed as '{}'", kind.name(), name.trim()),
                    None => format!("{} {inner} is no longer exposed", kind.name()),
                };
                self.succeeded(said);
            }
            Err(why) => {
                let key = (inner.component.clone(), field);
                let why = why.to_string();
                if self.field_notes.get(&key) != Some(&why) {
                    self.note(
                        LogLevel::Warn,
                        format!("{} {inner} not exposed: {why}", kind.name()),
                    );
                    self.field_notes.insert(key, why);
                }
            }
        }
    }

    /// A value typed for a property was refused or clamped: the inspector says `why` at the field, and the
    /// log keeps it.
    pub fn field_refused(&mut self, component: &str, property: &str, why: String) {
        let key = (component.to_owned(), property.to_owned());
        // The field reports once per edit, but a frame laid out twice reports twice.
        if self.field_notes.get(&key) == Some(&why) {
            return;
        }
        self.note(LogLevel::Warn, format!("{component}.{property}: {why}"));
        self.field_notes.insert(key, why);
    }

    /// Opens the viewers the document was saved with, in place of those open.
    pub fn restore_viewers(&mut self) {
        let viewers = self.document.diagram().viewers.clone();
        for kind in self.viewers.restore(&viewers) {
            self.note(
                LogLevel::Warn,
                format!("a viewer of kind '{kind}' saved in the diagram is unknown here: shown as a table"),
            );
        }
    }

    /// Puts the open viewers in the document, to be saved with it.
    fn keep_viewers_in_document(&mut self) {
        let open = self.viewers.specs();
        if open != self.document.diagram().viewers {
            self.document.set_viewers(open);
        }
    }

    /// Another document took this one's place (New, Open): what the fields said goes, and, unless the
    /// old diagram still runs (its telemetry is then still current), what its run showed.
    pub fn document_replaced(&mut self) {
        self.field_notes.clear();
        self.port_problems.clear();
        if !matches!(self.run_state, RuntimeState::Running | RuntimeState::Paused) {
            self.states.clear();
            self.monitor.clear();
        }
    }

    /// An edit was undone or redone: what the fields said was about values no longer there.
    pub fn edit_undone_or_redone(&mut self) {
        self.field_notes.clear();
    }

    /// What the inspector says under a property's field, if anything.
    pub fn field_note(&self, component: &str, property: &str) -> Option<&str> {
        self.field_notes
            .get(&(component.to_owned(), property.to_owned()))
            .map(String::as_str)
    }

    /// The edits the running (or paused) diagram does not have yet, in words; none when nothing runs.
    pub fn not_applied(&self) -> Vec<String> {
        match (&self.deployed, self.run_state) {
            (Some(deployed), RuntimeState::Running | RuntimeState::Paused) => {
                crate::pending::not_applied(deployed, self.document.diagram())
            }
            _ => Vec::new(),
        }
    }

    /// Changes how the connection `from` → `to` reads (one undoable edit).
    /// While the diagram runs the runtime keeps the old reader until the next run, which the log says at
    /// once (and the canvas's bar until then, with Restart).
    pub fn set_reader(&mut self, from: &PortRef, to: &PortRef, settings: ReaderSettings) {
        self.document.edit(|d| {
            if let Some(c) = d.connections.iter_mut().find(|c| &c.from == from && &c.to == to) {
                c.policy = settings.policy;
                c.buffer_size = settings.buffer_size;
                c.subsampling = settings.subsampling;
            }
        });
        if matches!(self.run_state, RuntimeState::Running | RuntimeState::Paused) {
            self.note(
                LogLevel::Info,
                format!(
                    "{from} -> {to}: the new reader settings apply at the next run; the running diagram \
                     keeps the old ones (Restart applies them now)"
                ),
            );
        }
    }

    /// Opens the diagram in `path` in place of the document; false (with the reason in the log) when it
    /// cannot be read.
    pub fn open(&mut self, path: &Path) -> bool {
        match Document::open(path) {
            Ok(document) => {
                self.document = document;
                self.restore_viewers();
                self.note(LogLevel::Info, format!("opened {}", path.display()));
                self.remember_recent(path.to_owned());
                true
            }
            Err(error) => {
                self.note(LogLevel::Error, error.to_string());
                false
            }
        }
    }

    /// Writes the document to its file.
    pub fn save(&mut self) -> Saved {
        self.keep_viewers_in_document();
        let Some(path) = self.document.path().map(Path::to_path_buf) else {
            return Saved::NeedsPath;
        };
        match self.document.save() {
            Ok(()) => {
                self.note(LogLevel::Info, format!("saved {}", path.display()));
                self.remember_recent(path);
            }
            Err(error) => self.note(LogLevel::Error, error.to_string()),
        }
        Saved::Done
    }

    /// Writes the document to `path`, which becomes its file.
    pub fn save_as(&mut self, path: &Path) {
        self.keep_viewers_in_document();
        match self.document.save_as(path) {
            Ok(()) => {
                self.note(LogLevel::Info, format!("saved {}", path.display()));
                self.remember_recent(path.to_owned());
            }
            Err(error) => self.note(LogLevel::Error, error.to_string()),
        }
    }

    fn remember_recent(&mut self, path: PathBuf) {
        if let Err(error) = self.settings.remember_recent(path) {
            self.note(
                LogLevel::Warn,
                format!("the recent files are not remembered: {error}"),
            );
        }
    }
}

/// The inspector field where a refused exposure of a component's `name` (port or property) is said.
pub fn exposed_field(kind: kairos_diagram::ExposedKind, name: &str) -> String {
    format!("exposed {} {name}", kind.name())
}

#[cfg(test)]
mod tests {
    use kairos_diagram::{Diagram, LibraryInfo, PortRef};
    use kairos_protocol::{LogLevel, Request, RequestBody, RuntimeState, ServerMessage};
    use serde_json::json;

    use super::{Effect, NodeState, Session};
    use crate::client::{Answer, ClientEvent, DroppedEvents};
    use crate::document::Document;
    use crate::settings::Settings;

    /// The library the studio's interface tests use (generated by the `kairos` binary).
    fn library() -> LibraryInfo {
        crate::library_from_components_json(include_str!("../tests/library.json")).unwrap()
    }

    const DIAGRAM: &str = "Diagram(format: 1, packs: [Pack(name: \"core\", version: \"^0.1\")], components: [\
        Component(id: \"counter1\", type: \"core.counter\", position: (x: 0.0, y: 0.0)), \
        Component(id: \"console1\", type: \"core.console\", position: (x: 300.0, y: 0.0))], \
        connections: [Connection(from: \"counter1.out\", to: \"console1.in\")])";

    fn document() -> Document {
        let diagram: Diagram = kairos_diagram::parse(DIAGRAM).unwrap().diagram;
        let mut document = Document::default();
        document.edit(|d| *d = diagram);
        document
    }

    /// A message as the runtime sends it on the wire.
    fn from_runtime(message: serde_json::Value) -> ClientEvent {
        match serde_json::from_value::<ServerMessage>(message).unwrap() {
            // The result of an unknown request cannot be read: only refusals come this way.
            ServerMessage::Reply(reply) => ClientEvent::Reply(Answer::of(reply, None)),
            ServerMessage::Telemetry(telemetry) => ClientEvent::Telemetry(telemetry),
            ServerMessage::Log(record) => ClientEvent::Log(record),
        }
    }

    /// The runtime's reply to `request`, as the client reads it.
    fn ok(request: &Request, result: serde_json::Value) -> ClientEvent {
        let mut reply = json!({"id": request.id, "ok": true});
        reply["result"] = result;
        let reply = serde_json::from_value(reply).unwrap();
        ClientEvent::Reply(Answer::of(reply, Some(request.body.kind())))
    }

    fn component(id: &str, state: &str, error: Option<&str>) -> serde_json::Value {
        json!({"id": id, "type_name": "core.counter", "state": state, "error": error, "cycles": 1,
               "cycle_rate_hz": 1.0, "cpu_share": 0.0})
    }

    fn telemetry(state: &str, components: &[serde_json::Value]) -> ClientEvent {
        from_runtime(
            json!({"type": "telemetry", "at_ns": 1, "state": state, "links": [],
                            "components": components}),
        )
    }

    /// The requests sent since the last call.
    fn sent(session: &mut Session) -> Vec<Request> {
        session
            .take_effects()
            .into_iter()
            .filter_map(|e| match e {
                Effect::Send(request) => Some(request),
                Effect::ReadShared(_) => None,
            })
            .collect()
    }

    /// A session connected to a runtime on another machine (no shared memory), its library known.
    fn connected() -> Session {
        let mut session = Session::new(document(), LibraryInfo::default(), Settings::default());
        session.connecting("runtime ws://robot:7400".to_owned(), "ws://robot:7400");
        let welcome = json!({"protocol": 1, "server": "kairos 0.1.0", "role": "operator"});
        session.handle(ClientEvent::Connected(serde_json::from_value(welcome).unwrap()));
        assert!(session.is_connected());
        let requests = sent(&mut session);
        let kinds: Vec<&RequestBody> = requests.iter().map(|r| &r.body).collect();
        assert!(matches!(
            kinds.as_slice(),
            [
                RequestBody::Library,
                RequestBody::SubscribeTelemetry { interval_ms: 250 },
                RequestBody::SubscribeLog {
                    level: LogLevel::Info
                },
                RequestBody::Foxglove,
            ]
        ));
        let library = serde_json::to_value(library()).unwrap();
        session.handle(ok(&requests[0], library));
        assert!(session.library.component("core.counter").is_some());
        // The diagram's instances are described once the library is known.
        let describe = sent(&mut session);
        assert!(matches!(describe[0].body, RequestBody::DescribeInstances { .. }));
        session.handle(ok(&describe[0], json!({"instances": {}, "problems": {}})));
        session
    }

    #[test]
    fn publishing_to_foxglove_on_another_machine_says_how_to_reach_it() {
        let mut session = connected();
        session.publish_to_foxglove("gain1.out", true);
        let requests = sent(&mut session);
        assert!(matches!(
            &requests[0].body,
            RequestBody::FoxglovePublish { outputs, publish: true } if outputs == &["gain1.out"]
        ));
        let state =
            json!({"address": "ws://127.0.0.1:8765", "all": false, "outputs": ["gain1.out"], "clients": 0});
        session.handle(ok(&requests[0], state));
        assert_eq!(session.foxglove().outputs, ["gain1.out"]);
        assert!(
            session.log.lines().any(|l| l
                .text
                .contains("forward it first (ssh -L 8765:127.0.0.1:8765 robot)")),
            "the runtime's loopback is not this machine's"
        );
        assert_eq!(super::host_of("ws://robot:7400").as_deref(), Some("robot"));
        assert_eq!(super::host_of("wss://[::1]:7400/").as_deref(), Some("::1"));
        assert_eq!(super::host_of("ws://10.0.0.2").as_deref(), Some("10.0.0.2"));
    }

    #[test]
    fn telemetry_sets_each_components_state_and_the_run_state() {
        let mut session = connected();
        session.handle(telemetry(
            "running",
            &[
                component("counter1", "running", None),
                component("console1", "failed", Some("stdout closed")),
            ],
        ));
        assert_eq!(session.run_state(), RuntimeState::Running);
        assert_eq!(session.node_state("counter1"), Some(&NodeState::Running));
        assert_eq!(
            session.node_state("console1"),
            Some(&NodeState::Failed("stdout closed".to_owned()))
        );
        session.handle(telemetry(
            "ready",
            &[
                component("counter1", "stopped", None),
                component("console1", "finished", None),
            ],
        ));
        assert_eq!(session.run_state(), RuntimeState::Ready);
        assert_eq!(
            session.node_state("counter1"),
            Some(&NodeState::Waiting("stopped".to_owned()))
        );
        assert_eq!(session.node_state("console1"), Some(&NodeState::Finished));
    }

    #[test]
    fn an_accepted_deploy_is_followed_by_start() {
        let mut session = connected();
        session.deploy_and_start();
        let deploy = sent(&mut session);
        let [
            Request {
                body: RequestBody::Deploy { diagram, .. },
                ..
            },
        ] = deploy.as_slice()
        else {
            panic!("one deploy: {deploy:?}");
        };
        assert_eq!(diagram, &session.document.diagram().to_ron());
        assert!(
            sent(&mut session).is_empty(),
            "no start before the deploy is accepted"
        );
        session.handle(ok(&deploy[0], json!({"diagnostics": [], "components": 2})));
        assert_eq!(session.run_state(), RuntimeState::Ready);
        let after: Vec<RequestBody> = sent(&mut session).into_iter().map(|r| r.body).collect();
        // The viewers' subscriptions are renewed for the new deployment (none open here), then it starts.
        assert_eq!(
            after,
            [
                RequestBody::UnsubscribeSamples { outputs: Vec::new() },
                RequestBody::Start {
                    at_ns: None,
                    forced: None,
                    start_unlocked: false,
                    lock_bound_ns: None,
                }
            ]
        );
        assert!(
            session
                .log
                .lines()
                .any(|l| l.text == "deployed" && l.tone == crate::log::Tone::Success)
        );
    }

    #[test]
    fn a_refused_deploy_marks_its_components_and_is_not_started() {
        let mut session = connected();
        session.deploy_and_start();
        let deploy = sent(&mut session);
        let text = session.document.diagram().to_ron();
        // The runtime's diagnostic points into the text deployed: at the second component.
        let offset = text.find("console1").unwrap();
        let diagnostic = kairos_diagram::Diagnostic::error(
            kairos_diagram::DiagnosticCode::UnknownComponentType,
            "no console today",
        )
        .at(Some(kairos_diagram::Location {
            line: 1,
            column: 1,
            offset,
            len: 8,
        }));
        session.handle(from_runtime(
            json!({"type": "reply", "id": deploy[0].id, "ok": false, "error": {
            "code": "invalid_diagram", "message": "the diagram has 1 error",
            "diagnostics": [diagnostic]}}),
        ));
        assert!(sent(&mut session).is_empty(), "nothing is started");
        assert_eq!(
            session.node_state("console1"),
            Some(&NodeState::Invalid("no console today".to_owned()))
        );
        assert!(session.log.lines().any(|l| l.text == "the diagram has 1 error"));
        // The marks stay through telemetry until the next deploy.
        session.handle(telemetry("empty", &[]));
        assert!(matches!(
            session.node_state("console1"),
            Some(NodeState::Invalid(_))
        ));
    }

    #[test]
    fn a_live_property_changes_in_the_running_diagram_too() {
        let mut session = connected();
        session.handle(telemetry("running", &[component("counter1", "running", None)]));
        let live = library()
            .component("core.counter")
            .and_then(|c| c.properties.iter().find(|p| p.live).cloned());
        let Some(property) = live else {
            panic!("core.counter has a live property");
        };
        session.set_property("counter1", &property.name, property.default.clone());
        let requests: Vec<RequestBody> = sent(&mut session).into_iter().map(|r| r.body).collect();
        assert!(
            matches!(requests.as_slice(), [RequestBody::SetProperty { component, .. }] if component == "counter1"),
            "{requests:?}"
        );
        assert!(
            session
                .document
                .diagram()
                .component("counter1")
                .unwrap()
                .properties
                .contains_key(&property.name)
        );
    }

    #[test]
    fn viewers_fall_back_to_the_socket_when_shared_memory_fails() {
        let mut session = connected();
        // As a runtime on this machine would be.
        session.frames = super::FramePath::SharedMemory;
        session.viewers.open("counter1.out".to_owned(), "i64");
        session.deploy_and_start();
        let deploy = sent(&mut session);
        session.handle(ok(&deploy[0], json!({"diagnostics": [], "components": 2})));
        let requests = sent(&mut session);
        let subscribe = requests
            .iter()
            .find(|r| matches!(r.body, RequestBody::SubscribeSamples { .. }))
            .unwrap();
        assert!(matches!(
            subscribe.body,
            RequestBody::SubscribeSamples {
                transport: kairos_protocol::SampleTransport::SharedMemory,
                ..
            }
        ));
        session.handle(ok(
            subscribe,
            json!({"max_rate_hz": 30.0, "services": {"counter1.out": "kairos/1/counter1.out"}}),
        ));
        assert!(matches!(session.take_effects().as_slice(), [Effect::ReadShared(s)] if s.len() == 1));
        // The reader thread could not open the services: the socket takes over.
        session.handle(ClientEvent::SharedMemory(Err(
            crate::shared::SharedMemoryError::Node(
                iceoryx2::node::NodeCreationFailure::InsufficientPermissions,
            ),
        )));
        assert!(!session.uses_shared_memory());
        let again = sent(&mut session);
        assert!(again.iter().any(|r| matches!(
            r.body,
            RequestBody::SubscribeSamples {
                transport: kairos_protocol::SampleTransport::Socket,
                ..
            }
        )));
        assert!(
            session.log.lines().any(|l| l.text
                == "cannot start iceoryx2: InsufficientPermissions; viewers use the socket instead")
        );
    }

    #[test]
    fn the_command_lines_viewers_open_once_the_library_is_known() {
        let mut session = Session::new(document(), LibraryInfo::default(), Settings::default());
        session.set_startup(
            vec!["counter1.out+nobody.out".to_owned(), "nobody.out".to_owned()],
            false,
        );
        session.connecting("runtime".to_owned(), "ws://robot:7400");
        assert!(session.viewers.list.is_empty());
        let welcome = json!({"protocol": 1, "server": "kairos 0.1.0", "role": "operator"});
        session.handle(ClientEvent::Connected(serde_json::from_value(welcome).unwrap()));
        let requests = sent(&mut session);
        session.handle(ok(&requests[0], serde_json::to_value(library()).unwrap()));
        let describe = sent(&mut session);
        session.handle(ok(&describe[0], json!({"instances": {}, "problems": {}})));
        let opened: Vec<&str> = session.viewers.list.iter().map(|v| v.output.as_str()).collect();
        assert_eq!(opened, ["counter1.out"]);
        assert!(
            session
                .log
                .lines()
                .any(|l| l.level == LogLevel::Error && l.text.starts_with("--view nobody.out"))
        );
        // What cannot be drawn over a viewer is said, and the viewer opens without it.
        assert!(session.viewers.list[0].also.is_empty());
        assert!(session.log.lines().any(|l| l.level == LogLevel::Error
            && l.text.starts_with(
                "--view counter1.out+nobody.out: nobody.out cannot be drawn over counter1.out"
            )));
    }

    /// Runs the document, the runtime accepting the deploy: the start request that follows.
    fn deployed_then_started(session: &mut Session) -> Request {
        session.deploy_and_start();
        let deploy = sent(session);
        session.handle(ok(&deploy[0], json!({"diagnostics": [], "components": 2})));
        sent(session)
            .into_iter()
            .find(|r| matches!(r.body, RequestBody::Start { .. }))
            .unwrap()
    }

    #[test]
    fn a_start_refused_for_clocks_not_locked_can_be_asked_again_anyway() {
        let mut session = connected();
        let start = deployed_then_started(&mut session);
        assert!(session.unlocked_refusal().is_none());
        let refusal = "not every host's clock is locked to its master within 1ms, so nothing was started: \
                       host 'b': clock acquiring, error +3.000 ms";
        session.handle(from_runtime(
            json!({"type": "reply", "id": start.id, "ok": false, "error": {
            "code": "wrong_state", "message": refusal}}),
        ));
        assert_eq!(session.unlocked_refusal(), Some(refusal));
        session.start_unlocked();
        let again: Vec<RequestBody> = sent(&mut session).into_iter().map(|r| r.body).collect();
        assert_eq!(
            again,
            [RequestBody::Start {
                at_ns: None,
                forced: None,
                start_unlocked: true,
                lock_bound_ns: None,
            }]
        );
        assert!(session.unlocked_refusal().is_none(), "offered once per refusal");
        session.start_unlocked();
        assert!(sent(&mut session).is_empty());
    }

    #[test]
    fn a_start_asks_for_the_lock_bound_set() {
        let mut session = connected();
        session.set_lock_bound(std::time::Duration::from_micros(250));
        let start = deployed_then_started(&mut session);
        assert!(
            matches!(
                start.body,
                RequestBody::Start {
                    lock_bound_ns: Some(250_000),
                    ..
                }
            ),
            "{:?}",
            start.body
        );
    }

    #[test]
    fn without_a_runtime_a_request_is_an_error_in_the_log() {
        let mut session = Session::new(document(), library(), Settings::default());
        session.request(RequestBody::Start {
            at_ns: None,
            forced: None,
            start_unlocked: false,
            lock_bound_ns: None,
        });
        assert!(session.take_effects().is_empty());
        assert!(
            session
                .log
                .lines()
                .any(|l| l.level == LogLevel::Error && l.text == "no runtime connected")
        );
    }

    #[test]
    fn dropped_events_are_said_in_the_log() {
        let mut session = connected();
        let before = session.log.lines().count();
        for samples in 1..=5 {
            session.report_dropped(DroppedEvents {
                samples,
                telemetry: 0,
                log: 0,
            });
        }
        session.report_dropped(DroppedEvents {
            samples: 5,
            telemetry: 0,
            log: 3,
        });
        let said: Vec<(&str, u32)> = session
            .log
            .lines()
            .skip(before)
            .map(|l| (l.text.as_str(), l.repeats))
            .collect();
        // Said at 1, 2 and 4 frames: one line, the latest count, said three times; then the log records.
        assert_eq!(said.len(), 2, "{said:?}");
        assert!(
            said[0].0.contains("4 sample frames") && said[0].1 == 3,
            "{said:?}"
        );
        assert!(said[1].0.contains("3 of the runtime's log records"));
    }

    #[test]
    fn a_recent_file_that_cannot_be_remembered_is_said_in_the_log() {
        let dir = tempfile::tempdir().unwrap();
        let blocked = dir.path().join("blocked");
        std::fs::write(&blocked, "").unwrap();
        let (settings, _) = Settings::load(Some(blocked.join("kairos")));
        let mut session = Session::new(document(), library(), settings);
        session.save_as(&dir.path().join("saved.ron"));
        assert!(dir.path().join("saved.ron").is_file());
        assert!(
            session
                .log
                .lines()
                .any(|l| l.level == LogLevel::Warn
                    && l.text.starts_with("the recent files are not remembered"))
        );
    }

    #[test]
    fn a_reader_policy_edit_is_one_undoable_step() {
        let mut session = Session::new(document(), library(), Settings::default());
        let (from, to) = (PortRef::new("counter1", "out"), PortRef::new("console1", "in"));
        let settings = super::ReaderSettings {
            policy: Some(kairos_diagram::ReaderPolicy::LastOrNext),
            buffer_size: Some(4),
            subsampling: None,
        };
        session.set_reader(&from, &to, settings);
        let connection = session.document.diagram().connections[0].clone();
        assert_eq!(connection.policy, Some(kairos_diagram::ReaderPolicy::LastOrNext));
        assert_eq!(connection.buffer_size, Some(4));
        assert!(session.document.undo());
        assert_eq!(session.document.diagram().connections[0].policy, None);
    }

    #[test]
    fn edits_the_running_diagram_lacks_are_told_until_the_next_deploy() {
        let mut session = connected();
        session.deploy_and_start();
        let deploy = sent(&mut session);
        session.handle(ok(&deploy[0], json!({"diagnostics": [], "components": 2})));
        let _start = sent(&mut session);
        session.handle(telemetry("running", &[component("counter1", "running", None)]));
        assert!(session.not_applied().is_empty());
        let (from, to) = (PortRef::new("counter1", "out"), PortRef::new("console1", "in"));
        session.set_reader(
            &from,
            &to,
            super::ReaderSettings {
                policy: Some(kairos_diagram::ReaderPolicy::LastOrNext),
                buffer_size: None,
                subsampling: None,
            },
        );
        assert_eq!(
            session.not_applied(),
            ["counter1.out -> console1.in: reader LastOrNext"]
        );
        assert!(session.log.lines().any(|l| {
            l.text
                .starts_with("counter1.out -> console1.in: the new reader settings apply at the next run")
        }));
        // Restart deploys the edited diagram: nothing is left to apply.
        session.deploy_and_start();
        let deploy = sent(&mut session);
        session.handle(ok(&deploy[0], json!({"diagnostics": [], "components": 2})));
        assert!(session.not_applied().is_empty());
    }

    #[test]
    fn a_refused_name_is_said_at_the_field_until_a_rename_succeeds() {
        let mut session = connected();
        assert!(!session.rename_component("counter1", "console1"));
        assert!(session.field_note("counter1", "name").is_some());
        assert!(session.rename_component("counter1", " count "));
        assert!(session.field_note("counter1", "name").is_none());
        assert!(session.field_note("count", "name").is_none());
        let connection = &session.document.diagram().connections[0];
        assert_eq!(connection.from.component, "count");
        assert!(session.log.lines().any(|l| l.text == "renamed counter1 to count"));
    }

    #[test]
    fn what_a_console_component_prints_goes_to_the_console_not_the_log() {
        let mut session = connected();
        let before = session.log.lines().count();
        for (component, message) in [
            ("console1", "console1: t=1 seq=0 latency=3.0µs 0.5"),
            ("counter1", "counter1 started"),
        ] {
            session.handle(from_runtime(json!({"type": "log", "at_ns": 5, "level": "info",
                "component": component, "message": message})));
        }
        let printed: Vec<&str> = session.console.lines().map(|l| l.text.as_str()).collect();
        assert_eq!(printed, ["console1: t=1 seq=0 latency=3.0µs 0.5"]);
        let logged: Vec<&str> = session
            .log
            .lines()
            .skip(before)
            .map(|l| l.text.as_str())
            .collect();
        assert_eq!(logged.len(), 1, "{logged:?}");
    }
}
