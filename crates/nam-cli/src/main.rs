//! `nam-cli`: the command-line front end of nam (DESIGN.md §1).
//!
//! One module per subcommand under `cmd/`; shared helpers: `args` (value parsers),
//! `output` (atomic image writing), `progress` (indicatif bars for long work).

mod args;
mod cmd;
mod output;
mod progress;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// Neural appearance models: estimate, relight and render materials.
#[derive(Debug, Parser)]
#[command(name = "nam-cli", version, about, long_about = None, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Render a 4-panel GGX SVBRDF map (the analytic reference) for one light and view.
    RenderGgx(cmd::render_ggx::Args),
    /// Estimate a photo's neural material and relight it for a new light and view.
    Relight(cmd::relight::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::RenderGgx(args) => cmd::render_ggx::run(&args),
        Command::Relight(args) => cmd::relight::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}
