//! What the PostgreSQL backend guarantees beyond the store suite's: what replicas on one
//! database share (the storage failing, the leases refused, the roster), the wake-ups
//! between them, the maintenance lock, and a result racing its job's cancellation.
//!
//! Run against the throwaway server of the end-to-end tests (`tests/src/pg.rs`); each test
//! gets a database of its own.

use std::sync::Arc;
use std::time::Duration;

use sqlx::Connection;
use tessera_service::store::{
    Completion, JobState, KeepAway, NewJob, Retried, Store, StoreError, TileState,
};
use tessera_tracer::{Rect, tiles};

const KEEP: KeepAway = KeepAway {
    after: 2,
    for_ms: 60_000,
    stall_ms: 500,
};

/// The throwaway PostgreSQL server, shared with the end-to-end tests.
#[allow(dead_code)]
#[path = "../../tests/src/pg.rs"]
mod pg;

/// A database of the test's own on the server (dropped with the returned value).
fn database() -> pg::Database {
    pg::database()
}

async fn job(q: &Store, id: &str, w: u32, h: u32, tile: u32) -> Vec<Rect> {
    let rects = tiles(w, h, tile);
    q.insert_job(
        &NewJob {
            id: id.into(),
            scene: "[GLOBALS]\n[/GLOBALS]\n".into(),
            name: None,
            width: w,
            height: h,
            tile,
            sampler: None,
            samples: None,
            threshold: None,
            created_at: 0,
            priority: 0,
        },
        &rects,
        &[],
    )
    .await
    .expect("job stored");
    rects
}

/// An error of the storage failing, as a lost connection gives.
fn storage_error() -> StoreError {
    StoreError::Db(sqlx::Error::Io(std::io::Error::from(
        std::io::ErrorKind::ConnectionReset,
    )))
}

/// What one replica noted while the database failed (a refused renewal, the failure's
/// time, the workers it heard) reaches the others once shared: their reaper extends the
/// lease it refused, reaps the lease nobody asked about, and lists the workers.
#[tokio::test]
async fn what_one_replica_noted_is_shared_with_the_others() {
    let db = database();
    let url = db.url.clone();
    let one = Store::open(&url).await.expect("open");
    let other = Store::open(&url).await.expect("open again");
    job(&one, "j", 16, 8, 8).await;
    let asked = one.claim("asked", 0, 1_000, 4).await.expect("claim");
    let silent = one.claim("silent", 0, 1_000, 4).await.expect("claim");
    let (asked, silent) = (asked.expect("a tile"), silent.expect("a tile"));
    let within = Duration::from_secs(60);
    let _ = one.heard_refused(&asked.lease, storage_error(), 500);
    one.seen("asked", 500, |w| w.claims += 1);
    assert!(one.storage_failed_within(500, within));
    assert!(!other.storage_failed_within(500, within));

    one.share(600).await.expect("share");
    other.share(700).await.expect("read what was shared");
    assert!(other.storage_failed_within(700, within));
    assert!(!other.storage_failed_within(700 + 60_000, within));
    let listed = other.workers(0).await.expect("workers");
    assert_eq!(listed.len(), 1);
    assert_eq!((listed[0].name.as_str(), listed[0].claims), ("asked", 1));

    assert_eq!(
        other
            .reap_unheard(5_000, 1_000, within, 4, KEEP)
            .await
            .expect("pass"),
        (1, 1)
    );
    let t = other
        .tile("j", asked.idx)
        .await
        .expect("read")
        .expect("tile");
    assert_eq!(t.lease.as_deref(), Some(asked.lease.as_str()));
    let t = other
        .tile("j", silent.idx)
        .await
        .expect("read")
        .expect("tile");
    assert_eq!(t.lease, None, "the silent worker's tile is queued again");
    // Past the window, the shared lease is no longer extended.
    assert_eq!(
        other
            .reap_unheard(200_000, 1_000, within, 4, KEEP)
            .await
            .expect("pass"),
        (0, 1)
    );
}

