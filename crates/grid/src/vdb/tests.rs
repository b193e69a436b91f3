use super::*;
use std::path::Path;

/// A file path of its own in a temporary directory, removed with the
/// returned guard.
fn temp(name: &str) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::Builder::new()
        .prefix("eikon-vdb-")
        .tempdir()
        .unwrap();
    let path = dir.path().join(name);
    (dir, path)
}

fn unit() -> Transform {
    Transform {
        voxel_size: DVec3::splat(0.5),
        translation: DVec3::new(1.0, -2.0, 0.25),
    }
}

fn write_file(path: &Path, grids: &[Grid], options: &WriteOptions) -> WriteReport {
    let report = super::write_file(path, grids, options).unwrap();
    assert_eq!(report.bytes, std::fs::metadata(path).unwrap().len());
    report
}

/// A deterministic pseudo-random value in [0, 1): the top 24 bits of the
/// SplitMix64 hash of `i`.
fn rnd(i: u64) -> f32 {
    (eikon_rng::mix(i.wrapping_add(eikon_rng::GOLDEN)) >> 40) as f32 / (1u64 << 24) as f32
}

/// Voxels scattered over several root nodes (32^3 nodes span 4096 voxels),
/// negative coordinates included, with a full uniform leaf (a tile).
fn scattered() -> Tree<f32> {
    let mut t = Tree::new(-0.5);
    let centres = [
        [0, 0, 0],
        [-5000, 3, 7],
        [4100, -4097, 9000],
        [-1, -1, -1],
        [100, 200, -300],
    ];
    let mut n = 0;
    for c in centres {
        for d in 0..40 {
            let ijk = [c[0] + d * 3 - 50, c[1] + (d * 7) % 19 - 9, c[2] + d % 5];
            t.set(ijk, rnd(n) * 10.0 - 5.0);
            n += 1;
        }
    }
    for x in 16..24 {
        for y in -8..0 {
            for z in 40..48 {
                t.set([x, y, z], 2.5);
            }
        }
    }
    t
}

#[test]
fn float_grids_round_trip_through_vdb_rs_exactly() {
    let tree = scattered();
    let roots: std::collections::BTreeSet<[i32; 3]> = tree
        .active_voxels()
        .map(|(c, _)| c.map(|x| x & !4095))
        .collect();
    assert!(roots.len() >= 4, "{roots:?}");
    for zip in [false, true] {
        let (_dir, path) = temp("scattered.vdb");
        let mut g = Grid::float("scattered", tree.clone(), unit());
        g.class = GridClass::FogVolume;
        let report = write_file(&path, &[g], &WriteOptions { zip });
        assert_eq!(report.grids[0].active_voxels, tree.active_voxel_count());
        assert!(report.grids[0].tiles >= 1, "{report:?}");
        let g = read_float_tree(&path, "scattered").unwrap();
        assert_eq!(g.tree.active_voxel_count(), tree.active_voxel_count());
        assert_eq!(g.tree.background(), -0.5);
        assert_eq!(g.transform, unit());
        let mut checked = 0;
        for (ijk, value) in tree.active_voxels() {
            assert_eq!(g.tree.get(ijk), Some(value), "{ijk:?}");
            checked += 1;
        }
        assert_eq!(checked, tree.active_voxel_count());
        assert_eq!(g.tree.get([5, 5, 5]), None);
        // Too sparse to hold densely for sampling: refused, not truncated.
        let e = read_float_grid(&path, "scattered").unwrap_err().to_string();
        assert!(e.contains("import is limited to"), "{e}");
    }
}

