//! Function-level parity of the sharp interfaces' WGSL (`surface.wgsl`,
//! `region.wgsl`) with the Rust they mirror: the closed-form first crossing
//! and normal of each analytic shape (`Shape::first_crossing`,
//! `Shape::normal`), the owner by priority (`Scene::owner`), each region's
//! index (`Regions::index`) and Snell's law in eikonal form
//! (`region::refract`), on seeded batches at f32 tolerance. They need a
//! Vulkan, Metal or DX12 adapter (lavapipe in CI, where a missing adapter
//! fails them; elsewhere they are reported as ignored).
//!
//! `cargo test --release -p eikon-grid --test wgsl_sharp -- --nocapture`
//! prints the largest errors. The binary's time is llvmpipe compiling the
//! kernels: it skips LLVM's optimisation passes ([`Tests::compile_bound`]),
//! which changed none of the printed errors.

use eikon_gpu::{Gpu, DISPATCH};
use eikon_grid::region::{gpu_regions, refract, GpuRegions, RegionGpu, STEP_WGSL, WGSL as REGION};
use eikon_grid::{Regions, Scene};
use eikon_shader::compose;
use eikon_testkit::parity::{v4, xyz, Cases, IO};
use eikon_testkit::Tests;
use glam::DVec3;

/// Every supported shape, rotated where it has a frame, with the three
/// index profiles, priorities that overlap, in glass.
fn scene() -> Scene {
    Scene::parse(
        r#"
[grid]
resolution = 32
min = [-1.5, -1.5, -1.5]
max = [1.5, 1.5, 1.5]
interfaces = "sharp"

[ambient]
index = 1.1

[[object]]
name = "lens"
shape = { type = "sphere", center = [0.2, -0.1, 0.05], radius = 0.7 }
index = { type = "luneburg" }
priority = 3

[[object]]
name = "slab"
shape = { type = "box", center = [-0.1, 0.2, 0.0], size = [1.6, 0.9, 1.2], rotation = [20, 35, -10] }
index = 1.5
priority = 2

[[object]]
name = "rod"
shape = { type = "cylinder", center = [0.0, 0.0, 0.3], radius = 0.45, height = 1.8, rotation = [60, 0, 25] }
index = { type = "linear", n0 = 1.3, gradient = [0.1, -0.2, 0.05], origin = [0.0, 0.0, 0.0] }
priority = 1

[[object]]
name = "floor"
shape = { type = "half_space", point = [0.0, -0.6, 0.0], normal = [0.1, -1.0, 0.2] }
index = 1.33
"#,
        "wgsl sharp parity",
    )
    .unwrap()
}

/// The shapes without a closed form in `surface.wgsl`'s first part: a
/// rotated rounded box, a solid of revolution (the wine glass of
/// `surface.rs`'s tests), a rotated torus, a rounded and a pinched (star)
/// superquadric, a smooth mesh (bumpy sphere) and a flat one
/// (cuboctahedron), overlapping, with priorities.
fn other_shapes() -> Scene {
    Scene::parse(
        r#"
[grid]
resolution = 32
min = [-1.5, -1.5, -1.5]
max = [1.5, 1.5, 1.5]
interfaces = "sharp"

[ambient]
index = 1.0

[[object]]
name = "cube"
shape = { type = "rounded_box", center = [-0.6, 0.5, 0.1], size = [1.0, 0.7, 0.8], radius = 0.15, rotation = [23, -41, 67] }
index = 1.5
priority = 6

[[object]]
name = "glass"
shape = { type = "revolution", base = [0.5, -0.9, 0.1], rotation = [10, 0, -15], profile = [[0.0, 0.0], [0.4, 0.0], [0.4, 0.03], [0.06, 0.08], [0.05, 0.5], [0.35, 0.7], [0.45, 1.0], [0.42, 1.0], [0.32, 0.73], [0.0, 0.6]] }
index = { type = "linear", n0 = 1.4, gradient = [0.0, 0.1, 0.0], origin = [0.0, 0.0, 0.0] }
priority = 5

[[object]]
name = "ring"
shape = { type = "torus", center = [0.1, 0.0, -0.2], major_radius = 0.6, minor_radius = 0.2, rotation = [50, 10, 30] }
index = 1.33
priority = 4

[[object]]
name = "pebble"
shape = { type = "superquadric", center = [-0.5, -0.6, 0.5], radii = [0.6, 0.4, 0.5], exponents = [0.5, 0.5], rotation = [23, -41, 67] }
index = 1.6
priority = 3

[[object]]
name = "star"
shape = { type = "superquadric", center = [0.6, 0.6, -0.6], radii = [0.6, 0.4, 0.5], exponents = [2.5, 2.5], rotation = [-20, 30, 5] }
index = 1.45
priority = 2

[[object]]
name = "bumpy"
shape = { type = "bumpy_sphere", center = [0.0, 0.1, 0.6], radius = 0.55, amplitude = 0.08, bumps = 6, frequency = 6 }
index = 1.7
priority = 1

[[object]]
name = "gem"
shape = { type = "cuboctahedron", center = [-0.5, 0.2, -0.7], edge = 0.6, rotation = [20, 35, 0] }
index = 2.4
"#,
        "wgsl sharp parity, other shapes",
    )
    .unwrap()
}

