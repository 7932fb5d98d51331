//! Opening a SQLite database: which URLs name one, the connections (one writer, a pool of
//! readers), and the schema's migrations.

use std::str::FromStr;
use std::sync::Arc;
use std::time::Duration;

use sqlx::sqlite::{
    SqliteConnectOptions, SqliteJournalMode, SqliteLockingMode, SqlitePoolOptions,
    SqliteSynchronous,
};
use tokio::sync::Mutex;

use super::checkpoint::{CHECKPOINT_EVERY_BYTES, WRITER_CHECKPOINT_PAGES, WalKeeper};
use super::spool::{self, Spool};
use super::{Result, SqliteStore, Writer};
use crate::store::DEFAULT_MAX_ATTEMPTS;
use crate::store::error::StoreError;

static MIGRATOR: sqlx::migrate::Migrator = sqlx::migrate!("../migrations/sqlite");

/// Whether `url` can name a SQLite database: `sqlite:` or no scheme at all (a bare path),
/// but not a SQLite URI file name (`file:…`, see [`SqliteStore::open`]).
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

impl SqliteStore {
    /// Opens (creating if missing) the database at `url` (`sqlite://path`, or
    /// `sqlite::memory:`) and brings its schema up to date.
    pub(crate) async fn open(url: &str) -> Result<SqliteStore> {
        SqliteStore::open_with(url, false).await
    }

    /// Opens the database file at `url` on a full disk, where [`SqliteStore::open`] fails:
    /// SQLite cannot size the `-shm` file that its connections share. One connection, in
    /// exclusive locking mode, keeps that index in its own memory instead, and serves the
    /// reads as well as the writes (as for an in-memory database). The schema must be up to
    /// date already: migrating would write. The connection takes writes once the disk has
    /// room again; it stays the only one until the service restarts.
    pub(crate) async fn open_exclusive(url: &str) -> Result<SqliteStore> {
        SqliteStore::open_with(url, true).await
    }

    async fn open_with(url: &str, exclusive: bool) -> Result<SqliteStore> {
        // sqlx reads any other scheme as a file name ("unable to open database file"). A bare
        // path (`tessera.db`) is a SQLite file.
        if is_uri_file_name(url) {
            return Err(StoreError::Url {
                url: url.to_string(),
                reason: "SQLite URI file names (`file:…`) are not taken: give the file as \
                         sqlite://PATH or a plain path"
                    .into(),
            });
        }
        if !is_sqlite(url) {
            return Err(StoreError::Url {
                url: url.to_string(),
                reason: "give sqlite://PATH (for example sqlite://tessera.db, or \
                         sqlite:///var/lib/tessera/queue.db) or postgres://USER@HOST:PORT/DB"
                    .into(),
            });
        }
        let opts = SqliteConnectOptions::from_str(url)
            .map_err(|e| StoreError::Url {
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
        let spool_dir = (!in_memory).then(|| spool::folder_for(opts.get_filename()));
        if let Some(dir) = &spool_dir {
            spool::check_folder(dir)?;
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
                // trip that tells nothing about a file opened in this process.
                .test_before_acquire(false)
                // A connection that comes back still inside a transaction is closed, not
                // reused. A COMMIT that fails (a full disk) leaves sqlx counting a
                // transaction that SQLite has already rolled back, and every later `BEGIN`
                // on that connection would fail ("non-zero transaction depth"), leaving the
                // store broken after the disk has room again.
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
        //   several jobs instead of several times per job copies far less. The cost: a WAL
        //   file of a few times [`CHECKPOINT_EVERY_BYTES`] at most beside the database.
        let mut writer_opts = opts
            .clone()
            .pragma("cache_size", "-16384")
            .pragma("wal_autocheckpoint", WRITER_CHECKPOINT_PAGES.to_string());
        if exclusive {
            // Set before the database is read, so that the WAL index is never looked for
            // in the `-shm` file.
            writer_opts = writer_opts.locking_mode(SqliteLockingMode::Exclusive);
        }
        // Migrated through a pool of its one connection, which is then taken out of it
        // (an in-memory database lives on that connection only).
        let migrating = SqlitePoolOptions::new()
            .max_connections(1)
            .connect_with(writer_opts.clone())
            .await
            .map_err(|source| StoreError::Open {
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
        // An in-memory database exists once per connection: it has only the writer's; so
        // has an exclusive one, which no other connection may read.
        let pool = if in_memory || exclusive {
            None
        } else {
            Some(connect(8, opts).await?)
        };
        let wal = (!in_memory)
            .then(|| WalKeeper::new(CHECKPOINT_EVERY_BYTES, tokio::sync::watch::Sender::new(0)));
        Ok(SqliteStore {
            pool,
            writer,
            wal,
            spool,
            max_attempts: DEFAULT_MAX_ATTEMPTS,
            issued: Arc::default(),
            failures: Arc::default(),
            roster: Arc::default(),
        })
    }

    /// The same store, failing a job whose tile lost its pixels `n` times (the service's
    /// `--max-attempts`; 4 until set).
    pub(crate) fn max_attempts(mut self, n: u32) -> SqliteStore {
        self.max_attempts = n;
        self
    }
}
