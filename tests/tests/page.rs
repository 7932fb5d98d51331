//! The web page's script, run by Node (`tests/tests/page/page.js`) against a real service:
//! the job list a page at a time, a submission through the form, a refused scene's position,
//! cancel and delete, a scene file with its textures, the workers heard from. Skipped, with a note, where `node` is
//! not installed (`.ci/run` installs it).

mod common;

use std::process::{Command, Stdio};
use std::time::Duration;

use common::{Service, TempDir, examples, wait_until};

/// Jobs the page lists at a time (`PAGE` in `page.html`).
const PAGE: usize = 50;

#[test]
fn the_page_lists_submits_and_deletes() {
    if Command::new("node").arg("--version").output().is_err() {
        eprintln!("skipped: `node` is not installed");
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
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/page/page.js");
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
    let steps: Vec<String> = stdout
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter_map(|v| v["step"].as_str().map(str::to_string))
        .collect();
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
            "textures"
        ]
    );
}
