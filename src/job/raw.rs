//! Phase 1 of job-file parsing: TOML text → plain structs, no I/O besides the text.
//!
//! Collects every problem instead of stopping at the first, each with the line of
//! the offending key (from the TOML parser's spans) and a "did you mean" hint.

use std::collections::BTreeMap;
use std::path::Path;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};
use toml::de::{DeTable, DeValue};

use super::overrides::{JobOverrides, substitute};
use super::{JobProblem, JobProblems};

/// The `[job]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct JobHeader {
    /// Name used in provenance and the default output folder.
    pub name: String,
    /// Seed of every random draw in the job; stages mix in their id.
    #[serde(default)]
    pub seed: u64,
    /// Output folder, relative to the job file. Default: `out/<name>` beside the job file.
    #[serde(default)]
    pub output: Option<String>,
    /// Robot file, relative to the job file.
    pub robot: String,
    /// Cable-robot geometry file, relative to the job file; the built-in default
    /// geometry (`jobs/cdpr/default.toml`) when absent.
    #[serde(default)]
    pub cable_robot: Option<String>,
    /// Default values of the `{name}` placeholders used in the file's strings
    /// (`egcal run --var name=value` and a fleet's robots override them), e.g.
    /// `vars = { robot_id = "robot_a" }` for `publish_dir = "calibration/{robot_id}"`.
    #[serde(default)]
    pub vars: BTreeMap<String, String>,
}

/// One `[[stages]]` entry before validation.
#[derive(Debug, Clone, PartialEq)]
pub struct RawStage {
    pub id: String,
    pub kind: String,
    /// Input name → reference: `stage`, `stage.table`, or a path/glob ending in `.parquet`.
    pub inputs: BTreeMap<String, String>,
    /// Every other key of the stage table: the kind's settings.
    pub settings: toml::Table,
    /// Key path prefix for messages, e.g. `stages[2]`.
    pub key: String,
}

#[derive(Debug, Clone, PartialEq)]
pub struct RawJob {
    pub header: JobHeader,
    pub stages: Vec<RawStage>,
    pub lines: LineIndex,
}

/// Key path → line number of that key in the file.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LineIndex(BTreeMap<String, usize>);

impl LineIndex {
    pub fn build(text: &str, table: &DeTable) -> LineIndex {
        let mut index = BTreeMap::new();
        visit(table, "", &mut |path, start, _| {
            index.insert(
                path.to_string(),
                crate::toml_error::line_column(text, start).0,
            );
        });
        LineIndex(index)
    }

    /// `true` when the file holds exactly `key`.
    pub fn has(&self, key: &str) -> bool {
        self.0.contains_key(key)
    }

    /// Line of `key`, or of its closest enclosing key that has one.
    pub fn line_of(&self, key: &str) -> Option<usize> {
        let mut key = key;
        loop {
            if let Some(line) = self.0.get(key) {
                return Some(*line);
            }
            let cut = key.rfind(['.', '['])?;
            key = &key[..cut];
        }
    }
}

/// Calls `f(key path, byte offset, value)` for every key and array item, depth first.
fn visit(table: &DeTable, prefix: &str, f: &mut dyn FnMut(&str, usize, &DeValue)) {
    for (key, value) in table {
        let path = if prefix.is_empty() {
            key.get_ref().to_string()
        } else {
            format!("{prefix}.{}", key.get_ref())
        };
        visit_value(&path, key.span().start, value.get_ref(), f);
    }
}

fn visit_value(
    path: &str,
    start: usize,
    value: &DeValue,
    f: &mut dyn FnMut(&str, usize, &DeValue),
) {
    f(path, start, value);
    match value {
        DeValue::Table(inner) => visit(inner, path, f),
        DeValue::Array(items) => {
            for (i, item) in items.iter().enumerate() {
                visit_value(
                    &format!("{path}[{i}]"),
                    item.span().start,
                    item.get_ref(),
                    f,
                );
            }
        }
        _ => {}
    }
}

