// Exact ray-surface crossings, outward normals and signed distances of the
// analytic shapes (`surface.rs`, `shape.rs`) in f32: the sphere, the box
// (not rounded), the capped cylinder and the half-space, with the same
// closed forms as `Shape::first_crossing`, `Shape::normal` and
// `Shape::distance`. A local frame is the rotation `rot` (its columns the
// shape's axes) about the centre: `local = transpose(rot) * (p - c)`.
//
// Needs: the `vector` module.

const SURFACE_FAR: f32 = 3.0e38;

// Where a segment crosses a surface: `ok`, its parameter and the unit
// outward normal there.
struct SurfaceHit {
    ok: bool,
    t: f32,
    normal: vec3<f32>,
}

fn surface_miss() -> SurfaceHit {
    return SurfaceHit(false, 0.0, vec3<f32>(0.0));
}

// `f64::signum` (1 for +0).
fn surface_signum(x: f32) -> f32 {
    return select(-1.0, 1.0, x >= 0.0);
}

// `unit_or`: the unit vector of v, or `fallback` where it has none.
fn surface_unit_or(v: vec3<f32>, fallback: vec3<f32>) -> vec3<f32> {
    let n = normalize_or_zero(v);
    if is_zero(n) {
        return fallback;
    }
    return n;
}

// `slab`: the open interval of t where lo < o + d t < hi on one axis
// (empty: start after end).
fn surface_slab(o: f32, d: f32, lo: f32, hi: f32) -> vec2<f32> {
    if d == 0.0 {
        if o > lo && o < hi {
            return vec2<f32>(-SURFACE_FAR, SURFACE_FAR);
        }
        return vec2<f32>(SURFACE_FAR, -SURFACE_FAR);
    }
    let a = (lo - o) / d;
    let b = (hi - o) / d;
    if a < b {
        return vec2<f32>(a, b);
    }
    return vec2<f32>(b, a);
}

// `ball`: the interval of t where |o + d t| < r (o relative to the centre),
// from the closest approach and the root nearer zero from the product of
// the roots.
fn surface_ball(o: vec3<f32>, d: vec3<f32>, r: f32) -> vec2<f32> {
    let a = dot(d, d);
    if a == 0.0 {
        if length(o) < r {
            return vec2<f32>(-SURFACE_FAR, SURFACE_FAR);
        }
        return vec2<f32>(SURFACE_FAR, -SURFACE_FAR);
    }
    let tc = -dot(o, d) / a;
    let m = length(o + d * tc);
    let h2 = (r - m) * (r + m);
    if h2 <= 0.0 {
        return vec2<f32>(SURFACE_FAR, -SURFACE_FAR);
    }
    let s = sqrt(h2 / a);
    let ol = length(o);
    let c = (ol - r) * (ol + r);
    if tc >= 0.0 {
        let t2 = tc + s;
        return vec2<f32>(c / (a * t2), t2);
    }
    let t1 = tc - s;
    return vec2<f32>(t1, c / (a * t1));
}

// `first_end`: the first end of the interval in (lo, hi]: (t, 1 entering
// or 0 leaving, 1 found).
fn surface_first_end(iv: vec2<f32>, lo: f32, hi: f32) -> vec3<f32> {
    if iv.x >= iv.y {
        return vec3<f32>(0.0);
    }
    if iv.x > lo && iv.x <= hi {
        return vec3<f32>(iv.x, 1.0, 1.0);
    }
    if iv.y > lo && iv.y <= hi {
        return vec3<f32>(iv.y, 0.0, 1.0);
    }
    return vec3<f32>(0.0);
}

// `Shape::first_crossing` of a sphere on lo < t <= hi.
fn surface_sphere(o: vec3<f32>, d: vec3<f32>, c: vec3<f32>, r: f32, lo: f32, hi: f32) -> SurfaceHit {
    let e = surface_first_end(surface_ball(o - c, d, r), lo, hi);
    if e.z == 0.0 {
        return surface_miss();
    }
    return SurfaceHit(true, e.x, surface_unit_or(o + d * e.x - c, vec3<f32>(0.0, 1.0, 0.0)));
}

