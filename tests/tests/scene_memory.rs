//! What checking large scenes costs the service's memory: many submissions of the largest
//! scene of small objects at once are checked in turn within `--max-checking-bytes`, so the
//! process's peak resident memory stays within that budget, the bodies and a margin; and
//! what the checks took is given back to the system once they are answered.

mod common;

use std::time::Duration;

use common::{Service, TempDir, client, wait_until};

/// A process's `VmHWM` (peak resident memory) and `VmRSS` (resident now), in bytes.
fn memory(pid: u32) -> (u64, u64) {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("proc status");
    let field = |name: &str| {
        status
            .lines()
            .find_map(|l| l.strip_prefix(name))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
            .expect("a memory figure")
            * 1024
    };
    (field("VmHWM:"), field("VmRSS:"))
}

const MIB: u64 = 1 << 20;

#[test]
fn large_scenes_are_checked_within_the_budget() {
    if !std::path::Path::new("/proc/self/status").exists() {
        eprintln!("skipped: no /proc to read memory from");
        return;
    }
    let dir = TempDir::new("scene-memory");
    let budget = 96 * MIB;
    let svc = Service::start(
        &dir,
        &[
            "--local-workers",
            "0",
            "--max-checking-bytes",
            &budget.to_string(),
        ],
    );
    // The densest scene text: the smallest objects, as many as the service takes.
    let scene = format!(
        "[GLOBALS]\nwidth = 8\nheight = 8\n[/GLOBALS]\n{}",
        "[OBJECT]\ntype=cube\n[/OBJECT]\n".repeat(99_999)
    );
    let scene_bytes = scene.len() as u64;
    // Warmed up by one of them, so that the baseline holds what one submission leaves.
    let first = client()
        .post(format!("{}/jobs", svc.url))
        .body(scene.clone())
        .send()
        .expect("an answer");
    assert_eq!(first.status(), 201, "{}", first.text().unwrap_or_default());
    wait_until(
        "the first check's memory given back",
        Duration::from_secs(20),
        || memory(svc.pid()).1 < 64 * MIB,
    );
    let (_, baseline) = memory(svc.pid());

    let n = 8;
    let answers: Vec<u16> = std::thread::scope(|s| {
        let sent: Vec<_> = (0..n)
            .map(|_| {
                s.spawn(|| {
                    client()
                        .post(format!("{}/jobs", svc.url))
                        .body(scene.clone())
                        .send()
                        .expect("an answer")
                        .status()
                        .as_u16()
                })
            })
            .collect();
        sent.into_iter()
            .map(|h| h.join().expect("a thread"))
            .collect()
    });
    assert!(answers.iter().all(|&s| s == 201), "{answers:?}");

    // Each check is charged 32× its scene: at most two fit the budget at once, where all
    // eight at once would take some 70 MB each. The bodies (held as bytes, then as text)
    // and a margin for the rest.
    let (peak, _) = memory(svc.pid());
    let bound = baseline + budget + 2 * n * scene_bytes + 48 * MIB;
    assert!(
        peak <= bound,
        "peak {} MiB over the bound {} MiB (baseline {} MiB)",
        peak / MIB,
        bound / MIB,
        baseline / MIB
    );
    // What the checks took goes back to the system; what stays is what the service keeps
    // on purpose (the database writer's page cache of 16 MB, now full of the new jobs)
    // and a margin.
    wait_until(
        "the checks' memory given back",
        Duration::from_secs(20),
        || memory(svc.pid()).1 <= baseline + 32 * MIB,
    );
}
