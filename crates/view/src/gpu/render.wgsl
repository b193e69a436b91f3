// The view renderer on the GPU (Ihrke et al. 2007, sections 3 and 5.3): the
// same image formation as the CPU renderer (`render.rs`), statement for
// statement, in f32. See `render.rs` for the physics; the comments here
// cite the same equations.
//
// Volumes are 3D textures read with `textureLoad` and a manual trilinear
// reconstruction (cell-centre convention, edge values held in the outer
// half cell). Texture x is the grid's z (the fastest axis of the CPU's
// C-order arrays), texture z the grid's x, so the arrays upload unchanged.
//
// A frame is rendered in passes, one per light volume (the device's
// sampled-texture limit leaves room for one bound at a time): the image is
// linear in the light volumes, and every pass marches the same rays, so
// pass 0 adds what needs no light volume (environment, checkerboard,
// emission, directly lit receiver) plus volume 0's in-scatter and
// receiver light, and pass j adds volume j's.

const INF: f32 = 1e30;
const PI: f32 = 3.14159265358979;
// background.rs: rounding allowance of a plane hit, relative to the scene's
// scale (1e-9 in f64 there; f32 rounding needs more).
const PLANE_EPS: f32 = 2e-6;
const NONE: u32 = 0xffffffffu;
const MAX_LIGHTS: u32 = 16u;

struct Light {
    // Directional: direction of travel; point and spot: position. w: kind
    // (0 directional, 1 point, 2 spot).
    a: vec4<f32>,
    // Spot: unit cone axis, half-angle in degrees.
    b: vec4<f32>,
    // RGB power; w: spot falloff in degrees.
    c: vec4<f32>,
}

struct Params {
    // nx, ny, nz, index channels.
    dims: vec4<u32>,
    // width, height, ray-step budget, light count.
    image: vec4<u32>,
    // rk4, skip empty, anything emits, anything scatters.
    flags: vec4<u32>,
    // environment kind (0 constant, 1 lat-long), map width, height,
    // checkerboard present.
    env: vec4<u32>,
    // receiver present, skip words per channel (cells), clear base word,
    // clear words per channel.
    skip: vec4<u32>,
    // macro-cell grid dims, 0.
    bdims: vec4<u32>,
    // grid min, voxel size h.
    gmin: vec4<f32>,
    // grid max, diagonal.
    gmax: vec4<f32>,
    // 1 / spacing, step length ds (world units).
    inv_spacing: vec4<f32>,
    // 1 / (spacing BLOCK), minimum transmittance.
    inv_block: vec4<f32>,
    // eye position; render.rs MIRROR_COS: mirror directions closer than
    // this share one lookup of the surroundings.
    eye: vec4<f32>,
    // constant environment radiance; phase.rs G_MAX, the largest |g|.
    env_const: vec4<f32>,
    // checkerboard point, square edge.
    chk_point: vec4<f32>,
    chk_normal: vec4<f32>,
    chk_u: vec4<f32>,
    chk_w: vec4<f32>,
    chk_c0: vec4<f32>,
    chk_c1: vec4<f32>,
    rec_point: vec4<f32>,
    rec_normal: vec4<f32>,
    rec_albedo: vec4<f32>,
    lights: array<Light, MAX_LIGHTS>,
}

struct Pass {
    // base pass (light-independent terms), a light volume bound, flux
    // arrays of the volume (1, or 3 with dispersion), samples in the chunk.
    p: vec4<u32>,
}

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<uniform> PASS: Pass;
// Per index channel: [n, grad(n^2/2)] (the grid's layout).
@group(0) @binding(2) var idx0: texture_3d<f32>;
@group(0) @binding(3) var idx1: texture_3d<f32>;
@group(0) @binding(4) var idx2: texture_3d<f32>;
// Properties (properties.rs): [sigma_t rgb, delta], [sigma_s rgb, g],
// [L_e rgb, 0], per channel [n_lo, n_hi].
@group(0) @binding(5) var propa: texture_3d<f32>;
@group(0) @binding(6) var propb: texture_3d<f32>;
@group(0) @binding(7) var emis: texture_3d<f32>;
@group(0) @binding(8) var sides0: texture_3d<f32>;
@group(0) @binding(9) var sides1: texture_3d<f32>;
@group(0) @binding(10) var sides2: texture_3d<f32>;
// This pass's light volume (eikon_wavefront::volume): fluence phi, net
// flux vector F per index channel.
@group(0) @binding(11) var flu: texture_3d<f32>;
@group(0) @binding(12) var flux0: texture_3d<f32>;
@group(0) @binding(13) var flux1: texture_3d<f32>;
@group(0) @binding(14) var flux2: texture_3d<f32>;
// Empty-space skipping (macrocell.rs): per channel the blocks'
// [n, sigma rgb] bits (NONE where not uniform), then per channel the
// voxels' clear distances, four bytes to a word.
@group(0) @binding(15) var<storage, read> skip: array<u32>;
// Lat-long environment, RGB per texel, top row first.
@group(0) @binding(16) var<storage, read> envmap: array<f32>;
// Eye ray directions of the chunk's samples, RGB-style triples per pixel.
@group(0) @binding(17) var<storage, read> rays: array<f32>;
// Sum of the samples' radiance per pixel, RGB.
@group(0) @binding(18) var<storage, read_write> accum: array<f32>;
// The frame's counters (render.rs `Stats`) as 64-bit integers in two
// words, low first: ray-equation steps, then empty-space skips. Counted in
// pass 0 only: every pass marches the same rays.
@group(0) @binding(19) var<storage, read_write> counters: array<atomic<u32>, 4>;

