//! The Tessera render worker: a stateless loop that claims tiles from a service over HTTP,
//! traces them with the tracer crate and posts their pixels back.
//!
//! A worker holds nothing the service cannot lose: its only state is a small cache of parsed
//! scenes. It runs one claim-render-post loop per thread ("slot"), backs off with jitter when
//! there is no work or the service is unreachable, renews its lease while a tile renders, and
//! on shutdown finishes the tiles it holds (or, past a grace period, gives them back).
//!
//! It knows nothing of SQL or axum; the service runs the same loop in-process for its
//! `--local-workers`, over the same HTTP protocol.

pub mod cli;
pub mod client;
mod pool;

use pool::Rendered;
pub use pool::{RenderPool, STRIP_PIXELS};

use std::future::Future;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use bytes::Bytes;
use tessera_tracer::{Limits, MemoryAssets, Sampler, Scene, TextureLimits};
use tokio::sync::{Mutex, oneshot, watch};
use tokio::task::JoinHandle;
use tracing::{debug, info, warn};

use client::{Client, ClientError, Posted};
use tessera_protocol::{Claim, encode_tile};

/// How a worker runs.
#[derive(Debug, Clone)]
pub struct WorkerConfig {
    /// The service's base URL, e.g. `http://127.0.0.1:8080`.
    pub server: String,
    /// Bearer token for the worker routes, when the service requires one.
    pub token: Option<String>,
    /// Tiles rendered at once (one per core is the default).
    pub threads: usize,
    /// This worker's name as the service sees it.
    pub name: String,
    /// Skip tracing and post black tiles: for measuring the queue, never for images.
    pub noop: bool,
    /// How long a claim waits at the service for work to appear (and the longest back-off
    /// while the service is unreachable is twice that, at least 2 s).
    pub idle_max: Duration,
    /// After a shutdown request, how long to keep rendering held tiles before giving them back.
    pub grace: Duration,
}

impl WorkerConfig {
    pub fn new(server: impl Into<String>) -> WorkerConfig {
        WorkerConfig {
            server: server.into(),
            token: None,
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            name: default_name(),
            noop: false,
            idle_max: Duration::from_millis(1000),
            grace: Duration::from_secs(30),
        }
    }
}

/// `host-pid-nnnn`: unique among the workers of one farm, readable in `/workers`.
pub fn default_name() -> String {
    let host = std::env::var("HOSTNAME")
        .ok()
        .or_else(|| std::fs::read_to_string("/etc/hostname").ok())
        .map(|h| h.trim().to_string())
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "worker".into());
    let salt = seed() % 10_000;
    format!("{host}-{}-{salt:04}", std::process::id())
}

/// Why a worker stopped before it was asked to.
#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    #[error(transparent)]
    Client(#[from] ClientError),
    #[error("worker must have at least one thread")]
    NoThreads,
    #[error("cannot start a render thread: {0}")]
    Thread(#[source] std::io::Error),
}

/// What a worker did, reported when it stops.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct Summary {
    pub tiles: u64,
    pub released: u64,
    pub failed: u64,
}

/// A job's scene, built once per worker and shared by its slots.
struct Prepared {
    scene: Scene,
    sampler: Sampler,
}

/// Why a claimed tile could not be rendered here.
enum Unusable {
    /// The job is gone (deleted or cancelled): drop the tile.
    Gone,
    /// The scene does not build on this worker: report a failure.
    Invalid(String),
    /// The service could not be asked: give up on this tile for now.
    Client(ClientError),
}

/// Built scenes by job id, most recently used last: shared by the slots of one worker, and
/// by several workers of one service (the service's `--local-workers`), so that a job's
/// scene is fetched and built once however many of them render its tiles. Job ids are one
/// service's own, so a cache must not be shared by workers of different services.
///
/// An async mutex guards it and is held while a missing scene is fetched and built, so no
/// two users fetch the same scene at once; a user wanting another job's scene waits for
/// that build too, as the slots of one worker always have.
#[derive(Clone, Default)]
pub struct SceneCache {
    scenes: Arc<Mutex<Vec<Cached>>>,
}

/// A job id and its built scene.
type Cached = (String, Arc<Prepared>);

impl std::fmt::Debug for SceneCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SceneCache").finish_non_exhaustive()
    }
}

