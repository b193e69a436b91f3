//! End-to-end tests of the `eikon` binary: good scenes work, bad input gets
//! a clear located error, a non-zero exit, no panic and no partial output.

use std::path::{Path, PathBuf};
mod binary;

use binary::{eikon, eikon_ok, expect_error, expect_error_after_notes};

fn config(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("configs")
        .join(name)
        .display()
        .to_string()
}

const SMALL: &str = r#"
[grid]
resolution = 16
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
name = "ball"
shape = { type = "sphere", center = [0, 0, 0], radius = 0.5 }
index = 1.5
"#;

fn write_scene(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn every_config_loads_and_builds() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs");
    let mut n = 0;
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "toml") {
            let out = eikon(&["info", "--json", p.to_str().unwrap()]);
            assert!(
                out.status.success(),
                "{}: {}",
                p.display(),
                String::from_utf8_lossy(&out.stderr)
            );
            let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
            let lo = v["index_range"][0].as_f64().unwrap();
            assert!(
                lo >= 1.0 - 1e-6,
                "{}: index below ambient: {lo}",
                p.display()
            );
            n += 1;
        }
    }
    assert!(n >= 4, "expected the four required scenes, found {n}");
}

/// Every shipped scene runs end to end (`eikon run`) at a small
/// resolution (8 voxels on the longest side: the scenes whose light is
/// trapped in glass follow it for hundreds of steps whatever the size),
/// writes its image, and is listed in the README.
#[test]
fn every_config_runs_and_is_in_the_readme() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let mut names = Vec::new();
    for e in std::fs::read_dir(root.join("configs")).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_none_or(|x| x != "toml") {
            continue;
        }
        let name = p.file_name().unwrap().to_str().unwrap().to_string();
        let out = tmp.path().join(&name);
        let o = eikon(&[
            "run",
            p.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--resolution",
            "8",
            "--width",
            "32",
            "--height",
            "24",
        ]);
        assert!(
            o.status.success(),
            "eikon run {name} failed: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        // The flag's grid is what was built.
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains("grid ") && err.contains("voxels"),
            "{name}: {err}"
        );
        assert!(out.join("image.png").is_file(), "{name}: no image");
        let sidecar: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("light_volumes.json")).unwrap())
                .unwrap();
        let dims: Vec<u64> = serde_json::from_value(sidecar["grid"]["dims"].clone()).unwrap();
        assert_eq!(dims.iter().max(), Some(&8), "{name}: dims {dims:?}");
        assert!(
            readme.contains(&format!("`{name}`")),
            "README.md does not list configs/{name}"
        );
        names.push(name);
    }
    assert!(names.len() >= 10, "{names:?}");
}

/// `--resolution` and `--smoothing` change the grid that is built; a light
/// volume simulated at one resolution is refused by a render at another,
/// with a hint naming the flag.
#[test]
fn resolution_flag_overrides_the_scene_grid() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = config("glass-sphere.toml");
    let light = tmp.path().join("light");
    let o = eikon(&[
        "simulate",
        &scene,
        "-o",
        light.to_str().unwrap(),
        "--resolution",
        "10",
        "--smoothing",
        "0.5",
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("grid 10 x 10 x 10 voxels, smoothing 0.5 voxel"),
        "{err}"
    );
    let png = tmp.path().join("a.png");
    let render = [
        "render",
        &scene,
        "--light",
        light.to_str().unwrap(),
        "-o",
        png.to_str().unwrap(),
        "--width",
        "8",
        "--height",
        "6",
    ];
    let e = expect_error(&render, &["--resolution"]);
    assert!(e.contains("light_volumes.json"), "{e}");
    eikon_ok(&[&render[..], &["--resolution", "10"]].concat());
    assert!(png.is_file());
    // Out-of-range values are refused by name.
    for bad in [
        vec!["--resolution", "0"],
        vec!["--smoothing", "9"],
        vec!["--smoothing", "nan"],
    ] {
        let mut a = vec!["simulate", &scene, "-o", light.to_str().unwrap()];
        a.extend(bad.iter().copied());
        let o = eikon(&a);
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(bad[0]), "{bad:?}: {err}");
    }
    // --preview caps the grid at 48 voxels and the image at 320 pixels.
    let o = eikon(&[
        "run",
        &config("glass-sphere.toml"),
        "-o",
        tmp.path().join("p").to_str().unwrap(),
        "--preview",
        "--resolution",
        "16",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("rendered 320 x 240"));
}

