//! The end-to-end harness: temporary directories, the service and workers as real processes
//! on real sockets with a real database (a SQLite file, or a database of its own on the test
//! binary's throwaway PostgreSQL server, `tessera_tests::pg`), and a blocking HTTP client.
//!
//! Tests that hold for either backend are written once, as a function taking a [`Backend`],
//! and [`on_both!`] makes them the tests `NAME::sqlite` and `NAME::postgres`.
//!
//! Waiting is always for an observable condition (a line on stdout, a job state) with a
//! deadline, never a fixed sleep.

#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use serde_json::Value;
use tessera_tracer::{DirAssets, Limits, Scene, TextureLimits, encode_png, parse};

pub const SERVICE: &str = env!("CARGO_BIN_EXE_e2e-service");
pub const WORKER: &str = env!("CARGO_BIN_EXE_e2e-worker");

pub use tessera_tests::pg;

/// Which database a test's services run on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backend {
    Sqlite,
    Postgres,
}

/// Runs test function `$name` (a `fn` taking a [`Backend`]) on each backend: the tests
/// `$name::sqlite` and `$name::postgres`.
#[macro_export]
macro_rules! on_both {
    ($name:ident) => {
        mod $name {
            use super::common::Backend;

            #[test]
            fn sqlite() {
                super::$name(Backend::Sqlite)
            }

            #[test]
            fn postgres() {
                super::$name(Backend::Postgres)
            }
        }
    };
}

/// A test's directory, removed when dropped, and its database: `tessera.db` in it, or a
/// database of its own on the PostgreSQL server, dropped with it.
pub struct TempDir {
    path: PathBuf,
    database: Option<pg::Database>,
    /// A small file system of its own mounted in it, which holds the SQLite file.
    disk: Option<PathBuf>,
}

impl TempDir {
    /// A directory whose services use a SQLite file in it.
    pub fn new(tag: &str) -> TempDir {
        TempDir::on(Backend::Sqlite, tag)
    }

