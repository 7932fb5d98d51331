//! Faults and hostile input against real processes: service restarts, killed workers, a
//! chaos run, limits, tokens and malformed tile blobs.
//!
//! The tests of what the queue does (restarts, leases, results, cancels, failures) run on
//! both backends (`NAME::sqlite`, `NAME::postgres`). The others run on SQLite only: what
//! they test (flags, limits, tokens, connections, workers against a fake service) does not
//! reach the database, or is SQLite's alone (its file lock, its tile spool, the local
//! workers of the one process on its file).

mod common;

use std::time::{Duration, Instant};

use common::{
    Backend, SERVICE, Service, TempDir, WORKER, Worker, client, examples, local_png, wait_until,
};
use serde_json::{Value, json};
use tessera_protocol::encode_tile;
use tessera_tracer::Rect;

const JOB_TIME: Duration = Duration::from_secs(180);

fn read(name: &str) -> String {
    std::fs::read_to_string(examples().join(name)).expect("example readable")
}

/// A loopback address with a port free right now, so a restarted service can reuse it.
fn free_addr() -> String {
    let l = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    l.local_addr().expect("addr").to_string()
}

/// A `size`² scene whose every sample is slow: the eye inside a mirrored sphere, each sample
/// bouncing 64 times with a shadow ray each time.
fn mirror_cave(size: u32, samples: u32) -> String {
    format!(
        "[GLOBALS]\nwidth = {size}\nheight = {size}\nsampler = jitter\nsamples = {samples}\n\
         max_depth = 64\n[/GLOBALS]\n[CAMERA]\neye = <0, 0, 0>\nlook_at = <0, 0, -1>\n\
         [/CAMERA]\n[LIGHT]\nposition = <0, 1, 0>\n[/LIGHT]\n\
         [OBJECT]\ntype = sphere\nradius = 50\nmirror = 0.9\n[/OBJECT]\n"
    )
}

/// Waits until a worker has claimed a tile of job `id` (the job is running).
fn wait_claimed(svc: &Service, id: &str) {
    wait_until("a tile to be claimed", Duration::from_secs(60), || {
        svc.get_json(&format!("/jobs/{id}"))["state"] == "running"
    });
}

fn tiles_done(svc: &Service, id: &str) -> u64 {
    svc.get_json(&format!("/jobs/{id}"))["tiles_done"]
        .as_u64()
        .unwrap_or(0)
}

fn jobs_survive_service_restarts_and_workers_ride_through(backend: Backend) {
    let dir = TempDir::on(backend, "restart");
    let addr = free_addr();
    let args = ["--local-workers", "0", "--lease-ms", "2000"];
    let mut svc = Service::start_on(&dir, &addr, &args);
    let url = svc.url.clone();
    let small = svc.submit_id(&read("checker.ray"), "");
    let big = svc.submit_id(&read("thesis.ray"), "?tile=16");
    let _w1 = Worker::start(&url, "w1", &[]);
    let _w2 = Worker::start(&url, "w2", &[]);
    assert_eq!(svc.wait_finished(&small, JOB_TIME)["state"], "done");
    let small_png = svc.image(&small);

    // SIGKILL mid-job, then start again on the same file and address.
    wait_until("progress on the big job", JOB_TIME, || {
        tiles_done(&svc, &big) > 50
    });
    svc.kill();
    svc = Service::start_on(&dir, &addr, &args);
    let before = tiles_done(&svc, &big);
    assert!(before > 0, "tiles stored before the crash survive it");
    // SIGTERM mid-job: a clean stop, and again a restart.
    wait_until("more progress", JOB_TIME, || {
        tiles_done(&svc, &big) > before + 50
    });
    assert!(svc.terminate().success());
    svc = Service::start_on(&dir, &addr, &args);

    // The workers were never restarted: they rode through both outages.
    let done = svc.wait_finished(&big, JOB_TIME);
    assert_eq!(done["state"], "done", "{done}");
    assert!(svc.image(&big) == local_png(&examples().join("thesis.ray"), None, None));
    assert!(
        svc.image(&small) == small_png,
        "a finished image survives restarts"
    );
}
on_both!(jobs_survive_service_restarts_and_workers_ride_through);

/// A service killed (SIGKILL, out of memory) with its local workers rendering: started
/// again, it requeues the tiles they held at once and charges nothing, since they died with
/// it. It extended their leases like any worker's and then charged each as a stall: four
/// crashes during one big tile failed the job, blaming a worker. Remote workers' leases are
/// still extended, for workers that ride through a restart.
#[test]
fn a_restarted_service_requeues_its_dead_local_workers_tiles_uncharged() {
    let dir = TempDir::new("local-crash");
    let addr = free_addr();
    let mut svc = Service::start_on(
        &dir,
        &addr,
        &[
            "--local-workers",
            "1",
            "--lease-ms",
            "60000",
            "--max-attempts",
            "1",
        ],
    );
    // Four tiles: the local worker renders one (and may hold one ahead), a remote worker
    // (the test) holds another.
    let id = svc.submit_id(&mirror_cave(128, 32), "?tile=64");
    wait_claimed(&svc, &id);
    let remote: Value = svc.claim("remote").json().expect("a claim");
    svc.kill();
    // No local workers now: the test claims as a worker would.
    svc = Service::start_on(
        &dir,
        &addr,
        &["--local-workers", "0", "--max-attempts", "1"],
    );
    assert!(
        svc.log().contains("tiles held by the local workers"),
        "{}",
        svc.log()
    );
    // Every tile but the remote worker's is free at once: the dead local worker's, and
    // those it never claimed. The remote worker's lease is extended, not taken.
    let mut free = Vec::new();
    loop {
        let c = svc.claim("after");
        if c.status() != 200 {
            assert_eq!(c.status(), 204);
            break;
        }
        let c: Value = c.json().expect("claim");
        assert_eq!(c["job"].as_str(), Some(id.as_str()));
        free.push(c["idx"].as_u64().expect("idx"));
    }
    free.sort_unstable();
    let held = remote["idx"].as_u64().expect("idx");
    assert_eq!(free, (0..4).filter(|&i| i != held).collect::<Vec<_>>());
    let renewed = client()
        .post(format!(
            "{}/worker/jobs/{id}/tiles/{held}/renew?lease={}",
            svc.url,
            remote["lease"].as_str().expect("lease")
        ))
        .send()
        .expect("answered");
    assert_eq!(
        renewed.status(),
        200,
        "the remote worker's lease is still good"
    );
    let job = svc.get_json(&format!("/jobs/{id}"));
    assert_eq!(job["state"], "running", "{job}");
}

fn chaos_killed_workers_and_a_restarted_service_still_give_the_exact_image(backend: Backend) {
    let dir = TempDir::on(backend, "chaos");
    let addr = free_addr();
    let args = [
        "--local-workers",
        "0",
        "--lease-ms",
        "400",
        "--max-attempts",
        "20",
    ];
    let mut svc = Service::start_on(&dir, &addr, &args);
    let url = svc.url.clone();
    let id = svc.submit_id(&read("mirrors.ray"), "?tile=16");
    let total = svc.get_json(&format!("/jobs/{id}"))["tiles_total"]
        .as_u64()
        .unwrap_or(0);
    let mut workers: Vec<Worker> = (0..3)
        .map(|i| Worker::start(&url, &format!("c{i}"), &[]))
        .collect();
    // A fixed-seed schedule of SIGKILLs and fresh workers; the service restarts once,
    // half-way through.
    let mut rng = 0x2545_F491_4F6C_DD1Du64;
    let mut next = || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        rng
    };
    let deadline = Instant::now() + JOB_TIME;
    let mut restarted = false;
    let mut spawned = 3;
    loop {
        let job = svc.get_json(&format!("/jobs/{id}"));
        let state = job["state"].as_str().unwrap_or("").to_string();
        if state != "queued" && state != "running" {
            assert_eq!(state, "done", "{job}");
            break;
        }
        assert!(
            Instant::now() < deadline,
            "chaos run did not finish: {job}\n{}",
            svc.log()
        );
        let done = job["tiles_done"].as_u64().unwrap_or(0);
        if !restarted && done * 2 >= total {
            svc.kill();
            svc = Service::start_on(&dir, &addr, &args);
            restarted = true;
        }
        // The chaos schedule: this pause is the interval between faults, not a wait for a
        // result.
        std::thread::sleep(Duration::from_millis(50 + next() % 200));
        let victim = (next() % workers.len() as u64) as usize;
        workers[victim].kill9();
        workers[victim] = Worker::start(&url, &format!("c{spawned}"), &[]);
        spawned += 1;
    }
    assert!(restarted, "the service was restarted during the run");
    assert!(spawned > 3, "workers were killed during the run");
    assert!(svc.image(&id) == local_png(&examples().join("mirrors.ray"), None, None));
}
on_both!(chaos_killed_workers_and_a_restarted_service_still_give_the_exact_image);

/// A worker restarted under its fixed name (a container, a systemd unit) and killed again and
/// again loses its leases each time: stalls, charged to the tile it held but never keeping
/// the worker away. Counted as failures, the second kill kept the name away and failed the
/// job ("every available worker failed this job") with its rendered tiles thrown away.
fn a_worker_killed_again_and_again_is_not_kept_away(backend: Backend) {
    let dir = TempDir::on(backend, "churn");
    let svc = Service::start(
        &dir,
        &[
            "--local-workers",
            "0",
            "--lease-ms",
            "500",
            "--keep-away-after",
            "2",
            "--max-attempts",
            "10",
        ],
    );
    let id = svc.submit_id(&read("thesis.ray"), "?tile=64");
    let reaps = || {
        svc.log()
            .matches("expired leases: tiles handed out again")
            .count()
    };
    // Four lives of the worker, each claiming a tile and vanishing (as a SIGKILL leaves it);
    // each lease runs out a lease or more after the last, so each is a stall of its own.
    for life in 0..4 {
        let before = reaps();
        let r = svc.claim("churn");
        assert_eq!(r.status(), 200, "life {life}: kept away?\n{}", svc.log());
        wait_until(
            "the lost lease to be reaped",
            Duration::from_secs(60),
            || reaps() > before,
        );
        let job = svc.get_json(&format!("/jobs/{id}"));
        assert_eq!(job["state"], "running", "life {life}: {job}");
    }
    // The name's next life renders the whole job, exactly.
    let _w = Worker::start(&svc.url, "churn", &[]);
    let job = svc.wait_finished(&id, JOB_TIME);
    assert_eq!(job["state"], "done", "{job}\n{}", svc.log());
    assert!(svc.image(&id) == local_png(&examples().join("thesis.ray"), None, None));
}
on_both!(a_worker_killed_again_and_again_is_not_kept_away);

