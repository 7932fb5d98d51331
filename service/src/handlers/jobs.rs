//! The job routes: submit a scene (`POST /jobs`), list jobs, get one (optionally waiting for
//! its end), cancel or purge one. Each checks what was sent, calls the queue and maps the
//! answer; reading the body is `upload`'s, checking the scene `validate`'s.

use std::sync::Arc;
use std::time::Duration;

use axum::Json;
use axum::extract::{Path, Query, Request, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use serde_json::Value;

use crate::error::{ApiError, ok_json};
use crate::names::check_job_name;
use crate::now_ms;
use crate::params::{
    DeleteParams, JobParams, ListParams, MAX_JOB_WAIT_SECS, MAX_JOBS_LISTED, MAX_PRIORITY,
    MIN_PRIORITY, SubmitParams, bad_query,
};
use crate::state::AppState;
use crate::store::{Cancel, JobRow, JobState, STORAGE_PAUSE};
use crate::tiling::{MAX_TILE, MIN_TILE};
use crate::upload::{non_utf8_param, read_submission};
use crate::validate::{scene_source, validate};

/// A job as the API shows it.
#[derive(Debug, Serialize)]
pub struct JobView {
    #[serde(flatten)]
    pub row: JobRow,
    /// Fraction of tiles done, 0 to 1.
    pub progress: f64,
    pub url: String,
    pub image_url: String,
    /// Why a job still to finish makes no progress now: the service cannot store tile
    /// pixels (a full disk), so no tile is handed out until it can again. Absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub paused: Option<String>,
}

impl From<JobRow> for JobView {
    fn from(row: JobRow) -> JobView {
        let progress = if row.tiles_total > 0 {
            row.tiles_done as f64 / row.tiles_total as f64
        } else {
            0.0
        };
        JobView {
            url: format!("/jobs/{}", row.id),
            image_url: format!("/jobs/{}/image.png", row.id),
            progress,
            row,
            paused: None,
        }
    }
}

impl JobView {
    /// The job as the API shows it, with the service's state: one with tiles still to
    /// render says so while the farm is paused for storage
    /// ([`Store::storage_trouble`](crate::store::Store::storage_trouble)), which otherwise
    /// only `/healthz` told. The reason is given in general terms: the failed write's own
    /// message names another job's spool file.
    fn of(state: &AppState, row: JobRow) -> JobView {
        let waiting = row.state.is_active() && row.tiles_done < row.tiles_total;
        let mut view = JobView::from(row);
        if waiting
            && state
                .store
                .storage_trouble(now_ms(), STORAGE_PAUSE)
                .is_some()
        {
            view.paused = Some(
                "the service has no room to store tile pixels now (a full disk, or no file \
                 descriptors to spare): tiles are handed out again once it has"
                    .to_string(),
            );
        }
        view
    }
}

/// `GET /jobs`: a page of jobs, newest first, as [`ListParams`] asks.
pub async fn list_jobs(
    State(state): State<AppState>,
    Query(params): Query<ListParams>,
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
/// [`JobParams`]); also at once when the service begins to stop.
pub async fn get_job(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Query(params): Query<JobParams>,
) -> Result<Json<Value>, ApiError> {
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
pub async fn delete_job(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Query(params): Query<DeleteParams>,
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
        state.ended.notify_waiters();
        return Ok(StatusCode::NO_CONTENT.into_response());
    }
    let outcome = state.store.cancel(&id, now_ms()).await?;
    // Waiting requests look again now.
    state.ended.notify_waiters();
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

/// `POST /jobs`: the raw scene as the body, or multipart with a `scene` part and one part
/// per asset named as the scene names it.
pub async fn submit(State(state): State<AppState>, req: Request) -> Result<Response, ApiError> {
    if let Some(key) = req.uri().query().and_then(non_utf8_param) {
        return Err(ApiError::bad_request(format!(
            "query parameter `{key}` is not UTF-8 text once percent-decoded"
        )));
    }
    let params: SubmitParams = match Query::<SubmitParams>::try_from_uri(req.uri()) {
        Ok(Query(p)) => p,
        Err(e) => return Err(ApiError::bad_request(bad_query(&e.body_text()))),
    };
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
    let location = format!("/jobs/{}", row.id);
    let mut resp = (StatusCode::CREATED, ok_json(JobView::of(&state, row))).into_response();
    if let Ok(v) = HeaderValue::from_str(&location) {
        resp.headers_mut().insert(header::LOCATION, v);
    }
    Ok(resp)
}
