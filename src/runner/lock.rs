//! One run per output folder at a time: a lock file holding the owner's pid,
//! created exclusively. A lock left by a process that no longer exists (killed,
//! Ctrl-C), or whose pid a later process reuses, is taken over with a message
//! instead of blocking the next run forever.

use std::fs::{self, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Held for the duration of a run; removed on drop.
#[derive(Debug)]
pub struct RunLock {
    path: PathBuf,
}

#[derive(Debug, thiserror::Error)]
pub enum LockError {
    #[error("another egcal run (pid {pid}) is using {dir}; wait for it or stop it")]
    Held { pid: u32, dir: PathBuf },
    #[error("cannot create lock file {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

impl RunLock {
    /// Takes the lock in `dir`; `on_stale` is told about a taken-over stale lock.
    pub fn acquire(dir: &Path, on_stale: impl Fn(&str)) -> Result<RunLock, LockError> {
        let path = dir.join("lock");
        let io = |source| LockError::Io {
            path: path.clone(),
            source,
        };
        fs::create_dir_all(dir).map_err(io)?;
        for _ in 0..3 {
            match OpenOptions::new().write(true).create_new(true).open(&path) {
                Ok(mut file) => {
                    writeln!(file, "{}", std::process::id()).map_err(io)?;
                    file.sync_all().map_err(io)?;
                    return Ok(RunLock { path });
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    let owner = fs::read_to_string(&path).unwrap_or_default();
                    let written = fs::metadata(&path)
                        .and_then(|m| m.modified())
                        .unwrap_or_else(|_| std::time::SystemTime::now());
                    match owner.trim().parse::<u32>() {
                        Ok(pid)
                            if pid != std::process::id()
                                && crate::fsio::sweep::owner_alive(pid, written) =>
                        {
                            return Err(LockError::Held {
                                pid,
                                dir: dir.to_path_buf(),
                            });
                        }
                        _ => {
                            on_stale(&format!(
                                "taking over a stale lock {} (its owner, pid {}, is no longer running)",
                                path.display(),
                                owner.trim()
                            ));
                            let _ = fs::remove_file(&path);
                        }
                    }
                }
                Err(e) => return Err(io(e)),
            }
        }
        Err(LockError::Io {
            path: path.clone(),
            source: std::io::Error::other("lock contended"),
        })
    }
}

impl Drop for RunLock {
    fn drop(&mut self) {
        let _ = fs::remove_file(&self.path);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::cell::RefCell;

    #[test]
    fn second_acquire_fails_while_held_and_stale_lock_is_taken_over() {
        let dir = tempfile::tempdir().unwrap();
        let lock = RunLock::acquire(dir.path(), |_| {}).unwrap();
        // Same process: treat our own pid as re-entrant only via a fresh file.
        drop(lock);
        assert!(!dir.path().join("lock").exists());

        // A lock from a pid that cannot exist.
        fs::write(dir.path().join("lock"), "4000000000\n").unwrap();
        let messages = RefCell::new(Vec::new());
        let _lock =
            RunLock::acquire(dir.path(), |m| messages.borrow_mut().push(m.to_string())).unwrap();
        assert!(messages.borrow()[0].contains("stale lock"));

        // A lock held by a live process (pid 1 always exists).
        let other = tempfile::tempdir().unwrap();
        fs::write(other.path().join("lock"), "1\n").unwrap();
        let err = RunLock::acquire(other.path(), |_| {}).unwrap_err();
        assert!(err.to_string().contains("pid 1"), "{err}");
    }

    #[test]
    fn a_lock_older_than_its_pid_s_process_was_left_by_another_one() {
        if !Path::new("/proc/1/stat").exists() {
            return; // no /proc: only the pid's existence is known
        }
        // Pid 1 exists, but it started after 1970: the lock's writer had the pid
        // before it was reused.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("lock");
        fs::write(&path, "1\n").unwrap();
        fs::File::options()
            .write(true)
            .open(&path)
            .unwrap()
            .set_modified(std::time::UNIX_EPOCH + std::time::Duration::from_secs(1000))
            .unwrap();
        let messages = RefCell::new(Vec::new());
        let _lock =
            RunLock::acquire(dir.path(), |m| messages.borrow_mut().push(m.to_string())).unwrap();
        assert!(messages.borrow()[0].contains("stale lock"));
    }
}