/// A worker killed while its service was down never renews: after the restart its lease
/// runs only for the restart's grace (half of this 12 s lease), so its tile is handed out
/// again well before a full lease. With a fresh term for every lease, the job waited a
/// whole lease more for a worker that was gone.
fn a_dead_workers_lease_is_reaped_after_the_restart_grace(backend: Backend) {
    let dir = TempDir::on(backend, "restart-grace");
    let addr = free_addr();
    let args = ["--local-workers", "0", "--lease-ms", "12000"];
    let mut svc = Service::start_on(&dir, &addr, &args);
    // One slow tile, so the worker is still rendering it when the service goes.
    let id = svc.submit_id(&mirror_cave(256, 32), "?tile=256");
    let mut w = Worker::start(&svc.url, "dies-in-the-outage", &[]);
    wait_claimed(&svc, &id);
    svc.kill();
    w.kill9();
    let restarted = Instant::now();
    let svc = Service::start_on(&dir, &addr, &args);
    wait_until("the dead worker's tile handed out again", JOB_TIME, || {
        svc.claim("next").status() == 200
    });
    let took = restarted.elapsed();
    assert!(
        took < Duration::from_millis(11_000),
        "handed out again {took:?} after the restart\n{}",
        svc.log()
    );
}
on_both!(a_dead_workers_lease_is_reaped_after_the_restart_grace);

#[test]
fn limits_refuse_oversized_input_and_store_nothing() {
    let dir = TempDir::new("limits");
    let svc = Service::start(
        &dir,
        &[
            "--local-workers",
            "0",
            "--max-body-bytes",
            "1048576",
            "--max-pixels",
            "10000",
            "--max-objects",
            "3",
            "--max-csg-depth",
            "2",
            "--max-texture-pixels",
            "4096",
            "--max-scene-texture-pixels",
            "6000",
            "--max-tiles",
            "10",
        ],
    );
    let http = client();
    let post = |body: Vec<u8>| {
        http.post(format!("{}/jobs", svc.url))
            .body(body)
            .send()
            .expect("answer")
    };
    let mut huge = b"# padding\n".repeat(120_000);
    huge.extend_from_slice(read("thesis.ray").as_bytes());
    let r = post(huge);
    assert_eq!(r.status(), 413);
    assert!(r.json::<Value>().expect("JSON 413")["error"].is_string());
    // A body declared over the limit is refused on its headers, before a byte of it is
    // sent (the service had read up to the limit first): here none ever is.
    for path in ["/jobs", "/worker/jobs/j/tiles/0?lease=l"] {
        use std::io::{Read, Write};
        let mut s =
            std::net::TcpStream::connect(svc.url.trim_start_matches("http://")).expect("connect");
        s.set_read_timeout(Some(Duration::from_secs(20)))
            .expect("timeout");
        let method = if path == "/jobs" { "POST" } else { "PUT" };
        write!(
            s,
            "{method} {path} HTTP/1.1\r\nHost: x\r\nContent-Length: 200000000\r\n\r\n"
        )
        .expect("write");
        let mut answer = [0u8; 512];
        let n = s.read(&mut answer).expect("an answer without the body");
        let answer = String::from_utf8_lossy(&answer[..n]);
        assert!(
            answer.starts_with("HTTP/1.1 413") && answer.contains("the limit is"),
            "{path}: {answer}"
        );
    }
    // A chunked body (no declared length) one byte over the limit: the same kind of JSON
    // message with the limit in it, not the extractor's "length limit exceeded". Exactly
    // limit + 1 bytes are sent, so the service has read all of them when it answers (unread
    // bytes at its close could reset the connection before the answer is read).
    let tile_limit = tessera_service::protocol_limit();
    for (method, path, limit) in [
        ("POST", "/jobs", 1_048_576usize),
        ("PUT", "/worker/jobs/j/tiles/0?lease=l", tile_limit),
    ] {
        use std::io::{Read, Write};
        let mut s =
            std::net::TcpStream::connect(svc.url.trim_start_matches("http://")).expect("connect");
        s.set_read_timeout(Some(Duration::from_secs(20)))
            .expect("timeout");
        write!(
            s,
            "{method} {path} HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n"
        )
        .expect("write");
        let chunk = vec![b'#'; 65536];
        let mut left = limit + 1;
        while left > 0 {
            let n = left.min(chunk.len());
            write!(s, "{n:x}\r\n").expect("write");
            s.write_all(&chunk[..n]).expect("write");
            s.write_all(b"\r\n").expect("write");
            left -= n;
        }
        let mut answer = Vec::new();
        let _ = s.read_to_end(&mut answer);
        let answer = String::from_utf8_lossy(&answer);
        assert!(
            answer.starts_with("HTTP/1.1 413")
                && answer.contains(&format!("over the limit of {limit} bytes")),
            "{path}: {answer}"
        );
    }

    let r = post(b"[GLOBALS]\nwidth = 200\nheight = 200\n[/GLOBALS]\n".to_vec());
    assert_eq!(r.status(), 400);

    let sphere = "[OBJECT]\ntype = sphere\nradius = 1\n[/OBJECT]\n";
    let r = post(
        format!(
            "[GLOBALS]\nwidth = 8\nheight = 8\n[/GLOBALS]\n{}",
            sphere.repeat(4)
        )
        .into_bytes(),
    );
    assert_eq!(r.status(), 400);
    let e: Value = r.json().expect("json");
    assert!(e["line"].is_u64(), "{e}");

    let nested = format!(
        "[GLOBALS]\nwidth = 8\nheight = 8\n[/GLOBALS]\n[CSG]\nop = union\n[CSG]\nop = union\n[CSG]\nop = union\n{sphere}{sphere}[/CSG]\n[/CSG]\n[/CSG]\n"
    );
    assert_eq!(post(nested.into_bytes()).status(), 400);

    // A black PNG of `w × h` texels.
    let black_png = |w: u32, h: u32| {
        let sink = tessera_tracer::SharedBuffer::new();
        let mut enc = png::Encoder::new(sink.clone(), w, h);
        enc.set_color(png::ColorType::Rgb);
        enc.set_compression(png::Compression::High);
        let mut out = enc
            .write_header()
            .expect("header")
            .into_stream_writer()
            .expect("stream");
        let row = vec![0u8; w as usize * 3];
        for _ in 0..h {
            std::io::Write::write_all(&mut out, &row).expect("row");
        }
        out.finish().expect("finish");
        sink.take()
    };
    let with_textures = |textures: Vec<(&str, Vec<u8>)>| {
        let mut scene = String::from("[GLOBALS]\nwidth = 8\nheight = 8\n[/GLOBALS]\n");
        let mut form = reqwest::blocking::multipart::Form::new();
        for (name, bytes) in textures {
            scene.push_str(&format!(
                "[OBJECT]\ntype = sphere\nradius = 1\ntexture = {name}\n[/OBJECT]\n"
            ));
            form = form.part(
                name.to_string(),
                reqwest::blocking::multipart::Part::bytes(bytes).file_name(name.to_string()),
            );
        }
        http.post(format!("{}/jobs", svc.url))
            .multipart(form.text("scene", scene))
            .send()
            .expect("answer")
    };
    // A decompression bomb: a small PNG that claims 8192 × 8192 texels, refused with the
    // size its header gives (it is not decoded).
    let bomb = black_png(8192, 8192);
    assert!(
        bomb.len() < 1_000_000,
        "the bomb is small: {} bytes",
        bomb.len()
    );
    common::refused(with_textures(vec![("bomb.png", bomb)]), "8192×8192 texels");
    // Two textures each within the limit (64 × 64 = 4096 texels), together over the scene's
    // 6000: the second is refused, at its name (line 13 of the scene the closure writes:
    // four lines of globals, then five per object, the name fourth).
    let e = common::refused(
        with_textures(vec![
            ("a.png", black_png(64, 64)),
            ("b.png", black_png(64, 64)),
        ]),
        "the limit is 6000 in all",
    );
    assert_eq!(common::line_col(&e), (Some(13), Some(11)), "{e}");

    // Too many tiles asked for: refused with the smallest edge that makes at most 10
    // (`⌈100/e⌉² ≤ 10` needs `⌈100/e⌉ ≤ 3`, so `e ≥ 34`).
    let hundred = |query: &str| {
        http.post(format!("{}/jobs{query}", svc.url))
            .body(format!(
                "[GLOBALS]\nwidth = 100\nheight = 100\n[/GLOBALS]\n{sphere}"
            ))
            .send()
            .expect("answer")
    };
    let r = hundred("?tile=8");
    assert_eq!(r.status(), 400);
    let e: Value = r.json().expect("json");
    assert_eq!(e["max_tiles"], 10, "{e}");
    assert_eq!(e["min_tile"], 34, "{e}");
    assert!(e["error"].as_str().unwrap_or("").contains("tile=34"), "{e}");

    assert_eq!(svc.get_json("/jobs"), json!([]), "nothing stored");

    let r = hundred("?tile=34");
    assert_eq!(r.status(), 201, "the smallest edge that fits is taken");
    assert_eq!(r.json::<Value>().expect("json")["tiles_total"], 9);
    // A job that asks for no size gets the service's pick grown to that edge: the pick (32 px
    // here) is the service's choice, not the job's, so it must not be refused as the job's.
    let r = hundred("");
    assert_eq!(r.status(), 201);
    let job: Value = r.json().expect("json");
    assert_eq!(
        (job["tile"].as_i64(), job["tiles_total"].as_i64()),
        (Some(34), Some(9)),
        "{job}"
    );
}

/// A job that asks for no tile size, on an image that even the largest tiles cut into more
/// than `--max-tiles`: the refusal counts the largest edge's tiles, not those of a pick the
/// job never asked for.
#[test]
fn an_image_too_large_for_any_tile_is_refused_for_the_largest() {
    let dir = TempDir::new("maxtiles");
    let svc = Service::start(&dir, &["--local-workers", "0", "--max-tiles", "2"]);
    let r = reqwest::blocking::Client::new()
        .post(format!("{}/jobs", svc.url))
        .body(
            "[GLOBALS]\nwidth = 3000\nheight = 8\n[/GLOBALS]\n\
             [OBJECT]\ntype = sphere\nradius = 1\n[/OBJECT]\n",
        )
        .send()
        .expect("answer");
    assert_eq!(r.status(), 400);
    let e: Value = r.json().expect("json");
    // The service's own pick for 3000×8 is 256 px, 12 tiles, which the message named.
    assert_eq!(e["tiles"], 3, "3 × 1 tiles of 1024 px: {e}");
    let msg = e["error"].as_str().unwrap_or("");
    assert!(
        msg.contains("tiles of 1024 px") && msg.contains("no tile edge up to 1024"),
        "{e}"
    );
    assert_eq!(svc.get_json("/jobs"), json!([]), "nothing stored");
}

