//! End to end: `eikon render --method`, `eikon compare`, `--backend` and
//! `eikon bench` on small scenes. The GPU runs need a Vulkan adapter; CI
//! has Mesa's lavapipe and sets `CI`, and there they must not be skipped.

use std::path::Path;
mod binary;

use binary::{eikon, eikon_ok, expect_error};

/// A small amber bumpy sphere lit from behind (configs/bumpy-amber.toml
/// in miniature).
const AMBER: &str = r#"
[grid]
resolution = 32
min = [-0.8, -0.8, -0.8]
max = [0.8, 0.8, 0.8]

[[object]]
shape = { type = "bumpy_sphere", center = [0.0, 0.0, 0.0], radius = 0.55, amplitude = 0.15, bumps = 12, seed = 3, frequency = 6 }
index = 1.55
extinction = [1.2, 2.2, 4.5]
albedo = [0.9, 0.75, 0.5]
g = 0.3

[[light]]
type = "point"
position = [0.4, 0.6, -2.5]
power = [60.0, 60.0, 60.0]

[camera]
position = [0.0, 0.0, 3.0]
target = [0.0, 0.0, 0.0]
fov = 26
resolution = [16, 16]

[background]
type = "constant"
color = [0.0, 0.0, 0.0]
"#;

/// An absorbing glass ball in a 16^3 grid under a directional light: the
/// scene of the tests that run the GPU light simulation through the CLI,
/// small enough for lavapipe's kernels in CI.
const BALL: &str = r#"
[grid]
resolution = 16
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
name = "ball"
shape = { type = "sphere", center = [0.0, 0.0, 0.0], radius = 0.6 }
index = 1.5
extinction = [0.2, 0.1, 0.1]

[[light]]
type = "directional"
direction = [-0.15, -0.2, 1.0]
power = [1, 1, 1]

[camera]
position = [0.0, 0.0, 3.0]
target = [0.0, 0.0, 0.0]
fov = 26
resolution = [16, 16]
"#;

fn write(dir: &Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p.to_str().unwrap().to_string()
}

/// Whether the GPU backend can run: built with the `gpu` feature, and an
/// adapter found (with `CI` set, a missing adapter fails instead).
fn has_gpu() -> bool {
    #[cfg(feature = "gpu")]
    return eikon_gpu::test_device().is_some();
    #[cfg(not(feature = "gpu"))]
    false
}

#[test]
fn compare_renders_every_method_and_measures_them_against_the_reference() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write(dir.path(), "amber.toml", AMBER);
    let out = dir.path().join("cmp");
    let o = eikon_ok(&[
        "compare",
        &scene,
        "-o",
        out.to_str().unwrap(),
        "--backend",
        "cpu",
        "--json",
    ]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let rows = v["methods"].as_array().unwrap();
    let names: Vec<&str> = rows.iter().map(|r| r["method"].as_str().unwrap()).collect();
    assert_eq!(names, ["eikonal", "walter", "holzschuch", "straight"]);
    let l1 = |m: &str| {
        rows.iter().find(|r| r["method"] == m).unwrap()["relative_l1"]
            .as_f64()
            .unwrap()
    };
    println!(
        "relative L1 against holzschuch: eikonal {:.3}, walter {:.4}, straight {:.3}",
        l1("eikonal"),
        l1("walter"),
        l1("straight")
    );
    assert_eq!(l1("holzschuch"), 0.0);
    // The two exact methods agree; ignoring refraction on the light side
    // does not.
    assert!(l1("walter") < 0.1, "{}", l1("walter"));
    assert!(l1("straight") > 3.0 * l1("walter"));
    for f in [
        "contact.png",
        "compare.json",
        "eikonal.exr",
        "walter.png",
        "holzschuch.exr",
        "straight.png",
        "light/light_volumes.json",
    ] {
        assert!(out.join(f).is_file(), "{f}");
    }
    // The contact sheet holds the four 16-pixel images and 3 gaps of 4,
    // under an 11-pixel strip with their labels.
    let decoder = png::Decoder::new(std::fs::File::open(out.join("contact.png")).unwrap());
    let info = decoder.read_info().unwrap().info().clone();
    assert_eq!((info.width, info.height), (4 * 16 + 3 * 4, 16 + 11));
}

