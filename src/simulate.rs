//! `eikon simulate`: the light volumes of every light of a scene.

use crate::backend::{Backend, BackendFlag};
use crate::output::{build_medium, build_surfaces};
use anyhow::{bail, Result};
use clap::ValueEnum;
use eikon_grid::{ray, Medium, Scene};
use eikon_wavefront::lightdir::{self, LightSummary, Run, RunOptions};
use eikon_wavefront::photons::simulate_photons_in;
use eikon_wavefront::{check_scene, DepositRule, LightVolume, Options, Summary};
use serde_json::{json, Value};
use std::path::PathBuf;
use std::time::Instant;

/// The most photons per light `--method photons` traces (hours on a
/// workstation; the tallies grow with the count).
pub const MAX_PHOTONS: usize = 10_000_000_000;

/// `--max-patches` unless the memory limit asks for fewer.
pub const DEFAULT_MAX_PATCHES: usize = 8 << 20;

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum SimMethod {
    /// Adaptive wavefront tracing (the paper's method).
    Wavefront,
    /// Brute-force photons with a track-length histogram: the baseline and
    /// cross-check (the same fluence and flux volumes, with noise).
    Photons,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum DepositArg {
    /// Track-length fluence and net flux of every patch; light passes
    /// through caustics.
    Fluence,
    /// The paper's rule [Ihrke07 sec 5.2.2]: the highest-energy ray per cell,
    /// patches culled at caustics. With --no-fresnel it reproduces the paper.
    Paper,
}

#[derive(Clone, Copy, ValueEnum)]
enum Integrator {
    /// Forward Euler, first order.
    Euler,
    /// Classical fourth-order Runge-Kutta.
    Rk4,
}

/// Arguments of `eikon simulate`.
#[derive(clap::Args, Clone)]
pub struct Args {
    /// Scene file (TOML).
    scene: PathBuf,
    /// Output directory (created if missing).
    #[arg(short, long)]
    output: PathBuf,
    /// Equal-time step, in voxels of optical path.
    #[arg(long, default_value_t = 0.5, allow_hyphen_values = true)]
    step: f64,
    /// Integrator for the particles.
    #[arg(long, value_enum, default_value = "rk4")]
    integrator: Integrator,
    /// Size of the emitted patches, in voxels [default: 0.5 at sharp
    /// interfaces, 1 with the smoothed index].
    #[arg(long, allow_hyphen_values = true)]
    patch_size: Option<f64>,
    /// Tessellate patches whose corners span more than this many voxels.
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true)]
    split: f64,
    /// Drop patches whose transmittance falls below this, in (0, 1).
    #[arg(long, default_value_t = 1e-4, allow_hyphen_values = true)]
    threshold: f64,
    /// Most patches alive at once [default: 8388608, or what fits the
    /// memory limit once the medium and volumes are held].
    #[arg(long)]
    max_patches: Option<usize>,
    /// Step limit per wavefront (default: 16 crossings of the volume's
    /// diagonal at its highest index).
    #[arg(long)]
    max_steps: Option<usize>,
    /// Light transport method.
    #[arg(long, value_enum, default_value = "wavefront")]
    method: SimMethod,
    /// How the wavefront becomes a light volume.
    #[arg(long, value_enum, default_value = "fluence")]
    deposit: DepositArg,
    /// No Fresnel transmission at interfaces ([Ihrke07 eq 18] has none).
    #[arg(long)]
    no_fresnel: bool,
    /// CPU: no straight runs of several steps through uniform space; every
    /// patch steps one step at a time, as on the GPU (to compare the
    /// backends' volumes).
    #[arg(long)]
    no_runs: bool,
    /// Do not trace the Fresnel-reflected light on (sharp interfaces, where
    /// it is traced by default as patches of its own; photons: as
    /// branches): the reflected part leaves the beam, counted as
    /// reflected. Faster, and the volumes read low wherever reflected
    /// light would go.
    #[arg(long)]
    no_reflections: bool,
    /// Photons per light (per colour channel with dispersion), with
    /// `--method photons`.
    #[arg(long, default_value_t = 1_000_000)]
    count: usize,
    /// Random seed of `--method photons`: the same seed gives the same
    /// volumes whatever the number of threads.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Print the summary as JSON.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    backend: BackendFlag,
    #[command(flatten)]
    grid: crate::grid::GridFlags,
    #[command(flatten)]
    frames: crate::frames::FrameFlags,
    /// Print nothing (for commands that simulate on the way to something else).
    #[arg(skip)]
    quiet: bool,
}

