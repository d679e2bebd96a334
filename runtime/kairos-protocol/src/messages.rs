//! Requests, replies and events: the JSON text messages.

use std::collections::BTreeMap;

use kairos_diagram::{Diagnostic, LibraryInfo, ReaderPolicy, Value};
use serde::{Deserialize, Serialize};

use crate::Token;

/// What a session may do: `monitor` only looks, `operator` also changes things.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// Read-only: the library, the diagram, status, telemetry, samples, logs.
    Monitor,
    /// Everything a monitor may, plus deploying, starting, stopping, properties, actions, recording, replay.
    Operator,
}

/// Least important first, as `tracing` orders them.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LogLevel {
    /// Very detailed.
    Trace,
    /// For developers.
    Debug,
    /// Normal operation.
    #[default]
    Info,
    /// Something looks wrong.
    Warn,
    /// Something failed.
    Error,
}

fn default_sample_rate() -> f64 {
    10.0
}

/// A client's request; the reply carries the same `id`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Request {
    /// Chosen by the client; echoed in the reply.
    pub id: u64,
    /// What is asked.
    #[serde(flatten)]
    pub body: RequestBody,
}

/// Declares every request once: its variant in [`RequestBody`] (with its fields), its `type` on the wire,
/// the type of its reply's result (its variant in [`ReplyBody`]) and the least role allowed to make it.
/// [`RequestKind`], its list, its names and the role table all come from this one table, so a request
/// cannot be added to one and forgotten in another.
macro_rules! requests {
    ($(
        $(#[$doc:meta])*
        $variant:ident = $name:literal $({ $($fields:tt)* })? => $reply:ty, $role:ident;
    )*) => {
        /// Every request, by its `type`.
        #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
        #[serde(tag = "type")]
        pub enum RequestBody {
            $(
                $(#[$doc])*
                #[serde(rename = $name)]
                $variant $({ $($fields)* })?,
            )*
        }

        /// A request's type without its fields: what the role table is keyed by.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
        pub enum RequestKind {
            $(
                $(#[$doc])*
                #[serde(rename = $name)]
                $variant,
            )*
        }

        impl RequestKind {
            /// Every request type, in the order the protocol lists them.
            pub const ALL: [RequestKind; [$($name),*].len()] = [$(RequestKind::$variant),*];

            /// The role table: the least role allowed to make this request.
            pub fn required_role(self) -> Role {
                match self {
                    $(RequestKind::$variant => Role::$role,)*
                }
            }

            /// The `type` of the request on the wire (`set_property`).
            pub fn name(self) -> &'static str {
                match self {
                    $(RequestKind::$variant => $name,)*
                }
            }
        }

        impl RequestBody {
            /// The request's type.
            pub fn kind(&self) -> RequestKind {
                match self {
                    $(RequestBody::$variant { .. } => RequestKind::$variant,)*
                }
            }
        }

        /// A successful reply's `result`, by the request it answers: one variant per request type, holding
        /// that request's result type. On the wire it is the result alone (no tag): a client knows which
        /// request an `id` was and decodes with [`ReplyBody::decode`] (or [`Reply::decode`]).
        #[derive(Debug, Clone, PartialEq, Serialize)]
        #[serde(untagged)]
        pub enum ReplyBody {
            $(
                #[doc = concat!("The result of `", $name, "`.")]
                $variant($reply),
            )*
        }

        impl ReplyBody {
            /// The type of the request this answers.
            pub fn kind(&self) -> RequestKind {
                match self {
                    $(ReplyBody::$variant(_) => RequestKind::$variant,)*
                }
            }

            /// Reads `result` as the result of a request of type `kind`.
            pub fn decode(kind: RequestKind, result: serde_json::Value) -> Result<ReplyBody, serde_json::Error> {
                match kind {
                    $(RequestKind::$variant => serde_json::from_value(result).map(ReplyBody::$variant),)*
                }
            }
        }
    };
}

requests! {
    /// The first message of a session: the protocol version, who is calling, the token, the role wanted.
    Hello = "hello" {
        /// The client's protocol version; must equal the server's.
        protocol: u32,
        /// A name for logs (`kairos-studio 0.1.0`, `demo.py`).
        client: String,
        /// The server's token, when it has one.
        #[serde(default)]
        token: Option<Token>,
        /// The role wanted (default: operator).
        #[serde(default)]
        role: Option<Role>,
    } => Welcome, Monitor;
    /// The component library: packs, component types, ports, properties, actions, docs.
    Library = "library" => LibraryInfo, Monitor;
    /// The ports of the instances of a diagram (RON text, not deployed) whose ports depend on their
    /// properties (a player's outputs follow its recordings).
    DescribeInstances = "describe_instances" {
        /// The diagram file's text.
        diagram: String,
    } => Described, Monitor;
    /// The deployed diagram's text.
    GetDiagram = "get_diagram" => DiagramReply, Monitor;
    /// The serial ports, CAN interfaces and cameras of the runtime's machine.
    Devices = "devices" => DeviceList, Monitor;
    /// The topics a ROS 2 graph advertises (the liveliness tokens `rmw_zenoh` declares), as the runtime's
    /// machine reaches it: for a topic picker.
    Ros2Topics = "ros2_topics" {
        /// The Zenoh endpoint of `rmw_zenoh`'s router, or of a peer (`tcp/localhost:7447`).
        router: String,
        /// The ROS 2 domain (`ROS_DOMAIN_ID`).
        #[serde(default)]
        domain_id: i64,
    } => Ros2TopicList, Monitor;
    /// Validates a diagram (RON text) and, if valid, makes it the runtime's diagram, stopping the old one.
    Deploy = "deploy" {
        /// The diagram file's text.
        diagram: String,
        /// For a part of a diagram spread over several hosts: the Zenoh network its links to the other
        /// parts travel on (`kairos deploy` sends it). Absent: the diagram has no such links.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        network: Option<LinkNetwork>,
        /// The folder, on the runtime's machine, that the diagram's relative paths start from (its hosts'
        /// token files and certificates). Absent: the runtime's working folder. A diagram with hosts
        /// deployed this way is coordinated by the runtime: it deploys each host's part, starts and stops
        /// them together, forwards property changes and actions, and reports every host's telemetry.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        folder: Option<String>,
    } => DeployResult, Operator;
    /// The first phase of deploying one host's part of a diagram spread over several: validates the
    /// diagram and builds it, as `deploy` would, without touching the deployed one. `commit_deploy` with the
    /// ticket replied makes it the deployed diagram; `abandon_deploy` drops it. A newer prepare replaces one
    /// not yet committed. `kairos deploy` prepares every host's part before it commits any, so that a part
    /// one host refuses changes no host.
    PrepareDeploy = "prepare_deploy" {
        /// The diagram file's text.
        diagram: String,
        /// As `deploy`'s: the Zenoh network the part's links travel on, joined when committed.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        network: Option<LinkNetwork>,
    } => Prepared, Operator;
    /// Makes the prepared diagram with this ticket the deployed one, stopping and replacing the running one.
    CommitDeploy = "commit_deploy" {
        /// The ticket `prepare_deploy` replied.
        ticket: u64,
    } => DeployResult, Operator;
    /// Drops the prepared diagram with this ticket; the deployed one is untouched. An unknown ticket (one
    /// already committed, abandoned or replaced) is done already.
    AbandonDeploy = "abandon_deploy" {
        /// The ticket `prepare_deploy` replied.
        ticket: u64,
    } => Done, Operator;
    /// The deployed diagram's links to other hosts: each end, and whether its far end has matched.
    Links = "links" => LinkList, Monitor;
    /// Installs a pack this runtime lacks (what `kairos deploy` does before deploying a part that needs it),
    /// sent in chunks of at most [`PACK_CHUNK_BYTES`]; the chunk that completes it loads it. A pack library
    /// is refused when it was built for another platform than [`this_platform`]; a Python pack (platform
    /// [`PYTHON_PACK_PLATFORM`]) travels as a tar archive of its folder and loads on any platform. Either is
    /// refused when a pack of that name is already loaded, or when its own name and version are not the
    /// ones announced.
    InstallPack = "install_pack" {
        /// The pack's name.
        name: String,
        /// The pack's version.
        version: String,
        /// The platform the library was built for (`linux-x86_64`).
        platform: String,
        /// The library's size in bytes.
        size: u64,
        /// Where this chunk starts in the library.
        offset: u64,
        /// The chunk, in base64 (RFC 4648, with padding).
        data: String,
    } => PackInstall, Operator;
    /// Starts the deployed diagram: now, or at an instant on the runtime's clock (several runtimes whose
    /// clocks follow one master start together); the reply comes once it has started.
    Start = "start" {
        /// When to start, ns since the UNIX epoch on the runtime's clock; absent: now.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        at_ns: Option<i64>,
        /// Set when the start goes ahead although hosts' clocks are not locked (`kairos deploy
        /// --start-unlocked`): which, in words. Every recording this start begins says so.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        forced: Option<String>,
        /// For a runtime coordinating a diagram spread over hosts: start although some hosts' clocks are
        /// not locked to their master (the studio's "Start anyway"); the recordings say so.
        #[serde(default, skip_serializing_if = "std::ops::Not::not")]
        start_unlocked: bool,
        /// For a runtime coordinating a diagram spread over hosts: how close to its master each host's
        /// clock must be for the start to go ahead, ns (1 ns to 10 s); absent: 1 ms, as `kairos deploy`.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        lock_bound_ns: Option<u64>,
    } => Started, Operator;
    /// Pauses it.
    Pause = "pause" => Done, Operator;
    /// Resumes it after a pause.
    Resume = "resume" => Done, Operator;
    /// Stops it (it can be started again): now, or at an instant on the runtime's clock (several runtimes
    /// stop together, as they started); the reply comes once it has stopped.
    Stop = "stop" {
        /// When to stop, ns since the UNIX epoch on the runtime's clock; absent: now.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        at_ns: Option<i64>,
    } => Done, Operator;
    /// Changes a property, validated; a refused value keeps the old one and the error says why.
    SetProperty = "set_property" {
        /// The component's id.
        component: String,
        /// The property.
        property: String,
        /// The new value.
        value: Value,
    } => Done, Operator;
    /// Triggers a component's action.
    TriggerAction = "trigger_action" {
        /// The component's id.
        component: String,
        /// The action.
        action: String,
    } => Done, Operator;
    /// The runtime's state and each component's.
    Status = "status" => Status, Monitor;
    /// Telemetry events every `interval_ms` (at least 20).
    SubscribeTelemetry = "subscribe_telemetry" {
        /// The period.
        interval_ms: u64,
    } => TelemetrySubscribed, Monitor;
    /// No more telemetry.
    UnsubscribeTelemetry = "unsubscribe_telemetry" => Done, Monitor;
    /// Binary sample frames from these outputs (`camera.image`), at most `max_rate_hz` per output, the
    /// latest sample each time (a slow client gets fewer, never older ones).
    SubscribeSamples = "subscribe_samples" {
        /// The outputs.
        outputs: Vec<String>,
        /// The most frames per second per output (default 10).
        #[serde(default = "default_sample_rate")]
        max_rate_hz: f64,
        /// Images wider than this are downscaled (by a whole factor) before sending.
        #[serde(default)]
        max_image_width: Option<u32>,
        /// How the frames travel: on this connection (default), or through shared memory for a client on
        /// the server's own machine (see [`Welcome::shared_memory_host`]).
        #[serde(default)]
        transport: SampleTransport,
        /// With shared memory: send images whose pixels already lie in the runtime's shared memory as a
        /// reference to them ([`crate::shared_pixels::PixelsReference`] in the frame's image layout), which
        /// the client maps, instead of copying the pixels into the frame. Ask for it only when
        /// [`crate::shared_pixels::can_map_buffers_of`] the server's [`Welcome::pid`] holds.
        #[serde(default, skip_serializing_if = "std::ops::Not::not")]
        shared_pixels: bool,
    } => SamplesSubscribed, Monitor;
    /// Stops sample frames from these outputs (all, when empty).
    UnsubscribeSamples = "unsubscribe_samples" {
        /// The outputs.
        #[serde(default)]
        outputs: Vec<String>,
    } => Done, Monitor;
    /// Publishes outputs live to Foxglove (or stops publishing them), in the schemas recordings use, on the
    /// runtime's Foxglove WebSocket server: the one `kairos serve --foxglove` started, or one started now on
    /// loopback (`ws://127.0.0.1:8765`, or the next free port).
    FoxglovePublish = "foxglove_publish" {
        /// The outputs (`camera.image`).
        outputs: Vec<String>,
        /// Publish them (true) or stop (false).
        publish: bool,
    } => FoxgloveState, Operator;
    /// What is published to Foxglove, and where.
    Foxglove = "foxglove" => FoxgloveState, Monitor;
    /// Log events at `level` and above.
    SubscribeLog = "subscribe_log" {
        /// The least important level sent.
        #[serde(default)]
        level: LogLevel,
    } => Done, Monitor;
    /// No more log events.
    UnsubscribeLog = "unsubscribe_log" => Done, Monitor;
    /// Starts a recorder (its `start` action).
    RecordStart = "record_start" {
        /// The recorder's id.
        component: String,
    } => Done, Operator;
    /// Stops a recorder and closes its file.
    RecordStop = "record_stop" {
        /// The recorder's id.
        component: String,
    } => Done, Operator;
    /// Closes a recorder's file and goes on in a new one.
    RecordSplit = "record_split" {
        /// The recorder's id.
        component: String,
    } => Done, Operator;
    /// Plays (resumes) a player.
    PlayerPlay = "player_play" {
        /// The player's id.
        component: String,
    } => Done, Operator;
    /// Pauses a player.
    PlayerPause = "player_pause" {
        /// The player's id.
        component: String,
    } => Done, Operator;
    /// Makes a paused player emit one sample.
    PlayerStep = "player_step" {
        /// The player's id.
        component: String,
    } => Done, Operator;
    /// Jumps to a time, in seconds from the recording's first message.
    PlayerSeek = "player_seek" {
        /// The player's id.
        component: String,
        /// Where to.
        seconds: f64,
    } => Done, Operator;
    /// Sets the replay speed (0.1 to 100).
    PlayerSpeed = "player_speed" {
        /// The player's id.
        component: String,
        /// The factor.
        factor: f64,
    } => Done, Operator;
}

/// How sample frames reach a client.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SampleTransport {
    /// As binary messages on the protocol connection.
    #[default]
    Socket,
    /// Published through iceoryx2 shared memory, one service per output, named in the reply
    /// (`{"services": {"camera.image": "kairos/..."}}`); only for clients on the server's machine.
    SharedMemory,
}

/// Why a request failed, for programs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ErrorCode {
    /// Not JSON, not an object, an unknown `type`, a missing or mistyped field.
    BadRequest,
    /// The client speaks another protocol version.
    UnsupportedVersion,
    /// No `hello` yet, or a missing or wrong token.
    Unauthorized,
    /// The session's role may not make this request.
    Forbidden,
    /// No such component, property, action or output.
    NotFound,
    /// The deployed diagram has errors; `diagnostics` lists them all.
    InvalidDiagram,
    /// A property value the property refuses; the old value stays.
    InvalidValue,
    /// Not possible in the runtime's present state (start without a diagram, ...).
    WrongState,
    /// The message is larger than the server accepts.
    TooLarge,
    /// The server is at its connection limit.
    Busy,
    /// The server failed; the message says how.
    Internal,
}

