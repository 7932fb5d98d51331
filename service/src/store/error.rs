//! The error of every store operation, whatever the backend.
//!
//! It names `sqlx::Error` (every backend speaks through sqlx) and the tile spool's
//! [`SpoolError`] (the SQLite backend keeps tile pixels in files beside its database); what
//! counts as the storage failing ([`StoreError::is_storage`]) is decided here, for every
//! backend's error codes.

use std::io;
use std::path::PathBuf;
use std::time::Duration;

use tessera_tracer::Rect;

/// Errors of the store.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// A statement failed.
    #[error("database: {0}")]
    Db(#[from] sqlx::Error),
    /// The schema could not be brought up to date.
    #[error("database migration: {0}")]
    Migrate(#[from] sqlx::migrate::MigrateError),
    /// The database URL names nothing this service can open.
    #[error("bad database URL `{url}`: {reason}")]
    Url {
        /// The URL as given.
        url: String,
        /// Why it is refused.
        reason: String,
    },
    /// The database could not be opened.
    #[error(
        "cannot open the database `{url}`: {source} (its folder must exist and be writable, \
         and a file already there must be a Tessera queue)"
    )]
    Open {
        /// The URL as given.
        url: String,
        /// What the driver said.
        source: sqlx::Error,
    },
    /// A PostgreSQL database cannot be used: no server answers, the credentials or the
    /// database name are refused, or the database is another application's or has a newer
    /// schema.
    #[error("cannot use the database `{url}`: {problem}")]
    Postgres {
        /// The URL as given, its password hidden.
        url: String,
        /// What is wrong, and what to do.
        problem: String,
    },
    /// A write waited longer than it may for the database.
    #[error("the database took no write within {0:?}")]
    WriteTimeout(Duration),
    /// The tile spool failed.
    #[error(transparent)]
    Spool(#[from] SpoolError),
    /// Spooled pixels of `tiles` tiles of `job` were missing or did not match their CRC:
    /// those tiles are queued again (see the SQLite backend's spool).
    #[error("{tiles} tile(s) of job `{job}` lost their pixels and are rendered again")]
    Lost {
        /// The job.
        job: String,
        /// How many of its tiles.
        tiles: usize,
    },
}

impl StoreError {
    /// Whether this is the storage failing (a full disk, an I/O error, a file gone
    /// read-only, a database server gone) rather than anything a request did: SQLite's
    /// `SQLITE_FULL`, `SQLITE_IOERR` (with its extended codes) and `SQLITE_READONLY`;
    /// PostgreSQL's classes 08 (connection), 53 (insufficient resources: a full disk), 57P
    /// (the server shutting down or starting) and 58 (system errors); a lost connection;
    /// or the tile spool's writes.
    pub fn is_storage(&self) -> bool {
        match self {
            StoreError::Db(e) => storage_failed(e),
            // Opening a database on a full disk fails too: SQLite cannot size its `-shm`.
            StoreError::Open { source, .. } => storage_failed(source),
            StoreError::Spool(SpoolError::Io { .. } | SpoolError::Unwritable { .. }) => true,
            _ => false,
        }
    }
}

/// [`StoreError::is_storage`] for what the driver said.
fn storage_failed(e: &sqlx::Error) -> bool {
    match e {
        sqlx::Error::Database(e)
            if e.try_downcast_ref::<sqlx::postgres::PgDatabaseError>()
                .is_some() =>
        {
            e.code().is_some_and(|c| {
                ["08", "53", "57P", "58"]
                    .iter()
                    .any(|class| c.starts_with(class))
            })
        }
        sqlx::Error::Database(e) => e
            .code()
            .and_then(|c| c.parse::<i32>().ok())
            .is_some_and(|c| matches!(c & 0xff, 8 | 10 | 13)),
        sqlx::Error::Io(_) | sqlx::Error::PoolClosed => true,
        _ => false,
    }
}

/// Why a spooled tile could not be used.
#[derive(Debug, thiserror::Error)]
pub enum SpoolError {
    /// The rectangle has no slot in the image's file.
    #[error("tile {tile:?} is not inside the {width}×{height} image")]
    Outside {
        /// The rectangle.
        tile: Rect,
        /// The image's width.
        width: u32,
        /// The image's height.
        height: u32,
    },
    /// A file of the spool could not be read or written.
    #[error("tile spool {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: io::Error,
    },
    /// Something other than a folder is where the spool's folder goes.
    #[error("{0} is not a folder: the tile spool goes there, beside the database (move that away)")]
    NotAFolder(PathBuf),
    /// No file can be written in the spool's folder.
    #[error(
        "the tile spool folder {dir} does not take a file: {source} (tile pixels wait there, \
         beside the database: the service must be able to write in it)"
    )]
    Unwritable {
        /// The folder.
        dir: PathBuf,
        /// Why.
        #[source]
        source: io::Error,
    },
}

impl SpoolError {
    /// Whether the machine is out of room: the disk or the user's quota full, or no file
    /// descriptor or memory to spare (`EMFILE`, `ENFILE`, `ENOMEM`), or the write was
    /// interrupted. A trouble that passes, and no fault of the tile or of the worker that
    /// rendered it.
    pub fn is_capacity(&self) -> bool {
        match self {
            SpoolError::Io { source, .. } | SpoolError::Unwritable { source, .. } => {
                matches!(
                    source.kind(),
                    io::ErrorKind::StorageFull
                        | io::ErrorKind::QuotaExceeded
                        | io::ErrorKind::OutOfMemory
                        | io::ErrorKind::Interrupted
                ) || matches!(source.raw_os_error(), Some(23 | 24))
            }
            _ => false,
        }
    }
}
