//! Frame sequences: `--frames A..B` over an animated scene (docs/SCENES.md,
//! "Animation"), shared out over processes by `--shard K/N`, a Slurm array
//! or a Kubernetes indexed job (docs/CLUSTER.md), and resumable.
//!
//! Every process keeps a manifest of the frames it finished
//! (`manifest-COMMAND.json`, or `manifest-COMMAND.K-of-N.json` for shard K
//! of N, so that `simulate` and `render` can share a folder): the scene's hash, the
//! settings, and per frame its files with their sizes and CRC-32. A frame
//! counts as done only once it is in a manifest and its files still match
//! it, so a run killed at any moment loses at most the frame in flight: its
//! files are written through temporaries (`eikon_wavefront::staging`) and
//! the manifest, rewritten after each frame the same way, never names a
//! frame whose files are not complete. `eikon status` merges the manifests.

use crate::output::write_atomic;
use anyhow::{bail, Context, Result};
use eikon_wavefront::staging::FileRecord;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The `--frames`, `--shard` and `--force` flags.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct FrameFlags {
    /// Frames to run: `A..B` (both included), `A`, or `all`. Each frame's
    /// output goes to its own files; a frame already done (in the
    /// output's manifest, its files intact) is skipped.
    #[arg(long)]
    pub frames: Option<String>,
    /// Run shard K of N (0-based): every N-th frame of the range from its
    /// K-th. Without it, a Slurm array task (`SLURM_ARRAY_TASK_ID`) or a
    /// Kubernetes indexed job (`JOB_COMPLETION_INDEX`, with the count in
    /// `EIKON_SHARD_COUNT`) takes its shard from its environment.
    #[arg(long, requires = "frames")]
    pub shard: Option<String>,
    /// Run over an output whose manifest records another scene or other
    /// settings: its frames are done again.
    #[arg(long, requires = "frames")]
    pub force: bool,
}

/// An inclusive range of frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Range {
    /// First frame.
    pub first: usize,
    /// Last frame (included).
    pub last: usize,
}

impl Range {
    /// `A..B`, `A..=B`, `A` or `all`, within an animation of `frames`.
    pub fn parse(s: &str, frames: usize) -> Result<Range> {
        let num = |t: &str| -> Result<usize> {
            t.trim().parse::<usize>().with_context(|| {
                format!("--frames: `{t}` is not a frame number (give A..B, A or all)")
            })
        };
        let r = if s.trim() == "all" {
            Range {
                first: 0,
                last: frames - 1,
            }
        } else if let Some((a, b)) = s.split_once("..") {
            let b = b.strip_prefix('=').unwrap_or(b);
            Range {
                first: num(a)?,
                last: num(b)?,
            }
        } else {
            let f = num(s)?;
            Range { first: f, last: f }
        };
        if r.first > r.last {
            bail!("--frames: {s} is empty (the first frame is after the last)");
        }
        if r.last >= frames {
            bail!(
                "--frames: frame {} does not exist: the scene has {frames} frame{} (0 to {})",
                r.last,
                if frames == 1 { "" } else { "s" },
                frames - 1
            );
        }
        Ok(r)
    }

    /// The frames of the range in order.
    pub fn frames(&self) -> std::ops::RangeInclusive<usize> {
        self.first..=self.last
    }
}

/// Which share of the frames this process runs.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    /// 0-based index.
    pub index: usize,
    /// Number of shards.
    pub count: usize,
    /// Where the figures came from (`--shard`, `SLURM_ARRAY_TASK_ID`, ...).
    pub source: String,
}

impl Shard {
    /// The whole range in one process.
    pub fn single() -> Shard {
        Shard {
            index: 0,
            count: 1,
            source: "one process".into(),
        }
    }

    /// `--shard K/N`, else a Slurm array task's or a Kubernetes indexed
    /// job's place, else the whole range; `env` reads the environment.
    pub fn detect(flag: Option<&str>, env: &dyn Fn(&str) -> Option<String>) -> Result<Shard> {
        let parse = |what: &str, v: &str| -> Result<usize> {
            v.trim()
                .parse::<usize>()
                .with_context(|| format!("{what}: `{v}` is not a whole number"))
        };
        let checked = |index: usize, count: usize, source: String| -> Result<Shard> {
            if count == 0 || index >= count {
                bail!(
                    "{source}: shard {index} of {count} does not exist (shards are 0 to count - 1)"
                );
            }
            Ok(Shard {
                index,
                count,
                source,
            })
        };
        if let Some(f) = flag {
            let (k, n) = f
                .split_once('/')
                .with_context(|| format!("--shard: `{f}` is not K/N (e.g. 0/4)"))?;
            return checked(parse("--shard", k)?, parse("--shard", n)?, "--shard".into());
        }
        if let Some(id) = env("SLURM_ARRAY_TASK_ID") {
            let id = parse("SLURM_ARRAY_TASK_ID", &id)?;
            let min = match env("SLURM_ARRAY_TASK_MIN") {
                Some(m) => parse("SLURM_ARRAY_TASK_MIN", &m)?,
                None => 0,
            };
            let count = match (env("SLURM_ARRAY_TASK_COUNT"), env("SLURM_ARRAY_TASK_MAX")) {
                (Some(c), _) => parse("SLURM_ARRAY_TASK_COUNT", &c)?,
                (None, Some(m)) => parse("SLURM_ARRAY_TASK_MAX", &m)? + 1 - min,
                (None, None) => bail!(
                    "SLURM_ARRAY_TASK_ID is set but neither SLURM_ARRAY_TASK_COUNT nor SLURM_ARRAY_TASK_MAX: give --shard K/N"
                ),
            };
            if id < min {
                bail!("SLURM_ARRAY_TASK_ID {id} is below SLURM_ARRAY_TASK_MIN {min}");
            }
            return checked(id - min, count, "Slurm array (SLURM_ARRAY_TASK_ID)".into());
        }
        if let Some(i) = env("JOB_COMPLETION_INDEX") {
            let i = parse("JOB_COMPLETION_INDEX", &i)?;
            let n = env("EIKON_SHARD_COUNT").with_context(|| {
                "JOB_COMPLETION_INDEX is set but EIKON_SHARD_COUNT is not: set it to the job's completions (docs/CLUSTER.md)"
            })?;
            return checked(
                i,
                parse("EIKON_SHARD_COUNT", &n)?,
                "Kubernetes indexed job (JOB_COMPLETION_INDEX)".into(),
            );
        }
        Ok(Shard::single())
    }

