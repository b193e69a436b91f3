//! The triangle mesh, its smooth normals, and the watertightness check.
//!
//! A [`Mesh`] is indexed: positions and unit per-vertex normals in two
//! parallel arrays and triangles as three `u32` vertex indices. Edges are
//! identified by their vertex indices, so a closed surface must share its
//! vertices between neighbouring triangles; files that repeat a vertex along a
//! seam can be joined with [`Mesh::weld`].
//!
//! Every constructor checks that indices are in range and positions finite,
//! so the other modules never see NaN or a dangling index. The raw check
//! [`check`] works on unvalidated arrays and reports those defects instead.

use crate::MeshError;
use glam::{DAffine3, DMat3, DVec3};
use std::collections::HashMap;
use std::fmt;

/// A triangle mesh with unit per-vertex normals.
///
/// Triangles wind counter-clockwise seen from outside (right-hand rule), so
/// the geometric normal `(p1 - p0) x (p2 - p0)` points out and a closed
/// mesh has positive [`signed_volume`](Mesh::signed_volume).
#[derive(Clone, Debug)]
pub struct Mesh {
    name: String,
    positions: Vec<DVec3>,
    normals: Vec<DVec3>,
    triangles: Vec<[u32; 3]>,
}

/// Checks shared by the constructors: something to render, indices that fit
/// and point at finite vertices.
fn validate(name: &str, positions: &[DVec3], triangles: &[[u32; 3]]) -> Result<(), MeshError> {
    if triangles.is_empty() {
        return Err(MeshError::NoTriangles {
            name: name.to_string(),
            detail: String::new(),
        });
    }
    // Triangle ids are u32 in the BVH, vertex indices u32 everywhere.
    if positions.len() > u32::MAX as usize || triangles.len() > u32::MAX as usize / 2 {
        return Err(MeshError::TooLarge {
            name: name.to_string(),
            count: positions.len().max(triangles.len()),
        });
    }
    if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
        return Err(MeshError::NonFiniteVertex {
            name: name.to_string(),
            index: i,
            position: positions[i].to_array(),
        });
    }
    for (t, tri) in triangles.iter().enumerate() {
        if let Some(&v) = tri.iter().find(|&&v| v as usize >= positions.len()) {
            return Err(MeshError::IndexOutOfRange {
                name: name.to_string(),
                face: t,
                vertex: v as u64,
                count: positions.len(),
            });
        }
    }
    Ok(())
}

impl Mesh {
    /// A mesh from positions and triangles, with normals computed by
    /// [`angle_weighted_normals`].
    ///
    /// Fails on no triangles, an index out of range, or a non-finite position.
    pub fn new(
        name: impl Into<String>,
        positions: Vec<DVec3>,
        triangles: Vec<[u32; 3]>,
    ) -> Result<Self, MeshError> {
        let name = name.into();
        validate(&name, &positions, &triangles)?;
        let normals = angle_weighted_normals(&positions, &triangles);
        Ok(Self {
            name,
            positions,
            normals,
            triangles,
        })
    }

    /// A mesh with given per-vertex normals, normalized here.
    ///
    /// Fails as [`Mesh::new`] does, and when the normal count differs from
    /// the vertex count or a normal is non-finite or zero.
    pub fn with_normals(
        name: impl Into<String>,
        positions: Vec<DVec3>,
        mut normals: Vec<DVec3>,
        triangles: Vec<[u32; 3]>,
    ) -> Result<Self, MeshError> {
        let name = name.into();
        validate(&name, &positions, &triangles)?;
        if normals.len() != positions.len() {
            return Err(MeshError::BadNormals {
                message: format!("{} normals for {} vertices", normals.len(), positions.len()),
                name,
            });
        }
        for (i, n) in normals.iter_mut().enumerate() {
            let m = n.normalize_or_zero();
            if m == DVec3::ZERO {
                return Err(MeshError::BadNormals {
                    message: format!("normal {i} is {:?}, not a finite non-zero vector", n),
                    name,
                });
            }
            *n = m;
        }
        Ok(Self {
            name,
            positions,
            normals,
            triangles,
        })
    }

