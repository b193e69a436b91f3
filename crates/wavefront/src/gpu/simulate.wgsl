// The wavefront light simulator on the GPU (Ihrke et al. 2007, 5.2): the
// same four steps, definitions and units as the CPU modules `propagate`,
// `refine` and `voxelize` (see their docs), in f32. One thread per patch
// (or per output slot of the HistoPyramid walk).
//
// Patch list, structure of arrays (`src` is the live list, `dst` the one
// the walk writes):
//   pos[4 i]     = (corner 0 position, its optical path travelled)
//   pos[4 i + c] = (corner c position relative to corner 0, its optical
//                   path), c = 1, 2, 3: the patch's shape in f32 does not
//                   wear away with the rounding of its absolute position
//                   (a plane wave's patches stay exactly square)
//   vel[4 i + c] = (corner c eikonal gradient v, |v| = n; 0)
//   aux[3 i + 0] = (RGB flux, W; area0)
//   aux[3 i + 1] = (RGB flux0; tessellation depth)
//   aux[3 i + 2] = (RGB differential irradiance, W/m^2; 0)
// The medium: index channel (n, grad(n^2 / 2)) and RGB extinction as 3D
// textures of texel (k, j, i) for cell (i, j, k) (z fastest, like the CPU
// arrays), read with textureLoad and interpolated by hand exactly as
// `VoxelField::sample` and `GridGeometry::trilinear` do.

struct Params {
    grid_min: vec3<f32>,
    n: u32,            // live patches (the list the kernels work on)
    spacing: vec3<f32>,
    n_old: u32,        // patches of the list the walk reads (its pyramid)
    inv_spacing: vec3<f32>,
    method: u32,       // 0 Euler, 1 RK4
    dims: vec3<u32>,
    group: i32,        // colour channel of a dispersive wavefront, or -1
    grid_max: vec3<f32>,
    dt: f32,
    hi: vec3<f32>,     // dims - 1
    max_depth: u32,
    max_cell: vec3<u32>, // dims - 2 (saturating)
    max_patches: u32,
    inv_block: vec3<f32>,
    threshold: f32,
    empty_dims: vec3<u32>,
    split_span: f32,
    scale: f32,        // fixed-point scale of the energy tallies
    stamp: u32,        // deposit phase id (midpoints; corners use stamp + 1)
    pad0: u32,
    pad1: u32,
}

