//! A slot's leases: renewing them while tiles render or wait in line, and giving tiles back.
//!
//! Not when to give a tile back (the slot, the stop and a scene that cannot be fetched
//! decide), nor the HTTP of it (`client.rs`).

use std::sync::atomic::Ordering;
use std::time::Duration;

use tessera_protocol::Claim;
use tracing::{debug, warn};

use crate::client::{ClientError, ignore_transient};
use crate::servers::{Claimed, Servers};
use crate::shared::Shared;
use crate::ticket::Ticket;

/// The longest a give-back (always while stopping) waits for the service's answer.
const GIVE_BACK_WAIT: Duration = Duration::from_secs(2);

/// How often a tile's lease is renewed: three times a lease, so that one renewal that does
/// not get through leaves time for the next.
pub(crate) fn renew_every(c: &Claim) -> Duration {
    Duration::from_millis((c.lease_ms / 3).max(10))
}

/// Whether the tile being rendered is still this worker's after a renewal.
pub(crate) enum Held {
    /// Renewed, or no server could be reached (a service extends leases when it restarts).
    Yes,
    /// The lease is lost: the tile is cancelled, and is someone else's business now.
    Lost,
}

/// Renews the lease of the tile being rendered (`t`) and of the tile queued after it, if
/// any, each at the server that handed it out or, when that one does not answer, another.
/// A queued tile whose lease is lost is cancelled and taken out of `queued`. A refusal that
/// retrying cannot fix is passed on.
pub(crate) async fn renew(
    servers: &Servers,
    t: &Ticket,
    queued: &mut Option<Ticket>,
) -> Result<Held, ClientError> {
    let c = &t.claim;
    match servers.renew(c, t.started.load(Ordering::Relaxed)).await {
        Ok(true) => {}
        Ok(false) => {
            debug!(job = %c.job, tile = c.idx, "lease lost; dropping the tile");
            t.cancel.store(true, Ordering::Relaxed);
            // The tile held ahead is most likely of the same (cancelled) job: ask now, not
            // a renewal period from now, before it starts rendering.
            if let Some(next) = queued.as_ref()
                && let Ok(false) = servers
                    .renew(&next.claim, next.started.load(Ordering::Relaxed))
                    .await
                && let Some(lost) = queued.take()
            {
                lost.cancel.store(true, Ordering::Relaxed);
            }
            return Ok(Held::Lost);
        }
        // Unreachable: keep rendering; the service extends leases when it restarts.
        Err(e) if e.is_transient() => debug!("renewal failed: {e}"),
        Err(e) => return Err(e),
    }
    if let Some(next) = queued.as_ref() {
        match servers
            .renew(&next.claim, next.started.load(Ordering::Relaxed))
            .await
        {
            Ok(true) => {}
            Ok(false) => {
                if let Some(lost) = queued.take() {
                    lost.cancel.store(true, Ordering::Relaxed);
                }
            }
            Err(e) if e.is_transient() => debug!("renewal failed: {e}"),
            Err(e) => return Err(e),
        }
    }
    Ok(Held::Yes)
}

/// Gives a queued tile back to the service: the render thread skips it if not yet started.
pub(crate) async fn release(shared: &Shared, t: Ticket) -> Result<(), ClientError> {
    t.cancel.store(true, Ordering::Relaxed);
    // Counted once the service has it back: a give-back that could not reach it is not one
    // (the tile returns when its lease runs out).
    give_back(shared, &t.claim).await
}

/// Gives a tile back, counting it in `released` only if the service took it back (not if
/// it is unreachable, or the lease is not this worker's any more).
pub(crate) async fn give_back(shared: &Shared, c: &Claimed) -> Result<(), ClientError> {
    // Given back while stopping: a service that does not answer (frozen) is not waited for
    // past `GIVE_BACK_WAIT`; the tile comes back when its lease runs out.
    let Ok(answer) = tokio::time::timeout(GIVE_BACK_WAIT, shared.servers.release(c)).await else {
        warn!(job = %c.job, tile = c.idx, "no answer to the give-back; the lease will run out");
        return Ok(());
    };
    match answer {
        Ok(taken) => {
            if taken {
                shared.released.fetch_add(1, Ordering::Relaxed);
            }
            Ok(())
        }
        Err(e) => ignore_transient(e),
    }
}
