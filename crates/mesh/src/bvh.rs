//! Bounding volume hierarchy for ray-triangle queries.
//!
//! Built once, top down, by the binned surface area heuristic (16 bins on each
//! axis, Wald 2007). Nodes live in one flat `Vec` in depth-first order (the
//! left child follows its parent, the right child's index is stored), and the
//! triangles' corners are copied into leaf order, so a traversal reads memory
//! mostly forward and needs no pointer chasing.
//!
//! The ray-triangle test is the watertight one of Woop, Benthin and Wald
//! (JCGT 2013): the ray is sheared so it runs along +z, and the 2-D edge
//! functions of a shared edge are computed from the same numbers with the
//! opposite sign. A ray through an edge or vertex therefore hits at least one
//! of the triangles there, never slips between them: a refracted ray that
//! enters a closed medium also finds its way out. Box tests are widened by
//! the rounding bound of Ize (2013) so no box drops a hit its triangle has.
//!
//! Both queries take the nearest hit with `t_min < t < t_max`; exact ties in
//! `t` go to the lower triangle id, so [`Bvh::closest_hit`] and
//! [`closest_hit_brute_force`] agree triangle for triangle.

use crate::mesh::Mesh;
use glam::DVec3;

/// A ray `origin + t * direction` for `t_min < t < t_max`. The direction need
/// not be unit length; `t` is measured in multiples of it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Start point.
    pub origin: DVec3,
    /// Direction (any non-zero length).
    pub direction: DVec3,
    /// Hits at or before this parameter are ignored.
    pub t_min: f64,
    /// Hits at or beyond this parameter are ignored.
    pub t_max: f64,
}

impl Ray {
    /// A ray over `0 < t < infinity`.
    pub fn new(origin: DVec3, direction: DVec3) -> Self {
        Self {
            origin,
            direction,
            t_min: 0.0,
            t_max: f64::INFINITY,
        }
    }

    /// A ray over `t_min < t < t_max`.
    pub fn segment(origin: DVec3, direction: DVec3, t_min: f64, t_max: f64) -> Self {
        Self {
            origin,
            direction,
            t_min,
            t_max,
        }
    }

    /// The point at parameter `t`.
    pub fn at(&self, t: f64) -> DVec3 {
        self.origin + self.direction * t
    }
}

/// Where a ray meets a triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// The triangle's index in the mesh.
    pub triangle: u32,
    /// Ray parameter of the hit.
    pub t: f64,
    /// Weights of the triangle's corners 0, 1, 2 (non-negative, sum 1).
    pub barycentric: [f64; 3],
    /// The hit point, interpolated from the corners (on the triangle's plane
    /// to rounding, unlike `origin + t * direction`).
    pub point: DVec3,
    /// Unit shading normal: the corners' vertex normals interpolated
    /// (the geometric normal where they cancel).
    pub normal: DVec3,
    /// Unit normal of the triangle's plane, outward for an outward mesh.
    pub geometric_normal: DVec3,
}

impl Hit {
    /// Whether a ray along `direction` crosses the surface from outside to
    /// inside here (against the geometric normal).
    pub fn entering(&self, direction: DVec3) -> bool {
        direction.dot(self.geometric_normal) < 0.0
    }
}

/// One node: its box, and either a leaf's triangle range (`count > 0`) or an
/// interior node's right child (`offset`) and split axis.
#[derive(Clone, Copy, Debug, Default)]
struct Node {
    lo: DVec3,
    hi: DVec3,
    offset: u32,
    count: u16,
    axis: u16,
}

/// One node as [`Bvh::flat_nodes`] exports it: a leaf when `count > 0`
/// (triangles `offset..offset + count` of [`Bvh::leaf_triangles`]), else an
/// interior node whose left child follows it and whose right child is
/// `offset`, split on `axis` (the near child of a ray whose direction is
/// negative on that axis is the right one).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlatNode {
    /// Lower corner of the node's box.
    pub lo: DVec3,
    /// Upper corner.
    pub hi: DVec3,
    /// Leaf: first triangle slot; interior: the right child's index.
    pub offset: u32,
    /// Triangles in a leaf (0: interior).
    pub count: u16,
    /// Interior: the split axis.
    pub axis: u16,
}

