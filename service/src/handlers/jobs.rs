//! The job routes: submit a scene (`POST /jobs`), list jobs, get one (optionally waiting for
//! its end; a browser gets the job's page), change its priority, retry, cancel or purge
//! one. Each checks what was sent, calls the queue and maps the answer; reading the body is
//! `upload`'s, checking the scene `validate`'s.

use std::sync::Arc;
use std::time::Duration;

use axum::Json;
use axum::extract::rejection::JsonRejection;
use axum::extract::{Path, Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, Uri, header};
use axum::response::{IntoResponse, Response};
use serde::Deserialize;
use serde_json::Value;
use utoipa::ToSchema;

use crate::error::{ApiError, ErrorBody, ok_json};
use crate::handlers::page;
use crate::job_view::JobView;
use crate::names::check_job_name;
use crate::now_ms;
use crate::params::{
    DeleteParams, JobParams, ListParams, MAX_JOB_WAIT_SECS, MAX_JOBS_LISTED, MAX_PRIORITY,
    MIN_PRIORITY, Params, SubmitParams,
};
use crate::state::AppState;
use crate::store::{Cancel, JobRow, JobState, Reprioritized, Retried};
use crate::tiling::{MAX_TILE, MIN_TILE};
use crate::upload::read_submission;
use crate::validate::{scene_source, validate};

/// `GET /jobs`: a page of jobs, newest first, as [`ListParams`] asks.
#[utoipa::path(
    get, path = "/jobs", tag = "jobs",
    summary = "List jobs",
    description = "A page of jobs, newest first: at most `limit`, and with `before`, those submitted before that job.",
    params(ListParams),
    responses(
        (status = 200, description = "A page of jobs, newest first", body = [JobView]),
        (status = 400, description = "A query parameter that does not parse or is out of range", body = ErrorBody),
        (status = 404, description = "`before` names no job", body = ErrorBody),
        (status = 503, description = "The database is busy or failing; try again", body = ErrorBody),
    )
)]
pub async fn list_jobs(
    State(state): State<AppState>,
    Params(params): Params<ListParams>,
) -> Result<Json<Value>, ApiError> {
    let limit = params.limit.unwrap_or(MAX_JOBS_LISTED);
    if !(1..=MAX_JOBS_LISTED).contains(&limit) {
        return Err(ApiError::bad_request(format!(
            "limit must be from 1 to {MAX_JOBS_LISTED}"
        )));
    }
    let before = params.before.as_deref();
    let rows = state.store.jobs(limit, before).await?.ok_or_else(|| {
        ApiError::not_found(format_args!(
            "job `{}` to list before",
            before.unwrap_or("")
        ))
    })?;
    let jobs: Vec<JobView> = rows.into_iter().map(|r| JobView::of(&state, r)).collect();
    Ok(ok_json(jobs))
}

/// How often a waiting request looks again without being woken: only a change made outside
/// this process (the database edited by hand, or a second service on it, which is not
/// supported) goes unannounced.
const JOB_WAIT_RECHECK: Duration = Duration::from_secs(1);

/// `GET /jobs/{id}`: the job, at once or, with `?wait=`, once it has ended (see
/// [`JobParams`]); also at once when the service begins to stop. A client that asks for
/// HTML first (a browser following the job's `url`) gets the job's page instead.
#[utoipa::path(
    get, path = "/jobs/{id}", tag = "jobs",
    summary = "Get a job",
    description = "The job, at once or, with `wait`, once it has ended (or the wait has passed). A browser, which asks for HTML first, gets the job's page instead.",
    params(("id" = String, Path, description = "The job's id"), JobParams),
    responses(
        (status = 200, description = "The job; a browser (`Accept: text/html` first) gets its page",
         content((JobView = "application/json"), (String = "text/html"))),
        (status = 400, description = "A query parameter that does not parse", body = ErrorBody),
        (status = 404, description = "No such job", body = ErrorBody),
        (status = 503, description = "The database is busy or failing; try again", body = ErrorBody),
    )
)]
pub async fn get_job(
    State(state): State<AppState>,
    Path(id): Path<String>,
    headers: HeaderMap,
    uri: Uri,
) -> Result<Response, ApiError> {
    if page::wants_html(&headers) {
        // The page reads the job itself; an unknown one is said here, as a page would.
        state
            .store
            .job(&id)
            .await?
            .ok_or_else(|| ApiError::no_job(&id))?;
        return Ok(page::job_page(&state).into_response());
    }
    let Params(params) = Params::<JobParams>::parse(&uri)?;
    Ok(job_json(state, id, params).await?.into_response())
}

