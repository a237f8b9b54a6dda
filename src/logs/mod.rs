//! Logged measurements: finding the files of a log folder or glob, pruning them by
//! their Hive partitions (`robot_id=…/date=…/`), scanning the rest lazily with the
//! robot and time-window filters pushed down, and sorting out bad data.
//!
//! A cell logs a few tracker checks a day, for years, so the folder grows without
//! bound while a night's re-calibration needs two weeks of one robot: partitions
//! outside the query are never opened, and inside the kept files polars reads only
//! the measurement columns and the rows of the window. Bad data is expected in
//! logs (a half-written file, a NaN from a glitch, a file delivered twice): it is
//! counted per reason and dropped, or fails the scan, as the caller chooses.
//!
//! Besides the contract's required columns, a scan keeps the optional ones
//! that say where a row was measured: the SMR (`target_id`), the carriage on
//! a track (`e1_mm`) and a positioner's axes (`p1_deg`, `p2_deg`). A file
//! without one reads it as null, and a column null in every kept row is
//! left out, so logs of a plain arm scan as before. For a robot on a track
//! (`LogQuery::on_track`) `e1_mm` is required on every row.
//!
//! Symbolic links in a log folder: the log folder itself may be a link, links to
//! files are read as the files, and links to folders are followed, except a link
//! back to the log folder, to a folder above it or to a folder already walked
//! (`.`, `..`, a loop): each folder is read once, by its device and inode, and
//! nothing outside the log folder is reached through a link to an ancestor. Only
//! regular files are opened: a FIFO, socket or device named `*.parquet` is a bad
//! file (it would block a reader forever), and so is a file that cannot be
//! opened (permission denied).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use polars::prelude::*;
use rayon::prelude::*;

use crate::table::schema::{self, JOINT_COLUMNS, POSITION_COLUMNS, WRENCH_COLUMNS};
use crate::table::time::date_string;

pub mod s3;

use s3::{S3Location, S3Settings, S3Store};

/// Where the logs are: a folder or glob on this machine, or an S3 prefix.
#[derive(Debug, Clone, PartialEq)]
pub enum LogSource {
    /// A folder searched recursively for `*.parquet`, or a glob pattern.
    Local(PathBuf),
    /// `s3://bucket/prefix`, listed recursively below the prefix.
    S3 {
        location: S3Location,
        settings: S3Settings,
    },
}

impl LogSource {
    /// `text` as an `s3://` address, else as a path relative to `dir`.
    pub fn parse(text: &str, dir: &Path, settings: &S3Settings) -> Result<LogSource, String> {
        match S3Location::parse(text) {
            Some(location) => Ok(LogSource::S3 {
                location: location?,
                settings: settings.clone(),
            }),
            None => Ok(LogSource::Local(dir.join(text))),
        }
    }
}

impl std::fmt::Display for LogSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LogSource::Local(path) => write!(f, "{}", path.display()),
            LogSource::S3 { location, .. } => write!(f, "{location}"),
        }
    }
}

/// Which rows a scan keeps.
#[derive(Debug, Clone, PartialEq)]
pub struct LogQuery {
    pub source: LogSource,
    pub robot_id: String,
    /// First and last day (day numbers since 1970-01-01, UTC), both included.
    pub first_day: i64,
    pub last_day: i64,
    /// Drop bad files and rows (counting them) instead of failing.
    pub skip_bad_data: bool,
    /// The robot rides a linear track: each row needs its carriage position
    /// (`e1_mm`), or is a bad row.
    pub on_track: bool,
}

/// Why a scan failed.
#[derive(Debug, thiserror::Error)]
pub enum LogError {
    #[error("{source_path}: {message}")]
    Source {
        source_path: String,
        message: String,
    },
    #[error("{file}: {message} (set `bad_data = \"skip\"` to skip bad files)")]
    BadFile { file: String, message: String },
    #[error(
        "{count} logged rows fail the measurements contract, first: {reason} (set `bad_data = \"skip\"` to drop bad rows)"
    )]
    BadRows { count: usize, reason: String },
    #[error("reading the logs: {0}")]
    Polars(#[from] PolarsError),
    /// A setting (or the environment it relies on) that cannot work: bad input,
    /// not a failure of the run. `key` is the setting (`logs`, `s3.endpoint`).
    #[error("setting `{key}`: {message}")]
    Setting { key: String, message: String },
    /// The source cannot be reached as configured (S3 settings or variables, no
    /// credentials): bad input, like [`LogError::Setting`].
    #[error("{source_path}: {message}")]
    Refused {
        source_path: String,
        message: String,
    },
}

