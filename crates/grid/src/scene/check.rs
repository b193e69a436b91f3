//! The checks of a scene file: every value read by [`super::raw`] is
//! checked (finite, in range, consistent) and turned into the public
//! types; every error is located ([`super::locate`]).

use super::assets::{attach_grids, load_mesh, mesh_shape, Volumes};
use super::locate::{Checker, Seg};
use super::raw::*;
use super::{
    Background, CameraSettings, GridSettings, Light, Receiver, RenderSettings, Scene,
    MAX_CELL_ASPECT, MAX_COORDINATE, MAX_EXTINCTION, MAX_LIGHT_POWER,
};
use crate::error::Result;
use crate::geometry::GridGeometry;
use crate::object::{IndexProfile, Material, Object};
use crate::shape::{rotation_from_degrees, Shape};
use crate::vdb::VdbSolid;
use glam::{DVec2, DVec3};
use std::path::Path;
use std::sync::Arc;

/// Check every value of `raw`, the file `c` reads, into a [`Scene`].
pub(super) fn scene(raw: RawScene, c: &Checker) -> Result<Scene> {
    use Seg::{Index as I, Key as K};
    let grid = check_grid(c, &raw.grid)?;
    let a = &raw.ambient;
    if let RawIndex::Profile(_) = a.index {
        return Err(c.err(
            &[K("ambient"), K("index")],
            "the ambient index must be a number (or [r, g, b] with dispersion)",
        ));
    }
    let ambient = check_material(c, &grid, &[K("ambient")], a.fields(), None)?;
    let mut objects = Vec::with_capacity(raw.objects.len());
    let mut volumes = Volumes::default();
    for (i, o) in raw.objects.iter().enumerate() {
        let shape = check_shape(c, &[K("object"), I(i), K("shape")], &o.shape, &mut volumes)?;
        let mut material =
            check_material(c, &grid, &[K("object"), I(i)], o.fields(), Some(&shape))?;
        attach_grids(c, &mut volumes, i, o, &mut material)?;
        objects.push(Object {
            name: o.name.clone().unwrap_or_else(|| format!("object{i}")),
            shape,
            material,
            priority: o.priority,
        });
    }
    let lights = (raw.lights.iter().enumerate())
        .map(|(i, l)| check_light(c, i, l))
        .collect::<Result<Vec<_>>>()?;
    let receiver = match &raw.receiver {
        None => None,
        Some(r) => Some(Receiver {
            point: c.vec3(&[K("receiver"), K("point")], r.point)?,
            normal: c.unit(&[K("receiver"), K("normal")], r.normal)?,
            albedo: c.rgb_in(&[K("receiver"), K("albedo")], r.albedo, 0.0, 1.0)?,
        }),
    };

    let camera = raw
        .camera
        .as_ref()
        .map(|r| check_camera(c, r))
        .transpose()?;
    let background = match &raw.background {
        None => Background::Sky { intensity: 1.0 },
        Some(b) => check_background(c, b)?,
    };
    let render = match &raw.render {
        None => RenderSettings::default(),
        Some(r) => check_render(c, r)?,
    };

    // Highest priority first; among equals the later object first.
    let mut precedence: Vec<usize> = (0..objects.len()).rev().collect();
    precedence.sort_by_key(|&i| std::cmp::Reverse(objects[i].priority));

    Ok(Scene {
        origin: c.origin.to_string(),
        text: c.text.to_string(),
        grid,
        ambient,
        objects,
        precedence,
        lights,
        receiver,
        camera,
        background,
        render,
    })
}

/// The checks of single values, each error located at `path`.
impl Checker<'_> {
    pub(super) fn finite(&self, path: &[Seg], v: &[f64]) -> Result<()> {
        if v.iter().all(|x| x.is_finite()) {
            Ok(())
        } else {
            Err(self.err(path, "must be a finite number (not NaN or infinity)"))
        }
    }

    pub(super) fn vec3(&self, path: &[Seg], v: [f64; 3]) -> Result<DVec3> {
        self.finite(path, &v)?;
        Ok(DVec3::from_array(v))
    }

    pub(super) fn positive(&self, path: &[Seg], v: f64) -> Result<f64> {
        self.finite(path, &[v])?;
        if v > 0.0 {
            Ok(v)
        } else {
            Err(self.err(path, format!("must be > 0, got {v}")))
        }
    }

    pub(super) fn unit(&self, path: &[Seg], v: [f64; 3]) -> Result<DVec3> {
        let d = self.vec3(path, v)?;
        if d.length() > 0.0 {
            Ok(d.normalize())
        } else {
            Err(self.err(path, "must be a non-zero vector"))
        }
    }

    pub(super) fn rgb_in(&self, path: &[Seg], v: [f64; 3], lo: f64, hi: f64) -> Result<DVec3> {
        let d = self.vec3(path, v)?;
        if v.iter().all(|x| (lo..=hi).contains(x)) {
            Ok(d)
        } else {
            Err(self.err(
                path,
                format!("each component must lie in [{lo}, {hi}], got {v:?}"),
            ))
        }
    }

    pub(super) fn index_value(&self, path: &[Seg], n: f64) -> Result<f64> {
        self.finite(path, &[n])?;
        if n > 0.0 {
            Ok(n)
        } else {
            Err(self.err(path, format!("refractive index must be > 0, got {n}")))
        }
    }
}

