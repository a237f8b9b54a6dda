//! Runs a [`Plan`]: stages in dependency order, independent ones in parallel, each
//! skipped when its cache key is already in the cache.
//!
//! Cache key = blake3 of (stage kind, its code version, canonical settings, the
//! content hash of each input, the robot file's canonical hash, the stage's seed:
//! the job seed mixed with the stage id).
//! Upstream tables enter by their *data* hash, so an upstream re-run that produces
//! the same table does not cascade. External files enter by their bytes, hashed
//! before the stage runs and checked again after it.
//!
//! Layout of an output folder:
//! `<stage>/<table>.parquet` (published results), `.egcal/cache/` (entries),
//! `.egcal/state/<stage>.json` (what the last run keyed on, for `status`),
//! `.egcal/work/<stage>/` (journals of resumable stages),
//! `.egcal/set_aside/<stage>/<UTC time>/` (journals `--remeasure` moved away),
//! `.egcal/lock`.
//!
//! A run, and `cache gc`, first removes the temporaries that killed runs left in
//! the output folder and in the calibration folders gate stages publish into
//! ([`fsio::sweep`]), and says what it removed.

pub mod cache;
pub mod lock;
pub mod progress;

use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::fsio;
use crate::job::{InputSource, Plan, PlannedStage};
use crate::robot::Robot;
use crate::stages::{InputTable, StageContext, StageError};
use crate::table::{self, Provenance, TableError};
use cache::{Cache, Lookup, Manifest};
use lock::{LockError, RunLock};
use progress::Reporter;

/// What a run should do beyond the default (run what is stale).
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// Run only this stage; its inputs must already be cached.
    pub only: Option<String>,
    /// Recompute this stage and everything downstream of it.
    pub from: Option<String>,
    /// Recompute every stage.
    pub force: bool,
    /// Stages run at once (at least 1).
    pub jobs: usize,
    /// Overrides the plan's run date (a replay of an earlier night).
    pub run_date: Option<i64>,
    /// Stages whose journals are set aside (kept under
    /// `.egcal/set_aside/<stage>/<time>/`, never deleted) so they start afresh,
    /// and which re-run with everything downstream: `--force` alone resumes a
    /// measuring stage from its journal and so replays the old readings.
    pub remeasure: Vec<String>,
}

/// The parts of a cache key, kept so `status` can say what changed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KeyParts {
    pub kind: String,
    pub code_version: u32,
    pub settings: serde_json::Value,
    /// Input name → content hash.
    pub inputs: BTreeMap<String, String>,
    pub robot: String,
    /// Hash of the cable-robot geometry, for stages that read it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cable_robot: Option<String>,
    pub seed: u64,
    /// What the stage reads outside its tables (logged files, run date), if anything.
    #[serde(default, skip_serializing_if = "serde_json::Value::is_null")]
    pub external: serde_json::Value,
}

impl KeyParts {
    pub fn key(&self) -> String {
        let bytes = serde_json::to_vec(self).expect("key parts serialise");
        blake3::hash(&bytes).to_hex().to_string()
    }
}

/// Recorded after each successful stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct StageState {
    key: String,
    parts: KeyParts,
}

/// How a stage ended in a run.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    Ran { seconds: f64 },
    Cached,
}

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Lock(#[from] LockError),
    #[error("unknown stage `{0}`{1}")]
    UnknownStage(String, String),
    #[error(
        "stage `{stage}` needs the output of `{upstream}`, which is not cached; run without --only first"
    )]
    MissingUpstream { stage: String, upstream: String },
    #[error("stage `{stage}` ({kind}) failed: {source}")]
    Stage {
        stage: String,
        kind: String,
        source: Box<StageError>,
    },
    #[error(
        "stage `{stage}`: input file {file} changed while the stage ran; nothing was cached, run again"
    )]
    InputChanged { stage: String, file: PathBuf },
    #[error("stage `{stage}`: {source}")]
    Table {
        stage: String,
        source: Box<TableError>,
    },
    #[error("{context}: {source}")]
    Io {
        context: String,
        source: std::io::Error,
    },
}

/// A finished stage: its key and what it produced.
#[derive(Debug, Clone)]
struct Done {
    key: String,
    manifest: Manifest,
}

