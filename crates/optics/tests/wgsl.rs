//! Function-level parity of the optics crate's WGSL module (the
//! Henyey-Greenstein phase function the GPU renderer is composed with)
//! with the Rust it mirrors, at f32 tolerance. It needs a Vulkan, Metal or
//! DX12 adapter (lavapipe in CI, where a missing adapter fails it; elsewhere it
//! is reported as ignored).

use eikon_gpu::Gpu;
use eikon_gpu::DISPATCH;
use eikon_optics::phase::{self, hg, G_MAX};
use eikon_shader::{compose, VECTOR};
use eikon_testkit::Tests;

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

fn main() {
    Tests::new()
        .gpu(
            "henyey_greenstein_matches_the_cpu",
            henyey_greenstein_matches_the_cpu,
        )
        .run()
}
