//! One client's session: hello, then requests answered in order, plus the event streams it subscribed to.
//!
//! Replies and events go through one bounded queue per client, written to the socket by a task of their
//! own. Events never wait for room (a slow client misses some and gets the latest next time); a client
//! whose queue is full of unread replies is disconnected. A property change or an action waits for the
//! component's answer in place (briefly; a wait that lasts moves the network runtime's other tasks aside).

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use futures_util::{SinkExt as _, StreamExt as _};
use kairos_protocol::{
    CLIENT_QUEUE, DeployResult, DiagramReply, Done, ErrorCode, LogLevel, MAX_MESSAGE_BYTES, PROTOCOL_VERSION,
    ProtocolError, ReplyBody, RequestBody, RequestKind, Role, SampleTransport, SamplesSubscribed,
    ServerMessage, Status, Telemetry, TelemetrySubscribed, Token, Welcome, decode_request,
};
use kairos_sdk_core::{Timestamp, Value};
use tokio::sync::mpsc;
use tokio::sync::mpsc::error::TrySendError;
use tokio::task::JoinHandle;
use tokio_tungstenite::tungstenite::protocol::frame::coding::CloseCode;
use tokio_tungstenite::tungstenite::protocol::{CloseFrame, WebSocketConfig};
use tokio_tungstenite::tungstenite::{Error as WsError, Message};

use super::Shared;
use super::runtime::Runtime;
use super::samples::{LatestSamples, PixelsIn};

/// The shortest telemetry period a client may ask for.
const MIN_TELEMETRY_MS: u64 = 20;
/// How often telemetry that has not changed (a stopped diagram's) is sent all the same: a client that
/// connected meanwhile or missed one still sees it soon.
const UNCHANGED_TELEMETRY_RESENT: Duration = Duration::from_secs(5);
/// The farthest ahead a start instant may be: further means clocks that disagree, or a wrong instant.
const FARTHEST_START: Duration = Duration::from_mins(1);
/// The most sample frames per second per output a client may ask for.
const MAX_SAMPLE_RATE_HZ: f64 = 120.0;

/// What the WebSocket layer reads before giving up on a message. Larger than [`MAX_MESSAGE_BYTES`] so that
/// a message over the documented limit is read whole and refused with a reply and close code 1009: a
/// connection dropped while the client still sends resets, and the client would never see the reply.
const READ_LIMIT_BYTES: usize = 16 * MAX_MESSAGE_BYTES;

fn websocket_config() -> WebSocketConfig {
    WebSocketConfig::default()
        .max_message_size(Some(READ_LIMIT_BYTES))
        .max_frame_size(Some(READ_LIMIT_BYTES))
}

/// How long the ROS 2 graph is asked for: its routers answer at once; the rest is a margin for a network.
const ROS2_GRAPH_WAIT: Duration = Duration::from_millis(1500);

/// The reply to a message over [`MAX_MESSAGE_BYTES`].
fn too_large(size: Option<usize>) -> ProtocolError {
    let size = size.map_or_else(|| "a message".to_owned(), |s| format!("a message of {s} bytes"));
    ProtocolError::new(
        ErrorCode::TooLarge,
        format!("{size} is over the limit of {MAX_MESSAGE_BYTES} bytes; the connection closes (code 1009)"),
    )
}

/// Serves one connection until the client leaves or misbehaves.
pub async fn run<S>(stream: S, peer: SocketAddr, shared: Arc<Shared>)
where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send + 'static,
{
    let websocket = match tokio_tungstenite::accept_async_with_config(stream, Some(websocket_config())).await
    {
        Ok(websocket) => websocket,
        Err(e) => {
            tracing::debug!("{peer}: not a WebSocket handshake: {e}");
            return;
        }
    };
    let (mut sink, mut source) = websocket.split();
    let (out, mut queue) = mpsc::channel::<Message>(CLIENT_QUEUE);
    let writer = tokio::spawn(async move {
        while let Some(message) = queue.recv().await {
            if sink.send(message).await.is_err() {
                return;
            }
        }
        let _ = sink.close().await;
    });
    let mut session = Session {
        peer,
        shared,
        role: None,
        out,
        telemetry: None,
        log: None,
        samples: BTreeMap::new(),
        shared_samples: BTreeMap::new(),
        upload: None,
    };
    tracing::debug!("{peer}: connected");
    while let Some(message) = source.next().await {
        let keep_going = match message {
            Ok(Message::Text(text)) if text.len() > MAX_MESSAGE_BYTES => {
                session.close_too_large(Some(text.len()));
                false
            }
            Ok(Message::Text(text)) => session.handle(text.as_str()).await,
            Ok(Message::Binary(_)) => session.refuse(
                None,
                ProtocolError::new(
                    ErrorCode::BadRequest,
                    "requests are JSON text messages; binary messages only carry sample frames from the runtime",
                ),
            ),
            Ok(Message::Close(_)) => false,
            Ok(_) => true,
            Err(WsError::Capacity(e)) => {
                tracing::debug!("{peer}: {e}");
                session.close_too_large(None);
                false
            }
            Err(e) => {
                tracing::debug!("{peer}: {e}");
                false
            }
        };
        if !keep_going {
            break;
        }
    }
    session.end();
    drop(session);
    let _ = writer.await;
    tracing::debug!("{peer}: gone");
}

