//! The CLI's commands as library functions (so tests call them directly); `main.rs`
//! only parses arguments, dispatches here and maps errors to exit codes.

pub mod frame;
pub mod pose;
pub mod reference;

pub use frame::frame_command as frame;
pub use pose::pose_command as pose;
pub use reference::list_stages;

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use polars::prelude::*;

use crate::cdpr::CableRobotSpec;
use crate::exit_code::{self, Finished};
use crate::job::{InputSource, JobOverrides, JobProblems, Plan};
use crate::job_run;
use crate::robot::{Robot, RobotSpec};
use crate::runner::{self, RunError, RunOptions};
use crate::stages::{self, InputTable, StageContext, StageError};
use crate::table::{self, Provenance, TableError};

/// A failed command, with the exit code the binary returns.
#[derive(Debug, thiserror::Error)]
pub enum CommandError {
    #[error("{0}")]
    Usage(String),
    #[error(transparent)]
    Job(#[from] JobProblems),
    #[error(transparent)]
    Table(Box<TableError>),
    #[error(transparent)]
    Run(Box<RunError>),
    #[error(transparent)]
    Robot(#[from] crate::robot::file::RobotFileError),
    #[error("stage `{kind}` failed: {source}")]
    Stage {
        kind: String,
        source: Box<StageError>,
    },
    #[error(transparent)]
    Fleet(Box<crate::fleet::FleetError>),
    #[error(transparent)]
    Fixture(Box<crate::fixture_cases::FixtureError>),
}

impl From<TableError> for CommandError {
    fn from(e: TableError) -> Self {
        CommandError::Table(Box::new(e))
    }
}

impl From<RunError> for CommandError {
    fn from(e: RunError) -> Self {
        CommandError::Run(Box::new(e))
    }
}

impl CommandError {
    pub fn exit_code(&self) -> u8 {
        match self {
            CommandError::Usage(_)
            | CommandError::Job(_)
            | CommandError::Table(_)
            | CommandError::Robot(_) => exit_code::BAD_INPUT,
            CommandError::Stage { source, .. } => exit_code::of_stage_error(source),
            CommandError::Fleet(e) => e.exit_code(),
            CommandError::Fixture(e) => e.exit_code(),
            CommandError::Run(e) => exit_code::of_run_error(e),
        }
    }
}

/// `egcal run`.
pub fn run(
    job: &Path,
    overrides: &JobOverrides,
    options: &RunOptions,
    quiet: bool,
) -> Result<Finished, CommandError> {
    let plan = Plan::load_with(job, overrides)?;
    Ok(job_run::run_plan(plan, options, quiet)?)
}

/// `egcal status`.
pub fn status(
    job: &Path,
    overrides: &JobOverrides,
    run_date: Option<i64>,
) -> Result<String, CommandError> {
    let mut plan = Plan::load_with(job, overrides)?;
    if let Some(day) = run_date {
        plan.run_date = day;
    }
    let mut out = String::new();
    for s in runner::status(&plan)? {
        if s.cached {
            writeln!(out, "{:<20} cached", s.stage).expect("write to string");
        } else {
            writeln!(out, "{:<20} stale: {}", s.stage, s.reasons.join("; "))
                .expect("write to string");
        }
    }
    Ok(out)
}

/// `egcal check`: the plan, the files stages import read as `run` reads them
/// ([`Plan::load_checked`]), and each external input's data checked against its schema.
pub fn check(job: &Path, overrides: &JobOverrides) -> Result<String, CommandError> {
    let plan = Plan::load_checked(job, overrides)?;
    let mut out = format!(
        "{}: {} stage(s) ok; robot {}; output {}\n",
        plan.name,
        plan.stages.len(),
        plan.robot_file.display(),
        plan.output_dir.display()
    );
    for stage in &plan.stages {
        for (name, source) in &stage.inputs {
            if let InputSource::Files { paths, .. } = source {
                let slot = stage
                    .kind
                    .info()
                    .inputs
                    .iter()
                    .find(|s| s.name == name)
                    .expect("declared input");
                for path in paths {
                    let df = table::read_checked(path, &(slot.schema)())?;
                    writeln!(
                        out,
                        "  {}.{name}: {} ({} rows) ok",
                        stage.id,
                        path.display(),
                        df.height()
                    )
                    .expect("write to string");
                }
            }
        }
    }
    Ok(out)
}

/// `egcal dag`: Mermaid (default) or Graphviz DOT.
pub fn dag(job: &Path, dot: bool) -> Result<String, CommandError> {
    let plan = Plan::load(job)?;
    let mut out = String::new();
    if dot {
        out.push_str("digraph job {\n  rankdir=LR;\n");
    } else {
        out.push_str("flowchart LR\n");
    }
    for stage in &plan.stages {
        let label = format!("{} ({})", stage.id, stage.kind.info().kind);
        if dot {
            writeln!(out, "  \"{}\" [label=\"{label}\", shape=box];", stage.id).expect("write");
        } else {
            writeln!(out, "  {}[\"{label}\"]", stage.id).expect("write");
        }
        for (name, source) in &stage.inputs {
            match source {
                InputSource::Stage { stage: up, table } => {
                    if dot {
                        writeln!(
                            out,
                            "  \"{up}\" -> \"{}\" [label=\"{table} -> {name}\"];",
                            stage.id
                        )
                        .expect("write");
                    } else {
                        writeln!(out, "  {up} -->|{table}| {}", stage.id).expect("write");
                    }
                }
                InputSource::Files { pattern, .. } => {
                    let node = format!("{}__{name}", stage.id);
                    if dot {
                        writeln!(out, "  \"{node}\" [label=\"{pattern}\", shape=note];\n  \"{node}\" -> \"{}\";", stage.id)
                            .expect("write");
                    } else {
                        writeln!(out, "  {node}[/\"{pattern}\"/] --> {}", stage.id).expect("write");
                    }
                }
            }
        }
    }
    if dot {
        out.push_str("}\n");
    }
    Ok(out)
}

/// `egcal show`: schema, provenance and the first rows of a Parquet file.
pub fn show(path: &Path, rows: usize) -> Result<String, CommandError> {
    let footer = table::read_footer(path)?;
    let mut out = format!("{}: {} rows\n\ncolumns:\n", path.display(), footer.rows);
    for (name, dtype) in &footer.columns {
        writeln!(out, "  {name:<16} {dtype}").expect("write");
    }
    match table::read_provenance(path)? {
        Some(p) => {
            writeln!(out, "\nprovenance:").expect("write");
            let json = serde_json::to_string_pretty(&p).expect("provenance serialises");
            for line in json.lines() {
                writeln!(out, "  {line}").expect("write");
            }
        }
        None => writeln!(out, "\nprovenance: none (not written by egcal)").expect("write"),
    }
    let file = std::fs::File::open(path).map_err(|e| table::schema::io_error(path, e))?;
    let head = ParquetReader::new(file)
        .with_slice(Some((0, rows)))
        .finish()
        .map_err(|e| table::schema::io_error(path, e))?;
    writeln!(
        out,
        "\nfirst {} rows:\n{}",
        head.height(),
        format_rows(&head)
    )
    .expect("write");
    Ok(out)
}

/// A plain aligned text rendering of a small frame.
fn format_rows(df: &DataFrame) -> String {
    let mut cells: Vec<Vec<String>> = Vec::new();
    for column in df.columns() {
        let mut col = vec![column.name().to_string()];
        let text = column.cast(&DataType::String).ok();
        for row in 0..df.height() {
            let value = text
                .as_ref()
                .and_then(|t| t.str().ok().and_then(|s| s.get(row).map(str::to_string)))
                .unwrap_or_else(|| "null".into());
            col.push(value);
        }
        cells.push(col);
    }
    let widths: Vec<usize> = cells
        .iter()
        .map(|c| c.iter().map(|s| s.chars().count()).max().unwrap_or(0))
        .collect();
    let mut out = String::new();
    for row in 0..=df.height() {
        let line: Vec<String> = cells
            .iter()
            .zip(&widths)
            .map(|(c, w)| format!("{:>w$}", c[row], w = *w))
            .collect();
        writeln!(out, "{}", line.join("  ")).expect("write");
    }
    out
}

/// One stage kind run on files, outside any job (`egcal stage`, `egcal predict`).
pub struct FileStage<'a> {
    pub kind: &'a str,
    pub robot_file: &'a Path,
    /// Cable-robot geometry; the built-in default when absent.
    pub cable_robot_file: Option<&'a Path>,
    pub inputs: &'a [(String, PathBuf)],
    pub seed: u64,
    /// Day relative time windows end on.
    pub run_date: i64,
}

/// `egcal stage`: one stage kind on files, outputs to `DIR/<table>.parquet`.
pub fn stage(
    stage: &FileStage,
    settings_file: Option<&Path>,
    out_dir: &Path,
) -> Result<Finished, CommandError> {
    let kind = stage.kind;
    let raw_settings: toml::Table = match settings_file {
        None => toml::Table::new(),
        Some(path) => {
            let text = std::fs::read_to_string(path).map_err(|e| {
                CommandError::Usage(format!("cannot read settings {}: {e}", path.display()))
            })?;
            toml::from_str(&text).map_err(|e| {
                CommandError::Usage(format!(
                    "{}: {}",
                    path.display(),
                    crate::toml_error::describe(&e, &text)
                ))
            })?
        }
    };
    let settings_name = settings_file.map_or("settings".to_string(), |p| p.display().to_string());
    let work_dir = out_dir.join(".work");
    let (mut outputs, provenance) = run_on_files(stage, &raw_settings, &settings_name, &work_dir)?;
    let mut written = Vec::new();
    for (name, df) in outputs.tables.iter_mut() {
        let path = out_dir.join(format!("{name}.parquet"));
        table::write_parquet(df, &path, Some(&provenance))?;
        written.push(format!("{} ({} rows)", path.display(), df.height()));
    }
    for (name, bytes) in &outputs.files {
        let path = out_dir.join(name);
        crate::fsio::write_bytes_atomic(&path, bytes)
            .map_err(|e| table::schema::io_error(&path, e))?;
        written.push(path.display().to_string());
    }
    let facts: String = outputs
        .facts
        .iter()
        .map(|(name, value)| format!("\n  {name} = {value}"))
        .collect();
    let code = if kind == "gate" {
        job_run::gate_code(&[job_run::gate_decision(out_dir)?])
    } else {
        exit_code::OK
    };
    Ok(Finished {
        message: format!("{kind}: wrote {}{facts}", written.join(", ")),
        code,
    })
}

/// `egcal publish`: puts a parameters table in service by hand (the first
/// calibration of a cell, or a rollback): `dir/current.parquet`, the previous one
/// kept as `retired-<date>.parquet`.
pub fn publish(
    parameters: &Path,
    dir: &Path,
    day: i64,
    accept_implausible: bool,
) -> Result<String, CommandError> {
    let checked = table::read_checked(parameters, &table::schema::parameters())?;
    if checked.height() == 0 {
        return Err(CommandError::Usage(format!(
            "{}: the parameters table is empty",
            parameters.display()
        )));
    }
    // What a controller would load is held to identify's own bounds.
    let defaults = crate::stages::identify::IdentifySettings::default();
    if let Some(problem) = table::parameters::implausible_row(
        &checked,
        parameters,
        defaults.plausible_length_mm,
        defaults.plausible_angle_deg,
        accept_implausible,
    )? {
        return Err(CommandError::Usage(format!(
            "{problem}; nothing was put in service"
        )));
    }
    let bytes = std::fs::read(parameters)
        .map_err(|e| CommandError::Usage(format!("cannot read {}: {e}", parameters.display())))?;
    let installed = crate::publish::install(dir, &bytes, day).map_err(|e| {
        CommandError::Run(Box::new(RunError::Io {
            context: format!("publishing into {}", dir.display()),
            source: e,
        }))
    })?;
    let leftovers = installed
        .swept
        .summary(dir)
        .map_or(String::new(), |s| format!("\n{s}"));
    let message = match installed.retired {
        Some(retired) => format!(
            "published {} as {}; the previous one is {}",
            parameters.display(),
            installed.current.display(),
            retired.display()
        ),
        None => format!(
            "published {} as {}",
            parameters.display(),
            installed.current.display()
        ),
    };
    Ok(message + &leftovers)
}

/// `egcal predict`: the `predict` stage on one input file, written to `output`.
pub fn predict(
    robot_file: &Path,
    params: Option<&Path>,
    model: &str,
    input: &Path,
    output: &Path,
) -> Result<String, CommandError> {
    let mut inputs = vec![("conf_wrenches".to_string(), input.to_path_buf())];
    if let Some(params) = params {
        inputs.push(("parameters".to_string(), params.to_path_buf()));
    }
    let mut settings = toml::Table::new();
    settings.insert("model".into(), toml::Value::String(model.to_string()));
    // The work folders of killed `egcal predict` runs are removed here, as no
    // job's sweep ever looks in the system's temporary folder. A failed sweep of
    // that shared folder must not stop a prediction, so its error is dropped.
    let tmp = std::env::temp_dir();
    let leftovers = crate::fsio::sweep::sweep_work_folders(&tmp)
        .ok()
        .and_then(|swept| swept.summary(&tmp))
        .map_or(String::new(), |s| format!("\n{s}"));
    let work_dir = tmp.join(crate::fsio::sweep::predict_temp_name());
    let stage = FileStage {
        kind: "predict",
        robot_file,
        cable_robot_file: None,
        inputs: &inputs,
        seed: 0,
        run_date: table::time::today(),
    };
    let (mut outputs, provenance) = run_on_files(&stage, &settings, "--model", &work_dir)?;
    let _ = std::fs::remove_dir_all(&work_dir);
    let df = outputs
        .tables
        .get_mut("predictions")
        .expect("predict writes predictions");
    table::write_parquet(df, output, Some(&provenance))?;
    Ok(format!(
        "predict: wrote {} ({} rows){leftovers}",
        output.display(),
        df.height()
    ))
}

/// Runs one stage kind on files outside any job: checks inputs against the kind's
/// schemas, runs it, and returns its tables with provenance for writing.
fn run_on_files(
    stage: &FileStage,
    raw_settings: &toml::Table,
    settings_name: &str,
    work_dir: &Path,
) -> Result<(stages::StageOutputs, Provenance), CommandError> {
    let FileStage {
        kind,
        robot_file,
        cable_robot_file,
        inputs,
        seed,
        run_date,
    } = *stage;
    let stage_kind = stages::lookup(kind)
        .ok_or_else(|| CommandError::Usage(stages::unknown_kind_message(kind)))?;
    let info = stage_kind.info();
    let settings_problems = |problems: Vec<stages::SettingsProblem>| {
        CommandError::Usage(
            problems
                .iter()
                .map(|p| match p.key.as_str() {
                    "" => format!("{settings_name}: {}", p.message),
                    key => format!("{settings_name}: {key}: {}", p.message),
                })
                .collect::<Vec<_>>()
                .join("\n"),
        )
    };
    let settings = stage_kind
        .canonical_settings(raw_settings)
        .map_err(settings_problems)?;
    let robot = Robot::new(RobotSpec::load(robot_file)?);
    let cable_robot = match cable_robot_file {
        Some(path) => CableRobotSpec::load(path).map_err(|e| CommandError::Usage(e.to_string()))?,
        None => CableRobotSpec::default(),
    };
    let job_dir = Path::new(".");
    let bound: Vec<&str> = inputs.iter().map(|(name, _)| name.as_str()).collect();
    let problems = stage_kind.check_settings(
        &settings,
        &stages::SettingsContext {
            robot: robot.spec(),
            cable_robot: &cable_robot,
            job_dir,
            bound_inputs: &bound,
        },
    );
    if !problems.is_empty() {
        return Err(settings_problems(problems));
    }
    let mut tables = BTreeMap::new();
    for (name, path) in inputs {
        let slot = info.inputs.iter().find(|s| s.name == name).ok_or_else(|| {
            CommandError::Usage(format!(
                "stage kind `{kind}` has no input `{name}`{}; its inputs: {}",
                crate::suggest::did_you_mean(name, info.inputs.iter().map(|s| s.name)),
                info.inputs
                    .iter()
                    .map(|s| s.name)
                    .collect::<Vec<_>>()
                    .join(", ")
            ))
        })?;
        let df = table::read_checked(path, &(slot.schema)())?;
        tables.insert(
            name.clone(),
            InputTable {
                path: path.clone(),
                df,
            },
        );
    }
    for slot in info.inputs.iter().filter(|s| s.required) {
        if !tables.contains_key(slot.name) {
            return Err(CommandError::Usage(format!(
                "missing required input `{}` ({}): pass --input {}=PATH",
                slot.name, slot.meaning, slot.name
            )));
        }
    }
    std::fs::create_dir_all(work_dir).map_err(|e| table::schema::io_error(work_dir, e))?;
    let ctx = StageContext {
        robot: &robot,
        cable_robot: &cable_robot,
        seed,
        inputs: &tables,
        work_dir,
        job_dir,
        run_date,
        progress: &WarningsToStderr { kind },
    };
    let outputs = stage_kind
        .run(&ctx, &settings)
        .map_err(|source| CommandError::Stage {
            kind: kind.to_string(),
            source: Box::new(source),
        })?;
    let provenance = Provenance {
        job: "(egcal stage)".into(),
        stage_id: kind.into(),
        stage_kind: kind.into(),
        cache_key: String::new(),
        input_hashes: inputs
            .iter()
            .map(|(n, p)| (n.clone(), crate::fsio::hash_file(p).unwrap_or_default()))
            .collect(),
        tool_version: env!("CARGO_PKG_VERSION").into(),
        created_at: table::now_rfc3339(),
        extra: outputs.facts.clone(),
    };
    Ok((outputs, provenance))
}

/// The progress of a stage run on files: no bars or log lines, but each
/// warning (rows dropped or left out, a guessed encoding) on stderr, so
/// nothing is left out in silence.
struct WarningsToStderr<'a> {
    kind: &'a str,
}

