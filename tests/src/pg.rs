//! A throwaway PostgreSQL server for one test binary, and a fresh database on it for each
//! test: the real server the PostgreSQL variants of the tests run against (no mock, no
//! server shared between test binaries or machines).
//!
//! [`server`] starts it on first use: `initdb` into a new temporary folder, then `postgres`
//! on a free loopback port with its socket in that folder, from the Debian `postgresql`
//! package's binaries (`/usr/lib/postgresql/*/bin`, the highest version; `TESSERA_PG_BIN`
//! names another folder). Running as root, both run as the `postgres` user, since they
//! refuse root. The server is started by a small shell that reads commands on its stdin
//! from a pipe this process holds: when this process exits, however it ends (a panic, a
//! SIGKILL), the pipe closes, and the shell stops the server and removes the folder.
//!
//! Over TCP only [`USER`] is trusted; any other role must give its password
//! (`scram-sha-256`), so that tests can give a wrong one.
//!
//! This module uses the standard library only (the server's own `psql` and `pg_isready`
//! talk to it), so that any test crate can include it. It is not a way to run PostgreSQL
//! for anything but tests: `fsync` is off, and anyone on the machine may connect as
//! `tessera` without a password.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

/// The role the tests connect as: the cluster's superuser, with `trust` authentication.
pub const USER: &str = "tessera";

/// How long the server may take to accept connections after a start.
const READY_WITHIN: Duration = Duration::from_secs(60);

/// How many free ports are tried when another process takes the chosen one first.
const PORT_TRIES: u32 = 5;

/// The shell that owns the server: `$1` the binaries' folder, `$2` the folder, `$3` the
/// port. It runs `initdb`, starts the server, then answers one line per command read
/// (`start PORT`: `started` or `failed`; `stop`: `stopped`). End of input (this process
/// gone) stops the server and removes the folder. `pg_ctl -w` waits (polling, up to a
/// minute) until a started server accepts connections or has exited, and a stopped one
/// has exited, so a stop never meets a server still setting up its signal handlers.
/// Signals are caught, and do nothing, so that an interrupt meant for the test run or an
/// answer written after this process is gone (SIGPIPE) cannot skip the cleanup.
const SUPERVISOR: &str = r#"
bin=$1 dir=$2 port=$3
trap : INT TERM HUP QUIT PIPE
start() {
  if "$bin/pg_ctl" -D "$dir/data" -l "$dir/log" -w -t 60 -s -o "-p $port -k $dir \
      -c listen_addresses=127.0.0.1 -c fsync=off -c max_connections=300" start \
      </dev/null >/dev/null 2>&1; then
    echo started
  else
    echo failed
  fi
}
stop() {
  "$bin/pg_ctl" -D "$dir/data" -w -t 60 -s -m fast stop </dev/null >/dev/null 2>&1
  echo stopped
}
if "$bin/initdb" -D "$dir/data" -A trust -U tessera --no-sync -E UTF8 --locale=C \
    >"$dir/initdb.log" 2>&1 </dev/null; then
  printf '%s\n' 'local all all trust' 'host all tessera 127.0.0.1/32 trust' \
    'host all all 127.0.0.1/32 scram-sha-256' >"$dir/data/pg_hba.conf"
  start
else
  echo "initdb failed"
fi
while read -r cmd arg; do
  case $cmd in
    start) port=${arg:-$port}; start ;;
    stop) stop ;;
  esac
done
stop >/dev/null
rm -rf "$dir"
"#;

/// The test binary's server, started on first use; panics, saying what to install or
/// fix, when it cannot start.
pub fn server() -> &'static Server {
    match try_server() {
        Ok(s) => s,
        Err(e) => panic!("the test PostgreSQL server: {e}"),
    }
}

/// The server of this process, once started (see [`try_server`]).
static SERVER: OnceLock<Result<Server, String>> = OnceLock::new();

/// The test binary's server, started on first use, or why it cannot start (for callers
/// that go on without it, such as the benchmarks).
pub fn try_server() -> Result<&'static Server, String> {
    SERVER
        .get_or_init(Server::launch)
        .as_ref()
        .map_err(Clone::clone)
}

/// A fresh, empty database on [`server`], for one test.
pub fn database() -> Database {
    server().database()
}

/// A running throwaway PostgreSQL server.
pub struct Server {
    bin: PathBuf,
    dir: PathBuf,
    port: Mutex<u16>,
    control: Mutex<Control>,
    databases: AtomicU32,
}