#[test]
fn tokens_guard_worker_routes_and_submission() {
    let dir = TempDir::new("tokens");
    let svc = Service::start(
        &dir,
        &[
            "--local-workers",
            "0",
            "--token",
            "w-secret",
            "--submit-token",
            "s-secret",
        ],
    );
    let http = client();
    let claim = |token: Option<&str>| {
        let mut r = http
            .post(format!("{}/worker/claim", svc.url))
            .json(&json!({"worker": "t"}));
        if let Some(t) = token {
            r = r.bearer_auth(t);
        }
        r.send().expect("answer").status()
    };
    assert_eq!(claim(None), 401);
    assert_eq!(claim(Some("w-secreT")), 401);
    assert_eq!(
        claim(Some("s-secret")),
        401,
        "the submit token is not a worker token"
    );
    assert_eq!(claim(Some("w-secret")), 204);

    let scene = read("checker.ray");
    let r = http
        .post(format!("{}/jobs", svc.url))
        .body(scene.clone())
        .send()
        .expect("answer");
    assert_eq!(r.status(), 401);
    assert!(r.json::<Value>().expect("json")["error"].is_string());
    assert_eq!(svc.get_json("/jobs"), json!([]));
    let r = http
        .post(format!("{}/jobs", svc.url))
        .bearer_auth("s-secret")
        .body(scene)
        .send()
        .expect("answer");
    assert_eq!(r.status(), 201);
    let id = r.json::<Value>().expect("json")["id"]
        .as_str()
        .expect("id")
        .to_string();
    assert_eq!(
        svc.get(&format!("/jobs/{id}")).status(),
        200,
        "reading stays open"
    );
    let r = http
        .delete(format!("{}/jobs/{id}", svc.url))
        .send()
        .expect("answer");
    assert_eq!(r.status(), 401);

    // A worker with the wrong token stops with an error instead of polling forever.
    let mut bad = Worker::start(&svc.url, "bad", &["--token", "nope"]);
    wait_until(
        "the refused worker to exit",
        Duration::from_secs(30),
        || bad.try_wait().is_some(),
    );
    assert!(!bad.try_wait().expect("exited").success());
    // One with none is told that a token is wanted, not that its token was refused.
    let mut none = std::process::Command::new(WORKER)
        .args(["--server", &svc.url, "--threads", "1"])
        .env_remove("TESSERA_WORKER_TOKEN")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("worker starts");
    wait_until(
        "the worker without a token to exit",
        Duration::from_secs(30),
        || none.try_wait().is_ok_and(|s| s.is_some()),
    );
    let mut said = String::new();
    std::io::Read::read_to_string(&mut none.stderr.take().expect("piped"), &mut said)
        .expect("stderr");
    assert!(said.contains("requires a worker token"), "{said}");
    // The right token renders the job.
    let _good = Worker::start(&svc.url, "good", &["--token", "w-secret"]);
    assert_eq!(svc.wait_finished(&id, JOB_TIME)["state"], "done");
}

#[test]
fn an_open_service_beyond_loopback_must_be_asked_for() {
    let dir = TempDir::new("open");
    let out = std::process::Command::new(SERVICE)
        .args([
            "--listen",
            "0.0.0.0:0",
            "--local-workers",
            "0",
            "--database",
        ])
        .arg(format!("sqlite://{}", dir.path().join("t.db").display()))
        .output()
        .expect("runs");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--submit-token"));
}

/// One service per database: a second one on the same file refuses to start, before it
/// touches the queue (touching it would requeue the first's local workers' tiles as if theirs
/// had ended), and the first keeps serving. The lock goes with the process however it ends: after
/// a SIGKILL the next service starts.
#[test]
fn a_second_service_on_the_same_database_refuses_to_start() {
    let dir = TempDir::new("second");
    let mut first = Service::start(&dir, &["--local-workers", "1"]);
    let id = first.submit_id(&read("checker.ray"), "?tile=16");
    let log = dir.path().join("second.log");
    let mut second = std::process::Command::new(SERVICE)
        .args([
            "--listen",
            "127.0.0.1:0",
            "--local-workers",
            "1",
            "--database",
        ])
        .arg(format!("sqlite://{}", first.db.display()))
        .stdout(std::process::Stdio::null())
        .stderr(std::fs::File::create(&log).expect("log file"))
        .spawn()
        .expect("runs");
    let status = common::wait_exit(&mut second, Duration::from_secs(30));
    if status.is_none() {
        let _ = second.kill();
    }
    let stderr = std::fs::read_to_string(&log).unwrap_or_default();
    assert_eq!(status.and_then(|s| s.code()), Some(1), "{stderr}");
    assert!(
        stderr.contains("one service per database")
            && stderr.contains("-service.lock")
            && !stderr.contains("requeued"),
        "{stderr}"
    );
    let job = first.wait_finished(&id, Duration::from_secs(60));
    assert_eq!(job["state"], "done", "{job}");
    first.kill();
    let third = Service::start(&dir, &["--local-workers", "0"]);
    assert_eq!(third.get_json(&format!("/jobs/{id}"))["state"], "done");
}

/// A thread count past `MAX_THREADS` is refused before anything starts (a mistyped
/// `--threads 100000` exhausted the process's threads).
#[test]
fn thread_counts_are_bounded() {
    let max = tessera_tracer::MAX_THREADS;
    let dir = TempDir::new("threads");
    let db = format!("sqlite://{}", dir.path().join("t.db").display());
    let refused = |program: &str, args: &[&str], flag: &str| {
        let out = std::process::Command::new(program)
            .args(args)
            .output()
            .expect("runs");
        assert!(!out.status.success());
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(
            stderr.contains(flag) && stderr.contains(&format!("..={max}")),
            "{stderr}"
        );
    };
    let over = (max + 1).to_string();
    refused(
        SERVICE,
        &["--local-workers", &over, "--database", &db],
        "--local-workers",
    );
    refused(WORKER, &["--threads", &over], "--threads");
    refused(WORKER, &["--threads", "0"], "--threads");
}

/// The service's numeric flags out of range exit with status 2 and clap's message naming
/// the flag and its range, as docs/OPERATIONS.md says of every flag: one refusal per flag,
/// with the usage status, not a message of the service's own.
#[test]
fn service_flags_out_of_range_are_usage_errors() {
    let dir = TempDir::new("flags");
    let db = format!("sqlite://{}", dir.path().join("t.db").display());
    for (flag, value, range) in [
        ("--tile", "7", "8..=1024"),
        ("--tile", "2000", "8..=1024"),
        ("--lease-ms", "99", "100.."),
        ("--max-attempts", "0", "1.."),
        ("--max-tiles", "0", "1.."),
        // Scene limits go up to the workers' own, which would refuse more.
        ("--max-csg-depth", "65", "1..=64"),
        ("--max-objects", "1000001", "1..=1000000"),
        ("--max-textures", "257", "0..=256"),
        ("--max-dimension", "32769", "1..=32768"),
        ("--max-pixels", "268435457", "1..=268435456"),
        ("--max-texture-pixels", "67108865", "1..=67108864"),
        ("--max-scene-texture-pixels", "134217729", "1..=134217728"),
        // An empty token locked out every worker (the local ones too) while the service
        // looked healthy; an empty database path failed with "no such table: jobs".
        ("--token", "", "may not be empty"),
        ("--submit-token", "", "may not be empty"),
        // HTTP trims the header that carries it: as locked out as an empty one.
        ("--token", " ", "white space"),
        ("--submit-token", "abc\t", "white space"),
        ("--database", "sqlite://", "sqlite://PATH"),
        ("--database", "sqlite:?mode=rwc", "sqlite://PATH"),
        // Values past any use overflowed the clock's arithmetic: every connection panicked
        // (idle timeout), a lease read as expired at once (lease), a stop panicked (grace).
        ("--lease-ms", "86400001", "100..=86400000"),
        ("--idle-timeout-secs", "86401", "1..=86400"),
        ("--grace-secs", "86401", "0..=86400"),
        ("--keep-away-secs", "604801", "0..=604800"),
        // The largest submission could never be received.
        ("--max-receiving-bytes", "1000", "at least --max-body-bytes"),
        // A service that refuses every submission, and a keep-away after no failure at all
        // (zero must not be read as one).
        ("--max-body-bytes", "0", "1.."),
        ("--keep-away-after", "0", "1.."),
        // Found only when the service tried to listen (exit 1).
        ("--listen", "foo", "HOST:PORT"),
        ("--listen", "http://127.0.0.1:8080", "HOST:PORT"),
        ("--listen", "foo bar:8080", "HOST:PORT"),
    ] {
        usage_error(
            SERVICE,
            &[flag, value, "--local-workers", "0", "--database", &db],
            range,
        );
    }
    // A token the service refuses is not printed back (clap's own refusal repeated it),
    // nor one that no header could carry.
    for (flag, token) in [("--token", " s3cret"), ("--submit-token", "s3\u{7}cret")] {
        let stderr = usage_refusal(
            SERVICE,
            &[flag, token, "--local-workers", "0", "--database", &db],
        );
        assert!(
            stderr.contains(flag) && !stderr.contains("s3"),
            "{flag}: {stderr}"
        );
    }
    for blank in ["", " "] {
        usage_error(
            SERVICE,
            &["--database", blank, "--local-workers", "0"],
            "sqlite://PATH",
        );
    }
    // The worker's: a name the service would refuse, an idle pause of nothing (a tight
    // polling loop) or of ages, a grace past any use, a service URL it cannot use, all
    // found at start, before any service is reached.
    for (flag, value, says) in [
        ("--name", "", "1 to 200 bytes"),
        ("--name", &"n".repeat(201), "1 to 200 bytes"),
        ("--idle-max-ms", "0", "25.."),
        ("--idle-max-ms", "60001", "25..=60000"),
        ("--grace-secs", "86401", "0..=86400"),
        // Not a URL, or https, which this build cannot speak: a worker would retry for ever.
        ("--server", "notaurl", "http://HOST:PORT"),
        ("--server", "https://127.0.0.1:1", "plain HTTP"),
        // A password would go to the service in clear and into the log; a query would be
        // merged into every request's; white space would be dropped without a word.
        (
            "--server",
            "http://user:secret@127.0.0.1:1",
            "no user name or password",
        ),
        (
            "--server",
            "http://127.0.0.1:1/?x=1",
            "no ?query or #fragment",
        ),
        (
            "--server",
            "http://127.0.0.1:1/#f",
            "no ?query or #fragment",
        ),
        ("--server", " http://127.0.0.1:1", "white space"),
        // Sent with its spaces, and refused by the service whose token it was.
        ("--token", " secret", "white space"),
    ] {
        let args: &[&str] = if flag == "--server" {
            &[flag, value]
        } else {
            &[flag, value, "--server", "http://127.0.0.1:1"]
        };
        usage_error(WORKER, args, says);
    }
    // No refusal repeats a password or a token, whatever it refuses the URL for.
    for args in [
        ["--server", "http://user:secret@127.0.0.1:1"],
        ["--server", "https://user:secret@127.0.0.1:1"],
        ["--server", " http://user:secret@127.0.0.1:1"],
        ["--server", "http://user:secret@no host"],
        ["--token", " secret"],
        ["--token", "sec\nret"],
    ] {
        let stderr = usage_refusal(WORKER, &args);
        assert!(
            !stderr.contains("secret") && !stderr.contains("sec\nret"),
            "{args:?}: {stderr}"
        );
    }
}

