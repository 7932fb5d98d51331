//! The store's guarantees, against real databases: atomic claims under contention, lease
//! fencing, harmless repeats, bounded failures, keep-away, expiry.
//!
//! Each test of the store's API runs on both backends, as `NAME::sqlite` (a SQLite file of
//! its own) and `NAME::postgres` (a database of its own on this test binary's throwaway
//! PostgreSQL server, see `pg`): the same body, given its database as a [`Db`]. The tests
//! of what only SQLite has (its WAL checkpoints, its tile spool, its migrations from older
//! files) are plain tests, each marked "SQLite only" with the reason.

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use tessera_service::store::{
    Cancel, Completion, JobState, KeepAway, NewJob, Retried, Store, StoreError,
};
use tessera_tracer::{Rect, tiles};

/// The throwaway PostgreSQL server, shared with the end-to-end tests.
#[allow(dead_code)]
#[path = "../../tests/src/pg.rs"]
mod pg;

/// Opens the store at `url`: every test opens its store through here, so that the same
/// tests can run against each backend, given its URL.
async fn open_store(url: &str) -> Result<Store, StoreError> {
    Store::open(url).await
}

/// Which backend a test's database is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Backend {
    Sqlite,
    Postgres,
}

/// A test's own database, removed when the test ends: a SQLite file in a folder of its
/// own, or a database of its own on the test binary's PostgreSQL server.
struct Db {
    backend: Backend,
    url: String,
    /// The SQLite database's folder.
    dir: Option<PathBuf>,
    _pg: Option<pg::Database>,
}