    /// Whether frame `f` of `range` is this shard's.
    pub fn takes(&self, range: &Range, f: usize) -> bool {
        (f - range.first) % self.count == self.index
    }

    /// This shard's manifest file name for `command`'s frames:
    /// `manifest-simulate.json`, `manifest-simulate.1-of-4.json`.
    pub fn manifest_name(&self, command: &str) -> String {
        if self.count == 1 {
            format!("manifest-{command}.json")
        } else {
            format!("manifest-{command}.{}-of-{}.json", self.index, self.count)
        }
    }
}

/// The manifest format.
pub const FORMAT: &str = "eikon-frames";
/// Its version.
pub const VERSION: u32 = 1;

/// What one process of a frame run has done.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Manifest {
    /// [`FORMAT`].
    pub format: String,
    /// [`VERSION`].
    pub version: u32,
    /// The command (`simulate`, `render`, `run`, `export`).
    pub command: String,
    /// The scene file.
    pub scene: String,
    /// CRC-32 of the scene file's text.
    pub scene_hash: String,
    /// The settings that shape the outputs, as one line.
    pub settings: String,
    /// The frames asked for, by every run into this manifest.
    pub ranges: Vec<Range>,
    /// Which of them this process runs.
    pub shard: Shard,
    /// Frames done, in the order done.
    pub done: Vec<FrameRecord>,
    /// Frames that failed, with the error.
    pub failed: Vec<Failure>,
}

/// A finished frame and its files.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FrameRecord {
    /// The frame.
    pub frame: usize,
    /// Its files, named relative to the output folder.
    pub files: Vec<FileRecord>,
    /// What it was made from, beside the scene and settings (the run ids of
    /// the light volumes a render read): when these change the frame is
    /// made again.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub inputs: Vec<String>,
    /// Wall time, seconds.
    pub seconds: f64,
}

/// A frame that failed.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Failure {
    /// The frame.
    pub frame: usize,
    /// The error.
    pub error: String,
}

/// CRC-32 of `bytes`, 8 hex digits.
pub fn hash(bytes: &[u8]) -> String {
    let mut h = crc32fast::Hasher::new();
    h.update(bytes);
    format!("{:08x}", h.finalize())
}

/// The folder of frame `f`'s light volumes in `out`.
pub fn frame_dir(out: &Path, f: usize) -> PathBuf {
    out.join(format!("frame_{f:04}"))
}

/// `path` with `_NNNN` (frame `f`) before its extension: `image.png` ->
/// `image_0007.png`.
pub fn numbered(path: &Path, f: usize) -> PathBuf {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let name = match path.extension() {
        Some(e) => format!("{stem}_{f:04}.{}", e.to_string_lossy()),
        None => format!("{stem}_{f:04}"),
    };
    path.with_file_name(name)
}

/// The `--gif` flag of `render --frames` and `run --frames`.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct GifFlag {
    /// After the frames, an animated GIF of their PNG images (256 colours)
    /// at the animation's fps. Written only once every frame of the range
    /// is done (by whichever shard finishes last), from the PNGs on disk,
    /// so a resumed run writes it too.
    #[arg(long, requires = "frames", value_name = "FILE.gif")]
    pub gif: Option<PathBuf>,
}

impl GifFlag {
    /// Refuse a `--gif` that is not a `.gif` file name, before any work.
    pub fn check(&self) -> Result<()> {
        if let Some(g) = &self.gif {
            let ext = g
                .extension()
                .map(|e| e.to_string_lossy().to_ascii_lowercase());
            if ext.as_deref() != Some("gif") {
                bail!("{}: --gif: give a .gif file name", g.display());
            }
            if g.is_dir() {
                bail!("{}: --gif: is a directory", g.display());
            }
        }
        Ok(())
    }
}