/// Runs `program` with `args`, whose first is a flag given a value out of its range: clap's
/// usage error (status 2) naming the flag and saying `says`.
#[track_caller]
fn usage_error(program: &str, args: &[&str], says: &str) {
    let stderr = usage_refusal(program, args);
    assert!(
        stderr.contains(args[0]) && stderr.contains(says),
        "{args:?}: {stderr}"
    );
}

/// Runs `program` with `args`, which it must refuse with clap's usage status (2), and
/// returns what it said.
#[track_caller]
fn usage_refusal(program: &str, args: &[&str]) -> String {
    let out = std::process::Command::new(program)
        .args(args)
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
    stderr
}

fn tile_blobs_are_checked_before_they_are_stored(backend: Backend) {
    let dir = TempDir::on(backend, "blobs");
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    let id = svc.submit_id(&read("checker.ray"), "?tile=32");
    let http = client();
    let c: Value = svc.claim("t").json().expect("claim");
    let u = |k: &str| c[k].as_u64().expect("number") as u32;
    let rect = Rect::new(u("x"), u("y"), u("w"), u("h"));
    let put = |lease: &str, body: Vec<u8>| {
        http.put(format!(
            "{}/worker/jobs/{id}/tiles/{}?lease={lease}",
            svc.url, c["idx"]
        ))
        .body(body)
        .send()
        .expect("answer")
    };
    let lease = c["lease"].as_str().expect("lease");
    let good = vec![9u8; rect.pixel_count() * 3];
    assert_eq!(
        put(lease, encode_tile(rect, &good[1..])).status(),
        422,
        "short"
    );
    let mut long = good.clone();
    long.push(0);
    assert_eq!(put(lease, encode_tile(rect, &long)).status(), 422, "long");
    let other = Rect::new(rect.x + 32, rect.y, rect.width, rect.height);
    let wrong = put(lease, encode_tile(other, &good));
    assert_eq!(wrong.status(), 422, "wrong tile");
    // Both rectangles, as a person reads them (size, then the top-left pixel).
    let message = wrong.json::<Value>().expect("json")["error"]
        .as_str()
        .expect("message")
        .to_string();
    let shown = |r: Rect| format!("{}×{} at ({}, {})", r.width, r.height, r.x, r.y);
    assert!(
        message.contains(&shown(other)) && message.contains(&shown(rect)),
        "{message}"
    );
    assert_eq!(put(lease, b"garbage".to_vec()).status(), 422, "no header");
    assert_eq!(
        put("someone-else", encode_tile(rect, &good)).status(),
        409,
        "not the lease"
    );
    assert_eq!(tiles_done(&svc, &id), 0, "nothing refused was stored");

    let r = put(lease, encode_tile(rect, &good));
    assert_eq!(r.status(), 200);
    assert_eq!(r.json::<Value>().expect("json")["repeat"], false);
    let r = put(lease, encode_tile(rect, &good));
    assert_eq!(r.status(), 200);
    assert_eq!(r.json::<Value>().expect("json")["repeat"], true);
    assert_eq!(tiles_done(&svc, &id), 1, "the repeat changed nothing");
}
on_both!(tile_blobs_are_checked_before_they_are_stored);

fn a_result_can_carry_the_next_claim(backend: Backend) {
    let dir = TempDir::on(backend, "ride");
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    let job = svc.submit(&read("checker.ray"), "?tile=128");
    let id = job["id"].as_str().expect("id").to_string();
    let total = job["tiles_total"].as_u64().expect("tiles_total");
    assert!(total >= 3, "a job of a few tiles ({total})");
    let http = client();
    let mut c: Value = svc.claim("t").json().expect("claim");
    let put = |c: &Value, next: &str| {
        let u = |k: &str| c[k].as_u64().expect("number") as u32;
        let rect = Rect::new(u("x"), u("y"), u("w"), u("h"));
        http.put(format!(
            "{}/worker/jobs/{id}/tiles/{}?lease={}{next}",
            svc.url,
            c["idx"],
            c["lease"].as_str().expect("lease")
        ))
        .body(encode_tile(rect, &vec![5u8; rect.pixel_count() * 3]))
        .send()
        .expect("answer")
    };
    // A name that is not one is refused before anything is stored.
    assert_eq!(put(&c, "&next=").status(), 400);
    assert_eq!(tiles_done(&svc, &id), 0);

    // Each post brings the next tile under a fresh lease, until there is none left.
    let mut seen = vec![c["idx"].as_u64().expect("idx")];
    let mut leases = vec![c["lease"].as_str().expect("lease").to_string()];
    loop {
        let r = put(&c, "&next=t");
        assert_eq!(r.status(), 200);
        let a: Value = r.json().expect("json");
        assert_eq!(a["repeat"], false);
        match a.get("next") {
            Some(next) => {
                seen.push(next["idx"].as_u64().expect("idx"));
                leases.push(next["lease"].as_str().expect("lease").to_string());
                c = next.clone();
            }
            None => break,
        }
    }
    seen.sort_unstable();
    assert_eq!(seen, (0..total).collect::<Vec<_>>(), "every tile, once");
    leases.sort_unstable();
    leases.dedup();
    assert_eq!(leases.len() as u64, total, "a fresh lease each time");
    assert_eq!(svc.wait_finished(&id, JOB_TIME)["state"], "done");
    // A repeat still answers 200, and with no work left it brings nothing.
    let again = put(&c, "&next=t");
    assert_eq!(again.status(), 200);
    let a: Value = again.json().expect("json");
    assert_eq!((a["repeat"].clone(), a.get("next")), (json!(true), None));
}
on_both!(a_result_can_carry_the_next_claim);

/// A connection that falls silent is closed after `--idle-timeout-secs`, whether it stopped
/// in its headers or in its body (either would otherwise hold its connection and the body
/// read so far for ever); one that keeps sending, however slowly, is not, and neither is a
/// wait for a job.
#[test]
fn silent_connections_are_closed() {
    use std::io::{Read, Write};
    use std::net::TcpStream;

    let dir = TempDir::new("idle");
    let svc = Service::start(&dir, &["--local-workers", "0", "--idle-timeout-secs", "2"]);
    let addr = svc.url.trim_start_matches("http://").to_string();
    // Reads what the service sends until it closes; `None` if it is still open after 20 s.
    let until_closed = |s: &mut TcpStream| -> Option<Vec<u8>> {
        s.set_read_timeout(Some(Duration::from_secs(20)))
            .expect("timeout");
        let mut got = Vec::new();
        let mut buf = [0u8; 4096];
        loop {
            match s.read(&mut buf) {
                Ok(0) => return Some(got),
                Ok(n) => got.extend_from_slice(&buf[..n]),
                Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => return Some(got),
                Err(_) => return None,
            }
        }
    };

    let mut headers = TcpStream::connect(&addr).expect("connect");
    headers
        .write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")
        .expect("write");
    let started = Instant::now();
    assert!(until_closed(&mut headers).is_some(), "half the headers");
    assert!(started.elapsed() >= Duration::from_secs(2));

    let mut body = TcpStream::connect(&addr).expect("connect");
    body.write_all(b"POST /jobs HTTP/1.1\r\nHost: x\r\nContent-Length: 100000\r\n\r\n[GLOBALS]\n")
        .expect("write");
    assert!(until_closed(&mut body).is_some(), "a tenth of the body");

    // A scene sent in five pieces 0.5 s apart (2 s in all, as long as the timeout): each
    // piece restarts the clock, and the job is accepted.
    let scene = read("thesis.ray");
    let mut slow = TcpStream::connect(&addr).expect("connect");
    write!(
        slow,
        "POST /jobs HTTP/1.1\r\nHost: x\r\nConnection: close\r\nContent-Length: {}\r\n\r\n",
        scene.len()
    )
    .expect("write");
    for piece in scene.as_bytes().chunks(scene.len().div_ceil(5)) {
        std::thread::sleep(Duration::from_millis(500));
        slow.write_all(piece).expect("write");
    }
    let answer = String::from_utf8(until_closed(&mut slow).expect("answered")).expect("text");
    assert!(answer.starts_with("HTTP/1.1 201"), "{answer}");

    // A wait shorter than the timeout but longer than most of it, on a job no worker takes.
    let id = svc.submit_id(&scene, "");
    let started = Instant::now();
    let job = svc.get_json(&format!("/jobs/{id}?wait=1"));
    assert_eq!(job["state"], "queued");
    assert!(started.elapsed() >= Duration::from_secs(1));
    // A wait longer than the timeout is cut to a second less than it, and answered, rather
    // than held until the silent connection is closed with no answer at all.
    let started = Instant::now();
    let job = svc.get_json(&format!("/jobs/{id}?wait=5"));
    assert_eq!(job["state"], "queued");
    assert!(started.elapsed() >= Duration::from_secs(1));
    // So is a worker's claim waiting for work, once there is none left to hand out.
    while svc.claim("idle").status() == 200 {}
    let r = client()
        .post(format!("{}/worker/claim?wait_ms=5000", svc.url))
        .json(&json!({"worker": "idle"}))
        .send()
        .expect("answered, not dropped");
    assert_eq!(r.status(), 204);
}

