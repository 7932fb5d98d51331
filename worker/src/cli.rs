//! The `tessera-worker` command line: flags (with environment fallbacks), logging, signals.
//! Kept in the library so that end-to-end tests can build the same program, and the service
//! can stop its local workers on the same signals.
//!
//! Not the worker itself: flags become a [`WorkerConfig`] handed to [`run`].

use std::process::ExitCode;
use std::time::Duration;

use clap::{CommandFactory, Parser};
use tessera_tracer::MAX_THREADS;

use crate::client::service_urls;
use crate::config::{WorkerConfig, default_name};
use crate::worker::run;

/// A stateless Tessera render worker: claims tiles from a service, traces them, posts them.
#[derive(Debug, Parser)]
#[command(name = "tessera-worker", version, about)]
struct Args {
    /// The service's base URL, http:// (this worker speaks plain HTTP, no TLS); or several,
    /// comma-separated, of replicas of one farm: claims are spread over them, and one that
    /// stops answering is skipped until it answers again.
    #[arg(long, env = "TESSERA_SERVER", default_value = "http://127.0.0.1:8080")]
    server: String,
    /// Tiles rendered at once, 1 to 1024 (default: one per core).
    #[arg(long, env = "TESSERA_THREADS",
          value_parser = clap::value_parser!(u16).range(1..=i64::from(MAX_THREADS)))]
    threads: Option<u16>,
    /// Bearer token for the worker routes, when the service requires one (empty: none).
    #[arg(long, env = "TESSERA_WORKER_TOKEN", hide_env_values = true)]
    token: Option<String>,
    /// This worker's name in the service's lists (default: host-pid-random).
    #[arg(long, env = "TESSERA_WORKER_NAME", value_parser = worker_name)]
    name: Option<String>,
    /// Longest pause between claims when idle, in milliseconds: 25 (the first pause: below
    /// it an idle worker would poll in a tight loop) to 60,000.
    #[arg(long, env = "TESSERA_IDLE_MAX_MS", default_value_t = 1000,
          value_parser = clap::value_parser!(u64).range(25..=60_000))]
    idle_max_ms: u64,
    /// Seconds to keep rendering held tiles after SIGINT/SIGTERM before giving them back,
    /// 0 to 86,400 (a day).
    #[arg(long, env = "TESSERA_GRACE_SECS", default_value_t = 30,
          value_parser = clap::value_parser!(u64).range(0..=86_400))]
    grace_secs: u64,
    /// Benchmarking only: skip tracing and post black tiles (measures the queue).
    #[cfg(feature = "bench")]
    #[arg(long, hide = true)]
    noop: bool,
}

fn worker_name(name: &str) -> Result<String, String> {
    tessera_protocol::check_worker_name(name).map(|()| name.to_string())
}

/// The program: parses flags, runs the worker until SIGINT/SIGTERM, reports errors.
pub fn main() -> ExitCode {
    let args = Args::parse();
    // Checked here rather than by clap, whose message repeats the value as given: a
    // password or a token would be printed back (usage error, status 2, all the same).
    let refuse = |msg: String| {
        Args::command()
            .error(clap::error::ErrorKind::ValueValidation, msg)
            .exit()
    };
    if let Err(e) = service_urls(&args.server) {
        refuse(format!("--server: {e}"));
    }
    if let Some(why) = args
        .token
        .as_deref()
        .and_then(tessera_protocol::token_problem)
    {
        refuse(format!("--token (or TESSERA_WORKER_TOKEN): {why}"));
    }
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        // Colour only on a terminal: a log redirected to a file stays plain text.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let mut cfg = WorkerConfig::new(args.server);
    if let Some(t) = args.threads {
        cfg.threads = usize::from(t);
    }
    cfg.token = args.token.filter(|t| !t.is_empty());
    cfg.name = args.name.unwrap_or_else(default_name);
    cfg.idle_max = Duration::from_millis(args.idle_max_ms);
    cfg.grace = Duration::from_secs(args.grace_secs);
    #[cfg(feature = "bench")]
    {
        cfg.noop = args.noop;
    }
    let runtime = match tokio::runtime::Runtime::new() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("tessera-worker: cannot start the async runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    // The handlers are installed inside the runtime, before `run` announces itself.
    match runtime.block_on(async { run(cfg, shutdown_signal()).await }) {
        Ok(summary) => {
            tracing::info!("rendered {} tiles", summary.tiles);
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("tessera-worker: {e}");
            ExitCode::FAILURE
        }
    }
}

/// SIGINT or SIGTERM, caught from the moment this is called: a signal that arrives while
/// the program starts is a graceful stop, never the default exit by signal. Call it inside
/// the Tokio runtime, before announcing that the program is ready. A second signal, while
/// the graceful stop is under way, ends the process at once (exit status 130), as a second
/// Ctrl-C does in most programs: what it held comes back to the queue when its leases run
/// out.
pub fn shutdown_signal() -> impl Future<Output = ()> + Send + 'static {
    let mut signals = Signals::install();
    async move {
        signals.next().await;
        tokio::spawn(async move {
            signals.next().await;
            tracing::warn!("a second signal: stopping now, without finishing or giving back tiles");
            std::process::exit(130);
        });
    }
}

/// The stop signals' handlers, installed when this is made (Tokio's signal streams register
/// at creation; `tokio::signal::ctrl_c` only at its first poll, too late for a signal sent
/// right after start-up).
struct Signals {
    #[cfg(unix)]
    interrupt: Option<tokio::signal::unix::Signal>,
    #[cfg(unix)]
    terminate: Option<tokio::signal::unix::Signal>,
}

impl Signals {
    fn install() -> Signals {
        #[cfg(unix)]
        {
            use tokio::signal::unix::{SignalKind, signal};
            Signals {
                interrupt: signal(SignalKind::interrupt()).ok(),
                terminate: signal(SignalKind::terminate()).ok(),
            }
        }
        #[cfg(not(unix))]
        Signals {}
    }

    /// The next stop signal. A handler that could not be installed never fires (rather than
    /// firing at once and ending the program right after it starts).
    async fn next(&mut self) {
        #[cfg(unix)]
        {
            async fn on(s: &mut Option<tokio::signal::unix::Signal>) {
                match s {
                    Some(s) => {
                        s.recv().await;
                    }
                    None => std::future::pending().await,
                }
            }
            tokio::select! {
                _ = on(&mut self.interrupt) => {}
                _ = on(&mut self.terminate) => {}
            }
        }
        #[cfg(not(unix))]
        if tokio::signal::ctrl_c().await.is_err() {
            std::future::pending::<()>().await;
        }
    }
}
