//! The Henyey-Greenstein scattering phase function (Henyey & Greenstein
//! 1941), the anisotropic phase function of [Ihrke07 eqs 3 and 6].
//!
//! # Convention
//!
//! `cos_theta` is the cosine of the angle between the direction in which the
//! **light travels** before scattering and the direction in which it travels
//! **after** scattering, i.e. towards the eye. A view ray is traced from the
//! eye into the scene along `v`, so the scattered light that reaches the eye
//! travels along `-v` and `cos_theta = dot(l, -v)`, where `l` is the local
//! light direction of travel (the wavefront normal from the light
//! simulation). [`hg_toward_eye`] applies this sign so callers need not.
//!
//! With this convention `g > 0` is forward scattering (light keeps going
//! roughly the way it went, so the medium looks brightest when looking
//! *towards* the light), `g < 0` back scattering, `g = 0` isotropic.
//!
//! The phase function is normalized over the sphere of scattered directions,
//! `∫ p dω = 1`, so its unit is 1/sr; [Ihrke07 eq 6] then multiplies it by the
//! differential irradiance `ΔE` to give radiance.

use eikon_shader::{Consts, Module};
use glam::DVec3;
use std::f64::consts::PI;

fn phase_declarations() -> String {
    Consts::new().f32("G_MAX", G_MAX as f32).wgsl().to_string()
}

/// The WGSL of [`hg`].
pub static WGSL: Module = Module {
    name: "phase",
    requires: &[&eikon_shader::VECTOR],
    declarations: phase_declarations,
    text: include_str!("phase.wgsl"),
};

/// Largest `|g|` accepted by [`hg`]; larger values are clamped to this.
///
/// At `|g| = 1` the function is a Dirac delta and the formula divides 0 by
/// 0; `0.9999` keeps the peak finite (about 1.6e7 /sr) while being
/// indistinguishable from a delta at any practical resolution.
pub const G_MAX: f64 = 0.9999;

/// Henyey-Greenstein phase function in 1/sr:
///
/// `p(θ) = (1 − g²) / (4π (1 + g² − 2 g cos θ)^{3/2})`
///
/// `cos_theta` follows the module convention (light's direction of travel
/// vs. direction of scattering towards the eye) and is clamped to `[-1, 1]`
/// to absorb the rounding of dot products of unit vectors. `g` is the mean
/// cosine of the scattering angle, clamped to `[-G_MAX, G_MAX]`. A NaN
/// argument gives NaN.
pub fn hg(cos_theta: f64, g: f64) -> f64 {
    let c = cos_theta.clamp(-1.0, 1.0);
    let g = g.clamp(-G_MAX, G_MAX);
    let g2 = g * g;
    // 1 + g² − 2gc >= (1 − |g|)² > 0 for |g| < 1: no division by zero.
    let denom = 1.0 + g2 - 2.0 * g * c;
    (1.0 - g2) / (4.0 * PI * denom * denom.sqrt())
}

/// Henyey-Greenstein value for light travelling along `light_dir` scattered
/// into a view ray travelling (from the eye into the scene) along
/// `view_dir`; the directions need not be unit length.
///
/// This is `hg(dot(l̂, −v̂), g)`: the light reaching the eye moves opposite
/// to the view ray. Zero-length or non-finite inputs give NaN.
pub fn hg_toward_eye(light_dir: DVec3, view_dir: DVec3, g: f64) -> f64 {
    let denom = (light_dir.length_squared() * view_dir.length_squared()).sqrt();
    if !(denom > 0.0 && denom.is_finite()) {
        return f64::NAN;
    }
    hg(-light_dir.dot(view_dir) / denom, g)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Composite Simpson rule on `[a, b]` with `n` (even) intervals.
    fn simpson(f: impl Fn(f64) -> f64, a: f64, b: f64, n: usize) -> f64 {
        let h = (b - a) / n as f64;
        let mut s = f(a) + f(b);
        for i in 1..n {
            let w = if i % 2 == 1 { 4.0 } else { 2.0 };
            s += w * f(a + h * i as f64);
        }
        s * h / 3.0
    }

    /// ∫_sphere f(cos θ) dω = 2π ∫_{-1}^{1} f(μ) dμ (azimuthal symmetry).
    /// 400k intervals put a few hundred nodes across the forward peak, whose
    /// width is ~(1 − g)² / 2g, even for g = 0.95.
    fn sphere(f: impl Fn(f64) -> f64) -> f64 {
        2.0 * PI * simpson(f, -1.0, 1.0, 400_000)
    }

    #[test]
    fn normalized_over_the_sphere() {
        for g in [-0.95, -0.7, -0.3, 0.0, 0.2, 0.5, 0.8, 0.95] {
            let total = sphere(|mu| hg(mu, g));
            assert!((total - 1.0).abs() < 1e-8, "g = {g}: {total}");
        }
    }

    #[test]
    fn mean_cosine_is_g() {
        for g in [-0.9, -0.4, 0.0, 0.3, 0.6, 0.9] {
            let mean = sphere(|mu| mu * hg(mu, g));
            assert!((mean - g).abs() < 1e-8, "g = {g}: {mean}");
        }
    }

    #[test]
    fn isotropic_is_one_over_four_pi() {
        for mu in [-1.0, -0.3, 0.0, 0.5, 1.0] {
            assert!((hg(mu, 0.0) - 1.0 / (4.0 * PI)).abs() < 1e-15);
        }
    }

    #[test]
    fn peak_values_and_symmetry() {
        for g in [0.1f64, 0.5, 0.9] {
            // Forward peak (1+g)/(4π(1−g)²), backward (1−g)/(4π(1+g)²).
            let fwd = (1.0 + g) / (4.0 * PI * (1.0 - g).powi(2));
            let back = (1.0 - g) / (4.0 * PI * (1.0 + g).powi(2));
            assert!((hg(1.0, g) / fwd - 1.0).abs() < 1e-12);
            assert!((hg(-1.0, g) / back - 1.0).abs() < 1e-12);
            // Mirror symmetry p(μ, g) = p(−μ, −g).
            assert!((hg(0.3, g) - hg(-0.3, -g)).abs() < 1e-15);
        }
    }

    #[test]
    fn clamps_out_of_range_arguments() {
        assert_eq!(hg(1.0 + 1e-12, 0.5), hg(1.0, 0.5));
        assert_eq!(hg(0.2, 1.0), hg(0.2, G_MAX));
        assert_eq!(hg(0.2, -3.0), hg(0.2, -G_MAX));
        assert!(hg(1.0, 1.0).is_finite());
        assert!(hg(f64::NAN, 0.5).is_nan());
    }

    #[test]
    fn eye_convention_forward_scattering_faces_the_light() {
        // Light travels along -z; the eye looks along +z, i.e. into the light.
        let light = -DVec3::Z;
        let towards_light = DVec3::Z;
        let g = 0.8;
        let facing = hg_toward_eye(light, towards_light, g);
        let away = hg_toward_eye(light, -towards_light, g);
        assert!((facing - hg(1.0, g)).abs() < 1e-12);
        assert!((away - hg(-1.0, g)).abs() < 1e-12);
        assert!(facing > away);
        // Unnormalized inputs give the same value.
        assert!((hg_toward_eye(3.0 * light, 0.5 * towards_light, g) - facing).abs() < 1e-12);
        assert!(hg_toward_eye(DVec3::ZERO, towards_light, g).is_nan());
    }
}