/// Two clients trickling their bodies a byte at a time hold the whole receiving budget; a
/// small submission waiting for room gets it once they are cut for their pace (`408`
/// naming `--min-upload-rate`) after 10 s, well within the 30 s it may wait. Before, they
/// kept their shares for as long as they trickled and it was refused with `503`.
#[test]
fn trickling_uploads_are_cut_and_a_waiting_submission_goes_through() {
    use std::io::{Read, Write};
    use std::net::TcpStream;

    let dir = TempDir::new("trickle");
    // Two declared bodies of 32 KiB fill a budget of 64 KiB.
    let svc = Service::start(
        &dir,
        &[
            "--local-workers",
            "0",
            "--max-receiving-bytes",
            "65536",
            "--max-body-bytes",
            "32768",
        ],
    );
    let addr = svc.url.trim_start_matches("http://").to_string();
    let tricklers: Vec<_> = (0..2)
        .map(|_| {
            let mut s = TcpStream::connect(&addr).expect("connect");
            s.write_all(b"POST /jobs HTTP/1.1\r\nHost: x\r\nContent-Length: 32768\r\n\r\n[")
                .expect("write");
            std::thread::spawn(move || {
                // A byte every half second (the client's pace, read timeouts between) until
                // the service answers; the answer as text.
                s.set_read_timeout(Some(Duration::from_millis(500)))
                    .expect("timeout");
                let mut got = Vec::new();
                let mut buf = [0u8; 4096];
                let deadline = Instant::now() + Duration::from_secs(60);
                while Instant::now() < deadline {
                    match s.read(&mut buf) {
                        Ok(0) => break,
                        Ok(n) => got.extend_from_slice(&buf[..n]),
                        Err(e)
                            if matches!(
                                e.kind(),
                                std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                            ) =>
                        {
                            if !got.is_empty() {
                                break;
                            }
                            let _ = s.write_all(b" ");
                        }
                        Err(_) => break,
                    }
                }
                String::from_utf8_lossy(&got).into_owned()
            })
        })
        .collect();
    // Both hold their shares once the service has read their headers; a round trip after
    // them comes later.
    assert_eq!(svc.get("/healthz").status(), 200);
    let started = Instant::now();
    let job = svc.submit(&read("thesis.ray"), "");
    assert!(job["id"].is_string(), "{job}");
    let waited = started.elapsed();
    for t in tricklers {
        let answer = t.join().expect("trickler");
        assert!(answer.starts_with("HTTP/1.1 408"), "{answer}");
        assert!(answer.contains("--min-upload-rate"), "{answer}");
    }
    assert!(waited < Duration::from_secs(30), "{waited:?}");
}

/// A service that was itself suspended longer than a lease does not blame its workers for
/// the renewals it could not take: it gives every lease a fresh term, and a worker's lease
/// from before the pause is still good after it (not reaped and its tile handed out again,
/// as if the worker had died).
fn a_paused_service_extends_leases_instead_of_reaping_them(backend: Backend) {
    let dir = TempDir::on(backend, "paused");
    let svc = Service::start(&dir, &["--local-workers", "0", "--lease-ms", "1000"]);
    let id = svc.submit_id(&read("thesis.ray"), "?tile=64");
    let c: Value = svc.claim("w").json().expect("claim");
    let pid = svc.pid().to_string();
    let signal = |sig: &str| {
        assert!(
            std::process::Command::new("kill")
                .args([sig, &pid])
                .status()
                .expect("kill runs")
                .success()
        );
    };
    signal("-STOP");
    // The pause itself: three leases long.
    std::thread::sleep(Duration::from_secs(3));
    signal("-CONT");
    wait_until(
        "the service to notice its pause",
        Duration::from_secs(20),
        || svc.log().contains("leases extended, none reaped"),
    );
    let renewed = client()
        .post(format!(
            "{}/worker/jobs/{id}/tiles/{}/renew?lease={}",
            svc.url,
            c["idx"],
            c["lease"].as_str().expect("lease")
        ))
        .send()
        .expect("answer");
    assert_eq!(renewed.status(), 200, "{}", svc.log());
}
on_both!(a_paused_service_extends_leases_instead_of_reaping_them);

/// A cancelled job's tile stops rendering when the worker's next renewal is refused: the
/// worker is free for the next job within a fraction of a lease, instead of rendering the
/// tile to its end (here a billion rays, minutes) while every job waits behind it.
fn a_cancelled_jobs_tile_stops_rendering(backend: Backend) {
    let dir = TempDir::on(backend, "cancel-tile");
    let svc = Service::start(&dir, &["--local-workers", "0", "--lease-ms", "600"]);
    // A billion slow samples in the one tile.
    let id = svc.submit_id(&mirror_cave(1024, 32), "?tile=1024");
    let _worker = Worker::start(&svc.url, "w", &[]);
    wait_claimed(&svc, &id);
    let r = client()
        .delete(format!("{}/jobs/{id}", svc.url))
        .send()
        .expect("answer");
    assert_eq!(r.status(), 200);
    let next = svc.submit(&read("thesis.ray"), "");
    let next = next["id"].as_str().expect("id");
    let done = svc.wait_finished(next, Duration::from_secs(60));
    assert_eq!(done["state"], "done", "{done}");
}
on_both!(a_cancelled_jobs_tile_stops_rendering);

/// A stop signal sent the moment the service says it is listening is a graceful stop: the
/// handlers are in place before that line, so the signal never meets the default action
/// (death by signal, an unclean exit status for a supervisor).
#[test]
fn a_stop_signal_right_after_start_is_a_graceful_stop() {
    let dir = TempDir::new("stop-at-start");
    for _ in 0..8 {
        let mut svc = Service::start(&dir, &["--local-workers", "0"]);
        let status = svc.terminate();
        assert!(status.success(), "{status:?}\n{}", svc.log());
    }
}

/// A stop does not wait for clients that never finish their requests: one that sent half
/// its headers and one part of an upload held a graceful stop for the idle timeout (two
/// minutes here), a trickling one for ever. Once the local workers are done, open requests
/// get a few seconds, then their connections are closed and the service exits cleanly.
#[test]
fn a_stop_does_not_wait_for_unfinished_requests() {
    use std::io::Write;
    let dir = TempDir::new("stop-deadline");
    let mut svc = Service::start(&dir, &["--local-workers", "0"]);
    let addr = svc.url.trim_start_matches("http://").to_string();
    let mut half = std::net::TcpStream::connect(&addr).expect("connect");
    half.write_all(b"GET /jobs HTTP/1.1\r\nHost: x\r\n")
        .expect("write");
    let mut upload = std::net::TcpStream::connect(&addr).expect("connect");
    upload
        .write_all(b"POST /jobs HTTP/1.1\r\nHost: x\r\nContent-Length: 100000\r\n\r\n[GLOBALS]\n")
        .expect("write");
    // Both are in: connections are accepted in order, and a later one has been answered.
    assert_eq!(svc.get("/healthz").status(), 200);
    let status = svc.terminate();
    assert!(status.success(), "{status:?}\n{}", svc.log());
    assert!(
        svc.log().contains("closing their connections"),
        "{}",
        svc.log()
    );
    drop((half, upload));
}

/// A worker stopped while the service is down exits once its grace period is over, giving
/// up the tile it could not post: it retried the post for four leases (two minutes by
/// default) whatever `--grace-secs` said, past any service manager's patience.
#[test]
fn a_worker_stops_within_its_grace_while_the_service_is_down() {
    // One tile of a second or two.
    let (log, took) =
        stop_worker_with_the_service_gone("stop-offline", &mirror_cave(96, 3), 96, 10, "debug");
    // Retried with its back-off, stopping or not: a retry loop that ignored the pause once
    // stopping sent thousands of posts in the grace period.
    let retries = log.matches("retrying in").count();
    assert!((1..60).contains(&retries), "{retries} retries:\n{log}");
    // Its grace and one back-off step at most; not four leases (120 s).
    assert!(took < Duration::from_secs(40), "{took:?}");
}

/// A reported failure says what became of the tile: requeued, or, when it was the tile's
/// last attempt, its job failed (the answer said `requeued` either way).
fn a_reported_failure_says_whether_it_failed_the_job(backend: Backend) {
    let dir = TempDir::on(backend, "fail-answer");
    let svc = Service::start(&dir, &["--local-workers", "0", "--max-attempts", "2"]);
    let id = svc.submit_id(&read("thesis.ray"), "?tile=64");
    let http = client();
    let mut answers = Vec::new();
    for worker in ["a", "b"] {
        let c: Value = svc.claim(worker).json().expect("claim");
        assert_eq!(c["idx"], 0, "{c}");
        let r = http
            .post(format!(
                "{}/worker/jobs/{id}/tiles/0/fail?lease={}",
                svc.url,
                c["lease"].as_str().expect("lease")
            ))
            .json(&json!({ "worker": worker, "reason": "boom" }))
            .send()
            .expect("answer");
        assert_eq!(r.status(), 200);
        answers.push(r.json::<Value>().expect("json"));
    }
    assert_eq!(answers[0], json!({ "requeued": true, "job_failed": false }));
    assert_eq!(answers[1], json!({ "requeued": false, "job_failed": true }));
    assert_eq!(svc.get_json(&format!("/jobs/{id}"))["state"], "failed");
}
on_both!(a_reported_failure_says_whether_it_failed_the_job);

/// A worker process of one thread for `url`, keeping its tiles `grace` seconds once asked
/// to stop; the caller sets its log level and where its log goes.
fn one_thread_worker(url: &str, grace: &str) -> std::process::Command {
    let mut worker = std::process::Command::new(WORKER);
    worker.args(["--server", url, "--threads", "1", "--grace-secs", grace]);
    worker
}

/// A second SIGTERM while a worker is stopping gracefully ends it at once (status 130),
/// instead of leaving it to finish its tile for up to its grace period.
#[test]
fn a_second_signal_stops_a_worker_at_once() {
    use std::io::BufRead;
    let dir = TempDir::new("second-signal");
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    let id = svc.submit_id(&mirror_cave(1024, 32), "?tile=1024");
    let mut worker = one_thread_worker(&svc.url, "600")
        .env("RUST_LOG", "info")
        .stderr(std::process::Stdio::piped())
        .stdout(std::process::Stdio::null())
        .spawn()
        .expect("worker starts");
    let mut log = std::io::BufReader::new(worker.stderr.take().expect("stderr")).lines();
    wait_claimed(&svc, &id);
    common::signal(&worker, "TERM");
    // The first is taken (the worker says so) before the second is sent.
    assert!(
        log.by_ref()
            .map_while(Result::ok)
            .any(|line| line.contains("stopping:")),
        "the worker's log ended without the stop"
    );
    common::signal(&worker, "TERM");
    let status = common::wait_exit(&mut worker, Duration::from_secs(60));
    let _ = worker.kill();
    assert_eq!(status.and_then(|s| s.code()), Some(130), "{status:?}");
}

