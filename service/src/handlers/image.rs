//! The finished image (`GET /jobs/{id}/image.png`), streamed chunk by chunk, and the file
//! name a download gets.

use axum::body::{Body, Bytes};
use axum::extract::{Path, State};
use axum::http::{HeaderMap, HeaderValue, header};
use axum::response::{IntoResponse, Response};

use crate::error::{ApiError, ErrorBody};
use crate::params::{NoParams, Params};
use crate::state::AppState;
use crate::store::JobState;

/// `GET /jobs/{id}/image.png`: the finished PNG, streamed from the database chunk by chunk.
#[utoipa::path(
    get, path = "/jobs/{id}/image.png", tag = "jobs",
    summary = "Download the image",
    description = "The finished PNG, once the job is done; before that, how far the job is.",
    params(("id" = String, Path, description = "The job's id")),
    responses(
        (status = 200, description = "The finished image (RGB, 8 bits, sRGB)", content_type = "image/png", body = Vec<u8>,
         headers(("Content-Disposition" = String, description = "The job's name as the file name"))),
        (status = 400, description = "A query parameter was given", body = ErrorBody),
        (status = 404, description = "No such job", body = ErrorBody),
        (status = 409, description = "The job is not done: how far it is, or why it has no image", body = ErrorBody),
        (status = 503, description = "The database is busy or failing; try again", body = ErrorBody),
    )
)]
pub async fn image(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Params(NoParams {}): Params<NoParams>,
) -> Result<Response, ApiError> {
    let row = state
        .store
        .job(&id)
        .await?
        .ok_or_else(|| ApiError::no_job(&id))?;
    if row.state != JobState::Done {
        let why = match row.state {
            JobState::Failed => format!("job failed: {}", row.error.clone().unwrap_or_default()),
            JobState::Cancelled => "job was cancelled; it has no image".to_string(),
            _ => format!(
                "job is {}: {} of {} tiles done",
                row.state, row.tiles_done, row.tiles_total
            ),
        };
        return Err(ApiError::conflict(why)
            .with("state", row.state)
            .with("tiles_done", row.tiles_done)
            .with("tiles_total", row.tiles_total));
    }
    let chunks = state.store.image_chunks(&id).await?;
    let store = state.store.clone();
    let stream = futures_util::stream::unfold(0u32, move |seq| {
        let store = store.clone();
        let id = id.clone();
        async move {
            if seq >= chunks {
                return None;
            }
            let item = match store.image_chunk(&id, seq).await {
                Ok(Some(bytes)) => Ok(Bytes::from(bytes)),
                Ok(None) => Err(std::io::Error::other("image chunk missing")),
                Err(e) => Err(std::io::Error::other(e.to_string())),
            };
            Some((item, seq + 1))
        }
    });
    let mut headers = HeaderMap::new();
    headers.insert(header::CONTENT_TYPE, HeaderValue::from_static("image/png"));
    // A done job's image never changes (ids are never reused), so a browser keeps it: the
    // web page, which redraws its list every second, does not fetch every thumbnail again.
    // `private`: a deleted job's image must not live on in a shared cache.
    headers.insert(
        header::CACHE_CONTROL,
        HeaderValue::from_static("private, max-age=31536000, immutable"),
    );
    if let Some(n) = row.png_bytes {
        headers.insert(header::CONTENT_LENGTH, HeaderValue::from(n));
    }
    if let Ok(v) = HeaderValue::from_str(&content_disposition(row.name.as_deref(), &row.id)) {
        headers.insert(header::CONTENT_DISPOSITION, v);
    }
    Ok((headers, Body::from_stream(stream)).into_response())
}

/// The download's `Content-Disposition`: the job's name (its last `/` segment, `.ray`
/// dropped) as a `.png` file name. `filename` holds its ASCII letters, digits, `-`, `_` and
/// `.` (the job id when that leaves no name); when that is not the whole name, `filename*`
/// (RFC 6266, RFC 8187) carries all of it, UTF-8 percent-encoded, for clients that read it.
fn content_disposition(name: Option<&str>, id: &str) -> String {
    let file = name.and_then(|n| n.rsplit('/').next()).unwrap_or(id);
    let stem = file.strip_suffix(".ray").unwrap_or(file);
    let plain = |c: char| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.');
    let safe: String = stem.chars().filter(|&c| plain(c)).collect();
    let fallback = if safe.chars().all(|c| c == '.') {
        id
    } else {
        &safe
    };
    let mut header = format!("inline; filename=\"{fallback}.png\"");
    if !stem.chars().all(plain) && !stem.trim().is_empty() {
        // RFC 8187 `attr-char`s stand for themselves; every other byte is `%XX`.
        let attr = |b: u8| b.is_ascii_alphanumeric() || b"!#$&+-.^_`|~".contains(&b);
        let mut encoded = String::new();
        for b in stem.bytes() {
            if attr(b) {
                encoded.push(char::from(b));
            } else {
                encoded.push_str(&format!("%{b:02X}"));
            }
        }
        header.push_str(&format!("; filename*=UTF-8''{encoded}.png"));
    }
    header
}

#[cfg(test)]
mod tests {
    use crate::upload::percent_decode;

    /// The header's plain `filename` is always a safe ASCII name, and `filename*` (when
    /// present) decodes back to the whole name: checked with the module's own decoder.
    #[test]
    fn download_names_keep_what_they_can_and_carry_the_rest_encoded() {
        let id = "0123456789abcdef";
        let parts = |h: &str| -> (String, Option<String>) {
            let plain = h
                .split("filename=\"")
                .nth(1)
                .and_then(|r| r.split('"').next())
                .unwrap_or_default()
                .to_string();
            let star = h
                .split("filename*=UTF-8''")
                .nth(1)
                .map(|e| percent_decode(e.split(';').next().unwrap_or_default()));
            (plain, star)
        };
        for (name, plain, star) in [
            (Some("scene.ray"), "scene.png", None),
            (Some("dir/sub/thesis.ray"), "thesis.png", None),
            (None, "0123456789abcdef.png", None),
            (Some("😀.ray"), "0123456789abcdef.png", Some("😀.png")),
            (Some("a b&c\"d;.ray"), "abcd.png", Some("a b&c\"d;.png")),
            (Some("Straße 1"), "Strae1.png", Some("Straße 1.png")),
            (Some(".."), "0123456789abcdef.png", None),
        ] {
            let h = super::content_disposition(name, id);
            assert!(h.is_ascii() && !h.contains('\n'), "{h}");
            let (p, s) = parts(&h);
            assert_eq!(p, plain, "{name:?}: {h}");
            assert_eq!(s.as_deref(), star, "{name:?}: {h}");
        }
    }
}