// This invocation's steps and skips, (low, high) words.
var<private> n_steps: vec2<u32>;
var<private> n_skips: vec2<u32>;
// The workgroup's sums, as `counters`.
var<workgroup> wg_counts: array<atomic<u32>, 4>;

// Add one to a two-word count.
fn bump(c: vec2<u32>) -> vec2<u32> {
    let lo = c.x + 1u;
    return vec2<u32>(lo, c.y + select(0u, 1u, lo == 0u));
}

fn max3(v: vec3<f32>) -> f32 {
    return max(v.x, max(v.y, v.z));
}

fn min3(v: vec3<f32>) -> f32 {
    return min(v.x, min(v.y, v.z));
}

fn normalize_or_zero(v: vec3<f32>) -> vec3<f32> {
    let len = length(v);
    if len > 0.0 && len < INF {
        return v / len;
    }
    return vec3<f32>(0.0);
}

fn is_zero(v: vec3<f32>) -> bool {
    return all(v == vec3<f32>(0.0));
}

// ---- Trilinear reconstruction (geometry.rs `trilinear`) ----

struct Tri {
    c: vec3<i32>,
    d: vec3<i32>,
    f: vec3<f32>,
}

fn tri(p: vec3<f32>) -> Tri {
    let n = vec3<i32>(P.dims.xyz);
    let hi = vec3<f32>(n - vec3<i32>(1));
    let u = clamp((p - P.gmin.xyz) * P.inv_spacing.xyz - 0.5, vec3<f32>(0.0), hi);
    let c = min(vec3<i32>(u), max(n - vec3<i32>(2), vec3<i32>(0)));
    let d = select(vec3<i32>(0), vec3<i32>(1), n > vec3<i32>(1));
    return Tri(c, d, u - vec3<f32>(c));
}

// Texel of corner k (bits: x, y, z).
fn corner(t: Tri, k: u32) -> vec3<i32> {
    let o = vec3<i32>(i32(k & 1u), i32((k >> 1u) & 1u), i32((k >> 2u) & 1u));
    let g = t.c + o * t.d;
    return g.zyx;
}

fn weight(t: Tri, k: u32) -> f32 {
    let wx = select(1.0 - t.f.x, t.f.x, (k & 1u) != 0u);
    let wy = select(1.0 - t.f.y, t.f.y, (k & 2u) != 0u);
    let wz = select(1.0 - t.f.z, t.f.z, (k & 4u) != 0u);
    return wx * wy * wz;
}

fn load4(tex: texture_3d<f32>, t: Tri) -> vec4<f32> {
    var s = vec4<f32>(0.0);
    for (var k = 0u; k < 8u; k++) {
        s += textureLoad(tex, corner(t, k), 0) * weight(t, k);
    }
    return s;
}

fn sides_at(ch: u32, t: Tri) -> vec2<f32> {
    switch ch {
        case 1u: { return load4(sides1, t).xy; }
        case 2u: { return load4(sides2, t).xy; }
        default: { return load4(sides0, t).xy; }
    }
}

fn flux_at(ch: u32, t: Tri) -> vec3<f32> {
    switch ch {
        case 1u: { return load4(flux1, t).xyz; }
        case 2u: { return load4(flux2, t).xyz; }
        default: { return load4(flux0, t).xyz; }
    }
}

