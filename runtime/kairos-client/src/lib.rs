//! The one client of the control protocol: `kairos deploy`, `kairos status`, a runtime coordinating a
//! diagram over hosts and the studio all reach a `kairos serve` through it.
//!
//! [`Connection::open`] connects to a `ws://` or `wss://` endpoint, says hello with a token and a role,
//! and hands back the session with the runtime's welcome. Two rules live here and nowhere else:
//! - a `wss://` endpoint is trusted through a certificate the caller names (the host's own, or the authority
//!   that issued it), never through whatever the machine happens to trust;
//! - a token never crosses the network in clear text: over `ws://` to an address off this machine it is
//!   refused unless the caller says the network is trusted ([`ConnectOptions::allow_clear_text_token`]).
//!
//! The session is blocking: [`Connection::call`] sends a request and waits for its reply, skipping events;
//! [`Connection::send_request`] and [`Connection::read`] let a caller with its own loop (the studio's
//! connection thread) interleave requests and events.

use std::fmt::Write as _;
use std::net::{SocketAddr, TcpStream, ToSocketAddrs as _};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use kairos_protocol::{
    PROTOCOL_VERSION, ProtocolError, Reply, ReplyBody, Request, RequestBody, RequestKind, Role, Token,
    Welcome,
};
use tungstenite::{Message, WebSocket};

/// How long reaching a runtime and each of its answers may take, unless the caller says otherwise.
pub const DEFAULT_WAIT: Duration = Duration::from_secs(5);

/// The id of the `hello` request; [`Connection::call`] numbers the others from 2.
pub const HELLO_ID: u64 = 1;

/// How the caller's user fixes what the client refuses, for the refusals to say: each caller has its own
/// way (a command-line flag, a field of the diagram's hosts section).
#[derive(Debug, Clone, Copy)]
pub struct Fixes {
    /// How to allow a token over plain `ws://` (`pass --allow-clear-text-tokens`).
    pub clear_text_opt_in: &'static str,
    /// How to name the certificate to trust (`add certificate: "FILE.pem" to its Host`).
    pub certificate: &'static str,
}

/// How to reach a runtime.
#[derive(Debug, Clone)]
pub struct ConnectOptions {
    /// Who is asking, as the runtime logs it (`kairos deploy 0.1.0`).
    pub client: String,
    /// The role asked for.
    pub role: Role,
    /// The runtime's token, where it requires one.
    pub token: Option<Token>,
    /// The certificate to trust for a `wss://` endpoint (PEM: the runtime's own, or its authority's).
    pub certificate: Option<PathBuf>,
    /// Send a token over plain `ws://` to an address off this machine (a network the user trusts).
    pub allow_clear_text_token: bool,
    /// How long connecting, and then each answer, may take.
    pub wait: Duration,
}

impl ConnectOptions {
    /// An operator's connection for `client`, with no token or certificate, waiting [`DEFAULT_WAIT`].
    pub fn operator(client: impl Into<String>) -> Self {
        ConnectOptions {
            client: client.into(),
            role: Role::Operator,
            token: None,
            certificate: None,
            allow_clear_text_token: false,
            wait: DEFAULT_WAIT,
        }
    }
}

