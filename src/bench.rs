//! `eikon bench`: the standard scenes on every available backend, with
//! light-simulation time, frame time (800x600 unless told) and peak memory.
//!
//! Each (scene, backend) pair runs in a child process of its own
//! (`eikon bench --one ...`), so that its peak resident memory is its own.
//! Times are medians over `--runs` simulations and `--frames` frames after
//! one untimed warm-up frame; building the grid, uploading it to the GPU
//! and compiling kernels are not timed.

use crate::backend::{Backend, BackendArg, BackendFlag};
use anyhow::{bail, Context, Result};
use eikon_grid::{Medium, Scene};
use eikon_view::{Options, Renderer, Surroundings};
use serde_json::{json, Value};
use std::path::PathBuf;
use std::time::Instant;

/// The standard scenes: name and TOML text.
fn standard() -> Vec<(&'static str, String)> {
    let sphere = include_str!("../configs/glass-sphere.toml");
    vec![
        ("glass-sphere-128", sphere.to_string()),
        (
            "glass-sphere-256",
            sphere.replace("resolution = 128", "resolution = 256"),
        ),
        (
            "wine-glass",
            include_str!("../configs/wine-glass.toml").to_string(),
        ),
        (
            "rounded-cube",
            include_str!("../configs/rounded-cube.toml").to_string(),
        ),
        (
            "bumpy-amber-96",
            include_str!("../configs/bumpy-amber.toml").to_string(),
        ),
    ]
}

