//! The service's configuration: flags with environment fallbacks, and the limits derived
//! from them. Every limit has a safe default; docs/OPERATIONS.md lists them all.

use clap::Parser;
use tessera_tracer::{Limits, MAX_THREADS, TextureLimits};

use crate::tiling::{MAX_TILE, MIN_TILE};

/// The longest a claim waits at the service for work (`?wait_ms=`).
pub const MAX_CLAIM_WAIT_MS: u64 = 10_000;

/// Shortest lease a service hands out, in milliseconds: workers renew at a third of it,
/// and below this a round trip could outlast the renewal interval.
pub const MIN_LEASE_MS: u64 = 100;

/// `HOST:PORT` with a numeric port: an IP address (`127.0.0.1:8080`, `[::]:8080`) or a host
/// name of letters, digits, `-`, `_` and `.` (`localhost:8080`, a container's name).
/// Checked with the flags, so that a bad address is a usage error (status 2) rather than a
/// failure to listen.
fn listen_addr(s: &str) -> Result<String, String> {
    let named = |host: &str| {
        !host.is_empty()
            && host
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '.' | '_'))
    };
    // As the standard library splits it: at the last `:`, so `:::8080` is `::` and 8080.
    let ok = s.parse::<std::net::SocketAddr>().is_ok()
        || s.rsplit_once(':').is_some_and(|(host, port)| {
            (named(host) || host.parse::<std::net::IpAddr>().is_ok()) && port.parse::<u16>().is_ok()
        });
    if ok {
        Ok(s.to_string())
    } else {
        Err("expected HOST:PORT, e.g. 127.0.0.1:8080, [::]:8080 or localhost:8080".to_string())
    }
}

/// Why a bearer token cannot be used: empty (which to a worker means none, so it would lock
/// out every worker, the local ones too, while the service looked healthy), or as
/// [`tessera_protocol::token_problem`] says.
fn token_problem(s: &str) -> Option<&'static str> {
    if s.is_empty() {
        Some("a token may not be empty")
    } else {
        tessera_protocol::token_problem(s)
    }
}

/// The database: not blank, and a `sqlite:` URL names a file, as sqlx reads it (`sqlite:`
/// or `//` dropped, then everything from `?`). `sqlite://` or `sqlite:?mode=rwc` would name
/// a private temporary database per connection (reads then fail with "no such table:
/// jobs"), and `' '` a file named by a space. A `postgres://` or `postgresql://` URL is
/// checked when the service opens it (sqlx parses it then, and says what is wrong).
fn database(s: &str) -> Result<String, String> {
    if crate::store::is_postgres(s) {
        return Ok(s.to_string());
    }
    let path = match s.strip_prefix("sqlite:") {
        Some(url) => {
            let url = url.strip_prefix("//").unwrap_or(url);
            url.split('?').next().unwrap_or_default()
        }
        None => s,
    };
    if path.trim().is_empty() || s.trim() != s {
        Err(
            "expected sqlite://PATH (or a file path), e.g. sqlite://tessera.db, or \
             postgres://USER@HOST:PORT/DB"
                .to_string(),
        )
    } else {
        Ok(s.to_string())
    }
}

