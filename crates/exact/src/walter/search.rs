//! Split-and-prune searches over a triangle with interpolated normals
//! ([Walter09 sec 3.3.1] and [Walter09 sec 3.3.2]): where to start the 2-D
//! Newton iteration.

use super::func::Problem;
use super::interval::{Interval, V3};
use super::newton::{newton2, pinv, plane_root, ACCEPT_RESIDUAL};
use super::{dedup, finish, Options, Solution, Stats, Triangle};
use glam::{DVec2, DVec3};

/// Solutions closer than this in barycentric units are the same one.
const DEDUP_TOL: f64 = 1e-8;

/// Newton steps allowed per run.
const MAX_NEWTON: u32 = 60;

/// A cone of directions with apex at the origin: unit `axis` and the
/// cosine and sine of its semi-angle `θ < π/2` (wider sets are represented
/// by `None`: "anything"). All tests compare cosines: no inverse
/// trigonometric function is evaluated.
#[derive(Debug, Clone, Copy)]
struct Cone {
    axis: DVec3,
    /// `cos θ`, in `(0, 1]`.
    cos: f64,
    /// `sin θ`, in `[0, 1)`.
    sin: f64,
}

impl Cone {
    /// The cone about `axis` through the direction whose dot product with
    /// `axis` is the smallest, `min_dot`; `None` for `θ >= π/2`.
    fn with_min_dot(axis: DVec3, min_dot: f64) -> Option<Cone> {
        let cos = min_dot.clamp(-1.0, 1.0);
        (cos > 0.0).then(|| Cone {
            axis,
            cos,
            sin: (1.0 - cos * cos).max(0.0).sqrt(),
        })
    }

    /// A cone containing the spherical triangle spanned by three unit
    /// vectors. The cone `{x : ∠(x, axis) <= θ}` is convex for `θ < π/2`, so
    /// containing the three corners means containing every normalized
    /// positive combination of them.
    fn of_units(w: [DVec3; 3]) -> Option<Cone> {
        let axis = (w[0] + w[1] + w[2]).normalize_or_zero();
        if axis == DVec3::ZERO {
            return None;
        }
        let min_dot = w[0].dot(axis).min(w[1].dot(axis)).min(w[2].dot(axis));
        Cone::with_min_dot(axis, min_dot)
    }

    /// The axis-aligned box of the unit vectors in the cone: the component
    /// along `e_k` of a unit vector at angle `<= θ` from the axis is a
    /// cosine of an angle in `[α_k − θ, α_k + θ]`, `α_k = ∠(axis, e_k)`,
    /// clamped to `[0, π]`; `cos(α ± θ)` by the addition formulas.
    fn bbox(&self) -> (DVec3, DVec3) {
        let (ct, st) = (self.cos, self.sin);
        let range = |a: f64| {
            let ca = a.clamp(-1.0, 1.0);
            let sa = (1.0 - ca * ca).max(0.0).sqrt();
            // α + θ <= π exactly when sin(α + θ) >= 0 (α + θ < 3π/2).
            let lo = if sa * ct + ca * st >= 0.0 {
                (ca * ct - sa * st).max(-1.0)
            } else {
                -1.0
            };
            // α <= θ exactly when cos α >= cos θ.
            let hi = if ca >= ct {
                1.0
            } else {
                (ca * ct + sa * st).min(1.0)
            };
            (lo, hi)
        };
        let (x, y, z) = (range(self.axis.x), range(self.axis.y), range(self.axis.z));
        (DVec3::new(x.0, y.0, z.0), DVec3::new(x.1, y.1, z.1))
    }