// The light of this pass's volume at a point (background.rs LightSample):
// RGB fluence, unit net flux direction, mean cosine |F| / phi (phi the
// channel's own with dispersion, else the mean of the three).
struct LightSample {
    fluence: vec3<f32>,
    dir: vec3<f32>,
    mu: f32,
}

fn light_at(ch: u32, t: Tri) -> LightSample {
    var s: LightSample;
    s.fluence = load4(flu, t).xyz;
    let f = flux_at(ch, t);
    s.dir = normalize_or_zero(f);
    var family = (s.fluence.x + s.fluence.y + s.fluence.z) / 3.0;
    if PASS.p.z == 3u {
        family = s.fluence[ch];
    }
    s.mu = 0.0;
    if family > 0.0 {
        s.mu = min(length(f) / family, 1.0);
    }
    return s;
}

fn idx_texel(ch: u32, g: vec3<i32>) -> vec4<f32> {
    switch ch {
        case 1u: { return textureLoad(idx1, g.zyx, 0); }
        case 2u: { return textureLoad(idx2, g.zyx, 0); }
        default: { return textureLoad(idx0, g.zyx, 0); }
    }
}

fn lerp4(a: vec4<f32>, b: vec4<f32>, t: f32) -> vec4<f32> {
    return a + (b - a) * t;
}

// The index field of channel `ch` at p (field.rs `VoxelField::sample`):
// (n, grad n), with grad n = grad(n^2 / 2) / n. Interpolated z, y, x in
// that order as on the CPU, so that equal corners give their value exactly.
fn field(ch: u32, p: vec3<f32>) -> vec4<f32> {
    let t = tri(p);
    let c = t.c;
    let dx = vec3<i32>(t.d.x, 0, 0);
    let dy = vec3<i32>(0, t.d.y, 0);
    let dz = vec3<i32>(0, 0, t.d.z);
    let c00 = lerp4(idx_texel(ch, c), idx_texel(ch, c + dz), t.f.z);
    let c01 = lerp4(idx_texel(ch, c + dy), idx_texel(ch, c + dy + dz), t.f.z);
    let c10 = lerp4(idx_texel(ch, c + dx), idx_texel(ch, c + dx + dz), t.f.z);
    let c11 = lerp4(idx_texel(ch, c + dx + dy), idx_texel(ch, c + dx + dy + dz), t.f.z);
    let v = lerp4(lerp4(c00, c01, t.f.y), lerp4(c10, c11, t.f.y), t.f.x);
    let inv = 1.0 / v.x;
    return vec4<f32>(v.x, v.yzw * inv);
}

// ---- Empty-space skipping (macrocell.rs) ----

// `clear_step`: a straight step that stays in one uniform region, or < 0.
fn clear_step(ch: u32, p: vec3<f32>) -> f32 {
    let u = (p - P.gmin.xyz) * P.inv_spacing.xyz;
    if !(u.x >= 0.0 && u.y >= 0.0 && u.z >= 0.0) {
        return -1.0;
    }
    let i = vec3<u32>(u);
    if any(i >= P.dims.xyz) {
        return -1.0;
    }
    let f = (i.x * P.dims.y + i.y) * P.dims.z + i.z;
    let word = skip[P.skip.z + ch * P.skip.w + f / 4u];
    let d = (word >> (8u * (f % 4u))) & 255u;
    if d >= 4u {
        return f32(d - 3u) * P.gmin.w;
    }
    return -1.0;
}

struct Crossing {
    ok: bool,
    n: f32,
    sigma: vec3<f32>,
    t: f32,
    // The axis of the face the line leaves by, and that face's world
    // coordinate along it.
    axis: u32,
    face: f32,
}

// `crossing`: if p lies in a uniform block, its medium and the distance
// along d to where the line leaves the block.
fn crossing(ch: u32, p: vec3<f32>, d: vec3<f32>) -> Crossing {
    let miss = Crossing(false, 0.0, vec3<f32>(0.0), 0.0, 0u, 0.0);
    let u = (p - P.gmin.xyz) * P.inv_block.xyz;
    if !(u.x >= 0.0 && u.y >= 0.0 && u.z >= 0.0) {
        return miss;
    }
    let b = vec3<u32>(u);
    if any(b >= P.bdims.xyz) {
        return miss;
    }
    let base = ch * P.skip.y + ((b.x * P.bdims.y + b.y) * P.bdims.z + b.z) * 4u;
    let nb = skip[base];
    if nb == NONE {
        return miss;
    }
    let cell = vec3<f32>(b);
    let du = d * P.inv_block.xyz;
    // Per axis: the distance to the face ahead (INF where parallel).
    let ahead = select(cell, cell + 1.0, du > vec3<f32>(0.0));
    let ta = select(vec3<f32>(INF), (ahead - u) / du, du != vec3<f32>(0.0));
    let t = min3(ta);
    var axis = 0u;
    if ta.y < ta[axis] {
        axis = 1u;
    }
    if ta.z < ta[axis] {
        axis = 2u;
    }
    let face = P.gmin[axis] + ahead[axis] / P.inv_block[axis];
    let sigma = vec3<f32>(bitcast<f32>(skip[base + 1u]), bitcast<f32>(skip[base + 2u]), bitcast<f32>(skip[base + 3u]));
    return Crossing(true, bitcast<f32>(nb), sigma, max(t, 0.0), axis, face);
}