/// The job as JSON, waiting for its end as `params` asks.
async fn job_json(state: AppState, id: String, params: JobParams) -> Result<Json<Value>, ApiError> {
    let wait = match params.wait {
        None => 0.0,
        Some(w) if w.is_finite() && w >= 0.0 => w
            .min(MAX_JOB_WAIT_SECS)
            .min(state.cfg.longest_silence().as_secs_f64()),
        Some(_) => {
            return Err(ApiError::bad_request(
                "`wait` must be a number of seconds ≥ 0",
            ));
        }
    };
    let deadline = tokio::time::Instant::now() + Duration::from_secs_f64(wait);
    loop {
        // Registered before looking, so that an end in between is not missed.
        let ended = state.ended.notified();
        tokio::pin!(ended);
        ended.as_mut().enable();
        let row = state
            .store
            .job(&id)
            .await?
            .ok_or_else(|| ApiError::no_job(&id))?;
        let now = tokio::time::Instant::now();
        let stopping = *state.stopping.borrow();
        if !row.state.is_active() || now >= deadline || stopping {
            return Ok(ok_json(JobView::of(&state, row)));
        }
        tokio::select! {
            _ = &mut ended => {}
            _ = tokio::time::sleep_until(deadline.min(now + JOB_WAIT_RECHECK)) => {}
            // The job as it is: the client asks again once the service is back.
            _ = state.stopped() => {}
        }
    }
}

/// `DELETE /jobs/{id}` cancels a queued or running job (`200` with the job). It is
/// idempotent, as HTTP clients (which retry a `DELETE`) and double clicks expect: a job that
/// has already ended is answered as it is, and one whose every tile is in (its image being
/// written) is not cancelled (`409`). `?purge=true` removes an ended job with its image
/// (`204`); an active one must be cancelled first (`409`). Cancel and purge are two requests
/// so that a repeated cancel cannot delete the job it just cancelled, nor a cancel that
/// reaches a job just finished delete its image.
#[utoipa::path(
    delete, path = "/jobs/{id}", tag = "jobs",
    summary = "Cancel or purge a job",
    description = "Cancels a queued or running job: its tiles are no longer handed out. Repeating it is harmless. With `purge=true`, removes an ended job and everything stored for it (an active one must be cancelled first).",
    security((), ("submit_token" = [])),
    params(("id" = String, Path, description = "The job's id"), DeleteParams),
    responses(
        (status = 200, description = "Cancelled (or already ended): the job", body = JobView),
        (status = 204, description = "Purged: the job and everything stored for it are gone"),
        (status = 400, description = "A query parameter that does not parse", body = ErrorBody),
        (status = 401, description = "The submit token is required and missing or wrong", body = ErrorBody),
        (status = 404, description = "No such job", body = ErrorBody),
        (status = 409, description = "Purging an active job, or cancelling one whose image is being written", body = ErrorBody),
        (status = 503, description = "The database is busy or failing; try again", body = ErrorBody),
    )
)]
pub async fn delete_job(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Params(params): Params<DeleteParams>,
) -> Result<Response, ApiError> {
    let view = |row: Option<JobRow>| row.map(JobView::from).ok_or_else(|| ApiError::no_job(&id));
    if params.purge {
        let job = view(state.store.job(&id).await?)?;
        if job.row.state.is_active() {
            return Err(ApiError::conflict(format!(
                "job `{id}` is {}: cancel it first (DELETE /jobs/{id}), then purge it",
                job.row.state
            ))
            .with("state", job.row.state));
        }
        state.store.delete(&id).await?;
        state.previews.forget(&id);
        state.changes.job(&id);
        state.ended.notify_waiters();
        return Ok(StatusCode::NO_CONTENT.into_response());
    }
    let outcome = state.store.cancel(&id, now_ms()).await?;
    // Waiting requests and the job's events look again now.
    state.ended.notify_waiters();
    state.changes.job(&id);
    if outcome == Cancel::Unknown {
        return Err(ApiError::no_job(&id));
    }
    let job = view(state.store.job(&id).await?)?;
    if outcome == Cancel::Complete && job.row.state == JobState::Running {
        return Err(ApiError::conflict(format!(
            "every tile of job `{id}` is in and its image is being written: it is not cancelled"
        ))
        .with("state", job.row.state));
    }
    Ok(ok_json(job).into_response())
}

