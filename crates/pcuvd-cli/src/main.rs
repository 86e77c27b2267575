//! `pcuvd`: simulate, process and quantify ultrafast vector Doppler acquisitions.

mod figures;
mod options;
mod process;
mod progress;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Pulse-coded ultrafast vector Doppler (PC-UVD) and conventional UVD, from channel data to velocity vectors.
#[derive(Parser)]
#[command(name = "pcuvd", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Process a recording (MUST-style .mat or pcuvd manifest .toml) into B-mode, power, colour and vector Doppler maps.
    Process(process::ProcessArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Process(args) => process::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            // `{:#}` prints the whole cause chain on one line and never the captured backtrace.
            eprintln!("error: {error:#}");
            ExitCode::FAILURE
        }
    }
}
