//! Background WAL checkpoints: the WAL's pages are copied into the database file off the
//! writing connection, so that the copy and its `fsync`s do not hold claims and results.
//!
//! Per process by design: a checkpoint is a matter of one SQLite file and the process that
//! writes it, nothing another process would need to agree on.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use super::{Reader, Result, SqliteStore};
use crate::store::types::Checkpoint;

/// Tile and image bytes written between two background checkpoints (see `WalKeeper`).
pub(crate) const CHECKPOINT_EVERY_BYTES: u64 = 48 << 20;

/// WAL pages (of 4 KB) after which the writer checkpoints by itself, should the background
/// checkpoints fall behind. A background checkpoint starts at about 16,000 pages (the
/// pixels and the pages around them), and one WAL that missed starting over (a reader was
/// in it at that moment) reaches about 32,000 by the next: three times the pixels' pages
/// stays above both.
pub(super) const WRITER_CHECKPOINT_PAGES: u64 = 3 * (CHECKPOINT_EVERY_BYTES >> 12);

/// Background checkpoints: the WAL's pages are copied into the database file by a reading
/// connection while the writer goes on writing.
///
/// SQLite's automatic checkpoint runs on the connection that commits past the threshold,
/// inside that statement: it copies the WAL's pages and `fsync`s the WAL and the database.
/// On the one writer, that would hold every claim and result of every job for the copy and
/// both `fsync`s, long enough for workers to run out of tiles. A `PASSIVE` checkpoint from
/// another connection does the same work while the writer goes on appending: SQLite's WAL
/// lets one checkpointer and one writer run at once. Only a last, short pass runs on the
/// writer, for the pages appended meanwhile: with every page copied, SQLite starts the WAL
/// over at the next write instead of letting it grow. The writer keeps an
/// automatic checkpoint as a backstop, at [`WRITER_CHECKPOINT_PAGES`], which it reaches
/// only if these fall behind.
#[derive(Debug)]
pub(super) struct WalKeeper {
    /// Bytes of tile pixels and image stored since the last checkpoint began.
    written: AtomicU64,
    /// A checkpoint is under way (at most one at a time).
    running: AtomicBool,
    /// Checkpoints finished, for tests to wait on.
    pub(super) done: tokio::sync::watch::Sender<u64>,
    pub(super) every: u64,
}

impl WalKeeper {
    pub(super) fn new(every: u64, done: tokio::sync::watch::Sender<u64>) -> Arc<WalKeeper> {
        Arc::new(WalKeeper {
            written: AtomicU64::new(0),
            running: AtomicBool::new(false),
            done,
            every,
        })
    }
}

impl SqliteStore {
    /// The same store, checkpointing after every `bytes` of tiles and images instead of
    /// [`CHECKPOINT_EVERY_BYTES`] (tests).
    #[cfg(feature = "bench")]
    pub(crate) fn checkpoint_every(mut self, bytes: u64) -> SqliteStore {
        if let Some(w) = &self.wal {
            self.wal = Some(WalKeeper::new(bytes, w.done.clone()));
        }
        self
    }

    /// Copies the WAL's committed pages into the database file, from a reading connection
    /// and without blocking the writer (`PASSIVE`). Pages the writer appends meanwhile wait
    /// for the next checkpoint. `None` for an in-memory database.
    #[cfg(feature = "bench")]
    pub(crate) async fn checkpoint(&self) -> Result<Option<Checkpoint>> {
        if self.wal.is_none() {
            return Ok(None);
        }
        self.checkpoint_on(false).await.map(Some)
    }

    pub(super) async fn checkpoint_on(&self, writer: bool) -> Result<Checkpoint> {
        let mut conn = if writer {
            Reader::Writer(self.writer.lock().await?)
        } else {
            self.reader().await?
        };
        let (_busy, log, copied): (i64, i64, i64) =
            sqlx::query_as("PRAGMA wal_checkpoint(PASSIVE)")
                .fetch_one(&mut *conn)
                .await?;
        Ok(Checkpoint { log, copied })
    }

    /// Background checkpoints finished so far, as a watch (tests wait on it).
    #[cfg(feature = "bench")]
    pub(crate) fn checkpoints(&self) -> Option<tokio::sync::watch::Receiver<u64>> {
        self.wal.as_ref().map(|w| w.done.subscribe())
    }

    /// Counts `bytes` written to the WAL and, past the threshold, starts a background
    /// checkpoint unless one is under way.
    pub(super) fn wrote(&self, bytes: usize) {
        let Some(w) = &self.wal else { return };
        let total = w.written.fetch_add(bytes as u64, Ordering::Relaxed) + bytes as u64;
        if total < w.every || w.running.swap(true, Ordering::AcqRel) {
            return;
        }
        w.written.store(0, Ordering::Relaxed);
        let (queue, keeper) = (self.clone(), w.clone());
        tokio::spawn(async move {
            // A pass copies what was committed when it began; the writer appends more
            // meanwhile (a few hundred pages during a first pass of 16,000, fewer during
            // the second). Two passes on a reading connection, then a last one on the
            // writer, which nothing can write under: it leaves every page copied, and
            // SQLite starts the WAL over from its beginning at the next write (it does so
            // only when no page is left to copy).
            for on_writer in [false, false, true] {
                match queue.checkpoint_on(on_writer).await {
                    Ok(c) => {
                        tracing::debug!(log = c.log, copied = c.copied, on_writer, "WAL checkpoint")
                    }
                    Err(e) => {
                        tracing::warn!("WAL checkpoint: {e}");
                        break;
                    }
                }
            }
            keeper.running.store(false, Ordering::Release);
            keeper.done.send_modify(|n| *n += 1);
        });
    }
}
