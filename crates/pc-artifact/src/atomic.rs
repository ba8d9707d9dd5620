//! Atomic publication of files: a writer fills a temporary file beside the final one, fsyncs
//! it and renames it over the final name, so a reader sees the old file or the new one, never
//! half of one. Every file pcgi writes goes through here: artifacts ([`crate::ArtifactWriter`]),
//! images, PLY files, reports.
//!
//! Temporary names are `NAME.<pid>.<unique>.tmp`, unique to the process and the write, so two
//! runs writing the same file never share (or delete) each other's temporary file; the last
//! rename wins and both files it could leave are complete. A temporary file left by a killed
//! process is removed by [`remove_stale_temps`] (the stage harness calls it once it holds the
//! output folder's lock). docs/artifacts.md, "Guarantees".

use std::ffi::OsStr;
use std::fs::{self, File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// The suffix of every temporary file.
pub const TMP_SUFFIX: &str = ".tmp";

/// The folder holding `path`, `.` for a bare file name.
pub fn parent_dir(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// A fresh temporary name for a write of `path`: `NAME.<pid>.<unique>.tmp` in the same folder.
pub fn tmp_path(path: &Path) -> io::Result<PathBuf> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path.file_name().ok_or_else(|| {
        io::Error::new(
            io::ErrorKind::InvalidInput,
            "the path names a folder, not a file",
        )
    })?;
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos() as u64)
        .unwrap_or(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let unique = nanos.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ n;
    let mut tmp = name.to_os_string();
    tmp.push(format!(".{}.{unique:016x}{TMP_SUFFIX}", std::process::id()));
    Ok(path.with_file_name(tmp))
}

/// If `file_name` is a temporary name of a write of `name` (`NAME.<pid>.<unique>.tmp`, or the
/// `NAME.tmp` of builds before unique names), the process id that made it (0 for the old form).
pub fn tmp_owner(file_name: &OsStr, name: &OsStr) -> Option<u32> {
    let f = file_name.to_str()?;
    let rest = f.strip_prefix(name.to_str()?)?.strip_suffix(TMP_SUFFIX)?;
    if rest.is_empty() {
        return Some(0);
    }
    let mut parts = rest.strip_prefix('.')?.split('.');
    let pid: u32 = parts.next()?.parse().ok()?;
    let unique = parts.next()?;
    (parts.next().is_none() && unique.len() == 16 && unique.bytes().all(|b| b.is_ascii_hexdigit()))
        .then_some(pid)
}

/// Whether the process `pid` is running (where the platform can tell; elsewhere `false`, so
/// only a caller that holds the folder's lock should act on it).
fn alive(pid: u32) -> bool {
    pid == std::process::id()
        || (cfg!(target_os = "linux") && Path::new(&format!("/proc/{pid}")).exists())
}

/// Removes the temporary files that writes of `path` left behind in processes that are no
/// longer running (killed before their rename). Returns how many it removed. Call it while
/// holding the folder's lock: another pcgi run cannot be writing there then.
pub fn remove_stale_temps(path: &Path) -> io::Result<usize> {
    let Some(name) = path.file_name() else {
        return Ok(0);
    };
    let dir = parent_dir(path);
    let entries = match fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(0),
        Err(e) => return Err(e),
    };
    let mut removed = 0;
    for entry in entries {
        let entry = entry?;
        if !entry.file_type()?.is_file() {
            continue;
        }
        match tmp_owner(&entry.file_name(), name) {
            Some(pid) if !alive(pid) => match fs::remove_file(entry.path()) {
                Ok(()) => removed += 1,
                Err(e) if e.kind() == io::ErrorKind::NotFound => {}
                Err(e) => return Err(e),
            },
            _ => {}
        }
    }
    Ok(removed)
}

/// Publishes a file that a writer must create itself (a library that opens its own file by
/// path: the LAS and E57 writers): `write` fills the fresh temporary path it is given; on
/// success the file is fsynced, renamed over `path` and the folder fsynced (best effort); on
/// failure the temporary file is removed and `path` is as it was.
pub fn publish_with<T>(path: &Path, write: impl FnOnce(&Path) -> io::Result<T>) -> io::Result<T> {
    fs::create_dir_all(parent_dir(path))?;
    let tmp = tmp_path(path)?;
    let published = write(&tmp).and_then(|value| {
        File::open(&tmp)?.sync_all()?;
        fs::rename(&tmp, path)?;
        Ok(value)
    });
    match published {
        Ok(value) => {
            if let Ok(dir) = File::open(parent_dir(path)) {
                let _ = dir.sync_all();
            }
            Ok(value)
        }
        Err(e) => {
            let _ = fs::remove_file(&tmp);
            Err(e)
        }
    }
}