#[test]
fn exact_methods_refuse_scenes_they_cannot_render() {
    let dir = tempfile::tempdir().unwrap();
    let sphere = AMBER.replace(
        "{ type = \"bumpy_sphere\", center = [0.0, 0.0, 0.0], radius = 0.55, amplitude = 0.15, bumps = 12, seed = 3, frequency = 6 }",
        "{ type = \"sphere\", center = [0.0, 0.0, 0.0], radius = 0.55 }",
    );
    let s = write(dir.path(), "sphere.toml", &sphere);
    let png = dir.path().join("x.png");
    let png = png.to_str().unwrap();
    expect_error(
        &["render", &s, "--method", "walter", "-o", png],
        &["sphere.toml", "object", "mesh"],
    );
    let spot = AMBER.replace(
        "type = \"point\"",
        "type = \"spot\"\ndirection = [0.0, 0.0, 1.0]\nangle = 20.0",
    );
    let s = write(dir.path(), "spot.toml", &spot);
    expect_error(
        &["render", &s, "--method", "holzschuch", "-o", png],
        &["spot.toml", "light[0].type", "spot"],
    );
    let disp = AMBER.replace("index = 1.55", "index = [1.54, 1.55, 1.57]");
    let s = write(dir.path(), "disp.toml", &disp);
    expect_error(
        &["render", &s, "--method", "straight", "-o", png],
        &["disp.toml", "object[0].index", "dispersion"],
    );
    let s = write(dir.path(), "amber.toml", AMBER);
    expect_error(
        &[
            "compare",
            &s,
            "-o",
            dir.path().join("c").to_str().unwrap(),
            "--methods",
            "walter",
            "--reference",
            "holzschuch",
        ],
        &["--reference", "holzschuch"],
    );
    assert!(!png_exists(dir.path()));
}

fn png_exists(dir: &Path) -> bool {
    dir.join("x.png").exists()
}

#[test]
fn the_backend_is_said_and_the_gpu_simulation_agrees_with_the_cpu() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write(dir.path(), "ball.toml", BALL);
    let run = |backend: &str| {
        let out = dir.path().join(backend);
        let o = eikon(&[
            "simulate",
            &scene,
            "-o",
            out.to_str().unwrap(),
            "--backend",
            backend,
            "--json",
        ]);
        (o, out)
    };
    let (cpu, _) = run("cpu");
    assert!(cpu.status.success());
    let v: serde_json::Value = serde_json::from_slice(&cpu.stdout).unwrap();
    assert!(v["backend"].as_str().unwrap().starts_with("cpu"));
    if !has_gpu() {
        return;
    }
    let (gpu, _) = run("gpu");
    assert!(
        gpu.status.success(),
        "{}",
        String::from_utf8_lossy(&gpu.stderr)
    );
    let w: serde_json::Value = serde_json::from_slice(&gpu.stdout).unwrap();
    assert!(w["backend"].as_str().unwrap().starts_with("gpu"));
    // Same physics: the power accounted for agrees to well under 1%.
    for k in ["entered", "absorbed", "exited"] {
        for c in 0..3 {
            let a = v["lights"][0]["energy_w"][k][c].as_f64().unwrap();
            let b = w["lights"][0]["energy_w"][k][c].as_f64().unwrap();
            assert!(
                (a - b).abs() <= 5e-3 * a.abs().max(1e-9),
                "{k}[{c}]: cpu {a}, gpu {b}"
            );
        }
    }
    // Without the flag the choice is said on stderr.
    let o = eikon(&[
        "simulate",
        &scene,
        "-o",
        dir.path().join("auto").to_str().unwrap(),
    ]);
    assert!(o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("backend: "), "{err}");
}

