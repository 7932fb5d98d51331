//! A worker given several servers (`--server URL1,URL2,...`), end to end: real services on
//! real sockets, each with its own SQLite file and its own job, and one worker process
//! that spreads its claims over them, skips one that does not answer, carries on when one
//! dies and comes back to it once it answers again.
//!
//! Services on one SQLite file each are separate farms, not replicas: these tests show the
//! worker's choice of server and its fall-over, which do not depend on the farm behind the
//! URLs. A result posted to another replica of the same farm needs a shared database
//! (PostgreSQL), and is tested with it.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use common::{Service, TempDir, WORKER, examples, local_png, wait_until};

const JOB_TIME: Duration = Duration::from_secs(120);

fn read(name: &str) -> String {
    std::fs::read_to_string(examples().join(name)).expect("example readable")
}

/// A loopback address with a port free right now: nothing answers there (or, once a
/// service is started on it, a restarted service can take it again).
fn free_addr() -> String {
    let l = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    l.local_addr().expect("addr").to_string()
}

/// A worker process with its log (`tessera_worker` at `info`) in a file.
struct Worker {
    child: Child,
    log: PathBuf,
}

impl Worker {
    fn start(servers: &[&str], name: &str, threads: u32, dir: &TempDir) -> Worker {
        let log = dir.path().join(format!("{name}.log"));
        let child = Command::new(WORKER)
            .arg("--server")
            .arg(servers.join(","))
            .args(["--threads", &threads.to_string(), "--idle-max-ms", "50"])
            .args(["--name", name])
            .env("RUST_LOG", "tessera_worker=info")
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).expect("log file can be created"))
            .spawn()
            .expect("worker starts");
        Worker { child, log }
    }

    fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// The log's lines that contain every one of `words`.
    fn lines_with(&self, words: &[&str]) -> usize {
        self.log()
            .lines()
            .filter(|l| words.iter().all(|w| l.contains(w)))
            .count()
    }

    fn running(&mut self) -> bool {
        self.child.try_wait().ok().flatten().is_none()
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn tiles_done(svc: &Service, id: &str) -> u64 {
    svc.get_json(&format!("/jobs/{id}"))["tiles_done"]
        .as_u64()
        .unwrap_or(0)
}

/// Tiles that `worker` rendered, as the service counts them.
fn tiles_by(svc: &Service, worker: &str) -> u64 {
    let workers = svc.get_json("/workers");
    workers
        .as_array()
        .and_then(|ws| ws.iter().find(|w| w["name"] == worker))
        .map_or(0, |w| w["tiles_done"].as_u64().unwrap_or(0))
}

fn assert_done_and_exact(svc: &Service, id: &str, scene: &Path, query_samples: Option<u32>) {
    let job = svc.wait_finished(id, JOB_TIME);
    assert_eq!(job["state"], "done", "{job}\n{}", svc.log());
    let sampler = query_samples.map(|_| "jitter");
    assert!(
        svc.image(id) == local_png(scene, sampler, query_samples),
        "the farm's PNG of {} differs from tessera-render's",
        scene.display()
    );
}

#[test]
fn one_worker_given_two_services_renders_both_their_jobs() {
    let (dir_a, dir_b) = (TempDir::new("two-a"), TempDir::new("two-b"));
    let a = Service::start(&dir_a, &["--local-workers", "0"]);
    let b = Service::start(&dir_b, &["--local-workers", "0"]);
    let job_a = a.submit_id(&read("thesis.ray"), "?tile=32");
    let job_b = b.submit_id(&read("checker.ray"), "?tile=32");
    let dir = TempDir::new("two-worker");
    let mut w = Worker::start(&[&a.url, &b.url], "both", 2, &dir);
    assert_done_and_exact(&a, &job_a, &examples().join("thesis.ray"), None);
    assert_done_and_exact(&b, &job_b, &examples().join("checker.ray"), None);
    // Every tile of each job came from the one worker, through its own service.
    assert_eq!(tiles_by(&a, "both"), 20 * 15);
    assert_eq!(tiles_by(&b, "both"), 15 * 12);
    assert!(w.running(), "{}", w.log());
    assert_eq!(w.lines_with(&["WARN"]), 0, "{}", w.log());
}

#[test]
fn a_worker_whose_first_server_is_dead_renders_on_the_second() {
    let dir_b = TempDir::new("dead-first-b");
    let b = Service::start(&dir_b, &["--local-workers", "0"]);
    let dead = format!("http://{}", free_addr());
    let job = b.submit_id(&read("thesis.ray"), "?tile=16");
    let dir = TempDir::new("dead-first-worker");
    let mut w = Worker::start(&[&dead, &b.url], "skips-the-dead", 2, &dir);
    assert_done_and_exact(&b, &job, &examples().join("thesis.ray"), None);
    assert_eq!(tiles_by(&b, "skips-the-dead"), 40 * 30);
    assert!(w.running(), "{}", w.log());
    // Gone is said once, not once per request; it never came back.
    assert_eq!(
        w.lines_with(&[&dead, "using the other servers meanwhile"]),
        1,
        "{}",
        w.log()
    );
    assert_eq!(w.lines_with(&["answers again"]), 0, "{}", w.log());
}

#[test]
fn a_worker_carries_on_when_one_service_dies_and_comes_back_to_it() {
    let (dir_a, dir_b) = (TempDir::new("dies-a"), TempDir::new("dies-b"));
    let addr_a = free_addr();
    // Its tiles rendering when it dies are charged to the worker once their leases run out
    // after the restart: not enough to keep the worker away from the job.
    let a_args = [
        "--local-workers",
        "0",
        "--lease-ms",
        "2000",
        "--keep-away-after",
        "50",
        "--max-attempts",
        "50",
    ];
    let mut a = Service::start_on(&dir_a, &addr_a, &a_args);
    let b = Service::start(&dir_b, &["--local-workers", "0"]);
    // Four rays a pixel: long enough for the worker to be mid-job when the service dies.
    let query = "?tile=16&sampler=jitter&samples=2";
    let job_a = a.submit_id(&read("thesis.ray"), query);
    let job_b = b.submit_id(&read("checker.ray"), query);
    let dir = TempDir::new("dies-worker");
    let mut w = Worker::start(&[&a.url, &b.url], "carries-on", 2, &dir);
    wait_until("tiles of both jobs rendered", JOB_TIME, || {
        tiles_done(&a, &job_a) >= 20 && tiles_done(&b, &job_b) >= 20
    });
    a.kill();
    let url_a = a.url.clone();

    // The worker renders the rest of B's job, and B's next one, without A.
    let checker = examples().join("checker.ray");
    assert_done_and_exact(&b, &job_b, &checker, Some(2));
    let next = b.submit_id(&read("checker.ray"), "?tile=32");
    assert_done_and_exact(&b, &next, &checker, None);
    assert!(w.running(), "{}", w.log());
    assert_eq!(
        w.lines_with(&[&url_a, "using the other servers meanwhile"]),
        1,
        "{}",
        w.log()
    );

    // A, back on its address with its database, gets the worker back and its job done.
    let a = Service::start_on(&dir_a, &addr_a, &a_args);
    assert_done_and_exact(&a, &job_a, &examples().join("thesis.ray"), Some(2));
    assert_eq!(w.lines_with(&[&url_a, "answers again"]), 1, "{}", w.log());
    assert!(w.running(), "{}", w.log());
}
