//! View renderer frame time: `cargo bench --bench render`.
//!
//! An 800x600 frame of the glass sphere of `configs/glass-sphere.toml`
//! (128^3, one directional light, the receiver plane) from a fixed camera,
//! lit by its simulated light volume (simulated once, before timing), with
//! and without empty-space skipping. The target is <= 0.25 s per
//! frame on the 2-core development machine (docs/PERFORMANCE.md).

use criterion::{criterion_group, criterion_main, Criterion};
use eikon_grid::{Medium, Scene};
use eikon_optics::Camera;
use eikon_view::background::load_environment;
use eikon_view::{Options, Renderer, Surroundings};
use eikon_wavefront::simulate_light;
use glam::DVec3;
use std::path::Path;

fn bench(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/glass-sphere.toml");
    let text = std::fs::read_to_string(&path).expect("glass-sphere.toml");
    let scene = Scene::parse(&text, "glass-sphere.toml").expect("scene");
    let medium = Medium::build(&scene).expect("medium");
    let volume = simulate_light(
        &scene.lights[0],
        &medium,
        &eikon_wavefront::Options::default(),
        &|_, _| {},
    )
    .expect("light volume")
    .0;
    let volumes = [volume];
    let env = load_environment(&scene.background).expect("environment");
    let surroundings = Surroundings::new(&scene, env, &volumes, &medium.geometry);
    let camera = Camera::new(
        DVec3::new(0.0, 1.0, 3.2),
        DVec3::new(0.0, -0.2, 0.0),
        DVec3::Y,
        40.0,
        800,
        600,
        1,
    )
    .expect("camera");
    let mut group = c.benchmark_group("render_glass_sphere_800x600");
    group.sample_size(10);
    for skip in [true, false] {
        let opts = Options {
            skip_empty: skip,
            ..Options::default()
        };
        let renderer = Renderer::new(&medium, &volumes, &surroundings, &camera, opts);
        let name = if skip {
            "skip_empty"
        } else {
            "march_everywhere"
        };
        group.bench_function(name, |b| b.iter(|| renderer.render(&|_, _| {})));
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
