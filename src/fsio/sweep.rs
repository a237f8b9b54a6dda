//! Removing what killed egcal processes left behind: the temporary files and
//! folders egcal writes before a rename, recognised by their exact names, which
//! carry the writer's pid.
//!
//! A kill -9 between creating a temporary and renaming it leaves the temporary
//! behind; nothing reads it (readers only open final names), but it takes space
//! and confuses people. A later run removes it once its writer is known to be
//! dead, and never one whose writer is alive (a concurrent egcal on another job
//! sharing a folder: the lock only covers one output folder).
//!
//! Liveness comes from Linux's `/proc`: the writer is dead when `/proc/<pid>` is
//! gone or a zombie, or when the process now holding that pid started after the
//! temporary was last modified (the pid was reused; the writer created the file
//! after it started). Where `/proc` cannot show every process (not Linux, or
//! mounted with `hidepid`), nothing is removed: a leftover is harmless, removing
//! a live writer's file fails its run.
//!
//! The names (see [`atomic_temp_pid`], [`cache_temp_pid`], [`predict_temp_pid`])
//! are matched exactly, numbers in canonical decimal, so a user's own file is not
//! mistaken for one; and only folders egcal writes into are swept.

use std::fs;
use std::io;
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// Linux reports process start times in `USER_HZ` ticks since boot; `USER_HZ` is
/// part of the kernel's user-space ABI, 100 on every architecture Rust targets
/// (it is what `sysconf(_SC_CLK_TCK)` returns), so no libc call is needed.
const TICKS_PER_SECOND: u64 = 100;

/// A writer that seems to have started this much after its temporary's last
/// change still counts as its writer. Covers the coarse file-time clock (a tick)
/// and small steps of the wall clock between the write and the sweep; a larger
/// forward step could remove a live writer's temporary, which makes that run
/// fail cleanly (its rename finds nothing), never corrupts a table.
const CLOCK_SLACK: Duration = Duration::from_secs(2);

/// Leftovers found by one sweep.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Swept {
    /// Removed temporaries and the pid of their dead writer.
    pub removed: Vec<(PathBuf, u32)>,
    /// Temporaries of live processes, left alone.
    pub kept: Vec<(PathBuf, u32)>,
    /// Dead writers' temporaries that could not be removed, with the reason.
    pub failed: Vec<(PathBuf, String)>,
}

/// Names listed in a summary before "and N more".
const LISTED: usize = 5;

impl Swept {
    /// Adds another sweep's findings.
    pub fn extend(&mut self, other: Swept) {
        self.removed.extend(other.removed);
        self.kept.extend(other.kept);
        self.failed.extend(other.failed);
    }

