//! Exact ray-surface crossings and outward normals of every [`Shape`], for
//! sharp interfaces: a curved-ray renderer cuts its straight steps exactly
//! where they leave one medium for another and applies Snell's law there.
//!
//! * Closed forms: the sphere, the box (slabs) and the rounded box (the
//!   union of three slabs, twelve edge cylinders and eight corner balls, all
//!   convex, so the union's interval on a line is the hull of the parts'
//!   intervals), the capped cylinder, the half-space and the solid of
//!   revolution (each profile edge sweeps a cone, cylinder or annulus: one
//!   quadratic or linear equation per edge).
//! * Root finding: the torus and the superquadric march along the segment
//!   by their distance bounds (a step no longer than the bound cannot jump
//!   over the surface) and bisect the first change of side to the last bit.
//! * The VDB solid walks the grid's cells (a 3-D DDA): inside one cell the
//!   trilinear interpolant along a line is a cubic, split at its extrema
//!   into monotone pieces, so no pair of crossings inside a cell is missed.
//! * The mesh asks its BVH (the watertight test of `eikon-mesh`).
//!
//! Crossings closer than [`SKIN`] (relative to the shape's size) after
//! `t_min` are ignored: a segment that starts on the surface, at the
//! previous crossing, must not find its own starting point again.

use crate::mesh_solid::MeshSolid;
use crate::profile::Profile;
use crate::shape::Shape;
use crate::vdb::VdbSolid;
use eikon_mesh::Ray;
use eikon_shader::{Module, VECTOR};
use glam::{DMat3, DVec2, DVec3};

/// The WGSL of every shape: [`Shape::first_crossing`], [`Shape::normal`]
/// and [`Shape::distance`] in f32 (`surface.wgsl`), by the same methods
/// as here (a VDB grid's distance only by its sign: the bound of its
/// distance transform is not on the GPU, and no kernel needs more than
/// the side), and a VDB grid's trilinear sample. A kernel provides the
/// hook `surface_data(i: u32) -> vec4<u32>`, record `i` of the data buffer
/// that holds profiles, mesh triangles and BVH nodes, and VDB volumes
/// (`crate::region::GpuRegions::data`).
pub static WGSL: Module = Module {
    name: "surface",
    requires: &[&VECTOR],
    declarations: surface_declarations,
    text: include_str!("surface.wgsl"),
};

/// Records (16 bytes) per mesh triangle in the GPU's data buffer: its three
/// corners (the first's `w` the mesh triangle id), then its three vertex
/// normals.
pub const MESH_TRIANGLE_RECORDS: u32 = 6;
/// Records per BVH node there: `(lo, offset)`, `(hi, count | axis << 16)`.
pub const MESH_NODE_RECORDS: u32 = 2;
/// Records of a VDB volume's header there, before its values (four to a
/// record): `(voxel size, background)`, `(translation, 0)`, `(origin, 0)`
/// and `(dims, 0)`.
pub const VDB_HEADER_RECORDS: u32 = 4;
/// The superquadric's march takes this fraction of its distance bound...
const SUPERQUADRIC_SAFETY: f64 = 0.25;
/// ... and steps of at most its size over this (see [`Shape::march`]).
const SUPERQUADRIC_STEPS: f64 = 128.0;
/// [`MIN_STEP`] in f32: a step must move `t` by a few ulps of the shape's
/// size, or a march that starts on the surface stands still.
const MIN_STEP_F32: f32 = 1e-6;
/// [`MAX_MARCH`] on the GPU, where a thread cannot run for long: a march
/// that grazes a surface for more steps than this gives up (no crossing).
const MAX_MARCH_F32: u32 = 1 << 14;
/// The step of the numeric normal (a superquadric's pinch) relative to the
/// size: the CPU's 1e-7 is at f32's resolution, 1e-4 keeps the rounding of
/// the difference near 1e-3 of the normal.
const NUMERIC_STEP_F32: f32 = 1e-4;

/// The BVH's widening of its box tests (`eikon_mesh::bvh`: twice the
/// rounding bound of three operations, Ize 2013) for f32's unit roundoff.
const BVH_WIDEN_F32: f32 = {
    let e = f32::EPSILON as f64 * 0.5;
    (2.0 * 3.0 * e / (1.0 - 3.0 * e)) as f32
};

fn surface_declarations() -> String {
    eikon_shader::Consts::new()
        .u32("MESH_TRIANGLE_RECORDS", MESH_TRIANGLE_RECORDS)
        .u32("MESH_NODE_RECORDS", MESH_NODE_RECORDS)
        .u32("VDB_HEADER_RECORDS", VDB_HEADER_RECORDS)
        .u32("BVH_STACK", eikon_mesh::bvh::STACK as u32)
        .f32("SUPERQUADRIC_SAFETY", SUPERQUADRIC_SAFETY as f32)
        .f32("SUPERQUADRIC_STEPS", SUPERQUADRIC_STEPS as f32)
        .f32("SURFACE_MIN_STEP", MIN_STEP_F32)
        .u32("SURFACE_MAX_MARCH", MAX_MARCH_F32)
        .f32("SURFACE_NUMERIC_STEP", NUMERIC_STEP_F32)
        .f32("BVH_WIDEN", BVH_WIDEN_F32)
        .wgsl()
        .to_string()
}

/// Where a straight segment first crosses a shape's surface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Crossing {
    /// Parameter of the point `o + d t` on the segment.
    pub t: f64,
    /// Unit outward normal of the surface there.
    pub normal: DVec3,
}

/// Crossings within this fraction of the shape's size after `t_min` are
/// the segment's own starting point (see the module docs).
const SKIN: f64 = 1e-12;
/// Smallest marching step, relative to the shape's size: it keeps a march
/// that starts on the surface (distance bound 0) moving; only grazes
/// thinner than this can slip between two samples.
const MIN_STEP: f64 = 1e-10;
/// Most marching steps before giving up (a guard against endless loops on
/// non-finite input; a normal march takes tens to thousands).
const MAX_MARCH: usize = 1 << 22;

/// An empty interval (its start after its end).
const EMPTY: (f64, f64) = (f64::INFINITY, f64::NEG_INFINITY);

fn local(p: DVec3, c: DVec3, rot: &DMat3) -> DVec3 {
    rot.transpose() * (p - c)
}

/// `a < b`, false when either is NaN.
fn before(a: f64, b: f64) -> bool {
    a.partial_cmp(&b) == Some(std::cmp::Ordering::Less)
}

/// The open interval of `t` where `lo < o + d t < hi` on one axis.
fn slab(o: f64, d: f64, lo: f64, hi: f64) -> (f64, f64) {
    if d == 0.0 {
        if o > lo && o < hi {
            (f64::NEG_INFINITY, f64::INFINITY)
        } else {
            EMPTY
        }
    } else {
        let a = (lo - o) / d;
        let b = (hi - o) / d;
        if a < b {
            (a, b)
        } else {
            (b, a)
        }
    }
}

