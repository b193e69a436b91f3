//! The light-volume folder holds one whole run: readers (`probe`,
//! `render --light`, `export --light`) refuse damaged, forged or mixed
//! folders with a clear error naming the file, never panic or abort, and a
//! run killed at any moment leaves the old run or the new one (issue 17).

use eikon_wavefront::lightdir::{FileRecord, SIDECAR};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
mod binary;

use binary::{eikon_ok, expect_error};

/// 16^3, a scattering glass ball, two lights (so a run writes five files),
/// a camera for small renders.
const SCENE: &str = r#"
[grid]
resolution = 16
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
shape = { type = "sphere", center = [0, 0, 0], radius = 0.5 }
index = 1.5
extinction = [0.5, 0.5, 0.5]
albedo = [0.5, 0.5, 0.5]

[[light]]
type = "point"
position = [0.2, 0.8, 0.1]
power = [4, 2, 1]

[[light]]
type = "directional"
direction = [0, -1, 0]
power = [1, 1, 1]

[camera]
position = [0, 1, 3]
target = [0, 0, 0]
resolution = [16, 12]
"#;

/// Two settings whose volumes differ.
const SETTINGS: [&[&str]; 2] = [
    &["--step", "0.5"],
    &["--step", "0.25", "--patch-size", "0.5"],
];

/// The files a run of `SCENE` writes.
const FILES: [&str; 5] = [
    "light0_fluence.npy",
    "light0_flux.npy",
    "light1_fluence.npy",
    "light1_flux.npy",
    SIDECAR,
];

const AT: &str = "0.1,-0.3,0.2";

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn strs(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

fn setup() -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene.toml");
    std::fs::write(&scene, SCENE).unwrap();
    (dir, scene)
}

fn simulate(scene: &Path, out: &Path, settings: &[&str]) {
    eikon_ok(&[&["simulate", s(scene), "-o", s(out)][..], settings].concat());
}

/// Rewrite file `name` of light folder `dir` with `bytes` and record its
/// new size and checksum in the sidecar, as if the run had written it: the
/// readers' other checks must then catch what is wrong with it.
fn reseal(dir: &Path, name: &str, bytes: &[u8]) {
    std::fs::write(dir.join(name), bytes).unwrap();
    let path = dir.join(SIDECAR);
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    let r = FileRecord::of_file(&dir.join(name)).unwrap();
    let files = v["files"].as_array_mut().unwrap();
    let f = files.iter_mut().find(|f| f["name"] == name).unwrap();
    *f = serde_json::to_value(r).unwrap();
    std::fs::write(&path, serde_json::to_vec_pretty(&v).unwrap()).unwrap();
}

/// A version 1 `.npy` file's bytes with `from` replaced by `to` in its
/// header (whose length is kept).
fn edit_header(bytes: &[u8], from: &str, to: &str) -> Vec<u8> {
    let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let text = std::str::from_utf8(&bytes[10..10 + hlen]).unwrap();
    assert!(text.contains(from), "{text}");
    let new = text.trim_end().replace(from, to);
    let mut out = bytes[..10].to_vec();
    out.extend_from_slice(new.as_bytes());
    out.resize(10 + hlen - 1, b' ');
    out.push(b'\n');
    out.extend_from_slice(&bytes[10 + hlen..]);
    out
}

/// Every reader of `light` refuses it with exit 1, a message holding
/// every fragment, and no panic; nothing is written.
fn every_reader_refuses(dir: &Path, scene: &Path, light: &Path, fragments: &[&str]) {
    let img = dir.join("never.exr");
    let vdb = dir.join("never.vdb");
    expect_error(&["probe", s(light), "--at", AT], fragments);
    expect_error(
        &["render", s(scene), "--light", s(light), "-o", s(&img)],
        fragments,
    );
    expect_error(
        &["export", s(scene), "--light", s(light), "--vdb", s(&vdb)],
        fragments,
    );
    assert!(!img.exists() && !vdb.exists());
}