struct Shared {
    cfg: WorkerConfig,
    client: Client,
    cache: SceneCache,
    tiles: AtomicU64,
    released: AtomicU64,
    failed: AtomicU64,
    /// When the stop began: what is still held is given up `cfg.grace` after it.
    stopping_since: OnceLock<Instant>,
}

const CACHE_SCENES: usize = 4;

/// Runs the worker until `shutdown` completes (then finishes or gives back what it holds) or
/// a refusal that retrying cannot fix (a wrong token).
pub async fn run(
    cfg: WorkerConfig,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<Summary, WorkerError> {
    run_with(cfg, SceneCache::default(), None, shutdown).await
}

/// [`run`], with built scenes kept in (and taken from) `scenes`, which other workers of the
/// same service may share, and rendering on `pool` when given (shared with them too: a
/// thread of one takes the tiles another put in line when it has none of its own), or else
/// on `cfg.threads` threads of its own.
pub async fn run_with(
    cfg: WorkerConfig,
    scenes: SceneCache,
    pool: Option<RenderPool>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<Summary, WorkerError> {
    if cfg.threads == 0 {
        return Err(WorkerError::NoThreads);
    }
    let pool = match pool {
        Some(p) => p,
        None => RenderPool::new(cfg.threads).map_err(WorkerError::Thread)?,
    };
    let client = Client::new(&cfg.server, cfg.token.clone())?;
    let (stop_tx, stop_rx) = watch::channel(false);
    info!(
        name = %cfg.name, server = %cfg.server, threads = cfg.threads,
        "worker started"
    );
    let shared = Arc::new(Shared {
        client,
        cache: scenes,
        tiles: AtomicU64::new(0),
        released: AtomicU64::new(0),
        failed: AtomicU64::new(0),
        stopping_since: OnceLock::new(),
        cfg,
    });
    let stopping = shared.clone();
    tokio::spawn(async move {
        shutdown.await;
        stopping.stopping_since.get_or_init(Instant::now);
        info!(
            grace_secs = stopping.cfg.grace.as_secs(),
            "stopping: finishing the tiles being rendered, giving back the rest"
        );
        let _ = stop_tx.send(true);
    });
    let mut slots = Vec::new();
    for i in 0..shared.cfg.threads {
        slots.push(tokio::spawn(slot(
            shared.clone(),
            pool.clone(),
            i,
            stop_rx.clone(),
        )));
    }
    // The threads end once the slots, the last holders of the pool, are done.
    drop(pool);
    let mut first_err = None;
    for s in slots {
        match s.await {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                first_err.get_or_insert(e);
            }
            Err(e) => warn!("worker slot ended abnormally: {e}"),
        }
    }
    let summary = Summary {
        tiles: shared.tiles.load(Ordering::Relaxed),
        released: shared.released.load(Ordering::Relaxed),
        failed: shared.failed.load(Ordering::Relaxed),
    };
    info!(
        tiles = summary.tiles,
        released = summary.released,
        "worker stopped"
    );
    match first_err {
        Some(e) => Err(e.into()),
        None => Ok(summary),
    }
}

/// Waits `d`, or less if a shutdown is requested. Returns whether shutdown was requested.
async fn pause(d: Duration, stop: &mut watch::Receiver<bool>) -> bool {
    if *stop.borrow() {
        return true;
    }
    tokio::select! {
        _ = tokio::time::sleep(d) => *stop.borrow(),
        _ = stop.changed() => true,
    }
}

/// Exponential back-off from 25 ms up to `max`, with ±50% jitter so that many idle workers
/// do not poll in step.
fn backoff(streak: u32, max: Duration, rng: &mut u64) -> Duration {
    let base = 25u64.saturating_mul(1u64 << streak.min(16));
    let capped = base.min(max.as_millis() as u64).max(1);
    // xorshift64: jitter needs no quality, only spread.
    *rng ^= *rng << 13;
    *rng ^= *rng >> 7;
    *rng ^= *rng << 17;
    let jitter = 0.5 + (*rng % 1000) as f64 / 1000.0;
    Duration::from_millis((capped as f64 * jitter) as u64)
}

fn seed() -> u64 {
    let t = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64);
    (t ^ (u64::from(std::process::id()) << 32)) | 1
}