/// The hierarchy over one mesh. It copies what it needs (corners and vertex
/// normals per triangle), so it does not borrow the mesh.
#[derive(Clone, Debug)]
pub struct Bvh {
    nodes: Vec<Node>,
    /// Corners in leaf order.
    corners: Vec<[DVec3; 3]>,
    /// Vertex normals of the corners, in leaf order.
    normals: Vec<[DVec3; 3]>,
    /// Mesh triangle id of each leaf slot.
    ids: Vec<u32>,
    depth: usize,
}

/// Relative traversal cost of a node against one triangle test.
const COST_TRAVERSAL: f64 = 1.0;
const BINS: usize = 16;
/// SAH leaves hold at most this many triangles.
const MAX_LEAF: usize = 8;
/// Beyond this depth splits are medians, which bounds the depth by this
/// plus log2(triangles) and so the traversal stack.
const SAH_DEPTH: usize = 64;
/// Entries of a traversal's stack: two per level, which the depth bound
/// (`SAH_DEPTH` plus log2 of the triangles) keeps within (a GPU copy of
/// the traversal uses the same).
pub const STACK: usize = 128;

/// `n * eps / (1 - n * eps)` with the unit roundoff: the bound on relative
/// error after `n` roundings (Higham; PBRT's `gamma`).
const fn gamma(n: f64) -> f64 {
    let e = f64::EPSILON * 0.5;
    n * e / (1.0 - n * e)
}
const WIDEN: f64 = 2.0 * gamma(3.0);

/// Index of the largest component (the first of equals).
fn argmax(v: DVec3) -> usize {
    if v.x >= v.y && v.x >= v.z {
        0
    } else if v.y >= v.z {
        1
    } else {
        2
    }
}

struct Prim {
    lo: DVec3,
    hi: DVec3,
    centroid: DVec3,
}

fn half_area(lo: DVec3, hi: DVec3) -> f64 {
    let d = (hi - lo).max(DVec3::ZERO);
    d.x * d.y + d.y * d.z + d.z * d.x
}

struct Builder<'a> {
    prims: &'a [Prim],
    nodes: Vec<Node>,
    depth: usize,
}

