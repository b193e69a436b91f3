//! Procedural meshes: convergence to the smooth shapes, watertightness,
//! exact volumes of faceted solids of revolution.

use eikon_mesh::{cuboid, icosphere, revolution, revolution_open, BumpySphere, Mesh};
use glam::{DVec2, DVec3};
use std::f64::consts::PI;

/// An inscribed polyhedron: volume and area approach the sphere's from below
/// at second order, the error shrinking 4x per level (each level halves the
/// edge length). Measured: volume error 0.395, 0.127, 0.0339, 8.62e-3,
/// 2.17e-3, 5.42e-4, 1.36e-4 for levels 0..=6, area error about 0.55 of that.
/// Tolerance per level L: volume error <= 0.6 * 4^-L, area error <= 0.33 * 4^-L.
#[test]
fn icosphere_volume_and_area_converge_to_the_sphere() {
    let radius: f64 = 1.7;
    let volume = 4.0 / 3.0 * PI * radius.powi(3);
    let area = 4.0 * PI * radius * radius;
    let mut previous: Option<(f64, f64)> = None;
    for level in 0..=6 {
        let m = icosphere(radius, level).unwrap();
        assert_eq!(m.triangle_count(), 20 * 4usize.pow(level));
        let ev = (volume - m.signed_volume()) / volume;
        let ea = (area - m.area()) / area;
        let scale = 0.25f64.powi(level as i32);
        assert!(
            ev > 0.0 && ev <= 0.6 * scale,
            "level {level}: volume error {ev:e}"
        );
        assert!(
            ea > 0.0 && ea <= 0.33 * scale,
            "level {level}: area error {ea:e}"
        );
        if let (Some((pv, pa)), true) = (previous, level >= 2) {
            let (rv, ra) = (pv / ev, pa / ea);
            assert!(
                (3.7..=4.1).contains(&rv),
                "level {level}: volume ratio {rv}"
            );
            assert!((3.7..=4.1).contains(&ra), "level {level}: area ratio {ra}");
        }
        previous = Some((ev, ea));
        // Every vertex on the sphere, every normal radial.
        for (p, n) in m.positions().iter().zip(m.normals()) {
            assert!((p.length() - radius).abs() < 1e-12);
            assert!(n.dot(p.normalize()) > 1.0 - 1e-12);
        }
    }
}

#[test]
fn icosphere_is_watertight() {
    for level in 0..=5 {
        let r = icosphere(1.0, level).unwrap().require_closed().unwrap();
        assert!(r.is_watertight() && r.signed_volume > 0.0);
        assert!(r.degenerate_triangles.is_empty());
        assert_eq!(r.unreferenced_vertices, 0);
    }
}

#[test]
fn bumpy_sphere_is_watertight_and_converges() {
    let b = BumpySphere::new(1.0, 0.15, 6, 7).unwrap();
    let exact = b.volume();
    // Radius stays within 1 +- amplitude.
    assert!(exact > 4.0 / 3.0 * PI * 0.85f64.powi(3) && exact < 4.0 / 3.0 * PI * 1.15f64.powi(3));
    // The paper's tessellation: 9680 triangles.
    let paper = b.mesh(22).unwrap();
    assert_eq!(paper.triangle_count(), 9680);
    let r = paper.require_closed().unwrap();
    assert!(r.signed_volume > 0.0 && r.degenerate_triangles.is_empty());
    // Measured relative volume errors: 5.66e-4 at frequency 32, 1.42e-4 at 64.
    let e32 = (exact - b.mesh(32).unwrap().signed_volume()) / exact;
    let e64 = (exact - b.mesh(64).unwrap().signed_volume()) / exact;
    assert!(e32.abs() < 1e-3 && e64.abs() < 2.5e-4, "{e32:e} {e64:e}");
    assert!((3.5..=4.5).contains(&(e32 / e64)), "{}", e32 / e64);
    // Vertices on the surface; the same seed gives the same shape.
    for p in paper.positions() {
        assert!((p.length() - b.radius_at(*p)).abs() < 1e-12);
    }
    assert_eq!(b, BumpySphere::new(1.0, 0.15, 6, 7).unwrap());
    assert_ne!(b, BumpySphere::new(1.0, 0.15, 6, 8).unwrap());
}

/// The exact normals of the bumpy sphere against the angle-weighted ones the
/// mesh would compute: they converge, which checks both.
#[test]
fn bumpy_sphere_normals_match_computed_ones() {
    let b = BumpySphere::new(1.0, 0.2, 5, 3).unwrap();
    let mut worst = Vec::new();
    for f in [16, 64] {
        let exact = b.mesh(f).unwrap();
        let mut computed = exact.clone();
        computed.recompute_normals();
        let max_angle = exact
            .normals()
            .iter()
            .zip(computed.normals())
            .map(|(a, b)| a.dot(*b).clamp(-1.0, 1.0).acos())
            .fold(0.0, f64::max);
        worst.push(max_angle);
        // Outward: away from the centre of a star-shaped solid.
        for (p, n) in exact.positions().iter().zip(exact.normals()) {
            assert!(n.dot(*p) > 0.0);
        }
    }
    assert!(worst[0] < 0.05, "{worst:?}");
    assert!(worst[1] < worst[0] / 4.0 && worst[1] < 5e-3, "{worst:?}");
}