/// What a frame run covers: the scene file, the range asked for, this
/// process's shard of it, and whether `--force` was given.
#[derive(Clone, Debug)]
pub struct Plan {
    /// The scene file.
    pub scene: PathBuf,
    /// Its text, as read (hashed into the manifest).
    pub text: String,
    /// The frames asked for.
    pub range: Range,
    /// This process's share.
    pub shard: Shard,
    /// `--force`.
    pub force: bool,
}

impl Plan {
    /// The range `flags` ask for in `anim` (read from `scene`) and this
    /// process's shard of it.
    pub fn new(
        flags: &FrameFlags,
        scene: &Path,
        anim: &eikon_grid::animation::Animation,
    ) -> Result<Plan> {
        Ok(Plan {
            scene: scene.to_path_buf(),
            text: anim.text().to_string(),
            range: Range::parse(flags.frames.as_deref().unwrap_or("all"), anim.frames)?,
            shard: Shard::detect(flags.shard.as_deref(), &|k| std::env::var(k).ok())?,
            force: flags.force,
        })
    }

    /// This process's share of the work when a frame has `lights` lights:
    /// per frame it visits, the lights it simulates. The units of work are
    /// (frame, light) pairs, frame-major; shard K of N takes every N-th
    /// unit from the K-th. With one light (or one shard) that is every
    /// N-th frame, each whole.
    pub fn units(&self, lights: usize) -> Vec<(usize, Vec<usize>)> {
        let lights = lights.max(1);
        let (k, n) = (self.shard.index, self.shard.count);
        self.range
            .frames()
            .filter_map(|f| {
                let base = (f - self.range.first) * lights;
                let mine: Vec<usize> = (0..lights).filter(|l| (base + l) % n == k).collect();
                (!mine.is_empty()).then_some((f, mine))
            })
            .collect()
    }

    /// The frames this process runs, in order.
    pub fn frames(&self) -> impl Iterator<Item = usize> + '_ {
        self.range
            .frames()
            .filter(|&f| self.shard.takes(&self.range, f))
    }
}

/// The inputs of frame `f` lit by the light folder `lights` (of `eikon
/// simulate --frames`): its `frame_NNNN/` sidecar's run id, so that a frame
/// simulated again is rendered again (nothing when unreadable: the frame is
/// then made again, and reading its volumes says what is wrong).
pub fn light_inputs(lights: &Path, f: usize) -> Vec<String> {
    let dir = frame_dir(lights, f);
    match eikon_wavefront::lightdir::LightDir::open(&dir) {
        Ok(d) => vec![format!("{} run {}", dir.display(), d.sidecar.run_id)],
        Err(_) => Vec::new(),
    }
}

/// Check that the light folder `lights` (of `eikon simulate --frames`)
/// holds a `frame_NNNN/` for each of `frames`, naming the first missing.
pub fn check_light_frames(lights: &Path, frames: impl IntoIterator<Item = usize>) -> Result<()> {
    if !lights.is_dir() {
        bail!(
            "{}: --light: no such folder (with --frames, give the output folder of `eikon simulate SCENE --frames ... -o FOLDER`)",
            lights.display()
        );
    }
    let missing: Vec<usize> = frames
        .into_iter()
        .filter(|&f| !frame_dir(lights, f).is_dir())
        .collect();
    if let Some(&f) = missing.first() {
        bail!(
            "{}: --light: no light volumes for frame {f} ({} frame(s) of the range are missing there): simulate them first (`eikon simulate SCENE --frames ... -o {}`)",
            frame_dir(lights, f).display(),
            missing.len(),
            lights.display()
        );
    }
    Ok(())
}

