// The wavefront light simulator on the GPU (Ihrke et al. 2007, 5.2): the
// same steps, definitions and units as the CPU modules `propagate`,
// `deposit`, `refine` and `deposit::paper` (see their docs), in f32. One thread
// per patch (or per output slot of the HistoPyramid walk). Two deposit
// rules (`DepositRule`): the track-length fluence deposit inside the
// propagate kernel (`propagate_tube`, 64-bit fixed-point counters), or the
// paper's highest-energy ray per cell (the `mid_*` and `corner_*` kernels).
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
// `VoxelField::sample` and `GridGeometry::trilinear` do. With Fresnel, the
// interface sides of the index channel and the boundary indicator as a
// third texture, (n_lo, n_hi, delta, 0) per cell (`eikon_grid::interface`).

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
    fluence: u32,      // 1: the track-length deposit (`DepositRule::Fluence`), 0: the paper's
    fresnel: u32,      // 1: Fresnel transmission at interfaces
    fl_scale: vec3<f32>, // fluence units per W of length, per channel (`Counters`)
    flux_scale: f32,   // flux-vector units per W of length
    inc_pos: vec3<f32>,  // `refine::Incident`: a point or spot light's position
    inc_power: f32,    // its power, or a plane wave's irradiance
    cone_axis: vec3<f32>, // a spot light's axis
    inc_kind: u32,     // 0 plane wave, 1 point light, 2 spot light
    cone_angle: f32,   // half-angle, degrees
    cone_falloff: f32, // falloff band, degrees
    dim: f32,          // `Rules::dim`
    faint: f32,        // `Rules::faint`
    voxel: f32,        // the smallest cell edge
    pad0: u32,
    pad1: u32,
    pad2: u32,
    pad3: vec4<u32>,
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
@group(0) @binding(9) var fresnel_tex: texture_3d<f32>;

@group(1) @binding(0) var<storage, read_write> pos: array<vec4<f32>>;
@group(1) @binding(1) var<storage, read_write> vel: array<vec4<f32>>;
@group(1) @binding(2) var<storage, read_write> aux: array<vec4<f32>>;
@group(1) @binding(3) var<storage, read_write> dpos: array<vec4<f32>>;
@group(1) @binding(4) var<storage, read_write> dvel: array<vec4<f32>>;
@group(1) @binding(5) var<storage, read_write> daux: array<vec4<f32>>;

// The light volume. Paper's deposit: the packed key, stamp and owner of
// each cell, then its irradiance and direction (bindings 0 to 8; 9 to 11
// unused). Fluence deposit: 64-bit fixed-point counters as (lo, hi) words
// in separate buffers of one word per cell (each fits a storage binding
// wherever one channel does): fluence per channel (lo 0-2, hi 3-5) and the
// flux vector of the wavefront group per component (lo 6-8, hi 9-11),
// two's complement. No entry point uses both sets.
@group(2) @binding(0) var<storage, read_write> key: array<atomic<u32>>;
@group(2) @binding(1) var<storage, read_write> stamp: array<atomic<u32>>;
@group(2) @binding(2) var<storage, read_write> owner: array<atomic<u32>>;
@group(2) @binding(3) var<storage, read_write> irr0: array<f32>;
@group(2) @binding(4) var<storage, read_write> irr1: array<f32>;
@group(2) @binding(5) var<storage, read_write> irr2: array<f32>;
@group(2) @binding(6) var<storage, read_write> dir0: array<f32>;
@group(2) @binding(7) var<storage, read_write> dir1: array<f32>;
@group(2) @binding(8) var<storage, read_write> dir2: array<f32>;

