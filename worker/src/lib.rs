//! The Tessera render worker: a stateless loop that claims tiles from a service over HTTP
//! (one, or several replicas of one farm), traces them with the tracer crate and posts
//! their pixels back.
//!
//! A worker holds nothing the service cannot lose: its only state is a small cache of parsed
//! scenes. It runs one claim-render-post loop per thread ("slot"), backs off with jitter when
//! there is no work or the service is unreachable, renews its lease while a tile renders, and
//! on shutdown finishes the tiles it holds (or, past a grace period, gives them back).
//!
//! It knows nothing of SQL or axum; the service runs the same loop in-process for its
//! `--local-workers`, over the same HTTP protocol (`tessera-protocol`).
//!
//! The modules, each using only those listed after it:
//! - `cli`: the `tessera-worker` program ([`main`], [`shutdown_signal`]).
//! - `worker`: one worker, its slots started and summed up ([`run`], [`run_with`]).
//! - `slot`: a slot's claim-render-post loop.
//! - `pipeline`, `post`, `lease`, `shutdown`: what a slot has in flight, posting, leases,
//!   the graceful stop.
//! - `ticket`, `shared`, `cache`, `config`: a queued tile, a worker's shared state, built
//!   scenes ([`SceneCache`]), settings ([`WorkerConfig`]).
//! - `servers`, `health`: the worker's servers, requests that move to another when one
//!   does not answer, and which answer.
//! - `client`, `pool`, `backoff`: the HTTP client of one server, the render threads
//!   ([`RenderPool`]), jittered back-off.

#![warn(missing_docs)]

mod backoff;
mod cache;
mod cli;
mod client;
mod config;
mod health;
mod lease;
mod meter;
mod pipeline;
mod pool;
mod post;
mod servers;
mod shared;
mod shutdown;
mod slot;
mod ticket;
mod worker;

pub use cache::SceneCache;
pub use cli::{main, shutdown_signal};
pub use client::{ClientError, MAX_RETRY_AFTER};
pub use config::{WorkerConfig, default_name};
pub use pool::{RenderPool, STRIP_PIXELS};
pub use worker::{Summary, WorkerError, run, run_with};
