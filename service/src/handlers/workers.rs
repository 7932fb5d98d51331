//! The worker routes: claim a tile, fetch a job's scene and assets, renew a lease, post a
//! result, report a failure, give a tile back, say goodbye (see `docs/PROTOCOL.md`); and
//! the list of workers heard from (`GET /workers`).
//!
//! Every tile route takes the lease token as `?lease=`; the queue applies it only while the
//! token is the tile's current lease. Blobs are checked against the tile before storage.

use std::time::{Duration, Instant};

use axum::Json;
use axum::body::Bytes;
use axum::extract::{Path, Query, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde::Deserialize;
use tessera_protocol::{
    Accepted, BlobError, Bye, Claim, ClaimRequest, FailRequest, Renewed, split_tile,
};

use crate::config::MAX_CLAIM_WAIT_MS;
use crate::error::{ApiError, ErrorBody, ok_json};
use crate::params::{NoParams, Params, flag};
use crate::state::AppState;
use crate::store::{Completion, JobState, STORAGE_PAUSE};
use crate::worker_view::{WorkerView, roster};
use crate::{metrics, now_ms};

/// `GET /workers`: the workers heard from in the last ten minutes, with what each does now.
#[utoipa::path(
    get, path = "/workers", tag = "service",
    summary = "List the workers",
    description = "The workers heard from in the last ten minutes, by name: rendering (with the tiles they hold), idle, or gone (said goodbye, or silent past a lease with their leases lapsed), with the threads and rays per second they report and what they have done.",
    responses(
        (status = 200, description = "The workers, by name", body = [WorkerView]),
        (status = 400, description = "A query parameter was given", body = ErrorBody),
        (status = 503, description = "The database is busy or failing; try again", body = ErrorBody),
    )
)]
pub async fn list_workers(
    State(state): State<AppState>,
    Params(NoParams {}): Params<NoParams>,
) -> Result<Json<Vec<WorkerView>>, ApiError> {
    Ok(Json(roster(&state, now_ms()).await?))
}

/// What a worker says of itself, checked: threads from 1, a rate that is a finite number
/// of at least 0.
fn check_said(threads: Option<u32>, rays_per_second: Option<f64>) -> Result<(), ApiError> {
    if threads == Some(0) {
        return Err(ApiError::bad_request("threads must be at least 1"));
    }
    if rays_per_second.is_some_and(|r| !r.is_finite() || r < 0.0) {
        return Err(ApiError::bad_request(
            "rays_per_second must be a finite number of at least 0",
        ));
    }
    Ok(())
}

/// Notes what `worker` says of itself (what it leaves out stands as it last said).
fn note_said(state: &AppState, worker: &str, threads: Option<u32>, rays_per_second: Option<f64>) {
    if threads.is_some() || rays_per_second.is_some() {
        state.store.seen(worker, now_ms(), |w| {
            w.threads = threads.or(w.threads);
            w.rays_per_second = rays_per_second.or(w.rays_per_second);
        });
    }
}

/// `POST /worker/bye`: the worker stops cleanly, having posted or given back every tile;
/// `/workers` lists it gone at once. A claim after it brings the worker back.
pub async fn bye(
    State(state): State<AppState>,
    Json(req): Json<Bye>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let name = worker_name(&req.worker)?;
    state.store.bye(name, now_ms()).await;
    Ok(ok_json(serde_json::json!({ "left": true })))
}

/// `POST /worker/claim?wait_ms=N`: with no work at hand, wait up to `N` ms (at most 10 s)
/// for some before answering `204`. Workers need not poll fast to start promptly.
#[derive(Debug, Default, Deserialize)]
pub struct ClaimParams {
    /// Milliseconds to wait for work (at most 10 s); none: answer at once.
    pub wait_ms: Option<u64>,
}

/// `?lease=L`: the lease a tile route acts under.
#[derive(Debug, Deserialize)]
pub struct LeaseParam {
    pub lease: String,
}

fn worker_name(name: &str) -> Result<&str, ApiError> {
    tessera_protocol::check_worker_name(name).map_err(ApiError::bad_request)?;
    Ok(name)
}