    /// Replaces normals with file-supplied ones where `given[i]` is finite and
    /// non-zero; other vertices keep their computed normals.
    pub(crate) fn override_normals(&mut self, given: &[DVec3]) {
        for (n, g) in self.normals.iter_mut().zip(given) {
            let m = g.normalize_or_zero();
            if m != DVec3::ZERO {
                *n = m;
            }
        }
    }

    /// The file path or shape description used in error messages.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Renames the mesh (error messages use the name).
    pub fn set_name(&mut self, name: impl Into<String>) {
        self.name = name.into();
    }

    /// Vertex positions.
    pub fn positions(&self) -> &[DVec3] {
        &self.positions
    }

    /// Unit per-vertex normals, parallel to [`positions`](Mesh::positions).
    /// A vertex used by no triangle of non-zero area has a zero normal.
    pub fn normals(&self) -> &[DVec3] {
        &self.normals
    }

    /// Triangles as vertex indices, counter-clockwise seen from outside.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// The three corners of triangle `t`.
    ///
    /// # Panics
    /// When `t` is not below [`triangle_count`](Mesh::triangle_count).
    pub fn corners(&self, t: usize) -> [DVec3; 3] {
        self.triangles[t].map(|v| self.positions[v as usize])
    }

    /// Unit geometric normal of triangle `t` (zero when it has no area).
    ///
    /// # Panics
    /// When `t` is not below [`triangle_count`](Mesh::triangle_count).
    pub fn face_normal(&self, t: usize) -> DVec3 {
        let [a, b, c] = self.corners(t);
        (b - a).cross(c - a).normalize_or_zero()
    }

