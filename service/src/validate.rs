//! Scene validation: a submitted scene and its uploads checked into the job to store. The
//! scene is parsed and built (textures decoded) off the async threads before anything is
//! stored, so a bad scene is a `400` naming line and column and leaves no trace.
//!
//! Room to check the scene, then room to decode its textures, are taken from the
//! submission budget (`receiving`) first; the memory checking took is given back to the
//! operating system once the answer is known ([`Trim`]). The tile size follows `tiling`.

use serde_json::{Value, json};
use tessera_tracer::{MemoryAssets, Scene, SceneError, Texture, parse, tiles};

use crate::error::ApiError;
use crate::now_ms;
use crate::params::SubmitParams;
use crate::receiving::{Full, Held, Receiving};
use crate::state::AppState;
use crate::store::NewJob;
use crate::tiling::{job_tile, tile_rays_per_pixel};
use crate::upload::{Uploads, try_again_shortly};

/// The scene's text from the bytes sent (as `tessera_tracer::scene_text` reads them): not
/// empty, and not a scene whose line breaks were lost on the way.
pub fn scene_source(bytes: Vec<u8>, multipart: bool) -> Result<String, ApiError> {
    let source = tessera_tracer::scene_text(bytes).map_err(|e| scene_error(&e))?;
    if source.trim().is_empty() {
        return Err(ApiError::bad_request(if multipart {
            "the `scene` part is empty: attach the scene file (curl -F scene=@scene.ray)"
        } else {
            "empty body: send the scene file (curl --data-binary @scene.ray)"
        }));
    }
    // `curl -d @scene.ray` sends the file without its line breaks, and a scene that starts
    // with a comment becomes one comment line, which would render a black image without a
    // word.
    if !multipart
        && !source.contains('\n')
        && source
            .trim_start_matches('\u{feff}')
            .trim_start()
            .starts_with('#')
    {
        return Err(ApiError::bad_request(
            "the body is one comment line, with no line breaks: `curl -d` drops a file's line \
             breaks; send the scene file with curl --data-binary @scene.ray",
        ));
    }
    Ok(source)
}

/// The `503` of a submission whose textures found no room to be decoded in time
/// (`--max-scene-texture-pixels` at once), or none while the service stops.
fn busy_decoding(state: &AppState) -> ApiError {
    try_again_shortly(
        "the service is decoding as many textures as it takes at once \
         (--max-scene-texture-pixels); try again shortly",
    )
    .with(
        "max_scene_texture_pixels",
        state.cfg.max_scene_texture_pixels,
    )
}

/// The `503` of a submission whose scene found no room to be checked in time
/// (`--max-checking-bytes` at once), or none while the service stops.
fn busy_checking(state: &AppState, cost: u64) -> ApiError {
    try_again_shortly(
        "the service is checking as many scenes as it takes at once \
         (--max-checking-bytes); try again shortly",
    )
    .with("max_checking_bytes", state.cfg.max_checking_bytes)
    .with("check_bytes", cost)
}

/// Checks at least this large give their memory back to the operating system when done.
const TRIM_FROM: u64 = 16 << 20;

/// Gives the memory a large check took back to the operating system when dropped, on every
/// way out of the check: the allocator keeps freed memory for reuse otherwise, and a burst
/// of large scenes would leave the service that much larger for good.
struct Trim(u64);

impl Drop for Trim {
    fn drop(&mut self) {
        if self.0 >= TRIM_FROM
            && let Ok(rt) = tokio::runtime::Handle::try_current()
        {
            rt.spawn_blocking(crate::memory::give_back);
        }
    }
}

/// A scene's texture name as the upload it stands for: `/`-separated, resolved by
/// `tessera-render`'s own rule ([`tessera_tracer::lexical_texture_path`]: `./globe.png` and
/// `maps/../globe.png` are `globe.png`). `None` for a name that leaves the scene's folder
/// or is no relative name (a leading `/`, a `\`, control characters).
fn texture_key(name: &str) -> Option<String> {
    if name.starts_with('/') || name.contains('\\') || name.chars().any(char::is_control) {
        return None;
    }
    let resolved = tessera_tracer::lexical_texture_path(name);
    let parts: Option<Vec<&str>> = resolved
        .components()
        .map(|c| match c {
            std::path::Component::Normal(s) => s.to_str(),
            _ => None,
        })
        .collect();
    parts.filter(|p| !p.is_empty()).map(|p| p.join("/"))
}

fn scene_error(e: &SceneError) -> ApiError {
    let first = e.first();
    let all: Vec<Value> = e
        .diagnostics()
        .iter()
        .map(|d| json!({ "line": d.pos.line, "column": d.pos.column, "message": d.message }))
        .collect();
    ApiError::bad_request(format!(
        "{}:{}: {}",
        first.pos.line, first.pos.column, first.message
    ))
    .with("line", first.pos.line)
    .with("column", first.pos.column)
    .with("errors", Value::Array(all))
}

