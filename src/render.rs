//! `eikon render`: an image of a scene, lit by light volumes written by
//! `eikon simulate`.

use crate::backend::Backend;
use crate::output::{build_medium, write_all_atomic};
use anyhow::{bail, Context, Result};
use clap::ValueEnum;
use eikon_grid::{ray, Medium, Scene};
use eikon_optics::{encode_exr, encode_png, Camera, Exposure, Image, ToneMap};
use eikon_view::{Options, Renderer, Stats, Surroundings};
use eikon_wavefront::lightdir::{LightDir, SIDECAR};
use eikon_wavefront::LightVolume;
use glam::DVec3;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Clone, Copy, Debug, ValueEnum)]
enum Integrator {
    /// Forward Euler [Ihrke07 eqs 11-12], the paper's choice.
    Euler,
    /// Classical fourth-order Runge-Kutta.
    Rk4,
}

/// Settings of a render that override the scene's `[camera]` and
/// `[render]` (shared by `render`, `run` and `demo`).
#[derive(clap::Args, Clone, Default)]
pub struct Overrides {
    /// Image width, pixels.
    #[arg(long)]
    width: Option<u32>,
    /// Image height, pixels.
    #[arg(long)]
    height: Option<u32>,
    /// Samples per pixel.
    #[arg(long)]
    samples: Option<u32>,
    /// Exposure in stops (default: the scene's, else automatic from the
    /// log-average luminance).
    #[arg(long, allow_hyphen_values = true)]
    exposure: Option<f64>,
    /// Eye-ray step, voxels.
    #[arg(long)]
    step: Option<f64>,
    /// Eye-ray integrator.
    #[arg(long, value_enum)]
    integrator: Option<Integrator>,
    /// March through empty space step by step instead of skipping it (to
    /// measure what skipping saves).
    #[arg(long)]
    no_skip: bool,
    /// Seed of the pixel sample jitter.
    #[arg(long)]
    pub seed: Option<u64>,
    #[command(flatten)]
    pub backend: crate::backend::BackendFlag,
    #[command(flatten)]
    pub grid: crate::grid::GridFlags,
}

/// How `eikon render` forms the image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum RenderMethod {
    /// The paper's pipeline: the voxelized scene, curved eye rays, light
    /// volumes from `eikon simulate`.
    Eikonal,
    /// Exact single scattering in a mesh-bounded medium, point samples
    /// along each refracted camera ray connected to the lights through the
    /// boundary (Walter et al. 2009).
    Walter,
    /// Exact single scattering, integrated per boundary triangle along the
    /// refracted camera ray (Holzschuch 2015).
    Holzschuch,
    /// Single scattering with straight shadow rays: refraction on the light
    /// side ignored (the approximation the exact methods improve on).
    Straight,
    /// Wyman's image-space two-interface refraction and caustic maps on
    /// the GPU's render pipelines: the fast approximate preview.
    Wyman,
}

impl RenderMethod {
    /// The name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            RenderMethod::Eikonal => "eikonal",
            RenderMethod::Walter => "walter",
            RenderMethod::Holzschuch => "holzschuch",
            RenderMethod::Straight => "straight",
            RenderMethod::Wyman => "wyman",
        }
    }
}

/// Settings of the exact mesh methods.
#[derive(clap::Args, Clone, Default)]
pub struct ExactOptions {
    /// Scatter points per refracted camera segment (walter, straight;
    /// default 32) or per piece of a triangle's interval (holzschuch;
    /// default 1).
    #[arg(long)]
    pub scatter_samples: Option<usize>,
    /// Find every refracted connection on smooth triangles with the
    /// interval (Krawczyk) test instead of the 30-degree cone heuristic.
    #[arg(long)]
    pub guaranteed: bool,
}

/// Arguments of `eikon render`.
#[derive(clap::Args)]
pub struct Args {
    /// Scene file (TOML).
    scene: PathBuf,
    /// Light volumes written by `eikon simulate` (without them in-scatter
    /// and the receiver are dark). Only for `--method eikonal`. With
    /// `--frames`, the output folder of `eikon simulate --frames`: frame F
    /// is lit by `LIGHT/frame_FFFF/`.
    #[arg(long)]
    light: Option<PathBuf>,
    /// Output image: `.exr` (linear HDR) or `.png` (tone-mapped); repeat
    /// for both. With `--frames`, frame F goes to `NAME_FFFF.png` (and
    /// `.exr`), every image in the first one's folder, beside the frames'
    /// manifest (`manifest-render.json`).
    #[arg(short, long, required = true)]
    output: Vec<PathBuf>,
    /// How to form the image. The exact methods need a scene whose one
    /// object is a mesh (type = "mesh", "bumpy_sphere", "cuboctahedron").
    #[arg(long, value_enum, default_value = "eikonal")]
    method: RenderMethod,
    #[command(flatten)]
    exact: ExactOptions,
    #[command(flatten)]
    wyman: crate::wyman::WymanOptions,
    #[command(flatten)]
    overrides: Overrides,
    /// Print the render's statistics as JSON (not with `--frames`: `eikon
    /// status FOLDER --json` reports a frame run).
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    frames: crate::frames::FrameFlags,
    #[command(flatten)]
    gif: crate::frames::GifFlag,
}

