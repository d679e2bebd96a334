//! Requests, replies and events: the JSON text messages.

use std::collections::BTreeMap;

use kairos_diagram::{Diagnostic, ReaderPolicy, Value};
use serde::{Deserialize, Serialize};

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

/// Every request, by its `type`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum RequestBody {
    /// The first message of a session: the protocol version, who is calling, the token, the role wanted.
    Hello {
        /// The client's protocol version; must equal the server's.
        protocol: u32,
        /// A name for logs (`kairos-studio 0.1.0`, `demo.py`).
        client: String,
        /// The server's token, when it has one.
        #[serde(default)]
        token: Option<String>,
        /// The role wanted (default: operator).
        #[serde(default)]
        role: Option<Role>,
    },
    /// The component library: packs, component types, ports, properties, actions, docs.
    Library,
    /// The ports of the instances of a diagram (RON text, not deployed) whose ports depend on their
    /// properties (a player's outputs follow its recordings). Replies a [`Described`].
    DescribeInstances {
        /// The diagram file's text.
        diagram: String,
    },
    /// The deployed diagram's text.
    GetDiagram,
    /// Validates a diagram (RON text) and, if valid, makes it the runtime's diagram, stopping the old one.
    Deploy {
        /// The diagram file's text.
        diagram: String,
    },
    /// Starts the deployed diagram.
    Start,
    /// Pauses it.
    Pause,
    /// Resumes it after a pause.
    Resume,
    /// Stops it (it can be started again).
    Stop,
    /// Changes a property, validated; a refused value keeps the old one and the error says why.
    SetProperty {
        /// The component's id.
        component: String,
        /// The property.
        property: String,
        /// The new value.
        value: Value,
    },
    /// Triggers a component's action.
    TriggerAction {
        /// The component's id.
        component: String,
        /// The action.
        action: String,
    },
    /// The runtime's state and each component's.
    Status,
    /// Telemetry events every `interval_ms` (at least 20).
    SubscribeTelemetry {
        /// The period.
        interval_ms: u64,
    },
    /// No more telemetry.
    UnsubscribeTelemetry,
    /// Binary sample frames from these outputs (`camera.image`), at most `max_rate_hz` per output, the
    /// latest sample each time (a slow client gets fewer, never older ones).
    SubscribeSamples {
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
    },
    /// Stops sample frames from these outputs (all, when empty).
    UnsubscribeSamples {
        /// The outputs.
        #[serde(default)]
        outputs: Vec<String>,
    },
    /// Log events at `level` and above.
    SubscribeLog {
        /// The least important level sent.
        #[serde(default)]
        level: LogLevel,
    },
    /// No more log events.
    UnsubscribeLog,
    /// Starts a recorder (its `start` action).
    RecordStart {
        /// The recorder's id.
        component: String,
    },
    /// Stops a recorder and closes its file.
    RecordStop {
        /// The recorder's id.
        component: String,
    },
    /// Closes a recorder's file and goes on in a new one.
    RecordSplit {
        /// The recorder's id.
        component: String,
    },
    /// Plays (resumes) a player.
    PlayerPlay {
        /// The player's id.
        component: String,
    },
    /// Pauses a player.
    PlayerPause {
        /// The player's id.
        component: String,
    },
    /// Makes a paused player emit one sample.
    PlayerStep {
        /// The player's id.
        component: String,
    },
    /// Jumps to a time, in seconds from the recording's first message.
    PlayerSeek {
        /// The player's id.
        component: String,
        /// Where to.
        seconds: f64,
    },
    /// Sets the replay speed (0.1 to 100).
    PlayerSpeed {
        /// The player's id.
        component: String,
        /// The factor.
        factor: f64,
    },
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

/// A request's type without its fields: what the role table is keyed by.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[allow(missing_docs, reason = "one per request; RequestBody documents each")]
pub enum RequestKind {
    Hello,
    Library,
    DescribeInstances,
    GetDiagram,
    Deploy,
    Start,
    Pause,
    Resume,
    Stop,
    SetProperty,
    TriggerAction,
    Status,
    SubscribeTelemetry,
    UnsubscribeTelemetry,
    SubscribeSamples,
    UnsubscribeSamples,
    SubscribeLog,
    UnsubscribeLog,
    RecordStart,
    RecordStop,
    RecordSplit,
    PlayerPlay,
    PlayerPause,
    PlayerStep,
    PlayerSeek,
    PlayerSpeed,
}

impl RequestKind {
    /// Every request type.
    pub const ALL: [RequestKind; 26] = [
        RequestKind::Hello,
        RequestKind::Library,
        RequestKind::DescribeInstances,
        RequestKind::GetDiagram,
        RequestKind::Deploy,
        RequestKind::Start,
        RequestKind::Pause,
        RequestKind::Resume,
        RequestKind::Stop,
        RequestKind::SetProperty,
        RequestKind::TriggerAction,
        RequestKind::Status,
        RequestKind::SubscribeTelemetry,
        RequestKind::UnsubscribeTelemetry,
        RequestKind::SubscribeSamples,
        RequestKind::UnsubscribeSamples,
        RequestKind::SubscribeLog,
        RequestKind::UnsubscribeLog,
        RequestKind::RecordStart,
        RequestKind::RecordStop,
        RequestKind::RecordSplit,
        RequestKind::PlayerPlay,
        RequestKind::PlayerPause,
        RequestKind::PlayerStep,
        RequestKind::PlayerSeek,
        RequestKind::PlayerSpeed,
    ];