/// `POST /jobs/{id}/retry`: makes a failed or cancelled job active again, rendering only
/// what is missing (`200` with the job). Its stored tiles stay, its other tiles are queued
/// with their failures forgotten, no worker is kept away from it, and it keeps its place in
/// the queue (priority and submission). A queued, running or done job is answered `409`.
#[utoipa::path(
    post, path = "/jobs/{id}/retry", tag = "jobs",
    summary = "Retry a failed or cancelled job",
    description = "Makes a failed or cancelled job active again. The tiles it stored stay; only the others are rendered, and the PNG is the same as a render without the interruption. Its failures are forgotten and no worker is kept away from it.",
    security((), ("submit_token" = [])),
    params(("id" = String, Path, description = "The job's id")),
    responses(
        (status = 200, description = "The job, queued or running again", body = JobView),
        (status = 400, description = "A query parameter, which this route takes none of", body = ErrorBody),
        (status = 401, description = "The submit token is required and missing or wrong", body = ErrorBody),
        (status = 404, description = "No such job", body = ErrorBody),
        (status = 409, description = "The job is queued, running or done", body = ErrorBody),
        (status = 503, description = "The database is busy or failing; try again", body = ErrorBody),
    )
)]
pub async fn retry_job(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Params(crate::params::NoParams {}): Params<crate::params::NoParams>,
) -> Result<Json<Value>, ApiError> {
    // What this process encoded of the image before the job ended is gone with its chunks:
    // the retried job's image is encoded whole once its last tile is in.
    state.progress.forget(&id);
    match state.store.retry(&id, now_ms()).await? {
        Retried::Unknown => return Err(ApiError::no_job(&id)),
        Retried::NotEnded(s) => {
            return Err(ApiError::conflict(format!(
                "job `{id}` is {s}: only a failed or cancelled job can be retried"
            ))
            .with("state", s));
        }
        Retried::Retried { complete } => {
            crate::metrics::count(crate::metrics::JOBS_RETRIED, 1);
            if complete {
                state.spawn_assembly(id.clone());
            } else {
                state.work.notify_waiters();
            }
        }
    }
    changed(&state, &id).await
}

/// `PATCH /jobs/{id}` body: what to change.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct JobPatch {
    /// The job's new priority: claims serve the highest first, and jobs of one priority in
    /// the order they came.
    #[schema(minimum = -1000, maximum = 1000)]
    #[serde(deserialize_with = "whole_number")]
    pub priority: i64,
}

