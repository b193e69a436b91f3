// The view renderer on the GPU [Ihrke07 secs 3, 5.3]: the same image
// formation as the CPU renderer (`render.rs`), statement for statement, in
// f32. See `render.rs` for the physics; the comments here cite the same
// equations. The physics it shares with the CPU and the light simulator
// comes from the shared modules composed ahead of this source (`mod.rs`:
// grid, ray, fresnel, phase, spot): the trilinear reconstruction in the
// grid's cell-centre convention, the ray equation's steps, Fresnel's
// reflectance, Henyey-Greenstein and the spot cone. Generated ahead of it:
// `ViewParams` (the uniform block `P`), `ViewLight`, `RenderPass`, and the
// constants (MAX_LIGHTS, LIGHT_*, MIRROR_COS, PLANE_EPS, NONE, INF).
//
// A frame is rendered in passes, one per light volume (the device's
// sampled-texture limit leaves room for one bound at a time): the image is
// linear in the light volumes, and every pass marches the same rays, so
// pass 0 adds what needs no light volume (environment, checkerboard,
// emission, directly lit receiver) plus volume 0's in-scatter and
// receiver light, and pass j adds volume j's.

@group(0) @binding(0) var<uniform> P: ViewParams;
@group(0) @binding(1) var<uniform> PASS: RenderPass;
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

fn sides_at(ch: u32, t: Tri) -> vec2<f32> {
    switch ch {
        case 1u: { return tri_sum(sides1, t).xy; }
        case 2u: { return tri_sum(sides2, t).xy; }
        default: { return tri_sum(sides0, t).xy; }
    }
}

