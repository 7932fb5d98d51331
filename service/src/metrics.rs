//! The service's Prometheus metrics (`GET /metrics`): what each name means, where it is
//! counted, and the scrape that reads the farm's numbers from the store.
//!
//! Counters and histograms are this process's own, counted where things happen (a claim,
//! a stored result, a reaped lease, a request): with several replicas on one database,
//! Prometheus sums them across replicas. Gauges (jobs by state, tiles waiting, workers by
//! state) are read from the database at each scrape, so every replica reports the whole
//! farm's: take one replica's, or the maximum, never the sum.
//!
//! What this is not: the HTTP handlers that call these, or an exporter with its own port.
//! The recorder is the process's one global `metrics` recorder, installed on first use.

use std::sync::OnceLock;
use std::time::Duration;

use axum::extract::{MatchedPath, Request};
use axum::middleware::Next;
use axum::response::Response;
use metrics::{Unit, counter, describe_counter, describe_gauge, describe_histogram, gauge};
use metrics_exporter_prometheus::{Matcher, PrometheusBuilder, PrometheusHandle};
use tracing::warn;

use crate::store::{FarmCounts, JobState};

/// Tiles handed to workers (claims answered with a tile, also those riding on a result).
pub const TILES_CLAIMED: &str = "tessera_tiles_claimed_total";
/// Tiles whose pixels were stored.
pub const TILES_STORED: &str = "tessera_tiles_stored_total";
/// Tiles a worker reported it could not render.
pub const TILES_FAILED: &str = "tessera_tiles_failed_total";
/// Leases that ran out and were taken back by the reaper.
pub const TILES_REAPED: &str = "tessera_tiles_reaped_total";
/// Rays traced for the stored tiles, as their workers counted them.
pub const RAYS_TRACED: &str = "tessera_rays_traced_total";
/// Jobs accepted.
pub const JOBS_SUBMITTED: &str = "tessera_jobs_submitted_total";
/// Failed or cancelled jobs made active again (`POST /jobs/{id}/retry`).
pub const JOBS_RETRIED: &str = "tessera_jobs_retried_total";
/// How long a claim answered with a tile waited at the service for one.
pub const CLAIM_WAIT: &str = "tessera_claim_wait_seconds";
/// The render-thread time a stored tile took, as its worker measured it.
pub const TILE_RENDER: &str = "tessera_tile_render_seconds";
/// Requests answered, by route, method and status.
pub const HTTP_REQUESTS: &str = "tessera_http_requests_total";
/// Jobs in each state (a gauge, read at the scrape).
pub const JOBS: &str = "tessera_jobs";
/// Tiles of active jobs waiting for a worker (a gauge).
pub const TILES_QUEUED: &str = "tessera_tiles_queued";
/// Tiles of active jobs under a lease (a gauge).
pub const TILES_LEASED: &str = "tessera_tiles_leased";
/// Workers heard from in the last ten minutes, by state (a gauge).
pub const WORKERS: &str = "tessera_workers";

/// The bucket bounds of the claim wait, in seconds: from an answer at once to a claim's
/// longest wait (10 s).
const CLAIM_WAIT_BUCKETS: [f64; 10] = [0.001, 0.005, 0.01, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 10.0];

/// The bucket bounds of a tile's render time, in seconds: tiles take from milliseconds
/// (one ray a pixel, small) to minutes (thousands of samples a pixel).
const TILE_RENDER_BUCKETS: [f64; 12] = [
    0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 10.0, 30.0, 120.0,
];

/// The process's recorder, installed on first use; `None` if another recorder was there
/// first (the metrics then read empty, and the service goes on).
fn handle() -> Option<&'static PrometheusHandle> {
    static HANDLE: OnceLock<Option<PrometheusHandle>> = OnceLock::new();
    HANDLE
        .get_or_init(|| {
            let built = PrometheusBuilder::new()
                .set_buckets_for_metric(Matcher::Full(CLAIM_WAIT.into()), &CLAIM_WAIT_BUCKETS)
                .and_then(|b| {
                    b.set_buckets_for_metric(
                        Matcher::Full(TILE_RENDER.into()),
                        &TILE_RENDER_BUCKETS,
                    )
                })
                .and_then(PrometheusBuilder::install_recorder);
            match built {
                Ok(h) => {
                    describe();
                    Some(h)
                }
                Err(e) => {
                    warn!("the metrics recorder could not be installed: {e}");
                    None
                }
            }
        })
        .as_ref()
}

