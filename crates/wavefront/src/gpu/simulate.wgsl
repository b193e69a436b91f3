// The wavefront light simulator on the GPU [Ihrke07 sec 5.2]: the same
// steps, definitions and units as the CPU modules `propagate`, `deposit`,
// `refine` and `voxelize` (see their docs), in f32. The physics they share
// with the CPU and the view renderer comes from the shared modules
// composed ahead of this source (`simulate.rs`: grid, ray, interface,
// fresnel, spot, patch, deposit, propagate, histopyramid); what is here is
// how this kernel stores and schedules the work. One thread per patch (or
// per output slot of the HistoPyramid walk). Two deposit rules
// (`DepositRule`): the track-length fluence deposit inside the propagate
// kernel (`propagate_tube`, 64-bit fixed-point counters), or the paper's
// highest-energy ray per cell (the `mid_*` and `corner_*` kernels).
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
//   aux[3 i + 1] = (RGB flux0; tessellation depth + 256 x the region its
//                   corners cross into, region_owner + 1, 0 between
//                   crossings: `Crossing::into`, patch_depth, patch_into)
//   aux[3 i + 2] = (RGB differential irradiance, W/m^2; the share of its
//                   flux the surface it straddles has let through so far,
//                   1 between crossings: `Crossing::kept`)
// The medium: the index channel (n, grad(n^2 / 2)) and the RGB extinction
// as 3D textures; with Fresnel, the interface sides of the index channel
// and the boundary indicator as a third, (n_lo, n_hi, delta, 0) per cell
// (`eikon_grid::interface`).
//
// Generated ahead of this source: `SimParams` (the parameter block `P`),
// `Level`, the stats slots (E_*, S_*, STATS_WORDS), the fates (FATE_*),
// the incident light's kinds (INCIDENT_*), NONE and LOCAL_CELLS.

@group(0) @binding(0) var<storage, read> P: SimParams;
@group(0) @binding(1) var index_tex: texture_3d<f32>;
@group(0) @binding(2) var ext_tex: texture_3d<f32>;
@group(0) @binding(3) var<storage, read> empty: array<f32>;
@group(0) @binding(4) var<storage, read_write> stats: array<atomic<u32>>;
// Two HistoPyramids: the counts' from 0, the split flags' from
// P.splits_base (the `histopyramid` module's hook).
@group(0) @binding(5) var<storage, read_write> pyramid: array<u32>;
@group(0) @binding(6) var<storage, read_write> fate: array<u32>;
// This step's deposits of each patch, (cell or NONE, packed key): slot 0
// its midpoint's, slots 1..4 its corners'. The passes after the first
// read them instead of recomputing; the winner recomputes its value.
@group(0) @binding(7) var<storage, read_write> deps: array<vec2<u32>>;
@group(0) @binding(8) var fresnel_tex: texture_3d<f32>;
// With sharp interfaces (P.sharp = 1), the regions (`region::gpu_regions`:
// the objects in precedence order, then the ambient medium); else one
// placeholder.
@group(0) @binding(9) var<storage, read> regions: array<RegionGpu>;
// With sharp interfaces, the frontier of the torn patches' trees of
// quarters: two levels of P.front_cap entries (patch, node), where node is
// level << 16 | path (two bits a level, the first quarter highest), with
// PIECE_TAG once the node has held together. Else one placeholder.
@group(0) @binding(10) var<storage, read_write> front: array<vec2<u32>>;
// With sharp interfaces, the regions' shape data (`region::gpu_regions`:
// profiles, mesh triangles and BVH nodes); else one placeholder.
@group(0) @binding(11) var<storage, read> shape_data: array<vec4<u32>>;

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

@group(3) @binding(0) var<storage, read> L: PyramidLevel;

// ---------------------------------------------------------------------
// Deterministic energy tallies: 64-bit fixed point (value * P.scale) in
// two u32 words with carry. Integer addition is associative, so the sums
// do not depend on the order the threads run in. Each workgroup sums its
// threads' tallies in workgroup memory first (`wg_stats`, the layout of
// `stats`) and adds them to `stats` once (`wg_begin`, `wg_end`): one
// global atomic per workgroup instead of one per patch.
var<workgroup> wg_stats: array<atomic<u32>, STATS_WORDS>;

fn add_fixed(w: u32, lo_u: u32, hi_u: u32, global: bool) {
    var old = 0u;
    if global {
        old = atomicAdd(&stats[w], lo_u);
    } else {
        old = atomicAdd(&wg_stats[w], lo_u);
    }
    var carry = 0u;
    if old + lo_u < old {
        carry = 1u;
    }
    if hi_u + carry > 0u {
        if global {
            atomicAdd(&stats[w + 1u], hi_u + carry);
        } else {
            atomicAdd(&wg_stats[w + 1u], hi_u + carry);
        }
    }
}

fn wg_begin(li: u32) {
    if li < STATS_WORDS {
        atomicStore(&wg_stats[li], 0u);
    }
    workgroupBarrier();
}

fn wg_end(li: u32) {
    workgroupBarrier();
    if li < S_EXITED / 2u {
        let lo = atomicLoad(&wg_stats[2u * li]);
        let hi = atomicLoad(&wg_stats[2u * li + 1u]);
        if lo != 0u || hi != 0u {
            add_fixed(2u * li, lo, hi, true);
        }
    } else if li >= S_EXITED && li < STATS_WORDS {
        let c = atomicLoad(&wg_stats[li]);
        if c != 0u {
            atomicAdd(&stats[li], c);
        }
    }
}