/// The Tessera render service: HTTP API, job queue (SQLite, or PostgreSQL shared by several
/// replicas), web page, and local workers.
#[derive(Debug, Clone, Parser)]
#[command(name = "tessera-service", version, about)]
pub struct Config {
    /// Address to listen on.
    #[arg(long, env = "TESSERA_LISTEN", default_value = "127.0.0.1:8080",
          value_parser = listen_addr)]
    pub listen: String,
    /// The queue's database: sqlite://PATH, or postgres://USER@HOST:PORT/DB (several
    /// services on one PostgreSQL database serve one farm).
    #[arg(long, env = "TESSERA_DATABASE", default_value = "sqlite://tessera.db",
          value_parser = database)]
    pub database: String,
    /// Workers run inside this process, over the same HTTP protocol, one thread each: 0 to
    /// 1024 (default: one per core).
    #[arg(long, env = "TESSERA_LOCAL_WORKERS",
          value_parser = clap::value_parser!(u16).range(0..=i64::from(MAX_THREADS)))]
    pub local_workers: Option<u16>,
    /// Bearer token the worker routes require (none: open). An empty one is refused: it
    /// would lock out every worker, its own local ones too.
    #[arg(long, env = "TESSERA_WORKER_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// Bearer token that job submission and deletion require (none: open, which is allowed
    /// only on a loopback address unless --open-submit is given). An empty one is refused.
    #[arg(long, env = "TESSERA_SUBMIT_TOKEN", hide_env_values = true)]
    pub submit_token: Option<String>,
    /// Bearer token that reads require (the job list, jobs, scenes, images, previews, events,
    /// the roster of workers, the API document); the submit token is accepted too, and the
    /// browser pages send either as the `tessera_token` cookie. `/healthz`, the page shells
    /// and `/static/` stay open (none: reads are open). An empty one is refused.
    #[arg(long, env = "TESSERA_READ_TOKEN", hide_env_values = true)]
    pub read_token: Option<String>,
    /// Accept jobs from anyone even when listening beyond loopback without --submit-token.
    #[arg(long, env = "TESSERA_OPEN_SUBMIT")]
    pub open_submit: bool,
    /// Tile edge in pixels (8 to 1024) for jobs that do not ask with `?tile=`; by default
    /// the service picks one per job from its size and samples per pixel.
    #[arg(long, env = "TESSERA_TILE",
          value_parser = clap::value_parser!(u32)
              .range(i64::from(MIN_TILE)..=i64::from(MAX_TILE)))]
    pub tile: Option<u32>,
    /// Seconds the local workers keep rendering the tiles they hold after SIGINT/SIGTERM
    /// before giving them back (as `tessera-worker --grace-secs`), 0 to 86,400 (a day).
    #[arg(long, env = "TESSERA_GRACE_SECS", default_value_t = 30,
          value_parser = clap::value_parser!(u64).range(0..=86_400))]
    pub grace_secs: u64,
    /// Lease length in milliseconds, 100 to 86,400,000 (a day); workers renew at a third
    /// of it.
    #[arg(long, env = "TESSERA_LEASE_MS", default_value_t = 30_000,
          value_parser = clap::value_parser!(u64).range(MIN_LEASE_MS..=86_400_000))]
    pub lease_ms: u64,
    /// Failures (reported, or leases lost) after which a tile fails its job (at least 1).
    #[arg(long, env = "TESSERA_MAX_ATTEMPTS", default_value_t = 4,
          value_parser = clap::value_parser!(u32).range(1..))]
    pub max_attempts: u32,
    /// Failures one worker reported on one job after which it is kept away from the job
    /// (at least 1). Leases it lost by stopping answering do not count.
    #[arg(long, env = "TESSERA_KEEP_AWAY_AFTER", default_value_t = 2,
          value_parser = clap::value_parser!(u32).range(1..))]
    pub keep_away_after: u32,
    /// How long a worker is kept away from a job it keeps failing, in seconds (at most
    /// 604,800, a week).
    #[arg(long, env = "TESSERA_KEEP_AWAY_SECS", default_value_t = 300,
          value_parser = clap::value_parser!(u64).range(0..=604_800))]
    pub keep_away_secs: u64,
    /// Largest request body for POST /jobs (scene plus textures), in bytes (at least 1).
    #[arg(long, env = "TESSERA_MAX_BODY_BYTES", default_value_t = 64 << 20,
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..))]
    pub max_body_bytes: usize,
    /// Body bytes of all the submissions being received and checked at once (default twice
    /// `--max-body-bytes`; at least `--max-body-bytes`): each holds its declared length, and
    /// a body silent for 10 s is cut (408). A submission that does not fit waits
    /// its turn, up to 30 s, then is answered 503 with Retry-After. (Textures being decoded
    /// are held to `--max-scene-texture-pixels` at once, the same way.)
    #[arg(long, env = "TESSERA_MAX_RECEIVING_BYTES")]
    pub max_receiving_bytes: Option<usize>,
    /// Memory for checking the scenes of submissions at once, in bytes (at least 1 MiB):
    /// each scene is charged 32 times its bytes while it is parsed and checked (the most a
    /// scene of the smallest objects takes). A submission that does not fit waits its turn,
    /// up to 30 s, then is answered 503 with Retry-After.
    #[arg(long, env = "TESSERA_MAX_CHECKING_BYTES", default_value_t = 1 << 30,
          value_parser = clap::value_parser!(u64).range(1 << 20..))]
    pub max_checking_bytes: u64,
    /// Largest image, width × height pixels. The limits below go up to the workers' own
    /// (the tracer's defaults, which `tessera-worker` applies), not past them, so that the
    /// service accepts no job that no worker would build.
    #[arg(long, env = "TESSERA_MAX_PIXELS", default_value_t = 7680 * 4320 * 2,
          value_parser = clap::value_parser!(u64).range(1..=268_435_456))]
    pub max_pixels: u64,
    /// Largest image width or height.
    #[arg(long, env = "TESSERA_MAX_DIMENSION", default_value_t = 16_384,
          value_parser = clap::value_parser!(u32).range(1..=32_768))]
    pub max_dimension: u32,
    /// Most tiles in one job. A job's tiles are stored in the one transaction that holds the
    /// queue's only writer, so no claim or result of another job is stored meanwhile; a job
    /// asking for more is refused with the smallest tile edge that would do, and the
    /// service's own pick grows to that edge.
    #[arg(long, env = "TESSERA_MAX_TILES", default_value_t = 65_536,
          value_parser = clap::value_parser!(u64).range(1..))]
    pub max_tiles: u64,
    /// Most objects in a scene, CSG children included.
    #[arg(long, env = "TESSERA_MAX_OBJECTS", default_value_t = 100_000,
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=1_000_000))]
    pub max_objects: usize,
    /// Deepest CSG nesting.
    #[arg(long, env = "TESSERA_MAX_CSG_DEPTH", default_value_t = 32,
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=64))]
    pub max_csg_depth: usize,
    /// Most texture files per scene.
    #[arg(long, env = "TESSERA_MAX_TEXTURES", default_value_t = 32,
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(0..=256))]
    pub max_textures: usize,
    /// Largest texture, width × height texels (checked from the image's header, before
    /// decoding).
    #[arg(long, env = "TESSERA_MAX_TEXTURE_PIXELS", default_value_t = 16 << 20,
          value_parser = clap::value_parser!(u64).range(1..=64 << 20))]
    pub max_texture_pixels: u64,
    /// Seconds a connection may stay silent (no byte either way) before it is closed, so
    /// that a stalled client cannot hold its connection, and the body it sent, for ever. Keep it
    /// above 60, the longest wait a route offers (`GET /jobs/{id}?wait=`, which is cut to a
    /// second less than this). 1 to 86,400 (a day).
    #[arg(long, env = "TESSERA_IDLE_TIMEOUT_SECS", default_value_t = 120,
          value_parser = clap::value_parser!(u64).range(1..=86_400))]
    pub idle_timeout_secs: u64,
    /// Slowest a submission's body may arrive, in bytes a second averaged from its first
    /// read, judged once it has taken 10 s: a slower body is cut with `408` and its share of
    /// `--max-receiving-bytes` given back. 0 turns the floor off; at most 1 GiB/s.
    #[arg(long, env = "TESSERA_MIN_UPLOAD_RATE", default_value_t = 1_024,
          value_parser = clap::value_parser!(u64).range(0..=1 << 30))]
    pub min_upload_rate: u64,
    /// Longest a submission's body may take to arrive, in seconds from its first read: one
    /// still arriving then is cut with `408`. 1 to 86,400 (a day).
    #[arg(long, env = "TESSERA_MAX_UPLOAD_SECS", default_value_t = 600,
          value_parser = clap::value_parser!(u64).range(1..=86_400))]
    pub max_upload_secs: u64,
    /// Most texels of all of a job's textures together (each texel is held while the scene
    /// is checked and rendered: 3 bytes).
    #[arg(long, env = "TESSERA_MAX_SCENE_TEXTURE_PIXELS", default_value_t = 32 << 20,
          value_parser = clap::value_parser!(u64).range(1..=128 << 20))]
    pub max_scene_texture_pixels: u64,
}

