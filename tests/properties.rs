//! Property tests of the readers (issue 17, item 7), beside the mutation
//! fuzzing of `tests/fuzz.rs`: generated valid inputs are accepted and
//! read back as written, generated invalid ones are refused with an error
//! that names the field, and arbitrary input never panics.

use eikon_grid::{vdb, Scene};
use glam::DVec3;
use proptest::prelude::*;
use std::fmt::Write as _;

/// A float as TOML writes it (shortest round-trip form).
fn f(x: f64) -> String {
    format!("{x:?}")
}

fn v3(v: [f64; 3]) -> String {
    format!("[{}, {}, {}]", f(v[0]), f(v[1]), f(v[2]))
}

/// A valid grid: per-axis voxels, a voxel size and per-axis stretches of at
/// most 8 (cells at most 8 times longer one way than another, within the
/// parser's limit of 64), a corner.
fn grid() -> impl Strategy<Value = ([u64; 3], [f64; 3], [f64; 3])> {
    (
        [1u64..=48, 1u64..=48, 1u64..=48],
        1e-3f64..10.0,
        [1.0f64..8.0, 1.0f64..8.0, 1.0f64..8.0],
        [-100.0f64..100.0, -100.0f64..100.0, -100.0f64..100.0],
    )
        .prop_map(|(dims, h, stretch, min)| {
            let max = [0, 1, 2].map(|a| min[a] + dims[a] as f64 * h * stretch[a]);
            (dims, min, max)
        })
        .prop_filter("max must exceed min after rounding", |(_, min, max)| {
            (0..3).all(|a| max[a] > min[a])
        })
}

/// A valid shape table inside the box `[lo, hi]`.
fn shape(lo: [f64; 3], hi: [f64; 3]) -> impl Strategy<Value = String> {
    let size = (0..3).map(|a| hi[a] - lo[a]).fold(f64::INFINITY, f64::min);
    let centre = [0, 1, 2].map(|a| lo[a]..=hi[a]);
    (
        0usize..7,
        centre,
        (size * 1e-3)..=size,
        (size * 1e-3)..=size,
        [-180.0f64..180.0, -180.0f64..180.0, -180.0f64..180.0],
        [0.05f64..=4.0, 0.05f64..=4.0],
        prop::array::uniform3(-1.0f64..1.0),
    )
        .prop_map(move |(kind, c, a, b, rot, e, n)| {
            let (c, rot) = (v3(c), v3(rot));
            match kind {
                0 => format!("{{ type = \"sphere\", center = {c}, radius = {} }}", f(a)),
                1 => format!(
                    "{{ type = \"box\", center = {c}, size = {}, rotation = {rot} }}",
                    v3([a, b, a])
                ),
                2 => format!(
                    "{{ type = \"rounded_box\", center = {c}, size = {}, radius = {}, rotation = {rot} }}",
                    v3([a, a, a]),
                    f(a * 0.25)
                ),
                3 => format!(
                    "{{ type = \"cylinder\", center = {c}, radius = {}, height = {}, rotation = {rot} }}",
                    f(a),
                    f(b)
                ),
                4 => format!(
                    "{{ type = \"torus\", center = {c}, major_radius = {}, minor_radius = {}, rotation = {rot} }}",
                    f(a),
                    f(b * 0.5)
                ),
                5 => format!(
                    "{{ type = \"superquadric\", center = {c}, radii = {}, exponents = [{}, {}], rotation = {rot} }}",
                    v3([a, b, a]),
                    f(e[0]),
                    f(e[1])
                ),
                _ => {
                    let n = if n.iter().all(|x| x.abs() < 1e-3) {
                        [0.0, 1.0, 0.0]
                    } else {
                        n
                    };
                    format!("{{ type = \"half_space\", point = {c}, normal = {} }}", v3(n))
                }
            }
        })
}

