//! What a ray sees once it leaves the volume: `L_bg` of [Ihrke07 eq 1], and the
//! diffuse receiver plane (the table a caustic falls on, the paper's
//! [Ihrke07 fig 7], where it replaces the environment lookup by a ray-plane
//! intersection).
//!
//! The receiver is lit by the light volumes where it lies inside the
//! grid: its radiance is `albedo / pi * sum_j max(0, -F_j . n)` (per
//! channel in proportion to the fluence), with `F_j` the net flux vector of
//! light `j` interpolated at the hit point ([`eikon_wavefront::volume`]),
//! and `n` the plane normal on the eye's side. Outside the grid nothing refracts or shadows, so it is lit by the
//! lights directly: a directional light's irradiance, or a point or spot
//! light's `P / (4 pi r^2)` (times the cone weight for a spot). An
//! image-space method may instead scale each light's direct irradiance by
//! its own shadow and caustic maps ([`Surroundings::with_light_factor`]).

use eikon_grid::{Background, GridGeometry, Light, Receiver, Scene, Trilinear};
use eikon_optics::environment::{Environment, EnvironmentError, LatLongMap};
use eikon_wavefront::volume::mean_cosine;
use eikon_wavefront::LightVolume;
use glam::DVec3;
use std::f64::consts::PI;

/// The far field of one render: environment, optional checkerboard, and
/// the receiver plane with the lights that illuminate it.
pub struct Surroundings<'a> {
    pub(crate) environment: Environment,
    pub(crate) checker: Option<Checker>,
    pub(crate) receiver: Option<Receiver>,
    pub(crate) lights: &'a [Light],
    pub(crate) volumes: &'a [LightVolume],
    pub(crate) grid: &'a GridGeometry,
    pub(crate) light_factor: Option<LightFactor<'a>>,
}

/// How much of light `j`'s unobstructed irradiance reaches receiver point
/// `x`, per channel: `light_factor(j, x)`. An image-space method supplies
/// it from its shadow and caustic maps (eikon-wyman) in place of light
/// volumes.
pub type LightFactor<'a> = &'a (dyn Fn(usize, DVec3) -> DVec3 + Sync);

/// An emitting checkerboard plane.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Checker {
    pub(crate) point: DVec3,
    pub(crate) normal: DVec3,
    pub(crate) u: DVec3,
    pub(crate) w: DVec3,
    pub(crate) square: f64,
    pub(crate) colors: [DVec3; 2],
}

/// A unit vector orthogonal to the unit `n` (a fixed, documented choice:
/// from the world axis least aligned with `n`), so that checker squares
/// line up with the world axes where they can.
pub fn tangent(n: DVec3) -> DVec3 {
    let a = n.abs();
    let axis = if a.x <= a.y && a.x <= a.z {
        DVec3::X
    } else if a.y <= a.z {
        DVec3::Y
    } else {
        DVec3::Z
    };
    (axis - n * n.dot(axis)).normalize()
}

/// Rounding allowance of a plane hit, relative to the scene's scale: a ray
/// that leaves the grid exactly on a plane lying on the grid's face must
/// still meet it.
const PLANE_EPS: f64 = 1e-9;

/// Distance along the unit `d` from `o` to the plane `(p, n)`, if ahead
/// (or within rounding of `o`, then 0).
#[inline]
fn plane_hit(o: DVec3, d: DVec3, p: DVec3, n: DVec3) -> Option<f64> {
    let den = d.dot(n);
    if den == 0.0 {
        return None;
    }
    let t = (p - o).dot(n) / den;
    let eps = PLANE_EPS * (1.0 + o.abs().max_element() + p.abs().max_element());
    (t > -eps && t.is_finite()).then_some(t.max(0.0))
}

impl<'a> Surroundings<'a> {
    /// The surroundings of `scene`, with its background already loaded as
    /// `environment` (for [`Background::Checker`], what lies beyond the
    /// board: black), lit by `volumes` (one per light of the scene, on
    /// `grid`).
    pub fn new(
        scene: &'a Scene,
        environment: Environment,
        volumes: &'a [LightVolume],
        grid: &'a GridGeometry,
    ) -> Self {
        let checker = match &scene.background {
            Background::Checker {
                point,
                normal,
                square,
                colors,
            } => {
                let u = tangent(*normal);
                Some(Checker {
                    point: *point,
                    normal: *normal,
                    u,
                    w: normal.cross(u),
                    square: *square,
                    colors: *colors,
                })
            }
            _ => None,
        };
        Self {
            environment,
            checker,
            receiver: scene.receiver.clone(),
            lights: &scene.lights,
            volumes,
            grid,
            light_factor: None,
        }
    }

