//! Function-level parity of the wavefront crate's WGSL modules (the ones
//! the GPU simulator is composed from) with the Rust they mirror: each
//! test evaluates one shared WGSL function on a batch of inputs in a small
//! kernel and compares it with the CPU function at f32 tolerance, so a
//! drift names the function that drifted. They need a Vulkan, Metal or
//! DX12 adapter (lavapipe in CI, where a missing adapter fails them; elsewhere
//! they are reported as ignored).

use eikon_gpu::Gpu;
use eikon_gpu::DISPATCH;
use eikon_grid::geometry::{GridGpu, WGSL as GRID};
use eikon_grid::region::Region;
use eikon_grid::GridGeometry;
use eikon_shader::compose;
use eikon_testkit::parity::{bits, f32s, v4, xyz, Cases, IO};
use eikon_testkit::Tests;
use eikon_wavefront::deposit::{self, Counters};
use eikon_wavefront::patch::{area, normal, span, Crossing, Split};
use eikon_wavefront::propagate::step_depth;
use eikon_wavefront::{histopyramid, patch, propagate, refine, HistoPyramid};
use glam::DVec3;

// ---------------------------------------------------------------------
// The HistoPyramid: the module the simulator runs, against the CPU's.

fn pyramid_source() -> String {
    let main = format!(
        "{IO}
@group(0) @binding(2) var<storage, read_write> pyramid: array<u32>;

// Input (level, n, entry): one reduction step.
@compute @workgroup_size(WORKGROUP)
fn reduce(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if i >= arrayLength(&input) {{
        return;
    }}
    let a = bitcast<vec4<u32>>(input[i]);
    hp_reduce(0u, a.y, a.x, a.z);
    output[i] = vec4<f32>(0.0);
}}

// Input (slot k, n): its source, part, the total, and the rank of entry k.
@compute @workgroup_size(WORKGROUP)
fn walk(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if i >= arrayLength(&input) {{
        return;
    }}
    let a = bitcast<vec4<u32>>(input[i]);
    var found = vec2<u32>(0u);
    if a.x < hp_total(0u, a.y) {{
        found = hp_locate(0u, a.y, a.x);
    }}
    var rank = 0u;
    if a.x < a.y {{
        rank = hp_rank(0u, a.y, a.x);
    }}
    output[i] = bitcast<vec4<f32>>(vec4<u32>(found, hp_total(0u, a.y), rank));
}}
"
    );
    compose("", &[&DISPATCH, &histopyramid::WGSL], &main)
}

/// Counts from {0, 1, 4} in the proportions `mix`.
fn counts(n: usize, seed: u64, mix: [u64; 3]) -> Vec<u8> {
    let mut r = Cases::new(seed.max(1));
    (0..n)
        .map(|_| {
            let x = r.next_u64() % (mix[0] + mix[1] + mix[2]);
            if x < mix[0] {
                0
            } else if x < mix[0] + mix[1] {
                1
            } else {
                4
            }
        })
        .collect()
}

fn histopyramid_module_equals_the_cpu_pyramid(gpu: &Gpu) {
    let source = pyramid_source();
    let reduce = gpu.eval_kernel(&source, "reduce").unwrap();
    let walk = gpu.eval_kernel(&source, "walk").unwrap();
    let mut cases: Vec<Vec<u8>> = vec![vec![], vec![0], vec![4], vec![0; 1000], vec![4; 4097]];
    for (i, n) in [
        1usize, 3, 5, 17, 63, 64, 65, 255, 1023, 4099, 100_003, 1_000_001,
    ]
    .into_iter()
    .enumerate()
    {
        cases.push(counts(n, 7 + i as u64, [1, 5, 1]));
        cases.push(counts(n, 99 + i as u64, [3, 1, 3]));
    }
    let mut cpu = HistoPyramid::new();
    let mut slots = 0;
    for c in &cases {
        let n = c.len() as u32;
        // Level 0 the counts, the rest built by the module level by level.
        let mut base: Vec<u32> = c.iter().map(|&x| x as u32).collect();
        let (mut len, mut size, mut depth) = (c.len().max(1), 0, 1);
        base.resize(len, 0);
        while len > 1 {
            size += len;
            len = len.div_ceil(4);
            depth += 1;
        }
        size += 1;
        base.resize(size, 0);
        let pyramid = gpu.storage("pyramid", &base);
        let mut len = c.len().max(1);
        for level in 1..depth as u32 {
            len = len.div_ceil(4);
            let inputs: Vec<[f32; 4]> = (0..len as u32).map(|j| bits([level, n, j, 0])).collect();
            reduce
                .run(gpu, &inputs, 1, &[pyramid.as_entire_binding()])
                .unwrap();
        }
        cpu.build(c);
        let total = cpu.total();
        let threads = total.max(c.len()).max(1) as u32;
        let inputs: Vec<[f32; 4]> = (0..threads).map(|k| bits([k, n, 0, 0])).collect();
        let out = walk
            .run(gpu, &inputs, 1, &[pyramid.as_entire_binding()])
            .unwrap();
        let mut prefix = 0u32;
        for (k, o) in out.iter().enumerate() {
            let o = o.map(f32::to_bits);
            assert_eq!(o[2] as usize, total, "total of {} counts", c.len());
            if k < total {
                let (src, part) = cpu.locate(k);
                assert_eq!(
                    (o[0], o[1]),
                    (src as u32, part),
                    "slot {k} of {} counts",
                    c.len()
                );
            }
            if k < c.len() {
                assert_eq!(o[3], prefix, "rank of entry {k} of {} counts", c.len());
                prefix += c[k] as u32;
            }
        }
        slots += total;
    }
    println!("{} cases, {slots} output slots: module == CPU", cases.len());
}

// ---------------------------------------------------------------------
// Patch geometry.

