//! `net.tcp_receiver` and `net.tcp_sender`: a TCP connection as a client, or the clients of a server.

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::io::{ErrorKind, Read as _, Write as _};
use std::net::{SocketAddr, TcpListener, TcpStream, ToSocketAddrs as _};
use std::sync::Arc;
use std::time::Duration;

use kairos_sdk::Throttle;
use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, DescribeError, Payload,
    ReaderPolicy, TypeFilter, Value,
};

use crate::encoding::{self, SampleReceiver, SampleSender};
use crate::framing::{Deframer, Framing};

/// How long a client's read waits, so stop and control requests get through.
const READ_WAIT: Duration = Duration::from_millis(50);
/// How long a server with nothing to read sleeps before looking again.
const IDLE_WAIT: Duration = Duration::from_millis(10);
/// How often a lost connection is tried again.
const RECONNECT_AFTER: Duration = Duration::from_secs(1);
/// How long a write to one client may block before that client is dropped.
const WRITE_WAIT: Duration = Duration::from_millis(500);
/// The most clients a server keeps.
const MOST_CLIENTS: usize = 64;

fn failed(error: impl std::fmt::Display) -> ComponentError {
    ComponentError::failed(error)
}

fn mode_property() -> Property {
    Property::choice("mode", &["client", "server"], "client")
        .doc("client: connect to address; server: listen on address for clients")
}

fn resolve(address: &str) -> Result<SocketAddr, ComponentError> {
    address
        .to_socket_addrs()
        .map_err(|e| failed(format_args!("cannot resolve {address}: {e}")))?
        .next()
        .ok_or_else(|| failed(format_args!("{address} resolves to no address")))
}

fn listen(address: &str) -> Result<TcpListener, ComponentError> {
    let listener = TcpListener::bind(address)
        .map_err(|e| failed(format_args!("cannot listen on TCP {address}: {e}")))?;
    listener.set_nonblocking(true).map_err(failed)?;
    Ok(listener)
}

/// Where a TCP component's connections come from: the clients of its own server, or its one connection
/// to a server, tried again every second while there is none.
#[derive(Debug)]
enum Side {
    Server(TcpListener),
    Client { server: SocketAddr, attempts: Throttle },
}

impl Side {
    /// The side the properties `mode` and `address` ask for: listening now, or ready to connect.
    fn of(ctx: &Context) -> Result<Self, ComponentError> {
        let address = ctx.text_property("address")?;
        Ok(if ctx.text_property("mode")? == "server" {
            Side::Server(listen(&address)?)
        } else {
            Side::Client {
                server: resolve(&address)?,
                attempts: Throttle::default(),
            }
        })
    }

    fn is_server(&self) -> bool {
        matches!(self, Side::Server(_))
    }

    /// The connections made since the last call: clients waiting at the server (`room` of them at most,
    /// the others refused), or the connection to the server while `connected` is false. A failure to
    /// connect is logged through `warnings`, followed by `meanwhile`.
    fn new_connections(
        &mut self,
        connected: usize,
        warnings: &mut Throttle,
        meanwhile: &str,
    ) -> Vec<(TcpStream, String)> {
        let mut made = Vec::new();
        match self {
            Side::Server(listener) => {
                while let Ok((stream, peer)) = listener.accept() {
                    if connected + made.len() >= MOST_CLIENTS {
                        warnings.warn(|| format!("more than {MOST_CLIENTS} clients: {peer} refused"));
                        continue;
                    }
                    tracing::info!("client {peer} connected");
                    made.push((stream, peer.to_string()));
                }
            }
            Side::Client { server, attempts } => {
                if connected == 0 && attempts.ready(RECONNECT_AFTER) {
                    match TcpStream::connect_timeout(server, Duration::from_secs(1)) {
                        Ok(stream) => {
                            tracing::info!("connected to {server}");
                            made.push((stream, server.to_string()));
                        }
                        Err(e) => warnings.warn(|| format!("cannot connect to {server}: {e}; {meanwhile}")),
                    }
                }
            }
        }
        made
    }
}

/// The descriptor of `net.tcp_receiver` as listed (raw bytes).
pub fn receiver_descriptor() -> ComponentInfo {
    receiver_base()
        .output(
            "data",
            DataType::Bytes,
            "Each message (raw and length_prefixed framing)",
        )
        .output("line", DataType::Text, "Each line (lines framing)")
        .build()
}

