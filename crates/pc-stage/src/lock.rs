//! One run at a time per output folder: an advisory lock on the folder itself, held while a
//! stage checks whether it is up to date, works and publishes, and released when the process
//! ends (however it ends: the operating system drops the lock of a killed process).
//!
//! A second run on the same folder waits, after saying so. Readers take no lock: artifacts are
//! replaced by an atomic rename, so a reader sees the old file or the new one. Under the lock,
//! temporary files of runs that were killed before their rename are removed (docs/artifacts.md,
//! "Guarantees"). Where a folder cannot be opened as a file (Windows), a `.pcgi.lock` file in it
//! takes the folder's place.

use std::fs::{File, OpenOptions, TryLockError};
use std::io;
use std::path::{Path, PathBuf};

/// The lock file's name inside an output folder, where the folder itself cannot be locked.
pub const LOCK_FILE: &str = ".pcgi.lock";

/// The held lock of one output folder; dropping it releases the lock.
#[derive(Debug)]
pub struct OutputLock {
    _file: File,
    path: PathBuf,
}

impl OutputLock {
    /// Takes the lock of the folder that holds `output` (creating the folder), waiting while
    /// another run holds it; `waiting` hears of the wait (with what is locked) before it.
    pub fn acquire(output: &Path, waiting: impl FnOnce(&Path)) -> io::Result<OutputLock> {
        let dir = pc_artifact::atomic::parent_dir(output);
        if dir.exists() && !dir.is_dir() {
            return Err(io::Error::new(
                io::ErrorKind::AlreadyExists,
                format!("{} is a file, not a folder", dir.display()),
            ));
        }
        std::fs::create_dir_all(dir)?;
        let (file, path) = match File::open(dir) {
            Ok(f) => (f, dir.to_path_buf()),
            Err(_) => {
                let path = dir.join(LOCK_FILE);
                let f = OpenOptions::new()
                    .write(true)
                    .create(true)
                    .truncate(false)
                    .open(&path)?;
                (f, path)
            }
        };
        match file.try_lock() {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => {
                waiting(&path);
                file.lock()?;
            }
            Err(TryLockError::Error(e)) => return Err(e),
        }
        Ok(OutputLock { _file: file, path })
    }

    /// What is locked: the folder (or its lock file).
    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_lock_waits_for_the_first_and_nothing_is_left_behind() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("sub/vmap.pcgi");
        let first = OutputLock::acquire(&out, |_| panic!("nobody holds it yet")).unwrap();
        assert!(first.path().ends_with("sub"));
        let (tx, rx) = std::sync::mpsc::channel();
        let out2 = out.clone();
        let t = std::thread::spawn(move || {
            let second = OutputLock::acquire(&out2, |locked| {
                tx.send(locked.to_path_buf()).unwrap();
            })
            .unwrap();
            drop(second);
        });
        assert!(rx.recv().unwrap().ends_with("sub"));
        drop(first);
        t.join().unwrap();
        assert_eq!(
            std::fs::read_dir(dir.path().join("sub")).unwrap().count(),
            0
        );
    }
}