fn patch_geometry_matches_the_cpu(gpu: &Gpu) {
    let main = format!(
        "{IO}
@compute @workgroup_size(WORKGROUP)
fn geometry(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if 4u * i >= arrayLength(&input) {{
        return;
    }}
    var x: array<vec3<f32>, 4>;
    for (var c = 0u; c < 4u; c++) {{
        x[c] = input[4u * i + c].xyz;
    }}
    let split = patch_split(x);
    output[6u * i] = vec4<f32>(patch_normal(x[0], x[1], x[2], x[3]), patch_area(x[0], x[1], x[2], x[3]));
    output[6u * i + 1u] = vec4<f32>(patch_span(x[0], x[1], x[2], x[3]), f32(split), 0.0, 0.0);
    for (var q = 0u; q < 4u; q++) {{
        output[6u * i + 2u + q] = patch_split_rect(split, q);
    }}
}}
"
    );
    let source = compose("", &[&DISPATCH, &patch::WGSL], &main);
    let mut r = Cases::new(11);
    let mut quads = Vec::new();
    for k in 0..2000 {
        // Near-squares, slivers both ways, and twisted quads.
        let (w, h) = match k % 4 {
            0 => (1.0, 1.0),
            1 => (3.0, 0.7),
            2 => (0.6, 2.5),
            _ => (1.0, 1.0),
        };
        let o = r.v(-2.0, 2.0);
        let jit = if k % 4 == 3 { 0.8 } else { 0.1 };
        quads.push([
            o + r.v(-jit, jit) * 0.1,
            o + DVec3::new(w, 0.0, 0.0) + r.v(-jit, jit) * 0.1,
            o + DVec3::new(w, h, 0.0) + r.v(-jit, jit) * 0.1,
            o + DVec3::new(0.0, h, 0.3) + r.v(-jit, jit) * 0.1,
        ]);
    }
    let inputs: Vec<[f32; 4]> = quads.iter().flatten().map(|&p| v4(p, 0.0)).collect();
    let out = gpu.eval(&source, "geometry", &inputs, 6, &[]).unwrap();
    for (k, p) in quads.iter().enumerate() {
        let o = &out[6 * k..];
        let n = normal(p);
        assert!(
            (xyz(o[0]) - n).length() < 1e-5 * (1.0 + n.length()),
            "normal {k}"
        );
        assert!(
            (o[0][3] as f64 - area(p)).abs() < 1e-5 * (1.0 + area(p)),
            "area {k}"
        );
        assert!(
            (o[1][0] as f64 - span(p)).abs() < 1e-5 * span(p),
            "span {k}"
        );
        let split = Split::of(p);
        assert_eq!(o[1][1] as u32, split as u32, "split {k}");
        for q in 0..4 {
            let (s0, t0, s1, t1) = split.rect(q);
            let want = [s0, t0, s1, t1].map(|x| x as f32);
            assert_eq!(o[2 + q], want, "rect {q} of {k}");
        }
    }
}

// ---------------------------------------------------------------------
// The deposit geometry: sub-patches, swept footprints, a chord's pieces.

fn grid() -> GridGeometry {
    GridGeometry::new(
        [6, 5, 4],
        DVec3::new(-1.0, -0.5, 0.0),
        DVec3::new(2.0, 2.0, 1.6),
    )
}

fn subpatches_and_swept_footprints_match_the_cpu(gpu: &Gpu) {
    let main = format!(
        "{IO}
// Input: a tube's corners before (4) and after (4), the voxel in w of the
// first: its sub-patches, and how the deposit cuts it.
@compute @workgroup_size(WORKGROUP)
fn subpatches(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if 8u * i >= arrayLength(&input) {{
        return;
    }}
    var x0: array<vec3<f32>, 4>;
    var x1: array<vec3<f32>, 4>;
    for (var c = 0u; c < 4u; c++) {{
        x0[c] = input[8u * i + c].xyz;
        x1[c] = input[8u * i + 4u + c].xyz;
    }}
    let k = deposit_subpatches(x0, x1, input[8u * i].w);
    let c = deposit_cut(x0, x1, input[8u * i].w);
    output[8u * i] = vec4<f32>(f32(k.x), f32(k.y), f32(c.x), f32(c.y));
}}

// Input (centre, width, sweep): the swept footprint's first cell, count
// and fractions.
@compute @workgroup_size(WORKGROUP)
fn swept(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if i >= arrayLength(&input) {{
        return;
    }}
    let p = deposit_swept(input[i].x, input[i].y, input[i].z);
    for (var k = 0u; k < MAX_SWEPT; k++) {{
        var f = 0.0;
        if k < p.count {{
            f = p.fraction[k];
        }}
        output[MAX_SWEPT * i + k] = vec4<f32>(f, f32(p.first), f32(p.count), 0.0);
    }}
}}

// Input (e1, major axis), (e2, 0), (moves, 0): both edges projected onto
// the layer's plane.
@compute @workgroup_size(WORKGROUP)
fn onto_layer(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if 3u * i >= arrayLength(&input) {{
        return;
    }}
    let a = input[3u * i];
    let moves = input[3u * i + 2u].xyz;
    output[3u * i] = vec4<f32>(deposit_onto_layer(a.xyz, moves, u32(a.w)), 0.0);
    output[3u * i + 1u] = vec4<f32>(deposit_onto_layer(input[3u * i + 1u].xyz, moves, u32(a.w)), 0.0);
}}