impl Builder<'_> {
    /// Builds the subtree over `order` (whose first slot is `start` in leaf
    /// order) and returns its node index.
    fn build(&mut self, order: &mut [u32], start: usize, depth: usize) -> usize {
        let idx = self.nodes.len();
        self.nodes.push(Node::default());
        self.depth = self.depth.max(depth + 1);
        let inf = DVec3::splat(f64::INFINITY);
        let (mut lo, mut hi, mut clo, mut chi) = (inf, -inf, inf, -inf);
        for &p in order.iter() {
            let p = &self.prims[p as usize];
            lo = lo.min(p.lo);
            hi = hi.max(p.hi);
            clo = clo.min(p.centroid);
            chi = chi.max(p.centroid);
        }
        self.nodes[idx].lo = lo;
        self.nodes[idx].hi = hi;
        let n = order.len();
        // (split axis, size of the left part)
        let mut split = None;
        if n > 1 && depth < SAH_DEPTH {
            if let Some((axis, bin, cost)) = self.best_split(order, lo, hi, clo, chi) {
                if n > MAX_LEAF || cost < n as f64 {
                    split = Some((axis, self.partition(order, axis, bin, clo, chi)));
                }
            }
        }
        if split.is_none() && n > MAX_LEAF {
            // No usable SAH split (identical centroids, or too deep): halve.
            let axis = argmax(chi - clo);
            let prims = self.prims;
            order.select_nth_unstable_by(n / 2, |&a, &b| {
                prims[a as usize].centroid[axis].total_cmp(&prims[b as usize].centroid[axis])
            });
            split = Some((axis, n / 2));
        }
        match split {
            Some((axis, m)) => {
                let (left, right) = order.split_at_mut(m);
                self.build(left, start, depth + 1);
                let r = self.build(right, start + m, depth + 1);
                self.nodes[idx].offset = r as u32;
                self.nodes[idx].axis = axis as u16;
            }
            None => {
                self.nodes[idx].offset = start as u32;
                self.nodes[idx].count = n as u16;
            }
        }
        idx
    }

    fn bin(c: f64, lo: f64, scale: f64) -> usize {
        (((c - lo) * scale) as usize).min(BINS - 1)
    }

    /// The cheapest binned split `(axis, first bin of the right side, cost)`
    /// in units of one triangle test, or `None` when centroids coincide.
    fn best_split(
        &self,
        order: &[u32],
        lo: DVec3,
        hi: DVec3,
        clo: DVec3,
        chi: DVec3,
    ) -> Option<(usize, usize, f64)> {
        let parent = half_area(lo, hi);
        let inv_parent = if parent > 0.0 { 1.0 / parent } else { 0.0 };
        let inf = DVec3::splat(f64::INFINITY);
        let mut best: Option<(usize, usize, f64)> = None;
        for axis in 0..3 {
            let extent = chi[axis] - clo[axis];
            if extent <= 0.0 {
                continue;
            }
            let scale = BINS as f64 / extent;
            let mut count = [0usize; BINS];
            let mut blo = [inf; BINS];
            let mut bhi = [-inf; BINS];
            for &p in order {
                let p = &self.prims[p as usize];
                let b = Self::bin(p.centroid[axis], clo[axis], scale);
                count[b] += 1;
                blo[b] = blo[b].min(p.lo);
                bhi[b] = bhi[b].max(p.hi);
            }
            // Right-to-left sweep: area and count right of each boundary.
            let mut right_area = [0.0; BINS];
            let mut right_count = [0usize; BINS];
            let (mut rlo, mut rhi, mut rn) = (inf, -inf, 0);
            for b in (1..BINS).rev() {
                rlo = rlo.min(blo[b]);
                rhi = rhi.max(bhi[b]);
                rn += count[b];
                right_area[b] = half_area(rlo, rhi);
                right_count[b] = rn;
            }
            let (mut llo, mut lhi, mut ln) = (inf, -inf, 0);
            for b in 1..BINS {
                llo = llo.min(blo[b - 1]);
                lhi = lhi.max(bhi[b - 1]);
                ln += count[b - 1];
                if ln == 0 || right_count[b] == 0 {
                    continue;
                }
                let cost = COST_TRAVERSAL
                    + (half_area(llo, lhi) * ln as f64 + right_area[b] * right_count[b] as f64)
                        * inv_parent;
                if best.is_none_or(|(_, _, c)| cost < c) {
                    best = Some((axis, b, cost));
                }
            }
        }
        best
    }

    /// Moves the primitives left of `bin` to the front; returns their count
    /// (never 0 or all, since the split was chosen with both sides used).
    fn partition(
        &self,
        order: &mut [u32],
        axis: usize,
        bin: usize,
        clo: DVec3,
        chi: DVec3,
    ) -> usize {
        let scale = BINS as f64 / (chi[axis] - clo[axis]);
        let (mut i, mut j) = (0, order.len());
        while i < j {
            let c = self.prims[order[i] as usize].centroid[axis];
            if Self::bin(c, clo[axis], scale) < bin {
                i += 1;
            } else {
                j -= 1;
                order.swap(i, j);
            }
        }
        i
    }
}

/// Per-ray constants: slab reciprocals and the shear of the watertight test.
struct Prepared {
    origin: DVec3,
    inv: DVec3,
    negative: [bool; 3],
    k: [usize; 3],
    shear: DVec3,
}