/// A failed request's error.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ProtocolError {
    /// For programs.
    pub code: ErrorCode,
    /// For people: what went wrong and, where known, how to fix it.
    pub message: String,
    /// For `invalid_diagram`: every problem found.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub diagnostics: Vec<Diagnostic>,
}

impl ProtocolError {
    /// An error without diagnostics.
    pub fn new(code: ErrorCode, message: impl Into<String>) -> Self {
        ProtocolError {
            code,
            message: message.into(),
            diagnostics: Vec::new(),
        }
    }
}

/// The answer to one request, as it travels: its result is read with [`Reply::decode`], knowing which
/// request the `id` was.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Reply {
    /// The request's id; `null` when the request was too broken to have one.
    pub id: Option<u64>,
    /// Whether it succeeded.
    pub ok: bool,
    /// What it returned, when it succeeded: a [`ReplyBody`] of the request's type.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub result: Option<serde_json::Value>,
    /// Why it failed, when it did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<ProtocolError>,
}

impl Reply {
    /// A successful reply carrying `body`. A body that cannot be written as JSON makes an `internal` error
    /// reply naming the request and the cause, never a reply with a missing or `null` result.
    pub fn success(id: u64, body: &ReplyBody) -> Reply {
        match encode_result(body.kind(), body) {
            Ok(result) => Reply {
                id: Some(id),
                ok: true,
                result: Some(result),
                error: None,
            },
            Err(error) => Reply::failure(Some(id), error),
        }
    }

