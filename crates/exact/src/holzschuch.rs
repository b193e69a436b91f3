//! Per-triangle integration of single scattering along a refracted camera
//! segment, after Holzschuch 2015, "Accurate computation of single
//! scattering in participating media with refractive boundaries"
//! [Holzschuch15 sec 3.2].
//!
//! Along the segment `V(t) = A + t ĉ`, `t ∈ [0, len]` [Holzschuch15 eq 13], the
//! points `P` of one triangle's plane that connect `V(t)` to the light by
//! Snell's law form a curve `f(t, a, b) = 0`. The contribution of one triangle
//! is smooth in `t` except where that curve crosses the triangle's edges, so
//! the integral is split at the edge crossings and each piece is sampled
//! regularly [Holzschuch15 eq 18] and summed with weight `(t_max − t_min)/K`
//! [Holzschuch15 eq 19].
//!
//! # How the edge crossings are found
//!
//! The paper runs Newton on `f` restricted to each edge with a 3×2
//! pseudo-inverse [Holzschuch15 eqs 14-15] and classifies each crossing as an
//! upper or lower bound from the curve's tangent [Holzschuch15 eqs 16-17]. Here
//! the crossing on an edge is found as a root in the edge parameter `s`
//! instead: for a fixed `P(s)` on the edge the light's refracted direction
//! `d(s)` inside is fixed (Snell at the interpolated shading normal), and
//! `P(s)` lies on the curve exactly when the ray `P(s) + u d(s)` meets the
//! camera line. The signed distance between the two lines,
//! `(P(s) − A)·(d(s) × ĉ)`, is scanned at [`EDGE_SCAN`] points and bracketed
//! roots are refined by bisection, which needs no start values and cannot
//! wander off the edge. Instead of the tangent test, each piece between
//! consecutive crossings is kept or skipped by solving at its midpoint (the
//! paper's `K = 1` sample is that same solve), so a curve entering and leaving
//! through the same edge needs no second loop.
//!
//! The camera segment's crossing of the triangle's plane is a breakpoint
//! too (on the far side `V` cannot scatter light through the triangle).

use crate::walter::{self, Mode, Solution, Triangle};
use glam::DVec3;

/// Points per edge at which the line distance is scanned for sign changes.
pub const EDGE_SCAN: usize = 16;

/// Work counters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    /// Edge crossings found.
    pub crossings: usize,
    /// Pieces (between breakpoints) examined.
    pub pieces: usize,
    /// Pieces with a path at their midpoint.
    pub live_pieces: usize,
    /// Solver calls.
    pub solves: usize,
}

impl std::ops::AddAssign for Counters {
    fn add_assign(&mut self, o: Counters) {
        self.crossings += o.crossings;
        self.pieces += o.pieces;
        self.live_pieces += o.live_pieces;
        self.solves += o.solves;
    }
}

/// The refracted direction inside of light from `l` hitting `p` with
/// outward shading normal `n`, or `None` if the light is behind.
fn refracted_inside(p: DVec3, n: DVec3, l: DVec3, eta: f64) -> Option<DVec3> {
    let wl = (l - p).normalize();
    if wl.dot(n) <= 0.0 {
        return None;
    }
    eikon_optics::fresnel::refract(-wl, n, 1.0, eta)
}

/// Parameters `(t, u)` of the closest approach between the camera line
/// `a + t c` and the light's ray `p + u d`, and their distance.
fn closest(a: DVec3, c: DVec3, p: DVec3, d: DVec3) -> Option<(f64, f64, f64)> {
    let w = a - p;
    let b = c.dot(d);
    let den = 1.0 - b * b;
    if den < 1e-14 {
        return None;
    }
    let (dc, dd) = (c.dot(w), d.dot(w));
    let t = (b * dd - dc) / den;
    let u = (dd - b * dc) / den;
    let gap = (a + t * c - (p + u * d)).length();
    Some((t, u, gap))
}