impl Prepared {
    fn new(ray: &Ray) -> Option<Self> {
        let d = ray.direction;
        if !(ray.origin.is_finite() && d.is_finite()) || d == DVec3::ZERO || ray.t_min.is_nan() {
            return None;
        }
        // The dominant axis becomes z; swapping x and y when it points down
        // keeps the triangles' winding.
        let kz = argmax(d.abs());
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        if d[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        Some(Self {
            origin: ray.origin,
            inv: d.recip(),
            // The sign bit, not `< 0`: a -0.0 component has reciprocal -inf,
            // and the slab's near side must follow the reciprocal.
            negative: [
                d.x.is_sign_negative(),
                d.y.is_sign_negative(),
                d.z.is_sign_negative(),
            ],
            k: [kx, ky, kz],
            shear: DVec3::new(d[kx] / d[kz], d[ky] / d[kz], 1.0 / d[kz]),
        })
    }

    /// Whether the ray meets the box within `t_min..=t_max`, widened for
    /// rounding. An axis the ray runs parallel to on the box's own face plane
    /// gives 0 * inf = NaN, which `max`/`min` ignore: such a ray lies in the
    /// closed slab, which is right.
    #[inline(always)]
    fn hits_box(&self, lo: DVec3, hi: DVec3, t_min: f64, t_max: f64) -> bool {
        let mut near = t_min;
        let mut far = t_max;
        for a in 0..3 {
            let (b0, b1) = if self.negative[a] {
                (hi[a], lo[a])
            } else {
                (lo[a], hi[a])
            };
            let t0 = (b0 - self.origin[a]) * self.inv[a];
            let t1 = (b1 - self.origin[a]) * self.inv[a];
            // Scaling (not adding) keeps infinities: a ray parallel to a
            // slab it lies outside of still misses.
            near = near.max(t0 * (1.0 - WIDEN.copysign(t0)));
            far = far.min(t1 * (1.0 + WIDEN.copysign(t1)));
        }
        near <= far
    }

    /// The watertight test: `(t, barycentric)` for `t_min < t < t_max`.
    #[inline(always)]
    fn hits_triangle(&self, tri: &[DVec3; 3], t_min: f64, t_max: f64) -> Option<(f64, [f64; 3])> {
        let [kx, ky, kz] = self.k;
        let s = self.shear;
        let a = tri[0] - self.origin;
        let b = tri[1] - self.origin;
        let c = tri[2] - self.origin;
        let (ax, ay) = (a[kx] - s.x * a[kz], a[ky] - s.y * a[kz]);
        let (bx, by) = (b[kx] - s.x * b[kz], b[ky] - s.y * b[kz]);
        let (cx, cy) = (c[kx] - s.x * c[kz], c[ky] - s.y * c[kz]);
        // Edge functions; u weighs corner 0, v corner 1, w corner 2.
        let u = cx * by - cy * bx;
        let v = ax * cy - ay * cx;
        let w = bx * ay - by * ax;
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return None;
        }
        let det = u + v + w;
        if det == 0.0 {
            return None;
        }
        let t = (u * s.z * a[kz] + v * s.z * b[kz] + w * s.z * c[kz]) / det;
        if !(t > t_min && t < t_max) {
            return None;
        }
        Some((t, [u / det, v / det, w / det]))
    }
}

fn make_hit(
    triangle: u32,
    t: f64,
    barycentric: [f64; 3],
    corners: &[DVec3; 3],
    normals: &[DVec3; 3],
) -> Hit {
    let [b0, b1, b2] = barycentric;
    let geometric_normal = (corners[1] - corners[0])
        .cross(corners[2] - corners[0])
        .normalize_or_zero();
    let normal = (normals[0] * b0 + normals[1] * b1 + normals[2] * b2).normalize_or_zero();
    Hit {
        triangle,
        t,
        barycentric,
        point: corners[0] * b0 + corners[1] * b1 + corners[2] * b2,
        normal: if normal == DVec3::ZERO {
            geometric_normal
        } else {
            normal
        },
        geometric_normal,
    }
}

impl Bvh {
    /// Builds the hierarchy over `mesh`'s triangles.
    pub fn new(mesh: &Mesh) -> Self {
        let n = mesh.triangle_count();
        let prims: Vec<Prim> = (0..n)
            .map(|t| {
                let [a, b, c] = mesh.corners(t);
                let (lo, hi) = (a.min(b).min(c), a.max(b).max(c));
                Prim {
                    lo,
                    hi,
                    centroid: (lo + hi) * 0.5,
                }
            })
            .collect();
        let mut order: Vec<u32> = (0..n as u32).collect();
        let mut builder = Builder {
            prims: &prims,
            nodes: Vec::with_capacity(2 * n.div_ceil(2).max(1)),
            depth: 0,
        };
        if n > 0 {
            builder.build(&mut order, 0, 0);
        }
        let tris = mesh.triangles();
        let vn = mesh.normals();
        Self {
            depth: builder.depth,
            nodes: builder.nodes,
            corners: order.iter().map(|&t| mesh.corners(t as usize)).collect(),
            normals: order
                .iter()
                .map(|&t| tris[t as usize].map(|v| vn[v as usize]))
                .collect(),
            ids: order,
        }
    }