// `Shape::first_crossing` of a box (not rounded) of half extents `half`.
fn surface_box(o: vec3<f32>, d: vec3<f32>, c: vec3<f32>, rot: mat3x3<f32>, half: vec3<f32>, lo: f32, hi: f32) -> SurfaceHit {
    let ol = (o - c) * rot;
    let dl = d * rot;
    var t_in = -SURFACE_FAR;
    var t_out = SURFACE_FAR;
    var ax_in = 0u;
    var ax_out = 0u;
    for (var k = 0u; k < 3u; k++) {
        let ab = surface_slab(ol[k], dl[k], -half[k], half[k]);
        if ab.x > t_in {
            t_in = ab.x;
            ax_in = k;
        }
        if ab.y < t_out {
            t_out = ab.y;
            ax_out = k;
        }
    }
    let e = surface_first_end(vec2<f32>(t_in, t_out), lo, hi);
    if e.z == 0.0 {
        return surface_miss();
    }
    var n = vec3<f32>(0.0);
    if e.y != 0.0 {
        n[ax_in] = -surface_signum(dl[ax_in]);
    } else {
        n[ax_out] = surface_signum(dl[ax_out]);
    }
    return SurfaceHit(true, e.x, rot * n);
}

// `Shape::first_crossing` of a capped cylinder about the local y axis.
fn surface_cylinder(o: vec3<f32>, d: vec3<f32>, c: vec3<f32>, rot: mat3x3<f32>, r: f32, hh: f32, lo: f32, hi: f32) -> SurfaceHit {
    let ol = (o - c) * rot;
    let dl = d * rot;
    let flat = vec3<f32>(1.0, 0.0, 1.0);
    let cc = surface_ball(ol * flat, dl * flat, r);
    let ss = surface_slab(ol.y, dl.y, -hh, hh);
    let e = surface_first_end(vec2<f32>(max(cc.x, ss.x), min(cc.y, ss.y)), lo, hi);
    if e.z == 0.0 {
        return surface_miss();
    }
    // The part that bounds the interval at that end was hit.
    let cap = select(ss.y < cc.y, ss.x > cc.x, e.y != 0.0);
    let p = ol + dl * e.x;
    var n = surface_unit_or(p * flat, vec3<f32>(1.0, 0.0, 0.0));
    if cap {
        n = vec3<f32>(0.0, select(-1.0, 1.0, p.y > 0.0), 0.0);
    }
    return SurfaceHit(true, e.x, rot * n);
}

// `Shape::first_crossing` of the half-space dot(p - point, normal) < 0.
fn surface_half_space(o: vec3<f32>, d: vec3<f32>, point: vec3<f32>, normal: vec3<f32>, lo: f32, hi: f32) -> SurfaceHit {
    let sd = dot(d, normal);
    if sd == 0.0 {
        return surface_miss();
    }
    let t = -dot(o - point, normal) / sd;
    if t > lo && t <= hi {
        return SurfaceHit(true, t, normal);
    }
    return surface_miss();
}

// `Shape::normal` of a box: the face the point is nearest (or beyond).
fn surface_box_normal(p: vec3<f32>, c: vec3<f32>, rot: mat3x3<f32>, half: vec3<f32>) -> vec3<f32> {
    let q = (p - c) * rot;
    let e = abs(q) - half;
    var k = 2u;
    if e.x >= e.y && e.x >= e.z {
        k = 0u;
    } else if e.y >= e.z {
        k = 1u;
    }
    var n = vec3<f32>(0.0);
    n[k] = surface_signum(q[k]);
    return rot * n;
}

// `Shape::normal` of a capped cylinder.
fn surface_cylinder_normal(p: vec3<f32>, c: vec3<f32>, rot: mat3x3<f32>, r: f32, hh: f32) -> vec3<f32> {
    let q = (p - c) * rot;
    let radial = surface_unit_or(vec3<f32>(q.x, 0.0, q.z), vec3<f32>(1.0, 0.0, 0.0));
    let axial = vec3<f32>(0.0, surface_signum(q.y), 0.0);
    let dr = length(q.xz) - r;
    let dy = abs(q.y) - hh;
    var n = axial;
    if dr > 0.0 && dy > 0.0 {
        n = radial * dr + axial * dy;
    } else if dr > dy {
        n = radial;
    }
    return rot * surface_unit_or(n, vec3<f32>(0.0, 1.0, 0.0));
}

// `Shape::distance` of a box (not rounded).
fn surface_box_distance(p: vec3<f32>, c: vec3<f32>, rot: mat3x3<f32>, half: vec3<f32>) -> f32 {
    let e = abs((p - c) * rot) - half;
    return length(max(e, vec3<f32>(0.0))) + min(max3(e), 0.0);
}

// `Shape::distance` of a capped cylinder.
fn surface_cylinder_distance(p: vec3<f32>, c: vec3<f32>, rot: mat3x3<f32>, r: f32, hh: f32) -> f32 {
    let q = (p - c) * rot;
    let e = vec2<f32>(length(q.xz) - r, abs(q.y) - hh);
    return length(max(e, vec2<f32>(0.0))) + min(max(e.x, e.y), 0.0);
}
