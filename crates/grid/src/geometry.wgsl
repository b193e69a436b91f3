// The grid as kernels see it (`geometry.rs`, `field.rs`): bounds, cells in
// C order (x slowest, z fastest), and the cell-centre convention: sample
// (i, j, k) is the value at the centre of its cell, trilinear in between,
// the edge value held in the outer half cell. A 3D texture holds cell
// (i, j, k) at texel (k, j, i), so the CPU's arrays upload unchanged.
//
// Needs: `GridGpu` (generated).

// `GridGeometry::contains`: inside the closed bounds.
fn grid_contains(g: GridGpu, p: vec3<f32>) -> bool {
    return all(p >= g.min) && all(p <= g.max);
}

struct Clip {
    hit: bool,
    t0: f32,
    t1: f32,
}

// `GridGeometry::clip_line`: the interval of `o + t d` inside the bounds
// (slab test).
fn grid_clip_line(g: GridGpu, o: vec3<f32>, d: vec3<f32>) -> Clip {
    var t0 = -3.0e38;
    var t1 = 3.0e38;
    for (var a = 0; a < 3; a++) {
        if d[a] == 0.0 {
            if o[a] < g.min[a] || o[a] > g.max[a] {
                return Clip(false, 0.0, 0.0);
            }
        } else {
            let inv = 1.0 / d[a];
            var ta = (g.min[a] - o[a]) * inv;
            var tb = (g.max[a] - o[a]) * inv;
            if ta > tb {
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

// `GridGeometry::flat_index`.
fn grid_flat(g: GridGpu, c: vec3<u32>) -> u32 {
    return (c.x * g.dims.y + c.y) * g.dims.z + c.z;
}

// `GridGeometry::cell_of`: the cell containing p as a flat index (a point
// on the upper faces belongs to no cell).
fn grid_cell_of(g: GridGpu, p: vec3<f32>) -> Cell {
    let u = (p - g.min) / g.spacing;
    if !all(u >= vec3<f32>(0.0)) {
        return Cell(false, 0u);
    }
    // Bounded before the conversion, whose result is undefined out of
    // range (SPIR-V's OpConvertFToU; a point at infinity).
    let c = vec3<u32>(min(u, vec3<f32>(g.dims)));
    if any(c >= g.dims) {
        return Cell(false, 0u);
    }
    return Cell(true, grid_flat(g, c));
}

// `GridGeometry::voxel_center` of a flat index.
fn grid_voxel_center(g: GridGpu, flat: u32) -> vec3<f32> {
    let k = flat % g.dims.z;
    let j = (flat / g.dims.z) % g.dims.y;
    let i = flat / (g.dims.y * g.dims.z);
    return g.min + (vec3<f32>(f32(i), f32(j), f32(k)) + 0.5) * g.spacing;
}

// The eight cells around a point: the lower corner `base`, the stride per
// axis (0 along an axis of one cell) and the fractions.
struct Tri {
    base: vec3<i32>,
    stride: vec3<i32>,
    f: vec3<f32>,
}

// `GridGeometry::trilinear` / `VoxelField::sample`'s corner: clamped to
// the centres, so the edge value is held in the outer half cell.
fn grid_trilinear(g: GridGpu, p: vec3<f32>) -> Tri {
    let n = vec3<i32>(g.dims);
    let hi = vec3<f32>(n - vec3<i32>(1));
    let u = clamp((p - g.min) * g.inv_spacing - 0.5, vec3<f32>(0.0), hi);
    // u >= 0, so truncation is floor; the lower corner stops one short of
    // the last cell.
    let c = min(vec3<i32>(u), max(n - vec3<i32>(2), vec3<i32>(0)));
    let stride = select(vec3<i32>(0), vec3<i32>(1), n > vec3<i32>(1));
    return Tri(c, stride, u - vec3<f32>(c));
}

fn tri_texel(t: texture_3d<f32>, q: Tri, o: vec3<i32>) -> vec4<f32> {
    let c = q.base + o * q.stride;
    return textureLoad(t, c.zyx, 0);
}

// a + (b - a) t: equal corners give their value exactly.
fn lerp4(a: vec4<f32>, b: vec4<f32>, t: f32) -> vec4<f32> {
    return a + (b - a) * t;
}

// `VoxelField::sample`'s interpolation: along z, then y, then x, so a
// uniform region samples its own value exactly.
fn tri_lerp(t: texture_3d<f32>, q: Tri) -> vec4<f32> {
    let c00 = lerp4(tri_texel(t, q, vec3<i32>(0, 0, 0)), tri_texel(t, q, vec3<i32>(0, 0, 1)), q.f.z);
    let c01 = lerp4(tri_texel(t, q, vec3<i32>(0, 1, 0)), tri_texel(t, q, vec3<i32>(0, 1, 1)), q.f.z);
    let c10 = lerp4(tri_texel(t, q, vec3<i32>(1, 0, 0)), tri_texel(t, q, vec3<i32>(1, 0, 1)), q.f.z);
    let c11 = lerp4(tri_texel(t, q, vec3<i32>(1, 1, 0)), tri_texel(t, q, vec3<i32>(1, 1, 1)), q.f.z);
    return lerp4(lerp4(c00, c01, q.f.y), lerp4(c10, c11, q.f.y), q.f.x);
}

// `Trilinear::scalar` / `Trilinear::vec3`: the weighted sum of the eight
// corners (corner k's bits: x, y, z).
fn tri_sum(t: texture_3d<f32>, q: Tri) -> vec4<f32> {
    var s = vec4<f32>(0.0);
    for (var k = 0u; k < 8u; k++) {
        let o = vec3<u32>(k & 1u, (k >> 1u) & 1u, (k >> 2u) & 1u);
        let w = select(1.0 - q.f, q.f, o != vec3<u32>(0u));
        s += tri_texel(t, q, vec3<i32>(o)) * (w.x * w.y * w.z);
    }
    return s;
}
