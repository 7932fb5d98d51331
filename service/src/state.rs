//! The one handle every handler shares ([`AppState`]), and the background work that a
//! handler starts through it (encoding an image's bands, assembling its PNG).
//!
//! It holds no policy of its own: the queue decides, the state carries the queue, the
//! configuration and the wake-ups (`work`, `ended`, `stopping`) between requests.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, PoisonError};

use serde::Serialize;
use tokio::sync::watch;
use tracing::{error, warn};

use crate::config::Config;
use crate::queue::{KeepAway, Queue};
use crate::receiving::Receiving;
use crate::{assemble, now_ms};

/// What the service knows about a worker it has heard from.
#[derive(Debug, Clone, Default, Serialize)]
pub struct WorkerSeen {
    /// The name the worker gives itself.
    pub name: String,
    /// When it was last heard from, in milliseconds since the Unix epoch.
    pub last_seen: i64,
    /// The tiles it claimed.
    pub claims: u64,
    /// Of those claims, the ones that came back with a posted result (`?next=`).
    pub claims_with_results: u64,
    /// The tiles it rendered whose results were stored.
    pub tiles_done: u64,
}

/// The state every handler shares.
#[derive(Clone)]
pub struct AppState {
    /// The service's configuration.
    pub cfg: Arc<Config>,
    /// The job queue: every job, tile, lease, result and image.
    pub queue: Queue,
    /// Workers seen since start (in memory only: informational).
    pub roster: Arc<Mutex<HashMap<String, WorkerSeen>>>,
    /// Woken whenever tiles become claimable, so that waiting claims answer at once.
    pub work: Arc<tokio::sync::Notify>,
    /// Woken whenever a job may have ended (done, failed, cancelled), so that
    /// `GET /jobs/{id}?wait=` answers at once.
    pub ended: Arc<tokio::sync::Notify>,
    /// The PNGs being encoded while their jobs render.
    pub progress: Arc<assemble::Progress>,
    /// The body bytes of submissions being received at once (`--max-receiving-bytes`).
    pub receiving: Receiving,
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

    /// When a worker that keeps failing a job's tiles is kept away from it, and for how long
    /// (`--keep-away-after`, `--keep-away-secs`); leases of one worker on one job that run
    /// out within half a lease of each other count as one failure.
    pub fn keep_away(&self) -> KeepAway {
        KeepAway {
            after: self.cfg.keep_away_after,
            for_ms: (self.cfg.keep_away_secs as i64).saturating_mul(1000),
            stall_ms: i64::try_from(self.cfg.lease_ms / 2).unwrap_or(i64::MAX),
        }
    }

    /// Notes that `worker` was heard from now, and lets `f` update what is known of it.
    pub fn seen(&self, worker: &str, f: impl FnOnce(&mut WorkerSeen)) {
        let mut roster = self.roster.lock().unwrap_or_else(PoisonError::into_inner);
        let entry = roster
            .entry(worker.to_string())
            .or_insert_with(|| WorkerSeen {
                name: worker.to_string(),
                ..WorkerSeen::default()
            });
        entry.last_seen = now_ms();
        f(entry);
    }

    /// Workers heard from within a lease period (plus slack for idle polling).
    pub fn live_workers(&self) -> Vec<String> {
        let cutoff = now_ms() - self.cfg.lease_ms as i64 - 5_000;
        self.roster
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .values()
            .filter(|w| w.last_seen >= cutoff)
            .map(|w| w.name.clone())
            .collect()
    }

    /// A tile of `job` other than its last is stored: encodes, in the background, the bands
    /// of the image that this completed.
    pub fn tile_stored(&self, job: String, tile: tessera_tracer::Rect) {
        if self.progress.stored(&job, tile) {
            let queue = self.queue.clone();
            let progress = self.progress.clone();
            let (work, ended) = (self.work.clone(), self.ended.clone());
            tokio::spawn(async move {
                if progress.advance(&queue, &job).await {
                    // Tiles to render again; or, lost too often, the job failed.
                    work.notify_waiters();
                    ended.notify_waiters();
                }
            });
        }
    }

    /// Assembles a job's PNG in the background once its last tile is in.
    pub fn spawn_assembly(&self, job: String) {
        let queue = self.queue.clone();
        let ended = self.ended.clone();
        let progress = self.progress.clone();
        let work = self.work.clone();
        tokio::spawn(async move {
            if let Err(e) = progress.complete(&queue, &job).await {
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
                let _ = queue
                    .fail_job(&job, &format!("assembling the image failed: {e}"), now_ms())
                    .await;
            }
            ended.notify_waiters();
        });
    }
}
