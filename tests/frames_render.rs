//! `--frames` on `render`, `run` and `export` (and `--gif`): frame files
//! and manifests, a frame equal to its static scene bit for bit, light
//! volumes per frame, and bad input refused before anything is written.

use std::path::Path;
mod binary;

use binary::{eikon, eikon_ok, expect_error};

/// A small scene, with the light's direction and the camera's position
/// filled in.
fn scene(direction: &str, camera: &str) -> String {
    format!(
        r#"
[grid]
resolution = 16
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
name = "ball"
shape = {{ type = "sphere", center = [0, 0.1, 0], radius = 0.5 }}
index = 1.5
extinction = [0.05, 0.05, 0.05]

[[light]]
type = "directional"
direction = {direction}
power = [1, 1, 1]

[receiver]
point = [0, -0.9, 0]
normal = [0, 1, 0]
albedo = [0.8, 0.8, 0.8]

[camera]
position = {camera}
target = [0, -0.25, 0]
fov = 45
resolution = [48, 36]
samples = 1
"#
    )
}

/// Five frames at 10 fps: the light turns and the camera slides, linearly
/// between keys at frames 0 and 4, so frame 2 is the exact midpoint
/// ([`frame_2`]).
fn animated() -> String {
    scene("[0.0, -1.0, 0.5]", "[0.5, 0.75, 2.9]")
        + r#"
[animation]
frames = 5
fps = 10

[[animation.track]]
field = "light[0].direction"
keys = [{ frame = 0, value = [0.0, -1.0, 0.5] }, { frame = 4, value = [1.0, -1.0, -0.5] }]

[[animation.track]]
field = "camera.position"
keys = [{ frame = 0, value = [0.5, 0.75, 2.9] }, { frame = 4, value = [-0.5, 0.75, 2.9] }]
"#
}

/// Frame 2 of [`animated`] written as a static scene.
fn frame_2() -> String {
    scene("[0.5, -1.0, 0.0]", "[0.0, 0.75, 2.9]")
}

fn write(dir: &Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p.to_str().unwrap().to_string()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn bytes(p: &Path) -> Vec<u8> {
    std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// The frames a manifest records done, with their files.
fn manifest_files(path: &Path) -> Vec<(u64, Vec<String>)> {
    let v: serde_json::Value = serde_json::from_slice(&bytes(path)).unwrap();
    v["done"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            let files = r["files"]
                .as_array()
                .unwrap()
                .iter()
                .map(|f| f["name"].as_str().unwrap().to_string())
                .collect();
            (r["frame"].as_u64().unwrap(), files)
        })
        .collect()
}

const CPU: [&str; 2] = ["--backend", "cpu"];

#[test]
fn run_frames_writes_volumes_images_manifest_and_gif() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write(dir.path(), "anim.toml", &animated());
    let out = dir.path().join("out");
    let gif = out.join("a.gif");
    let args = [
        &[
            "run",
            &scene,
            "--frames",
            "0..3",
            "-o",
            s(&out),
            "--gif",
            s(&gif),
        ][..],
        &CPU,
    ]
    .concat();
    let o = eikon_ok(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("medium reused"), "{err}");
    eikon_ok(&["status", s(&out)]);
    for f in 0..4 {
        for ext in ["exr", "png"] {
            assert!(out.join(format!("image_{f:04}.{ext}")).is_file());
        }
        assert!(out
            .join(format!("frame_{f:04}/light_volumes.json"))
            .is_file());
    }
    assert!(!out.join("image_0004.png").exists());
    // One manifest lists each frame's volumes, sidecar and images.
    let done = manifest_files(&out.join("manifest-run.json"));
    assert_eq!(done.len(), 4);
    for (f, files) in &done {
        let has = |n: String| files.contains(&n);
        assert!(has(format!("frame_{f:04}/light_volumes.json")), "{files:?}");
        assert!(files.iter().any(|n| n.ends_with(".npy")), "{files:?}");
        assert!(has(format!("image_{f:04}.exr")), "{files:?}");
        assert!(has(format!("image_{f:04}.png")), "{files:?}");
    }

    let check_gif = || {
        let mut options = gif::DecodeOptions::new();
        options.set_color_output(gif::ColorOutput::RGBA);
        let mut d = options
            .read_info(std::fs::File::open(&gif).unwrap())
            .unwrap();
        assert_eq!((d.width(), d.height()), (48, 36));
        let mut n = 0;
        while let Some(frame) = d.read_next_frame().unwrap() {
            assert_eq!((frame.width, frame.height), (48, 36));
            assert_eq!(frame.delay, 10, "10 fps: 10 hundredths of a second");
            n += 1;
        }
        assert_eq!(n, 4);
    };
    check_gif();

    // Run again: every frame is already done, and the GIF is made again
    // from the PNGs on disk.
    std::fs::remove_file(&gif).unwrap();
    let o = eikon_ok(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("4 already done"), "{err}");
    check_gif();
}