/// The interval of `t` where `|o + d t| < r` (`o` relative to the centre;
/// zero components of both give a disc). From the closest approach, and
/// the root nearer zero from the product of the roots, so neither a far
/// origin nor a start on the surface loses digits.
fn ball(o: DVec3, d: DVec3, r: f64) -> (f64, f64) {
    let a = d.length_squared();
    if a == 0.0 {
        return if o.length() < r {
            (f64::NEG_INFINITY, f64::INFINITY)
        } else {
            EMPTY
        };
    }
    let tc = -o.dot(d) / a;
    let m = (o + d * tc).length();
    let h2 = (r - m) * (r + m);
    if h2 <= 0.0 {
        return EMPTY;
    }
    let s = (h2 / a).sqrt();
    let ol = o.length();
    let c = (ol - r) * (ol + r);
    if tc >= 0.0 {
        let t2 = tc + s;
        (c / (a * t2), t2)
    } else {
        let t1 = tc - s;
        (t1, c / (a * t1))
    }
}

/// Real roots of `a t^2 + 2 b t + c` (NaN for a missing one), in the
/// cancellation-free form.
fn quadratic(a: f64, b: f64, c: f64) -> [f64; 2] {
    if a == 0.0 {
        return if b == 0.0 {
            [f64::NAN; 2]
        } else {
            [-c / (2.0 * b), f64::NAN]
        };
    }
    let disc = b * b - a * c;
    if disc < 0.0 {
        return [f64::NAN; 2];
    }
    let q = -(b + disc.sqrt().copysign(b));
    if q == 0.0 {
        [0.0, f64::NAN]
    } else {
        [q / a, c / q]
    }
}

/// The first end of the interval `(t_in, t_out)` in `(lo, hi]`, and
/// whether it is the entry.
fn first_end((t_in, t_out): (f64, f64), lo: f64, hi: f64) -> Option<(f64, bool)> {
    if t_in >= t_out {
        None
    } else if t_in > lo && t_in <= hi {
        Some((t_in, true))
    } else if t_out > lo && t_out <= hi {
        Some((t_out, false))
    } else {
        None
    }
}

/// Bisect `[a, b]` (inside-ness `side_a` at `a`, the other side at `b`)
/// until no double lies between; the end on the far side.
fn bisect(inside: impl Fn(f64) -> bool, mut a: f64, mut b: f64, side_a: bool) -> f64 {
    for _ in 0..2100 {
        let m = 0.5 * (a + b);
        if m <= a.min(b) || m >= a.max(b) {
            break;
        }
        if inside(m) == side_a {
            a = m;
        } else {
            b = m;
        }
    }
    b
}

/// The change of side of `f` (inside where negative) bracketed by
/// `(a, f(a))` and `(b, f(b))` on opposite sides, to `tol`: false position
/// with the Illinois rule (the end that stays has its value halved, so both
/// ends close in), bisecting where an interpolated point would not shrink
/// the bracket. Returns the end on `b`'s side, as [`bisect`] does; the
/// bracket holds throughout, so the answer is a true change of side.
fn illinois(f: impl Fn(f64) -> f64, a: (f64, f64), b: (f64, f64), tol: f64) -> f64 {
    let ((mut a, mut fa), (mut b, mut fb)) = (a, b);
    let side_a = fa < 0.0;
    // Which end was kept last: -1 a, 1 b.
    let mut kept = 0;
    for _ in 0..200 {
        if (b - a).abs() <= tol {
            break;
        }
        let (lo, hi) = (a.min(b), a.max(b));
        let mut m = if fa != fb {
            b - fb * (b - a) / (fb - fa)
        } else {
            f64::NAN
        };
        if !(m > lo && m < hi) {
            m = 0.5 * (a + b);
        }
        if m <= lo || m >= hi {
            break;
        }
        let fm = f(m);
        if (fm < 0.0) == side_a {
            (a, fa) = (m, fm);
            if kept == 1 {
                fb *= 0.5;
            }
            kept = 1;
        } else {
            (b, fb) = (m, fm);
            if kept == -1 {
                fa *= 0.5;
            }
            kept = -1;
        }
    }
    b
}

/// Unit vector or `fallback` where it has no direction.
fn unit_or(v: DVec3, fallback: DVec3) -> DVec3 {
    let n = v.normalize_or_zero();
    if n == DVec3::ZERO {
        fallback
    } else {
        n
    }
}

impl Shape {
    /// The first crossing of the surface by `o + d t` with
    /// `t_min < t <= t_max` (`d` need not be unit length), or None.
    ///
    /// A crossing is where [`Shape::contains`] changes; tangential touches
    /// may or may not be reported. Crossings within `1e-12` of the shape's
    /// size after `t_min` are ignored (a segment starting on the surface
    /// does not find its own start). `d = 0` and non-finite input give None.
    pub fn first_crossing(&self, o: DVec3, d: DVec3, t_min: f64, t_max: f64) -> Option<Crossing> {
        self.first_crossing_sized(o, d, t_min, t_max, self.size(o))
    }

    /// [`Shape::first_crossing`] with the shape's size (its tolerances'
    /// scale) given: [`Shape::fixed_size`] where it has one, which a caller
    /// that asks many times keeps rather than recomputes.
    pub fn first_crossing_sized(
        &self,
        o: DVec3,
        d: DVec3,
        t_min: f64,
        t_max: f64,
        size: f64,
    ) -> Option<Crossing> {
        let dl = d.length();
        if !dl.is_finite() || dl == 0.0 || !o.is_finite() {
            return None;
        }
        if !before(t_min, t_max) {
            return None;
        }
        let lo = t_min + SKIN * size / dl;
        let hi = t_max;
        if !before(lo, hi) {
            return None;
        }
        let at = |t: f64| o + d * t;
        match self {
            Shape::Sphere { center, radius } => {
                let (t, _) = first_end(ball(o - *center, d, *radius), lo, hi)?;
                let normal = unit_or(at(t) - *center, DVec3::Y);
                Some(Crossing { t, normal })
            }
            Shape::Box {
                center,
                half,
                radius,
                rot,
            } => {
                let (ol, dl) = (local(o, *center, rot), rot.transpose() * d);
                if *radius > 0.0 {
                    // The distance is exact: a segment shorter than it
                    // meets no surface, and the 23 pieces below need not
                    // be tried (a light step is half a voxel).
                    let reach = hi * d.length();
                    if self.distance(o).abs() > reach + SKIN * size {
                        return None;
                    }
                    let (t, _) = first_end(rounded_box(ol, dl, *half, *radius), lo, hi)?;
                    Some(Crossing {
                        t,
                        normal: self.normal(at(t)),
                    })
                } else {
                    let (mut t_in, mut t_out) = (f64::NEG_INFINITY, f64::INFINITY);
                    let (mut ax_in, mut ax_out) = (0, 0);
                    for k in 0..3 {
                        let (a, b) = slab(ol[k], dl[k], -half[k], half[k]);
                        if a > t_in {
                            (t_in, ax_in) = (a, k);
                        }
                        if b < t_out {
                            (t_out, ax_out) = (b, k);
                        }
                    }
                    let (t, entering) = first_end((t_in, t_out), lo, hi)?;
                    let (k, s) = if entering {
                        (ax_in, -dl[ax_in].signum())
                    } else {
                        (ax_out, dl[ax_out].signum())
                    };
                    let mut n = DVec3::ZERO;
                    n[k] = s;
                    Some(Crossing {
                        t,
                        normal: *rot * n,
                    })
                }
            }
            Shape::Cylinder {
                center,
                radius,
                half_height,
                rot,
            } => {
                let (ol, dl) = (local(o, *center, rot), rot.transpose() * d);
                let flat = DVec3::new(1.0, 0.0, 1.0);
                let (c0, c1) = ball(ol * flat, dl * flat, *radius);
                let (s0, s1) = slab(ol.y, dl.y, -half_height, *half_height);
                let (t, entering) = first_end((c0.max(s0), c1.min(s1)), lo, hi)?;
                // The part that bounds the interval at that end was hit.
                let cap = if entering { s0 > c0 } else { s1 < c1 };
                let p = ol + dl * t;
                let n = if cap {
                    DVec3::new(0.0, if p.y > 0.0 { 1.0 } else { -1.0 }, 0.0)
                } else {
                    unit_or(p * flat, DVec3::X)
                };
                Some(Crossing {
                    t,
                    normal: *rot * n,
                })
            }
            Shape::HalfSpace { point, normal } => {
                let sd = d.dot(*normal);
                if sd == 0.0 {
                    return None;
                }
                let t = -(o - *point).dot(*normal) / sd;
                (t > lo && t <= hi).then_some(Crossing { t, normal: *normal })
            }
            Shape::Revolution { base, profile, rot } => {
                let (ol, dl) = (local(o, *base, rot), rot.transpose() * d);
                let (t, n) = revolution_crossing(profile, ol, dl, lo, hi)?;
                Some(Crossing {
                    t,
                    normal: *rot * n,
                })
            }
            Shape::Superquadric {
                center,
                radii,
                e1,
                e2,
                rot,
            } if *e1 == 1.0 && *e2 == 1.0 => {
                // Both exponents 1: an ellipsoid, |q| = 1 in coordinates
                // scaled by the radii, where `contains` is |q|^2 < 1.
                let (ol, dl) = (
                    local(o, *center, rot) / *radii,
                    (rot.transpose() * d) / *radii,
                );
                let (t, _) = first_end(ball(ol, dl, 1.0), lo, hi)?;
                Some(Crossing {
                    t,
                    normal: self.normal(at(t)),
                })
            }
            Shape::Torus { .. } | Shape::Superquadric { .. } => {
                let t = self.march(o, d, lo, hi, size)?;
                Some(Crossing {
                    t,
                    normal: self.normal(at(t)),
                })
            }
            Shape::Vdb(solid) => {
                let t = vdb_crossing(solid, o, d, lo, hi)?;
                Some(Crossing {
                    t,
                    normal: vdb_normal(solid, at(t)),
                })
            }
            Shape::Mesh(solid) => mesh_crossing(solid, o, d, lo, hi),
        }
    }