/// A submission on one replica wakes what waits for work on another, through the
/// database, with no polling.
#[tokio::test]
async fn a_submission_on_one_replica_wakes_another() {
    let db = database();
    let url = db.url.clone();
    let one = Store::open(&url).await.expect("open");
    let other = Store::open(&url).await.expect("open again");
    let (work, ended) = (
        Arc::new(tokio::sync::Notify::new()),
        Arc::new(tokio::sync::Notify::new()),
    );
    let (stop, stopped) = tokio::sync::watch::channel(false);
    // Listening begins with a wake-up of each (news may have been missed before).
    let first = work.notified();
    tokio::pin!(first);
    first.as_mut().enable();
    let listening = tokio::spawn({
        let (work, ended) = (work.clone(), ended.clone());
        async move { other.listen(work, ended, stopped).await }
    });
    tokio::time::timeout(Duration::from_secs(10), first)
        .await
        .expect("listening");
    let woken = work.notified();
    tokio::pin!(woken);
    woken.as_mut().enable();
    job(&one, "j", 8, 8, 8).await;
    tokio::time::timeout(Duration::from_secs(10), woken)
        .await
        .expect("woken by the submission");
    let finished = ended.notified();
    tokio::pin!(finished);
    finished.as_mut().enable();
    one.cancel("j", 10).await.expect("cancel");
    tokio::time::timeout(Duration::from_secs(10), finished)
        .await
        .expect("woken by the cancellation");
    stop.send(true).expect("listener");
    listening.await.expect("listener stops");
}

/// One replica at a time holds the maintenance lock; it passes on when the holder goes.
#[tokio::test]
async fn one_replica_at_a_time_maintains() {
    let db = database();
    let url = db.url.clone();
    let one = Store::open(&url).await.expect("open");
    let other = Store::open(&url).await.expect("open again");
    assert!(one.maintains().await);
    assert!(!other.maintains().await);
    assert!(one.maintains().await, "held on the next pass");
    drop(one);
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    while !other.maintains().await {
        assert!(tokio::time::Instant::now() < deadline, "the lock passed on");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// A result whose job is cancelled between its tile's check and its count is stored and
/// counted, as every tile the job stored before its end: the tile's state, the job's count
/// and the pixels agree, and a retry keeps the tile.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_result_racing_its_jobs_cancellation_is_kept_and_counted() {
    let db = database();
    let url = db.url.clone();
    let q = Store::open(&url).await.expect("open");
    job(&q, "j", 16, 8, 8).await;
    let c = q
        .claim("w", 0, 60_000, 4)
        .await
        .expect("claim")
        .expect("a tile");
    let mut canceller = sqlx::PgConnection::connect(&url).await.expect("connect");
    let mut tx = canceller.begin().await.expect("begin");
    sqlx::query("SELECT 1 FROM jobs WHERE id = 'j' FOR UPDATE")
        .execute(&mut *tx)
        .await
        .expect("lock the job");
    let idx = c.idx;
    let posting = tokio::spawn({
        let q = q.clone();
        async move {
            let rgb = vec![7; c.rect().pixel_count() * 3];
            q.complete("j", c.idx, &c.lease, c.rect(), &rgb, 0).await
        }
    });
    // The result has marked its tile and waits for the job's row.
    let mut watcher = sqlx::PgConnection::connect(&url).await.expect("connect");
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    loop {
        let waiting: i64 = sqlx::query_scalar(
            "SELECT COUNT(*) FROM pg_stat_activity
             WHERE datname = current_database() AND wait_event_type = 'Lock'",
        )
        .fetch_one(&mut watcher)
        .await
        .expect("activity");
        if waiting > 0 {
            break;
        }
        assert!(tokio::time::Instant::now() < deadline, "the result waits");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    sqlx::query("UPDATE jobs SET state = 'cancelled', finished_at = 1 WHERE id = 'j'")
        .execute(&mut *tx)
        .await
        .expect("cancel");
    tx.commit().await.expect("commit");
    let posted = posting.await.expect("ran").expect("complete");
    assert!(
        matches!(&posted, Completion::Stored { last: false, .. }),
        "{posted:?}"
    );
    let kept: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM tile_pixels")
        .fetch_one(&mut watcher)
        .await
        .expect("count");
    assert_eq!(kept, 1);
    let j = q.job("j").await.expect("read").expect("job");
    assert_eq!((j.state, j.tiles_done), (JobState::Cancelled, 1));
    assert_eq!(
        q.retry("j", 2).await.expect("retry"),
        Retried::Retried { complete: false }
    );
    let j = q.job("j").await.expect("read").expect("job");
    assert_eq!(j.tiles_done, 1);
    let tile = q.tile("j", idx).await.expect("read").expect("tile");
    assert_eq!(tile.state, TileState::Done);
}
