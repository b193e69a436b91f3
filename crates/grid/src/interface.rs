//! Interfaces in the smoothed medium: the index on either side of each
//! boundary voxel, and the Fresnel transmittance of light crossing one.
//!
//! The smoothing spreads an interface over a band a few voxels wide, and
//! the ray equation refracts (or totally reflects) a ray through that band
//! by itself. What it cannot do is split the light: Fresnel's partial
//! reflection ([Ihrke07 eqs 2 and 5], `rho` and `tau`) needs the two indices
//! the interface separates, which no point inside the band holds. They are read
//! once per boundary voxel, beyond the band ([`Interfaces::new`]).
//!
//! # Crossing a band
//! The boundary indicator `delta` [Ihrke07 eq 2] integrates to 1 along the
//! normal across an interface, so a displacement `dx` inside the band covers
//! the fraction `w = delta |dx . normal|` of one crossing. Light keeps the
//! power fraction `(1 - R)^w` over it: over a whole crossing the fractions
//! add up to 1 and the product to `1 - R`, however the band is cut into
//! steps. `R` is the unpolarized Fresnel reflectance between the two side
//! indices at the angle of incidence, found from the tangential part of
//! the eikonal gradient `v` (`|v| = n`): at a planar interface Snell's
//! invariant `n sin(theta) = |v_t|` holds through the whole band, so `R` is
//! the same wherever in the band it is evaluated and whichever way the
//! light goes. Where `|v_t|` reaches the lower side index the interface
//! reflects totally; the ray equation turns the light back by itself, so it
//! keeps all its power (`R` is not applied).

use crate::field::Medium;
use crate::geometry::Trilinear;
use crate::ray::IndexField;
use eikon_optics::fresnel;
use eikon_shader::{nothing, Module};
use glam::DVec3;
use rayon::prelude::*;

/// The WGSL of [`crossing_transmittance`] and [`band_transmittance`].
pub static WGSL: Module = Module {
    name: "interface",
    requires: &[&eikon_optics::fresnel::WGSL],
    declarations: nothing,
    text: include_str!("interface.wgsl"),
};

/// The two sides of an interface at a point, for Fresnel.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Sides {
    /// Index on the side the gradient points away from.
    pub lo: f64,
    /// Index on the side the gradient points to.
    pub hi: f64,
}

/// The interface sides of every voxel of a medium, per index channel.
#[derive(Clone, Debug)]
pub struct Interfaces {
    /// Per index channel, per voxel (standard order): `[n_lo, n_hi]`, the
    /// index on the low and the high side of the interface a boundary voxel
    /// belongs to, read along the gradient a probe length either way from
    /// its centre (beyond the smoothing) and extrapolated back to the
    /// surface where the index is graded; elsewhere the voxel's own index
    /// twice (no jump).
    pub sides: Vec<Vec<[f32; 2]>>,
}

/// How far either side of a boundary voxel its sides are read, world
/// units: beyond the smoothing kernel's reach (3 sigma each way and the
/// gradient stencil), at least 1.5 voxels.
pub fn probe_length(medium: &Medium) -> f64 {
    (6.0 * medium.smoothing + 0.5).max(1.5) * medium.geometry.voxel_size()
}

impl Interfaces {
    /// Bytes the sides of a grid of `cells` voxels with `channels` index
    /// channels take (for the memory estimate checked before a run).
    pub fn bytes(cells: u128, channels: usize) -> u128 {
        cells * channels as u128 * std::mem::size_of::<[f32; 2]>() as u128
    }

    /// The sides of every voxel of `medium`, read `probe` world units
    /// either side of each boundary voxel ([`probe_length`] is the usual
    /// choice).
    pub fn new(medium: &Medium, probe: f64) -> Self {
        let g = &medium.geometry;
        let count = g.voxel_count();
        let bnd = medium.boundary.as_slice().expect("standard layout");
        let sides = (0..medium.channels())
            .map(|ch| {
                let field = medium.field(ch);
                let idx = medium.index[ch].as_slice().expect("standard layout");
                (0..count)
                    .into_par_iter()
                    .map(|f| {
                        let n = idx[4 * f];
                        let grad = DVec3::new(
                            idx[4 * f + 1] as f64,
                            idx[4 * f + 2] as f64,
                            idx[4 * f + 3] as f64,
                        );
                        if bnd[f] <= 0.0 || grad.length() == 0.0 {
                            return [n, n];
                        }
                        let [_, ny, nz] = g.dims;
                        let (i, j, k) = (f / (ny * nz), (f / nz) % ny, f % nz);
                        let c = g.voxel_center(i, j, k);
                        let normal = grad.normalize();
                        // Read a probe length out, and extrapolate back
                        // linearly from twice as far where the index keeps
                        // changing the same way (a graded index, like a
                        // Luneburg lens or a heated layer, ends at an
                        // object's surface without a jump); a plateau
                        // reads as it is.
                        let side = |s: f64| {
                            let near = field.sample(c + normal * (s * probe)).0;
                            let far = field.sample(c + normal * (2.0 * s * probe)).0;
                            let here = n as f64;
                            if (far - near) * (near - here) > 0.0 {
                                (2.0 * near - far) as f32
                            } else {
                                near as f32
                            }
                        };
                        [side(-1.0), side(1.0)]
                    })
                    .collect()
            })
            .collect();
        Self { sides }
    }