// ---- Grid bounds (geometry.rs) ----

// Exit distance `t1` of the slab test along d from o, or < 0 when the line
// misses the bounds; `t0` in .x.
fn clip_line(o: vec3<f32>, d: vec3<f32>) -> vec3<f32> {
    var t0 = -INF;
    var t1 = INF;
    for (var a = 0; a < 3; a++) {
        if d[a] == 0.0 {
            if o[a] < P.gmin[a] || o[a] > P.gmax[a] {
                return vec3<f32>(0.0, 0.0, -1.0);
            }
        } else {
            let inv = 1.0 / d[a];
            var ta = (P.gmin[a] - o[a]) * inv;
            var tb = (P.gmax[a] - o[a]) * inv;
            if ta > tb {
                let s = ta;
                ta = tb;
                tb = s;
            }
            t0 = max(t0, ta);
            t1 = min(t1, tb);
        }
    }
    if t0 <= t1 {
        return vec3<f32>(t0, t1, 1.0);
    }
    return vec3<f32>(0.0, 0.0, -1.0);
}

fn contains(p: vec3<f32>) -> bool {
    return all(p >= P.gmin.xyz) && all(p <= P.gmax.xyz);
}

// ---- Surroundings (background.rs, environment.rs) ----

// Distance along the unit d from o to the plane (p, n) if ahead (or within
// rounding of o, then 0); < 0 if none.
fn plane_hit(o: vec3<f32>, d: vec3<f32>, p: vec3<f32>, n: vec3<f32>) -> f32 {
    let den = dot(d, n);
    if den == 0.0 {
        return -1.0;
    }
    let t = dot(p - o, n) / den;
    let eps = PLANE_EPS * (1.0 + max3(abs(o)) + max3(abs(p)));
    if t > -eps && t < INF {
        return max(t, 0.0);
    }
    return -1.0;
}

fn receiver_hit(o: vec3<f32>, d: vec3<f32>, max_t: f32) -> f32 {
    if P.skip.x == 0u {
        return -1.0;
    }
    let eps = PLANE_EPS * (1.0 + max3(abs(o)));
    let t = plane_hit(o, d, P.rec_point.xyz, P.rec_normal.xyz);
    if t >= 0.0 && t <= max_t + eps {
        return t;
    }
    return -1.0;
}

// `eikon_optics::spot::cone_weight`.
fn cone_weight(dir: vec3<f32>, axis: vec3<f32>, angle: f32, falloff: f32) -> f32 {
    let theta = degrees(acos(clamp(dot(dir, axis), -1.0, 1.0)));
    if theta >= angle {
        return 0.0;
    } else if falloff <= 0.0 || theta <= angle - falloff {
        return 1.0;
    }
    let x = (angle - theta) / falloff;
    return x * x * (3.0 - 2.0 * x);
}

// Irradiance at x on a surface of unit normal n from light i, with nothing
// in between (background.rs `direct`).
fn direct(i: u32, x: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    let l = P.lights[i];
    let kind = u32(l.a.w);
    if kind == 0u {
        return l.c.xyz * max(-dot(l.a.xyz, n), 0.0);
    }
    var w = 1.0;
    let r = x - l.a.xyz;
    if kind == 2u {
        w = cone_weight(normalize_or_zero(r), l.b.xyz, l.b.w, l.c.w);
    }
    let r2 = dot(r, r);
    if r2 == 0.0 {
        return vec3<f32>(0.0);
    }
    let cosr = max(-dot(normalize(r), n), 0.0);
    return l.c.xyz * (w * cosr / (4.0 * PI * r2));
}