/// The `t` in `[0, len]` where the curve `f = 0` of `tri` crosses its
/// edges, for the camera segment `a + t c` (unit `c`) and the light `l`.
pub fn edge_crossings(
    tri: &Triangle,
    a: DVec3,
    c: DVec3,
    len: f64,
    l: DVec3,
    eta: f64,
) -> Vec<f64> {
    let mut out = Vec::new();
    let scale = (tri.p[1] - tri.p[0])
        .length()
        .max((tri.p[2] - tri.p[0]).length())
        .max(len);
    for e in 0..3 {
        let (i, j) = (e, (e + 1) % 3);
        let at = |s: f64| -> Option<(DVec3, DVec3)> {
            let p = tri.p[i].lerp(tri.p[j], s);
            let n = tri.n[i].lerp(tri.n[j], s).normalize_or_zero();
            let d = refracted_inside(p, n, l, eta)?;
            Some((p, d))
        };
        let g = |s: f64| at(s).map(|(p, d)| (p - a).dot(d.cross(c)));
        let mut prev: Option<(f64, f64)> = None;
        for k in 0..=EDGE_SCAN {
            let s = k as f64 / EDGE_SCAN as f64;
            let gs = g(s);
            if let (Some((s0, g0)), Some(g1)) = (prev, gs) {
                if (g0 <= 0.0) != (g1 <= 0.0) {
                    let (mut lo, mut hi, mut glo) = (s0, s, g0);
                    for _ in 0..60 {
                        let m = 0.5 * (lo + hi);
                        match g(m) {
                            Some(gm) if (gm <= 0.0) == (glo <= 0.0) => {
                                lo = m;
                                glo = gm;
                            }
                            Some(_) => hi = m,
                            None => break,
                        }
                    }
                    let s = 0.5 * (lo + hi);
                    if let Some((p, d)) = at(s) {
                        if let Some((t, u, gap)) = closest(a, c, p, d) {
                            if u > 0.0 && gap < 1e-7 * scale && (0.0..=len).contains(&t) {
                                out.push(t);
                            }
                        }
                    }
                }
            }
            prev = gs.map(|g1| (s, g1));
        }
    }
    out
}

/// Integrates one triangle's contribution along the segment `a + t c`,
/// `t ∈ [0, len]`: calls `weigh(t, solution)` for every path at the `k`
/// regular samples [Holzschuch15 eq 18] of every live piece between
/// breakpoints, and returns `Σ (piece length / k) · weigh(…)`
/// [Holzschuch15 eq 19].
#[allow(clippy::too_many_arguments)]
pub fn integrate_triangle<W: std::ops::Add<Output = W> + std::ops::Mul<f64, Output = W> + Copy>(
    tri: &Triangle,
    a: DVec3,
    c: DVec3,
    len: f64,
    l: DVec3,
    eta: f64,
    k: usize,
    mode: Mode,
    zero: W,
    counters: &mut Counters,
    mut weigh: impl FnMut(f64, &Solution) -> W,
) -> W {
    let k = k.max(1);
    let mut cuts = vec![0.0, len];
    let crossings = edge_crossings(tri, a, c, len, l, eta);
    counters.crossings += crossings.len();
    cuts.extend(crossings);
    // The camera line's crossing of the triangle's plane.
    let ng = tri.geometric_normal();
    let den = c.dot(ng);
    if den.abs() > 1e-15 {
        let t = (tri.p[0] - a).dot(ng) / den;
        if t > 0.0 && t < len {
            cuts.push(t);
        }
    }
    cuts.sort_by(f64::total_cmp);
    cuts.dedup_by(|x, y| (*x - *y).abs() <= 1e-12 * len.max(1e-300));
    let mut total = zero;
    for w in cuts.windows(2) {
        let (t0, t1) = (w[0], w[1]);
        if t1 <= t0 {
            continue;
        }
        counters.pieces += 1;
        let mid = 0.5 * (t0 + t1);
        counters.solves += 1;
        let probe = walter::solve(tri, a + mid * c, l, eta, mode);
        if probe.is_empty() {
            continue;
        }
        counters.live_pieces += 1;
        let dt = (t1 - t0) / k as f64;
        for i in 0..k {
            let t = t0 + (i as f64 + 0.5) * dt;
            let sols = if 2 * i + 1 == k {
                probe.clone()
            } else {
                counters.solves += 1;
                walter::solve(tri, a + t * c, l, eta, mode)
            };
            for s in &sols {
                total = total + weigh(t, s) * dt;
            }
        }
    }
    total
}