    /// One line for the user ("removed 3 temporary files left by a killed run
    /// (pid 1234): …"), paths relative to `root`; `None` when nothing was found.
    pub fn summary(&self, root: &Path) -> Option<String> {
        let mut parts = Vec::new();
        if !self.removed.is_empty() {
            parts.push(format!(
                "removed {} left by {}: {}",
                files(self.removed.len()),
                killed_runs(&self.removed),
                listed(self.removed.iter().map(|(p, _)| p), root)
            ));
        }
        if !self.failed.is_empty() {
            let reasons = self
                .failed
                .iter()
                .take(LISTED)
                .map(|(p, e)| format!("{} ({e})", relative(p, root)));
            parts.push(format!(
                "could not remove {} left by a killed run: {}",
                files(self.failed.len()),
                reasons.collect::<Vec<_>>().join(", ")
            ));
        }
        if !self.kept.is_empty() {
            let mut pids: Vec<u32> = self.kept.iter().map(|&(_, pid)| pid).collect();
            pids.sort_unstable();
            pids.dedup();
            parts.push(format!(
                "kept {} of running process{} {}",
                files(self.kept.len()),
                if pids.len() == 1 { "" } else { "es" },
                pids.iter()
                    .map(u32::to_string)
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        }
        (!parts.is_empty()).then(|| parts.join("; "))
    }
}

fn files(n: usize) -> String {
    if n == 1 {
        "1 temporary file".into()
    } else {
        format!("{n} temporary files")
    }
}

fn killed_runs(removed: &[(PathBuf, u32)]) -> String {
    let mut pids: Vec<u32> = removed.iter().map(|&(_, pid)| pid).collect();
    pids.sort_unstable();
    pids.dedup();
    let list = pids
        .iter()
        .map(u32::to_string)
        .collect::<Vec<_>>()
        .join(", ");
    if pids.len() == 1 {
        format!("a killed run (pid {list})")
    } else {
        format!("killed runs (pids {list})")
    }
}

fn listed<'a>(paths: impl ExactSizeIterator<Item = &'a PathBuf>, root: &Path) -> String {
    let total = paths.len();
    let mut text: Vec<String> = paths.take(LISTED).map(|p| relative(p, root)).collect();
    if total > LISTED {
        text.push(format!("and {} more", total - LISTED));
    }
    text.join(", ")
}

fn relative(path: &Path, root: &Path) -> String {
    path.strip_prefix(root)
        .unwrap_or(path)
        .display()
        .to_string()
}

/// The writer's pid if `name` is a temporary of [`super::write_atomic`]:
/// `.{name}.{pid}.{n}.tmp`.
pub fn atomic_temp_pid(name: &str) -> Option<u32> {
    let inner = name.strip_prefix('.')?.strip_suffix(".tmp")?;
    let (rest, n) = inner.rsplit_once('.')?;
    let (base, pid) = rest.rsplit_once('.')?;
    if base.is_empty() || !canonical_number(n) {
        return None;
    }
    parse_pid(pid)
}

/// The hidden folder a case is recorded in before its rename to `name`
/// (`egcal test record`): the shape [`atomic_temp_pid`] recognises.
pub fn staging_folder_name(name: &str) -> String {
    format!(".{name}.{}.0.tmp", std::process::id())
}

/// The name of a cache entry under construction (`runner::cache`):
/// `.{key}.{pid}.tmp`. Defined here, beside its parser.
pub fn cache_temp_name(key: &str) -> String {
    format!(".{key}.{}.tmp", std::process::id())
}

/// The writer's pid if `name` is [`cache_temp_name`]'s shape (the key is 64
/// lowercase hex digits).
pub fn cache_temp_pid(name: &str) -> Option<u32> {
    let inner = name.strip_prefix('.')?.strip_suffix(".tmp")?;
    let (key, pid) = inner.split_once('.')?;
    let hex = |b: u8| b.is_ascii_digit() || (b'a'..=b'f').contains(&b);
    if key.len() != 64 || !key.bytes().all(hex) {
        return None;
    }
    parse_pid(pid)
}

/// The work folder of `egcal predict` in the system's temporary folder:
/// `egcal-predict-{pid}`.
pub fn predict_temp_name() -> String {
    format!("egcal-predict-{}", std::process::id())
}

/// The writer's pid if `name` is [`predict_temp_name`]'s shape.
pub fn predict_temp_pid(name: &str) -> Option<u32> {
    parse_pid(name.strip_prefix("egcal-predict-")?)
}

/// The work folder of `egcal test` (the cases' outputs) in the system's
/// temporary folder: `egcal-test-{pid}`.
pub fn test_temp_name() -> String {
    format!("egcal-test-{}", std::process::id())
}

/// The writer's pid if `name` is [`predict_temp_name`]'s or [`test_temp_name`]'s shape.
fn work_folder_pid(name: &str) -> Option<u32> {
    predict_temp_pid(name).or_else(|| parse_pid(name.strip_prefix("egcal-test-")?))
}

/// The pid of any temporary egcal writes inside an output or calibration folder.
fn egcal_temp_pid(name: &str) -> Option<u32> {
    atomic_temp_pid(name).or_else(|| cache_temp_pid(name))
}

/// Decimal digits without a sign or a leading zero, as `format!` writes them.
fn canonical_number(text: &str) -> bool {
    !text.is_empty()
        && text.bytes().all(|b| b.is_ascii_digit())
        && (text == "0" || !text.starts_with('0'))
}

fn parse_pid(text: &str) -> Option<u32> {
    if !canonical_number(text) {
        return None;
    }
    text.parse().ok().filter(|&pid| pid > 0)
}

/// Removes dead writers' temporaries anywhere under `root` but in the folders
/// `except` (not following symbolic links; a live writer's temporary folder is
/// not entered). Costs one directory read per folder and a `stat` per
/// temporary. A missing `root` is an empty sweep.
pub fn sweep_tree(root: &Path, except: &[&Path]) -> io::Result<Swept> {
    sweep(root, Some(except), egcal_temp_pid, None)
}

/// Removes dead writers' temporaries directly in `dir` (a calibration folder).
pub fn sweep_folder(dir: &Path) -> io::Result<Swept> {
    sweep(dir, None, egcal_temp_pid, None)
}

/// Removes `egcal predict` and `egcal test` work folders of dead processes from
/// the system's temporary folder `tmp`; only this user's, as the folder is shared.
pub fn sweep_work_folders(tmp: &Path) -> io::Result<Swept> {
    let Some(uid) = fs::metadata("/proc/self").ok().as_ref().and_then(owner) else {
        return Ok(Swept::default());
    };
    sweep(tmp, None, work_folder_pid, Some(uid))
}

/// `recurse`: descend into sub-folders, but not these; `owner`: only files of
/// this user id are candidates.
fn sweep(
    dir: &Path,
    recurse: Option<&[&Path]>,
    recognise: fn(&str) -> Option<u32>,
    owner: Option<u32>,
) -> io::Result<Swept> {
    let mut swept = Swept::default();
    if let Some(processes) = Processes::visible() {
        let walk = Walk {
            processes,
            recurse,
            recognise,
            owner,
        };
        walk.folder(dir, &mut swept)?;
    }
    Ok(swept)
}

struct Walk<'a> {
    processes: Processes,
    recurse: Option<&'a [&'a Path]>,
    recognise: fn(&str) -> Option<u32>,
    owner: Option<u32>,
}

