//! What an operator sees of the farm, on both databases: the workers with their state
//! (rendering which tile, idle, gone at once after a clean stop, gone once a killed one's
//! leases lapse) and what they report (threads, rays per second); and the Prometheus
//! metrics read before and after a job, checked against the job's own tile and pixel
//! counts.

mod common;

use std::time::{Duration, Instant};

use common::{Backend, Service, TempDir, Worker, client, examples, wait_until};
use serde_json::{Value, json};

/// The sum of the samples of metric `name` whose labels include every pair of `labels`
/// (0 when there is none), from Prometheus text.
fn metric(text: &str, name: &str, labels: &[(&str, &str)]) -> f64 {
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .filter_map(|l| {
            let (series, value) = l.rsplit_once(' ')?;
            let (metric, labelled) = match series.split_once('{') {
                Some((m, rest)) => (m, rest.trim_end_matches('}')),
                None => (series, ""),
            };
            if metric != name {
                return None;
            }
            let has = |(k, v): &(&str, &str)| {
                labelled
                    .split(',')
                    .any(|pair| pair == format!("{k}=\"{v}\""))
            };
            labels.iter().all(has).then(|| value.parse::<f64>().ok())?
        })
        .sum()
}

fn scrape(svc: &Service) -> String {
    let r = svc.get("/metrics");
    assert_eq!(r.status(), 200);
    let kind = r
        .headers()
        .get("content-type")
        .and_then(|v| v.to_str().ok())
        .unwrap_or_default()
        .to_string();
    assert!(kind.starts_with("text/plain; version=0.0.4"), "{kind}");
    r.text().expect("a body")
}

fn metrics_count_a_job(backend: Backend) {
    let dir = TempDir::on(backend, "metrics");
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    let before = scrape(&svc);
    let _worker = Worker::start(&svc.url, "metered", &[]);
    let scene = std::fs::read_to_string(examples().join("thesis.ray")).expect("example");
    // 2×2 jittered samples a pixel: exactly four primary rays each.
    let id = svc.submit_id(&scene, "?tile=64&sampler=jitter&samples=2");
    let job = svc.wait_finished(&id, Duration::from_secs(120));
    assert_eq!(job["state"], "done", "{job}");
    let tiles = job["tiles_total"].as_f64().expect("a tile count");
    let pixels = job["width"].as_f64().unwrap_or(0.0) * job["height"].as_f64().unwrap_or(0.0);
    assert!(pixels > 0.0, "{job}");
    let after = scrape(&svc);
    let delta = |name: &str, labels: &[(&str, &str)]| {
        metric(&after, name, labels) - metric(&before, name, labels)
    };

    // Every tile stored once, claimed at least once, none failed or reaped.
    assert_eq!(delta("tessera_tiles_stored_total", &[]), tiles);
    assert!(delta("tessera_tiles_claimed_total", &[]) >= tiles);
    assert_eq!(delta("tessera_tiles_failed_total", &[]), 0.0);
    assert_eq!(delta("tessera_tiles_reaped_total", &[]), 0.0);
    // At least the primary rays: four a pixel.
    let rays = delta("tessera_rays_traced_total", &[]);
    assert!(rays >= 4.0 * pixels, "{rays} rays for {pixels} pixels");
    // One render time per stored tile; a histogram's +Inf bucket is its count.
    assert_eq!(delta("tessera_tile_render_seconds_count", &[]), tiles);
    for h in ["tessera_tile_render_seconds", "tessera_claim_wait_seconds"] {
        assert_eq!(
            metric(&after, &format!("{h}_bucket"), &[("le", "+Inf")]),
            metric(&after, &format!("{h}_count"), &[]),
            "{h}"
        );
    }
    assert!(
        delta("tessera_claim_wait_seconds_count", &[]) <= delta("tessera_tiles_claimed_total", &[])
    );
    // The job counted by state, the queue empty.
    assert_eq!(delta("tessera_jobs_submitted_total", &[]), 1.0);
    assert_eq!(metric(&after, "tessera_jobs", &[("state", "done")]), 1.0);
    for state in ["queued", "running", "failed", "cancelled"] {
        assert_eq!(
            metric(&after, "tessera_jobs", &[("state", state)]),
            0.0,
            "{state}"
        );
    }
    assert_eq!(metric(&after, "tessera_tiles_queued", &[]), 0.0);
    assert_eq!(metric(&after, "tessera_tiles_leased", &[]), 0.0);
    assert_eq!(metric(&after, "tessera_workers", &[]), 1.0, "{after}");
    // Requests by route pattern, not by id.
    let posted = [("route", "/jobs"), ("method", "POST"), ("status", "201")];
    assert_eq!(delta("tessera_http_requests_total", &posted), 1.0);
    let results = [
        ("route", "/worker/jobs/{id}/tiles/{idx}"),
        ("method", "PUT"),
        ("status", "200"),
    ];
    assert!(delta("tessera_http_requests_total", &results) >= tiles);
    assert!(!after.contains(&id), "no series is labelled by a job's id");
    // Every metric described, with its type.
    for (name, kind) in [
        ("tessera_tiles_claimed_total", "counter"),
        ("tessera_rays_traced_total", "counter"),
        ("tessera_tile_render_seconds", "histogram"),
        ("tessera_jobs", "gauge"),
        ("tessera_workers", "gauge"),
        ("tessera_http_requests_total", "counter"),
    ] {
        assert!(after.contains(&format!("# TYPE {name} {kind}")), "{name}");
        assert!(after.contains(&format!("# HELP {name} ")), "{name}");
    }
}