@group(2) @binding(0) var<storage, read_write> fl_lo0: array<atomic<u32>>;
@group(2) @binding(1) var<storage, read_write> fl_lo1: array<atomic<u32>>;
@group(2) @binding(2) var<storage, read_write> fl_lo2: array<atomic<u32>>;
@group(2) @binding(3) var<storage, read_write> fl_hi0: array<atomic<u32>>;
@group(2) @binding(4) var<storage, read_write> fl_hi1: array<atomic<u32>>;
@group(2) @binding(5) var<storage, read_write> fl_hi2: array<atomic<u32>>;
@group(2) @binding(6) var<storage, read_write> fx_lo0: array<atomic<u32>>;
@group(2) @binding(7) var<storage, read_write> fx_lo1: array<atomic<u32>>;
@group(2) @binding(8) var<storage, read_write> fx_lo2: array<atomic<u32>>;
@group(2) @binding(9) var<storage, read_write> fx_hi0: array<atomic<u32>>;
@group(2) @binding(10) var<storage, read_write> fx_hi1: array<atomic<u32>>;
@group(2) @binding(11) var<storage, read_write> fx_hi2: array<atomic<u32>>;

@group(3) @binding(0) var<uniform> L: Level;

// Stats words: energy tallies (category * 3 + channel) as 64-bit fixed
// point (lo, hi) in words 0..30; then counts.
const E_ABSORBED: u32 = 0u;
const E_EXITED: u32 = 1u;
const E_CULLED: u32 = 2u;
const E_REFLECTED: u32 = 3u;
const E_TRAPPED: u32 = 4u;
const S_EXITED: u32 = 30u;
const S_ABSORBED: u32 = 31u;
const S_CAUSTIC: u32 = 32u;
const S_HELD: u32 = 33u;
const S_KEPT: u32 = 34u;
const S_SPLITS: u32 = 35u;
const S_FAINT: u32 = 36u;
const STATS_WORDS: u32 = 37u;

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
var<workgroup> wg_stats: array<atomic<u32>, 37>;

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
    if (li < STATS_WORDS) {
        atomicStore(&wg_stats[li], 0u);
    }
    workgroupBarrier();
}

fn wg_end(li: u32) {
    workgroupBarrier();
    if (li < S_EXITED / 2u) {
        let lo = atomicLoad(&wg_stats[2u * li]);
        let hi = atomicLoad(&wg_stats[2u * li + 1u]);
        if (lo != 0u || hi != 0u) {
            add_fixed(2u * li, lo, hi, true);
        }
    } else if (li >= S_EXITED && li < STATS_WORDS) {
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

// ---------------------------------------------------------------------
// Fresnel transmission at interfaces (`eikon_grid::interface`).

// Unpolarized Fresnel reflectance from index n1 into n2 at incidence
// cosine cos_i (`fresnel::reflectance`).
fn reflectance(cos_in: f32, n1: f32, n2: f32) -> f32 {
    if (n1 == n2) {
        return 0.0;
    }
    let cos_i = min(abs(cos_in), 1.0);
    let sin_i2 = max(1.0 - cos_i * cos_i, 0.0);
    let eta = n1 / n2;
    let sin_t2 = eta * eta * sin_i2;
    if (sin_t2 >= 1.0) {
        return 1.0;
    }
    let cos_t = sqrt(1.0 - sin_t2);
    let rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t);
    let rp = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t);
    return 0.5 * (rs * rs + rp * rp);
}

// 1 - R crossing the interface between the sides `lo` and `hi` with unit
// `normal`, from Snell's invariant |v_t|; 1 under total internal
// reflection and where the sides do not differ
// (`interface::crossing_transmittance`).
fn crossing_transmittance(lo: f32, hi: f32, v: vec3<f32>, normal: vec3<f32>) -> f32 {
    if (!(lo > 0.0 && hi > 0.0) || lo == hi) {
        return 1.0;
    }
    let vt = v - normal * dot(v, normal);
    let vt2 = dot(vt, vt);
    let n_min = min(lo, hi);
    if (vt2 >= n_min * n_min) {
        return 1.0;
    }
    let cos_lo = sqrt(max(1.0 - vt2 / (lo * lo), 0.0));
    return 1.0 - reflectance(cos_lo, lo, hi);
}

