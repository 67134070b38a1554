//! The axum router: the embedded page, the read endpoints (`/api/state`, `/api/stats`, `/api/scene`,
//! `/api/slice`), the control endpoints (bearer token, JSON bodies of at most 64 KiB) and the WebSocket route.
//!
//! Every control endpoint follows one path ([`control_request`]): token check (401, nothing decoded), body
//! read (413 over the limit), JSON decode naming the bad field (400), then the session's own validation
//! ([`voxhap_api::ControlError::http_status`]), run on the blocking pool because a command waits for the
//! servo thread to apply it. A refused request changes nothing.

use super::auth::check_bearer;
use super::messages::{
    decode_command, decode_value, parse_json, slice_json, ControlFailed, ControlOk, EmptyBody,
    EnabledBody, HandBody, MessageError, ModeBody, RecordBody, State as StateMessage, StatsBody,
    StiffnessBody, StopRecordingBody, TransferBody, VolumeBody, MAX_MESSAGE_BYTES,
};
use super::origin::check_single;
use super::response::error_response;
use super::shared::Shared;
use super::{assets, ws};
use axum::body::Bytes;
use axum::extract::rejection::{BytesRejection, PathRejection, QueryRejection};
use axum::extract::{DefaultBodyLimit, Path, Query, State};
use axum::http::{header, HeaderMap, Method, StatusCode, Uri};
use axum::response::{IntoResponse, Response};
use axum::routing::{delete, get, post};
use axum::{Json, Router};
use glam::DVec3;
use serde::de::DeserializeOwned;
use serde_json::Value;
use std::collections::HashMap;
use std::sync::Arc;
use voxhap_api::{ControlCommand, ControlError, ControlReply, SliceAxis, SliceRequest};

type Shared_ = State<Arc<Shared>>;

/// The whole HTTP surface.
pub(crate) fn router(shared: Arc<Shared>) -> Router {
    Router::new()
        .route("/", get(assets::index))
        .route("/app.js", get(assets::app_js))
        .route("/style.css", get(assets::style_css))
        .route("/api/state", get(state))
        .route("/api/stats", get(stats))
        .route("/api/scene", get(scene))
        .route("/api/slice", get(slice))
        .route("/api/stiffness", post(stiffness))
        .route("/api/modes", post(body_command::<ModeBody, false>))
        .route("/api/modes/{name}", delete(mode_command::<EmptyBody>))
        .route(
            "/api/modes/{name}/transfer",
            post(mode_command::<TransferBody>),
        )
        .route(
            "/api/modes/{name}/enabled",
            post(mode_command::<EnabledBody>),
        )
        .route("/api/volume", post(body_command::<VolumeBody, false>))
        .route("/api/record/start", post(body_command::<RecordBody, false>))
        .route(
            "/api/record/stop",
            post(body_command::<StopRecordingBody, true>),
        )
        .route("/api/hand", post(body_command::<HandBody, false>))
        .route("/api/control", post(control))
        .route("/ws", get(ws::upgrade))
        .fallback(not_found)
        .layer(DefaultBodyLimit::max(MAX_MESSAGE_BYTES))
        .layer(axum::middleware::from_fn_with_state(
            shared.clone(),
            check_host_and_origin,
        ))
        .with_state(shared)
}

/// The Host check on every request, and the Origin check on `/ws` and every request that is not GET or
/// HEAD ([`super::origin`]); a request without a Host header, or with more than one Host or Origin header,
/// is refused (400) before either; 403 with the reason otherwise.
async fn check_host_and_origin(
    State(shared): Shared_,
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    let verdict = {
        let headers = request.headers();
        let text = |name: header::HeaderName| {
            headers
                .get(name)
                .map(|value| value.to_str().unwrap_or("(not text)"))
        };
        let host = text(header::HOST);
        let changes_state = !matches!(*request.method(), Method::GET | Method::HEAD);
        check_single("Host", headers.get_all(header::HOST).iter().count())
            .and_then(|()| check_single("Origin", headers.get_all(header::ORIGIN).iter().count()))
            .and_then(|()| shared.origin.check_host(host))
            .and_then(|()| {
                if changes_state || request.uri().path() == "/ws" {
                    shared.origin.check_origin(text(header::ORIGIN), host)
                } else {
                    Ok(())
                }
            })
    };
    match verdict {
        Ok(()) => next.run(request).await,
        Err(error) => {
            let status = StatusCode::from_u16(error.http_status()).unwrap_or(StatusCode::FORBIDDEN);
            error_response(status, error.to_string())
        }
    }
}