#[test]
fn uniform_regions_become_tiles_and_read_back() {
    // 160^3 of one value: whole 16^3 nodes (128^3) become tiles of the
    // 32^3 node, the rest 8^3 tiles of 16^3 nodes.
    let tree = Tree::from_dense([160, 136, 130], [-8, 0, -2], 0.0, |_| 1.25f32);
    let (_dir, path) = temp("uniform.vdb");
    let report = write_file(
        &path,
        &[Grid::float("u", tree.clone(), unit())],
        &WriteOptions::default(),
    );
    let r = &report.grids[0];
    assert_eq!(r.active_voxels, 160 * 136 * 130);
    assert!(r.tiles > 0);
    // Partial leaves remain leaves: far fewer than the 8^3 blocks.
    assert!(r.leaves < tree.leaf_count() as u64 / 2, "{r:?}");
    assert!(r.bytes < 200_000, "{r:?}");
    let v = read_float_grid(&path, "u").unwrap();
    assert_eq!(v.active_voxels, 160 * 136 * 130);
    for ijk in [
        [-8, 0, -2],
        [151, 135, 127],
        [0, 0, 0],
        [-9, 0, 0],
        [152, 0, 0],
    ] {
        assert_eq!(v.value(ijk), tree.get(ijk).unwrap_or(0.0), "{ijk:?}");
    }
}

#[test]
fn from_dense_keeps_only_values_other_than_the_background() {
    let dims = [19, 9, 13];
    let f = |[i, j, k]: [usize; 3]| {
        if (i + j + k) % 3 == 0 {
            1.0f32
        } else {
            i as f32
        }
    };
    let t = Tree::from_dense(dims, [-3, 4, -7], 1.0, f);
    let mut expect = 0;
    for i in 0..dims[0] {
        for j in 0..dims[1] {
            for k in 0..dims[2] {
                let v = f([i, j, k]);
                let ijk = [i as i32 - 3, j as i32 + 4, k as i32 - 7];
                if v != 1.0 {
                    expect += 1;
                    assert_eq!(t.get(ijk), Some(v));
                } else {
                    assert_eq!(t.get(ijk), None);
                }
            }
        }
    }
    assert_eq!(t.active_voxel_count(), expect);
}

#[test]
fn half_floats_round_to_half_precision() {
    let mut t = Tree::new(0.0f32);
    t.set([1, 2, 3], 0.1);
    t.set([-1, 2, 3], 1.0 / 3.0);
    let (_dir, path) = temp("half.vdb");
    let mut g = Grid::float("h", t, unit());
    g.half = true;
    write_file(&path, &[g], &WriteOptions { zip: false });
    let v = read_float_grid(&path, "h").unwrap();
    assert!(v.half);
    assert_eq!(v.value([1, 2, 3]), half::f16::from_f32(0.1).to_f32());
    assert_eq!(v.value([-1, 2, 3]), half::f16::from_f32(1.0 / 3.0).to_f32());
    // vdb-rs misreads zipped half floats: refused with a clear error.
    let mut g = Grid::float(
        "h",
        Tree::from_dense([4, 4, 4], [0; 3], 0.0, |_| 2.0f32),
        unit(),
    );
    g.half = true;
    write_file(&path, &[g], &WriteOptions { zip: true });
    let e = read_float_grid(&path, "h").unwrap_err().to_string();
    assert!(
        e.contains("half-float") && e.contains("--uncompressed"),
        "{e}"
    );
}

fn sample_file(zip: bool) -> (tempfile::TempDir, PathBuf, Vec<u8>) {
    let mut v = Tree::new([0.0f32; 3]);
    v.set([0, 1, 2], [1.0, 2.0, 3.0]);
    let mut f = Tree::new(0.0f32);
    for i in 0..30 {
        f.set([i - 10, i % 4, -i], i as f32 * 0.25);
    }
    let grids = [
        Grid::float("density", f, unit()),
        Grid::vec3("v", v, VectorType::Covariant, unit()),
    ];
    let (dir, path) = temp("sample.vdb");
    write_file(&path, &grids, &WriteOptions { zip });
    let bytes = std::fs::read(&path).unwrap();
    (dir, path, bytes)
}

