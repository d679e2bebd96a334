//! The studio's side of the control protocol: one connection to a runtime, on a thread of its own, so the
//! interface never waits for the network.

use std::collections::BTreeMap;
use std::net::TcpStream;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, Sender, TryRecvError, channel};
use std::time::Duration;

use kairos_protocol::{
    ErrorCode, LogRecord, PROTOCOL_VERSION, ProtocolError, Reply, ReplyBody, Request, RequestBody,
    RequestKind, Role, ServerMessage, Telemetry, Token, Welcome,
};
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

/// What the connection reports.
#[derive(Debug, Clone)]
pub enum ClientEvent {
    /// The runtime accepted the session.
    Connected(Welcome),
    /// The answer to a request.
    Reply(Answer),
    /// Statistics.
    Telemetry(Telemetry),
    /// A log record.
    Log(LogRecord),
    /// A sample of a subscribed output: its header and payload bytes.
    Sample(kairos_protocol::frame::SampleHeader, Vec<u8>),
    /// The connection failed or ended, and why.
    Disconnected(String),
}

/// A reply, read as the answer to the request it belongs to.
#[derive(Debug, Clone)]
pub struct Answer {
    /// The request's id, as [`RuntimeClient::request`] returned it (`None` when the runtime could not read
    /// one).
    pub id: Option<u64>,
    /// The result, of the request's own type, or why the request failed.
    pub outcome: Result<ReplyBody, ProtocolError>,
}

impl Answer {
    /// Reads `reply` as the answer to the request of type `kind` (`None`: a request this client did not
    /// send, whose result it cannot read; only its error is of use).
    fn of(reply: Reply, kind: Option<RequestKind>) -> Answer {
        let id = reply.id;
        let outcome = match kind {
            Some(kind) => reply.decode(kind),
            None => Err(reply.error.unwrap_or_else(|| {
                ProtocolError::new(
                    ErrorCode::Internal,
                    format!("a reply to request {id:?}, which this client did not send"),
                )
            })),
        };
        Answer { id, outcome }
    }
}

/// Calls that repaint the interface when something arrived.
type Wake = Arc<dyn Fn() + Send + Sync>;

/// A connection to a runtime.
pub struct RuntimeClient {
    url: String,
    outgoing: Sender<Request>,
    incoming: Receiver<ClientEvent>,
    next_id: u64,
    /// Where sample frames from shared memory join the other events.
    events: Sender<ClientEvent>,
    wake: Wake,
    /// The thread reading shared-memory frames, stopped by dropping its flag's other end.
    shared: Option<Arc<AtomicBool>>,
}

impl std::fmt::Debug for RuntimeClient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RuntimeClient")
            .field("url", &self.url)
            .field("shared_memory", &self.shared.is_some())
            .finish_non_exhaustive()
    }
}

impl Drop for RuntimeClient {
    fn drop(&mut self) {
        if let Some(stop) = self.shared.take() {
            stop.store(true, Ordering::Relaxed);
        }
    }
}

/// How long a read waits before the thread looks for requests to send.
const POLL: Duration = Duration::from_millis(15);

impl RuntimeClient {
    /// Connects to `url` with `token` on a background thread; `wake` is called after every event (to
    /// repaint the interface).
    pub fn connect(
        url: &str,
        token: Option<Token>,
        wake: impl Fn() + Send + Sync + 'static,
    ) -> RuntimeClient {
        let (outgoing, requests) = channel::<Request>();
        let (events, incoming) = channel();
        let address = url.to_owned();
        let wake: Wake = Arc::new(wake);
        let (thread_events, thread_wake) = (events.clone(), Arc::clone(&wake));
        std::thread::Builder::new()
            .name("studio:net".to_owned())
            .spawn(move || {
                let reason = run(&address, token, &requests, &thread_events, &*thread_wake);
                let _ = thread_events.send(ClientEvent::Disconnected(reason));
                thread_wake();
            })
            .ok();
        RuntimeClient {
            url: url.to_owned(),
            outgoing,
            incoming,
            next_id: 1,
            events,
            wake,
            shared: None,
        }
    }

    /// Reads sample frames from these iceoryx2 services (output → service, as a shared-memory subscription
    /// named them), in place of any read before; they arrive as [`ClientEvent::Sample`] like socket frames.
    /// An error says why the services cannot be read (the caller then subscribes through the socket).
    pub fn receive_shared(&mut self, services: BTreeMap<String, String>) -> Result<(), String> {
        if let Some(stop) = self.shared.take() {
            stop.store(true, Ordering::Relaxed);
        }
        if services.is_empty() {
            return Ok(());
        }
        let stop = Arc::new(AtomicBool::new(false));
        let (ready_tx, ready_rx) = channel::<Result<(), String>>();
        let (events, wake, stopping) = (self.events.clone(), Arc::clone(&self.wake), Arc::clone(&stop));
        std::thread::Builder::new()
            .name("studio:shm".to_owned())
            .spawn(move || crate::shared::read_frames(&services, &stopping, &ready_tx, &events, &*wake))
            .map_err(|e| format!("cannot start a thread: {e}"))?;
        match ready_rx.recv_timeout(Duration::from_secs(10)) {
            Ok(Ok(())) => {
                self.shared = Some(stop);
                Ok(())
            }
            Ok(Err(error)) => Err(error),
            Err(_) => Err("the shared-memory reader did not start in 10 s".to_owned()),
        }
    }