/// A valid scene: its text, the grid dims it asks for, min and max, and
/// its object and light counts.
fn valid_scene() -> impl Strategy<Value = (String, [u64; 3], [f64; 3], [f64; 3], usize, usize)> {
    grid().prop_flat_map(|(dims, min, max)| {
        (
            prop::collection::vec((shape(min, max), 1.0f64..3.0, -5i64..5), 0..4),
            prop::collection::vec(
                (
                    0usize..2,
                    prop::array::uniform3(0.0f64..1.0),
                    prop::array::uniform3(0.0f64..10.0),
                ),
                0..3,
            ),
            any::<bool>(),
        )
            .prop_map(move |(objects, lights, per_axis)| {
                // One number for the longest axis makes cells cubic, each axis
                // at least one voxel: keep the extents within the parser's
                // cell aspect limit for it.
                let extent = [0, 1, 2].map(|a| max[a] - min[a]);
                let ratio = extent.iter().cloned().fold(0.0, f64::max)
                    / extent.iter().cloned().fold(f64::INFINITY, f64::min);
                let per_axis = per_axis || ratio > 32.0;
                let mut t = String::new();
                let res = if per_axis {
                    format!("[{}, {}, {}]", dims[0], dims[1], dims[2])
                } else {
                    dims.iter().max().unwrap().to_string()
                };
                writeln!(
                    t,
                    "[grid]\nresolution = {res}\nmin = {}\nmax = {}",
                    v3(min),
                    v3(max)
                )
                .unwrap();
                for (shape, index, priority) in &objects {
                    writeln!(
                        t,
                        "\n[[object]]\nshape = {shape}\nindex = {}\npriority = {priority}",
                        f(*index)
                    )
                    .unwrap();
                }
                for (kind, p, power) in &lights {
                    // A unit cube position mapped into the grid.
                    let at = [0, 1, 2].map(|a| min[a] + p[a] * (max[a] - min[a]));
                    let dir = [p[0] - 0.5, -1.0, p[2] - 0.5];
                    match kind {
                        0 => writeln!(
                            t,
                            "\n[[light]]\ntype = \"directional\"\ndirection = {}\npower = {}",
                            v3(dir),
                            v3(*power)
                        ),
                        _ => writeln!(
                            t,
                            "\n[[light]]\ntype = \"point\"\nposition = {}\npower = {}",
                            v3(at),
                            v3(*power)
                        ),
                    }
                    .unwrap();
                }
                let want = if per_axis { Some(dims) } else { None };
                (
                    t,
                    want.unwrap_or([0; 3]),
                    min,
                    max,
                    objects.len(),
                    lights.len(),
                )
            })
    })
}

/// Pieces of scene files, for text that is nearly a scene.
const FRAGMENTS: [&str; 40] = [
    "[grid]\n",
    "resolution = 8\n",
    "resolution = [4, 4, 4]\n",
    "resolution = 0\n",
    "min = [-1, -1, -1]\n",
    "max = [1, 1, 1]\n",
    "max = [-1, 1, 1]\n",
    "smoothing = 0.5\n",
    "supersample = 16\n",
    "dispersion = true\n",
    "[ambient]\n",
    "index = 1.0\n",
    "index = [1.4, 1.5, 1.6]\n",
    "index = { type = \"luneburg\" }\n",
    "index = { type = \"linear\", n0 = 1.0, gradient = [0, -10, 0] }\n",
    "index = { type = \"vdb\" }\n",
    "[[object]]\n",
    "shape = { type = \"sphere\", center = [0, 0, 0], radius = 0.5 }\n",
    "shape = { type = \"revolution\", base = [0, 0, 0], profile = [[0, 0], [1, 0], [0, 1]] }\n",
    "shape = { type = \"mesh\", file = \"missing.obj\" }\n",
    "shape = { type = \"vdb\", file = \"missing.vdb\", grid = \"n\" }\n",
    "shape = { type = \"bumpy_sphere\", center = [0, 0, 0], radius = 0.5, frequency = 2 }\n",
    "shape = { type = \"cuboctahedron\", center = [0, 0, 0], edge = 0.5 }\n",
    "extinction = { type = \"vdb\", scale = [1, 1, 1] }\n",
    "g = 0.99\n",
    "[[light]]\n",
    "type = \"spot\"\n",
    "type = \"point\"\n",
    "position = [0, 0, 0]\n",
    "direction = [0, 0, 0]\n",
    "power = [1, 1, 1]\n",
    "angle = 45\n",
    "[camera]\n",
    "position = [0, 0, 3]\n",
    "target = [0, 0, 0]\n",
    "[background]\n",
    "type = \"checker\"\n",
    "[render]\n",
    "step = nan\n",
    "= = =\n",
];