    /// A cone containing the box `[lo, hi]` (as a set of vectors), `None`
    /// when the box contains the origin or needs a semi-angle of 90° or more.
    fn of_box(lo: DVec3, hi: DVec3) -> Option<Cone> {
        if lo.cmple(DVec3::ZERO).all() && hi.cmpge(DVec3::ZERO).all() {
            return None;
        }
        let axis = (0.5 * (lo + hi)).normalize_or_zero();
        if axis == DVec3::ZERO {
            return None;
        }
        let mut min_dot: f64 = 1.0;
        for i in 0..8 {
            let c = DVec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            );
            let c = c.normalize_or_zero();
            if c == DVec3::ZERO {
                return None;
            }
            min_dot = min_dot.min(c.dot(axis));
        }
        Cone::with_min_dot(axis, min_dot)
    }

    /// Two cones overlap if the angle between their axes is at most the sum
    /// of their semi-angles [Walter09 sec 3.3.1]: the sum is below `π`, so on
    /// cosines, `cos ∠ >= cos(θ₁ + θ₂)` (with a little slack for rounding).
    fn overlaps(&self, o: &Cone) -> bool {
        self.axis.dot(o.axis) >= self.cos * o.cos - self.sin * o.sin - 1e-12
    }

    /// Whether the two semi-angles sum to less than the angle with cosine
    /// `cos_limit`, an angle in `(0, π)` (the sum is below `π`).
    fn spans_less_than(&self, o: &Cone, cos_limit: f64) -> bool {
        self.cos * o.cos - self.sin * o.sin > cos_limit
    }
}

/// Bounding cones on `−σ Ĥ` and `N̂_s` over the sub-triangle with
/// barycentric corners `q` [Walter09 sec 3.3.1]: the directions to `V` and to
/// `L` from the sub-triangle form spherical triangles; their boxes, the `V` one
/// scaled by `η`, are added (Minkowski sum) to bound the unnormalized
/// half-vector, which is bounded in turn by a cone. A solution has
/// `N̂_s = −σ Ĥ`. `None` stands for "anything".
fn cones(
    tri: &Triangle,
    v: DVec3,
    l: DVec3,
    eta: f64,
    q: &[DVec2; 3],
) -> (Option<Cone>, Option<Cone>) {
    let ncone = Cone::of_units(q.map(|x| tri.shading_normal(x)));
    if ncone.is_none() {
        // The pair is "anything" whatever the half-vector cone is.
        return (None, None);
    }
    let pts = q.map(|x| tri.point(x));
    let vcone = Cone::of_units(pts.map(|p| (v - p).normalize()));
    let lcone = Cone::of_units(pts.map(|p| (l - p).normalize()));
    let hcone = match (vcone, lcone) {
        (Some(a), Some(b)) => {
            let (alo, ahi) = a.bbox();
            let (blo, bhi) = b.bbox();
            let (lo, hi) = (eta * alo + blo, eta * ahi + bhi);
            if eta > 1.0 {
                Cone::of_box(-hi, -lo)
            } else {
                Cone::of_box(lo, hi)
            }
        }
        _ => None,
    };
    (hcone, ncone)
}

/// Runs Newton from `start` and keeps a converged physical solution.
fn try_start(
    tri: &Triangle,
    (prob, pi): (&Problem<f64>, &Problem<Interval>),
    (v, l, eta): (DVec3, DVec3, f64),
    start: DVec2,
    certified: bool,
    stats: &mut Stats,
) -> Option<Solution> {
    let out = newton2(prob, start, MAX_NEWTON);
    stats.newton_runs += 1;
    stats.newton_iterations += out.iterations as usize;
    if !out.converged(pi) {
        return None;
    }
    finish(tri, v, l, eta, out.uv, out.iterations, certified)
}

/// The projection of `V` onto the triangle's plane along the mean vertex
/// normal, in barycentric coordinates (a start point of [Walter09 sec 3.3]).
fn projected_v(tri: &Triangle, v: DVec3) -> Option<DVec2> {
    let navg = tri.n[0].normalize() + tri.n[1].normalize() + tri.n[2].normalize();
    let ng = tri.geometric_normal();
    let t = (tri.p[0] - v).dot(ng) / navg.dot(ng);
    t.is_finite().then(|| tri.barycentric(v + t * navg))
}