#[test]
fn trace_reports_exit_through_luneburg_focus() {
    // A ray at impact parameter R/2 leaves the lens at the focus (0, 0, R)
    // and then travels straight to the bounds.
    let out = eikon_ok(&[
        "trace",
        &config("luneburg.toml"),
        "--origin",
        "0.4,0,-1.5",
        "--dir",
        "0,0,1",
        "--json",
    ]);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["status"], "exited");
    let p: Vec<f64> = (0..3).map(|i| v["exit"][i].as_f64().unwrap()).collect();
    let d: Vec<f64> = (0..3)
        .map(|i| v["direction"][i].as_f64().unwrap())
        .collect();
    assert!((p[2] - 1.0).abs() < 1e-9);
    // Back along the exit line to z = R = 0.8: within a quarter voxel of x = 0.
    let t = (p[2] - 0.8) / d[2];
    let x_at_focus = p[0] - t * d[0];
    assert!(x_at_focus.abs() < 0.25 * 2.0 / 128.0, "miss {x_at_focus}");
    assert!(v["path"].as_array().unwrap().len() > 100);
    assert!(v["optical_path"].as_f64().unwrap() > 2.0);
}

#[test]
fn trace_reports_a_trapped_ray_instead_of_dropping_it() {
    let out = eikon(&[
        "trace",
        &config("luneburg.toml"),
        "--origin",
        "0,0,0",
        "--dir",
        "1,0,0",
        "--max-steps",
        "5",
        "--every",
        "0",
    ]);
    assert_eq!(out.status.code(), Some(1));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("status        max-steps"), "{text}");
    assert!(String::from_utf8_lossy(&out.stderr).contains("--max-steps"));
}

#[test]
fn slice_writes_a_png_of_the_grid() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), "s.toml", SMALL);
    let png = dir.path().join("n.png");
    eikon_ok(&[
        "slice",
        scene.to_str().unwrap(),
        "--axis",
        "z",
        "--at",
        "0.5",
        "-o",
        png.to_str().unwrap(),
        "--scale",
        "2",
    ]);
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[1..4], b"PNG");
    // 16 x 16 voxels at scale 2: the IHDR width and height are 32.
    assert_eq!(u32::from_be_bytes(bytes[16..20].try_into().unwrap()), 32);
    assert_eq!(u32::from_be_bytes(bytes[20..24].try_into().unwrap()), 32);
    // No temporary file is left behind.
    let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(left.len(), 2);
}

#[test]
fn missing_file_is_named() {
    expect_error(
        &["info", "/nonexistent/scene.toml"],
        &["/nonexistent/scene.toml", "cannot read scene file"],
    );
}

#[test]
fn malformed_toml_names_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let p = write_scene(dir.path(), "bad.toml", "[grid]\nresolution = = 16\n");
    expect_error(&["info", p.to_str().unwrap()], &["bad.toml:2:14"]);
}

#[test]
fn unknown_field_is_rejected_with_its_place() {
    let dir = tempfile::tempdir().unwrap();
    let text = SMALL.replace("index = 1.5", "index = 1.5\ncolor = \"red\"");
    let p = write_scene(dir.path(), "unknown.toml", &text);
    expect_error(
        &["info", p.to_str().unwrap()],
        &["unknown.toml:11:1", "object[0]", "unknown field `color`"],
    );
}

#[test]
fn non_positive_index_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    for (bad, what) in [
        ("index = 0.0", "> 0"),
        ("index = -1.5", "> 0"),
        ("index = nan", "finite"),
    ] {
        let p = write_scene(dir.path(), "n.toml", &SMALL.replace("index = 1.5", bad));
        expect_error(
            &["info", p.to_str().unwrap()],
            &["n.toml:10:1", "object[0].index", what],
        );
    }
    // A linear profile that dips below zero inside the grid.
    let text = SMALL.replace(
        "index = 1.5",
        "index = { type = \"linear\", n0 = 1.0, gradient = [0, 3, 0] }",
    );
    let p = write_scene(dir.path(), "lin.toml", &text);
    expect_error(&["info", p.to_str().unwrap()], &["object[0].index", "<= 0"]);
}