    /// The runtime's address.
    pub fn url(&self) -> &str {
        &self.url
    }

    /// Sends a request; returns its id, which its reply carries.
    pub fn request(&mut self, body: RequestBody) -> u64 {
        self.next_id += 1;
        let request = Request {
            id: self.next_id,
            body,
        };
        let _ = self.outgoing.send(request);
        self.next_id
    }

    /// Everything that arrived since the last call.
    pub fn poll(&self) -> Vec<ClientEvent> {
        let mut events = Vec::new();
        loop {
            match self.incoming.try_recv() {
                Ok(event) => events.push(event),
                Err(TryRecvError::Empty | TryRecvError::Disconnected) => return events,
            }
        }
    }
}

/// Writes `request` on the socket.
fn send(socket: &mut WebSocket<MaybeTlsStream<TcpStream>>, request: &Request) -> Result<(), String> {
    let text = serde_json::to_string(request)
        .map_err(|e| format!("cannot write a '{}' request: {e}", request.body.kind().name()))?;
    socket.send(Message::text(text)).map_err(|e| e.to_string())
}

/// The id of the `hello` request; [`RuntimeClient::request`] numbers the others from 2.
const HELLO_ID: u64 = 1;

fn run(
    url: &str,
    token: Option<Token>,
    requests: &Receiver<Request>,
    events: &Sender<ClientEvent>,
    wake: &dyn Fn(),
) -> String {
    let mut socket: WebSocket<MaybeTlsStream<TcpStream>> = match tungstenite::connect(url) {
        Ok((socket, _)) => socket,
        Err(e) => return format!("cannot connect to {url}: {e}"),
    };
    if let MaybeTlsStream::Plain(stream) = socket.get_ref() {
        let _ = stream.set_read_timeout(Some(POLL));
        let _ = stream.set_nodelay(true);
    }
    let hello = Request {
        id: HELLO_ID,
        body: RequestBody::Hello {
            protocol: PROTOCOL_VERSION,
            client: format!("kairos-studio {}", env!("CARGO_PKG_VERSION")),
            token,
            role: Some(Role::Operator),
        },
    };
    if let Err(e) = send(&mut socket, &hello) {
        return format!("cannot talk to {url}: {e}");
    }
    // What each request awaiting its reply asked, to read the reply as that request's result.
    let mut awaiting: BTreeMap<u64, RequestKind> = BTreeMap::new();
    loop {
        loop {
            match requests.try_recv() {
                Ok(request) => {
                    awaiting.insert(request.id, request.body.kind());
                    if let Err(e) = send(&mut socket, &request) {
                        return format!("lost the runtime at {url}: {e}");
                    }
                }
                Err(TryRecvError::Empty) => break,
                Err(TryRecvError::Disconnected) => return "the studio closed the connection".to_owned(),
            }
        }
        match socket.read() {
            Ok(Message::Text(text)) => {
                let Ok(message) = serde_json::from_str::<ServerMessage>(text.as_str()) else {
                    continue;
                };
                let event = match message {
                    ServerMessage::Reply(reply) if reply.id == Some(HELLO_ID) => {
                        let refused = !reply.ok;
                        match reply.decode(RequestKind::Hello) {
                            Ok(ReplyBody::Hello(welcome)) => ClientEvent::Connected(welcome),
                            Err(error) if refused => {
                                return format!("the runtime at {url} refused the studio: {}", error.message);
                            }
                            Err(error) => {
                                return format!(
                                    "the runtime at {url} answered hello strangely: {}",
                                    error.message
                                );
                            }
                            Ok(_) => return format!("the runtime at {url} answered hello strangely"),
                        }
                    }
                    ServerMessage::Reply(reply) => {
                        let kind = reply.id.and_then(|id| awaiting.remove(&id));
                        ClientEvent::Reply(Answer::of(reply, kind))
                    }
                    ServerMessage::Telemetry(telemetry) => ClientEvent::Telemetry(telemetry),
                    ServerMessage::Log(record) => ClientEvent::Log(record),
                };
                if events.send(event).is_err() {
                    return "the studio closed the connection".to_owned();
                }
                wake();
            }
            Ok(Message::Binary(frame)) => {
                // A frame that does not decode is skipped: one bad sample must not end the session.
                if let Ok((header, payload)) = kairos_protocol::frame::decode(&frame) {
                    if events
                        .send(ClientEvent::Sample(header, payload.to_vec()))
                        .is_err()
                    {
                        return "the studio closed the connection".to_owned();
                    }
                    wake();
                }
            }
            Ok(Message::Close(_)) => return format!("the runtime at {url} closed the connection"),
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(e) => return format!("lost the runtime at {url}: {e}"),
        }
    }
}
