//! The Foxglove server's front door: where clients connect, in front of the `foxglove` crate's server,
//! so that clients still offering the protocol's former name are served too.
//!
//! The crate accepts the WebSocket subprotocols `foxglove.sdk.v1` and `foxglove.sdk.v1.1` only, and
//! answers anything else with HTTP 400. Clients released before the protocol was renamed (older
//! Lichtblick and Foxglove releases, `PlotJuggler`, tools built on Foxglove's ws-protocol libraries) offer
//! `foxglove.websocket.v1`, the same protocol under its former name. The door reads each handshake,
//! renames that offer to `foxglove.sdk.v1` (only when the client offers no `foxglove.sdk.*` name itself),
//! names it back in the server's answer, then copies both ways untouched.
//!
//! Decision: a rename at the handshake rather than a server of our own: the crate keeps serving every
//! message, and the door costs one loopback copy of the bytes.

use std::net::SocketAddr;

use tokio::io::{AsyncReadExt as _, AsyncWriteExt as _};
use tokio::net::{TcpListener, TcpStream};

/// The protocol's former name, which older clients offer.
pub const FORMER_SUBPROTOCOL: &str = "foxglove.websocket.v1";
/// The name the crate's server accepts for the same protocol.
const SUBPROTOCOL: &str = "foxglove.sdk.v1";
/// A handshake's head is a few hundred bytes; anything larger is not a client of ours.
const MOST_HEAD_BYTES: usize = 16 * 1024;

/// Accepts clients on `listener` and passes each to the server at `server`, for as long as the runtime
/// that runs it lives.
pub async fn serve(listener: TcpListener, server: SocketAddr) {
    loop {
        let Ok((client, _)) = listener.accept().await else {
            continue;
        };
        tokio::spawn(async move {
            if let Err(error) = pass(client, server).await {
                tracing::debug!("Foxglove client: {error}");
            }
        });
    }
}

async fn pass(mut client: TcpStream, server: SocketAddr) -> std::io::Result<()> {
    let _ = client.set_nodelay(true);
    let (head, rest) = read_head(&mut client).await?;
    let (head, renamed) = rename_offer(&head);
    let mut upstream = TcpStream::connect(server).await?;
    let _ = upstream.set_nodelay(true);
    upstream.write_all(&head).await?;
    upstream.write_all(&rest).await?;
    let (answer, rest) = read_head(&mut upstream).await?;
    let answer = if renamed { rename_answer(&answer) } else { answer };
    client.write_all(&answer).await?;
    client.write_all(&rest).await?;
    tokio::io::copy_bidirectional(&mut client, &mut upstream).await?;
    Ok(())
}

/// The HTTP head `stream` sends (through the blank line that ends it), and what it sent after it.
async fn read_head(stream: &mut TcpStream) -> std::io::Result<(Vec<u8>, Vec<u8>)> {
    let mut bytes = Vec::with_capacity(1024);
    let mut chunk = [0_u8; 4096];
    loop {
        if let Some(end) = bytes.windows(4).position(|w| w == b"\r\n\r\n") {
            let rest = bytes.split_off(end + 4);
            return Ok((bytes, rest));
        }
        if bytes.len() > MOST_HEAD_BYTES {
            return Err(std::io::Error::other("an HTTP head longer than 16 KiB"));
        }
        let read = stream.read(&mut chunk).await?;
        if read == 0 {
            return Err(std::io::ErrorKind::UnexpectedEof.into());
        }
        bytes.extend_from_slice(chunk.get(..read).unwrap_or_default());
    }
}

/// `head` with a `foxglove.websocket.v1` offer named `foxglove.sdk.v1`, when it offers no `foxglove.sdk.*`
/// name; and whether it was renamed.
fn rename_offer(head: &[u8]) -> (Vec<u8>, bool) {
    let text = String::from_utf8_lossy(head);
    let mut renamed = false;
    let lines: Vec<String> = text
        .split("\r\n")
        .map(|line| {
            let Some((name, value)) = line.split_once(':') else {
                return line.to_owned();
            };
            if !name.trim().eq_ignore_ascii_case("sec-websocket-protocol") {
                return line.to_owned();
            }
            let offered: Vec<&str> = value.split(',').map(str::trim).collect();
            if offered.iter().any(|o| o.starts_with("foxglove.sdk."))
                || !offered.contains(&FORMER_SUBPROTOCOL)
            {
                return line.to_owned();
            }
            renamed = true;
            let offered: Vec<&str> = offered
                .into_iter()
                .map(|o| if o == FORMER_SUBPROTOCOL { SUBPROTOCOL } else { o })
                .collect();
            format!("{name}: {}", offered.join(", "))
        })
        .collect();
    (lines.join("\r\n").into_bytes(), renamed)
}

/// The server's answer with the chosen `foxglove.sdk.v1` named back `foxglove.websocket.v1`.
fn rename_answer(head: &[u8]) -> Vec<u8> {
    let text = String::from_utf8_lossy(head);
    text.split("\r\n")
        .map(|line| match line.split_once(':') {
            Some((name, value))
                if name.trim().eq_ignore_ascii_case("sec-websocket-protocol")
                    && value.trim() == SUBPROTOCOL =>
            {
                format!("{name}: {FORMER_SUBPROTOCOL}")
            }
            _ => line.to_owned(),
        })
        .collect::<Vec<_>>()
        .join("\r\n")
        .into_bytes()
}

#[cfg(test)]
mod tests {
    use super::{rename_answer, rename_offer};

    #[test]
    fn the_former_name_is_renamed_only_when_no_current_one_is_offered() {
        let old = b"GET / HTTP/1.1\r\nHost: a\r\nSec-WebSocket-Protocol: foxglove.websocket.v1\r\n\r\n";
        let (head, renamed) = rename_offer(old);
        assert!(renamed);
        assert!(String::from_utf8_lossy(&head).contains("Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"));
        let both =
            b"GET / HTTP/1.1\r\nsec-websocket-protocol: foxglove.websocket.v1, foxglove.sdk.v1\r\n\r\n";
        assert_eq!(rename_offer(both), (both.to_vec(), false));
        let answer = b"HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: foxglove.sdk.v1\r\n\r\n";
        assert!(
            String::from_utf8_lossy(&rename_answer(answer))
                .contains("sec-websocket-protocol: foxglove.websocket.v1")
        );
    }
}