/// The pipe to the shell that owns the server, and its answers. Never dropped: the
/// server lives as long as this process, and the pipe closes with it.
struct Control {
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
    _shell: Child,
}

/// A database of its own on the server, dropped (with any connections still open to it)
/// when this value is.
pub struct Database {
    pub name: String,
    pub url: String,
}

impl Drop for Database {
    fn drop(&mut self) {
        let _ = server().try_sql(
            "postgres",
            &format!("DROP DATABASE IF EXISTS {} WITH (FORCE)", self.name),
        );
    }
}

/// The folder of the PostgreSQL binaries: `TESSERA_PG_BIN`, else the highest version
/// under `/usr/lib/postgresql`.
fn binaries() -> Result<PathBuf, String> {
    let install = "install the `postgresql` package (Debian and Ubuntu: \
                   `apt-get install postgresql`) to run the PostgreSQL tests, or set \
                   TESSERA_PG_BIN to a folder holding `initdb` and `postgres`";
    if let Some(dir) = std::env::var_os("TESSERA_PG_BIN") {
        let dir = PathBuf::from(dir);
        if dir.join("postgres").is_file() && dir.join("initdb").is_file() {
            return Ok(dir);
        }
        return Err(format!(
            "TESSERA_PG_BIN is {}, which holds no `postgres` and `initdb`: {install}",
            dir.display()
        ));
    }
    let root = Path::new("/usr/lib/postgresql");
    let mut found: Vec<(Vec<u32>, PathBuf)> = std::fs::read_dir(root)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().into_string().ok()?;
            let version = name
                .split('.')
                .map(|p| p.parse::<u32>().ok())
                .collect::<Option<Vec<u32>>>()?;
            let bin = e.path().join("bin");
            (bin.join("postgres").is_file() && bin.join("initdb").is_file())
                .then_some((version, bin))
        })
        .collect();
    found.sort();
    found.pop().map(|(_, bin)| bin).ok_or_else(|| {
        format!(
            "no PostgreSQL binaries in {}/*/bin: {install}",
            root.display()
        )
    })
}

/// Whether this process runs as root (whose `initdb` and `postgres` must run as another
/// user).
fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
}

/// A loopback port that was free a moment ago.
fn free_port() -> Result<u16, String> {
    let l = std::net::TcpListener::bind("127.0.0.1:0").map_err(|e| format!("no free port: {e}"))?;
    l.local_addr()
        .map(|a| a.port())
        .map_err(|e| format!("no free port: {e}"))
}

