//! What the slots of one worker share: its configuration, servers, scene cache, counters
//! and the moment its stop began.
//!
//! State only; the loops that use it live in `slot.rs`, `lease.rs`, `post.rs` and
//! `shutdown.rs`.

use std::sync::atomic::AtomicU64;
use std::sync::{Arc, OnceLock};
use std::time::Instant;

use tessera_protocol::ClaimRequest;

use crate::cache::SceneCache;
use crate::config::WorkerConfig;
use crate::meter::Meter;
use crate::servers::Servers;

/// One worker's state, shared by its slots and its tasks.
pub(crate) struct Shared {
    pub(crate) cfg: WorkerConfig,
    pub(crate) servers: Servers,
    pub(crate) cache: SceneCache,
    /// Tiles the service stored.
    pub(crate) tiles: AtomicU64,
    /// Tiles the service took back unrendered.
    pub(crate) released: AtomicU64,
    /// Tiles reported as failed.
    pub(crate) failed: AtomicU64,
    /// When the stop began: what is still held is given up `cfg.grace` after it.
    pub(crate) stopping_since: OnceLock<Instant>,
    /// The rays traced, for the rate the worker reports.
    pub(crate) meter: Arc<Meter>,
}

impl Shared {
    /// A claim by this worker, saying its threads and rays per second.
    pub(crate) fn claim_request(&self) -> ClaimRequest {
        let (threads, rays_per_second) = self.said();
        ClaimRequest {
            worker: self.cfg.name.clone(),
            threads: Some(threads),
            rays_per_second,
        }
    }

    /// What the worker says of itself with its claims and results: its threads, and the
    /// rays it traced per second lately (none before it has measured a whole window).
    pub(crate) fn said(&self) -> (u32, Option<f64>) {
        let threads = u32::try_from(self.cfg.threads).unwrap_or(u32::MAX);
        (threads, self.meter.rate(Instant::now()))
    }
}
