//! The render threads of a worker: one line of tiles that any idle thread takes from, oldest
//! first, and tiles that idle threads help finish.
//!
//! The threads are shared by a worker's slots, and by the service's local workers. A slot
//! puts its next tile in line while its current one renders, so a thread goes from one tile
//! to the next without waiting for the async side (which, on a machine whose cores are all
//! rendering, may wait milliseconds for a time slice). A thread whose slot has nothing for it
//! (at a job's end, or while that slot's next claim is on its way) takes the tile another
//! slot put in line.
//!
//! **Strips.** A tile is rendered in strips of rows, handed out one at a time from a
//! counter by whichever thread asks next. The thread that took the tile from the line
//! renders strip after strip; a thread that finds the line empty joins a tile still being
//! rendered and takes its next strips, going back to the line between strips as soon as a
//! tile waits there. So the last tiles of a job are finished by every thread instead of
//! one per tile while the others idle, and a tile's size no longer decides how long a job's
//! end keeps cores idle. A pixel's value does not depend on the rectangle it is rendered in,
//! so the bytes are those of the whole tile; the adaptive sampler's tiles are rendered
//! whole all the same (its strips would trace the rows along each strip's border again).
//! Idle threads sleep on a condition variable: nothing spins.
//!
//! This module knows nothing of HTTP or leases: a tile comes with a function that renders a
//! rectangle of it, a flag that gives it up, and a channel for its answer.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};

use tessera_tracer::Rect;
use tokio::sync::oneshot;

/// What a render thread sends back: the tile's sRGB bytes, or why it could not render.
pub(crate) type Rendered = Result<Vec<u8>, String>;

/// Renders a rectangle of a tile to sRGB bytes; `None` once the tile was given up.
pub(crate) type RenderRect = Box<dyn Fn(Rect) -> Option<Vec<u8>> + Send + Sync>;

/// Pixels a strip holds at most (whole rows of the tile, at least one): some hundreds of
/// microseconds of tracing at one ray per pixel, against a lock and a copy of the strip.
pub const STRIP_PIXELS: u32 = 4096;

/// The render threads (`tessera-render-0`, …). Clones share them; the threads end when the
/// last clone is dropped.
#[derive(Clone)]
pub struct RenderPool {
    inner: Arc<Inner>,
    _open: Arc<Open>,
}

impl std::fmt::Debug for RenderPool {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RenderPool").finish_non_exhaustive()
    }
}

struct Inner {
    state: Mutex<State>,
    wake: Condvar,
    /// How many tiles are in line, read without the lock by threads helping with a tile.
    in_line: AtomicUsize,
}

#[derive(Default)]
struct State {
    line: VecDeque<Arc<Tile>>,
    /// Tiles taken from the line whose strips may not all be handed out yet.
    sharing: Vec<Arc<Tile>>,
    /// Threads asleep waiting for work.
    idle: usize,
    closed: bool,
}

/// Closes the pool when the last [`RenderPool`] clone goes.
struct Open(Arc<Inner>);

impl Drop for Open {
    fn drop(&mut self) {
        self.0.lock().closed = true;
        self.0.wake.notify_all();
    }
}

impl Inner {
    fn lock(&self) -> MutexGuard<'_, State> {
        // Nothing panics while holding the lock (renders run outside it), so it is never
        // poisoned; if it were, the state behind it is still sound.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn push(&self, tile: Arc<Tile>) {
        let mut state = self.lock();
        state.line.push_back(tile);
        self.in_line.fetch_add(1, Ordering::Relaxed);
        // Every sleeper is woken, not one: a thread helping with a tile is not asleep, and
        // one woken sleeper may find the work already taken by it.
        if state.idle > 0 {
            self.wake.notify_all();
        }
    }
}

/// A tile being rendered in strips.
pub(crate) struct Tile {
    rect: Rect,
    /// Rows per strip, and strips in all.
    rows: u32,
    strips: u32,
    /// The next strip to hand out, and how many are not yet rendered.
    next: AtomicU32,
    left: AtomicU32,
    render: RenderRect,
    stop: Arc<AtomicBool>,
    started: Arc<AtomicBool>,
    /// The tile's bytes as its strips come in; allocated by the first (a tile of one strip
    /// never needs it).
    out: Mutex<Vec<u8>>,
    reply: Mutex<Option<oneshot::Sender<Rendered>>>,
}

/// A tile for [`RenderPool::render`].
pub(crate) struct TileWork {
    pub rect: Rect,
    /// Render it in strips that other threads may take (false: whole, by one thread).
    pub shareable: bool,
    pub render: RenderRect,
    /// Set by the slot to give the tile up: strips not yet begun are skipped.
    pub stop: Arc<AtomicBool>,
    /// Set here when a thread begins the tile.
    pub started: Arc<AtomicBool>,
    pub reply: oneshot::Sender<Rendered>,
}

impl Tile {
    fn has_strips(&self) -> bool {
        self.next.load(Ordering::Relaxed) < self.strips && !self.stop.load(Ordering::Relaxed)
    }