impl stages::Progress for WarningsToStderr<'_> {
    fn start(&self, _: u64, _: &str) {}
    fn advance(&self, _: u64) {}
    fn note(&self, message: &str) {
        if message.starts_with("warning") {
            eprintln!("{}: {message}", self.kind);
        }
    }
}

/// `egcal sim-driver`: serves the simulator over the driver protocol on
/// stdin/stdout until `shutdown` or end of input.
pub fn sim_driver(
    robot_file: &Path,
    truth: Option<&Path>,
    truth_model: &str,
    settings_file: Option<&Path>,
    seed: u64,
) -> Result<String, CommandError> {
    use crate::rig::simulator::{Simulator, SimulatorSettings};
    let robot = Robot::new(RobotSpec::load(robot_file)?);
    let nominal = crate::robot::ParamValues::nominal(robot.spec());
    let (values, targets) = match truth {
        None => (nominal, Vec::new()),
        Some(path) => {
            let model = truth_model.parse().map_err(CommandError::Usage)?;
            let set = table::parameters::load_model(path, model, robot.spec())?;
            (set.values, set.targets)
        }
    };
    let settings: SimulatorSettings = match settings_file {
        None => SimulatorSettings::default(),
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .map_err(|e| CommandError::Usage(format!("cannot read {}: {e}", path.display())))?;
            let settings: SimulatorSettings = toml::from_str(&text).map_err(|e| {
                CommandError::Usage(format!(
                    "{}: {}",
                    path.display(),
                    crate::toml_error::describe(&e, &text)
                ))
            })?;
            // The ranges a measure stage's `simulator` table is held to. NaN
            // cannot slip through: the raw table is checked before serde_json.
            let raw: toml::Table = toml::from_str(&text)
                .map_err(|e| CommandError::Usage(format!("{}: {}", path.display(), e.message())))?;
            let schema = serde_json::to_value(schemars::schema_for!(SimulatorSettings))
                .expect("schema serialises");
            let mut problems = stages::settings_check::non_finite_problems(&raw);
            if problems.is_empty() {
                let value = serde_json::to_value(&settings).expect("settings serialise");
                problems = stages::settings_check::range_problems(&value, &schema);
            }
            if let Some(p) = problems.first() {
                return Err(CommandError::Usage(format!(
                    "{}: {}: {}",
                    path.display(),
                    p.key,
                    p.message
                )));
            }
            settings
        }
    };
    let robot_has_track = robot.spec().track.is_some();
    let robot_has_positioner = robot.spec().positioner.is_some();
    let mut simulator = Simulator::new(robot, values, settings, seed)
        .map_err(CommandError::Usage)?
        .with_targets(targets);
    let stdin = std::io::stdin();
    let stdout = std::io::stdout();
    // The track's and the positioner's methods only for a cell with them.
    let all: Vec<String> = crate::rig::protocol::METHODS
        .iter()
        .chain(
            robot_has_track
                .then_some(&crate::rig::protocol::TRACK_METHODS[..])
                .into_iter()
                .flatten(),
        )
        .chain(
            robot_has_positioner
                .then_some(&crate::rig::protocol::POSITIONER_METHODS[..])
                .into_iter()
                .flatten(),
        )
        .map(|m| m.to_string())
        .collect();
    crate::rig::driver::serve(
        &mut simulator,
        "egcal simulator",
        &all,
        stdin.lock(),
        stdout.lock(),
    )
    .map_err(|e| CommandError::Usage(format!("driver I/O: {e}")))?;
    Ok(String::new())
}

