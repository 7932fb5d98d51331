//! The Tessera render service: the HTTP API users and workers talk to, the job store
//! behind it (SQLite), the web page, and optional in-process workers.
//!
//! Handlers are thin: they check what was sent and call the [`store::Store`], which holds
//! every guarantee about tiles and leases in SQL. Shared state is explicit ([`AppState`]);
//! errors become responses in one place ([`error::ApiError`]). The service does not trace
//! rays itself: local workers are ordinary `tessera_worker` loops speaking HTTP to it.

pub mod api;
pub mod assemble;
pub mod auth;
pub mod cli;
pub mod config;
pub mod db_lock;
pub mod error;
pub mod idle;
pub mod receiving;
pub mod rlimit;
pub mod store;
pub mod worker_api;

use std::future::{Future, IntoFuture};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::extract::DefaultBodyLimit;
use axum::routing::{get, post, put};
use tokio::net::TcpListener;
use tokio::sync::watch;
use tracing::{error, info, warn};

pub use config::Config;
use store::{KeepAway, Store, StoreError};

/// Milliseconds since the Unix epoch: the service's clock, which it passes to the store.
pub fn now_ms() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as i64)
}

/// The state every handler shares.
#[derive(Clone)]
pub struct AppState {
    pub cfg: Arc<Config>,
    pub store: Store,
    /// Woken whenever tiles become claimable, so that waiting claims answer at once.
    pub work: Arc<tokio::sync::Notify>,
    /// Woken whenever a job may have ended (done, failed, cancelled), so that
    /// `GET /jobs/{id}?wait=` answers at once.
    pub ended: Arc<tokio::sync::Notify>,
    /// The PNGs being encoded while their jobs render.
    pub progress: Arc<assemble::Progress>,
    /// The body bytes of submissions being received at once (`--max-receiving-bytes`).
    pub receiving: receiving::Receiving,
    /// Turns `true` when the service begins to stop: requests that wait (a claim waiting
    /// for work, `GET /jobs/{id}?wait=`) answer at once, since a graceful stop waits for
    /// every open request.
    pub stopping: watch::Receiver<bool>,
}

impl AppState {
    /// Completes when the service begins to stop (at once if it has).
    pub async fn stopped(&self) {
        let mut stopping = self.stopping.clone();
        // An error means the sender is gone, which only happens as the service ends.
        let _ = stopping.wait_for(|s| *s).await;
    }

    pub fn keep_away(&self) -> KeepAway {
        KeepAway {
            after: self.cfg.keep_away_after,
            for_ms: (self.cfg.keep_away_secs as i64).saturating_mul(1000),
            stall_ms: i64::try_from(self.cfg.lease_ms / 2).unwrap_or(i64::MAX),
        }
    }

    /// A tile of `job` other than its last is stored: encodes, in the background, the bands
    /// of the image that this completed.
    pub fn tile_stored(&self, job: String, tile: tessera_tracer::Rect) {
        if self.progress.stored(&job, tile) {
            let store = self.store.clone();
            let progress = self.progress.clone();
            let (work, ended) = (self.work.clone(), self.ended.clone());
            tokio::spawn(async move {
                if progress.advance(&store, &job).await {
                    // Tiles to render again; or, lost too often, the job failed.
                    work.notify_waiters();
                    ended.notify_waiters();
                }
            });
        }
    }

    /// Assembles a job's PNG in the background once its last tile is in.
    pub fn spawn_assembly(&self, job: String) {
        let store = self.store.clone();
        let ended = self.ended.clone();
        let progress = self.progress.clone();
        let work = self.work.clone();
        tokio::spawn(async move {
            if let Err(e) = progress.complete(&store, &job).await {
                if e.requeued() {
                    // Not a failure of the assembly: the lost tiles are queued again, and
                    // their last result assembles the image anew (unless, lost too often,
                    // they failed the job, which `ended` tells its waiters).
                    warn!(job = %job, "assembling the image: {e}");
                    work.notify_waiters();
                    ended.notify_waiters();
                    return;
                }
                error!(job = %job, "assembling the image failed: {e}");
                let _ = store
                    .fail_job(&job, &format!("assembling the image failed: {e}"), now_ms())
                    .await;
            }
            ended.notify_waiters();
        });
    }
}

