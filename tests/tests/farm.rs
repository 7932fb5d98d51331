//! The farm end to end: a real `tessera-service` process with a real database, real
//! `tessera-worker` processes, and HTTP requests as curl would send them. Every test runs
//! on both backends (`NAME::sqlite`, `NAME::postgres`).

mod common;

use std::time::Duration;

use common::{Backend, Service, TempDir, Worker, client, examples, line_col, local_png, refused};
use serde_json::Value;

const JOB_TIME: Duration = Duration::from_secs(120);

fn read(name: &str) -> String {
    std::fs::read_to_string(examples().join(name)).expect("example readable")
}

fn two_worker_processes_share_a_job_and_match_tessera_render(backend: Backend) {
    let dir = TempDir::on(backend, "share");
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    let _a = Worker::start(&svc.url, "worker-a", &[]);
    let _b = Worker::start(&svc.url, "worker-b", &[]);
    let job = svc.submit(&read("thesis.ray"), "?tile=16&name=thesis.ray");
    // Workers may claim its first tiles before the answer is even written.
    assert!(
        matches!(job["state"].as_str(), Some("queued" | "running")),
        "{job}"
    );
    assert_eq!(job["tiles_total"], 40 * 30);
    let id = job["id"].as_str().expect("job id");
    let done = svc.wait_finished(id, JOB_TIME);
    assert_eq!(done["state"], "done", "{done}");
    assert_eq!(done["tiles_done"], done["tiles_total"]);
    let png = svc.image(id);
    assert!(
        png == local_png(&examples().join("thesis.ray"), None, None),
        "farm PNG differs from tessera-render's"
    );
    let workers = svc.get_json("/workers");
    let done_by = |name: &str| worker_count(&workers, name, "tiles_done");
    assert!(
        done_by("worker-a") > 0 && done_by("worker-b") > 0,
        "{workers}"
    );
    assert_eq!(done_by("worker-a") + done_by("worker-b"), 1200);
}
on_both!(two_worker_processes_share_a_job_and_match_tessera_render);

/// A number from `GET /workers` for one worker (0 if it is not listed).
fn worker_count(workers: &Value, name: &str, what: &str) -> u64 {
    workers
        .as_array()
        .and_then(|ws| ws.iter().find(|w| w["name"] == name))
        .map_or(0, |w| w[what].as_u64().unwrap_or(0))
}

fn workers_claim_their_next_tile_with_the_result_they_post(backend: Backend) {
    let dir = TempDir::on(backend, "rides");
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    // Tiles that take a while to render (64 px, 16 rays a pixel: 80 tiles), so that each
    // claim made as a tile starts is answered long before the tile is done; and a worker
    // that traces nothing, which always asks for its next tile with its post.
    let w = Worker::start(&svc.url, "tracing", &[]);
    let job = svc.submit(&read("thesis.ray"), "?tile=64&sampler=jitter&samples=4");
    let id = job["id"].as_str().expect("job id").to_string();
    assert_eq!(svc.wait_finished(&id, JOB_TIME)["state"], "done");
    let workers = svc.get_json("/workers");
    let tiles = worker_count(&workers, "tracing", "tiles_done");
    let rides = worker_count(&workers, "tracing", "claims_with_results");
    assert_eq!(tiles, 80, "{workers}");
    // All but the first few: a post whose answer came back before the next tile finished.
    assert!(
        rides >= tiles / 2,
        "{rides} of {tiles} claims rode on a result: {workers}"
    );
    drop(w);

    let _n = Worker::start(&svc.url, "noop", &["--noop"]);
    let job = svc.submit(&read("checker.ray"), "?tile=32");
    let id = job["id"].as_str().expect("job id").to_string();
    let total = job["tiles_total"].as_u64().expect("tiles");
    assert_eq!(svc.wait_finished(&id, JOB_TIME)["state"], "done");
    let workers = svc.get_json("/workers");
    assert_eq!(worker_count(&workers, "noop", "tiles_done"), total);
    // Every claim but the first rode on a post.
    assert_eq!(
        worker_count(&workers, "noop", "claims_with_results"),
        total - 1,
        "{workers}"
    );
}
on_both!(workers_claim_their_next_tile_with_the_result_they_post);

