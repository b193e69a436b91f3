//! The distance factor `D` [Walter09 eqs 18-26] and the contribution of a
//! refracted path [Walter09 eq 17]: [Walter09 sec 4].
//!
//! What `D` measures, the `η²` left out of [Walter09 eq 17] and the signs used
//! in [Walter09 eqs 21 and 24] are explained in the documentation of [`super`].

use super::{Solution, Triangle};
use eikon_optics::{fresnel, phase};
use glam::{DVec2, DVec3};

/// [Walter09 eq 18]: the exact distance factor for a flat face (shading normal
/// equal to the geometric normal `N̂_g`):
///
/// `D = (d_V + η d_L) (|ω̂_L·N̂_g|/|ω̂_V·N̂_g| d_V + |ω̂_V·N̂_g|/|ω̂_L·N̂_g| η d_L)`.
///
/// The first factor is the spread perpendicular to the plane of incidence,
/// the second the spread within it.
pub fn distance_factor_flat(sol: &Solution, eta: f64) -> f64 {
    let n = sol.geometric_normal;
    let cl = sol.omega_l.dot(n).abs();
    let cv = sol.omega_v.dot(n).abs();
    (sol.d_v + eta * sol.d_l) * (cl / cv * sol.d_v + cv / cl * eta * sol.d_l)
}

/// `L'` of [Walter09 eq 25] for the perturbation `s` of `ω̂_V` (unit,
/// `⊥ ω̂_V`), through [Walter09 eqs 21-24] (with the signs explained in the
/// module documentation).
pub(crate) fn light_differential(tri: &Triangle, sol: &Solution, eta: f64, s: DVec3) -> DVec3 {
    let (wv, wl, ns, ng) = (sol.omega_v, sol.omega_l, sol.normal, sol.geometric_normal);
    // [Walter09 eq 21]: the point moves in the plane of the triangle.
    let dp = -sol.d_v * (s - s.dot(ng) / wv.dot(ng) * wv);
    // Barycentric rates of P' and the shading normal's derivative
    // [Walter09 eq 10].
    let e1 = tri.p[1] - tri.p[0];
    let e2 = tri.p[2] - tri.p[0];
    let (a, b, c) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (r1, r2) = (dp.dot(e1), dp.dot(e2));
    let det = a * c - b * b;
    let duv = DVec2::new((c * r1 - b * r2) / det, (a * r2 - b * r1) / det);
    let n = tri.interpolated_normal(sol.uv);
    let dn = duv.x * (tri.n[1] - tri.n[0]) + duv.y * (tri.n[2] - tri.n[0]);
    let dns = (dn - ns.dot(dn) * ns) / n.length();
    // [Walter09 eqs 22-24].
    let mu = wl.dot(ns) + eta * wv.dot(ns);
    let dmu = (eta * eta * wv.dot(ns) / wl.dot(ns) + eta) * (s.dot(ns) + wv.dot(dns));
    let dwl = -eta * s + dmu * ns + mu * dns;
    // [Walter09 eq 25].
    dp - dp.dot(wl) * wl + sol.d_l * dwl
}

/// [Walter09 eqs 21-26]: the distance factor `D = ‖L'_⊥ × L'_∥‖` for any
/// triangle, from the differentials `L'` for two orthonormal perturbations of
/// `ω̂_V`. Equals [`distance_factor_flat`] when the normals are flat.
pub fn distance_factor_general(tri: &Triangle, sol: &Solution, eta: f64) -> f64 {
    let (s1, s2) = sol.omega_v.any_orthonormal_pair();
    let l1 = light_differential(tri, sol, eta, s1);
    let l2 = light_differential(tri, sol, eta, s2);
    l1.cross(l2).length() // [Walter09 eq 26]
}

/// The distance factor of [Walter09 eq 17]: [Walter09 eq 18] on flat triangles,
/// [Walter09 eqs 21-26] otherwise.
pub fn distance_factor(tri: &Triangle, sol: &Solution, eta: f64) -> f64 {
    if tri.is_flat() {
        distance_factor_flat(sol, eta)
    } else {
        distance_factor_general(tri, sol, eta)
    }
}

/// A homogeneous medium: relative index of refraction, extinction and
/// Henyey-Greenstein asymmetry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Medium {
    /// `η = η_in / η_out`.
    pub eta: f64,
    /// Extinction coefficient `σ_t` (1/length), for the attenuation
    /// `A = exp(−σ_t d_V)` along `P → V`.
    pub sigma_t: f64,
    /// Henyey-Greenstein mean cosine `g`.
    pub g: f64,
}

/// The factors of [Walter09 eq 17] for one path and their product.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Contribution {
    /// Unpolarized Fresnel transmittance `F` entering the medium at `P`,
    /// incidence cosine `ω̂_L·N̂_s` (relative to the shading normal).
    pub transmittance: f64,
    /// `A = exp(−σ_t d_V)`.
    pub attenuation: f64,
    /// Phase function `ρ = hg(ω̂_V·ω̂_eye, g)` in 1/sr.
    pub phase: f64,
    /// `D` ([`distance_factor`]).
    pub distance_factor: f64,
    /// `I_e F A ρ / D` [Walter09 eq 17]. See the module documentation about
    /// `η²`.
    pub value: f64,
}

/// [Walter09 eq 17] for a point light of intensity `intensity` and the path
/// `sol` through `tri`: `I_e F A ρ / D`.
///
/// `toward_eye` is the direction in which the scattered light leaves `V`
/// towards the eye (the reverse of the view ray's direction; any length).
/// The phase function's argument is the cosine between the light's
/// direction of travel at `V`, which is `ω̂_V` (it goes from `P` to `V`),
/// and `toward_eye`, as [`eikon_optics::phase`] expects.
pub fn contribution(
    tri: &Triangle,
    sol: &Solution,
    medium: &Medium,
    intensity: f64,
    toward_eye: DVec3,
) -> Contribution {
    let transmittance = fresnel::transmittance(sol.omega_l.dot(sol.normal), 1.0, medium.eta);
    let attenuation = (-medium.sigma_t * sol.d_v).exp();
    let phase = phase::hg(sol.omega_v.dot(toward_eye.normalize()), medium.g);
    let d = distance_factor(tri, sol, medium.eta);
    Contribution {
        transmittance,
        attenuation,
        phase,
        distance_factor: d,
        value: intensity * transmittance * attenuation * phase / d,
    }
}
