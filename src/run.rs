//! `eikon run` (simulate, then render) and `eikon demo` (the same on a
//! built-in scene).

use crate::output::{build_medium, write_atomic};
use crate::render::{check_outputs, render_scene, Overrides};
use crate::simulate;
use anyhow::{Context, Result};
use eikon_grid::Scene;
use std::path::{Path, PathBuf};

/// Arguments of `eikon run`.
#[derive(clap::Args)]
pub struct Args {
    /// Scene file (TOML).
    scene: PathBuf,
    /// Output directory: the light volumes, `image.exr` and `image.png`.
    #[arg(short, long)]
    output: PathBuf,
    #[command(flatten)]
    overrides: Overrides,
}

/// Arguments of `eikon demo`.
#[derive(clap::Args)]
pub struct DemoArgs {
    /// Output directory: the scene, the light volumes, `demo.exr` and
    /// `demo.png`.
    #[arg(short, long, default_value = "eikon-demo")]
    output: PathBuf,
    #[command(flatten)]
    overrides: Overrides,
}

/// The built-in scene of `eikon demo`: a glass sphere over a table under
/// a directional light (the paper's Fig. 7), with its caustic.
pub const DEMO_SCENE: &str = include_str!("../configs/demo.toml");

/// Simulate `scene` into `dir`, then render it to `images`.
fn simulate_and_render(
    scene_path: &Path,
    scene: &Scene,
    dir: &Path,
    overrides: &Overrides,
    images: &[PathBuf],
) -> Result<()> {
    check_outputs(images)?;
    let medium = build_medium(scene)?;
    let backend = overrides.backend.select(false)?;
    let args = simulate::Args::defaults(scene_path.to_path_buf(), dir.to_path_buf());
    let volumes = simulate::simulate(&args, scene, &medium, &backend)?;
    render_scene(scene, &medium, &volumes, overrides, &backend, images, false)
}

/// Run `eikon run`.
pub fn run(args: Args) -> Result<()> {
    let scene = args.overrides.grid.load(&args.scene)?;
    let images = ["image.exr", "image.png"].map(|f| args.output.join(f));
    simulate_and_render(&args.scene, &scene, &args.output, &args.overrides, &images)
}

/// Run `eikon demo`.
pub fn demo(args: DemoArgs) -> Result<()> {
    let scene = args.overrides.grid.parse(DEMO_SCENE, "<demo scene>")?;
    std::fs::create_dir_all(&args.output).with_context(|| {
        format!(
            "{}: cannot create the output directory",
            args.output.display()
        )
    })?;
    let copy = args.output.join("demo.toml");
    write_atomic(&copy, |w| {
        w.write_all(DEMO_SCENE.as_bytes())
            .with_context(|| format!("{}: write failed", copy.display()))
    })?;
    let images = ["demo.exr", "demo.png"].map(|f| args.output.join(f));
    simulate_and_render(&copy, &scene, &args.output, &args.overrides, &images)
}
