//! Function-level parity of the grid crate's WGSL modules (the grid, the
//! ray equation, Fresnel, interfaces) with the Rust they mirror: each test
//! evaluates shared WGSL functions on a batch of inputs in a small kernel
//! and compares them with the CPU functions at f32 tolerance, so a drift
//! names the function that drifted. They need a Vulkan, Metal or DX12
//! adapter (lavapipe in CI, where a missing adapter fails them; elsewhere
//! they are reported as ignored).

use eikon_gpu::{Gpu, Texture, DISPATCH};
use eikon_grid::geometry::{GridGpu, WGSL as GRID};
use eikon_grid::interface::{band_transmittance, crossing_transmittance, Sides};
use eikon_grid::ray::{
    step_euler, step_euler_on_shell, step_euler_sampled, step_rk4, step_rk4_on_shell,
};
use eikon_grid::{interface, ray, Form, IndexField, Medium, RayState, Scene};
use eikon_optics::fresnel;
use eikon_shader::{compose, VECTOR};
use eikon_testkit::parity::{v4, xyz, Cases, IO};
use eikon_testkit::Tests;
use glam::DVec3;

/// A Luneburg lens in glass with an absorbing shell: graded, jumping and
/// constant regions, on a grid that is not a cube.
fn medium() -> Medium {
    let scene = Scene::parse(
        r#"
[grid]
resolution = [14, 12, 10]
min = [-1.2, -1.0, -0.9]
max = [1.3, 1.1, 0.8]

[[object]]
shape = { type = "sphere", center = [0.1, 0.0, 0.0], radius = 0.75 }
index = { type = "luneburg" }
priority = 2

[[object]]
shape = { type = "box", center = [0.0, 0.0, 0.0], size = [2.0, 1.6, 1.2] }
index = 1.5
extinction = [0.5, 1.0, 2.0]
priority = 1
"#,
        "wgsl parity",
    )
    .unwrap();
    Medium::build(&scene).unwrap()
}

/// A `(nx, ny, nz, 4)` array as an rgba32float texture.
fn texture(gpu: &Gpu, dims: [usize; 3], data: &[f32]) -> Texture {
    let slab = dims[1] * dims[2] * 4;
    gpu.texture_3d(
        "field",
        dims,
        wgpu::TextureFormat::Rgba32Float,
        &|i0, i1| bytemuck::cast_slice(&data[i0 * slab..i1 * slab]).to_vec(),
    )
}