fn multipart_scene_with_textures_matches_tessera_render(backend: Backend) {
    let dir = TempDir::on(backend, "multipart");
    let svc = Service::start(&dir, &["--local-workers", "2"]);
    let tex = examples().join("textures");
    let form = reqwest::blocking::multipart::Form::new()
        .file("scene", examples().join("textures.ray"))
        .expect("scene file")
        .file("textures/globe.png", tex.join("globe.png"))
        .expect("texture")
        .file("textures/tile.ppm", tex.join("tile.ppm"))
        .expect("texture");
    let submit = |form: reqwest::blocking::multipart::Form| {
        let r = client()
            .post(format!("{}/jobs", svc.url))
            .multipart(form)
            .send()
            .expect("answer");
        assert_eq!(r.status(), 201, "{}", r.text().unwrap_or_default());
        r
    };
    let r = submit(form);
    let location = r.headers()["location"].to_str().expect("ascii").to_string();
    let job: Value = r.json().expect("json");
    assert_eq!(
        location,
        format!("/jobs/{}", job["id"].as_str().expect("id"))
    );
    assert_eq!(job["name"], "textures.ray");
    let id = job["id"].as_str().expect("id");
    assert_eq!(svc.wait_finished(id, JOB_TIME)["state"], "done");
    assert!(svc.image(id) == local_png(&examples().join("textures.ray"), None, None));

    // A texture named through `.` and `..` is the same upload (here sent under its file name
    // alone), as `tessera-render` reads the same file beside the scene.
    let odd = std::fs::read_to_string(examples().join("textures.ray"))
        .expect("scene")
        .replace("textures/globe.png", "./textures/../textures/globe.png");
    assert!(odd.contains("./textures/../textures/globe.png"));
    let odd_path = dir.path().join("odd.ray");
    std::fs::write(&odd_path, &odd).expect("write");
    std::fs::create_dir_all(dir.path().join("textures")).expect("dir");
    for f in ["globe.png", "tile.ppm"] {
        std::fs::copy(tex.join(f), dir.path().join("textures").join(f)).expect("copy");
    }
    let form = reqwest::blocking::multipart::Form::new()
        .text("scene", odd)
        .file("globe.png", tex.join("globe.png"))
        .expect("texture")
        .file("textures/tile.ppm", tex.join("tile.ppm"))
        .expect("texture");
    let odd_id = submit(form).json::<Value>().expect("json")["id"]
        .as_str()
        .expect("id")
        .to_string();
    assert_eq!(svc.wait_finished(&odd_id, JOB_TIME)["state"], "done");
    assert!(svc.image(&odd_id) == local_png(&odd_path, None, None));

    // Both local workers rendered tiles of the job, yet its scene (and its textures) was
    // fetched and built once: they share one cache of built scenes.
    let workers = svc.get_json("/workers");
    let locals: Vec<&Value> = workers
        .as_array()
        .expect("a list")
        .iter()
        .filter(|w| w["name"].as_str().is_some_and(|n| n.contains("-local")))
        .collect();
    assert_eq!(locals.len(), 2, "{workers}");
    assert!(
        locals.iter().all(|w| w["claims"].as_u64() > Some(0)),
        "{workers}"
    );
    let log = svc.log();
    let builds = log
        .lines()
        .filter(|l| l.contains("scene built") && l.contains(id))
        .count();
    assert_eq!(builds, 1, "{log}");
}
on_both!(multipart_scene_with_textures_matches_tessera_render);

fn a_job_can_override_the_scenes_sampler(backend: Backend) {
    let dir = TempDir::on(backend, "sampler");
    let svc = Service::start(&dir, &["--local-workers", "2"]);
    let scene = read("checker.ray");
    let job = svc.submit(&scene, "?sampler=jitter&samples=2");
    assert_eq!(job["sampler"], "jitter");
    assert_eq!(job["samples"], 2);
    let id = job["id"].as_str().expect("id");
    assert_eq!(svc.wait_finished(id, JOB_TIME)["state"], "done");
    let png = svc.image(id);
    let path = examples().join("checker.ray");
    assert!(png == local_png(&path, Some("jitter"), Some(2)));
    assert!(
        png != local_png(&path, None, None),
        "the override changed nothing"
    );

    let bad = client()
        .post(format!("{}/jobs?sampler=random", svc.url))
        .body(scene)
        .send()
        .expect("answer");
    assert_eq!(bad.status(), 400);
    let body: Value = bad.json().expect("json");
    assert!(
        body["error"]
            .as_str()
            .unwrap_or("")
            .contains("unknown sampler"),
        "{body}"
    );
}
on_both!(a_job_can_override_the_scenes_sampler);

