// The track-length deposit (`deposit.rs`): the tube a patch sweeps,
// sub-patch by sub-patch, layer by layer of cells along its major axis,
// each piece's swept box footprint across the minor axes; and chords cut
// among the cells they cross by a 3D DDA (the corner rays of a torn
// patch). Each piece adds its fluence and flux-vector amounts, in
// fixed-point units not yet rounded, to its cell through the hook.
//
// Hook: `fn deposit_put(cell: u32, fluence: vec3<f32>, flux: vec3<f32>)`,
// where the pieces go (the light simulator sums them per cell in a small
// cache before its atomic adds).
// Needs: the `grid` and `patch` modules; MAX_SUBPATCHES,
// SUBPATCHES_PER_SIDE, WHOLE_SUBPATCHES, SUBPATCH_SIZE, SUBPATCH_SLACK, MAX_PARTS,
// MAX_SWEPT, MAX_CUTS (generated).

// What a chord's pieces are worth: fluence units per watt-unit of length
// per channel, flux-vector units per watt-unit of length, and the
// wavefront's colour channel with dispersion (else -1) (`Counters`).
struct ChordScales {
    fluence: vec3<f32>,
    flux: f32,
    group: i32,
}

// 1 - exp(-x) for x >= 0, without the cancellation at small x
// (`f64::exp_m1` on the CPU).
fn one_minus_exp(x: f32) -> f32 {
    if x < 0.01 {
        return x * (1.0 - x * (0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0))));
    }
    return 1.0 - exp(-x);
}

// `Sink::add`: the piece [ta, tb] of a chord in cell c. w: fluence units
// per unit of t; wf: flux-vector units per unit of t per channel; u: the
// chord's direction; depth: its optical depth per channel.
fn deposit_piece(g: GridGpu, c: vec3<i32>, ta: f32, tb: f32, w: vec3<f32>, wf: vec3<f32>, u: vec3<f32>, depth: vec3<f32>) {
    let weight = deposit_attenuated(depth, ta, tb);
    deposit_put(grid_flat(g, vec3<u32>(c)), w * weight, u * dot(wf, weight));
}

// `Counters::chord`: the chord from a to b carrying `flux` at a and losing
// optical depth `depth` over it, cut among the cells it crosses.
fn deposit_chord(g: GridGpu, sc: ChordScales, a: vec3<f32>, b: vec3<f32>, flux: vec3<f32>, depth: vec3<f32>) {
    let d = b - a;
    let len = length(d);
    if !(len > 0.0 && len < 3.0e38) {
        return;
    }
    var t0 = 0.0;
    var t1 = 1.0;
    if !(grid_contains(g, a) && grid_contains(g, b)) {
        let clip = grid_clip_line(g, a, d);
        if !clip.hit {
            return;
        }
        t0 = max(clip.t0, 0.0);
        t1 = min(clip.t1, 1.0);
    }
    if t1 <= t0 {
        return;
    }
    let w = flux * len * sc.fluence;
    var wf = flux * (len * sc.flux / 3.0);
    if sc.group >= 0 {
        wf = vec3<f32>(0.0);
        wf[sc.group] = flux[sc.group] * len * sc.flux;
    }
    let u = d / len;
    let gc = (a - g.min) * g.inv_spacing;
    let dg = d * g.inv_spacing;
    let top = vec3<i32>(g.dims) - 1;
    // Clamped before the conversion (see `grid_cell_of`).
    let topf = vec3<f32>(top);
    let first = vec3<i32>(clamp(gc + dg * t0, vec3<f32>(0.0), topf));
    let last = vec3<i32>(clamp(gc + dg * t1, vec3<f32>(0.0), topf));
    if all(first == last) {
        deposit_piece(g, first, t0, t1, w, wf, u, depth);
        return;
    }
    var cell = first;
    var step = vec3<i32>(0);
    var next = vec3<f32>(3.0e38);
    var delta = vec3<f32>(3.0e38);
    for (var ax = 0; ax < 3; ax++) {
        if dg[ax] > 0.0 {
            step[ax] = 1;
            next[ax] = (f32(cell[ax]) + 1.0 - gc[ax]) / dg[ax];
            delta[ax] = 1.0 / dg[ax];
        } else if dg[ax] < 0.0 {
            step[ax] = -1;
            next[ax] = (f32(cell[ax]) - gc[ax]) / dg[ax];
            delta[ax] = -1.0 / dg[ax];
        }
    }
    var t = t0;
    // A chord crosses at most this many cell faces.
    let most = i32(g.dims.x + g.dims.y + g.dims.z) + 3;
    for (var guard = 0; guard < most; guard++) {
        var ax = 2;
        if next.x <= next.y && next.x <= next.z {
            ax = 0;
        } else if next.y <= next.z {
            ax = 1;
        }
        let end = min(next[ax], t1);
        if end > t {
            deposit_piece(g, cell, t, end, w, wf, u, depth);
        }
        if next[ax] >= t1 {
            break;
        }
        cell[ax] += step[ax];
        if cell[ax] < 0 || cell[ax] > top[ax] {
            break;
        }
        next[ax] += delta[ax];
        t = max(t, end);
    }
}

