//! The job queue on SQLite: jobs, their tiles under lease, results, failures, and the
//! assembled image, each operation one statement or one `BEGIN IMMEDIATE` transaction.
//!
//! The guarantees live here, in SQL guarded by state, not in the handlers:
//! - a claim is one `UPDATE … WHERE rowid = (SELECT … LIMIT 1) RETURNING …`, so two claimers
//!   can never take the same queued tile (SQLite runs one writer at a time, and the update
//!   re-checks nothing it did not select under that same write lock);
//! - every claim gets a fresh random lease token; renewals, results, failures and releases
//!   are applied only `WHERE lease = ?` and the tile is still leased, so a stale worker
//!   changes nothing;
//! - expired leases are requeued by [`Queue::reap`], counting a failure against the tile and
//!   the worker; a tile that fails `max_attempts` times fails its job with a readable reason.
//!
//! A database file keeps its tiles' pixels outside SQLite, in the spool beside it
//! ([`crate::spool`]); the `tile_pixels` rows say which tiles are done and hold the CRC of
//! their bytes. An in-memory database keeps the pixels in the rows.
//!
//! Times are integer milliseconds since the Unix epoch, passed in by the caller so that the
//! SQL stays portable and tests control the clock. This module knows nothing of HTTP.

use std::collections::{HashMap, HashSet};
use std::str::FromStr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use serde::Serialize;
use sqlx::pool::PoolConnection;
use sqlx::sqlite::{
    SqliteConnectOptions, SqliteConnection, SqliteJournalMode, SqlitePoolOptions, SqliteSynchronous,
};
use sqlx::{Connection, Row, Sqlite, SqlitePool};
use tessera_protocol::{Claim, JobSpec};
use tessera_tracer::Rect;
use tokio::sync::{Mutex, MutexGuard};

use crate::spool::{Spool, SpoolError};

/// The embedded migrations of the top-level `migrations/` folder.
static MIGRATOR: sqlx::migrate::Migrator = sqlx::migrate!("../migrations");

/// Errors of the queue's storage.
#[derive(Debug, thiserror::Error)]
pub enum QueueError {
    #[error("database: {0}")]
    Db(#[from] sqlx::Error),
    #[error("database migration: {0}")]
    Migrate(#[from] sqlx::migrate::MigrateError),
    #[error("bad database URL `{url}`: {reason}")]
    Url { url: String, reason: String },
    #[error(
        "cannot open the database `{url}`: {source} (its folder must exist and be writable, \
         and a file already there must be a Tessera queue)"
    )]
    Open { url: String, source: sqlx::Error },
    #[error("the database took no write within {0:?}")]
    WriteTimeout(Duration),
    #[error(transparent)]
    Spool(#[from] SpoolError),
    /// Spooled pixels of `tiles` tiles of `job` were missing or did not match their CRC:
    /// those tiles are queued again (see [`crate::spool`]).
    #[error("{tiles} tile(s) of job `{job}` lost their pixels and are rendered again")]
    Lost { job: String, tiles: usize },
}

type Result<T> = std::result::Result<T, QueueError>;

impl QueueError {
    /// Whether this is the storage failing (a full disk, an I/O error, a file gone
    /// read-only) rather than anything a request did: SQLite's `SQLITE_FULL`, `SQLITE_IOERR`
    /// (with its extended codes) and `SQLITE_READONLY`, or the tile spool's writes.
    pub fn is_storage(&self) -> bool {
        match self {
            QueueError::Db(sqlx::Error::Database(e)) => e
                .code()
                .and_then(|c| c.parse::<i32>().ok())
                .is_some_and(|c| matches!(c & 0xff, 8 | 10 | 13)),
            QueueError::Db(sqlx::Error::Io(_)) => true,
            QueueError::Spool(SpoolError::Io { .. } | SpoolError::Unwritable { .. }) => true,
            _ => false,
        }
    }
}

/// A job as users see it.
#[derive(Debug, Clone, Serialize, sqlx::FromRow)]
pub struct JobRow {
    pub id: String,
    pub state: String,
    pub name: Option<String>,
    pub width: i64,
    pub height: i64,
    pub tile: i64,
    pub sampler: Option<String>,
    pub samples: Option<i64>,
    pub threshold: Option<f64>,
    pub tiles_total: i64,
    pub tiles_done: i64,
    pub error: Option<String>,
    pub created_at: i64,
    pub started_at: Option<i64>,
    pub finished_at: Option<i64>,
    pub png_bytes: Option<i64>,
    /// Claims take tiles of the highest-priority job first (see [`Queue::claim`]).
    pub priority: i64,
}

const JOB_COLUMNS: &str = "id, state, name, width, height, tile, sampler, samples, threshold, \
     tiles_total, tiles_done, error, created_at, started_at, finished_at, png_bytes, priority";

/// A job about to be stored.
#[derive(Debug, Clone)]
pub struct NewJob {
    pub id: String,
    pub scene: String,
    pub name: Option<String>,
    pub width: u32,
    pub height: u32,
    pub tile: u32,
    pub sampler: Option<String>,
    pub samples: Option<u32>,
    pub threshold: Option<f64>,
    pub created_at: i64,
    /// Higher first; first in, first out among equals.
    pub priority: i64,
}

/// A tile's place and lease, with its job's state.
#[derive(Debug, Clone)]
pub struct TileInfo {
    pub rect: Rect,
    pub state: String,
    pub lease: Option<String>,
    pub worker: Option<String>,
    pub job_state: String,
}

/// What became of a posted result.
#[derive(Debug, Clone, PartialEq)]
pub enum Completion {
    /// Stored; `last` when it was the job's last tile (the image can be assembled). `worker`
    /// is the name the tile was claimed under.
    Stored { last: bool, worker: Option<String> },
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
    /// (see [`Queue::complete`]). Says why.
    Unstored(String),
}

/// How long after a tile's pixels could not be written the service hands out no work (see
/// [`Queue::storage_trouble`]): long enough that workers do not render tile after tile
/// that cannot be stored, short enough that a freed disk is noticed soon. A claim after it
/// hands out a tile again, whose result tries the spool again.
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

/// Tiles stored by one `INSERT` when a job is stored.
///
/// One statement per tile was one round trip to SQLite's thread per tile, inside the
/// transaction that holds the only writer: a 7680×4320 job in 8-pixel tiles (518,400 of
/// them) took 32 s to submit, and no claim or result of any other job was stored meanwhile.
const TILES_PER_INSERT: usize = 1000;

/// `INSERT INTO tiles … VALUES (?1, idx, x, y, w, h, 'queued'), …` for `rows`, numbered
/// from `first`, with the job id as the only parameter. The numbers are written into the
/// statement's text: they are integers this process computed (`Rect`'s `u32`s and the
/// index), never text from a request, so the text cannot carry anything else; binding them
/// instead would take six parameters a row, and SQLite allows 32,766 in all.
fn tile_insert(first: usize, rows: &[Rect]) -> String {
    use std::fmt::Write;
    let mut sql = String::with_capacity(64 + rows.len() * 48);
    sql.push_str("INSERT INTO tiles (job_id, idx, x, y, w, h, state) VALUES ");
    for (i, r) in rows.iter().enumerate() {
        if i > 0 {
            sql.push_str(", ");
        }
        // Writing to a `String` cannot fail.
        let _ = write!(
            sql,
            "(?1, {}, {}, {}, {}, {}, 'queued')",
            first + i,
            r.x,
            r.y,
            r.width,
            r.height
        );
    }
    sql
}

/// A band's stored tiles, left to right (see [`Queue::band`]).
const BAND_SQL: &str = "SELECT t.x, t.w, t.h, p.rgb, p.crc, t.idx FROM tiles t
     JOIN tile_pixels p ON p.job_id = t.job_id AND p.idx = t.idx
     WHERE t.job_id = ?1 AND t.y = ?2 ORDER BY t.idx";

/// A stored tile of a band, as [`Queue::band`] read it: its place and size, and where its
/// rows' bytes are in the band's buffer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BandTile {
    pub x: u32,
    pub w: u32,
    pub h: u32,
    pub bytes: std::ops::Range<usize>,
}

/// A leased tile whose lease ran out, as [`Queue::reap`] reads it.
#[derive(Debug, sqlx::FromRow)]
struct Expired {
    job_id: String,
    idx: i64,
    worker: Option<String>,
    lease_expires: i64,
    /// Its holder said it was rendering it (see [`Queue::renew`]).
    rendering: bool,
}

/// What [`Queue::cancel`] found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Cancel {
    /// No such job.
    Unknown,
    /// It was queued or running (`from`); now it is cancelled.
    Cancelled { from: String },
    /// Every tile is in (a done job, or a running one whose image is being written): not
    /// cancelled.
    Complete,
    /// It had already ended (failed or cancelled): nothing changed.
    Ended { state: String },
}

/// How long a statement waits for the writing connection before the queue answers "busy"
/// (sqlx's pool waited as long).
const WRITER_WAIT: Duration = Duration::from_secs(30);

/// The one writing connection, held by the queue rather than lent by a pool of one: each
/// statement takes it in turn (a fair lock: first come, first served, as the pool's
/// waiters were) and runs on it, and nothing else crosses to SQLite's thread. A pool
/// `ping`s its connection's thread whenever one is handed back (sqlx does so
/// unconditionally, in a task of its own), which was a second round trip to that thread,
/// and a task, for every statement: SQLite's threads switched 210 → 110 times per
/// 1920×1080 job at one ray per pixel once the connection was held.
#[derive(Debug)]
struct Writer {
    conn: Mutex<SqliteConnection>,
    /// To open a fresh connection in place of one left inside a transaction.
    opts: SqliteConnectOptions,
}

impl Writer {
    /// The connection, once the statements before have run. A connection still inside a
    /// transaction is closed and replaced first: a COMMIT that fails (a full disk) leaves
    /// sqlx counting a transaction that SQLite has already rolled back, and every later
    /// `BEGIN` on that connection failed ("non-zero transaction depth"), so the queue
    /// stayed broken after the disk had room again. (A transaction dropped unfinished, its
    /// request cancelled, may be counted until its rollback has run: the connection is
    /// then replaced needlessly, which costs an open.)
    async fn lock(&self) -> Result<MutexGuard<'_, SqliteConnection>> {
        let mut conn = tokio::time::timeout(WRITER_WAIT, self.conn.lock())
            .await
            .map_err(|_| QueueError::Db(sqlx::Error::PoolTimedOut))?;
        if conn.is_in_transaction() {
            tracing::warn!("the writing connection was left inside a transaction: reopening it");
            let fresh = SqliteConnection::connect_with(&self.opts).await?;
            let stale = std::mem::replace(&mut *conn, fresh);
            let _ = stale.close_hard().await;
        }
        Ok(conn)
    }
}