// Lambertian receiver: albedo / pi * sum_j max(0, -F_j . n) (shared among
// the channels by fluence) inside the grid (light volumes), direct lighting
// outside.
fn receiver_radiance(x: vec3<f32>, d: vec3<f32>, ch: u32) -> vec3<f32> {
    if P.skip.x == 0u {
        return vec3<f32>(0.0);
    }
    let rn = P.rec_normal.xyz;
    let n = select(-rn, rn, dot(d, rn) < 0.0);
    var e = vec3<f32>(0.0);
    if contains(x) && PASS.p.y != 0u {
        let s = light_at(ch, tri(x));
        e += s.fluence * (max(-dot(s.dir, n), 0.0) * s.mu);
    } else if PASS.p.x != 0u {
        for (var i = 0u; i < P.image.w; i++) {
            e += direct(i, x, n);
        }
    }
    return P.rec_albedo.xyz * e / PI;
}

fn env_texel(i: u32, j: u32) -> vec3<f32> {
    let o = 3u * (j * P.env.y + i);
    return vec3<f32>(envmap[o], envmap[o + 1u], envmap[o + 2u]);
}

// environment.rs `lookup`: lat-long, bilinear, wrapping in longitude and
// clamping in latitude.
fn environment(dir: vec3<f32>) -> vec3<f32> {
    if P.env.x == 0u {
        return P.env_const.xyz;
    }
    let len = length(dir);
    if !(len > 0.0 && len < INF) {
        return vec3<f32>(0.0);
    }
    let d = dir / len;
    var u = 0.5 + atan2(d.x, -d.z) / (2.0 * PI);
    if u >= 1.0 {
        u -= 1.0;
    }
    let v = acos(clamp(d.y, -1.0, 1.0)) / PI;
    let w = f32(P.env.y);
    let h = f32(P.env.z);
    let x = u * w - 0.5;
    let y = clamp(v * h - 0.5, 0.0, h - 1.0);
    let x0 = floor(x);
    let y0 = floor(y);
    let fx = x - x0;
    let fy = y - y0;
    let wi = i32(P.env.y);
    let i0 = u32(((i32(x0) % wi) + wi) % wi);
    let i1 = (i0 + 1u) % P.env.y;
    let j0 = u32(y0);
    let j1 = min(j0 + 1u, P.env.z - 1u);
    let top = env_texel(i0, j0) * (1.0 - fx) + env_texel(i1, j0) * fx;
    let bottom = env_texel(i0, j1) * (1.0 - fx) + env_texel(i1, j1) * fx;
    return top * (1.0 - fy) + bottom * fy;
}

// background.rs `Surroundings::radiance`: the receiver, the checkerboard or
// the environment, whichever a ray from o along d meets first.
fn surroundings(o: vec3<f32>, d: vec3<f32>, ch: u32) -> vec3<f32> {
    let base = f32(PASS.p.x);
    let tr = receiver_hit(o, d, INF);
    var tc = -1.0;
    if P.env.w != 0u {
        tc = plane_hit(o, d, P.chk_point.xyz, P.chk_normal.xyz);
    }
    if tr >= 0.0 && (tc < 0.0 || tr <= tc) {
        return receiver_radiance(o + d * tr, d, ch);
    }
    if tc >= 0.0 {
        let q = o + d * tc - P.chk_point.xyz;
        let a = i32(floor(dot(q, P.chk_u.xyz) / P.chk_point.w));
        let b = i32(floor(dot(q, P.chk_w.xyz) / P.chk_point.w));
        let parity = ((a + b) % 2 + 2) % 2;
        return base * select(P.chk_c0.xyz, P.chk_c1.xyz, parity == 1);
    }
    if P.env.w != 0u {
        return vec3<f32>(0.0);
    }
    return base * environment(d);
}

// ---- Phase function and Fresnel (phase.rs, fresnel.rs) ----

// Henyey-Greenstein (eqs 3, 6), cos between the light's direction of travel
// and the direction towards the eye.
fn hg(cos_theta: f32, g_in: f32) -> f32 {
    let c = clamp(cos_theta, -1.0, 1.0);
    let g = clamp(g_in, -P.env_const.w, P.env_const.w);
    let g2 = g * g;
    let denom = 1.0 + g2 - 2.0 * g * c;
    return (1.0 - g2) / (4.0 * PI * denom * sqrt(denom));
}

// Unpolarized Fresnel reflectance rho (eqs 2, 5) from n1 into n2.
fn reflectance(cos_in: f32, n1: f32, n2: f32) -> f32 {
    if n1 == n2 {
        return 0.0;
    }
    let cos_i = min(abs(cos_in), 1.0);
    let sin_i2 = max(1.0 - cos_i * cos_i, 0.0);
    let eta = n1 / n2;
    let sin_t2 = eta * eta * sin_i2;
    if sin_t2 >= 1.0 {
        return 1.0;
    }
    let cos_t = sqrt(1.0 - sin_t2);
    let rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t);
    let rp = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t);
    return 0.5 * (rs * rs + rp * rp);
}