    /// A failed reply.
    pub fn failure(id: Option<u64>, error: ProtocolError) -> Reply {
        Reply {
            id,
            ok: false,
            result: None,
            error: Some(error),
        }
    }

    /// Reads this reply as the answer to a request of type `kind`: its result, or the server's error. A
    /// result this client cannot read (from a server of another version) is an `internal` error that says
    /// what did not match.
    pub fn decode(self, kind: RequestKind) -> Result<ReplyBody, ProtocolError> {
        match (self.ok, self.error) {
            (false, Some(error)) => Err(error),
            (false, None) => Err(ProtocolError::new(
                ErrorCode::Internal,
                format!("the server refused '{}' without saying why", kind.name()),
            )),
            (true, _) => {
                let result = self.result.unwrap_or(serde_json::Value::Null);
                ReplyBody::decode(kind, result).map_err(|e| {
                    ProtocolError::new(
                        ErrorCode::Internal,
                        format!(
                            "the result of '{}' is not what this client reads: {e}",
                            kind.name()
                        ),
                    )
                })
            }
        }
    }
}

/// `result` as JSON, or an `internal` error naming the request and the cause.
fn encode_result(kind: RequestKind, result: &impl Serialize) -> Result<serde_json::Value, ProtocolError> {
    serde_json::to_value(result).map_err(|e| {
        ProtocolError::new(
            ErrorCode::Internal,
            format!("the result of '{}' cannot be written as JSON: {e}", kind.name()),
        )
    })
}

