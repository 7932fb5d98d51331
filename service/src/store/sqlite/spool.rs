//! Tile pixels on their way from a worker's result to their band of the PNG: one file per
//! job beside the database (`<database>-tiles/<job>.rgb`), instead of SQLite pages.
//!
//! Why: a tile's pixels are written once and read once, by the band that encodes them. In
//! SQLite they would be copied into a record, written to the WAL a page at a time,
//! checkpointed into the database file, read back, and their pages freed and reused: a
//! large share of the service's own CPU (see docs/PERFORMANCE.md). Here they are one
//! `pwrite` and one `pread` of the page cache.
//!
//! What it is not: the record of which tiles are done. The queue's `tile_pixels` rows are
//! (see the SQLite backend's `leases` and `images`); a row of a spooled tile holds no pixels but the CRC-32 of its bytes.
//! Bytes that do not match their row when read, or cannot be read at all, are a lost tile:
//! the queue hands it out again rather than encode them (and fails the job once a tile was
//! lost `--max-attempts` times, see `SqliteStore::requeue_lost`). That happens when
//! - the machine stopped after SQLite's commit reached the disk but before the file's page
//!   did (neither is `fsync`ed per tile; SQLite's WAL with `synchronous = NORMAL` makes
//!   the same trade for its own pages);
//! - someone deleted or truncated the file;
//! - a tile's lease ran out and its late holder posted other bytes over the slot before
//!   the tile was handed out again (see below; a deterministic render posts the same).
//!
//! The layout is the image's own bytes, tile by tile. A band of tiles with top row `y` and
//! height `h` begins at byte `3·y·width`; in it, the tile at column `x` (width `w`) takes
//! the `3·w·h` bytes from `3·(y·width + x·h)`. The tiler cuts every image into such bands
//! (all tiles of a band share its height), so the slots of a job's tiles are disjoint and
//! fill the file exactly: the file never outgrows `3·width·height` bytes, however often a
//! tile is rendered again, and no allocation needs remembering across a restart. A
//! rectangle outside the image has no slot and is never written.
//!
//! The bytes are written before the queue's statement stores the row, so that a stored
//! row always points at bytes already in the page cache and the result stays one round
//! trip to SQLite; the queue writes them only under the tile's lease as it handed it out
//! (or as the tile's row says, after a restart) and for the tile's own rectangle, so no
//! other post can touch another tile's slot. Its record of leases is not told of a lease
//! that ran out: until the tile is handed out again, the late holder's result still
//! lands in the tile's own (then unused) slot. Nothing in this module decides what is
//! current; it only moves bytes.
//!
//! A write that fails for want of room (a full disk) is remembered with its reason until
//! one succeeds ([`Spool::trouble`]), so that the queue can tell workers and stop handing
//! out tiles whose results could not be stored; after any failed write, the job's file is
//! opened afresh at the next one.

use std::collections::{HashMap, HashSet};
use std::fs::{File, OpenOptions};
use std::io;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use tessera_tracer::Rect;

use crate::store::error::SpoolError;

/// The spool folder of a database file: `<file>-tiles`, beside SQLite's `-wal` and `-shm`.
pub fn folder_for(database: &Path) -> PathBuf {
    let mut name = database.as_os_str().to_owned();
    name.push("-tiles");
    PathBuf::from(name)
}

/// Where a tile's bytes go in its job's file: `(offset, length)`, or `None` for a rectangle
/// that is empty or not inside a `width × height` image. See the module comment.
pub fn slot(width: u32, height: u32, tile: Rect) -> Option<(u64, usize)> {
    let inside = tile.width > 0
        && tile.height > 0
        && u64::from(tile.x) + u64::from(tile.width) <= u64::from(width)
        && u64::from(tile.y) + u64::from(tile.height) <= u64::from(height);
    if !inside {
        return None;
    }
    let (w, x, y) = (u64::from(width), u64::from(tile.x), u64::from(tile.y));
    let offset = 3 * (y * w + x * u64::from(tile.height));
    let len = 3 * u64::from(tile.width) * u64::from(tile.height);
    Some((offset, usize::try_from(len).ok()?))
}

#[cfg(unix)]
fn write_at(file: &File, buf: &[u8], offset: u64) -> io::Result<()> {
    std::os::unix::fs::FileExt::write_all_at(file, buf, offset)
}

