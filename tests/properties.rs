//! Property tests: arbitrary bytes and arbitrary TOML values fed to the job-file
//! parser (both phases, every stage kind's settings), the robot-file parser, the
//! table checks and the driver-reply parser. Each must answer with a value or an
//! error, never a panic. `PROPTEST_CASES` raises the number of cases.

mod common;

use std::path::Path;

use egcal::robot::RobotSpec;
use egcal::stages;
use egcal::table::schema;
use polars::prelude::{Column, DataFrame, DataType};
use proptest::prelude::*;

/// Arbitrary TOML values a user could type, weighted towards the awkward ones:
/// non-finite and huge numbers, negative counts, empty and nested arrays.
fn toml_value() -> impl Strategy<Value = toml::Value> {
    let leaf = prop_oneof![
        any::<i64>().prop_map(toml::Value::Integer),
        prop_oneof![-3i64..=3, Just(i64::MAX), Just(i64::MIN)].prop_map(toml::Value::Integer),
        any::<f64>().prop_map(toml::Value::Float),
        prop_oneof![
            Just(f64::NAN),
            Just(f64::INFINITY),
            Just(f64::NEG_INFINITY),
            Just(1e300),
            Just(-1e300),
            Just(0.0),
            Just(-0.0),
            Just(-1.0),
        ]
        .prop_map(toml::Value::Float),
        any::<bool>().prop_map(toml::Value::Boolean),
        "[a-z_]{0,12}".prop_map(toml::Value::String),
        ".{0,8}".prop_map(toml::Value::String),
    ];
    leaf.prop_recursive(3, 16, 4, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..7).prop_map(toml::Value::Array),
            prop::collection::btree_map("[a-z_]{1,10}", inner, 0..4)
                .prop_map(|m| toml::Value::Table(m.into_iter().collect())),
        ]
    })
}

/// The setting names of a stage kind, so that generated keys hit real settings
/// most of the time.
fn setting_names(kind: &dyn stages::StageKind) -> Vec<String> {
    kind.settings_schema()["properties"]
        .as_object()
        .map(|p| p.keys().cloned().collect())
        .unwrap_or_default()
}

fn settings_for(kind_index: usize) -> impl Strategy<Value = toml::Table> {
    let kind = stages::registry()[kind_index];
    let mut names = setting_names(kind);
    names.push("not_a_setting".into());
    prop::collection::vec((prop::sample::select(names), toml_value()), 0..5)
        .prop_map(|pairs| pairs.into_iter().collect())
}

fn any_kind_and_settings() -> impl Strategy<Value = (usize, toml::Table)> {
    (0..stages::registry().len()).prop_flat_map(|k| (Just(k), settings_for(k)))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn job_text_of_any_bytes_is_answered(bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        let text = String::from_utf8_lossy(&bytes);
        let _ = egcal::job::raw::parse(&text, Path::new("job.toml"));
    }

    #[test]
    fn any_settings_values_are_answered((kind_index, settings) in any_kind_and_settings()) {
        let kind = stages::registry()[kind_index];
        let answer = kind.canonical_settings(&settings);
        // A NaN or an infinity is never a valid setting: it must be refused, not
        // turned into null or a default on the way to the stage.
        if settings.values().any(has_non_finite) {
            prop_assert!(answer.is_err(), "accepted {settings:?}");
        }
    }

    #[test]
    fn whole_job_files_with_any_settings_are_answered(
        (kind_index, settings) in any_kind_and_settings(),
        seed in any::<i64>(),
    ) {
        let dir = tempfile::tempdir().expect("tempdir");
        let kind = stages::registry()[kind_index].info().kind;
        let robot = common::root().join("jobs/robots/irb1600_145.toml");
        let mut stage = settings.clone();
        stage.insert("id".into(), toml::Value::String("s".into()));
        stage.insert("kind".into(), toml::Value::String(kind.into()));
        let mut job = toml::Table::new();
        job.insert("name".into(), "p".into());
        job.insert("seed".into(), toml::Value::Integer(seed));
        job.insert("robot".into(), robot.display().to_string().into());
        let mut root = toml::Table::new();
        root.insert("job".into(), toml::Value::Table(job));
        root.insert("stages".into(), toml::Value::Array(vec![toml::Value::Table(stage)]));
        // Some generated trees have no TOML text (a table inside an inline array);
        // every one that does must be answered.
        if let Ok(text) = toml::to_string(&root) {
            let path = dir.path().join("job.toml");
            std::fs::write(&path, text).expect("write job");
            let _ = egcal::job::Plan::load(&path);
        }
    }

    #[test]
    fn robot_text_of_any_bytes_is_answered(bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        let _ = RobotSpec::parse(&String::from_utf8_lossy(&bytes), Path::new("arm.toml"));
    }

    #[test]
    fn a_robot_file_with_any_value_replaced_is_answered(
        which in any::<prop::sample::Index>(),
        value in toml_value(),
    ) {
        let text = std::fs::read_to_string(common::root().join("jobs/robots/irb1600_145.toml"))
            .expect("robot file");
        let mut table: toml::Table = toml::from_str(&text).expect("shipped file parses");
        replace_nth_leaf(&mut table, which, value);
        if let Ok(mutated) = toml::to_string(&table)
            && let Ok(spec) = RobotSpec::parse(&mutated, Path::new("arm.toml"))
        {
            // An accepted robot predicts finite positions at its home pose.
            let robot = egcal::robot::Robot::new(spec);
            let nominal = egcal::robot::ParamValues::nominal(robot.spec());
            let row = egcal::robot::ConfWrench::new([0.0; 7], egcal::robot::Wrench::zero());
            let p = egcal::robot::batch_predict(&robot, &nominal, &[row]);
            prop_assert!(p[0].position_mm.iter().all(|v| v.is_finite()));
        }
    }

    #[test]
    fn any_table_is_checked_without_panic(columns in table_columns()) {
        if let Ok(df) = DataFrame::new_infer_height(columns) {
            for schema in schema::all() {
                let _ = schema.check(&df, Path::new("t.parquet"));
            }
        }
    }

    #[test]
    fn driver_replies_of_any_bytes_are_answered(bytes in prop::collection::vec(any::<u8>(), 0..300)) {
        let line = String::from_utf8_lossy(&bytes);
        let _ = serde_json::from_str::<egcal::rig::protocol::Reply>(&line);
    }

    #[test]
    fn driver_replies_of_any_json_are_answered(value in json_value()) {
        let _ = serde_json::from_value::<egcal::rig::protocol::Reply>(value);
    }
}