/// Parses and builds the scene off the async threads; on success returns what to store.
/// `tile` is the job's or `--tile`'s; without either the size follows
/// [`auto_tile`](crate::tiling::auto_tile).
pub async fn validate(
    state: &AppState,
    source: String,
    uploads: Uploads,
    params: &SubmitParams,
    tile: Option<u32>,
    name: Option<String>,
    held: &tokio::sync::Mutex<Held>,
) -> Result<(NewJob, Vec<tessera_tracer::Rect>, Uploads), ApiError> {
    let limits = state.cfg.scene_limits();
    let texture_limits = state.cfg.texture_limits();
    let sampler = params.sampler.clone();
    let samples = params.samples;
    let threshold = params.threshold;
    let panicked = |e: tokio::task::JoinError| {
        tracing::error!("scene validation panicked: {e}");
        ApiError::bad_request("the scene could not be checked (the validator failed)")
    };
    // Room for the check before the scene is parsed (see `receiving`).
    let cost = Receiving::check_cost(source.len());
    {
        let within = Receiving::wait_limit(state.cfg.longest_silence());
        let mut held = held.lock().await;
        let grown = tokio::select! {
            biased;
            room = held.grow_checking(cost, within) => room,
            () = state.stopped() => Err(Full),
        };
        if grown.is_err() {
            return Err(busy_checking(state, cost));
        }
    }
    // Declared after the room is taken: dropped first, at every return below.
    let _trim = Trim(cost);
    let matched = tokio::task::spawn_blocking(move || {
        let desc = parse(&source, &limits).map_err(|e| scene_error(&e))?;
        let chosen = desc
            .sampler
            .with_overrides(sampler.as_deref(), samples, threshold, limits.max_samples)
            .map_err(ApiError::bad_request)?;
        // Each texture the scene names gets the upload of that name or, failing that, of its
        // name with `.` and `..` resolved (`./globe.png`), or the one upload whose name is its
        // file name (`textures/globe.png` ← `globe.png`: many clients send only file names).
        let mut kept: Uploads = Vec::new();
        for (n, pos) in desc.texture_names() {
            let Some(key) = texture_key(n) else {
                let message = format!(
                    "texture `{n}` must name a file beside the scene or below it: no leading \
                     `/`, no `..` above the scene's folder, no `\\`"
                );
                return Err(scene_error(&SceneError::single(pos, message)));
            };
            let base = key.rsplit('/').next().unwrap_or(&key);
            let found = uploads
                .iter()
                .find(|(u, _)| u == n || *u == key)
                .or_else(|| uploads.iter().find(|(u, _)| u == base));
            if let Some((_, bytes)) = found {
                kept.push((n.to_string(), bytes.clone()));
            }
        }
        // What the textures decode to, from their headers (a bad header is the check's to
        // report, below).
        let texels: u64 = kept
            .iter()
            .filter_map(|(n, bytes)| Texture::dimensions(n, bytes, &texture_limits).ok())
            .map(|(w, h)| u64::from(w) * u64::from(h))
            .sum();
        Ok::<_, ApiError>((source, desc, chosen, kept, texels, texture_limits))
    })
    .await
    .map_err(panicked)??;
    let (source, desc, chosen, kept, texels, texture_limits) = matched;
    // Room for the textures before they are decoded (see `receiving`); none for textures
    // past the job's own limit, which the check refuses from their headers (they waited for
    // every texel there is, ahead of everyone, to be answered 400).
    if texels <= state.cfg.max_scene_texture_pixels {
        let within = Receiving::wait_limit(state.cfg.longest_silence());
        let mut held = held.lock().await;
        let grown = tokio::select! {
            biased;
            room = held.grow_texels(texels, within) => room,
            () = state.stopped() => Err(Full),
        };
        if grown.is_err() {
            return Err(busy_decoding(state));
        }
    }
    let checked = tokio::task::spawn_blocking(move || {
        let mut assets = MemoryAssets::new();
        for (n, bytes) in &kept {
            assets.insert(n.clone(), bytes.clone());
        }
        Scene::check(&desc, &assets, &texture_limits).map_err(|e| {
            let missing: Vec<&str> = desc
                .texture_names()
                .iter()
                .map(|(n, _)| *n)
                .filter(|n| !assets.contains(n))
                .collect();
            let err = scene_error(&e);
            if missing.is_empty() {
                err
            } else {
                err.with("missing_assets", missing)
            }
        })?;
        let rays = tile_rays_per_pixel(&chosen);
        Ok::<_, ApiError>((source, desc.width, desc.height, kept, rays))
    })
    .await
    .map_err(panicked)?;
    // The decoded textures and the checked scene are gone: their room is another
    // submission's while this one is stored.
    {
        let mut held = held.lock().await;
        held.release_texels();
        held.release_checking();
    }
    let checked = checked?;
    let (source, width, height, kept, rays) = checked;
    let tile = job_tile(width, height, rays, tile, state.cfg.max_tiles)?;
    let job = NewJob {
        id: uuid::Uuid::new_v4().simple().to_string()[..16].to_string(),
        scene: source,
        name,
        width,
        height,
        tile,
        sampler: params.sampler.clone(),
        samples: params.samples,
        threshold: params.threshold,
        created_at: now_ms(),
        priority: params.priority.unwrap_or(0),
    };
    let rects = tiles(width, height, tile);
    Ok((job, rects, kept))
}

#[cfg(test)]
mod tests {
    use super::texture_key;

    #[test]
    fn texture_names_resolve_like_paths_beside_the_scene() {
        for (name, key) in [
            ("globe.png", "globe.png"),
            ("./globe.png", "globe.png"),
            ("maps/../globe.png", "globe.png"),
            ("maps//./globe.png", "maps/globe.png"),
            ("a/b/../../c/d.png", "c/d.png"),
        ] {
            assert_eq!(texture_key(name).as_deref(), Some(key), "{name:?}");
        }
        for bad in [
            "",
            ".",
            "/etc/passwd",
            "../x.png",
            "a/../../b",
            "a\\b",
            "x\u{0}",
            "a/..",
        ] {
            assert_eq!(texture_key(bad), None, "{bad:?}");
        }
    }
}
