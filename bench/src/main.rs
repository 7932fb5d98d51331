//! `tessera-bench`: Tessera's benchmark programs. Each prints its figures and writes its
//! results; none of them asserts a speed (that would make tests flaky); the numbers go into
//! the README with the machine they came from.
//!
//! - `chart`: speed against accuracy. Every sampler at a range of settings on scenes that
//!   stress sampling, against a high-rate reference of the exact image; a CSV and an SVG
//!   chart (error against time, log-log, Pareto front marked).
//! - `features`: what each feature of a scene costs in rays and time, and that unused
//!   features cost nothing.
//! - `povray`: trace time and image difference against POV-Ray 3.7 on the same scenes.
//! - `tracer`: rays per second on the bench scenes, and how the per-ray cost grows with the
//!   number of objects with and without the BVH.

mod chart;
mod features;
mod povray;
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
    /// Rays per second per thread, and the BVH's scaling with the object count.
    Tracer(tracer::Args),
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().command {
        Command::Chart(args) => chart::run(&args),
        Command::Features(args) => features::run(&args),
        Command::Povray(args) => povray::run(&args),
        Command::Tracer(args) => tracer::run(&args),
    }
}