impl Walk<'_> {
    fn folder(&self, dir: &Path, swept: &mut Swept) -> io::Result<()> {
        let entries = match fs::read_dir(dir) {
            Ok(entries) => entries,
            Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(()),
            Err(e) => return Err(e),
        };
        for entry in entries {
            let entry = entry?;
            let path = entry.path();
            let Some(pid) = entry.file_name().to_str().and_then(self.recognise) else {
                // The folder read says what type an entry is: no `stat` here.
                let descend = self
                    .recurse
                    .is_some_and(|except| !except.contains(&path.as_path()));
                if descend && entry.file_type()?.is_dir() {
                    self.folder(&path, swept)?;
                }
                continue;
            };
            // A temporary may vanish meanwhile (its live writer renames it).
            let metadata = match entry.metadata() {
                Ok(m) => m,
                Err(e) if e.kind() == io::ErrorKind::NotFound => continue,
                Err(e) => return Err(e),
            };
            if self.owner.is_some_and(|uid| owner(&metadata) != Some(uid)) {
                continue;
            }
            if self.processes.wrote(pid, metadata.modified()?) {
                swept.kept.push((path, pid));
                continue;
            }
            let removal = if metadata.is_dir() {
                fs::remove_dir_all(&path)
            } else {
                fs::remove_file(&path)
            };
            match removal {
                Ok(()) => swept.removed.push((path, pid)),
                Err(e) if e.kind() == io::ErrorKind::NotFound => {}
                Err(e) => swept.failed.push((path, e.to_string())),
            }
        }
        Ok(())
    }
}

/// The user id owning a file (`/proc/self`: this process's user).
#[cfg(unix)]
fn owner(metadata: &fs::Metadata) -> Option<u32> {
    use std::os::unix::fs::MetadataExt;
    Some(metadata.uid())
}

