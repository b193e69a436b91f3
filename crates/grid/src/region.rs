//! Sharp interfaces: the medium as regions (each object's interior, and the
//! ambient medium), each with its own index profile, separated by the
//! objects' exact surfaces.
//!
//! [Ihrke07 sec 5.1] smooths the whole index field, interfaces included, so
//! that the ray equation [Ihrke07 eq 8] bends rays through them; the price
//! is an interface a few voxels wide (its Fig. 7 shows the shift against
//! POV-Ray). Smoothing is right for an index that varies continuously and
//! wrong for a jump between two materials. With [`Interfaces::Sharp`]:
//!
//! * inside a region a ray follows the ray equation through that region's
//!   own profile, sampled exactly ([`Regions::index`]: constant, Luneburg,
//!   linear, a VDB grid), never across a surface; a region of constant
//!   index is crossed in one straight step, surface to surface;
//! * a step that would leave the region is cut at the surface
//!   ([`crate::surface`]: closed forms, root finding, the mesh's BVH), and
//!   there Snell's law or total internal reflection is applied with the
//!   exact normal and the index on either side ([`refract`]);
//! * which region lies beyond a surface follows the scene's priorities
//!   [SchmidtBudge02 sec 2]: a crossing that does not change the owner
//!   (the surface of a lower-priority object inside a higher one) is a
//!   false crossing and changes nothing.
//!
//! Snell's law in the eikonal's terms: the tangential part of `v = grad S`
//! (`|v| = n`) is continuous across an interface, and the normal part takes
//! whatever length makes `|v| = n2`; when none does, the interface reflects
//! totally.

use crate::blocks::{BlockGrid, BLOCK};
use crate::field::Medium;
use crate::object::Material;
use crate::ray::{step_euler, step_rk4, Form, Integrator, RayState};
use crate::scene::Scene;
use crate::surface::Crossing;
use eikon_optics::fresnel;
use glam::DVec3;
use rayon::prelude::*;
use serde::Deserialize;

/// How rays meet the surfaces between materials (`[grid] interfaces`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Interfaces {
    /// The paper's way [Ihrke07 sec 5.1]: the index is smoothed across
    /// every interface and the ray equation bends rays through the band.
    Smoothed,
    /// Exact surfaces between regions, the ray equation inside each (this
    /// module). The default: what physics, and every renderer with exact
    /// surfaces, does at an interface.
    #[default]
    Sharp,
}

impl Interfaces {
    /// The name used in scene files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Interfaces::Smoothed => "smoothed",
            Interfaces::Sharp => "sharp",
        }
    }
}

/// A region: the interior of object `Some(i)` (after priorities), or the
/// ambient medium (`None`).
pub type Region = Option<usize>;

/// The scene's regions and surfaces, for tracing rays with sharp
/// interfaces.
pub struct Regions<'a> {
    scene: &'a Scene,
    /// Each object's bounding box (None: unbounded), padded by `eps`.
    boxes: Vec<Option<(DVec3, DVec3)>>,
    /// Each object's [`Shape::fixed_size`](crate::Shape::fixed_size), kept
    /// rather than recomputed per surface test.
    sizes: Vec<Option<f64>>,
    /// Length below which two points on a ray are the same point: a crossing
    /// is found only beyond it, and the far side of a surface is probed
    /// this far from it. A billionth of a voxel.
    eps: f64,
    /// Blocks no surface comes near, when known ([`Regions::clear_of`]).
    clear: Option<Clear>,
}

/// The 4^3 blocks of a grid that no surface comes near: every shape's
/// distance bound at the block's centre exceeds half the block's diagonal
/// and a voxel, or the boundary indicator of the voxel medium built from
/// the same scene is zero throughout the block and a voxel around it. So a
/// straight piece no longer than a voxel that starts in the block crosses
/// no surface, and the whole block belongs to one region. There a ray needs no surface test and
/// no owner query.
struct Clear {
    blocks: BlockGrid,
    /// Per block: 0 when a surface may come near, else the owner's code
    /// (1 for the ambient medium, 2 + i for object i).
    owner: Vec<u32>,
    /// The longest piece that stays within a block's margin: one voxel.
    reach: f64,
}

/// What happened where a ray met a surface that separates two regions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Event {
    /// The object whose surface it is.
    pub surface: usize,
    /// The point on the surface.
    pub point: DVec3,
    /// Unit normal of the surface, pointing the way the ray travelled
    /// (from the region it came from into the other).
    pub normal: DVec3,
    /// The ray's unit direction as it met the surface.
    pub incident: DVec3,
    /// Index on the side it came from, and on the other side.
    pub n1: f64,
    /// Index on the other side.
    pub n2: f64,
    /// Unpolarized Fresnel reflectance at the crossing [BornWolf99]; 1
    /// under total internal reflection.
    pub reflectance: f64,
    /// The surface reflected the ray totally: it stays in its region.
    pub total: bool,
    /// The region it came from.
    pub from: Region,
    /// The region on the other side.
    pub to: Region,
}

/// One step of [`Regions::step`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Step {
    /// How much of the step was used, in the form's units (distance, or
    /// optical path): less than asked when the ray stopped at a surface.
    pub used: f64,
    /// The surface where the step stopped, if it separates two regions.
    pub event: Option<Event>,
    /// The step stopped at a surface (a true or a false crossing).
    pub at_surface: bool,
}

/// A ray with sharp interfaces: its state and the region it is in.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SharpRay {
    /// Position, eikonal gradient and optical path.
    pub s: RayState,
    /// The region the ray is in.
    pub region: Region,
    /// Looking ahead: `None`, each straight step asks for the surfaces
    /// within its own length (light, whose corners start afresh each
    /// step); `Some(d)`, the first straight step asks once as far as the
    /// grid's edge and the ray keeps `d`, how far on along its line no
    /// surface lies, so the steps after it ask nothing until they come
    /// near (eye rays gathering cell by cell through a scattering region).
    pub ahead: Option<f64>,
}

