//! `tessera-bench farm`: what the farm costs. The service runs as a child process (this
//! program started again as `__service`), exactly as `tessera-service` would, and the figures
//! are measured over HTTP:
//!
//! - overhead: a job through the service with local workers on all threads, against the
//!   tracer rendering the same image on the same threads in this process (`tessera-render`'s
//!   code path), with the PNGs compared byte for byte;
//! - scaling: one local worker against two;
//! - tile size: both jobs at several tile sizes (full mode), the measurement behind the
//!   service's automatic tile size;
//! - queue: claims plus results per second with no-op workers (they post black tiles), on
//!   SQLite and on PostgreSQL through one replica and through two, with the service's CPU
//!   per stored tile;
//! - postgres: the overhead job with the queue on PostgreSQL;
//! - memory: the service process's peak resident memory while it takes in and assembles a
//!   7680×4320 image, against the image's RGBA8 size.
//!
//! Times are medians of repeated runs; ratios compare runs made in this same process.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use serde_json::Value;
use tessera_tracer::{Limits, MemoryAssets, Scene, TextureLimits, encode_png, parse};

use crate::stats::Spread;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Small images and single runs (seconds, for CI).
    #[arg(long)]
    pub quick: bool,
    /// Threads for the overhead comparison (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Repetitions per timing (median reported).
    #[arg(long, default_value_t = 5)]
    pub runs: usize,
    /// A tile edge for the overhead and scaling jobs (default: the service's choice).
    #[arg(long)]
    pub tile: Option<u32>,
    /// Only these parts (overhead, scaling, tiles, preview, queue, postgres, memory);
    /// default all.
    #[arg(long, value_delimiter = ',')]
    pub parts: Vec<String>,
    /// A PostgreSQL server for the PostgreSQL figures, as a URL whose user may create
    /// databases (`postgres://USER@HOST:PORT/postgres`); default: a throwaway server from
    /// the `postgresql` package's binaries, started for the run (skipped without them).
    #[arg(long, env = "TESSERA_BENCH_POSTGRES")]
    pub postgres: Option<String>,
}

impl Args {
    fn wants(&self, part: &str) -> bool {
        self.parts.is_empty() || self.parts.iter().any(|p| p == part)
    }
}

const SCENE: &str = include_str!("../scenes/mirrors.ray");