impl Db {
    /// A SQLite database `q.db` in a new folder named after `tag`.
    fn sqlite(tag: &str) -> Db {
        let dir = std::env::temp_dir().join(format!("tessera-queue-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("temp dir");
        Db {
            backend: Backend::Sqlite,
            url: format!("sqlite://{}", dir.join("q.db").display()),
            dir: Some(dir),
            _pg: None,
        }
    }

    /// A new database on the test binary's PostgreSQL server.
    fn postgres() -> Db {
        let db = pg::database();
        Db {
            backend: Backend::Postgres,
            url: db.url.clone(),
            dir: None,
            _pg: Some(db),
        }
    }

    fn url(&self) -> String {
        self.url.clone()
    }

    /// The SQLite database's folder (its file `q.db`, its spool `q.db-tiles`).
    fn dir(&self) -> &Path {
        self.dir.as_deref().expect("a SQLite database has a folder")
    }

    /// Runs `sql` (one or more statements) on the database beside the store.
    async fn execute(&self, sql: &'static str) {
        match self.backend {
            Backend::Sqlite => {
                let pool = sqlx::SqlitePool::connect(&self.url).await.expect("open");
                sqlx::raw_sql(sql).execute(&pool).await.expect("SQL runs");
                pool.close().await;
            }
            Backend::Postgres => {
                let pool = sqlx::PgPool::connect(&self.url).await.expect("open");
                sqlx::raw_sql(sql).execute(&pool).await.expect("SQL runs");
                pool.close().await;
            }
        }
    }

    /// The one integer that `sql` selects, read beside the store.
    async fn count(&self, sql: &'static str) -> i64 {
        match self.backend {
            Backend::Sqlite => {
                let pool = sqlx::SqlitePool::connect(&self.url).await.expect("open");
                let n = sqlx::query_scalar(sql)
                    .fetch_one(&pool)
                    .await
                    .expect("read");
                pool.close().await;
                n
            }
            Backend::Postgres => {
                let pool = sqlx::PgPool::connect(&self.url).await.expect("open");
                let n = sqlx::query_scalar(sql)
                    .fetch_one(&pool)
                    .await
                    .expect("read");
                pool.close().await;
                n
            }
        }
    }
}

impl Drop for Db {
    fn drop(&mut self) {
        if let Some(dir) = &self.dir {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

/// Runs test function `$name` (an `async fn` taking a [`Db`]) on each backend: the tests
/// `$name::sqlite` and `$name::postgres`, under `#[tokio::test]` or the attribute given.
macro_rules! on_both {
    ($name:ident) => {
        on_both!($name, #[tokio::test]);
    };
    ($name:ident, #[$test:meta]) => {
        mod $name {
            use super::Db;

            #[$test]
            async fn sqlite() {
                super::$name(Db::sqlite(stringify!($name))).await
            }

            #[$test]
            async fn postgres() {
                super::$name(Db::postgres()).await
            }
        }
    };
}

const KEEP: KeepAway = KeepAway {
    after: 2,
    for_ms: 60_000,
    stall_ms: 500,
};

async fn job(q: &Store, id: &str, w: u32, h: u32, tile: u32) -> Vec<Rect> {
    job_at(q, id, 0, w, h, tile).await
}

/// [`job`] of a given priority.
async fn job_at(q: &Store, id: &str, priority: i64, w: u32, h: u32, tile: u32) -> Vec<Rect> {
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
            priority,
        },
        &rects,
        &[],
    )
    .await
    .expect("job stored");
    rects
}

fn pixels(r: Rect) -> Vec<u8> {
    vec![7; r.pixel_count() * 3]
}

/// Every tile the queue hands worker `w` now, in order (`max_attempts` as `claim` takes it).
async fn claim_all(q: &Store, max_attempts: u32) -> Vec<tessera_protocol::Claim> {
    let mut claims = Vec::new();
    while let Some(c) = q.claim("w", 0, 60_000, max_attempts).await.expect("claim") {
        claims.push(c);
    }
    claims
}

/// The stored tiles of the band at row `y`, as `Store::band` hands them over.
async fn band(q: &Store, id: &str, y: u32) -> Vec<(u32, u32, u32, Vec<u8>)> {
    let mut buf = Vec::new();
    let tiles = q.band(id, y, 0, &mut buf).await.expect("band");
    tiles
        .into_iter()
        .map(|t| (t.x, t.w, t.h, buf[t.bytes].to_vec()))
        .collect()
}

async fn concurrent_claimers_never_share_a_tile(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    let rects = job(&q, "j", 160, 160, 8).await; // 400 tiles
    let claimed = Arc::new(std::sync::Mutex::new(Vec::new()));
    let mut tasks = Vec::new();
    // Separate pools, as separate service processes on one file would have.
    for w in 0..12 {
        let url = db.url();
        let claimed = claimed.clone();
        tasks.push(tokio::spawn(async move {
            let q = open_store(&url).await.expect("open");
            let name = format!("w{w}");
            while let Some(c) = q.claim(&name, 1_000, 60_000, 4).await.expect("claim") {
                let stored = q
                    .complete(&c.job, c.idx, &c.lease, c.rect(), &pixels(c.rect()), 0)
                    .await
                    .expect("complete");
                let Completion::Stored { last, worker } = stored else {
                    panic!("not stored: {stored:?}");
                };
                assert_eq!(worker.as_deref(), Some(name.as_str()));
                claimed.lock().expect("not poisoned").push((c.idx, last));
            }
        }));
    }
    for t in tasks {
        t.await.expect("claimer ran");
    }
    let claimed = claimed.lock().expect("not poisoned").clone();
    // Exactly one result is the job's last: the one that set off the image's assembly.
    assert_eq!(claimed.iter().filter(|(_, last)| *last).count(), 1);
    let distinct: HashSet<_> = claimed.iter().map(|(idx, _)| idx).collect();
    assert_eq!(
        claimed.len(),
        rects.len(),
        "every tile claimed exactly once"
    );
    assert_eq!(distinct.len(), rects.len());
    let j = q.job("j").await.expect("read").expect("job");
    assert_eq!(j.tiles_done, rects.len() as i64);
}
on_both!(
    concurrent_claimers_never_share_a_tile,
    #[tokio::test(flavor = "multi_thread", worker_threads = 4)]
);

async fn stale_and_repeated_results_change_nothing(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    job(&q, "j", 16, 8, 8).await;
    let first = q
        .claim("a", 0, 100, 4)
        .await
        .expect("claim")
        .expect("a tile");
    // The lease expires and the tile is handed to b.
    assert_eq!(q.reap(1_000, 4, KEEP).await.expect("reap"), 1);
    let second = q
        .claim("b", 1_000, 100, 4)
        .await
        .expect("claim")
        .expect("a tile");
    assert_eq!(
        (first.job.as_str(), first.idx),
        (second.job.as_str(), second.idx)
    );
    assert_ne!(first.lease, second.lease);

    let rgb = pixels(first.rect());
    let late = q
        .complete("j", first.idx, &first.lease, first.rect(), &rgb, 0)
        .await
        .expect("complete");
    assert!(matches!(late, Completion::Stale(_)), "{late:?}");
    assert!(
        q.renew("j", first.idx, &first.lease, 1_000, 100, true)
            .await
            .expect("renew")
            .is_none()
    );
    assert_eq!(q.job("j").await.expect("read").expect("job").tiles_done, 0);

    let ok = q
        .complete("j", second.idx, &second.lease, second.rect(), &rgb, 0)
        .await
        .expect("complete");
    assert_eq!(
        ok,
        Completion::Stored {
            last: false,
            worker: Some("b".into())
        }
    );
    let again = q
        .complete("j", second.idx, &second.lease, second.rect(), &rgb, 0)
        .await
        .expect("complete");
    assert_eq!(again, Completion::Repeat);
    assert_eq!(q.job("j").await.expect("read").expect("job").tiles_done, 1);
    // A failure or release on a finished tile is refused too.
    assert!(
        !q.release("j", second.idx, &second.lease)
            .await
            .expect("release")
    );

    // The job's other tile: pixels for the wrong rectangle are refused under a current
    // lease and change nothing; the right ones complete the job, and only they are `last`.
    let other = q
        .claim("c", 1_000, 100, 4)
        .await
        .expect("claim")
        .expect("the second tile");
    assert_ne!(other.idx, second.idx);
    let wrong = q
        .complete("j", other.idx, &other.lease, second.rect(), &rgb, 0)
        .await
        .expect("complete");
    assert_eq!(wrong, Completion::WrongTile(other.rect()));
    assert_eq!(q.job("j").await.expect("read").expect("job").tiles_done, 1);
    let last = q
        .complete(
            "j",
            other.idx,
            &other.lease,
            other.rect(),
            &pixels(other.rect()),
            0,
        )
        .await
        .expect("complete");
    assert_eq!(
        last,
        Completion::Stored {
            last: true,
            worker: Some("c".into())
        }
    );
    assert_eq!(q.job("j").await.expect("read").expect("job").tiles_done, 2);
    let missing = q
        .complete("j", 99, &other.lease, other.rect(), &rgb, 0)
        .await
        .expect("complete");
    assert_eq!(missing, Completion::Missing);
}
on_both!(stale_and_repeated_results_change_nothing);

async fn failing_tiles_move_to_other_workers_then_fail_the_job(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    job(&q, "j", 8, 8, 8).await; // one tile
    let max = 3;
    // Worker a fails it twice: kept away from the job.
    for _ in 0..2 {
        let c = q
            .claim("a", 10, 1_000, max)
            .await
            .expect("claim")
            .expect("tile");
        assert!(
            q.fail_tile("j", c.idx, &c.lease, "a", "out of memory", 10, max, KEEP)
                .await
                .expect("fail")
        );
    }
    assert!(
        q.claim("a", 20, 1_000, max).await.expect("claim").is_none(),
        "a is kept away"
    );
    // b gets it, and its failure is the third: the job fails with a readable reason.
    let c = q
        .claim("b", 20, 1_000, max)
        .await
        .expect("claim")
        .expect("tile for b");
    assert!(
        q.fail_tile("j", c.idx, &c.lease, "b", "disk full", 30, max, KEEP)
            .await
            .expect("fail")
    );
    let j = q.job("j").await.expect("read").expect("job");
    assert_eq!(j.state, JobState::Failed);
    let why = j.error.expect("a reason");
    assert!(
        why.contains("failed 3 times") && why.contains("disk full"),
        "{why}"
    );
    assert!(q.claim("c", 40, 1_000, max).await.expect("claim").is_none());
}
on_both!(failing_tiles_move_to_other_workers_then_fail_the_job);

/// A worker's two leases (the tile it renders, the one it holds ahead) run out a renewal
/// period apart and are reaped in two passes: still one stall, and only the first tile
/// charged. Counted twice, the held tile, never begun, would run out of attempts with the
/// next worker's loss. Stalls are counted apart from reported failures and never keep a
/// worker away: a worker restarted under its name is no evidence against it.
async fn a_stall_reaped_in_two_passes_is_one_stall_and_one_failure(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    job(&q, "j", 16, 8, 8).await; // tiles 0 and 1
    let max = 2;
    let a = q
        .claim("w", 0, 1_000, max)
        .await
        .expect("claim")
        .expect("0");
    let b = q
        .claim("w", 300, 1_000, max)
        .await
        .expect("claim")
        .expect("1");
    assert_eq!((a.idx, b.idx), (0, 1));
    assert_eq!(q.reap(1_100, max, KEEP).await.expect("reap"), 1);
    assert_eq!(q.reap(1_400, max, KEEP).await.expect("reap"), 1);
    // Nothing was renewed as rendering: the first to run out is charged.
    assert_eq!(failures(&db, "j").await, vec![1, 0]);
    // Tile 0 is rendered by another worker; tile 1's next holder is lost too: its first
    // charged failure, so the job goes on.
    let c = q
        .claim("v", 1_500, 1_000, max)
        .await
        .expect("claim")
        .expect("0");
    assert_eq!(c.idx, 0);
    q.complete("j", c.idx, &c.lease, c.rect(), &pixels(c.rect()), 0)
        .await
        .expect("complete");
    let d = q
        .claim("v", 1_600, 1_000, max)
        .await
        .expect("claim")
        .expect("1");
    assert_eq!(d.idx, 1);
    assert_eq!(q.reap(2_700, max, KEEP).await.expect("reap"), 1);
    assert_eq!(
        q.job("j").await.expect("read").expect("job").state,
        JobState::Running
    );
    // And `w`, with one stall, may take it.
    let e = q.claim("w", 2_800, 1_000, max).await.expect("claim");
    assert_eq!(e.map(|e| e.idx), Some(1), "one stall kept `w` away");
    assert_eq!(keep_away(&db, "j", "w").await, (0, 1));
    // A second stall of `w`, past the first's window, is a second stall, not a failure:
    // `w` is not kept away (with one attempt more allowed, so that the job goes on).
    assert_eq!(q.reap(3_900, max + 1, KEEP).await.expect("reap"), 1);
    assert_eq!(
        q.job("j").await.expect("read").expect("job").state,
        JobState::Running
    );
    assert_eq!(keep_away(&db, "j", "w").await, (0, 2));
    assert_eq!(
        q.claim("w", 4_000, 1_000, max + 1)
            .await
            .expect("claim")
            .map(|c| c.idx),
        Some(1),
        "two stalls kept `w` away"
    );
}
on_both!(a_stall_reaped_in_two_passes_is_one_stall_and_one_failure);

/// A worker's `(failures, stalls)` on a job, read from the database beside the queue.
async fn keep_away(db: &Db, job: &str, worker: &str) -> (i64, i64) {
    match db.backend {
        Backend::Sqlite => {
            let pool = sqlx::SqlitePool::connect(&db.url()).await.expect("open");
            let row = sqlx::query_as(
                "SELECT failures, stalls FROM keep_away WHERE job_id = ?1 AND worker = ?2",
            )
            .bind(job)
            .bind(worker)
            .fetch_one(&pool)
            .await
            .expect("read");
            pool.close().await;
            row
        }
        Backend::Postgres => {
            let pool = sqlx::PgPool::connect(&db.url()).await.expect("open");
            let row = sqlx::query_as(
                "SELECT failures, stalls FROM keep_away WHERE job_id = $1 AND worker = $2",
            )
            .bind(job)
            .bind(worker)
            .fetch_one(&pool)
            .await
            .expect("read");
            pool.close().await;
            row
        }
    }
}

/// Each tile's failures, read from the database beside the queue.
async fn failures(db: &Db, job: &str) -> Vec<i64> {
    let rows: Vec<(i64,)> = match db.backend {
        Backend::Sqlite => {
            let pool = sqlx::SqlitePool::connect(&db.url()).await.expect("open");
            let rows = sqlx::query_as("SELECT failures FROM tiles WHERE job_id = ?1 ORDER BY idx")
                .bind(job)
                .fetch_all(&pool)
                .await
                .expect("read");
            pool.close().await;
            rows
        }
        Backend::Postgres => {
            let pool = sqlx::PgPool::connect(&db.url()).await.expect("open");
            let rows = sqlx::query_as("SELECT failures FROM tiles WHERE job_id = $1 ORDER BY idx")
                .bind(job)
                .fetch_all(&pool)
                .await
                .expect("read");
            pool.close().await;
            rows
        }
    };
    rows.into_iter().map(|(f,)| f).collect()
}

/// A worker of two threads stalls holding four tiles: the two it said it was rendering
/// are charged a failure each, the two it held ahead none, and the worker one strike.
/// (Charging only the first to run out would leave a tile that crashes workers of many
/// threads uncharged most of the time.)
async fn a_stall_charges_the_tiles_being_rendered(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    job(&q, "j", 48, 8, 8).await; // tiles 0 to 5
    let max = 3;
    let mut held = Vec::new();
    for t in [0, 10, 20, 30] {
        held.push(
            q.claim("w", t, 1_000, max)
                .await
                .expect("claim")
                .expect("tile"),
        );
    }
    // Thread A renders tile 0 with tile 2 ahead; thread B tile 1 with tile 3 ahead. The
    // renewals come at different moments: B's rendering tile runs out after A's held one.
    for (c, t, rendering) in [
        (0, 300, true),
        (2, 300, false),
        (1, 350, true),
        (3, 350, false),
    ] {
        let c = &held[c];
        let renewed = q
            .renew("j", c.idx, &c.lease, t, 1_000, rendering)
            .await
            .expect("renew");
        assert!(renewed.is_some());
    }
    assert_eq!(q.reap(1_400, max, KEEP).await.expect("reap"), 4);
    assert_eq!(failures(&db, "j").await, vec![1, 1, 0, 0, 0, 0]);
    // One strike of two: `w` may go on.
    assert!(
        q.claim("w", 1_500, 1_000, max)
            .await
            .expect("claim")
            .is_some()
    );
}
on_both!(a_stall_charges_the_tiles_being_rendered);

/// The `rendering` flag is the holder's, not the tile's: a tile renewed as rendering, given
/// back and claimed again to be held ahead is not charged when its new holder stalls, and
/// the tile that holder renders is (the flag had stayed, charging the held tile and
/// sparing the rendered one).
async fn the_rendering_flag_does_not_pass_to_the_next_holder(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    job(&q, "j", 32, 8, 8).await; // tiles 0 to 3
    let max = 4;
    let a0 = q
        .claim("a", 0, 1_000, max)
        .await
        .expect("claim")
        .expect("0");
    let b1 = q
        .claim("b", 10, 1_000, max)
        .await
        .expect("claim")
        .expect("1");
    assert_eq!((a0.idx, b1.idx), (0, 1));
    let renewed = q.renew("j", 0, &a0.lease, 300, 1_000, true).await;
    assert!(renewed.expect("renew").is_some());
    assert!(q.release("j", 0, &a0.lease).await.expect("release"));
    // `b` renders tile 1 and holds tile 0 ahead, then stalls before renewing either.
    let b0 = q
        .claim("b", 410, 1_000, max)
        .await
        .expect("claim")
        .expect("0");
    assert_eq!(b0.idx, 0);
    assert_eq!(q.reap(1_500, max, KEEP).await.expect("reap"), 2);
    assert_eq!(failures(&db, "j").await, vec![0, 1, 0, 0]);
}
on_both!(the_rendering_flag_does_not_pass_to_the_next_holder);

async fn lost_leases_count_as_failures(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    job(&q, "j", 8, 8, 8).await;
    let max = 2;
    for (i, w) in ["a", "b"].iter().enumerate() {
        let now = i as i64 * 1_000;
        assert!(q.claim(w, now, 100, max).await.expect("claim").is_some());
        assert_eq!(q.reap(now + 500, max, KEEP).await.expect("reap"), 1);
    }
    let j = q.job("j").await.expect("read").expect("job");
    assert_eq!(j.state, JobState::Failed);
    assert!(j.error.unwrap_or_default().contains("stopped answering"));
}
on_both!(lost_leases_count_as_failures);

async fn a_job_no_live_worker_may_take_fails(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    job(&q, "j", 8, 8, 8).await;
    for _ in 0..2 {
        let c = q
            .claim("only", 0, 1_000, 9)
            .await
            .expect("claim")
            .expect("tile");
        q.fail_tile("j", c.idx, &c.lease, "only", "bad texture", 0, 9, KEEP)
            .await
            .expect("fail");
    }
    // Another live worker could still take it: nothing happens.
    let live = vec!["only".to_string(), "other".to_string()];
    assert_eq!(q.fail_unservable(&live, 1).await.expect("check"), 0);
    assert_eq!(q.fail_unservable(&live[..1], 1).await.expect("check"), 1);
    let j = q.job("j").await.expect("read").expect("job");
    assert_eq!(j.state, JobState::Failed);
    assert!(j.error.unwrap_or_default().contains("bad texture"));
}
on_both!(a_job_no_live_worker_may_take_fails);

/// A job whose every tile is stored is not cancelled: its image is being written, and the
/// worker that posted the last tile was told it was stored. (Else a cancel racing the last
/// result would end such a job "cancelled" with all its tiles done and no image.)
async fn a_job_with_every_tile_in_is_not_cancelled(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    job(&q, "j", 16, 8, 8).await;
    for last in [false, true] {
        let c = q
            .claim("w", 0, 1_000, 1)
            .await
            .expect("claim")
            .expect("tile");
        let stored = q
            .complete("j", c.idx, &c.lease, c.rect(), &pixels(c.rect()), 0)
            .await
            .expect("complete");
        assert!(matches!(stored, Completion::Stored { last: l, .. } if l == last));
    }
    assert_eq!(q.cancel("j", 5).await.expect("cancel"), Cancel::Complete);
    let j = q.job("j").await.expect("read").expect("job");
    assert_eq!(j.state, JobState::Running);
    assert_eq!(band(&q, "j", 0).await.len(), 2, "its pixels are kept");
}
on_both!(a_job_with_every_tile_in_is_not_cancelled);

/// A job that ends without an image (cancelled, failed) drops the chunks of its PNG
/// encoded so far, and keeps its stored tiles: a retry makes it active again with them, and
/// hands out only the others.
async fn a_job_that_ends_without_an_image_keeps_its_tiles_for_a_retry(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    // A job of two tiles stores one of them, and the first chunk of its PNG; returns the
    // stored tile's index.
    let store_one = async |id: &str| {
        job(&q, id, 16, 8, 8).await;
        let c = q
            .claim("w", 0, 1_000, 1)
            .await
            .expect("claim")
            .expect("tile");
        assert_eq!(c.job, id);
        let stored = q
            .complete(id, c.idx, &c.lease, c.rect(), &pixels(c.rect()), 0)
            .await
            .expect("complete");
        assert!(matches!(stored, Completion::Stored { last: false, .. }));
        assert_eq!(band(&q, id, 0).await.len(), 1);
        q.put_image_chunk(id, 0, b"PNG so far")
            .await
            .expect("chunk");
        assert_eq!(q.image_chunks(id).await.expect("count"), 1);
        c
    };
    // What an ended job keeps: its stored tile's pixels, no chunk of its image.
    let kept = async |id: &str, c: &tessera_protocol::Claim| {
        let mut buf = Vec::new();
        let tiles = q.stored_band(id, (16, 8), 0, &mut buf).await.expect("band");
        assert_eq!(tiles.len(), 1);
        assert_eq!(buf[tiles[0].bytes.clone()], pixels(c.rect()));
        assert_eq!(q.image_chunks(id).await.expect("count"), 0);
    };
    // Retried: active again with the tile counted; the other is the only one handed out.
    let retried = async |id: &str, c: &tessera_protocol::Claim| {
        assert_eq!(
            q.retry(id, 9).await.expect("retry"),
            Retried::Retried { complete: false }
        );
        let j = q.job(id).await.expect("read").expect("job");
        assert_eq!(
            (j.state, j.tiles_done, j.error),
            (JobState::Running, 1, None)
        );
        assert_eq!(band(&q, id, 0).await.len(), 1);
        let next = q
            .claim("w", 10, 1_000, 1)
            .await
            .expect("claim")
            .expect("the missing tile");
        assert_eq!(next.job, id);
        assert_ne!(next.idx, c.idx);
        assert!(q.claim("w", 10, 1_000, 1).await.expect("claim").is_none());
        let stored = q
            .complete(
                id,
                next.idx,
                &next.lease,
                next.rect(),
                &pixels(next.rect()),
                0,
            )
            .await
            .expect("complete");
        assert!(matches!(stored, Completion::Stored { last: true, .. }));
    };

    let c = store_one("cancelled").await;
    assert_eq!(
        q.cancel("cancelled", 5).await.expect("cancel"),
        Cancel::Cancelled {
            from: JobState::Running
        }
    );
    kept("cancelled", &c).await;
    // An encoding still under way cannot bring the image back.
    q.put_image_chunk("cancelled", 1, b"more")
        .await
        .expect("chunk");
    assert_eq!(q.image_chunks("cancelled").await.expect("count"), 0);
    retried("cancelled", &c).await;

    let stored = store_one("failed").await;
    let c = q
        .claim("w", 0, 1_000, 1)
        .await
        .expect("claim")
        .expect("tile");
    assert_eq!(c.job, "failed");
    assert!(
        q.fail_tile("failed", c.idx, &c.lease, "w", "broken", 0, 1, KEEP)
            .await
            .expect("fail")
    );
    assert_eq!(
        q.job("failed").await.expect("read").expect("job").state,
        JobState::Failed
    );
    kept("failed", &stored).await;
    // The worker that failed it is no longer kept away, and the tile has its attempts back.
    retried("failed", &stored).await;

    // Only an ended job is retried.
    assert_eq!(q.retry("nope", 11).await.expect("retry"), Retried::Unknown);
    job(&q, "active", 16, 8, 8).await;
    assert_eq!(
        q.retry("active", 11).await.expect("retry"),
        Retried::NotEnded(JobState::Queued)
    );
}
on_both!(a_job_that_ends_without_an_image_keeps_its_tiles_for_a_retry);

/// A job of more tiles than one insert statement holds (1,000) is stored tile for tile as
/// the tiler cut it: every index once, each with its own rectangle, in claim order.
async fn a_job_of_many_tiles_is_stored_as_the_tiler_cut_it(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    // 51 × 50 = 2,550 tiles, so two full statements and part of a third; the last column
    // and the last row of tiles are 4 pixels.
    let rects = job(&q, "m", 404, 396, 8).await;
    assert_eq!(rects.len(), 51 * 50);
    assert_eq!(
        q.job("m").await.expect("read").expect("job").tiles_total,
        rects.len() as i64
    );
    let mut claimed = Vec::new();
    while let Some(c) = q.claim("w", 0, 60_000, 1).await.expect("claim") {
        claimed.push((c.idx as usize, c.rect()));
    }
    let expected: Vec<(usize, Rect)> = rects.iter().copied().enumerate().collect();
    assert_eq!(claimed, expected);
}
on_both!(a_job_of_many_tiles_is_stored_as_the_tiler_cut_it);

/// A band is read back left to right whatever order its tiles arrived in, each with its
/// own pixels, and only once stored; the other bands' tiles stay out of it.
async fn a_band_reads_back_its_stored_tiles_left_to_right(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    // 3 tiles across (the last 4 pixels wide), 2 bands (the last 3 rows high).
    let rects = job(&q, "b", 20, 11, 8).await;
    let claims = claim_all(&q, 1).await;
    assert_eq!(claims.len(), rects.len());
    // The bottom band's tiles and the top band's first tile, right to left.
    for c in claims
        .iter()
        .rev()
        .filter(|c| c.rect().y == 8 || c.rect().x == 0)
    {
        let stored = q
            .complete("b", c.idx, &c.lease, c.rect(), &tile_rgb(c.rect()), 0)
            .await
            .expect("complete");
        assert!(matches!(stored, Completion::Stored { .. }));
    }
    let top = band(&q, "b", 0).await;
    assert_eq!(top, vec![(0, 8, 8, tile_rgb(rects[0]))]);
    let bottom = band(&q, "b", 8).await;
    let expected: Vec<_> = rects
        .iter()
        .filter(|r| r.y == 8)
        .map(|r| (r.x, r.width, r.height, tile_rgb(*r)))
        .collect();
    assert_eq!(expected.iter().map(|t| t.0).collect::<Vec<_>>(), [0, 8, 16]);
    assert_eq!(bottom, expected);
    assert!(band(&q, "b", 4).await.is_empty(), "no band starts at row 4");
}
on_both!(a_band_reads_back_its_stored_tiles_left_to_right);

/// Image chunks past the threshold start a checkpoint off the writer, which copies the
/// pages committed before it from the WAL into the database file. (Tile pixels of a
/// database file do not pass through SQLite: see the spool tests below.)
///
/// SQLite only: its WAL and file sizes.
#[tokio::test]
async fn stored_bytes_past_the_threshold_are_checkpointed_in_the_background() {
    let db = Db::sqlite("checkpoint");
    const EVERY: usize = 100_000;
    let q = open_store(&db.url())
        .await
        .expect("open")
        .checkpoint_every(EVERY as u64);
    let mut finished = q.checkpoints().expect("a database file has a WAL");
    job(&q, "c", 256, 256, 64).await;
    let file = std::fs::metadata(db.dir().join("q.db"))
        .expect("database file")
        .len();
    assert!(file < 100_000, "a new database file is small: {file} bytes");
    let piece = vec![7u8; 12_288];
    let mut stored = 0;
    for seq in 0..16 {
        if stored < EVERY {
            assert_eq!(*finished.borrow(), 0, "checkpointed before the threshold");
        }
        q.put_image_chunk("c", seq, &piece).await.expect("chunk");
        stored += piece.len();
    }
    assert!(stored > EVERY);
    // A timeout only turns a checkpoint that never comes into a failure.
    tokio::time::timeout(
        std::time::Duration::from_secs(60),
        finished.wait_for(|n| *n >= 1),
    )
    .await
    .expect("a checkpoint within a minute")
    .expect("the queue is alive");
    // Until a checkpoint, committed pages live in the WAL only; the database file holds the
    // bytes once they are copied into it.
    let file = std::fs::metadata(db.dir().join("q.db"))
        .expect("database file")
        .len();
    assert!(
        file as usize > stored,
        "the chunks' pages are in the database file: {file} bytes after {stored} of chunks"
    );
    let wal = q.checkpoint().await.expect("checkpoint").expect("a WAL");
    assert_eq!(wal.copied, wal.log, "every page is in the database file");
    assert_eq!(
        q.image_chunks("c").await.expect("count"),
        16,
        "the chunks read back"
    );

    let memory = open_store("sqlite::memory:").await.expect("open");
    assert!(memory.checkpoints().is_none());
    assert_eq!(memory.checkpoint().await.expect("no error"), None);
}

/// Tile pixels wait in the job's spool file, laid out as the image, not in SQLite; a band
/// reads them back, and the file goes when the image is stored.
///
/// SQLite only: its tile spool.
#[tokio::test]
async fn tile_pixels_wait_in_the_spool_not_in_sqlite() {
    let db = Db::sqlite("spool");
    let q = open_store(&db.url()).await.expect("open");
    let dir = q
        .spool_dir()
        .expect("a database file has a spool")
        .to_path_buf();
    assert_eq!(dir, db.dir().join("q.db-tiles"));
    let (w, h) = (300u32, 200u32);
    let rects = job(&q, "s", w, h, 64).await;
    let claims = claim_all(&q, 1).await;
    let mut last = 0;
    for c in &claims {
        match q
            .complete("s", c.idx, &c.lease, c.rect(), &tile_rgb(c.rect()), 0)
            .await
            .expect("complete")
        {
            Completion::Stored { last: true, .. } => last += 1,
            Completion::Stored { .. } => {}
            other => panic!("not stored: {other:?}"),
        }
    }
    assert_eq!(last, 1);
    let pixels = 3 * u64::from(w * h);
    let pool = sqlx::SqlitePool::connect(&db.url()).await.expect("open");
    let (rows, blob_bytes, with_crc): (i64, i64, i64) = sqlx::query_as(
        "SELECT COUNT(*), SUM(LENGTH(rgb)), COUNT(crc) FROM tile_pixels WHERE job_id = 's'",
    )
    .fetch_one(&pool)
    .await
    .expect("read");
    pool.close().await;
    assert_eq!(
        (rows, blob_bytes, with_crc),
        (claims.len() as i64, 0, claims.len() as i64)
    );
    let spooled = std::fs::metadata(dir.join("s.rgb"))
        .expect("spool file")
        .len();
    assert_eq!(spooled, pixels, "the file is the image's size");
    for y in (0..h).step_by(64) {
        let expected: Vec<_> = rects
            .iter()
            .filter(|r| r.y == y)
            .map(|r| (r.x, r.width, r.height, tile_rgb(*r)))
            .collect();
        assert_eq!(band(&q, "s", y).await, expected, "band {y}");
    }
    assert!(q.finish_image("s", 1, 0).await.expect("finish"));
    assert!(
        !dir.join("s.rgb").exists(),
        "the file goes with the image stored"
    );
}

/// Pixels that do not match their row when a band reads them (a crash between the file and
/// the commit, a deleted file, someone else's bytes) are never encoded: the tiles are queued
/// again, with a failure counted against the tile (not against any worker), and the band
/// reads once they are rendered again.
///
/// SQLite only: its tile spool.
#[tokio::test]
async fn lost_pixels_send_their_tiles_back_to_the_queue() {
    let db = Db::sqlite("spool-lost");
    let q = open_store(&db.url()).await.expect("open");
    let dir = q.spool_dir().expect("spool").to_path_buf();
    let rects = job(&q, "l", 40, 16, 8).await; // 5 × 2 tiles
    let claims = claim_all(&q, 1).await;
    for c in &claims {
        let stored = q
            .complete("l", c.idx, &c.lease, c.rect(), &tile_rgb(c.rect()), 0)
            .await
            .expect("complete");
        assert!(matches!(stored, Completion::Stored { .. }));
    }
    // One byte of the second tile changed in the file.
    let (at, _) = tessera_service::store::spool_slot(40, 16, rects[1]).expect("slot");
    let mut bytes = std::fs::read(dir.join("l.rgb")).expect("file");
    bytes[at as usize + 5] ^= 1;
    std::fs::write(dir.join("l.rgb"), &bytes).expect("write");
    let err = q
        .band("l", 0, 0, &mut Vec::new())
        .await
        .expect_err("a lost tile fails the band");
    assert!(err.to_string().contains("rendered again"), "{err}");
    let job = q.job("l").await.expect("job").expect("exists");
    assert_eq!(job.tiles_done, 9, "the lost tile is not done");
    assert!(q.unassembled().await.expect("list").is_empty());
    // Handed out again and stored again.
    let again = q
        .claim("v", 0, 60_000, 4)
        .await
        .expect("claim")
        .expect("a tile");
    assert_eq!((again.idx, again.rect()), (1, rects[1]));
    let mut expected = vec![0; 10];
    expected[1] = 1;
    assert_eq!(failures(&db, "l").await, expected);
    let stored = q
        .complete(
            "l",
            1,
            &again.lease,
            again.rect(),
            &tile_rgb(again.rect()),
            0,
        )
        .await
        .expect("complete");
    assert!(matches!(stored, Completion::Stored { last: true, .. }));
    assert_eq!(band(&q, "l", 0).await.len(), 5);
    // A deleted file (seen by a service started afresh: this one still has it open) loses
    // every tile of the band.
    std::fs::remove_file(dir.join("l.rgb")).expect("delete");
    let q = open_store(&db.url()).await.expect("open again");
    assert!(q.band("l", 8, 0, &mut Vec::new()).await.is_err());
    let job = q.job("l").await.expect("job").expect("exists");
    assert_eq!(job.tiles_done, 5);
}

/// A tile whose pixels keep being lost fails its job after `max_attempts` losses, with the
/// reason, instead of being rendered again for ever.
///
/// SQLite only: its tile spool.
#[tokio::test]
async fn a_tile_lost_again_and_again_fails_its_job() {
    let db = Db::sqlite("spool-lost-again");
    let q = open_store(&db.url()).await.expect("open").max_attempts(2);
    let file = q.spool_dir().expect("spool").join("r.rgb");
    job(&q, "r", 8, 8, 8).await; // one tile
    for round in 1..=2 {
        let c = q
            .claim("w", 0, 60_000, 2)
            .await
            .expect("claim")
            .expect("tile");
        let stored = q
            .complete("r", c.idx, &c.lease, c.rect(), &tile_rgb(c.rect()), 0)
            .await
            .expect("complete");
        assert!(matches!(stored, Completion::Stored { last: true, .. }));
        std::fs::write(&file, [0u8; 8 * 8 * 3]).expect("overwrite");
        assert!(q.band("r", 0, 0, &mut Vec::new()).await.is_err());
        let job = q.job("r").await.expect("job").expect("exists");
        if round == 1 {
            assert_eq!(job.state, JobState::Running, "one loss is rendered again");
        } else {
            assert_eq!(job.state, JobState::Failed, "the second loss fails the job");
            let error = job.error.unwrap_or_default();
            assert!(error.contains("lost from the tile spool"), "{error}");
        }
    }
    assert!(q.claim("w", 0, 60_000, 2).await.expect("claim").is_none());
}

/// The files of deleted jobs and of jobs whose image is stored are swept; those of active
/// jobs and of jobs that ended without an image (kept for a retry) are not.
///
/// SQLite only: its tile spool.
#[tokio::test]
async fn ended_jobs_spool_files_are_swept() {
    let db = Db::sqlite("spool-sweep");
    let q = open_store(&db.url()).await.expect("open");
    let dir = q.spool_dir().expect("spool").to_path_buf();
    for id in ["a", "b", "d"] {
        job(&q, id, 16, 16, 16).await;
        let c = q
            .claim("w", 0, 60_000, 1)
            .await
            .expect("claim")
            .expect("tile");
        // One 16×16 tile per job: storing it would be the job's last; a second tile is not
        // needed, the file exists once written.
        let _ = q
            .complete(id, c.idx, &c.lease, c.rect(), &tile_rgb(c.rect()), 0)
            .await
            .expect("complete");
    }
    assert!(
        ["a", "b", "d"]
            .iter()
            .all(|id| dir.join(format!("{id}.rgb")).exists())
    );
    // Job `b` failed; job `d` is done, its file (which went with its image) back as a crash
    // between the two would leave it; a file of a job that no longer exists.
    q.fail_job("b", "test", 0).await.expect("fail");
    assert!(q.finish_image("d", 1, 0).await.expect("finish"));
    assert!(
        !dir.join("d.rgb").exists(),
        "a stored image's file goes at once"
    );
    std::fs::write(dir.join("d.rgb"), b"x").expect("write");
    std::fs::write(dir.join("gone.rgb"), b"x").expect("write");
    assert_eq!(q.sweep_spool().await.expect("sweep"), 2);
    assert!(dir.join("a.rgb").exists(), "an active job's file is kept");
    assert!(dir.join("b.rgb").exists(), "a failed job's file is kept");
    assert!(!dir.join("d.rgb").exists() && !dir.join("gone.rgb").exists());
}

/// A submission's scene and textures count towards the next checkpoint as tile pixels do,
/// so that large submissions cannot grow the WAL unchecked.
///
/// SQLite only: its WAL.
#[tokio::test]
async fn a_large_submission_is_checkpointed_in_the_background() {
    let db = Db::sqlite("checkpoint-scene");
    let q = open_store(&db.url())
        .await
        .expect("open")
        .checkpoint_every(100_000);
    let mut finished = q.checkpoints().expect("a database file has a WAL");
    let scene = format!("[GLOBALS]\n[/GLOBALS]\n{}", "# padding\n".repeat(8_000));
    let texture = vec![1u8; 30_000];
    q.insert_job(
        &NewJob {
            id: "big".into(),
            scene,
            name: None,
            width: 8,
            height: 8,
            tile: 8,
            sampler: None,
            samples: None,
            threshold: None,
            created_at: 0,
            priority: 0,
        },
        &tiles(8, 8, 8),
        &[("t.ppm".to_string(), texture)],
    )
    .await
    .expect("job stored");
    // A timeout only turns a checkpoint that never comes into a failure.
    tokio::time::timeout(
        std::time::Duration::from_secs(20),
        finished.wait_for(|n| *n >= 1),
    )
    .await
    .expect("a checkpoint after 110 kB of submission")
    .expect("the queue is alive");
}

/// A pixel value that differs between neighbouring pixels and tiles.
fn shade(x: u32, y: u32, c: u32) -> u8 {
    (x.wrapping_mul(7) ^ y.wrapping_mul(13) ^ (c * 85)) as u8
}

fn tile_rgb(r: Rect) -> Vec<u8> {
    let mut v = Vec::with_capacity(r.pixel_count() * 3);
    for y in r.y..r.y + r.height {
        for x in r.x..r.x + r.width {
            v.extend((0..3).map(|c| shade(x, y, c)));
        }
    }
    v
}

/// Stores claim `c`'s pixels as the service does: the bands it completes are encoded while
/// the job renders (`progress` follows the job), and the last tile finishes the PNG.
async fn store_following(
    q: &Store,
    progress: &tessera_service::assemble::Progress,
    c: &tessera_protocol::Claim,
    rgb: &[u8],
) {
    let stored = q
        .complete(&c.job, c.idx, &c.lease, c.rect(), rgb, 0)
        .await
        .expect("complete");
    let Completion::Stored { last, .. } = stored else {
        panic!("{stored:?}")
    };
    if last {
        progress.complete(q, &c.job).await.expect("assembled");
    } else if progress.stored(&c.job, c.rect()) {
        progress.advance(q, &c.job).await;
    }
}

async fn png_of(q: &Store, id: &str) -> Vec<u8> {
    let mut png = Vec::new();
    for seq in 0..q.image_chunks(id).await.expect("count") {
        png.extend(q.image_chunk(id, seq).await.expect("read").expect("chunk"));
    }
    png
}

async fn bands_are_encoded_in_order_as_they_complete_and_give_the_whole_images_png(db: Db) {
    use tessera_service::assemble::Progress;
    let (w, h) = (64, 30); // four bands of 8-pixel tiles, the last 6 rows high
    let whole = tessera_tracer::encode_png(w, h, &tile_rgb(Rect::new(0, 0, w, h))).expect("png");

    let q = open_store(&db.url()).await.expect("open");
    let progress = Progress::default();
    let rects = tiles(w, h, 8);
    progress.follow("j", w, h, &rects);
    job(&q, "j", w, h, 8).await;
    let claims = claim_all(&q, 4).await;
    assert_eq!(claims.len(), rects.len());
    let store = async |band_y: u32| {
        for c in claims.iter().filter(|c| c.y == band_y) {
            store_following(&q, &progress, c, &tile_rgb(c.rect())).await;
        }
    };
    // The second band first: nothing can be encoded before the first.
    store(8).await;
    assert_eq!(progress.encoded_rows("j").await, Some(0));
    // The first band: both are encoded now.
    store(0).await;
    assert_eq!(progress.encoded_rows("j").await, Some(16));
    // Last band before the third, then the third, which completes the job.
    store(24).await;
    assert_eq!(progress.encoded_rows("j").await, Some(16));
    store(16).await;
    assert_eq!(
        progress.encoded_rows("j").await,
        None,
        "finished, no longer followed"
    );
    assert_eq!(
        q.job("j").await.expect("read").expect("job").state,
        JobState::Done
    );
    assert_eq!(
        png_of(&q, "j").await,
        whole,
        "the same bytes as one whole encode"
    );

    // A job not followed (stored before a restart) is assembled whole, to the same bytes.
    job(&q, "k", w, h, 8).await;
    while let Some(c) = q.claim("w", 0, 60_000, 4).await.expect("claim") {
        let stored = q
            .complete("k", c.idx, &c.lease, c.rect(), &tile_rgb(c.rect()), 0)
            .await
            .expect("complete");
        if let Completion::Stored { last: true, .. } = stored {
            progress.complete(&q, "k").await.expect("assembled");
        }
    }
    assert_eq!(
        q.job("k").await.expect("read").expect("job").state,
        JobState::Done
    );
    assert_eq!(png_of(&q, "k").await, whole);
}
on_both!(bands_are_encoded_in_order_as_they_complete_and_give_the_whole_images_png);

/// A cancelled job's leases are stale for every route: a failure report neither counts
/// against the tile or the worker nor requeues the tile, and a give-back is refused too.
async fn a_cancelled_jobs_leases_are_stale(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    job(&q, "j", 16, 8, 8).await;
    let a = q.claim("w", 0, 60_000, 3).await.expect("claim").expect("a");
    let b = q.claim("w", 0, 60_000, 3).await.expect("claim").expect("b");
    assert_eq!(
        q.cancel("j", 5).await.expect("cancel"),
        Cancel::Cancelled {
            from: JobState::Running
        }
    );
    // Again: it has ended, and nothing changes.
    assert_eq!(
        q.cancel("j", 6).await.expect("cancel"),
        Cancel::Ended {
            state: JobState::Cancelled
        }
    );
    assert_eq!(q.cancel("nope", 6).await.expect("cancel"), Cancel::Unknown);
    assert!(
        !q.fail_tile("j", a.idx, &a.lease, "w", "boom", 10, 3, KEEP)
            .await
            .expect("fail")
    );
    assert!(!q.release("j", b.idx, &b.lease).await.expect("release"));
    assert_eq!(
        q.job("j").await.expect("read").expect("job").state,
        JobState::Cancelled
    );
    // Nothing requeued: no tile of it is handed out again, nor counted as lost when its
    // leases run out.
    assert!(q.claim("v", 20, 60_000, 3).await.expect("claim").is_none());
    assert_eq!(q.reap(120_000, 3, KEEP).await.expect("reap"), 0);
}
on_both!(a_cancelled_jobs_leases_are_stale);

/// Leases of one job that run out together (a worker's tile and the one it holds ahead: one
/// stall) count once towards keeping the worker away: with keep-away after two, one stall
/// of a lone worker no longer bars it from the job.
async fn one_stall_is_one_strike(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    job(&q, "j", 32, 8, 8).await;
    for _ in 0..2 {
        q.claim("w", 0, 1_000, 4)
            .await
            .expect("claim")
            .expect("a tile");
    }
    assert_eq!(q.reap(5_000, 4, KEEP).await.expect("reap"), 2);
    // Kept away after two strikes: had the two leases counted as two, `w` would get nothing.
    let c = q.claim("w", 6_000, 1_000, 4).await.expect("claim");
    assert!(c.is_some(), "one stall kept the worker away");
}
on_both!(one_stall_is_one_strike);

/// A second connection holding what the health probe's write needs: SQLite's database
/// write lock, or PostgreSQL's lock on the health table.
enum WriteLock {
    Sqlite(sqlx::SqliteConnection),
    Postgres(sqlx::PgConnection),
}

impl WriteLock {
    async fn take(db: &Db) -> WriteLock {
        use sqlx::Connection;
        match db.backend {
            Backend::Sqlite => {
                let mut c = sqlx::SqliteConnection::connect(&db.url())
                    .await
                    .expect("second connection");
                sqlx::query("BEGIN EXCLUSIVE")
                    .execute(&mut c)
                    .await
                    .expect("lock");
                WriteLock::Sqlite(c)
            }
            Backend::Postgres => {
                let mut c = sqlx::PgConnection::connect(&db.url())
                    .await
                    .expect("second connection");
                sqlx::raw_sql("BEGIN; LOCK TABLE health IN ACCESS EXCLUSIVE MODE")
                    .execute(&mut c)
                    .await
                    .expect("lock");
                WriteLock::Postgres(c)
            }
        }
    }

    async fn release(self) {
        match self {
            WriteLock::Sqlite(mut c) => {
                sqlx::query("COMMIT").execute(&mut c).await.expect("unlock");
            }
            WriteLock::Postgres(mut c) => {
                sqlx::query("COMMIT").execute(&mut c).await.expect("unlock");
            }
        }
    }
}

/// The health check's write: it succeeds on a database that takes writes, and fails (in the
/// time it is given) while another connection holds the database's write lock, then
/// succeeds again once the lock is gone. The check only read, and so answered `200` while
/// every write failed.
async fn the_write_probe_fails_while_writes_cannot_happen(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    let quick = std::time::Duration::from_millis(300);
    q.probe_write(1, quick).await.expect("writable");
    let lock = WriteLock::take(&db).await;
    let refused = q.probe_write(2, quick).await;
    assert!(refused.is_err(), "{refused:?}");
    lock.release().await;
    q.probe_write(3, std::time::Duration::from_secs(20))
        .await
        .expect("writable again");
}
on_both!(the_write_probe_fails_while_writes_cannot_happen);

/// A database from before migration 0008, whose jobs hold their scenes in the `jobs` row,
/// opens with its scenes moved to `job_scenes`: a worker still gets each job's scene, and the
/// listing reads rows without one (a large scene in the row makes each listed job walk its
/// overflow pages to reach the columns after it).
///
/// SQLite only: its migrations from older files.
#[tokio::test]
async fn scenes_move_out_of_the_jobs_rows_when_an_older_database_opens() {
    use sqlx::sqlite::{SqliteConnectOptions, SqlitePoolOptions};
    let db = Db::sqlite("migrate-scenes");
    let opts: SqliteConnectOptions = db.url().parse().expect("url");
    let pool = SqlitePoolOptions::new()
        .connect_with(opts.create_if_missing(true))
        .await
        .expect("pool");
    let mut before = sqlx::migrate!("../migrations/sqlite");
    before.migrations = before
        .migrations
        .iter()
        .filter(|m| m.version < 8)
        .cloned()
        .collect::<Vec<_>>()
        .into();
    before.run(&pool).await.expect("migrations 1 to 7");
    let scene = format!("# a big scene\n{}", "# padding\n".repeat(100_000));
    sqlx::query(
        "INSERT INTO jobs (id, seq, state, scene, width, height, tile, tiles_total, created_at)
         VALUES ('old', 1, 'queued', ?1, 8, 8, 8, 1, 0)",
    )
    .bind(&scene)
    .execute(&pool)
    .await
    .expect("an old job");
    pool.close().await;

    let q = open_store(&db.url()).await.expect("opens, migrating");
    let (state, spec) = q.job_scene("old").await.expect("reads").expect("the job");
    assert_eq!((state.as_str(), spec.scene), ("queued", scene));
    let listed = q.jobs(10, None).await.expect("lists").expect("a page");
    assert_eq!(listed.len(), 1);
    assert_eq!(listed[0].id, "old");
    // The scene is in its own table only: the listed rows no longer carry it.
    let look = sqlx::SqlitePool::connect(&db.url()).await.expect("open");
    let columns: Vec<String> = sqlx::query_scalar("SELECT name FROM pragma_table_info('jobs')")
        .fetch_all(&look)
        .await
        .expect("columns");
    assert!(!columns.iter().any(|c| c == "scene"), "{columns:?}");
    // A job deleted takes its scene with it.
    assert!(q.delete("old").await.expect("deletes"));
    let left: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM job_scenes")
        .fetch_one(&look)
        .await
        .expect("count");
    assert_eq!(left, 0);
    look.close().await;
}

/// Claims serve the highest priority first, and jobs of one priority in the order they came:
/// a preview submitted behind a long render (at a higher priority) is rendered first, and a
/// job below every other waits for them all.
async fn claims_serve_the_highest_priority_first_then_the_oldest(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    job_at(&q, "long", 0, 64, 64, 32).await; // 4 tiles
    job_at(&q, "later", 0, 32, 32, 32).await; // 1 tile
    job_at(&q, "low", -5, 32, 32, 32).await;
    job_at(&q, "preview", 10, 64, 32, 32).await; // 2 tiles
    let mut order = Vec::new();
    while let Some(c) = q.claim("w", 0, 60_000, 4).await.expect("claim") {
        order.push(format!("{}/{}", c.job, c.idx));
    }
    assert_eq!(
        order,
        [
            "preview/0",
            "preview/1",
            "long/0",
            "long/1",
            "long/2",
            "long/3",
            "later/0",
            "low/0"
        ]
    );
}
on_both!(claims_serve_the_highest_priority_first_then_the_oldest);

/// A job's first claim marks it running in the claim's own statement: a claim whose job
/// could not be marked (here a trigger refuses the write, as a full disk would) stores no
/// lease at all, and the tile is the next claim's, as if the failed one never happened. (A
/// second statement marking the job after the claim had committed would leave the failed
/// claim's lease stored, its tile leased to a worker that never got it, and the job `queued`
/// with no start time while its tiles were rendered.)
async fn a_claim_and_its_jobs_start_are_one_write(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    job(&q, "j", 64, 32, 32).await; // 2 tiles
    // A trigger refuses to mark the job running, as a full disk would.
    match db.backend {
        Backend::Sqlite => {
            db.execute(
                "CREATE TRIGGER refuse_start BEFORE UPDATE OF state ON jobs
                 WHEN NEW.state = 'running' BEGIN SELECT RAISE(ABORT, 'disk full'); END",
            )
            .await
        }
        Backend::Postgres => {
            db.execute(
                "CREATE FUNCTION refuse_start() RETURNS trigger LANGUAGE plpgsql AS $$
                 BEGIN RAISE EXCEPTION 'disk full'; END $$;
                 CREATE TRIGGER refuse_start BEFORE UPDATE OF state ON jobs FOR EACH ROW
                 WHEN (NEW.state = 'running') EXECUTE FUNCTION refuse_start()",
            )
            .await
        }
    }
    let refused = q.claim("w", 5, 60_000, 4).await;
    assert!(refused.is_err(), "{refused:?}");
    let leased = db
        .count("SELECT COUNT(*) FROM tiles WHERE state != 'queued'")
        .await;
    assert_eq!(leased, 0, "the failed claim left a lease behind");
    match db.backend {
        Backend::Sqlite => db.execute("DROP TRIGGER refuse_start").await,
        Backend::Postgres => db.execute("DROP TRIGGER refuse_start ON jobs").await,
    }

    assert_eq!(
        q.job("j").await.expect("job").expect("row").state,
        JobState::Queued
    );
    let c = q
        .claim("w", 7, 60_000, 4)
        .await
        .expect("claim")
        .expect("a tile");
    assert_eq!((c.job.as_str(), c.idx), ("j", 0));
    let row = q.job("j").await.expect("job").expect("row");
    assert_eq!((row.state.as_str(), row.started_at), ("running", Some(7)));
    // A later claim of the running job changes neither.
    q.claim("w", 9, 60_000, 4)
        .await
        .expect("claim")
        .expect("a tile");
    let row = q.job("j").await.expect("job").expect("row");
    assert_eq!((row.state.as_str(), row.started_at), ("running", Some(7)));
}
on_both!(a_claim_and_its_jobs_start_are_one_write);

/// The PNG is stored in chunks of exactly `CHUNK` bytes but the last (what a download holds
/// per client while the client reads), whatever the size of each band's output, and the
/// chunks still make the whole image's PNG. Noise, so that the PNG is about as large as
/// its pixels and its bands' outputs straddle chunk boundaries.
async fn the_png_is_stored_in_chunks_of_one_size(db: Db) {
    use tessera_service::assemble::{CHUNK, Progress};
    let (w, h) = (256, 200);
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let noise: Vec<u8> = (0..w * h * 3)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 24) as u8
        })
        .collect();
    let whole = tessera_tracer::encode_png(w, h, &noise).expect("png");
    assert!(whole.len() > 2 * CHUNK, "a test of several chunks");
    let tile_of = |r: Rect| {
        let mut v = Vec::new();
        for y in r.y..r.y + r.height {
            let start = ((y * w + r.x) * 3) as usize;
            v.extend_from_slice(&noise[start..start + r.width as usize * 3]);
        }
        v
    };

    let q = open_store(&db.url()).await.expect("open");
    let progress = Progress::default();
    let rects = tiles(w, h, 32);
    progress.follow("j", w, h, &rects);
    job(&q, "j", w, h, 32).await;
    while let Some(c) = q.claim("w", 0, 60_000, 4).await.expect("claim") {
        store_following(&q, &progress, &c, &tile_of(c.rect())).await;
    }
    let n = q.image_chunks("j").await.expect("count");
    let mut png = Vec::new();
    for seq in 0..n {
        let chunk = q.image_chunk("j", seq).await.expect("read").expect("chunk");
        if seq + 1 < n {
            assert_eq!(chunk.len(), CHUNK, "chunk {seq} of {n}");
        } else {
            assert!(
                (1..=CHUNK).contains(&chunk.len()),
                "last chunk {}",
                chunk.len()
            );
        }
        png.extend(chunk);
    }
    assert_eq!(png, whole, "the same bytes as one whole encode");
    assert_eq!(
        q.job("j").await.expect("read").expect("job").png_bytes,
        Some(whole.len() as i64)
    );
}
on_both!(the_png_is_stored_in_chunks_of_one_size);

/// Flips a bit of tile `r`'s bytes in the spool file `file` of a `w`-wide, `h`-high image.
fn spoil(file: &std::path::Path, w: u32, h: u32, r: Rect) {
    let (at, _) = tessera_service::store::spool_slot(w, h, r).expect("slot");
    let mut bytes = std::fs::read(file).expect("file");
    bytes[at as usize] ^= 0x80;
    std::fs::write(file, &bytes).expect("write");
}

/// Job `id`'s last tile is in but tile `lost` lost its pixels: finishing the image waits
/// (the error says tiles are rendered again, and the job has not failed); the tile comes
/// back to the next claim, and stored again it completes the job, whose PNG is `whole`.
async fn finish_after_loss(
    q: &Store,
    progress: &tessera_service::assemble::Progress,
    id: &str,
    lost: Rect,
    whole: &[u8],
) {
    let err = progress.complete(q, id).await.expect_err("a tile was lost");
    assert!(err.requeued(), "{err}");
    let state = q.job(id).await.expect("read").expect("job").state;
    assert_ne!(state, JobState::Failed);
    let again = q
        .claim("w", 0, 60_000, 4)
        .await
        .expect("claim")
        .expect("tile");
    assert_eq!(again.rect(), lost, "the lost tile is handed out again");
    let stored = q
        .complete(id, again.idx, &again.lease, lost, &tile_rgb(lost), 0)
        .await
        .expect("complete");
    assert!(matches!(stored, Completion::Stored { last: true, .. }));
    progress.complete(q, id).await.expect("assembled");
    assert_eq!(
        q.job(id).await.expect("read").expect("job").state,
        JobState::Done
    );
    assert_eq!(png_of(q, id).await, whole);
}

/// A tile whose spooled pixels are lost is rendered again wherever the loss is found,
/// while encoding ahead or at the end, and the job's PNG is still the whole image's.
///
/// SQLite only: its tile spool.
#[tokio::test]
async fn a_job_whose_pixels_are_lost_still_gives_the_whole_images_png() {
    use tessera_service::assemble::Progress;
    let (w, h) = (32, 16); // two bands of four 8-pixel tiles
    let whole = tessera_tracer::encode_png(w, h, &tile_rgb(Rect::new(0, 0, w, h))).expect("png");
    let db = Db::sqlite("spool-assemble");
    let q = open_store(&db.url()).await.expect("open");
    let file = q.spool_dir().expect("spool").join("j.rgb");
    let progress = Progress::default();
    let rects = tiles(w, h, 8);
    progress.follow("j", w, h, &rects);
    job(&q, "j", w, h, 8).await;
    let corrupt = |r: Rect| spoil(&file, w, h, r);
    let store = async |c: &tessera_protocol::Claim| {
        q.complete("j", c.idx, &c.lease, c.rect(), &tile_rgb(c.rect()), 0)
            .await
            .expect("complete")
    };
    // The first band but its last tile, one of them corrupted, then its last tile: the band
    // is complete, and encoding it ahead finds the loss.
    let mut first: Vec<_> = Vec::new();
    for _ in 0..4 {
        first.push(
            q.claim("w", 0, 60_000, 4)
                .await
                .expect("claim")
                .expect("tile"),
        );
    }
    for c in &first[..3] {
        assert!(matches!(
            store(c).await,
            Completion::Stored { last: false, .. }
        ));
        assert!(!progress.stored("j", c.rect()));
    }
    corrupt(first[1].rect());
    assert!(matches!(
        store(&first[3]).await,
        Completion::Stored { last: false, .. }
    ));
    assert!(
        progress.stored("j", first[3].rect()),
        "the band is complete"
    );
    assert!(progress.advance(&q, "j").await, "the loss is reported");
    assert_eq!(q.job("j").await.expect("read").expect("job").tiles_done, 3);
    // The rest: the lost tile comes back first (lowest index), then the second band; the
    // last of them is corrupted just before it completes the job.
    let rest = claim_all(&q, 4).await;
    assert_eq!(
        rest[0].rect(),
        first[1].rect(),
        "the lost tile is handed out again"
    );
    assert_eq!(rest.len(), 5);
    for c in &rest[..4] {
        assert!(matches!(
            store(c).await,
            Completion::Stored { last: false, .. }
        ));
    }
    corrupt(rest[2].rect());
    assert!(matches!(
        store(&rest[4]).await,
        Completion::Stored { last: true, .. }
    ));
    finish_after_loss(&q, &progress, "j", rest[2].rect(), &whole).await;
    assert!(!file.exists());
}

/// A post that is not its tile's current result (a wrong lease, another tile's rectangle,
/// a rectangle spanning several tiles) writes nothing into the spool: the stored tiles'
/// pixels stay as they were, before and after a restart (whose queue knows no leases).
async fn refused_posts_leave_the_stored_pixels_alone(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    let rects = job(&q, "f", 32, 16, 8).await; // 4 × 2 tiles
    let claims = claim_all(&q, 4).await;
    // The first band stored, the second still leased.
    for c in claims.iter().filter(|c| c.y == 0) {
        let stored = q
            .complete("f", c.idx, &c.lease, c.rect(), &tile_rgb(c.rect()), 0)
            .await
            .expect("complete");
        assert!(matches!(stored, Completion::Stored { .. }));
    }
    let noise = |r: Rect| vec![0xA5; r.pixel_count() * 3];
    for q in [q.clone(), open_store(&db.url()).await.expect("open again")] {
        // A lease that is no one's, over the whole first band.
        let band_rect = Rect::new(0, 0, 32, 8);
        let r = q
            .complete("f", 0, "not-a-lease", band_rect, &noise(band_rect), 0)
            .await
            .expect("answer");
        assert!(
            matches!(r, Completion::Stale(_) | Completion::WrongTile(_)),
            "{r:?}"
        );
        // A current lease (tile 4, second band) posting tile 1's rectangle.
        let c = &claims[4];
        let r = q
            .complete("f", c.idx, &c.lease, rects[1], &noise(rects[1]), 0)
            .await
            .expect("answer");
        assert!(matches!(r, Completion::WrongTile(_)), "{r:?}");
        // A repeat of a stored tile's own lease with other bytes.
        let c = &claims[2];
        let r = q
            .complete("f", c.idx, &c.lease, c.rect(), &noise(c.rect()), 0)
            .await
            .expect("answer");
        assert!(matches!(r, Completion::Repeat), "{r:?}");
        let expected: Vec<_> = rects
            .iter()
            .filter(|r| r.y == 0)
            .map(|r| (r.x, r.width, r.height, tile_rgb(*r)))
            .collect();
        assert_eq!(
            band(&q, "f", 0).await,
            expected,
            "the stored pixels are intact"
        );
    }
}
on_both!(refused_posts_leave_the_stored_pixels_alone);

/// A loss found while encoding ahead, after the job's last tile is in, leaves the job to
/// wait for the tile rendered again (it failed with a gap in the image before).
///
/// SQLite only: its tile spool.
#[tokio::test]
async fn a_loss_found_ahead_after_the_last_tile_waits_for_the_tile() {
    use tessera_service::assemble::Progress;
    let (w, h) = (32, 16);
    let whole = tessera_tracer::encode_png(w, h, &tile_rgb(Rect::new(0, 0, w, h))).expect("png");
    let db = Db::sqlite("spool-late-loss");
    let q = open_store(&db.url()).await.expect("open");
    let file = q.spool_dir().expect("spool").join("g.rgb");
    let progress = Progress::default();
    let rects = tiles(w, h, 8);
    progress.follow("g", w, h, &rects);
    job(&q, "g", w, h, 8).await;
    let claims = claim_all(&q, 4).await;
    // Every tile stored (the last one says so); the first band's completion is counted but
    // its encoding has not run yet when a byte of tile 2 is lost.
    let mut band_done = false;
    for c in &claims {
        let stored = q
            .complete("g", c.idx, &c.lease, c.rect(), &tile_rgb(c.rect()), 0)
            .await
            .expect("complete");
        let Completion::Stored { last, .. } = stored else {
            panic!("{stored:?}")
        };
        if !last {
            band_done |= progress.stored("g", c.rect());
        }
    }
    assert!(band_done);
    spoil(&file, w, h, rects[2]);
    assert!(progress.advance(&q, "g").await, "the loss is found ahead");
    finish_after_loss(&q, &progress, "g", rects[2], &whole).await;
}

/// Cancelling a job keeps its spool file (its tiles wait for a retry); deleting a job
/// removes its file at once.
///
/// SQLite only: its tile spool.
#[tokio::test]
async fn cancel_keeps_the_spool_file_and_delete_removes_it() {
    let db = Db::sqlite("spool-cancel");
    let q = open_store(&db.url()).await.expect("open");
    let dir = q.spool_dir().expect("spool").to_path_buf();
    for id in ["c", "d"] {
        job(&q, id, 16, 8, 8).await; // two tiles each
    }
    let claims = claim_all(&q, 4).await;
    for c in claims.iter().filter(|c| c.idx == 0) {
        let stored = q
            .complete(&c.job, c.idx, &c.lease, c.rect(), &tile_rgb(c.rect()), 0)
            .await
            .expect("complete");
        assert!(matches!(stored, Completion::Stored { last: false, .. }));
        assert!(dir.join(format!("{}.rgb", c.job)).exists());
    }
    assert!(matches!(
        q.cancel("c", 0).await.expect("cancel"),
        Cancel::Cancelled { .. }
    ));
    assert!(dir.join("c.rgb").exists());
    assert!(q.delete("c").await.expect("delete"));
    assert!(!dir.join("c.rgb").exists());
    assert!(q.delete("d").await.expect("delete"));
    assert!(!dir.join("d.rgb").exists());
}

/// A spool folder that cannot be used is refused when the queue opens, with the reason,
/// before anything is created beside the database; one that stops taking files fails the
/// health probe. (A folder without write permission cannot be tested as root, which
/// writes anyway: a folder where the probe's file should go stands in for it.)
///
/// SQLite only: its tile spool.
#[tokio::test]
async fn an_unusable_spool_is_refused_at_start_and_by_the_health_probe() {
    let db = Db::sqlite("spool-unusable");
    let tiles = db.dir().join("q.db-tiles");
    std::fs::write(&tiles, b"not a folder").expect("file");
    let err = open_store(&db.url())
        .await
        .expect_err("a file is not a folder");
    assert!(err.to_string().contains("is not a folder"), "{err}");
    assert!(!db.dir().join("q.db").exists(), "nothing created beside it");
    std::fs::remove_file(&tiles).expect("remove");

    std::fs::create_dir_all(tiles.join("probe.tmp")).expect("a folder in the way");
    let err = open_store(&db.url())
        .await
        .expect_err("the probe cannot write");
    assert!(err.to_string().contains("does not take a file"), "{err}");
    std::fs::remove_dir(tiles.join("probe.tmp")).expect("remove");

    let q = open_store(&db.url()).await.expect("open");
    q.probe_write(0, std::time::Duration::from_secs(2))
        .await
        .expect("healthy");
    std::fs::create_dir_all(tiles.join("probe.tmp")).expect("a folder in the way");
    let err = q
        .probe_write(0, std::time::Duration::from_secs(2))
        .await
        .expect_err("the spool takes no file");
    assert!(err.to_string().contains("does not take a file"), "{err}");
}

/// Pixels kept in the tile rows (as before the spool) are assembled band by band into the
/// same PNG as the whole image encoded at once; a band whose tiles do not lie side by side
/// from the left edge is refused, not encoded with a hole, although their widths add up to
/// the image's.
async fn bands_are_encoded_from_tiles_side_by_side_only(db: Db) {
    use tessera_service::assemble::{AssembleError, assemble};
    let q = open_store(&db.url()).await.expect("open");
    let (w, h) = (40, 20); // 5 × 3 tiles of 8 px, the last band 4 rows high
    for id in ["g", "h"] {
        job(&q, id, w, h, 8).await;
    }
    for c in claim_all(&q, 4).await {
        let stored = q
            .complete(&c.job, c.idx, &c.lease, c.rect(), &tile_rgb(c.rect()), 0)
            .await
            .expect("complete");
        assert!(matches!(stored, Completion::Stored { .. }));
    }
    // SQLite's pixels moved from the spool into the rows (PostgreSQL keeps them there);
    // job `h`'s second tile of its first band then says it lies at the left edge, where
    // its first tile is.
    if db.backend == Backend::Sqlite {
        let pool = sqlx::SqlitePool::connect(&db.url()).await.expect("open");
        for (id, idx, x, y, tw, th) in sqlx::query_as::<_, (String, i64, u32, u32, u32, u32)>(
            "SELECT job_id, idx, x, y, w, h FROM tiles",
        )
        .fetch_all(&pool)
        .await
        .expect("tiles")
        {
            sqlx::query(
                "UPDATE tile_pixels SET rgb = ?3, crc = NULL WHERE job_id = ?1 AND idx = ?2",
            )
            .bind(&id)
            .bind(idx)
            .bind(tile_rgb(Rect::new(x, y, tw, th)))
            .execute(&pool)
            .await
            .expect("move the pixels");
        }
        pool.close().await;
    }
    db.execute("UPDATE tiles SET x = 0 WHERE job_id = 'h' AND idx = 1")
        .await;
    assemble(&q, "g").await.expect("assembled");
    let whole = tessera_tracer::encode_png(w, h, &tile_rgb(Rect::new(0, 0, w, h))).expect("png");
    assert_eq!(png_of(&q, "g").await, whole);
    let err = assemble(&q, "h").await.expect_err("a hole");
    assert!(
        matches!(
            err,
            AssembleError::Gap {
                y: 0,
                covered: 8,
                width: 40
            }
        ),
        "{err}"
    );
}
on_both!(bands_are_encoded_from_tiles_side_by_side_only);

/// A spool that cannot write (here its job file is `/dev/full`: every write fails with
/// "no space left") stores nothing, hands the tile back uncharged, and says why; once the
/// file can be written again the same tile is handed out and stored.
///
/// SQLite only: its tile spool.
#[cfg(target_os = "linux")]
#[tokio::test]
async fn a_tile_whose_pixels_cannot_be_written_is_queued_again_uncharged() {
    use tessera_service::store::STORAGE_PAUSE;
    let db = Db::sqlite("full");
    let q = open_store(&db.url()).await.expect("open");
    job(&q, "f", 16, 8, 8).await;
    let file = db.dir().join("q.db-tiles").join("f.rgb");
    std::os::unix::fs::symlink("/dev/full", &file).expect("a full file");
    assert_eq!(q.storage_trouble(0, STORAGE_PAUSE), None);
    let c = q
        .claim("w", 0, 60_000, 4)
        .await
        .expect("claim")
        .expect("a tile");
    let done = q
        .complete("f", c.idx, &c.lease, c.rect(), &tile_rgb(c.rect()), 0)
        .await
        .expect("complete");
    let Completion::Unstored(why) = done else {
        panic!("stored on a full disk: {done:?}");
    };
    assert!(why.contains("No space left"), "{why}");
    let trouble = q
        .storage_trouble(0, STORAGE_PAUSE)
        .expect("the spool's trouble");
    assert!(trouble.contains("No space left"), "{trouble}");
    assert_eq!(failures(&db, "f").await, vec![0, 0], "nobody is charged");
    let job = q.job("f").await.expect("job").expect("exists");
    assert_eq!((job.state.as_str(), job.tiles_done), ("running", 0));
    // The old lease stores nothing, even with the disk free again.
    std::fs::remove_file(&file).expect("free");
    let stale = q
        .complete("f", c.idx, &c.lease, c.rect(), &tile_rgb(c.rect()), 0)
        .await
        .expect("complete");
    assert!(matches!(stale, Completion::Stale(_)), "{stale:?}");
    assert!(
        !file.exists(),
        "a post under a lease given back writes nothing"
    );
    // The tile is handed out again, first in line, and stored.
    let again = q
        .claim("v", 0, 60_000, 4)
        .await
        .expect("claim")
        .expect("a tile");
    assert_eq!(again.idx, c.idx);
    let stored = q
        .complete(
            "f",
            again.idx,
            &again.lease,
            again.rect(),
            &tile_rgb(again.rect()),
            0,
        )
        .await
        .expect("complete");
    assert!(
        matches!(stored, Completion::Stored { last: false, .. }),
        "{stored:?}"
    );
    assert_eq!(
        q.storage_trouble(0, STORAGE_PAUSE),
        None,
        "a write succeeded since"
    );
    assert_eq!(band(&q, "f", 0).await[0].3, tile_rgb(c.rect()));
}

/// A spool write that fails for another reason than a full disk may never pass (here the
/// job file is a FIFO, where every positioned write is an "illegal seek"): the tile is
/// charged, never the worker, so that the job fails with the reason once the tile is out
/// of attempts instead of the tile being rendered for ever.
///
/// SQLite only: its tile spool.
#[cfg(target_os = "linux")]
#[tokio::test]
async fn a_tile_whose_pixels_keep_failing_to_be_written_fails_its_job() {
    let db = Db::sqlite("fifo");
    let q = open_store(&db.url()).await.expect("open").max_attempts(2);
    job(&q, "p", 16, 8, 8).await;
    let file = db.dir().join("q.db-tiles").join("p.rgb");
    let made = std::process::Command::new("mkfifo")
        .arg(&file)
        .status()
        .expect("mkfifo runs");
    assert!(made.success());
    for worker in ["w", "v"] {
        let c = q
            .claim(worker, 0, 60_000, 2)
            .await
            .expect("claim")
            .expect("a tile");
        assert_eq!(c.idx, 0, "the same tile, handed out again");
        let done = q
            .complete("p", c.idx, &c.lease, c.rect(), &tile_rgb(c.rect()), 0)
            .await
            .expect("complete");
        let Completion::Unstored(why) = done else {
            panic!("stored into a FIFO: {done:?}");
        };
        assert!(why.contains("Illegal seek"), "{why}");
    }
    assert_eq!(failures(&db, "p").await, vec![2, 0]);
    // This job file's trouble, not a lack of room: the farm is not paused for it.
    assert_eq!(
        q.storage_trouble(0, tessera_service::store::STORAGE_PAUSE),
        None
    );
    let job = q.job("p").await.expect("job").expect("exists");
    assert_eq!(job.state, JobState::Failed);
    let error = job.error.expect("a reason");
    assert!(error.contains("could not be stored"), "{error}");
    let pool = sqlx::SqlitePool::connect(&db.url()).await.expect("open");
    let (kept,): (i64,) = sqlx::query_as("SELECT COUNT(*) FROM keep_away")
        .fetch_one(&pool)
        .await
        .expect("count");
    assert_eq!(kept, 0, "no worker is charged");
    pool.close().await;
}

/// While the storage fails, the reaper gives a fresh lease to the tiles whose workers were
/// heard from (a renewal or a result under the lease was refused) and reaps the others as
/// ever: a worker that died meanwhile says nothing. Extending every lease would keep a dead
/// worker's tile for as long as failures kept coming.
async fn while_the_storage_fails_the_leases_of_silent_workers_are_reaped(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    job(&q, "j", 24, 8, 8).await;
    let claim = |w: &'static str, now: i64| {
        let q = &q;
        async move {
            q.claim(w, now, 1_000, 4)
                .await
                .expect("claim")
                .expect("a tile")
        }
    };
    let alive = claim("alive", 0).await;
    let dead = claim("dead", 0).await;
    q.heard(&alive.lease, 0);
    let within = std::time::Duration::from_secs(60);
    let pass = |now: i64| q.reap_unheard(now, 1_000, within, 4, KEEP);
    assert_eq!(pass(5_000).await.expect("pass"), (1, 1));
    // The silent worker's tile is handed out again, charged its failure; the live worker's
    // lease stands, uncharged.
    let again = claim("other", 5_000).await;
    assert_eq!(again.idx, dead.idx);
    let charged = failures(&db, "j").await;
    assert_eq!(
        (charged[alive.idx as usize], charged[dead.idx as usize]),
        (0, 1),
        "{charged:?}"
    );
    // A worker no longer heard from is forgotten, and its lease, once past, reaped too.
    q.heard(&again.lease, 5_000);
    q.forget_unheard(5_000, std::time::Duration::ZERO);
    assert_eq!(pass(7_000).await.expect("pass"), (0, 2));
    // A lease extended so takes its worker's result as any other.
    let third = claim("alive", 7_000).await;
    q.heard(&third.lease, 7_000);
    assert_eq!(pass(7_500).await.expect("pass"), (1, 0));
    let stored = q
        .complete(
            "j",
            third.idx,
            &third.lease,
            third.rect(),
            &pixels(third.rect()),
            0,
        )
        .await
        .expect("complete");
    assert!(matches!(stored, Completion::Stored { .. }), "{stored:?}");
}
on_both!(while_the_storage_fails_the_leases_of_silent_workers_are_reaped);

