//! The studio's side of the control protocol: one connection to a runtime, on a thread of its own, so the
//! interface never waits for the network.
//!
//! Events reach the interface through one bounded channel ([`EVENT_QUEUE`] events). When the interface
//! falls that far behind, what the runtime sends again anyway (telemetry every 250 ms, sample frames up to
//! 30 a second per output, log records) is dropped and counted ([`DroppedEvents`], which the studio reports
//! in its log); what answers the studio (replies, the session's start and end, the shared-memory reader's
//! start) is never dropped: the connection's thread waits for room instead, which the interface makes at
//! its next frame.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, Sender, SyncSender, TryRecvError, TrySendError, channel, sync_channel};
use std::time::Duration;

use kairos_client::{CallError, ConnectError, ConnectOptions, Connection, Fixes};
use kairos_protocol::{
    ErrorCode, LogRecord, ProtocolError, Reply, ReplyBody, Request, RequestBody, RequestKind, RuntimeState,
    ServerMessage, Telemetry, Token, Welcome,
};
use tungstenite::Message;

/// How many events wait for the interface at most. A frame of the interface takes them all; 256 covers
/// several seconds of a stalled interface at the rates the studio subscribes to (4 telemetry events a
/// second, 30 frames a second per viewed output), while bounding the memory held by queued image frames.
pub const EVENT_QUEUE: usize = 256;

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
    /// Whether the shared-memory reader asked for with [`RuntimeClient::receive_shared`] could open its
    /// services; on an error, no frames come from it.
    SharedMemory(Result<(), crate::shared::SharedMemoryError>),
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
    pub(crate) fn of(reply: Reply, kind: Option<RequestKind>) -> Answer {
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

/// Events dropped because the interface fell [`EVENT_QUEUE`] events behind, by kind, since the
/// connection began.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DroppedEvents {
    /// Sample frames (viewers show the next one).
    pub samples: u64,
    /// Telemetry events (the next comes within a second).
    pub telemetry: u64,
    /// Log records.
    pub log: u64,
}

/// The counters behind [`DroppedEvents`], shared by the threads that send events.
#[derive(Debug, Default)]
struct DropCounters {
    samples: AtomicU64,
    telemetry: AtomicU64,
    log: AtomicU64,
}

/// Calls that repaint the interface when something arrived.
type Wake = Arc<dyn Fn() + Send + Sync>;

/// The sending end of the interface's event channel: bounded, dropping (and counting) only events that
/// the runtime sends again anyway, waking the interface after each event.
#[derive(Clone)]
pub struct EventSender {
    sender: SyncSender<ClientEvent>,
    dropped: Arc<DropCounters>,
    wake: Wake,
    /// The last telemetry passed on while nothing ran, its time left out.
    resting: Arc<std::sync::Mutex<Option<Telemetry>>>,
}

impl std::fmt::Debug for EventSender {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EventSender").finish_non_exhaustive()
    }
}

impl EventSender {
    /// Hands `event` to the interface and wakes it. Telemetry, samples and log records are dropped and
    /// counted when the queue is full; other events wait for room. False once the interface is gone.
    pub fn send(&self, event: ClientEvent) -> bool {
        if let ClientEvent::Telemetry(telemetry) = &event
            && self.unchanged_at_rest(telemetry)
        {
            return true;
        }
        let counter = match &event {
            ClientEvent::Sample(..) => Some(&self.dropped.samples),
            ClientEvent::Telemetry(_) => Some(&self.dropped.telemetry),
            ClientEvent::Log(_) => Some(&self.dropped.log),
            ClientEvent::Connected(_)
            | ClientEvent::Reply(_)
            | ClientEvent::SharedMemory(_)
            | ClientEvent::Disconnected(_) => None,
        };
        let sent = match counter {
            Some(counter) => match self.sender.try_send(event) {
                Ok(()) => true,
                Err(TrySendError::Full(_)) => {
                    counter.fetch_add(1, Ordering::Relaxed);
                    return true;
                }
                Err(TrySendError::Disconnected(_)) => false,
            },
            None => self.sender.send(event).is_ok(),
        };
        if sent {
            (self.wake)();
        }
        sent
    }
}

impl EventSender {
    fn new(sender: SyncSender<ClientEvent>, wake: Wake) -> EventSender {
        EventSender {
            sender,
            dropped: Arc::new(DropCounters::default()),
            wake,
            resting: Arc::new(std::sync::Mutex::new(None)),
        }
    }