#[test]
fn resolution_too_large_is_refused_before_allocating() {
    let dir = tempfile::tempdir().unwrap();
    let p = write_scene(
        dir.path(),
        "huge.toml",
        &SMALL.replace("resolution = 16", "resolution = 100000"),
    );
    let start = std::time::Instant::now();
    expect_error(
        &["info", p.to_str().unwrap()],
        &["huge.toml:3:1", "grid.resolution", "memory is available"],
    );
    // Refused from the estimate alone: no time spent voxelizing.
    assert!(start.elapsed().as_secs_f64() < 5.0);
    let out = dir.path().join("never.png");
    expect_error(
        &[
            "slice",
            p.to_str().unwrap(),
            "--axis",
            "x",
            "--at",
            "0.5",
            "-o",
            out.to_str().unwrap(),
        ],
        &["grid.resolution"],
    );
    assert!(!out.exists(), "no output may be written on failure");
}

#[test]
fn bad_arguments_are_refused() {
    // clap's own usage errors exit with 2.
    let out = eikon(&[
        "trace",
        &config("luneburg.toml"),
        "--origin",
        "0,0",
        "--dir",
        "0,0,1",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("three comma-separated numbers"));
    expect_error(
        &[
            "trace",
            &config("luneburg.toml"),
            "--origin",
            "0,0,0",
            "--dir",
            "0,0,0",
        ],
        &["--dir"],
    );
    expect_error(
        &[
            "trace",
            &config("luneburg.toml"),
            "--origin",
            "0,0,0",
            "--dir",
            "0,0,1",
            "--step",
            "-1",
        ],
        &["--step"],
    );
}

#[test]
fn every_command_has_help() {
    for cmd in [
        vec!["--help"],
        vec!["info", "--help"],
        vec!["trace", "--help"],
        vec!["slice", "--help"],
        vec!["simulate", "--help"],
        vec!["probe", "--help"],
        vec!["render", "--help"],
        vec!["run", "--help"],
        vec!["demo", "--help"],
    ] {
        let out = eikon(&cmd);
        assert!(out.status.success());
        assert!(String::from_utf8_lossy(&out.stdout).contains("Usage:"));
    }
}

const LIT: &str = r#"
[grid]
resolution = 32
min = [-1, -1, -1]
max = [1, 1, 1]

[[light]]
type = "point"
position = [0.1, 0.05, -0.02]
power = [4, 2, 1]
"#;

#[test]
fn simulate_writes_light_volumes_that_probe_reads() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), "lit.toml", LIT);
    let out = dir.path().join("light");
    let run = eikon_ok(&[
        "simulate",
        scene.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--json",
    ]);
    let summary: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    let energy = &summary["lights"][0]["energy_w"];
    assert!(
        energy["imbalance_relative"].as_f64().unwrap() < 1e-9,
        "{energy}"
    );
    assert!((energy["entered"][0].as_f64().unwrap() - 4.0).abs() < 1e-9);
    for f in [
        "light_volumes.json",
        "light0_fluence.npy",
        "light0_flux.npy",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    // 0.5 away from the light: fluence P / (4 pi r^2), the net flux as
    // large, pointing away.
    let at = [0.6, 0.05, -0.02];
    let probe = eikon_ok(&[
        "probe",
        out.to_str().unwrap(),
        "--at",
        &format!("{},{},{}", at[0], at[1], at[2]),
        "--json",
    ]);
    let v: serde_json::Value = serde_json::from_slice(&probe.stdout).unwrap();
    let e = v["lights"][0]["fluence"][0].as_f64().unwrap();
    let want = 4.0 / (4.0 * std::f64::consts::PI * 0.25);
    assert!((e / want - 1.0).abs() < 0.02, "{e} vs {want}");
    // The flux vector is the mean of the channels' vectors.
    let mean = (0..3)
        .map(|c| v["lights"][0]["fluence"][c].as_f64().unwrap())
        .sum::<f64>()
        / 3.0;
    let f = v["lights"][0]["flux"][0][0].as_f64().unwrap();
    assert!(f / mean > 0.99, "flux x {f}, mean fluence {mean}");
    // Outside the volume is refused.
    expect_error(
        &["probe", out.to_str().unwrap(), "--at", "3,0,0"],
        &["--at", "outside"],
    );
    expect_error(
        &["probe", dir.path().to_str().unwrap(), "--at", "0,0,0"],
        &["light_volumes.json"],
    );
}

/// A plane wave onto a glass slab (n = 1.5) at normal incidence.
const SLAB: &str = r#"
[grid]
resolution = 16
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
name = "slab"
shape = { type = "box", center = [0.0, -1.6, 0.0], size = [4.0, 2.8, 4.0] }
index = 1.5

[[light]]
type = "directional"
direction = [0, -1, 0]
power = [1, 1, 1]
"#;