/// Keys whose integer literal is syntactically TOML but beyond i64, which the
/// TOML deserialiser rejects without a location: (key path, literal).
fn oversized_integers(table: &DeTable) -> Vec<(String, String)> {
    let mut found = Vec::new();
    visit(table, "", &mut |path, _, value| {
        if let DeValue::Integer(integer) = value
            && i64::from_str_radix(integer.as_str(), integer.radix()).is_err()
        {
            found.push((path.to_string(), integer.as_str().to_string()));
        }
    });
    found
}

const STAGE_KEYS: [&str; 3] = ["id", "kind", "inputs"];

/// Parses job-file text; `path` only names the file in messages.
pub fn parse(text: &str, path: &Path) -> Result<RawJob, JobProblems> {
    parse_with(text, path, &JobOverrides::default())
}

/// Parses job-file text with placeholder values and stage settings from outside
/// the file (see [`JobOverrides`]).
pub fn parse_with(
    text: &str,
    path: &Path,
    overrides: &JobOverrides,
) -> Result<RawJob, JobProblems> {
    let problem = |line: Option<usize>, key: &str, message: String| JobProblem {
        file: path.to_path_buf(),
        line,
        key: key.to_string(),
        message,
    };
    let spanned = DeTable::parse(text).map_err(|e| {
        let line = e
            .span()
            .map(|s| crate::toml_error::line_column(text, s.start).0);
        JobProblems(vec![problem(
            line,
            "",
            format!("invalid TOML: {}", e.message().trim()),
        )])
    })?;
    let lines = LineIndex::build(text, spanned.get_ref());
    let oversized = oversized_integers(spanned.get_ref());
    if !oversized.is_empty() {
        return Err(JobProblems(
            oversized
                .into_iter()
                .map(|(key, literal)| {
                    problem(
                        lines.line_of(&key),
                        &key,
                        format!(
                            "integer `{literal}` does not fit TOML's 64-bit signed integers (at most {})",
                            i64::MAX
                        ),
                    )
                })
                .collect(),
        ));
    }
    let mut root: toml::Table = toml::from_str(text).map_err(|e| {
        JobProblems(vec![problem(
            None,
            "",
            format!("invalid TOML: {}", e.message().trim()),
        )])
    })?;
    let mut problems = Vec::new();
    let at = |key: &str, message: String| problem(lines.line_of(key), key, message);
    problems.extend(
        apply_overrides(&mut root, overrides)
            .into_iter()
            .map(|(blame, message)| match blame {
                Blame::Job(key) => at(&key, message),
                Blame::Override { relative, job_key } => overrides
                    .origin_problem(&relative, &message)
                    .unwrap_or_else(|| at(&job_key, message)),
            }),
    );

    for key in root.keys().filter(|k| *k != "job" && *k != "stages") {
        problems.push(at(
            key,
            format!(
                "unknown top-level key `{key}`, expected `job` or `stages`{}",
                crate::suggest::did_you_mean(key, ["job", "stages"])
            ),
        ));
    }

    let header = match root.get("job") {
        None => {
            problems.push(problem(
                Some(1),
                "job",
                "missing `[job]` table (name, robot, seed, output)".into(),
            ));
            None
        }
        Some(value) => match serde_path_to_error::deserialize::<_, JobHeader>(value.clone()) {
            Ok(h) => Some(h),
            Err(e) => {
                let key = if e.path().to_string() == "." {
                    "job".to_string()
                } else {
                    format!("job.{}", e.path())
                };
                let message = e.inner().message().to_string();
                let hint = unknown_field_hint(
                    &message,
                    &["name", "seed", "output", "robot", "cable_robot", "vars"],
                );
                problems.push(at(&key, format!("{message}{hint}")));
                None
            }
        },
    };

    let mut stages = Vec::new();
    match root.get("stages") {
        None => problems.push(problem(None, "stages", "no `[[stages]]` declared".into())),
        Some(toml::Value::Array(items)) => {
            for (i, item) in items.iter().enumerate() {
                let key = format!("stages[{i}]");
                match parse_stage(item, &key) {
                    Ok(stage) => stages.push(stage),
                    Err(messages) => problems.extend(messages.into_iter().map(|(k, m)| at(&k, m))),
                }
            }
        }
        Some(other) => problems.push(at(
            "stages",
            format!(
                "expected an array of tables `[[stages]]`, found {}",
                other.type_str()
            ),
        )),
    }

    match header {
        Some(header) if problems.is_empty() => Ok(RawJob {
            header,
            stages,
            lines,
        }),
        _ => {
            let ids: Vec<(String, String)> = root
                .get("stages")
                .and_then(toml::Value::as_array)
                .into_iter()
                .flatten()
                .enumerate()
                .filter_map(|(i, stage)| {
                    let id = stage.get("id")?.as_str()?;
                    Some((format!("stages[{i}]"), id.to_string()))
                })
                .collect();
            Err(JobProblems(overrides.relocate(problems, &ids)))
        }
    }
}