/// A scene whose every section is valid once its `@NAME@` placeholders
/// are replaced.
const BASE: &str = r#"
[grid]
resolution = 8
min = [-1, -1, -1]
max = [1, 1, 1]
smoothing = @SMOOTHING@
supersample = @SUPERSAMPLE@

[[object]]
shape = { type = "sphere", center = [0, 0, 0], radius = @RADIUS@ }
index = @INDEX@
albedo = @ALBEDO@
extinction = @EXTINCTION@
g = @G@

[[light]]
type = "spot"
position = [0, 0.9, 0]
direction = [0, -1, 0]
angle = @ANGLE@
power = [1, 1, 1]

[receiver]
point = [0, -0.9, 0]
normal = [0, 1, 0]
albedo = @RECEIVER@

[camera]
position = [0, 0, 3]
target = [0, 0, 0]
fov = @FOV@
samples = @SAMPLES@

[render]
step = @STEP@
"#;

/// The placeholders of [`BASE`]: (placeholder, field path, a valid value).
const FIELDS: [(&str, &str, &str); 12] = [
    ("@SMOOTHING@", "grid.smoothing", "0.75"),
    ("@SUPERSAMPLE@", "grid.supersample", "4"),
    ("@RADIUS@", "object[0].shape.radius", "0.5"),
    ("@INDEX@", "object[0].index", "1.5"),
    ("@ALBEDO@", "object[0].albedo", "[0.5, 0.5, 0.5]"),
    ("@EXTINCTION@", "object[0].extinction", "[0.1, 0.1, 0.1]"),
    ("@G@", "object[0].g", "0.2"),
    ("@ANGLE@", "light[0].angle", "30"),
    ("@RECEIVER@", "receiver.albedo", "[0.8, 0.8, 0.8]"),
    ("@FOV@", "camera.fov", "40"),
    ("@SAMPLES@", "camera.samples", "1"),
    ("@STEP@", "render.step", "0.5"),
];

fn base_with(field: usize, value: &str) -> String {
    let mut text = BASE.to_string();
    for (i, (key, _, valid)) in FIELDS.iter().enumerate() {
        text = text.replace(key, if i == field { value } else { valid });
    }
    text
}