#[test]
fn several_grids_per_file_with_their_metadata() {
    let (_dir, path, _) = sample_file(true);
    let info = inspect(&path).unwrap();
    assert_eq!(info.file_version, 224);
    let names: Vec<&str> = info.grids.iter().map(|g| g.name.as_str()).collect();
    assert_eq!(names, ["density", "v"]);
    let v = &info.grids[1];
    assert_eq!(v.grid_type, "Tree_vec3s_5_4_3");
    let m = &v.metadata;
    assert_eq!(m["vector_type"], MetaValue::String("covariant".into()));
    assert_eq!(m["class"], MetaValue::String("unknown".into()));
    assert_eq!(m["name"], MetaValue::String("v".into()));
    assert_eq!(m["file_voxel_count"], MetaValue::I64(1));
    assert_eq!(m["file_bbox_min"], MetaValue::Vec3i([0, 1, 2]));
    assert_eq!(m["file_bbox_max"], MetaValue::Vec3i([0, 1, 2]));
    assert_eq!(m["is_saved_as_half_float"], MetaValue::Bool(false));
    let d = &info.grids[0].metadata;
    assert_eq!(d["file_bbox_min"], MetaValue::Vec3i([-10, 0, -29]));
    assert_eq!(d["file_bbox_max"], MetaValue::Vec3i([19, 3, 0]));
    assert!(!d.contains_key("vector_type"));
    // The float grid still reads after the vec3s one.
    assert_eq!(
        read_float_grid(&path, "density")
            .unwrap()
            .value([9, 3, -19]),
        4.75
    );
}

#[test]
fn bad_grids_are_refused_and_failed_writes_leave_nothing() {
    let t = Tree::new(0.0f32);
    let two = [
        Grid::float("a", t.clone(), unit()),
        Grid::float("a", t.clone(), unit()),
    ];
    let e = write(&mut Vec::new(), &two, &WriteOptions::default()).unwrap_err();
    assert!(e.to_string().contains("two grids are named `a`"), "{e}");
    let mut flat = unit();
    flat.voxel_size.y = 0.0;
    let e = write(
        &mut Vec::new(),
        &[Grid::float("a", t.clone(), flat)],
        &WriteOptions::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("voxel size"), "{e}");
    // The target is a directory: the rename fails, no temporary remains.
    let (_dir, parent) = temp("own-dir");
    let dir = parent.join("dir.vdb");
    std::fs::create_dir_all(&dir).unwrap();
    let e = super::write_file(
        &dir,
        &[Grid::float("a", t, unit())],
        &WriteOptions::default(),
    );
    assert!(e.is_err());
    let left = std::fs::read_dir(&parent)
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .ends_with(".tmp")
        })
        .count();
    assert_eq!(left, 0);
}

#[test]
fn the_same_grids_give_the_same_bytes() {
    let (_, _, a) = sample_file(true);
    let (_, _, b) = sample_file(true);
    assert_eq!(a, b);
}

#[test]
fn bad_files_get_clear_errors() {
    let (_dir, path, bytes) = sample_file(true);
    let e = read_float_grid(&path, "v").unwrap_err().to_string();
    assert!(
        e.contains("`v` is a vec3s grid") && e.contains("only float grids"),
        "{e}"
    );
    let e = read_float_grid(&path, "densty").unwrap_err().to_string();
    assert!(
        e.contains("no grid named `densty`") && e.contains("density, v"),
        "{e}"
    );
    let e = read_float_grid(Path::new("/nonexistent/x.vdb"), "d")
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("/nonexistent/x.vdb: "), "{e}");

    let (_dir, cut) = temp("cut.vdb");
    std::fs::write(&cut, &bytes[..bytes.len() - 10]).unwrap();
    let e = read_float_grid(&cut, "density").unwrap_err().to_string();
    assert!(e.contains("truncated"), "{e}");
    std::fs::write(&cut, b"not a vdb file at all").unwrap();
    let e = read_float_grid(&cut, "density").unwrap_err().to_string();
    assert!(e.contains("bad magic number"), "{e}");
}

