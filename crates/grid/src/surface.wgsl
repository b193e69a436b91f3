// Exact ray-surface crossings, outward normals and signed distances of
// every shape but the VDB grid (`surface.rs`, `shape.rs`) in f32, by the
// same methods as `Shape::first_crossing`, `Shape::normal` and
// `Shape::distance`: closed forms for the sphere, the box, the rounded box,
// the capped cylinder, the half-space and the solid of revolution; a march
// on the distance bound and bisection for the torus and the superquadric;
// the BVH (a stack traversal, the watertight test) for the mesh. A local
// frame is the rotation `rot` (its columns the shape's axes) about the
// centre: `local = transpose(rot) * (p - c)`.
//
// Needs: the `vector` module, the constants of `surface.rs`, and the hook
// `surface_data(i: u32) -> vec4<u32>`: record i of the data buffer that
// holds profiles, mesh triangles and BVH nodes (floats by their bits).

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

// ---- Rounded box, torus, superquadric, solid of revolution, mesh ----

// Record i of the data buffer as floats.
fn surface_data_f(i: u32) -> vec4<f32> {
    return bitcast<vec4<f32>>(surface_data(i));
}

// `f64::powf` of a non-negative base as the CPU gets it: pow(0, y) is 0
// for y > 0, 1 for y = 0 and infinite (SURFACE_FAR) for y < 0, where WGSL
// leaves it undefined.
fn surface_pow(x: f32, y: f32) -> f32 {
    if y == 0.0 {
        return 1.0;
    }
    if x == 0.0 {
        return select(SURFACE_FAR, 0.0, y > 0.0);
    }
    return pow(x, y);
}

// Real roots of a t^2 + 2 b t + c in the cancellation-free form
// (`quadratic`): (root, root, how many).
fn surface_quadratic(a: f32, b: f32, c: f32) -> vec3<f32> {
    if a == 0.0 {
        if b == 0.0 {
            return vec3<f32>(0.0);
        }
        return vec3<f32>(-c / (2.0 * b), 0.0, 1.0);
    }
    let disc = b * b - a * c;
    if disc < 0.0 {
        return vec3<f32>(0.0);
    }
    let q = -(b + select(-sqrt(disc), sqrt(disc), b >= 0.0));
    if q == 0.0 {
        return vec3<f32>(0.0, 0.0, 1.0);
    }
    return vec3<f32>(q / a, c / q, 2.0);
}

// The hull of interval `acc` and a non-empty `iv`.
fn surface_hull(acc: vec2<f32>, iv: vec2<f32>) -> vec2<f32> {
    if iv.x < iv.y {
        return vec2<f32>(min(acc.x, iv.x), max(acc.y, iv.y));
    }
    return acc;
}

// `rounded_box`: the entry and exit of a line into a rounded box (local
// frame), the hull of the intervals of its convex parts (three slabs,
// twelve edge cylinders, eight corner balls).
fn surface_rounded_box_interval(o: vec3<f32>, d: vec3<f32>, half: vec3<f32>, r: f32) -> vec2<f32> {
    let inner = max(half - vec3<f32>(r), vec3<f32>(0.0));
    var acc = vec2<f32>(SURFACE_FAR, -SURFACE_FAR);
    for (var k = 0u; k < 3u; k++) {
        var h = inner;
        h[k] += r;
        var a = -SURFACE_FAR;
        var b = SURFACE_FAR;
        for (var j = 0u; j < 3u; j++) {
            let s = surface_slab(o[j], d[j], -h[j], h[j]);
            a = max(a, s.x);
            b = min(b, s.y);
        }
        acc = surface_hull(acc, vec2<f32>(a, b));
    }
    for (var k = 0u; k < 3u; k++) {
        var flat = vec3<f32>(1.0);
        flat[k] = 0.0;
        let s = surface_slab(o[k], d[k], -inner[k], inner[k]);
        let i = (k + 1u) % 3u;
        let j = (k + 2u) % 3u;
        for (var corner = 0u; corner < 4u; corner++) {
            var c = inner;
            if (corner & 1u) == 1u {
                c[i] = -c[i];
            }
            if (corner & 2u) == 2u {
                c[j] = -c[j];
            }
            let ab = surface_ball((o - c) * flat, d * flat, r);
            acc = surface_hull(acc, vec2<f32>(max(ab.x, s.x), min(ab.y, s.y)));
        }
    }
    for (var corner = 0u; corner < 8u; corner++) {
        let c = vec3<f32>(
            select(inner.x, -inner.x, (corner & 1u) == 1u),
            select(inner.y, -inner.y, (corner & 2u) == 2u),
            select(inner.z, -inner.z, (corner & 4u) == 4u),
        );
        acc = surface_hull(acc, surface_ball(o - c, d, r));
    }
    return acc;
}

// `Shape::normal` of a rounded box at local q: the gradient of the
// distance to the inner box outside it, else the nearest face's.
fn surface_rounded_box_normal_local(q: vec3<f32>, half: vec3<f32>, r: f32) -> vec3<f32> {
    let inner = max(half - vec3<f32>(r), vec3<f32>(0.0));
    let out = abs(q) - inner;
    var n = vec3<f32>(0.0);
    if r > 0.0 && max3(out) > 0.0 {
        n = max(out, vec3<f32>(0.0)) * vec3<f32>(surface_signum(q.x), surface_signum(q.y), surface_signum(q.z));
    } else {
        let e = abs(q) - half;
        var k = 2u;
        if e.x >= e.y && e.x >= e.z {
            k = 0u;
        } else if e.y >= e.z {
            k = 1u;
        }
        n[k] = surface_signum(q[k]);
    }
    return surface_unit_or(n, vec3<f32>(0.0, 1.0, 0.0));
}

fn surface_rounded_box_normal(p: vec3<f32>, c: vec3<f32>, rot: mat3x3<f32>, half: vec3<f32>, r: f32) -> vec3<f32> {
    return rot * surface_rounded_box_normal_local((p - c) * rot, half, r);
}