fn bad_requests_get_json_errors_and_store_nothing(backend: Backend) {
    let dir = TempDir::on(backend, "errors");
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    let http = client();
    let post = |body: &str| {
        http.post(format!("{}/jobs", svc.url))
            .body(body.to_string())
            .send()
            .expect("answer")
    };
    let post_form = |form: reqwest::blocking::multipart::Form| {
        http.post(format!("{}/jobs", svc.url))
            .multipart(form)
            .send()
            .expect("answer")
    };

    // A misspelt key: 400 with its line and column.
    let e = refused(
        post("[GLOBALS]\nwidth = 8\nheigth = 6\n[/GLOBALS]\n"),
        "height",
    );
    assert_eq!(line_col(&e), (Some(3), Some(1)), "{e}");

    // A texture that was not uploaded: 400 naming it.
    let r = post(&read("textures.ray"));
    assert_eq!(r.status(), 400);
    let e: Value = r.json().expect("json");
    assert!(
        e["missing_assets"]
            .to_string()
            .contains("textures/globe.png"),
        "{e}"
    );

    // A texture named by a path out of the scene's folder: refused before any file system
    // could be involved, as a scene error (line, column, the list of errors).
    for path in ["../../etc/passwd", "/etc/passwd", "a/../../b.png"] {
        let r = post(&format!(
            "[OBJECT]\ntype = sphere\nradius = 1\ntexture = {path}\n[/OBJECT]\n"
        ));
        let e = refused(r, "beside the scene or below it");
        assert_eq!(line_col(&e), (Some(4), Some(11)), "{e}");
        assert!(e["errors"].is_array(), "{e}");
    }

    // Empty body, bad tile size, not UTF-8.
    assert_eq!(post("").status(), 400);
    // `curl -d @thesis.ray` (line breaks dropped: the whole scene one comment line) is
    // refused with the way to send it, not rendered black.
    let flattened = read("thesis.ray").replace(['\n', '\r'], "");
    assert!(flattened.starts_with('#'));
    refused(post(&flattened), "--data-binary");
    // Also from a file saved with a byte-order mark (it rendered black).
    refused(post(&format!("\u{feff}{flattened}")), "--data-binary");
    let r = http
        .post(format!("{}/jobs?tile=3", svc.url))
        .body(read("thesis.ray"))
        .send()
        .expect("answer");
    assert_eq!(r.status(), 400);
    // A misspelt parameter is refused, naming it, instead of rendering with the defaults.
    for typo in ["tiles=8", "sampler=jitter&sample=4"] {
        let r = http
            .post(format!("{}/jobs?{typo}", svc.url))
            .body(read("thesis.ray"))
            .send()
            .expect("answer");
        let bad = typo.rsplit('&').next().and_then(|p| p.split('=').next());
        refused(r, &format!("`{}`", bad.unwrap_or_default()));
    }
    // A priority out of its range is refused; one within it is the job's.
    let r = http
        .post(format!("{}/jobs?priority=1001", svc.url))
        .body(read("thesis.ray"))
        .send()
        .expect("answer");
    refused(r, "priority must be from -1000 to 1000");
    for (query, priority) in [("?priority=-3", -3), ("", 0)] {
        let job = svc.submit(&read("thesis.ray"), query);
        assert_eq!(job["priority"], priority, "{job}");
        // Gone again, as this test ends with nothing stored.
        let url = format!("{}/jobs/{}", svc.url, job["id"].as_str().expect("id"));
        assert_eq!(http.delete(&url).send().expect("cancel").status(), 200);
        let purge = http
            .delete(format!("{url}?purge=true"))
            .send()
            .expect("purge");
        assert_eq!(purge.status(), 204);
    }
    // So are the reading routes': `limt` listed every job, `wiat` answered at once, and the
    // image took anything.
    for (path, bad) in [
        ("/jobs?limt=5", "`limt`"),
        ("/jobs/j?wiat=60", "`wiat`"),
        ("/jobs/j/image.png?x=1", "`x`"),
    ] {
        let r = http
            .get(format!("{}{path}", svc.url))
            .send()
            .expect("answer");
        refused(r, bad);
    }
    let r = http
        .post(format!("{}/jobs", svc.url))
        .body(b"[GLOBALS]\nwidth = 8\xff\n".to_vec())
        .send()
        .expect("answer");
    assert_eq!(line_col(&refused(r, "UTF-8")), (Some(2), Some(10)));
    // Two scenes in one upload: which one was meant is not for the service to guess.
    let two = reqwest::blocking::multipart::Form::new()
        .text("scene", read("thesis.ray"))
        .text("scene", read("checker.ray"));
    refused(post_form(two), "twice");
    // Two textures of one file name: the answer says how to send both (the page sends
    // each by its file name, and could not).
    let part = || reqwest::blocking::multipart::Part::bytes(vec![1u8]).file_name("wood.png");
    let twins = reqwest::blocking::multipart::Form::new()
        .text("scene", read("thesis.ray"))
        .part("asset", part())
        .part("asset", part());
    refused(post_form(twins), "filename=a/wood.png");
    // An asset part with nothing to name it by says so (it read "`` is not a valid asset
    // name").
    let unnamed = reqwest::blocking::multipart::Form::new()
        .text("scene", read("thesis.ray"))
        .text("asset", "bytes");
    refused(post_form(unnamed), "has no file name");
    // An empty scene part is named as such, with the multipart way to send one.
    let empty = reqwest::blocking::multipart::Form::new().text("scene", "");
    refused(post_form(empty), "curl -F scene=@");
    // A job name too long for a list or a file name, with a line break in it, or bytes
    // that are not UTF-8 (it was stored with U+FFFD in their place).
    for name in [
        "n".repeat(256),
        "two%0Alines".to_string(),
        "caf%E9".to_string(),
    ] {
        let r = http
            .post(format!("{}/jobs?name={name}", svc.url))
            .body(read("thesis.ray"))
            .send()
            .expect("answer");
        assert_eq!(r.status(), 400, "{name}");
        assert!(r.json::<Value>().expect("json")["error"].is_string());
    }

    // Nothing was stored.
    assert_eq!(svc.get_json("/jobs"), Value::Array(vec![]));

    // Unknown job and unknown route: 404 JSON.
    let r = svc.get("/jobs/does-not-exist");
    assert_eq!(r.status(), 404);
    assert!(r.json::<Value>().expect("json")["error"].is_string());
    assert_eq!(svc.get("/jobs/does-not-exist/image.png").status(), 404);
    // An id of 5,000 characters is named by its first 64, not repeated whole.
    let long = "é".repeat(5000);
    let r = svc.get(&format!("/jobs/{long}"));
    assert_eq!(r.status(), 404);
    let e: Value = r.json().expect("json");
    let said = e["error"].as_str().unwrap_or("");
    assert!(
        said.contains(&format!("{}…", "é".repeat(64))) && said.chars().count() < 100,
        "{said}"
    );
    assert_eq!(svc.get("/nothing-here").status(), 404);
    let r = svc.get("/jobs/");
    assert_eq!(r.status(), 404);
    let e: Value = r.json().expect("json");
    assert!(
        e["error"]
            .as_str()
            .is_some_and(|m| m.contains("did you mean /jobs")),
        "{e}"
    );
    // Only routes that exist are suggested.
    for path in ["/nothing/", "//", "/jobs/a/b/"] {
        let e: Value = svc.get(path).json().expect("json");
        assert_eq!(e["error"], "no such route; see /", "{path}");
    }

    // An image before the job is done: 409 saying how far it is. (Its name is as long as
    // a name may be.)
    let job = svc.submit(&read("thesis.ray"), &format!("?name={}", "n".repeat(255)));
    assert_eq!(job["name"].as_str().map(str::len), Some(255));
    let id = job["id"].as_str().expect("id");
    let r = svc.get(&format!("/jobs/{id}/image.png"));
    assert_eq!(r.status(), 409);
    let e: Value = r.json().expect("json");
    assert_eq!(e["state"], "queued");
    assert_eq!(e["tiles_done"], 0);

    // Cancel: its tiles are no longer handed out.
    let r = http
        .delete(format!("{}/jobs/{id}", svc.url))
        .send()
        .expect("answer");
    assert_eq!(r.status(), 200);
    assert_eq!(svc.get_json(&format!("/jobs/{id}"))["state"], "cancelled");
    let claim = svc.claim("w");
    assert_eq!(claim.status(), 204);
    // A cancel again changes nothing (clients retry a DELETE): the job stays, cancelled.
    let r = http
        .delete(format!("{}/jobs/{id}", svc.url))
        .send()
        .expect("answer");
    assert_eq!(r.status(), 200);
    assert_eq!(r.json::<Value>().expect("json")["state"], "cancelled");
    // A misspelt parameter is refused, not taken for a cancel.
    let r = http
        .delete(format!("{}/jobs/{id}?purg=true", svc.url))
        .send()
        .expect("answer");
    assert_eq!(r.status(), 400);
    assert!(r.json::<Value>().expect("json")["error"].is_string());
    // Purging an ended (here: cancelled) job removes it; an active one must be cancelled
    // first.
    let r = http
        .delete(format!("{}/jobs/{id}?purge=maybe", svc.url))
        .send()
        .expect("answer");
    assert_eq!(r.status(), 400);
    let r = http
        .delete(format!("{}/jobs/{id}?purge=1", svc.url))
        .send()
        .expect("answer");
    assert_eq!(r.status(), 204);
    assert_eq!(svc.get(&format!("/jobs/{id}")).status(), 404);
    let active = svc.submit(&read("thesis.ray"), "");
    let active = active["id"].as_str().expect("id");
    let r = http
        .delete(format!("{}/jobs/{active}?purge=true", svc.url))
        .send()
        .expect("answer");
    assert_eq!(r.status(), 409);
    assert_eq!(r.json::<Value>().expect("json")["state"], "queued");
    assert_eq!(svc.get_json(&format!("/jobs/{active}"))["state"], "queued");

    assert_eq!(svc.get("/healthz").status(), 200);
    // The page's form, and the script behind it that submits to `/jobs` (the browser
    // tests drive both).
    let page = svc.get("/").text().expect("page");
    assert!(
        page.contains("<form") && page.contains("/static/list.js"),
        "{page}"
    );
    let script = svc.get("/static/list.js").text().expect("script");
    assert!(script.contains("/jobs"));
}
on_both!(bad_requests_get_json_errors_and_store_nothing);