    /// The nodes in their flat depth-first order, for a copy of the
    /// hierarchy on another device (the GPU's stack traversal walks the
    /// same nodes as [`Bvh::closest_hit`]).
    pub fn flat_nodes(&self) -> impl ExactSizeIterator<Item = FlatNode> + '_ {
        self.nodes.iter().map(|n| FlatNode {
            lo: n.lo,
            hi: n.hi,
            offset: n.offset,
            count: n.count,
            axis: n.axis,
        })
    }

    /// Each leaf slot's corners, vertex normals and mesh triangle id, in
    /// leaf order (a leaf's `offset` indexes these).
    pub fn leaf_triangles(&self) -> impl ExactSizeIterator<Item = (&[DVec3; 3], &[DVec3; 3], u32)> {
        self.corners
            .iter()
            .zip(&self.normals)
            .zip(&self.ids)
            .map(|((c, n), &id)| (c, n, id))
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Levels from the root to the deepest leaf, counting both.
    pub fn depth(&self) -> usize {
        self.depth
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.ids.len()
    }

    /// The root box `(min, max)`, or `None` for an empty hierarchy.
    pub fn bounds(&self) -> Option<(DVec3, DVec3)> {
        self.nodes.first().map(|n| (n.lo, n.hi))
    }

    /// Walks the nodes the ray's box tests admit, nearer child first, calling
    /// `leaf(slot, t_limit)` for each triangle; `leaf` returns the new limit
    /// on `t` (closest hit) or `None` to stop (any hit).
    #[inline(always)]
    fn traverse(&self, pr: &Prepared, ray: &Ray, mut leaf: impl FnMut(usize, f64) -> Option<f64>) {
        if self.nodes.is_empty() {
            return;
        }
        let mut limit = ray.t_max;
        let mut stack = [0u32; STACK];
        let mut sp = 1;
        while sp > 0 {
            sp -= 1;
            let index = stack[sp] as usize;
            let node = &self.nodes[index];
            if !pr.hits_box(node.lo, node.hi, ray.t_min, limit) {
                continue;
            }
            if node.count > 0 {
                let first = node.offset as usize;
                for slot in first..first + node.count as usize {
                    match leaf(slot, limit) {
                        Some(l) => limit = l,
                        None => return,
                    }
                }
            } else {
                let (left, right) = (index as u32 + 1, node.offset);
                let (near, far) = if pr.negative[node.axis as usize] {
                    (right, left)
                } else {
                    (left, right)
                };
                // The depth bound keeps sp + 2 <= STACK; see SAH_DEPTH.
                stack[sp] = far;
                stack[sp + 1] = near;
                sp += 2;
            }
        }
    }

    /// The nearest hit with `t_min < t < t_max`, ties to the lower triangle
    /// id. Both faces count (a ray inside a medium hits its boundary).
    pub fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        let pr = Prepared::new(ray)?;
        let mut best: Option<(usize, f64, [f64; 3])> = None;
        self.traverse(&pr, ray, |slot, limit| {
            if let Some((t, bary)) = pr.hits_triangle(&self.corners[slot], ray.t_min, ray.t_max) {
                let better = match best {
                    None => true,
                    Some((b, bt, _)) => t < bt || (t == bt && self.ids[slot] < self.ids[b]),
                };
                if better {
                    best = Some((slot, t, bary));
                    return Some(t);
                }
            }
            Some(limit)
        });
        best.map(|(slot, t, bary)| {
            make_hit(
                self.ids[slot],
                t,
                bary,
                &self.corners[slot],
                &self.normals[slot],
            )
        })
    }

    /// Whether any triangle is hit with `t_min < t < t_max` (shadow and
    /// visibility rays); stops at the first one found.
    pub fn any_hit(&self, ray: &Ray) -> bool {
        let Some(pr) = Prepared::new(ray) else {
            return false;
        };
        let mut found = false;
        self.traverse(&pr, ray, |slot, limit| {
            if pr
                .hits_triangle(&self.corners[slot], ray.t_min, ray.t_max)
                .is_some()
            {
                found = true;
                None
            } else {
                Some(limit)
            }
        });
        found
    }
}

/// The nearest hit by testing every triangle of `mesh` in order: the
/// reference [`Bvh::closest_hit`] is checked against (same test, same tie
/// rule, so the same triangle and bit-identical `t`).
pub fn closest_hit_brute_force(mesh: &Mesh, ray: &Ray) -> Option<Hit> {
    closest_hit_among(mesh, ray, 0..mesh.triangle_count() as u32)
}

