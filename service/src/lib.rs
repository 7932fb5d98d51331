//! The Tessera render service: the HTTP API users and workers talk to, the job store behind
//! it (SQLite), the web page, and optional in-process workers.
//!
//! Handlers are thin: they check what was sent and call the [`store::Store`], which holds
//! every guarantee about tiles and leases in SQL. Shared state is explicit ([`AppState`]);
//! errors become responses in one place ([`ApiError`]). The service does not trace
//! rays itself: local workers are ordinary `tessera_worker` loops speaking HTTP to it.
//!
//! # Where things are
//!
//! - `startup`: opening the store, listening, the graceful stop; `reaper`: the periodic
//!   maintenance pass; `local_workers`: the in-process workers.
//! - `routes`: the router, its body limits and token checks, and the OpenAPI document built
//!   with it; `handlers/`: one file per group of routes (`jobs`, `image`, `live`, `page`,
//!   `workers`); `params`: the user routes' query parameters, refused in words.
//! - `preview`: a job's image as far as it is rendered; `events`: a job's server-sent events,
//!   woken by `changes`; `job_view`: a job as every answer shows it.
//!   The web pages' files are in `service/web/`.
//! - `upload`: reading a submission's body (metered by `receiving`) and multipart parts;
//!   `validate`: a submitted scene checked into the job to store; `names`: job and asset
//!   names; `tiling`: the tile size the service picks and the tile count it allows.
//! - `state`: the one handle every handler shares; `error`: the one error type and how it
//!   becomes a response; `auth`: bearer tokens; `config`, `cli`: flags and the program.
//! - `store`: jobs, tiles, leases, results, images and workers behind one type, with the
//!   SQLite backend (and its tile spool) in `store/sqlite/`; `assemble`: encoding a job's PNG
//!   band by band from stored tiles; `db_lock`: one service per database file; `idle`:
//!   closing silent connections. All below the modules above.
//!
//! The crate's modules are private; what the binary, the end-to-end tests and the bench need
//! is re-exported here.

#![warn(missing_docs)]

// `assemble` and `store` are public: the store's own tests (`tests/store.rs`) and the farm
// bench drive them directly, without HTTP.
pub mod assemble;
mod auth;
mod changes;
mod cli;
mod clock;
mod config;
mod db_lock;
mod error;
mod events;
mod handlers;
mod idle;
mod job_view;
mod local_workers;
mod memory;
mod metrics;
mod names;
mod params;
mod preview;
mod read_only;
mod reaper;
mod receiving;
mod restart;
mod rlimit;
mod routes;
mod startup;
mod state;
pub mod store;
mod tiling;
mod upload;
mod validate;
mod worker_view;

pub use cli::{main, main_from};
pub use config::Config;
pub use error::{ApiError, ErrorBody};
pub use handlers::jobs::{get_job, submit};
pub use handlers::workers::{ClaimParams, claim};
pub use params::JobParams;
pub use receiving::{Full, Held, Receiving};
pub use state::AppState;
pub use store::WorkerSeen;
pub use tiling::protocol_limit;

pub(crate) use clock::now_ms;
