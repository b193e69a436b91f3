//! A light's caustic map and shadow map as the CPU reads them: how much of
//! the light's unobstructed irradiance reaches a receiver point.
//!
//! The caustic map holds, per texel of the light's view, the power of the
//! photons that landed there over what the unobstructed light sends
//! through that texel (per unit image-plane area for parallel light, per
//! unit solid angle for a pinhole): a receiver point's caustic irradiance
//! is its unobstructed irradiance times the map, bilinearly interpolated
//! between texel centres. Direct light is the unobstructed irradiance
//! where the shadow map says the refractor is not between the point and
//! the light (four nearest texels, weighted bilinearly).

use crate::view::View;
use glam::{DVec2, DVec3};

/// One light's caustic and shadow maps.
pub struct CausticMap {
    /// The caustic map's view.
    pub view: View,
    /// The photon buffer's and shadow map's view.
    pub shadow_view: View,
    values: Vec<DVec3>,
    shadow: Vec<Option<f32>>,
}

impl CausticMap {
    /// The maps as [`crate::Raster::caustic`] reads them back.
    pub fn new(
        view: View,
        shadow_view: View,
        values: Vec<DVec3>,
        shadow: Vec<Option<f32>>,
    ) -> Self {
        CausticMap {
            view,
            shadow_view,
            values,
            shadow,
        }
    }

    /// The caustic map's texel `(x, y)` (row-major from the top-left, as
    /// the light sees it).
    pub fn texel(&self, x: u32, y: u32) -> DVec3 {
        self.values[(y * self.view.size[0] + x) as usize]
    }

    /// The caustic at `x`: what the photons bring there over the
    /// unobstructed light, RGB.
    pub fn caustic(&self, x: DVec3) -> DVec3 {
        let Some(q) = self.view.pixel(x) else {
            return DVec3::ZERO;
        };
        bilinear(q, self.view.size, |i| self.values[i], DVec3::ZERO)
    }

    /// The fraction of the light that reaches `x` past the refractor
    /// unrefracted (1 lit, 0 in its shadow).
    pub fn visibility(&self, x: DVec3) -> f64 {
        let Some(q) = self.shadow_view.pixel(x) else {
            return 1.0;
        };
        let d = self.shadow_view.distance(x);
        // The refractor shadows a point it lies in front of (a hair of
        // allowance for f32 distances).
        let allowance = 1e-5 * d.abs().max(1.0);
        bilinear(
            q,
            self.shadow_view.size,
            |i| match self.shadow[i] {
                Some(s) if f64::from(s) < d - allowance => 0.0,
                _ => 1.0,
            },
            1.0,
        )
    }

    /// The light reaching `x` relative to the unobstructed light, RGB:
    /// direct (shadowed) plus caustic.
    pub fn factor(&self, x: DVec3) -> DVec3 {
        DVec3::splat(self.visibility(x)) + self.caustic(x)
    }
}

/// Bilinear interpolation between texel centres of a `size` image at the
/// continuous pixel position `q` (pixels, texel `(i, j)` centred at
/// `(i + 1/2, j + 1/2)`); texels beyond the image read `outside`.
fn bilinear<T>(q: DVec2, size: [u32; 2], at: impl Fn(usize) -> T, outside: T) -> T
where
    T: Copy + std::ops::Mul<f64, Output = T> + std::ops::Add<Output = T>,
{
    let u = q - DVec2::splat(0.5);
    let (i0, j0) = (u.x.floor(), u.y.floor());
    let (fx, fy) = (u.x - i0, u.y - j0);
    let [w, h] = size.map(i64::from);
    let texel = |i: i64, j: i64| {
        if i < 0 || j < 0 || i >= w || j >= h {
            outside
        } else {
            at((j * w + i) as usize)
        }
    };
    let (i, j) = (i0 as i64, j0 as i64);
    texel(i, j) * ((1.0 - fx) * (1.0 - fy))
        + texel(i + 1, j) * (fx * (1.0 - fy))
        + texel(i, j + 1) * ((1.0 - fx) * fy)
        + texel(i + 1, j + 1) * (fx * fy)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_reads_texel_centres_and_blends_between() {
        let data = [1.0, 2.0, 3.0, 4.0];
        let f = |q| bilinear(q, [2, 2], |i| data[i], 0.0);
        assert_eq!(f(DVec2::new(0.5, 0.5)), 1.0);
        assert_eq!(f(DVec2::new(1.5, 1.5)), 4.0);
        assert!((f(DVec2::new(1.0, 1.0)) - 2.5).abs() < 1e-12);
        // Half a texel beyond the edge: half the outside value.
        assert!((f(DVec2::new(2.0, 0.5)) - 1.0).abs() < 1e-12);
    }
}
