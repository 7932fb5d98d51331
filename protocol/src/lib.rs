//! The worker protocol of a Tessera farm: the JSON bodies and the tile blob format that the
//! service and its workers exchange over HTTP, and the checks both apply to a worker's name
//! and token. Both sides use these types, so they cannot drift apart.
//!
//! This crate is data only: no HTTP, no I/O, no queue. It depends on neither the service
//! nor the worker, so each can change its insides without the other. The routes that carry
//! these bodies are described in `docs/PROTOCOL.md`.
//!
//! It depends on `tessera-tracer` for one type, [`Rect`]: a tile blob's header is the
//! rectangle of the image it covers, which the worker renders and the service checks with
//! that very type. A copy of it here would need converting at both ends for no gain.
//! (A job's sampler travels as text, [`JobSpec::sampler`], parsed by the worker.)

#![warn(missing_docs)]

mod checks;
mod messages;
mod tile;

pub use checks::{MAX_WORKER_NAME, check_worker_name, token_problem};
pub use messages::{Accepted, Bye, Claim, ClaimRequest, FailRequest, JobSpec, Renewed};
pub use tessera_tracer::Rect;
pub use tile::{BlobError, TILE_HEADER_LEN, TILE_MAGIC, decode_tile, encode_tile, split_tile};