/// Every text message a server sends, by its `type`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ServerMessage {
    /// The answer to a request.
    Reply(Reply),
    /// Statistics, at the subscribed interval.
    Telemetry(Telemetry),
    /// One log record.
    Log(LogRecord),
}

impl ServerMessage {
    /// A successful reply (see [`Reply::success`]).
    pub fn ok(id: u64, body: &ReplyBody) -> Self {
        ServerMessage::Reply(Reply::success(id, body))
    }

    /// A failed reply.
    pub fn error(id: Option<u64>, error: ProtocolError) -> Self {
        ServerMessage::Reply(Reply::failure(id, error))
    }
}

/// What is wrong with a `set_property`'s `value`, in words naming the field; none when it can be a value.
fn property_value_problem(value: Option<&serde_json::Value>) -> Option<String> {
    let found = match value? {
        serde_json::Value::Bool(_) | serde_json::Value::Number(_) | serde_json::Value::String(_) => {
            return None;
        }
        serde_json::Value::Null => "null",
        serde_json::Value::Array(_) => "a list",
        serde_json::Value::Object(_) => "an object",
    };
    Some(format!(
        "\"value\" must be a boolean, a number or a text, not {found}"
    ))
}

/// Decodes a client's text message. On failure, the error names what is wrong and carries the request's
/// `id` when one could be read, so the reply can still be matched.
pub fn decode_request(text: &str) -> Result<Request, (Option<u64>, ProtocolError)> {
    let value: serde_json::Value = serde_json::from_str(text).map_err(|e| {
        (
            None,
            ProtocolError::new(ErrorCode::BadRequest, format!("not JSON: {e}")),
        )
    })?;
    let Some(object) = value.as_object() else {
        return Err((
            None,
            ProtocolError::new(
                ErrorCode::BadRequest,
                "a request is a JSON object with \"id\" and \"type\"",
            ),
        ));
    };
    let id = object.get("id").and_then(serde_json::Value::as_u64);
    if id.is_none() {
        return Err((
            None,
            ProtocolError::new(
                ErrorCode::BadRequest,
                "a request needs \"id\": a non-negative integer",
            ),
        ));
    }
    let Some(kind) = object
        .get("type")
        .and_then(serde_json::Value::as_str)
        .map(str::to_owned)
    else {
        return Err((
            id,
            ProtocolError::new(ErrorCode::BadRequest, "a request needs \"type\": a string"),
        ));
    };
    if !RequestKind::ALL.iter().any(|k| k.name() == kind) {
        let names: Vec<&str> = RequestKind::ALL.iter().map(|k| k.name()).collect();
        return Err((
            id,
            ProtocolError::new(
                ErrorCode::BadRequest,
                format!("unknown request type '{kind}'; known: {}", names.join(", ")),
            ),
        ));
    }
    if kind == "set_property"
        && let Some(problem) = property_value_problem(object.get("value"))
    {
        return Err((
            id,
            ProtocolError::new(ErrorCode::BadRequest, format!("'set_property': {problem}")),
        ));
    }
    serde_json::from_value(value).map_err(|e| {
        (
            id,
            ProtocolError::new(ErrorCode::BadRequest, format!("'{kind}': {e}")),
        )
    })
}

/// The result of `hello`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Welcome {
    /// The server's protocol version.
    pub protocol: u32,
    /// The server (`kairos 0.1.0`).
    pub server: String,
    /// The role granted.
    pub role: Role,
    /// The server machine's boot id, when the server can publish sample frames in shared memory: a client
    /// whose machine has the same id may subscribe with [`SampleTransport::SharedMemory`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shared_memory_host: Option<String>,
    /// The server's process id, given with `shared_memory_host`: a client maps the pixel buffers of
    /// `shared_pixels` frames through `/proc/PID/fd`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pid: Option<u32>,
    /// The server's platform ([`this_platform`]): which pack libraries it can load.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub platform: Option<String>,
}

/// The most bytes of a pack library one `install_pack` carries (before base64), well under
/// [`crate::MAX_MESSAGE_BYTES`] once encoded.
pub const PACK_CHUNK_BYTES: usize = 2 << 20;

/// The `platform` of a Python pack shipped by `install_pack`: its folder's `kairos-pack.toml`, `.py` files
/// and other files, as a tar archive.
pub const PYTHON_PACK_PLATFORM: &str = "python";

/// This machine's platform as pack libraries are built for it: operating system and architecture
/// (`linux-x86_64`). A library built for one platform does not load on another.
pub fn this_platform() -> String {
    // A documented test-only setting: a runtime that says it is another platform, so that refusing a pack
    // built for the wrong one can be tested on one machine.
    std::env::var("KAIROS_TEST_PLATFORM")
        .ok()
        .filter(|p| !p.is_empty())
        .unwrap_or_else(|| format!("{}-{}", std::env::consts::OS, std::env::consts::ARCH))
}

/// The result of `install_pack`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PackInstall {
    /// The bytes received so far.
    pub received: u64,
    /// Whether the library is complete, loaded and its components registered.
    pub installed: bool,
    /// Where it was written, once installed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub path: Option<String>,
}

/// This machine's boot id (Linux), which tells whether a client and a server share a machine.
pub fn this_host() -> Option<String> {
    std::fs::read_to_string("/proc/sys/kernel/random/boot_id")
        .ok()
        .map(|id| id.trim().to_owned())
        .filter(|id| !id.is_empty())
}