/// The optical fields an object and the ambient medium share.
struct MaterialFields<'a> {
    index: &'a RawIndex,
    extinction: [f64; 3],
    albedo: [f64; 3],
    g: f64,
    emission: [f64; 3],
}

/// `fields()` for the two raw types that carry a material.
macro_rules! material_fields {
    ($($raw:ty),*) => {$(
        impl $raw {
            fn fields(&self) -> MaterialFields<'_> {
                MaterialFields {
                    index: &self.index,
                    extinction: ConstantRgb::rgb(&self.extinction),
                    albedo: self.albedo,
                    g: self.g,
                    emission: self.emission,
                }
            }
        }
    )*};
}
material_fields!(RawAmbient, RawObject);

fn check_grid(c: &Checker, g: &RawGrid) -> Result<GridSettings> {
    use Seg::Key as K;
    let min = c.vec3(&[K("grid"), K("min")], g.min)?;
    let max = c.vec3(&[K("grid"), K("max")], g.max)?;
    if !(max.cmpgt(min).all()) {
        return Err(c.err(
            &[K("grid"), K("max")],
            format!("must exceed grid.min on every axis ({max} vs {min})"),
        ));
    }
    for (key, v) in [("min", min), ("max", max)] {
        if v.abs().max_element() > MAX_COORDINATE {
            return Err(c.err(
                &[K("grid"), K(key)],
                format!(
                    "coordinates beyond +-{MAX_COORDINATE:e} world units ({v}): use a smaller unit"
                ),
            ));
        }
    }
    let extent = max - min;
    let res = &[K("grid"), K("resolution")];
    let dims = match g.resolution {
        RawResolution::Longest(n) => {
            if n == 0 {
                return Err(c.err(res, "must be at least 1"));
            }
            let h = extent.max_element() / n as f64;
            let d = (extent / h).round().max(DVec3::ONE);
            [d.x as u64, d.y as u64, d.z as u64]
        }
        RawResolution::PerAxis(d) => {
            if d.contains(&0) {
                return Err(c.err(res, "every axis needs at least 1 voxel"));
            }
            d
        }
    };
    let dims = dims.map(|d| usize::try_from(d).unwrap_or(usize::MAX));
    if dims
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .is_none()
    {
        return Err(c.err(res, format!("{dims:?} voxels cannot even be counted")));
    }
    // Cells far from cubic make the voxel size (the smallest edge) that
    // steps and patches are measured in meaningless along the long edges,
    // and the work of crossing the grid unbounded.
    let spacing = extent / DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
    let aspect = spacing.max_element() / spacing.min_element();
    if aspect.is_nan() || aspect > MAX_CELL_ASPECT {
        return Err(c.err(
            res,
            format!(
                "cells of {:?} voxels over {extent} are {aspect:.3e} times longer on one axis than on another (at most {MAX_CELL_ASPECT}): give each axis voxels in proportion to its extent",
                dims
            ),
        ));
    }
    let smoothing = g.smoothing;
    c.finite(&[K("grid"), K("smoothing")], &[smoothing])?;
    if !(0.0..=8.0).contains(&smoothing) {
        return Err(c.err(
            &[K("grid"), K("smoothing")],
            format!("sigma in voxels must lie in [0, 8], got {smoothing}"),
        ));
    }
    if !(1..=16).contains(&g.supersample) {
        return Err(c.err(
            &[K("grid"), K("supersample")],
            format!(
                "must lie in 1..=16 sub-samples per axis, got {}",
                g.supersample
            ),
        ));
    }
    Ok(GridSettings {
        geometry: GridGeometry::new(dims, min, max),
        smoothing,
        supersample: g.supersample as usize,
        dispersion: g.dispersion,
        interfaces: g.interfaces,
    })
}

