//! Closed triangle meshes as solids of the grid: what the eikonal pipeline
//! voxelizes when a scene's object is a mesh (the same mesh the exact
//! mesh-boundary renderers of `eikon-view` trace).
//!
//! A [`MeshSolid`] answers the two questions the voxelizer asks of every
//! shape (see [`crate::shape`]):
//!
//! * `contains(p)`: the parity of the crossings of the ray from `p` along
//!   +x (or -x, whichever meets fewer triangles before the bucket grid
//!   knows the side). The crossing test works in the yz-plane with edge functions
//!   evaluated in one canonical orientation per edge, and ties broken as if
//!   `p` were moved by an infinitesimal `(0, ε, ε²)` (simulation of
//!   simplicity), so a ray through a shared edge or vertex of a closed mesh
//!   counts exactly one crossing there: inside/outside is exact, never
//!   "mostly right".
//! * `distance(p)`: a lower bound on the distance to the surface, exact
//!   near it (the closest point on the nearest triangle), found by a ring
//!   search in a uniform bucket grid over the mesh; far from it the search
//!   stops and returns the distance already known to be clear. A lower
//!   bound is all the voxelizer needs: it supersamples every cell the bound
//!   does not clear.

use eikon_mesh::{bvh::closest_hit_among_with, Bvh, Hit, Mesh, Ray};
use glam::DVec3;
use std::sync::Arc;

/// [`MeshSolid`]'s side of a bucket that triangles touch, from which
/// [`MeshSolid::contains`] walks along +x.
const HOLDS: u8 = 0;
/// A bucket wholly outside the solid.
const OUTSIDE: u8 = 1;
/// A bucket wholly inside the solid.
const INSIDE: u8 = 2;
/// A bucket that triangles touch, from which [`MeshSolid::contains`]
/// walks along -x (fewer triangles lie that way before a bucket of known
/// side).
const HOLDS_BACK: u8 = 3;

/// Most buckets a segment's box may overlap for [`MeshSolid::closest_hit`]
/// to test their triangles instead of descending the tree.
const SHORT_BUCKETS: usize = 8;

/// Most buckets along one axis.
const MAX_BUCKETS: usize = 96;
/// Shells of buckets searched around a point before `distance` settles for
/// a lower bound.
const MAX_SHELLS: usize = 3;

/// A closed, consistently oriented triangle mesh as a solid.
pub struct MeshSolid {
    mesh: Arc<Mesh>,
    smooth: bool,
    tris: Vec<[DVec3; 3]>,
    lo: DVec3,
    hi: DVec3,
    cell: DVec3,
    dims: [usize; 3],
    /// Bucket `b` lists `items[start[b]..start[b + 1]]`.
    start: Vec<u32>,
    items: Vec<u32>,
    /// Per entry of `items`, its triangle's corners' least and greatest
    /// `y` and `z`: a line along x outside them misses it
    /// ([`Self::crossings`]). Kept beside the lists, in their order, for
    /// the walks along a row.
    items_yz: Vec<[f64; 4]>,
    /// Per bucket: [`HOLDS`] or [`HOLDS_BACK`] where triangles touch it,
    /// else which side of the surface the whole bucket lies on
    /// ([`OUTSIDE`], [`INSIDE`]).
    side: Vec<u8>,
    /// The ray-triangle hierarchy, for exact surface crossings
    /// ([`crate::surface`]).
    bvh: Bvh,
}

impl std::fmt::Debug for MeshSolid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MeshSolid")
            .field("mesh", &self.mesh.name())
            .field("triangles", &self.tris.len())
            .field("buckets", &self.dims)
            .finish_non_exhaustive()
    }
}

