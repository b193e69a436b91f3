//! Newton-Raphson iterations: 1-D in the plane of incidence for flat
//! triangles ([Walter09 sec 3.2], [Walter09 eqs 5-7]) and 2-D on barycentric
//! coordinates with the pseudo-inverse for interpolated normals
//! ([Walter09 sec 3.3], [Walter09 eqs 8-10]).

use super::func::Problem;
use super::interval::Interval;
use super::search::certify_root;
use super::{finish, Solution, Stats, Triangle};
use glam::{DVec2, DVec3};

/// Residual `‖f‖` [Walter09 eq 8] below which a 2-D Newton run counts as
/// converged where doubles can resolve it (see [`NewtonOut::converged`]).
/// Simple roots converge to ~1e-16; the slack admits near-double roots at
/// caustics, where convergence is only linear.
pub(crate) const ACCEPT_RESIDUAL: f64 = 1e-10;

/// Safety factor on [`Problem::residual_floor`], a first-order bound that
/// leaves out second-order terms and a Newton iterate a few ulps off the
/// best one. (Measured: where `V` is 1e-6 from the plane, Newton stalls at
/// up to 1e-9, at most 1% of `FLOOR_FACTOR` times the bound; see
/// `nearly_flat_smooth_triangles_find_the_flat_roots`.)
const FLOOR_FACTOR: f64 = 4.0;

/// How far, in barycentric units, a root certified by [`certify_root`] may
/// be from the accepted Newton iterate (as far as `‖f‖ <= ACCEPT_RESIDUAL`
/// allows where `‖J⁺‖ ~ 1`; at the accepted runs it is a few ulps).
const CERTIFY_RADIUS: f64 = 1e-10;

/// The 1-D target of [Walter09 eq 5] and its derivative in the frame of
/// [Walter09 fig 3]: `V = (0, v_y)`, `P = (x, 0)`, `L = (l_x, l_y)`,
/// `N̂ = (0, 1)`.
fn flat_f(x: f64, vy: f64, lx: f64, ly: f64, eta: f64) -> (f64, f64) {
    let rv2 = x * x + vy * vy;
    let dx = lx - x;
    let rl2 = dx * dx + ly * ly;
    let (rv, rl) = (rv2.sqrt(), rl2.sqrt());
    let f = -eta * x / rv + dx / rl;
    // f' = −η v_y²/r_V³ − l_y²/r_L³ < 0: f is strictly decreasing.
    let df = -eta * vy * vy / (rv2 * rv) - ly * ly / (rl2 * rl);
    (f, df)
}

/// The root `x ∈ [0, l_x]` of [Walter09 eq 5] for `v_y < 0 < l_y`, `l_x >= 0`,
/// and the number of Newton steps taken.
///
/// Starts from [Walter09 eq 6], iterates [Walter09 eq 7] and clamps to the
/// bracket `[0, l_x]` as the paper does; since `f(0) >= 0 >= f(l_x)` and `f` is
/// strictly decreasing, the bracket is also narrowed at every step and a step
/// that would leave it is replaced by a secant step through the bracket's ends
/// or by bisection, so the iteration cannot fail.
pub(crate) fn flat_root(vy: f64, lx: f64, ly: f64, eta: f64) -> (f64, u32) {
    if lx <= 0.0 {
        return (0.0, 0);
    }
    // [Walter09 eq 6], the paper's empirical start value.
    let x0 = -vy * lx / (eta * ly - vy) * 4.0 / (3.0 + eta);
    let (mut lo, mut hi) = (0.0, lx);
    // f at the bracket ends, once evaluated there.
    let (mut flo, mut fhi) = (None, None);
    let mut x = x0.clamp(lo, hi);
    let mut iters = 0;
    while iters < 100 {
        let (f, df) = flat_f(x, vy, lx, ly, eta);
        if f > 0.0 {
            (lo, flo) = (x, Some(f));
        } else {
            (hi, fhi) = (x, Some(f));
        }
        // Each term of [Walter09 eq 5] is at most max(η, 1) in size, so a
        // residual at the level of their rounding errors is as good as it gets.
        if f.abs() <= 2.0 * f64::EPSILON * (1.0 + eta) {
            break;
        }
        iters += 1;
        let mut xn = x - f / df; // [Walter09 eq 7]
        let inside = |y: f64| y > lo && y < hi;
        if !inside(xn) {
            // Out of the bracket: the secant through its ends if known and
            // inside, else bisection.
            xn = match (flo, fhi) {
                (Some(a), Some(b)) if inside(lo - a * (hi - lo) / (b - a)) => {
                    lo - a * (hi - lo) / (b - a)
                }
                _ => 0.5 * (lo + hi),
            };
        }
        let step = (xn - x).abs();
        x = xn;
        // Newton's step at the noise level of f is a few ulps of x.
        if step <= 4.0 * f64::EPSILON * x || hi - lo <= 2.0 * f64::EPSILON * hi {
            break;
        }
    }
    (x, iters)
}