/// Who a problem found while applying overrides is about.
enum Blame {
    /// A key of the job file.
    Job(String),
    /// An override (`relative` below its table, e.g. `stages.gate.alpha`), named
    /// in its own file when it has one, else at `job_key` of the job file.
    Override { relative: String, job_key: String },
}

/// Merges the overrides' stage settings into `root` and fills the placeholders of
/// every string outside `[job] vars`; problems as (key, message).
fn apply_overrides(root: &mut toml::Table, overrides: &JobOverrides) -> Vec<(Blame, String)> {
    let mut problems = Vec::new();
    let mut vars = BTreeMap::new();
    match root.get("job").and_then(|job| job.get("vars")) {
        None => {}
        Some(toml::Value::Table(table)) => {
            for (name, value) in table {
                match value.as_str() {
                    Some(text) => {
                        vars.insert(name.clone(), text.to_string());
                    }
                    None => problems.push((
                        Blame::Job(format!("job.vars.{name}")),
                        format!("expected a string, found {}", value.type_str()),
                    )),
                }
            }
        }
        Some(other) => problems.push((
            Blame::Job("job.vars".to_string()),
            format!(
                "expected a table of name = \"value\", found {}",
                other.type_str()
            ),
        )),
    }
    vars.extend(overrides.vars.clone());

    for (id, settings) in &overrides.stage_settings {
        let stage = root
            .get_mut("stages")
            .and_then(toml::Value::as_array_mut)
            .and_then(|stages| {
                stages
                    .iter_mut()
                    .find(|s| s.get("id").and_then(toml::Value::as_str) == Some(id))
            })
            .and_then(toml::Value::as_table_mut);
        match stage {
            Some(table) => {
                for (key, value) in settings {
                    if STAGE_KEYS.contains(&key.as_str()) {
                        problems.push((
                            Blame::Override {
                                relative: format!("stages.{id}.{key}"),
                                job_key: "stages".to_string(),
                            },
                            format!("an override of stage `{id}` may not change `{key}`"),
                        ));
                    } else {
                        table.insert(key.clone(), value.clone());
                    }
                }
            }
            None => {
                let ids: Vec<&str> = root
                    .get("stages")
                    .and_then(toml::Value::as_array)
                    .into_iter()
                    .flatten()
                    .filter_map(|s| s.get("id").and_then(toml::Value::as_str))
                    .collect();
                problems.push((
                    Blame::Override {
                        relative: format!("stages.{id}"),
                        job_key: "stages".to_string(),
                    },
                    format!(
                        "settings override a stage `{id}` that the job does not declare{}; its stages: {}",
                        crate::suggest::did_you_mean(id, ids.iter().copied()),
                        ids.join(", ")
                    ),
                ));
            }
        }
    }

    let (mut used, mut unknown) = (std::collections::BTreeSet::new(), Vec::new());
    for (key, value) in root.iter_mut() {
        if key == "job" {
            if let Some(job) = value.as_table_mut() {
                for (field, item) in job.iter_mut().filter(|(f, _)| *f != "vars") {
                    substitute(
                        item,
                        &format!("job.{field}"),
                        &vars,
                        &mut used,
                        &mut unknown,
                    );
                }
            }
        } else {
            substitute(value, key, &vars, &mut used, &mut unknown);
        }
    }
    for (key, name) in unknown {
        problems.push((
            Blame::Job(key),
            format!(
                "`{{{name}}}` is not a variable of this job: declare it in `[job] vars` or pass `--var {name}=VALUE`"
            ),
        ));
    }
    for name in overrides.vars.keys().filter(|n| !used.contains(*n)) {
        problems.push((
            Blame::Override {
                relative: format!("vars.{name}"),
                job_key: "job.vars".to_string(),
            },
            format!("a value was given for `{{{name}}}` but the job file uses no `{{{name}}}`"),
        ));
    }
    problems
}