/// `{"error": message}` with `status`.
fn control_failed(status: StatusCode, message: impl Into<String>) -> Response {
    (status, Json(ControlFailed::new(message))).into_response()
}

fn control_error(error: &ControlError) -> Response {
    let status =
        StatusCode::from_u16(error.http_status()).unwrap_or(StatusCode::INTERNAL_SERVER_ERROR);
    control_failed(status, error.to_string())
}

/// A pre-serialised JSON body.
fn json_text(status: StatusCode, text: String) -> Response {
    (status, [(header::CONTENT_TYPE, "application/json")], text).into_response()
}

async fn not_found(method: Method, uri: Uri) -> Response {
    error_response(
        StatusCode::NOT_FOUND,
        format!("no such endpoint: {method} {}", uri.path()),
    )
}

async fn state(State(shared): Shared_) -> Response {
    match shared.api.snapshot() {
        Some(snapshot) => Json(StateMessage::new(&snapshot, 0)).into_response(),
        None => error_response(
            StatusCode::SERVICE_UNAVAILABLE,
            "no state yet: the servo loop has not ticked",
        ),
    }
}

async fn stats(State(shared): Shared_) -> Response {
    Json(StatsBody {
        servo: shared.api.stats(),
        server: shared.stats(),
    })
    .into_response()
}

async fn scene(State(shared): Shared_) -> Response {
    match shared.blocking(false, |api| api.scene()).await {
        Ok(scene) => Json(scene).into_response(),
        Err(error) => error_response(StatusCode::SERVICE_UNAVAILABLE, error.to_string()),
    }
}

/// Why a `GET /api/slice` query was refused: the parameter and the value given.
#[derive(Debug, thiserror::Error)]
enum SliceQueryError {
    #[error("unknown query parameter {0:?}; expected axis, size, at, volume, encoding")]
    Unknown(String),
    #[error(transparent)]
    Axis(ControlError),
    #[error("invalid: size must be a whole number, got {0:?}")]
    Size(String),
    #[error("invalid: at must be three finite numbers x,y,z in metres, got {0:?}")]
    Point(String),
}

/// Parses `x,y,z` (metres).
fn parse_point(text: &str) -> Result<DVec3, SliceQueryError> {
    let parts: Vec<&str> = text.split(',').collect();
    let numbers: Result<Vec<f64>, _> = parts.iter().map(|p| p.trim().parse::<f64>()).collect();
    match numbers {
        Ok(n) if n.len() == 3 && n.iter().all(|v| v.is_finite()) => {
            Ok(DVec3::new(n[0], n[1], n[2]))
        }
        _ => Err(SliceQueryError::Point(text.to_owned())),
    }
}

/// The slice request of a `GET /api/slice` query.
fn slice_request(params: &HashMap<String, String>) -> Result<SliceRequest, SliceQueryError> {
    if let Some(key) = params
        .keys()
        .find(|key| !matches!(key.as_str(), "axis" | "size" | "at" | "volume" | "encoding"))
    {
        return Err(SliceQueryError::Unknown(key.clone()));
    }
    let mut request = SliceRequest::default();
    if let Some(text) = params.get("axis") {
        request.axis = text.parse::<SliceAxis>().map_err(SliceQueryError::Axis)?;
    }
    if let Some(text) = params.get("size") {
        request.size = text
            .parse::<usize>()
            .map_err(|_| SliceQueryError::Size(text.clone()))?;
    }
    if let Some(text) = params.get("at") {
        request.at_m = Some(parse_point(text)?);
    }
    request.volume = params.get("volume").cloned();
    Ok(request)
}

