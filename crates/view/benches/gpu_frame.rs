//! Times the 800x600 frame of `configs/glass-sphere.toml` (128^3, its light
//! volume, 2 samples per pixel) on the GPU and on the CPU, and prints how
//! far apart the images are: `cargo bench -p eikon-view --bench
//! gpu_frame`. Without a GPU adapter it says so and times nothing.
//!
//! Figures, with the machine, are in docs/PERFORMANCE.md ("GPU backend").

use eikon_gpu::Gpu;
use eikon_grid::{Medium, Scene};
use eikon_testkit::metrics::psnr;
use eikon_view::background::load_environment;
use eikon_view::gpu::GpuRenderer;
use eikon_view::render::camera_settings;
use eikon_view::{Options, Renderer, Surroundings};
use std::time::Instant;

fn main() {
    let gpu = match Gpu::new() {
        Ok(g) => g,
        Err(e) => {
            eprintln!("no GPU adapter, nothing timed: {e}");
            return;
        }
    };
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../configs/glass-sphere.toml"
    );
    let scene = Scene::load(std::path::Path::new(path)).expect("the scene");
    let medium = Medium::build(&scene).expect("the medium");
    let volumes: Vec<_> = scene
        .lights
        .iter()
        .map(|l| {
            eikon_wavefront::simulate_light(l, &medium, &Default::default(), &|_, _| {})
                .expect("the light volume")
                .0
        })
        .collect();
    let env = load_environment(&scene.background).expect("the background");
    let s = Surroundings::new(&scene, env, &volumes, &medium.geometry);
    let cam = eikon_view::render::camera(&camera_settings(&scene)).expect("the camera");
    let opts = Options::default();
    let r = GpuRenderer::new(&gpu, &medium, &volumes, &s, &cam, opts).expect("the upload");
    let g = r.render().expect("a GPU frame");
    let gpu_s = r.time_frames(3).expect("GPU frames");
    let t = Instant::now();
    let (cpu, _) = Renderer::new(&medium, &volumes, &s, &cam, opts).render(&|_, _| {});
    let cpu_s = t.elapsed().as_secs_f64();
    println!(
        "glass sphere {}x{} x{} spp: GPU {gpu_s:.3} s/frame ({}), CPU {cpu_s:.3} s/frame ({} threads); PSNR {:.1} dB",
        cam.width(),
        cam.height(),
        cam.samples(),
        gpu.describe(),
        rayon::current_num_threads(),
        psnr(&cpu, &g)
    );
}