/// Paths of an output folder.
pub struct Layout {
    pub output: PathBuf,
    pub state: PathBuf,
    pub work: PathBuf,
    pub cache: Cache,
}

impl Layout {
    pub fn new(output: &Path) -> Self {
        let meta = output.join(".egcal");
        Layout {
            output: output.to_path_buf(),
            state: meta.join("state"),
            work: meta.join("work"),
            cache: Cache::new(meta.join("cache")),
        }
    }

    fn meta(&self) -> PathBuf {
        self.output.join(".egcal")
    }

    pub fn published(&self, stage: &str, table: &str) -> PathBuf {
        self.output.join(stage).join(format!("{table}.parquet"))
    }

    fn state_file(&self, stage: &str) -> PathBuf {
        self.state.join(format!("{stage}.json"))
    }

    fn read_state(&self, stage: &str) -> Option<StageState> {
        let text = std::fs::read_to_string(self.state_file(stage)).ok()?;
        serde_json::from_str(&text).ok()
    }
}

/// Moves a stage's work folder (its measurement journal) to
/// `.egcal/set_aside/<stage>/<UTC time>/`, so the stage starts afresh and the
/// old readings stay on disk. `None` when the stage has no work folder.
fn set_aside_work(layout: &Layout, stage: &str) -> Result<Option<PathBuf>, RunError> {
    let work = layout.work.join(stage);
    if !work.exists() {
        return Ok(None);
    }
    // RFC 3339 without the characters some file systems refuse; a second
    // set-aside within the same second gets a suffix.
    let stamp = crate::table::time::now_rfc3339().replace([':', '-'], "");
    let parent = layout.meta().join("set_aside").join(stage);
    let io = |context: String| move |source| RunError::Io { context, source };
    std::fs::create_dir_all(&parent).map_err(io(format!("creating {}", parent.display())))?;
    let mut target = parent.join(&stamp);
    let mut n = 1;
    while target.exists() {
        n += 1;
        target = parent.join(format!("{stamp}_{n}"));
    }
    std::fs::rename(&work, &target).map_err(io(format!(
        "moving {} to {}",
        work.display(),
        target.display()
    )))?;
    fsio::sync_dir(&parent).map_err(io(format!("syncing {}", parent.display())))?;
    Ok(Some(target))
}

/// The seed a stage draws from: the job seed mixed with the stage id.
pub fn stage_seed(job_seed: u64, stage_id: &str) -> u64 {
    let mut hasher = blake3::Hasher::new();
    hasher.update(&job_seed.to_le_bytes());
    hasher.update(stage_id.as_bytes());
    let bytes = hasher.finalize();
    u64::from_le_bytes(bytes.as_bytes()[..8].try_into().expect("8 bytes"))
}