fn add_energy(category: u32, channel: u32, value: f32) {
    let x = value * P.scale;
    if !(x >= 1.0) {
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
// The medium.

// The `ray` module's hook: the index field as light sees it
// (`propagate::Bounded`): n and grad n (stored grad(n^2 / 2) over n)
// inside the bounds, no gradient outside.
// With sharp interfaces, inside `region_step`, the profile of region
// `field_region` instead.
fn index_field(p: vec3<f32>) -> vec4<f32> {
    if field_region != NONE {
        return region_index(field_region, p, P.channel);
    }
    let v = tri_lerp(index_tex, grid_trilinear(P.grid, p));
    let inv = 1.0 / v.x;
    var g = v.yzw * inv;
    if !grid_contains(P.grid, p) {
        g = vec3<f32>(0.0);
    }
    return vec4<f32>(v.x, g);
}

// Extinction sigma_t per world unit (`Medium::sample_rgb`).
fn sample_ext(p: vec3<f32>) -> vec3<f32> {
    return tri_sum(ext_tex, grid_trilinear(P.grid, p)).xyz;
}

// The uniform index of the empty block around `p`, or -1
// (`EmptySpace::index_at`).
fn empty_at(p: vec3<f32>) -> f32 {
    let u = (p - P.grid.min) * P.inv_block;
    if !all(u >= vec3<f32>(0.0)) {
        return -1.0;
    }
    // Bounded before the conversion (see `grid_cell_of`).
    let c = vec3<u32>(min(u, vec3<f32>(P.empty_dims)));
    if any(c >= P.empty_dims) {
        return -1.0;
    }
    return empty[(c.x * P.empty_dims.y + c.y) * P.empty_dims.z + c.z];
}

// ---------------------------------------------------------------------
// Patches (`patch.rs`).

// Corner c relative to corner 0.
fn rel(i: u32, c: u32) -> vec3<f32> {
    if c == 0u {
        return vec3<f32>(0.0);
    }
    return pos[4u * i + c].xyz;
}

// Corner c's world position.
fn corner_x(i: u32, c: u32) -> vec3<f32> {
    return pos[4u * i].xyz + rel(i, c);
}

// `Patches::midpoint`.
fn midpoint(i: u32) -> vec3<f32> {
    return pos[4u * i].xyz + (rel(i, 1u) + rel(i, 2u) + rel(i, 3u)) * 0.25;
}

// `Patches::direction`.
fn direction(i: u32) -> vec3<f32> {
    var d = vec3<f32>(0.0);
    for (var c = 0u; c < 4u; c++) {
        d += normalize_or_zero(vel[4u * i + c].xyz);
    }
    return normalize_or_zero(d);
}

// ---------------------------------------------------------------------
// Step 1 [Ihrke07 eqs 14-15, 18] and step 2 [Ihrke07 eq 17]:
// `propagate::propagate` and `Patches::irradiance`.

// sigma_t / n per channel (zero outside the bounds and in empty space).
fn extinction_per_index(p: vec3<f32>) -> vec3<f32> {
    if !grid_contains(P.grid, p) || empty_at(p) >= 0.0 {
        return vec3<f32>(0.0);
    }
    return sample_ext(p) / index_field(p).x;
}

// `Interfaces::transmittance`: the power fraction kept over the
// displacement dx about p travelling with eikonal gradient v.
fn transmittance(p: vec3<f32>, v: vec3<f32>, dx: vec3<f32>) -> f32 {
    if !grid_contains(P.grid, p) {
        return 1.0;
    }
    let q = grid_trilinear(P.grid, p);
    let sides = tri_sum(fresnel_tex, q);
    return interface_transmittance(sides.x, sides.y, sides.z, index_field(p).yzw, v, dx);
}

// What a patch swept in one step, for the track-length deposit: its
// corners before and after, its flux before, the step's optical depth, and
// the share of the flux about each corner (`deposit::tube_cut`).
struct Swept {
    x0: array<vec3<f32>, 4>,
    x1: array<vec3<f32>, 4>,
    flux: vec3<f32>,
    depth: vec3<f32>,
    weights: vec4<f32>,
    // Its sub-patches (`deposit_cut`'s), or (0, 0): as it is cut alone.
    cut: vec2<u32>,
}

// One step of patch i: `propagate::propagate` and, for the paper's
// deposit, `Patches::irradiance`.
fn propagate_patch(i: u32) -> Swept {
    let dt = P.dt;
    let m0 = midpoint(i);
    var flux = aux[3u * i];
    var out: Swept;
    out.flux = flux.xyz;
    out.depth = vec3<f32>(0.0);
    out.weights = vec4<f32>(1.0);
    out.cut = vec2<u32>(0u);
    for (var c = 0u; c < 4u; c++) {
        out.x0[c] = corner_x(i, c);
    }
    var skipped = false;
    // Empty space: every corner and the midpoint in empty blocks of one
    // index: a straight step without loss.
    let n = empty_at(m0);
    if n >= 0.0 {
        var all_empty = true;
        for (var c = 0u; c < 4u; c++) {
            if empty_at(out.x0[c]) != n {
                all_empty = false;
            }
        }
        if all_empty {
            var d0 = vec3<f32>(0.0);
            for (var c = 0u; c < 4u; c++) {
                let v = normalize_or_zero(vel[4u * i + c].xyz) * n;
                let d = v * (dt / (n * n));
                let p = pos[4u * i + c];
                if c == 0u {
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
    if !skipped {
        let before = extinction_per_index(m0);
        var d0 = vec3<f32>(0.0);
        let x0 = pos[4u * i].xyz;
        for (var c = 0u; c < 4u; c++) {
            let p = pos[4u * i + c];
            // On the shell |v| = n, so each corner advances exactly dt of
            // optical path and the four stay on one wavefront.
            let r = ray_step_on_shell(FORM_EQUAL_TIME, P.integrator, x0 + rel(i, c), vel[4u * i + c].xyz, dt);
            if c == 0u {
                d0 = r.inc.x;
                pos[4u * i] = vec4<f32>(p.xyz + r.inc.x, p.w + r.inc.opl);
            } else {
                pos[4u * i + c] = vec4<f32>(p.xyz + (r.inc.x - d0), p.w + r.inc.opl);
            }
            vel[4u * i + c] = vec4<f32>(r.v + r.inc.v, 0.0);
        }
        let m1 = midpoint(i);
        let after = extinction_per_index(m1);
        let depth = step_depth(P.grid, m0, m1, before, after, dt);
        out.depth = depth;
        let kept = flux.xyz * exp(-depth);
        add_energy3(E_ABSORBED, flux.xyz - kept);
        flux = vec4<f32>(kept, flux.w);
        if P.fresnel != 0u {
            var v = vec3<f32>(0.0);
            for (var c = 0u; c < 4u; c++) {
                v += vel[4u * i + c].xyz;
            }
            let t = transmittance((m0 + m1) * 0.5, v * 0.25, m1 - m0);
            if t < 1.0 {
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
    if P.fluence == 0u {
        // [Ihrke07 eq 17]: flux over the current area.
        let ar = patch_area(vec3<f32>(0.0), rel(i, 1u), rel(i, 2u), rel(i, 3u));
        var e = vec3<f32>(0.0);
        if ar > 0.0 {
            e = flux.xyz / ar;
        }
        aux[3u * i + 2u] = vec4<f32>(e, aux[3u * i + 2u].w);
    }
    return out;
}

// ---------------------------------------------------------------------
// The track-length deposit's counters: the `deposit` module cuts each
// patch's tube into pieces per cell (`deposit_tube_cut`); they are summed per
// cell in a small per-thread list (the CPU sums a layer's cells in
// `deposit::Tile`) and added to 64-bit
// fixed-point counters with two u32 atomics and a carry. Integer addition
// commutes, so the counters are the same whatever the order.

// Add the 64-bit (lo, hi) to fluence counter `c` of `cell`.
fn add_fluence(c: u32, cell: u32, lo: u32, hi: u32) {
    var old = 0u;
    switch c {
        case 0u: { old = atomicAdd(&fl_lo0[cell], lo); }
        case 1u: { old = atomicAdd(&fl_lo1[cell], lo); }
        default: { old = atomicAdd(&fl_lo2[cell], lo); }
    }
    let h = hi + select(0u, 1u, old + lo < old);
    if h != 0u {
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
    if h != 0u {
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
        if u >= 1.0 {
            let w = split64(u);
            add_fluence(c, cell, w.x, w.y);
        }
    }
    for (var a = 0u; a < 3u; a++) {
        let u = floor(abs(fx[a]) + 0.5);
        if u >= 1.0 {
            var w = split64(u);
            if fx[a] < 0.0 {
                // Two's complement of the 64-bit magnitude.
                w = vec2<u32>(~w.x + 1u, ~w.y + select(0u, 1u, w.x == 0u));
            }
            add_flux(a, cell, w.x, w.y);
        }
    }
}

// The cells one patch's chords reach in one step, summed before they go
// to the counters (a short list searched per amount: private memory per
// thread is small; the CPU's `deposit::Tile` is indexed directly).
var<private> local_cell: array<u32, LOCAL_CELLS>;
var<private> local_fl: array<vec3<f32>, LOCAL_CELLS>;
var<private> local_fx: array<vec3<f32>, LOCAL_CELLS>;
var<private> local_len: u32;

fn local_flush() {
    for (var k = 0u; k < local_len; k++) {
        add_units(local_cell[k], local_fl[k], local_fx[k]);
    }
    local_len = 0u;
}

// The `deposit` module's hook.
fn deposit_put(cell: u32, fl: vec3<f32>, fx: vec3<f32>) {
    for (var k = local_len; k > 0u; k--) {
        if local_cell[k - 1u] == cell {
            local_fl[k - 1u] += fl;
            local_fx[k - 1u] += fx;
            return;
        }
    }
    if local_len == LOCAL_CELLS {
        local_flush();
    }
    local_cell[local_len] = cell;
    local_fl[local_len] = fl;
    local_fx[local_len] = fx;
    local_len += 1u;
}

// Deposit the tube a patch swept (`deposit::tube`).
fn tube(sw: Swept) {
    local_len = 0u;
    var k = sw.cut;
    if all(k == vec2<u32>(0u)) {
        k = deposit_cut(sw.x0, sw.x1, P.grid.voxel);
    }
    deposit_tube_cut(P.grid, ChordScales(P.fl_scale, P.flux_scale, P.group), sw.x0, sw.x1, sw.flux, sw.weights, sw.depth, k);
    local_flush();
}

// ---------------------------------------------------------------------
// Step 3: tessellation analysis (`refine::fate`), the book-keeping and the
// split grants (`refine::grant`).

// Whether a ray at x going along d has left the bounds for good.
fn gone(x: vec3<f32>, d: vec3<f32>) -> bool {
    return refine_gone(P.grid, x, d);
}

// The light the tessellation compares with (`Rules::incident`).
fn incident_light() -> Incident {
    return Incident(P.incident_kind, P.incident_power, P.incident_position, P.cone_axis, P.cone_angle, P.cone_falloff);
}

// The light's unobstructed irradiance per channel at x.
fn incident_at(x: vec3<f32>) -> vec3<f32> {
    return refine_incident_at(incident_light(), x);
}

// Whether patch i, `span` across, is too faint to follow (`refine::faint`).
fn too_faint(i: u32, flux: vec3<f32>, mid: vec3<f32>, span: f32) -> bool {
    var x: array<vec3<f32>, 4>;
    var v: array<vec3<f32>, 4>;
    for (var c = 0u; c < 4u; c++) {
        x[c] = corner_x(i, c);
        v[c] = vel[4u * i + c].xyz;
    }
    return refine_faint(P.grid, incident_light(), P.faint, P.corner_rays, flux, x, v, span, incident_at(mid));
}

// `refine::fate`.
fn fate_of(i: u32) -> u32 {
    // Shape measures relative to corner 0 (they do not depend on where).
    let p0 = vec3<f32>(0.0);
    let p1 = rel(i, 1u);
    let p2 = rel(i, 2u);
    let p3 = rel(i, 3u);
    let dir = direction(i);
    let mid = midpoint(i);
    let flux = aux[3u * i];
    let f0 = aux[3u * i + 1u];
    var exit = false;
    if P.fluence == 0u {
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
    if exit {
        return FATE_EXIT;
    }
    if all(flux.xyz <= P.threshold * f0.xyz) {
        return FATE_ABSORBED;
    }
    if P.faint > 0.0 && too_faint(i, flux.xyz, mid, patch_span(p0, p1, p2, p3)) {
        // Still travelling, too faint to follow: trapped.
        return FATE_FAINT;
    }
    if P.fluence == 0u && dot(patch_normal(p0, p1, p2, p3), dir) <= 0.0 {
        return FATE_CAUSTIC;
    }
    if patch_span(p0, p1, p2, p3) > P.split_span && patch_depth(f0.w) < P.max_depth {
        // Too dim to be worth more patches (`Rules::dim`).
        if P.dim > 0.0 && below(flux.xyz, P.dim * patch_area(p0, p1, p2, p3), incident_at(mid)) {
            return FATE_RETAIN;
        }
        if P.sharp != 0u && straddles(i) {
            // `refine::Hold`: new corners would mix a refracted direction
            // with an unrefracted one.
            return FATE_RETAIN;
        }
        return FATE_SPLIT;
    }
    return FATE_RETAIN;
}

// The fate of patch i, its split flag, and its part of the tallies
// (`refine::tally`).
fn analyse_patch(i: u32) {
    if P.sharp != 0u && i < P.sharp_n && fate[i] == FATE_TORN {
        // A torn patch: its pieces carry its flux on (after the list), its
        // slot ends here; `grant` gives it no slot.
        pyramid[P.splits_base + i] = 0u;
        return;
    }
    let f = fate_of(i);
    fate[i] = f;
    pyramid[P.splits_base + i] = select(0u, 1u, f == FATE_SPLIT);
    let flux = aux[3u * i].xyz;
    switch f {
        case FATE_EXIT: {
            atomicAdd(&wg_stats[S_EXITED], 1u);
            add_energy3(E_EXITED, flux);
        }
        case FATE_ABSORBED: {
            atomicAdd(&wg_stats[S_ABSORBED], 1u);
            add_energy3(E_CULLED, flux);
        }
        case FATE_FAINT: {
            atomicAdd(&wg_stats[S_FAINT], 1u);
            add_energy3(E_TRAPPED, flux);
        }
        case FATE_CAUSTIC: {
            atomicAdd(&wg_stats[S_CAUSTIC], 1u);
            add_energy3(E_CULLED, flux);
        }
        case FATE_RETAIN: {
            atomicAdd(&wg_stats[S_KEPT], 1u);
        }
        default: {
            atomicAdd(&wg_stats[S_SPLITS], 1u);
        }
    }
}

// `refine::grant`: splits that would overflow `max_patches` are refused,
// earlier patches first: a split is granted when fewer than `room` splits
// precede it, its rank read off the split flags' pyramid. The patch's
// count (0, 1 or 4) goes to the base of the counts' pyramid.
fn grant_patch(i: u32) {
    let f = fate[i];
    var count = 0u;
    if f == FATE_RETAIN {
        count = 1u;
    } else if f == FATE_SPLIT {
        let kept = atomicLoad(&stats[S_KEPT]);
        let nsplit = atomicLoad(&stats[S_SPLITS]);
        var room = 0u;
        if P.max_patches > kept + nsplit {
            room = (P.max_patches - (kept + nsplit)) / 3u;
        }
        var rank = 0u;
        if room < nsplit {
            rank = hp_rank(P.splits_base, P.n, i);
        }
        if rank < room {
            count = 4u;
        } else {
            count = 1u;
            atomicAdd(&stats[S_HELD], 1u);
        }
    }
    pyramid[i] = count;
}

// ---------------------------------------------------------------------
// `refine::rebuild`: one thread per output slot finds its source patch and
// part on the counts' pyramid (compaction and expansion in one phase) and
// writes the patch: a copy, or a child of a tessellated patch (`Split`).
fn rebuild_slot(k: u32) {
    let found = hp_locate(0u, P.n_old, k);
    let i = found.x;
    if pyramid[i] == 1u {
        for (var c = 0u; c < 4u; c++) {
            dpos[4u * k + c] = pos[4u * i + c];
            dvel[4u * k + c] = vel[4u * i + c];
        }
        for (var a = 0u; a < 3u; a++) {
            daux[3u * k + a] = aux[3u * i + a];
        }
        return;
    }
    let part = found.y;
    var x: array<vec3<f32>, 4>;
    var v: array<vec3<f32>, 4>;
    var o: array<vec3<f32>, 4>;
    for (var c = 0u; c < 4u; c++) {
        x[c] = rel(i, c);
        v[c] = vel[4u * i + c].xyz;
        o[c] = vec3<f32>(pos[4u * i + c].w, 0.0, 0.0);
    }
    let split = patch_split(x);
    var areas: array<f32, 4>;
    var total = 0.0;
    for (var q = 0u; q < 4u; q++) {
        let c = patch_child(x, patch_split_rect(split, q));
        areas[q] = patch_area(c[0], c[1], c[2], c[3]);
        total += areas[q];
    }
    var share = 0.25;
    if total > 0.0 {
        share = areas[part] / total;
    }
    let r = patch_split_rect(split, part);
    let cx = patch_child(x, r);
    let cv = patch_child(v, r);
    let co = patch_child(o, r);
    for (var c = 0u; c < 4u; c++) {
        // Bilinear v has the right direction but not |v| = n.
        let vn = normalize_or_zero(cv[c]) * shell_index(pos[4u * i].xyz + cx[c]);
        if c == 0u {
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
    if ar > 0.0 {
        e = fl / ar;
    }
    // A child keeps its parent's share through a surface it straddles.
    daux[3u * k + 2u] = vec4<f32>(e, aux[3u * i + 2u].w);
}

// ---------------------------------------------------------------------
// Step 4: voxelization by the highest-energy rule (`voxelize`, [Ihrke07 sec 5.2.2]), with
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
    let s = dot(d, grid_voxel_center(P.grid, flat) - mid);
    var m: array<vec3<f32>, 4>;
    var x: array<vec3<f32>, 4>;
    var u: array<vec3<f32>, 4>;
    for (var c = 0u; c < 4u; c++) {
        x[c] = rel(i, c);
        u[c] = normalize_or_zero(vel[4u * i + c].xyz);
        m[c] = x[c] + u[c] * s;
    }
    let ar = patch_area(m[0], m[1], m[2], m[3]);
    if (!(ar > 0.0)) {
        return Deposit(false, 0u, vec3<f32>(0.0));
    }
    let half = 0.5 * P.grid.voxel;
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
    let cell = grid_cell_of(P.grid, mid);
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
    let mc = grid_cell_of(P.grid, mid);
    var seen = array<u32, 5>(NONE, NONE, NONE, NONE, NONE);
    if (mc.ok) {
        seen[0] = mc.flat;
    }
    var any_cell = false;
    for (var c = 0u; c < 4u; c++) {
        let cell = grid_cell_of(P.grid, corner_x(i, c));
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

@compute @workgroup_size(WORKGROUP)
fn mid_max(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item(id, groups);
    if (i < P.n) {
        midpoint_max(i);
    }
}

@compute @workgroup_size(WORKGROUP)
fn mid_owner(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item(id, groups);
    if (i < P.n) {
        offer_owner(i, 0u, P.stamp);
    }
}

@compute @workgroup_size(WORKGROUP)
fn mid_write(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item(id, groups);
    if (i < P.n) {
        midpoint_write(i);
    }
}

@compute @workgroup_size(WORKGROUP)
fn corner_max(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item(id, groups);
    if (i < P.n) {
        corners_max(i);
    }
}

@compute @workgroup_size(WORKGROUP)
fn corner_owner(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item(id, groups);
    if (i < P.n) {
        for (var c = 1u; c < 5u; c++) {
            offer_owner(i, c, P.stamp + 1u);
        }
    }
}

@compute @workgroup_size(WORKGROUP)
fn corner_write(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item(id, groups);
    if (i < P.n) {
        corners_write(i);
    }
}
// ---------------------------------------------------------------------
// Sharp interfaces (`propagate::Sharp`, `[grid] interfaces = "sharp"`):
// each corner crosses every surface on its own with `region_step` (the
// `region_step` module, the twin of the CPU's `Regions::step`), the flux
// takes each corner's Fresnel transmittance to the power 1/4, and a patch
// whose corners disagree is taken back to where the step began and split
// in four, each piece traced again, down to MAX_SPLIT_LEVEL levels, a node
// no longer than `P.min_span` going on as a thin tube about its centre ray
// (`propagate::split_and_trace`). Here the tree of
// quarters is traced level by level, one node per thread: pass 0 steps
// every patch that holds together and marks a torn one; then, for each
// level, a pass traces the nodes of that level (the frontier)
// without depositing and writes how many entries each passes to the next
// (4 quarters of a torn node, 1 for a piece, 0 for a node dropped), and
// `front_build` builds the HistoPyramid of those counts, which the next
// level's threads walk to find their node. A piece passes through the
// later levels unchanged, so the last level's frontier lists every piece
// of every torn patch, patch by patch, each patch's in the CPU's depth-first
// order. `sharp_count` writes each torn patch's number of pieces into the
// pieces' pyramid, which gives them their slots after the list, in patch
// order; pass 2 (one thread per piece) traces each again,
// depositing and tallying, and writes it there. Where the pieces go is
// fixed before any is written, so the list is the same whatever the order
// the threads run in. One node per thread also keeps each invocation's
// loops short, which lavapipe needs: llvmpipe ends every loop of an
// invocation once all of them together have run 65535 iterations
// (LP_MAX_TGSI_LOOP_ITERATIONS, counted per SIMD group), and a torn
// patch's whole tree walked in one invocation, on meshes and solids of
// revolution, ran past that.

// The `region` module's hooks.
fn region_count() -> u32 {
    return P.region_count;
}

fn region_object(i: u32) -> RegionGpu {
    return regions[i];
}

// The `surface` module's hook: the shapes' data buffer (solids of
// revolution's profiles, meshes' triangles and BVH nodes).
fn surface_data(i: u32) -> vec4<u32> {
    return shape_data[i];
}

// The `region_step` module's hook: the region whose own profile
// `index_field` returns (NONE: the voxel field).
var<private> field_region: u32 = NONE;

// The index new corners take (`refine::rebuild`, `propagate::RegionIndex`
// with sharp interfaces: the own index of the region that owns p).
fn shell_index(p: vec3<f32>) -> f32 {
    if P.sharp != 0u {
        return region_index(region_owner(p), p, P.channel).x;
    }
    return index_field(p).x;
}

// `refine::Hold` with sharp interfaces: patch i's corners lie in
// different regions.
fn straddles(i: u32) -> bool {
    let at = region_owner(corner_x(i, 0u));
    for (var c = 1u; c < 4u; c++) {
        if region_owner(corner_x(i, c)) != at {
            return true;
        }
    }
    return false;
}

// A patch's corner rays: absolute positions, eikonal gradients, optical
// paths.
struct Quad {
    x: array<vec3<f32>, 4>,
    v: array<vec3<f32>, 4>,
    opl: vec4<f32>,
}

fn load_quad(i: u32) -> Quad {
    var q: Quad;
    let x0 = pos[4u * i].xyz;
    for (var c = 0u; c < 4u; c++) {
        q.x[c] = x0 + rel(i, c);
        q.v[c] = vel[4u * i + c].xyz;
        q.opl[c] = pos[4u * i + c].w;
    }
    return q;
}

fn store_quad(k: u32, q: Quad) {
    for (var c = 0u; c < 4u; c++) {
        var x = q.x[c];
        if c != 0u {
            x -= q.x[0];
        }
        pos[4u * k + c] = vec4<f32>(x, q.opl[c]);
        vel[4u * k + c] = vec4<f32>(q.v[c], 0.0);
    }
}

fn quad_span(q: Quad) -> f32 {
    return patch_span(q.x[0], q.x[1], q.x[2], q.x[3]);
}

// Quarter `part` of q (`Split::Quarters`, `Split::child`), its gradients
// rescaled to the own index where each new corner lies.
fn quad_child(q: Quad, part: u32) -> Quad {
    let r = patch_split_rect(SPLIT_QUARTERS, part);
    let cx = patch_child(q.x, r);
    let cv = patch_child(q.v, r);
    var o: array<vec3<f32>, 4>;
    for (var c = 0u; c < 4u; c++) {
        o[c] = vec3<f32>(q.opl[c], 0.0, 0.0);
    }
    let co = patch_child(o, r);
    var out: Quad;
    for (var c = 0u; c < 4u; c++) {
        out.x[c] = cx[c];
        // Bilinear v has the right direction but not |v| = n.
        out.v[c] = normalize_or_zero(cv[c]) * shell_index(cx[c]);
        out.opl[c] = co[c].x;
    }
    return out;
}

// sigma_t / n of region ri at p with sharp interfaces: its own extinction
// over its own index (zero outside the bounds).
fn sharp_extinction_per_index(ri: u32, p: vec3<f32>) -> vec3<f32> {
    if !grid_contains(P.grid, p) {
        return vec3<f32>(0.0);
    }
    return region_extinction(ri, p) / region_index(ri, p, P.channel).x;
}

// What `sharp_patch` did: whether the corners held together, their rays
// after the step and the flux after attenuation and Fresnel.
struct Tried {
    ok: bool,
    q: Quad,
    flux: vec3<f32>,
    // The Fresnel factor the step took from the flux (1 without).
    kept: f32,
    // The region the crossing it is in goes into (`Crossing::into`).
    into: u32,
}

// The tessellation depth and the region code of a crossing packed into
// aux[3 i + 1].w, and back.
fn patch_depth(w: f32) -> u32 {
    return u32(w) & 0xffu;
}

fn patch_into(w: f32) -> u32 {
    return u32(w) >> 8u;
}

fn pack_depth(depth: u32, into: u32) -> f32 {
    return f32(depth | (into << 8u));
}

// `propagate::sharp_patch`: one step of the patch q carrying `flux`, in
// the crossing (`into`, `kept`: `Crossing`) it began the step in; with
// `write`, its tube deposited and its losses tallied. Not ok (and nothing
// done) when its corners part ways.
fn sharp_patch(q: Quad, flux: vec3<f32>, into: u32, kept_before: f32, write: bool) -> Tried {
    let dt = P.dt;
    var out = Tried(true, q, flux, 1.0, into);
    let m0 = (q.x[0] + q.x[1] + q.x[2] + q.x[3]) * 0.25;
    let ne = empty_at(m0);
    if ne >= 0.0 {
        var all_empty = true;
        for (var c = 0u; c < 4u; c++) {
            if empty_at(q.x[c]) != ne {
                all_empty = false;
            }
        }
        if all_empty {
            // Empty space holds no surface (see `propagate_patch`).
            for (var c = 0u; c < 4u; c++) {
                let v = normalize_or_zero(q.v[c]) * ne;
                out.q.v[c] = v;
                out.q.x[c] = q.x[c] + v * (dt / (ne * ne));
                out.q.opl[c] = q.opl[c] + dt;
            }
            if write && P.fluence != 0u {
                tube(Swept(q.x, out.q.x, flux, vec3<f32>(0.0), vec4<f32>(1.0), vec2<u32>(0u)));
            }
            return out;
        }
    }
    // Each corner: the step's whole optical path, surface by surface; the
    // first crossing of each.
    var has = array<bool, 4>(false, false, false, false);
    var surf: array<u32, 4>;
    var total: array<bool, 4>;
    var came: array<u32, 4>;
    var beyond: array<u32, 4>;
    var kept = 1.0;
    // The optical depth of each corner's pieces, each in the region it
    // crosses (`sharp_patch`); the patch loses the corners' mean. Where
    // each corner's path first bent, the depth before it and the share of
    // the step's time it took (`propagate::Bend`).
    var depths = array<vec3<f32>, 4>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    var bend_at: array<vec3<f32>, 4>;
    var bend_depth: array<vec3<f32>, 4>;
    var bend_time: array<f32, 4>;
    // Each corner's Fresnel transmittance over the step's crossings, and
    // its region as the step began.
    var passed = vec4<f32>(1.0);
    var owner: array<u32, 4>;
    for (var k = 0u; k < 4u; k++) {
        var ray = RegionRay(q.x[k], q.v[k], q.opl[k], region_owner(q.x[k]));
        owner[k] = ray.region;
        var left = dt;
        var on_surface = false;
        for (var s = 0u; s < MAX_CROSSINGS; s++) {
            let xa = ray.x;
            let ra = ray.region;
            let st = region_step(&ray, FORM_EQUAL_TIME, P.integrator, left, P.channel, P.sharp_eps);
            on_surface = st.at_surface;
            left -= st.used;
            depths[k] += step_depth(P.grid, xa, ray.x, sharp_extinction_per_index(ra, xa), sharp_extinction_per_index(ra, ray.x), st.used);
            if st.c.event {
                if !has[k] {
                    bend_at[k] = ray.x;
                    bend_depth[k] = depths[k];
                    bend_time[k] = (dt - left) / dt;
                    has[k] = true;
                    surf[k] = st.surface;
                    total[k] = st.c.total;
                    came[k] = st.came;
                    beyond[k] = st.beyond;
                }
                if !st.c.total {
                    kept *= pow(max(1.0 - st.c.reflectance, 0.0), 0.25);
                    passed[k] *= max(1.0 - st.c.reflectance, 0.0);
                }
            }
            if !st.at_surface || left <= 0.0 {
                break;
            }
        }
        if on_surface {
            region_settle(&ray, P.sharp_eps);
        }
        out.q.x[k] = ray.x;
        out.q.v[k] = ray.v;
        out.q.opl[k] = ray.opl;
    }
    // Torn, as on the CPU: two corners meet the same surface and one
    // refracts where the other reflects totally; two meet different
    // surfaces that are not layers of one path; or a corner that crossed
    // nothing is still where the others came from and, straight ahead
    // within the patch's reach, meets none of their surfaces.
    var refracted = false;
    for (var a = 0u; a < 4u; a++) {
        if !has[a] {
            continue;
        }
        refracted = refracted || !total[a];
        for (var b = a + 1u; b < 4u; b++) {
            if !has[b] {
                continue;
            }
            var together = false;
            if surf[a] == surf[b] {
                together = total[a] == total[b];
            } else {
                together = beyond[a] == came[b] || beyond[b] == came[a] || (came[a] == came[b] && beyond[a] == beyond[b]);
            }
            if !together {
                out.ok = false;
                return out;
            }
        }
    }
    if refracted {
        let reach = max(quad_span(out.q), quad_span(q)) * 2.0 + dt;
        for (var k = 0u; k < 4u; k++) {
            if has[k] {
                continue;
            }
            let at = region_owner(out.q.x[k]);
            var from_here = false;
            var into_here = false;
            for (var e = 0u; e < 4u; e++) {
                from_here = from_here || (has[e] && came[e] == at);
                into_here = into_here || (has[e] && beyond[e] == at);
            }
            if !from_here || into_here {
                continue;
            }
            let hit = region_next_surface(out.q.x[k], normalize_or_zero(out.q.v[k]), P.sharp_eps, reach);
            var meets = false;
            for (var e = 0u; e < 4u; e++) {
                meets = meets || (hit.ok && has[e] && surf[e] == hit.obj);
            }
            if !meets {
                out.ok = false;
                return out;
            }
        }
    }
    let depth = (depths[0] + depths[1] + depths[2] + depths[3]) * 0.25;
    if write && P.fluence != 0u {
        // `propagate::bent_tube`: through each corner's first bend, in two
        // pieces, a corner that did not bend straight (one call site of the
        // deposit: each is inlined).
        var bent = 0u;
        var time = 0.0;
        for (var k = 0u; k < 4u; k++) {
            if has[k] {
                bent += 1u;
                time += bend_time[k];
            }
        }
        // The light about a corner that has crossed is what the surface
        // let through.
        let codes = vec4<u32>(owner[0], owner[1], owner[2], owner[3]) + vec4<u32>(1u);
        let weights = straddle_weights(codes, into, kept_before, select(vec4<f32>(1.0), passed, P.fresnel != 0u));
        var sw = Swept(q.x, out.q.x, flux, depth, weights.before, vec2<u32>(0u));
        var mid = out.q.x;
        var before = vec3<f32>(0.0);
        if bent > 0u {
            time /= f32(bent);
            for (var k = 0u; k < 4u; k++) {
                if has[k] {
                    mid[k] = bend_at[k];
                    before += bend_depth[k] * 0.25;
                } else {
                    mid[k] = q.x[k] + (out.q.x[k] - q.x[k]) * time;
                    before += depths[k] * (time * 0.25);
                }
            }
            sw.x1 = mid;
            sw.depth = before;
            // Both pieces in the same sub-patches (`bent_tube`).
            let ka = deposit_cut(q.x, mid, P.grid.voxel);
            let kb = deposit_cut(mid, out.q.x, P.grid.voxel);
            if ka.x != 0u && kb.x != 0u {
                sw.cut = max(ka, kb);
            }
        }
        for (var piece = 0u; piece < 1u + min(bent, 1u); piece++) {
            if piece == 1u {
                sw = Swept(mid, out.q.x, flux * exp(-before), max(depth - before, vec3<f32>(0.0)), weights.after, sw.cut);
            }
            tube(sw);
        }
    }
    let through = flux * exp(-depth);
    if write {
        add_energy3(E_ABSORBED, flux - through);
    }
    out.flux = through;
    // A crossing begins with the first corner that refracts.
    if into == 0u {
        for (var k = 0u; k < 4u; k++) {
            if out.into == 0u && has[k] && !total[k] {
                out.into = beyond[k] + 1u;
            }
        }
    }
    if P.fresnel != 0u {
        out.kept = kept;
    }
    return out;
}

// Whether the corners of q are in one region (`propagate::crossing_done`:
// a crossing is over).
fn one_region(q: Quad) -> bool {
    let r = region_owner(q.x[0]);
    var one = true;
    for (var c = 1u; c < 4u; c++) {
        one = one && region_owner(q.x[c]) == r;
    }
    return one;
}

// Where a patch's Fresnel reflection is (`propagate::reflection`).
struct Reflected {
    // Traced (`traced_reflection_of`); `patch_reflection` sets it where
    // every corner's incidence was found.
    ok: bool,
    // Every corner's incidence found, as `ok` left by `patch_reflection`.
    found: bool,
    // The reflected corners (in the order 0 3 2 1 of the patch's, which
    // keeps the orientation), and where each left the surface.
    q: Quad,
    hits: array<vec3<f32>, 4>,
    // The share of the patch's flux the surface lets through, set by
    // `traced_reflection_of`: `tau` where found, else the corners' factors
    // (`Crossing::kept`).
    kept: f32,
    // Fresnel's transmittance over the patch from its corners' incidence
    // (`fresnel_patch_transmittance`; `propagate::Reflection::transmitted`).
    tau: f32,
    // The optical depth the patch was charged beyond the surface since its
    // corners crossed, and the one the reflected light loses on its way
    // back (the corners' means; `propagate::Reflection`).
    restored: vec3<f32>,
    depth: vec3<f32>,
}

// `propagate::reflection`: the reflection of the patch m whose corners
// have all crossed one surface from one region into another, region `to`
// (corner 0's). Each corner is followed back along its line to the
// surface (at most REACH_SPANS spans and a step), its incident gradient
// found by Snell's law in reverse, and the reflected ray sent from there
// for the optical path the corner has come since.
fn patch_reflection(m: Quad, to: u32) -> Reflected {
    var out: Reflected;
    out.ok = false;
    let eps = P.sharp_eps;
    let reach = quad_span(m) * REACH_SPANS + P.dt;
    var surface = NONE;
    var came = NONE;
    // Some corner meets the surface with R > 0 and none with R = 1.
    var reflects = false;
    var r: Quad;
    var hits: array<vec3<f32>, 4>;
    var incidence: array<vec3<f32>, 4>;
    var restored = vec3<f32>(0.0);
    var depth = vec3<f32>(0.0);
    // Every corner must have arrived: checked for all four before any is
    // followed back (the search for the surface is what costs).
    for (var k = 1u; k < 4u; k++) {
        if region_owner(m.x[k]) != to {
            return out;
        }
    }
    for (var k = 0u; k < 4u; k++) {
        let d = normalize_or_zero(m.v[k]);
        // From just ahead, so that a corner that ended on the surface
        // finds it.
        let o = m.x[k] + d * (2.0 * eps);
        let hit = region_next_surface(o, -d, eps, reach);
        if !hit.ok || (surface != NONE && surface != hit.obj) {
            return out;
        }
        surface = hit.obj;
        let p = o - d * hit.t;
        let along = select(-hit.normal, hit.normal, dot(hit.normal, d) >= 0.0);
        let behind = region_owner(p - along * eps);
        if behind == to || (came != NONE && came != behind) {
            return out;
        }
        came = behind;
        let n1 = region_index(behind, p, P.channel).x;
        let n2 = region_index(to, p, P.channel).x;
        let back_in = region_refract(-d * n2, -along, n1);
        if back_in.w == 0.0 {
            return out;
        }
        let vi = -back_in.xyz;
        let cos_i = dot(vi / n1, along);
        let rho = fresnel_reflectance(cos_i, n1, n2);
        if !(rho < 1.0) {
            return out;
        }
        reflects = reflects || rho > 0.0;
        incidence[k] = vec3<f32>(cos_i, n1, n2);
        let back = 0.5 * (n2 + region_index(to, m.x[k], P.channel).x) * max(hit.t - 2.0 * eps, 0.0);
        restored += step_depth(P.grid, p, m.x[k], sharp_extinction_per_index(to, p), sharp_extinction_per_index(to, m.x[k]), back);
        var ray = RegionRay(p, vi - along * (2.0 * dot(vi, along)), m.opl[k] - back, behind);
        var left = back;
        for (var s = 0u; s < MAX_CROSSINGS; s++) {
            if left <= 0.0 {
                break;
            }
            let xa = ray.x;
            let ra = ray.region;
            let st = region_step(&ray, FORM_EQUAL_TIME, P.integrator, left, P.channel, eps);
            left -= st.used;
            depth += step_depth(P.grid, xa, ray.x, sharp_extinction_per_index(ra, xa), sharp_extinction_per_index(ra, ray.x), st.used);
            if !st.at_surface {
                break;
            }
        }
        // A corner that crossed at the end of its step is sent back from
        // the surface itself.
        region_settle(&ray, eps);
        r.x[k] = ray.x;
        r.v[k] = ray.v;
        r.opl[k] = ray.opl;
        hits[k] = p;
    }
    if !reflects {
        return out;
    }
    out.ok = true;
    out.tau = fresnel_patch_transmittance(incidence);
    out.restored = restored * 0.25;
    out.depth = depth * 0.25;
    let order = array<u32, 4>(0u, 3u, 2u, 1u);
    for (var c = 0u; c < 4u; c++) {
        out.q.x[c] = r.x[order[c]];
        out.q.v[c] = r.v[order[c]];
        out.q.opl[c] = r.opl[order[c]];
        out.hits[c] = hits[order[c]];
    }
    return out;
}

// The reflected flux of a patch that came with `came`: what the surface
// does not let through.
fn tallied_reflection(came: vec3<f32>, r: Reflected) -> vec3<f32> {
    return came * (1.0 - r.kept);
}

// The reflected flux at the surface: the tallied one with the absorption
// beyond the surface given back (`propagate::crossing_done`).
fn reflected_flux(came: vec3<f32>, r: Reflected) -> vec3<f32> {
    return tallied_reflection(came, r) * exp(r.restored);
}

// The Fresnel split of a patch at `moved` whose corners have all crossed
// into region `to`, carrying `came`, emitted with `flux0`, its corners'
// factors `kept` (`propagate::crossing_done`): where its corners'
// incidence is found (`found`), the surface lets `tau` through (`kept`);
// its reflection is traced (`ok`) if `traceable`, reflections are traced,
// and it is not below REFLECT_MIN of what the patch was emitted with.
fn traced_reflection_of(moved: Quad, to: u32, came: vec3<f32>, flux0: vec3<f32>, kept: f32, traceable: bool) -> Reflected {
    var r = patch_reflection(moved, to);
    r.found = r.ok;
    r.kept = select(kept, r.tau, r.found);
    if r.ok && (!traceable || P.reflections == 0u || all(reflected_flux(came, r) < REFLECT_MIN * flux0)) {
        r.ok = false;
    }
    return r;
}

// A split whose reflection is not traced: the reflected flux tallied at
// the surface (the absorption it was charged beyond it given back); the
// flux that goes on.
fn untraced_split(came: vec3<f32>, r: Reflected) -> vec3<f32> {
    let tallied = tallied_reflection(came, r);
    let f = reflected_flux(came, r);
    add_energy3(E_REFLECTED, f);
    add_energy3(E_RESTORED, f - tallied);
    return came * r.kept;
}

// Pass 1: deposit the reflection's tube from the surface (of a patch that
// came with `came`), and tally what it gets back off the absorbed; the
// flux it goes on with.
fn traced_reflection(r: Reflected, came: vec3<f32>) -> vec3<f32> {
    let tallied = tallied_reflection(came, r);
    let f = reflected_flux(came, r);
    if P.fluence != 0u {
        tube(Swept(r.hits, r.q.x, f, r.depth, vec4<f32>(1.0), vec2<u32>(0u)));
    }
    let out = f * exp(-r.depth);
    add_energy3(E_RESTORED, f - tallied);
    add_energy3(E_ABSORBED, f - out);
    atomicAdd(&wg_stats[S_REFLECTIONS], 1u);
    return out;
}

// [Ihrke07 eq 17]'s irradiance of a patch: flux over its area.
fn quad_irradiance(q: Quad, flux: vec3<f32>) -> vec3<f32> {
    let ar = patch_area(q.x[0], q.x[1], q.x[2], q.x[3]);
    var e = vec3<f32>(0.0);
    if ar > 0.0 {
        e = flux / ar;
    }
    return e;
}

// Write patch `slot` of the live list.
fn write_patch(slot: u32, q: Quad, flux: vec3<f32>, flux0: vec3<f32>, area0: f32, depth: f32, kept: f32) {
    store_quad(slot, q);
    aux[3u * slot] = vec4<f32>(flux, area0);
    aux[3u * slot + 1u] = vec4<f32>(flux0, depth);
    aux[3u * slot + 2u] = vec4<f32>(quad_irradiance(q, flux), kept);
}

// Quarter `part` of q with its share of q's flux (`split_and_trace`: in
// proportion to the quarters' areas).
struct Quarter {
    q: Quad,
    share: f32,
}

fn quarter(q: Quad, part: u32) -> Quarter {
    var sum = 0.0;
    var mine = 0.0;
    for (var c = 0u; c < 4u; c++) {
        let cx = patch_child(q.x, patch_split_rect(SPLIT_QUARTERS, c));
        let ar = patch_area(cx[0], cx[1], cx[2], cx[3]);
        sum += ar;
        mine = select(mine, ar, c == part);
    }
    var share = 0.25;
    if sum > 0.0 {
        share = mine / sum;
    }
    return Quarter(quad_child(q, part), share);
}

// A node of a torn patch's tree of quarters: its corners and flux (RGB,
// and area0 in w), derived from the patch's quarter by quarter down its
// path (two bits per level, the first quarter in the highest bits),
// exactly as the recursion of `split_and_trace` derives them.
struct Node {
    q: Quad,
    flux: vec4<f32>,
    flux0: vec3<f32>,
}

fn node_of(q: Quad, a: vec4<f32>, f0: vec3<f32>, level: u32, path: u32, thin: bool) -> Node {
    var n = Node(q, a, f0);
    for (var l = 1u; l <= level; l++) {
        let part = (path >> (2u * (level - l))) & 3u;
        let c = quarter(n.q, part);
        n.q = c.q;
        n.flux *= c.share;
        n.flux0 *= c.share;
    }
    if thin {
        n.q = quad_thin(n.q, P.min_span * THIN_SPAN);
    }
    return n;
}

// `propagate::thin_about_centre`: a quad `thin` across about the centre
// ray of q, its corners drawn in towards the centre, each moving as the
// centre ray does.
fn quad_thin(q: Quad, thin: f32) -> Quad {
    let x = (q.x[0] + q.x[1] + q.x[2] + q.x[3]) * 0.25;
    let v = normalize_or_zero(q.v[0] + q.v[1] + q.v[2] + q.v[3]) * shell_index(x);
    let shrink = thin / max(quad_span(q), thin);
    var out = q;
    for (var c = 0u; c < 4u; c++) {
        out.x[c] = x + (q.x[c] - x) * shrink;
        out.v[c] = v;
    }
    return out;
}

// Node `node` (THIN_TAG | level << 16 | path) of patch i's tree, from the
// patch in its slot (a torn patch's slot is not written during its step).
fn patch_node(i: u32, node: u32) -> Node {
    return node_of(load_quad(i), aux[3u * i], aux[3u * i + 1u].xyz, (node >> 16u) & 0xfu, node & 0xffffu, (node & THIN_TAG) != 0u);
}

// Where the counts of the frontier's level `level` are in the pyramid
// buffer (level 0: the step's patches): the counts' pyramid and the split
// flags' take turns, both free while a step propagates.
fn front_pyramid(level: u32, splits_base: u32) -> u32 {
    return select(splits_base, 0u, level % 2u == 0u);
}

// Entry k of the frontier's level `level` in `front`.
fn front_at(level: u32, k: u32) -> u32 {
    return (level % 2u) * P.front_cap + k;
}

// The frontier's entries at the last level: every piece of this step's
// torn patches, patch by patch.
fn pieces_total() -> u32 {
    if P.front_len == 0u {
        return 0u;
    }
    return hp_total(front_pyramid(MAX_SPLIT_LEVEL, P.splits_base), P.front_len);
}

// Piece k (of `pieces_total`): (patch, node).
fn piece_at(k: u32) -> vec2<u32> {
    let e = hp_locate(front_pyramid(MAX_SPLIT_LEVEL, P.splits_base), P.front_len, k).x;
    return front[front_at(MAX_SPLIT_LEVEL, e)];
}

// The first piece of patch i or of a later patch (the pieces are in patch
// order): a binary search.
fn first_piece_of(i: u32, total: u32) -> u32 {
    var lo = 0u;
    var hi = total;
    while lo < hi {
        let mid = lo + (hi - lo) / 2u;
        if piece_at(mid).x < i {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo;
}

// One thread of `propagate_sharp` (`P`'s pass `L.pass_id`, each a
// dispatch of its own): every pass traces its work with the one call of
// `sharp_patch` and finds a reflection with the one call of
// `traced_reflection_of` below, because drivers inline every call and a
// kernel with several copies of the shapes' code (a mesh's BVH, a
// profile's edges) took minutes to compile on lavapipe.
//
// - SHARP_PATCHES (pass 0), patch k (`propagate::propagate_sharp`): the
//   whole patch traced; if it held together it is written, deposited and
//   tallied, and marked if it reflects (`FATE_REFLECTS`: one piece, its
//   reflection, written by pass 1); a torn one is marked `FATE_TORN` and
//   left in its slot, to be split: its four quarters are the first level
//   of the frontier (or, no longer than the smallest split, itself as a
//   thin tube about its centre ray).
// - SHARP_LEVEL, entry k of the frontier's level P.front_level >= 1: found
//   from the level before through its pyramid (a quarter of a torn node or
//   patch, or a piece passed on), traced without depositing if it is a
//   node, and its count for the next level written: 4 (torn: its
//   quarters), 1 (a piece; or torn and no longer than the smallest split,
//   BOTTOM_TAG: itself as a thin tube, THIN_TAG, at the next level), 0 (a
//   torn thin tube, or torn at the last level: dropped, tallied as torn).
// - SHARP_REFLECTIONS (pass 1), patch k (the patches before the pieces,
//   P.n_old): a patch that held together and reflects writes its
//   reflection, found from where it is now as pass 0 found it, into its
//   slot after the list, deposits its tube and tallies it.
// - SHARP_PIECES (pass 2), piece k of the torn patches' (`pieces_total`):
//   traced again from its patch, depositing and tallying, and written in
//   its slot after the list: the patch's slots follow from the rank of its
//   pieces in the pieces' pyramid, in the order of its pieces.
fn sharp_work(k: u32, pass_id: u32) {
    // The patch, and the node of its tree traced (0: the whole patch).
    var e = vec2<u32>(k, 0u);
    let level = P.front_level;
    if pass_id == SHARP_LEVEL {
        let at = hp_locate(front_pyramid(level - 1u, P.splits_base), P.front_prev, k);
        if level == 1u {
            e = vec2<u32>(at.x, (1u << 16u) | at.y);
            // A patch no longer than the smallest split goes on as a thin
            // tube (its only entry).
            if quad_span(load_quad(at.x)) <= P.min_span {
                e.y = THIN_TAG;
            }
        } else {
            e = front[front_at(level - 1u, at.x)];
            if (e.y & PIECE_TAG) != 0u {
                // A piece, passed on.
                front[front_at(level, k)] = e;
                pyramid[front_pyramid(level, P.splits_base) + k] = 1u;
                return;
            }
            if (e.y & BOTTOM_TAG) != 0u {
                // The node itself as a thin tube (its only entry).
                e.y = (e.y & ~BOTTOM_TAG) | THIN_TAG;
            } else {
                // A quarter of a torn node, one level down.
                let depth = ((e.y >> 16u) & 0xfu) + 1u;
                e.y = (depth << 16u) | ((e.y & 0xffffu) << 2u) | at.y;
            }
        }
    } else if pass_id == SHARP_PIECES {
        e = piece_at(k);
        e.y &= ~PIECE_TAG;
    } else if pass_id == SHARP_REFLECTIONS && fate[k] != FATE_REFLECTS {
        return;
    }
    let i = e.x;
    let a = aux[3u * i];
    let f0 = aux[3u * i + 1u];
    let nd = patch_node(i, e.y);
    // The crossing the patch (or its node, a torn patch's) began the
    // step in.
    var t = Tried(true, nd.q, nd.flux.xyz, 1.0, 0u);
    if pass_id != SHARP_REFLECTIONS {
        t = sharp_patch(nd.q, nd.flux.xyz, patch_into(f0.w), aux[3u * i + 2u].w, pass_id != SHARP_LEVEL);
    }
    // The share of the flux the surface it straddles has let through
    // (`Crossing::kept`): the patch's (a torn patch's slot keeps it, for
    // its pieces) times this step's factor; pass 1 reads what pass 0
    // stored.
    let through = aux[3u * i + 2u].w * t.kept;
    // The patch as it reflects: as pass 0 stores it (and pass 1 reads it).
    var moved = t.q;
    if pass_id == SHARP_PATCHES && t.ok {
        store_quad(i, t.q);
        aux[3u * i] = vec4<f32>(t.flux, a.w);
        moved = load_quad(i);
    }
    var r: Reflected;
    r.ok = false;
    r.found = false;
    // A patch (pass 0) or piece (pass 2) whose corners have all crossed a
    // surface is split by Fresnel (`propagate::crossing_done`); pass 1
    // traces the reflection of a patch pass 0 found to reflect.
    // (The crossing is over once its corners are in one region, split or
    // not.)
    var done = pass_id == SHARP_REFLECTIONS;
    var into = t.into;
    if (pass_id == SHARP_PATCHES || pass_id == SHARP_PIECES) && t.ok && (through < 1.0 || into != 0u) {
        let over = one_region(moved);
        done = over && through < 1.0;
        into = select(into, 0u, over);
    }
    var look = pass_id == SHARP_REFLECTIONS;
    var to = 0u;
    if done {
        to = region_owner(moved.x[0]);
        // (A patch that began the step in `to` crossed nothing in it.)
        for (var c = 0u; c < 4u; c++) {
            look = look || region_owner(nd.q.x[c]) != to;
        }
    }
    if look {
        r = traced_reflection_of(moved, to, t.flux, f0.xyz, through, pass_id != SHARP_PIECES);
    } else {
        r.kept = through;
    }
    if pass_id == SHARP_PATCHES && t.ok {
        var flux = t.flux;
        // A patch that reflects keeps its factors for pass 1, which splits
        // it; one that does not is split here.
        var kept = through;
        if done && !r.ok {
            flux = untraced_split(t.flux, r);
            kept = 1.0;
            aux[3u * i] = vec4<f32>(flux, a.w);
        }
        aux[3u * i + 2u] = vec4<f32>(quad_irradiance(t.q, flux), kept);
        aux[3u * i + 1u] = vec4<f32>(f0.xyz, pack_depth(patch_depth(f0.w), into));
    }
    switch pass_id {
        case SHARP_PATCHES: {
            var quarters = 0u;
            var pieces = 0u;
            if t.ok {
                fate[i] = select(0u, FATE_REFLECTS, r.ok);
                if r.ok {
                    pieces = 1u;
                    atomicAdd(&wg_stats[S_TORN_NOW], 1u);
                }
            } else {
                fate[i] = FATE_TORN;
                atomicAdd(&wg_stats[S_TORN_NOW], 1u);
                // Its quarters, or itself as a thin tube if it is no
                // longer than the smallest split.
                quarters = select(4u, 1u, quad_span(nd.q) <= P.min_span);
            }
            pyramid[front_pyramid(0u, P.splits_base) + i] = quarters;
            pyramid[P.pieces_base + i] = pieces;
        }
        case SHARP_LEVEL: {
            var count = 1u;
            if t.ok {
                e.y |= PIECE_TAG;
            } else if (e.y & THIN_TAG) == 0u && ((e.y >> 16u) & 0xfu) + 1u <= MAX_SPLIT_LEVEL {
                count = 4u;
                if quad_span(nd.q) <= P.min_span {
                    // Itself as a thin tube at the next level.
                    count = 1u;
                    e.y |= BOTTOM_TAG;
                }
            } else {
                add_energy3(E_TORN, nd.flux.xyz);
                atomicAdd(&wg_stats[S_TORN], 1u);
                count = 0u;
            }
            front[front_at(level, k)] = e;
            pyramid[front_pyramid(level, P.splits_base) + k] = count;
        }
        case SHARP_REFLECTIONS: {
            var fl = vec3<f32>(0.0);
            var through_flux = a.xyz * r.kept;
            if r.ok {
                fl = traced_reflection(r, a.xyz);
            } else {
                // (Found as pass 0 found it, from the same input: not met.)
                through_flux = untraced_split(a.xyz, r);
            }
            // Its crossing is over: the patch's corners are in one region.
            aux[3u * i] = vec4<f32>(through_flux, a.w);
            aux[3u * i + 2u] = vec4<f32>(quad_irradiance(moved, through_flux), 1.0);
            let slot = P.n_old + hp_rank(P.pieces_base, P.n_old, i);
            write_patch(slot, r.q, fl, f0.xyz, a.w, pack_depth(patch_depth(f0.w), 0u), 1.0);
        }
        default: {
            let nth = k - first_piece_of(i, pieces_total());
            let slot = P.n_old + hp_rank(P.pieces_base, P.n_old, i) + nth;
            var flux = t.flux;
            var kept = through;
            if !t.ok {
                // The level found it whole and this trace does not (it
                // cannot, with the same code and input): dropped, counted
                // as torn.
                add_energy3(E_TORN, nd.flux.xyz);
                atomicAdd(&wg_stats[S_TORN], 1u);
                flux = vec3<f32>(0.0);
            } else if done {
                flux = untraced_split(t.flux, r);
                kept = 1.0;
            }
            write_patch(slot, t.q, flux, nd.flux0, nd.flux.w, pack_depth(patch_depth(f0.w) + 1u, into), kept);
        }
    }
}

// Torn patch i's number of pieces, into the pieces' pyramid (pass 0 wrote
// every other patch's).
fn sharp_count_patch(i: u32) {
    if fate[i] != FATE_TORN {
        return;
    }
    let total = pieces_total();
    pyramid[P.pieces_base + i] = first_piece_of(i + 1u, total) - first_piece_of(i, total);
}

// ---------------------------------------------------------------------
// Entry points, in the order a step runs them (`simulate.rs`).

// The walk, at the start of a step: the list the last step's grants
// asked for.
@compute @workgroup_size(WORKGROUP)
fn rebuild(@builtin(global_invocation_id) id: vec3<u32>,
           @builtin(num_workgroups) groups: vec3<u32>) {
    let k = item(id, groups);
    if k < P.n {
        rebuild_slot(k);
    }
}

@compute @workgroup_size(WORKGROUP)
fn propagate(@builtin(global_invocation_id) id: vec3<u32>,
             @builtin(num_workgroups) groups: vec3<u32>,
             @builtin(local_invocation_index) li: u32) {
    wg_begin(li);
    let i = item(id, groups);
    if i < P.n {
        _ = propagate_patch(i);
    }
    wg_end(li);
}

// The step with the track-length deposit of each patch's swept tube.
@compute @workgroup_size(WORKGROUP)
fn propagate_tube(@builtin(global_invocation_id) id: vec3<u32>,
                  @builtin(num_workgroups) groups: vec3<u32>,
                  @builtin(local_invocation_index) li: u32) {
    wg_begin(li);
    let i = item(id, groups);
    if i < P.n {
        tube(propagate_patch(i));
    }
    wg_end(li);
}

// The step with sharp interfaces: pass `L.pass_id` of `sharp_work` over
// its threads (the step's patches, a level's entries, or the pieces).
@compute @workgroup_size(WORKGROUP)
fn propagate_sharp(@builtin(global_invocation_id) id: vec3<u32>,
                   @builtin(num_workgroups) groups: vec3<u32>,
                   @builtin(local_invocation_index) li: u32) {
    wg_begin(li);
    let k = item(id, groups);
    let pass_id = L.pass_id;
    var n = P.n;
    if pass_id == SHARP_LEVEL {
        n = P.front_len;
    } else if pass_id == SHARP_REFLECTIONS {
        n = P.n_old;
    } else if pass_id == SHARP_PIECES {
        n = P.front_pieces;
    }
    if k < n {
        sharp_work(k, pass_id);
    }
    wg_end(li);
}

// The pyramid of a frontier level's counts, by one workgroup (a level
// holds few entries: one dispatch, not one per pyramid level).
@compute @workgroup_size(WORKGROUP)
fn front_build(@builtin(local_invocation_index) li: u32) {
    let base = front_pyramid(P.front_level, P.splits_base);
    let n = P.front_len;
    let depth = hp_depth(n);
    for (var l = 1u; l < depth; l++) {
        // Level l - 1 written by every thread of the group.
        storageBarrier();
        let len = hp_len(l, n);
        for (var j = li; j < len; j += WORKGROUP) {
            hp_reduce(base, n, l, j);
        }
    }
}

// The torn patches' numbers of pieces.
@compute @workgroup_size(WORKGROUP)
fn sharp_count(@builtin(global_invocation_id) id: vec3<u32>,
               @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item(id, groups);
    if i < P.n {
        sharp_count_patch(i);
    }
}

@compute @workgroup_size(WORKGROUP)
fn analyse(@builtin(global_invocation_id) id: vec3<u32>,
           @builtin(num_workgroups) groups: vec3<u32>,
           @builtin(local_invocation_index) li: u32) {
    wg_begin(li);
    let i = item(id, groups);
    if i < P.n {
        analyse_patch(i);
    }
    wg_end(li);
}

// One level (L.level >= 1) of the counts' or the split flags' pyramid over
// P.n entries.
@compute @workgroup_size(WORKGROUP)
fn reduce(@builtin(global_invocation_id) id: vec3<u32>,
          @builtin(num_workgroups) groups: vec3<u32>) {
    var base = 0u;
    if L.pyramid == 1u {
        base = P.splits_base;
    } else if L.pyramid == 2u {
        base = P.pieces_base;
    }
    hp_reduce(base, P.n, L.level, item(id, groups));
}

@compute @workgroup_size(WORKGROUP)
fn grant(@builtin(global_invocation_id) id: vec3<u32>,
         @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item(id, groups);
    if i < P.n {
        grant_patch(i);
    }
}

// Patches alive at the step limit: their flux is trapped.
@compute @workgroup_size(WORKGROUP)
fn cull_rest(@builtin(global_invocation_id) id: vec3<u32>,
             @builtin(num_workgroups) groups: vec3<u32>,
             @builtin(local_invocation_index) li: u32) {
    wg_begin(li);
    let i = item(id, groups);
    if i < P.n {
        add_energy3(E_TRAPPED, aux[3u * i].xyz);
    }
    wg_end(li);
}

// ---------------------------------------------------------------------
// The plan: the device schedules its own steps, so that one submission
// holds many and nothing is read back between them (`simulate.rs`,
// `GpuSimulator::trace`). Before a step `plan_step` reads the new list's
// length off the counts' pyramid, checks that it fits and that the step
// limit is not reached, and writes the step's parameter block and how many
// workgroups each of its kernels runs (indirect dispatch); with sharp
// interfaces `plan_pieces` does the same after pass 0 for the torn
// patches' pieces. The host copies `plan.params` into `P` after each.
// Where a step cannot go on (the list is empty, the step limit, a list
// or the scratch too small) the plan halts: every later dispatch of the
// submission runs no workgroup and `P` stays as it was, and the host
// reads `plan.state`, makes room or ends, and goes on from there.
// Generated ahead of this source: PL_* (the state's words), HALT_*,
// A_* (the dispatch slots), PLAN_STATE, PLAN_SLOTS and MAX_LEVELS.

struct Plan {
    state: array<u32, PLAN_STATE>,
    params: SimParams,
    args: array<u32, PLAN_ARGS>,
}

// Bound only to the plan kernels (a buffer that a dispatch reads its
// size from cannot be bound for writing in the same dispatch).
@group(3) @binding(1) var<storage, read_write> plan: Plan;

// Slot `slot` runs `items` threads: `eikon_gpu::groups`, with no
// workgroup for no item.
fn plan_args(slot: u32, items: u32) {
    let g = (items + WORKGROUP - 1u) / WORKGROUP;
    let x = min(g, 65535u);
    var y = 0u;
    if x > 0u {
        y = (g + x - 1u) / x;
    }
    plan.args[3u * slot] = x;
    plan.args[3u * slot + 1u] = y;
    plan.args[3u * slot + 2u] = min(g, 1u);
}

// The reductions of a pyramid over n entries from slot `first`: level l
// (>= 1) at `first + l - 1`, none above its top.
fn plan_levels(first: u32, n: u32) {
    let depth = hp_depth(n);
    for (var l = 1u; l < MAX_LEVELS; l++) {
        plan_args(first + l - 1u, select(0u, hp_len(l, n), l < depth));
    }
}

fn plan_halt(why: u32) {
    plan.state[PL_HALT] = why;
    for (var s = 0u; s < PLAN_SLOTS; s++) {
        plan_args(s, 0u);
    }
}

// Words of a pyramid over `cap` entries: where the split flags' pyramid
// starts (`splits_base`; the pieces' starts at twice that).
fn pyramid_words(cap: u32) -> u32 {
    return hp_offset(hp_depth(cap), cap);
}

// Before a step: the walk's length (the top of the counts' pyramid the
// last step built; the uploaded list's own at the first step), the step's
// uniforms and every slot for a step without torn patches.
@compute @workgroup_size(1)
fn plan_step() {
    plan.params = P;
    if plan.state[PL_HALT] != HALT_NONE {
        return;
    }
    let rebuild = plan.state[PL_REBUILD] != 0u;
    var total = P.n;
    if rebuild {
        total = hp_total(0u, P.n);
        plan.state[PL_PEAK] = max(plan.state[PL_PEAK], total);
    }
    plan.state[PL_TOTAL] = total;
    let cur = plan.state[PL_CUR];
    let dst = select(cur, 1u - cur, rebuild);
    if total == 0u {
        plan_halt(HALT_DONE);
        return;
    }
    if total > plan.state[PL_CAP + dst] || total > plan.state[PL_SCRATCH] {
        plan_halt(HALT_ROOM);
        return;
    }
    if plan.state[PL_STEPS] >= plan.state[PL_MAX_STEPS] {
        plan_halt(HALT_LIMIT);
        return;
    }
    plan.state[PL_STEPS] += 1u;
    plan.state[PL_CUR] = dst;
    plan.state[PL_REBUILD] = 1u;
    plan.state[PL_LEN] = total;
    let words = pyramid_words(plan.state[PL_SCRATCH]);
    plan.params.n = total;
    plan.params.n_old = select(P.n_old, P.n, rebuild);
    plan.params.stamp = plan.state[PL_STAMP];
    plan.state[PL_STAMP] += 2u;
    plan.params.splits_base = words;
    plan.params.pieces_base = 2u * words;
    atomicStore(&stats[S_KEPT], 0u);
    atomicStore(&stats[S_KEPT + 1u], 0u);
    atomicStore(&stats[S_TORN_NOW], 0u);
    plan_args(A_REBUILD, select(0u, total, rebuild));
    plan_args(A_N, total);
    plan_levels(A_LEVELS_N, total);
    plan.params.sharp_n = total;
    plan.params.front_cap = plan.state[PL_SCRATCH];
    plan.params.front_len = 0u;
    plan.params.front_pieces = 0u;
    plan.state[PL_LEVEL] = 1u;
    plan_args(A_FRONT, 0u);
    plan_args(A_BUILD, 0u);
    plan_args(A_COUNT, 0u);
    plan_args(A_PASS1, 0u);
    plan_args(A_PIECES, 0u);
    plan_args(A_LEN, total);
    plan_levels(A_LEVELS_LEN, total);
}

// Before level `PL_LEVEL` of the torn patches' trees (after pass 0, or
// after the level before): the frontier's length, off the pyramid of the
// level before (the patches' quarters at level 1), the level's uniforms,
// and its two dispatches (`propagate_sharp`'s SHARP_LEVEL pass,
// `front_build`); after the last,
// `sharp_count`'s. A frontier longer than the scratch halts the plan.
@compute @workgroup_size(1)
fn plan_level() {
    plan.params = P;
    if plan.state[PL_HALT] != HALT_NONE {
        return;
    }
    let level = plan.state[PL_LEVEL];
    let words = pyramid_words(plan.state[PL_SCRATCH]);
    var prev = P.front_len;
    if level == 1u {
        prev = P.n;
    }
    var total = 0u;
    if prev > 0u {
        total = hp_total(front_pyramid(level - 1u, words), prev);
    }
    if total > plan.state[PL_SCRATCH] {
        plan.state[PL_FRONT] = total;
        plan_halt(HALT_FRONTIER);
        return;
    }
    if level == 1u {
        plan.state[PL_DESCENT] = total;
    }
    plan.state[PL_LEVEL] = level + 1u;
    plan.params.splits_base = words;
    plan.params.pieces_base = 2u * words;
    plan.params.front_cap = plan.state[PL_SCRATCH];
    plan.params.front_level = level;
    plan.params.front_prev = prev;
    plan.params.front_len = total;
    plan_args(A_FRONT, total);
    // One workgroup builds the level's pyramid (none for an empty level:
    // the next reads no pyramid then).
    plan_args(A_BUILD, min(total, 1u));
    if level == MAX_SPLIT_LEVEL && plan.state[PL_DESCENT] > 0u {
        plan_args(A_COUNT, P.n);
    }
}

// After the torn patches' trees: with torn or reflecting patches, the
// list with their pieces after it (the pieces' pyramid gives their
// slots), passes 1 and 2's uniforms and the rest of the step's slots over
// it.
@compute @workgroup_size(1)
fn plan_pieces() {
    plan.params = P;
    if plan.state[PL_HALT] != HALT_NONE || atomicLoad(&stats[S_TORN_NOW]) == 0u {
        return;
    }
    let n = P.n;
    let words = pyramid_words(plan.state[PL_SCRATCH]);
    let len = n + hp_total(2u * words, n);
    plan.state[PL_LEN] = len;
    let cur = plan.state[PL_CUR];
    if len > plan.state[PL_CAP + cur] || len > plan.state[PL_SCRATCH] {
        plan_halt(HALT_PIECES);
        return;
    }
    var pieces = 0u;
    if P.front_len > 0u {
        pieces = hp_total(front_pyramid(MAX_SPLIT_LEVEL, words), P.front_len);
    }
    plan.params.n = len;
    plan.params.n_old = n;
    plan.params.splits_base = words;
    plan.params.pieces_base = 2u * words;
    plan.params.front_pieces = pieces;
    plan_args(A_PASS1, n);
    plan_args(A_PIECES, pieces);
    plan_args(A_LEN, len);
    plan_levels(A_LEVELS_LEN, len);
}
