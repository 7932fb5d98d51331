//! The router: every route with its handler, body limit and token check, and the layers
//! around all of them (JSON errors, request logging). Which token a route needs is decided
//! here; `auth` only checks tokens.

use std::time::Duration;

use axum::Router;
use axum::extract::DefaultBodyLimit;
use axum::routing::{get, post, put};
use tracing::error;

use crate::handlers::{image, jobs, page, workers};
use crate::state::AppState;
use crate::tiling::protocol_limit;
use crate::{auth, error};

/// All routes, with their body limits and token checks.
pub fn router(state: AppState) -> Router {
    // A tile blob: the header and at most `MAX_TILE` × `MAX_TILE` RGB pixels.
    let tile_limit = protocol_limit();
    let body_limit = state.cfg.max_body_bytes;
    let worker_routes = Router::new()
        .route("/worker/claim", post(workers::claim))
        .route("/worker/jobs/{id}", get(workers::job))
        .route("/worker/jobs/{id}/assets/{name}", get(workers::asset))
        .route("/worker/jobs/{id}/tiles/{idx}", put(workers::result))
        .route("/worker/jobs/{id}/tiles/{idx}/renew", post(workers::renew))
        .route("/worker/jobs/{id}/tiles/{idx}/fail", post(workers::fail))
        .route(
            "/worker/jobs/{id}/tiles/{idx}/release",
            post(workers::release),
        )
        .layer(DefaultBodyLimit::max(tile_limit))
        .route_layer(axum::middleware::from_fn(move |req, next| {
            error::declared_length_within(tile_limit, req, next)
        }))
        .route_layer(axum::middleware::from_fn_with_state(
            state.clone(),
            auth::require_worker_token,
        ));
    let job_routes = Router::new()
        .route("/jobs", get(jobs::list_jobs).post(jobs::submit))
        .route("/jobs/{id}", get(jobs::get_job).delete(jobs::delete_job))
        .layer(DefaultBodyLimit::max(state.cfg.max_body_bytes))
        .route_layer(axum::middleware::from_fn(move |req, next| {
            error::declared_length_within(body_limit, req, next)
        }))
        .route_layer(axum::middleware::from_fn_with_state(
            state.clone(),
            auth::require_submit_token,
        ));
    Router::new()
        .route("/", get(page::page))
        .route("/healthz", get(page::healthz))
        .route("/workers", get(workers::list_workers))
        .route("/jobs/{id}/image.png", get(image::image))
        .merge(job_routes)
        .merge(worker_routes)
        .fallback(error::no_route)
        .method_not_allowed_fallback(error::wrong_method)
        .layer(axum::middleware::from_fn(error::json_errors))
        .layer(tower_http::trace::TraceLayer::new_for_http().on_failure(log_failure))
        .with_state(state)
}

/// tower-http's log line for a failed response: an error, except a `503`, which the
/// service answers on purpose (a busy database, a farm paused for a full disk, a
/// submission waiting for room: each logged where it is decided) and which comes once per
/// waiting worker's claim while the farm is paused: logged at DEBUG.
fn log_failure(
    class: tower_http::classify::ServerErrorsFailureClass,
    latency: Duration,
    _span: &tracing::Span,
) {
    use tower_http::classify::ServerErrorsFailureClass::StatusCode as Status;
    let ms = latency.as_millis() as u64;
    match class {
        Status(s) if s == axum::http::StatusCode::SERVICE_UNAVAILABLE => {
            tracing::debug!(ms, "answered 503")
        }
        other => error!(ms, "response failed: {other}"),
    }
}