    /// The same surroundings with the receiver lit by each light's direct
    /// irradiance times `factor(j, x)` (shadowed, focused), everywhere,
    /// instead of by light volumes inside the grid.
    pub fn with_light_factor(mut self, factor: LightFactor<'a>) -> Self {
        self.light_factor = Some(factor);
        self
    }

    /// Where a ray from `o` along the unit `d` meets the receiver, if it
    /// does within `max_t`.
    #[inline]
    pub fn receiver_hit(&self, o: DVec3, d: DVec3, max_t: f64) -> Option<f64> {
        let r = self.receiver.as_ref()?;
        let eps = PLANE_EPS * (1.0 + o.abs().max_element());
        plane_hit(o, d, r.point, r.normal).filter(|&t| t <= max_t + eps)
    }

    /// Radiance leaving the receiver at `x` towards a viewer whose ray
    /// travels along `d`; `channel` picks the light volume's direction
    /// array with dispersion.
    pub fn receiver_radiance(&self, x: DVec3, d: DVec3, channel: usize) -> DVec3 {
        let Some(r) = &self.receiver else {
            return DVec3::ZERO;
        };
        // The side of the plane the viewer is on.
        let n = if d.dot(r.normal) < 0.0 {
            r.normal
        } else {
            -r.normal
        };
        let mut e = DVec3::ZERO;
        if let Some(factor) = self.light_factor {
            for (j, light) in self.lights.iter().enumerate() {
                e += direct(light, x, n) * factor(j, x);
            }
        } else if self.grid.contains(x) && !self.volumes.is_empty() {
            let t = self.grid.trilinear(x);
            for v in self.volumes {
                if let Some(light) = LightSample::at(v, &t, channel) {
                    e += light.irradiance(n);
                }
            }
        } else {
            for light in self.lights {
                e += direct(light, x, n);
            }
        }
        r.albedo * e / PI
    }

    /// Background radiance for a ray leaving from `o` along the unit `d`
    /// (it no longer meets the volume): the receiver, the checkerboard, or
    /// the environment, whichever it meets first.
    pub fn radiance(&self, o: DVec3, d: DVec3, channel: usize) -> DVec3 {
        let receiver = self.receiver_hit(o, d, f64::INFINITY);
        let checker = self
            .checker
            .and_then(|c| plane_hit(o, d, c.point, c.normal).map(|t| (t, c)));
        match (receiver, checker) {
            (Some(tr), Some((tc, _))) if tr <= tc => self.receiver_radiance(o + d * tr, d, channel),
            (Some(tr), None) => self.receiver_radiance(o + d * tr, d, channel),
            (_, Some((tc, c))) => {
                let q = o + d * tc - c.point;
                let (a, b) = (
                    (q.dot(c.u) / c.square).floor() as i64,
                    (q.dot(c.w) / c.square).floor() as i64,
                );
                c.colors[(a + b).rem_euclid(2) as usize]
            }
            (None, None) => {
                if self.checker.is_some() {
                    DVec3::ZERO
                } else {
                    DVec3::from_array(self.environment.lookup(d))
                }
            }
        }
    }
}

/// The environment of a scene's background, loaded and scaled by its
/// intensity ([`Background::Checker`] sees black beyond the board).
pub fn load_environment(background: &Background) -> Result<Environment, EnvironmentError> {
    let scale = |e: Environment, k: f64| -> Result<Environment, EnvironmentError> {
        if k == 1.0 {
            return Ok(e);
        }
        Ok(match e {
            Environment::Constant(c) => Environment::Constant(c.map(|x| x * k as f32)),
            Environment::LatLong(m) => {
                let data = m.data().iter().map(|p| p.map(|x| x * k as f32)).collect();
                Environment::LatLong(LatLongMap::new(m.width(), m.height(), data)?)
            }
        })
    };
    match background {
        Background::Constant(c) => Ok(Environment::Constant(c.as_vec3().to_array())),
        Background::Sky { intensity } => scale(Environment::sky(), *intensity),
        Background::Environment { file, intensity } => {
            scale(Environment::from_exr(file)?, *intensity)
        }
        Background::Checker { .. } => Ok(Environment::Constant([0.0; 3])),
    }
}

/// Irradiance at `x` on a surface of unit normal `n` from `light`, with
/// nothing in between.
fn direct(light: &Light, x: DVec3, n: DVec3) -> DVec3 {
    match light {
        Light::Directional { direction, power } => *power * (-direction.dot(n)).max(0.0),
        Light::Point { position, power } => point_irradiance(*position, *power, x, n, 1.0),
        Light::Spot {
            position,
            direction,
            angle,
            falloff,
            power,
        } => {
            let to = (x - *position).normalize_or_zero();
            let w = eikon_optics::spot::cone_weight(to, Some((*direction, *angle, *falloff)));
            point_irradiance(*position, *power, x, n, w)
        }
    }
}

