//! The JSON bodies of the worker routes: what a worker sends and what the service answers.
//!
//! Not the tile blob (binary, see `tile.rs`), and not the routes or status codes, which
//! each side's HTTP code owns.

use serde::{Deserialize, Serialize};
use tessera_tracer::Rect;

/// `POST /worker/claim` body.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClaimRequest {
    /// The worker's self-chosen name (host and process), used for keep-away and `/workers`.
    pub worker: String,
    /// Its render threads, for `/workers` (none: not said).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub threads: Option<u32>,
    /// The rays it traced per second over its last few seconds, all threads together, for
    /// `/workers` (none: not measured yet).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rays_per_second: Option<f64>,
}

impl ClaimRequest {
    /// A claim by `worker` that says nothing of itself.
    pub fn by(worker: impl Into<String>) -> ClaimRequest {
        ClaimRequest {
            worker: worker.into(),
            threads: None,
            rays_per_second: None,
        }
    }
}

/// `POST /worker/bye` body: the worker stops cleanly (its tiles are given back), so
/// `/workers` shows it gone at once.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Bye {
    /// The worker's name, as in its claims.
    pub worker: String,
}

/// A tile handed to one worker under a lease (`200` answer to a claim; `204` means no work).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Claim {
    /// The job's id.
    pub job: String,
    /// The tile's index within its job.
    pub idx: u32,
    /// The tile's left edge, in image pixels.
    pub x: u32,
    /// The tile's top edge, in image pixels.
    pub y: u32,
    /// The tile's width, in pixels.
    pub w: u32,
    /// The tile's height, in pixels.
    pub h: u32,
    /// The lease token: renewals, results, failures and releases carry it, and are accepted
    /// only while it is the tile's current lease.
    pub lease: String,
    /// How long the lease lasts without renewal.
    pub lease_ms: u64,
}

impl Claim {
    /// The tile's rectangle of the image.
    pub fn rect(&self) -> Rect {
        Rect::new(self.x, self.y, self.w, self.h)
    }
}

/// `GET /worker/jobs/{id}`: what a worker needs to build a job's scene.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct JobSpec {
    /// The job's id.
    pub id: String,
    /// The scene's `.ray` text.
    pub scene: String,
    /// The job's override of the scene's sampler, by its scene-file name.
    pub sampler: Option<String>,
    /// The job's override of the scene's sample count (per axis, as in the scene file).
    pub samples: Option<u32>,
    /// The job's override of the scene's adaptive threshold.
    pub threshold: Option<f64>,
    /// Names of the job's assets, fetched from `GET /worker/jobs/{id}/assets/{name}`.
    pub assets: Vec<String>,
}

/// Answer to a renewal.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Renewed {
    /// How long the renewed lease lasts without another renewal.
    pub lease_ms: u64,
}

/// Answer to a posted tile.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Accepted {
    /// The tile is already in from this lease: the repeat changes nothing.
    pub repeat: bool,
    /// When the post asked for its worker's next tile (`?next=NAME`): that claim, as
    /// `POST /worker/claim` would have answered it without waiting. Absent when there is no
    /// work at this moment, or none is asked for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub next: Option<Claim>,
}

/// `POST /worker/jobs/{id}/tiles/{idx}/fail` body.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FailRequest {
    /// The name of the worker that could not render the tile.
    pub worker: String,
    /// Why, in words, for the job's failure record.
    pub reason: String,
}
