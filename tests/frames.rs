//! `eikon simulate --frames` over an animated scene (issue 19): a frame
//! equals the static scene with the frame's values, a killed run resumed
//! gives the uninterrupted run's volumes bit for bit with no partial file
//! ever at a final path, and a changed scene or setting is refused.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
mod binary;

use binary::{eikon, eikon_ok, expect_error};

/// A point light moving over a glass ball in 8 frames (linear keys at
/// frames 0 and 4 and 7; at frame 2 the position is exactly [0.2, 0.7,
/// -0.2]), 12^3.
const SCENE: &str = r#"
[grid]
resolution = 12
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
shape = { type = "sphere", center = [0, 0, 0], radius = 0.5 }
index = 1.5
extinction = [0.2, 0.2, 0.2]

[[light]]
type = "point"
position = [0, 0.7, 0]
power = [2, 1, 1]

[[light]]
type = "directional"
direction = [0, -1, 0]
power = [1, 1, 1]

[animation]
frames = 8

[[animation.track]]
field = "light[0].position"
keys = [
    { frame = 0, value = [0, 0.7, 0] },
    { frame = 4, value = [0.4, 0.7, -0.4] },
    { frame = 7, value = [0.4, 0.7, 0.5] },
]

[[animation.track]]
field = "light[1].power"
interpolation = "smooth"
keys = [{ frame = 0, value = [1, 1, 1] }, { frame = 7, value = [2, 2, 2] }]
"#;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// Every `.npy` under `out` (relative path -> bytes); none when `out` does
/// not exist (yet: a run killed before it made its folder).
fn arrays(out: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut m = BTreeMap::new();
    let Ok(entries) = std::fs::read_dir(out) else {
        return m;
    };
    for e in entries.flatten() {
        if e.path().is_dir() {
            for f in std::fs::read_dir(e.path()).unwrap().flatten() {
                let name = f.file_name().to_string_lossy().into_owned();
                if name.ends_with(".npy") {
                    let key = format!("{}/{name}", e.file_name().to_string_lossy());
                    m.insert(key, std::fs::read(f.path()).unwrap());
                }
            }
        }
    }
    m
}

/// Every path under `dir`.
fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        if e.path().is_dir() {
            out.extend(walk(&e.path()));
        }
        out.push(e.path());
    }
    out
}

#[test]
fn a_frame_equals_its_static_scene() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write(dir.path(), "anim.toml", SCENE);
    let out = dir.path().join("frames");
    eikon_ok(&["simulate", s(&scene), "--frames", "2", "-o", s(&out)]);
    // The same frame as a static scene: the tracked values written out
    // (light[1].power at frame 2 of a two-key smooth track is on the line:
    // 1 + 2/7, computed here the way the spline's Hermite form does).
    let u: f64 = 2.0 / 7.0;
    let (h00, h10, h01, h11) = (
        2.0 * u.powi(3) - 3.0 * u * u + 1.0,
        u.powi(3) - 2.0 * u * u + u,
        -2.0 * u.powi(3) + 3.0 * u * u,
        u.powi(3) - u * u,
    );
    let p = h00 * 1.0 + h10 * 7.0 * (1.0 / 7.0) + h01 * 2.0 + h11 * 7.0 * (1.0 / 7.0);
    assert!((p - (1.0 + u)).abs() < 1e-15);
    let mut text = SCENE[..SCENE.find("[animation]").unwrap()].to_string();
    text = text.replace("position = [0, 0.7, 0]", "position = [0.2, 0.7, -0.2]");
    text = text.replace(
        "direction = [0, -1, 0]\npower = [1, 1, 1]",
        &format!("direction = [0, -1, 0]\npower = [{p:?}, {p:?}, {p:?}]"),
    );
    let still = write(dir.path(), "still.toml", &text);
    let one = dir.path().join("one");
    eikon_ok(&["simulate", s(&still), "-o", s(&one)]);
    for f in [
        "light0_fluence.npy",
        "light0_flux.npy",
        "light1_fluence.npy",
    ] {
        assert!(
            std::fs::read(out.join("frame_0002").join(f)).unwrap()
                == std::fs::read(one.join(f)).unwrap(),
            "{f} differs from the static scene's"
        );
    }
    // Frame 0 of the animation is what a plain simulate (no --frames) gives.
    let plain = dir.path().join("plain");
    eikon_ok(&["simulate", s(&scene), "-o", s(&plain)]);
    eikon_ok(&["simulate", s(&scene), "--frames", "0", "-o", s(&out)]);
    assert_eq!(
        std::fs::read(plain.join("light0_fluence.npy")).unwrap(),
        std::fs::read(out.join("frame_0000/light0_fluence.npy")).unwrap()
    );
}