impl LogError {
    /// `true` for bad input (a setting, the environment), `false` for a failure
    /// while reading.
    pub fn is_bad_input(&self) -> bool {
        matches!(self, LogError::Setting { .. } | LogError::Refused { .. })
    }
}

/// What a scan found and what it left out, for the stage log and metadata.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ScanReport {
    pub files_found: usize,
    /// Files whose partitions are outside the query; never opened.
    pub files_pruned: usize,
    /// Partition folders outside the query that were never listed (S3).
    pub folders_pruned: usize,
    pub files_read: usize,
    /// Unreadable or mistyped files, with the reason.
    pub bad_files: Vec<(LogFile, String)>,
    /// Rows of the robot in the window before row checks.
    pub rows_in_window: usize,
    /// Dropped rows by reason (`null in x_mm`, `non-finite q3_deg`, `duplicate cw_id`).
    pub dropped_rows: BTreeMap<String, usize>,
    /// Robot ids of the `robot_id=` folders, and, when no row matched, of the
    /// opened files' rows (to explain an empty result).
    pub robots_seen: BTreeSet<String>,
}

/// Rows kept by a scan, in the measurements contract (spec §6), sorted by
/// `measured_at` then `cw_id`, and the report.
#[derive(Debug)]
pub struct LogScan {
    pub measurements: DataFrame,
    /// UTC day (since 1970-01-01) of each kept row, ascending.
    pub days: Vec<i64>,
    pub report: ScanReport,
}

/// Required float columns of a logged row.
fn float_columns() -> impl Iterator<Item = &'static str> {
    JOINT_COLUMNS
        .into_iter()
        .chain(WRENCH_COLUMNS)
        .chain(POSITION_COLUMNS)
}

