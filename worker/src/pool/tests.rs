//! Unit tests of the render threads: lines, strips, helpers, give-ups and failures.

use super::*;
use std::sync::mpsc;
use std::time::Duration;

const WAIT: Duration = Duration::from_secs(30);

/// The bytes a test tile's pixel holds: a function of its place in the image only, as a
/// render's are, so any split into strips must give the whole tile's bytes.
fn shade(x: u32, y: u32) -> [u8; 3] {
    [(x * 7) as u8, (y * 13) as u8, (x ^ y) as u8]
}

fn shaded(r: Rect) -> Vec<u8> {
    (r.y..r.y + r.height)
        .flat_map(|y| (r.x..r.x + r.width).flat_map(move |x| shade(x, y)))
        .collect()
}

struct Submitted {
    rendered: oneshot::Receiver<Rendered>,
    started: Arc<AtomicBool>,
    stop: Arc<AtomicBool>,
}

fn submit(
    pool: &RenderPool,
    rect: Rect,
    shareable: bool,
    render: impl Fn(Rect) -> Option<Vec<u8>> + Send + Sync + 'static,
) -> Submitted {
    let (reply, rendered) = oneshot::channel();
    let started = Arc::new(AtomicBool::new(false));
    let stop = Arc::new(AtomicBool::new(false));
    pool.render(TileWork {
        rect,
        shareable,
        render: Box::new(render),
        stop: stop.clone(),
        started: started.clone(),
        reply,
    });
    Submitted {
        rendered,
        started,
        stop,
    }
}

/// A render that signals `began` and then waits for `go` (or gives up after `WAIT`).
fn held(
    began: mpsc::Sender<()>,
    go: mpsc::Receiver<()>,
) -> impl Fn(Rect) -> Option<Vec<u8>> + Send + Sync + 'static {
    let (began, go) = (Mutex::new(began), Mutex::new(go));
    move |r| {
        let _ = began
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .send(());
        let _ = go
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .recv_timeout(WAIT);
        Some(shaded(r))
    }
}

#[test]
fn a_pool_needs_a_thread() {
    assert!(RenderPool::new(0).is_err());
}

/// A tile in line is "rendering" (what its lease renewals say) only once a thread has
/// begun it, whichever slot's thread that is.
#[test]
fn a_tile_is_started_when_a_thread_begins_it() {
    let pool = RenderPool::new(1).expect("a thread");
    let (began, began_rx) = mpsc::channel();
    let (go, go_rx) = mpsc::channel();
    let first = submit(&pool, Rect::new(0, 0, 4, 4), false, held(began, go_rx));
    began_rx.recv_timeout(WAIT).expect("the first tile began");
    let second = submit(&pool, Rect::new(4, 0, 4, 4), true, |r| Some(shaded(r)));
    // The only thread is busy: the second tile waits in line, not begun.
    assert!(first.started.load(Ordering::Relaxed));
    assert!(!second.started.load(Ordering::Relaxed));
    go.send(()).expect("the thread waits");
    let rgb = second
        .rendered
        .blocking_recv()
        .expect("an answer")
        .expect("rendered");
    assert_eq!(rgb, shaded(Rect::new(4, 0, 4, 4)));
    assert!(second.started.load(Ordering::Relaxed));
}

/// The tail of a job: one thread busy with a long tile, another slot's tile in line. The
/// idle thread takes it (with a thread per slot, it waited for the busy one).
#[test]
fn an_idle_thread_takes_the_tile_another_slot_put_in_line() {
    let pool = RenderPool::new(2).expect("threads");
    let (began, began_rx) = mpsc::channel();
    let (go, go_rx) = mpsc::channel();
    // Rendered whole (not shareable): the other thread cannot help with it.
    let _busy = submit(&pool, Rect::new(0, 0, 8, 8), false, held(began, go_rx));
    began_rx.recv_timeout(WAIT).expect("the first tile began");
    let next = submit(&pool, Rect::new(8, 0, 8, 8), false, |r| Some(shaded(r)));
    // Only the other thread can answer while the first is held.
    let (done, done_rx) = mpsc::channel();
    std::thread::spawn(move || {
        let _ = done.send(next.rendered.blocking_recv());
    });
    let rgb = done_rx
        .recv_timeout(WAIT)
        .expect("the tile in line is rendered")
        .expect("an answer")
        .expect("rendered");
    assert_eq!(rgb, shaded(Rect::new(8, 0, 8, 8)));
    go.send(()).expect("the first thread waits");
}