/// Why the service could not start or run.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("cannot listen on {addr}: {source}")]
    Bind {
        addr: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{0}")]
    Config(String),
    #[error(transparent)]
    Lock(#[from] db_lock::LockError),
    #[error("server: {0}")]
    Io(#[from] std::io::Error),
}

/// All routes, with their body limits and token checks.
pub fn router(state: AppState) -> Router {
    // A tile blob: the 20-byte header and at most 1024 × 1024 RGB pixels.
    let tile_limit = protocol_limit();
    let body_limit = state.cfg.max_body_bytes;
    let worker_routes = Router::new()
        .route("/worker/claim", post(worker_api::claim))
        .route("/worker/jobs/{id}", get(worker_api::job))
        .route("/worker/jobs/{id}/assets/{name}", get(worker_api::asset))
        .route("/worker/jobs/{id}/tiles/{idx}", put(worker_api::result))
        .route(
            "/worker/jobs/{id}/tiles/{idx}/renew",
            post(worker_api::renew),
        )
        .route("/worker/jobs/{id}/tiles/{idx}/fail", post(worker_api::fail))
        .route(
            "/worker/jobs/{id}/tiles/{idx}/release",
            post(worker_api::release),
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
        .route("/jobs", get(api::list_jobs).post(api::submit))
        .route("/jobs/{id}", get(api::get_job).delete(api::delete_job))
        .layer(DefaultBodyLimit::max(state.cfg.max_body_bytes))
        .route_layer(axum::middleware::from_fn(move |req, next| {
            error::declared_length_within(body_limit, req, next)
        }))
        .route_layer(axum::middleware::from_fn_with_state(
            state.clone(),
            auth::require_submit_token,
        ));
    Router::new()
        .route("/", get(api::page))
        .route("/healthz", get(api::healthz))
        .route("/workers", get(api::workers))
        .route("/jobs/{id}/image.png", get(api::image))
        .merge(job_routes)
        .merge(worker_routes)
        .fallback(error::no_route)
        .method_not_allowed_fallback(error::wrong_method)
        .layer(axum::middleware::from_fn(error::json_errors))
        .layer(tower_http::trace::TraceLayer::new_for_http().on_failure(log_failure))
        .with_state(state)
}

/// Largest accepted tile blob.
pub const fn protocol_limit() -> usize {
    tessera_worker::protocol::TILE_HEADER_LEN + api::MAX_TILE as usize * api::MAX_TILE as usize * 3
}

/// Binds `cfg.listen` and serves until `shutdown` completes.
pub async fn run(
    cfg: Config,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), ServiceError> {
    let listener = TcpListener::bind(&cfg.listen)
        .await
        .map_err(|source| ServiceError::Bind {
            addr: cfg.listen.clone(),
            source,
        })?;
    serve(cfg, listener, shutdown).await
}

/// Serves on `listener` until `shutdown` completes: then local workers finish (or give back)
/// their tiles, open requests complete, and the function returns.
pub async fn serve(
    cfg: Config,
    listener: TcpListener,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), ServiceError> {
    let addr = listener.local_addr()?;
    if !addr.ip().is_loopback() && cfg.submit_token.is_none() && !cfg.open_submit {
        return Err(ServiceError::Config(format!(
            "listening on {addr}, beyond this machine, without --submit-token: anyone who can \
             reach it could submit jobs. Set --submit-token (TESSERA_SUBMIT_TOKEN), or pass \
             --open-submit to accept that."
        )));
    }
    if cfg
        .tile
        .is_some_and(|t| !(api::MIN_TILE..=api::MAX_TILE).contains(&t))
    {
        return Err(ServiceError::Config(format!(
            "--tile must be from {} to {}",
            api::MIN_TILE,
            api::MAX_TILE
        )));
    }
    if cfg.max_tiles == 0 {
        return Err(ServiceError::Config(
            "--max-tiles must be at least 1".into(),
        ));
    }
    // The command line refuses these already (clap ranges); a `Config` built in code is
    // checked here.
    if cfg.lease_ms < config::MIN_LEASE_MS {
        return Err(ServiceError::Config(format!(
            "--lease-ms must be at least {}",
            config::MIN_LEASE_MS
        )));
    }
    if cfg.receiving_bytes() < cfg.max_body_bytes {
        return Err(ServiceError::Config(format!(
            "--max-receiving-bytes ({}) must be at least --max-body-bytes ({}): a submission \
             of the largest size could never be received",
            cfg.receiving_bytes(),
            cfg.max_body_bytes
        )));
    }
    if cfg.max_body_bytes == 0 {
        return Err(ServiceError::Config(
            "--max-body-bytes must be at least 1".into(),
        ));
    }
    if cfg.max_attempts == 0 {
        return Err(ServiceError::Config(
            "--max-attempts must be at least 1".into(),
        ));
    }
    // Before anything touches the store: a second service's start requeued the first's
    // local workers' tiles (see `db_lock`).
    let lock = db_lock::DbLock::take(&cfg.database)?;
    if let Some(names) = lock.as_ref().and_then(|l| l.other_names) {
        warn!(
            "the database file has {names} names (hard links): one service per database is \
             enforced by name, so no service may use the file under another of them"
        );
    }
    let store = Store::open(&cfg.database)
        .await?
        .max_attempts(cfg.max_attempts);
    let local_count = local_worker_count(&cfg);
    // Unique to this run (host, pid, a random salt): no other worker's name starts with it
    // unless copied from this service's `/workers`.
    let local_prefix = format!("{}-local", tessera_worker::default_name());
    let requeued = store
        .forget_local_workers((local_count > 0).then_some(local_prefix.as_str()))
        .await?;
    if requeued > 0 {
        info!(
            "{requeued} tiles held by the local workers of the service's previous run \
             requeued (they ended with it)"
        );
    }
    let extended = store.extend_leases(now_ms(), cfg.lease_ms).await?;
    if extended > 0 {
        info!(
            "{extended} leases from before the restart extended by {} ms",
            cfg.lease_ms
        );
    }
    let (stop_tx, stop_rx) = watch::channel(false);
    let receiving = receiving::Receiving::new(cfg.receiving_bytes(), cfg.max_scene_texture_pixels);
    let state = AppState {
        cfg: Arc::new(cfg),
        store: store.clone(),
        work: Arc::default(),
        ended: Arc::default(),
        progress: Arc::default(),
        receiving,
        stopping: stop_rx.clone(),
    };
    match store.sweep_spool().await {
        Ok(0) => {}
        Ok(n) => info!("{n} spool files of ended jobs removed"),
        Err(e) => warn!("sweeping the tile spool: {e}"),
    }
    for job in store.unassembled().await? {
        info!(job = %job, "all tiles were in before the restart: assembling");
        state.spawn_assembly(job);
    }

    tokio::spawn(async move {
        shutdown.await;
        info!("shutting down: local workers finish their tiles");
        let _ = stop_tx.send(true);
    });
    tokio::spawn(reaper(state.clone(), stop_rx.clone()));

    let locals = spawn_local_workers(&state.cfg, addr, local_count, &local_prefix, &stop_rx);
    println!("tessera-service listening on http://{addr}");
    info!(
        "listening on http://{addr} with {} local workers, database {}",
        locals.len(),
        state.cfg.database
    );
    let mut stop_for_server = stop_rx.clone();
    let (drain_tx, drain_rx) = tokio::sync::oneshot::channel::<()>();
    let graceful = async move {
        let _ = stop_for_server.wait_for(|s| *s).await;
        for w in locals {
            let _ = w.await;
        }
        let _ = drain_tx.send(());
    };
    // Once the local workers are done, open requests get `DRAIN` to finish. A graceful stop
    // otherwise waited for every connection to close: a client that had sent half a request
    // held the stop for the idle timeout (two minutes), one that trickled its upload for
    // ever, past any service manager's patience.
    let deadline = async move {
        if drain_rx.await.is_ok() {
            tokio::time::sleep(DRAIN).await;
        } else {
            std::future::pending::<()>().await;
        }
    };
    let idle = Duration::from_secs(state.cfg.idle_timeout_secs);
    let server = axum::serve(idle::IdleListener::new(listener, idle), router(state))
        .with_graceful_shutdown(graceful)
        .into_future();
    tokio::select! {
        served = server => served?,
        () = deadline => warn!(
            "requests still open {} s after the stop: closing their connections",
            DRAIN.as_secs()
        ),
    }
    info!("stopped");
    Ok(())
}

/// tower-http's log line for a failed response: an error, except a `503`, which the
/// service answers on purpose (a busy database, a farm paused for a full disk, a
/// submission waiting for room: each logged where it is decided) and which came once per
/// waiting worker's claim, ten ERROR lines a second with two local workers.
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

/// How long requests still open when a stop begins (after the local workers are done) may
/// take before their connections are closed.
pub const DRAIN: Duration = Duration::from_secs(5);

/// `--local-workers`, or one per core.
fn local_worker_count(cfg: &Config) -> usize {
    cfg.local_workers.map_or_else(
        || std::thread::available_parallelism().map_or(1, |n| n.get()),
        usize::from,
    )
}

/// Starts `n` local workers named `{prefix}{i}`.
fn spawn_local_workers(
    cfg: &Config,
    addr: SocketAddr,
    n: usize,
    prefix: &str,
    stop: &watch::Receiver<bool>,
) -> Vec<tokio::task::JoinHandle<()>> {
    let host = if addr.ip().is_unspecified() {
        match addr {
            SocketAddr::V4(_) => format!("127.0.0.1:{}", addr.port()),
            SocketAddr::V6(_) => format!("[::1]:{}", addr.port()),
        }
    } else {
        addr.to_string()
    };
    // One cache of built scenes for all of them: a job's scene is fetched and built once.
    let scenes = tessera_worker::SceneCache::default();
    if n == 0 {
        return Vec::new();
    }
    // One queue of tiles in line for all their render threads: a thread whose worker has no
    // tile for it takes one another worker put in line.
    let pool = match tessera_worker::RenderPool::new(n) {
        Ok(p) => p,
        Err(e) => {
            error!("cannot start the local workers' render threads: {e}");
            return Vec::new();
        }
    };
    (0..n)
        .map(|i| {
            let mut wc = tessera_worker::WorkerConfig::new(format!("http://{host}"));
            wc.threads = 1;
            wc.token = cfg.token.clone();
            wc.name = format!("{prefix}{i}");
            wc.idle_max = Duration::from_millis(500);
            wc.grace = Duration::from_secs(cfg.grace_secs);
            let mut stop = stop.clone();
            let scenes = scenes.clone();
            let pool = pool.clone();
            tokio::spawn(async move {
                let stopped = async move {
                    let _ = stop.wait_for(|s| *s).await;
                };
                if let Err(e) = tessera_worker::run_with(wc, scenes, Some(pool), stopped).await {
                    error!("local worker {i} stopped: {e}");
                }
            })
        })
        .collect()
}

/// The least time a refused request keeps its lease from being reaped while the storage
/// fails: a worker retries a refused result at most 3 s apart, whatever the lease.
const HEARD_AT_LEAST: Duration = Duration::from_secs(5);

/// How often the reaper deletes the spool files of ended jobs.
const SWEEP_EVERY: Duration = Duration::from_secs(10);

/// Requeues expired leases a few times per lease period, and sweeps the tile spool.
async fn reaper(state: AppState, mut stop: watch::Receiver<bool>) {
    let every = Duration::from_millis((state.cfg.lease_ms / 4).clamp(25, 1000));
    let mut last = std::time::Instant::now();
    let mut swept = std::time::Instant::now();
    // Leases are being extended for the storage's failures (said once, not every pass).
    let mut extending = false;
    loop {
        tokio::select! {
            _ = tokio::time::sleep(every) => {}
            _ = stop.wait_for(|s| *s) => return,
        }
        // A service that did not run for half a lease (suspended, frozen, its machine
        // asleep) could not take the renewals its workers sent meanwhile: their leases ran
        // out through no fault of theirs, and reaping them would count it against them (a
        // 20 s freeze with 2 s leases failed a job). Give every lease a fresh term instead,
        // as a restart does.
        let paused = last.elapsed();
        last = std::time::Instant::now();
        // So with storage that failed within half a lease (a full disk): the renewals and
        // results of workers may have been refused meanwhile. Those refused are noted
        // (`Store::heard_refused`); a worker at work renews each lease every third of one,
        // and retries a refused result at most 3 s apart (its back-off's cap, with jitter),
        // so one heard from within a lease, and never less than 5 s, is alive.
        let window = Duration::from_millis(state.cfg.lease_ms / 2) + every;
        let heard_within = Duration::from_millis(state.cfg.lease_ms).max(HEARD_AT_LEAST) + every;
        // The pause first: it heard no one, so every lease is extended, whatever failed.
        if paused > window {
            match state
                .store
                .extend_leases(now_ms(), state.cfg.lease_ms)
                .await
            {
                Ok(n) => warn!(
                    "the service did not run for {:.1} s: {n} leases extended, none reaped",
                    paused.as_secs_f64()
                ),
                Err(e) => warn!(
                    "extending leases after a pause: {}",
                    state.store.noted(e, now_ms())
                ),
            }
            continue;
        }
        let reaped = if state.store.storage_failed_within(now_ms(), window) {
            // The leases of workers heard from are extended, the others reaped (the rest
            // of the pass goes on). Said once an episode.
            let pass = state
                .store
                .reap_unheard(
                    now_ms(),
                    state.cfg.lease_ms,
                    heard_within,
                    state.cfg.max_attempts,
                    state.keep_away(),
                )
                .await;
            if let Ok((extended, _)) = &pass
                && !extending
            {
                extending = true;
                warn!(
                    "the service's storage failed lately: the leases of workers whose requests \
                     it refused are extended, the others reaped as ever, until it has written \
                     again for half a lease ({extended} now)"
                );
            }
            pass.map(|(_, reaped)| reaped)
        } else {
            if extending {
                extending = false;
                info!("the service's storage writes again: expired leases are reaped again");
            }
            // `reap_unheard` forgets the leases refused too long ago; here, with nothing
            // refused lately, the record is only kept small.
            state.store.forget_unheard(now_ms(), heard_within);
            state
                .store
                .reap(now_ms(), state.cfg.max_attempts, state.keep_away())
                .await
        };
        match reaped {
            Ok(0) => {}
            Ok(n) => {
                warn!("{n} expired leases: tiles handed out again");
                state.work.notify_waiters();
                // A tile out of attempts fails its job.
                state.ended.notify_waiters();
            }
            Err(e) => warn!("reaping expired leases: {}", state.store.noted(e, now_ms())),
        }
        // The spool files of jobs that ended without an image (cancelled, failed, deleted).
        if swept.elapsed() >= SWEEP_EVERY {
            swept = std::time::Instant::now();
            if let Err(e) = state.store.sweep_spool().await {
                warn!("sweeping the tile spool: {e}");
            }
        }
        // Jobs that ended without an image (cancelled, failed) are no longer followed.
        let followed = state.progress.followed();
        if !followed.is_empty() {
            match state.store.active_jobs().await {
                Ok(active) => followed
                    .iter()
                    .filter(|id| !active.contains(id))
                    .for_each(|id| state.progress.forget(id)),
                Err(e) => warn!("listing active jobs: {e}"),
            }
        }
        // Workers heard from within a lease period (plus slack for idle polling).
        let live_since = now_ms() - state.cfg.lease_ms as i64 - 5_000;
        let live = match state.store.live_workers(live_since).await {
            Ok(live) => live,
            Err(e) => {
                warn!("listing live workers: {e}");
                continue;
            }
        };
        match state.store.fail_unservable(&live, now_ms()).await {
            Ok(0) => {}
            Ok(n) => {
                warn!("{n} jobs failed: every live worker is kept away from them");
                state.ended.notify_waiters();
            }
            Err(e) => warn!("checking kept-away jobs: {e}"),
        }
    }
}

/// SIGINT or SIGTERM (the worker's own signal handling, shared).
pub use tessera_worker::cli::shutdown_signal;