/// kill -9 at random (seeded) moments, resume, repeat: after each kill no
/// final path holds a partial file (every array present is the
/// uninterrupted run's), the manifest at its final path is whole JSON, and
/// when the runs finish the volumes are bitwise the uninterrupted run's.
#[test]
fn killed_and_resumed_runs_equal_one_uninterrupted_run() {
    let started = Instant::now();
    let dir = tempfile::tempdir().unwrap();
    let scene = write(dir.path(), "anim.toml", SCENE);
    let reference = dir.path().join("ref");
    let t = Instant::now();
    eikon_ok(&[
        "simulate",
        s(&scene),
        "--frames",
        "all",
        "-o",
        s(&reference),
    ]);
    let whole = t.elapsed().as_secs_f64();
    let want = arrays(&reference);
    assert_eq!(want.len(), 8 * 4, "8 frames of 2 lights, fluence and flux");
    let work = dir.path().join("work");
    let mut rng = 0x1234_5678_9abc_def1u64;
    let mut uniform = move || {
        rng ^= rng >> 12;
        rng ^= rng << 25;
        rng ^= rng >> 27;
        (rng.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    };
    let (mut alive, mut resumed_with_frames_done) = (0, 0);
    let done = |work: &Path| -> usize {
        std::fs::read(work.join("manifest-simulate.json"))
            .ok()
            .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
            .and_then(|v| v["done"].as_array().map(Vec::len))
            .unwrap_or(0)
    };
    // Kills until 12 have hit a running process (a loaded machine makes
    // some land after a run has finished), at most 40.
    let mut kills = 0;
    while alive < 12 && kills < 40 {
        kills += 1;
        // Kills fall within the time the frames left take; a finished
        // folder starts again from nothing.
        let left = 8 - done(&work);
        if left == 0 {
            std::fs::remove_dir_all(&work).unwrap();
        }
        let left = 8 - done(&work);
        if left < 8 {
            resumed_with_frames_done += 1;
        }
        let mut child = Command::new(env!("CARGO_BIN_EXE_eikon"))
            .args(["simulate", s(&scene), "--frames", "all", "-o", s(&work)])
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_secs_f64(
            uniform() * whole * (0.3 + 0.7 * left as f64 / 8.0),
        ));
        if child.try_wait().unwrap().is_none() {
            alive += 1;
        }
        child.kill().unwrap();
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!err.contains("panicked"), "{err}");
        for (name, bytes) in arrays(&work) {
            assert!(
                want.get(&name) == Some(&bytes),
                "{name}: a partial or different array at a final path"
            );
        }
        if let Ok(b) = std::fs::read(work.join("manifest-simulate.json")) {
            serde_json::from_slice::<serde_json::Value>(&b).expect("a whole manifest");
        }
    }
    // Finish: only the frames not yet done run.
    let o = eikon_ok(&["simulate", s(&scene), "--frames", "all", "-o", s(&work)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("already done"), "{err}");
    assert!(arrays(&work) == want, "resumed volumes differ");
    eikon_ok(&["status", s(&work)]);
    // The killed runs' temporaries are gone: the frames they were writing
    // were written again, the manifest rewritten.
    let mut temps = Vec::new();
    for e in walk(&work) {
        if e.to_string_lossy().ends_with(".tmp") {
            temps.push(e);
        }
    }
    assert!(temps.is_empty(), "{temps:?}");
    eprintln!(
        "kills: {alive} of {kills} while running ({resumed_with_frames_done} resumed past done frames), {:.1} s",
        started.elapsed().as_secs_f64()
    );
    assert!(
        alive >= 12,
        "only {alive} of {kills} kills hit a running process"
    );
    assert!(
        resumed_with_frames_done >= 4,
        "only {resumed_with_frames_done} runs resumed past frames already done"
    );
}