struct Session {
    peer: SocketAddr,
    shared: Arc<Shared>,
    role: Option<Role>,
    out: mpsc::Sender<Message>,
    telemetry: Option<JoinHandle<()>>,
    log: Option<JoinHandle<()>>,
    samples: BTreeMap<String, JoinHandle<()>>,
    /// Outputs published in shared memory for this client; dropping one stops it.
    shared_samples: BTreeMap<String, super::shm::ShmPublication>,
    /// A pack library being received, chunk by chunk (`install_pack`).
    upload: Option<PackUpload>,
}

/// The most bytes a shipped pack library may have.
const MAX_PACK_BYTES: u64 = 512 << 20;

/// A pack library partly received.
struct PackUpload {
    name: String,
    version: String,
    size: u64,
    bytes: Vec<u8>,
}

/// `message` as JSON text. A reply holds its result as a JSON value already (`Reply::success` made a result
/// that cannot be written an `internal` error reply), and JSON values always write: this can fail only for
/// an event, which is then dropped and logged.
pub(super) fn text_of(message: &ServerMessage) -> Option<String> {
    serde_json::to_string(message)
        .inspect_err(|e| tracing::error!("cannot write a message for a client as JSON: {e}"))
        .ok()
}

/// Blocks in `wait` with the network runtime's other tasks moved to another thread meanwhile.
fn wait_aside(wait: &mut dyn FnMut()) {
    tokio::task::block_in_place(wait);
}

/// Queues a text message; `false` when the client has stopped reading (its queue is full) or is gone.
fn send(out: &mpsc::Sender<Message>, message: &ServerMessage) -> bool {
    text_of(message).is_none_or(|text| out.try_send(Message::text(text)).is_ok())
}

impl Session {
    fn runtime(&self) -> Arc<Runtime> {
        Arc::clone(&self.shared.runtime)
    }

    /// Adds one chunk of a pack library to the upload `announced` (offset 0 starts one); the chunk that
    /// completes it installs the pack.
    fn install_pack_chunk(
        &mut self,
        announced: PackUpload,
        platform: &str,
        offset: u64,
        data: &str,
    ) -> Result<kairos_protocol::PackInstall, ProtocolError> {
        use base64::Engine as _;
        let (name, version, size) = (announced.name.clone(), announced.version.clone(), announced.size);
        let here = kairos_protocol::this_platform();
        let python = platform == kairos_protocol::PYTHON_PACK_PLATFORM;
        if platform != here && !python {
            return Err(ProtocolError::new(
                ErrorCode::InvalidValue,
                format!(
                    "pack '{name}' {version} was built for {platform}, and this machine is {here}: build the \
                     pack for {here} and put it on this machine's pack path (--pack-path) instead"
                ),
            ));
        }
        if size > MAX_PACK_BYTES {
            return Err(ProtocolError::new(
                ErrorCode::TooLarge,
                format!(
                    "pack '{name}' is {size} bytes; the most a shipped pack may have is {MAX_PACK_BYTES}"
                ),
            ));
        }
        let chunk = base64::engine::general_purpose::STANDARD
            .decode(data)
            .map_err(|e| {
                ProtocolError::new(
                    ErrorCode::BadRequest,
                    format!("install_pack: `data` is not base64: {e}"),
                )
            })?;
        if offset == 0 {
            self.upload = Some(announced);
        }
        let expected = self.upload.as_ref().map_or(0, |u| u.bytes.len() as u64);
        let upload = match self.upload.as_mut() {
            Some(upload)
                if upload.name == name
                    && upload.version == version
                    && upload.size == size
                    && offset == expected =>
            {
                upload
            }
            _ => {
                return Err(ProtocolError::new(
                    ErrorCode::BadRequest,
                    format!(
                        "install_pack: a chunk at offset {offset} of pack '{name}' {version}, where {expected} was \
                         expected; start again at offset 0"
                    ),
                ));
            }
        };
        if expected + chunk.len() as u64 > upload.size {
            self.upload = None;
            return Err(ProtocolError::new(
                ErrorCode::BadRequest,
                format!(
                    "install_pack: the chunks of pack '{name}' {version} run past its size of {size} bytes"
                ),
            ));
        }
        upload.bytes.extend_from_slice(&chunk);
        let received = upload.bytes.len() as u64;
        if received < upload.size {
            return Ok(kairos_protocol::PackInstall {
                received,
                installed: false,
                path: None,
            });
        }
        let Some(complete) = self.upload.take() else {
            return Err(ProtocolError::new(
                ErrorCode::Internal,
                "install_pack: the upload vanished",
            ));
        };
        let folder = self.shared.shipped_pack_folder.clone();
        let path = tokio::task::block_in_place(|| {
            let runtime = &self.shared.runtime;
            if python {
                runtime.install_python_pack(&complete.name, &complete.version, &complete.bytes, &folder)
            } else {
                runtime.install_pack(&complete.name, &complete.version, &complete.bytes, &folder)
            }
        })?;
        Ok(kairos_protocol::PackInstall {
            received,
            installed: true,
            path: Some(path.display().to_string()),
        })
    }

