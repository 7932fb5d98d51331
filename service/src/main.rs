//! `tessera-service`: the HTTP API, job queue and web page of a Tessera farm, with local
//! workers. See the `tessera_service` library for what it does.

use anyhow::Result;
use clap::Parser;
use tessera_service::{Config, run, shutdown_signal};

#[tokio::main]
async fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "info,sqlx=warn".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let cfg = Config::parse();
    run(cfg, shutdown_signal()).await?;
    Ok(())
}
