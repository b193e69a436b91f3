//! The target function of [Walter09 eq 8], `f(u, v) = Ĥ(u, v) + σ N̂_s(u, v)`,
//! and its 3×2 Jacobian (via [Walter09 eq 10]), written once over [`Scalar`] so
//! that the same code is evaluated at points (Newton, [Walter09 eq 9]) and over
//! boxes of barycentric coordinates in interval arithmetic (Krawczyk,
//! [Walter09 eqs 11-15]).
//!
//! `σ = +1` for `η > 1` (the paper's case: `Ĥ = −N̂_s` at a solution,
//! [Walter09 eq 4]) and `σ = −1` for `η < 1`, where `Ĥ` still points into the
//! denser medium, now the outside, so that `Ĥ = +N̂_s`.

use super::interval::{Scalar, V3};
use super::Triangle;
use glam::DVec3;

/// The per-query constants of [Walter09 eq 8] in the scalar type `T`.
/// Differences of input points are formed in `T`, so for intervals they enclose
/// the exact differences of the `f64` inputs.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Problem<T> {
    /// `V − p0`.
    pub v0: V3<T>,
    /// `L − p0`.
    pub l0: V3<T>,
    /// Edges `p1 − p0`, `p2 − p0`.
    pub e1: V3<T>,
    pub e2: V3<T>,
    /// Vertex normal `n0` and the differences `n1 − n0`, `n2 − n0` (the
    /// unnormalized interpolated normal is `n0 + u (n1 − n0) + v (n2 − n0)`).
    pub n0: V3<T>,
    pub dn1: V3<T>,
    pub dn2: V3<T>,
    pub eta: T,
    /// `σ` above.
    pub sigma: T,
}

/// Value of `f` and its partial derivatives `∂f/∂u`, `∂f/∂v`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Eval<T> {
    pub f: V3<T>,
    pub fu: V3<T>,
    pub fv: V3<T>,
}

impl<T: Scalar> Problem<T> {
    pub fn new(tri: &Triangle, v: DVec3, l: DVec3, eta: f64) -> Problem<T> {
        let p0 = V3::<T>::from_dvec(tri.p[0]);
        let n0 = V3::<T>::from_dvec(tri.n[0]);
        Problem {
            v0: V3::from_dvec(v).sub(p0),
            l0: V3::from_dvec(l).sub(p0),
            e1: V3::from_dvec(tri.p[1]).sub(p0),
            e2: V3::from_dvec(tri.p[2]).sub(p0),
            n0,
            dn1: V3::from_dvec(tri.n[1]).sub(n0),
            dn2: V3::from_dvec(tri.n[2]).sub(n0),
            eta: T::cst(eta),
            sigma: T::cst(if eta > 1.0 { 1.0 } else { -1.0 }),
        }
    }

    /// `P − p0 = u e1 + v e2`.
    fn offset(&self, u: T, v: T) -> V3<T> {
        self.e1.scale(u).add(self.e2.scale(v))
    }

    /// `Ĥ` of [Walter09 eq 3] and the unnormalized `η ω̂_V + ω̂_L`, its length,
    /// and the unit vectors of [Walter09 eqs 1-2] with their lengths.
    fn half_vector(&self, u: T, v: T) -> HalfVector<T> {
        let d = self.offset(u, v);
        let a = self.v0.sub(d); // V − P
        let b = self.l0.sub(d); // L − P
        let da = a.norm();
        let db = b.norm();
        let wv = a.div(da).unit_clamp(); // [Walter09 eq 1]
        let wl = b.div(db).unit_clamp(); // [Walter09 eq 2]
        let h = wv.scale(self.eta).add(wl);
        let dh = h.norm();
        let hn = h.div(dh).unit_clamp(); // [Walter09 eq 3]
        HalfVector {
            wv,
            wl,
            da,
            db,
            dh,
            h: hn,
        }
    }

    /// Unnormalized interpolated normal, its length and the unit normal.
    fn normal(&self, u: T, v: T) -> (V3<T>, T) {
        let n = self.n0.add(self.dn1.scale(u)).add(self.dn2.scale(v));
        let len = n.norm();
        (n.div(len).unit_clamp(), len)
    }

    /// `f(u, v)` of [Walter09 eq 8].
    pub fn f(&self, u: T, v: T) -> V3<T> {
        let hv = self.half_vector(u, v);
        let (ns, _) = self.normal(u, v);
        hv.h.add(ns.scale(self.sigma))
    }