/// A claim asked for ahead of time, running as its own task so that it is never dropped
/// half-way (a claim answered but never read would strand its tile until the lease ran out).
type ClaimTask = JoinHandle<Result<Option<Claim>, ClientError>>;

/// A rendered tile on its way to the service.
type PostTask = JoinHandle<Result<(), ClientError>>;

impl RenderPool {
    /// Puts a claimed tile in line; a no-op worker's black tile (`scene` is `None`) is
    /// answered at once, without a trip through a thread.
    fn submit(&self, claim: Claim, scene: Option<Arc<Prepared>>) -> Ticket {
        let (reply, rendered) = oneshot::channel();
        let cancel = Arc::new(AtomicBool::new(false));
        let started = Arc::new(AtomicBool::new(false));
        let Some(scene) = scene else {
            let _ = reply.send(Ok(vec![0u8; claim.rect().pixel_count() * 3]));
            return Ticket {
                claim,
                rendered,
                cancel,
                started,
            };
        };
        let stop = cancel.clone();
        // The adaptive sampler's strips would trace their borders' rows again.
        let shareable = !matches!(scene.sampler, Sampler::Adaptive { .. });
        self.render(pool::TileWork {
            rect: claim.rect(),
            shareable,
            // The same bytes `tessera-render` writes: a pixel's value does not depend on
            // the rectangle it is rendered in. Given up mid-strip once the slot sets
            // `cancel` (the lease was lost).
            render: Box::new(move |strip| {
                scene
                    .scene
                    .render_rect_stats_until(strip, &scene.sampler, &stop)
                    .map(|(rgb, _)| rgb)
            }),
            stop: cancel.clone(),
            started: started.clone(),
            reply,
        });
        Ticket {
            claim,
            rendered,
            cancel,
            started,
        }
    }
}

/// A claimed tile in a render thread's queue.
struct Ticket {
    claim: Claim,
    rendered: oneshot::Receiver<Rendered>,
    cancel: Arc<AtomicBool>,
    /// Set when a render thread begins the tile: what the lease renewals say (`rendering`),
    /// since with threads shared by the slots the tile held ahead may be rendering on
    /// another slot's thread while the slot's current one still waits in line.
    started: Arc<AtomicBool>,
}

impl Ticket {
    /// Gives the tile back to the service: the render thread skips it if not yet started.
    async fn release(self, shared: &Shared) -> Result<(), ClientError> {
        self.cancel.store(true, Ordering::Relaxed);
        // Counted once the service has it back: a give-back that could not reach it is not
        // one (the tile returns when its lease runs out).
        give_back(shared, &self.claim).await
    }
}

/// What a slot has in flight besides the tile it renders. While tile N renders, the claim
/// for tile N + 1 is already asked for and, once answered, put in the render thread's
/// queue; tile N − 1's pixels are being posted. The round trips to the service thus overlap
/// with tracing instead of leaving the core idle between tiles. Each slot holds at most one
/// tile ahead, which bounds what a job's last moments can wait for to one tile per slot.
#[derive(Default)]
struct Pipeline {
    /// The next claim, still on its way.
    claim: Option<ClaimTask>,
    /// A claim answer that gave no tile to queue (no work, or an error), for the slot loop.
    next: Option<Result<Option<Claim>, ClientError>>,
    /// The next tile, in the render thread's queue.
    queued: Option<Ticket>,
    /// Posts of earlier tiles still under way, oldest first (at most [`POSTS_IN_FLIGHT`]).
    posts: std::collections::VecDeque<PostTask>,
    /// A tile claimed ahead was given back because its scene or a texture could not be
    /// fetched: the slot backs off before its next claim.
    unfetched: bool,
}

impl Pipeline {
    /// Waits for the claim in flight, if any (forever if none: for `select!`).
    async fn claim_answer(&mut self) -> Result<Option<Claim>, ClientError> {
        match &mut self.claim {
            Some(task) => task.await.unwrap_or_else(|e| {
                warn!("claim task ended abnormally: {e}");
                Ok(None)
            }),
            None => std::future::pending().await,
        }
    }