/// No user ids here; nor a `/proc`, so nothing is swept anyway.
#[cfg(not(unix))]
fn owner(_: &fs::Metadata) -> Option<u32> {
    None
}

/// Whether process `pid` may still own a file it last changed at `modified`
/// (a lock file, a temp): alive, not a zombie, and not a later process that
/// reused the pid. Where `/proc` cannot tell, only its entry is looked at.
pub fn owner_alive(pid: u32, modified: SystemTime) -> bool {
    match Processes::visible() {
        Some(processes) => processes.wrote(pid, modified),
        None => std::path::Path::new(&format!("/proc/{pid}")).exists(),
    }
}

/// What `/proc` says about processes, when it can see all of them.
struct Processes {
    /// Wall-clock time of boot, whole seconds (rounded down, so start times
    /// computed from it are never later than the true ones).
    boot: SystemTime,
}

impl Processes {
    /// `None` unless `/proc` shows pid 1 (hidden with `hidepid`, absent off
    /// Linux) and the boot time.
    fn visible() -> Option<Processes> {
        fs::metadata("/proc/1/stat").ok()?;
        let stat = fs::read_to_string("/proc/stat").ok()?;
        let seconds = stat
            .lines()
            .find_map(|line| line.strip_prefix("btime "))?
            .trim()
            .parse()
            .ok()?;
        Some(Processes {
            boot: UNIX_EPOCH + Duration::from_secs(seconds),
        })
    }

    /// Whether process `pid` may have written a file last modified at `modified`.
    fn wrote(&self, pid: u32, modified: SystemTime) -> bool {
        match fs::read_to_string(format!("/proc/{pid}/stat")) {
            Ok(stat) => alive_writer(&stat, self.boot, modified),
            Err(e) if e.kind() == io::ErrorKind::NotFound => false,
            // Unreadable for another reason: assume alive, remove nothing.
            Err(_) => true,
        }
    }
}

/// The decision from a `/proc/<pid>/stat` line: alive unless a zombie or
/// started after `modified` (plus [`CLOCK_SLACK`]). An unparsable line counts
/// as alive.
fn alive_writer(stat: &str, boot: SystemTime, modified: SystemTime) -> bool {
    // `pid (comm) state … starttime …`: comm may hold spaces and parentheses,
    // so fields are counted after the last ')'; starttime is field 22, the 20th
    // after it.
    let Some((_, fields)) = stat.rsplit_once(')') else {
        return true;
    };
    let mut fields = fields.split_whitespace();
    let state = fields.next();
    if matches!(state, Some("Z" | "X" | "x")) {
        return false;
    }
    let Some(ticks) = fields.nth(18).and_then(|t| t.parse::<u64>().ok()) else {
        return true;
    };
    let started = boot + Duration::from_millis(ticks * 1000 / TICKS_PER_SECOND);
    started <= modified + CLOCK_SLACK
}

#[cfg(test)]
mod tests {
    use super::*;

    const KEY: &str = "0123456789abcdef0123456789abcdef0123456789abcdef0123456789abcdef";