    /// Axis-aligned bounds `(min, max)` of the vertices.
    pub fn bounds(&self) -> (DVec3, DVec3) {
        self.positions.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), p| (lo.min(*p), hi.max(*p)),
        )
    }

    /// Total surface area.
    pub fn area(&self) -> f64 {
        surface_area(&self.positions, &self.triangles)
    }

    /// Signed enclosed volume: positive for a closed, outward-facing mesh.
    /// Meaningless for an open mesh.
    pub fn signed_volume(&self) -> f64 {
        signed_volume(&self.positions, &self.triangles)
    }

    /// The watertightness report (see [`check`]).
    pub fn check(&self) -> CheckReport {
        check(&self.positions, &self.triangles)
    }

    /// The report, or an error unless the mesh is closed, manifold,
    /// consistently oriented and faces outward (positive volume), which a
    /// medium boundary must be for a ray that enters it to leave it again.
    pub fn require_closed(&self) -> Result<CheckReport, MeshError> {
        let r = self.check();
        let name = || self.name.clone();
        if let Some(&edge) = r.non_manifold_edges.first() {
            return Err(MeshError::NonManifold {
                name: name(),
                count: r.non_manifold_edges.len(),
                edge,
            });
        }
        if let Some(&edge) = r.boundary_edges.first() {
            return Err(MeshError::Open {
                name: name(),
                count: r.boundary_edges.len(),
                edge,
            });
        }
        if let Some(&edge) = r.misoriented_edges.first() {
            return Err(MeshError::Misoriented {
                name: name(),
                count: r.misoriented_edges.len(),
                edge,
            });
        }
        if r.signed_volume.is_nan() || r.signed_volume <= 0.0 {
            return Err(MeshError::InsideOut {
                name: name(),
                volume: r.signed_volume,
            });
        }
        Ok(r)
    }

    /// Recomputes the normals by [`angle_weighted_normals`].
    pub fn recompute_normals(&mut self) {
        self.normals = angle_weighted_normals(&self.positions, &self.triangles);
    }

    /// Reverses every triangle and normal (inside out).
    pub fn flip(&mut self) {
        for t in &mut self.triangles {
            t.swap(1, 2);
        }
        for n in &mut self.normals {
            *n = -*n;
        }
    }

    /// Applies an affine map: positions by `map`, normals by its inverse
    /// transpose. A reflection (negative determinant) also reverses the
    /// triangles so they stay outward-facing.
    ///
    /// Fails, leaving the mesh unchanged, when the linear part is singular or
    /// not finite, or a moved vertex overflows.
    pub fn transform(&mut self, map: DAffine3) -> Result<(), MeshError> {
        let m: DMat3 = map.matrix3;
        let det = m.determinant();
        if !det.is_finite() || det == 0.0 || !map.translation.is_finite() {
            return Err(MeshError::InvalidParameter {
                name: self.name.clone(),
                message: format!(
                    "cannot apply a singular or non-finite transform (determinant {det})"
                ),
            });
        }
        let positions: Vec<DVec3> = self
            .positions
            .iter()
            .map(|&p| map.transform_point3(p))
            .collect();
        if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
            return Err(MeshError::NonFiniteVertex {
                name: self.name.clone(),
                index: i,
                position: positions[i].to_array(),
            });
        }
        let nm = m.inverse().transpose();
        self.positions = positions;
        for n in &mut self.normals {
            *n = (nm * *n).normalize_or_zero();
        }
        if det < 0.0 {
            for t in &mut self.triangles {
                t.swap(1, 2);
            }
        }
        Ok(())
    }

    /// Merges vertices closer than `tolerance` (0: bit-identical positions),
    /// drops the triangles that collapse, and removes vertices no triangle
    /// uses. Normals of merged vertices are averaged. Returns how many
    /// vertices and triangles were removed.
    ///
    /// Use it for files that repeat vertices along seams: their edges are
    /// otherwise distinct and the mesh reads as open.
    pub fn weld(&mut self, tolerance: f64) -> Result<WeldSummary, MeshError> {
        if tolerance.is_nan() || tolerance < 0.0 {
            return Err(MeshError::InvalidParameter {
                name: self.name.clone(),
                message: format!("weld tolerance must be >= 0, not {tolerance}"),
            });
        }
        let remap = weld_map(&self.positions, tolerance);
        let (positions, normals, triangles, summary) = apply_weld(
            &self.positions,
            Some(&self.normals),
            &self.triangles,
            &remap,
        );
        if triangles.is_empty() {
            return Err(MeshError::NoTriangles {
                name: self.name.clone(),
                detail: format!("; welding at tolerance {tolerance} collapsed every triangle"),
            });
        }
        self.positions = positions;
        self.triangles = triangles;
        let normals = normals.unwrap_or_default();
        self.normals = angle_weighted_normals(&self.positions, &self.triangles);
        self.override_normals(&normals);
        Ok(summary)
    }
}

/// What [`Mesh::weld`] removed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WeldSummary {
    /// Vertices merged into another or no longer used.
    pub removed_vertices: usize,
    /// Triangles that collapsed (two corners became one vertex).
    pub removed_triangles: usize,
}

/// For each vertex, the first earlier vertex within `tolerance` of it (or
/// itself). A hash grid with cells of the tolerance keeps this linear.
pub(crate) fn weld_map(positions: &[DVec3], tolerance: f64) -> Vec<u32> {
    let mut remap = Vec::with_capacity(positions.len());
    if tolerance == 0.0 {
        // -0.0 and 0.0 are the same point.
        let key = |p: DVec3| (p + DVec3::ZERO).to_array().map(f64::to_bits);
        let mut seen: HashMap<[u64; 3], u32> = HashMap::with_capacity(positions.len());
        for (i, p) in positions.iter().enumerate() {
            remap.push(*seen.entry(key(*p)).or_insert(i as u32));
        }
        return remap;
    }
    let cell = |p: DVec3| (p / tolerance).floor().to_array().map(|c| c as i64);
    let mut grid: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
    let tol2 = tolerance * tolerance;
    for (i, &p) in positions.iter().enumerate() {
        let c = cell(p);
        let mut found = None;
        'search: for dx in -1..=1i64 {
            for dy in -1..=1i64 {
                for dz in -1..=1i64 {
                    let k = [
                        c[0].saturating_add(dx),
                        c[1].saturating_add(dy),
                        c[2].saturating_add(dz),
                    ];
                    if let Some(list) = grid.get(&k) {
                        if let Some(&j) = list
                            .iter()
                            .find(|&&j| positions[j as usize].distance_squared(p) <= tol2)
                        {
                            found = Some(j);
                            break 'search;
                        }
                    }
                }
            }
        }
        match found {
            Some(j) => remap.push(j),
            None => {
                grid.entry(c).or_default().push(i as u32);
                remap.push(i as u32);
            }
        }
    }
    remap
}