// `Shape::distance` of a rounded box.
fn surface_rounded_box_distance(p: vec3<f32>, c: vec3<f32>, rot: mat3x3<f32>, half: vec3<f32>, r: f32) -> f32 {
    let e = abs((p - c) * rot) - (half - vec3<f32>(r));
    return length(max(e, vec3<f32>(0.0))) + min(max3(e), 0.0) - r;
}

// `Shape::first_crossing` of a rounded box (rounding radius r).
fn surface_rounded_box(o: vec3<f32>, d: vec3<f32>, c: vec3<f32>, rot: mat3x3<f32>, half: vec3<f32>, r: f32, lo: f32, hi: f32) -> SurfaceHit {
    let ol = (o - c) * rot;
    let dl = d * rot;
    let e = surface_first_end(surface_rounded_box_interval(ol, dl, half, r), lo, hi);
    if e.z == 0.0 {
        return surface_miss();
    }
    return SurfaceHit(true, e.x, rot * surface_rounded_box_normal_local(ol + dl * e.x, half, r));
}

// `Shape::distance` of a torus at local q.
fn surface_torus_distance(q: vec3<f32>, major: f32, minor: f32) -> f32 {
    return length(vec2<f32>(length(q.xz) - major, q.y)) - minor;
}

// `Shape::normal` of a torus at local q.
fn surface_torus_normal(q: vec3<f32>, major: f32) -> vec3<f32> {
    let rho = length(q.xz);
    var n = vec3<f32>(0.0, q.y, 0.0);
    if rho > 0.0 {
        let k = 1.0 - major / rho;
        n = vec3<f32>(q.x * k, q.y, q.z * k);
    }
    return surface_unit_or(n, vec3<f32>(0.0, 1.0, 0.0));
}

// `Shape::distance` of a superquadric at local q: the conservative bound.
fn surface_superquadric_distance(q: vec3<f32>, radii: vec3<f32>, e1: f32, e2: f32) -> f32 {
    let s = abs(q / radii);
    let xz = surface_pow(surface_pow(s.x, 2.0 / e2) + surface_pow(s.z, 2.0 / e2), e2 / e1);
    let f = xz + surface_pow(s.y, 2.0 / e1);
    return (surface_pow(f, e1 / 2.0) - 1.0) * min3(radii) * 0.5;
}

// `Shape::normal` of a superquadric at local q (size: the shape's): the
// implicit function's gradient, or at a pinch or crease (zero or infinite
// partials) the central difference of the distance bound.
fn surface_superquadric_normal(q: vec3<f32>, radii: vec3<f32>, e1: f32, e2: f32, size: f32) -> vec3<f32> {
    let s = q / radii;
    let a = abs(s);
    let k = surface_pow(surface_pow(a.x, 2.0 / e2) + surface_pow(a.z, 2.0 / e2), e2 / e1 - 1.0);
    let g = vec3<f32>(
        k * surface_pow(a.x, 2.0 / e2 - 1.0) * surface_signum(s.x),
        surface_pow(a.y, 2.0 / e1 - 1.0) * surface_signum(s.y),
        k * surface_pow(a.z, 2.0 / e2 - 1.0) * surface_signum(s.z),
    ) / radii;
    let m = max3(abs(g));
    if m > 0.0 && m < SURFACE_FAR {
        return normalize(g / m);
    }
    // The central difference, one evaluation per iteration.
    let h = SURFACE_NUMERIC_STEP * size;
    var n = vec3<f32>(0.0);
    for (var k = 0u; k < 6u; k++) {
        var off = vec3<f32>(0.0);
        off[k / 2u] = select(h, -h, (k & 1u) == 1u);
        n[k / 2u] += select(1.0, -1.0, (k & 1u) == 1u) * surface_superquadric_distance(q + off, radii, e1, e2);
    }
    return surface_unit_or(n, vec3<f32>(0.0, 1.0, 0.0));
}

// The distance bound of the marched shapes at local q: a superquadric of
// radii `dims` and exponents (a, b), else a torus of radii (a, b).
fn surface_implicit_distance(sq: bool, q: vec3<f32>, dims: vec3<f32>, a: f32, b: f32) -> f32 {
    if sq {
        return surface_superquadric_distance(q, dims, a, b);
    }
    return surface_torus_distance(q, a, b);
}

// `Shape::march` in the local frame (half extents `bound`): sphere tracing
// by the distance bound from lo to hi, then bisection of the first change
// of side until no f32 lies between: (t, 1 found).
fn surface_march(sq: bool, o: vec3<f32>, d: vec3<f32>, dims: vec3<f32>, a: f32, b: f32, bound: vec3<f32>, size: f32, lo_in: f32, hi_in: f32) -> vec2<f32> {
    let dl = length(d);
    // Outside the bounding box nothing changes: start and stop there.
    var lo = lo_in;
    var hi = hi_in;
    let pad = SURFACE_MIN_STEP * size;
    for (var k = 0u; k < 3u; k++) {
        let s = surface_slab(o[k], d[k], -bound[k] - pad, bound[k] + pad);
        lo = max(lo, s.x);
        hi = min(hi, s.y);
    }
    if !(lo < hi) {
        return vec2<f32>(0.0);
    }
    let h_min = SURFACE_MIN_STEP * size / dl;
    // The superquadric's bound over-estimates near the pinches of a star
    // shape (an exponent over 2): a fraction of it, and steps of at most a
    // fraction of its size (as the CPU).
    var safety = 1.0;
    var h_max = SURFACE_FAR;
    if sq && max(a, b) > 2.0 {
        safety = SUPERQUADRIC_SAFETY;
        h_max = size / SUPERQUADRIC_STEPS / dl;
    }
    // One evaluation of the bound per iteration (drivers inline each call):
    // the start, then the march's steps, then, once the side changed, the
    // bisection of that step.
    var t0 = lo;
    var d0 = 0.0;
    var side = false;
    var t1 = lo;
    var ta = 0.0;
    var tb = 0.0;
    var bisecting = false;
    for (var i = 0u; i < SURFACE_MAX_MARCH; i++) {
        var tq = lo;
        if bisecting {
            tq = 0.5 * (ta + tb);
            if tq <= min(ta, tb) || tq >= max(ta, tb) {
                return vec2<f32>(tb, 1.0);
            }
        } else if i > 0u {
            t1 = min(t0 + clamp(safety * abs(d0) / dl, h_min, max(h_max, h_min)), hi);
            tq = t1;
        }
        let dq = surface_implicit_distance(sq, o + d * tq, dims, a, b);
        if bisecting {
            if (dq < 0.0) == side {
                ta = tq;
            } else {
                tb = tq;
            }
        } else if i == 0u {
            d0 = dq;
            side = dq < 0.0;
        } else if (dq < 0.0) != side {
            ta = t0;
            tb = t1;
            bisecting = true;
        } else if t1 >= hi || !(abs(dq) < SURFACE_FAR) {
            return vec2<f32>(0.0);
        } else {
            t0 = t1;
            d0 = dq;
        }
    }
    if bisecting {
        return vec2<f32>(tb, 1.0);
    }
    return vec2<f32>(0.0);
}