fn deposit_edge2(p: array<vec3<f32>, 4>, a: u32, b: u32) -> f32 {
    let d = p[a] - p[b];
    return dot(d, d);
}

// `deposit::sides2`: the squared lengths of the longer of each pair of
// opposite edges, along s and along t.
fn deposit_sides2(p: array<vec3<f32>, 4>) -> vec2<f32> {
    return vec2<f32>(max(deposit_edge2(p, 1u, 0u), deposit_edge2(p, 2u, 3u)), max(deposit_edge2(p, 3u, 0u), deposit_edge2(p, 2u, 1u)));
}

// `deposit::counts`: sub-patches along sides of squared lengths l2, (0, 0)
// where that would take more than MAX_SUBPATCHES.
fn deposit_counts(l2: vec2<f32>, voxel: f32) -> vec2<u32> {
    let k = max(ceil(sqrt(l2) / (SUBPATCH_SIZE * voxel) * (1.0 - SUBPATCH_SLACK)), vec2<f32>(1.0));
    if !(k.x <= f32(MAX_SUBPATCHES) && k.y <= f32(MAX_SUBPATCHES)) {
        return vec2<u32>(0u);
    }
    return vec2<u32>(k);
}

// `deposit::subpatches`: sub-patches along the two sides, (0, 0) where that
// would take more than MAX_SUBPATCHES.
fn deposit_subpatches(x0: array<vec3<f32>, 4>, x1: array<vec3<f32>, 4>, voxel: f32) -> vec2<u32> {
    return deposit_counts(max(deposit_sides2(x0), deposit_sides2(x1)), voxel);
}

// `deposit::cut`: how `deposit_tube_cut` cuts a patch sweeping from x0 to
// x1, (ns, nt) sub-patches, or (0, 0) for along its four corner rays.
fn deposit_cut(x0: array<vec3<f32>, 4>, x1: array<vec3<f32>, 4>, voxel: f32) -> vec2<u32> {
    let start = deposit_sides2(x0);
    let k = deposit_counts(max(start, deposit_sides2(x1)), voxel);
    if k.x == 0u {
        return k;
    }
    // Over two voxels across (`deposit::wide`).
    let wide = f32(max(k.x, k.y)) * SUBPATCH_SIZE > 2.0;
    // Torn: over two voxels across and far from a parallelogram.
    if wide && length(x1[0] - x1[1] + x1[2] - x1[3]) > 0.5 * patch_span(x1[0], x1[1], x1[2], x1[3]) {
        return vec2<u32>(0u);
    }
    // Left whole by the tessellation: over one voxel across before the
    // step (`deposit::left_whole`).
    let k0 = deposit_counts(start, voxel);
    if wide || k0.x == 0u || max(k0.x, k0.y) > WHOLE_SUBPATCHES {
        return min(k, vec2<u32>(SUBPATCHES_PER_SIDE));
    }
    return k;
}

// `deposit::swept_parts`: a box footprint of `width` cells whose centre
// moves uniformly over `sweep` cells, centred at cell coordinate `centre`:
// the cells it covers (`count` from `first`) and the fraction of its mass
// each holds, the integral over each cell of the trapezoid that is the
// convolution of the two boxes. Computed relative to the cell of the
// centre, so that f32 keeps its digits.
struct SweptParts {
    first: i32,
    count: u32,
    fraction: array<f32, MAX_SWEPT>,
}

