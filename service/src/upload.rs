//! Reading a submission's body: metered into its share of the submission budget
//! (`receiving`) before any byte is read, cut when it falls silent, and split into a scene
//! and its assets when it is multipart; with the percent-decoding that part names and query
//! values need.
//!
//! What the scene says is `validate`'s to check; this module only reads bytes.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::body::{Body, Bytes};
use axum::extract::{FromRequest, Multipart, Request};
use axum::http::{StatusCode, header};

use crate::error::ApiError;
use crate::names::check_asset_name;
use crate::receiving::{BODY_SILENCE, Full, Held, Receiving};
use crate::state::AppState;

/// A submission's body as read: the scene's bytes, the scene file's name (multipart only),
/// and the assets sent beside it.
pub struct Submission {
    /// The scene, as sent.
    pub scene: Vec<u8>,
    /// The `scene` part's file name, if it had one.
    pub file_name: Option<String>,
    /// The other parts, named as the scene names its textures.
    pub uploads: Uploads,
    /// Whether the body was multipart (the answers to an empty scene differ).
    pub multipart: bool,
}

/// Reads `POST /jobs`'s body, raw or multipart, metered into `held` (see [`metered`]). A
/// body cut for want of room is answered `503`, one cut for its silence `408`, anything
/// else as the reading failed.
pub async fn read_submission(
    req: Request,
    state: &AppState,
    held: &Arc<tokio::sync::Mutex<Held>>,
) -> Result<Submission, ApiError> {
    let req = metered(req, state, held.clone());
    // Media types are case-insensitive (RFC 9110): `Multipart/Form-Data` is multipart too.
    let is_multipart = req
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| {
            v.get(..19)
                .is_some_and(|m| m.eq_ignore_ascii_case("multipart/form-data"))
        });
    let read = if is_multipart {
        read_multipart(req, state).await
    } else {
        Bytes::from_request(req, state)
            .await
            .map(|body| (Vec::from(body), None, Vec::new()))
            .map_err(|e| ApiError::new(e.status(), e.body_text()))
    };
    match read {
        Ok((scene, file_name, uploads)) => Ok(Submission {
            scene,
            file_name,
            uploads,
            multipart: is_multipart,
        }),
        Err(e) => {
            let held = held.lock().await;
            Err(if held.refused() {
                busy(state)
            } else if let Some(why) = held.too_slow() {
                ApiError::new(StatusCode::REQUEST_TIMEOUT, why)
            } else if held.stalled() {
                stalled(state)
            } else {
                e
            })
        }
    }
}