/// The result of `get_diagram`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct DiagramReply {
    /// The deployed diagram's canonical text; `None` before any deploy.
    pub diagram: Option<String>,
}

/// The result of a successful `deploy`: warnings only.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct DeployResult {
    /// Warnings (errors make the deploy fail with `invalid_diagram`).
    pub diagnostics: Vec<Diagnostic>,
    /// How many components the diagram has.
    pub components: usize,
    /// The deployment's identity, as `status` reports it while this diagram is the deployed one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub deployment: Option<String>,
}

/// The result of a successful `prepare_deploy`: the diagram is valid and built, not yet deployed.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Prepared {
    /// What `commit_deploy` and `abandon_deploy` name it by.
    pub ticket: u64,
    /// Warnings (errors make the prepare fail with `invalid_diagram`).
    pub diagnostics: Vec<Diagnostic>,
    /// How many components the diagram has.
    pub components: usize,
}

/// The result of `start`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Started {
    /// For a start at an instant (`at_ns`): how long after it the runtime started, in ns, on its clock.
    /// `kairos deploy` says which hosts started more than a millisecond late.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub late_ns: Option<i64>,
}

/// The result of a request that returns nothing but its success (`start`, `set_property`, ...): `{}`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Done {}

/// The result of `subscribe_telemetry`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct TelemetrySubscribed {
    /// The period granted (the one asked for, raised to the shortest the server allows).
    pub interval_ms: u64,
}

/// The result of `subscribe_samples`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SamplesSubscribed {
    /// The most frames per second per output granted.
    pub max_rate_hz: f64,
    /// With [`SampleTransport::SharedMemory`]: the iceoryx2 service publishing each output's frames.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub services: Option<BTreeMap<String, String>>,
}

/// Where the runtime is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RuntimeState {
    /// No diagram deployed.
    Empty,
    /// A diagram is deployed and not running.
    Ready,
    /// Running.
    Running,
    /// Paused.
    Paused,
}

/// The result of `describe_instances`: the instances whose ports depend on their properties, described.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Described {
    /// By instance id: the instance's own description (ports as its properties make them).
    pub instances: BTreeMap<String, kairos_diagram::ComponentInfo>,
    /// By instance id: why an instance cannot be described (a recording that cannot be read).
    pub problems: BTreeMap<String, kairos_diagram::DescribeError>,
}

/// The result of `status`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Status {
    /// The runtime's state.
    pub state: RuntimeState,
    /// The latest statistics, when a diagram is deployed.
    pub telemetry: Option<Box<Telemetry>>,
    /// Where the runtime's clock stands: the master's it follows (`kairos serve --clock-slave-of`),
    /// whatever is deployed, or else the deployed diagram's time source; absent when it runs on the
    /// machine's own clock.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clock: Option<ClockTelemetry>,
    /// The deployed diagram's identity, as `deploy` and `commit_deploy` replied it: a new one with every
    /// deployment and every start of the server. `kairos deploy` re-attaches to a host it lost that still
    /// runs the deployment it made, instead of deploying it again. Absent before any deploy.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub deployment: Option<String>,
    /// How late the last start at an agreed instant (`start` with `at_ns`) came on this runtime's clock,
    /// ns; over a millisecond, this runtime's part started apart from the other hosts'. Absent until such
    /// a start, and again after a deploy.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start_late_ns: Option<i64>,
}

/// Latency figures of one link, in nanoseconds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[allow(missing_docs, reason = "the names say it")]
pub struct LatencyTelemetry {
    pub count: u64,
    pub min_ns: i64,
    pub mean_ns: i64,
    pub p50_ns: i64,
    pub p99_ns: i64,
    pub max_ns: i64,
}

/// One link's statistics (`written = read + skipped + overwritten + queued`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LinkTelemetry {
    /// `from -> to`.
    pub link: String,
    /// The reader policy.
    pub policy: ReaderPolicy,
    /// Samples written since the run started.
    pub written: u64,
    /// Samples the reader consumed.
    pub read: u64,
    /// Samples its policy or subsampling passed over.
    pub skipped: u64,
    /// Samples lost to the writer lapping the reader (drops).
    pub overwritten: u64,
    /// Samples waiting.
    pub queued: u64,
    /// Samples re-read (Sampling).
    pub repeated: u64,
    /// Samples written per second lately.
    pub rate_hz: f64,
    /// Time of issue − timestamp of what the reader read.
    pub latency: LatencyTelemetry,
}

/// Where a component is in its life, as telemetry reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ComponentState {
    /// Built, not started.
    Idle,
    /// Running its cycles.
    Running,
    /// Paused by the user.
    Paused,
    /// Its stream ended and it finished on its own.
    Finished,
    /// Stopped by the runtime.
    Stopped,
    /// It returned an error or panicked; [`ComponentTelemetry::error`] says which and why.
    Failed,
    /// A state this client does not know, from a newer server. Telemetry keeps flowing to an older client
    /// instead of failing to decode as a whole over one word; a server never sends it.
    #[serde(other)]
    Unknown,
}

impl ComponentState {
    /// The word on the wire (`running`), for tables.
    pub fn word(self) -> &'static str {
        match self {
            ComponentState::Idle => "idle",
            ComponentState::Running => "running",
            ComponentState::Paused => "paused",
            ComponentState::Finished => "finished",
            ComponentState::Stopped => "stopped",
            ComponentState::Failed => "failed",
            ComponentState::Unknown => "unknown",
        }
    }
}

impl std::fmt::Display for ComponentState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.word())
    }
}

/// One component's statistics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ComponentTelemetry {
    /// The id.
    pub id: String,
    /// The component type.
    pub type_name: String,
    /// Where it is in its life.
    pub state: ComponentState,
    /// Why it failed, when it did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// `core` calls completed.
    pub cycles: u64,
    /// Cycles per second lately.
    pub cycle_rate_hz: f64,
    /// Share of one core lately (0 to 1).
    pub cpu_share: f64,
    /// Periodic ticks skipped so far because the component fell more than a period behind.
    #[serde(default)]
    pub missed_ticks: u64,
    /// What the component publishes about itself, when it does: a player's `position_s`, `duration_s`,
    /// `playing`, `speed`, `loop` and `tracks`; a recorder's `recording`, `path` and `bytes`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub status: Option<serde_json::Value>,
    /// The execution group it runs in; absent: a thread of its own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub group: Option<String>,
}

