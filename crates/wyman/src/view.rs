//! The projections of the raster passes: the eye's pinhole (the scene's
//! camera, [`eikon_view::Camera`]'s conventions) and the light's view
//! (orthographic for a directional light, a pinhole at a point light).
//!
//! One [`View`] gives the shaders' world-to-clip matrix and, in f64 on the
//! CPU, the same mapping for lookups into what the passes rendered (the
//! caustic and shadow maps).
//!
//! Clip space is wgpu's: x right and y up in [-1, 1], depth in [0, 1];
//! framebuffer pixel (0, 0) is the top-left one and rasterization samples
//! pixel centres, so image point `(x, y)` (pixels, y down) is
//! `ndc = (2 x / w - 1, 1 - 2 y / h)`, as [`eikon_view::Camera::ray_through`].

use crate::WymanError;
use eikon_grid::{Light, Scene};
use eikon_optics::Camera;
use glam::{DMat4, DVec2, DVec3, DVec4};

/// A projection and the target it renders into.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    /// Perspective: the eye. Orthographic: a point behind everything drawn,
    /// on the view axis.
    pub eye: DVec3,
    /// Unit view axis.
    pub forward: DVec3,
    /// Unit image right.
    pub right: DVec3,
    /// Unit image up.
    pub up: DVec3,
    /// A pinhole (true) or parallel rays along `forward` (false).
    pub perspective: bool,
    /// Half the image plane: tangents of the half-angles (perspective) or
    /// half-extents in world units (orthographic).
    pub half: DVec2,
    /// Depth range along `forward` mapped to [0, 1].
    pub near: f64,
    /// See `near`.
    pub far: f64,
    /// Target size, pixels.
    pub size: [u32; 2],
    /// Where in its pixel the rasterizer's sample lands, in [0, 1)^2 (0.5,
    /// 0.5: the centre).
    pub offset: DVec2,
}

impl View {
    /// The eye pass of `camera` with the pixel sample at `offset` of every
    /// pixel, its depth range covering the sphere `(centre, radius)`.
    pub fn of_camera(camera: &Camera, offset: DVec2, centre: DVec3, radius: f64) -> View {
        let eye = camera.position();
        let forward = camera.forward();
        let tan_y = (0.5 * camera.fov_y_degrees()).to_radians().tan();
        let (w, h) = (camera.width(), camera.height());
        let along = (centre - eye).dot(forward);
        View {
            eye,
            forward,
            right: camera.right(),
            up: camera.true_up(),
            perspective: true,
            half: DVec2::new(tan_y * f64::from(w) / f64::from(h), tan_y),
            near: (along - radius).max(radius * 1e-3) * 0.99,
            far: (along + radius).max(radius * 2e-3) * 1.01,
            size: [w, h],
            offset,
        }
    }

    /// The light's view of the sphere `(centre, radius)`: the photon buffer
    /// and shadow map of [`size`] texels a side cover the sphere's outline
    /// (scale 1) or `scale` times it around its centre (the caustic map).
    pub fn of_light(
        light: &Light,
        centre: DVec3,
        radius: f64,
        scale: f64,
        size: u32,
    ) -> Result<View, LightView> {
        let margin = 1.01;
        let (eye, forward, perspective, half, near, far) = match *light {
            Light::Directional { direction, .. } => {
                let f = direction.normalize();
                let h = radius * margin * scale;
                (
                    centre - f * (2.0 * radius),
                    f,
                    false,
                    DVec2::splat(h),
                    0.5 * radius,
                    3.5 * radius,
                )
            }
            Light::Point { position, .. } => {
                let to = centre - position;
                let dist = to.length();
                if dist <= radius * margin {
                    return Err(LightView::Inside);
                }
                let tan = radius / (dist * dist - radius * radius).sqrt() * margin;
                let tan = (tan * scale).min(MAX_TAN);
                (
                    position,
                    to / dist,
                    true,
                    DVec2::splat(tan),
                    (dist - radius) * 0.99,
                    (dist + radius) * 1.01,
                )
            }
            Light::Spot { .. } => return Err(LightView::Spot),
        };
        let right = eikon_view::background::tangent(forward);
        let up = right.cross(forward);
        Ok(View {
            eye,
            forward,
            right,
            up,
            perspective,
            half,
            near,
            far,
            size: [size, size],
            offset: DVec2::splat(0.5),
        })
    }