/// `POST /worker/claim`: the next tile for the worker named in the body (`200` with the
/// claim), or `204` once `wait_ms` passed, or at once while the service stops, with none.
pub async fn claim(
    State(state): State<AppState>,
    Query(params): Query<ClaimParams>,
    Json(req): Json<ClaimRequest>,
) -> Result<Response, ApiError> {
    let name = worker_name(&req.worker)?;
    check_said(req.threads, req.rays_per_second)?;
    note_said(&state, name, req.threads, req.rays_per_second);
    let wait = Duration::from_millis(params.wait_ms.unwrap_or(0).min(MAX_CLAIM_WAIT_MS))
        .min(state.cfg.longest_silence());
    let asked = Instant::now();
    let deadline = tokio::time::Instant::now() + wait;
    loop {
        // Registered before looking, so that work arriving in between is not missed.
        let notified = state.work.notified();
        tokio::pin!(notified);
        notified.as_mut().enable();
        if let Some(c) = claim_now(&state, name, false).await? {
            metrics::observe(metrics::CLAIM_WAIT, asked.elapsed());
            return Ok(ok_json(c).into_response());
        }
        tokio::select! {
            _ = &mut notified => {}
            _ = tokio::time::sleep_until(deadline) => {
                return Ok(StatusCode::NO_CONTENT.into_response());
            }
            // No work from a service that is stopping; the worker asks again later.
            _ = state.stopped() => {
                return Ok(StatusCode::NO_CONTENT.into_response());
            }
        }
    }
}

/// The next tile for `worker`, if there is one now; `with_result` when the claim rides on a
/// posted result.
async fn claim_now(
    state: &AppState,
    worker: &str,
    with_result: bool,
) -> Result<Option<Claim>, ApiError> {
    // No work while results cannot be stored: it would be rendered for nothing. A claim
    // riding on a result just brings none (the result itself was stored).
    if let Some(why) = state.store.storage_trouble(now_ms(), STORAGE_PAUSE) {
        if with_result {
            return Ok(None);
        }
        return Err(ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            format!("no work is handed out while tile pixels cannot be stored: {why}"),
        )
        .retry_after(STORAGE_PAUSE.as_secs() as u32));
    }
    let claimed = state
        .store
        .claim(worker, now_ms(), state.cfg.lease_ms, state.cfg.max_attempts)
        .await
        .map_err(|e| state.store.noted(e, now_ms()))?;
    if let Some(c) = &claimed {
        state.changes.job(&c.job);
        metrics::count(metrics::TILES_CLAIMED, 1);
    }
    let n = u64::from(claimed.is_some());
    state.store.seen(worker, now_ms(), |w| {
        w.claims += n;
        if with_result {
            w.claims_with_results += n;
        }
    });
    Ok(claimed)
}

/// `GET /worker/jobs/{id}`: what a worker needs to render the job's tiles; `410` once the
/// job has ended.
pub async fn job(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let (job_state, spec) = state
        .store
        .job_scene(&id)
        .await?
        .ok_or_else(|| ApiError::no_job(&id))?;
    if !job_state.is_active() {
        return Err(ApiError::new(
            StatusCode::GONE,
            format!("job `{id}` is {job_state}"),
        ));
    }
    Ok(ok_json(spec))
}

/// `GET /worker/jobs/{id}/assets/{name}`: an asset's bytes as the job stored them.
pub async fn asset(
    State(state): State<AppState>,
    Path((id, name)): Path<(String, String)>,
) -> Result<Vec<u8>, ApiError> {
    state
        .store
        .asset(&id, &name)
        .await?
        .ok_or_else(|| ApiError::not_found(format_args!("asset `{name}` in job `{id}`")))
}

/// `POST /worker/jobs/{id}/tiles/{idx}/renew?lease=L[&rendering=true]`.
#[derive(Debug, Deserialize)]
pub struct RenewParams {
    pub lease: String,
    /// The worker is rendering the tile, not holding it ahead (see `Store::reap`).
    #[serde(default, deserialize_with = "flag")]
    pub rendering: bool,
}

/// Extends the lease by `--lease-ms`; `409` when it is no longer current.
pub async fn renew(
    State(state): State<AppState>,
    Path((id, idx)): Path<(String, u32)>,
    Query(q): Query<RenewParams>,
) -> Result<Json<serde_json::Value>, ApiError> {
    match state
        .store
        .renew(
            &id,
            idx,
            &q.lease,
            now_ms(),
            state.cfg.lease_ms,
            q.rendering,
        )
        .await
        .map_err(|e| state.store.heard_refused(&q.lease, e, now_ms()))?
    {
        Some(worker) => {
            state.store.seen(&worker, now_ms(), |_| {});
            Ok(ok_json(Renewed {
                lease_ms: state.cfg.lease_ms,
            }))
        }
        None => Err(ApiError::conflict("this lease is no longer current")),
    }
}

/// `PUT /worker/jobs/{id}/tiles/{idx}?lease=L`, with what the worker says of the tile and
/// of itself (each optional).
#[derive(Debug, Deserialize)]
pub struct ResultParams {
    pub lease: String,
    /// A worker name: with the result stored, also claim that worker's next tile (without
    /// waiting), saving it a round trip.
    pub next: Option<String>,
    /// The rays the tile took.
    pub rays: Option<u64>,
    /// The render-thread time the tile took, in milliseconds.
    pub render_ms: Option<u64>,
    /// The worker's render threads.
    pub threads: Option<u32>,
    /// The rays the worker traced per second lately.
    pub rays_per_second: Option<f64>,
}