/// A worker stopped while the service is frozen (it takes the post and never answers) exits
/// at the end of its grace period: the post waited for the client's two-minute timeout.
#[test]
fn a_worker_stops_within_its_grace_while_the_service_is_frozen() {
    let (log, took) =
        stop_worker_with_the_service_out("stop-frozen", &mirror_cave(96, 3), 96, 5, "info", true);
    assert!(took < Duration::from_secs(40), "{took:?}\n{log}");
}

/// A worker's closing count of tiles given back counts only those the service took back:
/// with the service gone, the give-back of the tile still rendering at the end of the grace
/// period fails, and it said `released=1` all the same.
#[test]
fn only_tiles_the_service_took_back_count_as_released() {
    let (log, _) =
        stop_worker_with_the_service_gone("released", &mirror_cave(1024, 32), 1024, 1, "info");
    let last = log
        .lines()
        .find(|l| l.contains("worker stopped"))
        .unwrap_or_else(|| panic!("no closing line:\n{log}"));
    assert!(last.contains("released=0"), "{last}");
}

/// Submits `scene` as one tile of edge `tile`, starts a one-thread worker with `grace`
/// seconds of grace logging at `level`, kills the service once the tile is claimed, stops
/// the worker with SIGTERM and checks it exits cleanly; returns its log and how long the
/// stop took.
fn stop_worker_with_the_service_gone(
    tag: &str,
    scene: &str,
    tile: u32,
    grace: u32,
    level: &str,
) -> (String, Duration) {
    stop_worker_with_the_service_out(tag, scene, tile, grace, level, false)
}

/// As `stop_worker_with_the_service_gone`, the service killed or, with `freeze`, stopped
/// (SIGSTOP: it takes connections and never answers).
fn stop_worker_with_the_service_out(
    tag: &str,
    scene: &str,
    tile: u32,
    grace: u32,
    level: &str,
    freeze: bool,
) -> (String, Duration) {
    let dir = TempDir::new(tag);
    let mut svc = Service::start(&dir, &["--local-workers", "0"]);
    let id = svc.submit_id(scene, &format!("?tile={tile}"));
    let log_path = dir.path().join("worker.log");
    let grace = grace.to_string();
    let mut worker = one_thread_worker(&svc.url, &grace)
        .env("RUST_LOG", format!("tessera_worker={level}"))
        .stdout(std::process::Stdio::null())
        .stderr(std::fs::File::create(&log_path).expect("log file"))
        .spawn()
        .expect("worker starts");
    wait_claimed(&svc, &id);
    // Claimed is not yet rendering: the worker fetches and builds the scene first, and a
    // service gone before that is a tile given back, not one to post (on a loaded machine
    // the test once stopped the service in between).
    wait_until(
        "the worker to build the scene",
        Duration::from_secs(60),
        || std::fs::read_to_string(&log_path).is_ok_and(|l| l.contains("scene built")),
    );
    if freeze {
        let stopped = std::process::Command::new("kill")
            .args(["-STOP", &svc.pid().to_string()])
            .status();
        assert!(stopped.is_ok_and(|s| s.success()));
    } else {
        svc.kill();
    }
    let start = Instant::now();
    common::signal(&worker, "TERM");
    let status = common::wait_exit(&mut worker, Duration::from_secs(60));
    let took = start.elapsed();
    let _ = worker.kill();
    assert!(status.is_some_and(|s| s.success()), "{status:?}");
    (std::fs::read_to_string(&log_path).expect("log"), took)
}

/// A renewal says whether the tile is rendering as a flag, `true`/`1` or `false`/`0`, as
/// `?purge=` does; anything else is refused.
fn a_renewal_takes_rendering_as_a_flag(backend: Backend) {
    let dir = TempDir::on(backend, "renew-flag");
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    let id = svc.submit_id(&read("thesis.ray"), "?tile=64");
    let c: Value = svc.claim("w").json().expect("claim");
    let lease = c["lease"].as_str().expect("lease");
    let renew = |flag: &str| {
        client()
            .post(format!(
                "{}/worker/jobs/{id}/tiles/{}/renew?lease={lease}{flag}",
                svc.url, c["idx"]
            ))
            .send()
            .expect("answer")
            .status()
    };
    for ok in ["", "&rendering=true", "&rendering=1", "&rendering=0"] {
        assert_eq!(renew(ok), 200, "{ok}");
    }
    assert_eq!(renew("&rendering=yes"), 400);
}
on_both!(a_renewal_takes_rendering_as_a_flag);

/// What the fake service of [`fake_service`] was asked.
#[derive(Default)]
struct Seen {
    claims: u32,
    /// When each claim came.
    claimed_at: Vec<Instant>,
    released: Vec<u32>,
    /// Tiles reported failed, with the reason given.
    failed: Vec<(u32, String)>,
    assets: u32,
}

/// A fake service for one worker: it always has a tile of job `j` to hand out (a scene with
/// one texture), answers every texture fetch with `asset_status` and records claims, texture
/// fetches and give-backs. One request per connection.
fn fake_service(asset_status: &'static str) -> (String, std::sync::Arc<std::sync::Mutex<Seen>>) {
    use std::io::{BufRead, BufReader, Read, Write};
    let seen = std::sync::Arc::new(std::sync::Mutex::new(Seen::default()));
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let url = format!("http://{}", listener.local_addr().expect("addr"));
    let scene = "[OBJECT]\ntype = sphere\ntexture = t.ppm\n[/OBJECT]\n";
    let shared = seen.clone();
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let Ok(stream) = stream else { continue };
            let mut reader = BufReader::new(stream);
            let mut head = String::new();
            let mut length = 0usize;
            loop {
                let mut line = String::new();
                if reader.read_line(&mut line).unwrap_or(0) == 0 {
                    break;
                }
                if let Some(v) = line.to_ascii_lowercase().strip_prefix("content-length:") {
                    length = v.trim().parse().unwrap_or(0);
                }
                if line == "\r\n" {
                    break;
                }
                head.push_str(&line);
            }
            let mut body = vec![0u8; length];
            let _ = reader.read_exact(&mut body);
            let target = head.split_whitespace().nth(1).unwrap_or("").to_string();
            let path = target.split('?').next().unwrap_or("").to_string();
            let mut s = shared.lock().expect("not poisoned");
            let (status, answer) = if path == "/worker/claim" {
                s.claims += 1;
                s.claimed_at.push(Instant::now());
                let claim = json!({"job": "j", "idx": s.claims - 1, "x": 0, "y": 0,
                    "w": 4, "h": 4, "lease": format!("L{}", s.claims), "lease_ms": 60_000});
                ("200 OK", claim.to_string())
            } else if path == "/worker/jobs/j" {
                let spec = json!({"id": "j", "scene": scene, "sampler": null,
                    "samples": null, "threshold": null, "assets": ["t.ppm"]});
                ("200 OK", spec.to_string())
            } else if path.starts_with("/worker/jobs/j/assets/") {
                s.assets += 1;
                (asset_status, json!({"error": asset_status}).to_string())
            } else if let Some(idx) = path
                .strip_prefix("/worker/jobs/j/tiles/")
                .and_then(|p| p.strip_suffix("/release"))
            {
                s.released.push(idx.parse().unwrap_or(u32::MAX));
                ("200 OK", "{}".to_string())
            } else if let Some(idx) = path
                .strip_prefix("/worker/jobs/j/tiles/")
                .and_then(|p| p.strip_suffix("/fail"))
            {
                let reason = serde_json::from_slice::<Value>(&body)
                    .ok()
                    .and_then(|v| v["reason"].as_str().map(String::from))
                    .unwrap_or_default();
                s.failed.push((idx.parse().unwrap_or(u32::MAX), reason));
                let answer = json!({"requeued": true, "job_failed": false});
                ("200 OK", answer.to_string())
            } else {
                (
                    "404 Not Found",
                    json!({"error": "no such route"}).to_string(),
                )
            };
            drop(s);
            let mut stream = reader.into_inner();
            let _ = write!(
                stream,
                "HTTP/1.1 {status}\r\ncontent-type: application/json\r\n\
                 content-length: {}\r\nconnection: close\r\n\r\n{answer}",
                answer.len()
            );
        }
    });
    (url, seen)
}

/// A worker that cannot fetch a job's texture (the service answers `500` for it) gives each
/// tile back and backs off, so that healthy workers get them at once, rather than taking the
/// job's every tile in turn and holding each until its lease runs out. The back-off grows
/// from one give-back to the next, and a successful claim does not reset it (that would be a
/// claim and a give-back every 50 ms, for ever).
#[test]
fn a_worker_that_cannot_fetch_a_texture_gives_the_tile_back() {
    let (url, seen) = fake_service("500 Internal Server Error");
    let _worker = Worker::start(&url, "unlucky", &[]);
    wait_until("seven tiles given back", Duration::from_secs(60), || {
        seen.lock().expect("not poisoned").released.len() >= 7
    });
    let s = seen.lock().expect("not poisoned");
    // Each tile it took was given back, but for one being fetched or claimed right now.
    assert!(
        s.claims <= s.released.len() as u32 + 2,
        "{} claims, {:?}",
        s.claims,
        s.released
    );
    assert!(s.assets >= 6);
    assert_eq!(s.released[..6], [0, 1, 2, 3, 4, 5]);
    // Pauses of 25 ms · 2^n, ±50 %: the sixth (800–2,000 ms) outlasts the first (25–75 ms)
    // four times over whatever the jitter; without the growth they were alike.
    let gap = |i: usize| s.claimed_at[i + 1] - s.claimed_at[i];
    assert!(gap(5) > gap(0) * 4, "{:?} then {:?}", gap(0), gap(5));
}