/// The issue's panic: `"dims": [0, 1, 1]` with a (0, 1, 1, 3) array.
#[test]
fn zero_dims_are_refused_not_a_panic() {
    let (dir, scene) = setup();
    let light = dir.path().join("light");
    simulate(&scene, &light, SETTINGS[0]);
    let path = light.join(SIDECAR);
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    v["grid"]["dims"] = serde_json::json!([0, 1, 1]);
    v["lights"][0]["flux_shape"] = serde_json::json!([0, 1, 1, 3]);
    std::fs::write(&path, serde_json::to_vec(&v).unwrap()).unwrap();
    for name in ["light0_fluence.npy", "light0_flux.npy"] {
        let bytes = std::fs::read(light.join(name)).unwrap();
        let mut empty = edit_header(&bytes, "(16, 16, 16, 3)", "(0, 1, 1, 3)");
        let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        empty.truncate(10 + hlen);
        reseal(&light, name, &empty);
    }
    expect_error(
        &["probe", s(&light), "--at", "0.5,0.5,0.5"],
        &[SIDECAR, "grid.dims: [0, 1, 1]", "at least one cell"],
    );
}

/// The issue's abort: a header claiming (1e12, 1, 1, 3) on a small file is
/// refused by every reader before anything is allocated for it.
#[test]
fn a_header_claiming_more_than_the_file_holds_is_refused() {
    let (dir, scene) = setup();
    let light = dir.path().join("light");
    simulate(&scene, &light, SETTINGS[0]);
    let name = "light0_fluence.npy";
    let bytes = std::fs::read(light.join(name)).unwrap();
    let forged = edit_header(&bytes, "(16, 16, 16, 3)", "(1000000000000, 1, 1, 3)");
    // The size and checksum are recorded: only the header gives it away.
    reseal(&light, name, &forged);
    every_reader_refuses(
        dir.path(),
        &scene,
        &light,
        &[
            name,
            "claims shape (1000000000000, 1, 1, 3)",
            "the file holds 49152 bytes",
        ],
    );
    // Not resealed, a file of another size is refused before it is read.
    std::fs::write(light.join(name), &bytes[..1000]).unwrap();
    every_reader_refuses(
        dir.path(),
        &scene,
        &light,
        &[name, "1000 bytes", "recorded"],
    );
}

/// NaN or inf in an input volume is refused with the file and the first
/// bad index; nothing reaches an EXR or a `.npy`.
#[test]
fn non_finite_input_is_refused_with_file_and_index() {
    let (dir, scene) = setup();
    let light = dir.path().join("light");
    simulate(&scene, &light, SETTINGS[0]);
    let name = "light1_flux.npy";
    let mut bytes = std::fs::read(light.join(name)).unwrap();
    let data = bytes.len() - 16 * 16 * 16 * 3 * 4;
    // [3, 4, 5, 1] and, later, [9, 0, 0, 2]: the first is reported.
    for (idx, v) in [([3, 4, 5, 1], f32::NAN), ([9, 0, 0, 2], f32::INFINITY)] {
        let flat = ((idx[0] * 16 + idx[1]) * 16 + idx[2]) * 3 + idx[3];
        let at = data + 4 * flat;
        bytes[at..at + 4].copy_from_slice(&v.to_le_bytes());
    }
    reseal(&light, name, &bytes);
    let npy = dir.path().join("npy");
    every_reader_refuses(
        dir.path(),
        &scene,
        &light,
        &[name, "NaN at index [3, 4, 5, 1]", "must be finite"],
    );
    expect_error(
        &["export", s(&scene), "--light", s(&light), "--npy", s(&npy)],
        &[name, "[3, 4, 5, 1]"],
    );
    assert!(!npy.exists());
}

