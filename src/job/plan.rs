//! Phase 2 of job-file parsing: a validated, ordered plan.
//!
//! Resolves the robot file and external inputs relative to the job file, looks up
//! stage kinds, canonicalises settings (defaults filled), binds every input to an
//! upstream table or to files, checks column compatibility (upstream output schema,
//! or the Parquet footers of external files — footers only, no data read), and
//! orders the stages topologically. Unknown references and cycles are reported with
//! their key and line.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use super::raw::{self, RawJob};
use super::{JobOverrides, JobProblem, JobProblems};
use crate::cdpr::CableRobotSpec;
use crate::robot::RobotSpec;
use crate::stages::{self, StageKind, TableSlot};
use crate::table::{self, TableSchema};

/// Where a stage input comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum InputSource {
    /// An output table of another stage of the job.
    Stage { stage: String, table: String },
    /// One or more Parquet files (a path or a glob), read and concatenated.
    Files {
        pattern: String,
        paths: Vec<PathBuf>,
    },
}

/// A stage ready to run.
pub struct PlannedStage {
    pub id: String,
    pub kind: &'static dyn StageKind,
    /// Settings with defaults filled (canonical JSON).
    pub settings: serde_json::Value,
    pub inputs: BTreeMap<String, InputSource>,
    /// Indexes (into [`Plan::stages`]) of the stages this one reads from.
    pub upstream: Vec<usize>,
}

/// A validated job.
pub struct Plan {
    pub job_file: PathBuf,
    pub name: String,
    pub seed: u64,
    pub output_dir: PathBuf,
    pub robot_file: PathBuf,
    pub robot: RobotSpec,
    pub cable_robot: CableRobotSpec,
    /// In dependency order.
    pub stages: Vec<PlannedStage>,
    /// The day (since 1970-01-01, UTC) relative time windows end on: today, or the
    /// `--run-date` of a replay. Part of the cache key of stages that use it.
    pub run_date: i64,
}

impl Plan {
    /// The job file's folder: relative paths in settings resolve here.
    pub fn job_dir(&self) -> &Path {
        self.job_file.parent().unwrap_or(Path::new("."))
    }

    /// Reads, parses and validates a job file.
    pub fn load(path: &Path) -> Result<Plan, JobProblems> {
        Plan::load_with(path, &JobOverrides::default())
    }

    /// [`Plan::load`] with placeholder values and stage settings from outside the
    /// file (`egcal run --var`, a fleet's robots).
    pub fn load_with(path: &Path, overrides: &JobOverrides) -> Result<Plan, JobProblems> {
        Plan::load_from(path, overrides, false)
    }

    /// [`Plan::load_with`] that also reads the files stages import
    /// ([`crate::stages::Stage::check_sources`]), as `egcal check` does: a
    /// missing or unreadable export is a problem of the setting naming it.
    pub fn load_checked(path: &Path, overrides: &JobOverrides) -> Result<Plan, JobProblems> {
        Plan::load_from(path, overrides, true)
    }

    fn load_from(
        path: &Path,
        overrides: &JobOverrides,
        read_sources: bool,
    ) -> Result<Plan, JobProblems> {
        let text = std::fs::read_to_string(path).map_err(|e| {
            JobProblems(vec![JobProblem {
                file: path.to_path_buf(),
                line: None,
                key: String::new(),
                message: format!("cannot read job file: {e}"),
            }])
        })?;
        let raw = raw::parse_with(&text, path, overrides)?;
        let stages: Vec<(String, String)> = raw
            .stages
            .iter()
            .map(|s| (s.key.clone(), s.id.clone()))
            .collect();
        build(raw, path, read_sources)
            .map_err(|JobProblems(problems)| JobProblems(overrides.relocate(problems, &stages)))
    }

    pub fn stage_index(&self, id: &str) -> Option<usize> {
        self.stages.iter().position(|s| s.id == id)
    }