/// Run `eikon render`.
pub fn run(args: Args) -> Result<()> {
    check_outputs(&args.output)?;
    if args.method != RenderMethod::Eikonal && args.light.is_some() {
        bail!("--light: light volumes are for --method eikonal; the other methods reach the lights themselves");
    }
    if args.frames.frames.is_some() {
        return run_frames(&args);
    }
    let scene = args.overrides.grid.load(&args.scene)?;
    if args.method == RenderMethod::Wyman {
        return crate::wyman::render(
            &scene,
            &args.overrides,
            &args.wyman,
            &args.output,
            args.json,
        );
    }
    if args.method != RenderMethod::Eikonal {
        let (image, stats, seconds) = exact_image(&scene, &args)?;
        let tone = tone(&scene, &args.overrides);
        write_images(&args.output, &image, &tone)?;
        let names: Vec<String> = args
            .output
            .iter()
            .map(|p| p.display().to_string())
            .collect();
        if args.json {
            println!(
                "{}",
                serde_json::to_string_pretty(&json!({
                    "method": args.method.name(),
                    "outputs": names,
                    "width": image.width,
                    "height": image.height,
                    "seconds": seconds,
                    "scatter_points": stats.scatter_points,
                    "paths": stats.paths,
                    "occluded": stats.occluded,
                }))?
            );
        } else {
            println!(
                "rendered {} x {} with {} in {seconds:.3} s ({} scatter points, {} refracted paths to the lights, {} occluded); wrote {}",
                image.width,
                image.height,
                args.method.name(),
                stats.scatter_points,
                stats.paths,
                stats.occluded,
                names.join(", ")
            );
        }
        return Ok(());
    }
    let medium = build_medium(&scene)?;
    let volumes = match &args.light {
        Some(dir) => load_light_volumes(dir, &scene, &medium)?,
        None => Vec::new(),
    };
    let backend = args.overrides.backend.select(args.json)?;
    render_scene(
        &scene,
        &medium,
        &volumes,
        &args.overrides,
        &backend,
        &args.output,
        args.json,
    )
}

/// Render `scene` by an exact mesh method (`--method walter`, ...): the
/// image, its statistics and the seconds it took.
fn exact_image(scene: &Scene, args: &Args) -> Result<(Image, eikon_exact::single::Stats, f64)> {
    let camera = camera(scene, &args.overrides)?;
    let method = crate::exact::method(args.method.name(), args.exact.scatter_samples)?;
    let seed = args.overrides.seed.unwrap_or(scene.render.seed);
    let started = Instant::now();
    let (image, stats) = crate::exact::render(scene, &camera, method, args.exact.guaranteed, seed)?;
    Ok((image, stats, started.elapsed().as_secs_f64()))
}

/// The settings of `overrides` that shape an image, as one line (for a
/// frame run's manifest), rendering on `backend`.
pub fn overrides_settings(o: &Overrides, backend: &Backend) -> String {
    format!(
        "width {:?}; height {:?}; samples {:?}; exposure {:?}; step {:?}; integrator {:?}; skip empty {}; seed {:?}; preview {}; grid {:?}; backend {}",
        o.width,
        o.height,
        o.samples,
        o.exposure,
        o.step,
        o.integrator,
        !o.no_skip,
        o.seed,
        o.grid.preview,
        o.grid.grid_override(),
        backend.name()
    )
}

/// The images of a frame run, all in the folder of the first: that folder
/// and their file names (relative to it).
fn frame_outputs(outputs: &[PathBuf]) -> Result<(PathBuf, Vec<PathBuf>)> {
    use crate::frames::{folder_of, relative_to};
    let folder = folder_of(&outputs[0]);
    let mut names: Vec<PathBuf> = Vec::new();
    for o in outputs {
        let name = relative_to(&folder, o)
            .filter(|n| n.components().count() == 1)
            .with_context(|| {
                format!(
                    "{}: -o: with --frames every image goes to one folder, that of the first -o ({}), where the frames' manifest is kept",
                    o.display(),
                    folder.display()
                )
            })?;
        if names.contains(&name) {
            bail!("{}: -o: given twice", o.display());
        }
        names.push(name);
    }
    Ok((folder, names))
}

