//! A job's events (`GET /jobs/{id}/events`): server-sent events that tell a page or a script
//! what happens to the job as it happens, so that neither polls.
//!
//! **Events.** Each event's data is one JSON object:
//! - `job`: the job as `GET /jobs/{id}` answers it; first, and whenever it changes (state,
//!   progress, priority);
//! - `tiles`: every tile as `GET /jobs/{id}/tiles` answers them; once, after the first `job`;
//! - `tile`: one tile whose state, holder or failures changed (stored: `state` is `done`, with
//!   its rectangle);
//! - `failure`: a tile's failures rose: its index and rectangle, how many failures, the
//!   reason, and the job's state (a failure that ran the tile out of attempts fails the job,
//!   which the next `job` and `end` say);
//! - `end`: the job as it ended (done, failed or cancelled); the stream closes after it;
//! - `deleted`: the job was deleted; the stream closes after it.
//!
//! **How changes are found.** The database is the record, so every event is a difference
//! between two reads of the job and its tiles' states, never a message that could be lost
//! or arrive out of order: a stream re-reads when this process changes the job (the
//! [`crate::changes::Changes`] it is told of by the handlers and the reaper) and, as a safety net and for
//! what other replicas on a shared database change, every [`RECHECK`] (or
//! [`RECHECK_SHARED`]). Reads are at most one per [`MIN_GAP`] per stream, however fast tiles
//! arrive: a burst of results gives one read and the events of all of them.
//!
//! **Ending.** A stream ends with its job, with its deletion, and when the service begins to
//! stop (so that a graceful stop is not held up by open streams); a browser's `EventSource`
//! reconnects by itself and starts again from a fresh `job` and `tiles`.

use std::collections::HashMap;
use std::convert::Infallible;
use std::time::Duration;

use axum::response::sse::{Event, KeepAlive, Sse};
use futures_util::Stream;
use serde_json::{Value, json};
use tokio::sync::broadcast;

use crate::changes::ANY_JOB;

use crate::error::ok_json;
use crate::job_view::JobView;
use crate::state::AppState;
use crate::store::{JobRow, TileView};

/// One server-sent event of a job's stream, as the OpenAPI document describes it (the
/// stream's keep-alive comments are not events).
#[derive(utoipa::ToSchema)]
#[allow(dead_code)]
pub struct JobEvent {
    /// What happened: `job`, `tiles`, `tile`, `failure`, `end` or `deleted`.
    #[schema(pattern = "^(job|tiles|tile|failure|end|deleted)$")]
    event: String,
    /// One JSON object (`tiles`: an array) saying it: the job as `GET /jobs/{id}` answers
    /// it for `job` and `end`, a tile as `GET /jobs/{id}/tiles` lists it for `tile`, all of
    /// them for `tiles`.
    #[schema(content_media_type = "application/json")]
    data: String,
}

/// How often a stream re-reads its job without being told of a change, with one service on
/// its database: a safety net only, since this process tells of its own changes.
pub const RECHECK: Duration = Duration::from_secs(5);
/// The same where other replicas change the job unannounced (a shared database).
pub const RECHECK_SHARED: Duration = Duration::from_secs(1);
/// The least time between two reads of one stream.
pub const MIN_GAP: Duration = Duration::from_millis(100);

/// What a stream last told of its job.
struct Seen {
    job: Value,
    tiles: HashMap<u32, TileView>,
}