/// The roster of workers seen is the database's: what one store heard is listed by
/// another store on the same database, counts added up, by name, and only those heard
/// from since the time asked.
async fn the_roster_of_workers_is_kept_in_the_database(db: Db) {
    let q = open_store(&db.url()).await.expect("open");
    q.seen("b", 1_000, |w| w.claims += 2);
    q.seen("a", 2_000, |w| w.tiles_done += 1);
    q.seen("b", 3_000, |w| w.claims_with_results += 1);
    let listed = q.workers(0).await.expect("workers");
    let names: Vec<&str> = listed.iter().map(|w| w.name.as_str()).collect();
    assert_eq!(names, ["a", "b"]);
    let b = &listed[1];
    assert_eq!(
        (b.last_seen, b.claims, b.claims_with_results),
        (3_000, 2, 1)
    );
    let other = open_store(&db.url()).await.expect("open again");
    other.seen("a", 4_000, |w| w.tiles_done += 1);
    let listed = other.workers(0).await.expect("workers");
    assert_eq!((listed[0].last_seen, listed[0].tiles_done), (4_000, 2));
    assert_eq!(
        other.live_workers(2_500).await.expect("live"),
        ["a".to_string(), "b".to_string()]
    );
    assert_eq!(
        q.live_workers(3_500).await.expect("live"),
        ["a".to_string()]
    );
}
on_both!(the_roster_of_workers_is_kept_in_the_database);