// The power fraction kept over the displacement `dx` about `p` travelling
// with eikonal gradient `v`: (1 - R)^(delta |dx . normal|)
// (`Interfaces::transmittance`).
fn transmittance(p: vec3<f32>, v: vec3<f32>, dx: vec3<f32>) -> f32 {
    if (!contains(p)) {
        return 1.0;
    }
    let q = corner8(p);
    let b = q.base;
    let o = q.o;
    let c00 = lerp4(texel(fresnel_tex, b.x, b.y, b.z), texel(fresnel_tex, b.x, b.y, b.z + o.z), q.f.z);
    let c01 = lerp4(texel(fresnel_tex, b.x, b.y + o.y, b.z), texel(fresnel_tex, b.x, b.y + o.y, b.z + o.z), q.f.z);
    let c10 = lerp4(texel(fresnel_tex, b.x + o.x, b.y, b.z), texel(fresnel_tex, b.x + o.x, b.y, b.z + o.z), q.f.z);
    let c11 = lerp4(texel(fresnel_tex, b.x + o.x, b.y + o.y, b.z), texel(fresnel_tex, b.x + o.x, b.y + o.y, b.z + o.z), q.f.z);
    let sides = lerp4(lerp4(c00, c01, q.f.y), lerp4(c10, c11, q.f.y), q.f.x);
    let delta = sides.z;
    if (!(delta > 0.0)) {
        return 1.0;
    }
    let grad = sample_field(p).g;
    let len = length(grad);
    if (!(len > 0.0 && len < 3.0e38)) {
        return 1.0;
    }
    let normal = grad / len;
    let part = min(delta * abs(dot(dx, normal)), 1.0);
    if (!(part > 0.0)) {
        return 1.0;
    }
    return pow(crossing_transmittance(sides.x, sides.y, v, normal), part);
}

// What a patch swept in one step, for the track-length deposit: its
// corners before and after, its flux before, the step's optical depth.
struct Swept {
    x0: array<vec3<f32>, 4>,
    x1: array<vec3<f32>, 4>,
    flux: vec3<f32>,
    depth: vec3<f32>,
}

