//! Walter 2009 / Holzschuch 2015 benchmarks:
//!
//! * `prune/*`: refracted connections to 32 (V, L) pairs on Walter's
//!   9680-triangle bumpy sphere, through the position-normal tree versus
//!   every triangle (the paper reports 32x for its pool scene).
//! * `connection/tree`: one connection (tree query plus solves).
//! * `equal_error/*`: a 12x12 render of a smooth sphere by Walter point
//!   sampling and by Holzschuch's per-triangle integration, each at the
//!   sample count that first reaches 1% relative L1 against a Holzschuch
//!   K = 16 reference (the sweep is printed before the timings).

use criterion::{criterion_group, criterion_main, Criterion};
use eikon_exact::single::{self, MeshLight, MeshMedium, Method};
use eikon_exact::walter::{self, Mode, Options, PnTree};
use eikon_mesh::{icosphere, BumpySphere};
use eikon_optics::{Camera, Image};
use glam::DVec3;
use std::hint::black_box;
use std::time::Instant;

fn pairs(bumpy: &BumpySphere, n: usize) -> Vec<(DVec3, DVec3)> {
    let mut rng = eikon_rng::SplitMix64::new(12345);
    (0..n)
        .map(|_| {
            let dv = DVec3::from(rng.direction());
            let v = dv * bumpy.radius_at(dv) * (0.2 + 0.7 * rng.unit());
            let l = DVec3::from(rng.direction()) * (2.0 + 2.0 * rng.unit());
            (v, l)
        })
        .collect()
}

fn prune(c: &mut Criterion) {
    let bumpy = BumpySphere::new(1.0, 0.15, 12, 7).unwrap();
    let mesh = bumpy.mesh(22).unwrap();
    let tree = PnTree::new(walter::mesh_triangles(&mesh));
    let ps = pairs(&bumpy, 32);
    let opts = Options::new(Mode::Heuristic);
    let mut scratch = Vec::new();
    let mut kept = 0;
    let mut found = 0;
    for &(v, l) in &ps {
        found += walter::solve_mesh(&tree, v, l, 1.5, &opts, &mut scratch)
            .0
            .len();
        kept += scratch.len();
    }
    println!(
        "bumpy sphere {} triangles, 32 pairs: tree keeps {kept} of {} ({:.2}%), {found} paths",
        tree.triangles().len(),
        32 * tree.triangles().len(),
        100.0 * kept as f64 / (32 * tree.triangles().len()) as f64
    );
    let mut g = c.benchmark_group("prune");
    g.sample_size(10);
    g.bench_function("tree", |b| {
        b.iter(|| {
            let mut n = 0;
            for &(v, l) in &ps {
                n += walter::solve_mesh(&tree, v, l, 1.5, &opts, &mut scratch)
                    .0
                    .len();
            }
            black_box(n)
        })
    });
    g.bench_function("tree_query_only", |b| {
        b.iter(|| {
            let mut n = 0;
            for &(v, l) in &ps {
                scratch.clear();
                tree.query_point(v, l, 1.5, &mut scratch);
                n += scratch.len();
            }
            black_box(n)
        })
    });
    g.bench_function("all_triangles", |b| {
        b.iter(|| {
            let mut n = 0;
            for &(v, l) in &ps {
                for t in tree.triangles() {
                    n += walter::solve_with(t, v, l, 1.5, &opts).0.len();
                }
            }
            black_box(n)
        })
    });
    g.finish();
    let (v, l) = ps[0];
    c.bench_function("connection/tree", |b| {
        b.iter(|| {
            black_box(
                walter::solve_mesh(&tree, v, l, 1.5, &opts, &mut scratch)
                    .0
                    .len(),
            )
        })
    });
}

fn rel_l1(a: &Image, b: &Image) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (x, y) in a.data.iter().zip(&b.data) {
        for c in 0..3 {
            num += f64::from((x[c] - y[c]).abs());
            den += f64::from(y[c].abs());
        }
    }
    num / den
}

fn equal_error(c: &mut Criterion) {
    let bumpy = BumpySphere::new(1.0, 0.1, 12, 7).unwrap();
    let medium = MeshMedium::new(
        bumpy.mesh(10).unwrap(),
        1.33,
        DVec3::new(0.6, 0.8, 1.0),
        DVec3::splat(0.9),
        0.3,
    )
    .unwrap();
    let _ = icosphere;
    let lights = [MeshLight::Point {
        position: DVec3::new(2.5, 3.0, 1.5),
        power: DVec3::splat(100.0),
    }];
    let cam = Camera::new(
        DVec3::new(0.0, 0.0, 4.0),
        DVec3::ZERO,
        DVec3::Y,
        35.0,
        12,
        12,
        1,
    )
    .unwrap();
    let bg = |_: DVec3| DVec3::ZERO;
    let quiet = |_: usize, _: usize| {};
    let run = |m: Method| {
        let t = Instant::now();
        let img = single::render(&medium, &lights, &cam, &bg, m, &quiet).0;
        (img, t.elapsed().as_secs_f64())
    };
    let (reference, tr) = run(Method::Holzschuch { samples: 16 });
    println!("reference Holzschuch K=16: {tr:.2}s");
    let target = 0.01;
    let mut walter_n = None;
    for n in [4, 8, 16, 32, 64, 128, 256] {
        let (img, t) = run(Method::Walter { samples: n });
        let e = rel_l1(&img, &reference);
        println!("Walter N={n}: rel L1 {e:.4}, {t:.3}s");
        if e < target && walter_n.is_none() {
            walter_n = Some(n);
        }
    }
    let mut holz_k = None;
    for k in [1, 2, 4, 8] {
        let (img, t) = run(Method::Holzschuch { samples: k });
        let e = rel_l1(&img, &reference);
        println!("Holzschuch K={k}: rel L1 {e:.4}, {t:.3}s");
        if e < target && holz_k.is_none() {
            holz_k = Some(k);
        }
    }
    println!("1% relative L1: Walter N = {walter_n:?}, Holzschuch K = {holz_k:?}");
    let mut g = c.benchmark_group("equal_error");
    g.sample_size(10);
    if let Some(n) = walter_n {
        g.bench_function(format!("walter_N{n}"), |b| {
            b.iter(|| {
                black_box(single::render(
                    &medium,
                    &lights,
                    &cam,
                    &bg,
                    Method::Walter { samples: n },
                    &quiet,
                ))
            })
        });
    }
    if let Some(k) = holz_k {
        g.bench_function(format!("holzschuch_K{k}"), |b| {
            b.iter(|| {
                black_box(single::render(
                    &medium,
                    &lights,
                    &cam,
                    &bg,
                    Method::Holzschuch { samples: k },
                    &quiet,
                ))
            })
        });
    }
    g.finish();
}

criterion_group!(benches, prune, equal_error);
criterion_main!(benches);
