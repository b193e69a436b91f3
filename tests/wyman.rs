//! End to end: `eikon render --method wyman` and the `wyman` row of
//! `eikon compare` (Wyman's image-space refraction and caustic maps on the
//! GPU's render pipelines). The renders need a Vulkan, Metal or DX12
//! adapter: without one they are reported as ignored, and under `CI` (which
//! has Mesa's lavapipe) they fail. Built with the `gpu` feature only
//! (`required-features`).

use eikon_gpu::Gpu;
use eikon_testkit::Tests;
use std::path::Path;
mod binary;

use binary::{eikon_ok, expect_error};

/// The glass sphere over a table (configs/glass-sphere.toml in miniature).
const SPHERE: &str = r#"
[grid]
resolution = 16
min = [-1.0, -1.0, -1.0]
max = [1.0, 1.0, 1.0]

[[object]]
shape = { type = "sphere", center = [0.0, 0.15, 0.0], radius = 0.45 }
index = 1.5
extinction = [0.05, 0.03, 0.03]

[[light]]
type = "directional"
direction = [0.2, -1.0, 0.1]
power = [1.0, 1.0, 1.0]

[receiver]
point = [0.0, -0.9, 0.0]
normal = [0.0, 1.0, 0.0]
albedo = [0.8, 0.8, 0.8]

[camera]
position = [0.5, 0.75, 2.9]
target = [0.1, -0.3, 0.0]
fov = 45
resolution = [40, 30]
samples = 2
"#;

fn write(dir: &Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p.to_str().unwrap().to_string()
}

fn render_method_wyman_writes_the_image_and_says_what_it_did(_: &Gpu) {
    let dir = tempfile::tempdir().unwrap();
    let scene = write(dir.path(), "sphere.toml", SPHERE);
    let png = dir.path().join("w.png");
    let exr = dir.path().join("w.exr");
    let o = eikon_ok(&[
        "render",
        &scene,
        "--method",
        "wyman",
        "--photons",
        "64",
        "--caustic-map",
        "64",
        "-o",
        png.to_str().unwrap(),
        "-o",
        exr.to_str().unwrap(),
        "--json",
    ]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["method"], "wyman");
    assert_eq!(
        (v["width"].as_u64(), v["height"].as_u64()),
        (Some(40), Some(30))
    );
    // Two samples of three eye passes, one light of four.
    assert_eq!(v["passes"].as_u64(), Some(10));
    assert_eq!(v["caustic_lights"].as_u64(), Some(1));
    assert!(v["covered"].as_u64().unwrap() > 0);
    assert!(png.is_file() && exr.is_file());
}

fn compare_has_a_wyman_row(_: &Gpu) {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/glass-bumpy.toml"),
    )
    .unwrap()
    .replace("resolution = [400, 400]", "resolution = [32, 32]")
    .replace("seed = 3 }", "seed = 3, frequency = 8 }");
    let scene = write(dir.path(), "glass.toml", &text);
    let out = dir.path().join("cmp");
    let o = eikon_ok(&[
        "compare",
        &scene,
        "-o",
        out.to_str().unwrap(),
        "--methods",
        "holzschuch,wyman",
        "--json",
    ]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let rows = v["methods"].as_array().unwrap();
    let names: Vec<&str> = rows.iter().map(|r| r["method"].as_str().unwrap()).collect();
    assert_eq!(names, ["holzschuch", "wyman"]);
    let l1 = rows[1]["relative_l1"].as_f64().unwrap();
    let seconds = rows[1]["seconds"].as_f64().unwrap();
    println!("wyman against holzschuch at 32 x 32: relative L1 {l1:.3}, {seconds:.3} s");
    assert!(l1 > 0.0 && l1 < 1.0, "{l1}");
    assert!(out.join("wyman.png").is_file() && out.join("contact.png").is_file());
}

fn wyman_refuses_what_it_cannot_do() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("x.png");
    let png = png.to_str().unwrap();
    let scene = write(dir.path(), "sphere.toml", SPHERE);
    expect_error(
        &[
            "render",
            &scene,
            "--method",
            "wyman",
            "--backend",
            "cpu",
            "-o",
            png,
        ],
        &["--backend cpu", "wyman"],
    );
    expect_error(
        &[
            "render",
            &scene,
            "--method",
            "wyman",
            "--light",
            dir.path().to_str().unwrap(),
            "-o",
            png,
        ],
        &["--light", "eikonal"],
    );
    // The scene is checked before a device is looked for.
    {
        let spot = SPHERE.replace(
            "type = \"directional\"",
            "type = \"spot\"\nposition = [0.0, 1.5, 0.0]\nangle = 20.0",
        );
        let s = write(dir.path(), "spot.toml", &spot);
        expect_error(
            &["render", &s, "--method", "wyman", "-o", png],
            &["spot.toml", "light[0].type", "spot"],
        );
        let rounded = SPHERE.replace(
            "{ type = \"sphere\", center = [0.0, 0.15, 0.0], radius = 0.45 }",
            "{ type = \"rounded_box\", center = [0.0, 0.15, 0.0], size = [0.6, 0.6, 0.6], radius = 0.1 }",
        );
        let s = write(dir.path(), "rounded.toml", &rounded);
        expect_error(
            &["render", &s, "--method", "wyman", "-o", png],
            &["rounded.toml", "object[0].shape.radius"],
        );
    }
    assert!(!Path::new(png).exists());
}

fn wyman_renders_frame_sequences(_: &Gpu) {
    let dir = tempfile::tempdir().unwrap();
    let anim = format!(
        "{SPHERE}\n[animation]\nframes = 2\n\n[[animation.track]]\nfield = \"light[0].direction\"\nkeys = [{{ frame = 0, value = [0.2, -1.0, 0.1] }}, {{ frame = 1, value = [-0.2, -1.0, 0.0] }}]\n"
    );
    let scene = write(dir.path(), "orbit.toml", &anim);
    let out = dir.path().join("frames");
    let png = out.join("img.png");
    eikon_ok(&[
        "render",
        &scene,
        "--method",
        "wyman",
        "--photons",
        "64",
        "--frames",
        "all",
        "-o",
        png.to_str().unwrap(),
    ]);
    let a = std::fs::read(out.join("img_0000.png")).unwrap();
    let b = std::fs::read(out.join("img_0001.png")).unwrap();
    // The caustic moves with the light.
    assert_ne!(a, b);
    assert!(out.join("manifest-render.json").is_file());
}

fn main() {
    Tests::new()
        .gpu(
            "render_method_wyman_writes_the_image_and_says_what_it_did",
            render_method_wyman_writes_the_image_and_says_what_it_did,
        )
        .gpu("compare_has_a_wyman_row", compare_has_a_wyman_row)
        .gpu(
            "wyman_renders_frame_sequences",
            wyman_renders_frame_sequences,
        )
        .cpu(
            "wyman_refuses_what_it_cannot_do",
            wyman_refuses_what_it_cannot_do,
        )
        .run()
}
