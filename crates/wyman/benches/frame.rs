//! Frame time of Wyman's image-space method against the eikonal renderer,
//! in one run: `configs/glass-sphere.toml` ([Ihrke07 fig 7]), 800x600
//! at one sample per pixel (the camera of the scene).
//!
//! ```sh
//! WGPU_BACKEND=vulkan cargo bench -p eikon-wyman --bench frame
//! ```
//!
//! * wyman: the whole frame (caustic and shadow map of the light: four
//!   render passes at `photons`^2; the eye's three passes at 800x600; one
//!   readback; the CPU's shading), and the eye's part alone (caustic maps
//!   kept, as the paper does while the light and object stand still);
//! * eikonal on the CPU backend and on the GPU backend (the same adapter),
//!   lit by one light simulation on the CPU (untimed), at `EIKON_RESOLUTION`
//!   voxels (default 128).
//!
//! Medians of `EIKON_RUNS` frames (default 5; 3 for the eikonal renderer
//! on a software adapter, whose frames take tens of seconds) after one
//! untimed warm-up frame; pipelines, the mesh and the medium are built
//! before timing.

use eikon_grid::{Medium, Scene};
use eikon_view::{Options, Renderer, Surroundings};
use eikon_wyman::{Raster, Settings};
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn env(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() {
    let runs = env("EIKON_RUNS", 5).max(1);
    let resolution = env("EIKON_RESOLUTION", 128);
    let text = include_str!("../../../configs/glass-sphere.toml")
        .replace("resolution = 128", &format!("resolution = {resolution}"));
    let scene = Scene::parse(&text, "configs/glass-sphere.toml").expect("the scene");
    let mut cs = eikon_view::render::camera_settings(&scene);
    cs.resolution = [800, 600];
    cs.samples = 1;
    let camera = eikon_view::render::camera(&cs).expect("the camera");
    let gpu = eikon_gpu::Gpu::new().expect("a GPU adapter (lavapipe will do)");
    let software = gpu.info.device_type == wgpu::DeviceType::Cpu;
    println!(
        "adapter: {}; CPU: {} threads",
        gpu.describe(),
        rayon::current_num_threads()
    );

    // Wyman: whole frames, then the eye's part with the caustic maps kept.
    let settings = Settings::default();
    let renderer = eikon_wyman::Renderer::new(&gpu, &scene, &settings).expect("the renderer");
    let frame = || renderer.render(&camera).expect("a frame");
    let (_, stats) = frame();
    let mut whole = Vec::new();
    let mut parts = Vec::new();
    for _ in 0..runs {
        let t = Instant::now();
        let (_, s) = frame();
        whole.push(t.elapsed().as_secs_f64());
        parts.push(s);
    }
    let refractor = eikon_wyman::render::check(&scene).expect("a refractor");
    let raster = Raster::new(&gpu, &refractor).expect("pipelines");
    let maps = eikon_wyman::render::caustic_maps(&raster, &scene, &refractor, &settings)
        .expect("caustic maps");
    let eye = median(
        parts
            .iter()
            .map(|s| s.eye_seconds + s.shade_seconds)
            .collect(),
    );
    let np = settings.photons;
    let nc = settings.caustic_map;
    println!(
        "wyman ({} triangles): {} render passes per frame (light: back, front, refraction, splats; eye: back, front, refraction); targets: eye 800x600 x (depth32 + 5 rgba32float), light {np}x{np} x (depth32 + 5 rgba32float), caustic map {nc}x{nc} x 3 x 64-bit sums ({} maps); {:.1} MB read back per frame",
        refractor.mesh.triangle_count(),
        stats.passes,
        maps.len(),
        stats.readback_bytes as f64 / 1e6
    );
    let m = |f: &dyn Fn(&eikon_wyman::Stats) -> f64| median(parts.iter().map(f).collect());
    println!(
        "wyman frame: {:.1} ms (caustic map {:.1} ms, eye passes and readback {:.1} ms, CPU shading {:.1} ms); eye part alone {:.1} ms",
        1e3 * median(whole.clone()),
        1e3 * m(&|s| s.caustic_seconds),
        1e3 * m(&|s| s.eye_seconds),
        1e3 * m(&|s| s.shade_seconds),
        1e3 * eye
    );

    // The eikonal renderer, lit by one light simulation.
    let t = Instant::now();
    let medium = Medium::build(&scene).expect("the medium");
    let (volume, _) = eikon_wavefront::simulate_light(
        &scene.lights[0],
        &medium,
        &eikon_wavefront::Options::default(),
        &|_, _| {},
    )
    .expect("the light simulation");
    println!(
        "eikonal at {resolution}^3: medium and light simulation (CPU, untimed) {:.1} s",
        t.elapsed().as_secs_f64()
    );
    let volumes = [volume];
    let bg = eikon_view::background::load_environment(&scene.background).expect("the sky");
    let surroundings = Surroundings::new(&scene, bg, &volumes, &medium.geometry);
    let cpu = Renderer::new(
        &medium,
        &volumes,
        &surroundings,
        &camera,
        Options::default(),
    );
    cpu.render(&|_, _| {});
    let cpu_frames: Vec<f64> = (0..runs)
        .map(|_| {
            let t = Instant::now();
            cpu.render(&|_, _| {});
            t.elapsed().as_secs_f64()
        })
        .collect();
    println!(
        "eikonal frame, CPU backend: {:.1} ms",
        1e3 * median(cpu_frames)
    );
    let gpu_runs = if software { runs.min(3) } else { runs };
    let g = eikon_view::gpu::GpuRenderer::new(
        &gpu,
        &medium,
        &volumes,
        &surroundings,
        &camera,
        Options::default(),
    )
    .expect("the GPU renderer");
    g.render().expect("a frame");
    let gpu_frames: Vec<f64> = (0..gpu_runs)
        .map(|_| {
            let t = Instant::now();
            g.render().expect("a frame");
            t.elapsed().as_secs_f64()
        })
        .collect();
    println!(
        "eikonal frame, GPU backend ({}): {:.1} ms (median of {gpu_runs})",
        gpu.describe(),
        1e3 * median(gpu_frames)
    );
}
