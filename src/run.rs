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
    /// With `--frames`, frame F's light volumes in `frame_FFFF/` and its
    /// images `image_FFFF.exr` and `image_FFFF.png`, beside the frames'
    /// manifest (`manifest-run.json`).
    #[arg(short, long)]
    output: PathBuf,
    #[command(flatten)]
    overrides: Overrides,
    #[command(flatten)]
    frames: crate::frames::FrameFlags,
    #[command(flatten)]
    gif: crate::frames::GifFlag,
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
/// a directional light ([Ihrke07 fig 7]), with its caustic.
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
    if args.frames.frames.is_some() {
        return run_frames(&args);
    }
    let scene = args.overrides.grid.load(&args.scene)?;
    let images = ["image.exr", "image.png"].map(|f| args.output.join(f));
    simulate_and_render(&args.scene, &scene, &args.output, &args.overrides, &images)
}

/// The images of frame `f` of `eikon run --frames`, relative to the
/// output folder.
fn frame_images(f: usize) -> [PathBuf; 2] {
    ["image.exr", "image.png"].map(|n| crate::frames::numbered(Path::new(n), f))
}

/// `eikon run --frames`: per frame, simulate into `OUT/frame_FFFF/` and
/// render `OUT/image_FFFF.exr` and `.png`, the medium built once when no
/// object moves; then the `--gif`.
fn run_frames(args: &Args) -> Result<()> {
    use crate::frames::{finish_gif, frame_dir, Job, Media, Output, Plan};
    args.gif.check()?;
    let anim = args.overrides.grid.load_animation(&args.scene)?;
    let plan = Plan::new(&args.frames, &args.scene, &anim)?;
    let backend = args.overrides.backend.select(false)?;
    let sim = simulate::Args::defaults(args.scene.clone(), args.output.clone());
    let settings = format!(
        "{}; render {}",
        sim.settings(&backend)?,
        crate::render::overrides_settings(&args.overrides, &backend)
    );
    let mut job = Job::open(&args.output, "run", &plan, settings, false)?;
    let mut media = Media::new(&anim, false);
    job.run(|f| {
        let scene = anim.frame(f)?;
        let (medium, note) = media.of(&scene)?;
        let dir = frame_dir(&args.output, f);
        let sim = simulate::Args::defaults(args.scene.clone(), dir.clone());
        let volumes = simulate::simulate_quiet(&sim, &scene, &medium, &backend)?;
        let (image, ..) =
            crate::render::render_image(&scene, &medium, &volumes, &args.overrides, &backend)?;
        let images = frame_images(f);
        let paths: Vec<PathBuf> = images.iter().map(|n| args.output.join(n)).collect();
        crate::render::write_images(
            &paths,
            &image,
            &crate::render::tone(&scene, &args.overrides),
        )?;
        let mut files = simulate::frame_files(&dir)?;
        files.extend(images);
        Ok(Output {
            files,
            note: note.to_string(),
            pending: false,
        })
    })?;
    if let Some(gif) = &args.gif.gif {
        let png = |f: usize| args.output.join(&frame_images(f)[1]);
        finish_gif(gif, &args.output, "run", plan.range, anim.fps, png, false)?;
    }
    Ok(())
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
