//! Range checks of stage settings against their JSON Schema.
//!
//! A setting's range is declared once, on its settings type
//! (`#[schemars(range(min = .., max = ..))]`, exclusive bounds with
//! `#[schemars(extend("exclusiveMinimum" = ..))]`), so `egcal list-stages`, the
//! published JSON Schema and job-file validation cannot disagree. This module walks
//! a settings value (canonical JSON) beside its schema and reports every value
//! outside its range with its key; it knows nothing of any particular stage.
//!
//! Non-finite floats are checked on the raw TOML instead, before serde: JSON has no
//! NaN, so `serde_json` would turn one into `null` and lose the key.

use serde_json::{Map, Value};

use super::SettingsProblem;

/// Every value of `settings` outside the bounds its schema declares (`minimum`,
/// `maximum`, `exclusiveMinimum`, `exclusiveMaximum`, `minItems`, `maxItems`,
/// `minLength`, `maxLength`), with keys like `simulator.tracker_noise_mm` or
/// `centre_mm[2]`.
pub fn range_problems(settings: &Value, schema: &Value) -> Vec<SettingsProblem> {
    let mut problems = Vec::new();
    walk(settings, schema, schema, "", &mut problems);
    problems
}

/// Every non-finite float (nan, inf, -inf) in a settings table, by key.
pub fn non_finite_problems(raw: &toml::Table) -> Vec<SettingsProblem> {
    let mut problems = Vec::new();
    for (key, value) in raw {
        non_finite(value, key, &mut problems);
    }
    problems
}

fn non_finite(value: &toml::Value, key: &str, problems: &mut Vec<SettingsProblem>) {
    match value {
        toml::Value::Float(f) if !f.is_finite() => problems.push(SettingsProblem {
            key: key.to_string(),
            // Spelled as TOML spells it.
            message: format!(
                "`{key}` is {}; expected a finite number",
                if f.is_nan() {
                    "nan".to_string()
                } else {
                    f.to_string()
                }
            ),
        }),
        toml::Value::Array(items) => {
            for (i, item) in items.iter().enumerate() {
                non_finite(item, &format!("{key}[{i}]"), problems);
            }
        }
        toml::Value::Table(table) => {
            for (k, v) in table {
                non_finite(v, &format!("{key}.{k}"), problems);
            }
        }
        _ => {}
    }
}

/// The schema `#/$defs/Name` (or `#/definitions/Name`) names, if any.
fn resolve<'a>(reference: &str, root: &'a Value) -> Option<&'a Value> {
    let pointer = reference.strip_prefix('#')?;
    root.pointer(pointer)
}

fn join(path: &str, key: &str) -> String {
    if path.is_empty() {
        key.to_string()
    } else {
        format!("{path}.{key}")
    }
}

/// Whether `schema` (after `$ref`) admits values of `value`'s JSON type; schemas
/// without a `type` admit anything.
fn admits_type(value: &Value, schema: &Value, root: &Value) -> bool {
    let schema = match schema.get("$ref").and_then(Value::as_str) {
        Some(r) => match resolve(r, root) {
            Some(s) => s,
            None => return true,
        },
        None => schema,
    };
    let matches = |t: &str| match t {
        "null" => value.is_null(),
        "boolean" => value.is_boolean(),
        "integer" => value.is_i64() || value.is_u64(),
        "number" => value.is_number(),
        "string" => value.is_string(),
        "array" => value.is_array(),
        "object" => value.is_object(),
        _ => true,
    };
    match schema.get("type") {
        Some(Value::String(t)) => matches(t),
        Some(Value::Array(types)) => types.iter().filter_map(Value::as_str).any(matches),
        _ => {
            if let Some(constant) = schema.get("const") {
                return constant == value;
            }
            if let Some(Value::Array(options)) = schema.get("enum") {
                return options.contains(value);
            }
            true
        }
    }
}

fn walk(value: &Value, schema: &Value, root: &Value, path: &str, out: &mut Vec<SettingsProblem>) {
    let Some(schema_obj) = schema.as_object() else {
        return;
    };
    if let Some(target) = schema_obj
        .get("$ref")
        .and_then(Value::as_str)
        .and_then(|r| resolve(r, root))
    {
        walk(value, target, root, path, out);
    }
    if let Some(Value::Array(all)) = schema_obj.get("allOf") {
        for sub in all {
            walk(value, sub, root, path, out);
        }
    }
    // An Option or an untagged enum: check against the first branch of the value's type.
    for key in ["anyOf", "oneOf"] {
        if let Some(Value::Array(branches)) = schema_obj.get(key)
            && let Some(branch) = branches.iter().find(|b| admits_type(value, b, root))
        {
            walk(value, branch, root, path, out);
        }
    }
    match value {
        Value::Number(n) => {
            if let Some(x) = n.as_f64() {
                check_number(x, schema_obj, path, out);
            }
        }
        Value::String(s) => check_count(
            s.chars().count(),
            "Length",
            "characters",
            schema_obj,
            path,
            out,
        ),
        Value::Array(items) => {
            check_count(items.len(), "Items", "items", schema_obj, path, out);
            let prefix = schema_obj.get("prefixItems").and_then(Value::as_array);
            for (i, item) in items.iter().enumerate() {
                let item_schema = prefix
                    .and_then(|p| p.get(i))
                    .or_else(|| schema_obj.get("items").filter(|s| s.is_object()));
                if let Some(item_schema) = item_schema {
                    walk(item, item_schema, root, &format!("{path}[{i}]"), out);
                }
            }
        }
        Value::Object(map) => walk_object(map, schema_obj, root, path, out),
        Value::Null | Value::Bool(_) => {}
    }
}

