//! OBJ and PLY: round trips, hand-written files, and the errors bad files get.

use eikon_mesh::load::{parse_obj, parse_ply, ply_bytes};
use eikon_mesh::{
    icosphere, load, load_obj, load_ply, save, write_obj, write_ply, BumpySphere, Mesh, MeshError,
    PlyEncoding,
};
use glam::DVec3;
use std::path::Path;

fn sample() -> Mesh {
    BumpySphere::new(1.3, 0.2, 4, 1).unwrap().mesh(5).unwrap()
}

/// Same triangles, corner for corner, with bit-identical positions and the
/// same normals (to the rounding of re-normalizing a unit vector).
fn assert_same_geometry(a: &Mesh, b: &Mesh) {
    assert_eq!(a.triangle_count(), b.triangle_count());
    assert_eq!(a.vertex_count(), b.vertex_count());
    for (ta, tb) in a.triangles().iter().zip(b.triangles()) {
        for k in 0..3 {
            let (va, vb) = (ta[k] as usize, tb[k] as usize);
            assert_eq!(a.positions()[va], b.positions()[vb]);
            assert!((a.normals()[va] - b.normals()[vb]).length() < 1e-15);
        }
    }
}

#[test]
fn obj_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bumpy.obj");
    let mesh = sample();
    write_obj(&mesh, &path).unwrap();
    let back = load(&path).unwrap();
    assert_eq!(back.name(), path.display().to_string());
    assert_same_geometry(&mesh, &back);
    back.require_closed().unwrap();
    // Nothing left behind but the file itself.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}

#[test]
fn ply_round_trips_in_every_encoding() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = sample();
    for (encoding, file) in [
        (PlyEncoding::Ascii, "a.ply"),
        (PlyEncoding::BinaryLittleEndian, "le.ply"),
        (PlyEncoding::BinaryBigEndian, "be.ply"),
    ] {
        let path = dir.path().join(file);
        write_ply(&mesh, &path, encoding).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let header = String::from_utf8_lossy(&bytes[..200]);
        let expected = match encoding {
            PlyEncoding::Ascii => "format ascii",
            PlyEncoding::BinaryLittleEndian => "format binary_little_endian",
            PlyEncoding::BinaryBigEndian => "format binary_big_endian",
        };
        assert!(header.contains(expected), "{header}");
        let back = load_ply(&path).unwrap();
        // PLY keeps the vertex order.
        assert_eq!(back.positions(), mesh.positions());
        assert_eq!(back.triangles(), mesh.triangles());
        assert_same_geometry(&mesh, &back);
    }
    // `save` picks the format from the extension.
    let path = dir.path().join("saved.PLY");
    save(&mesh, &path).unwrap();
    assert_same_geometry(&mesh, &load(&path).unwrap());
    assert!(
        ply_bytes(&mesh, PlyEncoding::BinaryLittleEndian)
            .unwrap()
            .len()
            < 60 * mesh.vertex_count() + 20 * mesh.triangle_count()
    );
}

const CUBE_OBJ: &str = "\
# a unit cube of quads, no normals
v 0 0 0
v 1 0 0
v 0 1 0
v 1 1 0
v 0 0 1
v 1 0 1
v 0 1 1
v 1 1 1
f 1 3 4 2
f 5 6 8 7
f 1 2 6 5
f 3 7 8 4
f 1 5 7 3
f 2 4 8 6
";

/// A cube-like mesh from a file without normals: computed normals point
/// outward along the corner diagonals.
#[test]
fn obj_quads_without_normals() {
    let m = parse_obj(CUBE_OBJ.as_bytes(), "cube.obj").unwrap();
    assert_eq!(m.triangle_count(), 12);
    assert_eq!(m.vertex_count(), 8);
    let r = m.require_closed().unwrap();
    assert!((r.signed_volume - 1.0).abs() < 1e-15);
    let centre = DVec3::splat(0.5);
    for (p, n) in m.positions().iter().zip(m.normals()) {
        assert!(n.dot((*p - centre).normalize()) > 1.0 - 1e-12, "{p} {n}");
    }
}

/// Groups get their own vertex copies in tobj; merging identical positions
/// makes the cube closed again.
#[test]
fn obj_groups_are_welded() {
    let mut text = String::new();
    for (i, line) in CUBE_OBJ.lines().enumerate() {
        if line.starts_with("f ") && i % 2 == 0 {
            text.push_str("g part\nusemtl glass\n");
        }
        text.push_str(line);
        text.push('\n');
    }
    let m = parse_obj(text.as_bytes(), "groups.obj").unwrap();
    assert_eq!(m.vertex_count(), 8);
    m.require_closed().unwrap();
}