/// The events of job `row` (read by the handler, which answers `404` for an unknown job)
/// and its `tiles`.
pub fn stream(
    state: AppState,
    row: JobRow,
    tiles: Vec<TileView>,
) -> Sse<impl Stream<Item = Result<Event, Infallible>>> {
    let keep_alive = (state.cfg.longest_silence() / 2).clamp(MIN_GAP, Duration::from_secs(15));
    let recheck = if state.store.is_shared() {
        RECHECK_SHARED
    } else {
        RECHECK
    };
    let id = row.id.clone();
    let mut changes = state.changes.subscribe();
    let stream = async_stream(move |tx| async move {
        let first = job_json(&state, row.clone());
        let ended = !row.state.is_active();
        if tx.send(event("job", &first)).await.is_err() {
            return;
        }
        if tx.send(event("tiles", &ok_json(&tiles).0)).await.is_err() || ended {
            let _ = tx.send(event("end", &first)).await;
            return;
        }
        let mut seen = Seen {
            job: first,
            tiles: tiles.into_iter().map(|t| (t.idx, t)).collect(),
        };
        let mut last = tokio::time::Instant::now();
        loop {
            tokio::select! {
                news = changes.recv() => match news {
                    Ok(job) if *job != *id && *job != *ANY_JOB => continue,
                    Ok(_) | Err(broadcast::error::RecvError::Lagged(_)) => {}
                    Err(broadcast::error::RecvError::Closed) => return,
                },
                _ = tokio::time::sleep_until(last + recheck) => {}
                _ = state.stopped() => return,
                _ = tx.closed() => return,
            }
            // At most one read per gap: the changes that arrive meanwhile are in it.
            tokio::select! {
                _ = tokio::time::sleep_until(last + MIN_GAP) => {}
                _ = state.stopped() => return,
            }
            last = tokio::time::Instant::now();
            let (row, tiles) = match (state.store.job(&id).await, state.store.tiles(&id).await) {
                (Ok(Some(row)), Ok(Some(tiles))) => (row, tiles),
                (Ok(None), _) | (_, Ok(None)) => {
                    let _ = tx.send(event("deleted", &json!({ "id": id }))).await;
                    return;
                }
                // The database failed: the stream tries again at the next change or recheck.
                (Err(e), _) | (_, Err(e)) => {
                    tracing::debug!(job = %id, "events: {e}");
                    continue;
                }
            };
            let ended = !row.state.is_active();
            let job_state = row.state;
            let job = job_json(&state, row);
            for t in tiles {
                let before = seen.tiles.get(&t.idx);
                if before == Some(&t) {
                    continue;
                }
                let failed = before.is_some_and(|b| t.failures > b.failures);
                if tx.send(event("tile", &ok_json(&t).0)).await.is_err() {
                    return;
                }
                if failed {
                    let failure = json!({
                        "idx": t.idx, "x": t.x, "y": t.y, "w": t.w, "h": t.h,
                        "failures": t.failures, "error": t.error, "job_state": job_state,
                    });
                    if tx.send(event("failure", &failure)).await.is_err() {
                        return;
                    }
                }
                seen.tiles.insert(t.idx, t);
            }
            if job != seen.job {
                if tx.send(event("job", &job)).await.is_err() {
                    return;
                }
                seen.job = job;
            }
            if ended {
                let _ = tx.send(event("end", &seen.job)).await;
                return;
            }
        }
    });
    Sse::new(stream).keep_alive(KeepAlive::new().interval(keep_alive))
}

/// The job as `GET /jobs/{id}` shows it.
fn job_json(state: &AppState, row: JobRow) -> Value {
    ok_json(JobView::of(state, row)).0
}

/// An event named `name` carrying `data` as JSON.
fn event(name: &str, data: &Value) -> Event {
    Event::default().event(name).data(data.to_string())
}

/// A stream fed by the task `f`, which sends events into a small channel: the channel's
/// bound is the stream's backpressure (a client that stops reading stops the task at its
/// next send), and the task ends when the client goes (its sends fail).
fn async_stream<F, Fut>(f: F) -> impl Stream<Item = Result<Event, Infallible>>
where
    F: FnOnce(tokio::sync::mpsc::Sender<Event>) -> Fut,
    Fut: std::future::Future<Output = ()> + Send + 'static,
{
    let (tx, rx) = tokio::sync::mpsc::channel(64);
    tokio::spawn(f(tx));
    futures_util::stream::unfold(
        rx,
        |mut rx| async move { rx.recv().await.map(|e| (Ok(e), rx)) },
    )
}
