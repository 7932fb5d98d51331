//! The service's configuration: flags with environment fallbacks, and the limits derived
//! from them. Every limit has a safe default; `README.md` lists them all.

use clap::Parser;
use tessera_tracer::{Limits, TextureLimits};

/// Default tile edge in pixels, chosen by measurement (`tessera-bench farm`): 64 px tiles
/// cost well under 1 % in queue overhead on a 1080p frame while leaving enough tiles
/// (510 of them) that no worker idles long at the end of a job.
pub const DEFAULT_TILE: u32 = 64;

/// The Tessera render service: HTTP API, SQLite job queue, web page, and local workers.
#[derive(Debug, Clone, Parser)]
#[command(name = "tessera-service", version, about)]
pub struct Config {
    /// Address to listen on.
    #[arg(long, env = "TESSERA_LISTEN", default_value = "127.0.0.1:8080")]
    pub listen: String,
    /// The queue's database.
    #[arg(long, env = "TESSERA_DATABASE", default_value = "sqlite://tessera.db")]
    pub database: String,
    /// Workers run inside this process, over the same HTTP protocol (default: one per core).
    #[arg(long, env = "TESSERA_LOCAL_WORKERS")]
    pub local_workers: Option<usize>,
    /// Bearer token the worker routes require (none: open).
    #[arg(long, env = "TESSERA_WORKER_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// Bearer token that job submission and deletion require (none: open, which is allowed
    /// only on a loopback address unless --open-submit is given).
    #[arg(long, env = "TESSERA_SUBMIT_TOKEN", hide_env_values = true)]
    pub submit_token: Option<String>,
    /// Accept jobs from anyone even when listening beyond loopback without --submit-token.
    #[arg(long, env = "TESSERA_OPEN_SUBMIT")]
    pub open_submit: bool,
    /// Default tile edge in pixels (a job may ask for another with `?tile=`).
    #[arg(long, env = "TESSERA_TILE", default_value_t = DEFAULT_TILE)]
    pub tile: u32,
    /// Lease length in milliseconds; workers renew at a third of it.
    #[arg(long, env = "TESSERA_LEASE_MS", default_value_t = 30_000)]
    pub lease_ms: u64,
    /// Failures (reported, or leases lost) after which a tile fails its job.
    #[arg(long, env = "TESSERA_MAX_ATTEMPTS", default_value_t = 4)]
    pub max_attempts: u32,
    /// Failures of one worker on one job after which it is kept away from the job.
    #[arg(long, env = "TESSERA_KEEP_AWAY_AFTER", default_value_t = 2)]
    pub keep_away_after: u32,
    /// How long a worker is kept away from a job it keeps failing, in seconds.
    #[arg(long, env = "TESSERA_KEEP_AWAY_SECS", default_value_t = 300)]
    pub keep_away_secs: u64,
    /// Largest request body for POST /jobs (scene plus textures), in bytes.
    #[arg(long, env = "TESSERA_MAX_BODY_BYTES", default_value_t = 64 << 20)]
    pub max_body_bytes: usize,
    /// Largest image, width × height pixels.
    #[arg(long, env = "TESSERA_MAX_PIXELS", default_value_t = 7680 * 4320 * 2)]
    pub max_pixels: u64,
    /// Largest image width or height.
    #[arg(long, env = "TESSERA_MAX_DIMENSION", default_value_t = 16_384)]
    pub max_dimension: u32,
    /// Most objects in a scene, CSG children included.
    #[arg(long, env = "TESSERA_MAX_OBJECTS", default_value_t = 100_000)]
    pub max_objects: usize,
    /// Deepest CSG nesting.
    #[arg(long, env = "TESSERA_MAX_CSG_DEPTH", default_value_t = 32)]
    pub max_csg_depth: usize,
    /// Most texture files per scene.
    #[arg(long, env = "TESSERA_MAX_TEXTURES", default_value_t = 32)]
    pub max_textures: usize,
    /// Largest texture, width × height texels (decoding stops before allocating more).
    #[arg(long, env = "TESSERA_MAX_TEXTURE_PIXELS", default_value_t = 16 << 20)]
    pub max_texture_pixels: u64,
}

impl Config {
    /// Defaults as if no flag were given (tests start from these).
    pub fn defaults() -> Config {
        Config::parse_from(["tessera-service"])
    }

    pub fn scene_limits(&self) -> Limits {
        Limits {
            max_dimension: self.max_dimension,
            max_pixels: self.max_pixels,
            max_objects: self.max_objects,
            max_csg_depth: self.max_csg_depth,
            max_textures: self.max_textures,
            ..Limits::default()
        }
    }

    pub fn texture_limits(&self) -> TextureLimits {
        TextureLimits {
            max_pixels: self.max_texture_pixels,
            ..TextureLimits::default()
        }
    }
}