/// VDB grids: a solid where the sample glass sphere's index grid exceeds
/// 1.25 with its index read from that grid, overlapping (priority above
/// it) a rotated box whose index is 1 + 0.5 x the grid's value and whose
/// extinction comes from the grid too.
fn vdb_shapes() -> Scene {
    let vdb = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../volumes/glass-sphere-64.vdb"
    );
    Scene::parse(
        &format!(
            r#"
[grid]
resolution = 32
min = [-1.5, -1.5, -1.5]
max = [1.5, 1.5, 1.5]
interfaces = "sharp"

[[object]]
name = "drop"
shape = {{ type = "vdb", file = "{vdb}", grid = "n", threshold = 1.25 }}
index = {{ type = "vdb" }}
priority = 2

[[object]]
name = "haze"
shape = {{ type = "box", center = [0.2, -0.1, 0.1], size = [1.2, 0.9, 1.1], rotation = [20, 35, -10] }}
index = {{ type = "vdb", file = "{vdb}", grid = "n", scale = 0.5 }}
extinction = {{ type = "vdb", file = "{vdb}", grid = "density", scale = [1.0, 2.0, 3.0] }}
priority = 1
"#
        ),
        "wgsl sharp parity, VDB grids",
    )
    .unwrap()
}

const TABLE_HOOKS: &str = "
@group(0) @binding(2) var<storage, read> table: array<RegionGpu>;
@group(0) @binding(3) var<storage, read> shape_data: array<vec4<u32>>;
fn region_count() -> u32 {
    return arrayLength(&table) - 1u;
}
fn region_object(i: u32) -> RegionGpu {
    return table[i];
}
fn surface_data(i: u32) -> vec4<u32> {
    return shape_data[i];
}
";

/// The `region_step` module's hooks: `index_field` reads the profile of
/// region `field_region` (channel 0).
const FIELD_HOOKS: &str = "
const NONE: u32 = 0xffffffffu;
var<private> field_region: u32 = NONE;
fn index_field(p: vec3<f32>) -> vec4<f32> {
    return region_index(field_region, p, 0u);
}
";

/// Run `entry` of `source` over `inputs` (`per_input` outputs each) with
/// the regions' table and shape data bound, as every kernel here reads
/// them.
fn eval_with(
    gpu: &Gpu,
    regions: &GpuRegions,
    (source, entry): (&str, &str),
    inputs: &[[f32; 4]],
    per_input: usize,
) -> Vec<[f32; 4]> {
    let table = gpu.storage("regions", &regions.table);
    let data = gpu.storage("shape data", &regions.data);
    gpu.eval(
        source,
        entry,
        inputs,
        per_input,
        &[table.as_entire_binding(), data.as_entire_binding()],
    )
    .unwrap()
}

/// How closely one shape's WGSL must follow the CPU.
struct Bounds {
    /// A crossing's parameter, in ulps of (scale + t) over the cosine of
    /// incidence.
    t_ulps: f64,
    /// The normal at the crossing (length of the difference).
    normal: f64,
    /// The signed distance at the CPU's crossing, in ulps of the scale.
    distance_ulps: f64,
}

/// The bounds, derived: inputs are exact in f32 and the shapes' data
/// rounded to f32 (relative 6e-8); a crossing's parameter is a root of a
/// line against a surface, its rounding error a few ulps of the scene's
/// scale (3) divided by the cosine of incidence |d . n|; a normal is a
/// normalized f32 vector (a few ulps), the signed distance at the CPU's
/// crossing a few ulps of the scale. That holds for the marched shapes
/// too: the march stops where the f32 distance bound changes sign, and the
/// bound's rounding (a few ulps of the scale) moves that root by a few ulps
/// over the cosine; the solid of revolution's cones are quadratics whose
/// coefficients cancel, but one Newton step on the unexpanded equation
/// brings them back to a few ulps (measured: at most 2 ulps for every
/// shape, where 64 are allowed). The superquadric's normal is a gradient
/// of powers (2/e, e2/e1, each multiplying the relative error of its
/// inputs, up to 4 times for e = 0.5), and a star's (e > 2) turns fast
/// near its pinches, where a crossing a few ulps off has a normal a
/// curvature times that further off: it is held to 1e-4 (measured 5e-5).
fn bounds(shape: &eikon_grid::Shape) -> Bounds {
    let normal = match shape {
        eikon_grid::Shape::Superquadric { .. } => 1e-4,
        _ => 1e-5,
    };
    Bounds {
        t_ulps: 64.0,
        normal,
        distance_ulps: 16.0,
    }
}

