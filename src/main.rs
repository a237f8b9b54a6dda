//! The `egcal` binary: parses arguments, dispatches to [`egcal::commands`], prints
//! the result or the error, and exits with the documented code.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};
use egcal::commands::{self, CommandError};
use egcal::exit_code::Finished;
use egcal::job::JobOverrides;
use egcal::runner::RunOptions;

#[derive(Parser)]
#[command(
    name = "egcal",
    version,
    about = "Elasto-geometric robot calibration as reproducible batch jobs"
)]
struct Cli {
    /// No progress bars or log lines; only results and errors.
    #[arg(long, short, global = true)]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a job: every stale stage, independent stages in parallel.
    Run {
        job: PathBuf,
        /// Run only this stage (its inputs must be cached).
        #[arg(long)]
        only: Option<String>,
        /// Recompute this stage and everything downstream.
        #[arg(long)]
        from: Option<String>,
        /// Recompute every stage. A measuring stage resumes from its journal,
        /// so its rows come back as recorded; see --remeasure.
        #[arg(long)]
        force: bool,
        /// Measure this stage afresh: its journal is set aside (kept under
        /// OUT/.egcal/set_aside/STAGE/TIME/) and it re-runs with everything
        /// downstream. Repeatable.
        #[arg(long, value_name = "STAGE")]
        remeasure: Vec<String>,
        /// Stages run at once (default: the number of cores).
        #[arg(long, short)]
        jobs: Option<usize>,
        /// Day relative time windows end on, YYYY-MM-DD (default: today, UTC).
        #[arg(long, value_parser = parse_run_date)]
        run_date: Option<i64>,
        /// NAME=VALUE for the job file's `{NAME}` placeholders (over `[job] vars`);
        /// repeatable.
        #[arg(long = "var", value_parser = parse_var)]
        vars: Vec<(String, String)>,
    },
    /// Dry run: each stage cached or stale, and why.
    Status {
        job: PathBuf,
        /// As for `run`.
        #[arg(long, value_parser = parse_run_date)]
        run_date: Option<i64>,
        /// As for `run`.
        #[arg(long = "var", value_parser = parse_var)]
        vars: Vec<(String, String)>,
    },
    /// Print the stage graph (Mermaid, or DOT with --dot).
    Dag {
        job: PathBuf,
        #[arg(long)]
        dot: bool,
    },
    /// Validate the job file and its external inputs; run nothing.
    Check {
        job: PathBuf,
        /// As for `run`.
        #[arg(long = "var", value_parser = parse_var)]
        vars: Vec<(String, String)>,
    },
    /// Schema, provenance and first rows of a Parquet table.
    Show {
        table: PathBuf,
        #[arg(long, default_value_t = 10)]
        rows: usize,
    },
    /// Run one stage kind on files (fixture tests, debugging).
    Stage {
        #[command(flatten)]
        stage: StageFiles,
        #[arg(long)]
        out: PathBuf,
    },
    /// Predict positions, load torques and deflections for conf-wrench rows.
    Predict {
        #[command(flatten)]
        arm: ArmModel,
        #[arg(long)]
        input: PathBuf,
        #[arg(long)]
        output: PathBuf,
    },
    /// Serve the simulator over the driver protocol on stdin/stdout (for testing
    /// the external-driver path, and as an example driver).
    SimDriver {
        #[arg(long)]
        robot: PathBuf,
        /// Parameters table of the simulated robot; nominal when absent.
        #[arg(long)]
        truth: Option<PathBuf>,
        #[arg(long, default_value = "elastogeometric")]
        truth_model: String,
        /// TOML file with simulator settings (the `simulator` table of a measure stage).
        #[arg(long)]
        settings: Option<PathBuf>,
        #[arg(long, default_value_t = 0)]
        seed: u64,
    },
    /// The reference lab driver: the cell file's devices (ATI Net F/T, egcal UDP
    /// cable robot) served over the driver protocol on stdin/stdout; name it as a
    /// measure stage's driver `command`.
    LabDriver {
        #[arg(long)]
        cell: PathBuf,
    },
    /// Put a parameters table in service: DIR/current.parquet, keeping the previous
    /// one as DIR/retired-<date>.parquet (a cell's first calibration, or a rollback).
    Publish {
        parameters: PathBuf,
        /// Calibration folder (the gate's `publish_dir`).
        #[arg(long)]
        to: PathBuf,
        /// Date the replaced file is retired under, YYYY-MM-DD (default: today, UTC).
        #[arg(long, value_parser = parse_run_date)]
        date: Option<i64>,
        /// Put in service a set whose length or angle errors lie beyond
        /// identify's default plausibility bounds (10 mm, 2°): a robot that
        /// truly differs that much from its file. Absurd values stay refused.
        #[arg(long)]
        accept_implausible: bool,
    },
    /// Stage kinds with their inputs, outputs and settings (with defaults).
    ListStages,
    /// Cache maintenance.
    Cache {
        #[command(subcommand)]
        action: CacheAction,
    },
    /// A fleet's nightly re-calibration: every robot's night of one job template.
    Fleet {
        #[command(subcommand)]
        action: FleetAction,
    },
    /// Run fixture cases (`<folder>/<kind>/<case>/case.toml`): each case's stage on
    /// its files, checked against what it expects. Exit 0 when all pass, 1 when a
    /// case fails, 2 when a case file is malformed.
    #[command(args_conflicts_with_subcommands = true)]
    Test {
        #[command(subcommand)]
        action: Option<TestAction>,
        /// Folders of cases, searched recursively (default: fixtures).
        dirs: Vec<PathBuf>,
        /// Only cases whose folder (as found, or below the searched folder)
        /// matches: a glob (`identify/*`) or a substring; repeatable.
        #[arg(long)]
        only: Vec<String>,
        /// Also write a JUnit XML report here.
        #[arg(long)]
        junit: Option<PathBuf>,
        /// Cases at once (default: the number of cores).
        #[arg(long, short)]
        jobs: Option<usize>,
        /// A case still running after this many seconds fails.
        #[arg(long, default_value_t = 600, value_parser = clap::value_parser!(u64).range(1..))]
        timeout_s: u64,
    },
    /// Regenerate the JSON schemas (job file, robot file, tables) into a folder.
    Schemas {
        #[arg(long, default_value = "schemas")]
        out: PathBuf,
        /// Also write the user guide's generated reference pages (stage kinds,
        /// tables) into this folder (`docs/reference`).
        #[arg(long)]
        guide: Option<PathBuf>,
    },
    /// The flange and tool pose at joint values as the controller shows them
    /// (unloaded): check a new robot file against the teach pendant.
    Pose {
        #[command(flatten)]
        arm: ArmModel,
        /// Joint values in the controller's numbering: deg (mm for a prismatic joint).
        #[arg(long, num_args = 1.., required = true, allow_hyphen_values = true, value_delimiter = ',')]
        joints: Vec<f64>,
    },
    /// A world (tracker ← base) and tool frame in both conventions: egcal's
    /// Rot·Trans numbers (x_w … gamma_w) and the base origin in the tracker frame
    /// with its XYZ angles (Trans·Rot).
    Frame {
        /// Robot file: its [world] and [tool].
        #[arg(long, required_unless_present = "origin_in_tracker")]
        robot: Option<PathBuf>,
        /// Parameters table: the frames of one of its models instead of the
        /// robot file's (needs --robot).
        #[arg(long, requires = "robot")]
        params: Option<PathBuf>,
        /// Model of the parameters table.
        #[arg(long, default_value = "elastogeometric")]
        model: String,
        /// The other way: the base origin in the tracker frame (mm) and the XYZ
        /// angles (deg) → the x_w … gamma_w a robot file's [world] takes.
        #[arg(long, num_args = 6, allow_negative_numbers = true, value_names = ["X_MM", "Y_MM", "Z_MM", "RX_DEG", "RY_DEG", "RZ_DEG"], conflicts_with_all = ["robot", "params"])]
        origin_in_tracker: Option<Vec<f64>>,
    },
}