fn deposit_swept(centre: f32, width: f32, sweep: f32) -> SweptParts {
    var out: SweptParts;
    out.first = 0;
    out.count = 1u;
    out.fraction[0] = 1.0;
    if !(abs(centre) < 3.0e38) {
        return out;
    }
    let base = floor(centre);
    let c = centre - base;
    var w = 0.0;
    if width == width {
        w = min(width, f32(MAX_PARTS - 1u));
    }
    var s = 0.0;
    if sweep == sweep {
        s = min(sweep, 2.0);
    }
    let a = min(w, s);
    let b = max(w, s);
    let half = 0.5 * (a + b);
    let first = floor(c - half);
    out.first = i32(base) + i32(first);
    if b <= 1e-9 || c + half <= first + 1.0 {
        return out;
    }
    let inner = 0.5 * (b - a);
    var ramp = 0.0;
    if a > 1e-9 * b {
        ramp = 0.5 / (a * b);
    }
    let end = c + half;
    var below = 0.0;
    var k = 0u;
    for (; k < MAX_SWEPT; k++) {
        let face = first + f32(k + 1u);
        if face >= end {
            out.fraction[k] = 1.0 - below;
            k++;
            break;
        }
        let x = face - c;
        var upto: f32;
        if x <= -inner {
            upto = (x + half) * (x + half) * ramp;
        } else if x <= inner {
            upto = (x + inner) / b + 0.5 * a / b;
        } else {
            upto = 1.0 - (half - x) * (half - x) * ramp;
        }
        out.fraction[k] = upto - below;
        below = upto;
    }
    out.count = k;
    return out;
}

// `deposit::attenuated`: the integral of exp(-tau t) over [ta, tb] per
// channel.
fn deposit_attenuated(depth: vec3<f32>, ta: f32, tb: f32) -> vec3<f32> {
    var weight = vec3<f32>(tb - ta);
    for (var ch = 0u; ch < 3u; ch++) {
        let tau = depth[ch];
        if tau > 0.0 {
            weight[ch] = exp(-tau * ta) * one_minus_exp(tau * (tb - ta)) / tau;
        }
    }
    return weight;
}

// One sub-patch of a tube in cell coordinates (`deposit::Lane`).
struct DepositLane {
    at: vec3<f32>,
    moves: vec3<f32>,
    e1: vec3<f32>,
    de1: vec3<f32>,
    e2: vec3<f32>,
    de2: vec3<f32>,
    lo: f32,
    hi: f32,
    w: vec3<f32>,
    wf: vec3<f32>,
    u: vec3<f32>,
}

// `Lane::in_layer`: the part of the lane's parameter in `layer` of the
// major axis m; empty when x >= y.
fn deposit_in_layer(l: DepositLane, m: u32, layer: i32) -> vec2<f32> {
    let g = l.at[m];
    let d = l.moves[m];
    let l0 = f32(layer);
    let l1 = f32(layer + 1);
    if d > 0.0 {
        return vec2<f32>(max((l0 - g) / d, l.lo), min((l1 - g) / d, l.hi));
    } else if d < 0.0 {
        return vec2<f32>(max((l1 - g) / d, l.lo), min((l0 - g) / d, l.hi));
    } else if i32(floor(g)) == layer {
        return vec2<f32>(l.lo, l.hi);
    }
    return vec2<f32>(1.0, 0.0);
}

// `deposit::onto_layer`: a sub-patch's edge e as its footprint in a layer
// of the major axis m has it, for a sub-patch moving along `moves`: e
// projected along the motion onto the layer's plane (as it stands where it
// moves nearly along the layer).
fn deposit_onto_layer(e: vec3<f32>, moves: vec3<f32>, m: u32) -> vec3<f32> {
    let a = abs(moves);
    if a[m] >= 0.25 * max(a.x, max(a.y, a.z)) && moves[m] != 0.0 {
        return e - moves * (e[m] / moves[m]);
    }
    return e;
}