// `Shape::first_crossing` of a torus (major, minor radius) about the local
// y axis.
fn surface_torus(o: vec3<f32>, d: vec3<f32>, c: vec3<f32>, rot: mat3x3<f32>, major: f32, minor: f32, size: f32, lo: f32, hi: f32) -> SurfaceHit {
    let ol = (o - c) * rot;
    let dl = d * rot;
    let bound = vec3<f32>(major + minor, minor, major + minor);
    let m = surface_march(false, ol, dl, vec3<f32>(0.0), major, minor, bound, size, lo, hi);
    if m.y == 0.0 {
        return surface_miss();
    }
    return SurfaceHit(true, m.x, rot * surface_torus_normal(ol + dl * m.x, major));
}

// `Shape::first_crossing` of a superquadric of `radii`, exponents e1, e2.
fn surface_superquadric(o: vec3<f32>, d: vec3<f32>, c: vec3<f32>, rot: mat3x3<f32>, radii: vec3<f32>, e1: f32, e2: f32, size: f32, lo: f32, hi: f32) -> SurfaceHit {
    let ol = (o - c) * rot;
    let dl = d * rot;
    let m = surface_march(true, ol, dl, radii, e1, e2, radii, size, lo, hi);
    if m.y == 0.0 {
        return surface_miss();
    }
    return SurfaceHit(true, m.x, rot * surface_superquadric_normal(ol + dl * m.x, radii, e1, e2, size));
}

// `swept_normal`: the outward normal (local frame) at p of the surface
// swept by a profile edge of outward 2-D normal n2.
fn surface_swept_normal(n2: vec2<f32>, p: vec3<f32>) -> vec3<f32> {
    let l = length(p.xz);
    var radial = vec2<f32>(0.0);
    if l > 0.0 && l < SURFACE_FAR {
        radial = p.xz / l;
    }
    return surface_unit_or(vec3<f32>(n2.x * radial.x, n2.y, n2.x * radial.y), vec3<f32>(0.0, surface_signum(n2.y), 0.0));
}

// `revolution_crossing`: the first crossing (local frame) of the solid of
// revolution whose n profile points (r, y, and the outward normal of the
// edge to the next) are records first.. of the data buffer: each edge
// sweeps an annulus (linear) or a cone or cylinder (quadratic, one Newton
// step on the unexpanded equation).
fn surface_revolution(o: vec3<f32>, d: vec3<f32>, c: vec3<f32>, rot: mat3x3<f32>, first: u32, n: u32, lo: f32, hi: f32) -> SurfaceHit {
    let ol = (o - c) * rot;
    let dl = d * rot;
    var best_t = 0.0;
    var best = n;
    for (var i = 0u; i < n; i++) {
        let a = surface_data_f(first + i).xy;
        let b = surface_data_f(first + (i + 1u) % n).xy;
        if a.y == b.y {
            // An annulus in the plane y = a.y.
            if dl.y == 0.0 {
                continue;
            }
            let t = (a.y - ol.y) / dl.y;
            let rho = length((ol + dl * t).xz);
            if rho >= min(a.x, b.x) && rho <= max(a.x, b.x) && t > lo && t <= hi && (best == n || t < best_t) {
                best_t = t;
                best = i;
            }
            continue;
        }
        if a.x <= 0.0 && b.x <= 0.0 {
            continue; // on the axis: inside the solid, no surface
        }
        // rho = m + k (y - o.y) along the edge's line.
        let k = (b.x - a.x) / (b.y - a.y);
        let m = a.x + k * (ol.y - a.y);
        let qa = dl.x * dl.x + dl.z * dl.z - k * k * dl.y * dl.y;
        let qb = ol.x * dl.x + ol.z * dl.z - k * m * dl.y;
        let qc = ol.x * ol.x + ol.z * ol.z - m * m;
        let y0 = min(a.y, b.y);
        let y1 = max(a.y, b.y);
        let roots = surface_quadratic(qa, qb, qc);
        for (var j = 0u; j < u32(roots.z); j++) {
            var t = roots[j];
            // The Newton step's guard is wider than the CPU's 1e-6: an f32
            // root is off by more than that where the roots are close.
            let p = ol + dl * t;
            let r = m + k * dl.y * t;
            let g = p.x * p.x + p.z * p.z - r * r;
            let dg = 2.0 * (p.x * dl.x + p.z * dl.z - r * k * dl.y);
            if dg != 0.0 {
                let step = g / dg;
                if abs(step) <= 1e-3 * (abs(t) + 1.0) {
                    t -= step;
                }
            }
            let y = ol.y + dl.y * t;
            if y >= y0 && y <= y1 && m + k * dl.y * t >= 0.0 && t > lo && t <= hi && (best == n || t < best_t) {
                best_t = t;
                best = i;
            }
        }
    }
    if best == n {
        return surface_miss();
    }
    let n2 = surface_data_f(first + best).zw;
    return SurfaceHit(true, best_t, rot * surface_swept_normal(n2, ol + dl * best_t));
}