fn unknown_field_hint(message: &str, fields: &[&str]) -> String {
    message
        .strip_prefix("unknown field `")
        .and_then(|rest| rest.split('`').next())
        .map(|field| crate::suggest::did_you_mean(field, fields.iter().copied()))
        .unwrap_or_default()
}

/// One stage table → (id, kind, inputs, settings); problems as (key, message).
fn parse_stage(item: &toml::Value, key: &str) -> Result<RawStage, Vec<(String, String)>> {
    let Some(table) = item.as_table() else {
        return Err(vec![(key.to_string(), "expected a table".into())]);
    };
    let mut problems = Vec::new();
    let mut text_field = |name: &str| match table.get(name) {
        Some(toml::Value::String(s)) if !s.is_empty() => Some(s.clone()),
        Some(other) => {
            problems.push((
                format!("{key}.{name}"),
                format!("expected a non-empty string, found {}", describe(other)),
            ));
            None
        }
        None => {
            problems.push((format!("{key}.{name}"), format!("missing `{name}`")));
            None
        }
    };
    let id = text_field("id");
    let kind = text_field("kind");
    let mut inputs = BTreeMap::new();
    match table.get("inputs") {
        None => {}
        Some(toml::Value::Table(map)) => {
            for (name, reference) in map {
                match reference {
                    toml::Value::String(s) => {
                        inputs.insert(name.clone(), s.clone());
                    }
                    other => problems.push((
                        format!("{key}.inputs.{name}"),
                        format!(
                            "expected a string (`stage`, `stage.table` or a .parquet path/glob), found {}",
                            other.type_str()
                        ),
                    )),
                }
            }
        }
        Some(other) => problems.push((
            format!("{key}.inputs"),
            format!(
                "expected a table of name = reference, found {}",
                other.type_str()
            ),
        )),
    }
    if let Some(id) = &id
        && !id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
    {
        problems.push((
            format!("{key}.id"),
            format!("stage id `{id}` may only use letters, digits, `_` and `-`"),
        ));
    }
    let settings: toml::Table = table
        .iter()
        .filter(|(k, _)| !STAGE_KEYS.contains(&k.as_str()))
        .map(|(k, v)| (k.clone(), v.clone()))
        .collect();
    match (id, kind) {
        (Some(id), Some(kind)) if problems.is_empty() => Ok(RawStage {
            id,
            kind,
            inputs,
            settings,
            key: key.to_string(),
        }),
        _ => Err(problems),
    }
}

