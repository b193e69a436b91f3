//! Refracted connecting paths through one triangle of a medium's boundary,
//! after Walter, Zhao, Holzschuch & Bala 2009, "Single scattering in
//! refractive media with triangle mesh boundaries" (ACM TOG 28(3), 2009,
//! DOI 10.1145/1531326.1531398; cited as `Walter09`:
//! [Walter09 secs 3.1-3.3 and 4]).
//!
//! Given a scatter point `V` inside a medium of relative index
//! `η = η_in / η_out`, a point light `L` outside, and one boundary triangle,
//! [`solve`] finds every point `P` on the triangle where light from `L`
//! refracts towards `V` (Snell's law relative to the shading normal), and
//! [`contribution`] weighs such a path by [Walter09 eq 17] with the distance
//! factor `D` of [Walter09 eq 18] (flat triangles) or [Walter09 eqs 21-26]
//! (interpolated normals).
//!
//! # Conventions (the paper's, [Walter09 sec 3.1])
//!
//! * Normals (vertex normals `n0, n1, n2`, the shading normal `N̂_s`, the
//!   geometric normal `N̂_g`) point **out of** the refractive medium. The
//!   geometric normal is the face normal oriented to agree with the vertex
//!   normals ([`Triangle::geometric_normal`]).
//! * `ω̂_V = (V − P)/‖V − P‖` and `ω̂_L = (L − P)/‖L − P‖` [Walter09 eqs 1-2]
//!   both point away from `P`. Light travels `L → P → V`, so its direction of
//!   travel inside the medium is `ω̂_V`.
//! * The generalized half-vector is `Ĥ = (η ω̂_V + ω̂_L)/‖η ω̂_V + ω̂_L‖`
//!   [Walter09 eq 3]. Its component tangent to the normal vanishes exactly when
//!   the tangential components obey `η sin θ_V = sin θ_L` in a common plane of
//!   incidence (Snell's law), and it points into the denser medium: for
//!   `η > 1` a solution has `Ĥ = −N̂_s` [Walter09 eq 4], for `η < 1` it has
//!   `Ĥ = +N̂_s`.
//! * A solution must also have `V` and `L` on opposite sides of the
//!   triangle's plane, `V·N̂_g < P·N̂_g < L·N̂_g` ([Walter09 eq 4], strict
//!   here), and `ω̂_L·N̂_s > 0 > ω̂_V·N̂_s`: light arrives from the outside of
//!   the shading frame too. (With strongly tilted shading normals
//!   [Walter09 eq 8] has a second, non-physical root family with both
//!   directions inside; it is discarded.)
//! * Positions on the triangle are barycentric `(u, v)`:
//!   `P = (1 − u − v) p0 + u p1 + v p2` (the paper's `(a, b)`), and the
//!   shading normal is the normalized linear interpolation
//!   `N̂_s = n / ‖n‖`, `n = (1 − u − v) n0 + u n1 + v n2`. A point is on the
//!   triangle when `u >= 0`, `v >= 0`, `u + v <= 1` (edges included, so a
//!   path through a shared edge of a mesh can be reported by both
//!   triangles).
//!
//! # Methods
//!
//! * Flat triangles (all vertex normals equal to the geometric normal):
//!   the 1-D Newton iteration of [Walter09 eqs 5-7] in the plane of incidence,
//!   with the start value of [Walter09 eq 6] and clamping to `[0, L_x]`,
//!   safeguarded by a bracket (`f` is strictly decreasing there, so the root is
//!   unique).
//! * Interpolated normals: 2-D Newton on `f(u, v) = Ĥ + σ N̂_s` [Walter09 eq 8]
//!   with the pseudo-inverse `J⁺ = (JᵀJ)⁻¹Jᵀ` [Walter09 eq 9], steps limited to
//!   length 1/2 and halved until `‖f‖` decreases, started from several points
//!   of each sub-region. Where to start is decided by one of two [`Mode`]s:
//!   [`Mode::Heuristic`] (split-and-prune with bounding cones, stop when the
//!   `Ĥ` and `N̂_s` cones together span less than 30°, [Walter09 sec 3.3.1]) or
//!   [`Mode::Guaranteed`] (split-and-prune on barycentric boxes with the
//!   interval Krawczyk test, [Walter09 eqs 11-15], [Walter09 sec 3.3.2]). A run
//!   is accepted at `‖f‖ <= 1e-10`, or, where doubles cannot reach that (`V` or
//!   `L` very close to the plane), at the residual they can reach with the root
//!   proven by an interval test (`newton::NewtonOut::converged`).
//!
//! # The distance factor and [Walter09 eq 17]
//!
//! `D = dA_L / dω_V`: perturb the direction `ω̂_V` at `V` over a small solid
//! angle `dω_V`, follow the path through the interface (refracting about
//! the shading normal at the moved point `P`), and measure the area `dA_L`
//! it sweeps at the light's distance, in the plane perpendicular to `ω̂_L`
//! [Walter09 eqs 21-26]. Without refraction `D = ‖L − V‖²`; at normal incidence
//! on a flat face `D = (d_V + η d_L)²`.
//!
//! For a flat face, reciprocity (conservation of étendue `n² dA dω`) relates
//! it to the spread of a beam leaving the light: `dA_V/dω_L = D/η²` (checked
//! by finite differences in the tests). The irradiance at `V` from a point
//! source of intensity `I_e` is therefore `η² I_e F / D` *inside* the medium;
//! [Walter09 eq 17] omits that `η²`, which is exactly the `1/η²` that
//! radiance loses when the scattered light leaves the medium towards an eye
//! outside it (the `n²` law of radiance).
//! So use [`Contribution::value`] as is for an eye outside the medium whose
//! exit refraction does not scale radiance, and multiply by `η²` for
//! radiance inside the medium. With interpolated normals the two beam
//! spreads are no longer reciprocal (shading normals break reciprocity);
//! the paper's `D` is the `V`-side one, computed here.
//!
//! ## Sign conventions in [Walter09 eqs 21 and 24]
//!
//! As printed, [Walter09 eq 21] (`P' = d_V(ω̂'_V − …)`) and [Walter09 eq 24]
//! (`ω̂'_L = η ω̂'_V + …`) take `ω̂'_V` as the derivative of the *view-ray*
//! direction `−ω̂_V` from `V` towards `P`, while [Walter09 eqs 22-23] use
//! `ω̂_V` of [Walter09 eq 1] (from `P` to `V`). With one derivative `s = ω̂'_V`
//! of [Walter09 eq 1]'s `ω̂_V` throughout, the consistent forms, derived from
//! `P = V − d_V ω̂_V` on the plane and `ω̂_L = μ N̂_s − η ω̂_V`
//! ([Walter09 eq 3] at a solution, `μ` of [Walter09 eq 22]), are
//! `P' = −d_V (s − (s·N̂_g)/(ω̂_V·N̂_g) ω̂_V)` and
//! `ω̂'_L = −η s + μ' N̂_s + μ N̂'_s`; [Walter09 eqs 22, 23, 25 and 26] are
//! used as printed. `D` does not depend on the sign of `s`; the
//! finite-difference tests confirm these forms.
//!
//! On a caustic `D = 0` and [Walter09 eq 17] is infinite; the paper clamps `D`
//! from below for such scenes [Walter09 sec 5]. That is left to the caller.
//!
//! # Meshes
//!
//! [`PnTree`] is the position-normal tree of [Walter09 sec 3.4] with its
//! spindle [Walter09 eq 16], sidedness and cone-overlap tests; [`solve_mesh`]
//! runs the solver on the triangles the tree keeps. Occlusion and lights are
//! the renderer's business ([`crate::single`]).