/// One execution group's statistics: the thread that runs its members one after the other.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GroupTelemetry {
    /// The group's name.
    pub name: String,
    /// Its members' ids, in the order they run.
    pub members: Vec<String>,
    /// Passes per second lately (a pass calls every member that has something to do).
    pub pass_rate_hz: f64,
    /// Share of one core its thread used lately (0 to 1).
    pub cpu_share: f64,
    /// The mean pass lately, in nanoseconds.
    pub mean_pass_ns: u64,
    /// The longest pass so far, in nanoseconds.
    pub longest_pass_ns: u64,
    /// Periodic ticks its members skipped so far because a pass ran past them.
    pub missed_ticks: u64,
    /// The member that took most of the longest pass.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub slowest_member: Option<String>,
}

/// Statistics of the whole diagram at one instant.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Telemetry {
    /// When, on the runtime clock (ns since the UNIX epoch).
    pub at_ns: i64,
    /// The runtime's state.
    pub state: RuntimeState,
    /// Per link.
    pub links: Vec<LinkTelemetry>,
    /// Per component.
    pub components: Vec<ComponentTelemetry>,
    /// The runtime clock, when a component of the diagram disciplines it (a GNSS receiver).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clock: Option<ClockTelemetry>,
    /// Per execution group.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub groups: Vec<GroupTelemetry>,
    /// With a diagram spread over hosts and coordinated here: each host's state and clock. Their
    /// components and links are in `components` and `links` beside this runtime's own.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub hosts: Vec<HostTelemetry>,
    /// With a diagram spread over hosts: each connection between two of them, as its link ends count it.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cross_links: Vec<CrossLinkTelemetry>,
}

/// A host of a spread diagram, as the runtime coordinating it sees it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HostTelemetry {
    /// Its name in the diagram's hosts section.
    pub name: String,
    /// Whether it answers; `false`: lost, its part is deployed again when it answers.
    pub answering: bool,
    /// Its runtime's state, when it answers.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub state: Option<RuntimeState>,
    /// Its clock, when it follows a master or disciplines its clock.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clock: Option<ClockTelemetry>,
}

/// A connection between two hosts, counted at its ends.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CrossLinkTelemetry {
    /// The producer's output, `component.port`.
    pub from: String,
    /// The consumer's input, `component.port`.
    pub to: String,
    /// The producer's host; absent: the coordinating runtime's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub from_host: Option<String>,
    /// The consumer's host; absent: the coordinating runtime's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub to_host: Option<String>,
    /// Samples sent by the producer's end.
    pub sent: u64,
    /// Samples received by the consumer's end.
    pub received: u64,
    /// Samples lost in transit (sequence gaps).
    pub lost: u64,
    /// Whether the sender sees its receiver.
    pub matched: bool,
    /// How long ago the last sample arrived, ms.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub last_sample_age_ms: Option<u64>,
    /// From how long a quiet is unusual on this link, ms: twice the longest recent wait between its
    /// arrivals, at least 400 ms, as its receiver learnt it; absent until it learnt one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub quiet_after_ms: Option<u64>,
    /// Time in transit over the last 256 samples, median and most, ns: the receiving host's clock at
    /// arrival less the time of issue on the producer's host (their clocks synchronised).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transit_p50_ns: Option<i64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[allow(missing_docs, reason = "with transit_p50_ns")]
    pub transit_max_ns: Option<i64>,
}

/// How long a link between hosts may have delivered nothing, while samples were sent that its receiver
/// never got, before it is said to deliver nothing (by `kairos deploy` and the studio), until its
/// receiver learnt how long it usually waits (`quiet_after_ms`).
pub const LINK_QUIET_MS: u64 = 1500;

impl CrossLinkTelemetry {
    /// Whether the link matches yet delivers nothing now (see [`link_delivers_nothing`]).
    pub fn delivers_nothing(&self) -> bool {
        link_delivers_nothing(
            self.matched,
            self.sent,
            self.received + self.lost,
            self.last_sample_age_ms,
            self.quiet_after_ms,
        )
    }
}

/// Whether a link whose sender sees its receiver (`matched`) delivers nothing: of the `sent` samples,
/// only `arrived` reached the receiver (received or counted lost), and it has received nothing for
/// `quiet_after_ms` (what its receiver learnt is unusual for it), or [`LINK_QUIET_MS`] before it
/// learnt (`quiet_ms`: its last sample's age; `None`, none yet). Its consumer is stalled, or the path
/// between the hosts carries nothing though both ends still see each other (seen for minutes after a
/// reconnection that flapped once more). The two ends' statuses are read at different instants (a
/// receiver's quiet may end just after a sender's new sample): said only when it holds at two looks.
pub fn link_delivers_nothing(
    matched: bool,
    sent: u64,
    arrived: u64,
    quiet_ms: Option<u64>,
    quiet_after_ms: Option<u64>,
) -> bool {
    let quiet_after = quiet_after_ms.unwrap_or(LINK_QUIET_MS);
    matched && sent > arrived && quiet_ms.is_none_or(|quiet| quiet >= quiet_after)
}

/// Where a runtime's clock stands against its reference, on the wire as its snake-case name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ClockState {
    /// No time from the source yet.
    Acquiring,
    /// Following the source, its last error under 10 ms.
    Locked,
    /// Following the source, a larger error being slewed away at 1 ms/s.
    Slewing,
    /// No time from the source for 3 s: running on at the last rate.
    Holdover,
    /// No time from the source for 30 s.
    Lost,
    /// A clock Kairos only measures (the system clock, kept by PTP or chrony) further from its reference
    /// than the bound set.
    Alarm,
    /// The clock master itself (`kairos serve --clock-master`): the reference of the others.
    Master,
    /// A state of a newer runtime this client does not know.
    #[serde(other)]
    Unknown,
}