struct Level {
    l: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var index_tex: texture_3d<f32>;
@group(0) @binding(2) var ext_tex: texture_3d<f32>;
@group(0) @binding(3) var<storage, read> empty: array<f32>;
@group(0) @binding(4) var<storage, read_write> stats: array<atomic<u32>>;
@group(0) @binding(5) var<storage, read_write> levels: array<u32>;
@group(0) @binding(6) var<storage, read_write> splits: array<u32>;
@group(0) @binding(7) var<storage, read_write> fate: array<u32>;
// This step's deposits of each patch, (cell or NONE, packed key): slot 0
// its midpoint's, slots 1..4 its corners'. The passes after the first
// read them instead of recomputing; the winner recomputes its value.
@group(0) @binding(8) var<storage, read_write> deps: array<vec2<u32>>;

@group(1) @binding(0) var<storage, read_write> pos: array<vec4<f32>>;
@group(1) @binding(1) var<storage, read_write> vel: array<vec4<f32>>;
@group(1) @binding(2) var<storage, read_write> aux: array<vec4<f32>>;
@group(1) @binding(3) var<storage, read_write> dpos: array<vec4<f32>>;
@group(1) @binding(4) var<storage, read_write> dvel: array<vec4<f32>>;
@group(1) @binding(5) var<storage, read_write> daux: array<vec4<f32>>;

@group(2) @binding(0) var<storage, read_write> key: array<atomic<u32>>;
@group(2) @binding(1) var<storage, read_write> stamp: array<atomic<u32>>;
@group(2) @binding(2) var<storage, read_write> owner: array<atomic<u32>>;
@group(2) @binding(3) var<storage, read_write> irr0: array<f32>;
@group(2) @binding(4) var<storage, read_write> irr1: array<f32>;
@group(2) @binding(5) var<storage, read_write> irr2: array<f32>;
@group(2) @binding(6) var<storage, read_write> dir0: array<f32>;
@group(2) @binding(7) var<storage, read_write> dir1: array<f32>;
@group(2) @binding(8) var<storage, read_write> dir2: array<f32>;

@group(3) @binding(0) var<uniform> L: Level;

// Stats words: energy tallies (category * 3 + channel) as 64-bit fixed
// point (lo, hi) in words 0..18; then counts.
const E_ABSORBED: u32 = 0u;
const E_EXITED: u32 = 1u;
const E_CULLED: u32 = 2u;
const S_EXITED: u32 = 18u;
const S_ABSORBED: u32 = 19u;
const S_CAUSTIC: u32 = 20u;
const S_HELD: u32 = 21u;
const S_KEPT: u32 = 22u;
const S_SPLITS: u32 = 23u;

// Fates (refine.rs `Fate`).
const F_EXIT: u32 = 0u;
const F_ABSORBED: u32 = 1u;
const F_CAUSTIC: u32 = 2u;
const F_RETAIN: u32 = 3u;
const F_SPLIT: u32 = 4u;

const NONE: u32 = 0xffffffffu;

fn item(id: vec3<u32>, groups: vec3<u32>) -> u32 {
    return id.x + id.y * groups.x * 64u;
}

// ---------------------------------------------------------------------
// Deterministic energy tallies: 64-bit fixed point (value * P.scale) in
// two u32 words with carry. Integer addition is associative, so the sums
// do not depend on the order the threads run in. Each workgroup sums its
// threads' tallies in workgroup memory first (`wg_stats`, the layout of
// `stats`) and adds them to `stats` once (`wg_begin`, `wg_end`): one
// global atomic per workgroup instead of one per patch.
var<workgroup> wg_stats: array<atomic<u32>, 24>;

fn add_fixed(w: u32, lo_u: u32, hi_u: u32, global: bool) {
    var old = 0u;
    if (global) {
        old = atomicAdd(&stats[w], lo_u);
    } else {
        old = atomicAdd(&wg_stats[w], lo_u);
    }
    var carry = 0u;
    if (old + lo_u < old) {
        carry = 1u;
    }
    if (hi_u + carry > 0u) {
        if (global) {
            atomicAdd(&stats[w + 1u], hi_u + carry);
        } else {
            atomicAdd(&wg_stats[w + 1u], hi_u + carry);
        }
    }
}

fn wg_begin(li: u32) {
    if (li < 24u) {
        atomicStore(&wg_stats[li], 0u);
    }
    workgroupBarrier();
}

fn wg_end(li: u32) {
    workgroupBarrier();
    if (li < 9u) {
        let lo = atomicLoad(&wg_stats[2u * li]);
        let hi = atomicLoad(&wg_stats[2u * li + 1u]);
        if (lo != 0u || hi != 0u) {
            add_fixed(2u * li, lo, hi, true);
        }
    } else if (li >= 18u && li < 24u) {
        let c = atomicLoad(&wg_stats[li]);
        if (c != 0u) {
            atomicAdd(&stats[li], c);
        }
    }
}

fn add_energy(category: u32, channel: u32, value: f32) {
    let x = value * P.scale;
    if (!(x >= 1.0)) {
        return; // zero, below one unit, negative or NaN
    }
    let hi = floor(x / 4294967296.0);
    let lo = x - hi * 4294967296.0;
    add_fixed(2u * (3u * category + channel), u32(lo), u32(hi), false);
}

fn add_energy3(category: u32, v: vec3<f32>) {
    add_energy(category, 0u, v.x);
    add_energy(category, 1u, v.y);
    add_energy(category, 2u, v.z);
}

// ---------------------------------------------------------------------
// Grid geometry (geometry.rs).

fn contains(p: vec3<f32>) -> bool {
    return all(p >= P.grid_min) && all(p <= P.grid_max);
}

struct Clip {
    hit: bool,
    t0: f32,
    t1: f32,
}

// Slab test: the interval of `o + t d` inside the bounds
// (`GridGeometry::clip_line`).
fn clip_line(o: vec3<f32>, d: vec3<f32>) -> Clip {
    var t0 = -3.0e38;
    var t1 = 3.0e38;
    for (var a = 0; a < 3; a++) {
        if (d[a] == 0.0) {
            if (o[a] < P.grid_min[a] || o[a] > P.grid_max[a]) {
                return Clip(false, 0.0, 0.0);
            }
        } else {
            let inv = 1.0 / d[a];
            var ta = (P.grid_min[a] - o[a]) * inv;
            var tb = (P.grid_max[a] - o[a]) * inv;
            if (ta > tb) {
                let s = ta;
                ta = tb;
                tb = s;
            }
            t0 = max(t0, ta);
            t1 = min(t1, tb);
        }
    }
    return Clip(t0 <= t1, t0, t1);
}

struct Cell {
    ok: bool,
    flat: u32,
}

// The cell containing `p` (`GridGeometry::cell_of`, flat C-order index).
fn cell_of(p: vec3<f32>) -> Cell {
    let u = (p - P.grid_min) / P.spacing;
    if (!all(u >= vec3<f32>(0.0))) {
        return Cell(false, 0u);
    }
    let c = vec3<u32>(u);
    if (any(c >= P.dims)) {
        return Cell(false, 0u);
    }
    return Cell(true, (c.x * P.dims.y + c.y) * P.dims.z + c.z);
}

fn voxel_center(flat: u32) -> vec3<f32> {
    let k = flat % P.dims.z;
    let j = (flat / P.dims.z) % P.dims.y;
    let i = flat / (P.dims.y * P.dims.z);
    return P.grid_min + (vec3<f32>(f32(i), f32(j), f32(k)) + 0.5) * P.spacing;
}

// ---------------------------------------------------------------------
// Trilinear sampling, cell-centre convention, edge value held in the outer
// half cell (`VoxelField::sample`).

struct Corner8 {
    base: vec3<i32>,
    o: vec3<i32>,
    f: vec3<f32>,
}

fn corner8(p: vec3<f32>) -> Corner8 {
    let u = clamp((p - P.grid_min) * P.inv_spacing - 0.5, vec3<f32>(0.0), P.hi);
    let c = min(vec3<u32>(u), P.max_cell);
    let f = u - vec3<f32>(c);
    let o = select(vec3<i32>(0), vec3<i32>(1), P.dims > vec3<u32>(1u));
    return Corner8(vec3<i32>(c), o, f);
}

fn texel(t: texture_3d<f32>, i: i32, j: i32, k: i32) -> vec4<f32> {
    return textureLoad(t, vec3<i32>(k, j, i), 0);
}

// a + (b - a) t, as the CPU: equal corners give their value exactly.
fn lerp4(a: vec4<f32>, b: vec4<f32>, t: f32) -> vec4<f32> {
    return a + (b - a) * t;
}

fn trilinear_index(p: vec3<f32>) -> vec4<f32> {
    let q = corner8(p);
    let b = q.base;
    let o = q.o;
    let c00 = lerp4(texel(index_tex, b.x, b.y, b.z), texel(index_tex, b.x, b.y, b.z + o.z), q.f.z);
    let c01 = lerp4(texel(index_tex, b.x, b.y + o.y, b.z), texel(index_tex, b.x, b.y + o.y, b.z + o.z), q.f.z);
    let c10 = lerp4(texel(index_tex, b.x + o.x, b.y, b.z), texel(index_tex, b.x + o.x, b.y, b.z + o.z), q.f.z);
    let c11 = lerp4(texel(index_tex, b.x + o.x, b.y + o.y, b.z), texel(index_tex, b.x + o.x, b.y + o.y, b.z + o.z), q.f.z);
    return lerp4(lerp4(c00, c01, q.f.y), lerp4(c10, c11, q.f.y), q.f.x);
}

// Extinction sigma_t per world unit (`Medium::sample_rgb`).
fn sample_ext(p: vec3<f32>) -> vec3<f32> {
    let q = corner8(p);
    let b = q.base;
    let o = q.o;
    let c00 = lerp4(texel(ext_tex, b.x, b.y, b.z), texel(ext_tex, b.x, b.y, b.z + o.z), q.f.z);
    let c01 = lerp4(texel(ext_tex, b.x, b.y + o.y, b.z), texel(ext_tex, b.x, b.y + o.y, b.z + o.z), q.f.z);
    let c10 = lerp4(texel(ext_tex, b.x + o.x, b.y, b.z), texel(ext_tex, b.x + o.x, b.y, b.z + o.z), q.f.z);
    let c11 = lerp4(texel(ext_tex, b.x + o.x, b.y + o.y, b.z), texel(ext_tex, b.x + o.x, b.y + o.y, b.z + o.z), q.f.z);
    return lerp4(lerp4(c00, c01, q.f.y), lerp4(c10, c11, q.f.y), q.f.x).xyz;
}

struct Sample {
    n: f32,
    g: vec3<f32>,
}

// The index field as light sees it (`propagate::Bounded`): n and grad n
// (stored grad(n^2 / 2) over n) inside the bounds, no gradient outside.
fn sample_field(p: vec3<f32>) -> Sample {
    let v = trilinear_index(p);
    let inv = 1.0 / v.x;
    var g = v.yzw * inv;
    if (!contains(p)) {
        g = vec3<f32>(0.0);
    }
    return Sample(v.x, g);
}

// The uniform index of the empty block around `p`, or -1
// (`EmptySpace::index_at`).
fn empty_at(p: vec3<f32>) -> f32 {
    let u = (p - P.grid_min) * P.inv_block;
    if (!all(u >= vec3<f32>(0.0))) {
        return -1.0;
    }
    let c = vec3<u32>(u);
    if (any(c >= P.empty_dims)) {
        return -1.0;
    }
    return empty[(c.x * P.empty_dims.y + c.y) * P.empty_dims.z + c.z];
}

// ---------------------------------------------------------------------
// The equal-time ray equation on the eikonal shell (ray.rs).

struct Ray {
    x: vec3<f32>,
    v: vec3<f32>,
    opl: f32,
}

struct Deriv {
    x: vec3<f32>,
    v: vec3<f32>,
}

// Eqs 14-15: dx/dt = v / n^2, dv/dt = grad n / n (dL/dt = 1).
fn rhs(s: Sample, v: vec3<f32>) -> Deriv {
    let inv = 1.0 / s.n;
    return Deriv(v * (inv * inv), s.g * inv);
}

fn deriv(x: vec3<f32>, v: vec3<f32>) -> Deriv {
    return rhs(sample_field(x), v);
}

fn onto_shell(v: vec3<f32>, n: f32) -> vec3<f32> {
    let len = length(v);
    if (len > 0.0) {
        return v * (n / len);
    }
    return v;
}

// `step_rk4_on_shell` / `step_euler_on_shell` in the equal-time form;
// returns the displacement (in `x`), the new v and the new optical path.
fn step_on_shell(r: Ray, h: f32) -> Ray {
    let s0 = sample_field(r.x);
    let v = onto_shell(r.v, s0.n);
    let k0 = rhs(s0, v);
    if (P.method == 0u) {
        return Ray(k0.x * h, v + k0.v * h, r.opl + h);
    }
    let k1 = deriv(r.x + k0.x * (0.5 * h), v + k0.v * (0.5 * h));
    let k2 = deriv(r.x + k1.x * (0.5 * h), v + k1.v * (0.5 * h));
    let k3 = deriv(r.x + k2.x * h, v + k2.v * h);
    let w = h / 6.0;
    return Ray(
        (k0.x + (k1.x + k2.x) * 2.0 + k3.x) * w,
        v + (k0.v + (k1.v + k2.v) * 2.0 + k3.v) * w,
        r.opl + 6.0 * w,
    );
}

// ---------------------------------------------------------------------
// Patch geometry (patch.rs).

fn normalize_or_zero(v: vec3<f32>) -> vec3<f32> {
    let l = length(v);
    if (l > 0.0 && l < 3.0e38) {
        return v / l;
    }
    return vec3<f32>(0.0);
}

fn quad_normal(p0: vec3<f32>, p1: vec3<f32>, p2: vec3<f32>, p3: vec3<f32>) -> vec3<f32> {
    return cross(p2 - p0, p3 - p1);
}

fn quad_area(p0: vec3<f32>, p1: vec3<f32>, p2: vec3<f32>, p3: vec3<f32>) -> f32 {
    return 0.5 * length(quad_normal(p0, p1, p2, p3));
}

fn quad_span(p0: vec3<f32>, p1: vec3<f32>, p2: vec3<f32>, p3: vec3<f32>) -> f32 {
    let a = dot(p0 - p1, p0 - p1);
    let b = dot(p1 - p2, p1 - p2);
    let c = dot(p2 - p3, p2 - p3);
    let d = dot(p3 - p0, p3 - p0);
    return sqrt(max(max(a, b), max(c, d)));
}

// Corner c relative to corner 0.
fn rel(i: u32, c: u32) -> vec3<f32> {
    if (c == 0u) {
        return vec3<f32>(0.0);
    }
    return pos[4u * i + c].xyz;
}

// Corner c's world position.
fn corner_x(i: u32, c: u32) -> vec3<f32> {
    return pos[4u * i].xyz + rel(i, c);
}

fn midpoint(i: u32) -> vec3<f32> {
    return pos[4u * i].xyz + (rel(i, 1u) + rel(i, 2u) + rel(i, 3u)) * 0.25;
}

fn direction(i: u32) -> vec3<f32> {
    var d = vec3<f32>(0.0);
    for (var c = 0u; c < 4u; c++) {
        d += normalize_or_zero(vel[4u * i + c].xyz);
    }
    return normalize_or_zero(d);
}

// ---------------------------------------------------------------------
// Step 1 (eqs 14-15, 18) and step 2 (eq 17): `propagate::propagate` and
// `propagate::irradiance`.

// sigma_t / n per channel (zero outside the bounds and in empty space).
fn extinction_per_index(p: vec3<f32>) -> vec3<f32> {
    if (!contains(p) || empty_at(p) >= 0.0) {
        return vec3<f32>(0.0);
    }
    return sample_ext(p) / sample_field(p).n;
}

// Eq 18's optical depth over one step: the trapezoid rule, or, for a step
// crossing the bounds, its part inside at the inside end's value
// (`propagate::step_depth`).
fn step_depth(x0: vec3<f32>, x1: vec3<f32>, before: vec3<f32>, after: vec3<f32>, dt: f32) -> vec3<f32> {
    let in0 = contains(x0);
    let in1 = contains(x1);
    if (in0 == in1) {
        return (before + after) * (0.5 * dt);
    }
    let c = clip_line(x0, x1 - x0);
    var inside = 0.0;
    if (c.hit) {
        inside = max(min(c.t1, 1.0) - max(c.t0, 0.0), 0.0);
    }
    return select(after, before, in0) * (dt * inside);
}

fn propagate_patch(i: u32) {
    let dt = P.dt;
    let m0 = midpoint(i);
    var flux = aux[3u * i];
    var lost = vec3<f32>(0.0);
    var skipped = false;
    // Empty space: every corner and the midpoint in empty blocks of one
    // index: a straight step without loss.
    let n = empty_at(m0);
    if (n >= 0.0) {
        var all_empty = true;
        for (var c = 0u; c < 4u; c++) {
            if (empty_at(corner_x(i, c)) != n) {
                all_empty = false;
            }
        }
        if (all_empty) {
            var d0 = vec3<f32>(0.0);
            for (var c = 0u; c < 4u; c++) {
                let v = normalize_or_zero(vel[4u * i + c].xyz) * n;
                let d = v * (dt / (n * n));
                let p = pos[4u * i + c];
                if (c == 0u) {
                    d0 = d;
                    pos[4u * i] = vec4<f32>(p.xyz + d, p.w + dt);
                } else {
                    pos[4u * i + c] = vec4<f32>(p.xyz + (d - d0), p.w + dt);
                }
                vel[4u * i + c] = vec4<f32>(v, 0.0);
            }
            skipped = true;
        }
    }
    if (!skipped) {
        let before = extinction_per_index(m0);
        var d0 = vec3<f32>(0.0);
        let x0 = pos[4u * i].xyz;
        for (var c = 0u; c < 4u; c++) {
            let p = pos[4u * i + c];
            let r = step_on_shell(Ray(x0 + rel(i, c), vel[4u * i + c].xyz, p.w), dt);
            if (c == 0u) {
                d0 = r.x;
                pos[4u * i] = vec4<f32>(p.xyz + r.x, r.opl);
            } else {
                pos[4u * i + c] = vec4<f32>(p.xyz + (r.x - d0), r.opl);
            }
            vel[4u * i + c] = vec4<f32>(r.v, 0.0);
        }
        let m1 = midpoint(i);
        let after = extinction_per_index(m1);
        let depth = step_depth(m0, m1, before, after, dt);
        let kept = flux.xyz * exp(-depth);
        lost = flux.xyz - kept;
        flux = vec4<f32>(kept, flux.w);
        aux[3u * i] = flux;
        add_energy3(E_ABSORBED, lost);
    }
    // Eq 17: flux over the current area.
    let ar = quad_area(vec3<f32>(0.0), rel(i, 1u), rel(i, 2u), rel(i, 3u));
    var e = vec3<f32>(0.0);
    if (ar > 0.0) {
        e = flux.xyz / ar;
    }
    aux[3u * i + 2u] = vec4<f32>(e, 0.0);
}

// ---------------------------------------------------------------------
// Step 3: tessellation analysis (`refine::fate`) and its book-keeping.

fn analyse_patch(i: u32) {
    // Shape measures relative to corner 0 (they do not depend on where).
    let p0 = vec3<f32>(0.0);
    let p1 = rel(i, 1u);
    let p2 = rel(i, 2u);
    let p3 = rel(i, 3u);
    let dir = direction(i);
    let mid = midpoint(i);
    let flux = aux[3u * i];
    let f0 = aux[3u * i + 1u];
    var f = F_RETAIN;
    let clip = clip_line(mid, dir);
    if (!contains(mid) && (!clip.hit || clip.t1 <= 0.0)) {
        f = F_EXIT;
    } else if (all(flux.xyz <= P.threshold * f0.xyz)) {
        f = F_ABSORBED;
    } else if (dot(quad_normal(p0, p1, p2, p3), dir) <= 0.0) {
        f = F_CAUSTIC;
    } else if (quad_span(p0, p1, p2, p3) > P.split_span && u32(f0.w) < P.max_depth) {
        f = F_SPLIT;
    }
    fate[i] = f;
    splits[i] = select(0u, 1u, f == F_SPLIT);
    switch f {
        case 0u: {
            atomicAdd(&wg_stats[S_EXITED], 1u);
            add_energy3(E_EXITED, flux.xyz);
        }
        case 1u: {
            atomicAdd(&wg_stats[S_ABSORBED], 1u);
            add_energy3(E_CULLED, flux.xyz);
        }
        case 2u: {
            atomicAdd(&wg_stats[S_CAUSTIC], 1u);
            add_energy3(E_CULLED, flux.xyz);
        }
        case 3u: {
            atomicAdd(&wg_stats[S_KEPT], 1u);
        }
        default: {
            atomicAdd(&wg_stats[S_SPLITS], 1u);
        }
    }
}

// ---------------------------------------------------------------------
// HistoPyramids (histopyramid.wgsl's layout): level 0 holds n entries,
// level l + 1 the sums of groups of four of level l, back to back.

fn pyr_depth(n: u32) -> u32 {
    var d = 1u;
    var len = max(n, 1u);
    while (len > 1u) {
        len = (len + 3u) / 4u;
        d += 1u;
    }
    return d;
}

fn pyr_offset(l: u32, n: u32) -> u32 {
    var off = 0u;
    var len = max(n, 1u);
    for (var m = 0u; m < l; m++) {
        off += len;
        len = (len + 3u) / 4u;
    }
    return off;
}

fn pyr_len(l: u32, n: u32) -> u32 {
    var len = max(n, 1u);
    for (var m = 0u; m < l; m++) {
        len = (len + 3u) / 4u;
    }
    return len;
}

// One reduction level (L.l >= 1) of the split flags' pyramid.
@compute @workgroup_size(64)
fn reduce_splits(@builtin(global_invocation_id) id: vec3<u32>,
                 @builtin(num_workgroups) groups: vec3<u32>) {
    let j = item(id, groups);
    let dst_len = pyr_len(L.l, P.n);
    if (j >= dst_len) {
        return;
    }
    let src = pyr_offset(L.l - 1u, P.n);
    let src_len = pyr_len(L.l - 1u, P.n);
    var sum = 0u;
    for (var c = 0u; c < 4u; c++) {
        if (4u * j + c < src_len) {
            sum += splits[src + 4u * j + c];
        }
    }
    splits[src + src_len + j] = sum;
}

// One reduction level of the counts' pyramid.
@compute @workgroup_size(64)
fn reduce_counts(@builtin(global_invocation_id) id: vec3<u32>,
                 @builtin(num_workgroups) groups: vec3<u32>) {
    let j = item(id, groups);
    let dst_len = pyr_len(L.l, P.n);
    if (j >= dst_len) {
        return;
    }
    let src = pyr_offset(L.l - 1u, P.n);
    let src_len = pyr_len(L.l - 1u, P.n);
    var sum = 0u;
    for (var c = 0u; c < 4u; c++) {
        if (4u * j + c < src_len) {
            sum += levels[src + 4u * j + c];
        }
    }
    levels[src + src_len + j] = sum;
}

// Splits that would overflow `max_patches` are refused, earlier patches
// first (as `refine::refine`): a split is granted when fewer than `room`
// splits precede it. Its rank is read off the split flags' pyramid by
// summing the left siblings on the way up.
@compute @workgroup_size(64)
fn grant(@builtin(global_invocation_id) id: vec3<u32>,
         @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item(id, groups);
    if (i >= P.n) {
        return;
    }
    let f = fate[i];
    var count = 0u;
    if (f == F_RETAIN) {
        count = 1u;
    } else if (f == F_SPLIT) {
        let kept = atomicLoad(&stats[S_KEPT]);
        let nsplit = atomicLoad(&stats[S_SPLITS]);
        var room = 0u;
        if (P.max_patches > kept + nsplit) {
            room = (P.max_patches - (kept + nsplit)) / 3u;
        }
        var rank = 0u;
        if (room < nsplit) {
            var node = i;
            var off = 0u;
            var len = max(P.n, 1u);
            let depth = pyr_depth(P.n);
            for (var l = 0u; l + 1u < depth; l++) {
                for (var c = node & ~3u; c < node; c++) {
                    rank += splits[off + c];
                }
                off += len;
                len = (len + 3u) / 4u;
                node = node >> 2u;
            }
        }
        if (rank < room) {
            count = 4u;
        } else {
            count = 1u;
            atomicAdd(&stats[S_HELD], 1u);
        }
    }
    levels[i] = count;
}

// ---------------------------------------------------------------------
// The walk: one thread per output slot finds its source patch and part
// (compaction and expansion in one phase) and writes the patch: a copy, or
// a child of a tessellated patch (`refine::refine`, `Split`).

fn bilinear_w(s: f32, t: f32) -> vec4<f32> {
    return vec4<f32>((1.0 - s) * (1.0 - t), s * (1.0 - t), s * t, (1.0 - s) * t);
}

// Parameter rectangle (s0, t0, s1, t1) of child `part` (`Split::rect`):
// split 0 quarters, 1 strips across s, 2 strips across t.
fn rect(split: u32, part: u32) -> vec4<f32> {
    let q = f32(part) * 0.25;
    if (split == 1u) {
        return vec4<f32>(q, 0.0, q + 0.25, 1.0);
    }
    if (split == 2u) {
        return vec4<f32>(0.0, q, 1.0, q + 0.25);
    }
    var st = vec2<f32>(0.0, 0.0);
    if (part == 1u) {
        st = vec2<f32>(0.5, 0.0);
    } else if (part == 2u) {
        st = vec2<f32>(0.5, 0.5);
    } else if (part == 3u) {
        st = vec2<f32>(0.0, 0.5);
    }
    return vec4<f32>(st, st + 0.5);
}

fn bilin3(a: array<vec3<f32>, 4>, w: vec4<f32>) -> vec3<f32> {
    var out = vec3<f32>(0.0);
    out += a[0] * w.x;
    out += a[1] * w.y;
    out += a[2] * w.z;
    out += a[3] * w.w;
    return out;
}

fn child_corners(x: array<vec3<f32>, 4>, r: vec4<f32>) -> array<vec3<f32>, 4> {
    return array<vec3<f32>, 4>(
        bilin3(x, bilinear_w(r.x, r.y)),
        bilin3(x, bilinear_w(r.z, r.y)),
        bilin3(x, bilinear_w(r.z, r.w)),
        bilin3(x, bilinear_w(r.x, r.w)),
    );
}

fn area4(c: array<vec3<f32>, 4>) -> f32 {
    return quad_area(c[0], c[1], c[2], c[3]);
}

@compute @workgroup_size(64)
fn expand(@builtin(global_invocation_id) id: vec3<u32>,
          @builtin(num_workgroups) groups: vec3<u32>) {
    let k = item(id, groups);
    if (k >= P.n) {
        return;
    }
    let n_old = P.n_old;
    let depth = pyr_depth(n_old);
    var rest = k;
    var node = 0u;
    var l = depth - 1u;
    loop {
        if (l == 0u) {
            break;
        }
        l -= 1u;
        let offset = pyr_offset(l, n_old);
        let len = pyr_len(l, n_old);
        let first = 4u * node;
        var child = first;
        let last = min(first + 3u, len - 1u);
        for (var c = first; c < last; c++) {
            let v = levels[offset + c];
            if (rest < v) {
                break;
            }
            rest -= v;
            child += 1u;
        }
        node = child;
    }
    let i = node;
    if (levels[i] == 1u) {
        for (var c = 0u; c < 4u; c++) {
            dpos[4u * k + c] = pos[4u * i + c];
            dvel[4u * k + c] = vel[4u * i + c];
        }
        for (var a = 0u; a < 3u; a++) {
            daux[3u * k + a] = aux[3u * i + a];
        }
        return;
    }
    let part = rest;
    var x: array<vec3<f32>, 4>;
    var v: array<vec3<f32>, 4>;
    var o: array<vec3<f32>, 4>;
    for (var c = 0u; c < 4u; c++) {
        x[c] = rel(i, c);
        v[c] = vel[4u * i + c].xyz;
        o[c] = vec3<f32>(pos[4u * i + c].w, 0.0, 0.0);
    }
    // `Split::of`.
    let ls = max(length(x[1] - x[0]), length(x[2] - x[3]));
    let lt = max(length(x[3] - x[0]), length(x[2] - x[1]));
    var split = 0u;
    if (ls > 2.0 * lt) {
        split = 1u;
    } else if (lt > 2.0 * ls) {
        split = 2u;
    }
    var areas: array<f32, 4>;
    var total = 0.0;
    for (var q = 0u; q < 4u; q++) {
        areas[q] = area4(child_corners(x, rect(split, q)));
        total += areas[q];
    }
    var share = 0.25;
    if (total > 0.0) {
        share = areas[part] / total;
    }
    let r = rect(split, part);
    let cx = child_corners(x, r);
    let cv = child_corners(v, r);
    let co = child_corners(o, r);
    for (var c = 0u; c < 4u; c++) {
        // Bilinear v has the right direction but not |v| = n.
        let vn = normalize_or_zero(cv[c]) * sample_field(pos[4u * i].xyz + cx[c]).n;
        if (c == 0u) {
            dpos[4u * k] = vec4<f32>(pos[4u * i].xyz + cx[0], co[0].x);
        } else {
            dpos[4u * k + c] = vec4<f32>(cx[c] - cx[0], co[c].x);
        }
        dvel[4u * k + c] = vec4<f32>(vn, 0.0);
    }
    let flux = aux[3u * i];
    let f0 = aux[3u * i + 1u];
    let fl = flux.xyz * share;
    daux[3u * k] = vec4<f32>(fl, flux.w * share);
    daux[3u * k + 1u] = vec4<f32>(f0.xyz * share, f0.w + 1.0);
    let ar = areas[part];
    var e = vec3<f32>(0.0);
    if (ar > 0.0) {
        e = fl / ar;
    }
    daux[3u * k + 2u] = vec4<f32>(e, 0.0);
}

// ---------------------------------------------------------------------
// Step 4: voxelization by the highest-energy rule (`voxelize`), with
// atomics. A deposit's packed key is tier << 31 | bits(energy): energies
// are non-negative floats, whose bits order like the values, so one
// atomicMax picks the midpoint tier first, then the highest energy. Three
// passes per tier: (a) atomicMax of the key, stamping the cells whose key
// rose this phase; (b) among the deposits equal to a stamped cell's new key,
// atomicMin of the patch index: the first of equal rays, as the CPU's
// in-order apply keeps; (c) that patch writes irradiance and direction.

struct Deposit {
    ok: bool,
    packed: u32,
    e: vec3<f32>,
}

// Whether the straight corner rays x + t u cross for some t in [lo, hi]:
// the tube's oriented area along d, a quadratic in t, fails to stay
// positive there (`voxelize::rays_cross`).
fn rays_cross(x: array<vec3<f32>, 4>, u: array<vec3<f32>, 4>, d: vec3<f32>, lo: f32, hi: f32) -> bool {
    let a0 = x[2] - x[0];
    let a1 = u[2] - u[0];
    let b0 = x[3] - x[1];
    let b1 = u[3] - u[1];
    let c0 = dot(cross(a0, b0), d);
    let c1 = dot(cross(a0, b1) + cross(a1, b0), d);
    let c2 = dot(cross(a1, b1), d);
    var m = min(c0 + lo * (c1 + lo * c2), c0 + hi * (c1 + hi * c2));
    if (c2 > 0.0) {
        let tv = -c1 / (2.0 * c2);
        if (tv > lo && tv < hi) {
            m = min(m, c0 + tv * (c1 + tv * c2));
        }
    }
    return !(m > 0.0);
}

// Patch i's irradiance carried to the centre of cell `flat`
// (`voxelize::deposit_at`).
fn deposit_at(i: u32, mid: vec3<f32>, d: vec3<f32>, ext: vec3<f32>, flat: u32, tier: u32) -> Deposit {
    let s = dot(d, voxel_center(flat) - mid);
    var m: array<vec3<f32>, 4>;
    var x: array<vec3<f32>, 4>;
    var u: array<vec3<f32>, 4>;
    for (var c = 0u; c < 4u; c++) {
        x[c] = rel(i, c);
        u[c] = normalize_or_zero(vel[4u * i + c].xyz);
        m[c] = x[c] + u[c] * s;
    }
    let ar = area4(m);
    if (!(ar > 0.0)) {
        return Deposit(false, 0u, vec3<f32>(0.0));
    }
    let half = 0.5 * min(P.spacing.x, min(P.spacing.y, P.spacing.z));
    if (rays_cross(x, u, d, min(s - half, 0.0), max(s + half, 0.0))) {
        return Deposit(false, 0u, vec3<f32>(0.0));
    }
    let e = aux[3u * i].xyz * exp(-ext * s) / ar;
    var k = e.x + e.y + e.z;
    if (P.group >= 0) {
        k = e[P.group];
    }
    if (!(k >= 0.0)) {
        return Deposit(false, 0u, vec3<f32>(0.0));
    }
    var bits = bitcast<u32>(k);
    if (k == 0.0) {
        bits = 0u;
    }
    return Deposit(true, (tier << 31u) | bits, e);
}

fn extinction_at(mid: vec3<f32>) -> vec3<f32> {
    if (empty_at(mid) >= 0.0) {
        return vec3<f32>(0.0);
    }
    return sample_ext(mid);
}

fn write_volume(flat: u32, e: vec3<f32>, d: vec3<f32>) {
    if (P.group < 0 || P.group == 0) {
        irr0[flat] = e.x;
    }
    if (P.group < 0 || P.group == 1) {
        irr1[flat] = e.y;
    }
    if (P.group < 0 || P.group == 2) {
        irr2[flat] = e.z;
    }
    dir0[flat] = d.x;
    dir1[flat] = d.y;
    dir2[flat] = d.z;
}

// Pass (a): raise the cell's key; stamp the cell if it rose.
fn offer_max(i: u32, slot: u32, flat: u32, packed: u32, st: u32) {
    deps[5u * i + slot] = vec2<u32>(flat, packed);
    let old = atomicMax(&key[flat], packed);
    if (old < packed) {
        atomicMax(&stamp[flat], st);
        atomicStore(&owner[flat], NONE);
    }
}

// Pass (b): the lowest patch index among the deposits equal to a stamped
// cell's new key.
fn offer_owner(i: u32, slot: u32, st: u32) {
    let dp = deps[5u * i + slot];
    if (dp.x == NONE) {
        return;
    }
    if (atomicLoad(&stamp[dp.x]) == st && atomicLoad(&key[dp.x]) == dp.y) {
        atomicMin(&owner[dp.x], i);
    }
}

// Whether patch i won slot `slot` in pass (b).
fn won(i: u32, slot: u32, st: u32) -> bool {
    let dp = deps[5u * i + slot];
    return dp.x != NONE && atomicLoad(&stamp[dp.x]) == st && atomicLoad(&owner[dp.x]) == i;
}

fn midpoint_max(i: u32) {
    deps[5u * i] = vec2<u32>(NONE, 0u);
    let mid = midpoint(i);
    let cell = cell_of(mid);
    if (!cell.ok) {
        return;
    }
    let d = direction(i);
    let dep = deposit_at(i, mid, d, extinction_at(mid), cell.flat, 1u);
    if (dep.ok) {
        offer_max(i, 0u, cell.flat, dep.packed, P.stamp);
    }
}

fn midpoint_write(i: u32) {
    if (!won(i, 0u, P.stamp)) {
        return;
    }
    let mid = midpoint(i);
    let d = direction(i);
    let flat = deps[5u * i].x;
    let dep = deposit_at(i, mid, d, extinction_at(mid), flat, 1u);
    write_volume(flat, dep.e, d);
}

// The cells under the corners that no midpoint has reached (tier 0),
// each once and not the midpoint's own.
fn corners_max(i: u32) {
    let mid = midpoint(i);
    let mc = cell_of(mid);
    var seen = array<u32, 5>(NONE, NONE, NONE, NONE, NONE);
    if (mc.ok) {
        seen[0] = mc.flat;
    }
    var any_cell = false;
    for (var c = 0u; c < 4u; c++) {
        let cell = cell_of(corner_x(i, c));
        if (!cell.ok) {
            continue;
        }
        var dup = false;
        for (var s = 0u; s < 5u; s++) {
            if (seen[s] == cell.flat) {
                dup = true;
            }
        }
        if (dup || atomicLoad(&key[cell.flat]) >= 0x80000000u) {
            continue;
        }
        seen[c + 1u] = cell.flat;
        any_cell = true;
    }
    for (var c = 1u; c < 5u; c++) {
        deps[5u * i + c] = vec2<u32>(NONE, 0u);
    }
    // Direction and extinction only once a cell needs them: most corners
    // land in cells a midpoint has already reached.
    if (!any_cell) {
        return;
    }
    let d = direction(i);
    let ext = extinction_at(mid);
    for (var c = 1u; c < 5u; c++) {
        if (seen[c] == NONE) {
            continue;
        }
        let dep = deposit_at(i, mid, d, ext, seen[c], 0u);
        if (dep.ok) {
            offer_max(i, c, seen[c], dep.packed, P.stamp + 1u);
        }
    }
}

fn corners_write(i: u32) {
    let st = P.stamp + 1u;
    if (!(won(i, 1u, st) || won(i, 2u, st) || won(i, 3u, st) || won(i, 4u, st))) {
        return;
    }
    let mid = midpoint(i);
    let d = direction(i);
    let ext = extinction_at(mid);
    for (var c = 1u; c < 5u; c++) {
        if (won(i, c, st)) {
            let flat = deps[5u * i + c].x;
            let dep = deposit_at(i, mid, d, ext, flat, 0u);
            write_volume(flat, dep.e, d);
        }
    }
}

@compute @workgroup_size(64)
fn mid_max(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item(id, groups);
    if (i < P.n) {
        midpoint_max(i);
    }
}

@compute @workgroup_size(64)
fn mid_owner(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item(id, groups);
    if (i < P.n) {
        offer_owner(i, 0u, P.stamp);
    }
}

@compute @workgroup_size(64)
fn mid_write(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item(id, groups);
    if (i < P.n) {
        midpoint_write(i);
    }
}

@compute @workgroup_size(64)
fn corner_max(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item(id, groups);
    if (i < P.n) {
        corners_max(i);
    }
}

@compute @workgroup_size(64)
fn corner_owner(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item(id, groups);
    if (i < P.n) {
        for (var c = 1u; c < 5u; c++) {
            offer_owner(i, c, P.stamp + 1u);
        }
    }
}

@compute @workgroup_size(64)
fn corner_write(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item(id, groups);
    if (i < P.n) {
        corners_write(i);
    }
}

@compute @workgroup_size(64)
fn propagate(@builtin(global_invocation_id) id: vec3<u32>,
             @builtin(num_workgroups) groups: vec3<u32>,
             @builtin(local_invocation_index) li: u32) {
    wg_begin(li);
    let i = item(id, groups);
    if (i < P.n) {
        propagate_patch(i);
    }
    wg_end(li);
}

@compute @workgroup_size(64)
fn analyse(@builtin(global_invocation_id) id: vec3<u32>,
           @builtin(num_workgroups) groups: vec3<u32>,
           @builtin(local_invocation_index) li: u32) {
    wg_begin(li);
    let i = item(id, groups);
    if (i < P.n) {
        analyse_patch(i);
    }
    wg_end(li);
}

// Patches alive at the step limit: their flux is culled.
@compute @workgroup_size(64)
fn cull_rest(@builtin(global_invocation_id) id: vec3<u32>,
             @builtin(num_workgroups) groups: vec3<u32>,
             @builtin(local_invocation_index) li: u32) {
    wg_begin(li);
    let i = item(id, groups);
    if (i < P.n) {
        add_energy3(E_CULLED, aux[3u * i].xyz);
    }
    wg_end(li);
}