/// The index profile at field path `ip`; `shape` is the object's (None for
/// the ambient medium).
fn check_index(
    c: &Checker,
    grid: &GridSettings,
    ip: &[Seg],
    index: &RawIndex,
    shape: Option<&Shape>,
) -> Result<IndexProfile> {
    let sub = |k| [ip, &[Seg::Key(k)]].concat();
    Ok(match index {
        RawIndex::Scalar(n) => IndexProfile::Constant([c.index_value(ip, *n)?; 3]),
        RawIndex::Rgb(n) => {
            if !grid.dispersion {
                return Err(c.err(ip, "an [r, g, b] index needs grid.dispersion = true"));
            }
            for &v in n {
                c.index_value(ip, v)?;
            }
            IndexProfile::Constant(*n)
        }
        RawIndex::Profile(RawProfile::Luneburg { outer }) => {
            let outer = c.index_value(&sub("outer"), *outer)?;
            match shape {
                Some(Shape::Sphere { center, radius }) => IndexProfile::Luneburg {
                    center: *center,
                    radius: *radius,
                    outer,
                },
                _ => {
                    return Err(c.err(
                        ip,
                        "a Luneburg profile needs a sphere shape (it takes the sphere's centre and radius)",
                    ))
                }
            }
        }
        RawIndex::Profile(RawProfile::Linear {
            n0,
            gradient,
            origin,
        }) => {
            let prof = IndexProfile::Linear {
                n0: c.index_value(&sub("n0"), *n0)?,
                gradient: c.vec3(&sub("gradient"), *gradient)?,
                origin: c.vec3(&sub("origin"), *origin)?,
            };
            // n must stay positive wherever the object meets the grid (with
            // room for the smoothing halo): check the corners of that box,
            // where a linear function takes its extremes.
            let geom = &grid.geometry;
            let halo = geom.spacing() * (4.0 * grid.smoothing + 2.0);
            let (mut lo, mut hi) = (geom.min - halo, geom.max + halo);
            if let Some((a, b)) = shape.and_then(Shape::aabb) {
                lo = lo.max(a);
                hi = hi.min(b);
            }
            for corner in 0..8 {
                let q = DVec3::new(
                    if corner & 1 == 0 { lo.x } else { hi.x },
                    if corner & 2 == 0 { lo.y } else { hi.y },
                    if corner & 4 == 0 { lo.z } else { hi.z },
                );
                let n = prof.value(q, 0);
                if (n.is_nan() || n <= 0.0) && lo.cmple(hi).all() {
                    return Err(c.err(
                        ip,
                        format!("the linear index reaches {n:.4} <= 0 at {q} inside the grid"),
                    ));
                }
            }
            prof
        }
        // Filled in from the grid by `attach_grids`.
        RawIndex::Profile(RawProfile::Vdb { .. }) => IndexProfile::Constant([1.0; 3]),
    })
}

/// The material whose fields sit under path `base`.
fn check_material(
    c: &Checker,
    grid: &GridSettings,
    base: &[Seg],
    m: MaterialFields,
    shape: Option<&Shape>,
) -> Result<Material> {
    let p = |k| [base, &[Seg::Key(k)]].concat();
    let index = check_index(c, grid, &p("index"), m.index, shape)?;
    let extinction = c.vec3(&p("extinction"), m.extinction)?;
    if extinction.min_element() < 0.0 {
        return Err(c.err(&p("extinction"), "extinction must be >= 0 (1 / world unit)"));
    }
    if extinction.max_element() > MAX_EXTINCTION {
        return Err(c.err(
            &p("extinction"),
            format!(
                "extinction {:e} exceeds the limit of {MAX_EXTINCTION:e} per world unit (stored as 32-bit floats)",
                extinction.max_element()
            ),
        ));
    }
    let albedo = c.rgb_in(&p("albedo"), m.albedo, 0.0, 1.0)?;
    c.finite(&p("g"), &[m.g])?;
    if !(m.g > -1.0 && m.g < 1.0) {
        return Err(c.err(
            &p("g"),
            format!("Henyey-Greenstein g must lie in (-1, 1), got {}", m.g),
        ));
    }
    let emission = c.vec3(&p("emission"), m.emission)?;
    if emission.min_element() < 0.0 {
        return Err(c.err(&p("emission"), "emission must be >= 0"));
    }
    Ok(Material {
        index,
        extinction,
        albedo,
        g: m.g,
        emission,
        index_grid: None,
        extinction_grid: None,
    })
}

