//! The refractor: a scene's one object as a closed triangle mesh, with the
//! shading normals the raster passes interpolate and the per-vertex
//! distance `d_N` of [Wyman06 eq 6.3.1], its index and extinction.
//!
//! Mesh objects (`mesh`, `bumpy_sphere`, `cuboctahedron`) are taken as
//! they are, shaded smooth or faceted as the scene says. Constant-index
//! analytic solids are meshed on the fly at a fixed tessellation:
//!
//! | shape | mesh | shading |
//! |---|---|---|
//! | `sphere` | geodesic sphere, [`SPHERE_FREQUENCY`] (20 f^2 = 20480 triangles), exact normals | smooth |
//! | `box` (no rounding) | 12 triangles | faceted |
//! | `cylinder`, `revolution` | solid of revolution, [`SEGMENTS`] segments | smooth within [`CREASE_DEGREES`], creased at sharper edges (a cylinder's rims) |
//! | `torus` | solid of revolution of a [`TORUS_PROFILE`]-gon, [`SEGMENTS`] segments | smooth |
//!
//! Everything else (rounded boxes, superquadrics, half-spaces, VDB grids,
//! graded or dispersive indices, grid-valued extinction, more than one
//! object, a medium outside that is not clear and of one index) is refused
//! with an error naming the scene field.

use crate::WymanError;
use eikon_grid::{IndexProfile, Scene, Shape};
use eikon_mesh::{cuboid, geodesic_sphere, revolution, Bvh, Mesh, Ray};
use glam::{DAffine3, DVec2, DVec3};

/// Frequency of the geodesic sphere an analytic sphere becomes.
pub const SPHERE_FREQUENCY: u32 = 32;

/// Segments around the axis of a meshed cylinder, solid of revolution or
/// torus.
pub const SEGMENTS: u32 = 128;

/// Points of the circle a torus's tube is swept from.
pub const TORUS_PROFILE: usize = 48;

/// Edges between faces whose normals differ by more than this are kept
/// sharp on meshed solids of revolution (a cylinder's rims); gentler ones
/// are smoothed.
pub const CREASE_DEGREES: f64 = 40.0;

/// How the raster passes shade the mesh.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shading {
    /// The mesh's vertex normals, interpolated.
    Smooth,
    /// Each triangle's face normal.
    Flat,
    /// Per triangle corner, the angle-weighted face normals around the
    /// vertex within this angle (degrees) of the triangle's own.
    Crease(f64),
}

/// The object the image-space method refracts through.
#[derive(Clone, Debug)]
pub struct Refractor {
    /// The closed, outward boundary.
    pub mesh: Mesh,
    /// How it is shaded.
    pub shading: Shading,
    /// Refractive index inside.
    pub inside: f64,
    /// Refractive index outside (the scene's ambient).
    pub outside: f64,
    /// Extinction sigma_t inside, RGB, per world unit.
    pub extinction: DVec3,
    /// What the method leaves out for this object (said to the user).
    pub unhandled: Vec<String>,
    bvh: Bvh,
}

/// One corner of a triangle as the raster passes read it (vertex pulling):
/// position and `d_N`, then the unit shading normal.
pub type Corner = [[f32; 4]; 2];

impl Refractor {
    /// A refractor from a closed mesh.
    pub fn new(
        mesh: Mesh,
        shading: Shading,
        inside: f64,
        outside: f64,
        extinction: DVec3,
    ) -> Result<Refractor, WymanError> {
        mesh.require_closed()?;
        let bvh = Bvh::new(&mesh);
        Ok(Refractor {
            mesh,
            shading,
            inside,
            outside,
            extinction,
            unhandled: Vec::new(),
            bvh,
        })
    }

