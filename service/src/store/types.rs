//! The values the store takes and answers with, whatever the backend.

use std::time::Duration;

use serde::Serialize;
use tessera_tracer::Rect;

use super::state::{JobState, TileState};

/// A job as users see it.
#[derive(Debug, Clone, Serialize, sqlx::FromRow, utoipa::ToSchema)]
pub struct JobRow {
    /// The job's id (hexadecimal, the service's own).
    pub id: String,
    /// Where it is in its life.
    #[sqlx(try_from = "String")]
    pub state: JobState,
    /// The name its submitter gave it.
    pub name: Option<String>,
    /// The image's width in pixels.
    pub width: i64,
    /// The image's height in pixels.
    pub height: i64,
    /// The tile size in pixels.
    pub tile: i64,
    /// The sampler asked for, if any.
    pub sampler: Option<String>,
    /// Samples per pixel asked for, if any.
    pub samples: Option<i64>,
    /// The adaptive sampler's threshold asked for, if any.
    pub threshold: Option<f64>,
    /// Tiles in all.
    pub tiles_total: i64,
    /// Tiles whose pixels are stored.
    pub tiles_done: i64,
    /// Why it failed.
    pub error: Option<String>,
    /// When it was submitted (ms since the epoch).
    pub created_at: i64,
    /// When its first tile was handed out.
    pub started_at: Option<i64>,
    /// When it ended.
    pub finished_at: Option<i64>,
    /// The size of its PNG, once done.
    pub png_bytes: Option<i64>,
    /// Claims take tiles of the highest-priority job first (see [`crate::store::Store::claim`]).
    pub priority: i64,
}

/// A job about to be stored.
#[derive(Debug, Clone)]
pub struct NewJob {
    /// Its id.
    pub id: String,
    /// The scene's text.
    pub scene: String,
    /// The name its submitter gave it.
    pub name: Option<String>,
    /// The image's width in pixels.
    pub width: u32,
    /// The image's height in pixels.
    pub height: u32,
    /// The tile size in pixels.
    pub tile: u32,
    /// The sampler asked for.
    pub sampler: Option<String>,
    /// Samples per pixel asked for.
    pub samples: Option<u32>,
    /// The adaptive sampler's threshold asked for.
    pub threshold: Option<f64>,
    /// When it was submitted (ms since the epoch).
    pub created_at: i64,
    /// Higher first; first in, first out among equals.
    pub priority: i64,
}

/// A tile's place and lease, with its job's state.
#[derive(Debug, Clone)]
pub struct TileInfo {
    /// Its rectangle in the image.
    pub rect: Rect,
    /// Where it is.
    pub state: TileState,
    /// Its current lease token, if handed out (kept once done: a repeat is recognised by it).
    pub lease: Option<String>,
    /// The worker it was handed to.
    pub worker: Option<String>,
    /// Its job's state.
    pub job_state: JobState,
}

/// What became of a posted result.
#[derive(Debug, Clone, PartialEq)]
pub enum Completion {
    /// Stored; `last` when it was the job's last tile (the image can be assembled). `worker`
    /// is the name the tile was claimed under.
    Stored {
        /// It was the job's last tile.
        last: bool,
        /// The worker that claimed it.
        worker: Option<String>,
    },
    /// Already stored from this very lease: nothing changed.
    Repeat,
    /// Not this lease's to post (expired and handed out again, released, or the job ended).
    Stale(String),
    /// The lease is current, but the pixels are for another rectangle than this tile.
    WrongTile(Rect),
    /// The job has no such tile (or no longer exists).
    Missing,
    /// The pixels could not be written to the spool: nothing was stored, and the tile was
    /// queued again, never charged to the worker. For want of room (a full disk) it is not
    /// charged at all; after any other write error the tile is charged, as a lost tile is
    /// (see [`crate::store::Store::complete`]). Says why.
    Unstored(String),
}

impl Completion {
    /// Why a result under `lease` stored nothing, from its tile as read afterwards (`None`:
    /// the job has no such tile). `repeat`: whether a tile done under this very lease is a
    /// repeat of a stored post (false when this post's own pixels were undone, its job
    /// having ended under it).
    pub(crate) fn refused(tile: Option<TileInfo>, lease: &str, repeat: bool) -> Completion {
        let Some(tile) = tile else {
            return Completion::Missing;
        };
        let current = tile.lease.as_deref() == Some(lease);
        if repeat && tile.state == TileState::Done && current {
            Completion::Repeat
        } else if !tile.job_state.is_active() {
            Completion::Stale(format!("the job is {}", tile.job_state))
        } else if !current || tile.state != TileState::Leased {
            Completion::Stale(
                "this lease is no longer current (it expired or was given back)".into(),
            )
        } else {
            Completion::WrongTile(tile.rect)
        }
    }
}

/// How long after a tile's pixels could not be written the service hands out no work (see
/// [`crate::store::Store::storage_trouble`]): long enough that workers do not render tile
/// after tile that cannot be stored, short enough that a freed disk is noticed soon. A
/// claim after it hands out a tile again, whose result tries the spool again.
pub const STORAGE_PAUSE: Duration = Duration::from_secs(5);

