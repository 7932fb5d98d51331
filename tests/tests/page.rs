//! The web page's script, run by Node against a real service in a stand-in browser
//! (`tests/tests/page/harness.js`). `page.js`: the job list a page at a time (and a notice
//! when it cannot be loaded), a submission through the form, a refused scene's position,
//! cancel and delete, a scene file with its textures, a chosen file sent as its own bytes
//! unless edited, the workers heard from. `guarded.js`, against a service with a submit token
//! and a small body limit: an upload over the limit refused before it is sent, a saved token
//! forgotten, refused and unanswered cancels and deletes shown, and the delete question
//! mentioning an image only for a done job. Skipped, with a note, where `node` is not
//! installed (`.ci/run` installs it).

mod common;

use std::process::{Command, Stdio};
use std::time::Duration;

use common::{Service, TempDir, examples, wait_until};

/// Whether `node` is missing here (said on stderr): `.ci/run` installs it.
fn node_missing() -> bool {
    let missing = Command::new("node").arg("--version").output().is_err();
    if missing {
        eprintln!("skipped: `node` is not installed");
    }
    missing
}

/// Jobs the page lists at a time (`PAGE` in `page.html`).
const PAGE: usize = 50;

#[test]
fn the_page_lists_submits_and_deletes() {
    if node_missing() {
        return;
    }
    let dir = TempDir::new("page");
    // No workers: every job stays queued, so the list holds still while the page reads it.
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    let scene = std::fs::read_to_string(examples().join("thesis.ray")).expect("example");
    let jobs = 2 * PAGE + 5;
    for n in 0..jobs {
        svc.submit(&scene, &format!("?name=job-{n:02}"));
    }
    // 640×480 in 64-pixel tiles: 10 × 8.
    let (tile, tiles) = (64, 80);
    assert!(scene.contains("width = 640\nheight = 480\n"));
    // The same scene with a word for its height: refused on that line, at the word.
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
        "tile": tile,
        "tiles": tiles,
        "bad_scene": bad,
        "bad_line": bad_line,
        "bad_column": "height = ".len() + 1,
        "examples": examples(),
    });
    let steps = run_script("page.js", &svc, &checks);
    assert_eq!(
        steps,
        [
            "workers",
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
        ]
    );
}

/// Body limit of the guarded service: `textures.ray` and its two textures (4,763 bytes) do
/// not fit, `thesis.ray` (379) does.
const SMALL_LIMIT: usize = 4096;

#[test]
fn the_page_with_a_token_and_a_small_body_limit() {
    if node_missing() {
        return;
    }
    let dir = TempDir::new("page-guarded");
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
    let steps = run_script("guarded.js", &svc, &checks);
    assert_eq!(
        steps,
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

/// Runs `tests/page/{script}` under Node against `svc` with `checks`, and returns the steps
/// it reported; fails if the script does.
fn run_script(script: &str, svc: &Service, checks: &serde_json::Value) -> Vec<String> {
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/page")
        .join(script);
    let mut node = Command::new("node")
        .arg(&script)
        .arg(&svc.url)
        .arg(checks.to_string())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("node starts");
    // Bounded: a page that never settles fails here instead of hanging the suite.
    let mut status = None;
    wait_until("the page script", Duration::from_secs(120), || {
        status = node.try_wait().ok().flatten();
        status.is_some()
    });
    let out = node.wait_with_output().expect("node's output");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        status.is_some_and(|s| s.success()),
        "the page script failed:\n{stdout}\n{}\n{}",
        String::from_utf8_lossy(&out.stderr),
        svc.log()
    );
    // Every step ran (the script stops at the first failed assertion).
    stdout
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter_map(|v| v["step"].as_str().map(str::to_string))
        .collect()
}