/// The optional columns a scan keeps when a file has them (module doc), with
/// their types.
fn optional_columns() -> [(&'static str, DataType); 4] {
    [
        ("target_id", DataType::String),
        (schema::TRACK_COLUMN, DataType::Float64),
        (schema::POSITIONER_COLUMNS[0], DataType::Float64),
        (schema::POSITIONER_COLUMNS[1], DataType::Float64),
    ]
}

/// One log file to open.
#[derive(Debug, Clone, PartialEq)]
pub struct LogFile {
    /// Local path or `s3://` URL.
    pub address: String,
    /// Below the log folder (or a glob's literal leading part, or the S3 prefix),
    /// `/`-separated: partitions are read here, and cache keys use it so that the
    /// same logs give the same key wherever they are stored.
    pub relative: String,
    /// The object's ETag (S3 only).
    pub e_tag: Option<String>,
}

/// The log files a query opens, and what partition pruning left out.
#[derive(Debug, Default)]
pub struct Discovered {
    /// Files to open, sorted.
    pub files: Vec<LogFile>,
    /// Files whose Hive partitions contradict the query (local logs).
    pub pruned: usize,
    /// Partition folders that contradict the query, never listed (S3).
    pub folders_pruned: usize,
    /// Robot ids of the `robot_id=` folders seen, kept or not (to explain an
    /// empty result without opening other robots' files).
    pub partition_robots: BTreeSet<String>,
    /// The bucket, for S3 sources.
    pub store: Option<S3Store>,
    /// Files found that cannot be opened (not a regular file, no permission),
    /// with the reason: bad files of the scan, never opened.
    pub unreadable: Vec<(LogFile, String)>,
}

/// How the cache key names a log file's content.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    serde::Serialize,
    serde::Deserialize,
    schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum ContentKey {
    /// The ETag S3 lists (local files: their BLAKE3 hash): no object is read to
    /// decide whether a night is cached.
    #[default]
    Etag,
    /// The BLAKE3 hash of every file's bytes, wherever it is stored: moving logs
    /// between a folder and a bucket keeps the cache, at the price of reading
    /// every object once more per run.
    Content,
}

/// File (relative to the log folder) → content identity, for the cache key.
pub fn content_keys(
    found: &Discovered,
    mode: ContentKey,
) -> Result<BTreeMap<String, String>, LogError> {
    let failed = |file: &LogFile, message: String| LogError::Source {
        source_path: file.address.clone(),
        message,
    };
    let unreadable = found
        .unreadable
        .iter()
        .map(|(file, reason)| Ok((file.relative.clone(), format!("unreadable: {reason}"))));
    found
        .files
        .iter()
        .map(|file| {
            let identity = match (&found.store, mode, &file.e_tag) {
                (None, _, _) => crate::fsio::hash_file(Path::new(&file.address))
                    .map_err(|e| failed(file, e.to_string()))?,
                (Some(_), ContentKey::Etag, Some(tag)) => format!("etag:{}", tag.trim_matches('"')),
                (Some(store), _, _) => {
                    let bytes = store
                        .read(&store_key(store, file))
                        .map_err(|e| failed(file, e))?;
                    blake3::hash(&bytes).to_hex().to_string()
                }
            };
            Ok((file.relative.clone(), identity))
        })
        .chain(unreadable)
        .collect()
}

/// The object key of a file listed from `store`.
fn store_key(store: &S3Store, file: &LogFile) -> String {
    let location = store.location();
    file.address
        .strip_prefix(&format!("s3://{}/", location.bucket))
        .unwrap_or(&file.address)
        .to_string()
}

/// Every `*.parquet` file of the query's source, sorted; the ones whose Hive
/// partitions contradict the query are counted and left out.
pub fn discover(query: &LogQuery) -> Result<Discovered, LogError> {
    match &query.source {
        LogSource::Local(path) => discover_local(path, query),
        LogSource::S3 { location, settings } => discover_s3(location, settings, query),
    }
}

fn discover_local(source: &Path, query: &LogQuery) -> Result<Discovered, LogError> {
    let source_error = |message: String| LogError::Source {
        source_path: source.display().to_string(),
        message,
    };
    let setting = |message: String| LogError::Setting {
        key: "logs".into(),
        message: format!("{}: {message}", source.display()),
    };
    let text = source.to_string_lossy();
    let is_glob = text.contains(['*', '?', '[']);
    let mut files = Vec::new();
    let root: PathBuf = if is_glob {
        source
            .components()
            .take_while(|c| !c.as_os_str().to_string_lossy().contains(['*', '?', '[']))
            .collect()
    } else {
        source.to_path_buf()
    };
    if !is_glob {
        match std::fs::metadata(source) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(setting(
                    "no such folder (expected a log folder, a glob or an s3:// prefix)".into(),
                ));
            }
            Err(e) => return Err(setting(format!("cannot read the log folder: {e}"))),
            Ok(meta) if meta.is_dir() => {
                walk(source, &mut files).map_err(|e| source_error(e.to_string()))?;
            }
            Ok(_) if text.ends_with(".parquet") => files.push(source.to_path_buf()),
            Ok(_) => {
                return Err(setting(
                    "is a file, not a folder (expected a log folder, a glob or an s3:// prefix)"
                        .into(),
                ));
            }
        }
    } else if text.contains("**") {
        // `**` descends any depth: walked with the loop guard, then matched.
        let pattern = glob::Pattern::new(&text).map_err(|e| setting(format!("bad glob: {e}")))?;
        let options = glob::MatchOptions {
            require_literal_separator: true,
            ..glob::MatchOptions::default()
        };
        if root.is_dir() {
            walk(&root, &mut files).map_err(|e| source_error(e.to_string()))?;
        }
        files.retain(|p| pattern.matches_path_with(p, options));
    } else {
        let paths = glob::glob(&text).map_err(|e| setting(format!("bad glob: {e}")))?;
        for path in paths {
            files.push(path.map_err(|e| source_error(e.to_string()))?);
        }
    }
    files.retain(|p| p.extension().is_some_and(|e| e == "parquet"));
    files.sort();
    files.dedup();
    let found = files.len();
    let mut partition_robots = BTreeSet::new();
    let mut kept = Vec::new();
    let mut unreadable = Vec::new();
    for path in files {
        let below = path.strip_prefix(&root).unwrap_or(&path);
        let relative = below
            .components()
            .map(|c| c.as_os_str().to_string_lossy())
            .collect::<Vec<_>>()
            .join("/");
        partition_robots.extend(partition_robot(&relative));
        if partition_matches(&relative, query) {
            let file = LogFile {
                address: path.display().to_string(),
                relative,
                e_tag: None,
            };
            match readable(&path) {
                Ok(()) => kept.push(file),
                Err(reason) => unreadable.push((file, reason)),
            }
        }
    }
    Ok(Discovered {
        pruned: found - kept.len() - unreadable.len(),
        folders_pruned: 0,
        files: kept,
        partition_robots,
        store: None,
        unreadable,
    })
}