    /// Renders strips until none is left to hand out; a `helper` also stops as soon as a
    /// tile waits in line (its own slot's next tile, or another slot's).
    fn work(&self, inner: &Inner, helper: bool) {
        loop {
            if helper && inner.in_line.load(Ordering::Relaxed) > 0 {
                return;
            }
            let i = self.next.fetch_add(1, Ordering::Relaxed);
            if i >= self.strips || self.stop.load(Ordering::Relaxed) {
                return;
            }
            let y = self.rect.y + i * self.rows;
            let h = self.rows.min(self.rect.y + self.rect.height - y);
            let strip = Rect::new(self.rect.x, y, self.rect.width, h);
            let rendered =
                std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| (self.render)(strip)));
            match rendered {
                // A tile of one strip (the adaptive sampler's) is answered with the render's
                // own bytes, not a copy.
                Ok(Some(bytes)) if self.strips == 1 && bytes.len() == strip.pixel_count() * 3 => {
                    self.answer(Ok(bytes));
                    return;
                }
                Ok(Some(bytes)) if bytes.len() == strip.pixel_count() * 3 => {
                    let at = (i * self.rows * self.rect.width) as usize * 3;
                    let mut out = self.out.lock().unwrap_or_else(PoisonError::into_inner);
                    if out.is_empty() {
                        out.resize(self.rect.pixel_count() * 3, 0);
                    }
                    out[at..at + bytes.len()].copy_from_slice(&bytes);
                }
                Ok(Some(bytes)) => {
                    self.stop.store(true, Ordering::Relaxed);
                    self.answer(Err(format!(
                        "a strip of {} pixels rendered to {} bytes",
                        strip.pixel_count(),
                        bytes.len()
                    )));
                    return;
                }
                // Given up: the slot has moved on and waits for no answer.
                Ok(None) => return,
                Err(panic) => {
                    let what = panic
                        .downcast_ref::<&str>()
                        .map(|s| s.to_string())
                        .or_else(|| panic.downcast_ref::<String>().cloned())
                        .unwrap_or_else(|| "unknown panic".into());
                    self.stop.store(true, Ordering::Relaxed);
                    self.answer(Err(format!("rendering panicked: {what}")));
                    return;
                }
            }
            if self.left.fetch_sub(1, Ordering::AcqRel) == 1 {
                let rgb =
                    std::mem::take(&mut *self.out.lock().unwrap_or_else(PoisonError::into_inner));
                self.answer(Ok(rgb));
                return;
            }
        }
    }

    fn answer(&self, rendered: Rendered) {
        let reply = self
            .reply
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .take();
        // The slot may have given the tile up meanwhile: nobody to tell.
        if let Some(reply) = reply {
            let _ = reply.send(rendered);
        }
    }
}

impl RenderPool {
    /// Starts `threads` render threads (`tessera-render-0`, …); at least one.
    pub fn new(threads: usize) -> std::io::Result<RenderPool> {
        if threads == 0 {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "a render pool needs at least one thread",
            ));
        }
        let inner = Arc::new(Inner {
            state: Mutex::new(State::default()),
            wake: Condvar::new(),
            in_line: AtomicUsize::new(0),
        });
        let open = Arc::new(Open(inner.clone()));
        for index in 0..threads {
            let inner = inner.clone();
            std::thread::Builder::new()
                .name(format!("tessera-render-{index}"))
                .spawn(move || thread_main(&inner))?;
        }
        Ok(RenderPool { inner, _open: open })
    }

    /// Puts a tile in line.
    pub(crate) fn render(&self, t: TileWork) {
        let (w, h) = (t.rect.width.max(1), t.rect.height.max(1));
        let rows = if t.shareable {
            (STRIP_PIXELS / w).clamp(1, h)
        } else {
            h
        };
        let strips = h.div_ceil(rows);
        let tile = Tile {
            rect: t.rect,
            rows,
            strips,
            next: AtomicU32::new(0),
            left: AtomicU32::new(strips),
            render: t.render,
            stop: t.stop,
            started: t.started,
            out: Mutex::new(Vec::new()),
            reply: Mutex::new(Some(t.reply)),
        };
        self.inner.push(Arc::new(tile));
    }
}

fn thread_main(inner: &Inner) {
    let mut state = inner.lock();
    loop {
        // Tiles with no strips left to hand out go (and with them their scenes, which a
        // finished job would otherwise keep while the line stays busy).
        state.sharing.retain(|t| t.has_strips());
        if let Some(tile) = state.line.pop_front() {
            inner.in_line.fetch_sub(1, Ordering::Relaxed);
            // Given up while in line: skipped, no answer (nobody waits for one).
            if tile.stop.load(Ordering::Relaxed) {
                continue;
            }
            tile.started.store(true, Ordering::Relaxed);
            if tile.strips > 1 {
                state.sharing.push(tile.clone());
                // Sleeping threads come and help while the line is empty.
                if state.idle > 0 && state.line.is_empty() {
                    inner.wake.notify_all();
                }
            }
            drop(state);
            tile.work(inner, false);
            state = inner.lock();
            continue;
        }
        if let Some(tile) = state.sharing.first().cloned() {
            drop(state);
            tile.work(inner, true);
            state = inner.lock();
            continue;
        }
        if state.closed {
            return;
        }
        state.idle += 1;
        state = inner
            .wake
            .wait(state)
            .unwrap_or_else(PoisonError::into_inner);
        state.idle -= 1;
    }
}

#[cfg(test)]
mod tests {
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
            .expect("the tile in line was rendered")
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
            "the other strips were rendered by the idle thread"
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
}
