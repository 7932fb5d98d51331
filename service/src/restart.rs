//! Putting the store right after a start: the writes a start needs (requeuing what the last
//! run's local workers held, the leases' grace, the spool's sweep, the images left to
//! assemble), at the start and, for a service that started read-only for want of room,
//! again at every maintenance pass until they go through.
//!
//! What it is not: the refusal of writes while read-only (`routes`), nor its reason
//! (`read_only`).

use tracing::{info, warn};

use crate::now_ms;
use crate::state::AppState;
use crate::store::StoreError;

/// Puts the store right after a start, with the writes that needs: checks that the store
/// takes writes, requeues what the local workers of the last run held, gives the leases
/// held a short grace, sweeps the tile spool, and assembles the images whose tiles were all
/// in. Run at the start, and again by the maintenance pass while the service is read-only
/// (see [`take_writes`]).
pub(crate) async fn settle(state: &AppState) -> Result<(), StoreError> {
    let store = &state.store;
    store
        .probe_write(now_ms(), crate::handlers::page::HEALTH_WRITE_WITHIN)
        .await?;
    let requeued = store
        .forget_local_workers(state.local_prefix.as_deref())
        .await?;
    if requeued > 0 {
        info!(
            "{requeued} tiles held by the local workers of the service's previous run \
             requeued (they ended with it)"
        );
    }
    // After a restart, every lease held runs for a grace at most ([`restart_grace_ms`]): the
    // workers that rode through renew or post within it, and the leases of those that died
    // meanwhile are reaped at its end, not a full term later.
    let grace = restart_grace_ms(state.cfg.lease_ms);
    let extended = store.restart_leases(now_ms(), grace).await?;
    if extended > 0 {
        info!("{extended} leases from before the start run out in {grace} ms unless renewed");
    }
    match store.sweep_spool().await {
        Ok(0) => {}
        Ok(n) => info!("{n} spool files of finished or deleted jobs removed"),
        Err(e) => warn!("sweeping the tile spool: {e}"),
    }
    for job in store.unassembled().await? {
        info!(job = %job, "all tiles were in before the restart: assembling");
        state.spawn_assembly(job);
    }
    Ok(())
}

/// While the service is read-only, tries the start's writes again ([`settle`]): true once
/// they went through and the service takes writes again.
pub(crate) async fn take_writes(state: &AppState) -> bool {
    match settle(state).await {
        Ok(()) => {
            state.read_only.set(None);
            info!("the disk has room again: taking writes");
            state.work.notify_waiters();
            state.changes.any();
            true
        }
        Err(e) => {
            tracing::debug!("still no room to write: {e}");
            if e.is_storage() {
                state.read_only.set(Some(e.to_string()));
            }
            false
        }
    }
}

/// How long the leases held when a service starts run before they are reaped: half a lease,
/// since a worker that rode through the restart renews every third of one; at least 3 s,
/// since it retries the post of a rendered tile every 2 s at most; never past a lease.
pub(crate) fn restart_grace_ms(lease_ms: u64) -> u64 {
    (lease_ms / 2).max(3_000).min(lease_ms)
}