    /// Unit outward normal of the surface at (or nearest to) `p`.
    pub fn normal(&self, p: DVec3) -> DVec3 {
        match self {
            Shape::Sphere { center, .. } => unit_or(p - *center, DVec3::Y),
            Shape::Box {
                center,
                half,
                radius,
                rot,
            } => {
                let q = local(p, *center, rot);
                let inner = (*half - DVec3::splat(*radius)).max(DVec3::ZERO);
                let out = q.abs() - inner;
                let n = if *radius > 0.0 && out.max_element() > 0.0 {
                    // The gradient of the distance to the inner box.
                    out.max(DVec3::ZERO) * q.signum()
                } else {
                    // The face the point is nearest (or beyond).
                    let e = q.abs() - *half;
                    let k = if e.x >= e.y && e.x >= e.z {
                        0
                    } else if e.y >= e.z {
                        1
                    } else {
                        2
                    };
                    let mut n = DVec3::ZERO;
                    n[k] = q[k].signum();
                    n
                };
                *rot * unit_or(n, DVec3::Y)
            }
            Shape::Cylinder {
                center,
                radius,
                half_height,
                rot,
            } => {
                let q = local(p, *center, rot);
                let radial = unit_or(DVec3::new(q.x, 0.0, q.z), DVec3::X);
                let axial = DVec3::new(0.0, q.y.signum(), 0.0);
                let dr = DVec2::new(q.x, q.z).length() - radius;
                let dy = q.y.abs() - half_height;
                let n = if dr > 0.0 && dy > 0.0 {
                    radial * dr + axial * dy
                } else if dr > dy {
                    radial
                } else {
                    axial
                };
                *rot * unit_or(n, DVec3::Y)
            }
            Shape::HalfSpace { normal, .. } => *normal,
            Shape::Revolution { base, profile, rot } => {
                let q = local(p, *base, rot);
                *rot * revolution_normal(profile, q)
            }
            Shape::Torus {
                center, major, rot, ..
            } => {
                let q = local(p, *center, rot);
                let rho = DVec2::new(q.x, q.z).length();
                let n = if rho > 0.0 {
                    let k = 1.0 - major / rho;
                    DVec3::new(q.x * k, q.y, q.z * k)
                } else {
                    DVec3::new(0.0, q.y, 0.0)
                };
                *rot * unit_or(n, DVec3::Y)
            }
            Shape::Superquadric {
                center,
                radii,
                e1,
                e2,
                rot,
            } => {
                let q = local(p, *center, rot) / *radii;
                let (ax, ay, az) = (q.x.abs(), q.y.abs(), q.z.abs());
                let s = ax.powf(2.0 / e2) + az.powf(2.0 / e2);
                let k = s.powf(e2 / e1 - 1.0);
                // The gradient of the implicit function (common factor
                // 2 / e1 dropped), back through the scaling by the radii.
                let g = DVec3::new(
                    k * ax.powf(2.0 / e2 - 1.0) * q.x.signum(),
                    ay.powf(2.0 / e1 - 1.0) * q.y.signum(),
                    k * az.powf(2.0 / e2 - 1.0) * q.z.signum(),
                ) / *radii;
                let n = g.normalize_or_zero();
                if n.is_finite() && n != DVec3::ZERO {
                    *rot * n
                } else {
                    // A pinch or crease: zero or infinite partials.
                    self.numeric_normal(p)
                }
            }
            Shape::Vdb(solid) => vdb_normal(solid, p),
            Shape::Mesh(solid) => mesh_normal(solid, p),
        }
    }

    /// A length that sets the scale of the shape's tolerances: its bounding
    /// box's diagonal (the half-space's distance from `o` to its point).
    fn size(&self, o: DVec3) -> f64 {
        match self {
            Shape::HalfSpace { point, .. } => finite_or_zero((o - *point).length()),
            _ => self.fixed_size().unwrap_or(0.0),
        }
    }

    /// The size of [`Shape::first_crossing_sized`] where it does not depend
    /// on the ray (every shape but the half-space).
    pub fn fixed_size(&self) -> Option<f64> {
        let s = match self {
            Shape::HalfSpace { .. } => return None,
            Shape::Vdb(solid) => {
                let v = solid.volume();
                let dims = v.dims();
                let n = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
                (n * v.transform.voxel_size).length()
            }
            _ => self.aabb().map_or(0.0, |(a, b)| (b - a).length()),
        };
        Some(finite_or_zero(s))
    }

    /// The normalized central-difference gradient of the distance bound.
    fn numeric_normal(&self, p: DVec3) -> DVec3 {
        let h = 1e-7 * self.size(p).max(1e-300);
        let g = DVec3::new(
            self.distance(p + DVec3::X * h) - self.distance(p - DVec3::X * h),
            self.distance(p + DVec3::Y * h) - self.distance(p - DVec3::Y * h),
            self.distance(p + DVec3::Z * h) - self.distance(p - DVec3::Z * h),
        );
        unit_or(g, DVec3::Y)
    }