/// Input: (o, k), (d, hi), (q, lo): shape k's first crossing of o + d t on
/// (lo, hi] as (t, ok), its normal; at q (the CPU's crossing point) the
/// normal and the signed distance; at o the owner and its index. Returns
/// per shape (kind, crossings compared, max |dt| cos / (scale + t), max
/// normal error).
fn check_surfaces(
    gpu: &Gpu,
    scene: &Scene,
    seed: u64,
    cases_n: usize,
    aim: bool,
) -> Vec<(String, usize, f64, f64)> {
    let main = format!(
        "{IO}{TABLE_HOOKS}
@compute @workgroup_size(WORKGROUP)
fn surfaces(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if 3u * i >= arrayLength(&input) {{
        return;
    }}
    let a = input[3u * i];
    let b = input[3u * i + 1u];
    let c = input[3u * i + 2u];
    let r = region_object(u32(a.w));
    let h = region_shape_crossing(r, a.xyz, b.xyz, c.w, b.w);
    output[4u * i] = vec4<f32>(h.t, f32(h.ok), 0.0, 0.0);
    output[4u * i + 1u] = vec4<f32>(h.normal, 0.0);
    output[4u * i + 2u] = vec4<f32>(region_shape_normal(r, c.xyz), region_shape_distance(r, c.xyz));
    let owner = region_owner(a.xyz);
    output[4u * i + 3u] = vec4<f32>(f32(owner), region_index(owner, a.xyz, 0u).x, 0.0, 0.0);
}}
"
    );
    let source = compose("", &[&DISPATCH, &REGION], &main);
    let regions = Regions::new(scene);
    let gpu_regions = gpu_regions(scene);
    let table: &[RegionGpu] = &gpu_regions.table;
    let count = table.len() - 1;
    let mut r = Cases::new(seed);
    struct Case {
        o: DVec3,
        d: DVec3,
        k: usize,
        lo: f64,
        hi: f64,
        cpu: Option<eikon_grid::Crossing>,
    }
    let cases: Vec<Case> = (0..cases_n)
        .map(|j| {
            let o = r.v(-1.5, 1.5);
            let d = loop {
                let d = r.v(-1.0, 1.0);
                if d.length() > 0.1 && d.length() < 1.0 {
                    break d.normalize();
                }
            };
            let k = j % count;
            let shape = &scene.objects[table[k].object as usize].shape;
            // With `aim`, every other segment heads for a point of the
            // shape's bounding box.
            let d = match shape.aabb() {
                Some((a, b)) if aim && j % 2 == 1 => {
                    let p = a + (b - a) * DVec3::new(r.f(0.0, 1.0), r.f(0.0, 1.0), r.f(0.0, 1.0));
                    (p - o).normalize_or(d)
                }
                _ => d,
            };
            let d = DVec3::new(d.x as f32 as f64, d.y as f32 as f64, d.z as f32 as f64);
            let lo = 1e-3;
            let hi = r.f(0.1, 4.0);
            let cpu = shape.first_crossing(o, d, lo, hi);
            Case {
                o,
                d,
                k,
                lo,
                hi,
                cpu,
            }
        })
        .collect();
    let inputs: Vec<[f32; 4]> = cases
        .iter()
        .flat_map(|c| {
            let q = c.cpu.map_or(c.o, |x| c.o + c.d * x.t);
            [v4(c.o, c.k as f64), v4(c.d, c.hi), v4(q, c.lo)]
        })
        .collect();
    let out = eval_with(gpu, &gpu_regions, (&source, "surfaces"), &inputs, 4);
    const ULP: f64 = 6e-8;
    let scale = 3.0;
    let mut per_shape: Vec<(String, usize, f64, f64)> = table[..count]
        .iter()
        .map(|t| {
            let o = &scene.objects[t.object as usize];
            (format!("{} {}", o.shape.kind(), o.name), 0, 0.0, 0.0)
        })
        .collect();
    let (mut max_t, mut max_n, mut max_q, mut max_dist, mut max_index) =
        (0f64, 0f64, 0f64, 0f64, 0f64);
    let (mut hits, mut excused, mut owners) = (0, 0, 0);
    for (j, c) in cases.iter().enumerate() {
        let o = &out[4 * j..4 * j + 4];
        let shape = &scene.objects[table[c.k].object as usize].shape;
        let b = bounds(shape);
        let gpu_hit = (o[0][1] != 0.0).then_some(o[0][0] as f64);
        // Near-degenerate: a crossing within rounding of either end of the
        // segment, or grazing (cosine below 0.02), may fall either way.
        let near_end = |t: f64| (t - c.lo).abs() < 1e-4 || (t - c.hi).abs() < 1e-4;
        let grazing = |n: DVec3| n.dot(c.d).abs() < 0.02;
        match (c.cpu, gpu_hit) {
            (Some(x), Some(t)) => {
                let cos = x.normal.dot(c.d).abs();
                let tol = b.t_ulps * ULP * (scale + x.t) / cos.max(1e-3);
                if (t - x.t).abs() > tol || (xyz(o[1]) - x.normal).length() > b.normal {
                    assert!(
                        near_end(x.t) || near_end(t) || grazing(x.normal) || grazing(xyz(o[1])),
                        "{} from {} along {}: GPU t {t} normal {}, CPU {x:?}",
                        shape.kind(),
                        c.o,
                        c.d,
                        xyz(o[1])
                    );
                    excused += 1;
                    continue;
                }
                hits += 1;
                let et = (t - x.t).abs() * cos.max(1e-3) / (scale + x.t);
                let en = (xyz(o[1]) - x.normal).length();
                let ps = &mut per_shape[c.k];
                ps.1 += 1;
                ps.2 = ps.2.max(et);
                ps.3 = ps.3.max(en);
                max_t = max_t.max(et);
                max_n = max_n.max(en);
                // At the CPU's crossing point: on the surface, with its
                // normal (a box's edge or a cylinder's rim has two, a
                // mesh's edge its two faces').
                let q = c.o + c.d * x.t;
                let dist = o[2][3] as f64;
                assert!(
                    dist.abs() < b.distance_ulps * ULP * scale,
                    "{}: distance {dist} at {q}",
                    shape.kind()
                );
                max_dist = max_dist.max(dist.abs());
                let nq = shape.normal(q);
                let err = (xyz(o[2]) - nq).length();
                if err < 1e-3 {
                    max_q = max_q.max(err);
                } else {
                    excused += 1;
                }
            }
            (None, None) => {}
            (Some(x), None) => {
                assert!(
                    near_end(x.t) || grazing(x.normal),
                    "{} from {} along {}: GPU none, CPU {x:?}",
                    shape.kind(),
                    c.o,
                    c.d
                );
                excused += 1;
            }
            (None, Some(t)) => {
                assert!(
                    near_end(t) || grazing(xyz(o[1])),
                    "{} from {} along {}: GPU {t}, CPU none",
                    shape.kind(),
                    c.o,
                    c.d
                );
                excused += 1;
            }
        }
        // The owner by priority, away from every surface.
        let near_surface = scene
            .objects
            .iter()
            .any(|ob| ob.shape.distance(c.o).abs() < 1e-5);
        if !near_surface {
            let want = scene.owner(c.o);
            let got = o[3][0] as usize;
            let got = (got < count).then(|| table[got].object as usize);
            assert_eq!(got, want, "owner of {}", c.o);
            owners += 1;
            let n = regions.index(want, c.o, 0).0;
            let err = (o[3][1] as f64 - n).abs();
            assert!(
                err < 8.0 * ULP * n * 4.0,
                "index at {}: {} vs {n}",
                c.o,
                o[3][1]
            );
            max_index = max_index.max(err);
        }
    }
    println!(
        "{hits} crossings compared, {excused} near-degenerate excused, {owners} owners: \
         max |dt| cos / (scale + t) {max_t:.2e}, max normal error {max_n:.2e} (at the CPU's point {max_q:.2e}), \
         max |distance| there {max_dist:.2e}, max index error {max_index:.2e}"
    );
    for (name, n, et, en) in &per_shape {
        println!("  {name}: {n} crossings, max |dt| cos / (scale + t) {et:.2e} ({:.0} ulps), max normal error {en:.2e}", et / ULP);
    }
    assert!(hits > cases_n / 8, "{hits}");
    assert!(excused * 100 < cases.len(), "{excused} excused");
    assert!(max_q < 1e-3);
    per_shape
}