/// The time left when `step` of about `crossing` steps took `elapsed`
/// seconds: the light's straight crossing at the pace so far, or the
/// steps past it (refracted and trapped light) when it is over.
fn eta(elapsed: f64, step: usize, crossing: usize) -> String {
    if step == 0 {
        return "starting".to_string();
    }
    if step >= crossing {
        return format!("{} steps past the straight crossing", step - crossing);
    }
    let left = elapsed * (crossing - step) as f64 / step as f64;
    format!(
        "about {} left",
        indicatif::HumanDuration(std::time::Duration::from_secs_f64(left))
    )
}

/// Trapped power above this fraction of the entered power is warned about.
pub const TRAPPED_WARNING: f64 = 0.01;

/// The warning for light `i` when more than [`TRAPPED_WARNING`] of the power
/// that entered was still travelling at the step limit.
pub fn trapped_warning(i: usize, s: &Summary) -> Option<String> {
    let f = s.trapped_fraction();
    (f > TRAPPED_WARNING).then(|| {
        format!(
            "warning: light {i}: {:.1}% of the power that entered is trapped: still travelling when no longer followed ({} patches at the step limit of {} steps, {} split too faint to follow), typically held by total internal reflection; the volume holds its light only up to there",
            100.0 * f,
            s.step_limit,
            s.steps,
            s.faint
        )
    })
}

/// The summary of one light as JSON (as recorded in the sidecar).
pub fn summary_json(s: &Summary, seconds: f64) -> Value {
    serde_json::to_value(LightSummary::new(s, seconds)).expect("plain data")
}

fn print_summary(i: usize, s: &Summary, seconds: f64) {
    let rgb = |v: [f64; 3]| format!("({:.6}, {:.6}, {:.6})", v[0], v[1], v[2]);
    println!("light {i}");
    println!("  steps          {}", s.steps);
    println!(
        "  peak patches   {} ({} emitted)",
        s.peak_patches, s.emitted
    );
    println!(
        "  patches ended  {} exited, {} absorbed, {} too faint to follow, {} at caustics, {} at the step limit",
        s.exited, s.absorbed, s.faint, s.caustic, s.step_limit
    );
    if s.held > 0 {
        println!("  held back      {} splits (--max-patches)", s.held);
    }
    println!("  entered        {} W", rgb(s.entered));
    println!("  absorbed       {} W", rgb(s.absorbed_power));
    println!("  exited         {} W", rgb(s.exited_power));
    if s.reflections > 0 {
        println!(
            "  reflections    {} reflected patches traced on (Fresnel, at sharp interfaces)",
            s.reflections
        );
    }
    println!("  reflected      {} W (not traced)", rgb(s.reflected_power));
    println!("  culled         {} W", rgb(s.culled_power));
    if s.torn > 0 {
        println!(
            "  torn           {} W ({} thin tubes still torn at a sharp interface, dropped)",
            rgb(s.torn_power),
            s.torn
        );
    }
    println!(
        "  trapped        {} W (still travelling: at the step limit or too faint to follow)",
        rgb(s.trapped_power)
    );
    println!(
        "  imbalance      {:.2e} of the entered power",
        s.energy_imbalance()
    );
    println!("  wall time      {seconds:.2} s");
}

/// A simulation error of light `i`, an overflow located at the light's
/// power (what scales every value of its volume).
fn located(scene: &Scene, i: usize, e: eikon_wavefront::Error) -> anyhow::Error {
    match e {
        eikon_wavefront::Error::NotFinite(message) => {
            scene.error_at(&format!("light[{i}].power"), message).into()
        }
        e => e.into(),
    }
}

impl Args {
    /// The default settings, simulating `scene` into `output` (for
    /// `eikon run` and `eikon demo`).
    pub fn defaults(scene: PathBuf, output: PathBuf) -> Args {
        use clap::Parser;
        #[derive(Parser)]
        struct Wrap {
            #[command(flatten)]
            args: Args,
        }
        let mut args = Wrap::parse_from(["eikon", "scene", "-o", "out"]).args;
        args.scene = scene;
        args.output = output;
        args
    }