/// A number outside the range of field `i` of [`FIELDS`] (or not finite).
fn out_of_range(i: usize) -> BoxedStrategy<String> {
    let huge = || prop_oneof![1e3f64..1e300, Just(f64::MAX)];
    let bad = prop_oneof![
        Just("nan".to_string()),
        Just("inf".to_string()),
        Just("-inf".to_string())
    ];
    let number = match i {
        0 => prop_oneof![
            (8.0f64..1e300).prop_filter("> 8", |x| *x > 8.0),
            -1e300f64..-1e-300
        ]
        .prop_map(f)
        .boxed(),
        1 => prop_oneof![
            Just(0u64),
            17u64..=u32::MAX as u64,
            (u32::MAX as u64 + 1)..=i64::MAX as u64
        ]
        .prop_map(|n| n.to_string())
        .boxed(),
        2 | 3 => prop_oneof![-1e300f64..=0.0, Just(-0.0)].prop_map(f).boxed(),
        4 | 8 => (
            0usize..3,
            prop_oneof![
                (1.0f64..1e300).prop_filter("> 1", |x| *x > 1.0),
                -1e300f64..-1e-300
            ],
        )
            .prop_map(|(k, x)| {
                let mut v = [0.5; 3];
                v[k] = x;
                v3(v)
            })
            .boxed(),
        5 => (0usize..3, -1e300f64..-1e-300)
            .prop_map(|(k, x)| {
                let mut v = [0.1; 3];
                v[k] = x;
                v3(v)
            })
            .boxed(),
        6 => prop_oneof![1.0f64..1e300, -1e300f64..=-1.0]
            .prop_map(f)
            .boxed(),
        7 => prop_oneof![
            (90.0f64..1e300).prop_filter("> 90", |x| *x > 90.0),
            -1e300f64..=0.0
        ]
        .prop_map(f)
        .boxed(),
        9 => prop_oneof![180.0f64..1e300, -1e300f64..=0.0]
            .prop_map(f)
            .boxed(),
        10 => prop_oneof![Just(0u64), 4097u64..=u32::MAX as u64]
            .prop_map(|n| n.to_string())
            .boxed(),
        _ => prop_oneof![
            (4.0f64..1e300).prop_filter("> 4", |x| *x > 4.0),
            -1e300f64..=0.0,
            huge()
        ]
        .prop_map(f)
        .boxed(),
    };
    // Non-finite values where the field is a float.
    if matches!(i, 1 | 10) {
        number
    } else if matches!(i, 4 | 5 | 8) {
        prop_oneof![3 => number, 1 => bad.prop_map(|b| format!("[0.5, {b}, 0.5]"))].boxed()
    } else {
        prop_oneof![3 => number, 1 => bad].boxed()
    }
}

