//! Solid shapes as signed distance bounds.
//!
//! Every shape answers `distance(p)`: negative inside, positive outside, and
//! never larger in magnitude than the true Euclidean distance to its surface
//! (exact for all but the superquadric, whose bound is conservative). The
//! voxelizer uses that bound to find the cells a surface may cross, and only
//! those cells are supersampled.

use crate::mesh_solid::MeshSolid;
use crate::profile::Profile;
use crate::vdb::VdbSolid;
use glam::{DMat3, DVec2, DVec3};
use std::sync::Arc;

/// A closed solid. Local frames are rotated about the shape's own centre.
#[derive(Clone, Debug)]
pub enum Shape {
    /// Ball of `radius` about `center`.
    Sphere { center: DVec3, radius: f64 },
    /// Box with full edge lengths `size`, optionally rounded by `radius`
    /// (the rounding eats into the box, which keeps its outer size).
    Box {
        center: DVec3,
        half: DVec3,
        radius: f64,
        rot: DMat3,
    },
    /// Capped cylinder along the local y axis.
    Cylinder {
        center: DVec3,
        radius: f64,
        half_height: f64,
        rot: DMat3,
    },
    /// Solid of revolution about the local y axis through `base`: the closed
    /// polygon `profile` of (radius, height) points is swept around the axis.
    Revolution {
        base: DVec3,
        profile: Profile,
        rot: DMat3,
    },
    /// Ring torus in the local xz plane (axis along local y).
    Torus {
        center: DVec3,
        major: f64,
        minor: f64,
        rot: DMat3,
    },
    /// Barr superquadric `((|x|/a)^(2/e2) + (|z|/c)^(2/e2))^(e2/e1) + (|y|/b)^(2/e1) <= 1`.
    Superquadric {
        center: DVec3,
        radii: DVec3,
        e1: f64,
        e2: f64,
        rot: DMat3,
    },
    /// Everything on the side of the plane opposite to its unit `normal`.
    HalfSpace { point: DVec3, normal: DVec3 },
    /// Where a float grid of a VDB file exceeds a threshold.
    Vdb(Arc<VdbSolid>),
    /// Inside a closed triangle mesh.
    Mesh(Arc<MeshSolid>),
}

/// Rotation from Euler angles in degrees, applied about x, then y, then z.
pub fn rotation_from_degrees(angles: [f64; 3]) -> DMat3 {
    let [x, y, z] = angles.map(f64::to_radians);
    DMat3::from_rotation_z(z) * DMat3::from_rotation_y(y) * DMat3::from_rotation_x(x)
}

/// The local coordinates of `p` in a frame centred at `c` with rotation `rot`.
fn local(p: DVec3, c: DVec3, rot: &DMat3) -> DVec3 {
    rot.transpose() * (p - c)
}

fn box_distance(q: DVec3, half: DVec3) -> f64 {
    let d = q.abs() - half;
    d.max(DVec3::ZERO).length() + d.max_element().min(0.0)
}

impl Shape {
    /// Signed distance bound: negative inside (see the module docs).
    pub fn distance(&self, p: DVec3) -> f64 {
        match self {
            Shape::Sphere { center, radius } => (p - *center).length() - radius,
            Shape::Box {
                center,
                half,
                radius,
                rot,
            } => {
                let q = local(p, *center, rot);
                box_distance(q, *half - DVec3::splat(*radius)) - radius
            }
            Shape::Cylinder {
                center,
                radius,
                half_height,
                rot,
            } => {
                let q = local(p, *center, rot);
                let d = DVec2::new(
                    DVec2::new(q.x, q.z).length() - radius,
                    q.y.abs() - half_height,
                );
                d.max(DVec2::ZERO).length() + d.max_element().min(0.0)
            }
            Shape::Revolution { base, profile, rot } => {
                let q = local(p, *base, rot);
                let m = DVec2::new(DVec2::new(q.x, q.z).length(), q.y);
                polygon_distance(profile, m)
            }
            Shape::Torus {
                center,
                major,
                minor,
                rot,
            } => {
                let q = local(p, *center, rot);
                DVec2::new(DVec2::new(q.x, q.z).length() - major, q.y).length() - minor
            }
            Shape::Superquadric {
                center,
                radii,
                e1,
                e2,
                rot,
            } => {
                let q = local(p, *center, rot) / *radii;
                let xz = q.x.abs().powf(2.0 / e2) + q.z.abs().powf(2.0 / e2);
                // x^1 is x (IEEE 754's pow is exact there): one `pow` fewer
                // for the usual e1 = e2, the same bits.
                let xz = if e1 == e2 { xz } else { xz.powf(e2 / e1) };
                let f = xz + q.y.abs().powf(2.0 / e1);
                // g = f^(e1/2) is positively 1-homogeneous in the scaled
                // coordinates. With both exponents at most 2 it is the gauge
                // of a convex body holding the octahedron |x|+|y|+|z| <= 1,
                // whose inscribed ball has radius 1/sqrt(3): g is then
                // sqrt(3)-Lipschitz there, and (g - 1) * smallest radius /
                // sqrt(3) bounds the distance; the factor 1/2 is below that.
                // The pinched (e > 2) shapes have no such bound: the march
                // takes a fraction of this one, in short steps
                // (`Shape::march`).
                (f.powf(e1 / 2.0) - 1.0) * radii.min_element() * 0.5
            }
            Shape::HalfSpace { point, normal } => (p - *point).dot(*normal),
            Shape::Vdb(solid) => solid.distance(p),
            Shape::Mesh(solid) => solid.distance(p),
        }
    }