/// The folder a file is written to: its parent, `.` for a bare name.
pub fn folder_of(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// `path` relative to the folder `base` (lexically), if it lies within
/// (empty when it is `base`).
pub fn relative_to(base: &Path, path: &Path) -> Option<PathBuf> {
    let strip_dot = |p: &Path| -> PathBuf {
        p.components()
            .filter(|c| !matches!(c, std::path::Component::CurDir))
            .collect()
    };
    let (base, path) = (strip_dot(base), strip_dot(path));
    let rel = path.strip_prefix(&base).ok()?.to_path_buf();
    let inside = rel
        .components()
        .all(|c| matches!(c, std::path::Component::Normal(_)));
    inside.then_some(rel)
}

/// A scene's medium across frames: built once and shared when no object
/// moves (only lights and the camera are animated), else built per frame.
pub struct Media {
    reuse: bool,
    kept: Option<std::sync::Arc<eikon_grid::Medium>>,
    quiet: bool,
}

impl Media {
    /// For the frames of `anim`; `quiet` says nothing on stderr.
    pub fn new(anim: &eikon_grid::animation::Animation, quiet: bool) -> Media {
        Media {
            reuse: !anim.moves_medium(),
            kept: None,
            quiet,
        }
    }

    /// The medium of `scene` (a frame of the animation) and a note for the
    /// frame's line (`, medium reused`).
    pub fn of(
        &mut self,
        scene: &eikon_grid::Scene,
    ) -> Result<(std::sync::Arc<eikon_grid::Medium>, &'static str)> {
        if let Some(m) = &self.kept {
            return Ok((m.clone(), ", medium reused"));
        }
        let t = std::time::Instant::now();
        let built = std::sync::Arc::new(crate::output::build_medium(scene)?);
        if self.reuse {
            if !self.quiet {
                eprintln!(
                    "medium built in {:.2} s, reused for every frame (only lights and the camera move)",
                    t.elapsed().as_secs_f64()
                );
            }
            self.kept = Some(built.clone());
        }
        Ok((built, ""))
    }
}

/// The frames of `command`'s manifests in `out` that are done, their files
/// intact (by any shard and any run), in order.
pub fn done_frames(out: &Path, command: &str) -> Result<Vec<usize>> {
    let mut done: Vec<usize> = read_manifests(out)?
        .into_iter()
        .filter(|(_, m)| m.command == command)
        .flat_map(|(_, m)| m.done)
        .filter(|r| intact(out, r))
        .map(|r| r.frame)
        .collect();
    done.sort_unstable();
    done.dedup();
    Ok(done)
}

/// The GIF frame delay for `fps`, in hundredths of a second (at least 1).
pub fn gif_delay(fps: f64) -> u16 {
    (100.0 / fps).round().clamp(1.0, u16::MAX as f64) as u16
}

/// Write an animated GIF of the PNG images `pngs` (all one size) at `fps`,
/// looping, each frame quantized to its own 256-colour palette; atomically.
pub fn write_gif(gif: &Path, pngs: &[PathBuf], fps: f64) -> Result<()> {
    let Some(first) = pngs.first() else {
        bail!("{}: no frames for the GIF", gif.display());
    };
    let (width, height, _) = crate::output::read_rgb8(first)?;
    let side = |v: u32| -> Result<u16> {
        u16::try_from(v).map_err(|_| {
            anyhow::anyhow!(
                "{}: a GIF is at most 65535 pixels a side; the frames are {width} x {height}",
                gif.display()
            )
        })
    };
    let (w, h) = (side(width)?, side(height)?);
    if let Some(dir) = gif.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create the folder", dir.display()))?;
    }
    let failed = |e: gif::EncodingError| {
        anyhow::Error::new(e).context(format!("{}: writing the GIF", gif.display()))
    };
    write_atomic(gif, |out| {
        let mut encoder = gif::Encoder::new(out, w, h, &[]).map_err(failed)?;
        encoder.set_repeat(gif::Repeat::Infinite).map_err(failed)?;
        for png in pngs {
            let (pw, ph, rgb) = crate::output::read_rgb8(png)?;
            if (pw, ph) != (width, height) {
                bail!(
                    "{}: {pw} x {ph}, but the first frame {} is {width} x {height}: a GIF's frames are one size",
                    png.display(),
                    first.display()
                );
            }
            let mut frame = gif::Frame::from_rgb_speed(w, h, &rgb, 10);
            frame.delay = gif_delay(fps);
            encoder.write_frame(&frame).map_err(failed)?;
        }
        encoder
            .into_inner()
            .with_context(|| format!("{}: writing the GIF", gif.display()))?;
        Ok(())
    })
}

/// After a frame run of `command` into `out`: write `gif` from the PNGs
/// `png(f)` of every frame of `range` if all are done, else say which are
/// not (another shard's, or failed) and leave it to the run that finishes
/// them.
pub fn finish_gif(
    gif: &Path,
    out: &Path,
    command: &str,
    range: Range,
    fps: f64,
    png: impl Fn(usize) -> PathBuf,
    quiet: bool,
) -> Result<()> {
    let done = done_frames(out, command)?;
    let missing: Vec<usize> = range.frames().filter(|f| !done.contains(f)).collect();
    if !missing.is_empty() {
        if !quiet {
            eprintln!(
                "note: --gif: frames {} of {}..{} are not done yet (other shards'?): {} is written by the run that finishes them",
                ranges(&missing),
                range.first,
                range.last,
                gif.display()
            );
        }
        return Ok(());
    }
    let pngs: Vec<PathBuf> = range.frames().map(png).collect();
    write_gif(gif, &pngs, fps)?;
    if !quiet {
        eprintln!(
            "wrote {}: {} frames at {fps} fps",
            gif.display(),
            pngs.len()
        );
    }
    Ok(())
}

/// The `; `-separated settings that differ between `was` and `now`, or
/// their difference in words.
fn differences(was: &str, now: &str) -> String {
    let split = |s: &str| -> Vec<String> {
        s.split("; ")
            .flat_map(|part| {
                let inner = part
                    .find(" { ")
                    .filter(|_| part.ends_with(" }"))
                    .map(|i| &part[i + 3..part.len() - 2]);
                match inner {
                    Some(fields) => fields.split(", ").map(str::to_string).collect(),
                    None => vec![part.to_string()],
                }
            })
            .collect()
    };
    let (a, b) = (split(was), split(now));
    let diff: Vec<String> = a
        .iter()
        .zip(&b)
        .filter(|(x, y)| x != y)
        .map(|(x, y)| format!("{x} there, {y} now"))
        .collect();
    if diff.is_empty() || a.len() != b.len() {
        format!("there: {was}; now: {now}")
    } else {
        diff.join("; ")
    }
}