    fn reply(&self, id: u64, result: &ReplyBody) -> bool {
        let delivered = send(&self.out, &ServerMessage::ok(id, result));
        if !delivered {
            tracing::warn!(
                "{}: disconnected: the client does not read its replies",
                self.peer
            );
        }
        delivered
    }

    fn refuse(&self, id: Option<u64>, error: ProtocolError) -> bool {
        send(&self.out, &ServerMessage::error(id, error))
    }

    /// Refuses a message over the limit, then closes with 1009 (message too big), in that order.
    fn close_too_large(&self, size: Option<usize>) {
        self.refuse(None, too_large(size));
        let frame = CloseFrame {
            code: CloseCode::Size,
            reason: format!("over {MAX_MESSAGE_BYTES} bytes").into(),
        };
        let _ = self.out.try_send(Message::Close(Some(frame)));
    }

    fn answer(&self, id: u64, outcome: Result<ReplyBody, ProtocolError>) -> bool {
        match outcome {
            Ok(result) => self.reply(id, &result),
            Err(error) => self.refuse(Some(id), error),
        }
    }

    /// Runs `operation`, which may block (joining threads, waiting for a component's answer), in place:
    /// the network runtime moves its other tasks to another thread meanwhile. No hop to a blocking pool,
    /// which would add two thread hand-overs to every request's round trip.
    #[allow(clippy::unused_async, reason = "callers await it like any other operation")]
    async fn blocking<T>(
        &self,
        operation: impl FnOnce(&Runtime) -> Result<T, ProtocolError>,
    ) -> Result<T, ProtocolError> {
        let runtime = self.runtime();
        tokio::task::block_in_place(|| operation(&runtime))
    }

    /// Waits until the runtime's clock reaches `at`: asleep until the last 2 ms, then looking every 50 µs.
    async fn wait_for_instant(&self, at: Timestamp) -> Result<(), ProtocolError> {
        let runtime = self.runtime();
        let ahead = at.nanos_since(runtime.now());
        if ahead > i64::try_from(FARTHEST_START.as_nanos()).unwrap_or(i64::MAX) {
            return Err(ProtocolError::new(
                ErrorCode::InvalidValue,
                format!(
                    "the instant asked for is {:.1} s away on this runtime's clock (at most {} s): the \
                     clocks disagree, or the instant is wrong",
                    ahead as f64 * 1e-9,
                    FARTHEST_START.as_secs()
                ),
            ));
        }
        let left = at.nanos_since(runtime.now());
        if left > 2_000_000 {
            tokio::time::sleep(Duration::from_nanos(u64::try_from(left - 2_000_000).unwrap_or(0))).await;
        }
        // The async timer's grain is a millisecond: the last two are waited on this thread.
        tokio::task::block_in_place(|| {
            while runtime.now() < at {
                std::thread::sleep(Duration::from_micros(50));
            }
        });
        Ok(())
    }