    /// Indexes of `index` and every stage downstream of it.
    pub fn descendants(&self, index: usize) -> Vec<usize> {
        let mut marked = vec![false; self.stages.len()];
        marked[index] = true;
        for (i, stage) in self.stages.iter().enumerate().skip(index + 1) {
            if stage.upstream.iter().any(|u| marked[*u]) {
                marked[i] = true;
            }
        }
        (0..self.stages.len()).filter(|i| marked[*i]).collect()
    }
}

/// The plan of `raw`; with `read_sources`, the files stages import are read too.
fn build(raw: RawJob, path: &Path, read_sources: bool) -> Result<Plan, JobProblems> {
    let dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let mut problems = Vec::new();
    let at = |key: &str, message: String| JobProblem {
        file: path.to_path_buf(),
        line: raw.lines.line_of(key),
        key: key.to_string(),
        message,
    };

    let robot_file = dir.join(&raw.header.robot);
    let robot = match RobotSpec::load(&robot_file) {
        Ok(r) => Some(r),
        Err(e) => {
            problems.push(at("job.robot", e.to_string()));
            None
        }
    };
    let cable_robot = match &raw.header.cable_robot {
        None => Some(CableRobotSpec::default()),
        Some(file) => match CableRobotSpec::load(&dir.join(file)) {
            Ok(spec) => Some(spec),
            Err(e) => {
                problems.push(at("job.cable_robot", e.to_string()));
                None
            }
        },
    };
    let output_dir = dir.join(
        raw.header
            .output
            .clone()
            .unwrap_or_else(|| format!("out/{}", raw.header.name)),
    );

    if let Some(blocker) = non_folder_ancestor(&output_dir) {
        let key = if raw.header.output.is_some() {
            "job.output"
        } else {
            "job.name"
        };
        problems.push(at(
            key,
            format!(
                "the output folder `{}` cannot be created: `{}` exists and is not a folder",
                output_dir.display(),
                blocker.display()
            ),
        ));
    }

    // The name is the default output folder's last part and a provenance label.
    let name = raw.header.name.as_str();
    if name == "."
        || name == ".."
        || name.contains(['/', '\\'])
        || name.chars().any(char::is_control)
    {
        problems.push(at(
            "job.name",
            format!("job name {name:?} must be one folder name: no `/`, `\\`, control characters, `.` or `..`"),
        ));
    }
    if let Some(problem) = output_holds_the_job(&output_dir, &dir) {
        let key = if raw.header.output.is_some() {
            "job.output"
        } else {
            "job.name"
        };
        problems.push(at(key, problem));
    }

    // Stage ids and kinds first, so references can be resolved in any order.
    let mut ids: HashMap<&str, usize> = HashMap::new();
    let mut kinds: Vec<Option<&'static dyn StageKind>> = Vec::new();
    for (i, stage) in raw.stages.iter().enumerate() {
        if let Some(first) = ids.insert(stage.id.as_str(), i) {
            problems.push(at(
                &format!("{}.id", stage.key),
                format!("duplicate stage id `{}` (also stages[{first}])", stage.id),
            ));
        }
        let kind = stages::lookup(&stage.kind);
        if kind.is_none() {
            problems.push(at(
                &format!("{}.kind", stage.key),
                stages::unknown_kind_message(&stage.kind),
            ));
        }
        kinds.push(kind);
    }

    let mut planned: Vec<Option<PlannedStage>> = Vec::new();
    let mut edges: Vec<Vec<usize>> = vec![Vec::new(); raw.stages.len()];
    for (i, stage) in raw.stages.iter().enumerate() {
        let Some(kind) = kinds[i] else {
            planned.push(None);
            continue;
        };
        let settings = match kind.canonical_settings(&stage.settings) {
            Ok(s) => Some(s),
            Err(list) => {
                for p in list {
                    problems.push(at(&settings_key(&stage.key, &p.key), p.message));
                }
                None
            }
        };
        // Checks across settings and against the robot: only with both files read
        // (their own problems are reported already).
        if let (Some(settings), Some(robot), Some(cable_robot)) = (&settings, &robot, &cable_robot)
        {
            let bound: Vec<&str> = stage.inputs.keys().map(String::as_str).collect();
            let ctx = stages::SettingsContext {
                robot,
                cable_robot,
                job_dir: &dir,
                bound_inputs: &bound,
            };
            let found = kind.check_settings(settings, &ctx);
            let clean = found.is_empty();
            for p in found {
                problems.push(at(&settings_key(&stage.key, &p.key), p.message));
            }
            if read_sources && clean {
                for p in kind.check_sources(settings, &ctx) {
                    problems.push(at(&settings_key(&stage.key, &p.key), p.message));
                }
            }
        }
        let mut inputs = BTreeMap::new();
        for (name, reference) in &stage.inputs {
            let key = format!("{}.inputs.{name}", stage.key);
            let Some(slot) = kind.info().inputs.iter().find(|s| s.name == *name) else {
                let names: Vec<&str> = kind.info().inputs.iter().map(|s| s.name).collect();
                problems.push(at(
                    &key,
                    format!(
                        "stage kind `{}` has no input `{name}`{}; its inputs: {}",
                        kind.info().kind,
                        crate::suggest::did_you_mean(name, names.iter().copied()),
                        names.join(", ")
                    ),
                ));
                continue;
            };
            // The edge counts for cycle detection even when the reference is
            // otherwise bad, so a cycle is reported alongside other problems.
            if !is_path(reference) {
                let stage_id = reference
                    .split_once('.')
                    .map_or(reference.as_str(), |(s, _)| s);
                if let Some(&u) = ids.get(stage_id) {
                    edges[i].push(u);
                }
            }
            match resolve_input(reference, slot, &dir, &raw, &ids, &kinds) {
                Ok(source) => {
                    inputs.insert(name.clone(), source);
                }
                Err(message) => problems.push(at(&key, message)),
            }
        }
        for slot in kind.info().inputs.iter().filter(|s| s.required) {
            if !stage.inputs.contains_key(slot.name) {
                problems.push(at(
                    &format!("{}.inputs", stage.key),
                    format!("missing required input `{}` ({})", slot.name, slot.meaning),
                ));
            }
        }
        planned.push(settings.map(|settings| PlannedStage {
            id: stage.id.clone(),
            kind,
            settings,
            inputs,
            upstream: Vec::new(),
        }));
    }

    let order = match topological_order(&edges) {
        Ok(order) => order,
        Err(cycle) => {
            let names: Vec<&str> = cycle.iter().map(|&i| raw.stages[i].id.as_str()).collect();
            problems.push(at(
                &format!("{}.inputs", raw.stages[cycle[0]].key),
                format!(
                    "stages form a cycle: {} -> {}",
                    names.join(" -> "),
                    names[0]
                ),
            ));
            Vec::new()
        }
    };

    if !problems.is_empty() {
        return Err(JobProblems(problems));
    }
    let robot = robot.expect("no problems means the robot loaded");
    let cable_robot = cable_robot.expect("no problems means the cable robot loaded");
    let mut new_index = vec![0; order.len()];
    for (position, &old) in order.iter().enumerate() {
        new_index[old] = position;
    }
    let mut stages: Vec<PlannedStage> = Vec::with_capacity(order.len());
    for &old in &order {
        let mut stage = planned[old]
            .take()
            .expect("no problems means every stage planned");
        stage.upstream = edges[old].iter().map(|u| new_index[*u]).collect();
        stage.upstream.sort();
        stage.upstream.dedup();
        stages.push(stage);
    }
    Ok(Plan {
        job_file: path.to_path_buf(),
        name: raw.header.name,
        seed: raw.header.seed,
        output_dir,
        robot_file,
        robot,
        cable_robot,
        stages,
        run_date: crate::table::time::today(),
    })
}