    /// Sphere tracing by the distance bound from `lo` to `hi`, then
    /// [`illinois`] on the bound within the first change of side (for shapes whose `contains` is the sign
    /// of `distance`).
    fn march(&self, o: DVec3, d: DVec3, lo: f64, hi: f64, size: f64) -> Option<f64> {
        let dl = d.length();
        // Outside the bounding box nothing changes: start and stop there.
        let (mut lo, mut hi) = (lo, hi);
        if let Some((a, b)) = self.aabb() {
            let pad = DVec3::splat(1e-9 * size);
            let (a, b) = (a - pad, b + pad);
            for k in 0..3 {
                let (s0, s1) = slab(o[k], d[k], a[k], b[k]);
                lo = lo.max(s0);
                hi = hi.min(s1);
            }
            if !before(lo, hi) {
                return None;
            }
        }
        let h_min = MIN_STEP * size / dl;
        // The superquadric's bound over-estimates near the pinches of the
        // star shapes (e > 2), where the implicit function's gradient is
        // unbounded: a quarter of it and steps of at most 1/128 of the size
        // keep the march from jumping a thin part. A convex one (both
        // exponents at most 2) is marched by its bound alone, which holds
        // there ([`Shape::distance`]); the torus's is exact.
        let (safety, h_max) = match self {
            Shape::Superquadric { e1, e2, .. } if e1.max(*e2) > 2.0 => {
                (SUPERQUADRIC_SAFETY, size / SUPERQUADRIC_STEPS / dl)
            }
            _ => (1.0, f64::INFINITY),
        };
        let mut t0 = lo;
        let mut d0 = self.distance(o + d * t0);
        let side = d0 < 0.0;
        let tol = 1e-14 * size / dl;
        let refine = |a, b| illinois(|t| self.distance(o + d * t), a, b, tol);
        let mut last: Option<(f64, f64)> = None;
        for _ in 0..MAX_MARCH {
            let step = (safety * d0.abs() / dl).clamp(h_min, h_max.max(h_min));
            let t1 = (t0 + step).min(hi);
            // Closing in on a surface, sphere tracing only creeps (each
            // step a fraction of a bound that shrinks with it): the secant
            // through the last two samples says where the bound reaches
            // zero, and a probe a little beyond (within the same largest
            // step) brackets the crossing in one sample.
            if let Some((tp, dp)) = last.filter(|&(_, dp)| d0.abs() < dp.abs()) {
                let ts = t0 - d0 * (t0 - tp) / (d0 - dp);
                let probe = (t0 + 1.25 * (ts - t0)).min(t0 + h_max).min(hi);
                if probe > t1 {
                    let dq = self.distance(o + d * probe);
                    if (dq < 0.0) != side {
                        return Some(refine((t0, d0), (probe, dq)));
                    }
                }
            }
            let d1 = self.distance(o + d * t1);
            if (d1 < 0.0) != side {
                return Some(refine((t0, d0), (t1, d1)));
            }
            last = Some((t0, d0));
            if t1 >= hi || !d1.is_finite() {
                return None;
            }
            (t0, d0) = (t1, d1);
        }
        None
    }
}

/// The entry and exit of a line into a rounded box (local frame): the hull
/// of the intervals of its convex parts, which cover it.
fn rounded_box(o: DVec3, d: DVec3, half: DVec3, r: f64) -> (f64, f64) {
    let inner = (half - DVec3::splat(r)).max(DVec3::ZERO);
    let (mut t_in, mut t_out) = EMPTY;
    let mut add = |(a, b): (f64, f64)| {
        if a < b {
            t_in = t_in.min(a);
            t_out = t_out.max(b);
        }
    };
    // Three boxes, each the inner box grown by r along one axis.
    for k in 0..3 {
        let mut h = inner;
        h[k] += r;
        let (mut a, mut b) = (f64::NEG_INFINITY, f64::INFINITY);
        for j in 0..3 {
            let (s0, s1) = slab(o[j], d[j], -h[j], h[j]);
            a = a.max(s0);
            b = b.min(s1);
        }
        add((a, b));
    }
    // Twelve edge cylinders along axis k, four per axis.
    for k in 0..3 {
        let mut flat = DVec3::ONE;
        flat[k] = 0.0;
        let (s0, s1) = slab(o[k], d[k], -inner[k], inner[k]);
        for corner in 0..4 {
            let mut c = inner;
            let (i, j) = ((k + 1) % 3, (k + 2) % 3);
            if corner & 1 == 1 {
                c[i] = -c[i];
            }
            if corner & 2 == 2 {
                c[j] = -c[j];
            }
            let (a, b) = ball((o - c) * flat, d * flat, r);
            add((a.max(s0), b.min(s1)));
        }
    }
    // Eight corner balls.
    for corner in 0..8 {
        let c = DVec3::new(
            if corner & 1 == 1 { -inner.x } else { inner.x },
            if corner & 2 == 2 { -inner.y } else { inner.y },
            if corner & 4 == 4 { -inner.z } else { inner.z },
        );
        add(ball(o - c, d, r));
    }
    (t_in, t_out)
}

fn finite_or_zero(s: f64) -> f64 {
    if s.is_finite() {
        s
    } else {
        0.0
    }
}

/// The outward normal (local frame) at `p` of the surface swept by the
/// profile edge with outward 2-D normal `n2`.
fn swept_normal(n2: DVec2, p: DVec3) -> DVec3 {
    let radial = DVec2::new(p.x, p.z).normalize_or_zero();
    unit_or(
        DVec3::new(n2.x * radial.x, n2.y, n2.x * radial.y),
        DVec3::Y * n2.y.signum(),
    )
}

/// The outward 2-D normal of profile edge `a -> b`.
pub(crate) fn edge_normal(a: DVec2, b: DVec2, orient: f64) -> DVec2 {
    let e = b - a;
    (DVec2::new(e.y, -e.x) * orient).normalize_or_zero()
}