/// The arm a command evaluates: a robot file, nominal or with one model of a
/// parameters table.
#[derive(Args)]
struct ArmModel {
    /// Robot file.
    #[arg(long)]
    robot: PathBuf,
    /// Parameters table; the robot file's nominal values when absent.
    #[arg(long)]
    params: Option<PathBuf>,
    /// Model of the parameters table to use.
    #[arg(long, default_value = "elastogeometric")]
    model: String,
}

#[derive(Subcommand)]
enum FleetAction {
    /// Run every robot's night on this machine, then gather it.
    Run {
        fleet: PathBuf,
        /// Robot-nights at once (default: 1; each night uses the cores left).
        #[arg(long, short, default_value_t = 1)]
        jobs: usize,
        /// The night, YYYY-MM-DD (default: today, UTC).
        #[arg(long, value_parser = parse_run_date)]
        run_date: Option<i64>,
    },
    /// Submit the night to Slurm as a job array (several robot-nights per task).
    Submit {
        fleet: PathBuf,
        #[arg(long, value_parser = parse_run_date)]
        run_date: Option<i64>,
        /// Tasks at once (`--array=…%M`); 0: no limit. Default: `[slurm] max_parallel`.
        #[arg(long)]
        max_parallel: Option<usize>,
        /// Wait for the tasks, then gather (exit code as `gather`).
        #[arg(long)]
        wait: bool,
    },
    /// Run one task of a submitted night (what each array task runs).
    Task {
        fleet: PathBuf,
        /// Task index; default SLURM_ARRAY_TASK_ID, else JOB_COMPLETION_INDEX.
        #[arg(long)]
        index: Option<usize>,
        /// Added to the index (arrays after the first, when a night is split at
        /// the cluster's MaxArraySize).
        #[arg(long, default_value_t = 0)]
        index_offset: usize,
        #[arg(long, value_parser = parse_run_date)]
        run_date: Option<i64>,
    },
    /// Collect the night's decisions into one table and page; exit 3 when a night
    /// failed or is missing, else 11 / 10 / 0 as the most urgent gate decision.
    Gather {
        fleet: PathBuf,
        #[arg(long, value_parser = parse_run_date)]
        run_date: Option<i64>,
    },
}