/// The `# HELP` and unit of every metric.
fn describe() {
    describe_counter!(TILES_CLAIMED, "Tiles handed to workers under a lease.");
    describe_counter!(TILES_STORED, "Tiles whose pixels were stored.");
    describe_counter!(TILES_FAILED, "Tiles a worker reported it could not render.");
    describe_counter!(
        TILES_REAPED,
        "Leases that ran out unrenewed and were taken back."
    );
    describe_counter!(
        RAYS_TRACED,
        "Rays traced for the stored tiles, as their workers counted them."
    );
    describe_counter!(JOBS_SUBMITTED, "Jobs accepted.");
    describe_counter!(
        JOBS_RETRIED,
        "Failed or cancelled jobs made active again by a retry."
    );
    describe_histogram!(
        CLAIM_WAIT,
        Unit::Seconds,
        "How long a claim answered with a tile waited for one."
    );
    describe_histogram!(
        TILE_RENDER,
        Unit::Seconds,
        "Render-thread time of a stored tile, as its worker measured it."
    );
    describe_counter!(
        HTTP_REQUESTS,
        "Requests answered, by route, method and status."
    );
    describe_gauge!(JOBS, "Jobs in each state.");
    describe_gauge!(
        TILES_QUEUED,
        "Tiles of queued and running jobs waiting for a worker."
    );
    describe_gauge!(
        TILES_LEASED,
        "Tiles of queued and running jobs under a lease."
    );
    describe_gauge!(
        WORKERS,
        "Workers heard from in the last ten minutes, by state."
    );
}

/// Installs the recorder (so that counts before the first scrape are kept) and drains the
/// histograms' pending samples every few seconds, so that they stay bounded between scrapes.
pub fn start(mut stop: tokio::sync::watch::Receiver<bool>) {
    let Some(h) = handle() else { return };
    tokio::spawn(async move {
        let mut every = tokio::time::interval(Duration::from_secs(5));
        loop {
            tokio::select! {
                _ = every.tick() => h.run_upkeep(),
                _ = stop.wait_for(|s| *s) => return,
            }
        }
    });
}

/// Counts `n` of `name` (a `_total` counter).
pub fn count(name: &'static str, n: u64) {
    if n > 0 {
        counter!(name).increment(n);
    }
}

/// Records `d` in the histogram `name`, in seconds.
pub fn observe(name: &'static str, d: Duration) {
    metrics::histogram!(name).record(d.as_secs_f64());
}

/// The Prometheus text of every metric, with the gauges set from `farm` and `workers` (the
/// count of workers in each state).
pub fn scrape(farm: &FarmCounts, workers: &[(&'static str, u64)]) -> String {
    let Some(h) = handle() else {
        return String::new();
    };
    for state in JobState::ALL {
        let n = farm
            .jobs
            .iter()
            .find(|(s, _)| *s == state)
            .map_or(0, |(_, n)| *n);
        gauge!(JOBS, "state" => state.as_str()).set(n as f64);
    }
    gauge!(TILES_QUEUED).set(farm.tiles_queued as f64);
    gauge!(TILES_LEASED).set(farm.tiles_leased as f64);
    for (state, n) in workers {
        gauge!(WORKERS, "state" => *state).set(*n as f64);
    }
    h.run_upkeep();
    h.render()
}

/// Counts each answered request by its route's pattern (`/jobs/{id}`, not the id: the
/// label's values stay few), method and status; requests that match no route count as
/// `unmatched`.
pub async fn count_requests(req: Request, next: Next) -> Response {
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map_or_else(|| "unmatched".to_string(), |p| p.as_str().to_string());
    let method = req.method().as_str().to_string();
    let response = next.run(req).await;
    let status = response.status().as_u16().to_string();
    counter!(HTTP_REQUESTS, "route" => route, "method" => method, "status" => status).increment(1);
    response
}