/// The first crossing (local frame) of the surface of revolution.
fn revolution_crossing(
    profile: &Profile,
    o: DVec3,
    d: DVec3,
    lo: f64,
    hi: f64,
) -> Option<(f64, DVec3)> {
    let mut best: Option<(f64, usize)> = None;
    // The nearest crossing; of equal ones the lowest edge's, whatever the
    // order the edges come in.
    let mut take = |t: f64, i: usize| {
        if t > lo && t <= hi && best.is_none_or(|(b, j)| t < b || (t == b && i < j)) {
            best = Some((t, i));
        }
    };
    // The heights the segment spans: an edge wholly above or below them
    // cannot be crossed (a light step is half a voxel, so this leaves one
    // or two of the profile's edges, which the profile's filing by height
    // finds without looking at the others). The margin covers the rounding of
    // the crossing's height, which is checked exactly below.
    let (ya, yb) = (o.y + d.y * lo, o.y + d.y * hi);
    let (span_lo, span_hi) = if ya.is_finite() && yb.is_finite() {
        let margin = 1e-9 * (ya.abs() + yb.abs() + (yb - ya).abs()) + f64::MIN_POSITIVE;
        (ya.min(yb) - margin, ya.max(yb) + margin)
    } else {
        (f64::NEG_INFINITY, f64::INFINITY)
    };
    // And the distances from the axis it spans (squared): the nearest is
    // where the line comes closest to the axis within [lo, hi], the
    // farthest at an end (the squared distance is convex along the line).
    // An edge whose radii lie wholly inside or outside them cannot be
    // crossed; the margins keep the test conservative.
    let rho2 = |t: f64| {
        let (x, z) = (o.x + d.x * t, o.z + d.z * t);
        x * x + z * z
    };
    let (r2_lo, r2_hi) = if lo.is_finite() && hi.is_finite() {
        let a2 = d.x * d.x + d.z * d.z;
        let near = if a2 > 0.0 {
            (-(o.x * d.x + o.z * d.z) / a2).clamp(lo, hi)
        } else {
            lo
        };
        let (r_near, r_far) = (rho2(near), rho2(lo).max(rho2(hi)));
        let margin = 1e-9 * (r_far + rho2(0.0)) + f64::MIN_POSITIVE;
        (r_near - margin, r_far + margin)
    } else {
        (f64::NEG_INFINITY, f64::INFINITY)
    };
    profile.for_edges_within(span_lo, span_hi, |i| {
        let (a, b) = profile.edge(i);
        if a.y.max(b.y) < span_lo || a.y.min(b.y) > span_hi {
            return;
        }
        let (ra, rb) = (a.x.max(0.0), b.x.max(0.0));
        if ra.max(rb) * ra.max(rb) < r2_lo || ra.min(rb) * ra.min(rb) > r2_hi {
            return;
        }
        if a.y == b.y {
            // An annulus in the plane y = a.y.
            if d.y == 0.0 {
                return;
            }
            let t = (a.y - o.y) / d.y;
            let p = o + d * t;
            let rho = DVec2::new(p.x, p.z).length();
            if rho >= a.x.min(b.x) && rho <= a.x.max(b.x) {
                take(t, i);
            }
        } else {
            if a.x <= 0.0 && b.x <= 0.0 {
                return; // on the axis: inside the solid, no surface
            }
            // rho = m + k (y - o.y) along the edge's line.
            let k = (b.x - a.x) / (b.y - a.y);
            let m = a.x + k * (o.y - a.y);
            let qa = d.x * d.x + d.z * d.z - k * k * d.y * d.y;
            let qb = o.x * d.x + o.z * d.z - k * m * d.y;
            let qc = o.x * o.x + o.z * o.z - m * m;
            let (y0, y1) = (a.y.min(b.y), a.y.max(b.y));
            for mut t in quadratic(qa, qb, qc) {
                if !t.is_finite() {
                    continue;
                }
                // One Newton step on the unexpanded equation recovers the
                // digits the coefficients lose.
                let p = o + d * t;
                let r = m + k * d.y * t;
                let g = p.x * p.x + p.z * p.z - r * r;
                let dg = 2.0 * (p.x * d.x + p.z * d.z - r * k * d.y);
                if dg != 0.0 {
                    let step = g / dg;
                    if step.abs() <= 1e-6 * (t.abs() + 1.0) {
                        t -= step;
                    }
                }
                let y = o.y + d.y * t;
                if y >= y0 && y <= y1 && m + k * d.y * t >= 0.0 {
                    take(t, i);
                }
            }
        }
    });
    let (t, i) = best?;
    let (a, b) = profile.edge(i);
    let n2 = edge_normal(a, b, profile.orientation());
    Some((t, swept_normal(n2, o + d * t)))
}

/// The outward normal (local frame) of the solid of revolution nearest `q`.
fn revolution_normal(profile: &Profile, q: DVec3) -> DVec3 {
    let n = profile.len();
    if n < 2 {
        return DVec3::Y;
    }
    let orient = profile.orientation();
    let m = DVec2::new(DVec2::new(q.x, q.z).length(), q.y);
    let mut best = (f64::INFINITY, 0);
    for i in 0..n {
        let (a, b) = (profile[i], profile[(i + 1) % n]);
        let e = b - a;
        let s = ((m - a).dot(e) / e.length_squared()).clamp(0.0, 1.0);
        let s = if s.is_finite() { s } else { 0.0 };
        let d2 = (m - (a + e * s)).length_squared();
        if d2 < best.0 {
            best = (d2, i);
        }
    }
    let (_, i) = best;
    let (a, b) = (profile[i], profile[(i + 1) % n]);
    // At a corner the normal of one of its edges stands in.
    let n2 = edge_normal(a, b, orient);
    swept_normal(n2, q)
}

/// The mesh's nearest triangle crossed by the segment.
fn mesh_crossing(solid: &MeshSolid, o: DVec3, d: DVec3, lo: f64, hi: f64) -> Option<Crossing> {
    // The BVH takes hits with t < t_max; the crossing may sit on t_max.
    let ray = Ray::segment(o, d, lo, hi.next_up());
    let hit = solid.closest_hit(&ray)?;
    let normal = if solid.smooth() {
        hit.normal
    } else {
        hit.geometric_normal
    };
    Some(Crossing { t: hit.t, normal })
}

/// The mesh's normal at the point of its surface nearest `p`: the face
/// normal, or the interpolated vertex normal for a smooth mesh.
fn mesh_normal(solid: &MeshSolid, p: DVec3) -> DVec3 {
    let mesh = solid.mesh();
    let Some((t, x)) = solid.closest_triangle(p) else {
        return DVec3::Y;
    };
    let [a, b, c] = mesh.corners(t);
    let face = unit_or((b - a).cross(c - a), DVec3::Y);
    if !solid.smooth() {
        return face;
    }
    // Barycentric weights of x on the triangle.
    let (v0, v1, v2) = (b - a, c - a, x - a);
    let (d00, d01, d11) = (v0.dot(v0), v0.dot(v1), v1.dot(v1));
    let (d20, d21) = (v2.dot(v0), v2.dot(v1));
    let den = d00 * d11 - d01 * d01;
    if den == 0.0 {
        return face;
    }
    let w1 = (d11 * d20 - d01 * d21) / den;
    let w2 = (d00 * d21 - d01 * d20) / den;
    let w0 = 1.0 - w1 - w2;
    let tri = mesh.triangles()[t];
    let vn = mesh.normals();
    let n = vn[tri[0] as usize] * w0 + vn[tri[1] as usize] * w1 + vn[tri[2] as usize] * w2;
    unit_or(n, face)
}

/// Cubic polynomial coefficients, constant first.
type Cubic = [f64; 4];

fn eval(p: &Cubic, s: f64) -> f64 {
    ((p[3] * s + p[2]) * s + p[1]) * s + p[0]
}