/// `PUT /worker/jobs/{id}/tiles/{idx}?lease=L[&next=NAME]`: the tile blob. `200` stored (or a
/// harmless repeat from the same lease), with the next claim when asked for and there is
/// work; `404` no such tile, `409` from a lease that is not current, `422` for a blob that is
/// not this tile's.
pub async fn result(
    State(state): State<AppState>,
    Path((id, idx)): Path<(String, u32)>,
    Query(q): Query<ResultParams>,
    body: Bytes,
) -> Result<Json<serde_json::Value>, ApiError> {
    let next_for = q.next.as_deref().map(worker_name).transpose()?;
    check_said(q.threads, q.rays_per_second)?;
    let (rect, rgb) = split_tile(&body)
        .map_err(|e| ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, e.to_string()))?;
    let completed = state
        .store
        .complete(&id, idx, &q.lease, rect, rgb, now_ms())
        .await;
    let repeat = match completed.map_err(|e| state.store.heard_refused(&q.lease, e, now_ms()))? {
        Completion::Stored { last, worker } => {
            if let Some(worker) = &worker {
                state.store.seen(worker, now_ms(), |w| w.tiles_done += 1);
                note_said(&state, worker, q.threads, q.rays_per_second);
            }
            metrics::count(metrics::TILES_STORED, 1);
            metrics::count(metrics::RAYS_TRACED, q.rays.unwrap_or(0));
            if let Some(ms) = q.render_ms {
                metrics::observe(metrics::TILE_RENDER, Duration::from_millis(ms));
            }
            state.changes.job(&id);
            if last {
                state.spawn_assembly(id);
            } else {
                state.tile_stored(id, rect);
            }
            false
        }
        Completion::Repeat => true,
        Completion::Stale(why) => return Err(ApiError::conflict(why)),
        Completion::Missing => {
            return Err(ApiError::not_found(format_args!(
                "tile {idx} of job `{id}`"
            )));
        }
        Completion::Unstored(why) => {
            // The tile is back in the queue (claims waiting for work hear of it once the
            // pause is over, or at once if it came back with a failure instead).
            state.work.notify_waiters();
            state.ended.notify_waiters();
            return Err(ApiError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                format!(
                    "the service cannot store tile pixels now ({why}); the tile is queued again"
                ),
            )
            .retry_after(STORAGE_PAUSE.as_secs() as u32));
        }
        Completion::WrongTile(expected) => {
            let e = BlobError::WrongTile {
                expected,
                got: rect,
            };
            return Err(ApiError::new(
                StatusCode::UNPROCESSABLE_ENTITY,
                e.to_string(),
            ));
        }
    };
    let next = match next_for {
        Some(name) => claim_now(&state, name, true).await?,
        None => None,
    };
    Ok(ok_json(Accepted { repeat, next }))
}

/// `POST /worker/jobs/{id}/tiles/{idx}/fail?lease=L`: the worker could not render the tile;
/// it is queued again, or, out of attempts, fails its job (the answer says which).
pub async fn fail(
    State(state): State<AppState>,
    Path((id, idx)): Path<(String, u32)>,
    Query(q): Query<LeaseParam>,
    Json(req): Json<FailRequest>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let worker = worker_name(&req.worker)?;
    let reason: String = req.reason.chars().take(1000).collect();
    let ok = state
        .store
        .fail_tile(
            &id,
            idx,
            &q.lease,
            worker,
            &reason,
            now_ms(),
            state.cfg.max_attempts,
            state.keep_away(),
        )
        .await?;
    if ok {
        metrics::count(metrics::TILES_FAILED, 1);
        state.work.notify_waiters();
        state.changes.job(&id);
        // The tile may have been out of attempts, failing its job: then it is not requeued,
        // and the answer says so.
        state.ended.notify_waiters();
        let job_failed = state
            .store
            .job(&id)
            .await?
            .is_some_and(|j| j.state == JobState::Failed);
        Ok(ok_json(
            serde_json::json!({ "requeued": !job_failed, "job_failed": job_failed }),
        ))
    } else {
        Err(ApiError::conflict("this lease is no longer current"))
    }
}

/// `POST /worker/jobs/{id}/tiles/{idx}/release?lease=L`: the worker gives the tile back
/// unrendered (it is stopping); it is queued again without counting an attempt.
pub async fn release(
    State(state): State<AppState>,
    Path((id, idx)): Path<(String, u32)>,
    Query(q): Query<LeaseParam>,
) -> Result<Json<serde_json::Value>, ApiError> {
    if state.store.release(&id, idx, &q.lease).await? {
        state.work.notify_waiters();
        state.changes.job(&id);
        Ok(ok_json(serde_json::json!({ "requeued": true })))
    } else {
        Err(ApiError::conflict("this lease is no longer current"))
    }
}
