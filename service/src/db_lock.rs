//! One service per database: an advisory lock on a file beside the database, taken before the
//! service touches the store and held for its life.
//!
//! A second service on the same file would take the first's local workers for dead (it
//! requeues their tiles at start, and renews nothing of theirs), and its waits and progress
//! would never hear of the first's results. So it refuses to start, naming the lock file.
//!
//! The lock is `flock` on `<database>-service.lock`, which the kernel releases when the
//! process ends however it ends (SIGKILL, out of memory): a service that was killed never
//! keeps the next one out, and the file left behind is empty and harmless. It is not taken on
//! the database file itself: SQLite's own locks on that are POSIX record locks, which a
//! process loses when it closes *any* descriptor of the file.
//!
//! What it is not: a guard against other programs using the database (SQLite's own locking
//! keeps those consistent), nor against a service on another machine sharing the file over
//! a network file system that does not honour `flock`. In-memory databases take no lock. It
//! is released when `serve` returns: in the binary the process ends then, but a program
//! that calls `serve` itself should let the runtime's remaining tasks end before it starts
//! another service on the file.

use std::fs::{File, OpenOptions, TryLockError};
use std::path::PathBuf;
use std::str::FromStr;

use sqlx::sqlite::SqliteConnectOptions;

/// Why the lock could not be taken.
#[derive(Debug, thiserror::Error)]
pub enum LockError {
    #[error(
        "another tessera-service is using the database {database} (it holds {lock}): one \
         service per database. Stop that one first, or give this one another --database."
    )]
    Held { database: PathBuf, lock: PathBuf },
    #[error(
        "cannot open {lock}, the lock file beside the database: {source} (the database's \
         folder must exist and be writable)"
    )]
    Open {
        lock: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

/// The lock, held until dropped (or the process ends).
#[derive(Debug)]
pub struct DbLock {
    _file: File,
    /// How many names (hard links) the database file has, when it has more than one: the
    /// lock is found by name, so a service started through another of them is not kept out.
    pub other_names: Option<u64>,
}

impl DbLock {
    /// Takes the lock of the database at `url` (as `--database` gives it), without waiting.
    /// `None` for an in-memory database, and for a URL the queue will refuse anyway (it
    /// says why).
    pub fn take(url: &str) -> Result<Option<DbLock>, LockError> {
        let Some(database) = database_file(url) else {
            return Ok(None);
        };
        let database = real_path(database);
        let mut name = database.clone().into_os_string();
        name.push("-service.lock");
        let lock = PathBuf::from(name);
        let file = OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(&lock)
            .map_err(|source| LockError::Open {
                lock: lock.clone(),
                source,
            })?;
        // A hard link is another name of the same file, whose lock file is another: not
        // locked here, since a lock on the database file itself would meet SQLite's own
        // record locks on macOS and the BSDs and over NFS or SMB (where `flock` and `fcntl`
        // locks interact), but said, so that whoever runs two services can find out why.
        let links = std::fs::metadata(&database).map_or(1, |m| {
            #[cfg(unix)]
            {
                std::os::unix::fs::MetadataExt::nlink(&m)
            }
            #[cfg(not(unix))]
            {
                let _ = m;
                1
            }
        });
        match file.try_lock() {
            Ok(()) => Ok(Some(DbLock {
                _file: file,
                other_names: (links > 1).then_some(links),
            })),
            Err(TryLockError::WouldBlock) => Err(LockError::Held { database, lock }),
            Err(TryLockError::Error(source)) => Err(LockError::Open { lock, source }),
        }
    }
}

/// The path of the file itself, through symbolic links and `..`, so that every name of one
/// database takes one lock (else a link to the file would take a lock of its own, and a
/// second service would start beside the first); for a database not created yet, its folder's real path and
/// its name. As written where even the folder cannot be resolved (opening the lock then
/// says why). Hard links are other paths to the same file and are not recognised (the
/// service warns when the file has more than one).
fn real_path(database: PathBuf) -> PathBuf {
    if let Ok(real) = std::fs::canonicalize(&database) {
        return real;
    }
    let folder = match database.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => std::path::Path::new("."),
    };
    match (std::fs::canonicalize(folder), database.file_name()) {
        (Ok(folder), Some(name)) => folder.join(name),
        _ => database,
    }
}