impl MeshSolid {
    /// The solid bounded by `mesh`, which must be closed (checked by the
    /// caller with [`Mesh::require_closed`]) and non-empty. `smooth` says
    /// whether renderers of the exact boundary shade it with the mesh's
    /// vertex normals (a curved surface) or its face normals (facets).
    pub fn new(mesh: Arc<Mesh>, smooth: bool) -> MeshSolid {
        let bvh = Bvh::new(&mesh);
        let tris: Vec<[DVec3; 3]> = (0..mesh.triangle_count())
            .map(|t| mesh.corners(t))
            .collect();
        let (mut lo, mut hi) = mesh.bounds();
        // Pad the box so that rounding at its faces never drops a triangle.
        let pad = (hi - lo).max_element().max(1e-300) * 1e-9;
        lo -= DVec3::splat(pad);
        hi += DVec3::splat(pad);
        let ext = hi - lo;
        // About two triangles per bucket, cells roughly cubic.
        let target = (2.0 * tris.len() as f64).cbrt().max(1.0);
        let scale = target / ext.max_element();
        let dims =
            [ext.x, ext.y, ext.z].map(|e| ((e * scale).ceil() as usize).clamp(1, MAX_BUCKETS));
        let cell = ext / DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
        let mut solid = MeshSolid {
            mesh,
            smooth,
            tris,
            lo,
            hi,
            cell,
            dims,
            start: Vec::new(),
            items: Vec::new(),
            items_yz: Vec::new(),
            side: Vec::new(),
            bvh,
        };
        solid.fill_buckets();
        solid.find_sides();
        solid
    }

