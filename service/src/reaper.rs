//! The periodic maintenance pass: requeues expired leases (extending them instead after a
//! pause of the service or while its storage fails), sweeps the tile spool, stops following
//! ended jobs, fails jobs that every live worker is kept away from, and (on a shared
//! database) assembles the images of complete jobs that no process is assembling.
//!
//! Every process shares what it noted ([`crate::store::Store::share`]) on each pass; on a
//! database several processes share, only the one holding the maintenance lock
//! ([`crate::store::Store::maintains`]) does the rest, so that no two reap at once.
//!
//! A service that started without room to write does none of it: each pass only tries the
//! start's writes again (`restart::take_writes`), until they go through.
//!
//! It decides nothing the queue does not: it calls the queue with the time and the
//! configuration's limits, and wakes waiting requests when something changed.

use std::time::Duration;

use tokio::sync::watch;
use tracing::{info, warn};

use crate::now_ms;
use crate::state::AppState;

/// The least time a refused request keeps its lease from being reaped while the storage
/// fails: a worker retries a refused result at most 3 s apart, whatever the lease.
const HEARD_AT_LEAST: Duration = Duration::from_secs(5);

/// How often the reaper deletes the spool files of ended jobs.
const SWEEP_EVERY: Duration = Duration::from_secs(10);

/// How often the maintaining process of a shared database looks for complete jobs whose
/// image nobody assembles (their assembler died, or the database failed under it).
const ASSEMBLE_EVERY: Duration = Duration::from_secs(2);

