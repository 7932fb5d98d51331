//! Posting a rendered tile: retries while the service cannot be reached, the next claim
//! that the post may carry, and the grace period that bounds it all once the worker stops.
//!
//! Not the order in which posts are waited for (`pipeline.rs`), nor the HTTP (`client.rs`).

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use bytes::Bytes;
use tokio::sync::{oneshot, watch};
use tokio::task::JoinHandle;
use tracing::{debug, warn};

use crate::backoff::{backoff, seed};
use crate::client::{ClientError, Posted, Said, Spent};
use crate::servers::Claimed;
use crate::shared::Shared;
use crate::shutdown::grace_over;

/// A rendered tile on its way to the service.
pub(crate) type PostTask = JoinHandle<Result<(), ClientError>>;

/// The claim a post may carry: the post's answer, or nothing (the post fails, is refused,
/// or the service has no work at that moment).
pub(crate) type Ride = oneshot::Sender<Option<Claimed>>;

/// Posts a rendered tile, to the server that handed it out or, when that one does not
/// answer, another, riding through a service restart (it extends leases when it comes
/// back). With `ride`, the first attempt also asks for the slot's next tile and hands the
/// answer over; later attempts do not (the slot claims on its own then).
pub(crate) async fn post(
    shared: Arc<Shared>,
    c: Claimed,
    blob: Bytes,
    spent: Spent,
    ride: Option<Ride>,
    stop: watch::Receiver<bool>,
) -> Result<(), ClientError> {
    // A rendered tile is worth waiting for, but once the worker is stopping only for the
    // grace period: the service may be down, or frozen (it takes the request and never
    // answers), for longer than a service manager waits. Without this bound a stop would
    // wait four leases or the client's two-minute timeout, whatever `--grace-secs` says.
    tokio::select! {
        posted = post_retrying(&shared, &c, blob, spent, ride) => posted,
        () = grace_over(&shared, stop) => {
            warn!(job = %c.job, tile = c.idx, "stopping: the tile could not be posted in time; giving it up");
            Ok(())
        }
    }
}

/// Posts the tile, retrying with back-off for up to four leases while no server can be
/// reached.
async fn post_retrying(
    shared: &Shared,
    c: &Claimed,
    blob: Bytes,
    spent: Spent,
    mut ride: Option<Ride>,
) -> Result<(), ClientError> {
    let give_up_at = Instant::now() + Duration::from_millis(c.lease_ms.max(1000) * 4);
    let mut rng = seed();
    let mut streak = 0;
    loop {
        let next = ride.is_some().then_some(shared.cfg.name.as_str());
        let (threads, rays_per_second) = shared.said();
        let said = Said {
            spent,
            threads,
            rays_per_second,
        };
        let answer = shared.servers.post_tile(c, blob.clone(), next, &said).await;
        if let Some(tx) = ride.take() {
            let claim = match &answer {
                Ok((_, next)) => next.clone(),
                Err(_) => None,
            };
            // The claim task ends only after hearing from here, and the slot's `drain` waits
            // for it (to give back what it brought); the send fails only if that wait timed
            // out, and then the tile comes back when its lease runs out.
            let _ = tx.send(claim);
        }
        match answer {
            Ok((Posted::Accepted { .. }, _)) => {
                shared.tiles.fetch_add(1, Ordering::Relaxed);
                return Ok(());
            }
            Ok((Posted::Stale(why), _)) => {
                debug!(job = %c.job, tile = c.idx, "result refused: {why}");
                return Ok(());
            }
            Err(e) if e.is_transient() && Instant::now() < give_up_at => {
                streak += 1;
                let pause = backoff(streak, Duration::from_secs(2), &mut rng);
                debug!(job = %c.job, tile = c.idx, "posting failed ({e}); retrying in {pause:?}");
                tokio::time::sleep(pause).await;
            }
            Err(e) if e.is_transient() => {
                warn!(job = %c.job, tile = c.idx, "could not post the tile: {e}");
                return Ok(());
            }
            Err(e) => return Err(e),
        }
    }
}