fn a_killed_workers_tile_is_handed_out_again(backend: Backend) {
    let dir = TempDir::on(backend, "killed");
    let svc = Service::start(&dir, &["--local-workers", "0", "--lease-ms", "500"]);
    let scene = read("thesis.ray");
    let id = svc.submit_id(&scene, "?tile=64");
    let http = client();

    // A worker that claims a tile and dies before posting it: the test holds its lease.
    let r = svc.claim("doomed");
    assert_eq!(r.status(), 200);
    let dead: Value = r.json().expect("claim");

    // A real worker process, killed with SIGKILL once it has claimed.
    let mut a = Worker::start(&svc.url, "killed", &[]);
    common::wait_until("the worker's first claim", Duration::from_secs(30), || {
        svc.get_json("/workers").as_array().is_some_and(|ws| {
            ws.iter()
                .any(|w| w["name"] == "killed" && w["claims"].as_u64() > Some(0))
        })
    });
    a.kill9();

    let _b = Worker::start(&svc.url, "survivor", &[]);
    let done = svc.wait_finished(&id, JOB_TIME);
    assert_eq!(done["state"], "done", "{done}");
    assert!(svc.image(&id) == local_png(&examples().join("thesis.ray"), None, None));

    // The dead worker's late result is refused: its lease was handed to someone else.
    let rect = tessera_tracer::Rect::new(
        dead["x"].as_u64().expect("x") as u32,
        dead["y"].as_u64().expect("y") as u32,
        dead["w"].as_u64().expect("w") as u32,
        dead["h"].as_u64().expect("h") as u32,
    );
    let blob = tessera_protocol::encode_tile(rect, &vec![0; rect.pixel_count() * 3]);
    let r = http
        .put(format!(
            "{}/worker/jobs/{id}/tiles/{}?lease={}",
            svc.url,
            dead["idx"],
            dead["lease"].as_str().expect("lease")
        ))
        .body(blob)
        .send()
        .expect("answer");
    assert_eq!(r.status(), 409);
    // And the image is unchanged by it.
    assert!(svc.image(&id) == local_png(&examples().join("thesis.ray"), None, None));
}
on_both!(a_killed_workers_tile_is_handed_out_again);