fn flux_at(ch: u32, t: Tri) -> vec3<f32> {
    switch ch {
        case 1u: { return tri_sum(flux1, t).xyz; }
        case 2u: { return tri_sum(flux2, t).xyz; }
        default: { return tri_sum(flux0, t).xyz; }
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
    s.fluence = tri_sum(flu, t).xyz;
    let f = flux_at(ch, t);
    s.dir = normalize_or_zero(f);
    var family = (s.fluence.x + s.fluence.y + s.fluence.z) / 3.0;
    if PASS.flux_arrays == 3u {
        family = s.fluence[ch];
    }
    s.mu = 0.0;
    if family > 0.0 {
        s.mu = min(length(f) / family, 1.0);
    }
    return s;
}

// The index channel the current ray marches through.
var<private> channel: u32;
// With sharp interfaces, the region whose own profile the ray equation
// integrates through (NONE: the grid's index field).
var<private> field_region: u32 = NONE;

// The `ray` module's hook: the index field of `channel` at p
// (`VoxelField::sample`): (n, grad n), with grad n = grad(n^2 / 2) / n.
// With sharp interfaces, the profile of region `field_region` instead
// (`sharp_index`, `sharp.wgsl`).
fn index_field(p: vec3<f32>) -> vec4<f32> {
    if field_region != NONE {
        return sharp_index(p);
    }
    let q = grid_trilinear(P.grid, p);
    var v: vec4<f32>;
    switch channel {
        case 1u: { v = tri_lerp(idx1, q); }
        case 2u: { v = tri_lerp(idx2, q); }
        default: { v = tri_lerp(idx0, q); }
    }
    let inv = 1.0 / v.x;
    return vec4<f32>(v.x, v.yzw * inv);
}

// ---- Empty-space skipping (macrocell.rs) ----

// `clear_step`: a straight step that stays in one uniform region, or < 0.
fn clear_step(ch: u32, p: vec3<f32>) -> f32 {
    let u = (p - P.grid.min) * P.grid.inv_spacing;
    if !(u.x >= 0.0 && u.y >= 0.0 && u.z >= 0.0) {
        return -1.0;
    }
    let i = vec3<u32>(u);
    if any(i >= P.grid.dims) {
        return -1.0;
    }
    let f = (i.x * P.grid.dims.y + i.y) * P.grid.dims.z + i.z;
    let word = skip[P.clear_base + ch * P.clear_words + f / 4u];
    let d = (word >> (8u * (f % 4u))) & 255u;
    if d >= 4u {
        return f32(d - 3u) * P.grid.voxel;
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
    let u = (p - P.grid.min) * P.inv_block;
    if !(u.x >= 0.0 && u.y >= 0.0 && u.z >= 0.0) {
        return miss;
    }
    let b = vec3<u32>(u);
    if any(b >= P.block_dims) {
        return miss;
    }
    let base = ch * P.skip_words + ((b.x * P.block_dims.y + b.y) * P.block_dims.z + b.z) * 4u;
    let nb = skip[base];
    if nb == NONE {
        return miss;
    }
    let cell = vec3<f32>(b);
    let du = d * P.inv_block;
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
    let face = P.grid.min[axis] + ahead[axis] / P.inv_block[axis];
    let sigma = vec3<f32>(bitcast<f32>(skip[base + 1u]), bitcast<f32>(skip[base + 2u]), bitcast<f32>(skip[base + 3u]));
    return Crossing(true, bitcast<f32>(nb), sigma, max(t, 0.0), axis, face);
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
    if P.has_receiver == 0u {
        return -1.0;
    }
    let eps = PLANE_EPS * (1.0 + max3(abs(o)));
    let t = plane_hit(o, d, P.receiver_point, P.receiver_normal);
    if t >= 0.0 && t <= max_t + eps {
        return t;
    }
    return -1.0;
}

// The receiver along a march's chord from a to b: (the chord's unit
// direction, the distance from a to the hit), the distance -1 where the
// chord is empty or misses. Both marches test each chord with it.
fn receiver_on_chord(a: vec3<f32>, b: vec3<f32>) -> vec4<f32> {
    let chord = b - a;
    let len = length(chord);
    if len > 0.0 {
        let u = chord / len;
        return vec4<f32>(u, receiver_hit(a, u, len));
    }
    return vec4<f32>(0.0, 0.0, 0.0, -1.0);
}

// Irradiance at x on a surface of unit normal n from light i, with nothing
// in between (background.rs `direct`).
fn direct(i: u32, x: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    let l = P.lights[i];
    if l.kind == LIGHT_DIRECTIONAL {
        return l.power * max(-dot(l.direction, n), 0.0);
    }
    var w = 1.0;
    let r = x - l.position;
    if l.kind == LIGHT_SPOT {
        w = spot_cone_weight(normalize_or_zero(r), l.direction, l.angle, l.falloff);
    }
    let r2 = dot(r, r);
    if r2 == 0.0 {
        return vec3<f32>(0.0);
    }
    let cosr = max(-dot(normalize(r), n), 0.0);
    return l.power * (w * cosr / (4.0 * PI * r2));
}

// Lambertian receiver: albedo / pi * sum_j max(0, -F_j . n) (shared among
// the channels by fluence) inside the grid (light volumes), direct lighting
// outside.
fn receiver_radiance(x: vec3<f32>, d: vec3<f32>, ch: u32) -> vec3<f32> {
    if P.has_receiver == 0u {
        return vec3<f32>(0.0);
    }
    let rn = P.receiver_normal;
    let n = select(-rn, rn, dot(d, rn) < 0.0);
    var e = vec3<f32>(0.0);
    if grid_contains(P.grid, x) && PASS.lit != 0u {
        let s = light_at(ch, grid_trilinear(P.grid, x));
        e += s.fluence * (max(-dot(s.dir, n), 0.0) * s.mu);
    } else if PASS.base != 0u {
        for (var i = 0u; i < P.light_count; i++) {
            e += direct(i, x, n);
        }
    }
    return P.receiver_albedo * e / PI;
}

fn env_texel(i: u32, j: u32) -> vec3<f32> {
    let o = 3u * (j * P.env_width + i);
    return vec3<f32>(envmap[o], envmap[o + 1u], envmap[o + 2u]);
}

// environment.rs `lookup`: lat-long, bilinear, wrapping in longitude and
// clamping in latitude.
fn environment(dir: vec3<f32>) -> vec3<f32> {
    if P.env_kind == 0u {
        return P.env_const;
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
    let w = f32(P.env_width);
    let h = f32(P.env_height);
    let x = u * w - 0.5;
    let y = clamp(v * h - 0.5, 0.0, h - 1.0);
    let x0 = floor(x);
    let y0 = floor(y);
    let fx = x - x0;
    let fy = y - y0;
    let wi = i32(P.env_width);
    let i0 = u32(((i32(x0) % wi) + wi) % wi);
    let i1 = (i0 + 1u) % P.env_width;
    let j0 = u32(y0);
    let j1 = min(j0 + 1u, P.env_height - 1u);
    let top = env_texel(i0, j0) * (1.0 - fx) + env_texel(i1, j0) * fx;
    let bottom = env_texel(i0, j1) * (1.0 - fx) + env_texel(i1, j1) * fx;
    return top * (1.0 - fy) + bottom * fy;
}

// background.rs `Surroundings::radiance`: the receiver, the checkerboard or
// the environment, whichever a ray from o along d meets first.
fn surroundings(o: vec3<f32>, d: vec3<f32>, ch: u32) -> vec3<f32> {
    let base = f32(PASS.base);
    let tr = receiver_hit(o, d, INF);
    var tc = -1.0;
    if P.has_checker != 0u {
        tc = plane_hit(o, d, P.checker_point, P.checker_normal);
    }
    if tr >= 0.0 && (tc < 0.0 || tr <= tc) {
        return receiver_radiance(o + d * tr, d, ch);
    }
    if tc >= 0.0 {
        let q = o + d * tc - P.checker_point;
        let a = i32(floor(dot(q, P.checker_u) / P.checker_square));
        let b = i32(floor(dot(q, P.checker_w) / P.checker_square));
        let parity = ((a + b) % 2 + 2) % 2;
        return base * select(P.checker_color0, P.checker_color1, parity == 1);
    }
    if P.has_checker != 0u {
        return vec3<f32>(0.0);
    }
    return base * environment(d);
}

// ---- The march (render.rs) ----

struct Walk {
    x: vec3<f32>,
    // v = n dx/ds [Ihrke07 eqs 9-10].
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

// render.rs `absorb_and_emit`: the medium's part of [Ihrke07 eq 1] over
// one step of length `stp` along the unit d, the medium taken as (sigma,
// emission, scatter, g) at the grid point t and index n over the step:
// in-scatter from this pass's light volume [Ihrke07 eqs 2, 3, 6], emission
// (`emission`: zero outside pass 0), attenuation [Ihrke07 eq 5].
fn absorb_and_emit(t: Tri, sigma: vec3<f32>, emission: vec3<f32>, scatter: vec3<f32>, g: f32, n: f32, d: vec3<f32>, stp: f32, ch: u32, w: ptr<function, Walk>) {
    var source = emission;
    if max3(scatter) > 0.0 && PASS.lit != 0u {
        if g == 0.0 {
            // Isotropic: HG is 1 / (4 pi) whatever the light's direction,
            // which is not read (render.rs).
            let fluence = tri_sum(flu, t).xyz;
            if max3(fluence) > 0.0 {
                source += scatter * fluence * hg(1.0, 0.0);
            }
        } else {
            let s = light_at(ch, t);
            if max3(s.fluence) > 0.0 {
                // [Ihrke07 eq 6] with the light's first angular moment: HG
                // about the net flux direction, g scaled by the mean cosine.
                source += scatter * s.fluence * hg(dot(s.dir, -d), g * s.mu);
            }
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
}

// [Ihrke07 eq 1] over one step of length `stp` from x along the unit d:
// in-scatter [Ihrke07 eqs 2, 3, 6], emission, attenuation [Ihrke07 eq 5] and
// Fresnel at boundaries.
fn gather(x: vec3<f32>, n: f32, grad: vec3<f32>, d: vec3<f32>, stp: f32, ch: u32, w: ptr<function, Walk>) {
    let t = grid_trilinear(P.grid, x);
    let a = tri_sum(propa, t);
    var emission = vec3<f32>(0.0);
    if PASS.base != 0u && P.emits != 0u {
        emission = tri_sum(emis, t).xyz;
    }
    // Nothing scatters where the medium has no albedo anywhere (the
    // texture then holds zero scatter): its read is skipped.
    var b = vec4<f32>(0.0);
    if P.scatters != 0u && PASS.lit != 0u {
        b = tri_sum(propb, t);
    }
    absorb_and_emit(t, a.xyz, emission, b.xyz, b.w, n, d, stp, ch, w);

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
        let rho = fresnel_reflectance(cos_i, n1, n2);
        if rho > 0.0 {
            let mirror = incident - 2.0 * dot(incident, normal) * normal;
            var l_r = vec3<f32>(0.0);
            if (*w).mirrored && dot((*w).mirror, mirror) > MIRROR_COS {
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

// Radiance arriving at the eye from -d; with dispersion each channel traces
// its own ray through its own index field. One call site for each march in
// a loop over the channels: drivers inline every call, and a march written
// out per channel made the kernel four times the size (minutes more to
// compile on lavapipe).
fn radiance(o: vec3<f32>, d: vec3<f32>) -> vec3<f32> {
    var out = vec3<f32>(0.0);
    for (var ch = 0u; ch < P.channels; ch += 1u) {
        channel = ch;
        var c: vec3<f32>;
        // A ray that misses the grid, or meets the receiver before it,
        // sees what lies there; the others march from where they enter.
        let clip = grid_clip_line(P.grid, o, d);
        let t0 = max(clip.t0, 0.0);
        let tr0 = receiver_hit(o, d, t0);
        if !clip.hit || clip.t1 <= 0.0 {
            c = surroundings(o, d, ch);
        } else if tr0 >= 0.0 {
            c = receiver_radiance(o + d * tr0, d, ch);
        } else if P.sharp != 0u {
            c = march_sharp(o + d * t0, d, ch);
        } else {
            c = march(o + d * t0, d, ch);
        }
        if P.channels == 1u {
            out = c;
        } else {
            out[ch] = c[ch];
        }
    }
    return out;
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

@compute @workgroup_size(TILE, TILE, 1)
fn render(@builtin(global_invocation_id) id: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let w = P.width;
    let h = P.height;
    // No early return: every invocation reaches the barriers below.
    if id.x < w && id.y < h {
        let pix = id.y * w + id.x;
        var sum = vec3<f32>(0.0);
        for (var s = 0u; s < PASS.samples; s++) {
            let r = 3u * (s * w * h + pix);
            let d = vec3<f32>(rays[r], rays[r + 1u], rays[r + 2u]);
            sum += radiance(P.eye, d);
        }
        accum[3u * pix] += sum.x;
        accum[3u * pix + 1u] += sum.y;
        accum[3u * pix + 2u] += sum.z;
    }
    if PASS.base == 0u {
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
