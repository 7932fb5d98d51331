//! The user routes: submit a scene, list and inspect jobs, download the image, cancel or
//! delete a job, the web page and the health check.
//!
//! A submitted scene is parsed and built (textures decoded) before anything is stored, so a
//! bad scene is a `400` naming line and column and leaves no trace.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;

use axum::Json;
use axum::body::{Body, Bytes};
use axum::extract::{FromRequest, Multipart, Path, Query, Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{Html, IntoResponse, Response};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};
use tessera_tracer::{MemoryAssets, Sampler, Scene, SceneError, Texture, parse, tile_count, tiles};

use crate::config::auto_tile;
use crate::error::{ApiError, ok_json};
use crate::queue::{Cancel, JobRow, NewJob, STORAGE_PAUSE};
use crate::receiving::{BODY_SILENCE, Full, Held, Receiving};
use crate::{AppState, now_ms};

/// Smallest and largest tile edge a job may ask for.
pub const MIN_TILE: u32 = 8;
pub const MAX_TILE: u32 = 1024;

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
    /// ([`Queue::storage_trouble`](crate::queue::Queue::storage_trouble)), which otherwise
    /// only `/healthz` told. The reason is given in general terms: the failed write's own
    /// message names another job's spool file.
    fn of(state: &AppState, row: JobRow) -> JobView {
        let waiting =
            matches!(row.state.as_str(), "queued" | "running") && row.tiles_done < row.tiles_total;
        let mut view = JobView::from(row);
        if waiting && state.queue.storage_trouble(STORAGE_PAUSE).is_some() {
            view.paused = Some(
                "the service has no room to store tile pixels now (a full disk, or no file \
                 descriptors to spare): tiles are handed out again once it has"
                    .to_string(),
            );
        }
        view
    }
}

/// The web page, told this service's body limit (`--max-body-bytes`) so that it can refuse a
/// scene and textures too large to send before sending them: the service answers `413` from
/// the request's length and closes the connection, which a browser's `fetch` reports as a
/// network error rather than the answer.
pub async fn page(State(state): State<AppState>) -> Html<String> {
    Html(include_str!("page.html").replace(
        "__TESSERA_MAX_BODY_BYTES__",
        &state.cfg.max_body_bytes.to_string(),
    ))
}

/// `200` when the database answers a read and takes a write (a row rewritten within
/// [`HEALTH_WRITE_WITHIN`]), `503` naming what failed otherwise: it was `200` while every
/// submission and result failed on a full disk.
pub async fn healthz(State(state): State<AppState>) -> Result<Json<Value>, ApiError> {
    state.queue.ping().await?;
    if let Some(why) = state.queue.storage_trouble(STORAGE_PAUSE) {
        return Err(ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            format!("the tile spool failed to store a tile's pixels: {why}"),
        ));
    }
    if let Err(e) = state.queue.probe_write(now_ms(), HEALTH_WRITE_WITHIN).await {
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

/// Workers heard from in the last ten minutes.
pub async fn workers(State(state): State<AppState>) -> Json<Value> {
    let cutoff = now_ms() - 600_000;
    let mut list: Vec<_> = state
        .roster
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .values()
        .filter(|w| w.last_seen >= cutoff)
        .cloned()
        .collect();
    list.sort_by(|a, b| a.name.cmp(&b.name));
    ok_json(list)
}

/// `GET /jobs` query parameters: a page of at most `limit` jobs (default and most
/// [`MAX_JOBS_LISTED`]), those submitted before job `before` when given.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ListParams {
    pub limit: Option<u32>,
    pub before: Option<String>,
}

/// The most jobs one `GET /jobs` lists.
pub const MAX_JOBS_LISTED: u32 = 200;

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
    let rows = state.queue.jobs(limit, before).await?.ok_or_else(|| {
        ApiError::not_found(format_args!(
            "job `{}` to list before",
            before.unwrap_or("")
        ))
    })?;
    let jobs: Vec<JobView> = rows.into_iter().map(|r| JobView::of(&state, r)).collect();
    Ok(ok_json(jobs))
}

/// `GET /jobs/{id}?wait=S`: with `wait`, the answer waits until the job has ended (done,
/// failed or cancelled) or `S` seconds (at most [`MAX_JOB_WAIT_SECS`], and less than the
/// idle timeout) have passed, so a
/// client learns of the end at once instead of polling.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JobParams {
    pub wait: Option<f64>,
}

/// The longest `GET /jobs/{id}?wait=` holds a request.
pub const MAX_JOB_WAIT_SECS: f64 = 60.0;