/// Whether every file of `r` (relative to `out`) is there with its size
/// and CRC-32.
fn intact(out: &Path, r: &FrameRecord) -> bool {
    r.files.iter().all(|f| {
        let path = out.join(&f.name);
        std::fs::metadata(&path).is_ok_and(|m| m.len() == f.bytes)
            && FileRecord::of_file(&path).is_ok_and(|now| now.crc32 == f.crc32)
    })
}

/// Every manifest in `out`, by file name.
pub fn read_manifests(out: &Path) -> Result<Vec<(String, Manifest)>> {
    let mut parts = Vec::new();
    let Ok(entries) = std::fs::read_dir(out) else {
        return Ok(parts);
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if !(name.starts_with("manifest-") && name.ends_with(".json")) {
            continue;
        }
        let path = e.path();
        let bytes = match std::fs::read(&path) {
            Ok(b) => b,
            // Removed since listed (another shard's --force).
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(e) => return Err(e).with_context(|| format!("{}: cannot read", path.display())),
        };
        let m: Manifest = serde_json::from_slice(&bytes)
            .with_context(|| format!("{}: not a frame manifest", path.display()))?;
        if m.format != FORMAT || m.version != VERSION {
            bail!(
                "{}: format {} version {} (this eikon reads {FORMAT} version {VERSION})",
                path.display(),
                m.format,
                m.version
            );
        }
        parts.push((name, m));
    }
    parts.sort_by(|a, b| a.0.cmp(&b.0));
    Ok(parts)
}

/// One frame's outputs, as the caller made them.
pub struct Output {
    /// The files written, relative to the output folder.
    pub files: Vec<PathBuf>,
    /// A line about the frame (what was reused, ...).
    pub note: String,
    /// This process did its share of the frame, which waits for other
    /// shards' (its lights, `simulate`): nothing to record yet.
    pub pending: bool,
}

/// A frame run over the frames of `range` this process's `shard` takes,
/// writing under `out`.
pub struct Job {
    out: PathBuf,
    manifest: Manifest,
    range: Range,
    /// A frame's inputs now (see [`FrameRecord::inputs`]).
    inputs: Option<Box<dyn Fn(usize) -> Vec<String>>>,
    /// The frames to visit, when not the shard's own (see [`Plan::units`]).
    visit: Option<Vec<usize>>,
    /// Frames done before this run, found intact (by any shard).
    before: Vec<FrameRecord>,
    quiet: bool,
}

