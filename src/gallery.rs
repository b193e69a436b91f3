//! `eikon gallery`: the pictures in `docs/gallery/`, made by one command,
//! and a check that they still show what the code renders.
//!
//! A manifest (`docs/gallery/gallery.toml`) lists each picture: the `eikon`
//! command that makes it, the image it keeps, and the small settings of its
//! check image. `eikon gallery` runs every command, copies each image into
//! the gallery, then renders each check image and records its pixels' hash
//! and the check image itself (`check/NAME.png`). `eikon gallery --check`
//! renders the check images again and fails when one no longer matches: the
//! code has changed what the gallery shows, and the gallery must be made
//! again.

use crate::output::read_rgb8;
use anyhow::{bail, Context, Result};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// Arguments of `eikon gallery`.
#[derive(clap::Args)]
pub struct Args {
    /// The gallery's manifest.
    #[arg(long, default_value = "docs/gallery/gallery.toml")]
    manifest: PathBuf,
    /// Only render the check images and compare them with the recorded
    /// ones (exit 1 when one differs); the gallery is left as it is.
    #[arg(long)]
    check: bool,
    /// Only these entries (by name; repeat or separate by commas).
    #[arg(long, value_delimiter = ',')]
    only: Vec<String>,
    /// Render and record the check images only, leaving the pictures as
    /// they are (after `eikon gallery` made them and was stopped before it
    /// recorded, or where a change cannot alter what a picture shows).
    #[arg(long, conflicts_with = "check")]
    record_checks: bool,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Manifest {
    /// Directory the commands run in, relative to the manifest.
    root: PathBuf,
    #[serde(rename = "entry")]
    entries: Vec<Entry>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Entry {
    /// The picture's name: `NAME.png` in the manifest's directory.
    name: String,
    /// `eikon` arguments that make it; `-o DIR` is added.
    command: Vec<String>,
    /// The file in DIR that becomes the picture.
    image: String,
    /// Arguments added to `command` for the check image (small grid and
    /// image, the CPU backend).
    check: Vec<String>,
}

/// What a check records per entry: the settings and the hash of the RGB8
/// pixels (FNV-1a, 64 bits).
type Record = BTreeMap<String, CheckRecord>;

#[derive(serde::Serialize, Deserialize, Clone, PartialEq, Debug)]
struct CheckRecord {
    arguments: Vec<String>,
    width: u32,
    height: u32,
    fnv1a64: String,
}

/// A check image whose hash differs still matches when no 8-bit value is
/// more than this many levels off ...
const ROUNDING_LEVELS: u8 = 2;
/// ... and at most this fraction of the values differ at all: the last
/// bits another machine's libm may round otherwise. The stale
/// pictures differed in 2.3% of their values.
const ROUNDING_FRACTION: f64 = 0.002;

/// FNV-1a over `bytes`, 64 bits.
fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// Run `eikon ARGS -o out` in `root`, showing what it prints when `show`;
/// the seconds it took.
fn eikon(root: &Path, args: &[String], out: &Path, show: bool) -> Result<f64> {
    let exe = std::env::current_exe().context("finding the eikon executable")?;
    let t = Instant::now();
    let status = Command::new(exe)
        .current_dir(root)
        .args(args)
        .arg("-o")
        .arg(out)
        .stdout(if show {
            std::process::Stdio::inherit()
        } else {
            std::process::Stdio::null()
        })
        .status()
        .context("running eikon")?;
    if !status.success() {
        bail!("`eikon {}` failed (its messages are above)", args.join(" "));
    }
    Ok(t.elapsed().as_secs_f64())
}

/// `command` with each `--flag value` pair of `check` replacing the same
/// flag's value, or added.
fn merge(command: &[String], check: &[String]) -> Result<Vec<String>> {
    if !check.len().is_multiple_of(2) || check.iter().step_by(2).any(|f| !f.starts_with("--")) {
        bail!("check: expected `--flag value` pairs, got {check:?}");
    }
    let mut args = command.to_vec();
    for pair in check.chunks_exact(2) {
        match args.iter().position(|a| a == &pair[0]) {
            Some(i) if i + 1 < args.len() => args[i + 1] = pair[1].clone(),
            _ => args.extend(pair.iter().cloned()),
        }
    }
    Ok(args)
}

/// Render `e`'s check image into `tmp`: its path and record.
fn check_image(root: &Path, e: &Entry, tmp: &Path) -> Result<(PathBuf, CheckRecord)> {
    let args = merge(&e.command, &e.check).with_context(|| format!("entry {}", e.name))?;
    let out = tmp.join(format!("{}-check", e.name));
    eikon(root, &args, &out, false)?;
    let path = out.join(&e.image);
    let (width, height, rgb) = read_rgb8(&path)?;
    Ok((
        path,
        CheckRecord {
            arguments: args,
            width,
            height,
            fnv1a64: format!("{:016x}", fnv1a64(&rgb)),
        },
    ))
}

/// How two RGB8 images differ: the largest difference of a channel value
/// and the fraction of values that differ at all.
fn difference(a: &[u8], b: &[u8]) -> (u8, f64) {
    let mut worst = 0u8;
    let mut n = 0usize;
    for (x, y) in a.iter().zip(b) {
        let d = x.abs_diff(*y);
        worst = worst.max(d);
        n += (d > 0) as usize;
    }
    (worst, n as f64 / a.len().max(1) as f64)
}

/// Run `eikon gallery`.
pub fn run(args: Args) -> Result<()> {
    let text = std::fs::read_to_string(&args.manifest).with_context(|| {
        format!(
            "{}: cannot read the gallery manifest",
            args.manifest.display()
        )
    })?;
    let manifest: Manifest = toml::from_str(&text)
        .with_context(|| format!("{}: not a gallery manifest", args.manifest.display()))?;
    let dir = args
        .manifest
        .parent()
        .unwrap_or(Path::new("."))
        .to_path_buf();
    let root = dir.join(&manifest.root);
    let record_path = dir.join("check.json");
    let check_dir = dir.join("check");
    for o in &args.only {
        if !manifest.entries.iter().any(|e| &e.name == o) {
            bail!("--only: {}: no entry {o}", args.manifest.display());
        }
    }
    let entries: Vec<&Entry> = manifest
        .entries
        .iter()
        .filter(|e| args.only.is_empty() || args.only.contains(&e.name))
        .collect();
    let tmp = std::env::temp_dir().join(format!("eikon-gallery-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).with_context(|| format!("{}: cannot create", tmp.display()))?;
    let result = if args.check {
        check(&root, &entries, &record_path, &check_dir, &tmp)
    } else {
        make(
            &root,
            (!args.record_checks).then_some(dir.as_path()),
            &entries,
            &record_path,
            &check_dir,
            &tmp,
        )
    };
    let _ = std::fs::remove_dir_all(&tmp);
    result
}

fn read_record(path: &Path) -> Result<Record> {
    match std::fs::read(path) {
        Ok(b) => {
            serde_json::from_slice(&b).with_context(|| format!("{}: unreadable", path.display()))
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Record::new()),
        Err(e) => Err(e).with_context(|| format!("{}: cannot read", path.display())),
    }
}

/// Make every picture of `entries` (into `dir`; none without), then its
/// check image and record.
fn make(
    root: &Path,
    dir: Option<&Path>,
    entries: &[&Entry],
    record_path: &Path,
    check_dir: &Path,
    tmp: &Path,
) -> Result<()> {
    let mut record = read_record(record_path)?;
    std::fs::create_dir_all(check_dir)
        .with_context(|| format!("{}: cannot create", check_dir.display()))?;
    for e in entries {
        if let Some(dir) = dir {
            eprintln!("gallery: {} (eikon {})", e.name, e.command.join(" "));
            let out = tmp.join(&e.name);
            let seconds = eikon(root, &e.command, &out, true)?;
            let picture = dir.join(format!("{}.png", e.name));
            crate::output::copy_atomic(&out.join(&e.image), &picture)?;
            println!("{}: {seconds:.1} s", picture.display());
        }
        let (path, rec) = check_image(root, e, tmp)?;
        crate::output::copy_atomic(&path, &check_dir.join(format!("{}.png", e.name)))?;
        println!("{}: check image {}", e.name, rec.fnv1a64);
        record.insert(e.name.clone(), rec);
        // Recorded as each entry is done: a run stopped later keeps it.
        write_record(record_path, &record)?;
    }
    Ok(())
}

fn write_record(record_path: &Path, record: &Record) -> Result<()> {
    let json = serde_json::to_string_pretty(record)? + "\n";
    crate::output::write_atomic(record_path, |w| {
        w.write_all(json.as_bytes())
            .with_context(|| format!("{}: write failed", record_path.display()))
    })
}

/// Render every check image of `entries` and compare it with the record.
fn check(
    root: &Path,
    entries: &[&Entry],
    record_path: &Path,
    check_dir: &Path,
    tmp: &Path,
) -> Result<()> {
    let record = read_record(record_path)?;
    let mut stale = Vec::new();
    for e in entries {
        let Some(want) = record.get(&e.name) else {
            stale.push(format!("{}: no check image recorded", e.name));
            continue;
        };
        let (path, got) = check_image(root, e, tmp)?;
        if got.arguments != want.arguments {
            stale.push(format!(
                "{}: the manifest's settings changed ({} now, {} recorded)",
                e.name,
                got.arguments.join(" "),
                want.arguments.join(" ")
            ));
        } else if got.fnv1a64 != want.fnv1a64 {
            let diff = match read_rgb8(&check_dir.join(format!("{}.png", e.name))) {
                Ok((w, h, old)) if (w, h) == (got.width, got.height) => {
                    let (_, _, new) = read_rgb8(&path)?;
                    Some(difference(&old, &new))
                }
                _ => None,
            };
            match diff {
                // Another CPU's libm may round a last bit otherwise: a few
                // values a level or two apart are the same picture.
                Some((worst, frac)) if worst <= ROUNDING_LEVELS && frac <= ROUNDING_FRACTION => {
                    println!(
                        "{}: matches within rounding ({:.3}% of values differ, by up to {worst}/255)",
                        e.name,
                        100.0 * frac
                    )
                }
                Some((worst, frac)) => stale.push(format!(
                    "{}: hash {} (recorded {}): {:.2}% of channel values differ, by up to {worst}/255",
                    e.name,
                    got.fnv1a64,
                    want.fnv1a64,
                    100.0 * frac
                )),
                None => stale.push(format!(
                    "{}: hash {} (recorded {}): the recorded check image is missing or of another size",
                    e.name, got.fnv1a64, want.fnv1a64
                )),
            }
        } else {
            println!("{}: matches ({})", e.name, got.fnv1a64);
        }
    }
    if !stale.is_empty() {
        bail!(
            "the gallery no longer shows what this code renders; make it again with `eikon gallery` (or `--only NAME`):\n  {}",
            stale.join("\n  ")
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fnv1a64_known_values() {
        // The published FNV-1a 64 test vectors.
        assert_eq!(fnv1a64(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a64(b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(fnv1a64(b"foobar"), 0x8594_4171_f739_67e8);
    }

    #[test]
    fn check_arguments_replace_or_extend() {
        let v = |a: &[&str]| a.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        let m = merge(
            &v(&["run", "a.toml", "--width", "640"]),
            &v(&["--width", "64", "--samples", "1"]),
        );
        assert_eq!(
            m.unwrap(),
            v(&["run", "a.toml", "--width", "64", "--samples", "1"])
        );
        assert!(merge(&v(&["run"]), &v(&["--width"])).is_err());
        assert!(merge(&v(&["run"]), &v(&["width", "3"])).is_err());
    }

    #[test]
    fn difference_counts_values() {
        assert_eq!(difference(&[1, 2, 3, 4], &[1, 2, 3, 4]), (0, 0.0));
        assert_eq!(difference(&[1, 2, 3, 4], &[1, 9, 3, 3]), (7, 0.5));
    }
}