#[test]
fn every_truncation_and_corruption_is_an_error_not_a_panic() {
    for zip in [false, true] {
        // One 32^3 node with leaves, tiles and a vec3s grid after it.
        let mut f = Tree::from_dense([8, 8, 8], [8, 0, 0], 0.0, |_| 3.0f32);
        for i in 0..40 {
            f.set([i - 20, (i * 7) % 13, i % 3 - 1], i as f32 * 0.5 + 0.25);
        }
        let mut v = Tree::new([0.0f32; 3]);
        v.set([0, 1, 2], [1.0, 2.0, 3.0]);
        let grids = [
            Grid::float("density", f, unit()),
            Grid::vec3("v", v, VectorType::Invariant, unit()),
        ];
        let (_dir, path) = temp("broken.vdb");
        let mut bytes = Vec::new();
        write(&mut bytes, &grids, &WriteOptions { zip }).unwrap();
        // Every byte of the header, descriptors, metadata, transform and
        // root; every 11th byte of the node masks and values after that.
        let positions: Vec<usize> = (0..bytes.len())
            .filter(|&p| p < 700 || p % 11 == 0)
            .collect();
        for &len in &positions {
            std::fs::write(&path, &bytes[..len]).unwrap();
            let r = std::panic::catch_unwind(|| read_float_grid(&path, "density"));
            assert!(matches!(r, Ok(Err(_))), "cut at {len}: {r:?}");
        }
        // Flip one byte at a time: never a panic (some flips only change a
        // value and still read).
        let mut rejected = 0;
        for &at in &positions {
            let mut b = bytes.clone();
            b[at] ^= 0xA5;
            std::fs::write(&path, &b).unwrap();
            let r = std::panic::catch_unwind(|| read_float_grid(&path, "density"));
            match r {
                Ok(Err(_)) => rejected += 1,
                Ok(Ok(_)) => {}
                Err(_) => panic!("byte {at} flipped: panic"),
            }
        }
        assert!(
            rejected > positions.len() / 4,
            "{rejected} of {}",
            positions.len()
        );
    }
}

/// The header, metadata and descriptor of a file with one float grid whose
/// tree is `tree` (topology then buffers), written by hand.
fn handmade(tree: &[u8], map: &str) -> Vec<u8> {
    let s = |out: &mut Vec<u8>, t: &str| {
        out.extend_from_slice(&(t.len() as u32).to_le_bytes());
        out.extend_from_slice(t.as_bytes());
    };
    let mut body = Vec::new();
    body.extend_from_slice(&2u32.to_le_bytes()); // active mask
    body.extend_from_slice(&0u32.to_le_bytes()); // no metadata
    s(&mut body, map);
    for v in [1.0f64; 18] {
        body.extend_from_slice(&v.to_le_bytes());
    }
    body.extend_from_slice(tree);
    let mut out = Vec::new();
    out.extend_from_slice(&0x5644_4220i64.to_le_bytes());
    out.extend_from_slice(&224u32.to_le_bytes());
    out.extend_from_slice(&10u32.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.push(1);
    out.extend_from_slice(&[b'0'; 36]);
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&1u32.to_le_bytes());
    s(&mut out, "g");
    s(&mut out, "Tree_float_5_4_3");
    s(&mut out, "");
    let grid_pos = out.len() as i64 + 24;
    let end = grid_pos + body.len() as i64;
    for p in [grid_pos, end, end] {
        out.extend_from_slice(&p.to_le_bytes());
    }
    out.extend_from_slice(&body);
    out
}

#[test]
fn what_vdb_rs_cannot_read_is_refused_by_name() {
    // A root-level tile (vdb-rs drops them).
    let mut tree = Vec::new();
    tree.extend_from_slice(&1u32.to_le_bytes());
    tree.extend_from_slice(&0f32.to_le_bytes());
    tree.extend_from_slice(&1u32.to_le_bytes()); // one tile
    tree.extend_from_slice(&0u32.to_le_bytes()); // no children
    for c in [0i32, 4096, 0] {
        tree.extend_from_slice(&c.to_le_bytes());
    }
    tree.extend_from_slice(&3f32.to_le_bytes());
    tree.push(1);
    let (_dir, path) = temp("tile.vdb");
    std::fs::write(&path, handmade(&tree, "ScaleTranslateMap")).unwrap();
    let e = read_float_grid(&path, "g").unwrap_err().to_string();
    assert!(e.contains("root-level tile at [0, 4096, 0]"), "{e}");
    // Transforms vdb-rs would panic on.
    std::fs::write(&path, handmade(&tree, "AffineMap")).unwrap();
    let e = read_float_grid(&path, "g").unwrap_err().to_string();
    assert!(e.contains("transform `AffineMap` is not supported"), "{e}");
}

