//! The committed schema files are generated from the Rust types; this fails when
//! they are stale. Regenerate with `cargo run -- schemas --out schemas`.

mod common;

#[test]
fn committed_schemas_match_the_code() {
    let dir = common::root().join("schemas");
    let mut stale = Vec::new();
    for (name, text) in egcal::commands::generated_schemas() {
        let committed = std::fs::read_to_string(dir.join(&name)).unwrap_or_default();
        if committed != text {
            stale.push(name);
        }
    }
    assert!(
        stale.is_empty(),
        "stale schema files {stale:?}: run `cargo run -- schemas --out schemas` and commit them"
    );
}

#[test]
fn committed_guide_reference_pages_match_the_code() {
    let dir = common::root().join("docs/reference");
    let mut stale = Vec::new();
    for (name, text) in egcal::commands::reference::generated_guide_pages() {
        let committed = std::fs::read_to_string(dir.join(&name)).unwrap_or_default();
        if committed != text {
            stale.push(name);
        }
    }
    assert!(
        stale.is_empty(),
        "stale guide pages {stale:?}: run `cargo run -- schemas --out schemas --guide docs/reference` and commit them"
    );
}

#[test]
fn the_job_schema_accepts_the_shipped_jobs_stage_kinds() {
    let schema: serde_json::Value =
        serde_json::from_str(&egcal::job::schema::job_schema_json()).unwrap();
    let kinds: Vec<&str> = schema["properties"]["stages"]["items"]["oneOf"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v["properties"]["kind"]["const"].as_str().unwrap())
        .collect();
    for kind in egcal::stages::registry().iter().map(|k| k.info().kind) {
        assert!(kinds.contains(&kind), "{kind} missing from the job schema");
    }
    let wrenches = schema["properties"]["stages"]["items"]["oneOf"]
        .as_array()
        .unwrap()
        .iter()
        .find(|v| v["properties"]["kind"]["const"] == "wrenches")
        .unwrap();
    assert!(wrenches["properties"]["per_config"].is_object());
    assert_eq!(wrenches["additionalProperties"], false);
}
