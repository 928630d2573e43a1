//! rspiv-engine: the standalone Rust command line over dewarp-core and piv-core, for cluster
//! nodes without Python. Every sub-command lives in its own module; errors print one line naming
//! the file and the problem and exit with status 2.

use clap::{Parser, Subcommand};

mod cmd_calibrate;
mod cmd_dewarp;
mod cmd_mapping;
mod cmd_piv;
mod csv;
mod imageio;
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
    /// Fit a mapping model (r1, r2, p3) to point pairs x_obj,y_obj,x_img,y_img from a CSV file.
    FitMapping(cmd_mapping::FitMappingArgs),
    /// Apply a saved mapping to points x,y from a CSV file (object -> image, or --inverse).
    Map(cmd_mapping::MapArgs),
    /// Calibrate from a target image: markers, grid, mapping -> calibration JSON.
    Calibrate(cmd_calibrate::CalibrateArgs),
    /// Multipass PIV of an image pair (TIFF/PNG/BMP/JPEG), plain or corrected (--calibration,
    /// --method I|II) -> CSV of x,y,u,v,valid,replaced,masked,peak_ratio,coef,peak_choice,sigma_u,sigma_v.
    Piv(Box<cmd_piv::PivArgs>),
    /// Dewarp images through a calibration (Method I, Keys bicubic) -> 16-bit TIFF.
    Dewarp(cmd_dewarp::DewarpArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result: Result<(), String> = match cli.command {
        Command::FitMapping(args) => cmd_mapping::run_fit_mapping(&args),
        Command::Map(args) => cmd_mapping::run_map(&args),
        Command::Calibrate(args) => cmd_calibrate::run_calibrate(&args),
        Command::Piv(args) => cmd_piv::run_piv(&args),
        Command::Dewarp(args) => cmd_dewarp::run_dewarp(&args),
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
