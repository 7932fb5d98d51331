//! The PostgreSQL backend: the store over one PostgreSQL database that several service
//! processes (replicas) share, each operation one statement or one transaction.
//!
//! The guarantees are the SQLite backend's, in SQL that holds with any number of
//! replicas at once:
//! - a claim is one `UPDATE … WHERE (job_id, idx) = (SELECT … LIMIT 1 FOR UPDATE SKIP
//!   LOCKED) RETURNING …`: concurrent claimers skip the rows another has locked instead of
//!   waiting for them or taking them twice;
//! - renewals, results, failures and releases change a tile only `WHERE lease = $lease`
//!   and the tile is still leased, re-checked by PostgreSQL on the row's latest version
//!   when two statements meet on it, so a stale worker or a second replica changes nothing;
//! - maintenance (reaping, failing unservable jobs, assembling images nobody assembles) is
//!   run by one replica at a time, the holder of an advisory lock ([`PgStore::maintains`]),
//!   and each of its statements is also guarded so that running it twice is harmless;
//! - a submission or a requeue on any replica wakes the claims waiting on every replica
//!   (`NOTIFY` inside the transaction that made the work, `LISTEN` on each replica: see
//!   [`notify`]).
//!
//! Nothing two replicas must agree on is kept in one process's memory. What each replica
//! keeps is a cache or a record of its own requests, written to the database for the
//! others ([`PgStore::share`]): the roster of workers it heard from, and the leases whose
//! requests it refused while the database failed.
//!
//! The files: [`open`] (URLs, connections, the schema and the errors at start), [`jobs`],
//! [`leases`], [`reap`], [`images`], [`view`] (a job's tiles and stored pixels as users see
//! them, its priority), [`workers`], [`health`], [`notify`] (wake-ups, the maintenance lock,
//! the assembly lock).

mod health;
mod images;
mod jobs;
mod leases;
mod notify;
mod open;
mod reap;
mod view;
mod workers;

use std::sync::Arc;
use std::sync::atomic::AtomicI64;

use sqlx::PgPool;
use sqlx::postgres::{PgConnectOptions, PgConnection};
use tokio::sync::Mutex;

use super::error::StoreError;
use super::memo::{FailureRecord, RosterBatch};
use super::state::{JobState, TileState};

pub use notify::AssemblyLock;
pub(crate) use open::{is_postgres, redacted};

type Result<T> = std::result::Result<T, StoreError>;

/// A job state read from the database.
fn job_state(s: String) -> Result<JobState> {
    JobState::try_from(s).map_err(|e| StoreError::Db(sqlx::Error::Decode(Box::new(e))))
}

/// A tile state read from the database.
fn tile_state(s: String) -> Result<TileState> {
    TileState::try_from(s).map_err(|e| StoreError::Db(sqlx::Error::Decode(Box::new(e))))
}

/// The store over one PostgreSQL database.
#[derive(Debug, Clone)]
pub struct PgStore {
    /// The pool every operation runs on.
    pool: PgPool,
    /// How to open a connection of its own (the maintenance and assembly locks, `LISTEN`).
    opts: Arc<PgConnectOptions>,
    /// The service's `--max-attempts`, for tiles whose pixels keep being lost.
    max_attempts: u32,
    /// The connection that holds (`true`) or asks for the maintenance lock (see
    /// [`PgStore::maintains`]).
    leader: Arc<Mutex<Option<(PgConnection, bool)>>>,
    /// When a database write of this replica last failed for the storage's sake, and the
    /// leases whose requests it refused lately (see [`health`]).
    failures: Arc<FailureRecord>,
    /// The latest such failure any replica shared, as last read ([`PgStore::share`]);
    /// `i64::MIN` for none.
    shared_failed: Arc<AtomicI64>,
    /// What this replica heard of workers since it last wrote the roster (see [`workers`]).
    roster: Arc<RosterBatch>,
}