mod distance;
mod func;
pub mod interval;
mod newton;
mod search;
#[cfg(test)]
mod tests;
mod tree;

pub use distance::{
    contribution, distance_factor, distance_factor_flat, distance_factor_general, Contribution,
    Medium,
};
pub use interval::Interval;
pub use tree::{NormalCone, PnTree, TreeStats};

use glam::{DVec2, DVec3};

/// One boundary triangle: vertex positions and (outward) vertex normals.
/// The vertex normals need not be unit length; they are interpolated
/// linearly and then normalized.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Triangle {
    /// Vertex positions `p0, p1, p2`.
    pub p: [DVec3; 3],
    /// Vertex normals `n0, n1, n2`, pointing out of the medium.
    pub n: [DVec3; 3],
}

impl Triangle {
    /// A triangle with the given positions and vertex normals.
    pub fn new(p: [DVec3; 3], n: [DVec3; 3]) -> Triangle {
        Triangle { p, n }
    }

    /// A flat triangle (no shading normals): every vertex normal is the face
    /// normal `(p1 − p0) × (p2 − p0)`, normalized, i.e. the vertices run
    /// counter-clockwise when seen from outside the medium.
    pub fn flat(p0: DVec3, p1: DVec3, p2: DVec3) -> Triangle {
        let n = (p1 - p0).cross(p2 - p0).normalize();
        Triangle {
            p: [p0, p1, p2],
            n: [n; 3],
        }
    }