/// A reading connection: one of the pool's, or the writer's for an in-memory database.
enum Reader<'a> {
    Pool(PoolConnection<Sqlite>),
    Writer(MutexGuard<'a, SqliteConnection>),
}

impl std::ops::Deref for Reader<'_> {
    type Target = SqliteConnection;
    fn deref(&self) -> &SqliteConnection {
        match self {
            Reader::Pool(c) => c,
            Reader::Writer(c) => c,
        }
    }
}

impl std::ops::DerefMut for Reader<'_> {
    fn deref_mut(&mut self) -> &mut SqliteConnection {
        match self {
            Reader::Pool(c) => c,
            Reader::Writer(c) => c,
        }
    }
}

/// The queue over one SQLite database.
#[derive(Debug, Clone)]
pub struct Queue {
    /// Readers: several connections, which WAL lets read while the writer writes; `None`
    /// for an in-memory database, which exists on the writer's connection only.
    pool: Option<SqlitePool>,
    /// The one writing connection. SQLite admits one writer at a time; with writers on
    /// several connections, the losers of each race get `SQLITE_BUSY` and sleep in SQLite's
    /// busy handler (1, 2, 5, 10 … ms) even when the winner needs only microseconds, which
    /// under load left workers waiting milliseconds for claims. One connection makes writers
    /// queue for it instead, in order, and wake as soon as it is free (see [`Writer`]).
    writer: Arc<Writer>,
    /// Checkpoints the WAL off the writer; `None` for an in-memory database (no WAL).
    wal: Option<Arc<WalKeeper>>,
    /// Where tile pixels wait for their band (a file per job beside the database); `None`
    /// for an in-memory database, whose rows keep their pixels.
    spool: Option<Arc<Spool>>,
    /// The service's `--max-attempts`, for tiles whose pixels keep being lost (see
    /// [`Queue::requeue_lost`]); the other operations take it as an argument.
    max_attempts: u32,
    /// The lease and rectangle of each tile this process handed out and has not yet stored,
    /// by job and index: a result's pixels are written to the spool only under its tile's
    /// current lease and rectangle (see [`Queue::complete`]). After a restart the tile's row
    /// is read instead. Entries of ended jobs go with their spool files.
    issued: Arc<std::sync::Mutex<Issued>>,
    /// When a write last failed for the storage's sake ([`QueueError::is_storage`]), as
    /// noted by [`Queue::noted`].
    storage_failed: Arc<std::sync::Mutex<Option<std::time::Instant>>>,
    /// Leases whose renewal or result was refused lately for a failure of the service's,
    /// and when: see [`Queue::heard_refused`].
    heard: Arc<std::sync::Mutex<HashMap<String, std::time::Instant>>>,
}

/// Leases handed out and not yet stored: `(job, idx)` → `(lease, rectangle)`.
type Issued = HashMap<(String, u32), (String, Rect)>;

/// The most leases [`Queue::heard`] keeps at once (a worker holds two per render thread):
/// a few MB at most. Past it, a lease not yet heard from is not noted, and so is reaped as
/// it would be without the record if the storage fails while its lease runs out.
pub const HEARD_LEASES: usize = 1 << 16;

/// [`Queue::max_attempts`] until set: the service's default `--max-attempts`.
const DEFAULT_MAX_ATTEMPTS: u32 = 4;

/// Tile and image bytes written between two background checkpoints (see `WalKeeper`).
pub const CHECKPOINT_EVERY_BYTES: u64 = 48 << 20;

/// WAL pages (of 4 KB) after which the writer checkpoints by itself, should the background
/// checkpoints fall behind. A background checkpoint starts at about 16,000 pages (the
/// pixels and the pages around them), and one WAL that missed starting over (a reader was
/// in it at that moment) reaches about 32,000 by the next: three times the pixels' pages
/// stays above both.
const WRITER_CHECKPOINT_PAGES: u64 = 3 * (CHECKPOINT_EVERY_BYTES >> 12);

/// Background checkpoints: the WAL's pages are copied into the database file by a reading
/// connection while the writer goes on writing.
///
/// SQLite's automatic checkpoint runs on the connection that commits past the threshold,
/// inside that statement: it copies the WAL's pages and `fsync`s the WAL and the database.
/// On the one writer, that held every claim and result of every job for the copy and both
/// `fsync`s: 70–100 ms, five times in forty 1920×1080 jobs, during which workers ran out of
/// tiles (sqlx's statement log). A `PASSIVE` checkpoint from another connection does the
/// same work while the writer goes on appending: SQLite's WAL lets one checkpointer and
/// one writer run at once. Only a last, short pass runs on the writer, for the pages
/// appended meanwhile (1–13 ms in the same forty jobs): with every page copied, SQLite
/// starts the WAL over at the next write instead of letting it grow. The writer keeps an
/// automatic checkpoint as a backstop, at [`WRITER_CHECKPOINT_PAGES`], which it reaches
/// only if these fall behind.
#[derive(Debug)]
struct WalKeeper {
    /// Bytes of tile pixels and image stored since the last checkpoint began.
    written: AtomicU64,
    /// A checkpoint is under way (at most one at a time).
    running: AtomicBool,
    /// Checkpoints finished, for tests to wait on.
    done: tokio::sync::watch::Sender<u64>,
    every: u64,
}

impl WalKeeper {
    fn new(every: u64, done: tokio::sync::watch::Sender<u64>) -> Arc<WalKeeper> {
        Arc::new(WalKeeper {
            written: AtomicU64::new(0),
            running: AtomicBool::new(false),
            done,
            every,
        })
    }
}

/// What a checkpoint did, in WAL frames (pages).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Checkpoint {
    /// Frames in the WAL.
    pub log: i64,
    /// Frames of it now copied into the database file.
    pub copied: i64,
}

/// The claim: the first queued tile (by index) of the first active job (by priority, then
/// submission) that has one the worker may take. Its job is found through `jobs_to_claim`
/// (migration 0009), which holds only the active jobs, in that order, so the walk stops at
/// the first job that qualifies. Named, because SQLite's planner preferred `jobs_by_state`
/// and then sorted every active job, checking each for a tile, on every claim. The claim
/// stamps `claimed_at` with the queue's clock, which the `job_started` trigger (migration
/// 0010) copies into a queued job's `started_at` as it marks the job running, inside this
/// statement.
const CLAIM_SQL: &str =
    "UPDATE tiles SET state = 'leased', attempt = attempt + 1, lease = ?2, worker = ?1,
                   lease_expires = ?3, rendering = 0, claimed_at = ?4
  WHERE rowid = (
      SELECT t.rowid FROM tiles t
      WHERE t.job_id = (
          SELECT j.id FROM jobs j INDEXED BY jobs_to_claim
          WHERE j.state IN ('queued', 'running')
            AND NOT EXISTS (SELECT 1 FROM keep_away k
                            WHERE k.job_id = j.id AND k.worker = ?1 AND k.until > ?4)
            AND EXISTS (SELECT 1 FROM tiles q
                        WHERE q.job_id = j.id AND q.state = 'queued' AND q.failures < ?5)
          ORDER BY j.priority DESC, j.seq LIMIT 1)
        AND t.state = 'queued' AND t.failures < ?5
      ORDER BY t.idx LIMIT 1)
  RETURNING job_id, idx, x, y, w, h";

/// Whether `url` can name a SQLite database: `sqlite:` or no scheme at all (a bare path),
/// but not a SQLite URI file name (`file:…`, see [`Queue::open`]).
pub fn is_sqlite(url: &str) -> bool {
    !is_uri_file_name(url)
        && url
            .split_once("://")
            .is_none_or(|(scheme, _)| scheme == "sqlite")
}

/// A SQLite URI file name (`file:f.db`, `sqlite:file:f.db?mode=rwc`): SQLite opens the file
/// it names (`f.db`), while the service's lock and tile spool would be named after the
/// whole text (`file:f.db-service.lock`), so a second service could open the same database
/// as `f.db`.
fn is_uri_file_name(url: &str) -> bool {
    let name = url.strip_prefix("sqlite:").unwrap_or(url);
    name.trim_start_matches('/').starts_with("file:")
}