/// Why a connection could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum ConnectError {
    /// The endpoint is not a `ws://HOST:PORT` or `wss://HOST:PORT` address.
    #[error("{endpoint} is not an address to reach a runtime at: write ws://HOST:PORT or wss://HOST:PORT")]
    BadEndpoint {
        /// The endpoint as given.
        endpoint: String,
    },
    /// A token would have gone over plain `ws://` to another machine.
    #[error(
        "its token would cross the network in clear text to {endpoint} (ws://), where anyone on the path can \
         read it and take control of that runtime; use a wss:// endpoint, or {opt_in} on a network you trust"
    )]
    ClearTextToken {
        /// The endpoint.
        endpoint: String,
        /// How the caller's user says the network is trusted (`pass --allow-clear-text-tokens`).
        opt_in: &'static str,
    },
    /// A `wss://` endpoint with no certificate to trust.
    #[error(
        "a wss:// endpoint needs the certificate to trust (the runtime's own, or the authority that issued \
         it): {fix}"
    )]
    NoCertificate {
        /// How to name it (`add certificate: "FILE.pem" to its Host`).
        fix: &'static str,
    },
    /// The certificate to trust could not be read.
    #[error("cannot use the certificate {path}: {reason}")]
    Certificate {
        /// The certificate's file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// Nothing accepted the connection in time.
    #[error("is unreachable at {endpoint}")]
    Unreachable {
        /// The endpoint.
        endpoint: String,
    },
    /// The WebSocket (or TLS) handshake failed.
    #[error("at {endpoint}: {reason}{hint}")]
    Handshake {
        /// The endpoint.
        endpoint: String,
        /// What failed.
        reason: String,
        /// What to check, where the reason points at the certificate.
        hint: &'static str,
    },
    /// The runtime answered `hello` with a refusal.
    #[error("refused the connection: {}", .0.message)]
    Refused(ProtocolError),
    /// The session could not be carried on.
    #[error(transparent)]
    Call(#[from] CallError),
}

/// Why a request got no result.
#[derive(Debug, thiserror::Error)]
pub enum CallError {
    /// The connection failed, or the runtime did not answer in time.
    #[error("stopped answering: {0}")]
    Lost(#[source] tungstenite::Error),
    /// The runtime refused the request; the message lists each diagnostic on a line of its own.
    #[error("refused: {}", refusal_text(.0))]
    Refused(ProtocolError),
    /// The request could not be encoded.
    #[error("a '{kind}' request cannot be encoded: {source}")]
    Encode {
        /// The request's kind.
        kind: &'static str,
        /// Why.
        source: serde_json::Error,
    },
    /// The reply is not one this client can read.
    #[error("answered strangely: {0}")]
    Malformed(String),
}

fn refusal_text(error: &ProtocolError) -> String {
    let mut text = error.message.clone();
    for diagnostic in &error.diagnostics {
        let _ = write!(text, "\n  {diagnostic}");
    }
    text
}

/// What a runtime's WebSocket runs on: TCP, or TLS over TCP for a `wss://` endpoint.
#[derive(Debug)]
pub enum Stream {
    /// `ws://`.
    Plain(TcpStream),
    /// `wss://`.
    Tls(Box<rustls::StreamOwned<rustls::ClientConnection, TcpStream>>),
}

impl std::io::Read for Stream {
    fn read(&mut self, buffer: &mut [u8]) -> std::io::Result<usize> {
        match self {
            Stream::Plain(stream) => stream.read(buffer),
            Stream::Tls(stream) => stream.read(buffer),
        }
    }
}

impl std::io::Write for Stream {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        match self {
            Stream::Plain(stream) => stream.write(bytes),
            Stream::Tls(stream) => stream.write(bytes),
        }
    }

    fn flush(&mut self) -> std::io::Result<()> {
        match self {
            Stream::Plain(stream) => stream.flush(),
            Stream::Tls(stream) => stream.flush(),
        }
    }
}

/// An endpoint's parts: `host:port` and whether it is `wss://`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Endpoint {
    /// `HOST:PORT` as written (an IPv6 host in brackets).
    pub address: String,
    /// Whether the endpoint is `wss://`.
    pub secure: bool,
}

impl Endpoint {
    /// Reads `ws://HOST:PORT[/...]` or `wss://HOST:PORT[/...]`.
    pub fn parse(endpoint: &str) -> Result<Endpoint, ConnectError> {
        let bad = || ConnectError::BadEndpoint {
            endpoint: endpoint.to_owned(),
        };
        let (scheme, rest) = endpoint.split_once("://").ok_or_else(bad)?;
        let secure = match scheme {
            "ws" => false,
            "wss" => true,
            _ => return Err(bad()),
        };
        let address = rest.split('/').next().unwrap_or_default();
        if address.is_empty() {
            return Err(bad());
        }
        Ok(Endpoint {
            address: address.to_owned(),
            secure,
        })
    }