/// [Walter09 sec 3.3.1] with the cone-angle stopping heuristic: split the
/// triangle 4 ways while the cones of `−σĤ` and `N̂_s` overlap, until their
/// semi-angles sum to less than `opts.cone_angle_deg`; then run Newton in each
/// remaining sub-triangle. Start points: see [`Options::paper_starts`].
pub(crate) fn heuristic(
    tri: &Triangle,
    v: DVec3,
    l: DVec3,
    eta: f64,
    opts: &Options,
    stats: &mut Stats,
) -> Vec<Solution> {
    let prob = Problem::<f64>::new(tri, v, l, eta);
    let pi = Problem::<Interval>::new(tri, v, l, eta);
    let probs = (&prob, &pi);
    // The stopping rule on cosines: `θ_H + θ_N < limit`, with both
    // semi-angles below π/2.
    let limit = opts.cone_angle_deg.to_radians();
    let cos_limit = limit.cos();
    let vproj = projected_v(tri, v);
    let query = (v, l, eta);
    let mut found = Vec::new();
    let mut stack = vec![([DVec2::ZERO, DVec2::X, DVec2::Y], 0u32)];
    let mut any_leaf = false;
    while let Some((q, depth)) = stack.pop() {
        stats.regions += 1;
        let (hcone, ncone) = cones(tri, v, l, eta, &q);
        let (stop, overlap) = match (hcone, ncone) {
            (Some(h), Some(n)) => {
                let stop = if limit >= std::f64::consts::PI {
                    true
                } else if limit > 0.0 {
                    h.spans_less_than(&n, cos_limit)
                } else {
                    false
                };
                (stop, h.overlaps(&n))
            }
            _ => (false, true),
        };
        if !overlap {
            stats.pruned += 1;
            continue;
        }
        if depth == 0 && no_residual_below_accept(&pi) {
            // Proven: no point of the triangle has ‖f‖ small enough for a
            // Newton run to be accepted there, so none of the runs below
            // could report anything.
            stats.pruned += 1;
            continue;
        }
        let m = [
            0.5 * (q[0] + q[1]),
            0.5 * (q[1] + q[2]),
            0.5 * (q[2] + q[0]),
        ];
        if stop || depth >= opts.max_depth {
            any_leaf = true;
            let c = (q[0] + q[1] + q[2]) / 3.0;
            if opts.paper_starts {
                // The centroid, unless ‖f‖ > 1 there: then the best of the
                // centroid, the corners and the projection of V.
                let norm = |x: DVec2| prob.f(x.x, x.y).to_dvec().length();
                let mut best = (norm(c), c);
                if best.0 > 1.0 {
                    for s in [q[0], q[1], q[2]].into_iter().chain(vproj) {
                        let r = norm(s);
                        if r < best.0 {
                            best = (r, s);
                        }
                    }
                }
                found.extend(try_start(tri, probs, query, best.1, false, stats));
            } else {
                for s in [c, q[0], q[1], q[2], m[0], m[1], m[2]] {
                    found.extend(try_start(tri, probs, query, s, false, stats));
                }
            }
        } else {
            for sub in [
                [q[0], m[0], m[2]],
                [m[0], q[1], m[1]],
                [m[2], m[1], q[2]],
                [m[0], m[1], m[2]],
            ] {
                stack.push((sub, depth + 1));
            }
        }
    }
    if any_leaf && !opts.paper_starts {
        // The flat triangle's root ([Walter09 sec 3.2], about the geometric
        // normal): for nearly flat normals it lies within about ‖J⁺‖ times
        // their tilt of a root, where the other start points may all be outside
        // Newton's basin (with V or L close to the plane the basin is that
        // small).
        let (flat, iters) = plane_root(tri, v, l, eta);
        stats.newton_iterations += iters as usize;
        for s in vproj.into_iter().chain([flat]) {
            found.extend(try_start(tri, probs, query, s, false, stats));
        }
    }
    dedup(found, DEDUP_TOL)
}

