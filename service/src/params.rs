//! The query parameters of the user routes, and how a query that does not parse is
//! answered. Every route refuses parameters it does not take: a misspelt one would
//! otherwise be ignored without a word.

use serde::Deserialize;
use utoipa::IntoParams;

use crate::tiling::{MAX_TILE, MIN_TILE};

/// `GET /jobs` query parameters: a page of at most `limit` jobs (default and most
/// [`MAX_JOBS_LISTED`]), those submitted before job `before` when given.
#[derive(Debug, Default, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct ListParams {
    /// The most jobs to list, 1 to 200 (default 200).
    #[param(minimum = 1, maximum = 200)]
    pub limit: Option<u32>,
    /// List the jobs submitted before this job (the last of the page before).
    pub before: Option<String>,
}

/// The most jobs one `GET /jobs` lists.
pub const MAX_JOBS_LISTED: u32 = 200;

/// `GET /jobs/{id}?wait=S`: with `wait`, the answer waits until the job has ended (done,
/// failed or cancelled) or `S` seconds (at most 60, and less than the idle timeout) have
/// passed, so a client learns of the end at once instead of polling.
#[derive(Debug, Default, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct JobParams {
    /// Seconds to wait for the job's end (at most 60); none: answer at once.
    #[param(minimum = 0)]
    pub wait: Option<f64>,
}

/// The longest `GET /jobs/{id}?wait=` holds a request.
pub const MAX_JOB_WAIT_SECS: f64 = 60.0;

/// `DELETE /jobs/{id}` query parameters.
#[derive(Debug, Default, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct DeleteParams {
    /// Remove an ended job and everything stored for it, instead of cancelling: `true` or
    /// `1` (`false`, `0` or absent: cancel).
    #[serde(default, deserialize_with = "flag")]
    #[param(value_type = Option<String>, pattern = "^(true|false|1|0)$")]
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
#[derive(Debug, Default, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct SubmitParams {
    /// The tile edge in pixels, 8 to 1024 (default: the service's choice).
    #[param(minimum = 8, maximum = 1024)]
    pub tile: Option<u32>,
    /// The sampler, overriding the scene's: `center`, `thesis`, `grid`, `jitter` or
    /// `adaptive`.
    pub sampler: Option<String>,
    /// Samples per pixel along each axis, overriding the scene's.
    #[param(minimum = 1)]
    pub samples: Option<u32>,
    /// The adaptive sampler's threshold, overriding the scene's.
    pub threshold: Option<f64>,
    /// A name for the job (the scene file's name, shown in lists and used for the download).
    pub name: Option<String>,
    /// Claims serve the highest priority first ([`MIN_PRIORITY`] to [`MAX_PRIORITY`],
    /// default 0), and jobs of one priority in the order they came.
    #[param(minimum = -1000, maximum = 1000)]
    pub priority: Option<i64>,
}

/// The lowest `?priority=`.
pub const MIN_PRIORITY: i64 = -1000;
/// The highest `?priority=`.
pub const MAX_PRIORITY: i64 = 1000;

/// The answer to a query that does not parse, in the project's words: the parameter named
/// and what it takes, from serde's own rejection (for `?tile=abc` serde says only "invalid
/// digit found in string"; for a misspelt one, "unknown field").
pub fn bad_query(reason: &str) -> String {
    let reason = reason
        .strip_prefix("Failed to deserialize query string: ")
        .unwrap_or(reason);
    // serde_urlencoded's reasons, after the parameter's name when it has one: "unknown field
    // `x`, expected one of `a`, `b`" (or "expected `a` or `b`", or "there are no fields");
    // "missing field `x`"; or what is wrong with the value.
    let (field, why) = match reason.split_once(": ") {
        Some((f, w)) if !f.contains(' ') => (Some(f), w),
        _ => (None, reason),
    };
    if let Some(rest) = why.strip_prefix("unknown field ") {
        let (name, takes) = rest.split_once(", ").unwrap_or((rest, ""));
        let takes = match takes.strip_prefix("expected ") {
            Some(list) => format!(
                "this route takes {}",
                list.strip_prefix("one of ").unwrap_or(list)
            ),
            None => "this route takes no query parameters".to_string(),
        };
        return format!("unknown query parameter {name}; {takes}");
    }
    if let Some(name) = why.strip_prefix("missing field ") {
        return format!("the query parameter {name} is required");
    }
    let Some(field) = field else {
        return format!("the query does not parse: {reason}");
    };
    let takes = match field {
        "tile" => format!("; `tile` is a whole number of pixels, {MIN_TILE} to {MAX_TILE}"),
        "samples" => "; `samples` is a positive whole number".to_string(),
        "threshold" => "; `threshold` is a number".to_string(),
        "priority" => format!("; `priority` is a whole number, {MIN_PRIORITY} to {MAX_PRIORITY}"),
        "limit" => format!("; `limit` is a whole number, 1 to {MAX_JOBS_LISTED}"),
        "wait" => "; `wait` is a number of seconds".to_string(),
        _ => String::new(),
    };
    format!("query parameter `{field}`: {why}{takes}")
}

/// A route's query parameters, `T`, refused in the project's words ([`bad_query`]) with
/// `400`: axum's own `Query` answers serde's message ("Failed to deserialize query
/// string: …"), which names serde, not what the route takes.
#[derive(Debug)]
pub struct Params<T>(pub T);

impl<T, S> axum::extract::FromRequestParts<S> for Params<T>
where
    T: serde::de::DeserializeOwned,
    S: Send + Sync,
{
    type Rejection = crate::error::ApiError;

    async fn from_request_parts(
        parts: &mut axum::http::request::Parts,
        _state: &S,
    ) -> Result<Self, Self::Rejection> {
        Params::parse(&parts.uri)
    }
}

impl<T: serde::de::DeserializeOwned> Params<T> {
    /// The query of `uri`, or the answer to a query that does not parse.
    pub fn parse(uri: &axum::http::Uri) -> Result<Params<T>, crate::error::ApiError> {
        if let Some(key) = uri.query().and_then(crate::upload::non_utf8_param) {
            return Err(crate::error::ApiError::bad_request(format!(
                "query parameter `{key}` is not UTF-8 text once percent-decoded"
            )));
        }
        match axum::extract::Query::<T>::try_from_uri(uri) {
            Ok(axum::extract::Query(v)) => Ok(Params(v)),
            Err(e) => Err(crate::error::ApiError::bad_request(bad_query(
                &e.body_text(),
            ))),
        }
    }
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
            let field = q.split('=').next().unwrap_or_default();
            assert!(
                m.starts_with(&format!("query parameter `{field}`: ")) && m.ends_with(takes),
                "{q}: {m}"
            );
            assert!(!m.contains("deserialize"), "{q}: {m}");
        }
        let m = reason("tlie=8");
        assert!(
            m.starts_with("unknown query parameter `tlie`; this route takes `tile`, ")
                && !m.contains("whole number")
                && !m.contains("field"),
            "{m}"
        );
    }
}
