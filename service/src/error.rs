//! The one error type every handler returns, and the one place it becomes a response:
//! JSON `{"error": ...}` (plus fields such as `line`/`column`) with a fitting status code.
//!
//! Storage failures are the service's fault, so they are logged and answered `503` (the
//! database is busy or unavailable: retry) or `500`; nothing a user sends ends up there.

use axum::Json;
use axum::extract::Request;
use axum::http::StatusCode;
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use serde_json::{Map, Value, json};
use utoipa::ToSchema;

use crate::store::StoreError;

/// An answer other than success: a status and a JSON body with at least `error`.
#[derive(Debug)]
pub struct ApiError {
    /// The response's status.
    pub status: StatusCode,
    /// The JSON body: `error` (the message) and any fields added with [`ApiError::with`].
    pub body: Map<String, Value>,
    /// Seconds for a `Retry-After` header (a `503` the client may simply repeat).
    pub retry_after: Option<u32>,
}

impl ApiError {
    /// `status` with the message `message`.
    pub fn new(status: StatusCode, message: impl Into<String>) -> ApiError {
        let mut body = Map::new();
        body.insert("error".into(), Value::String(message.into()));
        ApiError {
            status,
            body,
            retry_after: None,
        }
    }

    /// Says when to try again (`Retry-After`, in seconds).
    pub fn retry_after(mut self, secs: u32) -> ApiError {
        self.retry_after = Some(secs);
        self
    }

    /// `400`: what was sent cannot be taken, and `message` says why.
    pub fn bad_request(message: impl Into<String>) -> ApiError {
        ApiError::new(StatusCode::BAD_REQUEST, message)
    }

    /// `404`, saying "no" `what`.
    pub fn not_found(what: impl std::fmt::Display) -> ApiError {
        ApiError::new(StatusCode::NOT_FOUND, format!("no {what}"))
    }

    /// `404` for a job id that names no job, shown cut to its first 64 characters: any
    /// path segment is taken as an id, and a long one is not repeated whole.
    pub fn no_job(id: &str) -> ApiError {
        ApiError::not_found(format_args!("job `{}`", shown(id)))
    }

    /// `409`: the request does not fit the state of what it names.
    pub fn conflict(message: impl Into<String>) -> ApiError {
        ApiError::new(StatusCode::CONFLICT, message)
    }

    /// Adds a field to the JSON body: one of [`ErrorBody::FIELDS`].
    pub fn with(mut self, key: &str, value: impl Into<Value>) -> ApiError {
        debug_assert!(
            ErrorBody::FIELDS.contains(&key),
            "`{key}` is not a field of ErrorBody: describe it there first"
        );
        self.body.insert(key.into(), value.into());
        self
    }
}

impl From<StoreError> for ApiError {
    fn from(e: StoreError) -> ApiError {
        let busy = matches!(&e, StoreError::Db(sqlx::Error::PoolTimedOut))
            || e.to_string().contains("database is locked");
        tracing::error!("storage error: {e}");
        if e.is_storage() {
            // A full disk or a failing one: the service's trouble, and it may pass.
            ApiError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                format!("the service's storage is failing now: {e}"),
            )
            .retry_after(5)
        } else if busy {
            ApiError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                "the database is busy; try again",
            )
            .retry_after(1)
        } else {
            ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, "internal storage error")
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let mut resp = (self.status, Json(Value::Object(self.body))).into_response();
        if let Some(secs) = self.retry_after {
            resp.headers_mut()
                .insert(axum::http::header::RETRY_AFTER, secs.into());
        }
        resp
    }
}

/// JSON 404 for unknown routes; a user route written with a trailing `/` (`POST /jobs/`)
/// is told the route without it.
pub async fn no_route(uri: axum::http::Uri) -> ApiError {
    let message = match uri
        .path()
        .strip_suffix('/')
        .filter(|bare| is_user_route(bare))
    {
        Some(bare) => {
            format!("no such route; did you mean {bare} (without the trailing `/`)? see /")
        }
        None => "no such route; see /".to_string(),
    };
    ApiError::new(StatusCode::NOT_FOUND, message)
}

/// Whether `path` is one of the user routes (`/jobs`, `/jobs/{id}` and what is under it,
/// `/healthz`, `/workers`, `/metrics`, `/openapi.json`, `/api`).
fn is_user_route(path: &str) -> bool {
    let segs: Vec<&str> = path.split('/').skip(1).collect();
    match segs.as_slice() {
        ["jobs" | "healthz" | "workers" | "metrics" | "openapi.json" | "api"] => true,
        ["jobs", id] => !id.is_empty(),
        [
            "jobs",
            id,
            "image.png" | "preview.png" | "events" | "tiles" | "scene" | "retry",
        ] => !id.is_empty(),
        _ => false,
    }
}

/// JSON 405 for known routes with the wrong method.
pub async fn wrong_method() -> ApiError {
    ApiError::new(
        StatusCode::METHOD_NOT_ALLOWED,
        "method not allowed on this route",
    )
}

