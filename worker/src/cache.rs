//! Built scenes by job: fetched from the service and built once, then shared by every slot
//! (and every local worker of one service) that renders the job's tiles.
//!
//! Not the rendering, and not what a slot does with a tile whose scene cannot be had: it
//! gets the reason ([`Unusable`]) and decides.

use std::sync::Arc;
use std::time::Instant;

use tessera_tracer::{Limits, MemoryAssets, Sampler, Scene, TextureLimits};
use tokio::sync::Mutex;
use tracing::info;

use crate::client::ClientError;
use crate::servers::Servers;

/// Scenes a cache keeps: a worker renders few jobs at once, and a job's scene may be large.
const CACHE_SCENES: usize = 4;

/// A job's scene, built once per worker and shared by its slots.
pub(crate) struct Prepared {
    pub(crate) scene: Scene,
    pub(crate) sampler: Sampler,
}

/// Why a claimed tile could not be rendered here.
pub(crate) enum Unusable {
    /// The job is gone (deleted or cancelled): drop the tile.
    Gone,
    /// The scene does not build on this worker: report a failure.
    Invalid(String),
    /// The service could not be asked: give up on this tile for now.
    Client(ClientError),
}

/// Built scenes by job id, most recently used last: shared by the slots of one worker, and
/// by several workers of one service (the service's `--local-workers`), so that a job's
/// scene is fetched and built once however many of them render its tiles. Job ids are one
/// farm's own (its replicas share them), so a cache must not be shared by workers of
/// different farms.
///
/// An async mutex guards it and is held while a missing scene is fetched and built, so no
/// two users fetch the same scene at once; a user wanting another job's scene waits for
/// that build too, as the slots of one worker do.
#[derive(Clone, Default)]
pub struct SceneCache {
    scenes: Arc<Mutex<Vec<Cached>>>,
}

/// A job id and its built scene.
type Cached = (String, Arc<Prepared>);

impl std::fmt::Debug for SceneCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SceneCache").finish_non_exhaustive()
    }
}

impl SceneCache {
    /// The scene of `job`, from the cache or fetched and built: asked of server `from`
    /// (the one that handed out the tile) first, then of the others while it does not
    /// answer.
    pub(crate) async fn prepared(
        &self,
        servers: &Servers,
        from: usize,
        job: &str,
    ) -> Result<Arc<Prepared>, Unusable> {
        let mut cache = self.scenes.lock().await;
        if let Some(i) = cache.iter().position(|(id, _)| id == job) {
            let entry = cache.remove(i);
            let p = entry.1.clone();
            cache.push(entry);
            return Ok(p);
        }
        let spec = match servers.job(from, job).await {
            Ok(s) => s,
            Err(ClientError::Status { status: 404, .. })
            | Err(ClientError::Status { status: 410, .. }) => {
                return Err(Unusable::Gone);
            }
            Err(e) => return Err(Unusable::Client(e)),
        };
        let mut assets = MemoryAssets::new();
        for name in &spec.assets {
            let bytes = match servers.asset(from, job, name).await {
                Ok(bytes) => bytes,
                // Not found: the job has been deleted since the worker fetched its scene, or
                // a proxy in front of the service refuses the texture's URL (some refuse the `%2F` of
                // `textures%2Fglobe.png`), which no retry mends. Reported as a failure, with
                // the reason: this worker is then kept away from the job, and a job no
                // worker can fetch fails, instead of coming back to the same tile for ever.
                // Neither an error that stops the worker nor a tile dropped unreleased:
                // its lease would run out and be charged as a crash.
                Err(e @ ClientError::Status { status: 404, .. })
                | Err(e @ ClientError::Status { status: 410, .. }) => {
                    return Err(Unusable::Invalid(format!(
                        "cannot fetch texture `{name}`: {e}"
                    )));
                }
                Err(e) => return Err(Unusable::Client(e)),
            };
            assets.insert(name.clone(), bytes);
        }
        let started = Instant::now();
        let built = tokio::task::spawn_blocking(move || -> Result<Prepared, String> {
            let limits = Limits::default();
            let desc = tessera_tracer::parse(&spec.scene, &limits).map_err(|e| e.to_string())?;
            let sampler = desc.sampler.with_overrides(
                spec.sampler.as_deref(),
                spec.samples,
                spec.threshold,
                limits.max_samples,
            )?;
            let scene = Scene::build(&desc, &assets, &TextureLimits::default())
                .map_err(|e| e.to_string())?;
            Ok(Prepared { scene, sampler })
        })
        .await
        .map_err(|e| Unusable::Invalid(format!("building the scene panicked: {e}")))?
        .map_err(Unusable::Invalid)?;
        info!(
            job,
            ms = started.elapsed().as_millis() as u64,
            "scene built"
        );
        let p = Arc::new(built);
        if cache.len() >= CACHE_SCENES {
            cache.remove(0);
        }
        cache.push((job.to_string(), p.clone()));
        Ok(p)
    }
}