// `Lane::deposit`: the piece [ta, tb] of the lane in `layer`, its swept
// box footprint across the minor axes.
fn deposit_lane_piece(g: GridGpu, l: DepositLane, ta: f32, tb: f32, depth: vec3<f32>, axes: vec3<u32>, layer: i32) {
    let dt = tb - ta;
    if !(dt > 0.0) {
        return;
    }
    let m = axes.x;
    let ab = axes.y;
    let ac = axes.z;
    let t = 0.5 * (ta + tb);
    let c = l.at + l.moves * t;
    let e1 = l.e1 + l.de1 * t;
    let e2 = l.e2 + l.de2 * t;
    let width = sqrt(e1 * e1 + e2 * e2);
    let weight = deposit_attenuated(depth, ta, tb);
    let fl = l.w * weight;
    let along = l.u * dot(l.wf, weight);
    let pb = deposit_swept(c[ab], width[ab], abs(l.moves[ab] * dt));
    let pc = deposit_swept(c[ac], width[ac], abs(l.moves[ac] * dt));
    let dims = vec3<i32>(g.dims);
    for (var kb = 0u; kb < pb.count; kb++) {
        let ib = pb.first + i32(kb);
        if ib < 0 || ib >= dims[ab] {
            continue;
        }
        for (var kc = 0u; kc < pc.count; kc++) {
            let ic = pc.first + i32(kc);
            if ic < 0 || ic >= dims[ac] {
                continue;
            }
            var idx = vec3<u32>(0u);
            idx[m] = u32(layer);
            idx[ab] = u32(ib);
            idx[ac] = u32(ic);
            let f = pb.fraction[kb] * pc.fraction[kc];
            deposit_put(grid_flat(g, idx), fl * f, along * f);
        }
    }
}

// `deposit::weight_at`: the bilinear interpolation of per-corner weights
// at (s, t); the weight itself, exactly, where all four are equal.
fn deposit_weight_at(w: vec4<f32>, s: f32, t: f32) -> f32 {
    if all(w == vec4<f32>(w.x)) {
        return w.x;
    }
    return w[0] * ((1.0 - s) * (1.0 - t)) + w[1] * (s * (1.0 - t)) + w[2] * (s * t) + w[3] * ((1.0 - s) * t);
}