/// `Ok` for a regular file this process can open; else why not. Never opens a
/// FIFO (which would block until a writer comes).
fn readable(path: &Path) -> Result<(), String> {
    let meta = std::fs::metadata(path).map_err(|e| format!("cannot open: {e}"))?;
    if !meta.is_file() {
        use std::os::unix::fs::FileTypeExt;
        let kind = meta.file_type();
        let what = if kind.is_dir() {
            "a folder"
        } else if kind.is_fifo() {
            "a FIFO (named pipe)"
        } else if kind.is_socket() {
            "a socket"
        } else if kind.is_block_device() || kind.is_char_device() {
            "a device"
        } else {
            "not a regular file"
        };
        return Err(format!("not a regular file: {what}"));
    }
    std::fs::File::open(path)
        .map(drop)
        .map_err(|e| format!("cannot open: {e}"))
}

fn discover_s3(
    location: &S3Location,
    settings: &S3Settings,
    query: &LogQuery,
) -> Result<Discovered, LogError> {
    let source_error = |message: String| LogError::Source {
        source_path: location.to_string(),
        message,
    };
    let refused = |message: String| LogError::Refused {
        source_path: location.to_string(),
        message,
    };
    let store = S3Store::connect(location, settings).map_err(refused)?;
    let listing = store
        .list(&|segment| segment_matches(segment, query))
        .map_err(|m| match store.found_credentials() {
            true => source_error(m),
            false => refused(m),
        })?;
    let partition_robots = listing
        .folders_seen
        .iter()
        .filter_map(|segment| segment.strip_prefix("robot_id=").map(str::to_string))
        .collect();
    let files: Vec<LogFile> = listing
        .objects
        .into_iter()
        .filter(|object| object.key.ends_with(".parquet"))
        .map(|object| LogFile {
            address: location.url_of(&object.key),
            relative: location.relative(&object.key).to_string(),
            e_tag: object.e_tag,
        })
        .filter(|file| partition_matches(&file.relative, query))
        .collect();
    Ok(Discovered {
        files,
        pruned: 0,
        folders_pruned: listing.folders_pruned,
        partition_robots,
        store: Some(store),
        unreadable: Vec::new(),
    })
}

/// The robot ids of the `robot_id=` folders below a log source (a folder or an S3
/// prefix; the folders of a glob's literal leading part), without entering them.
pub fn partition_robot_ids(source: &LogSource) -> Result<BTreeSet<String>, LogError> {
    let mut ids = BTreeSet::new();
    match source {
        LogSource::Local(path) => {
            let root: PathBuf = path
                .components()
                .take_while(|c| !c.as_os_str().to_string_lossy().contains(['*', '?', '[']))
                .collect();
            find_robot_dirs(&root, 0, &mut ids).map_err(|e| LogError::Source {
                source_path: root.display().to_string(),
                message: e.to_string(),
            })?;
        }
        LogSource::S3 { location, settings } => {
            let refused = |message: String| LogError::Refused {
                source_path: location.to_string(),
                message,
            };
            let store = S3Store::connect(location, settings).map_err(refused)?;
            let listing = store
                .list(&|segment| !segment.starts_with("robot_id=") && !segment.starts_with("date="))
                .map_err(|message| match store.found_credentials() {
                    true => LogError::Source {
                        source_path: location.to_string(),
                        message,
                    },
                    false => refused(message),
                })?;
            ids.extend(
                listing
                    .folders_seen
                    .iter()
                    .filter_map(|s| s.strip_prefix("robot_id=").map(str::to_string)),
            );
        }
    }
    Ok(ids)
}

fn find_robot_dirs(dir: &Path, depth: usize, ids: &mut BTreeSet<String>) -> std::io::Result<()> {
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        let kind = entry.file_type()?;
        // A linked folder counts as a robot's; only real folders are entered
        // (the depth bound keeps even those from looping).
        let linked_dir = kind.is_symlink() && entry.path().is_dir();
        if !kind.is_dir() && !linked_dir {
            continue;
        }
        let name = entry.file_name().to_string_lossy().to_string();
        match name.strip_prefix("robot_id=") {
            Some(id) => {
                ids.insert(id.to_string());
            }
            None if kind.is_dir()
                && depth < 6
                && !name.starts_with("date=")
                && !name.starts_with('.') =>
            {
                find_robot_dirs(&entry.path(), depth + 1, ids)?;
            }
            None => {}
        }
    }
    Ok(())
}