// ---- The march (render.rs) ----

struct Walk {
    x: vec3<f32>,
    // v = n dx/ds (eqs 9-10).
    v: vec3<f32>,
    radiance: vec3<f32>,
    alpha: vec3<f32>,
    steps: u32,
    mirrored: bool,
    mirror: vec3<f32>,
    mirror_l: vec3<f32>,
    has_incident: bool,
    incident: vec3<f32>,
    // Index at the eye (render.rs `eye_index`).
    n_eye: f32,
}

// Eq 1 over one step of length `stp` from x along the unit d: in-scatter
// (eqs 2, 3, 6), emission, attenuation (eq 5) and Fresnel at boundaries.
fn gather(x: vec3<f32>, n: f32, grad: vec3<f32>, d: vec3<f32>, stp: f32, ch: u32, w: ptr<function, Walk>) {
    let t = tri(x);
    let a = load4(propa, t);
    let sigma = a.xyz;
    var source = vec3<f32>(0.0);
    if PASS.p.x != 0u && P.flags.z != 0u {
        source = load4(emis, t).xyz;
    }
    // Nothing scatters where the medium has no albedo anywhere (the
    // texture then holds zero scatter): its read is skipped.
    var b = vec4<f32>(0.0);
    if P.flags.w != 0u && PASS.p.y != 0u {
        b = load4(propb, t);
    }
    let scatter = b.xyz;
    if max3(scatter) > 0.0 && PASS.p.y != 0u {
        let s = light_at(ch, t);
        if max3(s.fluence) > 0.0 {
            // Eq 6 with the light's first angular moment: HG about the net
            // flux direction, g scaled by the mean cosine.
            source += scatter * s.fluence * hg(dot(s.dir, -d), b.w * s.mu);
        }
    }
    // The radiance law (render.rs): radiance arising where the index is n
    // reaches the eye scaled by (n_eye / n)^2.
    let k = (*w).n_eye / n;
    source *= k * k;
    // Exact for constant sigma and S over the step:
    // int_0^ds exp(-sigma s) ds = (1 - exp(-sigma ds)) / sigma.
    if max3(sigma) > 0.0 {
        let att = exp(-sigma * stp);
        if !is_zero(source) {
            let wt = select(vec3<f32>(stp), (1.0 - att) / sigma, sigma > vec3<f32>(1e-12));
            (*w).radiance += (*w).alpha * source * wt;
        }
        (*w).alpha *= att;
    } else if !is_zero(source) {
        (*w).radiance += (*w).alpha * source * stp;
    }

    let delta = a.w;
    if delta <= 0.0 {
        (*w).mirrored = false;
        (*w).has_incident = false;
        return;
    }
    let len = length(grad);
    if len == 0.0 {
        return;
    }
    let normal = grad / len;
    let cosv = dot(d, normal);
    let part = min(delta * stp * abs(cosv), 1.0);
    let sides = sides_at(ch, t);
    // Fresnel at the angle the ray met the interface at: its direction
    // where it entered the band, kept until it leaves the band.
    if !(*w).has_incident {
        (*w).has_incident = true;
        (*w).incident = d;
    }
    let incident = (*w).incident;
    let cos_in = dot(incident, normal);
    let tangent = incident - normal * cos_in;
    let sin_i = min(length(tangent), 1.0);
    let cos_i = abs(cos_in);
    var n1 = sides.y;
    var n2 = sides.x;
    if cos_in > 0.0 {
        n1 = sides.x;
        n2 = sides.y;
    }
    if n1 / n2 * sin_i < 1.0 {
        let rho = reflectance(cos_i, n1, n2);
        if rho > 0.0 {
            let mirror = incident - 2.0 * dot(incident, normal) * normal;
            var l_r = vec3<f32>(0.0);
            if (*w).mirrored && dot((*w).mirror, mirror) > P.eye.w {
                l_r = (*w).mirror_l;
            } else {
                l_r = surroundings(x, mirror, ch);
                (*w).mirrored = true;
                (*w).mirror = mirror;
                (*w).mirror_l = l_r;
            }
            (*w).radiance += (*w).alpha * l_r * (part * rho);
            (*w).alpha *= pow(1.0 - rho, part);
        }
    }
}