    /// Counting sort of the triangles into every bucket their (padded)
    /// bounding box overlaps.
    fn fill_buckets(&mut self) {
        let [nx, ny, nz] = self.dims;
        let mut count = vec![0u32; nx * ny * nz + 1];
        let ranges: Vec<[[usize; 2]; 3]> = self
            .tris
            .iter()
            .map(|t| {
                let a = t[0].min(t[1]).min(t[2]);
                let b = t[0].max(t[1]).max(t[2]);
                let pad = (b - a).max_element() * 1e-9 + 1e-300;
                let i0 = self.bucket_of(a - DVec3::splat(pad));
                let i1 = self.bucket_of(b + DVec3::splat(pad));
                [0, 1, 2].map(|k| [i0[k], i1[k]])
            })
            .collect();
        for r in &ranges {
            for_each_bucket(r, |[i, j, k]| count[(i * ny + j) * nz + k] += 1);
        }
        let mut start = vec![0u32; nx * ny * nz + 1];
        for b in 0..nx * ny * nz {
            start[b + 1] = start[b] + count[b];
        }
        let mut fill = start.clone();
        let mut items = vec![0u32; start[nx * ny * nz] as usize];
        for (t, r) in ranges.iter().enumerate() {
            for_each_bucket(r, |[i, j, k]| {
                let b = (i * ny + j) * nz + k;
                items[fill[b] as usize] = t as u32;
                fill[b] += 1;
            });
        }
        self.items_yz = items
            .iter()
            .map(|&t| {
                let t = &self.tris[t as usize];
                let (a, b) = (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]));
                [a.y, b.y, a.z, b.z]
            })
            .collect();
        self.start = start;
        self.items = items;
    }

    /// The side of every bucket no triangle touches: along each row of
    /// buckets, from its far end back, the parity of the crossings beyond
    /// (the line through the row's centre, each crossing counted in the
    /// bucket its `x` falls in, as [`Self::contains`] counts them). A
    /// bucket without triangles lies wholly on one side of a closed
    /// surface, so any point of it has that side.
    fn find_sides(&mut self) {
        let [nx, ny, nz] = self.dims;
        let mut side = vec![HOLDS; nx * ny * nz];
        // Per bucket of a row, the triangles met walking +x from it.
        let mut ahead = vec![0usize; nx];
        for j in 0..ny {
            for k in 0..nz {
                let y = self.lo.y + (j as f64 + 0.5) * self.cell.y;
                let z = self.lo.z + (k as f64 + 0.5) * self.cell.z;
                let mut inside = false;
                for i in (0..nx).rev() {
                    let b = [i, j, k];
                    if self.bucket(b).is_empty() {
                        side[(i * ny + j) * nz + k] = if inside { INSIDE } else { OUTSIDE };
                        continue;
                    }
                    let (x0, x1) = self.row_span(i);
                    self.crossings(b, y, z, |x| {
                        if x >= x0 && x < x1 {
                            inside = !inside;
                        }
                    });
                }
                // Which way from each bucket with triangles reaches a bucket
                // of known side (or the row's end) past fewer of them.
                let row = |i: usize| (i * ny + j) * nz + k;
                let mut run = 0;
                for i in (0..nx).rev() {
                    run = if side[row(i)] == HOLDS {
                        run + self.bucket([i, j, k]).len()
                    } else {
                        0
                    };
                    ahead[i] = run;
                }
                run = 0;
                for (i, &ahead) in ahead.iter().enumerate() {
                    if side[row(i)] != HOLDS {
                        run = 0;
                        continue;
                    }
                    run += self.bucket([i, j, k]).len();
                    if run < ahead {
                        side[row(i)] = HOLDS_BACK;
                    }
                }
            }
        }
        self.side = side;
    }

    /// Hand `at` the `x` of each crossing of the line along x through
    /// `(y, z)` with a triangle of bucket `b` ([`crossing_x`]), after a
    /// look at each triangle's box: a line outside it (strictly: on its
    /// edge the tie-break decides) misses.
    #[inline(always)]
    fn crossings(&self, [i, j, k]: [usize; 3], y: f64, z: f64, mut at: impl FnMut(f64)) {
        let b = (i * self.dims[1] + j) * self.dims[2] + k;
        let span = self.start[b] as usize..self.start[b + 1] as usize;
        for (&t, &[y0, y1, z0, z1]) in self.items[span.clone()].iter().zip(&self.items_yz[span]) {
            if y < y0 || y > y1 || z < z0 || z > z1 {
                continue;
            }
            if let Some(x) = crossing_x(&self.tris[t as usize], y, z) {
                at(x);
            }
        }
    }

    /// The `x` range whose crossings bucket column `i` counts: its own,
    /// open to infinity at either end of the row.
    #[inline]
    fn row_span(&self, i: usize) -> (f64, f64) {
        let x0 = if i == 0 {
            f64::NEG_INFINITY
        } else {
            self.lo.x + i as f64 * self.cell.x
        };
        let x1 = if i + 1 == self.dims[0] {
            f64::INFINITY
        } else {
            self.lo.x + (i + 1) as f64 * self.cell.x
        };
        (x0, x1)
    }

    /// The bucket holding `p`, clamped into the grid.
    fn bucket_of(&self, p: DVec3) -> [usize; 3] {
        let q = ((p - self.lo) / self.cell).to_array();
        [0, 1, 2].map(|k| (q[k].floor().max(0.0) as usize).min(self.dims[k] - 1))
    }

    fn bucket(&self, [i, j, k]: [usize; 3]) -> &[u32] {
        let b = (i * self.dims[1] + j) * self.dims[2] + k;
        &self.items[self.start[b] as usize..self.start[b + 1] as usize]
    }

    /// The mesh.
    pub fn mesh(&self) -> &Arc<Mesh> {
        &self.mesh
    }

    /// The ray-triangle hierarchy over the mesh.
    pub fn bvh(&self) -> &Bvh {
        &self.bvh
    }

    /// The ray's nearest hit, the same as [`Bvh::closest_hit`]'s bit for
    /// bit. A segment whose box overlaps only a few buckets (a light step
    /// of half a voxel near the surface) tests their triangles: every
    /// triangle it could meet is listed in the bucket of the point where it
    /// would meet it, which lies in that box.
    pub fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        let a = ray.origin + ray.direction * ray.t_min;
        let b = ray.origin + ray.direction * ray.t_max;
        if a.is_finite() && b.is_finite() {
            // The rounding of the ends, and of the hit, covered.
            let pad = DVec3::splat(1e-9 * (a.abs() + b.abs()).max_element() + 1e-300);
            let (lo, hi) = (a.min(b) - pad, a.max(b) + pad);
            if lo.cmpgt(self.hi).any() || hi.cmplt(self.lo).any() {
                return None;
            }
            let (i0, i1) = (self.bucket_of(lo), self.bucket_of(hi));
            let count: usize = (0..3).map(|k| i1[k] - i0[k] + 1).product();
            if count <= SHORT_BUCKETS {
                let r = [0, 1, 2].map(|k| [i0[k], i1[k]]);
                let mut ids = [0u32; 64];
                let mut n = 0;
                let mut fits = true;
                for_each_bucket(&r, |c| {
                    for &t in self.bucket(c) {
                        if n < ids.len() {
                            ids[n] = t;
                            n += 1;
                        } else {
                            fits = false;
                        }
                    }
                });
                if fits {
                    // A triangle over several buckets is listed in each:
                    // tested once (the hit is the same either way).
                    let ids = &mut ids[..n];
                    ids.sort_unstable();
                    let mut m = 0;
                    for k in 0..ids.len() {
                        if k == 0 || ids[k] != ids[m - 1] {
                            ids[m] = ids[k];
                            m += 1;
                        }
                    }
                    let tris = &self.tris;
                    return closest_hit_among_with(
                        &self.mesh,
                        |t| tris[t as usize],
                        ray,
                        ids[..m].iter().copied(),
                    );
                }
            }
        }
        self.bvh.closest_hit(ray)
    }

    /// The triangle nearest to `p` and the closest point on it: a ring
    /// search over the buckets that, unlike [`Self::unsigned_distance`],
    /// runs until the answer is exact (callers ask near the surface).
    pub fn closest_triangle(&self, p: DVec3) -> Option<(usize, DVec3)> {
        let q = p.clamp(self.lo, self.hi);
        let outside = (p - q).length();
        let c = self.bucket_of(q);
        let cmin = self.cell.min_element();
        let mut best: Option<(usize, DVec3, f64)> = None;
        let shells = self.dims.iter().copied().max().unwrap_or(1);
        for r in 0..=shells {
            self.for_shell(c, r, |b| {
                for &t in self.bucket(b) {
                    let x = closest_point(&self.tris[t as usize], p);
                    let d2 = (x - p).length_squared();
                    if best.is_none_or(|(_, _, b2)| d2 < b2) {
                        best = Some((t as usize, x, d2));
                    }
                }
            });
            let clear = (r as f64 * cmin).hypot(outside);
            if best.is_some_and(|(_, _, d2)| d2.sqrt() <= clear) {
                break;
            }
        }
        best.map(|(t, x, _)| (t, x))
    }

    /// Whether the surface is shaded with vertex normals.
    pub fn smooth(&self) -> bool {
        self.smooth
    }

    /// World-space bounding box of the mesh (padded by a hair).
    pub fn aabb(&self) -> (DVec3, DVec3) {
        (self.lo, self.hi)
    }

    /// Whether `p` is inside: parity of the crossings along +x (or -x,
    /// whichever passes fewer triangles from `p`'s bucket, [`HOLDS_BACK`]),
    /// up to the first bucket no triangle touches, whose side is known
    /// ([`Self::find_sides`]). Either way counts the crossings of the line
    /// through `p` along x on one side of it, each where its `x` falls, so
    /// the two agree off the surface.
    pub fn contains(&self, p: DVec3) -> bool {
        if p.cmplt(self.lo).any() || p.cmpgt(self.hi).any() {
            return false;
        }
        let [i0, j, k] = self.bucket_of(p);
        let at = |i: usize| (i * self.dims[1] + j) * self.dims[2] + k;
        let back = self.side[at(i0)] == HOLDS_BACK;
        let mut inside = false;
        // The buckets of the row from `p`'s on, the way the walk goes.
        let (mut i, end) = if back {
            (i0 as isize, -1)
        } else {
            (i0 as isize, self.dims[0] as isize)
        };
        let way = if back { -1 } else { 1 };
        while i != end {
            let iu = i as usize;
            match self.side[at(iu)] {
                OUTSIDE => return inside,
                INSIDE => return !inside,
                _ => {}
            }
            // A triangle spanning several buckets of the row is counted in
            // the one bucket its crossing falls in (`p`'s own bucket counts
            // everything between `p` and its far face too).
            let (x0, x1) = self.row_span(iu);
            let (x0, x1) = match (iu == i0, back) {
                (true, false) => (f64::NEG_INFINITY, x1),
                (true, true) => (x0, f64::INFINITY),
                _ => (x0, x1),
            };
            self.crossings([iu, j, k], p.y, p.z, |x| {
                let beyond = if back { x < p.x } else { x > p.x };
                if beyond && x >= x0 && x < x1 {
                    inside = !inside;
                }
            });
            i += way;
        }
        inside
    }

    /// A lower bound on the distance from `p` to the surface, exact within
    /// a few buckets of it.
    pub fn unsigned_distance(&self, p: DVec3) -> f64 {
        // Distance from p to the bucket grid's box: every bucket is at
        // least this far, and the search below runs from p's projection.
        let q = p.clamp(self.lo, self.hi);
        let outside = (p - q).length();
        let c = self.bucket_of(q);
        let cmin = self.cell.min_element();
        let mut best2 = f64::INFINITY;
        let shells = self.dims.iter().copied().max().unwrap_or(1);
        for r in 0..shells.min(MAX_SHELLS + 1) {
            self.for_shell(c, r, |b| {
                for &t in self.bucket(b) {
                    let d2 = (closest_point(&self.tris[t as usize], p) - p).length_squared();
                    best2 = best2.min(d2);
                }
            });
            // Unvisited buckets lie r whole buckets away from q at least;
            // projection onto the box does not lengthen distances.
            let clear = (r as f64 * cmin).hypot(outside);
            if best2.sqrt() <= clear {
                return best2.sqrt();
            }
        }
        let clear = (MAX_SHELLS as f64 * cmin).hypot(outside);
        best2.sqrt().min(clear)
    }

    /// Signed distance bound: negative inside.
    pub fn distance(&self, p: DVec3) -> f64 {
        let d = self.unsigned_distance(p);
        if self.contains(p) {
            -d
        } else {
            d
        }
    }

    /// Visit the buckets at Chebyshev distance exactly `r` from `c`.
    fn for_shell(&self, c: [usize; 3], r: usize, mut f: impl FnMut([usize; 3])) {
        let r = r as isize;
        let lim = |a: usize, n: usize| {
            let a = a as isize;
            ((a - r).max(0), (a + r).min(n as isize - 1))
        };
        let (x0, x1) = lim(c[0], self.dims[0]);
        let (y0, y1) = lim(c[1], self.dims[1]);
        let (z0, z1) = lim(c[2], self.dims[2]);
        let c = c.map(|v| v as isize);
        for i in x0..=x1 {
            for j in y0..=y1 {
                for k in z0..=z1 {
                    let m = (i - c[0]).abs().max((j - c[1]).abs()).max((k - c[2]).abs());
                    if m == r {
                        f([i as usize, j as usize, k as usize]);
                    }
                }
            }
        }
    }
}

