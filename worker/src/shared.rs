//! What the slots of one worker share: its configuration, servers, scene cache, counters
//! and the moment its stop began.
//!
//! State only; the loops that use it live in `slot.rs`, `lease.rs`, `post.rs` and
//! `shutdown.rs`.

use std::sync::OnceLock;
use std::sync::atomic::AtomicU64;
use std::time::Instant;

use crate::cache::SceneCache;
use crate::config::WorkerConfig;
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
}