    /// Handles one text message; `false` ends the session.
    async fn handle(&mut self, text: &str) -> bool {
        let request = match decode_request(text) {
            Ok(request) => request,
            Err((id, error)) => return self.refuse(id, error),
        };
        let (id, kind) = (request.id, request.body.kind());
        match (self.role, kind) {
            (None, RequestKind::Hello) => {}
            (None, _) => {
                return self.refuse(
                    Some(id),
                    ProtocolError::new(
                        ErrorCode::Unauthorized,
                        format!(
                            "say hello first: {{\"id\": 1, \"type\": \"hello\", \"protocol\": {PROTOCOL_VERSION}, \"client\": \"...\", \"token\": \"...\"}}"
                        ),
                    ),
                );
            }
            (Some(_), RequestKind::Hello) => {
                return self.refuse(
                    Some(id),
                    ProtocolError::new(ErrorCode::BadRequest, "hello was already said"),
                );
            }
            (Some(role), kind) if role < kind.required_role() => {
                return self.refuse(
                    Some(id),
                    ProtocolError::new(
                        ErrorCode::Forbidden,
                        format!(
                            "'{}' needs the operator role; this session is a monitor",
                            kind.name()
                        ),
                    ),
                );
            }
            (Some(_), _) => {}
        }
        let outcome = self.dispatch(request.body).await;
        let delivered = self.answer(id, outcome);
        // A refused hello ends the session: one try per connection, so guessing tokens costs a connection
        // each.
        delivered && self.role.is_some()
    }

    /// Checks a `hello`; the session takes the role it grants.
    fn hello(
        &mut self,
        protocol: u32,
        client: &str,
        token: Option<&Token>,
        role: Option<Role>,
    ) -> Result<Welcome, ProtocolError> {
        let role = self
            .shared
            .access
            .grant(protocol, token, role)
            .inspect_err(|error| tracing::warn!("{}: refused: {}", self.peer, error.message))?;
        self.role = Some(role);
        tracing::info!("{}: {client} connected as {role:?}", self.peer);
        Ok(Welcome {
            protocol: PROTOCOL_VERSION,
            server: self.shared.server_name.clone(),
            role,
            shared_memory_host: kairos_protocol::this_host(),
            pid: Some(std::process::id()),
            platform: Some(kairos_protocol::this_platform()),
        })
    }

