//! The live view's front door: accepts both WebSocket subprotocol names of the Foxglove WebSocket protocol.
//!
//! Where it sits: the `foxglove` SDK's server (`super::foxglove`) accepts only `foxglove.sdk.v1` (and
//! `.v1.1`); the official ws-protocol client (`@foxglove/ws-protocol`) and older Foxglove Studio and
//! Lichtblick releases ask for `foxglove.websocket.v1`, the same protocol under its older name, and got
//! HTTP 400. This relay listens on the live view's address, renames `foxglove.websocket.v1` to
//! `foxglove.sdk.v1` in the upgrade request when the client offers no `foxglove.sdk.*` name (and the name
//! back in the server's answer), then copies bytes both ways to the SDK's server on a loopback port.

use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::task::JoinSet;

/// The older name of the protocol, which the SDK does not know.
pub const OLD_SUBPROTOCOL: &str = "foxglove.websocket.v1";
/// The name the SDK accepts for the same protocol.
pub const SDK_SUBPROTOCOL: &str = "foxglove.sdk.v1";
/// Most bytes of an upgrade request's or answer's head; a longer one closes the connection.
pub const MAX_HEAD_BYTES: usize = 16 * 1024;
/// How long a client has to send its upgrade request.
pub const HEAD_TIMEOUT: Duration = Duration::from_secs(10);

/// The loopback address of the same family as `public`, port 0, for the SDK's server behind the relay.
pub fn inner_addr(public: SocketAddr) -> SocketAddr {
    match public.ip() {
        IpAddr::V4(_) => SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), 0),
        IpAddr::V6(_) => SocketAddr::new(IpAddr::V6(Ipv6Addr::LOCALHOST), 0),
    }
}

/// Relays every connection accepted on `listener` to `inner` until the task is aborted (its connections
/// end with it).
pub async fn run(listener: TcpListener, inner: SocketAddr) {
    let mut connections = JoinSet::new();
    loop {
        tokio::select! {
            accepted = listener.accept() => {
                if let Ok((client, _)) = accepted {
                    connections.spawn(relay(client, inner));
                }
            }
            Some(_) = connections.join_next(), if !connections.is_empty() => {}
        }
    }
}

/// One connection: the request head (renamed when needed), the answer head (renamed back), then bytes.
async fn relay(mut client: TcpStream, inner: SocketAddr) {
    let Ok(Ok(request)) = tokio::time::timeout(HEAD_TIMEOUT, read_head(&mut client)).await else {
        return;
    };
    let (request, renamed) = rename_offer(&request);
    let Ok(mut server) = TcpStream::connect(inner).await else {
        return;
    };
    if server.write_all(&request).await.is_err() {
        return;
    }
    let Ok(Ok(answer)) = tokio::time::timeout(HEAD_TIMEOUT, read_head(&mut server)).await else {
        return;
    };
    let answer = if renamed {
        rename_answer(&answer)
    } else {
        answer
    };
    if client.write_all(&answer).await.is_err() {
        return;
    }
    let _ = tokio::io::copy_bidirectional(&mut client, &mut server).await;
}

/// Reads up to and including the blank line that ends an HTTP head (the bytes after it too, if they came
/// in the same read). Errors on end of stream or a head over [`MAX_HEAD_BYTES`].
async fn read_head<R: AsyncRead + Unpin>(reader: &mut R) -> std::io::Result<Vec<u8>> {
    let mut head = Vec::with_capacity(1024);
    let mut buffer = [0u8; 2048];
    loop {
        let read = reader.read(&mut buffer).await?;
        if read == 0 {
            return Err(std::io::ErrorKind::UnexpectedEof.into());
        }
        head.extend_from_slice(&buffer[..read]);
        if head.windows(4).any(|w| w == b"\r\n\r\n") {
            return Ok(head);
        }
        if head.len() > MAX_HEAD_BYTES {
            return Err(std::io::ErrorKind::InvalidData.into());
        }
    }
}

/// Splits `bytes` into the head's lines (without their CRLF) and what follows the blank line.
fn split_head(bytes: &[u8]) -> Option<(Vec<&[u8]>, &[u8])> {
    let end = bytes.windows(4).position(|w| w == b"\r\n\r\n")?;
    let lines = bytes[..end]
        .split(|&b| b == b'\n')
        .map(|line| line.strip_suffix(b"\r").unwrap_or(line));
    Some((lines.collect(), &bytes[end + 4..]))
}