    fn options(&self) -> Result<Options> {
        let opts = Options {
            step: self.step,
            integrator: match self.integrator {
                Integrator::Euler => ray::Integrator::Euler,
                Integrator::Rk4 => ray::Integrator::Rk4,
            },
            patch_size: self.patch_size,
            split: self.split,
            threshold: self.threshold,
            max_patches: self.max_patches.unwrap_or(DEFAULT_MAX_PATCHES),
            max_steps: self.max_steps,
            deposit: match self.deposit {
                DepositArg::Fluence => DepositRule::Fluence,
                DepositArg::Paper => DepositRule::Paper,
            },
            fresnel: !self.no_fresnel,
            reflections: !self.no_reflections,
            max_depth: None,
            runs: !self.no_runs,
        };
        if let Err(e) = opts.check() {
            bail!("--{e}");
        }
        if self.method == SimMethod::Photons && !(1..=MAX_PHOTONS).contains(&self.count) {
            bail!(
                "--count: must lie in 1..={MAX_PHOTONS:e} photons per light, got {}",
                self.count
            );
        }
        Ok(opts)
    }
}

/// Run `eikon simulate`.
pub fn run(args: Args) -> Result<()> {
    args.options()?;
    if args.frames.frames.is_some() {
        return run_frames(&args);
    }
    let scene = args.grid.load(&args.scene)?;
    let backend = args.select_backend()?;
    // Nothing here renders. With sharp interfaces the wavefront on the
    // CPU reads each region's index and extinction from the scene: of the
    // voxels it needs only the boundary indicator, which the regions read
    // once (`Regions::clear_of`). Else what only renderers read goes. Both
    // go before the light volumes' counters are allocated.
    if args.reads_surfaces_alone(&scene, &backend)? {
        let mut medium = build_surfaces(&scene)?;
        let regions = eikon_grid::Regions::new(&scene).clear_of(&medium);
        medium.release_boundary();
        simulate_in(&args, &scene, &medium, &backend, Some(regions))?;
    } else {
        let mut medium = build_medium(&scene)?;
        medium.release_render_properties();
        simulate(&args, &scene, &medium, &backend)?;
    }
    Ok(())
}

impl Args {
    /// Whether the simulation reads the medium's surfaces alone
    /// (`Medium::build_surfaces_within`): the wavefront with sharp
    /// interfaces and the fluence deposit, on the CPU.
    fn reads_surfaces_alone(&self, scene: &Scene, backend: &Backend) -> Result<bool> {
        Ok(self.method == SimMethod::Wavefront
            && matches!(backend, Backend::Cpu)
            && scene.grid.interfaces == eikon_grid::Interfaces::Sharp
            && self.options()?.deposit == DepositRule::Fluence)
    }

    fn select_backend(&self) -> Result<Backend> {
        let gpu_asked = self.backend.backend == Some(crate::backend::BackendArg::Gpu);
        if self.method == SimMethod::Photons {
            if gpu_asked {
                bail!(
                    "--backend gpu: photons run on the CPU only (--method wavefront runs on the GPU)"
                );
            }
            return Ok(Backend::Cpu);
        }
        self.backend.select(self.json)
    }

    /// The settings that shape the volumes, as one line (a frame run's
    /// manifest records it; a resumed run must have the same).
    pub fn settings(&self, backend: &Backend) -> Result<String> {
        let method = self.method.to_possible_value().expect("no skipped values");
        Ok(format!(
            "method {}; {:?}; photons {}; seed {}; backend {}; grid {:?}",
            method.get_name(),
            self.options()?,
            self.count,
            self.seed,
            backend.name(),
            self.grid.grid_override()
        ))
    }
}