fn walk_object(
    map: &Map<String, Value>,
    schema: &Map<String, Value>,
    root: &Value,
    path: &str,
    out: &mut Vec<SettingsProblem>,
) {
    let properties = schema.get("properties").and_then(Value::as_object);
    let additional = schema.get("additionalProperties").filter(|s| s.is_object());
    for (key, item) in map {
        let item_schema = properties.and_then(|p| p.get(key)).or(additional);
        if let Some(item_schema) = item_schema {
            walk(item, item_schema, root, &join(path, key), out);
        }
    }
}

/// The range a setting's schema declares, for `egcal list-stages`: `[0, 1]`, `each
/// in [-100000, 100000]` for arrays and maps; `None` without bounds.
pub fn range_text(schema: &Value, root: &Value) -> Option<String> {
    let schema = match schema.get("$ref").and_then(Value::as_str) {
        Some(r) => resolve(r, root)?,
        None => schema,
    };
    let obj = schema.as_object()?;
    let bounded = ["minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum"]
        .iter()
        .any(|k| obj.contains_key(*k));
    if bounded {
        return Some(interval(obj));
    }
    if let Some(inner) = obj
        .get("items")
        .or_else(|| obj.get("additionalProperties"))
        .filter(|s| s.is_object())
    {
        return range_text(inner, root).map(|r| format!("each in {r}"));
    }
    ["anyOf", "oneOf"]
        .iter()
        .filter_map(|k| obj.get(*k).and_then(Value::as_array))
        .flatten()
        .find_map(|branch| range_text(branch, root))
}

/// A number as text: Rust's shortest form, so `1` not `1.0` and `0.02` exact.
fn show(x: f64) -> String {
    format!("{x}")
}

/// The whole declared range in interval notation, e.g. `[0, 1]` or `(0, ∞)`.
fn interval(schema: &Map<String, Value>) -> String {
    let bound = |key: &str| schema.get(key).and_then(Value::as_f64);
    let lower = match (bound("exclusiveMinimum"), bound("minimum")) {
        (Some(x), _) => format!("({}", show(x)),
        (None, Some(x)) => format!("[{}", show(x)),
        (None, None) => "(-∞".to_string(),
    };
    let upper = match (bound("exclusiveMaximum"), bound("maximum")) {
        (Some(x), _) => format!("{})", show(x)),
        (None, Some(x)) => format!("{}]", show(x)),
        (None, None) => "∞)".to_string(),
    };
    format!("{lower}, {upper}")
}

fn check_number(x: f64, schema: &Map<String, Value>, path: &str, out: &mut Vec<SettingsProblem>) {
    let bound = |key: &str| schema.get(key).and_then(Value::as_f64);
    let violated = [
        ("≥", bound("minimum").filter(|&m| x < m)),
        (">", bound("exclusiveMinimum").filter(|&m| x <= m)),
        ("≤", bound("maximum").filter(|&m| x > m)),
        ("<", bound("exclusiveMaximum").filter(|&m| x >= m)),
    ]
    .into_iter()
    .find_map(|(sign, b)| b.map(|b| (sign, b)));
    if let Some((sign, b)) = violated {
        out.push(SettingsProblem {
            key: path.to_string(),
            message: format!(
                "`{path}` is {}; expected {sign} {} (range {})",
                show(x),
                show(b),
                interval(schema)
            ),
        });
    }
}