/// `eikon simulate SCENE -o OUT --json [FLAGS]`: its JSON summary and the
/// sidecar it wrote.
fn simulate_json(
    scene: &Path,
    out: &Path,
    flags: &[&str],
) -> (serde_json::Value, serde_json::Value) {
    let mut args = vec![
        "simulate",
        scene.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--json",
    ];
    args.extend(flags);
    let run = eikon_ok(&args);
    let summary = serde_json::from_slice(&run.stdout).unwrap();
    let sidecar =
        serde_json::from_slice(&std::fs::read(out.join("light_volumes.json")).unwrap()).unwrap();
    (summary, sidecar)
}

/// The emitted patch size follows the interfaces unless given: half a
/// voxel at sharp interfaces (16^2 x 4 patches emitted by the plane wave
/// over the 16^3 slab), a voxel with the smoothed index (16^2), and
/// `--patch-size` over either; the sidecar records the size the run used.
#[test]
fn the_emitted_patch_size_follows_the_interfaces_unless_given() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), "slab.toml", SLAB);
    for (i, (flags, size, emitted)) in [
        (&[][..], 0.5, 1024),
        (&["--interfaces", "smoothed"][..], 1.0, 256),
        (
            &["--interfaces", "smoothed", "--patch-size", "0.5"][..],
            0.5,
            1024,
        ),
        (&["--patch-size", "1"][..], 1.0, 256),
    ]
    .into_iter()
    .enumerate()
    {
        let (summary, sidecar) =
            simulate_json(&scene, &dir.path().join(format!("light{i}")), flags);
        assert_eq!(
            sidecar["options"]["patch_size_voxels"].as_f64(),
            Some(size),
            "{flags:?}: {sidecar}"
        );
        assert_eq!(
            summary["lights"][0]["emitted"].as_u64(),
            Some(emitted),
            "{flags:?}: {summary}"
        );
    }
}

/// By default the Fresnel-reflected light is traced on and recorded so;
/// with `--no-reflections` it is dropped and counted as reflected. In
/// front of the slab the fluence reads `1 + R` (R = 0.04) and 1.
#[test]
fn simulate_traces_reflected_light_unless_told_not_to() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), "slab.toml", SLAB);
    for (flag, want) in [(None, 1.04), (Some("--no-reflections"), 1.0)] {
        let out = dir.path().join(format!("light{}", flag.is_some()));
        let (summary, sidecar) = simulate_json(&scene, &out, flag.as_slice());
        let light = &summary["lights"][0];
        let traced = light["reflections"].as_u64().unwrap_or(0);
        let reflected = light["energy_w"]["reflected"][0].as_f64().unwrap();
        assert_eq!(
            sidecar["options"]["reflections"].as_bool(),
            Some(flag.is_none()),
            "{sidecar}"
        );
        if flag.is_none() {
            assert!(traced > 0 && reflected < 1e-6, "{light}");
        } else {
            assert!(
                traced == 0 && (reflected / 0.16 - 1.0).abs() < 1e-6,
                "{light}"
            );
        }
        let probe = eikon_ok(&[
            "probe",
            out.to_str().unwrap(),
            "--at",
            "0.05,0.5,0.05",
            "--json",
        ]);
        let v: serde_json::Value = serde_json::from_slice(&probe.stdout).unwrap();
        let e = v["lights"][0]["fluence"][0].as_f64().unwrap();
        assert!(
            (e - want).abs() < 2e-3,
            "{flag:?}: fluence {e}, want {want}"
        );
    }
}

/// `--no-runs` steps every patch one step at a time and the sidecar says
/// which was done; the light in front of the slab and inside it reads the
/// same either way (`1 + R` = 1.04 with the reflected light, and T = 0.96,
/// to the deposit's own accuracy), and the energy account is the same.
#[test]
fn simulate_without_runs_says_so_and_reads_the_same() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), "slab.toml", SLAB);
    let mut read = Vec::new();
    for flag in [None, Some("--no-runs")] {
        let out = dir.path().join(format!("runs{}", flag.is_none()));
        let (summary, sidecar) = simulate_json(&scene, &out, flag.as_slice());
        let exited = summary["lights"][0]["energy_w"]["exited"][0]
            .as_f64()
            .unwrap();
        assert_eq!(
            sidecar["options"]["runs"].as_bool(),
            Some(flag.is_none()),
            "{sidecar}"
        );
        let probe = |at: &str| {
            let p = eikon_ok(&["probe", out.to_str().unwrap(), "--at", at, "--json"]);
            let v: serde_json::Value = serde_json::from_slice(&p.stdout).unwrap();
            v["lights"][0]["fluence"][0].as_f64().unwrap()
        };
        read.push((probe("0.05,0.5,0.05"), probe("0.05,-0.6,0.05"), exited));
    }
    let ((front, inside, exited), (front1, inside1, exited1)) = (read[0], read[1]);
    for (a, b, want) in [(front, front1, 1.04), (inside, inside1, 0.96)] {
        assert!(
            (a - want).abs() < 2e-3 && (b - want).abs() < 2e-3,
            "{read:?}"
        );
    }
    assert!((exited - exited1).abs() < 1e-9, "{read:?}");
}

