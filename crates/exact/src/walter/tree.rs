//! The position-normal tree of [Walter09 sec 3.4], and the pruning tests
//! that walk it: the spindle test [Walter09 eq 16], the sidedness test and
//! the cone-overlap test on the generalized half-vector. The same tree serves
//! Holzschuch 2015's segment queries [Holzschuch15 sec 3.2.4]: a sweeping cone
//! for `ω̂_V` over the refracted camera segment, bounding spheres for the
//! nodes.
//!
//! Each node bounds the positions of its triangles (an axis-aligned box and
//! the sphere around it) and every normal that can occur on them (a cone
//! holding the geometric normals and the vertex normals; normalized
//! interpolations of vertex normals stay inside a cone of semi-angle below
//! 90°, which is convex, and a wider cone is treated as "any direction").
//!
//! The tree is built bottom-up: the triangles are ordered along a Morton
//! curve of their centroids, then clusters that are each other's best
//! partner (smallest merged bounding sphere) within a window of that order
//! are merged, pass after pass, until one root is left.
//!
//! All tests are conservative: a node is pruned only when no triangle below
//! it can hold a refracted path (checked against brute force in the tests).

use super::Triangle;
use glam::DVec3;
use std::f64::consts::{FRAC_PI_2, PI};

/// A cone of directions `{x : ∠(x, axis) <= angle}`; `angle >= π` is the
/// whole sphere.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NormalCone {
    /// Unit axis.
    pub axis: DVec3,
    /// Semi-angle in radians.
    pub angle: f64,
}

fn angle_between(a: DVec3, b: DVec3) -> f64 {
    // atan2 form: accurate for small and large angles.
    a.cross(b).length().atan2(a.dot(b))
}

impl NormalCone {
    /// The smallest cone (about the normalized mean) holding `dirs` (unit).
    fn of_units(dirs: &[DVec3]) -> NormalCone {
        let axis = dirs.iter().copied().sum::<DVec3>().normalize_or_zero();
        if axis == DVec3::ZERO {
            return NormalCone {
                axis: DVec3::Z,
                angle: PI,
            };
        }
        let angle = dirs
            .iter()
            .map(|&d| angle_between(axis, d))
            .fold(0.0, f64::max);
        NormalCone { axis, angle }
    }

    /// The smallest cone holding both.
    fn union(self, o: NormalCone) -> NormalCone {
        if self.angle >= PI || o.angle >= PI {
            return NormalCone {
                axis: self.axis,
                angle: PI,
            };
        }
        let phi = angle_between(self.axis, o.axis);
        if phi + o.angle <= self.angle {
            return self;
        }
        if phi + self.angle <= o.angle {
            return o;
        }
        let angle = 0.5 * (phi + self.angle + o.angle);
        if angle >= PI || phi >= PI - 1e-12 {
            return NormalCone {
                axis: self.axis,
                angle: PI,
            };
        }
        // Rotate self.axis towards o.axis by (angle - self.angle).
        let rot = angle - self.angle;
        let perp = (o.axis - self.axis * self.axis.dot(o.axis)).normalize_or_zero();
        let axis = (self.axis * rot.cos() + perp * rot.sin()).normalize();
        NormalCone {
            axis,
            // A little slack for rounding in the rotation.
            angle: angle + 1e-12,
        }
    }

    /// Whether this cone is bounded enough to be convex (semi-angle < 90°).
    fn is_convex(&self) -> bool {
        self.angle < FRAC_PI_2
    }
}

/// One node: bounds and either two children or a triangle.
#[derive(Debug, Clone, Copy)]
struct Node {
    lo: DVec3,
    hi: DVec3,
    center: DVec3,
    radius: f64,
    cone: NormalCone,
    /// `cos` and `sin` of the cone's semi-angle (for trig-free tests).
    cone_cos: f64,
    cone_sin: f64,
    /// Leaf: the triangle index; interior: `u32::MAX`.
    triangle: u32,
    /// Interior: children indices.
    children: [u32; 2],
}

/// What a query did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TreeStats {
    /// Nodes visited (tested).
    pub visited: usize,
    /// Nodes pruned by the spindle test ([Walter09 eq 16], or Holzschuch's
    /// sphere variant for segments).
    pub spindle: usize,
    /// Nodes pruned by the sidedness test.
    pub sidedness: usize,
    /// Nodes pruned by the half-vector cone-overlap test.
    pub cone: usize,
    /// Triangles returned.
    pub candidates: usize,
}

