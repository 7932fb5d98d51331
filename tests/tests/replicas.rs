//! Several service replicas on one PostgreSQL database, as real processes: one job rendered
//! by workers of three replicas while one replica is killed, a hundred claimers across
//! three replicas, the database restarted under a job, replicas starting together on an
//! empty database, and the configurations a replica refuses at start.
//!
//! Every test here uses the test binary's PostgreSQL server, and one of them stops and
//! starts it: that one holds [`SERVER_USE`] for writing, the others for reading, so that no
//! other test sees the outage.

mod common;

use std::collections::HashMap;
use std::process::{Command, Stdio};
use std::sync::{PoisonError, RwLock, RwLockReadGuard};
use std::time::Duration;

use common::{Backend, SERVICE, Service, TempDir, Worker, client, local_png_from, pg, wait_exit};
use serde_json::Value;
use tessera_protocol::encode_tile;
use tessera_tracer::Rect;

const JOB_TIME: Duration = Duration::from_secs(180);

/// Held for reading by every test that needs the server up, for writing by the one that
/// stops it.
static SERVER_USE: RwLock<()> = RwLock::new(());

fn server_up() -> RwLockReadGuard<'static, ()> {
    SERVER_USE.read().unwrap_or_else(PoisonError::into_inner)
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

/// What `tessera-render` writes for `scene`.
fn rendered(scene: &str) -> Vec<u8> {
    local_png_from(scene, std::path::Path::new("."), None, None)
}

/// `n` replicas on `dir`'s database, started one after another.
fn replicas(dir: &TempDir, n: usize, args: &[&str]) -> Vec<Service> {
    (0..n).map(|_| Service::start(dir, args)).collect()
}

/// The `--server` of the `i`-th worker of a farm of `replicas`: every replica, starting
/// with a different one for each worker, so that claims are spread and a dead replica is
/// left for the others.
fn server_of(replicas: &[&str], i: usize) -> String {
    let n = replicas.len();
    (0..n)
        .map(|k| replicas[(i + k) % n])
        .collect::<Vec<_>>()
        .join(",")
}

fn tiles_done(svc: &Service, id: &str) -> u64 {
    svc.get_json(&format!("/jobs/{id}"))["tiles_done"]
        .as_u64()
        .unwrap_or(0)
}

/// Three replicas and four workers on one job; one replica is killed (SIGKILL) while the
/// job renders. The job still completes, through the others, to the image
/// `tessera-render` writes, and every live replica serves it.
#[test]
fn three_replicas_render_a_job_exactly_while_one_is_killed() {
    let _up = server_up();
    let dir = TempDir::on(Backend::Postgres, "three");
    let mut farm = replicas(&dir, 3, &["--local-workers", "0", "--lease-ms", "1500"]);
    let urls: Vec<&str> = farm.iter().map(|s| s.url.as_str()).collect();
    let workers: Vec<Worker> = (0..4)
        .map(|i| Worker::start(&server_of(&urls, i), &format!("w{i}"), &[]))
        .collect();
    let scene = mirror_cave(64, 3);
    let id = farm[1].submit_id(&scene, "?tile=8");
    let total = 64;
    common::wait_until("a quarter of the tiles", JOB_TIME, || {
        tiles_done(&farm[2], &id) >= total / 4
    });
    assert_ne!(
        farm[2].get_json(&format!("/jobs/{id}"))["state"],
        "done",
        "the job ended before the kill: make it longer"
    );
    farm[0].kill();
    let done = farm[2].wait_finished(&id, JOB_TIME);
    assert_eq!(done["state"], "done", "{done}");
    assert_eq!(done["tiles_done"], total);
    let png = farm[2].image(&id);
    assert!(png == rendered(&scene), "the farm's PNG differs");
    assert!(
        farm[1].image(&id) == png,
        "another replica serves other bytes"
    );
    drop(workers);
}

/// A claim as the service answered it.
#[derive(Debug, Clone)]
struct Claimed {
    idx: u64,
    lease: String,
    stored: bool,
}