    /// World to clip space, as the shaders use it.
    pub fn view_proj(&self) -> DMat4 {
        let [w, h] = self.size.map(f64::from);
        // The sample at `offset` of a pixel moves to its centre.
        let shift = DVec2::new(
            2.0 * (0.5 - self.offset.x) / w,
            2.0 * (self.offset.y - 0.5) / h,
        );
        let (r, u, f, e) = (self.right, self.up, self.forward, self.eye);
        // Rows of the matrix: x, y, z and w of clip space.
        let (x, y, z, ww) = if self.perspective {
            let depth = self.far / (self.far - self.near);
            (
                DVec4::new(r.x, r.y, r.z, -r.dot(e)) / self.half.x
                    + DVec4::new(f.x, f.y, f.z, -f.dot(e)) * shift.x,
                DVec4::new(u.x, u.y, u.z, -u.dot(e)) / self.half.y
                    + DVec4::new(f.x, f.y, f.z, -f.dot(e)) * shift.y,
                DVec4::new(f.x, f.y, f.z, -f.dot(e) - self.near) * depth,
                DVec4::new(f.x, f.y, f.z, -f.dot(e)),
            )
        } else {
            let span = self.far - self.near;
            (
                DVec4::new(r.x, r.y, r.z, -r.dot(e)) / self.half.x + DVec4::W * shift.x,
                DVec4::new(u.x, u.y, u.z, -u.dot(e)) / self.half.y + DVec4::W * shift.y,
                DVec4::new(f.x, f.y, f.z, -f.dot(e) - self.near) / span,
                DVec4::W,
            )
        };
        DMat4::from_cols(x, y, z, ww).transpose()
    }

    /// The continuous framebuffer position of `p` (pixels, y down), or
    /// `None` behind a pinhole.
    pub fn pixel(&self, p: DVec3) -> Option<DVec2> {
        let c = self.view_proj() * p.extend(1.0);
        if c.w <= 0.0 {
            return None;
        }
        let [w, h] = self.size.map(f64::from);
        Some(DVec2::new(
            (c.x / c.w + 1.0) * 0.5 * w,
            (1.0 - c.y / c.w) * 0.5 * h,
        ))
    }

    /// Distance of `p` along its view ray: from the eye (perspective) or
    /// along the axis (orthographic), as the shaders' `view_dist`.
    pub fn distance(&self, p: DVec3) -> f64 {
        if self.perspective {
            (p - self.eye).length()
        } else {
            (p - self.eye).dot(self.forward)
        }
    }

    /// The cosine, to the view axis, of the ray through image point `ndc`
    /// (1 for parallel rays).
    pub fn axis_cosine(&self, ndc: DVec2) -> f64 {
        if self.perspective {
            1.0 / (1.0 + (ndc * self.half).length_squared()).sqrt()
        } else {
            1.0
        }
    }
}

/// The largest tangent of a light view's half-angle (80 degrees).
const MAX_TAN: f64 = 5.671_281_819_617_709;

/// Why a light has no view of the refractor.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LightView {
    /// A point light inside the refractor's bounding sphere.
    Inside,
    /// A spot light (its cone would weight each photon; not done).
    Spot,
}

impl LightView {
    /// The error for light `i` of `scene`.
    pub fn error(self, scene: &Scene, i: usize) -> WymanError {
        let (field, msg) = match self {
            LightView::Inside => (
                format!("light[{i}].position"),
                "the image-space method (wyman) needs a point light outside the refracting object's bounding sphere",
            ),
            LightView::Spot => (
                format!("light[{i}].type"),
                "the image-space method (wyman) takes point and directional lights; a spot light needs --method eikonal",
            ),
        };
        WymanError::Scene(scene.error_at(&field, msg))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_eye_view_maps_each_camera_ray_to_its_pixel() {
        let cam = Camera::new(
            DVec3::new(0.5, 0.75, 2.9),
            DVec3::new(0.1, -0.3, 0.0),
            DVec3::Y,
            45.0,
            80,
            60,
            1,
        )
        .unwrap();
        for offset in [DVec2::splat(0.5), DVec2::new(0.1, 0.85)] {
            let v = View::of_camera(&cam, offset, DVec3::ZERO, 0.5);
            for (px, py) in [(0u32, 0u32), (79, 59), (13, 41)] {
                let (x, y) = (f64::from(px) + offset.x, f64::from(py) + offset.y);
                let (o, d) = cam.ray_through(x, y);
                let q = v.pixel(o + d * 2.7).unwrap();
                // The sample point lands on the pixel centre.
                let want = DVec2::new(f64::from(px) + 0.5, f64::from(py) + 0.5);
                assert!((q - want).length() < 1e-9, "{q} vs {want}");
            }
            // Depth: the near and far planes at 0 and 1.
            let m = v.view_proj();
            for (t, z) in [(v.near, 0.0), (v.far, 1.0)] {
                let c = m * (cam.position() + cam.forward() * t).extend(1.0);
                assert!((c.z / c.w - z).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn a_directional_light_looks_along_its_direction() {
        let l = Light::Directional {
            direction: DVec3::new(0.2, -1.0, 0.1),
            power: DVec3::ONE,
        };
        let c = DVec3::new(0.0, 0.15, 0.0);
        let v = View::of_light(&l, c, 0.45, 1.0, 64).unwrap();
        // The centre at the middle, points along the light on one texel.
        let q = v.pixel(c).unwrap();
        assert!((q - DVec2::splat(32.0)).length() < 1e-9);
        let q2 = v.pixel(c + v.forward * 5.0).unwrap();
        assert!((q2 - q).length() < 1e-9);
        // The outline fits: the sphere's edge at 1/1.01 of the half-width.
        let edge = v.pixel(c + v.right * 0.45).unwrap();
        assert!((edge.x - 32.0 - 32.0 / 1.01).abs() < 1e-9);
        let z = v.distance(c);
        assert!(z > v.near + 0.45 && z < v.far - 0.45);
    }
}