/// Snell's law for the eikonal gradient `v` (`|v| = n1`) crossing a
/// surface with unit `normal` along the direction of travel
/// (`v . normal > 0`) into index `n2`: the tangential part is kept and the normal part
/// takes the length that makes `|v| = n2`. `None` when no length does
/// (total internal reflection).
#[inline]
pub fn refract(v: DVec3, normal: DVec3, n2: f64) -> Option<DVec3> {
    let vn = v.dot(normal);
    let vt = v - normal * vn;
    let rest = n2 * n2 - vt.length_squared();
    (rest >= 0.0).then(|| vt + normal * rest.sqrt())
}

impl<'a> Regions<'a> {
    /// The regions of `scene`, on the scale of its grid's voxels.
    pub fn new(scene: &'a Scene) -> Self {
        let eps = 1e-9 * scene.grid.geometry.voxel_size();
        let boxes = scene
            .objects
            .iter()
            .map(|o| {
                o.shape
                    .aabb()
                    .map(|(a, b)| (a - DVec3::splat(eps), b + DVec3::splat(eps)))
            })
            .collect();
        let sizes = scene.objects.iter().map(|o| o.shape.fixed_size()).collect();
        Self {
            scene,
            boxes,
            sizes,
            eps,
            clear: None,
        }
    }

    /// The scene.
    pub fn scene(&self) -> &Scene {
        self.scene
    }

    /// The tolerance of crossings, world units (see the field's docs).
    pub fn eps(&self) -> f64 {
        self.eps
    }

    /// Skip the surface tests and owner queries far from every surface,
    /// as the shapes' distance bounds and the boundary indicator of
    /// `medium` (built from this scene; the bounds alone once
    /// [`Medium::release_boundary`] freed it) show it (see [`Clear`]).
    /// Results are the same; only the work differs.
    pub fn clear_of(mut self, medium: &Medium) -> Self {
        let g = &medium.geometry;
        if g.dims != self.scene.grid.geometry.dims {
            return self;
        }
        let blocks = BlockGrid::new(g);
        // Released (`Medium::release_boundary`): the distance bounds alone.
        let bnd = (medium.boundary.dim() == (g.dims[0], g.dims[1], g.dims[2]))
            .then_some(&medium.boundary);
        let reach = g.spacing().min_element();
        // A point of the block lies within half its diagonal of the centre;
        // a piece from it within `reach` more. Where every shape's distance
        // bound at the centre exceeds both (the true distance is at least
        // the bound), no surface comes that near.
        let far = 0.5 * (g.spacing() * BLOCK as f64).length() + reach;
        let far = far * (1.0 + 1e-9);
        let objects = &self.scene.objects;
        let owner = (0..blocks.len())
            .into_par_iter()
            .map(|f| {
                let b = blocks.coords(f);
                let c = blocks.centre(b);
                if objects.iter().all(|o| o.shape.distance(c).abs() > far)
                    || bnd.is_some_and(|bnd| blocks.all_around(b, |i, j, k| bnd[[i, j, k]] == 0.0))
                {
                    match self.scene.owner(c) {
                        None => 1,
                        Some(i) => 2 + i as u32,
                    }
                } else {
                    0
                }
            })
            .collect();
        self.clear = Some(Clear {
            blocks,
            owner,
            reach,
        });
        self
    }

    /// The region of `p` when `p` lies in a block no surface comes near.
    #[inline]
    fn clear_region(&self, p: DVec3) -> Option<Region> {
        let c = self.clear.as_ref()?;
        let (b, _) = c.blocks.locate(p)?;
        match c.owner[c.blocks.flat(b)] {
            0 => None,
            1 => Some(None),
            code => Some(Some(code as usize - 2)),
        }
    }

    /// The region that owns `p` [SchmidtBudge02 sec 2].
    #[inline]
    pub fn at(&self, p: DVec3) -> Region {
        match self.clear_region(p) {
            Some(r) => r,
            // `Scene::owner`, with the bounding boxes ruling out most
            // objects before their shapes are asked.
            None => self.scene.precedence().iter().copied().find(|&i| {
                self.boxes[i].is_none_or(|(lo, hi)| p.cmpge(lo).all() && p.cmple(hi).all())
                    && self.scene.objects[i].shape.contains(p)
            }),
        }
    }

    /// The material of region `r`.
    #[inline]
    pub fn material(&self, r: Region) -> &Material {
        match r {
            Some(i) => &self.scene.objects[i].material,
            None => &self.scene.ambient,
        }
    }

    /// Whether the index of region `r` is one constant (rays go straight).
    #[inline]
    pub fn uniform(&self, r: Region) -> bool {
        let m = self.material(r);
        m.index_grid.is_none() && matches!(m.index, crate::IndexProfile::Constant(_))
    }

    /// Whether region `r` bends every colour channel alike: its index is
    /// the same for all three ([`crate::IndexProfile::achromatic`]; a VDB index
    /// grid holds one index for all).
    #[inline]
    pub fn achromatic(&self, r: Region) -> bool {
        let m = self.material(r);
        m.index_grid.is_some() || m.index.achromatic()
    }

    /// The index of region `r` at `p` for colour `ch`, and its gradient:
    /// the region's own profile, exactly (a VDB index grid by central
    /// differences half a grid voxel either way).
    #[inline]
    pub fn index(&self, r: Region, p: DVec3, ch: usize) -> (f64, DVec3) {
        let m = self.material(r);
        match &m.index_grid {
            None => m.index.sample(p, ch),
            Some(g) => {
                let t = &g.volume.transform;
                let h = 0.5 * (t.index_to_world(DVec3::X) - t.index_to_world(DVec3::ZERO)).length();
                let d = |e: DVec3| (g.value(p + e * h) - g.value(p - e * h)) / (2.0 * h);
                (
                    g.value(p),
                    DVec3::new(d(DVec3::X), d(DVec3::Y), d(DVec3::Z)),
                )
            }
        }
    }