    /// Starts posting a rendered tile without waiting for earlier posts, unless
    /// [`POSTS_IN_FLIGHT`] are still under way (the service is slow or unreachable): then
    /// the oldest is waited for first. A refusal that retrying cannot fix is passed on.
    async fn start_post(&mut self, task: PostTask) -> Result<(), ClientError> {
        while self.posts.front().is_some_and(JoinHandle::is_finished)
            || self.posts.len() >= POSTS_IN_FLIGHT
        {
            self.finish_oldest_post().await?;
        }
        self.posts.push_back(task);
        Ok(())
    }

    async fn finish_oldest_post(&mut self) -> Result<(), ClientError> {
        match self.posts.pop_front() {
            Some(task) => task.await.unwrap_or_else(|e| {
                warn!("post task ended abnormally: {e}");
                Ok(())
            }),
            None => Ok(()),
        }
    }

    /// Waits for every post under way; the first refusal is passed on.
    async fn finish_posts(&mut self) -> Result<(), ClientError> {
        let mut first = Ok(());
        while !self.posts.is_empty() {
            let r = self.finish_oldest_post().await;
            if first.is_ok() {
                first = r;
            }
        }
        first
    }
}

/// Posts a slot may have under way at once: the next render never waits for the service
/// unless this many are stuck.
const POSTS_IN_FLIGHT: usize = 4;

async fn slot(
    shared: Arc<Shared>,
    renderer: RenderPool,
    index: usize,
    mut stop: watch::Receiver<bool>,
) -> Result<(), ClientError> {
    let mut rng = seed().wrapping_add(index as u64 * 0x9E37_79B9_7F4A_7C15) | 1;
    let mut idle = 0u32;
    let mut failing_since: Option<Instant> = None;
    // Tiles given back in a row because their scene or textures could not be fetched: the
    // back-off grows with them, as with a failing service (a claim that succeeds between
    // them does not reset it, or the slot would claim and give back ten times a second).
    let mut unfetched = 0u32;
    let mut pipe = Pipeline::default();
    let outcome = loop {
        if *stop.borrow() {
            break Ok(());
        }
        if std::mem::take(&mut pipe.unfetched) {
            unfetched = unfetched.saturating_add(1);
            let max = shared.cfg.idle_max.max(Duration::from_secs(2));
            if pause(backoff(unfetched, max, &mut rng), &mut stop).await {
                break Ok(());
            }
            continue;
        }
        if let Some(ticket) = pipe.queued.take() {
            unfetched = 0;
            if let Err(e) = work(&shared, &renderer, ticket, &mut stop, &mut pipe).await {
                break Err(e);
            }
            continue;
        }
        let claimed = if let Some(answer) = pipe.next.take() {
            answer
        } else if pipe.claim.is_some() {
            tokio::select! {
                a = pipe.claim_answer() => {
                    pipe.claim = None;
                    a
                }
                _ = stop.changed() => break Ok(()),
            }
        } else {
            tokio::select! {
                c = shared.client.claim(&shared.cfg.name, shared.cfg.idle_max) => c,
                _ = stop.changed() => break Ok(()),
            }
        };
        match claimed {
            Ok(Some(c)) => {
                if let Some(since) = failing_since.take() {
                    info!(
                        "the service answers again after {:.1} s",
                        since.elapsed().as_secs_f64()
                    );
                }
                idle = 0;
                let ticket = match submit(&shared, &renderer, c).await {
                    Ok(Submitted::Queued(t)) => t,
                    Ok(Submitted::Dropped) => continue,
                    Ok(Submitted::Unfetched) => {
                        pipe.unfetched = true;
                        continue;
                    }
                    Err(e) => break Err(e),
                };
                if let Err(e) = work(&shared, &renderer, ticket, &mut stop, &mut pipe).await {
                    break Err(e);
                }
            }
            Ok(None) => {
                // The service already waited `idle_max` for work (or, an older service,
                // answered at once): a short jittered pause keeps idle workers out of step.
                failing_since = None;
                idle = idle.saturating_add(1);
                if pause(backoff(0, shared.cfg.idle_max, &mut rng), &mut stop).await {
                    break Ok(());
                }
            }
            Err(e) if e.is_transient() => {
                if failing_since.is_none() {
                    warn!("{e}; retrying with back-off");
                    failing_since = Some(Instant::now());
                }
                idle = idle.saturating_add(1);
                let max = shared.cfg.idle_max.max(Duration::from_secs(2));
                // At least as long as the service asked (a farm paused for a full disk).
                let wait = backoff(idle, max, &mut rng).max(e.retry_after().unwrap_or_default());
                if pause(wait, &mut stop).await {
                    break Ok(());
                }
            }
            Err(e) => break Err(e),
        }
    };
    let drained = drain(&shared, pipe).await;
    outcome.and(drained)
}