// One step of patch i: `propagate::propagate` (eqs 14-15, 18, Fresnel) and,
// for the paper's deposit, `propagate::irradiance` (eq 17).
fn propagate_patch(i: u32) -> Swept {
    let dt = P.dt;
    let m0 = midpoint(i);
    var flux = aux[3u * i];
    var out: Swept;
    out.flux = flux.xyz;
    out.depth = vec3<f32>(0.0);
    for (var c = 0u; c < 4u; c++) {
        out.x0[c] = corner_x(i, c);
    }
    var skipped = false;
    // Empty space: every corner and the midpoint in empty blocks of one
    // index: a straight step without loss.
    let n = empty_at(m0);
    if (n >= 0.0) {
        var all_empty = true;
        for (var c = 0u; c < 4u; c++) {
            if (empty_at(out.x0[c]) != n) {
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
        out.depth = depth;
        let kept = flux.xyz * exp(-depth);
        add_energy3(E_ABSORBED, flux.xyz - kept);
        flux = vec4<f32>(kept, flux.w);
        if (P.fresnel != 0u) {
            var v = vec3<f32>(0.0);
            for (var c = 0u; c < 4u; c++) {
                v += vel[4u * i + c].xyz;
            }
            let t = transmittance((m0 + m1) * 0.5, v * 0.25, m1 - m0);
            if (t < 1.0) {
                let through = flux.xyz * t;
                add_energy3(E_REFLECTED, flux.xyz - through);
                flux = vec4<f32>(through, flux.w);
            }
        }
        aux[3u * i] = flux;
    }
    for (var c = 0u; c < 4u; c++) {
        out.x1[c] = corner_x(i, c);
    }
    if (P.fluence == 0u) {
        // Eq 17: flux over the current area.
        let ar = quad_area(vec3<f32>(0.0), rel(i, 1u), rel(i, 2u), rel(i, 3u));
        var e = vec3<f32>(0.0);
        if (ar > 0.0) {
            e = flux.xyz / ar;
        }
        aux[3u * i + 2u] = vec4<f32>(e, 0.0);
    }
    return out;
}

// ---------------------------------------------------------------------
// The track-length deposit (`deposit`): each patch's swept tube as
// sub-patch chords with box footprints, cut among the cells by a 3D DDA,
// summed per cell in a small per-thread cache (`deposit::Local`) and added
// to 64-bit fixed-point counters with two u32 atomics and a carry. Integer
// addition commutes, so the counters are the same whatever the order.

// Add the 64-bit (lo, hi) to fluence counter `c` of `cell`.
fn add_fluence(c: u32, cell: u32, lo: u32, hi: u32) {
    var old = 0u;
    switch c {
        case 0u: { old = atomicAdd(&fl_lo0[cell], lo); }
        case 1u: { old = atomicAdd(&fl_lo1[cell], lo); }
        default: { old = atomicAdd(&fl_lo2[cell], lo); }
    }
    let h = hi + select(0u, 1u, old + lo < old);
    if (h != 0u) {
        switch c {
            case 0u: { atomicAdd(&fl_hi0[cell], h); }
            case 1u: { atomicAdd(&fl_hi1[cell], h); }
            default: { atomicAdd(&fl_hi2[cell], h); }
        }
    }
}

// Add the 64-bit two's complement (lo, hi) to flux-vector counter `a`.
fn add_flux(a: u32, cell: u32, lo: u32, hi: u32) {
    var old = 0u;
    switch a {
        case 0u: { old = atomicAdd(&fx_lo0[cell], lo); }
        case 1u: { old = atomicAdd(&fx_lo1[cell], lo); }
        default: { old = atomicAdd(&fx_lo2[cell], lo); }
    }
    let h = hi + select(0u, 1u, old + lo < old);
    if (h != 0u) {
        switch a {
            case 0u: { atomicAdd(&fx_hi0[cell], h); }
            case 1u: { atomicAdd(&fx_hi1[cell], h); }
            default: { atomicAdd(&fx_hi2[cell], h); }
        }
    }
}

// A non-negative whole number of units (below 2^64) as (lo, hi).
fn split64(x: f32) -> vec2<u32> {
    let y = min(x, 1.8e19);
    let hi = floor(y / 4294967296.0);
    return vec2<u32>(u32(y - hi * 4294967296.0), u32(hi));
}

// Round the amounts of one cell to units and add them (`Counters::add`):
// fluence to the nearest unit, flux-vector components half away from zero.
fn add_units(cell: u32, fl: vec3<f32>, fx: vec3<f32>) {
    for (var c = 0u; c < 3u; c++) {
        let u = floor(fl[c] + 0.5);
        if (u >= 1.0) {
            let w = split64(u);
            add_fluence(c, cell, w.x, w.y);
        }
    }
    for (var a = 0u; a < 3u; a++) {
        let u = floor(abs(fx[a]) + 0.5);
        if (u >= 1.0) {
            var w = split64(u);
            if (fx[a] < 0.0) {
                // Two's complement of the 64-bit magnitude.
                w = vec2<u32>(~w.x + 1u, ~w.y + select(0u, 1u, w.x == 0u));
            }
            add_flux(a, cell, w.x, w.y);
        }
    }
}

// The cells one patch's chords reach in one step, summed before they go
// to the counters (`deposit::Local`).
const LOCAL_CELLS: u32 = 16u;
var<private> local_cell: array<u32, 16>;
var<private> local_fl: array<vec3<f32>, 16>;
var<private> local_fx: array<vec3<f32>, 16>;
var<private> local_len: u32;

fn local_flush() {
    for (var k = 0u; k < local_len; k++) {
        add_units(local_cell[k], local_fl[k], local_fx[k]);
    }
    local_len = 0u;
}

fn local_put(cell: u32, fl: vec3<f32>, fx: vec3<f32>) {
    for (var k = local_len; k > 0u; k--) {
        if (local_cell[k - 1u] == cell) {
            local_fl[k - 1u] += fl;
            local_fx[k - 1u] += fx;
            return;
        }
    }
    if (local_len == LOCAL_CELLS) {
        local_flush();
    }
    local_cell[local_len] = cell;
    local_fl[local_len] = fl;
    local_fx[local_len] = fx;
    local_len += 1u;
}

// 1 - exp(-x) for x >= 0, without the cancellation at small x.
fn one_minus_exp(x: f32) -> f32 {
    if (x < 0.01) {
        return x * (1.0 - x * (0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0))));
    }
    return 1.0 - exp(-x);
}