/// How often a waiting request looks again without being woken: only a change made outside
/// this process (the database edited by hand, or a second service on it, which is not
/// supported) goes unannounced.
const JOB_WAIT_RECHECK: Duration = Duration::from_secs(1);

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
            .queue
            .job(&id)
            .await?
            .ok_or_else(|| ApiError::no_job(&id))?;
        let now = tokio::time::Instant::now();
        let stopping = *state.stopping.borrow();
        if !matches!(row.state.as_str(), "queued" | "running") || now >= deadline || stopping {
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

/// `DELETE /jobs/{id}` query parameters.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeleteParams {
    /// Remove an ended job and everything stored for it, instead of cancelling: `true` or
    /// `1` (`false`, `0` or absent: cancel).
    #[serde(default, deserialize_with = "flag")]
    pub purge: bool,
}

/// A query flag: `true`/`1` or `false`/`0`.
pub(crate) fn flag<'de, D: serde::Deserializer<'de>>(d: D) -> Result<bool, D::Error> {
    match String::deserialize(d)?.as_str() {
        "true" | "1" => Ok(true),
        "false" | "0" => Ok(false),
        other => Err(serde::de::Error::custom(format!(
            "`{other}` is not a flag: expected true, false, 1 or 0"
        ))),
    }
}

/// `DELETE /jobs/{id}` cancels a queued or running job (`200` with the job). It is
/// idempotent, as HTTP clients (which retry a `DELETE`) and double clicks expect: a job that
/// has already ended is answered as it is, and one whose every tile is in (its image being
/// written) is not cancelled (`409`). `?purge=true` removes an ended job with its image
/// (`204`); an active one must be cancelled first (`409`). Until both were one request, a
/// repeated cancel deleted the job it had just cancelled, and a cancel that reached a job
/// just finished deleted its image.
pub async fn delete_job(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Query(params): Query<DeleteParams>,
) -> Result<Response, ApiError> {
    let view = |row: Option<JobRow>| row.map(JobView::from).ok_or_else(|| ApiError::no_job(&id));
    if params.purge {
        let job = view(state.queue.job(&id).await?)?;
        if matches!(job.row.state.as_str(), "queued" | "running") {
            return Err(ApiError::conflict(format!(
                "job `{id}` is {}: cancel it first (DELETE /jobs/{id}), then purge it",
                job.row.state
            ))
            .with("state", job.row.state.clone()));
        }
        state.queue.delete(&id).await?;
        state.ended.notify_waiters();
        return Ok(StatusCode::NO_CONTENT.into_response());
    }
    let outcome = state.queue.cancel(&id, now_ms()).await?;
    // Waiting requests look again now.
    state.ended.notify_waiters();
    if outcome == Cancel::Unknown {
        return Err(ApiError::no_job(&id));
    }
    let job = view(state.queue.job(&id).await?)?;
    if outcome == Cancel::Complete && job.row.state == "running" {
        return Err(ApiError::conflict(format!(
            "every tile of job `{id}` is in and its image is being written: it is not cancelled"
        ))
        .with("state", job.row.state.clone()));
    }
    Ok(ok_json(job).into_response())
}

/// Query parameters of a route that takes none: one given is a mistake, refused as on the
/// routes that take some (`?x=1` on the image was answered as if absent).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoParams {}

/// The finished PNG, streamed from the database chunk by chunk.
pub async fn image(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Query(NoParams {}): Query<NoParams>,
) -> Result<Response, ApiError> {
    let row = state
        .queue
        .job(&id)
        .await?
        .ok_or_else(|| ApiError::no_job(&id))?;
    if row.state != "done" {
        let why = match row.state.as_str() {
            "failed" => format!("job failed: {}", row.error.clone().unwrap_or_default()),
            "cancelled" => "job was cancelled; it has no image".to_string(),
            _ => format!(
                "job is {}: {} of {} tiles done",
                row.state, row.tiles_done, row.tiles_total
            ),
        };
        return Err(ApiError::conflict(why)
            .with("state", row.state.clone())
            .with("tiles_done", row.tiles_done)
            .with("tiles_total", row.tiles_total));
    }
    let chunks = state.queue.image_chunks(&id).await?;
    let queue = state.queue.clone();
    let stream = futures_util::stream::unfold(0u32, move |seq| {
        let queue = queue.clone();
        let id = id.clone();
        async move {
            if seq >= chunks {
                return None;
            }
            let item = match queue.image_chunk(&id, seq).await {
                Ok(Some(bytes)) => Ok(Bytes::from(bytes)),
                Ok(None) => Err(std::io::Error::other("image chunk missing")),
                Err(e) => Err(std::io::Error::other(e.to_string())),
            };
            Some((item, seq + 1))
        }
    });
    let mut headers = HeaderMap::new();
    headers.insert(header::CONTENT_TYPE, HeaderValue::from_static("image/png"));
    // A done job's image never changes (ids are never reused), so a browser keeps it: the
    // web page, which redraws its list every second, does not fetch every thumbnail again.
    // `private`: a deleted job's image must not live on in a shared cache.
    headers.insert(
        header::CACHE_CONTROL,
        HeaderValue::from_static("private, max-age=31536000, immutable"),
    );
    if let Some(n) = row.png_bytes {
        headers.insert(header::CONTENT_LENGTH, HeaderValue::from(n));
    }
    if let Ok(v) = HeaderValue::from_str(&content_disposition(row.name.as_deref(), &row.id)) {
        headers.insert(header::CONTENT_DISPOSITION, v);
    }
    Ok((headers, Body::from_stream(stream)).into_response())
}