/// On the way out: the last posts are finished, and a tile claimed ahead (or still being
/// claimed) is given back at once rather than left to its lease.
async fn drain(shared: &Shared, mut pipe: Pipeline) -> Result<(), ClientError> {
    let posted = pipe.finish_posts().await;
    if let Some(ticket) = pipe.queued.take() {
        ticket.release(shared).await?;
    }
    if let Some(mut task) = pipe.claim.take() {
        // The claim waits at most `idle_max` at the service; past that and a margin, the
        // answer is abandoned and the tile, if any, comes back when its lease runs out.
        let limit = shared.cfg.idle_max + Duration::from_secs(2);
        match tokio::time::timeout(limit, &mut task).await {
            Ok(Ok(answer)) => pipe.next = Some(answer),
            Ok(Err(e)) => warn!("claim task ended abnormally: {e}"),
            Err(_) => task.abort(),
        }
    }
    if let Some(Ok(Some(c))) = &pipe.next {
        give_back(shared, c).await?;
    }
    posted
}

/// What became of a claimed tile handed to [`submit`].
enum Submitted {
    /// In the render thread's queue.
    Queued(Ticket),
    /// Dealt with: its job is gone, or its scene does not build here (reported).
    Dropped,
    /// Its scene or a texture could not be fetched (the service failed to answer, or could
    /// not be reached): the tile was given back, and the slot backs off as from a failing
    /// service. It took the job's every tile in turn, each held until its lease ran out.
    Unfetched,
}

/// Puts a claimed tile in the render thread's queue, with its scene (from the cache, or
/// fetched and built), or deals with a tile that cannot be rendered here.
async fn submit(
    shared: &Shared,
    renderer: &RenderPool,
    c: Claim,
) -> Result<Submitted, ClientError> {
    if shared.cfg.noop {
        return Ok(Submitted::Queued(renderer.submit(c, None)));
    }
    match prepared(shared, &c.job).await {
        Ok(p) => Ok(Submitted::Queued(renderer.submit(c, Some(p)))),
        Err(Unusable::Gone) => Ok(Submitted::Dropped),
        Err(Unusable::Invalid(reason)) => {
            warn!(job = %c.job, "cannot build scene: {reason}");
            shared.failed.fetch_add(1, Ordering::Relaxed);
            shared
                .client
                .fail(&c, &shared.cfg.name, &reason)
                .await
                .or_else(ignore_transient)?;
            Ok(Submitted::Dropped)
        }
        Err(Unusable::Client(e)) if !e.is_transient() => Err(e),
        Err(Unusable::Client(e)) => {
            // Not the tile's fault, nor the scene's: another worker may fetch it. If the
            // give-back cannot reach the service either, the lease runs out.
            warn!(job = %c.job, "cannot fetch scene: {e}; giving the tile back");
            give_back(shared, &c).await?;
            Ok(Submitted::Unfetched)
        }
    }
}

