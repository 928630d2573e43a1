//! rspiv-engine: the standalone Rust command line over dewarp-core and piv-core, for cluster
//! nodes without Python. Every sub-command lives in its own module; errors print one line naming
//! the file and the problem and exit with status 2.

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "rspiv-engine",
    version,
    about = "rspiv engine: calibration, dewarping and PIV without Python"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print the engine's version and the number of worker threads.
    Info,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result: Result<(), String> = match cli.command {
        Command::Info => {
            println!(
                "rspiv-engine {} ({} threads)",
                env!("CARGO_PKG_VERSION"),
                rayon::current_num_threads()
            );
            Ok(())
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(msg) => {
            eprintln!("rspiv-engine: error: {msg}");
            ExitCode::from(2)
        }
    }
}
