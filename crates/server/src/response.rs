//! The JSON error response every HTTP endpoint and the WebSocket upgrade refuse a request with:
//! `{"error": "<message>"}` with the given status.

use super::messages::ErrorBody;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;

pub(crate) fn error_response(status: StatusCode, message: impl Into<String>) -> Response {
    (
        status,
        Json(ErrorBody {
            error: message.into(),
        }),
    )
        .into_response()
}