fn surfaces_owner_and_index_match_the_cpu(gpu: &Gpu) {
    let per_shape = check_surfaces(gpu, &scene(), 11, 20000, false);
    for (name, n, et, en) in per_shape {
        assert!(n > 500, "{name}: {n}");
        assert!(et < 64.0 * 6e-8 && en < 1e-5, "{name}");
    }
}

/// The same for the rounded box, solid of revolution, torus,
/// superquadrics and meshes (bounds per shape: [`bounds`]).
fn other_surfaces_owner_and_index_match_the_cpu(gpu: &Gpu) {
    let scene = other_shapes();
    let per_shape = check_surfaces(gpu, &scene, 12, 28000, true);
    for (k, (name, n, et, _)) in per_shape.iter().enumerate() {
        // Each shape is hit by a fair share of its 4000 segments (the
        // star, thin between its pinches, by fewer).
        assert!(*n > 250, "{name} (region {k}): {n} crossings");
        assert!(*et < 64.0 * 6e-8, "{name}: {et}");
    }
}

/// Input: (v, n2), (normal, 0): region_refract against `region::refract`.
fn refract_matches_the_cpu(gpu: &Gpu) {
    let main = format!(
        "{IO}
fn region_count() -> u32 {{
    return 0u;
}}
fn region_object(i: u32) -> RegionGpu {{
    var r: RegionGpu;
    return r;
}}
fn surface_data(i: u32) -> vec4<u32> {{
    return vec4<u32>(0u);
}}
@compute @workgroup_size(WORKGROUP)
fn refr(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if 2u * i >= arrayLength(&input) {{
        return;
    }}
    let a = input[2u * i];
    let b = input[2u * i + 1u];
    output[i] = region_refract(a.xyz, b.xyz, a.w);
}}
"
    );
    let source = compose("", &[&DISPATCH, &REGION], &main);
    let mut r = Cases::new(5);
    let cases: Vec<(DVec3, DVec3, f64)> = (0..20000)
        .map(|_| {
            let unit = |r: &mut Cases| loop {
                let d = r.v(-1.0, 1.0);
                if d.length() > 0.1 && d.length() < 1.0 {
                    let d = d.normalize();
                    break DVec3::new(d.x as f32 as f64, d.y as f32 as f64, d.z as f32 as f64);
                }
            };
            let normal = unit(&mut r);
            let mut d = unit(&mut r);
            if d.dot(normal) < 0.0 {
                d = -d;
            }
            let n1 = r.f(1.0, 2.0);
            let v = d * n1;
            let v = DVec3::new(v.x as f32 as f64, v.y as f32 as f64, v.z as f32 as f64);
            (v, normal, r.f(1.0, 2.0))
        })
        .collect();
    let inputs: Vec<[f32; 4]> = cases
        .iter()
        .flat_map(|&(v, normal, n2)| [v4(v, n2), v4(normal, 0.0)])
        .collect();
    let out = gpu.eval(&source, "refr", &inputs, 1, &[]).unwrap();
    let (mut max_err, mut tir, mut excused) = (0f64, 0, 0);
    for (k, &(v, normal, n2)) in cases.iter().enumerate() {
        let o = out[k];
        let vt = v - normal * v.dot(normal);
        let rest = n2 * n2 - vt.length_squared();
        // rest is rounded to a few ulps of n2^2; its square root then to
        // that over 2 sqrt(rest): within it of the critical angle either
        // answer is right.
        let ulp = 6e-8;
        if rest.abs() < 64.0 * ulp * n2 * n2 {
            excused += 1;
            continue;
        }
        match refract(v, normal, n2) {
            Some(want) => {
                assert_eq!(o[3], 1.0, "refract {v} {normal} {n2}");
                let tol = 16.0 * ulp * (1.0 + n2) + 8.0 * ulp * n2 * n2 / rest.sqrt();
                let err = (xyz(o) - want).length();
                assert!(err < tol, "refract {v} {normal} {n2}: {} vs {want}", xyz(o));
                max_err = max_err.max(err);
            }
            None => {
                assert_eq!(o[3], 0.0, "total reflection {v} {normal} {n2}");
                tir += 1;
            }
        }
    }
    println!("refract: max error {max_err:.2e}, {tir} total reflections, {excused} at the critical angle");
    assert!(tir > 1000, "{tir}");
}

