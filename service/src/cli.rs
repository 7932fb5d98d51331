//! The `tessera-service` command line: flags, logging, the runtime, errors at the edge.
//! Kept in the library so that end-to-end tests can build the same program.

use std::process::ExitCode;

use clap::{CommandFactory, Parser};

use tessera_worker::shutdown_signal;

use crate::config::Config;
use crate::startup::run;

/// The program: parses flags, serves until SIGINT/SIGTERM, reports errors.
pub fn main() -> ExitCode {
    main_from(std::env::args_os())
}

/// [`main`] with the command line given (the first item is the program name).
pub fn main_from<I, T>(args: I) -> ExitCode
where
    I: IntoIterator<Item = T>,
    T: Into<std::ffi::OsString> + Clone,
{
    let cfg = Config::parse_from(args);
    if let Some(why) = cfg.token_problem() {
        // Here rather than in clap's parsing, whose refusal repeats the token as given;
        // clap's usage status (2) all the same.
        Config::command()
            .error(clap::error::ErrorKind::ValueValidation, why)
            .exit();
    }
    if cfg.receiving_bytes() < cfg.max_body_bytes {
        // Exits with clap's usage status (2), as a value out of its range does.
        Config::command()
            .error(
                clap::error::ErrorKind::ValueValidation,
                format!(
                    "--max-receiving-bytes ({}) must be at least --max-body-bytes ({}): a \
                     submission of the largest size could never be received",
                    cfg.receiving_bytes(),
                    cfg.max_body_bytes
                ),
            )
            .exit();
    }
    crate::memory::settle();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "info,sqlx=warn,tower_http=warn".into()),
        )
        .with_writer(std::io::stderr)
        // Colour only on a terminal: a log redirected to a file stays plain text.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    if let Some((before, after)) = crate::rlimit::raise_open_files() {
        tracing::info!("open-file limit raised from {before} to {after} (each connection is one)");
    }
    let runtime = match tokio::runtime::Runtime::new() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("tessera-service: cannot start the async runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    // The handlers are installed inside the runtime, before `run` announces itself.
    match runtime.block_on(async { run(cfg, shutdown_signal()).await }) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("tessera-service: {e}");
            ExitCode::FAILURE
        }
    }
}