#[test]
fn simulate_refuses_bad_input_without_writing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("never");
    let dark = write_scene(dir.path(), "dark.toml", SMALL);
    expect_error(
        &[
            "simulate",
            dark.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ],
        &["dark.toml", "no [[light]]"],
    );
    let lit = write_scene(dir.path(), "lit.toml", LIT);
    for t in ["0", "-0.5", "1.5"] {
        expect_error(
            &[
                "simulate",
                lit.to_str().unwrap(),
                "-o",
                out.to_str().unwrap(),
                "--threshold",
                t,
            ],
            &["--threshold"],
        );
    }
    let buried = write_scene(
        dir.path(),
        "buried.toml",
        &format!(
            "{LIT}\n[[object]]\nshape = {{ type = \"sphere\", center = [0.1, 0.05, -0.02], radius = 0.3 }}\nindex = 1.5\nextinction = [1e6, 1e6, 1e6]\n"
        ),
    );
    expect_error(
        &[
            "simulate",
            buried.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ],
        &["light[0].position", "opaque"],
    );
    assert!(!out.exists(), "no output may be written on failure");
}

/// Issue 17: a light power beyond the limit is refused at its place; one
/// within it that a tiny grid still concentrates beyond 32-bit floats is
/// refused at the same place, with nothing written; trapped light is its
/// own line of the summary and a warning on stderr.
#[test]
fn simulate_refuses_overflow_and_warns_of_trapped_light() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("never");
    let huge = write_scene(
        dir.path(),
        "huge.toml",
        &LIT.replace("power = [4, 2, 1]", "power = [4, 1e38, 1]"),
    );
    let err = expect_error(
        &[
            "simulate",
            huge.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ],
        &["huge.toml", "light[0].power", "1e20"],
    );
    println!("{err}");
    let tiny = write_scene(
        dir.path(),
        "tiny.toml",
        "[grid]\nresolution = 8\nmin = [0, 0, 0]\nmax = [1e-10, 1e-10, 1e-10]\n\
         [[light]]\ntype = \"point\"\nposition = [5.1e-11, 4.9e-11, 5.2e-11]\npower = [1e20, 1e20, 1e20]\n",
    );
    let err = expect_error(
        &[
            "simulate",
            tiny.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--json",
        ],
        &["tiny.toml", "light[0].power", "overflow"],
    );
    println!("{err}");
    assert!(!out.exists(), "no output may be written on failure");
    // A point light off the centre of a clear n = 3 sphere: geometric
    // optics traps 83% (`crates/wavefront/tests/finite.rs` checks the fraction).
    let trap = write_scene(
        dir.path(),
        "trap.toml",
        "[grid]\nresolution = 16\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n\
         [[object]]\nshape = { type = \"sphere\", center = [0, 0, 0], radius = 0.8 }\nindex = 3\n\
         [[light]]\ntype = \"point\"\nposition = [0.48, 0.01, 0.02]\npower = [1, 1, 1]\n",
    );
    let light = dir.path().join("trap");
    let run = eikon_ok(&[
        "simulate",
        trap.to_str().unwrap(),
        "-o",
        light.to_str().unwrap(),
        "--max-steps",
        "300",
        "--json",
    ]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    println!("{stderr}");
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    let energy = &v["lights"][0]["energy_w"];
    let trapped = energy["trapped"][0].as_f64().unwrap();
    let entered = energy["entered"][0].as_f64().unwrap();
    assert!(trapped > 0.5 * entered, "{energy}");
    assert!(energy["imbalance_relative"].as_f64().unwrap() < 1e-9);
    let pct = format!("{:.1}%", 100.0 * trapped / entered);
    assert!(
        stderr.contains("warning: light 0:") && stderr.contains("trapped") && stderr.contains(&pct),
        "{stderr}"
    );
    // The text summary has the line; a light that traps nothing warns of
    // nothing.
    let text = eikon_ok(&[
        "simulate",
        trap.to_str().unwrap(),
        "-o",
        light.to_str().unwrap(),
        "--max-steps",
        "300",
    ]);
    assert!(String::from_utf8_lossy(&text.stdout).contains("  trapped  "));
    let lit = write_scene(dir.path(), "lit.toml", LIT);
    let free = eikon_ok(&[
        "simulate",
        lit.to_str().unwrap(),
        "-o",
        dir.path().join("free").to_str().unwrap(),
    ]);
    assert!(!String::from_utf8_lossy(&free.stderr).contains("trapped"));
}

