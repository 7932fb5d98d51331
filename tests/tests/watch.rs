//! Watching a job over HTTP, on both databases: the live preview against the same scene
//! rendered whole by the library (stored tiles in their final pixels, transparent
//! elsewhere; `304` while nothing new is stored; a done job's preview is its image), the
//! job's server-sent events as it is claimed, failed and cancelled, a stream ended by the
//! service's stop without holding it up, a job's priority changed (claims follow it), and
//! the answers to what a user may send wrong.

mod common;

use std::io::{BufRead, BufReader};
use std::time::{Duration, Instant};

use common::{Backend, Service, TempDir, Worker, client, examples, local_png, wait_until};
use serde_json::{Value, json};

/// A PNG's pixels as RGBA (an RGB image gets alpha 255), with its size.
fn rgba(png_bytes: &[u8]) -> (u32, u32, Vec<u8>) {
    let mut reader = png::Decoder::new(std::io::Cursor::new(png_bytes))
        .read_info()
        .expect("a PNG");
    let mut buf = vec![0; reader.output_buffer_size().expect("a size")];
    let info = reader.next_frame(&mut buf).expect("a frame");
    buf.truncate(info.buffer_size());
    let pixels = match info.color_type {
        png::ColorType::Rgba => buf,
        png::ColorType::Rgb => buf
            .chunks_exact(3)
            .flat_map(|p| [p[0], p[1], p[2], 255])
            .collect(),
        other => panic!("unexpected colour type {other:?}"),
    };
    (info.width, info.height, pixels)
}

fn preview(svc: &Service, id: &str) -> (reqwest::StatusCode, Option<String>, Vec<u8>) {
    let r = svc.get(&format!("/jobs/{id}/preview.png"));
    let status = r.status();
    let etag = r
        .headers()
        .get("etag")
        .and_then(|v| v.to_str().ok())
        .map(str::to_string);
    (status, etag, r.bytes().expect("a body").to_vec())
}