/// A worker claims its next tile while the current one renders. Stopped with SIGTERM, it
/// must finish what it renders and give back the tile it holds ahead at once: with leases
/// far longer than the test, a tile left behind would be missing from what others can claim.
fn a_stopped_worker_gives_back_the_tile_it_claimed_ahead(backend: Backend) {
    let dir = TempDir::on(backend, "ahead");
    let svc = Service::start(&dir, &["--local-workers", "0", "--lease-ms", "600000"]);
    // 32 px tiles at 8×8 jitter: 300 tiles, each long enough (65,536 rays) that the worker
    // is nearly always mid-render with the next tile claimed and queued. (Stopped between
    // a claim and its answer instead, it gives that tile back on the way out; both are
    // checked the same way below.)
    let job = svc.submit(&read("thesis.ray"), "?tile=32&sampler=jitter&samples=8");
    let id = job["id"].as_str().expect("id").to_string();
    let total = job["tiles_total"].as_u64().expect("tiles_total");

    let mut w = Worker::start(&svc.url, "stopping", &[]);
    common::wait_until("a few tiles done", JOB_TIME, || {
        svc.get_json(&format!("/jobs/{id}"))["tiles_done"].as_u64() >= Some(4)
    });
    assert!(w.terminate().success(), "the worker exits cleanly");
    let done = svc.get_json(&format!("/jobs/{id}"))["tiles_done"]
        .as_u64()
        .expect("tiles_done");
    assert!(
        done < total,
        "the job finished before the worker was stopped"
    );

    // Every tile not done is claimable again right now: nothing is stranded under a lease.
    let mut claimed = std::collections::HashSet::new();
    loop {
        let r = svc.claim("probe");
        if r.status() == 204 {
            break;
        }
        assert_eq!(r.status(), 200);
        let c: Value = r.json().expect("claim");
        assert!(claimed.insert(c["idx"].as_u64().expect("idx")), "{c}");
    }
    assert_eq!(claimed.len() as u64, total - done);
}
on_both!(a_stopped_worker_gives_back_the_tile_it_claimed_ahead);