/// A texture answered `404` (its job deleted between the worker's fetch of the scene and of
/// the texture, or a proxy that refuses the texture's URL, which no retry mends): the worker
/// reports the tile failed, naming the texture, and carries on, so that the service keeps it
/// away from the job and a job no worker can fetch fails with that reason. Neither stopping
/// the worker, nor dropping the tile unreleased (its lease would run out and be charged as a
/// crash), nor giving it back uncharged (the worker would come back to the same tile for
/// ever) would do.
#[test]
fn a_worker_whose_texture_is_not_found_reports_the_tile_failed_and_carries_on() {
    let (url, seen) = fake_service("404 Not Found");
    let mut worker = Worker::start(&url, "carries-on", &[]);
    wait_until("three tiles reported", Duration::from_secs(30), || {
        seen.lock().expect("not poisoned").failed.len() >= 3 || worker.try_wait().is_some()
    });
    assert!(worker.try_wait().is_none(), "the worker stopped");
    let s = seen.lock().expect("not poisoned");
    assert_eq!(
        s.failed.iter().map(|f| f.0).take(3).collect::<Vec<_>>(),
        [0, 1, 2]
    );
    assert!(
        s.failed[0].1.contains("t.ppm") && s.failed[0].1.contains("404"),
        "{:?}",
        s.failed[0]
    );
    assert!(s.released.is_empty(), "{:?}", s.released);
}

/// The service raises its open-file limit from the soft limit to the hard one at start: at
/// a soft limit of 1,024 a few hundred idle clients (each held until the idle timeout) used
/// up the rest, and every new connection, `/healthz` and the local workers' included, then
/// waited while the service logged "Too many open files".
#[cfg(target_os = "linux")]
#[test]
fn the_service_raises_its_open_file_limit() {
    use std::io::{BufRead, BufReader};
    use std::process::{Command, Stdio};
    let soft_and_hard = |pid: u32| -> (String, String) {
        let limits = std::fs::read_to_string(format!("/proc/{pid}/limits")).expect("limits");
        let line = limits
            .lines()
            .find(|l| l.starts_with("Max open files"))
            .expect("a line for open files")
            .to_string();
        let mut fields = line["Max open files".len()..].split_whitespace();
        let soft = fields.next().unwrap_or_default().to_string();
        let hard = fields.next().unwrap_or_default().to_string();
        (soft, hard)
    };
    let (_, hard) = soft_and_hard(std::process::id());
    if hard.parse::<u64>().is_ok_and(|h| h <= 64) {
        eprintln!("skipped: the hard limit here is {hard}");
        return;
    }
    let dir = TempDir::new("nofile");
    let db = format!("sqlite://{}", dir.path().join("t.db").display());
    let mut child = Command::new("bash")
        .args(["-c", "ulimit -S -n 64 && exec \"$0\" \"$@\""])
        .arg(SERVICE)
        .args([
            "--listen",
            "127.0.0.1:0",
            "--local-workers",
            "0",
            "--database",
            &db,
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("starts");
    let stdout = child.stdout.take().expect("piped");
    let listening = BufReader::new(stdout)
        .lines()
        .map_while(Result::ok)
        .any(|l| l.starts_with("tessera-service listening on "));
    let (soft, hard) = soft_and_hard(child.id());
    let _ = child.kill();
    let _ = child.wait();
    assert!(listening, "the service started");
    let expected = hard.parse::<u64>().map_or(1 << 20, |h| h.min(1 << 20));
    assert_eq!(
        soft.parse::<u64>().ok(),
        Some(expected),
        "raised from 64 (hard: {hard})"
    );
}

/// Submissions share one budget of body bytes (`--max-receiving-bytes`): each holds its
/// declared length, all or nothing, while its body arrives, and a body that stops arriving
/// is cut. A submission that finds no room waits its turn, gets it when another ends, and is
/// answered `503` with `Retry-After` if none ends in time, so that many large uploads at
/// once cannot hold unbounded memory. Textures' own budget:
/// `a_submission_waiting_to_decode_its_textures_answers_when_the_service_stops`.
#[test]
fn submissions_past_the_receiving_budget_wait_their_turn() {
    use std::io::{Read, Write};
    use std::sync::atomic::{AtomicBool, Ordering};
    const KIB: usize = 1024;
    let dir = TempDir::new("receiving");
    let svc = Service::start(
        &dir,
        &[
            "--local-workers",
            "0",
            "--max-body-bytes",
            &(64 * KIB).to_string(),
            "--max-receiving-bytes",
            &(96 * KIB).to_string(),
            "--idle-timeout-secs",
            "5",
        ],
    );
    // A scene padded with comment lines to `len` bytes.
    let padded = |len: usize| {
        let mut s = read("thesis.ray");
        while s.len() < len {
            let line = "#".repeat((len - s.len()).min(200) - 1);
            s.push_str(&line);
            s.push('\n');
        }
        s.into_bytes()
    };
    let post = |body: Vec<u8>| {
        client()
            .post(format!("{}/jobs", svc.url))
            .body(body)
            .send()
            .expect("answer")
    };
    let connect = || {
        let s =
            std::net::TcpStream::connect(svc.url.trim_start_matches("http://")).expect("connect");
        s.set_read_timeout(Some(Duration::from_secs(20)))
            .expect("timeout");
        s
    };
    // A body that stops arriving is cut with a JSON 408 (at 4 s here, a second under the
    // idle timeout) and its room given back: the next submission, as large as the budget
    // allows beside nothing, goes straight in. (A client that declared 64 MiB and fell
    // silent held it until the idle timeout: two such shut every submission out.)
    let mut silent = connect();
    write!(
        silent,
        "POST /jobs HTTP/1.1\r\nHost: x\r\nContent-Length: {}\r\n\r\n#",
        64 * KIB
    )
    .expect("write");
    let mut answer = String::new();
    let _ = silent.read_to_string(&mut answer);
    assert!(
        answer.starts_with("HTTP/1.1 408") && answer.contains("stopped arriving"),
        "{answer}"
    );
    assert_eq!(post(padded(64 * KIB)).status(), 201);

    // The first submission sends 50 KiB of its 60 and then a byte every 200 ms (never
    // silent for long), holding its declared 60 of the 96 KiB while the test waits on the
    // others.
    let big = padded(60 * KIB);
    let mut first = connect();
    write!(
        first,
        "POST /jobs HTTP/1.1\r\nHost: x\r\nContent-Length: {}\r\n\r\n",
        big.len()
    )
    .expect("write");
    first.write_all(&big[..50 * KIB]).expect("write");
    let done = std::sync::Arc::new(AtomicBool::new(false));
    let trickle = std::thread::spawn({
        let done = done.clone();
        let mut first = first.try_clone().expect("clone");
        move || {
            let mut sent = 50 * KIB;
            while !done.load(Ordering::Acquire) && sent < 55 * KIB {
                first.write_all(&big[sent..sent + 1]).expect("write");
                sent += 1;
                std::thread::sleep(Duration::from_millis(200));
            }
            first.write_all(&big[sent..]).expect("write");
        }
    });
    // 50 KiB more do not fit: refused after waiting (4 s, a second under the idle timeout).
    // A submission that got in before the first one's bytes were counted is served; the
    // next finds them counted.
    let deadline = Instant::now() + Duration::from_secs(60);
    let refused = loop {
        let r = post(padded(50 * KIB));
        if r.status() != 201 {
            break r;
        }
        assert!(Instant::now() < deadline, "never refused");
    };
    assert_eq!(refused.status(), 503);
    assert_eq!(refused.headers()["retry-after"], "5");
    let body: Value = refused.json().expect("JSON");
    assert!(
        body["error"]
            .as_str()
            .is_some_and(|e| e.contains("--max-receiving-bytes")),
        "{body}"
    );
    assert_eq!(body["receiving_bytes"], 96 * KIB);
    // What the refused one held is given back: a small one fits beside the first.
    assert_eq!(post(padded(20 * KIB)).status(), 201);
    // One that waits is served once the first one is in (sent before the first one's rest,
    // it is most likely waiting by then; served either way).
    let waiting = std::thread::spawn({
        let url = svc.url.clone();
        move || {
            client()
                .post(format!("{url}/jobs"))
                .body(padded(50 * KIB))
                .send()
                .expect("answer")
                .status()
        }
    });
    done.store(true, Ordering::Release);
    trickle.join().expect("trickle");
    let mut answer = [0u8; 64];
    let n = first.read(&mut answer).expect("an answer");
    assert!(
        answer[..n].starts_with(b"HTTP/1.1 201"),
        "{}",
        String::from_utf8_lossy(&answer[..n])
    );
    assert_eq!(waiting.join().expect("waiting"), 201);
}

/// Media types are case-insensitive (RFC 9110): a multipart body sent as
/// `Multipart/Form-Data` is read as multipart, not as a raw scene refused at 1:1.
#[test]
fn a_multipart_type_in_any_case_is_multipart() {
    let dir = TempDir::new("multipart-case");
    let svc = Service::start(&dir, &["--local-workers", "0"]);
    let mut body = b"--XyZ\r\nContent-Disposition: form-data; name=\"scene\"\r\n\r\n".to_vec();
    body.extend_from_slice(read("thesis.ray").as_bytes());
    body.extend_from_slice(b"\r\n--XyZ--\r\n");
    for ct in ["Multipart/Form-Data", "MULTIPART/FORM-DATA"] {
        let r = client()
            .post(format!("{}/jobs", svc.url))
            .header("content-type", format!("{ct}; boundary=XyZ"))
            .body(body.clone())
            .send()
            .expect("answer");
        assert_eq!(r.status(), 201, "{ct}: {:?}", r.text());
    }
}

/// Claims a tile of job `id` as worker `t` and posts it in grey (bytes of 7); the answer to
/// the post.
fn claim_and_post_grey(svc: &Service, id: &str) -> reqwest::blocking::Response {
    let c: Value = svc.claim("t").json().expect("claim");
    let u = |k: &str| c[k].as_u64().expect("number") as u32;
    let rect = Rect::new(u("x"), u("y"), u("w"), u("h"));
    client()
        .put(format!(
            "{}/worker/jobs/{id}/tiles/{}?lease={}",
            svc.url,
            c["idx"],
            c["lease"].as_str().expect("lease")
        ))
        .body(encode_tile(rect, &vec![7u8; rect.pixel_count() * 3]))
        .send()
        .expect("answer")
}

/// A disk that fills under the tile spool (here the job's spool file is `/dev/full`, where
/// every write fails with "no space left"): the result is answered `503` with the reason
/// and its tile queued again, claims get `503` and the health check fails meanwhile; once
/// the disk is free a worker finishes the job with the exact image. The full disk is the
/// service's trouble, not the worker's: no `500`, no tile left to its lease and charged to
/// the worker, no job failed blaming workers after `--max-attempts` such tiles.
#[cfg(target_os = "linux")]
#[test]
fn a_full_disk_under_the_spool_pauses_the_farm_and_loses_nothing() {
    let dir = TempDir::new("full");
    let svc = Service::start(&dir, &["--local-workers", "0", "--max-attempts", "1"]);
    let id = svc.submit_id(&read("checker.ray"), "?tile=64");
    let spool_file =
        std::path::PathBuf::from(format!("{}-tiles", svc.db.display())).join(format!("{id}.rgb"));
    std::os::unix::fs::symlink("/dev/full", &spool_file).expect("a full file");
    let r = claim_and_post_grey(&svc, &id);
    assert_eq!(r.status(), 503);
    assert!(r.headers().contains_key("retry-after"));
    let e: Value = r.json().expect("json");
    let says = e["error"].as_str().expect("message");
    assert!(
        says.contains("No space left") && says.contains("queued again"),
        "{says}"
    );
    let claim = svc.claim("t");
    assert_eq!(
        claim.status(),
        503,
        "no work while results cannot be stored"
    );
    assert_eq!(svc.get("/healthz").status(), 503);
    let job = svc.get_json(&format!("/jobs/{id}"));
    assert_eq!(job["state"], "running");
    // The job says why it stands still, in its own answer and in the list.
    let paused = job["paused"].as_str().unwrap_or("");
    assert!(paused.contains("no room to store tile pixels"), "{job}");
    // In general terms: the failed write's own message names the spool file.
    assert!(!paused.contains(".rgb"), "{job}");
    assert_eq!(svc.get_json("/jobs")[0]["paused"], job["paused"]);

    std::fs::remove_file(&spool_file).expect("the disk is free again");
    let _w = Worker::start(&svc.url, "w", &[]);
    let job = svc.wait_finished(&id, JOB_TIME);
    // With `--max-attempts 1`, one failure charged to the tile would have failed the job.
    assert_eq!(job["state"], "done", "{job}");
    assert_eq!(
        svc.image(&id),
        local_png(&examples().join("checker.ray"), None, None)
    );
    assert_eq!(svc.get("/healthz").status(), 200);
}

/// A disk that stays full keeps the farm paused for as long as it does, not for 5 s after
/// the last failed result: here the job's spool file and the spool's probe file are both
/// `/dev/full`, so the disk has no room for anything. The job says `paused` and `/healthz`
/// fails for well past 5 s; once there is room again the pause lapses and the job finishes
/// with the exact image.
#[cfg(target_os = "linux")]
#[test]
fn a_disk_that_stays_full_keeps_the_farm_paused() {
    let dir = TempDir::new("still-full");
    let svc = Service::start(&dir, &["--local-workers", "0", "--lease-ms", "1000"]);
    let id = svc.submit_id(&read("checker.ray"), "?tile=64");
    let spool = std::path::PathBuf::from(format!("{}-tiles", svc.db.display()));
    let (job_file, probe_file) = (spool.join(format!("{id}.rgb")), spool.join("probe.tmp"));
    std::os::unix::fs::symlink("/dev/full", &job_file).expect("a full file");
    std::os::unix::fs::symlink("/dev/full", &probe_file).expect("a full probe");
    let r = claim_and_post_grey(&svc, &id);
    assert_eq!(r.status(), 503);
    // Nothing else writes meanwhile: the pause holds on the service's own looks.
    let held_until = Instant::now() + Duration::from_secs(8);
    while Instant::now() < held_until {
        let job = svc.get_json(&format!("/jobs/{id}"));
        assert!(
            job["paused"].is_string(),
            "the pause lapsed on a full disk: {job}"
        );
        assert_eq!(svc.get("/healthz").status(), 503);
        std::thread::sleep(Duration::from_millis(250));
    }
    std::fs::remove_file(&job_file).expect("room again");
    std::fs::remove_file(&probe_file).expect("room again");
    wait_until("the pause to lapse", Duration::from_secs(15), || {
        svc.get_json(&format!("/jobs/{id}"))["paused"].is_null()
    });
    let _w = Worker::start(&svc.url, "w", &[]);
    let job = svc.wait_finished(&id, JOB_TIME);
    assert_eq!(job["state"], "done", "{job}");
    assert_eq!(
        svc.image(&id),
        local_png(&examples().join("checker.ray"), None, None)
    );
}

/// A worker whose claim is answered `503` with `Retry-After` (a service pausing its farm
/// for a full disk says 5 s) asks again no sooner: it backed off from 25 ms, some fifteen
/// claims in a five-second pause.
#[test]
fn a_worker_waits_as_long_as_retry_after_says() {
    use std::io::{BufRead, BufReader, Write};
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let url = format!("http://{}", listener.local_addr().expect("addr"));
    let asked = std::sync::Arc::new(std::sync::Mutex::new(Vec::<Instant>::new()));
    let seen = asked.clone();
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let Ok(stream) = stream else { continue };
            let mut reader = BufReader::new(stream);
            let mut line = String::new();
            // The request's head; a claim's small body is left unread (the connection closes).
            while reader.read_line(&mut line).unwrap_or(0) > 0 && line != "\r\n" {
                line.clear();
            }
            seen.lock().expect("not poisoned").push(Instant::now());
            let answer = json!({"error": "paused"}).to_string();
            let _ = write!(
                reader.into_inner(),
                "HTTP/1.1 503 Service Unavailable\r\nretry-after: 1\r\n\
                 content-type: application/json\r\ncontent-length: {}\r\n\
                 connection: close\r\n\r\n{answer}",
                answer.len()
            );
        }
    });
    let mut worker = one_thread_worker(&url, "1")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("worker starts");
    wait_until("three claims", Duration::from_secs(30), || {
        asked.lock().expect("not poisoned").len() >= 3
    });
    let _ = worker.kill();
    let _ = worker.wait();
    let at = asked.lock().expect("not poisoned").clone();
    for pair in at.windows(2) {
        let gap = pair[1] - pair[0];
        assert!(
            gap >= Duration::from_millis(900),
            "asked again after {gap:?}"
        );
    }
}