#[cfg(unix)]
fn read_at(file: &File, buf: &mut [u8], offset: u64) -> io::Result<()> {
    std::os::unix::fs::FileExt::read_exact_at(file, buf, offset)
}

// Elsewhere, positioned writes move the file's cursor: one at a time per process.
#[cfg(not(unix))]
static CURSOR: Mutex<()> = Mutex::new(());

#[cfg(not(unix))]
fn write_at(mut file: &File, buf: &[u8], offset: u64) -> io::Result<()> {
    use std::io::{Seek, SeekFrom, Write};
    let _one = CURSOR.lock().unwrap_or_else(PoisonError::into_inner);
    file.seek(SeekFrom::Start(offset))?;
    file.write_all(buf)
}

#[cfg(not(unix))]
fn read_at(mut file: &File, buf: &mut [u8], offset: u64) -> io::Result<()> {
    use std::io::{Read, Seek, SeekFrom};
    let _one = CURSOR.lock().unwrap_or_else(PoisonError::into_inner);
    file.seek(SeekFrom::Start(offset))?;
    file.read_exact(buf)
}

/// One job's open file and the size of its image.
#[derive(Debug)]
struct JobFile {
    file: File,
    width: u32,
    height: u32,
}

/// The spool folder, with the files of the jobs it has written or read open.
#[derive(Debug)]
pub struct Spool {
    dir: PathBuf,
    open: Mutex<HashMap<String, Arc<JobFile>>>,
    /// Files the sweep could not remove and has said so once (it tries every sweep).
    stuck: Mutex<HashSet<PathBuf>>,
    /// The last write that failed, when none has succeeded since: when (ms since the
    /// epoch), and why. Per process by design: the spool is this process's files.
    failing: Mutex<Option<(i64, String)>>,
}

/// Fails when `dir` exists but is not a folder (checked before the database is opened, so
/// that nothing is created beside it).
pub fn check_folder(dir: &Path) -> Result<(), SpoolError> {
    match std::fs::symlink_metadata(dir) {
        Ok(m) if m.is_dir() => Ok(()),
        // A link to a folder is a folder.
        Ok(m) if m.is_symlink() && dir.is_dir() => Ok(()),
        Ok(_) => Err(SpoolError::NotAFolder(dir.to_path_buf())),
        Err(_) => Ok(()),
    }
}

impl Spool {
    /// Opens (creating if missing) the spool folder `dir`, and checks that a file can be
    /// written in it.
    pub fn open(dir: PathBuf) -> Result<Spool, SpoolError> {
        check_folder(&dir)?;
        std::fs::create_dir_all(&dir).map_err(|source| SpoolError::Io {
            path: dir.clone(),
            source,
        })?;
        let spool = Spool {
            dir,
            open: Mutex::new(HashMap::new()),
            stuck: Mutex::new(HashSet::new()),
            failing: Mutex::new(None),
        };
        // A folder that cannot take files is refused; a full disk is not: the service then
        // starts read-only (see the service's `startup`), and takes writes once it has room.
        match spool.probe() {
            Err(e) if !e.is_capacity() => Err(e),
            _ => Ok(spool),
        }
    }

    /// Writes and removes a small file in the folder: whether tile pixels can be stored now
    /// (the service's start, and its health check).
    pub fn probe(&self) -> Result<(), SpoolError> {
        let path = self.dir.join("probe.tmp");
        let unwritable = |source| SpoolError::Unwritable {
            dir: self.dir.clone(),
            source,
        };
        std::fs::write(&path, b"tessera").map_err(unwritable)?;
        match std::fs::remove_file(&path) {
            // Another probe at the same moment (two health checks, two queues on one
            // database in tests) removed it first: the write is what was being tested.
            Err(e) if e.kind() != io::ErrorKind::NotFound => Err(unwritable(e)),
            _ => Ok(()),
        }
    }