    /// The host part, without the port or an IPv6 address's brackets.
    pub fn host(&self) -> &str {
        self.address
            .rsplit_once(':')
            .map_or(self.address.as_str(), |(host, _)| host)
            .trim_start_matches('[')
            .trim_end_matches(']')
    }

    fn resolve(&self) -> Option<SocketAddr> {
        self.address.to_socket_addrs().ok()?.next()
    }
}

/// Whether a token may go to `endpoint` as it is reached: always over `wss://` or to this machine, over
/// plain `ws://` elsewhere only when the user said so.
fn check_clear_text(
    endpoint: &str,
    parsed: &Endpoint,
    resolved: Option<SocketAddr>,
    options: &ConnectOptions,
    opt_in: &'static str,
) -> Result<(), ConnectError> {
    let off_this_machine = resolved.is_some_and(|address| !address.ip().is_loopback());
    if options.token.is_some() && !parsed.secure && !options.allow_clear_text_token && off_this_machine {
        return Err(ConnectError::ClearTextToken {
            endpoint: endpoint.to_owned(),
            opt_in,
        });
    }
    Ok(())
}

/// TLS over `stream`, trusting the certificates in `certificate` and checking they name `server`.
fn tls_client(
    certificate: &Path,
    server: &str,
    stream: TcpStream,
) -> Result<rustls::StreamOwned<rustls::ClientConnection, TcpStream>, ConnectError> {
    use rustls::pki_types::pem::PemObject as _;
    use rustls::pki_types::{CertificateDer, ServerName};
    let unusable = |reason: String| ConnectError::Certificate {
        path: certificate.to_owned(),
        reason,
    };
    let mut roots = rustls::RootCertStore::empty();
    for trusted in CertificateDer::pem_file_iter(certificate).map_err(|e| unusable(e.to_string()))? {
        let trusted = trusted.map_err(|e| unusable(format!("not a PEM certificate: {e}")))?;
        roots.add(trusted).map_err(|e| unusable(e.to_string()))?;
    }
    let config =
        rustls::ClientConfig::builder_with_provider(Arc::new(rustls::crypto::ring::default_provider()))
            .with_safe_default_protocol_versions()
            .map_err(|e| unusable(e.to_string()))?
            .with_root_certificates(roots)
            .with_no_client_auth();
    let server_name = ServerName::try_from(server.to_owned()).map_err(|e| ConnectError::Handshake {
        endpoint: server.to_owned(),
        reason: format!("{server} cannot name a TLS server: {e}"),
        hint: "",
    })?;
    let connection =
        rustls::ClientConnection::new(Arc::new(config), server_name).map_err(|e| unusable(e.to_string()))?;
    Ok(rustls::StreamOwned::new(connection, stream))
}

/// A session with one runtime.
pub struct Connection {
    endpoint: String,
    socket: WebSocket<Stream>,
    /// The connection under the WebSocket, for its timeouts.
    tcp: TcpStream,
    next_id: u64,
    welcome: Welcome,
}

impl std::fmt::Debug for Connection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Connection")
            .field("endpoint", &self.endpoint)
            .finish_non_exhaustive()
    }
}