/// A hundred claimers at once, spread over three replicas, each claiming until no tile is
/// left and posting the results of every other tile it got (to the next replica), holding
/// the rest. No tile is handed out twice (no lease runs out meanwhile), and the database's
/// own record agrees: each tile is leased or done under the one lease its claimer got,
/// done exactly when its result was posted.
#[test]
fn a_hundred_claimers_on_three_replicas_never_share_a_tile() {
    let _up = server_up();
    let dir = TempDir::on(Backend::Postgres, "claimers");
    let farm = replicas(&dir, 3, &["--local-workers", "0", "--lease-ms", "600000"]);
    let job = farm[0].submit(&mirror_cave(160, 1), "?tile=8");
    let id = job["id"].as_str().expect("id").to_string();
    let total = job["tiles_total"].as_u64().expect("tiles_total");
    assert_eq!(total, 400);
    let claimed: Vec<Claimed> = std::thread::scope(|s| {
        let claimers: Vec<_> = (0..100)
            .map(|i| {
                let farm = &farm;
                let id = id.as_str();
                s.spawn(move || {
                    let http = client();
                    let mut mine = Vec::new();
                    loop {
                        let r = farm[i % 3].claim(&format!("c{i}"));
                        if r.status() == 204 {
                            return mine;
                        }
                        assert_eq!(r.status(), 200, "a claim");
                        let c: Value = r.json().expect("a claim");
                        assert_eq!(c["job"], id);
                        let u = |k: &str| c[k].as_u64().expect("number") as u32;
                        let rect = Rect::new(u("x"), u("y"), u("w"), u("h"));
                        let idx = c["idx"].as_u64().expect("idx");
                        let lease = c["lease"].as_str().expect("lease").to_string();
                        let stored = mine.len() % 2 == 0;
                        if stored {
                            let r = http
                                .put(format!(
                                    "{}/worker/jobs/{id}/tiles/{idx}?lease={lease}",
                                    farm[(i + 1) % 3].url
                                ))
                                .body(encode_tile(rect, &vec![7u8; rect.pixel_count() * 3]))
                                .send()
                                .expect("an answer");
                            assert_eq!(r.status(), 200, "a result");
                        }
                        mine.push(Claimed { idx, lease, stored });
                    }
                })
            })
            .collect();
        claimers
            .into_iter()
            .flat_map(|c| c.join().expect("a claimer"))
            .collect()
    });
    let mut by_tile: HashMap<u64, Claimed> = HashMap::new();
    for c in &claimed {
        assert!(
            by_tile.insert(c.idx, c.clone()).is_none(),
            "tile {} handed out twice",
            c.idx
        );
    }
    assert_eq!(by_tile.len() as u64, total, "every tile handed out");
    let name = dir.pg_name().expect("a PostgreSQL database");
    let rows = pg::server().sql(
        name,
        &format!("SELECT idx, state, lease FROM tiles WHERE job_id = '{id}' ORDER BY idx"),
    );
    let mut seen = 0;
    for row in rows.lines() {
        let cols: Vec<&str> = row.split('|').collect();
        let [idx, state, lease] = cols[..] else {
            panic!("a row of three columns: {row}");
        };
        let c = &by_tile[&idx.parse::<u64>().expect("an index")];
        assert_eq!(lease, c.lease, "tile {idx}'s lease in the database");
        let expected = if c.stored { "done" } else { "leased" };
        assert_eq!(state, expected, "tile {idx}");
        seen += 1;
    }
    assert_eq!(seen, total);
    let stored = claimed.iter().filter(|c| c.stored).count() as u64;
    let done = pg::server().sql(
        name,
        &format!("SELECT tiles_done FROM jobs WHERE id = '{id}'"),
    );
    assert_eq!(done, stored.to_string());
}

/// PostgreSQL stops while a job renders: meanwhile the replicas answer `503` with the
/// reason (workers back off); once the server is back they reconnect by themselves, and
/// the job completes to the image `tessera-render` writes.
#[test]
fn a_database_restart_mid_job_loses_nothing() {
    let _alone = SERVER_USE.write().unwrap_or_else(PoisonError::into_inner);
    let dir = TempDir::on(Backend::Postgres, "restart");
    let farm = replicas(&dir, 2, &["--local-workers", "0", "--lease-ms", "3000"]);
    let urls: Vec<&str> = farm.iter().map(|s| s.url.as_str()).collect();
    let _workers: Vec<Worker> = (0..2)
        .map(|i| Worker::start(&server_of(&urls, i), &format!("w{i}"), &[]))
        .collect();
    let scene = mirror_cave(64, 3);
    let id = farm[0].submit_id(&scene, "?tile=8");
    common::wait_until("a few tiles", JOB_TIME, || tiles_done(&farm[1], &id) >= 4);
    let server = pg::server();
    server.stop();
    for svc in &farm {
        let r = svc.get(&format!("/jobs/{id}"));
        assert_eq!(r.status(), 503, "the job while the database is down");
        let e: Value = r.json().expect("a JSON error");
        assert!(
            e["error"].as_str().is_some_and(|m| !m.is_empty()),
            "a reason: {e}"
        );
        let r = svc.claim("probe");
        assert_eq!(r.status(), 503, "a claim while the database is down");
    }
    server.start();
    let done = farm[1].wait_finished(&id, JOB_TIME);
    assert_eq!(done["state"], "done", "{done}");
    assert!(
        farm[0].image(&id) == rendered(&scene),
        "the farm's PNG differs"
    );
}

