//! Initial wavefronts of the light sources [Ihrke07 sec 5.2].
//!
//! Every patch starts where its central ray first meets the volume bounds
//! (a short margin before it), which skips the empty space between the
//! light and the volume: outside the bounds light travels straight in the
//! ambient medium, so moving a patch's four corners the same distance along
//! their rays keeps them on one wavefront. Patches whose central ray never
//! meets the volume carry no light into it and are not emitted.
//!
//! * Directional light: a plane wave tiled by square patches of the
//!   requested size; each carries `irradiance * area`.
//! * Point light: a spherical wave on a cube-sphere, each patch carrying
//!   `power * solid angle / (4 pi)`. A patch starting at distance r then has
//!   irradiance `power / (4 pi r^2)`: the 1/r^2 law holds from entry on.
//! * Spot light: the point light's wavefront weighted by the cone, with a
//!   smooth edge of width `falloff` inside the half-angle.

use crate::patch::Patches;
use eikon_grid::{GridGeometry, IndexField, Light, RayState};
use eikon_optics::spot::cone_weight;
use glam::DVec3;
use std::f64::consts::PI;

/// Distance a patch starts before the bounds, in voxels.
pub(crate) const MARGIN_VOXELS: f64 = 0.5;
/// Fewest patches along a cube-sphere face.
const MIN_FACE_PATCHES: usize = 16;
/// Radius, in voxels, of the sphere a point light inside the volume starts on.
pub(crate) const INNER_RADIUS_VOXELS: f64 = 1.0;

/// Emit the initial wavefront of `light` into `out`, scaled per colour
/// channel by `mask` (1 for channels this wavefront carries). Patches are
/// about `size` world units across. Returns the RGB power that enters.
pub fn emit<F: IndexField + ?Sized>(
    light: &Light,
    grid: &GridGeometry,
    field: &F,
    size: f64,
    mask: [f64; 3],
    out: &mut Patches,
) -> [f64; 3] {
    let before = out.len();
    match light {
        Light::Directional { direction, power } => {
            directional(*direction, *power, grid, field, size, mask, out)
        }
        Light::Point { position, power } => {
            spherical(*position, *power, None, grid, field, size, mask, out)
        }
        Light::Spot {
            position,
            direction,
            angle,
            falloff,
            power,
        } => spherical(
            *position,
            *power,
            Some((*direction, *angle, *falloff)),
            grid,
            field,
            size,
            mask,
            out,
        ),
    }
    let mut entered = [0.0; 3];
    for f in &out.flux[before..] {
        for c in 0..3 {
            entered[c] += f[c];
        }
    }
    entered
}

/// A unit vector perpendicular to unit `d`.
fn perpendicular(d: DVec3) -> DVec3 {
    let a = if d.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    (a - d * a.dot(d)).normalize()
}

fn corners_of(grid: &GridGeometry) -> [DVec3; 8] {
    std::array::from_fn(|i| {
        DVec3::new(
            if i & 1 == 0 { grid.min.x } else { grid.max.x },
            if i & 2 == 0 { grid.min.y } else { grid.max.y },
            if i & 4 == 0 { grid.min.z } else { grid.max.z },
        )
    })
}

fn start<F: IndexField + ?Sized>(field: &F, x: DVec3, dir: DVec3) -> RayState {
    RayState::new(x, dir, field.sample(x).0)
}

/// Where a directional light's wavefront is emitted from: the plane
/// normal to its direction `d` that first touches the volume, in the
/// orthonormal frame `(u, w, d)` with `u x w = d` (so corners listed
/// counter-clockwise in `(u, w)` face along `d`), with the ranges `a` and
/// `b` of the volume's projection onto `u` and `w`.
pub(crate) struct PlaneFrame {
    pub u: DVec3,
    pub w: DVec3,
    pub a: (f64, f64),
    pub b: (f64, f64),
    /// Offset of the plane along `d`.
    pub s0: f64,
}

impl PlaneFrame {
    pub(crate) fn new(d: DVec3, grid: &GridGeometry) -> Self {
        let u = perpendicular(d);
        let w = d.cross(u);
        let cs = corners_of(grid);
        let range = |axis: DVec3| {
            cs.iter()
                .map(|c| c.dot(axis))
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
                    (lo.min(x), hi.max(x))
                })
        };
        Self {
            u,
            w,
            a: range(u),
            b: range(w),
            s0: range(d).0,
        }
    }
}

