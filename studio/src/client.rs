//! The studio's side of the control protocol: one connection to a runtime, on a thread of its own, so the
//! interface never waits for the network.

use std::collections::BTreeMap;
use std::net::TcpStream;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, Sender, TryRecvError, channel};
use std::time::Duration;

use kairos_protocol::{
    LogRecord, PROTOCOL_VERSION, Reply, Request, RequestBody, Role, ServerMessage, Telemetry, Welcome,
};
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

/// What the connection reports.
#[derive(Debug, Clone)]
pub enum ClientEvent {
    /// The runtime accepted the session.
    Connected(Welcome),
    /// The answer to a request.
    Reply(Reply),
    /// Statistics.
    Telemetry(Telemetry),
    /// A log record.
    Log(LogRecord),
    /// A sample of a subscribed output: its header and payload bytes.
    Sample(kairos_protocol::frame::SampleHeader, Vec<u8>),
    /// The connection failed or ended, and why.
    Disconnected(String),
}

/// Calls that repaint the interface when something arrived.
type Wake = Arc<dyn Fn() + Send + Sync>;

/// A connection to a runtime.
pub struct RuntimeClient {
    url: String,
    outgoing: Sender<String>,
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
        token: Option<String>,
        wake: impl Fn() + Send + Sync + 'static,
    ) -> RuntimeClient {
        let (outgoing, requests) = channel::<String>();
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
        let _ = self
            .outgoing
            .send(serde_json::to_string(&request).unwrap_or_default());
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

fn run(
    url: &str,
    token: Option<String>,
    requests: &Receiver<String>,
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
        id: 1,
        body: RequestBody::Hello {
            protocol: PROTOCOL_VERSION,
            client: format!("kairos-studio {}", env!("CARGO_PKG_VERSION")),
            token,
            role: Some(Role::Operator),
        },
    };
    if let Err(e) = socket.send(Message::text(serde_json::to_string(&hello).unwrap_or_default())) {
        return format!("cannot talk to {url}: {e}");
    }
    loop {
        loop {
            match requests.try_recv() {
                Ok(text) => {
                    if let Err(e) = socket.send(Message::text(text)) {
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
                    ServerMessage::Reply(reply) if reply.id == Some(1) => {
                        if !reply.ok {
                            let why = reply.error.map_or_else(String::new, |e| e.message);
                            return format!("the runtime at {url} refused the studio: {why}");
                        }
                        match reply.result.and_then(|r| serde_json::from_value(r).ok()) {
                            Some(welcome) => ClientEvent::Connected(welcome),
                            None => return format!("the runtime at {url} answered hello strangely"),
                        }
                    }
                    ServerMessage::Reply(reply) => ClientEvent::Reply(reply),
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