#[test]
fn transform_puts_vdb_voxels_on_eikon_cells() {
    let g = GridGeometry::new(
        [10, 20, 5],
        DVec3::new(-1.0, 0.0, 2.0),
        DVec3::new(1.0, 2.0, 3.0),
    );
    let t = Transform::for_grid(&g);
    for ijk in [[0, 0, 0], [9, 19, 4], [3, 7, 1]] {
        let c = g.voxel_center(ijk[0], ijk[1], ijk[2]);
        let w = t.index_to_world(DVec3::new(ijk[0] as f64, ijk[1] as f64, ijk[2] as f64));
        assert!((c - w).length() < 1e-12);
        assert!(
            (t.world_to_index(c) - DVec3::new(ijk[0] as f64, ijk[1] as f64, ijk[2] as f64))
                .length()
                < 1e-12
        );
    }
    assert!(!t.is_uniform());
}

#[test]
fn a_grid_as_a_solid_has_a_conservative_distance_bound() {
    // A ball of radius 6 voxels as a density grid.
    let h = 0.1;
    let tree = Tree::from_dense([24, 24, 24], [-12; 3], 0.0, |[i, j, k]| {
        let p = DVec3::new(i as f64 - 12.0, j as f64 - 12.0, k as f64 - 12.0);
        (6.0 - p.length()).clamp(-1.0, 1.0).max(0.0) as f32
    });
    let transform = Transform {
        voxel_size: DVec3::splat(h),
        translation: DVec3::new(0.3, 0.0, -0.2),
    };
    let (_dir, path) = temp("ball.vdb");
    write_file(
        &path,
        &[Grid::float("density", tree, transform)],
        &WriteOptions::default(),
    );
    let volume = std::sync::Arc::new(read_float_grid(&path, "density").unwrap());
    let solid = VdbSolid::new(volume, 0.5);
    assert!(solid.contains(transform.translation));
    let (lo, hi) = solid.aabb().unwrap();
    let c = transform.translation;
    assert!(
        (lo - c).max_element() < -0.55 && (hi - c).min_element() > 0.55,
        "{lo} {hi}"
    );
    assert!(
        (lo - c).min_element() > -0.8 && (hi - c).max_element() < 0.8,
        "{lo} {hi}"
    );
    // Check |distance| against brute force over a dense set of surface points.
    let surface: Vec<DVec3> = (0..40_000)
        .filter_map(|n| {
            let p = transform.translation
                + (DVec3::new(
                    rnd(3 * n) as f64,
                    rnd(3 * n + 1) as f64,
                    rnd(3 * n + 2) as f64,
                ) * 2.0
                    - 1.0)
                    * 0.8;
            let v = solid.volume().sample(p) - 0.5;
            (v.abs() < 0.01).then_some(p)
        })
        .collect();
    assert!(surface.len() > 50);
    for n in 0..400 {
        let p = transform.translation
            + (DVec3::new(
                rnd(7 * n) as f64,
                rnd(7 * n + 1) as f64,
                rnd(7 * n + 2) as f64,
            ) * 2.0
                - 1.0)
                * 2.0;
        let d = solid.distance(p);
        assert_eq!(d < 0.0, solid.contains(p), "{p}");
        let nearest = surface
            .iter()
            .map(|s| (*s - p).length())
            .fold(f64::INFINITY, f64::min);
        assert!(d.abs() <= nearest + 0.02, "{p}: bound {d} vs {nearest}");
    }
    // Far away the bound is large (few cells are supersampled).
    assert!(solid.distance(transform.translation + DVec3::splat(3.0)) > 2.0);
}