impl Queue {
    /// Opens (creating if missing) the database at `url` (`sqlite://path`, or
    /// `sqlite::memory:`) and brings its schema up to date.
    pub async fn open(url: &str) -> Result<Queue> {
        // sqlx reads any other scheme as a file name ("unable to open database file"). A bare
        // path (`tessera.db`) is a SQLite file, as it always was.
        if is_uri_file_name(url) {
            return Err(QueueError::Url {
                url: url.to_string(),
                reason: "SQLite URI file names (`file:…`) are not taken: give the file as \
                         sqlite://PATH or a plain path"
                    .into(),
            });
        }
        if !is_sqlite(url) {
            return Err(QueueError::Url {
                url: url.to_string(),
                reason: "the queue is SQLite only: give sqlite://PATH (for example \
                         sqlite://tessera.db, or sqlite:///var/lib/tessera/queue.db)"
                    .into(),
            });
        }
        let opts = SqliteConnectOptions::from_str(url)
            .map_err(|e| QueueError::Url {
                url: url.to_string(),
                reason: e.to_string(),
            })?
            .create_if_missing(true)
            // WAL: readers (job lists, downloads) never block the writer, nor it them.
            .journal_mode(SqliteJournalMode::Wal)
            // NORMAL in WAL mode loses at most the last commits on power loss, never
            // consistency; FULL would fsync on every claim.
            .synchronous(SqliteSynchronous::Normal)
            .busy_timeout(Duration::from_secs(10))
            .foreign_keys(true);
        let in_memory = url.contains(":memory:");
        // Beside the database file, so opened only once that file is (its folder exists).
        let spool_dir = (!in_memory).then(|| crate::spool::folder_for(opts.get_filename()));
        if let Some(dir) = &spool_dir {
            crate::spool::check_folder(dir)?;
        }
        // The readers' pool (the writer's connection is held: see [`Writer`]).
        let connect = |n: u32, opts: SqliteConnectOptions| {
            SqlitePoolOptions::new()
                .max_connections(n)
                .min_connections(1)
                .idle_timeout(None)
                .max_lifetime(None)
                // No `ping` before each use: sqlx's default sends one to the connection's
                // thread and waits for the answer before every statement, a thread round
                // trip that tells nothing about a file opened in this process. Without it,
                // SQLite's threads switch a third less often (310 → 210 times per 1920×1080
                // job at one ray per pixel; the CPU saved was within the noise).
                .test_before_acquire(false)
                // A connection that comes back still inside a transaction is closed, not
                // reused. A COMMIT that fails (a full disk) leaves sqlx counting a
                // transaction that SQLite has already rolled back, and every later `BEGIN`
                // on that connection failed ("non-zero transaction depth"): the queue
                // stayed broken after the disk had room again.
                .after_release(|conn, _| {
                    Box::pin(async move { Ok(!sqlx::Connection::is_in_transaction(&*conn)) })
                })
                .connect_with(opts)
        };
        // The writer's connection keeps
        // - 16 MB of pages (SQLite's default is 2 MB): enough to still hold the tiles of a
        //   band when the band is read back for the PNG (see `band`);
        // - its automatic checkpoint only as a backstop ([`WalKeeper`] checkpoints off the
        //   writer, every 48 MB of pixels, instead of SQLite's every 1,000 pages). Tile
        //   pixels fill pages that are freed when their job's image is done and then reused
        //   by the next jobs' tiles; each checkpoint copies a page into the database file
        //   once however often it was rewritten since the last, so checkpointing once per
        //   several jobs instead of several times per job copies far less (checkpoints were
        //   a sixth of SQLite's time on a 1920×1080 job, `perf`). The cost: a WAL file of
        //   about 64 MB (at most about 150 MB) beside the database.
        let writer_opts = opts
            .clone()
            .pragma("cache_size", "-16384")
            .pragma("wal_autocheckpoint", WRITER_CHECKPOINT_PAGES.to_string());
        // Migrated through a pool of its one connection, which is then taken out of it
        // (an in-memory database lives on that connection only).
        let migrating = SqlitePoolOptions::new()
            .max_connections(1)
            .connect_with(writer_opts.clone())
            .await
            .map_err(|source| QueueError::Open {
                url: url.to_string(),
                source,
            })?;
        MIGRATOR.run(&migrating).await?;
        let conn = migrating.acquire().await?.detach();
        migrating.close().await;
        let writer = Arc::new(Writer {
            conn: Mutex::new(conn),
            opts: writer_opts,
        });
        let spool = match spool_dir {
            Some(dir) => Some(Arc::new(Spool::open(dir)?)),
            None => None,
        };
        // An in-memory database exists once per connection: it has only the writer's.
        let pool = if in_memory {
            None
        } else {
            Some(connect(8, opts).await?)
        };
        let wal = (!in_memory)
            .then(|| WalKeeper::new(CHECKPOINT_EVERY_BYTES, tokio::sync::watch::Sender::new(0)));
        Ok(Queue {
            pool,
            writer,
            wal,
            spool,
            max_attempts: DEFAULT_MAX_ATTEMPTS,
            issued: Arc::default(),
            storage_failed: Arc::default(),
            heard: Arc::default(),
        })
    }

    /// The same queue, failing a job whose tile lost its pixels `n` times (the service's
    /// `--max-attempts`; 4 until set).
    pub fn max_attempts(mut self, n: u32) -> Queue {
        self.max_attempts = n;
        self
    }

    /// The same queue, checkpointing after every `bytes` of tiles and images instead of
    /// [`CHECKPOINT_EVERY_BYTES`] (tests).
    pub fn checkpoint_every(mut self, bytes: u64) -> Queue {
        if let Some(w) = &self.wal {
            self.wal = Some(WalKeeper::new(bytes, w.done.clone()));
        }
        self
    }

    /// Copies the WAL's committed pages into the database file, from a reading connection
    /// and without blocking the writer (`PASSIVE`). Pages the writer appends meanwhile wait
    /// for the next checkpoint. `None` for an in-memory database.
    pub async fn checkpoint(&self) -> Result<Option<Checkpoint>> {
        if self.wal.is_none() {
            return Ok(None);
        }
        self.checkpoint_on(false).await.map(Some)
    }

    async fn checkpoint_on(&self, writer: bool) -> Result<Checkpoint> {
        let mut conn = if writer {
            Reader::Writer(self.writer.lock().await?)
        } else {
            self.reader().await?
        };
        let (_busy, log, copied): (i64, i64, i64) =
            sqlx::query_as("PRAGMA wal_checkpoint(PASSIVE)")
                .fetch_one(&mut *conn)
                .await?;
        Ok(Checkpoint { log, copied })
    }

    /// Background checkpoints finished so far, as a watch (tests wait on it).
    pub fn checkpoints(&self) -> Option<tokio::sync::watch::Receiver<u64>> {
        self.wal.as_ref().map(|w| w.done.subscribe())
    }

    /// Counts `bytes` written to the WAL and, past the threshold, starts a background
    /// checkpoint unless one is under way.
    fn wrote(&self, bytes: usize) {
        let Some(w) = &self.wal else { return };
        let total = w.written.fetch_add(bytes as u64, Ordering::Relaxed) + bytes as u64;
        if total < w.every || w.running.swap(true, Ordering::AcqRel) {
            return;
        }
        w.written.store(0, Ordering::Relaxed);
        let (queue, keeper) = (self.clone(), w.clone());
        tokio::spawn(async move {
            // A pass copies what was committed when it began; the writer appends more
            // meanwhile (a few hundred pages during a first pass of 16,000, fewer during
            // the second). Two passes on a reading connection, then a last one on the
            // writer, which nothing can write under: it leaves every page copied, and
            // SQLite starts the WAL over from its beginning at the next write (it does so
            // only when no page is left to copy).
            for on_writer in [false, false, true] {
                let t = std::time::Instant::now();
                match queue.checkpoint_on(on_writer).await {
                    Ok(c) => tracing::debug!(
                        log = c.log,
                        copied = c.copied,
                        on_writer,
                        us = t.elapsed().as_micros() as u64,
                        "WAL checkpoint"
                    ),
                    Err(e) => {
                        tracing::warn!("WAL checkpoint: {e}");
                        break;
                    }
                }
            }
            keeper.running.store(false, Ordering::Release);
            keeper.done.send_modify(|n| *n += 1);
        });
    }

