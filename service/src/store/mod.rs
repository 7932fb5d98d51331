//! The storage seam: [`Store`], the one type the handlers, the reaper and the image
//! assembly talk to for jobs, tiles, leases, results, images and workers.
//!
//! `Store` is an enum over backends: SQLite ([`SqliteStore`], `store/sqlite/`), the
//! one-command default for one service process, and PostgreSQL ([`PgStore`],
//! `store/postgres/`), which several service processes (replicas) share. An enum rather
//! than a trait: every call is a static `match` with no boxed
//! futures (a trait object could not have `async fn`s without them), the handlers name one
//! concrete type instead of carrying a type parameter through `AppState` and every route,
//! and a new backend is a variant that every `match` here must then handle, so the
//! compiler lists what it has to provide.
//!
//! What lives here and not in the handlers: every guarantee about tiles and leases (one
//! holder per tile, stale leases change nothing, failures counted and bounded), and the
//! state several service processes on one database would have to share (the jobs, the
//! tiles and their leases, keep-away, the roster of workers seen, the health row). What a
//! backend keeps in a process's memory is that process's by design, and says why where it
//! is kept (the SQLite backend's WAL checkpoints, its tile spool, its record of the storage
//! failing).
//!
//! Time: a store reads no clock. Every operation that needs the time takes `now`, in
//! milliseconds since the Unix epoch, from its caller (the service's `now_ms`, or a test's
//! own numbers), and windows ("failed less than `within` ago") are measured from that `now`.
//! The only timing inside is how long to wait for the database (the writer's queue, the
//! health probe's deadline), which tokio's timers measure.
//!
//! The shared values are in `types`, the states and their text in `state`, the error in
//! `error`; none of them depends on a backend. This module knows nothing of HTTP.

mod error;
mod memo;
mod postgres;
mod sqlite;
mod stall;
mod state;
mod types;

use std::path::Path;
use std::time::Duration;

use tessera_protocol::{Claim, JobSpec};
use tessera_tracer::Rect;

pub use error::{SpoolError, StoreError};
pub use postgres::PgStore;
pub use sqlite::SqliteStore;
pub use state::{JobState, TileState, UnknownState};
pub use types::{
    BandTile, Cancel, Checkpoint, Completion, FarmCounts, HeldTile, JobRow, KeepAway, NewJob,
    Reprioritized, Retried, STORAGE_PAUSE, TileInfo, TileView, WorkerSeen,
};

pub(crate) use postgres::{is_postgres, redacted};
pub(crate) use sqlite::is_sqlite;

/// The service's default `--max-attempts`, which a store uses until told otherwise.
const DEFAULT_MAX_ATTEMPTS: u32 = 4;

/// Tile and image bytes written between two background WAL checkpoints of a SQLite store.
#[cfg(feature = "bench")]
pub const CHECKPOINT_EVERY_BYTES: u64 = sqlite::CHECKPOINT_EVERY_BYTES;

/// The most leases a store's record of refused requests holds at once (see
/// [`Store::heard_refused`]).
pub const HEARD_LEASES: usize = memo::HEARD_LEASES;

/// Where a tile's bytes lie in its job's spool file, `(offset, length)` (tests spoil them).
#[cfg(feature = "bench")]
pub fn spool_slot(width: u32, height: u32, tile: Rect) -> Option<(u64, usize)> {
    sqlite::spool::slot(width, height, tile)
}

type Result<T> = std::result::Result<T, StoreError>;

/// The store the service runs on: one backend, chosen by the database URL.
#[derive(Debug, Clone)]
pub enum Store {
    /// A SQLite database file (or an in-memory database).
    Sqlite(SqliteStore),
    /// A PostgreSQL database, shared by any number of service processes.
    Postgres(PgStore),
}