/// Light `i` of the file.
fn check_camera(c: &Checker, r: &RawCamera) -> Result<CameraSettings> {
    let p = |k| [Seg::Key("camera"), Seg::Key(k)];
    let position = c.vec3(&p("position"), r.position)?;
    let target = c.vec3(&p("target"), r.target)?;
    if (target - position).length() == 0.0 {
        return Err(c.err(
            &p("target"),
            "the camera must look somewhere: target equals position",
        ));
    }
    let up = c.unit(&p("up"), r.up)?;
    if up.cross((target - position).normalize()).length() < 1e-6 {
        return Err(c.err(&p("up"), "up must not be parallel to the view direction"));
    }
    c.finite(&p("fov"), &[r.fov])?;
    if !(r.fov > 0.0 && r.fov < 180.0) {
        return Err(c.err(
            &p("fov"),
            format!("field of view must lie in (0, 180) degrees, got {}", r.fov),
        ));
    }
    let [w, h] = r.resolution;
    if w == 0 || h == 0 || w > 16384 || h > 16384 {
        return Err(c.err(
            &p("resolution"),
            format!("image size must be 1 to 16384 pixels a side, got {w} x {h}"),
        ));
    }
    if r.samples == 0 || r.samples > 4096 {
        return Err(c.err(
            &p("samples"),
            format!("samples per pixel must lie in 1..=4096, got {}", r.samples),
        ));
    }
    Ok(CameraSettings {
        position,
        target,
        up,
        fov: r.fov,
        resolution: r.resolution,
        samples: r.samples,
    })
}

fn check_background(c: &Checker, b: &RawBackground) -> Result<Background> {
    let p = |k| [Seg::Key("background"), Seg::Key(k)];
    let scale = |v: f64| -> Result<f64> {
        c.finite(&p("intensity"), &[v])?;
        if v < 0.0 {
            return Err(c.err(&p("intensity"), "intensity must be >= 0"));
        }
        Ok(v)
    };
    let radiance = |path: &[Seg], v: [f64; 3]| -> Result<DVec3> {
        let v = c.vec3(path, v)?;
        if v.min_element() < 0.0 {
            return Err(c.err(path, "radiance must be >= 0"));
        }
        Ok(v)
    };
    Ok(match b {
        RawBackground::Constant { color } => Background::Constant(radiance(&p("color"), *color)?),
        RawBackground::Sky { intensity } => Background::Sky {
            intensity: scale(*intensity)?,
        },
        RawBackground::Environment { file, intensity } => {
            let base = Path::new(c.origin).parent().unwrap_or(Path::new(""));
            Background::Environment {
                file: base.join(file),
                intensity: scale(*intensity)?,
            }
        }
        RawBackground::Checker {
            point,
            normal,
            square,
            colors,
        } => {
            let path = |i| [Seg::Key("background"), Seg::Key("colors"), Seg::Index(i)];
            Background::Checker {
                point: c.vec3(&p("point"), *point)?,
                normal: c.unit(&p("normal"), *normal)?,
                square: c.positive(&p("square"), *square)?,
                colors: [
                    radiance(&path(0), colors[0])?,
                    radiance(&path(1), colors[1])?,
                ],
            }
        }
    })
}

fn check_render(c: &Checker, r: &RawRender) -> Result<RenderSettings> {
    let p = |k| [Seg::Key("render"), Seg::Key(k)];
    let step = c.positive(&p("step"), r.step)?;
    if step > 4.0 {
        return Err(c.err(
            &p("step"),
            format!("step must be at most 4 voxels, got {step}"),
        ));
    }
    if let Some(e) = r.exposure {
        c.finite(&p("exposure"), &[e])?;
    }
    Ok(RenderSettings {
        step,
        integrator: match r.integrator {
            RawIntegrator::Euler => crate::ray::Integrator::Euler,
            RawIntegrator::Rk4 => crate::ray::Integrator::Rk4,
        },
        exposure: r.exposure,
        seed: r.seed,
    })
}