impl Job {
    /// Open the run: refuse an output whose manifests record another scene
    /// or other settings (unless `force`), and find the frames already
    /// done there with their files intact.
    pub fn open(
        out: &Path,
        command: &str,
        plan: &Plan,
        settings: String,
        quiet: bool,
    ) -> Result<Job> {
        let (scene, range, force) = (&plan.scene, plan.range, plan.force);
        let shard = plan.shard.clone();
        if out.exists() && !out.is_dir() {
            bail!("{}: exists and is not a directory", out.display());
        }
        std::fs::create_dir_all(out)
            .with_context(|| format!("{}: cannot create the output directory", out.display()))?;
        let own = shard.manifest_name(command);
        // This shard's manifest, written by a run killed mid-write, left
        // its temporary (other shards' may be in use right now).
        eikon_wavefront::staging::remove_stale_temps(out, |f| f == own);
        let scene_hash = hash(plan.text.as_bytes());
        let mut before = Vec::new();
        let mut ranges = Vec::new();
        let mut carried = Vec::new();
        for (name, m) in read_manifests(out)? {
            // Another command's frames (simulate's beside render's) are
            // its own business.
            if m.command != command {
                continue;
            }
            let changed = if m.scene_hash != scene_hash {
                Some(format!(
                    "was made from another scene ({}, whose text differs from {})",
                    m.scene,
                    scene.display()
                ))
            } else if m.settings != settings {
                Some(format!(
                    "was made with other settings ({})",
                    differences(&m.settings, &settings)
                ))
            } else {
                None
            };
            if let Some(what) = changed {
                if !force {
                    bail!(
                        "{}: {what}: give --force to redo its frames, or another -o",
                        out.join(&name).display()
                    );
                }
                if !quiet {
                    eprintln!("note: --force: the frames of {name} are done again");
                }
                // Shards started together with --force all remove the old
                // manifests: one may find another was quicker.
                match std::fs::remove_file(out.join(&name)) {
                    Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                        return Err(e).with_context(|| {
                            format!("{}: cannot remove", out.join(&name).display())
                        });
                    }
                    _ => {}
                }
                continue;
            }
            let intact: Vec<FrameRecord> = m.done.into_iter().filter(|r| intact(out, r)).collect();
            if name == own {
                ranges = m.ranges;
                // Frames this run does not take stay in its manifest.
                carried = intact
                    .iter()
                    .filter(|r| {
                        !(range.frames().contains(&r.frame) && shard.takes(&range, r.frame))
                    })
                    .cloned()
                    .collect();
            }
            before.extend(intact);
        }
        if !ranges.contains(&range) {
            ranges.push(range);
        }
        if !quiet {
            eprintln!(
                "frames {}..{}: shard {} of {} ({})",
                range.first, range.last, shard.index, shard.count, shard.source
            );
        }
        let manifest = Manifest {
            format: FORMAT.into(),
            version: VERSION,
            command: command.into(),
            scene: scene.display().to_string(),
            scene_hash,
            settings,
            ranges,
            shard,
            done: carried,
            failed: Vec::new(),
        };
        let range_now = range;
        Ok(Job {
            out: out.to_path_buf(),
            manifest,
            range: range_now,
            inputs: None,
            visit: None,
            before,
            quiet,
        })
    }

    /// Visit `frames` instead of the shard's own (a shard of lights visits
    /// every frame holding one of its lights).
    pub fn visit(&mut self, frames: Vec<usize>) {
        self.visit = Some(frames);
    }

    /// The frames this process runs, in order.
    pub fn frames(&self) -> Vec<usize> {
        if let Some(v) = &self.visit {
            return v.clone();
        }
        let r = self.range;
        r.frames()
            .filter(|&f| self.manifest.shard.takes(&r, f))
            .collect()
    }

    /// Track the light volumes of `lights` (`--light`, when given) as each
    /// frame's inputs ([`light_inputs`]).
    pub fn lit_by(&mut self, lights: Option<&Path>) {
        if let Some(l) = lights {
            let l = l.to_path_buf();
            self.track_inputs(move |f| light_inputs(&l, f));
        }
    }

    /// Make each frame's record name its inputs as `inputs` gives them, and
    /// count a frame done only while they are unchanged.
    pub fn track_inputs(&mut self, inputs: impl Fn(usize) -> Vec<String> + 'static) {
        self.inputs = Some(Box::new(inputs));
    }

    /// Run `frame` for every frame of this process not already done, then
    /// record it; a failed frame is recorded and the others still run.
    /// Errors if any frame failed.
    pub fn run(&mut self, mut frame: impl FnMut(usize) -> Result<Output>) -> Result<()> {
        let frames = self.frames();
        let started = std::time::Instant::now();
        let (mut ran, mut skipped, mut shared) = (0usize, 0usize, 0usize);
        for f in frames.iter().copied() {
            let inputs = self.inputs.as_ref().map_or_else(Vec::new, |g| g(f));
            if let Some(r) = self
                .before
                .iter()
                .find(|r| r.frame == f && r.inputs == inputs)
            {
                if !self.manifest.done.iter().any(|x| x.frame == f) {
                    self.manifest.done.push(r.clone());
                }
                skipped += 1;
                continue;
            }
            let t = std::time::Instant::now();
            match frame(f) {
                Ok(o) if o.pending => {
                    shared += 1;
                    if !self.quiet {
                        eprintln!("frame {f}: {}", o.note);
                    }
                }
                Ok(o) => {
                    let files = o
                        .files
                        .iter()
                        .map(|p| {
                            let mut r = FileRecord::of_file(&self.out.join(p))?;
                            r.name = p.to_string_lossy().replace('\\', "/");
                            Ok(r)
                        })
                        .collect::<Result<Vec<_>, eikon_wavefront::staging::Error>>()?;
                    let seconds = t.elapsed().as_secs_f64();
                    self.manifest.done.retain(|x| x.frame != f);
                    self.manifest.done.push(FrameRecord {
                        frame: f,
                        files,
                        inputs,
                        seconds,
                    });
                    self.manifest.failed.retain(|x| x.frame != f);
                    ran += 1;
                    if !self.quiet {
                        eprintln!("frame {f}: {seconds:.2} s{}", o.note);
                    }
                }
                Err(e) => {
                    let error = format!("{e:#}");
                    if !self.quiet {
                        eprintln!("frame {f}: failed: {error}");
                    }
                    self.manifest.failed.push(Failure { frame: f, error });
                }
            }
            self.save()?;
        }
        self.save()?;
        let wall = started.elapsed().as_secs_f64();
        if !self.quiet {
            eprintln!(
                "{ran} frame(s) done in {wall:.1} s ({:.1} frames/min), {skipped} already done, {}{} failed; manifest {}",
                if wall > 0.0 { 60.0 * ran as f64 / wall } else { 0.0 },
                if shared > 0 {
                    format!("{shared} waiting for other shards' lights, ")
                } else {
                    String::new()
                },
                self.manifest.failed.len(),
                self.out
                    .join(self.manifest.shard.manifest_name(&self.manifest.command))
                    .display()
            );
        }
        if let Some(f) = self.manifest.failed.first() {
            bail!(
                "{} frame(s) failed, the first frame {}: {}",
                self.manifest.failed.len(),
                f.frame,
                f.error
            );
        }
        Ok(())
    }

    fn save(&self) -> Result<()> {
        let path = self
            .out
            .join(self.manifest.shard.manifest_name(&self.manifest.command));
        write_atomic(&path, |w| {
            serde_json::to_writer_pretty(&mut *w, &self.manifest)
                .with_context(|| format!("{}: write failed", path.display()))?;
            writeln!(w).with_context(|| format!("{}: write failed", path.display()))
        })
    }
}

