//! One WebSocket client: the upgrade checks (`?rate=`, the client cap), the client task that writes frames and
//! answers requests, and the sampler task that feeds it states at the client's rate.
//!
//! Memory and time are bounded whatever the client does:
//! - the sampler reads `SessionApi::snapshot` (wait-free for the servo) and *tries* to reserve a place in a
//!   queue of [`CLIENT_QUEUE_FRAMES`]; when the client reads too slowly the queue is full and the frame is
//!   dropped and counted (never serialised, never buffered);
//! - the client task writes one message at a time to a socket whose kernel send buffer is capped
//!   ([`super::SEND_BUFFER_BYTES`]), so a client that never reads holds at most the queue, one message in
//!   flight and that buffer;
//! - incoming messages are limited to 64 KiB (larger closes with 1009) and the task handles one request at a
//!   time: it stops reading while a command or slice is in flight;
//! - a shutdown interrupts even a blocked write: the client gets close 1001 if its socket takes it within a
//!   second, and is dropped otherwise.

use super::auth::check_token;
use super::messages::{
    check_rate, decode_client_message, ClientMessage, ErrorMessage, Hello, MessageError, Reply,
    SliceMessage, State as StateMessage, DEFAULT_RATE_HZ, MAX_MESSAGE_BYTES, SCHEMA,
};
use super::response::error_response;
use super::shared::{ClientSlot, Shared, CLIENT_QUEUE_FRAMES};
use axum::extract::rejection::QueryRejection;
use axum::extract::ws::{
    rejection::WebSocketUpgradeRejection, CloseFrame, Message, WebSocket, WebSocketUpgrade,
};
use axum::extract::{Query, State};
use axum::http::StatusCode;
use axum::response::Response;
use futures_util::stream::SplitSink;
use futures_util::{SinkExt, StreamExt};
use serde::Serialize;
use serde_json::Value;
use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;
use tokio::time::MissedTickBehavior;

/// Close code: the server is going away.
const CLOSE_GOING_AWAY: u16 = 1001;
/// Close code: a message was too big.
const CLOSE_TOO_BIG: u16 = 1009;
/// How long a close frame may take to go out.
const CLOSE_TIMEOUT: Duration = Duration::from_secs(1);

/// `GET /ws?rate=HZ`: checks the rate and the cap before upgrading.
pub(crate) async fn upgrade(
    State(shared): State<Arc<Shared>>,
    query: Result<Query<HashMap<String, String>>, QueryRejection>,
    upgrade: Result<WebSocketUpgrade, WebSocketUpgradeRejection>,
) -> Response {
    let params = match query {
        Ok(Query(params)) => params,
        Err(rejection) => return error_response(rejection.status(), rejection.body_text()),
    };
    let rate_hz = match params.get("rate") {
        None => DEFAULT_RATE_HZ,
        Some(text) => match text
            .parse::<f64>()
            .map_err(|_| MessageError::RateNotANumber(text.clone()))
            .and_then(check_rate)
        {
            Ok(rate) => rate,
            Err(error) => return error_response(StatusCode::BAD_REQUEST, error.to_string()),
        },
    };
    let upgrade = match upgrade {
        Ok(upgrade) => upgrade,
        Err(rejection) => {
            return error_response(
                rejection.status(),
                format!("/ws is a WebSocket endpoint: {}", rejection.body_text()),
            )
        }
    };
    if *shared.shutdown.borrow() {
        return error_response(
            StatusCode::SERVICE_UNAVAILABLE,
            "the server is shutting down",
        );
    }
    let Some(slot) = shared.try_add_client() else {
        return error_response(
            StatusCode::SERVICE_UNAVAILABLE,
            format!(
                "too many clients: {} are connected, the limit (--max-clients) is {}",
                shared.config.max_clients, shared.config.max_clients
            ),
        );
    };
    upgrade
        .max_message_size(MAX_MESSAGE_BYTES)
        .max_frame_size(MAX_MESSAGE_BYTES)
        .on_upgrade(move |socket| client(socket, shared, rate_hz, slot))
}

/// Aborts a task when dropped (the sampler dies with its client).
struct AbortOnDrop<T>(JoinHandle<T>);

impl<T> Drop for AbortOnDrop<T> {
    fn drop(&mut self) {
        self.0.abort();
    }
}

type Sink = SplitSink<WebSocket, Message>;