/// A stage kind and the files it runs on: `egcal stage`'s and `egcal test
/// record`'s arguments.
#[derive(clap::Args)]
struct StageFiles {
    /// Stage kind (`egcal list-stages`).
    kind: String,
    /// Robot file (TOML).
    #[arg(long)]
    robot: PathBuf,
    /// Cable-robot geometry (TOML); the built-in default when absent.
    #[arg(long)]
    cable_robot: Option<PathBuf>,
    /// NAME=PATH, repeatable.
    #[arg(long = "input", value_parser = parse_input)]
    inputs: Vec<(String, PathBuf)>,
    /// TOML file with the stage's settings (as in a job's stage table).
    #[arg(long)]
    settings: Option<PathBuf>,
    /// The job seed the stage's randomness derives from.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Day relative time windows end on, YYYY-MM-DD (default: today, UTC).
    #[arg(long, value_parser = parse_run_date)]
    run_date: Option<i64>,
}

#[derive(Subcommand)]
enum TestAction {
    /// Create a regression case from a stage run on these files: inputs copied,
    /// today's output tables (or, with --expect-error, its error) stored as the
    /// expectation, marked as recorded from egcal, checked to pass once more
    /// before the folder is written.
    Record {
        #[command(flatten)]
        stage: StageFiles,
        /// A file or folder a setting names by relative path (`logs`), copied into
        /// the case under the same path; repeatable.
        #[arg(long = "copy")]
        copies: Vec<PathBuf>,
        /// Relative tolerance of the recorded float comparisons.
        #[arg(long, default_value_t = 1e-9)]
        tolerance: f64,
        /// The stage fails on these files: record its error message and exit code
        /// as the expectation (a known bad file) instead of output tables.
        #[arg(long)]
        expect_error: bool,
        /// A case still running after this many seconds fails.
        #[arg(long, default_value_t = 600, value_parser = clap::value_parser!(u64).range(1..))]
        timeout_s: u64,
        /// The case folder to create (must not exist).
        #[arg(long)]
        out: PathBuf,
    },
}

#[derive(Subcommand)]
enum CacheAction {
    /// Remove cache entries that no stage of the job uses any more.
    Gc { job: PathBuf },
}

fn parse_input(text: &str) -> Result<(String, PathBuf), String> {
    let (name, path) = text
        .split_once('=')
        .ok_or_else(|| format!("expected NAME=PATH, found `{text}`"))?;
    Ok((name.to_string(), PathBuf::from(path)))
}

fn parse_var(text: &str) -> Result<(String, String), String> {
    let (name, value) = text
        .split_once('=')
        .ok_or_else(|| format!("expected NAME=VALUE, found `{text}`"))?;
    Ok((name.to_string(), value.to_string()))
}

fn overrides(vars: Vec<(String, String)>) -> JobOverrides {
    JobOverrides::with_vars(vars.into_iter().collect())
}