/// `eikon render --frames`: frame F's images to `NAME_FFFF.EXT` beside each
/// `-o`, lit by `LIGHT/frame_FFFF/`; the medium built once when no object
/// moves; then the `--gif`.
fn run_frames(args: &Args) -> Result<()> {
    use crate::frames::{
        check_light_frames, finish_gif, frame_dir, numbered, Job, Media, Output, Plan,
    };
    if args.json {
        bail!("--json: not with --frames (`eikon status FOLDER --json` reports a frame run)");
    }
    args.gif.check()?;
    let (folder, names) = frame_outputs(&args.output)?;
    let png = names
        .iter()
        .find(|n| extension(n).as_deref() == Some("png"))
        .cloned();
    if args.gif.gif.is_some() && png.is_none() {
        bail!("--gif: needs a .png -o output: the GIF is made of the frames' tone-mapped PNGs");
    }
    let anim = args.overrides.grid.load_animation(&args.scene)?;
    let plan = Plan::new(&args.frames, &args.scene, &anim)?;
    if let Some(light) = &args.light {
        check_light_frames(light, plan.frames())?;
    }
    let eikonal = args.method == RenderMethod::Eikonal;
    let backend = if eikonal {
        args.overrides.backend.select(false)?
    } else {
        Backend::Cpu
    };
    let wyman = if args.method == RenderMethod::Wyman {
        crate::wyman::check_backend(&args.overrides)?;
        crate::wyman::check(&anim.frame(plan.range.first)?)?;
        Some(crate::wyman::device()?)
    } else {
        None
    };
    let settings = format!(
        "method {}; light {}; images {}; scatter samples {:?}; guaranteed {}; wyman {}; {}",
        args.method.name(),
        args.light
            .as_ref()
            .map_or("none".to_string(), |l| l.display().to_string()),
        names
            .iter()
            .map(|n| n.display().to_string())
            .collect::<Vec<_>>()
            .join(" "),
        args.exact.scatter_samples,
        args.exact.guaranteed,
        args.wyman.describe(),
        overrides_settings(&args.overrides, &backend)
    );
    let mut job = Job::open(&folder, "render", &plan, settings, false)?;
    job.lit_by(args.light.as_deref());
    let mut media = Media::new(&anim, false);
    job.run(|f| {
        let scene = anim.frame(f)?;
        let (image, note) = if eikonal {
            let (medium, note) = media.of(&scene)?;
            let volumes = match &args.light {
                Some(l) => load_light_volumes(&frame_dir(l, f), &scene, &medium)?,
                None => Vec::new(),
            };
            let (image, ..) = render_image(&scene, &medium, &volumes, &args.overrides, &backend)?;
            (image, note)
        } else if let Some(gpu) = &wyman {
            (
                crate::wyman::image(gpu, &scene, &args.overrides, &args.wyman)?.0,
                "",
            )
        } else {
            (exact_image(&scene, args)?.0, "")
        };
        let files: Vec<PathBuf> = names.iter().map(|n| numbered(n, f)).collect();
        let paths: Vec<PathBuf> = files.iter().map(|n| folder.join(n)).collect();
        write_images(&paths, &image, &tone(&scene, &args.overrides))?;
        Ok(Output {
            files,
            note: note.to_string(),
            pending: false,
        })
    })?;
    if let (Some(gif), Some(png)) = (&args.gif.gif, &png) {
        finish_gif(
            gif,
            &folder,
            "render",
            plan.range,
            anim.fps,
            |f| folder.join(numbered(png, f)),
            false,
        )?;
    }
    Ok(())
}

/// The camera of `scene` with the command line's overrides.
pub fn camera(scene: &Scene, overrides: &Overrides) -> Result<Camera> {
    let mut cs = eikon_view::render::camera_settings(scene);
    if overrides.grid.preview {
        // At most PREVIEW_WIDTH wide, the scene's aspect ratio, one sample.
        let [w, h] = cs.resolution;
        if w > crate::grid::PREVIEW_WIDTH {
            let scale = crate::grid::PREVIEW_WIDTH as f64 / w as f64;
            cs.resolution = [
                crate::grid::PREVIEW_WIDTH,
                ((h as f64 * scale).round() as u32).max(1),
            ];
        }
        cs.samples = 1;
    }
    if let Some(w) = overrides.width {
        cs.resolution[0] = w;
    }
    if let Some(h) = overrides.height {
        cs.resolution[1] = h;
    }
    if let Some(s) = overrides.samples {
        cs.samples = s;
    }
    // The same limits as the scene's [camera] (scene.rs).
    let [w, h] = cs.resolution;
    if !(1..=MAX_IMAGE_SIDE).contains(&w) || !(1..=MAX_IMAGE_SIDE).contains(&h) {
        bail!("--width/--height: image size must be 1 to {MAX_IMAGE_SIDE} pixels a side, got {w} x {h}");
    }
    if !(1..=MAX_SAMPLES).contains(&cs.samples) {
        bail!(
            "--samples: must lie in 1..={MAX_SAMPLES}, got {}",
            cs.samples
        );
    }
    eikon_view::render::camera(&cs).with_context(|| format!("{}: camera", scene.origin))
}