#[test]
fn a_frame_equals_its_static_scene_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let anim = write(dir.path(), "anim.toml", &animated());
    let still = write(dir.path(), "still.toml", &frame_2());
    // Frame 2 after frames 0 and 1, its medium reused from frame 0.
    let a = dir.path().join("a");
    eikon_ok(&[&["run", &anim, "--frames", "0..2", "-o", s(&a)][..], &CPU].concat());
    let b = dir.path().join("b");
    eikon_ok(&[&["run", &still, "-o", s(&b)][..], &CPU].concat());
    for ext in ["png", "exr"] {
        assert!(
            bytes(&a.join(format!("image_0002.{ext}"))) == bytes(&b.join(format!("image.{ext}"))),
            "{ext} of frame 2 differs from the static scene's"
        );
    }
    // render --frames with the run's light volumes (its frame folders).
    let c = dir.path().join("c");
    let (png, exr) = (c.join("img.png"), c.join("img.exr"));
    eikon_ok(
        &[
            &[
                "render",
                &anim,
                "--frames",
                "2",
                "--light",
                s(&a),
                "-o",
                s(&png),
                "-o",
                s(&exr),
            ][..],
            &CPU,
        ]
        .concat(),
    );
    assert!(bytes(&c.join("img_0002.png")) == bytes(&b.join("image.png")));
    assert!(bytes(&c.join("img_0002.exr")) == bytes(&b.join("image.exr")));
    assert!(!png.exists() && !exr.exists());
    let done = manifest_files(&c.join("manifest-render.json"));
    assert_eq!(
        done,
        vec![(
            2,
            vec!["img_0002.png".to_string(), "img_0002.exr".to_string()]
        )]
    );
}