/// A stopping service's local workers give their tiles back after `--grace-secs` rather than
/// finishing them (the service image sets 8 s, before `docker stop`'s kill at 10 s), and the
/// tile is claimable at once after a restart, not stranded under its lease.
fn a_stopping_services_local_workers_give_back_their_tiles_after_the_grace(backend: Backend) {
    let dir = TempDir::on(backend, "grace");
    let lease = ["--lease-ms", "600000"];
    let mut svc = Service::start(
        &dir,
        &[&["--local-workers", "1", "--grace-secs", "0"][..], &lease].concat(),
    );
    // One tile of 640×480 pixels at 32×32 jitter: about 300 million rays, seconds of work
    // at the least (12 s on the development machine).
    let job = svc.submit(&read("thesis.ray"), "?tile=1024&sampler=jitter&samples=32");
    let id = job["id"].as_str().expect("id").to_string();
    common::wait_until("the local worker claims the tile", JOB_TIME, || {
        svc.get_json("/workers")
            .as_array()
            .is_some_and(|ws| ws.iter().any(|w| w["claims"].as_u64() > Some(0)))
    });
    let start = std::time::Instant::now();
    assert!(svc.terminate().success(), "the service exits cleanly");
    // With the default grace (30 s) the worker would have rendered on, and either finished
    // the tile (no give-back below) or given it back after 30 s.
    assert!(
        start.elapsed() < Duration::from_secs(20),
        "stopped after {:?}",
        start.elapsed()
    );
    assert!(svc.log().contains("giving the tile back"), "{}", svc.log());

    let svc = Service::start(&dir, &[&["--local-workers", "0"][..], &lease].concat());
    assert_eq!(svc.get_json(&format!("/jobs/{id}"))["tiles_done"], 0);
    let r = svc.claim("probe");
    assert_eq!(r.status(), 200, "the tile is claimable at once");
    assert_eq!(r.json::<Value>().expect("claim")["job"], id.as_str());
}
on_both!(a_stopping_services_local_workers_give_back_their_tiles_after_the_grace);

/// Tile sizes: a job's `?tile=` wins over `--tile`, which wins over the service's own pick;
/// whichever is used, the job's tiles cover its image exactly once.
fn tile_size_comes_from_the_job_then_the_flag_then_the_service(backend: Backend) {
    let scene = read("thesis.ray");
    let covers = |job: &Value| {
        let (w, h, t) = (
            job["width"].as_u64().expect("width"),
            job["height"].as_u64().expect("height"),
            job["tile"].as_u64().expect("tile"),
        );
        assert_eq!(
            job["tiles_total"].as_u64(),
            Some(w.div_ceil(t) * h.div_ceil(t)),
            "{job}"
        );
        t
    };
    let dir = TempDir::on(backend, "tileflag");
    let svc = Service::start(&dir, &["--local-workers", "0", "--tile", "48"]);
    assert_eq!(covers(&svc.submit(&scene, "")), 48);
    assert_eq!(covers(&svc.submit(&scene, "?tile=40")), 40);

    let dir = TempDir::on(backend, "tileauto");
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    // thesis.ray: 640×480 at one ray per pixel. 512 px tiles, the largest picked, would be
    // only 2 × 1 = 2 tiles and 256 px 3 × 2 = 6 (under 12), so 128 px: 5 × 4 = 20.
    assert_eq!(covers(&svc.submit(&scene, "")), 128);
    // With 8×8 jitter, 64² × 64 rays is the 262,144 a picked tile carries.
    assert_eq!(covers(&svc.submit(&scene, "?sampler=jitter&samples=8")), 64);
}
on_both!(tile_size_comes_from_the_job_then_the_flag_then_the_service);

fn a_job_can_be_waited_for(backend: Backend) {
    let dir = TempDir::on(backend, "wait");
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    let job = svc.submit(&read("checker.ray"), "");
    let id = job["id"].as_str().expect("job id").to_string();
    // Nothing renders it: the wait runs to its end and shows the job as it is.
    let start = std::time::Instant::now();
    let j = svc.get_json(&format!("/jobs/{id}?wait=0.3"));
    assert!(start.elapsed() >= Duration::from_millis(300), "waited");
    assert_eq!(j["state"], "queued");
    let bad = svc.get(&format!("/jobs/{id}?wait=-1"));
    assert_eq!(bad.status(), 400);

    // A long wait ends when the job does, whatever ends it: here a cancel.
    let url = format!("{}/jobs/{id}?wait=60", svc.url);
    let waiter = std::thread::spawn(move || {
        let t = std::time::Instant::now();
        let j: Value = client()
            .get(url)
            .send()
            .expect("answer")
            .json()
            .expect("json");
        (j, t.elapsed())
    });
    // The waiter is registered once its request is in; a cancel before that is also fine,
    // since the wait looks at the job before it waits.
    let r = client()
        .delete(format!("{}/jobs/{id}", svc.url))
        .send()
        .expect("answer");
    assert_eq!(r.status(), 200);
    let (j, took) = waiter.join().expect("waiter");
    assert_eq!(j["state"], "cancelled");
    assert!(
        took < Duration::from_secs(30),
        "answered at the end, not the limit"
    );
}
on_both!(a_job_can_be_waited_for);