fn deposit_put(cell: u32, fluence: vec3<f32>, flux: vec3<f32>) {{}}
"
    );
    let source = compose("", &[&DISPATCH, &GRID, &patch::WGSL, &deposit::WGSL], &main);
    onto_layer_matches_the_cpu(gpu, &source);
    let mut r = Cases::new(5);
    let voxel = 0.25;
    let mut tubes = Vec::new();
    let mut inputs = Vec::new();
    for k in 0..3000 {
        // Sides of 0.2, 1.2, 1.6, 2.4, 4.8 and 10 voxels.
        let size = [0.05, 0.3, 1.2, 2.5, 0.4, 0.6][k % 6];
        let o = r.v(-1.0, 1.0);
        let x0: [DVec3; 4] = [0.0, 1.0, 1.0, 0.0]
            .into_iter()
            .zip([0.0, 0.0, 1.0, 1.0])
            .map(|(s, t)| {
                o + DVec3::new(s * size, t * size * r.f(0.3, 1.5), 0.0) + r.v(-0.02, 0.02)
            })
            .collect::<Vec<_>>()
            .try_into()
            .unwrap();
        let step = r.v(-0.1, 0.1) + DVec3::Z * 0.1;
        let x1 = x0.map(|x| x + step + r.v(-0.05, 0.05) * size);
        let x1 = x1.map(|x| DVec3::new(x.x as f32 as f64, x.y as f32 as f64, x.z as f32 as f64));
        for (c, x) in x0.iter().chain(&x1).enumerate() {
            inputs.push(v4(*x, if c == 0 { voxel } else { 0.0 }));
        }
        tubes.push((x0, x1));
    }
    let out = gpu.eval(&source, "subpatches", &inputs, 1, &[]).unwrap();
    let mut checked = 0;
    let mut capped = 0;
    for (k, (x0, x1)) in tubes.iter().enumerate() {
        let got = (out[8 * k][0] as usize, out[8 * k][1] as usize);
        let want = deposit::subpatches(x0, x1, voxel).unwrap_or((0, 0));
        let got_cut = (out[8 * k][2] as usize, out[8 * k][3] as usize);
        let want_cut = deposit::cut(x0, x1, voxel).unwrap_or((0, 0));
        // A side within f32 rounding of a sub-patch boundary (over the
        // step, or before it) may round either way, and so may a twist
        // within rounding of the torn threshold; every other case must
        // agree exactly.
        let whole = |u: f64| (u - u.round()).abs() < 1e-4;
        let near = |a: usize, b: usize, c: usize, d: usize| {
            let l0 = (x0[a] - x0[b]).length().max((x0[c] - x0[d]).length());
            let l = l0
                .max((x1[a] - x1[b]).length())
                .max((x1[c] - x1[d]).length());
            let unit = deposit::SUBPATCH_SIZE * voxel;
            whole(l / unit) || whole(l0 / unit)
        };
        let twist = (x1[0] - x1[1] + x1[2] - x1[3]).length();
        let span = eikon_wavefront::patch::span(x1);
        if near(1, 0, 2, 3) || near(3, 0, 2, 1) || (twist - 0.5 * span).abs() < 1e-4 * span {
            continue;
        }
        assert_eq!(got, want, "tube {k}");
        assert_eq!(got_cut, want_cut, "tube {k}: the cut");
        if want_cut != want && want_cut != (0, 0) {
            capped += 1;
        }
        checked += 1;
    }
    assert!(checked > 2900, "{checked}");
    assert!(
        capped > 500,
        "patches cut coarser than their sub-patches: {capped}"
    );

    let cases: Vec<(f64, f64, f64)> = (0..4000)
        .map(|k| {
            let width = match k % 5 {
                0 => 0.0,
                1 => r.f(0.0, 0.9),
                2 => r.f(0.9, 2.0),
                3 => r.f(2.0, 3.0),
                _ => r.f(3.0, 5.0),
            };
            let sweep = match k % 3 {
                0 => 0.0,
                1 => r.f(0.0, 1.0),
                _ => r.f(1.0, 2.5),
            };
            (r.f(0.0, 40.0), width, sweep)
        })
        .collect();
    let inputs: Vec<[f32; 4]> = cases
        .iter()
        .map(|&(c, w, s)| [c as f32, w as f32, s as f32, 0.0])
        .collect();
    let most = deposit::MAX_SWEPT;
    let out = gpu.eval(&source, "swept", &inputs, most, &[]).unwrap();
    let mut checked = 0;
    for (k, &(c, w, s)) in cases.iter().enumerate() {
        // The case as the GPU read it.
        let (c, w, s) = (c as f32 as f64, w as f32 as f64, s as f32 as f64);
        let want = deposit::swept_parts(c, w, s);
        let got = &out[most * k..most * (k + 1)];
        // An edge within f32 rounding of a cell face may cut a sliver
        // either side of it.
        let half = 0.5 * (w.min((deposit::MAX_PARTS - 1) as f64) + s.min(2.0));
        let on_face = |x: f64| (x - x.round()).abs() < 1e-4;
        if on_face(c - half) || on_face(c + half) {
            continue;
        }
        checked += 1;
        assert_eq!(got[0][2] as usize, want.count, "count of ({c}, {w}, {s})");
        assert_eq!(got[0][1] as i64, want.first, "first of ({c}, {w}, {s})");
        for (f, g) in want.fraction[..want.count].iter().zip(got) {
            assert!(
                (g[0] as f64 - f).abs() < 1e-5,
                "fraction of ({c}, {w}, {s}): {g:?} vs {f}"
            );
        }
    }
    assert!(checked > 3800, "{checked}");
}

/// `deposit::onto_layer` against the kernel `onto_layer` of `source`: edges
/// and motions in every direction, some moving nearly along the layer.
fn onto_layer_matches_the_cpu(gpu: &Gpu, source: &str) {
    let mut r = Cases::new(29);
    let cases: Vec<(DVec3, DVec3, DVec3, usize)> = (0..3000)
        .map(|k| {
            let m = k % 3;
            let mut moves = r.v(-2.0, 2.0);
            if k % 4 == 0 {
                // Nearly along the layer: about the guard's quarter.
                moves[m] *= r.f(0.0, 0.6);
            }
            (f32s(r.v(-1.0, 1.0)), f32s(r.v(-1.0, 1.0)), f32s(moves), m)
        })
        .collect();
    let inputs: Vec<[f32; 4]> = cases
        .iter()
        .flat_map(|&(e1, e2, mv, m)| [v4(e1, m as f64), v4(e2, 0.0), v4(mv, 0.0)])
        .collect();
    let out = gpu.eval(source, "onto_layer", &inputs, 3, &[]).unwrap();
    let (mut checked, mut oblique) = (0, 0);
    for (k, &(e1, e2, mv, m)) in cases.iter().enumerate() {
        // Within f32 rounding of the guard, either projection may be taken.
        let ratio = mv[m].abs() / mv.abs().max_element();
        if (ratio - 0.25).abs() < 1e-4 {
            continue;
        }
        // The projection divides by the motion along the axis: f32's
        // rounding grows with the stretch it gives.
        let stretch = 1.0 + (e1.length() + e2.length()) / mv[m].abs().max(1e-3);
        for (e, o) in [(e1, 0), (e2, 1)] {
            let want = deposit::onto_layer(e, mv, m);
            let got = xyz(out[3 * k + o]);
            assert!(
                (got - want).length() < 2e-6 * stretch * (1.0 + want.length()),
                "case {k}, edge {o}: {got} vs {want}"
            );
        }
        checked += 1;
        oblique += usize::from(ratio >= 0.25);
    }
    assert!(
        checked > 2900 && oblique > 2000 && checked - oblique > 300,
        "{checked} checked, {oblique} projected along the motion"
    );
}