/// Every non-folder entry below `root`, following links to folders except to
/// `root`, its ancestors and folders already walked (see the module doc).
fn walk(root: &Path, files: &mut Vec<PathBuf>) -> std::io::Result<()> {
    use std::os::unix::fs::MetadataExt;
    let identity = |meta: &std::fs::Metadata| (meta.dev(), meta.ino());
    let mut seen = std::collections::HashSet::new();
    // The log folder's ancestors: a link to one of them would leave the folder.
    if let Ok(canonical) = std::fs::canonicalize(root) {
        for ancestor in canonical.ancestors() {
            if let Ok(meta) = std::fs::metadata(ancestor) {
                seen.insert(identity(&meta));
            }
        }
    }
    let mut pending = vec![root.to_path_buf()];
    while let Some(dir) = pending.pop() {
        let named =
            |e: std::io::Error| std::io::Error::new(e.kind(), format!("{}: {e}", dir.display()));
        for entry in std::fs::read_dir(&dir).map_err(named)? {
            let entry = entry.map_err(named)?;
            let path = entry.path();
            let kind = entry.file_type().map_err(named)?;
            let is_dir = if kind.is_symlink() {
                // A dangling link is listed as a file: opening it names the problem.
                std::fs::metadata(&path).is_ok_and(|m| m.is_dir())
            } else {
                kind.is_dir()
            };
            if !is_dir {
                files.push(path);
                continue;
            }
            let meta = std::fs::metadata(&path).map_err(named)?;
            if seen.insert(identity(&meta)) {
                pending.push(path);
            }
        }
    }
    Ok(())
}

/// The robot of a `robot_id=` folder in `relative` (`/`-separated, below the root).
fn partition_robot(relative: &str) -> Option<String> {
    relative
        .split('/')
        .find_map(|part| part.strip_prefix("robot_id=").map(str::to_string))
}

/// False when a `robot_id=` or `date=` folder of the path (relative to the search
/// root) excludes it.
fn partition_matches(relative: &str, query: &LogQuery) -> bool {
    relative.split('/').all(|part| segment_matches(part, query))
}

/// False when one path segment is a `robot_id=` or `date=` partition outside the query.
fn segment_matches(segment: &str, query: &LogQuery) -> bool {
    match segment.split_once('=') {
        Some(("robot_id", id)) => id == query.robot_id,
        Some(("date", date)) => crate::table::time::parse_date(date)
            .is_none_or(|day| (query.first_day..=query.last_day).contains(&day)),
        _ => true,
    }
}

/// Scans `files` (from [`discover`]) for the query's rows.
pub fn scan(query: &LogQuery, found: &Discovered) -> Result<LogScan, LogError> {
    let mut report = ScanReport {
        files_found: found.files.len() + found.pruned,
        files_pruned: found.pruned,
        folders_pruned: found.folders_pruned,
        robots_seen: found.partition_robots.clone(),
        ..ScanReport::default()
    };
    let from_us = query.first_day * 86_400_000_000;
    let to_us = (query.last_day + 1) * 86_400_000_000;
    let mut opened = Vec::new();
    let cloud = found.store.as_ref().map(S3Store::cloud_options);
    report.files_found += found.unreadable.len();
    for (file, message) in &found.unreadable {
        if !query.skip_bad_data {
            return Err(LogError::BadFile {
                file: file.address.clone(),
                message: message.clone(),
            });
        }
        report.bad_files.push((file.clone(), message.clone()));
    }
    // Opened on the threads; a robot's own local files are read whole there
    // (`open`): polars' lazy scans of a 10 000-row night's 14 small files
    // took 20 ms of its 26, reading them 7 ms (issue #31).
    let frames: Vec<Result<LazyFrame, String>> = found
        .files
        .par_iter()
        .map(|file| open(file, partition_robot(&file.relative), cloud.clone()))
        .collect();
    for (file, frame) in found.files.iter().zip(frames) {
        match frame {
            Ok(frame) => {
                opened.push(frame);
                report.files_read += 1;
            }
            Err(message) if query.skip_bad_data => report.bad_files.push((file.clone(), message)),
            Err(message) => {
                return Err(LogError::BadFile {
                    file: file.address.clone(),
                    message,
                });
            }
        }
    }
    let rows = if opened.is_empty() {
        empty_rows()
    } else {
        let all = concat(opened, UnionArgs::default())?;
        let rows = all
            .clone()
            .filter(
                col("robot_id")
                    .eq(lit(query.robot_id.clone()))
                    .and(col("measured_at").gt_eq(lit(from_us)))
                    .and(col("measured_at").lt(lit(to_us))),
            )
            .sort(["measured_at", "cw_id"], SortMultipleOptions::default())
            .collect()?;
        if rows.height() == 0 {
            // Only to explain an empty result: which robots the files do hold.
            let ids = all.select([col("robot_id").unique()]).collect()?;
            report.robots_seen.extend(
                ids.column("robot_id")?
                    .str()?
                    .iter()
                    .flatten()
                    .map(str::to_string),
            );
        }
        rows
    };
    report.rows_in_window = rows.height();
    let rows = drop_bad_rows(rows, query, &mut report)?;
    let rows = without_empty_optional_columns(rows)?;
    let days = rows
        .column("measured_at")?
        .i64()?
        .iter()
        .map(|t| t.unwrap_or_default().div_euclid(86_400_000_000))
        .collect();
    Ok(LogScan {
        measurements: to_contract(rows)?,
        days,
        report,
    })
}