fn check_light(c: &Checker, i: usize, l: &RawLight) -> Result<Light> {
    let p = |k| [Seg::Key("light"), Seg::Index(i), Seg::Key(k)];
    let power = |v| -> Result<DVec3> {
        let v = c.vec3(&p("power"), v)?;
        if v.min_element() < 0.0 {
            return Err(c.err(&p("power"), "power must be >= 0"));
        }
        if v.max_element() > MAX_LIGHT_POWER {
            return Err(c.err(
                &p("power"),
                format!(
                    "power {:e} exceeds the limit of {MAX_LIGHT_POWER:e} per channel (the light volumes are 32-bit floats)",
                    v.max_element()
                ),
            ));
        }
        Ok(v)
    };
    Ok(match l {
        RawLight::Directional {
            direction,
            power: pw,
        } => Light::Directional {
            direction: c.unit(&p("direction"), *direction)?,
            power: power(*pw)?,
        },
        RawLight::Point {
            position,
            power: pw,
        } => Light::Point {
            position: c.vec3(&p("position"), *position)?,
            power: power(*pw)?,
        },
        RawLight::Spot {
            position,
            direction,
            angle,
            falloff,
            power: pw,
        } => {
            c.finite(&p("angle"), &[*angle])?;
            if !(*angle > 0.0 && *angle <= 90.0) {
                return Err(c.err(&p("angle"), "cone half-angle must lie in (0, 90] degrees"));
            }
            c.finite(&p("falloff"), &[*falloff])?;
            if !(0.0..=*angle).contains(falloff) {
                return Err(c.err(&p("falloff"), "falloff must lie in [0, angle] degrees"));
            }
            Light::Spot {
                position: c.vec3(&p("position"), *position)?,
                direction: c.unit(&p("direction"), *direction)?,
                angle: *angle,
                falloff: *falloff,
                power: power(*pw)?,
            }
        }
    })
}