fn preview_shows_stored_tiles(backend: Backend) {
    let dir = TempDir::on(backend, "preview");
    // Leases outlast the test: the tiles the killed worker held stay held.
    let svc = Service::start(&dir, &["--local-workers", "0", "--lease-ms", "300000"]);
    let path = examples().join("thesis.ray");
    let scene = std::fs::read_to_string(&path).expect("example");
    let id = svc.submit_id(&scene, "?tile=64&sampler=jitter&samples=6");

    // Before any tile: the whole preview is transparent.
    let (status, etag, png_bytes) = preview(&svc, &id);
    assert_eq!(status, 200);
    let (w, h, px) = rgba(&png_bytes);
    assert_eq!((w, h), (640, 480));
    assert!(px.iter().all(|&b| b == 0), "nothing stored, nothing shown");
    let empty = etag.expect("an ETag");

    // A worker renders some tiles and is stopped part-way (it gives back what it holds).
    let mut worker = Worker::start(&svc.url, "preview-worker", &[]);
    wait_until("a few stored tiles", Duration::from_secs(120), || {
        svc.get_json(&format!("/jobs/{id}"))["tiles_done"].as_i64() >= Some(3)
    });
    worker.terminate();
    let job = svc.get_json(&format!("/jobs/{id}"));
    let total = job["tiles_total"].as_i64().expect("a count");
    let done = job["tiles_done"].as_i64().expect("a count");
    assert!(done < total, "part-way: {done}/{total}");

    // Every stored tile's pixels are the whole render's, opaque; every other pixel is
    // transparent black.
    let (_, _, reference) = rgba(&local_png(&path, Some("jitter"), Some(6)));
    let (status, etag, png_bytes) = preview(&svc, &id);
    assert_eq!(status, 200);
    let etag = etag.expect("an ETag");
    assert_ne!(etag, empty, "a new version with new tiles");
    let (_, _, px) = rgba(&png_bytes);
    let tiles: Vec<Value> = svc
        .get_json(&format!("/jobs/{id}/tiles"))
        .as_array()
        .expect("tiles")
        .clone();
    assert_eq!(tiles.len() as i64, total);
    let stored = tiles.iter().filter(|t| t["state"] == "done").count() as i64;
    assert_eq!(stored, done);
    let mut covered = vec![false; (w * h) as usize];
    for t in tiles.iter().filter(|t| t["state"] == "done") {
        let n = |k: &str| t[k].as_u64().expect("a number") as u32;
        for y in n("y")..n("y") + n("h") {
            for x in n("x")..n("x") + n("w") {
                covered[(y * w + x) as usize] = true;
            }
        }
    }
    for (i, &c) in covered.iter().enumerate() {
        let (got, want) = (&px[4 * i..4 * i + 4], &reference[4 * i..4 * i + 4]);
        if c {
            assert_eq!(
                got,
                want,
                "a stored pixel at {}, {}",
                i as u32 % w,
                i as u32 / w
            );
        } else {
            assert_eq!(
                got,
                [0, 0, 0, 0],
                "an empty pixel at {}, {}",
                i as u32 % w,
                i as u32 / w
            );
        }
    }

    // Asked again with its ETag while nothing new is stored: 304, no body.
    let r = client()
        .get(format!("{}/jobs/{id}/preview.png", svc.url))
        .header("If-None-Match", &etag)
        .send()
        .expect("an answer");
    assert_eq!(r.status(), 304);

    // Finished by another worker: the preview of the done job is its image, opaque.
    let _worker = Worker::start(&svc.url, "preview-worker-2", &[]);
    let job = svc.wait_finished(&id, Duration::from_secs(300));
    assert_eq!(job["state"], "done", "{job}");
    let (status, _, png_bytes) = preview(&svc, &id);
    assert_eq!(status, 200);
    let (_, _, px) = rgba(&png_bytes);
    assert!(
        px == reference,
        "the done job's preview is the whole render"
    );
    let (_, _, image) = rgba(&svc.image(&id));
    assert!(px == image, "and its image");
}

on_both!(preview_shows_stored_tiles);

/// A job's event stream, read event by event.
struct Events {
    lines: std::io::Lines<BufReader<reqwest::blocking::Response>>,
}

impl Events {
    fn open(svc: &Service, id: &str) -> Events {
        let r = reqwest::blocking::Client::builder()
            .timeout(None)
            .build()
            .expect("a client")
            .get(format!("{}/jobs/{id}/events", svc.url))
            .send()
            .expect("an answer");
        assert_eq!(r.status(), 200);
        assert_eq!(r.headers()["content-type"], "text/event-stream");
        Events {
            lines: BufReader::new(r).lines(),
        }
    }

    /// The next event's name and data, or `None` once the stream has ended.
    fn next(&mut self) -> Option<(String, Value)> {
        let (mut name, mut data) = (String::new(), String::new());
        loop {
            let line = self.lines.next()?.ok()?;
            if line.is_empty() {
                if !name.is_empty() {
                    let value = serde_json::from_str(&data).expect("JSON data");
                    return Some((name, value));
                }
                continue;
            }
            if let Some(n) = line.strip_prefix("event: ") {
                name = n.to_string();
            } else if let Some(d) = line.strip_prefix("data: ") {
                data.push_str(d);
            }
        }
    }

    /// Events up to and including the first for which `want` holds.
    fn until(&mut self, what: &str, want: impl Fn(&str, &Value) -> bool) -> Vec<(String, Value)> {
        let mut seen = Vec::new();
        loop {
            let Some((name, data)) = self.next() else {
                panic!("the stream ended before {what}: {seen:?}");
            };
            let done = want(&name, &data);
            seen.push((name, data));
            if done {
                return seen;
            }
        }
    }
}

