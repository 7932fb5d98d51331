//! How a worker runs ([`WorkerConfig`]) and the name it goes by when none is given.
//!
//! Not the command line: `cli.rs` turns flags into a [`WorkerConfig`]; the service builds
//! one for each of its local workers.

use std::time::Duration;

use crate::backoff::seed;

/// How a worker runs.
#[derive(Debug, Clone)]
pub struct WorkerConfig {
    /// The service's base URL, e.g. `http://127.0.0.1:8080`; or several, separated by
    /// commas, of replicas of one farm (one database): claims are spread over them, and a
    /// request goes to another while one does not answer.
    pub server: String,
    /// Bearer token for the worker routes, when the service requires one.
    pub token: Option<String>,
    /// Tiles rendered at once (one per core is the default).
    pub threads: usize,
    /// This worker's name as the service sees it.
    pub name: String,
    /// Skip tracing and post black tiles: for measuring the queue, never for images (cargo
    /// feature `bench` only, so that no shipped worker can post a wrong image).
    #[cfg(feature = "bench")]
    pub noop: bool,
    /// How long a claim waits at the service for work to appear (and the longest back-off
    /// while the service is unreachable is twice that, at least 2 s).
    pub idle_max: Duration,
    /// After a shutdown request, how long to keep rendering held tiles before giving them back.
    pub grace: Duration,
    /// Whether a clean stop says goodbye (`POST /worker/bye`), so that the service lists
    /// the worker gone at once. The service's own workers do not: they stop with it.
    pub say_bye: bool,
}

impl WorkerConfig {
    /// Whether tiles are posted black without tracing: never without the `bench` feature.
    pub(crate) fn noop(&self) -> bool {
        #[cfg(feature = "bench")]
        return self.noop;
        #[cfg(not(feature = "bench"))]
        false
    }

    /// The defaults for a worker of the service at `server`: one thread per core, the
    /// [`default_name`], claims that wait up to 1 s, a grace period of 30 s.
    pub fn new(server: impl Into<String>) -> WorkerConfig {
        WorkerConfig {
            server: server.into(),
            token: None,
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            name: default_name(),
            #[cfg(feature = "bench")]
            noop: false,
            idle_max: Duration::from_millis(1000),
            grace: Duration::from_secs(30),
            say_bye: true,
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