/// A file being written that becomes `path` only on [`AtomicFile::commit`]; dropped without
/// committing, the temporary file is removed and `path` is as it was.
#[derive(Debug)]
pub struct AtomicFile {
    path: PathBuf,
    tmp: PathBuf,
    file: Option<File>,
}

impl AtomicFile {
    /// Creates the parent folders and a fresh temporary file beside `path`.
    pub fn create(path: impl AsRef<Path>) -> io::Result<AtomicFile> {
        let path = path.as_ref().to_path_buf();
        fs::create_dir_all(parent_dir(&path))?;
        let tmp = tmp_path(&path)?;
        let file = OpenOptions::new().write(true).create_new(true).open(&tmp)?;
        Ok(AtomicFile {
            path,
            tmp,
            file: Some(file),
        })
    }

    /// The final path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The temporary file's path (for messages about the write).
    pub fn tmp_path(&self) -> &Path {
        &self.tmp
    }

    /// The temporary file, to write into.
    pub fn file(&mut self) -> &mut File {
        self.file.as_mut().expect("present until commit")
    }

    /// fsyncs the temporary file, renames it over the final path and fsyncs the folder (best
    /// effort: not every platform can). On failure the temporary file is removed.
    pub fn commit(mut self) -> io::Result<()> {
        let file = self.file.as_ref().expect("present until commit");
        file.sync_all()?;
        fs::rename(&self.tmp, &self.path)?;
        // Published: nothing left for `Drop` to remove.
        self.file = None;
        if let Ok(dir) = File::open(parent_dir(&self.path)) {
            let _ = dir.sync_all();
        }
        Ok(())
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if self.file.take().is_some() {
            let _ = fs::remove_file(&self.tmp);
        }
    }
}

/// Writes `bytes` to `path` atomically ([`AtomicFile`]), creating the parent folder.
pub fn write_file_atomically(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let mut f = AtomicFile::create(path)?;
    f.file().write_all(bytes)?;
    f.commit()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temporary_names_are_unique_and_recognised() {
        let p = Path::new("out/a.octree");
        let (a, b) = (tmp_path(p).unwrap(), tmp_path(p).unwrap());
        assert_ne!(a, b);
        let name = OsStr::new("a.octree");
        assert_eq!(
            tmp_owner(a.file_name().unwrap(), name),
            Some(std::process::id())
        );
        assert_eq!(tmp_owner(OsStr::new("a.octree.tmp"), name), Some(0));
        for other in [
            "a.octree",
            "b.octree.1.0000000000000000.tmp",
            "a.octree.x.tmp",
            "a.octree.1.tmp",
        ] {
            assert_eq!(tmp_owner(OsStr::new(other), name), None, "{other}");
        }
        assert!(tmp_path(Path::new("/")).is_err());
        assert_eq!(parent_dir(Path::new("a")), Path::new("."));
        assert_eq!(parent_dir(Path::new("out/a")), Path::new("out"));
    }

    #[test]
    fn stale_temps_of_dead_processes_go_and_live_ones_stay() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("vmap.pcgi");
        let mine = tmp_path(&path).unwrap();
        fs::write(&mine, b"mine").unwrap();
        fs::write(dir.path().join("vmap.pcgi.tmp"), b"old form").unwrap();
        // pid 0 is never a user process.
        fs::write(dir.path().join("vmap.pcgi.0.00000000000000ff.tmp"), b"dead").unwrap();
        fs::write(dir.path().join("other.pcgi.0.00000000000000ff.tmp"), b"x").unwrap();
        assert_eq!(remove_stale_temps(&path).unwrap(), 2);
        assert!(mine.exists());
        assert!(dir
            .path()
            .join("other.pcgi.0.00000000000000ff.tmp")
            .exists());
    }

    #[test]
    fn an_uncommitted_file_leaves_nothing_and_the_old_file_intact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub/image.png");
        write_file_atomically(&path, b"old").unwrap();
        let mut f = AtomicFile::create(&path).unwrap();
        f.file().write_all(b"new, unfinished").unwrap();
        let tmp = f.tmp_path().to_path_buf();
        assert!(tmp.exists());
        drop(f);
        assert!(!tmp.exists());
        assert_eq!(fs::read(&path).unwrap(), b"old");
        assert_eq!(fs::read_dir(dir.path().join("sub")).unwrap().count(), 1);
    }
}
