// Patch geometry (`patch.rs`): a wavefront patch is the quadrilateral of
// its four corner rays, corner 0 at parameters (0, 0), 1 at (1, 0), 2 at
// (1, 1), 3 at (0, 1).
//
// Needs: SPLIT_* (generated from `Split`).

// `patch::normal`: oriented, not normalized; it flips at a caustic.
fn patch_normal(p0: vec3<f32>, p1: vec3<f32>, p2: vec3<f32>, p3: vec3<f32>) -> vec3<f32> {
    return cross(p2 - p0, p3 - p1);
}

// `patch::area`: half the cross product of the diagonals.
fn patch_area(p0: vec3<f32>, p1: vec3<f32>, p2: vec3<f32>, p3: vec3<f32>) -> f32 {
    return 0.5 * length(patch_normal(p0, p1, p2, p3));
}

// `patch::span`: the longest edge.
fn patch_span(p0: vec3<f32>, p1: vec3<f32>, p2: vec3<f32>, p3: vec3<f32>) -> f32 {
    let a = dot(p0 - p1, p0 - p1);
    let b = dot(p1 - p2, p1 - p2);
    let c = dot(p2 - p3, p2 - p3);
    let d = dot(p3 - p0, p3 - p0);
    return sqrt(max(max(a, b), max(c, d)));
}

// Bilinear weights of the corners at (s, t) (`patch::bilinear`).
fn patch_weights(s: f32, t: f32) -> vec4<f32> {
    return vec4<f32>((1.0 - s) * (1.0 - t), s * (1.0 - t), s * t, (1.0 - s) * t);
}

fn patch_bilinear(p: array<vec3<f32>, 4>, s: f32, t: f32) -> vec3<f32> {
    let w = patch_weights(s, t);
    return p[0] * w.x + p[1] * w.y + p[2] * w.z + p[3] * w.w;
}

// `Split::of`: quarters, or four strips across a side over twice as long
// as the other.
fn patch_split(p: array<vec3<f32>, 4>) -> u32 {
    let ls = max(length(p[1] - p[0]), length(p[2] - p[3]));
    let lt = max(length(p[3] - p[0]), length(p[2] - p[1]));
    if ls > 2.0 * lt {
        return SPLIT_STRIPS_S;
    }
    if lt > 2.0 * ls {
        return SPLIT_STRIPS_T;
    }
    return SPLIT_QUARTERS;
}

// `Split::rect`: the parameter rectangle (s0, t0, s1, t1) of child `part`.
fn patch_split_rect(split: u32, part: u32) -> vec4<f32> {
    let q = f32(part) * 0.25;
    if split == SPLIT_STRIPS_S {
        return vec4<f32>(q, 0.0, q + 0.25, 1.0);
    }
    if split == SPLIT_STRIPS_T {
        return vec4<f32>(0.0, q, 1.0, q + 0.25);
    }
    var st = vec2<f32>(0.0, 0.0);
    if part == 1u {
        st = vec2<f32>(0.5, 0.0);
    } else if part == 2u {
        st = vec2<f32>(0.5, 0.5);
    } else if part == 3u {
        st = vec2<f32>(0.0, 0.5);
    }
    return vec4<f32>(st, st + 0.5);
}

// `Split::child` of any per-corner vector: the child's corners over the
// rectangle r.
fn patch_child(p: array<vec3<f32>, 4>, r: vec4<f32>) -> array<vec3<f32>, 4> {
    return array<vec3<f32>, 4>(
        patch_bilinear(p, r.x, r.y),
        patch_bilinear(p, r.z, r.y),
        patch_bilinear(p, r.z, r.w),
        patch_bilinear(p, r.x, r.w),
    );
}
