//! The web pages and what they load: the job list (`GET /`), a job's page (`GET /jobs/{id}`
//! asked for as HTML), the API page (`GET /api`), their scripts, style and icon
//! (`/static/…`), the OpenAPI document (`GET /openapi.json`), and the health check
//! (`GET /healthz`).
//!
//! The pages are static files built into the binary; their scripts read the JSON routes like
//! any client. No page has inline script or style, so that a strict `Content-Security-Policy`
//! (`script-src 'self'`) holds for them.

use std::time::Duration;

use axum::Extension;
use axum::Json;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{Html, IntoResponse, Response};
use serde_json::{Value, json};

use crate::error::{ApiError, ErrorBody};
use crate::params::{NoParams, Params};
use crate::state::AppState;
use crate::store::STORAGE_PAUSE;
use crate::worker_view::{by_state, roster};
use crate::{metrics, now_ms};

/// The files under `/static/`: name, media type, contents.
const STATIC: &[(&str, &str, &str)] = &[
    (
        "app.css",
        "text/css; charset=utf-8",
        include_str!("../../web/app.css"),
    ),
    (
        "common.js",
        "text/javascript; charset=utf-8",
        include_str!("../../web/common.js"),
    ),
    (
        "list.js",
        "text/javascript; charset=utf-8",
        include_str!("../../web/list.js"),
    ),
    (
        "job.js",
        "text/javascript; charset=utf-8",
        include_str!("../../web/job.js"),
    ),
    (
        "api.js",
        "text/javascript; charset=utf-8",
        include_str!("../../web/api.js"),
    ),
    (
        "favicon.svg",
        "image/svg+xml",
        include_str!("../../web/favicon.svg"),
    ),
];

/// The list page, told this service's body limit (`--max-body-bytes`) so that it can refuse
/// a scene and textures too large to send before sending them: the service answers `413`
/// from the request's length and closes the connection, which a browser's `fetch` reports
/// as a network error rather than the answer.
#[utoipa::path(
    get, path = "/", tag = "pages",
    summary = "The web page",
    description = "Submit a scene, see jobs and their progress, open a job's page, see the workers.",
    responses((status = 200, description = "The page", content_type = "text/html", body = String))
)]
pub async fn page(State(state): State<AppState>) -> Html<String> {
    Html(include_str!("../../web/index.html").replace(
        "__TESSERA_MAX_BODY_BYTES__",
        &state.cfg.max_body_bytes.to_string(),
    ))
}

/// A job's page (its script reads the job from the address it is shown at).
pub fn job_page(_state: &AppState) -> Response {
    let mut resp = Html(include_str!("../../web/job.html")).into_response();
    // `/jobs/{id}` answers JSON or this page by `Accept`: caches must keep both apart.
    resp.headers_mut()
        .insert(header::VARY, HeaderValue::from_static("Accept"));
    resp
}

/// The API page: the OpenAPI document made readable.
#[utoipa::path(
    get, path = "/api", tag = "pages",
    summary = "The API page",
    description = "This document, written out for people.",
    responses((status = 200, description = "The page", content_type = "text/html", body = String))
)]
pub async fn api_page() -> Html<&'static str> {
    Html(include_str!("../../web/api.html"))
}

/// Whether a request asks for HTML before JSON: a browser's navigation does
/// (`text/html,…,*/*;q=0.8`); `fetch`, curl and `EventSource` do not.
pub fn wants_html(headers: &HeaderMap) -> bool {
    let Some(accept) = headers.get(header::ACCEPT).and_then(|v| v.to_str().ok()) else {
        return false;
    };
    // Each media range with its weight (`q`, 1 when absent), in the order given.
    let ranges: Vec<(&str, f32)> = accept
        .split(',')
        .map(|range| {
            let mut parts = range.split(';');
            let kind = parts.next().unwrap_or("").trim();
            let q = parts
                .filter_map(|p| p.trim().strip_prefix("q="))
                .find_map(|q| q.trim().parse::<f32>().ok())
                .unwrap_or(1.0);
            (kind, q)
        })
        .collect();
    let find = |kind: &str| {
        ranges
            .iter()
            .enumerate()
            .find(|(_, (k, _))| k.eq_ignore_ascii_case(kind))
            .map(|(at, &(_, q))| (at, q))
    };
    match (find("text/html"), find("application/json")) {
        (Some((_, q)), _) if q <= 0.0 => false,
        (Some((h_at, h_q)), Some((j_at, j_q))) => h_q > j_q || (h_q == j_q && h_at < j_at),
        (Some(_), None) => true,
        (None, _) => false,
    }
}