/// Requeues expired leases a few times per lease period, and sweeps the tile spool.
pub async fn reaper(state: AppState, mut stop: watch::Receiver<bool>) {
    let every = Duration::from_millis((state.cfg.lease_ms / 4).clamp(25, 1000));
    let mut last = std::time::Instant::now();
    let mut swept = std::time::Instant::now();
    let mut assembled = std::time::Instant::now();
    // Leases are being extended for the storage's failures (said once, not every pass).
    let mut extending = false;
    // Sharing failed last pass (said once, not every pass).
    let mut unshared = false;
    loop {
        tokio::select! {
            _ = tokio::time::sleep(every) => {}
            _ = stop.wait_for(|s| *s) => return,
        }
        // Started without room to write: nothing else is done until the start's writes go
        // through (leases are given their grace then, so none is reaped for the wait).
        if state.read_only.why().is_some() && !crate::restart::take_writes(&state).await {
            last = std::time::Instant::now();
            continue;
        }
        // A full disk keeps the farm paused for as long as it stays full.
        state
            .store
            .recheck_storage(now_ms(), crate::store::STORAGE_PAUSE);
        match state.store.share(now_ms()).await {
            Ok(()) if unshared => {
                unshared = false;
                info!("sharing this process's records through the database again");
            }
            Ok(()) => {}
            Err(e) if !unshared => {
                unshared = true;
                warn!(
                    "sharing this process's records: {}",
                    state.store.noted(e, now_ms())
                );
            }
            Err(e) => {
                state.store.noted(e, now_ms());
            }
        }
        // Jobs that ended without an image (cancelled, failed) are no longer followed.
        let followed = state.progress.followed();
        if !followed.is_empty() {
            match state.store.active_jobs().await {
                Ok(active) => followed
                    .iter()
                    .filter(|id| !active.contains(id))
                    .for_each(|id| state.progress.forget(id)),
                Err(e) => warn!("listing active jobs: {e}"),
            }
        }
        if !state.store.maintains().await {
            // Another process maintains the database; this one's pauses are its own.
            last = std::time::Instant::now();
            continue;
        }
        // A service that did not run for half a lease (suspended, frozen, its machine
        // asleep) could not take the renewals its workers sent meanwhile: their leases ran
        // out through no fault of theirs, and reaping them would count it against them (and,
        // with short leases, fail jobs). Give every lease a fresh term instead, as a restart
        // does.
        let paused = last.elapsed();
        last = std::time::Instant::now();
        // So with storage that failed within half a lease (a full disk): the renewals and
        // results of workers may have been refused meanwhile. Those refused are noted
        // (`Store::heard_refused`); a worker at work renews each lease every third of one,
        // and retries a refused result at most 3 s apart (its back-off's cap, with jitter),
        // so one heard from within a lease, and never less than 5 s, is alive.
        let window = Duration::from_millis(state.cfg.lease_ms / 2) + every;
        let heard_within = Duration::from_millis(state.cfg.lease_ms).max(HEARD_AT_LEAST) + every;
        // The pause first: it heard no one, so every lease is extended, whatever failed.
        if paused > window {
            match state
                .store
                .extend_leases(now_ms(), state.cfg.lease_ms)
                .await
            {
                Ok(n) => warn!(
                    "the service did not run for {:.1} s: {n} leases extended, none reaped",
                    paused.as_secs_f64()
                ),
                Err(e) => warn!(
                    "extending leases after a pause: {}",
                    state.store.noted(e, now_ms())
                ),
            }
            continue;
        }
        let reaped = if state.store.storage_failed_within(now_ms(), window) {
            // The leases of workers heard from are extended, the others reaped (the rest
            // of the pass goes on). Said once an episode.
            let pass = state
                .store
                .reap_unheard(
                    now_ms(),
                    state.cfg.lease_ms,
                    heard_within,
                    state.cfg.max_attempts,
                    state.keep_away(),
                )
                .await;
            if let Ok((extended, _)) = &pass
                && !extending
            {
                extending = true;
                warn!(
                    "the service's storage failed lately: the leases of workers whose requests \
                     it refused are extended, the others reaped as ever, until it has written \
                     again for half a lease ({extended} now)"
                );
            }
            pass.map(|(_, reaped)| reaped)
        } else {
            if extending {
                extending = false;
                info!("the service's storage writes again: expired leases are reaped again");
            }
            // `reap_unheard` forgets the leases refused too long ago; here, with nothing
            // refused lately, the record is only kept small.
            state.store.forget_unheard(now_ms(), heard_within);
            state
                .store
                .reap(now_ms(), state.cfg.max_attempts, state.keep_away())
                .await
        };
        match reaped {
            Ok(0) => {}
            Ok(n) => {
                warn!("{n} expired leases: tiles handed out again");
                crate::metrics::count(crate::metrics::TILES_REAPED, n);
                state.work.notify_waiters();
                // A tile out of attempts fails its job.
                state.ended.notify_waiters();
                state.changes.any();
            }
            Err(e) => warn!("reaping expired leases: {}", state.store.noted(e, now_ms())),
        }
        // The spool files of deleted jobs (and of finished ones a crash left behind).
        if swept.elapsed() >= SWEEP_EVERY {
            swept = std::time::Instant::now();
            if let Err(e) = state.store.sweep_spool().await {
                warn!("sweeping the tile spool: {e}");
            }
        }
        // Complete jobs whose assembler died or failed: assembled here (the store's
        // assembly lock skips those another process is still writing).
        if state.store.is_shared() && assembled.elapsed() >= ASSEMBLE_EVERY {
            assembled = std::time::Instant::now();
            match state.store.unassembled().await {
                Ok(jobs) => jobs.into_iter().for_each(|job| state.spawn_assembly(job)),
                Err(e) => warn!("listing complete jobs: {e}"),
            }
        }
        // Workers heard from within a lease period (plus slack for idle polling).
        let live_since = now_ms() - state.cfg.lease_ms as i64 - 5_000;
        let live = match state.store.live_workers(live_since).await {
            Ok(live) => live,
            Err(e) => {
                warn!("listing live workers: {e}");
                continue;
            }
        };
        match state.store.fail_unservable(&live, now_ms()).await {
            Ok(0) => {}
            Ok(n) => {
                warn!("{n} jobs failed: every live worker is kept away from them");
                state.ended.notify_waiters();
                state.changes.any();
            }
            Err(e) => warn!("checking kept-away jobs: {e}"),
        }
    }
}
