//! The SQLite backend: the store over one SQLite database file (or an in-memory database,
//! for tests), each operation one statement or one `BEGIN IMMEDIATE` transaction.
//!
//! The guarantees live here, in SQL guarded by state, not in the handlers:
//! - a claim is one `UPDATE … WHERE rowid = (SELECT … LIMIT 1) RETURNING …`, so two claimers
//!   can never take the same queued tile (SQLite runs one writer at a time, and the update
//!   re-checks nothing it did not select under that same write lock);
//! - every claim gets a fresh random lease token; renewals, results, failures and releases
//!   are applied only `WHERE lease = ?` and the tile is still leased, so a stale worker
//!   changes nothing;
//! - expired leases are requeued by [`SqliteStore::reap`], counting a failure against the
//!   tile and the worker; a tile that fails `max_attempts` times fails its job with a
//!   readable reason.
//!
//! A database file keeps its tiles' pixels outside SQLite, in the spool beside it
//! ([`spool`]); the `tile_pixels` rows say which tiles are done and hold the CRC of their
//! bytes. An in-memory database keeps the pixels in the rows.
//!
//! One service process uses a database file at a time (the service takes `db_lock` on it
//! first). What this backend keeps in the process's memory is therefore this process's
//! alone by design, and each piece says why where it is declared: the WAL checkpoints
//! ([`checkpoint`]), the spool and its guard of the leases handed out ([`leases`]), and the
//! record of storage failures and refused leases ([`health`]). The roster of workers seen
//! is in the database ([`workers`]).
//!
//! The files: [`open`] (URLs, connections, migrations), [`checkpoint`], [`jobs`],
//! [`leases`] (claim, renew, result, fail, release), [`reap`] (expiry, keep-away, jobs no
//! worker may take), [`health`], [`images`] (bands and PNG chunks), [`view`] (a job's tiles
//! and stored pixels as users see them, its priority), [`workers`], [`spool`].

mod checkpoint;
mod health;
mod images;
mod jobs;
mod leases;
mod open;
mod reap;
pub(crate) mod spool;
mod view;
mod workers;

#[cfg(test)]
mod tests;

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;

use sqlx::pool::PoolConnection;
use sqlx::sqlite::{SqliteConnectOptions, SqliteConnection};
use sqlx::{Connection, Sqlite, SqlitePool};
use tessera_tracer::Rect;
use tokio::sync::{Mutex, MutexGuard};

use super::error::StoreError;
use super::memo::{FailureRecord, RosterBatch};
use super::state::{JobState, TileState};
use checkpoint::WalKeeper;
use spool::Spool;

#[cfg(feature = "bench")]
pub(crate) use checkpoint::CHECKPOINT_EVERY_BYTES;
pub(crate) use open::is_sqlite;

type Result<T> = std::result::Result<T, StoreError>;

/// A job state read from the database.
fn job_state(s: String) -> Result<JobState> {
    JobState::try_from(s).map_err(|e| StoreError::Db(sqlx::Error::Decode(Box::new(e))))
}

/// A tile state read from the database.
fn tile_state(s: String) -> Result<TileState> {
    TileState::try_from(s).map_err(|e| StoreError::Db(sqlx::Error::Decode(Box::new(e))))
}

/// How long a statement waits for the writing connection before the store answers "busy"
/// (as long as sqlx's pool waits for a connection).
const WRITER_WAIT: Duration = Duration::from_secs(30);

/// The one writing connection, held by the store rather than lent by a pool of one: each
/// statement takes it in turn (a fair lock: first come, first served, as a pool's waiters
/// are) and runs on it, and nothing else crosses to SQLite's thread. A pool `ping`s its
/// connection's thread whenever one is handed back (sqlx does so unconditionally, in a task
/// of its own): a second round trip to that thread, and a task, for every statement.
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
    /// `BEGIN` on that connection would fail ("non-zero transaction depth"), leaving the
    /// store broken after the disk has room again. (A transaction dropped unfinished, its
    /// request cancelled, may be counted until its rollback has run: the connection is
    /// then replaced needlessly, which costs an open.)
    async fn lock(&self) -> Result<MutexGuard<'_, SqliteConnection>> {
        let mut conn = tokio::time::timeout(WRITER_WAIT, self.conn.lock())
            .await
            .map_err(|_| StoreError::Db(sqlx::Error::PoolTimedOut))?;
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

/// The store over one SQLite database.
#[derive(Debug, Clone)]
pub struct SqliteStore {
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
    /// [`SqliteStore::requeue_lost`]); the other operations take it as an argument.
    max_attempts: u32,
    /// The lease and rectangle of each tile this process handed out and has not yet stored,
    /// by job and index: a result's pixels are written to the spool only under its tile's
    /// current lease and rectangle (see [`SqliteStore::complete`]). After a restart the
    /// tile's row is read instead. Entries of ended jobs go with their spool files.
    ///
    /// Per process by design: it guards this process's spool, and it is a copy of what the
    /// tiles' rows say, kept to save a read per result; the rows remain the record.
    issued: Arc<std::sync::Mutex<Issued>>,
    /// The record of the storage failing and of the leases refused meanwhile (see
    /// [`health`] for why it is kept in memory).
    failures: Arc<FailureRecord>,
    /// What this process heard of workers since it last wrote the roster (see
    /// [`workers`]).
    roster: Arc<RosterBatch>,
}

/// Leases handed out and not yet stored: `(job, idx)` → `(lease, rectangle)`.
type Issued = HashMap<(String, u32), (String, Rect)>;

impl SqliteStore {
    /// A reading connection (see [`Reader`]).
    async fn reader(&self) -> Result<Reader<'_>> {
        Ok(match &self.pool {
            Some(pool) => Reader::Pool(pool.acquire().await?),
            None => Reader::Writer(self.writer.lock().await?),
        })
    }

    /// Answers when the database does.
    pub(crate) async fn ping(&self) -> Result<()> {
        sqlx::query("SELECT 1")
            .execute(&mut *self.reader().await?)
            .await?;
        Ok(())
    }

    /// Rewrites the health row on the writing connection: whether the database takes a
    /// write now, within `within` (the writer may be behind a lock held elsewhere); and
    /// writes a file in the tile spool's folder.
    pub(crate) async fn probe_write(&self, now: i64, within: Duration) -> Result<()> {
        let write = async {
            sqlx::query(
                "INSERT INTO health (id, checked_at) VALUES (1, ?1)
                 ON CONFLICT (id) DO UPDATE SET checked_at = excluded.checked_at",
            )
            .bind(now)
            .execute(&mut *self.writer.lock().await?)
            .await
            .map_err(StoreError::from)
        };
        match tokio::time::timeout(within, write).await {
            Ok(done) => done.map(|_| ())?,
            Err(_) => return Err(StoreError::WriteTimeout(within)),
        }
        // And tile pixels can be stored.
        if let Some(spool) = &self.spool {
            spool.probe()?;
        }
        Ok(())
    }
}