/// Arguments of `eikon bench`.
#[derive(clap::Args)]
pub struct Args {
    /// Scene files to run instead of the standard scenes (the 128^3 and
    /// 256^3 glass sphere of [Ihrke07 fig 7], the wine glass, the rounded
    /// cube and the bumpy amber at 96^3).
    #[arg(long)]
    scene: Vec<PathBuf>,
    /// Backends to run (default: the CPU, and the GPU when an adapter
    /// exists, software ones included).
    #[arg(long, value_enum, value_delimiter = ',')]
    backends: Vec<BackendArg>,
    /// Simulations per scene and backend (the median is reported).
    #[arg(long, default_value_t = 3)]
    runs: usize,
    /// Frames per scene and backend (the median is reported).
    #[arg(long, default_value_t = 5)]
    frames: u32,
    /// Frame width, pixels.
    #[arg(long, default_value_t = 800)]
    width: u32,
    /// Frame height, pixels.
    #[arg(long, default_value_t = 600)]
    height: u32,
    /// Print the table as JSON.
    #[arg(long)]
    json: bool,
    /// Run one scene on one backend and print its figures as JSON (what
    /// the parent runs in a child process).
    #[arg(long, hide = true)]
    one: Option<String>,
    #[command(flatten)]
    grid: crate::grid::GridFlags,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Peak resident memory of this process, MiB (Linux; `None` elsewhere).
fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

/// The figures of one scene on one backend, in this process.
fn one(name: &str, text: &str, backend: Backend, args: &Args) -> Result<Value> {
    let (runs, frames) = (args.runs, args.frames);
    let scene = Scene::parse_with(text, name, &args.grid.grid_override())?;
    let medium = Medium::build(&scene)?;
    let opts = eikon_wavefront::Options::default();
    eikon_wavefront::check_scene(&scene, &medium, &opts)?;
    let quiet = |_: usize, _: usize| {};
    let mut sims = Vec::new();
    let mut volumes = Vec::new();
    let mut patches = 0;
    // The GPU uploads the medium once, untimed.
    let sim = backend.simulator(&medium, &scene, None)?;
    let bname = backend.name();
    eprintln!("  {name} on {bname}: {}", crate::grid::describe(&scene));
    // Round trips to the GPU per simulation (all lights): the same every run.
    // (submissions, readbacks) so far.
    let traffic = || -> Option<(u64, u64)> {
        match &backend {
            Backend::Cpu => None,
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => {
                let t = g.traffic();
                Some((t.submissions, t.readbacks))
            }
        }
    };
    let mut round_trips = None;
    for run in 0..runs.max(1) {
        let t = Instant::now();
        let before = traffic();
        volumes.clear();
        for l in &scene.lights {
            let (v, s) = sim.simulate(l, &opts, &quiet)?;
            patches = patches.max(s.peak_patches);
            volumes.push(v);
        }
        sims.push(t.elapsed().as_secs_f64());
        if let (Some(a), Some(b)) = (traffic(), before) {
            round_trips = Some((a.0 - b.0, a.1 - b.1));
        }
        eprintln!(
            "  {name} on {bname}: light simulation {}/{}: {:.3} s, {patches} peak patches",
            run + 1,
            runs.max(1),
            t.elapsed().as_secs_f64()
        );
    }
    let mut cs = eikon_view::render::camera_settings(&scene);
    cs.resolution = [args.width, args.height];
    cs.samples = 1;
    let camera = eikon_view::render::camera(&cs)?;
    let env = eikon_view::background::load_environment(&scene.background)?;
    let surroundings = Surroundings::new(&scene, env, &volumes, &medium.geometry);
    let ropts = Options::default();
    let frame = match &backend {
        Backend::Cpu => {
            let mut r = Renderer::new(&medium, &volumes, &surroundings, &camera, ropts);
            if scene.grid.interfaces == eikon_grid::Interfaces::Sharp {
                r = r.sharp(&scene);
            }
            r.render(&quiet);
            median(
                (0..frames.max(1))
                    .map(|i| {
                        let t = Instant::now();
                        r.render(&quiet);
                        let s = t.elapsed().as_secs_f64();
                        frame_done(name, bname, i, frames, s);
                        s
                    })
                    .collect(),
            )
        }
        #[cfg(feature = "gpu")]
        Backend::Gpu(gpu) => {
            let r = eikon_view::gpu::GpuRenderer::with_scene(
                gpu,
                &scene,
                &medium,
                &volumes,
                &surroundings,
                &camera,
                ropts,
            )?;
            r.render()?;
            median(
                (0..frames.max(1))
                    .map(|i| {
                        let s = r.time_frames(1)?;
                        frame_done(name, bname, i, frames, s);
                        Ok(s)
                    })
                    .collect::<Result<Vec<_>, eikon_gpu::GpuError>>()?,
            )
        }
    };
    Ok(json!({
        "scene": name,
        "interfaces": scene.grid.interfaces.name(),
        "dims": medium.geometry.dims,
        "backend": backend.name(),
        "device": backend.describe(),
        "deposit": match opts.deposit {
            eikon_wavefront::DepositRule::Fluence => "fluence",
            eikon_wavefront::DepositRule::Paper => "paper",
        },
        "simulate_seconds": median(sims.clone()),
        "simulate_runs": sims,
        "peak_patches": patches,
        "simulate_submissions": round_trips.map(|t| t.0),
        "simulate_readbacks": round_trips.map(|t| t.1),
        "frame": [args.width, args.height],
        "frame_seconds": frame,
        "frames_per_second": 1.0 / frame,
        "peak_rss_mib": peak_rss_mib(),
    }))
}

/// Say on stderr that frame `i` of `frames` took `seconds`.
fn frame_done(name: &str, backend: &str, i: u32, frames: u32, seconds: f64) {
    eprintln!(
        "  {name} on {backend}: frame {}/{}: {:.1} ms",
        i + 1,
        frames.max(1),
        1e3 * seconds
    );
}

/// Run `eikon bench`.
pub fn run(args: Args) -> Result<()> {
    let scenes: Vec<(String, String)> = if args.scene.is_empty() {
        standard()
            .into_iter()
            .map(|(n, t)| (n.to_string(), t))
            .collect()
    } else {
        args.scene
            .iter()
            .map(|p| {
                let text = std::fs::read_to_string(p)
                    .with_context(|| format!("{}: cannot read the scene", p.display()))?;
                args.grid.parse(&text, &p.display().to_string())?;
                Ok((p.display().to_string(), text))
            })
            .collect::<Result<_>>()?
    };
    if let Some(spec) = &args.one {
        let Some((name, text)) = scenes.iter().find(|(n, _)| n == spec) else {
            bail!("--one: no scene {spec}");
        };
        let backend = BackendFlag {
            backend: Some(args.backends.first().copied().unwrap_or(BackendArg::Cpu)),
        }
        .select(true)?;
        let v = one(name, text, backend, &args)?;
        println!("{}", serde_json::to_string(&v)?);
        return Ok(());
    }
    let backends = if args.backends.is_empty() {
        crate::backend::available()
    } else {
        args.backends.clone()
    };
    let exe = std::env::current_exe().context("finding the eikon executable")?;
    let mut rows = Vec::new();
    for (name, _) in &scenes {
        for b in &backends {
            let bname = match b {
                BackendArg::Cpu => "cpu",
                BackendArg::Gpu => "gpu",
            };
            eprintln!("{name} on {bname} ...");
            let mut cmd = std::process::Command::new(&exe);
            cmd.args(["bench", "--one", name, "--backends", bname]);
            cmd.args(["--runs", &args.runs.to_string()]);
            cmd.args(["--frames", &args.frames.to_string()]);
            cmd.args(["--width", &args.width.to_string()]);
            cmd.args(["--height", &args.height.to_string()]);
            for s in &args.scene {
                cmd.arg("--scene").arg(s);
            }
            if let Some(r) = args.grid.resolution {
                cmd.args(["--resolution", &r.to_string()]);
            }
            if let Some(s) = args.grid.smoothing {
                cmd.args(["--smoothing", &s.to_string()]);
            }
            if let Some(i) = args.grid.interfaces {
                cmd.args(["--interfaces", i.name()]);
            }
            if args.grid.preview {
                cmd.arg("--preview");
            }
            // The child's progress (stderr) shows as it runs; its figures
            // come back on stdout.
            cmd.stderr(std::process::Stdio::inherit());
            let out = cmd.output().context("running a benchmark child")?;
            if !out.status.success() {
                bail!("{name} on {bname} failed (its messages are above)");
            }
            let v: Value = serde_json::from_slice(&out.stdout)
                .with_context(|| format!("{name} on {bname}: unreadable figures"))?;
            rows.push(v);
        }
    }
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({ "runs": rows }))?
        );
        return Ok(());
    }
    let w = rows
        .iter()
        .filter_map(|r| r["scene"].as_str())
        .map(str::len)
        .fold(5, usize::max);
    println!(
        "{:<w$} {:<5} {:<8} {:>12} {:>9} {:>9} {:>12} {:>10} {:>10}  device",
        "scene",
        "",
        "surfaces",
        "simulate s",
        "submits",
        "readbacks",
        "frame ms",
        "fps",
        "peak MiB"
    );
    // Submissions and readbacks per simulation: "-" on the CPU.
    let count = |v: &Value| v.as_u64().map_or("-".to_string(), |n| n.to_string());
    for r in &rows {
        println!(
            "{:<w$} {:<5} {:<8} {:>12.3} {:>9} {:>9} {:>12.2} {:>10.1} {:>10.0}  {}",
            r["scene"].as_str().unwrap_or("?"),
            r["backend"].as_str().unwrap_or("?"),
            r["interfaces"].as_str().unwrap_or("?"),
            r["simulate_seconds"].as_f64().unwrap_or(f64::NAN),
            count(&r["simulate_submissions"]),
            count(&r["simulate_readbacks"]),
            1e3 * r["frame_seconds"].as_f64().unwrap_or(f64::NAN),
            r["frames_per_second"].as_f64().unwrap_or(f64::NAN),
            r["peak_rss_mib"].as_f64().unwrap_or(f64::NAN),
            r["device"].as_str().unwrap_or("?"),
        );
    }
    Ok(())
}