fn for_each_bucket(r: &[[usize; 2]; 3], mut f: impl FnMut([usize; 3])) {
    for i in r[0][0]..=r[0][1] {
        for j in r[1][0]..=r[1][1] {
            for k in r[2][0]..=r[2][1] {
                f([i, j, k]);
            }
        }
    }
}

/// The edge function of the yz-projected edge `a -> b` at `(y, z)`,
/// evaluated with the endpoints in a canonical order (so both triangles of
/// a shared edge get bitwise opposite values) and never zero: a tie is
/// decided as if the point sat at `(y + ε, z + ε²)`.
#[inline]
fn edge(a: DVec3, b: DVec3, y: f64, z: f64) -> f64 {
    let swap = (a.y, a.z) > (b.y, b.z);
    let (a, b) = if swap { (b, a) } else { (a, b) };
    let (dy, dz) = (b.y - a.y, b.z - a.z);
    let mut e = dy * (z - a.z) - dz * (y - a.y);
    if e == 0.0 {
        // d/dε of the perturbed value: -dz, then the ε² term: dy.
        e = if dz != 0.0 { -dz } else { dy };
    }
    if swap {
        -e
    } else {
        e
    }
}

/// Where the line `{(x, y, z): x real}` crosses triangle `t`, if it does.
#[inline]
fn crossing_x(t: &[DVec3; 3], y: f64, z: f64) -> Option<f64> {
    let e0 = edge(t[1], t[2], y, z);
    let e1 = edge(t[2], t[0], y, z);
    let e2 = edge(t[0], t[1], y, z);
    let inside = (e0 > 0.0 && e1 > 0.0 && e2 > 0.0) || (e0 < 0.0 && e1 < 0.0 && e2 < 0.0);
    if !inside {
        return None;
    }
    let s = e0 + e1 + e2;
    let x = (e0 * t[0].x + e1 * t[1].x + e2 * t[2].x) / s;
    // Rounding must not carry the crossing out of the triangle's own x
    // range (and so out of the buckets it is listed in).
    let (x0, x1) = (
        t[0].x.min(t[1].x).min(t[2].x),
        t[0].x.max(t[1].x).max(t[2].x),
    );
    Some(x.clamp(x0, x1))
}

