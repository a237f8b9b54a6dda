//! What a caller changes in a job file without editing it: values of its `{name}`
//! placeholders (`[job] vars` gives the defaults, `egcal run --var` and a fleet's
//! robots override them) and, for a fleet's per-robot settings, whole keys of a
//! stage's table.
//!
//! Placeholders are replaced inside string values of the parsed TOML, never in the
//! text, so a value cannot change the file's structure and every problem keeps the
//! line of its key.

use std::collections::{BTreeMap, BTreeSet};

/// Values for a job's placeholders and settings to merge into its stages.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct JobOverrides {
    /// Placeholder name → value, over the job's own `[job] vars`.
    pub vars: BTreeMap<String, String>,
    /// Stage id → keys replacing (or adding to) that stage's settings.
    pub stage_settings: BTreeMap<String, toml::Table>,
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
