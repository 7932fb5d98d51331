//! The one handle every handler shares ([`AppState`]), and the background work that a
//! handler starts through it (encoding an image's bands, assembling its PNG).
//!
//! It holds no policy of its own: the store decides, the state carries the store, the
//! configuration and the wake-ups (`work`, `ended`, `stopping`) between requests.

use std::sync::Arc;

use tokio::sync::watch;
use tracing::{error, warn};

use crate::changes::Changes;
use crate::config::Config;
use crate::read_only::ReadOnly;
use crate::receiving::Receiving;
use crate::store::{KeepAway, Store};
use crate::{assemble, now_ms, preview};

/// The state every handler shares.
#[derive(Clone)]
pub struct AppState {
    /// The service's configuration.
    pub cfg: Arc<Config>,
    /// The job store: every job, tile, lease, result, image and worker.
    pub store: Store,
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
    /// The ids of jobs this process changes, told to the streams of their events.
    pub changes: Changes,
    /// Previews encoded lately, shared by every viewer of a job.
    pub previews: Arc<preview::Cache>,
    /// Why the service takes no writes, while it has had no room to write since it started.
    pub read_only: Arc<ReadOnly>,
    /// The name prefix of this process's local workers; `None` without any.
    pub local_prefix: Option<String>,
}

impl AppState {
    /// The state of a service with configuration `cfg` on `store`, stopping once `stopping`
    /// turns `true`, with nothing yet received, encoded or waited for.
    pub fn new(cfg: Config, store: Store, stopping: watch::Receiver<bool>) -> AppState {
        AppState {
            receiving: Receiving::new(
                cfg.receiving_bytes(),
                cfg.max_scene_texture_pixels,
                cfg.max_checking_bytes,
            ),
            cfg: Arc::new(cfg),
            store,
            work: Arc::default(),
            ended: Arc::default(),
            progress: Arc::default(),
            stopping,
            changes: Changes::default(),
            previews: Arc::default(),
            read_only: Arc::default(),
            local_prefix: None,
        }
    }

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
        let changes = self.changes.clone();
        tokio::spawn(async move {
            // Done, failed, or tiles to render again: the job's events say which.
            let _told = Told(&changes, &job);
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
                if e.transient() && store.is_shared() {
                    // The maintenance pass of whichever replica holds it assembles the
                    // job again once the database answers.
                    warn!(job = %job, "assembling the image, to be retried: {e}");
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

/// Tells the streams of a job's events that it changed when dropped: on every way out of
/// the task that holds it.
struct Told<'a>(&'a Changes, &'a str);

impl Drop for Told<'_> {
    fn drop(&mut self) {
        self.0.job(self.1);
    }
}