    /// A reading connection (see [`Reader`]).
    async fn reader(&self) -> Result<Reader<'_>> {
        Ok(match &self.pool {
            Some(pool) => Reader::Pool(pool.acquire().await?),
            None => Reader::Writer(self.writer.lock().await?),
        })
    }

    /// Answers when the database does.
    pub async fn ping(&self) -> Result<()> {
        sqlx::query("SELECT 1")
            .execute(&mut *self.reader().await?)
            .await?;
        Ok(())
    }

    /// Rewrites the health row on the writing connection: whether the database takes a
    /// write now, within `within` (the writer may be behind a lock held elsewhere); and
    /// writes a file in the tile spool's folder.
    pub async fn probe_write(&self, now: i64, within: Duration) -> Result<()> {
        let write = async {
            sqlx::query(
                "INSERT INTO health (id, checked_at) VALUES (1, ?1)
                 ON CONFLICT (id) DO UPDATE SET checked_at = excluded.checked_at",
            )
            .bind(now)
            .execute(&mut *self.writer.lock().await?)
            .await
            .map_err(QueueError::from)
        };
        match tokio::time::timeout(within, write).await {
            Ok(done) => done.map(|_| ())?,
            Err(_) => return Err(QueueError::WriteTimeout(within)),
        }
        // And tile pixels can be stored.
        if let Some(spool) = &self.spool {
            spool.probe()?;
        }
        Ok(())
    }

    /// Stores a job, its tiles and its assets in one transaction.
    pub async fn insert_job(
        &self,
        job: &NewJob,
        tiles: &[Rect],
        assets: &[(String, Vec<u8>)],
    ) -> Result<JobRow> {
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        sqlx::query(
            "INSERT INTO jobs (id, seq, state, name, width, height, tile, sampler, samples,
                               threshold, tiles_total, created_at, priority)
             VALUES (?1, (SELECT COALESCE(MAX(seq), 0) + 1 FROM jobs), 'queued', ?2, ?3, ?4,
                     ?5, ?6, ?7, ?8, ?9, ?10, ?11)",
        )
        .bind(&job.id)
        .bind(&job.name)
        .bind(i64::from(job.width))
        .bind(i64::from(job.height))
        .bind(i64::from(job.tile))
        .bind(&job.sampler)
        .bind(job.samples.map(i64::from))
        .bind(job.threshold)
        .bind(tiles.len() as i64)
        .bind(job.created_at)
        .bind(job.priority)
        .execute(&mut *tx)
        .await?;
        sqlx::query("INSERT INTO job_scenes (job_id, scene) VALUES (?1, ?2)")
            .bind(&job.id)
            .bind(&job.scene)
            .execute(&mut *tx)
            .await?;
        for (chunk, rows) in tiles.chunks(TILES_PER_INSERT).enumerate() {
            sqlx::query(sqlx::AssertSqlSafe(tile_insert(
                chunk * TILES_PER_INSERT,
                rows,
            )))
            // Text of its own for every job: kept out of the writer's cache of prepared
            // statements (a hundred), where it pushed out the claim's and the result's.
            .persistent(false)
            .bind(&job.id)
            .execute(&mut *tx)
            .await?;
        }
        for (name, bytes) in assets {
            sqlx::query("INSERT INTO assets (job_id, name, bytes) VALUES (?1, ?2, ?3)")
                .bind(&job.id)
                .bind(name)
                .bind(bytes)
                .execute(&mut *tx)
                .await?;
        }
        tx.commit().await?;
        // The reading below may be on the writer's connection (an in-memory database).
        drop(conn);
        // The scene and textures went into the WAL too: a few 64 MiB submissions left it at
        // 200 MB when only pixels counted towards the next checkpoint.
        self.wrote(job.scene.len() + assets.iter().map(|(_, b)| b.len()).sum::<usize>());
        self.job(&job.id).await?.ok_or_else(|| {
            QueueError::Db(sqlx::Error::Protocol("job vanished after insert".into()))
        })
    }

    /// Jobs, newest first: at most `limit`, and with `before`, only those submitted before
    /// that job (a page after the one that ended with it). `None` when `before` names no job.
    pub async fn jobs(&self, limit: u32, before: Option<&str>) -> Result<Option<Vec<JobRow>>> {
        let below = match before {
            None => i64::MAX,
            Some(id) => {
                let seq: Option<i64> = sqlx::query_scalar("SELECT seq FROM jobs WHERE id = ?1")
                    .bind(id)
                    .fetch_optional(&mut *self.reader().await?)
                    .await?;
                let Some(seq) = seq else { return Ok(None) };
                seq
            }
        };
        let sql =
            format!("SELECT {JOB_COLUMNS} FROM jobs WHERE seq < ?2 ORDER BY seq DESC LIMIT ?1");
        Ok(Some(
            sqlx::query_as(sqlx::AssertSqlSafe(sql))
                .bind(i64::from(limit))
                .bind(below)
                .fetch_all(&mut *self.reader().await?)
                .await?,
        ))
    }

    pub async fn job(&self, id: &str) -> Result<Option<JobRow>> {
        let sql = format!("SELECT {JOB_COLUMNS} FROM jobs WHERE id = ?1");
        Ok(sqlx::query_as(sqlx::AssertSqlSafe(sql))
            .bind(id)
            .fetch_optional(&mut *self.reader().await?)
            .await?)
    }

    /// Cancels a queued or running job (its tiles are no longer handed out and results for
    /// it are refused) and drops its partial pixels and image (by the migrations' trigger),
    /// unless every tile is already in: then the job is as good as done (its image is being
    /// written), and throwing the pixels away would lose a finished render that a worker was
    /// told was stored.
    pub async fn cancel(&self, id: &str, now: i64) -> Result<Cancel> {
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        let before: Option<(String, i64, i64)> =
            sqlx::query_as("SELECT state, tiles_done, tiles_total FROM jobs WHERE id = ?1")
                .bind(id)
                .fetch_optional(&mut *tx)
                .await?;
        let outcome = match before {
            None => Cancel::Unknown,
            Some((_, done, total)) if done >= total => Cancel::Complete,
            Some((from, _, _)) if matches!(from.as_str(), "queued" | "running") => {
                // The `job_ended_without_image` trigger drops its pixels and image chunks.
                sqlx::query("UPDATE jobs SET state = 'cancelled', finished_at = ?2 WHERE id = ?1")
                    .bind(id)
                    .bind(now)
                    .execute(&mut *tx)
                    .await?;
                Cancel::Cancelled { from }
            }
            Some((state, _, _)) => Cancel::Ended { state },
        };
        tx.commit().await?;
        drop(conn);
        if let Cancel::Cancelled { .. } = outcome {
            self.forget_job(id);
        }
        Ok(outcome)
    }

    /// Removes a finished job and everything stored for it.
    pub async fn delete(&self, id: &str) -> Result<bool> {
        let r = sqlx::query("DELETE FROM jobs WHERE id = ?1")
            .bind(id)
            .execute(&mut *self.writer.lock().await?)
            .await?;
        self.forget_job(id);
        Ok(r.rows_affected() > 0)
    }

    /// Hands the first queued tile of the first active job (the highest priority, then the
    /// oldest) to `worker` under a new lease, unless the worker is kept away from that job. One statement: see the module comment.
    /// The job is chosen first and its tile second, so that both steps walk an index in
    /// order (`jobs_to_claim`, `tiles_by_state`) instead of sorting every queued tile of
    /// every job on each claim.
    pub async fn claim(
        &self,
        worker: &str,
        now: i64,
        lease_ms: u64,
        max_attempts: u32,
    ) -> Result<Option<Claim>> {
        let lease = uuid::Uuid::new_v4().simple().to_string();
        let row = sqlx::query(CLAIM_SQL)
            .bind(worker)
            .bind(&lease)
            .bind(now.saturating_add(lease_ms as i64))
            .bind(now)
            .bind(i64::from(max_attempts))
            // To the statement's end, not its first row: SQLite commits an autocommit statement
            // when it finishes, and a commit that fails (a full disk) must be this call's error,
            // not lost in a reset after the row was taken (the claim was answered with a lease
            // that was never stored).
            .fetch_all(&mut *self.writer.lock().await?)
            .await?
            .into_iter()
            .next();
        let Some(row) = row else { return Ok(None) };
        let claim = Claim {
            job: row.try_get(0)?,
            idx: row.try_get::<i64, _>(1)? as u32,
            x: row.try_get::<i64, _>(2)? as u32,
            y: row.try_get::<i64, _>(3)? as u32,
            w: row.try_get::<i64, _>(4)? as u32,
            h: row.try_get::<i64, _>(5)? as u32,
            lease,
            lease_ms,
        };
        if self.spool.is_some() {
            self.issued_map().insert(
                (claim.job.clone(), claim.idx),
                (claim.lease.clone(), claim.rect()),
            );
        }
        Ok(Some(claim))
    }

    /// Extends a lease that is still current; returns its worker's name, `None` if stale.
    /// `rendering`: the worker says it is rendering the tile, not holding it ahead (kept
    /// until the tile is handed out again; see [`Queue::reap`]).
    pub async fn renew(
        &self,
        job: &str,
        idx: u32,
        lease: &str,
        now: i64,
        lease_ms: u64,
        rendering: bool,
    ) -> Result<Option<String>> {
        let worker: Option<Option<String>> = sqlx::query_scalar(
            "UPDATE tiles SET lease_expires = ?4, rendering = MAX(rendering, ?5)
             WHERE job_id = ?1 AND idx = ?2 AND lease = ?3 AND state = 'leased'
               AND EXISTS (SELECT 1 FROM jobs WHERE id = ?1 AND state IN ('queued', 'running'))
             RETURNING worker",
        )
        .bind(job)
        .bind(i64::from(idx))
        .bind(lease)
        .bind(now.saturating_add(lease_ms as i64))
        .bind(i64::from(rendering))
        // To the statement's end, not its first row: SQLite commits an autocommit statement
        // when it finishes, and a commit that fails (a full disk) must be this call's error,
        // not lost in a reset after the row was taken (the claim was answered with a lease
        // that was never stored).
        .fetch_all(&mut *self.writer.lock().await?)
        .await?
        .into_iter()
        .next();
        Ok(worker.map(Option::unwrap_or_default))
    }

    /// A tile's rectangle, state and lease, with its job's state.
    pub async fn tile(&self, job: &str, idx: u32) -> Result<Option<TileInfo>> {
        let row = sqlx::query(
            "SELECT t.x, t.y, t.w, t.h, t.state, t.lease, j.state, t.worker FROM tiles t
             JOIN jobs j ON j.id = t.job_id WHERE t.job_id = ?1 AND t.idx = ?2",
        )
        .bind(job)
        .bind(i64::from(idx))
        .fetch_optional(&mut *self.reader().await?)
        .await?;
        let Some(row) = row else { return Ok(None) };
        let u = |i: usize| row.try_get::<i64, _>(i).map(|v| v as u32);
        Ok(Some(TileInfo {
            rect: Rect::new(u(0)?, u(1)?, u(2)?, u(3)?),
            state: row.try_get(4)?,
            lease: row.try_get(5)?,
            job_state: row.try_get(6)?,
            worker: row.try_get(7)?,
        }))
    }

    /// Stores a tile's pixels if `lease` is its current lease, its job is active and `rect`
    /// (what the blob says it holds; `rgb` has been checked against it) is the tile's.
    ///
    /// One statement, so one round trip to the writing connection: the insert happens only
    /// `WHERE` all of that holds, and the `tile_pixels_stored` trigger (migration 0002) marks
    /// the tile done and counts it in its job within the same statement. Only when nothing
    /// was stored does a second query find out why.
    pub async fn complete(
        &self,
        job: &str,
        idx: u32,
        lease: &str,
        rect: Rect,
        rgb: &[u8],
    ) -> Result<Completion> {
        // Spooled, the pixels are written first (see `spool.rs`) and the row gets their CRC,
        // but only under the tile's current lease and for its own rectangle: any other post
        // (stale, foreign, for another tile, or for a job that has ended) writes nothing, so
        // that it cannot touch the pixels of tiles already stored.
        let (blob, crc): (&[u8], Option<i64>) = match &self.spool {
            None => (rgb, None),
            Some(spool) => match self.spooled_size(spool, job).await? {
                Some((width, height)) if self.holds(job, idx, lease, rect).await? => {
                    match spool.write(job, width, height, rect, rgb) {
                        Ok(crc) => (&[], Some(i64::from(crc))),
                        Err(SpoolError::Outside { .. }) => (&[], None),
                        Err(e) if e.is_capacity() => {
                            // A full disk: the service's trouble, and it passes. The tile
                            // goes back to the queue uncharged, rather than wait for its
                            // lease to run out and count against the worker (whose job
                            // would fail, blaming workers, after `--max-attempts` such
                            // posts). With the database on the same full disk the requeue
                            // may fail too: then the tile stays leased, and the reaper
                            // extends the leases of workers it hears from while it fails.
                            let e = QueueError::from(e);
                            if let Err(requeue) = self.release(job, idx, lease).await {
                                tracing::error!(
                                    job,
                                    tile = idx,
                                    "cannot store the tile's pixels ({e}), nor queue it again: {requeue}"
                                );
                                return Err(self.noted(requeue));
                            }
                            tracing::error!(
                                job,
                                tile = idx,
                                "cannot store the tile's pixels, queued again: {e}"
                            );
                            return Ok(Completion::Unstored(e.to_string()));
                        }
                        Err(e) => {
                            // Any other failure (an I/O error, a file that cannot be
                            // written) may not pass: the tile is queued again with a failure
                            // counted against it, not the worker, as a lost tile is, so that
                            // a disk that keeps failing fails the job with the reason after
                            // `--max-attempts` instead of rendering the tile for ever.
                            tracing::error!(
                                job,
                                tile = idx,
                                "cannot store the tile's pixels, queued again with a failure: {e}"
                            );
                            let reason = format!("its pixels could not be stored: {e}");
                            self.requeue_unstored(job, idx, lease, &reason, crate::now_ms())
                                .await?;
                            return Ok(Completion::Unstored(e.to_string()));
                        }
                    }
                }
                _ => (&[], None),
            },
        };
        let spooled = self.spool.is_some();
        let stored: Option<(i64, i64, Option<String>)> = if spooled && crc.is_none() {
            None
        } else {
            self.insert_result(job, idx, lease, rect, blob, crc).await?
        };
        if let Some((done_before, total, worker)) = stored {
            if spooled {
                self.forget_lease(job, idx);
            } else {
                self.wrote(rgb.len());
            }
            // `RETURNING` is computed before the trigger counts this tile (see the migration).
            return Ok(Completion::Stored {
                last: done_before + 1 == total,
                worker,
            });
        }
        let Some(tile) = self.tile(job, idx).await? else {
            return Ok(Completion::Missing);
        };
        Ok(
            if tile.state == "done" && tile.lease.as_deref() == Some(lease) {
                Completion::Repeat
            } else if !matches!(tile.job_state.as_str(), "queued" | "running") {
                Completion::Stale(format!("the job is {}", tile.job_state))
            } else if tile.lease.as_deref() != Some(lease) || tile.state != "leased" {
                Completion::Stale(
                    "this lease is no longer current (it expired or was given back)".into(),
                )
            } else {
                Completion::WrongTile(tile.rect)
            },
        )
    }

    fn issued_map(&self) -> std::sync::MutexGuard<'_, Issued> {
        self.issued
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Forgets the lease this process handed out for tile `idx` of `job` (stored, given
    /// back, or queued again): a later post under it writes nothing to the spool.
    fn forget_lease(&self, job: &str, idx: u32) {
        self.issued_map().remove(&(job.to_string(), idx));
    }

    /// Whether `lease` is tile `idx`'s current lease and `rect` its rectangle: as this
    /// process handed it out, or else (after a restart) as its row says.
    async fn holds(&self, job: &str, idx: u32, lease: &str, rect: Rect) -> Result<bool> {
        let issued = self.issued_map().get(&(job.to_string(), idx)).cloned();
        if let Some((current, tile)) = issued {
            return Ok(current == lease && tile == rect);
        }
        Ok(self.tile(job, idx).await?.is_some_and(|t| {
            t.state == "leased" && t.lease.as_deref() == Some(lease) && t.rect == rect
        }))
    }

    /// Drops what this process keeps of an ended (or deleted) job: its spool file and the
    /// leases it handed out.
    fn forget_job(&self, id: &str) {
        if let Some(spool) = &self.spool {
            spool.remove(id);
            self.issued_map().retain(|(job, _), _| job != id);
        }
    }

    /// The image size of job `id`, for its spool file: remembered by the spool once the
    /// file is open, read from the job's row the first time. `None`: no such job, or it
    /// has ended (nothing of it is written any more).
    async fn spooled_size(&self, spool: &Spool, id: &str) -> Result<Option<(u32, u32)>> {
        if let Some(size) = spool.size_of(id) {
            return Ok(Some(size));
        }
        let row: Option<(i64, i64)> = sqlx::query_as(
            "SELECT width, height FROM jobs WHERE id = ?1 AND state IN ('queued', 'running')",
        )
        .bind(id)
        .fetch_optional(&mut *self.reader().await?)
        .await?;
        Ok(row.map(|(w, h)| (w as u32, h as u32)))
    }

    /// The result's one statement: see [`Queue::complete`].
    async fn insert_result(
        &self,
        job: &str,
        idx: u32,
        lease: &str,
        rect: Rect,
        blob: &[u8],
        crc: Option<i64>,
    ) -> Result<Option<(i64, i64, Option<String>)>> {
        Ok(sqlx::query_as(
            "INSERT INTO tile_pixels (job_id, idx, rgb, crc)
             SELECT ?1, ?2, ?4, ?9 WHERE EXISTS (
                 SELECT 1 FROM tiles t JOIN jobs j ON j.id = t.job_id
                 WHERE t.job_id = ?1 AND t.idx = ?2 AND t.lease = ?3 AND t.state = 'leased'
                   AND t.x = ?5 AND t.y = ?6 AND t.w = ?7 AND t.h = ?8
                   AND j.state IN ('queued', 'running'))
             RETURNING (SELECT tiles_done FROM jobs WHERE id = ?1),
                       (SELECT tiles_total FROM jobs WHERE id = ?1),
                       (SELECT worker FROM tiles WHERE job_id = ?1 AND idx = ?2)",
        )
        .bind(job)
        .bind(i64::from(idx))
        .bind(lease)
        .bind(blob)
        .bind(i64::from(rect.x))
        .bind(i64::from(rect.y))
        .bind(i64::from(rect.width))
        .bind(i64::from(rect.height))
        .bind(crc)
        // To the statement's end, not its first row: SQLite commits an autocommit statement
        // when it finishes, and a commit that fails (a full disk) must be this call's error,
        // not lost in a reset after the row was taken (the claim was answered with a lease
        // that was never stored).
        .fetch_all(&mut *self.writer.lock().await?)
        .await?
        .into_iter()
        .next())
    }

    /// A worker reports that it cannot render a tile: requeue it with one more failure,
    /// count the failure against the worker (keeping it away from the job past the policy's
    /// limit) and fail the job if the tile is out of attempts. False when the lease is stale.
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
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        let r = sqlx::query(
            "UPDATE tiles SET state = 'queued', lease = NULL, worker = NULL, lease_expires = NULL,
                              failures = failures + 1, last_error = ?4
             WHERE job_id = ?1 AND idx = ?2 AND lease = ?3 AND state = 'leased'
               AND EXISTS (SELECT 1 FROM jobs WHERE id = ?1 AND state IN ('queued', 'running'))",
        )
        .bind(job)
        .bind(i64::from(idx))
        .bind(lease)
        .bind(format!("worker {worker}: {reason}"))
        .execute(&mut *tx)
        .await?;
        if r.rows_affected() == 0 {
            tx.rollback().await?;
            return Ok(false);
        }
        sqlx::query(
            "INSERT INTO keep_away (job_id, worker, failures, until) VALUES (?1, ?2, 1, 0)
             ON CONFLICT (job_id, worker) DO UPDATE SET failures = failures + 1",
        )
        .bind(job)
        .bind(worker)
        .execute(&mut *tx)
        .await?;
        Self::apply_keep_away(&mut tx, now, keep).await?;
        Self::fail_exhausted(&mut tx, now, max_attempts).await?;
        tx.commit().await?;
        Ok(true)
    }

    /// Gives a tile back unrendered (a worker shutting down): no failure is counted.
    pub async fn release(&self, job: &str, idx: u32, lease: &str) -> Result<bool> {
        let r = sqlx::query(
            "UPDATE tiles SET state = 'queued', lease = NULL, worker = NULL, lease_expires = NULL
             WHERE job_id = ?1 AND idx = ?2 AND lease = ?3 AND state = 'leased'
               AND EXISTS (SELECT 1 FROM jobs WHERE id = ?1 AND state IN ('queued', 'running'))",
        )
        .bind(job)
        .bind(i64::from(idx))
        .bind(lease)
        .execute(&mut *self.writer.lock().await?)
        .await?;
        let released = r.rows_affected() == 1;
        if released {
            // The lease is no longer current: a late post under it writes nothing.
            self.forget_lease(job, idx);
        }
        Ok(released)
    }

    /// Passes `e` through, noting when it is the database's storage failing (a full disk
    /// under it): renewals may be refused then, so the reaper gives the leases of workers
    /// it hears from a fresh term instead of reaping them ([`Queue::storage_failed_within`],
    /// [`Queue::reap_unheard`]). The spool's own failures
    /// refuse no renewal (and their tiles are queued again at once), so they do not count.
    pub fn noted(&self, e: QueueError) -> QueueError {
        if matches!(e, QueueError::Db(_)) && e.is_storage() {
            *self
                .storage_failed
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner) =
                Some(std::time::Instant::now());
        }
        e
    }

    /// Whether a database write failed for the storage's sake less than `within` ago (as
    /// [`Queue::noted`]): renewals may have been refused meanwhile, so the leases of workers
    /// that asked and were refused ran out through no fault of theirs.
    pub fn storage_failed_within(&self, within: Duration) -> bool {
        let noted = *self
            .storage_failed
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        noted.is_some_and(|at| at.elapsed() < within)
    }

    /// Queues tile `idx` again, under `lease`, with a failure counted against the tile
    /// alone (its pixels could not be stored for a reason that may not pass), failing the
    /// job if the tile is out of attempts.
    async fn requeue_unstored(
        &self,
        job: &str,
        idx: u32,
        lease: &str,
        reason: &str,
        now: i64,
    ) -> Result<()> {
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        let r = sqlx::query(
            "UPDATE tiles SET state = 'queued', lease = NULL, worker = NULL,
                    lease_expires = NULL, rendering = 0, failures = failures + 1,
                    last_error = ?4
             WHERE job_id = ?1 AND idx = ?2 AND lease = ?3 AND state = 'leased'
               AND EXISTS (SELECT 1 FROM jobs WHERE id = ?1 AND state IN ('queued', 'running'))",
        )
        .bind(job)
        .bind(i64::from(idx))
        .bind(lease)
        .bind(reason)
        .execute(&mut *tx)
        .await?;
        if r.rows_affected() == 1 {
            Self::fail_exhausted(&mut tx, now, self.max_attempts).await?;
        }
        tx.commit().await?;
        drop(conn);
        self.forget_lease(job, idx);
        Ok(())
    }

    /// Why tile pixels cannot be stored now, if the spool failed to write a tile's pixels
    /// less than `within` ago and has written none since ([`crate::spool::Spool::trouble`]);
    /// `None` for an in-memory database, which keeps them in SQLite.
    pub fn storage_trouble(&self, within: Duration) -> Option<String> {
        self.spool.as_ref().and_then(|s| s.trouble(within))
    }

    /// Requeues tiles whose lease expired and fails jobs with a tile out of attempts.
    /// Returns the number of tiles requeued. Tiles of a job that has ended (cancelled,
    /// failed) are left as they are: nothing will hand them out, and their workers did
    /// nothing wrong.
    ///
    /// A worker's leases on one job that run out within `keep.stall_ms` of each other are
    /// one stall, in this pass or across passes: one strike towards keeping the worker away.
    /// A failure is charged to each tile it said it was rendering (a renewal with
    /// `rendering`), one per thread of a worker of many; the tiles it held ahead go back to
    /// the queue uncharged. A worker that stalled before renewing anything said nothing:
    /// then the tile whose lease ran out first is charged (its held-ahead tiles were claimed
    /// later). Counted once a tile, one pause or crash of a lone worker was two strikes,
    /// enough to fail its job, and tiles never begun ran out of attempts.
    pub async fn reap(&self, now: i64, max_attempts: u32, keep: KeepAway) -> Result<u64> {
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        let expired: Vec<Expired> = sqlx::query_as(
            "SELECT job_id, idx, worker, lease_expires, rendering FROM tiles
             WHERE state = 'leased' AND lease_expires < ?1
               AND EXISTS (SELECT 1 FROM jobs
                           WHERE id = tiles.job_id AND state IN ('queued', 'running'))
             ORDER BY job_id, worker, lease_expires, idx",
        )
        .bind(now)
        .fetch_all(&mut *tx)
        .await?;
        // One worker's expired leases on one job, in the order they ran out.
        for tiles in expired.chunk_by(|a, b| a.job_id == b.job_id && a.worker == b.worker) {
            let (job, worker) = (&tiles[0].job_id, &tiles[0].worker);
            let mut stall_until: i64 = match worker {
                Some(w) => sqlx::query_scalar(
                    "SELECT stall_until FROM keep_away WHERE job_id = ?1 AND worker = ?2",
                )
                .bind(job)
                .bind(w)
                .fetch_optional(&mut *tx)
                .await?
                .unwrap_or(0),
                None => 0,
            };
            let mut strikes = 0i64;
            for (k, t) in tiles.iter().enumerate() {
                // A lease with no worker name (none is stored so) is its own stall.
                let opens = worker.is_none() || t.lease_expires >= stall_until;
                if opens {
                    strikes += 1;
                    stall_until = t.lease_expires.saturating_add(keep.stall_ms);
                }
                // Charged: a tile the worker said it was rendering; or, when it said so of
                // none of this stall's tiles (it stopped before its first renewal), the one
                // whose lease ran out first.
                let charged = t.rendering
                    || (opens
                        && !tiles[k..]
                            .iter()
                            .take_while(|u| u.lease_expires < stall_until)
                            .any(|u| u.rendering));
                sqlx::query(
                    "UPDATE tiles SET state = 'queued', failures = failures + ?3,
                         last_error = CASE WHEN ?3 = 1
                             THEN 'lease lost: worker ' || COALESCE(worker, '?')
                                  || ' stopped answering'
                             ELSE last_error END,
                         lease = NULL, worker = NULL, lease_expires = NULL
                     WHERE job_id = ?1 AND idx = ?2",
                )
                .bind(job)
                .bind(t.idx)
                .bind(i64::from(charged))
                .execute(&mut *tx)
                .await?;
            }
            if let Some(w) = worker {
                sqlx::query(
                    "INSERT INTO keep_away (job_id, worker, failures, until, stall_until)
                     VALUES (?1, ?2, ?3, 0, ?4)
                     ON CONFLICT (job_id, worker) DO UPDATE
                     SET failures = failures + ?3, stall_until = ?4",
                )
                .bind(job)
                .bind(w)
                .bind(strikes)
                .bind(stall_until)
                .execute(&mut *tx)
                .await?;
            }
        }
        if !expired.is_empty() {
            Self::apply_keep_away(&mut tx, now, keep).await?;
            Self::fail_exhausted(&mut tx, now, max_attempts).await?;
        }
        tx.commit().await?;
        Ok(expired.len() as u64)
    }

    async fn apply_keep_away(
        tx: &mut sqlx::Transaction<'_, sqlx::Sqlite>,
        now: i64,
        keep: KeepAway,
    ) -> Result<()> {
        sqlx::query("UPDATE keep_away SET until = ?1, failures = 0 WHERE failures >= ?2")
            .bind(now.saturating_add(keep.for_ms))
            .bind(i64::from(keep.after.max(1)))
            .execute(&mut **tx)
            .await?;
        Ok(())
    }

    async fn fail_exhausted(
        tx: &mut sqlx::Transaction<'_, sqlx::Sqlite>,
        now: i64,
        max_attempts: u32,
    ) -> Result<()> {
        sqlx::query(
            "UPDATE jobs SET state = 'failed', finished_at = ?1,
                 error = (SELECT 'tile ' || t.idx || ' (' || t.w || '×' || t.h || ' at ' || t.x || ','
                                 || t.y || ') failed ' || t.failures || ' times; last: '
                                 || COALESCE(t.last_error, 'unknown')
                          FROM tiles t WHERE t.job_id = jobs.id AND t.state = 'queued'
                            AND t.failures >= ?2 LIMIT 1)
             WHERE state IN ('queued', 'running') AND EXISTS (
                 SELECT 1 FROM tiles t WHERE t.job_id = jobs.id AND t.state = 'queued'
                   AND t.failures >= ?2)",
        )
        .bind(now)
        .bind(i64::from(max_attempts))
        .execute(&mut **tx)
        .await?;
        Ok(())
    }

    /// Active jobs with queued work from which every one of `live` workers is kept away:
    /// failed, since nothing would ever render them (Flamenco's rule). Returns how many.
    pub async fn fail_unservable(&self, live: &[String], now: i64) -> Result<u64> {
        if live.is_empty() {
            return Ok(0);
        }
        let rows: Vec<(String, String)> = sqlx::query_as(
            "SELECT k.job_id, k.worker FROM keep_away k JOIN jobs j ON j.id = k.job_id
             WHERE k.until > ?1 AND j.state IN ('queued', 'running')",
        )
        .bind(now)
        .fetch_all(&mut *self.reader().await?)
        .await?;
        let mut jobs: Vec<&str> = rows.iter().map(|(j, _)| j.as_str()).collect();
        jobs.sort_unstable();
        jobs.dedup();
        let mut failed = 0;
        for job in jobs {
            let all_away = live
                .iter()
                .all(|w| rows.iter().any(|(j, k)| j == job && k == w));
            if !all_away {
                continue;
            }
            let r = sqlx::query(
                "UPDATE jobs SET state = 'failed', finished_at = ?2,
                     error = 'every available worker failed this job; last: ' || COALESCE(
                         (SELECT last_error FROM tiles WHERE job_id = ?1 AND last_error IS NOT NULL
                          ORDER BY failures DESC LIMIT 1), 'unknown')
                 WHERE id = ?1 AND state IN ('queued', 'running')
                   AND EXISTS (SELECT 1 FROM tiles WHERE job_id = ?1 AND state = 'queued')",
            )
            .bind(job)
            .bind(now)
            .execute(&mut *self.writer.lock().await?)
            .await?;
            failed += r.rows_affected();
        }
        Ok(failed)
    }

    /// At start: the tiles held by the local workers of the service process that last
    /// started on this database (their names begin with a prefix it stored) are requeued
    /// without a failure counted, since those workers ended with that process; `prefix`, the
    /// name prefix of this process's local workers (none without any), is stored instead.
    /// Tiles of jobs that have ended are left as they are, as the reaper leaves them.
    /// Returns the number of tiles requeued.
    pub async fn forget_local_workers(&self, prefix: Option<&str>) -> Result<u64> {
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        let requeued = sqlx::query(
            "UPDATE tiles SET state = 'queued', lease = NULL, worker = NULL, lease_expires = NULL
             WHERE state = 'leased'
               AND job_id IN (SELECT id FROM jobs WHERE state IN ('queued', 'running'))
               AND EXISTS (SELECT 1 FROM local_workers p
                           WHERE substr(tiles.worker, 1, length(p.prefix)) = p.prefix)",
        )
        .execute(&mut *tx)
        .await?
        .rows_affected();
        sqlx::query("DELETE FROM local_workers")
            .execute(&mut *tx)
            .await?;
        if let Some(prefix) = prefix {
            sqlx::query("INSERT INTO local_workers (prefix) VALUES (?1)")
                .bind(prefix)
                .execute(&mut *tx)
                .await?;
        }
        tx.commit().await?;
        Ok(requeued)
    }

    /// [`Queue::noted`], for a renewal or a result under `lease` that failed: its worker is
    /// alive and asked in time, so while the storage fails the reaper gives the lease a
    /// fresh term rather than reap it ([`Queue::reap_unheard`]). Only refusals are noted (a
    /// renewal that went through has moved the lease on by itself), only what could be a
    /// lease, and at most [`HEARD_LEASES`] at once: requests under made-up leases cannot
    /// grow the record past that.
    pub fn heard_refused(&self, lease: &str, e: QueueError) -> QueueError {
        self.heard(lease);
        self.noted(e)
    }

    /// Notes a refused request under `lease` now (see [`Queue::heard_refused`]).
    pub fn heard(&self, lease: &str) {
        let plausible = lease.len() == 32
            && lease
                .bytes()
                .all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f'));
        if plausible {
            let mut heard = self
                .heard
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            let room = heard.len() < HEARD_LEASES;
            match heard.get_mut(lease) {
                Some(at) => *at = std::time::Instant::now(),
                None if room => {
                    heard.insert(lease.to_string(), std::time::Instant::now());
                }
                None => {}
            }
        }
    }

    /// Forgets the leases not heard from within `within` (the reaper's every pass, so that
    /// the record holds only the leases of workers still asking).
    pub fn forget_unheard(&self, within: Duration) {
        let mut heard = self
            .heard
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        heard.retain(|_, at| at.elapsed() < within);
    }

    /// The reaper's pass while the storage fails ([`Queue::storage_failed_within`]): the
    /// leases heard from within `within` ([`Queue::heard_refused`]: their workers asked to
    /// renew them or to store their results, and were refused) get a fresh `lease_ms`; the
    /// others are reaped as ever, since a worker that died meanwhile asks nothing, and one
    /// whose renewals went through holds a lease that has not run out. Extending every
    /// lease, as it did, kept a dead worker's tiles for as long as failures kept coming,
    /// which on a nearly full disk, failing now and then, could be for ever. Returns how
    /// many leases were extended and how many reaped.
    pub async fn reap_unheard(
        &self,
        now: i64,
        lease_ms: u64,
        within: Duration,
        max_attempts: u32,
        keep: KeepAway,
    ) -> Result<(u64, u64)> {
        self.forget_unheard(within);
        let heard: HashSet<String> = self
            .heard
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .keys()
            .cloned()
            .collect();
        let mut extended = 0;
        if !heard.is_empty() {
            let mut conn = self.writer.lock().await?;
            let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
            let leased: Vec<(String, i64, String)> = sqlx::query_as(
                "SELECT job_id, idx, lease FROM tiles WHERE state = 'leased' AND lease IS NOT NULL",
            )
            .fetch_all(&mut *tx)
            .await?;
            for (job, idx, lease) in leased.iter().filter(|(_, _, l)| heard.contains(l)) {
                extended += sqlx::query(
                    "UPDATE tiles SET lease_expires = ?1
                     WHERE job_id = ?2 AND idx = ?3 AND lease = ?4 AND state = 'leased'",
                )
                .bind(now.saturating_add(lease_ms as i64))
                .bind(job)
                .bind(idx)
                .bind(lease)
                .execute(&mut *tx)
                .await?
                .rows_affected();
            }
            tx.commit().await?;
        }
        let reaped = self.reap(now, max_attempts, keep).await?;
        Ok((extended, reaped))
    }

    /// After a restart: every live lease gets a fresh `lease_ms`, so workers that rode
    /// through the outage can still post what they rendered.
    pub async fn extend_leases(&self, now: i64, lease_ms: u64) -> Result<u64> {
        let r = sqlx::query("UPDATE tiles SET lease_expires = ?1 WHERE state = 'leased'")
            .bind(now.saturating_add(lease_ms as i64))
            .execute(&mut *self.writer.lock().await?)
            .await?;
        Ok(r.rows_affected())
    }

    /// The ids of queued and running jobs.
    pub async fn active_jobs(&self) -> Result<Vec<String>> {
        Ok(
            sqlx::query_scalar("SELECT id FROM jobs WHERE state IN ('queued', 'running')")
                .fetch_all(&mut *self.reader().await?)
                .await?,
        )
    }

    /// Deletes the spool files of jobs that have ended or were deleted (see
    /// [`Spool::sweep`]); returns how many. A finished image's file goes at once; this
    /// catches the rest (cancelled and failed jobs, deletions, a crash).
    pub async fn sweep_spool(&self) -> Result<usize> {
        let Some(spool) = &self.spool else {
            return Ok(0);
        };
        let listing = spool.listing()?;
        if listing.is_empty() && self.issued_map().is_empty() {
            return Ok(0);
        }
        let active = self.active_jobs().await?;
        // A job submitted since `active` was read loses its entries here: its results then
        // read their tile's row instead, one query slower.
        self.issued_map()
            .retain(|(job, _), _| active.iter().any(|a| a == job));
        Ok(spool.sweep(&listing, &active))
    }

    /// The spool's folder; `None` for an in-memory database.
    pub fn spool_dir(&self) -> Option<&std::path::Path> {
        self.spool.as_deref().map(Spool::dir)
    }

    /// Jobs whose tiles are all in but whose image is not yet assembled (after a restart).
    pub async fn unassembled(&self) -> Result<Vec<String>> {
        Ok(sqlx::query_scalar(
            "SELECT id FROM jobs WHERE state IN ('queued', 'running') AND tiles_done = tiles_total
             ORDER BY seq",
        )
        .fetch_all(&mut *self.reader().await?)
        .await?)
    }

    /// A job's state, and what a worker needs of it: scene, sampler settings, asset names.
    pub async fn job_scene(&self, id: &str) -> Result<Option<(String, JobSpec)>> {
        type SceneRow = (String, String, Option<String>, Option<i64>, Option<f64>);
        let row: Option<SceneRow> = sqlx::query_as(
            "SELECT state, scene, sampler, samples, threshold
             FROM jobs JOIN job_scenes ON job_scenes.job_id = jobs.id WHERE id = ?1",
        )
        .bind(id)
        .fetch_optional(&mut *self.reader().await?)
        .await?;
        let Some((state, scene, sampler, samples, threshold)) = row else {
            return Ok(None);
        };
        let assets = sqlx::query_scalar("SELECT name FROM assets WHERE job_id = ?1 ORDER BY name")
            .bind(id)
            .fetch_all(&mut *self.reader().await?)
            .await?;
        let spec = JobSpec {
            id: id.to_string(),
            scene,
            sampler,
            samples: samples.map(|s| s as u32),
            threshold,
            assets,
        };
        Ok(Some((state, spec)))
    }

    pub async fn asset(&self, id: &str, name: &str) -> Result<Option<Vec<u8>>> {
        Ok(
            sqlx::query_scalar("SELECT bytes FROM assets WHERE job_id = ?1 AND name = ?2")
                .bind(id)
                .bind(name)
                .fetch_optional(&mut *self.reader().await?)
                .await?,
        )
    }

    /// The stored tiles of one band of rows starting at `y`, left to right: each tile's
    /// bytes are appended to `buf` (cleared first, its capacity kept from band to band), and
    /// the tiles are returned in order with where their bytes are in it.
    ///
    /// The rows come in `idx` order from the `tiles_by_band` index (migration 0003), which
    /// within a band is left to right, so SQLite sorts nothing. A spooled tile's pixels are
    /// read from the job's spool file straight into `buf` and checked against the row's
    /// CRC; pixels kept in the row (an in-memory database, rows from before migration 0011)
    /// are copied from it.
    ///
    /// Tiles whose spooled pixels are missing or do not match are lost: they are queued
    /// again ([`Queue::requeue_lost`]) and the call fails with [`QueueError::Lost`].
    ///
    /// Read on the writing connection, taken in turn with the results and claims: a band
    /// is one short read, and the rows of pixels kept in SQLite are still in its cache.
    pub async fn band(
        &self,
        id: &str,
        y: u32,
        now: i64,
        buf: &mut Vec<u8>,
    ) -> Result<Vec<BandTile>> {
        buf.clear();
        let rows = sqlx::query(BAND_SQL)
            .bind(id)
            .bind(i64::from(y))
            .fetch_all(&mut *self.writer.lock().await?)
            .await?;
        let mut tiles = Vec::with_capacity(rows.len());
        let mut lost = Vec::new();
        // The job's image size, looked up once a band (and only if a row is spooled).
        let mut size = None;
        for row in &rows {
            let (x, w, h): (i64, i64, i64) = (row.try_get(0)?, row.try_get(1)?, row.try_get(2)?);
            let (x, w, h) = (x as u32, w as u32, h as u32);
            let crc: Option<i64> = row.try_get(4)?;
            let start = buf.len();
            let read = match (crc, &self.spool) {
                (Some(crc), Some(spool)) => {
                    if size.is_none() {
                        size = Some(self.spooled_size(spool, id).await?);
                    }
                    match size.flatten() {
                        Some((width, height)) => {
                            spool.read(id, width, height, Rect::new(x, y, w, h), crc as u32, buf)
                        }
                        None => false,
                    }
                }
                // A spooled row read without a spool (the database moved to memory: cannot
                // happen, an in-memory database is new) is lost like a missing file.
                (Some(_), None) => false,
                (None, _) => {
                    buf.extend_from_slice(row.try_get::<&[u8], _>(3)?);
                    true
                }
            };
            if read {
                tiles.push(BandTile {
                    x,
                    w,
                    h,
                    bytes: start..buf.len(),
                });
            } else {
                lost.push(row.try_get::<i64, _>(5)?);
            }
        }
        if !lost.is_empty() {
            let tiles = self.requeue_lost(id, &lost, now).await?;
            tracing::warn!(job = %id, y, tiles, "tile pixels lost from the spool: rendering them again");
            return Err(QueueError::Lost {
                job: id.to_string(),
                tiles: lost.len(),
            });
        }
        Ok(tiles)
    }

    /// Hands out again the done tiles `idxs` of an active job whose pixels were lost: their
    /// rows go, the tiles are queued and the job counts them as not done. Each loss counts
    /// a failure against its tile, not against any worker (none did anything wrong), so
    /// that a tile whose pixels keep being lost (a failing disk, a folder something else
    /// empties) fails its job after `max_attempts` losses with the reason, instead of being
    /// rendered for ever. Returns how many tiles were requeued.
    pub async fn requeue_lost(&self, id: &str, idxs: &[i64], now: i64) -> Result<u64> {
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        let mut requeued = 0;
        for &idx in idxs {
            let r = sqlx::query(
                "UPDATE tiles SET state = 'queued', lease = NULL, worker = NULL,
                        lease_expires = NULL, rendering = 0, failures = failures + 1,
                        last_error = 'its pixels were lost from the tile spool'
                 WHERE job_id = ?1 AND idx = ?2 AND state = 'done'
                   AND EXISTS (SELECT 1 FROM jobs WHERE id = ?1 AND state IN ('queued', 'running'))",
            )
            .bind(id)
            .bind(idx)
            .execute(&mut *tx)
            .await?;
            if r.rows_affected() == 1 {
                sqlx::query("DELETE FROM tile_pixels WHERE job_id = ?1 AND idx = ?2")
                    .bind(id)
                    .bind(idx)
                    .execute(&mut *tx)
                    .await?;
                requeued += 1;
            }
        }
        sqlx::query("UPDATE jobs SET tiles_done = tiles_done - ?2 WHERE id = ?1")
            .bind(id)
            .bind(requeued as i64)
            .execute(&mut *tx)
            .await?;
        Self::fail_exhausted(&mut tx, now, self.max_attempts).await?;
        tx.commit().await?;
        Ok(requeued)
    }

    pub async fn clear_image(&self, id: &str) -> Result<()> {
        sqlx::query("DELETE FROM image_chunks WHERE job_id = ?1")
            .bind(id)
            .execute(&mut *self.writer.lock().await?)
            .await?;
        Ok(())
    }

    /// Stores a chunk of a job's PNG, unless the job has ended meanwhile (a cancelled job's
    /// chunks are dropped with it and must not come back).
    pub async fn put_image_chunk(&self, id: &str, seq: u32, bytes: &[u8]) -> Result<()> {
        self.put_image_chunks(id, seq, &[bytes]).await
    }

    /// Stores `pieces` as the job's PNG chunks `first_seq`, `first_seq + 1`, …, a hundred to
    /// a statement, unless the job has ended meanwhile (as [`Queue::put_image_chunk`]).
    pub async fn put_image_chunks(&self, id: &str, first_seq: u32, pieces: &[&[u8]]) -> Result<()> {
        const PER_STATEMENT: usize = 100;
        for (n, group) in pieces.chunks(PER_STATEMENT).enumerate() {
            let values = (0..group.len())
                .map(|i| format!("(?{}, ?{})", 2 + 2 * i, 3 + 2 * i))
                .collect::<Vec<_>>()
                .join(", ");
            let sql = format!(
                "INSERT INTO image_chunks (job_id, seq, bytes)
                 SELECT ?1, column1, column2 FROM (VALUES {values})
                 WHERE EXISTS (SELECT 1 FROM jobs WHERE id = ?1 AND state IN ('queued', 'running'))"
            );
            // Only placeholders are formatted in: the values are bound. One text per group
            // size: kept out of the writer's statement cache, as the tiles' insert is.
            let mut q = sqlx::query(sqlx::AssertSqlSafe(sql))
                .persistent(false)
                .bind(id);
            let first = i64::from(first_seq) + (n * PER_STATEMENT) as i64;
            for (i, piece) in group.iter().enumerate() {
                q = q.bind(first + i as i64).bind(*piece);
            }
            q.execute(&mut *self.writer.lock().await?).await?;
            self.wrote(group.iter().map(|p| p.len()).sum());
        }
        Ok(())
    }

    /// Marks an assembled job done and drops its tile pixels. False (and the image dropped)
    /// when the job was cancelled meanwhile.
    pub async fn finish_image(&self, id: &str, png_bytes: u64, now: i64) -> Result<bool> {
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        let r = sqlx::query(
            "UPDATE jobs SET state = 'done', finished_at = ?2, png_bytes = ?3
             WHERE id = ?1 AND state IN ('queued', 'running') AND tiles_done = tiles_total",
        )
        .bind(id)
        .bind(now)
        .bind(png_bytes as i64)
        .execute(&mut *tx)
        .await?;
        let done = r.rows_affected() == 1;
        if !done {
            sqlx::query("DELETE FROM image_chunks WHERE job_id = ?1")
                .bind(id)
                .execute(&mut *tx)
                .await?;
        }
        // The pixels go unless the job is still active: then a tile was handed out again
        // meanwhile (its pixels lost), and the others' wait for the next assembly.
        let ended = sqlx::query(
            "DELETE FROM tile_pixels WHERE job_id = ?1
               AND NOT EXISTS (SELECT 1 FROM jobs WHERE id = ?1 AND state IN ('queued', 'running'))",
        )
        .bind(id)
        .execute(&mut *tx)
        .await?;
        tx.commit().await?;
        drop(conn);
        if done || ended.rows_affected() > 0 {
            self.forget_job(id);
        }
        Ok(done)
    }

    /// Fails a job whose image could not be assembled.
    pub async fn fail_job(&self, id: &str, reason: &str, now: i64) -> Result<()> {
        sqlx::query(
            "UPDATE jobs SET state = 'failed', error = ?2, finished_at = ?3
             WHERE id = ?1 AND state IN ('queued', 'running')",
        )
        .bind(id)
        .bind(reason)
        .bind(now)
        .execute(&mut *self.writer.lock().await?)
        .await?;
        Ok(())
    }

    /// The number of chunks of a job's PNG.
    pub async fn image_chunks(&self, id: &str) -> Result<u32> {
        let n: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM image_chunks WHERE job_id = ?1")
            .bind(id)
            .fetch_one(&mut *self.reader().await?)
            .await?;
        Ok(n as u32)
    }

    pub async fn image_chunk(&self, id: &str, seq: u32) -> Result<Option<Vec<u8>>> {
        Ok(
            sqlx::query_scalar("SELECT bytes FROM image_chunks WHERE job_id = ?1 AND seq = ?2")
                .bind(id)
                .bind(i64::from(seq))
                .fetch_optional(&mut *self.reader().await?)
                .await?,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A transaction that fails on a full database (here the writer's `max_page_count`)
    /// leaves the queue working once there is room again: later transactions on the writer
    /// succeed. SQLite rolls such a transaction back itself, and sqlx, still counting it,
    /// refused every later `BEGIN` on that connection, which [`Writer::lock`] replaces.
    #[tokio::test]
    async fn a_transaction_that_failed_on_a_full_database_leaves_the_writer_usable() {
        let dir = std::env::temp_dir().join(format!("tessera-full-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("temp dir");
        let q = Queue::open(&format!("sqlite://{}", dir.join("q.db").display()))
            .await
            .expect("open");
        let job = |id: &str, scene: String| NewJob {
            id: id.into(),
            scene,
            name: None,
            width: 64,
            height: 64,
            tile: 16,
            sampler: None,
            samples: None,
            threshold: None,
            created_at: 0,
            priority: 0,
        };
        let rects = tessera_tracer::tiles(64, 64, 16);
        {
            let mut w = q.writer.lock().await.expect("the writer");
            let (pages,): (i64,) = sqlx::query_as("PRAGMA page_count")
                .fetch_one(&mut *w)
                .await
                .expect("pages");
            sqlx::query(sqlx::AssertSqlSafe(format!(
                "PRAGMA max_page_count = {pages}"
            )))
            .execute(&mut *w)
            .await
            .expect("limit");
        }
        let big = "# x\n".repeat(200_000);
        let full = q.insert_job(&job("a", big), &rects, &[]).await;
        let full = full.expect_err("the database is full");
        // SQLite's own `SQLITE_FULL`, which the service answers `503` and which makes the
        // reaper extend leases rather than charge workers.
        assert!(full.is_storage(), "{full:?}");
        assert!(!q.storage_failed_within(Duration::from_secs(60)));
        let _ = q.noted(full);
        assert!(q.storage_failed_within(Duration::from_secs(60)));
        let not_storage = QueueError::Url {
            url: "x".into(),
            reason: "y".into(),
        };
        assert!(!not_storage.is_storage());
        // The spool's failures are storage failures, but refuse no renewal: not noted.
        let spool = QueueError::Spool(SpoolError::Io {
            path: dir.join("x.rgb"),
            source: std::io::Error::from_raw_os_error(28),
        });
        assert!(spool.is_storage());
        let q2 = Queue::open(&format!("sqlite://{}", dir.join("q2.db").display()))
            .await
            .expect("open");
        let _ = q2.noted(spool);
        assert!(!q2.storage_failed_within(Duration::from_secs(60)));
        // Room again (a fresh connection has no page limit; the old one keeps it).
        {
            let mut w = q.writer.lock().await.expect("the writer");
            sqlx::query("PRAGMA max_page_count = 1073741823")
                .execute(&mut *w)
                .await
                .expect("lift");
        }
        let small = "[GLOBALS]\n[/GLOBALS]\n".to_string();
        q.insert_job(&job("b", small), &rects, &[])
            .await
            .expect("stored once there is room");
        let c = q.claim("w", 0, 60_000, 4).await.expect("claim");
        assert!(c.is_some_and(|c| c.job == "b"));
        let _ = std::fs::remove_dir_all(dir);
    }

    /// The claim finds its job through `jobs_to_claim` and sorts no jobs: without it, the
    /// planner found the active jobs through `jobs_by_state` and sorted them all, each
    /// checked for a tile the worker may take, on every claim.
    #[tokio::test]
    async fn the_claim_walks_the_active_jobs_in_order() {
        let q = Queue::open("sqlite::memory:").await.expect("open");
        let rows: Vec<(i64, i64, i64, String)> = sqlx::query_as(sqlx::AssertSqlSafe(format!(
            "EXPLAIN QUERY PLAN {CLAIM_SQL}"
        )))
        .bind("w")
        .bind("lease")
        .bind(0i64)
        .bind(0i64)
        .bind(4i64)
        .fetch_all(&mut *q.writer.lock().await.expect("the writer"))
        .await
        .expect("plan");
        let plan: Vec<String> = rows.into_iter().map(|r| r.3).collect();
        assert!(plan.iter().any(|d| d.contains("jobs_to_claim")), "{plan:?}");
        assert!(!plan.iter().any(|d| d.contains("B-TREE")), "{plan:?}");
    }

    /// The band query finds its rows through `tiles_by_band` and sorts nothing: a sort
    /// would copy every tile's pixels once more into SQLite's sorter.
    #[tokio::test]
    async fn the_band_query_sorts_nothing() {
        let q = Queue::open("sqlite::memory:").await.expect("open");
        let rows: Vec<(i64, i64, i64, String)> = sqlx::query_as(sqlx::AssertSqlSafe(format!(
            "EXPLAIN QUERY PLAN {BAND_SQL}"
        )))
        .bind("job")
        .bind(0i64)
        .fetch_all(&mut *q.writer.lock().await.expect("the writer"))
        .await
        .expect("plan");
        let plan: Vec<String> = rows.into_iter().map(|r| r.3).collect();
        assert!(plan.iter().any(|d| d.contains("tiles_by_band")), "{plan:?}");
        assert!(!plan.iter().any(|d| d.contains("B-TREE")), "{plan:?}");
    }

    /// A database the queue cannot use says which and why: another scheme is refused as
    /// not SQLite (sqlx took it for a file name), and so is a SQLite URI file name; a file
    /// in a missing folder names the URL;
    /// a bare path is still a SQLite file.
    #[tokio::test]
    async fn a_database_that_cannot_be_opened_is_named() {
        // A SQLite URI file name too: SQLite would open `f.db`, but the lock and the spool
        // would be named `file:f.db-…`, letting a second service onto the same file.
        for url in [
            "postgres://u@h/db",
            "bogus://x",
            "file:f.db",
            "sqlite:file:f.db?mode=rwc",
            "sqlite://file:f.db",
        ] {
            match Queue::open(url).await {
                Err(e @ QueueError::Url { .. }) => {
                    let m = e.to_string();
                    assert!(m.contains(url) && m.contains("sqlite://PATH"), "{m}");
                }
                other => panic!("{url}: {:?}", other.err()),
            }
            assert!(
                !std::path::Path::new("f.db").exists(),
                "{url} opened nothing"
            );
        }
        let dir = std::env::temp_dir().join(format!("tessera-open-{}", std::process::id()));
        let missing = format!("sqlite://{}/no-such-folder/q.db", dir.display());
        match Queue::open(&missing).await {
            Err(e @ QueueError::Open { .. }) => {
                assert!(e.to_string().contains(&missing), "{e}");
            }
            other => panic!("{missing}: {:?}", other.err()),
        }
        std::fs::create_dir_all(&dir).expect("temp dir");
        let bare = dir.join("q.db");
        let q = Queue::open(&bare.display().to_string()).await;
        assert!(q.is_ok(), "{:?}", q.err());
        assert!(bare.exists());
        drop(q);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
