//! The Tessera render service: the HTTP API users and workers talk to, the SQLite job queue
//! behind it, the web page, and optional in-process workers.
//!
//! Handlers are thin: they check what was sent and call the [`queue::Queue`], which holds
//! every guarantee about tiles and leases in SQL. Shared state is explicit ([`AppState`]);
//! errors become responses in one place ([`ApiError`]). The service does not trace
//! rays itself: local workers are ordinary `tessera_worker` loops speaking HTTP to it.
//!
//! # Where things are
//!
//! - `startup`: opening the queue, listening, the graceful stop; `reaper`: the periodic
//!   maintenance pass; `local_workers`: the in-process workers.
//! - `routes`: the router, its body limits and token checks; `handlers/`: one file per
//!   group of routes (`jobs`, `image`, `page`, `workers`); `params`: the user routes' query
//!   parameters.
//! - `upload`: reading a submission's body (metered by `receiving`) and multipart parts;
//!   `validate`: a submitted scene checked into the job to store; `names`: job and asset
//!   names; `tiling`: the tile size the service picks and the tile count it allows.
//! - `state`: the one handle every handler shares; `error`: the one error type and how it
//!   becomes a response; `auth`: bearer tokens; `config`, `cli`: flags and the program.
//! - `queue`, `spool`, `assemble`, `db_lock`, `idle`: storage and connections, below all of
//!   the above.
//!
//! The crate's modules are private; what the binary, the end-to-end tests and the bench need
//! is re-exported here.

#![warn(missing_docs)]

// The storage modules keep their own visibility and docs (they are public while their
// callers outside this crate, `tests/queue.rs` and the bench, name them by path).
#[allow(missing_docs)]
pub mod assemble;
mod auth;
mod cli;
mod clock;
mod config;
mod db_lock;
mod error;
mod handlers;
mod idle;
mod local_workers;
mod names;
mod params;
#[allow(missing_docs)]
pub mod queue;
mod reaper;
mod receiving;
mod rlimit;
mod routes;
#[allow(missing_docs)]
pub mod spool;
mod startup;
mod state;
mod tiling;
mod upload;
mod validate;

pub use cli::{main, main_from};
pub use config::Config;
pub use error::ApiError;
pub use handlers::jobs::{get_job, submit};
pub use handlers::workers::{ClaimParams, claim};
pub use params::JobParams;
pub use receiving::{Full, Held, Receiving};
pub use state::{AppState, WorkerSeen};
pub use tiling::protocol_limit;

pub(crate) use clock::now_ms;