fn a_chords_pieces_match_the_cpu_deposit(gpu: &Gpu) {
    const PIECES: usize = 16;
    let main = format!(
        "{IO}
@group(0) @binding(2) var<uniform> G: GridGpu;
@group(0) @binding(3) var<uniform> S: vec4<f32>;

var<private> pieces: u32;
var<private> first: u32;

// Each piece as (cell, fluence) and (flux vector, 0).
fn deposit_put(cell: u32, fluence: vec3<f32>, flux: vec3<f32>) {{
    if pieces < {PIECES}u {{
        output[first + 2u * pieces] = vec4<f32>(bitcast<f32>(cell), fluence);
        output[first + 2u * pieces + 1u] = vec4<f32>(flux, 0.0);
        pieces += 1u;
    }}
}}

// Input: a, b, flux, depth: the chord's pieces, the cell NONE after the last.
@compute @workgroup_size(WORKGROUP)
fn chord(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if 4u * i >= arrayLength(&input) {{
        return;
    }}
    first = 8u * {PIECES}u * i;
    pieces = 0u;
    let sc = ChordScales(S.xyz, S.w, -1);
    deposit_chord(G, sc, input[4u * i].xyz, input[4u * i + 1u].xyz, input[4u * i + 2u].xyz, input[4u * i + 3u].xyz);
    if pieces < {PIECES}u {{
        output[first + 2u * pieces] = vec4<f32>(bitcast<f32>(0xffffffffu), 0.0, 0.0, 0.0);
    }}
}}
"
    );
    let source = compose("", &[&DISPATCH, &GRID, &patch::WGSL, &deposit::WGSL], &main);
    let g = grid();
    let cells = g.voxel_count();
    let volume = {
        let s = g.spacing();
        s.x * s.y * s.z
    };
    let mut r = Cases::new(23);
    let mut chords = Vec::new();
    for k in 0..400 {
        // Inside, through the bounds, along an axis, within one cell.
        let a = r.v(-1.5, 2.5);
        let b = match k % 4 {
            0 => a + r.v(-1.0, 1.0),
            1 => r.v(-1.5, 2.5),
            2 => a + DVec3::X * r.f(0.1, 2.0),
            _ => a + r.v(-0.05, 0.05),
        };
        let b = DVec3::new(b.x as f32 as f64, b.y as f32 as f64, b.z as f32 as f64);
        let flux = [r.f(0.1, 1.0), r.f(0.0, 1.0), r.f(0.1, 1.0)];
        let depth = if k % 3 == 0 {
            DVec3::ZERO
        } else {
            r.v(0.0, 3.0)
        };
        chords.push((a, b, flux, depth));
    }
    // One chord per CPU tally, so each compares on its own.
    let counters = |_: usize| Counters::new(&g, 1, [1.0; 3], 1e9);
    let (scale, flux_scale) = counters(0).scales();
    let inputs: Vec<[f32; 4]> = chords
        .iter()
        .flat_map(|&(a, b, f, d)| {
            [
                v4(a, 0.0),
                v4(b, 0.0),
                v4(DVec3::from_array(f), 0.0),
                v4(d, 0.0),
            ]
        })
        .collect();
    let grid_buf = gpu.uniform("grid", &[GridGpu::new(&g)]);
    let scales = gpu.uniform(
        "scales",
        &[[
            scale[0] as f32,
            scale[1] as f32,
            scale[2] as f32,
            flux_scale as f32,
        ]],
    );
    let out = gpu
        .eval(
            &source,
            "chord",
            &inputs,
            2 * PIECES,
            &[grid_buf.as_entire_binding(), scales.as_entire_binding()],
        )
        .unwrap();
    let mut pieces = 0;
    for (k, &(a, b, f, d)) in chords.iter().enumerate() {
        let t = counters(k);
        t.chord(a, b, &f, d, None);
        let cpu = t.into_volume();
        let mut fl = vec![[0.0f64; 3]; cells];
        let mut fx = vec![DVec3::ZERO; cells];
        let got = &out[8 * PIECES * k..];
        for p in 0..PIECES {
            let cell = got[2 * p][0].to_bits();
            if cell == u32::MAX {
                break;
            }
            pieces += 1;
            for c in 0..3 {
                fl[cell as usize][c] += got[2 * p][1 + c] as f64 / scale[c] / volume;
            }
            fx[cell as usize] += xyz(got[2 * p + 1]) / flux_scale / volume;
        }
        let total: f64 = f.iter().sum::<f64>() * (b - a).length() / volume;
        for (cell, (fl, fx)) in fl.iter().zip(&fx).enumerate() {
            let [i, j, kk] = [cell / 20, (cell / 4) % 5, cell % 4];
            for (c, got) in fl.iter().enumerate() {
                let want = cpu.fluence[[i, j, kk, c]] as f64;
                assert!(
                    (got - want).abs() < 1e-5 * total + 1e-7,
                    "chord {k} cell {cell} channel {c}: {got} vs {want}"
                );
            }
            let want = DVec3::new(
                cpu.flux[0][[i, j, kk, 0]] as f64,
                cpu.flux[0][[i, j, kk, 1]] as f64,
                cpu.flux[0][[i, j, kk, 2]] as f64,
            );
            assert!(
                (*fx - want).length() < 1e-5 * total + 1e-7,
                "chord {k} cell {cell} flux"
            );
        }
    }
    println!("{} chords, {pieces} pieces: module == CPU", chords.len());
}

// ---------------------------------------------------------------------
// [Ihrke07 eq 18]'s step depth and the spot cone.