    /// The first surface the segment `o + d t`, `eps < t <= t_max`, crosses
    /// (`d` unit): the object and where.
    pub fn next_surface(&self, o: DVec3, d: DVec3, t_max: f64) -> Option<(usize, Crossing)> {
        let mut best: Option<(usize, Crossing)> = None;
        for (i, obj) in self.scene.objects.iter().enumerate() {
            let limit = best.map_or(t_max, |(_, c)| c.t);
            if let Some((lo, hi)) = self.boxes[i] {
                match slab(o, d, lo, hi) {
                    Some((t0, t1)) if t1 > self.eps && t0 <= limit => {}
                    _ => continue,
                }
            }
            let crossing = match self.sizes[i] {
                Some(size) => obj.shape.first_crossing_sized(o, d, self.eps, limit, size),
                None => obj.shape.first_crossing(o, d, self.eps, limit),
            };
            if let Some(c) = crossing {
                if best.is_none_or(|(_, b)| c.t < b.t) {
                    best = Some((i, c));
                }
            }
        }
        best
    }

    /// Move a ray that a step left on a surface (its length ran out where
    /// it crossed) a few `eps` on along its direction, until the region
    /// its position reports is the one it is in ([`SharpRay::region`]):
    /// a step that starts there takes its region from its position, and
    /// its crossing test skips what lies within `eps` of its start, so a
    /// ray left on the surface could pass back through it unseen. The
    /// optical path is not changed (the move is a millionth of a voxel at
    /// most).
    pub fn settle(&self, ray: &mut SharpRay) {
        let d = ray.s.v.normalize_or_zero();
        let mut h = 2.0 * self.eps;
        for _ in 0..4 {
            if self.at(ray.s.x) == ray.region {
                return;
            }
            ray.s.x += d * h;
            h *= 8.0;
        }
    }

    /// The ray is at `point` on a surface with unit outward `normal`: find
    /// the region beyond and refract or reflect `ray` there. `None` for a
    /// false crossing (the same region on both sides).
    pub fn cross(
        &self,
        ray: &mut SharpRay,
        surface: usize,
        point: DVec3,
        normal: DVec3,
        ch: usize,
    ) -> Option<Event> {
        ray.s.x = point;
        let d = ray.s.v.normalize_or_zero();
        let along = if d.dot(normal) >= 0.0 {
            normal
        } else {
            -normal
        };
        let to = self.at(point + along * self.eps);
        let from = ray.region;
        if to == from {
            return None;
        }
        let n1 = self.index(from, point, ch).0;
        let n2 = self.index(to, point, ch).0;
        // On the eikonal shell |v| = n1 at the surface (the ray equation
        // keeps it there to the integrator's accuracy).
        let v = d * n1;
        let cos_i = d.dot(along);
        let event = |reflectance, total| Event {
            surface,
            point,
            normal: along,
            incident: d,
            n1,
            n2,
            reflectance,
            total,
            from,
            to,
        };
        match refract(v, along, n2) {
            Some(v2) => {
                ray.s.v = v2;
                ray.region = to;
                Some(event(fresnel::reflectance(cos_i, n1, n2), false))
            }
            None => {
                ray.s.v = v - along * (2.0 * v.dot(along));
                Some(event(1.0, true))
            }
        }
    }

    /// Advance `ray` by at most `h` (distance for [`Form::EqualDistance`],
    /// optical path for [`Form::EqualTime`]) within its region, stopping at
    /// the first surface it meets and crossing it there. A region of
    /// constant index is crossed straight; elsewhere one step of
    /// `integrator` on the region's profile is taken, and cut where its
    /// chord meets a surface (to [`Regions::eps`], by false position on the
    /// step length).
    pub fn step(
        &self,
        ray: &mut SharpRay,
        form: Form,
        integrator: Integrator,
        h: f64,
        ch: usize,
    ) -> Step {
        if self.uniform(ray.region) {
            let n = self.index(ray.region, ray.s.x, ch).0;
            let d = ray.s.v.normalize_or_zero();
            // The distance that uses the whole step.
            let per = match form {
                Form::EqualDistance => 1.0,
                Form::EqualTime => n,
            };
            let len = h / per;
            // A surface just beyond the step's end (within the crossing
            // test's `eps`, which the next step's test would skip as its
            // own start) is crossed now: a step never ends on a surface
            // without crossing it.
            let reach = len + 2.0 * self.eps;
            // Far from every surface a short piece crosses none.
            let clear = self.clear.as_ref().is_some_and(|c| {
                reach <= c.reach && self.clear_region(ray.s.x) == Some(ray.region)
            });
            let hit = match ray.ahead {
                _ if clear => None,
                None => self.next_surface(ray.s.x, d, reach),
                Some(free) if reach <= free => None,
                Some(_) => {
                    // The straight line on to the grid's edge (its surfaces
                    // beyond are met by the steps after a crossing).
                    let horizon = self
                        .scene
                        .grid
                        .geometry
                        .clip_line(ray.s.x, d)
                        .map_or(reach, |(_, t1)| t1.max(reach));
                    match self.next_surface(ray.s.x, d, horizon) {
                        Some(h) if h.1.t <= reach => Some(h),
                        beyond => {
                            ray.ahead = Some(beyond.map_or(horizon, |h| h.1.t));
                            None
                        }
                    }
                }
            };
            match hit {
                Some((obj, c)) => {
                    ray.s.opl += n * c.t;
                    ray.s.v = d * n;
                    let event = self.cross(ray, obj, ray.s.x + d * c.t, c.normal, ch);
                    ray.ahead = ray.ahead.map(|_| 0.0);
                    Step {
                        used: c.t * per,
                        event,
                        at_surface: true,
                    }
                }
                None => {
                    ray.s.x += d * len;
                    ray.s.v = d * n;
                    ray.s.opl += n * len;
                    ray.ahead = ray.ahead.map(|free| free - len);
                    Step {
                        used: h,
                        event: None,
                        at_surface: false,
                    }
                }
            }
        } else {
            // A curved path leaves the line looked along.
            ray.ahead = ray.ahead.map(|_| 0.0);
            self.curved_step(ray, form, integrator, h, ch)
        }
    }

