//! The files of one run, written so that a final path only ever holds a
//! complete file of one run: every file goes to a temporary beside its
//! final name (`.NAME.PID.tmp`), is flushed to disk with its size and
//! CRC-32 counted on the way, and only when all are complete are they
//! renamed into place, a sidecar naming them (if any) last. Used by the
//! light-volume folder ([`crate::lightdir`]), `eikon export --npy` and the
//! renderer's images, so the scheme lives in one place.
//!
//! A folder may hold files that are not ours (`eikon run` writes images
//! beside the volumes, users keep their own files there) and a directory
//! cannot be renamed over a non-empty one, so a run is not swapped in as a
//! whole folder. Instead its sidecar carries a fresh run id and every
//! file's size and CRC-32 ([`FileRecord`]); a reader that checks them
//! refuses a folder left half-updated by a killed run.

use std::fs::File;
use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};

/// Test knob: when set, [`Staging::commit`] waits this many milliseconds
/// before each rename, so that crash tests killing a run at random moments
/// land between renames often. Unset in normal use.
pub const RENAME_PAUSE_ENV: &str = "EIKON_TEST_RENAME_PAUSE_MS";

/// A file that cannot be written or read: the file and what is wrong.
#[derive(Debug, thiserror::Error)]
#[error("{}: {message}", path.display())]
pub struct Error {
    /// The file (or folder) concerned.
    pub path: PathBuf,
    /// What is wrong.
    pub message: String,
}

pub(crate) fn err(path: &Path, message: impl Into<String>) -> Error {
    Error {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// One file of a run: its name in the folder, size and CRC-32.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct FileRecord {
    /// File name (no directory part).
    pub name: String,
    /// Size in bytes.
    pub bytes: u64,
    /// CRC-32 (IEEE 802.3, as zlib), 8 lowercase hex digits.
    pub crc32: String,
}

impl FileRecord {
    /// The record of the file at `path` as it is now (readers verify a
    /// file against its sidecar with it; tools and tests that rewrite a
    /// file on purpose reseal it).
    pub fn of_file(path: &Path) -> Result<FileRecord, Error> {
        let mut f = File::open(path).map_err(|e| err(path, format!("cannot read: {e}")))?;
        let mut h = crc32fast::Hasher::new();
        let mut buf = vec![0u8; 1 << 16];
        let mut bytes = 0u64;
        loop {
            let n = f
                .read(&mut buf)
                .map_err(|e| err(path, format!("cannot read: {e}")))?;
            if n == 0 {
                break;
            }
            h.update(&buf[..n]);
            bytes += n as u64;
        }
        Ok(FileRecord {
            name: file_name(path),
            bytes,
            crc32: format!("{:08x}", h.finalize()),
        })
    }
}

pub(crate) fn file_name(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// A fresh run id: 16 hex digits from the clock, the process and a counter.
pub fn new_run_id() -> String {
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64);
    let x = nanos
        ^ (u64::from(std::process::id()) << 40)
        ^ COUNTER
            .fetch_add(1, Ordering::Relaxed)
            .wrapping_mul(eikon_rng::GOLDEN);
    format!("{:016x}", eikon_rng::mix(x))
}

/// A writer that counts and checksums what passes through it.
struct Tally<W> {
    inner: W,
    crc: crc32fast::Hasher,
    bytes: u64,
}

impl<W: Write> Write for Tally<W> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.crc.update(&buf[..n]);
        self.bytes += n as u64;
        Ok(n)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
}

/// The temporary beside `path` that this process writes it through.
fn temp_path(path: &Path) -> PathBuf {
    let name = format!(".{}.{}.tmp", file_name(path), std::process::id());
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.join(name),
        _ => PathBuf::from(name),
    }
}

fn pause_before_rename() {
    if let Some(ms) = std::env::var(RENAME_PAUSE_ENV)
        .ok()
        .and_then(|v| v.parse::<u64>().ok())
    {
        std::thread::sleep(std::time::Duration::from_millis(ms));
    }
}

/// Files of one run written to temporaries, renamed into place together by
/// [`Staging::commit`]; dropped uncommitted, the temporaries are removed.
#[derive(Default)]
pub struct Staging {
    /// Temporary, final path, record.
    staged: Vec<(PathBuf, PathBuf, FileRecord)>,
}

impl Staging {
    /// Nothing staged yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Write the file that will be `path` to a temporary beside it,
    /// flushed to disk; `write` gets a buffered writer. Its record (name,
    /// size, CRC-32) is returned and kept for [`Staging::files`].
    pub fn add<E: std::fmt::Display>(
        &mut self,
        path: &Path,
        write: impl FnOnce(&mut dyn Write) -> Result<(), E>,
    ) -> Result<&FileRecord, Error> {
        if path.file_name().is_none() {
            return Err(err(path, "not a file path"));
        }
        let tmp = temp_path(path);
        let fail = |m: String| err(path, m);
        let result = (|| {
            let file = File::create(&tmp).map_err(|e| fail(format!("cannot create: {e}")))?;
            let mut w = Tally {
                inner: io::BufWriter::new(file),
                crc: crc32fast::Hasher::new(),
                bytes: 0,
            };
            write(&mut w).map_err(|e| fail(format!("write failed: {e:#}")))?;
            let file = w
                .inner
                .into_inner()
                .map_err(|e| fail(format!("write failed: {}", e.error())))?;
            file.sync_all()
                .map_err(|e| fail(format!("write failed: {e}")))?;
            Ok(FileRecord {
                name: file_name(path),
                bytes: w.bytes,
                crc32: format!("{:08x}", w.crc.finalize()),
            })
        })();
        match result {
            Ok(r) => {
                self.staged.push((tmp, path.to_path_buf(), r));
                Ok(&self.staged.last().expect("just pushed").2)
            }
            Err(e) => {
                let _ = std::fs::remove_file(&tmp);
                Err(e)
            }
        }
    }