// The piece [ta, tb] of a chord in cell c (`Sink::add`): w the fluence
// units per unit of t, wf the flux-vector units per unit of t per channel.
fn piece(c: vec3<i32>, ta: f32, tb: f32, w: vec3<f32>, wf: vec3<f32>, u: vec3<f32>, depth: vec3<f32>) {
    var weight = vec3<f32>(tb - ta);
    for (var ch = 0u; ch < 3u; ch++) {
        let tau = depth[ch];
        if (tau > 0.0) {
            weight[ch] = exp(-tau * ta) * one_minus_exp(tau * (tb - ta)) / tau;
        }
    }
    let flat = (u32(c.x) * P.dims.y + u32(c.y)) * P.dims.z + u32(c.z);
    local_put(flat, w * weight, u * dot(wf, weight));
}

// The chord from a to b carrying `flux` at a and losing optical depth
// `depth` over it, cut among the cells it crosses (`Counters::chord`).
fn chord(a: vec3<f32>, b: vec3<f32>, flux: vec3<f32>, depth: vec3<f32>) {
    let d = b - a;
    let len = length(d);
    if (!(len > 0.0 && len < 3.0e38)) {
        return;
    }
    var t0 = 0.0;
    var t1 = 1.0;
    if (!(contains(a) && contains(b))) {
        let clip = clip_line(a, d);
        if (!clip.hit) {
            return;
        }
        t0 = max(clip.t0, 0.0);
        t1 = min(clip.t1, 1.0);
    }
    if (t1 <= t0) {
        return;
    }
    let w = flux * len * P.fl_scale;
    var wf = flux * (len * P.flux_scale / 3.0);
    if (P.group >= 0) {
        wf = vec3<f32>(0.0);
        wf[P.group] = flux[P.group] * len * P.flux_scale;
    }
    let u = d / len;
    let g = (a - P.grid_min) * P.inv_spacing;
    let dg = d * P.inv_spacing;
    let top = vec3<i32>(P.dims) - 1;
    let first = clamp(vec3<i32>(g + dg * t0), vec3<i32>(0), top);
    let last = clamp(vec3<i32>(g + dg * t1), vec3<i32>(0), top);
    if (all(first == last)) {
        piece(first, t0, t1, w, wf, u, depth);
        return;
    }
    var cell = first;
    var step = vec3<i32>(0);
    var next = vec3<f32>(3.0e38);
    var delta = vec3<f32>(3.0e38);
    for (var ax = 0; ax < 3; ax++) {
        if (dg[ax] > 0.0) {
            step[ax] = 1;
            next[ax] = (f32(cell[ax]) + 1.0 - g[ax]) / dg[ax];
            delta[ax] = 1.0 / dg[ax];
        } else if (dg[ax] < 0.0) {
            step[ax] = -1;
            next[ax] = (f32(cell[ax]) - g[ax]) / dg[ax];
            delta[ax] = -1.0 / dg[ax];
        }
    }
    var t = t0;
    // A chord crosses at most this many cell faces.
    let most = i32(P.dims.x + P.dims.y + P.dims.z) + 3;
    for (var guard = 0; guard < most; guard++) {
        var ax = 2;
        if (next.x <= next.y && next.x <= next.z) {
            ax = 0;
        } else if (next.y <= next.z) {
            ax = 1;
        }
        let end = min(next[ax], t1);
        if (end > t) {
            piece(cell, t, end, w, wf, u, depth);
        }
        if (next[ax] >= t1) {
            break;
        }
        cell[ax] += step[ax];
        if (cell[ax] < 0 || cell[ax] > top[ax]) {
            break;
        }
        next[ax] += delta[ax];
        t = max(t, end);
    }
}