    /// [`Regions::step`] in a region whose index varies.
    fn curved_step(
        &self,
        ray: &mut SharpRay,
        form: Form,
        integrator: Integrator,
        h: f64,
        ch: usize,
    ) -> Step {
        let field = RegionField {
            regions: self,
            region: ray.region,
            ch,
        };
        let take = |s: &mut RayState, h: f64| match integrator {
            Integrator::Euler => step_euler(&field, form, s, h),
            _ => step_rk4(&field, form, s, h),
        };
        // On the eikonal shell of the region's index, so that in the
        // equal-time form every step is exactly `h` of optical path.
        let n0 = self.index(ray.region, ray.s.x, ch).0;
        let len0 = ray.s.v.length();
        if len0 > 0.0 {
            ray.s.v *= n0 / len0;
        }
        let start = ray.s;
        let mut end = start;
        take(&mut end, h);
        let chord = end.x - start.x;
        let len = chord.length();
        let hit = if len > 0.0 {
            self.next_surface(start.x, chord / len, len)
        } else {
            None
        };
        let Some((obj, c)) = hit else {
            ray.s = end;
            return Step {
                used: h,
                event: None,
                at_surface: false,
            };
        };
        // Cut the step where its end lies on the surface: the object's
        // signed distance changes sign between the step's start side and
        // the chord's far end.
        let shape = &self.scene.objects[obj].shape;
        let u = chord / len;
        let side = if shape.contains(start.x + u * (0.5 * c.t)) {
            -1.0
        } else {
            1.0
        };
        let f = |s: &RayState| side * shape.distance(s.x);
        let (mut a, mut fa) = (0.0, f(&start).max(0.0));
        let (mut b, mut fb) = (h, f(&end));
        let mut at = end;
        if fb > 0.0 {
            // The end is back on the start's side (the step crossed the
            // surface twice, or grazed it): cut at the chord's crossing.
            b = h * (c.t / len);
            at = start;
            take(&mut at, b);
            fb = f(&at).min(0.0);
        }
        // Illinois false position: each iteration is one integrator step.
        let mut last = 0;
        for _ in 0..100 {
            if (b - a) <= self.eps || fb == 0.0 {
                break;
            }
            let m = if fa - fb != 0.0 {
                (b - fb * (b - a) / (fb - fa)).clamp(a + 0.01 * (b - a), b - 0.01 * (b - a))
            } else {
                0.5 * (a + b)
            };
            let mut s = start;
            take(&mut s, m);
            let fm = f(&s);
            if fm > 0.0 {
                a = m;
                fa = fm;
                if last == -1 {
                    fb *= 0.5;
                }
                last = -1;
            } else {
                b = m;
                fb = fm;
                at = s;
                if last == 1 {
                    fa *= 0.5;
                }
                last = 1;
            }
        }
        ray.s = at;
        let normal = shape.normal(at.x);
        let event = self.cross(ray, obj, at.x, normal, ch);
        if event.is_none() {
            // A false crossing, or a graze that turns back into the region
            // (a ray skimming a Luneburg lens's surface follows it): nothing
            // changes there, so the whole step stands. Cutting it would
            // creep along the surface a sliver at a time. (A graze that
            // ends just outside belongs to the region there.)
            ray.s = end;
            ray.region = self.at(end.x);
            return Step {
                used: h,
                event: None,
                at_surface: false,
            };
        }
        Step {
            used: b,
            event,
            at_surface: true,
        }
    }

    /// A ray at `x` heading along unit `dir`, in the region that owns `x`
    /// (on the eikonal shell of that region's index).
    pub fn ray(&self, x: DVec3, dir: DVec3, ch: usize) -> SharpRay {
        let region = self.at(x);
        SharpRay {
            s: RayState::new(x, dir, self.index(region, x, ch).0),
            region,
            ahead: Some(0.0),
        }
    }
}

/// One region's index profile as an [`crate::IndexField`], for the
/// integrators.
struct RegionField<'r, 'a> {
    regions: &'r Regions<'a>,
    region: Region,
    ch: usize,
}

impl crate::IndexField for RegionField<'_, '_> {
    #[inline]
    fn sample(&self, p: DVec3) -> (f64, DVec3) {
        self.regions.index(self.region, p, self.ch)
    }
}

/// The parameter range where the line `o + d t` is inside the box.
#[inline]
fn slab(o: DVec3, d: DVec3, lo: DVec3, hi: DVec3) -> Option<(f64, f64)> {
    let inv = d.recip();
    let a = (lo - o) * inv;
    let b = (hi - o) * inv;
    let t0 = a.min(b).max_element();
    let t1 = a.max(b).min_element();
    // NaN (a zero direction component on a slab's face) counts as inside.
    if t0 <= t1 || t0.is_nan() || t1.is_nan() {
        Some((t0, t1))
    } else {
        None
    }
}