fn has_non_finite(value: &toml::Value) -> bool {
    match value {
        toml::Value::Float(f) => !f.is_finite(),
        toml::Value::Array(items) => items.iter().any(has_non_finite),
        toml::Value::Table(t) => t.values().any(has_non_finite),
        _ => false,
    }
}

/// Replaces the `which`-th scalar of a TOML tree (depth first) with `value`.
fn replace_nth_leaf(table: &mut toml::Table, which: prop::sample::Index, value: toml::Value) {
    fn leaves<'a>(v: &'a mut toml::Value, out: &mut Vec<&'a mut toml::Value>) {
        match v {
            toml::Value::Table(t) => t.iter_mut().for_each(|(_, c)| leaves(c, out)),
            toml::Value::Array(a) => a.iter_mut().for_each(|c| leaves(c, out)),
            other => out.push(other),
        }
    }
    let mut all = Vec::new();
    for (_, v) in table.iter_mut() {
        leaves(v, &mut all);
    }
    if !all.is_empty() {
        let i = which.index(all.len());
        *all[i] = value;
    }
}

/// Columns named like the schemas' (and a few others), of any type, with
/// non-finite values and nulls among them.
fn table_columns() -> impl Strategy<Value = Vec<Column>> {
    let names: Vec<String> = schema::all()
        .iter()
        .flat_map(|s| s.columns.iter().map(|c| c.name.to_string()))
        .chain(["extra".to_string()])
        .collect();
    let column = (prop::sample::select(names), 0usize..4, 0usize..5).prop_map(|(name, kind, n)| {
        let name = name.as_str().into();
        match kind {
            0 => Column::new(
                name,
                (0..n)
                    .map(|i| [f64::NAN, 1.0, f64::INFINITY, -1e300, 0.5][i % 5])
                    .collect::<Vec<_>>(),
            ),
            1 => Column::new(
                name,
                (0..n)
                    .map(|i| if i % 2 == 0 { Some(i as i64) } else { None })
                    .collect::<Vec<_>>(),
            ),
            2 => Column::new(name, (0..n).map(|i| format!("v{i}")).collect::<Vec<_>>()),
            _ => Column::new(name, vec![1i64; n])
                .cast(&DataType::Int32)
                .expect("casts"),
        }
    });
    prop::collection::vec(column, 0..8).prop_map(|mut cols| {
        let mut seen = std::collections::HashSet::new();
        cols.retain(|c| seen.insert(c.name().to_string()));
        cols
    })
}

fn json_value() -> impl Strategy<Value = serde_json::Value> {
    let leaf = prop_oneof![
        Just(serde_json::Value::Null),
        any::<bool>().prop_map(serde_json::Value::Bool),
        any::<i64>().prop_map(|i| serde_json::json!(i)),
        any::<u64>().prop_map(|i| serde_json::json!(i)),
        any::<f64>().prop_map(|f| serde_json::json!(f)),
        ".{0,6}".prop_map(serde_json::Value::String),
    ];
    leaf.prop_recursive(3, 24, 6, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..7).prop_map(serde_json::Value::Array),
            prop::collection::btree_map(
                prop::sample::select(vec![
                    "id",
                    "result",
                    "error",
                    "message",
                    "transient",
                    "q_deg",
                    "wrench",
                    "position_mm",
                    "protocol",
                    "name",
                    "capabilities",
                    "measured_at_us",
                    "x",
                ]),
                inner,
                0..4
            )
            .prop_map(|m| serde_json::Value::Object(
                m.into_iter().map(|(k, v)| (k.to_string(), v)).collect()
            )),
        ]
    })
}

/// Every setting of every stage kind, given NaN or an infinity on its own, is
/// refused (deterministic companion of `any_settings_values_are_answered`).
#[test]
fn each_setting_refuses_non_finite_numbers() {
    for kind in stages::registry() {
        for name in setting_names(kind) {
            for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
                let mut settings = toml::Table::new();
                settings.insert(name.clone(), toml::Value::Float(bad));
                assert!(
                    kind.canonical_settings(&settings).is_err(),
                    "{}: `{name} = {bad}` accepted",
                    kind.info().kind
                );
            }
        }
    }
}