fn grid_geometry_and_trilinear_samples_match_the_cpu(gpu: &Gpu) {
    let main = format!(
        "{IO}
@group(0) @binding(2) var<uniform> G: GridGpu;
@group(0) @binding(3) var field: texture_3d<f32>;
@group(0) @binding(4) var ext: texture_3d<f32>;

// Input: (p, 0), (d, 0): contains, the clipped interval, the cell, its
// centre, the index (tri_lerp) and the extinction (tri_sum).
@compute @workgroup_size(WORKGROUP)
fn geometry(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if 2u * i >= arrayLength(&input) {{
        return;
    }}
    let p = input[2u * i].xyz;
    let d = input[2u * i + 1u].xyz;
    let c = grid_clip_line(G, p, d);
    let cell = grid_cell_of(G, p);
    var centre = vec3<f32>(0.0);
    if cell.ok {{
        centre = grid_voxel_center(G, cell.flat);
    }}
    let q = grid_trilinear(G, p);
    output[4u * i] = vec4<f32>(f32(grid_contains(G, p)), f32(c.hit), c.t0, c.t1);
    output[4u * i + 1u] = vec4<f32>(centre, select(-1.0, f32(cell.flat), cell.ok));
    output[4u * i + 2u] = tri_lerp(field, q);
    output[4u * i + 3u] = tri_sum(ext, q);
}}
"
    );
    let source = compose("", &[&DISPATCH, &GRID], &main);
    let m = medium();
    let g = &m.geometry;
    let field = texture(gpu, g.dims, m.index[0].as_slice().unwrap());
    let ext = m.extinction.as_slice().unwrap();
    let mut rgba = vec![0f32; g.voxel_count() * 4];
    for (o, e) in rgba.chunks_exact_mut(4).zip(ext.chunks_exact(3)) {
        o[..3].copy_from_slice(e);
    }
    let ext = texture(gpu, g.dims, &rgba);
    let grid = gpu.uniform("grid", &[GridGpu::new(g)]);
    let mut r = Cases::new(3);
    let cases: Vec<(DVec3, DVec3)> = (0..5000)
        .map(|k| {
            let p = r.v(-1.6, 1.6);
            let mut d = r.v(-1.0, 1.0);
            if k % 7 == 0 {
                d.y = 0.0; // parallel to a pair of faces
            }
            (p, d)
        })
        .collect();
    let inputs: Vec<[f32; 4]> = cases
        .iter()
        .flat_map(|&(p, d)| [v4(p, 0.0), v4(d, 0.0)])
        .collect();
    let out = gpu
        .eval(
            &source,
            "geometry",
            &inputs,
            2,
            &[
                grid.as_entire_binding(),
                wgpu::BindingResource::TextureView(&field.view),
                wgpu::BindingResource::TextureView(&ext.view),
            ],
        )
        .unwrap();
    let vf = m.field(0);
    let spacing = g.spacing();
    let mut inside = 0;
    for (k, &(p, d)) in cases.iter().enumerate() {
        let o = &out[4 * k..4 * k + 4];
        // A point within f32 rounding of a face may fall either side.
        let near_face = (0..3).any(|a| {
            let u = (p[a] - g.min[a]) / spacing[a];
            (u - u.round()).abs() < 1e-4
        });
        if near_face {
            continue;
        }
        assert_eq!(o[0][0] != 0.0, g.contains(p), "contains {p}");
        match g.clip_line(p, d) {
            Some((t0, t1)) => {
                assert_eq!(o[0][1], 1.0, "clip {p} {d}");
                let tol = 1e-5 * (1.0 + t0.abs().max(t1.abs()));
                assert!(
                    (o[0][2] as f64 - t0).abs() < tol && (o[0][3] as f64 - t1).abs() < tol,
                    "clip {p} {d}"
                );
            }
            None => assert_eq!(o[0][1], 0.0, "clip {p} {d}"),
        }
        match g.cell_of(p) {
            Some([i, j, kk]) => {
                inside += 1;
                assert_eq!(o[1][3] as usize, g.flat_index(i, j, kk), "cell of {p}");
                let c = g.voxel_center(i, j, kk);
                assert!((xyz(o[1]) - c).length() < 1e-6, "centre of {p}");
            }
            None => assert_eq!(o[1][3], -1.0, "cell of {p}"),
        }
        // VoxelField::sample's interpolation: n and the stored
        // grad(n^2 / 2) (the gradient over n).
        let (n, grad) = vf.sample(p);
        let stored = grad * n;
        assert!(
            (o[2][0] as f64 - n).abs() < 2e-6,
            "n at {p}: {} vs {n}",
            o[2][0]
        );
        let got = DVec3::new(o[2][1] as f64, o[2][2] as f64, o[2][3] as f64);
        assert!(
            (got - stored).length() < 1e-5 * (1.0 + stored.length()),
            "grad at {p}"
        );
        // Trilinear weights, as Medium::sample_rgb.
        let sigma = m.sample_rgb(&m.extinction, p);
        assert!(
            (xyz(o[3]) - sigma).length() < 1e-5 * (1.0 + sigma.length()),
            "sigma at {p}"
        );
    }
    assert!(inside > 1000, "{inside}");
}