/// The mirrors bench scene at `w × h`.
fn scene_at(w: u32, h: u32) -> String {
    SCENE
        .lines()
        .map(|l| {
            let t = l.trim_start();
            if t.starts_with("width") {
                format!("width = {w}")
            } else if t.starts_with("height") {
                format!("height = {h}")
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// CPU ticks of a service's threads by kind (see [`Service::thread_cpu`]).
#[derive(Debug, Default, Clone, Copy)]
struct ThreadCpu {
    render: u64,
    sqlite: u64,
    other: u64,
}

impl ThreadCpu {
    /// What the service's own threads (tokio's, SQLite's) used between two readings, as
    /// shares of what its render threads used: the farm's own work, on a measure that the
    /// host's drifting speed scales alike on both sides.
    fn shares_since(&self, before: &ThreadCpu) -> Option<(f64, f64)> {
        let render = self.render.checked_sub(before.render)?;
        (render > 0).then(|| {
            let share = |now: u64, then: u64| now.saturating_sub(then) as f64 / render as f64;
            (
                share(self.other, before.other),
                share(self.sqlite, before.sqlite),
            )
        })
    }
}

/// A service child process.
struct Service {
    child: Child,
    url: String,
    _dir: TempDir,
}

struct TempDir(PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

impl Service {
    /// A service on a fresh SQLite database of its own.
    fn start<S: AsRef<std::ffi::OsStr>>(extra: &[S]) -> Result<Service> {
        Service::start_on(None, extra)
    }

    /// A service on `database` (a fresh SQLite database of its own when `None`).
    fn start_on<S: AsRef<std::ffi::OsStr>>(database: Option<&str>, extra: &[S]) -> Result<Service> {
        static N: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let dir = std::env::temp_dir().join(format!(
            "tessera-bench-farm-{}-{}",
            std::process::id(),
            N.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
        ));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir)?;
        let mut child = Command::new(std::env::current_exe()?)
            .arg("__service")
            .args(["--listen", "127.0.0.1:0", "--database"])
            .arg(database.map_or_else(
                || format!("sqlite://{}", dir.join("bench.db").display()),
                str::to_string,
            ))
            .args(extra)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .context("starting the service")?;
        let stdout = child.stdout.take().context("service stdout")?;
        let mut line = String::new();
        BufReader::new(stdout).read_line(&mut line)?;
        let url = line
            .trim()
            .strip_prefix("tessera-service listening on ")
            .with_context(|| format!("unexpected service output `{line}`"))?
            .to_string();
        Ok(Service {
            child,
            url,
            _dir: TempDir(dir),
        })
    }

    /// CPU time used so far by the service's threads (Linux), in clock ticks, summed by
    /// kind: the local workers' render threads, SQLite's connection threads, and the rest
    /// (tokio's threads: HTTP on both sides, the queue's async code, the PNG bands). Only
    /// ratios of these are reported, so the tick's length does not matter.
    fn thread_cpu(&self) -> Option<ThreadCpu> {
        let tasks = std::fs::read_dir(format!("/proc/{}/task", self.child.id())).ok()?;
        let mut cpu = ThreadCpu::default();
        for task in tasks.flatten() {
            let path = task.path();
            let (Ok(name), Ok(stat)) = (
                std::fs::read_to_string(path.join("comm")),
                std::fs::read_to_string(path.join("stat")),
            ) else {
                continue; // the thread ended meanwhile
            };
            // Fields after the command name (which may hold spaces) start at the state,
            // field 3; utime and stime are fields 14 and 15.
            let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
            let ticks: u64 =
                fields.get(11)?.parse::<u64>().ok()? + fields.get(12)?.parse::<u64>().ok()?;
            if name.starts_with("tessera-render") {
                cpu.render += ticks;
            } else if name.starts_with("sqlx-sqlite") {
                cpu.sqlite += ticks;
            } else {
                cpu.other += ticks;
            }
        }
        Some(cpu)
    }

    /// CPU time the whole service process used so far (Linux), in clock ticks.
    fn process_cpu(&self) -> Option<u64> {
        let stat = std::fs::read_to_string(format!("/proc/{}/stat", self.child.id())).ok()?;
        let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
        Some(fields.get(11)?.parse::<u64>().ok()? + fields.get(12)?.parse::<u64>().ok()?)
    }

    /// Peak resident memory so far (Linux), in bytes.
    fn peak_rss(&self) -> Option<u64> {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.child.id())).ok()?;
        let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
        let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
        Some(kb * 1024)
    }

    /// Submits a scene, waits until it is done, downloads the PNG; returns it and the time.
    fn render(
        &self,
        http: &reqwest::blocking::Client,
        scene: &str,
        query: &str,
    ) -> Result<(Vec<u8>, Duration)> {
        self.render_job(http, scene, query)
            .map(|(png, t, _)| (png, t))
    }

    /// Submits `scene` with `query`; the job as the service answers it (`201`).
    fn submit(&self, http: &reqwest::blocking::Client, scene: &str, query: &str) -> Result<Value> {
        let r = http
            .post(format!("{}/jobs{query}", self.url))
            .body(scene.to_string())
            .send()?;
        if r.status() != 201 {
            bail!("submit: {} {}", r.status(), r.text().unwrap_or_default());
        }
        Ok(r.json()?)
    }

    /// As [`Service::render`], also returning the tile edge the service used.
    fn render_job(
        &self,
        http: &reqwest::blocking::Client,
        scene: &str,
        query: &str,
    ) -> Result<(Vec<u8>, Duration, u64)> {
        let start = Instant::now();
        let job = self.submit(http, scene, query)?;
        let id = job["id"].as_str().context("job id")?.to_string();
        let tile = job["tile"].as_u64().context("job tile")?;
        loop {
            // The service answers as soon as the job ends (or after 30 s, to look again).
            let j: Value = http
                .get(format!("{}/jobs/{id}?wait=30", self.url))
                .send()?
                .json()?;
            match j["state"].as_str() {
                Some("done") => break,
                Some("queued" | "running") => {}
                _ => bail!("job ended: {j}"),
            }
        }
        let png = http
            .get(format!("{}/jobs/{id}/image.png", self.url))
            .send()?
            .bytes()?
            .to_vec();
        Ok((png, start.elapsed(), tile))
    }
}

/// What watching jobs cost: previews fetched whole and their time, and those answered 304.
#[derive(Debug, Default)]
struct Watch {
    full: u32,
    not_modified: u32,
    time: Duration,
    longest: Duration,
    bytes: u64,
}

impl Watch {
    fn add(&mut self, other: &Watch) {
        self.full += other.full;
        self.not_modified += other.not_modified;
        self.time += other.time;
        self.longest = self.longest.max(other.longest);
        self.bytes += other.bytes;
    }

    fn mean_ms(&self) -> f64 {
        self.time.as_secs_f64() * 1e3 / f64::from(self.full.max(1))
    }

    fn mean_kib(&self) -> f64 {
        self.bytes as f64 / 1024.0 / f64::from(self.full.max(1))
    }
}

impl Service {
    /// As [`Service::render`], with the job watched as its page watches it: its events
    /// open, its preview fetched every second with the `ETag` held. Returns what the
    /// previews cost too.
    fn render_watched(
        &self,
        http: &reqwest::blocking::Client,
        scene: &str,
        query: &str,
    ) -> Result<(Vec<u8>, Duration, Watch)> {
        let start = Instant::now();
        let job = self.submit(http, scene, query)?;
        let id = job["id"].as_str().context("job id")?.to_string();
        let events = http
            .get(format!("{}/jobs/{id}/events", self.url))
            .timeout(Duration::from_secs(3600))
            .send()?;
        // Read to its end (the job's end) on a thread of its own, as a browser would.
        let reader =
            std::thread::spawn(move || std::io::copy(&mut { events }, &mut std::io::sink()));
        let mut watch = Watch::default();
        let mut etag: Option<String> = None;
        loop {
            let asked = Instant::now();
            let mut req = http.get(format!("{}/jobs/{id}/preview.png", self.url));
            if let Some(tag) = &etag {
                req = req.header("If-None-Match", tag);
            }
            let r = req.send()?;
            if r.status() == 304 {
                watch.not_modified += 1;
            } else if r.status() == 200 {
                etag = r
                    .headers()
                    .get("etag")
                    .and_then(|v| v.to_str().ok())
                    .map(str::to_string);
                watch.bytes += r.bytes()?.len() as u64;
                let took = asked.elapsed();
                watch.full += 1;
                watch.time += took;
                watch.longest = watch.longest.max(took);
            } else {
                bail!("preview: {}", r.status());
            }
            let j: Value = http
                .get(format!("{}/jobs/{id}?wait=1", self.url))
                .send()?
                .json()?;
            match j["state"].as_str() {
                Some("done") => break,
                Some("queued" | "running") => {}
                _ => bail!("job ended: {j}"),
            }
        }
        let elapsed = start.elapsed();
        let _ = reader.join();
        let png = http
            .get(format!("{}/jobs/{id}/image.png", self.url))
            .send()?
            .bytes()?
            .to_vec();
        Ok((png, elapsed, watch))
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A service with `workers` local workers, and `--tile` when given.
fn service_args(workers: usize, tile: Option<u32>) -> Vec<String> {
    let mut a = vec!["--local-workers".to_string(), workers.to_string()];
    if let Some(t) = tile {
        a.extend(["--tile".to_string(), t.to_string()]);
    }
    a
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

/// What `tessera-render --threads n` does, timed: parse, build, render in its tiles
/// ([`tessera_tracer::local_tile`]) on a pool of `n` threads, encode the PNG.
fn local(scene: &str, threads: usize, samples: Option<u32>) -> Result<(Vec<u8>, Duration)> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    let start = Instant::now();
    let mut desc = parse(scene, &Limits::default())?;
    if let Some(n) = samples {
        desc.sampler = desc
            .sampler
            .with_overrides(Some("jitter"), Some(n), None, 32)
            .map_err(anyhow::Error::msg)?;
    }
    let s = Scene::build(&desc, &MemoryAssets::new(), &TextureLimits::default())?;
    let tile = tessera_tracer::local_tile(s.width, s.height, threads);
    let (rgb, _) = pool.install(|| s.render_image(tile, |_| {}));
    let png = encode_png(s.width, s.height, &rgb)?;
    Ok((png, start.elapsed()))
}

fn runs(
    n: usize,
    mut f: impl FnMut() -> Result<(Vec<u8>, Duration)>,
) -> Result<(Vec<u8>, Duration)> {
    let mut times = Vec::new();
    let mut last = Vec::new();
    for _ in 0..n.max(1) {
        let (png, t) = f()?;
        times.push(t);
        last = png;
    }
    Ok((last, median(times)))
}

/// Runs in-process no-op workers against `url` until `done` says stop.
fn noop_workers(
    url: &str,
    workers: usize,
    threads: usize,
) -> Result<(tokio::runtime::Runtime, tokio::sync::watch::Sender<bool>)> {
    noop_workers_on(&[url], workers, threads)
}

/// Runs in-process no-op workers, dealt in turn to `urls`, until `done` says stop.
fn noop_workers_on(
    urls: &[&str],
    workers: usize,
    threads: usize,
) -> Result<(tokio::runtime::Runtime, tokio::sync::watch::Sender<bool>)> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    let (tx, rx) = tokio::sync::watch::channel(false);
    for i in 0..workers {
        let mut cfg = tessera_worker::WorkerConfig::new(urls[i % urls.len()]);
        cfg.noop = true;
        cfg.threads = threads;
        cfg.name = format!("noop-{i}");
        cfg.idle_max = Duration::from_millis(20);
        let mut rx = rx.clone();
        rt.spawn(async move {
            let stop = async move {
                let _ = rx.wait_for(|s| *s).await;
            };
            let _ = tessera_worker::run(cfg, stop).await;
        });
    }
    Ok((rt, tx))
}

pub fn run(args: &Args) -> Result<()> {
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let reps = if args.quick { 1 } else { args.runs };
    let (w, h) = if args.quick { (320, 180) } else { (1920, 1080) };
    let http = reqwest::blocking::Client::builder()
        .timeout(Duration::from_secs(600))
        .build()?;
    let scene = scene_at(w, h);

    println!("farm: mirrors scene at {w}×{h}, {threads} threads, median of {reps}");
    // Two workloads: the scene as written (1 ray per pixel, a fraction of a second: the
    // farm's fixed and per-tile costs show) and with 4×4 jittered samples per pixel (a
    // render worth distributing).
    for samples in [None, Some(4)] {
        let (query, label) = match samples {
            Some(n) => (
                format!("?sampler=jitter&samples={n}"),
                format!("jitter {n}×{n}"),
            ),
            None => (String::new(), "1 ray/pixel".to_string()),
        };
        if args.wants("overhead") {
            // Local and farm runs alternate, and the figure is the median of each pair's
            // ratio: on a shared machine whose speed drifts from minute to minute, a pair run
            // back to back sees the same machine.
            let svc = Service::start(&service_args(threads, args.tile))?;
            let cpu_before = svc.thread_cpu();
            let (mut t_local, mut t_farm, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
            let mut tile = 0;
            for _ in 0..reps.max(1) {
                let (local_png, tl) = local(&scene, threads, samples)?;
                let (farm_png, tf, edge) = svc.render_job(&http, &scene, &query)?;
                if local_png != farm_png {
                    bail!("the farm's PNG differs from the local render");
                }
                tile = edge;
                ratios.push(tf.as_secs_f64() / tl.as_secs_f64());
                t_local.push(tl);
                t_farm.push(tf);
            }
            let cpu_after = svc.thread_cpu();
            drop(svc);
            let ratio = Spread::of(ratios);
            let pct = |r: f64| (r - 1.0) * 100.0;
            let choice = if args.tile.is_some() {
                "set by --tile"
            } else {
                "the service's choice"
            };
            println!(
                "  overhead ({label}): tessera-render path {:.3} s, farm ({tile} px tiles, {choice}; {threads} local workers) {:.3} s: {:+.1} % (median of {} back-to-back pairs; range {:+.1} to {:+.1} %; PNG identical: yes)",
                median(t_local).as_secs_f64(),
                median(t_farm).as_secs_f64(),
                pct(ratio.median),
                ratio.count,
                pct(ratio.lo),
                pct(ratio.hi),
            );
            if let Some((other, sqlite)) = cpu_after
                .zip(cpu_before)
                .and_then(|(after, before)| after.shares_since(&before))
            {
                println!(
                    "    the service's own CPU over those jobs, as a share of its render threads': {:.1} % (tokio's threads {:.1} %: HTTP, the queue, the PNG bands, which tessera-render encodes too; SQLite's {:.1} %)",
                    (other + sqlite) * 100.0,
                    other * 100.0,
                    sqlite * 100.0,
                );
            }
        }
        if samples.is_some() && args.wants("preview") {
            // A job watched as the job page watches it (its preview fetched every second
            // with the ETag held, its events open) against the same job unwatched, in
            // back-to-back pairs on one service.
            let svc = Service::start(&service_args(threads, args.tile))?;
            let (mut plain, mut watched, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
            let mut fetches = Watch::default();
            for _ in 0..reps.max(1) {
                let (png_plain, tp) = svc.render(&http, &scene, &query)?;
                let (png_watched, tw, seen) = svc.render_watched(&http, &scene, &query)?;
                if png_plain != png_watched {
                    bail!("a watched job's PNG differs");
                }
                fetches.add(&seen);
                ratios.push(tw.as_secs_f64() / tp.as_secs_f64());
                plain.push(tp);
                watched.push(tw);
            }
            drop(svc);
            let ratio = Spread::of(ratios);
            let pct = |r: f64| (r - 1.0) * 100.0;
            println!(
                "  preview ({label}): unwatched {:.3} s, watched {:.3} s: {:+.1} % (median of {} back-to-back pairs; range {:+.1} to {:+.1} %; PNG identical: yes); {} previews fetched, {:.1} ms each on average ({:.1} ms the longest, {:.0} KiB on average), {} answered 304",
                median(plain).as_secs_f64(),
                median(watched).as_secs_f64(),
                pct(ratio.median),
                ratio.count,
                pct(ratio.lo),
                pct(ratio.hi),
                fetches.full,
                fetches.mean_ms(),
                fetches.longest.as_secs_f64() * 1e3,
                fetches.mean_kib(),
                fetches.not_modified,
            );
        }
        if !args.quick && args.wants("tiles") {
            // The measurement behind the automatic tile size (`auto_tile` in the service).
            let svc = Service::start(&["--local-workers", &threads.to_string()])?;
            let mut line = format!("  tile size ({label}):");
            for tile in [32, 64, 128, 256, 512] {
                let sep = if query.is_empty() { '?' } else { '&' };
                let q = format!("{query}{sep}tile={tile}");
                let (_, t) = runs(reps, || svc.render(&http, &scene, &q))?;
                line.push_str(&format!("  {tile} px {:.3} s", t.as_secs_f64()));
            }
            println!("{line}");
        }
        if args.wants("scaling") {
            // Back-to-back pairs, as for the overhead: both services stay up (the idle one's
            // workers wait in long-polled claims), and each pair runs one job on each.
            let one = Service::start(&service_args(1, args.tile))?;
            let two = Service::start(&service_args(2, args.tile))?;
            let (mut t1s, mut t2s, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
            for _ in 0..reps.max(1) {
                let (_, t1) = one.render(&http, &scene, &query)?;
                let (_, t2) = two.render(&http, &scene, &query)?;
                ratios.push(t1.as_secs_f64() / t2.as_secs_f64());
                t1s.push(t1);
                t2s.push(t2);
            }
            drop((one, two));
            let ratio = Spread::of(ratios);
            println!(
                "  scaling ({label}): 1 worker {:.3} s, 2 workers {:.3} s: {:.2}× (median of {} back-to-back pairs; range {:.2}× to {:.2}×)",
                median(t1s).as_secs_f64(),
                median(t2s).as_secs_f64(),
                ratio.median,
                ratio.count,
                ratio.lo,
                ratio.hi,
            );
        }
    }

    // The PostgreSQL server of the run, if any (see `--postgres`).
    let postgres = if args.wants("queue") || args.wants("postgres") {
        Postgres::find(args.postgres.as_deref())
    } else {
        Err("not asked for".into())
    };
    if let Err(why) = &postgres
        && why != "not asked for"
    {
        println!("  (PostgreSQL figures skipped: {why})");
    }
    if args.wants("queue") {
        // The queue: no-op workers, 8-pixel tiles, the same job on each database.
        let (qw, qh): (u32, u32) = if args.quick { (320, 240) } else { (1920, 1080) };
        let tiles = u64::from(qw.div_ceil(8) * qh.div_ceil(8));
        let queue = |label: &str, dbs: &[Option<String>]| -> Result<()> {
            let svcs = dbs
                .iter()
                .map(|db| Service::start_on(db.as_deref(), &["--local-workers", "0"]))
                .collect::<Result<Vec<_>>>()?;
            let urls: Vec<&str> = svcs.iter().map(|s| s.url.as_str()).collect();
            let (rt, stop) = noop_workers_on(&urls, 4, 4)?;
            let cpu_before: Option<u64> = svcs.iter().map(Service::process_cpu).sum();
            let (_, tq) = svcs[0].render(&http, &scene_at(qw, qh), "?tile=8")?;
            let cpu_after: Option<u64> = svcs.iter().map(Service::process_cpu).sum();
            let _ = stop.send(true);
            rt.shutdown_timeout(Duration::from_secs(5));
            drop(svcs);
            let per_s = 2.0 * tiles as f64 / tq.as_secs_f64();
            let cpu = cpu_after.zip(cpu_before).map(|(a, b)| {
                // Clock ticks are 1/100 s on Linux (`getconf CLK_TCK`).
                (a.saturating_sub(b)) as f64 * 10.0 / tiles as f64
            });
            println!(
                "  queue ({label}): {tiles} tiles claimed and posted by 16 no-op worker loops in {:.3} s: {:.0} claims+results/s; the service's CPU {} ms per stored tile",
                tq.as_secs_f64(),
                per_s,
                cpu.map_or("?".to_string(), |c| format!("{c:.2}")),
            );
            Ok(())
        };
        queue("SQLite", &[None])?;
        if let Ok(pg) = &postgres {
            let db = pg.database()?;
            queue("PostgreSQL, one replica", &[Some(db.clone())])?;
            let db = pg.database()?;
            queue("PostgreSQL, two replicas", &[Some(db.clone()), Some(db)])?;
        }
    }
    if args.wants("postgres")
        && let Ok(pg) = &postgres
    {
        // The overhead job of the first workload, with the queue on PostgreSQL.
        let svc = Service::start_on(Some(&pg.database()?), &service_args(threads, args.tile))?;
        let (mut t_local, mut t_farm, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..reps.max(1) {
            let (local_png, tl) = local(&scene, threads, Some(4))?;
            let (farm_png, tf) = svc.render(&http, &scene, "?sampler=jitter&samples=4")?;
            if local_png != farm_png {
                bail!("the farm's PNG on PostgreSQL differs from the local render");
            }
            ratios.push(tf.as_secs_f64() / tl.as_secs_f64());
            t_local.push(tl);
            t_farm.push(tf);
        }
        drop(svc);
        let ratio = Spread::of(ratios);
        let pct = |r: f64| (r - 1.0) * 100.0;
        println!(
            "  overhead on PostgreSQL (jitter 4×4): tessera-render path {:.3} s, farm ({threads} local workers) {:.3} s: {:+.1} % (median of {} back-to-back pairs; range {:+.1} to {:+.1} %; PNG identical: yes)",
            median(t_local).as_secs_f64(),
            median(t_farm).as_secs_f64(),
            pct(ratio.median),
            ratio.count,
            pct(ratio.lo),
            pct(ratio.hi),
        );
    }
    if args.wants("memory") {
        // Memory: a large image through no-op workers.
        let (mw, mh): (u32, u32) = if args.quick {
            (1920, 1080)
        } else {
            (7680, 4320)
        };
        let svc = Service::start(&["--local-workers", "0"])?;
        let (rt, stop) = noop_workers(&svc.url, 2, 4)?;
        // The base: the service after a small job.
        svc.render(&http, &scene_at(64, 64), "")?;
        let base = svc.peak_rss().unwrap_or(0);
        let (png, tm) = svc.render(&http, &scene_at(mw, mh), "")?;
        let peak = svc.peak_rss().unwrap_or(0);
        let _ = stop.send(true);
        rt.shutdown_timeout(Duration::from_secs(5));
        drop(svc);
        let rgba = u64::from(mw) * u64::from(mh) * 4;
        let mib = |b: u64| b as f64 / (1024.0 * 1024.0);
        println!(
            "  memory: {mw}×{mh} ({:.0} MiB as RGBA8, PNG {:.1} MiB, {:.2} s): service peak {:.1} MiB, base {:.1} MiB, peak − base = {:.2} × RGBA8",
            mib(rgba),
            mib(png.len() as u64),
            tm.as_secs_f64(),
            mib(peak),
            mib(base),
            (peak.saturating_sub(base)) as f64 / rgba as f64
        );
    }
    Ok(())
}

/// The PostgreSQL server of a run: one given by `--postgres`, or a throwaway one.
enum Postgres {
    /// A server at this URL, whose user may create databases.
    Given(String),
    /// The throwaway server (`tessera_tests::pg`), for this process's life.
    Throwaway,
}

impl Postgres {
    /// The server to use, or why there is none.
    fn find(given: Option<&str>) -> std::result::Result<Postgres, String> {
        if let Some(url) = given {
            return Ok(Postgres::Given(url.to_string()));
        }
        tessera_tests::pg::try_server().map(|_| Postgres::Throwaway)
    }

    /// A fresh database for one service (left on the server for inspection when given,
    /// dropped with the throwaway server otherwise), as a URL.
    fn database(&self) -> Result<String> {
        static N: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        match self {
            Postgres::Throwaway => {
                let db = tessera_tests::pg::database();
                let url = db.url.clone();
                // Kept until the server goes, with the process.
                std::mem::forget(db);
                Ok(url)
            }
            Postgres::Given(url) => {
                let name = format!(
                    "tessera_bench_{}_{}",
                    std::process::id(),
                    N.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
                );
                let out = Command::new("psql")
                    .arg(url)
                    .args(["-v", "ON_ERROR_STOP=1", "-qc"])
                    .arg(format!("CREATE DATABASE {name}"))
                    .output()
                    .context("running psql to create the benchmark's database")?;
                if !out.status.success() {
                    bail!(
                        "creating a database: {}",
                        String::from_utf8_lossy(&out.stderr)
                    );
                }
                let base = url.rsplit_once('/').map_or(url.as_str(), |(b, _)| b);
                Ok(format!("{base}/{name}"))
            }
        }
    }
}