/// The descriptor of one `net.tcp_receiver`: bytes and lines, or with encoding kairos, samples of the sent
/// type.
pub fn describe_receiver(properties: &BTreeMap<String, Value>) -> Result<ComponentInfo, DescribeError> {
    Ok(if encoding::is_kairos(properties) {
        let data_type = encoding::data_type_of(properties)?;
        receiver_base()
            .output(
                encoding::SAMPLES,
                data_type,
                "Each sample received, with both its times",
            )
            .build()
    } else {
        receiver_descriptor()
    })
}

fn receiver_base() -> Descriptor {
    Descriptor::new(
        "net.tcp_receiver",
        "network",
        "Reads TCP: as a client of a server, or as a server of many clients; raw reads, lines or \
         length-prefixed messages, each one sample stamped on reception; or (encoding kairos) whole Kairos \
         samples with their times",
    )
    .label("TCP receiver")
    .property(mode_property())
    .property(
        Property::text("address", "127.0.0.1:5001")
            .doc("The server to connect to, or the address to listen on"),
    )
    .property(Framing::property())
    .property(encoding::property())
    .property(encoding::data_type_property())
}

/// One connection being read.
#[derive(Debug)]
struct Connection {
    stream: TcpStream,
    peer: String,
    deframer: Deframer,
}

/// `net.tcp_receiver`. See [`receiver_descriptor`].
#[derive(Debug, Default)]
pub struct TcpReceiver {
    framing: Option<Framing>,
    side: Option<Side>,
    connections: Vec<Connection>,
    buffer: Vec<u8>,
    messages: u64,
    cut_off: u64,
    refused: u64,
    samples: Option<SampleReceiver>,
    warnings: Throttle,
}

impl TcpReceiver {
    fn connect_or_accept(&mut self, framing: Framing) {
        let Some(side) = &mut self.side else { return };
        let server = side.is_server();
        for (stream, peer) in side.new_connections(
            self.connections.len(),
            &mut self.warnings,
            "trying again every second",
        ) {
            // A server reads its clients in turn without waiting; a client waits a little for its server.
            let ready = if server {
                stream.set_nonblocking(true)
            } else {
                stream.set_read_timeout(Some(READ_WAIT))
            };
            if ready.is_ok() {
                self.connections.push(Connection {
                    stream,
                    peer,
                    deframer: Deframer::new(framing),
                });
            }
        }
    }
}

impl Component for TcpReceiver {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.framing = Some(Framing::of(&ctx.text_property("framing")?));
        if encoding::is_kairos(ctx.properties()) {
            self.samples = Some(SampleReceiver::of(ctx)?);
            self.framing = Some(Framing::LengthPrefixed);
        }
        self.side = Some(Side::of(ctx)?);
        self.buffer = vec![0; 256 * 1024];
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let framing = self.framing.unwrap_or(Framing::Raw);
        self.connect_or_accept(framing);
        if self.connections.is_empty() {
            ctx.sleep(if self.side.as_ref().is_some_and(Side::is_server) {
                IDLE_WAIT
            } else {
                READ_WAIT
            })?;
            return Ok(());
        }
        let mut messages: Vec<(Vec<u8>, usize)> = Vec::new();
        let mut closed = Vec::new();
        for (index, connection) in self.connections.iter_mut().enumerate() {
            let read = match connection.stream.read(&mut self.buffer) {
                Ok(0) => Err("the peer closed the connection".to_owned()),
                Ok(read) => Ok(read),
                Err(e)
                    if matches!(
                        e.kind(),
                        ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted
                    ) =>
                {
                    Ok(0)
                }
                Err(e) => Err(e.to_string()),
            };
            match read {
                Ok(read) => {
                    let bytes = self.buffer.get(..read).unwrap_or_default();
                    if let Err(too_long) = connection
                        .deframer
                        .feed(bytes, |m| messages.push((m.to_vec(), index)))
                    {
                        self.refused += 1;
                        self.warnings.warn(|| {
                            format!(
                                "{}: a message of {} bytes is too long; the connection is closed",
                                connection.peer, too_long.0
                            )
                        });
                        closed.push(index);
                    }
                }
                Err(reason) => {
                    if connection.deframer.pending() > 0 {
                        self.cut_off += 1;
                    }
                    self.warnings.warn(|| format!("{}: {reason}", connection.peer));
                    closed.push(index);
                }
            }
        }
        let now = ctx.now();
        let idle = messages.is_empty();
        for (message, from) in messages {
            self.messages += 1;
            if let Some(samples) = &mut self.samples {
                let peer = self.connections.get(from).map_or("", |c| c.peer.as_str());
                samples.take(&message, peer, ctx)?;
            } else if framing == Framing::Lines {
                let text = String::from_utf8_lossy(&message);
                ctx.write_at("line", Payload::Text(Arc::from(text.as_ref())), now)?;
            } else {
                ctx.write_at("data", Payload::Bytes(Arc::from(message)), now)?;
            }
        }
        for index in closed.into_iter().rev() {
            self.connections.remove(index);
        }
        if idle && self.side.as_ref().is_some_and(Side::is_server) {
            ctx.sleep(IDLE_WAIT)?;
        }
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        let status = serde_json::json!({
            "kind": "tcp", "connections": self.connections.len(), "messages": self.messages,
            "cut_off": self.cut_off, "refused": self.refused,
        });
        Some(encoding::status_with(status, self.samples.as_ref()))
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}

