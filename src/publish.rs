//! Putting a parameters table in service: `<dir>/current.parquet` is what the
//! cell's controller loads. Replacing it must never leave a moment without a valid
//! `current.parquet`, and the one it replaces is kept under a dated name so a
//! rollback is a copy.
//!
//! Order of operations: hard-link the old `current.parquet` to
//! `retired-<date>.parquet` (a copy where links are not supported), then write
//! the new one beside it and rename it over `current.parquet` ([`fsio`]). A crash
//! leaves either the old current (perhaps with its retired twin) or the new one,
//! and perhaps a temporary file, which the next installation removes
//! ([`fsio::sweep`]) before it writes.

use std::io;
use std::path::{Path, PathBuf};

use crate::fsio;
use crate::table::time::date_string;

/// The file a calibration folder's controller reads.
pub const CURRENT: &str = "current.parquet";

/// What an installation did.
#[derive(Debug, Clone, PartialEq)]
pub struct Installed {
    pub current: PathBuf,
    /// Where the replaced table now lives, if there was one.
    pub retired: Option<PathBuf>,
    /// Temporaries of killed installations found in the folder.
    pub swept: fsio::sweep::Swept,
}

/// Installs `bytes` (a parameters table's file) as `dir/current.parquet` on `day`
/// (days since 1970-01-01), retiring the previous one as
/// `retired-YYYY-MM-DD[-N].parquet`. Does nothing but report when the current
/// file already has these bytes. First removes temporaries of dead writers from
/// `dir`.
pub fn install(dir: &Path, bytes: &[u8], day: i64) -> io::Result<Installed> {
    let swept = fsio::sweep::sweep_folder(dir)?;
    let current = dir.join(CURRENT);
    let retired = match std::fs::read(&current) {
        Ok(old) if old == bytes => {
            return Ok(Installed {
                current,
                retired: None,
                swept,
            });
        }
        Ok(_) => {
            let retired = free_name(dir, day);
            if std::fs::hard_link(&current, &retired).is_err() {
                std::fs::copy(&current, &retired)?;
            }
            fsio::sync_dir(dir)?;
            Some(retired)
        }
        Err(e) if e.kind() == io::ErrorKind::NotFound => None,
        Err(e) => return Err(e),
    };
    fsio::write_bytes_atomic(&current, bytes)?;
    Ok(Installed {
        current,
        retired,
        swept,
    })
}

/// `retired-<date>.parquet`, `retired-<date>-2.parquet`, …: the names a day's
/// retired files take, in the order they are taken.
fn retired_names(dir: &Path, day: i64) -> impl Iterator<Item = PathBuf> + '_ {
    let date = date_string(day);
    (1..).map(move |n| match n {
        1 => dir.join(format!("retired-{date}.parquet")),
        n => dir.join(format!("retired-{date}-{n}.parquet")),
    })
}

/// The newest file retired on `day` (`retired-<date>.parquet` or its highest
/// `-N` twin), if any.
pub fn newest_retired(dir: &Path, day: i64) -> Option<PathBuf> {
    retired_names(dir, day).take_while(|p| p.exists()).last()
}

/// The first free retired name of `day`.
fn free_name(dir: &Path, day: i64) -> PathBuf {
    retired_names(dir, day)
        .find(|p| !p.exists())
        .expect("an unbounded sequence of names has a free one")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::table::time::parse_date;

    #[test]
    fn installs_retires_the_previous_and_skips_an_identical_table() {
        let dir = tempfile::tempdir().unwrap();
        let calibration = dir.path().join("robot_a");
        let day = parse_date("2026-11-20").unwrap();

        let first = install(&calibration, b"first", day).unwrap();
        assert_eq!(first.retired, None);
        assert_eq!(std::fs::read(&first.current).unwrap(), b"first");

        let second = install(&calibration, b"second", day).unwrap();
        let retired = second.retired.unwrap();
        assert!(retired.ends_with("retired-2026-11-20.parquet"));
        assert_eq!(std::fs::read(&retired).unwrap(), b"first");
        assert_eq!(std::fs::read(&second.current).unwrap(), b"second");

        let third = install(&calibration, b"third", day).unwrap();
        assert!(
            third
                .retired
                .unwrap()
                .ends_with("retired-2026-11-20-2.parquet")
        );
        // The retired file is a link to the old bytes, not to the new ones.
        assert_eq!(std::fs::read(&retired).unwrap(), b"first");

        // A temporary of a dead writer (pid beyond any real one is never alive).
        let leftover = calibration.join(".current.parquet.4000000000.0.tmp");
        std::fs::write(&leftover, b"torn").unwrap();
        let again = install(&calibration, b"third", day + 1).unwrap();
        assert_eq!(again.retired, None);
        if Path::new("/proc/1/stat").exists() {
            assert_eq!(again.swept.removed, vec![(leftover, 4000000000)]);
        } else {
            std::fs::remove_file(&leftover).unwrap(); // no /proc: the sweep keeps it
        }
        let names: Vec<String> = std::fs::read_dir(&calibration)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names.len(), 3, "{names:?}");
    }
}
