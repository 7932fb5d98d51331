//! One slot's claim-render-post loop: a slot claims a tile, has it rendered on the render
//! threads while it renews the lease and claims the next, posts the pixels, and repeats,
//! backing off when there is no work or no server can be reached.
//!
//! A worker runs one slot per thread (`worker.rs`). The pieces a slot uses live below it:
//! the in-flight bookkeeping (`pipeline.rs`), leases (`lease.rs`), posts (`post.rs`), the
//! stop (`shutdown.rs`), the scenes (`cache.rs`) and the servers (`servers.rs`), which
//! wait out a server that does not answer.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use bytes::Bytes;
use tessera_protocol::encode_tile;
use tokio::sync::{oneshot, watch};
use tracing::{debug, info, warn};

use crate::backoff::{backoff, seed};
use crate::cache::Unusable;
use crate::client::{ClientError, Spent, ignore_transient};
use crate::lease::{self, Held, give_back, renew_every};
use crate::pipeline::{ClaimTask, Pipeline};
use crate::pool::RenderPool;
use crate::post::post;
use crate::servers::Claimed;
use crate::shared::Shared;
use crate::shutdown::pause;
use crate::ticket::Ticket;

/// Runs slot `index` of a worker until the stop, or a refusal that retrying cannot fix;
/// then finishes its posts and gives back what it claimed ahead.
pub(crate) async fn slot(
    shared: Arc<Shared>,
    renderer: RenderPool,
    index: usize,
    mut stop: watch::Receiver<bool>,
) -> Result<(), ClientError> {
    let mut rng = seed().wrapping_add((index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)) | 1;
    let mut idle = 0u32;
    // Tiles given back in a row because their scene or textures could not be fetched: the
    // back-off grows with them, as with a failing service (a claim that succeeds between
    // them does not reset it, or the slot would claim and give back ten times a second).
    let mut unfetched = 0u32;
    let mut pipe = Pipeline::default();
    // Slots start at different servers, so that a worker's first claims are spread too.
    pipe.turn = index % shared.servers.len();
    let outcome = loop {
        if *stop.borrow() {
            break Ok(());
        }
        if std::mem::take(&mut pipe.unfetched) {
            unfetched = unfetched.saturating_add(1);
            let max = shared.cfg.idle_max.max(Duration::from_secs(2));
            if pause(backoff(unfetched, max, &mut rng), &mut stop).await {
                break Ok(());
            }
            continue;
        }
        if let Some(ticket) = pipe.queued.take() {
            unfetched = 0;
            if let Err(e) = work(&shared, &renderer, ticket, &mut stop, &mut pipe).await {
                break Err(e);
            }
            continue;
        }
        let claimed = if let Some(answer) = pipe.next.take() {
            answer
        } else if pipe.claim.is_some() {
            tokio::select! {
                a = pipe.claim_answer() => {
                    pipe.claim = None;
                    a
                }
                _ = stop.changed() => break Ok(()),
            }
        } else {
            let first = pipe.next_turn(shared.servers.len());
            let (req, wait) = (shared.claim_request(), shared.cfg.idle_max);
            tokio::select! {
                c = shared.servers.claim(first, &req, wait, stop.clone()) => c,
                _ = stop.changed() => break Ok(()),
            }
        };
        match claimed {
            Ok(Some(c)) => {
                idle = 0;
                let ticket = match submit(&shared, &renderer, c).await {
                    Ok(Submitted::Queued(t)) => t,
                    Ok(Submitted::Dropped) => continue,
                    Ok(Submitted::Unfetched) => {
                        pipe.unfetched = true;
                        continue;
                    }
                    Err(e) => break Err(e),
                };
                if let Err(e) = work(&shared, &renderer, ticket, &mut stop, &mut pipe).await {
                    break Err(e);
                }
            }
            Ok(None) => {
                // The service already waited `idle_max` for work (or, a service that does
                // not wait, answered at once): a short jittered pause keeps idle workers
                // out of step.
                idle = idle.saturating_add(1);
                if pause(backoff(0, shared.cfg.idle_max, &mut rng), &mut stop).await {
                    break Ok(());
                }
            }
            // `Servers::claim` waits out servers that do not answer (and logs it), so an
            // error that waiting may mend does not come here; were one to, it is waited
            // out all the same rather than stopping the worker.
            Err(e) if e.is_transient() => {
                idle = idle.saturating_add(1);
                let max = shared.cfg.idle_max.max(Duration::from_secs(2));
                // At least as long as the service asked (a farm paused for a full disk).
                let wait = backoff(idle, max, &mut rng).max(e.retry_after().unwrap_or_default());
                if pause(wait, &mut stop).await {
                    break Ok(());
                }
            }
            Err(e) => break Err(e),
        }
    };
    let drained = drain(&shared, pipe).await;
    outcome.and(drained)
}