/// A lazy frame of one file's measurement columns (`measured_at` as µs, `robot_id`
/// from the data or else the partition folder's). Reads only the footer, but
/// for a local file of one robot's partition, which it reads whole.
fn open(
    file: &LogFile,
    partition_robot: Option<String>,
    cloud_options: Option<cloud::CloudOptions>,
) -> Result<LazyFrame, String> {
    let not_parquet = |e: PolarsError| format!("not a readable Parquet file: {e}");
    let (frame, schema) = match cloud_options {
        // A local file in a robot's partition folder holds that robot's rows
        // only: read whole, without a query's overhead. Other files (several
        // robots' rows, objects in S3) are scanned, the filter pushed down.
        None if partition_robot.is_some() => {
            let opened =
                std::fs::File::open(&file.address).map_err(|e| format!("cannot open: {e}"))?;
            let df = ParquetReader::new(opened).finish().map_err(not_parquet)?;
            let schema = df.schema().clone();
            (df.lazy(), schema)
        }
        cloud_options => {
            let args = ScanArgsParquet {
                hive_options: HiveOptions {
                    enabled: Some(false),
                    ..HiveOptions::default()
                },
                cloud_options,
                ..ScanArgsParquet::default()
            };
            let path = match &args.cloud_options {
                Some(_) => PlRefPath::new(file.address.as_str()),
                None => {
                    PlRefPath::try_from_path(Path::new(&file.address)).map_err(|e| e.to_string())?
                }
            };
            let mut frame = LazyFrame::scan_parquet(path, args).map_err(|e| e.to_string())?;
            let schema = frame.collect_schema().map_err(not_parquet)?;
            (frame, schema)
        }
    };
    let contract = schema::measurements();
    let mut columns = vec![col("cw_id")];
    for name in std::iter::once("cw_id").chain(float_columns()) {
        let spec = contract.column(name).expect("contract column");
        match schema.get(name) {
            None => return Err(format!("missing required column `{name}`")),
            Some(dtype) if !spec.dtype.accepts(dtype) => {
                return Err(format!(
                    "column `{name}` is {dtype}, expected {}",
                    spec.dtype.polars()
                ));
            }
            Some(_) if name == "cw_id" => {}
            Some(_) => columns.push(col(name)),
        }
    }
    for (name, dtype) in optional_columns() {
        columns.push(match schema.get(name) {
            Some(found) if found == &dtype => col(name),
            Some(found) if dtype == DataType::Float64 && found.is_primitive_numeric() => {
                col(name).cast(DataType::Float64)
            }
            Some(found) => return Err(format!("column `{name}` is {found}, expected {dtype}")),
            None => lit(NULL).cast(dtype).alias(name),
        });
    }
    columns.push(match schema.get("config_id") {
        Some(DataType::Int64) => col("config_id"),
        Some(other) => return Err(format!("column `config_id` is {other}, expected i64")),
        None => lit(NULL).cast(DataType::Int64).alias("config_id"),
    });
    columns.push(match (schema.get("robot_id"), &partition_robot) {
        (Some(DataType::String), _) => col("robot_id"),
        (Some(other), _) => return Err(format!("column `robot_id` is {other}, expected str")),
        (None, Some(id)) => lit(id.clone()).alias("robot_id"),
        (None, None) => {
            return Err("no `robot_id` column and no `robot_id=` partition folder".into());
        }
    });
    let micros_per_unit = match schema.get("measured_at") {
        Some(DataType::Datetime(unit, _)) => match unit {
            TimeUnit::Nanoseconds => -1000,
            TimeUnit::Microseconds => 1,
            TimeUnit::Milliseconds => 1000,
        },
        Some(other) => {
            return Err(format!(
                "column `measured_at` is {other}, expected a timestamp"
            ));
        }
        None => return Err("no `measured_at` column (time windows need it)".into()),
    };
    let physical = col("measured_at").cast(DataType::Int64);
    columns.push(
        match micros_per_unit {
            -1000 => physical / lit(1000i64),
            1 => physical,
            factor => physical * lit(factor as i64),
        }
        .alias("measured_at"),
    );
    Ok(frame.select(columns))
}

