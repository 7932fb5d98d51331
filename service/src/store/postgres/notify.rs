//! What replicas tell each other through the database: wake-ups (`LISTEN`/`NOTIFY`), the
//! maintenance lock (one replica at a time reaps and sweeps), and the assembly lock (one
//! replica at a time writes a job's PNG).
//!
//! Both locks are connection-level advisory locks (`pg_try_advisory_lock`, held until
//! released or disconnected) on a connection of their own, never a pooled one:
//! a lock taken through the pool would stay with whichever request used that connection
//! next, and die with it. A replica that dies (or loses its connection) releases its locks
//! as its connection closes, so another takes over on its next pass.

use std::sync::Arc;
use std::time::Duration;

use sqlx::Connection;
use sqlx::postgres::{PgConnection, PgListener};
use tokio::sync::{Notify, watch};

use super::{PgStore, Result};

/// The channel told that tiles became claimable (a submission, a requeue).
pub(super) const WORK: &str = "tessera_work";
/// The channel told that a job may have ended (done, failed, cancelled, deleted).
pub(super) const ENDED: &str = "tessera_ended";

/// The advisory lock key of the maintenance pass ("tessera\0" as a number).
const MAINTENANCE_KEY: i64 = 0x7465_7373_6572_6100;

/// A channel's name as a quoted SQL literal, for statements built with `concat!` that
/// notify only when a step of theirs changed a row (`SELECT pg_notify(channel!(WORK), '')
/// FROM changed`): `channel!(WORK)` is [`WORK`]'s, `channel!(ENDED)` [`ENDED`]'s.
macro_rules! channel {
    (WORK) => {
        "'tessera_work'"
    };
    (ENDED) => {
        "'tessera_ended'"
    };
}
pub(super) use channel;

/// The statement that tells `channel` (run inside the transaction whose commit it
/// announces: PostgreSQL delivers it only if that commits).
pub(super) fn notify_sql(channel: &str) -> &'static str {
    if channel == WORK {
        "SELECT pg_notify('tessera_work', '')"
    } else {
        "SELECT pg_notify('tessera_ended', '')"
    }
}

/// The advisory lock key of a job's assembly: the job id's bytes folded into 63 bits, in
/// a range apart from [`MAINTENANCE_KEY`]'s. Two jobs may share a key (then they are
/// assembled one after the other, which is only slower).
fn assembly_key(job: &str) -> i64 {
    // FNV-1a: stable across processes and versions, unlike `std`'s hasher.
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in job.bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    (h >> 1) as i64
}

/// Held while this replica writes a job's PNG: no other replica writes it meanwhile.
/// Dropping it closes its connection, which releases the lock.
#[derive(Debug)]
pub struct AssemblyLock {
    _conn: PgConnection,
}

impl PgStore {
    /// Wakes `work` and `ended` whenever any replica (this one included) says so, until
    /// `stop` turns true. A lost connection is opened again; both are woken then, since
    /// news may have been missed meanwhile.
    pub(crate) async fn listen(
        &self,
        work: Arc<Notify>,
        ended: Arc<Notify>,
        mut stop: watch::Receiver<bool>,
    ) {
        loop {
            let mut listener = match PgListener::connect_with(&self.pool).await {
                Ok(l) => l,
                Err(e) => {
                    tracing::warn!("listening for other replicas' news: {e}");
                    tokio::select! {
                        _ = tokio::time::sleep(Duration::from_secs(1)) => continue,
                        _ = stop.wait_for(|s| *s) => return,
                    }
                }
            };
            if let Err(e) = listener.listen_all([WORK, ENDED]).await {
                tracing::warn!("listening for other replicas' news: {e}");
                tokio::select! {
                    _ = tokio::time::sleep(Duration::from_secs(1)) => continue,
                    _ = stop.wait_for(|s| *s) => return,
                }
            }
            // Listening again after a gap: whatever was said meanwhile was missed.
            work.notify_waiters();
            ended.notify_waiters();
            loop {
                tokio::select! {
                    got = listener.try_recv() => match got {
                        Ok(Some(n)) if n.channel() == WORK => work.notify_waiters(),
                        Ok(Some(_)) => ended.notify_waiters(),
                        // The connection was lost: open another.
                        Ok(None) | Err(_) => break,
                    },
                    _ = stop.wait_for(|s| *s) => return,
                }
            }
        }
    }

    /// Whether this replica holds the maintenance lock now, taking it if no replica does.
    /// Checked on every pass: a lock whose connection died is gone, and then any replica
    /// may take it.
    pub(crate) async fn maintains(&self) -> bool {
        let mut slot = self.leader.lock().await;
        if let Some((conn, held)) = slot.as_mut() {
            let still = if *held {
                conn.ping().await.map(|()| true)
            } else {
                try_lock(conn, MAINTENANCE_KEY).await
            };
            match still {
                Ok(now) => {
                    if now && !*held {
                        tracing::info!("this replica runs the farm's maintenance (reaping)");
                    }
                    *held = now;
                    return now;
                }
                // The connection is gone, and with it any lock it held.
                Err(_) => *slot = None,
            }
        }
        let Ok(mut conn) = PgConnection::connect_with(&self.opts).await else {
            return false;
        };
        let held = try_lock(&mut conn, MAINTENANCE_KEY).await.unwrap_or(false);
        if held {
            tracing::info!("this replica runs the farm's maintenance (reaping)");
        }
        *slot = Some((conn, held));
        held
    }

    /// The lock on job `id`'s assembly, or `None` while another replica (or another task
    /// of this one) holds it.
    pub(crate) async fn assembling(&self, id: &str) -> Result<Option<AssemblyLock>> {
        let mut conn = PgConnection::connect_with(&self.opts).await?;
        let got = try_lock(&mut conn, assembly_key(id)).await?;
        Ok(got.then_some(AssemblyLock { _conn: conn }))
    }
}

/// Takes the advisory lock `key` on `conn` if no other connection holds it.
async fn try_lock(conn: &mut PgConnection, key: i64) -> std::result::Result<bool, sqlx::Error> {
    sqlx::query_scalar("SELECT pg_try_advisory_lock($1)")
        .bind(key)
        .fetch_one(conn)
        .await
}
