//! The accept loop and one connection's reader and writer tasks.

use super::codec;
use super::codec::status_code;
use super::config::{
    LINGER_BYTES, LINGER_TIME, MAX_CLIENTS, REPLY_QUEUE, SEND_BUFFER_BYTES, STATUS_DEVICE,
};
use super::read::{read_message, Incoming};
use super::session::{apply_targets, ClientSession, Reply};
use super::state::{choose_victim, unix_now_ns, Candidate, Connection, Frame, Shared, NOT_WRITING};
use super::stream::status_frame;
use glam::DVec3;
use std::sync::atomic::{AtomicU16, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::tcp::OwnedWriteHalf;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{broadcast, mpsc, oneshot, watch};

/// The accept loop: one reader and one writer task per client. When [`MAX_CLIENTS`] are connected, the
/// connection [`choose_victim`] picks is told to close and the newcomer takes its place at once.
pub(super) async fn accept(
    listener: TcpListener,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<bool>,
) {
    loop {
        let accepted = tokio::select! {
            _ = stop.changed() => break,
            accepted = listener.accept() => accepted,
        };
        let Ok((socket, _)) = accepted else {
            // Out of file descriptors and the like: wait a moment rather than spin.
            tokio::time::sleep(Duration::from_millis(50)).await;
            continue;
        };
        let _ = socket.set_nodelay(true);
        let _ = socket2::SockRef::from(&socket).set_send_buffer_size(SEND_BUFFER_BYTES);
        let now_ms = shared.now_ms();
        let connection = Arc::new(Connection::new(now_ms));
        let victim = {
            let Ok(mut table) = shared.table.lock() else {
                break;
            };
            let victim = if table.len() >= MAX_CLIENTS {
                let candidates: Vec<Candidate> =
                    table.iter().map(|c| c.candidate(now_ms)).collect();
                choose_victim(&candidates).map(|index| table.remove(index))
            } else {
                None
            };
            table.push(connection.clone());
            victim
        };
        if let Some(victim) = victim {
            shared
                .counters
                .clients_evicted
                .fetch_add(1, Ordering::Relaxed);
            victim.evicted.notify_one();
        }
        shared.counters.clients.fetch_add(1, Ordering::AcqRel);
        tokio::spawn(client(socket, connection, shared.clone(), stop.clone()));
    }
}

/// Writes `bytes`, marking the write in progress on `connection`; false when the socket failed or
/// a message could not be written whole within the idle timeout (counted).
pub(super) async fn write_marked(
    writer: &mut OwnedWriteHalf,
    bytes: &[u8],
    connection: &Connection,
    shared: &Shared,
) -> bool {
    connection
        .writing_since_ms
        .store(shared.now_ms(), Ordering::Relaxed);
    let written = tokio::time::timeout(shared.idle_timeout, writer.write_all(bytes)).await;
    connection
        .writing_since_ms
        .store(NOT_WRITING, Ordering::Relaxed);
    match written {
        Ok(result) => result.is_ok(),
        Err(_) => {
            shared.counters.idle_closed.fetch_add(1, Ordering::Relaxed);
            false
        }
    }
}

/// One connection: a writer (stream frames and replies) and this task reading requests.
pub(super) async fn client(
    socket: TcpStream,
    connection: Arc<Connection>,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<bool>,
) {
    let (mut reader, mut writer) = socket.into_split();
    let version = Arc::new(AtomicU16::new(1));
    let (reply_tx, mut reply_rx) = mpsc::channel::<Reply>(REPLY_QUEUE);
    let mut frames = shared.frames.subscribe();
    let initial = shared.status.lock().ok().and_then(|s| s.clone());
    let writer_shared = shared.clone();
    let writer_connection = connection.clone();
    let writer_version = version.clone();
    let (writer_done_tx, mut writer_done) = oneshot::channel::<()>();
    let writer_task = tokio::spawn(async move {
        let shared = writer_shared;
        let connection = writer_connection;
        let frame_bytes = |frame: &Frame, version: u16| -> Vec<u8> {
            if version >= 2 {
                frame.v2.clone()
            } else {
                frame.v1.clone()
            }
        };
        let initial =
            initial.unwrap_or_else(|| status_frame(&shared, shared.api.snapshot().as_ref()));
        let bytes = frame_bytes(&initial, writer_version.load(Ordering::Relaxed));
        let mut failed = !write_marked(&mut writer, &bytes, &connection, &shared).await;
        while !failed {
            tokio::select! {
                frame = frames.recv() => match frame {
                    Ok(frame) => {
                        let bytes = frame_bytes(&frame, writer_version.load(Ordering::Relaxed));
                        failed = !write_marked(&mut writer, &bytes, &connection, &shared).await;
                        if !failed {
                            shared.counters.frames_sent.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                    Err(broadcast::error::RecvError::Lagged(lost)) => {
                        shared.counters.frames_dropped.fetch_add(lost, Ordering::Relaxed);
                    }
                    Err(broadcast::error::RecvError::Closed) => break,
                },
                reply = reply_rx.recv() => match reply {
                    Some(reply) => {
                        let mut out = Vec::with_capacity(64 + reply.message.len());
                        let timestamp = codec::timestamp_from_unix_ns(unix_now_ns());
                        codec::encode_message(
                            &mut out,
                            writer_version.load(Ordering::Relaxed),
                            "STATUS",
                            &reply.device,
                            timestamp,
                            &[],
                            |o| codec::encode_status(o, reply.code, 0, reply.error_name, &reply.message),
                        );
                        failed = !write_marked(&mut writer, &out, &connection, &shared).await;
                    }
                    None => break,
                },
            }
        }
        let _ = writer.shutdown().await;
        let _ = writer_done_tx.send(());
    });
    let (target_tx, target_rx) = watch::channel::<Option<DVec3>>(None);
    let target_task = tokio::spawn(apply_targets(shared.clone(), target_rx, reply_tx.clone()));
    let mut session = ClientSession {
        shared: shared.clone(),
        connection: connection.clone(),
        replies: reply_tx,
        targets: target_tx,
        version,
    };
    let mut linger = false;
    loop {
        let authorised = connection.authorised.load(Ordering::Relaxed);
        tokio::select! {
            _ = stop.changed() => break,
            _ = &mut writer_done => break,
            () = connection.evicted.notified() => {
                let _ = session.replies.try_send(Reply::new(
                    STATUS_DEVICE,
                    status_code::BUSY,
                    "Evicted",
                    format!(
                        "voxhap closes this connection to make room for a new client ({MAX_CLIENTS} were \
                         connected; connections without the token, not reading, or silent longest go first)"
                    ),
                ));
                break;
            }
            outcome = read_message(&mut reader, authorised, &shared, &connection) => match outcome {
                Ok(Some(message)) => {
                    let Incoming { header, body, budget } = message;
                    let handled = session.handle(header, body).await;
                    drop(budget);
                    if handled.is_err() {
                        break;
                    }
                }
                Ok(None) => break,
                Err(problem) => {
                    linger = problem.linger;
                    session.reply(Reply::new(STATUS_DEVICE, problem.code, problem.name, problem.message)).await;
                    break;
                }
            }
        }
    }
    drop(session);
    target_task.abort();
    // The writer ends when its reply queue closes; one stuck on a client that does not read is aborted.
    let writer_abort = writer_task.abort_handle();
    if tokio::time::timeout(Duration::from_secs(1), writer_task)
        .await
        .is_err()
    {
        writer_abort.abort();
    }
    if linger {
        // The refusal is written and the write side shut: read and drop (never store) a bounded amount of
        // what the client still sends, so that closing does not reset the connection before it reads the
        // refusal.
        let mut scratch = [0u8; 16 * 1024];
        let mut discard = (&mut reader).take(LINGER_BYTES);
        let _ = tokio::time::timeout(LINGER_TIME, async {
            while matches!(discard.read(&mut scratch).await, Ok(n) if n > 0) {}
        })
        .await;
    }
    if let Ok(mut table) = shared.table.lock() {
        table.retain(|c| !Arc::ptr_eq(c, &connection));
    }
    shared.counters.clients.fetch_sub(1, Ordering::AcqRel);
}