    /// Does what `body` asks; the result is the reply of the request's own type. Each request is one
    /// call: what it does is in the function it names.
    async fn dispatch(&mut self, body: RequestBody) -> Result<ReplyBody, ProtocolError> {
        Ok(match body {
            RequestBody::Hello {
                protocol,
                client,
                token,
                role,
            } => ReplyBody::Hello(self.hello(protocol, &client, token.as_ref(), role)?),
            RequestBody::Library => ReplyBody::Library(self.shared.runtime.library()),
            RequestBody::Devices => ReplyBody::Devices(kairos_protocol::DeviceList {
                devices: crate::devices::list(Path::new("/")),
            }),
            RequestBody::Ros2Topics { router, domain_id } => {
                ReplyBody::Ros2Topics(tokio::task::block_in_place(|| ros2_graph(&router, domain_id))?)
            }
            RequestBody::DescribeInstances { diagram } => {
                ReplyBody::DescribeInstances(tokio::task::block_in_place(|| {
                    self.shared.runtime.describe_instances(&diagram)
                })?)
            }
            RequestBody::GetDiagram => ReplyBody::GetDiagram(self.get_diagram().await?),
            RequestBody::Deploy {
                diagram,
                network,
                folder,
            } => ReplyBody::Deploy(self.deploy(diagram, network, folder).await?),
            RequestBody::PrepareDeploy { diagram, network } => ReplyBody::PrepareDeploy(
                self.blocking(move |r| r.prepare(&diagram, network.as_ref()))
                    .await?,
            ),
            RequestBody::CommitDeploy { ticket } => {
                ReplyBody::CommitDeploy(self.blocking(move |r| r.commit(ticket)).await?)
            }
            RequestBody::AbandonDeploy { ticket } => ReplyBody::AbandonDeploy(
                self.blocking(move |r| {
                    r.abandon(ticket);
                    Ok(Done {})
                })
                .await?,
            ),
            RequestBody::InstallPack {
                name,
                version,
                platform,
                size,
                offset,
                data,
            } => ReplyBody::InstallPack(self.install_pack_chunk(
                PackUpload {
                    name,
                    version,
                    size,
                    bytes: Vec::new(),
                },
                &platform,
                offset,
                &data,
            )?),
            RequestBody::Links => ReplyBody::Links(kairos_protocol::LinkList {
                links: tokio::task::block_in_place(kairos_pack_link::network::ends),
            }),
            RequestBody::Start {
                at_ns,
                forced,
                start_unlocked,
                lock_bound_ns,
            } => ReplyBody::Start(
                self.start(at_ns, forced, start_unlocked, lock_bound(lock_bound_ns)?)
                    .await?,
            ),
            RequestBody::Pause => ReplyBody::Pause(self.blocking(Runtime::pause).await.map(|()| Done {})?),
            RequestBody::Resume => ReplyBody::Resume(self.blocking(Runtime::resume).await.map(|()| Done {})?),
            RequestBody::Stop { at_ns } => ReplyBody::Stop(self.stop(at_ns).await?),
            RequestBody::SetProperty {
                component,
                property,
                value,
            } => ReplyBody::SetProperty(
                self.set_property(component, property, value)
                    .await
                    .map(|()| Done {})?,
            ),
            RequestBody::TriggerAction { component, action } => {
                ReplyBody::TriggerAction(self.action(component, action).await.map(|()| Done {})?)
            }
            RequestBody::Status => ReplyBody::Status(self.status().await?),
            RequestBody::SubscribeTelemetry { interval_ms } => {
                ReplyBody::SubscribeTelemetry(self.subscribe_telemetry(interval_ms))
            }
            RequestBody::UnsubscribeTelemetry => {
                abort(self.telemetry.take());
                ReplyBody::UnsubscribeTelemetry(Done {})
            }
            RequestBody::FoxglovePublish { outputs, publish } => {
                let shared = Arc::clone(&self.shared);
                ReplyBody::FoxglovePublish(tokio::task::block_in_place(|| {
                    shared.foxglove_publish(&outputs, publish)
                })?)
            }
            RequestBody::Foxglove => ReplyBody::Foxglove(self.shared.foxglove_state()),
            RequestBody::SubscribeLog { level } => {
                let task = self.log_task(level);
                abort(self.log.replace(task));
                ReplyBody::SubscribeLog(Done {})
            }
            RequestBody::UnsubscribeLog => {
                abort(self.log.take());
                ReplyBody::UnsubscribeLog(Done {})
            }
            RequestBody::SubscribeSamples {
                outputs,
                max_rate_hz,
                max_image_width,
                transport,
                shared_pixels,
            } => {
                let pixels_in = if shared_pixels {
                    PixelsIn::SharedMemory
                } else {
                    PixelsIn::Frame
                };
                ReplyBody::SubscribeSamples(self.subscribe_samples(
                    outputs,
                    max_rate_hz,
                    max_image_width,
                    transport,
                    pixels_in,
                )?)
            }
            RequestBody::UnsubscribeSamples { outputs } => {
                self.unsubscribe_samples(outputs);
                ReplyBody::UnsubscribeSamples(Done {})
            }
            body => self.recorder_or_player(body).await?,
        })
    }

    /// The recorder's and the player's requests: each an action or a property of the component.
    async fn recorder_or_player(&mut self, body: RequestBody) -> Result<ReplyBody, ProtocolError> {
        let (component, action, reply): (String, &str, fn(Done) -> ReplyBody) = match body {
            RequestBody::RecordStart { component } => (component, "start", ReplyBody::RecordStart),
            RequestBody::RecordStop { component } => (component, "stop", ReplyBody::RecordStop),
            RequestBody::RecordSplit { component } => (component, "split", ReplyBody::RecordSplit),
            RequestBody::PlayerPlay { component } => (component, "play", ReplyBody::PlayerPlay),
            RequestBody::PlayerPause { component } => (component, "pause", ReplyBody::PlayerPause),
            RequestBody::PlayerStep { component } => (component, "step", ReplyBody::PlayerStep),
            RequestBody::PlayerSeek { component, seconds } => {
                self.set_property(component, "seek_s".to_owned(), Value::F64(seconds))
                    .await?;
                return Ok(ReplyBody::PlayerSeek(Done {}));
            }
            RequestBody::PlayerSpeed { component, factor } => {
                self.set_property(component, "speed".to_owned(), Value::F64(factor))
                    .await?;
                return Ok(ReplyBody::PlayerSpeed(Done {}));
            }
            other => {
                return Err(ProtocolError::new(
                    ErrorCode::Internal,
                    format!("no handler for a '{}' request", other.kind().name()),
                ));
            }
        };
        self.action(component, action.to_owned()).await?;
        Ok(reply(Done {}))
    }

    /// `get_diagram`: the deployed diagram's text.
    async fn get_diagram(&mut self) -> Result<DiagramReply, ProtocolError> {
        self.blocking(|r| {
            Ok(DiagramReply {
                diagram: r.diagram_text(),
            })
        })
        .await
    }