/// The nearest hit among the listed triangles of `mesh` (ids in any
/// order, repeats allowed), by [`Bvh::closest_hit`]'s test and tie rule (of
/// equal `t` the lowest id): where the list holds every triangle the ray
/// could meet, the same hit, bit for bit. A short segment finds its few
/// candidates in a grid of buckets faster than a descent of the tree.
pub fn closest_hit_among(
    mesh: &Mesh,
    ray: &Ray,
    triangles: impl IntoIterator<Item = u32>,
) -> Option<Hit> {
    closest_hit_among_with(mesh, |t| mesh.corners(t as usize), ray, triangles)
}

/// [`closest_hit_among`] with each triangle's corners from `corners` (a
/// copy of `mesh`'s, [`Mesh::corners`], kept by the caller: no lookup
/// through the vertex indices per test).
pub fn closest_hit_among_with(
    mesh: &Mesh,
    corners: impl Fn(u32) -> [DVec3; 3],
    ray: &Ray,
    triangles: impl IntoIterator<Item = u32>,
) -> Option<Hit> {
    let pr = Prepared::new(ray)?;
    let mut best: Option<(u32, f64, [f64; 3], [DVec3; 3])> = None;
    for t in triangles {
        let corners = corners(t);
        if let Some((th, bary)) = pr.hits_triangle(&corners, ray.t_min, ray.t_max) {
            if best.is_none_or(|(bt_id, bt, _, _)| th < bt || (th == bt && t < bt_id)) {
                best = Some((t, th, bary, corners));
            }
        }
    }
    best.map(|(t, th, bary, corners)| {
        let normals = mesh.triangles()[t as usize].map(|v| mesh.normals()[v as usize]);
        make_hit(t, th, bary, &corners, &normals)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedural::{cuboid, icosphere};

    #[test]
    fn ray_through_the_centre_of_a_sphere() {
        let m = icosphere(1.0, 3).unwrap();
        let bvh = Bvh::new(&m);
        let ray = Ray::new(DVec3::new(0.0, 0.0, -5.0), DVec3::Z);
        let h = bvh.closest_hit(&ray).unwrap();
        // The inscribed polyhedron is inside the sphere; here the ray meets
        // a vertex, which lies on it.
        assert!(h.t >= 4.0 - 1e-12 && h.t < 4.01, "{}", h.t);
        assert!(h.entering(ray.direction));
        assert!(h.normal.dot(-DVec3::Z) > 0.99);
        let b: f64 = h.barycentric.iter().sum();
        assert!((b - 1.0).abs() < 1e-14);
        // From inside, the far side is hit and the ray leaves.
        let inside = Ray::new(DVec3::ZERO, DVec3::Z);
        let h2 = bvh.closest_hit(&inside).unwrap();
        assert!(!h2.entering(inside.direction));
        assert!(bvh.any_hit(&inside));
        assert!(!bvh.any_hit(&Ray::segment(DVec3::ZERO, DVec3::Z, 0.0, 0.5)));
        assert!(bvh
            .closest_hit(&Ray::new(DVec3::ZERO, DVec3::ZERO))
            .is_none());
    }

    /// Rays aimed exactly at shared edges and vertices of a box, whose
    /// faces are split along diagonals, must still hit: no cracks.
    #[test]
    fn rays_through_edges_and_vertices_do_not_leak() {
        let m = cuboid(DVec3::ONE).unwrap();
        let bvh = Bvh::new(&m);
        let mut leaks = 0;
        for i in 0..=20 {
            for j in 0..=20 {
                // Targets on the z = 1 face, including its diagonal and rim.
                let target = DVec3::new(-1.0 + 0.1 * i as f64, -1.0 + 0.1 * j as f64, 1.0);
                let origin = DVec3::new(0.3, -0.2, 4.0);
                let ray = Ray::new(origin, target - origin);
                if bvh.closest_hit(&ray).is_none() {
                    leaks += 1;
                }
            }
        }
        assert_eq!(leaks, 0);
        // A ray in the plane x = -1 of a side face, with direction x = 0: its
        // slab test meets 0 * inf on that axis. It grazes the side face and
        // hits the top face on its rim edge.
        let ray = Ray::new(DVec3::new(-1.0, 0.3, 5.0), -DVec3::Z);
        let h = bvh.closest_hit(&ray).unwrap();
        assert_eq!(h.t, 4.0);
    }
}
