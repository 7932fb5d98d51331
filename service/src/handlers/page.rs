//! The web page (`GET /`) and the health check (`GET /healthz`).

use std::time::Duration;

use axum::Json;
use axum::extract::State;
use axum::http::StatusCode;
use axum::response::Html;
use serde_json::{Value, json};

use crate::error::ApiError;
use crate::now_ms;
use crate::state::AppState;
use crate::store::STORAGE_PAUSE;

/// The web page, told this service's body limit (`--max-body-bytes`) so that it can refuse a
/// scene and textures too large to send before sending them: the service answers `413` from
/// the request's length and closes the connection, which a browser's `fetch` reports as a
/// network error rather than the answer.
pub async fn page(State(state): State<AppState>) -> Html<String> {
    Html(include_str!("../page.html").replace(
        "__TESSERA_MAX_BODY_BYTES__",
        &state.cfg.max_body_bytes.to_string(),
    ))
}

/// `200` when the database answers a read and takes a write (a row rewritten within
/// [`HEALTH_WRITE_WITHIN`]), `503` naming what failed otherwise, so that a full disk, which
/// fails every submission and result, shows here.
pub async fn healthz(State(state): State<AppState>) -> Result<Json<Value>, ApiError> {
    state.store.ping().await?;
    if let Some(why) = state.store.storage_trouble(now_ms(), STORAGE_PAUSE) {
        return Err(ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            format!("the tile spool failed to store a tile's pixels: {why}"),
        ));
    }
    if let Err(e) = state.store.probe_write(now_ms(), HEALTH_WRITE_WITHIN).await {
        tracing::error!("health check: {e}");
        return Err(ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            format!("the database or the tile spool does not take writes: {e}"),
        ));
    }
    Ok(Json(json!({ "status": "ok" })))
}

/// How long the health check's write may wait for the database.
pub const HEALTH_WRITE_WITHIN: Duration = Duration::from_secs(2);
