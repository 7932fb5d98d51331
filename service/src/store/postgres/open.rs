//! Opening a PostgreSQL database: which URLs name one, the pool, the schema's migrations,
//! and a clear error for each way a configuration can be wrong (no server there, refused
//! credentials, no such database, another application's tables, a newer schema).

use std::str::FromStr;
use std::sync::Arc;
use std::sync::atomic::AtomicI64;
use std::time::Duration;

use sqlx::Connection;
use sqlx::postgres::{PgConnectOptions, PgConnection, PgPoolOptions};

use super::{PgStore, Result};
use crate::store::error::StoreError;

static MIGRATOR: sqlx::migrate::Migrator = sqlx::migrate!("../migrations/postgres");

/// The migrations' bookkeeping table (sqlx's).
const MIGRATIONS_TABLE: &str = "_sqlx_migrations";

/// The most connections one replica opens. Each request holds one for a statement or a
/// short transaction; PostgreSQL's default `max_connections` (100) leaves room for several
/// replicas and the dedicated connections (maintenance lock, `LISTEN`, assemblies).
const POOL_SIZE: u32 = 16;

/// How long a request waits for a pooled connection (and, at start, for the server).
const CONNECT_WAIT: Duration = Duration::from_secs(10);

/// Whether `url` names a PostgreSQL database (`postgres://` or `postgresql://`).
pub fn is_postgres(url: &str) -> bool {
    url.starts_with("postgres://") || url.starts_with("postgresql://")
}

/// `url` with its password, if any, replaced by `***`: what errors and logs show.
pub fn redacted(url: &str) -> String {
    let Some((scheme, rest)) = url.split_once("://") else {
        return url.to_string();
    };
    let (auth, host) = match rest.split_once('@') {
        Some(parts) => parts,
        None => return url.to_string(),
    };
    match auth.split_once(':') {
        Some((user, _)) => format!("{scheme}://{user}:***@{host}"),
        None => url.to_string(),
    }
}

/// The error at start for `e`, naming what is wrong.
fn open_error(url: &str, opts: &PgConnectOptions, e: sqlx::Error) -> StoreError {
    let at = format!("{}:{}", opts.get_host(), opts.get_port());
    let problem = match &e {
        sqlx::Error::Io(io) => format!(
            "no PostgreSQL server answers at {at} ({io}): is it running, and listening there?"
        ),
        sqlx::Error::PoolTimedOut => format!(
            "no PostgreSQL server answered at {at} within {CONNECT_WAIT:?}: is it running, \
             and reachable from here?"
        ),
        sqlx::Error::Tls(tls) => format!("the TLS connection to {at} failed: {tls}"),
        sqlx::Error::Database(d) => match d.code().as_deref() {
            Some("28P01" | "28000") => format!(
                "the server at {at} refused the credentials of user `{}`: {}",
                opts.get_username(),
                d.message()
            ),
            Some("3D000") => format!(
                "the server at {at} has no database `{}`: create it (createdb) or name \
                 another",
                opts.get_database().unwrap_or("?")
            ),
            _ => format!("the server at {at} refused the connection: {}", d.message()),
        },
        other => format!("cannot connect to {at}: {other}"),
    };
    StoreError::Postgres {
        url: redacted(url),
        problem,
    }
}