impl ClockState {
    /// Its name, as on the wire: `locked`.
    pub fn name(self) -> &'static str {
        match self {
            ClockState::Acquiring => "acquiring",
            ClockState::Locked => "locked",
            ClockState::Slewing => "slewing",
            ClockState::Holdover => "holdover",
            ClockState::Lost => "lost",
            ClockState::Alarm => "alarm",
            ClockState::Master => "master",
            ClockState::Unknown => "unknown",
        }
    }

    /// Whether the clock agrees with its reference: locked to it, or the reference itself.
    pub fn agrees(self) -> bool {
        matches!(self, ClockState::Locked | ClockState::Master)
    }

    /// Whether an error measured against the reference means something yet (not for the reference
    /// itself, nor before the first exchange).
    pub fn has_error(self) -> bool {
        !matches!(self, ClockState::Master | ClockState::Acquiring)
    }
}

impl std::fmt::Display for ClockState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A runtime clock that follows a component of the diagram.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClockTelemetry {
    /// The component it follows.
    pub source: String,
    /// Where it stands against its source.
    pub state: ClockState,
    /// The source's time minus the clock's at its last reference, ns.
    pub error_ns: i64,
    /// How far the first reference stepped the clock from the machine's, ns.
    pub step_ns: i64,
    /// References taken.
    pub references: u64,
    /// Seconds since the last one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub since_reference_s: Option<f64>,
    /// How far from its source the clock may be, when the source can tell (a clock master: half the
    /// round trip of the exchange used), ns.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error_bound_ns: Option<i64>,
    /// The rate correction applied (the master's pace against this machine's), ppm, when estimated.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rate_ppm: Option<f64>,
}

/// Where a runtime's links to other hosts travel: one Zenoh session, listening and connecting on explicit
/// endpoints (`tcp/192.168.1.10:7447`), with scouting off.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct LinkNetwork {
    /// Where this runtime listens for the other hosts.
    #[serde(default)]
    pub listen: Vec<String>,
    /// The other hosts' endpoints this runtime connects to.
    #[serde(default)]
    pub connect: Vec<String>,
    /// The certificates (PEM) to trust on `tls/` endpoints: those of the hosts section.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub trusted_certificates: Vec<String>,
}

/// The result of `foxglove_publish` and `foxglove`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct FoxgloveState {
    /// Where Foxglove connects (`ws://127.0.0.1:8765`); absent when no server runs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub address: Option<String>,
    /// Every output of the deployed diagram is published.
    #[serde(default)]
    pub all: bool,
    /// The outputs published, when not `all`.
    #[serde(default)]
    pub outputs: Vec<String>,
    /// Foxglove clients connected now.
    #[serde(default)]
    pub clients: usize,
}

/// The result of `ros2_topics`: by name.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Ros2TopicList {
    /// Each topic with a publisher or a subscription on the graph.
    pub topics: Vec<Ros2Topic>,
    /// Each service with a server or a client on the graph.
    #[serde(default)]
    pub services: Vec<Ros2Service>,
}

/// One ROS 2 service on the graph.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Ros2Service {
    /// `/reset`.
    pub name: String,
    /// `std_srvs/srv/Trigger`.
    #[serde(rename = "type")]
    pub type_name: String,
    /// Its servers.
    pub servers: u32,
    /// Its clients.
    pub clients: u32,
}

/// One ROS 2 topic on the graph.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Ros2Topic {
    /// `/imu/data`.
    pub name: String,
    /// `sensor_msgs/msg/Imu`.
    #[serde(rename = "type")]
    pub type_name: String,
    /// Its publishers.
    pub publishers: u32,
    /// Its subscriptions.
    pub subscriptions: u32,
}

/// The result of `links`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct LinkList {
    /// Each end of a link to another host held by the deployed diagram.
    pub links: Vec<LinkEnd>,
}

/// One end of a link between hosts.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct LinkEnd {
    /// The component carrying it (placed by `kairos deploy`).
    pub component: String,
    /// The Zenoh key its samples travel under.
    pub key: String,
    /// `sender` or `receiver`.
    pub role: String,
    /// The far end, in words (`fusion.imu on host 'roadside'`).
    pub peer: String,
    /// For a sender: whether a receiver matches it. A receiver cannot tell; it says `true` once it has
    /// received a sample.
    pub matched: bool,
}

/// The result of `devices`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct DeviceList {
    /// Serial ports first, each kind by path.
    pub devices: Vec<DeviceInfo>,
}

/// One device of the runtime's machine.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct DeviceInfo {
    /// Its kind; a property marked with the same kind names such devices.
    pub kind: kairos_diagram::DeviceKind,
    /// What a property takes: a device path (`/dev/ttyUSB0`) or an interface name (`can0`).
    pub path: String,
    /// What it is, where the system says (`FTDI FT232R USB UART`, `UVC Camera`), and a state.
    pub description: String,
}

