//! Frames shared out over processes (docs/CLUSTER.md): `--shard K/N`, the
//! shipped Kubernetes indexed Job run as local processes, and the shipped
//! Slurm array script on a one-node Slurm cluster (tests/support/slurm-up.sh).
//! Each way must give the very bytes of one process running every frame.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

const ROOT: &str = env!("CARGO_MANIFEST_DIR");
const EIKON: &str = env!("CARGO_BIN_EXE_eikon");
/// The frames every test runs, and the flags that make them small. The CPU
/// backend, so that a machine with a GPU compares like with like.
const FRAMES: &str = "0..5";
const FRAME_COUNT: usize = 6;
const SMALL: [&str; 4] = ["--resolution", "16", "--backend", "cpu"];

fn scene() -> String {
    format!("{ROOT}/configs/orbit.toml")
}

/// `eikon` without the environment that picks a shard (the tests may run
/// inside a Slurm job or a Kubernetes pod).
fn eikon() -> Command {
    let mut c = Command::new(EIKON);
    for v in [
        "SLURM_ARRAY_TASK_ID",
        "SLURM_ARRAY_TASK_COUNT",
        "SLURM_ARRAY_TASK_MIN",
        "SLURM_ARRAY_TASK_MAX",
        "JOB_COMPLETION_INDEX",
        "EIKON_SHARD_COUNT",
    ] {
        c.env_remove(v);
    }
    c
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

fn ok(what: &str, out: Output) -> Output {
    assert!(
        out.status.success(),
        "{what} failed ({}):\n{}{}",
        out.status,
        text(&out.stdout),
        text(&out.stderr)
    );
    out
}

/// `eikon simulate` of the test frames into `out`, with `more` flags.
fn simulate(out: &Path, more: &[&str]) -> Output {
    let o = eikon()
        .args(["simulate", &scene(), "--frames", FRAMES, "-o"])
        .arg(out)
        .args(SMALL)
        .args(more)
        .output()
        .unwrap();
    ok(&format!("simulate -o {} {more:?}", out.display()), o)
}

/// The reference: every frame in one process.
fn one_process(tmp: &Path) -> PathBuf {
    let dir = tmp.join("one");
    let o = simulate(&dir, &[]);
    assert!(text(&o.stderr).contains("shard 0 of 1 (one process)"));
    dir
}

fn status(dir: &Path) -> Output {
    eikon().arg("status").arg(dir).output().unwrap()
}

/// The `.npy` files of a frame folder, by name.
fn arrays(frame: &Path) -> BTreeMap<String, Vec<u8>> {
    let entries = std::fs::read_dir(frame)
        .unwrap_or_else(|e| panic!("{}: {e}", frame.display()))
        .map(|e| e.unwrap().path());
    entries
        .filter(|p| p.extension().is_some_and(|x| x == "npy"))
        .map(|p| {
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            (name, std::fs::read(&p).unwrap())
        })
        .collect()
}

/// Every test frame of `got` holds the arrays of `want`'s, bit for bit,
/// and `got` holds no other frame.
fn assert_same_frames(want: &Path, got: &Path) {
    let frames = std::fs::read_dir(got)
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .starts_with("frame_")
        })
        .count();
    assert_eq!(frames, FRAME_COUNT, "{}", got.display());
    for f in 0..FRAME_COUNT {
        let name = format!("frame_{f:04}");
        let (a, b) = (arrays(&want.join(&name)), arrays(&got.join(&name)));
        assert!(a.len() >= 2, "{name}: {:?}", a.keys());
        assert_eq!(
            a.keys().collect::<Vec<_>>(),
            b.keys().collect::<Vec<_>>(),
            "{name}"
        );
        for (file, bytes) in &a {
            assert!(
                *bytes == b[file],
                "{}: {name}/{file} differs from the one-process run",
                got.display()
            );
        }
    }
    // The frames are not all alike (the light moves).
    let first = arrays(&want.join("frame_0000"));
    let last = arrays(&want.join(format!("frame_{:04}", FRAME_COUNT - 1)));
    assert!(first["light0_fluence.npy"] != last["light0_fluence.npy"]);
}