impl Connection {
    /// Connects to `endpoint` and says hello; a refusal says how to fix it in the words of `fixes`.
    pub fn open(endpoint: &str, options: &ConnectOptions, fixes: Fixes) -> Result<Self, ConnectError> {
        let parsed = Endpoint::parse(endpoint)?;
        let resolved = parsed.resolve();
        check_clear_text(endpoint, &parsed, resolved, options, fixes.clear_text_opt_in)?;
        let certificate = match (&options.certificate, parsed.secure) {
            (Some(certificate), true) => Some(certificate.as_path()),
            (None, true) => {
                return Err(ConnectError::NoCertificate {
                    fix: fixes.certificate,
                });
            }
            (_, false) => None,
        };
        let unreachable = || ConnectError::Unreachable {
            endpoint: endpoint.to_owned(),
        };
        let stream = resolved
            .and_then(|address| TcpStream::connect_timeout(&address, options.wait).ok())
            .ok_or_else(unreachable)?;
        let lost = |e: std::io::Error| CallError::Lost(tungstenite::Error::Io(e));
        stream.set_read_timeout(Some(options.wait)).map_err(lost)?;
        // Nagle's delay only slows small requests down; without it everything still works.
        let _ = stream.set_nodelay(true);
        let tcp = stream.try_clone().map_err(lost)?;
        let stream = match certificate {
            Some(certificate) => Stream::Tls(Box::new(tls_client(certificate, parsed.host(), stream)?)),
            None => Stream::Plain(stream),
        };
        let (socket, _) = tungstenite::client(endpoint, stream).map_err(|e| {
            let reason = e.to_string();
            let hint = if parsed.secure && reason.contains("certificate") {
                "; is the certificate to trust the host's own (its --tls-cert) or the authority that issued it?"
            } else {
                ""
            };
            ConnectError::Handshake {
                endpoint: endpoint.to_owned(),
                reason,
                hint,
            }
        })?;
        let mut connection = Connection {
            endpoint: endpoint.to_owned(),
            socket,
            tcp,
            next_id: HELLO_ID,
            // Replaced by the runtime's own below, before anyone sees it.
            welcome: Welcome {
                protocol: 0,
                server: String::new(),
                role: options.role,
                shared_memory_host: None,
                pid: None,
                platform: None,
            },
        };
        let hello = RequestBody::Hello {
            protocol: PROTOCOL_VERSION,
            client: options.client.clone(),
            token: options.token.clone(),
            role: Some(options.role),
        };
        connection.send_request(&Request {
            id: HELLO_ID,
            body: hello,
        })?;
        let reply = connection.reply_to(HELLO_ID)?;
        let refused = !reply.ok;
        connection.welcome = match reply.decode(RequestKind::Hello) {
            Ok(ReplyBody::Hello(welcome)) => welcome,
            Err(error) if refused => return Err(ConnectError::Refused(error)),
            Err(error) => return Err(CallError::Malformed(error.message).into()),
            Ok(_) => return Err(CallError::Malformed("not a welcome".to_owned()).into()),
        };
        Ok(connection)
    }

    /// The runtime's welcome.
    pub fn welcome(&self) -> &Welcome {
        &self.welcome
    }

    /// The endpoint connected to.
    pub fn endpoint(&self) -> &str {
        &self.endpoint
    }

    /// How long a read waits (`None`: for ever).
    pub fn set_read_timeout(&self, wait: Option<Duration>) -> std::io::Result<()> {
        self.tcp.set_read_timeout(wait)
    }

    /// Sends `body` and waits for its reply: its result, or the refusal.
    pub fn call(&mut self, body: RequestBody) -> Result<serde_json::Value, CallError> {
        let id = self.send(body)?;
        self.wait(id)
    }

    /// Sends `body` with the next id, without waiting; that id, for [`Connection::wait`].
    pub fn send(&mut self, body: RequestBody) -> Result<u64, CallError> {
        self.next_id += 1;
        let id = self.next_id;
        self.send_request(&Request { id, body })?;
        Ok(id)
    }

    /// Sends a request as it is, with the caller's id (above [`HELLO_ID`]; a caller choosing ids uses this
    /// alone, never [`Connection::send`]).
    pub fn send_request(&mut self, request: &Request) -> Result<(), CallError> {
        let text = serde_json::to_string(request).map_err(|source| CallError::Encode {
            kind: request.body.kind().name(),
            source,
        })?;
        self.socket.send(Message::text(text)).map_err(CallError::Lost)
    }

    /// The result of request `id`, skipping everything else that arrives meanwhile.
    pub fn wait(&mut self, id: u64) -> Result<serde_json::Value, CallError> {
        let reply = self.reply_to(id)?;
        match reply.error.filter(|_| !reply.ok) {
            Some(error) => Err(CallError::Refused(error)),
            None => Ok(reply.result.unwrap_or_default()),
        }
    }