    /// While a lack of room is recorded (within `within` before `now`), probes the folder;
    /// a probe that finds no room renews the record at `now`. So the farm stays paused as
    /// long as the disk stays full, not only for `within` after the last failed result:
    /// with no room, workers hold back their results and nothing else would fail a write.
    /// A probe that writes leaves the record to lapse as it would.
    pub fn recheck(&self, now: i64, within: Duration) {
        if self.trouble(now, within).is_none() {
            return;
        }
        if let Err(e) = self.probe()
            && e.is_capacity()
        {
            *self.failing.lock().unwrap_or_else(PoisonError::into_inner) =
                Some((now, e.to_string()));
        }
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The file of job `id`. Job ids are the service's own (hexadecimal); any other byte is
    /// written as `%XX`, so that no id can name a path outside the folder.
    pub fn path(&self, id: &str) -> PathBuf {
        let mut name = String::with_capacity(id.len() + 4);
        for b in id.bytes() {
            if b.is_ascii_alphanumeric() || b == b'_' || b == b'-' {
                name.push(char::from(b));
            } else {
                name.push_str(&format!("%{b:02X}"));
            }
        }
        name.push_str(".rgb");
        self.dir.join(name)
    }

    fn io(&self, id: &str) -> impl FnOnce(io::Error) -> SpoolError + '_ {
        let path = self.path(id);
        move |source| SpoolError::Io { path, source }
    }

    /// Whether job `id`'s file is open here, with its image size.
    pub fn size_of(&self, id: &str) -> Option<(u32, u32)> {
        let open = self.open.lock().unwrap_or_else(PoisonError::into_inner);
        open.get(id).map(|f| (f.width, f.height))
    }

    /// Job `id`'s file for a `width × height` image, opened if it is not open; with
    /// `create`, created if missing (and the folder too, should something have removed it).
    fn job(
        &self,
        id: &str,
        width: u32,
        height: u32,
        create: bool,
    ) -> Result<Arc<JobFile>, SpoolError> {
        let mut open = self.open.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(f) = open.get(id) {
            return Ok(f.clone());
        }
        let path = self.path(id);
        let opening = || {
            OpenOptions::new()
                .read(true)
                .write(true)
                .create(create)
                .truncate(false)
                .open(&path)
        };
        let file = match opening() {
            Err(e) if create && e.kind() == io::ErrorKind::NotFound => {
                std::fs::create_dir_all(&self.dir).and_then(|()| opening())
            }
            // A file left that this service may not open (another user's, say): its bytes
            // are of no use to anyone but this job, whose tiles they are; start it afresh.
            // Not for other failures (too many open files, an I/O error), which may pass,
            // while the file holds the job's stored tiles.
            Err(e) if create && e.kind() == io::ErrorKind::PermissionDenied => {
                std::fs::remove_file(&path).and_then(|()| opening())
            }
            other => other,
        }
        .map_err(self.io(id))?;
        let f = Arc::new(JobFile {
            file,
            width,
            height,
        });
        open.insert(id.to_string(), f.clone());
        Ok(f)
    }

    /// Writes a tile's bytes into its slot of job `id`'s file (a `width × height` image) and
    /// returns their CRC-32. A failure for want of room is dated `now` (see
    /// [`Spool::trouble`]).
    pub fn write(
        &self,
        id: &str,
        width: u32,
        height: u32,
        tile: Rect,
        rgb: &[u8],
        now: i64,
    ) -> Result<u32, SpoolError> {
        let outside = SpoolError::Outside {
            tile,
            width,
            height,
        };
        let Some((offset, len)) = slot(width, height, tile) else {
            return Err(outside);
        };
        if len != rgb.len() {
            return Err(outside);
        }
        let written = self
            .job(id, width, height, true)
            .and_then(|f| write_at(&f.file, rgb, offset).map_err(self.io(id)));
        match written {
            Ok(()) => {
                // Hashed before the lock, which every result's write takes, is held.
                let crc = crc32fast::hash(rgb);
                *self.failing.lock().unwrap_or_else(PoisonError::into_inner) = None;
                Ok(crc)
            }
            Err(e) => {
                // Only a lack of room pauses the farm (see `trouble`): another failure is
                // this job file's, and its tile is charged instead.
                if e.is_capacity() {
                    *self.failing.lock().unwrap_or_else(PoisonError::into_inner) =
                        Some((now, e.to_string()));
                }
                // The next write opens the file afresh: the one open may be what failed.
                self.open
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .remove(id);
                Err(e)
            }
        }
    }