/// [`crate::ray::trace`] with sharp interfaces: a ray from `origin` along
/// `dir` through the regions of `regions`' scene, in index channel `ch`,
/// until it leaves the grid's bounds. Steps are `opts.step` (Dormand-Prince
/// takes RK4's), and as long as the region allows: surface to surface in
/// constant ones.
pub fn trace(
    regions: &Regions,
    origin: DVec3,
    dir: DVec3,
    opts: &crate::TraceOptions,
    ch: usize,
) -> crate::RayEnd {
    use crate::Status;
    let grid = &regions.scene.grid.geometry;
    let d = dir.normalize_or_zero();
    let mut end = crate::RayEnd {
        status: Status::Missed,
        entry: origin,
        position: origin,
        direction: d,
        optical_path: 0.0,
        steps: 0,
        rejected: 0,
        path: Vec::new(),
    };
    if d == DVec3::ZERO || !origin.is_finite() || !d.is_finite() {
        end.status = Status::Diverged;
        return end;
    }
    let start = if grid.contains(origin) {
        origin
    } else {
        match grid.clip_line(origin, d) {
            Some((t0, t1)) if t1 >= 0.0 && t0 >= 0.0 => origin + d * t0,
            _ => return end,
        }
    };
    end.entry = start;
    if opts.record_path {
        end.path.push(start);
    }
    let mut ray = regions.ray(start, d, ch);
    let integrator = match opts.integrator {
        Integrator::Euler => Integrator::Euler,
        _ => Integrator::Rk4,
    };
    let finish = |end: &mut crate::RayEnd, ray: &SharpRay, status| {
        end.status = status;
        end.position = ray.s.x;
        end.direction = ray.s.v.normalize_or_zero();
        end.optical_path = ray.s.opl;
    };
    loop {
        if end.steps >= opts.max_steps {
            finish(&mut end, &ray, Status::MaxSteps);
            return end;
        }
        let dir = ray.s.v.normalize_or_zero();
        let exit = grid
            .clip_line(ray.s.x, dir)
            .map_or(0.0, |(_, t1)| t1.max(0.0));
        let n = regions.index(ray.region, ray.s.x, ch).0;
        let per = match opts.form {
            Form::EqualDistance => 1.0,
            Form::EqualTime => n,
        };
        // Constant regions go as far as the bounds in one step.
        let h = if regions.uniform(ray.region) {
            exit * per
        } else {
            opts.step
        };
        let before = ray;
        let st = regions.step(&mut ray, opts.form, integrator, h.max(0.0), ch);
        end.steps += 1;
        if !(ray.s.x.is_finite() && ray.s.v.is_finite()) {
            finish(&mut end, &before, Status::Diverged);
            return end;
        }
        if !grid.contains(ray.s.x) || (!st.at_surface && regions.uniform(before.region)) {
            // Left the bounds: end on them, along the last chord.
            let chord = ray.s.x - before.s.x;
            let len = chord.length();
            if len > 0.0 && !grid.contains(ray.s.x) {
                let u = chord / len;
                let t = grid
                    .clip_line(before.s.x, u)
                    .map_or(len, |(_, t1)| t1.clamp(0.0, len));
                let f = t / len;
                ray.s.x = before.s.x + u * t;
                ray.s.opl = before.s.opl + (ray.s.opl - before.s.opl) * f;
            }
            if opts.record_path {
                end.path.push(ray.s.x);
            }
            finish(&mut end, &ray, Status::Exited);
            return end;
        }
        if opts.record_path {
            end.path.push(ray.s.x);
        }
    }
}

/// Kinds of [`RegionGpu`]: the shape of an object's region, or the ambient
/// medium.
pub const SHAPE_SPHERE: u32 = 0;
/// A box (not rounded).
pub const SHAPE_BOX: u32 = 1;
/// A capped cylinder.
pub const SHAPE_CYLINDER: u32 = 2;
/// A half-space.
pub const SHAPE_HALF_SPACE: u32 = 3;
/// The ambient medium (no shape).
pub const SHAPE_AMBIENT: u32 = 4;
/// A rounded box (`radius` the rounding).
pub const SHAPE_ROUNDED_BOX: u32 = 5;
/// A solid of revolution (its profile in the data buffer).
pub const SHAPE_REVOLUTION: u32 = 6;
/// A torus (`radius` the major radius, `shape_a` the minor).
pub const SHAPE_TORUS: u32 = 7;
/// A superquadric (`half` the radii, `shape_a`, `shape_b` the exponents).
pub const SHAPE_SUPERQUADRIC: u32 = 8;
/// A triangle mesh (its triangles and BVH in the data buffer).
pub const SHAPE_MESH: u32 = 9;
/// A VDB grid's solid (`data` its volume, `radius` the threshold).
pub const SHAPE_VDB: u32 = 10;
/// Not a shape: the bit of [`table_kinds`] for regions whose index a VDB
/// grid gives.
pub const KIND_GRID_INDEX: u32 = 11;
/// The bit of [`table_kinds`] for regions whose extinction a VDB grid
/// gives.
pub const KIND_GRID_EXTINCTION: u32 = 12;
/// [`RegionGpu::flags`]: the mesh is shaded with its vertex normals.
pub const FLAG_SMOOTH: u32 = 1;
/// Index profiles of [`RegionGpu`].
pub const PROFILE_CONSTANT: u32 = 0;
/// [`crate::IndexProfile::Luneburg`].
pub const PROFILE_LUNEBURG: u32 = 1;
/// [`crate::IndexProfile::Linear`].
pub const PROFILE_LINEAR: u32 = 2;
/// An index from a VDB grid ([`crate::object::GridIndex`]): `index_b +
/// index_a * value` of the volume at `index_volume`.
pub const PROFILE_VDB: u32 = 3;
/// No volume (`RegionGpu::ext_volume`).
pub const NO_VOLUME: u32 = u32::MAX;