/// A JSON number with no fraction, as an `i64`: `10` and `10.0` alike (JSON Schema's
/// `integer` takes both), never `10.5`.
fn whole_number<'de, D: serde::Deserializer<'de>>(d: D) -> Result<i64, D::Error> {
    let n = serde_json::Number::deserialize(d)?;
    if let Some(i) = n.as_i64() {
        return Ok(i);
    }
    match n.as_f64() {
        // Within ±2^53 every whole `f64` is exact, and the range check follows anyway.
        Some(f) if f.fract() == 0.0 && f.abs() <= 9.007_199_254_740_992e15 => Ok(f as i64),
        _ => Err(serde::de::Error::custom(format!(
            "`{n}` is not a whole number"
        ))),
    }
}

/// `PATCH /jobs/{id}` with `{"priority": N}`: changes a queued or running job's priority
/// (`409` for one that has ended). Tiles already handed out render on; the next claims
/// follow the new order.
#[utoipa::path(
    patch, path = "/jobs/{id}", tag = "jobs",
    summary = "Change a job's priority",
    description = "Sets a queued or running job's priority. Tiles already handed out render on; the next claims follow the new order.",
    security((), ("submit_token" = [])),
    params(("id" = String, Path, description = "The job's id")),
    request_body(content = JobPatch, content_type = "application/json"),
    responses(
        (status = 200, description = "The job, with its new priority", body = JobView),
        (status = 400, description = "A body that is not `{\"priority\": N}` with N from -1000 to 1000", body = ErrorBody),
        (status = 401, description = "The submit token is required and missing or wrong", body = ErrorBody),
        (status = 404, description = "No such job", body = ErrorBody),
        (status = 409, description = "The job has ended", body = ErrorBody),
        (status = 415, description = "The body is not declared `application/json`", body = ErrorBody),
        (status = 503, description = "The database is busy or failing; try again", body = ErrorBody),
    )
)]
pub async fn patch_job(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Params(crate::params::NoParams {}): Params<crate::params::NoParams>,
    body: Result<Json<JobPatch>, JsonRejection>,
) -> Result<Json<Value>, ApiError> {
    let Json(patch) = body.map_err(patch_rejected)?;
    if !(MIN_PRIORITY..=MAX_PRIORITY).contains(&patch.priority) {
        return Err(ApiError::bad_request(format!(
            "priority must be from {MIN_PRIORITY} to {MAX_PRIORITY}"
        )));
    }
    match state.store.set_priority(&id, patch.priority).await? {
        Reprioritized::Unknown => return Err(ApiError::no_job(&id)),
        Reprioritized::Ended(s) => {
            return Err(ApiError::conflict(format!(
                "job `{id}` is {s}: only a queued or running job's priority can change"
            ))
            .with("state", s));
        }
        Reprioritized::Changed => {}
    }
    changed(&state, &id).await
}

/// The answer to a change of job `id`: its events are told, and the job as it is now.
async fn changed(state: &AppState, id: &str) -> Result<Json<Value>, ApiError> {
    state.changes.job(id);
    let row = state
        .store
        .job(id)
        .await?
        .ok_or_else(|| ApiError::no_job(id))?;
    Ok(ok_json(JobView::of(state, row)))
}

/// A `PATCH` body that is not `{"priority": N}`, said in the project's words.
fn patch_rejected(e: JsonRejection) -> ApiError {
    match e {
        JsonRejection::MissingJsonContentType(_) => ApiError::new(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "send the change as JSON with `Content-Type: application/json`, e.g. {\"priority\": 10}",
        ),
        other => {
            // serde_json's reason, without axum's preamble.
            let text = other.body_text();
            let why = text.rsplit_once(": ").map_or(text.as_str(), |(_, w)| w);
            ApiError::bad_request(format!(
                "the body must be {{\"priority\": N}} with N a whole number from \
                 {MIN_PRIORITY} to {MAX_PRIORITY}: {why}"
            ))
        }
    }
}

