//! The workers that run inside the service's process: ordinary `tessera_worker` loops that
//! speak HTTP to the service, sharing one scene cache and one pool of render threads.

use std::net::SocketAddr;
use std::time::Duration;

use tokio::sync::watch;
use tracing::error;

use crate::config::Config;

/// The start of every local worker's name: unique to this run (host, pid, a random salt),
/// so that no other worker's name starts with it unless copied from this service's
/// `/workers`. A restart requeues the tiles held under the previous run's prefix.
pub fn local_prefix() -> String {
    format!("{}-local", tessera_worker::default_name())
}

/// `--local-workers`, or one per core.
pub fn local_worker_count(cfg: &Config) -> usize {
    cfg.local_workers.map_or_else(
        || std::thread::available_parallelism().map_or(1, |n| n.get()),
        usize::from,
    )
}

/// Starts `n` local workers named `{prefix}{i}`.
pub fn spawn_local_workers(
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
            wc.say_bye = false;
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