/// The request with its body counted into the submission's share of the budget (see
/// `receiving`): its declared length (the body limit if it declares none) before the first
/// byte is read, all or nothing, held until the submission is answered. A share that gets
/// no room in time (or none while the service stops) ends the body with [`Full`], which
/// [`read_submission`] answers `503`; a body silent for [`BODY_SILENCE`] (or a second under the
/// idle timeout) ends with [`Stalled`], answered `408`, and so does one that arrives slower
/// than `--min-upload-rate` once it has taken [`BODY_SILENCE`], or for longer than
/// `--max-upload-secs` in all: a trickling client holds no share of the budget for long.
fn metered(req: Request, state: &AppState, held: Arc<tokio::sync::Mutex<Held>>) -> Request {
    use futures_util::StreamExt;
    let limit = state.cfg.max_body_bytes as u64;
    let want = crate::error::declared_length(req.headers()).map_or(limit, |n| n.min(limit));
    let within = Receiving::wait_limit(state.cfg.longest_silence());
    let silence = BODY_SILENCE.min(state.cfg.longest_silence());
    let min_rate = state.cfg.min_upload_rate;
    let most = Duration::from_secs(state.cfg.max_upload_secs);
    let (parts, body) = req.into_parts();
    struct Meter {
        body: axum::body::BodyDataStream,
        held: Arc<tokio::sync::Mutex<Held>>,
        state: AppState,
        /// Whether the share holds the body's room yet (taken at the first read).
        holding: bool,
        /// When the share got its room: the body's clock starts then.
        since: Instant,
        /// Bytes read so far.
        read: u64,
    }
    let meter = Meter {
        body: body.into_data_stream(),
        held,
        state: state.clone(),
        holding: false,
        since: Instant::now(),
        read: 0,
    };
    let chunks = futures_util::stream::unfold(Some(meter), move |meter| async move {
        let mut m = meter?;
        if !m.holding {
            let mut held = m.held.lock().await;
            // Biased: a share that finds room goes on though the service is stopping; only
            // one that must wait for room is refused (a random pick would cut uploads that
            // need no wait).
            let room = tokio::select! {
                biased;
                room = held.grow(want, within) => room,
                () = m.state.stopped() => {
                    held.refuse();
                    Err(Full)
                }
            };
            drop(held);
            if let Err(e) = room {
                return Some((Err(axum::Error::new(e)), None));
            }
            m.holding = true;
            m.since = Instant::now();
        }
        let left = most.saturating_sub(m.since.elapsed());
        match tokio::time::timeout(silence.min(left), m.body.next()).await {
            Ok(Some(Ok(chunk))) => {
                m.read += chunk.len() as u64;
                let took = m.since.elapsed();
                let floor = min_rate as f64 * took.as_secs_f64();
                if took >= most {
                    m.held.lock().await.cut_slow(too_long(most));
                    return Some((Err(axum::Error::new(Stalled)), None));
                }
                if min_rate > 0 && took >= BODY_SILENCE && (m.read as f64) < floor {
                    let why = format!(
                        "the body arrived at {:.0} bytes/s, below --min-upload-rate \
                         ({min_rate}); send it again over a faster link (its room in \
                         --max-receiving-bytes is given to others meanwhile)",
                        m.read as f64 / took.as_secs_f64()
                    );
                    m.held.lock().await.cut_slow(why);
                    return Some((Err(axum::Error::new(Stalled)), None));
                }
                Some((Ok(chunk), Some(m)))
            }
            Ok(Some(Err(e))) => Some((Err(e), None)),
            Ok(None) => None,
            Err(_) if m.since.elapsed() >= most => {
                m.held.lock().await.cut_slow(too_long(most));
                Some((Err(axum::Error::new(Stalled)), None))
            }
            Err(_) => {
                m.held.lock().await.stall();
                Some((Err(axum::Error::new(Stalled)), None))
            }
        }
    });
    Request::from_parts(parts, Body::from_stream(chunks))
}

/// Why a body still arriving after `most` was cut.
fn too_long(most: Duration) -> String {
    format!(
        "the body took longer than --max-upload-secs ({} s) to arrive; send it again over a \
         faster link (its room in --max-receiving-bytes is given to others meanwhile)",
        most.as_secs()
    )
}

/// A body that stopped arriving for [`BODY_SILENCE`], or arrived too slowly.
#[derive(Debug, thiserror::Error)]
#[error("the body stopped arriving, or arrived too slowly")]
struct Stalled;

/// The `408` of a submission whose body stopped arriving.
fn stalled(state: &AppState) -> ApiError {
    let secs = BODY_SILENCE.min(state.cfg.longest_silence()).as_secs();
    ApiError::new(
        StatusCode::REQUEST_TIMEOUT,
        format!(
            "the body stopped arriving for {secs} s; send it again (its room in \
             --max-receiving-bytes is given to others meanwhile)"
        ),
    )
}

/// The `503` of a submission that found no room in `--max-receiving-bytes` in time (or
/// none while the service stops).
fn busy(state: &AppState) -> ApiError {
    try_again_shortly(
        "the service is receiving and checking as many scenes as it takes at once \
         (--max-receiving-bytes); try again shortly",
    )
    .with("receiving_bytes", state.cfg.receiving_bytes())
}

/// A `503` that a client may simply repeat a few seconds later.
pub fn try_again_shortly(message: &str) -> ApiError {
    ApiError::new(StatusCode::SERVICE_UNAVAILABLE, message).retry_after(5)
}