fn point_irradiance(position: DVec3, power: DVec3, x: DVec3, n: DVec3, weight: f64) -> DVec3 {
    let r = x - position;
    let r2 = r.length_squared();
    if r2 == 0.0 {
        return DVec3::ZERO;
    }
    let cos = (-r.normalize().dot(n)).max(0.0);
    power * (weight * cos / (4.0 * PI * r2))
}

/// The light of one light volume at a point, as the renderer uses it (see
/// [`eikon_wavefront::volume`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct LightSample {
    /// RGB fluence rate.
    pub fluence: DVec3,
    /// Unit direction of the net flux (zero where it cancels).
    pub direction: DVec3,
    /// Mean cosine `|F| / phi`.
    pub mean_cosine: f64,
}

impl LightSample {
    /// Trilinear sample of volume `v` for colour channel `ch`; `None` where
    /// it is dark.
    #[inline]
    pub fn at(v: &LightVolume, t: &Trilinear, ch: usize) -> Option<Self> {
        Self::fluence(v, t).map(|fluence| Self::with_fluence(v, t, fluence, ch))
    }

    /// The RGB fluence rate of volume `v` at `t`; `None` where it is dark.
    #[inline]
    pub fn fluence(v: &LightVolume, t: &Trilinear) -> Option<DVec3> {
        let fluence = t.vec3(v.fluence.as_slice().expect("standard layout"));
        (fluence.max_element() > 0.0).then_some(fluence)
    }

    /// [`Self::at`] given the `fluence` read there ([`Self::fluence`]): the
    /// channels share it, each with its own flux where there are three.
    #[inline]
    pub fn with_fluence(v: &LightVolume, t: &Trilinear, fluence: DVec3, ch: usize) -> Self {
        let f = t.vec3(v.flux_of(ch).as_slice().expect("standard layout"));
        let net = f.length();
        let mean_cosine = mean_cosine(fluence.to_array(), net, ch, v.flux.len());
        Self {
            fluence,
            direction: f.normalize_or_zero(),
            mean_cosine,
        }
    }

    /// RGB irradiance on a surface whose normal `n` faces the light: the
    /// net flux through it, `max(0, -F . n)`, shared among the channels in
    /// proportion to their fluence (`|F| = mu phi`).
    #[inline]
    pub fn irradiance(&self, n: DVec3) -> DVec3 {
        self.fluence * ((-self.direction.dot(n)).max(0.0) * self.mean_cosine)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tangent_is_orthogonal_and_unit() {
        for n in [DVec3::X, DVec3::Y, DVec3::new(0.3, -0.4, 0.87).normalize()] {
            let t = tangent(n);
            assert!(t.dot(n).abs() < 1e-12);
            assert!((t.length() - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn a_ray_leaving_from_a_plane_meets_it() {
        // A receiver on the grid's face: the eye ray stops on it, give or
        // take rounding, and must still see it.
        let (p, n) = (DVec3::new(0.0, -0.7, 0.0), DVec3::Y);
        let d = DVec3::new(0.3, -1.0, 0.2).normalize();
        for o in [p, p + DVec3::Y * 1e-12, p - DVec3::Y * 1e-12] {
            let t = plane_hit(o + DVec3::new(0.2, 0.0, 0.1), d, p, n);
            assert!(t.is_some_and(|t| t < 2e-12), "{o}: {t:?}");
        }
        // Clearly behind: no hit.
        assert_eq!(plane_hit(p - DVec3::Y * 1e-3, d, p, n), None);
    }

    #[test]
    fn a_point_light_lights_a_plane_by_the_inverse_square_and_cosine() {
        let p = DVec3::new(0.0, 2.0, 0.0);
        let power = DVec3::splat(4.0 * PI);
        // Straight below at distance 2: E = 4 pi / (4 pi 4) = 0.25.
        let e = point_irradiance(p, power, DVec3::ZERO, DVec3::Y, 1.0);
        assert!((e.x - 0.25).abs() < 1e-12);
        // At 45 degrees: distance^2 = 8, cos = 1/sqrt 2.
        let e = point_irradiance(p, power, DVec3::new(2.0, 0.0, 0.0), DVec3::Y, 1.0);
        assert!((e.x - 1.0 / 8.0 / 2f64.sqrt()).abs() < 1e-12);
        // From below the plane: nothing.
        let e = point_irradiance(p, power, DVec3::ZERO, -DVec3::Y, 1.0);
        assert_eq!(e, DVec3::ZERO);
    }
}
