//! Mesh objects in scenes: the grid voxelizes a closed triangle mesh (from
//! a file, or the procedural bumpy sphere and cuboctahedron) as exactly the
//! solid it bounds, and bad mesh files get errors that name the file and
//! the field.

use eikon_grid::{IndexField, Medium, Scene};
use glam::DVec3;
use std::path::Path;
mod binary;

use binary::expect_error;

/// The points of an `n`^3 lattice over `[-h, h]^3`, shifted off the
/// mesh's symmetry planes by an irrational fraction of a cell.
fn lattice(n: usize, h: f64) -> impl Iterator<Item = DVec3> {
    let cell = 2.0 * h / n as f64;
    (0..n * n * n).map(move |i| {
        let ijk = DVec3::new((i % n) as f64, (i / n % n) as f64, (i / (n * n)) as f64);
        (ijk + DVec3::new(0.29, 0.53, 0.71)) * cell - h
    })
}

#[test]
fn a_bumpy_sphere_object_is_the_bumpy_sphere() {
    let scene = Scene::parse(
        r#"
[grid]
resolution = 16
min = [-1.0, -1.0, -1.0]
max = [1.0, 1.0, 1.0]
[[object]]
shape = { type = "bumpy_sphere", center = [0.1, 0.0, -0.1], radius = 0.6, amplitude = 0.2, bumps = 9, seed = 5, frequency = 60 }
index = 1.5
"#,
        "bumpy.toml",
    )
    .unwrap();
    let shape = &scene.objects[0].shape;
    let exact = eikon_mesh::BumpySphere::new(0.6, 0.2, 9, 5).unwrap();
    let center = DVec3::new(0.1, 0.0, -0.1);
    let (mut judged, mut wrong) = (0, 0);
    for p in lattice(34, 0.9) {
        let q = p - center;
        // Away from the surface by more than the tessellation's chord
        // error (72 000 triangles: well under 0.01 of the radius).
        if (q.length() - exact.radius_at(q.normalize())).abs() < 0.006 {
            continue;
        }
        judged += 1;
        wrong += (shape.contains(p) != exact.contains(q)) as usize;
    }
    println!("{judged} points judged, {wrong} wrong");
    assert!(judged > 35_000);
    assert_eq!(wrong, 0);
}

#[test]
fn a_mesh_file_voxelizes_like_the_analytic_solid() {
    let dir = tempfile::tempdir().unwrap();
    // A 5120-triangle icosphere of radius 1, written out, then scaled to
    // 0.5 and moved by the scene.
    let sphere = eikon_mesh::icosphere(1.0, 4).unwrap();
    eikon_mesh::write_obj(&sphere, dir.path().join("ball.obj")).unwrap();
    let grid = "[grid]\nresolution = 32\nmin = [-1.0, -1.0, -1.0]\nmax = [1.0, 1.0, 1.0]\n";
    let mesh = format!(
        "{grid}[[object]]\nshape = {{ type = \"mesh\", file = \"ball.obj\", scale = 0.5, translate = [0.1, 0.0, 0.0] }}\nindex = 1.5\nextinction = [2.0, 2.0, 2.0]\n"
    );
    let ball = format!(
        "{grid}[[object]]\nshape = {{ type = \"sphere\", center = [0.1, 0.0, 0.0], radius = 0.5 }}\nindex = 1.5\nextinction = [2.0, 2.0, 2.0]\n"
    );
    let path = dir.path().join("mesh.toml");
    std::fs::write(&path, mesh).unwrap();
    let a = Medium::build(&Scene::load(&path).unwrap()).unwrap();
    let b = Medium::build(&Scene::parse(&ball, "ball.toml").unwrap()).unwrap();
    // The inscribed polyhedron lies at most r (1 - cos(edge/2r)) inside the
    // sphere, about 3e-4 of a 0.0625 voxel here: a cell's index differs by
    // that fraction of the 0.5 step at most, where a sub-sample falls in
    // the sliver.
    let (na, nb) = (a.field(0), b.field(0));
    let mut worst: f64 = 0.0;
    let g = &a.geometry;
    for i in 0..32 {
        for j in 0..32 {
            for k in 0..32 {
                let p = g.voxel_center(i, j, k);
                worst = worst.max((na.sample(p).0 - nb.sample(p).0).abs());
            }
        }
    }
    println!("largest index difference {worst:.2e}");
    assert!(worst < 0.01, "{worst}");
    assert!(na.sample(DVec3::new(0.1, 0.0, 0.0)).0 > 1.49);
    assert!(na.sample(DVec3::new(0.9, 0.9, 0.9)).0 < 1.01);
}

fn bad_scene(dir: &Path, name: &str, obj: &str) -> String {
    std::fs::write(dir.join(format!("{name}.obj")), obj).unwrap();
    let scene = dir.join(format!("{name}.toml"));
    std::fs::write(
        &scene,
        format!(
            "[grid]\nresolution = 8\nmin = [-1.0, -1.0, -1.0]\nmax = [1.0, 1.0, 1.0]\n[[object]]\nshape = {{ type = \"mesh\", file = \"{name}.obj\" }}\nindex = 1.5\n"
        ),
    )
    .unwrap();
    scene.to_str().unwrap().to_string()
}

#[test]
fn bad_meshes_get_located_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cube = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n";
    // The cube without its top (two faces missing).
    let open = format!("{cube}f 1 3 2\nf 1 4 3\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7\nf 1 5 8\nf 1 8 4\n");
    expect_error(
        &["info", &bad_scene(d, "open", &open)],
        &["object[0].shape.file", "open.obj", "open", "boundary edges"],
    );
    // Three triangles on one edge.
    let fin = format!("{cube}f 1 2 3\nf 2 1 5\nf 1 2 8\n");
    expect_error(
        &["info", &bad_scene(d, "fin", &fin)],
        &["object[0].shape.file", "fin.obj"],
    );
    let nan = "v 0 0 0\nv 1 0 nan\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n";
    expect_error(
        &["info", &bad_scene(d, "nan", nan)],
        &["object[0].shape.file", "nan.obj:2", "not finite"],
    );
    expect_error(
        &["info", &bad_scene(d, "empty", "")],
        &["object[0].shape.file", "empty.obj", "empty"],
    );
    let missing = bad_scene(d, "missing", "");
    std::fs::remove_file(d.join("missing.obj")).unwrap();
    expect_error(
        &["info", &missing],
        &["object[0].shape.file", "missing.obj", "cannot read"],
    );
}

#[test]
fn a_mesh_split_at_its_seams_is_welded_and_accepted() {
    // Every face with its own corners, as exporters write per-face normals.
    let dir = tempfile::tempdir().unwrap();
    let ico = eikon_mesh::icosphere(0.5, 1).unwrap();
    let mut obj = String::new();
    for t in ico.triangles() {
        for &v in t {
            let p = ico.positions()[v as usize];
            obj += &format!("v {} {} {}\n", p.x, p.y, p.z);
        }
    }
    for t in 0..ico.triangle_count() {
        obj += &format!("f {} {} {}\n", 3 * t + 1, 3 * t + 2, 3 * t + 3);
    }
    let scene = bad_scene(dir.path(), "seams", &obj);
    let s = Scene::load(Path::new(&scene)).unwrap();
    assert!(s.objects[0].shape.contains(DVec3::ZERO));
    assert!(!s.objects[0].shape.contains(DVec3::splat(0.45)));
}