/// Runs the plan. Returns each stage's outcome in plan order (stages not selected
/// by `--only` are absent).
pub fn run(
    plan: &Plan,
    options: &RunOptions,
    reporter: &Reporter,
) -> Result<Vec<(String, Outcome)>, RunError> {
    let layout = Layout::new(&plan.output_dir);
    let _lock = RunLock::acquire(&layout.meta(), |m| reporter.line(m))?;
    if let Some(summary) = sweep_leftovers(plan, &layout)? {
        reporter.line(&summary);
    }
    let robot = Robot::new(plan.robot.clone());
    let robot_hash = plan.robot.content_hash();

    let index_of = |id: &str| {
        plan.stage_index(id).ok_or_else(|| {
            RunError::UnknownStage(
                id.to_string(),
                crate::suggest::did_you_mean(id, plan.stages.iter().map(|s| s.id.as_str())),
            )
        })
    };
    let selected: Vec<bool> = match &options.only {
        Some(id) => {
            let only = index_of(id)?;
            (0..plan.stages.len()).map(|i| i == only).collect()
        }
        None => vec![true; plan.stages.len()],
    };
    let mut remeasured = Vec::new();
    for id in &options.remeasure {
        let index = index_of(id)?;
        if let Some(moved) = set_aside_work(&layout, id)? {
            reporter.line(&format!(
                "{id}: earlier journal set aside in {} (kept); measuring afresh",
                moved.display()
            ));
        }
        remeasured.extend(plan.descendants(index));
        remeasured.push(index);
    }
    let forced: Vec<bool> = if options.force {
        vec![true; plan.stages.len()]
    } else if let Some(id) = &options.from {
        let from = index_of(id)?;
        let below = plan.descendants(from);
        (0..plan.stages.len()).map(|i| below.contains(&i)).collect()
    } else if options.only.is_some() {
        // `--only` means "run this stage now", even when cached.
        selected.clone()
    } else {
        vec![false; plan.stages.len()]
    };
    let forced: Vec<bool> = forced
        .iter()
        .enumerate()
        .map(|(i, f)| *f || remeasured.contains(&i))
        .collect();

    // Upstream stages that are not selected must come from the cache.
    let mut done: Vec<Option<Done>> = vec![None; plan.stages.len()];
    for (i, stage) in plan.stages.iter().enumerate() {
        if !selected[i] {
            continue;
        }
        for &u in &stage.upstream {
            if !selected[u] {
                let upstream = &plan.stages[u].id;
                let cached =
                    layout
                        .read_state(upstream)
                        .and_then(|s| match layout.cache.lookup(&s.key) {
                            Lookup::Hit(manifest) => Some(Done {
                                key: s.key,
                                manifest,
                            }),
                            _ => None,
                        });
                done[u] = Some(cached.ok_or_else(|| RunError::MissingUpstream {
                    stage: stage.id.clone(),
                    upstream: upstream.clone(),
                })?);
            }
        }
    }

    let jobs = options.jobs.max(1);
    let mut outcomes: Vec<Option<Outcome>> = vec![None; plan.stages.len()];
    let mut started = vec![false; plan.stages.len()];
    let mut failure: Option<RunError> = None;
    let mut running = 0;
    std::thread::scope(|scope| {
        let (sender, receiver) = mpsc::channel::<(usize, Result<(Done, Outcome), RunError>)>();
        loop {
            if failure.is_none() {
                for i in 0..plan.stages.len() {
                    if running >= jobs {
                        break;
                    }
                    let ready = selected[i]
                        && !started[i]
                        && plan.stages[i].upstream.iter().all(|&u| done[u].is_some());
                    if !ready {
                        continue;
                    }
                    started[i] = true;
                    running += 1;
                    let upstream: BTreeMap<usize, Done> = plan.stages[i]
                        .upstream
                        .iter()
                        .map(|&u| (u, done[u].clone().expect("ready")))
                        .collect();
                    let sender = sender.clone();
                    let (layout, robot, robot_hash) = (&layout, &robot, &robot_hash);
                    let force = forced[i];
                    scope.spawn(move || {
                        let result = execute(
                            plan, i, &upstream, layout, robot, robot_hash, force, reporter,
                        );
                        let _ = sender.send((i, result));
                    });
                }
            }
            if running == 0 {
                break;
            }
            let (i, result) = receiver.recv().expect("a running stage reports");
            running -= 1;
            match result {
                Ok((finished, outcome)) => {
                    done[i] = Some(finished);
                    outcomes[i] = Some(outcome);
                }
                Err(e) => {
                    if failure.is_none() {
                        failure = Some(e);
                    } else {
                        reporter.line(&format!("also failed: {e}"));
                    }
                }
            }
        }
    });
    if let Some(e) = failure {
        return Err(e);
    }
    Ok(plan
        .stages
        .iter()
        .zip(outcomes)
        .filter_map(|(s, o)| o.map(|o| (s.id.clone(), o)))
        .collect())
}

/// Content hashes of a stage's inputs, from upstream manifests or file bytes.
fn input_hashes(
    stage: &PlannedStage,
    plan: &Plan,
    upstream: &BTreeMap<usize, Done>,
) -> Result<BTreeMap<String, String>, RunError> {
    let mut hashes = BTreeMap::new();
    for (name, source) in &stage.inputs {
        let hash = match source {
            InputSource::Stage { stage: id, table } => {
                let u = plan.stage_index(id).expect("planned reference");
                upstream[&u].manifest.tables[table].content_hash.clone()
            }
            InputSource::Files { paths, .. } => {
                files_hash(paths).map_err(|source| RunError::Io {
                    context: format!("stage `{}`: hashing input `{name}`", stage.id),
                    source,
                })?
            }
        };
        hashes.insert(name.clone(), hash);
    }
    Ok(hashes)
}