/// The file a `--database` value names, as sqlx will open it; `None` in memory or unparsable.
fn database_file(url: &str) -> Option<PathBuf> {
    if !crate::store::is_sqlite(url) || url.contains(":memory:") || url.contains("mode=memory") {
        return None;
    }
    let opts = SqliteConnectOptions::from_str(url).ok()?;
    let path = opts.get_filename();
    (!path.as_os_str().is_empty()).then(|| path.to_path_buf())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp(tag: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("tessera-db-lock-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("temp dir");
        dir
    }

    /// Held once per database, whichever way the URL names it; free again when dropped; a
    /// second database beside it is another lock.
    #[test]
    fn one_holder_per_database_file() {
        let dir = temp("one");
        let db = dir.join("q.db");
        let url = format!("sqlite://{}", db.display());
        let first = DbLock::take(&url).expect("free").expect("a file");
        match DbLock::take(db.to_str().expect("UTF-8 path")) {
            Err(LockError::Held { lock, .. }) => {
                assert_eq!(lock, dir.join("q.db-service.lock"));
            }
            other => panic!("taken twice: {other:?}"),
        }
        assert!(DbLock::take(&format!("{url}?mode=rwc")).is_err());
        let other = DbLock::take(&format!("sqlite://{}", dir.join("r.db").display()));
        assert!(matches!(other, Ok(Some(_))));
        drop(first);
        assert!(matches!(DbLock::take(&url), Ok(Some(_))));
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A symbolic link to the database, or a path through `..`, is the same database: one
    /// lock, whether the file exists yet or not.
    #[test]
    fn other_names_of_one_database_share_its_lock() {
        let dir = temp("names");
        std::fs::create_dir_all(dir.join("sub")).expect("sub folder");
        let db = dir.join("q.db");
        let _first = DbLock::take(db.to_str().expect("UTF-8"))
            .expect("free")
            .expect("a file");
        let dotted = dir.join("sub/../q.db");
        assert!(matches!(
            DbLock::take(dotted.to_str().expect("UTF-8")),
            Err(LockError::Held { .. })
        ));
        std::fs::write(&db, b"").expect("the database file");
        let link = dir.join("link.db");
        std::os::unix::fs::symlink(&db, &link).expect("symlink");
        match DbLock::take(&format!("sqlite://{}", link.display())) {
            Err(LockError::Held { lock, .. }) => assert_eq!(
                lock,
                std::fs::canonicalize(&dir)
                    .expect("real")
                    .join("q.db-service.lock")
            ),
            other => panic!("a link took its own lock: {other:?}"),
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A hard link is another name whose lock file is another: not locked out, but counted,
    /// for the service's warning.
    #[test]
    fn a_database_with_hard_links_says_how_many_names_it_has() {
        let dir = temp("hard");
        let db = dir.join("q.db");
        let alone = DbLock::take(db.to_str().expect("UTF-8"))
            .expect("free")
            .expect("a file");
        assert_eq!(alone.other_names, None, "no file yet");
        drop(alone);
        std::fs::write(&db, b"").expect("the database file");
        std::fs::hard_link(&db, dir.join("hard.db")).expect("hard link");
        let linked = DbLock::take(db.to_str().expect("UTF-8"))
            .expect("free")
            .expect("a file");
        assert_eq!(linked.other_names, Some(2));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn memory_takes_no_lock_and_a_missing_folder_says_so() {
        assert!(matches!(DbLock::take("sqlite::memory:"), Ok(None)));
        // The queue refuses other schemes with its own message ("SQLite only").
        assert!(matches!(DbLock::take("postgres://u@h/db"), Ok(None)));
        let dir = temp("missing");
        let url = format!("sqlite://{}", dir.join("no/such/folder/q.db").display());
        let e = DbLock::take(&url).expect_err("no folder");
        assert!(e.to_string().contains("folder must exist"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
