//! The GPU backend against the CPU one. These tests need a Vulkan, Metal
//! or DX12 adapter: CI installs Mesa's lavapipe and sets `CI` and
//! `WGPU_BACKEND=vulkan`, and there a missing adapter fails the test
//! instead of skipping it.

use eikon_gpu::Gpu;
use eikon_wavefront::gpu::GpuHistoPyramid;
use eikon_wavefront::HistoPyramid;

fn gpu() -> Option<Gpu> {
    match Gpu::new() {
        Ok(g) => {
            println!("adapter: {}", g.describe());
            if std::env::var("WGPU_BACKEND").is_ok_and(|b| b.eq_ignore_ascii_case("vulkan")) {
                assert_eq!(g.info.backend, wgpu::Backend::Vulkan, "{}", g.describe());
            }
            Some(g)
        }
        Err(e) => {
            assert!(
                std::env::var_os("CI").is_none(),
                "CI must have a GPU adapter (lavapipe): {e}"
            );
            eprintln!("skipped (no GPU adapter here): {e}");
            None
        }
    }
}

/// A seeded xorshift, so the cases are the same on every run.
fn counts(n: usize, seed: u64, mix: [u32; 3]) -> Vec<u8> {
    let mut s = seed.max(1);
    (0..n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let r = (s % (mix[0] + mix[1] + mix[2]) as u64) as u32;
            if r < mix[0] {
                0
            } else if r < mix[0] + mix[1] {
                1
            } else {
                4
            }
        })
        .collect()
}

#[test]
fn gpu_histopyramid_equals_the_cpu_one() {
    let Some(gpu) = gpu() else { return };
    let hp = GpuHistoPyramid::new(&gpu).unwrap();
    let mut cpu = HistoPyramid::new();
    let mut cases: Vec<Vec<u8>> = vec![
        vec![],
        vec![0],
        vec![4],
        vec![0; 1000],
        vec![4; 4097],
        vec![1; 65],
    ];
    for (i, n) in [
        1usize, 3, 5, 17, 63, 64, 65, 255, 1023, 4099, 100_003, 1_000_001,
    ]
    .into_iter()
    .enumerate()
    {
        cases.push(counts(n, 7 + i as u64, [1, 5, 1]));
        cases.push(counts(n, 99 + i as u64, [3, 1, 3]));
    }
    let mut slots = 0;
    for c in &cases {
        cpu.build(c);
        let (mut src, mut part) = (Vec::new(), Vec::new());
        cpu.expand_into(&mut src, &mut part);
        let (gsrc, gpart) = hp.compact_expand(c).unwrap();
        assert_eq!(gsrc.len(), src.len(), "{} counts", c.len());
        assert!(gsrc == src, "sources differ for {} counts", c.len());
        assert!(gpart == part, "parts differ for {} counts", c.len());
        slots += src.len();
    }
    println!("{} cases, {slots} output slots: GPU == CPU", cases.len());
}

// ---------------------------------------------------------------------
// The light simulator on the GPU.

use eikon_grid::{Medium, Scene};
use eikon_wavefront::{LightVolume, Options, Summary};
use glam::DVec3;
use std::f64::consts::PI;

fn medium(text: &str) -> (Scene, Medium) {
    let scene = Scene::parse(text, "test").unwrap();
    let m = Medium::build(&scene).unwrap();
    (scene, m)
}

fn run_gpu(gpu: &Gpu, scene: &Scene, m: &Medium, light: usize) -> (LightVolume, Summary) {
    let t = std::time::Instant::now();
    let out = eikon_wavefront::gpu::simulate_light(
        gpu,
        &scene.lights[light],
        m,
        &Options::default(),
        &|_, _| {},
    )
    .unwrap();
    println!("GPU: {:.2} s, {:?}", t.elapsed().as_secs_f64(), out.1);
    out
}

fn run_cpu(scene: &Scene, m: &Medium, light: usize) -> (LightVolume, Summary) {
    let t = std::time::Instant::now();
    let out =
        eikon_wavefront::simulate_light(&scene.lights[light], m, &Options::default(), &|_, _| {})
            .unwrap();
    println!("CPU: {:.2} s, {:?}", t.elapsed().as_secs_f64(), out.1);
    out
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn glass_sphere(res: usize) -> String {
    format!(
        r#"
[grid]
resolution = {res}
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
shape = {{ type = "sphere", center = [0.02, 0.1, -0.01], radius = 0.5 }}
index = 1.5
extinction = [0.3, 0.6, 0.9]
albedo = [0.5, 0.5, 0.5]

[[light]]
type = "directional"
direction = [0.2, -1.0, 0.1]
power = [1, 1, 1]

[[light]]
type = "point"
position = [0.7, 0.8, -0.6]
power = [5, 5, 5]

[[light]]
type = "spot"
position = [-1.5, 0.3, 0.2]
direction = [1, -0.2, 0]
angle = 30
falloff = 5
power = [20, 10, 5]
"#
    )
}

#[test]
fn gpu_smoke() {
    let Some(gpu) = gpu() else { return };
    let (scene, m) = medium(&glass_sphere(32));
    let (gv, gs) = run_gpu(&gpu, &scene, &m, 0);
    let (cv, cs) = run_cpu(&scene, &m, 0);
    println!(
        "imbalance gpu {} cpu {}",
        gs.energy_imbalance(),
        cs.energy_imbalance()
    );
    let lit = cv.irradiance.iter().filter(|&&e| e > 0.0).count();
    let glit = gv.irradiance.iter().filter(|&&e| e > 0.0).count();
    println!("lit cpu {lit} gpu {glit}");
}