eikon_shader::layout! {
    /// One region as a kernel reads it (`RegionGpu` in `region.wgsl`), in
    /// f32: an object's shape and material, or the ambient medium's
    /// material ([`gpu_regions`]).
    pub struct RegionGpu {
        /// Sphere, box or cylinder centre; a half-space's point.
        pub center: [f32; 3],
        /// `SHAPE_*`.
        pub kind: u32,
        /// Box half extents; a cylinder's `(radius, half height, radius)`;
        /// a half-space's unit outward normal.
        pub half: [f32; 3],
        /// Sphere or cylinder radius.
        pub radius: f32,
        /// The local frame's x axis (first column of the rotation).
        pub axis_x: [f32; 3],
        /// `PROFILE_*`.
        pub profile: u32,
        /// Its y axis.
        pub axis_y: [f32; 3],
        /// The object's index in the scene (`u32::MAX` for the ambient).
        pub object: u32,
        /// Its z axis.
        pub axis_z: [f32; 3],
        /// A VDB index's volume in the data buffer.
        pub index_volume: u32,
        /// Constant: n per channel; Luneburg: the centre; linear: the
        /// gradient.
        pub index: [f32; 3],
        /// Luneburg: the radius; linear: n0; VDB: the scale of the value.
        pub index_a: f32,
        /// Linear: the origin.
        pub index_origin: [f32; 3],
        /// Luneburg: the outer index; VDB: n where the value is 0.
        pub index_b: f32,
        /// RGB extinction; with an extinction grid, per unit of its value.
        pub extinction: [f32; 3],
        /// Henyey-Greenstein g.
        pub g: f32,
        /// RGB single-scattering albedo.
        pub albedo: [f32; 3],
        /// The extinction grid's volume in the data buffer, or
        /// [`NO_VOLUME`].
        pub ext_volume: u32,
        /// RGB emission.
        pub emission: [f32; 3],
        /// Padding.
        pub pad2: f32,
        /// Torus: the minor radius; superquadric: e1; solid of
        /// revolution: the profile's orientation (+1 counter-clockwise).
        pub shape_a: f32,
        /// Superquadric: e2.
        pub shape_b: f32,
        /// The shape's size (its bounding box's diagonal): the scale of its
        /// root finding's steps.
        pub size: f32,
        /// `FLAG_*`.
        pub flags: u32,
        /// Where the shape's records start in the data buffer
        /// ([`GpuRegions::data`]): a profile's points, a mesh's triangles,
        /// a VDB grid's volume.
        pub data: u32,
        /// Profile points, or mesh triangles.
        pub data_len: u32,
        /// A mesh's first BVH node record.
        pub nodes: u32,
        /// A mesh's BVH nodes.
        pub node_count: u32,
    }
}

/// The regions of a scene as kernels read them ([`gpu_regions`]).
pub struct GpuRegions {
    /// Its objects in precedence order (highest priority first), then the
    /// ambient medium.
    pub table: Vec<RegionGpu>,
    /// The per-shape data the table's `data` and `nodes` point into, in
    /// 16-byte records (`vec4<u32>`, floats by their bits): per profile
    /// point of a solid of revolution `(r, y, n_r, n_y)`, with `n` the
    /// outward normal of the edge to the next point; per mesh triangle
    /// [`crate::surface::MESH_TRIANGLE_RECORDS`], per BVH node
    /// [`crate::surface::MESH_NODE_RECORDS`]; per VDB volume (each once,
    /// however many shapes and grids of the scene read it)
    /// [`crate::surface::VDB_HEADER_RECORDS`] and its values four to a
    /// record ([`volume_records`]). Never empty (a buffer binding cannot
    /// be).
    pub data: Vec<[u32; 4]>,
}

impl GpuRegions {
    /// Bytes of the data buffer.
    pub fn data_bytes(&self) -> u64 {
        self.data.len() as u64 * 16
    }
}

/// A VDB volume in the data buffer: its header
/// ([`crate::surface::VDB_HEADER_RECORDS`]: voxel size and background,
/// translation, origin, dims) and its dense box's values, four to a
/// record, x slowest and z fastest, as `FloatVolume` holds them.
fn volume_records(v: &crate::vdb::FloatVolume, out: &mut Vec<[u32; 4]>) {
    let t = &v.transform;
    let [h, c] = [t.voxel_size, t.translation].map(f3);
    out.push(record(h[0], h[1], h[2], v.background.to_bits()));
    out.push(record(c[0], c[1], c[2], 0));
    let o = v.origin();
    out.push([o[0] as u32, o[1] as u32, o[2] as u32, 0]);
    let d = v.dims();
    out.push([d[0] as u32, d[1] as u32, d[2] as u32, 0]);
    let values: Vec<f32> = v.voxels().map(|(_, x)| x).collect();
    for chunk in values.chunks(4) {
        let mut r = [0u32; 4];
        for (slot, x) in r.iter_mut().zip(chunk) {
            *slot = x.to_bits();
        }
        out.push(r);
    }
}

/// The data buffer's VDB volumes, each written once.
#[derive(Default)]
struct Volumes {
    /// Each volume written (by address) and its first record.
    seen: Vec<(*const crate::vdb::FloatVolume, u32)>,
}

impl Volumes {
    /// The first record of `v` in `data`, written there if new.
    fn at(&mut self, v: &std::sync::Arc<crate::vdb::FloatVolume>, data: &mut Vec<[u32; 4]>) -> u32 {
        let key = std::sync::Arc::as_ptr(v);
        if let Some(&(_, at)) = self.seen.iter().find(|(k, _)| *k == key) {
            return at;
        }
        let at = data.len() as u32;
        volume_records(v, data);
        self.seen.push((key, at));
        at
    }
}

/// A record of four floats, by their bits.
fn record(x: f32, y: f32, z: f32, w: u32) -> [u32; 4] {
    [x.to_bits(), y.to_bits(), z.to_bits(), w]
}

fn f3(v: DVec3) -> [f32; 3] {
    v.to_array().map(|x| x as f32)
}

/// A material's GPU form with sharp interfaces: its index profile (a VDB
/// index grid's volume written to `data`) and optical properties (an
/// extinction grid's volume too).
fn gpu_material(
    m: &Material,
    out: &mut RegionGpu,
    data: &mut Vec<[u32; 4]>,
    volumes: &mut Volumes,
) {
    out.ext_volume = NO_VOLUME;
    if let Some(g) = &m.extinction_grid {
        out.ext_volume = volumes.at(&g.volume, data);
    }
    if let Some(g) = &m.index_grid {
        out.profile = PROFILE_VDB;
        out.index_volume = volumes.at(&g.volume, data);
        (out.index_a, out.index_b) = match g.scale {
            None => (1.0, 0.0),
            Some(k) => (k as f32, 1.0),
        };
    } else {
        gpu_profile(&m.index, out);
    }
    // With an extinction grid, `extinction` is the scale of its value.
    out.extinction = f3(m.extinction_grid.as_ref().map_or(m.extinction, |g| g.scale));
    out.albedo = f3(m.albedo);
    out.g = m.g as f32;
    out.emission = f3(m.emission);
}