    #[test]
    fn recognises_exactly_egcal_temp_names() {
        assert_eq!(atomic_temp_pid(".stats.parquet.1234.0.tmp"), Some(1234));
        assert_eq!(atomic_temp_pid(".lock.7.12.tmp"), Some(7));
        let written = super::super::temp_path(Path::new("dir/a.json"));
        let name = written.file_name().unwrap().to_str().unwrap();
        assert_eq!(atomic_temp_pid(name), Some(std::process::id()));
        for not_ours in [
            "stats.parquet.1234.0.tmp",   // not hidden
            ".stats.parquet.1234.0",      // no .tmp
            "..1234.0.tmp",               // no base name
            ".1234.0.tmp",                // no base name
            ".stats.parquet.01234.0.tmp", // leading zero
            ".stats.parquet.1234.00.tmp",
            ".stats.parquet.+12.0.tmp",
            ".stats.parquet.0.0.tmp", // pid 0
            ".stats.parquet.99999999999.0.tmp",
            ".stats.parquet.12a.0.tmp",
            ".notes.tmp",
            ".stats.parquet.1234.tmp",
        ] {
            assert_eq!(atomic_temp_pid(not_ours), None, "{not_ours}");
        }

        assert_eq!(cache_temp_pid(&format!(".{KEY}.42.tmp")), Some(42));
        assert_eq!(
            cache_temp_pid(&cache_temp_name(KEY)),
            Some(std::process::id())
        );
        assert_eq!(cache_temp_pid(&format!(".{}.42.tmp", &KEY[1..])), None);
        assert_eq!(
            cache_temp_pid(&format!(".{}.42.tmp", KEY.to_uppercase())),
            None
        );
        assert_eq!(cache_temp_pid(&format!(".{KEY}.42.0.tmp")), None);
        assert_eq!(atomic_temp_pid(&format!(".{KEY}.42.tmp")), None);

        assert_eq!(predict_temp_pid("egcal-predict-77"), Some(77));
        assert_eq!(
            predict_temp_pid(&predict_temp_name()),
            Some(std::process::id())
        );
        assert_eq!(predict_temp_pid("egcal-predict-"), None);
        assert_eq!(predict_temp_pid("egcal-predict-77.bak"), None);
        assert_eq!(work_folder_pid("egcal-test-77"), Some(77));
        assert_eq!(
            atomic_temp_pid(&staging_folder_name("case")),
            Some(std::process::id())
        );
        assert_eq!(work_folder_pid(&test_temp_name()), Some(std::process::id()));
        assert_eq!(work_folder_pid("egcal-test-077"), None);
    }

    fn stat_line(state: &str, start_ticks: u64) -> String {
        // Fields 3..=21 before starttime; a comm with spaces and parentheses.
        let middle = vec!["0"; 18].join(" ");
        format!("4242 (egcal (x) y) {state} {middle} {start_ticks} 0 0\n")
    }

    #[test]
    fn a_writer_is_alive_only_if_it_started_before_the_write() {
        let boot = UNIX_EPOCH + Duration::from_secs(1_000_000);
        let at = |seconds: u64| boot + Duration::from_secs(seconds);
        // Started 10 s after boot, file written at 60 s: the writer.
        assert!(alive_writer(&stat_line("R", 1000), boot, at(60)));
        assert!(alive_writer(&stat_line("S", 1000), boot, at(10)));
        // Started at 100 s, after the file's last change at 60 s: a reused pid.
        assert!(!alive_writer(&stat_line("S", 10_000), boot, at(60)));
        // Within the clock slack: still counted as the writer.
        assert!(alive_writer(&stat_line("S", 6_150), boot, at(60)));
        // Zombies and dead tasks write nothing.
        assert!(!alive_writer(&stat_line("Z", 1000), boot, at(60)));
        assert!(!alive_writer(&stat_line("X", 1000), boot, at(60)));
        // Unparsable: assume alive.
        assert!(alive_writer("garbage", boot, at(60)));
        assert!(alive_writer("1 (a) S 1 2", boot, at(60)));
    }

    #[test]
    fn this_process_is_alive_and_a_reaped_child_is_dead() {
        let Some(processes) = Processes::visible() else {
            return; // no /proc here: the sweep removes nothing, tested below
        };
        let now = SystemTime::now();
        assert!(processes.wrote(std::process::id(), now));
        // Our own pid on a file older than this process: a previous holder's.
        assert!(!processes.wrote(std::process::id(), UNIX_EPOCH));
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let pid = child.id();
        child.wait().unwrap();
        assert!(!processes.wrote(pid, now));
    }

