//! The web pages in a real browser: Playwright (`playwright-core`) driving Debian's Chromium,
//! headless, against a real service and worker. The scripts are in `tests/browser/`:
//! `list.mjs` (the job list: pages, the form, textures, refusals, cancel and delete, a list
//! that cannot be loaded, a phone's width), `guarded.mjs` (a submit token and a small body
//! limit), `watch.mjs` (a job's page: the tile map, the preview filling in, the worker
//! holding tiles, priority, cancel, delete, the API page).
//!
//! Each needs `node`, Chromium and `tests/browser/node_modules` (`npm ci` there), which
//! `.ci/run` installs. Without them the tests are skipped with a note, unless `TESSERA_CI` is
//! set (as `.ci/run` sets it): then a missing tool fails them.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use common::{Service, TempDir, Worker, examples, wait_until};

/// The folder of the browser scripts.
fn scripts() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("browser")
}

/// The browser, from `TESSERA_CHROMIUM` or Debian's path.
fn chromium() -> PathBuf {
    std::env::var_os("TESSERA_CHROMIUM").map_or_else(|| "/usr/bin/chromium".into(), PathBuf::from)
}

/// Whether the browser tests can run here; says what is missing otherwise, and fails where
/// CI requires them.
fn ready() -> bool {
    let mut missing = Vec::new();
    if Command::new("node").arg("--version").output().is_err() {
        missing.push("`node`".to_string());
    }
    if !chromium().exists() {
        missing.push(format!("Chromium at {}", chromium().display()));
    }
    if !scripts().join("node_modules/playwright-core").exists() {
        missing.push("playwright-core (`npm ci` in tests/browser)".to_string());
    }
    if missing.is_empty() {
        return true;
    }
    let why = format!("the browser tests need {}", missing.join(", "));
    assert!(std::env::var_os("TESSERA_CI").is_none(), "{why}");
    eprintln!("skipped: {why}");
    false
}

/// Runs `tests/browser/{script}` against `svc` with `checks`, and returns the steps it
/// reported; fails if it does.
fn run_script(script: &str, svc: &Service, checks: &serde_json::Value) -> Vec<String> {
    let mut node = Command::new("node")
        .arg(scripts().join(script))
        .current_dir(scripts())
        .env("TESSERA_URL", &svc.url)
        .env("TESSERA_CHECKS", checks.to_string())
        .env("TESSERA_CHROMIUM", chromium())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("node starts");
    // Bounded: a page that never settles fails here instead of hanging the suite.
    let mut status = None;
    wait_until(script, Duration::from_secs(240), || {
        status = node.try_wait().ok().flatten();
        status.is_some()
    });
    let out = node.wait_with_output().expect("node's output");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        status.is_some_and(|s| s.success()),
        "{script} failed:\n{stdout}\n{}\n{}",
        String::from_utf8_lossy(&out.stderr),
        svc.log()
    );
    stdout
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter_map(|v| v["step"].as_str().map(str::to_string))
        .collect()
}

/// Jobs the list shows at a time (`PAGE` in `list.js`).
const PAGE: usize = 50;

#[test]
fn the_job_list() {
    if !ready() {
        return;
    }
    let dir = TempDir::new("browser-list");
    // No workers: every job stays queued, so the list holds still while the page reads it.
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    let scene = std::fs::read_to_string(examples().join("thesis.ray")).expect("example");
    let jobs = 2 * PAGE + 5;
    for n in 0..jobs {
        svc.submit(&scene, &format!("?name=job-{n:03}"));
    }
    // 640×480 in 64-pixel tiles: 10 × 8.
    assert!(scene.contains("width = 640\nheight = 480\n"));
    let bad = scene.replacen("height = 480", "height = wide", 1);
    let bad_line = bad
        .lines()
        .position(|l| l == "height = wide")
        .expect("the changed line")
        + 1;
    let checks = serde_json::json!({
        "jobs": jobs,
        "page": PAGE,
        "scene": scene,
        "tile": 64,
        "tiles": 80,
        "bad_scene": bad,
        "bad_line": bad_line,
        "bad_column": "height = ".len() + 1,
        "examples": examples(),
    });
    assert_eq!(
        run_script("list.mjs", &svc, &checks),
        [
            "newest page",
            "older pages",
            "submitted",
            "refused",
            "cancelled and deleted",
            "anchor gone",
            "textures",
            "scene file as bytes",
            "edited scene",
            "list notice",
            "narrow",
        ]
    );
}

/// Body limit of the guarded service: `textures.ray` and its two textures (4,763 bytes) do
/// not fit, `thesis.ray` (379) does.
const SMALL_LIMIT: usize = 4096;

#[test]
fn the_job_list_with_a_token_and_a_small_body_limit() {
    if !ready() {
        return;
    }
    let dir = TempDir::new("browser-guarded");
    let token = "page-secret";
    let limit = SMALL_LIMIT.to_string();
    // No workers (the script plays one), and one attempt a tile, so that a tile reported
    // failed fails its job.
    let svc = Service::start(
        &dir,
        &[
            "--local-workers",
            "0",
            "--max-attempts",
            "1",
            "--submit-token",
            token,
            "--max-body-bytes",
            &limit,
        ],
    );
    let scene = std::fs::read_to_string(examples().join("thesis.ray")).expect("example");
    assert!(scene.contains("width = 640\nheight = 480\n"));
    let checks = serde_json::json!({
        "token": token,
        "limit": SMALL_LIMIT,
        "scene": scene,
        "examples": examples(),
    });
    assert_eq!(
        run_script("guarded.mjs", &svc, &checks),
        [
            "too large",
            "pasted too large",
            "within the limit",
            "token forgotten",
            "cancel refused",
            "failed job deleted",
            "done job asks about its image",
            "cancel of a job gone",
        ]
    );
}

#[test]
fn watching_a_job() {
    if !ready() {
        return;
    }
    let dir = TempDir::new("browser-watch");
    // Leases outlast the test, so that tiles held by the stopped worker stay held.
    let svc = Service::start(&dir, &["--local-workers", "0", "--lease-ms", "300000"]);
    let worker = Worker::start(&svc.url, "browser-worker", &[]);
    // Stopped until the script lets it run; it made no request yet that matters.
    signal_worker(&worker, "STOP");
    let scene = std::fs::read_to_string(examples().join("thesis.ray")).expect("example");
    let checks = serde_json::json!({
        "scene": scene,
        "examples": examples(),
        "tile": 64,
        // 8 × 8 jittered samples a pixel: tiles take long enough to be seen held.
        "samples": 8,
        "worker_pid": worker.pid(),
        "worker_name": worker.name,
    });
    let steps = run_script("watch.mjs", &svc, &checks);
    // Whatever the script left it as, the worker runs again before it is dropped.
    signal_worker(&worker, "CONT");
    assert_eq!(
        steps,
        [
            "job page",
            "tile map",
            "priority",
            "leased",
            "preview",
            "narrow",
            "cancelled",
            "retried",
            "deleted",
            "api page",
        ]
    );
}

fn signal_worker(w: &Worker, sig: &str) {
    let status = Command::new("kill")
        .arg(format!("-{sig}"))
        .arg(w.pid().to_string())
        .status()
        .expect("kill runs");
    assert!(status.success(), "kill -{sig}");
}