/// The first crossing of the VDB solid's surface: the cells the segment
/// passes, one cubic per cell (see the module docs).
fn vdb_crossing(solid: &VdbSolid, o: DVec3, d: DVec3, lo: f64, hi: f64) -> Option<f64> {
    let vol = solid.volume();
    let thr = solid.threshold();
    let dims = vol.dims();
    if dims.contains(&0) {
        return None; // the background everywhere
    }
    let org = vol.origin();
    let h = vol.transform.voxel_size;
    let u0 = vol.transform.world_to_index(o);
    let du = d / h;
    if !u0.is_finite() || !du.is_finite() {
        return None;
    }
    // The dense box has a voxel of background all round: beyond the
    // middle of that layer the interpolant is the constant background.
    let (mut a, mut b) = (lo, hi);
    for k in 0..3 {
        let (s0, s1) = slab(
            u0[k],
            du[k],
            org[k] as f64 - 0.5,
            org[k] as f64 + dims[k] as f64 - 0.5,
        );
        a = a.max(s0);
        b = b.min(s1);
    }
    if !before(a, b) {
        return None;
    }
    let mut side: Option<bool> = None;
    let mut t = a;
    let mut steps = 0usize;
    while t < b && steps < MAX_MARCH {
        steps += 1;
        let u = u0 + du * t;
        let mut cell = [0i32; 3];
        let mut te = b;
        for k in 0..3 {
            let c = if du[k] < 0.0 {
                u[k].ceil() - 1.0
            } else {
                u[k].floor()
            };
            cell[k] = c as i32;
            if du[k] > 0.0 {
                te = te.min((c + 1.0 - u0[k]) / du[k]);
            } else if du[k] < 0.0 {
                te = te.min((c - u0[k]) / du[k]);
            }
        }
        if te <= t {
            // Rounding at a cell face: nudge across it.
            te = (t + (t.abs() + 1.0) * 1e-15).min(b);
            if te <= t {
                break;
            }
        }
        let mut v = [0.0f64; 8];
        for (corner, val) in v.iter_mut().enumerate() {
            let ijk = [
                cell[0] + (corner & 1) as i32,
                cell[1] + ((corner >> 1) & 1) as i32,
                cell[2] + ((corner >> 2) & 1) as i32,
            ];
            *val = vol.value(ijk) as f64 - thr;
        }
        let all_in = v.iter().all(|&x| x > 0.0);
        let all_out = v.iter().all(|&x| x <= 0.0);
        if all_in || all_out {
            // The interpolant is a mean of the corners: one side throughout.
            match side {
                Some(s) if s != all_in => return Some(t),
                _ => side = Some(all_in),
            }
            t = te;
            continue;
        }
        // The interpolant along the line, s = t' - t in [0, te - t].
        let f0 = u - DVec3::new(cell[0] as f64, cell[1] as f64, cell[2] as f64);
        let mut poly: Cubic = [0.0; 4];
        for (corner, &val) in v.iter().enumerate() {
            let mut p: Cubic = [val, 0.0, 0.0, 0.0];
            for k in 0..3 {
                let (c0, c1) = if (corner >> k) & 1 == 1 {
                    (f0[k], du[k])
                } else {
                    (1.0 - f0[k], -du[k])
                };
                p = [
                    p[0] * c0,
                    p[1] * c0 + p[0] * c1,
                    p[2] * c0 + p[1] * c1,
                    p[3] * c0 + p[2] * c1,
                ];
            }
            for i in 0..4 {
                poly[i] += p[i];
            }
        }
        let len = te - t;
        // Split at the extrema: each piece is monotone.
        let mut pts = [0.0, f64::NAN, f64::NAN, len];
        let crit = quadratic(3.0 * poly[3], poly[2], poly[1]);
        for (slot, c) in pts[1..3].iter_mut().zip(crit) {
            if c > 0.0 && c < len {
                *slot = c;
            }
        }
        if pts[1] > pts[2] {
            pts.swap(1, 2);
        }
        let s0 = eval(&poly, 0.0) > 0.0;
        let mut cur = match side {
            Some(s) if s != s0 => return Some(t),
            _ => s0,
        };
        let mut prev = 0.0;
        for &s in pts[1..].iter().filter(|s| s.is_finite()) {
            let here = eval(&poly, s) > 0.0;
            if here != cur {
                let root = bisect(|x| eval(&poly, x) > 0.0, prev, s, cur);
                return Some(t + root);
            }
            (prev, cur) = (s, here);
        }
        side = Some(cur);
        t = te;
    }
    None
}

