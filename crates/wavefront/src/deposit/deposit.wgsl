// The track-length deposit (`deposit.rs`): the tube a patch sweeps in one
// step, as sub-patch chords with box footprints, each chord cut among the
// cells it crosses by a 3D DDA. Each piece [ta, tb] of a chord adds its
// fluence and flux-vector amounts, in fixed-point units not yet rounded,
// to its cell through the hook.
//
// Hook: `fn deposit_put(cell: u32, fluence: vec3<f32>, flux: vec3<f32>)`,
// where the pieces go (the light simulator sums them per cell in a small
// cache before its atomic adds).
// Needs: the `grid` and `patch` modules; MAX_SUBPATCHES, SUBPATCH_SIZE, SUBPATCH_SLACK,
// MAX_PARTS (generated).

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
    var weight = vec3<f32>(tb - ta);
    for (var ch = 0u; ch < 3u; ch++) {
        let tau = depth[ch];
        if tau > 0.0 {
            weight[ch] = exp(-tau * ta) * one_minus_exp(tau * (tb - ta)) / tau;
        }
    }
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

// `deposit::subpatches`: sub-patches along the two sides, (0, 0) where that
// would take more than MAX_SUBPATCHES.
fn deposit_subpatches(x0: array<vec3<f32>, 4>, x1: array<vec3<f32>, 4>, voxel: f32) -> vec2<u32> {
    let ls = sqrt(max(max(deposit_edge2(x0, 1u, 0u), deposit_edge2(x0, 2u, 3u)), max(deposit_edge2(x1, 1u, 0u), deposit_edge2(x1, 2u, 3u))));
    let lt = sqrt(max(max(deposit_edge2(x0, 3u, 0u), deposit_edge2(x0, 2u, 1u)), max(deposit_edge2(x1, 3u, 0u), deposit_edge2(x1, 2u, 1u))));
    let ks = max(ceil(ls / (SUBPATCH_SIZE * voxel) * (1.0 - SUBPATCH_SLACK)), 1.0);
    let kt = max(ceil(lt / (SUBPATCH_SIZE * voxel) * (1.0 - SUBPATCH_SLACK)), 1.0);
    if !(ks <= f32(MAX_SUBPATCHES) && kt <= f32(MAX_SUBPATCHES)) {
        return vec2<u32>(0u);
    }
    return vec2<u32>(u32(ks), u32(kt));
}

// A box footprint of `width` cells centred at cell coordinate `centre`
// (`deposit::box_parts`), as its span (lo, hi) relative to the cell of the
// centre (so that f32 keeps its digits for the offsets), narrowed to
// MAX_PARTS - 1 cells; a footprint too narrow to cut is (0, 0), one part of
// the whole width at the centre.
fn deposit_box_span(centre: f32, width: f32) -> vec2<f32> {
    let w = min(width, f32(MAX_PARTS - 1u));
    if !(w > 1e-9) || !(abs(centre) < 3.0e38) {
        return vec2<f32>(0.0);
    }
    let c = centre - floor(centre);
    return vec2<f32>(c - 0.5 * w, c + 0.5 * w);
}

// The parts of a footprint span: at least one.
fn deposit_box_count(span: vec2<f32>) -> u32 {
    if !(span.y > span.x) {
        return 1u;
    }
    return clamp(u32(ceil(span.y) - floor(span.x)), 1u, MAX_PARTS);
}

// Part k of a footprint span: (fraction of the width, offset of its centre
// from the footprint's centre, cells).
fn deposit_box_part(span: vec2<f32>, k: u32) -> vec2<f32> {
    if !(span.y > span.x) {
        return vec2<f32>(1.0, 0.0);
    }
    let base = floor(span.x) + f32(k);
    let a = max(span.x, base);
    let b = min(span.y, base + 1.0);
    return vec2<f32>(max(b - a, 0.0) / (span.y - span.x), 0.5 * (a + b) - 0.5 * (span.x + span.y));
}

// `deposit::tube`: the tube a patch sweeps in one step, corners from x0 to
// x1, carrying `flux` at the start and losing `depth` over the step.
fn deposit_tube(g: GridGpu, sc: ChordScales, x0: array<vec3<f32>, 4>, x1: array<vec3<f32>, 4>, flux: vec3<f32>, depth: vec3<f32>) {
    let k = deposit_subpatches(x0, x1, g.voxel);
    var whole = k.x > 0u;
    if whole && f32(max(k.x, k.y)) * SUBPATCH_SIZE > 2.0 {
        // Torn: over two voxels across and far from a parallelogram.
        let twist = length(x1[0] - x1[1] + x1[2] - x1[3]);
        whole = !(twist > 0.5 * patch_span(x1[0], x1[1], x1[2], x1[3]));
    }
    if !whole {
        // Along its four corner rays, a quarter each.
        for (var c = 0u; c < 4u; c++) {
            deposit_chord(g, sc, x0[c], x1[c], flux * 0.25, depth);
        }
        return;
    }
    let ns = k.x;
    let nt = k.y;
    let share = 1.0 / f32(ns * nt);
    // The axis the tube runs along most (in cells): footprints are boxes in
    // the plane of the other two.
    let run = ((x1[0] + x1[1] + x1[2] + x1[3]) - (x0[0] + x0[1] + x0[2] + x0[3])) * g.inv_spacing;
    let r = abs(run);
    var major = 2u;
    if r.x >= r.y && r.x >= r.z {
        major = 0u;
    } else if r.y >= r.z {
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
            let a = patch_bilinear(x0, sm, tm);
            let b = patch_bilinear(x1, sm, tm);
            // The sub-patch halfway through the step: its second moments
            // across the two minor axes give the box.
            let q0 = patch_bilinear(xm, s0, t0);
            let q1 = patch_bilinear(xm, s1, t0);
            let q2 = patch_bilinear(xm, s1, t1);
            let q3 = patch_bilinear(xm, s0, t1);
            let e1 = (q1 - q0 + q2 - q3) * 0.5;
            let e2 = (q3 - q0 + q2 - q1) * 0.5;
            let extent = sqrt(e1 * e1 + e2 * e2) * g.inv_spacing;
            let cc = ((a + b) * 0.5 - g.min) * g.inv_spacing;
            let sb = deposit_box_span(cc[ab], extent[ab]);
            let sc2 = deposit_box_span(cc[ac], extent[ac]);
            let nb = deposit_box_count(sb);
            let nc = deposit_box_count(sc2);
            for (var kb = 0u; kb < nb; kb++) {
                let pb = deposit_box_part(sb, kb);
                for (var kc = 0u; kc < nc; kc++) {
                    let pc = deposit_box_part(sc2, kc);
                    var off = vec3<f32>(0.0);
                    off[ab] = pb.y * g.spacing[ab];
                    off[ac] = pc.y * g.spacing[ac];
                    deposit_chord(g, sc, a + off, b + off, flux * (share * pb.x * pc.x), depth);
                }
            }
        }
    }
}