    /// Why tile pixels could not be written, if a write failed for want of room
    /// ([`SpoolError::is_capacity`]) less than `within` before `now` and none has
    /// succeeded since: the service hands out no work meanwhile, since no result could be
    /// stored.
    pub fn trouble(&self, now: i64, within: Duration) -> Option<String> {
        let within = i64::try_from(within.as_millis()).unwrap_or(i64::MAX);
        let failing = self.failing.lock().unwrap_or_else(PoisonError::into_inner);
        failing
            .as_ref()
            .filter(|(at, _)| now.saturating_sub(*at) < within)
            .map(|(_, why)| why.clone())
    }

    /// Appends a tile's bytes from job `id`'s file to `buf` and checks them against `crc`:
    /// false, with `buf` as it was, when they do not match or cannot be read (a lost tile:
    /// see the module comment; a file that is not there is not created). Appending lets a
    /// band's tiles be read one after another into one buffer, each straight from the file.
    pub fn read(
        &self,
        id: &str,
        width: u32,
        height: u32,
        tile: Rect,
        crc: u32,
        buf: &mut Vec<u8>,
    ) -> bool {
        let Some((offset, len)) = slot(width, height, tile) else {
            return false;
        };
        let start = buf.len();
        // Every byte is read over: no need to clear (and zero) a buffer of the right size.
        buf.resize(start + len, 0);
        let read = self
            .job(id, width, height, false)
            .and_then(|f| read_at(&f.file, &mut buf[start..], offset).map_err(self.io(id)));
        let good = match read {
            Ok(()) => crc32fast::hash(&buf[start..]) == crc,
            // Not there, shorter than the slot (never written, or truncated), or unreadable.
            Err(e) => {
                tracing::warn!(job = %id, "reading tile {tile:?}: {e}");
                false
            }
        };
        if !good {
            buf.truncate(start);
        }
        good
    }

    /// Closes job `id`'s file, keeping it: the job ended without an image, and its tiles
    /// wait for a retry or its deletion. The next read or write opens it again.
    pub fn close(&self, id: &str) {
        self.open
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .remove(id);
    }

    /// Deletes job `id`'s file (its image is stored, or the job was deleted).
    pub fn remove(&self, id: &str) {
        self.close(id);
        match std::fs::remove_file(self.path(id)) {
            Ok(()) => {}
            Err(e) if e.kind() == io::ErrorKind::NotFound => {}
            Err(e) => tracing::warn!("removing {}: {e}", self.path(id).display()),
        }
    }