// Most sub-patches along one side of a patch (`deposit::MAX_SUBPATCHES`),
// their size in voxels (`SUBPATCH_SIZE`), the most cells a footprint spans
// along one axis (`MAX_PARTS`).
const MAX_SUBPATCHES: f32 = 8.0;
const SUBPATCH_SIZE: f32 = 0.5;
const MAX_PARTS: u32 = 4u;

fn bilinear_point(p: array<vec3<f32>, 4>, s: f32, t: f32) -> vec3<f32> {
    return p[0] * ((1.0 - s) * (1.0 - t)) + p[1] * (s * (1.0 - t)) + p[2] * (s * t) + p[3] * ((1.0 - s) * t);
}

// A box footprint of `width` cells centred at cell coordinate `centre`,
// cut at the cell faces (`deposit::box_parts`): its span (lo, hi) relative
// to the cell of the centre (so that f32 keeps its digits for the
// offsets), narrowed to MAX_PARTS - 1 cells; a footprint too narrow to cut
// is (0, 0), one part of the whole width at the centre. Part k covers
// [max(lo, floor(lo) + k), min(hi, floor(lo) + k + 1)] (`box_part`).
fn box_span(centre: f32, width: f32) -> vec2<f32> {
    let w = min(width, f32(MAX_PARTS - 1u));
    if (!(w > 1e-9) || !(abs(centre) < 3.0e38)) {
        return vec2<f32>(0.0);
    }
    let c = centre - floor(centre);
    return vec2<f32>(c - 0.5 * w, c + 0.5 * w);
}

// Parts of a footprint span (`box_span`): at least one.
fn box_count(span: vec2<f32>) -> u32 {
    if (!(span.y > span.x)) {
        return 1u;
    }
    return clamp(u32(ceil(span.y) - floor(span.x)), 1u, MAX_PARTS);
}

// Part k of a footprint span: (fraction of the width, offset of its centre
// from the footprint's centre, cells).
fn box_part(span: vec2<f32>, k: u32) -> vec2<f32> {
    if (!(span.y > span.x)) {
        return vec2<f32>(1.0, 0.0);
    }
    let base = floor(span.x) + f32(k);
    let a = max(span.x, base);
    let b = min(span.y, base + 1.0);
    return vec2<f32>(max(b - a, 0.0) / (span.y - span.x), 0.5 * (a + b) - 0.5 * (span.x + span.y));
}

fn edge2(p: array<vec3<f32>, 4>, a: u32, b: u32) -> f32 {
    let d = p[a] - p[b];
    return dot(d, d);
}