/// The same for a VDB grid's solid and grid-read indices
/// (`vdb_shapes`): the crossing of the trilinear interpolant cell by cell
/// (`vdb_crossing`), its normal and the index from a grid with its
/// gradient. The GPU's distance of a VDB solid is only its sign (the
/// threshold less the sample): at the CPU's crossing it is the sample's
/// rounding, within the distance bound of `bounds`.
fn vdb_surfaces_owner_and_index_match_the_cpu(gpu: &Gpu) {
    let scene = vdb_shapes();
    let per_shape = check_surfaces(gpu, &scene, 13, 8000, true);
    for (name, n, et, en) in per_shape {
        // The drop is small: about 200 of its 4000 segments cross it.
        assert!(n > 150, "{name}: {n}");
        assert!(et < 64.0 * 6e-8 && en < 1e-5, "{name}: {et} {en}");
    }
}

/// The extinction a region reads (`Material::extinction_at`): a VDB grid's
/// scaled sample inside the box of `vdb_shapes`, the constant elsewhere;
/// and the gradient of an index read from a grid (`Regions::index`:
/// central differences half a grid voxel either way, 1/64 here, so each
/// sample's f32 rounding, about 1.2e-7 in the value plus the gradient (up
/// to 6) times 6e-8 in the position, grows 32-fold: held to 3e-5).
fn vdb_extinction_matches_the_cpu(gpu: &Gpu) {
    let scene = vdb_shapes();
    let main = format!(
        "{IO}{TABLE_HOOKS}
@compute @workgroup_size(WORKGROUP)
fn ext(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if i >= arrayLength(&input) {{
        return;
    }}
    let a = input[i];
    output[2u * i] = vec4<f32>(region_extinction(u32(a.w), a.xyz), 0.0);
    output[2u * i + 1u] = region_index(u32(a.w), a.xyz, 0u);
}}
"
    );
    let source = compose("", &[&DISPATCH, &REGION], &main);
    let gpu_regions = gpu_regions(&scene);
    let table = &gpu_regions.table;
    let mut r = Cases::new(14);
    let cases: Vec<(DVec3, usize)> = (0..4000)
        .map(|j| (r.v(-0.5, 0.5) + DVec3::new(0.0, 0.15, 0.0), j % table.len()))
        .collect();
    let inputs: Vec<[f32; 4]> = cases.iter().map(|&(p, k)| v4(p, k as f64)).collect();
    let out = eval_with(gpu, &gpu_regions, (&source, "ext"), &inputs, 2);
    let regions = Regions::new(&scene);
    let (mut worst, mut worst_g) = (0f64, 0f64);
    let (mut graded, mut bent) = (0, 0);
    for (j, &(p, k)) in cases.iter().enumerate() {
        let o = &out[2 * j..2 * j + 2];
        let region = (table[k].object != u32::MAX).then_some(table[k].object as usize);
        let m = regions.material(region);
        let want = m.extinction_at(p);
        graded += usize::from(m.extinction_grid.is_some() && want != DVec3::ZERO);
        let err = (xyz(o[0]) - want).length();
        // f32 position and sample: a few ulps of the largest value (3).
        assert!(
            err < 1e-5,
            "extinction of region {k} at {p}: {} vs {want}",
            xyz(o[0])
        );
        worst = worst.max(err);
        let (n, g) = regions.index(region, p, 0);
        assert!(
            (o[1][0] as f64 - n).abs() < 1e-6,
            "index of region {k} at {p}"
        );
        if m.index_grid.is_some() {
            let err = (DVec3::new(o[1][1] as f64, o[1][2] as f64, o[1][3] as f64) - g).length();
            assert!(
                err < 3e-5,
                "gradient of region {k} at {p}: {:?} vs {g}",
                o[1]
            );
            worst_g = worst_g.max(err);
            bent += usize::from(g.length() > 0.1);
        }
    }
    println!(
        "extinction: {graded} samples inside the grid, max error {worst:.2e}; \
         index gradient: {bent} samples where it exceeds 0.1, max error {worst_g:.2e}"
    );
    assert!(graded > 100 && bent > 100, "{graded} {bent}");
}