/// Cases a property: `PROPTEST_CASES` when set, else `default`.
fn cases_or(default: u32) -> u32 {
    std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(cases_or(256)))]

    /// Any text parses to a scene or an error; nothing panics.
    #[test]
    fn any_text_is_a_scene_or_an_error(text in any::<String>()) {
        let _ = Scene::parse(&text, "<prop>");
    }

    /// Text assembled from scene fragments (nearly a scene) parses to a
    /// scene or an error naming where.
    #[test]
    fn scene_fragments_are_a_scene_or_an_error(
        pieces in prop::collection::vec(prop::sample::select(FRAGMENTS.as_slice()), 0..40)
    ) {
        let text = pieces.concat();
        if let Err(e) = Scene::parse(&text, "<prop>") {
            prop_assert!(e.to_string().starts_with("<prop>"), "{e}");
        }
    }

    /// A generated valid scene parses, with the grid, objects and lights it
    /// was written with.
    #[test]
    fn valid_scenes_parse_and_keep_their_grid(
        (text, dims, min, max, objects, lights) in valid_scene()
    ) {
        let scene = Scene::parse(&text, "<prop>");
        prop_assert!(scene.is_ok(), "{}\n{text}", scene.err().unwrap());
        let scene = scene.unwrap();
        let g = &scene.grid.geometry;
        if dims != [0; 3] {
            prop_assert_eq!(g.dims, dims.map(|d| d as usize));
        } else {
            // One number: the longest axis gets it.
            let longest = text.lines().find_map(|l| l.strip_prefix("resolution = ")).unwrap();
            prop_assert_eq!(*g.dims.iter().max().unwrap(), longest.parse::<usize>().unwrap());
        }
        prop_assert_eq!(g.min, DVec3::from_array(min));
        prop_assert_eq!(g.max, DVec3::from_array(max));
        prop_assert_eq!(scene.objects.len(), objects);
        prop_assert_eq!(scene.lights.len(), lights);
    }

    /// A number outside its field's range is refused with an error naming
    /// the field.
    #[test]
    fn out_of_range_numbers_name_their_field(
        (i, value) in (0..FIELDS.len()).prop_flat_map(|i| (Just(i), out_of_range(i)))
    ) {
        let valid = base_with(usize::MAX, "");
        prop_assert!(Scene::parse(&valid, "<prop>").is_ok());
        let text = base_with(i, &value);
        match Scene::parse(&text, "<prop>") {
            Ok(_) => prop_assert!(false, "{} = {value} accepted", FIELDS[i].1),
            Err(e) => {
                let msg = e.to_string();
                prop_assert!(msg.contains(FIELDS[i].1), "{} = {value}: {msg}", FIELDS[i].1);
            }
        }
    }

    /// OBJ text of random vertices (some not finite) and faces (indices
    /// anywhere, polygons of any size) loads or errors; a loaded mesh is
    /// usable.
    #[test]
    fn random_obj_loads_or_errors(
        vertices in prop::collection::vec(
            prop::array::uniform3(prop_oneof![
                8 => -10.0f64..10.0,
                1 => Just(f64::NAN),
                1 => Just(f64::INFINITY),
                1 => Just(1e308),
            ]),
            0..12,
        ),
        faces in prop::collection::vec(
            (prop::collection::vec(-14i64..14, 0..7), 0usize..4),
            0..16,
        ),
    ) {
        let mut text = String::new();
        for v in &vertices {
            writeln!(text, "v {} {} {}", v[0], v[1], v[2]).unwrap();
        }
        text.push_str("vt 0 0\nvn 0 0 1\n");
        for (corners, style) in &faces {
            text.push('f');
            for c in corners {
                match style {
                    0 => write!(text, " {c}"),
                    1 => write!(text, " {c}/1"),
                    2 => write!(text, " {c}//1"),
                    _ => write!(text, " {c}/1/1"),
                }
                .unwrap();
            }
            text.push('\n');
        }
        if let Ok(mesh) = eikon_mesh::load::parse_obj(text.as_bytes(), "prop.obj") {
            let n = mesh.vertex_count();
            prop_assert!(mesh.positions().iter().all(|p| p.is_finite()));
            prop_assert!(mesh.triangles().iter().all(|t| t.iter().all(|&v| (v as usize) < n)));
        }
    }

    /// ASCII PLY files with random counts and values load or error.
    #[test]
    fn random_ply_loads_or_errors(
        vertex_count in prop_oneof![0u64..10, Just(u32::MAX as u64), Just(u64::MAX)],
        face_count in prop_oneof![0u64..10, Just(i32::MAX as u64)],
        list in prop::sample::select(&["uchar int", "uint uint", "char short", "uchar float", "int uchar"][..]),
        numbers in prop::collection::vec(prop_oneof![
            -4i64..12,
            Just(255),
            Just(-1),
            Just(i64::MAX),
            Just(u32::MAX as i64),
        ], 0..80),
    ) {
        let mut text = format!(
            "ply\nformat ascii 1.0\nelement vertex {vertex_count}\nproperty float x\nproperty float y\nproperty float z\nelement face {face_count}\nproperty list {list} vertex_indices\nend_header\n"
        );
        for (i, n) in numbers.iter().enumerate() {
            write!(text, "{n}{}", if i % 4 == 3 { '\n' } else { ' ' }).unwrap();
        }
        if let Ok(mesh) = eikon_mesh::load::parse_ply(text.as_bytes(), "prop.ply") {
            let n = mesh.vertex_count();
            prop_assert!(mesh.triangles().iter().all(|t| t.iter().all(|&v| (v as usize) < n)));
        }
    }

    /// A mesh written as OBJ and as PLY in each encoding reads back with
    /// the same triangles at the same positions, bit for bit.
    #[test]
    fn meshes_read_back_as_written(
        positions in prop::collection::vec(prop::array::uniform3(-1e6f64..1e6), 3..20),
        picks in prop::collection::vec((0usize..1000, 0usize..1000, 0usize..1000), 1..20),
    ) {
        let n = positions.len();
        let triangles: Vec<[u32; 3]> = picks
            .iter()
            .map(|&(a, b, c)| [a % n, b % n, c % n].map(|v| v as u32))
            .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
            .collect();
        let positions: Vec<DVec3> = positions.into_iter().map(DVec3::from_array).collect();
        prop_assume!(!triangles.is_empty());
        // Every vertex used, none twice at one place (OBJ merges those).
        let used = |v: usize| triangles.iter().any(|t| t.contains(&(v as u32)));
        prop_assume!((0..n).all(used));
        prop_assume!((0..n).all(|i| (0..i).all(|j| positions[i] != positions[j])));
        let mesh = eikon_mesh::Mesh::new("prop", positions.clone(), triangles.clone()).unwrap();
        use eikon_mesh::load::{obj_bytes, parse_obj, parse_ply, ply_bytes};
        use eikon_mesh::PlyEncoding as E;
        let corners = |m: &eikon_mesh::Mesh| -> Vec<[DVec3; 3]> {
            m.triangles().iter().map(|t| t.map(|v| m.positions()[v as usize])).collect()
        };
        // OBJ: tobj numbers the vertices in order of use, so compare the
        // triangles' corners.
        let obj = parse_obj(&obj_bytes(&mesh), "prop.obj").unwrap();
        prop_assert_eq!(corners(&obj), corners(&mesh));
        prop_assert_eq!(obj.vertex_count(), n);
        for e in [E::Ascii, E::BinaryLittleEndian, E::BinaryBigEndian] {
            let b = parse_ply(&ply_bytes(&mesh, e).unwrap(), "prop.ply").unwrap();
            prop_assert_eq!(b.positions(), positions.as_slice());
            prop_assert_eq!(b.triangles(), triangles.as_slice());
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(cases_or(64)))]

    /// Sparse float grids written by eikon's VDB writer (zipped or not)
    /// read back voxel for voxel.
    #[test]
    fn vdb_grids_read_back_as_written(
        voxels in prop::collection::vec(
            (prop::array::uniform3(-3000i32..3000), -1e6f32..1e6),
            1..200,
        ),
        background in -10.0f32..10.0,
        zip in any::<bool>(),
        voxel_size in 1e-3f64..10.0,
    ) {
        let mut tree = vdb::Tree::new(background);
        for (ijk, v) in &voxels {
            if *v != background {
                tree.set(*ijk, *v);
            }
        }
        prop_assume!(tree.active_voxel_count() > 0);
        let transform = vdb::Transform {
            voxel_size: DVec3::splat(voxel_size),
            translation: DVec3::new(0.5, -1.0, 2.0),
        };
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("prop.vdb");
        vdb::write_file(&path, &[vdb::Grid::float("g", tree.clone(), transform)], &vdb::WriteOptions { zip })
            .unwrap();
        let back = vdb::read_float_tree(&path, "g").unwrap();
        prop_assert_eq!(back.tree.background(), background);
        let mut want: Vec<_> = tree.active_voxels().collect();
        let mut got: Vec<_> = back.tree.active_voxels().collect();
        want.sort_by_key(|(ijk, _)| *ijk);
        got.sort_by_key(|(ijk, _)| *ijk);
        prop_assert_eq!(got, want);
    }

    /// Images written by eikon's EXR encoder read back as environment maps
    /// texel for texel (negative values read as 0).
    #[test]
    fn exr_maps_read_back_as_written(
        (w, h, texels) in (1usize..24, 1usize..24).prop_flat_map(|(w, h)| {
            (Just(w), Just(h), prop::collection::vec(prop::array::uniform3(-1.0f32..1e4), w * h))
        })
    ) {
        let mut image = eikon_optics::Image::new(w as u32, h as u32);
        image.data.clone_from(&texels);
        let bytes = eikon_optics::encode_exr(&image).unwrap();
        let map = eikon_optics::LatLongMap::from_exr_bytes(&bytes, std::path::Path::new("prop.exr")).unwrap();
        prop_assert_eq!((map.width(), map.height()), (w, h));
        let want: Vec<[f32; 3]> = texels.iter().map(|t| t.map(|c| c.max(0.0))).collect();
        prop_assert_eq!(map.data(), want.as_slice());
    }
}
