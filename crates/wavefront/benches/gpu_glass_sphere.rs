//! Times the 128^3 glass-sphere scene (configs/glass-sphere.toml) on the
//! GPU (without the medium upload) and on the CPU, with either deposit, and
//! prints how far apart their volumes are:
//! `cargo bench -p eikon-wavefront --bench gpu_glass_sphere`. Without a GPU
//! adapter it says so and times nothing.
//!
//! Figures, with the machine, are in docs/PERFORMANCE.md ("GPU backend").

use eikon_gpu::Gpu;
use eikon_grid::{Medium, Scene};
use eikon_testkit::metrics::agreement;
use eikon_wavefront::gpu::GpuSimulator;
use eikon_wavefront::{DepositRule, Options};
use std::time::Instant;

fn main() {
    let gpu = match Gpu::new() {
        Ok(g) => g,
        Err(e) => {
            eprintln!("no GPU adapter, nothing timed: {e}");
            return;
        }
    };
    println!("adapter: {}", gpu.describe());
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../configs/glass-sphere.toml"
    );
    let scene = Scene::load(std::path::Path::new(path)).expect("the scene");
    let m = Medium::build(&scene).expect("the medium");
    let t = Instant::now();
    let sim = GpuSimulator::new(&gpu, &m).expect("the upload");
    println!("upload: {:.2} s", t.elapsed().as_secs_f64());
    let paper = Options {
        deposit: DepositRule::Paper,
        fresnel: false,
        ..Options::default()
    };
    for opts in [Options::default(), paper] {
        let t = Instant::now();
        let (gv, gs) = sim
            .simulate(&scene.lights[0], &opts, &|_, _| {})
            .expect("the GPU simulation");
        let gpu_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let (cv, cs) = eikon_wavefront::simulate_light(&scene.lights[0], &m, &opts, &|_, _| {})
            .expect("the CPU simulation");
        let cpu_s = t.elapsed().as_secs_f64();
        println!(
            "128^3 ({:?}): GPU {gpu_s:.2} s ({} steps, peak {} patches), CPU {cpu_s:.2} s ({} steps, peak {}); {:?}",
            opts.deposit,
            gs.steps,
            gs.peak_patches,
            cs.steps,
            cs.peak_patches,
            agreement(&cv, &gv)
        );
    }
}