/// An index profile's GPU form.
fn gpu_profile(index: &crate::IndexProfile, out: &mut RegionGpu) {
    match index {
        crate::IndexProfile::Constant(n) => {
            out.profile = PROFILE_CONSTANT;
            out.index = n.map(|x| x as f32);
        }
        crate::IndexProfile::Luneburg {
            center,
            radius,
            outer,
        } => {
            out.profile = PROFILE_LUNEBURG;
            out.index = f3(*center);
            out.index_a = *radius as f32;
            out.index_b = *outer as f32;
        }
        crate::IndexProfile::Linear {
            n0,
            gradient,
            origin,
        } => {
            out.profile = PROFILE_LINEAR;
            out.index = f3(*gradient);
            out.index_a = *n0 as f32;
            out.index_origin = f3(*origin);
        }
    }
}

/// The regions of `scene` as a kernel reads them: its objects in
/// precedence order (highest priority first), then the ambient medium,
/// and the data of the shapes and grids that need more than the table
/// holds: every shape, index profile and grid of the CPU's.
pub fn gpu_regions(scene: &Scene) -> GpuRegions {
    use crate::shape::Shape;
    let mut out = Vec::with_capacity(scene.objects.len() + 1);
    let mut data: Vec<[u32; 4]> = Vec::new();
    let mut volumes = Volumes::default();
    for &i in scene.precedence() {
        let o = &scene.objects[i];
        let size = o.shape.aabb().map_or(0.0, |(a, b)| (b - a).length() as f32);
        let mut r = RegionGpu {
            object: i as u32,
            axis_x: [1.0, 0.0, 0.0],
            axis_y: [0.0, 1.0, 0.0],
            axis_z: [0.0, 0.0, 1.0],
            size: if size.is_finite() { size } else { 0.0 },
            ..Default::default()
        };
        let mut frame = |rot: &glam::DMat3| {
            r.axis_x = f3(rot.x_axis);
            r.axis_y = f3(rot.y_axis);
            r.axis_z = f3(rot.z_axis);
        };
        match &o.shape {
            Shape::Sphere { center, radius } => {
                r.kind = SHAPE_SPHERE;
                r.center = f3(*center);
                r.radius = *radius as f32;
            }
            Shape::Box {
                center,
                half,
                radius,
                rot,
            } => {
                frame(rot);
                r.kind = if *radius > 0.0 {
                    SHAPE_ROUNDED_BOX
                } else {
                    SHAPE_BOX
                };
                r.center = f3(*center);
                r.half = f3(*half);
                r.radius = *radius as f32;
            }
            Shape::Cylinder {
                center,
                radius,
                half_height,
                rot,
            } => {
                frame(rot);
                r.kind = SHAPE_CYLINDER;
                r.center = f3(*center);
                r.radius = *radius as f32;
                r.half = [*radius as f32, *half_height as f32, *radius as f32];
            }
            Shape::HalfSpace { point, normal } => {
                r.kind = SHAPE_HALF_SPACE;
                r.center = f3(*point);
                r.half = f3(*normal);
            }
            Shape::Revolution { base, profile, rot } => {
                frame(rot);
                r.kind = SHAPE_REVOLUTION;
                r.center = f3(*base);
                let orient = profile.orientation();
                r.shape_a = orient as f32;
                r.data = data.len() as u32;
                r.data_len = profile.len() as u32;
                // The edges' normals in f64, rounded once.
                let n = profile.len();
                for k in 0..n {
                    let (a, b) = (profile[k], profile[(k + 1) % n]);
                    let e = crate::surface::edge_normal(a, b, orient);
                    data.push(record(
                        a.x as f32,
                        a.y as f32,
                        e.x as f32,
                        (e.y as f32).to_bits(),
                    ));
                }
            }
            Shape::Torus {
                center,
                major,
                minor,
                rot,
            } => {
                frame(rot);
                r.kind = SHAPE_TORUS;
                r.center = f3(*center);
                r.radius = *major as f32;
                r.shape_a = *minor as f32;
            }
            Shape::Superquadric {
                center,
                radii,
                e1,
                e2,
                rot,
            } => {
                frame(rot);
                r.kind = SHAPE_SUPERQUADRIC;
                r.center = f3(*center);
                r.half = f3(*radii);
                r.shape_a = *e1 as f32;
                r.shape_b = *e2 as f32;
            }
            Shape::Mesh(solid) => {
                r.kind = SHAPE_MESH;
                if solid.smooth() {
                    r.flags |= FLAG_SMOOTH;
                }
                let bvh = solid.bvh();
                r.data = data.len() as u32;
                r.data_len = bvh.triangle_count() as u32;
                for (c, n, id) in bvh.leaf_triangles() {
                    for (k, p) in c.iter().enumerate() {
                        let [x, y, z] = f3(*p);
                        data.push(record(x, y, z, if k == 0 { id } else { 0 }));
                    }
                    for v in n {
                        let [x, y, z] = f3(*v);
                        data.push(record(x, y, z, 0));
                    }
                }
                r.nodes = data.len() as u32;
                r.node_count = bvh.node_count() as u32;
                for node in bvh.flat_nodes() {
                    let [x, y, z] = f3(node.lo);
                    data.push(record(x, y, z, node.offset));
                    let [x, y, z] = f3(node.hi);
                    data.push(record(
                        x,
                        y,
                        z,
                        u32::from(node.count) | (u32::from(node.axis) << 16),
                    ));
                }
            }
            Shape::Vdb(solid) => {
                r.kind = SHAPE_VDB;
                r.data = volumes.at(solid.volume(), &mut data);
                r.radius = solid.threshold() as f32;
                // Its size as the CPU takes it (the dense box's diagonal).
                r.size = o.shape.fixed_size().unwrap_or(0.0) as f32;
            }
        }
        gpu_material(&o.material, &mut r, &mut data, &mut volumes);
        out.push(r);
    }
    let mut ambient = RegionGpu {
        kind: SHAPE_AMBIENT,
        object: u32::MAX,
        ..Default::default()
    };
    gpu_material(&scene.ambient, &mut ambient, &mut data, &mut volumes);
    out.push(ambient);
    if data.is_empty() {
        data.push([0; 4]);
    }
    GpuRegions { table: out, data }
}