/// Keep-away policy for workers that fail a job.
#[derive(Debug, Clone, Copy)]
pub struct KeepAway {
    /// Failures (reported or lost leases) of one worker on one job before it is kept away.
    pub after: u32,
    /// For how long.
    pub for_ms: i64,
    /// Leases of one worker on one job that run out within this of the first are one stall
    /// (the service uses half a lease: a worker renews all its leases at once, every third
    /// of one).
    pub stall_ms: i64,
}

/// A stored tile of a band, as [`crate::store::Store::band`] read it: its place and size,
/// and where its rows' bytes are in the band's buffer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BandTile {
    /// Its left column.
    pub x: u32,
    /// Its width.
    pub w: u32,
    /// Its height.
    pub h: u32,
    /// Where its bytes are in the band's buffer.
    pub bytes: std::ops::Range<usize>,
}

/// What [`crate::store::Store::cancel`] found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Cancel {
    /// No such job.
    Unknown,
    /// It was queued or running (`from`); now it is cancelled.
    Cancelled {
        /// Its state before.
        from: JobState,
    },
    /// Every tile is in (a done job, or a running one whose image is being written): not
    /// cancelled.
    Complete,
    /// It had already ended (failed or cancelled): nothing changed.
    Ended {
        /// Its state.
        state: JobState,
    },
}

/// What a WAL checkpoint did, in frames (pages).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Checkpoint {
    /// Frames in the WAL.
    pub log: i64,
    /// Frames of it now copied into the database file.
    pub copied: i64,
}

/// What the service knows about a worker it has heard from (the `/workers` route's rows).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct WorkerSeen {
    /// The name it gives.
    pub name: String,
    /// When it was last heard from (ms since the epoch).
    pub last_seen: i64,
    /// Tiles it claimed.
    pub claims: u64,
    /// Of those claims, the ones that came back with a posted result (`?next=`).
    pub claims_with_results: u64,
    /// Tiles it rendered that were stored.
    pub tiles_done: u64,
    /// Its render threads, as it last said (none: never said).
    pub threads: Option<u32>,
    /// The rays it traced per second lately, as it last said (none: never said).
    pub rays_per_second: Option<f64>,
    /// When it last said goodbye (ms since the epoch; 0: never). It has left while this is
    /// at least `last_seen`.
    pub left_at: i64,
}

impl WorkerSeen {
    /// Whether it said goodbye and has not been heard from since.
    pub fn has_left(&self) -> bool {
        self.left_at > 0 && self.left_at >= self.last_seen
    }
}

/// A lease held now: which worker renders (or holds ahead) which tile.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HeldTile {
    /// The worker that holds it.
    pub worker: String,
    /// The tile's job.
    pub job: String,
    /// The tile's index within its job.
    pub idx: u32,
    /// Whether the worker said it is rendering it (not holding it ahead of its turn).
    pub rendering: bool,
}

/// The farm's numbers at one moment, for the metrics: jobs by state and the tiles waiting
/// or leased in active jobs.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct FarmCounts {
    /// Jobs in each state that has any (states with none are left out).
    pub jobs: Vec<(JobState, u64)>,
    /// Tiles of queued and running jobs waiting for a worker.
    pub tiles_queued: u64,
    /// Tiles of queued and running jobs under a lease.
    pub tiles_leased: u64,
}

/// A tile as users see it: where it is in the image, where it is in its life, who holds or
/// rendered it, and how often it was handed out and failed (`GET /jobs/{id}/tiles`, the job
/// page's map, the job's events).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, utoipa::ToSchema)]
pub struct TileView {
    /// Its index within its job.
    pub idx: u32,
    /// Its left edge, in image pixels.
    pub x: u32,
    /// Its top edge, in image pixels.
    pub y: u32,
    /// Its width in pixels.
    pub w: u32,
    /// Its height in pixels.
    pub h: u32,
    /// Queued, leased or done.
    pub state: TileState,
    /// The worker that holds it (leased) or rendered it (done).
    pub worker: Option<String>,
    /// How many times it was handed out.
    pub attempts: i64,
    /// How many of those ended without its pixels: reported failures and leases that ran out.
    pub failures: i64,
    /// Why it last failed.
    pub error: Option<String>,
}

/// What [`crate::store::Store::set_priority`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reprioritized {
    /// No such job.
    Unknown,
    /// The job was queued or running; its priority is the new one.
    Changed,
    /// The job has ended (its state): nothing changed.
    Ended(JobState),
}

/// What [`crate::store::Store::retry`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Retried {
    /// No such job.
    Unknown,
    /// The job is queued, running or done (its state): nothing changed.
    NotEnded(JobState),
    /// The failed or cancelled job is active again, its stored tiles kept and the others
    /// queued with their failures forgotten. `complete`: every tile was already stored (an
    /// image whose assembly failed), so only the image is left to write.
    Retried {
        /// Every tile is stored: nothing to render, only the image to assemble.
        complete: bool,
    },
}