    /// The records of the files staged so far, in order.
    pub fn files(&self) -> Vec<FileRecord> {
        self.staged.iter().map(|(_, _, r)| r.clone()).collect()
    }

    /// Rename every staged file into place, in the order staged (a sidecar
    /// staged last lands last), and sync the folders they are in. A failed
    /// rename removes the temporaries not yet renamed.
    pub fn commit(mut self) -> Result<(), Error> {
        let staged = std::mem::take(&mut self.staged);
        let mut dirs: Vec<PathBuf> = Vec::new();
        for (n, (tmp, to, _)) in staged.iter().enumerate() {
            pause_before_rename();
            if let Err(e) = std::fs::rename(tmp, to) {
                for (t, _, _) in &staged[n..] {
                    let _ = std::fs::remove_file(t);
                }
                return Err(err(to, format!("cannot move output into place: {e}")));
            }
            let dir = match to.parent() {
                Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
                _ => PathBuf::from("."),
            };
            if !dirs.contains(&dir) {
                dirs.push(dir);
            }
        }
        // The renames themselves reach the disk with their folders.
        for d in dirs {
            if let Ok(d) = File::open(d) {
                let _ = d.sync_all();
            }
        }
        Ok(())
    }
}

impl Drop for Staging {
    fn drop(&mut self) {
        for (t, _, _) in &self.staged {
            let _ = std::fs::remove_file(t);
        }
    }
}

/// After a run is committed into `dir`: remove the files of the run it
/// replaced (`before`, as that run's sidecar named them) that this one
/// did not write again (`kept` says which it did), and the temporaries of
/// runs killed before their renames. Only names `ours` accepts are
/// touched: a user's files stay.
pub fn tidy(
    dir: &Path,
    before: &[String],
    kept: impl Fn(&str) -> bool,
    ours: impl Fn(&str) -> bool,
) {
    for old in before {
        if plain_name(old) && ours(old) && !kept(old) {
            let _ = std::fs::remove_file(dir.join(old));
        }
    }
    remove_stale_temps(dir, ours);
}

/// Remove the temporaries of runs killed before their renames
/// (`.NAME.PID.tmp` in `dir` for the names `ours` accepts). Call it once a
/// run is committed: its own temporaries are renamed by then.
pub fn remove_stale_temps(dir: &Path, ours: impl Fn(&str) -> bool) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name();
        let Some(inner) = name
            .to_str()
            .and_then(|n| n.strip_prefix('.'))
            .and_then(|n| n.strip_suffix(".tmp"))
        else {
            continue;
        };
        if let Some((file, pid)) = inner.rsplit_once('.') {
            if !pid.is_empty() && pid.bytes().all(|b| b.is_ascii_digit()) && ours(file) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
}

/// A file name without any directory part, not hidden (so never one of our
/// temporaries): safe to join to a folder when read from a sidecar.
pub fn plain_name(name: &str) -> bool {
    !name.is_empty()
        && !name.starts_with('.')
        && !name.contains(['/', '\\', '\0'])
        && Path::new(name).file_name().is_some_and(|n| n == name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32_is_zlibs() {
        // zlib.crc32(b"123456789") == 0xcbf43926, the CRC-32 check value.
        let mut h = crc32fast::Hasher::new();
        h.update(b"123456789");
        assert_eq!(h.finalize(), 0xcbf4_3926);
    }

    #[test]
    fn staged_files_appear_only_on_commit_and_match_their_records() {
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("a.bin");
        let b = dir.path().join("sub").join("b.txt");
        std::fs::create_dir_all(b.parent().unwrap()).unwrap();
        std::fs::write(&a, b"old").unwrap();
        let mut s = Staging::new();
        s.add(&a, |w| w.write_all(&[7u8; 1000])).unwrap();
        s.add(&b, |w| w.write_all(b"123456789")).unwrap();
        assert_eq!(std::fs::read(&a).unwrap(), b"old", "renamed before commit");
        assert!(!b.exists());
        let files = s.files();
        s.commit().unwrap();
        assert_eq!(std::fs::read(&a).unwrap(), vec![7u8; 1000]);
        assert_eq!(files[1].crc32, "cbf43926");
        assert_eq!(files[1].bytes, 9);
        for (f, p) in files.iter().zip([&a, &b]) {
            assert_eq!(&FileRecord::of_file(p).unwrap(), f);
        }
        let left: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(left.len(), 2, "temporaries left: {left:?}");
    }

    #[test]
    fn a_failed_or_dropped_run_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("a.bin");
        let b = dir.path().join("b.bin");
        let mut s = Staging::new();
        s.add(&a, |w| w.write_all(b"x")).unwrap();
        let e = s
            .add(&b, |_| Err::<(), _>("encoder gave up"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("b.bin") && e.contains("encoder gave up"), "{e}");
        drop(s);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn stale_temporaries_of_ours_go_others_stay() {
        let dir = tempfile::tempdir().unwrap();
        for n in [
            ".x.npy.123.tmp",
            ".mine.txt.123.tmp",
            ".x.npy.abc.tmp",
            "x.npy",
        ] {
            std::fs::write(dir.path().join(n), b"").unwrap();
        }
        remove_stale_temps(dir.path(), |f| f == "x.npy");
        let mut left: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        assert_eq!(left, [".mine.txt.123.tmp", ".x.npy.abc.tmp", "x.npy"]);
    }
}
