//! Convex polyhedra with sharp edges, for the papers' faceted test objects.

use crate::mesh::Mesh;
use crate::MeshError;
use glam::DVec3;

/// The cuboctahedron of edge length `edge` centred at the origin: the 12
/// vertices `(±1, ±1, 0)` and their permutations scaled by `edge / √2`,
/// with 8 triangular and 6 square faces (the squares split in two), every
/// triangle wound counter-clockwise seen from outside. Vertices are shared,
/// so the mesh is closed; its angle-weighted vertex normals round the
/// edges, so render it with flat (face) normals for the sharp solid.
pub fn cuboctahedron(edge: f64) -> Result<Mesh, MeshError> {
    let name = format!("cuboctahedron (edge {edge})");
    if !(edge.is_finite() && edge > 0.0) {
        return Err(MeshError::InvalidParameter {
            name,
            message: format!("edge must be finite and > 0, not {edge}"),
        });
    }
    let s = edge / 2f64.sqrt();
    // Corners found among the unscaled vertices (whose coordinates are
    // exactly 0 and +-1): an edge of 5e-324 scales every vertex to 0, and a
    // search among scaled ones found none.
    let mut unit = Vec::with_capacity(12);
    for axis in 0..3 {
        for (a, b) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
            // The vertex with a zero on `axis`.
            let mut v = [0.0; 3];
            v[(axis + 1) % 3] = a;
            v[(axis + 2) % 3] = b;
            unit.push(DVec3::from_array(v));
        }
    }
    let find = |v: DVec3| {
        unit.iter()
            .position(|p| *p == v)
            .expect("a cuboctahedron vertex") as u32
    };
    let mut faces: Vec<Vec<u32>> = Vec::new();
    // Triangles: one per octant.
    for sx in [1.0, -1.0] {
        for sy in [1.0, -1.0] {
            for sz in [1.0, -1.0] {
                faces.push(vec![
                    find(DVec3::new(sx, sy, 0.0)),
                    find(DVec3::new(sx, 0.0, sz)),
                    find(DVec3::new(0.0, sy, sz)),
                ]);
            }
        }
    }
    // Squares: one per axis direction, corners in cyclic order.
    for axis in 0..3 {
        for sign in [1.0, -1.0] {
            let corner = |a: f64, b: f64| {
                let mut v = [0.0; 3];
                v[axis] = sign;
                v[(axis + 1) % 3] = a;
                v[(axis + 2) % 3] = b;
                find(DVec3::from_array(v))
            };
            faces.push(vec![
                corner(1.0, 0.0),
                corner(0.0, 1.0),
                corner(-1.0, 0.0),
                corner(0.0, -1.0),
            ]);
        }
    }
    let mut triangles = Vec::with_capacity(20);
    for f in faces {
        for k in 1..f.len() - 1 {
            let mut t = [f[0], f[k], f[k + 1]];
            let [a, b, c] = t.map(|i| unit[i as usize]);
            // Convex about the origin: outward means away from it.
            if (b - a).cross(c - a).dot(a + b + c) < 0.0 {
                t.swap(1, 2);
            }
            triangles.push(t);
        }
    }
    let positions = unit.iter().map(|v| *v * s).collect();
    Mesh::new(name, positions, triangles)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cuboctahedron_is_closed_with_the_known_volume() {
        let m = cuboctahedron(1.0).unwrap();
        let r = m.require_closed().unwrap();
        assert_eq!((r.vertices, r.triangles), (12, 20));
        // V = 5 √2 / 3 a^3.
        let want = 5.0 * 2f64.sqrt() / 3.0;
        assert!(
            (m.signed_volume() - want).abs() < 1e-12,
            "{}",
            m.signed_volume()
        );
        assert!(cuboctahedron(-1.0).is_err());
    }

    /// Found by `tests/fuzz.rs` (family `scene`): `edge = 5e-324` in a
    /// scene panicked with "a cuboctahedron vertex" (every scaled vertex
    /// was 0, and the search among them found none).
    #[test]
    fn tiny_and_huge_edges_do_not_panic() {
        for edge in [5e-324, 1e-310, 1e-300, 1e300, f64::MAX] {
            let m = cuboctahedron(edge).unwrap();
            assert_eq!((m.vertex_count(), m.triangle_count()), (12, 20));
            assert!(m.positions().iter().all(|p| p.is_finite()));
        }
    }
}