fn check_count(
    n: usize,
    suffix: &str,
    what: &str,
    schema: &Map<String, Value>,
    path: &str,
    out: &mut Vec<SettingsProblem>,
) {
    let bound = |key: String| schema.get(&key).and_then(Value::as_u64);
    if let Some(min) = bound(format!("min{suffix}")).filter(|&m| (n as u64) < m) {
        out.push(SettingsProblem {
            key: path.to_string(),
            message: format!("`{path}` has {n} {what}; expected at least {min}"),
        });
    }
    if let Some(max) = bound(format!("max{suffix}")).filter(|&m| (n as u64) > m) {
        out.push(SettingsProblem {
            key: path.to_string(),
            message: format!("`{path}` has {n} {what}; expected at most {max}"),
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn schema() -> Value {
        json!({
            "type": "object",
            "properties": {
                "noise_mm": { "type": "number", "minimum": 0.0 },
                "edge_mm": { "type": "number", "exclusiveMinimum": 0.0, "maximum": 1e4 },
                "restarts": { "type": "integer", "minimum": 1, "maximum": 1000 },
                "fraction": { "type": "number", "exclusiveMinimum": 0.0, "exclusiveMaximum": 1.0 },
                "centre_mm": { "type": "array", "items": { "type": "number", "minimum": -1e4 } },
                "pair": { "type": "array", "prefixItems": [ { "type": "integer" }, { "type": "integer", "minimum": 5 } ] },
                "tracker_mm": { "type": ["number", "null"], "minimum": 0.0 },
                "optional": { "anyOf": [ { "$ref": "#/$defs/Inner" }, { "type": "null" } ] },
                "inner": { "$ref": "#/$defs/Inner" },
                "offsets": { "type": "object", "additionalProperties": { "type": "number", "maximum": 1.0 } },
                "models": { "type": "array", "items": { "type": "string" }, "minItems": 1 },
                "fixed": { "type": "object", "additionalProperties": { "$ref": "#/$defs/Fixed" } }
            },
            "$defs": {
                "Inner": { "type": "object", "properties": { "sigma": { "type": "number", "minimum": 0.0 } } },
                "Fixed": { "anyOf": [ { "type": "number", "minimum": -5.0 }, { "type": "string" } ] }
            }
        })
    }

    fn keys(value: Value) -> Vec<String> {
        range_problems(&value, &schema())
            .into_iter()
            .map(|p| p.key)
            .collect()
    }

    #[test]
    fn values_in_range_pass() {
        let ok = json!({
            "noise_mm": 0.0, "edge_mm": 1e4, "restarts": 1, "fraction": 0.5,
            "centre_mm": [0.0, -1e4, 3.0], "pair": [-3, 5], "tracker_mm": null,
            "optional": null, "inner": { "sigma": 0.0 }, "offsets": { "a": 1.0 },
            "models": ["x"], "fixed": { "k6": "nominal", "dd5": -5.0 }
        });
        assert!(keys(ok).is_empty());
    }

    #[test]
    fn each_kind_of_bound_is_enforced_with_its_key() {
        let bad = json!({
            "noise_mm": -0.02, "edge_mm": 0.0, "restarts": 0, "fraction": 1.0,
            "centre_mm": [0.0, 0.0, -2e4], "pair": [0, 4], "tracker_mm": -1.0,
            "optional": { "sigma": -1.0 }, "inner": { "sigma": -2.0 },
            "offsets": { "a": 2.0 }, "models": [], "fixed": { "dd5": -6.0 }
        });
        let mut got = keys(bad);
        got.sort();
        let mut want = vec![
            "noise_mm",
            "edge_mm",
            "restarts",
            "fraction",
            "centre_mm[2]",
            "pair[1]",
            "tracker_mm",
            "optional.sigma",
            "inner.sigma",
            "offsets.a",
            "models",
            "fixed.dd5",
        ];
        want.sort();
        assert_eq!(got, want);
    }

    #[test]
    fn message_names_value_bound_and_range() {
        let problems = range_problems(&json!({ "noise_mm": -0.02 }), &schema());
        assert_eq!(
            problems[0].message,
            "`noise_mm` is -0.02; expected ≥ 0 (range [0, ∞))"
        );
        let problems = range_problems(&json!({ "edge_mm": -5.0 }), &schema());
        assert_eq!(
            problems[0].message,
            "`edge_mm` is -5; expected > 0 (range (0, 10000])"
        );
    }

    #[test]
    fn range_text_reads_bounds_through_refs_items_and_maps() {
        let root = schema();
        let text = |key: &str| range_text(&root["properties"][key], &root);
        assert_eq!(text("noise_mm").as_deref(), Some("[0, ∞)"));
        assert_eq!(text("fraction").as_deref(), Some("(0, 1)"));
        assert_eq!(text("centre_mm").as_deref(), Some("each in [-10000, ∞)"));
        assert_eq!(text("offsets").as_deref(), Some("each in (-∞, 1]"));
        assert_eq!(text("fixed").as_deref(), Some("each in [-5, ∞)"));
        assert_eq!(text("models"), None);
    }

    #[test]
    fn non_finite_floats_are_found_by_key() {
        let raw: toml::Table = toml::from_str(
            "edge_mm = nan\nok = 1.0\ncentre_mm = [0.0, inf, 1.0]\n[simulator]\ntracker_noise_mm = -inf\n",
        )
        .unwrap();
        let problems = non_finite_problems(&raw);
        let keys: Vec<&str> = problems.iter().map(|p| p.key.as_str()).collect();
        assert_eq!(
            keys,
            ["centre_mm[1]", "edge_mm", "simulator.tracker_noise_mm"]
        );
        assert_eq!(
            problems[1].message,
            "`edge_mm` is nan; expected a finite number"
        );
    }
}
