//! Watching a job render: its tiles (`GET /jobs/{id}/tiles`), its scene
//! (`GET /jobs/{id}/scene`), its live preview (`GET /jobs/{id}/preview.png`) and its
//! events (`GET /jobs/{id}/events`). What they read and how is `preview`'s and `events`'s;
//! these check the request and map the answer.

use axum::Json;
use axum::body::Body;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};

use crate::error::ApiError;
use crate::error::ErrorBody;
use crate::events;
use crate::params::{NoParams, Params};
use crate::preview::{self, Version};
use crate::state::AppState;
use crate::store::{JobRow, TileView};

/// The job and all its tiles, or `404`.
async fn job_and_tiles(state: &AppState, id: &str) -> Result<(JobRow, Vec<TileView>), ApiError> {
    let row = state
        .store
        .job(id)
        .await?
        .ok_or_else(|| ApiError::no_job(id))?;
    let tiles = state
        .store
        .tiles(id)
        .await?
        .ok_or_else(|| ApiError::no_job(id))?;
    Ok((row, tiles))
}

/// `GET /jobs/{id}/tiles`: every tile of the job in index order, with its state, the worker
/// that holds or rendered it, and its attempts and failures.
#[utoipa::path(
    get, path = "/jobs/{id}/tiles", tag = "jobs",
    summary = "List a job's tiles",
    description = "Every tile of the job in index order: where it is, its state, the worker that holds or rendered it, how often it was handed out and failed.",
    params(("id" = String, Path, description = "The job's id")),
    responses(
        (status = 200, description = "The job's tiles in index order", body = [TileView]),
        (status = 400, description = "A query parameter was given", body = ErrorBody),
        (status = 404, description = "No such job", body = ErrorBody),
        (status = 503, description = "The database is busy or failing; try again", body = ErrorBody),
    )
)]
pub async fn tiles(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Params(NoParams {}): Params<NoParams>,
) -> Result<Json<Vec<TileView>>, ApiError> {
    let (_, tiles) = job_and_tiles(&state, &id).await?;
    Ok(Json(tiles))
}

/// `GET /jobs/{id}/preview.png`: the image as far as it is rendered (see `preview`), with its
/// version as `ETag`; `304` when `If-None-Match` names the current version.
#[utoipa::path(
    get, path = "/jobs/{id}/preview.png", tag = "jobs",
    summary = "The image so far",
    description = "The image as far as it is rendered, at any moment: an RGBA PNG whose stored tiles hold their final pixels and whose other pixels are transparent. Its `ETag` changes with every stored tile; ask with `If-None-Match` to get `304` while nothing new is stored.",
    params(
        ("id" = String, Path, description = "The job's id"),
        ("If-None-Match" = Option<String>, Header, description = "The `ETag` of a preview already held"),
    ),
    responses(
        (status = 200, description = "An RGBA PNG: stored tiles in their final pixels, alpha 0 elsewhere",
         content_type = "image/png", body = Vec<u8>,
         headers(("ETag" = String, description = "The preview's version"))),
        (status = 304, description = "The preview named by `If-None-Match` is still the current one"),
        (status = 400, description = "A query parameter was given", body = ErrorBody),
        (status = 404, description = "No such job", body = ErrorBody),
        (status = 503, description = "The database is busy or failing; try again", body = ErrorBody),
    )
)]
pub async fn preview(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Params(NoParams {}): Params<NoParams>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let (row, tiles) = job_and_tiles(&state, &id).await?;
    let version = Version::of(&row, &tiles);
    let mut out = HeaderMap::new();
    if let Ok(v) = HeaderValue::from_str(version.etag()) {
        out.insert(header::ETAG, v);
    }
    // Revalidated every time: the preview changes with every stored tile.
    out.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    let held = headers
        .get(header::IF_NONE_MATCH)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.split(',').any(|tag| tag.trim() == version.etag()));
    if held {
        return Ok((StatusCode::NOT_MODIFIED, out).into_response());
    }
    out.insert(header::CONTENT_TYPE, HeaderValue::from_static("image/png"));
    if let Some(png) = state.previews.get(&version) {
        return Ok((out, png).into_response());
    }
    let stream = preview::stream(
        state.store.clone(),
        state.previews.clone(),
        row,
        tiles,
        version,
    );
    Ok((out, Body::from_stream(stream)).into_response())
}

/// `GET /jobs/{id}/events`: the job's server-sent events (see `events`).
#[utoipa::path(
    get, path = "/jobs/{id}/events", tag = "jobs",
    summary = "Follow a job",
    description = "Server-sent events: `job` (the job, first and whenever it changes), `tiles` (every tile, once), `tile` (a tile whose state, holder or failures changed), `failure` (a tile's failures rose), `end` (the job ended; the stream closes), `deleted`. Each event's data is JSON.",
    params(("id" = String, Path, description = "The job's id")),
    responses(
        (status = 200, description = "Server-sent events: `job`, `tiles`, `tile`, `failure`, `end`, `deleted`; \
                                      each event's data is one JSON object",
         content_type = "text/event-stream", body = events::JobEvent),
        (status = 400, description = "A query parameter was given", body = ErrorBody),
        (status = 404, description = "No such job", body = ErrorBody),
        (status = 503, description = "The database is busy or failing; try again", body = ErrorBody),
    )
)]
pub async fn events(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Params(NoParams {}): Params<NoParams>,
) -> Result<Response, ApiError> {
    let (row, tiles) = job_and_tiles(&state, &id).await?;
    Ok(events::stream(state, row, tiles).into_response())
}

/// `GET /jobs/{id}/scene`: the scene's `.ray` text as it was submitted.
#[utoipa::path(
    get, path = "/jobs/{id}/scene", tag = "jobs",
    summary = "Get a job's scene",
    description = "The scene's `.ray` text as it was submitted.",
    params(("id" = String, Path, description = "The job's id")),
    responses(
        (status = 200, description = "The scene's text as submitted", content_type = "text/plain", body = String),
        (status = 400, description = "A query parameter was given", body = ErrorBody),
        (status = 404, description = "No such job", body = ErrorBody),
        (status = 503, description = "The database is busy or failing; try again", body = ErrorBody),
    )
)]
pub async fn scene(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Params(NoParams {}): Params<NoParams>,
) -> Result<Response, ApiError> {
    let (_, spec) = state
        .store
        .job_scene(&id)
        .await?
        .ok_or_else(|| ApiError::no_job(&id))?;
    let mut headers = HeaderMap::new();
    headers.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("text/plain; charset=utf-8"),
    );
    Ok((headers, spec.scene).into_response())
}