    /// The unit face normal `N̂_g`, oriented to agree with the sum of the
    /// vertex normals (outward).
    pub fn geometric_normal(&self) -> DVec3 {
        let g = (self.p[1] - self.p[0])
            .cross(self.p[2] - self.p[0])
            .normalize();
        if g.dot(self.n[0] + self.n[1] + self.n[2]) < 0.0 {
            -g
        } else {
            g
        }
    }

    /// Whether every vertex normal is parallel to the geometric normal (to
    /// 1e-12 rad), so that the closed-form methods of [Walter09 sec 3.2] and
    /// [Walter09 eq 18] apply.
    pub fn is_flat(&self) -> bool {
        let g = self.geometric_normal();
        self.n.iter().all(|n| {
            let n = n.normalize();
            n.dot(g) > 0.0 && n.cross(g).length() <= 1e-12
        })
    }

    /// The point with barycentric coordinates `(u, v)`.
    pub fn point(&self, uv: DVec2) -> DVec3 {
        self.p[0] + uv.x * (self.p[1] - self.p[0]) + uv.y * (self.p[2] - self.p[0])
    }

    /// The unnormalized interpolated normal at `(u, v)`.
    pub fn interpolated_normal(&self, uv: DVec2) -> DVec3 {
        self.n[0] + uv.x * (self.n[1] - self.n[0]) + uv.y * (self.n[2] - self.n[0])
    }

    /// The unit shading normal `N̂_s(u, v)`.
    pub fn shading_normal(&self, uv: DVec2) -> DVec3 {
        self.interpolated_normal(uv).normalize()
    }

    /// Barycentric coordinates of the orthogonal projection of `x` onto the
    /// triangle's plane.
    pub fn barycentric(&self, x: DVec3) -> DVec2 {
        let e1 = self.p[1] - self.p[0];
        let e2 = self.p[2] - self.p[0];
        let d = x - self.p[0];
        let (a, b, c) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
        let (r1, r2) = (d.dot(e1), d.dot(e2));
        let det = a * c - b * b;
        DVec2::new((c * r1 - b * r2) / det, (a * r2 - b * r1) / det)
    }

    /// Whether `(u, v)` is on the closed triangle.
    pub fn contains(uv: DVec2) -> bool {
        uv.x >= 0.0 && uv.y >= 0.0 && uv.x + uv.y <= 1.0
    }
}

/// How [`solve`] searches a triangle with interpolated normals (flat
/// triangles are always solved by the exact 1-D method of [Walter09 sec 3.2]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Interval split-and-prune with the Krawczyk test [Walter09 eqs 11-15]:
    /// every box is either proven free of solutions [Walter09 eq 12 or 13] or
    /// proven to hold at most one, which is then found by Newton iteration
    /// [Walter09 eqs 14-15]. Solutions it reports carry `certified = true`
    /// unless a box shrank to [`Options::min_box_width`] without being resolved
    /// (a near-double root at a caustic), in which case plain Newton runs from
    /// it.
    Guaranteed,
    /// Cone split-and-prune stopping once the `Ĥ` and `N̂_s` bounding cones
    /// together span less than [`Options::cone_angle_deg`] (30°,
    /// [Walter09 sec 3.3.1]), then Newton from start points in each
    /// sub-triangle ([`Options::paper_starts`]). Fast, but it may miss
    /// solutions (see the tests for measured miss rates).
    Heuristic,
}

