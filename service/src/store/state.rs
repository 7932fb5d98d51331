//! The states of jobs and tiles, and their text in the database and in JSON: the one place
//! that text is written.
//!
//! Rust code matches on [`JobState`] and [`TileState`]; SQL takes the same text from the
//! `job_sql!` and `tile_sql!` macros (string literals, so that `concat!` builds statements
//! that are still `&'static str` and stay in sqlx's cache of prepared statements). The
//! enums' [`JobState::as_str`] is written with those macros too, so the two cannot
//! disagree; the tests check that every state round-trips and that the schema's `CHECK`
//! constraints accept exactly these. The migrations keep their own literals: they are
//! history that SQLite checksums, and the tests hold them to these enums.
//!
//! What this is not: the rules of which state follows which. Those live in the statements
//! of the backends, guarded by the states they read.

use std::fmt;

/// The text of a job state as a quoted SQL literal: `job_sql!(Queued)` is `"'queued'"`;
/// `job_sql!(active)` is the parenthesized list of the active states, for `IN`.
macro_rules! job_sql {
    (Queued) => {
        "'queued'"
    };
    (Running) => {
        "'running'"
    };
    (Done) => {
        "'done'"
    };
    (Failed) => {
        "'failed'"
    };
    (Cancelled) => {
        "'cancelled'"
    };
    // The partial index `jobs_to_claim` (migration 0009) is chosen only for a query whose
    // `WHERE` has this very term, so it is spelled as the migration spells it.
    (active) => {
        "('queued', 'running')"
    };
}

/// The text of a tile state as a quoted SQL literal: `tile_sql!(Leased)` is `"'leased'"`.
macro_rules! tile_sql {
    (Queued) => {
        "'queued'"
    };
    (Leased) => {
        "'leased'"
    };
    (Done) => {
        "'done'"
    };
}

pub(crate) use {job_sql, tile_sql};

/// A quoted SQL literal without its quotes (for [`JobState::as_str`], from the same macro).
const fn unquoted(quoted: &'static str) -> &'static str {
    let bytes = quoted.as_bytes();
    let (_, rest) = bytes.split_at(1);
    let (inner, _) = rest.split_at(rest.len() - 1);
    match std::str::from_utf8(inner) {
        Ok(s) => s,
        // The macros' literals are ASCII: stripping one byte at each end keeps them UTF-8.
        Err(_) => panic!("a state literal is ASCII"),
    }
}

/// Where a job is in its life. Serialized as its lowercase name, the text of the
/// database's `jobs.state`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(into = "&'static str")]
pub enum JobState {
    /// Stored; no tile handed out yet.
    Queued,
    /// A tile has been handed out.
    Running,
    /// Every tile is in and the image is stored.
    Done,
    /// Ended without an image: a tile ran out of attempts, no worker may take it, or the
    /// image could not be assembled (`jobs.error` says which).
    Failed,
    /// Ended without an image at a user's request.
    Cancelled,
}

impl JobState {
    /// Every state, in the order of the schema's `CHECK`.
    pub const ALL: [JobState; 5] = [
        JobState::Queued,
        JobState::Running,
        JobState::Done,
        JobState::Failed,
        JobState::Cancelled,
    ];

    /// The state's text in the database and in JSON.
    pub const fn as_str(self) -> &'static str {
        match self {
            JobState::Queued => unquoted(job_sql!(Queued)),
            JobState::Running => unquoted(job_sql!(Running)),
            JobState::Done => unquoted(job_sql!(Done)),
            JobState::Failed => unquoted(job_sql!(Failed)),
            JobState::Cancelled => unquoted(job_sql!(Cancelled)),
        }
    }

    /// The state whose text is `s`, if any.
    pub fn parse(s: &str) -> Option<JobState> {
        JobState::ALL.into_iter().find(|j| j.as_str() == s)
    }

    /// Queued or running: tiles are handed out and results taken.
    pub const fn is_active(self) -> bool {
        matches!(self, JobState::Queued | JobState::Running)
    }
}

/// Where a tile is: waiting, out under a lease, or stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(into = "&'static str")]
pub enum TileState {
    /// Waiting to be handed out.
    Queued,
    /// Handed out under a lease.
    Leased,
    /// Its pixels are stored.
    Done,
}

impl TileState {
    /// Every state, in the order of the schema's `CHECK`.
    pub const ALL: [TileState; 3] = [TileState::Queued, TileState::Leased, TileState::Done];

    /// The state's text in the database.
    pub const fn as_str(self) -> &'static str {
        match self {
            TileState::Queued => unquoted(tile_sql!(Queued)),
            TileState::Leased => unquoted(tile_sql!(Leased)),
            TileState::Done => unquoted(tile_sql!(Done)),
        }
    }

    /// The state whose text is `s`, if any.
    pub fn parse(s: &str) -> Option<TileState> {
        TileState::ALL.into_iter().find(|t| t.as_str() == s)
    }
}

/// A state's text that names no state (a database written by something else).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("`{0}` is not a state")]
pub struct UnknownState(pub String);

impl TryFrom<String> for JobState {
    type Error = UnknownState;
    fn try_from(s: String) -> Result<JobState, UnknownState> {
        JobState::parse(&s).ok_or(UnknownState(s))
    }
}

impl TryFrom<String> for TileState {
    type Error = UnknownState;
    fn try_from(s: String) -> Result<TileState, UnknownState> {
        TileState::parse(&s).ok_or(UnknownState(s))
    }
}

impl From<JobState> for &'static str {
    fn from(s: JobState) -> &'static str {
        s.as_str()
    }
}

impl From<TileState> for &'static str {
    fn from(s: TileState) -> &'static str {
        s.as_str()
    }
}

impl From<JobState> for serde_json::Value {
    fn from(s: JobState) -> serde_json::Value {
        serde_json::Value::String(s.as_str().to_string())
    }
}

impl fmt::Display for JobState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl fmt::Display for TileState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A string schema whose values are `states`' texts: the document lists exactly the states
/// the code writes.
fn states_schema(
    states: impl IntoIterator<Item = &'static str>,
) -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
    use utoipa::openapi::schema::{ObjectBuilder, Type};
    ObjectBuilder::new()
        .schema_type(Type::String)
        .enum_values(Some(states))
        .into()
}

impl utoipa::PartialSchema for JobState {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        states_schema(JobState::ALL.map(JobState::as_str))
    }
}

impl utoipa::ToSchema for JobState {}

impl utoipa::PartialSchema for TileState {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        states_schema(TileState::ALL.map(TileState::as_str))
    }
}

impl utoipa::ToSchema for TileState {}