/// Two replicas started at the same moment on an empty database both come up, with one
/// schema between them (each migration applied once), and serve the same farm.
#[test]
fn two_replicas_starting_at_once_share_one_schema() {
    let _up = server_up();
    let dir = TempDir::on(Backend::Postgres, "together");
    let args = ["--local-workers", "0"];
    let (a, b) = std::thread::scope(|s| {
        let a = s.spawn(|| Service::start(&dir, &args));
        let b = s.spawn(|| Service::start(&dir, &args));
        (a.join().expect("first"), b.join().expect("second"))
    });
    for svc in [&a, &b] {
        assert_eq!(svc.get("/healthz").status(), 200);
    }
    let migrations = std::fs::read_dir(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../migrations/postgres"),
    )
    .expect("the migrations")
    .filter(|e| {
        e.as_ref()
            .is_ok_and(|e| e.path().extension().is_some_and(|x| x == "sql"))
    })
    .count();
    let name = dir.pg_name().expect("a PostgreSQL database");
    let applied = pg::server().sql(
        name,
        "SELECT COUNT(*), COUNT(DISTINCT version) FROM _sqlx_migrations WHERE success",
    );
    assert_eq!(applied, format!("{migrations}|{migrations}"));
    let id = a.submit_id(&mirror_cave(16, 1), "");
    assert_eq!(b.get_json(&format!("/jobs/{id}"))["state"], "queued");
}

/// Runs a service on `database`, which must refuse to start: it exits non-zero within a
/// minute. Its standard error.
fn refused_at_start(database: &str) -> String {
    let dir = TempDir::new("refused");
    let err = dir.path().join("stderr");
    let mut child = Command::new(SERVICE)
        .args(["--listen", "127.0.0.1:0", "--local-workers", "0"])
        .arg("--database")
        .arg(database)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&err).expect("a file"))
        .spawn()
        .expect("the service runs");
    let status = wait_exit(&mut child, Duration::from_secs(60));
    let _ = child.kill();
    let said = std::fs::read_to_string(&err).unwrap_or_default();
    let status = status.unwrap_or_else(|| panic!("still running on {database}:\n{said}"));
    assert!(!status.success(), "started on {database}:\n{said}");
    said
}

/// Each way a database can be wrong is refused at start, named: no server there, refused
/// credentials (the password never shown), no such database, another application's tables,
/// and a schema newer than the binary.
#[test]
fn bad_databases_are_refused_at_start_by_name() {
    let _up = server_up();
    let server = pg::server();

    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port();
    let said = refused_at_start(&format!("postgres://tessera@127.0.0.1:{port}/t"));
    assert!(
        said.contains("PostgreSQL server") && said.contains(&format!("127.0.0.1:{port}")),
        "no server: {said}"
    );

    let db = pg::database();
    let _ = server.try_sql("postgres", "CREATE ROLE tessera_pw LOGIN PASSWORD 'right'");
    let url = format!(
        "postgres://tessera_pw:wrong@127.0.0.1:{}/{}",
        server.port(),
        db.name
    );
    let said = refused_at_start(&url);
    assert!(
        said.contains("credentials") && said.contains("tessera_pw"),
        "wrong password: {said}"
    );
    assert!(!said.contains(":wrong@"), "the password is shown: {said}");

    let said = refused_at_start(&server.url("no_such_database"));
    assert!(said.contains("no database `no_such_database`"), "{said}");

    server.sql(&db.name, "CREATE TABLE invoices (id INTEGER PRIMARY KEY)");
    let said = refused_at_start(&db.url);
    assert!(
        said.contains("another application") && said.contains("invoices"),
        "another application's tables: {said}"
    );

    let dir = TempDir::on(Backend::Postgres, "newer");
    let mut svc = Service::start(&dir, &["--local-workers", "0"]);
    let status = svc.terminate();
    assert!(status.success(), "{status}:\n{}", svc.log());
    let name = dir.pg_name().expect("a PostgreSQL database");
    server.sql(
        name,
        "INSERT INTO _sqlx_migrations (version, description, success, checksum, execution_time)
         VALUES (99990101000000, 'from a newer service', TRUE, '\\x00', 0)",
    );
    let said = refused_at_start(&dir.database());
    assert!(
        said.contains("newer") && said.contains("99990101000000"),
        "a newer schema: {said}"
    );
}