fn empty_rows() -> DataFrame {
    let mut columns = vec![Column::new("cw_id".into(), Vec::<i64>::new())];
    columns.extend(float_columns().map(|n| Column::new(n.into(), Vec::<f64>::new())));
    for (name, dtype) in optional_columns() {
        columns.push(Column::new_empty(name.into(), &dtype));
    }
    columns.push(Column::new("config_id".into(), Vec::<i64>::new()));
    columns.push(Column::new("robot_id".into(), Vec::<String>::new()));
    columns.push(Column::new("measured_at".into(), Vec::<i64>::new()));
    crate::table::frame(columns)
}

/// Leaves out the optional columns null in every row.
fn without_empty_optional_columns(mut rows: DataFrame) -> Result<DataFrame, LogError> {
    for (name, _) in optional_columns() {
        if rows.column(name)?.null_count() == rows.height() {
            rows.drop_in_place(name)?;
        }
    }
    Ok(rows)
}

/// Removes rows with a null or non-finite required value (with `e1_mm` on a
/// track) and repeated `cw_id`s (the first, oldest row is kept), counting
/// each row under its first problem.
fn drop_bad_rows(
    rows: DataFrame,
    query: &LogQuery,
    report: &mut ScanReport,
) -> Result<DataFrame, LogError> {
    let skip = query.skip_bad_data;
    let height = rows.height();
    let mut reason: Vec<Option<String>> = vec![None; height];
    let ids = rows.column("cw_id")?.i64()?.clone();
    let times = rows.column("measured_at")?.i64()?.clone();
    for (row, (id, time)) in ids.iter().zip(times.iter()).enumerate() {
        if id.is_none() {
            reason[row] = Some("null cw_id".into());
        } else if time.is_none() {
            reason[row] = Some("null measured_at".into());
        }
    }
    let track = query.on_track.then_some(schema::TRACK_COLUMN);
    for name in float_columns().chain(track) {
        let values = rows.column(name)?.f64()?.clone();
        for (row, value) in values.iter().enumerate() {
            if reason[row].is_some() {
                continue;
            }
            reason[row] = match value {
                None => Some(format!("null {name}")),
                Some(v) if !v.is_finite() => Some(format!("non-finite {name}")),
                Some(_) => None,
            };
        }
    }
    let mut seen = std::collections::HashSet::new();
    for (row, id) in ids.iter().enumerate() {
        if let (None, Some(id)) = (&reason[row], id)
            && !seen.insert(id)
        {
            reason[row] = Some("duplicate cw_id".into());
        }
    }
    let bad: Vec<(usize, &String)> = reason
        .iter()
        .enumerate()
        .filter_map(|(row, r)| r.as_ref().map(|r| (row, r)))
        .collect();
    if let Some((row, first)) = bad.first()
        && !skip
    {
        let id = ids.get(*row).map_or("null".into(), |id| id.to_string());
        let day = times
            .get(*row)
            .map_or("?".into(), |t| date_string(t.div_euclid(86_400_000_000)));
        return Err(LogError::BadRows {
            count: bad.len(),
            reason: format!("{first} (cw_id {id}, logged {day})"),
        });
    }
    for (_, r) in &bad {
        *report.dropped_rows.entry((*r).clone()).or_default() += 1;
    }
    let keep: BooleanChunked = reason.iter().map(|r| Some(r.is_none())).collect();
    Ok(rows.filter(&keep)?)
}