#[test]
fn bench_prints_a_row_per_scene_and_backend() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write(dir.path(), "tiny.toml", BALL);
    let backends = if has_gpu() { "cpu,gpu" } else { "cpu" };
    let o = eikon_ok(&[
        "bench",
        "--scene",
        &scene,
        "--backends",
        backends,
        "--runs",
        "1",
        "--frames",
        "1",
        "--json",
    ]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let rows = v["runs"].as_array().unwrap();
    assert_eq!(rows.len(), backends.split(',').count());
    for r in rows {
        println!("{r}");
        assert!(r["simulate_seconds"].as_f64().unwrap() > 0.0);
        assert!(r["frame_seconds"].as_f64().unwrap() > 0.0);
        assert_eq!(r["dims"], serde_json::json!([16, 16, 16]));
        // The GPU's round trips per simulation are counted; the CPU has none.
        if r["backend"] == "gpu" {
            let submits = r["simulate_submissions"].as_u64().unwrap();
            let reads = r["simulate_readbacks"].as_u64().unwrap();
            assert!(submits > 0 && reads > 0 && reads <= submits, "{r}");
        } else {
            assert!(r["simulate_submissions"].is_null(), "{r}");
        }
    }
}

/// On a software or integrated adapter (lavapipe in CI) the GPU's buffers
/// are host memory: the memory check lists them beside the host's arrays,
/// for the simulator and the renderer.
#[cfg(feature = "gpu")]
#[test]
fn gpu_buffers_are_in_the_memory_check() {
    if !has_gpu() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let scene = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("configs/glass-sphere.toml")
        .to_str()
        .unwrap()
        .to_string();
    let out = dir.path().join("out");
    let small = ["--resolution", "16", "--backend", "gpu"];
    let o = eikon(
        &[
            &["simulate", &scene, "-o", out.to_str().unwrap()][..],
            &small,
            &["--max-patches", "100000", "--max-memory", "8M"],
        ]
        .concat(),
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("GPU buffers") && err.contains("patch list"),
        "{err}"
    );
    let png = dir.path().join("big.png");
    let o = eikon(
        &[
            &["render", &scene, "-o", png.to_str().unwrap()][..],
            &small,
            &[
                "--width",
                "3000",
                "--height",
                "3000",
                "--max-memory",
                "200M",
            ],
        ]
        .concat(),
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("GPU buffers") && err.contains("image"),
        "{err}"
    );
    assert!(!png.exists());
}

/// Built without the `gpu` feature, `--backend gpu` is refused with a
/// message that says how to get it, and the default runs on the CPU.
#[cfg(not(feature = "gpu"))]
#[test]
fn without_the_gpu_feature_the_gpu_backend_is_refused_and_the_default_is_the_cpu() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write(dir.path(), "amber.toml", AMBER);
    let out = dir.path().join("gpu");
    let args = ["simulate", &scene, "-o", out.to_str().unwrap()];
    binary::expect_error_after_notes(
        &[&args[..], &["--backend", "gpu"]].concat(),
        &[
            "built without the `gpu` feature",
            "rebuild with default features",
        ],
    );
    assert!(!out.exists());
    let auto = dir.path().join("auto");
    let o = eikon_ok(&["simulate", &scene, "-o", auto.to_str().unwrap(), "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["backend"].as_str().unwrap().starts_with("cpu"));
}

/// The `gpu` feature gates every GPU dependency: the CPU-only build's tree
/// (`--no-default-features`) has no wgpu, the default one has.
#[test]
fn the_cpu_only_dependency_tree_has_no_wgpu() {
    let tree = |features: &[&str]| {
        let o = std::process::Command::new(env!("CARGO"))
            .args(["tree", "--offline", "-e", "normal", "-p", "eikon"])
            .args(["--prefix", "none"])
            .args(features)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .expect("running cargo tree");
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let text = String::from_utf8(o.stdout).unwrap();
        assert!(
            text.lines().any(|l| l.starts_with("eikon-wavefront")),
            "{text}"
        );
        text.lines()
            .filter(|l| l.starts_with("wgpu") || l.starts_with("eikon-gpu"))
            .map(str::to_string)
            .collect::<Vec<_>>()
    };
    let cpu = tree(&["--no-default-features"]);
    assert!(cpu.is_empty(), "the CPU-only build compiles {cpu:?}");
    assert!(!tree(&[]).is_empty(), "the default build has no wgpu");
}