/// Why a client task stopped writing.
enum Stop {
    /// The client went away or the socket failed.
    Gone,
    /// Close with this code and reason.
    Close(u16, &'static str),
}

fn to_text(message: &impl Serialize) -> String {
    // The messages are plain data (no maps with non-string keys): serialisation cannot fail.
    serde_json::to_string(message).unwrap_or_default()
}

fn error_text(id: &Value, error: &str) -> String {
    to_text(&ErrorMessage { id, error })
}

/// Writes one text message, giving up when the server shuts down.
async fn send(
    sink: &mut Sink,
    text: String,
    shutdown: &mut watch::Receiver<bool>,
) -> Result<(), Stop> {
    tokio::select! {
        sent = sink.send(Message::Text(text.into())) => sent.map_err(|_| Stop::Gone),
        _ = shutdown.wait_for(|stop| *stop) => Err(Stop::Close(CLOSE_GOING_AWAY, "server shutting down")),
    }
}

/// What to do with one text message: answer now, or start a request whose answer comes later.
enum Handled {
    Answer(String),
    Pending(JoinHandle<String>),
}

fn handle_text(shared: &Arc<Shared>, text: &str, rate: &watch::Sender<f64>) -> Handled {
    let message = match decode_client_message(text) {
        Ok(message) => message,
        Err(error) => {
            return Handled::Answer(error_text(
                &error.id,
                &format!("invalid message: {}", error.message),
            ))
        }
    };
    match message {
        ClientMessage::Rate { id, rate_hz } => match check_rate(rate_hz) {
            Ok(rate_hz) => {
                rate.send_replace(rate_hz);
                Handled::Answer(to_text(&Reply {
                    id: &id,
                    ok: true,
                    message: &format!("rate set to {rate_hz} Hz"),
                    scene_generation: 0,
                }))
            }
            Err(error) => Handled::Answer(error_text(&id, &format!("invalid: {error}"))),
        },
        ClientMessage::Control { id, token, command } => {
            if let Err(error) = check_token(&shared.config.token, token.as_deref()) {
                let error = match error {
                    super::auth::AuthError::Missing => {
                        "unauthorized: control messages need a \"token\" field (the token `voxhap serve` printed)".to_owned()
                    }
                    other => other.to_string(),
                };
                return Handled::Answer(error_text(&id, &error));
            }
            let shared = shared.clone();
            Handled::Pending(tokio::spawn(async move {
                match shared
                    .blocking(false, move |api| api.control(command))
                    .await
                    .and_then(|r| r)
                {
                    Ok(reply) => to_text(&Reply {
                        id: &id,
                        ok: true,
                        message: &reply.message,
                        scene_generation: reply.scene_generation,
                    }),
                    Err(error) => error_text(&id, &error.to_string()),
                }
            }))
        }
        ClientMessage::Slice { id, request } => {
            let shared = shared.clone();
            Handled::Pending(tokio::spawn(async move {
                let id_for_slice = id.clone();
                let answer = shared
                    .blocking(true, move |api| {
                        api.slice(request).map(|slice| {
                            to_text(&SliceMessage {
                                id: &id_for_slice,
                                slice: &slice,
                            })
                        })
                    })
                    .await
                    .and_then(|r| r);
                answer.unwrap_or_else(|error| error_text(&id, &error.to_string()))
            }))
        }
    }
}

/// Feeds `frames` with states at the client's rate, only when the servo tick advanced; drops (and counts)
/// a frame when the queue is full.
async fn sample_states(
    shared: Arc<Shared>,
    mut rate: watch::Receiver<f64>,
    frames: mpsc::Sender<String>,
    dropped: Arc<AtomicU64>,
) {
    let mut last_tick = None;
    loop {
        let rate_hz = *rate.borrow_and_update();
        let mut interval = tokio::time::interval(Duration::from_secs_f64(1.0 / rate_hz));
        interval.set_missed_tick_behavior(MissedTickBehavior::Skip);
        loop {
            tokio::select! {
                _ = interval.tick() => {}
                changed = rate.changed() => {
                    if changed.is_err() {
                        return;
                    }
                    break;
                }
                () = frames.closed() => return,
            }
            let Some(snapshot) = shared.api.snapshot() else {
                continue;
            };
            if last_tick == Some(snapshot.tick) {
                continue;
            }
            last_tick = Some(snapshot.tick);
            match frames.try_reserve() {
                Ok(permit) => {
                    let lost = dropped.load(Ordering::Relaxed);
                    permit.send(to_text(&StateMessage::new(&snapshot, lost)));
                }
                Err(mpsc::error::TrySendError::Full(())) => {
                    dropped.fetch_add(1, Ordering::Relaxed);
                    shared.frames_dropped.fetch_add(1, Ordering::Relaxed);
                }
                Err(mpsc::error::TrySendError::Closed(())) => return,
            }
        }
    }
}

/// A read error that means the client sent more than [`MAX_MESSAGE_BYTES`]. The WebSocket library's error
/// type is not re-exported by axum, so its message is matched ("Space limit exceeded: Message too long");
/// a test in tests/server.rs pins it.
fn is_too_big(error: &axum::Error) -> bool {
    let text = error.to_string();
    text.contains("Space limit exceeded") || text.contains("too long")
}

/// The client task: hello, then states, answers and requests until the client leaves or the server shuts
/// down.
async fn client(socket: WebSocket, shared: Arc<Shared>, rate_hz: f64, _slot: ClientSlot) {
    let (mut sink, mut stream) = socket.split();
    let mut shutdown = shared.shutdown.clone();
    let stop = run_client(&shared, &mut sink, &mut stream, rate_hz, &mut shutdown).await;
    if let Stop::Close(code, reason) = stop {
        let frame = CloseFrame {
            code,
            reason: reason.into(),
        };
        let _ = tokio::time::timeout(CLOSE_TIMEOUT, sink.send(Message::Close(Some(frame)))).await;
    }
}

async fn run_client(
    shared: &Arc<Shared>,
    sink: &mut Sink,
    stream: &mut futures_util::stream::SplitStream<WebSocket>,
    rate_hz: f64,
    shutdown: &mut watch::Receiver<bool>,
) -> Stop {
    let hello = {
        let servo_rate_hz = shared.api.stats().rate_hz;
        match shared.blocking(false, |api| api.scene()).await {
            Ok(scene) => to_text(&Hello {
                schema: SCHEMA,
                rate_hz,
                servo_rate_hz,
                scene: &scene,
            }),
            Err(_) => return Stop::Close(CLOSE_GOING_AWAY, "server shutting down"),
        }
    };
    if let Err(stop) = send(sink, hello, shutdown).await {
        return stop;
    }
    let dropped = Arc::new(AtomicU64::new(0));
    let (frames_tx, mut frames) = mpsc::channel::<String>(CLIENT_QUEUE_FRAMES);
    let (rate_tx, rate_rx) = watch::channel(rate_hz);
    let _sampler = AbortOnDrop(tokio::spawn(sample_states(
        shared.clone(),
        rate_rx,
        frames_tx,
        dropped,
    )));
    let mut pending: Option<JoinHandle<String>> = None;
    loop {
        let event = tokio::select! {
            biased;
            _ = shutdown.wait_for(|stop| *stop) => Event::Shutdown,
            answer = async { pending.as_mut().expect("guarded by is_some").await }, if pending.is_some() => {
                Event::Answer(answer.ok())
            }
            frame = frames.recv() => Event::Frame(frame),
            incoming = stream.next(), if pending.is_none() => Event::Incoming(incoming),
        };
        let outcome = match event {
            Event::Shutdown => return Stop::Close(CLOSE_GOING_AWAY, "server shutting down"),
            Event::Answer(answer) => {
                pending = None;
                let text = answer.unwrap_or_else(|| {
                    error_text(
                        &Value::Null,
                        "unavailable: the request failed inside the server",
                    )
                });
                send(sink, text, shutdown).await
            }
            Event::Frame(None) => return Stop::Gone,
            Event::Frame(Some(text)) => {
                let sent = send(sink, text, shutdown).await;
                if sent.is_ok() {
                    shared.frames_sent.fetch_add(1, Ordering::Relaxed);
                }
                sent
            }
            Event::Incoming(None) => return Stop::Gone,
            Event::Incoming(Some(Err(error))) => {
                return if is_too_big(&error) {
                    Stop::Close(CLOSE_TOO_BIG, "message too big: the limit is 65536 bytes")
                } else {
                    Stop::Gone
                };
            }
            Event::Incoming(Some(Ok(Message::Text(text)))) => {
                match handle_text(shared, text.as_str(), &rate_tx) {
                    Handled::Answer(answer) => send(sink, answer, shutdown).await,
                    Handled::Pending(task) => {
                        pending = Some(task);
                        Ok(())
                    }
                }
            }
            Event::Incoming(Some(Ok(Message::Binary(_)))) => {
                let text = error_text(
                    &Value::Null,
                    "invalid message: binary messages are not supported; send JSON text",
                );
                send(sink, text, shutdown).await
            }
            Event::Incoming(Some(Ok(Message::Close(_)))) => {
                // Flush the close reply the WebSocket library queued.
                let _ = tokio::time::timeout(CLOSE_TIMEOUT, sink.close()).await;
                return Stop::Gone;
            }
            Event::Incoming(Some(Ok(Message::Ping(_) | Message::Pong(_)))) => Ok(()),
        };
        if let Err(stop) = outcome {
            return stop;
        }
    }
}

/// What woke the client task.
enum Event {
    Shutdown,
    /// A request finished (`None`: its task failed).
    Answer(Option<String>),
    Frame(Option<String>),
    Incoming(Option<Result<Message, axum::Error>>),
}