fn dispatch(cli: Cli) -> Result<Finished, CommandError> {
    match cli.command {
        Command::Run {
            job,
            only,
            from,
            force,
            remeasure,
            jobs,
            run_date,
            vars,
        } => {
            let jobs =
                jobs.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
            commands::run(
                &job,
                &overrides(vars),
                &RunOptions {
                    only,
                    from,
                    force,
                    jobs,
                    run_date,
                    remeasure,
                },
                cli.quiet,
            )
        }
        Command::Status {
            job,
            run_date,
            vars,
        } => commands::status(&job, &overrides(vars), run_date).map(Finished::from),
        Command::Dag { job, dot } => commands::dag(&job, dot).map(Finished::from),
        Command::Check { job, vars } => commands::check(&job, &overrides(vars)).map(Finished::from),
        Command::Show { table, rows } => commands::show(&table, rows).map(Finished::from),
        Command::Stage { stage, out } => commands::stage(
            &commands::FileStage {
                kind: &stage.kind,
                robot_file: &stage.robot,
                cable_robot_file: stage.cable_robot.as_deref(),
                inputs: &stage.inputs,
                seed: stage.seed,
                run_date: stage.run_date.unwrap_or_else(egcal::table::time::today),
            },
            stage.settings.as_deref(),
            &out,
        ),
        Command::Predict { arm, input, output } => commands::predict(
            &arm.robot,
            arm.params.as_deref(),
            &arm.model,
            &input,
            &output,
        )
        .map(Finished::from),
        Command::SimDriver {
            robot,
            truth,
            truth_model,
            settings,
            seed,
        } => commands::sim_driver(
            &robot,
            truth.as_deref(),
            &truth_model,
            settings.as_deref(),
            seed,
        )
        .map(Finished::from),
        Command::Publish {
            parameters,
            to,
            date,
            accept_implausible,
        } => commands::publish(
            &parameters,
            &to,
            date.unwrap_or_else(egcal::table::time::today),
            accept_implausible,
        )
        .map(Finished::from),
        Command::LabDriver { cell } => commands::lab_driver(&cell).map(Finished::from),
        Command::ListStages => Ok(commands::list_stages().into()),
        Command::Cache {
            action: CacheAction::Gc { job },
        } => commands::cache_gc(&job).map(Finished::from),
        Command::Fleet { action } => fleet_command(action, cli.quiet),
        Command::Test {
            action,
            dirs,
            only,
            junit,
            jobs,
            timeout_s,
        } => match action {
            Some(action) => record_command(action),
            None => test_command(dirs, only, junit, jobs, timeout_s, cli.quiet),
        },
        Command::Schemas { out, guide } => {
            commands::write_schemas(&out, guide.as_deref()).map(Finished::from)
        }
        Command::Pose { arm, joints } => {
            commands::pose(&arm.robot, arm.params.as_deref(), &arm.model, &joints)
                .map(Finished::from)
        }
        Command::Frame {
            robot,
            params,
            model,
            origin_in_tracker,
        } => commands::frame(
            robot.as_deref(),
            params.as_deref(),
            &model,
            origin_in_tracker.as_deref(),
        )
        .map(Finished::from),
    }
}

/// `egcal fleet …`: errors keep their own exit codes.
fn fleet_command(action: FleetAction, quiet: bool) -> Result<Finished, CommandError> {
    use egcal::fleet::{self, Fleet, FleetError};
    let today = egcal::table::time::today;
    let ran = |r: Result<Finished, FleetError>| r.map_err(|e| CommandError::Fleet(Box::new(e)));
    let gathered = |g: fleet::gather::Gathered| Finished {
        message: g.summary,
        code: g.code,
    };
    ran((|| match action {
        FleetAction::Run {
            fleet,
            jobs,
            run_date,
        } => {
            let fleet = Fleet::load(&fleet)?;
            let options = fleet::local::LocalOptions {
                run_date: run_date.unwrap_or_else(today),
                jobs,
                quiet,
            };
            fleet::local::run(&fleet, &options).map(gathered)
        }
        FleetAction::Submit {
            fleet,
            run_date,
            max_parallel,
            wait,
        } => {
            let fleet = Fleet::load(&fleet)?;
            let run_date = run_date.unwrap_or_else(today);
            let submitted = fleet::slurm::submit(
                &fleet,
                &fleet::slurm::SubmitOptions {
                    run_date,
                    max_parallel,
                    wait,
                },
            )?;
            if let Some(g) = submitted.gathered {
                return Ok(gathered(g));
            }
            Ok(Finished::from(submitted.summary(&fleet)))
        }
        FleetAction::Task {
            fleet,
            index,
            index_offset,
            run_date,
        } => {
            let fleet = Fleet::load(&fleet)?;
            let index = fleet::slurm::task_index(index)? + index_offset;
            fleet::slurm::task(&fleet, run_date.unwrap_or_else(today), index)
        }
        FleetAction::Gather { fleet, run_date } => {
            let fleet = Fleet::load(&fleet)?;
            fleet::gather::gather(&fleet, run_date.unwrap_or_else(today)).map(gathered)
        }
    })())
}