fn step_depth_and_the_spot_cone_match_the_cpu(gpu: &Gpu) {
    let main = format!(
        "{IO}
@group(0) @binding(2) var<uniform> G: GridGpu;

// Input: (x0, dt), x1, before, after.
@compute @workgroup_size(WORKGROUP)
fn depth(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if 4u * i >= arrayLength(&input) {{
        return;
    }}
    let x0 = input[4u * i];
    output[4u * i] = vec4<f32>(step_depth(G, x0.xyz, input[4u * i + 1u].xyz, input[4u * i + 2u].xyz, input[4u * i + 3u].xyz, x0.w), 0.0);
}}

// Input: (dir, angle), (axis, falloff).
@compute @workgroup_size(WORKGROUP)
fn cone(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if 2u * i >= arrayLength(&input) {{
        return;
    }}
    let a = input[2u * i];
    let b = input[2u * i + 1u];
    output[2u * i] = vec4<f32>(spot_cone_weight(a.xyz, b.xyz, a.w, b.w));
}}
"
    );
    let source = compose(
        "",
        &[
            &DISPATCH,
            &GRID,
            &propagate::WGSL,
            &eikon_optics::spot::WGSL,
        ],
        &main,
    );
    let g = grid();
    let grid_buf = gpu.uniform("grid", &[GridGpu::new(&g)]);
    let mut r = Cases::new(31);
    let steps: Vec<_> = (0..3000)
        .map(|_| {
            let x0 = r.v(-1.5, 2.5);
            let x1 = x0 + r.v(-0.4, 0.4);
            let x1 = DVec3::new(x1.x as f32 as f64, x1.y as f32 as f64, x1.z as f32 as f64);
            (x0, x1, r.v(0.0, 2.0), r.v(0.0, 2.0), r.f(0.01, 0.5))
        })
        .collect();
    let inputs: Vec<[f32; 4]> = steps
        .iter()
        .flat_map(|&(x0, x1, b, a, dt)| [v4(x0, dt), v4(x1, 0.0), v4(b, 0.0), v4(a, 0.0)])
        .collect();
    let out = gpu
        .eval(
            &source,
            "depth",
            &inputs,
            1,
            &[grid_buf.as_entire_binding()],
        )
        .unwrap();
    let mut crossing = 0;
    for (k, &(x0, x1, b, a, dt)) in steps.iter().enumerate() {
        let want = step_depth(&g, x0, x1, b, a, dt);
        crossing += usize::from(g.contains(x0) != g.contains(x1));
        let got = xyz(out[4 * k]);
        assert!(
            (got - want).length() < 1e-5 * (1.0 + want.length()),
            "step {k}: {got} vs {want}"
        );
    }
    assert!(crossing > 100, "{crossing} steps across the bounds");

    let cones: Vec<_> = (0..4000).map(|k| around_a_cone(&mut r, k)).collect();
    let inputs: Vec<[f32; 4]> = cones
        .iter()
        .flat_map(|&(d, a, angle, fall)| [v4(d, angle), v4(a, fall)])
        .collect();
    let out = gpu.eval(&source, "cone", &inputs, 1, &[]).unwrap();
    let mut checked = 0;
    for (k, &(d, a, angle, fall)) in cones.iter().enumerate() {
        let want = eikon_optics::spot::cone_weight(d, Some((a, angle, fall)));
        let got = out[2 * k][0] as f64;
        let Some(tol) = cone_tolerance(d, a, angle, fall) else {
            continue;
        };
        let tol = tol + 1e-6;
        assert!((got - want).abs() < tol, "cone {k}: {got} vs {want}");
        checked += 1;
    }
    assert!(checked > 3800, "{checked}");
}

// ---------------------------------------------------------------------
// A straddling patch's light per corner (`propagate::straddle_weights`)
// and its interpolation over the patch (`deposit::weight_at`).

fn straddle_weights_and_their_interpolation_match_the_cpu(gpu: &Gpu) {
    let main = format!(
        "{IO}
// Input: the corners' region codes, (into, kept, s, t), passed.
@compute @workgroup_size(WORKGROUP)
fn weights(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if 3u * i >= arrayLength(&input) {{
        return;
    }}
    let codes = vec4<u32>(input[3u * i]);
    let c = input[3u * i + 1u];
    let w = straddle_weights(codes, u32(c.x), c.y, input[3u * i + 2u]);
    output[3u * i] = w.before;
    output[3u * i + 1u] = w.after;
    output[3u * i + 2u] = vec4<f32>(deposit_weight_at(w.after, c.z, c.w));
}}

fn deposit_put(cell: u32, fluence: vec3<f32>, flux: vec3<f32>) {{}}
"
    );
    let source = compose(
        "",
        &[
            &DISPATCH,
            &GRID,
            &patch::WGSL,
            &deposit::WGSL,
            &propagate::WGSL,
        ],
        &main,
    );
    let mut r = Cases::new(71);
    let f = |x: f64| x as f32 as f64;
    // Corners in the ambient region or in one of two objects; a crossing
    // into one of them, none, or one whose corners have taken no factor;
    // each corner's transmittance over the step, some 1.
    let region = |r: &mut Cases| -> Region {
        match r.next_u64() % 3 {
            0 => None,
            k => Some(k as usize - 1),
        }
    };
    let cases: Vec<_> = (0..3000)
        .map(|k| {
            let owner = [0; 4].map(|_| region(&mut r));
            let into = if k % 7 == 0 {
                0
            } else {
                propagate::region_code(region(&mut r))
            };
            let kept = if k % 5 == 0 { 1.0 } else { f(r.f(0.3, 1.0)) };
            // (Every fourth step crosses nothing.)
            let passed = [0; 4].map(|_| {
                if k % 4 == 0 || r.f(0.0, 1.0) < 0.4 {
                    1.0
                } else {
                    f(r.f(0.5, 1.0))
                }
            });
            let (s, t) = (f(r.f(0.0, 1.0)), f(r.f(0.0, 1.0)));
            (owner, Crossing { kept, into }, passed, s, t)
        })
        .collect();
    let inputs: Vec<[f32; 4]> = cases
        .iter()
        .flat_map(|(owner, c, passed, s, t)| {
            [
                owner.map(|o| propagate::region_code(o) as f32),
                [c.into as f32, c.kept as f32, *s as f32, *t as f32],
                passed.map(|p| p as f32),
            ]
        })
        .collect();
    let out = gpu.eval(&source, "weights", &inputs, 3, &[]).unwrap();
    let (mut weighted, mut uniform) = (0, 0);
    for (k, (owner, c, passed, s, t)) in cases.iter().enumerate() {
        let (before, after) = propagate::straddle_weights(owner, *c, passed);
        let near = |got: f32, want: f64| (got as f64 - want).abs() <= 2e-6 * want.max(1.0);
        for corner in 0..4 {
            assert!(
                near(out[3 * k][corner], before[corner]),
                "case {k} corner {corner}: before {} vs {}",
                out[3 * k][corner],
                before[corner]
            );
            assert!(
                near(out[3 * k + 1][corner], after[corner]),
                "case {k} corner {corner}: after {} vs {}",
                out[3 * k + 1][corner],
                after[corner]
            );
        }
        let want = deposit::weight_at(&after, *s, *t);
        let got = out[3 * k + 2][0];
        assert!(near(got, want), "case {k}: weight {got} vs {want}");
        if before.iter().any(|&w| w != 1.0) {
            weighted += 1;
        }
        let gpu_after = out[3 * k + 1];
        if after.iter().all(|&w| w == after[0]) && gpu_after.iter().all(|&w| w == gpu_after[0]) {
            // Exactly the weight where all four are equal.
            assert_eq!(got, gpu_after[0], "case {k}");
            uniform += 1;
        }
    }
    assert!(
        weighted > 1000 && uniform > 100,
        "{weighted} weighted, {uniform} uniform"
    );
}