// One classical RK4 step of the equal-distance ray equation (eqs 9-10).
fn rk4(ch: u32, w: ptr<function, Walk>, h: f32) {
    let x = (*w).x;
    let v = (*w).v;
    let f0 = field(ch, x);
    let kx0 = v * (1.0 / f0.x);
    let kv0 = f0.yzw;
    let x1 = x + kx0 * (0.5 * h);
    let v1 = v + kv0 * (0.5 * h);
    let f1 = field(ch, x1);
    let kx1 = v1 * (1.0 / f1.x);
    let kv1 = f1.yzw;
    let x2 = x + kx1 * (0.5 * h);
    let v2 = v + kv1 * (0.5 * h);
    let f2 = field(ch, x2);
    let kx2 = v2 * (1.0 / f2.x);
    let kv2 = f2.yzw;
    let x3 = x + kx2 * h;
    let v3 = v + kv2 * h;
    let f3 = field(ch, x3);
    let kx3 = v3 * (1.0 / f3.x);
    let kv3 = f3.yzw;
    let s = h / 6.0;
    (*w).x = x + (kx0 + (kx1 + kx2) * 2.0 + kx3) * s;
    (*w).v = v + (kv0 + (kv1 + kv2) * 2.0 + kv3) * s;
}

// March one eye ray through index channel ch; the RGB radiance it gathers.
fn march(o: vec3<f32>, d: vec3<f32>, ch: u32) -> vec3<f32> {
    let clip = clip_line(o, d);
    if clip.z < 0.0 || clip.y <= 0.0 {
        return surroundings(o, d, ch);
    }
    let t0 = max(clip.x, 0.0);
    let tr0 = receiver_hit(o, d, t0);
    if tr0 >= 0.0 {
        return receiver_radiance(o + d * tr0, d, ch);
    }
    let h = P.gmin.w;
    let ds = P.inv_spacing.w;
    let x0 = o + d * t0;
    var w: Walk;
    w.x = x0;
    w.v = d * field(ch, x0).x;
    w.radiance = vec3<f32>(0.0);
    w.alpha = vec3<f32>(1.0);
    w.steps = 0u;
    w.mirrored = false;
    w.has_incident = false;
    w.n_eye = field(ch, P.eye.xyz).x;
    let budget = P.image.z;
    let skip_empty = P.flags.y != 0u;
    while w.steps < budget {
        let dir = normalize_or_zero(w.v);
        // Distance to the bounds: the slab test only within two steps.
        let clearance = min3(min(w.x - P.gmin.xyz, P.gmax.xyz - w.x));
        var exit = INF;
        if !(clearance > 2.0 * ds) {
            let c = clip_line(w.x, dir);
            exit = select(0.0, max(c.y, 0.0), c.z >= 0.0);
        }
        if exit <= 0.0 || is_zero(dir) {
            break;
        }
        if max3(w.alpha) < P.inv_block.w {
            return w.radiance;
        }
        // A straight step across clear space or a uniform block, or
        // else one step of the ray equation.
        var moved = false;
        if skip_empty {
            // A skip may be longer than two steps: it must still end at the
            // bounds (render.rs `skip_exit`).
            if exit == INF {
                let c = clip_line(w.x, dir);
                exit = select(0.0, max(c.y, 0.0), c.z >= 0.0);
            }
            let s = clear_step(ch, w.x);
            if s >= 0.0 {
                // Clear of anything that bends, scatters, emits or reflects
                // for s: one straight step in the local constant medium.
                let t = min(s, exit);
                let n = field(ch, w.x).x;
                let sigma = load4(propa, tri(w.x)).xyz;
                let tr = receiver_hit(w.x, dir, t);
                if tr >= 0.0 {
                    w.alpha *= exp(-sigma * tr);
                    w.radiance += w.alpha * receiver_radiance(w.x + dir * tr, dir, ch);
                    return w.radiance;
                }
                w.alpha *= exp(-sigma * t);
                w.x += dir * t;
                w.v = dir * n;
                w.mirrored = false;
                w.has_incident = false;
                n_skips = bump(n_skips);
                moved = true;
            }
            if !moved {
                let c = crossing(ch, w.x, dir);
                if c.ok {
                    // Just past the block's face, so that the next lookup
                    // lands in the next block: 1e-6 voxels on the CPU, at
                    // least 8 ulps of the position in f32 (less would not
                    // move the ray off the face).
                    let t = min(c.t + max(1e-6 * h, 1e-6 * max3(abs(w.x))), exit);
                    let tr = receiver_hit(w.x, dir, t);
                    if tr >= 0.0 {
                        w.alpha *= exp(-c.sigma * tr);
                        w.radiance += w.alpha * receiver_radiance(w.x + dir * tr, dir, ch);
                        return w.radiance;
                    }
                    w.alpha *= exp(-c.sigma * t);
                    w.x += dir * t;
                    if t < exit {
                        // Past the face for certain: x + d t rounds to
                        // either side of it in f32, and a ray left on the
                        // face would cross this block again, with a step of
                        // nothing. A few ulps of the scene's scale along
                        // the face's axis, never backwards.
                        let a = c.axis;
                        let eps = 2e-6 * (h + max(max3(abs(P.gmin.xyz)), max3(abs(P.gmax.xyz))));
                        if dir[a] > 0.0 {
                            w.x[a] = max(w.x[a], c.face + eps);
                        } else {
                            w.x[a] = min(w.x[a], c.face - eps);
                        }
                    }
                    w.v = dir * c.n;
                    w.mirrored = false;
                    w.has_incident = false;
                    n_skips = bump(n_skips);
                    moved = true;
                }
            }
        }
        if !moved {
            let stp = min(ds, max(exit, 1e-6 * h));
            let xs = w.x;
            let f = field(ch, xs);
            gather(xs, f.x, f.yzw, dir, stp, ch, &w);
            if P.flags.x != 0u {
                rk4(ch, &w, stp);
            } else {
                // Eqs 11-12 with the sample already taken.
                w.x += w.v * (stp / f.x);
                w.v += f.yzw * stp;
            }
            w.steps += 1u;
            n_steps = bump(n_steps);
            let chord = w.x - xs;
            let len = length(chord);
            if len > 0.0 {
                let u = chord / len;
                let tr = receiver_hit(xs, u, len);
                if tr >= 0.0 {
                    w.radiance += w.alpha * receiver_radiance(xs + u * tr, u, ch);
                    return w.radiance;
                }
            }
        }
    }
    if w.steps >= budget {
        return w.radiance;
    }
    let dir = normalize_or_zero(w.v);
    w.radiance += w.alpha * surroundings(w.x, dir, ch);
    return w.radiance;
}