fn events_follow_a_job(backend: Backend) {
    let dir = TempDir::on(backend, "events");
    let svc = Service::start(&dir, &["--local-workers", "0", "--max-attempts", "3"]);
    let scene = std::fs::read_to_string(examples().join("thesis.ray")).expect("example");
    let id = svc.submit_id(&scene, "?tile=128");
    let mut events = Events::open(&svc, &id);

    // First the job, then all its tiles.
    let (name, job) = events.next().expect("an event");
    assert_eq!(
        (name.as_str(), job["state"].as_str()),
        ("job", Some("queued"))
    );
    let (name, tiles) = events.next().expect("an event");
    assert_eq!(name, "tiles");
    let tiles = tiles.as_array().expect("an array").clone();
    assert_eq!(
        tiles.len() as i64,
        job["tiles_total"].as_i64().expect("a count")
    );
    assert!(tiles.iter().all(|t| t["state"] == "queued"));

    // A claim: the tile is leased by that worker, and the job runs.
    let claim: Value = svc.claim("events-test").json().expect("a claim");
    let idx = claim["idx"].clone();
    let seen = events.until("the lease", |n, d| n == "tile" && d["idx"] == idx);
    let tile = &seen.last().expect("an event").1;
    assert_eq!(
        (tile["state"].as_str(), tile["worker"].as_str()),
        (Some("leased"), Some("events-test"))
    );
    assert_eq!(tile["attempts"], 1);
    events.until("the job running", |n, d| {
        n == "job" && d["state"] == "running"
    });

    // A reported failure: the tile is queued again with its failure, and a `failure` event
    // says why.
    let r = client()
        .post(format!(
            "{}/worker/jobs/{id}/tiles/{idx}/fail?lease={}",
            svc.url,
            claim["lease"].as_str().expect("a lease")
        ))
        .json(&json!({ "worker": "events-test", "reason": "out of paint" }))
        .send()
        .expect("an answer");
    assert_eq!(r.status(), 200);
    let seen = events.until("the failure", |n, _| n == "failure");
    let failure = &seen.last().expect("an event").1;
    assert_eq!(failure["idx"], idx);
    assert_eq!(failure["failures"], 1);
    assert_eq!(failure["error"], "worker events-test: out of paint");
    assert!(
        seen.iter()
            .any(|(n, d)| n == "tile" && d["idx"] == idx && d["state"] == "queued"),
        "{seen:?}"
    );

    // A cancel: the job as it ended, then the end, then nothing.
    let r = client()
        .delete(format!("{}/jobs/{id}", svc.url))
        .send()
        .expect("an answer");
    assert_eq!(r.status(), 200);
    let seen = events.until("the end", |n, _| n == "end");
    assert_eq!(seen.last().expect("an event").1["state"], "cancelled");
    assert!(events.next().is_none(), "the stream closes after `end`");

    // A job that has ended answers its state and its end at once.
    let mut again = Events::open(&svc, &id);
    let names: Vec<String> = std::iter::from_fn(|| again.next())
        .map(|(n, _)| n)
        .collect();
    assert_eq!(names, ["job", "tiles", "end"]);
}

on_both!(events_follow_a_job);

/// A service stopping ends the event streams it serves, and is not held up by them.
#[test]
fn event_streams_end_when_the_service_stops() {
    let dir = TempDir::new("events-stop");
    let mut svc = Service::start(&dir, &["--local-workers", "0"]);
    let scene = std::fs::read_to_string(examples().join("thesis.ray")).expect("example");
    let id = svc.submit_id(&scene, "");
    let mut events = Events::open(&svc, &id);
    assert_eq!(events.next().expect("an event").0, "job");
    let started = Instant::now();
    let status = svc.terminate();
    assert!(status.success(), "{status:?}");
    // Well under the service's drain deadline for requests left open (`DRAIN`).
    assert!(
        started.elapsed() < Duration::from_secs(5),
        "stopped in {:?}",
        started.elapsed()
    );
    let rest: Vec<String> = std::iter::from_fn(|| events.next())
        .map(|(n, _)| n)
        .collect();
    assert!(
        !rest.contains(&"end".to_string()),
        "the job did not end: {rest:?}"
    );
}