/// `egcal lab-driver`: the cell file's devices served over the driver protocol
/// on stdin/stdout until `shutdown` or end of input.
pub fn lab_driver(cell_file: &Path) -> Result<String, CommandError> {
    let cell =
        crate::lab::CellFile::load(cell_file).map_err(|e| CommandError::Usage(e.to_string()))?;
    let mut rig = crate::lab::LabRig::connect(cell, cell_file);
    let (name, capabilities) = (rig.name(), rig.capabilities());
    let stdin = std::io::stdin();
    let stdout = std::io::stdout();
    crate::rig::driver::serve(&mut rig, &name, &capabilities, stdin.lock(), stdout.lock())
        .map_err(|e| CommandError::Usage(format!("driver I/O: {e}")))?;
    Ok(String::new())
}

/// `egcal cache gc`.
pub fn cache_gc(job: &Path) -> Result<String, CommandError> {
    let plan = Plan::load(job)?;
    let collected = runner::gc(&plan)?;
    let mut message = format!(
        "removed {} cache entries ({:.1} MiB)",
        collected.entries,
        collected.bytes as f64 / 1048576.0
    );
    if let Some(leftovers) = collected.leftovers {
        write!(message, "\n{leftovers}").expect("write to string");
    }
    Ok(message)
}

/// `egcal schemas`: (re)writes the generated schema files into `dir`, and the
/// guide's generated reference pages into `guide_dir` when given.
pub fn write_schemas(dir: &Path, guide_dir: Option<&Path>) -> Result<String, CommandError> {
    let files = generated_schemas();
    for (name, text) in &files {
        let path = dir.join(name);
        crate::fsio::write_bytes_atomic(&path, text.as_bytes())
            .map_err(|e| table::schema::io_error(&path, e))?;
    }
    let mut message = format!("wrote {} schema files to {}", files.len(), dir.display());
    if let Some(guide_dir) = guide_dir {
        let pages = reference::generated_guide_pages();
        for (name, text) in &pages {
            let path = guide_dir.join(name);
            crate::fsio::write_bytes_atomic(&path, text.as_bytes())
                .map_err(|e| table::schema::io_error(&path, e))?;
        }
        write!(
            message,
            "\nwrote {} guide pages to {}",
            pages.len(),
            guide_dir.display()
        )
        .expect("write to string");
    }
    Ok(message)
}

