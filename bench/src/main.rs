//! `tessera-bench`: Tessera's benchmark programs. Each prints its figures and writes its
//! results; none of them asserts a speed (that would make tests flaky); the numbers go into
//! docs/PERFORMANCE.md with the command and the machine they came from.
//!
//! - `chart`: speed against accuracy. Every sampler at a range of settings on scenes that
//!   stress sampling, against a high-rate reference of the exact image; a CSV and an SVG
//!   chart (error against time, log-log, Pareto front marked).
//! - `features`: what each feature of a scene costs in rays and time, and that unused
//!   features cost nothing.
//! - `povray`: trace time and image difference against POV-Ray 3.7 on the same scenes.
//! - `embree`: rays per second against Intel Embree 3 tracing the same picture (skipped
//!   where Embree is not installed).
//! - `tracer`: rays per second on the bench scenes, and how the per-ray cost grows with the
//!   number of objects with and without the BVH.
//! - `farm`: the farm's overhead against the local tracer, two-worker scaling, queue
//!   throughput and the service's peak memory on a large image.
//! - `all`: `tracer`, `farm`, `povray` and `embree` in one run: every performance figure.

mod chart;
mod embree;
mod farm;
mod features;
mod povray;
mod scenes;
mod stats;
mod svg;
mod tracer;

use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(name = "tessera-bench", version, about = "Tessera's benchmarks")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Speed against accuracy for every sampler: CSV, SVG chart and a summary.
    Chart(chart::Args),
    /// Rays and time for scenes with and without each feature.
    Features(features::Args),
    /// Trace time and image difference against POV-Ray 3.7 on the same scenes.
    Povray(povray::Args),
    /// Rays per second against an Embree 3 reference tracing the same picture.
    Embree(embree::Args),
    /// Rays per second per thread, and the BVH's scaling with the object count.
    Tracer(tracer::Args),
    /// The farm: overhead against the local tracer, scaling, queue throughput, memory.
    Farm(farm::Args),
    /// Every performance figure in one run: `tracer`, `farm`, `povray` and `embree`.
    All {
        /// The short modes (CI).
        #[arg(long)]
        quick: bool,
    },
}

fn dispatch(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Farm(args) => farm::run(&args),
        Command::Chart(args) => chart::run(&args),
        Command::Features(args) => features::run(&args),
        Command::Povray(args) => povray::run(&args),
        Command::Embree(args) => embree::run(&args),
        Command::Tracer(args) => tracer::run(&args),
        Command::All { quick } => {
            for sub in ["tracer", "farm", "povray", "embree"] {
                let mut argv = vec!["tessera-bench", sub];
                if quick {
                    argv.push("--quick");
                }
                println!("\n== tessera-bench {} ==", argv[1..].join(" "));
                dispatch(Cli::try_parse_from(argv)?.command)?;
            }
            Ok(())
        }
    }
}

fn main() -> anyhow::Result<()> {
    // The farm benchmark runs the service as a child process: this program, started again.
    let argv: Vec<std::ffi::OsString> = std::env::args_os().collect();
    if argv.get(1).is_some_and(|a| a == "__service") {
        let rest = std::iter::once(argv[0].clone()).chain(argv[2..].iter().cloned());
        return match tessera_service::main_from(rest) {
            code if code == std::process::ExitCode::SUCCESS => Ok(()),
            _ => anyhow::bail!("service failed"),
        };
    }
    // The chart counts a render's instructions in this program, started again under callgrind.
    if argv.get(1).is_some_and(|a| a == "__count") {
        return chart::count_child(&argv[2..]);
    }
    dispatch(Cli::parse().command)
}