/// The issue's mixed folder: files of two runs side by side are refused,
/// naming the file that does not belong.
#[test]
fn a_folder_mixing_two_runs_is_refused() {
    let (dir, scene) = setup();
    let a = dir.path().join("a");
    let b = dir.path().join("b");
    simulate(&scene, &a, SETTINGS[0]);
    simulate(&scene, &b, SETTINGS[1]);
    std::fs::copy(b.join("light0_fluence.npy"), a.join("light0_fluence.npy")).unwrap();
    every_reader_refuses(
        dir.path(),
        &scene,
        &a,
        &["light0_fluence.npy", "CRC-32", "mixes files of two runs"],
    );
    // The whole run copied over is whole again.
    for f in FILES {
        std::fs::copy(b.join(f), a.join(f)).unwrap();
    }
    eikon_ok(&["probe", s(&a), "--at", AT]);
    // A sidecar of an older format is refused with what to do.
    let path = a.join(SIDECAR);
    let text = std::fs::read_to_string(&path).unwrap();
    std::fs::write(&path, text.replace("\"version\": 3", "\"version\": 2")).unwrap();
    expect_error(
        &["probe", s(&a), "--at", AT],
        &[SIDECAR, "version: 2", "simulate this scene again"],
    );
}

/// A small seeded generator (xorshift64*).
struct Rng(u64);

impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// What one complete run of each setting gives: the probe's values, a
/// render, an export, and its files' bytes.
struct Reference {
    probe: serde_json::Value,
    exr: Vec<u8>,
    vdb: Vec<u8>,
    files: Vec<Vec<u8>>,
}

fn probe_values(light: &Path) -> Result<serde_json::Value, String> {
    let o = binary::eikon(&["probe", s(light), "--at", AT, "--json"]);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(!err.contains("panicked"), "probe panicked: {err}");
    if o.status.success() {
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        Ok(v["lights"].clone())
    } else {
        assert_eq!(o.status.code(), Some(1), "probe: {err}");
        assert!(err.starts_with("error: "), "{err}");
        Err(err)
    }
}