/// `Regions::step` against `region_step` (equal time, RK4) in and around
/// the VDB drop of `vdb_shapes`, whose index the grid gives (curved paths,
/// cut where they meet its surface): rays from points about the drop, in
/// every direction, each taking `STEPS` steps of 0.04 (optical path; the
/// grid's voxel is 1/32). Compared: where each ends, its region, and how
/// many true crossings it made. Paths that graze a surface or pass within
/// rounding of one part on the two (f32 against f64): at most 2% of them
/// may end apart; the others end within 1e-4.
fn vdb_steps_match_the_cpu(gpu: &Gpu) {
    const STEPS: u32 = 12;
    const H: f64 = 0.04;
    let scene = vdb_shapes();
    let main = format!(
        "{IO}{TABLE_HOOKS}{FIELD_HOOKS}
@compute @workgroup_size(WORKGROUP)
fn steps(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if 2u * i >= arrayLength(&input) {{
        return;
    }}
    let a = input[2u * i];
    let b = input[2u * i + 1u];
    let start = region_owner(a.xyz);
    var ray = RegionRay(a.xyz, b.xyz * region_index(start, a.xyz, 0u).x, 0.0, start);
    var events = 0u;
    for (var k = 0u; k < {STEPS}u; k++) {{
        let st = region_step(&ray, FORM_EQUAL_TIME, INTEGRATOR_RK4, {H}, 0u, a.w);
        events += u32(st.c.event);
    }}
    output[2u * i] = vec4<f32>(ray.x, f32(ray.region));
    output[2u * i + 1u] = vec4<f32>(ray.v, f32(events));
}}
"
    );
    let source = compose("", &[&DISPATCH, &STEP_WGSL], &main);
    let regions = Regions::new(&scene);
    let gpu_regions = gpu_regions(&scene);
    let table = &gpu_regions.table;
    let count = table.len() - 1;
    let eps = eikon_grid::region::gpu_eps(&scene.grid.geometry);
    let mut r = Cases::new(26);
    let cases: Vec<(DVec3, DVec3)> = (0..4000)
        .map(|_| {
            let o = r.v(-0.6, 0.6) + DVec3::new(0.0, 0.15, 0.0);
            let d = loop {
                let d = r.v(-1.0, 1.0);
                if d.length() > 0.1 && d.length() < 1.0 {
                    let d = d.normalize();
                    break DVec3::new(d.x as f32 as f64, d.y as f32 as f64, d.z as f32 as f64);
                }
            };
            (
                DVec3::new(o.x as f32 as f64, o.y as f32 as f64, o.z as f32 as f64),
                d,
            )
        })
        .collect();
    let inputs: Vec<[f32; 4]> = cases
        .iter()
        .flat_map(|&(o, d)| [v4(o, eps), v4(d, 0.0)])
        .collect();
    let out = eval_with(gpu, &gpu_regions, (&source, "steps"), &inputs, 2);
    let (mut apart, mut crossed, mut worst) = (0, 0, 0f64);
    let mut errors = Vec::new();
    for (k, &(o, d)) in cases.iter().enumerate() {
        let g = &out[2 * k..2 * k + 2];
        let mut ray = regions.ray(o, d, 0);
        ray.ahead = None;
        let mut events = 0;
        for _ in 0..STEPS {
            let st = regions.step(
                &mut ray,
                eikon_grid::Form::EqualTime,
                eikon_grid::Integrator::Rk4,
                H,
                0,
            );
            events += usize::from(st.event.is_some());
        }
        let region = (g[0][3] as usize) < count;
        let region = region.then(|| table[g[0][3] as usize].object as usize);
        let err = (xyz(g[0]) - ray.s.x).length();
        crossed += usize::from(events > 0);
        if err > 1e-4 || region != ray.region || g[1][3] as usize != events {
            apart += 1;
            if apart <= 5 {
                println!(
                    "apart: from {o} along {d}: GPU {:?} region {region:?} events {}, CPU {} region {:?} events {events}",
                    xyz(g[0]),
                    g[1][3],
                    ray.s.x,
                    ray.region
                );
            }
            continue;
        }
        errors.push(err);
        worst = worst.max(err);
    }
    errors.sort_by(f64::total_cmp);
    let median = errors.get(errors.len() / 2).copied().unwrap_or(0.0);
    println!(
        "steps: {} rays, {crossed} crossing a surface, {apart} apart; the others end within {worst:.2e} (median {median:.2e})",
        cases.len()
    );
    assert!(crossed > 500, "{crossed}");
    assert!(apart * 50 < cases.len(), "{apart} apart");
}

/// Input: (o, eps), (d, t_max): the next surface of o + d t on
/// (eps, t_max] over every region (`Regions::next_surface`) as (t, ok,
/// object), its normal, and the crossing there from the region owning o
/// (`Regions::cross`): (event, total, region, reflectance), the new v.
fn next_surface_and_cross_match_the_cpu(gpu: &Gpu) {
    check_next_surface(gpu, &scene(), 23, (4000, 1000));
}

/// The same over the rounded box, solid of revolution, torus,
/// superquadrics and meshes.
fn other_next_surface_and_cross_match_the_cpu(gpu: &Gpu) {
    check_next_surface(gpu, &other_shapes(), 24, (4000, 1000));
}

/// The same over VDB grids (`vdb_shapes`: two objects, so fewer
/// segments meet a surface).
fn vdb_next_surface_and_cross_match_the_cpu(gpu: &Gpu) {
    check_next_surface(gpu, &vdb_shapes(), 25, (1500, 1000));
}