/// `PATCH /jobs/{id}` changes the order of claims; it refuses an ended job, and bodies that
/// are not `{"priority": N}`, in words.
#[test]
fn a_job_priority_changes_the_order_of_claims() {
    let dir = TempDir::new("priority");
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    let scene = std::fs::read_to_string(examples().join("thesis.ray")).expect("example");
    let older = svc.submit_id(&scene, "");
    let newer = svc.submit_id(&scene, "");
    let patch = |id: &str, body: &str, kind: Option<&str>| {
        let mut r = client()
            .patch(format!("{}/jobs/{id}", svc.url))
            .body(body.to_string());
        if let Some(k) = kind {
            r = r.header("content-type", k);
        }
        let r = r.send().expect("an answer");
        let status = r.status().as_u16();
        (status, r.json::<Value>().expect("JSON"))
    };
    // Equal priorities: the older job's tile first. Raised, the newer one's.
    let (status, job) = patch(&newer, r#"{"priority": 5.0}"#, Some("application/json"));
    assert_eq!(status, 200, "{job}");
    assert_eq!(job["priority"], 5);
    let claim: Value = svc.claim("prio").json().expect("a claim");
    assert_eq!(claim["job"], newer.as_str());
    assert_eq!(svc.get_json(&format!("/jobs/{newer}"))["priority"], 5);

    for (body, kind, status, words) in [
        (
            r#"{"priority": 1001}"#,
            Some("application/json"),
            400,
            "from -1000 to 1000",
        ),
        (
            r#"{"priority": 1.5}"#,
            Some("application/json"),
            400,
            "not a whole number",
        ),
        (
            r#"{"priority": "high"}"#,
            Some("application/json"),
            400,
            r#"{"priority": N}"#,
        ),
        (
            r#"{"prio": 1}"#,
            Some("application/json"),
            400,
            r#"{"priority": N}"#,
        ),
        ("{", Some("application/json"), 400, r#"{"priority": N}"#),
        (r#"{"priority": 1}"#, None, 415, "application/json"),
    ] {
        let (got, e) = patch(&older, body, kind);
        assert_eq!(got, status, "{body}: {e}");
        let m = e["error"].as_str().expect("an error");
        assert!(m.contains(words) && !m.contains("Failed to"), "{body}: {m}");
    }
    assert_eq!(
        svc.get_json(&format!("/jobs/{older}"))["priority"],
        0,
        "unchanged"
    );
    let (status, _) = patch("nosuchjob", r#"{"priority": 1}"#, Some("application/json"));
    assert_eq!(status, 404);
    client()
        .delete(format!("{}/jobs/{older}", svc.url))
        .send()
        .expect("cancelled");
    let (status, e) = patch(&older, r#"{"priority": 1}"#, Some("application/json"));
    assert_eq!(
        (status, e["state"].as_str()),
        (409, Some("cancelled")),
        "{e}"
    );
}

/// Query parameters that do not parse are refused in the project's words, naming the
/// parameter and what the route takes.
#[test]
fn query_mistakes_are_said_in_words() {
    let dir = TempDir::new("query-words");
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    let id = svc.submit_id(
        &std::fs::read_to_string(examples().join("thesis.ray")).expect("example"),
        "",
    );
    for (path, words) in [
        ("/jobs?limit=many".to_string(), "query parameter `limit`: "),
        (
            "/jobs?lmit=5".to_string(),
            "unknown query parameter `lmit`; this route takes `limit` or `before`",
        ),
        (
            format!("/jobs/{id}/image.png?size=2"),
            "unknown query parameter `size`; this route takes no query parameters",
        ),
        (
            format!("/jobs/{id}/preview.png?x=1"),
            "this route takes no query parameters",
        ),
        (format!("/jobs/{id}?wait=soon"), "query parameter `wait`: "),
    ] {
        let r = svc.get(&path);
        assert_eq!(r.status(), 400, "{path}");
        let e: Value = r.json().expect("JSON");
        let m = e["error"].as_str().expect("an error");
        assert!(m.contains(words), "{path}: {m}");
        assert!(
            !m.contains("deserialize") && !m.contains("field"),
            "{path}: {m}"
        );
    }
}

/// `/jobs/{id}` is the job's JSON for a script and its page for a browser; a page's files,
/// the icon and the API page are served.
#[test]
fn a_job_url_is_its_page_in_a_browser() {
    let dir = TempDir::new("job-page");
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    let scene = std::fs::read_to_string(examples().join("thesis.ray")).expect("example");
    let job = svc.submit(&scene, "");
    let url = job["url"].as_str().expect("a url");
    let get = |path: &str, accept: &str| {
        client()
            .get(format!("{}{path}", svc.url))
            .header("accept", accept)
            .send()
            .expect("an answer")
    };
    let browser = "text/html,application/xhtml+xml,application/xml;q=0.9,*/*;q=0.8";
    let page = get(url, browser);
    assert_eq!(page.status(), 200);
    assert!(
        page.headers()["content-type"]
            .to_str()
            .is_ok_and(|t| t.starts_with("text/html"))
    );
    assert_eq!(page.headers()["vary"], "Accept");
    assert!(page.text().expect("text").contains("/static/job.js"));
    let json: Value = get(url, "*/*").json().expect("JSON for a script");
    assert_eq!(json["id"], job["id"]);
    assert_eq!(get("/jobs/nosuchjob", browser).status(), 404);
    let scene_back = svc.get(&format!("{url}/scene"));
    assert_eq!(scene_back.text().expect("text"), scene);
    for (path, kind) in [
        ("/static/job.js", "text/javascript"),
        ("/static/app.css", "text/css"),
        ("/favicon.ico", "image/svg+xml"),
        ("/api", "text/html"),
    ] {
        let r = svc.get(path);
        assert_eq!(r.status(), 200, "{path}");
        let t = r.headers()["content-type"]
            .to_str()
            .expect("ASCII")
            .to_string();
        assert!(t.starts_with(kind), "{path}: {t}");
    }
    assert_eq!(svc.get("/static/nothing.js").status(), 404);
}

/// Every answer, page, script, JSON or error, says `nosniff`, `no-referrer` and a strict
/// content security policy; the pages need nothing that policy forbids (no inline script,
/// style or handler).
#[test]
fn answers_carry_the_security_headers_and_the_pages_obey_them() {
    let dir = TempDir::new("security-headers");
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    let browser = "text/html,application/xhtml+xml,application/xml;q=0.9,*/*;q=0.8";
    for path in [
        "/",
        "/api",
        "/static/job.js",
        "/static/app.css",
        "/jobs",
        "/healthz",
        "/jobs/nosuchjob",
    ] {
        let r = client()
            .get(format!("{}{path}", svc.url))
            .header("accept", browser)
            .send()
            .expect("an answer");
        let h = r.headers();
        assert_eq!(h["x-content-type-options"], "nosniff", "{path}");
        assert_eq!(h["referrer-policy"], "no-referrer", "{path}");
        let csp = h["content-security-policy"].to_str().expect("ASCII");
        for directive in [
            "default-src 'none'",
            "script-src 'self'",
            "style-src 'self'",
        ] {
            assert!(csp.contains(directive), "{path}: {csp}");
        }
        assert!(!csp.contains("unsafe-inline"), "{path}: {csp}");
    }
    let web = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../service/web");
    for entry in std::fs::read_dir(&web).expect("the page's files") {
        let path = entry.expect("entry").path();
        let text = std::fs::read_to_string(&path)
            .unwrap_or_default()
            .to_lowercase();
        let name = path.display();
        if path.extension().is_some_and(|e| e == "html") {
            assert!(!text.contains("<style"), "{name}: an inline style sheet");
            assert!(!text.contains(" style="), "{name}: an inline style");
            assert!(!text.contains("javascript:"), "{name}: a javascript: URL");
            for tag in text.split("<script").skip(1) {
                let open = tag.split('>').next().unwrap_or_default();
                assert!(open.contains("src="), "{name}: an inline script");
            }
            for attr in text.split_whitespace() {
                let handler = attr.starts_with("on")
                    && attr
                        .split('=')
                        .next()
                        .is_some_and(|a| a.len() > 2 && a.bytes().all(|b| b.is_ascii_lowercase()))
                    && attr.contains('=');
                assert!(!handler, "{name}: an inline handler {attr}");
            }
        }
        if path.extension().is_some_and(|e| e == "js") {
            for forbidden in [
                "eval(",
                "new function(",
                "setattribute(\"style",
                "style=",
                "on\" + ",
            ] {
                assert!(!text.contains(forbidden), "{name}: {forbidden}");
            }
        }
    }
}

/// With `--read-token`, reads need it (or the submit token), as a bearer token or the
/// pages' `tessera_token` cookie; `/healthz`, the page shells and their files stay open so
/// that the token can be typed; writes still need the submit token.
#[test]
fn a_read_token_guards_reads() {
    let dir = TempDir::new("read-token");
    let svc = Service::start(
        &dir,
        &[
            "--local-workers",
            "0",
            "--read-token",
            "r3ad",
            "--submit-token",
            "subm1t",
        ],
    );
    let scene = std::fs::read_to_string(examples().join("thesis.ray")).expect("example");
    let submitted = client()
        .post(format!("{}/jobs", svc.url))
        .bearer_auth("subm1t")
        .body(scene.clone())
        .send()
        .expect("an answer");
    assert_eq!(submitted.status(), 201);
    let job: Value = submitted.json().expect("JSON");
    let id = job["id"].as_str().expect("id").to_string();
    let get = |path: &str, auth: Option<&str>, cookie: Option<&str>, accept: &str| {
        let mut r = client()
            .get(format!("{}{path}", svc.url))
            .header("accept", accept);
        if let Some(t) = auth {
            r = r.bearer_auth(t);
        }
        if let Some(c) = cookie {
            r = r.header("cookie", c);
        }
        r.send().expect("an answer").status()
    };
    let json = "application/json";
    let browser = "text/html,application/xhtml+xml,application/xml;q=0.9,*/*;q=0.8";
    let job_path = format!("/jobs/{id}");
    let scene_path = format!("/jobs/{id}/scene");
    let events = format!("/jobs/{id}/events");
    for path in [
        "/jobs",
        job_path.as_str(),
        scene_path.as_str(),
        "/workers",
        "/openapi.json",
    ] {
        assert_eq!(get(path, None, None, json), 401, "{path} without a token");
        assert_eq!(get(path, Some("wrong"), None, json), 401, "{path}");
        assert_eq!(get(path, Some("r3ad"), None, json), 200, "{path}");
        assert_eq!(get(path, Some("subm1t"), None, json), 200, "{path}");
        assert_eq!(
            get(path, None, Some("theme=dark; tessera_token=r3ad"), json),
            200,
            "{path} with the cookie"
        );
    }
    assert_eq!(get(&events, None, None, "text/event-stream"), 401);
    for path in ["/healthz", "/", "/api", "/static/common.js", "/favicon.ico"] {
        assert_eq!(get(path, None, None, browser), 200, "{path} stays open");
    }
    // A job's page for a browser is a shell; its JSON is a read.
    assert_eq!(get(&job_path, None, None, browser), 200);
    // Writes still need the submit token, not the read token.
    let r = client()
        .delete(format!("{}/jobs/{id}", svc.url))
        .bearer_auth("r3ad")
        .send()
        .expect("an answer");
    assert_eq!(r.status(), 401);
}