/// Tuning knobs for [`solve_with`]; [`Options::new`] gives the paper's values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    /// Search strategy for triangles with interpolated normals.
    pub mode: Mode,
    /// Heuristic mode: stop splitting when the two cone semi-angles sum to
    /// less than this many degrees (the paper: 30).
    pub cone_angle_deg: f64,
    /// Heuristic mode: the deepest 4-way split (a sub-triangle at depth `k`
    /// has `4^-k` of the area).
    pub max_depth: u32,
    /// Heuristic mode: start Newton only where the paper does (the centroid
    /// of each final sub-triangle, or, if `‖f‖ > 1` there, the best of the
    /// centroid, its corners and the projection of `V` along the mean
    /// normal). When `false` (the default), Newton runs from the centroid,
    /// the corners and the edge midpoints of every final sub-triangle, once
    /// from the projection of `V` and once from the root the triangle would
    /// have if it were flat [Walter09 sec 3.2], and duplicates are merged.
    pub paper_starts: bool,
    /// Guaranteed mode: boxes narrower than this (in barycentric units) that
    /// are still unresolved fall back to uncertified Newton.
    pub min_box_width: f64,
    /// Guaranteed mode: give up splitting after this many boxes (the rest
    /// fall back to uncertified Newton). Never reached in the tests.
    pub max_boxes: usize,
}

impl Options {
    /// The defaults for `mode`: 30° cones, depth 10, extended start points,
    /// boxes down to 1e-10, at most 200 000 boxes.
    pub fn new(mode: Mode) -> Options {
        Options {
            mode,
            cone_angle_deg: 30.0,
            max_depth: 10,
            paper_starts: false,
            min_box_width: 1e-10,
            max_boxes: 200_000,
        }
    }
}

/// One refracted path `L → P → V` through the triangle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Solution {
    /// Barycentric coordinates `(u, v)` of `P`.
    pub uv: DVec2,
    /// The refraction point `P`.
    pub point: DVec3,
    /// The unit shading normal `N̂_s(P)` (outward).
    pub normal: DVec3,
    /// The unit geometric normal `N̂_g` (outward).
    pub geometric_normal: DVec3,
    /// `ω̂_V`, unit direction from `P` to `V` [Walter09 eq 1]; the direction
    /// light travels inside the medium.
    pub omega_v: DVec3,
    /// `ω̂_L`, unit direction from `P` to `L` [Walter09 eq 2].
    pub omega_l: DVec3,
    /// `d_V = ‖V − P‖` [Walter09 eq 19].
    pub d_v: f64,
    /// `d_L = ‖L − P‖` [Walter09 eq 20].
    pub d_l: f64,
    /// `‖Ĥ + σ N̂_s‖` at the solution ([Walter09 eq 8]; for flat triangles the
    /// same quantity with `N̂_s = N̂_g`).
    pub residual: f64,
    /// Newton iterations used by the run that produced it.
    pub iterations: u32,
    /// Whether uniqueness in an enclosing region was proven: always for flat
    /// triangles ([Walter09 eq 5] is strictly monotonic) and for
    /// Krawczyk-certified boxes; never in heuristic mode.
    pub certified: bool,
}

/// Work counters of one [`solve_with`] call.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Stats {
    /// Sub-triangles (heuristic) or boxes (guaranteed) examined.
    pub regions: usize,
    /// Regions discarded: cone test (heuristic) or [Walter09 eq 12 or 13].
    pub pruned: usize,
    /// Guaranteed mode: boxes proven to hold at most one solution
    /// [Walter09 eqs 14-15].
    pub certified: usize,
    /// Guaranteed mode: boxes that reached the size or count limit
    /// unresolved.
    pub unresolved: usize,
    /// Newton runs started.
    pub newton_runs: usize,
    /// Newton iterations over all runs.
    pub newton_iterations: usize,
}

/// All refracted paths from `L` (outside) to `V` (inside) through `tri` for
/// relative index `eta = η_in/η_out > 0`, with the paper's default settings
/// for `mode`. See [`solve_with`].
pub fn solve(tri: &Triangle, v: DVec3, l: DVec3, eta: f64, mode: Mode) -> Vec<Solution> {
    solve_with(tri, v, l, eta, &Options::new(mode)).0
}