/// The running binary: each fixture case runs as its own `egcal stage`.
fn this_egcal() -> Result<PathBuf, CommandError> {
    std::env::current_exe()
        .map_err(|e| CommandError::Usage(format!("cannot find the egcal binary: {e}")))
}

/// `egcal test`: a line per case as it ends (failures and summary in the result).
fn test_command(
    dirs: Vec<PathBuf>,
    only: Vec<String>,
    junit: Option<PathBuf>,
    jobs: Option<usize>,
    timeout_s: u64,
    quiet: bool,
) -> Result<Finished, CommandError> {
    use egcal::fixture_cases::{self, Outcome};
    let fixture = |e| CommandError::Fixture(Box::new(e));
    let options = fixture_cases::TestOptions {
        dirs: if dirs.is_empty() {
            vec![PathBuf::from("fixtures")]
        } else {
            dirs
        },
        only,
        jobs: jobs.unwrap_or_else(|| {
            std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
        }),
        egcal: this_egcal()?,
        timeout: std::time::Duration::from_secs(timeout_s),
    };
    let print = |result: &fixture_cases::CaseResult| {
        let status = match result.outcome {
            Outcome::Passed if quiet => return,
            Outcome::Passed => "ok",
            Outcome::Failed(_) => "FAILED",
            Outcome::Malformed(_) => "MALFORMED",
        };
        let recorded = if result.recorded { " (recorded)" } else { "" };
        let _ = writeln!(
            std::io::stdout().lock(),
            "{status:<9} {}{recorded} ({:.2} s)",
            result.name,
            result.seconds
        );
    };
    if let Some(path) = &junit {
        fixture_cases::check_report_path(path).map_err(fixture)?;
    }
    let summary = fixture_cases::run(&options, &print).map_err(fixture)?;
    if let Some(path) = &junit {
        fixture_cases::write_junit(&summary, path)
            .map_err(|e| CommandError::Usage(format!("{}\n{e}", summary.report().trim_start())))?;
    }
    Ok(Finished {
        message: summary.report(),
        code: summary.exit_code(),
    })
}

/// `egcal test record`.
fn record_command(action: TestAction) -> Result<Finished, CommandError> {
    let TestAction::Record {
        stage,
        copies,
        tolerance,
        expect_error,
        timeout_s,
        out,
    } = action;
    let options = egcal::fixture_cases::RecordOptions {
        kind: stage.kind,
        robot_file: stage.robot,
        cable_robot_file: stage.cable_robot,
        inputs: stage.inputs,
        settings_file: stage.settings,
        seed: stage.seed,
        run_date: stage.run_date.unwrap_or_else(egcal::table::time::today),
        copies,
        tolerance,
        out,
        expect_error,
        egcal: this_egcal()?,
        timeout: std::time::Duration::from_secs(timeout_s),
    };
    egcal::fixture_cases::record(&options)
        .map(Finished::from)
        .map_err(|e| CommandError::Fixture(Box::new(e)))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match dispatch(cli) {
        Ok(Finished { message, code }) => {
            let message = message.trim_end();
            if !message.is_empty() {
                // A reader that stops early (`egcal list-stages | head`) is not an
                // error of the command: the result stands, nothing to report.
                let _ = writeln!(std::io::stdout().lock(), "{message}");
            }
            ExitCode::from(code)
        }
        Err(e) => {
            let _ = writeln!(std::io::stderr().lock(), "error: {e}");
            ExitCode::from(e.exit_code())
        }
    }
}

fn parse_run_date(text: &str) -> Result<i64, String> {
    egcal::table::time::parse_date(text).ok_or_else(|| format!("`{text}` is not a date YYYY-MM-DD"))
}