    /// The scene's one object, if the method can render it (module docs).
    pub fn from_scene(scene: &Scene) -> Result<Refractor, WymanError> {
        let err = |field: &str, msg: String| WymanError::Scene(scene.error_at(field, msg));
        let Some(o) = scene.objects.first() else {
            return Err(err(
                "object",
                "the image-space method (wyman) refracts through one object; this scene has none"
                    .into(),
            ));
        };
        if scene.objects.len() > 1 {
            return Err(err(
                "object[1]",
                format!(
                    "the image-space method (wyman) refracts through one object; this scene has {} (use --method eikonal)",
                    scene.objects.len()
                ),
            ));
        }
        let amb = &scene.ambient;
        let outside = match amb.index {
            IndexProfile::Constant([a, b, c]) if a == b && b == c && amb.index_grid.is_none() => a,
            _ => {
                return Err(err(
                    "ambient.index",
                    "the image-space method (wyman) needs one constant ambient index".into(),
                ))
            }
        };
        if amb.extinction != DVec3::ZERO || amb.extinction_grid.is_some() {
            return Err(err(
                "ambient.extinction",
                "the image-space method (wyman) needs a clear ambient medium (extinction 0)".into(),
            ));
        }
        let m = &o.material;
        let inside = match m.index {
            IndexProfile::Constant([a, b, c]) if a == b && b == c && m.index_grid.is_none() => a,
            IndexProfile::Constant(_) if m.index_grid.is_none() => {
                return Err(err(
                    "object[0].index",
                    "the image-space method (wyman) takes one index; dispersion needs --method eikonal".into(),
                ))
            }
            _ => {
                return Err(err(
                    "object[0].index",
                    "the image-space method (wyman) needs a constant index; a graded index needs --method eikonal".into(),
                ))
            }
        };
        if m.extinction_grid.is_some() {
            return Err(err(
                "object[0].extinction",
                "the image-space method (wyman) needs a constant extinction".into(),
            ));
        }
        let (mesh, shading) = mesh_of(&o.shape)
            .map_err(|(field, msg)| err(&format!("object[0].shape{}", field), msg))?;
        let mut r = Refractor::new(mesh, shading, inside, outside, m.extinction)
            .map_err(|e| err("object[0].shape", e.to_string()))?;
        if m.albedo.max_element() > 0.0 && m.extinction.max_element() > 0.0 {
            r.unhandled.push(format!(
                "object[0].albedo: the image-space method renders no scattering; {} only attenuates (sigma_t)",
                o.name
            ));
        }
        if m.emission.max_element() > 0.0 {
            r.unhandled.push(format!(
                "object[0].emission: the image-space method renders no emission; {} is dark inside",
                o.name
            ));
        }
        Ok(r)
    }

    /// The ray-casting hierarchy over the mesh.
    pub fn bvh(&self) -> &Bvh {
        &self.bvh
    }

    /// Centre and radius of a sphere around the mesh (its bounding box's).
    pub fn bounding_sphere(&self) -> (DVec3, f64) {
        let (lo, hi) = self.mesh.bounds();
        let c = 0.5 * (lo + hi);
        let r = self
            .mesh
            .positions()
            .iter()
            .map(|p| (*p - c).length())
            .fold(0.0, f64::max);
        (c, r.max(1e-300))
    }

    /// Whether `p` lies inside the mesh (the first surface met along a
    /// fixed direction is left, not entered).
    pub fn contains(&self, p: DVec3) -> bool {
        let d = DVec3::new(0.267_261, 0.534_522, 0.801_784);
        self.bvh
            .closest_hit(&Ray::new(p, d))
            .is_some_and(|h| !h.entering(d))
    }

    /// The shading normal of each corner of triangle `t`.
    fn corner_normals(&self, t: usize, faces: &[DVec3], around: &[Vec<u32>]) -> [DVec3; 3] {
        let tri = self.mesh.triangles()[t];
        match self.shading {
            Shading::Smooth => tri.map(|v| self.mesh.normals()[v as usize]),
            Shading::Flat => [faces[t]; 3],
            Shading::Crease(deg) => {
                let cos = deg.to_radians().cos();
                let mut out = [DVec3::ZERO; 3];
                for (k, &v) in tri.iter().enumerate() {
                    let mut sum = DVec3::ZERO;
                    for &u in &around[v as usize] {
                        let u = u as usize;
                        if faces[u].dot(faces[t]) >= cos {
                            sum += faces[u] * corner_angle(&self.mesh, u, v);
                        }
                    }
                    out[k] = sum.try_normalize().unwrap_or(faces[t]);
                }
                out
            }
        }
    }

    /// The corners the raster passes draw, three per triangle in mesh
    /// order: position with `d_N`, and the shading normal. `d_N` is the
    /// distance from the corner along its inward normal to the far side of
    /// the mesh, ray cast once here, as the paper precomputes it ("We
    /// precomputed d_N via ray tracing and stored it in the surface
    /// normal's w-component").
    pub fn corners(&self) -> Vec<Corner> {
        let mesh = &self.mesh;
        let faces: Vec<DVec3> = (0..mesh.triangle_count())
            .map(|t| mesh.face_normal(t))
            .collect();
        let mut around: Vec<Vec<u32>> = vec![Vec::new(); mesh.vertex_count()];
        if matches!(self.shading, Shading::Crease(_)) {
            for (t, tri) in mesh.triangles().iter().enumerate() {
                for &v in tri {
                    around[v as usize].push(t as u32);
                }
            }
        }
        let (_, radius) = self.bounding_sphere();
        let eps = 1e-9 * radius;
        let mut out = Vec::with_capacity(3 * mesh.triangle_count());
        for t in 0..mesh.triangle_count() {
            let p = mesh.corners(t);
            let centroid = (p[0] + p[1] + p[2]) / 3.0;
            let normals = self.corner_normals(t, &faces, &around);
            for k in 0..3 {
                // Start a hair inside the triangle, so that a ray from a
                // corner on a sharp edge does not run along the next face.
                let o = p[k] + 1e-6 * (centroid - p[k]);
                let d = -normals[k];
                let d_n = self
                    .bvh
                    .closest_hit(&Ray::segment(o, d, eps, f64::INFINITY))
                    .map_or(0.0, |h| h.t);
                let (q, n) = (p[k].as_vec3(), normals[k].as_vec3());
                out.push([[q.x, q.y, q.z, d_n as f32], [n.x, n.y, n.z, 0.0]]);
            }
        }
        out
    }
}