/// The descriptor of `net.tcp_sender` as listed (text or bytes).
pub fn sender_descriptor() -> ComponentInfo {
    sender_base(encoding::sender_accepts(&BTreeMap::new()))
}

/// The descriptor of one `net.tcp_sender`: text or bytes in, or with encoding kairos, samples of any type.
pub fn describe_sender(properties: &BTreeMap<String, Value>) -> Result<ComponentInfo, DescribeError> {
    Ok(sender_base(encoding::sender_accepts(properties)))
}

fn sender_base(accepts: TypeFilter) -> ComponentInfo {
    Descriptor::new(
        "net.tcp_sender",
        "network",
        "Writes each text or bytes sample to TCP: as a client of a server, or to every client of a server \
         it runs; raw, as lines or length-prefixed; or (encoding kairos) each sample of any type whole, with \
         its times and sequence number",
    )
    .label("TCP sender")
    .input_with_policy("in", accepts, ReaderPolicy::Fifo, "What to send")
    .property(mode_property())
    .property(
        Property::text("address", "127.0.0.1:5001")
            .doc("The server to connect to, or the address to listen on"),
    )
    .property(Framing::property())
    .property(encoding::property())
    .build()
}

/// `net.tcp_sender`. See [`sender_descriptor`].
#[derive(Debug, Default)]
pub struct TcpSender {
    framing: Option<Framing>,
    side: Option<Side>,
    peers: Vec<(TcpStream, String)>,
    /// With encoding kairos: whole samples, each after its length.
    samples: Option<SampleSender>,
    sent: u64,
    dropped: u64,
    warnings: Throttle,
}

impl TcpSender {
    fn connect_or_accept(&mut self) {
        let Some(side) = &mut self.side else { return };
        let meanwhile = "samples are dropped (and counted) until it connects, tried every second";
        for (stream, peer) in side.new_connections(self.peers.len(), &mut self.warnings, meanwhile) {
            // Blocking writes, but never for long: a stuck client is dropped, not waited for.
            // Samples go out as they come: a small one waits for no acknowledgement.
            let _ = stream.set_nodelay(self.samples.is_some());
            if stream.set_nonblocking(false).is_ok() && stream.set_write_timeout(Some(WRITE_WAIT)).is_ok() {
                self.peers.push((stream, peer));
            }
        }
    }
}

impl Component for TcpSender {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.framing = Some(Framing::of(&ctx.text_property("framing")?));
        if encoding::is_kairos(ctx.properties()) {
            self.samples = Some(SampleSender::of(ctx));
        }
        self.side = Some(Side::of(ctx)?);
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        self.connect_or_accept();
        // Kairos samples are framed as they are encoded: one copy of the payload, not two.
        let framed: Cow<'_, [u8]> = match &mut self.samples {
            Some(sender) => Cow::Borrowed(sender.frame(&sample, true)),
            None => Cow::Owned(
                self.framing
                    .unwrap_or(Framing::Raw)
                    .frame(encoding::raw_bytes(&sample.payload)?),
            ),
        };
        if self.peers.is_empty() {
            self.dropped += 1;
        }
        let mut gone = Vec::new();
        for (index, (stream, peer)) in self.peers.iter_mut().enumerate() {
            match stream.write_all(&framed) {
                Ok(()) => self.sent += 1,
                Err(e) => {
                    self.dropped += 1;
                    self.warnings.warn(|| format!("{peer}: {e}; disconnected"));
                    gone.push(index);
                }
            }
        }
        for index in gone.into_iter().rev() {
            self.peers.remove(index);
        }
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({
            "kind": "tcp", "connections": self.peers.len(), "sent": self.sent, "dropped": self.dropped,
        }))
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}