impl Config {
    /// Defaults as if no flag were given (tests start from these).
    pub fn defaults() -> Config {
        Config::parse_from(["tessera-service"])
    }

    /// The longest a request may wait without a byte sent (`GET /jobs/{id}?wait=`, a claim's
    /// `wait_ms`): a second under `--idle-timeout-secs`, which would otherwise close the
    /// silent connection with no answer at all.
    pub fn longest_silence(&self) -> std::time::Duration {
        std::time::Duration::from_secs(self.idle_timeout_secs.saturating_sub(1))
    }

    /// The first token flag that cannot be used and why, named as the user gives it.
    pub fn token_problem(&self) -> Option<String> {
        [
            ("--token (or TESSERA_WORKER_TOKEN)", &self.token),
            (
                "--submit-token (or TESSERA_SUBMIT_TOKEN)",
                &self.submit_token,
            ),
            ("--read-token (or TESSERA_READ_TOKEN)", &self.read_token),
        ]
        .into_iter()
        .find_map(|(flag, t)| {
            let why = token_problem(t.as_deref()?)?;
            Some(format!("{flag}: {why}"))
        })
    }

    /// The submission budget in bytes (`--max-receiving-bytes`, or twice the body limit).
    pub fn receiving_bytes(&self) -> usize {
        self.max_receiving_bytes
            .unwrap_or(self.max_body_bytes.saturating_mul(2))
    }

    /// The limits a submitted scene is parsed and built under.
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

    /// The limits a submitted scene's textures are checked and decoded under.
    pub fn texture_limits(&self) -> TextureLimits {
        TextureLimits {
            max_pixels: self.max_texture_pixels,
            max_total_pixels: self.max_scene_texture_pixels,
            ..TextureLimits::default()
        }
    }
}