/// Arguments of `eikon status`.
#[derive(clap::Args)]
pub struct StatusArgs {
    /// The output folder of a `--frames` run.
    output: PathBuf,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

/// Frames as ranges: `0-3, 7, 9-12`.
fn ranges(frames: &[usize]) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut i = 0;
    while i < frames.len() {
        let mut j = i;
        while j + 1 < frames.len() && frames[j + 1] == frames[j] + 1 {
            j += 1;
        }
        out.push(if i == j {
            frames[i].to_string()
        } else {
            format!("{}-{}", frames[i], frames[j])
        });
        i = j + 1;
    }
    if out.is_empty() {
        "none".into()
    } else {
        out.join(", ")
    }
}

/// Run `eikon status`: the frames done (files intact), missing and failed,
/// over every manifest in the folder. Exits non-zero unless every frame
/// asked for is done.
pub fn status(args: StatusArgs) -> Result<()> {
    let parts = read_manifests(&args.output)?;
    if parts.is_empty() {
        bail!(
            "{}: no frame manifest here (manifest-COMMAND.json): not the output of a --frames run",
            args.output.display()
        );
    }
    let mut commands: Vec<&str> = parts.iter().map(|(_, m)| m.command.as_str()).collect();
    commands.sort_unstable();
    commands.dedup();
    let mut reports = Vec::new();
    let mut incomplete = 0;
    for command in commands {
        let group: Vec<&(String, Manifest)> =
            parts.iter().filter(|(_, m)| m.command == command).collect();
        let (r, left) = command_status(&args.output, &group)?;
        incomplete += left;
        reports.push(r);
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&reports)?);
    } else {
        for r in &reports {
            let list = |k: &str| -> Vec<usize> {
                serde_json::from_value(r[k].clone()).expect("frame numbers")
            };
            println!(
                "{} of {}: {} manifest(s)",
                r["command"].as_str().unwrap_or(""),
                r["scene"].as_str().unwrap_or(""),
                r["manifests"].as_array().map_or(0, Vec::len)
            );
            let done = list("done");
            println!(
                "  done     {} of {}: {}",
                done.len(),
                r["asked"],
                ranges(&done)
            );
            println!("  missing  {}", ranges(&list("missing")));
            println!("  failed   {}", ranges(&list("failed")));
            let damaged = list("damaged");
            if !damaged.is_empty() {
                println!(
                    "  damaged  {} (files changed since; run again to redo)",
                    ranges(&damaged)
                );
            }
            for e in r["errors"].as_array().into_iter().flatten() {
                println!(
                    "  frame {}: {}",
                    e["frame"],
                    e["error"].as_str().unwrap_or("")
                );
            }
        }
    }
    if incomplete > 0 {
        bail!(
            "{}: {incomplete} frame(s) are not done",
            args.output.display()
        );
    }
    Ok(())
}