fn hash_json(value: &impl Serialize) -> String {
    blake3::hash(&serde_json::to_vec(value).expect("serialises"))
        .to_hex()
        .to_string()
}

fn files_hash(paths: &[PathBuf]) -> std::io::Result<String> {
    let mut hasher = blake3::Hasher::new();
    for path in paths {
        hasher.update(fsio::hash_file(path)?.as_bytes());
    }
    Ok(hasher.finalize().to_hex().to_string())
}

fn key_parts(
    plan: &Plan,
    stage: &PlannedStage,
    inputs: BTreeMap<String, String>,
    robot_hash: &str,
) -> Result<KeyParts, RunError> {
    let external = stage
        .kind
        .external_key(&stage.settings, plan.job_dir(), plan.run_date)
        .map_err(|source| RunError::Stage {
            stage: stage.id.clone(),
            kind: stage.kind.info().kind.to_string(),
            source: Box::new(source),
        })?;
    Ok(KeyParts {
        kind: stage.kind.info().kind.to_string(),
        code_version: stage.kind.info().code_version,
        settings: stage.settings.clone(),
        inputs,
        robot: robot_hash.to_string(),
        cable_robot: stage
            .kind
            .info()
            .uses_cable_robot
            .then(|| hash_json(&plan.cable_robot)),
        // The seed the stage draws from, not the job's: two stages alike but for
        // their ids draw different streams, so they must not share an entry.
        seed: stage_seed(plan.seed, &stage.id),
        external,
    })
}

#[allow(clippy::too_many_arguments)]
fn execute(
    plan: &Plan,
    index: usize,
    upstream: &BTreeMap<usize, Done>,
    layout: &Layout,
    robot: &Robot,
    robot_hash: &str,
    force: bool,
    reporter: &Reporter,
) -> Result<(Done, Outcome), RunError> {
    let stage = &plan.stages[index];
    let table_error = |source| RunError::Table {
        stage: stage.id.clone(),
        source: Box::new(source),
    };
    let hashes = input_hashes(stage, plan, upstream)?;
    let parts = key_parts(plan, stage, hashes.clone(), robot_hash)?;
    let key = parts.key();
    if !force {
        match layout.cache.lookup(&key) {
            Lookup::Hit(manifest) => {
                publish(layout, &stage.id, &key, &manifest).map_err(table_error)?;
                write_state(layout, &stage.id, &key, &parts)?;
                reporter.line(&format!("{}: cached", stage.id));
                return Ok((Done { key, manifest }, Outcome::Cached));
            }
            Lookup::Corrupt(reason) => {
                reporter.line(&format!(
                    "{}: cache entry {key} is corrupt ({reason}); recomputing",
                    stage.id
                ));
                layout.cache.remove(&key).map_err(|source| RunError::Io {
                    context: format!("removing corrupt cache entry {key}"),
                    source,
                })?;
            }
            Lookup::Miss => {}
        }
    }

    let started = Instant::now();
    reporter.line(&format!("{}: running {}", stage.id, stage.kind.info().kind));
    let inputs = load_inputs(plan, stage, upstream, layout).map_err(table_error)?;
    let work_dir = layout.work.join(&stage.id);
    std::fs::create_dir_all(&work_dir).map_err(|source| RunError::Io {
        context: format!("creating {}", work_dir.display()),
        source,
    })?;
    let progress = reporter.stage(&stage.id);
    let ctx = StageContext {
        robot,
        cable_robot: &plan.cable_robot,
        seed: stage_seed(plan.seed, &stage.id),
        inputs: &inputs,
        work_dir: &work_dir,
        job_dir: plan.job_dir(),
        run_date: plan.run_date,
        progress: &progress,
    };
    let stage_error = |source| RunError::Stage {
        stage: stage.id.clone(),
        kind: stage.kind.info().kind.to_string(),
        source: Box::new(source),
    };
    let mut outputs = stage.kind.run(&ctx, &stage.settings).map_err(stage_error)?;
    drop(progress);
    check_outputs(stage, &outputs.tables).map_err(stage_error)?;

    // Inputs must not have changed under the stage.
    for (name, source) in &stage.inputs {
        if let InputSource::Files { paths, .. } = source
            && stage.kind.info().updates_input != Some(name.as_str())
            && files_hash(paths).ok().as_ref() != hashes.get(name)
        {
            return Err(RunError::InputChanged {
                stage: stage.id.clone(),
                file: paths[0].clone(),
            });
        }
    }

    let provenance = Provenance {
        job: plan.name.clone(),
        stage_id: stage.id.clone(),
        stage_kind: stage.kind.info().kind.to_string(),
        cache_key: key.clone(),
        input_hashes: hashes,
        tool_version: env!("CARGO_PKG_VERSION").to_string(),
        created_at: table::now_rfc3339(),
        extra: outputs.facts.clone(),
    };
    let manifest = layout
        .cache
        .store(
            &key,
            stage.kind.info().kind,
            &mut outputs.tables,
            &outputs.files,
            &outputs.facts,
            &provenance,
        )
        .map_err(table_error)?;
    publish(layout, &stage.id, &key, &manifest).map_err(table_error)?;
    write_state(layout, &stage.id, &key, &parts)?;
    let seconds = started.elapsed().as_secs_f64();
    let facts: Vec<String> = outputs
        .facts
        .iter()
        .map(|(k, v)| format!("{k}={}", shortened(v)))
        .collect();
    reporter.line(&format!(
        "{}: done in {seconds:.2} s {}",
        stage.id,
        facts.join(" ")
    ));
    Ok((Done { key, manifest }, Outcome::Ran { seconds }))
}