#[test]
fn obj_normals_are_used_when_every_face_has_them() {
    let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 2\nf 1//1 2//1 3//1\n";
    let m = parse_obj(text.as_bytes(), "tri.obj").unwrap();
    assert!(m.normals().iter().all(|n| *n == DVec3::Z));
    // One corner without a normal: all computed (here also +z).
    let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 1 0 0\nf 1//1 2//1 3\n";
    let m = parse_obj(text.as_bytes(), "tri.obj").unwrap();
    assert!(m.normals().iter().all(|n| *n == DVec3::Z));
}

#[test]
fn ply_ascii_with_extra_elements_and_properties() {
    let text = "ply
format ascii 1.0
comment a tetrahedron with colours and an extra element
element vertex 4
property float x
property float y
property float z
property uchar red
element face 4
property list uchar int vertex_indices
property uchar flags
element edge 1
property int vertex1
property int vertex2
end_header
0 0 0 255
1 0 0 0
0 1 0 0
0 0 1 0
3 0 2 1 7
3 0 1 3 7
3 0 3 2 7
3 1 2 3 7
0 1
";
    let m = parse_ply(text.as_bytes(), "tet.ply").unwrap();
    assert_eq!(m.triangle_count(), 4);
    let r = m.require_closed().unwrap();
    assert!((r.signed_volume - 1.0 / 6.0).abs() < 1e-15);
}

/// Writes `contents` to `name` in a fresh directory, loads it, returns the
/// error text (checking it names the file).
fn load_error(name: &str, contents: &[u8]) -> (MeshError, String) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, contents).unwrap();
    let e = load(&path).unwrap_err();
    let text = e.to_string();
    assert!(text.contains(&path.display().to_string()), "{text}");
    (e, text)
}

#[test]
fn bad_files_get_clear_errors() {
    // Missing, a directory, unknown extension.
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.obj");
    let e = load(&missing).unwrap_err();
    assert!(matches!(e, MeshError::Read { .. }), "{e}");
    assert!(e.to_string().contains("missing.obj"));
    let sub = dir.path().join("folder.ply");
    std::fs::create_dir(&sub).unwrap();
    assert!(matches!(load(&sub).unwrap_err(), MeshError::Read { .. }));
    let (e, _) = load_error("mesh.stl", b"solid x");
    assert!(matches!(e, MeshError::UnknownExtension { ref extension, .. } if extension == "stl"));
    let e = load(Path::new("noextension")).unwrap_err();
    assert!(matches!(e, MeshError::UnknownExtension { .. }), "{e}");

    // Empty files.
    let (e, _) = load_error("empty.obj", b"");
    assert!(matches!(e, MeshError::EmptyFile { .. }), "{e}");
    let (e, _) = load_error("empty.ply", b"");
    assert!(matches!(e, MeshError::EmptyFile { .. }), "{e}");

    // NaN vertex: the OBJ error names the line.
    let (e, text) = load_error("nan.obj", b"v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n");
    assert!(
        matches!(e, MeshError::NonFiniteVertex { index: 2, .. }),
        "{e}"
    );
    assert!(text.contains("nan.obj:3"), "{text}");
    let nan_ply = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\nproperty double z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 inf 0\n3 0 1 2\n";
    // ply-rs rejects "inf" in ASCII; its message gives the line.
    let (e, text) = load_error("inf.ply", nan_ply);
    assert!(matches!(e, MeshError::Parse { .. }), "{e}");
    assert!(text.contains("Line 12"), "{text}");
    let mut binary = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty double x\nproperty double y\nproperty double z\nelement face 1\nproperty list uchar uint vertex_indices\nend_header\n".to_vec();
    for v in [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, f64::NAN, 0.0f64] {
        binary.extend_from_slice(&v.to_le_bytes());
    }
    binary.push(3);
    for i in [0u32, 1, 2] {
        binary.extend_from_slice(&i.to_le_bytes());
    }
    let (e, _) = load_error("nan.ply", &binary);
    assert!(
        matches!(e, MeshError::NonFiniteVertex { index: 2, .. }),
        "{e}"
    );

    // Garbage and structural problems.
    let (e, _) = load_error("garbage.obj", b"v 0 0 0\nf 1 2 3\n");
    assert!(matches!(e, MeshError::Parse { .. }), "{e}");
    let (e, _) = load_error("points.obj", b"v 0 0 0\nv 1 0 0\n");
    assert!(matches!(e, MeshError::NoTriangles { .. }), "{e}");
    let (e, _) = load_error("garbage.ply", b"not a ply file\n");
    assert!(matches!(e, MeshError::Parse { .. }), "{e}");
    let cloud = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n";
    let (e, text) = load_error("cloud.ply", cloud);
    assert!(matches!(e, MeshError::NoTriangles { .. }), "{e}");
    assert!(text.contains("point cloud"), "{text}");
    let out_of_range = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n";
    let (e, _) = load_error("range.ply", out_of_range);
    assert!(
        matches!(e, MeshError::IndexOutOfRange { vertex: 5, .. }),
        "{e}"
    );
    let short = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n2 0 1\n";
    let (e, _) = load_error("short.ply", short);
    assert!(matches!(e, MeshError::ShortFace { count: 2, .. }), "{e}");
    let truncated = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n\x00\x00";
    let (e, _) = load_error("truncated.ply", truncated);
    assert!(
        matches!(e, MeshError::Parse { .. } | MeshError::NoTriangles { .. }),
        "{e}"
    );
    let no_z = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n0 0\n";
    let (e, text) = load_error("noz.ply", no_z);
    assert!(matches!(e, MeshError::Parse { .. }), "{e}");
    assert!(text.contains("\"z\""), "{text}");
}