/// The download is named after the job: a plain ASCII `filename` always, and the whole name
/// in `filename*` when it holds more than that; an empty `name=` names nothing.
fn downloads_are_named_after_their_job(backend: Backend) {
    let dir = TempDir::on(backend, "names");
    let svc = Service::start(&dir, &["--local-workers", "1"]);
    let scene = "[GLOBALS]\nwidth = 16\nheight = 16\n[/GLOBALS]\n";
    let named = svc.submit(scene, "?name=dir%2FStra%C3%9Fe%20%231.ray");
    assert_eq!(named["name"], "dir/Straße #1.ray");
    let unnamed = svc.submit(scene, "?name=");
    assert_eq!(unnamed["name"], Value::Null, "{unnamed}");
    let disposition = |job: &Value| {
        let id = job["id"].as_str().expect("job id");
        assert_eq!(svc.wait_finished(id, JOB_TIME)["state"], "done");
        let r = svc.get(&format!("/jobs/{id}/image.png"));
        assert_eq!(r.status(), 200);
        let cache = r.headers()["cache-control"].to_str().expect("ASCII header");
        assert!(
            cache.contains("immutable") && cache.contains("private"),
            "{cache}"
        );
        r.headers()["content-disposition"]
            .to_str()
            .expect("ASCII header")
            .to_string()
    };
    assert_eq!(
        disposition(&named),
        "inline; filename=\"Strae1.png\"; filename*=UTF-8''Stra%C3%9Fe%20#1.png"
    );
    let id = unnamed["id"].as_str().expect("job id");
    assert_eq!(
        disposition(&unnamed),
        format!("inline; filename=\"{id}.png\"")
    );
}
on_both!(downloads_are_named_after_their_job);

/// `GET /jobs` lists the newest first, a page at a time: `limit`, then `before` the last one
/// seen, until a page comes back short; every job once, in submission order reversed.
fn jobs_are_listed_newest_first_a_page_at_a_time(backend: Backend) {
    let dir = TempDir::on(backend, "pages");
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    let scene = "[GLOBALS]\nwidth = 8\nheight = 8\n[/GLOBALS]\n";
    let submitted: Vec<String> = (0..5).map(|_| svc.submit_id(scene, "")).collect();
    let ids = |page: &Value| -> Vec<String> {
        page.as_array()
            .expect("a list")
            .iter()
            .map(|j| j["id"].as_str().expect("id").to_string())
            .collect()
    };
    let mut listed = Vec::new();
    let mut query = "?limit=2".to_string();
    loop {
        let page = ids(&svc.get_json(&format!("/jobs{query}")));
        assert!(page.len() <= 2, "{page:?}");
        listed.extend(page.iter().cloned());
        match page.last() {
            Some(last) if page.len() == 2 => query = format!("?limit=2&before={last}"),
            _ => break,
        }
    }
    let newest_first: Vec<String> = submitted.iter().rev().cloned().collect();
    assert_eq!(listed, newest_first);
    assert_eq!(
        ids(&svc.get_json("/jobs")),
        newest_first,
        "no parameters: all of them"
    );

    assert_eq!(svc.get("/jobs?before=nosuchjob").status(), 404);
    for bad in ["?limit=0", "?limit=201", "?limit=x"] {
        assert_eq!(svc.get(&format!("/jobs{bad}")).status(), 400, "{bad}");
    }
}
on_both!(jobs_are_listed_newest_first_a_page_at_a_time);

/// The done tiles of job `id`, by index, with how often each was handed out.
fn stored_tiles(svc: &Service, id: &str) -> Vec<(u64, u64)> {
    let tiles = svc.get_json(&format!("/jobs/{id}/tiles"));
    tiles
        .as_array()
        .expect("tiles")
        .iter()
        .filter(|t| t["state"] == "done")
        .map(|t| {
            let n = |k: &str| t[k].as_u64().expect("a count");
            (n("idx"), n("attempts"))
        })
        .collect()
}

/// A worker's `POST /worker/jobs/{id}/tiles/{idx}/fail` for the tile a claim handed out.
fn report_failure(svc: &Service, claim: &Value, worker: &str) {
    let r = client()
        .post(format!(
            "{}/worker/jobs/{}/tiles/{}/fail?lease={}",
            svc.url,
            claim["job"].as_str().expect("a job"),
            claim["idx"],
            claim["lease"].as_str().expect("a lease")
        ))
        .json(&serde_json::json!({ "worker": worker, "reason": "out of paint" }))
        .send()
        .expect("an answer");
    assert_eq!(r.status(), 200);
}

/// Sends `SIGSTOP` or `SIGCONT` to a worker.
fn pause(worker: &Worker, sig: &str) {
    let status = std::process::Command::new("kill")
        .args([format!("-{sig}"), worker.pid().to_string()])
        .status()
        .expect("kill runs");
    assert!(status.success());
}