/// Welded arrays after a vertex remap: the kept vertices in their original
/// order, summed normals, triangles with distinct corners.
#[allow(clippy::type_complexity)]
pub(crate) fn apply_weld(
    positions: &[DVec3],
    normals: Option<&[DVec3]>,
    triangles: &[[u32; 3]],
    remap: &[u32],
) -> (Vec<DVec3>, Option<Vec<DVec3>>, Vec<[u32; 3]>, WeldSummary) {
    let mut kept = Vec::with_capacity(triangles.len());
    for t in triangles {
        let m = t.map(|v| remap[v as usize]);
        if m[0] != m[1] && m[1] != m[2] && m[0] != m[2] {
            kept.push(m);
        }
    }
    // Compact: only representatives that some kept triangle uses.
    let mut new_index = vec![u32::MAX; positions.len()];
    let mut used = vec![false; positions.len()];
    for t in &kept {
        for &v in t {
            used[v as usize] = true;
        }
    }
    let mut out_pos = Vec::new();
    for (i, p) in positions.iter().enumerate() {
        if used[i] {
            new_index[i] = out_pos.len() as u32;
            out_pos.push(*p);
        }
    }
    let out_normals = normals.map(|ns| {
        let mut sum = vec![DVec3::ZERO; out_pos.len()];
        for (i, n) in ns.iter().enumerate() {
            let r = remap[i] as usize;
            if used[r] {
                sum[new_index[r] as usize] += *n;
            }
        }
        sum
    });
    for t in &mut kept {
        *t = t.map(|v| new_index[v as usize]);
    }
    let summary = WeldSummary {
        removed_vertices: positions.len() - out_pos.len(),
        removed_triangles: triangles.len() - kept.len(),
    };
    (out_pos, out_normals, kept, summary)
}

/// Per-vertex normals as the average of the adjacent face normals weighted by
/// the corner angle (Thürmer & Wüthrich 1998).
///
/// Angle weights make the normal independent of how a face is split into
/// triangles: a cube corner gets the exact diagonal whatever the diagonals of
/// its faces. Triangles of zero area are skipped; a vertex with no other
/// triangle gets the zero vector. Indices must be in range.
pub fn angle_weighted_normals(positions: &[DVec3], triangles: &[[u32; 3]]) -> Vec<DVec3> {
    let mut acc = vec![DVec3::ZERO; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|v| positions[v as usize]);
        let (ab, ac, bc) = (b - a, c - a, c - b);
        let cross = ab.cross(ac);
        let len = cross.length();
        if len == 0.0 || !len.is_finite() {
            continue;
        }
        let n = cross / len;
        // atan2 of |cross| and dot is accurate for all angles, unlike acos.
        let angle_a = len.atan2(ab.dot(ac));
        let angle_b = ab.cross(bc).length().atan2(-ab.dot(bc));
        let angle_c = (std::f64::consts::PI - angle_a - angle_b).max(0.0);
        acc[t[0] as usize] += n * angle_a;
        acc[t[1] as usize] += n * angle_b;
        acc[t[2] as usize] += n * angle_c;
    }
    acc.iter().map(|n| n.normalize_or_zero()).collect()
}

/// Total area of the triangles whose corners are finite and in range.
fn surface_area(positions: &[DVec3], triangles: &[[u32; 3]]) -> f64 {
    triangles
        .iter()
        .filter_map(|t| corners_checked(positions, t))
        .map(|[a, b, c]| 0.5 * (b - a).cross(c - a).length())
        .filter(|a| a.is_finite())
        .sum()
}