/// One log record.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct LogRecord {
    /// Wall-clock time, ns since the UNIX epoch.
    pub at_ns: i64,
    /// The level.
    pub level: LogLevel,
    /// The component it concerns, when one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub component: Option<String>,
    /// The text.
    pub message: String,
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::{
        ComponentState, ComponentTelemetry, ErrorCode, Reply, ReplyBody, RequestBody, RequestKind, Role,
        SamplesSubscribed, ServerMessage, Started, decode_request, encode_result,
    };

    #[test]
    fn every_request_type_has_a_name_and_a_role() {
        let mut names = std::collections::BTreeSet::new();
        for kind in RequestKind::ALL {
            assert!(names.insert(kind.name()), "two requests named {}", kind.name());
            assert_eq!(serde_json::to_value(kind).unwrap(), kind.name());
            let _ = kind.required_role();
        }
        assert_eq!(RequestKind::SetProperty.name(), "set_property");
        assert_eq!(RequestKind::Status.required_role(), Role::Monitor);
        assert_eq!(RequestKind::Deploy.required_role(), Role::Operator);
    }

    #[test]
    fn requests_decode_with_their_fields() {
        let request = decode_request(
            r#"{"id": 4, "type": "set_property", "component": "gain1", "property": "gain", "value": 2.5}"#,
        )
        .unwrap();
        assert_eq!(request.id, 4);
        assert_eq!(request.body.kind(), RequestKind::SetProperty);
        let RequestBody::SubscribeSamples { max_rate_hz, .. } =
            decode_request(r#"{"id": 5, "type": "subscribe_samples", "outputs": ["a.b"]}"#)
                .unwrap()
                .body
        else {
            panic!("wrong variant");
        };
        assert!((max_rate_hz - 10.0).abs() < f64::EPSILON);
    }

    #[test]
    fn broken_requests_say_what_is_wrong_and_keep_the_id_when_they_can() {
        let cases = [
            ("not json", None, "not JSON"),
            ("[1, 2]", None, "JSON object"),
            (r#"{"type": "start"}"#, None, "\"id\""),
            (r#"{"id": 3}"#, Some(3), "\"type\""),
            (
                r#"{"id": 3, "type": "explode"}"#,
                Some(3),
                "unknown request type 'explode'",
            ),
            (
                r#"{"id": 3, "type": "deploy"}"#,
                Some(3),
                "missing field `diagram`",
            ),
            (
                r#"{"id": 3, "type": "deploy", "diagram": 7}"#,
                Some(3),
                "invalid type",
            ),
        ];
        for (text, id, needle) in cases {
            let (got_id, error) = decode_request(text).unwrap_err();
            assert_eq!(got_id, id, "{text}");
            assert_eq!(error.code, ErrorCode::BadRequest);
            assert!(error.message.contains(needle), "{text}: {}", error.message);
        }
    }

    /// The reply as a client reads it off the wire.
    fn over_the_wire(message: &ServerMessage) -> Reply {
        let text = serde_json::to_string(message).unwrap();
        let ServerMessage::Reply(reply) = serde_json::from_str(&text).unwrap() else {
            panic!("not a reply: {text}");
        };
        reply
    }

    #[test]
    fn replies_are_written_as_before_and_read_back_as_their_request_type() {
        let done = ServerMessage::ok(7, &ReplyBody::Start(Started::default()));
        assert_eq!(
            serde_json::to_string(&done).unwrap(),
            r#"{"type":"reply","id":7,"ok":true,"result":{}}"#
        );
        assert_eq!(
            over_the_wire(&done).decode(RequestKind::Start),
            Ok(ReplyBody::Start(Started::default()))
        );
        let subscribed = ReplyBody::SubscribeSamples(SamplesSubscribed {
            max_rate_hz: 15.0,
            services: None,
        });
        let message = ServerMessage::ok(9, &subscribed);
        assert_eq!(
            serde_json::to_value(&message).unwrap()["result"],
            serde_json::json!({"max_rate_hz": 15.0})
        );
        assert_eq!(
            over_the_wire(&message).decode(RequestKind::SubscribeSamples),
            Ok(subscribed)
        );
        let shared = ReplyBody::SubscribeSamples(SamplesSubscribed {
            max_rate_hz: 30.0,
            services: Some(BTreeMap::from([(
                "camera.image".to_owned(),
                "kairos/1/2/3/camera.image".to_owned(),
            )])),
        });
        assert_eq!(
            over_the_wire(&ServerMessage::ok(9, &shared)).decode(RequestKind::SubscribeSamples),
            Ok(shared)
        );
    }

    #[test]
    fn a_reply_that_does_not_fit_its_request_or_was_refused_is_an_error_for_the_client() {
        let status = over_the_wire(&ServerMessage::ok(3, &ReplyBody::Start(Started::default())));
        let error = status.decode(RequestKind::Status).unwrap_err();
        assert_eq!(error.code, ErrorCode::Internal);
        assert!(
            error.message.contains("'status'") && error.message.contains("missing field"),
            "{}",
            error.message
        );
        let refused = over_the_wire(&ServerMessage::error(
            Some(3),
            super::ProtocolError::new(ErrorCode::WrongState, "nothing is running"),
        ));
        assert_eq!(
            refused.decode(RequestKind::Pause).unwrap_err().code,
            ErrorCode::WrongState
        );
    }

    #[test]
    fn a_result_that_cannot_be_written_is_an_error_naming_the_request_and_the_cause() {
        // JSON object keys must be text: a map keyed by pairs cannot be written.
        let unwritable = BTreeMap::from([((1_u8, 2_u8), 3_u8)]);
        let error = encode_result(RequestKind::Status, &unwritable).unwrap_err();
        assert_eq!(error.code, ErrorCode::Internal);
        assert!(
            error.message.contains("'status'") && error.message.contains("key must be a string"),
            "{}",
            error.message
        );
    }

    #[test]
    fn component_states_travel_as_words_and_unknown_ones_do_not_break_telemetry() {
        let states = [
            (ComponentState::Idle, "idle"),
            (ComponentState::Running, "running"),
            (ComponentState::Paused, "paused"),
            (ComponentState::Finished, "finished"),
            (ComponentState::Stopped, "stopped"),
            (ComponentState::Failed, "failed"),
        ];
        for (state, word) in states {
            assert_eq!(serde_json::to_value(state).unwrap(), word);
            assert_eq!(state.word(), word);
            assert_eq!(
                serde_json::from_value::<ComponentState>(word.into()).unwrap(),
                state
            );
        }
        // A newer server's state: the rest of the component's figures still arrive.
        let component: ComponentTelemetry = serde_json::from_value(serde_json::json!({
            "id": "gain1", "type_name": "core.gain", "state": "hibernating",
            "cycles": 3, "cycle_rate_hz": 1.0, "cpu_share": 0.0,
        }))
        .unwrap();
        assert_eq!((component.state, component.cycles), (ComponentState::Unknown, 3));
    }
}
