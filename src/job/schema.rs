//! The job file's JSON Schema, generated from the Rust types: the `[job]` header
//! struct and, per stage kind, its settings struct plus `id`, `kind` and `inputs`.
//! TOML language servers (taplo, Even Better TOML) use it for completion and checks.
//! `schemas/job.schema.json` is this output; a test fails when it is stale.

use serde_json::{Value, json};

use super::raw::JobHeader;
use crate::stages;

/// The schema as pretty JSON with a trailing newline (the committed file's form).
pub fn job_schema_json() -> String {
    let mut text = serde_json::to_string_pretty(&job_schema()).expect("schema serialises");
    text.push('\n');
    text
}

pub fn job_schema() -> Value {
    let header = serde_json::to_value(schemars::schema_for!(JobHeader)).expect("schema serialises");
    let mut definitions = serde_json::Map::new();
    let mut variants = Vec::new();
    for kind in stages::registry() {
        let info = kind.info();
        let mut settings = kind.settings_schema();
        let object = settings
            .as_object_mut()
            .expect("settings schema is an object");
        if let Some(Value::Object(defs)) = object.remove("$defs") {
            definitions.extend(defs);
        }
        let mut properties = object
            .remove("properties")
            .and_then(|p| p.as_object().cloned())
            .unwrap_or_default();
        properties.insert("id".into(), json!({"type": "string", "pattern": "^[A-Za-z0-9_-]+$", "description": "Unique stage id"}));
        properties.insert(
            "kind".into(),
            json!({"const": info.kind, "description": info.summary}),
        );
        let inputs: serde_json::Map<String, Value> = info
            .inputs
            .iter()
            .map(|slot| {
                (
                    slot.name.to_string(),
                    json!({
                        "type": "string",
                        "description": format!("{} ({} table): `stage`, `stage.table`, or a .parquet path or glob relative to the job file", slot.meaning, (slot.schema)().kind),
                    }),
                )
            })
            .collect();
        let required_inputs: Vec<&str> = info
            .inputs
            .iter()
            .filter(|s| s.required)
            .map(|s| s.name)
            .collect();
        properties.insert(
            "inputs".into(),
            json!({"type": "object", "properties": inputs, "required": required_inputs, "additionalProperties": false}),
        );
        let mut required = vec!["id", "kind"];
        if !required_inputs.is_empty() {
            required.push("inputs");
        }
        variants.push(json!({
            "title": info.kind,
            "description": info.summary,
            "type": "object",
            "properties": properties,
            "required": required,
            "additionalProperties": false,
        }));
    }
    json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "egcal job file",
        "type": "object",
        "properties": {
            "job": header,
            "stages": {"type": "array", "items": {"oneOf": variants}},
        },
        "required": ["job", "stages"],
        "additionalProperties": false,
        "$defs": definitions,
    })
}