#[test]
fn simulate_with_photons_agrees_with_the_wavefront_in_free_space() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), "lit.toml", LIT);
    let out = dir.path().join("photons");
    eikon_ok(&[
        "simulate",
        scene.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--method",
        "photons",
        "--count",
        "200000",
        "--seed",
        "7",
    ]);
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("light_volumes.json")).unwrap())
            .unwrap();
    assert_eq!(meta["method"], "photons");
    assert_eq!(meta["lights"][0]["flux_file"], "light0_flux.npy");
    let probe = eikon_ok(&[
        "probe",
        out.to_str().unwrap(),
        "--at",
        "-0.5,0.4,0.3",
        "--json",
    ]);
    let v: serde_json::Value = serde_json::from_slice(&probe.stdout).unwrap();
    let e = v["lights"][0]["fluence"][0].as_f64().unwrap();
    let r2 = 0.6f64.powi(2) + 0.35f64.powi(2) + 0.32f64.powi(2);
    let want = 4.0 / (4.0 * std::f64::consts::PI * r2);
    // 200k photons over 32^3 cells: a few hundred crossings per cell.
    assert!((e / want - 1.0).abs() < 0.1, "{e} vs {want}");
    expect_error(
        &[
            "simulate",
            scene.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--method",
            "photons",
            "--count",
            "0",
        ],
        &["--count"],
    );
}

/// A small lit scene with a camera, for the render commands.
const VIEW: &str = r#"
[grid]
resolution = 24
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
shape = { type = "sphere", center = [0, 0, 0], radius = 0.5 }
index = 1.5
extinction = [0.5, 0.5, 0.5]
albedo = [0.5, 0.5, 0.5]

[[light]]
type = "directional"
direction = [0, -1, 0]
power = [1, 1, 1]

[receiver]
point = [0, -0.8, 0]
normal = [0, 1, 0]
albedo = [0.8, 0.8, 0.8]

[camera]
position = [0, 1, 3]
target = [0, 0, 0]
resolution = [32, 24]
"#;

