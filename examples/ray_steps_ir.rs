//! The `ray_steps` bench's workload once, for instruction counts:
//! `valgrind --tool=callgrind --collect-atstart=no --toggle-collect='*fan*'
//! target/release/examples/ray_steps_ir euler one` counts what a step costs
//! (Ir / steps, the steps printed), the same on every run of a binary,
//! whatever else the machine does. Wall-clock figures come from
//! `cargo bench --bench ray_steps`.
//!
//! Arguments: `euler|rk4` and `one|many` (one ray at a time with `trace`,
//! or eight lanes with `trace_many`); optional repetitions (default 2).

use eikon_grid::{trace, trace_many, Form, Integrator, Medium, Scene, TraceOptions};
use glam::DVec3;

/// The bench's scene: a 128^3 voxelized Luneburg lens.
#[path = "../benches/common/ray_steps_workload.rs"]
mod workload;
use workload::{origins, SCENE};

#[inline(never)]
fn fan_one(
    field: &eikon_grid::VoxelField<'_>,
    g: &eikon_grid::GridGeometry,
    o: &[DVec3],
    t: &TraceOptions,
) -> usize {
    o.iter()
        .map(|&x| trace(field, g, x, DVec3::Z, t).steps)
        .sum()
}

#[inline(never)]
fn fan_many(
    field: &eikon_grid::VoxelField<'_>,
    g: &eikon_grid::GridGeometry,
    rays: &[(DVec3, DVec3)],
    t: &TraceOptions,
) -> usize {
    trace_many(field, g, rays, t).iter().map(|e| e.steps).sum()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let method = match args.get(1).map(String::as_str) {
        Some("rk4") => Integrator::Rk4,
        _ => Integrator::Euler,
    };
    let many = args.get(2).map(String::as_str) == Some("many");
    let reps: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(2);
    let scene = Scene::parse(SCENE, "ray_steps_ir").expect("scene");
    let medium = Medium::build(&scene).expect("medium");
    let field = medium.field(0);
    let g = &scene.grid.geometry;
    let origins = origins();
    let rays: Vec<(DVec3, DVec3)> = origins.iter().map(|&o| (o, DVec3::Z)).collect();
    let opts = TraceOptions::in_voxels(g, Form::EqualDistance, method, 0.5);
    let t = std::time::Instant::now();
    let mut steps = 0;
    for _ in 0..reps {
        steps += if many {
            fan_many(&field, g, &rays, &opts)
        } else {
            fan_one(&field, g, &origins, &opts)
        };
    }
    let s = t.elapsed().as_secs_f64();
    println!(
        "{steps} steps in {s:.4} s: {:.1} M steps/s",
        steps as f64 / s / 1e6
    );
}