// `revolution_normal`: the outward normal of the solid of revolution at
// (or nearest to) p, that of the profile edge nearest it.
fn surface_revolution_normal(p: vec3<f32>, c: vec3<f32>, rot: mat3x3<f32>, first: u32, n: u32) -> vec3<f32> {
    if n < 2u {
        return rot * vec3<f32>(0.0, 1.0, 0.0);
    }
    let q = (p - c) * rot;
    let m = vec2<f32>(length(q.xz), q.y);
    var best_d2 = SURFACE_FAR;
    var best = 0u;
    for (var i = 0u; i < n; i++) {
        let a = surface_data_f(first + i).xy;
        let e = surface_data_f(first + (i + 1u) % n).xy - a;
        let l2 = dot(e, e);
        var s = 0.0;
        if l2 > 0.0 {
            s = clamp(dot(m - a, e) / l2, 0.0, 1.0);
        }
        let w = m - (a + e * s);
        let d2 = dot(w, w);
        if d2 < best_d2 {
            best_d2 = d2;
            best = i;
        }
    }
    return rot * surface_swept_normal(surface_data_f(first + best).zw, q);
}

// `Shape::distance` of the solid of revolution: the profile polygon's
// signed distance (even-odd inside test) at (radius, height).
fn surface_revolution_distance(p: vec3<f32>, c: vec3<f32>, rot: mat3x3<f32>, first: u32, n: u32) -> f32 {
    let q = (p - c) * rot;
    let m = vec2<f32>(length(q.xz), q.y);
    var d2 = SURFACE_FAR;
    var inside = false;
    for (var i = 0u; i < n; i++) {
        let a = surface_data_f(first + i).xy;
        let b = surface_data_f(first + (i + 1u) % n).xy;
        let e = b - a;
        let w = m - a;
        let l2 = dot(e, e);
        var t = 0.0;
        if l2 > 0.0 {
            t = clamp(dot(w, e) / l2, 0.0, 1.0);
        }
        let x = w - e * t;
        d2 = min(d2, dot(x, x));
        if (a.y > m.y) != (b.y > m.y) && m.x < a.x + (m.y - a.y) / (b.y - a.y) * e.x {
            inside = !inside;
        }
    }
    return select(sqrt(d2), -sqrt(d2), inside);
}

// A mesh as its data-buffer records: triangles from `tris` (six records
// each, in leaf order), BVH nodes from `nodes` (two each).
struct SurfaceMesh {
    tris: u32,
    nodes: u32,
    node_count: u32,
    // Shaded with vertex normals (`smooth` is a WGSL keyword).
    shaded: bool,
}

// Node i's box, and its offset and count | axis << 16.
struct SurfaceNode {
    lo: vec3<f32>,
    hi: vec3<f32>,
    offset: u32,
    count: u32,
    axis: u32,
}

fn surface_node(m: SurfaceMesh, i: u32) -> SurfaceNode {
    let a = surface_data(m.nodes + MESH_NODE_RECORDS * i);
    let b = surface_data(m.nodes + MESH_NODE_RECORDS * i + 1u);
    return SurfaceNode(bitcast<vec3<f32>>(a.xyz), bitcast<vec3<f32>>(b.xyz), a.w, b.w & 0xffffu, b.w >> 16u);
}

// Corner k (0..2) of leaf slot s, or its vertex normal (k 3..5).
fn surface_corner(m: SurfaceMesh, s: u32, k: u32) -> vec3<f32> {
    return surface_data_f(m.tris + MESH_TRIANGLE_RECORDS * s + k).xyz;
}

// The watertight ray-triangle test (`Prepared::hits_triangle`, Woop et
// al.) for the ray sheared along its dominant axis kz: (t, b0, b1, b2
// barycentric) with t in (lo, hi], or t = -SURFACE_FAR for none.
fn surface_triangle(o: vec3<f32>, kk: vec3<u32>, shear: vec3<f32>, ta: vec3<f32>, tb: vec3<f32>, tc: vec3<f32>, lo: f32, hi: f32) -> vec4<f32> {
    let a = ta - o;
    let b = tb - o;
    let c = tc - o;
    let ax = a[kk.x] - shear.x * a[kk.z];
    let ay = a[kk.y] - shear.y * a[kk.z];
    let bx = b[kk.x] - shear.x * b[kk.z];
    let by = b[kk.y] - shear.y * b[kk.z];
    let cx = c[kk.x] - shear.x * c[kk.z];
    let cy = c[kk.y] - shear.y * c[kk.z];
    let u = cx * by - cy * bx;
    let v = ax * cy - ay * cx;
    let w = bx * ay - by * ax;
    let none = vec4<f32>(-SURFACE_FAR, 0.0, 0.0, 0.0);
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
        return none;
    }
    let det = u + v + w;
    if det == 0.0 {
        return none;
    }
    let t = (u * shear.z * a[kk.z] + v * shear.z * b[kk.z] + w * shear.z * c[kk.z]) / det;
    if !(t > lo && t <= hi) {
        return none;
    }
    return vec4<f32>(t, u / det, v / det, w / det);
}