    fn reply_to(&mut self, id: u64) -> Result<Reply, CallError> {
        loop {
            let message = match self.socket.read() {
                // A signal to this process (the user's Ctrl-C, handled) cut the wait short: nothing was
                // read, so reading again loses nothing. The runtime is not lost for it.
                Err(tungstenite::Error::Io(error)) if error.kind() == std::io::ErrorKind::Interrupted => {
                    continue;
                }
                other => other.map_err(CallError::Lost)?,
            };
            let Message::Text(text) = message else {
                continue;
            };
            let Ok(value) = serde_json::from_str::<serde_json::Value>(text.as_str()) else {
                continue;
            };
            if value["type"] != "reply" || value["id"] != id {
                continue;
            }
            return serde_json::from_value(value).map_err(|e| CallError::Malformed(e.to_string()));
        }
    }

    /// The next message from the runtime, whatever it is (a reply, an event, a sample frame).
    pub fn read(&mut self) -> Result<Message, tungstenite::Error> {
        self.socket.read()
    }

    /// Closes the session politely.
    pub fn close(&mut self) {
        let _ = self.socket.close(None);
        let _ = self.socket.flush();
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "a failed unwrap is a failed test")]

    use super::*;

    const FIXES: Fixes = Fixes {
        clear_text_opt_in: "opt in",
        certificate: "name it",
    };

    #[test]
    fn endpoints_read_as_address_and_scheme() {
        let plain = Endpoint::parse("ws://10.0.0.2:7400").unwrap();
        assert_eq!(plain.address, "10.0.0.2:7400");
        assert!(!plain.secure);
        let secure = Endpoint::parse("wss://[::1]:7400/path").unwrap();
        assert!(secure.secure);
        assert_eq!(secure.host(), "::1");
        for bad in ["10.0.0.2:7400", "http://a:1", "ws://", "wss:///x"] {
            assert!(
                matches!(Endpoint::parse(bad), Err(ConnectError::BadEndpoint { .. })),
                "{bad}"
            );
        }
    }

    #[test]
    fn a_token_in_clear_text_goes_only_to_this_machine_unless_allowed() {
        let mut options = ConnectOptions::operator("test");
        options.token = Some(Token::new("0123456789abcdef0123456789abcdef"));
        let far: SocketAddr = "10.0.0.2:7400".parse().unwrap();
        let near: SocketAddr = "127.0.0.1:7400".parse().unwrap();
        let plain = Endpoint::parse("ws://10.0.0.2:7400").unwrap();
        let refused = check_clear_text("ws://10.0.0.2:7400", &plain, Some(far), &options, "pass --x");
        let message = refused.unwrap_err().to_string();
        assert!(
            message.contains("clear text") && message.contains("wss://") && message.contains("pass --x"),
            "{message}"
        );
        assert!(check_clear_text("ws://127.0.0.1:7400", &plain, Some(near), &options, "").is_ok());
        let secure = Endpoint::parse("wss://10.0.0.2:7400").unwrap();
        assert!(check_clear_text("wss://10.0.0.2:7400", &secure, Some(far), &options, "").is_ok());
        options.allow_clear_text_token = true;
        assert!(check_clear_text("ws://10.0.0.2:7400", &plain, Some(far), &options, "").is_ok());
        options.allow_clear_text_token = false;
        options.token = None;
        assert!(check_clear_text("ws://10.0.0.2:7400", &plain, Some(far), &options, "").is_ok());
    }

    #[test]
    fn a_secure_endpoint_without_a_certificate_is_told_what_to_add() {
        let options = ConnectOptions::operator("test");
        let refused = Connection::open("wss://127.0.0.1:1", &options, FIXES).unwrap_err();
        assert!(matches!(refused, ConnectError::NoCertificate { .. }), "{refused}");
        let message = refused.to_string();
        assert!(
            message.contains("needs the certificate to trust") && message.contains("name it"),
            "{message}"
        );
    }

    #[test]
    fn nothing_listening_is_unreachable() {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let address = listener.local_addr().unwrap();
        drop(listener);
        let mut options = ConnectOptions::operator("test");
        options.wait = Duration::from_millis(300);
        let refused = Connection::open(&format!("ws://{address}"), &options, FIXES).unwrap_err();
        assert!(matches!(refused, ConnectError::Unreachable { .. }), "{refused}");
    }
}
