//! `nam-cli`: the command-line front end of nam (DESIGN.md §1).
//!
//! One module per subcommand under `cmd/`; shared helpers: `args` (value parsers),
//! `backend` (`--model`, `--backend`, `--precision`), `output` (atomic image writing),
//! `progress` (indicatif bars for long work), `sweep` (light sweeps, contact sheets, GIFs),
//! `viewer` (the browser viewer's server).

mod args;
mod backend;
mod cmd;
mod forecast;
mod output;
mod progress;
mod sweep;
mod viewer;

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
    /// Relight a photo or a saved material (.nam) for new lights and views (sweeps too).
    Relight(cmd::relight::Args),
    /// Estimate a photo's neural material once and save it (.nam).
    Estimate(cmd::estimate::Args),
    /// Describe a model (.safetensors) or a material (.nam).
    Info(cmd::info::Args),
    /// Error against run time on the held-out set: Markdown table and PNG plot.
    Report(cmd::report::Args),
    /// Time the CPU paths (estimate, relights, ROI, queries) against each other: Markdown table.
    Bench(cmd::bench::Args),
    /// Serve an interactive relighting viewer to a browser on this machine (127.0.0.1).
    View(cmd::view::Args),
}

/// libwayland-client, loaded by Mesa's Vulkan drivers while wgpu enumerates adapters, prints
/// "error: XDG_RUNTIME_DIR is invalid or not set in the environment." whenever the variable is
/// missing or relative (containers, CI, ssh sessions), even though no display is ever used.
/// A successful run must not print errors, so point it at the temp dir when unusable; it only
/// serves as the place where wayland would look for a compositor socket.
#[cfg(feature = "gpu")]
fn quiet_wayland_probe() {
    let usable =
        std::env::var_os("XDG_RUNTIME_DIR").is_some_and(|d| std::path::Path::new(&d).is_absolute());
    if !usable {
        // SAFETY: called first thing in `main`, before any other thread exists, so nothing
        // reads the environment concurrently.
        unsafe { std::env::set_var("XDG_RUNTIME_DIR", std::env::temp_dir()) };
    }
}

fn main() -> ExitCode {
    #[cfg(feature = "gpu")]
    quiet_wayland_probe();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::RenderGgx(args) => cmd::render_ggx::run(&args),
        Command::Relight(args) => cmd::relight::run(&args),
        Command::Estimate(args) => cmd::estimate::run(&args),
        Command::Info(args) => cmd::info::run(&args),
        Command::Report(args) => cmd::report::run(&args),
        Command::Bench(args) => cmd::bench::run(&args),
        Command::View(args) => cmd::view::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}