/// Signed volume by the divergence theorem. Corners are taken relative to a
/// reference vertex so a mesh far from the origin does not lose digits.
fn signed_volume(positions: &[DVec3], triangles: &[[u32; 3]]) -> f64 {
    let origin = positions
        .iter()
        .copied()
        .find(|p| p.is_finite())
        .unwrap_or(DVec3::ZERO);
    triangles
        .iter()
        .filter_map(|t| corners_checked(positions, t))
        .map(|[a, b, c]| (a - origin).dot((b - origin).cross(c - origin)) / 6.0)
        .filter(|v| v.is_finite())
        .sum()
}

fn corners_checked(positions: &[DVec3], t: &[u32; 3]) -> Option<[DVec3; 3]> {
    let get = |v: u32| positions.get(v as usize).copied().filter(|p| p.is_finite());
    Some([get(t[0])?, get(t[1])?, get(t[2])?])
}

/// What [`check`] found. Edges are pairs of vertex indices; lists are in
/// ascending order of the smaller index.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CheckReport {
    /// Number of vertices.
    pub vertices: usize,
    /// Number of triangles.
    pub triangles: usize,
    /// Edges with exactly one triangle, directed as that triangle runs them.
    pub boundary_edges: Vec<[u32; 2]>,
    /// Edges with more than two triangles, as `[smaller, larger]`.
    pub non_manifold_edges: Vec<[u32; 2]>,
    /// Edges whose two triangles run them in the same direction (their
    /// orientations disagree), as `[smaller, larger]`.
    pub misoriented_edges: Vec<[u32; 2]>,
    /// Triangles with a repeated corner or (numerically) zero area. They are
    /// reported, not rejected: they cover nothing and no ray hits them.
    /// Triangles with a repeated corner take no part in the edge analysis.
    pub degenerate_triangles: Vec<u32>,
    /// Vertices with a NaN or infinite coordinate.
    pub non_finite_vertices: Vec<u32>,
    /// Triangles with a vertex index out of range (left out of everything else).
    pub invalid_triangles: Vec<u32>,
    /// Vertices no triangle uses.
    pub unreferenced_vertices: usize,
    /// Surface area of the valid triangles.
    pub area: f64,
    /// Signed volume of the valid triangles; positive when closed and
    /// outward-facing.
    pub signed_volume: f64,
}

impl CheckReport {
    /// Closed, manifold and consistently oriented: every edge has exactly two
    /// triangles that run it in opposite directions, and every vertex and
    /// index is valid. Says nothing about the sign of the volume.
    pub fn is_closed(&self) -> bool {
        self.boundary_edges.is_empty()
            && self.non_manifold_edges.is_empty()
            && self.misoriented_edges.is_empty()
            && self.non_finite_vertices.is_empty()
            && self.invalid_triangles.is_empty()
    }

    /// Closed and facing outward (positive volume).
    pub fn is_watertight(&self) -> bool {
        self.is_closed() && self.signed_volume > 0.0
    }
}

impl fmt::Display for CheckReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} vertices, {} triangles, area {:.6e}, volume {:.6e}; ",
            self.vertices, self.triangles, self.area, self.signed_volume
        )?;
        if self.is_watertight() {
            write!(f, "watertight")?;
        } else if self.is_closed() {
            write!(f, "closed but facing inward")?;
        } else {
            let parts = [
                (self.boundary_edges.len(), "boundary edges"),
                (self.non_manifold_edges.len(), "non-manifold edges"),
                (self.misoriented_edges.len(), "misoriented edges"),
                (self.non_finite_vertices.len(), "non-finite vertices"),
                (self.invalid_triangles.len(), "triangles with bad indices"),
            ];
            let list: Vec<String> = parts
                .iter()
                .filter(|(n, _)| *n > 0)
                .map(|(n, what)| format!("{n} {what}"))
                .collect();
            write!(f, "not closed: {}", list.join(", "))?;
        }
        if !self.degenerate_triangles.is_empty() {
            write!(
                f,
                "; {} degenerate triangles",
                self.degenerate_triangles.len()
            )?;
        }
        Ok(())
    }
}