/// `sum (x_i + x_j)(x_i y_j - x_j y_i) / 6`: the first moment of the polygon
/// about the axis, so 2 pi times it is the smooth solid's volume (Pappus).
fn first_moment(profile: &[DVec2]) -> f64 {
    let n = profile.len();
    let s: f64 = (0..n)
        .map(|i| {
            let (a, b) = (profile[i], profile[(i + 1) % n]);
            (a.x + b.x) * a.perp_dot(b)
        })
        .sum();
    (s / 6.0).abs()
}

/// Rings are regular s-gons and the quads between rings are planar
/// trapezoids, so each horizontal section is the s-gon inscribed in the
/// smooth section: the volume is exactly `s sin(2 pi / s) / (2 pi)` times
/// Pappus'.
fn faceted_volume(profile: &[DVec2], segments: u32) -> f64 {
    let s = segments as f64;
    s * (2.0 * PI / s).sin() * first_moment(profile)
}

fn wine_glass() -> Vec<DVec2> {
    // configs/wine-glass.toml
    [
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
    .collect()
}

#[test]
fn revolutions_are_watertight_with_exact_volume() {
    let cylinder = [
        DVec2::new(0.0, 0.0),
        DVec2::new(1.0, 0.0),
        DVec2::new(1.0, 2.0),
        DVec2::new(0.0, 2.0),
    ];
    // configs/shapes.toml, and a ring that never reaches the axis.
    let vase: Vec<DVec2> = [
        [0.0, 0.0],
        [0.25, 0.0],
        [0.3, 0.3],
        [0.15, 0.6],
        [0.2, 0.8],
        [0.0, 0.8],
    ]
    .iter()
    .map(|p| DVec2::from_array(*p))
    .collect();
    let ring = [
        DVec2::new(0.5, 0.0),
        DVec2::new(1.0, 0.0),
        DVec2::new(0.75, 0.5),
    ];
    let mut reversed = wine_glass();
    reversed.reverse();
    for (name, profile) in [
        ("cylinder", cylinder.to_vec()),
        ("wine glass", wine_glass()),
        ("clockwise wine glass", reversed),
        ("vase", vase),
        ("ring", ring.to_vec()),
    ] {
        for segments in [3, 16, 96] {
            let m = revolution(&profile, segments).unwrap();
            let r = m
                .require_closed()
                .unwrap_or_else(|e| panic!("{name}, {segments}: {e}"));
            let expected = faceted_volume(&profile, segments);
            assert!(
                (r.signed_volume - expected).abs() <= 1e-12 * expected,
                "{name}, {segments}: {} vs {expected}",
                r.signed_volume
            );
            assert!(r.degenerate_triangles.is_empty(), "{name}");
        }
    }
    // Cylinder: 2 poles, 2 rings; caps are fans, the side quads.
    let m = revolution(&cylinder, 16).unwrap();
    assert_eq!(m.vertex_count(), 2 + 2 * 16);
    assert_eq!(m.triangle_count(), 16 + 16 + 2 * 16);
}

/// An open profile gets flat caps where it ends off the axis.
#[test]
fn open_profiles_are_capped() {
    let tube = [
        DVec2::new(1.0, 0.0),
        DVec2::new(1.2, 0.5),
        DVec2::new(1.0, 1.0),
    ];
    let m = revolution_open(&tube, 32).unwrap();
    m.require_closed().unwrap();
    let closed = [
        DVec2::new(0.0, 0.0),
        DVec2::new(1.0, 0.0),
        DVec2::new(1.2, 0.5),
        DVec2::new(1.0, 1.0),
        DVec2::new(0.0, 1.0),
    ];
    assert!((m.signed_volume() - faceted_volume(&closed, 32)).abs() < 1e-12);
    // Caps are flat discs: every vertex at the end heights lies on them.
    let bottom: Vec<&DVec3> = m.positions().iter().filter(|p| p.y == 0.0).collect();
    assert_eq!(bottom.len(), 33);
    // Ends already on the axis need no cap.
    let spindle = [
        DVec2::new(0.0, 0.0),
        DVec2::new(0.5, 0.5),
        DVec2::new(0.0, 1.0),
    ];
    let s = revolution_open(&spindle, 12).unwrap();
    s.require_closed().unwrap();
    assert_eq!(s.vertex_count(), 2 + 12);
}

/// A scene's revolution placed by its base and rotation stays watertight.
#[test]
fn placed_revolution_stays_watertight() {
    let mut m: Mesh = revolution(&wine_glass(), 48).unwrap();
    let v = m.signed_volume();
    let rot = glam::DMat3::from_rotation_z(0.3) * glam::DMat3::from_rotation_x(1.1);
    m.transform(glam::DAffine3::from_mat3_translation(
        rot,
        DVec3::new(0.0, -0.7, 0.2),
    ))
    .unwrap();
    let r = m.require_closed().unwrap();
    assert!((r.signed_volume - v).abs() < 1e-12);
}

/// A cube-like mesh (a box, 8 shared corners): every computed normal points
/// out along its corner's diagonal.
#[test]
fn box_normals_point_outward() {
    let half = DVec3::new(1.0, 0.5, 2.0);
    let m = cuboid(half).unwrap();
    for (p, n) in m.positions().iter().zip(m.normals()) {
        let diagonal = p.signum() / 3f64.sqrt();
        assert!(n.dot(diagonal) > 1.0 - 1e-12, "{p} {n}");
    }
    for t in 0..m.triangle_count() {
        let [a, b, c] = m.corners(t);
        assert!(m.face_normal(t).dot((a + b + c) / 3.0) > 0.0);
    }
}
