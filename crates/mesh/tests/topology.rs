//! The watertightness check on broken meshes.

use eikon_mesh::mesh::check;
use eikon_mesh::{icosphere, Mesh, MeshError};
use glam::DVec3;

fn tetrahedron() -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let p = vec![
        DVec3::new(0.0, 0.0, 0.0),
        DVec3::new(1.0, 0.0, 0.0),
        DVec3::new(0.0, 1.0, 0.0),
        DVec3::new(0.0, 0.0, 1.0),
    ];
    let t = vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
    (p, t)
}

#[test]
fn tetrahedron_is_watertight() {
    let (p, t) = tetrahedron();
    let r = Mesh::new("tet", p, t).unwrap().require_closed().unwrap();
    assert!((r.signed_volume - 1.0 / 6.0).abs() < 1e-15);
}

/// Deleting triangles opens the mesh: one hole of 3 edges, two neighbours
/// sharing an edge leave a hole of 4, two apart leave 6.
#[test]
fn deleted_triangles_leave_the_right_boundary() {
    let sphere = icosphere(1.0, 2).unwrap();
    let tris = sphere.triangles().to_vec();
    let positions = sphere.positions().to_vec();
    let neighbour = |a: usize| {
        let ta = tris[a];
        (0..tris.len())
            .find(|&b| b != a && tris[b].iter().filter(|v| ta.contains(v)).count() == 2)
            .unwrap()
    };
    let far = (0..tris.len())
        .find(|&b| tris[b].iter().all(|v| !tris[0].contains(v)))
        .unwrap();
    for (removed, expected) in [(vec![0], 3), (vec![0, neighbour(0)], 4), (vec![0, far], 6)] {
        let kept: Vec<[u32; 3]> = tris
            .iter()
            .enumerate()
            .filter(|(i, _)| !removed.contains(i))
            .map(|(_, t)| *t)
            .collect();
        let r = check(&positions, &kept);
        assert_eq!(r.boundary_edges.len(), expected, "{removed:?}");
        assert!(r.non_manifold_edges.is_empty() && r.misoriented_edges.is_empty());
        assert!(!r.is_closed());
        // Boundary edges run the way their triangles do: each appears
        // reversed in the deleted triangles.
        for [a, b] in &r.boundary_edges {
            assert!(removed.iter().any(|&i| {
                let t = tris[i];
                (0..3).any(|k| t[k] == *b && t[(k + 1) % 3] == *a)
            }));
        }
        let m = Mesh::new("opened sphere", positions.clone(), kept).unwrap();
        match m.require_closed() {
            Err(e @ MeshError::Open { count, .. }) => {
                assert_eq!(count, expected);
                let text = e.to_string();
                assert!(
                    text.contains("opened sphere") && text.contains("open"),
                    "{text}"
                );
            }
            other => panic!("expected an open mesh, got {other:?}"),
        }
    }
}

/// A fin on an edge of a tetrahedron: three triangles share that edge.
#[test]
fn three_triangles_on_an_edge_are_non_manifold() {
    let (mut p, mut t) = tetrahedron();
    p.push(DVec3::new(1.0, 1.0, -1.0));
    t.push([0, 1, 4]);
    let r = check(&p, &t);
    assert_eq!(r.non_manifold_edges, vec![[0, 1]]);
    // The fin's two free edges.
    assert_eq!(r.boundary_edges.len(), 2);
    let e = Mesh::new("finned", p, t)
        .unwrap()
        .require_closed()
        .unwrap_err();
    assert!(
        matches!(
            e,
            MeshError::NonManifold {
                count: 1,
                edge: [0, 1],
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("finned"));
}

/// Two closed tetrahedra touching along an edge: every edge has an even
/// number of consistent triangles, but one has four.
#[test]
fn two_solids_sharing_an_edge_are_non_manifold() {
    let (mut p, mut t) = tetrahedron();
    let (q, s) = tetrahedron();
    // The second turned half a turn about the y axis (a rotation, so it
    // still faces outward) shares edge 0-2 with the first and nothing else.
    let base = p.len() as u32;
    p.extend(q.iter().map(|v| DVec3::new(-v.x, v.y, -v.z)));
    for tri in s {
        // Vertices 0 and 2 of the copy coincide with 0 and 2: reuse them.
        let map = |v: u32| if v == 0 || v == 2 { v } else { base + v };
        t.push([map(tri[0]), map(tri[1]), map(tri[2])]);
    }
    let r = check(&p, &t);
    assert_eq!(r.non_manifold_edges, vec![[0, 2]]);
    assert!(r.boundary_edges.is_empty());
    assert_eq!(r.unreferenced_vertices, 2);
}

/// Degenerate triangles are reported but harmless; a NaN vertex is refused
/// by the constructor and reported by the raw check.
#[test]
fn degenerate_and_nan_are_reported() {
    let (mut p, mut t) = tetrahedron();
    t.push([1, 1, 2]);
    p.push(DVec3::new(0.5, 0.0, 0.0));
    t.push([0, 1, 4]);
    t.push([0, 4, 1]);
    let r = check(&p, &t);
    assert_eq!(r.degenerate_triangles, vec![4, 5, 6]);
    // The collinear pair is a folded sliver: its edge 0-1 now has four
    // triangles.
    assert_eq!(r.non_manifold_edges, vec![[0, 1]]);
    let mut q = p.clone();
    q[2] = DVec3::new(f64::NAN, 0.0, 0.0);
    let r = check(&q, &t);
    assert_eq!(r.non_finite_vertices, vec![2]);
    assert!(!r.is_closed());
    let e = Mesh::new("nan mesh", q, t).unwrap_err();
    assert!(
        matches!(e, MeshError::NonFiniteVertex { index: 2, .. }),
        "{e}"
    );
    assert!(e.to_string().contains("nan mesh"));
    let e = Mesh::new("empty", p, vec![]).unwrap_err();
    assert!(matches!(e, MeshError::NoTriangles { .. }), "{e}");
}