/// Run `eikon args` with `env` and kill -9 it `delay` after it starts or,
/// with `sidecar`, after it has written the temporary file of that sidecar
/// (its renames begin then): whether it was still running.
fn kill_after(
    args: &[&str],
    env: &[(&str, &str)],
    sidecar: Option<&Path>,
    delay: Duration,
) -> bool {
    let mut child = Command::new(env!("CARGO_BIN_EXE_eikon"))
        .args(args)
        .envs(env.iter().copied())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    if let Some(sidecar) = sidecar {
        let name = sidecar.file_name().unwrap().to_str().unwrap();
        let tmp = sidecar.with_file_name(format!(".{name}.{}.tmp", child.id()));
        let t = Instant::now();
        while !tmp.exists() && child.try_wait().unwrap().is_none() {
            assert!(t.elapsed().as_secs() < 60, "no {}", tmp.display());
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    std::thread::sleep(delay);
    let alive = child.try_wait().unwrap().is_none();
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    alive
}

/// Which setting a light folder's sidecar names (by its step).
fn setting_of(light: &Path) -> Option<usize> {
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(light.join(SIDECAR)).ok()?)
        .expect("a sidecar at its final path is complete JSON");
    match v["options"]["step_voxels"].as_f64() {
        Some(0.5) => Some(0),
        Some(0.25) => Some(1),
        other => panic!("unexpected step {other:?}"),
    }
}

/// The required crash test: kill -9 at random (seeded) moments during
/// `simulate` (into a new folder and re-runs into one holding a complete
/// run and a file of the user's), `render` and `export`; after each kill
/// every reader sees exactly the old run, exactly the new one, or refuses
/// the folder as mixed, and no final path holds a partial file.
#[test]
fn killed_runs_leave_the_old_run_or_the_new_one() {
    let started = Instant::now();
    let (dir, scene) = setup();
    let tmp = dir.path();
    let refs: Vec<Reference> = SETTINGS
        .iter()
        .enumerate()
        .map(|(k, set)| {
            let light = tmp.join(format!("ref{k}"));
            simulate(&scene, &light, set);
            let exr = tmp.join(format!("ref{k}.exr"));
            let vdb = tmp.join(format!("ref{k}.vdb"));
            let l = s(&light);
            eikon_ok(&["render", s(&scene), "--light", l, "-o", s(&exr)]);
            eikon_ok(&["export", s(&scene), "--light", l, "--vdb", s(&vdb)]);
            Reference {
                probe: probe_values(&light).unwrap(),
                exr: std::fs::read(&exr).unwrap(),
                vdb: std::fs::read(&vdb).unwrap(),
                files: FILES[..4]
                    .iter()
                    .map(|f| std::fs::read(light.join(f)).unwrap())
                    .collect(),
            }
        })
        .collect();
    assert_ne!(refs[0].probe, refs[1].probe, "the settings must differ");
    assert_ne!(refs[0].exr, refs[1].exr);
    for (a, b) in refs[0].files.iter().zip(&refs[1].files) {
        assert_ne!(a, b);
    }
    // How the whole folder looks after a kill: which run a reader sees.
    let check = |light: &Path, tally: &mut [usize; 4]| {
        for (i, f) in FILES[..4].iter().enumerate() {
            if let Ok(bytes) = std::fs::read(light.join(f)) {
                assert!(
                    refs.iter().any(|r| r.files[i] == bytes),
                    "{f}: a partial or foreign file at a final path"
                );
            }
        }
        let named = setting_of(light);
        match probe_values(light) {
            Ok(v) => {
                let k = named.expect("probe read a folder without a sidecar");
                assert_eq!(v, refs[k].probe, "probe read a mix of two runs");
                tally[k] += 1;
                let exr = light.with_extension("check.exr");
                let o = binary::eikon(&["render", s(&scene), "--light", s(light), "-o", s(&exr)]);
                assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
                assert!(
                    std::fs::read(&exr).unwrap() == refs[k].exr,
                    "render read a mix"
                );
                std::fs::remove_file(&exr).unwrap();
            }
            Err(e) if named.is_none() => {
                assert!(
                    e.contains("cannot read the light-volume description"),
                    "{e}"
                );
                tally[3] += 1;
            }
            Err(e) => {
                assert!(e.contains("mixes files of two runs"), "{e}");
                tally[2] += 1;
            }
        }
    };
    let mut rng = Rng(0x5eed_1e55_0b5e_55ed);
    let mut alive = 0;
    // [old or new by setting 0, by setting 1, refused as mixed, no run yet]
    let mut tally = [0usize; 4];
    let timed = |args: &[&str]| {
        let t = Instant::now();
        eikon_ok(args);
        t.elapsed().as_secs_f64()
    };

    // Re-runs into a folder that holds a complete run and a user's file;
    // kills fall within the time a complete run takes (measured here, as
    // the machine is loaded now).
    let work = tmp.join("work");
    std::fs::create_dir(&work).unwrap();
    std::fs::write(work.join("notes.txt"), "mine").unwrap();
    let simulate_args = |out: &Path, k: usize| -> Vec<String> {
        [&["simulate", s(&scene), "-o", s(out)][..], SETTINGS[k]]
            .concat()
            .iter()
            .map(|a| a.to_string())
            .collect()
    };
    let seconds: Vec<f64> = [1, 0]
        .iter()
        .map(|&k| timed(&strs(&simulate_args(&work, k))))
        .collect();
    let seconds = [seconds[1], seconds[0]];
    // Most re-runs pause before each rename, so that the renames take a
    // window of 0.2 s; half of the kills land in it, the others anywhere
    // (some after the run has finished).
    const PAUSE: [(&str, &str); 1] = [("EIKON_TEST_RENAME_PAUSE_MS", "40")];
    let window = FILES.len() as f64 * 0.04;
    for i in 0..24 {
        // The other setting than the one the folder's sidecar names, so
        // that old and new files differ.
        let k = 1 - setting_of(&work).unwrap();
        let (env, renames_in, delay): (&[(&str, &str)], _, f64) = match i % 4 {
            3 => (&[], None, rng.uniform() * 1.5 * seconds[k]),
            1 => (&PAUSE, None, rng.uniform() * 1.3 * (seconds[k] + window)),
            _ => (&PAUSE, Some(work.join(SIDECAR)), rng.uniform() * window),
        };
        let args = simulate_args(&work, k);
        let delay = Duration::from_secs_f64(delay);
        alive += kill_after(&strs(&args), env, renames_in.as_deref(), delay) as usize;
        let refused = tally[2];
        check(&work, &mut tally);
        assert_eq!(std::fs::read(work.join("notes.txt")).unwrap(), b"mine");
        if tally[2] > refused {
            // Start the next kill from a whole run again.
            simulate(&scene, &work, SETTINGS[k]);
        }
    }
    // First runs into a new folder.
    for i in 0..6 {
        let fresh = tmp.join(format!("fresh{i}"));
        let k = i % 2;
        let delay = Duration::from_secs_f64(rng.uniform() * seconds[k]);
        alive += kill_after(&strs(&simulate_args(&fresh, k)), &[], None, delay) as usize;
        check(&fresh, &mut tally);
    }
    // Renders and exports killed: their outputs are absent, the old one or
    // the new one; the folders they read are untouched.
    let exr = tmp.join("killed.exr");
    let vdb = tmp.join("killed.vdb");
    let owned = |v: &[&str]| -> Vec<String> { v.iter().map(|a| a.to_string()).collect() };
    let render = |light: &Path| owned(&["render", s(&scene), "--light", s(light), "-o", s(&exr)]);
    let export =
        |light: &Path| owned(&["export", s(&scene), "--light", s(light), "--vdb", s(&vdb)]);
    let ref0 = tmp.join("ref0");
    let span = [timed(&strs(&render(&ref0))), timed(&strs(&export(&ref0)))];
    for i in 0..12 {
        let k = (rng.uniform() * 2.0) as usize;
        let light = tmp.join(format!("ref{k}"));
        let delay = Duration::from_secs_f64(rng.uniform() * span[i % 2]);
        let args = if i % 2 == 0 {
            render(&light)
        } else {
            export(&light)
        };
        alive += kill_after(&strs(&args), &[], None, delay) as usize;
        if let Ok(b) = std::fs::read(&exr) {
            assert!(refs.iter().any(|r| r.exr == b), "a partial image");
        }
        if let Ok(b) = std::fs::read(&vdb) {
            assert!(refs.iter().any(|r| r.vdb == b), "a partial VDB file");
        }
        assert_eq!(probe_values(&light).unwrap(), refs[k].probe);
    }
    // The folder takes a complete run again, which removes the killed
    // runs' temporaries and leaves the user's file.
    simulate(&scene, &work, SETTINGS[1]);
    assert_eq!(probe_values(&work).unwrap(), refs[1].probe);
    let mut left: Vec<String> = std::fs::read_dir(&work)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    assert_eq!(left, [&FILES[..], &["notes.txt"]].concat(), "{left:?}");
    eprintln!(
        "kills: {alive} of 42 while running; after them readers saw setting 0 {} times, setting 1 {} times, refused a mixed folder {} times, found no run {} times ({:.1} s)",
        tally[0],
        tally[1],
        tally[2],
        tally[3],
        started.elapsed().as_secs_f64()
    );
    assert!(alive >= 14, "only {alive} kills hit a running process");
    // Kills between renames leave a mixed folder, which readers refuse;
    // none at all means the test missed the moment it is about.
    assert!(tally[2] > 0, "no kill landed between the renames");
}

/// CRC-32 (IEEE, reflected, as zlib), bit by bit: the test's own, not the
/// engine's.
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 == 1 {
                (c >> 1) ^ 0xedb8_8320
            } else {
                c >> 1
            };
        }
    }
    !c
}