on_both!(metrics_count_a_job);

/// The row of `/workers` for worker `name`, if listed.
fn worker(svc: &Service, name: &str) -> Option<Value> {
    svc.get_json("/workers")
        .as_array()?
        .iter()
        .find(|w| w["name"] == name)
        .cloned()
}

fn workers_show_what_they_do(backend: Backend) {
    let dir = TempDir::on(backend, "worker-state");
    // Short leases: a killed worker's lapse within the test.
    let svc = Service::start(&dir, &["--local-workers", "0", "--lease-ms", "2000"]);
    let scene = std::fs::read_to_string(examples().join("thesis.ray")).expect("example");
    // Many small, slow tiles: the job outlasts the test.
    let id = svc.submit_id(&scene, "?tile=32&sampler=jitter&samples=32");

    // A worker rendering: which tile of which job, its threads, then its rate.
    let mut a = Worker::start(&svc.url, "steady", &[]);
    wait_until(
        "the worker rendering a tile of the job",
        Duration::from_secs(30),
        || {
            worker(&svc, "steady").is_some_and(|w| {
                w["state"] == "rendering"
                    && w["tiles"]
                        .as_array()
                        .is_some_and(|t| t.iter().any(|t| t["job"] == id.as_str()))
            })
        },
    );
    let w = worker(&svc, "steady").expect("listed");
    assert_eq!(w["threads"], 1, "{w}");
    assert_eq!(w["left_cleanly"], false, "{w}");
    // The job's own tile list names the worker as the holder of the same tiles.
    let held: Vec<u64> = w["tiles"]
        .as_array()
        .expect("tiles")
        .iter()
        .filter_map(|t| t["idx"].as_u64())
        .collect();
    let job_tiles = svc.get_json(&format!("/jobs/{id}/tiles"));
    for idx in &held {
        let t = &job_tiles[*idx as usize];
        assert!(t["worker"] == "steady" || t["state"] == "done", "{t}");
    }
    wait_until("a measured rate", Duration::from_secs(30), || {
        worker(&svc, "steady")
            .is_some_and(|w| w["rays_per_second"].as_f64().is_some_and(|r| r > 0.0))
    });

    // A clean stop: gone as soon as the process has exited.
    assert!(a.terminate().success());
    let w = worker(&svc, "steady").expect("still listed");
    assert_eq!(
        (&w["state"], &w["left_cleanly"]),
        (&json!("gone"), &json!(true)),
        "{w}"
    );
    assert_eq!(w["tiles"], json!([]), "{w}");

    // A worker killed while it renders: gone once its leases lapse, not said to have left.
    let mut b = Worker::start(&svc.url, "doomed", &[]);
    let mut last = Value::Null;
    let deadline = Instant::now() + Duration::from_secs(30);
    while last["state"] != "rendering" {
        assert!(
            Instant::now() < deadline,
            "the second worker is not rendering: {last}\n{}",
            svc.get_json(&format!("/jobs/{id}"))
        );
        std::thread::sleep(Duration::from_millis(20));
        last = worker(&svc, "doomed").unwrap_or_default();
    }
    b.kill9();
    wait_until(
        "the killed worker shown gone",
        Duration::from_secs(40),
        || worker(&svc, "doomed").is_some_and(|w| w["state"] == "gone"),
    );
    let job = svc.get_json(&format!("/jobs/{id}"));
    assert_eq!(job["state"], "running", "the job outlasts the test: {job}");
    let w = worker(&svc, "doomed").expect("listed");
    assert_eq!(
        (&w["left_cleanly"], &w["tiles"]),
        (&json!(false), &json!([])),
        "{w}"
    );

    // A goodbye under a name no worker may have is refused.
    let r = client()
        .post(format!("{}/worker/bye", svc.url))
        .json(&json!({ "worker": "" }))
        .send()
        .expect("an answer");
    assert_eq!(r.status(), 400);
    let r = client()
        .post(format!("{}/worker/claim", svc.url))
        .json(&json!({ "worker": "liar", "rays_per_second": -1.0 }))
        .send()
        .expect("an answer");
    assert_eq!(r.status(), 400);
}

on_both!(workers_show_what_they_do);
