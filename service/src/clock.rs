//! The service's clock: milliseconds since the Unix epoch, the unit the queue stores times
//! in. Read here, at the edge, and passed into the queue's calls as an argument.

/// Milliseconds since the Unix epoch: the queue's clock.
pub fn now_ms() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as i64)
}
