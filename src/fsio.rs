//! Crash-safe file writes: write a temporary file in the target's folder, fsync it,
//! rename it over the target, fsync the folder. A reader (or the next run after a
//! kill) sees the old file or the new one, never a torn one. A kill between the
//! two leaves the temporary file, which [`sweep`] removes later.

pub mod sweep;

use std::fs::{self, File};
use std::io::{self, Write};
use std::path::{Path, PathBuf};

/// Writes `path` atomically with the bytes that `write` produces.
pub fn write_atomic<F>(path: &Path, write: F) -> io::Result<()>
where
    F: FnOnce(&mut File) -> io::Result<()>,
{
    let (dir, tmp) = prepare_dir_and_temp(path)?;
    let result = (|| {
        let mut file = File::create(&tmp)?;
        write(&mut file)?;
        file.flush()?;
        file.sync_all()?;
        fs::rename(&tmp, path)?;
        sync_dir(dir)
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// Writes `bytes` to `path` atomically.
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    write_atomic(path, |f| f.write_all(bytes))
}

/// Writes a new file at `path` (its folder created) and fsyncs its bytes, with
/// no temporary of its own and no sync of its folder: for a file in a private
/// folder that becomes visible only when the whole folder is renamed into
/// place (a cache entry being built), after [`sync_dirs`] on its folders. A
/// stage's tables then cost one fsync each instead of three (issue #31).
pub fn write_unpublished<F>(path: &Path, write: F) -> io::Result<()>
where
    F: FnOnce(&mut File) -> io::Result<()>,
{
    if let Some(dir) = path.parent() {
        fs::create_dir_all(dir)?;
    }
    let mut file = File::create(path)?;
    write(&mut file)?;
    file.flush()?;
    file.sync_all()
}

/// Syncs each folder of `dirs` once (renames and new files in them become
/// durable), however often it is named.
pub fn sync_dirs<'a>(dirs: impl IntoIterator<Item = &'a Path>) -> io::Result<()> {
    let mut seen: Vec<&Path> = Vec::new();
    for dir in dirs {
        if !seen.contains(&dir) {
            sync_dir(dir)?;
            seen.push(dir);
        }
    }
    Ok(())
}

/// Puts a durable file's bytes at `path` atomically: a hard link to `source`
/// where both are on one file system (no copy, no second fsync of the data:
/// a million-row table's was 0.3 s a stage, issue #31), else a copy. The
/// two names then share the bytes, so `source` must never be written in
/// place (cache entries never are: they are verified by hash before reuse).
///
/// It does not sync `path`'s folder but returns it: the caller syncs it once
/// after placing all its files there ([`sync_dirs`]). Until then a crash may
/// leave the old file, never a torn one.
pub fn link_or_copy_unsynced(source: &Path, path: &Path) -> io::Result<PathBuf> {
    let (dir, tmp) = prepare_dir_and_temp(path)?;
    let dir = dir.to_path_buf();
    if fs::hard_link(source, &tmp).is_err() {
        write_bytes_atomic(path, &fs::read(source)?)?;
        return Ok(dir);
    }
    if let Err(e) = fs::rename(&tmp, path) {
        let _ = fs::remove_file(&tmp);
        return Err(e);
    }
    Ok(dir)
}

/// Whether two paths name the same file (one inode, as after
/// [`link_or_copy_unsynced`]).
pub fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (fs::metadata(a), fs::metadata(b)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

/// The folder of `path` (created) and a temporary sibling to rename over it.
fn prepare_dir_and_temp(path: &Path) -> io::Result<(&Path, PathBuf)> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    fs::create_dir_all(dir)?;
    Ok((dir, temp_path(path)))
}

/// Makes a rename or a new file in `dir` durable.
pub fn sync_dir(dir: &Path) -> io::Result<()> {
    File::open(dir)?.sync_all()
}

/// A sibling name unique to this process and call, hidden, ending in `.tmp` so
/// that garbage collection can recognise leftovers of a killed process.
fn temp_path(path: &Path) -> PathBuf {
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    path.with_file_name(format!(".{name}.{}.{n}.tmp", std::process::id()))
}

/// Blake3 of a file's bytes, hex; streams so large logs do not sit in memory.
pub fn hash_file(path: &Path) -> io::Result<String> {
    let mut hasher = blake3::Hasher::new();
    hasher.update_reader(File::open(path)?)?;
    Ok(hasher.finalize().to_hex().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_link_replaces_the_target_shares_the_bytes_and_leaves_no_temp() {
        let dir = tempfile::tempdir().unwrap();
        let source = dir.path().join("cache.bin");
        let target = dir.path().join("out").join("published.bin");
        write_bytes_atomic(&source, b"new").unwrap();
        write_bytes_atomic(&target, b"old").unwrap();
        let folder = link_or_copy_unsynced(&source, &target).unwrap();
        assert_eq!(folder, target.parent().unwrap());
        sync_dirs([folder.as_path()]).unwrap();
        assert_eq!(fs::read(&target).unwrap(), b"new");
        assert!(same_file(&source, &target));
        assert_eq!(fs::read_dir(target.parent().unwrap()).unwrap().count(), 1);
        // Replacing the target later (atomically) leaves the source alone.
        write_bytes_atomic(&target, b"other").unwrap();
        assert_eq!(fs::read(&source).unwrap(), b"new");
        assert!(!same_file(&source, &target));
    }

    #[test]
    fn atomic_write_replaces_and_leaves_no_temp() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.txt");
        write_bytes_atomic(&path, b"one").unwrap();
        write_bytes_atomic(&path, b"two").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"two");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn failed_write_keeps_the_old_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.txt");
        write_bytes_atomic(&path, b"old").unwrap();
        let err = write_atomic(&path, |f| {
            f.write_all(b"partial")?;
            Err(io::Error::other("boom"))
        });
        assert!(err.is_err());
        assert_eq!(fs::read(&path).unwrap(), b"old");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
    }
}
