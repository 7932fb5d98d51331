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
//! one per tile while the others idle, and a tile's size does not decide how long a job's
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

/// Renders a rectangle of a tile to sRGB bytes; `None` once the tile is given up.
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
        // poisoned; a poisoned lock's state would still be sound.
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
mod tests;