/// The nearest existing ancestor of `dir` (or `dir` itself) when it is not a
/// folder, so the output folder could never be created under it.
/// Why `output_dir` cannot be a job's output folder, or `None`: the folder of
/// the job file itself or one of its ancestors (`""`, `"."`, `".."`, `"/"`),
/// where stage folders and `.egcal` would sit among the user's own files, and
/// a stage's table could overwrite an input of the same name.
fn output_holds_the_job(output_dir: &Path, job_dir: &Path) -> Option<String> {
    let output = resolved(output_dir);
    let job = resolved(job_dir);
    job.starts_with(&output).then(|| {
        format!(
            "the output folder `{}` is the job file's folder or holds it; name a folder of its own (e.g. `out/<job name>`)",
            output_dir.display()
        )
    })
}

/// `path` made absolute, component by component: symbolic links resolved
/// where the path exists, `.` and `..` applied as the file system would.
fn resolved(path: &Path) -> PathBuf {
    use std::path::Component;
    let absolute = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir().unwrap_or_default().join(path)
    };
    let mut out = PathBuf::new();
    for part in absolute.components() {
        match part {
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            other => {
                out.push(other);
                if let Ok(real) = out.canonicalize() {
                    out = real;
                }
            }
        }
    }
    out
}

fn non_folder_ancestor(dir: &Path) -> Option<PathBuf> {
    dir.ancestors()
        .find(|p| p.exists())
        .filter(|p| !p.is_dir())
        .map(Path::to_path_buf)
}

