//! The query parameters of the user routes, and how a query that does not parse is
//! answered. Every route refuses parameters it does not take: a misspelt one would
//! otherwise be ignored without a word.

use serde::Deserialize;

use crate::tiling::{MAX_TILE, MIN_TILE};

/// `GET /jobs` query parameters: a page of at most `limit` jobs (default and most
/// [`MAX_JOBS_LISTED`]), those submitted before job `before` when given.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ListParams {
    pub limit: Option<u32>,
    pub before: Option<String>,
}

/// The most jobs one `GET /jobs` lists.
pub const MAX_JOBS_LISTED: u32 = 200;

/// `GET /jobs/{id}?wait=S`: with `wait`, the answer waits until the job has ended (done,
/// failed or cancelled) or `S` seconds (at most 60, and less than the idle timeout) have
/// passed, so a client learns of the end at once instead of polling.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JobParams {
    /// Seconds to wait for the job's end; none: answer at once.
    pub wait: Option<f64>,
}

/// The longest `GET /jobs/{id}?wait=` holds a request.
pub const MAX_JOB_WAIT_SECS: f64 = 60.0;

/// `DELETE /jobs/{id}` query parameters.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeleteParams {
    /// Remove an ended job and everything stored for it, instead of cancelling: `true` or
    /// `1` (`false`, `0` or absent: cancel).
    #[serde(default, deserialize_with = "flag")]
    pub purge: bool,
}

/// A query flag: `true`/`1` or `false`/`0`.
pub fn flag<'de, D: serde::Deserializer<'de>>(d: D) -> Result<bool, D::Error> {
    match String::deserialize(d)?.as_str() {
        "true" | "1" => Ok(true),
        "false" | "0" => Ok(false),
        other => Err(serde::de::Error::custom(format!(
            "`{other}` is not a flag: expected true, false, 1 or 0"
        ))),
    }
}

/// Query parameters of a route that takes none: one given is a mistake, refused as on the
/// routes that take some (`?x=1` on the image is refused, not ignored).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoParams {}

/// `POST /jobs` query parameters. Any other is refused, as a misspelt key in a scene is: a
/// misspelt `?tiles=8` or `?sample=4` would otherwise render with the defaults.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SubmitParams {
    pub tile: Option<u32>,
    pub sampler: Option<String>,
    pub samples: Option<u32>,
    pub threshold: Option<f64>,
    /// A name for the job (the scene file's name, shown in lists and used for the download).
    pub name: Option<String>,
    /// Claims serve the highest priority first ([`MIN_PRIORITY`] to [`MAX_PRIORITY`],
    /// default 0), and jobs of one priority in the order they came.
    pub priority: Option<i64>,
}

/// The lowest `?priority=`.
pub const MIN_PRIORITY: i64 = -1000;
/// The highest `?priority=`.
pub const MAX_PRIORITY: i64 = 1000;

/// The answer to a submission's query that does not parse: serde's reason, and what the
/// parameter it names takes (for `?tile=abc`, serde says only "invalid digit found in
/// string").
pub fn bad_query(reason: &str) -> String {
    let field = reason
        .strip_prefix("Failed to deserialize query string: ")
        .and_then(|r| r.split_once(':'))
        .map(|(f, _)| f);
    let takes = match field {
        Some("tile") => format!("; `tile` is a whole number of pixels, {MIN_TILE} to {MAX_TILE}"),
        Some("samples") => "; `samples` is a positive whole number".to_string(),
        Some("threshold") => "; `threshold` is a number".to_string(),
        Some("priority") => {
            format!("; `priority` is a whole number, {MIN_PRIORITY} to {MAX_PRIORITY}")
        }
        _ => String::new(),
    };
    format!("bad query: {reason}{takes}")
}

#[cfg(test)]
mod tests {
    use super::{SubmitParams, bad_query};

    /// A parameter that does not parse is named with what it takes, from serde's own
    /// rejection of it; a query that fails for another reason keeps serde's words alone.
    #[test]
    fn a_bad_query_says_what_the_parameter_takes() {
        let reason = |q: &str| {
            let uri: axum::http::Uri = format!("/jobs?{q}").parse().expect("a valid URI");
            match axum::extract::Query::<SubmitParams>::try_from_uri(&uri) {
                Ok(_) => panic!("`{q}` parsed"),
                Err(e) => bad_query(&e.body_text()),
            }
        };
        for (q, takes) in [
            ("tile=abc", "`tile` is a whole number of pixels, 8 to 1024"),
            ("tile=-1", "`tile` is a whole number of pixels, 8 to 1024"),
            ("samples=-1", "`samples` is a positive whole number"),
            ("threshold=x", "`threshold` is a number"),
            (
                "priority=1.5",
                "`priority` is a whole number, -1000 to 1000",
            ),
        ] {
            let m = reason(q);
            assert!(
                m.starts_with("bad query: ") && m.ends_with(takes),
                "{q}: {m}"
            );
        }
        let m = reason("tlie=8");
        assert!(
            m.contains("unknown field") && !m.contains("whole number"),
            "{m}"
        );
    }
}