#[test]
fn run_simulates_and_renders_and_render_reuses_the_volumes() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), "view.toml", VIEW);
    let out = dir.path().join("out");
    eikon_ok(&["run", scene.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    for f in [
        "light_volumes.json",
        "light0_fluence.npy",
        "image.exr",
        "image.png",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let png = out.join("again.png");
    let exr = out.join("again.exr");
    let r = eikon_ok(&[
        "render",
        scene.to_str().unwrap(),
        "--light",
        out.to_str().unwrap(),
        "-o",
        png.to_str().unwrap(),
        "-o",
        exr.to_str().unwrap(),
        "--json",
    ]);
    let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    assert_eq!(v["width"], 32);
    // Deterministic: the same scene renders the same image.
    assert_eq!(
        std::fs::read(out.join("image.exr")).unwrap(),
        std::fs::read(&exr).unwrap()
    );
    assert!(std::fs::read(&png).unwrap().starts_with(b"\x89PNG"));
}

#[test]
fn render_refuses_bad_input_without_writing() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), "view.toml", VIEW);
    let s = scene.to_str().unwrap();
    let img = dir.path().join("never.png");
    let i = img.to_str().unwrap();
    // A missing light-volume directory.
    let missing = dir.path().join("nothing-here");
    expect_error(
        &["render", s, "--light", missing.to_str().unwrap(), "-o", i],
        &["light_volumes.json", "cannot read"],
    );
    // Light volumes of another grid.
    let other = write_scene(
        dir.path(),
        "other.toml",
        &VIEW.replace("resolution = 24", "resolution = 16"),
    );
    let vols = dir.path().join("vols16");
    eikon_ok(&[
        "simulate",
        other.to_str().unwrap(),
        "-o",
        vols.to_str().unwrap(),
    ]);
    expect_error(
        &["render", s, "--light", vols.to_str().unwrap(), "-o", i],
        &["grid", "16x16x16", "24x24x24", "simulate this scene again"],
    );
    // An unreadable environment map, named with its field.
    let bad_env = write_scene(dir.path(), "env.exr", "not an exr file");
    let with_env = write_scene(
        dir.path(),
        "env.toml",
        &format!(
            "{VIEW}\n[background]\ntype = \"environment\"\nfile = \"{}\"\n",
            bad_env.file_name().unwrap().to_str().unwrap()
        ),
    );
    expect_error(
        &["render", with_env.to_str().unwrap(), "-o", i],
        &["background.file", "env.exr"],
    );
    let absent = write_scene(
        dir.path(),
        "absent.toml",
        &format!("{VIEW}\n[background]\ntype = \"environment\"\nfile = \"gone.exr\"\n"),
    );
    expect_error(
        &["render", absent.to_str().unwrap(), "-o", i],
        &["background.file", "gone.exr"],
    );
    // An unknown image format, before any work.
    expect_error(
        &[
            "render",
            s,
            "-o",
            dir.path().join("x.jpg").to_str().unwrap(),
        ],
        &["x.jpg", ".exr", ".png"],
    );
    // A bad camera in the scene file, located.
    let cam = write_scene(
        dir.path(),
        "cam.toml",
        &VIEW.replace("target = [0, 0, 0]", "target = [0, 1, 3]"),
    );
    expect_error(
        &["render", cam.to_str().unwrap(), "-o", i],
        &["camera.target"],
    );
    assert!(!img.exists(), "a failed render left an image");
}

#[test]
fn demo_needs_no_files() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    eikon_ok(&[
        "demo",
        "-o",
        out.to_str().unwrap(),
        "--width",
        "64",
        "--height",
        "48",
    ]);
    for f in ["demo.toml", "demo.png", "demo.exr", "light_volumes.json"] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
}

/// Issue 17's reproducers of unbounded work and memory: each is refused
/// before any work, with the flag or field that caused it, exit 1 and no
/// panic.
#[test]
fn inputs_that_would_make_unbounded_work_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let o = out.to_str().unwrap();
    let ball = write_scene(tmp.path(), "ball.toml", SMALL);
    let lit = |light: &str| format!("{SMALL}\n[[light]]\n{light}\npower = [1, 1, 1]\n");
    let sun = lit("type = \"directional\"\ndirection = [0, -1, 0]");
    let lit_ball = write_scene(tmp.path(), "lit.toml", &sun);
    let s = lit_ball.to_str().unwrap();
    // Grids: huge coordinates, cells far from cubic.
    for (text, field) in [
        (
            SMALL.replace("max = [1, 1, 1]", "max = [4e299, 1, 1]"),
            "grid.max",
        ),
        (
            SMALL.replace(
                "min = [-1, -1, -1]\nmax = [1, 1, 1]",
                "min = [-1, 0, -1]\nmax = [1, 1e-12, 1]",
            ),
            "grid.resolution",
        ),
    ] {
        let p = write_scene(tmp.path(), "grid.toml", &text);
        expect_error(&["info", p.to_str().unwrap()], &[field]);
    }
    // A point light 1e30 away.
    let far = write_scene(
        tmp.path(),
        "far.toml",
        &lit("type = \"point\"\nposition = [1e30, 0, 0]"),
    );
    expect_error(
        &["simulate", far.to_str().unwrap(), "-o", o],
        &["light[0].position", "directional"],
    );
    // Steps, patches and splits far below a voxel; emission beyond the
    // patch limit.
    for (flag, value) in [
        ("--patch-size", "1e-300"),
        ("--patch-size", "0.001"),
        ("--split", "1e-9"),
        ("--step", "1e-9"),
    ] {
        expect_error(&["simulate", s, "-o", o, flag, value], &[&flag[2..]]);
    }
    expect_error(
        &[
            "simulate",
            s,
            "-o",
            o,
            "--patch-size",
            "0.0625",
            "--max-patches",
            "16",
        ],
        &["light[0]", "--max-patches"],
    );
    // Photon counts and image sizes beyond their limits.
    for count in ["18446744073709551615", "1000000000000"] {
        expect_error(
            &[
                "simulate", s, "-o", o, "--method", "photons", "--count", count,
            ],
            &["--count"],
        );
    }
    let png = tmp.path().join("a.png");
    expect_error(
        &[
            "render",
            ball.to_str().unwrap(),
            "-o",
            png.to_str().unwrap(),
            "--width",
            "4294967295",
        ],
        &["--width"],
    );
    assert!(!png.exists() && !out.exists());
    // A device given as a scene is not read until memory runs out.
    if Path::new("/dev/zero").exists() {
        expect_error(&["info", "/dev/zero"], &["/dev/zero", "not a regular file"]);
    }
}

