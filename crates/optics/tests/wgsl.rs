//! Function-level parity of the optics crate's WGSL modules (the
//! Henyey-Greenstein phase function, Fresnel's reflectance and a patch's
//! mean transmittance, Snell's refraction and the mirror direction, which the GPU kernels are composed
//! with) with the Rust they mirror, at f32 tolerance. It needs a Vulkan, Metal or
//! DX12 adapter (lavapipe in CI, where a missing adapter fails it; elsewhere it
//! is reported as ignored).

use eikon_gpu::Gpu;
use eikon_gpu::DISPATCH;
use eikon_optics::fresnel;
use eikon_optics::phase::{self, hg, G_MAX};
use eikon_shader::{compose, VECTOR};
use eikon_testkit::Tests;
use glam::{DQuat, DVec3};

fn henyey_greenstein_matches_the_cpu(gpu: &Gpu) {
    let main = "
@group(0) @binding(0) var<storage, read> input: array<vec4<f32>>;
@group(0) @binding(1) var<storage, read_write> output: array<vec4<f32>>;

// Input (cos, g): the phase function.
@compute @workgroup_size(WORKGROUP)
fn phase(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item(id, groups);
    if i >= arrayLength(&input) {
        return;
    }
    output[i] = vec4<f32>(hg(input[i].x, input[i].y));
}
";
    let source = compose("", &[&DISPATCH, &VECTOR, &phase::WGSL], main);
    // Every g from back to forward scattering, beyond the clamp too, and
    // cosines across [-1, 1] with the forward peak sampled finely.
    let mut cases = Vec::new();
    for gi in 0..=42 {
        let g = -1.05 + 0.05 * gi as f64;
        for ci in 0..=200 {
            let c = -1.0 + 0.01 * ci as f64;
            cases.push((c as f32 as f64, g as f32 as f64));
        }
        for ci in 0..50 {
            let c = 1.0 - 1e-4 * ci as f64;
            cases.push((c as f32 as f64, g as f32 as f64));
        }
    }
    for g in [G_MAX, 0.999, -0.999] {
        cases.push((1.0, g as f32 as f64));
        cases.push((-1.0, g as f32 as f64));
    }
    let inputs: Vec<[f32; 4]> = cases
        .iter()
        .map(|&(c, g)| [c as f32, g as f32, 0.0, 0.0])
        .collect();
    let out = gpu.eval(&source, "phase", &inputs, 1, &[]).unwrap();
    for (k, &(c, g)) in cases.iter().enumerate() {
        let want = hg(c, g);
        let got = out[k][0] as f64;
        // Relative: the peak at g = G_MAX is about 1.6e7 /sr, and there
        // it moves by 3 / (1 - |g|) of a change of g: the clamp's G_MAX
        // rounded to f32 is 6e-8 off.
        let near_one = 1.0 - g.abs().min(G_MAX);
        let tol = 1e-5 + 6e-8 * 3.0 / near_one;
        assert!(
            (got - want).abs() <= tol * want,
            "hg({c}, {g}): {got} vs {want}"
        );
    }
}

fn fresnel_refraction_and_reflection_match_the_cpu(gpu: &Gpu) {
    let main = "
@group(0) @binding(0) var<storage, read> input: array<vec4<f32>>;
@group(0) @binding(1) var<storage, read_write> output: array<vec4<f32>>;

// Input: (d, n1), (normal, n2): the refracted direction (zero under total
// internal reflection) with the reflectance, and the mirror direction.
@compute @workgroup_size(WORKGROUP)
fn snell(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item(id, groups);
    if 2u * i >= arrayLength(&input) {
        return;
    }
    let a = input[2u * i];
    let b = input[2u * i + 1u];
    output[2u * i] = vec4<f32>(fresnel_refract(a.xyz, b.xyz, a.w, b.w), fresnel_reflectance(dot(a.xyz, b.xyz), a.w, b.w));
    output[2u * i + 1u] = vec4<f32>(fresnel_reflect(a.xyz, b.xyz), 0.0);
}
";
    let source = compose("", &[&DISPATCH, &fresnel::WGSL], main);
    // Every pair of indices (into denser and rarer, and none), incidences
    // up to grazing, a tilted normal of both orientations.
    let f = |v: DVec3| DVec3::new(v.x as f32 as f64, v.y as f32 as f64, v.z as f32 as f64);
    let mut cases = Vec::new();
    for (n1, n2) in [
        (1.0, 1.5),
        (1.5, 1.0),
        (1.0, 2.42),
        (1.33, 1.5),
        (1.7, 1.2),
        (1.5, 1.5),
    ] {
        for k in 0..=80 {
            let th = (f64::from(k) / 80.0) * 89.9f64.to_radians();
            let d = DVec3::new(th.sin(), 0.0, -th.cos());
            let n = DVec3::new(0.3, 0.2, 1.0).normalize();
            let rot = DQuat::from_rotation_arc(DVec3::Z, n);
            cases.push((f(rot * d), f(n), n1 as f32 as f64, n2 as f32 as f64));
            cases.push((f(rot * d), f(-n), n1 as f32 as f64, n2 as f32 as f64));
        }
    }
    let inputs: Vec<[f32; 4]> = cases
        .iter()
        .flat_map(|&(d, n, n1, n2)| {
            [
                [d.x as f32, d.y as f32, d.z as f32, n1 as f32],
                [n.x as f32, n.y as f32, n.z as f32, n2 as f32],
            ]
        })
        .collect();
    let out = gpu.eval(&source, "snell", &inputs, 1, &[]).unwrap();
    let mut tir = 0;
    for (k, &(d, n, n1, n2)) in cases.iter().enumerate() {
        let want = fresnel::interface(d, n, n1, n2);
        let o = out[2 * k];
        let t = DVec3::new(o[0] as f64, o[1] as f64, o[2] as f64);
        // Within f32 rounding of the critical angle, either side.
        let sin_c = n2 / n1;
        let crit = n1 > n2 && (want.cos_i - (1.0 - sin_c * sin_c).sqrt()).abs() < 1e-4;
        if !crit {
            match want.refracted {
                Some(w) => assert!((t - w).length() < 2e-5, "{k}: refracted {t} vs {w}"),
                None => {
                    tir += 1;
                    assert_eq!(t, DVec3::ZERO, "{k}: total internal reflection");
                }
            }
            // As for R in the grid's tests: f32 loses digits near the
            // critical angle as 1 / cos_t.
            let cos_t = want.refracted.map_or(0.0, |r| r.dot(n).abs());
            let tol = 2e-6 + 1e-6 / cos_t.max(1e-3);
            assert!(
                (o[3] as f64 - want.reflectance).abs() < tol,
                "{k}: R {} vs {}",
                o[3],
                want.reflectance
            );
        }
        let m = out[2 * k + 1];
        let m = DVec3::new(m[0] as f64, m[1] as f64, m[2] as f64);
        assert!(
            (m - want.reflected).length() < 1e-6,
            "{k}: reflected {m} vs {}",
            want.reflected
        );
    }
    assert!(tir > 20, "{tir} cases of total internal reflection");
}