/// [Walter09 sec 3.2]: the unique refraction point in the plane of a flat
/// triangle, if it lies on the triangle. `V` and `L` are assumed to be on the
/// inner and outer sides of the plane (checked by the caller).
pub(crate) fn solve_flat(
    tri: &Triangle,
    v: DVec3,
    l: DVec3,
    eta: f64,
    stats: &mut Stats,
) -> Option<Solution> {
    let (uv, iters) = plane_root(tri, v, l, eta);
    stats.newton_runs += 1;
    stats.newton_iterations += iters as usize;
    finish(tri, v, l, eta, uv, iters, true)
}

/// The root of [Walter09 eq 5] in the plane of `tri`, about its geometric
/// normal, in barycentric coordinates (on the triangle or not), and the Newton
/// steps taken. `V` and `L` are on the inner and outer sides of the plane.
pub(crate) fn plane_root(tri: &Triangle, v: DVec3, l: DVec3, eta: f64) -> (DVec2, u32) {
    let ng = tri.geometric_normal();
    let vy = (v - tri.p[0]).dot(ng);
    let ly = (l - tri.p[0]).dot(ng);
    // [Walter09 fig 3] frame: the foot of V is the origin, the x axis runs
    // towards the foot of L, the y axis is the normal.
    let vfoot = v - vy * ng;
    let t = (l - ly * ng) - vfoot;
    let lx = t.length();
    let (x, iters) = flat_root(vy, lx, ly, eta);
    let p = if lx > 0.0 {
        vfoot + (x / lx) * t
    } else {
        vfoot
    };
    (tri.barycentric(p), iters)
}

/// Result of one 2-D Newton run.
#[derive(Debug, Clone, Copy)]
pub(crate) struct NewtonOut {
    pub uv: DVec2,
    /// `‖f‖` at `uv`.
    pub residual: f64,
    pub iterations: u32,
    /// The residual doubles can reach at `uv`: [`FLOOR_FACTOR`] times
    /// [`Problem::residual_floor`].
    pub floor: f64,
}

impl NewtonOut {
    /// Whether the run ended at a root of [Walter09 eq 8] (`pi`: the same
    /// problem in interval arithmetic).
    ///
    /// Where doubles resolve [`ACCEPT_RESIDUAL`] (`floor` below it, the
    /// usual case), the run converged if `‖f‖ <= ACCEPT_RESIDUAL`, as
    /// before. Where they do not, a fixed tolerance is meaningless: with
    /// `V` 1e-6 from the triangle's plane, `ω̂_V` is a 1e-6-long difference
    /// of order-one coordinates and `‖f‖` stalls near 1e-10 at the root, so
    /// nearly flat smooth triangles lost roots the flat solver finds
    /// (issue 17), and a lucky `‖f‖ <= 1e-10` there would prove nothing.
    /// Then the run must reach the noise, `‖f‖ <= floor`, and a root must be
    /// proven to exist within [`CERTIFY_RADIUS`] of `uv` by the interval test
    /// ([`certify_root`], Krawczyk's operator of [Walter09 eq 11] on a square
    /// form of [Walter09 eq 8]): the relaxed tolerance cannot admit a false
    /// root. (A near-double root is not certified; there doubles cannot tell it
    /// from a near miss.)
    pub fn converged(&self, pi: &Problem<Interval>) -> bool {
        if self.floor <= ACCEPT_RESIDUAL {
            self.residual <= ACCEPT_RESIDUAL
        } else {
            self.residual <= self.floor && certify_root(pi, self.uv, CERTIFY_RADIUS)
        }
    }
}