fn check_shape(c: &Checker, sp: &[Seg], s: &RawShape, volumes: &mut Volumes) -> Result<Shape> {
    let f = |k: &'static str| [sp, &[Seg::Key(k)]].concat();
    let rot = |r: [f64; 3]| -> Result<glam::DMat3> {
        c.finite(&f("rotation"), &r)?;
        Ok(rotation_from_degrees(r))
    };
    let size = |v: [f64; 3]| -> Result<DVec3> {
        let v = c.vec3(&f("size"), v)?;
        if v.min_element() > 0.0 {
            Ok(v)
        } else {
            Err(c.err(&f("size"), "every edge length must be > 0"))
        }
    };
    Ok(match s {
        RawShape::Sphere { center, radius } => Shape::Sphere {
            center: c.vec3(&f("center"), *center)?,
            radius: c.positive(&f("radius"), *radius)?,
        },
        RawShape::Box {
            center,
            size: sz,
            rotation,
        } => Shape::Box {
            center: c.vec3(&f("center"), *center)?,
            half: size(*sz)? * 0.5,
            radius: 0.0,
            rot: rot(*rotation)?,
        },
        RawShape::RoundedBox {
            center,
            size: sz,
            radius,
            rotation,
        } => {
            let half = size(*sz)? * 0.5;
            let r = c.positive(&f("radius"), *radius)?;
            if r > half.min_element() {
                return Err(c.err(
                    &f("radius"),
                    "rounding radius exceeds half the smallest edge",
                ));
            }
            Shape::Box {
                center: c.vec3(&f("center"), *center)?,
                half,
                radius: r,
                rot: rot(*rotation)?,
            }
        }
        RawShape::Cylinder {
            center,
            radius,
            height,
            rotation,
        } => Shape::Cylinder {
            center: c.vec3(&f("center"), *center)?,
            radius: c.positive(&f("radius"), *radius)?,
            half_height: 0.5 * c.positive(&f("height"), *height)?,
            rot: rot(*rotation)?,
        },
        RawShape::Revolution {
            base,
            profile,
            rotation,
        } => {
            if profile.len() < 3 {
                return Err(c.err(
                    &f("profile"),
                    "a profile needs at least 3 [radius, height] points",
                ));
            }
            let mut pts = Vec::with_capacity(profile.len());
            let mut area2 = 0.0;
            for (i, q) in profile.iter().enumerate() {
                let at = [sp, &[Seg::Key("profile"), Seg::Index(i)]].concat();
                c.finite(&at, q)?;
                if q[0] < 0.0 {
                    return Err(c.err(&at, "profile radius must be >= 0"));
                }
                pts.push(DVec2::new(q[0], q[1]));
            }
            for i in 0..pts.len() {
                area2 += pts[i].perp_dot(pts[(i + 1) % pts.len()]);
            }
            if area2.abs() < 1e-12 {
                return Err(c.err(&f("profile"), "the profile polygon encloses no area"));
            }
            Shape::Revolution {
                base: c.vec3(&f("base"), *base)?,
                profile: crate::profile::Profile::new(pts),
                rot: rot(*rotation)?,
            }
        }
        RawShape::Torus {
            center,
            major_radius,
            minor_radius,
            rotation,
        } => Shape::Torus {
            center: c.vec3(&f("center"), *center)?,
            major: c.positive(&f("major_radius"), *major_radius)?,
            minor: c.positive(&f("minor_radius"), *minor_radius)?,
            rot: rot(*rotation)?,
        },
        RawShape::Superquadric {
            center,
            radii,
            exponents,
            rotation,
        } => {
            let r = c.vec3(&f("radii"), *radii)?;
            if r.min_element() <= 0.0 {
                return Err(c.err(&f("radii"), "every radius must be > 0"));
            }
            c.finite(&f("exponents"), exponents)?;
            if !exponents.iter().all(|e| (0.05..=4.0).contains(e)) {
                return Err(c.err(&f("exponents"), "exponents must lie in [0.05, 4]"));
            }
            Shape::Superquadric {
                center: c.vec3(&f("center"), *center)?,
                radii: r,
                e1: exponents[0],
                e2: exponents[1],
                rot: rot(*rotation)?,
            }
        }
        RawShape::HalfSpace { point, normal } => Shape::HalfSpace {
            point: c.vec3(&f("point"), *point)?,
            normal: c.unit(&f("normal"), *normal)?,
        },
        RawShape::Vdb {
            file,
            grid,
            threshold,
        } => {
            let volume = volumes.load(c, sp, file, grid)?;
            let t = match threshold {
                Some(t) => {
                    c.finite(&f("threshold"), &[*t])?;
                    *t
                }
                None => volume.background as f64,
            };
            let solid = VdbSolid::new(volume.clone(), t);
            if solid.inside_voxels() == 0 && volume.background as f64 <= t {
                let (lo, hi) = volume.range();
                return Err(c.err(
                    &f("threshold"),
                    format!(
                        "no voxel of grid `{grid}` exceeds {t} (its values span {lo} to {hi}): the solid would be empty"
                    ),
                ));
            }
            Shape::Vdb(Arc::new(solid))
        }
        RawShape::Mesh {
            file,
            scale,
            translate,
            rotation,
            smooth,
        } => {
            let mut mesh = load_mesh(c, &f("file"), file)?;
            let scale = match scale {
                Some(k) => c.positive(&f("scale"), *k)?,
                None => 1.0,
            };
            let map = glam::DAffine3::from_translation(c.vec3(&f("translate"), *translate)?)
                * glam::DAffine3::from_mat3(rot(*rotation)?)
                * glam::DAffine3::from_scale(DVec3::splat(scale));
            mesh.transform(map)
                .map_err(|e| c.err(&f("file"), e.to_string()))?;
            mesh_shape(c, &f("file"), mesh, smooth.unwrap_or(true))?
        }
        RawShape::BumpySphere {
            center,
            radius,
            amplitude,
            bumps,
            seed,
            frequency,
        } => {
            let center = c.vec3(&f("center"), *center)?;
            let radius = c.positive(&f("radius"), *radius)?;
            if !(1..=200).contains(frequency) {
                return Err(c.err(
                    &f("frequency"),
                    format!("must lie in 1..=200 (20 f^2 triangles), got {frequency}"),
                ));
            }
            let mut mesh = eikon_mesh::BumpySphere::new(radius, *amplitude, *bumps, *seed)
                .and_then(|b| b.mesh(*frequency))
                .map_err(|e| c.err(sp, e.to_string()))?;
            mesh.transform(glam::DAffine3::from_translation(center))
                .map_err(|e| c.err(sp, e.to_string()))?;
            mesh_shape(c, sp, mesh, true)?
        }
        RawShape::Cuboctahedron {
            center,
            edge,
            rotation,
        } => {
            let edge = c.positive(&f("edge"), *edge)?;
            let mut mesh =
                eikon_mesh::cuboctahedron(edge).map_err(|e| c.err(&f("edge"), e.to_string()))?;
            let map = glam::DAffine3::from_translation(c.vec3(&f("center"), *center)?)
                * glam::DAffine3::from_mat3(rot(*rotation)?);
            mesh.transform(map).map_err(|e| c.err(sp, e.to_string()))?;
            mesh_shape(c, sp, mesh, false)?
        }
    })
}
