//! A service that started on a disk with no room: it serves reads (the pages, jobs, images,
//! previews, workers, metrics) and refuses every write with `503` until the disk has room
//! again, so that a supervisor that restarts it brings back at least the reads.
//!
//! What is decided here: whether the service is read-only now and why, and what a refused
//! write is answered ([`ReadOnly`]). Not here: the middleware that refuses writes
//! (`routes`), nor finding out that the disk has room (the maintenance pass tries the
//! start's writes again, see `restart`).

use std::sync::{PoisonError, RwLock};

use axum::http::StatusCode;

use crate::error::ApiError;

/// How long a refused writer is told to wait before it asks again, in seconds: about two
/// maintenance passes, each of which looks for room.
const RETRY_AFTER_SECS: u32 = 5;

/// Why the service takes no writes now, while it has no room to write since it started.
#[derive(Debug, Default)]
pub struct ReadOnly(RwLock<Option<String>>);

impl ReadOnly {
    /// Why writes are refused; `None` when they are taken.
    pub fn why(&self) -> Option<String> {
        self.0
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }

    /// Refuses writes for `why`, or takes them again with `None`.
    pub fn set(&self, why: Option<String>) {
        *self.0.write().unwrap_or_else(PoisonError::into_inner) = why;
    }

    /// The answer to a write while read-only, or to the health check.
    pub fn refusal(why: &str) -> ApiError {
        ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            format!(
                "the service is read-only: it started without room to write ({why}); reads \
                 are served, and writes are taken again once the disk has room"
            ),
        )
        .retry_after(RETRY_AFTER_SECS)
    }
}