/// `POST /jobs`: the raw scene as the body, or multipart with a `scene` part and one part
/// per asset named as the scene names it.
#[utoipa::path(
    post, path = "/jobs", tag = "jobs",
    summary = "Submit a scene",
    description = "Queues a job for the scene in the body: the `.ray` file itself, or a form with a part `scene` and one part per texture, named by the file name the scene uses. A scene with mistakes is refused with each at its line and column.",
    security((), ("submit_token" = [])),
    params(SubmitParams),
    request_body(
        description = "The scene file itself, or a form with a part `scene` and one part per texture named by the file name the scene uses",
        content(
            (String = "text/plain"),
            (String = "application/octet-stream"),
            (SubmitForm = "multipart/form-data"),
        )
    ),
    responses(
        (status = 201, description = "The job, queued", body = JobView,
         headers(("Location" = String, description = "The job's URL"))),
        (status = 400, description = "A scene with mistakes (each at its line and column), a missing texture, or a bad query parameter", body = ErrorBody),
        (status = 401, description = "The submit token is required and missing or wrong", body = ErrorBody),
        (status = 408, description = "The body stopped arriving", body = ErrorBody),
        (status = 413, description = "The body is over the service's limit", body = ErrorBody),
        (status = 503, description = "No room to receive the body now, or the database is busy or failing; try again", body = ErrorBody),
    )
)]
pub async fn submit(State(state): State<AppState>, req: Request) -> Result<Response, ApiError> {
    let Params(params) = Params::<SubmitParams>::parse(req.uri())?;
    // The submission's share of `--max-receiving-bytes`: its body's room, taken before the
    // body is read, and its textures' before they are decoded; given back once answered.
    let held = Arc::new(tokio::sync::Mutex::new(state.receiving.hold()));
    let read = read_submission(req, &state, &held).await?;
    let source = scene_source(read.scene, read.multipart)?;
    if params
        .priority
        .is_some_and(|p| !(MIN_PRIORITY..=MAX_PRIORITY).contains(&p))
    {
        return Err(ApiError::bad_request(format!(
            "priority must be from {MIN_PRIORITY} to {MAX_PRIORITY}"
        )));
    }
    let tile = params.tile.or(state.cfg.tile);
    if tile.is_some_and(|t| !(MIN_TILE..=MAX_TILE).contains(&t)) {
        return Err(ApiError::bad_request(format!(
            "tile must be from {MIN_TILE} to {MAX_TILE} pixels"
        )));
    }
    // An empty `name=` (a form's empty field) names nothing.
    let name = params
        .name
        .clone()
        .filter(|n| !n.trim().is_empty())
        .or(read.file_name);
    if let Some(n) = &name {
        check_job_name(n)?;
    }
    let job = validate(&state, source, read.uploads, &params, tile, name, &held).await?;
    let (new_job, rects, assets) = job;
    // Followed before it is stored, so that no stored tile goes uncounted; not where other
    // processes share the database, since the tiles they store would go uncounted here
    // (the image is then encoded whole once its last tile is in).
    if !state.store.is_shared() {
        state
            .progress
            .follow(&new_job.id, new_job.width, new_job.height, &rects);
    }
    let row = match state.store.insert_job(&new_job, &rects, &assets).await {
        Ok(row) => row,
        Err(e) => {
            state.progress.forget(&new_job.id);
            return Err(e.into());
        }
    };
    state.work.notify_waiters();
    state.changes.job(&row.id);
    crate::metrics::count(crate::metrics::JOBS_SUBMITTED, 1);
    let location = format!("/jobs/{}", row.id);
    let mut resp = (StatusCode::CREATED, ok_json(JobView::of(&state, row))).into_response();
    if let Ok(v) = HeaderValue::from_str(&location) {
        resp.headers_mut().insert(header::LOCATION, v);
    }
    Ok(resp)
}

/// `POST /jobs` as a form (`multipart/form-data`).
#[derive(ToSchema)]
#[allow(dead_code)]
pub struct SubmitForm {
    /// The scene's `.ray` text; its file name, if any, names the job.
    #[schema(format = Binary, content_media_type = "application/octet-stream")]
    scene: String,
}