// Deposit the tube a patch swept (`deposit::tube`).
fn tube(sw: Swept) {
    let x0 = sw.x0;
    let x1 = sw.x1;
    local_len = 0u;
    // `subpatches`: enough that none exceeds SUBPATCH_SIZE voxels on the
    // longer of each pair of opposite edges, before or after the step.
    let ls = sqrt(max(max(edge2(x0, 1u, 0u), edge2(x0, 2u, 3u)), max(edge2(x1, 1u, 0u), edge2(x1, 2u, 3u))));
    let lt = sqrt(max(max(edge2(x0, 3u, 0u), edge2(x0, 2u, 1u)), max(edge2(x1, 3u, 0u), edge2(x1, 2u, 1u))));
    let ks = max(ceil(ls / (SUBPATCH_SIZE * P.voxel)), 1.0);
    let kt = max(ceil(lt / (SUBPATCH_SIZE * P.voxel)), 1.0);
    var whole = ks <= MAX_SUBPATCHES && kt <= MAX_SUBPATCHES;
    if (whole && max(ks, kt) * SUBPATCH_SIZE > 2.0) {
        // Torn: over two voxels across and far from a parallelogram.
        let twist = length(x1[0] - x1[1] + x1[2] - x1[3]);
        whole = !(twist > 0.5 * quad_span(x1[0], x1[1], x1[2], x1[3]));
    }
    if (!whole) {
        // Along its four corner rays, a quarter each.
        for (var c = 0u; c < 4u; c++) {
            chord(x0[c], x1[c], sw.flux * 0.25, sw.depth);
        }
        local_flush();
        return;
    }
    let ns = u32(ks);
    let nt = u32(kt);
    let share = 1.0 / f32(ns * nt);
    // The axis the tube runs along most (in cells): footprints are boxes
    // in the plane of the other two.
    let run = ((x1[0] + x1[1] + x1[2] + x1[3]) - (x0[0] + x0[1] + x0[2] + x0[3])) * P.inv_spacing;
    let r = abs(run);
    var major = 2u;
    if (r.x >= r.y && r.x >= r.z) {
        major = 0u;
    } else if (r.y >= r.z) {
        major = 1u;
    }
    let ab = (major + 1u) % 3u;
    let ac = (major + 2u) % 3u;
    // Halfway through the step.
    let xm = array<vec3<f32>, 4>((x0[0] + x1[0]) * 0.5, (x0[1] + x1[1]) * 0.5, (x0[2] + x1[2]) * 0.5, (x0[3] + x1[3]) * 0.5);
    let inv_ns = 1.0 / f32(ns);
    let inv_nt = 1.0 / f32(nt);
    for (var i = 0u; i < ns; i++) {
        let s0 = f32(i) * inv_ns;
        let s1 = f32(i + 1u) * inv_ns;
        let sm = 0.5 * (s0 + s1);
        for (var j = 0u; j < nt; j++) {
            let t0 = f32(j) * inv_nt;
            let t1 = f32(j + 1u) * inv_nt;
            let tm = 0.5 * (t0 + t1);
            let a = bilinear_point(x0, sm, tm);
            let b = bilinear_point(x1, sm, tm);
            // The sub-patch halfway through the step: its second moments
            // across the two minor axes give the box.
            let q0 = bilinear_point(xm, s0, t0);
            let q1 = bilinear_point(xm, s1, t0);
            let q2 = bilinear_point(xm, s1, t1);
            let q3 = bilinear_point(xm, s0, t1);
            let e1 = (q1 - q0 + q2 - q3) * 0.5;
            let e2 = (q3 - q0 + q2 - q1) * 0.5;
            let extent = sqrt(e1 * e1 + e2 * e2) * P.inv_spacing;
            let cc = ((a + b) * 0.5 - P.grid_min) * P.inv_spacing;
            let sb = box_span(cc[ab], extent[ab]);
            let sc = box_span(cc[ac], extent[ac]);
            let nb = box_count(sb);
            let nc = box_count(sc);
            for (var kb = 0u; kb < nb; kb++) {
                let pb = box_part(sb, kb);
                for (var kc = 0u; kc < nc; kc++) {
                    let pc = box_part(sc, kc);
                    var off = vec3<f32>(0.0);
                    off[ab] = pb.y * P.spacing[ab];
                    off[ac] = pc.y * P.spacing[ac];
                    let f = sw.flux * (share * pb.x * pc.x);
                    chord(a + off, b + off, f, sw.depth);
                }
            }
        }
    }
    local_flush();
}

// ---------------------------------------------------------------------
// Step 3: tessellation analysis (`refine::fate`) and its book-keeping.

// Whether a ray at x going along d has left the bounds for good.
fn gone(x: vec3<f32>, d: vec3<f32>) -> bool {
    let clip = clip_line(x, d);
    return !contains(x) && (!clip.hit || clip.t1 <= 0.0);
}

// A spot light's weight of unit direction `dir` (`eikon_optics::spot::cone_weight`).
fn cone_weight(dir: vec3<f32>) -> f32 {
    if (P.inc_kind != 2u) {
        return 1.0;
    }
    let theta = degrees(acos(clamp(dot(dir, P.cone_axis), -1.0, 1.0)));
    if (theta >= P.cone_angle) {
        return 0.0;
    }
    if (P.cone_falloff <= 0.0 || theta <= P.cone_angle - P.cone_falloff) {
        return 1.0;
    }
    let x = (P.cone_angle - theta) / P.cone_falloff;
    return x * x * (3.0 - 2.0 * x);
}