/// `measured_at` back to a UTC µs timestamp, as in the measurements contract.
fn to_contract(mut rows: DataFrame) -> Result<DataFrame, LogError> {
    let stamps = rows.column("measured_at")?.cast(&DataType::Datetime(
        TimeUnit::Microseconds,
        Some(TimeZone::UTC),
    ))?;
    rows.replace("measured_at", stamps)?;
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn query(robot: &str) -> LogQuery {
        LogQuery {
            source: LogSource::Local(PathBuf::from("logs")),
            robot_id: robot.into(),
            first_day: crate::table::time::parse_date("2026-11-08").unwrap(),
            last_day: crate::table::time::parse_date("2026-11-21").unwrap(),
            skip_bad_data: true,
            on_track: false,
        }
    }

    #[test]
    fn partitions_outside_the_query_are_pruned() {
        let q = query("r1");
        let keeps = |p: &str| partition_matches(p, &q);
        assert!(keeps("logs/robot_id=r1/date=2026-11-08/a.parquet"));
        assert!(keeps("logs/robot_id=r1/date=2026-11-21/a.parquet"));
        assert!(!keeps("logs/robot_id=r1/date=2026-11-22/a.parquet"));
        assert!(!keeps("logs/robot_id=r1/date=2026-11-07/a.parquet"));
        assert!(!keeps("logs/robot_id=r2/date=2026-11-10/a.parquet"));
        // Not partitioned, or an unparsable date: opened and filtered by the data.
        assert!(keeps("logs/2026/a.parquet"));
        assert!(keeps("logs/robot_id=r1/date=latest/a.parquet"));
    }

    #[test]
    fn folders_above_the_log_folder_never_prune() {
        let dir = tempfile::tempdir().unwrap();
        let logs = dir.path().join("date=2020-01-01/robot_id=old/logs");
        for part in ["robot_id=r1/date=2026-11-10", "robot_id=r2/date=2026-11-10"] {
            std::fs::create_dir_all(logs.join(part)).unwrap();
            std::fs::write(logs.join(part).join("a.parquet"), b"").unwrap();
        }
        for source in [logs.clone(), logs.join("*/*/*.parquet")] {
            let found = discover(&LogQuery {
                source: LogSource::Local(source),
                ..query("r1")
            })
            .unwrap();
            assert_eq!(
                found.files[0].relative,
                "robot_id=r1/date=2026-11-10/a.parquet"
            );
            assert_eq!(found.files.len(), 1, "{found:?}");
            assert_eq!(found.pruned, 1);
            let robots: Vec<&str> = found.partition_robots.iter().map(String::as_str).collect();
            assert_eq!(robots, ["r1", "r2"]);
        }
    }

    #[test]
    fn links_to_the_folder_or_above_are_not_followed() {
        let dir = tempfile::tempdir().unwrap();
        let logs = dir.path().join("logs");
        for part in ["robot_id=r1/date=2026-11-10", "robot_id=r1/date=2026-11-11"] {
            std::fs::create_dir_all(logs.join(part)).unwrap();
            std::fs::write(logs.join(part).join("a.parquet"), b"").unwrap();
        }
        std::fs::create_dir_all(dir.path().join("other")).unwrap();
        std::fs::write(dir.path().join("other/b.parquet"), b"").unwrap();
        for (name, target) in [("here", "."), ("again", "."), ("up", "..")] {
            std::os::unix::fs::symlink(target, logs.join(name)).unwrap();
        }
        std::os::unix::fs::symlink("../..", logs.join("robot_id=r1/date=2026-11-11/top")).unwrap();
        // A linked folder elsewhere is followed, once.
        std::fs::create_dir_all(dir.path().join("disk2/date=2026-11-12")).unwrap();
        std::fs::write(dir.path().join("disk2/date=2026-11-12/c.parquet"), b"").unwrap();
        std::os::unix::fs::symlink(dir.path().join("disk2"), logs.join("robot_id=r1/more"))
            .unwrap();
        std::os::unix::fs::symlink(dir.path().join("disk2"), logs.join("robot_id=r1/same"))
            .unwrap();
        let found = discover(&LogQuery {
            source: LogSource::Local(logs),
            ..query("r1")
        })
        .unwrap();
        let files: Vec<&str> = found.files.iter().map(|f| f.relative.as_str()).collect();
        assert_eq!(files.len(), 3, "{files:?}");
        assert!(files.contains(&"robot_id=r1/date=2026-11-10/a.parquet"));
        assert!(files.contains(&"robot_id=r1/date=2026-11-11/a.parquet"));
        assert!(
            files
                .iter()
                .any(|f| f.ends_with("date=2026-11-12/c.parquet"))
        );
    }

    #[test]
    fn partition_dates_need_four_digit_years() {
        assert!(crate::table::time::parse_date("2026-11-10").is_some());
        for bad in [
            "99999999999-01-01",
            "2026-1-10",
            "2026-02-30",
            "+026-11-10",
            "",
        ] {
            assert!(crate::table::time::parse_date(bad).is_none(), "{bad}");
        }
    }
}
