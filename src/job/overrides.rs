//! What a caller changes in a job file without editing it: values of its `{name}`
//! placeholders (`[job] vars` gives the defaults, `egcal run --var` and a fleet's
//! robots override them) and, for a fleet's per-robot settings, whole keys of a
//! stage's table.
//!
//! Placeholders are replaced inside string values of the parsed TOML, never in the
//! text, so a value cannot change the file's structure and every problem keeps the
//! line of its key.
//!
//! Overrides written in another file (a fleet file's `[robots.<id>]`) carry
//! their [`OverrideOrigin`]: a problem with an overridden value (a misspelt
//! setting, a wrong type, an unknown stage id, a variable the template does not
//! use) names that file, its line and the key as written there
//! (`robots.robot_b.stages.gate.alpha`), not the template's line.

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;

use super::JobProblem;
use super::raw::LineIndex;

/// Values for a job's placeholders and settings to merge into its stages.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct JobOverrides {
    /// Placeholder name → value, over the job's own `[job] vars`.
    pub vars: BTreeMap<String, String>,
    /// Stage id → keys replacing (or adding to) that stage's settings.
    pub stage_settings: BTreeMap<String, toml::Table>,
    /// The file the overrides were written in, when not the command line.
    pub origin: Option<OverrideOrigin>,
}

/// Where overrides were written.
#[derive(Debug, Clone, PartialEq)]
pub struct OverrideOrigin {
    pub file: PathBuf,
    /// Key of the overrides' table in that file, e.g. `robots.robot_b`; below it
    /// `vars.<name>` and `stages.<stage id>.<setting>`.
    pub key: String,
    pub lines: LineIndex,
}

impl JobOverrides {
    /// A problem with the override at `relative` (`vars.cell`,
    /// `stages.gate.alpha[0]`), in the file it was written in; `None` when the
    /// overrides have no origin or the file does not hold that key.
    pub fn origin_problem(&self, relative: &str, message: &str) -> Option<JobProblem> {
        let origin = self.origin.as_ref()?;
        let key = format!("{}.{relative}", origin.key);
        let written = relative
            .split(['.', '['])
            .take(if relative.starts_with("stages.") {
                3
            } else {
                2
            })
            .collect::<Vec<_>>()
            .join(".");
        origin
            .lines
            .has(&format!("{}.{written}", origin.key))
            .then(|| JobProblem {
                file: origin.file.clone(),
                line: origin.lines.line_of(&key),
                key,
                message: message.to_string(),
            })
    }

    /// `problems` with those at a stage setting the overrides replaced moved to
    /// the file the overrides came from; `stages`: (key, id) of each stage
    /// (`stages[2]`, `gate`).
    pub fn relocate(
        &self,
        problems: Vec<JobProblem>,
        stages: &[(String, String)],
    ) -> Vec<JobProblem> {
        if self.origin.is_none() {
            return problems;
        }
        problems
            .into_iter()
            .map(|problem| {
                let moved = stages.iter().find_map(|(stage_key, id)| {
                    let rest = problem
                        .key
                        .strip_prefix(stage_key.as_str())?
                        .strip_prefix('.')?;
                    let setting = rest.split(['.', '[']).next().unwrap_or(rest);
                    self.stage_settings.get(id)?.get(setting)?;
                    self.origin_problem(&format!("stages.{id}.{rest}"), &problem.message)
                });
                moved.unwrap_or(problem)
            })
            .collect()
    }
}

impl JobOverrides {
    pub fn with_vars(vars: BTreeMap<String, String>) -> Self {
        JobOverrides {
            vars,
            ..JobOverrides::default()
        }
    }
}

/// `true` for a placeholder name: a letter or `_`, then letters, digits or `_`.
fn is_name(text: &str) -> bool {
    let mut chars = text.chars();
    chars
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// The placeholders `{name}` of `text`, in order.
pub fn placeholders(text: &str) -> Vec<&str> {
    let mut found = Vec::new();
    let mut rest = text;
    while let Some(open) = rest.find('{') {
        let after = &rest[open + 1..];
        match after.find('}') {
            Some(close) if is_name(&after[..close]) => {
                found.push(&after[..close]);
                rest = &after[close + 1..];
            }
            _ => rest = after,
        }
    }
    found
}

/// `text` with each `{name}` of `vars` replaced; other braces are left alone.
fn fill(text: &str, vars: &BTreeMap<String, String>) -> String {
    let mut out = text.to_string();
    for name in placeholders(text) {
        if let Some(value) = vars.get(name) {
            out = out.replace(&format!("{{{name}}}"), value);
        }
    }
    out
}

/// Replaces placeholders in every string of `value` (key path `path`); records the
/// names used, and each unknown one as (key path, name).
pub fn substitute(
    value: &mut toml::Value,
    path: &str,
    vars: &BTreeMap<String, String>,
    used: &mut BTreeSet<String>,
    unknown: &mut Vec<(String, String)>,
) {
    match value {
        toml::Value::String(text) => {
            for name in placeholders(text) {
                if vars.contains_key(name) {
                    used.insert(name.to_string());
                } else {
                    unknown.push((path.to_string(), name.to_string()));
                }
            }
            *text = fill(text, vars);
        }
        toml::Value::Array(items) => {
            for (i, item) in items.iter_mut().enumerate() {
                substitute(item, &format!("{path}[{i}]"), vars, used, unknown);
            }
        }
        toml::Value::Table(table) => {
            for (key, item) in table.iter_mut() {
                let inner = if path.is_empty() {
                    key.clone()
                } else {
                    format!("{path}.{key}")
                };
                substitute(item, &inner, vars, used, unknown);
            }
        }
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_names_between_braces_only() {
        assert_eq!(
            placeholders("calibration/{robot_id}/{date}.parquet"),
            ["robot_id", "date"]
        );
        assert!(placeholders("{ a = 1 }, {}, {1x}, {a-b}").is_empty());
        assert_eq!(placeholders("{{x}}"), ["x"]);
    }

    #[test]
    fn fills_known_names_and_reports_unknown_ones_by_key() {
        let mut value: toml::Value = toml::from_str(
            r#"
a = "out/{robot_id}/x"
b = ["{robot_id}", "{cell}"]
c = { d = "{robot_id}{robot_id}" }
"#,
        )
        .unwrap();
        let vars = BTreeMap::from([("robot_id".to_string(), "r7".to_string())]);
        let (mut used, mut unknown) = (BTreeSet::new(), Vec::new());
        substitute(&mut value, "", &vars, &mut used, &mut unknown);
        assert_eq!(value["a"].as_str(), Some("out/r7/x"));
        assert_eq!(value["b"][0].as_str(), Some("r7"));
        assert_eq!(value["b"][1].as_str(), Some("{cell}"));
        assert_eq!(value["c"]["d"].as_str(), Some("r7r7"));
        assert_eq!(unknown, [("b[1]".to_string(), "cell".to_string())]);
        assert!(used.contains("robot_id"));
    }

    #[test]
    fn a_value_with_quotes_stays_one_string() {
        let mut value = toml::Value::String("{x}".into());
        let vars = BTreeMap::from([("x".to_string(), "a\"\n[job]".to_string())]);
        substitute(
            &mut value,
            "k",
            &vars,
            &mut BTreeSet::new(),
            &mut Vec::new(),
        );
        assert_eq!(value.as_str(), Some("a\"\n[job]"));
    }
}