async fn slice(
    State(shared): Shared_,
    query: Result<Query<HashMap<String, String>>, QueryRejection>,
) -> Response {
    let params = match query {
        Ok(Query(params)) => params,
        Err(rejection) => return error_response(rejection.status(), rejection.body_text()),
    };
    let request = match slice_request(&params) {
        Ok(request) => request,
        Err(error) => return error_response(StatusCode::BAD_REQUEST, error.to_string()),
    };
    let u8_levels = match params.get("encoding").map(String::as_str) {
        None | Some("f32") => false,
        Some("u8") => true,
        Some(other) => {
            return error_response(
                StatusCode::BAD_REQUEST,
                format!("invalid: encoding must be f32 or u8, got {other:?}"),
            )
        }
    };
    let result = shared
        .blocking(true, move |api| {
            api.slice(request)
                .map(|slice| slice_json(&slice, u8_levels))
        })
        .await
        .and_then(|r| r);
    match result {
        Ok(text) => json_text(StatusCode::OK, text),
        Err(error) => error_response(
            StatusCode::from_u16(error.http_status()).unwrap_or(StatusCode::BAD_REQUEST),
            error.to_string(),
        ),
    }
}

/// What a control endpoint makes of its (decoded) body.
type Decode = Box<dyn FnOnce(Value) -> Result<Vec<ControlCommand>, MessageError> + Send>;

/// The shared path of every control endpoint: token, body, decode, apply (all commands or none refused).
async fn control_request(
    shared: &Arc<Shared>,
    headers: &HeaderMap,
    body: Result<Bytes, BytesRejection>,
    empty_ok: bool,
    decode: Decode,
) -> Response {
    if let Err(error) = check_bearer(&shared.config.token, headers) {
        return control_failed(StatusCode::UNAUTHORIZED, error.to_string());
    }
    let bytes = match body {
        Ok(bytes) => bytes,
        Err(rejection) => {
            return control_failed(
                rejection.status(),
                format!("invalid: the request body: {}", rejection.body_text()),
            )
        }
    };
    let value = if empty_ok && bytes.iter().all(u8::is_ascii_whitespace) {
        Value::Object(serde_json::Map::new())
    } else {
        match parse_json(&bytes) {
            Ok(value) => value,
            Err(message) => {
                return control_failed(StatusCode::BAD_REQUEST, format!("invalid: {message}"))
            }
        }
    };
    let commands = match decode(value) {
        Ok(commands) => commands,
        Err(message) => {
            return control_failed(StatusCode::BAD_REQUEST, format!("invalid: {message}"))
        }
    };
    let applied = shared
        .blocking(false, move |api| {
            let mut replies: Vec<ControlReply> = Vec::with_capacity(commands.len());
            for command in commands {
                replies.push(api.control(command)?);
            }
            Ok::<_, ControlError>(replies)
        })
        .await
        .and_then(|r| r);
    match applied {
        Ok(replies) => {
            let message = replies
                .iter()
                .map(|r| r.message.as_str())
                .collect::<Vec<_>>()
                .join("; ");
            let scene_generation = replies
                .iter()
                .map(|r| r.scene_generation)
                .max()
                .unwrap_or(0);
            Json(ControlOk::from(ControlReply {
                message,
                scene_generation,
            }))
            .into_response()
        }
        Err(error) => control_error(&error),
    }
}

fn one(command: ControlCommand) -> Result<Vec<ControlCommand>, MessageError> {
    Ok(vec![command])
}

async fn stiffness(
    State(shared): Shared_,
    headers: HeaderMap,
    body: Result<Bytes, BytesRejection>,
) -> Response {
    let decode: Decode = Box::new(|value| {
        let body: StiffnessBody = decode_value(value)?;
        if let Some(damping) = body.damping {
            if !(damping.is_finite() && damping >= 0.0) {
                return Err(MessageError::Damping(damping));
            }
        }
        // Both given: one command, checked whole before anything is applied (the damping's bound depends
        // on the new stiffness), so a refused damping does not leave a changed k behind.
        Ok(vec![match (body.k, body.damping) {
            (Some(k), Some(damping)) => ControlCommand::SetCoupling { k, damping },
            (Some(k), None) => ControlCommand::SetStiffness { k },
            (None, Some(damping)) => ControlCommand::SetDamping { damping },
            (None, None) => return Err(MessageError::NoStiffness),
        }])
    });
    control_request(&shared, &headers, body, false, decode).await
}