/// `eikon simulate --frames`: each frame's light volumes in
/// `OUT/frame_NNNN/`, the medium built once when only lights and the
/// camera move (see [`crate::frames`]). Shards share out (frame, light)
/// units ([`crate::frames::Plan::units`]): a shard holding only some
/// lights of a frame writes them to `OUT/parts/frame_NNNN/light_L/`, and
/// whichever shard completes a frame's last light puts the frame together.
fn run_frames(args: &Args) -> Result<()> {
    use crate::frames::{frame_dir, Job, Media, Output, Plan};
    let anim = args.grid.load_animation(&args.scene)?;
    let plan = Plan::new(&args.frames, &args.scene, &anim)?;
    let backend = args.select_backend()?;
    let mut job = Job::open(
        &args.output,
        "simulate",
        &plan,
        args.settings(&backend)?,
        args.quiet,
    )?;
    let lights = anim.frame(plan.range.first)?.lights.len();
    let units = plan.units(lights);
    job.visit(units.iter().map(|(f, _)| *f).collect());
    let mut media = Media::new(&anim, args.quiet);
    job.run(|f| {
        let scene = anim.frame(f)?;
        let (medium, note) = media.of(&scene)?;
        let dir = frame_dir(&args.output, f);
        let into = |output: PathBuf| Args {
            output,
            quiet: true,
            ..args.clone()
        };
        let mine = units
            .iter()
            .find(|(g, _)| *g == f)
            .map_or(&[][..], |(_, l)| l.as_slice());
        if mine.len() == scene.lights.len() {
            simulate(&into(dir.clone()), &scene, &medium, &backend)?;
            return Ok(Output {
                files: frame_files(&dir)?,
                note: note.to_string(),
                pending: false,
            });
        }
        let parts = parts_dir(&args.output, f);
        for &l in mine {
            let part = parts.join(format!("light_{l}"));
            if lightdir::LightDir::open(&part).is_ok() {
                continue; // written by an earlier run of this shard
            }
            let mut one = scene.clone();
            one.lights = vec![scene.lights[l].clone()];
            simulate(&into(part), &one, &medium, &backend)?;
        }
        Ok(match assemble(&args.output, f, &scene)? {
            Some(files) => Output {
                files,
                note: format!("{note}, lights {mine:?} here, the others from other shards"),
                pending: false,
            },
            None => Output {
                files: Vec::new(),
                note: format!("lights {mine:?} written; the frame waits for other shards' lights"),
                pending: true,
            },
        })
    })
}

/// Where the lights of frame `f` simulated by separate shards wait to be
/// put together.
fn parts_dir(out: &std::path::Path, f: usize) -> PathBuf {
    out.join("parts").join(format!("frame_{f:04}"))
}

/// Put frame `f` together from its lights' parts once every one is there
/// (its files, relative to `out`), or `None` while some are missing. Two
/// shards finishing a frame's last lights at once may both do it: they
/// write the same arrays, and the one that finds the parts already gone
/// takes the other's frame.
fn assemble(out: &std::path::Path, f: usize, scene: &Scene) -> Result<Option<Vec<PathBuf>>> {
    let parts = parts_dir(out, f);
    let dir = crate::frames::frame_dir(out, f);
    let mut found = Vec::with_capacity(scene.lights.len());
    for l in 0..scene.lights.len() {
        match lightdir::LightDir::open(&parts.join(format!("light_{l}"))) {
            Ok(d) => found.push(d),
            Err(_) => return Ok(None),
        }
    }
    let put = || -> Result<Vec<PathBuf>> {
        let volumes = found
            .iter()
            .map(|d| Ok(d.volumes()?.remove(0)))
            .collect::<Result<Vec<LightVolume>>>()?;
        let first = &found[0].sidecar;
        let run = Run {
            scene: first.scene.clone(),
            method: first.method.clone(),
            options: first.options.clone(),
            backend: first.backend.clone(),
            seconds: found.iter().map(|d| d.sidecar.seconds).sum(),
            lights: scene
                .lights
                .iter()
                .zip(&volumes)
                .zip(&found)
                .map(|((light, v), d)| (light, v, d.sidecar.lights[0].summary.clone()))
                .collect(),
        };
        lightdir::write(&dir, &first.geometry(), &run)?;
        frame_files(&dir)
    };
    match put() {
        Ok(files) => {
            let _ = std::fs::remove_dir_all(&parts);
            // The parts folder goes with its last frame (not while another
            // frame's parts are in it).
            let _ = std::fs::remove_dir(out.join("parts"));
            Ok(Some(files))
        }
        Err(e) => match lightdir::LightDir::open(&dir) {
            Ok(d) if d.sidecar.lights.len() == scene.lights.len() => Ok(Some(frame_files(&dir)?)),
            _ => Err(e),
        },
    }
}