/// Refuses a database that holds another application's tables, or a schema that a newer
/// service has migrated past what this binary knows: migrating either would fail half-way
/// or damage it.
async fn check_schema(pool: &sqlx::PgPool, url: &str) -> Result<()> {
    let tables: Vec<String> = sqlx::query_scalar(
        "SELECT table_name::text FROM information_schema.tables
         WHERE table_schema = current_schema() ORDER BY table_name",
    )
    .fetch_all(pool)
    .await?;
    let refuse = |problem: String| StoreError::Postgres {
        url: redacted(url),
        problem,
    };
    if tables.is_empty() {
        return Ok(());
    }
    if !tables.iter().any(|t| t == MIGRATIONS_TABLE) {
        let shown: Vec<&str> = tables.iter().take(5).map(String::as_str).collect();
        return Err(refuse(format!(
            "the database belongs to another application: it has tables ({}{}) and no \
             Tessera schema; give the service a database of its own",
            shown.join(", "),
            if tables.len() > 5 { ", …" } else { "" }
        )));
    }
    let applied: Vec<(i64, String)> =
        sqlx::query_as("SELECT version, description FROM _sqlx_migrations ORDER BY version")
            .fetch_all(pool)
            .await?;
    let ours = |v: i64| MIGRATOR.iter().find(|m| m.version == v);
    let newest = MIGRATOR.iter().map(|m| m.version).max().unwrap_or(0);
    if let Some((v, _)) = applied.iter().find(|(v, _)| *v > newest) {
        return Err(refuse(format!(
            "the database's schema is newer than this service: it has migration {v}, and \
             this binary knows migrations up to {newest}; run the newer service (or a \
             database of its own)"
        )));
    }
    if let Some((v, d)) = applied
        .iter()
        .find(|(v, d)| ours(*v).is_none_or(|m| m.description != *d))
    {
        return Err(refuse(format!(
            "the database belongs to another application: its migration {v} (`{d}`) is \
             not Tessera's"
        )));
    }
    Ok(())
}

impl PgStore {
    /// Opens the database at `url` (`postgres://USER[:PASSWORD]@HOST:PORT/DB`, with
    /// sqlx's options such as `sslmode`) and brings its schema up to date. Any number of
    /// replicas may do so at once: sqlx's migrator holds an advisory lock while it runs.
    pub(crate) async fn open(url: &str) -> Result<PgStore> {
        let opts = PgConnectOptions::from_str(url).map_err(|e| StoreError::Url {
            url: redacted(url),
            reason: e.to_string(),
        })?;
        // Named in the server's activity views, unless the URL names it otherwise.
        let opts = if url.contains("application_name=") {
            opts
        } else {
            opts.application_name("tessera-service")
        };
        // One connection first, so that a refused one is told at once and named (a pool
        // retries until its timeout, and then says only that it timed out).
        let first = tokio::time::timeout(CONNECT_WAIT, PgConnection::connect_with(&opts))
            .await
            .map_err(|_| sqlx::Error::PoolTimedOut)
            .and_then(|c| c)
            .map_err(|e| open_error(url, &opts, e))?;
        let _ = first.close().await;
        let pool = PgPoolOptions::new()
            .max_connections(POOL_SIZE)
            .min_connections(1)
            .acquire_timeout(CONNECT_WAIT)
            // No ping before each use: it doubles every statement's round trips. A
            // connection the server dropped fails its next statement instead, which is
            // answered `503` like any lost connection, and the pool opens a fresh one.
            .test_before_acquire(false)
            .connect_with(opts.clone())
            .await
            .map_err(|e| open_error(url, &opts, e))?;
        check_schema(&pool, url).await?;
        MIGRATOR.run(&pool).await.map_err(|e| match e {
            sqlx::migrate::MigrateError::VersionMissing(v) => StoreError::Postgres {
                url: redacted(url),
                problem: format!(
                    "the database has migration {v}, which this service does not know: \
                     its schema is newer (or another application's)"
                ),
            },
            other => StoreError::Migrate(other),
        })?;
        Ok(PgStore {
            pool,
            opts: Arc::new(opts),
            max_attempts: super::super::DEFAULT_MAX_ATTEMPTS,
            leader: Arc::default(),
            failures: Arc::default(),
            shared_failed: Arc::new(AtomicI64::new(i64::MIN)),
            roster: Arc::default(),
        })
    }

    /// The same store, failing a job whose tile lost its pixels `n` times.
    pub(crate) fn max_attempts(mut self, n: u32) -> PgStore {
        self.max_attempts = n;
        self
    }

    /// Answers when the database does.
    pub(crate) async fn ping(&self) -> Result<()> {
        sqlx::query("SELECT 1").execute(&self.pool).await?;
        Ok(())
    }
}