fn directional<F: IndexField + ?Sized>(
    d: DVec3,
    irradiance: DVec3,
    grid: &GridGeometry,
    field: &F,
    size: f64,
    mask: [f64; 3],
    out: &mut Patches,
) {
    let PlaneFrame {
        u,
        w,
        a: (a0, a1),
        b: (b0, b1),
        s0,
    } = PlaneFrame::new(d, grid);
    let na = ((a1 - a0) / size).ceil().max(1.0) as usize;
    let nb = ((b1 - b0) / size).ceil().max(1.0) as usize;
    let margin = MARGIN_VOXELS * grid.voxel_size();
    let flux = [0, 1, 2].map(|c| irradiance[c] * mask[c] * size * size);
    for j in 0..nb {
        for i in 0..na {
            let (a, b) = (a0 + i as f64 * size, b0 + j as f64 * size);
            let at = |da: f64, db: f64, s: f64| u * (a + da) + w * (b + db) + d * s;
            let mid = at(0.5 * size, 0.5 * size, s0);
            let Some((t0, t1)) = grid.clip_line(mid, d) else {
                continue;
            };
            if t1 <= 0.0 {
                continue;
            }
            let s = s0 + (t0 - margin).max(0.0);
            let corners = [(0.0, 0.0), (size, 0.0), (size, size), (0.0, size)]
                .map(|(da, db)| start(field, at(da, db, s), d));
            out.push(corners, flux);
        }
    }
}

/// Solid angle of the spherical triangle with unit corners `a, b, c`
/// (Van Oosterom and Strackee 1983).
fn triangle_solid_angle(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let num = a.dot(b.cross(c)).abs();
    let den = 1.0 + a.dot(b) + b.dot(c) + c.dot(a);
    2.0 * num.atan2(den)
}

/// How many patches `emit` considers for `light` with patches of `size`
/// world units (it keeps those whose central ray meets the volume): the
/// work and memory of emission, checked before emitting
/// ([`crate::check_scene`]).
pub fn candidates(light: &Light, grid: &GridGeometry, size: f64) -> f64 {
    match light {
        Light::Directional { direction, .. } => {
            let f = PlaneFrame::new(*direction, grid);
            ((f.a.1 - f.a.0) / size).ceil().max(1.0) * ((f.b.1 - f.b.0) / size).ceil().max(1.0)
        }
        Light::Point { position, .. } => {
            6.0 * (face_patches(*position, None, grid, size) as f64).powi(2)
        }
        Light::Spot {
            position,
            direction,
            angle,
            falloff,
            ..
        } => {
            let cone = Some((*direction, *angle, *falloff));
            6.0 * (face_patches(*position, cone, grid, size) as f64).powi(2)
        }
    }
}

/// Patches along each cube-sphere face of a point light at `p` (a spot's
/// `cone`: axis, half-angle, falloff in degrees).
fn face_patches(
    p: DVec3,
    cone: Option<(DVec3, f64, f64)>,
    grid: &GridGeometry,
    size: f64,
) -> usize {
    let h = grid.voxel_size();
    let inside = grid.contains(p);
    // Nearest start radius: the sphere's patches are sized for it; patches
    // that start farther out are larger and are tessellated before the
    // first step.
    let nearest = if inside {
        INNER_RADIUS_VOXELS * h
    } else {
        (p.clamp(grid.min, grid.max) - p).length()
    }
    .max(INNER_RADIUS_VOXELS * h);
    // At least 16 patches along a cube face (5.6 degrees each): a patch is
    // flat, and must stay close to the sphere it stands for.
    let mut n = ((0.5 * PI * nearest / size).ceil() as usize).clamp(MIN_FACE_PATCHES, 4096);
    // A spot's edge is only as sharp as the emitted patches: each is in or
    // out of the cone by its centre, and its children share its weight.
    // Resolve the cone with at least 32 patches across its half-angle (and
    // 4 across a soft edge).
    if let Some((_, angle, falloff)) = cone {
        let soft = if falloff > 0.0 {
            falloff / 4.0
        } else {
            f64::INFINITY
        };
        let step = (angle / 32.0).min(soft).max(0.05).to_radians();
        n = n.max(((0.5 * PI / step).ceil() as usize).min(2048));
    }
    n
}