/// Whether `‖f‖ > 2·ACCEPT_RESIDUAL` at every point of the whole triangle,
/// proven with the mean-value form: for `x` in the triangle `T` and its
/// centroid `c`, `w·f(x) ∈ w·F(c) + Σ_j (w·F'_j(X)) (x_j − c_j)` for any
/// unit `w`, with `F'(X)` the interval Jacobian over `X = [0, 1]² ⊇ T`.
/// The linear part is bounded at the vertices of `T` (it is exact there for
/// the midpoint coefficients) and the coefficients' radii by `|x_j − c_j| <=
/// 2/3`. Directions tried: the normal of the Jacobian's range (a residual
/// that Gauss-Newton cannot remove) and the rows of `M⁺` and their sum (a
/// linearized root beyond an edge of `T`, as in [Walter09 eq 13]), and `f(c)`
/// itself. Since `‖f(x)‖ >= |w·f(x)|`, a sign-definite interval beyond the
/// margin means no Newton run can converge (`‖f‖ <= ACCEPT_RESIDUAL`) on `T`
/// where doubles resolve that tolerance, and `T` holds no root that
/// [`certify_root`] could certify where they do not.
pub(crate) fn no_residual_below_accept(pi: &Problem<Interval>) -> bool {
    excluded_on(pi, &[DVec2::ZERO, DVec2::X, DVec2::Y], EXCLUSION_DEPTH)
}

/// Splits of the triangle tried by [`no_residual_below_accept`].
const EXCLUSION_DEPTH: u32 = 1;

/// [`no_residual_below_accept`] on the sub-triangle `q`, splitting it 4
/// ways (all four must be excluded) at most `depth` more times.
fn excluded_on(pi: &Problem<Interval>, q: &[DVec2; 3], depth: u32) -> bool {
    let margin = 2.0 * ACCEPT_RESIDUAL;
    let lo = q[0].min(q[1]).min(q[2]);
    let hi = q[0].max(q[1]).max(q[2]);
    let e = pi.eval(Interval::new(lo.x, hi.x), Interval::new(lo.y, hi.y));
    let c = (q[0] + q[1] + q[2]) / 3.0;
    let fc = pi.f(Interval::point(c.x), Interval::point(c.y));
    let (ju, jv) = (mid3(e.fu), mid3(e.fv));
    let mut dirs = [DVec3::ZERO; 5];
    dirs[0] = ju.cross(jv);
    if let Some(mp) = pinv(ju, jv) {
        dirs[1] = mp[0];
        dirs[2] = mp[1];
        dirs[3] = mp[0] + mp[1];
    }
    dirs[4] = mid3(fc);
    // Vertex offsets x − c of q, and bounds on |x_j − c_j| over q.
    let verts = q.map(|x| x - c);
    let dmax = verts[0].abs().max(verts[1].abs()).max(verts[2].abs()) * (1.0 + 1e-12);
    for w in dirs {
        let w = w.normalize_or_zero();
        if w == DVec3::ZERO || !w.is_finite() {
            continue;
        }
        let g0 = dot_fi(w, fc);
        let (a0, a1) = (dot_fi(w, e.fu), dot_fi(w, e.fv));
        let (m0, m1) = (a0.mid(), a1.mid());
        let rad =
            (a0.hi() - m0).max(m0 - a0.lo()) * dmax.x + (a1.hi() - m1).max(m1 - a1.lo()) * dmax.y;
        let (mut lmin, mut lmax) = (f64::INFINITY, f64::NEG_INFINITY);
        for d in verts {
            let t = m0 * d.x + m1 * d.y;
            lmin = lmin.min(t);
            lmax = lmax.max(t);
        }
        // Rounding of the float terms above: far below the margin.
        let slack = 1e-12 * (m0.abs() + m1.abs()) + rad * (1.0 + 1e-12);
        if g0.lo() + lmin - slack > margin || g0.hi() + lmax + slack < -margin {
            return true;
        }
    }
    if depth == 0 {
        return false;
    }
    let m = [
        0.5 * (q[0] + q[1]),
        0.5 * (q[1] + q[2]),
        0.5 * (q[2] + q[0]),
    ];
    [
        [q[0], m[0], m[2]],
        [m[0], q[1], m[1]],
        [m[2], m[1], q[2]],
        [m[0], m[1], m[2]],
    ]
    .iter()
    .all(|sub| excluded_on(pi, sub, depth - 1))
}

/// Whether some component's interval excludes zero ([Walter09 eq 12] proves
/// there is no solution then; the paper prints "∅ ∉ F(X)" for "0 ∉ F(X)").
fn excludes_zero(f: V3<Interval>) -> bool {
    !(f.x.contains(0.0) && f.y.contains(0.0) && f.z.contains(0.0))
}