// `mesh_crossing`: the nearest triangle the segment crosses, through the
// BVH (`Bvh::closest_hit`: nearer child first, boxes widened by the f32
// rounding bound, ties to the lower triangle id).
fn surface_mesh(m: SurfaceMesh, o: vec3<f32>, d: vec3<f32>, lo: f32, hi: f32) -> SurfaceHit {
    if m.node_count == 0u || is_zero(d) {
        return surface_miss();
    }
    // The dominant axis becomes z; swapping x and y when it points down
    // keeps the triangles' winding.
    let ad = abs(d);
    var kz = 2u;
    if ad.x >= ad.y && ad.x >= ad.z {
        kz = 0u;
    } else if ad.y >= ad.z {
        kz = 1u;
    }
    var kx = (kz + 1u) % 3u;
    var ky = (kx + 1u) % 3u;
    if d[kz] < 0.0 {
        let k = kx;
        kx = ky;
        ky = k;
    }
    let kk = vec3<u32>(kx, ky, kz);
    let shear = vec3<f32>(d[kx] / d[kz], d[ky] / d[kz], 1.0 / d[kz]);
    // A zero component: a reciprocal that stays finite (WGSL promises no
    // infinities), large enough that the slab is all or nothing.
    let neg = d < vec3<f32>(0.0);
    let safe = select(d, select(vec3<f32>(1e-30), vec3<f32>(-1e-30), neg), d == vec3<f32>(0.0));
    let inv = 1.0 / safe;
    var best_t = hi;
    var best_b = vec3<f32>(0.0);
    var best_slot = 0xffffffffu;
    var best_id = 0u;
    var stack: array<u32, BVH_STACK>;
    stack[0] = 0u;
    var sp = 1u;
    while sp > 0u {
        sp -= 1u;
        let index = stack[sp];
        let node = surface_node(m, index);
        // `hits_box`, widened.
        var near = lo;
        var far = best_t;
        for (var k = 0u; k < 3u; k++) {
            let b0 = select(node.lo[k], node.hi[k], neg[k]);
            let b1 = select(node.hi[k], node.lo[k], neg[k]);
            let t0 = (b0 - o[k]) * inv[k];
            let t1 = (b1 - o[k]) * inv[k];
            near = max(near, t0 * (1.0 - select(-BVH_WIDEN, BVH_WIDEN, t0 >= 0.0)));
            far = min(far, t1 * (1.0 + select(-BVH_WIDEN, BVH_WIDEN, t1 >= 0.0)));
        }
        if near > far {
            continue;
        }
        if node.count > 0u {
            for (var s = node.offset; s < node.offset + node.count; s++) {
                let h = surface_triangle(o, kk, shear, surface_corner(m, s, 0u), surface_corner(m, s, 1u), surface_corner(m, s, 2u), lo, hi);
                if h.x == -SURFACE_FAR {
                    continue;
                }
                let id = surface_data(m.tris + MESH_TRIANGLE_RECORDS * s).w;
                if best_slot == 0xffffffffu || h.x < best_t || (h.x == best_t && id < best_id) {
                    best_t = h.x;
                    best_b = h.yzw;
                    best_slot = s;
                    best_id = id;
                }
            }
        } else if sp + 2u <= BVH_STACK {
            let left = index + 1u;
            let right = node.offset;
            if neg[node.axis] {
                stack[sp] = left;
                stack[sp + 1u] = right;
            } else {
                stack[sp] = right;
                stack[sp + 1u] = left;
            }
            sp += 2u;
        }
    }
    if best_slot == 0xffffffffu {
        return surface_miss();
    }
    let a = surface_corner(m, best_slot, 0u);
    let face = normalize_or_zero(cross(surface_corner(m, best_slot, 1u) - a, surface_corner(m, best_slot, 2u) - a));
    var n = face;
    if m.shaded {
        let s = normalize_or_zero(surface_corner(m, best_slot, 3u) * best_b.x + surface_corner(m, best_slot, 4u) * best_b.y + surface_corner(m, best_slot, 5u) * best_b.z);
        if !is_zero(s) {
            n = s;
        }
    }
    return SurfaceHit(true, best_t, n);
}