// `deposit::tube_cut`: the tube a patch sweeps along straight corner
// paths, corners from x0 to x1, carrying `flux` at the start, times the
// bilinear interpolation of the per-corner `weights`, and losing `depth`
// over the way, cut into k.x x k.y sub-patches (`deposit_cut`'s, or the
// other piece's of a bent tube), or along its four corner rays where k.x
// is 0. Sub-patch by sub-patch (the CPU goes layer by layer over all of
// them, which only orders the same pieces differently), each followed
// layer by layer along the major axis and cut where its centre crosses a
// face of the minor axes.
fn deposit_tube_cut(g: GridGpu, sc: ChordScales, x0: array<vec3<f32>, 4>, x1: array<vec3<f32>, 4>, flux: vec3<f32>, weights: vec4<f32>, depth: vec3<f32>, k: vec2<u32>) {
    if k.x == 0u {
        // Along its four corner rays, a quarter each.
        for (var c = 0u; c < 4u; c++) {
            deposit_chord(g, sc, x0[c], x1[c], flux * (0.25 * weights[c]), depth);
        }
        return;
    }
    let ns = k.x;
    let nt = k.y;
    let share = flux / f32(ns * nt);
    // The axis the tube runs along most (in cells) and the other two.
    let run = ((x1[0] + x1[1] + x1[2] + x1[3]) - (x0[0] + x0[1] + x0[2] + x0[3])) * g.inv_spacing;
    let r = abs(run);
    let tie = 1.0 - AXIS_TIE;
    var m = 2u;
    if r.x >= r.y * tie && r.x >= r.z * tie {
        m = 0u;
    } else if r.y >= r.z * tie {
        m = 1u;
    }
    let axes = vec3<u32>(m, (m + 1u) % 3u, (m + 2u) % 3u);
    let dims_m = f32(g.dims[m]);
    let top = i32(g.dims[m]) - 1;
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
            let a = patch_bilinear(x0, sm, tm);
            let b = patch_bilinear(x1, sm, tm);
            let len = length(b - a);
            if !(len > 0.0 && len < 3.0e38) {
                continue;
            }
            var l: DepositLane;
            l.at = (a - g.min) * g.inv_spacing;
            l.moves = (b - a) * g.inv_spacing;
            let p0 = patch_bilinear(x0, s0, t0);
            let p1 = patch_bilinear(x0, s1, t0);
            let p2 = patch_bilinear(x0, s1, t1);
            let p3 = patch_bilinear(x0, s0, t1);
            let q0 = patch_bilinear(x1, s0, t0);
            let q1 = patch_bilinear(x1, s1, t0);
            let q2 = patch_bilinear(x1, s1, t1);
            let q3 = patch_bilinear(x1, s0, t1);
            let e1 = (p1 - p0 + p2 - p3) * 0.5;
            let e2 = (p3 - p0 + p2 - p1) * 0.5;
            let f1 = (q1 - q0 + q2 - q3) * 0.5;
            let f2 = (q3 - q0 + q2 - q1) * 0.5;
            // Edges projected along the lane's motion onto the layers'
            // plane (`deposit::onto_layer`).
            l.e1 = deposit_onto_layer(e1 * g.inv_spacing, l.moves, m);
            l.de1 = deposit_onto_layer((f1 - e1) * g.inv_spacing, l.moves, m);
            l.e2 = deposit_onto_layer(e2 * g.inv_spacing, l.moves, m);
            l.de2 = deposit_onto_layer((f2 - e2) * g.inv_spacing, l.moves, m);
            // The part of the centre's path inside the grid along the
            // major axis.
            if l.moves[m] != 0.0 {
                let ta = -l.at[m] / l.moves[m];
                let tb = (dims_m - l.at[m]) / l.moves[m];
                l.lo = max(min(ta, tb), 0.0);
                l.hi = min(max(ta, tb), 1.0);
            } else if l.at[m] >= 0.0 && l.at[m] < dims_m {
                l.lo = 0.0;
                l.hi = 1.0;
            } else {
                continue;
            }
            if !(l.hi > l.lo) {
                continue;
            }
            let mine = share * deposit_weight_at(weights, sm, tm);
            l.w = mine * len * sc.fluence;
            l.wf = mine * (len * sc.flux / 3.0);
            if sc.group >= 0 {
                l.wf = vec3<f32>(0.0);
                l.wf[sc.group] = mine[sc.group] * len * sc.flux;
            }
            l.u = (b - a) / len;
            // Clamped before the conversion (see `grid_cell_of`).
            let la = i32(clamp(floor(l.at[m] + l.moves[m] * l.lo), 0.0, f32(top)));
            let lb = i32(clamp(floor(l.at[m] + l.moves[m] * l.hi), 0.0, f32(top)));
            for (var layer = min(la, lb); layer <= max(la, lb); layer++) {
                let span = deposit_in_layer(l, m, layer);
                let ta = span.x;
                let tb = span.y;
                if !(tb > ta) {
                    continue;
                }
                // Cut where the centre crosses a face of a minor axis.
                var cuts: array<f32, 10>;
                var n = 1u;
                cuts[0] = ta;
                for (var q = 1u; q < 3u; q++) {
                    let ax = axes[q];
                    let ya = l.at[ax] + l.moves[ax] * ta;
                    let yb = l.at[ax] + l.moves[ax] * tb;
                    var face = floor(min(ya, yb)) + 1.0;
                    let last = n + MAX_CUTS;
                    for (; face < max(ya, yb) && n < last; face += 1.0) {
                        cuts[n] = clamp((face - l.at[ax]) / l.moves[ax], ta, tb);
                        n++;
                    }
                }
                cuts[n] = tb;
                n++;
                // Insertion sort of the inner cuts.
                for (var p = 2u; p + 1u < n; p++) {
                    let v = cuts[p];
                    var q = p;
                    for (; q > 1u && cuts[q - 1u] > v; q--) {
                        cuts[q] = cuts[q - 1u];
                    }
                    cuts[q] = v;
                }
                for (var p = 0u; p + 1u < n; p++) {
                    deposit_lane_piece(g, l, cuts[p], cuts[p + 1u], depth, axes, layer);
                }
            }
        }
    }
}