/// The download's `Content-Disposition`: the job's name (its last `/` segment, `.ray`
/// dropped) as a `.png` file name. `filename` holds its ASCII letters, digits, `-`, `_` and
/// `.` (the job id when that leaves no name); when that is not the whole name, `filename*`
/// (RFC 6266, RFC 8187) carries all of it, UTF-8 percent-encoded, for clients that read it.
fn content_disposition(name: Option<&str>, id: &str) -> String {
    let file = name.and_then(|n| n.rsplit('/').next()).unwrap_or(id);
    let stem = file.strip_suffix(".ray").unwrap_or(file);
    let plain = |c: char| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.');
    let safe: String = stem.chars().filter(|&c| plain(c)).collect();
    let fallback = if safe.chars().all(|c| c == '.') {
        id
    } else {
        &safe
    };
    let mut header = format!("inline; filename=\"{fallback}.png\"");
    if !stem.chars().all(plain) && !stem.trim().is_empty() {
        // RFC 8187 `attr-char`s stand for themselves; every other byte is `%XX`.
        let attr = |b: u8| b.is_ascii_alphanumeric() || b"!#$&+-.^_`|~".contains(&b);
        let mut encoded = String::new();
        for b in stem.bytes() {
            if attr(b) {
                encoded.push(char::from(b));
            } else {
                encoded.push_str(&format!("%{b:02X}"));
            }
        }
        header.push_str(&format!("; filename*=UTF-8''{encoded}.png"));
    }
    header
}

/// `POST /jobs` query parameters. Any other is refused: a misspelt `?tiles=8` or `?sample=4`
/// rendered with the defaults, unlike a misspelt key in a scene.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SubmitParams {
    pub tile: Option<u32>,
    pub sampler: Option<String>,
    pub samples: Option<u32>,
    pub threshold: Option<f64>,
    /// A name for the job (the scene file's name, shown in lists and used for the download).
    pub name: Option<String>,
    /// Claims serve the highest priority first ([`MIN_PRIORITY`] to [`MAX_PRIORITY`],
    /// default 0), and jobs of one priority in the order they came.
    pub priority: Option<i64>,
}

/// The lowest `?priority=`.
pub const MIN_PRIORITY: i64 = -1000;
/// The highest `?priority=`.
pub const MAX_PRIORITY: i64 = 1000;