/// The job-file key of a setting: `stages[2]` and `simulator.seed` make
/// `stages[2].simulator.seed`; a problem of the whole settings names the stage.
fn settings_key(stage_key: &str, setting: &str) -> String {
    if setting.is_empty() {
        stage_key.to_string()
    } else {
        format!("{stage_key}.{setting}")
    }
}

/// Whether a reference names files rather than a stage.
fn is_path(reference: &str) -> bool {
    reference.ends_with(".parquet") || reference.contains('/') || reference.contains('*')
}

fn resolve_input(
    reference: &str,
    slot: &TableSlot,
    dir: &Path,
    raw: &RawJob,
    ids: &HashMap<&str, usize>,
    kinds: &[Option<&'static dyn StageKind>],
) -> Result<InputSource, String> {
    let expected = (slot.schema)();
    if is_path(reference) {
        let paths = expand(dir, reference)?;
        for path in &paths {
            check_footer(path, &expected)?;
        }
        return Ok(InputSource::Files {
            pattern: reference.to_string(),
            paths,
        });
    }
    let (stage_id, table) = match reference.split_once('.') {
        Some((s, t)) => (s, Some(t)),
        None => (reference, None),
    };
    let Some(&upstream) = ids.get(stage_id) else {
        return Err(format!(
            "unknown stage `{stage_id}`{} (a file input must end in .parquet or contain /)",
            crate::suggest::did_you_mean(stage_id, raw.stages.iter().map(|s| s.id.as_str()))
        ));
    };
    let Some(kind) = kinds[upstream] else {
        // Its unknown kind is reported already.
        return Ok(InputSource::Stage {
            stage: stage_id.to_string(),
            table: table.unwrap_or_default().to_string(),
        });
    };
    let outputs = kind.info().outputs;
    let output = match table {
        Some(t) => outputs.iter().find(|o| o.name == t).ok_or_else(|| {
            format!(
                "stage `{stage_id}` has no output `{t}`{}; its outputs: {}",
                crate::suggest::did_you_mean(t, outputs.iter().map(|o| o.name)),
                names(outputs)
            )
        })?,
        None if outputs.len() == 1 => &outputs[0],
        None => outputs
            .iter()
            .find(|o| o.name == slot.name)
            .ok_or_else(|| {
                format!(
                    "stage `{stage_id}` has several outputs ({}); write `{stage_id}.<table>`",
                    names(outputs)
                )
            })?,
    };
    let produced = (output.schema)();
    for column in expected.columns.iter().filter(|c| c.required) {
        if produced.column(column.name).is_none() {
            return Err(format!(
                "output `{stage_id}.{}` ({}) lacks column `{}` that input `{}` needs",
                output.name, produced.kind, column.name, slot.name
            ));
        }
    }
    Ok(InputSource::Stage {
        stage: stage_id.to_string(),
        table: output.name.to_string(),
    })
}

fn names(slots: &[TableSlot]) -> String {
    slots.iter().map(|s| s.name).collect::<Vec<_>>().join(", ")
}

/// Files matching `pattern` (relative to `dir`), sorted; an error when none match.
fn expand(dir: &Path, pattern: &str) -> Result<Vec<PathBuf>, String> {
    let full = dir.join(pattern);
    let full_str = full.to_string_lossy();
    let paths: Vec<PathBuf> = glob::glob(&full_str)
        .map_err(|e| format!("bad glob `{pattern}`: {e}"))?
        .filter_map(Result::ok)
        .filter(|p| p.is_file())
        .collect();
    if paths.is_empty() {
        return Err(format!("no file matches `{}`", full.display()));
    }
    Ok(paths)
}

/// Checks required columns and their types from the Parquet footer only.
fn check_footer(path: &Path, expected: &TableSchema) -> Result<(), String> {
    let footer = table::read_footer(path).map_err(|e| e.to_string())?;
    for column in expected.columns.iter() {
        let find = |wanted: &str| footer.columns.iter().find(|(name, _)| name == wanted);
        // A prismatic joint's `q{i}_mm` stands for its `q{i}_deg`.
        let found = find(column.name).or_else(|| column.alternative.and_then(find));
        match found {
            None if column.required => {
                return Err(format!(
                    "{}: missing required column `{}` for a {} table",
                    path.display(),
                    column.name,
                    expected.kind
                ));
            }
            None => {}
            Some((name, dtype)) => {
                let wanted = column.dtype.polars().to_string();
                let same = dtype == &wanted
                    || (wanted.starts_with("datetime") && dtype.starts_with("datetime"));
                if !same {
                    return Err(format!(
                        "{}: column `{name}` has type {dtype}, expected {wanted}",
                        path.display(),
                    ));
                }
            }
        }
    }
    Ok(())
}

/// Kahn's algorithm over `edges[i]` = stages that stage `i` reads from. Keeps the
/// file order among independent stages. On a cycle, returns one cycle's members.
fn topological_order(edges: &[Vec<usize>]) -> Result<Vec<usize>, Vec<usize>> {
    let n = edges.len();
    let mut indegree: Vec<usize> = edges.iter().map(Vec::len).collect();
    let mut order = Vec::with_capacity(n);
    let mut done = vec![false; n];
    while order.len() < n {
        let Some(next) = (0..n).find(|&i| !done[i] && indegree[i] == 0) else {
            // Walk upstream from any remaining stage until a stage repeats.
            let mut path = vec![(0..n).find(|&i| !done[i]).expect("a remaining stage")];
            loop {
                let last = *path.last().expect("non-empty");
                let up = *edges[last]
                    .iter()
                    .find(|&&u| !done[u])
                    .expect("remaining stages have remaining upstream");
                if let Some(pos) = path.iter().position(|&p| p == up) {
                    let mut cycle = path[pos..].to_vec();
                    cycle.reverse();
                    return Err(cycle);
                }
                path.push(up);
            }
        };
        done[next] = true;
        order.push(next);
        for (i, ups) in edges.iter().enumerate() {
            if !done[i] {
                indegree[i] -= ups.iter().filter(|&&u| u == next).count();
            }
        }
    }
    Ok(order)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topological_order_keeps_file_order_and_finds_cycles() {
        assert_eq!(
            topological_order(&[vec![1], vec![], vec![0]]),
            Ok(vec![1, 0, 2])
        );
        let cycle = topological_order(&[vec![2], vec![0], vec![1]]).unwrap_err();
        assert_eq!(cycle.len(), 3);
    }
}
