//! End-to-end tests of the Tessera farm live in `tests/`; this crate's binaries are the
//! service and worker programs those tests start as separate processes, and [`pg`] the
//! throwaway PostgreSQL server that the tests' PostgreSQL variants run against.

pub mod pg;