/// The scene of `job`, from the cache or fetched and built.
async fn prepared(shared: &Shared, job: &str) -> Result<Arc<Prepared>, Unusable> {
    let mut cache = shared.cache.scenes.lock().await;
    if let Some(i) = cache.iter().position(|(id, _)| id == job) {
        let entry = cache.remove(i);
        let p = entry.1.clone();
        cache.push(entry);
        return Ok(p);
    }
    let spec = match shared.client.job(job).await {
        Ok(s) => s,
        Err(ClientError::Status { status: 404, .. })
        | Err(ClientError::Status { status: 410, .. }) => {
            return Err(Unusable::Gone);
        }
        Err(e) => return Err(Unusable::Client(e)),
    };
    let mut assets = MemoryAssets::new();
    for name in &spec.assets {
        let bytes = match shared.client.asset(job, name).await {
            Ok(bytes) => bytes,
            // Not found: the job was deleted since its scene was fetched, or a proxy before
            // the service refuses the texture's URL (some refuse the `%2F` of
            // `textures%2Fglobe.png`), which no retry mends. Reported as a failure, with
            // the reason: this worker is then kept away from the job, and a job no worker
            // can fetch fails, instead of coming back to the same tile for ever. (It stopped
            // the worker with an error; then, dropped unreleased, the tile's lease ran out
            // and was charged as a crash.)
            Err(e @ ClientError::Status { status: 404, .. })
            | Err(e @ ClientError::Status { status: 410, .. }) => {
                return Err(Unusable::Invalid(format!(
                    "cannot fetch texture `{name}`: {e}"
                )));
            }
            Err(e) => return Err(Unusable::Client(e)),
        };
        assets.insert(name.clone(), bytes);
    }
    let started = Instant::now();
    let built = tokio::task::spawn_blocking(move || -> Result<Prepared, String> {
        let limits = Limits::default();
        let desc = tessera_tracer::parse(&spec.scene, &limits).map_err(|e| e.to_string())?;
        let sampler = desc.sampler.with_overrides(
            spec.sampler.as_deref(),
            spec.samples,
            spec.threshold,
            limits.max_samples,
        )?;
        let scene =
            Scene::build(&desc, &assets, &TextureLimits::default()).map_err(|e| e.to_string())?;
        Ok(Prepared { scene, sampler })
    })
    .await
    .map_err(|e| Unusable::Invalid(format!("building the scene panicked: {e}")))?
    .map_err(Unusable::Invalid)?;
    info!(
        job,
        ms = started.elapsed().as_millis() as u64,
        "scene built"
    );
    let p = Arc::new(built);
    if cache.len() >= CACHE_SCENES {
        cache.remove(0);
    }
    cache.push((job.to_string(), p.clone()));
    Ok(p)
}

