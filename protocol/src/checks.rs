//! The checks that a worker's name and a bearer token pass on both sides: the service
//! refuses what fails them, and `tessera-worker` refuses them at start, so that a value the
//! service would refuse stops the worker with a message instead of failing every request.
//!
//! Not the service's own rules beyond these (it also refuses an empty token, which to a
//! worker means none).

/// The longest worker name, in bytes.
pub const MAX_WORKER_NAME: usize = 200;

/// A worker name as the service takes it: 1 to [`MAX_WORKER_NAME`] bytes, no control
/// characters. `tessera-worker` checks its `--name` by it at start, since a name the service
/// refuses would otherwise show only once the service answered, and be retried for ever
/// while it did not.
pub fn check_worker_name(name: &str) -> Result<(), String> {
    if name.is_empty() || name.len() > MAX_WORKER_NAME || name.chars().any(char::is_control) {
        return Err(format!(
            "a worker name is 1 to {MAX_WORKER_NAME} bytes of printable characters"
        ));
    }
    Ok(())
}

/// Why a bearer token cannot be sent as it is, if it cannot: white space at either end,
/// which HTTP trims from the header that carries it (the service would then refuse its own
/// token with 401, and `--token ' '` would lock every worker out), or a control character,
/// which no header may hold (every request would fail as though the service could not be reached).
/// Both programs check their tokens by it after clap has parsed them, since clap's own
/// refusal repeats the value; the service also refuses an empty one, which to a worker
/// means none.
pub fn token_problem(token: &str) -> Option<&'static str> {
    if token.trim() != token {
        Some("a token may not start or end with white space")
    } else if token.chars().any(char::is_control) {
        Some("a token may not hold control characters")
    } else {
        None
    }
}
