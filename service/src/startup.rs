//! Starting and stopping the service: the configuration's cross-checks, the database lock,
//! opening the store (on a full disk too), listening, and the graceful stop (local workers
//! finish, open requests get [`DRAIN`] to complete).
//!
//! Putting the store right after a restart is `restart`'s, the periodic maintenance
//! `reaper`'s, the in-process workers `local_workers`'; this module only starts them.

use std::future::{Future, IntoFuture};
use std::net::SocketAddr;
use std::time::Duration;

use tokio::net::TcpListener;
use tokio::sync::watch;
use tracing::{info, warn};

use crate::config::{self, Config};
use crate::local_workers::{local_prefix, local_worker_count, spawn_local_workers};
use crate::reaper::reaper;
use crate::routes::router;
use crate::state::AppState;
use crate::store::{Store, StoreError};
use crate::tiling::{MAX_TILE, MIN_TILE};
use crate::{db_lock, idle, restart};

/// Why the service could not start or run.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    /// The store could not be opened or put right after a restart.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The listening address could not be bound.
    #[error("cannot listen on {addr}: {source}")]
    Bind {
        /// The address, as configured.
        addr: String,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// The configuration cannot be run with (see `check`).
    #[error("{0}")]
    Config(String),
    /// Another service holds the database.
    #[error(transparent)]
    Lock(#[from] db_lock::LockError),
    /// Serving failed.
    #[error("server: {0}")]
    Io(#[from] std::io::Error),
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
    check(&cfg, addr)?;
    // Before anything touches the store: a second service's start would requeue the first's
    // local workers' tiles (see `db_lock`).
    let lock = db_lock::DbLock::take(&cfg.database)?;
    if let Some(names) = lock.as_ref().and_then(|l| l.other_names) {
        warn!(
            "the database file has {names} names (hard links): one service per database is \
             enforced by name, so no service may use the file under another of them"
        );
    }
    let store = open_store(&cfg.database)
        .await?
        .max_attempts(cfg.max_attempts);
    let local_count = local_worker_count(&cfg);
    let local_prefix = local_prefix();
    let (stop_tx, stop_rx) = watch::channel(false);
    let mut state = AppState::new(cfg, store.clone(), stop_rx.clone());
    state.local_prefix = (local_count > 0).then(|| local_prefix.clone());
    // Without room to write, the service starts read-only, and the maintenance pass tries
    // these writes again until they go through (see `restart`).
    if let Err(e) = restart::settle(&state).await {
        if !e.is_storage() {
            return Err(e.into());
        }
        warn!(
            "no room to write: serving reads only, and refusing writes until the disk has \
             room ({e})"
        );
        state.read_only.set(Some(e.to_string()));
    }

    tokio::spawn(async move {
        shutdown.await;
        info!("shutting down: local workers finish their tiles");
        let _ = stop_tx.send(true);
    });
    tokio::spawn(reaper(state.clone(), stop_rx.clone()));
    crate::metrics::start(stop_rx.clone());
    // Other replicas' submissions and requeues wake this one's waiting claims.
    let (news, work, ended) = (store.clone(), state.work.clone(), state.ended.clone());
    let stop_listening = stop_rx.clone();
    tokio::spawn(async move { news.listen(work, ended, stop_listening).await });

    let locals = spawn_local_workers(&state.cfg, addr, local_count, &local_prefix, &stop_rx);
    println!("tessera-service listening on http://{addr}");
    info!(
        "listening on http://{addr} with {} local workers, database {}",
        locals.len(),
        crate::store::redacted(&state.cfg.database)
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
    // alone waits for every connection to close: a client that has sent half a request
    // would hold the stop for the idle timeout, one that trickles its upload for ever, past
    // any service manager's patience.
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

/// Opens the store at `url`. A SQLite file on a disk too full to open it as usual is opened
/// on one exclusive connection instead (see `Store::open_exclusive`), so that the service can
/// start read-only; if that fails too, the first error is the one reported.
async fn open_store(url: &str) -> Result<Store, StoreError> {
    match Store::open(url).await {
        Err(e) if e.is_storage() => match Store::open_exclusive(url).await {
            Some(Ok(store)) => {
                warn!(
                    "the database could not be opened as usual ({e}): one connection serves \
                     its reads and writes until the service restarts"
                );
                Ok(store)
            }
            _ => Err(e),
        },
        opened => opened,
    }
}

/// Refuses a configuration the service cannot run with: open submission beyond loopback
/// without `--open-submit`, and limits out of their ranges. The command line refuses the
/// latter already (clap ranges); a `Config` built in code is checked here.
fn check(cfg: &Config, addr: SocketAddr) -> Result<(), ServiceError> {
    if !addr.ip().is_loopback() && cfg.submit_token.is_none() && !cfg.open_submit {
        return Err(ServiceError::Config(format!(
            "listening on {addr}, beyond this machine, without --submit-token: anyone who can \
             reach it could submit jobs. Set --submit-token (TESSERA_SUBMIT_TOKEN), or pass \
             --open-submit to accept that."
        )));
    }
    if cfg
        .tile
        .is_some_and(|t| !(MIN_TILE..=MAX_TILE).contains(&t))
    {
        return Err(ServiceError::Config(format!(
            "--tile must be from {} to {}",
            MIN_TILE, MAX_TILE
        )));
    }
    if cfg.max_tiles == 0 {
        return Err(ServiceError::Config(
            "--max-tiles must be at least 1".into(),
        ));
    }
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
    Ok(())
}

/// How long requests still open when a stop begins (after the local workers are done) may
/// take before their connections are closed.
pub const DRAIN: Duration = Duration::from_secs(5);
