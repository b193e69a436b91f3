// Caustic map (Wyman, "Interactive Refractions and Caustics Using
// Image-Space Techniques", ShaderX5, 2006, "Rendering the Caustic Map"):
// each photon of the light's refraction passes (one per photon-buffer
// texel, its exit ray) is followed to the receiver plane and drawn as a
// small quad of `splat` x `splat` caustic-map texels around where it lands,
// seen from the light; each texel adds the photon's power times Gaussian
// weights that sum to R = (caustic texels per unit of the light's image
// plane) / (photons per unit of it), the paper's `pixelsInCausticMap /
// totalPhotons` when both maps cover the same view.
//
// The sums are 64-bit fixed-point integers added with atomics (two u32
// words with a carry, as the light simulation's deposits): exact and the
// same whatever order the fragments run in. (Additive blending needs a
// blendable format: without optional features wgpu blends 16-bit floats
// only, whose 11-bit sums drop a photon's tail weights once a caustic
// texel holds a few hundred photons.)

@group(0) @binding(0) var<uniform> sp: SplatUniform;
@group(0) @binding(1) var exit_position: texture_2d<f32>;
@group(0) @binding(2) var exit_direction: texture_2d<f32>;
@group(0) @binding(3) var front_position: texture_2d<f32>;
// Per caustic texel, three channels of (lo, hi) words.
@group(0) @binding(4) var<storage, read_write> sums: array<atomic<u32>>;

struct Quad {
    @builtin(position) clip: vec4<f32>,
    // Where the photon lands, in caustic texels.
    @location(0) @interpolate(flat) centre: vec2<f32>,
    // Its power over the sum of its Gaussian weights, RGB.
    @location(1) @interpolate(flat) power: vec3<f32>,
    // The cosine of its ray to the light's axis, cubed (a pinhole's texels
    // subtend solid angles in proportion to it).
    @location(2) @interpolate(flat) cos3: f32,
};

fn gauss(x: f32) -> f32 {
    let s = sp.sigma;
    return exp(-0.5 * x * x / (s * s));
}

// The sum of the Gaussian weights of the `splat` texel centres from
// k0 - half to k0 + half, for a photon at c.
fn weights(c: f32, k0: f32, half: f32) -> f32 {
    var sum = 0.0;
    for (var m = -half; m <= half; m += 1.0) {
        sum += gauss(k0 + m + 0.5 - c);
    }
    return sum;
}

fn cos3(ndc: vec2<f32>, half: f32) -> f32 {
    if (sp.pinhole == 0u) {
        return 1.0;
    }
    let t = ndc * half;
    let c = inverseSqrt(1.0 + dot(t, t));
    return c * c * c;
}

@vertex
fn splat_vs(@builtin(vertex_index) v: u32, @builtin(instance_index) k: u32) -> Quad {
    var out: Quad;
    // Off screen unless the photon lands.
    out.clip = vec4<f32>(4.0, 4.0, 0.5, 1.0);
    out.centre = vec2<f32>(0.0);
    out.power = vec3<f32>(0.0);
    out.cos3 = 1.0;
    let np = u32(sp.photon_side);
    let ij = vec2<i32>(i32(k % np), i32(k / np));
    let e0 = textureLoad(exit_position, ij, 0);
    let e1 = textureLoad(exit_direction, ij, 0);
    let status = u32(e0.w);
    if ((status & 1u) == 0u || e1.w <= 0.0) {
        return out;
    }
    let den = dot(e1.xyz, sp.receiver_normal);
    if (den == 0.0) {
        return out;
    }
    let t = dot(sp.receiver_point - e0.xyz, sp.receiver_normal) / den;
    if (!(t > 0.0)) {
        return out;
    }
    let p3 = e0.xyz + t * e1.xyz;
    let c = sp.view_proj * vec4<f32>(p3, 1.0);
    if (c.w <= 0.0) {
        return out;
    }
    let nc = sp.caustic_side;
    let centre = vec2<f32>((c.x / c.w + 1.0) * 0.5 * nc, (1.0 - c.y / c.w) * 0.5 * nc);
    let half = floor(0.5 * sp.splat_side);
    let k0 = floor(centre);
    if (!(k0.x + half >= 0.0 && k0.y + half >= 0.0 && k0.x - half < nc && k0.y - half < nc)) {
        return out;
    }
    // Beer-Lambert over the estimated inside path |p2 - p1|.
    let p1 = textureLoad(front_position, ij, 0).xyz;
    let attenuation = exp(-sp.extinction * length(e0.xyz - p1));
    let norm = weights(centre.x, k0.x, half) * weights(centre.y, k0.y, half);
    // The photon's own ray to the light's axis.
    let npf = sp.photon_side;
    let ndc_p = vec2<f32>(2.0 * (f32(ij.x) + 0.5) / npf - 1.0, 1.0 - 2.0 * (f32(ij.y) + 0.5) / npf);
    out.cos3 = cos3(ndc_p, sp.photon_half);
    out.power = e1.w * attenuation * sp.texels_per_photon / norm;
    out.centre = centre;
    let corner = vec2<f32>(f32(v == 1u || v == 4u || v == 5u), f32(v == 2u || v == 3u || v == 5u));
    let texel = k0 - vec2<f32>(half) + corner * (2.0 * half + 1.0);
    out.clip = vec4<f32>(2.0 * texel.x / nc - 1.0, 1.0 - 2.0 * texel.y / nc, 0.5, 1.0);
    return out;
}

fn add64(w: u32, x: f32) {
    let y = floor(min(x, 1.8e19) + 0.5);
    if (!(y >= 1.0)) {
        return;
    }
    let hi = floor(y / 4294967296.0);
    let lo = u32(y - hi * 4294967296.0);
    let old = atomicAdd(&sums[w], lo);
    let h = u32(hi) + select(0u, 1u, old + lo < old);
    if (h != 0u) {
        atomicAdd(&sums[w + 1u], h);
    }
}

@fragment
fn splat_fs(q: Quad) -> @location(0) vec4<f32> {
    let d = q.clip.xy - q.centre;
    let nc = sp.caustic_side;
    let ndc = vec2<f32>(2.0 * q.clip.x / nc - 1.0, 1.0 - 2.0 * q.clip.y / nc);
    // Power per unit solid angle of this texel (a pinhole): the photon's
    // solid angle over the texel's, R cos^3(photon) / cos^3(texel).
    let value = q.power * gauss(d.x) * gauss(d.y) * (q.cos3 / cos3(ndc, sp.caustic_half)) * sp.scale;
    let texel = u32(q.clip.y) * u32(nc) + u32(q.clip.x);
    add64(6u * texel, value.x);
    add64(6u * texel + 2u, value.y);
    add64(6u * texel + 4u, value.z);
    return vec4<f32>(0.0);
}