#[test]
fn shards_equal_one_process() {
    let tmp = tempfile::tempdir().unwrap();
    let one = one_process(tmp.path());
    for n in [2, 3] {
        let dir = tmp.path().join(format!("{n}-shards"));
        for k in 0..n {
            let o = simulate(&dir, &["--shard", &format!("{k}/{n}")]);
            let err = text(&o.stderr);
            assert!(
                err.contains(&format!("shard {k} of {n} (--shard)")),
                "{err}"
            );
            assert!(dir
                .join(format!("manifest-simulate.{k}-of-{n}.json"))
                .is_file());
        }
        let s = ok("status", status(&dir));
        let out = text(&s.stdout);
        assert!(
            out.contains(&format!("done     {FRAME_COUNT} of {FRAME_COUNT}")),
            "{out}"
        );
        assert!(out.contains(&format!("{n} manifest(s)")), "{out}");
        assert_same_frames(&one, &dir);
    }

    // A changed scene is refused over the folder; with --force, shards
    // started together redo every frame.
    let three = tmp.path().join("3-shards");
    let changed = tmp.path().join("changed.toml");
    let orbit = std::fs::read_to_string(scene()).unwrap();
    assert!(orbit.contains("index = 1.5"));
    std::fs::write(&changed, orbit.replace("index = 1.5", "index = 1.4")).unwrap();
    let run = |k: usize, force: bool| {
        let mut c = eikon();
        c.arg("simulate")
            .arg(&changed)
            .args(["--frames", FRAMES, "--shard", &format!("{k}/3"), "-o"])
            .arg(&three)
            .args(SMALL)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        if force {
            c.arg("--force");
        }
        c.spawn().unwrap()
    };
    let refused = run(0, false).wait_with_output().unwrap();
    let err = text(&refused.stderr);
    assert_eq!(refused.status.code(), Some(1), "{err}");
    assert!(
        err.contains("another scene") && err.contains("--force"),
        "{err}"
    );
    let forced: Vec<_> = (0..3).map(|k| run(k, true)).collect();
    for (k, f) in forced.into_iter().enumerate() {
        ok(&format!("--force shard {k}"), f.wait_with_output().unwrap());
    }
    let s = ok("status", status(&three));
    assert!(text(&s.stdout).contains("done     6 of 6"));
    assert!(text(&s.stdout).contains("changed.toml"));
    for f in 0..FRAME_COUNT {
        let name = format!("frame_{f:04}");
        let (a, b) = (arrays(&one.join(&name)), arrays(&three.join(&name)));
        assert!(a["light0_fluence.npy"] != b["light0_fluence.npy"], "{name}");
    }

    // A shard that never ran: status names its frames and fails.
    let partial = tmp.path().join("partial");
    simulate(&partial, &["--shard", "0/3"]);
    simulate(&partial, &["--shard", "2/3"]);
    let s = status(&partial);
    assert_eq!(s.status.code(), Some(1), "{}", text(&s.stdout));
    let out = text(&s.stdout);
    assert!(out.contains("done     4 of 6: 0, 2-3, 5"), "{out}");
    assert!(out.contains("missing  1, 4"), "{out}");
    assert!(text(&s.stderr).contains("2 frame(s) are not done"));
    let json = eikon()
        .args(["status", "--json"])
        .arg(&partial)
        .output()
        .unwrap();
    assert_eq!(json.status.code(), Some(1));
    let v: serde_json::Value = serde_json::from_slice(&json.stdout).unwrap();
    assert_eq!(v[0]["missing"], serde_json::json!([1, 4]));

    // Running the missing shard finishes the folder; running a shard again
    // does nothing.
    simulate(&partial, &["--shard", "1/3"]);
    let again = simulate(&partial, &["--shard", "0/3"]);
    let err = text(&again.stderr);
    assert!(
        err.contains("0 frame(s) done") && err.contains("2 already done"),
        "{err}"
    );
    ok("status", status(&partial));
    assert_same_frames(&one, &partial);
}

/// What the tests read of the shipped Job: a line-based reading of the
/// fields it needs, not a YAML parser (the file keeps to one line each).
struct IndexedJob {
    completions: usize,
    command: Vec<String>,
    env: BTreeMap<String, String>,
}

fn unquote(s: &str) -> String {
    s.trim().trim_matches('"').to_string()
}