fn ray_steps_match_the_cpu_in_both_forms(gpu: &Gpu) {
    let main = format!(
        "{IO}
@group(0) @binding(2) var<uniform> G: GridGpu;
@group(0) @binding(3) var field: texture_3d<f32>;

fn index_field(p: vec3<f32>) -> vec4<f32> {{
    let v = tri_lerp(field, grid_trilinear(G, p));
    let inv = 1.0 / v.x;
    return vec4<f32>(v.x, v.yzw * inv);
}}

// Input: (x, h), (v, form), (integrator, on the shell, sampled Euler): the
// step's x, v and optical path increments, and the v they apply to.
@compute @workgroup_size(WORKGROUP)
fn step(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if 3u * i >= arrayLength(&input) {{
        return;
    }}
    let a = input[3u * i];
    let b = input[3u * i + 1u];
    let c = input[3u * i + 2u];
    let form = u32(b.w);
    let integrator = u32(c.x);
    var v = b.xyz;
    var inc: RayDeriv;
    if c.y != 0.0 {{
        let s = ray_step_on_shell(form, integrator, a.xyz, v, a.w);
        v = s.v;
        inc = s.inc;
    }} else if c.z != 0.0 {{
        let f = index_field(a.xyz);
        inc = ray_euler_sampled(f.x, f.yzw, v, a.w);
    }} else {{
        inc = ray_increment(form, integrator, a.xyz, v, ray_deriv(form, a.xyz, v), a.w);
    }}
    output[3u * i] = vec4<f32>(inc.x, inc.opl);
    output[3u * i + 1u] = vec4<f32>(inc.v, 0.0);
    output[3u * i + 2u] = vec4<f32>(v, 0.0);
}}
"
    );
    let source = compose("", &[&DISPATCH, &GRID, &ray::WGSL], &main);
    let m = medium();
    let g = &m.geometry;
    let tex = texture(gpu, g.dims, m.index[0].as_slice().unwrap());
    let grid = gpu.uniform("grid", &[GridGpu::new(g)]);
    let f = m.field(0);
    let mut r = Cases::new(17);
    // Form, integrator (0 Euler, 1 RK4, 2 the eye rays' Euler from their
    // sample), on the shell.
    let kinds = [
        (Form::EqualDistance, 2u32, false),
        (Form::EqualDistance, 0u32, false),
        (Form::EqualDistance, 1, false),
        (Form::EqualTime, 0, true),
        (Form::EqualTime, 1, true),
        (Form::EqualTime, 1, false),
    ];
    let mut cases = Vec::new();
    for k in 0..4000 {
        let (form, integ, shell) = kinds[k % kinds.len()];
        let x = r.v(-1.0, 1.1);
        let n = f.sample(x).0;
        // Off the shell by up to 2% where the step puts it back.
        let scale = if shell { r.f(0.98, 1.02) } else { 1.0 };
        let v = r.v(-1.0, 1.0).normalize() * n * scale;
        let v = DVec3::new(v.x as f32 as f64, v.y as f32 as f64, v.z as f32 as f64);
        let h = r.f(0.01, 0.15);
        cases.push((x, v, h, form, integ, shell));
    }
    let inputs: Vec<[f32; 4]> = cases
        .iter()
        .flat_map(|&(x, v, h, form, integ, shell)| {
            [
                v4(x, h),
                v4(v, form as u32 as f64),
                [
                    integ.min(1) as f32,
                    f32::from(u8::from(shell)),
                    f32::from(u8::from(integ == 2)),
                    0.0,
                ],
            ]
        })
        .collect();
    let out = gpu
        .eval(
            &source,
            "step",
            &inputs,
            1,
            &[
                grid.as_entire_binding(),
                wgpu::BindingResource::TextureView(&tex.view),
            ],
        )
        .unwrap();
    for (k, &(x, v, h, form, integ, shell)) in cases.iter().enumerate() {
        let mut s = RayState { x, v, opl: 0.0 };
        match (integ, shell) {
            (2, _) => step_euler_sampled(&mut s, f.sample(x), h),
            (0, false) => step_euler(&f, form, &mut s, h),
            (_, false) => step_rk4(&f, form, &mut s, h),
            (0, true) => step_euler_on_shell(&f, form, &mut s, h),
            (_, true) => step_rk4_on_shell(&f, form, &mut s, h),
        }
        let o = &out[3 * k..3 * k + 3];
        let (dx, dvel, dl) = (s.x - x, s.v - dv_of(o[2], v, shell), s.opl);
        let got_dx = xyz(o[0]);
        let got_dv = xyz(o[1]);
        // f32 rounding of the stages' positions (about 1e-7 of x) moves
        // the samples; the increments agree to that over a step.
        let tol_x = 2e-5 * dx.length() + 1e-6 * h;
        assert!(
            (got_dx - dx).length() < tol_x,
            "{k} {form:?} {integ} dx {got_dx} vs {dx}"
        );
        let tol_v = 2e-5 * (1.0 + dvel.length()) * h.max(dvel.length());
        assert!(
            (got_dv - dvel).length() < tol_v.max(1e-6),
            "{k} {form:?} {integ} dv {got_dv} vs {dvel}"
        );
        assert!((o[0][3] as f64 - dl).abs() < 1e-5 * dl, "{k} opl");
    }
}

/// The v an increment applies to: the input's, or on the shell the
/// GPU's rescaled one (checked against the CPU's rescaling here).
fn dv_of(gpu_v: [f32; 4], v: DVec3, shell: bool) -> DVec3 {
    if !shell {
        return v;
    }
    let got = xyz(gpu_v);
    assert!((got.length() / v.length() - 1.0).abs() < 0.03);
    // The CPU starts from v rescaled to |v| = n in f64; the GPU's, in
    // f32, differs by rounding only.
    got
}

