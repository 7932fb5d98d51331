//! The SQLite backend's own checks: its connections after a failure, its query plans, its
//! URLs, and its schema's states against [`JobState`] and [`TileState`].

use std::time::Duration;

use super::SqliteStore;
use super::images::BAND_SQL;
use super::leases::CLAIM_SQL;
use crate::store::error::{SpoolError, StoreError};
use crate::store::state::{JobState, TileState};
use crate::store::types::NewJob;

/// A transaction that fails on a full database (here the writer's `max_page_count`)
/// leaves the store working once there is room again: later transactions on the writer
/// succeed. SQLite rolls such a transaction back itself, and sqlx, still counting it,
/// would refuse every later `BEGIN` on that connection, which `Writer::lock` replaces.
#[tokio::test]
async fn a_transaction_that_failed_on_a_full_database_leaves_the_writer_usable() {
    let dir = std::env::temp_dir().join(format!("tessera-full-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    let q = SqliteStore::open(&format!("sqlite://{}", dir.join("q.db").display()))
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
    assert!(!q.storage_failed_within(0, Duration::from_secs(60)));
    let _ = q.noted(full, 0);
    assert!(q.storage_failed_within(0, Duration::from_secs(60)));
    let not_storage = StoreError::Url {
        url: "x".into(),
        reason: "y".into(),
    };
    assert!(!not_storage.is_storage());
    // The spool's failures are storage failures, but refuse no renewal: not noted.
    let spool = StoreError::Spool(SpoolError::Io {
        path: dir.join("x.rgb"),
        source: std::io::Error::from_raw_os_error(28),
    });
    assert!(spool.is_storage());
    let q2 = SqliteStore::open(&format!("sqlite://{}", dir.join("q2.db").display()))
        .await
        .expect("open");
    let _ = q2.noted(spool, 0);
    assert!(!q2.storage_failed_within(0, Duration::from_secs(60)));
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
/// planner would find the active jobs through `jobs_by_state` and sort them all, each
/// checked for a tile the worker may take, on every claim.
#[tokio::test]
async fn the_claim_walks_the_active_jobs_in_order() {
    let q = SqliteStore::open("sqlite::memory:").await.expect("open");
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
    let q = SqliteStore::open("sqlite::memory:").await.expect("open");
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

/// A database the store cannot use says which and why: another scheme is refused as
/// not SQLite (sqlx would take it for a file name), and so is a SQLite URI file name; a file
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
        match SqliteStore::open(url).await {
            Err(e @ StoreError::Url { .. }) => {
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
    match SqliteStore::open(&missing).await {
        Err(e @ StoreError::Open { .. }) => {
            assert!(e.to_string().contains(&missing), "{e}");
        }
        other => panic!("{missing}: {:?}", other.err()),
    }
    std::fs::create_dir_all(&dir).expect("temp dir");
    let bare = dir.join("q.db");
    let q = SqliteStore::open(&bare.display().to_string()).await;
    assert!(q.is_ok(), "{:?}", q.err());
    assert!(bare.exists());
    drop(q);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Every state's text round-trips through its enum, and the schema's `CHECK` constraints
/// on `jobs.state` and `tiles.state` list exactly the enums' texts, in their order.
#[tokio::test]
async fn the_schemas_states_are_exactly_the_enums() {
    for s in JobState::ALL {
        assert_eq!(JobState::parse(s.as_str()), Some(s));
        assert_eq!(JobState::try_from(s.as_str().to_string()), Ok(s));
        assert_eq!(serde_json::to_value(s).expect("json"), s.as_str());
    }
    for s in TileState::ALL {
        assert_eq!(TileState::parse(s.as_str()), Some(s));
        assert_eq!(TileState::try_from(s.as_str().to_string()), Ok(s));
    }
    assert!(JobState::parse("leased").is_none() && TileState::parse("running").is_none());
    let q = SqliteStore::open("sqlite::memory:").await.expect("open");
    let mut w = q.writer.lock().await.expect("the writer");
    for (table, texts) in [
        ("jobs", JobState::ALL.map(JobState::as_str).to_vec()),
        ("tiles", TileState::ALL.map(TileState::as_str).to_vec()),
    ] {
        let sql: String = sqlx::query_scalar("SELECT sql FROM sqlite_master WHERE name = ?1")
            .bind(table)
            .fetch_one(&mut *w)
            .await
            .expect("schema");
        let check = sql
            .split("CHECK (state IN (")
            .nth(1)
            .and_then(|rest| rest.split("))").next())
            .expect("a CHECK on state");
        let listed: Vec<String> = check
            .split(',')
            .map(|t| t.trim().trim_matches('\'').to_string())
            .collect();
        assert_eq!(listed, texts, "{table}");
    }
}