    /// The role table: the least role allowed to make this request.
    pub fn required_role(self) -> Role {
        match self {
            RequestKind::Hello
            | RequestKind::Library
            | RequestKind::DescribeInstances
            | RequestKind::GetDiagram
            | RequestKind::Status
            | RequestKind::SubscribeTelemetry
            | RequestKind::UnsubscribeTelemetry
            | RequestKind::SubscribeSamples
            | RequestKind::UnsubscribeSamples
            | RequestKind::SubscribeLog
            | RequestKind::UnsubscribeLog => Role::Monitor,
            RequestKind::Deploy
            | RequestKind::Start
            | RequestKind::Pause
            | RequestKind::Resume
            | RequestKind::Stop
            | RequestKind::SetProperty
            | RequestKind::TriggerAction
            | RequestKind::RecordStart
            | RequestKind::RecordStop
            | RequestKind::RecordSplit
            | RequestKind::PlayerPlay
            | RequestKind::PlayerPause
            | RequestKind::PlayerStep
            | RequestKind::PlayerSeek
            | RequestKind::PlayerSpeed => Role::Operator,
        }
    }

    /// The `type` string of the request.
    pub fn name(self) -> String {
        serde_json::to_value(self)
            .ok()
            .and_then(|v| v.as_str().map(str::to_owned))
            .unwrap_or_default()
    }
}

impl RequestBody {
    /// The request's type.
    pub fn kind(&self) -> RequestKind {
        match self {
            RequestBody::Hello { .. } => RequestKind::Hello,
            RequestBody::Library => RequestKind::Library,
            RequestBody::DescribeInstances { .. } => RequestKind::DescribeInstances,
            RequestBody::GetDiagram => RequestKind::GetDiagram,
            RequestBody::Deploy { .. } => RequestKind::Deploy,
            RequestBody::Start => RequestKind::Start,
            RequestBody::Pause => RequestKind::Pause,
            RequestBody::Resume => RequestKind::Resume,
            RequestBody::Stop => RequestKind::Stop,
            RequestBody::SetProperty { .. } => RequestKind::SetProperty,
            RequestBody::TriggerAction { .. } => RequestKind::TriggerAction,
            RequestBody::Status => RequestKind::Status,
            RequestBody::SubscribeTelemetry { .. } => RequestKind::SubscribeTelemetry,
            RequestBody::UnsubscribeTelemetry => RequestKind::UnsubscribeTelemetry,
            RequestBody::SubscribeSamples { .. } => RequestKind::SubscribeSamples,
            RequestBody::UnsubscribeSamples { .. } => RequestKind::UnsubscribeSamples,
            RequestBody::SubscribeLog { .. } => RequestKind::SubscribeLog,
            RequestBody::UnsubscribeLog => RequestKind::UnsubscribeLog,
            RequestBody::RecordStart { .. } => RequestKind::RecordStart,
            RequestBody::RecordStop { .. } => RequestKind::RecordStop,
            RequestBody::RecordSplit { .. } => RequestKind::RecordSplit,
            RequestBody::PlayerPlay { .. } => RequestKind::PlayerPlay,
            RequestBody::PlayerPause { .. } => RequestKind::PlayerPause,
            RequestBody::PlayerStep { .. } => RequestKind::PlayerStep,
            RequestBody::PlayerSeek { .. } => RequestKind::PlayerSeek,
            RequestBody::PlayerSpeed { .. } => RequestKind::PlayerSpeed,
        }
    }
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

/// The answer to one request.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Reply {
    /// The request's id; `null` when the request was too broken to have one.
    pub id: Option<u64>,
    /// Whether it succeeded.
    pub ok: bool,
    /// What it returned, when it succeeded (its shape depends on the request: see the docs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub result: Option<serde_json::Value>,
    /// Why it failed, when it did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<ProtocolError>,
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
    /// A successful reply.
    pub fn ok(id: u64, result: serde_json::Value) -> Self {
        ServerMessage::Reply(Reply {
            id: Some(id),
            ok: true,
            result: Some(result),
            error: None,
        })
    }

    /// A failed reply.
    pub fn error(id: Option<u64>, error: ProtocolError) -> Self {
        ServerMessage::Reply(Reply {
            id,
            ok: false,
            result: None,
            error: Some(error),
        })
    }
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
    let known = RequestKind::ALL.iter().any(|k| k.name() == kind);
    if !known {
        let names: Vec<String> = RequestKind::ALL.iter().map(|k| k.name()).collect();
        return Err((
            id,
            ProtocolError::new(
                ErrorCode::BadRequest,
                format!("unknown request type '{kind}'; known: {}", names.join(", ")),
            ),
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
    pub telemetry: Option<Telemetry>,
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

/// One component's statistics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ComponentTelemetry {
    /// The id.
    pub id: String,
    /// The component type.
    pub type_name: String,
    /// `idle`, `running`, `paused`, `finished`, `stopped` or `failed`.
    pub state: String,
    /// Why it failed, when it did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// `core` calls completed.
    pub cycles: u64,
    /// Cycles per second lately.
    pub cycle_rate_hz: f64,
    /// Share of one core lately (0 to 1).
    pub cpu_share: f64,
    /// What the component publishes about itself, when it does: a player's `position_s`, `duration_s`,
    /// `playing`, `speed`, `loop` and `tracks`; a recorder's `recording`, `path` and `bytes`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub status: Option<serde_json::Value>,
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
    use super::{ErrorCode, RequestBody, RequestKind, Role, decode_request};

    #[test]
    fn every_request_type_has_a_name_and_a_role() {
        for kind in RequestKind::ALL {
            assert!(!kind.name().is_empty(), "{kind:?}");
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
}