/// A spot's cone and a direction around its edge, `(dir, axis, angle,
/// falloff)` (degrees; the vectors rounded to f32): the `k`th of a series
/// in which every fourth cone has no falloff band.
fn around_a_cone(r: &mut Cases, k: usize) -> (DVec3, DVec3, f64, f64) {
    let axis = r.v(-1.0, 1.0).normalize();
    let angle = r.f(5.0, 80.0);
    let falloff = if k.is_multiple_of(4) {
        0.0
    } else {
        r.f(1.0, angle)
    };
    // Directions spread around the cone's edge.
    let theta = (angle + r.f(-1.5 * falloff - 5.0, 5.0)).clamp(0.0, 179.0);
    let side = axis.any_orthonormal_vector();
    let t = theta.to_radians();
    let dir = axis * t.cos() + side * t.sin();
    (f32s(dir), f32s(axis), angle, falloff)
}

/// How far the GPU's cone weight of the unit `dir` may stray from the
/// CPU's: Vulkan allows acos an error of 4096 ulp of the angle (it is
/// inherited from atan2), times the band's slope (at most 1.5 / falloff
/// per degree). `None` within f32 rounding of the edge or of the band's
/// inner edge, where the weight may fall either side of a kink.
fn cone_tolerance(dir: DVec3, axis: DVec3, angle: f64, falloff: f64) -> Option<f64> {
    let theta = dir.dot(axis).clamp(-1.0, 1.0).acos().to_degrees();
    if (theta - angle).abs() < 0.01 || (theta - (angle - falloff)).abs() < 0.01 {
        return None;
    }
    let ulp = theta.to_radians() * f32::EPSILON as f64;
    let slope = if falloff > 0.0 { 1.5 / falloff } else { 0.0 };
    Some(slope * (4096.0 * ulp).to_degrees())
}

// ---------------------------------------------------------------------
// The tessellation analysis's light tests: `refine::below` and a point
// or spot light's `refine::Incident::at`.

fn the_faint_test_and_a_point_lights_irradiance_match_the_cpu(gpu: &Gpu) {
    let main = format!(
        "{IO}
// Input: (flux, k), (incident, 0).
@compute @workgroup_size(WORKGROUP)
fn faint(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if 2u * i >= arrayLength(&input) {{
        return;
    }}
    let a = input[2u * i];
    output[2u * i] = vec4<f32>(select(0.0, 1.0, below(a.xyz, a.w, input[2u * i + 1u].xyz)));
}}

// Input: (x, spot), (position, angle), (power, falloff), (axis, 0).
@compute @workgroup_size(WORKGROUP)
fn irradiance(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if 4u * i >= arrayLength(&input) {{
        return;
    }}
    let x = input[4u * i];
    let p = input[4u * i + 1u];
    let w = input[4u * i + 2u];
    let axis = input[4u * i + 3u].xyz;
    output[4u * i] = vec4<f32>(point_irradiance(x.xyz, p.xyz, w.xyz, x.w > 0.5, axis, p.w, w.w), 0.0);
}}
"
    );
    let source = compose("", &[&DISPATCH, &refine::WGSL], &main);
    let mut r = Cases::new(47);
    let f = |x: f64| x as f32 as f64;

    // Each channel's flux near, above or below k times its irradiance,
    // or a channel the light does not carry.
    let cases: Vec<([f64; 3], f64, [f64; 3])> = (0..4000)
        .map(|_| {
            let k = f(r.f(0.05, 4.0));
            let mut flux = [0.0; 3];
            let mut incident = [0.0; 3];
            for c in 0..3 {
                let u = r.f(0.0, 1.0);
                incident[c] = if u < 0.15 { 0.0 } else { f(r.f(0.01, 3.0)) };
                let scale = if r.f(0.0, 1.0) < 0.7 {
                    r.f(0.99, 1.01)
                } else {
                    r.f(0.0, 3.0)
                };
                flux[c] = f(if incident[c] > 0.0 {
                    k * incident[c] * scale
                } else {
                    r.f(0.0, 2.0)
                });
            }
            (flux, k, incident)
        })
        .collect();
    let inputs: Vec<[f32; 4]> = cases
        .iter()
        .flat_map(|&(fl, k, inc)| {
            [
                v4(DVec3::from_array(fl), k),
                v4(DVec3::from_array(inc), 0.0),
            ]
        })
        .collect();
    let out = gpu.eval(&source, "faint", &inputs, 1, &[]).unwrap();
    let (mut yes, mut no, mut carried_not) = (0, 0, 0);
    for (n, &(fl, k, inc)) in cases.iter().enumerate() {
        // The GPU rounds k * incident to f32: a channel within that
        // rounding of the edge may fall either way.
        if (0..3).any(|c| inc[c] > 0.0 && (fl[c] - k * inc[c]).abs() <= 1e-6 * k * inc[c]) {
            continue;
        }
        let want = refine::below(&fl, k, &inc);
        let got = out[2 * n][0] == 1.0;
        assert_eq!(got, want, "case {n}: flux {fl:?}, k {k}, incident {inc:?}");
        if want {
            yes += 1;
        } else {
            no += 1;
        }
        carried_not += usize::from(inc.contains(&0.0));
    }
    assert!(
        yes > 300 && no > 300 && carried_not > 1000,
        "{yes} below, {no} not, {carried_not} with a channel not carried"
    );

    // Point and spot lights, with the receiving point around the cone's
    // edge for a spot.
    let lights: Vec<_> = (0..3000)
        .map(|k| {
            let position = r.v(-2.0, 2.0);
            let power = DVec3::new(r.f(0.0, 5.0), r.f(0.0, 5.0), r.f(0.1, 5.0));
            let spot = k % 2 == 1;
            let (dir, axis, angle, falloff) = if spot {
                around_a_cone(&mut r, k / 2)
            } else {
                (r.v(-1.0, 1.0).normalize(), DVec3::Z, 0.0, 0.0)
            };
            let x = f32s(position + dir * r.f(0.05, 3.0));
            (
                x,
                f32s(position),
                f32s(power),
                spot,
                axis,
                f(angle),
                f(falloff),
            )
        })
        .collect();
    let inputs: Vec<[f32; 4]> = lights
        .iter()
        .flat_map(|&(x, p, w, spot, axis, angle, fall)| {
            [
                v4(x, if spot { 1.0 } else { 0.0 }),
                v4(p, angle),
                v4(w, fall),
                v4(axis, 0.0),
            ]
        })
        .collect();
    let out = gpu.eval(&source, "irradiance", &inputs, 1, &[]).unwrap();
    let (mut points, mut spots) = (0, 0);
    for (n, &(x, p, w, spot, axis, angle, fall)) in lights.iter().enumerate() {
        let cone = spot.then_some((axis, angle, fall));
        let incident = refine::Incident::Point {
            position: p,
            power: w.to_array(),
            cone,
        };
        let want = DVec3::from_array(incident.at(x));
        let got = xyz(out[4 * n]);
        let unweighted = w.length() / (4.0 * std::f64::consts::PI * (x - p).length_squared());
        let mut tol = 1e-5 * unweighted;
        if spot {
            let Some(cone) = cone_tolerance((x - p).normalize(), axis, angle, fall) else {
                continue;
            };
            tol += unweighted * cone;
            spots += 1;
        } else {
            points += 1;
        }
        assert!((got - want).length() <= tol, "light {n}: {got} vs {want}");
    }
    assert!(
        points > 1400 && spots > 1300,
        "{points} point lights, {spots} spots"
    );
}