/// Joins head lines and the rest back into bytes.
fn join_head(lines: &[Vec<u8>], rest: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    for line in lines {
        out.extend_from_slice(line);
        out.extend_from_slice(b"\r\n");
    }
    out.extend_from_slice(b"\r\n");
    out.extend_from_slice(rest);
    out
}

/// The value of a `Sec-WebSocket-Protocol` header line, if `line` is one.
fn protocol_value(line: &[u8]) -> Option<&str> {
    let text = std::str::from_utf8(line).ok()?;
    let (name, value) = text.split_once(':')?;
    name.trim()
        .eq_ignore_ascii_case("sec-websocket-protocol")
        .then_some(value.trim())
}

/// The request with `foxglove.websocket.v1` offered as `foxglove.sdk.v1` when the client offers no
/// `foxglove.sdk.*` name; and whether it was renamed. Anything else passes unchanged.
pub fn rename_offer(request: &[u8]) -> (Vec<u8>, bool) {
    let Some((lines, rest)) = split_head(request) else {
        return (request.to_vec(), false);
    };
    let offers: Vec<&str> = lines
        .iter()
        .filter_map(|line| protocol_value(line))
        .flat_map(|value| value.split(',').map(str::trim))
        .collect();
    if !offers.contains(&OLD_SUBPROTOCOL) || offers.iter().any(|o| o.starts_with("foxglove.sdk.")) {
        return (request.to_vec(), false);
    }
    let lines: Vec<Vec<u8>> = lines
        .iter()
        .map(|line| match protocol_value(line) {
            Some(value) => {
                let renamed: Vec<&str> = value
                    .split(',')
                    .map(str::trim)
                    .map(|o| {
                        if o == OLD_SUBPROTOCOL {
                            SDK_SUBPROTOCOL
                        } else {
                            o
                        }
                    })
                    .collect();
                format!("Sec-WebSocket-Protocol: {}", renamed.join(", ")).into_bytes()
            }
            None => line.to_vec(),
        })
        .collect();
    (join_head(&lines, rest), true)
}

/// The server's answer with the chosen `foxglove.sdk.v1` named `foxglove.websocket.v1`, as the client asked.
pub fn rename_answer(answer: &[u8]) -> Vec<u8> {
    let Some((lines, rest)) = split_head(answer) else {
        return answer.to_vec();
    };
    let lines: Vec<Vec<u8>> = lines
        .iter()
        .map(|line| match protocol_value(line) {
            Some(SDK_SUBPROTOCOL) => {
                format!("Sec-WebSocket-Protocol: {OLD_SUBPROTOCOL}").into_bytes()
            }
            _ => line.to_vec(),
        })
        .collect();
    join_head(&lines, rest)
}

#[cfg(test)]
mod tests {
    use super::*;

    const REQUEST: &str = "GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\n";

    #[test]
    fn only_the_old_name_alone_is_renamed_and_renamed_back() {
        let old = format!("{REQUEST}Sec-WebSocket-Protocol: {OLD_SUBPROTOCOL}\r\n\r\nrest");
        let (renamed, did) = rename_offer(old.as_bytes());
        assert!(did);
        let text = String::from_utf8(renamed).unwrap();
        assert!(
            text.contains("Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n"),
            "{text}"
        );
        assert!(text.ends_with("\r\n\r\nrest"), "{text}");
        for unchanged in [
            format!("{REQUEST}Sec-WebSocket-Protocol: foxglove.sdk.v1, {OLD_SUBPROTOCOL}\r\n\r\n"),
            format!("{REQUEST}Sec-WebSocket-Protocol: other\r\n\r\n"),
            format!("{REQUEST}\r\n"),
            "no head at all".to_owned(),
        ] {
            let (out, did) = rename_offer(unchanged.as_bytes());
            assert!(!did, "{unchanged}");
            assert_eq!(out, unchanged.as_bytes());
        }
        let answer =
            "HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: foxglove.sdk.v1\r\n\r\n";
        let back = String::from_utf8(rename_answer(answer.as_bytes())).unwrap();
        assert!(
            back.contains("Sec-WebSocket-Protocol: foxglove.websocket.v1\r\n"),
            "{back}"
        );
    }
}