pub type Uploads = Vec<(String, Vec<u8>)>;

async fn read_multipart(
    req: Request,
    state: &AppState,
) -> Result<(Vec<u8>, Option<String>, Uploads), ApiError> {
    let mut mp = Multipart::from_request(req, state)
        .await
        .map_err(|e| ApiError::new(e.status(), e.body_text()))?;
    let mut scene = None;
    let mut file_name = None;
    let mut uploads = Vec::new();
    let mut seen = HashMap::new();
    while let Some(field) = mp
        .next_field()
        .await
        .map_err(|e| ApiError::new(e.status(), e.body_text()))?
    {
        // Some clients (reqwest among them) percent-encode part names: `textures%2Fglobe.png`.
        let field_name = percent_decode(field.name().unwrap_or_default());
        let fname = field.file_name().map(str::to_string);
        let bytes = field
            .bytes()
            .await
            .map_err(|e| ApiError::new(e.status(), e.body_text()))?;
        if field_name == "scene" {
            if scene.is_some() {
                return Err(ApiError::bad_request(
                    "the `scene` part was sent twice: send one scene per job",
                ));
            }
            scene = Some(Vec::from(bytes));
            file_name = fname;
            continue;
        }
        // An asset is named by its part's name, as the scene names it; a part with no
        // name (or the generic `asset`) goes by its file name.
        let name = if field_name.is_empty() || field_name == "asset" {
            match fname.filter(|f| !f.is_empty()) {
                Some(f) => f,
                None => {
                    return Err(ApiError::bad_request(format!(
                        "the part `{field_name}` has no file name to name the asset by: send \
                         the file (curl -F asset=@globe.png) or name the part as the scene \
                         names the texture (-F globe.png=<globe.png)"
                    )));
                }
            }
        } else {
            field_name
        };
        check_asset_name(&name)?;
        if seen.insert(name.clone(), ()).is_some() {
            return Err(ApiError::bad_request(format!(
                "asset `{name}` was sent twice: for two textures of one file name in different \
                 folders, name each part by the scene's whole texture name \
                 (curl -F 'asset=@a/{name};filename=a/{name}' -F 'asset=@b/{name};filename=b/{name}')"
            )));
        }
        uploads.push((name, Vec::from(bytes)));
    }
    let scene = scene.ok_or_else(|| {
        ApiError::bad_request("multipart body has no `scene` part (curl -F scene=@file.ray)")
    })?;
    Ok((scene, file_name, uploads))
}

/// Decodes `%XX` escapes; anything malformed is kept as written.
pub fn percent_decode(s: &str) -> String {
    String::from_utf8(percent_decode_bytes(s)).unwrap_or_else(|_| s.to_string())
}

/// The first query parameter whose value, percent-decoded, is not UTF-8. The query parser
/// turns such bytes into U+FFFD without a word, so that `name=%ff` would be stored as "�".
pub fn non_utf8_param(query: &str) -> Option<&str> {
    query.split('&').find_map(|pair| {
        let (key, value) = pair.split_once('=').unwrap_or((pair, ""));
        std::str::from_utf8(&percent_decode_bytes(value))
            .is_err()
            .then_some(key)
    })
}

/// The bytes `%XX` escapes stand for; anything malformed is kept as written.
fn percent_decode_bytes(s: &str) -> Vec<u8> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let hex = |c: u8| (c as char).to_digit(16);
        if b[i] == b'%'
            && i + 2 < b.len()
            && let (Some(h), Some(l)) = (hex(b[i + 1]), hex(b[i + 2]))
        {
            out.push((h * 16 + l) as u8);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::percent_decode;

    #[test]
    fn part_names_are_percent_decoded() {
        assert_eq!(percent_decode("textures%2Fglobe.png"), "textures/globe.png");
        assert_eq!(percent_decode("a%2"), "a%2");
        assert_eq!(percent_decode("100%"), "100%");
        assert_eq!(percent_decode("plain.ppm"), "plain.ppm");
    }
}
