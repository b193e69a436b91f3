//! The BVH against brute force, and watertightness of the ray test.

use eikon_mesh::bvh::closest_hit_brute_force;
use eikon_mesh::{icosphere, revolution, BumpySphere, Bvh, Mesh, Ray};
use glam::{DVec2, DVec3};

// SplitMix64, for reproducible rays.
use eikon_rng::SplitMix64 as Rng;

/// A uniform point of the box `[lo, hi]`.
fn in_box(rng: &mut Rng, lo: DVec3, hi: DVec3) -> DVec3 {
    lo + (hi - lo) * DVec3::new(rng.unit(), rng.unit(), rng.unit())
}

fn wine_glass() -> Mesh {
    let profile: Vec<DVec2> = [
        [0.0, 0.0],
        [0.3, 0.0],
        [0.3, 0.025],
        [0.06, 0.05],
        [0.04, 0.1],
        [0.04, 0.5],
        [0.12, 0.56],
        [0.25, 0.7],
        [0.29, 0.9],
        [0.27, 1.3],
        [0.245, 1.3],
        [0.264, 0.9],
        [0.224, 0.714],
        [0.11, 0.59],
        [0.0, 0.575],
    ]
    .iter()
    .map(|p| DVec2::from_array(*p))
    .collect();
    revolution(&profile, 64).unwrap()
}

/// ~10k random rays per mesh, origins around and inside the mesh, some
/// with a finite segment: the BVH returns exactly the brute-force hit (same
/// triangle, t within 1e-9; in fact bit-identical).
#[test]
fn closest_hits_equal_brute_force() {
    let bumpy = BumpySphere::new(1.0, 0.15, 6, 11)
        .unwrap()
        .mesh(22)
        .unwrap();
    let meshes = [bumpy, wine_glass(), icosphere(0.5, 3).unwrap()];
    let mut rng = Rng::new(2024);
    for mesh in &meshes {
        let bvh = Bvh::new(mesh);
        assert_eq!(bvh.triangle_count(), mesh.triangle_count());
        assert!(bvh.depth() <= 64, "depth {}", bvh.depth());
        let (lo, hi) = mesh.bounds();
        let pad = (hi - lo) * 0.5;
        let (mut hits, mut total) = (0, 0);
        for i in 0..10_000 {
            let origin = if i % 3 == 0 {
                in_box(&mut rng, lo, hi)
            } else {
                in_box(&mut rng, lo - pad, hi + pad)
            };
            // Aim two rays in three at a point of the box so most hit.
            // Every eleventh ray runs along an axis: its slab tests meet
            // infinite reciprocals, of both signs (negating gives -0.0).
            let direction = if i % 11 == 5 {
                let axis = [DVec3::X, DVec3::Y, DVec3::Z][i % 3];
                if i % 2 == 0 {
                    axis
                } else {
                    -axis
                }
            } else if i % 3 == 1 {
                in_box(&mut rng, lo, hi) - origin
            } else {
                DVec3::from(rng.direction())
            };
            let mut ray = Ray::new(origin, direction);
            if i % 7 == 0 {
                ray.t_max = rng.unit() * 2.0;
                ray.t_min = rng.unit() * 0.1;
            }
            let a = bvh.closest_hit(&ray);
            let b = closest_hit_brute_force(mesh, &ray);
            total += 1;
            match (a, b) {
                (None, None) => {}
                (Some(a), Some(b)) => {
                    hits += 1;
                    assert_eq!(a.triangle, b.triangle, "{}: ray {i}", mesh.name());
                    assert!((a.t - b.t).abs() <= 1e-9, "{}: ray {i}", mesh.name());
                    assert_eq!(a, b, "{}: ray {i}", mesh.name());
                    // The hit lies on the triangle's plane and the ray.
                    let [p0, p1, p2] = mesh.corners(a.triangle as usize);
                    assert!((a.point - p0).dot(a.geometric_normal).abs() < 1e-12);
                    assert!((a.point - ray.at(a.t)).length() < 1e-9 * (1.0 + a.t));
                    assert!(a.barycentric.iter().all(|b| *b >= 0.0));
                    assert!(a.normal.is_normalized() && a.geometric_normal.is_normalized());
                    let _ = (p1, p2);
                }
                (a, b) => panic!("{}: ray {i}: bvh {a:?}, brute force {b:?}", mesh.name()),
            }
            assert_eq!(bvh.any_hit(&ray), a.is_some(), "{}: ray {i}", mesh.name());
        }
        assert!(
            hits > total / 3,
            "{}: only {hits} of {total} rays hit",
            mesh.name()
        );
    }
}

/// Rays from inside a closed mesh must leave through it: any miss would be
/// a crack between triangles. Rays are aimed at vertices and edge midpoints
/// too, where a non-watertight test drops hits.
#[test]
fn rays_from_inside_always_hit() {
    let b = BumpySphere::new(1.0, 0.2, 6, 5).unwrap();
    let mesh = b.mesh(22).unwrap();
    let bvh = Bvh::new(&mesh);
    let mut rng = Rng::new(7);
    let mut tested = 0;
    for i in 0..5_000 {
        // An interior point (the solid is star-shaped about the origin).
        let u = DVec3::from(rng.direction());
        let origin = u * b.radius_at(u) * 0.7 * rng.unit();
        let target = if i % 2 == 0 {
            mesh.positions()[i % mesh.vertex_count()]
        } else {
            let t = mesh.triangles()[i % mesh.triangle_count()];
            (mesh.positions()[t[0] as usize] + mesh.positions()[t[1] as usize]) * 0.5
        };
        let ray = Ray::new(origin, target - origin);
        let hit = bvh.closest_hit(&ray).expect("a ray from inside escaped");
        assert!(!hit.entering(ray.direction), "ray {i}");
        tested += 1;
    }
    assert_eq!(tested, 5_000);
}

/// Along any line through a closed mesh the hits alternate between
/// entering and leaving.
#[test]
fn hits_alternate_between_entering_and_leaving() {
    let mesh = wine_glass();
    let bvh = Bvh::new(&mesh);
    let mut rng = Rng::new(99);
    let (lo, hi) = mesh.bounds();
    for _ in 0..500 {
        let origin = in_box(&mut rng, lo - DVec3::ONE, hi + DVec3::ONE);
        let origin = DVec3::new(origin.x, origin.y, hi.z + 1.0);
        let target = in_box(&mut rng, lo, hi);
        let mut ray = Ray::new(origin, target - origin);
        let mut expect_entering = true;
        let mut count = 0;
        while let Some(h) = bvh.closest_hit(&ray) {
            assert_eq!(h.entering(ray.direction), expect_entering);
            expect_entering = !expect_entering;
            ray.t_min = h.t;
            count += 1;
            assert!(count < 100);
        }
        assert!(expect_entering, "the ray ended inside the glass");
    }
}