/// Longest fact value shown on a stage's "done" line; the whole value is in the
/// stage log above it and in the tables' metadata (`egcal show`).
const FACT_SHOWN_CHARS: usize = 48;

fn shortened(value: &str) -> String {
    match value.char_indices().nth(FACT_SHOWN_CHARS) {
        Some((end, _)) => format!("{}…", &value[..end]),
        None => value.to_string(),
    }
}

/// Every declared output present and matching its schema: a stage bug is caught
/// here rather than in the stage that reads the table.
fn check_outputs(
    stage: &PlannedStage,
    tables: &BTreeMap<String, polars::prelude::DataFrame>,
) -> Result<(), StageError> {
    for slot in stage.kind.info().outputs {
        // An optional output is written only when the stage's inputs ask for it
        // (e.g. `select`'s `work_targets`, with a `targets` input).
        let Some(df) = tables.get(slot.name) else {
            if slot.required {
                return Err(StageError::Failed(format!(
                    "produced no `{}` table",
                    slot.name
                )));
            }
            continue;
        };
        (slot.schema)().check(df, Path::new(&format!("<output {}>", slot.name)))?;
    }
    Ok(())
}

fn load_inputs(
    plan: &Plan,
    stage: &PlannedStage,
    upstream: &BTreeMap<usize, Done>,
    layout: &Layout,
) -> Result<BTreeMap<String, InputTable>, TableError> {
    let mut inputs = BTreeMap::new();
    for (name, source) in &stage.inputs {
        let slot = stage
            .kind
            .info()
            .inputs
            .iter()
            .find(|s| s.name == name)
            .expect("planned inputs are declared");
        let schema = (slot.schema)();
        let table = match source {
            InputSource::Stage { stage: id, table } => {
                let u = plan.stage_index(id).expect("planned reference");
                let done = &upstream[&u];
                let path = layout
                    .cache
                    .table_path(&done.key, &done.manifest.tables[table]);
                let df = table::read_checked(&path, &schema)?;
                InputTable {
                    path: layout.published(id, table),
                    df,
                }
            }
            InputSource::Files { paths, pattern } => {
                let mut frames = Vec::with_capacity(paths.len());
                for path in paths {
                    frames.push(table::read_checked(path, &schema)?);
                }
                let mut df = frames.remove(0);
                for other in frames {
                    df.vstack_mut(&other)
                        .map_err(|e| table::schema::io_error(Path::new(pattern), e))?;
                }
                let path = if paths.len() == 1 {
                    paths[0].clone()
                } else {
                    PathBuf::from(pattern)
                };
                schema.check(&df, &path)?;
                InputTable { path, df }
            }
        };
        inputs.insert(name.clone(), table);
    }
    Ok(inputs)
}