/// Waits for a queued tile's render, renewing its lease (and that of the tile queued after
/// it) meanwhile, then starts posting it. The next claim is asked for as this wait begins,
/// and put in the render thread's queue as soon as it is answered.
async fn work(
    shared: &Arc<Shared>,
    renderer: &RenderPool,
    mut t: Ticket,
    stop: &mut watch::Receiver<bool>,
    pipe: &mut Pipeline,
) -> Result<(), ClientError> {
    let client = &shared.client;
    // A no-op tile is "rendered" already: its next claim rides on its post instead.
    if !shared.cfg.noop
        && pipe.claim.is_none()
        && pipe.next.is_none()
        && pipe.queued.is_none()
        && !*stop.borrow()
    {
        pipe.claim = Some(spawn_claim(shared, None, stop.clone()));
    }

    let c = t.claim.clone();
    let renew_every = Duration::from_millis((c.lease_ms / 3).max(10));
    let mut ticker =
        tokio::time::interval_at(tokio::time::Instant::now() + renew_every, renew_every);
    let mut deadline: Option<tokio::time::Instant> = None;
    let started = Instant::now();
    let rendered = loop {
        let give_up = async {
            match deadline {
                Some(d) => tokio::time::sleep_until(d).await,
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            r = &mut t.rendered => break r,
            answer = pipe.claim_answer() => {
                pipe.claim = None;
                match answer {
                    Ok(Some(next)) if !*stop.borrow() => {
                        match submit(shared, renderer, next).await? {
                            Submitted::Queued(t) => pipe.queued = Some(t),
                            Submitted::Dropped => {}
                            Submitted::Unfetched => pipe.unfetched = true,
                        }
                    }
                    other => pipe.next = Some(other),
                }
            }
            _ = ticker.tick() => {
                match client.renew(&c, t.started.load(Ordering::Relaxed)).await {
                    Ok(true) => {}
                    Ok(false) => {
                        debug!(job = %c.job, tile = c.idx, "lease lost; dropping the tile");
                        t.cancel.store(true, Ordering::Relaxed);
                        // The tile held ahead is most likely of the same (cancelled) job: ask
                        // now, not a renewal period from now, before it starts rendering.
                        if let Some(queued) = &pipe.queued
                            && let Ok(false) = client
                                .renew(&queued.claim, queued.started.load(Ordering::Relaxed))
                                .await
                            && let Some(lost) = pipe.queued.take()
                        {
                            lost.cancel.store(true, Ordering::Relaxed);
                        }
                        return Ok(());
                    }
                    // Unreachable: keep rendering; the service extends leases when it restarts.
                    Err(e) if e.is_transient() => debug!("renewal failed: {e}"),
                    Err(e) => return Err(e),
                }
                if let Some(queued) = &pipe.queued {
                    match client
                        .renew(&queued.claim, queued.started.load(Ordering::Relaxed))
                        .await
                    {
                        Ok(true) => {}
                        Ok(false) => {
                            if let Some(lost) = pipe.queued.take() {
                                lost.cancel.store(true, Ordering::Relaxed);
                            }
                        }
                        Err(e) if e.is_transient() => debug!("renewal failed: {e}"),
                        Err(e) => return Err(e),
                    }
                }
            }
            changed = stop.changed(), if deadline.is_none() => {
                if changed.is_err() || *stop.borrow() {
                    deadline = Some(tokio::time::Instant::now() + shared.cfg.grace);
                    // The tile queued next will not be rendered here: others may take it now.
                    if let Some(queued) = pipe.queued.take() {
                        queued.release(shared).await?;
                    }
                }
            }
            _ = give_up => {
                info!(job = %c.job, tile = c.idx, "shutting down: giving the tile back");
                return t.release(shared).await;
            }
        }
    };
    let rgb = match rendered {
        Ok(Ok(rgb)) => rgb,
        failed => {
            let reason = match failed {
                Ok(Err(reason)) => reason,
                _ => "the render thread is gone".to_string(),
            };
            warn!(job = %c.job, tile = c.idx, "{reason}");
            shared.failed.fetch_add(1, Ordering::Relaxed);
            return client
                .fail(&c, &shared.cfg.name, &reason)
                .await
                .or_else(ignore_transient);
        }
    };
    debug!(job = %c.job, tile = c.idx, ms = started.elapsed().as_millis() as u64, "rendered");
    // `Bytes`: every attempt at posting (see `post`) sends this buffer, not a copy of it.
    let blob = Bytes::from(encode_tile(c.rect(), &rgb));
    // Unless a claim is already under way or answered, this post also asks for the slot's
    // next tile: one round trip instead of two. The tile after the one now queued is thus
    // asked for as soon as this one is rendered, as it would be by a separate claim.
    let ride = if pipe.claim.is_none() && pipe.next.is_none() && !*stop.borrow() {
        let (tx, rx) = oneshot::channel();
        pipe.claim = Some(spawn_claim(shared, Some(rx), stop.clone()));
        Some(tx)
    } else {
        None
    };
    pipe.start_post(tokio::spawn(post(
        shared.clone(),
        c,
        blob,
        ride,
        stop.clone(),
    )))
    .await
}

/// The claim a post may carry: the post's answer, or nothing (the post failed, was refused,
/// or the service had no work at that moment).
type Ride = oneshot::Sender<Option<Claim>>;

/// A claim for the slot's next tile, as its own task: the one a post brings back (`ride`),
/// or else an ordinary claim, which waits up to `idle_max` at the service for work. Nothing
/// is claimed once the worker is stopping.
fn spawn_claim(
    shared: &Arc<Shared>,
    ride: Option<oneshot::Receiver<Option<Claim>>>,
    stop: watch::Receiver<bool>,
) -> ClaimTask {
    let client = shared.client.clone();
    let (name, wait) = (shared.cfg.name.clone(), shared.cfg.idle_max);
    tokio::spawn(async move {
        if let Some(ride) = ride
            && let Ok(Some(c)) = ride.await
        {
            return Ok(Some(c));
        }
        if *stop.borrow() {
            return Ok(None);
        }
        client.claim(&name, wait).await
    })
}

/// Posts a rendered tile, riding through a service restart (it extends leases when it
/// comes back). With `ride`, the first attempt also asks for the slot's next tile and hands
/// the answer over; later attempts do not (the slot claims on its own then).
async fn post(
    shared: Arc<Shared>,
    c: Claim,
    blob: Bytes,
    ride: Option<Ride>,
    stop: watch::Receiver<bool>,
) -> Result<(), ClientError> {
    // A rendered tile is worth waiting for, but once the worker is stopping only for the
    // grace period: the service may be down, or frozen (it takes the request and never
    // answers), for longer than a service manager waits; a stop took four leases or the
    // client's two-minute timeout, whatever `--grace-secs` said.
    tokio::select! {
        posted = post_retrying(&shared, &c, blob, ride) => posted,
        () = grace_over(&shared, stop) => {
            warn!(job = %c.job, tile = c.idx, "stopping: the tile could not be posted in time; giving it up");
            Ok(())
        }
    }
}

/// Posts the tile, retrying with back-off for up to four leases while the service cannot
/// be reached.
async fn post_retrying(
    shared: &Shared,
    c: &Claim,
    blob: Bytes,
    mut ride: Option<Ride>,
) -> Result<(), ClientError> {
    let give_up_at = Instant::now() + Duration::from_millis(c.lease_ms.max(1000) * 4);
    let mut rng = seed();
    let mut streak = 0;
    loop {
        let next = ride.is_some().then_some(shared.cfg.name.as_str());
        let answer = shared.client.post_tile(c, blob.clone(), next).await;
        if let Some(tx) = ride.take() {
            let claim = match &answer {
                Ok(Posted::Accepted { next, .. }) => next.clone(),
                _ => None,
            };
            // The claim task ends only after hearing from here, and the slot's `drain` waits
            // for it (to give back what it brought); the send fails only if that wait timed
            // out, and then the tile comes back when its lease runs out.
            let _ = tx.send(claim);
        }
        match answer {
            Ok(Posted::Accepted { .. }) => {
                shared.tiles.fetch_add(1, Ordering::Relaxed);
                return Ok(());
            }
            Ok(Posted::Stale(why)) => {
                debug!(job = %c.job, tile = c.idx, "result refused: {why}");
                return Ok(());
            }
            Err(e) if e.is_transient() && Instant::now() < give_up_at => {
                streak += 1;
                let pause = backoff(streak, Duration::from_secs(2), &mut rng);
                debug!(job = %c.job, tile = c.idx, "posting failed ({e}); retrying in {pause:?}");
                tokio::time::sleep(pause).await;
            }
            Err(e) if e.is_transient() => {
                warn!(job = %c.job, tile = c.idx, "could not post the tile: {e}");
                return Ok(());
            }
            Err(e) => return Err(e),
        }
    }
}

/// The longest a give-back (always while stopping) waits for the service's answer.
const GIVE_BACK_WAIT: Duration = Duration::from_secs(2);

/// Completes once the worker is stopping and its grace period is over.
async fn grace_over(shared: &Shared, mut stop: watch::Receiver<bool>) {
    if stop.wait_for(|s| *s).await.is_err() {
        // The stop can no longer come.
        std::future::pending::<()>().await;
    }
    let since = *shared.stopping_since.get_or_init(Instant::now);
    tokio::time::sleep_until((since + shared.cfg.grace).into()).await;
}

/// Gives a tile back, counting it in `released` only if the service took it back (not if
/// it was unreachable, or the lease was no longer this worker's).
async fn give_back(shared: &Shared, c: &Claim) -> Result<(), ClientError> {
    // Given back while stopping: a service that does not answer (frozen) is not waited for
    // past `GIVE_BACK_WAIT`; the tile comes back when its lease runs out.
    let Ok(answer) = tokio::time::timeout(GIVE_BACK_WAIT, shared.client.release(c)).await else {
        warn!(job = %c.job, tile = c.idx, "no answer to the give-back; the lease will run out");
        return Ok(());
    };
    match answer {
        Ok(taken) => {
            if taken {
                shared.released.fetch_add(1, Ordering::Relaxed);
            }
            Ok(())
        }
        Err(e) => ignore_transient(e),
    }
}

fn ignore_transient(e: ClientError) -> Result<(), ClientError> {
    if e.is_transient() { Ok(()) } else { Err(e) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_grows_to_its_cap_with_bounded_jitter() {
        let mut rng = 12345;
        let max = Duration::from_millis(800);
        for streak in 0..40 {
            let d = backoff(streak, max, &mut rng);
            let nominal = (25u64 << streak.min(16)).min(800);
            assert!(d.as_millis() as u64 >= nominal / 2, "{streak}: {d:?}");
            assert!(d.as_millis() as u64 <= nominal * 3 / 2, "{streak}: {d:?}");
        }
    }
}