// The light's unobstructed irradiance at x (`refine::Incident::at`).
fn incident_at(x: vec3<f32>) -> f32 {
    if (P.inc_kind == 0u) {
        return P.inc_power;
    }
    let d = x - P.inc_pos;
    let r2 = dot(d, d);
    return P.inc_power * cone_weight(d / sqrt(r2)) / (4.0 * 3.14159265358979 * r2);
}

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
    var faint = false;
    var exit = false;
    if (P.fluence == 0u) {
        // The paper's deposit reads the midpoint only.
        exit = gone(mid, dir);
    } else {
        // The track-length deposit lights every cell a patch covers: it
        // leaves when each corner has.
        exit = true;
        for (var c = 0u; c < 4u; c++) {
            exit = exit && gone(corner_x(i, c), vel[4u * i + c].xyz);
        }
    }
    let total = flux.x + flux.y + flux.z;
    if (exit) {
        f = F_EXIT;
    } else if (all(flux.xyz <= P.threshold * f0.xyz)) {
        f = F_ABSORBED;
    } else if (P.faint > 0.0 && total < P.faint * incident_at(mid)) {
        // Still travelling, too faint to follow: trapped (`Fate::Faint`).
        f = F_ABSORBED;
        faint = true;
    } else if (P.fluence == 0u && dot(quad_normal(p0, p1, p2, p3), dir) <= 0.0) {
        f = F_CAUSTIC;
    } else if (quad_span(p0, p1, p2, p3) > P.split_span && u32(f0.w) < P.max_depth) {
        f = F_SPLIT;
        // Too dim to be worth more patches (`Rules::dim`).
        if (P.dim > 0.0 && total < P.dim * incident_at(mid) * quad_area(p0, p1, p2, p3)) {
            f = F_RETAIN;
        }
    }
    fate[i] = f;
    splits[i] = select(0u, 1u, f == F_SPLIT);
    switch f {
        case 0u: {
            atomicAdd(&wg_stats[S_EXITED], 1u);
            add_energy3(E_EXITED, flux.xyz);
        }
        case 1u: {
            if (faint) {
                atomicAdd(&wg_stats[S_FAINT], 1u);
                add_energy3(E_TRAPPED, flux.xyz);
            } else {
                atomicAdd(&wg_stats[S_ABSORBED], 1u);
                add_energy3(E_CULLED, flux.xyz);
            }
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
// Step 4: voxelization by the highest-energy rule (`deposit::paper`), with
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
// positive there (`deposit::paper::rays_cross`).
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
// (`deposit::paper::deposit_at`).
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
    // Attenuation carried forwards only, never exp(+sigma |s|).
    let e = aux[3u * i].xyz * exp(-ext * max(s, 0.0)) / ar;
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
        _ = propagate_patch(i);
    }
    wg_end(li);
}

// The step with the track-length deposit of each patch's swept tube.
@compute @workgroup_size(64)
fn propagate_tube(@builtin(global_invocation_id) id: vec3<u32>,
                  @builtin(num_workgroups) groups: vec3<u32>,
                  @builtin(local_invocation_index) li: u32) {
    wg_begin(li);
    let i = item(id, groups);
    if (i < P.n) {
        tube(propagate_patch(i));
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

// Patches alive at the step limit: their flux is trapped.
@compute @workgroup_size(64)
fn cull_rest(@builtin(global_invocation_id) id: vec3<u32>,
             @builtin(num_workgroups) groups: vec3<u32>,
             @builtin(local_invocation_index) li: u32) {
    wg_begin(li);
    let i = item(id, groups);
    if (i < P.n) {
        add_energy3(E_TRAPPED, aux[3u * i].xyz);
    }
    wg_end(li);
}