impl std::ops::AddAssign for TreeStats {
    fn add_assign(&mut self, o: TreeStats) {
        self.visited += o.visited;
        self.spindle += o.spindle;
        self.sidedness += o.sidedness;
        self.cone += o.cone;
        self.candidates += o.candidates;
    }
}

/// The position-normal tree over a set of [`Triangle`]s [Walter09 sec 3.4].
#[derive(Debug, Clone)]
pub struct PnTree {
    nodes: Vec<Node>,
    root: u32,
    triangles: Vec<Triangle>,
}

/// Interleaves the low 21 bits of `x` with two zero bits between each.
fn spread(mut x: u64) -> u64 {
    x &= 0x1f_ffff;
    x = (x | x << 32) & 0x1f_0000_0000_ffff;
    x = (x | x << 16) & 0x1f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    x = (x | x << 2) & 0x1249_2492_4924_9249;
    x
}

impl PnTree {
    /// Builds the tree bottom-up over `triangles`.
    pub fn new(triangles: Vec<Triangle>) -> PnTree {
        let mut nodes: Vec<Node> = Vec::with_capacity(2 * triangles.len());
        if triangles.is_empty() {
            return PnTree {
                nodes,
                root: u32::MAX,
                triangles,
            };
        }
        let (mut glo, mut ghi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for t in &triangles {
            for p in t.p {
                glo = glo.min(p);
                ghi = ghi.max(p);
            }
        }
        let ext = (ghi - glo).max(DVec3::splat(1e-300));
        let mut order: Vec<(u64, u32)> = triangles
            .iter()
            .enumerate()
            .map(|(i, t)| {
                let c = (t.p[0] + t.p[1] + t.p[2]) / 3.0;
                let q =
                    ((c - glo) / ext * 2_097_151.0).clamp(DVec3::ZERO, DVec3::splat(2_097_151.0));
                let code = spread(q.x as u64) | spread(q.y as u64) << 1 | spread(q.z as u64) << 2;
                (code, i as u32)
            })
            .collect();
        order.sort_unstable();
        let mut level: Vec<u32> = Vec::with_capacity(order.len());
        for &(_, i) in &order {
            let t = &triangles[i as usize];
            let lo = t.p[0].min(t.p[1]).min(t.p[2]);
            let hi = t.p[0].max(t.p[1]).max(t.p[2]);
            let ng = t.geometric_normal();
            let ns = t.n.map(|n| n.normalize_or_zero());
            let cone = if ng.is_finite() && ns.iter().all(|n| *n != DVec3::ZERO) {
                NormalCone::of_units(&[ng, ns[0], ns[1], ns[2]])
            } else {
                NormalCone {
                    axis: DVec3::Z,
                    angle: PI,
                }
            };
            let (center, radius) = triangle_sphere(t.p);
            level.push(nodes.len() as u32);
            nodes.push(Node {
                lo,
                hi,
                center,
                radius,
                cone,
                cone_cos: cone.angle.cos(),
                cone_sin: cone.angle.sin(),
                triangle: i,
                children: [u32::MAX; 2],
            });
        }
        // Locally-ordered agglomerative clustering (Meister and Bittner
        // 2018) along the Morton order: each cluster picks, among the
        // `WINDOW` clusters on either side, the one whose merge has the
        // smallest bounding sphere; mutual picks are merged, in place, and
        // the pass repeats until one root is left. Ties go to the lower
        // index, so the build is deterministic.
        const WINDOW: usize = 8;
        let mut best: Vec<usize> = Vec::with_capacity(level.len());
        while level.len() > 1 {
            best.clear();
            for i in 0..level.len() {
                let (lo, hi) = (i.saturating_sub(WINDOW), (i + WINDOW).min(level.len() - 1));
                let mut pick = (f64::INFINITY, usize::MAX);
                for j in (lo..=hi).filter(|&j| j != i) {
                    let (a, b) = (&nodes[level[i] as usize], &nodes[level[j] as usize]);
                    let cost = merged_sphere(a, b).1;
                    if cost < pick.0 {
                        pick = (cost, j);
                    }
                }
                best.push(pick.1);
            }
            let mut next = Vec::with_capacity(level.len());
            let mut merged = false;
            for i in 0..level.len() {
                let j = best[i];
                if j != usize::MAX && best[j] == i {
                    if i < j {
                        next.push(push_parent(&mut nodes, level[i], level[j]));
                        merged = true;
                    }
                } else {
                    next.push(level[i]);
                }
            }
            if !merged {
                // Cannot happen with finite costs (the cheapest pair is
                // mutual); a fallback so the build always ends.
                next.clear();
                next.push(push_parent(&mut nodes, level[0], level[1]));
                next.extend_from_slice(&level[2..]);
            }
            level = next;
        }
        PnTree {
            root: level[0],
            nodes,
            triangles,
        }
    }

    /// The triangles, indexed as in the query results.
    pub fn triangles(&self) -> &[Triangle] {
        &self.triangles
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Appends to `out` every triangle that may hold a refracted path from
    /// `l` (outside) to `v` (inside) for relative index `eta`, pruning with
    /// the spindle [Walter09 eq 16], sidedness and cone-overlap tests of
    /// [Walter09 sec 3.4].
    pub fn query_point(&self, v: DVec3, l: DVec3, eta: f64, out: &mut Vec<u32>) -> TreeStats {
        let mut stats = TreeStats::default();
        if self.root == u32::MAX || !(eta > 0.0 && eta.is_finite()) {
            return stats;
        }
        let mid = 0.5 * (v + l);
        let dist_vl = (l - v).length();
        let axis = (l - v) / dist_vl;
        // The exact spindle: the deviation `θ_L − θ_V` of a refraction is at
        // most `γ = π/2 − asin(1/η)`, so the angle V P L is at least
        // `π − γ`; by the inscribed-angle theorem `P` lies in the lens
        // `|P − M|² + |LV| cot(γ) r <= |LV|²/4`, `cot γ = 1/sqrt(η² − 1)`
        // ([Walter09 eq 16] uses the smaller, looser `1/η`).
        let spindle_k = if eta > 1.0 {
            dist_vl / (eta * eta - 1.0).sqrt()
        } else {
            0.0
        };
        let spindle_r2 = 0.25 * dist_vl * dist_vl * (1.0 + 1e-9);
        // The critical angle: inside the denser medium a refracted
        // direction is within `asin(1/η)` of the inward normal (`ω̂_V` of
        // `−N̂_s` for `η > 1`; `ω̂_L` of `N̂_s` for `η < 1`).
        let critical = if eta > 1.0 {
            (1.0 / eta).asin()
        } else {
            eta.asin()
        } + 1e-9;
        // Its cosine and sine, so that the per-node test below needs no
        // trigonometric function.
        let (crit_sin, crit_cos) = critical.sin_cos();
        let mut stack = Vec::with_capacity(64);
        stack.push(self.root);
        while let Some(i) = stack.pop() {
            let n = &self.nodes[i as usize];
            stats.visited += 1;
            // Spindle test: a lower bound of |P − M|² over the box plus
            // |LV| cot γ times a lower bound of the distance to line VL.
            if eta > 1.0 && dist_vl > 0.0 {
                let d_box = (mid.clamp(n.lo, n.hi) - mid).length_squared();
                let w = n.center - v;
                let r_line = (w - axis * w.dot(axis)).length();
                let r_min = (r_line - n.radius).max(0.0);
                if d_box + spindle_k * r_min > spindle_r2 {
                    stats.spindle += 1;
                    continue;
                }
            }
            // Critical angle, then sidedness (both about the normal cone).
            if eta != 1.0 && n.cone.is_convex() {
                let (x, toward) = if eta > 1.0 {
                    (v, -n.cone.axis)
                } else {
                    (l, n.cone.axis)
                };
                let w = x - n.center;
                let d = w.length();
                if d > n.radius * (1.0 + 1e-9) {
                    let cos_a = (w.dot(toward) / d).clamp(-1.0, 1.0);
                    // spread = asin(r/d) + θ_N + critical, by the addition
                    // formulas: the first two terms are each below π/2,
                    // so the sum is in [0, 3π/2) and below π exactly when
                    // its sine is positive.
                    let s1 = n.radius / d;
                    let c1 = (1.0 - s1 * s1).max(0.0).sqrt();
                    let c12 = c1 * n.cone_cos - s1 * n.cone_sin;
                    let s12 = s1 * n.cone_cos + c1 * n.cone_sin;
                    let cos_spread = c12 * crit_cos - s12 * crit_sin;
                    let sin_spread = s12 * crit_cos + c12 * crit_sin;
                    if sin_spread > 0.0 && cos_a < cos_spread - 1e-12 {
                        stats.sidedness += 1;
                        continue;
                    }
                }
            }
            if !sided(n, l, 1.0) || !sided(n, v, -1.0) {
                stats.sidedness += 1;
                continue;
            }
            if !half_vector_overlaps_point(n, v, l, eta) {
                stats.cone += 1;
                continue;
            }
            self.descend(n, &mut stack, out, &mut stats);
        }
        stats
    }

    /// Appends to `out` every triangle that may hold a refracted path from
    /// `l` to some point of the segment `[a, b]` ([Holzschuch15 sec 3.2.4]):
    /// the bounding-sphere spindle test with a sweeping cone for `ω̂_V`,
    /// sidedness at both ends, and the half-vector cone test.
    pub fn query_segment(
        &self,
        a: DVec3,
        b: DVec3,
        l: DVec3,
        eta: f64,
        out: &mut Vec<u32>,
    ) -> TreeStats {
        let mut stats = TreeStats::default();
        if self.root == u32::MAX || !(eta > 0.0 && eta.is_finite()) {
            return stats;
        }
        let mut stack = vec![self.root];
        while let Some(i) = stack.pop() {
            let n = &self.nodes[i as usize];
            stats.visited += 1;
            let lc = direction_cone(n, l);
            let vc = sweep_cone(n, a, b);
            // Geometry test: the angle between ω̂_V and −ω̂_L is at most
            // π/2 − asin(1/η).
            if eta > 1.0 {
                if let (Some(lc), Some(min_angle)) =
                    (lc, min_angle_to_arc(n, -(l - n.center), a, b))
                {
                    let theta_v = seg_theta(n, a, b);
                    if let Some(theta_v) = theta_v {
                        let limit = FRAC_PI_2 - (1.0 / eta).asin() + theta_v + lc.angle;
                        if min_angle > limit + 1e-12 {
                            stats.spindle += 1;
                            continue;
                        }
                    }
                }
            }
            if !sided(n, l, 1.0) || (!sided(n, a, -1.0) && !sided(n, b, -1.0)) {
                stats.sidedness += 1;
                continue;
            }
            if !half_vector_overlaps(n, vc, lc, eta) {
                stats.cone += 1;
                continue;
            }
            self.descend(n, &mut stack, out, &mut stats);
        }
        stats
    }

    fn descend(&self, n: &Node, stack: &mut Vec<u32>, out: &mut Vec<u32>, stats: &mut TreeStats) {
        if n.triangle != u32::MAX {
            out.push(n.triangle);
            stats.candidates += 1;
        } else {
            stack.push(n.children[1]);
            stack.push(n.children[0]);
        }
    }
}

/// The bounding sphere of the parent of `a` and `b`: the smaller of the
/// sphere around their joint box and the sphere around both spheres.
fn merged_sphere(a: &Node, b: &Node) -> (DVec3, f64) {
    let lo = a.lo.min(b.lo);
    let hi = a.hi.max(b.hi);
    let (center, radius) = (0.5 * (lo + hi), 0.5 * (hi - lo).length());
    let (c2, r2) = merge_spheres(a.center, a.radius, b.center, b.radius);
    if r2 < radius {
        (c2, r2)
    } else {
        (center, radius)
    }
}

/// Appends the parent of nodes `a` and `b` and returns its index.
fn push_parent(nodes: &mut Vec<Node>, a: u32, b: u32) -> u32 {
    let (na, nb) = (nodes[a as usize], nodes[b as usize]);
    let (center, radius) = merged_sphere(&na, &nb);
    let cone = na.cone.union(nb.cone);
    nodes.push(Node {
        lo: na.lo.min(nb.lo),
        hi: na.hi.max(nb.hi),
        center,
        radius,
        cone,
        cone_cos: cone.angle.cos(),
        cone_sin: cone.angle.sin(),
        triangle: u32::MAX,
        children: [a, b],
    });
    (nodes.len() - 1) as u32
}

/// The smallest sphere holding the triangle's corners (the circumsphere of
/// an acute triangle, else the sphere on its longest edge), padded for
/// rounding; every point of the triangle is inside since the ball is convex.
fn triangle_sphere(p: [DVec3; 3]) -> (DVec3, f64) {
    let pad = |c: DVec3, r: f64| {
        let r = p.iter().map(|&q| (q - c).length()).fold(r, f64::max);
        (c, r * (1.0 + 1e-12) + 1e-300)
    };
    // Longest edge opposite vertex k.
    let e = [
        (p[1] - p[2]).length_squared(),
        (p[2] - p[0]).length_squared(),
        (p[0] - p[1]).length_squared(),
    ];
    let k = if e[0] >= e[1] && e[0] >= e[2] {
        0
    } else if e[1] >= e[2] {
        1
    } else {
        2
    };
    let (a, b) = (p[(k + 1) % 3], p[(k + 2) % 3]);
    let c = 0.5 * (a + b);
    let r = 0.5 * (b - a).length();
    if (p[k] - c).length() <= r {
        return pad(c, r);
    }
    // Circumcentre of the acute triangle.
    let (u, w) = (p[1] - p[0], p[2] - p[0]);
    let n = u.cross(w);
    let n2 = n.length_squared();
    let cc =
        p[0] + (w.length_squared() * n.cross(u) + u.length_squared() * w.cross(n)) / (2.0 * n2);
    if n2.is_nan() || n2 <= 0.0 || !cc.is_finite() {
        let lo = p[0].min(p[1]).min(p[2]);
        let hi = p[0].max(p[1]).max(p[2]);
        return pad(0.5 * (lo + hi), 0.5 * (hi - lo).length());
    }
    pad(cc, 0.0)
}

/// The smallest sphere holding two spheres, padded for rounding.
fn merge_spheres(c1: DVec3, r1: f64, c2: DVec3, r2: f64) -> (DVec3, f64) {
    let d = (c2 - c1).length();
    if d + r2 <= r1 {
        return (c1, r1);
    }
    if d + r1 <= r2 {
        return (c2, r2);
    }
    let r = 0.5 * (d + r1 + r2);
    let c = c1 + (c2 - c1) * ((r - r1) / d);
    // Check both spheres are inside despite rounding.
    let r = r.max((c - c1).length() + r1).max((c - c2).length() + r2);
    (c, r * (1.0 + 1e-12))
}

/// Sidedness: whether some point `P` of the node's sphere and some normal
/// `n` of its cone have `sign · (x − P)·n > 0` (`sign = 1`: `x` in front,
/// as the light must be; `−1`: behind, as the scatter point must be).
fn sided(n: &Node, x: DVec3, sign: f64) -> bool {
    if n.cone.angle >= FRAC_PI_2 {
        // Bound by |x − C| + r only: prune nothing but the trivial.
        return true;
    }
    let w = sign * (x - n.center);
    let len = w.length();
    if len <= n.radius {
        return true;
    }
    // With α = ∠(w, axis): if α <= θ the bound is len + r > 0; else
    // len cos(α − θ) = (w·a) cos θ + |w × a| sin θ.
    let wa = w.dot(n.cone.axis);
    if wa >= len * n.cone_cos {
        return true;
    }
    let wx = w.cross(n.cone.axis).length();
    wa * n.cone_cos + wx * n.cone_sin + n.radius > -1e-12 * (len + n.radius)
}

/// The cone of directions from the node's sphere towards `x`:
/// axis `(x − C)/|x − C|`, semi-angle `asin(r/|x − C|)`. `None` when `x`
/// is inside the sphere.
fn direction_cone(n: &Node, x: DVec3) -> Option<NormalCone> {
    let w = x - n.center;
    let d = w.length();
    (d > n.radius * (1.0 + 1e-9)).then(|| NormalCone {
        axis: w / d,
        angle: (n.radius / d).asin(),
    })
}

/// Distance from the node's centre to the segment `[a, b]`.
fn segment_distance(c: DVec3, a: DVec3, b: DVec3) -> f64 {
    let ab = b - a;
    let len2 = ab.length_squared();
    let t = if len2 > 0.0 {
        ((c - a).dot(ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (a + t * ab - c).length()
}

/// Holzschuch's `θ_V = asin(r/d_min)`, `None` when the segment meets the
/// sphere.
fn seg_theta(n: &Node, a: DVec3, b: DVec3) -> Option<f64> {
    let d = segment_distance(n.center, a, b);
    (d > n.radius * (1.0 + 1e-9)).then(|| (n.radius / d).asin())
}

/// A cone holding `ω̂_V` for every `V` in `[a, b]` and `P` in the node's
/// sphere: the arc of axes from `u_Vmin` to `u_Vmax` widened by `θ_V`.
fn sweep_cone(n: &Node, a: DVec3, b: DVec3) -> Option<NormalCone> {
    let theta_v = seg_theta(n, a, b)?;
    let ua = (a - n.center).normalize();
    let ub = (b - n.center).normalize();
    let arc = angle_between(ua, ub);
    let axis = (ua + ub).normalize_or_zero();
    if axis == DVec3::ZERO {
        return None;
    }
    let angle = 0.5 * arc + theta_v;
    (angle < PI).then_some(NormalCone { axis, angle })
}

/// Minimum angle between `w` and the directions `(V − C)` for `V` in
/// `[a, b]` (an arc of a great circle). `None` if undefined.
fn min_angle_to_arc(n: &Node, w: DVec3, a: DVec3, b: DVec3) -> Option<f64> {
    let w = w.normalize_or_zero();
    let ua = (a - n.center).normalize_or_zero();
    let ub = (b - n.center).normalize_or_zero();
    if w == DVec3::ZERO || ua == DVec3::ZERO || ub == DVec3::ZERO {
        return None;
    }
    let ends = angle_between(w, ua).min(angle_between(w, ub));
    let normal = ua.cross(ub);
    if normal.length() < 1e-12 {
        return Some(ends);
    }
    let normal = normal.normalize();
    let wp = (w - normal * w.dot(normal)).normalize_or_zero();
    if wp == DVec3::ZERO {
        return Some(ends);
    }
    // Is wp between ua and ub on the short arc?
    let inside = ua.cross(wp).dot(normal) >= 0.0 && wp.cross(ub).dot(normal) >= 0.0;
    if inside {
        Some(angle_between(w, wp).min(ends))
    } else {
        Some(ends)
    }
}

/// [`half_vector_overlaps`] for the direction cones from the node's sphere
/// towards the points `v` and `l`, without trigonometric functions: the
/// chord `2 sin(φ/2)` of a cone with `sin φ = r/d` is
/// `sqrt(2 (1 − cos φ))`, `1 − cos φ = sin²φ / (1 + cos φ)`, and the angle
/// comparison `∠(a, −σH) <= θ_N + θ_H` is made on cosines (the sum is below
/// π since both cones are convex).
fn half_vector_overlaps_point(n: &Node, v: DVec3, l: DVec3, eta: f64) -> bool {
    if !n.cone.is_convex() || eta == 1.0 {
        return true;
    }
    let (wv, wl) = (v - n.center, l - n.center);
    let (dv, dl) = (wv.length(), wl.length());
    let lim = n.radius * (1.0 + 1e-9);
    if !(dv > lim && dl > lim) {
        return true;
    }
    let chord = |d: f64| {
        let s = n.radius / d;
        let c = (1.0 - s * s).max(0.0).sqrt();
        (2.0 * s * s / (1.0 + c)).sqrt()
    };
    let center = eta * (wv / dv) + wl / dl;
    let rad = eta * chord(dv) + chord(dl);
    let len = center.length();
    if len <= rad * (1.0 + 1e-9) {
        return true;
    }
    let sh = rad / len;
    let ch = (1.0 - sh * sh).max(0.0).sqrt();
    let cos_beta = n.cone_cos * ch - n.cone_sin * sh;
    let sigma = if eta > 1.0 { 1.0 } else { -1.0 };
    let cos_a = n.cone.axis.dot(-sigma * center) / len;
    cos_a >= cos_beta - 1e-9
}

/// Cone-overlap test: a solution has `N̂_s = −σ Ĥ` (`σ = sign(η − 1)`), so
/// the node's normal cone must meet the cone bounding `−σ Ĥ`, where
/// `H = η ω̂_V + ω̂_L` lies in a ball around `η u_V + u_L` of radius
/// `η r_V + r_L` (`r = 2 sin(θ/2)`, chord of each cone).
fn half_vector_overlaps(
    n: &Node,
    vc: Option<NormalCone>,
    lc: Option<NormalCone>,
    eta: f64,
) -> bool {
    if !n.cone.is_convex() || eta == 1.0 {
        return true;
    }
    let (Some(vc), Some(lc)) = (vc, lc) else {
        return true;
    };
    let center = eta * vc.axis + lc.axis;
    let rad = eta * 2.0 * (0.5 * vc.angle.min(PI)).sin() + 2.0 * (0.5 * lc.angle.min(PI)).sin();
    let len = center.length();
    if len <= rad * (1.0 + 1e-9) {
        return true;
    }
    let theta_h = (rad / len).asin();
    let sigma = if eta > 1.0 { 1.0 } else { -1.0 };
    angle_between(n.cone.axis, -sigma * center) <= n.cone.angle + theta_h + 1e-9
}