/// HeldTile while this process writes a job's PNG (see [`Store::assembling`]).
#[derive(Debug)]
pub struct AssemblyLock(#[allow(dead_code)] Option<postgres::AssemblyLock>);

/// Runs `$e` with `$s` bound to the backend.
macro_rules! on {
    ($self:expr, $s:ident => $e:expr) => {
        match $self {
            Store::Sqlite($s) => $e,
            Store::Postgres($s) => $e,
        }
    };
}

impl Store {
    /// Opens the database at `url` and brings its schema up to date: `sqlite://PATH`, a
    /// bare path or `sqlite::memory:` (created if missing), or `postgres://…` (also
    /// `postgresql://`), which must exist. Any other URL is refused with
    /// [`StoreError::Url`], saying what is taken.
    pub async fn open(url: &str) -> Result<Store> {
        if is_postgres(url) {
            return Ok(Store::Postgres(PgStore::open(url).await?));
        }
        Ok(Store::Sqlite(SqliteStore::open(url).await?))
    }

    /// Opens the SQLite database file at `url` on a disk too full for [`Store::open`], on
    /// one exclusive connection (see `SqliteStore::open_exclusive`), so that the service
    /// can serve its reads; `None` for a URL that names no SQLite file.
    pub async fn open_exclusive(url: &str) -> Option<Result<Store>> {
        if is_postgres(url) || url.contains(":memory:") {
            return None;
        }
        Some(SqliteStore::open_exclusive(url).await.map(Store::Sqlite))
    }

    /// The same store, failing a job whose tile lost its pixels `n` times (the service's
    /// `--max-attempts`; 4 until set).
    pub fn max_attempts(self, n: u32) -> Store {
        match self {
            Store::Sqlite(s) => Store::Sqlite(s.max_attempts(n)),
            Store::Postgres(s) => Store::Postgres(s.max_attempts(n)),
        }
    }

    /// Whether other service processes may use this database at the same time (a
    /// PostgreSQL store): then what one process remembers of a job (the bands it encoded
    /// ahead) does not see the tiles the others store.
    pub fn is_shared(&self) -> bool {
        matches!(self, Store::Postgres(_))
    }

    /// Whether this process runs the periodic maintenance now (reaping, sweeping, failing
    /// unservable jobs, assembling images no one assembles): always for SQLite, whose
    /// database has one process; for PostgreSQL, the one replica holding the maintenance
    /// lock, checked on every call.
    pub async fn maintains(&self) -> bool {
        match self {
            Store::Sqlite(_) => true,
            Store::Postgres(s) => s.maintains().await,
        }
    }

    /// Writes what this process noted for the other processes on the database (the
    /// workers it heard from, the leases it refused while the storage failed) and reads
    /// what they shared; nothing for SQLite.
    pub async fn share(&self, now: i64) -> Result<()> {
        match self {
            Store::Sqlite(_) => Ok(()),
            Store::Postgres(s) => s.share(now).await,
        }
    }

    /// Wakes `work` and `ended` when another process on the database makes work or ends a
    /// job, until `stop` turns true; returns at once for SQLite.
    pub async fn listen(
        &self,
        work: std::sync::Arc<tokio::sync::Notify>,
        ended: std::sync::Arc<tokio::sync::Notify>,
        stop: tokio::sync::watch::Receiver<bool>,
    ) {
        if let Store::Postgres(s) = self {
            s.listen(work, ended, stop).await;
        }
    }

    /// The right to write job `id`'s PNG, held until dropped; `None` while another process
    /// (or task) writes it. SQLite's one process always gets it (its assemblies are kept
    /// apart in memory, by `assemble`).
    pub async fn assembling(&self, id: &str) -> Result<Option<AssemblyLock>> {
        match self {
            Store::Sqlite(_) => Ok(Some(AssemblyLock(None))),
            Store::Postgres(s) => Ok(s.assembling(id).await?.map(|l| AssemblyLock(Some(l)))),
        }
    }

    /// The same store, checkpointing a SQLite WAL after every `bytes` of tiles and images
    /// instead of [`CHECKPOINT_EVERY_BYTES`].
    #[cfg(feature = "bench")]
    pub fn checkpoint_every(self, bytes: u64) -> Store {
        match self {
            Store::Sqlite(s) => Store::Sqlite(s.checkpoint_every(bytes)),
            other => other,
        }
    }

    /// Copies a SQLite WAL's committed pages into the database file without blocking the
    /// writer; `None` for an in-memory database.
    #[cfg(feature = "bench")]
    pub async fn checkpoint(&self) -> Result<Option<Checkpoint>> {
        match self {
            Store::Sqlite(s) => s.checkpoint().await,
            Store::Postgres(_) => Ok(None),
        }
    }

    /// Background checkpoints finished so far, as a watch; `None` without a WAL.
    #[cfg(feature = "bench")]
    pub fn checkpoints(&self) -> Option<tokio::sync::watch::Receiver<u64>> {
        match self {
            Store::Sqlite(s) => s.checkpoints(),
            Store::Postgres(_) => None,
        }
    }

    /// Answers when the database does.
    pub async fn ping(&self) -> Result<()> {
        on!(self, s => s.ping().await)
    }

    /// Rewrites the health row (dated `now`) within `within`, and checks that tile pixels
    /// can be stored: whether the store takes writes now.
    pub async fn probe_write(&self, now: i64, within: Duration) -> Result<()> {
        on!(self, s => s.probe_write(now, within).await)
    }

    /// Stores a job, its tiles and its assets in one transaction.
    pub async fn insert_job(
        &self,
        job: &NewJob,
        tiles: &[Rect],
        assets: &[(String, Vec<u8>)],
    ) -> Result<JobRow> {
        on!(self, s => s.insert_job(job, tiles, assets).await)
    }

    /// Jobs, newest first: at most `limit`, and with `before`, only those submitted before
    /// that job. `None` when `before` names no job.
    pub async fn jobs(&self, limit: u32, before: Option<&str>) -> Result<Option<Vec<JobRow>>> {
        on!(self, s => s.jobs(limit, before).await)
    }

    /// One job.
    pub async fn job(&self, id: &str) -> Result<Option<JobRow>> {
        on!(self, s => s.job(id).await)
    }

    /// Cancels a queued or running job at `now`, unless every tile is already in (see
    /// [`Cancel`]); its stored tiles stay until it is deleted (see [`Store::retry`]).
    pub async fn cancel(&self, id: &str, now: i64) -> Result<Cancel> {
        on!(self, s => s.cancel(id, now).await)
    }

    /// Makes a failed or cancelled job active again at `now`, rendering only what is
    /// missing: its stored tiles stay, the others are queued with their failures
    /// forgotten, and no worker is kept away from it (see [`Retried`]).
    pub async fn retry(&self, id: &str, now: i64) -> Result<Retried> {
        on!(self, s => s.retry(id, now).await)
    }

    /// Removes a job and everything stored for it; false if there was none.
    pub async fn delete(&self, id: &str) -> Result<bool> {
        on!(self, s => s.delete(id).await)
    }

    /// Hands the first queued tile of the first active job (the highest priority, then the
    /// oldest) that `worker` is not kept away from to it, under a new lease of `lease_ms`
    /// from `now`. No tile that failed `max_attempts` times is handed out. Two claims never
    /// get the same tile.
    pub async fn claim(
        &self,
        worker: &str,
        now: i64,
        lease_ms: u64,
        max_attempts: u32,
    ) -> Result<Option<Claim>> {
        on!(self, s => s.claim(worker, now, lease_ms, max_attempts).await)
    }

    /// Extends a lease that is still current to `lease_ms` from `now`; its worker's name,
    /// or `None` if the lease is stale. `rendering`: the worker says it is rendering the
    /// tile, not holding it ahead (see [`Store::reap`]).
    pub async fn renew(
        &self,
        job: &str,
        idx: u32,
        lease: &str,
        now: i64,
        lease_ms: u64,
        rendering: bool,
    ) -> Result<Option<String>> {
        on!(self, s => s.renew(job, idx, lease, now, lease_ms, rendering).await)
    }

    /// A tile's rectangle, state and lease, with its job's state.
    pub async fn tile(&self, job: &str, idx: u32) -> Result<Option<TileInfo>> {
        on!(self, s => s.tile(job, idx).await)
    }

    /// Stores a tile's pixels if `lease` is its current lease, its job is active and `rect`
    /// (what the blob says it holds; `rgb` has been checked against it) is the tile's; says
    /// what became of them otherwise ([`Completion`]). `now` dates a failure to store them.
    #[allow(clippy::too_many_arguments)]
    pub async fn complete(
        &self,
        job: &str,
        idx: u32,
        lease: &str,
        rect: Rect,
        rgb: &[u8],
        now: i64,
    ) -> Result<Completion> {
        on!(self, s => s.complete(job, idx, lease, rect, rgb, now).await)
    }

    /// A worker reports that it cannot render a tile: the tile is queued again with one more
    /// failure, the failure counts against the worker (keeping it away from the job past
    /// `keep`'s limit), and the job fails if the tile is out of attempts. False when the
    /// lease is stale.
    #[allow(clippy::too_many_arguments)]
    pub async fn fail_tile(
        &self,
        job: &str,
        idx: u32,
        lease: &str,
        worker: &str,
        reason: &str,
        now: i64,
        max_attempts: u32,
        keep: KeepAway,
    ) -> Result<bool> {
        on!(self, s => s.fail_tile(job, idx, lease, worker, reason, now, max_attempts, keep).await)
    }

    /// Gives a tile back unrendered (a worker shutting down): no failure is counted. False
    /// when the lease is stale.
    pub async fn release(&self, job: &str, idx: u32, lease: &str) -> Result<bool> {
        on!(self, s => s.release(job, idx, lease).await)
    }

    /// Passes `e` through, noting at `now` when it is the database's storage failing (see
    /// [`Store::storage_failed_within`]).
    pub fn noted(&self, e: StoreError, now: i64) -> StoreError {
        on!(self, s => s.noted(e, now))
    }

    /// Whether a database write failed for the storage's sake less than `within` before
    /// `now`: renewals may have been refused meanwhile.
    pub fn storage_failed_within(&self, now: i64, within: Duration) -> bool {
        on!(self, s => s.storage_failed_within(now, within))
    }

    /// Why tile pixels cannot be stored now, if a write of them failed for want of room
    /// less than `within` before `now` and none has succeeded since.
    pub fn storage_trouble(&self, now: i64, within: Duration) -> Option<String> {
        match self {
            Store::Sqlite(s) => s.storage_trouble(now, within),
            // No spool: pixels go into the database, whose failures are its errors.
            Store::Postgres(_) => None,
        }
    }

    /// While the farm is paused for want of room to store tile pixels, looks again: the pause
    /// lasts as long as there is none (the reaper's every pass).
    pub fn recheck_storage(&self, now: i64, within: Duration) {
        match self {
            Store::Sqlite(s) => s.recheck_storage(now, within),
            Store::Postgres(_) => {}
        }
    }

    /// Requeues tiles whose lease expired before `now`, charging the stalls to their tiles
    /// and workers, and fails jobs with a tile out of attempts. Returns how many tiles were
    /// requeued.
    pub async fn reap(&self, now: i64, max_attempts: u32, keep: KeepAway) -> Result<u64> {
        on!(self, s => s.reap(now, max_attempts, keep).await)
    }

    /// Fails the active jobs with queued work from which every one of `live` workers is
    /// kept away at `now`. Returns how many.
    pub async fn fail_unservable(&self, live: &[String], now: i64) -> Result<u64> {
        on!(self, s => s.fail_unservable(live, now).await)
    }

    /// At start: requeues, uncharged, the tiles held by the local workers of the process
    /// that last started on this database, and stores `prefix`, the name prefix of this
    /// process's local workers. Returns how many tiles were requeued.
    ///
    /// With PostgreSQL, nothing: the replica that last started is not the one whose
    /// local workers ended (the others run on), so their leases run out as any worker's.
    pub async fn forget_local_workers(&self, prefix: Option<&str>) -> Result<u64> {
        match self {
            Store::Sqlite(s) => s.forget_local_workers(prefix).await,
            Store::Postgres(_) => Ok(0),
        }
    }

    /// [`Store::noted`], for a renewal or a result under `lease` that failed: while the
    /// storage fails, the reaper gives that lease a fresh term rather than reap it
    /// ([`Store::reap_unheard`]). At most [`HEARD_LEASES`] are kept.
    pub fn heard_refused(&self, lease: &str, e: StoreError, now: i64) -> StoreError {
        on!(self, s => s.heard_refused(lease, e, now))
    }

    /// Notes a refused request under `lease` at `now` (see [`Store::heard_refused`]).
    pub fn heard(&self, lease: &str, now: i64) {
        on!(self, s => s.heard(lease, now))
    }

    /// Forgets the leases not heard from within `within` before `now`.
    pub fn forget_unheard(&self, now: i64, within: Duration) {
        on!(self, s => s.forget_unheard(now, within))
    }

    /// The reaper's pass while the storage fails: the leases heard from within `within`
    /// get a fresh `lease_ms` from `now`, the others are reaped as ever. Returns how many
    /// leases were extended and how many reaped.
    pub async fn reap_unheard(
        &self,
        now: i64,
        lease_ms: u64,
        within: Duration,
        max_attempts: u32,
        keep: KeepAway,
    ) -> Result<(u64, u64)> {
        on!(self, s => s.reap_unheard(now, lease_ms, within, max_attempts, keep).await)
    }

    /// Sets every live lease to run out `lease_ms` from `now` (a restart's grace, or a fresh
    /// term after a pause of the service). Returns how many.
    pub async fn extend_leases(&self, now: i64, lease_ms: u64) -> Result<u64> {
        on!(self, s => s.extend_leases(now, lease_ms).await)
    }

    /// When a service starts: every live lease runs out `grace_ms` from `now`. On SQLite
    /// that lengthens the leases of workers that rode through the outage (nobody could renew
    /// meanwhile) and shortens the others; on a shared database it only shortens, since the
    /// other replicas took renewals. Returns how many leases changed.
    pub async fn restart_leases(&self, now: i64, grace_ms: u64) -> Result<u64> {
        match self {
            Store::Sqlite(s) => s.extend_leases(now, grace_ms).await,
            Store::Postgres(s) => s.cap_leases(now, grace_ms).await,
        }
    }

    /// The ids of queued and running jobs.
    pub async fn active_jobs(&self) -> Result<Vec<String>> {
        on!(self, s => s.active_jobs().await)
    }

    /// Deletes the tile pixels kept for jobs whose image is stored or that were deleted (a
    /// SQLite store's spool files); returns how many files went. Jobs that ended without
    /// an image keep theirs for a retry.
    pub async fn sweep_spool(&self) -> Result<usize> {
        match self {
            Store::Sqlite(s) => s.sweep_spool().await,
            Store::Postgres(_) => Ok(0),
        }
    }

    /// The folder where a SQLite store keeps tile pixels; `None` for one that keeps them in
    /// the database.
    pub fn spool_dir(&self) -> Option<&Path> {
        match self {
            Store::Sqlite(s) => s.spool_dir(),
            Store::Postgres(_) => None,
        }
    }

    /// Jobs whose tiles are all in but whose image is not yet assembled (after a restart).
    pub async fn unassembled(&self) -> Result<Vec<String>> {
        on!(self, s => s.unassembled().await)
    }

    /// A job's state, and what a worker needs of it: scene, sampler settings, asset names.
    pub async fn job_scene(&self, id: &str) -> Result<Option<(JobState, JobSpec)>> {
        on!(self, s => s.job_scene(id).await)
    }

    /// One asset of a job.
    pub async fn asset(&self, id: &str, name: &str) -> Result<Option<Vec<u8>>> {
        on!(self, s => s.asset(id, name).await)
    }

    /// The stored tiles of the band of rows starting at `y`, left to right: their bytes
    /// appended to `buf` (cleared first), each tile with where its bytes are. Tiles whose
    /// pixels were lost are queued again (dated `now`) and the call fails with
    /// [`StoreError::Lost`].
    pub async fn band(
        &self,
        id: &str,
        y: u32,
        now: i64,
        buf: &mut Vec<u8>,
    ) -> Result<Vec<BandTile>> {
        on!(self, s => s.band(id, y, now, buf).await)
    }

    /// Hands out again the done tiles `idxs` of an active job whose pixels were lost, each
    /// loss a failure of its tile; returns how many were requeued.
    pub async fn requeue_lost(&self, id: &str, idxs: &[i64], now: i64) -> Result<u64> {
        on!(self, s => s.requeue_lost(id, idxs, now).await)
    }

    /// Drops a job's PNG chunks.
    pub async fn clear_image(&self, id: &str) -> Result<()> {
        on!(self, s => s.clear_image(id).await)
    }

    /// Stores a chunk of a job's PNG, unless the job has ended meanwhile.
    pub async fn put_image_chunk(&self, id: &str, seq: u32, bytes: &[u8]) -> Result<()> {
        on!(self, s => s.put_image_chunks(id, seq, &[bytes]).await)
    }

    /// Stores `pieces` as the job's PNG chunks from `first_seq` on, unless the job has
    /// ended meanwhile.
    pub async fn put_image_chunks(&self, id: &str, first_seq: u32, pieces: &[&[u8]]) -> Result<()> {
        on!(self, s => s.put_image_chunks(id, first_seq, pieces).await)
    }

    /// Marks an assembled job done at `now` and drops its tile pixels. False (and the image
    /// dropped) when the job ended meanwhile; its pixels then stay for a retry.
    pub async fn finish_image(&self, id: &str, png_bytes: u64, now: i64) -> Result<bool> {
        on!(self, s => s.finish_image(id, png_bytes, now).await)
    }

    /// Fails a job whose image could not be assembled.
    pub async fn fail_job(&self, id: &str, reason: &str, now: i64) -> Result<()> {
        on!(self, s => s.fail_job(id, reason, now).await)
    }

    /// The number of chunks of a job's PNG.
    pub async fn image_chunks(&self, id: &str) -> Result<u32> {
        on!(self, s => s.image_chunks(id).await)
    }

    /// One chunk of a job's PNG.
    pub async fn image_chunk(&self, id: &str, seq: u32) -> Result<Option<Vec<u8>>> {
        on!(self, s => s.image_chunk(id, seq).await)
    }

    /// Notes that `worker` was heard from at `now`; `f` adds to its counts (claims,
    /// results). The roster reaches the database by the next read of it.
    pub fn seen(&self, worker: &str, now: i64, f: impl FnOnce(&mut WorkerSeen)) {
        on!(self, s => s.seen(worker, now, f))
    }

    /// The workers heard from at or after `since`, by name.
    pub async fn workers(&self, since: i64) -> Result<Vec<WorkerSeen>> {
        on!(self, s => s.workers(since).await)
    }

    /// Notes that `worker` said goodbye at `now` (it stops cleanly, its tiles given back),
    /// and writes the roster at once so that every process on the database lists it gone.
    pub async fn bye(&self, worker: &str, now: i64) {
        self.seen(worker, now, |w| w.left_at = now);
        on!(self, s => s.write_roster_now().await)
    }

    /// The leases that run past `now`: which worker holds which tile.
    pub async fn held(&self, now: i64) -> Result<Vec<HeldTile>> {
        on!(self, s => s.held(now).await)
    }

    /// Jobs by state and the tiles of active jobs waiting and leased, for the metrics.
    pub async fn counts(&self) -> Result<FarmCounts> {
        on!(self, s => s.counts().await)
    }

    /// Every tile of job `id` in index order, as users see it; `None` when there is no such
    /// job.
    pub async fn tiles(&self, id: &str) -> Result<Option<Vec<TileView>>> {
        on!(self, s => s.tiles(id).await)
    }

    /// The top rows of job `id`'s bands of tiles (tiles that share their top row and height
    /// and lie side by side), top to bottom.
    pub async fn bands(&self, id: &str) -> Result<Vec<u32>> {
        on!(self, s => s.bands(id).await)
    }

    /// The stored tiles of the band of rows starting at `y` of job `id` (its image
    /// `size`), left to right, their bytes appended to `buf` (cleared first). Read only:
    /// tiles whose pixels cannot be read are left out, not requeued ([`Store::band`] does
    /// that for the image).
    pub async fn stored_band(
        &self,
        id: &str,
        size: (u32, u32),
        y: u32,
        buf: &mut Vec<u8>,
    ) -> Result<Vec<BandTile>> {
        on!(self, s => s.stored_band(id, size, y, buf).await)
    }

    /// Sets a queued or running job's priority (claims serve the highest first).
    pub async fn set_priority(&self, id: &str, priority: i64) -> Result<Reprioritized> {
        on!(self, s => s.set_priority(id, priority).await)
    }

    /// The names of the workers heard from at or after `since`.
    pub async fn live_workers(&self, since: i64) -> Result<Vec<String>> {
        Ok(self
            .workers(since)
            .await?
            .into_iter()
            .map(|w| w.name)
            .collect())
    }
}