// The point of triangle (a, b, c) closest to p [Ericson05 sec 5.1.5].
fn surface_closest_point(a: vec3<f32>, b: vec3<f32>, c: vec3<f32>, p: vec3<f32>) -> vec3<f32> {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let d3 = dot(ab, bp);
    let d4 = dot(ac, bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let d5 = dot(ab, cp);
    let d6 = dot(ac, cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    return a + ab * (vb * denom) + ac * (vc * denom);
}

// The mesh's triangle nearest p (`MeshSolid::closest_triangle`, here a
// BVH search, nearer child first, pruned by the boxes' distance):
// (closest point, squared distance) and its leaf slot.
struct SurfaceNearest {
    x: vec3<f32>,
    d2: f32,
    slot: u32,
}

fn surface_mesh_nearest(m: SurfaceMesh, p: vec3<f32>) -> SurfaceNearest {
    var best = SurfaceNearest(p, SURFACE_FAR, 0xffffffffu);
    if m.node_count == 0u {
        return best;
    }
    var stack: array<u32, BVH_STACK>;
    stack[0] = 0u;
    var sp = 1u;
    while sp > 0u {
        sp -= 1u;
        let index = stack[sp];
        let node = surface_node(m, index);
        let gap = max(max(node.lo - p, p - node.hi), vec3<f32>(0.0));
        if dot(gap, gap) >= best.d2 {
            continue;
        }
        if node.count > 0u {
            for (var s = node.offset; s < node.offset + node.count; s++) {
                let x = surface_closest_point(surface_corner(m, s, 0u), surface_corner(m, s, 1u), surface_corner(m, s, 2u), p);
                let d2 = dot(x - p, x - p);
                if d2 < best.d2 {
                    best = SurfaceNearest(x, d2, s);
                }
            }
        } else if sp + 2u <= BVH_STACK {
            let left = index + 1u;
            let right = node.offset;
            let l = surface_node(m, left);
            let r = surface_node(m, right);
            let gl = max(max(l.lo - p, p - l.hi), vec3<f32>(0.0));
            let gr = max(max(r.lo - p, p - r.hi), vec3<f32>(0.0));
            // The nearer child on top.
            if dot(gl, gl) <= dot(gr, gr) {
                stack[sp] = right;
                stack[sp + 1u] = left;
            } else {
                stack[sp] = left;
                stack[sp + 1u] = right;
            }
            sp += 2u;
        }
    }
    return best;
}

// The edge function of the yz-projected edge a -> b at (y, z) in a
// canonical orientation, never zero (`mesh_solid::edge`: simulation of
// simplicity), so that both triangles of an edge get opposite values.
fn surface_edge(a_in: vec3<f32>, b_in: vec3<f32>, y: f32, z: f32) -> f32 {
    let swap = a_in.y > b_in.y || (a_in.y == b_in.y && a_in.z > b_in.z);
    let a = select(a_in, b_in, swap);
    let b = select(b_in, a_in, swap);
    let dy = b.y - a.y;
    let dz = b.z - a.z;
    var e = dy * (z - a.z) - dz * (y - a.y);
    if e == 0.0 {
        e = select(dy, -dz, dz != 0.0);
    }
    return select(e, -e, swap);
}

// `MeshSolid::contains`: the parity of the crossings of the ray from p
// along +x (`crossing_x` per triangle, over the BVH's boxes that the ray
// meets; each triangle sits in one leaf).
fn surface_mesh_inside(m: SurfaceMesh, p: vec3<f32>) -> bool {
    if m.node_count == 0u {
        return false;
    }
    var inside = false;
    var stack: array<u32, BVH_STACK>;
    stack[0] = 0u;
    var sp = 1u;
    while sp > 0u {
        sp -= 1u;
        let index = stack[sp];
        let node = surface_node(m, index);
        if p.y < node.lo.y || p.y > node.hi.y || p.z < node.lo.z || p.z > node.hi.z || node.hi.x <= p.x {
            continue;
        }
        if node.count > 0u {
            for (var s = node.offset; s < node.offset + node.count; s++) {
                let t0 = surface_corner(m, s, 0u);
                let t1 = surface_corner(m, s, 1u);
                let t2 = surface_corner(m, s, 2u);
                let e0 = surface_edge(t1, t2, p.y, p.z);
                let e1 = surface_edge(t2, t0, p.y, p.z);
                let e2 = surface_edge(t0, t1, p.y, p.z);
                let hit = (e0 > 0.0 && e1 > 0.0 && e2 > 0.0) || (e0 < 0.0 && e1 < 0.0 && e2 < 0.0);
                if !hit {
                    continue;
                }
                let x = clamp((e0 * t0.x + e1 * t1.x + e2 * t2.x) / (e0 + e1 + e2), min(t0.x, min(t1.x, t2.x)), max(t0.x, max(t1.x, t2.x)));
                if x > p.x {
                    inside = !inside;
                }
            }
        } else if sp + 2u <= BVH_STACK {
            stack[sp] = index + 1u;
            stack[sp + 1u] = node.offset;
            sp += 2u;
        }
    }
    return inside;
}

// `Shape::distance` of a mesh: the distance to its nearest triangle,
// negative inside (the CPU's is a lower bound, exact near the surface).
fn surface_mesh_distance(m: SurfaceMesh, p: vec3<f32>) -> f32 {
    let d = sqrt(surface_mesh_nearest(m, p).d2);
    return select(d, -d, surface_mesh_inside(m, p));
}

// `mesh_normal`: the normal at the mesh's point nearest p, the face's, or
// for a smooth mesh the vertex normals interpolated there.
fn surface_mesh_normal(m: SurfaceMesh, p: vec3<f32>) -> vec3<f32> {
    let near = surface_mesh_nearest(m, p);
    if near.slot == 0xffffffffu {
        return vec3<f32>(0.0, 1.0, 0.0);
    }
    let a = surface_corner(m, near.slot, 0u);
    let b = surface_corner(m, near.slot, 1u);
    let c = surface_corner(m, near.slot, 2u);
    let face = surface_unit_or(cross(b - a, c - a), vec3<f32>(0.0, 1.0, 0.0));
    if !m.shaded {
        return face;
    }
    // Barycentric weights of the closest point.
    let v0 = b - a;
    let v1 = c - a;
    let v2 = near.x - a;
    let d00 = dot(v0, v0);
    let d01 = dot(v0, v1);
    let d11 = dot(v1, v1);
    let d20 = dot(v2, v0);
    let d21 = dot(v2, v1);
    let den = d00 * d11 - d01 * d01;
    if den == 0.0 {
        return face;
    }
    let w1 = (d11 * d20 - d01 * d21) / den;
    let w2 = (d00 * d21 - d01 * d20) / den;
    let w0 = 1.0 - w1 - w2;
    let n = surface_corner(m, near.slot, 3u) * w0 + surface_corner(m, near.slot, 4u) * w1 + surface_corner(m, near.slot, 5u) * w2;
    return surface_unit_or(n, face);
}

// ---- VDB grid ----
// A float volume (`vdb::FloatVolume`) in the data buffer from record v:
// (voxel size, background), (translation, 0), (origin as i32, 0),
// (dims, 0), then its dense box's values four to a record, x slowest, z
// fastest (`region::volume_records`).

// Volume v's dense box: its origin, dims and background, read once for
// the voxels of a cell.
struct SurfaceBox {
    values: u32,
    origin: vec3<i32>,
    dims: vec3<u32>,
    background: f32,
}

fn surface_vdb_box(v: u32) -> SurfaceBox {
    return SurfaceBox(v + VDB_HEADER_RECORDS, bitcast<vec3<i32>>(surface_data(v + 2u).xyz), surface_data(v + 3u).xyz, surface_data_f(v).w);
}

// The value of voxel `ijk` of a box (the background outside it).
fn surface_box_value(b: SurfaceBox, ijk: vec3<i32>) -> f32 {
    let l = ijk - b.origin;
    if any(l < vec3<i32>(0)) || any(vec3<u32>(l) >= b.dims) {
        return b.background;
    }
    let flat = (u32(l.x) * b.dims.y + u32(l.y)) * b.dims.z + u32(l.z);
    return bitcast<f32>(surface_data(b.values + flat / 4u)[flat % 4u]);
}

// `Transform::world_to_index` of volume v.
fn surface_vdb_index(v: u32, p: vec3<f32>) -> vec3<f32> {
    return (p - surface_data_f(v + 1u).xyz) / surface_data_f(v).xyz;
}

// Whether the cell with lowest corner `f` (whole numbers) lies within a
// voxel of volume v's box on every axis (`FloatVolume::sample`'s test;
// also false for NaN), so that its corners convert to i32 safely.
fn surface_vdb_near(v: u32, f: vec3<f32>) -> bool {
    let origin = vec3<f32>(bitcast<vec3<i32>>(surface_data(v + 2u).xyz));
    let dims = vec3<f32>(surface_data(v + 3u).xyz);
    return all(f >= origin - 1.0) && all(f <= origin + dims);
}

// The eight values of volume v's cell with lowest corner i0, corner c at
// bit k of c along axis k. Written out rather than looped (here and in the
// other grid functions): a grid is sampled many times per step of a
// curved ray, and lavapipe ends every loop of an invocation once all of
// them together have run 65535 iterations.
struct SurfaceCell {
    c0: vec4<f32>,
    c1: vec4<f32>,
}

fn surface_vdb_cell(v: u32, i0: vec3<i32>) -> SurfaceCell {
    let b = surface_vdb_box(v);
    let x = vec3<i32>(1, 0, 0);
    let y = vec3<i32>(0, 1, 0);
    let z = vec3<i32>(0, 0, 1);
    return SurfaceCell(
        vec4<f32>(
            surface_box_value(b, i0),
            surface_box_value(b, i0 + x),
            surface_box_value(b, i0 + y),
            surface_box_value(b, i0 + x + y),
        ),
        vec4<f32>(
            surface_box_value(b, i0 + z),
            surface_box_value(b, i0 + x + z),
            surface_box_value(b, i0 + y + z),
            surface_box_value(b, i0 + x + y + z),
        ),
    );
}

// The trilinear interpolant of a cell at fractions t.
fn surface_cell_lerp(c: SurfaceCell, t: vec3<f32>) -> f32 {
    let a = mix(c.c0.xz, c.c0.yw, t.x);
    let b = mix(c.c1.xz, c.c1.yw, t.x);
    return mix(mix(a.x, a.y, t.y), mix(b.x, b.y, t.y), t.z);
}

// `FloatVolume::sample`: trilinear interpolation between voxel centres
// (OpenVDB's BoxSampler); the background far from the data.
fn surface_vdb_sample(v: u32, p: vec3<f32>) -> f32 {
    let u = surface_vdb_index(v, p);
    let f = floor(u);
    if !surface_vdb_near(v, f) {
        return surface_data_f(v).w;
    }
    return surface_cell_lerp(surface_vdb_cell(v, vec3<i32>(f)), u - f);
}

// The cubic c0 + c1 s + c2 s^2 + c3 s^3 at s.
fn surface_cubic(c: vec4<f32>, s: f32) -> f32 {
    return ((c.w * s + c.z) * s + c.y) * s + c.x;
}

// The root of the cubic c on [a, b], where its sign is `side_a` (> 0) at a
// and the other at b: bisection until no f32 lies between (`bisect`); the
// end on b's side.
fn surface_cubic_root(c: vec4<f32>, a_in: f32, b_in: f32, side_a: bool) -> f32 {
    var a = a_in;
    var b = b_in;
    for (var k = 0u; k < 160u; k++) {
        let m = 0.5 * (a + b);
        if m <= min(a, b) || m >= max(a, b) {
            break;
        }
        if (surface_cubic(c, m) > 0.0) == side_a {
            a = m;
        } else {
            b = m;
        }
    }
    return b;
}

// One corner's part of the cubic along a line: its value times three
// weights linear in s, each (constant, slope), multiplied out as the CPU
// does (constant first).
fn surface_corner_poly(val: f32, wx: vec2<f32>, wy: vec2<f32>, wz: vec2<f32>) -> vec4<f32> {
    var p = vec4<f32>(val, 0.0, 0.0, 0.0);
    p = vec4<f32>(p.x * wx.x, p.y * wx.x + p.x * wx.y, p.z * wx.x + p.y * wx.y, p.w * wx.x + p.z * wx.y);
    p = vec4<f32>(p.x * wy.x, p.y * wy.x + p.x * wy.y, p.z * wy.x + p.y * wy.y, p.w * wy.x + p.z * wy.y);
    p = vec4<f32>(p.x * wz.x, p.y * wz.x + p.x * wz.y, p.z * wz.x + p.y * wz.y, p.w * wz.x + p.z * wz.y);
    return p;
}

// `vdb_crossing`: the first crossing, on lo < t <= hi, of the solid where
// volume v exceeds `thr`: the cells the segment passes (a 3-D DDA), one
// cubic per cell, split at its extrema into monotone pieces. Returns
// (t, 1 found).
fn surface_vdb_t(v: u32, thr: f32, o: vec3<f32>, d: vec3<f32>, lo: f32, hi: f32) -> vec2<f32> {
    let dims = surface_data(v + 3u).xyz;
    if any(dims == vec3<u32>(0u)) {
        return vec2<f32>(0.0);
    }
    let org = vec3<f32>(bitcast<vec3<i32>>(surface_data(v + 2u).xyz));
    let h = surface_data_f(v).xyz;
    let u0 = surface_vdb_index(v, o);
    let du = d / h;
    // Beyond the middle of the background layer round the dense box the
    // interpolant is the constant background.
    var a = lo;
    var b = hi;
    for (var k = 0u; k < 3u; k++) {
        let s = surface_slab(u0[k], du[k], org[k] - 0.5, org[k] + f32(dims[k]) - 0.5);
        a = max(a, s.x);
        b = min(b, s.y);
    }
    if !(a < b) {
        return vec2<f32>(0.0);
    }
    // The side of the cells passed so far: 0 none yet, 1 inside, 2 outside.
    var side = 0u;
    var t = a;
    for (var steps = 0u; steps < SURFACE_MAX_MARCH; steps++) {
        if !(t < b) {
            break;
        }
        let u = u0 + du * t;
        var cellf = floor(u);
        var te = b;
        for (var k = 0u; k < 3u; k++) {
            if du[k] < 0.0 {
                cellf[k] = ceil(u[k]) - 1.0;
            }
            if du[k] > 0.0 {
                te = min(te, (cellf[k] + 1.0 - u0[k]) / du[k]);
            } else if du[k] < 0.0 {
                te = min(te, (cellf[k] - u0[k]) / du[k]);
            }
        }
        if te <= t {
            // Rounding at a cell face: nudge across it.
            te = min(t + (abs(t) + 1.0) * 1e-6, b);
            if te <= t {
                break;
            }
        }
        // The cell lies within the slab-clipped box, a voxel of
        // background round the data at most.
        let cell = vec3<i32>(clamp(cellf, org - 2.0, org + vec3<f32>(dims) + 1.0));
        let raw = surface_vdb_cell(v, cell);
        let vals = SurfaceCell(raw.c0 - thr, raw.c1 - thr);
        let all_in = all(vals.c0 > vec4<f32>(0.0)) && all(vals.c1 > vec4<f32>(0.0));
        let all_out = all(vals.c0 <= vec4<f32>(0.0)) && all(vals.c1 <= vec4<f32>(0.0));
        if all_in || all_out {
            // The interpolant is a mean of the corners: one side throughout.
            let here = select(2u, 1u, all_in);
            if side != 0u && side != here {
                return vec2<f32>(t, 1.0);
            }
            side = here;
            t = te;
            continue;
        }
        // The interpolant along the line, s = t' - t in [0, te - t]: each
        // axis's weight is linear in s, (1 - f - du s) or (f + du s); the
        // products of three such, summed over the corners in the CPU's
        // order.
        let f0 = u - vec3<f32>(cell);
        let lo_w = vec2<f32>(1.0 - f0.x, -du.x);
        let hi_w = vec2<f32>(f0.x, du.x);
        let lo_y = vec2<f32>(1.0 - f0.y, -du.y);
        let hi_y = vec2<f32>(f0.y, du.y);
        let lo_z = vec2<f32>(1.0 - f0.z, -du.z);
        let hi_z = vec2<f32>(f0.z, du.z);
        var poly = surface_corner_poly(vals.c0.x, lo_w, lo_y, lo_z);
        poly += surface_corner_poly(vals.c0.y, hi_w, lo_y, lo_z);
        poly += surface_corner_poly(vals.c0.z, lo_w, hi_y, lo_z);
        poly += surface_corner_poly(vals.c0.w, hi_w, hi_y, lo_z);
        poly += surface_corner_poly(vals.c1.x, lo_w, lo_y, hi_z);
        poly += surface_corner_poly(vals.c1.y, hi_w, lo_y, hi_z);
        poly += surface_corner_poly(vals.c1.z, lo_w, hi_y, hi_z);
        poly += surface_corner_poly(vals.c1.w, hi_w, hi_y, hi_z);
        let len = te - t;
        // Split at the extrema: each piece is monotone.
        var pts = array<f32, 3>(len, len, len);
        let crit = surface_quadratic(3.0 * poly.w, poly.z, poly.y);
        var m1 = len;
        var m2 = len;
        if crit.z >= 1.0 && crit.x > 0.0 && crit.x < len {
            m1 = crit.x;
        }
        if crit.z >= 2.0 && crit.y > 0.0 && crit.y < len {
            m2 = crit.y;
        }
        pts[0] = min(m1, m2);
        pts[1] = max(m1, m2);
        let s0 = surface_cubic(poly, 0.0) > 0.0;
        var cur = s0;
        if side != 0u && (side == 1u) != s0 {
            return vec2<f32>(t, 1.0);
        }
        var prev = 0.0;
        for (var j = 0u; j < 3u; j++) {
            let s = pts[j];
            let here = surface_cubic(poly, s) > 0.0;
            if here != cur {
                return vec2<f32>(t + surface_cubic_root(poly, prev, s, cur), 1.0);
            }
            prev = s;
            cur = here;
        }
        side = select(2u, 1u, cur);
        t = te;
    }
    return vec2<f32>(0.0);
}

// `vdb_normal`: the outward normal of the VDB solid at p, minus the
// gradient of the trilinear interpolant of its cell, normalized.
fn surface_vdb_normal(v: u32, p: vec3<f32>) -> vec3<f32> {
    let u = surface_vdb_index(v, p);
    let f = floor(u);
    if !surface_vdb_near(v, f) {
        return vec3<f32>(0.0, 1.0, 0.0);
    }
    let w = u - f;
    let c = surface_vdb_cell(v, vec3<i32>(f));
    // The interpolant's partial derivatives: differences across each axis,
    // interpolated along the other two.
    let dx = vec4<f32>(c.c0.y - c.c0.x, c.c0.w - c.c0.z, c.c1.y - c.c1.x, c.c1.w - c.c1.z);
    let gx = mix(mix(dx.x, dx.y, w.y), mix(dx.z, dx.w, w.y), w.z);
    let dy = vec4<f32>(c.c0.z - c.c0.x, c.c0.w - c.c0.y, c.c1.z - c.c1.x, c.c1.w - c.c1.y);
    let gy = mix(mix(dy.x, dy.y, w.x), mix(dy.z, dy.w, w.x), w.z);
    let dz = c.c1 - c.c0;
    let gz = mix(mix(dz.x, dz.y, w.x), mix(dz.z, dz.w, w.x), w.y);
    let g = vec3<f32>(gx, gy, gz);
    return surface_unit_or(-g / surface_data_f(v).xyz, vec3<f32>(0.0, 1.0, 0.0));
}

// `Shape::first_crossing` of the VDB solid where volume v exceeds `thr`.
fn surface_vdb(v: u32, thr: f32, o: vec3<f32>, d: vec3<f32>, lo: f32, hi: f32) -> SurfaceHit {
    let r = surface_vdb_t(v, thr, o, d, lo, hi);
    if r.y == 0.0 {
        return surface_miss();
    }
    return SurfaceHit(true, r.x, surface_vdb_normal(v, o + d * r.x));
}