    /// `f` and its Jacobian columns. Every derivative of a normalized vector
    /// uses [Walter09 eq 10] in the equivalent form
    /// `n̂' = (u' − (n̂·u') n̂) / ‖u‖`.
    pub fn eval(&self, u: T, v: T) -> Eval<T> {
        let hv = self.half_vector(u, v);
        let (ns, nlen) = self.normal(u, v);
        let unit_deriv = |n: V3<T>, len: T, du: V3<T>| du.sub(n.scale(n.dot(du))).div(len);
        // ∂(V − P)/∂u = −e1, ∂(L − P)/∂u = −e1 (likewise for v with e2).
        let column = |e: V3<T>, dn: V3<T>| {
            let me = V3 {
                x: -e.x,
                y: -e.y,
                z: -e.z,
            };
            let dwv = unit_deriv(hv.wv, hv.da, me);
            let dwl = unit_deriv(hv.wl, hv.db, me);
            let dh = dwv.scale(self.eta).add(dwl);
            let dhn = unit_deriv(hv.h, hv.dh, dh);
            let dns = unit_deriv(ns, nlen, dn);
            dhn.add(dns.scale(self.sigma))
        };
        Eval {
            f: hv.h.add(ns.scale(self.sigma)),
            fu: column(self.e1, self.dn1),
            fv: column(self.e2, self.dn2),
        }
    }
}

impl<T: Scalar> Problem<T> {
    /// The square system that certifies a root ([`super::search::certify_root`]):
    /// `c(u, v) = h × n` with the unnormalized half-vector
    /// `h = η ω̂_V + ω̂_L` ([Walter09 eq 3] before normalizing) and the
    /// unnormalized interpolated normal `n`, its partial derivatives, `h·n` and
    /// `n`. `c = 0` with `sign(h·n) = −σ` is exactly `Ĥ = −σ N̂_s`, i.e. `f = 0`.
    pub fn cross_eval(&self, u: T, v: T) -> CrossEval<T> {
        let hv = self.half_vector(u, v);
        let h = hv.wv.scale(self.eta).add(hv.wl);
        let n = self.n0.add(self.dn1.scale(u)).add(self.dn2.scale(v));
        let unit_deriv = |w: V3<T>, len: T, du: V3<T>| du.sub(w.scale(w.dot(du))).div(len);
        let column = |e: V3<T>, dn: V3<T>| {
            let me = e.neg();
            let dh = unit_deriv(hv.wv, hv.da, me)
                .scale(self.eta)
                .add(unit_deriv(hv.wl, hv.db, me));
            dh.cross(n).add(h.cross(dn))
        };
        CrossEval {
            c: h.cross(n),
            cu: column(self.e1, self.dn1),
            cv: column(self.e2, self.dn2),
            hn: h.dot(n),
            n,
        }
    }
}

/// Value and partial derivatives of `c = h × n`, with `h·n` and `n`
/// ([`Problem::cross_eval`]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct CrossEval<T> {
    pub c: V3<T>,
    pub cu: V3<T>,
    pub cv: V3<T>,
    pub hn: T,
    pub n: V3<T>,
}

impl Problem<f64> {
    /// A bound on the smallest `‖f‖` that [`Problem::f`] can be expected to
    /// return near a root at `(u, v)` in doubles (`fu`, `fv`: the Jacobian
    /// there), to first order in the unit roundoff `u_r = 2⁻⁵³`:
    ///
    /// * `V − P = v0 − (u e1 + v e2)` is formed with an error of at most
    ///   `3 u_r S_V`, `S_V = ‖v0‖ + |u| ‖e1‖ + |v| ‖e2‖`; normalizing it
    ///   [Walter09 eq 1] divides that by `d_V = ‖V − P‖` (the projection onto
    ///   the unit sphere does not enlarge it; a factor 2 and `4 u_r` for the
    ///   norm and the division are added). Likewise `ω̂_L` [Walter09 eq 2] and
    ///   `N̂_s` (with `S_N = ‖n0‖ + |u| ‖n1 − n0‖ + |v| ‖n2 − n0‖`).
    /// * `Ĥ` [Walter09 eq 3] sums `η ω̂_V + ω̂_L` and divides by its length
    ///   `d_H`.
    /// * The root itself lies between representable `(u, v)`: at the
    ///   nearest one `‖f‖` is up to `u_r (|u| ‖f_u‖ + |v| ‖f_v‖)`.
    ///
    /// Away from the triangle's plane this is ~1e-15. With `V` 1e-6 from
    /// the plane and order-one coordinates, `u_r S_V / d_V` alone is ~1e-10:
    /// the residual cannot be driven below that, whatever the iteration.
    pub fn residual_floor(&self, u: f64, v: f64, fu: DVec3, fv: DVec3) -> f64 {
        let ur = 0.5 * f64::EPSILON;
        let len = |x: V3<f64>| x.to_dvec().length();
        let (au, av) = (u.abs(), v.abs());
        let d = self.offset(u, v);
        let a = self.v0.sub(d).to_dvec();
        let b = self.l0.sub(d).to_dvec();
        let n = self.n0.add(self.dn1.scale(u)).add(self.dn2.scale(v));
        let (da, db, dn) = (a.length(), b.length(), len(n));
        let dh = (self.eta * a / da + b / db).length();
        let s_v = len(self.v0) + au * len(self.e1) + av * len(self.e2);
        let s_l = len(self.l0) + au * len(self.e1) + av * len(self.e2);
        let s_n = len(self.n0) + au * len(self.dn1) + av * len(self.dn2);
        let e_wv = 6.0 * ur * s_v / da + 4.0 * ur;
        let e_wl = 6.0 * ur * s_l / db + 4.0 * ur;
        let e_h = self.eta * e_wv + e_wl + 2.0 * ur * (self.eta + 1.0);
        let e_hhat = 2.0 * e_h / dh + 4.0 * ur;
        let e_ns = 6.0 * ur * s_n / dn + 4.0 * ur;
        let quantum = ur * (au * fu.length() + av * fv.length());
        e_hhat + e_ns + 2.0 * ur + quantum
    }
}