/// `POST /api/modes`, `/api/volume`, `/api/record/start`, `/api/record/stop`, `/api/hand`: the body as `B`
/// (`EMPTY_OK`: an empty body stands for `{}`), and the one command it makes (`From<B> for ControlCommand`,
/// beside the control API's wire decoding).
async fn body_command<
    B: DeserializeOwned + Into<ControlCommand> + 'static,
    const EMPTY_OK: bool,
>(
    State(shared): Shared_,
    headers: HeaderMap,
    body: Result<Bytes, BytesRejection>,
) -> Response {
    let decode: Decode = Box::new(|value| one(decode_value::<B>(value)?.into()));
    control_request(&shared, &headers, body, EMPTY_OK, decode).await
}

/// The body of a control endpoint on one mode (`/api/modes/{name}...`): the command from the mode's name
/// and the body.
trait ModeCommand: DeserializeOwned + 'static {
    /// Whether an empty body stands for `{}`.
    const EMPTY_OK: bool = false;
    fn command(self, mode: String) -> ControlCommand;
}

impl ModeCommand for EmptyBody {
    const EMPTY_OK: bool = true;
    fn command(self, name: String) -> ControlCommand {
        ControlCommand::RemoveMode { name }
    }
}

impl ModeCommand for TransferBody {
    fn command(self, mode: String) -> ControlCommand {
        ControlCommand::SetTransfer {
            mode,
            transfer: self.transfer,
        }
    }
}

impl ModeCommand for EnabledBody {
    fn command(self, mode: String) -> ControlCommand {
        ControlCommand::SetModeEnabled {
            mode,
            enabled: self.enabled,
        }
    }
}

/// `DELETE /api/modes/{name}`, `POST /api/modes/{name}/transfer`, `POST /api/modes/{name}/enabled`: the
/// mode's name from the path, then the body as `B`.
async fn mode_command<B: ModeCommand>(
    State(shared): Shared_,
    headers: HeaderMap,
    name: Result<Path<String>, PathRejection>,
    body: Result<Bytes, BytesRejection>,
) -> Response {
    let mode = match name {
        Ok(Path(name)) => name,
        Err(rejection) => return control_failed(rejection.status(), rejection.body_text()),
    };
    let decode: Decode = Box::new(move |value| one(decode_value::<B>(value)?.command(mode)));
    control_request(&shared, &headers, body, B::EMPTY_OK, decode).await
}

async fn control(
    State(shared): Shared_,
    headers: HeaderMap,
    body: Result<Bytes, BytesRejection>,
) -> Response {
    let decode: Decode = Box::new(|value| decode_command(value).map(|c| vec![c]));
    control_request(&shared, &headers, body, false, decode).await
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(pairs: &[(&str, &str)]) -> HashMap<String, String> {
        pairs
            .iter()
            .map(|(k, v)| ((*k).to_owned(), (*v).to_owned()))
            .collect()
    }

    #[test]
    fn slice_queries_parse_or_say_why() {
        let request = slice_request(&params(&[
            ("axis", "x"),
            ("size", "64"),
            ("at", "0,0.01,-0.02"),
        ]))
        .unwrap();
        assert_eq!(request.axis, SliceAxis::X);
        assert_eq!(request.size, 64);
        assert_eq!(request.at_m, Some(DVec3::new(0.0, 0.01, -0.02)));
        let request = slice_request(&params(&[])).unwrap();
        assert_eq!((request.axis, request.size), (SliceAxis::Z, 128));
        for (key, value, expected) in [
            ("axis", "w", "axis must be x, y or z"),
            ("at", "1,2", "at must be three finite numbers"),
            ("at", "1,2,NaN", "at must be"),
            ("sise", "1", "unknown query parameter \"sise\""),
        ] {
            let err = slice_request(&params(&[(key, value)]))
                .unwrap_err()
                .to_string();
            assert!(err.contains(expected), "{key}={value}: {err}");
        }
    }
}