fn patch_transmittance_matches_the_cpu(gpu: &Gpu) {
    let main = "
@group(0) @binding(0) var<storage, read> input: array<vec4<f32>>;
@group(0) @binding(1) var<storage, read_write> output: array<vec4<f32>>;

// Input: four corners (cos_i, n1, n2, -); the patch's mean transmittance.
@compute @workgroup_size(WORKGROUP)
fn mean_tau(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item(id, groups);
    if 4u * i >= arrayLength(&input) {
        return;
    }
    var c: array<vec3<f32>, 4>;
    for (var k = 0u; k < 4u; k++) {
        c[k] = input[4u * i + k].xyz;
    }
    output[i] = vec4<f32>(fresnel_patch_transmittance(c));
}
";
    let source = compose("", &[&DISPATCH, &fresnel::WGSL], main);
    // Corners from normal to grazing incidence, into denser and rarer
    // media (kept 1e-3 in cosine clear of the critical angle, where f32
    // loses digits as 1 / cos_t), and indices that vary across the patch.
    let mut cases = Vec::new();
    let mut seed = 0x9e37_79b9_u64;
    let mut next = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    for (n1, n2) in [
        (1.0f64, 1.5f64),
        (1.5, 1.0),
        (1.0, 2.42),
        (1.33, 1.5),
        (1.7, 1.2),
    ] {
        let floor = if n1 > n2 {
            (1.0 - (n2 / n1) * (n2 / n1)).sqrt() + 1e-3
        } else {
            0.0
        };
        for _ in 0..200 {
            let corner = |u: f64, dn: f64| fresnel::Incidence {
                cos_i: (floor + (1.0 - floor) * u) as f32 as f64,
                n1: n1 as f32 as f64,
                n2: (n2 + dn) as f32 as f64,
            };
            let wide = next() < 0.5;
            let base = next();
            cases.push([0; 4].map(|_| {
                let u = if wide {
                    next()
                } else {
                    (base + 0.05 * next()).min(1.0)
                };
                corner(u * u, if n1 > n2 { 0.0 } else { 0.01 * next() })
            }));
        }
    }
    let inputs: Vec<[f32; 4]> = cases
        .iter()
        .flat_map(|c| c.map(|k| [k.cos_i as f32, k.n1 as f32, k.n2 as f32, 0.0]))
        .collect();
    let out = gpu.eval(&source, "mean_tau", &inputs, 1, &[]).unwrap();
    let mut worst = 0.0f64;
    for (k, c) in cases.iter().enumerate() {
        let want = fresnel::patch_transmittance(c);
        let got = out[k][0] as f64;
        worst = worst.max((got - want).abs());
        assert!((got - want).abs() < 2e-5, "{k}: {got} vs {want} ({c:?})");
    }
    println!(
        "patch transmittance: {} patches, worst {worst:.1e}",
        cases.len()
    );
}

fn main() {
    Tests::new()
        .gpu(
            "henyey_greenstein_matches_the_cpu",
            henyey_greenstein_matches_the_cpu,
        )
        .gpu(
            "fresnel_refraction_and_reflection_match_the_cpu",
            fresnel_refraction_and_reflection_match_the_cpu,
        )
        .gpu(
            "patch_transmittance_matches_the_cpu",
            patch_transmittance_matches_the_cpu,
        )
        .run()
}