struct HalfVector<T> {
    wv: V3<T>,
    wl: V3<T>,
    da: T,
    db: T,
    dh: T,
    h: V3<T>,
}

#[cfg(test)]
mod tests {
    use super::super::interval::Interval;
    use super::*;

    fn tri() -> Triangle {
        Triangle::new(
            [
                DVec3::new(0.0, 0.0, 0.0),
                DVec3::new(1.0, 0.1, 0.0),
                DVec3::new(0.2, 0.9, 0.1),
            ],
            [
                DVec3::new(0.3, -0.2, 1.0),
                DVec3::new(-0.4, 0.1, 1.0),
                DVec3::new(0.1, 0.5, 1.0),
            ],
        )
    }

    /// The analytic Jacobian equals central differences of `f`.
    #[test]
    fn jacobian_matches_finite_differences() {
        let t = tri();
        let p = Problem::<f64>::new(
            &t,
            DVec3::new(0.3, 0.2, -0.7),
            DVec3::new(-1.0, 2.0, 1.5),
            1.5,
        );
        for &(u, v) in &[(0.2, 0.3), (0.7, 0.1), (0.05, 0.9), (1.3, -0.2)] {
            let e = p.eval(u, v);
            let h = 1e-6;
            let du = p.f(u + h, v).sub(p.f(u - h, v)).scale(0.5 / h);
            let dv = p.f(u, v + h).sub(p.f(u, v - h)).scale(0.5 / h);
            assert!((du.to_dvec() - e.fu.to_dvec()).length() < 1e-8);
            assert!((dv.to_dvec() - e.fv.to_dvec()).length() < 1e-8);
        }
    }

    /// Interval evaluation over a box encloses the point values of `f` and of
    /// its Jacobian at the corners and at interior samples ([Walter09 eq 12]
    /// and the `F'(X)` of [Walter09 eq 11] depend on this).
    #[test]
    fn interval_extension_encloses_point_values() {
        let t = tri();
        let (v, l) = (DVec3::new(0.3, 0.2, -0.7), DVec3::new(-1.0, 2.0, 1.5));
        for eta in [1.5, 0.7] {
            let pf = Problem::<f64>::new(&t, v, l, eta);
            let pi = Problem::<Interval>::new(&t, v, l, eta);
            let mut checked = 0;
            for (u0, v0, w) in [
                (0.0, 0.0, 1.0),
                (0.2, 0.3, 0.1),
                (0.6, 0.1, 1e-3),
                (0.4, 0.4, 1e-7),
            ] {
                let bu = Interval::new(u0, u0 + w);
                let bv = Interval::new(v0, v0 + w);
                let big = pi.eval(bu, bv);
                for i in 0..=10 {
                    for j in 0..=10 {
                        let u = u0 + w * i as f64 / 10.0;
                        let vv = v0 + w * j as f64 / 10.0;
                        let e = pf.eval(u, vv);
                        for (iv, pv) in [(big.f, e.f), (big.fu, e.fu), (big.fv, e.fv)] {
                            assert!(iv.x.contains(pv.x), "{iv:?} {pv:?}");
                            assert!(iv.y.contains(pv.y), "{iv:?} {pv:?}");
                            assert!(iv.z.contains(pv.z), "{iv:?} {pv:?}");
                            checked += 1;
                        }
                    }
                }
            }
            assert_eq!(checked, 4 * 121 * 3);
        }
    }
}
