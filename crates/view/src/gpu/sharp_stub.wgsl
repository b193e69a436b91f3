// Stand-ins for `sharp.wgsl` in the kernel of scenes without sharp
// interfaces (`P.sharp` is 0 there: never called).

fn sharp_index(p: vec3<f32>) -> vec4<f32> {
    return vec4<f32>(1.0, 0.0, 0.0, 0.0);
}

fn march_sharp(x0: vec3<f32>, d: vec3<f32>, ch: u32) -> vec3<f32> {
    return vec3<f32>(0.0);
}