#[test]
fn render_frames_takes_light_per_frame_and_names_a_missing_one() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write(dir.path(), "anim.toml", &animated());
    let lights = dir.path().join("lights");
    eikon_ok(
        &[
            &["simulate", &scene, "--frames", "all", "-o", s(&lights)][..],
            &CPU,
        ]
        .concat(),
    );
    // Rendered into the simulation's own folder: the two manifests side by
    // side, and status reports both.
    let gif = dir.path().join("anim.gif");
    eikon_ok(
        &[
            &[
                "render",
                &scene,
                "--frames",
                "0..4",
                "--light",
                s(&lights),
                "-o",
                s(&lights.join("view.png")),
                "--gif",
                s(&gif),
            ][..],
            &CPU,
        ]
        .concat(),
    );
    for f in 0..5 {
        assert!(lights.join(format!("view_{f:04}.png")).is_file());
    }
    assert!(lights.join("manifest-render.json").is_file());
    assert!(lights.join("manifest-simulate.json").is_file());
    let o = eikon_ok(&["status", s(&lights), "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let commands: Vec<&str> = v
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["command"].as_str().unwrap())
        .collect();
    assert_eq!(commands, ["render", "simulate"]);
    let d = gif::DecodeOptions::new()
        .read_info(std::fs::File::open(&gif).unwrap())
        .unwrap();
    assert_eq!((d.width(), d.height()), (48, 36));

    // Lit frames differ from one another (the light moves).
    assert!(bytes(&lights.join("view_0000.png")) != bytes(&lights.join("view_0004.png")));

    // Frame 1's light simulated again (a new run id): rendering the range
    // again renders that frame only.
    std::fs::remove_dir_all(lights.join("frame_0001")).unwrap();
    eikon_ok(
        &[
            &["simulate", &scene, "--frames", "1", "-o", s(&lights)][..],
            &CPU,
        ]
        .concat(),
    );
    let again = eikon_ok(
        &[
            &[
                "render",
                &scene,
                "--frames",
                "0..4",
                "--light",
                s(&lights),
                "-o",
                s(&lights.join("view.png")),
            ][..],
            &CPU,
        ]
        .concat(),
    );
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(
        err.contains("frame 1: ")
            && err.contains("1 frame(s) done")
            && err.contains("4 already done"),
        "{err}"
    );

    // A frame folder missing: named, and nothing is written.
    std::fs::remove_dir_all(lights.join("frame_0003")).unwrap();
    let r = dir.path().join("r");
    expect_error(
        &[
            &[
                "render",
                &scene,
                "--frames",
                "2..4",
                "--light",
                s(&lights),
                "-o",
                s(&r.join("x.png")),
            ][..],
            &CPU,
        ]
        .concat(),
        &["frame_0003", "frame 3"],
    );
    assert!(!r.exists());
    // Frames whose light is there still render.
    eikon_ok(
        &[
            &[
                "render",
                &scene,
                "--frames",
                "0..2",
                "--light",
                s(&lights),
                "-o",
                s(&r.join("x.png")),
            ][..],
            &CPU,
        ]
        .concat(),
    );
    assert!(r.join("x_0002.png").is_file());
}

#[test]
fn export_frames_writes_a_numbered_vdb_sequence() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write(dir.path(), "anim.toml", &animated());
    let lights = dir.path().join("lights");
    eikon_ok(
        &[
            &["simulate", &scene, "--frames", "1..2", "-o", s(&lights)][..],
            &CPU,
        ]
        .concat(),
    );
    let v = dir.path().join("v");
    eikon_ok(&[
        "export",
        &scene,
        "--frames",
        "1..2",
        "--light",
        s(&lights),
        "--vdb",
        s(&v.join("light.vdb")),
        "--npy",
        s(&v.join("arrays")),
    ]);
    for f in [1, 2] {
        let vdb = v.join(format!("light_{f:04}.vdb"));
        // OpenVDB's magic number, 0x56444220 little-endian.
        assert_eq!(&bytes(&vdb)[..4], b" BDV", "{}", vdb.display());
        let npy = v.join(format!("arrays/frame_{f:04}"));
        assert!(npy.join("volumes.json").is_file());
        assert!(npy.join("fluence.npy").is_file());
    }
    assert!(!v.join("light.vdb").exists() && !v.join("light_0000.vdb").exists());
    let done = manifest_files(&v.join("manifest-export.json"));
    assert_eq!(done.iter().map(|d| d.0).collect::<Vec<_>>(), [1, 2]);
    for (f, files) in &done {
        assert!(files.contains(&format!("light_{f:04}.vdb")), "{files:?}");
        assert!(
            files.contains(&format!("arrays/frame_{f:04}/volumes.json")),
            "{files:?}"
        );
        assert!(
            files.contains(&format!("arrays/frame_{f:04}/fluence.npy")),
            "{files:?}"
        );
    }
    eikon_ok(&["status", s(&v)]);
    // Light volumes for frame 0 were never simulated.
    let w = dir.path().join("w");
    expect_error(
        &[
            "export",
            &scene,
            "--frames",
            "0..2",
            "--light",
            s(&lights),
            "--vdb",
            s(&w.join("light.vdb")),
        ],
        &["frame_0000"],
    );
    assert!(!w.exists());
}