/// The arrays of an `export --npy` folder (name and bytes, sorted) if every
/// file its `volumes.json` lists has the size and CRC-32 recorded there;
/// otherwise which file disagrees.
fn verified_npy(dir: &Path) -> Result<Vec<(String, Vec<u8>)>, String> {
    let side = std::fs::read(dir.join("volumes.json")).map_err(|e| e.to_string())?;
    let v: serde_json::Value =
        serde_json::from_slice(&side).expect("a sidecar at its final path is complete JSON");
    let mut out = Vec::new();
    for f in v["files"].as_array().expect("files") {
        let name = f["name"].as_str().unwrap().to_string();
        let bytes = std::fs::read(dir.join(&name)).map_err(|e| format!("{name}: {e}"))?;
        if bytes.len() as u64 != f["bytes"].as_u64().unwrap()
            || format!("{:08x}", crc32(&bytes)) != f["crc32"].as_str().unwrap()
        {
            return Err(format!("{name}: not the file the sidecar names"));
        }
        out.push((name, bytes));
    }
    out.sort();
    Ok(out)
}

/// `export --npy` re-run into a folder and killed at random moments (many
/// of them between its renames): the folder's sidecar either verifies and
/// the arrays are exactly one export's, or a file disagrees with it (a
/// mixed folder, which a reader checking the sidecar refuses); no array at
/// a final path is ever partial. The sidecar's checksums are checked
/// against an independent CRC-32.
#[test]
fn killed_npy_exports_verify_as_one_run_or_not_at_all() {
    let (dir, scene) = setup();
    let tmp = dir.path();
    let export = |k: usize, out: &Path| -> Vec<String> {
        let light = tmp.join(format!("light{k}"));
        ["export", s(&scene), "--light", s(&light), "--npy", s(out)]
            .iter()
            .map(|a| a.to_string())
            .collect()
    };
    let refs: Vec<Vec<(String, Vec<u8>)>> = (0..2)
        .map(|k| {
            simulate(&scene, &tmp.join(format!("light{k}")), SETTINGS[k]);
            let out = tmp.join(format!("ref{k}"));
            eikon_ok(&strs(&export(k, &out)));
            verified_npy(&out).unwrap()
        })
        .collect();
    assert_ne!(refs[0], refs[1], "the two exports must differ");
    assert!(refs[0].iter().any(|(n, _)| n == "fluence.npy"));
    let work = tmp.join("work");
    eikon_ok(&strs(&export(0, &work)));
    std::fs::write(work.join("notes.txt"), "mine").unwrap();
    let seconds = {
        let t = Instant::now();
        eikon_ok(&strs(&export(1, &work)));
        t.elapsed().as_secs_f64()
    };
    const PAUSE: [(&str, &str); 1] = [("EIKON_TEST_RENAME_PAUSE_MS", "30")];
    let mut rng = Rng(0x0e4b_0127_5eed_0001);
    let (mut whole, mut mixed) = ([0usize; 2], 0usize);
    for i in 0..12 {
        let now = refs
            .iter()
            .position(|r| Ok(r) == verified_npy(&work).as_ref())
            .expect("each kill starts from a whole export");
        let k = 1 - now;
        let (sidecar, delay) = if i % 3 == 2 {
            (None, rng.uniform() * 1.3 * seconds)
        } else {
            (Some(work.join("volumes.json")), rng.uniform() * 0.2)
        };
        let args = export(k, &work);
        kill_after(
            &strs(&args),
            &PAUSE,
            sidecar.as_deref(),
            Duration::from_secs_f64(delay),
        );
        for (n, (name, _)) in refs[0].iter().enumerate() {
            let bytes = std::fs::read(work.join(name)).unwrap();
            assert!(
                refs.iter().any(|r| r[n].1 == bytes),
                "{name}: a partial or foreign array at a final path"
            );
        }
        match verified_npy(&work) {
            Ok(files) => {
                let r = refs.iter().position(|r| *r == files);
                whole[r.expect("a verified folder holds one export's arrays")] += 1;
            }
            Err(e) => {
                assert!(e.contains("not the file the sidecar names"), "{e}");
                mixed += 1;
                eikon_ok(&strs(&export(k, &work)));
            }
        }
        assert_eq!(std::fs::read(work.join("notes.txt")).unwrap(), b"mine");
    }
    eprintln!("npy exports killed: whole old or new {whole:?}, mixed and refused {mixed}");
    assert!(mixed > 0, "no kill landed between the renames");
    assert!(
        whole.iter().sum::<usize>() > 0,
        "every kill left a mixed folder"
    );
    // A complete export cleans up the killed runs' temporaries.
    eikon_ok(&strs(&export(0, &work)));
    let mut left: Vec<String> = std::fs::read_dir(&work)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    let mut want: Vec<String> = refs[0].iter().map(|(n, _)| n.clone()).collect();
    want.extend(["notes.txt".to_string(), "volumes.json".to_string()]);
    want.sort();
    assert_eq!(left, want);
}