    /// A directory whose services use `backend`.
    pub fn on(backend: Backend, tag: &str) -> TempDir {
        static N: AtomicU32 = AtomicU32::new(0);
        let p = std::env::temp_dir().join(format!(
            "tessera-e2e-{tag}-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = std::fs::remove_dir_all(&p);
        std::fs::create_dir_all(&p).expect("temp dir can be created");
        TempDir {
            path: p,
            database: (backend == Backend::Postgres).then(pg::database),
            disk: None,
        }
    }

    /// A directory whose services use a SQLite file on a disk of `bytes` of its own (a tmpfs
    /// mounted in it, unmounted when dropped), which a test may fill; the logs stay off it.
    /// `None` where this process may not mount one (not root, or a container that forbids
    /// it).
    pub fn on_small_disk(tag: &str, bytes: u64) -> Option<TempDir> {
        let mut dir = TempDir::new(tag);
        let disk = dir.path.join("disk");
        std::fs::create_dir_all(&disk).expect("a mount point");
        let mounted = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={bytes}"), "tmpfs"])
            .arg(&disk)
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        dir.disk = Some(disk);
        mounted.then_some(dir)
    }

    /// The SQLite file of the services (unused on PostgreSQL).
    pub fn db_file(&self) -> PathBuf {
        self.disk.as_ref().unwrap_or(&self.path).join("tessera.db")
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The services' `--database`.
    pub fn database(&self) -> String {
        match &self.database {
            Some(db) => db.url.clone(),
            None => format!("sqlite://{}", self.db_file().display()),
        }
    }

    /// The PostgreSQL database's name; `None` on SQLite.
    pub fn pg_name(&self) -> Option<&str> {
        self.database.as_ref().map(|d| d.name.as_str())
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        if let Some(disk) = &self.disk {
            let _ = Command::new("umount")
                .arg("-l")
                .arg(disk)
                .stderr(Stdio::null())
                .status();
        }
        let _ = std::fs::remove_dir_all(&self.path);
    }
}

pub fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples")
}

pub fn signal(child: &Child, sig: &str) {
    let _ = Command::new("kill")
        .arg(format!("-{sig}"))
        .arg(child.id().to_string())
        .status();
}

pub fn wait_exit(child: &mut Child, within: Duration) -> Option<std::process::ExitStatus> {
    let deadline = Instant::now() + within;
    loop {
        if let Ok(Some(s)) = child.try_wait() {
            return Some(s);
        }
        if Instant::now() > deadline {
            return None;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// A `tessera-service` process.
pub struct Service {
    child: Child,
    pub url: String,
    /// The SQLite file, when it runs on one.
    pub db: PathBuf,
    pub log: PathBuf,
}

impl Service {
    /// Starts a service on a free loopback port with `dir`'s database.
    pub fn start(dir: &TempDir, args: &[&str]) -> Service {
        Service::start_on(dir, "127.0.0.1:0", args)
    }

    /// Starts a service on `listen` (a fixed port, to restart on the same address).
    pub fn start_on(dir: &TempDir, listen: &str, args: &[&str]) -> Service {
        let db = dir.db_file();
        let log = dir.path().join(format!(
            "service-{}.log",
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos())
        ));
        let mut child = Command::new(SERVICE)
            .arg("--listen")
            .arg(listen)
            .arg("--database")
            .arg(dir.database())
            .args(args)
            .env("RUST_LOG", "info,sqlx=warn")
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&log).expect("log file can be created"))
            .spawn()
            .expect("service starts");
        let stdout = child.stdout.take().expect("stdout is piped");
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if let Some(url) = line.strip_prefix("tessera-service listening on ") {
                    let _ = tx.send(url.trim().to_string());
                }
            }
        });
        let url = match rx.recv_timeout(Duration::from_secs(30)) {
            Ok(u) => u,
            Err(_) => {
                let _ = child.kill();
                panic!(
                    "service did not start:\n{}",
                    std::fs::read_to_string(&log).unwrap_or_default()
                );
            }
        };
        Service {
            child,
            url,
            db,
            log,
        }
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// SIGTERM, then waits for a clean exit.
    pub fn terminate(&mut self) -> std::process::ExitStatus {
        signal(&self.child, "TERM");
        wait_exit(&mut self.child, Duration::from_secs(60)).expect("service exits after SIGTERM")
    }

    pub fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    pub fn get(&self, path: &str) -> reqwest::blocking::Response {
        client()
            .get(format!("{}{path}", self.url))
            .send()
            .expect("service answers")
    }

    pub fn get_json(&self, path: &str) -> Value {
        self.get(path).json().expect("JSON answer")
    }

    /// `POST /worker/claim` as worker `name`, without a token: the raw answer.
    pub fn claim(&self, name: &str) -> reqwest::blocking::Response {
        client()
            .post(format!("{}/worker/claim", self.url))
            .json(&serde_json::json!({ "worker": name }))
            .send()
            .expect("service answers")
    }

    /// Submits a raw scene; panics unless the answer is 201.
    pub fn submit(&self, scene: &str, query: &str) -> Value {
        let r = client()
            .post(format!("{}/jobs{query}", self.url))
            .body(scene.to_string())
            .send()
            .expect("service answers");
        let status = r.status();
        let body: Value = r.json().expect("JSON answer");
        assert_eq!(status, 201, "submit failed: {body}");
        body
    }

    /// Submits a raw scene (panics unless the answer is 201) and returns the job's id.
    pub fn submit_id(&self, scene: &str, query: &str) -> String {
        self.submit(scene, query)["id"]
            .as_str()
            .expect("a job id")
            .to_string()
    }