/// `REGION_KINDS` of every kind: a kernel holds every shape's code unless
/// [`only_kinds`] narrows it.
const ALL_KINDS: u32 = u32::MAX;

/// The shape kinds (`SHAPE_*` bits) of a region table, with
/// [`KIND_GRID_INDEX`] and [`KIND_GRID_EXTINCTION`] where a region reads
/// its index or extinction from a VDB grid: each kind's code is compiled
/// only where the scene needs it (see [`only_kinds`]).
pub fn table_kinds(table: &[RegionGpu]) -> u32 {
    table.iter().fold(0, |k, r| {
        let index = u32::from(r.profile == PROFILE_VDB) << KIND_GRID_INDEX;
        let ext = u32::from(r.ext_volume != NO_VOLUME) << KIND_GRID_EXTINCTION;
        k | (1 << r.kind) | index | ext
    })
}

/// `source`, a kernel composed with [`WGSL`], holding the code of the
/// shape kinds in `kinds` only (bits `1 << SHAPE_*`, [`table_kinds`]):
/// drivers inline every call of the region functions, and a kernel with
/// every shape's code at each call site takes minutes to compile on
/// lavapipe. A table with other kinds must not be bound to it.
pub fn only_kinds(source: &str, kinds: u32) -> String {
    source.replacen(
        &format!("const REGION_KINDS: u32 = {ALL_KINDS}u;"),
        &format!("const REGION_KINDS: u32 = {kinds}u;"),
        1,
    )
}

fn region_declarations() -> String {
    use eikon_shader::Layout;
    format!(
        "{}{}",
        RegionGpu::declaration(),
        eikon_shader::Consts::new()
            .u32("SHAPE_SPHERE", SHAPE_SPHERE)
            .u32("SHAPE_BOX", SHAPE_BOX)
            .u32("SHAPE_CYLINDER", SHAPE_CYLINDER)
            .u32("SHAPE_HALF_SPACE", SHAPE_HALF_SPACE)
            .u32("SHAPE_AMBIENT", SHAPE_AMBIENT)
            .u32("SHAPE_ROUNDED_BOX", SHAPE_ROUNDED_BOX)
            .u32("SHAPE_REVOLUTION", SHAPE_REVOLUTION)
            .u32("SHAPE_TORUS", SHAPE_TORUS)
            .u32("SHAPE_SUPERQUADRIC", SHAPE_SUPERQUADRIC)
            .u32("SHAPE_MESH", SHAPE_MESH)
            .u32("SHAPE_VDB", SHAPE_VDB)
            .u32("KIND_GRID_INDEX", KIND_GRID_INDEX)
            .u32("KIND_GRID_EXTINCTION", KIND_GRID_EXTINCTION)
            .u32("FLAG_SMOOTH", FLAG_SMOOTH)
            .u32("REGION_KINDS", ALL_KINDS)
            .u32("PROFILE_CONSTANT", PROFILE_CONSTANT)
            .u32("PROFILE_LUNEBURG", PROFILE_LUNEBURG)
            .u32("PROFILE_LINEAR", PROFILE_LINEAR)
            .u32("PROFILE_VDB", PROFILE_VDB)
            .u32("NO_VOLUME", NO_VOLUME)
            .wgsl()
    )
}

/// The WGSL of sharp interfaces (`region.wgsl`): `RegionGpu`, the owner by
/// priority, each region's index, the next surface, [`refract`] and
/// [`Regions::cross`], over the table of [`gpu_regions`] that a kernel
/// provides through the hooks `region_count` and `region_object`.
pub static WGSL: eikon_shader::Module = eikon_shader::Module {
    name: "region",
    requires: &[
        &eikon_shader::VECTOR,
        &crate::surface::WGSL,
        &eikon_optics::fresnel::WGSL,
    ],
    declarations: region_declarations,
    text: include_str!("region.wgsl"),
};

/// The WGSL of [`Regions::step`] in either form (`region_step.wgsl`:
/// `region_step`, the straight step through a constant region and the
/// integrator's step cut at a surface, then [`Regions::cross`]), over the
/// `region` module. The kernel provides `var<private> field_region: u32`,
/// which its `index_field` reads (region `field_region`'s own profile while
/// it is not `NONE`), and the constant `NONE`.
pub static STEP_WGSL: eikon_shader::Module = eikon_shader::Module {
    name: "region_step",
    requires: &[&crate::ray::WGSL, &WGSL],
    declarations: eikon_shader::nothing,
    text: include_str!("region_step.wgsl"),
};

/// The length below which two points on a ray are one on the GPU with
/// sharp interfaces: the CPU's [`Regions::eps`] is a billionth of a voxel,
/// below f32's resolution; here a few hundred ulps of the scene's scale,
/// well above the rounding of a crossing point (a few ulps), so that a
/// segment starting on a surface does not find its own start and the far
/// side is probed beyond that rounding.
pub fn gpu_eps(g: &crate::GridGeometry) -> f64 {
    let scale = g.min.abs().max(g.max.abs()).max_element() + g.voxel_size();
    4e-6 * scale
}