/// The memory a run needs, everything it holds included, is checked against
/// `--max-memory` (else what is available): a default patch cap is lowered
/// to what fits, a given one, a grid or an image that does not fit is
/// refused with the items listed.
#[test]
fn memory_estimates_are_checked_against_the_limit() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let o = out.to_str().unwrap();
    let scene = config("glass-sphere.toml");
    let small = ["--resolution", "16", "--max-memory", "3M"];
    let ok = eikon_ok(&[&["simulate", &scene, "-o", o][..], &small].concat());
    let err = String::from_utf8_lossy(&ok.stderr);
    assert!(err.contains("patches fit the memory limit"), "{err}");
    let e = expect_error_after_notes(
        &[
            &["simulate", &scene, "-o", o, "--max-patches", "100000"][..],
            &small,
        ]
        .concat(),
        &["patch list at its cap", "--max-memory"],
    );
    assert!(e.contains("light volumes") && e.contains("medium"), "{e}");
    expect_error_after_notes(
        &[
            "simulate",
            &scene,
            "-o",
            o,
            "--resolution",
            "64",
            "--max-memory",
            "1M",
        ],
        &["grid.resolution", "--max-memory"],
    );
    let png = tmp.path().join("big.png");
    expect_error_after_notes(
        &[
            "render",
            &scene,
            "-o",
            png.to_str().unwrap(),
            "--resolution",
            "16",
            "--max-memory",
            "2M",
            "--width",
            "4000",
            "--height",
            "4000",
        ],
        &["image", "--max-memory"],
    );
    assert!(!png.exists());
    let o = eikon(&["info", &scene, "--max-memory", "lots"]);
    assert_eq!(o.status.code(), Some(2), "clap's usage error");
    assert!(String::from_utf8_lossy(&o.stderr).contains("--max-memory"));
}

/// The estimate checked before a simulation covers what the run holds: its
/// peak resident memory (Linux `VmHWM`, reported by `--json`) exceeds the
/// estimate by no more than the process's fixed cost (code, libraries,
/// thread stacks: the excess of an 8^3 run, whose arrays are a few KiB)
/// plus one eighth of the estimate for what the allocator keeps of memory
/// freed while the medium is built (measured at 128^3: about 5%).
#[test]
fn the_memory_estimate_covers_the_peak_resident_memory() {
    if !Path::new("/proc/self/status").exists() {
        eprintln!("ignored: no /proc/self/status on this system");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let scene = config("glass-sphere.toml");
    let run = |extra: &[&str]| -> (f64, f64) {
        let o = eikon_ok(
            &[
                &["simulate", &scene, "-o", out.to_str().unwrap(), "--json"][..],
                extra,
            ]
            .concat(),
        );
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let m = &v["memory"];
        (
            m["estimate_bytes"].as_f64().unwrap(),
            m["peak_resident_bytes"].as_f64().unwrap(),
        )
    };
    let photons = ["--method", "photons", "--count", "20000"];
    let (e0, p0) = run(&[&["--resolution", "8"][..], &photons].concat());
    assert!(e0 < 2e6, "an 8^3 run holds little: {e0}");
    let fixed = p0 - e0;
    let cases: [&[&str]; 2] = [
        &[
            "--resolution",
            "96",
            "--method",
            "photons",
            "--count",
            "20000",
        ],
        &[
            "--resolution",
            "80",
            "--max-patches",
            "40000",
            "--backend",
            "cpu",
        ],
    ];
    for extra in cases {
        let (e, p) = run(extra);
        eprintln!(
            "{extra:?}: estimate {:.1} MiB, peak resident {:.1} MiB, fixed cost {:.1} MiB",
            e / 1048576.0,
            p / 1048576.0,
            fixed / 1048576.0
        );
        assert!(p <= e * 1.125 + fixed, "{extra:?}: peak {p} > estimate {e}");
        assert!(e > 8.0 * fixed, "{extra:?}: the arrays dominate");
    }
}