/// On the way out: the last posts are finished, and a tile claimed ahead (or still being
/// claimed) is given back at once rather than left to its lease.
async fn drain(shared: &Shared, mut pipe: Pipeline) -> Result<(), ClientError> {
    let posted = pipe.finish_posts().await;
    if let Some(ticket) = pipe.queued.take() {
        lease::release(shared, ticket).await?;
    }
    if let Some(mut task) = pipe.claim.take() {
        // The claim waits at most `idle_max` at the service; past that and a margin, the
        // answer is abandoned and the tile, if any, comes back when its lease runs out.
        let limit = shared.cfg.idle_max + Duration::from_secs(2);
        match tokio::time::timeout(limit, &mut task).await {
            Ok(Ok(answer)) => pipe.next = Some(answer),
            Ok(Err(e)) => warn!("claim task ended abnormally: {e}"),
            Err(_) => task.abort(),
        }
    }
    if let Some(Ok(Some(c))) = &pipe.next {
        give_back(shared, c).await?;
    }
    posted
}

/// What became of a claimed tile handed to [`submit`].
enum Submitted {
    /// In the render thread's queue.
    Queued(Ticket),
    /// Dealt with: its job is gone, or its scene does not build here (reported).
    Dropped,
    /// Its scene or a texture could not be fetched (the service failed to answer, or could
    /// not be reached): the tile is given back at once rather than held until its lease
    /// runs out, and the slot backs off as from a failing service, so that it does not take
    /// the job's every tile in turn.
    Unfetched,
}

/// Puts a claimed tile in the render thread's queue, with its scene (from the cache, or
/// fetched and built), or deals with a tile that cannot be rendered here.
async fn submit(
    shared: &Shared,
    renderer: &RenderPool,
    c: Claimed,
) -> Result<Submitted, ClientError> {
    if shared.cfg.noop() {
        return Ok(Submitted::Queued(renderer.submit(c, None, &shared.meter)));
    }
    match shared.cache.prepared(&shared.servers, c.from, &c.job).await {
        Ok(p) => Ok(Submitted::Queued(renderer.submit(
            c,
            Some(p),
            &shared.meter,
        ))),
        Err(Unusable::Gone) => Ok(Submitted::Dropped),
        Err(Unusable::Invalid(reason)) => {
            warn!(job = %c.job, "cannot build scene: {reason}");
            shared.failed.fetch_add(1, Ordering::Relaxed);
            shared
                .servers
                .fail(&c, &shared.cfg.name, &reason)
                .await
                .or_else(ignore_transient)?;
            Ok(Submitted::Dropped)
        }
        Err(Unusable::Client(e)) if !e.is_transient() => Err(e),
        Err(Unusable::Client(e)) => {
            // Not the tile's fault, nor the scene's: another worker may fetch it. If the
            // give-back cannot reach the service either, the lease runs out.
            warn!(job = %c.job, "cannot fetch scene: {e}; giving the tile back");
            give_back(shared, &c).await?;
            Ok(Submitted::Unfetched)
        }
    }
}