    #[test]
    fn sweeps_dead_writers_temporaries_and_keeps_live_ones() {
        if Processes::visible().is_none() {
            return;
        }
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let dead = child.id();
        child.wait().unwrap();
        let live = std::process::id();

        let stage = root.join("validate");
        fs::create_dir_all(&stage).unwrap();
        let dead_file = stage.join(format!(".stats.parquet.{dead}.3.tmp"));
        let live_file = stage.join(format!(".stats.parquet.{live}.4.tmp"));
        let user_file = stage.join(format!(".notes.{dead}.tmp"));
        let shard = root.join(".egcal/cache/01");
        let dead_entry = shard.join(format!(".{KEY}.{dead}.tmp"));
        fs::create_dir_all(dead_entry.join("sub")).unwrap();
        for file in [&dead_file, &live_file, &user_file] {
            fs::write(file, b"x").unwrap();
        }
        fs::write(dead_entry.join("sub/t.parquet"), b"x").unwrap();
        // A live pid on a file older than that process: left by a previous holder.
        let reused = root.join(format!(".egcal/state/.a.json.{live}.0.tmp"));
        fs::create_dir_all(reused.parent().unwrap()).unwrap();
        fs::write(&reused, b"x").unwrap();
        fs::File::options()
            .write(true)
            .open(&reused)
            .unwrap()
            .set_modified(UNIX_EPOCH + Duration::from_secs(1))
            .unwrap();

        let swept = sweep_tree(root, &[]).unwrap();
        assert!(!dead_file.exists() && !dead_entry.exists() && !reused.exists());
        assert!(live_file.exists() && user_file.exists());
        assert_eq!(swept.removed.len(), 3, "{swept:?}");
        assert_eq!(swept.kept, vec![(live_file.clone(), live)]);
        let summary = swept.summary(root).unwrap();
        assert!(
            summary.starts_with("removed 3 temporary files left by killed runs (pids "),
            "{summary}"
        );
        assert!(
            summary.contains(&format!("validate/.stats.parquet.{dead}.3.tmp")),
            "{summary}"
        );
        assert!(
            summary.ends_with(&format!("kept 1 temporary file of running process {live}")),
            "{summary}"
        );

        // A calibration folder: only its own level.
        let deep = stage.join(format!("x/.a.{dead}.0.tmp"));
        fs::create_dir_all(deep.parent().unwrap()).unwrap();
        fs::write(&deep, b"x").unwrap();
        fs::write(&dead_file, b"x").unwrap();
        let swept = sweep_folder(&stage).unwrap();
        assert_eq!(swept.removed, vec![(dead_file.clone(), dead)]);
        assert!(deep.exists());
        assert_eq!(
            swept.summary(&stage).unwrap(),
            format!(
                "removed 1 temporary file left by a killed run (pid {dead}): .stats.parquet.{dead}.3.tmp; kept 1 temporary file of running process {live}"
            )
        );
        assert_eq!(
            sweep_tree(&root.join("missing"), &[]).unwrap(),
            Swept::default()
        );
        // A folder left out of a tree sweep.
        let other = root.join("other");
        fs::create_dir_all(&other).unwrap();
        fs::write(&dead_file, b"x").unwrap();
        fs::write(other.join(format!(".a.{dead}.0.tmp")), b"x").unwrap();
        let swept = sweep_tree(root, &[other.as_path()]).unwrap();
        let mut removed: Vec<PathBuf> = swept.removed.into_iter().map(|(p, _)| p).collect();
        removed.sort();
        assert_eq!(removed, vec![dead_file, deep]);
        assert!(other.join(format!(".a.{dead}.0.tmp")).exists());
    }

    #[test]
    fn predict_folders_only() {
        if Processes::visible().is_none() {
            return;
        }
        let dir = tempfile::tempdir().unwrap();
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let dead = child.id();
        child.wait().unwrap();
        let predict = dir.path().join(format!("egcal-predict-{dead}"));
        let other = dir.path().join(format!(".a.{dead}.0.tmp"));
        fs::create_dir_all(&predict).unwrap();
        fs::write(&other, b"x").unwrap();
        let swept = sweep_work_folders(dir.path()).unwrap();
        assert_eq!(swept.removed, vec![(predict.clone(), dead)]);
        assert!(
            other.exists(),
            "not a predict folder: not ours to judge here"
        );
    }
}