    /// The sides of index channel `ch` with trilinear weights already
    /// computed on the medium's grid.
    #[inline]
    pub fn sides_at(&self, t: &Trilinear, ch: usize) -> Sides {
        let s = &self.sides[ch];
        let (mut lo, mut hi) = (0.0, 0.0);
        for k in 0..8 {
            let w = t.weight[k];
            let v = s[t.cell[k]];
            lo += w * v[0] as f64;
            hi += w * v[1] as f64;
        }
        Sides { lo, hi }
    }

    /// The power fraction light keeps over the displacement `dx` about the
    /// point `p` of index channel `ch`, travelling with eikonal gradient `v`
    /// (`|v| = n` there): `(1 - R)^(delta |dx . normal|)` (see the module
    /// docs). 1 away from interfaces and under total internal reflection.
    #[inline]
    pub fn transmittance<F: IndexField + ?Sized>(
        &self,
        medium: &Medium,
        field: &F,
        p: DVec3,
        v: DVec3,
        dx: DVec3,
        ch: usize,
    ) -> f64 {
        let g = &medium.geometry;
        if !g.contains(p) {
            return 1.0;
        }
        let t = g.trilinear(p);
        let delta = t.scalar(medium.boundary.as_slice().expect("standard layout"));
        if delta <= 0.0 {
            return 1.0;
        }
        band_transmittance(self.sides_at(&t, ch), delta, field.sample(p).1, v, dx)
    }
}

/// [`Interfaces::transmittance`] from its samples at the point: the
/// `sides`, the boundary indicator `delta` and the index gradient `grad`
/// (whose direction is the interface's normal).
#[inline]
pub fn band_transmittance(sides: Sides, delta: f64, grad: DVec3, v: DVec3, dx: DVec3) -> f64 {
    if delta <= 0.0 {
        return 1.0;
    }
    let len = grad.length();
    if len == 0.0 || !len.is_finite() {
        return 1.0;
    }
    let normal = grad / len;
    let part = (delta * dx.dot(normal).abs()).min(1.0);
    if part <= 0.0 {
        return 1.0;
    }
    crossing_transmittance(sides, v, normal).powf(part)
}

/// `1 - R` for light with eikonal gradient `v` crossing the interface with
/// unit `normal` between `sides`, from Snell's invariant `|v_t|`; 1 under
/// total internal reflection (the ray equation reflects the light itself)
/// and where the sides do not differ.
#[inline]
pub fn crossing_transmittance(sides: Sides, v: DVec3, normal: DVec3) -> f64 {
    let Sides { lo, hi } = sides;
    if !(lo > 0.0 && hi > 0.0) || lo == hi {
        return 1.0;
    }
    let vt2 = (v - normal * v.dot(normal)).length_squared();
    let n_min = lo.min(hi);
    if vt2 >= n_min * n_min {
        return 1.0;
    }
    // Incidence on the low side: sin = |v_t| / lo (R is the same seen
    // from either side).
    let cos_lo = (1.0 - vt2 / (lo * lo)).max(0.0).sqrt();
    1.0 - fresnel::reflectance(cos_lo, lo, hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crossing_transmittance_is_fresnel_from_either_side() {
        let sides = Sides { lo: 1.0, hi: 1.5 };
        let normal = DVec3::Y;
        // Normal incidence: 1 - ((n - 1) / (n + 1))^2, either way.
        let t0 = 1.0 - (0.5f64 / 2.5).powi(2);
        for v in [DVec3::Y, -DVec3::Y * 1.5, DVec3::Y * 1.2] {
            assert!((crossing_transmittance(sides, v, normal) - t0).abs() < 1e-12);
        }
        // 40 degrees in air; the same ray inside the glass (Snell).
        let th = 40f64.to_radians();
        let air = DVec3::new(th.sin(), th.cos(), 0.0);
        let sin_g = th.sin() / 1.5;
        let glass = DVec3::new(sin_g, (1.0 - sin_g * sin_g).sqrt(), 0.0) * 1.5;
        let want = 1.0 - fresnel::reflectance(th.cos(), 1.0, 1.5);
        assert!((crossing_transmittance(sides, air, normal) - want).abs() < 1e-12);
        assert!((crossing_transmittance(sides, glass, normal) - want).abs() < 1e-12);
        // Beyond the critical angle inside the glass: total reflection, no
        // loss (the ray equation turns the light back).
        let tir = DVec3::new(1.2, 0.9, 0.0);
        assert_eq!(crossing_transmittance(sides, tir, normal), 1.0);
        // No jump, no reflection.
        let flat = Sides { lo: 1.3, hi: 1.3 };
        assert_eq!(crossing_transmittance(flat, air, normal), 1.0);
    }
}