    /// Waits (`GET /jobs/{id}?wait=`, a few seconds per request) until the job is no
    /// longer queued or running.
    pub fn wait_finished(&self, id: &str, within: Duration) -> Value {
        let deadline = Instant::now() + within;
        loop {
            let job = self.get_json(&format!("/jobs/{id}?wait=5"));
            let state = job["state"].as_str().unwrap_or("").to_string();
            if !matches!(state.as_str(), "queued" | "running") {
                return job;
            }
            assert!(
                Instant::now() < deadline,
                "job {id} not finished in {within:?}: {job}\n{}",
                self.log()
            );
        }
    }

    /// The finished image; panics unless the answer is 200 image/png.
    pub fn image(&self, id: &str) -> Vec<u8> {
        let r = self.get(&format!("/jobs/{id}/image.png"));
        assert_eq!(r.status(), 200, "image of {id}");
        assert_eq!(r.headers()["content-type"], "image/png");
        r.bytes().expect("image body").to_vec()
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A `tessera-worker` process.
pub struct Worker {
    child: Child,
    pub name: String,
}

impl Worker {
    pub fn start(url: &str, name: &str, args: &[&str]) -> Worker {
        let child = Command::new(WORKER)
            .args([
                "--server",
                url,
                "--threads",
                "1",
                "--idle-max-ms",
                "50",
                "--name",
                name,
            ])
            .args(args)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("worker starts");
        Worker {
            child,
            name: name.to_string(),
        }
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    pub fn kill9(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    pub fn terminate(&mut self) -> std::process::ExitStatus {
        signal(&self.child, "TERM");
        wait_exit(&mut self.child, Duration::from_secs(60)).expect("worker exits after SIGTERM")
    }

    pub fn try_wait(&mut self) -> Option<std::process::ExitStatus> {
        self.child.try_wait().ok().flatten()
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Asserts that `r` is a `400` whose JSON `error` mentions `needle`; returns the body.
pub fn refused(r: reqwest::blocking::Response, needle: &str) -> Value {
    assert_eq!(r.status(), 400);
    let e: Value = r.json().expect("a JSON error");
    assert!(
        e["error"].as_str().is_some_and(|m| m.contains(needle)),
        "{needle:?} in {e}"
    );
    e
}

/// A scene error's `(line, column)`.
pub fn line_col(e: &Value) -> (Option<u64>, Option<u64>) {
    (e["line"].as_u64(), e["column"].as_u64())
}

pub fn client() -> reqwest::blocking::Client {
    reqwest::blocking::Client::builder()
        .timeout(Duration::from_secs(60))
        .build()
        .expect("HTTP client builds")
}

/// What `tessera-render` writes for `path` (same parse, textures from the scene's directory,
/// same renderer and encoder), with optional sampler overrides.
pub fn local_png(path: &Path, sampler: Option<&str>, samples: Option<u32>) -> Vec<u8> {
    let source = std::fs::read_to_string(path).expect("scene readable");
    local_png_from(
        &source,
        path.parent().unwrap_or(Path::new(".")),
        sampler,
        samples,
    )
}

pub fn local_png_from(
    source: &str,
    dir: &Path,
    sampler: Option<&str>,
    samples: Option<u32>,
) -> Vec<u8> {
    let limits = Limits::default();
    let mut desc = parse(source, &limits).expect("scene parses");
    desc.sampler = desc
        .sampler
        .with_overrides(sampler, samples, None, limits.max_samples)
        .expect("valid override");
    let scene =
        Scene::build(&desc, &DirAssets::new(dir), &TextureLimits::default()).expect("scene builds");
    let (rgb, _) = scene.render_image(32, |_| {});
    encode_png(scene.width, scene.height, &rgb).expect("PNG encodes")
}

/// Waits until `cond` holds, polling; panics with `what` after `within`.
pub fn wait_until(what: &str, within: Duration, mut cond: impl FnMut() -> bool) {
    let deadline = Instant::now() + within;
    while !cond() {
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(10));
    }
}
