//! Bearer tokens: the worker token guards the worker routes, the submit token guards job
//! submission and deletion, the read token (or the submit token) guards reads. Compared in constant time, so response timing reveals nothing
//! about how much of a guess was right.
//!
//! This module only checks tokens; which routes need which token is decided in `routes`.

use axum::extract::{Request, State};
use axum::http::{StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use crate::AppState;
use crate::error::ApiError;

/// Equal length and equal bytes, examining every byte whatever the first difference.
/// (The length itself is not secret: tokens are fixed-length random strings in practice.)
pub fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    if a.len() != b.len() {
        return false;
    }
    let mut diff = 0u8;
    for (x, y) in a.iter().zip(b) {
        diff |= std::hint::black_box(x ^ y);
    }
    diff == 0
}

/// The token of an `Authorization: Bearer <token>` header. The scheme's name is matched
/// without regard to case (RFC 9110 §11.1: `bearer` and `BEARER` are `Bearer`), and any
/// run of spaces may separate it from the token.
fn presented(req: &Request) -> Option<&[u8]> {
    let value = req.headers().get(header::AUTHORIZATION)?.as_bytes();
    bearer_token(value)
}

fn bearer_token(value: &[u8]) -> Option<&[u8]> {
    let (scheme, rest) = value.split_at_checked(6)?;
    if !scheme.eq_ignore_ascii_case(b"Bearer") || !rest.starts_with(b" ") {
        return None;
    }
    Some(rest.trim_ascii_start())
}

fn check(expected: Option<&str>, req: &Request, what: &str) -> Result<(), Box<Response>> {
    let Some(expected) = expected else {
        return Ok(());
    };
    match presented(req) {
        Some(t) if constant_time_eq(t, expected.as_bytes()) => Ok(()),
        _ => Err(Box::new(
            (
                [(header::WWW_AUTHENTICATE, "Bearer")],
                ApiError::new(
                    StatusCode::UNAUTHORIZED,
                    format!("this route needs the {what} token: `Authorization: Bearer <token>`"),
                ),
            )
                .into_response(),
        )),
    }
}

/// Middleware for the worker routes.
pub async fn require_worker_token(
    State(state): State<AppState>,
    req: Request,
    next: Next,
) -> Response {
    match check(state.cfg.token.as_deref(), &req, "worker") {
        Ok(()) => next.run(req).await,
        Err(r) => *r,
    }
}

/// Middleware for job submission and deletion.
pub async fn require_submit_token(
    State(state): State<AppState>,
    req: Request,
    next: Next,
) -> Response {
    if req.method() == axum::http::Method::GET {
        return next.run(req).await;
    }
    match check(state.cfg.submit_token.as_deref(), &req, "submit") {
        Ok(()) => next.run(req).await,
        Err(r) => *r,
    }
}

/// The `tessera_token` cookie's value (percent-decoded, as the pages encode it), which the
/// pages send for what they load without headers (images, the event stream).
fn cookie_token(req: &Request) -> Option<Vec<u8>> {
    req.headers()
        .get_all(header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .find_map(|c| c.trim().strip_prefix("tessera_token="))
        .map(|t| crate::upload::percent_decode(t).into_bytes())
}

/// The paths whose `GET` is open whatever `--read-token` says: the page shells, which hold
/// no data and must load for the token to be typed, the health check, and the icon.
pub const OPEN_READS: [&str; 4] = ["/", "/api", "/healthz", "/favicon.ico"];

/// Whether a `GET` of `path` reads data that `--read-token` guards: not [`OPEN_READS`], the
/// page's files, nor a job's page for a browser (a shell too); nor the worker routes (their
/// own token).
fn guarded_read(req: &Request) -> bool {
    let path = req.uri().path();
    let open = OPEN_READS.contains(&path)
        || path.starts_with("/static/")
        || path.starts_with("/worker/")
        || (path.starts_with("/jobs/")
            && path[6..].split('/').count() == 1
            && crate::handlers::page::wants_html(req.headers()));
    !open
}

/// Middleware for reads (`GET`, `HEAD`) when `--read-token` is set: the read token or the
/// submit token, as a bearer token or the `tessera_token` cookie.
pub async fn require_read_token(
    State(state): State<AppState>,
    req: Request,
    next: Next,
) -> Response {
    let Some(read) = state.cfg.read_token.as_deref() else {
        return next.run(req).await;
    };
    let is_read = matches!(
        *req.method(),
        axum::http::Method::GET | axum::http::Method::HEAD
    );
    if !is_read || !guarded_read(&req) {
        return next.run(req).await;
    }
    let submit = state.cfg.submit_token.as_deref();
    let accepted = |t: &[u8]| {
        constant_time_eq(t, read.as_bytes())
            | submit.is_some_and(|s| constant_time_eq(t, s.as_bytes()))
    };
    let ok =
        presented(&req).is_some_and(accepted) || cookie_token(&req).is_some_and(|t| accepted(&t));
    if ok {
        return next.run(req).await;
    }
    (
        [(header::WWW_AUTHENTICATE, "Bearer")],
        ApiError::new(
            StatusCode::UNAUTHORIZED,
            "reading needs the read token (or the submit token): `Authorization: Bearer \
             <token>`, or the page's token field",
        ),
    )
        .into_response()
}

#[cfg(test)]
mod tests {
    use super::{bearer_token, constant_time_eq};

    #[test]
    fn the_scheme_is_matched_without_regard_to_case() {
        for v in ["Bearer s3", "bearer s3", "BEARER s3", "Bearer   s3"] {
            assert_eq!(bearer_token(v.as_bytes()), Some(&b"s3"[..]), "{v}");
        }
        for v in ["Basic s3", "Bearers3", "Bearer", "Beare s3", ""] {
            assert_eq!(bearer_token(v.as_bytes()), None, "{v}");
        }
    }

    #[test]
    fn equal_only_when_every_byte_is() {
        assert!(constant_time_eq(b"secret", b"secret"));
        assert!(!constant_time_eq(b"secret", b"secreT"));
        assert!(!constant_time_eq(b"secret", b"Secret"));
        assert!(!constant_time_eq(b"secret", b"secrets"));
        assert!(!constant_time_eq(b"", b"x"));
    }
}