    /// Whether `telemetry` says what the last one said while nothing runs: then it changes nothing on the
    /// screen and is not passed on, so a studio at rest draws nothing.
    fn unchanged_at_rest(&self, telemetry: &Telemetry) -> bool {
        let Ok(mut resting) = self.resting.lock() else {
            return false;
        };
        if matches!(telemetry.state, RuntimeState::Running | RuntimeState::Paused) {
            *resting = None;
            return false;
        }
        let timeless = Telemetry {
            at_ns: 0,
            ..telemetry.clone()
        };
        if resting.as_ref() == Some(&timeless) {
            return true;
        }
        *resting = Some(timeless);
        false
    }
}

/// A connection to a runtime.
pub struct RuntimeClient {
    url: String,
    outgoing: Sender<Request>,
    incoming: Receiver<ClientEvent>,
    next_id: u64,
    /// Where sample frames from shared memory join the other events.
    events: EventSender,
    /// The thread reading shared-memory frames, stopped by setting its flag.
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
    /// Connects to `url` with `token` on a background thread and returns at once: the outcome arrives as
    /// [`ClientEvent::Connected`] or [`ClientEvent::Disconnected`]. `wake` is called after every event (to
    /// repaint the interface).
    pub fn connect(
        url: &str,
        token: Option<Token>,
        wake: impl Fn() + Send + Sync + 'static,
    ) -> RuntimeClient {
        let options = ConnectOptions {
            token,
            ..ConnectOptions::operator(format!("kairos-studio {}", env!("CARGO_PKG_VERSION")))
        };
        Self::connect_with(url, options, wake)
    }

    /// [`RuntimeClient::connect`] with every option: the certificate to trust for a `wss://` address, and
    /// whether a token may cross the network in clear text.
    pub fn connect_with(
        url: &str,
        options: ConnectOptions,
        wake: impl Fn() + Send + Sync + 'static,
    ) -> RuntimeClient {
        let (outgoing, requests) = channel::<Request>();
        let (sender, incoming) = sync_channel(EVENT_QUEUE);
        let events = EventSender::new(sender, Arc::new(wake));
        let address = url.to_owned();
        let thread_events = events.clone();
        let spawned = std::thread::Builder::new()
            .name("studio:net".to_owned())
            .spawn(move || {
                let reason = run(&address, &options, &requests, &thread_events);
                thread_events.send(ClientEvent::Disconnected(reason));
            });
        if let Err(error) = spawned {
            // The queue is empty yet, so this does not wait.
            events.send(ClientEvent::Disconnected(format!(
                "cannot start the connection's thread: {error}"
            )));
        }
        RuntimeClient {
            url: url.to_owned(),
            outgoing,
            incoming,
            next_id: 1,
            events,
            shared: None,
        }
    }

    /// Reads sample frames from these iceoryx2 services (output → service, as a shared-memory subscription
    /// named them), in place of any read before; they arrive as [`ClientEvent::Sample`] like socket frames.
    /// Returns at once: whether the services could be opened arrives as [`ClientEvent::SharedMemory`] (on
    /// an error the caller subscribes through the socket). An empty map only stops the reading. An error
    /// here says the reader's thread could not be started.
    pub fn receive_shared(
        &mut self,
        services: BTreeMap<String, String>,
    ) -> Result<(), crate::shared::SharedMemoryError> {
        if let Some(stop) = self.shared.take() {
            stop.store(true, Ordering::Relaxed);
        }
        if services.is_empty() {
            return Ok(());
        }
        let stop = Arc::new(AtomicBool::new(false));
        let (events, stopping) = (self.events.clone(), Arc::clone(&stop));
        std::thread::Builder::new()
            .name("studio:shm".to_owned())
            .spawn(move || crate::shared::read_frames(&services, &stopping, &events))
            .map_err(|e| crate::shared::SharedMemoryError::Thread(Arc::new(e)))?;
        self.shared = Some(stop);
        Ok(())
    }

    /// The runtime's address.
    pub fn url(&self) -> &str {
        &self.url
    }

    /// Sends a request with an id of the client's choosing; returns that id, which its reply carries.
    /// (A caller that chooses ids itself uses [`RuntimeClient::send`] instead, never both.)
    pub fn request(&mut self, body: RequestBody) -> u64 {
        self.next_id += 1;
        let request = Request {
            id: self.next_id,
            body,
        };
        self.send(&request);
        self.next_id
    }