/// The point of triangle `t` closest to `p` [Ericson05 sec 5.1.5].
fn closest_point(t: &[DVec3; 3], p: DVec3) -> DVec3 {
    let [a, b, c] = *t;
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec2;

    fn solid(mesh: Mesh) -> MeshSolid {
        mesh.require_closed().unwrap();
        MeshSolid::new(Arc::new(mesh), true)
    }

    /// A seeded xorshift in [0, 1).
    struct Rng(u64);
    impl Rng {
        fn unit(&mut self) -> f64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// The bumpy sphere the near-surface tests use.
    fn bumpy_sphere() -> MeshSolid {
        solid(
            eikon_mesh::BumpySphere::new(0.5, 0.1, 9, 4)
                .and_then(|b| b.mesh(24))
                .unwrap(),
        )
    }

    /// Inside by the plain parity of every triangle crossed along +x.
    fn parity_along_x(s: &MeshSolid, p: DVec3) -> bool {
        s.tris
            .iter()
            .filter(|t| crossing_x(t, p.y, p.z).is_some_and(|x| x > p.x))
            .count()
            % 2
            == 1
    }

    /// A point within `spread` (a cube's side) of a random vertex.
    fn near_a_vertex(s: &MeshSolid, rng: &mut Rng, spread: f64) -> DVec3 {
        let v = s.tris[(rng.unit() * s.tris.len() as f64) as usize][0];
        v + (DVec3::new(rng.unit(), rng.unit(), rng.unit()) - 0.5) * spread
    }

    #[test]
    fn a_cube_mesh_holds_exactly_the_cube() {
        let s = solid(eikon_mesh::cuboid(DVec3::new(0.5, 0.25, 1.0)).unwrap());
        let mut rng = Rng(7);
        let half = DVec3::new(0.5, 0.25, 1.0);
        let mut wrong = 0;
        for _ in 0..20_000 {
            let p = DVec3::new(rng.unit(), rng.unit(), rng.unit()) * 3.0 - 1.5;
            let inside = p.abs().cmplt(half).all();
            wrong += (s.contains(p) != inside) as usize;
            let want = (p.abs() - half).max(DVec3::ZERO).length()
                + (p.abs() - half).max_element().min(0.0).abs();
            let d = s.unsigned_distance(p);
            assert!(d <= want + 1e-12, "{p}: bound {d} exceeds {want}");
        }
        assert_eq!(wrong, 0);
        // Rays through the diagonals that split the x-faces into triangles
        // (shared edges and vertices) cross exactly once per face.
        for (y, z) in [
            (0.0, 0.0),
            (0.125, 0.5),
            (0.125, -0.5),
            (-0.25 + 1e-3, 1.0 - 4e-3),
        ] {
            let p = DVec3::new(0.0, y, z);
            assert!(s.contains(p), "{p}");
            assert!(!s.contains(p - DVec3::X * 0.75), "{p}");
            assert!(!s.contains(p + DVec3::X * 0.75), "{p}");
        }
        // Exact near the surface.
        let d = s.unsigned_distance(DVec3::new(0.6, 0.0, 0.0));
        assert!((d - 0.1).abs() < 1e-12, "{d}");
        let d = s.distance(DVec3::new(0.4, 0.0, 0.0));
        assert!((d + 0.1).abs() < 1e-12, "{d}");
    }

    #[test]
    fn a_spool_holds_what_the_parity_over_every_triangle_says() {
        // A concave solid (a spool: thick ends, a narrow waist): the side
        // found at the first bucket without triangles must agree with the
        // plain parity of every triangle crossed along +x.
        let profile: Vec<DVec2> = [
            [0.0, 0.0],
            [0.5, 0.0],
            [0.5, 0.2],
            [0.15, 0.5],
            [0.5, 0.8],
            [0.5, 1.0],
            [0.0, 1.0],
        ]
        .iter()
        .map(|&[r, y]| DVec2::new(r, y))
        .collect();
        let s = solid(eikon_mesh::revolution(&profile, 96).unwrap());
        assert!(s.side.contains(&INSIDE) && s.side.contains(&OUTSIDE));
        let mut rng = Rng(5);
        let (lo, hi) = s.aabb();
        let (mut inside, mut outside) = (0, 0);
        for _ in 0..20_000 {
            let u = DVec3::new(rng.unit(), rng.unit(), rng.unit());
            let p = lo + (hi - lo) * (u * 1.1 - 0.05);
            let parity = parity_along_x(&s, p);
            assert_eq!(s.contains(p), parity, "{p}");
            if parity {
                inside += 1;
            } else {
                outside += 1;
            }
        }
        assert!(inside > 1000 && outside > 1000, "{inside} {outside}");
    }

    #[test]
    fn either_way_along_x_a_bumpy_sphere_holds_what_the_parity_says() {
        // Points within a few buckets of a bumpy sphere's surface, where
        // `contains` walks from buckets with triangles: +x or -x, whichever
        // passes fewer of them. Both must agree with the plain parity of
        // every triangle crossed along +x, and both ways must be taken.
        let s = bumpy_sphere();
        let mut rng = Rng(23);
        let mut ways = [0usize; 2];
        let mut inside = 0;
        for _ in 0..20_000 {
            let p = near_a_vertex(&s, &mut rng, 0.1);
            let parity = parity_along_x(&s, p);
            assert_eq!(s.contains(p), parity, "{p}");
            inside += parity as usize;
            let [i, j, k] = s.bucket_of(p);
            match s.side[(i * s.dims[1] + j) * s.dims[2] + k] {
                HOLDS => ways[0] += 1,
                HOLDS_BACK => ways[1] += 1,
                _ => {}
            }
        }
        assert!(ways.iter().all(|&w| w > 2000), "{ways:?}");
        assert!(inside > 5000 && inside < 15_000, "{inside}");
    }

    #[test]
    fn short_segments_hit_what_the_tree_hits() {
        // Segments from a hundredth of the mesh's size to all of it,
        // aimed near the surface of a bumpy sphere: the buckets' answer is
        // the tree's, triangle and distance bit for bit (misses too).
        let s = bumpy_sphere();
        let mut rng = Rng(11);
        let (mut hits, mut short) = (0, 0);
        for i in 0..20_000 {
            let o = near_a_vertex(&s, &mut rng, 0.06);
            let d = DVec3::new(rng.unit(), rng.unit(), rng.unit()) * 2.0 - 1.0;
            let len = [0.01, 0.03, 0.1, 1.0][i % 4];
            let ray = Ray::segment(o, d, 0.0, len / d.length());
            let (a, b) = (s.closest_hit(&ray), s.bvh().closest_hit(&ray));
            assert_eq!(
                a.map(|h| (h.triangle, h.t.to_bits(), h.normal.to_array())),
                b.map(|h| (h.triangle, h.t.to_bits(), h.normal.to_array())),
                "{o} {d} {len}"
            );
            hits += b.is_some() as usize;
            short += (i % 4 < 2) as usize * b.is_some() as usize;
        }
        assert!(hits > 5000 && short > 1500, "{hits} {short}");
    }

    #[test]
    fn an_icosphere_is_its_polyhedron() {
        let mesh = eikon_mesh::icosphere(1.0, 3).unwrap();
        let s = solid(mesh.clone());
        // Inside the polyhedron exactly when on the inner side of every
        // face plane (it is convex).
        let planes: Vec<(DVec3, f64)> = (0..mesh.triangle_count())
            .map(|t| {
                let n = mesh.face_normal(t).normalize();
                (n, n.dot(mesh.corners(t)[0]))
            })
            .collect();
        let mut rng = Rng(99);
        let mut checked = 0;
        for _ in 0..20_000 {
            let p = DVec3::new(rng.unit(), rng.unit(), rng.unit()) * 2.4 - 1.2;
            let margin = planes
                .iter()
                .map(|(n, d)| n.dot(p) - d)
                .fold(f64::MIN, f64::max);
            if margin.abs() < 1e-9 {
                continue;
            }
            assert_eq!(s.contains(p), margin < 0.0, "{p}: margin {margin}");
            if margin < 0.0 && margin > -0.05 {
                // Inside a convex polyhedron the distance is the nearest
                // face plane's (exact this near the surface).
                assert!((s.unsigned_distance(p) + margin).abs() < 1e-9);
            }
            checked += 1;
        }
        assert!(checked > 19_000);
    }
}