    /// `deploy`: the diagram replaces the deployed one, joining its link network.
    async fn deploy(
        &mut self,
        diagram: String,
        network: Option<kairos_protocol::LinkNetwork>,
        folder: Option<String>,
    ) -> Result<DeployResult, ProtocolError> {
        self.blocking(move |r| r.deploy(&diagram, network.as_ref(), folder.as_deref().map(Path::new)))
            .await
    }

    /// `start`: now, or at the instant `at_ns` on this runtime's clock, saying how late it was.
    async fn start(
        &mut self,
        at_ns: Option<i64>,
        forced: Option<String>,
        start_unlocked: bool,
        lock_bound: Option<Duration>,
    ) -> Result<kairos_protocol::Started, ProtocolError> {
        if let Some(at) = at_ns {
            self.wait_for_instant(Timestamp(at)).await?;
        }
        self.blocking(move |r| r.start(forced.as_deref(), start_unlocked, lock_bound))
            .await?;
        let late_ns = at_ns.map(|at| self.runtime().now().nanos_since(Timestamp(at)));
        if let Some(late) = late_ns {
            self.runtime().record_start_lateness(late);
            if kairos_coordinator::start::started_late(late) {
                tracing::warn!("started {:.1} ms after the agreed instant", late as f64 * 1e-6);
            } else {
                tracing::info!("started at the agreed instant (+{:.0} µs)", late as f64 * 1e-3);
            }
        }
        Ok(kairos_protocol::Started { late_ns })
    }

    /// `stop`: now, or at the instant `at_ns` on this runtime's clock.
    async fn stop(&mut self, at_ns: Option<i64>) -> Result<Done, ProtocolError> {
        if let Some(at) = at_ns {
            self.wait_for_instant(Timestamp(at)).await?;
        }
        self.blocking(Runtime::stop).await?;
        Ok(Done {})
    }

    /// `status`: the runtime's state, its clock and its latest telemetry.
    async fn status(&mut self) -> Result<Status, ProtocolError> {
        self.blocking(|r| {
            let telemetry = r.telemetry();
            Ok(Status {
                state: r.state(),
                clock: r
                    .clock_telemetry()
                    .or_else(|| telemetry.as_ref().and_then(|t| t.clock.clone())),
                telemetry: telemetry.map(Box::new),
                deployment: r.deployment_identity(),
                start_late_ns: r.start_lateness(),
            })
        })
        .await
    }

    /// `subscribe_telemetry`: every `interval_ms` (at least [`MIN_TELEMETRY_MS`]), in place of any earlier.
    fn subscribe_telemetry(&mut self, interval_ms: u64) -> TelemetrySubscribed {
        let interval_ms = interval_ms.max(MIN_TELEMETRY_MS);
        let period = Duration::from_millis(interval_ms);
        let task = self.telemetry_task(period);
        abort(self.telemetry.replace(task));
        TelemetrySubscribed { interval_ms }
    }

    /// `unsubscribe_samples`: these outputs' streams end, or every stream when none is named.
    fn unsubscribe_samples(&mut self, outputs: Vec<String>) {
        let names: Vec<String> = if outputs.is_empty() {
            self.samples
                .keys()
                .chain(self.shared_samples.keys())
                .cloned()
                .collect()
        } else {
            outputs
        };
        for name in names {
            abort(self.samples.remove(&name));
            self.shared_samples.remove(&name);
        }
    }

    /// Runs in place without moving the network runtime's other tasks aside first: a component waiting for
    /// data answers within microseconds, and moving them costs the round trip two thread wake-ups. Only a
    /// wait that lasts (a busy deployment, a component in a long cycle) moves them, through
    /// [`wait_aside`].
    #[allow(clippy::unused_async, reason = "callers await it like any other operation")]
    async fn set_property(
        &self,
        component: String,
        property: String,
        value: Value,
    ) -> Result<(), ProtocolError> {
        self.runtime()
            .set_property(&component, &property, &value, &wait_aside)
    }

    #[allow(clippy::unused_async, reason = "callers await it like any other operation")]
    async fn action(&self, component: String, action: String) -> Result<(), ProtocolError> {
        self.runtime().trigger_action(&component, &action, &wait_aside)
    }

