//! Light simulation wall time: `cargo bench --bench simulate`.
//!
//! The glass sphere of `configs/glass-sphere.toml` (n = 1.5 over a ground
//! plane, one directional light) at 64^3 and at the 128^3 of the file,
//! whole `simulate_light` runs on all cores. The target is <= 1.0 s
//! at 128^3 on the 2-core development machine (docs/PERFORMANCE.md).

use criterion::{criterion_group, criterion_main, Criterion};
use eikon_grid::{Medium, Scene};
use eikon_wavefront::{simulate_light, Options};
use std::path::Path;

fn bench(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/glass-sphere.toml");
    let text = std::fs::read_to_string(&path).expect("glass-sphere.toml");
    let mut group = c.benchmark_group("simulate_glass_sphere");
    group.sample_size(10);
    for res in [64, 128] {
        let scene = Scene::parse(
            &text.replace("resolution = 128", &format!("resolution = {res}")),
            "glass-sphere.toml",
        )
        .expect("scene");
        let medium = Medium::build(&scene).expect("medium");
        group.bench_function(format!("{res}^3"), |b| {
            b.iter(|| simulate_light(&scene.lights[0], &medium, &Options::default(), &|_, _| {}))
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