#[test]
fn changed_scenes_and_settings_are_refused_unless_forced() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write(dir.path(), "anim.toml", SCENE);
    let out = dir.path().join("out");
    let o = s(&out);
    eikon_ok(&["simulate", s(&scene), "--frames", "0..1", "-o", o]);
    expect_error(
        &[
            "simulate",
            s(&scene),
            "--frames",
            "0..1",
            "-o",
            o,
            "--step",
            "0.25",
        ],
        &[
            "manifest-simulate.json",
            "other settings",
            "step: 0.5 there, step: 0.25 now",
            "--force",
        ],
    );
    let changed = write(
        dir.path(),
        "anim.toml",
        &SCENE.replace("index = 1.5", "index = 1.4"),
    );
    expect_error(
        &["simulate", s(&changed), "--frames", "0..1", "-o", o],
        &["another scene", "--force"],
    );
    let before = std::fs::read(out.join("frame_0000/light0_fluence.npy")).unwrap();
    let e = eikon_ok(&[
        "simulate",
        s(&changed),
        "--frames",
        "0..1",
        "-o",
        o,
        "--force",
    ]);
    assert!(String::from_utf8_lossy(&e.stderr).contains("--force"));
    assert_ne!(
        before,
        std::fs::read(out.join("frame_0000/light0_fluence.npy")).unwrap()
    );
    // Bad ranges and shards.
    expect_error(
        &["simulate", s(&scene), "--frames", "3..9", "-o", o],
        &["--frames", "frame 9 does not exist", "8 frames"],
    );
    expect_error(
        &[
            "simulate",
            s(&scene),
            "--frames",
            "0..7",
            "--shard",
            "2/2",
            "-o",
            o,
        ],
        &["--shard", "shard 2 of 2 does not exist"],
    );
    // A broken track is located in the file.
    let bad = write(
        dir.path(),
        "bad.toml",
        &SCENE.replace("{ frame = 7, value = [0.4", "{ frame = 3, value = [0.4"),
    );
    expect_error(
        &["simulate", s(&bad), "--frames", "all", "-o", o],
        &[
            "bad.toml:",
            "animation.track[0].keys[2].frame",
            "increasing frame order",
        ],
    );
    // status names what is missing and fails. Two lights over two shards:
    // shard 0 holds light 0 of every frame, so no frame is whole until
    // shard 1 has run.
    let part = dir.path().join("part");
    let shard = |k: &str, frames: &str| {
        eikon_ok(&[
            "simulate",
            s(&scene),
            "--frames",
            frames,
            "--shard",
            k,
            "-o",
            s(&part),
        ]);
        let st = eikon(&["status", s(&part)]);
        (
            st.status.code(),
            String::from_utf8_lossy(&st.stdout).into_owned(),
        )
    };
    let (code, text) = shard("0/2", "0..3");
    assert_eq!(code, Some(1));
    assert!(
        text.contains("done     0 of 4: none") && text.contains("missing  0-3"),
        "{text}"
    );
    let (code, text) = shard("1/2", "0..2");
    assert_eq!(code, Some(1));
    assert!(
        text.contains("done     3 of 4: 0-2") && text.contains("missing  3"),
        "{text}"
    );
}

/// Shards share out (frame, light) units: with two lights and three shards
/// each frame's lights are simulated by different processes and put
/// together by whichever finishes its last light. Run one after another
/// and all at once, the frames equal one process's, bitwise, and the
/// parts are gone.
#[test]
fn lights_are_shared_out_over_shards() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write(dir.path(), "anim.toml", SCENE);
    let one = dir.path().join("one");
    eikon_ok(&["simulate", s(&scene), "--frames", "0..3", "-o", s(&one)]);
    let want = arrays(&one);
    assert_eq!(want.len(), 4 * 4);
    let args = |out: &Path, k: usize| -> Vec<String> {
        let shard = format!("{k}/3");
        [
            "simulate",
            s(&scene),
            "--frames",
            "0..3",
            "--shard",
            &shard,
            "-o",
            s(out),
        ]
        .iter()
        .map(|a| a.to_string())
        .collect()
    };
    // One after another: shard 0 holds no whole frame (units 0, 3, 6: light
    // 0 of frames 0 and 3, light 1 of frame 1), so it only writes parts.
    let seq = dir.path().join("seq");
    let mut waited = 0;
    for k in 0..3 {
        let a = args(&seq, k);
        let o = eikon_ok(&a.iter().map(String::as_str).collect::<Vec<_>>());
        let err = String::from_utf8_lossy(&o.stderr);
        waited += err.matches("waits for other shards").count();
        if k == 0 {
            assert!(err.contains("0 frame(s) done"), "{err}");
        }
    }
    assert!(waited >= 3, "{waited}");
    assert!(
        arrays(&seq) == want,
        "sequential shards differ from one process"
    );
    assert!(!seq.join("parts").exists());
    eikon_ok(&["status", s(&seq)]);
    // All at once.
    let par = dir.path().join("par");
    let children: Vec<_> = (0..3)
        .map(|k| {
            Command::new(env!("CARGO_BIN_EXE_eikon"))
                .args(args(&par, k))
                .stdout(Stdio::null())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap()
        })
        .collect();
    for c in children {
        let o = c.wait_with_output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    assert!(
        arrays(&par) == want,
        "concurrent shards differ from one process"
    );
    assert!(!par.join("parts").exists());
    eikon_ok(&["status", s(&par)]);
}