fn mid3(v: V3<Interval>) -> DVec3 {
    DVec3::new(v.x.mid(), v.y.mid(), v.z.mid())
}

/// `row · col` for a float row and an interval column.
fn dot_fi(row: DVec3, col: V3<Interval>) -> Interval {
    col.x * row.x + col.y * row.y + col.z * row.z
}

/// Outcome of the Krawczyk test on one box.
pub(crate) enum Krawczyk {
    /// [Walter09 eq 12 or 13]: no solution in the box.
    Empty,
    /// [Walter09 eqs 14 and 15]: at most one solution, the unique fixed point
    /// of `g(x) = x − M⁺ f(x)`, reachable by the chord iteration with `M⁺`.
    Unique { m_plus: [DVec3; 2] },
    /// Undecided; a solution, if any, lies in the contracted box `K ∩ X`.
    Split([Interval; 2]),
}

/// The Krawczyk operator of [Walter09 eq 11] on the barycentric box `x`:
/// `K(X) = m₀ − M⁺ f(m₀) + [I − M⁺ F'(X)](X − m₀)` with `m₀ = m(X)`,
/// `M = m(F'(X))` and `M⁺` its pseudo-inverse.
///
/// `g(x) = x − M⁺ f(x)` maps `X` into `K(X)` (mean-value form), and every
/// zero of `f` is a fixed point of `g`. Hence `K ∩ X = ∅` excludes
/// solutions [Walter09 eq 13]; `K ⊆ X` (Brouwer) with `‖I − M⁺F'(X)‖∞ < 1`
/// (contraction, [Walter09 eq 15]) gives a unique fixed point of `g` in `X`, so
/// at most one zero of `f` (with a 3×2 Jacobian a fixed point of `g` need only
/// make `f` orthogonal to the range of `M`; the caller checks `‖f‖` there).
pub(crate) fn krawczyk(pi: &Problem<Interval>, x: [Interval; 2]) -> Krawczyk {
    // [Walter09 eq 12], the cheaper test, first.
    if excludes_zero(pi.f(x[0], x[1])) {
        return Krawczyk::Empty;
    }
    let e = pi.eval(x[0], x[1]);
    let m0 = [x[0].mid(), x[1].mid()];
    let Some(mp) = pinv(mid3(e.fu), mid3(e.fv)) else {
        return Krawczyk::Split(x);
    };
    let fm = pi.f(Interval::point(m0[0]), Interval::point(m0[1]));
    let cols = [e.fu, e.fv];
    let mut k = [Interval::ENTIRE; 2];
    let mut norm: f64 = 0.0;
    for i in 0..2 {
        let mut row_sum = Interval::point(0.0);
        let mut ki = Interval::point(m0[i]) - dot_fi(mp[i], fm);
        for j in 0..2 {
            let delta = if i == j { 1.0 } else { 0.0 };
            let a = Interval::point(delta) - dot_fi(mp[i], cols[j]);
            row_sum = row_sum + Interval::point(a.mag());
            ki = ki + a * (x[j] - m0[j]);
        }
        norm = norm.max(row_sum.hi());
        k[i] = ki;
    }
    let (Some(c0), Some(c1)) = (k[0].intersect(x[0]), k[1].intersect(x[1])) else {
        return Krawczyk::Empty; // [Walter09 eq 13]
    };
    if k[0].subset_of(x[0]) && k[1].subset_of(x[1]) && norm < 1.0 {
        return Krawczyk::Unique { m_plus: mp }; // [Walter09 eqs 14-15]
    }
    Krawczyk::Split([c0, c1])
}