/// The files of the light folder `dir` (one frame's, `OUT/frame_NNNN/`)
/// named relative to its parent: its volumes and the sidecar.
pub fn frame_files(dir: &std::path::Path) -> Result<Vec<PathBuf>> {
    let sidecar = lightdir::LightDir::open(dir)?.sidecar;
    let name = PathBuf::from(dir.file_name().expect("a frame folder"));
    let mut files: Vec<PathBuf> = sidecar.files.iter().map(|r| name.join(&r.name)).collect();
    files.push(name.join(lightdir::SIDECAR));
    Ok(files)
}

/// [`simulate`] without printing the summary.
pub fn simulate_quiet(
    args: &Args,
    scene: &Scene,
    medium: &Medium,
    backend: &Backend,
) -> Result<Vec<LightVolume>> {
    let quiet = Args {
        quiet: true,
        ..args.clone()
    };
    simulate(&quiet, scene, medium, backend)
}

/// Simulate every light of `scene` (built as `medium`), write the volumes
/// and the sidecar to `args.output`, print the summary. Returns the light
/// volumes (of either method). The wavefront runs on `backend`.
pub fn simulate(
    args: &Args,
    scene: &Scene,
    medium: &Medium,
    backend: &Backend,
) -> Result<Vec<LightVolume>> {
    simulate_in(args, scene, medium, backend, None)
}