/// Every generated schema file: (path relative to `schemas/`, content).
pub fn generated_schemas() -> Vec<(String, String)> {
    let mut files = vec![
        (
            "job.schema.json".to_string(),
            crate::job::schema::job_schema_json(),
        ),
        (
            "driver-protocol.schema.json".to_string(),
            crate::rig::protocol::schema_json(),
        ),
    ];
    let robot =
        serde_json::to_string_pretty(&schemars::schema_for!(RobotSpec)).expect("schema serialises");
    files.push(("robot.schema.json".into(), robot + "\n"));
    let fleet =
        serde_json::to_string_pretty(&schemars::schema_for!(crate::fleet::file::FleetFileRaw))
            .expect("schema serialises");
    files.push(("fleet.schema.json".into(), fleet + "\n"));
    let cell = serde_json::to_string_pretty(&schemars::schema_for!(crate::lab::CellFile))
        .expect("schema serialises");
    files.push(("cell.schema.json".into(), cell + "\n"));
    files.push((
        "fixture-case.schema.json".into(),
        crate::fixture_cases::case::schema_json(),
    ));
    for schema in table::schema::all() {
        let text = serde_json::to_string_pretty(&schema).expect("schema serialises");
        files.push((format!("tables/{}.json", schema.kind), text + "\n"));
    }
    files
}