/// Proves that [Walter09 eq 8] has a root within `max_radius` (barycentric
/// units) of the Newton iterate `x` (used where doubles cannot bring `‖f‖`
/// below the fixed tolerance, [`super::newton::NewtonOut::converged`]).
///
/// With a 3×2 Jacobian a fixed point of the paper's Krawczyk operator
/// [Walter09 eqs 11, 14-15] need only make `f` orthogonal to the range of `M`,
/// so the test runs on a square form of [Walter09 eq 8] instead:
/// `g = Tᵀ (h × n)`, with `h = η ω̂_V + ω̂_L`, `n` the interpolated normal
/// ([`Problem::cross_eval`]) and `T` two unit vectors across the shading normal
/// `ν` at `x`. If `g = 0`, `h × n` is parallel to `ν` and orthogonal to `n`,
/// hence zero wherever `ν·n ≠ 0`; with `sign(h·n) = −σ` that is `Ĥ = −σ N̂_s`,
/// a root of [Walter09 eq 8]. On the box `X` of half-width four times the
/// enclosed Newton correction `|Y g(x)|` (plus 4 ulps) around `x`, with `Y` the
/// inverse of the point Jacobian (refused if wider than `max_radius`), the
/// Krawczyk operator
/// `K = x − Y g(x) + (I − Y G'(X))(X − x)` maps `X` into its interior and
/// `‖I − Y G'(X)‖∞ < 1` (R. Krawczyk 1969, "Newton-Algorithmen zur
/// Bestimmung von Nullstellen mit Fehlerschranken", Computing 4): then `Y`
/// is regular and `g` has exactly one zero in `X` (Brouwer for the map
/// `x − Y g(x)`, which takes `X` into `K`; the norm makes it a
/// contraction). `ν·n > 0` and the sign of
/// `h·n` are checked over all of `X`. Every bound is an interval enclosure
/// of exact values of the stated problem, so a certified root is a true
/// one.
pub(crate) fn certify_root(pi: &Problem<Interval>, x: DVec2, max_radius: f64) -> bool {
    let xs = [x.x, x.y];
    let at = pi.cross_eval(Interval::point(x.x), Interval::point(x.y));
    let nu = mid3(at.n).normalize_or_zero();
    if nu == DVec3::ZERO || !nu.is_finite() {
        return false;
    }
    let (t1, t2) = nu.any_orthonormal_pair();
    let g = [dot_fi(t1, at.c), dot_fi(t2, at.c)];
    let jm = [
        [dot_fi(t1, at.cu).mid(), dot_fi(t1, at.cv).mid()],
        [dot_fi(t2, at.cu).mid(), dot_fi(t2, at.cv).mid()],
    ];
    let det = jm[0][0] * jm[1][1] - jm[0][1] * jm[1][0];
    if !det.is_finite() || det == 0.0 {
        return false;
    }
    let y = [
        [jm[1][1] / det, -jm[0][1] / det],
        [-jm[1][0] / det, jm[0][0] / det],
    ];
    // The Newton correction Y g(x), enclosed, and the box around x.
    let yg = [0, 1].map(|i| g[0] * y[i][0] + g[1] * y[i][1]);
    let bx = [0, 1].map(|i| {
        let r = 4.0 * yg[i].mag() + 4.0 * f64::EPSILON * xs[i].abs() + f64::MIN_POSITIVE;
        let (p, r) = (Interval::point(xs[i]), Interval::point(r));
        Interval::new((p - r).lo(), (p + r).hi())
    });
    let small = |i: usize| bx[i].hi() - xs[i] <= max_radius && xs[i] - bx[i].lo() <= max_radius;
    if !small(0) || !small(1) {
        return false;
    }
    let over = pi.cross_eval(bx[0], bx[1]);
    let oriented = if pi.sigma.lo() > 0.0 {
        over.hn.hi() < 0.0
    } else {
        over.hn.lo() > 0.0
    };
    if !oriented || dot_fi(nu, over.n).lo() <= 0.0 {
        return false;
    }
    let gp = [
        [dot_fi(t1, over.cu), dot_fi(t1, over.cv)],
        [dot_fi(t2, over.cu), dot_fi(t2, over.cv)],
    ];
    for i in 0..2 {
        let mut k = Interval::point(xs[i]) - yg[i];
        let mut row = Interval::point(0.0);
        for j in 0..2 {
            let delta = if i == j { 1.0 } else { 0.0 };
            let a = Interval::point(delta) - (gp[0][j] * y[i][0] + gp[1][j] * y[i][1]);
            row = row + Interval::point(a.mag());
            k = k + a * (bx[j] - Interval::point(xs[j]));
        }
        let inside = k.lo() > bx[i].lo() && k.hi() < bx[i].hi();
        if !inside || row.hi() >= 1.0 {
            return false;
        }
    }
    true
}