impl IndexedJob {
    fn read(path: &Path) -> IndexedJob {
        let yaml = std::fs::read_to_string(path).unwrap();
        let lines: Vec<&str> = yaml
            .lines()
            .map(str::trim)
            .filter(|l| !l.starts_with('#'))
            .collect();
        let field = |key: &str| -> String {
            let prefix = format!("{key}:");
            let hits: Vec<&&str> = lines.iter().filter(|l| l.starts_with(&prefix)).collect();
            assert_eq!(hits.len(), 1, "{key}: {hits:?}");
            unquote(&hits[0][prefix.len()..])
        };
        // command and args are flow sequences of quoted strings: JSON.
        let list = |key: &str| -> Vec<String> {
            serde_json::from_str(&field(key)).unwrap_or_else(|e| panic!("{key}: {e}"))
        };
        assert_eq!(field("completionMode"), "Indexed");
        let completions: usize = field("completions").parse().unwrap();
        assert_eq!(field("parallelism").parse::<usize>().unwrap(), completions);
        let mut command = list("command");
        command.extend(list("args"));
        let mut env = BTreeMap::new();
        for w in lines.windows(2) {
            if let (Some(name), Some(value)) =
                (w[0].strip_prefix("- name:"), w[1].strip_prefix("value:"))
            {
                env.insert(unquote(name), unquote(value));
            }
        }
        // The output is on the volume, and the volume is the claim.
        let mount = field("mountPath");
        assert!(env["OUT"].starts_with(&format!("{mount}/")), "{env:?}");
        let pvc = lines
            .iter()
            .position(|l| *l == "kind: PersistentVolumeClaim")
            .expect("a PersistentVolumeClaim");
        let pvc_name = lines[pvc..]
            .iter()
            .find_map(|l| l.strip_prefix("name:"))
            .map(unquote);
        assert_eq!(pvc_name, Some(field("claimName")));
        assert!(!field("image").is_empty());
        IndexedJob {
            completions,
            command,
            env,
        }
    }
}

#[test]
fn kubernetes_indexed_job_runs_as_local_processes() {
    let job = IndexedJob::read(&Path::new(ROOT).join("docs/cluster/k8s-indexed-job.yaml"));
    assert_eq!(job.completions, 4);
    assert_eq!(
        job.env["EIKON_SHARD_COUNT"],
        job.completions.to_string(),
        "EIKON_SHARD_COUNT must equal completions"
    );
    assert_eq!(job.command[..2], ["eikon", "simulate"]);
    assert!(
        !job.command.iter().any(|a| a == "--shard"),
        "{:?}",
        job.command
    );

    let tmp = tempfile::tempdir().unwrap();
    let one = one_process(tmp.path());
    let out = tmp.path().join("k8s");
    // Our values for the variables the Job sets; Kubernetes substitutes
    // $(NAME) in command and args from the container's env.
    let mut vars = job.env.clone();
    vars.insert("SCENE".into(), scene());
    vars.insert("FRAMES".into(), FRAMES.into());
    vars.insert("OUT".into(), format!("{}/", out.display()));
    let mut substituted = Vec::new();
    let args: Vec<String> = job.command[1..]
        .iter()
        .map(|a| {
            let mut a = a.clone();
            for (k, v) in &vars {
                let r = format!("$({k})");
                if a.contains(&r) {
                    substituted.push(k.clone());
                    a = a.replace(&r, v);
                }
            }
            assert!(!a.contains("$("), "unknown variable in {a}");
            a
        })
        .collect();
    substituted.sort();
    assert_eq!(substituted, ["FRAMES", "OUT", "SCENE"]);

    // Every pod at once, as parallelism asks, into one folder.
    let pods: Vec<_> = (0..job.completions)
        .map(|i| {
            eikon()
                .args(&args)
                .args(SMALL)
                .env("JOB_COMPLETION_INDEX", i.to_string())
                .env("EIKON_SHARD_COUNT", &job.env["EIKON_SHARD_COUNT"])
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap()
        })
        .collect();
    for (i, pod) in pods.into_iter().enumerate() {
        let o = ok(&format!("pod {i}"), pod.wait_with_output().unwrap());
        let err = text(&o.stderr);
        let n = job.completions;
        assert!(
            err.contains(&format!(
                "shard {i} of {n} (Kubernetes indexed job (JOB_COMPLETION_INDEX))"
            )),
            "{err}"
        );
    }
    let s = ok("status", status(&out));
    assert!(text(&s.stdout).contains("4 manifest(s)"));
    assert_same_frames(&one, &out);
}

/// Whether the cluster tests must run (`CI` set, as `.ci/run` does).
fn required() -> bool {
    std::env::var("CI").is_ok_and(|v| !v.is_empty() && v != "0" && v != "false")
}

/// Runs tests/support/slurm-down.sh when dropped, whatever happened.
struct Cluster {
    up_dir: PathBuf,
    sudo: bool,
}

impl Cluster {
    /// Run a support script as root (through `sudo -n` when not root).
    fn script(&self, name: &str) -> Output {
        let path = format!("{ROOT}/tests/support/{name}");
        let up_dir = format!("SLURM_UP_DIR={}", self.up_dir.display());
        let mut c = if self.sudo {
            let mut c = Command::new("sudo");
            c.args(["-n", "env", &up_dir, &path]);
            c
        } else {
            let mut c = Command::new(&path);
            c.env("SLURM_UP_DIR", &self.up_dir);
            c
        };
        c.stdin(Stdio::null()).output().unwrap()
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let o = self.script("slurm-down.sh");
        eprint!("{}{}", text(&o.stdout), text(&o.stderr));
        if !o.status.success() && !std::thread::panicking() {
            panic!("slurm-down.sh failed: {}", o.status);
        }
    }
}