#[allow(clippy::too_many_arguments)]
fn spherical<F: IndexField + ?Sized>(
    p: DVec3,
    power: DVec3,
    cone: Option<(DVec3, f64, f64)>,
    grid: &GridGeometry,
    field: &F,
    size: f64,
    mask: [f64; 3],
    out: &mut Patches,
) {
    let h = grid.voxel_size();
    let inside = grid.contains(p);
    let n = face_patches(p, cone, grid, size);
    let margin = MARGIN_VOXELS * h;
    let axes = [DVec3::X, DVec3::Y, DVec3::Z];
    for face in 0..6 {
        let normal = axes[face / 2] * if face % 2 == 0 { 1.0 } else { -1.0 };
        // (e1, e2) with e1 x e2 = normal: counter-clockwise corners face out.
        let e1 = axes[(face / 2 + 1) % 3];
        let e2 = normal.cross(e1);
        let dir = |i: usize, j: usize| {
            let a = -1.0 + 2.0 * i as f64 / n as f64;
            let b = -1.0 + 2.0 * j as f64 / n as f64;
            (normal + e1 * a + e2 * b).normalize()
        };
        for j in 0..n {
            for i in 0..n {
                let ds = [dir(i, j), dir(i + 1, j), dir(i + 1, j + 1), dir(i, j + 1)];
                let mid = (ds[0] + ds[1] + ds[2] + ds[3]).normalize();
                let weight = cone_weight(mid, cone);
                if weight == 0.0 {
                    continue;
                }
                let r = if inside {
                    INNER_RADIUS_VOXELS * h
                } else {
                    match grid.clip_line(p, mid) {
                        Some((t0, t1)) if t1 > 0.0 => (t0 - margin).max(INNER_RADIUS_VOXELS * h),
                        _ => continue,
                    }
                };
                let omega = triangle_solid_angle(ds[0], ds[1], ds[2])
                    + triangle_solid_angle(ds[0], ds[2], ds[3]);
                let share = weight * omega / (4.0 * PI);
                let flux = [0, 1, 2].map(|c| power[c] * mask[c] * share);
                out.push(ds.map(|d| start(field, p + d * r, d)), flux);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Uniform;
    impl IndexField for Uniform {
        fn sample(&self, _: DVec3) -> (f64, DVec3) {
            (1.0, DVec3::ZERO)
        }
    }

    fn grid() -> GridGeometry {
        GridGeometry::new([16, 16, 16], DVec3::splat(-1.0), DVec3::splat(1.0))
    }

    #[test]
    fn cube_sphere_covers_the_sphere() {
        let mut out = Patches::default();
        let light = Light::Point {
            position: DVec3::ZERO,
            power: DVec3::new(4.0, 2.0, 1.0),
        };
        let entered = emit(&light, &grid(), &Uniform, 0.125, [1.0; 3], &mut out);
        // Inside the volume every direction enters: all the power does.
        for (e, want) in entered.iter().zip([4.0, 2.0, 1.0]) {
            assert!((e - want).abs() < 1e-12, "{e} vs {want}");
        }
        // Irradiance at the start sphere is power / (4 pi r^2) up to the
        // patches' flatness.
        let r = out.corner[0][0].x.length();
        let e = (0..out.len()).map(|i| out.irradiance(i)[0]).sum::<f64>() / out.len() as f64;
        let want = 4.0 / (4.0 * PI * r * r);
        assert!((e / want - 1.0).abs() < 0.05, "{e} vs {want}");
    }

    #[test]
    fn outside_point_light_starts_with_inverse_square_irradiance() {
        let mut out = Patches::default();
        let p = DVec3::new(0.0, 0.0, -3.0);
        let light = Light::Point {
            position: p,
            power: DVec3::splat(10.0),
        };
        emit(&light, &grid(), &Uniform, 0.0625, [1.0; 3], &mut out);
        assert!(!out.is_empty());
        for i in 0..out.len() {
            let r = (out.midpoint(i) - p).length();
            let want = 10.0 / (4.0 * PI * r * r);
            let got = out.irradiance(i)[0];
            assert!((got / want - 1.0).abs() < 0.01, "r {r}: {got} vs {want}");
            // It starts half a voxel before the bounds, along its central ray.
            let start = (out.corner[0][i].x - p).length();
            let (t0, _) = grid().clip_line(p, out.direction(i)).unwrap();
            assert!((start - (t0 - 0.5 * 0.125)).abs() < 1e-9, "{start} vs {t0}");
        }
    }

    #[test]
    fn plane_wave_carries_its_irradiance() {
        let mut out = Patches::default();
        let light = Light::Directional {
            direction: DVec3::new(0.3, -1.0, 0.2).normalize(),
            power: DVec3::new(2.0, 1.0, 0.5),
        };
        emit(&light, &grid(), &Uniform, 0.1, [1.0; 3], &mut out);
        for i in 0..out.len() {
            assert!((out.irradiance(i)[0] - 2.0).abs() < 1e-9);
            let n = crate::patch::normal(&out.positions(i)).normalize();
            assert!((n.dot(out.direction(i)) - 1.0).abs() < 1e-9);
        }
    }

    #[test]
    fn spot_cone_limits_the_power() {
        let mut out = Patches::default();
        let light = Light::Spot {
            position: DVec3::ZERO,
            direction: DVec3::Y,
            angle: 60.0,
            falloff: 0.0,
            power: DVec3::ONE,
        };
        let entered = emit(&light, &grid(), &Uniform, 0.02, [1.0; 3], &mut out);
        // A 60 degree cone holds (1 - cos 60) / 2 = 1/4 of the sphere.
        assert!((entered[0] - 0.25).abs() < 0.01, "{}", entered[0]);
    }
}
