//! The Kairos control protocol: how a client (the studio, a script in any language) drives a runtime
//! (`kairos serve`), on the same machine or across a network.
//!
//! Transport: WebSocket. Requests, replies and events are JSON text messages; sample data travels in
//! binary messages ([`frame`]). A session starts with `hello` (protocol version, token, wanted role); every
//! later request is checked against the role table ([`RequestKind::required_role`]). `docs/protocol.md`
//! lists every message with an example.
//!
//! ```
//! use kairos_protocol::{ReplyBody, Request, RequestBody, ServerMessage, Started};
//!
//! let request: Request = serde_json::from_str(r#"{"id": 1, "type": "start"}"#).unwrap();
//! assert_eq!(request.body, RequestBody::Start { at_ns: None, forced: None, start_unlocked: false, lock_bound_ns: None });
//! let reply = ServerMessage::ok(1, &ReplyBody::Start(Started::default()));
//! assert_eq!(serde_json::to_string(&reply).unwrap(), r#"{"type":"reply","id":1,"ok":true,"result":{}}"#);
//! ```
//!
//! Every request type is declared once, with its reply's type and its role (`requests!` in
//! `messages.rs`): [`RequestBody`], [`RequestKind`], [`ReplyBody`] and the role table follow from it.

#![warn(missing_docs)]

use serde::{Deserialize, Serialize};

mod clock_watch;
pub mod frame;
mod messages;

pub use clock_watch::{ReferenceWatch, References, error_ms};

/// Pixel buffers in shared memory (the `kairos-shm` crate, which the runtime side shares without linking the
/// protocol): frames name them instead of carrying the pixels.
pub use kairos_shm as shared_pixels;

pub use messages::{
    ClockState, ClockTelemetry, ComponentState, ComponentTelemetry, CrossLinkTelemetry, DeployResult,
    Described, DeviceInfo, DeviceList, DiagramReply, Done, ErrorCode, FoxgloveState, GroupTelemetry,
    HostTelemetry, LINK_QUIET_MS, LatencyTelemetry, LinkEnd, LinkList, LinkNetwork, LinkTelemetry, LogLevel,
    LogRecord, PACK_CHUNK_BYTES, PYTHON_PACK_PLATFORM, PackInstall, Prepared, ProtocolError, Reply,
    ReplyBody, Request, RequestBody, RequestKind, Role, Ros2Service, Ros2Topic, Ros2TopicList, RuntimeState,
    SampleTransport, SamplesSubscribed, ServerMessage, Started, Status, Telemetry, TelemetrySubscribed,
    Welcome, decode_request, link_delivers_nothing, this_host, this_platform,
};

/// The protocol version this crate speaks. A client with another version is refused at `hello`, with
/// both versions named.
pub const PROTOCOL_VERSION: u32 = 1;

/// The largest message a server accepts (text or binary), in bytes: a diagram's text fits many times over.
pub const MAX_MESSAGE_BYTES: usize = 4 << 20;

/// How many messages may wait for one client before the server drops events for it (replies are never
/// dropped: a client that lets this many pile up is disconnected).
pub const CLIENT_QUEUE: usize = 256;

/// How many clients a server serves at once unless told otherwise.
pub const DEFAULT_MAX_CONNECTIONS: usize = 32;

/// The shortest token a server accepts.
pub const MIN_TOKEN_CHARS: usize = 32;

/// A token that grants a role: sent in `hello`, read from a token file. Its `Debug` never shows it and
/// it has no `Display`, so it cannot reach a log by accident; [`Token::reveal`] is the one way to its
/// text. Equality is [`tokens_match`], in constant time.
#[derive(Clone, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Token(String);

impl Token {
    /// A token of this text.
    pub fn new(text: impl Into<String>) -> Self {
        Token(text.into())
    }

    /// The token's text, for the one place that must send or check it.
    pub fn reveal(&self) -> &str {
        &self.0
    }
}

impl std::fmt::Debug for Token {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Token(***)")
    }
}

impl PartialEq for Token {
    fn eq(&self, other: &Token) -> bool {
        tokens_match(&self.0, &other.0)
    }
}

impl Eq for Token {}

/// Compares two tokens in time that depends only on their lengths, so a client cannot find a token's
/// prefix by timing refusals.
pub fn tokens_match(given: &str, expected: &str) -> bool {
    let (a, b) = (given.as_bytes(), expected.as_bytes());
    let mut difference = u8::from(a.len() != b.len());
    for (index, byte) in b.iter().enumerate() {
        difference |= byte ^ a.get(index).copied().unwrap_or(0);
    }
    difference == 0
}

#[cfg(test)]
mod tests {
    use super::{PROTOCOL_VERSION, Request, RequestBody, Token, tokens_match};

    #[test]
    fn a_token_is_never_printed() {
        let secret = "3f9c0a61d2b84e7f95c3a0d6e1b27f48";
        let hello = Request {
            id: 1,
            body: RequestBody::Hello {
                protocol: PROTOCOL_VERSION,
                client: "test".to_owned(),
                token: Some(Token::new(secret)),
                role: None,
            },
        };
        let printed = format!("{hello:?} {hello:#?}");
        assert!(!printed.contains(secret), "{printed}");
        assert!(printed.contains("Token(***)"), "{printed}");
        // On the wire it is the plain text the server reads.
        let wire = serde_json::to_value(&hello).unwrap();
        assert_eq!(wire["token"], secret);
        assert_eq!(serde_json::from_value::<Request>(wire).unwrap(), hello);
    }

    #[test]
    fn tokens_match_only_when_equal() {
        let token = "a".repeat(40);
        assert!(tokens_match(&token, &token));
        assert!(!tokens_match(&"a".repeat(39), &token));
        assert!(!tokens_match(&"a".repeat(41), &token));
        assert!(!tokens_match(&format!("{}b", "a".repeat(39)), &token));
        assert!(!tokens_match("", &token));
    }
}