// Radiance arriving at the eye from -d; with dispersion each channel traces
// its own ray through its own index field.
fn radiance(o: vec3<f32>, d: vec3<f32>) -> vec3<f32> {
    if P.dims.w == 1u {
        return march(o, d, 0u);
    }
    return vec3<f32>(march(o, d, 0u).x, march(o, d, 1u).y, march(o, d, 2u).z);
}

// Add the two-word count c to counters k, k + 1 of `wg_counts` (global:
// false) or `counters` (true), carrying out of the low word.
fn add_count(global: bool, k: u32, c: vec2<u32>) {
    if global {
        let old = atomicAdd(&counters[k], c.x);
        atomicAdd(&counters[k + 1u], c.y + select(0u, 1u, old + c.x < old));
    } else {
        let old = atomicAdd(&wg_counts[k], c.x);
        atomicAdd(&wg_counts[k + 1u], c.y + select(0u, 1u, old + c.x < old));
    }
}

@compute @workgroup_size(8, 8, 1)
fn render(@builtin(global_invocation_id) id: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let w = P.image.x;
    let h = P.image.y;
    // No early return: every invocation reaches the barriers below.
    if id.x < w && id.y < h {
        let pix = id.y * w + id.x;
        var sum = vec3<f32>(0.0);
        for (var s = 0u; s < PASS.p.w; s++) {
            let r = 3u * (s * w * h + pix);
            let d = vec3<f32>(rays[r], rays[r + 1u], rays[r + 2u]);
            sum += radiance(P.eye.xyz, d);
        }
        accum[3u * pix] += sum.x;
        accum[3u * pix + 1u] += sum.y;
        accum[3u * pix + 2u] += sum.z;
    }
    if PASS.p.x == 0u {
        return;
    }
    // The counts: summed in the workgroup, then one global add per group.
    if li < 4u {
        atomicStore(&wg_counts[li], 0u);
    }
    workgroupBarrier();
    add_count(false, 0u, n_steps);
    add_count(false, 2u, n_skips);
    workgroupBarrier();
    if li == 0u {
        add_count(true, 0u, vec2<u32>(atomicLoad(&wg_counts[0]), atomicLoad(&wg_counts[1])));
        add_count(true, 2u, vec2<u32>(atomicLoad(&wg_counts[2]), atomicLoad(&wg_counts[3])));
    }
}
