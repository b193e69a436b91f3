//! `eikon`: light transport in refractive volumes, from the command line.

mod backend;
mod bench;
mod compare;
mod exact;
mod export;
mod frames;
mod gallery;
mod grid;
mod info;
mod label;
mod output;
mod probe;
mod render;
mod run;
mod simulate;
mod slice;
mod trace;
mod wyman;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// Light transport in refractive volumes (Eikonal Rendering, Ihrke et al. 2007).
#[derive(Parser)]
#[command(name = "eikon", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Describe a scene: resolution, memory, index range, objects, lights.
    Info(info::Args),
    /// Trace one ray through a scene's index field with the ray equation.
    Trace(trace::Args),
    /// Write a false-colour PNG slice of a field, to see what was built.
    Slice(slice::Args),
    /// Simulate every light by adaptive wavefront tracing; write the light volumes.
    Simulate(simulate::Args),
    /// Print the simulated fluence and net flux at a point.
    Probe(probe::Args),
    /// Render an image of a scene lit by simulated light volumes.
    Render(render::Args),
    /// Simulate every light of a scene, then render it.
    Run(run::Args),
    /// Simulate and render a built-in scene (a glass sphere and its caustic): no files needed.
    Demo(run::DemoArgs),
    /// Time the standard scenes' light simulation and 800x600 frames on every available backend.
    Bench(bench::Args),
    /// Render a scene with a mesh-bounded medium by every method (eikonal, walter, holzschuch, straight; wyman on request), side by side, with errors and times.
    Compare(compare::Args),
    /// Write a scene's volumes (index, gradient, extinction, light) as OpenVDB grids and/or NumPy arrays.
    Export(export::Args),
    /// List the frames of a --frames run that are done, missing or failed (over every shard's manifest).
    Status(frames::StatusArgs),
    /// Make the pictures of docs/gallery from its manifest, or check that they still match what this code renders.
    Gallery(gallery::Args),
}

fn main() -> ExitCode {
    // Mesa's Vulkan drivers print "error: XDG_RUNTIME_DIR is invalid" while
    // probing for a display when it is unset (a headless machine, a
    // container); eikon never presents to a display, so any directory will
    // do. Set here, before any thread exists.
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
        std::env::set_var("XDG_RUNTIME_DIR", std::env::temp_dir());
    }
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Info(a) => info::run(a),
        Command::Trace(a) => trace::run(a),
        Command::Slice(a) => slice::run(a),
        Command::Simulate(a) => simulate::run(a),
        Command::Probe(a) => probe::run(a),
        Command::Render(a) => render::run(a),
        Command::Run(a) => run::run(a),
        Command::Demo(a) => run::demo(a),
        Command::Export(a) => export::run(a),
        Command::Compare(a) => compare::run(a),
        Command::Bench(a) => bench::run(a),
        Command::Gallery(a) => gallery::run(a),
        Command::Status(a) => frames::status(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