    fn telemetry_task(&self, period: Duration) -> JoinHandle<()> {
        let runtime = self.runtime();
        let out = self.out.clone();
        tokio::spawn(async move {
            let mut ticker = tokio::time::interval(period);
            ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
            let mut last_sent: Option<(Telemetry, Instant)> = None;
            loop {
                ticker.tick().await;
                let runtime = Arc::clone(&runtime);
                let Ok(Some(telemetry)) = tokio::task::spawn_blocking(move || runtime.telemetry()).await
                else {
                    continue;
                };
                // A stopped diagram's statistics do not change: sent again at every tick they would
                // only keep the client parsing and redrawing. Sent again now and then all the same.
                let now = Instant::now();
                if let Some((last, at)) = &last_sent
                    && now.duration_since(*at) < UNCHANGED_TELEMETRY_RESENT
                    && same_but_for_time(last, &telemetry)
                {
                    continue;
                }
                let Some(text) = text_of(&ServerMessage::Telemetry(telemetry.clone())) else {
                    continue;
                };
                if let Err(TrySendError::Closed(_)) = out.try_send(Message::text(text)) {
                    return;
                }
                last_sent = Some((telemetry, now));
            }
        })
    }

    fn log_task(&self, level: LogLevel) -> JoinHandle<()> {
        let mut records = crate::log_tap::subscribe();
        let out = self.out.clone();
        tokio::spawn(async move {
            loop {
                let record = match records.recv().await {
                    Ok(record) => record,
                    Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => continue,
                    Err(tokio::sync::broadcast::error::RecvError::Closed) => return,
                };
                if record.level < level {
                    continue;
                }
                let Some(text) = text_of(&ServerMessage::Log(record)) else {
                    continue;
                };
                if let Err(TrySendError::Closed(_)) = out.try_send(Message::text(text)) {
                    return;
                }
            }
        })
    }

    fn subscribe_samples(
        &mut self,
        outputs: Vec<String>,
        max_rate_hz: f64,
        max_image_width: Option<u32>,
        transport: SampleTransport,
        pixels_in: PixelsIn,
    ) -> Result<SamplesSubscribed, ProtocolError> {
        let runtime = self.runtime();
        let mut unknown = Vec::new();
        for output in &outputs {
            let known = output
                .rsplit_once('.')
                .is_some_and(|(component, port)| runtime.output(component, port).is_some());
            if !known {
                unknown.push(output.clone());
            }
        }
        if !unknown.is_empty() {
            return Err(ProtocolError::new(
                ErrorCode::NotFound,
                format!(
                    "no output {} in the deployed diagram (outputs are named component.port)",
                    unknown.join(", ")
                ),
            ));
        }
        if !(max_rate_hz > 0.0 && max_rate_hz <= MAX_SAMPLE_RATE_HZ) {
            return Err(ProtocolError::new(
                ErrorCode::InvalidValue,
                format!(
                    "max_rate_hz must be above 0 and at most {MAX_SAMPLE_RATE_HZ} frames a second per output, \
                     not {max_rate_hz}; leave it out for 10"
                ),
            ));
        }
        let rate = max_rate_hz;
        if transport == SampleTransport::SharedMemory {
            return self.subscribe_shared(outputs, rate, max_image_width, pixels_in);
        }
        for output in outputs {
            self.shared_samples.remove(&output);
            let task = sample_task(
                Arc::clone(&runtime),
                self.out.clone(),
                output.clone(),
                rate,
                max_image_width,
                self.peer,
            );
            if let Some(old) = self.samples.insert(output, task) {
                old.abort();
            }
        }
        Ok(SamplesSubscribed {
            max_rate_hz: rate,
            services: None,
        })
    }

    /// Publishes `outputs` in shared memory, one iceoryx2 service each, named in the reply.
    fn subscribe_shared(
        &mut self,
        outputs: Vec<String>,
        rate: f64,
        max_image_width: Option<u32>,
        pixels_in: PixelsIn,
    ) -> Result<SamplesSubscribed, ProtocolError> {
        if !self.peer.ip().is_loopback() {
            return Err(ProtocolError::new(
                ErrorCode::BadRequest,
                "shared memory is only for clients on the server's machine; use the socket transport",
            ));
        }
        let mut services = BTreeMap::new();
        for output in outputs {
            // A fresh name per subscription: a publisher being stopped may still hold the previous one.
            let service = format!(
                "kairos/{}/{}/{}/{output}",
                std::process::id(),
                self.peer.port(),
                super::shm::next_publication()
            );
            let started = tokio::task::block_in_place(|| {
                super::shm::publish(
                    self.runtime(),
                    output.clone(),
                    service.clone(),
                    rate,
                    max_image_width,
                    pixels_in,
                    self.peer.to_string(),
                )
            });
            match started {
                Ok(publication) => {
                    if let Some(task) = self.samples.remove(&output) {
                        task.abort();
                    }
                    self.shared_samples.insert(output.clone(), publication);
                    services.insert(output, service);
                }
                Err(error) => {
                    return Err(ProtocolError::new(
                        ErrorCode::Internal,
                        format!(
                            "cannot publish {output} in shared memory: {error}; use the socket transport"
                        ),
                    ));
                }
            }
        }
        Ok(SamplesSubscribed {
            max_rate_hz: rate,
            services: Some(services),
        })
    }

