//! Ray steps per second on one core through a 128^3 voxelized Luneburg lens.
//!
//! `cargo bench --bench ray_steps`. The throughput criterion prints is in
//! steps ("elem/s"): every ray of a fixed fan is traced from bounds to
//! bounds with `trace`, so the figure includes trilinear sampling of n and
//! grad n, the integrator, and the exit test, exactly as users run it.

use criterion::{black_box, criterion_group, criterion_main, Criterion, Throughput};
use eikon_grid::{trace, trace_many, Form, Integrator, Medium, Scene, TraceOptions};
use glam::DVec3;

#[path = "common/ray_steps_workload.rs"]
mod workload;
use workload::{origins, SCENE};

fn bench(c: &mut Criterion) {
    let scene = Scene::parse(SCENE, "bench").expect("scene");
    let medium = Medium::build(&scene).expect("medium");
    let field = medium.field(0);
    let geom = &scene.grid.geometry;
    // A 16 x 16 fan of parallel rays across the lens.
    let origins = origins();
    let mut group = c.benchmark_group("ray_steps_128");
    for method in [Integrator::Euler, Integrator::Rk4] {
        let opts = TraceOptions::in_voxels(geom, Form::EqualDistance, method, 0.5);
        let steps: usize = origins
            .iter()
            .map(|&o| trace(&field, geom, o, DVec3::Z, &opts).steps)
            .sum();
        group.throughput(Throughput::Elements(steps as u64));
        group.bench_function(format!("{method:?}/one-by-one"), |b| {
            b.iter(|| {
                let mut total = 0usize;
                for &o in &origins {
                    total += trace(&field, geom, black_box(o), DVec3::Z, &opts).steps;
                }
                black_box(total)
            })
        });
        let rays: Vec<(DVec3, DVec3)> = origins.iter().map(|&o| (o, DVec3::Z)).collect();
        group.bench_function(format!("{method:?}/trace_many"), |b| {
            b.iter(|| {
                let ends = trace_many(&field, geom, black_box(&rays), &opts);
                black_box(ends.iter().map(|e| e.steps).sum::<usize>())
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