/// All refracted paths from `L` to `V` through `tri`, sorted by `(u, v)`,
/// with work counters.
///
/// Returns nothing if `V` and `L` are not strictly on the inner and outer
/// sides of the triangle's plane [Walter09 eq 4], if `eta` is not finite and
/// positive, or if the triangle is degenerate. For `eta == 1` the only path
/// is the straight segment, reported if it crosses the triangle.
pub fn solve_with(
    tri: &Triangle,
    v: DVec3,
    l: DVec3,
    eta: f64,
    opts: &Options,
) -> (Vec<Solution>, Stats) {
    let mut stats = Stats::default();
    let ng = tri.geometric_normal();
    let valid = eta.is_finite() && eta > 0.0 && ng.is_finite();
    if !valid {
        return (Vec::new(), stats);
    }
    // Sidedness of [Walter09 eq 4] against the triangle's plane.
    let plane = ng.dot(tri.p[0]);
    if !(v.dot(ng) < plane && plane < l.dot(ng)) {
        return (Vec::new(), stats);
    }
    if eta == 1.0 || tri.is_flat() {
        // For eta = 1 the 1-D method returns the straight-line crossing.
        let sol = newton::solve_flat(tri, v, l, eta, &mut stats);
        return (sol.into_iter().collect(), stats);
    }
    let mut sols = match opts.mode {
        Mode::Heuristic => search::heuristic(tri, v, l, eta, opts, &mut stats),
        Mode::Guaranteed => search::guaranteed(tri, v, l, eta, opts, &mut stats),
    };
    sols.sort_by(|a, b| a.uv.x.total_cmp(&b.uv.x).then(a.uv.y.total_cmp(&b.uv.y)));
    (sols, stats)
}

/// Builds a [`Solution`] at `uv` if it is a physical refraction point on the
/// triangle (see the module conventions), else `None`.
pub(crate) fn finish(
    tri: &Triangle,
    v: DVec3,
    l: DVec3,
    eta: f64,
    uv: DVec2,
    iterations: u32,
    certified: bool,
) -> Option<Solution> {
    if !Triangle::contains(uv) {
        return None;
    }
    let point = tri.point(uv);
    let normal = tri.shading_normal(uv);
    let ng = tri.geometric_normal();
    let (a, b) = (v - point, l - point);
    let (d_v, d_l) = (a.length(), b.length());
    let (omega_v, omega_l) = (a / d_v, b / d_l);
    if !(omega_l.dot(normal) > 0.0 && omega_v.dot(normal) < 0.0) {
        return None;
    }
    let sigma = if eta > 1.0 { 1.0 } else { -1.0 };
    let h = (eta * omega_v + omega_l).normalize();
    let residual = if eta == 1.0 {
        0.0
    } else {
        (h + sigma * normal).length()
    };
    Some(Solution {
        uv,
        point,
        normal,
        geometric_normal: ng,
        omega_v,
        omega_l,
        d_v,
        d_l,
        residual,
        iterations,
        certified,
    })
}

/// Removes solutions closer than `tol` in barycentric coordinates to an
/// earlier one, preferring certified ones.
pub(crate) fn dedup(mut sols: Vec<Solution>, tol: f64) -> Vec<Solution> {
    sols.sort_by_key(|s| !s.certified);
    let mut out: Vec<Solution> = Vec::with_capacity(sols.len());
    for s in sols {
        if out.iter().all(|o| (o.uv - s.uv).length() > tol) {
            out.push(s);
        }
    }
    out
}

/// The [`Triangle`]s of a mesh, in its triangle order (outward vertex
/// normals as stored in the mesh).
pub fn mesh_triangles(mesh: &eikon_mesh::Mesh) -> Vec<Triangle> {
    let (p, n) = (mesh.positions(), mesh.normals());
    mesh.triangles()
        .iter()
        .map(|t| {
            let i = t.map(|k| k as usize);
            Triangle::new([p[i[0]], p[i[1]], p[i[2]]], [n[i[0]], n[i[1]], n[i[2]]])
        })
        .collect()
}

/// All refracted paths from `l` to `v` through the triangles of `tree`
/// that survive its pruning [Walter09 sec 3.4], as
/// `(triangle index, solution)`, in triangle order. `scratch` is reused for the
/// candidate list.
pub fn solve_mesh(
    tree: &PnTree,
    v: DVec3,
    l: DVec3,
    eta: f64,
    opts: &Options,
    scratch: &mut Vec<u32>,
) -> (Vec<(u32, Solution)>, TreeStats) {
    scratch.clear();
    let stats = tree.query_point(v, l, eta, scratch);
    scratch.sort_unstable();
    let mut out = Vec::new();
    for &t in scratch.iter() {
        for s in solve_with(&tree.triangles()[t as usize], v, l, eta, opts).0 {
            out.push((t, s));
        }
    }
    (out, stats)
}