/// Topology and geometry check of raw arrays (no validation needed: bad
/// indices and non-finite vertices are reported, not fatal).
///
/// Edges are sorted rather than hashed, which keeps the check fast and the
/// report deterministic.
pub fn check(positions: &[DVec3], triangles: &[[u32; 3]]) -> CheckReport {
    let n = positions.len();
    let mut report = CheckReport {
        vertices: n,
        triangles: triangles.len(),
        ..Default::default()
    };
    report.non_finite_vertices = positions
        .iter()
        .enumerate()
        .filter(|(_, p)| !p.is_finite())
        .map(|(i, _)| i as u32)
        .collect();
    let mut used = vec![false; n];
    // (edge key, forward?) per directed edge of each usable triangle.
    let mut edges: Vec<(u64, bool)> = Vec::with_capacity(3 * triangles.len());
    for (ti, t) in triangles.iter().enumerate() {
        if t.iter().any(|&v| v as usize >= n) {
            report.invalid_triangles.push(ti as u32);
            continue;
        }
        for &v in t {
            used[v as usize] = true;
        }
        let repeated = t[0] == t[1] || t[1] == t[2] || t[0] == t[2];
        if repeated || is_zero_area(t.map(|v| positions[v as usize])) {
            report.degenerate_triangles.push(ti as u32);
        }
        if repeated {
            continue;
        }
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let key = ((a.min(b) as u64) << 32) | a.max(b) as u64;
            edges.push((key, a < b));
        }
    }
    report.unreferenced_vertices = used.iter().filter(|u| !**u).count();
    edges.sort_unstable();
    let split = |key: u64| [(key >> 32) as u32, key as u32];
    let mut i = 0;
    while i < edges.len() {
        let key = edges[i].0;
        let mut j = i + 1;
        while j < edges.len() && edges[j].0 == key {
            j += 1;
        }
        match j - i {
            1 => {
                let [lo, hi] = split(key);
                report
                    .boundary_edges
                    .push(if edges[i].1 { [lo, hi] } else { [hi, lo] });
            }
            2 => {
                if edges[i].1 == edges[i + 1].1 {
                    report.misoriented_edges.push(split(key));
                }
            }
            _ => report.non_manifold_edges.push(split(key)),
        }
        i = j;
    }
    report.area = surface_area(positions, triangles);
    report.signed_volume = signed_volume(positions, triangles);
    report
}