/// The largest image side, pixels (as the scene's `[camera] resolution`).
pub const MAX_IMAGE_SIDE: u32 = 16384;

/// The most samples per pixel.
pub const MAX_SAMPLES: u32 = 4096;

/// The tone mapping of `scene` with the command line's exposure.
pub fn tone(scene: &Scene, overrides: &Overrides) -> ToneMap {
    ToneMap {
        exposure: match overrides.exposure.or(scene.render.exposure) {
            Some(stops) => Exposure::Fixed(stops),
            None => Exposure::Auto,
        },
        ..ToneMap::default()
    }
}

/// Refuse output paths whose format is unknown before any work is done.
pub fn check_outputs(outputs: &[PathBuf]) -> Result<()> {
    for o in outputs {
        match extension(o).as_deref() {
            Some("exr") | Some("png") => {}
            _ => bail!(
                "{}: -o: unknown image format: use a .exr (linear HDR) or .png (tone-mapped) file name",
                o.display()
            ),
        }
    }
    Ok(())
}

fn extension(p: &Path) -> Option<String> {
    p.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
}

/// Render `scene` lit by `volumes` and write every image of `outputs`.
pub fn render_scene(
    scene: &Scene,
    medium: &Medium,
    volumes: &[LightVolume],
    overrides: &Overrides,
    backend: &Backend,
    outputs: &[PathBuf],
    json: bool,
) -> Result<()> {
    let (image, stats, seconds) = render_image(scene, medium, volumes, overrides, backend)?;
    let tone = tone(scene, overrides);
    write_images(outputs, &image, &tone)?;
    report(&image, &stats, seconds, outputs, json)
}

/// Render `scene` (built as `medium`, lit by `volumes`) with the eikonal
/// pipeline on `backend`: the image, its statistics (the CPU's; the GPU
/// counts none) and the seconds it took.
pub fn render_image(
    scene: &Scene,
    medium: &Medium,
    volumes: &[LightVolume],
    overrides: &Overrides,
    backend: &Backend,
) -> Result<(Image, Stats, f64)> {
    let camera = camera(scene, overrides)?;
    let r = &scene.render;
    let opts = Options {
        step: overrides.step.unwrap_or(r.step),
        integrator: match overrides.integrator {
            Some(Integrator::Euler) => ray::Integrator::Euler,
            Some(Integrator::Rk4) => ray::Integrator::Rk4,
            None => r.integrator,
        },
        skip_empty: !overrides.no_skip,
        seed: overrides.seed.unwrap_or(r.seed),
        ..Options::default()
    };
    if !(opts.step > 0.0 && opts.step <= 4.0) {
        bail!("--step: must lie in (0, 4] voxels, got {}", opts.step);
    }
    let env = eikon_view::background::load_environment(&scene.background)
        .with_context(|| format!("{}: background.file", scene.origin))?;
    // Said once, not for every frame of a sequence.
    static WARNED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    if volumes.is_empty()
        && !scene.lights.is_empty()
        && !WARNED.swap(true, std::sync::atomic::Ordering::Relaxed)
    {
        eprintln!(
            "warning: no --light volumes given: in-scatter and the receiver are dark (run `eikon simulate` first, or `eikon run`)"
        );
    }
    let gpu = backend.renderer_host_bytes(medium, volumes, &env, &camera, &opts);
    crate::grid::check_memory(
        scene,
        &crate::grid::Needs {
            light_volumes: !volumes.is_empty(),
            renderer: true,
            pixels: Some(camera.width() as u64 * camera.height() as u64),
            gpu,
            ..crate::grid::Needs::default()
        },
    )?;
    let surroundings = Surroundings::new(scene, env, volumes, &medium.geometry);
    crate::backend::announce();
    #[cfg(feature = "gpu")]
    if let Backend::Gpu(gpu) = backend {
        let started = Instant::now();
        // With sharp interfaces: the analytic shapes; any other is refused
        // here, naming the object.
        let renderer = eikon_view::gpu::GpuRenderer::with_scene(
            gpu,
            scene,
            medium,
            volumes,
            &surroundings,
            &camera,
            opts,
        )?;
        let (image, stats) = renderer.render_with_stats()?;
        return Ok((image, stats, started.elapsed().as_secs_f64()));
    }
    let mut renderer = Renderer::new(medium, volumes, &surroundings, &camera, opts);
    if scene.grid.interfaces == eikon_grid::Interfaces::Sharp {
        renderer = renderer.sharp(scene);
    }

    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "rendering {bar:40} {pos}/{len} tiles ({elapsed}, {eta} left)",
        )
        .expect("valid template"),
    );
    let started = Instant::now();
    let (image, stats) = renderer.render(&|done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    });
    let seconds = started.elapsed().as_secs_f64();
    bar.finish_and_clear();
    Ok((image, stats, seconds))
}