/// The Gauss-Newton step `J⁺ f = (JᵀJ)⁻¹ Jᵀ f` of [Walter09 eq 9] for a 3×2
/// Jacobian with columns `ju`, `jv`; `None` if `JᵀJ` is numerically singular.
pub(crate) fn pinv_apply(ju: DVec3, jv: DVec3, f: DVec3) -> Option<DVec2> {
    pinv(ju, jv).map(|m| DVec2::new(m[0].dot(f), m[1].dot(f)))
}

/// The pseudo-inverse `M⁺ = (MᵀM)⁻¹Mᵀ` (2×3, rows returned) of a 3×2
/// matrix with columns `ju`, `jv`; `None` if `MᵀM` is numerically singular
/// (determinant below 1e-28 of the product of its diagonal).
pub(crate) fn pinv(ju: DVec3, jv: DVec3) -> Option<[DVec3; 2]> {
    let (a, b, c) = (ju.dot(ju), ju.dot(jv), jv.dot(jv));
    let det = a * c - b * b;
    let regular = det.is_finite() && det > 1e-28 * a * c;
    regular.then(|| [(c * ju - b * jv) / det, (a * jv - b * ju) / det])
}

/// 2-D Newton iteration of [Walter09 eq 9] from `start`, at most `max_iter`
/// steps.
///
/// Each step is limited to length 1/2 in barycentric units and halved (up
/// to 40 times) until `‖f‖` decreases [Walter09 sec 3.3]. The iterate may leave
/// the triangle (the parametrization extends to the whole plane); the caller
/// decides what to keep.
pub(crate) fn newton2(prob: &Problem<f64>, start: DVec2, max_iter: u32) -> NewtonOut {
    let eval = |x: DVec2| {
        let e = prob.eval(x.x, x.y);
        (e.f.to_dvec(), e.fu.to_dvec(), e.fv.to_dvec())
    };
    let mut x = start;
    let (mut f, mut ju, mut jv) = eval(x);
    let mut r = f.length();
    let mut iters = 0;
    while iters < max_iter && r.is_finite() && r > 1e-15 {
        let Some(mut d) = pinv_apply(ju, jv, f) else {
            break;
        };
        let len = d.length();
        if !len.is_finite() {
            break;
        }
        if len > 0.5 {
            d *= 0.5 / len;
        }
        iters += 1;
        let mut t = 1.0;
        let mut accepted = false;
        for _ in 0..40 {
            let xn = x - t * d;
            let (fn_, jun, jvn) = eval(xn);
            let rn = fn_.length();
            if rn < r {
                (x, f, ju, jv, r) = (xn, fn_, jun, jvn, rn);
                accepted = true;
                break;
            }
            t *= 0.5;
        }
        if !accepted || t * d.length() <= 1e-16 * (1.0 + x.length()) || x.length() > 1e3 {
            break;
        }
    }
    NewtonOut {
        uv: x,
        residual: r,
        iterations: iters,
        floor: FLOOR_FACTOR * prob.residual_floor(x.x, x.y, ju, jv),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flat_root_solves_eq5_from_eq6() {
        let mut worst = 0.0f64;
        let mut max_it = 0;
        let mut total = 0;
        let mut n = 0;
        for &eta in &[1.0, 1.33, 1.5, 2.42, 0.75] {
            for &vy in &[-0.01, -0.3, -1.0, -5.0] {
                for &ly in &[0.01, 0.5, 2.0, 30.0] {
                    for &lx in &[0.0, 1e-6, 0.2, 1.0, 10.0, 1e3] {
                        let (x, it) = flat_root(vy, lx, ly, eta);
                        assert!((0.0..=lx).contains(&x));
                        let (f, df) = flat_f(x, vy, lx, ly, eta);
                        // A root located to a few ulps of the coordinates:
                        // |f| within |f'| · 8 ulp(l_x) of the rounding level.
                        let tol =
                            4.0 * f64::EPSILON * (1.0 + eta) + df.abs() * 8.0 * f64::EPSILON * lx;
                        worst = worst.max(f.abs() / tol);
                        max_it = max_it.max(it);
                        total += it;
                        n += 1;
                    }
                }
            }
        }
        println!(
            "flat 1-D Newton (extreme grid of geometries): {n} cases, mean {:.2} iterations, \
             max {max_it}, worst |f| / tolerance = {worst:.2}",
            total as f64 / n as f64
        );
        assert!(worst <= 1.0);
    }
}