/// A failed job and a cancelled one keep the tiles they stored (across a restart, whose
/// sweep of the tile spool keeps them too) and are retried rendering only the others: no
/// stored tile is handed out again, and the PNG is `tessera-render`'s.
fn a_failed_or_cancelled_job_is_retried_rendering_only_what_is_missing(backend: Backend) {
    let dir = TempDir::on(backend, "retry");
    let args = ["--local-workers", "0", "--max-attempts", "1"];
    let mut svc = Service::start(&dir, &args);
    let scene = read("thesis.ray");
    let want = local_png(&examples().join("thesis.ray"), None, None);
    let retry = |svc: &Service, id: &str| {
        client()
            .post(format!("{}/jobs/{id}/retry", svc.url))
            .send()
            .expect("an answer")
    };
    let tiles_done = |svc: &Service, id: &str| {
        svc.get_json(&format!("/jobs/{id}"))["tiles_done"]
            .as_u64()
            .expect("a count")
    };
    assert_eq!(retry(&svc, "nosuchjob").status(), 404);

    // A job fails part-way: the test holds its first tile while a worker stores others,
    // then reports that tile failed (one attempt allowed).
    let failed = svc.submit_id(&scene, "?tile=64");
    let r = retry(&svc, &failed);
    assert_eq!(r.status(), 409);
    assert_eq!(r.json::<Value>().expect("json")["state"], "queued");
    let held: Value = svc.claim("holder").json().expect("a claim");
    assert_eq!(held["job"], failed.as_str());
    let mut worker = Worker::start(&svc.url, "renderer", &[]);
    // Half the image or more: the top rows of the scene are sky, whose tiles are alike.
    common::wait_until("tiles stored", JOB_TIME, || tiles_done(&svc, &failed) >= 40);
    report_failure(&svc, &held, "holder");
    let job = svc.wait_finished(&failed, JOB_TIME);
    assert_eq!(job["state"], "failed", "{job}");
    worker.kill9();

    // Across a restart: its stored tiles are still counted and listed.
    drop(svc);
    svc = Service::start(&dir, &args);
    let kept = stored_tiles(&svc, &failed);
    let job = svc.get_json(&format!("/jobs/{failed}"));
    assert!(!kept.is_empty() && kept.len() < 80, "{kept:?}");
    assert_eq!(job["tiles_done"].as_u64(), Some(kept.len() as u64));

    // Retried: active again with those tiles, its error gone; only the others render.
    let r = retry(&svc, &failed);
    assert_eq!(r.status(), 200);
    let job: Value = r.json().expect("json");
    assert_eq!(job["state"], "running", "{job}");
    assert_eq!(job["tiles_done"].as_u64(), Some(kept.len() as u64));
    assert!(job["error"].is_null(), "{job}");
    let worker = Worker::start(&svc.url, "renderer", &[]);
    let job = svc.wait_finished(&failed, JOB_TIME);
    assert_eq!(job["state"], "done", "{job}");
    assert!(svc.image(&failed) == want, "the retried PNG differs");
    let after = stored_tiles(&svc, &failed);
    assert_eq!(after.len(), 80);
    for tile in &kept {
        assert!(after.contains(tile), "tile {tile:?} was handed out again");
    }
    // A done job is not retried.
    let r = retry(&svc, &failed);
    assert_eq!(r.status(), 409);
    assert_eq!(r.json::<Value>().expect("json")["state"], "done");

    // A job cancelled part-way: the test holds one tile so that it cannot finish first.
    pause(&worker, "STOP");
    let cancelled = svc.submit_id(&scene, "?tile=64");
    let held: Value = svc.claim("holder").json().expect("a claim");
    assert_eq!(held["job"], cancelled.as_str());
    pause(&worker, "CONT");
    common::wait_until("tiles stored", JOB_TIME, || {
        tiles_done(&svc, &cancelled) >= 40
    });
    let r = client()
        .delete(format!("{}/jobs/{cancelled}", svc.url))
        .send()
        .expect("an answer");
    assert_eq!(r.status(), 200);
    assert_eq!(r.json::<Value>().expect("json")["state"], "cancelled");
    let kept = stored_tiles(&svc, &cancelled);
    assert!(!kept.is_empty() && kept.len() < 80, "{kept:?}");
    assert_eq!(tiles_done(&svc, &cancelled), kept.len() as u64);
    assert_eq!(retry(&svc, &cancelled).status(), 200);
    let job = svc.wait_finished(&cancelled, JOB_TIME);
    assert_eq!(job["state"], "done", "{job}");
    assert!(svc.image(&cancelled) == want, "the retried PNG differs");
    let after = stored_tiles(&svc, &cancelled);
    for tile in &kept {
        assert!(after.contains(tile), "tile {tile:?} was handed out again");
    }
}
on_both!(a_failed_or_cancelled_job_is_retried_rendering_only_what_is_missing);