/// The status of one command's manifests: a JSON report and how many
/// frames asked for are not done.
fn command_status(out: &Path, parts: &[&(String, Manifest)]) -> Result<(serde_json::Value, usize)> {
    let (first_name, first) = parts[0];
    for (name, m) in &parts[1..] {
        if m.scene_hash != first.scene_hash || m.settings != first.settings {
            bail!(
                "{}: {name} records another scene or other settings than {first_name}",
                out.display()
            );
        }
    }
    let mut asked: Vec<usize> = parts
        .iter()
        .flat_map(|(_, m)| m.ranges.iter().flat_map(|r| r.frames()))
        .collect();
    asked.sort_unstable();
    asked.dedup();
    let mut done = Vec::new();
    let mut damaged = Vec::new();
    let mut seconds = 0.0;
    for (_, m) in parts {
        for r in &m.done {
            if intact(out, r) {
                done.push(r.frame);
                seconds += r.seconds;
            } else {
                damaged.push(r.frame);
            }
        }
    }
    done.sort_unstable();
    done.dedup();
    let errors: Vec<&Failure> = parts
        .iter()
        .flat_map(|(_, m)| m.failed.iter())
        .filter(|f| !done.contains(&f.frame))
        .collect();
    let mut failed: Vec<usize> = errors.iter().map(|f| f.frame).collect();
    failed.sort_unstable();
    failed.dedup();
    damaged.retain(|f| !done.contains(f));
    let missing: Vec<usize> = asked
        .iter()
        .copied()
        .filter(|f| !done.contains(f) && !failed.contains(f))
        .collect();
    let left = asked.iter().filter(|f| !done.contains(f)).count();
    Ok((
        serde_json::json!({
            "command": first.command,
            "scene": first.scene,
            "manifests": parts.iter().map(|(n, _)| n).collect::<Vec<_>>(),
            "asked": asked.len(),
            "done": done,
            "missing": missing,
            "failed": failed,
            "damaged": damaged,
            "errors": errors,
            "seconds": seconds,
        }),
        left,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_parse() {
        assert_eq!(
            Range::parse("0..9", 10).unwrap(),
            Range { first: 0, last: 9 }
        );
        assert_eq!(
            Range::parse("3..=5", 10).unwrap(),
            Range { first: 3, last: 5 }
        );
        assert_eq!(Range::parse("4", 10).unwrap(), Range { first: 4, last: 4 });
        assert_eq!(Range::parse("all", 3).unwrap(), Range { first: 0, last: 2 });
        for bad in ["0..10", "5..2", "x", "1..y", "10"] {
            assert!(Range::parse(bad, 10).is_err(), "{bad}");
        }
    }

    #[test]
    fn shards_come_from_the_flag_slurm_or_kubernetes() {
        let none = |_: &str| None;
        assert_eq!(Shard::detect(None, &none).unwrap(), Shard::single());
        let s = Shard::detect(Some("2/5"), &none).unwrap();
        assert_eq!((s.index, s.count), (2, 5));
        for bad in ["5/5", "1", "a/2", "0/0"] {
            assert!(Shard::detect(Some(bad), &none).is_err(), "{bad}");
        }
        let slurm = |k: &str| match k {
            "SLURM_ARRAY_TASK_ID" => Some("7".to_string()),
            "SLURM_ARRAY_TASK_MIN" => Some("4".to_string()),
            "SLURM_ARRAY_TASK_MAX" => Some("7".to_string()),
            _ => None,
        };
        let s = Shard::detect(None, &slurm).unwrap();
        assert_eq!((s.index, s.count), (3, 4));
        assert!(s.source.contains("Slurm"));
        let k8s = |k: &str| match k {
            "JOB_COMPLETION_INDEX" => Some("1".to_string()),
            "EIKON_SHARD_COUNT" => Some("3".to_string()),
            _ => None,
        };
        let s = Shard::detect(None, &k8s).unwrap();
        assert_eq!((s.index, s.count), (1, 3));
        let half = |k: &str| (k == "JOB_COMPLETION_INDEX").then(|| "0".to_string());
        let e = Shard::detect(None, &half).unwrap_err().to_string();
        assert!(e.contains("EIKON_SHARD_COUNT"), "{e}");
        // The flag wins over the environment.
        assert_eq!(Shard::detect(Some("0/2"), &slurm).unwrap().count, 2);
    }

    #[test]
    fn shards_partition_the_range() {
        let r = Range { first: 3, last: 12 };
        for n in 1..5 {
            let mut all: Vec<usize> = (0..n)
                .flat_map(|k| {
                    let s = Shard {
                        index: k,
                        count: n,
                        source: String::new(),
                    };
                    r.frames().filter(move |&f| s.takes(&r, f))
                })
                .collect();
            all.sort_unstable();
            assert_eq!(all, r.frames().collect::<Vec<_>>());
        }
    }

    #[test]
    fn units_partition_frames_and_lights() {
        let range = Range { first: 2, last: 6 };
        for lights in 1..4 {
            for n in 1..5 {
                let mut all: Vec<(usize, usize)> = (0..n)
                    .flat_map(|k| {
                        let plan = Plan {
                            scene: PathBuf::new(),
                            text: String::new(),
                            range,
                            shard: Shard {
                                index: k,
                                count: n,
                                source: String::new(),
                            },
                            force: false,
                        };
                        if lights == 1 {
                            // One light: the shard's own frames, whole.
                            let frames: Vec<usize> = plan.frames().collect();
                            let visited: Vec<usize> =
                                plan.units(1).into_iter().map(|(f, _)| f).collect();
                            assert_eq!(frames, visited);
                        }
                        plan.units(lights)
                            .into_iter()
                            .flat_map(|(f, ls)| ls.into_iter().map(move |l| (f, l)))
                            .collect::<Vec<_>>()
                    })
                    .collect();
                all.sort_unstable();
                let want: Vec<(usize, usize)> = range
                    .frames()
                    .flat_map(|f| (0..lights).map(move |l| (f, l)))
                    .collect();
                assert_eq!(all, want, "{lights} lights, {n} shards");
            }
        }
    }

    #[test]
    fn names() {
        assert_eq!(
            numbered(Path::new("out/image.png"), 7),
            Path::new("out/image_0007.png")
        );
        assert_eq!(numbered(Path::new("x"), 12345), Path::new("x_12345"));
        assert_eq!(frame_dir(Path::new("o"), 3), Path::new("o/frame_0003"));
        assert_eq!(ranges(&[0, 1, 2, 5, 7, 8]), "0-2, 5, 7-8");
        assert_eq!(folder_of(Path::new("image.png")), Path::new("."));
        assert_eq!(folder_of(Path::new("out/image.png")), Path::new("out"));
        let rel = |b: &str, p: &str| relative_to(Path::new(b), Path::new(p));
        assert_eq!(rel(".", "image.png").unwrap(), Path::new("image.png"));
        assert_eq!(rel("out", "./out/npy").unwrap(), Path::new("npy"));
        assert_eq!(rel("out", "out").unwrap(), Path::new(""));
        assert_eq!(rel("/a/b", "/a/b/c/d").unwrap(), Path::new("c/d"));
        assert!(rel("out", "elsewhere/npy").is_none());
        assert!(rel("out", "out/../x").is_none());
    }

    #[test]
    fn gif_delays_follow_the_fps() {
        assert_eq!(gif_delay(10.0), 10);
        assert_eq!(gif_delay(12.0), 8);
        assert_eq!(gif_delay(24.0), 4);
        assert_eq!(gif_delay(1000.0), 1);
        assert_eq!(gif_delay(0.001), u16::MAX);
    }
}