fn fresnel_and_interface_transmittance_match_the_cpu(gpu: &Gpu) {
    let main = format!(
        "{IO}
// Input: (cos, n1, n2, 0), (v, lo), (normal, hi), (dx, delta).
@compute @workgroup_size(WORKGROUP)
fn fresnel(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if 4u * i >= arrayLength(&input) {{
        return;
    }}
    let a = input[4u * i];
    let v = input[4u * i + 1u];
    let n = input[4u * i + 2u];
    let d = input[4u * i + 3u];
    output[4u * i] = vec4<f32>(
        fresnel_reflectance(a.x, a.y, a.z),
        interface_crossing_transmittance(v.w, n.w, v.xyz, normalize(n.xyz)),
        interface_transmittance(v.w, n.w, d.w, n.xyz, v.xyz, d.xyz),
        0.0,
    );
}}
"
    );
    let source = compose(
        "",
        &[&DISPATCH, &VECTOR, &fresnel::WGSL, &interface::WGSL],
        &main,
    );
    let mut r = Cases::new(29);
    let indices = [1.0f64, 1.0, 1.333, 1.5, 2.42];
    let mut cases = Vec::new();
    for k in 0..6000 {
        let cos = if k % 50 == 0 { 0.0 } else { r.f(-1.0, 1.0) };
        let n1 = indices[k % 5];
        let n2 = indices[(k / 5) % 5];
        let (lo, hi) = (n1.min(n2), n1.max(n2));
        let grad = r.v(-3.0, 3.0);
        // Eikonal gradients of either side's length, all directions.
        let v = r.v(-1.0, 1.0).normalize() * if k % 2 == 0 { lo } else { hi };
        let v = DVec3::new(v.x as f32 as f64, v.y as f32 as f64, v.z as f32 as f64);
        let dx = r.v(-0.05, 0.05);
        let delta = if k % 9 == 0 { 0.0 } else { r.f(0.0, 40.0) };
        cases.push((cos, n1, n2, lo, hi, v, grad, dx, delta));
    }
    let inputs: Vec<[f32; 4]> = cases
        .iter()
        .flat_map(|&(cos, n1, n2, lo, hi, v, grad, dx, delta)| {
            [
                [cos as f32, n1 as f32, n2 as f32, 0.0],
                v4(v, lo),
                v4(grad, hi),
                v4(dx, delta),
            ]
        })
        .collect();
    let out = gpu.eval(&source, "fresnel", &inputs, 1, &[]).unwrap();
    let mut tir = 0;
    for (k, &(cos, n1, n2, lo, hi, v, grad, dx, delta)) in cases.iter().enumerate() {
        let o = out[4 * k];
        let want = fresnel::reflectance(cos, n1, n2);
        // Just past the critical angle R is 1 and just before it steep:
        // a cosine within f32 rounding of it may fall either side.
        let crit = n1 > n2 && {
            let sin_c = n2 / n1;
            let c = (1.0 - sin_c * sin_c).sqrt();
            (cos.abs() - c).abs() < 1e-4
        };
        if !crit {
            // Near the critical angle cos_t = sqrt(1 - sin_t^2) loses the
            // digits f32 rounds sin_t^2 to: the tolerance grows as 1 / cos_t.
            let sin_t2 = (n1 / n2).powi(2) * (1.0 - cos * cos);
            let cos_t = (1.0 - sin_t2).max(0.0).sqrt();
            let tol = 2e-6 + 1e-6 / cos_t.max(1e-3);
            assert!(
                (o[0] as f64 - want).abs() < tol,
                "R({cos}, {n1}, {n2}): {} vs {want}",
                o[0]
            );
        }
        tir += usize::from(want == 1.0);
        let sides = Sides { lo, hi };
        let normal = grad.normalize();
        let normal32 = DVec3::new(
            normal.x as f32 as f64,
            normal.y as f32 as f64,
            normal.z as f32 as f64,
        );
        let vt2 = (v - normal * v.dot(normal)).length_squared();
        let grazing = (vt2.sqrt() - lo.min(hi)).abs() < 1e-4;
        if !grazing {
            // As for R, near grazing on the low side: f32 rounds 1 - sin^2
            // there, and the cosine loses digits as 1 / cos.
            let cos_lo = (1.0 - vt2 / (lo * lo)).max(0.0).sqrt();
            let tol = 2e-6 + 1e-6 / cos_lo.max(1e-3);
            let want = crossing_transmittance(sides, v, normal32);
            assert!(
                (o[1] as f64 - want).abs() < tol,
                "crossing {k}: {} vs {want}",
                o[1]
            );
            let want = band_transmittance(sides, delta, grad, v, dx);
            assert!(
                (o[2] as f64 - want).abs() < tol,
                "band {k}: {} vs {want}",
                o[2]
            );
        }
    }
    assert!(tir > 100, "{tir} cases of total internal reflection");
}

fn main() {
    Tests::new()
        .gpu(
            "grid_geometry_and_trilinear_samples_match_the_cpu",
            grid_geometry_and_trilinear_samples_match_the_cpu,
        )
        .gpu(
            "ray_steps_match_the_cpu_in_both_forms",
            ray_steps_match_the_cpu_in_both_forms,
        )
        .gpu(
            "fresnel_and_interface_transmittance_match_the_cpu",
            fresnel_and_interface_transmittance_match_the_cpu,
        )
        .run()
}