/// Links (or copies) a cache entry's tables and files to `<output>/<stage>/`,
/// unless already identical.
fn publish(layout: &Layout, stage: &str, key: &str, manifest: &Manifest) -> Result<(), TableError> {
    let tables = manifest.tables.iter().map(|(name, t)| {
        (
            layout.published(stage, name),
            layout.cache.table_path(key, t),
            &t.bytes_hash,
        )
    });
    let files = manifest.files.iter().map(|(name, f)| {
        (
            layout.output.join(stage).join(name),
            layout.cache.file_path(key, f),
            &f.bytes_hash,
        )
    });
    // Each file is replaced atomically; the folders they are in are synced
    // once at the end rather than after each (one fsync a folder, issue #31).
    let mut folders = Vec::new();
    for (target, source, hash) in tables.chain(files) {
        if fsio::same_file(&source, &target) || fsio::hash_file(&target).ok().as_ref() == Some(hash)
        {
            continue;
        }
        let folder = fsio::link_or_copy_unsynced(&source, &target)
            .map_err(|e| table::schema::io_error(&target, e))?;
        folders.push(folder);
    }
    fsio::sync_dirs(folders.iter().map(PathBuf::as_path))
        .map_err(|e| table::schema::io_error(&layout.output.join(stage), e))
}

fn write_state(layout: &Layout, stage: &str, key: &str, parts: &KeyParts) -> Result<(), RunError> {
    let state = StageState {
        key: key.to_string(),
        parts: parts.clone(),
    };
    let path = layout.state_file(stage);
    fsio::write_bytes_atomic(
        &path,
        &serde_json::to_vec_pretty(&state).expect("state serialises"),
    )
    .map_err(|source| RunError::Io {
        context: format!("writing {}", path.display()),
        source,
    })
}

/// A stage's standing before a run, with the reasons.
#[derive(Debug, Clone, PartialEq)]
pub struct StageStatus {
    pub stage: String,
    pub cached: bool,
    pub reasons: Vec<String>,
}

/// Dry run: which stages would run and why. Reads manifests and hashes inputs; runs nothing.
pub fn status(plan: &Plan) -> Result<Vec<StageStatus>, RunError> {
    let layout = Layout::new(&plan.output_dir);
    let robot_hash = plan.robot.content_hash();
    let mut done: BTreeMap<usize, Done> = BTreeMap::new();
    let mut result = Vec::new();
    for (i, stage) in plan.stages.iter().enumerate() {
        let stale_upstream: Vec<&str> = stage
            .upstream
            .iter()
            .filter(|u| !done.contains_key(u))
            .map(|&u| plan.stages[u].id.as_str())
            .collect();
        if !stale_upstream.is_empty() {
            result.push(StageStatus {
                stage: stage.id.clone(),
                cached: false,
                reasons: vec![format!(
                    "waits on stale upstream {} (skipped after it if its output is unchanged)",
                    stale_upstream.join(", ")
                )],
            });
            continue;
        }
        let upstream: BTreeMap<usize, Done> = stage
            .upstream
            .iter()
            .map(|&u| (u, done[&u].clone()))
            .collect();
        let parts = key_parts(
            plan,
            stage,
            input_hashes(stage, plan, &upstream)?,
            &robot_hash,
        )?;
        let key = parts.key();
        let (cached, reasons) = match layout.cache.lookup(&key) {
            Lookup::Hit(manifest) => {
                done.insert(i, Done { key, manifest });
                (true, Vec::new())
            }
            Lookup::Corrupt(reason) => (false, vec![format!("cache entry is corrupt ({reason})")]),
            Lookup::Miss => (false, explain(layout.read_state(&stage.id), &parts)),
        };
        result.push(StageStatus {
            stage: stage.id.clone(),
            cached,
            reasons,
        });
    }
    Ok(result)
}