/// The answer to a submission's query that does not parse: serde's reason, and what the
/// parameter it names takes (`?tile=abc` said only "invalid digit found in string").
fn bad_query(reason: &str) -> String {
    let field = reason
        .strip_prefix("Failed to deserialize query string: ")
        .and_then(|r| r.split_once(':'))
        .map(|(f, _)| f);
    let takes = match field {
        Some("tile") => format!("; `tile` is a whole number of pixels, {MIN_TILE} to {MAX_TILE}"),
        Some("samples") => "; `samples` is a positive whole number".to_string(),
        Some("threshold") => "; `threshold` is a number".to_string(),
        Some("priority") => {
            format!("; `priority` is a whole number, {MIN_PRIORITY} to {MAX_PRIORITY}")
        }
        _ => String::new(),
    };
    format!("bad query: {reason}{takes}")
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
    let req = metered(req, &state, held.clone());
    // Media types are case-insensitive (RFC 9110): `Multipart/Form-Data` was read as a
    // raw scene.
    let is_multipart = req
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| {
            v.get(..19)
                .is_some_and(|m| m.eq_ignore_ascii_case("multipart/form-data"))
        });
    let read = if is_multipart {
        read_multipart(req, &state).await
    } else {
        Bytes::from_request(req, &state)
            .await
            .map(|body| (Vec::from(body), None, Vec::new()))
            .map_err(|e| ApiError::new(e.status(), e.body_text()))
    };
    let (scene_bytes, file_name, uploads) = match read {
        Ok(read) => read,
        Err(e) => {
            let held = held.lock().await;
            return Err(if held.refused() {
                busy(&state)
            } else if held.stalled() {
                stalled(&state)
            } else {
                e
            });
        }
    };
    let source = tessera_tracer::scene_text(scene_bytes).map_err(|e| scene_error(&e))?;
    if source.trim().is_empty() {
        return Err(ApiError::bad_request(if is_multipart {
            "the `scene` part is empty: attach the scene file (curl -F scene=@scene.ray)"
        } else {
            "empty body: send the scene file (curl --data-binary @scene.ray)"
        }));
    }
    // `curl -d @scene.ray` sends the file without its line breaks, and a scene that starts
    // with a comment becomes one comment line: it rendered a black image without a word.
    if !is_multipart
        && !source.contains('\n')
        && source
            .trim_start_matches('\u{feff}')
            .trim_start()
            .starts_with('#')
    {
        return Err(ApiError::bad_request(
            "the body is one comment line, with no line breaks: `curl -d` drops a file's line \
             breaks; send the scene file with curl --data-binary @scene.ray",
        ));
    }
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
        .or(file_name);
    if let Some(n) = &name {
        check_job_name(n)?;
    }
    let job = validate(&state, source, uploads, &params, tile, name, &held).await?;
    let (new_job, rects, assets) = job;
    // Followed before it is stored, so that no stored tile goes uncounted.
    state
        .progress
        .follow(&new_job.id, new_job.width, new_job.height, &rects);
    let row = match state.queue.insert_job(&new_job, &rects, &assets).await {
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

/// The request with its body counted into the submission's share of the budget (see
/// `receiving`): its declared length (the body limit if it declares none) before the first
/// byte is read, all or nothing, held until the submission is answered. A share that gets
/// no room in time (or none while the service stops) ends the body with [`Full`], which
/// [`submit`] answers `503`; a body silent for [`BODY_SILENCE`] (or a second under the
/// idle timeout) ends with [`Stalled`], answered `408`.
fn metered(req: Request, state: &AppState, held: Arc<tokio::sync::Mutex<Held>>) -> Request {
    use futures_util::StreamExt;
    let limit = state.cfg.max_body_bytes as u64;
    let want = crate::error::declared_length(req.headers()).map_or(limit, |n| n.min(limit));
    let within = Receiving::wait_limit(state.cfg.longest_silence());
    let silence = BODY_SILENCE.min(state.cfg.longest_silence());
    let (parts, body) = req.into_parts();
    struct Meter {
        body: axum::body::BodyDataStream,
        held: Arc<tokio::sync::Mutex<Held>>,
        state: AppState,
        /// Whether the share holds the body's room yet (taken at the first read).
        holding: bool,
    }
    let meter = Meter {
        body: body.into_data_stream(),
        held,
        state: state.clone(),
        holding: false,
    };
    let chunks = futures_util::stream::unfold(Some(meter), move |meter| async move {
        let mut m = meter?;
        if !m.holding {
            let mut held = m.held.lock().await;
            // Biased: a share that finds room goes on though the service is stopping (a
            // random pick cut half the uploads under way with a 503).
            let room = tokio::select! {
                biased;
                room = held.grow(want, within) => room,
                () = m.state.stopped() => {
                    held.refuse();
                    Err(Full)
                }
            };
            drop(held);
            if let Err(e) = room {
                return Some((Err(axum::Error::new(e)), None));
            }
            m.holding = true;
        }
        match tokio::time::timeout(silence, m.body.next()).await {
            Ok(Some(Ok(chunk))) => Some((Ok(chunk), Some(m))),
            Ok(Some(Err(e))) => Some((Err(e), None)),
            Ok(None) => None,
            Err(_) => {
                m.held.lock().await.stall();
                Some((Err(axum::Error::new(Stalled)), None))
            }
        }
    });
    Request::from_parts(parts, Body::from_stream(chunks))
}

/// A body that stopped arriving for [`BODY_SILENCE`].
#[derive(Debug, thiserror::Error)]
#[error("the body stopped arriving")]
struct Stalled;

/// The `408` of a submission whose body stopped arriving.
fn stalled(state: &AppState) -> ApiError {
    let secs = BODY_SILENCE.min(state.cfg.longest_silence()).as_secs();
    ApiError::new(
        StatusCode::REQUEST_TIMEOUT,
        format!(
            "the body stopped arriving for {secs} s; send it again (its room in \
             --max-receiving-bytes is given to others meanwhile)"
        ),
    )
}

/// The `503` of a submission whose textures found no room to be decoded in time
/// (`--max-scene-texture-pixels` at once), or none while the service stops.
fn busy_decoding(state: &AppState) -> ApiError {
    try_again_shortly(
        "the service is decoding as many textures as it takes at once \
         (--max-scene-texture-pixels); try again shortly",
    )
    .with(
        "max_scene_texture_pixels",
        state.cfg.max_scene_texture_pixels,
    )
}

/// The `503` of a submission that found no room in `--max-receiving-bytes` in time (or
/// none while the service stops).
fn busy(state: &AppState) -> ApiError {
    try_again_shortly(
        "the service is receiving and checking as many scenes as it takes at once \
         (--max-receiving-bytes); try again shortly",
    )
    .with("receiving_bytes", state.cfg.receiving_bytes())
}

/// A `503` that a client may simply repeat a few seconds later.
fn try_again_shortly(message: &str) -> ApiError {
    ApiError::new(StatusCode::SERVICE_UNAVAILABLE, message).retry_after(5)
}

type Uploads = Vec<(String, Vec<u8>)>;

async fn read_multipart(
    req: Request,
    state: &AppState,
) -> Result<(Vec<u8>, Option<String>, Uploads), ApiError> {
    let mut mp = Multipart::from_request(req, state)
        .await
        .map_err(|e| ApiError::new(e.status(), e.body_text()))?;
    let mut scene = None;
    let mut file_name = None;
    let mut uploads = Vec::new();
    let mut seen = HashMap::new();
    while let Some(field) = mp
        .next_field()
        .await
        .map_err(|e| ApiError::new(e.status(), e.body_text()))?
    {
        // Some clients (reqwest among them) percent-encode part names: `textures%2Fglobe.png`.
        let field_name = percent_decode(field.name().unwrap_or_default());
        let fname = field.file_name().map(str::to_string);
        let bytes = field
            .bytes()
            .await
            .map_err(|e| ApiError::new(e.status(), e.body_text()))?;
        if field_name == "scene" {
            if scene.is_some() {
                return Err(ApiError::bad_request(
                    "the `scene` part was sent twice: send one scene per job",
                ));
            }
            scene = Some(Vec::from(bytes));
            file_name = fname;
            continue;
        }
        // An asset is named by its part's name, as the scene names it; a part with no
        // name (or the generic `asset`) goes by its file name.
        let name = if field_name.is_empty() || field_name == "asset" {
            match fname.filter(|f| !f.is_empty()) {
                Some(f) => f,
                None => {
                    return Err(ApiError::bad_request(format!(
                        "the part `{field_name}` has no file name to name the asset by: send \
                         the file (curl -F asset=@globe.png) or name the part as the scene \
                         names the texture (-F globe.png=<globe.png)"
                    )));
                }
            }
        } else {
            field_name
        };
        check_asset_name(&name)?;
        if seen.insert(name.clone(), ()).is_some() {
            return Err(ApiError::bad_request(format!(
                "asset `{name}` was sent twice: for two textures of one file name in different \
                 folders, name each part by the scene's whole texture name \
                 (curl -F 'asset=@a/{name};filename=a/{name}' -F 'asset=@b/{name};filename=b/{name}')"
            )));
        }
        uploads.push((name, Vec::from(bytes)));
    }
    let scene = scene.ok_or_else(|| {
        ApiError::bad_request("multipart body has no `scene` part (curl -F scene=@file.ray)")
    })?;
    Ok((scene, file_name, uploads))
}

/// Decodes `%XX` escapes; anything malformed is kept as written.
fn percent_decode(s: &str) -> String {
    String::from_utf8(percent_decode_bytes(s)).unwrap_or_else(|_| s.to_string())
}

/// The first query parameter whose value, percent-decoded, is not UTF-8. The query parser
/// turns such bytes into U+FFFD without a word: `name=%ff` was stored as "�".
fn non_utf8_param(query: &str) -> Option<&str> {
    query.split('&').find_map(|pair| {
        let (key, value) = pair.split_once('=').unwrap_or((pair, ""));
        std::str::from_utf8(&percent_decode_bytes(value))
            .is_err()
            .then_some(key)
    })
}

/// The bytes `%XX` escapes stand for; anything malformed is kept as written.
fn percent_decode_bytes(s: &str) -> Vec<u8> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let hex = |c: u8| (c as char).to_digit(16);
        if b[i] == b'%'
            && i + 2 < b.len()
            && let (Some(h), Some(l)) = (hex(b[i + 1]), hex(b[i + 2]))
        {
            out.push((h * 16 + l) as u8);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    out
}

/// Longest job or asset name, in bytes (a file name's usual limit: a job's name becomes the
/// download's file name).
pub const MAX_NAME: usize = 255;

/// A job's name (`name=`, or the uploaded scene's file name) is shown in every job list and
/// page: at most [`MAX_NAME`] bytes and no control characters.
pub fn check_job_name(name: &str) -> Result<(), ApiError> {
    if name.len() > MAX_NAME {
        return Err(ApiError::bad_request(format!(
            "the job name is {} bytes long; at most {MAX_NAME} are allowed",
            name.len()
        )));
    }
    if name.chars().any(char::is_control) {
        return Err(ApiError::bad_request(
            "the job name may not hold control characters (line breaks, tabs …)",
        ));
    }
    Ok(())
}

/// Asset names are names, not paths: relative, `/`-separated, no `.` or `..` segments, no
/// backslashes or control characters. Nothing ever resolves them on a file system anyway.
pub fn check_asset_name(name: &str) -> Result<(), ApiError> {
    let bad = name.is_empty()
        || name.len() > MAX_NAME
        || name.starts_with('/')
        || name.contains('\\')
        || name.chars().any(char::is_control)
        || name
            .split('/')
            .any(|seg| seg.is_empty() || seg == "." || seg == "..");
    if bad {
        return Err(ApiError::bad_request(format!(
            "`{name}` is not a valid asset name: use the relative file name the scene uses, \
             without `..` or a leading `/`"
        )));
    }
    Ok(())
}

/// A scene's texture name as the upload it stands for: `/`-separated, resolved by
/// `tessera-render`'s own rule ([`tessera_tracer::lexical_texture_path`]: `./globe.png` and
/// `maps/../globe.png` are `globe.png`). `None` for a name that leaves the scene's folder
/// or is no relative name (a leading `/`, a `\`, control characters).
fn texture_key(name: &str) -> Option<String> {
    if name.starts_with('/') || name.contains('\\') || name.chars().any(char::is_control) {
        return None;
    }
    let resolved = tessera_tracer::lexical_texture_path(name);
    let parts: Option<Vec<&str>> = resolved
        .components()
        .map(|c| match c {
            std::path::Component::Normal(s) => s.to_str(),
            _ => None,
        })
        .collect();
    parts.filter(|p| !p.is_empty()).map(|p| p.join("/"))
}

fn scene_error(e: &SceneError) -> ApiError {
    let first = e.first();
    let all: Vec<Value> = e
        .diagnostics()
        .iter()
        .map(|d| json!({ "line": d.pos.line, "column": d.pos.column, "message": d.message }))
        .collect();
    ApiError::bad_request(format!(
        "{}:{}: {}",
        first.pos.line, first.pos.column, first.message
    ))
    .with("line", first.pos.line)
    .with("column", first.pos.column)
    .with("errors", Value::Array(all))
}

/// Primary rays per pixel as the automatic tile size counts a job's cost: what a fixed
/// pattern traces, and for the adaptive sampler its first pass of four (a pixel that the
/// scene's geometry shows smooth ends after one ray; one at an edge takes more).
fn tile_rays_per_pixel(sampler: &Sampler) -> u32 {
    match sampler {
        Sampler::Adaptive { .. } => 4,
        other => other.max_samples_per_pixel(),
    }
}

/// Parses and builds the scene off the async threads; on success returns what to store.
/// `tile` is the job's or `--tile`'s; without either the size follows [`auto_tile`].
async fn validate(
    state: &AppState,
    source: String,
    uploads: Uploads,
    params: &SubmitParams,
    tile: Option<u32>,
    name: Option<String>,
    held: &tokio::sync::Mutex<Held>,
) -> Result<(NewJob, Vec<tessera_tracer::Rect>, Uploads), ApiError> {
    let limits = state.cfg.scene_limits();
    let texture_limits = state.cfg.texture_limits();
    let sampler = params.sampler.clone();
    let samples = params.samples;
    let threshold = params.threshold;
    let panicked = |e: tokio::task::JoinError| {
        tracing::error!("scene validation panicked: {e}");
        ApiError::bad_request("the scene could not be checked (the validator failed)")
    };
    let matched = tokio::task::spawn_blocking(move || {
        let desc = parse(&source, &limits).map_err(|e| scene_error(&e))?;
        let chosen = desc
            .sampler
            .with_overrides(sampler.as_deref(), samples, threshold, limits.max_samples)
            .map_err(ApiError::bad_request)?;
        // Each texture the scene names gets the upload of that name or, failing that, of its
        // name with `.` and `..` resolved (`./globe.png`), or the one upload whose name is its
        // file name (`textures/globe.png` ← `globe.png`: many clients send only file names).
        let mut kept: Uploads = Vec::new();
        for (n, pos) in desc.texture_names() {
            let Some(key) = texture_key(n) else {
                let message = format!(
                    "texture `{n}` must name a file beside the scene or below it: no leading \
                     `/`, no `..` above the scene's folder, no `\\`"
                );
                return Err(scene_error(&SceneError::single(pos, message)));
            };
            let base = key.rsplit('/').next().unwrap_or(&key);
            let found = uploads
                .iter()
                .find(|(u, _)| u == n || *u == key)
                .or_else(|| uploads.iter().find(|(u, _)| u == base));
            if let Some((_, bytes)) = found {
                kept.push((n.to_string(), bytes.clone()));
            }
        }
        // What the textures decode to, from their headers (a bad header is the check's to
        // report, below).
        let texels: u64 = kept
            .iter()
            .filter_map(|(n, bytes)| Texture::dimensions(n, bytes, &texture_limits).ok())
            .map(|(w, h)| u64::from(w) * u64::from(h))
            .sum();
        Ok::<_, ApiError>((source, desc, chosen, kept, texels, texture_limits))
    })
    .await
    .map_err(panicked)??;
    let (source, desc, chosen, kept, texels, texture_limits) = matched;
    // Room for the textures before they are decoded (see `receiving`); none for textures
    // past the job's own limit, which the check refuses from their headers (they waited for
    // every texel there is, ahead of everyone, to be answered 400).
    if texels <= state.cfg.max_scene_texture_pixels {
        let within = Receiving::wait_limit(state.cfg.longest_silence());
        let mut held = held.lock().await;
        let grown = tokio::select! {
            biased;
            room = held.grow_texels(texels, within) => room,
            () = state.stopped() => Err(Full),
        };
        if grown.is_err() {
            return Err(busy_decoding(state));
        }
    }
    let checked = tokio::task::spawn_blocking(move || {
        let mut assets = MemoryAssets::new();
        for (n, bytes) in &kept {
            assets.insert(n.clone(), bytes.clone());
        }
        Scene::check(&desc, &assets, &texture_limits).map_err(|e| {
            let missing: Vec<&str> = desc
                .texture_names()
                .iter()
                .map(|(n, _)| *n)
                .filter(|n| !assets.contains(n))
                .collect();
            let err = scene_error(&e);
            if missing.is_empty() {
                err
            } else {
                err.with("missing_assets", missing)
            }
        })?;
        let rays = tile_rays_per_pixel(&chosen);
        Ok::<_, ApiError>((source, desc.width, desc.height, kept, rays))
    })
    .await
    .map_err(panicked)?;
    // The decoded textures are gone: their room is another submission's while this one is
    // stored.
    held.lock().await.release_texels();
    let checked = checked?;
    let (source, width, height, kept, rays) = checked;
    // The service's own pick grows to the smallest edge that `--max-tiles` allows (a job
    // that asked for no size was refused for the service's choice), and where none does,
    // the refusal below counts the largest edge's tiles; an edge the job or `--tile` asked
    // for is refused below instead, naming the smallest that fits.
    let tile = tile.unwrap_or_else(|| {
        let auto = auto_tile(width, height, rays);
        smallest_fitting_tile(width, height, auto, state.cfg.max_tiles).unwrap_or(MAX_TILE)
    });
    check_tile_count(width, height, tile, state.cfg.max_tiles)?;
    let job = NewJob {
        id: uuid::Uuid::new_v4().simple().to_string()[..16].to_string(),
        scene: source,
        name,
        width,
        height,
        tile,
        sampler: params.sampler.clone(),
        samples: params.samples,
        threshold: params.threshold,
        created_at: now_ms(),
        priority: params.priority.unwrap_or(0),
    };
    let rects = tiles(width, height, tile);
    Ok((job, rects, kept))
}

/// The smallest tile edge from `from` up to [`MAX_TILE`] that cuts a `width × height` image
/// into at most `max_tiles` tiles, if any does. The count only falls as the edge grows, so
/// the first edge that fits is the smallest.
fn smallest_fitting_tile(width: u32, height: u32, from: u32, max_tiles: u64) -> Option<u32> {
    (from..=MAX_TILE).find(|&e| tile_count(width, height, e) <= max_tiles)
}

/// Refuses a job of more than `max_tiles` tiles (`--max-tiles`), naming the smallest tile
/// edge that would do, if any does.
fn check_tile_count(width: u32, height: u32, tile: u32, max_tiles: u64) -> Result<(), ApiError> {
    let count = tile_count(width, height, tile);
    if count <= max_tiles {
        return Ok(());
    }
    let fits = smallest_fitting_tile(width, height, tile, max_tiles);
    let hint = match fits {
        Some(edge) => format!("; ask for tile={edge} or more"),
        None => format!("; no tile edge up to {MAX_TILE} makes so few"),
    };
    let err = ApiError::bad_request(format!(
        "tiles of {tile} px make {count} tiles of this {width}×{height} image; a job may have \
         at most {max_tiles} (--max-tiles){hint}"
    ))
    .with("tiles", count)
    .with("max_tiles", max_tiles);
    Err(match fits {
        Some(edge) => err.with("min_tile", edge),
        None => err,
    })
}

#[cfg(test)]
mod tests {
    use super::{
        MAX_TILE, MIN_TILE, SubmitParams, bad_query, check_asset_name, check_tile_count,
        percent_decode, texture_key,
    };

    /// A parameter that does not parse is named with what it takes, from serde's own
    /// rejection of it; a query that fails for another reason keeps serde's words alone.
    #[test]
    fn a_bad_query_says_what_the_parameter_takes() {
        let reason = |q: &str| {
            let uri: axum::http::Uri = format!("/jobs?{q}").parse().expect("a valid URI");
            match axum::extract::Query::<SubmitParams>::try_from_uri(&uri) {
                Ok(_) => panic!("`{q}` parsed"),
                Err(e) => bad_query(&e.body_text()),
            }
        };
        for (q, takes) in [
            ("tile=abc", "`tile` is a whole number of pixels, 8 to 1024"),
            ("tile=-1", "`tile` is a whole number of pixels, 8 to 1024"),
            ("samples=-1", "`samples` is a positive whole number"),
            ("threshold=x", "`threshold` is a number"),
            (
                "priority=1.5",
                "`priority` is a whole number, -1000 to 1000",
            ),
        ] {
            let m = reason(q);
            assert!(
                m.starts_with("bad query: ") && m.ends_with(takes),
                "{q}: {m}"
            );
        }
        let m = reason("tlie=8");
        assert!(
            m.contains("unknown field") && !m.contains("whole number"),
            "{m}"
        );
    }

    /// Over many sizes and caps: a job is refused exactly when the tiler would make more
    /// tiles than the cap (counted by the tiler itself), and the edge it suggests is the
    /// smallest that the tiler keeps under the cap.
    #[test]
    fn jobs_of_too_many_tiles_are_refused_with_the_smallest_edge_that_fits() {
        let count = |w: u32, h: u32, e: u32| tessera_tracer::tiles(w, h, e).len() as u64;
        for (w, h) in [(1, 1), (100, 100), (333, 7), (1920, 1080), (7680, 4320)] {
            for max in [1, 2, 10, 169, 1000, 65_536] {
                for tile in [MIN_TILE, 9, 31, 256, MAX_TILE] {
                    let n = count(w, h, tile);
                    match check_tile_count(w, h, tile, max) {
                        Ok(()) => assert!(n <= max, "{w}×{h} tile {tile} max {max}"),
                        Err(e) => {
                            assert!(n > max, "{w}×{h} tile {tile} max {max}");
                            assert_eq!(e.status, 400);
                            assert_eq!(e.body["tiles"], n);
                            match e.body.get("min_tile").and_then(|v| v.as_u64()) {
                                Some(m) => {
                                    let m = m as u32;
                                    assert!(m > tile && m <= MAX_TILE && count(w, h, m) <= max);
                                    assert!(count(w, h, m - 1) > max, "{w}×{h} max {max}: {m}");
                                    let msg = e.body.get("error").and_then(|v| v.as_str());
                                    let msg = msg.unwrap_or_default();
                                    assert!(msg.contains(&format!("tile={m}")), "{msg}");
                                }
                                None => assert!(count(w, h, MAX_TILE) > max),
                            }
                        }
                    }
                }
            }
        }
    }

    /// The header's plain `filename` is always a safe ASCII name, and `filename*` (when
    /// present) decodes back to the whole name: checked with the module's own decoder.
    #[test]
    fn download_names_keep_what_they_can_and_carry_the_rest_encoded() {
        let id = "0123456789abcdef";
        let parts = |h: &str| -> (String, Option<String>) {
            let plain = h
                .split("filename=\"")
                .nth(1)
                .and_then(|r| r.split('"').next())
                .unwrap_or_default()
                .to_string();
            let star = h
                .split("filename*=UTF-8''")
                .nth(1)
                .map(|e| percent_decode(e.split(';').next().unwrap_or_default()));
            (plain, star)
        };
        for (name, plain, star) in [
            (Some("scene.ray"), "scene.png", None),
            (Some("dir/sub/thesis.ray"), "thesis.png", None),
            (None, "0123456789abcdef.png", None),
            (Some("😀.ray"), "0123456789abcdef.png", Some("😀.png")),
            (Some("a b&c\"d;.ray"), "abcd.png", Some("a b&c\"d;.png")),
            (Some("Straße 1"), "Strae1.png", Some("Straße 1.png")),
            (Some(".."), "0123456789abcdef.png", None),
        ] {
            let h = super::content_disposition(name, id);
            assert!(h.is_ascii() && !h.contains('\n'), "{h}");
            let (p, s) = parts(&h);
            assert_eq!(p, plain, "{name:?}: {h}");
            assert_eq!(s.as_deref(), star, "{name:?}: {h}");
        }
    }

    #[test]
    fn part_names_are_percent_decoded() {
        assert_eq!(percent_decode("textures%2Fglobe.png"), "textures/globe.png");
        assert_eq!(percent_decode("a%2"), "a%2");
        assert_eq!(percent_decode("100%"), "100%");
        assert_eq!(percent_decode("plain.ppm"), "plain.ppm");
    }

    #[test]
    fn asset_names_cannot_be_paths_out() {
        for bad in [
            "",
            "/etc/passwd",
            "../x.png",
            "a/../../b",
            "a\\b",
            "./a",
            "a//b",
            "x\u{0}",
        ] {
            assert!(check_asset_name(bad).is_err(), "{bad:?}");
        }
        for good in ["globe.png", "textures/globe.png", "a b.ppm"] {
            assert!(check_asset_name(good).is_ok(), "{good:?}");
        }
    }

    #[test]
    fn texture_names_resolve_like_paths_beside_the_scene() {
        for (name, key) in [
            ("globe.png", "globe.png"),
            ("./globe.png", "globe.png"),
            ("maps/../globe.png", "globe.png"),
            ("maps//./globe.png", "maps/globe.png"),
            ("a/b/../../c/d.png", "c/d.png"),
        ] {
            assert_eq!(texture_key(name).as_deref(), Some(key), "{name:?}");
        }
        for bad in [
            "",
            ".",
            "/etc/passwd",
            "../x.png",
            "a/../../b",
            "a\\b",
            "x\u{0}",
            "a/..",
        ] {
            assert_eq!(texture_key(bad), None, "{bad:?}");
        }
    }
}