// ---------------------------------------------------------------------
// The faint rule as a whole (`refine::faint`): the midpoint's test, or a
// wide patch's corners one by one, some inside the grid and some outside
// it, heading away or back.

fn the_faint_rule_matches_the_cpu(gpu: &Gpu) {
    let main = format!(
        "{IO}
@group(0) @binding(2) var<uniform> G: GridGpu;

// Input: (flux, k), (position, kind), (power, angle), (axis, falloff),
// the corners (x, span or corner_rays in w of the first two) and their
// velocities.
@compute @workgroup_size(WORKGROUP)
fn faint(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {{
    let i = item(id, groups);
    if 12u * i >= arrayLength(&input) {{
        return;
    }}
    let a = input[12u * i];
    let p = input[12u * i + 1u];
    let w = input[12u * i + 2u];
    let ax = input[12u * i + 3u];
    let light = Incident(u32(p.w), w.xyz, p.xyz, ax.xyz, w.w, ax.w);
    var x: array<vec3<f32>, 4>;
    var v: array<vec3<f32>, 4>;
    for (var c = 0u; c < 4u; c++) {{
        x[c] = input[12u * i + 4u + c].xyz;
        v[c] = input[12u * i + 8u + c].xyz;
    }}
    let mid = 0.25 * (x[0] + x[1] + x[2] + x[3]);
    let span = input[12u * i + 4u].w;
    let corner_rays = input[12u * i + 5u].w;
    let f = refine_faint(G, light, a.w, corner_rays, a.xyz, x, v, span, refine_incident_at(light, mid));
    output[12u * i] = vec4<f32>(select(0.0, 1.0, f));
}}
"
    );
    let source = compose("", &[&DISPATCH, &GRID, &refine::WGSL], &main);
    let g = grid();
    let mut r = Cases::new(61);
    let f = |x: f64| x as f32 as f64;
    let centre = (g.min + g.max) * 0.5;
    struct Case {
        rules: refine::Rules,
        kind: u32,
        flux: [f64; 3],
        x: [DVec3; 4],
        v: [DVec3; 4],
        span: f64,
    }
    let mut cases = Vec::new();
    for k in 0..6000 {
        // A plane wave, a point light or a spot aimed near the grid.
        let kind = [
            refine::INCIDENT_UNIFORM,
            refine::INCIDENT_POINT,
            refine::INCIDENT_SPOT,
        ][k % 3];
        let position = f32s(centre + r.v(-1.0, 1.0).normalize() * r.f(3.0, 5.0));
        let power = f32s(DVec3::new(r.f(0.5, 5.0), r.f(0.5, 5.0), r.f(0.5, 5.0)));
        let axis = f32s((centre + r.v(-1.0, 1.0) - position).normalize());
        let (angle, falloff) = (f(r.f(10.0, 40.0)), f(r.f(0.0, 8.0)));
        let incident = match kind {
            refine::INCIDENT_UNIFORM => refine::Incident::Uniform(power.to_array()),
            _ => refine::Incident::Point {
                position,
                power: power.to_array(),
                cone: (kind == refine::INCIDENT_SPOT).then_some((axis, angle, falloff)),
            },
        };
        // A patch around the grid: its corners inside, across a face or
        // all outside, spread over up to two units.
        let o = centre + r.v(-1.0, 1.0) * (g.max - g.min) * 0.7;
        let size = r.f(0.05, 2.0);
        let x = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)].map(|(s, t)| {
            f32s(o + DVec3::new(s * size, t * size * 0.8, 0.3 * s * size) + r.v(-0.3, 0.3) * size)
        });
        // Corners heading back towards the grid or away from it.
        let v = x.map(|p| {
            let d = if r.f(0.0, 1.0) < 0.5 {
                centre - p + r.v(-0.5, 0.5)
            } else {
                p - centre + r.v(-0.5, 0.5)
            };
            f32s(d.normalize())
        });
        let span = f(span(&x));
        // The midpoint's test for half, the corners' for the rest.
        let corner_rays = f(span * if k % 2 == 0 { 1.3 } else { 0.7 });
        let faint = f(r.f(0.01, 0.5));
        // A flux about the limit at the midpoint (its quarter, for a
        // wide patch), or anywhere well below or above it.
        let mid = (x[0] + x[1] + x[2] + x[3]) * 0.25;
        let at = incident.at(mid);
        let share = if k % 2 == 0 { 1.0 } else { 4.0 };
        let scale = if r.f(0.0, 1.0) < 0.6 {
            r.f(0.7, 1.4)
        } else {
            r.f(0.0, 3.0)
        };
        let flux = at.map(|e| f(share * faint * e * scale));
        let rules = refine::Rules {
            split_span: 1.0,
            threshold: 0.0,
            max_patches: usize::MAX,
            max_depth: 0,
            cull_caustics: false,
            dim: 0.0,
            incident,
            faint,
            corner_rays,
        };
        cases.push(Case {
            rules,
            kind,
            flux,
            x,
            v,
            span,
        });
    }
    let inputs: Vec<[f32; 4]> = cases
        .iter()
        .flat_map(|c| {
            let (position, power, axis, angle, falloff) = match c.rules.incident {
                refine::Incident::Uniform(e) => (DVec3::ZERO, e, DVec3::Z, 0.0, 0.0),
                refine::Incident::Point {
                    position,
                    power,
                    cone,
                } => {
                    let (axis, angle, falloff) = cone.unwrap_or((DVec3::Z, 0.0, 0.0));
                    (position, power, axis, angle, falloff)
                }
            };
            let mut row = vec![
                v4(DVec3::from_array(c.flux), c.rules.faint),
                v4(position, c.kind as f64),
                v4(DVec3::from_array(power), angle),
                v4(axis, falloff),
            ];
            let w = [c.span, c.rules.corner_rays, 0.0, 0.0];
            row.extend((0..4).map(|k| v4(c.x[k], w[k])));
            row.extend(c.v.iter().map(|&d| v4(d, 0.0)));
            row
        })
        .collect();
    let grid_buf = gpu.uniform("grid", &[GridGpu::new(&g)]);
    let out = gpu
        .eval(
            &source,
            "faint",
            &inputs,
            12,
            &[grid_buf.as_entire_binding()],
        )
        .unwrap();
    // A case is compared where the CPU's answer stands when the flux moves
    // by the f32 rounding of the irradiance (and, for a spot, by how far
    // its cone weight may stray, `cone_tolerance`) and the grid's faces
    // move by a ten-thousandth of its size: a corner on a face, a ray
    // grazing an edge or a flux at the limit may fall either way.
    let (mut counted, mut yes, mut no, mut by_corners, mut outside) = (0, 0, 0, 0, 0);
    for (n, c) in cases.iter().enumerate() {
        let want = refine::faint(
            &g,
            &c.rules,
            &c.flux,
            &c.x,
            &c.v,
            c.span,
            &c.rules
                .incident
                .at((c.x[0] + c.x[1] + c.x[2] + c.x[3]) * 0.25),
        );
        let mut tol = 1e-4;
        if let refine::Incident::Point {
            position,
            cone: Some((axis, angle, falloff)),
            ..
        } = c.rules.incident
        {
            let mid = (c.x[0] + c.x[1] + c.x[2] + c.x[3]) * 0.25;
            let mut worst = Some(0.0f64);
            for p in c.x.iter().chain([&mid]) {
                worst = worst
                    .zip(cone_tolerance(
                        (*p - position).normalize(),
                        axis,
                        angle,
                        falloff,
                    ))
                    .map(|(a, b)| a.max(b));
            }
            let Some(w) = worst else {
                continue;
            };
            tol += w;
        }
        let pad = (g.max - g.min) * 1e-4;
        let stands = [-1.0, 1.0].iter().all(|&s| {
            let grown = GridGeometry::new(g.dims, g.min - pad * s, g.max + pad * s);
            let flux = c.flux.map(|x| x * (1.0 + s * tol));
            let incident = c
                .rules
                .incident
                .at((c.x[0] + c.x[1] + c.x[2] + c.x[3]) * 0.25);
            refine::faint(&grown, &c.rules, &c.flux, &c.x, &c.v, c.span, &incident) == want
                && refine::faint(&g, &c.rules, &flux, &c.x, &c.v, c.span, &incident) == want
        });
        if !stands {
            continue;
        }
        let got = out[12 * n][0] == 1.0;
        assert_eq!(
            got,
            want,
            "case {n}: {} corners inside",
            c.x.iter().filter(|&&p| g.contains(p)).count()
        );
        counted += 1;
        if want {
            yes += 1;
        } else {
            no += 1;
        }
        if c.span > c.rules.corner_rays {
            by_corners += 1;
            outside += usize::from(c.x.iter().any(|&p| !g.contains(p)));
        }
    }
    println!("{counted} cases: {yes} faint, {no} not; {by_corners} by their corners, {outside} of them with a corner outside");
    assert!(
        yes > 600 && no > 600 && by_corners > 1500 && outside > 1000,
        "{yes} faint, {no} not, {by_corners} by their corners, {outside} with a corner outside"
    );
}

fn main() {
    Tests::new()
        .gpu(
            "histopyramid_module_equals_the_cpu_pyramid",
            histopyramid_module_equals_the_cpu_pyramid,
        )
        .gpu(
            "patch_geometry_matches_the_cpu",
            patch_geometry_matches_the_cpu,
        )
        .gpu(
            "subpatches_and_swept_footprints_match_the_cpu",
            subpatches_and_swept_footprints_match_the_cpu,
        )
        .gpu(
            "a_chords_pieces_match_the_cpu_deposit",
            a_chords_pieces_match_the_cpu_deposit,
        )
        .gpu(
            "step_depth_and_the_spot_cone_match_the_cpu",
            step_depth_and_the_spot_cone_match_the_cpu,
        )
        .gpu(
            "the_faint_test_and_a_point_lights_irradiance_match_the_cpu",
            the_faint_test_and_a_point_lights_irradiance_match_the_cpu,
        )
        .gpu(
            "the_faint_rule_matches_the_cpu",
            the_faint_rule_matches_the_cpu,
        )
        .gpu(
            "straddle_weights_and_their_interpolation_match_the_cpu",
            straddle_weights_and_their_interpolation_match_the_cpu,
        )
        .run()
}