/// Waits for a queued tile's render, renewing its lease (and that of the tile queued after
/// it) meanwhile, then starts posting it. The next claim is asked for as this wait begins,
/// and put in the render thread's queue as soon as it is answered.
async fn work(
    shared: &Arc<Shared>,
    renderer: &RenderPool,
    mut t: Ticket,
    stop: &mut watch::Receiver<bool>,
    pipe: &mut Pipeline,
) -> Result<(), ClientError> {
    let servers = &shared.servers;
    // A no-op tile is "rendered" already: its next claim rides on its post instead.
    if !shared.cfg.noop()
        && pipe.claim.is_none()
        && pipe.next.is_none()
        && pipe.queued.is_none()
        && !*stop.borrow()
    {
        let first = pipe.next_turn(servers.len());
        pipe.claim = Some(spawn_claim(shared, None, stop.clone(), first));
    }

    let c = t.claim.clone();
    let renew_every = renew_every(&c);
    let mut ticker =
        tokio::time::interval_at(tokio::time::Instant::now() + renew_every, renew_every);
    let mut deadline: Option<tokio::time::Instant> = None;
    let started = Instant::now();
    let rendered = loop {
        let give_up = async {
            match deadline {
                Some(d) => tokio::time::sleep_until(d).await,
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            r = &mut t.rendered => break r,
            answer = pipe.claim_answer() => {
                pipe.claim = None;
                match answer {
                    Ok(Some(next)) if !*stop.borrow() => {
                        match submit(shared, renderer, next).await? {
                            Submitted::Queued(t) => pipe.queued = Some(t),
                            Submitted::Dropped => {}
                            Submitted::Unfetched => pipe.unfetched = true,
                        }
                    }
                    other => pipe.next = Some(other),
                }
            }
            _ = ticker.tick() => {
                if let Held::Lost = lease::renew(servers, &t, &mut pipe.queued).await? {
                    return Ok(());
                }
            }
            changed = stop.changed(), if deadline.is_none() => {
                if changed.is_err() || *stop.borrow() {
                    deadline = Some(tokio::time::Instant::now() + shared.cfg.grace);
                    // The tile queued next will not be rendered here: others may take it now.
                    if let Some(queued) = pipe.queued.take() {
                        lease::release(shared, queued).await?;
                    }
                }
            }
            _ = give_up => {
                info!(job = %c.job, tile = c.idx, "shutting down: giving the tile back");
                return lease::release(shared, t).await;
            }
        }
    };
    let rgb = match rendered {
        Ok(Ok(rgb)) => rgb,
        failed => {
            let reason = match failed {
                Ok(Err(reason)) => reason,
                _ => "the render thread is gone".to_string(),
            };
            warn!(job = %c.job, tile = c.idx, "{reason}");
            shared.failed.fetch_add(1, Ordering::Relaxed);
            return servers
                .fail(&c, &shared.cfg.name, &reason)
                .await
                .or_else(ignore_transient);
        }
    };
    debug!(job = %c.job, tile = c.idx, ms = started.elapsed().as_millis() as u64, "rendered");
    // `Bytes`: every attempt at posting (see `post`) sends this buffer, not a copy of it.
    let blob = Bytes::from(encode_tile(c.rect(), &rgb));
    // Unless a claim is already under way or answered, this post also asks for the slot's
    // next tile: one round trip instead of two. The tile after the one now queued is thus
    // asked for as soon as this one is rendered, as it would be by a separate claim. Only
    // when the slot's next claim is this server's turn, though: a post carrying every claim
    // would keep a slot on the server its first tile came from.
    let ride = if pipe.claim.is_none()
        && pipe.next.is_none()
        && !*stop.borrow()
        && pipe.turn % servers.len() == c.from
    {
        let (tx, rx) = oneshot::channel();
        let first = pipe.next_turn(servers.len());
        pipe.claim = Some(spawn_claim(shared, Some(rx), stop.clone(), first));
        Some(tx)
    } else {
        None
    };
    let spent = Spent {
        rays: t.cost.rays(),
        render_ms: t.cost.millis(),
    };
    pipe.start_post(tokio::spawn(post(
        shared.clone(),
        c,
        blob,
        spent,
        ride,
        stop.clone(),
    )))
    .await
}

/// A claim for the slot's next tile, as its own task: the one a post brings back (`ride`),
/// or else an ordinary claim of server `first` (or the next that answers), which waits up
/// to `idle_max` at the service for work. Nothing is claimed once the worker is stopping.
fn spawn_claim(
    shared: &Arc<Shared>,
    ride: Option<oneshot::Receiver<Option<Claimed>>>,
    stop: watch::Receiver<bool>,
    first: usize,
) -> ClaimTask {
    let shared = shared.clone();
    tokio::spawn(async move {
        if let Some(ride) = ride
            && let Ok(Some(c)) = ride.await
        {
            return Ok(Some(c));
        }
        let (req, wait) = (shared.claim_request(), shared.cfg.idle_max);
        shared.servers.claim(first, &req, wait, stop).await
    })
}