/// `least`: the fewest crossings compared and true crossings found.
fn check_next_surface(gpu: &Gpu, scene: &Scene, seed: u64, least: (usize, usize)) {
    let main = format!(
        "{IO}{TABLE_HOOKS}
@compute @workgroup_size(WORKGROUP)
fn next_and_cross(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if 2u * i >= arrayLength(&input) {{
        return;
    }}
    let a = input[2u * i];
    let b = input[2u * i + 1u];
    let h = region_next_surface(a.xyz, b.xyz, a.w, b.w);
    output[4u * i] = vec4<f32>(h.t, f32(h.ok), f32(h.obj), 0.0);
    output[4u * i + 1u] = vec4<f32>(h.normal, 0.0);
    let here = region_owner(a.xyz);
    let v = b.xyz * region_index(here, a.xyz, 0u).x;
    let c = region_cross(here, v, a.xyz + b.xyz * h.t, h.normal, a.w, 0u);
    output[4u * i + 2u] = vec4<f32>(f32(c.event), f32(c.total), f32(c.region), c.reflectance);
    output[4u * i + 3u] = vec4<f32>(c.v, 0.0);
}}
"
    );
    let source = compose("", &[&DISPATCH, &REGION], &main);
    let regions = Regions::new(scene);
    let gpu_regions = gpu_regions(scene);
    let table: &[RegionGpu] = &gpu_regions.table;
    let count = table.len() - 1;
    // The GPU renderer's tolerance for a 3-unit scene (`sharp_eps`).
    let eps = 4e-6 * 1.6;
    let mut r = Cases::new(seed);
    let cases: Vec<(DVec3, DVec3, f64)> = (0..20000)
        .map(|_| {
            let o = r.v(-1.5, 1.5);
            let d = loop {
                let d = r.v(-1.0, 1.0);
                if d.length() > 0.1 && d.length() < 1.0 {
                    let d = d.normalize();
                    break DVec3::new(d.x as f32 as f64, d.y as f32 as f64, d.z as f32 as f64);
                }
            };
            (o, d, r.f(0.1, 4.0))
        })
        .collect();
    let inputs: Vec<[f32; 4]> = cases
        .iter()
        .flat_map(|&(o, d, t)| [v4(o, eps), v4(d, t)])
        .collect();
    let out = eval_with(gpu, &gpu_regions, (&source, "next_and_cross"), &inputs, 4);
    const ULP: f64 = 6e-8;
    let (mut compared, mut excused, mut events, mut total) = (0, 0, 0, 0);
    let (mut max_t, mut max_v, mut max_r) = (0f64, 0f64, 0f64);
    for (k, &(o, d, t_max)) in cases.iter().enumerate() {
        let g = &out[4 * k..4 * k + 4];
        let cpu = regions.next_surface(o, d, t_max);
        let gpu_hit =
            (g[0][1] != 0.0).then(|| (table[g[0][2] as usize].object as usize, g[0][0] as f64));
        // Degenerate: a crossing near either end, grazing, or two surfaces
        // within rounding of each other along the ray (or near the point).
        let near = |p: DVec3| {
            scene
                .objects
                .iter()
                .filter(|ob| ob.shape.distance(p).abs() < 1e-4)
                .count()
        };
        let degenerate = |t: f64, n: DVec3| {
            t < 1e-4 || (t - t_max).abs() < 1e-4 || n.dot(d).abs() < 0.02 || near(o + d * t) > 1
        };
        let (Some((obj, c)), Some((gobj, gt))) = (cpu, gpu_hit) else {
            if cpu.is_some() != gpu_hit.is_some() {
                let ok = match (cpu, gpu_hit) {
                    (Some((_, c)), _) => degenerate(c.t, c.normal),
                    (_, Some((_, t))) => degenerate(t, xyz(g[1])),
                    _ => true,
                };
                assert!(
                    ok,
                    "next surface from {o} along {d}: CPU {cpu:?}, GPU {gpu_hit:?}"
                );
                excused += 1;
            }
            continue;
        };
        if obj != gobj || degenerate(c.t, c.normal) {
            assert!(
                degenerate(c.t, c.normal) || degenerate(gt, xyz(g[1])),
                "next surface from {o} along {d}: CPU {obj} {c:?}, GPU {gobj} {gt}"
            );
            excused += 1;
            continue;
        }
        let cos = c.normal.dot(d).abs();
        let tol_t = 64.0 * ULP * (3.0 + c.t) / cos;
        assert!(
            (gt - c.t).abs() < tol_t,
            "t from {o} along {d}: {gt} vs {}",
            c.t
        );
        max_t = max_t.max((gt - c.t).abs() * cos / (3.0 + c.t));
        compared += 1;
        // The crossing, from the region that owns o.
        let mut ray = regions.ray(o, d, 0);
        ray.s.x = o;
        let ev = regions.cross(&mut ray, obj, o + d * c.t, c.normal, 0);
        assert_eq!(
            g[2][0] != 0.0,
            ev.is_some(),
            "event from {o} along {d}: {ev:?}"
        );
        let Some(ev) = ev else { continue };
        events += 1;
        let region = (g[2][2] as usize) < count;
        let region = region.then(|| table[g[2][2] as usize].object as usize);
        assert_eq!(region, ray.region, "region after {o} along {d}");
        // Near the critical angle either answer is right (see refract).
        let vt2 =
            (ev.incident - ev.normal * ev.incident.dot(ev.normal)).length_squared() * ev.n1 * ev.n1;
        let rest = ev.n2 * ev.n2 - vt2;
        if rest.abs() < 1e-4 {
            continue;
        }
        assert_eq!(
            g[2][1] != 0.0,
            ev.total,
            "total reflection after {o} along {d}"
        );
        total += usize::from(ev.total);
        let cos_t = rest.max(0.0).sqrt().max(1e-3);
        // Both follow the normal's error (1e-5, a superquadric's 1e-4:
        // `bounds`).
        let nb = bounds(&scene.objects[obj].shape).normal;
        let tol_v = nb * (1.0 + ev.n2) / cos_t.min(1.0) / cos.min(1.0);
        let err_v = (xyz(g[3]) - ray.s.v).length();
        assert!(
            err_v < tol_v,
            "v after {o} along {d}: {} vs {}",
            xyz(g[3]),
            ray.s.v
        );
        max_v = max_v.max(err_v);
        let err_r = (g[2][3] as f64 - ev.reflectance).abs();
        assert!(
            err_r < nb / cos_t.min(1.0) / cos.min(1.0),
            "R after {o} along {d}: {} vs {} (surface of object {obj}, cos {cos}, cos_t {cos_t}, n1 {} n2 {}, GPU normal {}, CPU {})",
            g[2][3],
            ev.reflectance,
            ev.n1,
            ev.n2,
            xyz(g[1]),
            c.normal
        );
        max_r = max_r.max(err_r);
    }
    println!(
        "next surface: {compared} compared, {excused} near-degenerate excused, {events} true crossings ({total} total reflections): \
         max |dt| cos / (scale + t) {max_t:.2e}, max v error {max_v:.2e}, max R error {max_r:.2e}"
    );
    assert!(
        compared > least.0 && events > least.1,
        "{compared} {events}"
    );
    assert!(excused * 100 < cases.len(), "{excused} excused");
}