/// Every error answer's body: `error` says what went wrong, in words; some answers add
/// fields that say where or how far.
#[derive(Debug, Serialize, ToSchema)]
pub struct ErrorBody {
    /// What went wrong.
    pub error: String,
    /// A refused scene: the line of its first mistake (1-based).
    #[schema(required = false)]
    pub line: Option<u32>,
    /// A refused scene: the column of its first mistake (1-based, in characters).
    #[schema(required = false)]
    pub column: Option<u32>,
    /// A refused scene: every mistake found.
    #[schema(required = false)]
    pub errors: Option<Vec<SceneMistake>>,
    /// A request that does not fit the job's state: that state.
    #[schema(required = false)]
    pub state: Option<String>,
    /// A job's image asked for too early: tiles done so far.
    #[schema(required = false)]
    pub tiles_done: Option<i64>,
    /// A job's image asked for too early: tiles in all.
    #[schema(required = false)]
    pub tiles_total: Option<i64>,
    /// A scene whose textures were not sent: their names.
    #[schema(required = false)]
    pub missing_assets: Option<Vec<String>>,
    /// A submission that found no room: the service's budget of bytes being received.
    #[schema(required = false)]
    pub receiving_bytes: Option<u64>,
    /// A submission whose scene found no room to be checked: the memory the service gives
    /// to checking scenes at once.
    #[schema(required = false)]
    pub max_checking_bytes: Option<u64>,
    /// A submission whose scene found no room to be checked: what its check is charged.
    #[schema(required = false)]
    pub check_bytes: Option<u64>,
    /// A submission whose textures found no room to be decoded: the most texels the service
    /// decodes at once.
    #[schema(required = false)]
    pub max_scene_texture_pixels: Option<u64>,
    /// A job of too many tiles: its tile count.
    #[schema(required = false)]
    pub tiles: Option<u64>,
    /// A job of too many tiles: the most a job may have.
    #[schema(required = false)]
    pub max_tiles: Option<u64>,
    /// A job of too many tiles: the smallest tile edge that would fit.
    #[schema(required = false)]
    pub min_tile: Option<u32>,
}

/// One mistake in a refused scene.
#[derive(Debug, Serialize, ToSchema)]
pub struct SceneMistake {
    /// Its line (1-based).
    pub line: u32,
    /// Its column (1-based, in characters).
    pub column: u32,
    /// What is wrong, and what was expected.
    pub message: String,
}

impl ErrorBody {
    /// The fields an error answer may carry besides `error` ([`ApiError::with`] takes no
    /// other, so that the document's description of errors stays the answers' own).
    pub const FIELDS: [&str; 14] = [
        "line",
        "column",
        "errors",
        "state",
        "tiles_done",
        "tiles_total",
        "missing_assets",
        "receiving_bytes",
        "max_scene_texture_pixels",
        "max_checking_bytes",
        "check_bytes",
        "tiles",
        "max_tiles",
        "min_tile",
    ];
}

/// The body of a successful JSON answer.
pub fn ok_json(v: impl serde::Serialize) -> Json<Value> {
    Json(serde_json::to_value(v).unwrap_or_else(|e| json!({ "error": e.to_string() })))
}

/// The safety net behind [`ApiError`]: an error answer produced outside the handlers (an
/// extractor's rejection of a malformed path, query or JSON body, a body over its limit) is
/// rewritten as JSON `{"error": ...}` with its status and headers kept.
pub async fn json_errors(req: Request, next: Next) -> Response {
    let resp = next.run(req).await;
    let status = resp.status();
    if !(status.is_client_error() || status.is_server_error()) {
        return resp;
    }
    let is_json = resp
        .headers()
        .get(axum::http::header::CONTENT_TYPE)
        .is_some_and(|v| v.as_bytes().starts_with(b"application/json"));
    if is_json {
        return resp;
    }
    let (mut parts, body) = resp.into_parts();
    let text = match axum::body::to_bytes(body, 64 * 1024).await {
        Ok(b) => String::from_utf8_lossy(&b).trim().to_string(),
        Err(_) => String::new(),
    };
    let message = if text.is_empty() {
        status.canonical_reason().unwrap_or("error").to_string()
    } else {
        text
    };
    parts.headers.remove(axum::http::header::CONTENT_LENGTH);
    parts.headers.remove(axum::http::header::CONTENT_TYPE);
    let mut out = ApiError::new(status, message).into_response();
    for (k, v) in parts.headers.iter() {
        out.headers_mut().insert(k, v.clone());
    }
    out
}

/// Refuses a request whose `Content-Length` is over `limit` with `413` before reading any
/// of its body. The body limit alone stops a body only once `limit` bytes of it have
/// arrived (and are held); a declared length over it needs none read.
///
/// A body that declares no length (chunked) is stopped by the body limit once it passes
/// it; that `413` comes from axum's extractor ("length limit exceeded"), and is answered
/// here with the same kind of message as a declared one, so that a client sees the limit
/// either way. (No handler on these routes answers `413` for anything else.)
pub async fn declared_length_within(limit: usize, req: Request, next: Next) -> Response {
    match declared_length(req.headers()) {
        Some(n) if n > limit as u64 => ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("the body is {n} bytes; the limit is {limit}"),
        )
        .into_response(),
        _ => {
            let resp = next.run(req).await;
            if resp.status() == StatusCode::PAYLOAD_TOO_LARGE {
                ApiError::new(
                    StatusCode::PAYLOAD_TOO_LARGE,
                    format!("the body is over the limit of {limit} bytes"),
                )
                .into_response()
            } else {
                resp
            }
        }
    }
}

/// The request's `Content-Length`, when it has a readable one.
pub fn declared_length(headers: &axum::http::HeaderMap) -> Option<u64> {
    headers
        .get(axum::http::header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse().ok())
}

/// A name the user sent, cut for a message to its first 64 characters (with `…`).
pub fn shown(name: &str) -> std::borrow::Cow<'_, str> {
    match name.char_indices().nth(64) {
        Some((end, _)) => format!("{}…", &name[..end]).into(),
        None => name.into(),
    }
}