impl Server {
    fn launch() -> Result<Server, String> {
        let bin = binaries()?;
        static N: AtomicU32 = AtomicU32::new(0);
        let dir = std::env::temp_dir().join(format!(
            "tessera-pg-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        let root = is_root();
        if root {
            let owned = Command::new("chown")
                .arg("postgres:")
                .arg(&dir)
                .status()
                .map_err(|e| format!("chown: {e}"))?;
            if !owned.success() {
                let _ = std::fs::remove_dir_all(&dir);
                return Err(format!(
                    "running as root, and PostgreSQL refuses to: the server runs as the \
                     `postgres` user, and {} cannot be given to it (is there such a user? \
                     the `postgresql` package creates it)",
                    dir.display()
                ));
            }
        }
        let mut port = free_port()?;
        let mut shell = if root {
            let mut c = Command::new("runuser");
            c.args(["-u", "postgres", "--", "sh", "-c", SUPERVISOR, "sh"]);
            c
        } else {
            let mut c = Command::new("sh");
            c.args(["-c", SUPERVISOR, "sh"]);
            c
        };
        let mut shell = shell
            .arg(&bin)
            .arg(&dir)
            .arg(port.to_string())
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .map_err(|e| format!("the shell that runs the server: {e}"))?;
        let control = Control {
            stdin: shell.stdin.take().ok_or("no stdin")?,
            stdout: BufReader::new(shell.stdout.take().ok_or("no stdout")?),
            _shell: shell,
        };
        let server = Server {
            bin,
            dir,
            port: Mutex::new(port),
            control: Mutex::new(control),
            databases: AtomicU32::new(0),
        };
        let mut answer = server.control.lock().map_err(|_| "poisoned")?.answer()?;
        if answer == "initdb failed" {
            let log = std::fs::read_to_string(server.dir.join("initdb.log")).unwrap_or_default();
            return Err(format!("initdb failed:\n{log}"));
        }
        // Another process may take the port between its choice and the server's bind:
        // then another port, a few times.
        for _ in 1..PORT_TRIES {
            if answer != "failed" || !server.log().contains("could not bind") {
                break;
            }
            port = free_port()?;
            *server.port.lock().map_err(|_| "poisoned")? = port;
            answer = server.command(&format!("start {port}"))?;
        }
        if answer != "started" {
            return Err(format!("the server did not start:\n{}", server.log()));
        }
        server.wait_ready()?;
        Ok(server)
    }

    /// The server's port on 127.0.0.1.
    pub fn port(&self) -> u16 {
        *self.port.lock().expect("the port's lock is never poisoned")
    }

    /// The folder of the server's data, socket and log (`log`).
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The server's log so far.
    pub fn log(&self) -> String {
        std::fs::read_to_string(self.dir.join("log")).unwrap_or_default()
    }

    /// The URL of database `db` on this server as [`USER`].
    pub fn url(&self, db: &str) -> String {
        format!("postgres://{USER}@127.0.0.1:{}/{db}", self.port())
    }

    /// A new, empty database: `t_<n>`.
    pub fn database(&self) -> Database {
        let name = format!("t_{}", self.databases.fetch_add(1, Ordering::Relaxed));
        self.sql("postgres", &format!("CREATE DATABASE {name}"));
        Database {
            url: self.url(&name),
            name,
        }
    }

    /// Runs `sql` (one or more statements) in database `db` with `psql`; its output, one
    /// line per row and `|` between columns. Panics with the server's error.
    pub fn sql(&self, db: &str, sql: &str) -> String {
        self.try_sql(db, sql)
            .unwrap_or_else(|e| panic!("SQL failed in {db}: {sql}\n{e}"))
    }

    /// [`Server::sql`], returning the error (as `psql` printed it) instead of panicking.
    pub fn try_sql(&self, db: &str, sql: &str) -> Result<String, String> {
        let out = Command::new(self.bin.join("psql"))
            .args([
                "-X",
                "-q",
                "-A",
                "-t",
                "-v",
                "ON_ERROR_STOP=1",
                "-h",
                "127.0.0.1",
            ])
            .arg("-p")
            .arg(self.port().to_string())
            .args(["-U", USER, "-d", db, "-c", sql])
            .stdin(Stdio::null())
            .output()
            .map_err(|e| format!("psql: {e}"))?;
        if out.status.success() {
            Ok(String::from_utf8_lossy(&out.stdout).trim_end().to_string())
        } else {
            Err(String::from_utf8_lossy(&out.stderr).into_owned())
        }
    }

    /// Stops the server (a fast shutdown: open connections are closed) and waits until
    /// its process has exited.
    pub fn stop(&self) {
        let answer = self.command("stop").expect("the server stops");
        assert_eq!(answer, "stopped");
    }

    /// Starts the server again, on the same port and data, and waits until it accepts
    /// connections.
    pub fn start(&self) {
        self.command(&format!("start {}", self.port()))
            .expect("the server starts");
        self.wait_ready()
            .expect("the server accepts connections again");
    }

    /// [`Server::stop`], then [`Server::start`].
    pub fn restart(&self) {
        self.stop();
        self.start();
    }

    /// Sends `line` to the shell that owns the server, and returns its answer.
    fn command(&self, line: &str) -> Result<String, String> {
        let mut c = self.control.lock().map_err(|_| "poisoned")?;
        writeln!(c.stdin, "{line}").map_err(|e| format!("the server's shell: {e}"))?;
        c.stdin
            .flush()
            .map_err(|e| format!("the server's shell: {e}"))?;
        c.answer()
    }

    /// Waits until the server accepts connections on its socket.
    fn wait_ready(&self) -> Result<(), String> {
        let deadline = Instant::now() + READY_WITHIN;
        loop {
            let ready = Command::new(self.bin.join("pg_isready"))
                .args(["-q", "-h"])
                .arg(&self.dir)
                .arg("-p")
                .arg(self.port().to_string())
                .args(["-U", USER, "-d", "postgres"])
                .status()
                .map_err(|e| format!("pg_isready: {e}"))?;
            if ready.success() {
                return Ok(());
            }
            if Instant::now() > deadline {
                return Err(format!(
                    "the server did not accept connections within {READY_WITHIN:?}:\n{}",
                    self.log()
                ));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Control {
    /// The shell's next line.
    fn answer(&mut self) -> Result<String, String> {
        let mut line = String::new();
        match self.stdout.read_line(&mut line) {
            Ok(0) => Err("the server's shell exited".into()),
            Ok(_) => Ok(line.trim().to_string()),
            Err(e) => Err(format!("the server's shell: {e}")),
        }
    }
}