/// What a service started without room to write does: it serves reads (the page, the job
/// list, a done job's image, `png`), and answers writes (a submission, a worker's claim)
/// and the health check `503` saying it is read-only; a refused write is told when to ask
/// again.
fn serves_reads_only(svc: &Service, id: &str, png: &[u8]) {
    assert_eq!(svc.get("/").status(), 200);
    let jobs = svc.get_json("/jobs");
    assert!(
        jobs.as_array()
            .is_some_and(|j| j.iter().any(|j| j["id"] == id)),
        "{jobs}"
    );
    assert!(svc.image(id) == png, "the image read back differs");
    let health = svc.get("/healthz");
    assert_eq!(health.status(), 503);
    let said = health.text().unwrap_or_default();
    assert!(said.contains("read-only"), "{said}");
    let r = client()
        .post(format!("{}/jobs", svc.url))
        .body(read("thesis.ray"))
        .send()
        .expect("an answer");
    assert_eq!(r.status(), 503);
    assert!(r.headers().contains_key("retry-after"));
    let said = r.text().unwrap_or_default();
    assert!(said.contains("read-only"), "{said}");
    assert_eq!(svc.claim("w").status(), 503);
}

/// Once the disk has room again, the same service takes writes without a restart: a new
/// job renders (by its local worker) to `tessera-render`'s image.
fn takes_writes_again(svc: &Service) {
    wait_until(
        "the service to take writes",
        Duration::from_secs(30),
        || svc.get("/healthz").status() == 200,
    );
    let id = svc.submit_id(&read("thesis.ray"), "?tile=64");
    let job = svc.wait_finished(&id, JOB_TIME);
    assert_eq!(job["state"], "done", "{job}");
    assert!(svc.image(&id) == local_png(&examples().join("thesis.ray"), None, None));
}

/// A service that starts while its tile folder has no room (the spool's probe file is
/// `/dev/full`) starts read-only, and takes writes once there is room.
#[cfg(target_os = "linux")]
#[test]
fn a_service_started_without_room_for_tiles_serves_reads_until_it_has_room() {
    let dir = TempDir::new("start-full-spool");
    let args = ["--local-workers", "1"];
    let svc = Service::start(&dir, &args);
    let id = svc.submit_id(&read("thesis.ray"), "?tile=64");
    assert_eq!(svc.wait_finished(&id, JOB_TIME)["state"], "done");
    let png = svc.image(&id);
    let probe = std::path::PathBuf::from(format!("{}-tiles", svc.db.display())).join("probe.tmp");
    drop(svc);
    std::os::unix::fs::symlink("/dev/full", &probe).expect("a full probe");
    let svc = Service::start(&dir, &args);
    serves_reads_only(&svc, &id, &png);
    std::fs::remove_file(&probe).expect("room again");
    takes_writes_again(&svc);
}

/// A service that starts on a disk that is full (a small file system of its own, filled to
/// the last byte), where SQLite cannot open its database as usual, starts read-only, and
/// takes writes once a file is deleted. Mounting needs the privilege to; where the test may
/// not, it says so and checks nothing.
#[cfg(target_os = "linux")]
#[test]
fn a_service_started_on_a_full_disk_serves_reads_until_it_has_room() {
    let Some(dir) = TempDir::on_small_disk("start-full-disk", 16 << 20) else {
        eprintln!("note: no file system could be mounted here; the full-disk start is untested");
        return;
    };
    let args = ["--local-workers", "1"];
    let mut svc = Service::start(&dir, &args);
    let id = svc.submit_id(&read("thesis.ray"), "?tile=64");
    assert_eq!(svc.wait_finished(&id, JOB_TIME)["state"], "done");
    let png = svc.image(&id);
    assert!(svc.terminate().success());
    // Without the index its connections share (which SQLite removes when the last one
    // closes, unless that races the exit, and rebuilds from the WAL), the database cannot be
    // opened as usual on a full disk: SQLite cannot make that file again.
    let _ = std::fs::remove_file(dir.db_file().with_file_name("tessera.db-shm"));
    // The disk filled to its last byte by another program's file.
    let filler = dir.db_file().with_file_name("filler");
    {
        use std::io::Write;
        let mut f = std::fs::File::create(&filler).expect("a file");
        let block = vec![0u8; 64 << 10];
        while f.write_all(&block).is_ok() {}
        let byte = [0u8; 1];
        while f.write_all(&byte).is_ok() {}
    }
    let svc = Service::start(&dir, &args);
    assert!(
        svc.log()
            .contains("one connection serves its reads and writes"),
        "the database opened as usual: {}",
        svc.log()
    );
    serves_reads_only(&svc, &id, &png);
    std::fs::remove_file(&filler).expect("room again");
    takes_writes_again(&svc);
}