/// An open mesh loads (it may be a part of something), but a medium
/// boundary refuses it with the file's name.
#[test]
fn open_file_is_refused_as_a_boundary() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("open.obj");
    let m = icosphere(1.0, 1).unwrap();
    let mut text = String::from_utf8(eikon_mesh::load::obj_bytes(&m)).unwrap();
    // Drop the last face line.
    let cut = text.trim_end().rfind('\n').unwrap();
    text.truncate(cut + 1);
    std::fs::write(&path, text).unwrap();
    let m = load_obj(&path).unwrap();
    let e = m.require_closed().unwrap_err();
    assert!(matches!(e, MeshError::Open { count: 3, .. }), "{e}");
    assert!(e.to_string().contains("open.obj"), "{e}");
}

#[test]
fn writing_to_a_bad_place_fails_cleanly() {
    let m = icosphere(1.0, 0).unwrap();
    let e = write_obj(&m, "/nonexistent-dir/x.obj").unwrap_err();
    assert!(matches!(e, MeshError::Write { .. }), "{e}");
    assert!(e.to_string().contains("/nonexistent-dir/x.obj"));
    assert!(matches!(
        save(&m, "x.stl").unwrap_err(),
        MeshError::UnknownExtension { .. }
    ));
}

/// Found by `tests/fuzz.rs` (family `ply`): a header announcing more
/// records than the file can hold is refused before reading. A 3 KB binary
/// file with `element end_header 2147483647` (an element without
/// properties, whose records take no bytes) made the reader allocate until
/// the process was killed.
#[test]
fn ply_counts_beyond_the_file_are_refused() {
    let file = |count: &str| {
        let mut f = format!("ply\nformat binary_big_endian 1.0\nelement end_header {count}\nelement vertex 3\nproperty double x\nproperty double y\nproperty double z\nelement face 1\nproperty list uchar uint vertex_indices\nend_header\n").into_bytes();
        for v in [0.0f64, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
            f.extend_from_slice(&v.to_be_bytes());
        }
        f.push(3);
        for i in [0u32, 1, 2] {
            f.extend_from_slice(&i.to_be_bytes());
        }
        f
    };
    let start = std::time::Instant::now();
    let e = parse_ply(&file("2147483647"), "fuzzed.ply").unwrap_err();
    assert!(start.elapsed().as_secs_f64() < 1.0);
    assert!(matches!(e, MeshError::Parse { .. }), "{e}");
    assert!(e.to_string().contains("2147483647 \"end_header\""), "{e}");
    // With the count the data holds (none), the file loads.
    assert_eq!(parse_ply(&file("0"), "ok.ply").unwrap().triangle_count(), 1);
    // Counts beyond the data in ASCII and binary: refused the same way.
    let ascii = b"ply\nformat ascii 1.0\nelement vertex 4294967295\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
    let e = parse_ply(ascii, "ascii.ply").unwrap_err();
    assert!(e.to_string().contains("4294967295 \"vertex\""), "{e}");
    let binary = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 100\nproperty list uchar uint vertex_indices\nend_header\n";
    let e = parse_ply(binary, "binary.ply").unwrap_err();
    assert!(e.to_string().contains("more than the 0 bytes"), "{e}");
}