    /// Sends a request as it is. Ids above 1 are the caller's (1 is the connection's `hello`). Once the
    /// connection has ended nothing is sent; the ending was reported as [`ClientEvent::Disconnected`].
    pub fn send(&self, request: &Request) {
        // An error means the connection's thread has ended, which it reported itself. A request that
        // cannot be encoded is said there, in the log.
        let _ = self.outgoing.send(request.clone());
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

    /// How many events were dropped so far because the interface fell behind.
    pub fn dropped(&self) -> DroppedEvents {
        let counters = &self.events.dropped;
        DroppedEvents {
            samples: counters.samples.load(Ordering::Relaxed),
            telemetry: counters.telemetry.load(Ordering::Relaxed),
            log: counters.log.load(Ordering::Relaxed),
        }
    }
}

/// Why a session ended while requests were sent.
#[derive(Debug, thiserror::Error)]
enum SessionEnded {
    /// The interface is gone.
    #[error("the studio closed the connection")]
    Closed,
    /// The connection broke.
    #[error("lost the runtime at {url}: {source}")]
    Lost {
        /// The runtime's address.
        url: String,
        /// What the connection said.
        source: tungstenite::Error,
    },
}

/// Sends every request the interface queued, remembering what each asked so that its reply can be read
/// as that request's result; `Err` says why the session ends.
fn send_requests(
    socket: &mut Connection,
    requests: &Receiver<Request>,
    awaiting: &mut BTreeMap<u64, RequestKind>,
    events: &EventSender,
    url: &str,
) -> Result<(), SessionEnded> {
    let closed = || SessionEnded::Closed;
    loop {
        match requests.try_recv() {
            Ok(request) => match socket.send_request(&request) {
                Ok(()) => {
                    awaiting.insert(request.id, request.body.kind());
                }
                Err(CallError::Lost(source)) => {
                    return Err(SessionEnded::Lost {
                        url: url.to_owned(),
                        source,
                    });
                }
                Err(error) => {
                    let message = format!("a request was not sent: {error}");
                    let record = studio_record(kairos_protocol::LogLevel::Error, message);
                    if !events.send(ClientEvent::Log(record)) {
                        return Err(closed());
                    }
                }
            },
            Err(TryRecvError::Empty) => return Ok(()),
            Err(TryRecvError::Disconnected) => return Err(closed()),
        }
    }
}

/// How the studio's user fixes what the client refuses.
const FIXES: Fixes = Fixes {
    clear_text_opt_in: "start the studio with --allow-clear-text-tokens",
    certificate: "start the studio with --certificate FILE.pem",
};

/// The connection's thread: connects and says hello (through the one protocol client, which holds the TLS
/// and clear-text-token rules), then sends requests and hands on what arrives until the connection ends;
/// returns why it ended.
fn run(url: &str, options: &ConnectOptions, requests: &Receiver<Request>, events: &EventSender) -> String {
    let mut socket = match Connection::open(url, options, FIXES) {
        Ok(socket) => socket,
        Err(ConnectError::Refused(error)) => {
            return format!("the runtime at {url} refused the studio: {}", error.message);
        }
        Err(e) => return format!("cannot connect to {url}: {e}"),
    };
    // Without the timeout the thread would wait on reads and never send requests.
    if let Err(e) = socket.set_read_timeout(Some(POLL)) {
        return format!("cannot set up the connection to {url}: {e}");
    }
    let closed = "the studio closed the connection".to_owned();
    if !events.send(ClientEvent::Connected(socket.welcome().clone())) {
        return closed;
    }
    let mut not_understood: u64 = 0;
    // What each request awaiting its reply asked, to read the reply as that request's result.
    let mut awaiting: BTreeMap<u64, RequestKind> = BTreeMap::new();
    loop {
        if let Err(why) = send_requests(&mut socket, requests, &mut awaiting, events, url) {
            return why.to_string();
        }
        match socket.read() {
            Ok(Message::Text(text)) => {
                let message = match serde_json::from_str::<ServerMessage>(text.as_str()) {
                    Ok(message) => message,
                    Err(e) => {
                        // A message this studio does not understand must not end the session: it is said
                        // in the log, at the 1st, 2nd, 4th, 8th ... such message.
                        not_understood += 1;
                        if not_understood.is_power_of_two()
                            && !events.send(ClientEvent::Log(studio_record(
                                kairos_protocol::LogLevel::Warn,
                                format!(
                                    "{not_understood} message(s) from the runtime the studio does not \
                                     understand, the last: {e}"
                                ),
                            )))
                        {
                            return closed;
                        }
                        continue;
                    }
                };
                let event = match message {
                    ServerMessage::Reply(reply) => {
                        let kind = reply.id.and_then(|id| awaiting.remove(&id));
                        ClientEvent::Reply(Answer::of(reply, kind))
                    }
                    ServerMessage::Telemetry(telemetry) => ClientEvent::Telemetry(telemetry),
                    ServerMessage::Log(record) => ClientEvent::Log(record),
                };
                if !events.send(event) {
                    return closed;
                }
            }
            Ok(Message::Binary(frame)) => {
                // A frame that does not decode is skipped, as a lost one would be: one bad sample must not
                // end the session.
                if let Ok((header, payload)) = kairos_protocol::frame::decode(&frame)
                    && !events.send(ClientEvent::Sample(header, payload.to_vec()))
                {
                    return closed;
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

/// A log record of the studio's own, for what its threads have to say.
pub fn studio_record(level: kairos_protocol::LogLevel, message: String) -> LogRecord {
    let at_ns = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX));
    LogRecord {
        at_ns,
        level,
        component: None,
        message,
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;
    use std::sync::mpsc::sync_channel;
    use std::time::Duration;

    use super::{ClientEvent, EventSender};

    fn telemetry() -> ClientEvent {
        let telemetry = serde_json::json!({"at_ns": 1, "state": "running", "links": [], "components": []});
        ClientEvent::Telemetry(serde_json::from_value(telemetry).unwrap())
    }

    fn reply(id: u64) -> ClientEvent {
        let reply = serde_json::json!({"id": id, "ok": true, "result": {}});
        let reply = serde_json::from_value(reply).unwrap();
        ClientEvent::Reply(super::Answer::of(
            reply,
            Some(kairos_protocol::RequestKind::Start),
        ))
    }

    #[test]
    fn a_full_queue_drops_and_counts_telemetry_but_waits_to_deliver_replies() {
        let (sender, receiver) = sync_channel(2);
        let events = EventSender::new(sender, Arc::new(|| {}));
        for _ in 0..3 {
            assert!(events.send(telemetry()));
        }
        assert_eq!(
            events
                .dropped
                .telemetry
                .load(std::sync::atomic::Ordering::Relaxed),
            1,
            "the third did not fit"
        );
        // A reply waits for room: it arrives once the interface takes what is queued.
        let replying = events.clone();
        let thread = std::thread::Builder::new()
            .name("test:reply".to_owned())
            .spawn(move || replying.send(reply(7)))
            .unwrap();
        std::thread::sleep(Duration::from_millis(50));
        assert!(!thread.is_finished(), "the reply waits while the queue is full");
        for _ in 0..2 {
            assert!(matches!(receiver.try_recv(), Ok(ClientEvent::Telemetry(_))));
        }
        assert!(thread.join().unwrap());
        let next = receiver.recv_timeout(Duration::from_secs(5)).unwrap();
        assert!(matches!(next, ClientEvent::Reply(r) if r.id == Some(7)));
    }

    #[test]
    fn telemetry_that_changes_nothing_while_nothing_runs_is_not_passed_on() {
        let (sender, receiver) = sync_channel(16);
        let events = EventSender::new(sender, Arc::new(|| {}));
        let at = |at_ns: i64, state: &str| {
            let telemetry =
                serde_json::json!({"at_ns": at_ns, "state": state, "links": [], "components": []});
            ClientEvent::Telemetry(serde_json::from_value(telemetry).unwrap())
        };
        for (at_ns, state) in [
            (1, "running"),
            (2, "running"),
            (3, "ready"),
            (4, "ready"),
            (5, "ready"),
        ] {
            assert!(events.send(at(at_ns, state)));
        }
        assert!(events.send(at(6, "running")));
        let passed: Vec<i64> = receiver
            .try_iter()
            .map(|e| match e {
                ClientEvent::Telemetry(t) => t.at_ns,
                _ => unreachable!(),
            })
            .collect();
        assert_eq!(
            passed,
            [1, 2, 3, 6],
            "the same figures again at rest are left out"
        );
    }
}
