//! The queue's guarantees, against real SQLite files: atomic claims under contention, lease
//! fencing, harmless repeats, bounded failures, keep-away, expiry.

use std::collections::HashSet;
use std::sync::Arc;

use tessera_service::queue::{Completion, KeepAway, NewJob, Queue};
use tessera_tracer::{Rect, tiles};

struct Db(std::path::PathBuf);

impl Db {
    fn new(tag: &str) -> Db {
        let dir = std::env::temp_dir().join(format!("tessera-queue-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("temp dir");
        Db(dir)
    }

    fn url(&self) -> String {
        format!("sqlite://{}", self.0.join("q.db").display())
    }
}

impl Drop for Db {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

const KEEP: KeepAway = KeepAway {
    after: 2,
    for_ms: 60_000,
};

async fn job(q: &Queue, id: &str, w: u32, h: u32, tile: u32) -> Vec<Rect> {
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

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn concurrent_claimers_never_share_a_tile() {
    let db = Db::new("claims");
    let q = Queue::open(&db.url()).await.expect("open");
    let rects = job(&q, "j", 160, 160, 8).await; // 400 tiles
    let claimed = Arc::new(std::sync::Mutex::new(Vec::new()));
    let mut tasks = Vec::new();
    // Separate pools, as separate service processes on one file would have.
    for w in 0..12 {
        let url = db.url();
        let claimed = claimed.clone();
        tasks.push(tokio::spawn(async move {
            let q = Queue::open(&url).await.expect("open");
            let name = format!("w{w}");
            while let Some(c) = q.claim(&name, 1_000, 60_000, 4).await.expect("claim") {
                let stored = q
                    .complete(&c.job, c.idx, &c.lease, c.rect(), &pixels(c.rect()))
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

#[tokio::test]
async fn stale_and_repeated_results_change_nothing() {
    let db = Db::new("stale");
    let q = Queue::open(&db.url()).await.expect("open");
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
        .complete("j", first.idx, &first.lease, first.rect(), &rgb)
        .await
        .expect("complete");
    assert!(matches!(late, Completion::Stale(_)), "{late:?}");
    assert!(
        q.renew("j", first.idx, &first.lease, 1_000, 100)
            .await
            .expect("renew")
            .is_none()
    );
    assert_eq!(q.job("j").await.expect("read").expect("job").tiles_done, 0);

    let ok = q
        .complete("j", second.idx, &second.lease, second.rect(), &rgb)
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
        .complete("j", second.idx, &second.lease, second.rect(), &rgb)
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
        .complete("j", other.idx, &other.lease, second.rect(), &rgb)
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
        .complete("j", 99, &other.lease, other.rect(), &rgb)
        .await
        .expect("complete");
    assert_eq!(missing, Completion::Missing);
}

#[tokio::test]
async fn failing_tiles_move_to_other_workers_then_fail_the_job() {
    let db = Db::new("fail");
    let q = Queue::open(&db.url()).await.expect("open");
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
    assert_eq!(j.state, "failed");
    let why = j.error.expect("a reason");
    assert!(
        why.contains("failed 3 times") && why.contains("disk full"),
        "{why}"
    );
    assert!(q.claim("c", 40, 1_000, max).await.expect("claim").is_none());
}

#[tokio::test]
async fn lost_leases_count_as_failures() {
    let db = Db::new("lost");
    let q = Queue::open(&db.url()).await.expect("open");
    job(&q, "j", 8, 8, 8).await;
    let max = 2;
    for (i, w) in ["a", "b"].iter().enumerate() {
        let now = i as i64 * 1_000;
        assert!(q.claim(w, now, 100, max).await.expect("claim").is_some());
        assert_eq!(q.reap(now + 500, max, KEEP).await.expect("reap"), 1);
    }
    let j = q.job("j").await.expect("read").expect("job");
    assert_eq!(j.state, "failed");
    assert!(j.error.unwrap_or_default().contains("stopped answering"));
}

#[tokio::test]
async fn a_job_no_live_worker_may_take_fails() {
    let db = Db::new("unservable");
    let q = Queue::open(&db.url()).await.expect("open");
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
    assert_eq!(j.state, "failed");
    assert!(j.error.unwrap_or_default().contains("bad texture"));
}