    /// Whether `p` is inside the solid.
    pub fn contains(&self, p: DVec3) -> bool {
        match self {
            Shape::Vdb(solid) => solid.contains(p),
            Shape::Mesh(solid) => solid.contains(p),
            Shape::Revolution { base, profile, rot } => {
                let q = local(p, *base, rot);
                polygon_contains(profile, DVec2::new(DVec2::new(q.x, q.z).length(), q.y))
            }
            _ => self.distance(p) < 0.0,
        }
    }

    /// World-space axis-aligned bounding box, or `None` when unbounded.
    pub fn aabb(&self) -> Option<(DVec3, DVec3)> {
        let rotated_box = |c: DVec3, half: DVec3, rot: &DMat3| {
            let m = DMat3::from_cols(rot.x_axis.abs(), rot.y_axis.abs(), rot.z_axis.abs());
            let e = m * half;
            (c - e, c + e)
        };
        match self {
            Shape::Sphere { center, radius } => Some((
                *center - DVec3::splat(*radius),
                *center + DVec3::splat(*radius),
            )),
            Shape::Box {
                center, half, rot, ..
            } => Some(rotated_box(*center, *half, rot)),
            Shape::Cylinder {
                center,
                radius,
                half_height,
                rot,
            } => Some(rotated_box(
                *center,
                DVec3::new(*radius, *half_height, *radius),
                rot,
            )),
            Shape::Revolution { base, profile, rot } => {
                let r = profile.iter().map(|q| q.x).fold(0.0, f64::max);
                let y0 = profile.iter().map(|q| q.y).fold(f64::INFINITY, f64::min);
                let y1 = profile
                    .iter()
                    .map(|q| q.y)
                    .fold(f64::NEG_INFINITY, f64::max);
                let c = *base + *rot * DVec3::new(0.0, 0.5 * (y0 + y1), 0.0);
                Some(rotated_box(c, DVec3::new(r, 0.5 * (y1 - y0), r), rot))
            }
            Shape::Torus {
                center,
                major,
                minor,
                rot,
            } => Some(rotated_box(
                *center,
                DVec3::new(major + minor, *minor, major + minor),
                rot,
            )),
            Shape::Superquadric {
                center, radii, rot, ..
            } => Some(rotated_box(*center, *radii, rot)),
            Shape::HalfSpace { .. } => None,
            Shape::Vdb(solid) => solid.aabb(),
            Shape::Mesh(solid) => Some(solid.aabb()),
        }
    }

    /// Short name used in listings.
    pub fn kind(&self) -> &'static str {
        match self {
            Shape::Sphere { .. } => "sphere",
            Shape::Box { radius, .. } if *radius > 0.0 => "rounded box",
            Shape::Box { .. } => "box",
            Shape::Cylinder { .. } => "cylinder",
            Shape::Revolution { .. } => "solid of revolution",
            Shape::Torus { .. } => "torus",
            Shape::Superquadric { .. } => "superquadric",
            Shape::HalfSpace { .. } => "half-space",
            Shape::Vdb(_) => "VDB grid",
            Shape::Mesh(_) => "triangle mesh",
        }
    }
}

/// Signed distance from `p` to the closed polygon `poly` (negative inside),
/// using the even-odd rule for the inside test.
/// `polygon_distance(poly, p) < 0` without the distances: inside by the
/// crossing rule and not on an edge, where the distance would be zero. Only
/// an edge whose heights span `p.y` can pass through `p`, so only those are
/// measured.
fn polygon_contains(poly: &Profile, p: DVec2) -> bool {
    // The edges filed at p's height: every edge that spans it, the only
    // ones either test below can count.
    let edges = poly.edges_at(p.y);
    let mut inside = false;
    for &i in edges {
        let (a, b) = poly.edge(i as usize);
        if (a.y > p.y) != (b.y > p.y) && p.x < a.x + (p.y - a.y) / (b.y - a.y) * (b.x - a.x) {
            inside = !inside;
        }
    }
    inside
        && edges.iter().all(|&i| {
            let (a, b) = poly.edge(i as usize);
            if p.y < a.y.min(b.y) || p.y > a.y.max(b.y) {
                return true;
            }
            let e = b - a;
            let w = p - a;
            let t = (w.dot(e) / e.length_squared()).clamp(0.0, 1.0);
            // NaN for a repeated vertex, which the distance ignores too.
            (w - e * t).length_squared() != 0.0
        })
}