/// What differs between the last run's key parts and the current ones.
fn explain(previous: Option<StageState>, now: &KeyParts) -> Vec<String> {
    let Some(previous) = previous else {
        return vec!["never run".into()];
    };
    let before = &previous.parts;
    let mut reasons = Vec::new();
    if before.kind != now.kind {
        reasons.push(format!(
            "stage kind changed ({} -> {})",
            before.kind, now.kind
        ));
    }
    if before.code_version != now.code_version {
        reasons.push(format!(
            "code version of `{}` changed ({} -> {})",
            now.kind, before.code_version, now.code_version
        ));
    }
    if let (Some(old), Some(new)) = (before.settings.as_object(), now.settings.as_object()) {
        let keys: std::collections::BTreeSet<&String> = old.keys().chain(new.keys()).collect();
        for key in keys {
            if old.get(key) != new.get(key) {
                reasons.push(format!(
                    "setting `{key}` changed ({} -> {})",
                    old.get(key).map_or("unset".into(), |v| v.to_string()),
                    new.get(key).map_or("unset".into(), |v| v.to_string())
                ));
            }
        }
    }
    let names: std::collections::BTreeSet<&String> =
        before.inputs.keys().chain(now.inputs.keys()).collect();
    for name in names {
        if before.inputs.get(name) != now.inputs.get(name) {
            reasons.push(format!("input `{name}` changed"));
        }
    }
    if before.robot != now.robot {
        reasons.push("robot file changed".into());
    }
    if before.cable_robot != now.cable_robot {
        reasons.push("cable-robot geometry changed".into());
    }
    if before.seed != now.seed {
        reasons.push("seed changed (the job's seed, or the stage's id)".into());
    }
    if reasons.is_empty() {
        reasons.push("cache entry missing (removed by gc or by hand)".into());
    }
    reasons
}

/// Keys every stage of the plan last ran with (what `cache gc` keeps).
pub fn live_keys(plan: &Plan) -> HashSet<String> {
    let layout = Layout::new(&plan.output_dir);
    plan.stages
        .iter()
        .filter_map(|s| layout.read_state(&s.id).map(|state| state.key))
        .collect()
}

/// What `cache gc` removed.
#[derive(Debug, Clone, PartialEq)]
pub struct Collected {
    pub entries: usize,
    pub bytes: u64,
    /// Leftovers of killed runs, described for the user.
    pub leftovers: Option<String>,
}

/// Removes cache entries no stage of the plan uses, and leftovers of killed runs.
pub fn gc(plan: &Plan) -> Result<Collected, RunError> {
    let layout = Layout::new(&plan.output_dir);
    let _lock = RunLock::acquire(&layout.meta(), |_| {})?;
    let leftovers = sweep_leftovers(plan, &layout)?;
    let (entries, bytes) = layout
        .cache
        .gc(&live_keys(plan))
        .map_err(|source| RunError::Io {
            context: format!("collecting {}", layout.cache.root().display()),
            source,
        })?;
    Ok(Collected {
        entries,
        bytes,
        leftovers,
    })
}

/// Removes temporaries of dead writers from the output folder (all of it: stage
/// outputs, the state and the work folders, the cache's shards) and from the folders of
/// inputs a stage may replace (where `gate` publishes; another job's run may be
/// writing there, which the sweep's liveness check allows for). Returns a line
/// for the user when it found any. Runs under the lock.
fn sweep_leftovers(plan: &Plan, layout: &Layout) -> Result<Option<String>, RunError> {
    let io = |dir: &Path| {
        let context = format!("removing temporary files left in {}", dir.display());
        move |source| RunError::Io { context, source }
    };
    let cache = layout.cache.root();
    let mut swept =
        fsio::sweep::sweep_tree(&layout.output, &[cache]).map_err(io(&layout.output))?;
    swept.extend(layout.cache.sweep().map_err(io(cache))?);
    let mut published: Vec<&Path> = plan
        .stages
        .iter()
        .filter_map(|stage| {
            let name = stage.kind.info().updates_input?;
            match stage.inputs.get(name)? {
                InputSource::Files { paths, .. } => Some(paths),
                InputSource::Stage { .. } => None,
            }
        })
        .flatten()
        .filter_map(|path| path.parent())
        .filter(|dir| !dir.starts_with(&layout.output))
        .collect();
    published.sort();
    published.dedup();
    for dir in published {
        swept.extend(fsio::sweep::sweep_folder(dir).map_err(io(dir))?);
    }
    Ok(swept.summary(&plan.output_dir))
}
