//! Reading one message from a client within the time and size limits, with the token deciding how large a
//! body may be.

use super::codec::{status_code, Header, HEADER_BYTES};
use super::config::{
    LARGE_BODY_BUDGET_BYTES, MAX_BODY_BYTES, MESSAGE_TIMEOUT, UNAUTHENTICATED_BODY_BYTES,
};
use super::state::{Connection, Shared};
use std::sync::atomic::Ordering;
use tokio::io::{AsyncRead, AsyncReadExt};
use tokio::sync::OwnedSemaphorePermit;

/// Why a connection is closed after a bad message.
pub(super) struct ReadProblem {
    pub(super) code: u16,
    pub(super) name: &'static str,
    pub(super) message: String,
    /// The client may still be sending the refused body: discard a bounded amount before closing.
    pub(super) linger: bool,
}

impl ReadProblem {
    pub(super) fn new(code: u16, name: &'static str, message: String) -> Self {
        ReadProblem {
            code,
            name,
            message,
            linger: false,
        }
    }
}

/// A whole message read from a client, with its share of the large-body budget (if it needed one).
pub(super) struct Incoming {
    pub(super) header: Header,
    pub(super) body: Vec<u8>,
    pub(super) budget: Option<OwnedSemaphorePermit>,
}

/// Reads one message: `Ok(None)` at a clean end of the connection. A bad CRC is not a read problem: the
/// message is framed, so it is returned with its CRC left for the caller to check. A body larger than
/// [`UNAUTHENTICATED_BODY_BYTES`] is refused from the header when the connection is not `authorised`, and
/// otherwise waits for its share of [`LARGE_BODY_BUDGET_BYTES`] before a byte of it is read.
pub(super) async fn read_message<R: AsyncRead + Unpin>(
    reader: &mut R,
    authorised: bool,
    shared: &Shared,
    connection: &Connection,
) -> Result<Option<Incoming>, ReadProblem> {
    let closing = |what: String| {
        ReadProblem::new(
            status_code::CONFIGURATION_ERROR,
            "Error",
            format!("voxhap closes the connection: {what}"),
        )
    };
    let heard = || {
        connection
            .heard_ms
            .store(shared.now_ms(), Ordering::Relaxed)
    };
    let mut raw = [0u8; HEADER_BYTES];
    match reader.read(&mut raw[..1]).await {
        Ok(0) | Err(_) => return Ok(None),
        Ok(_) => heard(),
    }
    let rest = tokio::time::timeout(MESSAGE_TIMEOUT, reader.read_exact(&mut raw[1..])).await;
    let header = match rest {
        // Without the token the smaller limit below applies first, so that the answer is "send the token".
        Ok(Ok(_)) => Header::decode(&raw, if authorised { MAX_BODY_BYTES } else { u64::MAX })
            .map_err(|e| closing(e.to_string()))?,
        Ok(Err(_)) => return Ok(None),
        Err(_) => {
            return Err(closing(format!(
                "a message header did not arrive whole within {} s",
                MESSAGE_TIMEOUT.as_secs()
            )))
        }
    };
    heard();
    let mut budget = None;
    if header.body_size > UNAUTHENTICATED_BODY_BYTES {
        if !authorised {
            shared
                .counters
                .large_bodies_refused
                .fetch_add(1, Ordering::Relaxed);
            return Err(ReadProblem {
                code: status_code::ACCESS_DENIED,
                name: "AccessDenied",
                message: format!(
                    "voxhap closes the connection: {} {:?} announces a {}-byte body, and a connection without \
                     the control token may send at most {UNAUTHENTICATED_BODY_BYTES} bytes; send the STRING \
                     \"token <T>\" first (T is printed by voxhap serve as 'igtl: control token T')",
                    header.type_name, header.device_name, header.body_size
                ),
                linger: true,
            });
        }
        let share = kib(header.body_size);
        let waited = tokio::time::timeout(
            MESSAGE_TIMEOUT,
            shared.large_bodies.clone().acquire_many_owned(share),
        )
        .await;
        budget = match waited {
            Ok(Ok(permit)) => Some(permit),
            Ok(Err(_)) => return Ok(None),
            Err(_) => {
                return Err(ReadProblem::new(
                    status_code::NOT_ENOUGH_RESOURCE,
                    "Busy",
                    format!(
                        "voxhap closes the connection: other clients' large messages held the \
                         {LARGE_BODY_BUDGET_BYTES}-byte budget for {} s; send the {}-byte {} again later",
                        MESSAGE_TIMEOUT.as_secs(),
                        header.body_size,
                        header.type_name
                    ),
                ))
            }
        };
    }
    let body_size = header.body_size;
    let read_body = async {
        // Grows with the bytes that actually arrive, never to the claimed size up front.
        let mut body = Vec::with_capacity(body_size.min(64 * 1024) as usize);
        let read = reader.take(body_size).read_to_end(&mut body).await?;
        Ok::<_, std::io::Error>((read, body))
    };
    match tokio::time::timeout(MESSAGE_TIMEOUT, read_body).await {
        Ok(Ok((read, body))) if read as u64 == body_size => {
            heard();
            Ok(Some(Incoming {
                header,
                body,
                budget,
            }))
        }
        Ok(_) => Ok(None),
        Err(_) => Err(closing(format!(
            "the {body_size}-byte body of {} {:?} did not arrive whole within {} s of its header",
            header.type_name,
            header.device_name,
            MESSAGE_TIMEOUT.as_secs()
        ))),
    }
}

/// KiB, rounded up (the unit of [`Shared::large_bodies`]).
pub(super) fn kib(bytes: u64) -> u32 {
    u32::try_from(bytes.div_ceil(1024)).unwrap_or(u32::MAX)
}