/// Zero area up to rounding: the cross product is negligible next to the
/// longest edge squared. Non-finite corners count as degenerate too.
fn is_zero_area([a, b, c]: [DVec3; 3]) -> bool {
    let (ab, ac, bc) = (b - a, c - a, c - b);
    let longest = ab
        .length_squared()
        .max(ac.length_squared())
        .max(bc.length_squared());
    let cross = ab.cross(ac).length();
    // NaN compares as unordered, hence degenerate.
    !matches!(
        cross.partial_cmp(&(4.0 * f64::EPSILON * longest)),
        Some(std::cmp::Ordering::Greater)
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Unit cube, 8 shared corners, 12 outward triangles.
    pub(crate) fn cube() -> (Vec<DVec3>, Vec<[u32; 3]>) {
        let p: Vec<DVec3> = (0..8)
            .map(|i| DVec3::new((i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64))
            .collect();
        let quads = [
            [0, 2, 3, 1], // z = 0, normal -z
            [4, 5, 7, 6], // z = 1
            [0, 1, 5, 4], // y = 0
            [2, 6, 7, 3], // y = 1
            [0, 4, 6, 2], // x = 0
            [1, 3, 7, 5], // x = 1
        ];
        let mut t = Vec::new();
        for q in quads {
            t.push([q[0], q[1], q[2]]);
            t.push([q[0], q[2], q[3]]);
        }
        (p, t)
    }

    #[test]
    fn cube_is_watertight_with_unit_volume() {
        let (p, t) = cube();
        let m = Mesh::new("cube", p, t).unwrap();
        let r = m.require_closed().unwrap();
        assert!((r.signed_volume - 1.0).abs() < 1e-14);
        assert!((r.area - 6.0).abs() < 1e-14);
        assert_eq!(r.unreferenced_vertices, 0);
        assert!(r.degenerate_triangles.is_empty());
    }

    #[test]
    fn cube_normals_are_the_corner_diagonals() {
        let (p, t) = cube();
        let m = Mesh::new("cube", p, t).unwrap();
        let centre = DVec3::splat(0.5);
        for (p, n) in m.positions().iter().zip(m.normals()) {
            let diagonal = (*p - centre).normalize();
            assert!(n.dot(diagonal) > 1.0 - 1e-14, "{p} {n}");
        }
    }

    #[test]
    fn flipped_cube_is_inside_out() {
        let (p, t) = cube();
        let mut m = Mesh::new("cube", p, t).unwrap();
        m.flip();
        assert!(m.check().is_closed());
        let e = m.require_closed().unwrap_err();
        assert!(matches!(e, MeshError::InsideOut { .. }), "{e}");
        assert!(e.to_string().contains("cube"));
    }

    #[test]
    fn one_misoriented_triangle_is_found() {
        let (p, mut t) = cube();
        t[3].swap(1, 2);
        let r = check(&p, &t);
        assert_eq!(r.misoriented_edges.len(), 3);
        assert!(r.boundary_edges.is_empty());
        let e = Mesh::new("c", p, t).unwrap().require_closed().unwrap_err();
        assert!(matches!(e, MeshError::Misoriented { count: 3, .. }), "{e}");
    }

    #[test]
    fn raw_check_reports_nan_and_bad_indices() {
        let (mut p, mut t) = cube();
        p[5].y = f64::NAN;
        t.push([0, 1, 99]);
        let r = check(&p, &t);
        assert_eq!(r.non_finite_vertices, vec![5]);
        assert_eq!(r.invalid_triangles, vec![12]);
        assert!(!r.is_closed());
        assert!(r.area.is_finite() && r.signed_volume.is_finite());
        let e = Mesh::new("nan", p.clone(), t[..12].to_vec()).unwrap_err();
        assert!(
            matches!(e, MeshError::NonFiniteVertex { index: 5, .. }),
            "{e}"
        );
        p[5].y = 0.0;
        let e = Mesh::new("idx", p, t).unwrap_err();
        assert!(
            matches!(
                e,
                MeshError::IndexOutOfRange {
                    face: 12,
                    vertex: 99,
                    ..
                }
            ),
            "{e}"
        );
    }

    #[test]
    fn weld_joins_a_cube_with_split_faces() {
        let (p, t) = cube();
        // Every triangle gets its own three vertices, as some exporters do.
        let mut sp = Vec::new();
        let mut st = Vec::new();
        for tri in &t {
            let base = sp.len() as u32;
            for &v in tri {
                sp.push(p[v as usize] + DVec3::splat(1e-9 * (sp.len() % 3) as f64));
            }
            st.push([base, base + 1, base + 2]);
        }
        let mut m = Mesh::new("split", sp, st).unwrap();
        assert_eq!(m.check().boundary_edges.len(), 36);
        let s = m.weld(1e-6).unwrap();
        assert_eq!(s.removed_vertices, 36 - 8);
        assert_eq!(s.removed_triangles, 0);
        m.require_closed().unwrap();
        // A huge tolerance collapses everything.
        assert!(m.weld(10.0).is_err());
    }

    #[test]
    fn reflection_keeps_the_mesh_outward() {
        let (p, t) = cube();
        let mut m = Mesh::new("cube", p, t).unwrap();
        let mirror = DAffine3::from_scale(DVec3::new(-2.0, 1.0, 1.0));
        m.transform(mirror).unwrap();
        let r = m.require_closed().unwrap();
        assert!((r.signed_volume - 2.0).abs() < 1e-13);
        // Normals still point away from the centre.
        let c = DVec3::new(-1.0, 0.5, 0.5);
        for (p, n) in m.positions().iter().zip(m.normals()) {
            assert!(n.dot(*p - c) > 0.0);
        }
        assert!(m.transform(DAffine3::from_scale(DVec3::ZERO)).is_err());
    }
}