fn near_box(uv: DVec2, x: &[Interval; 2], tol: f64) -> bool {
    uv.x >= x[0].lo() - tol
        && uv.x <= x[0].hi() + tol
        && uv.y >= x[1].lo() - tol
        && uv.y <= x[1].hi() + tol
}

/// [Walter09 sec 3.3.2]: split-and-prune on boxes of barycentric coordinates,
/// starting from `[0, 1]²`, with the Krawczyk test deciding each box. Boxes
/// entirely beyond the hypotenuse `u + v = 1` are dropped. Undecided boxes are
/// contracted to `K ∩ X` (sound: every solution in `X` lies in `K(X)`),
/// and bisected across their wider side unless that shrank their
/// semi-perimeter by a quarter (either way it shrinks geometrically, so the
/// search terminates).
pub(crate) fn guaranteed(
    tri: &Triangle,
    v: DVec3,
    l: DVec3,
    eta: f64,
    opts: &Options,
    stats: &mut Stats,
) -> Vec<Solution> {
    let pf = Problem::<f64>::new(tri, v, l, eta);
    let pi = Problem::<Interval>::new(tri, v, l, eta);
    let unit = Interval::new(0.0, 1.0);
    let mut stack = vec![[unit, unit]];
    let mut found = Vec::new();
    let query = (v, l, eta);
    while let Some(x) = stack.pop() {
        if x[0].lo() + x[1].lo() > 1.0 + 1e-12 {
            continue;
        }
        stats.regions += 1;
        let center = DVec2::new(x[0].mid(), x[1].mid());
        if stats.regions > opts.max_boxes {
            stats.unresolved += 1;
            found.extend(try_start(tri, (&pf, &pi), query, center, false, stats));
            continue;
        }
        match krawczyk(&pi, x) {
            Krawczyk::Empty => stats.pruned += 1,
            Krawczyk::Unique { m_plus } => {
                stats.certified += 1;
                // Chord iteration with the fixed M⁺: a contraction of X.
                let mut y = center;
                for _ in 0..100 {
                    let f = pf.f(y.x, y.y).to_dvec();
                    let d = DVec2::new(m_plus[0].dot(f), m_plus[1].dot(f));
                    y = DVec2::new(
                        (y.x - d.x).clamp(x[0].lo(), x[0].hi()),
                        (y.y - d.y).clamp(x[1].lo(), x[1].hi()),
                    );
                    if d.length() <= 1e-15 {
                        break;
                    }
                }
                let out = newton2(&pf, y, MAX_NEWTON);
                stats.newton_runs += 1;
                stats.newton_iterations += out.iterations as usize;
                if out.converged(&pi) && near_box(out.uv, &x, 1e-9) {
                    found.extend(finish(tri, v, l, eta, out.uv, out.iterations, true));
                }
            }
            Krawczyk::Split(c) => {
                let (w0, w1) = (c[0].width(), c[1].width());
                if w0.max(w1) < opts.min_box_width {
                    stats.unresolved += 1;
                    let mid = DVec2::new(c[0].mid(), c[1].mid());
                    found.extend(try_start(tri, (&pf, &pi), query, mid, false, stats));
                } else if w0 + w1 <= 0.75 * (x[0].width() + x[1].width()) {
                    stack.push(c);
                } else if w0 >= w1 {
                    let m = c[0].mid();
                    stack.push([Interval::new(c[0].lo(), m), c[1]]);
                    stack.push([Interval::new(m, c[0].hi()), c[1]]);
                } else {
                    let m = c[1].mid();
                    stack.push([c[0], Interval::new(c[1].lo(), m)]);
                    stack.push([c[0], Interval::new(m, c[1].hi())]);
                }
            }
        }
    }
    dedup(found, DEDUP_TOL)
}