/// Skip (with the reason) where Slurm cannot run, unless `CI` is set.
fn cannot_run(reason: &str) {
    assert!(
        !required(),
        "{reason}; the Slurm test may not be skipped in CI"
    );
    eprintln!("notice: skipping the Slurm test: {reason}");
}

#[test]
fn slurm_array_matches_one_process() {
    let started = Instant::now();
    let root = Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| text(&o.stdout).trim() == "0");
    let sudo = !root
        && Command::new("sudo")
            .args(["-n", "true"])
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
    if !root && !sudo {
        return cannot_run("it needs root or passwordless sudo to start Slurm");
    }
    let tmp = tempfile::tempdir().unwrap();
    let one = one_process(tmp.path());
    let submit = tmp.path().join("submit");
    std::fs::create_dir(&submit).unwrap();
    let out = tmp.path().join("slurm-out");

    // Declared after `tmp`, so dropped (the cluster stopped) before it.
    let cluster = Cluster {
        up_dir: tmp.path().join("slurm"),
        sudo,
    };
    let up = cluster.script("slurm-up.sh");
    let up_log = format!("{}{}", text(&up.stdout), text(&up.stderr));
    eprint!("{up_log}");
    match up.status.code() {
        Some(0) => {}
        Some(77) => return cannot_run(&format!("slurm-up.sh: {}", up_log.trim())),
        _ => panic!("slurm-up.sh failed ({}):\n{up_log}", up.status),
    }
    let up_at = started.elapsed();

    let script = format!("{ROOT}/docs/cluster/slurm-array.sh");
    let sbatch = Command::new("sbatch")
        .args(["--parsable", "--array=0-3", "--chdir"])
        .arg(&submit)
        .arg(&script)
        .env("SCENE", scene())
        .env("FRAMES", FRAMES)
        .env("OUT", &out)
        .env("EIKON", EIKON)
        .env("EIKON_FLAGS", SMALL.join(" "))
        .env_remove("JOB_COMPLETION_INDEX")
        .env_remove("EIKON_SHARD_COUNT")
        .output()
        .unwrap();
    let sbatch = ok("sbatch", sbatch);
    let id = text(&sbatch.stdout);
    let id = id.trim().split(';').next().unwrap().to_string();
    assert!(id.parse::<u64>().is_ok(), "sbatch printed {id}");

    // Wait until the array leaves the queue (no accounting here: no sacct).
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let q = Command::new("squeue")
            .args(["-h", "-j", &id])
            .output()
            .unwrap();
        if text(&q.stdout).trim().is_empty() {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "array {id} still queued after 60 s:\n{}",
            text(&q.stdout)
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    let job_at = started.elapsed();

    // slurmctld keeps finished jobs a while (MinJobAge): every task
    // completed with exit code 0.
    let show = ok(
        "scontrol show job",
        Command::new("scontrol")
            .args(["-o", "show", "job", &id])
            .output()
            .unwrap(),
    );
    let tasks: Vec<String> = text(&show.stdout).lines().map(String::from).collect();
    assert_eq!(tasks.len(), 4, "{tasks:#?}");
    for t in &tasks {
        assert!(
            t.contains("JobState=COMPLETED") && t.contains("ExitCode=0:0"),
            "{t}"
        );
    }
    // Each task took its shard from Slurm's environment, and said so.
    for k in 0..4 {
        let log = submit.join(format!("eikon-light-{id}_{k}.out"));
        let log =
            std::fs::read_to_string(&log).unwrap_or_else(|e| panic!("{}: {e}", log.display()));
        eprintln!("--- task {k}:\n{log}");
        assert!(
            log.contains(&format!(
                "frames 0..5: shard {k} of 4 (Slurm array (SLURM_ARRAY_TASK_ID))"
            )),
            "{log}"
        );
    }
    let s = ok("status", status(&out));
    eprint!("{}", text(&s.stdout));
    assert!(text(&s.stdout).contains("4 manifest(s)"));
    assert_same_frames(&one, &out);
    drop(cluster);
    eprintln!(
        "slurm: up after {:.1} s, array done after {:.1} s, down after {:.1} s",
        up_at.as_secs_f64(),
        job_at.as_secs_f64(),
        started.elapsed().as_secs_f64()
    );
}
