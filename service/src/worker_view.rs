//! The workers as the API shows them ([`WorkerView`]): what the roster knows of each, with
//! what it does now (the tiles it holds) and whether it is still there. The JSON of
//! `GET /workers`, and the workers-by-state gauge of the metrics.
//!
//! A worker's state is decided here, from facts the store keeps: its leases that run past
//! now, its goodbye, and when it was last heard from.

use std::collections::HashMap;

use serde::Serialize;
use utoipa::ToSchema;

use crate::config::MAX_CLAIM_WAIT_MS;
use crate::state::AppState;
use crate::store::{HeldTile, StoreError, WorkerSeen};

/// How far back the list reaches: workers heard from in the last ten minutes.
pub const LISTED_FOR_MS: i64 = 600_000;

/// The least silence after which a worker without a lease counts as gone: longer than a
/// claim's longest wait at the service and an idle worker's default pause after it, so
/// that a live idle worker is never shown gone between its claims.
const LEAST_SILENCE_MS: u64 = MAX_CLAIM_WAIT_MS + 2_000;

/// What a worker is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum WorkerState {
    /// It holds a lease that runs past now.
    Rendering,
    /// It holds no lease and was heard from lately.
    Idle,
    /// It said goodbye, or has been silent longer than a lease (at least 12 s) with no
    /// lease left: its leases lapsed.
    Gone,
}

impl WorkerState {
    /// Every state, in the order the metrics list them.
    pub const ALL: [WorkerState; 3] =
        [WorkerState::Rendering, WorkerState::Idle, WorkerState::Gone];

    /// The state's word, as in the JSON.
    pub const fn as_str(self) -> &'static str {
        match self {
            WorkerState::Rendering => "rendering",
            WorkerState::Idle => "idle",
            WorkerState::Gone => "gone",
        }
    }
}

/// A tile a worker holds.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, ToSchema)]
pub struct HeldView {
    /// The tile's job.
    pub job: String,
    /// The tile's index within its job.
    pub idx: u32,
    /// Whether the worker said it is rendering it; otherwise it holds it ahead of its turn.
    pub rendering: bool,
}

/// A worker heard from in the last ten minutes.
#[derive(Debug, Clone, PartialEq, Serialize, ToSchema)]
pub struct WorkerView {
    /// The name it gives.
    pub name: String,
    /// What it is doing.
    pub state: WorkerState,
    /// It said goodbye: it stopped cleanly, giving back what it held.
    pub left_cleanly: bool,
    /// The tiles it holds now, by job and index.
    pub tiles: Vec<HeldView>,
    /// Its render threads, as it said (null: never said).
    pub threads: Option<u32>,
    /// The rays it traced per second lately, all threads together, as it said (null:
    /// never said).
    pub rays_per_second: Option<f64>,
    /// When it was last heard from (ms since the Unix epoch).
    pub last_seen: i64,
    /// Tiles it claimed.
    pub claims: u64,
    /// Of those claims, the ones that came back with a posted result.
    pub claims_with_results: u64,
    /// Tiles it rendered that were stored.
    pub tiles_done: u64,
}

/// The state of worker `w`, holding `held` tiles at `now`, with leases of `lease_ms`.
pub fn state_of(w: &WorkerSeen, held: usize, now: i64, lease_ms: u64) -> WorkerState {
    let silence = i64::try_from(lease_ms.max(LEAST_SILENCE_MS)).unwrap_or(i64::MAX);
    if held > 0 {
        WorkerState::Rendering
    } else if w.has_left() || now.saturating_sub(w.last_seen) > silence {
        WorkerState::Gone
    } else {
        WorkerState::Idle
    }
}

/// The workers heard from in the ten minutes before `now`, by name, with their state.
pub async fn roster(state: &AppState, now: i64) -> Result<Vec<WorkerView>, StoreError> {
    let seen = state.store.workers(now - LISTED_FOR_MS).await?;
    let mut held: HashMap<String, Vec<HeldView>> = HashMap::new();
    for HeldTile {
        worker,
        job,
        idx,
        rendering,
    } in state.store.held(now).await?
    {
        held.entry(worker).or_default().push(HeldView {
            job,
            idx,
            rendering,
        });
    }
    Ok(seen
        .into_iter()
        .map(|w| {
            let tiles = held.remove(&w.name).unwrap_or_default();
            WorkerView {
                state: state_of(&w, tiles.len(), now, state.cfg.lease_ms),
                left_cleanly: w.has_left(),
                tiles,
                threads: w.threads,
                rays_per_second: w.rays_per_second,
                last_seen: w.last_seen,
                claims: w.claims,
                claims_with_results: w.claims_with_results,
                tiles_done: w.tiles_done,
                name: w.name,
            }
        })
        .collect())
}

/// How many of `workers` are in each state, every state listed.
pub fn by_state(workers: &[WorkerView]) -> Vec<(&'static str, u64)> {
    WorkerState::ALL
        .into_iter()
        .map(|s| {
            let n = workers.iter().filter(|w| w.state == s).count();
            (s.as_str(), n as u64)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seen(last_seen: i64, left_at: i64) -> WorkerSeen {
        WorkerSeen {
            name: "w".into(),
            last_seen,
            left_at,
            ..WorkerSeen::default()
        }
    }

    #[test]
    fn a_lease_means_rendering_a_goodbye_or_a_long_silence_gone() {
        let lease = 30_000;
        let now = 1_000_000;
        // Heard from a moment ago, holding nothing: idle.
        assert_eq!(
            state_of(&seen(now - 500, 0), 0, now, lease),
            WorkerState::Idle
        );
        // Holding a lease that runs past now: rendering, however long silent.
        assert_eq!(
            state_of(&seen(now - 29_000, 0), 1, now, lease),
            WorkerState::Rendering
        );
        // Said goodbye and not heard since: gone at once.
        assert_eq!(
            state_of(&seen(now - 10, now - 10), 0, now, lease),
            WorkerState::Gone
        );
        // Heard from again after its goodbye: back.
        assert_eq!(
            state_of(&seen(now - 5, now - 10), 0, now, lease),
            WorkerState::Idle
        );
        // Silent for just over a lease, nothing held (its leases lapsed): gone.
        assert_eq!(
            state_of(&seen(now - lease as i64 - 1, 0), 0, now, lease),
            WorkerState::Gone
        );
        assert_eq!(
            state_of(&seen(now - lease as i64, 0), 0, now, lease),
            WorkerState::Idle
        );
    }

    #[test]
    fn a_short_lease_does_not_call_an_idle_worker_between_claims_gone() {
        let now = 1_000_000;
        // A claim may wait 10 s at the service: an idle worker is silent that long.
        let waited = now - MAX_CLAIM_WAIT_MS as i64 - 1_000;
        assert_eq!(state_of(&seen(waited, 0), 0, now, 500), WorkerState::Idle);
        let lapsed = now - LEAST_SILENCE_MS as i64 - 1;
        assert_eq!(state_of(&seen(lapsed, 0), 0, now, 500), WorkerState::Gone);
    }
}