/// Outward normal of the VDB solid at `p`: minus the gradient of the
/// trilinear interpolant (of its cell), normalized.
fn vdb_normal(solid: &VdbSolid, p: DVec3) -> DVec3 {
    let vol = solid.volume();
    let u = vol.transform.world_to_index(p);
    if !u.is_finite() {
        return DVec3::Y;
    }
    let f = u.floor();
    let w = u - f;
    let base = [f.x as i32, f.y as i32, f.z as i32];
    let mut g = DVec3::ZERO;
    for corner in 0..8 {
        let bit = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
        let val = vol.value([base[0] + bit[0], base[1] + bit[1], base[2] + bit[2]]) as f64;
        let wt = |k: usize| if bit[k] == 1 { w[k] } else { 1.0 - w[k] };
        let dw = |k: usize| if bit[k] == 1 { 1.0 } else { -1.0 };
        g.x += val * dw(0) * wt(1) * wt(2);
        g.y += val * wt(0) * dw(1) * wt(2);
        g.z += val * wt(0) * wt(1) * dw(2);
    }
    unit_or(-g / vol.transform.voxel_size, DVec3::Y)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shape::rotation_from_degrees;
    use crate::vdb::{FloatGrid, FloatVolume, Transform, Tree};
    use eikon_rng::SplitMix64;
    use std::sync::Arc;

    fn dir(rng: &mut SplitMix64) -> DVec3 {
        DVec3::from_array(rng.direction())
    }

    /// The first change of `contains` along the segment by dense sampling,
    /// then bisection with `contains` alone: (t, sample spacing).
    fn brute(s: &Shape, o: DVec3, d: DVec3, t0: f64, t1: f64, n: usize) -> Option<f64> {
        let side = s.contains(o + d * t0);
        let mut prev = t0;
        for i in 1..=n {
            let t = t0 + (t1 - t0) * i as f64 / n as f64;
            if s.contains(o + d * t) != side {
                return Some(bisect(|x| s.contains(o + d * x), prev, t, side));
            }
            prev = t;
        }
        None
    }

    struct Report {
        hits: usize,
        worst_t: f64,
        worst_distance: f64,
        worst_normal: f64,
        grazes: usize,
    }

    /// Random segments against brute force; `analytic`: check the distance
    /// at the hit and the normal against the distance's gradient.
    fn check(s: &Shape, segments: usize, samples: usize, analytic: bool, seed: u64) -> Report {
        let (lo, hi) = s.aabb().unwrap_or((DVec3::splat(-1.0), DVec3::splat(1.0)));
        let (c, ext) = ((lo + hi) * 0.5, (hi - lo).length());
        let mut rng = SplitMix64::new(seed);
        let mut r = Report {
            hits: 0,
            worst_t: 0.0,
            worst_distance: 0.0,
            worst_normal: 0.0,
            grazes: 0,
        };
        for i in 0..segments {
            let o = c + dir(&mut rng) * ext * rng.uniform(0.0, 1.0);
            // Half the segments aim at a point inside the box, all have
            // a direction of random length.
            let aim = lo + (hi - lo) * DVec3::new(rng.unit(), rng.unit(), rng.unit());
            let w = if i % 2 == 0 {
                (aim - o).normalize_or(DVec3::X)
            } else {
                dir(&mut rng)
            };
            let d = w * rng.uniform(0.2, 3.0);
            let (t0, t1) = (
                rng.uniform(-0.5, 0.2),
                rng.uniform(0.5, 2.0) * ext / d.length(),
            );
            let spacing = (t1 - t0) / samples as f64;
            let want = brute(s, o, d, t0, t1, samples);
            let got = s.first_crossing(o, d, t0, t1);
            let scale = ext / d.length();
            match (got, want) {
                (Some(g), Some(w)) => {
                    let err = (g.t - w).abs() / scale;
                    if err > 1e-11 {
                        // Only a graze the samples stepped over may come
                        // first, and it must be a real change of side.
                        assert!(g.t < w, "{} seg {i}: t {} vs brute {w}", s.kind(), g.t);
                        assert!(w - g.t > 0.0);
                        r.grazes += 1;
                    } else {
                        r.worst_t = r.worst_t.max(err);
                    }
                }
                (Some(g), None) => {
                    // A pair of crossings between two samples.
                    let next = s.first_crossing(o, d, g.t, t1);
                    assert!(
                        next.is_some_and(|n| n.t - g.t < 2.0 * spacing),
                        "{} seg {i}: crossing at {} that brute force has not",
                        s.kind(),
                        g.t
                    );
                    r.grazes += 1;
                }
                (None, Some(w)) => panic!("{} seg {i}: missed the crossing at {w}", s.kind()),
                (None, None) => {}
            }
            let Some(g) = got else { continue };
            r.hits += 1;
            let p = o + d * g.t;
            assert!((g.normal.length() - 1.0).abs() < 1e-12);
            let e = 1e-7 * scale;
            let grazing = g.normal.dot(d.normalize()).abs() < 1e-3;
            if !grazing {
                assert_ne!(
                    s.contains(o + d * (g.t - e)),
                    s.contains(o + d * (g.t + e)),
                    "{} seg {i}: no change of side at {}",
                    s.kind(),
                    g.t
                );
                let eps = 1e-7 * ext;
                assert!(
                    s.contains(p - g.normal * eps),
                    "{} seg {i}: normal",
                    s.kind()
                );
                assert!(
                    !s.contains(p + g.normal * eps),
                    "{} seg {i}: normal",
                    s.kind()
                );
            }
            if analytic {
                r.worst_distance = r.worst_distance.max(s.distance(p).abs() / ext);
                let h = 1e-7 * ext;
                let grad = DVec3::new(
                    s.distance(p + DVec3::X * h) - s.distance(p - DVec3::X * h),
                    s.distance(p + DVec3::Y * h) - s.distance(p - DVec3::Y * h),
                    s.distance(p + DVec3::Z * h) - s.distance(p - DVec3::Z * h),
                )
                .normalize();
                let dn = (grad - g.normal).length();
                // Away from edges and creases, where the gradient jumps.
                if dn < 0.1 {
                    r.worst_normal = r.worst_normal.max(dn);
                }
                assert!((s.normal(p) - g.normal).length() < 1e-6 || dn >= 0.1);
            }
            // Starting on the surface finds the next crossing, not this one.
            if let Some(next) = s.first_crossing(o, d, g.t, t1) {
                assert!(next.t > g.t + 1e-13 * scale, "{} seg {i}", s.kind());
                if let Some(w) = brute(s, o, d, g.t + 1e-9 * scale, t1, samples) {
                    assert!(
                        (next.t - w).abs() < 1e-11 * scale || next.t < w,
                        "{} seg {i}: next {} vs {w}",
                        s.kind(),
                        next.t
                    );
                }
            }
        }
        assert!(r.hits > segments / 5, "{}: only {} hits", s.kind(), r.hits);
        assert!(
            r.grazes * 100 < segments,
            "{}: {} grazes",
            s.kind(),
            r.grazes
        );
        assert!(r.worst_t < 1e-11, "{}: t error {}", s.kind(), r.worst_t);
        if analytic {
            assert!(
                r.worst_distance < 1e-12,
                "{}: {}",
                s.kind(),
                r.worst_distance
            );
            assert!(r.worst_normal < 1e-5, "{}: {}", s.kind(), r.worst_normal);
        }
        eprintln!(
            "{}: {} hits, worst |dt|/scale {:.2e}, |distance|/size {:.2e}, normal {:.2e}, {} grazes",
            s.kind(),
            r.hits,
            r.worst_t,
            r.worst_distance,
            r.worst_normal,
            r.grazes
        );
        r
    }

    fn rot() -> DMat3 {
        rotation_from_degrees([23.0, -41.0, 67.0])
    }

    #[test]
    fn surface_sphere_matches_brute_force() {
        let s = Shape::Sphere {
            center: DVec3::new(0.1, -0.2, 0.05),
            radius: 0.7,
        };
        check(&s, 3000, 20_000, true, 1);
    }

    #[test]
    fn surface_boxes_match_brute_force() {
        for radius in [0.0, 0.12] {
            let s = Shape::Box {
                center: DVec3::new(0.2, 0.1, -0.1),
                half: DVec3::new(0.5, 0.3, 0.4),
                radius,
                rot: rot(),
            };
            check(&s, 3000, 20_000, true, 2);
        }
    }

    #[test]
    fn surface_cylinder_matches_brute_force() {
        let s = Shape::Cylinder {
            center: DVec3::new(-0.1, 0.0, 0.3),
            radius: 0.35,
            half_height: 0.6,
            rot: rot(),
        };
        check(&s, 3000, 20_000, true, 3);
    }

    #[test]
    fn surface_half_space_matches_brute_force() {
        let s = Shape::HalfSpace {
            point: DVec3::new(0.1, 0.2, -0.3),
            normal: DVec3::new(0.3, -0.5, 0.8).normalize(),
        };
        check(&s, 3000, 20_000, true, 4);
    }

    fn wine_glass() -> Shape {
        let profile = [
            (0.0, 0.0),
            (0.4, 0.0),
            (0.4, 0.03),
            (0.06, 0.08),
            (0.05, 0.5),
            (0.35, 0.7),
            (0.45, 1.0),
            (0.42, 1.0),
            (0.32, 0.73),
            (0.0, 0.6),
        ];
        Shape::Revolution {
            base: DVec3::new(0.0, -0.5, 0.1),
            profile: Profile::new(profile.iter().map(|&(x, y)| DVec2::new(x, y)).collect()),
            rot: rot(),
        }
    }

    #[test]
    fn surface_revolution_matches_brute_force() {
        check(&wine_glass(), 3000, 20_000, true, 5);
        // The same profile clockwise: the normals must still point out.
        if let Shape::Revolution { base, profile, rot } = wine_glass() {
            let reversed = Profile::new(profile.iter().rev().copied().collect());
            let s = Shape::Revolution {
                base,
                profile: reversed,
                rot,
            };
            check(&s, 1000, 20_000, true, 6);
        }
    }

    #[test]
    fn surface_torus_matches_brute_force() {
        let s = Shape::Torus {
            center: DVec3::new(0.1, 0.0, -0.2),
            major: 0.6,
            minor: 0.2,
            rot: rot(),
        };
        check(&s, 3000, 20_000, true, 7);
    }

    #[test]
    fn surface_superquadrics_match_brute_force() {
        // 1: the ellipsoid's closed form; 0.7 as in the amber scene, 0.3
        // as in the shapes scene; 2, the octahedron, the last marched by
        // its bound alone; 2.5 a star.
        for e in [0.5, 1.0, 0.7, 0.3, 2.0, 2.5] {
            let s = Shape::Superquadric {
                center: DVec3::new(0.0, 0.1, 0.0),
                radii: DVec3::new(0.6, 0.4, 0.5),
                e1: e,
                e2: e,
                rot: rot(),
            };
            check(&s, 2000, 20_000, true, 8);
        }
    }

    #[test]
    fn surface_mesh_matches_brute_force() {
        for smooth in [false, true] {
            let mut mesh = eikon_mesh::icosphere(0.7, 2).unwrap();
            mesh.transform(glam::DAffine3::from_mat3_translation(
                rot() * DMat3::from_diagonal(DVec3::new(1.0, 0.6, 0.8)),
                DVec3::new(0.1, 0.0, -0.1),
            ))
            .unwrap();
            let s = Shape::Mesh(Arc::new(MeshSolid::new(Arc::new(mesh), smooth)));
            let r = check(&s, 600, 5000, false, 9);
            assert!(r.hits > 200);
            // Smooth shading normals still point out of the mesh.
            let mut rng = SplitMix64::new(10);
            for _ in 0..200 {
                let o = dir(&mut rng) * 3.0;
                if let Some(c) = s.first_crossing(o, -o, 0.0, 1.0) {
                    assert!(c.normal.dot(o) > 0.0);
                    let n = s.normal(o * (1.0 - c.t));
                    assert!((n - c.normal).length() < 1e-6, "{n} {}", c.normal);
                }
            }
        }
    }

    #[test]
    fn surface_vdb_matches_brute_force() {
        // A blobby ball of radius about 6 voxels as a density grid.
        let tree = Tree::from_dense([24, 24, 24], [-12; 3], 0.0, |[i, j, k]| {
            let p = DVec3::new(i as f64 - 12.0, j as f64 - 12.0, k as f64 - 12.0);
            let r = 6.0 + 1.5 * (0.7 * p.x).sin() * (0.5 * p.y).cos();
            ((r - p.length()) * 0.5).clamp(-1.0, 1.0).max(0.0) as f32
        });
        let grid = FloatGrid {
            path: Default::default(),
            name: "density".into(),
            transform: Transform {
                voxel_size: DVec3::new(0.05, 0.06, 0.05),
                translation: DVec3::new(0.3, 0.0, -0.2),
            },
            half: false,
            tree,
        };
        let volume = Arc::new(FloatVolume::from_grid(grid).unwrap());
        let s = Shape::Vdb(Arc::new(VdbSolid::new(volume, 0.3)));
        check(&s, 2000, 20_000, false, 11);
    }

    /// Short segments around the surface (a light step is half a voxel)
    /// find what the segment that runs on past them finds: the culling of
    /// the revolution's edges by height and of the rounded box by its
    /// distance drops no crossing and invents none.
    #[test]
    fn short_segments_agree_with_long_ones() {
        let rounded = Shape::Box {
            center: DVec3::new(0.05, -0.1, 0.0),
            half: DVec3::new(0.5, 0.4, 0.3),
            radius: 0.12,
            rot: rot(),
        };
        for s in [wine_glass(), rounded] {
            let (lo, hi) = s.aabb().unwrap();
            let ext = (hi - lo).length();
            let mut rng = SplitMix64::new(11);
            let (mut hits, mut misses) = (0, 0);
            for _ in 0..20_000 {
                let aim = lo + (hi - lo) * DVec3::new(rng.unit(), rng.unit(), rng.unit());
                let d = dir(&mut rng);
                let o = aim - d * ext;
                let Some(c) = s.first_crossing(o, d, 0.0, 2.0 * ext) else {
                    continue;
                };
                // A short segment that starts before the crossing (or just
                // misses it) and one that starts beyond it.
                let len = ext * 10f64.powf(rng.uniform(-5.0, -1.0));
                for start in [c.t - len * rng.uniform(0.0, 1.2), c.t + len * 0.01] {
                    let long = s.first_crossing(o, d, start, 2.0 * ext);
                    let short = s.first_crossing(o, d, start, start + len);
                    let want = long.filter(|l| l.t <= start + len);
                    match (short, want) {
                        (Some(a), Some(b)) => {
                            assert!((a.t - b.t).abs() <= 1e-12 * ext, "{} {a:?} {b:?}", s.kind());
                            hits += 1;
                        }
                        (None, None) => misses += 1,
                        (a, b) => panic!("{}: short {a:?}, long {b:?}", s.kind()),
                    }
                }
            }
            assert!(
                hits > 5000 && misses > 2000,
                "{}: {hits} {misses}",
                s.kind()
            );
        }
    }

    #[test]
    fn surface_closed_forms_are_exact() {
        let s = Shape::Sphere {
            center: DVec3::new(1.0, 2.0, 3.0),
            radius: 0.5,
        };
        let c = s
            .first_crossing(DVec3::new(1.0, 2.0, 0.0), DVec3::Z * 2.0, 0.0, 10.0)
            .unwrap();
        assert_eq!(c.t, 1.25);
        assert_eq!(c.normal, -DVec3::Z);
        // From the surface, the exit.
        let c = s
            .first_crossing(DVec3::new(1.0, 2.0, 0.0), DVec3::Z * 2.0, c.t, 10.0)
            .unwrap();
        assert_eq!(c.t, 1.75);
        assert_eq!(c.normal, DVec3::Z);
        // Restarted at the crossing point with a new direction (t_min = 0).
        let c = s
            .first_crossing(
                DVec3::new(1.0, 2.0, 2.5),
                DVec3::new(0.0, 0.1, 1.0),
                0.0,
                10.0,
            )
            .unwrap();
        assert!(c.t > 0.1);
        assert!(s
            .first_crossing(DVec3::ZERO, DVec3::ZERO, 0.0, 1.0)
            .is_none());
        assert!(s.first_crossing(DVec3::ZERO, DVec3::X, 0.0, 1.0).is_none());

        let b = Shape::Box {
            center: DVec3::ZERO,
            half: DVec3::new(1.0, 2.0, 3.0),
            radius: 0.0,
            rot: DMat3::IDENTITY,
        };
        let c = b
            .first_crossing(DVec3::new(0.5, -5.0, 0.5), DVec3::Y, 0.0, 10.0)
            .unwrap();
        assert_eq!((c.t, c.normal), (3.0, -DVec3::Y));
        let c = b
            .first_crossing(DVec3::new(0.5, -5.0, 0.5), DVec3::Y, 3.0, 10.0)
            .unwrap();
        assert_eq!((c.t, c.normal), (7.0, DVec3::Y));
        assert!(b
            .first_crossing(DVec3::new(0.5, -5.0, 0.5), DVec3::Y, 0.0, 2.9)
            .is_none());

        let n = DVec3::new(1.0, 2.0, 2.0) / 3.0;
        let h = Shape::HalfSpace {
            point: DVec3::ZERO,
            normal: n,
        };
        let c = h.first_crossing(n * 4.0, -n, 0.0, 10.0).unwrap();
        assert!((c.t - 4.0).abs() < 1e-15);
        assert_eq!(c.normal, n);
        assert!(h.first_crossing(n * 4.0, n, 0.0, 10.0).is_none());

        let cyl = Shape::Cylinder {
            center: DVec3::ZERO,
            radius: 0.5,
            half_height: 1.0,
            rot: DMat3::IDENTITY,
        };
        let c = cyl
            .first_crossing(DVec3::new(-2.0, 0.3, 0.0), DVec3::X, 0.0, 10.0)
            .unwrap();
        assert_eq!((c.t, c.normal), (1.5, -DVec3::X));
        let c = cyl
            .first_crossing(DVec3::new(0.1, 3.0, 0.0), -DVec3::Y, 0.0, 10.0)
            .unwrap();
        assert_eq!((c.t, c.normal), (2.0, DVec3::Y));
    }
}