/// `GET /static/{file}`: a page's script, style or icon.
pub async fn asset(Path(file): Path<String>) -> Result<Response, ApiError> {
    let (_, kind, body) = STATIC
        .iter()
        .find(|(name, _, _)| *name == file)
        .ok_or_else(|| {
            ApiError::not_found(format_args!("file `{}`", crate::error::shown(&file)))
        })?;
    let mut resp = (*body).into_response();
    let headers = resp.headers_mut();
    headers.insert(header::CONTENT_TYPE, HeaderValue::from_static(kind));
    // Checked again on every load, so that a new version of the service serves new pages.
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    Ok(resp)
}

/// `GET /favicon.ico`: browsers ask for it whatever the page says; the icon is an SVG.
pub async fn favicon() -> Result<Response, ApiError> {
    asset(Path("favicon.svg".to_string())).await
}

/// The OpenAPI document as JSON, handed to [`openapi`] by the router that it describes (an
/// extension, so that this module does not depend on the router's).
#[derive(Debug, Clone)]
pub struct Document(pub &'static str);

/// `GET /openapi.json`: the OpenAPI 3.1 document of the user routes, as the router built
/// it from the handlers' own descriptions.
#[utoipa::path(
    get, path = "/openapi.json", tag = "service",
    summary = "This document",
    description = "The OpenAPI 3.1 document of every user route, generated from the service's own code.",
    responses((status = 200, description = "The document", body = Value))
)]
pub async fn openapi(Extension(doc): Extension<Document>) -> Response {
    let mut resp = doc.0.into_response();
    resp.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/json"),
    );
    resp
}

/// `200` when the database answers a read and takes a write (a row rewritten within
/// [`HEALTH_WRITE_WITHIN`]), `503` naming what failed otherwise, so that a full disk, which
/// fails every submission and result, shows here.
#[utoipa::path(
    get, path = "/healthz", tag = "service",
    summary = "Health",
    description = "`200` when the service and its database answer and take writes; `503` naming what fails otherwise (a full disk shows here).",
    responses(
        (status = 200, description = "The service and its database answer and take writes", body = Value,
         example = json!({"status": "ok"})),
        (status = 503, description = "What fails: the database, the storage of tile pixels, or room to write since the start (the service is then read-only)", body = ErrorBody),
    )
)]
pub async fn healthz(State(state): State<AppState>) -> Result<Json<Value>, ApiError> {
    state.store.ping().await?;
    if let Some(why) = state.read_only.why() {
        return Err(crate::read_only::ReadOnly::refusal(&why));
    }
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

#[cfg(test)]
mod tests {
    use axum::http::{HeaderMap, HeaderValue, header};

    /// A browser's navigation gets the page; `fetch`, curl, `EventSource` and a client that
    /// prefers JSON get JSON.
    #[test]
    fn html_is_for_clients_that_ask_for_it_first() {
        let wants = |accept: Option<&'static str>| {
            let mut h = HeaderMap::new();
            if let Some(a) = accept {
                h.insert(header::ACCEPT, HeaderValue::from_static(a));
            }
            super::wants_html(&h)
        };
        assert!(wants(Some(
            "text/html,application/xhtml+xml,application/xml;q=0.9,image/avif,*/*;q=0.8"
        )));
        assert!(wants(Some("Text/HTML")));
        assert!(!wants(None));
        assert!(!wants(Some("*/*")));
        assert!(!wants(Some("text/event-stream")));
        assert!(!wants(Some("application/json, text/html")));
        assert!(wants(Some("text/html;q=0.9, application/json;q=0.8")));
        assert!(!wants(Some("application/json;q=0.9, text/html;q=0.5")));
        assert!(wants(Some("application/json;q=0.1, text/html")));
        assert!(!wants(Some("text/html;q=0")));
    }
}

/// `GET /metrics`: the Prometheus text of the service's metrics (see `metrics`).
#[utoipa::path(
    get, path = "/metrics", tag = "service",
    summary = "Prometheus metrics",
    description = "The service's metrics in Prometheus's text format: jobs by state, tiles waiting and leased, workers by state (read from the database at each scrape), and this process's counters and histograms: tiles claimed, stored, failed and reaped, rays traced, jobs submitted, claim wait and tile render time, requests by route and status. Each metric is described in `docs/OPERATIONS.md`.",
    responses(
        (status = 200, description = "The metrics, as Prometheus text", body = String,
         content_type = "text/plain; version=0.0.4; charset=utf-8"),
        (status = 400, description = "A query parameter was given", body = ErrorBody),
        (status = 503, description = "The database is busy or failing; try again", body = ErrorBody),
    )
)]
pub async fn scrape_metrics(
    State(state): State<AppState>,
    Params(NoParams {}): Params<NoParams>,
) -> Result<Response, ApiError> {
    let farm = state.store.counts().await?;
    let workers = roster(&state, now_ms()).await?;
    let text = metrics::scrape(&farm, &by_state(&workers));
    Ok((
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("text/plain; version=0.0.4; charset=utf-8"),
        )],
        text,
    )
        .into_response())
}