#[test]
fn bad_frame_input_is_refused_before_anything_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write(dir.path(), "anim.toml", &animated());
    let out = dir.path().join("out");
    let png = out.join("x.png");
    let gif = out.join("x.gif");
    let vdb = out.join("x.vdb");
    let exr = out.join("x.exr");
    let elsewhere = dir.path().join("elsewhere/x.exr");
    let cases: Vec<(Vec<&str>, &[&str])> = vec![
        (
            vec!["run", &scene, "--frames", "0..99", "-o", s(&out)],
            &["frame 99 does not exist", "5 frames"],
        ),
        (
            vec!["render", &scene, "--frames", "0..99", "-o", s(&png)],
            &["frame 99 does not exist"],
        ),
        (
            vec!["export", &scene, "--frames", "0..99", "--vdb", s(&vdb)],
            &["frame 99 does not exist"],
        ),
        (
            vec![
                "run",
                &scene,
                "--frames",
                "0..2",
                "-o",
                s(&out),
                "--gif",
                s(&png),
            ],
            &["--gif", ".gif"],
        ),
        (
            vec![
                "render",
                &scene,
                "--frames",
                "0..2",
                "-o",
                s(&exr),
                "--gif",
                s(&gif),
            ],
            &["--gif", ".png"],
        ),
        (
            vec![
                "render",
                &scene,
                "--frames",
                "0..2",
                "-o",
                s(&png),
                "-o",
                s(&elsewhere),
            ],
            &["one folder"],
        ),
        (
            vec![
                "render",
                &scene,
                "--frames",
                "0..2",
                "-o",
                s(&png),
                "--json",
            ],
            &["--json", "eikon status"],
        ),
        (
            vec![
                "render",
                &scene,
                "--frames",
                "0..2",
                "--method",
                "walter",
                "--light",
                s(dir.path()),
                "-o",
                s(&png),
            ],
            &["--light", "eikonal"],
        ),
    ];
    for (args, fragments) in &cases {
        expect_error(args, fragments);
        assert!(!out.exists(), "{args:?} wrote {}", out.display());
    }
    // --gif without --frames: clap's usage error.
    for args in [
        vec!["run", &scene, "-o", s(&out), "--gif", s(&gif)],
        vec!["render", &scene, "-o", s(&png), "--gif", s(&gif)],
    ] {
        let o = eikon(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(err.contains("--frames"), "{err}");
        assert!(!out.exists());
    }
}

#[test]
fn exact_methods_take_frames_too() {
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("configs/cuboctahedron.toml")).unwrap()
        + r#"
[animation]
frames = 3
fps = 6

[[animation.track]]
field = "camera.fov"
keys = [{ frame = 0, value = 40.0 }, { frame = 2, value = 30.0 }]
"#;
    let scene = write(dir.path(), "cub.toml", &text);
    let w = dir.path().join("w");
    let gif = w.join("c.gif");
    eikon_ok(&[
        "render",
        &scene,
        "--method",
        "walter",
        "--frames",
        "all",
        "--width",
        "32",
        "--height",
        "24",
        "-o",
        s(&w.join("c.png")),
        "--gif",
        s(&gif),
    ]);
    for f in 0..3 {
        assert!(w.join(format!("c_{f:04}.png")).is_file());
    }
    assert!(bytes(&w.join("c_0000.png")) != bytes(&w.join("c_0002.png")));
    let mut d = gif::DecodeOptions::new()
        .read_info(std::fs::File::open(&gif).unwrap())
        .unwrap();
    let mut n = 0;
    while let Some(frame) = d.read_next_frame().unwrap() {
        assert_eq!(frame.delay, 17, "6 fps: 100/6 rounded");
        n += 1;
    }
    assert_eq!(n, 3);
}