/// The interior angle of triangle `t` at vertex `v`.
fn corner_angle(mesh: &Mesh, t: usize, v: u32) -> f64 {
    let tri = mesh.triangles()[t];
    let k = tri.iter().position(|&x| x == v).unwrap_or(0);
    let p = mesh.corners(t);
    let a = (p[(k + 1) % 3] - p[k]).normalize_or_zero();
    let b = (p[(k + 2) % 3] - p[k]).normalize_or_zero();
    a.dot(b).clamp(-1.0, 1.0).acos()
}

/// The mesh and shading of a shape, or the field (below `shape`) that
/// makes it unsupported and why.
fn mesh_of(shape: &Shape) -> Result<(Mesh, Shading), (String, String)> {
    let mesh_err = |e: eikon_mesh::MeshError| (String::new(), e.to_string());
    let placed = |mut m: Mesh, rot: glam::DMat3, at: DVec3| -> Result<Mesh, (String, String)> {
        m.transform(DAffine3::from_mat3_translation(rot, at))
            .map_err(mesh_err)?;
        Ok(m)
    };
    let crease = Shading::Crease(CREASE_DEGREES);
    match shape {
        Shape::Mesh(solid) => Ok((
            (**solid.mesh()).clone(),
            if solid.smooth() {
                Shading::Smooth
            } else {
                Shading::Flat
            },
        )),
        Shape::Sphere { center, radius } => {
            let m = geodesic_sphere(*radius, SPHERE_FREQUENCY).map_err(mesh_err)?;
            Ok((
                placed(m, glam::DMat3::IDENTITY, *center)?,
                Shading::Smooth,
            ))
        }
        Shape::Box {
            center,
            half,
            radius,
            rot,
        } => {
            if *radius > 0.0 {
                return Err((
                    ".radius".into(),
                    "the image-space method (wyman) meshes sharp boxes only; a rounded box needs --method eikonal".into(),
                ));
            }
            let m = cuboid(*half).map_err(mesh_err)?;
            Ok((placed(m, *rot, *center)?, Shading::Flat))
        }
        Shape::Cylinder {
            center,
            radius,
            half_height,
            rot,
        } => {
            let (r, h) = (*radius, *half_height);
            let profile = [
                DVec2::new(0.0, -h),
                DVec2::new(r, -h),
                DVec2::new(r, h),
                DVec2::new(0.0, h),
            ];
            let m = revolution(&profile, SEGMENTS).map_err(mesh_err)?;
            Ok((placed(m, *rot, *center)?, crease))
        }
        Shape::Revolution { base, profile, rot } => {
            let m = revolution(profile, SEGMENTS).map_err(mesh_err)?;
            Ok((placed(m, *rot, *base)?, crease))
        }
        Shape::Torus {
            center,
            major,
            minor,
            rot,
        } => {
            let profile: Vec<DVec2> = (0..TORUS_PROFILE)
                .map(|i| {
                    let a = std::f64::consts::TAU * i as f64 / TORUS_PROFILE as f64;
                    DVec2::new(major + minor * a.cos(), minor * a.sin())
                })
                .collect();
            let m = revolution(&profile, SEGMENTS).map_err(mesh_err)?;
            Ok((placed(m, *rot, *center)?, crease))
        }
        Shape::Superquadric { .. } | Shape::HalfSpace { .. } | Shape::Vdb(_) => Err((
            ".type".into(),
            "the image-space method (wyman) refracts through meshes, spheres, sharp boxes, cylinders, solids of revolution and tori; this shape needs --method eikonal".into(),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(object: &str, extra: &str) -> Scene {
        let text = format!(
            "[grid]\nresolution = 8\nmin = [-1.0, -1.0, -1.0]\nmax = [1.0, 1.0, 1.0]\n{extra}\n[[object]]\n{object}\n"
        );
        Scene::parse(&text, "s.toml").unwrap()
    }

    fn refused(object: &str, extra: &str, field: &str) {
        let e = Refractor::from_scene(&scene(object, extra))
            .unwrap_err()
            .to_string();
        assert!(e.contains("s.toml") && e.contains(field), "{field}: {e}");
    }

    #[test]
    fn constant_index_solids_are_meshed_closed() {
        for (shape, triangles) in [
            ("{ type = \"sphere\", center = [0.1, 0.0, 0.0], radius = 0.5 }", 20 * 32 * 32),
            ("{ type = \"box\", center = [0.0, 0.0, 0.0], size = [0.5, 0.4, 0.3], rotation = [10.0, 20.0, 30.0] }", 12),
            ("{ type = \"cylinder\", center = [0.0, 0.0, 0.0], radius = 0.3, height = 0.8 }", 4 * 128),
            ("{ type = \"torus\", center = [0.0, 0.0, 0.0], major_radius = 0.5, minor_radius = 0.2 }", 2 * 48 * 128),
        ] {
            let s = scene(&format!("shape = {shape}\nindex = 1.5"), "");
            let r = Refractor::from_scene(&s).unwrap();
            assert_eq!(r.mesh.triangle_count(), triangles, "{shape}");
            r.mesh.require_closed().unwrap();
            assert_eq!((r.inside, r.outside), (1.5, 1.0));
            // Every corner's d_N runs to the far side: positive, within
            // the object's diameter.
            let (_, radius) = r.bounding_sphere();
            assert!(r
                .corners()
                .iter()
                .all(|c| c[0][3] > 0.0 && f64::from(c[0][3]) <= 2.0 * radius * 1.0001));
        }
        // The cylinder's rims stay sharp: cap corners face along the axis.
        let s = scene(
            "shape = { type = \"cylinder\", center = [0.0, 0.0, 0.0], radius = 0.3, height = 0.8 }\nindex = 1.5",
            "",
        );
        let r = Refractor::from_scene(&s).unwrap();
        let caps = r
            .corners()
            .iter()
            .filter(|c| (c[0][1].abs() - 0.4).abs() < 1e-6 && c[1][1].abs() > 0.999)
            .count();
        assert!(caps >= 2 * 128, "{caps}");
    }

    #[test]
    fn what_the_method_cannot_do_is_refused_by_field() {
        let glass = "index = 1.5";
        refused(
            &format!("shape = {{ type = \"rounded_box\", center = [0.0, 0.0, 0.0], size = [0.5, 0.5, 0.5], radius = 0.1 }}\n{glass}"),
            "",
            "object[0].shape.radius",
        );
        refused(
            &format!("shape = {{ type = \"superquadric\", center = [0.0, 0.0, 0.0], radii = [0.3, 0.3, 0.3], exponents = [0.5, 0.5] }}\n{glass}"),
            "",
            "object[0].shape.type",
        );
        refused(
            "shape = { type = \"sphere\", center = [0.0, 0.0, 0.0], radius = 0.5 }\nindex = [1.5, 1.51, 1.52]",
            "dispersion = true",
            "object[0].index",
        );
        refused(
            "shape = { type = \"sphere\", center = [0.0, 0.0, 0.0], radius = 0.5 }\nindex = { type = \"luneburg\", outer = 1.0 }",
            "",
            "object[0].index",
        );
        refused(
            &format!("shape = {{ type = \"sphere\", center = [0.0, 0.0, 0.0], radius = 0.5 }}\n{glass}\n[[object]]\nshape = {{ type = \"sphere\", center = [0.5, 0.0, 0.0], radius = 0.2 }}\n{glass}"),
            "",
            "object[1]",
        );
        refused(
            &format!(
                "shape = {{ type = \"sphere\", center = [0.0, 0.0, 0.0], radius = 0.5 }}\n{glass}"
            ),
            "[ambient]\nindex = 1.0\nextinction = [0.1, 0.1, 0.1]",
            "ambient.extinction",
        );
    }

    #[test]
    fn scattering_and_emission_are_said_to_be_left_out() {
        let s = scene(
            "shape = { type = \"sphere\", center = [0.0, 0.0, 0.0], radius = 0.5 }\nindex = 1.5\nextinction = [1.0, 1.0, 1.0]\nalbedo = [0.5, 0.5, 0.5]\nemission = [0.1, 0.1, 0.1]",
            "",
        );
        let r = Refractor::from_scene(&s).unwrap();
        assert_eq!(r.unhandled.len(), 2);
        assert!(
            r.unhandled[0].contains("object[0].albedo")
                && r.unhandled[1].contains("object[0].emission")
        );
    }
}