    fn end(&mut self) {
        for task in self
            .telemetry
            .take()
            .into_iter()
            .chain(self.log.take())
            .chain(std::mem::take(&mut self.samples).into_values())
        {
            task.abort();
        }
        self.shared_samples.clear();
    }
}

/// Sends the latest sample of `output` at most `rate` times a second. Its reader is LastOrNext on the
/// output's buffer: it never slows the writer, and what the client cannot take is skipped, not queued.
fn sample_task(
    runtime: Arc<Runtime>,
    out: mpsc::Sender<Message>,
    output: String,
    rate: f64,
    max_image_width: Option<u32>,
    peer: SocketAddr,
) -> JoinHandle<()> {
    tokio::spawn(async move {
        let mut ticker = tokio::time::interval(Duration::from_secs_f64(1.0 / rate));
        ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        let mut latest = LatestSamples::new(runtime, output.clone(), format!("client {peer}"));
        let mut unsent = 0;
        loop {
            ticker.tick().await;
            let Some((sample, skipped)) = latest.next() else {
                continue;
            };
            let skipped = skipped + unsent;
            let frame = super::samples::encode(&output, &sample, skipped, max_image_width);
            match out.try_send(Message::binary(frame)) {
                Ok(()) => unsent = 0,
                Err(TrySendError::Full(_)) => unsent += 1,
                Err(TrySendError::Closed(_)) => return,
            }
        }
    })
}

/// Ends a task the session no longer wants, if there is one.
fn abort(task: Option<JoinHandle<()>>) {
    if let Some(task) = task {
        task.abort();
    }
}

/// The longest lock bound a start may ask for: beyond it, clocks that far apart are not synchronised.
const MOST_LOCK_BOUND: Duration = Duration::from_secs(10);

/// A start's `lock_bound_ns`, checked: 1 ns to [`MOST_LOCK_BOUND`].
fn lock_bound(lock_bound_ns: Option<u64>) -> Result<Option<Duration>, ProtocolError> {
    let Some(ns) = lock_bound_ns else {
        return Ok(None);
    };
    let bound = Duration::from_nanos(ns);
    if bound.is_zero() || bound > MOST_LOCK_BOUND {
        return Err(ProtocolError::new(
            ErrorCode::InvalidValue,
            format!(
                "lock_bound_ns {ns}: a start's clock lock bound is from 1 ns to {} s (1 ms when absent)",
                MOST_LOCK_BOUND.as_secs()
            ),
        ));
    }
    Ok(Some(bound))
}

/// Whether two telemetries say the same but for when they were taken.
fn same_but_for_time(earlier: &Telemetry, later: &Telemetry) -> bool {
    // Taken apart field by field: a field added later must be weighed here.
    let Telemetry {
        at_ns: _,
        state,
        links,
        components,
        clock,
        groups,
        hosts,
        cross_links,
    } = earlier;
    *state == later.state
        && *links == later.links
        && *components == later.components
        && *clock == later.clock
        && *groups == later.groups
        && *hosts == later.hosts
        && *cross_links == later.cross_links
}

/// The topics and services of the ROS 2 graph `router` reaches in `domain_id`, as the protocol says them.
fn ros2_graph(router: &str, domain_id: i64) -> Result<kairos_protocol::Ros2TopicList, ProtocolError> {
    let found = kairos_pack_ros2::graph::graph(router, domain_id, ROS2_GRAPH_WAIT)
        .map_err(|e| ProtocolError::new(ErrorCode::InvalidValue, e.to_string()))?;
    Ok(kairos_protocol::Ros2TopicList {
        topics: found
            .topics
            .into_iter()
            .map(|topic| kairos_protocol::Ros2Topic {
                name: topic.name,
                type_name: topic.type_name,
                publishers: topic.publishers,
                subscriptions: topic.subscriptions,
            })
            .collect(),
        services: found
            .services
            .into_iter()
            .map(|service| kairos_protocol::Ros2Service {
                name: service.name,
                type_name: service.type_name,
                servers: service.servers,
                clients: service.clients,
            })
            .collect(),
    })
}