/// [`simulate`] with the scene's `regions` already cleared of the medium
/// (`Regions::clear_of`), where given: a medium of the surfaces alone
/// whose boundary indicator was released.
fn simulate_in<'a>(
    args: &Args,
    scene: &'a Scene,
    medium: &'a Medium,
    backend: &'a Backend,
    regions: Option<eikon_grid::Regions<'a>>,
) -> Result<Vec<LightVolume>> {
    // The emitted patch size settled for the interfaces, as the run records it.
    let mut opts = args
        .options()?
        .settled(scene.grid.interfaces == eikon_grid::Interfaces::Sharp);
    // What the run holds besides patches and GPU buffers.
    let held = crate::grid::Needs {
        light_only: !medium.has_render_properties(),
        surfaces_only: !medium.has_voxel_fields(),
        light_volumes: true,
        counters: true,
        // (Sharp interfaces on the CPU know both sides exactly.)
        interfaces: opts.fresnel && medium.has_voxel_fields(),
        photons: args.method == SimMethod::Photons,
        ..crate::grid::Needs::default()
    };
    // The patch list at its cap is part of the memory the run needs: the
    // default cap is lowered to what fits, a cap the user gave is checked.
    if args.method == SimMethod::Wavefront && args.max_patches.is_none() {
        let fit = crate::grid::patches_that_fit(scene, opts.max_patches, &held);
        if fit < opts.max_patches {
            if !args.quiet {
                eprintln!(
                    "note: at most {fit} patches fit the memory limit (--max-memory, else what is available); fewer splits may be granted"
                );
            }
            opts.max_patches = fit;
            opts.check()?;
        }
    }
    let estimate = crate::grid::check_memory(
        scene,
        &crate::grid::Needs {
            patches: (args.method == SimMethod::Wavefront).then_some(opts.max_patches),
            gpu: (args.method == SimMethod::Wavefront)
                .then(|| {
                    backend.simulator_host_bytes(
                        scene.grid.geometry.dims,
                        scene.channels(),
                        &opts,
                        scene.grid.interfaces == eikon_grid::Interfaces::Sharp,
                    )
                })
                .flatten(),
            ..held
        },
    )?;
    check_scene(scene, medium, &opts)?;
    if args.output.exists() && !args.output.is_dir() {
        bail!("{}: exists and is not a directory", args.output.display());
    }
    crate::backend::announce();
    let started = Instant::now();
    // Photons run on the CPU whatever the backend.
    let on = match args.method {
        SimMethod::Wavefront => backend,
        SimMethod::Photons => &Backend::Cpu,
    };
    let sim = on.simulator(medium, scene, regions)?;
    let photon_regions = (args.method == SimMethod::Photons
        && scene.grid.interfaces == eikon_grid::Interfaces::Sharp)
        .then(|| eikon_grid::Regions::new(scene).clear_of(medium));
    let sim_backend = on.describe();
    let mut results: Vec<(LightVolume, Summary, f64)> = Vec::new();
    for (i, light) in scene.lights.iter().enumerate() {
        let bar = indicatif::ProgressBar::new_spinner();
        bar.set_style(
            indicatif::ProgressStyle::with_template("{spinner} light {prefix}: {msg} ({elapsed})")
                .expect("valid template"),
        );
        bar.set_prefix(format!("{i}/{}", scene.lights.len()));
        let t = Instant::now();
        let (volume, summary) = match args.method {
            SimMethod::Wavefront => {
                let crossing = eikon_wavefront::crossing_steps(light, medium, &opts);
                let progress = |step: usize, live: usize| {
                    bar.set_message(format!(
                        "step {step} of ~{crossing}, {live} live patches, {}",
                        eta(t.elapsed().as_secs_f64(), step, crossing)
                    ));
                    bar.tick();
                };
                sim.simulate(light, &opts, &progress)
            }
            SimMethod::Photons => {
                bar.set_message(format!("tracing {} photons", args.count));
                bar.enable_steady_tick(std::time::Duration::from_millis(200));
                simulate_photons_in(
                    light,
                    medium,
                    photon_regions.as_ref(),
                    args.count,
                    args.seed,
                    &opts,
                )
            }
        }
        .map_err(|e| located(scene, i, e))?;
        bar.finish_and_clear();
        if let Some(w) = trapped_warning(i, &summary) {
            eprintln!("{w}");
        }
        results.push((volume, summary, t.elapsed().as_secs_f64()));
    }
    let wall = started.elapsed().as_secs_f64();

    // One run into the folder, its sidecar last, with the run id and every
    // file's size and checksum that the readers verify (lightdir's docs).
    let run = Run {
        scene: args.scene.display().to_string(),
        method: match args.method {
            SimMethod::Wavefront => "wavefront",
            SimMethod::Photons => "photons",
        }
        .into(),
        options: RunOptions {
            step_voxels: opts.step,
            integrator: format!("{:?}", opts.integrator),
            patch_size_voxels: opts
                .emitted_size(scene.grid.interfaces == eikon_grid::Interfaces::Sharp),
            split_voxels: opts.split,
            threshold: opts.threshold,
            deposit: match opts.deposit {
                DepositRule::Fluence => "fluence",
                DepositRule::Paper => "paper",
            }
            .into(),
            fresnel: opts.fresnel,
            // Traced at sharp interfaces only.
            reflections: opts.fresnel
                && opts.reflections
                && scene.grid.interfaces == eikon_grid::Interfaces::Sharp,
            // The CPU's wavefront with the fluence deposit takes them.
            runs: opts.runs
                && args.method == SimMethod::Wavefront
                && opts.deposit == DepositRule::Fluence
                && matches!(on, Backend::Cpu),
            photons: (args.method == SimMethod::Photons).then_some(args.count),
            seed: (args.method == SimMethod::Photons).then_some(args.seed),
        },
        backend: sim_backend.clone(),
        seconds: wall,
        lights: results
            .iter()
            .zip(&scene.lights)
            .map(|((volume, summary, secs), light)| {
                (light, volume, LightSummary::new(summary, *secs))
            })
            .collect(),
    };
    let sidecar = lightdir::write(&args.output, &medium.geometry, &run)?;
    if args.quiet {
    } else if args.json {
        let summaries: Vec<Value> = results
            .iter()
            .map(|(_, s, secs)| summary_json(s, *secs))
            .collect();
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({
                "output": args.output.display().to_string(),
                "run_id": sidecar.run_id,
                "backend": sim_backend,
                "lights": summaries,
                "seconds": wall,
                "memory": {
                    "estimate_bytes": estimate as u64,
                    "peak_resident_bytes": crate::grid::peak_resident(),
                },
            }))?
        );
    } else {
        for (i, (_, s, secs)) in results.iter().enumerate() {
            print_summary(i, s, *secs);
        }
        println!(
            "wrote {} light volume(s) to {} in {wall:.2} s",
            results.len(),
            args.output.display()
        );
    }
    Ok(results.into_iter().map(|(v, _, _)| v).collect())
}