fn describe(value: &toml::Value) -> String {
    match value {
        toml::Value::String(_) => "an empty string".into(),
        other => other.type_str().to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
[job]
name = "t"
seed = 3
robot = "robots/irb1600_145.toml"

[[stages]]
id = "p"
kind = "predict"
inputs = { conf_wrenches = "data/in.parquet" }
model = "nominal"
"#;

    #[test]
    fn parses_header_stages_inputs_and_settings() {
        let job = parse(GOOD, Path::new("j.toml")).unwrap();
        assert_eq!(job.header.seed, 3);
        assert_eq!(job.stages[0].inputs["conf_wrenches"], "data/in.parquet");
        assert_eq!(job.stages[0].settings["model"].as_str(), Some("nominal"));
        assert_eq!(job.lines.line_of("stages[0].model"), Some(11));
        assert_eq!(
            job.lines.line_of("stages[0].inputs.conf_wrenches"),
            Some(10)
        );
    }

    #[test]
    fn collects_every_problem_with_lines_and_hints() {
        let text = GOOD
            .replace("seed = 3", "sed = 3")
            .replace("kind = \"predict\"\n", "");
        let problems = parse(&text, Path::new("j.toml")).unwrap_err();
        let rendered = problems.to_string();
        assert_eq!(problems.0.len(), 2, "{rendered}");
        assert!(rendered.contains("j.toml:4: job.sed"), "{rendered}");
        assert!(rendered.contains("did you mean `seed`"), "{rendered}");
        assert!(
            rendered.contains("stages[0].kind: missing `kind`"),
            "{rendered}"
        );
    }

    const TEMPLATE: &str = r#"
[job]
name = "nightly_{robot_id}"
robot = "robots/irb1600_145.toml"
vars = { robot_id = "robot_a" }

[[stages]]
id = "gate"
kind = "gate"
publish_dir = "calibration/{robot_id}"
alpha = 0.01
inputs = { in_service = "calibration/{robot_id}/current.parquet" }
"#;

    fn vars(pairs: &[(&str, &str)]) -> JobOverrides {
        JobOverrides::with_vars(
            pairs
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect(),
        )
    }

    #[test]
    fn placeholders_take_the_files_defaults_or_the_callers_values() {
        let job = parse(TEMPLATE, Path::new("j.toml")).unwrap();
        assert_eq!(job.header.name, "nightly_robot_a");
        let stage = &job.stages[0];
        assert_eq!(
            stage.settings["publish_dir"].as_str(),
            Some("calibration/robot_a")
        );
        let job = parse_with(TEMPLATE, Path::new("j.toml"), &vars(&[("robot_id", "r7")])).unwrap();
        assert_eq!(job.header.name, "nightly_r7");
        assert_eq!(
            job.stages[0].inputs["in_service"],
            "calibration/r7/current.parquet"
        );
        assert_eq!(
            job.header.vars["robot_id"], "robot_a",
            "the file's default is kept"
        );
    }

    #[test]
    fn stage_settings_are_merged_and_unknown_stages_refused() {
        let mut overrides = vars(&[]);
        let settings: toml::Table =
            toml::from_str("alpha = 0.05\nmin_improvement_mm = 0.1").unwrap();
        overrides
            .stage_settings
            .insert("gate".into(), settings.clone());
        let job = parse_with(TEMPLATE, Path::new("j.toml"), &overrides).unwrap();
        assert_eq!(job.stages[0].settings["alpha"].as_float(), Some(0.05));
        assert_eq!(
            job.stages[0].settings["min_improvement_mm"].as_float(),
            Some(0.1)
        );
        overrides.stage_settings.insert("gaet".into(), settings);
        let message = parse_with(TEMPLATE, Path::new("j.toml"), &overrides)
            .unwrap_err()
            .to_string();
        assert!(
            message.contains("stage `gaet` that the job does not declare"),
            "{message}"
        );
    }

    #[test]
    fn unknown_and_unused_variables_are_named_with_their_line() {
        let text = TEMPLATE.replace("alpha = 0.01", "alpha = 0.01\nmodel = \"{model}\"");
        let message = parse(&text, Path::new("j.toml")).unwrap_err().to_string();
        assert!(
            message.contains("j.toml:12: stages[0].model: `{model}` is not a variable"),
            "{message}"
        );
        let message = parse_with(TEMPLATE, Path::new("j.toml"), &vars(&[("cell", "c1")]))
            .unwrap_err()
            .to_string();
        assert!(
            message.contains("the job file uses no `{cell}`"),
            "{message}"
        );
        let text = TEMPLATE.replace(
            "vars = { robot_id = \"robot_a\" }",
            "vars = { robot_id = 3 }",
        );
        let message = parse(&text, Path::new("j.toml")).unwrap_err().to_string();
        assert!(
            message.contains("job.vars.robot_id: expected a string"),
            "{message}"
        );
    }

    #[test]
    fn syntax_error_names_the_line() {
        let problems = parse("[job]\nname = \n", Path::new("j.toml")).unwrap_err();
        assert!(problems.to_string().starts_with("j.toml:2:"), "{problems}");
    }
}