    /// The files in the folder now, as paths.
    pub fn listing(&self) -> Result<Vec<PathBuf>, SpoolError> {
        let entries = std::fs::read_dir(&self.dir).map_err(|source| SpoolError::Io {
            path: self.dir.clone(),
            source,
        })?;
        Ok(entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "rgb"))
            .collect())
    }

    /// Closes the files of jobs not in `active`, and deletes the files of `listing` (taken
    /// before `kept` was read) that belong to no job of `kept`: jobs whose image is stored
    /// since, or that were deleted. `kept` holds the active jobs and those that ended
    /// without an image (their tiles wait for a retry). A job submitted after the listing is
    /// not in it, so its file is safe however late `kept` was read. Returns how many files
    /// it deleted.
    pub fn sweep(&self, listing: &[PathBuf], active: &[String], kept: &[String]) -> usize {
        let open_ones: HashSet<&str> = active.iter().map(String::as_str).collect();
        let mut open = self.open.lock().unwrap_or_else(PoisonError::into_inner);
        open.retain(|id, _| open_ones.contains(id.as_str()));
        drop(open);
        let keep: HashSet<PathBuf> = kept.iter().map(|id| self.path(id)).collect();
        let mut removed = 0;
        for path in listing.iter().filter(|p| !keep.contains(*p)) {
            match std::fs::remove_file(path) {
                Ok(()) => removed += 1,
                Err(e) if e.kind() == io::ErrorKind::NotFound => {}
                Err(e) => {
                    let mut stuck = self.stuck.lock().unwrap_or_else(PoisonError::into_inner);
                    if stuck.insert(path.clone()) {
                        tracing::warn!(
                            "removing {} (tried again every sweep): {e}",
                            path.display()
                        );
                    }
                }
            }
        }
        removed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_slots_of_any_tiling_are_disjoint_and_fill_the_image_exactly() {
        for (width, height, edge) in [
            (1, 1, 1),
            (7, 5, 3),
            (64, 64, 64),
            (65, 63, 16),
            (1920, 1080, 256),
            (1921, 1079, 100),
            (3, 1000, 7),
        ] {
            let mut spans: Vec<(u64, u64)> = tessera_tracer::tiles(width, height, edge)
                .into_iter()
                .map(|t| {
                    let (at, len) = slot(width, height, t).expect("a tile is inside its image");
                    (at, at + len as u64)
                })
                .collect();
            spans.sort_unstable();
            // Independent of the formula: sorted spans must abut from 0 to the image's size.
            let mut end = 0;
            for (at, to) in spans {
                assert_eq!(at, end, "{width}×{height} by {edge}: gap or overlap");
                end = to;
            }
            assert_eq!(end, 3 * u64::from(width) * u64::from(height));
        }
    }

    #[test]
    fn rectangles_outside_the_image_have_no_slot() {
        assert_eq!(slot(10, 10, Rect::new(0, 0, 0, 4)), None);
        assert_eq!(slot(10, 10, Rect::new(8, 0, 3, 4)), None);
        assert_eq!(slot(10, 10, Rect::new(0, 9, 2, 2)), None);
        assert_eq!(slot(10, 10, Rect::new(u32::MAX, 0, 1, 1)), None);
        assert!(slot(10, 10, Rect::new(8, 8, 2, 2)).is_some());
    }

    #[test]
    fn ids_cannot_name_a_path_outside_the_folder() {
        let dir = std::env::temp_dir().join(format!("spool-ids-{}", std::process::id()));
        let spool = Spool::open(dir.clone()).expect("folder");
        for id in ["../x", "a/b", "..", "", "ab%2F"] {
            let p = spool.path(id);
            assert_eq!(p.parent(), Some(dir.as_path()), "{id}: {}", p.display());
        }
        assert_ne!(spool.path("a/b"), spool.path("a%2Fb"));
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn bytes_read_back_are_checked_against_their_crc() {
        let dir = std::env::temp_dir().join(format!("spool-crc-{}", std::process::id()));
        let spool = Spool::open(dir.clone()).expect("folder");
        let tile = Rect::new(2, 0, 2, 3);
        let rgb: Vec<u8> = (0..18).collect();
        let crc = spool.write("j", 4, 3, tile, &rgb, 0).expect("written");
        let mut buf = vec![7];
        assert!(spool.read("j", 4, 3, tile, crc, &mut buf));
        assert_eq!(buf[0], 7, "read appends");
        assert_eq!(buf[1..], rgb);
        buf.clear();
        // A wrong CRC, a tile never written (a hole of zeros before the written slot), a
        // changed byte, a file shorter than the slot and a deleted file are all lost tiles.
        assert!(!spool.read("j", 4, 3, tile, crc ^ 1, &mut buf));
        let other = Rect::new(0, 0, 2, 3);
        assert!(!spool.read("j", 4, 3, other, crc, &mut buf));
        let f = OpenOptions::new()
            .write(true)
            .open(spool.path("j"))
            .expect("file");
        write_at(&f, &[255], 3 * 2 * 3 + 5).expect("write");
        assert!(!spool.read("j", 4, 3, tile, crc, &mut buf));
        f.set_len(3 * 2 * 3 + 4).expect("truncate");
        assert!(!spool.read("j", 4, 3, tile, crc, &mut buf));
        spool.remove("j");
        assert!(!spool.read("j", 4, 3, tile, crc, &mut buf));
        assert!(buf.is_empty(), "a lost tile leaves nothing in the buffer");
        assert!(!spool.path("j").exists(), "reading creates no file");
        assert!(
            spool
                .write("j", 4, 3, Rect::new(3, 0, 2, 3), &rgb, 0)
                .is_err()
        );
        // A folder removed under the service is made again by the next write.
        std::fs::remove_dir_all(&dir).expect("remove the folder");
        let crc = spool.write("k", 4, 3, tile, &rgb, 0).expect("written");
        assert!(spool.read("k", 4, 3, tile, crc, &mut buf));
        let _ = std::fs::remove_dir_all(dir);
    }
}