/// Write `image` to each of `paths`: EXR (linear) or PNG (tone-mapped by
/// `tone`), all renamed into place together once every one is complete.
pub fn write_images(paths: &[PathBuf], image: &Image, tone: &ToneMap) -> Result<()> {
    let mut outputs = Vec::with_capacity(paths.len());
    for path in paths {
        let bytes = match extension(path).as_deref() {
            Some("exr") => encode_exr(image),
            _ => encode_png(image, tone),
        }
        .with_context(|| format!("{}: encoding the image", path.display()))?;
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("{}: cannot create the folder", dir.display()))?;
        }
        outputs.push((path.clone(), bytes));
    }
    write_all_atomic(&outputs)
}

fn report(
    image: &Image,
    stats: &Stats,
    seconds: f64,
    outputs: &[PathBuf],
    json: bool,
) -> Result<()> {
    let names: Vec<String> = outputs.iter().map(|p| p.display().to_string()).collect();
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({
                "outputs": names,
                "width": image.width,
                "height": image.height,
                "seconds": seconds,
                "ray_steps": stats.steps,
                "empty_skips": stats.skips,
                "mean_luminance": image.data.iter().map(|&p| eikon_optics::image::luminance(p)).sum::<f64>() / image.data.len().max(1) as f64,
            }))?
        );
    } else {
        println!(
            "rendered {} x {} in {seconds:.3} s ({} ray steps, {} empty-space skips); wrote {}",
            image.width,
            image.height,
            stats.steps,
            stats.skips,
            names.join(", ")
        );
    }
    Ok(())
}

/// Read the light volumes of `dir` (written by `eikon simulate`) for
/// `scene`, checking that they belong to its grid and lights before reading
/// them, and every file against the sidecar as they are read
/// ([`eikon_wavefront::lightdir`]).
pub fn load_light_volumes(dir: &Path, scene: &Scene, medium: &Medium) -> Result<Vec<LightVolume>> {
    let folder = LightDir::open(dir)?;
    let meta = &folder.sidecar;
    let sidecar = dir.join(SIDECAR);
    let g = &medium.geometry;
    let dims = meta.grid.dims;
    let (min, max) = (
        DVec3::from_array(meta.grid.min),
        DVec3::from_array(meta.grid.max),
    );
    let tol = 1e-9 * g.diagonal();
    if dims != g.dims
        || (min - g.min).abs().max_element() > tol
        || (max - g.max).abs().max_element() > tol
    {
        bail!(
            "{}: grid: the light volumes are {}x{}x{} over {:?} .. {:?}, but {} is {}x{}x{} over {:?} .. {:?}: simulate this scene again, or render with the --resolution (or --preview) it was simulated with",
            sidecar.display(),
            dims[0], dims[1], dims[2], min.to_array(), max.to_array(),
            scene.origin,
            g.dims[0], g.dims[1], g.dims[2], g.min.to_array(), g.max.to_array()
        );
    }
    if meta.lights.len() != scene.lights.len() {
        bail!(
            "{}: lights: {} light volume(s), but {} has {} light(s): simulate this scene again",
            sidecar.display(),
            meta.lights.len(),
            scene.origin,
            scene.lights.len()
        );
    }
    for l in &meta.lights {
        let arrays = if l.flux_shape.len() == 5 { 3 } else { 1 };
        if arrays != medium.channels() {
            bail!(
                "{}: {arrays} flux volume(s) but the scene has {} index field(s) (dispersion differs): simulate this scene again",
                dir.join(&l.flux_file).display(),
                medium.channels()
            );
        }
    }
    Ok(folder.volumes()?)
}