/// `Regions::settle` against `region_settle`: rays put on a surface of the
/// first scene where a line from a random point meets it (not grazing:
/// |d . n| >= 0.2), heading on across it and in the region beyond, as a
/// step that crossed at its very end leaves them. Each backend must move
/// every one (the GPU at most 1%: its point is rounded to f32) into that
/// region, and no further than a thousandth (the moves are a few `eps`);
/// the two must end in the same region. Settling must have been needed
/// for a good share: where the point's owner is still the region before.
fn settle_matches_the_cpu(gpu: &Gpu) {
    let scene = scene();
    let main = format!(
        "{IO}{TABLE_HOOKS}{FIELD_HOOKS}
@compute @workgroup_size(WORKGROUP)
fn settle(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if 2u * i >= arrayLength(&input) {{
        return;
    }}
    let a = input[2u * i];
    let b = input[2u * i + 1u];
    var ray = RegionRay(a.xyz, b.xyz, 0.0, u32(b.w));
    region_settle(&ray, a.w);
    output[2u * i] = vec4<f32>(ray.x, f32(region_owner(ray.x)));
    output[2u * i + 1u] = vec4<f32>(ray.v, 0.0);
}}
"
    );
    let source = compose("", &[&DISPATCH, &STEP_WGSL], &main);
    let regions = Regions::new(&scene);
    let gpu_regions = gpu_regions(&scene);
    let table = &gpu_regions.table;
    let count = table.len() - 1;
    let slot = |r: Option<usize>| {
        r.map_or(count, |o| {
            table.iter().position(|t| t.object as usize == o).unwrap()
        })
    };
    let eps = eikon_grid::region::gpu_eps(&scene.grid.geometry);
    let mut r = Cases::new(31);
    let mut cases = Vec::new();
    while cases.len() < 3000 {
        let o = r.v(-1.2, 1.2);
        let d = r.v(-1.0, 1.0);
        if !(d.length() > 0.1 && d.length() < 1.0) {
            continue;
        }
        let d = eikon_testkit::parity::f32s(d.normalize());
        let Some((_, c)) = regions.next_surface(o, d, 4.0) else {
            continue;
        };
        let p = o + d * c.t;
        let beyond = regions.at(p + d * 1e-3);
        if c.normal.dot(d).abs() < 0.2 || regions.at(p - d * 1e-3) == beyond {
            continue;
        }
        cases.push((p, d, beyond));
    }
    let inputs: Vec<[f32; 4]> = cases
        .iter()
        .flat_map(|&(p, d, beyond)| [v4(p, eps), v4(d, slot(beyond) as f64)])
        .collect();
    let out = eval_with(gpu, &gpu_regions, (&source, "settle"), &inputs, 2);
    let (mut needed, mut gpu_unsettled, mut apart) = (0, 0, 0);
    for (k, &(p, d, beyond)) in cases.iter().enumerate() {
        needed += usize::from(regions.at(p) != beyond);
        let mut ray = regions.ray(p, d, 0);
        ray.region = beyond;
        ray.ahead = None;
        regions.settle(&mut ray);
        assert!(
            regions.at(ray.s.x) == beyond && (ray.s.x - p).length() < 1e-3,
            "CPU: {p} along {d} into {beyond:?} settled at {} in {:?}",
            ray.s.x,
            regions.at(ray.s.x)
        );
        let g = out[2 * k];
        let owner = g[3] as usize;
        if owner != slot(beyond) || (xyz(g) - p).length() >= 1e-3 {
            gpu_unsettled += 1;
        }
        apart += usize::from(owner != slot(regions.at(ray.s.x)));
    }
    println!(
        "settle: {} rays on a surface, {needed} owned by the region before; the GPU left {gpu_unsettled} unsettled, {apart} apart from the CPU",
        cases.len()
    );
    assert!(needed * 10 > cases.len(), "{needed}");
    assert!(gpu_unsettled * 100 < cases.len(), "{gpu_unsettled}");
    assert!(apart * 100 < cases.len(), "{apart}");
}

fn main() {
    // The longest first: the harness runs the others beside it.
    Tests::compile_bound()
        .gpu("sharp_vdb_steps_match_the_cpu", vdb_steps_match_the_cpu)
        .gpu("sharp_settle_matches_the_cpu", settle_matches_the_cpu)
        .gpu(
            "sharp_surfaces_owner_and_index_match_the_cpu",
            surfaces_owner_and_index_match_the_cpu,
        )
        .gpu(
            "sharp_other_surfaces_owner_and_index_match_the_cpu",
            other_surfaces_owner_and_index_match_the_cpu,
        )
        .gpu("sharp_refract_matches_the_cpu", refract_matches_the_cpu)
        .gpu(
            "sharp_other_next_surface_and_cross_match_the_cpu",
            other_next_surface_and_cross_match_the_cpu,
        )
        .gpu(
            "sharp_next_surface_and_cross_match_the_cpu",
            next_surface_and_cross_match_the_cpu,
        )
        .gpu(
            "sharp_vdb_surfaces_owner_and_index_match_the_cpu",
            vdb_surfaces_owner_and_index_match_the_cpu,
        )
        .gpu(
            "sharp_vdb_extinction_matches_the_cpu",
            vdb_extinction_matches_the_cpu,
        )
        .gpu(
            "sharp_vdb_next_surface_and_cross_match_the_cpu",
            vdb_next_surface_and_cross_match_the_cpu,
        )
        .run()
}
