//! One worker as a whole: starts its slots and the stop watcher, waits for them, and sums
//! up what they did ([`run`], [`run_with`]).
//!
//! Not what a slot does (`slot.rs`), nor the program around it (`cli.rs`).

use std::future::Future;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::Instant;

use tokio::sync::watch;
use tracing::{info, warn};

use crate::cache::SceneCache;
use crate::client::ClientError;
use crate::config::WorkerConfig;
use crate::meter::Meter;
use crate::pool::RenderPool;
use crate::servers::Servers;
use crate::shared::Shared;
use crate::shutdown::on_shutdown;
use crate::slot::slot;

/// Why a worker stopped without being asked to.
#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    /// The service refused the worker in a way that retrying cannot fix (a wrong token, a
    /// bad URL).
    #[error(transparent)]
    Client(#[from] ClientError),
    /// [`WorkerConfig::threads`] is 0.
    #[error("worker must have at least one thread")]
    NoThreads,
    /// The operating system would not start a render thread.
    #[error("cannot start a render thread: {0}")]
    Thread(#[source] std::io::Error),
}

/// What a worker did, reported when it stops.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct Summary {
    /// Tiles rendered and stored by the service.
    pub tiles: u64,
    /// Tiles given back unrendered, and taken back by the service.
    pub released: u64,
    /// Tiles reported as failed (their scene did not build, or their render failed).
    pub failed: u64,
}

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
    let servers = Servers::new(&cfg.server, cfg.token.clone(), cfg.idle_max)?;
    let (stop_tx, stop_rx) = watch::channel(false);
    info!(
        name = %cfg.name, server = %cfg.server, threads = cfg.threads,
        "worker started"
    );
    let shared = Arc::new(Shared {
        servers,
        cache: scenes,
        tiles: AtomicU64::new(0),
        released: AtomicU64::new(0),
        failed: AtomicU64::new(0),
        stopping_since: OnceLock::new(),
        meter: Arc::new(Meter::new(Instant::now())),
        cfg,
    });
    on_shutdown(shared.clone(), shutdown, stop_tx);
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
    // Said once every tile is posted or given back, so that nothing it held is left to
    // lapse; a worker stopped by a refusal says nothing (the service may not hear it).
    if first_err.is_none()
        && shared.cfg.say_bye
        && let Err(e) = shared.servers.bye(&shared.cfg.name).await
    {
        warn!("saying goodbye to the service: {e}");
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