/// The last tile of a job: the thread that took it is held in its first strip, and the
/// idle thread renders every other strip meanwhile. The tile's bytes are the whole
/// tile's, whoever rendered which strip.
#[test]
fn an_idle_thread_renders_the_strips_of_a_tile_being_rendered() {
    let pool = RenderPool::new(2).expect("threads");
    // 32 px wide: strips of STRIP_PIXELS / 32 rows, four of them.
    let rows = STRIP_PIXELS / 32;
    let rect = Rect::new(32, 8, 32, 4 * rows);
    let (go, go_rx) = mpsc::channel::<()>();
    let go_rx = Mutex::new(go_rx);
    let (strips_tx, strips) = mpsc::channel();
    let strips_tx = Mutex::new(strips_tx);
    let first_y = rect.y;
    let tile = submit(&pool, rect, true, move |r| {
        let me = std::thread::current().id();
        let _ = strips_tx
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .send((r, me));
        if r.y == first_y {
            // Held until the other strips are in.
            let _ = go_rx
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .recv_timeout(WAIT);
        }
        Some(shaded(r))
    });
    let mut seen = Vec::new();
    for _ in 0..4 {
        seen.push(strips.recv_timeout(WAIT).expect("a strip began"));
    }
    go.send(()).expect("the first strip waits");
    let rgb = tile
        .rendered
        .blocking_recv()
        .expect("an answer")
        .expect("rendered");
    assert_eq!(rgb, shaded(rect));
    seen.sort_by_key(|(r, _)| r.y);
    let ys: Vec<u32> = seen.iter().map(|(r, _)| r.y).collect();
    assert_eq!(ys, (0..4).map(|i| rect.y + i * rows).collect::<Vec<_>>());
    assert!(seen.iter().all(|(r, _)| r.height == rows && r.width == 32));
    let holder = seen[0].1;
    assert!(
        seen[1..].iter().all(|(_, t)| *t != holder),
        "the other strips are rendered by the idle thread"
    );
}

/// A tile that is not shareable (the adaptive sampler's) is rendered in one piece.
#[test]
fn a_tile_that_is_not_shareable_is_rendered_whole() {
    let pool = RenderPool::new(2).expect("threads");
    let rect = Rect::new(0, 0, 16, 2 * STRIP_PIXELS / 16 + 3);
    let (asked_tx, asked) = mpsc::channel();
    let asked_tx = Mutex::new(asked_tx);
    let tile = submit(&pool, rect, false, move |r| {
        let _ = asked_tx
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .send(r);
        Some(shaded(r))
    });
    let rgb = tile
        .rendered
        .blocking_recv()
        .expect("answer")
        .expect("rendered");
    assert_eq!(rgb, shaded(rect));
    assert_eq!(asked.try_iter().collect::<Vec<_>>(), vec![rect]);
}

/// A strip that panics fails the tile with the panic's message, and the pool goes on.
#[test]
fn a_panicking_strip_fails_its_tile() {
    let pool = RenderPool::new(1).expect("a thread");
    let tile = submit(&pool, Rect::new(0, 0, 64, 256), true, |r| {
        if r.y > 0 {
            panic!("strip at {}", r.y);
        }
        Some(shaded(r))
    });
    let err = tile
        .rendered
        .blocking_recv()
        .expect("an answer")
        .expect_err("a panic");
    assert!(err.starts_with("rendering panicked: strip at"), "{err}");
    let next = submit(&pool, Rect::new(0, 0, 4, 4), true, |r| Some(shaded(r)));
    assert!(next.rendered.blocking_recv().expect("answer").is_ok());
}

/// A strip rendered to the wrong number of bytes fails its tile instead of panicking
/// the thread (which would leave every later tile unanswered).
#[test]
fn a_strip_of_the_wrong_size_fails_its_tile() {
    let pool = RenderPool::new(1).expect("a thread");
    let tile = submit(&pool, Rect::new(0, 0, 8, 8), true, |_| Some(vec![0; 5]));
    let err = tile
        .rendered
        .blocking_recv()
        .expect("an answer")
        .expect_err("refused");
    assert!(err.contains("rendered to 5 bytes"), "{err}");
    let next = submit(&pool, Rect::new(0, 0, 4, 4), true, |r| Some(shaded(r)));
    assert!(next.rendered.blocking_recv().expect("answer").is_ok());
}

/// A tile given up while in line is skipped: not begun, never answered.
#[test]
fn a_tile_given_up_in_line_is_skipped() {
    let pool = RenderPool::new(1).expect("a thread");
    let (began, began_rx) = mpsc::channel();
    let (go, go_rx) = mpsc::channel();
    let _busy = submit(&pool, Rect::new(0, 0, 4, 4), false, held(began, go_rx));
    began_rx.recv_timeout(WAIT).expect("began");
    let called = Arc::new(AtomicBool::new(false));
    let flag = called.clone();
    let dropped = submit(&pool, Rect::new(4, 0, 4, 4), true, move |r| {
        flag.store(true, Ordering::Relaxed);
        Some(shaded(r))
    });
    dropped.stop.store(true, Ordering::Relaxed);
    let after = submit(&pool, Rect::new(8, 0, 4, 4), true, |r| Some(shaded(r)));
    go.send(()).expect("waits");
    assert!(after.rendered.blocking_recv().expect("answer").is_ok());
    assert!(dropped.rendered.blocking_recv().is_err(), "no answer");
    assert!(!dropped.started.load(Ordering::Relaxed));
    assert!(!called.load(Ordering::Relaxed));
}
