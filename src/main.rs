//! The `strata` command line. See `strata --help` and DESIGN.md for the contracts.

use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;
use strata::cli;

#[derive(Parser)]
#[command(
    name = "strata",
    version,
    about = "Shading-language compiler and path tracer for binding-level layered shading"
)]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print the composed slot table of every renderable prim.
    Layers {
        /// A `.usda` scene (default: the embedded default scene).
        scene: Option<PathBuf>,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// Print the wired IR of one prim's composed material.
    Ir {
        /// A `.usda` scene.
        scene: PathBuf,
        /// The prim path (`/World/Ball`).
        #[arg(long)]
        prim: String,
        /// Skip constant folding and layer pruning.
        #[arg(long)]
        no_optimize: bool,
        /// Print node counts per pass to stderr.
        #[arg(long)]
        stats: bool,
    },
    /// Check a substance file or a scene and report every problem.
    Check {
        /// A `.ash` substance file or a `.usda` scene.
        file: PathBuf,
    },
}

fn main() -> ExitCode {
    let args = Args::parse();
    let result = match args.command {
        Command::Layers { scene, json } => cli::layers(scene.as_deref(), json),
        Command::Ir { scene, prim, no_optimize, stats } => cli::ir(&scene, &prim, !no_optimize, stats),
        Command::Check { file } => cli::check(&file),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(cli::Failure) => ExitCode::FAILURE,
    }
}