fn polygon_distance(poly: &[DVec2], p: DVec2) -> f64 {
    let mut d2 = f64::INFINITY;
    let mut inside = false;
    let n = poly.len();
    for i in 0..n {
        let a = poly[i];
        let b = poly[(i + 1) % n];
        let e = b - a;
        let w = p - a;
        let t = (w.dot(e) / e.length_squared()).clamp(0.0, 1.0);
        d2 = d2.min((w - e * t).length_squared());
        if (a.y > p.y) != (b.y > p.y) && p.x < a.x + (p.y - a.y) / (b.y - a.y) * e.x {
            inside = !inside;
        }
    }
    if inside {
        -d2.sqrt()
    } else {
        d2.sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polygon_contains_is_the_sign_of_the_distance() {
        // A wine-glass outline with a repeated vertex; points on a lattice
        // that hits vertices and edges exactly, and scattered ones.
        let poly: Profile = Profile::new(
            [
                [0.0, 0.0],
                [0.3, 0.0],
                [0.3, 0.025],
                [0.06, 0.05],
                [0.04, 0.1],
                [0.04, 0.5],
                [0.04, 0.5],
                [0.25, 0.7],
                [0.27, 1.3],
                [0.245, 1.3],
                [0.0, 0.575],
            ]
            .iter()
            .map(|&[x, y]| DVec2::new(x, y))
            .collect(),
        );
        let mut checked = (0, 0);
        for i in -4..=70 {
            for j in -4..=280 {
                let p = DVec2::new(i as f64 * 0.005, j as f64 * 0.005);
                let q = p + DVec2::new(0.00123 * (j % 7) as f64, 0.00071 * (i % 5) as f64);
                for p in [p, q] {
                    let inside = polygon_distance(&poly, p) < 0.0;
                    assert_eq!(polygon_contains(&poly, p), inside, "{p}");
                    if inside {
                        checked.0 += 1;
                    } else {
                        checked.1 += 1;
                    }
                }
            }
        }
        assert!(checked.0 > 1000 && checked.1 > 1000, "{checked:?}");
        for v in poly.iter() {
            assert!(!polygon_contains(&poly, *v));
        }
    }

    #[test]
    fn distances_have_the_right_sign_and_size() {
        let s = Shape::Sphere {
            center: DVec3::ZERO,
            radius: 1.0,
        };
        assert!((s.distance(DVec3::new(2.0, 0.0, 0.0)) - 1.0).abs() < 1e-12);
        let b = Shape::Box {
            center: DVec3::ZERO,
            half: DVec3::ONE,
            radius: 0.0,
            rot: DMat3::IDENTITY,
        };
        assert!((b.distance(DVec3::new(0.5, 0.0, 0.0)) + 0.5).abs() < 1e-12);
        let t = Shape::Torus {
            center: DVec3::ZERO,
            major: 1.0,
            minor: 0.25,
            rot: DMat3::IDENTITY,
        };
        assert!(t.contains(DVec3::new(1.0, 0.0, 0.0)));
        assert!(!t.contains(DVec3::ZERO));
        // A cylinder profile swept about y is a cylinder.
        let r = Shape::Revolution {
            base: DVec3::ZERO,
            profile: Profile::new(vec![
                DVec2::new(0.0, 0.0),
                DVec2::new(1.0, 0.0),
                DVec2::new(1.0, 2.0),
                DVec2::new(0.0, 2.0),
            ]),
            rot: DMat3::IDENTITY,
        };
        assert!((r.distance(DVec3::new(0.0, 1.0, 3.0)) - 2.0).abs() < 1e-12);
        assert!((r.distance(DVec3::new(0.5, 1.0, 0.0)) + 0.5).abs() < 1e-12);
        let q = Shape::Superquadric {
            center: DVec3::ZERO,
            radii: DVec3::ONE,
            e1: 1.0,
            e2: 1.0,
            rot: DMat3::IDENTITY,
        };
        // e1 = e2 = 1 is the unit ball; the bound may only under-estimate.
        let d = q.distance(DVec3::new(2.0, 0.0, 0.0));
        assert!(d > 0.0 && d <= 1.0);
    }

    #[test]
    fn rotated_aabb_contains_the_solid() {
        let rot = rotation_from_degrees([30.0, 45.0, 10.0]);
        let c = Shape::Cylinder {
            center: DVec3::new(0.2, 0.1, 0.0),
            radius: 0.3,
            half_height: 0.5,
            rot,
        };
        let (lo, hi) = c.aabb().unwrap();
        for i in 0..2000 {
            let f = |k: u32| ((i * 7919 + k * 104729) % 1000) as f64 / 1000.0;
            let p = DVec3::new(f(1), f(2), f(3)) * 2.0 - 1.0;
            if c.contains(p) {
                assert!(p.cmpge(lo).all() && p.cmple(hi).all());
            }
        }
    }
}
